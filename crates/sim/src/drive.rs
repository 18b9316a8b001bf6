//! [`SimDrive`]: a simulated CiA 402 servo drive.
//!
//! The drive wraps a [`SimNode`] built from the drive EDS (by default the
//! bundled `cangate-drive.eds`), which serves SDO, NMT, heartbeat, SYNC,
//! EMCY and the PDOs, and adds a drive model stepped at fixed intervals (1 ms
//! by default) while the drive is enabled or moving:
//!
//! | feature | behaviour |
//! |---|---|
//! | state machine | driven by 0x6040 written over SDO or RPDO, evaluated on every write and model step; reflected in 0x6041; transitions 2..=12, 15, 16 (16 only with quick stop option code 5..=8); leaving operation enabled (5, 8, 9) stops the motor at once |
//! | statusword | state bits, bit 4 voltage enabled while the power stage is on (switched on, operation enabled, quick stop active, and fault reaction active when entered from those), bit 9 remote always set, bits 10..=13 per mode; a change triggers every event-driven TPDO that maps 0x6041 |
//! | profile position (1) | new set-point handshake (bit 4 rising edge accepts 0x607A, bit 12 set-point acknowledge until bit 4 falls), one buffered set-point, change set immediately (bit 5), relative (bit 6, to the previous target), halt (bit 8), trapezoidal profile with 0x6081/0x6083/0x6084, target reached (bit 10) |
//! | profile velocity (3) | ramps to 0x60FF with 0x6083 (faster) / 0x6084 (slower); bit 10 at the target velocity, bit 12 at speed 0; halt ramps to 0 |
//! | homing (6) | bit 4 rising edge starts 0x6098: 35/37 set the position to 0x607C home offset at once; 17..=30 move at 0x6099:01 with 0x609A to a virtual switch at the physical position 0, then set the position to the home offset; any other method ends in homing error (bit 13); bit 4 falling or halt interrupts |
//! | cyclic synchronous torque (10) / profile torque (4) | the torque model: the motor torque (0x6071 at once in CST; ramped towards it at 0x6087 per mille/s in profile torque) minus viscous and Coulomb friction accelerates the inertia ([`TorqueModel`]), integrated at the model step (torque → acceleration → velocity → position), at most 0x6072 max torque when present; halt (bit 8) brakes on 0x6084 with the drive's own velocity loop and holds; 0x6077 is the motor torque; bit 12 (CST: target torque followed) / bit 10 (profile torque: torque reached) |
//! | interpolated position (7) | with controlword bit 4 (enable ip mode) set, each new 0x60C1:01 is reached by linear interpolation over the interpolation time period 0x60C2 (value · 10^index s), then followed with the first-order lag; bit 12 ip mode active |
//! | supported modes | 0x6502 as the EDS says (PP, PV, PT, HM, IP, CSP, CSV, CST for the bundled one), or [`SimDriveOptions::supported_modes`]: a mode not in it is not taken (0x6061 keeps the mode in effect) |
//! | cyclic synchronous position (8) / velocity (9) | follow 0x607A / 0x60FF (as written by RPDO, at once or at SYNC per the RPDO's transmission type) with a first-order lag; in position mode each new set-point is reached by linear interpolation over the SYNC period (the interval between the latest two SYNCs), as drives interpolate between cyclic set-points, so the motion and 0x606C are smooth, not a step per SYNC; bit 12 set; following error 0x60F4 written when present; with 0x6065 present a following error beyond the window for longer than 0x6066 ms faults with EMCY 0x8611 |
//! | quick stop | decelerates with 0x6085 (0x6084 when absent, or for option codes 1 and 5), then goes to switch on disabled for quick stop option codes 0..=4 (0x605A, default 2) or stays in quick stop active for 5..=8 |
//! | heartbeat loss | a node monitored by 0x1016 falls silent (the master, when it configured its heartbeat there): the node sends EMCY 0x8130, and the drive enters fault reaction active (stops with the quick stop deceleration), then fault, with 0x603F = 0x8130 |
//! | several axes | a CiA 402 multi-axis drive (e.g. `sim_drive_eds_with_axes(2)`): as many axes as the object dictionary has statuswords at 0x6041 + n × 0x800, each with its own state machine and model on its own objects (index + n × 0x800); an NMT reset node and a heartbeat loss act on every axis, [`SimDrive::inject_axis_fault`] on one; the accessors without an axis ([`SimDrive::state`], [`SimDrive::position`], …) are the first axis's |
//! | faults | [`SimDrive::inject_fault`]: fault reaction active (stops with the quick stop deceleration), then fault; 0x603F and 0x1001 set and an EMCY sent; fault reset (rising edge of bit 7) clears them and sends the EMCY "error reset" |
//! | limits | software position limits 0x607D (when min < max) bound every mode but homing: profile position clamps the target, the others stop at the limit; bit 11 internal limit |
//! | feed-forward | velocity offset 0x60B1 and torque offset 0x60B2 (in the bundled EDS, mappable): recorded as written (by RPDO or SDO) and read back; the motion model does not use them |
//! | process values | 0x6064 position, 0x606C velocity and 0x6077 torque (per mille, proportional to the acceleration, bounded by 0x6072 max torque when present) updated every step; TPDOs go out per their configuration (event timer, SYNC) |
//! | switches | [`SimDriveInputs`]: limit and home switches at physical positions set 0x60FD bits 0 (negative limit), 1 (positive limit), 2 (home); in every mode but homing a limit switch stops motion into it at the quick stop deceleration (the drive stays in operation enabled, bit 11 internal limit set) and motion away from it runs; a cyclic position set-point into it is not followed and counts no following error |
//! | touch probe 1 | 0x60B8 bit 0 enables it, bit 1 continuous (else the first edge only), bit 4/5 latch at the rising/falling edge; the input is the physical position crossing [`SimDriveInputs::touch_probe`] (rising upwards), latched exactly at the crossing into 0x60BA/0x60BB; 0x60B9 bit 0 enabled, bit 1/2 positive/negative edge stored; a changed 0x60B8 re-arms (clears bits 1 and 2) |
//!
//! Units are increments, increments/s and increments/s². An NMT reset node
//! restores the object dictionary and restarts the drive in switch on
//! disabled at the same physical position (as with an absolute encoder),
//! with the homing offset cleared.

use std::collections::VecDeque;
use std::time::Duration;

use cangate_can::Frame;
use cangate_canopen::cia402::{
    Controlword, DriveState, MAX_DRIVE_AXES, ModeOfOperation, Statusword, objects as obj, on_axis,
    profile_index,
};
use cangate_canopen::eds::{Eds, SIM_DRIVE_EDS};
use cangate_canopen::emcy::ErrorRegister;
use cangate_canopen::nmt::NmtReset;
use cangate_canopen::od::ObjectDictionary;
use cangate_canopen::value::Value;
use cangate_canopen::{NodeId, ObjectAddress};

use crate::canopen_node::{SimEvent, SimNode, SimNodeOptions};
use crate::{Device, SimError};

/// The first TPDO mapping parameter index.
const TPDO_MAP: u16 = 0x1A00;
/// TPDO mapping parameters looked at for the statusword.
const MAX_TPDOS: u16 = 512;
/// Per mille of rated torque per increment/s² of acceleration.
const TORQUE_PER_ACCEL: f64 = 1.0 / 1000.0;
/// The longest SYNC interval taken as the interpolation period; beyond it
/// a set-point is reached at once.
const MAX_SYNC_PERIOD: Duration = Duration::from_millis(100);
/// EMCY code of a following error.
const FOLLOWING_ERROR_CODE: u16 = 0x8611;

/// The mechanics the torque modes drive: an inertia with viscous and
/// Coulomb friction. Integers, so that the options stay comparable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TorqueModel {
    /// Increments/s² one per mille of net torque gives the inertia (1000
    /// by default: the same scale as 0x6077 in the other modes).
    pub accel_per_permille: u32,
    /// Viscous friction in per mille per 1000 increments/s (1 by
    /// default).
    pub viscous_per_kilo_speed: u32,
    /// Coulomb (dry) friction in per mille (10 by default): a torque below
    /// it does not start the motor at rest.
    pub coulomb: u32,
}

impl Default for TorqueModel {
    fn default() -> Self {
        TorqueModel {
            accel_per_permille: 1000,
            viscous_per_kilo_speed: 1,
            coulomb: 10,
        }
    }
}

impl TorqueModel {
    /// The velocity after `dt` s of motor `torque` (per mille) from `vel`
    /// (increments/s): friction opposes the motion, and at rest holds
    /// the motor until the torque overcomes it; it never reverses the
    /// motion by itself.
    pub fn step(&self, vel: f64, torque: f64, dt: f64) -> f64 {
        let k = f64::from(self.accel_per_permille);
        let coulomb = f64::from(self.coulomb);
        let viscous = f64::from(self.viscous_per_kilo_speed) / 1000.0;
        if vel == 0.0 {
            if torque.abs() <= coulomb {
                return 0.0;
            }
            return (torque - coulomb * torque.signum()) * k * dt;
        }
        let friction = viscous * vel + coulomb * vel.signum();
        let next = vel + (torque - friction) * k * dt;
        if next.signum() != vel.signum() && torque.abs() <= coulomb {
            // Friction brought it to rest within the step.
            return 0.0;
        }
        next
    }
}

/// Switches and the touch probe input of a [`SimDrive`], at physical
/// positions in increments (where the motor is before any homing shift).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SimDriveInputs {
    /// The negative limit switch is active at and below this position.
    pub negative_limit_switch: Option<i32>,
    /// The positive limit switch is active at and above this position.
    pub positive_limit_switch: Option<i32>,
    /// The home switch is active at and above this position.
    pub home_switch: Option<i32>,
    /// The touch probe 1 input is active at and above this position: moving
    /// up across it is its rising edge, down its falling edge.
    pub touch_probe: Option<i32>,
}

/// 0x60FD bit of the negative limit switch (CiA 402-2).
pub const INPUT_NEGATIVE_LIMIT: u32 = 1 << 0;
/// 0x60FD bit of the positive limit switch.
pub const INPUT_POSITIVE_LIMIT: u32 = 1 << 1;
/// 0x60FD bit of the home switch.
pub const INPUT_HOME_SWITCH: u32 = 1 << 2;

/// How a [`SimDrive`] behaves beyond what its EDS says.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SimDriveOptions {
    /// Options of the CANopen node underneath.
    pub node: SimNodeOptions,
    /// The model step (1 ms by default; zero is taken as 1 ms).
    pub step: Duration,
    /// Time constant of the first-order lag with which the cyclic
    /// synchronous modes follow their command (5 ms by default; zero
    /// follows at once).
    pub follow_time_constant: Duration,
    /// Transmit the event-driven TPDOs that map 0x6041 whenever the
    /// statusword changes (on by default), as drives do.
    pub tpdo_on_statusword_change: bool,
    /// The motor's top speed in increments/s when the object dictionary has
    /// no 0x6080 max motor speed (100 000 by default); every mode is
    /// limited to it.
    pub max_speed: u32,
    /// The drive was enabled before anyone listened: the first
    /// [`Device::start`] finds it in operation enabled, in this mode, at
    /// this position (increments), controlword 0x000F, holding (with
    /// [`SimNodeOptions::running_at_start`] for its NMT state). A power
    /// cycle starts it as usual.
    pub enabled_at_start: Option<(ModeOfOperation, i32)>,
    /// Limit and home switches, touch probe input (none by default).
    pub inputs: SimDriveInputs,
    /// 0x6502 supported drive modes at power on instead of the EDS's
    /// value (a drive without CSP that needs interpolated position, say).
    pub supported_modes: Option<u32>,
    /// The mechanics of the torque modes.
    pub torque_model: TorqueModel,
}

impl Default for SimDriveOptions {
    fn default() -> Self {
        SimDriveOptions {
            node: SimNodeOptions::default(),
            step: Duration::from_millis(1),
            follow_time_constant: Duration::from_millis(5),
            tpdo_on_statusword_change: true,
            max_speed: 100_000,
            enabled_at_start: None,
            inputs: SimDriveInputs::default(),
            supported_modes: None,
            torque_model: TorqueModel::default(),
        }
    }
}

/// The profile position set-point state.
#[derive(Debug, Clone, Copy, PartialEq)]
struct ProfilePosition {
    /// The target being moved to.
    active: Option<f64>,
    /// The buffered next target.
    queued: Option<f64>,
    /// The latest accepted target (base of relative moves).
    last_target: f64,
    /// Set-point acknowledge (statusword bit 12).
    ack: bool,
    /// The latest target was clamped to a software limit.
    limited: bool,
}

impl ProfilePosition {
    fn idle(position: f64) -> Self {
        ProfilePosition {
            active: None,
            queued: None,
            last_target: position,
            ack: false,
            limited: false,
        }
    }
}

/// The interpolated position command of cyclic synchronous position: from
/// the command at the latest set-point's arrival to the set-point, over
/// one SYNC period.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Interpolation {
    from: f64,
    to: f64,
    /// Model time of the set-point's arrival.
    start: Duration,
    period: Duration,
}

impl Interpolation {
    fn holding(position: f64) -> Self {
        Interpolation {
            from: position,
            to: position,
            start: Duration::ZERO,
            period: Duration::ZERO,
        }
    }

    fn at(&self, t: Duration) -> f64 {
        if self.period.is_zero() || t >= self.start + self.period {
            return self.to;
        }
        let f = t.saturating_sub(self.start).as_secs_f64() / self.period.as_secs_f64();
        self.from + (self.to - self.from) * f
    }
}

/// Where a homing procedure stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Homing {
    /// Not started or interrupted.
    Idle,
    /// Moving to the virtual switch.
    Running,
    /// Completed.
    Attained,
    /// Failed (unsupported method).
    Error,
}

/// What changes from one model step to the next; equal snapshots mean the
/// model is at rest.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Snapshot {
    state: DriveState,
    pos: f64,
    vel: f64,
    torque: i16,
    statusword: u16,
    follow_error: f64,
}

