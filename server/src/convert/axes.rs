//! Axis state, events and outcomes as protobuf messages.

use crate::axes::{Axes, AxisEventKind};
use cangate_axis::cia402::AxisSnapshot;
use cangate_axis::{Activity, Outcome};
use cangate_can::Timestamp;
use cangate_canopen::cia402::DriveState;
use cangate_proto::v1 as pb;

/// The slowest velocity (or acceleration) a drive can carry out: one
/// count per second (per second²). Below it the set-point rounds to zero
/// and a move would never end.
pub(crate) fn resolution(counts_per_unit: f64) -> f64 {
    1.0 / counts_per_unit.abs()
}

pub(crate) fn outcome_pb(o: Option<Outcome>) -> pb::Outcome {
    match o {
        None => pb::Outcome::Accepted,
        Some(Outcome::Completed) => pb::Outcome::Completed,
        Some(Outcome::Superseded) => pb::Outcome::Superseded,
        Some(Outcome::Fault) => pb::Outcome::Fault,
        Some(Outcome::Timeout) => pb::Outcome::Timeout,
        Some(Outcome::Stopped) => pb::Outcome::Stopped,
    }
}

pub(crate) fn state_pb(s: Option<DriveState>) -> pb::DriveState {
    match s {
        None | Some(DriveState::Unknown) => pb::DriveState::Unspecified,
        Some(DriveState::NotReadyToSwitchOn) => pb::DriveState::NotReadyToSwitchOn,
        Some(DriveState::SwitchOnDisabled) => pb::DriveState::SwitchOnDisabled,
        Some(DriveState::ReadyToSwitchOn) => pb::DriveState::ReadyToSwitchOn,
        Some(DriveState::SwitchedOn) => pb::DriveState::SwitchedOn,
        Some(DriveState::OperationEnabled) => pb::DriveState::OperationEnabled,
        Some(DriveState::QuickStopActive) => pb::DriveState::QuickStopActive,
        Some(DriveState::FaultReactionActive) => pb::DriveState::FaultReactionActive,
        Some(DriveState::Fault) => pb::DriveState::Fault,
    }
}

pub(crate) fn activity_pb(a: Activity) -> pb::AxisActivity {
    match a {
        Activity::Idle => pb::AxisActivity::Idle,
        Activity::Switching => pb::AxisActivity::Switching,
        Activity::Homing => pb::AxisActivity::Homing,
        Activity::Moving => pb::AxisActivity::Moving,
        Activity::Jogging => pb::AxisActivity::Jogging,
        Activity::Stopping => pb::AxisActivity::Stopping,
    }
}

pub(crate) fn status_pb(
    m: &Axes,
    i: usize,
    s: Option<&AxisSnapshot>,
    at: Timestamp,
) -> pb::AxisStatus {
    let (controlled_by, lease_remaining_ms) =
        m.control(i).map_or((String::new(), 0), |(h, left)| {
            (h, left.as_millis().min(u128::from(u32::MAX)) as u32)
        });
    let mut st = pb::AxisStatus {
        axis: m.name(i).to_string(),
        controlled_by,
        lease_remaining_ms,
        timestamp_us: at.0 / 1000,
        ..Default::default()
    };
    if let Some(s) = s {
        st.state = state_pb(s.state) as i32;
        st.statusword = u32::from(s.statusword);
        st.mode = i32::from(s.mode);
        st.activity = activity_pb(s.activity) as i32;
        st.position = s.position;
        st.velocity = s.velocity;
        st.demand_position = s.demand_position;
        st.following_error = s.following_error;
        st.homed = s.homed;
        st.node_lost = s.node_lost.is_some();
        if let Some((code, text)) = &s.fault {
            st.fault_code = u32::from(*code);
            st.fault_text = text.clone();
        }
        st.torque_actual = s.signals.torque.map(i32::from);
        st.following_error_actual = s.signals.following_error;
        st.digital_inputs = s.signals.digital_inputs.map(digital_inputs_pb);
        st.touch_probe_status = s.signals.touch_probe_status.map(u32::from);
    } else {
        st.node_lost = true;
        st.fault_text = "no process data from the drive yet".into();
    }
    st
}

/// 0x60FD as named booleans (CiA 402-2 bit layout, see
/// [`cangate_axis::signals`]).
pub(crate) fn digital_inputs_pb(raw: u32) -> pb::DigitalInputs {
    use cangate_axis::signals::{HOME_SWITCH, NEGATIVE_LIMIT_SWITCH, POSITIVE_LIMIT_SWITCH};
    pb::DigitalInputs {
        negative_limit_switch: raw & NEGATIVE_LIMIT_SWITCH != 0,
        positive_limit_switch: raw & POSITIVE_LIMIT_SWITCH != 0,
        home_switch: raw & HOME_SWITCH != 0,
        raw,
    }
}

/// The signals of one axis of a set-point stream.
pub(crate) fn stream_signals_pb(s: Option<&AxisSnapshot>) -> pb::StreamAxisSignals {
    let Some(s) = s else {
        return pb::StreamAxisSignals::default();
    };
    pb::StreamAxisSignals {
        torque_actual: s.signals.torque.map(i32::from),
        velocity_actual: s.state.is_some().then_some(s.velocity),
        following_error_actual: s.signals.following_error,
        digital_inputs: s.signals.digital_inputs.map(digital_inputs_pb),
    }
}

pub(crate) fn event_pb(m: &Axes, axis: usize, at: Timestamp, e: AxisEventKind) -> pb::AxisEvent {
    use pb::axis_event::Kind;
    let kind = match e {
        AxisEventKind::MotionDone {
            command,
            outcome,
            detail,
        } => Kind::MotionDone(pb::MotionDone {
            command: command.name().to_string(),
            outcome: outcome_pb(Some(outcome)) as i32,
            detail,
        }),
        AxisEventKind::Fault { code, text } => Kind::Fault(pb::Fault {
            // The axis layer reports a clearing as code 0 with no text;
            // every fault and lost node carries a text.
            active: code != 0 || !text.is_empty(),
            code: u32::from(code),
            text,
        }),
        AxisEventKind::Control {
            holder,
            previous,
            reason,
        } => Kind::Control(pb::ControlChange {
            holder,
            previous,
            reason,
        }),
        AxisEventKind::Node { lost, reason } => Kind::Node(pb::NodeLink { lost, reason }),
        AxisEventKind::TouchProbe { rising, position } => Kind::TouchProbe(pb::TouchProbeLatch {
            probe: 1,
            edge: if rising {
                pb::TouchProbeEdge::Rising
            } else {
                pb::TouchProbeEdge::Falling
            } as i32,
            position,
        }),
    };
    pb::AxisEvent {
        axis: m.name(axis).to_string(),
        timestamp_us: at.0 / 1000,
        kind: Some(kind),
    }
}
