//! Set-point streams as a client runs them: opened over cyclic (CSP)
//! CiA 402 axes of one bus or the axes of one CANsmc master, under the
//! client's control lease, fed with batches of time-stamped points,
//! reported on periodically and when something happens.
//!
//! The points are played by the bus's SYNC thread
//! ([`super::cyclic_setpoints`]) or the CANsmc master's cycle thread
//! ([`super::cansmc_setpoints`]), a [`SetpointPlayer`] per stream: no
//! thread hand-over per cycle. This session only passes points in and
//! reports out, at the client's batch rate and the report period, and
//! watches the lease: each batch renews it; once it no longer covers the
//! stream's axes (released, lapsed, taken over), the stream ramps to rest
//! and ends. A stop of any of its axes (from anyone) ends it at once, in
//! the axis task ([`super::cia402_task`]); the session reports why.
//!
//! [`SetpointPlayer`]: cangate_axis::setpoint_stream::SetpointPlayer

use super::cansmc_setpoints::CansmcSetpoints;
use super::cyclic_setpoints::{CyclicSetpoints, StreamEnd, StreamReport};
use super::{Axes, AxisEntry, AxisError, Caller};
use cangate_axis::setpoint_stream::{
    AxisLimits, PlayerConfig, PlayerEvent, PlayerState, PointRefused, SetpointKind, StreamPoint,
};
use cangate_axis::{Activity, AxisCommand, CommandError, DriveSpec};
use cangate_canopen::cia402::DriveState;
use std::collections::HashSet;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

/// The deepest jitter buffer a stream may ask for.
pub const MAX_DEPTH: Duration = Duration::from_secs(2);
/// The longest extrapolation on an underrun.
pub const MAX_EXTRAPOLATE: Duration = Duration::from_secs(1);
/// How often a stream reports when the client gives no period.
pub const DEFAULT_REPORT_PERIOD: Duration = Duration::from_millis(50);
/// Bounds of the report period.
pub const MIN_REPORT_PERIOD: Duration = Duration::from_millis(10);
/// Bounds of the report period.
pub const MAX_REPORT_PERIOD: Duration = Duration::from_secs(1);
/// How often a stream's batches renew its lease (the lease's TTL is at
/// least 100 ms).
pub const RENEW_PERIOD: Duration = Duration::from_millis(50);
/// Refused points reported one by one per report; more are counted only.
pub const MAX_REFUSALS_PER_REPORT: usize = 32;

/// What a client asks for when it opens a stream.
#[derive(Debug, Clone)]
pub struct StreamRequest {
    /// The axes, in the order of each point's positions.
    pub axes: Vec<String>,
    /// The jitter buffer: how long after the fastest arrival a point plays.
    pub depth: Duration,
    /// How long the axes go on along the last segment when no point is
    /// left, before they ramp to rest; `None`: the depth.
    pub extrapolate: Option<Duration>,
    /// The client's point period, if it says: the buffer must hold at
    /// least one.
    pub point_period: Option<Duration>,
    /// How often the stream reports; `None`: [`DEFAULT_REPORT_PERIOD`].
    pub report_period: Option<Duration>,
}

/// What a client sends once the stream is open.
#[derive(Debug, Clone)]
pub enum StreamInput {
    /// Points, in time order.
    Points(Vec<StreamPoint>),
    /// No more points: the buffered ones play, then the axes ramp to rest.
    End,
}

/// A refused point: its client time and why.
#[derive(Debug, Clone)]
pub struct Refusal {
    /// The point's client time, µs.
    pub t_us: u64,
    /// Why.
    pub reason: PointRefused,
}

/// One report of a stream.
#[derive(Debug, Clone)]
pub struct StreamUpdate {
    /// The player's side.
    pub report: StreamReport,
    /// The points refused since the last update (at most
    /// [`MAX_REFUSALS_PER_REPORT`]; the counters have them all).
    pub refused: Vec<Refusal>,
    /// The drives' actual positions (user units, stream order; `NaN`
    /// where none is known).
    pub actual: Vec<f64>,
    /// The axes' latest states (stream order; `None` before the first),
    /// for their signals.
    pub latest: Vec<Option<Arc<cangate_axis::cia402::AxisSnapshot>>>,
}

