//! CNC handwheel (manual pulse generator) feed protocol, sans-IO.
//!
//! Implements the wire format of `shared/specs/handwheel.md`: the handwheel
//! sends one TPDO1 (COB-ID `0x180 + node_id`, 1 data byte) per feed unit.
//! Byte 0 holds the axis (bits 0–2: 0 = X … 4 = V, 5–7 invalid), the
//! direction (bit 3: 1 = positive) and a rolling sequence counter whose
//! layout is [`CounterLayout::Nibble`] (bits 4–7, step 1, the default) or
//! [`CounterLayout::Bits6_7`] (bits 6–7, the paper's experiment).
//!
//! [`FeedDecoder`] turns the feed frames of one handwheel into
//! [`FeedEvent`]s and keeps [`FeedStats`]. For consecutive counters
//! `gap = (c - c_prev) mod m` (`m` = 16 or 4):
//!
//! - `gap == 1`: one unit;
//! - `gap > 1`: `gap - 1` frames were lost; they carried feed in the axis and
//!   direction of the frame that follows them, so the event moves
//!   `1 + (gap - 1)` units and reports `gap - 1` as compensated;
//! - `gap == 0`: a repeated frame, reported as duplicate, no movement.
//!
//! The first frame after start-up or after [`FeedDecoder::reset_baseline`]
//! (heartbeat loss, mode change, …) is the baseline: one unit, no gap check.
//! An outage of more than `m - 1` consecutive frames cannot be seen in the
//! counter; the application must reset the baseline when it learns of it
//! (typically on heartbeat loss), it is never guessed.
//!
//! Frames with an invalid axis code are counted as bad frames and never
//! move; their counter still counts as received (they are not lost frames).
//! Frames of another length than 1 byte are bad too and, since their
//! counter cannot be read, drop the baseline.
//!
//! Time convention: every `now` is a [`Duration`] from an arbitrary origin.

use std::fmt;
use std::time::Duration;

use cangate_can::Frame;

use crate::NodeId;
use crate::ids::cob;

/// Where the sequence counter sits in the feed byte.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub enum CounterLayout {
    /// Bits 4–7, +1 (mod 16) per frame; up to 14 lost frames detectable
    /// (15 lost make the next counter equal the last one: a repeat; the
    /// handwheel spec says 15).
    #[default]
    Nibble,
    /// Bits 6–7 only, +1 (mod 4) per frame (the byte moves in steps of
    /// 0x40); up to 2 lost frames detectable (3 look like a repeat). Bits
    /// 4–5 are ignored.
    Bits6_7,
}

impl CounterLayout {
    /// The counter modulus: 16 or 4.
    pub const fn modulus(self) -> u8 {
        match self {
            CounterLayout::Nibble => 16,
            CounterLayout::Bits6_7 => 4,
        }
    }

    /// Extracts the counter (`0..modulus`) from a feed byte.
    pub const fn counter(self, byte: u8) -> u8 {
        match self {
            CounterLayout::Nibble => byte >> 4,
            CounterLayout::Bits6_7 => byte >> 6,
        }
    }

    /// Places a counter (taken mod the modulus) into the counter bits.
    pub const fn counter_bits(self, counter: u8) -> u8 {
        match self {
            CounterLayout::Nibble => (counter & 0x0F) << 4,
            CounterLayout::Bits6_7 => (counter & 0x03) << 6,
        }
    }
}

/// The axis selected on the handwheel (feed byte bits 0–2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum HandwheelAxis {
    /// Code 0.
    X,
    /// Code 1.
    Y,
    /// Code 2.
    Z,
    /// Code 3.
    W,
    /// Code 4.
    V,
}

impl HandwheelAxis {
    /// Every axis, in code order.
    pub const ALL: [HandwheelAxis; 5] = [Self::X, Self::Y, Self::Z, Self::W, Self::V];

    /// The axis of a code 0..=4; `None` for 5..=7 (invalid) and beyond.
    pub const fn from_code(code: u8) -> Option<Self> {
        match code {
            0 => Some(Self::X),
            1 => Some(Self::Y),
            2 => Some(Self::Z),
            3 => Some(Self::W),
            4 => Some(Self::V),
            _ => None,
        }
    }