impl AxisModel {
    /// Moving, or with the motor under control: the model steps.
    fn active(&self) -> bool {
        self.vel != 0.0
            || matches!(
                self.state,
                DriveState::OperationEnabled
                    | DriveState::QuickStopActive
                    | DriveState::FaultReactionActive
            )
    }

    fn new(axis: u8) -> Self {
        AxisModel {
            axis,
            state: DriveState::NotReadyToSwitchOn,
            powered: false,
            mode: None,
            mode_code: 0,
            prev_cw: Controlword(0),
            pos: 0.0,
            vel: 0.0,
            shift: 0.0,
            torque: 0,
            pp: ProfilePosition::idle(0.0),
            homing: Homing::Idle,
            limit_hit: false,
            switch_blocked: false,
            probe_function: 0,
            probe_input: None,
            probe_status: 0,
            probe_positive: 0,
            probe_negative: 0,
            follow_error: 0.0,
            csp: Interpolation::holding(0.0),
            torque_demand: 0.0,
            follow_over_since: None,
            error_code: 0,
            model_time: Duration::ZERO,
        }
    }
}

/// A simulated CiA 402 servo drive. See the [module documentation](self).
#[derive(Debug)]
pub struct SimDrive {
    node: SimNode,
    options: SimDriveOptions,
    started: bool,
    /// The latest SYNC received and the interval to the one before.
    last_sync: Option<Duration>,
    sync_period: Option<Duration>,
    /// The latest time seen.
    now: Duration,
    /// 0-based numbers of the TPDOs present (0x1A00 + n).
    tpdos: Vec<u16>,
    outbox: Vec<Frame>,
    events: VecDeque<SimEvent>,
    /// The model of the axis being stepped (the first axis outside of
    /// [`SimDrive::each_axis`]).
    m: AxisModel,
    /// The models of the drive's further axes (CiA 402 multi-axis drive:
    /// axis n's objects at index + 0x800 × n), while not being stepped.
    others: Vec<AxisModel>,
}

/// The state of one axis of a [`SimDrive`]: its state machine and motion
/// model.
#[derive(Debug)]
struct AxisModel {
    /// Which axis of the drive (0..=7).
    axis: u8,
    state: DriveState,
    /// The power stage is on (statusword bit 4).
    powered: bool,
    /// The mode in effect (0x6061) and its code.
    mode: Option<ModeOfOperation>,
    mode_code: i8,
    /// The controlword as last evaluated, for edges.
    prev_cw: Controlword,
    /// Position (as reported), velocity, and reported minus physical
    /// position (set by homing).
    pos: f64,
    vel: f64,
    shift: f64,
    torque: i16,
    pp: ProfilePosition,
    homing: Homing,
    /// A software limit stopped the motor in the latest step.
    limit_hit: bool,
    /// A limit switch held the motor back in the latest step.
    switch_blocked: bool,
    /// Touch probe 1: the function (0x60B8) last seen, the input's level,
    /// the status (0x60B9) and the latched positions (0x60BA, 0x60BB).
    probe_function: u16,
    probe_input: Option<bool>,
    probe_status: u16,
    probe_positive: i32,
    probe_negative: i32,
    /// Command minus actual position in cyclic synchronous position mode.
    follow_error: f64,
    /// The interpolated command of cyclic synchronous position (and of
    /// interpolated position).
    csp: Interpolation,
    /// The motor torque of the torque modes (per mille), ramped towards
    /// 0x6071 in profile torque.
    torque_demand: f64,
    /// Since when the following error has been beyond the window.
    follow_over_since: Option<Duration>,
    error_code: u16,
    /// The time of the latest model step.
    model_time: Duration,
}

impl SimDrive {
    /// A drive with the object dictionary of `eds` at `node`, not yet
    /// started.
    pub fn new(eds: &Eds, node: NodeId, options: SimDriveOptions) -> Self {
        Self::from_od(eds.od_with_dummies(), node, options)
    }

    /// A drive with the bundled `cangate-drive.eds`.
    pub fn bundled(node: NodeId, options: SimDriveOptions) -> Self {
        Self::from_eds_text(SIM_DRIVE_EDS, node, options).expect("the bundled drive EDS is valid")
    }

    /// A drive from EDS/DCF text.
    pub fn from_eds_text(
        text: &str,
        node: NodeId,
        options: SimDriveOptions,
    ) -> Result<Self, SimError> {
        Ok(Self::from_od(
            Eds::parse(text)?.od_with_dummies(),
            node,
            options,
        ))
    }

    /// A drive serving `od`, which should hold the CiA 402 objects the
    /// model uses (absent ones read as 0 or are not written).
    pub fn from_od(od: ObjectDictionary, node: NodeId, mut options: SimDriveOptions) -> Self {
        if options.step.is_zero() {
            options.step = Duration::from_millis(1);
        }
        let tpdos = (0..MAX_TPDOS)
            .filter(|n| od.object(TPDO_MAP + n).is_some())
            .collect();
        // Axis n of a multi-axis drive: its statusword at 0x6041 + n × 0x800.
        let axes = (0..MAX_DRIVE_AXES)
            .take_while(|&n| od.object(profile_index(obj::STATUSWORD.index, n)).is_some())
            .count()
            .max(1) as u8;
        SimDrive {
            node: SimNode::from_od(od, node, options.node.clone()),
            options,
            started: false,
            last_sync: None,
            sync_period: None,
            now: Duration::ZERO,
            tpdos,
            outbox: Vec::new(),
            events: VecDeque::new(),
            m: AxisModel::new(0),
            others: (1..axes).map(AxisModel::new).collect(),
        }
    }

    /// Runs `f` for every axis of the drive, each as the one being stepped
    /// (`self.m`), the first axis first.
    fn each_axis(&mut self, mut f: impl FnMut(&mut Self)) {
        f(self);
        for k in 0..self.others.len() {
            std::mem::swap(&mut self.m, &mut self.others[k]);
            f(self);
            std::mem::swap(&mut self.m, &mut self.others[k]);
        }
    }

    /// Runs `f` with axis `axis` (0: the first) as the one being stepped.
    fn on_drive_axis<T>(&mut self, axis: u8, f: impl FnOnce(&mut Self) -> T) -> T {
        if axis == 0 {
            return f(self);
        }
        let k = usize::from(axis) - 1;
        std::mem::swap(&mut self.m, &mut self.others[k]);
        let r = f(self);
        std::mem::swap(&mut self.m, &mut self.others[k]);
        r
    }

    fn axis_model(&self, axis: u8) -> &AxisModel {
        match axis {
            0 => &self.m,
            n => &self.others[usize::from(n) - 1],
        }
    }

    /// How many axes the drive has: one, or as many as its object
    /// dictionary has statuswords at 0x6041 + n × 0x800 (a CiA 402
    /// multi-axis drive).
    pub fn axes(&self) -> u8 {
        1 + self.others.len() as u8
    }

    /// The state machine state of axis `axis` (0..[`SimDrive::axes`]).
    ///
    /// # Panics
    /// When the drive has no such axis.
    pub fn axis_state(&self, axis: u8) -> DriveState {
        self.axis_model(axis).state
    }

    /// The position of axis `axis` in increments.
    ///
    /// # Panics
    /// When the drive has no such axis.
    pub fn axis_position(&self, axis: u8) -> f64 {
        self.axis_model(axis).pos
    }

    /// The velocity of axis `axis` in increments/s.
    ///
    /// # Panics
    /// When the drive has no such axis.
    pub fn axis_velocity(&self, axis: u8) -> f64 {
        self.axis_model(axis).vel
    }

    /// As [`SimDrive::inject_fault`], on axis `axis` only.
    ///
    /// # Panics
    /// When the drive has no such axis.
    pub fn inject_axis_fault(&mut self, axis: u8, code: u16) -> Vec<Frame> {
        if !self.started {
            return Vec::new();
        }
        self.on_drive_axis(axis, |d| {
            d.fault(code);
            d.write_outputs();
        });
        let mut out = std::mem::take(&mut self.outbox);
        out.extend(self.node.on_tick(self.now));
        out
    }

    /// The CANopen node underneath.
    pub fn node(&self) -> &SimNode {
        &self.node
    }

    /// The CANopen node underneath, e.g. to set parameters locally. The
    /// model reads its inputs (0x6040, 0x6060, targets, profile
    /// parameters) at every frame and model step, so local changes take
    /// effect at the next one.
    pub fn node_mut(&mut self) -> &mut SimNode {
        &mut self.node
    }

    /// The options in force.
    pub fn options(&self) -> &SimDriveOptions {
        &self.options
    }

    /// The state machine state.
    pub fn state(&self) -> DriveState {
        self.m.state
    }

    /// The statusword the drive reports.
    pub fn statusword(&self) -> Statusword {
        Statusword(self.compose_statusword())
    }

    /// The mode of operation in effect (0x6061), `None` for no mode.
    pub fn mode(&self) -> Option<ModeOfOperation> {
        self.m.mode
    }

    /// The position in increments (0x6064 is this, rounded).
    pub fn position(&self) -> f64 {
        self.m.pos
    }

    /// The velocity in increments/s (0x606C is this, rounded).
    pub fn velocity(&self) -> f64 {
        self.m.vel
    }

    /// The error code of the latest fault (0x603F), 0 when none.
    pub fn error_code(&self) -> u16 {
        self.m.error_code
    }

    /// The following error in cyclic synchronous position mode.
    pub fn following_error(&self) -> f64 {
        self.m.follow_error
    }

    /// Takes the node events that happened since the last call, oldest
    /// first (the drive reads them from the node first).
    pub fn take_events(&mut self) -> Vec<SimEvent> {
        self.events.drain(..).collect()
    }

    /// Injects a fault with EMCY error code `code` (e.g. 0x2310 continuous
    /// over-current): the drive enters fault reaction active (then fault
    /// once stopped), 0x603F is set to `code` and 0x1001 to the generic bit
    /// plus the class bit of the code (current, voltage, temperature,
    /// communication). Returns the frames to send: the EMCY (when the NMT
    /// state allows it) and any TPDO carrying the new statusword. Does
    /// nothing before [`Device::start`].
    pub fn inject_fault(&mut self, code: u16) -> Vec<Frame> {
        if !self.started {
            return Vec::new();
        }
        self.fault(code);
        self.write_outputs();
        let mut out = std::mem::take(&mut self.outbox);
        out.extend(self.node.on_tick(self.now));
        out
    }

    // ---- inputs and the state machine ----

    /// The value of profile object `addr` (as the first axis names it) of
    /// the axis being stepped; other objects are the node's.
    fn int(&self, addr: ObjectAddress) -> Option<i128> {
        self.node.get(self.here(addr)).and_then(Value::as_i128)
    }

    /// `addr` (an object of the first axis) on the axis being stepped.
    fn here(&self, addr: ObjectAddress) -> ObjectAddress {
        on_axis(addr, self.m.axis)
    }

    fn param(&self, addr: ObjectAddress) -> f64 {
        self.int(addr).unwrap_or(0) as f64
    }

    /// An acceleration parameter; 0 (or absent) means "at once".
    fn rate(&self, addr: ObjectAddress) -> f64 {
        match self.param(addr) {
            r if r > 0.0 => r,
            _ => f64::INFINITY,
        }
    }

    /// The top speed: 0x6080 max motor speed, else the option.
    fn max_speed(&self) -> f64 {
        match self.int(obj::MAX_MOTOR_SPEED) {
            Some(v) if v > 0 => v as f64,
            _ => f64::from(self.options.max_speed),
        }
    }

    fn controlword(&self) -> Controlword {
        Controlword(self.int(obj::CONTROLWORD).unwrap_or(0) as u16)
    }

    fn quick_stop_option(&self) -> i128 {
        self.int(obj::QUICK_STOP_OPTION_CODE).unwrap_or(2)
    }

    /// The software position limits, when enabled (min < max).
    fn limits(&self) -> Option<(f64, f64)> {
        let min = self.int(obj::SOFTWARE_POSITION_LIMIT_MIN)?;
        let max = self.int(obj::SOFTWARE_POSITION_LIMIT_MAX)?;
        (min < max).then_some((min as f64, max as f64))
    }

    /// Reads the mode and the controlword and applies them.
    fn apply_inputs(&mut self) {
        if !self.started {
            return;
        }
        let requested = self.int(obj::MODES_OF_OPERATION).unwrap_or(0) as i8;
        if requested != self.m.mode_code {
            let supported = self
                .int(obj::SUPPORTED_DRIVE_MODES)
                .map_or(u32::MAX, |m| m as u32);
            match ModeOfOperation::from_code(requested) {
                Some(m) if supported & m.supported_mask() != 0 => self.set_mode(Some(m), requested),
                None if requested == 0 => self.set_mode(None, 0),
                _ => {} // not supported: the display keeps the mode in effect
            }
        }
        let cw = self.controlword();
        let prev = std::mem::replace(&mut self.m.prev_cw, cw);
        if let Some(command) = cw.command_after(prev) {
            // "Switch on + enable operation" takes two transitions.
            for _ in 0..2 {
                let Some(t) = self.m.state.on_command(command) else {
                    break;
                };
                if t.number == 16 && !(5..=8).contains(&self.quick_stop_option()) {
                    break;
                }
                if t.number == 15 {
                    self.m.error_code = 0;
                    self.m.follow_over_since = None;
                    self.outbox.extend(self.node.clear_emcy());
                }
                self.enter(t.to);
            }
        }
        if self.m.state == DriveState::OperationEnabled {
            self.mode_edges(prev, cw);
        }
    }

    fn set_mode(&mut self, mode: Option<ModeOfOperation>, code: i8) {
        self.m.mode = mode;
        self.m.mode_code = code;
        self.reset_generators();
    }

    fn reset_generators(&mut self) {
        self.m.pp = ProfilePosition::idle(self.m.pos);
        self.m.csp = Interpolation::holding(self.m.pos);
        self.m.torque_demand = 0.0;
        self.m.homing = Homing::Idle;
        self.m.follow_error = 0.0;
        self.m.follow_over_since = None;
    }

