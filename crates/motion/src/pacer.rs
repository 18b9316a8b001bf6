//! Even pacing of bursty handwheel units.

use std::collections::VecDeque;
use std::time::Duration;

use crate::{MotionError, check_limit};

/// Outcome of [`JogPacer::push`]. All counts are signed like the units they
/// count; `accepted + dropped == units` pushed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PushResult {
    /// Units queued for execution (sign of the push).
    pub accepted: i64,
    /// Units refused because the backlog was full (sign of the push). They
    /// are discarded, never executed later.
    pub dropped: i64,
    /// Units of the *opposite* direction that were still queued and have
    /// been discarded because the direction changed (sign of the old
    /// backlog; 0 if there was no reversal).
    pub flushed: i64,
}

/// Running totals of a [`JogPacer`] (magnitudes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PacerStats {
    /// Units accepted into the backlog.
    pub accepted: u64,
    /// Units refused because the backlog was full.
    pub dropped: u64,
    /// Queued units discarded by a direction change or [`JogPacer::clear`].
    pub flushed: u64,
    /// Queued units discarded because [`JogPacer::poll`] was called too late
    /// to execute them before their deadline (see [`JogPacer`]).
    pub expired: u64,
    /// Units returned by [`JogPacer::poll`].
    pub emitted: u64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Batch {
    count: u64,
    /// Latest time (seconds) at which these units may still be executed.
    deadline: f64,
}

/// Relative tolerance on slot times (rounding of `now` and slot arithmetic).
const SLOT_SLACK: f64 = 1e-9;

/// Default lateness tolerance of [`JogPacer::poll`] beyond the drain bound.
const DEFAULT_GRACE: Duration = Duration::from_millis(20);

/// Turns bursty signed units (handwheel detents, encoder counts) into an
/// even stream at a bounded rate with a bounded backlog.
///
/// # Schedule
/// Units are executed one per *slot*; slots are `1 / max_units_per_s`
/// apart. When units arrive on an empty backlog, the first slot is `now`,
/// or the slot after the last executed unit if that is later: idle time
/// never builds up credit, so a burst is never replayed as a burst.
/// [`poll`](JogPacer::poll) returns the units whose slots have come; polled
/// at least once per slot, it returns at most 1 unit per call with outputs
/// at least one slot apart, and over any interval at most
/// `rate × interval + 1` units.
///
/// # Backlog and overflow
/// At most `max_backlog` units wait. Units beyond that are **dropped** at
/// [`push`](JogPacer::push) and reported in [`PushResult::dropped`]: they are
/// never executed late.
///
/// # Direction changes
/// Units are signed. Pushing units of the opposite sign to the queued
/// backlog **flushes** the old backlog first (reported in
/// [`PushResult::flushed`]), then queues the new units. A handwheel reversal
/// means the operator wants to go back *now*; finishing the stale units
/// would overshoot by up to the whole backlog. The slot spacing is kept
/// across the reversal, so the output rate bound still holds.
///
/// # Stop guarantee
/// Every unit's slot is at most `max_backlog / rate` seconds
/// ([`drain_bound`](JogPacer::drain_bound)) after the push that accepted it
/// (the backlog holds at most `max_backlog` units, one slot each, and the
/// next slot is never more than one slot ahead of `now`). So once units stop
/// arriving, the last unit is due within `max_backlog / rate` of the last
/// push, and a caller polling every cycle `c` sees the backlog empty within
/// `max_backlog / rate + c`. As a safety net for a stalled caller, units
/// still queued past `drain_bound + grace` after their push are **expired**
/// (discarded, counted in [`PacerStats::expired`]) instead of executed
/// late; `grace` defaults to 20 ms ([`with_grace`](JogPacer::with_grace)).
/// A caller that polls late but within the grace gets the overdue units in
/// one call.
///
/// # Time
/// `now` is a [`Duration`] from an arbitrary monotonic origin; a `now`
/// earlier than one already seen is treated as the latest seen.
#[derive(Debug, Clone)]
pub struct JogPacer {
    rate: f64,
    period: f64,
    max_backlog: u32,
    grace: f64,
    /// Sign of the queued units (+1 or -1); meaningless when empty.
    direction: i64,
    backlog: u64,
    batches: VecDeque<Batch>,
    /// Slot `k` is at `anchor + k × period` seconds.
    anchor: f64,
    next_slot: u64,
    latest_now: f64,
    stats: PacerStats,
}

