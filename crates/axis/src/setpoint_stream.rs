//! Streamed set-points, sans-IO: a client's time-stamped positions for one
//! or more axes, buffered against network jitter and played out on the
//! bus's cycle (the SYNC grid, or the CANsmc cycle) with every step inside
//! the axes' limits.
//!
//! [`SetpointPlayer`] takes points as they arrive ([`SetpointPlayer::push`],
//! with the gateway's time of arrival) and gives the set-points of each
//! cycle ([`SetpointPlayer::next`]). It is a pure state machine over
//! points and time: the runtime feeds it, tests drive it in virtual time.
//!
//! # Time
//!
//! Points carry the client's own clock (µs, any origin, increasing). The
//! player plays client time `tc` at gateway time `tc + offset + depth`:
//! `offset` is the smallest delay seen (arrival minus client time, over
//! the recent arrivals: the network's fastest path), `depth` the
//! configured jitter buffer. A point delayed by more than `depth` beyond
//! the fastest is late. `offset` follows the clocks' drift and a changed
//! route by slewing, at most [`PlayerConfig::max_slew`] (a fraction of the
//! elapsed time), never by a step: the played motion is at most that much
//! faster or slower than the client's, and never jumps.
//!
//! Between points the position is interpolated linearly, so the client's
//! period need not be the bus's. (Indexing points by cycle instead would
//! need the client to know the gateway's cycle and phase; time stamps
//! work with any client period and any bus.)
//!
//! # Never a jump, never beyond the limits
//!
//! A point is refused (and counted, with its reason) when it goes back in
//! time, when an axis's position lies outside its soft limits or could not
//! be stopped inside them at the speed it arrives with, when the segment
//! to it is faster than the axis's maximum velocity, or when the velocity
//! changes from the previous segment faster than the maximum acceleration
//! over the segment's duration. Played steps are interpolations of
//! accepted segments, so no step is faster than the maximum velocity.
//! A last guard checks every step: its velocity, and its change of
//! velocity against the maximum acceleration over one cycle (where a
//! client's period longer than the cycle turns the interpolated path at a
//! point, the axes follow within the acceleration and catch the path up
//! in a few cycles; counted as `limited`). After a gap, the player rejoins
//! the client's path from where the axes are only when that keeps the
//! limits, else it ramps to rest.
//!
//! # Underrun and the end of a stream
//!
//! When the playout reaches the last point, the player goes on along the
//! last segment's velocity for [`PlayerConfig::extrapolate`] (a late point
//! may still come), then brings every axis of the stream to rest along
//! one ramp: all axes decelerate together and stop at the same instant,
//! so the path keeps its direction, each within its stop deceleration.
//! That is an underrun ([`PlayerEvent::Underrun`]). Points that arrive
//! during the ramp are dropped (counted); once at rest the stream can
//! resume: its next point starts a new epoch and must lie where the axes
//! stand (within one cycle's travel at the maximum velocity).
//! [`SetpointPlayer::stop`] (the stream ended, was cancelled, its client
//! died, its lease was lost) brings the axes to rest the same way.
//!
//! # Torque streams
//!
//! A stream of [`SetpointKind::Torque`] carries one torque per axis (per
//! mille of the rated torque). The player plays the torques as it plays
//! positions (the jitter buffer, interpolation, late points, rejoin), with
//! the limits of [`AxisLimits::torque`]: no torque above the axis's
//! maximum, no change faster than its torque slope (between points and
//! every cycle). A playout starts from 0 torque; with no point left the
//! last torque is held (not extrapolated along its slope) for
//! [`PlayerConfig::extrapolate`], then every torque ramps to 0 at its
//! slope, all axes reaching 0 together; a stop does the same. The motion
//! a torque makes is the drive's and its load's: the runtime guards the
//! actual velocity and position and halts the drive (see
//! `server/src/axes/setpoint_streams.rs`).

use std::collections::VecDeque;
use std::time::Duration;

/// The limits of one axis of a stream (user units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisLimits {
    /// Maximum velocity, units/s.
    pub max_velocity: f64,
    /// Maximum acceleration, units/s².
    pub max_acceleration: f64,
    /// Deceleration of the ramp to rest, units/s² (at most the axis's stop
    /// deceleration).
    pub stop_deceleration: f64,
    /// Soft limits.
    pub min_position: Option<f64>,
    /// Soft limits.
    pub max_position: Option<f64>,
    /// Maximum jerk of the client's path, units/s³ (`None`: not bounded):
    /// a point whose acceleration (over its segment) changes from the
    /// previous segment's faster than this over the segment is refused.
    pub max_jerk: Option<f64>,
}

impl AxisLimits {
    /// The limits of an axis in a torque stream ([`SetpointKind::Torque`]),
    /// whose values are torques (per mille of the rated torque): a torque
    /// within ±`max_torque`, changing at most at `torque_slope` (per mille
    /// per second) and ramped to 0 at that slope. The player's position
    /// is then the torque: the bound of its rate (`max_velocity`) is the
    /// slope, its range (the soft limits) ±`max_torque`; its acceleration
    /// is not bounded (the slope bounds each step).
    pub fn torque(max_torque: f64, torque_slope: f64) -> AxisLimits {
        AxisLimits {
            max_jerk: None,
            max_velocity: torque_slope,
            max_acceleration: UNBOUNDED,
            stop_deceleration: UNBOUNDED,
            min_position: Some(-max_torque),
            max_position: Some(max_torque),
        }
    }
}

/// A rate of change of a torque's slope no check reaches (a torque
/// stream bounds the slope, not its change).
const UNBOUNDED: f64 = 1e300;