    fn enter(&mut self, to: DriveState) {
        use DriveState as S;
        let from = self.m.state;
        self.m.state = to;
        match to {
            S::NotReadyToSwitchOn | S::SwitchOnDisabled | S::ReadyToSwitchOn | S::Fault => {
                self.m.powered = false;
                self.m.vel = 0.0;
            }
            S::SwitchedOn => {
                self.m.powered = true;
                self.m.vel = 0.0;
            }
            S::OperationEnabled => {
                self.m.powered = true;
                if from != S::OperationEnabled {
                    self.reset_generators();
                }
            }
            S::QuickStopActive => {
                if self.quick_stop_option() == 0 {
                    // Option code 0: disable the drive function at once.
                    self.enter(S::SwitchOnDisabled);
                }
            }
            S::FaultReactionActive | S::Unknown => {}
        }
    }

    /// Handles the mode-specific controlword edges in operation enabled.
    fn mode_edges(&mut self, prev: Controlword, cw: Controlword) {
        let rising = cw.new_set_point() && !prev.new_set_point();
        let falling = !cw.new_set_point() && prev.new_set_point();
        match self.m.mode {
            Some(ModeOfOperation::ProfilePosition) => {
                if rising {
                    self.accept_set_point(cw);
                }
                if falling {
                    self.m.pp.ack = false;
                }
            }
            Some(ModeOfOperation::Homing) => {
                if rising {
                    self.start_homing();
                } else if falling && self.m.homing == Homing::Running {
                    self.m.homing = Homing::Idle;
                }
            }
            _ => {}
        }
    }

    fn accept_set_point(&mut self, cw: Controlword) {
        let busy = self.m.pp.active.is_some();
        if busy && !cw.change_set_immediately() && self.m.pp.queued.is_some() {
            return; // the buffer is full: not acknowledged
        }
        let raw = self.param(obj::TARGET_POSITION);
        let wanted = if cw.relative() {
            self.m.pp.last_target + raw
        } else {
            raw
        };
        let (target, limited) = match self.limits() {
            Some((min, max)) => {
                let t = wanted.clamp(min, max);
                (t, t != wanted)
            }
            None => (wanted, false),
        };
        self.m.pp.last_target = target;
        self.m.pp.limited = limited;
        if !busy || cw.change_set_immediately() {
            self.m.pp.active = Some(target);
            self.m.pp.queued = None;
        } else {
            self.m.pp.queued = Some(target);
        }
        self.m.pp.ack = true;
    }

    fn start_homing(&mut self) {
        let method = self.int(obj::HOMING_METHOD).unwrap_or(0);
        let offset = self.param(obj::HOME_OFFSET);
        self.m.homing = match method {
            35 | 37 => {
                self.m.shift += offset - self.m.pos;
                self.m.pos = offset;
                Homing::Attained
            }
            17..=30 => Homing::Running,
            _ => Homing::Error,
        };
    }

    fn fault(&mut self, code: u16) {
        self.m.error_code = code;
        if !matches!(
            self.m.state,
            DriveState::Fault | DriveState::FaultReactionActive
        ) {
            self.enter(DriveState::FaultReactionActive);
        }
        self.outbox
            .extend(self.node.inject_emcy(code, error_register(code), [0; 5]));
    }

    /// The fault reaction to a lost heartbeat: as [`SimDrive::inject_fault`]
    /// with code 0x8130, except that the node has sent the EMCY already.
    fn heartbeat_lost(&mut self) {
        self.m.error_code = crate::canopen_node::HEARTBEAT_ERROR_CODE;
        if !matches!(
            self.m.state,
            DriveState::Fault | DriveState::FaultReactionActive
        ) {
            self.enter(DriveState::FaultReactionActive);
        }
        self.write_outputs();
    }

    // ---- the model ----

    fn active(&self) -> bool {
        self.started && self.m.active()
    }

    /// Every axis's state (the first axis first).
    fn states(&self) -> [DriveState; MAX_DRIVE_AXES as usize] {
        let mut states = [DriveState::Unknown; MAX_DRIVE_AXES as usize];
        for (s, m) in states
            .iter_mut()
            .zip(std::iter::once(&self.m).chain(&self.others))
        {
            *s = m.state;
        }
        states
    }

    fn snapshot(&self) -> Snapshot {
        Snapshot {
            state: self.m.state,
            pos: self.m.pos,
            vel: self.m.vel,
            torque: self.m.torque,
            statusword: self.compose_statusword(),
            follow_error: self.m.follow_error,
        }
    }

    /// Runs the model steps due up to `now`.
    fn advance(&mut self, now: Duration) {
        if !self.active() {
            self.m.model_time = self.m.model_time.max(now);
            return;
        }
        let step = self.options.step;
        while self.m.model_time + step <= now {
            self.m.model_time += step;
            let before = self.snapshot();
            self.step_model();
            if !self.active() {
                self.m.model_time = now;
                break;
            }
            if self.snapshot() == before {
                // At rest: nothing changes until an input does.
                let behind = (now - self.m.model_time).as_nanos();
                let skip = behind - behind % step.as_nanos();
                self.m.model_time += Duration::from_nanos(u64::try_from(skip).unwrap_or(u64::MAX));
                break;
            }
        }
    }

    fn step_model(&mut self) {
        self.apply_inputs();
        let dt = self.options.step.as_secs_f64();
        let v0 = self.m.vel;
        self.m.limit_hit = false;
        match self.m.state {
            DriveState::OperationEnabled => self.step_enabled(dt),
            DriveState::QuickStopActive => {
                let dec = match self.quick_stop_option() {
                    1 | 5 => self.rate(obj::PROFILE_DECELERATION),
                    _ => self.quick_stop_deceleration(),
                };
                self.stop(dec, dt);
                if self.m.vel == 0.0 && (0..=4).contains(&self.quick_stop_option()) {
                    self.enter(DriveState::SwitchOnDisabled); // transition 12
                }
            }
            DriveState::FaultReactionActive => {
                let dec = self.quick_stop_deceleration();
                self.stop(dec, dt);
                if self.m.vel == 0.0 {
                    self.enter(DriveState::Fault); // transition 14
                }
            }
            _ => self.m.vel = 0.0,
        }
        let accel = (self.m.vel - v0) / dt;
        let max_torque = self.int(obj::MAX_TORQUE).map_or(f64::from(i16::MAX), |m| {
            m.clamp(0, i128::from(i16::MAX)) as f64
        });
        let torque = if self.in_torque_mode() {
            self.m.torque_demand
        } else {
            accel * TORQUE_PER_ACCEL
        };
        self.m.torque = torque.round().clamp(-max_torque, max_torque) as i16;
        self.write_outputs();
    }

    fn quick_stop_deceleration(&self) -> f64 {
        if self
            .node
            .get(self.here(obj::QUICK_STOP_DECELERATION))
            .is_some()
        {
            self.rate(obj::QUICK_STOP_DECELERATION)
        } else {
            self.rate(obj::PROFILE_DECELERATION)
        }
    }

    fn stop(&mut self, dec: f64, dt: f64) {
        self.m.vel = ramp(self.m.vel, 0.0, dec, dec, dt);
        self.m.pos += self.m.vel * dt;
    }

    fn step_enabled(&mut self, dt: f64) {
        let (pos0, v0) = (self.m.pos, self.m.vel);
        let cw = self.m.prev_cw;
        let dec = self.rate(obj::PROFILE_DECELERATION);
        match self.m.mode {
            Some(ModeOfOperation::ProfilePosition) => match self.m.pp.active {
                Some(target) if !cw.halt() => {
                    let vmax = self.param(obj::PROFILE_VELOCITY).min(self.max_speed());
                    let acc = self.rate(obj::PROFILE_ACCELERATION);
                    (self.m.pos, self.m.vel) =
                        profile_step(self.m.pos, self.m.vel, target, vmax, acc, dec, dt);
                    if self.m.pos == target && self.m.vel == 0.0 {
                        self.m.pp.active = self.m.pp.queued.take();
                    }
                }
                _ => self.stop(dec, dt),
            },
            Some(ModeOfOperation::ProfileVelocity) => {
                let vmax = self.max_speed();
                let target = if cw.halt() {
                    0.0
                } else {
                    self.param(obj::TARGET_VELOCITY).clamp(-vmax, vmax)
                };
                let acc = self.rate(obj::PROFILE_ACCELERATION);
                self.m.vel = ramp(self.m.vel, target, acc, dec, dt);
                self.m.pos += self.m.vel * dt;
            }
            Some(ModeOfOperation::Homing) => {
                let acc = self.rate(obj::HOMING_ACCELERATION);
                if self.m.homing == Homing::Running && cw.halt() {
                    self.m.homing = Homing::Idle;
                }
                if self.m.homing == Homing::Running {
                    // The virtual switch is at the physical position 0.
                    let switch = self.m.shift;
                    let speed = self.param(obj::HOMING_SPEED_SWITCH).min(self.max_speed());
                    (self.m.pos, self.m.vel) =
                        profile_step(self.m.pos, self.m.vel, switch, speed, acc, acc, dt);
                    if self.m.pos == switch && self.m.vel == 0.0 {
                        let offset = self.param(obj::HOME_OFFSET);
                        self.m.shift = offset;
                        self.m.pos = offset;
                        self.m.homing = Homing::Attained;
                    }
                } else {
                    self.stop(acc, dt);
                }
                return; // homing ignores the software limits
            }
            Some(ModeOfOperation::CyclicSynchronousPosition) => {
                let mut set_point = self.param(obj::TARGET_POSITION);
                if let Some((min, max)) = self.limits() {
                    set_point = set_point.clamp(min, max);
                }
                if set_point != self.m.csp.to {
                    // A new set-point (it arrived during the step that
                    // just ended): reach it over one SYNC period.
                    let arrived = self.m.model_time.saturating_sub(self.options.step);
                    self.m.csp = Interpolation {
                        from: self.m.csp.at(arrived),
                        to: set_point,
                        start: arrived,
                        period: self.sync_period.unwrap_or(Duration::ZERO),
                    };
                }
                let command = self.m.csp.at(self.m.model_time);
                let mut next = self.m.pos + (command - self.m.pos) * self.follow_gain(dt);
                if (command - next).abs() < 1e-3 {
                    next = command;
                }
                let reach = self.max_speed() * dt;
                next = next.clamp(self.m.pos - reach, self.m.pos + reach);
                self.m.vel = (next - self.m.pos) / dt;
                self.m.pos = next;
                self.m.follow_error = command - self.m.pos;
                self.check_following_error();
            }
            Some(ModeOfOperation::CyclicSynchronousTorque | ModeOfOperation::ProfileTorque) => {
                self.step_torque(dt, cw.halt(), dec);
            }
            Some(ModeOfOperation::InterpolatedPosition) => self.step_interpolated(dt, cw),
            Some(ModeOfOperation::CyclicSynchronousVelocity) => {
                let vmax = self.max_speed();
                let command = self.param(obj::TARGET_VELOCITY).clamp(-vmax, vmax);
                let mut next = self.m.vel + (command - self.m.vel) * self.follow_gain(dt);
                if (command - next).abs() < 1e-3 {
                    next = command;
                }
                self.m.vel = next;
                self.m.pos += self.m.vel * dt;
            }
            _ => self.stop(dec, dt),
        }
        self.apply_limit_switches(pos0, v0, dt);
        self.apply_limits();
    }

    /// The physical position (before any homing shift).
    fn physical(&self, pos: f64) -> f64 {
        pos - self.m.shift
    }

    /// The limit switches active at the reported position `pos`:
    /// (negative, positive).
    fn limit_switches_at(&self, pos: f64) -> (bool, bool) {
        let phys = self.physical(pos);
        let inputs = self.options.inputs;
        (
            inputs
                .negative_limit_switch
                .is_some_and(|n| phys <= f64::from(n)),
            inputs
                .positive_limit_switch
                .is_some_and(|p| phys >= f64::from(p)),
        )
    }

    /// A limit switch active where the step started holds back motion
    /// into it: from the velocity the step started with, the motor brakes
    /// at the quick stop deceleration and does not go on into the switch;
    /// motion away from it runs as the mode commands.
    fn apply_limit_switches(&mut self, pos0: f64, v0: f64, dt: f64) {
        let (negative, positive) = self.limit_switches_at(pos0);
        let into = (positive && self.m.vel > 0.0) || (negative && self.m.vel < 0.0);
        self.m.switch_blocked = into;
        if !into {
            return;
        }
        let dec = self.quick_stop_deceleration();
        let v = ramp(v0, 0.0, dec, dec, dt);
        let v = if positive { v.max(0.0) } else { v.min(0.0) };
        self.m.vel = v;
        self.m.pos = pos0 + v * dt;
        self.m.limit_hit = true;
    }

    /// 0x60FD from the switches at the current position.
    fn digital_inputs(&self) -> u32 {
        let (negative, positive) = self.limit_switches_at(self.m.pos);
        let home = self
            .options
            .inputs
            .home_switch
            .is_some_and(|h| self.physical(self.m.pos) >= f64::from(h));
        let mut bits = 0;
        if negative {
            bits |= INPUT_NEGATIVE_LIMIT;
        }
        if positive {
            bits |= INPUT_POSITIVE_LIMIT;
        }
        if home {
            bits |= INPUT_HOME_SWITCH;
        }
        bits
    }

    /// Touch probe 1: follows 0x60B8 and latches the edges of the input.
    fn update_touch_probe(&mut self) {
        let function = self.int(obj::TOUCH_PROBE_FUNCTION).unwrap_or(0) as u16;
        if function != self.m.probe_function {
            // A new function re-arms: nothing stored yet.
            self.m.probe_function = function;
            self.m.probe_status = function & 1;
        }
        let Some(at) = self.options.inputs.touch_probe else {
            return;
        };
        let level = self.physical(self.m.pos) >= f64::from(at);
        let Some(previous) = self.m.probe_input.replace(level) else {
            return;
        };
        if function & 1 == 0 || level == previous {
            return;
        }
        // The input switches exactly at its position: latched there, not
        // where the model step ended.
        let latched = (f64::from(at) + self.m.shift).round() as i32;
        let continuous = function & 2 != 0;
        if level && function & 0x10 != 0 && (continuous || self.m.probe_status & 2 == 0) {
            self.m.probe_positive = latched;
            self.m.probe_status |= 2;
        }
        if !level && function & 0x20 != 0 && (continuous || self.m.probe_status & 4 == 0) {
            self.m.probe_negative = latched;
            self.m.probe_status |= 4;
        }
    }