impl JogPacer {
    /// A pacer executing at most `max_units_per_s` units per second with at
    /// most `max_backlog` units waiting.
    ///
    /// # Errors
    /// [`MotionError::InvalidLimit`] if the rate is not finite and > 0 or
    /// `max_backlog` is 0.
    pub fn new(max_units_per_s: f64, max_backlog: u32) -> Result<Self, MotionError> {
        let rate = check_limit("max units per second", max_units_per_s)?;
        check_limit("max backlog", f64::from(max_backlog))?;
        Ok(Self {
            rate,
            period: 1.0 / rate,
            max_backlog,
            grace: DEFAULT_GRACE.as_secs_f64(),
            direction: 1,
            backlog: 0,
            batches: VecDeque::new(),
            anchor: f64::NEG_INFINITY,
            next_slot: 0,
            latest_now: f64::NEG_INFINITY,
            stats: PacerStats::default(),
        })
    }

    /// A pacer whose backlog is sized so that motion stops within `d` of
    /// the last push: `max_backlog = floor(d × max_units_per_s)`.
    ///
    /// # Errors
    /// [`MotionError::InvalidLimit`] if the rate is invalid or `d` holds
    /// less than one unit at that rate.
    pub fn stop_within(max_units_per_s: f64, d: Duration) -> Result<Self, MotionError> {
        let rate = check_limit("max units per second", max_units_per_s)?;
        let units = (d.as_secs_f64() * rate * (1.0 + SLOT_SLACK)).floor();
        let max_backlog = units.min(f64::from(u32::MAX)) as u32;
        if max_backlog == 0 {
            return Err(MotionError::InvalidLimit {
                name: "stop time × rate (max backlog)",
                value: units,
            });
        }
        Self::new(rate, max_backlog)
    }

    /// Set how late past [`drain_bound`](JogPacer::drain_bound) a queued
    /// unit may still be executed before it expires (default 20 ms).
    pub fn with_grace(mut self, grace: Duration) -> Self {
        self.grace = grace.as_secs_f64();
        self
    }

    /// Queue `units` (signed) arriving at `now`. See the type docs for the
    /// overflow and direction-change rules.
    pub fn push(&mut self, units: i64, now: Duration) -> PushResult {
        let now = self.observe(now);
        let mut result = PushResult::default();
        if units == 0 {
            return result;
        }
        let sign = units.signum();
        if self.backlog > 0 && sign != self.direction {
            result.flushed = self.flush();
        }
        if self.backlog == 0 {
            self.direction = sign;
            // No idle credit: the first unit goes at `now` at the earliest.
            if self.slot_time(self.next_slot) < now {
                self.anchor = now;
                self.next_slot = 0;
            }
        }
        let free = u64::from(self.max_backlog) - self.backlog;
        let accepted = units.unsigned_abs().min(free);
        if accepted > 0 {
            self.backlog += accepted;
            let deadline = now + f64::from(self.max_backlog) * self.period + self.grace;
            self.batches.push_back(Batch {
                count: accepted,
                deadline,
            });
        }
        // accepted <= max_backlog <= u32::MAX, so these conversions are exact.
        result.accepted = sign * accepted as i64;
        result.dropped = units - result.accepted;
        self.stats.accepted += accepted;
        self.stats.dropped += result.dropped.unsigned_abs();
        result
    }

    /// Signed number of units to execute now (0 if none is due).
    pub fn poll(&mut self, now: Duration) -> i64 {
        let now = self.observe(now);
        if self.backlog == 0 {
            return 0;
        }
        let elapsed_slots = ((now - self.anchor) / self.period + SLOT_SLACK).floor();
        if elapsed_slots.is_nan() || elapsed_slots < self.next_slot as f64 {
            return 0;
        }
        // Slots next_slot..=elapsed_slots are due.
        let due_slots = (elapsed_slots - self.next_slot as f64 + 1.0).min(self.backlog as f64);
        let due = due_slots as u64;
        let mut left = due;
        let mut emitted = 0u64;
        while left > 0 {
            let Some(front) = self.batches.front_mut() else {
                break;
            };
            let take = front.count.min(left);
            if front.deadline < now {
                self.stats.expired += take;
            } else {
                emitted += take;
            }
            front.count -= take;
            left -= take;
            if front.count == 0 {
                self.batches.pop_front();
            }
        }
        self.backlog -= due;
        self.next_slot += due;
        self.stats.emitted += emitted;
        // emitted <= max_backlog <= u32::MAX.
        self.direction * emitted as i64
    }

    /// Discard the whole backlog now (e.g. on an emergency stop); returns
    /// the signed number of units discarded.
    pub fn clear(&mut self) -> i64 {
        self.flush()
    }

