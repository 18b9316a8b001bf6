//! One CANsmc servo slave as an axis, sans-IO.
//!
//! A CANsmc axis is driven the way an NC interpolator drives a servo: every
//! cycle the gateway computes the next position set-point and sends it in
//! the slave's position MDT (function 0x02); the slave applies it at the
//! following MST. Moves are trapezoids ([`TrapezoidProfile`]), jogs a
//! velocity ramp with a dead-man, stops a ramp to rest — all planned here,
//! so position feedback is available every cycle. Homing hands the motion
//! to the slave (function 0x04) until it reports homed and in position.
//! Enable, halt and fault reset are MDTCW bits 0, 1 and 2.
//!
//! **Electronic gearing**: an axis configured with a [`Gear`] follows the
//! encoder count of another slave (function 0x07): its set-point in cycle
//! k+1 is `offset + ratio × count(k)`, the count sampled at the MST of
//! cycle k — one cycle of data lag, the spec's command pipeline. Gearing
//! engages when the axis is enabled and at rest (without a jump: the offset
//! is taken at that instant) and disengages on a stop, a disable or a
//! fault.
//!
//! **Set-point streams**: a streamed axis takes its demand from a stream's
//! player ([`crate::setpoint_stream::SetpointPlayer`]), one set-point per
//! cycle ([`CansmcAxis::stream_setpoint`]), through the same soft limits.
//! It takes no command but a stop meanwhile; a stop (or a fault, a
//! disable, a lost slave) ends the streamed motion at once — the axis
//! ramps down on its own stop ramp — and the runtime sees it in
//! [`CansmcAxis::is_streamed`].
//!
//! The runtime calls [`CansmcAxis::on_cycle`] once per cycle, right after
//! the master started it, with the slave's latest DT (and the gear
//! source's count), and sends what it returns.

use std::time::Duration;

use cangate_canopen::cia402::DriveState;
use cangate_cansmc::telegram::{Command, ControlWord, CycleCounter, StatusWord};
use cangate_motion::{Limits, TrapezoidProfile};

use crate::cia402::AxisSnapshot;
use crate::{
    Activity, AxisCommand, AxisEvent, CansmcDrive, CommandError, CommandKind, MotionSpec, OpId,
    Outcome, Units,
};

/// CiA 402 mode numbers reported in snapshots, so HMIs show one vocabulary
/// for both drive families: 8 = cyclic synchronous position, 6 = homing.
const MODE_CYCLIC_POSITION: i8 = 8;
const MODE_HOMING: i8 = 6;

pub use crate::spec::{Gear, JogMode};

/// The configuration of one CANsmc axis: what every axis has and its
/// slave (see [`crate::CansmcDrive::controller`]).
#[derive(Debug, Clone, PartialEq)]
pub struct CansmcAxisConfig {
    /// Units, limits, defaults, stops, time bounds.
    pub motion: MotionSpec,
    /// The slave, its master's cycle, gearing and jog mode.
    pub drive: CansmcDrive,
}

impl CansmcAxisConfig {
    /// A configuration suitable for the simulated slaves (tests, demo).
    pub fn example(counts_per_unit: f64, cycle_time: Duration) -> Self {
        CansmcAxisConfig {
            motion: MotionSpec::example(counts_per_unit, 1000.0),
            drive: CansmcDrive::example(cycle_time),
        }
    }
}

/// The slave's latest answer, as the master holds it at a cycle start.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CycleInput {
    /// Status word of the DT answering the previous cycle (`None` when it
    /// did not come: the axis keeps the one before and does not count the
    /// cycle towards a command's effect).
    pub status: Option<StatusWord>,
    /// Actual position (counts) from the latest position or homing DT.
    pub position: Option<i32>,
    /// The gear source's encoder count from its latest DT.
    pub source_count: Option<i32>,
    /// Actual velocity from the latest velocity DT (unit 0.001 r/min).
    pub velocity: Option<i32>,
    /// The slave's own encoder count from its latest encoder DT.
    pub encoder: Option<i32>,
}

/// The MDT content for this cycle (the master adds the counter).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CycleOutput {
    /// Enable, halt, fault reset.
    pub control: ControlWord,
    /// Position set-point or homing.
    pub command: Command,
}

