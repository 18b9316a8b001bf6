//! Where every feed unit of a wheel goes: the bindings' pacers and the
//! counters that account for each unit exactly once.
//!
//! A decoded unit is counted in [`BindingStats::units`] when it arrives and
//! then ends in exactly one place: executed, one of the dropped counters, or
//! still pending in a pacer. So at every moment
//! `units = executed + dropped_* + pending` ([`BindingStats::balance`]):
//! nothing is lost silently, not the units that arrive in automatic mode,
//! not those a mode change or a stalled task discards from a backlog.

use super::{Binding, BindingStats};
use cangate_canopen::handwheel::HandwheelAxis;
use cangate_motion::JogPacer;
use std::time::Duration;

/// What became of units handed to an axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Executed {
    /// The axis took them as a relative move.
    Done,
    /// The axis is not in operation enabled, or its node is lost.
    NotEnabled,
    /// The wheel does not hold control of the axis.
    NotControlled,
    /// The axis refused the move (its command queue is full, a limit).
    Refused,
}

/// The pacers of a wheel's bindings and their accounting.
#[derive(Debug)]
pub(crate) struct BindingLedger {
    /// By binding index; `None` when the binding's rate and backlog make no
    /// pacer (refused by the configuration check, kept for safety).
    pacers: Vec<Option<JogPacer>>,
    /// Each pacer's expired units already accounted for.
    expired_seen: Vec<u64>,
    stats: BindingStats,
}

impl BindingLedger {
    /// One pacer per binding: at most `max_units_per_s`, a backlog of
    /// `stop_within` worth of units.
    pub(crate) fn new(bindings: usize, max_units_per_s: f64, stop_within: Duration) -> Self {
        BindingLedger {
            pacers: (0..bindings)
                .map(|_| JogPacer::stop_within(max_units_per_s, stop_within).ok())
                .collect(),
            expired_seen: vec![0; bindings],
            stats: BindingStats::default(),
        }
    }

    /// Accounts for `units` (signed) of wheel axis `axis` arriving at `now`,
    /// and queues them on the axis's pacer when the wheel is in manual mode.
    pub(crate) fn feed(
        &mut self,
        bindings: &[Binding],
        axis: HandwheelAxis,
        units: i64,
        manual: bool,
        now: Duration,
    ) {
        let magnitude = units.unsigned_abs();
        if magnitude == 0 {
            return;
        }
        self.stats.units += magnitude;
        if !manual {
            self.stats.dropped_not_manual += magnitude;
            return;
        }
        let Some(k) = bindings.iter().position(|b| b.wheel_axis == axis) else {
            self.stats.dropped_unbound += magnitude;
            return;
        };
        let Some(p) = self.pacers.get_mut(k).and_then(Option::as_mut) else {
            self.stats.dropped_backlog += magnitude;
            return;
        };
        let r = p.push(units, now);
        // Units refused by a full backlog, and queued units of the other
        // direction discarded at a reversal: both never run late.
        self.stats.dropped_backlog += r.dropped.unsigned_abs() + r.flushed.unsigned_abs();
    }

    /// Discards every queued unit (mode change, the wheel rebooted).
    pub(crate) fn clear(&mut self) {
        for p in self.pacers.iter_mut().flatten() {
            self.stats.dropped_backlog += p.clear().unsigned_abs();
        }
    }

    /// Hands the units now due to `execute(binding index, signed units)`
    /// and accounts for the outcome; units the pacers let expire (the task
    /// polled too late) count as dropped by the backlog.
    pub(crate) fn poll(&mut self, now: Duration, mut execute: impl FnMut(usize, i64) -> Executed) {
        for (k, slot) in self.pacers.iter_mut().enumerate() {
            let Some(p) = slot else { continue };
            let units = p.poll(now);
            let expired = p.stats().expired;
            self.stats.dropped_backlog += expired - self.expired_seen[k];
            self.expired_seen[k] = expired;
            if units == 0 {
                continue;
            }
            let magnitude = units.unsigned_abs();
            match execute(k, units) {
                Executed::Done => self.stats.executed += magnitude,
                Executed::NotEnabled => self.stats.dropped_not_enabled += magnitude,
                Executed::NotControlled => self.stats.dropped_not_controlled += magnitude,
                Executed::Refused => self.stats.dropped_backlog += magnitude,
            }
        }
    }

