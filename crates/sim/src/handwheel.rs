//! [`SimHandwheel`]: a simulated CANopen CNC handwheel (manual pulse
//! generator) per `shared/specs/handwheel.md`.
//!
//! The handwheel wraps a [`SimNode`] built from the handwheel EDS (by
//! default the bundled `cangate-handwheel.eds`), which serves SDO, NMT and
//! the heartbeat. On top of it:
//!
//! - [`SimHandwheel::turn`] adds `detents * multiplier` to the accumulator
//!   `S` (multiplier 1, 10 or 100, [`SimHandwheel::set_multiplier`]);
//! - while `S != 0`, the node is operational, the TPDO1 COB-ID (0x1800:01)
//!   is valid and the mode 0x2000 is 1 (manual), one feed frame per unit
//!   goes out on that COB-ID at an even pace
//!   ([`SimHandwheelOptions::frame_rate`]) and `S` moves one unit towards
//!   zero. While the feed is closed (any other mode, 0 = automatic; not
//!   operational; TPDO1 invalid) the wheel counts its turns
//!   ([`SimHandwheelStats::turned_units`]) but queues nothing: those units
//!   are discarded ([`SimHandwheelStats::discarded_units`]), and units still
//!   queued when the feed closes are discarded too. A wheel never replays
//!   a turn made while it could not send: switching to manual mode later
//!   must not move an axis by turns made in automatic mode;
//! - the feed byte is axis (bits 0–2, [`SimHandwheel::set_axis`]),
//!   direction (bit 3) and the sequence counter in the configured
//!   [`CounterLayout`], +1 per feed frame; it is also stored in 0x2001, and
//!   the switch positions in 0x2002/0x2003 when the EDS has them;
//! - an optional [`FrameLoss`] drops feed frames as if lost on the wire
//!   (the counter still advances).
//!
//! The node's own transmissions of TPDO1 (on entering operational, event
//! timer, RTR) are suppressed: only the wheel decides when a feed frame is
//! sent, one per unit.

use std::fmt;
use std::time::Duration;

use cangate_can::{CanId, Frame};
use cangate_canopen::eds::{Eds, SIM_HANDWHEEL_EDS};
use cangate_canopen::handwheel::{CounterLayout, Direction, FeedFrame, HandwheelAxis};
use cangate_canopen::nmt::NmtState;
use cangate_canopen::od::ObjectDictionary;
use cangate_canopen::value::Value;
use cangate_canopen::{NodeId, ObjectAddress};

use crate::canopen_node::{SimEvent, SimNode, SimNodeOptions};
use crate::{Device, SimError};

/// Operating mode object (0 = automatic, 1 = manual).
pub const MODE: ObjectAddress = ObjectAddress::new(0x2000, 0);
/// Last feed byte (the object mapped into TPDO1).
pub const FEED: ObjectAddress = ObjectAddress::new(0x2001, 0);
/// Multiplier switch position (1, 10, 100).
pub const MULTIPLIER: ObjectAddress = ObjectAddress::new(0x2002, 0);
/// Axis switch position (0–4).
pub const AXIS: ObjectAddress = ObjectAddress::new(0x2003, 0);
/// Value of [`MODE`] for manual mode (feed TPDOs).
pub const MODE_MANUAL: u8 = 1;
/// Value of [`MODE`] for automatic mode (no feed).
pub const MODE_AUTOMATIC: u8 = 0;
/// TPDO1 COB-ID.
const TPDO1_COB_ID: ObjectAddress = ObjectAddress::new(0x1800, 1);

/// The multiplier switch.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub enum Multiplier {
    /// x1.
    #[default]
    X1,
    /// x10.
    X10,
    /// x100.
    X100,
}

impl Multiplier {
    /// 1, 10 or 100.
    pub const fn factor(self) -> u8 {
        match self {
            Multiplier::X1 => 1,
            Multiplier::X10 => 10,
            Multiplier::X100 => 100,
        }
    }
}