    /// The code on the wire (0..=4).
    pub const fn code(self) -> u8 {
        self as u8
    }
}

/// The feed direction (feed byte bit 3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Bit 3 = 1: phase A leads B.
    Positive,
    /// Bit 3 = 0: phase A lags B.
    Negative,
}

impl Direction {
    /// +1 or -1.
    pub const fn sign(self) -> i64 {
        match self {
            Direction::Positive => 1,
            Direction::Negative => -1,
        }
    }
}

/// A feed byte that cannot be decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, thiserror::Error)]
pub enum BadFrame {
    /// Axis code 5..=7 in bits 0–2.
    #[error("invalid axis code {code} in feed byte {byte:#04x}")]
    InvalidAxis {
        /// The axis code.
        code: u8,
        /// The whole byte.
        byte: u8,
    },
    /// The frame does not carry exactly one data byte (or is a remote
    /// frame).
    #[error("feed frame with {len} data bytes, expected 1")]
    Length {
        /// The data length received.
        len: usize,
    },
}

/// One decoded feed byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct FeedFrame {
    /// The selected axis.
    pub axis: HandwheelAxis,
    /// The direction.
    pub direction: Direction,
    /// The sequence counter, `0..layout.modulus()`.
    pub counter: u8,
}

impl FeedFrame {
    /// Decodes a feed byte with the given counter layout.
    pub fn decode(byte: u8, layout: CounterLayout) -> Result<FeedFrame, BadFrame> {
        let code = byte & 0x07;
        let axis = HandwheelAxis::from_code(code).ok_or(BadFrame::InvalidAxis { code, byte })?;
        let direction = if byte & 0x08 != 0 {
            Direction::Positive
        } else {
            Direction::Negative
        };
        Ok(FeedFrame {
            axis,
            direction,
            counter: layout.counter(byte),
        })
    }

    /// Encodes the feed byte (the counter is taken mod the layout's
    /// modulus).
    pub fn encode(&self, layout: CounterLayout) -> u8 {
        let dir = match self.direction {
            Direction::Positive => 0x08,
            Direction::Negative => 0x00,
        };
        self.axis.code() | dir | layout.counter_bits(self.counter)
    }
}

/// Why the decoder took (or will take) a new baseline.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BaselineReason {
    /// First frame since the decoder was created.
    Startup,
    /// The handwheel's heartbeat was lost (an outage of unknown length).
    HeartbeatLost,
    /// The handwheel booted (boot-up message seen, or reported by the
    /// application).
    DeviceRestart,
    /// The operating mode (0x2000) was changed.
    ModeChange,
    /// A frame whose counter could not be read (wrong length).
    MalformedFrame,
    /// Any other reason given by the application.
    Other,
}

/// Flags of a [`FeedEvent`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub struct FeedFlags {
    /// Same counter as the previous frame: reported, not moved.
    pub duplicate: bool,
    /// Lost frames were compensated (`gap > 1`).
    pub compensated: bool,
    /// This frame is a baseline (no gap check).
    pub baseline: bool,
    /// The frame could not be decoded: never moved.
    pub bad: bool,
}

/// What one received feed frame means.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FeedEvent {
    /// The handwheel's node id.
    pub handwheel: NodeId,
    /// Receive time.
    pub at: Duration,
    /// The raw feed byte (`None` for a frame of the wrong length).
    pub byte: Option<u8>,
    /// The axis (`None` for bad frames).
    pub axis: Option<HandwheelAxis>,
    /// The direction (`None` for bad frames).
    pub direction: Option<Direction>,
    /// The sequence counter on the wire (`None` when unreadable).
    pub sequence: Option<u8>,
    /// Units to move: `1 + compensated`; 0 for duplicate and bad frames.
    pub units: u32,
    /// `(c - c_prev) mod m`; `None` for baselines and bad frames.
    pub gap: Option<u8>,
    /// Units added for lost frames (`gap - 1` when `gap > 1`).
    pub compensated: u32,
    /// Flags.
    pub flags: FeedFlags,
    /// Why this frame is a baseline (set when `flags.baseline`).
    pub baseline_reason: Option<BaselineReason>,
    /// Why the frame is bad (set when `flags.bad`).
    pub error: Option<BadFrame>,
}

