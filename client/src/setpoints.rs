//! Streamed set-points (`Axes.StreamSetpoints`): a client's trajectory,
//! point by point, into the gateway's jitter buffer, played on the bus's
//! SYNC grid with every step inside the axes' limits.

use crate::error::Error;
use crate::lease::ControlLease;
use crate::{Client, pb};
use std::time::Duration;
use tokio::sync::mpsc;

/// How a set-point stream is opened.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SetpointStreamOptions {
    /// The jitter buffer (1 ms to 2 s): network delay beyond the fastest
    /// arrival it absorbs, and the latency it adds.
    pub depth: Duration,
    /// How long the axes go on along the last segment on an underrun
    /// before they ramp to rest; `None`: the depth.
    pub extrapolate: Option<Duration>,
    /// The client's point period, if it keeps one (checked against the
    /// depth).
    pub point_period: Option<Duration>,
    /// How often the gateway reports; `None`: every 50 ms.
    pub status_period: Option<Duration>,
}

impl Default for SetpointStreamOptions {
    /// A 20 ms buffer, extrapolating for as long, reports every 50 ms.
    fn default() -> Self {
        SetpointStreamOptions {
            depth: Duration::from_millis(20),
            extrapolate: None,
            point_period: None,
            status_period: None,
        }
    }
}

/// The sending half of a [`SetpointStream`] (cheap to clone; a task can
/// send while another reads the statuses).
#[derive(Debug, Clone)]
pub struct SetpointSender {
    tx: mpsc::Sender<pb::SetpointStreamRequest>,
    axes: usize,
}

impl SetpointSender {
    /// Sends a batch of points (time order; each with one position per
    /// axis ([`setpoint`]) for axes in csp or CANsmc axes, one velocity
    /// per axis and no position ([`velocity_setpoint`]) for axes in csv, or
    /// one torque per axis and nothing else ([`torque_setpoint`]) for axes
    /// in cst, in the order the stream was opened with).
    ///
    /// # Errors
    /// [`Error::InvalidInput`] for a point with neither one position, nor
    /// (without positions) one velocity, nor (without either) one torque
    /// per axis; [`Error::Transport`] once the call has ended (read the
    /// statuses for why).
    pub async fn send(&self, points: Vec<pb::Setpoint>) -> Result<(), Error> {
        let fits = |p: &pb::Setpoint| {
            p.positions.len() == self.axes
                || (p.positions.is_empty() && p.velocities.len() == self.axes)
                || (p.positions.is_empty()
                    && p.velocities.is_empty()
                    && p.torques.len() == self.axes)
        };
        if let Some(p) = points.iter().find(|p| !fits(p)) {
            return Err(Error::InvalidInput {
                message: format!(
                    "point at {} µs has {} positions, {} velocities and {} torques for a stream \
                     of {} axes",
                    p.t_us,
                    p.positions.len(),
                    p.velocities.len(),
                    p.torques.len(),
                    self.axes
                ),
            });
        }
        self.tx
            .send(pb::SetpointStreamRequest {
                message: Some(pb::setpoint_stream_request::Message::Batch(
                    pb::SetpointBatch { points },
                )),
            })
            .await
            .map_err(|_| Error::Transport {
                message: "the set-point stream has ended".into(),
            })
    }
}

/// An open set-point stream ([`Client::stream_setpoints`]). Points go out
/// with [`SetpointStream::send`]; the gateway's statuses come with
/// [`SetpointStream::status`]. [`SetpointStream::finish`] ends it after
/// the buffered points (the axes then ramp to rest); dropping it cancels
/// it (the axes ramp to rest from where they are).
pub struct SetpointStream {
    sender: Option<SetpointSender>,
    statuses: tonic::Streaming<pb::SetpointStreamStatus>,
    axes: Vec<String>,
}

impl SetpointStream {
    /// The stream's axes, in point order.
    pub fn axes(&self) -> &[String] {
        &self.axes
    }

    /// A sender for another task (see [`SetpointSender`]).
    pub fn sender(&self) -> Option<SetpointSender> {
        self.sender.clone()
    }

    /// Sends a batch of points (see [`SetpointSender::send`]).
    ///
    /// # Errors
    /// As [`SetpointSender::send`]; after [`SetpointStream::finish`] an
    /// [`Error::InvalidInput`].
    pub async fn send(&self, points: Vec<pb::Setpoint>) -> Result<(), Error> {
        match &self.sender {
            Some(s) => s.send(points).await,
            None => Err(Error::InvalidInput {
                message: "the set-point stream was finished: no more points".into(),
            }),
        }
    }

    /// No more points from here: the gateway plays the buffered ones, then
    /// ramps the axes to rest and ends the call (read the statuses to the
    /// end). Senders handed out keep the stream open until dropped.
    pub fn finish(&mut self) {
        self.sender = None;
    }