    /// Sets why the bindings cannot move now ("" when they can).
    pub(crate) fn set_blocked(&mut self, why: String) {
        self.stats.blocked = why;
    }

    /// The counters now, with the units still queued as `pending`.
    pub(crate) fn stats(&self) -> BindingStats {
        let mut s = self.stats.clone();
        s.pending = self
            .pacers
            .iter()
            .flatten()
            .map(|p| p.backlog().unsigned_abs())
            .sum();
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn binding(axis: HandwheelAxis) -> Binding {
        Binding {
            wheel_axis: axis,
            axis: 0,
            axis_name: "X".into(),
            distance_per_unit: 0.001,
        }
    }

    #[test]
    fn units_in_automatic_mode_are_counted_as_dropped() {
        let bindings = [binding(HandwheelAxis::X)];
        let mut l = BindingLedger::new(1, 1000.0, Duration::from_millis(100));
        l.feed(&bindings, HandwheelAxis::X, 500, false, Duration::ZERO);
        l.feed(&bindings, HandwheelAxis::Y, -3, true, Duration::ZERO);
        let s = l.stats();
        assert_eq!(
            (s.units, s.dropped_not_manual, s.dropped_unbound, s.pending),
            (503, 500, 3, 0)
        );
        assert_eq!(s.balance(), 0);
    }

    #[test]
    fn cleared_and_expired_units_are_counted() {
        let bindings = [binding(HandwheelAxis::X)];
        let mut l = BindingLedger::new(1, 1000.0, Duration::from_millis(100));
        l.feed(&bindings, HandwheelAxis::X, 50, true, Duration::ZERO);
        assert_eq!(l.stats().pending, 50);
        l.clear();
        assert_eq!(l.stats().dropped_backlog, 50);
        // A task that stalls past the drain bound: the units expire.
        l.feed(
            &bindings,
            HandwheelAxis::X,
            80,
            true,
            Duration::from_secs(1),
        );
        l.poll(Duration::from_secs(5), |_, _| Executed::Done);
        let s = l.stats();
        assert_eq!(s.pending, 0);
        assert_eq!(s.executed + s.dropped_backlog, 130, "{s:?}");
        assert_eq!(s.balance(), 0, "{s:?}");
    }

    /// `units = executed + dropped + pending` after every step of random
    /// sequences of feed in both directions, mode changes, clears, polls
    /// with every outcome and stalls (fixed seeds; a failure names the seed
    /// and the steps).
    #[test]
    fn counters_add_up_under_random_sequences() {
        let bindings = [binding(HandwheelAxis::X), binding(HandwheelAxis::Z)];
        for seed in 1..=300u64 {
            let mut rng = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
            let mut next = move |n: u64| {
                rng ^= rng << 13;
                rng ^= rng >> 7;
                rng ^= rng << 17;
                rng % n
            };
            let mut l = BindingLedger::new(2, 2000.0, Duration::from_millis(50));
            let mut now = Duration::ZERO;
            let mut manual = true;
            let mut log = Vec::new();
            for _ in 0..200 {
                let step = next(10);
                log.push(step);
                match step {
                    0..=3 => {
                        let axis = HandwheelAxis::ALL[next(5) as usize];
                        let units = next(401) as i64 - 200;
                        l.feed(&bindings, axis, units, manual, now);
                    }
                    4 => manual = !manual,
                    5 => l.clear(),
                    6 => now += Duration::from_millis(next(500)),
                    _ => {
                        now += Duration::from_micros(next(3000));
                        let outcome = [
                            Executed::Done,
                            Executed::Done,
                            Executed::NotEnabled,
                            Executed::NotControlled,
                            Executed::Refused,
                        ][next(5) as usize];
                        l.poll(now, |_, _| outcome);
                    }
                }
                let s = l.stats();
                assert_eq!(s.balance(), 0, "seed {seed}, steps {log:?}: {s:?}");
            }
        }
    }
}
