//! SYNC producer (CiA 301 §7.2.5) and the drift-free [`Periodic`] schedule
//! shared by the periodic producers of this crate (SYNC, heartbeat).
//!
//! The producer sends COB-ID 0x080 every communication cycle period
//! (object 0x1006), either with no data or, when the synchronous counter
//! overflow value (object 0x1019) is 2..=240, with a one-byte counter that
//! runs 1..=overflow and wraps back to 1.
//!
//! Deadlines are `origin + k × period`: a late tick never shifts later
//! deadlines, and periods that passed entirely while the runner was late are
//! skipped (not sent in a burst) and counted.

use std::time::Duration;

use cangate_can::{CanId, Frame};

use crate::ids::cob;

/// A drift-free periodic schedule: deadlines at `origin + k × period` for
/// `k = 1, 2, …`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Periodic {
    origin: Duration,
    period: Duration,
    /// Index of the next deadline.
    k: u64,
}

impl Periodic {
    /// A schedule whose first deadline is `origin + period`.
    ///
    /// A zero `period` is treated as 1 ns so the schedule always advances.
    pub fn new(origin: Duration, period: Duration) -> Self {
        let period = period.max(Duration::from_nanos(1));
        Periodic {
            origin,
            period,
            k: 1,
        }
    }

    /// The period.
    pub fn period(&self) -> Duration {
        self.period
    }

    /// When the next deadline falls.
    pub fn next_deadline(&self) -> Duration {
        self.at(self.k)
    }

    /// If a deadline is due at `now`, consumes every deadline up to `now` and
    /// returns how many of them were skipped (all but the latest one);
    /// otherwise `None`.
    pub fn poll(&mut self, now: Duration) -> Option<u64> {
        if now < self.next_deadline() {
            return None;
        }
        let elapsed = now.saturating_sub(self.origin).as_nanos();
        let latest = u64::try_from(elapsed / self.period.as_nanos()).unwrap_or(u64::MAX);
        let skipped = latest.saturating_sub(self.k);
        self.k = latest.saturating_add(1);
        Some(skipped)
    }

    fn at(&self, k: u64) -> Duration {
        let nanos = self.period.as_nanos().saturating_mul(u128::from(k));
        let offset = Duration::new(
            u64::try_from(nanos / 1_000_000_000).unwrap_or(u64::MAX),
            (nanos % 1_000_000_000) as u32,
        );
        self.origin.saturating_add(offset)
    }
}

/// An invalid SYNC producer configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SyncConfigError {
    /// A zero communication cycle period.
    #[error("SYNC period must be greater than zero")]
    ZeroPeriod,
    /// A counter overflow value other than 0 or 2..=240 (0x1019).
    #[error("SYNC counter overflow value {0} is reserved (use 0 for no counter or 2..=240)")]
    BadOverflow(u8),
}

/// The SYNC producer.
#[derive(Debug, Clone)]
pub struct SyncProducer {
    period: Duration,
    overflow: u8,
    /// Counter value of the next SYNC (1..=overflow) when the counter is on.
    counter: u8,
    schedule: Option<Periodic>,
    sent: u64,
    skipped: u64,
}

impl SyncProducer {
    /// A stopped producer with the given period and counter overflow value
    /// (0 = no counter, 2..=240 = counter 1..=overflow).
    pub fn new(period: Duration, overflow: u8) -> Result<Self, SyncConfigError> {
        if period.is_zero() {
            return Err(SyncConfigError::ZeroPeriod);
        }
        if overflow == 1 || overflow > 240 {
            return Err(SyncConfigError::BadOverflow(overflow));
        }
        Ok(SyncProducer {
            period,
            overflow,
            counter: 1,
            schedule: None,
            sent: 0,
            skipped: 0,
        })
    }

    /// From object dictionary values: 0x1006 communication cycle period in
    /// µs (0 = no SYNC, giving `Ok(None)`) and 0x1019 counter overflow value.
    pub fn from_od(cycle_period_us: u32, overflow: u8) -> Result<Option<Self>, SyncConfigError> {
        if cycle_period_us == 0 {
            return Ok(None);
        }
        Self::new(Duration::from_micros(u64::from(cycle_period_us)), overflow).map(Some)
    }

    /// Starts (or restarts) producing: the first SYNC is due at
    /// `now + period`, and the counter restarts at 1.
    pub fn start(&mut self, now: Duration) {
        self.schedule = Some(Periodic::new(now, self.period));
        self.counter = 1;
    }

    /// Stops producing.
    pub fn stop(&mut self) {
        self.schedule = None;
    }

    /// True while started.
    pub fn is_running(&self) -> bool {
        self.schedule.is_some()
    }

    /// The communication cycle period.
    pub fn period(&self) -> Duration {
        self.period
    }

    /// The counter overflow value (0 = no counter).
    pub fn overflow(&self) -> u8 {
        self.overflow
    }

    /// Returns the SYNC frame to send if a deadline is due at `now`.
    pub fn on_tick(&mut self, now: Duration) -> Option<Frame> {
        let skipped = self.schedule.as_mut()?.poll(now)?;
        self.skipped += skipped;
        self.sent += 1;
        let frame = if self.overflow == 0 {
            sync_frame(None)
        } else {
            let c = self.counter;
            self.counter = if c >= self.overflow { 1 } else { c + 1 };
            sync_frame(Some(c))
        };
        Some(frame)
    }