    /// The next status; `None` once the call ended normally (after
    /// [`SetpointStream::finish`], with the axes at rest).
    ///
    /// # Errors
    /// Why the call ended otherwise: [`Error`] with ABORTED when a stop,
    /// a lost lease or a drive leaving operation ended it (the last status
    /// before says which in `ended`), the open's refusal, a transport
    /// failure.
    pub async fn status(&mut self) -> Result<Option<pb::SetpointStreamStatus>, Error> {
        self.statuses.message().await.map_err(Error::from)
    }
}

/// A point: client time `t_us` (µs, any origin, increasing) and one
/// position per axis.
pub fn setpoint(t_us: u64, positions: Vec<f64>) -> pb::Setpoint {
    pb::Setpoint {
        t_us,
        positions,
        velocities: Vec::new(),
        torques: Vec::new(),
    }
}

/// A point of a velocity stream (axes in cyclic synchronous velocity):
/// client time `t_us` and one velocity per axis (user units/s).
pub fn velocity_setpoint(t_us: u64, velocities: Vec<f64>) -> pb::Setpoint {
    pb::Setpoint {
        t_us,
        positions: Vec::new(),
        velocities,
        torques: Vec::new(),
    }
}

/// A point of a torque stream (axes in cyclic synchronous torque): client
/// time `t_us` and one torque per axis (per mille of the drive's rated
/// torque).
pub fn torque_setpoint(t_us: u64, torques: Vec<f64>) -> pb::Setpoint {
    pb::Setpoint {
        t_us,
        positions: Vec::new(),
        velocities: Vec::new(),
        torques,
    }
}

impl Client {
    /// Opens a set-point stream over `axes` (cyclic axes of one bus, all
    /// in csp (positions), all in csv (velocities) or all in cst
    /// (torques), or CANsmc axes of one master; enabled, at rest) under
    /// `lease`, which must cover them all.
    ///
    /// ```no_run
    /// # async fn demo(client: cangate_client::Client) -> Result<(), cangate_client::Error> {
    /// use cangate_client::{SetpointStreamOptions, setpoint};
    /// let lease = client.acquire_control(&["X", "Y"], std::time::Duration::from_secs(2)).await?;
    /// let mut stream = client
    ///     .stream_setpoints(&lease, &["X", "Y"], SetpointStreamOptions::default())
    ///     .await?;
    /// stream.send(vec![setpoint(0, vec![0.0, 0.0]), setpoint(1000, vec![0.0, 0.0])]).await?;
    /// stream.finish();
    /// while let Some(status) = stream.status().await? {
    ///     println!("buffer {} µs", status.buffer_level_us);
    /// }
    /// # Ok(()) }
    /// ```
    ///
    /// # Errors
    /// NOT_FOUND, INVALID_ARGUMENT and FAILED_PRECONDITION as the gateway
    /// refuses the open (see `StreamSetpoints` in axes.proto).
    pub async fn stream_setpoints(
        &self,
        lease: &ControlLease,
        axes: &[&str],
        opts: SetpointStreamOptions,
    ) -> Result<SetpointStream, Error> {
        self.stream_setpoints_with_token(lease.token(), axes, opts)
            .await
    }

    /// [`Client::stream_setpoints`] with a lease token (a lease held
    /// elsewhere, or none: the gateway then refuses).
    ///
    /// # Errors
    /// As [`Client::stream_setpoints`].
    pub async fn stream_setpoints_with_token(
        &self,
        lease: &str,
        axes: &[&str],
        opts: SetpointStreamOptions,
    ) -> Result<SetpointStream, Error> {
        let ms = |d: Duration| u32::try_from(d.as_millis()).unwrap_or(u32::MAX);
        let open = pb::SetpointStreamOpen {
            axes: axes.iter().map(|a| a.to_string()).collect(),
            lease: lease.to_string(),
            depth_ms: ms(opts.depth),
            extrapolate_ms: opts.extrapolate.map_or(0, ms),
            point_period_us: opts
                .point_period
                .map_or(0, |p| u32::try_from(p.as_micros()).unwrap_or(u32::MAX)),
            status_period_ms: opts.status_period.map_or(0, ms),
        };
        let (tx, rx) = mpsc::channel(64);
        tx.send(pb::SetpointStreamRequest {
            message: Some(pb::setpoint_stream_request::Message::Open(open)),
        })
        .await
        .map_err(|_| Error::InvalidInput {
            message: "the request stream closed before the open".into(),
        })?;
        let requests =
            futures::stream::unfold(rx, |mut rx| async move { rx.recv().await.map(|m| (m, rx)) });
        let statuses = self
            .call(
                "StreamSetpoints",
                None,
                self.axes_client().stream_setpoints(requests),
            )
            .await?;
        Ok(SetpointStream {
            sender: Some(SetpointSender {
                tx,
                axes: axes.len(),
            }),
            statuses,
            axes: axes.iter().map(|a| a.to_string()).collect(),
        })
    }
}