/// Where a stream plays: a bus's SYNC thread or a CANsmc master's cycle
/// thread.
#[derive(Clone)]
enum StreamTable {
    Sync(Arc<CyclicSetpoints>),
    Cansmc(Arc<CansmcSetpoints>),
}

impl StreamTable {
    fn push_points(&self, id: u64, points: Vec<StreamPoint>) -> Vec<(usize, PointRefused)> {
        match self {
            StreamTable::Sync(t) => t.push_points(id, points),
            StreamTable::Cansmc(t) => t.push_points(id, points),
        }
    }

    fn stop_stream(&self, id: u64, reason: StreamEnd) {
        match self {
            StreamTable::Sync(t) => t.stop_stream(id, reason),
            StreamTable::Cansmc(t) => t.stop_stream(id, reason),
        }
    }

    fn report(&self, id: u64) -> Option<StreamReport> {
        match self {
            StreamTable::Sync(t) => t.report(id),
            StreamTable::Cansmc(t) => t.report(id),
        }
    }

    fn close_stream(&self, id: u64, reason: StreamEnd) {
        match self {
            StreamTable::Sync(t) => t.close_stream(id, reason),
            StreamTable::Cansmc(t) => t.close_stream(id, reason),
        }
    }
}

/// An open stream. Dropping it brings its axes to rest (the client went
/// away).
pub struct SetpointStream {
    axes: Arc<Axes>,
    table: StreamTable,
    id: u64,
    idx: Vec<usize>,
    caller: Caller,
    report_period: Duration,
    kind: SetpointKind,
    /// Why it ended, once the session saw it end.
    end: Option<StreamEnd>,
    /// Per axis: whether a position stream's velocity and torque
    /// feed-forward reach the drive.
    feed_forward_sent: Vec<(bool, bool)>,
}

/// The mode a stream of `kind` plays in, for messages.
fn mode_name(kind: SetpointKind) -> &'static str {
    match kind {
        SetpointKind::Position => "csp",
        SetpointKind::Velocity => "csv",
        SetpointKind::Torque => "cst",
    }
}