    fn in_torque_mode(&self) -> bool {
        self.m.state == DriveState::OperationEnabled
            && matches!(
                self.m.mode,
                Some(ModeOfOperation::CyclicSynchronousTorque | ModeOfOperation::ProfileTorque)
            )
    }

    /// The torque set-point (0x6071), bounded by 0x6072 max torque.
    fn target_torque(&self) -> f64 {
        let t = self.param(obj::TARGET_TORQUE);
        match self.int(obj::MAX_TORQUE) {
            Some(m) if m > 0 => t.clamp(-(m as f64), m as f64),
            _ => t,
        }
    }

    /// One step of a torque mode: the motor torque (at once in CST,
    /// ramped at 0x6087 in profile torque) through the torque model;
    /// halted, the drive's velocity loop brakes at `dec` instead.
    fn step_torque(&mut self, dt: f64, halt: bool, dec: f64) {
        if halt {
            self.m.torque_demand = 0.0;
            self.stop(dec, dt);
            return;
        }
        let target = self.target_torque();
        self.m.torque_demand = if self.m.mode == Some(ModeOfOperation::ProfileTorque) {
            let slope = self.rate(obj::TORQUE_SLOPE);
            ramp(self.m.torque_demand, target, slope, slope, dt)
        } else {
            target
        };
        let vmax = self.max_speed();
        self.m.vel = self
            .options
            .torque_model
            .step(self.m.vel, self.m.torque_demand, dt)
            .clamp(-vmax, vmax);
        self.m.pos += self.m.vel * dt;
    }

    /// The interpolation time period 0x60C2 (value · 10^index s).
    fn interpolation_period(&self) -> Duration {
        let value = self.int(obj::INTERPOLATION_PERIOD_VALUE).unwrap_or(1) as f64;
        let index = self.int(obj::INTERPOLATION_PERIOD_INDEX).unwrap_or(-3) as i32;
        Duration::from_secs_f64((value * 10f64.powi(index)).clamp(0.0, 1.0))
    }

    /// One step of interpolated position: with ip mode enabled (bit 4),
    /// each new 0x60C1:01 is reached over the interpolation period.
    fn step_interpolated(&mut self, dt: f64, cw: Controlword) {
        if cw.new_set_point() {
            let mut set_point = self.param(obj::INTERPOLATION_DATA);
            if let Some((min, max)) = self.limits() {
                set_point = set_point.clamp(min, max);
            }
            if set_point != self.m.csp.to {
                let arrived = self.m.model_time.saturating_sub(self.options.step);
                self.m.csp = Interpolation {
                    from: self.m.csp.at(arrived),
                    to: set_point,
                    start: arrived,
                    period: self.interpolation_period(),
                };
            }
        }
        let command = self.m.csp.at(self.m.model_time);
        let mut next = self.m.pos + (command - self.m.pos) * self.follow_gain(dt);
        if (command - next).abs() < 1e-3 {
            next = command;
        }
        let reach = self.max_speed() * dt;
        next = next.clamp(self.m.pos - reach, self.m.pos + reach);
        self.m.vel = (next - self.m.pos) / dt;
        self.m.pos = next;
        self.m.follow_error = command - self.m.pos;
    }

    /// The fraction of the remaining error a first-order lag closes in `dt`.
    fn follow_gain(&self, dt: f64) -> f64 {
        let tau = self.options.follow_time_constant.as_secs_f64();
        if tau <= 0.0 {
            1.0
        } else {
            1.0 - (-dt / tau).exp()
        }
    }

    /// The following error window (0x6065), when present and not off.
    fn following_window(&self) -> Option<f64> {
        match self.int(obj::FOLLOWING_ERROR_WINDOW)? {
            0xFFFF_FFFF => None,
            w => Some(w as f64),
        }
    }

    fn following_error_exceeded(&self) -> bool {
        self.following_window()
            .is_some_and(|w| self.m.follow_error.abs() > w)
    }

    fn check_following_error(&mut self) {
        if !self.following_error_exceeded() || self.m.switch_blocked {
            self.m.follow_over_since = None;
            return;
        }
        let since = *self.m.follow_over_since.get_or_insert(self.m.model_time);
        let timeout = Duration::from_millis(
            self.int(obj::FOLLOWING_ERROR_TIMEOUT)
                .map_or(0, |t| t.clamp(0, i128::from(u64::MAX)) as u64),
        );
        if self.m.model_time - since >= timeout {
            self.fault(FOLLOWING_ERROR_CODE);
        }
    }

    fn apply_limits(&mut self) {
        let Some((min, max)) = self.limits() else {
            return;
        };
        if self.m.pos > max {
            self.m.pos = max;
            self.m.vel = self.m.vel.min(0.0);
            self.m.limit_hit = true;
        } else if self.m.pos < min {
            self.m.pos = min;
            self.m.vel = self.m.vel.max(0.0);
            self.m.limit_hit = true;
        }
    }

    // ---- outputs ----

    fn compose_statusword(&self) -> u16 {
        if !self.started {
            return 0;
        }
        let mut sw = Statusword::from_state(self.m.state)
            .with(Statusword::REMOTE, true)
            .with(Statusword::VOLTAGE_ENABLED, self.m.powered);
        let stopped = self.m.vel == 0.0;
        match self.m.state {
            DriveState::OperationEnabled => sw = self.mode_bits(sw),
            DriveState::QuickStopActive => sw = sw.with(Statusword::TARGET_REACHED, stopped),
            _ => {}
        }
        sw.bits()
    }

    fn mode_bits(&self, sw: Statusword) -> Statusword {
        let stopped = self.m.vel == 0.0;
        let halt = self.m.prev_cw.halt();
        let sw = sw.with(Statusword::INTERNAL_LIMIT, self.m.limit_hit);
        match self.m.mode {
            Some(ModeOfOperation::ProfilePosition) => {
                let reached = stopped && (self.m.pp.active.is_none() || halt);
                sw.with(Statusword::TARGET_REACHED, reached)
                    .with(Statusword::OMS_12, self.m.pp.ack)
                    .with(
                        Statusword::INTERNAL_LIMIT,
                        self.m.limit_hit || self.m.pp.limited,
                    )
            }
            Some(ModeOfOperation::ProfileVelocity) => {
                let vmax = self.max_speed();
                let target = if halt {
                    0.0
                } else {
                    self.param(obj::TARGET_VELOCITY).clamp(-vmax, vmax)
                };
                sw.with(Statusword::TARGET_REACHED, self.m.vel == target)
                    .with(Statusword::OMS_12, stopped)
            }
            Some(ModeOfOperation::Homing) => match self.m.homing {
                Homing::Idle => sw.with(Statusword::TARGET_REACHED, stopped),
                Homing::Running => sw,
                Homing::Attained => sw
                    .with(Statusword::TARGET_REACHED, stopped)
                    .with(Statusword::OMS_12, true),
                Homing::Error => sw
                    .with(Statusword::TARGET_REACHED, stopped)
                    .with(Statusword::OMS_13, true),
            },
            Some(ModeOfOperation::CyclicSynchronousPosition) => sw
                .with(Statusword::OMS_12, true)
                .with(Statusword::OMS_13, self.following_error_exceeded()),
            Some(ModeOfOperation::CyclicSynchronousVelocity) => sw.with(Statusword::OMS_12, true),
            Some(ModeOfOperation::CyclicSynchronousTorque) => sw.with(Statusword::OMS_12, !halt),
            Some(ModeOfOperation::ProfileTorque) => {
                let reached = if halt {
                    stopped
                } else {
                    self.m.torque_demand == self.target_torque()
                };
                sw.with(Statusword::TARGET_REACHED, reached)
            }
            Some(ModeOfOperation::InterpolatedPosition) => {
                sw.with(Statusword::OMS_12, self.m.prev_cw.new_set_point())
            }
            _ => sw,
        }
    }

    /// Sets an object when it exists and its value differs.
    fn put(&mut self, addr: ObjectAddress, value: Value) -> bool {
        let addr = self.here(addr);
        match self.node.get(addr) {
            Some(current) if *current != value => self.node.set(addr, value).is_ok(),
            _ => false,
        }
    }

    fn write_outputs(&mut self) {
        let sw = self.compose_statusword();
        if self.put(obj::STATUSWORD, Value::Unsigned16(sw))
            && self.started
            && self.options.tpdo_on_statusword_change
        {
            self.trigger_statusword_tpdos();
        }
        self.put(
            obj::MODES_OF_OPERATION_DISPLAY,
            Value::Integer8(self.m.mode_code),
        );
        self.put(
            obj::POSITION_ACTUAL,
            Value::Integer32(self.m.pos.round() as i32),
        );
        self.put(
            obj::VELOCITY_ACTUAL,
            Value::Integer32(self.m.vel.round() as i32),
        );
        self.put(obj::TORQUE_ACTUAL, Value::Integer16(self.m.torque));
        self.put(obj::ERROR_CODE, Value::Unsigned16(self.m.error_code));
        self.put(
            obj::FOLLOWING_ERROR_ACTUAL,
            Value::Integer32(self.m.follow_error.round() as i32),
        );
        if self.started {
            self.put(
                obj::DIGITAL_INPUTS,
                Value::Unsigned32(self.digital_inputs()),
            );
            self.update_touch_probe();
            self.put(
                obj::TOUCH_PROBE_STATUS,
                Value::Unsigned16(self.m.probe_status),
            );
            self.put(
                obj::TOUCH_PROBE_1_POSITIVE,
                Value::Integer32(self.m.probe_positive),
            );
            self.put(
                obj::TOUCH_PROBE_1_NEGATIVE,
                Value::Integer32(self.m.probe_negative),
            );
        }
    }

    /// Marks every TPDO that maps the statusword for transmission.
    fn trigger_statusword_tpdos(&mut self) {
        let statusword = self.here(obj::STATUSWORD);
        let mapping = |n: u16| {
            let index = TPDO_MAP + n;
            let count = self
                .int(ObjectAddress::new(index, 0))
                .unwrap_or(0)
                .clamp(0, 64) as u8;
            (1..=count).any(|sub| {
                self.int(ObjectAddress::new(index, sub))
                    .is_some_and(|e| (e as u32) >> 8 == u32::from(statusword.index) << 8)
            })
        };
        let maps: Vec<u16> = self.tpdos.iter().copied().filter(|&n| mapping(n)).collect();
        for n in maps {
            self.node.trigger_tpdo(n + 1);
        }
    }

    /// Whether `frame` is a SYNC (the COB-ID of 0x1005, 0x080 by default).
    fn is_sync(&self, frame: &Frame) -> bool {
        let cob = self
            .int(ObjectAddress::new(0x1005, 0))
            .map_or(0x080, |v| (v as u32) & 0x7FF);
        frame.raw_id() == cob && frame.data().len() <= 1 && !frame.is_extended()
    }

    /// Reads the node's events: a reset node restarts the drive; the loss
    /// of a consumed heartbeat faults it.
    fn drain_events(&mut self) {
        for event in self.node.take_events() {
            if let SimEvent::Reset {
                kind: NmtReset::Node,
            } = event
            {
                // The node's reset restarts every axis.
                self.each_axis(Self::power_on);
            }
            if let SimEvent::HeartbeatLost { .. } = event {
                self.each_axis(Self::heartbeat_lost);
            }
            if self.options.node.max_events > 0 {
                while self.events.len() >= self.options.node.max_events {
                    self.events.pop_front();
                }
                self.events.push_back(event);
            }
        }
    }

    /// In operation enabled in `mode` at `position`, as if a master had
    /// enabled it long ago: the controlword, the mode and the targets in
    /// the dictionary say so, the motor holds.
    fn enabled_since_before(&mut self, mode: ModeOfOperation, position: i32) {
        let _ = self.node.set(
            self.here(obj::CONTROLWORD),
            Value::Unsigned16(Controlword::ENABLE_OPERATION.0),
        );
        let _ = self.node.set(
            self.here(obj::MODES_OF_OPERATION),
            Value::Integer8(mode.code()),
        );
        // Its last set-points: hold here.
        let _ = self
            .node
            .set(self.here(obj::TARGET_POSITION), Value::Integer32(position));
        let _ = self
            .node
            .set(self.here(obj::TARGET_VELOCITY), Value::Integer32(0));
        self.m.pos = f64::from(position);
        self.m.prev_cw = self.controlword();
        self.set_mode(Some(mode), mode.code());
        self.enter(DriveState::SwitchedOn);
        self.enter(DriveState::OperationEnabled);
        self.reset_generators();
        self.write_outputs();
    }

    /// Transitions 0 and 1: initialised, in switch on disabled, at the same
    /// physical position.
    fn power_on(&mut self) {
        self.started = true;
        self.m.state = DriveState::SwitchOnDisabled;
        self.m.powered = false;
        self.m.pos -= self.m.shift;
        self.m.shift = 0.0;
        self.m.vel = 0.0;
        self.m.torque = 0;
        self.m.mode = None;
        self.m.mode_code = 0;
        self.m.prev_cw = self.controlword();
        self.m.error_code = 0;
        self.m.limit_hit = false;
        self.m.switch_blocked = false;
        self.m.probe_function = 0;
        self.m.probe_input = None;
        self.m.probe_status = 0;
        self.m.probe_positive = 0;
        self.m.probe_negative = 0;
        self.reset_generators();
        if let Some(mask) = self.options.supported_modes {
            let _ = self.node.set(
                self.here(obj::SUPPORTED_DRIVE_MODES),
                Value::Unsigned32(mask),
            );
        }
        self.write_outputs();
    }
}

/// The EMCY error register for an error code: generic, plus current,
/// voltage, temperature or communication by the code's class.
fn error_register(code: u16) -> u8 {
    ErrorRegister::GENERIC
        | match code >> 12 {
            0x2 => ErrorRegister::CURRENT,
            0x3 => ErrorRegister::VOLTAGE,
            0x4 => ErrorRegister::TEMPERATURE,
            0x8 if code >> 8 == 0x81 => ErrorRegister::COMMUNICATION,
            _ => 0,
        }
}

