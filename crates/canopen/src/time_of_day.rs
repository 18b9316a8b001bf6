//! The TIME object (CiA 301 §7.2.6): COB-ID 0x100 with a TIME_OF_DAY, six
//! bytes little-endian: milliseconds after midnight as UNSIGNED28 (the
//! upper four bits of the first 32-bit word are reserved and sent as 0),
//! then days since 1 January 1984 as UNSIGNED16.
//!
//! What the spec leaves open, settled here: the producer's clock is UTC
//! (CiA 301 names no time zone; python `canopen`'s producer sends the
//! host's Unix time the same way), times before 1984 are not
//! representable and are refused, and the day counter wraps after
//! 65,535 days (the year 2163) like the field.

use std::time::Duration;

use cangate_can::{CanId, Frame};

use crate::ids::cob;

/// Seconds from the Unix epoch to 1984-01-01 00:00:00 UTC, TIME_OF_DAY's
/// epoch (5,113 days).
pub const EPOCH_1984_UNIX_SECS: u64 = 441_763_200;

const MS_PER_DAY: u64 = 86_400_000;

/// A CANopen TIME_OF_DAY.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimeOfDay {
    /// Milliseconds after midnight, 0..86,400,000.
    pub ms: u32,
    /// Days since 1984-01-01.
    pub days: u16,
}

/// Why bytes or a time are not a TIME_OF_DAY.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum TimeOfDayError {
    /// The payload is not six bytes.
    #[error("a TIME_OF_DAY has 6 bytes, not {0}")]
    Length(usize),
    /// More milliseconds than a day has.
    #[error("{0} ms after midnight is more than a day")]
    PastMidnight(u32),
    /// Before 1984-01-01, which the field cannot express.
    #[error("times before 1984-01-01 cannot be sent as a TIME_OF_DAY")]
    Before1984,
}

impl TimeOfDay {
    /// The TIME_OF_DAY of a time given as the duration since the Unix
    /// epoch (sub-millisecond parts are cut).
    pub fn from_unix(since_epoch: Duration) -> Result<TimeOfDay, TimeOfDayError> {
        let ms = since_epoch
            .as_millis()
            .checked_sub(u128::from(EPOCH_1984_UNIX_SECS) * 1000)
            .ok_or(TimeOfDayError::Before1984)?;
        let ms = u64::try_from(ms).unwrap_or(u64::MAX);
        Ok(TimeOfDay {
            ms: (ms % MS_PER_DAY) as u32,
            days: (ms / MS_PER_DAY) as u16,
        })
    }

    /// The duration since the Unix epoch this TIME_OF_DAY stands for.
    pub fn to_unix(self) -> Duration {
        Duration::from_millis(
            EPOCH_1984_UNIX_SECS * 1000 + u64::from(self.days) * MS_PER_DAY + u64::from(self.ms),
        )
    }

    /// The six payload bytes.
    pub fn encode(self) -> [u8; 6] {
        let mut b = [0; 6];
        b[..4].copy_from_slice(&(self.ms & 0x0FFF_FFFF).to_le_bytes());
        b[4..].copy_from_slice(&self.days.to_le_bytes());
        b
    }

    /// Reads a payload; the reserved bits are ignored.
    pub fn decode(data: &[u8]) -> Result<TimeOfDay, TimeOfDayError> {
        let b: [u8; 6] = data
            .try_into()
            .map_err(|_| TimeOfDayError::Length(data.len()))?;
        let ms = u32::from_le_bytes([b[0], b[1], b[2], b[3]]) & 0x0FFF_FFFF;
        if u64::from(ms) >= MS_PER_DAY {
            return Err(TimeOfDayError::PastMidnight(ms));
        }
        Ok(TimeOfDay {
            ms,
            days: u16::from_le_bytes([b[4], b[5]]),
        })
    }

    /// The TIME frame (COB-ID 0x100).
    pub fn frame(self) -> Frame {
        Frame::new(CanId::Standard(cob::TIME), &self.encode())
            .expect("a TIME frame is a valid classic frame")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_epoch_is_1984() {
        // 1970..1984: 14 years, three of them leap years (72, 76, 80).
        assert_eq!(EPOCH_1984_UNIX_SECS, (14 * 365 + 3) * 86_400);
        let t = TimeOfDay::from_unix(Duration::from_secs(EPOCH_1984_UNIX_SECS)).unwrap();
        assert_eq!(t, TimeOfDay { ms: 0, days: 0 });
        assert_eq!(t.encode(), [0; 6]);
    }

    #[test]
    fn exact_bytes() {
        // One day and 3,600.5 s after the epoch: 3,600,500 ms = 0x0036F074.
        let unix = Duration::from_millis(EPOCH_1984_UNIX_SECS * 1000 + 86_400_000 + 3_600_500);
        let t = TimeOfDay::from_unix(unix).unwrap();
        assert_eq!(
            t,
            TimeOfDay {
                ms: 3_600_500,
                days: 1
            }
        );
        assert_eq!(t.encode(), [0x74, 0xF0, 0x36, 0x00, 0x01, 0x00]);
        assert_eq!(t.frame().raw_id(), 0x100);
        assert_eq!(TimeOfDay::decode(&t.encode()), Ok(t));
        assert_eq!(t.to_unix(), unix);
        // 2025-11-24 00:00:00 UTC is Unix day 20,416: day 15,303 since 1984.
        let t = TimeOfDay::from_unix(Duration::from_secs(20_416 * 86_400 + 1)).unwrap();
        assert_eq!(
            t,
            TimeOfDay {
                ms: 1000,
                days: 15_303
            }
        );
        assert_eq!(t.encode(), [0xE8, 0x03, 0, 0, 0xC7, 0x3B]);
    }

    #[test]
    fn refusals() {
        assert_eq!(
            TimeOfDay::from_unix(Duration::from_secs(EPOCH_1984_UNIX_SECS - 1)),
            Err(TimeOfDayError::Before1984)
        );
        assert_eq!(TimeOfDay::decode(&[0; 5]), Err(TimeOfDayError::Length(5)));
        assert_eq!(TimeOfDay::decode(&[0; 8]), Err(TimeOfDayError::Length(8)));
        // 86,400,000 = 0x05265C00 ms is midnight of the next day.
        assert_eq!(
            TimeOfDay::decode(&[0x00, 0x5C, 0x26, 0x05, 0, 0]),
            Err(TimeOfDayError::PastMidnight(86_400_000))
        );
        // Reserved bits are ignored.
        assert_eq!(
            TimeOfDay::decode(&[0x01, 0, 0, 0xF0, 2, 0]),
            Ok(TimeOfDay { ms: 1, days: 2 })
        );
    }

    #[test]
    fn every_millisecond_of_a_day_round_trips() {
        for ms in (0..86_400_000u32).step_by(997) {
            let t = TimeOfDay { ms, days: 12_345 };
            assert_eq!(TimeOfDay::decode(&t.encode()), Ok(t));
            assert_eq!(TimeOfDay::from_unix(t.to_unix()), Ok(t));
        }
    }
}
