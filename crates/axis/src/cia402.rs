//! [`Cia402Axis`]: a CiA 402 servo drive as an axis, sans-IO.
//!
//! Inputs: the drive's process data ([`Cia402Axis::on_feedback`]), SYNC
//! ([`Cia402Axis::on_sync`], or split in two where another thread sends
//! the SYNC: [`Cia402Axis::cyclic_plan`] sampled there, each
//! [`CyclicSample`] handed back by [`Cia402Axis::on_cyclic_sample`]), time
//! ([`Cia402Axis::on_tick`] at
//! [`Cia402Axis::next_deadline`]), the outcome of SDO writes it asked for
//! ([`Cia402Axis::on_sdo_done`]), EMCY codes and node loss. Outputs
//! ([`Output`]): the process image to send as RPDOs, SDO writes, events.
//!
//! How each command runs:
//!
//! | command | profile position axis | cyclic (CSP) axis |
//! |---|---|---|
//! | enable / disable / reset fault | [`StateMachineDriver`] walk | the same; enable first sets mode 8 and target = actual position so the drive does not jump |
//! | move | SDO 0x6081/0x6083/0x6084 when they changed; mode 1; target + new set-point (bit 4) with change immediately (bit 5); accepted on set-point acknowledge (bit 12), bit 4 cleared; done on target reached (bit 10) | a trapezoid from the current demand (position and velocity) to the target, sampled every SYNC; done when the profile ended and the actual position is within the in-position window |
//! | jog | mode 3 (profile velocity), target velocity; the drive's soft limits (0x607D, written at boot) bound it | a trapezoid towards the soft limit at the jog speed |
//! | stop (also the jog dead-man) | halt (bit 8) until the next motion command, and 0x6084 raised to the stop deceleration by SDO right after it; done at standstill | a trapezoid to the stopping point at the stop deceleration |
//! | quick stop | controlword quick stop, and 0x6084 raised to the quick stop deceleration; done when the drive left operation enabled and stands still | the same |
//! | home | mode 6, homing start (bit 4); done on homing attained + target reached, failed on homing error; back to the position mode | the same, then demand = actual position, mode 8 |
//!
//! The other modes ([`DriveMode`]): cyclic synchronous velocity runs jogs
//! and stops as CSP does, the trajectory's velocity sent in 0x60FF every
//! SYNC (its stop ramps the velocity to 0 at the stop deceleration);
//! the torque modes (CST, profile torque) take [`AxisCommand::SetTorque`]
//! in 0x6071 (profile torque ramps it at 0x6087, written at boot), stop by
//! halt on 0x6084 as profile position does, and stop themselves when the
//! velocity exceeds the axis's maximum. [`AxisCommand::SetMode`] changes
//! the mode at rest only.
//!
//! Stops brake at least at the configured stop deceleration, more when the
//! interrupted motion brakes harder. A profile axis brakes on the drive's
//! own ramp: CiA 402 halts on 0x6084 with the default halt option code
//! (0x605D = 1); rather than re-configure 0x605D/0x6085 at boot (objects a
//! drive may lack, and then one ramp for halt and quick stop), the halt
//! goes out at once and 0x6084 follows by SDO: the drive brakes at the
//! motion's deceleration for one SDO round trip, then at the stop's.
//!
//! A motion command (move, jog, home) ends at the first statusword that
//! shows the drive out of operation enabled, naming the state; a motion
//! command is refused while a disable runs.
//!
//! Completion checks look only at process data that left the drive after
//! it saw the command: the first statusword after each new process image
//! is skipped (it may have been in flight already).

use std::time::Duration;

use cangate_canopen::ObjectAddress;
use cangate_canopen::cia402::{
    Controlword, DriveState, DriverStep, HomingStatus, ModeOfOperation, StateMachineDriver,
    Statusword, objects as obj, on_axis,
};
use cangate_motion::{Limits, TrapezoidProfile};

use crate::signals::{DriveSignals, LimitSwitch, Supervision, TouchProbeTracker};
use crate::{
    Activity, AxisCommand, AxisEvent, CommandError, CommandKind, DriveMode, MotionSpec, OpId,
    Outcome, PositionMode, TorqueSpec, Units,
};

/// The configuration of one CiA 402 axis: what every axis has and its
/// position mode (see [`crate::Cia402Drive::controller`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Cia402Config {
    /// Units, limits, defaults, stops, time bounds.
    pub motion: MotionSpec,
    /// The mode of operation the axis starts in.
    pub mode: DriveMode,
    /// Torque bounds (the torque modes).
    pub torque: TorqueSpec,
    /// Following error window and time-out, max torque (boot writes).
    pub supervision: Supervision,
    /// Which axis of its drive node this is (0..=7): every profile object
    /// the axis writes by SDO is that axis's, index + 0x800 × `drive_axis`
    /// ([`cangate_canopen::cia402::profile_index`]).
    pub drive_axis: u8,
}

impl Cia402Config {
    /// A configuration with the given scale and defaults suitable for the
    /// simulated drives (tests, demo).
    pub fn example(counts_per_unit: f64, position_mode: PositionMode) -> Self {
        Cia402Config {
            motion: MotionSpec::example(counts_per_unit, 500.0),
            mode: DriveMode::of_position_mode(position_mode),
            torque: TorqueSpec::default(),
            supervision: Supervision::default(),
            drive_axis: 0,
        }
    }

    /// As [`Cia402Config::example`], in `mode`, with the target torque in
    /// the process data.
    pub fn example_in(counts_per_unit: f64, mode: DriveMode) -> Self {
        Cia402Config {
            motion: MotionSpec::example(counts_per_unit, 500.0),
            mode,
            torque: TorqueSpec {
                in_process_data: true,
                ..TorqueSpec::default()
            },
            supervision: Supervision::default(),
            drive_axis: 0,
        }
    }

    /// How moves run in the mode the axis starts in.
    pub fn position_mode(&self) -> PositionMode {
        self.mode.position_mode()
    }
}

/// The process data the gateway sends to the drive (RPDOs): controlword,
/// mode of operation, target position, target velocity.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ProcessImage {
    /// 0x6040.
    pub controlword: u16,
    /// 0x6060.
    pub mode: i8,
    /// 0x607A (counts).
    pub target_position: i32,
    /// 0x60FF (counts/s).
    pub target_velocity: i32,
    /// 0x6071 (per mille of the rated torque).
    pub target_torque: i16,
}

/// Process data from the drive; `None` fields were not in this update.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Feedback {
    /// 0x6041.
    pub statusword: Option<u16>,
    /// 0x6064 (counts).
    pub position: Option<i32>,
    /// 0x606C (counts/s).
    pub velocity: Option<i32>,
    /// 0x6061.
    pub mode_display: Option<i8>,
    /// 0x60F4 (counts).
    pub following_error: Option<i32>,
    /// 0x6077 (per mille of rated torque).
    pub torque: Option<i16>,
    /// 0x60FD.
    pub digital_inputs: Option<u32>,
    /// 0x60B9.
    pub touch_probe_status: Option<u16>,
    /// 0x60BA (counts).
    pub touch_probe_positive: Option<i32>,
    /// 0x60BB (counts).
    pub touch_probe_negative: Option<i32>,
}

/// What the axis asks its runtime to do.
#[derive(Debug, Clone, PartialEq)]
pub enum Output {
    /// Send the process image (all RPDOs, the one with the target values
    /// before the one with the controlword).
    Image(ProcessImage),
    /// Write these objects by SDO in order, then call
    /// [`Cia402Axis::on_sdo_done`].
    SdoWrites(Vec<(ObjectAddress, Vec<u8>)>),
    /// Report this.
    Event(AxisEvent),
}

/// The live state of an axis in user units.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisSnapshot {
    /// Drive state; `None` before the first statusword.
    pub state: Option<DriveState>,
    /// Raw statusword.
    pub statusword: u16,
    /// Mode displayed (0 unknown).
    pub mode: i8,
    /// What the axis is doing.
    pub activity: Activity,
    /// Actual position.
    pub position: f64,
    /// Actual velocity.
    pub velocity: f64,
    /// Demand (cyclic) or latest target (profile).
    pub demand_position: f64,
    /// Demand − actual.
    pub following_error: f64,
    /// Homed since switched on.
    pub homed: bool,
    /// Why the node is lost, if it is.
    pub node_lost: Option<String>,
    /// Active fault.
    pub fault: Option<(u16, String)>,
    /// Torque, following error, digital inputs, touch probe status, as the
    /// drive's process data carries them.
    pub signals: DriveSignals,
}

/// Where a command stands.
#[derive(Debug)]
enum Step {
    /// Walking the state machine.
    Switch(StateMachineDriver),
    /// Bringing the drive to rest in its current mode (a cyclic stop
    /// ramp, or halt) before switching it to this mode: a drive never
    /// changes mode while it moves, so no mode's own ramp (homing's is
    /// slow) takes over a fast motion.
    SettleFor(ModeOfOperation),
    /// Waiting for SDO writes (profile parameters) to finish.
    AwaitSdo,
    /// Waiting for the mode display to show the mode.
    AwaitMode(ModeOfOperation),
    /// Profile position: new set-point sent, waiting for the acknowledge.
    AwaitAck,
    /// Profile position: moving to the target.
    ProfileMoving,
    /// Cyclic: following the trajectory.
    CyclicMoving,
    /// Homing started, waiting for attained/error.
    Homing,
    /// Homing attained; switching back to the position mode.
    HomingReturn,
    /// Profile velocity jog running.
    Jogging,
    /// Decelerating (halt, quick stop, cyclic stop ramp).
    Stopping,
    /// A torque command runs (the velocity guarded).
    Torque,
}

#[derive(Debug)]
struct Op {
    id: OpId,
    kind: CommandKind,
    step: Step,
    /// The command as given (for the steps after preparation).
    command: AxisCommand,
    /// Target (user units) of a move.
    target: f64,
    /// When the step times out, once the drive has been heard from after
    /// it ([`LATE_FEEDBACK`] statuswords): a deadline the host itself was
    /// late for (a loaded machine) does not fail a drive that is on time.
    deadline: Option<Duration>,
    /// Statuswords received since `deadline` passed.
    late_feedback: u32,
    /// `deadline` has passed (its grace runs).
    overdue: bool,
    /// A cyclic trajectory ended: the deadline is the settle time.
    settling: bool,
    /// Accepted has been reported.
    accepted: bool,
    /// Why a guard stopped the command (the torque command's velocity
    /// guard).
    guard: Option<String>,
}

impl Op {
    fn new(id: OpId, command: AxisCommand, step: Step) -> Op {
        Op {
            id,
            kind: command.kind(),
            step,
            command,
            target: 0.0,
            deadline: None,
            late_feedback: 0,
            overdue: false,
            settling: false,
            accepted: false,
            guard: None,
        }
    }

    /// Sets (or clears) the step's deadline.
    fn arm(&mut self, deadline: Option<Duration>) {
        self.deadline = deadline;
        self.late_feedback = 0;
        self.overdue = false;
    }
}

/// Profile velocity, acceleration and deceleration in drive counts (0x6081,
/// 0x6083, 0x6084).
type ProfileCounts = (u32, u32, u32);

/// Statuswords that must arrive after a step's deadline before the step
/// times out: the drive's own word that it is late.
const LATE_FEEDBACK: u32 = 3;

/// A cyclic trajectory: a trapezoid, optionally stretched in time (one axis
/// of a coordinated move).
#[derive(Debug, Clone, PartialEq)]
struct Trajectory {
    profile: TrapezoidProfile,
    /// Profile time per wall time (≤ 1; 1 for a single-axis move).
    ratio: f64,
    /// The time of the state it starts from (the latest SYNC sample), or
    /// `None` to start at the next SYNC.
    start: Option<Duration>,
}

impl Trajectory {
    fn duration(&self) -> f64 {
        if self.ratio > 0.0 {
            self.profile.duration() / self.ratio
        } else {
            0.0
        }
    }

    fn sample(&self, t: f64) -> (f64, f64) {
        let (p, v, _) = self.profile.sample(t * self.ratio);
        (p, v * self.ratio)
    }

    /// The deceleration this trajectory runs with (wall time).
    fn deceleration(&self) -> f64 {
        self.profile.limits().deceleration() * self.ratio * self.ratio
    }

    /// The ramp from position `p` at velocity `v` to rest at `decel`,
    /// starting at `start`; `None` at standstill.
    fn stop_ramp(p: f64, v: f64, decel: f64, start: Option<Duration>) -> Option<Trajectory> {
        let decel = decel.max(f64::MIN_POSITIVE);
        let stop_at = p + v * v.abs() / (2.0 * decel);
        Limits::symmetric(v.abs().max(1e-9), decel)
            .ok()
            .and_then(|l| TrapezoidProfile::new(p, v, stop_at, l).ok())
            .map(|profile| Trajectory {
                profile,
                ratio: 1.0,
                start,
            })
    }
}