impl FeedEvent {
    /// Units with sign (positive direction > 0); 0 when nothing moves.
    pub fn signed_units(&self) -> i64 {
        self.direction
            .map_or(0, |d| d.sign() * i64::from(self.units))
    }
}

/// Running statistics of a [`FeedDecoder`].
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct FeedStats {
    /// Frames received on the feed COB-ID (all kinds).
    pub frames: u64,
    /// Units moved (compensated ones included), by axis code and direction
    /// (`[positive, negative]`); see [`FeedStats::units`].
    pub units_by_axis: [[u64; 2]; 5],
    /// Frames with `gap > 1`.
    pub gaps: u64,
    /// Units added for lost frames.
    pub compensated_units: u64,
    /// Repeated frames (`gap == 0`).
    pub duplicates: u64,
    /// Undecodable frames (invalid axis, wrong length).
    pub bad_frames: u64,
    /// Baseline frames taken (start-up included).
    pub baselines: u64,
    /// Baseline resets ([`FeedDecoder::reset_baseline`], boot-up seen,
    /// malformed frames).
    pub baseline_resets: u64,
}

impl FeedStats {
    /// Units moved on `axis` in `direction` (compensated ones included).
    pub fn units(&self, axis: HandwheelAxis, direction: Direction) -> u64 {
        self.units_by_axis[usize::from(axis.code())][dir_index(direction)]
    }

    /// Units moved in total, all axes and directions.
    pub fn total_units(&self) -> u64 {
        self.units_by_axis.iter().flatten().sum()
    }

    /// Net signed units on `axis` (positive minus negative).
    pub fn net_units(&self, axis: HandwheelAxis) -> i64 {
        let [p, n] = self.units_by_axis[usize::from(axis.code())];
        p as i64 - n as i64
    }
}

fn dir_index(d: Direction) -> usize {
    match d {
        Direction::Positive => 0,
        Direction::Negative => 1,
    }
}

/// Decodes the feed frames of one handwheel. See the [module
/// documentation](self).
#[derive(Debug, Clone)]
pub struct FeedDecoder {
    node: NodeId,
    layout: CounterLayout,
    /// The previous counter; `None` while waiting for a baseline.
    prev: Option<u8>,
    /// Why the next frame is a baseline.
    pending_reason: BaselineReason,
    stats: FeedStats,
}

impl FeedDecoder {
    /// A decoder for the handwheel at `node` (feed COB-ID `0x180 + node`).
    pub fn new(node: NodeId, layout: CounterLayout) -> Self {
        FeedDecoder {
            node,
            layout,
            prev: None,
            pending_reason: BaselineReason::Startup,
            stats: FeedStats::default(),
        }
    }

    /// The handwheel's node id.
    pub fn node_id(&self) -> NodeId {
        self.node
    }

    /// The counter layout.
    pub fn layout(&self) -> CounterLayout {
        self.layout
    }

    /// The feed COB-ID, `0x180 + node`.
    pub fn cob_id(&self) -> u16 {
        cob::TPDO[0] + u16::from(self.node.get())
    }

    /// The statistics so far.
    pub fn stats(&self) -> &FeedStats {
        &self.stats
    }

    /// True while the next feed frame will be a baseline.
    pub fn awaiting_baseline(&self) -> bool {
        self.prev.is_none()
    }

    /// Forgets the previous counter: the next feed frame is a baseline
    /// (one unit, no gap check) reported with `reason`. Call it on
    /// heartbeat loss, device restart and mode change. Counted in
    /// [`FeedStats::baseline_resets`].
    pub fn reset_baseline(&mut self, reason: BaselineReason) {
        self.prev = None;
        self.pending_reason = reason;
        self.stats.baseline_resets += 1;
    }