/// What the points of a stream carry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SetpointKind {
    /// A position per axis (cyclic synchronous position, interpolated
    /// position, CANsmc): played as the path.
    #[default]
    Position,
    /// A velocity per axis (cyclic synchronous velocity): the player
    /// integrates the velocities into the path they predict (trapezoidal
    /// between points, from where the axes stand when a playout starts),
    /// checks each point's velocity, its change against the acceleration
    /// and the predicted position against the soft limits, and plays that
    /// path; each cycle's velocity ([`SetpointPlayer::velocity`]) is the
    /// drive's set-point. A playout starts and resumes from rest.
    Velocity,
    /// A torque per axis (cyclic synchronous torque), per mille of the
    /// rated torque, with the limits of [`AxisLimits::torque`]: played
    /// like positions, each cycle's value ([`SetpointPlayer::position`])
    /// is the drive's torque set-point. A playout starts from 0 torque,
    /// holds the last torque when no point is left, and ramps to 0.
    Torque,
}

/// How a stream is played.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlayerConfig {
    /// What the points carry.
    pub kind: SetpointKind,
    /// The bus's cycle: the SYNC period, or the CANsmc cycle.
    pub cycle: Duration,
    /// The jitter buffer: how long after the fastest arrival a point is
    /// played.
    pub depth: Duration,
    /// How long the player goes on along the last segment when no point
    /// is left, before it ramps to rest.
    pub extrapolate: Duration,
    /// Arrivals over this window make the offset estimate.
    pub offset_window: Duration,
    /// The most the offset moves, as a fraction of the time elapsed
    /// (e.g. 0.001: the playout runs at most 0.1 % faster or slower than
    /// the client's clock).
    pub max_slew: f64,
}

impl PlayerConfig {
    /// A player for `cycle` with a jitter buffer of `depth`, extrapolating
    /// for one depth, the offset from the last 2 s of arrivals, slewing at
    /// most 0.1 %.
    pub fn new(cycle: Duration, depth: Duration) -> Self {
        PlayerConfig {
            kind: SetpointKind::Position,
            cycle,
            depth,
            extrapolate: depth,
            offset_window: Duration::from_secs(2),
            max_slew: 0.001,
        }
    }
}

/// One streamed point: the client's time and a value per axis of the
/// stream, in the stream's axis order.
#[derive(Debug, Clone, PartialEq)]
pub struct StreamPoint {
    /// The client's clock, µs.
    pub t_us: u64,
    /// One value per axis: a position (user units) in a position stream,
    /// a velocity (user units/s) in a velocity stream, a torque (per mille
    /// of the rated torque) in a torque stream ([`SetpointKind`]).
    pub values: Vec<f64>,
    /// A position stream's feed-forward, if the client gives one.
    pub feed_forward: Option<FeedForward>,
}

/// The feed-forward of a point of a position stream: the velocity (and
/// optionally the torque) the client's path has there, per axis. Checked
/// with the point (finite, the velocity within the maximum velocity, the
/// torque within the maximum torque where the player knows it) and
/// interpolated between points like the position
/// ([`SetpointPlayer::feed_forward`]).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FeedForward {
    /// One velocity per axis (user units/s).
    pub velocities: Vec<f64>,
    /// One torque per axis (per mille of the rated torque), or none.
    pub torques: Vec<f64>,
}

impl FeedForward {
    /// `self` and `other` mixed at `f` (0: `self`, 1: `other`); torques
    /// only where both have them.
    fn lerp(&self, other: &FeedForward, f: f64) -> FeedForward {
        let mix = |a: &[f64], b: &[f64]| -> Vec<f64> {
            if a.len() != b.len() {
                return Vec::new();
            }
            a.iter().zip(b).map(|(x, y)| x + (y - x) * f).collect()
        };
        FeedForward {
            velocities: mix(&self.velocities, &other.velocities),
            torques: mix(&self.torques, &other.torques),
        }
    }
}

/// Why a point was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PointRefused {
    /// Not one position per axis of the stream.
    #[error("{got} positions for a stream of {want} axes")]
    Dimension {
        /// Positions given.
        got: usize,
        /// Axes of the stream.
        want: usize,
    },
    /// A position is not a finite number.
    #[error("axis {axis}: position {value} is not a finite number")]
    NotFinite {
        /// Index of the axis in the stream.
        axis: usize,
        /// The value.
        value: f64,
    },
    /// Its time is not after the previous point's.
    #[error("time {t_us} µs is not after the previous point's {previous_us} µs")]
    NotAfterPrevious {
        /// Its time.
        t_us: u64,
        /// The previous accepted point's.
        previous_us: u64,
    },
    /// Outside the soft limits, or too fast to stop inside them.
    #[error(
        "axis {axis}: {position} at {velocity} units/s cannot stay inside the soft limits \
         (it would need until {stop_at} to stop)"
    )]
    BeyondSoftLimit {
        /// Index of the axis in the stream.
        axis: usize,
        /// The position.
        position: f64,
        /// The velocity it arrives with.
        velocity: f64,
        /// Where it would come to rest at the stop deceleration.
        stop_at: f64,
    },
    /// The segment to it is faster than the axis's maximum velocity.
    #[error("axis {axis}: {velocity:.6} units/s exceeds the maximum velocity {max}")]
    TooFast {
        /// Index of the axis in the stream.
        axis: usize,
        /// The segment's velocity.
        velocity: f64,
        /// The maximum.
        max: f64,
    },
    /// The velocity changes faster than the axis's maximum acceleration.
    #[error("axis {axis}: {acceleration:.6} units/s² exceeds the maximum acceleration {max}")]
    TooHardAcceleration {
        /// Index of the axis in the stream.
        axis: usize,
        /// The acceleration between the segments.
        acceleration: f64,
        /// The maximum.
        max: f64,
    },
    /// The acceleration changes faster than the axis's maximum jerk.
    #[error("axis {axis}: {jerk:.6} units/s³ exceeds the maximum jerk {max}")]
    TooHardJerk {
        /// Index of the axis in the stream.
        axis: usize,
        /// The change of acceleration between the segments, per second.
        jerk: f64,
        /// The maximum.
        max: f64,
    },
    /// The first velocity of a playout is not (nearly) 0: a velocity
    /// stream starts and resumes from rest.
    #[error(
        "axis {axis}: a velocity stream starts from rest: the first velocity must be within \
         {tolerance} units/s of 0, not {velocity}"
    )]
    NotFromRest {
        /// Index of the axis in the stream.
        axis: usize,
        /// The point's velocity.
        velocity: f64,
        /// The velocity reachable from rest in one cycle.
        tolerance: f64,
    },
    /// A torque above the axis's maximum torque.
    #[error("axis {axis}: torque {torque} per mille exceeds the maximum {max} per mille")]
    TorqueAboveMax {
        /// Index of the axis in the stream.
        axis: usize,
        /// The point's torque.
        torque: f64,
        /// The axis's maximum torque.
        max: f64,
    },
    /// The torque changes from the previous point faster than the axis's
    /// torque slope.
    #[error("axis {axis}: the torque changes at {slope:.3} per mille/s, above the slope {max}")]
    TorqueTooSteep {
        /// Index of the axis in the stream.
        axis: usize,
        /// The change from the previous point, per mille per second.
        slope: f64,
        /// The axis's torque slope.
        max: f64,
    },
    /// The first torque of a playout is not (nearly) 0: a torque stream
    /// starts and resumes from 0 torque.
    #[error(
        "axis {axis}: a torque stream starts from 0 torque: the first torque must be within \
         {tolerance} per mille of 0, not {torque}"
    )]
    TorqueNotFromZero {
        /// Index of the axis in the stream.
        axis: usize,
        /// The point's torque.
        torque: f64,
        /// The change the torque slope allows in one cycle.
        tolerance: f64,
    },
    /// The first point after a rest is not where the axes stand.
    #[error("axis {axis}: a stream resumes where the axis stands ({standing}), not at {position}")]
    NotWhereTheAxisStands {
        /// Index of the axis in the stream.
        axis: usize,
        /// Where it stands.
        standing: f64,
        /// The point's position.
        position: f64,
    },
}