/// The deceleration of a stop of `trajectory`: `configured`, or the
/// trajectory's own when that brakes harder.
fn stop_deceleration(configured: f64, trajectory: Option<&Trajectory>) -> f64 {
    trajectory.map_or(configured, |t| configured.max(t.deceleration()))
}

/// How long after a cyclic jog's dead-man deadline the axis stops the jog
/// itself when no SYNC sample has stopped it (the SYNC is not running).
/// Normally the first SYNC after the deadline stops it
/// ([`CyclicPlan::sample`]), whatever the thread that runs the axis does.
const DEADMAN_GRACE: Duration = Duration::from_millis(50);

/// The set-points a cyclic (CSP) axis sends with every SYNC, as a value:
/// whoever sends the SYNC samples it right there ([`CyclicPlan::sample`]),
/// so the set-point leaves with its SYNC without a hand-over to the thread
/// that runs the axis, and hands each [`CyclicSample`] back to the axis
/// ([`Cia402Axis::on_cyclic_sample`]). A plan stays valid until the axis's
/// [`Cia402Axis::cyclic_plan`] differs from it (a new move, a stop, the
/// drive leaving operation enabled).
#[derive(Debug, Clone, PartialEq)]
pub struct CyclicPlan {
    trajectory: Option<Trajectory>,
    /// The demand (user units) without a trajectory, and after it ended.
    hold: f64,
    units: Units,
    /// A jog's dead-man: the first sample at or after it replaces the
    /// trajectory by a stop ramp. Enforced here, where the set-points are
    /// sampled, so that a jog stops on time even when the thread that runs
    /// the axis is held up.
    deadman: Option<Duration>,
    /// The axis's stop deceleration (the dead-man's stop ramp).
    stop_deceleration: f64,
    /// The object each sample is sent in.
    setpoint: SetpointObject,
}

/// The object a cyclic axis's set-point goes to with every SYNC.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SetpointObject {
    /// 0x607A target position (CSP): [`CyclicSample::counts`].
    TargetPosition,
    /// 0x60FF target velocity (CSV): [`CyclicSample::velocity_counts`].
    TargetVelocity,
    /// 0x60C1:01 interpolation data record (IP): [`CyclicSample::counts`].
    InterpolationData,
}

/// The set-point a [`CyclicPlan`] gave for one SYNC.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CyclicSample {
    /// The SYNC's time (the axis's clock).
    pub at: Duration,
    /// The set-point in drive counts: the RPDO's target position.
    pub counts: i32,
    /// The demand velocity in drive counts/s: the target velocity of a
    /// CSV axis.
    pub velocity_counts: i32,
    /// Demand position and velocity (user units).
    demand: f64,
    velocity: f64,
    /// When the trajectory started: its first sample fixes it.
    start: Option<Duration>,
    /// The trajectory ended with this sample.
    finished: bool,
    /// The jog's dead-man expired at this sample, which is the first of the
    /// stop ramp.
    deadman_stop: bool,
}

impl CyclicSample {
    /// Whether this sample ended the trajectory or started the dead-man's
    /// stop ramp: the axis must see it, not only a later sample.
    pub fn ends_a_motion(&self) -> bool {
        self.finished || self.deadman_stop
    }

    /// The set-point of a SYNC sent at `at` from a source other than the
    /// axis's own plan (a set-point stream played by the sampler): demand
    /// `position` moving at `velocity` (user units). The axis's demand
    /// follows it, so a stop that interrupts the source ramps down from
    /// there.
    pub fn streamed(at: Duration, position: f64, velocity: f64, units: Units) -> CyclicSample {
        CyclicSample {
            at,
            counts: units.to_counts(position),
            velocity_counts: units.to_counts(velocity),
            demand: position,
            velocity,
            start: None,
            finished: false,
            deadman_stop: false,
        }
    }

    /// The demand position of this set-point (user units).
    pub fn demand(&self) -> f64 {
        self.demand
    }
}

impl CyclicPlan {
    /// A plan that holds `position` (user units): the set-point of an axis
    /// at rest.
    pub fn holding(position: f64, units: Units) -> CyclicPlan {
        CyclicPlan {
            trajectory: None,
            hold: position,
            units,
            deadman: None,
            stop_deceleration: 0.0,
            setpoint: SetpointObject::TargetPosition,
        }
    }

    /// The object the samples go to.
    pub fn setpoint_object(&self) -> SetpointObject {
        self.setpoint
    }

    /// The same plan, its samples sent to `setpoint`.
    pub fn sent_to(mut self, setpoint: SetpointObject) -> CyclicPlan {
        self.setpoint = setpoint;
        self
    }

    /// True while a trajectory runs (the axis moves, or waits for the SYNC
    /// that starts its move).
    pub fn is_moving(&self) -> bool {
        self.trajectory.is_some()
    }

    /// Periods passed without a SYNC (a late or stalled sender skipped
    /// them): the trajectory is held back by `missed`, so that the next
    /// sample continues from the last one sent by one period, never by
    /// the skipped ones too. A drive in CSP takes each set-point as the
    /// position one SYNC period after the previous one: sampled at the wall
    /// clock, a skipped period would reach it as a double step (twice the
    /// velocity for a cycle). The motion ends `missed` later instead.
    pub fn hold_back(&mut self, missed: Duration) {
        if let Some(start) = self.trajectory.as_mut().and_then(|t| t.start.as_mut()) {
            *start += missed;
        }
    }

    /// Whether `other` is this plan as published before some of its
    /// samples (the same motion, held back or started differently): a
    /// sampler keeps its own copy then.
    pub fn same_motion(&self, other: &CyclicPlan) -> bool {
        let motion = |t: &Trajectory| (t.profile.clone(), t.ratio);
        self.trajectory.as_ref().map(motion) == other.trajectory.as_ref().map(motion)
            && self.hold == other.hold
            && self.units == other.units
            && self.deadman == other.deadman
            && self.stop_deceleration == other.stop_deceleration
            && self.setpoint == other.setpoint
    }

    /// The set-point of a SYNC sent at `at`; the first sample of a
    /// trajectory that waits for the next SYNC starts it.
    pub fn sample(&mut self, at: Duration) -> CyclicSample {
        let mut deadman_stop = false;
        if let Some(d) = self.deadman
            && at >= d
        {
            self.deadman = None;
            if let Some(traj) = &self.trajectory {
                let start = traj.start.unwrap_or(at);
                let (p, v) = traj.sample(at.saturating_sub(start).as_secs_f64());
                self.hold = p;
                let decel = stop_deceleration(self.stop_deceleration, Some(traj));
                self.trajectory = Trajectory::stop_ramp(p, v, decel, Some(at));
                deadman_stop = true;
            }
        }
        let Some(traj) = &mut self.trajectory else {
            return CyclicSample {
                at,
                counts: self.units.to_counts(self.hold),
                velocity_counts: 0,
                demand: self.hold,
                velocity: 0.0,
                start: None,
                finished: false,
                deadman_stop,
            };
        };
        let start = *traj.start.get_or_insert(at);
        let t = at.saturating_sub(start).as_secs_f64();
        let (p, v) = traj.sample(t);
        let finished = t >= traj.duration();
        if finished {
            self.trajectory = None;
            self.hold = p;
        }
        let velocity = if finished { 0.0 } else { v };
        CyclicSample {
            at,
            counts: self.units.to_counts(p),
            velocity_counts: self.units.to_counts(velocity),
            demand: p,
            velocity,
            start: Some(start),
            finished,
            deadman_stop,
        }
    }
}

/// The controlword that holds a drive in `state`, for an axis that finds
/// it there (`current`, with its mode bits, where no command holds it).
fn adopted_controlword(state: Option<DriveState>, current: u16) -> u16 {
    let hold = match state {
        Some(DriveState::OperationEnabled) => Controlword::ENABLE_OPERATION,
        Some(DriveState::SwitchedOn) => Controlword::SWITCH_ON,
        Some(DriveState::ReadyToSwitchOn) => Controlword::SHUTDOWN,
        _ => return current,
    };
    (current & !Controlword::COMMAND_MASK) | hold.bits()
}

/// One CiA 402 drive as an axis. See the [module documentation](self).
#[derive(Debug)]
pub struct Cia402Axis {
    cfg: Cia402Config,
    statusword: Option<Statusword>,
    position: Option<i32>,
    velocity: i32,
    mode_display: Option<i8>,
    drive_following_error: Option<i32>,
    /// Statuswords received since the image last changed.
    fresh: u32,
    image: ProcessImage,
    /// Demand position and velocity (user units) of a cyclic axis.
    demand: f64,
    demand_velocity: f64,
    /// When the demand was last sampled (the latest SYNC of a cyclic
    /// axis): new trajectories start from that state at that time, so a
    /// stream of re-plans between SYNCs (a handwheel) still advances.
    demand_at: Option<Duration>,
    trajectory: Option<Trajectory>,
    jog_deadline: Option<Duration>,
    /// Latest target of a profile move (user units).
    last_target: f64,
    /// Profile velocity, acceleration and deceleration (0x6081, 0x6083,
    /// 0x6084, counts) the drive holds.
    profile_written: Option<ProfileCounts>,
    /// SDO writes in flight and what they write.
    sdo_in_flight: Option<ProfileCounts>,
    /// The profile wanted last: written when the writes in flight end (a
    /// stop's ramp asked for while a move's parameters were being written).
    profile_wanted: Option<ProfileCounts>,
    homed: bool,
    /// The image requests a mode the drive has not shown since.
    mode_pending: bool,
    node_lost: Option<String>,
    emcy: Option<(u16, String)>,
    fault_reported: bool,
    op: Option<Op>,
    next_id: OpId,
    /// Torque, digital inputs, touch probe status from the process data.
    signals: DriveSignals,
    probe: TouchProbeTracker,
    /// The limit switch reported as the axis's fault (active).
    limit_reported: Option<LimitSwitch>,
    /// A limit switch stopped the axis: a cyclic axis's demand is set to
    /// where the drive stands once its stop ramp ended (the drive did not
    /// follow into the switch); a profile axis holds its halt until the
    /// next command.
    limit_stop: Option<LimitSwitch>,
    /// The largest following error (user units, absolute) reported or
    /// computed since the axis was last enabled: what a following error
    /// fault names.
    following_error_peak: f64,
    /// The mode of operation the axis runs in now (the configured one
    /// until [`AxisCommand::SetMode`] changes it).
    mode: DriveMode,
    /// The modes the drive supports (0x6502, read at its boot); `None`
    /// while unknown.
    supported_modes: Option<u32>,
}