impl Axes {
    /// Opens a set-point stream of `caller` over `req.axes`: cyclic (CSP)
    /// CiA 402 axes of one bus, or CANsmc axes of one master; each
    /// enabled, at rest, in no other stream, and controlled by the
    /// caller's lease.
    ///
    /// # Errors
    /// [`AxisError::NotFound`] for an unknown axis;
    /// [`AxisError::BadAxisList`] and [`CommandError::BadValue`] for an
    /// empty or repeated axis list, a depth or period out of range;
    /// [`AxisError::Lease`] without control; [`AxisError::NotStreamable`]
    /// for axes that cannot be streamed now.
    ///
    /// A torque stream (axes in cst) first gives each axis a torque
    /// command of 0: it releases the drive's halt and guards the axis
    /// while the stream plays (its velocity against `max_velocity`, a stop
    /// from where it is against the soft limits), as a SetTorque does;
    /// when that guard or a stop ends the command, the stream ends and its
    /// torques ramp to 0. Every end of a torque stream halts its drives.
    pub async fn open_setpoint_stream(
        self: &Arc<Self>,
        caller: &Caller,
        req: StreamRequest,
    ) -> Result<SetpointStream, AxisError> {
        if self.closing() {
            return Err(AxisError::ShuttingDown);
        }
        if req.axes.is_empty() {
            return Err(AxisError::BadAxisList(
                "name at least one axis to stream".into(),
            ));
        }
        let mut seen = HashSet::new();
        let mut idx = Vec::with_capacity(req.axes.len());
        for a in &req.axes {
            idx.push(self.index(a)?);
            if !seen.insert(a) {
                return Err(AxisError::BadAxisList(format!("axis {a} is named twice")));
            }
        }
        let bad = |m: String| AxisError::Refused(CommandError::BadValue(m));
        if req.depth.is_zero() || req.depth > MAX_DEPTH {
            return Err(bad(format!(
                "buffer depth {} ms: give 1 to {} ms",
                req.depth.as_millis(),
                MAX_DEPTH.as_millis()
            )));
        }
        let extrapolate = req.extrapolate.unwrap_or(req.depth);
        if extrapolate > MAX_EXTRAPOLATE {
            return Err(bad(format!(
                "extrapolation {} ms: give at most {} ms",
                extrapolate.as_millis(),
                MAX_EXTRAPOLATE.as_millis()
            )));
        }
        if let Some(p) = req.point_period
            && p > req.depth
        {
            return Err(bad(format!(
                "a point every {} µs needs a buffer of at least that: the depth is {} µs",
                p.as_micros(),
                req.depth.as_micros()
            )));
        }
        let report_period = req
            .report_period
            .unwrap_or(DEFAULT_REPORT_PERIOD)
            .clamp(MIN_REPORT_PERIOD, MAX_REPORT_PERIOD);
        self.check_lease_owner(&caller.lease, caller.identity.as_deref())?;
        for &i in &idx {
            self.authorize(i, &caller.lease)?;
        }
        let not = AxisError::NotStreamable;
        let first = &self.axes[idx[0]];
        let family = |e: &AxisEntry| match &e.spec.drive {
            DriveSpec::Cia402(_) => format!("a CiA 402 axis on bus {}", e.spec.bus()),
            DriveSpec::Cansmc(d) => format!("a CANsmc axis of master {}", d.master),
        };
        let mut limits = Vec::with_capacity(idx.len());
        let mut units = Vec::with_capacity(idx.len());
        let mut locals = Vec::with_capacity(idx.len());
        let mut positions = Vec::with_capacity(idx.len());
        let mut kind = None;
        for &i in &idx {
            let e = &self.axes[i];
            let name = &e.spec.name;
            match (&first.cansmc, &e.cansmc, &e.cyclic) {
                (Some(smc0), Some(smc), _) => {
                    if !Arc::ptr_eq(smc0, smc) {
                        return Err(not(format!(
                            "a set-point stream plays on one CANsmc master's cycle: {} is {}, \
                             {name} {}",
                            first.spec.name,
                            family(first),
                            family(e)
                        )));
                    }
                    if smc.in_stream(e.local) {
                        return Err(not(format!("axis {name} is already in a set-point stream")));
                    }
                }
                // The mode the axis runs in now is checked below: one
                // configured in profile position may run in CSP (SetMode).
                (None, None, Some((_, table))) => {
                    let Some((_, table0)) = &first.cyclic else {
                        return Err(not(format!("axis {} cannot be streamed", first.spec.name)));
                    };
                    if !Arc::ptr_eq(table, table0) {
                        return Err(not(format!(
                            "a set-point stream plays on one bus's SYNC: {} is on {}, {name} on {}",
                            first.spec.name,
                            first.spec.bus(),
                            e.spec.bus()
                        )));
                    }
                    if table.in_stream(e.local) {
                        return Err(not(format!("axis {name} is already in a set-point stream")));
                    }
                }
                _ => {
                    return Err(not(format!(
                        "a set-point stream plays on one bus's cycle: {} is {}, {name} {}; \
                         stream them separately",
                        first.spec.name,
                        family(first),
                        family(e)
                    )));
                }
            }
        }
        // The state of each axis once all are of one bus: a mixed list
        // hears of the mix first.
        for &i in &idx {
            let e = &self.axes[i];
            let name = &e.spec.name;
            let Some((snap, _)) = self.latest(i) else {
                return Err(not(format!(
                    "axis {name}: no process data from its drive yet"
                )));
            };
            if snap.state != Some(DriveState::OperationEnabled) || snap.node_lost.is_some() {
                return Err(not(format!(
                    "axis {name} is not enabled (enable it first: a stream needs operation \
                     enabled)"
                )));
            }
            // The mode now (SetMode may have changed it at run time) says
            // what the points carry: positions in cyclic synchronous
            // position, velocities in cyclic synchronous velocity.
            let axis_kind = match snap.mode {
                8 => SetpointKind::Position,
                9 => SetpointKind::Velocity,
                10 => SetpointKind::Torque,
                m => {
                    return Err(not(format!(
                        "axis {name} runs in mode {m} (0x6061): set-point streams play on axes \
                         in csp (positions), csv (velocities) or cst (torques)"
                    )));
                }
            };
            match kind {
                None => kind = Some(axis_kind),
                Some(k) if k != axis_kind => {
                    return Err(not(format!(
                        "axis {name} runs in {}, {} in {}: a stream carries positions (csp), \
                         velocities (csv) or torques (cst), not both; stream them separately",
                        mode_name(axis_kind),
                        first.spec.name,
                        mode_name(k)
                    )));
                }
                Some(_) => {}
            }
            if snap.activity != Activity::Idle || snap.velocity.abs() > e.spec.motion.rest_speed() {
                return Err(not(format!(
                    "axis {name} is moving or busy ({:?}): stop it or wait until it is at rest",
                    snap.activity
                )));
            }
            let m = &e.spec.motion;
            limits.push(match (axis_kind, &e.spec.drive) {
                (SetpointKind::Torque, DriveSpec::Cia402(d)) => {
                    if !d.torque.in_process_data {
                        return Err(not(format!(
                            "axis {name}: its process data has no target torque (0x6071): \
                             configure it with mode = \"cst\" to stream torques"
                        )));
                    }
                    AxisLimits::torque(d.torque.max_torque, d.torque.torque_slope)
                }
                _ => AxisLimits {
                    max_jerk: m.max_jerk,
                    max_velocity: m.max_velocity,
                    max_acceleration: m.max_acceleration,
                    stop_deceleration: m.stop_deceleration,
                    min_position: m.min_position,
                    max_position: m.max_position,
                },
            });
            units.push(m.units);
            locals.push(e.local);
            positions.push(snap.demand_position);
        }
        let kind = kind.unwrap_or_default();
        let mut feed_forward_sent = vec![(false, false); idx.len()];
        let (table, id) = match (&first.spec.drive, &first.cansmc, &first.cyclic) {
            (DriveSpec::Cansmc(d), Some(smc), _) => {
                let mut cfg = PlayerConfig::new(d.cycle_time, req.depth);
                cfg.extrapolate = extrapolate;
                let id = smc
                    .open_stream(&locals, limits, positions, cfg)
                    .map_err(not)?;
                (StreamTable::Cansmc(smc.clone()), id)
            }
            (_, _, Some((master, table))) => {
                let sync = master.sync_settings();
                if !sync.running || sync.period.is_zero() {
                    return Err(not(format!(
                        "the SYNC of bus {} is stopped: a stream plays on the SYNC",
                        first.spec.bus()
                    )));
                }
                let mut cfg = PlayerConfig::new(sync.period, req.depth);
                cfg.extrapolate = extrapolate;
                cfg.kind = kind;
                if kind == SetpointKind::Torque {
                    self.hold_torque_axes(&idx).await?;
                }
                let opened = table.open_stream(&locals, limits, units, cfg);
                let id = match opened {
                    Ok(id) => id,
                    Err(e) => {
                        if kind == SetpointKind::Torque {
                            for &i in &idx {
                                let _ = self.enqueue(i, AxisCommand::Stop);
                            }
                        }
                        return Err(not(e));
                    }
                };
                if kind == SetpointKind::Position {
                    let max_torque = idx
                        .iter()
                        .map(|&i| match &self.axes[i].spec.drive {
                            DriveSpec::Cia402(d) => d.torque.max_torque,
                            DriveSpec::Cansmc(_) => 0.0,
                        })
                        .collect();
                    table.set_feed_forward_torque_limits(id, max_torque);
                    feed_forward_sent =
                        locals.iter().map(|&l| table.feed_forward_sent(l)).collect();
                }
                (StreamTable::Sync(table.clone()), id)
            }
            _ => {
                return Err(not(format!("axis {} cannot be streamed", first.spec.name)));
            }
        };
        let names: Vec<&str> = idx.iter().map(|&i| self.name(i)).collect();
        tracing::info!(target: "cangate::audit", peer = %caller.name, axes = ?names, depth_ms = req.depth.as_millis() as u64, "set-point stream opened");
        Ok(SetpointStream {
            axes: self.clone(),
            table,
            id,
            idx,
            caller: caller.clone(),
            report_period,
            kind,
            end: None,
            feed_forward_sent,
        })
    }

