//! The cyclic set-points of a bus's CSP axes, sent by the CANopen master's
//! SYNC thread with every SYNC.
//!
//! The axis task publishes each cyclic axis's [`CyclicPlan`] here whenever
//! it changes (a move, a stop, the drive enabled or lost). At every SYNC
//! the SYNC thread samples each plan, patches the target position into the
//! axis's set-point RPDO and sends it in the SYNC's batch, then leaves the
//! sample for the axis task, which hands it to the axis
//! ([`cangate_axis::cia402::Cia402Axis::on_cyclic_sample`]) at its next
//! wake-up (the drives' TPDOs answering that SYNC).
//!
//! Why: computed by the axis task, each set-point needed that task woken by
//! every SYNC, a thread hand-over per period ("Wake-ups cost more than
//! frames" in docs/design.md). The set-point
//! now also leaves in the same batch as its SYNC, whatever the load on the
//! gateway's bus thread.
//!
//! Set-points are sampled on the SYNC's nominal grid (k·T, not when the
//! thread got to send it), and periods the thread skipped hold each plan
//! back ([`CyclicPlan::hold_back`]): the plan advances one period per SYNC
//! actually sent, so a late or stalled SYNC never becomes a double step.
//!
//! Only the RPDO that maps the target position (0x607A) is sent here; the
//! other RPDOs (the controlword) still go out from the axis task the moment
//! they change. Where a custom mapping puts the controlword into the
//! target-position RPDO, a controlword change rides with the next SYNC.

use crate::canopen::sync_thread::{SyncRider, SyncTick};
use cangate_axis::Units;
use cangate_axis::cia402::{CyclicPlan, CyclicSample, SetpointObject};
use cangate_axis::setpoint_stream::{
    AxisLimits, PlayerConfig, PlayerCounters, PlayerEvent, PlayerState, PointRefused, SetpointKind,
    SetpointPlayer, StreamPoint,
};
use cangate_can::{CanId, Frame};
use cangate_canopen::cia402::first_axis;
use cangate_canopen::cia402::objects::{
    INTERPOLATION_DATA, TARGET_POSITION, TARGET_TORQUE, TARGET_VELOCITY, TORQUE_OFFSET,
    VELOCITY_OFFSET,
};
use cangate_canopen::pdo::PdoConfig;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Where the target position sits in an RPDO.
#[derive(Debug, Clone)]
pub struct SetpointLayout {
    /// The RPDO that maps the target position.
    pub rpdo: PdoConfig,
    /// Byte offset of the 32-bit target position in its payload.
    pub offset: usize,
    /// Byte offset of the 32-bit target velocity in the same payload, if
    /// mapped there: a CSV axis's set-point.
    pub velocity_offset: Option<usize>,
}

impl SetpointLayout {
    /// The layout of the first RPDO in `rpdos` that maps the target
    /// position as 32 bits (PDO mappings here are byte-aligned).
    pub fn find(rpdos: &[PdoConfig]) -> Option<SetpointLayout> {
        for p in rpdos {
            let mut offset = 0;
            let mut position = None;
            let mut velocity = None;
            for m in &p.mapping {
                // Any axis of a multi-axis drive (the RPDOs are the axis's).
                let addr = first_axis(m.addr);
                // Interpolated position: 0x60C1:01 takes the position.
                if (addr == TARGET_POSITION || addr == INTERPOLATION_DATA) && m.bits == 32 {
                    position = Some(offset);
                }
                if addr == TARGET_VELOCITY && m.bits == 32 {
                    velocity = Some(offset);
                }
                offset += usize::from(m.bits) / 8;
            }
            if let Some(offset) = position {
                return Some(SetpointLayout {
                    rpdo: p.clone(),
                    offset,
                    velocity_offset: velocity,
                });
            }
        }
        None
    }

    /// `payload` with the target position's bytes cleared: what a change
    /// of the RPDO's other values is compared on.
    pub fn masked(&self, payload: &[u8]) -> Vec<u8> {
        let mut p = payload.to_vec();
        for at in std::iter::once(self.offset).chain(self.velocity_offset) {
            if let Some(target) = p.get_mut(at..at + 4) {
                target.fill(0);
            }
        }
        p
    }
}

/// The RPDO a torque stream sends each SYNC's torque in: one that maps
/// the target torque (0x6071, 16 bits) and nothing else (the gateway's
/// torque RPDO, [`cangate_axis::process_data::torque_rpdo`]), so the
/// SYNC thread owns its whole payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TorqueLayout {
    /// Its COB-ID.
    pub cob_id: u16,
}

impl TorqueLayout {
    /// The first RPDO in `rpdos` that maps the target torque alone.
    pub fn find(rpdos: &[PdoConfig]) -> Option<TorqueLayout> {
        rpdos.iter().find_map(|p| {
            matches!(p.mapping.as_slice(), [m] if first_axis(m.addr) == TARGET_TORQUE && m.bits == 16)
                .then(|| TorqueLayout {
                    cob_id: p.cob_id,
                })
        })
    }

    /// The RPDO frame commanding `per_mille` (rounded, within i16).
    pub fn frame(&self, per_mille: f64) -> Option<Frame> {
        let t = per_mille.round().clamp(-32768.0, 32767.0) as i16;
        Frame::new(CanId::Standard(self.cob_id), &t.to_le_bytes()).ok()
    }
}

/// The RPDO a position stream sends each SYNC's feed-forward in: velocity
/// offset 0x60B1 (32 bits) first and, where mapped, torque offset 0x60B2
/// (16 bits) after it, and nothing else
/// ([`cangate_axis::process_data::feed_forward_rpdo`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FeedForwardLayout {
    /// Its COB-ID.
    pub cob_id: u16,
    /// It carries the torque offset too.
    pub torque: bool,
}

impl FeedForwardLayout {
    /// The first RPDO in `rpdos` that maps the velocity offset (and
    /// perhaps the torque offset) as above.
    pub fn find(rpdos: &[PdoConfig]) -> Option<FeedForwardLayout> {
        rpdos.iter().find_map(|p| {
            let objects: Vec<_> = p
                .mapping
                .iter()
                .map(|m| (first_axis(m.addr), m.bits))
                .collect();
            let torque = match objects.as_slice() {
                [(VELOCITY_OFFSET, 32)] => false,
                [(VELOCITY_OFFSET, 32), (TORQUE_OFFSET, 16)] => true,
                _ => return None,
            };
            Some(FeedForwardLayout {
                cob_id: p.cob_id,
                torque,
            })
        })
    }

    /// The RPDO frame with velocity offset `velocity_counts` (counts/s)
    /// and torque offset `torque` (per mille, rounded within i16; sent
    /// where mapped).
    pub fn frame(&self, velocity_counts: i32, torque: f64) -> Option<Frame> {
        let mut data = velocity_counts.to_le_bytes().to_vec();
        if self.torque {
            let t = torque.round().clamp(-32768.0, 32767.0) as i16;
            data.extend_from_slice(&t.to_le_bytes());
        }
        Frame::new(CanId::Standard(self.cob_id), &data).ok()
    }
}