    /// Handles a frame received at `now`. Returns an event for frames on
    /// the feed COB-ID; `None` for any other frame. A boot-up message of
    /// the handwheel (`0x700 + node`, `[00]`) resets the baseline
    /// ([`BaselineReason::DeviceRestart`]) and returns `None`.
    pub fn on_frame(&mut self, frame: &Frame, now: Duration) -> Option<FeedEvent> {
        if frame.is_error() || frame.is_extended() {
            return None;
        }
        let id = frame.raw_id();
        if id == u32::from(cob::HEARTBEAT + u16::from(self.node.get()))
            && !frame.is_remote()
            && frame.data() == [0]
        {
            self.reset_baseline(BaselineReason::DeviceRestart);
            return None;
        }
        if id != u32::from(self.cob_id()) {
            return None;
        }
        self.stats.frames += 1;
        let data = frame.data();
        if frame.is_remote() || data.len() != 1 {
            let error = BadFrame::Length {
                len: if frame.is_remote() { 0 } else { data.len() },
            };
            self.stats.bad_frames += 1;
            self.reset_baseline(BaselineReason::MalformedFrame);
            return Some(self.bad_event(now, None, None, error));
        }
        Some(self.on_byte(data[0], now))
    }

    /// Handles one feed byte received at `now` (the frame's COB-ID already
    /// checked).
    pub fn on_byte(&mut self, byte: u8, now: Duration) -> FeedEvent {
        let counter = self.layout.counter(byte);
        let frame = match FeedFrame::decode(byte, self.layout) {
            Ok(f) => f,
            Err(error) => {
                self.stats.bad_frames += 1;
                // Received, so not lost: a baseline for the counter only.
                self.prev = Some(counter);
                return self.bad_event(now, Some(byte), Some(counter), error);
            }
        };
        let mut event = FeedEvent {
            handwheel: self.node,
            at: now,
            byte: Some(byte),
            axis: Some(frame.axis),
            direction: Some(frame.direction),
            sequence: Some(counter),
            units: 0,
            gap: None,
            compensated: 0,
            flags: FeedFlags::default(),
            baseline_reason: None,
            error: None,
        };
        match self.prev {
            None => {
                event.units = 1;
                event.flags.baseline = true;
                event.baseline_reason = Some(self.pending_reason);
                self.stats.baselines += 1;
            }
            Some(prev) => {
                let m = self.layout.modulus();
                let gap = (counter + m - prev) % m;
                event.gap = Some(gap);
                if gap == 0 {
                    event.flags.duplicate = true;
                    self.stats.duplicates += 1;
                } else {
                    event.compensated = u32::from(gap - 1);
                    event.units = u32::from(gap);
                    if gap > 1 {
                        event.flags.compensated = true;
                        self.stats.gaps += 1;
                        self.stats.compensated_units += u64::from(gap - 1);
                    }
                }
            }
        }
        self.prev = Some(counter);
        self.stats.units_by_axis[usize::from(frame.axis.code())][dir_index(frame.direction)] +=
            u64::from(event.units);
        event
    }

    fn bad_event(
        &self,
        now: Duration,
        byte: Option<u8>,
        sequence: Option<u8>,
        error: BadFrame,
    ) -> FeedEvent {
        FeedEvent {
            handwheel: self.node,
            at: now,
            byte,
            axis: None,
            direction: None,
            sequence,
            units: 0,
            gap: None,
            compensated: 0,
            flags: FeedFlags {
                bad: true,
                ..FeedFlags::default()
            },
            baseline_reason: None,
            error: Some(error),
        }
    }
}