    /// Gives each axis of a torque stream a torque command of 0 (halt
    /// released, guarded; see [`Axes::open_setpoint_stream`]); halts them
    /// again when one refuses.
    async fn hold_torque_axes(&self, idx: &[usize]) -> Result<(), AxisError> {
        let items = idx
            .iter()
            .map(|&i| (i, AxisCommand::SetTorque { per_mille: 0.0 }))
            .collect();
        let results = self.many(items, false).await?;
        let failed = results.into_iter().zip(idx).find_map(|(r, &i)| match r {
            Ok(r) if r.outcome.is_none() => None,
            Ok(r) => Some(AxisError::NotStreamable(format!(
                "axis {}: its torque command ended at once: {}",
                self.name(i),
                r.detail
            ))),
            Err(e) => Some(e),
        });
        if let Some(e) = failed {
            for &i in idx {
                let _ = self.enqueue(i, AxisCommand::Stop);
            }
            return Err(e);
        }
        Ok(())
    }
}

impl SetpointStream {
    /// Runs the stream until it ends and its axes are at rest: `inbound`
    /// are the client's messages (closed without [`StreamInput::End`]: the
    /// client went away), `out` takes the reports (one per report period,
    /// and one after a batch with refused points). Returns why it ended.
    pub async fn run(
        mut self,
        mut inbound: mpsc::Receiver<StreamInput>,
        out: mpsc::Sender<StreamUpdate>,
        shutdown: CancellationToken,
    ) -> StreamEnd {
        let mut tick = tokio::time::interval(self.report_period);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let mut input_open = true;
        let mut ending = false;
        let mut refused: Vec<Refusal> = Vec::new();
        let mut last_end = None;
        let mut renewed: Option<tokio::time::Instant> = None;
        loop {
            let mut report_now = false;
            tokio::select! {
                _ = shutdown.cancelled(), if last_end.is_none() => {
                    self.table.stop_stream(self.id, StreamEnd::ShuttingDown);
                }
                m = inbound.recv(), if input_open => match m {
                    Some(StreamInput::Points(points)) => {
                        if last_end.is_none() {
                            report_now = self.push(points, &mut refused, &mut renewed);
                        }
                    }
                    Some(StreamInput::End) => {
                        input_open = false;
                        ending = true;
                    }
                    None => {
                        input_open = false;
                        self.table.stop_stream(self.id, StreamEnd::ClientGone);
                    }
                },
                _ = tick.tick() => report_now = true,
            }
            if out.is_closed() {
                self.table.stop_stream(self.id, StreamEnd::ClientGone);
            }
            if let Err(why) = self.lease_held() {
                self.table.stop_stream(self.id, StreamEnd::LeaseLost(why));
            }
            let Some(report) = self.table.report(self.id) else {
                let end = last_end.unwrap_or(StreamEnd::ClientGone);
                self.end = Some(end.clone());
                return end;
            };
            if self.kind == SetpointKind::Torque
                && report.end.is_none()
                && report.events.contains(&PlayerEvent::Underrun)
            {
                // A torque stream's drives halt on an underrun: it ends.
                self.table.stop_stream(self.id, StreamEnd::Underrun);
            }
            if ending
                && report.end.is_none()
                && report.level.is_zero()
                && matches!(
                    report.state,
                    PlayerState::Extrapolating | PlayerState::Waiting
                )
            {
                // The playout passed the client's last point.
                self.table.stop_stream(self.id, StreamEnd::ClientEnded);
            }
            last_end.clone_from(&report.end);
            let finished = report.finished;
            if report_now || !report.events.is_empty() || finished {
                let update = StreamUpdate {
                    actual: self.actual(),
                    latest: self
                        .idx
                        .iter()
                        .map(|&i| self.axes.latest(i).map(|(s, _)| s))
                        .collect(),
                    refused: std::mem::take(&mut refused),
                    report,
                };
                // A client that does not read its reports holds the
                // session up no longer than a report period.
                if tokio::time::timeout(self.report_period, out.send(update))
                    .await
                    .is_err()
                {
                    tracing::warn!("set-point stream: the client does not read its reports");
                }
            }
            if finished {
                let end = last_end.unwrap_or(StreamEnd::ClientGone);
                self.end = Some(end.clone());
                return end;
            }
        }
    }

