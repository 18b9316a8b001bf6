//! Budgets that keep client raw frames and bulk transfers from crowding
//! out the gateway's own time-critical traffic (pure: times are
//! nanoseconds supplied by the caller).
//!
//! On the wire, arbitration already favours low identifiers, but a frame
//! only takes part in arbitration once it reaches the head of the queues in
//! front of the wire (the bus owner's submission queue, a controller's or
//! a virtual port's transmit FIFO). A client flooding `SendFrames`, or an
//! SDO block transfer handing over 127 segments at once, fills those
//! queues, and the SYNC, the set-points and the NMT commands queued after
//! them wait; a flood on a low identifier also wins every arbitration.
//! So each frame carries a [`TxClass`]: the gateway's own frames go
//! straight to the wire, while client and bulk frames are paced by a
//! [`Pacer`] to a configurable share of the bus's time ([`TxShares`]) and,
//! on the virtual bus, queue in a transmit lane of their own that the own
//! frames overtake (as a controller's separate transmit mailboxes would).
//! Client frames are moreover held while other frames wait for the wire
//! (see `others_waiting` in the bus module): a share is a ceiling, not a
//! reservation, so a busy cycle plus a flood never overloads the bus.

/// What a frame is sent for, which decides its place in the queues in
/// front of the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum TxClass {
    /// The gateway's own traffic: SYNC, set-points, NMT, SDO requests,
    /// PDOs. Never held back.
    Control,
    /// Bulk data the gateway sends for a client (an SDO block download's
    /// sub-blocks): paced to the bus's bulk share.
    Bulk,
    /// A client's raw frames (`SendFrames`): paced to the bus's client
    /// share.
    Client,
}

impl TxClass {
    /// The transmit lane of the class on a virtual bus: each lane of a port
    /// is a FIFO of its own, so frames of one class never wait behind
    /// another class's backlog.
    pub fn lane(self) -> u8 {
        match self {
            TxClass::Control => 0,
            TxClass::Bulk => 1,
            TxClass::Client => 2,
        }
    }
}

/// Shares of a bus's time, in percent, that client raw frames and bulk
/// transfers may use; 100 means no limit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TxShares {
    /// Client raw frames (`SendFrames`), 1..=100.
    pub client_percent: u8,
    /// Bulk SDO data (block download sub-blocks), 1..=100.
    pub bulk_percent: u8,
}

impl TxShares {
    /// Default client share: a flood at full rate leaves more than two
    /// thirds of the bus to the gateway's cycle and the devices' answers.
    pub const DEFAULT_CLIENT_PERCENT: u8 = 30;
    /// Default bulk share: a block transfer runs at half the bus rate.
    pub const DEFAULT_BULK_PERCENT: u8 = 50;

    /// Checks both shares are in 1..=100.
    pub fn validate(&self) -> Result<(), String> {
        for (key, v) in [
            ("client_share_percent", self.client_percent),
            ("bulk_share_percent", self.bulk_percent),
        ] {
            if !(1..=100).contains(&v) {
                return Err(format!("{key} = {v} is out of range (1..=100)"));
            }
        }
        Ok(())
    }

    /// The share of `class` in percent (`Control`: 100).
    pub fn percent(&self, class: TxClass) -> u8 {
        match class {
            TxClass::Control => 100,
            TxClass::Bulk => self.bulk_percent,
            TxClass::Client => self.client_percent,
        }
    }
}

impl Default for TxShares {
    fn default() -> Self {
        TxShares {
            client_percent: Self::DEFAULT_CLIENT_PERCENT,
            bulk_percent: Self::DEFAULT_BULK_PERCENT,
        }
    }
}

/// Paces frames to a share of the bus's time (the generic cell rate
/// algorithm): a frame that occupies the bus for `d` ns costs `d / share`
/// ns of the pacer's clock, and may go as long as that clock is no more
/// than the tolerance ahead of real time. The tolerance is the largest
/// burst: it lets a caller that wakes only every millisecond send what
/// accumulated since, and no more.
#[derive(Debug, Clone)]
pub struct Pacer {
    /// Theoretical arrival time: when the frames sent so far would have
    /// finished at exactly the share.
    tat_ns: u64,
    tolerance_ns: u64,
}

impl Pacer {
    /// A pacer allowing bursts of `tolerance_ns` of its clock.
    pub fn new(tolerance_ns: u64) -> Self {
        Pacer {
            tat_ns: 0,
            tolerance_ns,
        }
    }

    /// Charges a frame of `busy_ns` bus time at `share_percent` (1..=100)
    /// if it may go at `now_ns`; false (nothing charged) if it has to wait
    /// until [`Pacer::ready_at`].
    pub fn try_take(&mut self, busy_ns: u64, share_percent: u8, now_ns: u64) -> bool {
        let tat = self.tat_ns.max(now_ns);
        if tat > now_ns + self.tolerance_ns {
            return false;
        }
        let share = u64::from(share_percent.clamp(1, 100));
        self.tat_ns = tat + busy_ns * 100 / share;
        true
    }

    /// The earliest time at which the next frame may go.
    pub fn ready_at(&self) -> u64 {
        self.tat_ns.saturating_sub(self.tolerance_ns)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// At a 25 % share, frames of 100 µs go one per 400 µs on average,
    /// after a first burst of the tolerance.
    #[test]
    fn pacer_holds_the_share_over_time() {
        let mut p = Pacer::new(1_000_000);
        let mut sent = 0u64;
        let mut now = 0u64;
        while now <= 1_000_000_000 {
            while p.try_take(100_000, 25, now) {
                sent += 1;
            }
            assert!(p.ready_at() > now, "refused only until ready_at");
            now = p.ready_at().max(now + 1_000_000);
        }
        // One second at 25 % of 100 µs frames: 2,500 frames, plus the
        // burst of the tolerance (1 ms at 400 µs per frame: 3).
        assert!((2_500..=2_504).contains(&sent), "{sent}");
    }

    #[test]
    fn pacer_burst_is_bounded_by_the_tolerance() {
        let mut p = Pacer::new(2_000_000);
        let mut burst = 0;
        while p.try_take(135_000, 50, 10_000_000) {
            burst += 1;
        }
        // 2 ms of tolerance at 270 µs per frame: the frame at the start
        // plus 7 more.
        assert_eq!(burst, 8);
        assert_eq!(p.ready_at(), 10_000_000 + 8 * 270_000 - 2_000_000);
        // An idle pacer does not save up more than the tolerance.
        let mut p = Pacer::new(2_000_000);
        let mut late = 0;
        while p.try_take(135_000, 50, 5_000_000_000) {
            late += 1;
        }
        assert_eq!(late, 8);
    }

    #[test]
    fn shares_are_validated() {
        assert!(TxShares::default().validate().is_ok());
        let bad = TxShares {
            client_percent: 0,
            ..TxShares::default()
        };
        assert!(bad.validate().unwrap_err().contains("client_share_percent"));
        let bad = TxShares {
            bulk_percent: 101,
            ..TxShares::default()
        };
        assert!(bad.validate().unwrap_err().contains("bulk_share_percent"));
        assert_eq!(TxShares::default().percent(TxClass::Control), 100);
    }
}
