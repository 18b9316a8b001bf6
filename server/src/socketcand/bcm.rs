//! socketcand's BCM mode without I/O: a session's receive operations
//! (`subscribe`, `filter`, `unsubscribe`), driven by frames and time; its
//! cyclic transmission jobs (`add`, `update`, `delete`) run in the
//! runtime's [`crate::cyclic`], as those of every client do.
//!
//! Source of truth: `doc/protocol.md` of linux-can/socketcand and
//! `src/state_bcm.c` (commit 6dd5d33), which hands each command to the
//! kernel's broadcast manager (`TX_SETUP`, `TX_DELETE`, `RX_SETUP`,
//! `RX_DELETE`); the semantics below are those of the Linux BCM
//! (`net/can/bcm.c`) for the flags socketcand sets:
//!
//! - **`add secs usecs id dlc data…`**: `TX_SETUP` with `SETTIMER |
//!   STARTTIMER`: the frame goes out every interval, the first one interval
//!   after the command (no `TX_ANNOUNCE`). One job per identifier: a second
//!   `add` replaces the job and restarts its timer. The gateway refuses an
//!   interval below [`crate::cyclic::MIN_INTERVAL`] (the kernel's floor is
//!   the timer's) and more than [`crate::cyclic::MAX_JOBS`] jobs per
//!   session.
//! - **`update id dlc data…`**: `TX_SETUP` without timer flags: the job's
//!   frame is replaced, its timer goes on. The gateway refuses an update of
//!   a job that does not exist (the kernel would create one without a
//!   timer, which sends nothing).
//! - **`delete id`**: `TX_DELETE`.
//! - **`subscribe secs usecs id`**: `RX_SETUP` with `RX_FILTER_ID`: every
//!   frame of the identifier, at most one per interval when one is given
//!   (`SETTIMER` throttling: frames in between are held back and the last
//!   one is reported when the interval has passed).
//! - **`filter secs usecs id dlc mask…`**: `RX_SETUP` with one frame as the
//!   content mask: the first frame of the identifier, then each one whose
//!   masked data differs from the previous frame's, throttled as above.
//! - **`unsubscribe id`**: `RX_DELETE` (a subscription or a filter).
//! - **Frames out**: `< frame 123 23.424242 11 22 33  >`, the bytes each
//!   followed by a space, then ` >` (`state_bcm.c`'s format, not raw
//!   mode's).
//!
//! Time is a [`Duration`] since an arbitrary start, given by the caller.

use cangate_can::{CanId, Frame};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::Duration;

/// Receive operations one session may have.
pub const MAX_RX_OPS: usize = 256;

#[derive(Debug, Clone)]
struct RxOp {
    /// `None`: every frame (subscribe); else the content mask (filter).
    mask: Option<Vec<u8>>,
    throttle: Duration,
    /// The previous frame's data (for the content comparison).
    previous: Option<Vec<u8>>,
    /// When the last frame was reported.
    reported: Option<Duration>,
    /// A frame held back by the throttle.
    held: Option<Frame>,
}

/// A session's BCM receive operations.
#[derive(Debug, Default)]
pub struct Bcm {
    rx: BTreeMap<CanId, RxOp>,
}

impl Bcm {
    /// `subscribe` (`mask` `None`) or `filter`: replaces an operation of
    /// the same identifier.
    ///
    /// # Errors
    /// [`MAX_RX_OPS`] operations already.
    pub fn receive(
        &mut self,
        id: CanId,
        mask: Option<Vec<u8>>,
        throttle: Duration,
    ) -> Result<(), String> {
        if !self.rx.contains_key(&id) && self.rx.len() >= MAX_RX_OPS {
            return Err(format!(
                "at most {MAX_RX_OPS} subscriptions and filters per session"
            ));
        }
        self.rx.insert(
            id,
            RxOp {
                mask,
                throttle,
                previous: None,
                reported: None,
                held: None,
            },
        );
        Ok(())
    }

    /// `unsubscribe`.
    ///
    /// # Errors
    /// No subscription or filter for the identifier.
    pub fn unsubscribe(&mut self, id: CanId) -> Result<(), String> {
        self.rx
            .remove(&id)
            .map(|_| ())
            .ok_or_else(|| format!("unsubscribe: no subscription or filter for {}", id_text(id)))
    }

    /// The identifiers with a receive operation (for the feed's filters).
    pub fn receive_ids(&self) -> Vec<CanId> {
        self.rx.keys().copied().collect()
    }

    /// Whether any receive operation runs.
    pub fn active(&self) -> bool {
        !self.rx.is_empty()
    }

    /// The next time a held frame is due ([`Bcm::due`]).
    pub fn next_deadline(&self) -> Option<Duration> {
        self.rx
            .values()
            .filter(|op| op.held.is_some())
            .filter_map(|op| op.reported.map(|r| r + op.throttle))
            .min()
    }