/// Which feed frames are lost on the wire.
pub enum FrameLoss {
    /// None.
    None,
    /// Drops frame `n` (0-based index of feed frames sent since creation)
    /// when the closure returns true.
    Pattern(Box<dyn FnMut(u64) -> bool + Send>),
    /// Drops each frame with `probability` (0.0..=1.0) from a generator
    /// seeded with `seed`, but never more than `max_consecutive` in a row,
    /// and never the first or the last frame of a drain (sending until the
    /// accumulator is empty): a receiver learns of lost frames only from
    /// the next one, and a first frame may be its baseline (no gap check),
    /// so a test that turns the wheel and counts the feed sees every loss.
    Random {
        /// Loss probability per frame.
        probability: f64,
        /// Cap on consecutive losses.
        max_consecutive: u32,
        /// PRNG seed (deterministic runs).
        seed: u64,
    },
}

impl fmt::Debug for FrameLoss {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FrameLoss::None => f.write_str("None"),
            FrameLoss::Pattern(_) => f.write_str("Pattern(..)"),
            FrameLoss::Random {
                probability,
                max_consecutive,
                seed,
            } => f
                .debug_struct("Random")
                .field("probability", probability)
                .field("max_consecutive", max_consecutive)
                .field("seed", seed)
                .finish(),
        }
    }
}

/// How a [`SimHandwheel`] behaves beyond what its EDS says.
#[derive(Debug, Clone, PartialEq)]
pub struct SimHandwheelOptions {
    /// Options of the CANopen node underneath.
    pub node: SimNodeOptions,
    /// Counter layout of the feed byte.
    pub layout: CounterLayout,
    /// Feed frames per second (15 000 by default, about what a 1 Mbit/s
    /// bus carries with 1-byte frames; zero is taken as the default).
    pub frame_rate: u32,
}

impl Default for SimHandwheelOptions {
    fn default() -> Self {
        SimHandwheelOptions {
            node: SimNodeOptions::default(),
            layout: CounterLayout::Nibble,
            frame_rate: 15_000,
        }
    }
}

/// Counters of a [`SimHandwheel`]. They always add up:
/// `turned_units = frames + discarded_units + cancelled_units +
/// |pending_units|` ([`SimHandwheel::pending_units`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SimHandwheelStats {
    /// Feed frames produced (delivered + dropped), one per unit.
    pub frames: u64,
    /// Feed frames dropped by the [`FrameLoss`].
    pub dropped: u64,
    /// Units turned (`|detents| × multiplier` summed over every turn).
    pub turned_units: u64,
    /// Units discarded because the feed was closed (automatic mode, not
    /// operational, TPDO1 invalid) when they were turned or while they
    /// were still queued.
    pub discarded_units: u64,
    /// Queued units cancelled by a turn in the other direction (the
    /// accumulator is a signed sum).
    pub cancelled_units: u64,
}

/// A simulated CNC handwheel. See the [module documentation](self).
#[derive(Debug)]
pub struct SimHandwheel {
    node: SimNode,
    /// As built, for [`crate::PowerOn`].
    options: SimHandwheelOptions,
    layout: CounterLayout,
    period: Duration,
    accumulator: i64,
    multiplier: Multiplier,
    axis: HandwheelAxis,
    counter: u8,
    next_slot: Duration,
    now: Duration,
    loss: FrameLoss,
    rng: u64,
    consecutive_drops: u32,
    /// Frames sent (or lost) since the wheel last stopped sending.
    drain_frames: u64,
    stats: SimHandwheelStats,
}

impl SimHandwheel {
    /// A handwheel with the object dictionary of `eds` at `node`, not yet
    /// started.
    pub fn new(eds: &Eds, node: NodeId, options: SimHandwheelOptions) -> Self {
        Self::from_od(eds.od_with_dummies(), node, options)
    }

    /// A handwheel with the bundled `cangate-handwheel.eds`.
    pub fn bundled(node: NodeId, options: SimHandwheelOptions) -> Self {
        Self::from_eds_text(SIM_HANDWHEEL_EDS, node, options)
            .expect("the bundled handwheel EDS is valid")
    }

    /// A handwheel from EDS/DCF text.
    pub fn from_eds_text(
        text: &str,
        node: NodeId,
        options: SimHandwheelOptions,
    ) -> Result<Self, SimError> {
        Ok(Self::from_od(
            Eds::parse(text)?.od_with_dummies(),
            node,
            options,
        ))
    }