/// One axis's entry.
#[derive(Debug, Default)]
struct Entry {
    /// The published plan, as sampled since; `None`: nothing is sent.
    plan: Option<CyclicPlan>,
    /// The set-point RPDO: COB-ID, payload (the target position is patched
    /// in at each SYNC), offset of the target position.
    rpdo: Option<(u16, Vec<u8>, usize)>,
    /// Samples of `plan` not yet taken by the axis task: the latest, after
    /// every sample that ended a trajectory or started a dead-man stop
    /// (the axis must see those even when it wakes only every few SYNCs).
    samples: Vec<CyclicSample>,
    /// The axis's name, for a veto's reason.
    name: String,
    /// The set-point stream that drives this axis instead of `plan`.
    stream: Option<u64>,
    /// The holding plan a stream left the axis with: the axis's own plans
    /// that hold elsewhere are from samples before the stream ended and
    /// are ignored until the axis has caught up (one that moves, or none,
    /// is taken at once).
    settling: Option<CyclicPlan>,
    /// This SYNC's sample from the axis's stream.
    streamed: Option<CyclicSample>,
    /// Byte offset of the target velocity in the set-point RPDO (CSV).
    velocity_offset: Option<usize>,
    /// The torque RPDO (CST), if the axis has one a stream may send.
    torque: Option<TorqueLayout>,
    /// This SYNC's torque from the axis's torque stream (per mille).
    streamed_torque: Option<f64>,
    /// The feed-forward RPDO (0x60B1, 0x60B2), if the drive has one.
    feed_forward: Option<FeedForwardLayout>,
    /// This SYNC's feed-forward from the axis's position stream: velocity
    /// offset (counts/s) and torque offset (per mille).
    streamed_feed_forward: Option<(i32, f64)>,
}

/// Why a set-point stream ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StreamEnd {
    /// The client ended it: the buffered points were played, then the
    /// axes ramped to rest.
    ClientEnded,
    /// The client cancelled it or went away.
    ClientGone,
    /// A stop or quick stop of one of its axes (from anyone: a stop never
    /// waits for the stream).
    Stopped {
        /// The axis stopped.
        axis: String,
    },
    /// The control lease no longer covers its axes.
    LeaseLost(String),
    /// One of its axes left operation enabled in cyclic position mode
    /// (disabled, fault, node lost).
    AxisLeft {
        /// The axis.
        axis: String,
    },
    /// One of its axes ran into an active limit switch: the axis stopped
    /// at its quick stop deceleration, the others ramped to rest.
    LimitSwitch {
        /// The axis.
        axis: String,
        /// "negative" or "positive".
        switch: &'static str,
    },
    /// A torque stream's guard stopped one of its axes (its velocity
    /// above the maximum, or a stop from where it is would pass a soft
    /// limit): every torque ramped to 0 and the drives halted.
    TorqueGuard {
        /// The axis.
        axis: String,
        /// What the guard saw.
        why: String,
    },
    /// A torque stream ran out of points: the torques ramped to 0 and the
    /// drives halted (a halted drive takes no torque: a torque stream
    /// does not resume after an underrun).
    Underrun,
    /// The gateway shuts down.
    ShuttingDown,
}

impl std::fmt::Display for StreamEnd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StreamEnd::ClientEnded => write!(f, "the client ended the stream"),
            StreamEnd::ClientGone => write!(f, "the client cancelled the stream or went away"),
            StreamEnd::Stopped { axis } => write!(
                f,
                "axis {axis} was stopped: the stream ended and its axes ramped to rest"
            ),
            StreamEnd::LeaseLost(why) => write!(
                f,
                "the control lease no longer covers the stream's axes ({why}): they ramped to rest"
            ),
            StreamEnd::LimitSwitch { axis, switch } => write!(
                f,
                "axis {axis} ran into its {switch} limit switch and stopped: the stream ended and \
                 its other axes ramped to rest"
            ),
            StreamEnd::AxisLeft { axis } => write!(
                f,
                "axis {axis} left operation enabled in cyclic position mode (disabled, fault or \
                 node lost): the stream ended"
            ),
            StreamEnd::TorqueGuard { axis, why } => write!(
                f,
                "axis {axis}: {why}; the stream ended, its torques ramped to 0 and its drives \
                 halted"
            ),
            StreamEnd::Underrun => write!(
                f,
                "no point came in time: the torques ramped to 0 and the drives halted (a torque \
                 stream ends on an underrun)"
            ),
            StreamEnd::ShuttingDown => write!(f, "the gateway shuts down"),
        }
    }
}

/// Where a set-point stream stands.
#[derive(Debug, Clone)]
pub struct StreamReport {
    /// The player's state.
    pub state: PlayerState,
    /// The counters.
    pub counters: PlayerCounters,
    /// Client time buffered ahead of the playout.
    pub level: Duration,
    /// Gateway time minus client time of the fastest recent arrival, µs.
    pub clock_offset_us: Option<i64>,
    /// The commanded positions (user units, stream order).
    pub positions: Vec<f64>,
    /// What happened since the last report, in order.
    pub events: Vec<PlayerEvent>,
    /// Why it ended, once it did.
    pub end: Option<StreamEnd>,
    /// Ended and at rest: every axis is back on its own plan.
    pub finished: bool,
}

/// One stream as the thread that plays it holds it (the SYNC thread
/// here, a CANsmc master's cycle thread in [`super::cansmc_setpoints`]).
#[derive(Debug)]
pub(super) struct PlayedStream<X> {
    pub(super) id: u64,
    /// Table indices of its axes, in the stream's order.
    pub(super) axes: Vec<usize>,
    pub(super) player: SetpointPlayer,
    /// Periods skipped since it started: its clock is held back by them,
    /// as a plan is ([`CyclicPlan::hold_back`]), so a late SYNC or cycle
    /// never carries a double step.
    pub(super) held_back: Duration,
    pub(super) end: Option<StreamEnd>,
    pub(super) events: Vec<PlayerEvent>,
    pub(super) finished: bool,
    /// Its session is gone: dropped once finished.
    pub(super) orphaned: bool,
    /// What only its thread keeps (here the axes' units; a CANsmc master:
    /// whether the axes were handed to the stream).
    pub(super) extra: X,
}

impl<X> PlayedStream<X> {
    pub(super) fn new(id: u64, axes: &[usize], player: SetpointPlayer, extra: X) -> Self {
        PlayedStream {
            id,
            axes: axes.to_vec(),
            player,
            held_back: Duration::ZERO,
            end: None,
            events: Vec::new(),
            finished: false,
            orphaned: false,
            extra,
        }
    }

    pub(super) fn stop(&mut self, reason: StreamEnd, now: Duration) {
        if self.end.is_none() {
            self.end = Some(reason);
        }
        self.player.stop(now.saturating_sub(self.held_back));
    }

    /// Where it stands at `now`; the events since the last report.
    pub(super) fn report(&mut self, now: Duration) -> StreamReport {
        StreamReport {
            state: self.player.state(),
            counters: self.player.counters(),
            level: self.player.level(now.saturating_sub(self.held_back)),
            clock_offset_us: self.player.clock_offset_us(),
            positions: self.player.position().to_vec(),
            events: std::mem::take(&mut self.events),
            end: self.end.clone(),
            finished: self.finished,
        }
    }
}

/// The session of stream `id` in `streams` is gone: a stream still
/// playing ramps to rest (ended by `reason` unless it had ended already)
/// and is dropped once at rest.
pub(super) fn close_stream<X>(
    streams: &mut Vec<PlayedStream<X>>,
    id: u64,
    reason: StreamEnd,
    now: Duration,
) {
    let Some(s) = streams.iter_mut().find(|s| s.id == id) else {
        return;
    };
    if !s.finished {
        s.stop(reason, now);
    }
    s.orphaned = true;
    streams.retain(|s| !(s.finished && s.orphaned));
}

/// A stream of the SYNC thread: `extra` are its axes' units.
type SyncStream = PlayedStream<Vec<Units>>;

/// The table's state, under one lock.
#[derive(Debug, Default)]
struct State {
    entries: Vec<Entry>,
    streams: Vec<SyncStream>,
    next_stream: u64,
}

impl State {
    fn stream(&mut self, id: u64) -> Option<&mut SyncStream> {
        self.streams.iter_mut().find(|s| s.id == id)
    }
}