    /// The held frames to report at `now`.
    pub fn due(&mut self, now: Duration) -> Vec<Frame> {
        let mut report = Vec::new();
        for op in self.rx.values_mut() {
            if let (Some(r), true) = (op.reported, op.held.is_some())
                && r + op.throttle <= now
            {
                report.extend(op.held.take());
                op.reported = Some(now);
            }
        }
        report
    }

    /// A received frame: `Some` when it is reported now.
    pub fn on_frame(&mut self, frame: &Frame, now: Duration) -> Option<Frame> {
        let op = self.rx.get_mut(&frame.id())?;
        if let Some(mask) = &op.mask {
            let masked = |d: &[u8]| -> Vec<u8> {
                mask.iter()
                    .enumerate()
                    .map(|(i, m)| d.get(i).copied().unwrap_or(0) & m)
                    .collect()
            };
            let now_masked = masked(frame.data());
            let changed = op
                .previous
                .as_deref()
                .is_none_or(|p| masked(p) != now_masked);
            op.previous = Some(frame.data().to_vec());
            if !changed {
                return None;
            }
        }
        match op.reported {
            Some(r) if !op.throttle.is_zero() && now < r + op.throttle => {
                op.held = Some(*frame);
                None
            }
            _ => {
                op.reported = Some(now);
                op.held = None;
                Some(*frame)
            }
        }
    }
}

/// An identifier as socketcand writes it (`%03X`, `%08X` extended).
pub fn id_text(id: CanId) -> String {
    match id {
        CanId::Standard(i) => format!("{i:03X}"),
        CanId::Extended(i) => format!("{i:08X}"),
    }
}

/// The line for a frame reported in BCM mode (`state_bcm.c`'s layout).
pub fn format_bcm_frame(frame: &Frame) -> String {
    let ns = frame.timestamp().as_nanos();
    let (secs, usecs) = (ns / 1_000_000_000, (ns % 1_000_000_000) / 1000);
    let mut line = format!("< frame {} {secs}.{usecs:06} ", id_text(frame.id()));
    for b in frame.data() {
        let _ = write!(line, "{b:02X} ");
    }
    line.push_str(" >");
    line
}

#[cfg(test)]
mod tests {
    use super::*;
    use cangate_can::Timestamp;

    fn frame(id: u16, data: &[u8]) -> Frame {
        Frame::new(CanId::Standard(id), data).unwrap()
    }

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    #[test]
    fn a_filter_reports_content_changes_under_its_mask() {
        // `< filter 0 0 123 1 FF >`: changes in the first byte.
        let mut b = Bcm::default();
        b.receive(CanId::Standard(0x123), Some(vec![0xFF]), Duration::ZERO)
            .unwrap();
        assert!(b.on_frame(&frame(0x123, &[1, 2]), ms(0)).is_some(), "first");
        assert!(
            b.on_frame(&frame(0x123, &[1, 3]), ms(1)).is_none(),
            "same byte 0"
        );
        assert!(b.on_frame(&frame(0x123, &[2, 3]), ms(2)).is_some());
        assert!(b.on_frame(&frame(0x124, &[9]), ms(3)).is_none(), "other id");
        b.unsubscribe(CanId::Standard(0x123)).unwrap();
        assert!(b.on_frame(&frame(0x123, &[7]), ms(4)).is_none());
    }

    #[test]
    fn a_throttled_subscription_holds_back_and_reports_the_last() {
        let mut b = Bcm::default();
        b.receive(CanId::Standard(0x80), None, ms(100)).unwrap();
        assert!(b.on_frame(&frame(0x80, &[1]), ms(0)).is_some());
        assert!(b.on_frame(&frame(0x80, &[2]), ms(10)).is_none());
        assert!(b.on_frame(&frame(0x80, &[3]), ms(20)).is_none());
        assert_eq!(b.next_deadline(), Some(ms(100)));
        assert_eq!(b.due(ms(100)), vec![frame(0x80, &[3])]);
        assert_eq!(b.next_deadline(), None);
        assert!(b.on_frame(&frame(0x80, &[4]), ms(150)).is_none());
        assert!(b.on_frame(&frame(0x80, &[5]), ms(250)).is_some());
    }

    #[test]
    fn frames_print_as_state_bcm_c_prints_them() {
        let f = frame(0x123, &[0x11, 0x22, 0x33]).with_timestamp(Timestamp(23_424_242_000));
        assert_eq!(format_bcm_frame(&f), "< frame 123 23.424242 11 22 33  >");
        let e = Frame::new(CanId::Extended(0x1ABCDEF0), &[])
            .unwrap()
            .with_timestamp(Timestamp(1_000_000_000));
        assert_eq!(format_bcm_frame(&e), "< frame 1ABCDEF0 1.000000  >");
    }
}