/// One step of a velocity ramp towards `target`: `acc` when speeding up,
/// `dec` when slowing down (or reversing).
fn ramp(vel: f64, target: f64, acc: f64, dec: f64, dt: f64) -> f64 {
    if vel == target {
        return vel;
    }
    let speeding_up = target.abs() > vel.abs() && (vel == 0.0 || target.signum() == vel.signum());
    let rate = if speeding_up { acc } else { dec } * dt;
    vel + (target - vel).clamp(-rate, rate)
}

/// One step of a trapezoidal move towards `target` with at most `vmax`,
/// accelerating with `acc` and braking with `dec` so as to stop at the
/// target; returns the new position and velocity. Never overshoots: the
/// step that would pass the target ends on it at standstill.
fn profile_step(
    pos: f64,
    vel: f64,
    target: f64,
    vmax: f64,
    acc: f64,
    dec: f64,
    dt: f64,
) -> (f64, f64) {
    let d = target - pos;
    if d == 0.0 && vel == 0.0 {
        return (target, 0.0);
    }
    let dir = if d != 0.0 { d.signum() } else { -vel.signum() };
    let v_dir = vel * dir;
    if v_dir < 0.0 {
        // Moving away from the target: brake first.
        let v = (v_dir + dec * dt).min(0.0) * dir;
        return (pos + v * dt, v);
    }
    let dist = d.abs();
    let allowed = vmax.min((2.0 * dec * dist).sqrt());
    let v = if v_dir < allowed {
        (v_dir + acc * dt).min(allowed)
    } else {
        (v_dir - dec * dt).max(allowed)
    };
    if v * dt >= dist {
        return (target, 0.0);
    }
    (pos + dir * v * dt, dir * v)
}

impl Device for SimDrive {
    fn start(&mut self, now: Duration) -> Vec<Frame> {
        self.now = now;
        self.each_axis(|d| d.m.model_time = now);
        let out = self.node.start(now);
        // What the drive was doing before anyone listened applies to this
        // start only (the options are what a power cycle starts from).
        self.options.node.running_at_start = None;
        if !self.started {
            self.each_axis(Self::power_on);
            if let Some((mode, position)) = self.options.enabled_at_start.take() {
                self.enabled_since_before(mode, position);
            }
        }
        self.drain_events();
        out
    }

    fn on_frame(&mut self, frame: &Frame, now: Duration) -> Vec<Frame> {
        self.now = now;
        self.each_axis(|d| d.advance(now));
        if self.is_sync(frame) {
            if let Some(last) = self.last_sync
                && now > last
                && now - last <= MAX_SYNC_PERIOD
            {
                self.sync_period = Some(now - last);
            }
            self.last_sync = Some(now);
        }
        let mut out = self.node.on_frame(frame, now);
        self.drain_events();
        self.each_axis(|d| {
            d.apply_inputs();
            d.write_outputs();
        });
        out.append(&mut self.outbox);
        out.extend(self.node.on_tick(now));
        out
    }

    fn on_tick(&mut self, now: Duration) -> Vec<Frame> {
        self.now = now;
        self.each_axis(|d| d.advance(now));
        let mut out = std::mem::take(&mut self.outbox);
        out.extend(self.node.on_tick(now));
        // A heartbeat consumer timeout shows up in a tick.
        let before = self.states();
        self.drain_events();
        if !self.outbox.is_empty() || self.states() != before {
            out.append(&mut self.outbox);
            out.extend(self.node.on_tick(now));
        }
        out
    }

    fn receive_filters(&self) -> Option<Vec<cangate_can::Filter>> {
        Some(self.node.receive_filters())
    }

    fn filter_generation(&self) -> u64 {
        self.node.filter_generation()
    }

    fn next_deadline(&self) -> Option<Duration> {
        let step = self.options.step;
        let model = std::iter::once(&self.m)
            .chain(&self.others)
            .filter(|m| self.started && m.active())
            .map(|m| m.model_time + step)
            .min();
        [model, self.node.next_deadline()]
            .into_iter()
            .flatten()
            .min()
    }
}

#[cfg(test)]
mod tests {
    use cangate_can::CanId;
    use cangate_canopen::cia402::{DriverStep, StateMachineDriver};
    use cangate_canopen::od::{AccessType, DefaultValue, Object, Variable};
    use cangate_canopen::value::DataType;

    use super::*;

    const MS: Duration = Duration::from_millis(1);

    fn frame(id: u16, data: &[u8]) -> Frame {
        Frame::new(CanId::Standard(id), data).unwrap()
    }

    fn wire(frames: &[Frame]) -> Vec<(u32, Vec<u8>)> {
        frames
            .iter()
            .map(|f| (f.raw_id(), f.data().to_vec()))
            .collect()
    }

    /// The bundled drive at node 5, started at t = 0.
    fn drive() -> SimDrive {
        let mut d = SimDrive::bundled(NodeId::new(5).unwrap(), SimDriveOptions::default());
        assert_eq!(wire(&d.start(Duration::ZERO)), [(0x705, vec![0x00])]);
        d
    }

    /// The drive, operational since t = 0 (its first TPDOs discarded).
    fn operational() -> SimDrive {
        let mut d = drive();
        d.on_frame(&frame(0x000, &[0x01, 0x05]), Duration::ZERO);
        d
    }

    /// An expedited SDO download; checks the confirmation and returns the
    /// other frames sent.
    fn sdo_write(d: &mut SimDrive, addr: ObjectAddress, bytes: &[u8], now: Duration) -> Vec<Frame> {
        let cs = match bytes.len() {
            1 => 0x2F,
            2 => 0x2B,
            4 => 0x23,
            n => panic!("{n} bytes"),
        };
        let [lo, hi] = addr.index.to_le_bytes();
        let mut data = vec![cs, lo, hi, addr.sub];
        data.extend_from_slice(bytes);
        data.resize(8, 0);
        let mut out = d.on_frame(&frame(0x605, &data), now);
        assert!(!out.is_empty(), "no reply to the write of {addr}");
        let reply = out.remove(0);
        assert_eq!(
            wire(&[reply]),
            [(0x585, vec![0x60, lo, hi, addr.sub, 0, 0, 0, 0])],
            "write of {addr}"
        );
        out
    }

    /// An expedited SDO upload; returns the value bytes.
    fn sdo_read(d: &mut SimDrive, addr: ObjectAddress, now: Duration) -> Vec<u8> {
        let [lo, hi] = addr.index.to_le_bytes();
        let out = d.on_frame(&frame(0x605, &[0x40, lo, hi, addr.sub, 0, 0, 0, 0]), now);
        let reply = out.iter().find(|f| f.raw_id() == 0x585).expect("SDO reply");
        let data = reply.data();
        assert_eq!(
            data[0] & 0xF3,
            0x43,
            "expedited upload of {addr}: {data:02X?}"
        );
        let n = 4 - usize::from((data[0] >> 2) & 3);
        data[4..4 + n].to_vec()
    }

    fn read_u16(d: &mut SimDrive, addr: ObjectAddress, now: Duration) -> u16 {
        u16::from_le_bytes(sdo_read(d, addr, now).try_into().unwrap())
    }

    fn read_i32(d: &mut SimDrive, addr: ObjectAddress, now: Duration) -> i32 {
        i32::from_le_bytes(sdo_read(d, addr, now).try_into().unwrap())
    }

    fn statusword(d: &mut SimDrive, now: Duration) -> u16 {
        read_u16(d, obj::STATUSWORD, now)
    }

    /// RPDO1: controlword + target position.
    fn rpdo1(cw: u16, target: i32) -> Frame {
        let mut data = cw.to_le_bytes().to_vec();
        data.extend_from_slice(&target.to_le_bytes());
        frame(0x205, &data)
    }

    /// RPDO2: controlword + target velocity.
    fn rpdo2(cw: u16, velocity: i32) -> Frame {
        let mut data = cw.to_le_bytes().to_vec();
        data.extend_from_slice(&velocity.to_le_bytes());
        frame(0x305, &data)
    }

    /// TPDO1 payload: statusword + position.
    fn tpdo1(sw: u16, pos: i32) -> (u32, Vec<u8>) {
        let mut data = sw.to_le_bytes().to_vec();
        data.extend_from_slice(&pos.to_le_bytes());
        (0x185, data)
    }

    /// Ticks the drive at its deadlines from `from` up to `to`; calls
    /// `each` after every tick. Returns the frames sent with their times.
    fn run(
        d: &mut SimDrive,
        to: Duration,
        mut each: impl FnMut(&SimDrive, Duration),
    ) -> Vec<(Duration, Frame)> {
        let mut out = Vec::new();
        let mut last = None;
        while let Some(t) = d.next_deadline().filter(|&t| t <= to) {
            assert_ne!(last, Some(t), "no progress at {t:?}");
            last = Some(t);
            out.extend(d.on_tick(t).into_iter().map(|f| (t, f)));
            each(d, t);
        }
        out
    }

    /// Enables the drive in `mode` over RPDO1 at `now`, `now + 1 ms` and
    /// `now + 2 ms` (target position 0).
    fn enable(d: &mut SimDrive, mode: ModeOfOperation, now: Duration) {
        sdo_write(d, obj::MODES_OF_OPERATION, &[mode.code() as u8], now);
        for (k, cw) in [0x0006u16, 0x0007, 0x000F].into_iter().enumerate() {
            let target = d.position().round() as i32;
            d.on_frame(&rpdo1(cw, target), now + MS * (k as u32 + 1));
        }
        assert_eq!(d.state(), DriveState::OperationEnabled);
        assert_eq!(d.mode(), Some(mode));
    }

    /// A drive with two axes (the bundled EDS with each profile object
    /// again at + 0x800): each axis has its own state machine and model,
    /// commanded through its own objects; a node reset restarts both.
    #[test]
    fn a_two_axis_drive_runs_each_axis_on_its_own_objects() {
        let text = cangate_canopen::eds::sim_drive_eds_with_axes(2);
        let mut d =
            SimDrive::from_eds_text(&text, NodeId::new(5).unwrap(), SimDriveOptions::default())
                .unwrap();
        assert_eq!(d.axes(), 2);
        d.start(Duration::ZERO);
        d.on_frame(&frame(0x000, &[0x01, 0x05]), Duration::ZERO);
        let second = |a: ObjectAddress| on_axis(a, 1);
        // Axis 1 in profile velocity at 5000 inc/s, by SDO on 0x68xx.
        sdo_write(&mut d, second(obj::MODES_OF_OPERATION), &[3], MS);
        sdo_write(
            &mut d,
            second(obj::TARGET_VELOCITY),
            &5000i32.to_le_bytes(),
            MS,
        );
        for (k, cw) in [0x0006u16, 0x0007, 0x000F].into_iter().enumerate() {
            sdo_write(
                &mut d,
                second(obj::CONTROLWORD),
                &cw.to_le_bytes(),
                MS * (2 + k as u32),
            );
        }
        assert_eq!(d.axis_state(1), DriveState::OperationEnabled);
        assert_eq!(d.axis_state(0), DriveState::SwitchOnDisabled);
        assert_eq!(
            read_u16(&mut d, second(obj::STATUSWORD), 5 * MS) & 0x6F,
            0x27
        );
        assert_eq!(read_u16(&mut d, obj::STATUSWORD, 5 * MS) & 0x6F, 0x40);
        run(&mut d, 200 * MS, |_, _| {});
        assert_eq!(d.axis_velocity(1), 5000.0);
        assert!(d.axis_position(1) > 0.0);
        assert_eq!(
            read_i32(&mut d, second(obj::VELOCITY_ACTUAL), 200 * MS),
            5000
        );
        // The first axis has not moved, and its objects say so.
        assert_eq!((d.axis_position(0), d.axis_velocity(0)), (0.0, 0.0));
        assert_eq!(read_i32(&mut d, obj::VELOCITY_ACTUAL, 200 * MS), 0);
        // Axis 0 enabled and halted while axis 1 keeps running.
        sdo_write(&mut d, obj::MODES_OF_OPERATION, &[3], 201 * MS);
        for (k, cw) in [0x0006u16, 0x0007, 0x000F].into_iter().enumerate() {
            sdo_write(
                &mut d,
                obj::CONTROLWORD,
                &cw.to_le_bytes(),
                MS * (202 + k as u32),
            );
        }
        assert_eq!(d.axis_state(0), DriveState::OperationEnabled);
        sdo_write(&mut d, obj::CONTROLWORD, &0x0002u16.to_le_bytes(), 210 * MS);
        run(&mut d, 300 * MS, |_, _| {});
        assert_eq!(d.axis_state(0), DriveState::SwitchOnDisabled);
        assert_eq!(d.axis_state(1), DriveState::OperationEnabled);
        assert_eq!(d.axis_velocity(1), 5000.0);
        // A fault on axis 1 alone.
        d.inject_axis_fault(1, 0x2310);
        run(&mut d, 400 * MS, |_, _| {});
        assert_eq!(d.axis_state(1), DriveState::Fault);
        assert_eq!(read_u16(&mut d, second(obj::ERROR_CODE), 400 * MS), 0x2310);
        assert_eq!(read_u16(&mut d, obj::ERROR_CODE, 400 * MS), 0);
        // NMT reset node: both axes restart in switch on disabled.
        sdo_write(&mut d, obj::MODES_OF_OPERATION, &[3], 401 * MS);
        for (k, cw) in [0x0006u16, 0x0007, 0x000F].into_iter().enumerate() {
            sdo_write(
                &mut d,
                obj::CONTROLWORD,
                &cw.to_le_bytes(),
                MS * (402 + k as u32),
            );
        }
        assert_eq!(d.axis_state(0), DriveState::OperationEnabled);
        d.on_frame(&frame(0x000, &[0x81, 0x05]), 410 * MS);
        assert_eq!(d.axis_state(0), DriveState::SwitchOnDisabled);
        assert_eq!(d.axis_state(1), DriveState::SwitchOnDisabled);
    }

