//! Waiting for an instant with little CPU: timed sleeps that end close to
//! their deadline, and a short active wait only for the rest.
//!
//! Why: a thread of the default policy sleeps up to its timer slack (50 µs
//! by default) longer than asked, plus the wake-up latency. Spinning
//! through that margin gives exact instants but costs CPU for every
//! deadline (an idle demo spent a third of a core that way). With a timer
//! slack of 1 µs ([`fine_timer_slack`]) the margin is the wake-up latency
//! alone, which [`SpinMargin`] measures as it goes, so the active part is
//! as short as this host allows, and longer again when the host gets busy.

use std::time::{Duration, Instant};

/// Asks the kernel to wake the calling thread's timed sleeps at most 1 µs
/// late on purpose (`PR_SET_TIMERSLACK`); the default lets it batch wakes
/// 50 µs late. Best effort: a refusal leaves the default.
pub fn fine_timer_slack() {
    let _ = nix::sys::prctl::set_timerslack(1_000);
}

/// How early to stop sleeping before a deadline, learnt from how late the
/// sleeps actually woke: the latest recent wake-up latency plus a margin,
/// within `[floor, ceiling]`. It rises at once when a sleep wakes late and
/// comes down by 1 µs per wait, so one late wake-up costs a little CPU for
/// a while instead of one late deadline per busy period.
#[derive(Debug, Clone)]
pub struct SpinMargin {
    margin: Duration,
    floor: Duration,
    ceiling: Duration,
}

/// Added to the measured wake-up latency.
const HEADROOM: Duration = Duration::from_micros(15);
/// How fast the margin comes down again, per wait.
const DECAY: Duration = Duration::from_micros(1);

impl SpinMargin {
    /// A margin between `floor` and `ceiling`, starting at `ceiling`.
    pub fn new(floor: Duration, ceiling: Duration) -> Self {
        let floor = floor.min(ceiling);
        SpinMargin {
            margin: ceiling,
            floor,
            ceiling,
        }
    }

    /// The current margin.
    pub fn margin(&self) -> Duration {
        self.margin
    }

    /// Records that a sleep asked to end at `asked` ended at `woke`.
    pub fn record(&mut self, asked: Instant, woke: Instant) {
        let late = woke.saturating_duration_since(asked);
        let wanted = late + HEADROOM;
        self.margin = self
            .margin
            .saturating_sub(DECAY)
            .max(wanted)
            .clamp(self.floor, self.ceiling);
    }

    /// Sleeps until the margin before `target`, then waits actively until
    /// `target`; learns from the sleep. Returns at once if `target` passed.
    pub fn wait_until(&mut self, target: Instant) {
        let now = Instant::now();
        if now >= target {
            return;
        }
        if target - now > self.margin {
            let asked = target - self.margin;
            std::thread::sleep(asked - now);
            self.record(asked, Instant::now());
        }
        while Instant::now() < target {
            std::hint::spin_loop();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn us(n: u64) -> Duration {
        Duration::from_micros(n)
    }

    #[test]
    fn the_margin_follows_late_wake_ups_at_once_and_decays_slowly() {
        let mut m = SpinMargin::new(us(20), us(200));
        assert_eq!(m.margin(), us(200));
        let t = Instant::now();
        // Punctual wakes bring it down 1 µs per wait, to the floor.
        for _ in 0..10 {
            m.record(t, t + us(2));
        }
        assert_eq!(m.margin(), us(190));
        for _ in 0..500 {
            m.record(t, t + us(2));
        }
        assert_eq!(m.margin(), us(20));
        // A late wake raises it at once, within the ceiling.
        m.record(t, t + us(80));
        assert_eq!(m.margin(), us(95));
        m.record(t, t + us(5_000));
        assert_eq!(m.margin(), us(200));
        // A wake reported before it was asked counts as punctual.
        m.record(t + us(10), t);
        assert_eq!(m.margin(), us(199));
    }

    #[test]
    fn waits_until_the_target_and_not_before() {
        fine_timer_slack();
        let mut m = SpinMargin::new(us(20), us(200));
        for _ in 0..5 {
            let target = Instant::now() + Duration::from_millis(2);
            m.wait_until(target);
            assert!(Instant::now() >= target);
        }
        // A target in the past returns at once.
        m.wait_until(Instant::now() - us(1));
    }
}