    /// Pushes `points`; true when some were refused (or the lease is gone).
    /// Renews the lease at most every [`RENEW_PERIOD`] (`renewed`: when it
    /// last did): each renewal wakes the lease expiry task, and a client
    /// may send a batch every millisecond. Between renewals every turn of
    /// the session checks that the lease still covers the axes.
    fn push(
        &self,
        points: Vec<StreamPoint>,
        refused: &mut Vec<Refusal>,
        renewed: &mut Option<tokio::time::Instant>,
    ) -> bool {
        let now = tokio::time::Instant::now();
        if renewed.is_none_or(|at| now.duration_since(at) >= RENEW_PERIOD) {
            *renewed = Some(now);
            for &i in &self.idx {
                if let Err(e) = self.axes.authorize(i, &self.caller.lease) {
                    self.table
                        .stop_stream(self.id, StreamEnd::LeaseLost(e.to_string()));
                    return true;
                }
            }
        }
        let times: Vec<u64> = points.iter().map(|p| p.t_us).collect();
        let r = self.table.push_points(self.id, points);
        let any = !r.is_empty();
        for (k, reason) in r {
            if refused.len() < MAX_REFUSALS_PER_REPORT {
                refused.push(Refusal {
                    t_us: times[k],
                    reason,
                });
            }
        }
        any
    }

