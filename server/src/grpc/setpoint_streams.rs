//! `Axes.StreamSetpoints` at the edge: the client's messages become
//! [`StreamInput`]s, the runtime's [`StreamUpdate`]s become
//! `SetpointStreamStatus` messages. The stream's rules (buffer, limits,
//! lease, stops) are the runtime's ([`crate::axes::setpoint_streams`]).

use super::error::ApiError;
use super::forward::{MessageStream, stream_of};
use crate::axes::cyclic_setpoints::StreamEnd;
use crate::axes::setpoint_streams::{StreamInput, StreamRequest, StreamUpdate};
use crate::axes::{Axes, Caller};
use cangate_axis::setpoint_stream::{
    FeedForward, PlayerEvent, PlayerState, PointRefused, SetpointKind, StreamPoint,
};
use cangate_can::Timestamp;
use cangate_proto::v1 as pb;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;
use tonic::{Code, Status};

/// How long a client may take to send its SetpointStreamOpen.
pub const OPEN_TIMEOUT: Duration = Duration::from_secs(10);

fn protocol(message: impl Into<String>) -> Status {
    ApiError::refused(
        Code::InvalidArgument,
        "SETPOINT_STREAM_PROTOCOL",
        message,
        vec![],
    )
    .into()
}

/// Serves one StreamSetpoints call of `caller` (its lease comes with the
/// open message).
pub async fn serve(
    axes: Arc<Axes>,
    caller: Caller,
    mut inbound: tonic::Streaming<pb::SetpointStreamRequest>,
    shutdown: CancellationToken,
) -> Result<MessageStream<pb::SetpointStreamStatus>, Status> {
    use pb::setpoint_stream_request::Message;
    let first = tokio::select! {
        _ = shutdown.cancelled() => return Err(ApiError::ShuttingDown.into()),
        m = tokio::time::timeout(OPEN_TIMEOUT, inbound.message()) => m,
    };
    let open = match first {
        Err(_) => {
            return Err(protocol(format!(
                "no SetpointStreamOpen within {} s",
                OPEN_TIMEOUT.as_secs()
            )));
        }
        Ok(Err(status)) => return Err(status),
        Ok(Ok(Some(pb::SetpointStreamRequest {
            message: Some(Message::Open(open)),
        }))) => open,
        Ok(Ok(_)) => {
            return Err(protocol("the first message must be a SetpointStreamOpen"));
        }
    };
    let n = open.axes.len();
    let request = StreamRequest {
        axes: open.axes,
        depth: Duration::from_millis(u64::from(open.depth_ms)),
        extrapolate: (open.extrapolate_ms > 0)
            .then(|| Duration::from_millis(u64::from(open.extrapolate_ms))),
        point_period: (open.point_period_us > 0)
            .then(|| Duration::from_micros(u64::from(open.point_period_us))),
        report_period: (open.status_period_ms > 0)
            .then(|| Duration::from_millis(u64::from(open.status_period_ms))),
    };
    let names = request.axes.clone();
    let caller = caller.with_lease(open.lease);
    let stream = axes
        .open_setpoint_stream(&caller, request)
        .await
        .map_err(ApiError::from)?;
    let kind = stream.kind();
    let feed_forward_sent = stream.feed_forward_sent().to_vec();
    let (in_tx, in_rx) = mpsc::channel(64);
    let (up_tx, mut up_rx) = mpsc::channel(16);
    let (tx, rx) = mpsc::channel(16);
    let protocol_tx = tx.clone();
    tokio::spawn(async move {
        loop {
            let batch = match inbound.message().await {
                Ok(Some(pb::SetpointStreamRequest {
                    message: Some(Message::Batch(b)),
                })) => b,
                Ok(Some(_)) => {
                    let _ = protocol_tx
                        .send(Err(protocol(
                            "after the SetpointStreamOpen every message must be a SetpointBatch",
                        )))
                        .await;
                    return;
                }
                Ok(None) => {
                    let _ = in_tx.send(StreamInput::End).await;
                    return;
                }
                // The client went away: dropping `in_tx` says so.
                Err(_) => return,
            };
            match points(batch, n, kind) {
                Ok(p) => {
                    if in_tx.send(StreamInput::Points(p)).await.is_err() {
                        return;
                    }
                }
                Err(m) => {
                    let _ = protocol_tx.send(Err(protocol(m))).await;
                    return;
                }
            }
        }
    });
    tokio::spawn(async move {
        stream.run(in_rx, up_tx, shutdown).await;
    });
    tokio::spawn(async move {
        while let Some(u) = up_rx.recv().await {
            let end = u.report.end.clone();
            let finished = u.report.finished;
            let mut status = status_pb(&names, kind, u);
            status.velocity_feed_forward_sent = feed_forward_sent.iter().map(|f| f.0).collect();
            status.torque_feed_forward_sent = feed_forward_sent.iter().map(|f| f.1).collect();
            if tx.send(Ok(status)).await.is_err() {
                return;
            }
            if finished {
                if let Some(end) = end
                    && end != StreamEnd::ClientEnded
                {
                    let _ = tx
                        .send(Err(ApiError::refused(
                            Code::Aborted,
                            "SETPOINT_STREAM_ENDED",
                            end.to_string(),
                            vec![("ended", end_reason(&end).to_string())],
                        )
                        .into()))
                        .await;
                }
                return;
            }
        }
    });
    Ok(stream_of(rx))
}