/// The table shared by one bus's axis task and its master's SYNC thread,
/// indexed by the task's axis index.
#[derive(Debug)]
pub struct CyclicSetpoints {
    /// The axis task's clock: samples are taken in its time.
    origin: Instant,
    state: Mutex<State>,
}

impl CyclicSetpoints {
    /// A table for the named axes, all without a plan, on the clock that
    /// starts at `origin`.
    pub fn new(origin: Instant, names: impl IntoIterator<Item = String>) -> CyclicSetpoints {
        CyclicSetpoints {
            origin,
            state: Mutex::new(State {
                entries: names
                    .into_iter()
                    .map(|name| Entry {
                        name,
                        ..Entry::default()
                    })
                    .collect(),
                ..State::default()
            }),
        }
    }

    /// Replaces the plans of several axes at once, so that a multi-axis
    /// command starts in one SYNC: (axis, plan or `None` to stop sending,
    /// COB-ID and current payload of its set-point RPDO, target offset).
    /// Drops the samples of the replaced plans. A plan that is the one
    /// sampled here as published earlier (the axis took up a sample's
    /// start) keeps the copy sampled here, which may have been held back
    /// since.
    pub fn publish(
        &self,
        plans: impl IntoIterator<Item = (usize, Option<CyclicPlan>, u16, Vec<u8>, usize)>,
    ) {
        let now = self.origin.elapsed();
        let mut st = self.state.lock().expect("set-point table lock");
        let State {
            entries, streams, ..
        } = &mut *st;
        for (i, plan, cob, payload, offset) in plans {
            let Some(e) = entries.get_mut(i) else {
                continue;
            };
            if let Some(id) = e.stream {
                if plan.as_ref().is_some_and(|p| !p.is_moving()) {
                    // The stream rules the set-point; the RPDO's other
                    // values follow the axis.
                    e.rpdo = Some((cob, payload, offset));
                    continue;
                }
                // A stop ramp (a stop reached the axis), or the drive left
                // operation enabled: the axis follows its own plan from
                // now on, the stream's other axes ramp to rest. Its plan
                // has no feed-forward: the drive's goes to 0.
                e.stream = None;
                if e.feed_forward.is_some() {
                    e.streamed_feed_forward = Some((0, 0.0));
                }
                let reason = if plan.is_some() {
                    StreamEnd::Stopped {
                        axis: e.name.clone(),
                    }
                } else {
                    StreamEnd::AxisLeft {
                        axis: e.name.clone(),
                    }
                };
                if let Some(s) = streams.iter_mut().find(|s| s.id == id) {
                    s.stop(reason, now);
                }
            }
            if let Some(settled) = &e.settling {
                if plan
                    .as_ref()
                    .is_some_and(|p| !p.is_moving() && !p.same_motion(settled))
                {
                    e.rpdo = Some((cob, payload, offset));
                    continue;
                }
                e.settling = None;
            }
            e.rpdo = plan.is_some().then_some((cob, payload, offset));
            if let (Some(old), Some(new)) = (&e.plan, &plan)
                && old.same_motion(new)
            {
                continue;
            }
            e.plan = plan;
            e.samples.clear();
        }
    }

    /// The set-point RPDO's other values changed (a custom mapping with
    /// the controlword): the next SYNC carries `payload`.
    pub fn set_payload(&self, i: usize, payload: Vec<u8>) {
        let mut st = self.state.lock().expect("set-point table lock");
        if let Some((_, p, _)) = st.entries.get_mut(i).and_then(|e| e.rpdo.as_mut()) {
            *p = payload;
        }
    }

    /// Where axis `i`'s set-point RPDO carries the target velocity: a
    /// CSV plan's samples go there.
    pub fn set_velocity_offset(&self, i: usize, offset: Option<usize>) {
        let mut st = self.state.lock().expect("set-point table lock");
        if let Some(e) = st.entries.get_mut(i) {
            e.velocity_offset = offset;
        }
    }

    /// The torque RPDO of axis `i`, which a torque stream sends each
    /// SYNC's torque in (`None`: the axis takes no torque stream).
    pub fn set_torque_rpdo(&self, i: usize, layout: Option<TorqueLayout>) {
        let mut st = self.state.lock().expect("set-point table lock");
        if let Some(e) = st.entries.get_mut(i) {
            e.torque = layout;
        }
    }

    /// The feed-forward RPDO of axis `i`, which a position stream sends
    /// each SYNC's feed-forward in (`None`: feed-forward is not sent).
    pub fn set_feed_forward_rpdo(&self, i: usize, layout: Option<FeedForwardLayout>) {
        let mut st = self.state.lock().expect("set-point table lock");
        if let Some(e) = st.entries.get_mut(i) {
            e.feed_forward = layout;
        }
    }

    /// What of a position stream's feed-forward reaches axis `i`'s drive:
    /// (the velocity, the torque).
    pub fn feed_forward_sent(&self, i: usize) -> (bool, bool) {
        let st = self.state.lock().expect("set-point table lock");
        st.entries
            .get(i)
            .and_then(|e| e.feed_forward)
            .map_or((false, false), |l| (true, l.torque))
    }

    /// Bounds the feed-forward torques of stream `id` (per axis, per
    /// mille): a point beyond is refused.
    pub fn set_feed_forward_torque_limits(&self, id: u64, max: Vec<f64>) {
        let mut st = self.state.lock().expect("set-point table lock");
        if let Some(s) = st.stream(id) {
            let player = s.player.clone().with_feed_forward_torque_limits(max);
            s.player = player;
        }
    }

    /// Whether axis `i` (table index) plays in a torque stream.
    pub fn in_torque_stream(&self, i: usize) -> bool {
        self.torque_stream_cob(i).is_some()
    }

    /// The COB-ID of axis `i`'s torque RPDO while the axis plays in a
    /// torque stream (which sends it with every SYNC).
    pub fn torque_stream_cob(&self, i: usize) -> Option<u16> {
        let st = self.state.lock().expect("set-point table lock");
        let e = st.entries.get(i)?;
        let id = e.stream?;
        st.streams
            .iter()
            .any(|s| s.id == id && s.player.kind() == SetpointKind::Torque)
            .then_some(e.torque?.cob_id)
    }

    /// Moves the samples taken since the last call into `out`.
    pub fn take_samples(&self, out: &mut Vec<(usize, CyclicSample)>) {
        let mut st = self.state.lock().expect("set-point table lock");
        for (i, e) in st.entries.iter_mut().enumerate() {
            out.extend(e.samples.drain(..).map(|s| (i, s)));
        }
    }

    /// Opens a set-point stream over the axes `axes` (table indices), each
    /// with its limits and units: the SYNC thread plays it from the next
    /// SYNC on. Each axis must be sent set-points (enabled in cyclic
    /// position mode), at rest, and in no other stream.
    ///
    /// # Errors
    /// Why an axis cannot be streamed, for a person.
    pub fn open_stream(
        &self,
        axes: &[usize],
        limits: Vec<AxisLimits>,
        units: Vec<Units>,
        cfg: PlayerConfig,
    ) -> Result<u64, String> {
        let now = self.origin.elapsed();
        let mut st = self.state.lock().expect("set-point table lock");
        let mut positions = Vec::with_capacity(axes.len());
        for &i in axes {
            let e = &st.entries[i];
            if e.stream.is_some() {
                return Err(format!("axis {} is already in a set-point stream", e.name));
            }
            if cfg.kind == SetpointKind::Torque {
                // A torque stream starts from 0 torque; the axis's own
                // command (a torque of 0) holds the drive meanwhile.
                if e.torque.is_none() {
                    return Err(format!(
                        "axis {} has no RPDO that maps the target torque (0x6071) alone: a \
                         torque stream needs the gateway's torque RPDO (PDO process data, mode \
                         = \"cst\")",
                        e.name
                    ));
                }
                positions.push(0.0);
                continue;
            }
            let (Some(plan), Some(_)) = (&e.plan, &e.rpdo) else {
                return Err(format!(
                    "axis {} gets no set-points: it must be enabled in cyclic position mode (CSP) \
                     with its bus's SYNC running",
                    e.name
                ));
            };
            if plan.is_moving() {
                return Err(format!(
                    "axis {} is moving: stop it or wait until it is at rest",
                    e.name
                ));
            }
            positions.push(plan.clone().sample(now).demand());
        }
        let id = st.next_stream;
        st.next_stream += 1;
        for &i in axes {
            let e = &mut st.entries[i];
            e.stream = Some(id);
            e.settling = None;
        }
        st.streams.push(PlayedStream::new(
            id,
            axes,
            SetpointPlayer::new(cfg, limits, positions),
            units,
        ));
        Ok(id)
    }

