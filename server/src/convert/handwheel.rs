//! Handwheels, feed events and their statistics as protobuf messages.

use crate::handwheel::{Handwheels, Mode, WheelFeed};
use cangate_canopen::handwheel::{
    BaselineReason, CounterLayout, Direction, FeedStats, HandwheelAxis,
};
use cangate_proto::v1 as pb;

pub(crate) fn axis_pb(a: HandwheelAxis) -> pb::WheelAxis {
    match a {
        HandwheelAxis::X => pb::WheelAxis::X,
        HandwheelAxis::Y => pb::WheelAxis::Y,
        HandwheelAxis::Z => pb::WheelAxis::Z,
        HandwheelAxis::W => pb::WheelAxis::W,
        HandwheelAxis::V => pb::WheelAxis::V,
    }
}

pub(crate) fn stats_pb(s: &FeedStats) -> pb::FeedStats {
    pb::FeedStats {
        frames: s.frames,
        positive_units: HandwheelAxis::ALL
            .iter()
            .map(|a| s.units(*a, Direction::Positive))
            .collect(),
        negative_units: HandwheelAxis::ALL
            .iter()
            .map(|a| s.units(*a, Direction::Negative))
            .collect(),
        gaps: s.gaps,
        compensated_units: s.compensated_units,
        duplicates: s.duplicates,
        bad_frames: s.bad_frames,
        baselines: s.baselines,
        baseline_resets: s.baseline_resets,
    }
}

pub(crate) fn mode_pb(m: Option<Mode>) -> pb::HandwheelMode {
    match m {
        None => pb::HandwheelMode::Unspecified,
        Some(Mode::Automatic) => pb::HandwheelMode::Automatic,
        Some(Mode::Manual) => pb::HandwheelMode::Manual,
    }
}

pub(crate) fn wheel_pb(m: &Handwheels, i: usize) -> pb::Handwheel {
    let w = m.wheel(i);
    let c = &w.config;
    let b = w.binding.lock().expect("binding lock").clone();
    pb::Handwheel {
        name: c.name.clone(),
        bus: c.bus.clone(),
        node: c.node,
        counter_layout: match w.layout {
            CounterLayout::Nibble => pb::CounterLayout::Nibble,
            CounterLayout::Bits6_7 => pb::CounterLayout::Bits67,
        } as i32,
        mode: mode_pb(*w.mode.lock().expect("mode lock")) as i32,
        node_lost: *w.node_lost.lock().expect("lock"),
        simulated: w.sim.is_some(),
        stats: Some(stats_pb(&w.stats.lock().expect("stats lock"))),
        bindings: w
            .bindings
            .iter()
            .map(|b| pb::AxisBinding {
                wheel_axis: axis_pb(b.wheel_axis) as i32,
                axis: b.axis_name.clone(),
                distance_per_unit: b.distance_per_unit,
            })
            .collect(),
        max_units_per_s: c.max_units_per_s,
        stop_within_ms: c.stop_within_ms,
        binding: Some(pb::BindingStats {
            executed_units: b.executed,
            dropped_backlog: b.dropped_backlog,
            dropped_not_enabled: b.dropped_not_enabled,
            dropped_not_controlled: b.dropped_not_controlled,
            dropped_unbound: b.dropped_unbound,
            blocked: b.blocked,
            units: b.units,
            dropped_not_manual: b.dropped_not_manual,
            pending_units: b.pending,
        }),
    }
}

pub(crate) fn baseline_note(r: BaselineReason) -> &'static str {
    match r {
        BaselineReason::Startup => "baseline: first frame",
        BaselineReason::HeartbeatLost => "baseline: after heartbeat loss",
        BaselineReason::DeviceRestart => "baseline: after the wheel rebooted",
        BaselineReason::ModeChange => "baseline: after a mode change",
        BaselineReason::MalformedFrame => "baseline: after a malformed frame",
        BaselineReason::Other => "baseline: after a gap in reception",
    }
}

pub(crate) fn event_pb(m: &Handwheels, f: &WheelFeed) -> pb::FeedEvent {
    let e = &f.event;
    let note = match (&e.error, e.baseline_reason) {
        (Some(err), _) => err.to_string(),
        (None, Some(r)) => baseline_note(r).to_string(),
        _ => String::new(),
    };
    pb::FeedEvent {
        handwheel: m.wheel(f.wheel).config.name.clone(),
        timestamp_us: f.at.0 / 1000,
        axis: e.axis.map_or(pb::WheelAxis::Unspecified, axis_pb) as i32,
        direction: match e.direction {
            Some(Direction::Positive) => 1,
            Some(Direction::Negative) => -1,
            None => 0,
        },
        units: e.units,
        compensated: e.compensated,
        sequence: u32::from(e.sequence.unwrap_or(0)),
        gap: u32::from(e.gap.unwrap_or(0)),
        duplicate: e.flags.duplicate,
        compensated_flag: e.flags.compensated,
        baseline: e.flags.baseline,
        bad: e.flags.bad,
        note,
        raw: u32::from(e.byte.unwrap_or(0)),
        frames: 1,
        lost_before: 0,
    }
}

/// Adds `b` into the window summary `a` (same wheel, axis and direction).
pub(crate) fn merge(a: &mut pb::FeedEvent, b: pb::FeedEvent) {
    a.units += b.units;
    a.compensated += b.compensated;
    a.frames += b.frames;
    a.duplicate |= b.duplicate;
    a.compensated_flag |= b.compensated_flag;
    a.baseline |= b.baseline;
    a.bad |= b.bad;
    a.sequence = b.sequence;
    a.gap = a.gap.max(b.gap);
    a.raw = b.raw;
    a.timestamp_us = b.timestamp_us;
    if a.note.is_empty() {
        a.note = b.note;
    }
}