    /// A handwheel serving `od`.
    pub fn from_od(od: ObjectDictionary, node: NodeId, options: SimHandwheelOptions) -> Self {
        let rate = if options.frame_rate == 0 {
            SimHandwheelOptions::default().frame_rate
        } else {
            options.frame_rate
        };
        let mut wheel = SimHandwheel {
            node: SimNode::from_od(od, node, options.node.clone()),
            options: options.clone(),
            layout: options.layout,
            period: Duration::from_nanos(1_000_000_000 / u64::from(rate))
                .max(Duration::from_nanos(1)),
            accumulator: 0,
            multiplier: Multiplier::X1,
            axis: HandwheelAxis::X,
            counter: 0,
            next_slot: Duration::ZERO,
            now: Duration::ZERO,
            loss: FrameLoss::None,
            rng: 0,
            consecutive_drops: 0,
            drain_frames: 0,
            stats: SimHandwheelStats::default(),
        };
        wheel.publish_switches();
        wheel
    }

    /// The CANopen node underneath.
    pub fn node(&self) -> &SimNode {
        &self.node
    }

    /// The CANopen node underneath, e.g. to take its events.
    pub fn node_mut(&mut self) -> &mut SimNode {
        &mut self.node
    }

    /// The accumulator `S`: units still to send (signed).
    pub fn pending_units(&self) -> i64 {
        self.accumulator
    }

    /// Frames produced and dropped so far.
    pub fn stats(&self) -> SimHandwheelStats {
        self.stats
    }

    /// The counter value the next feed frame carries.
    pub fn next_counter(&self) -> u8 {
        self.counter
    }

    /// The selected axis.
    pub fn axis(&self) -> HandwheelAxis {
        self.axis
    }

    /// The multiplier switch.
    pub fn multiplier(&self) -> Multiplier {
        self.multiplier
    }

    /// True when 0x2000 is 1 (manual mode).
    pub fn is_manual(&self) -> bool {
        matches!(self.node.get(MODE), Some(Value::Unsigned8(MODE_MANUAL)))
    }

    /// Turns the wheel by `detents` (positive: A leads B): `S +=
    /// detents * multiplier` while the feed is open; otherwise the units
    /// are counted and discarded (see the [module documentation](self)).
    /// Returns the units queued by this turn (0 when discarded).
    pub fn turn(&mut self, detents: i32) -> i64 {
        let units = i64::from(detents) * i64::from(self.multiplier.factor());
        self.stats.turned_units += units.unsigned_abs();
        if !self.feed_open() {
            self.stats.discarded_units += units.unsigned_abs();
            return 0;
        }
        if self.accumulator == 0 {
            // Idle: the first frame may go out at once.
            self.next_slot = self.next_slot.max(self.now);
        }
        if self.accumulator.signum() * units.signum() < 0 {
            self.stats.cancelled_units +=
                2 * self.accumulator.unsigned_abs().min(units.unsigned_abs());
        }
        self.accumulator += units;
        units
    }

    /// Sets the axis switch.
    pub fn set_axis(&mut self, axis: HandwheelAxis) {
        self.axis = axis;
        self.publish_switches();
    }

    /// Sets the multiplier switch (applies to later detents).
    pub fn set_multiplier(&mut self, multiplier: Multiplier) {
        self.multiplier = multiplier;
        self.publish_switches();
    }

    /// Sets which feed frames are lost from now on.
    pub fn set_frame_loss(&mut self, loss: FrameLoss) {
        if let FrameLoss::Random { seed, .. } = loss {
            self.rng = seed;
        }
        self.consecutive_drops = 0;
        self.loss = loss;
    }

    fn publish_switches(&mut self) {
        // The objects may be absent from an EDS; then there is nothing to show.
        let _ = self
            .node
            .set(MULTIPLIER, Value::Unsigned8(self.multiplier.factor()));
        let _ = self.node.set(AXIS, Value::Unsigned8(self.axis.code()));
    }

    /// The TPDO1 COB-ID when valid (bit 31 clear).
    fn feed_cob_id(&self) -> Option<u16> {
        match self.node.get(TPDO1_COB_ID) {
            Some(Value::Unsigned32(v)) if v & 0x8000_0000 == 0 => Some((v & 0x7FF) as u16),
            _ => None,
        }
    }