    /// Takes points of stream `id` that arrived now: the refused ones
    /// with their position in `points` and the reason.
    pub fn push_points(
        &self,
        id: u64,
        points: impl IntoIterator<Item = StreamPoint>,
    ) -> Vec<(usize, PointRefused)> {
        self.push_points_at(id, points, self.origin.elapsed())
    }

    /// [`CyclicSetpoints::push_points`] for points that arrived at `now`
    /// (this table's clock).
    pub fn push_points_at(
        &self,
        id: u64,
        points: impl IntoIterator<Item = StreamPoint>,
        now: Duration,
    ) -> Vec<(usize, PointRefused)> {
        let mut st = self.state.lock().expect("set-point table lock");
        let Some(s) = st.stream(id) else {
            return Vec::new();
        };
        let arrived = now.saturating_sub(s.held_back);
        points
            .into_iter()
            .enumerate()
            .filter_map(|(k, p)| s.player.push(p, arrived).err().map(|e| (k, e)))
            .collect()
    }

    /// Ends the stream axis `i` (table index) plays in, if any, for
    /// `reason`, before its next plan is published (which would end it as
    /// stopped).
    pub fn end_stream_of(&self, i: usize, reason: StreamEnd) {
        let id = {
            let st = self.state.lock().expect("set-point table lock");
            st.entries.get(i).and_then(|e| e.stream)
        };
        if let Some(id) = id {
            self.stop_stream(id, reason);
        }
    }

    /// Brings stream `id` to rest and ends it (its first reason stays).
    pub fn stop_stream(&self, id: u64, reason: StreamEnd) {
        let now = self.origin.elapsed();
        let mut st = self.state.lock().expect("set-point table lock");
        if let Some(s) = st.stream(id) {
            s.stop(reason, now);
        }
    }

    /// A stop reached axis `i` (table index): its stream, if any, ramps to
    /// rest at once, all its axes together, and ends.
    pub fn stop_stream_of(&self, i: usize) {
        let now = self.origin.elapsed();
        let mut st = self.state.lock().expect("set-point table lock");
        let State {
            entries, streams, ..
        } = &mut *st;
        let Some(e) = entries.get(i) else {
            return;
        };
        if let Some(id) = e.stream
            && let Some(s) = streams.iter_mut().find(|s| s.id == id)
        {
            s.stop(
                StreamEnd::Stopped {
                    axis: e.name.clone(),
                },
                now,
            );
        }
    }

    /// Whether axis `i` (table index) is driven by a set-point stream.
    pub fn in_stream(&self, i: usize) -> bool {
        let st = self.state.lock().expect("set-point table lock");
        st.entries.get(i).is_some_and(|e| e.stream.is_some())
    }

    /// Where stream `id` stands; its events since the last report.
    pub fn report(&self, id: u64) -> Option<StreamReport> {
        let now = self.origin.elapsed();
        let mut st = self.state.lock().expect("set-point table lock");
        Some(st.stream(id)?.report(now))
    }

    /// The session of stream `id` is gone: a stream still playing ramps to
    /// rest (ended by `reason` unless it had ended already) and is dropped
    /// once at rest.
    pub fn close_stream(&self, id: u64, reason: StreamEnd) {
        let now = self.origin.elapsed();
        let mut st = self.state.lock().expect("set-point table lock");
        close_stream(&mut st.streams, id, reason, now);
    }
}

impl SyncRider for CyclicSetpoints {
    fn sync_change_veto(&self) -> Option<String> {
        // Every enabled cyclic axis, moving or not: its drive interpolates
        // the set-points of each SYNC over the period it was enabled with
        // and (on most drives) faults when the SYNC stops or its period
        // changes under it.
        let st = self.state.lock().expect("set-point table lock");
        let entries = &st.entries;
        let enabled: Vec<&str> = entries
            .iter()
            .filter(|e| e.plan.is_some())
            .map(|e| e.name.as_str())
            .collect();
        let moving = entries
            .iter()
            .any(|e| e.stream.is_some() || e.plan.as_ref().is_some_and(CyclicPlan::is_moving));
        (!enabled.is_empty()).then(|| {
            format!(
                "cyclic axis {} is {} on this SYNC; {} it first (its drive takes a set-point \
                 with every SYNC)",
                enabled.join(", "),
                if moving { "moving" } else { "enabled" },
                if moving {
                    "stop and disable"
                } else {
                    "disable"
                },
            )
        })
    }