    /// Whether the caller's lease still covers every axis (not renewing
    /// it).
    fn lease_held(&self) -> Result<(), String> {
        let leases = self.axes.leases.lock().expect("lease lock");
        for &i in &self.idx {
            let name = self.axes.name(i);
            match leases.holder_of(name) {
                Some(l) if l.token == self.caller.lease => {}
                Some(l) => return Err(format!("axis {name} is now controlled by {}", l.holder)),
                None => {
                    return Err(format!(
                        "axis {name} is no longer controlled (lease released or lapsed)"
                    ));
                }
            }
        }
        Ok(())
    }

    fn actual(&self) -> Vec<f64> {
        self.idx
            .iter()
            .map(|&i| self.axes.latest(i).map_or(f64::NAN, |(s, _)| s.position))
            .collect()
    }

    /// What the stream's points carry: positions (csp and CANsmc axes) or
    /// velocities (csv axes).
    pub fn kind(&self) -> SetpointKind {
        self.kind
    }

    /// Per axis of the stream: whether the feed-forward of a position
    /// stream reaches the drive, (velocity in 0x60B1, torque in 0x60B2).
    /// Feed-forward that does not is checked and not sent.
    pub fn feed_forward_sent(&self) -> &[(bool, bool)] {
        &self.feed_forward_sent
    }

    /// The stream's axes (global indices), in its order.
    pub fn axes(&self) -> &[usize] {
        &self.idx
    }
}

impl Drop for SetpointStream {
    fn drop(&mut self) {
        self.table.close_stream(self.id, StreamEnd::ClientGone);
        if self.kind == SetpointKind::Torque {
            // Every end of a torque stream halts its drives (their torque
            // is ramped to 0 by the stream meanwhile): with a halt when
            // the stream ended in order, else as the axis stops on a loss.
            let orderly = matches!(
                self.end,
                Some(
                    StreamEnd::ClientEnded
                        | StreamEnd::Underrun
                        | StreamEnd::TorqueGuard { .. }
                        | StreamEnd::Stopped { .. }
                )
            );
            for &i in &self.idx {
                let cmd = if orderly {
                    AxisCommand::Stop
                } else {
                    super::stop_command(self.axes.spec(i).stop_on_loss)
                };
                match self.axes.enqueue(i, cmd) {
                    // The shutdown stops every axis itself.
                    Ok(()) | Err(AxisError::ShuttingDown) => {}
                    Err(e) => {
                        tracing::error!(axis = %self.axes.name(i), error = %e, "torque stream ended: the drive could not be halted");
                    }
                }
            }
        }
    }
}