    /// Whether feed frames may go out now: operational, manual mode and
    /// a valid TPDO1 COB-ID.
    pub fn feed_open(&self) -> bool {
        self.node.nmt_state() == NmtState::Operational
            && self.is_manual()
            && self.feed_cob_id().is_some()
    }

    fn can_send(&self) -> bool {
        self.accumulator != 0 && self.feed_open()
    }

    fn next_random(&mut self) -> f64 {
        // splitmix64
        self.rng = self.rng.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.rng;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }

    fn lost(&mut self, index: u64, edge: bool) -> bool {
        let drop = match &mut self.loss {
            FrameLoss::None => false,
            FrameLoss::Pattern(f) => f(index),
            FrameLoss::Random {
                probability,
                max_consecutive,
                ..
            } => {
                let (p, max) = (*probability, *max_consecutive);
                self.next_random() < p && self.consecutive_drops < max && !edge
            }
        };
        self.consecutive_drops = if drop { self.consecutive_drops + 1 } else { 0 };
        drop
    }

    /// Sends the feed frames due at `now`.
    fn pump(&mut self, now: Duration, out: &mut Vec<Frame>) {
        while self.can_send() && self.next_slot <= now {
            let Some(cob) = self.feed_cob_id() else { break };
            let direction = if self.accumulator > 0 {
                Direction::Positive
            } else {
                Direction::Negative
            };
            let byte = FeedFrame {
                axis: self.axis,
                direction,
                counter: self.counter,
            }
            .encode(self.layout);
            self.accumulator -= direction.sign();
            self.counter = (self.counter + 1) % self.layout.modulus();
            let _ = self.node.set(FEED, Value::Unsigned8(byte));
            let index = self.stats.frames;
            self.stats.frames += 1;
            self.next_slot += self.period;
            // Never lost: the first frame of a drain (it may be a
            // receiver's baseline, which has no gap check) and the last.
            let edge = self.accumulator == 0 || self.drain_frames == 0;
            self.drain_frames += 1;
            if self.lost(index, edge) {
                self.stats.dropped += 1;
                continue;
            }
            let id = CanId::standard(u32::from(cob)).expect("11-bit COB-ID");
            out.push(Frame::new(id, &[byte]).expect("1-byte frame"));
        }
        if !self.feed_open() && self.accumulator != 0 {
            // Queued units are stale once the feed closes: sending them when
            // it reopens would move an axis nobody is turning.
            self.stats.discarded_units += self.accumulator.unsigned_abs();
            self.accumulator = 0;
        }
        if !self.can_send() {
            // Idle or blocked: the next frame may go as soon as allowed.
            self.next_slot = self.next_slot.max(now);
            self.drain_frames = 0;
        }
    }

    /// Drops the node's own TPDO1 transmissions (only the wheel sends feed).
    fn filter(&self, frames: Vec<Frame>) -> Vec<Frame> {
        let cob = self.feed_cob_id();
        frames
            .into_iter()
            .filter(|f| cob.is_none_or(|c| f.raw_id() != u32::from(c) || f.is_extended()))
            .collect()
    }

    fn drain_events(&mut self) {
        for event in self.node.take_events() {
            if let SimEvent::Reset { .. } = event {
                self.publish_switches();
            }
        }
    }
}

impl crate::PowerOn for SimHandwheel {
    fn powered_on(&self) -> Self {
        let mut wheel = SimHandwheel::from_od(
            self.node.od().clone(),
            self.node.node_id(),
            self.options.clone(),
        );
        // The program is in flash: it survives the power cut.
        wheel.node.keep_program_of(&self.node);
        wheel
    }
}

impl Device for SimHandwheel {
    fn start(&mut self, now: Duration) -> Vec<Frame> {
        self.now = now;
        self.next_slot = self.next_slot.max(now);
        let out = self.node.start(now);
        // Only this start finds it running; a power cycle boots it.
        self.options.node.running_at_start = None;
        self.drain_events();
        out
    }

    fn on_frame(&mut self, frame: &Frame, now: Duration) -> Vec<Frame> {
        self.now = now;
        let out = self.node.on_frame(frame, now);
        self.drain_events();
        let mut out = self.filter(out);
        self.pump(now, &mut out);
        out
    }