    fn on_sync(&self, tick: SyncTick, frames: &mut Vec<Frame>) {
        let t = tick.at.saturating_duration_since(self.origin);
        let mut st = self.state.lock().expect("set-point table lock");
        let State {
            entries, streams, ..
        } = &mut *st;
        for s in streams.iter_mut().filter(|s| !s.finished) {
            s.held_back += tick.missed;
            s.player.skipped(tick.missed);
            let cycle = s.player.next(t.saturating_sub(s.held_back));
            if let Some(ev) = cycle.event {
                s.events.push(ev);
            }
            // Ended and at rest: each axis holds where the stream left it.
            let done = s.end.is_some() && cycle.state == PlayerState::Waiting;
            for (k, &i) in s.axes.iter().enumerate() {
                let e = &mut entries[i];
                if e.stream != Some(s.id) {
                    continue;
                }
                if s.player.kind() == SetpointKind::Torque {
                    // The torque itself; the axis keeps no plan (its own
                    // torque command holds the drive).
                    e.streamed_torque = Some(if done { 0.0 } else { cycle.positions[k] });
                    if done {
                        e.stream = None;
                    }
                    continue;
                }
                let (p, v) = (cycle.positions[k], s.player.velocity()[k]);
                if e.feed_forward.is_some() && s.player.kind() == SetpointKind::Position {
                    // Each SYNC's feed-forward with its position; 0 once
                    // the stream is at rest and over. (In CSV the drive
                    // adds 0x60B1 to the velocity set-point: a velocity
                    // stream sends none.)
                    let ff = s.player.feed_forward();
                    e.streamed_feed_forward = Some(if done {
                        (0, 0.0)
                    } else {
                        (
                            s.extra[k].to_counts(ff.velocities[k]),
                            ff.torques.get(k).copied().unwrap_or(0.0),
                        )
                    });
                }
                e.streamed = Some(CyclicSample::streamed(
                    t,
                    p,
                    if done { 0.0 } else { v },
                    s.extra[k],
                ));
                if done {
                    let object = e
                        .plan
                        .as_ref()
                        .map_or(SetpointObject::TargetPosition, CyclicPlan::setpoint_object);
                    let hold = CyclicPlan::holding(p, s.extra[k]).sent_to(object);
                    e.stream = None;
                    e.plan = Some(hold.clone());
                    e.settling = Some(hold);
                }
            }
            s.finished = done;
        }
        streams.retain(|s| !(s.finished && s.orphaned));
        for e in entries.iter_mut() {
            if let (Some((v, t)), Some(layout)) = (e.streamed_feed_forward.take(), &e.feed_forward)
            {
                match layout.frame(v, t) {
                    Some(f) => frames.push(f),
                    None => tracing::error!(cob_id = layout.cob_id, "feed-forward RPDO not sent"),
                }
            }
            if let (Some(t), Some(layout)) = (e.streamed_torque.take(), &e.torque) {
                match layout.frame(t) {
                    Some(f) => frames.push(f),
                    None => tracing::error!(cob_id = layout.cob_id, "torque RPDO not sent"),
                }
            }
            let streamed = e.streamed.take();
            let (Some(plan), Some((cob, payload, offset))) = (&mut e.plan, &mut e.rpdo) else {
                continue;
            };
            let sample = match streamed {
                Some(sample) => sample,
                None => {
                    plan.hold_back(tick.missed);
                    plan.sample(t)
                }
            };
            let (at, value) = match (plan.setpoint_object(), e.velocity_offset) {
                (SetpointObject::TargetVelocity, Some(v)) => (v, sample.velocity_counts),
                _ => (*offset, sample.counts),
            };
            if let Some(target) = payload.get_mut(at..at + 4) {
                target.copy_from_slice(&value.to_le_bytes());
            }
            match Frame::new(CanId::Standard(*cob), payload) {
                Ok(f) => frames.push(f),
                Err(e) => tracing::error!(cob_id = *cob, error = %e, "set-point RPDO not sent"),
            }
            // A plain sample replaces the previous plain one: only the
            // latest demand matters then.
            if e.samples.last().is_some_and(|s| !s.ends_a_motion()) {
                e.samples.pop();
            }
            e.samples.push(sample);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cangate_axis::process_data::{FeedbackTrigger, standard_pdos};
    use cangate_canopen::NodeId;

    #[test]
    fn the_standard_layout_puts_the_target_position_first_in_rpdo2() {
        let (rpdos, _) = standard_pdos(NodeId::new(5).unwrap(), FeedbackTrigger::Sync);
        let l = SetpointLayout::find(&rpdos).expect("target position mapped");
        assert_eq!(l.rpdo.cob_id, 0x305);
        assert_eq!(l.offset, 0);
        assert_eq!(l.velocity_offset, Some(4));
        // Both set-points (CSP: position, CSV: velocity) are the SYNC
        // thread's.
        assert_eq!(l.masked(&[1, 2, 3, 4, 5, 6, 7, 8]), vec![0; 8]);
        assert!(SetpointLayout::find(&rpdos[..1]).is_none());
        // Interpolated position: 0x60C1:01 takes the position's place.
        let ip = cangate_axis::process_data::interpolated_rpdo(NodeId::new(5).unwrap());
        let l = SetpointLayout::find(&[ip]).expect("interpolation data mapped");
        assert_eq!((l.offset, l.velocity_offset), (0, Some(4)));
    }

    #[test]
    fn a_csv_plan_sends_its_velocity_in_the_target_velocity() {
        let origin = Instant::now();
        let table = CyclicSetpoints::new(origin, ["v"].map(String::from));
        table.set_velocity_offset(0, Some(4));
        let units = cangate_axis::Units {
            counts_per_unit: 1000.0,
        };
        // A CSV axis's stream-free plan: the demand velocity of each SYNC
        // goes to bytes 4..8, the position bytes stay as the image has
        // them.
        let plan = CyclicPlan::holding(1.5, units).sent_to(SetpointObject::TargetVelocity);
        table.publish([(0, Some(plan), 0x301, vec![7, 7, 7, 7, 1, 1, 1, 1], 0)]);
        let mut frames = Vec::new();
        let at = origin + std::time::Duration::from_millis(3);
        table.on_sync(SyncTick::on_time(at), &mut frames);
        assert_eq!(frames[0].data(), &[7, 7, 7, 7, 0, 0, 0, 0]);
        // A streamed sample carries its velocity (12.5 mm/s) for a CSV
        // axis in a stream.
        let s = CyclicSample::streamed(std::time::Duration::ZERO, 1.5, 12.5, units);
        assert_eq!(s.velocity_counts, 12_500);
    }

    #[test]
    fn each_sync_sends_the_sampled_set_point_and_leaves_the_sample() {
        let origin = Instant::now();
        let table = CyclicSetpoints::new(origin, ["a", "b", "c"].map(String::from));
        let units = cangate_axis::Units {
            counts_per_unit: 1000.0,
        };
        // Axis 1 holds 1.5 mm; its RPDO also maps a target velocity.
        table.publish([(
            1,
            Some(CyclicPlan::holding(1.5, units)),
            0x302,
            vec![0, 0, 0, 0, 9, 8, 7, 6],
            0,
        )]);
        let mut frames = vec![Frame::new(CanId::Standard(0x080), &[]).unwrap()];
        let at = origin + std::time::Duration::from_millis(3);
        table.on_sync(SyncTick::on_time(at), &mut frames);
        assert_eq!(frames.len(), 2, "the SYNC first, then the set-point");
        assert_eq!(frames[1].raw_id(), 0x302);
        assert_eq!(frames[1].data(), &[0xDC, 0x05, 0, 0, 9, 8, 7, 6]);
        let mut samples = Vec::new();
        table.take_samples(&mut samples);
        assert_eq!(samples.len(), 1);
        assert_eq!(samples[0].0, 1);
        assert_eq!(samples[0].1.counts, 1500);
        assert_eq!(samples[0].1.at, std::time::Duration::from_millis(3));
        // Taken once.
        samples.clear();
        table.take_samples(&mut samples);
        assert!(samples.is_empty());
        // A new payload rides with the next SYNC.
        table.set_payload(1, vec![0, 0, 0, 0, 1, 1, 1, 1]);
        let mut frames = Vec::new();
        table.on_sync(SyncTick::on_time(at), &mut frames);
        assert_eq!(frames[0].data(), &[0xDC, 0x05, 0, 0, 1, 1, 1, 1]);
        // Withdrawn: nothing is sent, and the pending sample of the old
        // plan is dropped.
        table.publish([(1, None, 0x302, Vec::new(), 0)]);
        let mut frames = Vec::new();
        table.on_sync(SyncTick::on_time(at), &mut frames);
        assert!(frames.is_empty());
        table.take_samples(&mut samples);
        assert!(samples.is_empty());
    }

    /// Issue 26, item 4: a SYNC thread that stalls (5.5 periods without a
    /// SYNC), or wakes late (0.4 periods), or finds the bus queue full
    /// (a SYNC built, not sent) never sends a set-point further than one
    /// period's travel at the maximum velocity from the previous one sent:
    /// the plan is sampled on the SYNC grid and held back by the periods
    /// without a SYNC. The move still ends at its target.
    /// An enabled cyclic-position axis (1000 counts per unit) at 0,
    /// commanded to move to `target` at its maximum velocity and
    /// acceleration, at time 0.
    fn moving_cyclic_axis(
        target: f64,
    ) -> (
        cangate_axis::cia402::Cia402Axis,
        cangate_axis::cia402::Cia402Config,
    ) {
        use cangate_axis::cia402::{Cia402Axis, Cia402Config, Feedback};
        use cangate_axis::{AxisCommand, PositionMode};
        use std::time::Duration;

        let cfg = Cia402Config::example(1000.0, PositionMode::Cyclic);
        let mut axis = Cia402Axis::new(cfg.clone());
        let mut out = Vec::new();
        let enabled = Feedback {
            statusword: Some(0x0237),
            position: Some(0),
            velocity: Some(0),
            mode_display: Some(8),
            ..Default::default()
        };
        axis.on_feedback(enabled, Duration::ZERO, &mut out);
        axis.command(
            AxisCommand::Move {
                target,
                relative: false,
                velocity: Some(cfg.motion.max_velocity),
                acceleration: Some(cfg.motion.max_acceleration),
            },
            Duration::ZERO,
            &mut out,
        )
        .expect("move");
        (axis, cfg)
    }

    #[test]
    fn a_stalled_sync_thread_never_sends_a_double_step() {
        use crate::canopen::sync_thread::due_sync;
        use cangate_canopen::sync::SyncProducer;
        use std::time::Duration;

        let period = Duration::from_millis(1);
        let (mut axis, cfg) = moving_cyclic_axis(300.0);
        let max_step = cfg.motion.max_velocity * period.as_secs_f64() * 1000.0 + 1.0;
        let mut out = Vec::new();
        let origin = Instant::now();
        let table = CyclicSetpoints::new(origin, ["x".to_string()]);
        let mut published = None;
        let mut producer = SyncProducer::new(period, 0).expect("period");
        producer.start(Duration::ZERO);
        let mut sent: Vec<i32> = Vec::new();
        let mut samples = Vec::new();
        let mut unsent = 0;
        let mut now = Duration::ZERO;
        for k in 1..=3000u32 {
            now = period * k;
            match k % 200 {
                // Stalled for 5.5 periods.
                100..=104 => continue,
                105 => now += period / 2,
                // Late by 0.4 periods.
                150 => now += period * 2 / 5,
                _ => {}
            }
            // The axis task: samples back to the axis, its plan published
            // when it changed.
            table.take_samples(&mut samples);
            for (_, s) in samples.drain(..) {
                axis.on_cyclic_sample(&s, now, &mut out);
            }
            let plan = axis.cyclic_plan();
            if plan != published {
                table.publish([(0, plan.clone(), 0x301, vec![0; 8], 0)]);
                published = plan;
            }
            // The SYNC thread.
            let Some((sync, due, missed)) = due_sync(&mut producer, now, unsent) else {
                continue;
            };
            let mut frames = vec![sync];
            table.on_sync(
                SyncTick {
                    at: origin + due,
                    missed,
                },
                &mut frames,
            );
            if k % 200 == 170 {
                // The bus's queue was full: built, not sent.
                unsent += 1;
                continue;
            }
            unsent = 0;
            let counts = i32::from_le_bytes(frames[1].data()[..4].try_into().unwrap());
            if let Some(&last) = sent.last() {
                let step = f64::from(counts - last).abs();
                assert!(
                    step <= max_step,
                    "SYNC {k} at {now:?}: a step of {step} counts (at most {max_step})"
                );
            }
            sent.push(counts);
        }
        assert_eq!(sent.last(), Some(&300_000), "the move ends at its target");
        assert!(now > Duration::from_secs(2));
    }

    /// An axis task that wakes only every few SYNCs (a loaded host) still
    /// hears of the sample that finished the trajectory, although later
    /// SYNCs sampled the plan again: the move completes with the SYNC that
    /// ends it, not at the axis's deadline.
    #[test]
    fn a_slow_axis_task_still_sees_the_sample_that_ends_the_move() {
        use std::time::Duration;

        let period = Duration::from_millis(1);
        for wake_every in 2..=5u32 {
            for phase in 0..wake_every {
                let (mut axis, _) = moving_cyclic_axis(10.0);
                let mut out = Vec::new();
                let origin = Instant::now();
                let table = CyclicSetpoints::new(origin, ["x".to_string()]);
                let plan = axis.cyclic_plan();
                table.publish([(0, plan.clone(), 0x301, vec![0; 8], 0)]);
                let mut published = plan;
                let mut samples = Vec::new();
                let mut ended_at = None;
                for k in 1..=5000u32 {
                    let now = period * k;
                    if k % wake_every == phase {
                        table.take_samples(&mut samples);
                        for (_, s) in samples.drain(..) {
                            axis.on_cyclic_sample(&s, now, &mut out);
                        }
                        let plan = axis.cyclic_plan();
                        if plan != published {
                            table.publish([(0, plan.clone(), 0x301, vec![0; 8], 0)]);
                            published = plan;
                        }
                        if let Some(end) = ended_at
                            && k > end + wake_every
                        {
                            assert!(
                                !axis.cyclic_plan().is_some_and(|p| p.is_moving()),
                                "waking every {wake_every} SYNCs (phase {phase}): the trajectory \
                                 ended at SYNC {end}, the axis still moves at {k}"
                            );
                            break;
                        }
                    }
                    let mut frames = Vec::new();
                    table.on_sync(SyncTick::on_time(origin + now), &mut frames);
                    let counts = i32::from_le_bytes(frames[0].data()[..4].try_into().unwrap());
                    if counts == 10_000 && ended_at.is_none() {
                        ended_at = Some(k);
                    }
                }
                assert!(ended_at.is_some(), "the move reached its target");
            }
        }
    }

    /// A table of two cyclic axes holding at 0 (1000 counts per unit),
    /// RPDOs 0x301 and 0x302.
    fn two_holding_axes(origin: Instant) -> CyclicSetpoints {
        let table = CyclicSetpoints::new(origin, ["x", "y"].map(String::from));
        table.publish((0..2).map(|i| {
            (
                i,
                Some(CyclicPlan::holding(0.0, UNITS)),
                0x301 + i as u16,
                vec![0; 8],
                0,
            )
        }));
        table
    }

    const UNITS: Units = Units {
        counts_per_unit: 1000.0,
    };

    fn limits() -> AxisLimits {
        AxisLimits {
            max_jerk: None,
            max_velocity: 100.0,
            max_acceleration: 1000.0,
            stop_deceleration: 1000.0,
            min_position: Some(-200.0),
            max_position: Some(200.0),
        }
    }

    /// Opens a stream over both axes of `table` (1 ms cycle, 5 ms buffer).
    fn open(table: &CyclicSetpoints) -> u64 {
        table
            .open_stream(
                &[0, 1],
                vec![limits(); 2],
                vec![UNITS; 2],
                PlayerConfig::new(Duration::from_millis(1), Duration::from_millis(5)),
            )
            .expect("both axes hold at rest")
    }

    /// The target positions (counts) of the RPDOs one SYNC at `k` ms sends.
    fn sync_counts(table: &CyclicSetpoints, origin: Instant, k: u64) -> Vec<i32> {
        let mut frames = Vec::new();
        table.on_sync(
            SyncTick::on_time(origin + Duration::from_millis(k)),
            &mut frames,
        );
        frames
            .iter()
            .map(|f| i32::from_le_bytes(f.data()[..4].try_into().unwrap()))
            .collect()
    }

    /// A streamed line plays on the SYNC grid (after the buffer's depth),
    /// each axis's sample carries the streamed demand to its axis task,
    /// and a stop of one axis ramps both to rest together, ends the
    /// stream, and hands each axis back to a plan holding where it stopped;
    /// the axis task's plans from before the end do not move it back.
    #[test]
    fn a_stream_plays_on_the_sync_grid_and_a_stop_ends_it_at_rest() {
        let origin = Instant::now();
        let table = two_holding_axes(origin);
        let id = open(&table);
        assert!(table.in_stream(0) && table.in_stream(1));
        // Up to 50 mm/s on x (at 500 mm/s²), half that backwards on y, a
        // point per ms, sent as they come.
        let x = |s: f64| {
            if s < 0.1 {
                250.0 * s * s
            } else {
                2.5 + 50.0 * (s - 0.1)
            }
        };
        let mut sent = Vec::new();
        let mut samples = Vec::new();
        for k in 0..200u64 {
            let t_us = k * 1000;
            let s = k as f64 / 1000.0;
            let refused = table.push_points_at(
                id,
                [StreamPoint {
                    feed_forward: None,
                    t_us,
                    values: vec![x(s), -x(s) / 2.0],
                }],
                Duration::from_millis(k),
            );
            assert!(refused.is_empty(), "{refused:?}");
            sent.push(sync_counts(&table, origin, k));
            table.take_samples(&mut samples);
        }
        // Played 5 ms behind the client: at 199 ms, client time 194 ms.
        let last = sent.last().unwrap();
        assert!((last[0] - 7_200).abs() <= 60, "{last:?}");
        assert!((last[1] + 3_600).abs() <= 30, "{last:?}");
        // No step beyond 100 mm/s over 1 ms.
        for w in sent.windows(2) {
            for a in 0..2 {
                assert!((w[1][a] - w[0][a]).abs() <= 100, "{w:?}");
            }
        }
        let (i, s) = samples.last().unwrap();
        assert_eq!(*i, 1);
        assert_eq!(s.counts, last[1]);
        // The axis task publishes plans holding its (lagging) demand: ignored.
        table.publish([(
            0,
            Some(CyclicPlan::holding(1.0, UNITS)),
            0x301,
            vec![0; 8],
            0,
        )]);
        let moving = sync_counts(&table, origin, 200);
        assert!(moving[0] > last[0], "{moving:?} after {last:?}");

        table.stop_stream_of(1);
        let mut k = 201;
        let mut previous = moving;
        let report = loop {
            let now = sync_counts(&table, origin, k);
            for a in 0..2 {
                // 1000 mm/s² over 1 ms: a step changes by at most 1 count.
                let v_before = previous[a];
                assert!((now[a] - v_before).abs() <= 100, "{now:?} {previous:?}");
            }
            previous = now;
            let r = table.report(id).unwrap();
            if r.finished {
                break r;
            }
            k += 1;
            assert!(k < 400, "the ramp to rest ends within 50 ms");
        };
        assert_eq!(report.end, Some(StreamEnd::Stopped { axis: "y".into() }));
        assert!(!table.in_stream(0));
        // At rest: the next SYNCs hold, and a stale holding plan of the
        // axis task does not move the axis back.
        table.publish([(
            0,
            Some(CyclicPlan::holding(9.0, UNITS)),
            0x301,
            vec![0; 8],
            0,
        )]);
        let held = sync_counts(&table, origin, k + 1);
        assert_eq!(held, previous);
        // The axis catches up: its plan holds where the stream stopped.
        let x = f64::from(previous[0]) / 1000.0;
        table.publish([(0, Some(CyclicPlan::holding(x, UNITS)), 0x301, vec![0; 8], 0)]);
        assert_eq!(sync_counts(&table, origin, k + 2), previous);
        // Another stream can open now.
        assert!(
            table
                .open_stream(
                    &[0],
                    vec![limits()],
                    vec![UNITS],
                    PlayerConfig::new(Duration::from_millis(1), Duration::from_millis(5))
                )
                .is_ok()
        );
    }

    /// SYNCs the SYNC thread skipped hold a stream's clock back, as they
    /// hold a plan back: the next set-point sent is one period's travel
    /// from the previous one sent, never a double step.
    #[test]
    fn a_skipped_sync_holds_the_stream_back_instead_of_a_double_step() {
        let origin = Instant::now();
        let table = two_holding_axes(origin);
        let id = open(&table);
        // Up to 100 mm/s (the maximum) at 1000 mm/s², all points at once.
        let x = |s: f64| {
            if s < 0.1 {
                500.0 * s * s
            } else {
                5.0 + 100.0 * (s - 0.1)
            }
        };
        let points: Vec<StreamPoint> = (0..400u64)
            .map(|k| StreamPoint {
                feed_forward: None,
                t_us: k * 1000,
                values: vec![x(k as f64 / 1000.0), 0.0],
            })
            .collect();
        assert!(table.push_points_at(id, points, Duration::ZERO).is_empty());
        let mut previous: Option<i32> = None;
        let mut at = Duration::ZERO;
        let mut largest = 0;
        for k in 1..300u64 {
            let mut missed = Duration::ZERO;
            if k % 50 == 0 {
                // The thread stalled for 4 periods.
                at += Duration::from_millis(4);
                missed = Duration::from_millis(4);
            }
            at += Duration::from_millis(1);
            let mut frames = Vec::new();
            table.on_sync(
                SyncTick {
                    at: origin + at,
                    missed,
                },
                &mut frames,
            );
            let counts = i32::from_le_bytes(frames[0].data()[..4].try_into().unwrap());
            if let Some(p) = previous {
                largest = largest.max((counts - p).abs());
            }
            previous = Some(counts);
        }
        // 100 mm/s over 1 ms: 100 counts (and a count of rounding).
        assert!(largest <= 101, "a step of {largest} counts");
        assert!(largest >= 99, "it reached full speed: {largest}");
    }

    /// A velocity stream on a CSV axis sends each SYNC's velocity in the
    /// target velocity, and a SYNC the thread skipped (the drive held the
    /// last velocity for the skipped periods too) moves the prediction on
    /// by that travel: the drive's integral of the velocities sent over
    /// real time stays the stream's predicted position, so the soft-limit
    /// guards judge where the drive is. The velocity never changes by more
    /// than the acceleration allows over a period.
    #[test]
    fn a_skipped_sync_moves_a_velocity_stream_on_with_the_drive() {
        let origin = Instant::now();
        let table = CyclicSetpoints::new(origin, ["s"].map(String::from));
        table.set_velocity_offset(0, Some(4));
        let plan = CyclicPlan::holding(0.0, UNITS).sent_to(SetpointObject::TargetVelocity);
        table.publish([(0, Some(plan), 0x301, vec![0; 8], 0)]);
        let mut cfg = PlayerConfig::new(Duration::from_millis(1), Duration::from_millis(5));
        cfg.kind = cangate_axis::setpoint_stream::SetpointKind::Velocity;
        let id = table
            .open_stream(&[0], vec![limits()], vec![UNITS], cfg)
            .unwrap();
        // Up to 50 mm/s at 500 mm/s², held: all points at once.
        let points: Vec<StreamPoint> = (0..400u64)
            .map(|k| StreamPoint {
                feed_forward: None,
                t_us: k * 1000,
                values: vec![(0.5 * k as f64).min(50.0)],
            })
            .collect();
        assert!(table.push_points_at(id, points, Duration::ZERO).is_empty());
        let mut drive = 0.0;
        let mut held = 0.0;
        let mut at = Duration::ZERO;
        for k in 1..300u64 {
            let mut missed = Duration::ZERO;
            let before = at;
            if k % 50 == 0 {
                // The thread stalled for 4 periods.
                at += Duration::from_millis(4);
                missed = Duration::from_millis(4);
            }
            at += Duration::from_millis(1);
            // The drive integrates the velocity it holds over real time.
            drive += held * (at - before).as_secs_f64();
            let mut frames = Vec::new();
            table.on_sync(
                SyncTick {
                    at: origin + at,
                    missed,
                },
                &mut frames,
            );
            let counts = i32::from_le_bytes(frames[0].data()[4..8].try_into().unwrap());
            let v = f64::from(counts) / 1000.0;
            assert!(
                (v - held).abs() <= 1.0 + 1e-3,
                "SYNC {k}: {held} -> {v} mm/s"
            );
            held = v;
        }
        // A SYNC's velocity is the step to its predicted position, which
        // the drive covers over the next period.
        let predicted = table.report(id).unwrap().positions[0];
        assert!(held > 40.0, "it reached speed: {held}");
        drive += held * 0.001;
        assert!(
            (drive - predicted).abs() < 0.01,
            "the drive at {drive}, the prediction at {predicted}"
        );
    }

    /// A stop that reaches an axis of a stream as its own stop ramp (the
    /// axis task's plan moves) takes the axis out of the stream at once;
    /// the stream's other axes ramp to rest and the stream ends. Opening is
    /// refused for an axis already streamed, one that moves, and one that
    /// gets no set-points.
    #[test]
    fn an_axis_plan_that_moves_takes_the_axis_out_of_its_stream() {
        let origin = Instant::now();
        let table = two_holding_axes(origin);
        let id = open(&table);
        let err = table
            .open_stream(
                &[1],
                vec![limits()],
                vec![UNITS],
                PlayerConfig::new(Duration::from_millis(1), Duration::from_millis(5)),
            )
            .unwrap_err();
        assert!(err.contains("already in a set-point stream"), "{err}");
        // An axis leaving operation enabled (no plan) ends the stream too.
        table.publish([(0, None, 0x301, Vec::new(), 0)]);
        assert!(!table.in_stream(0));
        let r = table.report(id).unwrap();
        assert_eq!(r.end, Some(StreamEnd::AxisLeft { axis: "x".into() }));
        sync_counts(&table, origin, 1);
        assert!(table.report(id).unwrap().finished);
        table.close_stream(id, StreamEnd::ClientGone);
        assert!(
            table.report(id).is_none(),
            "a finished, closed stream is gone"
        );
        let err = table
            .open_stream(
                &[0],
                vec![limits()],
                vec![UNITS],
                PlayerConfig::new(Duration::from_millis(1), Duration::from_millis(5)),
            )
            .unwrap_err();
        assert!(err.contains("gets no set-points"), "{err}");
        // A moving axis cannot be streamed.
        let (axis, _) = moving_cyclic_axis(10.0);
        table.publish([(1, axis.cyclic_plan(), 0x302, vec![0; 8], 0)]);
        let err = table
            .open_stream(
                &[1],
                vec![limits()],
                vec![UNITS],
                PlayerConfig::new(Duration::from_millis(1), Duration::from_millis(5)),
            )
            .unwrap_err();
        assert!(err.contains("is moving"), "{err}");
    }

    #[test]
    fn a_sync_without_plans_adds_nothing_and_leaves_no_sample() {
        let table = CyclicSetpoints::new(Instant::now(), ["a", "b"].map(String::from));
        let mut frames = Vec::new();
        table.on_sync(SyncTick::on_time(Instant::now()), &mut frames);
        assert!(frames.is_empty());
        let mut samples = Vec::new();
        table.take_samples(&mut samples);
        assert!(samples.is_empty());
    }

    /// A position stream's feed-forward leaves with every SYNC in the
    /// feed-forward RPDO (0x60B1 counts/s, then 0x60B2 per mille), next to
    /// the position; once the stream is over the offsets go to 0. A torque
    /// stream's torque leaves in the torque RPDO (0x6071 alone).
    #[test]
    fn the_feed_forward_and_a_torque_leave_with_the_sync_in_exact_bytes() {
        use cangate_axis::setpoint_stream::FeedForward;
        let origin = Instant::now();
        let table = two_holding_axes(origin);
        table.set_feed_forward_rpdo(
            0,
            Some(FeedForwardLayout {
                cob_id: 0x401,
                torque: true,
            }),
        );
        assert_eq!(table.feed_forward_sent(0), (true, true));
        assert_eq!(table.feed_forward_sent(1), (false, false));
        let id = open(&table);
        // 10 mm/s on x from rest at 1000 mm/s² (10 ms), then on at 10 mm/s,
        // its feed-forward 10 mm/s and 40 per mille throughout.
        let x = |s: f64| {
            if s < 0.01 {
                500.0 * s * s
            } else {
                0.05 + 10.0 * (s - 0.01)
            }
        };
        let points: Vec<StreamPoint> = (0..100u64)
            .map(|k| StreamPoint {
                feed_forward: Some(FeedForward {
                    velocities: vec![10.0, 0.0],
                    torques: vec![40.0, 0.0],
                }),
                t_us: k * 1000,
                values: vec![x(k as f64 / 1000.0), 0.0],
            })
            .collect();
        let mut frames = Vec::new();
        for k in 0..60u64 {
            if k == 0 {
                assert!(
                    table
                        .push_points_at(id, points.clone(), Duration::ZERO)
                        .is_empty()
                );
            }
            frames.clear();
            table.on_sync(
                SyncTick::on_time(origin + Duration::from_millis(k)),
                &mut frames,
            );
        }
        let ff: Vec<&Frame> = frames
            .iter()
            .filter(|f| f.id() == CanId::Standard(0x401))
            .collect();
        assert_eq!(ff.len(), 1, "{frames:?}");
        assert_eq!(ff[0].data(), [0x10, 0x27, 0, 0, 0x28, 0]);
        table.stop_stream(id, StreamEnd::ClientGone);
        let mut last = Vec::new();
        for k in 60..200u64 {
            frames.clear();
            table.on_sync(
                SyncTick::on_time(origin + Duration::from_millis(k)),
                &mut frames,
            );
            last.extend(
                frames
                    .iter()
                    .filter(|f| f.id() == CanId::Standard(0x401))
                    .map(|f| f.data().to_vec()),
            );
            if table.report(id).unwrap().finished {
                break;
            }
        }
        assert_eq!(last.last().unwrap(), &vec![0u8; 6]);

        // A torque stream on an axis with the torque RPDO.
        let table = CyclicSetpoints::new(origin, ["t"].map(String::from));
        let (rpdos, _) = cangate_axis::process_data::standard_pdos(
            NodeId::new(2).unwrap(),
            FeedbackTrigger::Sync,
        );
        assert_eq!(TorqueLayout::find(&rpdos), None);
        let torque = cangate_axis::process_data::torque_rpdo(NodeId::new(2).unwrap());
        let layout = TorqueLayout::find(&[torque]).unwrap();
        assert_eq!(layout.cob_id, 0x402);
        table.set_torque_rpdo(0, Some(layout));
        let mut cfg = PlayerConfig::new(Duration::from_millis(1), Duration::from_millis(5));
        cfg.kind = SetpointKind::Torque;
        let id = table
            .open_stream(
                &[0],
                vec![AxisLimits::torque(300.0, 10_000.0)],
                vec![UNITS],
                cfg,
            )
            .unwrap();
        assert!(table.in_torque_stream(0));
        assert_eq!(table.torque_stream_cob(0), Some(0x402));
        let points: Vec<StreamPoint> = (0..=20u64)
            .map(|k| StreamPoint {
                feed_forward: None,
                t_us: k * 1000,
                values: vec![5.0 * k as f64],
            })
            .collect();
        let mut sent = Vec::new();
        for k in 0..=25u64 {
            if k == 0 {
                assert!(
                    table
                        .push_points_at(id, points.clone(), Duration::ZERO)
                        .is_empty()
                );
            }
            frames.clear();
            table.on_sync(
                SyncTick::on_time(origin + Duration::from_millis(k)),
                &mut frames,
            );
            sent.extend(frames.iter().map(|f| (f.id(), f.data().to_vec())));
        }
        // 100 per mille (0x0064) reached, in the torque RPDO alone.
        assert!(
            sent.iter()
                .all(|(id, d)| *id == CanId::Standard(0x402) && d.len() == 2)
        );
        assert!(
            sent.contains(&(CanId::Standard(0x402), vec![0x64, 0x00])),
            "{sent:?}"
        );
    }
}
