//! [`AxisSpec`]: the one description of an axis, whatever drives it.
//!
//! What every axis has (units, limits, the defaults of moves, the stops,
//! the time bounds) is one [`MotionSpec`]; what belongs to a drive family
//! is its [`DriveSpec`]: a CiA 402 drive on a CANopen bus, or a CANsmc
//! slave of a master. The controllers ([`crate::cia402::Cia402Axis`],
//! [`crate::cansmc::CansmcAxis`]) take the shared part and their family's
//! part from it; the runtime and the API read the axis's facts from it.

use std::time::Duration;

use cangate_canopen::NodeId;
use cangate_cansmc::SmcAddress;

use crate::{DriveMode, PositionMode, StopKind, Units};

/// One axis: its name, what every axis has, how it stops when its
/// controller goes away, and its drive.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisSpec {
    /// Unique name among all axes of the gateway, e.g. "X".
    pub name: String,
    /// Units, limits, defaults, stops, time bounds.
    pub motion: MotionSpec,
    /// How a lapsed lease, a dead-man timeout or a shutdown stops the axis.
    pub stop_on_loss: StopKind,
    /// What drives it.
    pub drive: DriveSpec,
}

/// What every axis has, whatever drives it, in user units.
#[derive(Debug, Clone, PartialEq)]
pub struct MotionSpec {
    /// Unit conversion (drive or slave encoder counts per user unit).
    pub units: Units,
    /// Unit name for messages ("mm").
    pub unit: String,
    /// Soft limits (both or none).
    pub min_position: Option<f64>,
    /// Soft limits (both or none).
    pub max_position: Option<f64>,
    /// Velocity ceiling (units/s); also bounds a geared CANsmc axis.
    pub max_velocity: f64,
    /// Acceleration ceiling (units/s²).
    pub max_acceleration: f64,
    /// Velocity of a move without one.
    pub default_velocity: f64,
    /// Acceleration of a move without one.
    pub default_acceleration: f64,
    /// Every stop (Stop, the jog dead-man, a lost lease, shutdown)
    /// decelerates at least this hard (units/s²): the interrupted motion's
    /// own deceleration when that is higher.
    pub stop_deceleration: f64,
    /// The deceleration of a quick stop (units/s²); a CiA 402 drive gets it
    /// in 0x6084 with the quick stop (it brakes on its quick stop ramp
    /// 0x6085 when it has one and its option code says so).
    pub quick_stop_deceleration: f64,
    /// The largest jerk of a streamed path, units/s³ (`None`: not
    /// bounded): a streamed point whose change of acceleration exceeds it
    /// is refused.
    pub max_jerk: Option<f64>,
    /// Bound of each state change (enable, disable, fault reset), and of a
    /// CiA 402 set-point acknowledge and mode switch.
    pub state_timeout: Duration,
    /// Bound of a homing run.
    pub homing_timeout: Duration,
    /// Time allowed beyond the planned duration of a move (and of a stop)
    /// before it times out.
    pub settle_timeout: Duration,
    /// Jog dead-man time.
    pub jog_deadman: Duration,
    /// A move is done when the actual position is this close to the
    /// target (units).
    pub in_position_window: f64,
    /// Decimals an HMI shows positions with (the gateway computes in full
    /// precision whatever this says); [`display_decimals_for`] by default.
    pub display_decimals: u8,
}

/// The decimals that show one count of an axis with `counts_per_unit`
/// (1000 counts per mm: 3, to the µm), at most 4: finer digits only
/// flicker on a readout.
pub fn display_decimals_for(counts_per_unit: f64) -> u8 {
    let c = counts_per_unit.abs();
    if !c.is_finite() || c <= 1.0 {
        return 0;
    }
    (c.log10() - 1e-9).ceil().clamp(0.0, 4.0) as u8
}

impl MotionSpec {
    /// Limits and defaults suitable for the simulated drives (tests,
    /// demo), soft limits at ±`limit`.
    pub fn example(counts_per_unit: f64, limit: f64) -> Self {
        MotionSpec {
            units: Units { counts_per_unit },
            unit: "mm".into(),
            min_position: Some(-limit),
            max_position: Some(limit),
            max_velocity: 200.0,
            max_acceleration: 2000.0,
            default_velocity: 50.0,
            default_acceleration: 500.0,
            stop_deceleration: 2000.0,
            quick_stop_deceleration: 2000.0,
            max_jerk: None,
            state_timeout: Duration::from_secs(1),
            homing_timeout: Duration::from_secs(30),
            settle_timeout: Duration::from_secs(2),
            jog_deadman: Duration::from_millis(500),
            in_position_window: 0.01,
            display_decimals: display_decimals_for(counts_per_unit),
        }
    }

    /// The speed (units/s) below which the controllers call the axis at
    /// rest: the in-position window per 100 ms.
    pub fn rest_speed(&self) -> f64 {
        10.0 * self.in_position_window
    }
}

/// What drives an axis: its drive family and that family's part.
#[derive(Debug, Clone, PartialEq)]
pub enum DriveSpec {
    /// A CiA 402 drive on a CANopen bus.
    Cia402(Cia402Drive),
    /// A CANsmc servo slave.
    Cansmc(CansmcDrive),
}