impl Cia402Axis {
    /// An axis; nothing is sent until the first statusword arrives.
    pub fn new(cfg: Cia402Config) -> Self {
        let mode = cfg.mode.operation();
        let cfg_mode = cfg.mode;
        Cia402Axis {
            cfg,
            statusword: None,
            position: None,
            velocity: 0,
            mode_display: None,
            drive_following_error: None,
            fresh: 0,
            image: ProcessImage {
                controlword: 0,
                mode: mode.code(),
                target_position: 0,
                target_velocity: 0,
                target_torque: 0,
            },
            demand: 0.0,
            demand_velocity: 0.0,
            demand_at: None,
            trajectory: None,
            jog_deadline: None,
            last_target: 0.0,
            profile_written: None,
            sdo_in_flight: None,
            profile_wanted: None,
            homed: false,
            mode_pending: false,
            node_lost: None,
            emcy: None,
            fault_reported: false,
            op: None,
            next_id: 1,
            signals: DriveSignals::default(),
            probe: TouchProbeTracker::default(),
            limit_reported: None,
            limit_stop: None,
            following_error_peak: 0.0,
            mode: cfg_mode,
            supported_modes: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &Cia402Config {
        &self.cfg
    }

    /// The process image as last computed.
    pub fn image(&self) -> ProcessImage {
        self.image
    }

    /// The SDO writes the gateway makes at boot for this axis: homing is
    /// configured by the node's own writes; here the soft limits in counts
    /// (0x607D, when both are configured) and the default profile; the
    /// objects of the axis's own drive axis.
    pub fn boot_writes(&self) -> Vec<(ObjectAddress, Vec<u8>)> {
        let mut w = self.first_axis_boot_writes();
        for (addr, _) in &mut w {
            *addr = on_axis(*addr, self.cfg.drive_axis);
        }
        w
    }

    fn first_axis_boot_writes(&self) -> Vec<(ObjectAddress, Vec<u8>)> {
        let mut w = Vec::new();
        if let (Some(min), Some(max)) = (self.cfg.motion.min_position, self.cfg.motion.max_position)
        {
            let (a, b) = (
                self.cfg.motion.units.to_counts(min),
                self.cfg.motion.units.to_counts(max),
            );
            let (lo, hi) = (a.min(b), a.max(b));
            w.push((obj::SOFTWARE_POSITION_LIMIT_MIN, lo.to_le_bytes().to_vec()));
            w.push((obj::SOFTWARE_POSITION_LIMIT_MAX, hi.to_le_bytes().to_vec()));
        }
        w.extend(self.cfg.supervision.boot_writes(self.units()));
        if self.cfg.torque.in_process_data {
            // Profile torque's ramp: written for every torque axis, so a
            // mode change to profile torque needs no SDO at run time.
            let slope = self
                .cfg
                .torque
                .torque_slope
                .round()
                .clamp(0.0, f64::from(u32::MAX)) as u32;
            w.push((obj::TORQUE_SLOPE, slope.to_le_bytes().to_vec()));
        }
        w
    }

    fn mode_for_position(&self) -> ModeOfOperation {
        self.mode.operation()
    }

    /// How moves run in the axis's current mode.
    fn position_mode(&self) -> PositionMode {
        self.mode.position_mode()
    }

    fn units(&self) -> Units {
        self.cfg.motion.units
    }

    fn actual(&self) -> f64 {
        self.units()
            .from_counts(f64::from(self.position.unwrap_or_default()))
    }

    fn state(&self) -> Option<DriveState> {
        self.statusword.map(Statusword::state)
    }

    fn is_fault(&self) -> bool {
        matches!(
            self.state(),
            Some(DriveState::Fault | DriveState::FaultReactionActive)
        )
    }

    /// At rest: the drive's velocity would not carry it past the
    /// in-position window within 100 ms (and at least one count/s). Strictly
    /// below: the velocity comes rounded to whole counts/s.
    fn at_rest(&self) -> bool {
        let v = self.units().from_counts(f64::from(self.velocity)).abs();
        self.velocity == 0 || v < self.cfg.motion.in_position_window * 10.0
    }

    /// At rest within the in-position window of `target`.
    fn in_position(&self, target: f64) -> bool {
        (self.actual() - target).abs() <= self.cfg.motion.in_position_window && self.at_rest()
    }

    /// The live state.
    pub fn snapshot(&self) -> AxisSnapshot {
        let u = self.units();
        let position = self.actual();
        let demand = match self.position_mode() {
            PositionMode::Cyclic => self.demand,
            PositionMode::Profile => self.last_target,
        };
        let following_error = match (self.drive_following_error, self.position_mode()) {
            (Some(fe), _) => u.from_counts(f64::from(fe)),
            (None, PositionMode::Cyclic) if self.position.is_some() => self.demand - position,
            _ => 0.0,
        };
        AxisSnapshot {
            state: self.state(),
            statusword: self.statusword.map(Statusword::bits).unwrap_or_default(),
            mode: self.mode_display.unwrap_or_default(),
            activity: self.activity(),
            position,
            velocity: u.from_counts(f64::from(self.velocity)),
            demand_position: demand,
            following_error,
            homed: self.homed,
            node_lost: self.node_lost.clone(),
            fault: self.fault(),
            signals: DriveSignals {
                following_error: self
                    .drive_following_error
                    .map(|fe| u.from_counts(f64::from(fe))),
                ..self.signals
            },
        }
    }

    fn fault(&self) -> Option<(u16, String)> {
        if let Some(reason) = &self.node_lost {
            return Some((0, format!("node lost: {reason}")));
        }
        if self.is_fault() {
            return Some(
                self.emcy
                    .clone()
                    .unwrap_or((0, "drive fault (no EMCY received)".into())),
            );
        }
        self.limit_reported.map(|sw| (0, sw.reached()))
    }

    /// What the axis is doing.
    pub fn activity(&self) -> Activity {
        match self.op.as_ref().map(|o| (&o.kind, &o.step)) {
            None => Activity::Idle,
            Some((_, Step::Stopping)) => Activity::Stopping,
            Some((CommandKind::Enable | CommandKind::Disable | CommandKind::ResetFault, _)) => {
                Activity::Switching
            }
            Some((CommandKind::Home, _)) => Activity::Homing,
            Some((CommandKind::Jog, _)) => Activity::Jogging,
            Some((CommandKind::Move, _)) => Activity::Moving,
            Some((CommandKind::Stop | CommandKind::QuickStop, _)) => Activity::Stopping,
            Some((CommandKind::Torque, _)) => Activity::Moving,
            Some((CommandKind::SetMode, _)) => Activity::Switching,
        }
    }

    /// Why a guard stopped the command in progress (a torque command's
    /// velocity or soft-limit guard), if one did.
    pub fn guard(&self) -> Option<&str> {
        self.op.as_ref().and_then(|o| o.guard.as_deref())
    }

    /// The id of the command in progress, if any.
    pub fn current_op(&self) -> Option<OpId> {
        self.op.as_ref().map(|o| o.id)
    }

    // ---------------------------------------------------------------- input

    /// Handles process data received at `now`.
    pub fn on_feedback(&mut self, fb: Feedback, now: Duration, out: &mut Vec<Output>) {
        if let Some(p) = fb.position {
            self.position = Some(p);
        }
        if let Some(v) = fb.velocity {
            self.velocity = v;
        }
        if let Some(m) = fb.mode_display {
            self.mode_display = Some(m);
        }
        if let Some(fe) = fb.following_error {
            self.drive_following_error = Some(fe);
        }
        self.on_signals(&fb, out);
        let Some(sw) = fb.statusword else {
            self.advance(now, out);
            return;
        };
        let first = self.statusword.is_none();
        self.statusword = Some(Statusword(sw));
        self.fresh = self.fresh.saturating_add(1);
        if self.fresh >= 2 && self.mode_display.is_none_or(|m| m == self.image.mode) {
            self.mode_pending = false;
        }
        if let Some(op) = &mut self.op
            && op.deadline.is_some_and(|d| now >= d)
        {
            op.late_feedback = op.late_feedback.saturating_add(1);
        }
        if first {
            // Start from where the drive is, without a jump.
            self.demand = self.actual();
            self.last_target = self.demand;
            self.image.target_position = self.position.unwrap_or_default();
            // And in the state it is in: the next image keeps it there (a
            // drive found enabled is not disabled by a controlword of 0).
            self.image.controlword = adopted_controlword(self.state(), self.image.controlword);
        }
        if self.is_fault() {
            if !self.fault_reported {
                self.fault_reported = true;
                let (code, text) = self.fault().unwrap_or_default();
                out.push(Output::Event(AxisEvent::Fault { code, text }));
                self.drop_trajectory();
                self.jog_deadline = None;
                if let Some(op) = &self.op
                    && !matches!(op.kind, CommandKind::ResetFault | CommandKind::Disable)
                {
                    let (code, text) = self.fault().unwrap_or_default();
                    self.finish(
                        Outcome::Fault,
                        format!("drive fault 0x{code:04X} {text}"),
                        out,
                    );
                }
            }
        } else if self.fault_reported {
            self.fault_reported = false;
            out.push(Output::Event(AxisEvent::Fault {
                code: 0,
                text: String::new(),
            }));
            // A limit switch still active is what the axis reports again.
            if let Some(sw) = self.limit_reported
                && self.node_lost.is_none()
            {
                out.push(Output::Event(AxisEvent::Fault {
                    code: 0,
                    text: sw.reached(),
                }));
            }
        }
        if matches!(
            self.state(),
            Some(
                DriveState::SwitchOnDisabled
                    | DriveState::ReadyToSwitchOn
                    | DriveState::NotReadyToSwitchOn
            )
        ) {
            // Power stage off: the homing reference is not trusted any more
            // only after a reset; keep `homed`, but no motion continues.
            self.drop_trajectory();
            self.jog_deadline = None;
        }
        self.check_still_enabled(out);
        self.advance(now, out);
    }

    /// A motion command needs the drive in operation enabled all along: a
    /// drive that left it (a controlword written by someone else, a quick
    /// stop from its own input, an internal disable) ends the command at
    /// once, saying so; it does not wait for its deadline. Faults are
    /// reported as such (see on_feedback); a stop in progress ends when the
    /// drive stands still.
    fn check_still_enabled(&mut self, out: &mut Vec<Output>) {
        let Some(state) = self.state() else {
            return;
        };
        let Some(op) = &self.op else {
            return;
        };
        if state == DriveState::OperationEnabled
            || self.is_fault()
            || !matches!(
                op.kind,
                CommandKind::Move | CommandKind::Jog | CommandKind::Home | CommandKind::Torque
            )
            || matches!(op.step, Step::Stopping)
        {
            return;
        }
        self.drop_trajectory();
        self.jog_deadline = None;
        self.release_handshake(out);
        self.finish(
            Outcome::Fault,
            format!("the drive left operation enabled (now {state})"),
            out,
        );
    }

    /// Handles an EMCY of this drive (`code` 0 = error reset).
    pub fn on_emcy(&mut self, code: u16, text: &str, out: &mut Vec<Output>) {
        if code == 0 {
            self.emcy = None;
            return;
        }
        let text = if code == FOLLOWING_ERROR_CODE {
            self.following_error_text()
        } else {
            text.to_string()
        };
        let text = text.as_str();
        self.emcy = Some((code, text.to_string()));
        if self.fault_reported {
            out.push(Output::Event(AxisEvent::Fault {
                code,
                text: text.to_string(),
            }));
        }
    }

    /// The drive's node was lost (heartbeat timeout, boot failure).
    pub fn on_node_lost(&mut self, reason: &str, out: &mut Vec<Output>) {
        if let Some(lost) = &mut self.node_lost {
            // Lost already (rebooted, waiting for its boot procedure): a
            // later reason (the boot procedure failed, and why) replaces
            // the earlier one, so the status says what to fix.
            if lost != reason {
                *lost = reason.to_string();
                out.push(Output::Event(AxisEvent::Fault {
                    code: 0,
                    text: format!("node lost: {reason}"),
                }));
            }
            return;
        }
        self.node_lost = Some(reason.to_string());
        self.drop_trajectory();
        self.jog_deadline = None;
        out.push(Output::Event(AxisEvent::Fault {
            code: 0,
            text: format!("node lost: {reason}"),
        }));
        if self.op.is_some() {
            self.finish(Outcome::Fault, format!("node lost: {reason}"), out);
        }
    }

    /// The node is back (heartbeat recovered, booted). Its drive state is
    /// taken from the next statusword; after a reset it is not homed.
    pub fn on_node_back(&mut self, rebooted: bool, out: &mut Vec<Output>) {
        if self.node_lost.take().is_some() {
            out.push(Output::Event(AxisEvent::Fault {
                code: 0,
                text: String::new(),
            }));
            // A drive fault that outlasted the loss is still there: the
            // event stream must not end on "cleared" while the status says
            // FAULT.
            if !rebooted
                && self.fault_reported
                && let Some((code, text)) = self.fault()
            {
                out.push(Output::Event(AxisEvent::Fault { code, text }));
            }
        }
        if rebooted {
            self.homed = false;
            self.statusword = None;
            self.profile_written = None;
            self.profile_wanted = None;
            self.image.controlword = 0;
            // The rebooted drive's first statusword says afresh whether it
            // is faulted.
            self.fault_reported = false;
            self.emcy = None;
            // Its signals, probe and switches too.
            self.signals = DriveSignals::default();
            self.probe = TouchProbeTracker::default();
            self.limit_reported = None;
            self.limit_stop = None;
            self.following_error_peak = 0.0;
        }
    }

    /// The SDO writes asked for by [`Output::SdoWrites`] finished.
    pub fn on_sdo_done(
        &mut self,
        result: Result<(), String>,
        now: Duration,
        out: &mut Vec<Output>,
    ) {
        let written = self.sdo_in_flight.take();
        match result {
            Ok(()) => {
                self.profile_written = written;
                if let Some(want) = self.profile_wanted
                    && written != Some(want)
                {
                    self.want_profile_counts(want, out);
                }
            }
            Err(e) => {
                self.profile_written = None;
                self.profile_wanted = None;
                if matches!(self.op.as_ref().map(|o| &o.step), Some(Step::AwaitSdo)) {
                    self.finish(
                        Outcome::Fault,
                        format!("writing the profile parameters failed: {e}"),
                        out,
                    );
                }
            }
        }
        self.advance(now, out);
    }

    /// A SYNC was sent at `now`: a cyclic axis samples its trajectory and
    /// sends the set-point (every SYNC while enabled in CSP, also at rest).
    /// The same as sampling [`Cia402Axis::cyclic_plan`] and handing the
    /// sample to [`Cia402Axis::on_cyclic_sample`], plus the image.
    pub fn on_sync(&mut self, now: Duration, out: &mut Vec<Output>) {
        let Some(mut plan) = self.cyclic_plan() else {
            return;
        };
        let sample = plan.sample(now);
        self.apply_sample(&sample, now);
        out.push(Output::Image(self.image));
        self.advance(now, out);
    }

    /// The set-points this axis wants sent with every SYNC from now on;
    /// `None` while it sends none (not cyclic, not in CSP, not operation
    /// enabled, node lost).
    pub fn cyclic_plan(&self) -> Option<CyclicPlan> {
        if !self.cyclic_plan_active() {
            return None;
        }
        Some(CyclicPlan {
            trajectory: self.trajectory.clone(),
            // Unused while a trajectory runs (its end becomes the hold),
            // and kept constant then: the demand moving with each sample
            // must not make the plan look changed.
            hold: if self.trajectory.is_some() {
                0.0
            } else {
                self.demand
            },
            units: self.units(),
            deadman: self.trajectory.as_ref().and(self.jog_deadline),
            stop_deceleration: self.cfg.motion.stop_deceleration,
            setpoint: self.setpoint_object(),
        })
    }

    /// A SYNC went out with `sample` of this axis's current
    /// [`Cia402Axis::cyclic_plan`]: the demand follows it, and a finished
    /// trajectory completes its command. A sample of an earlier plan must
    /// not be handed in: its trajectory may be the one a new command
    /// replaced.
    pub fn on_cyclic_sample(
        &mut self,
        sample: &CyclicSample,
        now: Duration,
        out: &mut Vec<Output>,
    ) {
        self.apply_sample(sample, now);
        self.advance(now, out);
    }

    /// Whether this axis sends set-points with every SYNC now.
    fn cyclic_plan_active(&self) -> bool {
        self.position_mode() == PositionMode::Cyclic
            && self.in_cyclic_mode()
            && self.state() == Some(DriveState::OperationEnabled)
            && self.node_lost.is_none()
    }

    fn apply_sample(&mut self, s: &CyclicSample, now: Duration) {
        if s.deadman_stop {
            // The jog's dead-man stopped it at this SYNC: the same stop
            // ramp as the sampler's, from the same state.
            self.jog_deadline = None;
            let decel = self.stop_deceleration();
            self.trajectory = Trajectory::stop_ramp(s.demand, s.velocity, decel, Some(s.at));
            if let Some(op) = &mut self.op
                && op.kind == CommandKind::Jog
            {
                op.step = Step::Stopping;
                let t = self.trajectory.as_ref().map_or(0.0, Trajectory::duration);
                op.arm(Some(
                    now + Duration::from_secs_f64(t) + self.cfg.motion.settle_timeout,
                ));
            }
        }
        if let Some(traj) = &mut self.trajectory {
            // The first sample fixes the start; later ones may hold it back
            // (SYNC periods skipped, see CyclicPlan::hold_back).
            if s.start.is_some() {
                traj.start = s.start;
            }
            if s.finished {
                self.drop_trajectory();
            }
        }
        self.demand = s.demand;
        self.demand_velocity = s.velocity;
        self.demand_at = Some(s.at);
        if self.mode == DriveMode::CyclicVelocity {
            self.image.target_velocity = s.velocity_counts;
        } else {
            self.image.target_position = s.counts;
        }
    }

    /// The object the cyclic set-points of the current mode go to.
    fn setpoint_object(&self) -> SetpointObject {
        match self.mode {
            DriveMode::CyclicVelocity => SetpointObject::TargetVelocity,
            DriveMode::InterpolatedPosition => SetpointObject::InterpolationData,
            _ => SetpointObject::TargetPosition,
        }
    }

    /// Handles time passing.
    pub fn on_tick(&mut self, now: Duration, out: &mut Vec<Output>) {
        self.advance(now, out);
    }

    /// When [`Cia402Axis::on_tick`] is due next.
    pub fn next_deadline(&self) -> Option<Duration> {
        let grace = self.deadline_grace();
        let op = self.op.as_ref().and_then(|o| match &o.step {
            Step::Switch(d) => d.next_deadline(),
            _ if o.overdue => o.deadline.map(|d| d + grace),
            _ => o.deadline,
        });
        [op, self.jog_deadman_due()].into_iter().flatten().min()
    }

    /// When the axis stops a jog itself: at the dead-man deadline, except
    /// for a cyclic jog whose set-points are being sampled, which the first
    /// SYNC past the deadline stops (its plan carries the deadline); the
    /// axis steps in only if none came within [`DEADMAN_GRACE`].
    fn jog_deadman_due(&self) -> Option<Duration> {
        let d = self.jog_deadline?;
        if self.trajectory.is_some() && self.cyclic_plan_active() {
            Some(d + DEADMAN_GRACE)
        } else {
            Some(d)
        }
    }

    // ------------------------------------------------------------- commands

    /// Starts a command at `now`.
    ///
    /// # Errors
    /// [`CommandError`] when the value or the drive's state rules it out;
    /// nothing is sent then.
    pub fn command(
        &mut self,
        cmd: AxisCommand,
        now: Duration,
        out: &mut Vec<Output>,
    ) -> Result<OpId, CommandError> {
        self.check(&cmd)?;
        // A repeated jog re-arms the dead-man of the running jog.
        if let AxisCommand::Jog {
            velocity,
            acceleration,
        } = cmd
            && let Some(op) = &self.op
            && op.kind == CommandKind::Jog
            && !matches!(op.step, Step::Stopping)
            && velocity != 0.0
        {
            self.check_jog(velocity)?;
            let (id, accepted) = (op.id, op.accepted);
            let preparing = matches!(op.step, Step::SettleFor(_))
                || matches!(op.step, Step::AwaitMode(m) if m == self.mode.operation() && self.position_mode() == PositionMode::Cyclic);
            self.jog_deadline = Some(now + self.cfg.motion.jog_deadman);
            if preparing {
                // The jog starts with the latest velocity once the drive
                // is in its mode.
                if let Some(op) = &mut self.op {
                    op.command = cmd;
                }
            } else {
                self.retarget_jog(velocity, acceleration, now, out)?;
            }
            if accepted {
                out.push(Output::Event(AxisEvent::Accepted { op: id }));
            }
            return Ok(id);
        }
        if let AxisCommand::Jog { velocity: 0.0, .. } = cmd {
            return self.command(AxisCommand::Stop, now, out);
        }
        // Everything that can refuse the command is checked before the
        // running command ends: a refused command changes nothing.
        let mut target = 0.0;
        let mut driver = None;
        match cmd {
            AxisCommand::Move {
                target: t,
                relative,
                ..
            } => {
                // Relative to where the axis is going: the running
                // trajectory's end (so consecutive relative moves add up
                // exactly), else the demand; profile axes: the latest target.
                let base = match self.position_mode() {
                    PositionMode::Cyclic => self
                        .trajectory
                        .as_ref()
                        .map_or(self.demand, |t| t.profile.target()),
                    PositionMode::Profile => self.last_target,
                };
                target = if relative { base + t } else { t };
                self.check_limits(target)?;
                let from = match self.position_mode() {
                    PositionMode::Cyclic => self.demand,
                    PositionMode::Profile => self.actual(),
                };
                self.check_not_into_limit_switch(target - from)?;
            }
            AxisCommand::Jog { velocity, .. } => self.check_jog(velocity)?,
            AxisCommand::Enable | AxisCommand::Disable | AxisCommand::ResetFault => {
                let state = match cmd {
                    AxisCommand::Enable => DriveState::OperationEnabled,
                    AxisCommand::Disable => DriveState::ReadyToSwitchOn,
                    _ => DriveState::SwitchOnDisabled,
                };
                driver = Some(
                    StateMachineDriver::new(state, self.cfg.motion.state_timeout, now)
                        .map_err(|e| CommandError::StateUnreachable(e.to_string()))?,
                );
            }
            _ => {}
        }
        let id = self.next_id;
        self.next_id += 1;
        let kind = cmd.kind();
        if self.position_mode() == PositionMode::Profile {
            // The limit switch's halt ends with the next command.
            self.limit_stop = None;
        }
        if matches!(kind, CommandKind::Enable | CommandKind::ResetFault) {
            self.following_error_peak = 0.0;
        }
        let previous = if matches!(kind, CommandKind::Stop | CommandKind::QuickStop) {
            Outcome::Stopped
        } else {
            Outcome::Superseded
        };
        if self.op.is_some() {
            self.finish(previous, format!("{} by {}", previous.name(), kind), out);
        }
        self.jog_deadline = None;
        // A set-point or homing start the drive has not seen fall yet
        // would swallow the next rising edge: every command starts from
        // bit 4 low, sent.
        self.release_handshake(out);
        let mut op = Op::new(id, cmd, Step::Stopping);
        op.target = target;
        match cmd {
            AxisCommand::Enable | AxisCommand::Disable | AxisCommand::ResetFault => {
                if matches!(cmd, AxisCommand::Enable) {
                    self.prepare_enable();
                }
                self.image.controlword &= !(Controlword::HALT_BIT | Controlword::NEW_SET_POINT_BIT);
                self.keep_ip_enabled();
                let driver = driver
                    .expect("made above")
                    .with_previous(Controlword(self.image.controlword));
                op.step = Step::Switch(driver);
                op.accepted = true;
                out.push(Output::Event(AxisEvent::Accepted { op: id }));
            }
            AxisCommand::Home => {
                if self.moving() {
                    self.settle_for(ModeOfOperation::Homing, now, &mut op, out);
                    self.send_image(out);
                } else {
                    self.begin_mode(ModeOfOperation::Homing, now, &mut op, out);
                }
            }
            AxisCommand::Move {
                velocity,
                acceleration,
                ..
            } => match self.position_mode() {
                PositionMode::Cyclic if self.in_cyclic_mode() => {
                    self.plan_move(&mut op, now, out)?;
                }
                PositionMode::Cyclic => {
                    self.settle_for(self.mode.operation(), now, &mut op, out);
                    self.send_image(out);
                }
                PositionMode::Profile => {
                    self.last_target = op.target;
                    op.step = Step::AwaitSdo;
                    op.arm(Some(now + self.cfg.motion.state_timeout));
                    let v = velocity.unwrap_or(self.cfg.motion.default_velocity);
                    let a = acceleration.unwrap_or(self.cfg.motion.default_acceleration);
                    self.want_profile(v, a, out);
                    self.set_mode(ModeOfOperation::ProfilePosition);
                }
            },
            AxisCommand::Jog {
                velocity,
                acceleration,
            } => {
                self.jog_deadline = Some(now + self.cfg.motion.jog_deadman);
                if self.position_mode() == PositionMode::Cyclic && !self.in_cyclic_mode() {
                    self.settle_for(self.mode.operation(), now, &mut op, out);
                    self.send_image(out);
                } else {
                    self.op = Some(op);
                    self.retarget_jog(velocity, acceleration, now, out)?;
                    self.advance(now, out);
                    return Ok(id);
                }
            }
            AxisCommand::Stop => {
                op.step = Step::Stopping;
                op.accepted = true;
                out.push(Output::Event(AxisEvent::Accepted { op: id }));
                self.start_stop(now, &mut op, out);
                self.send_image(out);
            }
            AxisCommand::SetTorque { per_mille } => {
                let mode = self.mode.operation();
                if self.mode_is(mode) {
                    self.start_torque(&mut op, per_mille, out);
                } else {
                    // Back from homing (or a drive that changed mode
                    // itself): the torque starts in the axis's mode.
                    self.image.target_torque = 0;
                    self.begin_mode(mode, now, &mut op, out);
                }
            }
            AxisCommand::SetMode { mode } => {
                // At rest (checked): the new mode starts from where the
                // drive stands, with no torque and no velocity.
                self.mode = mode;
                self.image.target_torque = 0;
                self.last_target = self.actual();
                op.accepted = true;
                out.push(Output::Event(AxisEvent::Accepted { op: id }));
                self.begin_mode(mode.operation(), now, &mut op, out);
            }
            AxisCommand::QuickStop => {
                op.step = Step::Stopping;
                op.accepted = true;
                out.push(Output::Event(AxisEvent::Accepted { op: id }));
                self.drop_trajectory();
                // The drive brakes on its quick stop ramp: 0x6085, or 0x6084
                // (quick stop option codes 1 and 5, drives without 0x6085).
                self.want_stop_ramp(self.cfg.motion.quick_stop_deceleration, out);
                self.image.controlword = Controlword(self.image.controlword)
                    .with_command(Controlword::QUICK_STOP)
                    .0;
                op.arm(Some(
                    now + self.cfg.motion.state_timeout + self.cfg.motion.settle_timeout,
                ));
                self.send_image(out);
            }
        }
        self.op = Some(op);
        self.image_changed();
        self.advance(now, out);
        Ok(id)
    }

    /// Whether the axis (or its drive) moves: a trajectory runs, the demand
    /// or the drive is not at rest.
    fn moving(&self) -> bool {
        self.trajectory.is_some() || self.demand_velocity != 0.0 || !self.at_rest()
    }

    /// Whether the image commands the axis's cyclic mode (CSP, IP, CSV):
    /// the gateway's trajectories run.
    fn in_cyclic_mode(&self) -> bool {
        self.position_mode() == PositionMode::Cyclic
            && self.image.mode == self.mode.operation().code()
    }

    /// `op` first brings the drive to rest in its current mode, then
    /// switches to `mode` ([`Step::SettleFor`]).
    fn settle_for(
        &mut self,
        mode: ModeOfOperation,
        now: Duration,
        op: &mut Op,
        out: &mut Vec<Output>,
    ) {
        op.step = Step::SettleFor(mode);
        self.start_stop(now, op, out);
    }

    /// Switches the drive to `mode` (at rest) for `op`: the halt is
    /// released, a cyclic axis holds where the drive stands.
    fn begin_mode(
        &mut self,
        mode: ModeOfOperation,
        now: Duration,
        op: &mut Op,
        out: &mut Vec<Output>,
    ) {
        self.drop_trajectory();
        if matches!(
            mode,
            ModeOfOperation::CyclicSynchronousPosition
                | ModeOfOperation::CyclicSynchronousVelocity
                | ModeOfOperation::InterpolatedPosition
        ) {
            self.demand = self.actual();
            self.demand_at = None;
            self.image.target_position = self.position.unwrap_or_default();
            self.image.target_velocity = 0;
        }
        self.set_mode(mode);
        self.image.controlword &= !(Controlword::HALT_BIT | Controlword::HOMING_START_BIT);
        self.keep_ip_enabled();
        op.step = Step::AwaitMode(mode);
        op.arm(Some(now + self.cfg.motion.state_timeout));
        self.send_image(out);
    }

    /// Plans a cyclic move of `op` to `op.target` from the demand.
    fn plan_move(
        &mut self,
        op: &mut Op,
        now: Duration,
        out: &mut Vec<Output>,
    ) -> Result<(), CommandError> {
        let (v, a) = self.wanted_profile(op);
        let limits = Limits::symmetric(v, a).map_err(|e| CommandError::BadValue(e.to_string()))?;
        let profile = TrapezoidProfile::new(self.demand, self.demand_velocity, op.target, limits)
            .map_err(|e| CommandError::BadValue(e.to_string()))?;
        let total = Duration::from_secs_f64(profile.duration().min(1e6));
        self.trajectory = Some(Trajectory {
            profile,
            ratio: 1.0,
            start: self.demand_at,
        });
        op.step = Step::CyclicMoving;
        op.arm(Some(now + total + self.cfg.motion.settle_timeout));
        if !op.accepted {
            op.accepted = true;
            out.push(Output::Event(AxisEvent::Accepted { op: op.id }));
        }
        Ok(())
    }

    /// Plans the cyclic jog of `op` (its command): a trapezoid from the
    /// demand towards the soft limit at the jog's velocity.
    fn plan_jog(&mut self, op: &mut Op, out: &mut Vec<Output>) -> Result<(), CommandError> {
        let AxisCommand::Jog {
            velocity,
            acceleration,
        } = op.command
        else {
            return Ok(());
        };
        let a = acceleration.unwrap_or(self.cfg.motion.default_acceleration);
        if self.mode == DriveMode::CyclicVelocity
            && self.trajectory.is_none()
            && self.demand_velocity == 0.0
        {
            // The drive integrates the velocity set-points itself: a jog
            // from rest plans from where it stands, so roundings of
            // earlier jogs do not add up against the soft limits.
            self.demand = self.actual();
        }
        let far = if velocity > 0.0 {
            self.cfg.motion.max_position.unwrap_or(self.demand + 1e6)
        } else {
            self.cfg.motion.min_position.unwrap_or(self.demand - 1e6)
        };
        let limits = Limits::symmetric(velocity.abs(), a)
            .map_err(|e| CommandError::BadValue(e.to_string()))?;
        let profile = TrapezoidProfile::new(self.demand, self.demand_velocity, far, limits)
            .map_err(|e| CommandError::BadValue(e.to_string()))?;
        self.trajectory = Some(Trajectory {
            profile,
            ratio: 1.0,
            start: self.demand_at,
        });
        op.step = Step::Jogging;
        op.arm(None);
        if !op.accepted {
            op.accepted = true;
            out.push(Output::Event(AxisEvent::Accepted { op: op.id }));
        }
        Ok(())
    }

    /// Ends any trajectory: the demand holds where it is.
    fn drop_trajectory(&mut self) {
        self.trajectory = None;
        self.demand_velocity = 0.0;
    }

    /// Clears controlword bit 4 (new set-point, homing start) and sends
    /// the image when it was set.
    fn release_handshake(&mut self, out: &mut Vec<Output>) {
        if self.image.mode == ModeOfOperation::InterpolatedPosition.code() {
            // Bit 4 is "enable ip mode" there: it stays set.
            return;
        }
        if self.image.controlword & Controlword::NEW_SET_POINT_BIT != 0 {
            self.image.controlword &= !Controlword::NEW_SET_POINT_BIT;
            self.send_image(out);
        }
    }

    /// A jog at `velocity` must not head further out of the soft limits.
    fn check_jog(&self, velocity: f64) -> Result<(), CommandError> {
        self.check_not_into_limit_switch(velocity)?;
        let at = match self.position_mode() {
            PositionMode::Cyclic => self.demand,
            PositionMode::Profile => self.actual(),
        };
        let unit = &self.cfg.motion.unit;
        if velocity > 0.0
            && let Some(max) = self.cfg.motion.max_position
            && at >= max
        {
            return Err(CommandError::BeyondSoftLimit(format!(
                "the axis is at or beyond its soft limit max_position = {max} {unit} ({at:.3} {unit}): it can only jog back"
            )));
        }
        if velocity < 0.0
            && let Some(min) = self.cfg.motion.min_position
            && at <= min
        {
            return Err(CommandError::BeyondSoftLimit(format!(
                "the axis is at or beyond its soft limit min_position = {min} {unit} ({at:.3} {unit}): it can only jog back"
            )));
        }
        Ok(())
    }

    /// Starts one axis of a coordinated cyclic move: `profile` in user
    /// units (from this axis's demand position, at rest), stretched to wall
    /// time by `ratio` (profile time per wall time). All axes of the move
    /// start sampling at the same SYNC.
    ///
    /// # Errors
    /// As [`Cia402Axis::command`].
    pub fn start_coordinated(
        &mut self,
        profile: TrapezoidProfile,
        ratio: f64,
        now: Duration,
        out: &mut Vec<Output>,
    ) -> Result<OpId, CommandError> {
        let target = profile.target();
        self.check_coordinated(target)?;
        let id = self.next_id;
        self.next_id += 1;
        if self.op.is_some() {
            self.finish(Outcome::Superseded, "superseded by move".into(), out);
        }
        self.jog_deadline = None;
        self.release_handshake(out);
        let traj = Trajectory {
            profile,
            ratio,
            start: self.demand_at,
        };
        let total = Duration::from_secs_f64(traj.duration().min(1e6));
        self.trajectory = Some(traj);
        let mut op = Op::new(
            id,
            AxisCommand::Move {
                target,
                relative: false,
                velocity: None,
                acceleration: None,
            },
            Step::CyclicMoving,
        );
        op.target = target;
        op.arm(Some(now + total + self.cfg.motion.settle_timeout));
        op.accepted = true;
        self.op = Some(op);
        out.push(Output::Event(AxisEvent::Accepted { op: id }));
        Ok(id)
    }

    /// Whether a coordinated move to `target` could start now.
    ///
    /// # Errors
    /// As [`Cia402Axis::command`]; also when the axis is not cyclic or is
    /// moving (a coordinated move starts from rest).
    pub fn check_coordinated(&self, target: f64) -> Result<(), CommandError> {
        self.check(&AxisCommand::Move {
            target,
            relative: false,
            velocity: None,
            acceleration: None,
        })?;
        if self.position_mode() != PositionMode::Cyclic {
            return Err(CommandError::NotCyclic(
                "coordinated moves need cyclic (CSP) axes".into(),
            ));
        }
        self.check_limits(target)?;
        self.check_not_into_limit_switch(target - self.demand)?;
        if !self.in_cyclic_mode() || self.activity() == Activity::Homing {
            return Err(CommandError::NotCyclic(
                "the axis is homing or not in cyclic position mode: wait for the homing or stop it first"
                    .into(),
            ));
        }
        if self.demand_velocity != 0.0 || self.trajectory.is_some() {
            return Err(CommandError::Busy(
                "the axis is moving: stop it before a coordinated move".into(),
            ));
        }
        Ok(())
    }

    /// The current demand position (cyclic) or latest target (profile), in
    /// user units.
    pub fn demand(&self) -> f64 {
        match self.position_mode() {
            PositionMode::Cyclic => self.demand,
            PositionMode::Profile => self.last_target,
        }
    }

    fn check(&self, cmd: &AxisCommand) -> Result<(), CommandError> {
        if let Some(reason) = &self.node_lost {
            return Err(CommandError::DriveUnavailable(format!(
                "the drive's node is lost ({reason}): commands are refused until it is back"
            )));
        }
        let Some(state) = self.state() else {
            return Err(CommandError::DriveUnavailable(
                "no process data from the drive yet (is its node booted and operational?)".into(),
            ));
        };
        crate::checks::motion_arguments(
            cmd,
            self.cfg.motion.max_velocity,
            self.cfg.motion.max_acceleration,
            &self.cfg.motion.unit,
        )?;
        self.check_mode(cmd)?;
        let needs_enabled = matches!(
            cmd,
            AxisCommand::Move { .. }
                | AxisCommand::Jog { .. }
                | AxisCommand::Home
                | AxisCommand::SetTorque { .. }
        );
        if self.is_fault() && (needs_enabled || matches!(cmd, AxisCommand::Enable)) {
            let (code, text) = self.fault().unwrap_or_default();
            return Err(CommandError::InFault(format!(
                "the drive is in fault (0x{code:04X} {text}): call ResetFault first"
            )));
        }
        if needs_enabled && state != DriveState::OperationEnabled {
            return Err(CommandError::NotEnabled(format!(
                "the axis is not enabled (drive state: {state}): call Enable first"
            )));
        }
        if needs_enabled
            && self
                .op
                .as_ref()
                .is_some_and(|o| o.kind == CommandKind::Disable)
        {
            return Err(CommandError::Busy(
                "the axis is being disabled: wait for the disable to end, then enable it".into(),
            ));
        }
        Ok(())
    }

    /// Whether the axis's mode has `cmd` (see [`DriveMode`]), and a mode
    /// change or torque command is possible now.
    fn check_mode(&self, cmd: &AxisCommand) -> Result<(), CommandError> {
        let mode = self.mode;
        let change = "change the mode at rest with SetMode first";
        match *cmd {
            AxisCommand::Move { .. }
                if !matches!(
                    mode,
                    DriveMode::ProfilePosition
                        | DriveMode::CyclicPosition
                        | DriveMode::InterpolatedPosition
                ) =>
            {
                Err(CommandError::WrongMode(format!(
                    "the axis runs in {mode} mode, which has no moves (profile_position, csp and \
                     ip have): {change}"
                )))
            }
            AxisCommand::Jog { .. } if mode.is_torque() => Err(CommandError::WrongMode(format!(
                "the axis runs in {mode} mode, which has no jog (a torque mode takes SetTorque): \
                 {change}"
            ))),
            AxisCommand::SetTorque { per_mille } => {
                if !mode.is_torque() {
                    return Err(CommandError::WrongMode(format!(
                        "the axis runs in {mode} mode: a torque command needs cst or \
                         profile_torque; {change}"
                    )));
                }
                crate::checks::finite("torque (per mille)", per_mille)?;
                let max = self.cfg.torque.max_torque;
                if per_mille.abs() > max {
                    return Err(CommandError::AboveMaximum(format!(
                        "torque {per_mille} per mille exceeds the axis maximum {max} per mille"
                    )));
                }
                Ok(())
            }
            AxisCommand::SetMode { mode: to } => self.check_mode_change(to),
            _ => Ok(()),
        }
    }

    /// A mode change to `to`: supported by the drive, its set-point in the
    /// process data, and the axis at rest.
    fn check_mode_change(&self, to: DriveMode) -> Result<(), CommandError> {
        if let Some(mask) = self.supported_modes
            && mask & to.operation().supported_mask() == 0
        {
            return Err(CommandError::WrongMode(format!(
                "the drive does not support {to} mode ({}; its 0x6502 supported drive modes \
                 are 0x{mask:08X})",
                to.operation()
            )));
        }
        // An interpolated position axis's process data carries 0x60C1:01
        // where the others carry 0x607A.
        let ip = DriveMode::InterpolatedPosition;
        if (to == ip) != (self.cfg.mode == ip)
            && matches!(
                to,
                DriveMode::ProfilePosition
                    | DriveMode::CyclicPosition
                    | DriveMode::InterpolatedPosition
            )
        {
            return Err(CommandError::WrongMode(format!(
                "the axis's process data carries the position in {}: {to} needs {}; configure \
                 the axis with mode = \"{to}\" for it",
                if self.cfg.mode == ip {
                    "0x60C1:01 (interpolated position)"
                } else {
                    "0x607A (target position)"
                },
                if to == ip { "0x60C1:01" } else { "0x607A" }
            )));
        }
        if to.is_torque() && !self.cfg.torque.in_process_data {
            return Err(CommandError::WrongMode(format!(
                "the axis's process data has no target torque (0x6071): configure it with \
                 mode = \"cst\" or \"profile_torque\" (the gateway maps 0x6071 then) to use {to}"
            )));
        }
        if let Some(op) = &self.op {
            return Err(CommandError::Busy(format!(
                "the axis is busy ({}): the mode changes only at rest; stop it and wait for the \
                 stop to end",
                op.kind
            )));
        }
        if self.moving() {
            let unit = &self.cfg.motion.unit;
            return Err(CommandError::Busy(format!(
                "the axis is moving ({:.3} {unit}/s): the mode changes only at rest; stop it first",
                self.units().from_counts(f64::from(self.velocity))
            )));
        }
        Ok(())
    }

    /// The modes the drive supports (0x6502, read at its boot): a mode
    /// change to another one is refused.
    pub fn set_supported_modes(&mut self, mask: u32) {
        self.supported_modes = Some(mask);
    }

    /// The mode the axis runs in now.
    pub fn mode(&self) -> DriveMode {
        self.mode
    }

    /// Starts (or changes) the torque of a torque command: the halt is
    /// released and 0x6071 sent.
    fn start_torque(&mut self, op: &mut Op, per_mille: f64, out: &mut Vec<Output>) {
        self.image.target_torque = per_mille.round().clamp(-32768.0, 32767.0) as i16;
        self.image.controlword &= !Controlword::HALT_BIT;
        op.step = Step::Torque;
        op.arm(None);
        self.send_image(out);
        if !op.accepted {
            op.accepted = true;
            out.push(Output::Event(AxisEvent::Accepted { op: op.id }));
        }
    }

    /// A torque command runs until the velocity exceeds the axis's maximum
    /// velocity: then the axis stops (halt on its stop deceleration), so
    /// that an unloaded axis under torque cannot run away.
    fn torque_guard(&mut self, op: &mut Op, now: Duration, out: &mut Vec<Output>) {
        let v = self.units().from_counts(f64::from(self.velocity));
        let max = self.cfg.motion.max_velocity;
        let unit = &self.cfg.motion.unit;
        // Where a stop from here would end, braking at the stop
        // deceleration, plus a feedback period's travel at this velocity
        // (10 ms: the SYNC period of the slowest usual bus).
        let at = self.actual();
        let decel = self.cfg.motion.stop_deceleration.max(f64::MIN_POSITIVE);
        let reach = at + v * v.abs() / (2.0 * decel) + v * 0.01;
        let beyond = match (self.cfg.motion.min_position, self.cfg.motion.max_position) {
            (_, Some(hi)) if v > 0.0 && reach >= hi => Some(("max_position", hi)),
            (Some(lo), _) if v < 0.0 && reach <= lo => Some(("min_position", lo)),
            _ => None,
        };
        op.guard = if v.abs() > max {
            Some(format!(
                "the velocity {v:.3} {unit}/s exceeded max_velocity {max} {unit}/s under \
                 torque: stopped"
            ))
        } else if let Some((name, limit)) = beyond {
            Some(format!(
                "under torque at {at:.3} {unit} and {v:.3} {unit}/s the axis would pass its \
                 soft limit {name} = {limit} {unit}: stopped"
            ))
        } else {
            return;
        };
        op.step = Step::Stopping;
        self.start_stop(now, op, out);
        self.send_image(out);
    }

    fn check_limits(&self, target: f64) -> Result<(), CommandError> {
        crate::checks::soft_limits(
            target,
            self.cfg.motion.min_position,
            self.cfg.motion.max_position,
            &self.cfg.motion.unit,
        )
    }

    fn prepare_enable(&mut self) {
        // Enable in the position mode, holding the current position: a
        // cyclic drive follows 0x607A from the first enabled cycle.
        let mode = self.mode_for_position();
        self.set_mode(mode);
        self.drop_trajectory();
        self.demand = self.actual();
        self.demand_velocity = 0.0;
        self.demand_at = None;
        self.last_target = self.demand;
        self.image.target_position = self.position.unwrap_or_default();
        self.image.target_velocity = 0;
        self.image.target_torque = 0;
    }

    /// In interpolated position controlword bit 4 (enable ip mode) stays
    /// set whatever clears the set-point bit of the other modes.
    fn keep_ip_enabled(&mut self) {
        if self.image.mode == ModeOfOperation::InterpolatedPosition.code() {
            self.image.controlword |= Controlword::NEW_SET_POINT_BIT;
        }
    }

    fn set_mode(&mut self, mode: ModeOfOperation) {
        if self.image.mode != mode.code() {
            // Interpolated position runs while controlword bit 4 (enable
            // ip mode) is set: set entering it, cleared leaving it.
            let ip = ModeOfOperation::InterpolatedPosition;
            if mode == ip {
                self.image.controlword |= Controlword::NEW_SET_POINT_BIT;
            } else if self.image.mode == ip.code() {
                self.image.controlword &= !Controlword::NEW_SET_POINT_BIT;
            }
            self.image.mode = mode.code();
            self.mode_pending = true;
            self.image_changed();
        }
    }

    /// The drive runs in `mode`, as requested: a display that shows it
    /// counts only from the second statusword after the request (the
    /// first may have left before the drive saw it).
    fn mode_is(&self, mode: ModeOfOperation) -> bool {
        // Without 0x6061 in the process data the mode is taken as applied.
        self.image.mode == mode.code()
            && !self.mode_pending
            && self.mode_display.is_none_or(|m| m == mode.code())
    }

    fn image_changed(&mut self) {
        self.fresh = 0;
    }

    /// Asks for the profile velocity/acceleration (user units) unless the
    /// drive holds them already.
    fn want_profile(&mut self, v: f64, a: f64, out: &mut Vec<Output>) {
        let u = self.units();
        let a = u.to_counts_unsigned(a);
        self.want_profile_counts((u.to_counts_unsigned(v), a, a), out);
    }

    /// A stop on the drive's own ramp (halt, quick stop) brakes at least at
    /// `decel` (user units/s²): 0x6084 is raised to it (first of the
    /// writes; never lowered below the deceleration of the interrupted
    /// motion). The controlword that stops goes out as a PDO and does not
    /// wait for them.
    fn want_stop_ramp(&mut self, decel: f64, out: &mut Vec<Output>) {
        let u = self.units();
        let base = self
            .profile_wanted
            .or(self.profile_written)
            .unwrap_or_else(|| {
                let a = u.to_counts_unsigned(self.cfg.motion.default_acceleration);
                (u.to_counts_unsigned(self.cfg.motion.default_velocity), a, a)
            });
        let d = u.to_counts_unsigned(decel).max(base.2);
        self.want_profile_counts((base.0, base.1, d), out);
    }

    fn want_profile_counts(&mut self, want: ProfileCounts, out: &mut Vec<Output>) {
        self.profile_wanted = Some(want);
        if self.profile_written == Some(want) || self.sdo_in_flight == Some(want) {
            return;
        }
        if self.sdo_in_flight.is_some() {
            // The writes in flight are for an older command; this one
            // writes after them (see on_sdo_done).
            self.profile_written = None;
            return;
        }
        self.sdo_in_flight = Some(want);
        // The deceleration first: a stop's ramp takes effect soonest.
        let axis = self.cfg.drive_axis;
        out.push(Output::SdoWrites(vec![
            (
                on_axis(obj::PROFILE_DECELERATION, axis),
                want.2.to_le_bytes().to_vec(),
            ),
            (
                on_axis(obj::PROFILE_VELOCITY, axis),
                want.0.to_le_bytes().to_vec(),
            ),
            (
                on_axis(obj::PROFILE_ACCELERATION, axis),
                want.1.to_le_bytes().to_vec(),
            ),
        ]));
    }

    fn wanted_profile(&self, op: &Op) -> (f64, f64) {
        match op.command {
            AxisCommand::Move {
                velocity,
                acceleration,
                ..
            } => (
                velocity.unwrap_or(self.cfg.motion.default_velocity),
                acceleration.unwrap_or(self.cfg.motion.default_acceleration),
            ),
            AxisCommand::Jog {
                velocity,
                acceleration,
            } => (
                velocity.abs(),
                acceleration.unwrap_or(self.cfg.motion.default_acceleration),
            ),
            _ => (
                self.cfg.motion.default_velocity,
                self.cfg.motion.default_acceleration,
            ),
        }
    }

    fn retarget_jog(
        &mut self,
        velocity: f64,
        acceleration: Option<f64>,
        now: Duration,
        out: &mut Vec<Output>,
    ) -> Result<(), CommandError> {
        let a = acceleration.unwrap_or(self.cfg.motion.default_acceleration);
        if let Some(op) = &mut self.op {
            op.command = AxisCommand::Jog {
                velocity,
                acceleration,
            };
        }
        match self.position_mode() {
            PositionMode::Cyclic => {
                let Some(mut op) = self.op.take() else {
                    return Ok(());
                };
                let r = self.plan_jog(&mut op, out);
                self.op = Some(op);
                r?;
            }
            PositionMode::Profile => {
                self.want_profile(velocity.abs(), a, out);
                self.image.target_velocity = self.units().to_counts(velocity);
                self.image.controlword &= !Controlword::HALT_BIT;
                self.set_mode(ModeOfOperation::ProfileVelocity);
                if let Some(op) = &mut self.op
                    && !matches!(op.step, Step::Jogging)
                {
                    op.step = Step::AwaitSdo;
                    op.arm(Some(now + self.cfg.motion.state_timeout));
                }
                if matches!(self.op.as_ref().map(|o| &o.step), Some(Step::Jogging)) {
                    out.push(Output::Image(self.image));
                }
            }
        }
        Ok(())
    }

    /// The deceleration of a stop: the configured stop deceleration, or the
    /// running trajectory's when that brakes harder.
    fn stop_deceleration(&self) -> f64 {
        stop_deceleration(self.cfg.motion.stop_deceleration, self.trajectory.as_ref())
    }

    fn start_stop(&mut self, now: Duration, op: &mut Op, out: &mut Vec<Output>) {
        match self.position_mode() {
            PositionMode::Cyclic if self.in_cyclic_mode() => {
                let decel = self.stop_deceleration();
                self.trajectory =
                    Trajectory::stop_ramp(self.demand, self.demand_velocity, decel, self.demand_at);
                let t = self.trajectory.as_ref().map_or(0.0, Trajectory::duration);
                op.arm(Some(
                    now + Duration::from_secs_f64(t) + self.cfg.motion.settle_timeout,
                ));
            }
            _ => {
                // In the torque modes too: the drive brakes on its halt
                // ramp with its own velocity loop (the gateway has none
                // there), and stays in operation enabled. The torque
                // set-point drops to 0 so that releasing the halt later
                // does not start the axis again.
                self.image.controlword |= Controlword::HALT_BIT;
                self.image.target_velocity = 0;
                self.image.target_torque = 0;
                op.arm(Some(
                    now + self.cfg.motion.state_timeout + self.cfg.motion.settle_timeout,
                ));
                // The halt brakes on 0x6084 (halt option code 0x605D = 1,
                // the default): raised to the stop deceleration. The halt
                // itself does not wait for the write.
                self.want_stop_ramp(self.cfg.motion.stop_deceleration, out);
            }
        }
    }

    fn finish(&mut self, outcome: Outcome, detail: String, out: &mut Vec<Output>) {
        if let Some(op) = self.op.take() {
            if matches!(op.kind, CommandKind::Jog) {
                self.jog_deadline = None;
            }
            if op.kind == CommandKind::Torque && self.image.target_torque != 0 {
                // No torque outlives its command (superseded by a homing
                // at rest, say, it would come back with the torque mode).
                self.image.target_torque = 0;
                self.send_image(out);
            }
            // An interrupted homing says what it leaves behind.
            let detail = if op.kind == CommandKind::Home && outcome != Outcome::Completed {
                let homing = match op.step {
                    Step::SettleFor(_) => "homing did not start",
                    _ => "homing interrupted",
                };
                if self.homed {
                    format!("{detail}: {homing}; the earlier homing reference stays")
                } else {
                    format!("{detail}: {homing}; the axis is not homed")
                }
            } else {
                detail
            };
            out.push(Output::Event(AxisEvent::Done {
                op: op.id,
                command: op.kind,
                outcome,
                detail,
            }));
        }
    }

    fn send_image(&mut self, out: &mut Vec<Output>) {
        self.image_changed();
        out.push(Output::Image(self.image));
    }

    /// Moves the command in progress forward.
    fn advance(&mut self, now: Duration, out: &mut Vec<Output>) {
        // The dead-man of a jog.
        if let Some(d) = self.jog_deadman_due()
            && now >= d
        {
            self.jog_deadline = None;
            if let Some(op) = &self.op
                && op.kind == CommandKind::Jog
            {
                let mut op = self.op.take().expect("op");
                op.step = Step::Stopping;
                self.start_stop(now, &mut op, out);
                self.op = Some(op);
                if self.position_mode() == PositionMode::Profile {
                    self.send_image(out);
                }
            }
        }
        let Some(mut op) = self.op.take() else {
            return;
        };
        let result = self.step(&mut op, now, out);
        match result {
            None => self.op = Some(op),
            Some((outcome, detail)) => {
                self.op = Some(op);
                self.finish(outcome, detail, out);
            }
        }
    }

    /// One step of `op`; `Some` when it ended. Progress is judged first,
    /// from the latest feedback; a deadline only then, and only once the
    /// drive has been heard from after it ([`LATE_FEEDBACK`]) or its grace
    /// ran out without any feedback.
    fn step(
        &mut self,
        op: &mut Op,
        now: Duration,
        out: &mut Vec<Output>,
    ) -> Option<(Outcome, String)> {
        if !op.settling
            && matches!(op.step, Step::CyclicMoving | Step::Stopping)
            && self.trajectory.is_none()
            && self.in_cyclic_mode()
        {
            // The trajectory ended (however late the host ran it): the
            // drive gets its settle time from here.
            op.settling = true;
            op.arm(Some(now + self.cfg.motion.settle_timeout));
        }
        if let Some(r) = self.progress(op, now, out) {
            return Some(r);
        }
        let d = op.deadline?;
        if now < d || matches!(op.step, Step::Switch(_) | Step::Jogging) {
            return None;
        }
        op.overdue = true;
        if op.late_feedback < LATE_FEEDBACK && now < d + self.deadline_grace() {
            return None;
        }
        if matches!(op.step, Step::CyclicMoving) && self.in_position(op.target) {
            // The drive stands at the target although the trajectory's last
            // sample never came back to this axis (a SYNC thread held back
            // by skipped periods finished its copy of the plan, and a
            // republished plan replaced the sample): the move is done.
            self.drop_trajectory();
            return Some((
                Outcome::Completed,
                format!(
                    "target reached at {:.3} {}",
                    self.actual(),
                    self.cfg.motion.unit
                ),
            ));
        }
        let unit = &self.cfg.motion.unit;
        let what = match op.step {
            Step::AwaitSdo => "the profile parameters were not written in time".to_string(),
            Step::AwaitMode(m) => format!(
                "the drive did not switch to {m} mode within {} ms",
                self.cfg.motion.state_timeout.as_millis()
            ),
            Step::AwaitAck => "the drive did not acknowledge the set-point".to_string(),
            Step::Homing => "homing did not complete in time".to_string(),
            Step::SettleFor(_) => format!(
                "the drive did not come to rest in time (at {:.3} {unit}, {:.3} {unit}/s)",
                self.actual(),
                self.units().from_counts(f64::from(self.velocity))
            ),
            Step::Stopping => format!(
                "not at rest in time: at {:.3} {unit}, {:.3} {unit}/s",
                self.actual(),
                self.units().from_counts(f64::from(self.velocity))
            ),
            _ => format!(
                "not in position in time: at {:.3} {unit}, target {:.3} {unit}",
                self.actual(),
                op.target
            ),
        };
        // The next command starts from bit 4 low.
        self.release_handshake(out);
        Some((Outcome::Timeout, what))
    }

    /// How long a deadline waits for the drive's feedback after it passed
    /// before it fails without any.
    fn deadline_grace(&self) -> Duration {
        self.cfg.motion.state_timeout + self.cfg.motion.settle_timeout
    }

    /// Moves `op` forward on the latest feedback; `Some` when it ended.
    /// Each step of a command has its own function below; a step that
    /// hands over to the next one at once (`Flow::Again`) is run again.
    fn progress(
        &mut self,
        op: &mut Op,
        now: Duration,
        out: &mut Vec<Output>,
    ) -> Option<(Outcome, String)> {
        loop {
            let flow = match &op.step {
                Step::Switch(_) => Flow::Done(self.switch_step(op, now, out)),
                Step::AwaitSdo => self.await_profile_sdo(op, out),
                Step::AwaitMode(mode) => {
                    let mode = *mode;
                    Flow::Done(self.mode_reached(op, mode, now, out))
                }
                Step::AwaitAck => Flow::Done(self.set_point_acknowledged(op, now, out)),
                Step::ProfileMoving => Flow::Done(self.profile_target_reached()),
                Step::SettleFor(mode) => {
                    let mode = *mode;
                    self.settled_for(op, mode, now, out)
                }
                Step::CyclicMoving => Flow::Done(self.cyclic_target_reached(op)),
                Step::Homing => Flow::Done(self.homing_step(op, now, out)),
                Step::HomingReturn => Flow::Done(self.homing_returned()),
                Step::Jogging => Flow::Done(None),
                Step::Torque => {
                    self.torque_guard(op, now, out);
                    if matches!(op.step, Step::Stopping) {
                        Flow::Again
                    } else {
                        Flow::Done(None)
                    }
                }
                Step::Stopping => Flow::Done(self.stop_finished(op)),
            };
            match flow {
                Flow::Again => {}
                Flow::Done(ended) => return ended,
            }
        }
    }

    /// Walking the drive's state machine (enable, disable, reset fault).
    fn switch_step(
        &mut self,
        op: &mut Op,
        now: Duration,
        out: &mut Vec<Output>,
    ) -> Option<(Outcome, String)> {
        let Step::Switch(driver) = &mut op.step else {
            return None;
        };
        if driver.target() == DriveState::OperationEnabled
            && self.state() != Some(DriveState::OperationEnabled)
            && self.position_mode() == PositionMode::Cyclic
        {
            // Until the drive is enabled it may still move (a
            // quick stop's ramp): it holds where it stands
            // when enabled, not where it stood at the command.
            self.demand = self.actual();
            self.image.target_position = self.position.unwrap_or_default();
        }
        let step = match self.statusword {
            Some(sw) if self.fresh > 0 || driver.statusword().is_none() => {
                self.fresh = 0;
                driver.on_statusword(sw, now)
            }
            _ => driver.on_tick(now),
        };
        match step {
            DriverStep::Send(cw) => {
                self.image.controlword =
                    (self.image.controlword & !Controlword::COMMAND_MASK) | cw.bits();
                self.send_image(out);
                None
            }
            DriverStep::Wait => None,
            DriverStep::Done(Ok(())) => {
                let state = driver.target();
                Some((Outcome::Completed, format!("drive in {state}")))
            }
            DriverStep::Done(Err(e)) => Some((Outcome::Timeout, e.to_string())),
        }
    }

    /// A profile move or jog: the profile velocity and acceleration
    /// written by SDO first, then the mode.
    fn await_profile_sdo(&mut self, op: &mut Op, out: &mut Vec<Output>) -> Flow {
        let (v, a) = self.wanted_profile(op);
        let u = self.units();
        let a_counts = u.to_counts_unsigned(a);
        let want = (u.to_counts_unsigned(v), a_counts, a_counts);
        if self.profile_written == Some(want) {
            let mode = match op.kind {
                CommandKind::Jog => ModeOfOperation::ProfileVelocity,
                _ => ModeOfOperation::ProfilePosition,
            };
            op.step = Step::AwaitMode(mode);
            if !self.mode_is(mode) {
                // Switch modes first; the set-point follows
                // once the drive displays the new mode.
                self.send_image(out);
            }
            return Flow::Again;
        }
        if self.sdo_in_flight.is_none() {
            self.want_profile(v, a, out);
        }
        Flow::Done(None)
    }

    /// The drive displays the mode the command needs: start it.
    fn mode_reached(
        &mut self,
        op: &mut Op,
        mode: ModeOfOperation,
        now: Duration,
        out: &mut Vec<Output>,
    ) -> Option<(Outcome, String)> {
        if !self.mode_is(mode) {
            return None;
        }
        if let AxisCommand::SetMode { .. } = op.command {
            // A mode change ends when the drive shows the new mode.
            return Some((
                Outcome::Completed,
                format!("drive in {} mode ({mode})", self.mode),
            ));
        }
        match mode {
            ModeOfOperation::ProfilePosition => {
                self.image.target_position = self.units().to_counts(op.target);
                self.image.controlword =
                    (self.image.controlword & !Controlword::HALT_BIT & !Controlword::RELATIVE_BIT)
                        | Controlword::NEW_SET_POINT_BIT
                        | Controlword::CHANGE_SET_IMMEDIATELY_BIT;
                self.send_image(out);
                op.step = Step::AwaitAck;
                op.arm(Some(now + self.cfg.motion.state_timeout));
                None
            }
            ModeOfOperation::ProfileVelocity => {
                op.step = Step::Jogging;
                op.arm(None);
                self.send_image(out);
                if !op.accepted {
                    op.accepted = true;
                    out.push(Output::Event(AxisEvent::Accepted { op: op.id }));
                }
                None
            }
            ModeOfOperation::CyclicSynchronousPosition
            | ModeOfOperation::CyclicSynchronousVelocity
            | ModeOfOperation::InterpolatedPosition => {
                let planned = match op.command {
                    AxisCommand::Jog { .. } => self.plan_jog(op, out),
                    _ => self.plan_move(op, now, out),
                };
                match planned {
                    Ok(()) => None,
                    Err(e) => Some((Outcome::Fault, e.to_string())),
                }
            }
            ModeOfOperation::CyclicSynchronousTorque | ModeOfOperation::ProfileTorque => {
                if let AxisCommand::SetTorque { per_mille } = op.command {
                    self.start_torque(op, per_mille, out);
                }
                None
            }
            ModeOfOperation::Homing => {
                self.image.controlword |= Controlword::HOMING_START_BIT;
                self.send_image(out);
                op.step = Step::Homing;
                op.arm(Some(now + self.cfg.motion.homing_timeout));
                op.accepted = true;
                out.push(Output::Event(AxisEvent::Accepted { op: op.id }));
                None
            }
        }
    }

    /// A profile move's new set-point acknowledged by the drive.
    fn set_point_acknowledged(
        &mut self,
        op: &mut Op,
        now: Duration,
        out: &mut Vec<Output>,
    ) -> Option<(Outcome, String)> {
        let sw = self.statusword?;
        if !sw.set_point_acknowledge() {
            return None;
        }
        self.image.controlword &= !Controlword::NEW_SET_POINT_BIT;
        self.send_image(out);
        op.accepted = true;
        out.push(Output::Event(AxisEvent::Accepted { op: op.id }));
        op.step = Step::ProfileMoving;
        let dist = (op.target - self.actual()).abs();
        let (v, a) = self.wanted_profile(op);
        let est = Limits::symmetric(v, a)
            .ok()
            .and_then(|l| TrapezoidProfile::rest_to_rest(0.0, dist, l).ok())
            .map_or(0.0, |p| p.duration());
        op.arm(Some(
            now + Duration::from_secs_f64(est.min(1e6)) + self.cfg.motion.settle_timeout,
        ));
        None
    }

    /// A profile move ends when the drive reports the target reached.
    fn profile_target_reached(&self) -> Option<(Outcome, String)> {
        let unit = &self.cfg.motion.unit;
        let fresh = self.fresh >= 2;
        let sw = self.statusword?;
        if fresh && !sw.set_point_acknowledge() && sw.target_reached() {
            return Some((
                Outcome::Completed,
                format!("target reached at {:.3} {unit}", self.actual()),
            ));
        }
        None
    }

    /// Waiting for the axis to stand still before it changes mode.
    fn settled_for(
        &mut self,
        op: &mut Op,
        mode: ModeOfOperation,
        now: Duration,
        out: &mut Vec<Output>,
    ) -> Flow {
        let fresh = self.fresh >= 2;
        if self.trajectory.is_some() || !fresh || !self.at_rest() {
            return Flow::Done(None);
        }
        self.begin_mode(mode, now, op, out);
        Flow::Again
    }

    /// A cyclic move ends when its trajectory ended and the drive is in
    /// position.
    fn cyclic_target_reached(&self, op: &Op) -> Option<(Outcome, String)> {
        let unit = &self.cfg.motion.unit;
        let fresh = self.fresh >= 2;
        if self.trajectory.is_none() && fresh && self.in_position(op.target) {
            return Some((
                Outcome::Completed,
                format!("target reached at {:.3} {unit}", self.actual()),
            ));
        }
        None
    }

    /// The drive's homing method runs.
    fn homing_step(
        &mut self,
        op: &mut Op,
        now: Duration,
        out: &mut Vec<Output>,
    ) -> Option<(Outcome, String)> {
        let fresh = self.fresh >= 2;
        let sw = self.statusword?;
        if !fresh {
            return None;
        }
        match sw.homing_status() {
            HomingStatus::Completed => {
                self.homed = true;
                self.image.controlword &= !Controlword::HOMING_START_BIT;
                // Back to the position mode, holding the new
                // position.
                self.demand = self.actual();
                self.demand_velocity = 0.0;
                self.demand_at = None;
                self.last_target = self.demand;
                self.image.target_position = self.position.unwrap_or_default();
                self.set_mode(self.mode_for_position());
                self.send_image(out);
                op.step = Step::HomingReturn;
                op.arm(Some(now + self.cfg.motion.state_timeout));
                None
            }
            HomingStatus::ErrorMoving | HomingStatus::ErrorStopped => {
                self.image.controlword &= !Controlword::HOMING_START_BIT;
                self.send_image(out);
                Some((
                    Outcome::Fault,
                    format!("homing error reported by the drive (statusword {sw})"),
                ))
            }
            _ => None,
        }
    }

    /// Homed, and back in the position mode.
    fn homing_returned(&self) -> Option<(Outcome, String)> {
        let unit = &self.cfg.motion.unit;
        let fresh = self.fresh >= 2;
        let mode = self.mode_for_position();
        if self.mode_is(mode) && fresh {
            return Some((
                Outcome::Completed,
                format!("homed at {:.3} {unit}", self.actual()),
            ));
        }
        None
    }

    /// A stop (or a jog's dead-man stop) ends with the axis at rest.
    fn stop_finished(&self, op: &Op) -> Option<(Outcome, String)> {
        let unit = &self.cfg.motion.unit;
        let fresh = self.fresh >= 2;
        let done = match op.kind {
            // Out of operation enabled (quick stop active,
            // switch on disabled, a fault) and standing still.
            CommandKind::QuickStop => {
                fresh && self.state() != Some(DriveState::OperationEnabled) && self.at_rest()
            }
            _ => match self.position_mode() {
                // In CSV the drive integrates the velocity itself: its
                // position may differ from the gateway's demand by a
                // rounding; at rest after the ramp is the end.
                PositionMode::Cyclic
                    if self.in_cyclic_mode() && self.mode == DriveMode::CyclicVelocity =>
                {
                    self.trajectory.is_none() && fresh && self.at_rest()
                }
                PositionMode::Cyclic if self.in_cyclic_mode() => {
                    self.trajectory.is_none() && fresh && self.in_position(self.demand)
                }
                _ => fresh && self.at_rest(),
            },
        };
        // A drive that left operation enabled (fault
        // reaction, disabled) is done when it stands still.
        if done
            || self.state() != Some(DriveState::OperationEnabled)
                && fresh
                && self.at_rest()
                && op.kind != CommandKind::QuickStop
        {
            let outcome = if matches!(op.kind, CommandKind::Jog | CommandKind::Torque) {
                Outcome::Stopped
            } else {
                Outcome::Completed
            };
            let detail = if let Some(guard) = &op.guard {
                format!("{guard}; at rest at {:.3} {unit}", self.actual())
            } else if op.kind == CommandKind::Jog {
                format!(
                    "jog dead-man released; at rest at {:.3} {unit}",
                    self.actual()
                )
            } else {
                format!("at rest at {:.3} {unit}", self.actual())
            };
            return Some((outcome, detail));
        }
        None
    }
}

/// EMCY code of a following error (CiA 402).
const FOLLOWING_ERROR_CODE: u16 = 0x8611;

/// The signals beyond position and velocity: torque, digital inputs (limit
/// switches), touch probe, following error (see [`crate::signals`]).
impl Cia402Axis {
    /// Takes the signals of one process data update: latches of the touch
    /// probe become events, the limit switches are watched.
    fn on_signals(&mut self, fb: &Feedback, out: &mut Vec<Output>) {
        if let Some(t) = fb.torque {
            self.signals.torque = Some(t);
        }
        if let Some(d) = fb.digital_inputs {
            self.signals.digital_inputs = Some(d);
        }
        if let Some(st) = fb.touch_probe_status {
            self.signals.touch_probe_status = Some(st);
        }
        let u = self.units();
        for (rising, counts) in self.probe.on_feedback(
            fb.touch_probe_status,
            fb.touch_probe_positive,
            fb.touch_probe_negative,
        ) {
            out.push(Output::Event(AxisEvent::TouchProbe {
                rising,
                position: u.from_counts(f64::from(counts)),
            }));
        }
        if let Some(fe) = self.current_following_error()
            && fe.abs() > self.following_error_peak
        {
            self.following_error_peak = fe.abs();
            // The drive faults between two process data updates: the error
            // it reports after the fault says by how much; the fault says
            // it again with that.
            if let Some((FOLLOWING_ERROR_CODE, text)) = &self.emcy {
                let now_text = self.following_error_text();
                if *text != now_text {
                    self.emcy = Some((FOLLOWING_ERROR_CODE, now_text.clone()));
                    if self.fault_reported {
                        out.push(Output::Event(AxisEvent::Fault {
                            code: FOLLOWING_ERROR_CODE,
                            text: now_text,
                        }));
                    }
                }
            }
        }
        if fb.digital_inputs.is_some() {
            self.on_limit_switches(out);
        }
        self.rebase_after_limit_stop();
    }

    /// The following error: the drive's 0x60F4, else demand − actual of a
    /// cyclic axis.
    fn current_following_error(&self) -> Option<f64> {
        match (self.drive_following_error, self.position_mode()) {
            (Some(fe), _) => Some(self.units().from_counts(f64::from(fe))),
            (None, PositionMode::Cyclic) if self.position.is_some() => {
                Some(self.demand - self.actual())
            }
            _ => None,
        }
    }

    /// What a following error fault (EMCY 0x8611) says.
    fn following_error_text(&self) -> String {
        let unit = &self.cfg.motion.unit;
        let peak = self.following_error_peak;
        match self.cfg.supervision.following_error_window {
            Some(w) if peak > w => {
                format!("following error beyond the window ({peak:.3} {unit} > {w:.3} {unit})")
            }
            Some(w) => format!(
                "following error beyond the window of {w:.3} {unit} (largest reported {peak:.3} {unit})"
            ),
            None => format!(
                "following error beyond the drive's window (largest reported {peak:.3} {unit})"
            ),
        }
    }

    /// A limit switch became active or inactive (reported as the axis's
    /// fault while active), or the axis moves into an active one: it stops
    /// at the quick stop deceleration.
    fn on_limit_switches(&mut self, out: &mut Vec<Output>) {
        let active = self.signals.limit_switch();
        if active != self.limit_reported {
            self.limit_reported = active;
            // A drive fault or a lost node stays what the axis reports.
            if self.node_lost.is_none() && !self.is_fault() {
                out.push(Output::Event(AxisEvent::Fault {
                    code: 0,
                    text: active.map(LimitSwitch::reached).unwrap_or_default(),
                }));
            }
        }
        let Some(sw) = active else {
            return;
        };
        if self.limit_stop == Some(sw)
            || self.state() != Some(DriveState::OperationEnabled)
            || self.node_lost.is_some()
        {
            return;
        }
        // Homing methods use the limit switches as their reference; the
        // other state changes do not move the axis.
        if self.op.as_ref().is_some_and(|o| {
            matches!(
                o.kind,
                CommandKind::Home
                    | CommandKind::Enable
                    | CommandKind::Disable
                    | CommandKind::ResetFault
                    | CommandKind::QuickStop
            )
        }) {
            return;
        }
        if self.moving_into(sw) {
            self.stop_at_limit_switch(sw, out);
        }
    }

    /// Whether the drive, the demand or the command in progress heads into
    /// limit switch `sw`.
    fn moving_into(&self, sw: LimitSwitch) -> bool {
        let u = self.units();
        let drive = !self.at_rest() && sw.is_into(u.from_counts(f64::from(self.velocity)), u);
        let demand = sw.is_into(self.demand_velocity, u)
            || self
                .trajectory
                .as_ref()
                .is_some_and(|t| sw.is_into(t.profile.target() - self.demand, u));
        let command = self.op.as_ref().is_some_and(|o| match o.command {
            AxisCommand::Move { .. } if self.position_mode() == PositionMode::Profile => {
                sw.is_into(o.target - self.actual(), u)
            }
            AxisCommand::Jog { velocity, .. } => sw.is_into(velocity, u),
            _ => false,
        });
        drive || demand || command
    }

    /// Stops the axis at its quick stop deceleration, the drive staying
    /// enabled (so that it can be moved off the switch): a move or jog ends
    /// with outcome FAULT saying so; a stop in progress goes on.
    fn stop_at_limit_switch(&mut self, sw: LimitSwitch, out: &mut Vec<Output>) {
        self.limit_stop = Some(sw);
        self.jog_deadline = None;
        let unit = &self.cfg.motion.unit;
        let detail = format!("{} at {:.3} {unit}", sw.reached(), self.actual());
        if self
            .op
            .as_ref()
            .is_some_and(|o| matches!(o.kind, CommandKind::Move | CommandKind::Jog))
        {
            self.finish(Outcome::Fault, detail, out);
        }
        let decel = self.cfg.motion.quick_stop_deceleration;
        if self.position_mode() == PositionMode::Cyclic && self.in_cyclic_mode() {
            let decel = stop_deceleration(decel, self.trajectory.as_ref());
            self.trajectory =
                Trajectory::stop_ramp(self.demand, self.demand_velocity, decel, self.demand_at);
        } else {
            self.image.controlword |= Controlword::HALT_BIT;
            self.image.target_velocity = 0;
            self.want_stop_ramp(decel, out);
            self.send_image(out);
        }
    }

    /// A cyclic axis stopped by a limit switch: once its ramp ended and the
    /// drive stands, the demand is where the drive stands (the drive did
    /// not follow the set-points into the switch).
    fn rebase_after_limit_stop(&mut self) {
        if self.limit_stop.is_none()
            || self.position_mode() != PositionMode::Cyclic
            || !self.in_cyclic_mode()
            || self.trajectory.is_some()
            || !self.at_rest()
        {
            return;
        }
        self.limit_stop = None;
        self.demand = self.actual();
        self.demand_velocity = 0.0;
        self.last_target = self.demand;
        self.image.target_position = self.position.unwrap_or_default();
    }

    /// A motion by `delta` (user units, its sign the direction) must not
    /// head into an active limit switch.
    fn check_not_into_limit_switch(&self, delta: f64) -> Result<(), CommandError> {
        let u = self.units();
        for sw in [LimitSwitch::Negative, LimitSwitch::Positive] {
            if self.signals.is_active(sw) && sw.is_into(delta, u) {
                let unit = &self.cfg.motion.unit;
                return Err(CommandError::BeyondSoftLimit(format!(
                    "the {} limit switch is active (the axis is at {:.3} {unit}): it can only move away from it",
                    sw.name(),
                    self.actual()
                )));
            }
        }
        Ok(())
    }
}

/// What a step of a command did: ended it (or not yet: `None`), or
/// handed over to the next step, which runs at once.
enum Flow {
    Done(Option<(Outcome, String)>),
    Again,
}

#[cfg(test)]
mod tests;