/// What the player is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlayerState {
    /// At rest, waiting for a (first or resumed) point.
    Waiting,
    /// Buffering the first points of an epoch; the axes hold.
    Filling,
    /// Playing the client's points.
    Playing,
    /// No point left: going on along the last segment.
    Extrapolating,
    /// Ramping to rest (an underrun, or a stop).
    Stopping,
}

/// Something the stream's client should hear about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlayerEvent {
    /// No point came in time: the axes are brought to rest.
    Underrun,
    /// The axes came to rest (after an underrun or a stop).
    AtRest,
}

/// Counts of a stream. `received = accepted + refused`;
/// `accepted = played + late + dropped + buffered`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PlayerCounters {
    /// Points pushed.
    pub received: u64,
    /// Points taken into the buffer.
    pub accepted: u64,
    /// Points refused (their reason went back to the client).
    pub refused: u64,
    /// Points the playout passed (interpolated or reached).
    pub played: u64,
    /// Points that arrived after their playout time.
    pub late: u64,
    /// Points dropped while the axes were brought to rest.
    pub dropped: u64,
    /// Underruns.
    pub underruns: u64,
    /// Cycles whose step the acceleration or velocity guard shortened
    /// (the axes then lag the client's path for a few cycles).
    pub limited: u64,
}

/// The set-points of one cycle.
#[derive(Debug, Clone, PartialEq)]
pub struct CycleSetpoints {
    /// One position per axis of the stream (user units).
    pub positions: Vec<f64>,
    /// The player's state after this cycle.
    pub state: PlayerState,
    /// What happened in this cycle, if anything.
    pub event: Option<PlayerEvent>,
}

/// A point in the buffer, with the velocity of the segment that ends in
/// it (units/s per axis).
#[derive(Debug, Clone)]
struct Buffered {
    t_us: u64,
    positions: Vec<f64>,
    velocity: Vec<f64>,
    /// The acceleration of the segment that ends in it (units/s² per
    /// axis): the reference of the next point's jerk.
    acceleration: Vec<f64>,
    /// The client's feed-forward at the point.
    feed_forward: Option<FeedForward>,
}

/// The ramp to rest: from `from` at `velocity`, decelerating over
/// `duration` (all axes together); or, `to_zero` (a torque stream), from
/// `from` straight to 0 over `duration`.
#[derive(Debug, Clone)]
struct Ramp {
    start: Duration,
    from: Vec<f64>,
    velocity: Vec<f64>,
    duration: f64,
    to_zero: bool,
}

impl Ramp {
    fn at(&self, t: Duration) -> (Vec<f64>, bool) {
        let s = t
            .saturating_sub(self.start)
            .as_secs_f64()
            .min(self.duration);
        let done = s >= self.duration;
        if self.to_zero {
            let left = if done { 0.0 } else { 1.0 - s / self.duration };
            return (self.from.iter().map(|t| t * left).collect(), done);
        }
        let k = if self.duration > 0.0 {
            s - s * s / (2.0 * self.duration)
        } else {
            0.0
        };
        let p = (self.from.iter().zip(&self.velocity))
            .map(|(p, v)| p + v * k)
            .collect();
        (p, done)
    }
}

/// Plays one stream. See the [module documentation](self).
#[derive(Debug, Clone)]
pub struct SetpointPlayer {
    cfg: PlayerConfig,
    limits: Vec<AxisLimits>,
    state: PlayerState,
    buffer: VecDeque<Buffered>,
    /// The point the playout last passed (its segment is played next).
    last_played: Option<Buffered>,
    /// Last accepted point (the buffer's back, or `last_played`).
    last_accepted: Option<Buffered>,
    /// Where the axes are commanded now, and their velocity.
    position: Vec<f64>,
    velocity: Vec<f64>,
    /// Playout offset (gateway µs − client µs), in µs, and its target.
    offset_us: Option<f64>,
    target_offset_us: f64,
    /// Recent (arrival µs, delay µs) for the offset's estimate.
    delays: VecDeque<(f64, f64)>,
    /// The last cycle's time.
    last_cycle: Option<Duration>,
    /// Extrapolating since.
    extrapolating_since: Option<Duration>,
    ramp: Option<Ramp>,
    counters: PlayerCounters,
    /// A velocity stream's last accepted point: its time, velocities and
    /// the position they predict (`None` at the start of a playout).
    chain: Option<Chain>,
    /// The client's feed-forward interpolated for the last cycle, if the
    /// points around it had one.
    cycle_feed_forward: Option<FeedForward>,
    /// The largest feed-forward torque per axis, where known.
    max_feed_forward_torque: Option<Vec<f64>>,
    /// The client gave a feed-forward with a point.
    given_feed_forward: bool,
}