/// The points of a batch: positions (their feed-forward checked) for a
/// position stream, velocities for a velocity stream, torques for a
/// torque stream.
fn points(
    batch: pb::SetpointBatch,
    axes: usize,
    kind: SetpointKind,
) -> Result<Vec<StreamPoint>, String> {
    batch
        .points
        .into_iter()
        .map(|p| {
            if kind == SetpointKind::Torque {
                if !p.positions.is_empty() || !p.velocities.is_empty() {
                    return Err(format!(
                        "point at {} µs: the stream's axes run in cst: a point carries one \
                         torque per axis in `torques`, no positions nor velocities",
                        p.t_us
                    ));
                }
                return Ok(StreamPoint {
                    feed_forward: None,
                    t_us: p.t_us,
                    values: p.torques,
                });
            }
            if kind == SetpointKind::Velocity {
                if !p.torques.is_empty() {
                    return Err(format!(
                        "point at {} µs: the stream's axes run in csv: a point carries one \
                         velocity per axis in `velocities`, no torques",
                        p.t_us
                    ));
                }
                if !p.positions.is_empty() {
                    return Err(format!(
                        "point at {} µs: the stream's axes run in csv: a point carries one \
                         velocity per axis in `velocities`, no positions",
                        p.t_us
                    ));
                }
                return Ok(StreamPoint {
                    feed_forward: None,
                    t_us: p.t_us,
                    values: p.velocities,
                });
            }
            if !p.velocities.is_empty()
                && (p.velocities.len() != axes || p.velocities.iter().any(|v| !v.is_finite()))
            {
                return Err(format!(
                    "point at {} µs: velocity feed-forward must be empty or one finite value per \
                     axis ({axes}), got {:?}",
                    p.t_us, p.velocities
                ));
            }
            if !p.torques.is_empty()
                && (p.velocities.is_empty()
                    || p.torques.len() != axes
                    || p.torques.iter().any(|v| !v.is_finite()))
            {
                return Err(format!(
                    "point at {} µs: torque feed-forward must be empty or one finite value per \
                     axis ({axes}), with the velocity feed-forward, got {:?}",
                    p.t_us, p.torques
                ));
            }
            Ok(StreamPoint {
                feed_forward: (!p.velocities.is_empty()).then_some(FeedForward {
                    velocities: p.velocities,
                    torques: p.torques,
                }),
                t_us: p.t_us,
                values: p.positions,
            })
        })
        .collect()
}

fn end_reason(e: &StreamEnd) -> &'static str {
    match e {
        StreamEnd::ClientEnded => "CLIENT_ENDED",
        StreamEnd::ClientGone => "CLIENT_GONE",
        StreamEnd::Stopped { .. } => "STOPPED",
        StreamEnd::LeaseLost(_) => "LEASE_LOST",
        StreamEnd::AxisLeft { .. } => "AXIS_LEFT",
        StreamEnd::LimitSwitch { .. } => "LIMIT_SWITCH",
        StreamEnd::TorqueGuard { .. } => "TORQUE_GUARD",
        StreamEnd::Underrun => "UNDERRUN",
        StreamEnd::ShuttingDown => "SHUTTING_DOWN",
    }
}

fn end_axis(e: &StreamEnd) -> &str {
    match e {
        StreamEnd::Stopped { axis }
        | StreamEnd::AxisLeft { axis }
        | StreamEnd::LimitSwitch { axis, .. }
        | StreamEnd::TorqueGuard { axis, .. } => axis,
        _ => "",
    }
}