impl fmt::Display for HandwheelAxis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = match self {
            Self::X => "X",
            Self::Y => "Y",
            Self::Z => "Z",
            Self::W => "W",
            Self::V => "V",
        };
        f.write_str(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cangate_can::CanId;

    fn node() -> NodeId {
        NodeId::new(5).unwrap()
    }

    fn feed(byte: u8) -> Frame {
        Frame::new(CanId::standard(0x185).unwrap(), &[byte]).unwrap()
    }

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    fn byte(axis: HandwheelAxis, direction: Direction, counter: u8, l: CounterLayout) -> u8 {
        FeedFrame {
            axis,
            direction,
            counter,
        }
        .encode(l)
    }

    #[test]
    fn paper_trace_bits6_7() {
        let trace = [0x08, 0x48, 0x88, 0xC8, 0x08, 0x40, 0x80, 0xC0, 0x00];
        let mut d = FeedDecoder::new(node(), CounterLayout::Bits6_7);
        let events: Vec<_> = trace
            .iter()
            .enumerate()
            .map(|(i, &b)| d.on_frame(&feed(b), ms(i as u64)).unwrap())
            .collect();
        for (i, e) in events.iter().enumerate() {
            assert_eq!(e.axis, Some(HandwheelAxis::X));
            let want = if i < 5 {
                Direction::Positive
            } else {
                Direction::Negative
            };
            assert_eq!(e.direction, Some(want), "frame {i}");
            assert_eq!(e.units, 1);
            assert_eq!(e.compensated, 0);
            assert_eq!(e.sequence, Some(i as u8 % 4));
            assert!(!e.flags.duplicate && !e.flags.bad && !e.flags.compensated);
            assert_eq!(e.flags.baseline, i == 0);
            assert_eq!(e.gap, if i == 0 { None } else { Some(1) });
        }
        assert_eq!(events[0].baseline_reason, Some(BaselineReason::Startup));
        let s = d.stats();
        assert_eq!(s.frames, 9);
        assert_eq!(s.units(HandwheelAxis::X, Direction::Positive), 5);
        assert_eq!(s.units(HandwheelAxis::X, Direction::Negative), 4);
        assert_eq!(s.net_units(HandwheelAxis::X), 1);
        assert_eq!((s.gaps, s.duplicates, s.bad_frames), (0, 0, 0));
        // The same bytes with the nibble layout would be read as gaps.
        let mut n = FeedDecoder::new(node(), CounterLayout::Nibble);
        n.on_frame(&feed(0x08), ms(0));
        assert_eq!(n.on_frame(&feed(0x48), ms(1)).unwrap().gap, Some(4));
    }

    #[test]
    fn decode_and_encode() {
        assert_eq!(
            FeedFrame::decode(0xAC, CounterLayout::Nibble),
            Ok(FeedFrame {
                axis: HandwheelAxis::V,
                direction: Direction::Positive,
                counter: 0xA
            })
        );
        assert_eq!(
            FeedFrame::decode(0xB3, CounterLayout::Bits6_7),
            Ok(FeedFrame {
                axis: HandwheelAxis::W,
                direction: Direction::Negative,
                counter: 2
            })
        );
        for code in 5..8u8 {
            assert_eq!(
                FeedFrame::decode(0x10 | code, CounterLayout::Nibble),
                Err(BadFrame::InvalidAxis {
                    code,
                    byte: 0x10 | code
                })
            );
        }
        for b in 0..=255u8 {
            if let Ok(f) = FeedFrame::decode(b, CounterLayout::Nibble) {
                assert_eq!(f.encode(CounterLayout::Nibble), b);
            }
        }
    }

    #[test]
    fn nibble_every_gap_compensated() {
        let l = CounterLayout::Nibble;
        for gap in 1..=15u8 {
            for start in 0..16u8 {
                let mut d = FeedDecoder::new(node(), l);
                let first = byte(HandwheelAxis::Y, Direction::Negative, start, l);
                assert!(d.on_frame(&feed(first), ms(0)).unwrap().flags.baseline);
                let next = byte(HandwheelAxis::Y, Direction::Negative, start + gap, l);
                let e = d.on_frame(&feed(next), ms(1)).unwrap();
                assert_eq!(e.gap, Some(gap));
                assert_eq!(e.units, u32::from(gap));
                assert_eq!(e.compensated, u32::from(gap - 1));
                assert_eq!(e.flags.compensated, gap > 1);
                assert_eq!(e.signed_units(), -i64::from(gap));
                let s = d.stats();
                assert_eq!(
                    s.units(HandwheelAxis::Y, Direction::Negative),
                    1 + u64::from(gap)
                );
                assert_eq!(s.compensated_units, u64::from(gap - 1));
                assert_eq!(s.gaps, u64::from(gap > 1));
            }
        }
    }

    #[test]
    fn bits6_7_gaps_up_to_three() {
        let l = CounterLayout::Bits6_7;
        let mut d = FeedDecoder::new(node(), l);
        d.on_frame(
            &feed(byte(HandwheelAxis::Z, Direction::Positive, 0, l)),
            ms(0),
        );
        let e = d
            .on_frame(
                &feed(byte(HandwheelAxis::Z, Direction::Positive, 3, l)),
                ms(1),
            )
            .unwrap();
        assert_eq!((e.gap, e.units, e.compensated), (Some(3), 3, 2));
    }

    #[test]
    fn duplicates_reported_not_moved() {
        let l = CounterLayout::Nibble;
        let mut d = FeedDecoder::new(node(), l);
        let b = byte(HandwheelAxis::X, Direction::Positive, 7, l);
        d.on_frame(&feed(b), ms(0));
        let e = d.on_frame(&feed(b), ms(1)).unwrap();
        assert!(e.flags.duplicate);
        assert_eq!((e.gap, e.units, e.signed_units()), (Some(0), 0, 0));
        // The duplicate does not shift the baseline.
        let e = d
            .on_frame(
                &feed(byte(HandwheelAxis::X, Direction::Positive, 8, l)),
                ms(2),
            )
            .unwrap();
        assert_eq!((e.gap, e.units), (Some(1), 1));
        let s = d.stats();
        assert_eq!(s.duplicates, 1);
        assert_eq!(s.frames, 3);
        assert_eq!(s.total_units(), 2);
    }

    #[test]
    fn invalid_axis_counted_never_moved() {
        let l = CounterLayout::Nibble;
        let mut d = FeedDecoder::new(node(), l);
        // Bad before any baseline: still no movement, next frame is the baseline.
        let e = d.on_frame(&feed(0x0D), ms(0)).unwrap();
        assert!(e.flags.bad && e.axis.is_none() && e.units == 0);
        assert_eq!(e.signed_units(), 0);
        d.on_frame(&feed(0x1D), ms(1));
        let e = d.on_frame(&feed(0x28), ms(2)).unwrap();
        // A bad frame is received, not lost: gap 1 from its counter.
        assert_eq!((e.gap, e.units, e.compensated), (Some(1), 1, 0));
        for code in 5..8u8 {
            let e = d.on_frame(&feed(0x38 | code), ms(3)).unwrap();
            assert_eq!(
                e.error,
                Some(BadFrame::InvalidAxis {
                    code,
                    byte: 0x38 | code
                })
            );
        }
        let s = d.stats();
        assert_eq!(s.bad_frames, 5);
        assert_eq!(s.total_units(), 1);
        // Wrong length: bad and the baseline is dropped.
        let f = Frame::new(CanId::standard(0x185).unwrap(), &[0x48, 0]).unwrap();
        let e = d.on_frame(&f, ms(4)).unwrap();
        assert_eq!(e.error, Some(BadFrame::Length { len: 2 }));
        assert!(d.awaiting_baseline());
        let e = d.on_frame(&feed(0x98), ms(5)).unwrap();
        assert_eq!(e.baseline_reason, Some(BaselineReason::MalformedFrame));
        assert_eq!(d.stats().bad_frames, 6);
    }

    #[test]
    fn baseline_reset() {
        let l = CounterLayout::Nibble;
        let mut d = FeedDecoder::new(node(), l);
        d.on_frame(&feed(0x08), ms(0));
        d.on_frame(&feed(0x18), ms(1));
        // A long outage: 20 frames lost, the wheel's heartbeat was lost.
        d.reset_baseline(BaselineReason::HeartbeatLost);
        assert!(d.awaiting_baseline());
        let e = d.on_frame(&feed(0x58), ms(100)).unwrap();
        assert!(e.flags.baseline);
        assert_eq!(e.baseline_reason, Some(BaselineReason::HeartbeatLost));
        assert_eq!((e.gap, e.units, e.compensated), (None, 1, 0));
        // Boot-up of the wheel resets the baseline too.
        let boot = Frame::new(CanId::standard(0x705).unwrap(), &[0]).unwrap();
        assert!(d.on_frame(&boot, ms(200)).is_none());
        let e = d.on_frame(&feed(0x08), ms(201)).unwrap();
        assert_eq!(e.baseline_reason, Some(BaselineReason::DeviceRestart));
        d.reset_baseline(BaselineReason::ModeChange);
        let s = d.stats();
        assert_eq!((s.baselines, s.baseline_resets), (3, 3));
        assert_eq!(s.total_units(), 4);
        // Other nodes' frames are ignored.
        let other = Frame::new(CanId::standard(0x186).unwrap(), &[0x08]).unwrap();
        assert!(d.on_frame(&other, ms(300)).is_none());
        assert_eq!(d.stats().frames, 4);
    }
}