    #[test]
    fn enable_sequence_over_sdo_with_exact_statuswords() {
        let mut d = drive();
        let cw = obj::CONTROLWORD;
        assert_eq!(statusword(&mut d, MS), 0x0240);
        let steps: &[(u16, u16)] = &[
            (0x0006, 0x0221), // 2: shutdown
            (0x0007, 0x0233), // 3: switch on
            (0x000F, 0x0237), // 4: enable operation
            (0x0007, 0x0233), // 5: disable operation
            (0x0006, 0x0221), // 6: shutdown
            (0x000F, 0x0237), // 3+4: switch on + enable operation
            (0x0006, 0x0221), // 8: shutdown
            (0x0002, 0x0240), // 7: quick stop
            (0x0002, 0x0240), // nothing in switch on disabled
            (0x0007, 0x0240), // switch on needs ready to switch on first
            (0x0006, 0x0221),
            (0x0007, 0x0233),
            (0x0000, 0x0240), // 10: disable voltage
            (0x0006, 0x0221),
            (0x000F, 0x0237),
            (0x0000, 0x0240), // 9: disable voltage
        ];
        let mut now = 2 * MS;
        for &(control, status) in steps {
            // Pre-operational: no TPDO, only the SDO confirmation.
            assert!(sdo_write(&mut d, cw, &control.to_le_bytes(), now).is_empty());
            assert_eq!(
                statusword(&mut d, now + MS),
                status,
                "after 0x{control:04X}"
            );
            now += 2 * MS;
        }
        assert_eq!(read_u16(&mut d, cw, now), 0x0000);
        assert_eq!(d.statusword(), Statusword(0x0240));
    }

    #[test]
    fn enable_sequence_over_rpdo_sends_the_statusword_tpdo() {
        let mut d = drive();
        let started = d.on_frame(&frame(0x000, &[0x01, 0x05]), Duration::ZERO);
        assert_eq!(
            wire(&started),
            [
                (0x705, vec![0x05]), // the new state at once
                tpdo1(0x0240, 0),
                (0x285, vec![0, 0, 0, 0, 0, 0]), // velocity + torque
            ]
        );
        let steps = [(0x0006u16, 0x0221u16), (0x0007, 0x0233), (0x000F, 0x0237)];
        for (k, (cw, sw)) in steps.into_iter().enumerate() {
            let out = d.on_frame(&rpdo1(cw, 0), MS * (10 + k as u32));
            assert_eq!(wire(&out), [tpdo1(sw, 0)], "after 0x{cw:04X}");
        }
        // Enabled: the model steps every millisecond.
        assert_eq!(d.next_deadline(), Some(13 * MS));
        assert!(d.on_tick(13 * MS).is_empty());
        assert_eq!(d.next_deadline(), Some(14 * MS));
        // The same controlword again changes nothing and sends nothing.
        assert!(d.on_frame(&rpdo1(0x000F, 0), 14 * MS).is_empty());
        assert_eq!(d.next_deadline(), Some(15 * MS));
        // Disabled: only the node's schedule (TPDO event timers at 100 ms).
        d.on_frame(&rpdo1(0x0000, 0), 20 * MS);
        assert_eq!(d.next_deadline(), Some(100 * MS));
    }

    #[test]
    fn profile_position_move_reaches_the_target() {
        let mut d = operational();
        enable(&mut d, ModeOfOperation::ProfilePosition, 10 * MS);
        assert_eq!(statusword(&mut d, 13 * MS), 0x0637);

        // New set-point: acknowledged (bit 12) while bit 4 is high.
        let start = 20 * MS;
        let out = d.on_frame(&rpdo1(0x001F, 10_000), start);
        assert_eq!(wire(&out), [tpdo1(0x1237, 0)]);
        let out = d.on_frame(&rpdo1(0x000F, 10_000), start);
        assert_eq!(wire(&out), [tpdo1(0x0237, 0)]);

        let mut positions = vec![0];
        let mut reached_at = None;
        let mut vmax = 0.0f64;
        run(&mut d, start + 2000 * MS, |d, t| {
            positions.push(d.position().round() as i32);
            vmax = vmax.max(d.velocity());
            if reached_at.is_none() && d.statusword().target_reached() {
                reached_at = Some(t - start);
            }
        });
        assert!(positions.windows(2).all(|w| w[0] <= w[1]), "monotonic");
        assert_eq!(*positions.last().unwrap(), 10_000);
        assert!(vmax <= 10_000.0, "profile velocity respected: {vmax}");
        // 0.1 s accelerating, 0.9 s at 10000 inc/s, 0.1 s braking.
        let reached_at = reached_at.unwrap();
        assert!(
            (1090 * MS..=1120 * MS).contains(&reached_at),
            "reached after {reached_at:?}"
        );
        let now = start + 2001 * MS;
        assert_eq!(statusword(&mut d, now), 0x0637);
        assert_eq!(read_i32(&mut d, obj::POSITION_ACTUAL, now), 10_000);
        assert_eq!(read_i32(&mut d, obj::VELOCITY_ACTUAL, now), 0);

        // A relative move adds to the previous target.
        let start = 3000 * MS;
        d.on_frame(&rpdo1(0x005F, 500), start);
        d.on_frame(&rpdo1(0x004F, 500), start + MS);
        run(&mut d, start + 1000 * MS, |_, _| {});
        assert_eq!(d.position(), 10_500.0);
        assert_eq!(d.statusword(), Statusword(0x0637));
    }

    #[test]
    fn profile_position_halt_buffer_and_change_immediately() {
        let mut d = operational();
        enable(&mut d, ModeOfOperation::ProfilePosition, 10 * MS);
        d.on_frame(&rpdo1(0x001F, 10_000), 20 * MS);
        d.on_frame(&rpdo1(0x000F, 10_000), 21 * MS);
        run(&mut d, 300 * MS, |_, _| {});
        assert_eq!(d.velocity(), 10_000.0);

        // Halt: brakes to standstill, target reached while halted.
        d.on_frame(&rpdo1(0x010F, 10_000), 300 * MS);
        run(&mut d, 450 * MS, |_, _| {});
        assert_eq!(d.velocity(), 0.0);
        let halted_at = d.position();
        assert!(halted_at < 10_000.0);
        assert_eq!(d.statusword(), Statusword(0x0637));
        // Released: the move continues to the target.
        d.on_frame(&rpdo1(0x000F, 10_000), 450 * MS);
        assert_eq!(d.statusword(), Statusword(0x0237));
        run(&mut d, 500 * MS, |_, _| {});
        assert!(d.position() > halted_at);

        // A second set-point without "change set immediately" is buffered
        // and runs after the first; a third is refused (no acknowledge).
        d.on_frame(&rpdo1(0x001F, 12_000), 500 * MS);
        assert!(d.statusword().set_point_acknowledge());
        d.on_frame(&rpdo1(0x000F, 12_000), 501 * MS);
        d.on_frame(&rpdo1(0x001F, 99_999), 502 * MS);
        assert!(!d.statusword().set_point_acknowledge());
        d.on_frame(&rpdo1(0x000F, 99_999), 503 * MS);
        let mut passed_first = false;
        run(&mut d, 3000 * MS, |d, _| {
            passed_first |= d.position() > 10_000.0;
        });
        assert!(passed_first);
        assert_eq!(d.position(), 12_000.0);

        // "Change set immediately" replaces the target during a move,
        // here reversing the direction.
        d.on_frame(&rpdo1(0x001F, 20_000), 3000 * MS);
        d.on_frame(&rpdo1(0x000F, 20_000), 3001 * MS);
        run(&mut d, 3200 * MS, |_, _| {});
        assert!(d.position() > 12_000.0);
        d.on_frame(&rpdo1(0x003F, 11_000), 3200 * MS);
        d.on_frame(&rpdo1(0x002F, 11_000), 3201 * MS);
        run(&mut d, 5000 * MS, |_, _| {});
        assert_eq!(d.position(), 11_000.0);
        assert_eq!(d.statusword(), Statusword(0x0637));
    }

    #[test]
    fn profile_velocity_ramps_to_the_target_velocity() {
        let mut d = operational();
        sdo_write(&mut d, obj::MODES_OF_OPERATION, &[3], 5 * MS);
        for (k, cw) in [0x0006u16, 0x0007, 0x000F].into_iter().enumerate() {
            d.on_frame(&rpdo2(cw, 0), MS * (10 + k as u32));
        }
        // At rest on a zero target: target reached and speed 0 (bit 12).
        assert_eq!(statusword(&mut d, 13 * MS), 0x1637);

        // Target velocity set: target no longer reached, still at speed 0.
        let out = d.on_frame(&rpdo2(0x000F, 5000), 20 * MS);
        assert_eq!(wire(&out), [tpdo1(0x1237, 0)]);
        let mut velocities = Vec::new();
        run(&mut d, 70 * MS, |d, _| velocities.push(d.velocity()));
        // 100000 inc/s²: 100 inc/s more every millisecond.
        assert_eq!(velocities[0], 100.0);
        assert_eq!(velocities[49], 5000.0);
        assert!(velocities.windows(2).all(|w| w[0] <= w[1]));
        assert_eq!(statusword(&mut d, 70 * MS), 0x0637);
        assert_eq!(read_i32(&mut d, obj::VELOCITY_ACTUAL, 70 * MS), 5000);
        let pos = read_i32(&mut d, obj::POSITION_ACTUAL, 70 * MS);
        // The 50 ms ramp: 100 + 200 + … + 5000 inc/s for 1 ms each.
        assert!((127..=128).contains(&pos), "position {pos}");

        // Back to zero with the deceleration.
        d.on_frame(&rpdo2(0x000F, 0), 100 * MS);
        run(&mut d, 160 * MS, |_, _| {});
        assert_eq!(d.velocity(), 0.0);
        assert_eq!(statusword(&mut d, 160 * MS), 0x1637);
        // Reversing and halt.
        d.on_frame(&rpdo2(0x000F, -2000), 200 * MS);
        run(&mut d, 300 * MS, |_, _| {});
        assert_eq!(d.velocity(), -2000.0);
        d.on_frame(&rpdo2(0x010F, -2000), 300 * MS);
        run(&mut d, 400 * MS, |_, _| {});
        assert_eq!(d.velocity(), 0.0);
        assert_eq!(d.statusword(), Statusword(0x1637));
    }

    #[test]
    fn homing_method_35_sets_the_home_offset() {
        let mut d = operational();
        sdo_write(&mut d, obj::HOME_OFFSET, &1234i32.to_le_bytes(), 2 * MS);
        enable(&mut d, ModeOfOperation::Homing, 10 * MS);
        // Not started: "homing interrupted or not started".
        assert_eq!(statusword(&mut d, 13 * MS), 0x0637);
        let out = d.on_frame(&rpdo1(0x001F, 0), 20 * MS);
        // Homing attained + target reached, position = home offset.
        assert_eq!(wire(&out), [tpdo1(0x1637, 1234)]);
        assert_eq!(read_i32(&mut d, obj::POSITION_ACTUAL, 21 * MS), 1234);
        assert_eq!(
            d.statusword().homing_status(),
            cangate_canopen::cia402::HomingStatus::Completed
        );
        // Attained stays after bit 4 falls.
        d.on_frame(&rpdo1(0x000F, 0), 22 * MS);
        assert_eq!(statusword(&mut d, 23 * MS), 0x1637);

        // An unsupported method (1: index pulse) ends in homing error.
        sdo_write(&mut d, obj::HOMING_METHOD, &[1], 30 * MS);
        d.on_frame(&rpdo1(0x001F, 0), 31 * MS);
        assert_eq!(statusword(&mut d, 32 * MS), 0x2637);
    }

    #[test]
    fn homing_on_the_virtual_switch() {
        let mut d = operational();
        // Move to 3000 first.
        enable(&mut d, ModeOfOperation::ProfilePosition, 10 * MS);
        d.on_frame(&rpdo1(0x001F, 3000), 20 * MS);
        d.on_frame(&rpdo1(0x000F, 3000), 21 * MS);
        run(&mut d, 1000 * MS, |_, _| {});
        assert_eq!(d.position(), 3000.0);

        // Method 17 at 0x6099:01 = 1000 inc/s towards the switch at 0,
        // then the position becomes the home offset.
        sdo_write(&mut d, obj::HOMING_METHOD, &[17], 1000 * MS);
        sdo_write(
            &mut d,
            obj::HOMING_SPEED_SWITCH,
            &1000u32.to_le_bytes(),
            1000 * MS,
        );
        sdo_write(
            &mut d,
            obj::HOMING_ACCELERATION,
            &10_000u32.to_le_bytes(),
            1000 * MS,
        );
        sdo_write(&mut d, obj::HOME_OFFSET, &(-50i32).to_le_bytes(), 1000 * MS);
        sdo_write(&mut d, obj::MODES_OF_OPERATION, &[6], 1000 * MS);
        d.on_frame(&rpdo1(0x001F, 0), 1001 * MS);
        assert_eq!(d.statusword(), Statusword(0x0237)); // in progress
        let mut positions = Vec::new();
        let mut vmax = 0.0f64;
        run(&mut d, 1500 * MS, |d, _| {
            positions.push(d.position());
            vmax = vmax.max(d.velocity().abs());
        });
        assert!(positions.windows(2).all(|w| w[0] > w[1]), "moving down");
        assert_eq!(vmax, 1000.0);
        // Bit 4 low interrupts homing.
        d.on_frame(&rpdo1(0x000F, 0), 1500 * MS);
        run(&mut d, 1700 * MS, |_, _| {});
        assert_eq!(d.velocity(), 0.0);
        assert_eq!(d.statusword(), Statusword(0x0637));
        // Restarted, it completes.
        d.on_frame(&rpdo1(0x001F, 0), 1700 * MS);
        run(&mut d, 6000 * MS, |_, _| {});
        assert_eq!(d.position(), -50.0);
        assert_eq!(statusword(&mut d, 6000 * MS), 0x1637);
        assert_eq!(read_i32(&mut d, obj::POSITION_ACTUAL, 6000 * MS), -50);
    }