#[derive(Debug, Clone, PartialEq)]
enum Motion {
    /// Hold the demand position.
    Hold,
    /// Follow a profile from `start` (time of its first sample), stretched
    /// by `ratio` (profile time per wall time).
    Profile {
        profile: TrapezoidProfile,
        ratio: f64,
        elapsed: Duration,
    },
    /// Velocity ramp towards `target` (units/s) with `acceleration`.
    Jog { target: f64, acceleration: f64 },
    /// The slave homes itself.
    Homing,
    /// Electronic gearing: demand counts = offset + ratio × source; the
    /// offset is set by the first source count after engaging.
    Geared { offset: Option<f64> },
    /// The slave's velocity mode: jogging at `target` (units/s), braking to
    /// 0, or reading the position back before holding it.
    SlaveVelocity { target: f64, stage: VelocityStage },
    /// A set-point stream's player sets the demand: the position and
    /// velocity of this cycle ([`CansmcAxis::stream_setpoint`]), taken by
    /// the next cycle.
    Streamed { next: Option<(f64, f64)> },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum VelocityStage {
    Running,
    Braking,
    ReadingPosition,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Step {
    Enabling,
    Disabling,
    Resetting,
    Homing,
    Moving,
    Jogging,
    Stopping,
}

#[derive(Debug, Clone)]
struct Op {
    id: OpId,
    kind: CommandKind,
    step: Step,
    target: f64,
    deadline: Option<Duration>,
    /// Jog: the dead-man expires here.
    deadman: Option<Duration>,
    /// Fresh DTs since the command started: the command goes out in the
    /// next MDT, the slave applies it at the following MST and the DT of
    /// that cycle reports it, which the axis sees at the MST after. So the
    /// first two statuses after a command still describe the slave before
    /// it; the third is the first that can show its effect.
    cycles: u32,
}

/// A CANsmc servo slave as an axis.
#[derive(Debug)]
pub struct CansmcAxis {
    cfg: CansmcAxisConfig,
    status: Option<StatusWord>,
    /// Actual position, counts.
    position: Option<i32>,
    /// Actual velocity estimated from consecutive positions, units/s.
    velocity: f64,
    /// Demand position and velocity, user units.
    demand: f64,
    demand_velocity: f64,
    motion: Motion,
    enable: bool,
    halt: bool,
    /// Fault reset bit: set for one cycle (the slave acts on the edge).
    reset_pulse: bool,
    op: Option<Op>,
    next_id: OpId,
    lost: Option<String>,
    /// Why the axis was disabled behind the user's back: its slave was lost
    /// while enabled. Kept (and shown as the axis's fault) after the slave
    /// answers again, until an enable or a fault reset acknowledges it, so
    /// a disabled axis always says why.
    disabled_by_loss: Option<String>,
    faulted: bool,
    homed: bool,
    /// Cycles the gear demand was clipped to the velocity limit.
    gear_clipped: u64,
    /// Velocity DTs since a slave-velocity jog began braking: the slave is
    /// at rest only by a DT that answers the braking command (see
    /// `Op::cycles`), not by one from before the jog got going.
    braking_dts: u32,
}

impl CansmcAxis {
    /// An axis for `cfg`, disabled, before any feedback.
    pub fn new(cfg: CansmcAxisConfig) -> Self {
        CansmcAxis {
            cfg,
            status: None,
            position: None,
            velocity: 0.0,
            demand: 0.0,
            demand_velocity: 0.0,
            motion: Motion::Hold,
            enable: false,
            halt: false,
            reset_pulse: false,
            op: None,
            next_id: 1,
            lost: None,
            disabled_by_loss: None,
            faulted: false,
            homed: false,
            gear_clipped: 0,
            braking_dts: 0,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &CansmcAxisConfig {
        &self.cfg
    }

    fn units(&self) -> Units {
        self.cfg.motion.units
    }

    /// User units/s to the slave's velocity unit (0.001 r/min).
    fn slave_velocity_of(&self, v: f64) -> i32 {
        let rpm_milli = v * self.cfg.motion.units.counts_per_unit
            / f64::from(self.cfg.drive.counts_per_rev.max(1))
            * 60_000.0;
        rpm_milli
            .round()
            .clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
    }

    /// The slave's velocity unit (0.001 r/min) to user units/s.
    fn user_velocity_of(&self, v: i32) -> f64 {
        self.units()
            .from_counts(f64::from(v) * f64::from(self.cfg.drive.counts_per_rev.max(1)) / 60_000.0)
    }

    fn actual(&self) -> f64 {
        self.position
            .map(|p| self.units().from_counts(f64::from(p)))
            .unwrap_or(self.demand)
    }

    /// Cycles the geared demand was limited by the velocity ceiling.
    pub fn gear_clipped(&self) -> u64 {
        self.gear_clipped
    }

    /// Whether the axis currently follows its gear source.
    pub fn is_geared(&self) -> bool {
        matches!(self.motion, Motion::Geared { .. })
    }

    /// Whether a set-point stream drives the axis.
    pub fn is_streamed(&self) -> bool {
        matches!(self.motion, Motion::Streamed { .. })
    }

    /// Hands the axis to a set-point stream whose player starts at `from`
    /// (user units): the axis must be enabled, at rest, running no
    /// command, and hold `from` (within a count: the player starts where
    /// the axis stands, so the stream never jumps).
    ///
    /// # Errors
    /// Why the axis cannot be streamed now.
    pub fn start_stream(&mut self, from: f64) -> Result<(), CommandError> {
        if self.is_streamed() {
            return Err(CommandError::Busy(
                "the axis is already in a set-point stream".into(),
            ));
        }
        self.check(&AxisCommand::Move {
            target: self.demand,
            relative: false,
            velocity: None,
            acceleration: None,
        })?;
        if self.op.is_some() || self.demand_velocity != 0.0 || self.motion != Motion::Hold {
            return Err(CommandError::Busy(
                "the axis is moving or busy: stop it or wait until it is at rest".into(),
            ));
        }
        let counts = |x: f64| i64::from(self.units().to_counts(x));
        if (counts(from) - counts(self.demand)).abs() > 1 {
            return Err(CommandError::Busy(format!(
                "the axis moved since the stream opened (it holds {:.4} {}, the stream starts at \
                 {from:.4})",
                self.demand, self.cfg.motion.unit
            )));
        }
        self.motion = Motion::Streamed { next: None };
        Ok(())
    }

    /// The stream's set-point for the coming cycle (user units, units/s):
    /// [`CansmcAxis::on_cycle`] sends it, inside the soft limits. Ignored
    /// unless the axis is streamed.
    pub fn stream_setpoint(&mut self, position: f64, velocity: f64) {
        if let Motion::Streamed { next } = &mut self.motion {
            *next = Some((position, velocity));
        }
    }

    /// The stream ended with the axis at rest: it holds the stream's last
    /// set-point (one given since the last cycle), else its demand.
    pub fn end_stream(&mut self) {
        if let Motion::Streamed { next } = self.motion {
            if let Some((p, _)) = next {
                self.demand = self.within_soft_limits(p, self.demand);
            }
            self.motion = Motion::Hold;
            self.demand_velocity = 0.0;
        }
    }

    /// `p` kept inside the soft limits, unless `previous` is already
    /// outside (then not further out).
    fn within_soft_limits(&self, p: f64, previous: f64) -> f64 {
        let mut p = p;
        if let Some(max) = self.cfg.motion.max_position {
            p = p.min(max.max(previous));
        }
        if let Some(min) = self.cfg.motion.min_position {
            p = p.max(min.min(previous));
        }
        p
    }

    /// The demand position in user units.
    pub fn demand(&self) -> f64 {
        self.demand
    }

    fn state(&self) -> Option<DriveState> {
        let s = self.status?;
        Some(if s.fault {
            DriveState::Fault
        } else if s.enabled {
            DriveState::OperationEnabled
        } else if s.ready {
            DriveState::SwitchOnDisabled
        } else {
            DriveState::NotReadyToSwitchOn
        })
    }

    /// What the axis is doing.
    pub fn activity(&self) -> Activity {
        match self.op.as_ref().map(|o| o.step) {
            Some(Step::Enabling | Step::Disabling | Step::Resetting) => Activity::Switching,
            Some(Step::Homing) => Activity::Homing,
            Some(Step::Moving) => Activity::Moving,
            Some(Step::Jogging) => Activity::Jogging,
            Some(Step::Stopping) => Activity::Stopping,
            None if self.is_geared() || self.is_streamed() => Activity::Moving,
            None => Activity::Idle,
        }
    }

    /// The id of the command in progress, if any.
    pub fn current_op(&self) -> Option<OpId> {
        self.op.as_ref().map(|o| o.id)
    }

    /// Whether the axis is in fault or its slave is lost (cheap: no
    /// snapshot).
    pub fn has_fault(&self) -> bool {
        self.lost.is_some()
            || self.status.is_some_and(|s| s.fault)
            || self.disabled_by_loss.is_some()
    }

    fn fault_text(&self) -> Option<(u16, String)> {
        if let Some(reason) = &self.lost {
            return Some((0, format!("slave lost: {reason}")));
        }
        if let Some(s) = self.status
            && s.fault
        {
            return Some(if s.following_error {
                (0x8611, "following error over limit (DTSW bit 5)".into())
            } else {
                (0, "drive fault (DTSW bit 2)".into())
            });
        }
        self.disabled_by_loss.as_ref().map(|reason| {
            (
                0,
                format!(
                    "disabled because the slave was lost ({reason}); it answers again: enable the axis"
                ),
            )
        })
    }

    /// The live state.
    pub fn snapshot(&self) -> AxisSnapshot {
        let position = self.actual();
        AxisSnapshot {
            signals: Default::default(),
            state: self.state(),
            // Without the cycle counter echo (bits 12-15): it changes with
            // every DT and says the telegram is fresh, not how the drive
            // is; with it every axis would change every cycle, at rest too.
            statusword: self
                .status
                .map(|s| {
                    StatusWord {
                        counter_echo: CycleCounter::new(0),
                        ..s
                    }
                    .to_bits()
                })
                .unwrap_or_default(),
            mode: if matches!(self.motion, Motion::Homing) {
                MODE_HOMING
            } else {
                MODE_CYCLIC_POSITION
            },
            activity: self.activity(),
            position,
            velocity: self.velocity,
            demand_position: self.demand,
            following_error: if self.position.is_some() {
                self.demand - position
            } else {
                0.0
            },
            homed: self.homed,
            node_lost: self.lost.clone(),
            fault: self.fault_text(),
        }
    }

    // ------------------------------------------------------------ commands

    fn check(&self, cmd: &AxisCommand) -> Result<(), CommandError> {
        if let Some(reason) = &self.lost
            && !matches!(cmd, AxisCommand::Stop | AxisCommand::QuickStop)
        {
            return Err(CommandError::DriveUnavailable(format!(
                "the slave is lost ({reason}): commands are refused until it answers again"
            )));
        }
        let Some(status) = self.status else {
            return Err(CommandError::DriveUnavailable(
                "no drive telegram from the slave yet (is the CANsmc master in P2?)".into(),
            ));
        };
        if self.is_streamed()
            && !matches!(
                cmd,
                AxisCommand::Stop | AxisCommand::QuickStop | AxisCommand::ResetFault
            )
        {
            return Err(CommandError::Busy(
                "the axis plays a set-point stream: end the stream or stop the axis first".into(),
            ));
        }
        crate::checks::motion_arguments(
            cmd,
            self.cfg.motion.max_velocity,
            self.cfg.motion.max_acceleration,
            &self.cfg.motion.unit,
        )?;
        let needs_enabled = |what: &str| {
            if status.fault {
                Err(CommandError::InFault(format!(
                    "the drive is in fault: reset it before {what}"
                )))
            } else if !status.enabled || !self.enable {
                Err(CommandError::NotEnabled(format!(
                    "the axis is not enabled: enable it before {what}"
                )))
            } else {
                Ok(())
            }
        };
        let not_geared = |what: &str| {
            if self.is_geared() {
                Err(CommandError::Busy(format!(
                    "the axis follows slave {}'s encoder: stop it before {what}",
                    self.cfg.drive.gear.map(|g| g.source).unwrap_or_default()
                )))
            } else {
                Ok(())
            }
        };
        match *cmd {
            AxisCommand::Move { .. } | AxisCommand::Jog { .. } => {
                let what = if matches!(cmd, AxisCommand::Move { .. }) {
                    "a move"
                } else {
                    "a jog"
                };
                needs_enabled(what)?;
                not_geared(what)?;
                if self.op.as_ref().is_some_and(|o| o.step == Step::Homing) {
                    return Err(CommandError::Busy(
                        "the axis is homing: stop it first".into(),
                    ));
                }
            }
            AxisCommand::Home => {
                needs_enabled("homing")?;
                not_geared("homing")?;
            }
            AxisCommand::Enable => {
                if status.fault {
                    return Err(CommandError::InFault(
                        "the drive is in fault: reset it before enabling".into(),
                    ));
                }
            }
            AxisCommand::Disable
            | AxisCommand::Stop
            | AxisCommand::QuickStop
            | AxisCommand::ResetFault => {}
            AxisCommand::SetTorque { .. } | AxisCommand::SetMode { .. } => {
                return Err(CommandError::WrongMode(
                    "a CANsmc axis has no modes of operation: it runs position set-points only"
                        .into(),
                ));
            }
        }
        Ok(())
    }

    fn check_limits(&self, target: f64) -> Result<(), CommandError> {
        crate::checks::soft_limits(
            target,
            self.cfg.motion.min_position,
            self.cfg.motion.max_position,
            &self.cfg.motion.unit,
        )
    }

    /// The deceleration a motion at `v` (from the demand position) needs
    /// to come to rest inside the soft limits: `a`, or more when `a` would
    /// carry it past the limit ahead (a jog near a limit brakes late, at
    /// its own acceleration; a move or stop taking over must not brake more
    /// gently). At most the maximum acceleration.
    fn braking_within_limits(&self, v: f64, a: f64) -> f64 {
        let room = if v > 0.0 {
            self.cfg.motion.max_position.map(|m| m - self.demand)
        } else if v < 0.0 {
            self.cfg.motion.min_position.map(|m| self.demand - m)
        } else {
            None
        };
        let ceiling = self.cfg.motion.max_acceleration.max(a);
        match room {
            // 1 % margin: the cycle's discretisation.
            Some(d) if d > 0.0 => a.max(1.01 * v * v / (2.0 * d)).min(ceiling),
            Some(_) => ceiling,
            None => a,
        }
    }

    /// The deceleration the running motion brakes with (0 at rest).
    fn motion_deceleration(&self) -> f64 {
        match &self.motion {
            Motion::Profile { profile, ratio, .. } => {
                profile.limits().deceleration() * ratio * ratio
            }
            Motion::Jog { acceleration, .. } => *acceleration,
            _ => 0.0,
        }
    }

    fn limits(&self, velocity: f64, acceleration: f64) -> Result<Limits, CommandError> {
        Limits::symmetric(velocity, acceleration).map_err(|e| CommandError::BadValue(e.to_string()))
    }

    fn finish(&mut self, outcome: Outcome, detail: String, out: &mut Vec<AxisEvent>) {
        if let Some(op) = self.op.take() {
            out.push(AxisEvent::Done {
                op: op.id,
                command: op.kind,
                outcome,
                detail,
            });
        }
    }

    fn begin(
        &mut self,
        kind: CommandKind,
        step: Step,
        target: f64,
        deadline: Option<Duration>,
        out: &mut Vec<AxisEvent>,
    ) -> OpId {
        let id = self.next_id;
        self.next_id += 1;
        if self.op.is_some() {
            self.finish(Outcome::Superseded, format!("superseded by {kind}"), out);
        }
        self.op = Some(Op {
            id,
            kind,
            step,
            target,
            deadline,
            deadman: None,
            cycles: 0,
        });
        out.push(AxisEvent::Accepted { op: id });
        id
    }

    /// Starts `cmd` at `now`.
    ///
    /// # Errors
    /// A typed refusal (limits, state, lost slave); nothing changes then.
    pub fn command(
        &mut self,
        cmd: AxisCommand,
        now: Duration,
        out: &mut Vec<AxisEvent>,
    ) -> Result<OpId, CommandError> {
        self.check(&cmd)?;
        if matches!(cmd, AxisCommand::Enable | AxisCommand::ResetFault)
            && self.disabled_by_loss.take().is_some()
            && !self.faulted
        {
            // The loss is acknowledged.
            out.push(AxisEvent::Fault {
                code: 0,
                text: String::new(),
            });
        }
        let state_deadline = Some(now + self.cfg.motion.state_timeout);
        match cmd {
            AxisCommand::Enable => {
                self.demand = self.actual();
                self.demand_velocity = 0.0;
                self.motion = Motion::Hold;
                self.enable = true;
                self.halt = false;
                Ok(self.begin(
                    CommandKind::Enable,
                    Step::Enabling,
                    0.0,
                    state_deadline,
                    out,
                ))
            }
            AxisCommand::Disable => {
                self.enable = false;
                self.motion = Motion::Hold;
                self.demand_velocity = 0.0;
                Ok(self.begin(
                    CommandKind::Disable,
                    Step::Disabling,
                    0.0,
                    state_deadline,
                    out,
                ))
            }
            AxisCommand::ResetFault => {
                if self.lost.is_none() && !self.status.is_some_and(|s| s.fault) {
                    // Nothing to reset: the axis stays as it is (an enabled
                    // axis stays enabled, a command in progress runs on).
                    let id = self.next_id;
                    self.next_id += 1;
                    out.push(AxisEvent::Accepted { op: id });
                    out.push(AxisEvent::Done {
                        op: id,
                        command: CommandKind::ResetFault,
                        outcome: Outcome::Completed,
                        detail: "no fault to reset".into(),
                    });
                    return Ok(id);
                }
                self.reset_pulse = true;
                self.enable = false;
                Ok(self.begin(
                    CommandKind::ResetFault,
                    Step::Resetting,
                    0.0,
                    state_deadline,
                    out,
                ))
            }
            AxisCommand::Home => {
                self.motion = Motion::Homing;
                self.homed = false;
                self.halt = false;
                Ok(self.begin(
                    CommandKind::Home,
                    Step::Homing,
                    0.0,
                    Some(now + self.cfg.motion.homing_timeout),
                    out,
                ))
            }
            AxisCommand::Move {
                target,
                relative,
                velocity,
                acceleration,
            } => {
                let base = match &self.op {
                    Some(op) if op.step == Step::Moving => op.target,
                    _ => self.demand,
                };
                let target = if relative { base + target } else { target };
                self.check_limits(target)?;
                let acceleration = self.braking_within_limits(
                    self.demand_velocity,
                    acceleration.unwrap_or(self.cfg.motion.default_acceleration),
                );
                let limits = self.limits(
                    velocity.unwrap_or(self.cfg.motion.default_velocity),
                    acceleration,
                )?;
                let profile =
                    TrapezoidProfile::new(self.demand, self.demand_velocity, target, limits)
                        .map_err(|e| CommandError::BadValue(e.to_string()))?;
                let total = Duration::from_secs_f64(profile.duration().min(1e6));
                self.motion = Motion::Profile {
                    profile,
                    ratio: 1.0,
                    elapsed: Duration::ZERO,
                };
                self.halt = false;
                Ok(self.begin(
                    CommandKind::Move,
                    Step::Moving,
                    target,
                    Some(now + total + self.cfg.motion.settle_timeout),
                    out,
                ))
            }
            AxisCommand::Jog {
                velocity,
                acceleration,
            } => {
                let mut acceleration = acceleration.unwrap_or(self.cfg.motion.default_acceleration);
                if velocity == 0.0 {
                    // A jog at 0 is a stop: at least the stop deceleration.
                    acceleration = acceleration.max(self.cfg.motion.stop_deceleration);
                }
                let deadman = Some(now + self.cfg.motion.jog_deadman);
                let motion = match self.cfg.drive.jog_mode {
                    JogMode::Interpolated => Motion::Jog {
                        target: velocity,
                        acceleration,
                    },
                    // Towards a soft limit it cannot stop before: keep
                    // braking (a renewal must not restart a jog the limit
                    // stopped), or stay at rest.
                    JogMode::SlaveVelocity if self.slave_jog_blocked(velocity) => {
                        match self.motion {
                            Motion::SlaveVelocity { stage, .. }
                                if stage != VelocityStage::Running =>
                            {
                                self.motion.clone()
                            }
                            Motion::SlaveVelocity { .. } => Motion::SlaveVelocity {
                                target: 0.0,
                                stage: VelocityStage::Braking,
                            },
                            _ => Motion::Hold,
                        }
                    }
                    JogMode::SlaveVelocity => Motion::SlaveVelocity {
                        target: velocity,
                        stage: if velocity == 0.0 {
                            VelocityStage::Braking
                        } else {
                            VelocityStage::Running
                        },
                    },
                };
                // A repeated jog continues the motion (the ramp goes on
                // from the current velocity) as a new command: it is
                // acknowledged like any other, and the previous jog ends
                // superseded. (A renewal without its own acknowledgement
                // would leave a caller without `wait` waiting for the end
                // of the jog, so it could not repeat the jog in time.)
                self.motion = motion;
                self.halt = false;
                let id = self.begin(CommandKind::Jog, Step::Jogging, 0.0, None, out);
                if let Some(op) = &mut self.op {
                    op.deadman = deadman;
                }
                Ok(id)
            }
            AxisCommand::Stop | AxisCommand::QuickStop => {
                let quick = matches!(cmd, AxisCommand::QuickStop);
                let kind = cmd.kind();
                let id = self.stop(quick, kind, now, out);
                Ok(id)
            }
            AxisCommand::SetTorque { .. } | AxisCommand::SetMode { .. } => Err(
                CommandError::WrongMode("a CANsmc axis has no modes of operation".into()),
            ),
        }
    }

    /// Starts a stop ramp (or ends at once when at rest).
    fn stop(
        &mut self,
        quick: bool,
        kind: CommandKind,
        now: Duration,
        out: &mut Vec<AxisEvent>,
    ) -> OpId {
        let wanted = if quick {
            self.cfg.motion.quick_stop_deceleration
        } else {
            self.cfg.motion.stop_deceleration
        };
        let decel = self
            .braking_within_limits(self.demand_velocity, wanted.max(self.motion_deceleration()));
        if self.op.is_some() {
            self.finish(Outcome::Stopped, format!("stopped by {kind}"), out);
        }
        let id = self.begin(kind, Step::Stopping, 0.0, None, out);
        match self.motion {
            Motion::SlaveVelocity { .. } => {
                // The slave ramps down in its velocity mode; the position
                // is read back at rest.
                self.motion = Motion::SlaveVelocity {
                    target: 0.0,
                    stage: VelocityStage::Braking,
                };
            }
            Motion::Homing => {
                // The slave plans its homing run: halt it, then hold where
                // it stands.
                self.halt = true;
                self.motion = Motion::Hold;
                self.demand = self.actual();
                self.demand_velocity = 0.0;
            }
            _ => {
                let v = self.demand_velocity;
                let stop_at = self.demand + v * v.abs() / (2.0 * decel);
                let profile = Limits::symmetric(self.cfg.motion.max_velocity.max(v.abs()), decel)
                    .ok()
                    .and_then(|l| TrapezoidProfile::new(self.demand, v, stop_at, l).ok());
                self.motion = match profile {
                    Some(profile) if v != 0.0 => Motion::Profile {
                        profile,
                        ratio: 1.0,
                        elapsed: Duration::ZERO,
                    },
                    _ => Motion::Hold,
                };
            }
        }
        let bound = self.cfg.motion.settle_timeout
            + Duration::from_secs_f64((self.demand_velocity.abs() / decel).min(1e6));
        if let Some(op) = &mut self.op {
            op.deadline = Some(now + bound);
        }
        id
    }

    /// Starts one axis of a coordinated move: `profile` in user units (from
    /// this axis's demand position, at rest), stretched to wall time by
    /// `ratio`. All axes of the move start at the same cycle.
    ///
    /// # Errors
    /// As [`CansmcAxis::command`]; also when the axis is moving.
    pub fn start_coordinated(
        &mut self,
        profile: TrapezoidProfile,
        ratio: f64,
        now: Duration,
        out: &mut Vec<AxisEvent>,
    ) -> Result<OpId, CommandError> {
        let target = profile.target();
        self.check_coordinated(target)?;
        let duration = if ratio > 0.0 {
            profile.duration() / ratio
        } else {
            0.0
        };
        self.motion = Motion::Profile {
            profile,
            ratio,
            elapsed: Duration::ZERO,
        };
        self.halt = false;
        Ok(self.begin(
            CommandKind::Move,
            Step::Moving,
            target,
            Some(now + Duration::from_secs_f64(duration.min(1e6)) + self.cfg.motion.settle_timeout),
            out,
        ))
    }

    /// Whether a coordinated move to `target` could start now.
    ///
    /// # Errors
    /// As [`CansmcAxis::command`]; also when the axis is moving.
    pub fn check_coordinated(&self, target: f64) -> Result<(), CommandError> {
        self.check(&AxisCommand::Move {
            target,
            relative: false,
            velocity: None,
            acceleration: None,
        })?;
        self.check_limits(target)?;
        if self.demand_velocity != 0.0 || self.op.is_some() {
            return Err(CommandError::Busy(
                "the axis is moving: stop it before a coordinated move".into(),
            ));
        }
        Ok(())
    }

    // ---------------------------------------------------------------- input

    /// The master declared the slave lost.
    pub fn on_slave_lost(&mut self, reason: &str, out: &mut Vec<AxisEvent>) {
        if self.lost.is_some() {
            return;
        }
        self.lost = Some(reason.to_string());
        if self.enable || self.op.is_some() {
            self.disabled_by_loss = Some(reason.to_string());
        }
        // Nothing reaches the drive now: drop the enable so that a
        // returning slave does not resume a stale motion.
        self.enable = false;
        self.motion = Motion::Hold;
        self.demand_velocity = 0.0;
        self.finish(Outcome::Fault, format!("slave lost: {reason}"), out);
        out.push(AxisEvent::Fault {
            code: 0,
            text: format!("slave lost: {reason}"),
        });
    }

    /// The slave answers again.
    pub fn on_slave_back(&mut self, out: &mut Vec<AxisEvent>) {
        if self.lost.take().is_some() {
            self.demand = self.actual();
            if !self.faulted {
                // Still disabled by the loss: say so (the loss's fault
                // text is replaced, not cleared).
                let (code, text) = self.fault_text().unwrap_or_default();
                out.push(AxisEvent::Fault { code, text });
            }
        }
    }

    /// One cycle: `input` is the slave's latest answer at the start of the
    /// cycle (`now`); returns the MDT content of this cycle.
    pub fn on_cycle(
        &mut self,
        now: Duration,
        input: CycleInput,
        out: &mut Vec<AxisEvent>,
    ) -> CycleOutput {
        let dt = self.cfg.drive.cycle_time.as_secs_f64();
        if let Some(p) = input.position {
            if let Some(prev) = self.position {
                self.velocity = self.units().from_counts(f64::from(p) - f64::from(prev)) / dt;
            }
            self.position = Some(p);
        }
        if let Some(v) = input.velocity {
            // Velocity mode: no position feedback; dead-reckon it.
            self.velocity = self.user_velocity_of(v);
            if let Some(p) = self.position {
                let moved = (self.velocity * dt * self.cfg.motion.units.counts_per_unit).round();
                self.position = Some(
                    (f64::from(p) + moved).clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32,
                );
            }
        }
        if let (Some(c), Motion::SlaveVelocity { stage, .. }) = (input.encoder, &self.motion)
            && *stage == VelocityStage::ReadingPosition
        {
            // The slave's own count, read at rest: position control resumes
            // exactly where the motor stands.
            self.position = Some(c);
            self.velocity = 0.0;
            self.demand = self.actual();
            self.demand_velocity = 0.0;
            self.motion = Motion::Hold;
        }
        if input.status.is_some() {
            self.status = input.status;
        }
        self.track_status(out);
        self.advance_op(now, input.status.is_some(), out);
        if matches!(
            self.motion,
            Motion::SlaveVelocity {
                stage: VelocityStage::Braking,
                ..
            }
        ) {
            if input.velocity.is_some() {
                self.braking_dts = self.braking_dts.saturating_add(1);
            }
        } else {
            self.braking_dts = 0;
        }
        self.advance_motion(input.source_count, dt);
        let control = ControlWord {
            enable: self.enable,
            halt: self.halt,
            fault_reset: std::mem::take(&mut self.reset_pulse),
            ..ControlWord::default()
        };
        let command = match self.motion {
            Motion::Homing => Command::Homing {
                method: self.cfg.drive.homing_method,
            },
            Motion::SlaveVelocity {
                target,
                stage: VelocityStage::Running,
            } => Command::Velocity(self.slave_velocity_of(target)),
            Motion::SlaveVelocity {
                stage: VelocityStage::Braking,
                ..
            } => Command::Velocity(0),
            Motion::SlaveVelocity {
                stage: VelocityStage::ReadingPosition,
                ..
            } => Command::Encoder,
            _ => Command::Position(self.units().to_counts(self.demand)),
        };
        CycleOutput { control, command }
    }

    fn track_status(&mut self, out: &mut Vec<AxisEvent>) {
        let Some(s) = self.status else {
            return;
        };
        if s.homed && !self.homed && !matches!(self.motion, Motion::Homing) {
            self.homed = true;
        }
        if s.fault && !self.faulted {
            self.faulted = true;
            self.enable = false;
            self.halt = false;
            self.motion = Motion::Hold;
            self.demand_velocity = 0.0;
            let (code, text) = self.fault_text().unwrap_or_default();
            if self.op.as_ref().is_some_and(|o| o.step != Step::Resetting) {
                self.finish(Outcome::Fault, format!("drive fault: {text}"), out);
            }
            out.push(AxisEvent::Fault { code, text });
        } else if !s.fault && self.faulted {
            self.faulted = false;
            if self.lost.is_none() && self.disabled_by_loss.is_none() {
                out.push(AxisEvent::Fault {
                    code: 0,
                    text: String::new(),
                });
            }
        }
        // Not enabled (or in fault): the set-point tracks the drive, so
        // that enabling never jumps.
        if !s.enabled || s.fault {
            self.demand = self.actual();
            self.demand_velocity = 0.0;
            if !matches!(self.motion, Motion::Homing) {
                self.motion = Motion::Hold;
            }
        }
    }

    fn at_rest(&self) -> bool {
        self.demand_velocity == 0.0
            && self.velocity.abs() <= self.cfg.motion.in_position_window * 100.0
    }

    fn advance_op(&mut self, now: Duration, fresh: bool, out: &mut Vec<AxisEvent>) {
        let Some(op) = self.op.as_mut() else {
            return;
        };
        if fresh {
            op.cycles = op.cycles.saturating_add(1);
        }
        let op = op.clone();
        let Some(s) = self.status else {
            return;
        };
        let timed_out = op.deadline.is_some_and(|d| now >= d);
        // A status that can show the command's effect (see `Op::cycles`):
        // an enable right after the enable bit was dropped for a cycle
        // would otherwise complete on the slave's state before the drop.
        let effective = op.cycles > 2;
        match op.step {
            Step::Enabling if effective && s.enabled => {
                self.finish(Outcome::Completed, "enabled".into(), out);
                if self.cfg.drive.gear.is_some() {
                    self.engage_gear();
                }
            }
            Step::Disabling if effective && !s.enabled => {
                self.finish(Outcome::Completed, "disabled".into(), out);
            }
            Step::Resetting if !s.fault && self.lost.is_none() => {
                self.finish(Outcome::Completed, "fault reset".into(), out);
            }
            Step::Homing if effective && s.homed && s.target_reached => {
                self.homed = true;
                self.motion = Motion::Hold;
                self.demand = self.actual();
                self.demand_velocity = 0.0;
                self.finish(Outcome::Completed, "homing attained".into(), out);
            }
            Step::Moving => {
                let planned_done = !matches!(self.motion, Motion::Profile { .. });
                if planned_done
                    && (self.actual() - op.target).abs() <= self.cfg.motion.in_position_window
                {
                    self.finish(Outcome::Completed, "target reached".into(), out);
                } else if timed_out {
                    self.finish(
                        Outcome::Timeout,
                        format!(
                            "not in position: {:.4} {} from the target after the planned time",
                            op.target - self.actual(),
                            self.cfg.motion.unit
                        ),
                        out,
                    );
                }
            }
            Step::Jogging => {
                let deadman_expired = op.deadman.is_some_and(|d| now >= d);
                if deadman_expired {
                    let stop_deceleration = self.cfg.motion.stop_deceleration;
                    let braking = match &mut self.motion {
                        Motion::Jog {
                            target,
                            acceleration,
                        } if *target != 0.0 => {
                            // The dead-man is a stop: at least the stop
                            // deceleration.
                            *target = 0.0;
                            *acceleration = acceleration.max(stop_deceleration);
                            true
                        }
                        Motion::SlaveVelocity { target, stage } if *target != 0.0 => {
                            *target = 0.0;
                            *stage = VelocityStage::Braking;
                            true
                        }
                        _ => false,
                    };
                    if braking && let Some(op) = &mut self.op {
                        op.deadline = Some(now + self.cfg.motion.settle_timeout);
                    }
                }
                let requested_zero =
                    matches!(self.motion, Motion::Jog { target, .. } if target == 0.0);
                let slave_at_rest = matches!(self.motion, Motion::Hold)
                    && self.cfg.drive.jog_mode == JogMode::SlaveVelocity;
                if (requested_zero && self.demand_velocity == 0.0) || slave_at_rest {
                    self.motion = Motion::Hold;
                    if deadman_expired {
                        self.finish(
                            Outcome::Stopped,
                            format!(
                                "dead-man: no jog command within {} ms",
                                self.cfg.motion.jog_deadman.as_millis()
                            ),
                            out,
                        );
                    } else {
                        self.finish(Outcome::Completed, "at rest".into(), out);
                    }
                }
            }
            Step::Stopping => {
                // At rest by a status that answers the stop: a motion
                // commanded just before (a homing, a jog) may not have
                // reached the slave yet.
                if (effective || self.lost.is_some())
                    && matches!(self.motion, Motion::Hold)
                    && self.at_rest()
                {
                    if self.halt {
                        // The slave braked on its own ramp (a halted
                        // homing): hold where it came to rest, or releasing
                        // the halt would send it back to where it was when
                        // the stop began.
                        self.demand = self.actual();
                        self.demand_velocity = 0.0;
                    }
                    self.halt = false;
                    self.finish(Outcome::Completed, "at rest".into(), out);
                } else if timed_out {
                    self.finish(Outcome::Timeout, "not at rest in time".into(), out);
                }
            }
            _ if timed_out => {
                let what = match op.step {
                    Step::Enabling => "the drive did not report enabled",
                    Step::Disabling => "the drive did not report disabled",
                    Step::Resetting => "the fault did not clear",
                    Step::Homing => "homing did not finish",
                    _ => "no progress",
                };
                if op.step == Step::Homing {
                    self.motion = Motion::Hold;
                    self.demand = self.actual();
                }
                let bound = match op.step {
                    Step::Homing => self.cfg.motion.homing_timeout,
                    _ => self.cfg.motion.state_timeout,
                };
                self.finish(
                    Outcome::Timeout,
                    format!("{what} within {} ms", bound.as_millis()),
                    out,
                );
            }
            _ => {}
        }
    }

    /// Whether a slave-velocity jog at `v` would run into a soft limit it
    /// cannot stop before.
    fn slave_jog_blocked(&self, v: f64) -> bool {
        let p = self.actual();
        let u = if v.signum() == self.velocity.signum() {
            self.velocity.abs().max(v.abs())
        } else {
            v.abs()
        };
        let stopping = slave_stopping_distance(u, &self.cfg);
        (v > 0.0
            && self
                .cfg
                .motion
                .max_position
                .is_some_and(|m| p + stopping >= m))
            || (v < 0.0
                && self
                    .cfg
                    .motion
                    .min_position
                    .is_some_and(|m| p - stopping <= m))
    }

    fn engage_gear(&mut self) {
        // The offset is taken from the first source count, so engaging
        // never jumps.
        self.motion = Motion::Geared { offset: None };
    }

    fn advance_motion(&mut self, source: Option<i32>, dt: f64) {
        let previous = self.demand;
        let actual = self.actual();
        match &mut self.motion {
            Motion::Hold | Motion::Homing => {
                self.demand_velocity = 0.0;
            }
            Motion::Profile {
                profile,
                ratio,
                elapsed,
            } => {
                *elapsed += self.cfg.drive.cycle_time;
                let t = elapsed.as_secs_f64() * *ratio;
                let (p, v, _) = profile.sample(t);
                self.demand = p;
                self.demand_velocity = v * *ratio;
                if t >= profile.duration() {
                    self.demand = profile.target();
                    self.demand_velocity = 0.0;
                    self.motion = Motion::Hold;
                }
            }
            Motion::Jog {
                target,
                acceleration,
            } => {
                // Soft limits: aim for rest in time to stop at the limit.
                let mut goal = *target;
                let a = *acceleration;
                let v = self.demand_velocity;
                let stopping = v * v.abs() / (2.0 * a);
                if (v > 0.0
                    && self
                        .cfg
                        .motion
                        .max_position
                        .is_some_and(|m| self.demand + stopping >= m))
                    || (v < 0.0
                        && self
                            .cfg
                            .motion
                            .min_position
                            .is_some_and(|m| self.demand + stopping <= m))
                {
                    goal = 0.0;
                }
                let dv = (goal - v).clamp(-a * dt, a * dt);
                let v_new = v + dv;
                self.demand += (v + v_new) / 2.0 * dt;
                self.demand_velocity = if v_new.abs() < 1e-9 { 0.0 } else { v_new };
                if let Some(max) = self.cfg.motion.max_position {
                    self.demand = self.demand.min(max.max(previous));
                }
                if let Some(min) = self.cfg.motion.min_position {
                    self.demand = self.demand.max(min.min(previous));
                }
            }
            Motion::SlaveVelocity { target, stage } => {
                // The demand shows where the motor is (the slave plans).
                self.demand = actual;
                self.demand_velocity = match stage {
                    VelocityStage::Running => *target,
                    _ => 0.0,
                };
                match stage {
                    VelocityStage::Running => {
                        // Soft limits: brake in time (at the axis's default
                        // deceleration; the slave's own ramp must not be
                        // slower).
                        let v = self.velocity;
                        let stopping = slave_stopping_distance(v, &self.cfg);
                        let p = self.demand;
                        if (v > 0.0
                            && self
                                .cfg
                                .motion
                                .max_position
                                .is_some_and(|m| p + stopping >= m))
                            || (v < 0.0
                                && self
                                    .cfg
                                    .motion
                                    .min_position
                                    .is_some_and(|m| p + stopping <= m))
                        {
                            *target = 0.0;
                            *stage = VelocityStage::Braking;
                        }
                    }
                    VelocityStage::Braking => {
                        if self.braking_dts > 2
                            && self.velocity.abs() <= self.cfg.motion.in_position_window
                        {
                            *stage = VelocityStage::ReadingPosition;
                        }
                    }
                    VelocityStage::ReadingPosition => {}
                }
            }
            Motion::Streamed { next } => {
                let Some((p, v)) = next.take() else {
                    // No set-point this cycle: hold.
                    self.demand_velocity = 0.0;
                    return;
                };
                self.demand = self.within_soft_limits(p, previous);
                self.demand_velocity = v;
            }
            Motion::Geared { offset } => {
                let Some(count) = source else {
                    return;
                };
                let ratio = self.cfg.drive.gear.map_or(1.0, |g| g.ratio);
                let demand_counts = self.cfg.motion.units.counts_per_unit * self.demand;
                let offset = *offset.get_or_insert(demand_counts - ratio * f64::from(count));
                let wanted = self
                    .cfg
                    .motion
                    .units
                    .from_counts(offset + ratio * f64::from(count));
                let step = self.cfg.motion.max_velocity * dt;
                let clipped = (wanted - previous).clamp(-step, step);
                if clipped != wanted - previous {
                    self.gear_clipped += 1;
                }
                self.demand = previous + clipped;
                self.demand_velocity = clipped / dt;
            }
        }
    }
}

/// Signed distance a slave-velocity jog at `v` (units/s) travels before it
/// is at rest: its ramp at the default deceleration plus the pipeline — the
/// brake command reaches the slave one cycle later and the velocity the
/// axis knows is a cycle old.
fn slave_stopping_distance(v: f64, cfg: &CansmcAxisConfig) -> f64 {
    let lag = 3.0 * cfg.drive.cycle_time.as_secs_f64();
    v * v.abs() / (2.0 * cfg.motion.default_acceleration) + v * lag
}

#[cfg(test)]
mod tests;