    /// When `on_tick` next has something to do; `None` when stopped.
    pub fn next_deadline(&self) -> Option<Duration> {
        self.schedule.as_ref().map(Periodic::next_deadline)
    }

    /// SYNC frames sent since creation.
    pub fn sent(&self) -> u64 {
        self.sent
    }

    /// Periods skipped because the runner ticked too late to send them.
    pub fn skipped(&self) -> u64 {
        self.skipped
    }
}

/// A SYNC frame: 0x080 with no data, or with the one-byte counter.
pub fn sync_frame(counter: Option<u8>) -> Frame {
    let data = counter.as_slice();
    Frame::new(CanId::Standard(cob::SYNC), data).expect("SYNC frame is a valid classic frame")
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn config_validation() {
        assert_eq!(
            SyncProducer::new(Duration::ZERO, 0).unwrap_err(),
            SyncConfigError::ZeroPeriod
        );
        assert_eq!(
            SyncProducer::new(MS, 1).unwrap_err(),
            SyncConfigError::BadOverflow(1)
        );
        assert_eq!(
            SyncProducer::new(MS, 241).unwrap_err(),
            SyncConfigError::BadOverflow(241)
        );
        assert!(SyncProducer::new(MS, 0).is_ok());
        assert!(SyncProducer::new(MS, 2).is_ok());
        assert!(SyncProducer::new(MS, 240).is_ok());
        assert!(SyncProducer::from_od(0, 0).unwrap().is_none());
        assert_eq!(
            SyncProducer::from_od(10_000, 0).unwrap().unwrap().period(),
            10 * MS
        );
    }

    #[test]
    fn stopped_producer_is_silent() {
        let mut s = SyncProducer::new(MS, 0).unwrap();
        assert_eq!(s.next_deadline(), None);
        assert_eq!(s.on_tick(Duration::from_secs(5)), None);
        s.start(Duration::ZERO);
        assert!(s.is_running());
        s.stop();
        assert_eq!(s.on_tick(Duration::from_secs(5)), None);
    }

    #[test]
    fn frames_without_counter() {
        let mut s = SyncProducer::new(10 * MS, 0).unwrap();
        s.start(Duration::from_secs(1));
        assert_eq!(s.next_deadline(), Some(Duration::from_secs(1) + 10 * MS));
        assert_eq!(s.on_tick(Duration::from_secs(1) + 9 * MS), None);
        let f = s.on_tick(Duration::from_secs(1) + 10 * MS).unwrap();
        assert_eq!(f.id(), CanId::Standard(0x080));
        assert_eq!(f.data(), &[] as &[u8]);
        assert_eq!(s.on_tick(Duration::from_secs(1) + 10 * MS), None);
        assert_eq!(s.next_deadline(), Some(Duration::from_secs(1) + 20 * MS));
    }

    #[test]
    fn counter_wraps_to_one() {
        let mut s = SyncProducer::new(MS, 3).unwrap();
        s.start(Duration::ZERO);
        let counters: Vec<u8> = (1..=7)
            .map(|k| s.on_tick(k * MS).unwrap().data()[0])
            .collect();
        assert_eq!(counters, [1, 2, 3, 1, 2, 3, 1]);
        // Restarting resets the counter.
        s.start(7 * MS);
        assert_eq!(s.on_tick(8 * MS).unwrap().data(), &[1]);
    }

    #[test]
    fn late_ticks_skip_and_count_periods() {
        let mut s = SyncProducer::new(10 * MS, 240).unwrap();
        s.start(Duration::ZERO);
        assert_eq!(s.on_tick(10 * MS).unwrap().data(), &[1]);
        // Woken 35 ms late: periods at 20, 30 and 40 are due; send one, skip two.
        assert_eq!(s.on_tick(45 * MS).unwrap().data(), &[2]);
        assert_eq!(s.skipped(), 2);
        assert_eq!(s.sent(), 2);
        // The schedule stays on the original grid.
        assert_eq!(s.next_deadline(), Some(50 * MS));
    }

    #[test]
    fn no_drift_over_ten_thousand_periods_with_jitter() {
        let period = Duration::from_micros(1_000);
        let mut s = SyncProducer::new(period, 240).unwrap();
        let origin = Duration::from_secs(3);
        s.start(origin);
        // Deterministic pseudo-random jitter of 0..600 µs after each deadline.
        let mut seed: u32 = 0x1234_5678;
        let mut expected_counter = 1u8;
        for k in 1..=10_000u32 {
            let deadline = s.next_deadline().unwrap();
            assert_eq!(deadline, origin + period * k, "drift at period {k}");
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let jitter = Duration::from_micros(u64::from(seed >> 16) % 600);
            assert_eq!(s.on_tick(deadline - Duration::from_nanos(1)), None);
            let f = s.on_tick(deadline + jitter).unwrap();
            assert_eq!(f.data(), &[expected_counter]);
            expected_counter = if expected_counter == 240 {
                1
            } else {
                expected_counter + 1
            };
        }
        assert_eq!(s.sent(), 10_000);
        assert_eq!(s.skipped(), 0);
        assert_eq!(s.next_deadline(), Some(origin + period * 10_001));
    }

    #[test]
    fn periodic_handles_huge_gaps() {
        let mut p = Periodic::new(Duration::ZERO, Duration::from_nanos(1));
        assert_eq!(p.poll(Duration::from_secs(1)), Some(999_999_999));
        assert_eq!(p.next_deadline(), Duration::from_nanos(1_000_000_001));
    }
}