    #[test]
    fn fault_injection_emcy_and_fault_reset() {
        let mut d = operational();
        enable(&mut d, ModeOfOperation::ProfileVelocity, 10 * MS);
        d.on_frame(&rpdo2(0x000F, 3000), 20 * MS);
        run(&mut d, 100 * MS, |_, _| {});
        assert_eq!(d.velocity(), 3000.0);

        let out = d.inject_fault(0x2310);
        assert_eq!(
            wire(&out),
            [
                (0x085, vec![0x10, 0x23, 0x03, 0, 0, 0, 0, 0]),
                tpdo1(0x021F, d.position().round() as i32),
            ]
        );
        assert_eq!(d.state(), DriveState::FaultReactionActive);
        // The fault reaction brakes with the quick stop deceleration.
        run(&mut d, 200 * MS, |_, _| {});
        assert_eq!(d.state(), DriveState::Fault);
        assert_eq!(d.velocity(), 0.0);
        assert_eq!(statusword(&mut d, 200 * MS), 0x0208);
        assert_eq!(read_u16(&mut d, obj::ERROR_CODE, 200 * MS), 0x2310);
        assert_eq!(
            sdo_read(&mut d, ObjectAddress::new(0x1001, 0), 200 * MS),
            [0x03]
        );
        // No model steps in fault: the next deadline is TPDO1's event
        // timer, restarted when the fault statusword went out at 130 ms.
        assert_eq!(d.next_deadline(), Some(230 * MS));

        // Enabling does nothing in fault.
        assert!(d.on_frame(&rpdo2(0x000F, 0), 210 * MS).is_empty());
        assert_eq!(d.state(), DriveState::Fault);
        // Fault reset: rising edge of bit 7 → switch on disabled, EMCY reset.
        let out = d.on_frame(&rpdo2(0x0080, 0), 220 * MS);
        let pos = d.position().round() as i32;
        assert_eq!(wire(&out), [(0x085, vec![0; 8]), tpdo1(0x0240, pos)]);
        assert_eq!(read_u16(&mut d, obj::ERROR_CODE, 221 * MS), 0);
        assert_eq!(
            sdo_read(&mut d, ObjectAddress::new(0x1001, 0), 221 * MS),
            [0]
        );

        // A fault while bit 7 is held needs a new edge.
        d.inject_fault(0x4310);
        run(&mut d, 230 * MS, |_, _| {});
        assert_eq!(d.state(), DriveState::Fault);
        d.on_frame(&rpdo2(0x0080, 0), 230 * MS);
        assert_eq!(d.state(), DriveState::Fault);
        d.on_frame(&rpdo2(0x0000, 0), 231 * MS);
        d.on_frame(&rpdo2(0x0080, 0), 232 * MS);
        assert_eq!(d.state(), DriveState::SwitchOnDisabled);

        // Enabled again.
        for (k, cw) in [0x0006u16, 0x0007, 0x000F].into_iter().enumerate() {
            d.on_frame(&rpdo2(cw, 0), MS * (240 + k as u32));
        }
        assert_eq!(statusword(&mut d, 250 * MS), 0x1637);
    }

    #[test]
    fn software_position_limits() {
        let mut d = operational();
        let max = obj::SOFTWARE_POSITION_LIMIT_MAX;
        let min = obj::SOFTWARE_POSITION_LIMIT_MIN;
        sdo_write(&mut d, max, &2000i32.to_le_bytes(), MS);
        sdo_write(&mut d, min, &(-1000i32).to_le_bytes(), MS);
        enable(&mut d, ModeOfOperation::ProfilePosition, 10 * MS);
        d.on_frame(&rpdo1(0x001F, 5000), 20 * MS);
        d.on_frame(&rpdo1(0x000F, 5000), 21 * MS);
        run(&mut d, 1000 * MS, |d, _| assert!(d.position() <= 2000.0));
        assert_eq!(d.position(), 2000.0);
        // Target reached + internal limit.
        assert_eq!(statusword(&mut d, 1000 * MS), 0x0E37);

        // Profile velocity stops at the lower limit.
        sdo_write(&mut d, obj::MODES_OF_OPERATION, &[3], 1000 * MS);
        d.on_frame(&rpdo2(0x000F, -10_000), 1001 * MS);
        run(&mut d, 2000 * MS, |d, _| assert!(d.position() >= -1000.0));
        assert_eq!(d.position(), -1000.0);
        let sw = d.statusword();
        assert!(sw.internal_limit(), "{sw}");
        assert!(!sw.target_reached(), "{sw}");
        // Away from the limit, the bit clears.
        d.on_frame(&rpdo2(0x000F, 1000), 2000 * MS);
        run(&mut d, 2100 * MS, |_, _| {});
        assert!(!d.statusword().internal_limit());
        assert!(d.position() > -1000.0);
    }

    #[test]
    fn quick_stop_then_switch_on_disabled_or_stay() {
        let mut d = operational();
        enable(&mut d, ModeOfOperation::ProfileVelocity, 10 * MS);
        d.on_frame(&rpdo2(0x000F, 5000), 20 * MS);
        run(&mut d, 100 * MS, |_, _| {});
        // Option code 2 (default): brake, then switch on disabled.
        let out = d.on_frame(&rpdo2(0x0002, 5000), 100 * MS);
        let pos = d.position().round() as i32;
        assert_eq!(wire(&out), [tpdo1(0x0217, pos)]);
        let mut stopped_at = None;
        run(&mut d, 200 * MS, |d, t| {
            if stopped_at.is_none() && d.state() == DriveState::SwitchOnDisabled {
                stopped_at = Some(t);
            }
        });
        assert_eq!(stopped_at, Some(150 * MS));
        assert_eq!(statusword(&mut d, 200 * MS), 0x0240);

        // Option code 6: stay in quick stop active; enable operation (16).
        sdo_write(
            &mut d,
            obj::QUICK_STOP_OPTION_CODE,
            &6i16.to_le_bytes(),
            200 * MS,
        );
        for (k, cw) in [0x0006u16, 0x0007, 0x000F].into_iter().enumerate() {
            d.on_frame(&rpdo2(cw, 5000), MS * (210 + k as u32));
        }
        run(&mut d, 300 * MS, |_, _| {});
        d.on_frame(&rpdo2(0x0002, 5000), 300 * MS);
        run(&mut d, 400 * MS, |_, _| {});
        assert_eq!(d.state(), DriveState::QuickStopActive);
        assert_eq!(statusword(&mut d, 400 * MS), 0x0617);
        d.on_frame(&rpdo2(0x000F, 5000), 400 * MS);
        assert_eq!(d.state(), DriveState::OperationEnabled);
        run(&mut d, 500 * MS, |_, _| {});
        assert_eq!(d.velocity(), 5000.0);
    }

    #[test]
    fn tpdo_on_sync_carries_the_current_position() {
        let mut d = operational();
        // TPDO1 synchronous, every SYNC.
        sdo_write(&mut d, ObjectAddress::new(0x1800, 2), &[1], MS);
        enable(&mut d, ModeOfOperation::ProfileVelocity, 10 * MS);
        d.on_frame(&rpdo2(0x000F, 5000), 20 * MS);
        run(&mut d, 100 * MS, |_, _| {});
        let sync = frame(0x080, &[]);
        let out = d.on_frame(&sync, 100 * MS + MS / 2);
        let pos = d.position().round() as i32;
        assert_eq!(pos, 128 + 150); // ramp, then 30 ms at 5000 inc/s
        assert!(wire(&out).contains(&tpdo1(0x0637, pos)));
        run(&mut d, 110 * MS, |_, _| {});
        let out = d.on_frame(&sync, 110 * MS + MS / 2);
        assert!(wire(&out).contains(&tpdo1(0x0637, pos + 50)));
        assert!(d.take_events().contains(&SimEvent::Sync { counter: None }));
    }

    #[test]
    fn the_drive_can_run_on_the_runner() {
        fn device<D: Device + Send + 'static>(_: &D) {}
        device(&drive());
    }

    /// The drive EDS plus 0x6065 following error window (100) and 0x60F4
    /// following error actual value.
    fn with_following_error_objects() -> SimDrive {
        let mut od = Eds::parse(SIM_DRIVE_EDS).unwrap().od_with_dummies();
        let mut window = Variable::new(
            obj::FOLLOWING_ERROR_WINDOW,
            "Following error window",
            DataType::Unsigned32,
            AccessType::Rw,
        );
        window.default = Some(DefaultValue::fixed(Value::Unsigned32(100)));
        od.insert(Object::var(window));
        let mut actual = Variable::new(
            obj::FOLLOWING_ERROR_ACTUAL,
            "Following error actual value",
            DataType::Integer32,
            AccessType::Ro,
        );
        actual.default = Some(DefaultValue::fixed(Value::Integer32(0)));
        od.insert(Object::var(actual));
        let mut d = SimDrive::from_od(od, NodeId::new(5).unwrap(), SimDriveOptions::default());
        d.start(Duration::ZERO);
        d.on_frame(&frame(0x000, &[0x01, 0x05]), Duration::ZERO);
        d
    }

    #[test]
    fn cyclic_synchronous_position_follows_with_a_lag() {
        let mut d = with_following_error_objects();
        enable(&mut d, ModeOfOperation::CyclicSynchronousPosition, 10 * MS);
        assert_eq!(d.statusword(), Statusword(0x1237));
        // A ramp of 10 inc per millisecond, one RPDO per millisecond.
        let mut lag = 0.0;
        for k in 1..=100i32 {
            let t = MS * (20 + k as u32);
            d.on_frame(&rpdo1(0x000F, 10 * k), t);
            d.on_tick(t);
            lag = d.following_error();
            assert!(d.position() <= f64::from(10 * k));
        }
        // Steady lag of a first-order system: about v·τ = 10000 · 5 ms.
        assert!((45.0..=60.0).contains(&lag), "lag {lag}");
        assert_eq!(
            read_i32(&mut d, obj::FOLLOWING_ERROR_ACTUAL, 120 * MS),
            lag.round() as i32
        );
        run(&mut d, 300 * MS, |_, _| {});
        assert_eq!(d.position(), 1000.0);
        assert_eq!(d.velocity(), 0.0);
        assert_eq!(statusword(&mut d, 300 * MS), 0x1237);
    }

    /// Issue 14, item 4: with set-points every SYNC (10 ms) on a ramp of
    /// 10 mm/s, the velocity the drive reports (0x606C, read at each SYNC
    /// as its TPDO would) is the derivative of its position within 2 %.
    #[test]
    fn cyclic_position_velocity_feedback_is_the_position_derivative() {
        let mut d = with_following_error_objects();
        enable(&mut d, ModeOfOperation::CyclicSynchronousPosition, 10 * MS);
        let sync = frame(0x080, &[]);
        let mut samples = Vec::new();
        for k in 1..=60i32 {
            let t = MS * (20 + 10 * k as u32);
            d.on_frame(&sync, t);
            samples.push((
                f64::from(read_i32(&mut d, obj::POSITION_ACTUAL, t)),
                f64::from(read_i32(&mut d, obj::VELOCITY_ACTUAL, t)),
            ));
            // The set-point of this SYNC: 10 000 inc/s.
            d.on_frame(&rpdo1(0x000F, 100 * k), t);
        }
        // After the start-up (the first 10 SYNCs), every SYNC.
        for w in samples[10..].windows(2) {
            let derivative = (w[1].0 - w[0].0) / 0.010;
            let reported = w[1].1;
            assert!(
                (reported - derivative).abs() <= 0.02 * derivative.abs(),
                "0x606C {reported} against the position's derivative {derivative}"
            );
            assert!((derivative - 10_000.0).abs() <= 200.0, "{derivative}");
        }
    }

    #[test]
    fn following_error_beyond_the_window_faults() {
        let mut d = with_following_error_objects();
        enable(&mut d, ModeOfOperation::CyclicSynchronousPosition, 10 * MS);
        d.on_frame(&rpdo1(0x000F, 5000), 20 * MS);
        // The fault reaction brakes from the top speed (100 000 inc/s).
        let out = run(&mut d, 1100 * MS, |_, _| {});
        let emcy: Vec<_> = out
            .iter()
            .filter(|(_, f)| f.raw_id() == 0x085)
            .map(|(t, f)| (*t, f.data().to_vec()))
            .collect();
        assert_eq!(emcy, [(21 * MS, vec![0x11, 0x86, 0x01, 0, 0, 0, 0, 0])]);
        assert_eq!(d.state(), DriveState::Fault);
        assert_eq!(d.error_code(), 0x8611);
    }

    #[test]
    fn nmt_reset_node_restarts_the_drive() {
        let mut d = operational();
        sdo_write(&mut d, obj::HOME_OFFSET, &700i32.to_le_bytes(), MS);
        enable(&mut d, ModeOfOperation::Homing, 10 * MS);
        d.on_frame(&rpdo1(0x001F, 0), 20 * MS);
        assert_eq!(d.position(), 700.0);
        let out = d.on_frame(&frame(0x000, &[0x81, 0x05]), 30 * MS);
        assert_eq!(wire(&out), [(0x705, vec![0x00])]);
        assert_eq!(d.state(), DriveState::SwitchOnDisabled);
        assert_eq!(d.mode(), None);
        // Same physical place, homing offset gone.
        assert_eq!(d.position(), 0.0);
        assert_eq!(statusword(&mut d, 31 * MS), 0x0240);
        assert!(d.take_events().iter().any(|e| matches!(
            e,
            SimEvent::Reset {
                kind: NmtReset::Node
            }
        )));
    }

    /// The bundled drive at node 5 with switches and a touch probe input,
    /// operational since t = 0.
    fn with_inputs(inputs: SimDriveInputs) -> SimDrive {
        let options = SimDriveOptions {
            inputs,
            ..SimDriveOptions::default()
        };
        let mut d = SimDrive::bundled(NodeId::new(5).unwrap(), options);
        d.start(Duration::ZERO);
        d.on_frame(&frame(0x000, &[0x01, 0x05]), Duration::ZERO);
        d
    }