/// The stable reason of a refused point and the axis it names.
fn refusal_reason(r: &PointRefused) -> (&'static str, Option<usize>) {
    match r {
        PointRefused::Dimension { .. } => ("DIMENSION", None),
        PointRefused::NotFinite { axis, .. } => ("NOT_FINITE", Some(*axis)),
        PointRefused::NotAfterPrevious { .. } => ("NOT_AFTER_PREVIOUS", None),
        PointRefused::BeyondSoftLimit { axis, .. } => ("BEYOND_SOFT_LIMIT", Some(*axis)),
        PointRefused::TooFast { axis, .. } => ("TOO_FAST", Some(*axis)),
        PointRefused::TooHardAcceleration { axis, .. } => ("TOO_HARD_ACCELERATION", Some(*axis)),
        PointRefused::TooHardJerk { axis, .. } => ("TOO_HARD_JERK", Some(*axis)),
        PointRefused::NotFromRest { axis, .. } | PointRefused::TorqueNotFromZero { axis, .. } => {
            ("NOT_FROM_REST", Some(*axis))
        }
        PointRefused::TorqueAboveMax { axis, .. } => ("TORQUE_ABOVE_MAX", Some(*axis)),
        PointRefused::TorqueTooSteep { axis, .. } => ("TORQUE_TOO_STEEP", Some(*axis)),
        PointRefused::NotWhereTheAxisStands { axis, .. } => {
            ("NOT_WHERE_THE_AXIS_STANDS", Some(*axis))
        }
    }
}

fn status_pb(names: &[String], kind: SetpointKind, u: StreamUpdate) -> pb::SetpointStreamStatus {
    use pb::SetpointEventKind as K;
    let r = &u.report;
    let state = if r.finished {
        pb::SetpointStreamState::SetpointStreamEnded
    } else {
        match r.state {
            PlayerState::Waiting => pb::SetpointStreamState::SetpointStreamWaiting,
            PlayerState::Filling => pb::SetpointStreamState::SetpointStreamFilling,
            PlayerState::Playing => pb::SetpointStreamState::SetpointStreamPlaying,
            PlayerState::Extrapolating => pb::SetpointStreamState::SetpointStreamExtrapolating,
            PlayerState::Stopping => pb::SetpointStreamState::SetpointStreamStopping,
        }
    };
    let axis_name = |a: Option<usize>| a.and_then(|a| names.get(a)).cloned().unwrap_or_default();
    let mut events: Vec<pb::SetpointStreamEvent> = u
        .refused
        .iter()
        .map(|f| {
            let (reason, axis) = refusal_reason(&f.reason);
            pb::SetpointStreamEvent {
                kind: K::SetpointEventPointRefused as i32,
                reason: reason.into(),
                axis: axis_name(axis),
                t_us: f.t_us,
                detail: format!("point at {} µs refused: {}", f.t_us, f.reason),
            }
        })
        .collect();
    for e in &r.events {
        let (kind, detail) = match e {
            PlayerEvent::Underrun => (
                K::SetpointEventUnderrun,
                "no point came in time: the axes ramp to rest (send a point where they stand to \
                 resume)",
            ),
            PlayerEvent::AtRest => (K::SetpointEventAtRest, "the axes are at rest"),
        };
        events.push(pb::SetpointStreamEvent {
            kind: kind as i32,
            reason: String::new(),
            axis: String::new(),
            t_us: 0,
            detail: detail.into(),
        });
    }
    let ended = match (&r.end, r.finished) {
        (Some(e), true) => {
            events.push(pb::SetpointStreamEvent {
                kind: K::SetpointEventEnded as i32,
                reason: end_reason(e).into(),
                axis: end_axis(e).into(),
                t_us: 0,
                detail: e.to_string(),
            });
            end_reason(e).to_string()
        }
        _ => String::new(),
    };
    let c = r.counters;
    pb::SetpointStreamStatus {
        state: state as i32,
        buffer_level_us: r.level.as_micros() as u64,
        counters: Some(pb::SetpointCounters {
            received: c.received,
            accepted: c.accepted,
            refused: c.refused,
            played: c.played,
            late: c.late,
            dropped: c.dropped,
            underruns: c.underruns,
            limited: c.limited,
        }),
        clock_offset_us: r.clock_offset_us.unwrap_or(0),
        commanded_positions: if kind == SetpointKind::Torque {
            Vec::new()
        } else {
            r.positions.clone()
        },
        commanded_torques: if kind == SetpointKind::Torque {
            r.positions.clone()
        } else {
            Vec::new()
        },
        velocity_feed_forward_sent: Vec::new(),
        torque_feed_forward_sent: Vec::new(),
        actual_positions: u.actual,
        signals: u
            .latest
            .iter()
            .map(|s| crate::convert::axes::stream_signals_pb(s.as_deref()))
            .collect(),
        events,
        timestamp_us: Timestamp::now().0 / 1000,
        ended,
    }
}