    /// Signed number of units waiting.
    pub fn backlog(&self) -> i64 {
        self.direction * self.backlog as i64
    }

    /// The configured backlog capacity.
    pub fn max_backlog(&self) -> u32 {
        self.max_backlog
    }

    /// The configured rate in units per second.
    pub fn max_units_per_s(&self) -> f64 {
        self.rate
    }

    /// `max_backlog / rate`: the longest time between a push and the slot
    /// of any unit it queued, hence the longest the axis keeps moving after
    /// the last push (plus the caller's poll period).
    pub fn drain_bound(&self) -> Duration {
        Duration::try_from_secs_f64(f64::from(self.max_backlog) * self.period)
            .unwrap_or(Duration::MAX)
    }

    /// When the next queued unit is due, or `None` if the backlog is empty
    /// (for callers that schedule their next poll).
    pub fn next_due(&self) -> Option<Duration> {
        if self.backlog == 0 {
            return None;
        }
        Duration::try_from_secs_f64(self.slot_time(self.next_slot).max(self.latest_now).max(0.0))
            .ok()
    }

    /// Running totals.
    pub fn stats(&self) -> PacerStats {
        self.stats
    }

    fn slot_time(&self, k: u64) -> f64 {
        self.anchor + k as f64 * self.period
    }

    fn observe(&mut self, now: Duration) -> f64 {
        self.latest_now = self.latest_now.max(now.as_secs_f64());
        self.latest_now
    }

    fn flush(&mut self) -> i64 {
        let flushed = self.backlog();
        self.stats.flushed += self.backlog;
        self.backlog = 0;
        self.batches.clear();
        flushed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(x: u64) -> Duration {
        Duration::from_millis(x)
    }

    #[test]
    fn idle_time_builds_no_credit() {
        let mut p = JogPacer::new(1000.0, 100).unwrap();
        assert_eq!(p.poll(ms(5000)), 0);
        p.push(10, ms(10_000));
        assert_eq!(p.poll(ms(10_000)), 1);
        assert_eq!(p.poll(ms(10_000)), 0);
        assert_eq!(p.poll(ms(10_001)), 1);
        assert_eq!(p.backlog(), 8);
        assert_eq!(p.next_due(), Some(ms(10_002)));
    }

    #[test]
    fn reversal_flushes_the_old_direction() {
        let mut p = JogPacer::new(1000.0, 100).unwrap();
        p.push(50, ms(0));
        assert_eq!(p.poll(ms(0)), 1);
        let r = p.push(-3, ms(0));
        assert_eq!(
            r,
            PushResult {
                accepted: -3,
                dropped: 0,
                flushed: 49
            }
        );
        assert_eq!(p.backlog(), -3);
        // Rate still bounded across the reversal: next unit one slot later.
        assert_eq!(p.poll(ms(0)), 0);
        assert_eq!(p.poll(ms(1)), -1);
        assert_eq!(p.stats().flushed, 49);
    }

    #[test]
    fn late_poll_expires_instead_of_executing_late() {
        let mut p = JogPacer::new(1000.0, 10).unwrap().with_grace(ms(5));
        p.push(10, ms(0));
        // Deadline is 10 ms + 5 ms after the push.
        assert_eq!(p.poll(ms(100)), 0);
        assert_eq!(p.backlog(), 0);
        assert_eq!(p.stats().expired, 10);
        // Within the grace the overdue units come out together.
        p.push(10, ms(200));
        assert_eq!(p.poll(ms(212)), 10);
    }

    #[test]
    fn extreme_pushes_do_not_overflow() {
        let mut p = JogPacer::new(1.0, u32::MAX).unwrap();
        let r = p.push(i64::MIN, ms(0));
        assert_eq!(r.accepted, -i64::from(u32::MAX));
        assert_eq!(r.accepted + r.dropped, i64::MIN);
        let r = p.push(i64::MAX, ms(0));
        assert_eq!(r.flushed, -i64::from(u32::MAX));
        assert_eq!(r.accepted + r.dropped, i64::MAX);
    }

    #[test]
    fn invalid_configuration() {
        assert!(JogPacer::new(0.0, 10).is_err());
        assert!(JogPacer::new(f64::NAN, 10).is_err());
        assert!(JogPacer::new(10.0, 0).is_err());
        assert!(JogPacer::stop_within(10.0, ms(50)).is_err());
        let p = JogPacer::stop_within(1000.0, ms(250)).unwrap();
        assert_eq!(p.max_backlog(), 250);
        assert_eq!(p.drain_bound(), ms(250));
    }
}