/// The last accepted point of a velocity stream, integrated.
#[derive(Debug, Clone)]
struct Chain {
    t_us: u64,
    velocity: Vec<f64>,
    position: Vec<f64>,
}

impl SetpointPlayer {
    /// A player for axes standing at `positions` (one per `limits`).
    pub fn new(cfg: PlayerConfig, limits: Vec<AxisLimits>, positions: Vec<f64>) -> Self {
        let n = limits.len();
        SetpointPlayer {
            cfg,
            limits,
            state: PlayerState::Waiting,
            buffer: VecDeque::new(),
            last_played: None,
            last_accepted: None,
            position: positions,
            velocity: vec![0.0; n],
            offset_us: None,
            target_offset_us: 0.0,
            delays: VecDeque::new(),
            last_cycle: None,
            extrapolating_since: None,
            ramp: None,
            counters: PlayerCounters::default(),
            chain: None,
            cycle_feed_forward: None,
            max_feed_forward_torque: None,
            given_feed_forward: false,
        }
    }

    /// The same player, refusing a point whose feed-forward torque exceeds
    /// `max` (per axis, per mille; [`PointRefused::TorqueAboveMax`]).
    pub fn with_feed_forward_torque_limits(mut self, max: Vec<f64>) -> Self {
        self.max_feed_forward_torque = Some(max);
        self
    }

    /// The feed-forward of the last cycle, per axis: the client's,
    /// interpolated between the points around the cycle where both have
    /// one; else, once the client gave one (extrapolating, ramping to
    /// rest, a point without), the commanded velocity of the cycle and no
    /// torque; 0 in a stream whose client never gave one (the drive's own
    /// feed-forward, if it has one, is not doubled). Velocities in user
    /// units/s, torques in per mille (empty: none).
    pub fn feed_forward(&self) -> FeedForward {
        match &self.cycle_feed_forward {
            Some(ff) if ff.velocities.len() == self.velocity.len() => ff.clone(),
            _ => FeedForward {
                velocities: if self.given_feed_forward {
                    self.velocity.clone()
                } else {
                    vec![0.0; self.velocity.len()]
                },
                torques: Vec::new(),
            },
        }
    }

    /// What the points carry.
    pub fn kind(&self) -> SetpointKind {
        self.cfg.kind
    }

    /// The player's state.
    pub fn state(&self) -> PlayerState {
        self.state
    }

    /// The counters.
    pub fn counters(&self) -> PlayerCounters {
        self.counters
    }

    /// The playout's offset of the client's clock, µs: gateway time minus
    /// client time of the fastest recent arrival (the network's delay plus
    /// the clocks' difference), while a stream plays.
    pub fn clock_offset_us(&self) -> Option<i64> {
        self.offset_us.map(|o| o.round() as i64)
    }

    /// Where the axes are commanded now (user units, one per axis).
    pub fn position(&self) -> &[f64] {
        &self.position
    }

    /// The commanded velocity of each axis over the last cycle (user
    /// units/s).
    pub fn velocity(&self) -> &[f64] {
        &self.velocity
    }

    /// How much client time is buffered ahead of the playout at `now`.
    pub fn level(&self, now: Duration) -> Duration {
        let (Some(last), Some(offset)) = (self.last_accepted.as_ref(), self.offset_us) else {
            return Duration::ZERO;
        };
        let playing = self.client_time(now, offset);
        Duration::from_micros((last.t_us as f64 - playing).max(0.0) as u64)
    }

    fn client_time(&self, now: Duration, offset_us: f64) -> f64 {
        now.as_micros() as f64 - offset_us - self.cfg.depth.as_micros() as f64
    }

    /// Takes a point that arrived at `arrived` (the gateway's clock).
    pub fn push(&mut self, point: StreamPoint, arrived: Duration) -> Result<(), PointRefused> {
        self.counters.received += 1;
        let r = match self.cfg.kind {
            SetpointKind::Position => self.accept(point, arrived),
            SetpointKind::Velocity => self.accept_velocity(point, arrived),
            SetpointKind::Torque => self.accept_torque(point, arrived),
        };
        if r.is_err() {
            self.counters.refused += 1;
        }
        r
    }

    /// A feed-forward: one finite velocity per axis within its maximum
    /// velocity, no torque or one finite torque per axis within its
    /// maximum.
    fn check_feed_forward(&self, ff: &FeedForward) -> Result<(), PointRefused> {
        let n = self.limits.len();
        let torques_fit = ff.torques.is_empty() || ff.torques.len() == n;
        if ff.velocities.len() != n || !torques_fit {
            let got = if torques_fit {
                ff.velocities.len()
            } else {
                ff.torques.len()
            };
            return Err(PointRefused::Dimension { got, want: n });
        }
        for values in [&ff.velocities, &ff.torques] {
            if let Some((axis, &value)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
                return Err(PointRefused::NotFinite { axis, value });
            }
        }
        for (axis, (&v, l)) in ff.velocities.iter().zip(&self.limits).enumerate() {
            if v.abs() > l.max_velocity * (1.0 + 1e-9) {
                return Err(PointRefused::TooFast {
                    axis,
                    velocity: v,
                    max: l.max_velocity,
                });
            }
        }
        if let Some(max) = &self.max_feed_forward_torque {
            for (axis, (&torque, &max)) in ff.torques.iter().zip(max).enumerate() {
                if torque.abs() > max * (1.0 + 1e-9) {
                    return Err(PointRefused::TorqueAboveMax { axis, torque, max });
                }
            }
        }
        Ok(())
    }