    fn on_tick(&mut self, now: Duration) -> Vec<Frame> {
        self.now = now;
        let out = self.node.on_tick(now);
        self.drain_events();
        let mut out = self.filter(out);
        self.pump(now, &mut out);
        out
    }

    fn receive_filters(&self) -> Option<Vec<cangate_can::Filter>> {
        Some(self.node.receive_filters())
    }

    fn filter_generation(&self) -> u64 {
        self.node.filter_generation()
    }

    fn next_deadline(&self) -> Option<Duration> {
        let feed = self.can_send().then_some(self.next_slot);
        [feed, self.node.next_deadline()]
            .into_iter()
            .flatten()
            .min()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cangate_canopen::handwheel::{FeedDecoder, HandwheelAxis};

    const NODE: u8 = 3;

    fn frame(id: u32, data: &[u8]) -> Frame {
        Frame::new(CanId::standard(id).unwrap(), data).unwrap()
    }

    /// Boots the wheel, starts it (NMT) and writes the mode over SDO.
    fn wheel(layout: CounterLayout, mode: u8) -> SimHandwheel {
        let options = SimHandwheelOptions {
            layout,
            ..SimHandwheelOptions::default()
        };
        let mut w = SimHandwheel::bundled(NodeId::new(u32::from(NODE)).unwrap(), options);
        w.start(Duration::ZERO);
        w.on_frame(&frame(0, &[0x01, NODE]), Duration::ZERO);
        let sdo = [0x2F, 0x00, 0x20, 0x00, mode, 0, 0, 0];
        let out = w.on_frame(&frame(0x600 + u32::from(NODE), &sdo), Duration::ZERO);
        assert_eq!(out[0].data()[0], 0x60, "SDO download confirmed");
        assert_eq!(w.is_manual(), mode == MODE_MANUAL);
        w
    }

    /// Runs the wheel in virtual time until idle; returns feed frames with times.
    fn run(w: &mut SimHandwheel, until: Duration) -> Vec<(Duration, Frame)> {
        let feed_id = 0x180 + u32::from(NODE);
        let mut got = Vec::new();
        while let Some(t) = w.next_deadline() {
            if t > until {
                break;
            }
            for f in w.on_tick(t) {
                if f.raw_id() == feed_id {
                    got.push((t, f));
                }
            }
        }
        got
    }

    #[test]
    fn paper_trace_from_sim() {
        let mut w = wheel(CounterLayout::Bits6_7, MODE_MANUAL);
        w.turn(5);
        let mut bytes: Vec<u8> = run(&mut w, Duration::from_secs(1))
            .iter()
            .map(|(_, f)| f.data()[0])
            .collect();
        w.turn(-4);
        bytes.extend(
            run(&mut w, Duration::from_secs(2))
                .iter()
                .map(|(_, f)| f.data()[0]),
        );
        assert_eq!(
            bytes,
            [0x08, 0x48, 0x88, 0xC8, 0x08, 0x40, 0x80, 0xC0, 0x00]
        );
        assert_eq!(w.node().get(FEED), Some(&Value::Unsigned8(0x00)));
    }

    #[test]
    fn even_pace_and_switches() {
        let mut w = wheel(CounterLayout::Nibble, MODE_MANUAL);
        w.set_axis(HandwheelAxis::Z);
        w.set_multiplier(Multiplier::X10);
        // 0x2002 is absent from the bundled EDS (see the report), so not set.
        assert_eq!(w.node().get(MULTIPLIER), None);
        w.turn(-2);
        let got = run(&mut w, Duration::from_secs(1));
        assert_eq!(got.len(), 20);
        let period = Duration::from_nanos(1_000_000_000 / 15_000);
        for pair in got.windows(2) {
            assert_eq!(pair[1].0 - pair[0].0, period);
        }
        for (i, (_, f)) in got.iter().enumerate() {
            assert_eq!(f.data(), [0x02 | ((i as u8 % 16) << 4)]);
        }
        assert_eq!(w.pending_units(), 0);
    }

    #[test]
    fn automatic_mode_sends_no_feed_and_replays_nothing() {
        let mut w = wheel(CounterLayout::Nibble, MODE_AUTOMATIC);
        assert_eq!(w.turn(7), 0, "nothing queued in automatic mode");
        assert!(run(&mut w, Duration::from_secs(3)).is_empty());
        assert_eq!(w.pending_units(), 0);
        assert_eq!(w.stats().turned_units, 7, "keeps counting its turns");
        assert_eq!(w.stats().discarded_units, 7);
        assert_eq!(w.stats().frames, 0);
        // Switching to manual sends nothing of what was turned before.
        let sdo = [0x2F, 0x00, 0x20, 0x00, MODE_MANUAL, 0, 0, 0];
        let out = w.on_frame(
            &frame(0x600 + u32::from(NODE), &sdo),
            Duration::from_secs(3),
        );
        assert!(out.iter().all(|f| f.raw_id() != 0x183), "{out:?}");
        assert!(run(&mut w, Duration::from_secs(4)).is_empty());
        // A turn in manual mode is sent.
        w.turn(2);
        assert_eq!(run(&mut w, Duration::from_secs(5)).len(), 2);
    }

    #[test]
    fn units_queued_when_the_feed_closes_are_discarded() {
        let mut w = wheel(CounterLayout::Nibble, MODE_MANUAL);
        w.set_multiplier(Multiplier::X100);
        w.turn(10);
        // 1000 units at 15 000/s: some went out in the first 10 ms.
        let sent = run(&mut w, Duration::from_millis(10)).len() as u64;
        assert!(sent > 0 && sent < 1000, "{sent}");
        let sdo = [0x2F, 0x00, 0x20, 0x00, MODE_AUTOMATIC, 0, 0, 0];
        w.on_frame(
            &frame(0x600 + u32::from(NODE), &sdo),
            Duration::from_millis(10),
        );
        assert_eq!(w.pending_units(), 0);
        assert_eq!(w.stats().discarded_units, 1000 - w.stats().frames);
        let sdo = [0x2F, 0x00, 0x20, 0x00, MODE_MANUAL, 0, 0, 0];
        w.on_frame(
            &frame(0x600 + u32::from(NODE), &sdo),
            Duration::from_millis(20),
        );
        assert!(run(&mut w, Duration::from_secs(2)).is_empty(), "no replay");
    }

    #[test]
    fn no_feed_before_operational_nor_node_tpdo() {
        let mut w = SimHandwheel::bundled(NodeId::new(3).unwrap(), SimHandwheelOptions::default());
        w.start(Duration::ZERO);
        w.node_mut()
            .set(MODE, Value::Unsigned8(MODE_MANUAL))
            .unwrap();
        w.turn(3);
        assert!(run(&mut w, Duration::from_secs(1)).is_empty());
        assert_eq!(w.stats().discarded_units, 3, "turned before operational");
        // Entering operational: the node's own TPDO1 (stale 0x2001) is
        // suppressed, and the turn made before is not replayed.
        let out = w.on_frame(&frame(0, &[0x01, NODE]), Duration::from_secs(1));
        assert!(out.iter().all(|f| f.raw_id() != 0x183), "{out:?}");
        w.turn(3);
        let got = run(&mut w, Duration::from_secs(3));
        assert_eq!(got.len(), 3, "no event-timer resends");
        assert_eq!(got[0].1.data(), [0x08]);
    }

    /// The counters add up after any sequence of turns, mode changes, NMT
    /// commands and ticks (random sequences, fixed seeds).
    #[test]
    fn counters_add_up_under_random_sequences() {
        for seed in 1..=200u64 {
            let mut rng = seed;
            let mut next = move |n: u64| {
                rng ^= rng << 13;
                rng ^= rng >> 7;
                rng ^= rng << 17;
                rng % n
            };
            let mut w = wheel(CounterLayout::Nibble, MODE_MANUAL);
            let mut now = Duration::ZERO;
            let mut log = Vec::new();
            for _ in 0..60 {
                let step = next(8);
                log.push(step);
                match step {
                    0..=2 => {
                        w.set_multiplier(
                            [Multiplier::X1, Multiplier::X10, Multiplier::X100][next(3) as usize],
                        );
                        w.turn(next(41) as i32 - 20);
                    }
                    3 => {
                        let mode = next(2) as u8;
                        let sdo = [0x2F, 0x00, 0x20, 0x00, mode, 0, 0, 0];
                        w.on_frame(&frame(0x600 + u32::from(NODE), &sdo), now);
                    }
                    4 => {
                        let cs = [0x01, 0x02, 0x80, 0x81][next(4) as usize];
                        w.on_frame(&frame(0, &[cs, NODE]), now);
                    }
                    5 => w.set_frame_loss(FrameLoss::Random {
                        probability: 0.3,
                        max_consecutive: 14,
                        seed: next(1000),
                    }),
                    _ => {
                        now += Duration::from_micros(next(20_000));
                        run(&mut w, now);
                    }
                }
                let s = w.stats();
                assert_eq!(
                    s.turned_units,
                    s.frames
                        + s.discarded_units
                        + s.cancelled_units
                        + w.pending_units().unsigned_abs(),
                    "seed {seed}, steps {log:?}: {s:?}, pending {}",
                    w.pending_units()
                );
                assert!(s.dropped <= s.frames);
                if !w.feed_open() {
                    assert_eq!(w.pending_units(), 0, "seed {seed}, steps {log:?}");
                }
            }
        }
    }

    fn decode_all(d: &mut FeedDecoder, frames: &[(Duration, Frame)]) -> (i64, u64) {
        let mut moved = 0;
        for (t, f) in frames {
            let e = d.on_frame(f, *t).unwrap();
            assert!(!e.flags.bad && !e.flags.duplicate);
            moved += e.signed_units();
        }
        (moved, d.stats().compensated_units)
    }

    #[test]
    fn loss_compensated_exactly() {
        let mut w = wheel(CounterLayout::Nibble, MODE_MANUAL);
        w.set_multiplier(Multiplier::X10);
        // 10 % loss, at most 14 in a row (15 would wrap to gap 0); the first frame (baseline) and the
        // last one (revealing trailing losses) get through.
        let mut rng = 0x1234_5678_u64;
        let mut run_len = 0;
        w.set_frame_loss(FrameLoss::Pattern(Box::new(move |i| {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            let drop = i != 0 && i != 1999 && rng.is_multiple_of(10) && run_len < 14;
            run_len = if drop { run_len + 1 } else { 0 };
            drop
        })));
        for _ in 0..200 {
            w.turn(1);
        }
        let got = run(&mut w, Duration::from_secs(5));
        let s = w.stats();
        assert_eq!(s.frames, 2000);
        assert!(s.dropped > 100 && s.dropped < 300, "{s:?}");
        assert_eq!(got.len() as u64, 2000 - s.dropped);
        let mut d = FeedDecoder::new(NodeId::new(3).unwrap(), CounterLayout::Nibble);
        let (moved, compensated) = decode_all(&mut d, &got);
        assert_eq!(moved, 2000);
        assert_eq!(compensated, s.dropped);
        assert_eq!(d.stats().units(HandwheelAxis::X, Direction::Positive), 2000);
    }

    #[test]
    fn random_loss_capped() {
        let mut w = wheel(CounterLayout::Nibble, MODE_MANUAL);
        w.set_multiplier(Multiplier::X100);
        w.set_frame_loss(FrameLoss::Random {
            probability: 0.9,
            // 15 lost frames make gap 16 = 0 (a duplicate): 14 is the limit.
            max_consecutive: 14,
            seed: 7,
        });
        w.turn(20);
        let got = run(&mut w, Duration::from_secs(5));
        let s = w.stats();
        assert_eq!(s.frames, 2000);
        assert!(s.dropped > 1500, "{s:?}");
        // Flush: one more frame without loss reveals any trailing losses.
        w.set_frame_loss(FrameLoss::None);
        w.set_multiplier(Multiplier::X1);
        w.turn(1);
        let mut all = got;
        all.extend(run(&mut w, Duration::from_secs(6)));
        let mut d = FeedDecoder::new(NodeId::new(3).unwrap(), CounterLayout::Nibble);
        let (moved, _) = decode_all(&mut d, &all);
        // Only frames lost before the baseline are unrecoverable.
        let first = all[0].1.data()[0] >> 4;
        assert_eq!(moved, 2001 - i64::from(first));
        let mut cons = 0;
        let mut prev = None;
        for (_, f) in &all {
            let c = f.data()[0] >> 4;
            if let Some(p) = prev {
                cons = (c + 16 - p) % 16 - 1;
                assert!(cons <= 15);
            }
            prev = Some(c);
        }
        let _ = cons;
    }
}