/// A CiA 402 drive behind an axis.
#[derive(Debug, Clone, PartialEq)]
pub struct Cia402Drive {
    /// The bus (with a CANopen master).
    pub bus: String,
    /// The drive's node.
    pub node: NodeId,
    /// The mode of operation it starts in (see [`DriveMode`]).
    pub mode: DriveMode,
    /// Torque bounds (the torque modes).
    pub torque: TorqueSpec,
    /// How the process data travels.
    pub process_data: ProcessDataPath,
    /// Homing method written to 0x6098 at boot.
    pub homing_method: i8,
    /// Following error window and time-out, max torque, written at boot.
    pub supervision: crate::signals::Supervision,
    /// Map the drive's signals (torque, following error, digital inputs,
    /// touch probe) into its TPDOs where it has them
    /// ([`crate::process_data::with_signal_tpdos`]).
    pub signal_pdos: bool,
    /// Which axis of the drive node this is (CiA 402 multi-axis drives,
    /// 0..=7): its objects are at index + 0x800 × `drive_axis`.
    pub drive_axis: u8,
}

/// The torque bounds of a CiA 402 axis, per mille of the drive's rated
/// torque.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TorqueSpec {
    /// The largest torque a torque command may ask for.
    pub max_torque: f64,
    /// Profile torque's ramp (0x6087, per mille per second), written when
    /// the axis enters profile torque.
    pub torque_slope: f64,
    /// The process data carries the target torque (0x6071): the gateway
    /// maps it for an axis configured in a torque mode. Without it the
    /// torque modes are refused.
    pub in_process_data: bool,
}

impl Default for TorqueSpec {
    fn default() -> Self {
        TorqueSpec {
            max_torque: 1000.0,
            torque_slope: 10_000.0,
            in_process_data: false,
        }
    }
}

/// How a CiA 402 axis's process data (controlword, targets, statusword,
/// actual position and velocity) travels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProcessDataPath {
    /// PDOs mapped by the gateway at the drive's boot.
    Pdo,
    /// SDO: the feedback is polled every `poll`, changed objects written.
    Sdo {
        /// The poll period.
        poll: Duration,
    },
}

/// A CANsmc slave behind an axis.
#[derive(Debug, Clone, PartialEq)]
pub struct CansmcDrive {
    /// The master's name.
    pub master: String,
    /// The master's command bus (channel 0).
    pub command_bus: String,
    /// The slave.
    pub address: SmcAddress,
    /// The master's cycle time (the set-point spacing).
    pub cycle_time: Duration,
    /// Homing method byte sent with function 0x04.
    pub homing_method: u8,
    /// Follow another slave's encoder.
    pub gear: Option<Gear>,
    /// How jogs run.
    pub jog_mode: JogMode,
    /// Slave encoder counts per motor revolution (parameter 3), to convert
    /// velocities to the slave's unit for [`JogMode::SlaveVelocity`].
    pub counts_per_rev: u32,
}

impl CansmcDrive {
    /// Slave 1 of master "smc" on "smc0" with `cycle_time` and the
    /// defaults (tests, demo).
    pub fn example(cycle_time: Duration) -> Self {
        CansmcDrive {
            master: "smc".into(),
            command_bus: "smc0".into(),
            address: SmcAddress::new(1).expect("1 is a slave address"),
            cycle_time,
            homing_method: 1,
            gear: None,
            jog_mode: JogMode::Interpolated,
            counts_per_rev: 10_000,
        }
    }
}

/// Electronic gearing: follow another slave's encoder count.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gear {
    /// Address of the slave whose encoder count (function 0x07) is
    /// followed.
    pub source: u8,
    /// Follower counts per source count (negative reverses).
    pub ratio: f64,
}

/// How a CANsmc axis jogs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum JogMode {
    /// The gateway ramps the velocity and sends a position set-point every
    /// cycle (position feedback all along).
    #[default]
    Interpolated,
    /// The slave's velocity mode (function 0x03, unit 0.001 r/min: the
    /// runtime writes parameter 2 = 1 in P1): the slave ramps with its own
    /// acceleration; the position is estimated from the velocity feedback
    /// while jogging and read back from the slave's encoder count
    /// (function 0x07) at rest, before position control resumes.
    SlaveVelocity,
}

impl AxisSpec {
    /// How the axis executes moves: a CANsmc axis is always cyclic (the
    /// gateway interpolates every cycle).
    pub fn position_mode(&self) -> PositionMode {
        match &self.drive {
            DriveSpec::Cia402(d) => d.mode.position_mode(),
            DriveSpec::Cansmc(_) => PositionMode::Cyclic,
        }
    }

    /// The bus its commands leave on: the CANopen bus, or the CANsmc
    /// master's command bus.
    pub fn bus(&self) -> &str {
        match &self.drive {
            DriveSpec::Cia402(d) => &d.bus,
            DriveSpec::Cansmc(d) => &d.command_bus,
        }
    }

    /// The drive's node id, or the CANsmc slave's address.
    pub fn node(&self) -> u8 {
        match &self.drive {
            DriveSpec::Cia402(d) => d.node.get(),
            DriveSpec::Cansmc(d) => d.address.get(),
        }
    }
}

impl Cia402Drive {
    /// The controller's configuration of an axis with `motion` on this
    /// drive.
    pub fn controller(&self, motion: MotionSpec) -> crate::cia402::Cia402Config {
        crate::cia402::Cia402Config {
            motion,
            mode: self.mode,
            torque: self.torque,
            supervision: self.supervision,
            drive_axis: self.drive_axis,
        }
    }
}

impl CansmcDrive {
    /// The controller's configuration of an axis with `motion` on this
    /// slave.
    pub fn controller(&self, motion: MotionSpec) -> crate::cansmc::CansmcAxisConfig {
        crate::cansmc::CansmcAxisConfig {
            motion,
            drive: self.clone(),
        }
    }
}