    /// One finite value per axis.
    fn check_values(&self, p: &StreamPoint) -> Result<(), PointRefused> {
        let n = self.limits.len();
        if p.values.len() != n {
            return Err(PointRefused::Dimension {
                got: p.values.len(),
                want: n,
            });
        }
        if let Some((axis, &value)) = p.values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(PointRefused::NotFinite { axis, value });
        }
        Ok(())
    }

    /// A point of a torque stream: each torque within the axis's maximum,
    /// from 0 at the start of a playout, and changing from the previous
    /// point at most at the torque slope; then taken as a position.
    fn accept_torque(&mut self, p: StreamPoint, arrived: Duration) -> Result<(), PointRefused> {
        self.check_values(&p)?;
        for (axis, (&torque, l)) in p.values.iter().zip(&self.limits).enumerate() {
            let max = l.max_position.unwrap_or(f64::INFINITY);
            if torque.abs() > max * (1.0 + 1e-9) {
                return Err(PointRefused::TorqueAboveMax { axis, torque, max });
            }
        }
        match (&self.last_accepted, self.state) {
            (_, PlayerState::Stopping) => {}
            (Some(prev), s) if s != PlayerState::Waiting => {
                if p.t_us > prev.t_us {
                    let dt = (p.t_us - prev.t_us) as f64 / 1e6;
                    for (axis, ((&t, &t0), l)) in
                        (p.values.iter().zip(&prev.positions).zip(&self.limits)).enumerate()
                    {
                        let slope = (t - t0) / dt;
                        if slope.abs() > l.max_velocity * (1.0 + 1e-9) {
                            return Err(PointRefused::TorqueTooSteep {
                                axis,
                                slope,
                                max: l.max_velocity,
                            });
                        }
                    }
                }
            }
            _ => {
                let cycle = self.cfg.cycle.as_secs_f64();
                for (axis, ((&torque, &now), l)) in
                    (p.values.iter().zip(&self.position).zip(&self.limits)).enumerate()
                {
                    let tolerance = l.max_velocity * cycle;
                    if (torque - now).abs() > tolerance + 1e-9 {
                        return Err(PointRefused::TorqueNotFromZero {
                            axis,
                            torque,
                            tolerance,
                        });
                    }
                }
            }
        }
        self.accept(p, arrived)
    }

    /// A point of a velocity stream: its velocities checked, integrated
    /// into the position they predict, and that point taken as in a
    /// position stream.
    fn accept_velocity(&mut self, p: StreamPoint, arrived: Duration) -> Result<(), PointRefused> {
        self.check_values(&p)?;
        if self.state == PlayerState::Waiting {
            // A new playout, from rest.
            self.chain = None;
        }
        for (axis, (&v, l)) in p.values.iter().zip(&self.limits).enumerate() {
            if v.abs() > l.max_velocity * (1.0 + 1e-9) {
                return Err(PointRefused::TooFast {
                    axis,
                    velocity: v,
                    max: l.max_velocity,
                });
            }
        }
        let position = match &self.chain {
            None => {
                let cycle = self.cfg.cycle.as_secs_f64();
                for (axis, (&v, l)) in p.values.iter().zip(&self.limits).enumerate() {
                    let tolerance = l.max_acceleration * cycle;
                    if v.abs() > tolerance + 1e-9 {
                        return Err(PointRefused::NotFromRest {
                            axis,
                            velocity: v,
                            tolerance,
                        });
                    }
                }
                self.position.clone()
            }
            Some(c) => {
                if p.t_us <= c.t_us {
                    return Err(PointRefused::NotAfterPrevious {
                        t_us: p.t_us,
                        previous_us: c.t_us,
                    });
                }
                let dt = (p.t_us - c.t_us) as f64 / 1e6;
                for (axis, ((&v, &v0), l)) in
                    (p.values.iter().zip(&c.velocity).zip(&self.limits)).enumerate()
                {
                    let a = (v - v0) / dt;
                    if a.abs() > l.max_acceleration * (1.0 + 1e-9) {
                        return Err(PointRefused::TooHardAcceleration {
                            axis,
                            acceleration: a,
                            max: l.max_acceleration,
                        });
                    }
                }
                (c.position.iter().zip(&c.velocity).zip(&p.values))
                    .map(|((x, v0), v)| x + (v0 + v) / 2.0 * dt)
                    .collect()
            }
        };
        for (axis, ((&x, &v), l)) in position.iter().zip(&p.values).zip(&self.limits).enumerate() {
            let stop_at = x + v * v.abs() / (2.0 * l.stop_deceleration.max(1e-12));
            let inside = |y: f64| {
                l.min_position.is_none_or(|m| y >= m - 1e-9)
                    && l.max_position.is_none_or(|m| y <= m + 1e-9)
            };
            if !inside(x) || !inside(stop_at) {
                return Err(PointRefused::BeyondSoftLimit {
                    axis,
                    position: x,
                    velocity: v,
                    stop_at,
                });
            }
        }
        let t_us = p.t_us;
        let velocity = p.values;
        self.accept(
            StreamPoint {
                feed_forward: None,
                t_us,
                values: position.clone(),
            },
            arrived,
        )?;
        // The point's own velocity, not the segment's mean: extrapolation
        // holds it.
        for b in [
            self.buffer.back_mut(),
            self.last_accepted.as_mut(),
            self.last_played.as_mut(),
        ]
        .into_iter()
        .flatten()
        {
            if b.t_us == t_us {
                b.velocity.clone_from(&velocity);
            }
        }
        self.chain = Some(Chain {
            t_us,
            velocity,
            position,
        });
        Ok(())
    }

    fn accept(&mut self, p: StreamPoint, arrived: Duration) -> Result<(), PointRefused> {
        let n = self.limits.len();
        self.check_values(&p)?;
        if let Some(ff) = &p.feed_forward {
            self.check_feed_forward(ff)?;
            self.given_feed_forward = true;
        }
        if self.state == PlayerState::Stopping {
            // Counted as accepted and dropped: the client sent it in good
            // faith; the axes are on their way to rest.
            self.counters.accepted += 1;
            self.counters.dropped += 1;
            return Ok(());
        }
        let arrived_us = arrived.as_micros() as f64;
        let new_epoch = self.state == PlayerState::Waiting;
        let mut acceleration = vec![0.0; n];
        let velocity = match (&self.last_accepted, new_epoch) {
            (Some(prev), false) => {
                if p.t_us <= prev.t_us {
                    return Err(PointRefused::NotAfterPrevious {
                        t_us: p.t_us,
                        previous_us: prev.t_us,
                    });
                }
                let dt = (p.t_us - prev.t_us) as f64 / 1e6;
                let v: Vec<f64> = (p.values.iter().zip(&prev.positions))
                    .map(|(a, b)| (a - b) / dt)
                    .collect();
                for (axis, (&vel, l)) in v.iter().zip(&self.limits).enumerate() {
                    if vel.abs() > l.max_velocity * (1.0 + 1e-9) {
                        return Err(PointRefused::TooFast {
                            axis,
                            velocity: vel,
                            max: l.max_velocity,
                        });
                    }
                    let a = (vel - prev.velocity[axis]) / dt;
                    if self.cfg.kind == SetpointKind::Position
                        && a.abs() > l.max_acceleration * (1.0 + 1e-9)
                    {
                        return Err(PointRefused::TooHardAcceleration {
                            axis,
                            acceleration: a,
                            max: l.max_acceleration,
                        });
                    }
                    let jerk = (a - prev.acceleration[axis]) / dt;
                    if self.cfg.kind == SetpointKind::Position
                        && let Some(max) = l.max_jerk
                        && jerk.abs() > max * (1.0 + 1e-9)
                    {
                        return Err(PointRefused::TooHardJerk { axis, jerk, max });
                    }
                    acceleration[axis] = a;
                }
                v
            }
            _ => {
                // A new epoch starts where the axes stand.
                for (axis, (&pos, l)) in p.values.iter().zip(&self.limits).enumerate() {
                    let tolerance = l.max_velocity * self.cfg.cycle.as_secs_f64() + 1e-9;
                    if (pos - self.position[axis]).abs() > tolerance {
                        return Err(PointRefused::NotWhereTheAxisStands {
                            axis,
                            standing: self.position[axis],
                            position: pos,
                        });
                    }
                }
                vec![0.0; n]
            }
        };
        for (axis, ((&pos, &vel), l)) in
            p.values.iter().zip(&velocity).zip(&self.limits).enumerate()
        {
            let stop_at = pos + vel * vel.abs() / (2.0 * l.stop_deceleration.max(1e-12));
            let inside = |x: f64| {
                l.min_position.is_none_or(|m| x >= m - 1e-9)
                    && l.max_position.is_none_or(|m| x <= m + 1e-9)
            };
            if !inside(pos) || !inside(stop_at) {
                return Err(PointRefused::BeyondSoftLimit {
                    axis,
                    position: pos,
                    velocity: vel,
                    stop_at,
                });
            }
        }
        // The offset: the smallest recent delay.
        let delay = arrived_us - p.t_us as f64;
        let window = self.cfg.offset_window.as_micros() as f64;
        self.delays.push_back((arrived_us, delay));
        while self
            .delays
            .front()
            .is_some_and(|(at, _)| *at < arrived_us - window)
        {
            self.delays.pop_front();
        }
        self.target_offset_us = self
            .delays
            .iter()
            .map(|d| d.1)
            .fold(f64::INFINITY, f64::min);
        let b = Buffered {
            t_us: p.t_us,
            positions: p.values,
            velocity,
            acceleration,
            feed_forward: p.feed_forward,
        };
        if new_epoch {
            self.offset_us = Some(delay);
            self.target_offset_us = delay;
            self.delays.clear();
            self.delays.push_back((arrived_us, delay));
            self.state = PlayerState::Filling;
            self.last_played = Some(b.clone());
            self.counters.accepted += 1;
            self.counters.played += 1;
            self.last_accepted = Some(b);
            return Ok(());
        }
        self.counters.accepted += 1;
        // Late: its time is already behind the playout.
        if let (Some(offset), Some(last)) = (self.offset_us, self.last_cycle)
            && (b.t_us as f64) < self.client_time(last, offset)
        {
            self.counters.late += 1;
            // Still the reference for the next segment's checks: the
            // client's path goes on from there.
            self.last_accepted = Some(b);
            return Ok(());
        }
        self.last_accepted = Some(b.clone());
        self.buffer.push_back(b);
        Ok(())
    }

    /// Cycles were skipped for `missed` (a stalled sender), and the
    /// player's clock is held back by them. In a velocity stream the drive
    /// went on at the last velocity meanwhile (it integrates the set-point
    /// it has over real time): the prediction, and the path still to play,
    /// move on by that travel, so the soft-limit guards judge where the
    /// drive is and the client's velocities play on from there. A position
    /// stream needs nothing: the drive holds the last position.
    pub fn skipped(&mut self, missed: Duration) {
        if self.cfg.kind != SetpointKind::Velocity || missed.is_zero() {
            return;
        }
        let s = missed.as_secs_f64();
        let travel: Vec<f64> = self.velocity.iter().map(|v| v * s).collect();
        let shift = |xs: &mut Vec<f64>| {
            for (x, d) in xs.iter_mut().zip(&travel) {
                *x += d;
            }
        };
        shift(&mut self.position);
        if let Some(r) = self.ramp.as_mut() {
            shift(&mut r.from);
        }
        for b in (self.buffer.iter_mut())
            .chain(self.last_played.as_mut())
            .chain(self.last_accepted.as_mut())
        {
            shift(&mut b.positions);
        }
        if let Some(c) = self.chain.as_mut() {
            shift(&mut c.position);
        }
    }

    /// Brings the axes to rest from where they are (the stream ended, was
    /// cancelled, or lost its lease).
    pub fn stop(&mut self, now: Duration) {
        if matches!(self.state, PlayerState::Waiting | PlayerState::Stopping) {
            return;
        }
        // From where the axes were commanded last.
        self.begin_ramp(self.last_cycle.unwrap_or(now));
    }

    /// Ramps to rest from `self.position` (commanded at `start`) at
    /// `self.velocity`.
    fn begin_ramp(&mut self, start: Duration) {
        self.counters.dropped += self.buffer.len() as u64;
        self.buffer.clear();
        if self.cfg.kind == SetpointKind::Torque {
            // Every torque to 0 at its slope, all reaching 0 together.
            let duration = (self.position.iter().zip(&self.limits))
                .map(|(t, l)| t.abs() / l.max_velocity.max(1e-12))
                .fold(0.0, f64::max);
            self.ramp = Some(Ramp {
                start,
                from: self.position.clone(),
                velocity: self.velocity.clone(),
                duration,
                to_zero: true,
            });
            self.state = PlayerState::Stopping;
            return;
        }
        // All axes stop together: the longest stop time, each axis's
        // deceleration then within its own.
        let duration = (self.velocity.iter().zip(&self.limits))
            .map(|(v, l)| v.abs() / l.stop_deceleration.max(1e-12))
            .fold(0.0, f64::max);
        self.ramp = Some(Ramp {
            start,
            from: self.position.clone(),
            velocity: self.velocity.clone(),
            duration,
            to_zero: false,
        });
        self.state = PlayerState::Stopping;
    }

    /// The set-points of the cycle at `now` (call once per cycle, in time
    /// order).
    pub fn next(&mut self, now: Duration) -> CycleSetpoints {
        let prev = self.last_cycle;
        let dt = prev
            .map_or(self.cfg.cycle, |l| now.saturating_sub(l))
            .as_secs_f64();
        // Where the axes are (`self.position`) is where they were commanded
        // at `prev`: a ramp begun in this cycle starts there.
        let ramp_start = prev.unwrap_or(now);
        self.last_cycle = Some(now);
        let mut event = None;
        let before = self.position.clone();
        let offset_before = self.offset_us;
        self.cycle_feed_forward = None;
        // Slew the offset towards its estimate, bounded.
        if let Some(o) = self.offset_us.as_mut() {
            let max = self.cfg.max_slew * dt * 1e6;
            *o += (self.target_offset_us - *o).clamp(-max, max);
        }
        match self.state {
            PlayerState::Waiting => {}
            PlayerState::Stopping => self.ramp_on(now, &mut event),
            PlayerState::Filling | PlayerState::Playing | PlayerState::Extrapolating => {
                let offset = self.offset_us.expect("an offset while playing");
                let tc = self.client_time(now, offset);
                let start = self.last_played.as_ref().map_or(0, |b| b.t_us) as f64;
                if self.state == PlayerState::Filling && tc < start {
                    // Still filling the buffer: hold.
                } else if self.state == PlayerState::Extrapolating && !self.buffer.is_empty() {
                    // Points came back while the axes went on along the
                    // last segment: rejoin the client's path from where
                    // they are, or stop when that would take a jump.
                    let tc_prev = prev
                        .zip(offset_before)
                        .map_or(tc, |(p, o)| self.client_time(p, o));
                    self.rejoin(tc_prev, tc, now, dt, ramp_start, &mut event);
                } else {
                    self.play(tc, now, dt, ramp_start, &mut event);
                }
            }
        }
        if dt > 0.0 {
            self.limit(&before, dt);
        }
        if self.cfg.kind == SetpointKind::Torque && self.state == PlayerState::Waiting {
            // At rest a torque stream commands no torque: exactly 0, not
            // the rounding of the ramp's last step.
            self.position.iter_mut().for_each(|t| *t = 0.0);
            self.velocity.iter_mut().for_each(|v| *v = 0.0);
        }
        CycleSetpoints {
            positions: self.position.clone(),
            state: self.state,
            event,
        }
    }

    /// The last guard against a jump: the step from `before` to
    /// `self.position` keeps each axis's maximum velocity and changes its
    /// velocity by at most its acceleration over `dt` (its stop
    /// deceleration on the ramp to rest). Linear interpolation turns at
    /// each point, which a client's period longer than the cycle would
    /// make a step change of velocity; here it becomes a bounded
    /// acceleration that catches the path up within a few cycles
    /// (counted in `limited`).
    fn limit(&mut self, before: &[f64], dt: f64) {
        let stopping = self.state == PlayerState::Stopping;
        let mut limited = false;
        for (a, l) in self.limits.iter().enumerate() {
            let wanted = (self.position[a] - before[a]) / dt;
            let accel = if stopping {
                l.stop_deceleration.max(l.max_acceleration)
            } else {
                l.max_acceleration
            };
            let previous = self.velocity[a];
            let mut v = wanted
                .clamp(previous - accel * dt, previous + accel * dt)
                .clamp(-l.max_velocity, l.max_velocity);
            if self.cfg.kind == SetpointKind::Velocity {
                // A velocity stream's path is its drive's integral, which
                // no point pins: whatever late points and rejoins made of
                // it, the axis can always stop inside its soft limits.
                v = within_stopping_reach(v, before[a], dt, l);
            }
            if (v - wanted).abs() > 1e-9 * l.max_velocity.max(1.0) {
                limited = true;
            }
            let mut p = before[a] + v * dt;
            if let Some(m) = l.min_position {
                p = p.max(m);
            }
            if let Some(m) = l.max_position {
                p = p.min(m);
            }
            self.position[a] = p;
            self.velocity[a] = (p - before[a]) / dt;
        }
        if limited {
            self.counters.limited += 1;
        }
    }

    /// One cycle along the ramp to rest.
    fn ramp_on(&mut self, now: Duration, event: &mut Option<PlayerEvent>) {
        let ramp = self.ramp.as_ref().expect("a ramp while stopping");
        let (p, done) = ramp.at(now);
        self.position = p;
        if done {
            self.state = PlayerState::Waiting;
            self.ramp = None;
            self.last_accepted = None;
            self.last_played = None;
            self.offset_us = None;
            *event = Some(PlayerEvent::AtRest);
        }
    }

    /// Plays client time `tc`: interpolated between the points around it,
    /// or, with none ahead, along the last segment until the extrapolation
    /// time is up (then the ramp to rest).
    fn play(
        &mut self,
        tc: f64,
        now: Duration,
        dt: f64,
        ramp_start: Duration,
        event: &mut Option<PlayerEvent>,
    ) {
        self.state = PlayerState::Playing;
        while self.buffer.front().is_some_and(|b| b.t_us as f64 <= tc) {
            self.last_played = self.buffer.pop_front();
            self.counters.played += 1;
        }
        match (self.last_played.as_ref(), self.buffer.front()) {
            (Some(a), Some(b)) => {
                let f = ((tc - a.t_us as f64) / (b.t_us - a.t_us) as f64).clamp(0.0, 1.0);
                self.position = (a.positions.iter().zip(&b.positions))
                    .map(|(x, y)| x + (y - x) * f)
                    .collect();
                self.cycle_feed_forward = match (&a.feed_forward, &b.feed_forward) {
                    (Some(x), Some(y)) => Some(x.lerp(y, f)),
                    _ => None,
                };
                self.extrapolating_since = None;
            }
            (Some(a), None) => {
                let first = self.extrapolating_since.is_none();
                let since = *self.extrapolating_since.get_or_insert(now);
                self.state = PlayerState::Extrapolating;
                if now.saturating_sub(since) >= self.cfg.extrapolate
                    || self.extrapolation_leaves_the_limits(dt)
                {
                    self.underrun(ramp_start, now, event);
                } else if self.cfg.kind == SetpointKind::Torque {
                    // A torque is held, not extrapolated along its slope.
                    self.position.clone_from(&a.positions);
                } else if first {
                    // The path up to the last point is played, then on
                    // along its last segment: from the previous cycle's
                    // position the rest of the path would be cut short.
                    let past = (tc - a.t_us as f64) / 1e6;
                    self.position = (a.positions.iter().zip(&a.velocity))
                        .map(|(p, v)| p + v * past)
                        .collect();
                } else {
                    let v = a.velocity.clone();
                    for (p, v) in self.position.iter_mut().zip(&v) {
                        *p += v * dt;
                    }
                }
            }
            (None, _) => {}
        }
    }

    fn underrun(&mut self, ramp_start: Duration, now: Duration, event: &mut Option<PlayerEvent>) {
        self.counters.underruns += 1;
        *event = Some(PlayerEvent::Underrun);
        self.extrapolating_since = None;
        self.begin_ramp(ramp_start);
        self.ramp_on(now, event);
        // Already at rest (the axes stood still): the cycle reports the
        // underrun; the state says the player waits.
        *event = Some(PlayerEvent::Underrun);
    }

    /// Leaves the extrapolation for the next buffered point ahead of `tc`:
    /// the axes go from where they are (commanded at client time
    /// `tc_prev`) straight to it, when that segment keeps the limits;
    /// otherwise they ramp to rest. Points already behind `tc` are late.
    fn rejoin(
        &mut self,
        tc_prev: f64,
        tc: f64,
        now: Duration,
        dt: f64,
        ramp_start: Duration,
        event: &mut Option<PlayerEvent>,
    ) {
        while self.buffer.front().is_some_and(|b| b.t_us as f64 <= tc) {
            self.buffer.pop_front();
            self.counters.late += 1;
        }
        let Some(b) = self.buffer.front() else {
            // Everything that came is already behind: keep extrapolating.
            self.play(tc, now, dt, ramp_start, event);
            return;
        };
        let span = (b.t_us as f64 - tc_prev) / 1e6;
        let cycle = self.cfg.cycle.as_secs_f64();
        let fits = span > 0.0
            && (self
                .position
                .iter()
                .zip(&b.positions)
                .zip(&self.velocity)
                .zip(&self.limits))
            .all(|(((p, q), v), l)| {
                let needed = (q - p) / span;
                needed.abs() <= l.max_velocity
                    && (needed - v).abs() <= l.max_acceleration * span.max(cycle)
            });
        if !fits {
            self.underrun(ramp_start, now, event);
            return;
        }
        let from = Buffered {
            t_us: tc_prev.max(0.0) as u64,
            positions: self.position.clone(),
            velocity: self.velocity.clone(),
            acceleration: vec![0.0; self.limits.len()],
            feed_forward: None,
        };
        self.last_played = Some(from);
        self.extrapolating_since = None;
        self.state = PlayerState::Playing;
        let f = ((tc - tc_prev) / (b.t_us as f64 - tc_prev)).clamp(0.0, 1.0);
        self.position = (self.position.iter().zip(&b.positions))
            .map(|(x, y)| x + (y - x) * f)
            .collect();
    }

    /// Whether one more cycle along the last segment would leave a point
    /// from which an axis cannot stop inside its soft limits.
    fn extrapolation_leaves_the_limits(&self, dt: f64) -> bool {
        if self.cfg.kind == SetpointKind::Torque {
            // A held torque stays where it was accepted.
            return false;
        }
        (self.position.iter().zip(&self.velocity).zip(&self.limits)).any(|((p, v), l)| {
            let next = p + v * dt;
            let stop_at = next + v * v.abs() / (2.0 * l.stop_deceleration.max(1e-12));
            l.min_position.is_some_and(|m| stop_at < m)
                || l.max_position.is_some_and(|m| stop_at > m)
        })
    }
}

/// `v`, reduced where needed so that an axis at `x` that moves at it for
/// `dt` can still stop inside its soft limits at its stop deceleration.
fn within_stopping_reach(v: f64, x: f64, dt: f64, l: &AxisLimits) -> f64 {
    let d = l.stop_deceleration.max(1e-12);
    // v·dt + v²/(2d) <= room
    let reach = |room: f64| {
        if room <= 0.0 {
            0.0
        } else {
            -d * dt + ((d * dt).powi(2) + 2.0 * d * room).sqrt()
        }
    };
    let mut v = v;
    if let Some(m) = l.max_position {
        v = v.min(reach(m - x));
    }
    if let Some(m) = l.min_position {
        v = v.max(-reach(x - m));
    }
    v
}

#[cfg(test)]
mod tests;