    #[test]
    fn limit_switch_stops_motion_into_it_and_lets_it_back_off() {
        let mut d = with_inputs(SimDriveInputs {
            negative_limit_switch: Some(-3000),
            positive_limit_switch: Some(2000),
            home_switch: Some(500),
            touch_probe: None,
        });
        // Quick stop deceleration (0x6084 here: the EDS has no 0x6085).
        sdo_write(
            &mut d,
            obj::PROFILE_DECELERATION,
            &100_000u32.to_le_bytes(),
            MS,
        );
        assert_eq!(sdo_read(&mut d, obj::DIGITAL_INPUTS, MS), [0, 0, 0, 0]);
        enable(&mut d, ModeOfOperation::ProfileVelocity, 10 * MS);
        d.on_frame(&rpdo2(0x000F, 10_000), 20 * MS);
        let mut max_pos = 0.0f64;
        run(&mut d, 1000 * MS, |d, _| {
            max_pos = max_pos.max(d.position())
        });
        // Braked from 10 000 inc/s at 100 000 inc/s²: 500 inc beyond the
        // switch at most (plus the step on which it engaged).
        assert!(
            (2000.0..=2000.0 + 500.0 + 10.0).contains(&max_pos),
            "{max_pos}"
        );
        assert_eq!(d.velocity(), 0.0);
        // Bits 1 (positive limit) and 2 (home) of 0x60FD.
        assert_eq!(
            sdo_read(&mut d, obj::DIGITAL_INPUTS, 1000 * MS),
            [0x06, 0, 0, 0]
        );
        assert!(d.statusword().internal_limit());
        assert_eq!(d.state(), DriveState::OperationEnabled);
        // Still commanded into it: it stays.
        run(&mut d, 1100 * MS, |_, _| {});
        assert_eq!(d.position(), max_pos);
        // Away from it: runs, and the bits clear.
        d.on_frame(&rpdo2(0x000F, -5000), 1100 * MS);
        run(&mut d, 1800 * MS, |_, _| {});
        assert!(d.position() < 0.0, "{}", d.position());
        assert_eq!(
            sdo_read(&mut d, obj::DIGITAL_INPUTS, 1800 * MS),
            [0, 0, 0, 0]
        );
        // On to the negative switch: bit 0.
        run(&mut d, 4000 * MS, |_, _| {});
        let p = d.position();
        assert!((-3000.0 - 135.0..=-3000.0).contains(&p), "{p}");
        assert_eq!(d.velocity(), 0.0);
        assert_eq!(
            sdo_read(&mut d, obj::DIGITAL_INPUTS, 4000 * MS),
            [0x01, 0, 0, 0]
        );
    }

    #[test]
    fn touch_probe_latches_the_crossing_single_and_continuous() {
        let mut d = with_inputs(SimDriveInputs {
            touch_probe: Some(1500),
            ..SimDriveInputs::default()
        });
        // 0x60B8 = 0x0031: probe 1 on, first edge only, both edges.
        let out = d.on_frame(
            &frame(0x605, &[0x2B, 0xB8, 0x60, 0x00, 0x31, 0x00, 0, 0]),
            MS,
        );
        assert_eq!(
            wire(&out),
            [(0x585, vec![0x60, 0xB8, 0x60, 0x00, 0, 0, 0, 0])]
        );
        assert_eq!(sdo_read(&mut d, obj::TOUCH_PROBE_STATUS, MS), [0x01, 0x00]);
        enable(&mut d, ModeOfOperation::ProfileVelocity, 10 * MS);
        d.on_frame(&rpdo2(0x000F, 7000), 20 * MS);
        run(&mut d, 500 * MS, |_, _| {});
        assert!(d.position() > 1500.0);
        // Positive edge stored, at the probe's position exactly.
        assert_eq!(
            sdo_read(&mut d, obj::TOUCH_PROBE_STATUS, 500 * MS),
            [0x03, 0x00]
        );
        assert_eq!(
            sdo_read(&mut d, obj::TOUCH_PROBE_1_POSITIVE, 500 * MS),
            1500i32.to_le_bytes()
        );
        // Back down across it: the negative edge.
        d.on_frame(&rpdo2(0x000F, -7000), 500 * MS);
        run(&mut d, 1000 * MS, |_, _| {});
        assert!(d.position() < 1500.0);
        assert_eq!(
            sdo_read(&mut d, obj::TOUCH_PROBE_STATUS, 1000 * MS),
            [0x07, 0x00]
        );
        assert_eq!(
            sdo_read(&mut d, obj::TOUCH_PROBE_1_NEGATIVE, 1000 * MS),
            1500i32.to_le_bytes()
        );
        // Homed with an offset: the latch is in reported positions. Up
        // again: first-edge mode latches nothing new.
        d.on_frame(&rpdo2(0x000F, 7000), 1000 * MS);
        run(&mut d, 2000 * MS, |_, _| {});
        assert_eq!(
            sdo_read(&mut d, obj::TOUCH_PROBE_STATUS, 2000 * MS),
            [0x07, 0x00]
        );
        // Re-armed continuous, rising only (0x0013): every rising edge.
        sdo_write(&mut d, obj::TOUCH_PROBE_FUNCTION, &[0x13, 0x00], 2000 * MS);
        assert_eq!(
            sdo_read(&mut d, obj::TOUCH_PROBE_STATUS, 2000 * MS),
            [0x01, 0x00]
        );
        d.on_frame(&rpdo2(0x000F, -7000), 2000 * MS);
        run(&mut d, 3500 * MS, |_, _| {});
        assert_eq!(
            sdo_read(&mut d, obj::TOUCH_PROBE_STATUS, 3500 * MS),
            [0x01, 0x00]
        );
        d.on_frame(&rpdo2(0x000F, 7000), 3500 * MS);
        run(&mut d, 5000 * MS, |_, _| {});
        assert_eq!(
            sdo_read(&mut d, obj::TOUCH_PROBE_STATUS, 5000 * MS),
            [0x03, 0x00]
        );
    }

    /// TPDO3 mapped by SDO with torque, digital inputs and probe status
    /// goes out at every SYNC with them.
    #[test]
    fn signals_tpdo_on_sync_with_exact_bytes() {
        let mut d = with_inputs(SimDriveInputs {
            positive_limit_switch: Some(0),
            ..SimDriveInputs::default()
        });
        let comm = 0x1802;
        let map = 0x1A02;
        sdo_write(
            &mut d,
            ObjectAddress::new(comm, 1),
            &0x8000_0385u32.to_le_bytes(),
            MS,
        );
        sdo_write(&mut d, ObjectAddress::new(comm, 2), &[1], MS);
        sdo_write(&mut d, ObjectAddress::new(map, 0), &[0], MS);
        sdo_write(
            &mut d,
            ObjectAddress::new(map, 1),
            &0x6077_0010u32.to_le_bytes(),
            MS,
        );
        sdo_write(
            &mut d,
            ObjectAddress::new(map, 2),
            &0x60FD_0020u32.to_le_bytes(),
            MS,
        );
        sdo_write(
            &mut d,
            ObjectAddress::new(map, 3),
            &0x60B9_0010u32.to_le_bytes(),
            MS,
        );
        sdo_write(&mut d, ObjectAddress::new(map, 0), &[3], MS);
        sdo_write(
            &mut d,
            ObjectAddress::new(comm, 1),
            &0x0000_0385u32.to_le_bytes(),
            MS,
        );
        sdo_write(&mut d, obj::TOUCH_PROBE_FUNCTION, &[0x11, 0x00], MS);
        let out = d.on_frame(&frame(0x080, &[]), 2 * MS);
        assert!(
            wire(&out).contains(&(0x385, vec![0, 0, 0x02, 0, 0, 0, 0x01, 0x00])),
            "{:02X?}",
            wire(&out)
        );
    }

    /// The state machine driver of the CiA 402 core enables the simulated
    /// drive from fault, reading TPDO1 and writing RPDO1.
    #[test]
    fn state_machine_driver_enables_the_simulated_drive() {
        let mut d = operational();
        d.inject_fault(0x3210);
        run(&mut d, 5 * MS, |_, _| {});
        assert_eq!(d.state(), DriveState::Fault);

        let mut driver =
            StateMachineDriver::new(DriveState::OperationEnabled, 500 * MS, 10 * MS).unwrap();
        let mut sent = Vec::new();
        let mut now = 10 * MS;
        // The first statusword by SDO, the rest from TPDO1.
        let mut statuswords = vec![statusword(&mut d, now)];
        let result = loop {
            let step = match statuswords.pop() {
                Some(sw) => driver.on_statusword(Statusword(sw), now),
                None => driver.on_tick(now),
            };
            match step {
                DriverStep::Send(cw) => {
                    sent.push(cw.bits());
                    now += MS;
                    for f in d.on_frame(&rpdo1(cw.bits(), 0), now) {
                        if f.raw_id() == 0x185 {
                            statuswords.insert(0, u16::from_le_bytes([f.data()[0], f.data()[1]]));
                        }
                    }
                }
                DriverStep::Wait => now += MS,
                DriverStep::Done(result) => break result,
            }
        };
        assert_eq!(result, Ok(()));
        assert_eq!(sent, [0x0080, 0x0006, 0x0007, 0x000F]);
        assert_eq!(d.statusword(), Statusword(0x0237));
    }

    const SEC: Duration = Duration::from_secs(1);

    /// A drive at node 5 with `options`, operational since t = 0.
    fn operational_with(options: SimDriveOptions) -> SimDrive {
        let mut d = SimDrive::bundled(NodeId::new(5).unwrap(), options);
        d.start(Duration::ZERO);
        d.on_frame(&frame(0x000, &[0x01, 0x05]), Duration::ZERO);
        d
    }

    #[test]
    fn cyclic_synchronous_torque_drives_the_torque_model_and_halts() {
        let mut d = operational();
        enable(&mut d, ModeOfOperation::CyclicSynchronousTorque, 10 * MS);
        // 0x6071 = 30 per mille (expedited download of 2 bytes).
        let reply = d.on_frame(
            &frame(0x605, &[0x2B, 0x71, 0x60, 0x00, 0x1E, 0x00, 0x00, 0x00]),
            20 * MS,
        );
        assert!(
            wire(&reply).contains(&(0x585, vec![0x60, 0x71, 0x60, 0x00, 0, 0, 0, 0])),
            "{reply:?}"
        );
        // 30 - 10 (Coulomb) per mille against 1 per mille per 1000
        // counts/s: 20 000 counts/s at the end, with a time constant of
        // 1 s (inertia 1000 counts/s² per per mille over the viscous
        // friction).
        run(&mut d, Duration::from_millis(1020), |_, _| {});
        let v1 = d.velocity();
        assert!(
            (v1 - 20_000.0 * (1.0 - (-1.0f64).exp())).abs() < 300.0,
            "{v1}"
        );
        run(&mut d, Duration::from_secs(6), |_, _| {});
        assert!((d.velocity() - 20_000.0).abs() < 100.0, "{}", d.velocity());
        assert_eq!(
            sdo_read(&mut d, obj::TORQUE_ACTUAL, 6 * SEC),
            vec![0x1E, 0x00]
        );
        // Halt (0x010F): the velocity loop brakes at 0x6084 (100 000
        // counts/s²) within 0.2 s, and holds; bit 12 drops.
        let target = d.position().round() as i32;
        d.on_frame(&rpdo1(0x010F, target), 6 * SEC);
        run(&mut d, 6 * SEC + Duration::from_millis(210), |_, _| {});
        assert_eq!(d.velocity(), 0.0);
        assert_eq!(d.statusword().bits() & Statusword::OMS_12, 0);
        let at = d.position();
        run(&mut d, 7 * SEC, |_, _| {});
        assert_eq!(d.position(), at, "the halt holds against the torque");
    }

    #[test]
    fn interpolated_position_reaches_0x60c1_over_the_interpolation_period() {
        let mut d = operational_with(SimDriveOptions {
            follow_time_constant: Duration::ZERO,
            ..SimDriveOptions::default()
        });
        // 0x60C2 = 10 x 10^-3 s.
        sdo_write(&mut d, obj::INTERPOLATION_PERIOD_VALUE, &[10], 5 * MS);
        enable(&mut d, ModeOfOperation::InterpolatedPosition, 10 * MS);
        // Without bit 4 (enable ip mode) a set-point is not taken.
        sdo_write(
            &mut d,
            obj::INTERPOLATION_DATA,
            &1000i32.to_le_bytes(),
            20 * MS,
        );
        run(&mut d, 40 * MS, |_, _| {});
        assert_eq!(d.position(), 0.0);
        assert_eq!(d.statusword().bits() & Statusword::OMS_12, 0);
        // Bit 4 set (controlword 0x001F): from 0 to 1000 over 10 ms.
        d.on_frame(&rpdo1(0x001F, 0), 40 * MS);
        let mut seen = Vec::new();
        run(&mut d, 52 * MS, |d, t| seen.push((t, d.position())));
        assert_ne!(
            d.statusword().bits() & Statusword::OMS_12,
            0,
            "ip mode active"
        );
        let at = |ms: u64| {
            seen.iter()
                .find(|(t, _)| *t == Duration::from_millis(ms))
                .map(|(_, p)| *p)
        };
        let near = |got: Option<f64>, want: f64| got.is_some_and(|p| (p - want).abs() < 1e-6);
        assert!(near(at(45), 500.0), "{seen:?}");
        assert!(near(at(50), 1000.0), "{seen:?}");
        assert!((d.position() - 1000.0).abs() < 1e-6);
    }

    #[test]
    fn a_mode_outside_the_configured_supported_modes_is_not_taken() {
        // PP, PV, HM, IP, CSV: no CSP.
        let mut d = operational_with(SimDriveOptions {
            supported_modes: Some(0x165),
            ..SimDriveOptions::default()
        });
        assert_eq!(
            sdo_read(&mut d, obj::SUPPORTED_DRIVE_MODES, MS),
            vec![0x65, 0x01, 0x00, 0x00]
        );
        sdo_write(&mut d, obj::MODES_OF_OPERATION, &[0x08], 2 * MS);
        assert_eq!(d.mode(), None);
        assert_eq!(
            sdo_read(&mut d, obj::MODES_OF_OPERATION_DISPLAY, 3 * MS),
            vec![0x00]
        );
        sdo_write(&mut d, obj::MODES_OF_OPERATION, &[0x07], 4 * MS);
        assert_eq!(d.mode(), Some(ModeOfOperation::InterpolatedPosition));
    }
}
