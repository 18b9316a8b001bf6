//! The time a protocol core is given for a received frame: when it arrived,
//! not when its task got to read it.
//!
//! A core judges its peers by their timing (a heartbeat consumer, an SDO
//! timeout). A task held up by a loaded host reads frames that waited in
//! its queue; judged at the reading time, a heartbeat that came in time
//! looks late, and a device or master would declare a healthy peer lost
//! for its own delay. Every frame carries the wall-clock time it arrived
//! ([`Frame::timestamp`]: the kernel's receive time on SocketCAN, the end of
//! transmission on the virtual bus), so its age tells how long before the
//! task's `now` it came. The times given never go back, so a core sees them
//! in order with its ticks.

use std::time::Duration;

use crate::frame::{Frame, Timestamp};

/// Turns a task's clock and frames' arrival stamps into the
/// non-decreasing times it hands its core (see the module documentation).
#[derive(Debug, Default, Clone)]
pub struct ArrivalClock {
    last: Duration,
}

impl ArrivalClock {
    /// The time to give the core for `frame`, read at the task's `now`
    /// (its own clock, e.g. since it started) when the wall clock reads
    /// `wall_now`. A frame without a stamp, or stamped after `wall_now` (a
    /// wall clock stepped back), counts as arriving at `now`; none is
    /// earlier than the last time given.
    pub fn frame_time(&mut self, now: Duration, frame: &Frame, wall_now: Timestamp) -> Duration {
        let stamped = frame.timestamp().as_nanos();
        let age = if stamped == 0 {
            Duration::ZERO
        } else {
            Duration::from_nanos(wall_now.as_nanos().saturating_sub(stamped))
        };
        self.time(now.saturating_sub(age))
    }

    /// The time to give the core for anything else that happens at `now`
    /// (a tick, a command): `now`, or the last time given if later.
    pub fn time(&mut self, now: Duration) -> Duration {
        self.last = self.last.max(now);
        self.last
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::CanId;

    fn stamped(ns: u64) -> Frame {
        Frame::new(CanId::Standard(0x77F), &[0x05])
            .unwrap()
            .with_timestamp(Timestamp(ns))
    }

    const WALL: u64 = 1_800_000_000_000_000_000;

    #[test]
    fn a_frame_read_late_is_given_its_arrival_time() {
        let mut clock = ArrivalClock::default();
        // Read at 1.000 s of the task's clock, 350 ms after it arrived.
        let t = clock.frame_time(
            Duration::from_millis(1000),
            &stamped(WALL - 350_000_000),
            Timestamp(WALL),
        );
        assert_eq!(t, Duration::from_millis(650));
    }

    #[test]
    fn times_never_go_back() {
        let mut clock = ArrivalClock::default();
        assert_eq!(
            clock.time(Duration::from_millis(700)),
            Duration::from_millis(700)
        );
        // Arrived at 650 ms, after a tick at 700 ms was given: 700 ms.
        let t = clock.frame_time(
            Duration::from_millis(1000),
            &stamped(WALL - 350_000_000),
            Timestamp(WALL),
        );
        assert_eq!(t, Duration::from_millis(700));
        assert_eq!(
            clock.time(Duration::from_millis(690)),
            Duration::from_millis(700)
        );
        assert_eq!(
            clock.time(Duration::from_millis(1000)),
            Duration::from_millis(1000)
        );
    }

    #[test]
    fn unstamped_future_and_ancient_frames() {
        let mut clock = ArrivalClock::default();
        let now = Duration::from_millis(500);
        let unstamped = Frame::new(CanId::Standard(0x77F), &[0x05]).unwrap();
        assert_eq!(clock.frame_time(now, &unstamped, Timestamp(WALL)), now);
        // Stamped after the wall clock's reading: arrives now.
        let mut clock = ArrivalClock::default();
        assert_eq!(
            clock.frame_time(now, &stamped(WALL + 5), Timestamp(WALL)),
            now
        );
        // Older than the task's clock: its start.
        let mut clock = ArrivalClock::default();
        assert_eq!(
            clock.frame_time(now, &stamped(WALL - 2_000_000_000), Timestamp(WALL)),
            Duration::ZERO
        );
    }
}
