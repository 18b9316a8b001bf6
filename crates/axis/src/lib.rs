//! The axis layer, sans-IO: what an axis is and how commands on it run,
//! independent of sockets, tasks and gRPC.
//!
//! - [`cia402::Cia402Axis`]: one CiA 402 servo drive as an axis. It takes
//!   the drive's process data (statusword, position, velocity, mode
//!   display), SYNC ticks and commands, and returns the process image to
//!   send (controlword, mode, target position and velocity), SDO writes and
//!   events. Moves run either in profile position (the drive plans; the
//!   new set-point handshake) or cyclic synchronous position (the gateway
//!   plans a trapezoid and sends a set-point every SYNC).
//! - [`lease::LeaseTable`]: exclusive control with time-to-live leases.
//! - [`Units`]: user units (mm, degrees) to drive counts.
//! - [`AxisSpec`]: the one description of an axis: what every axis has
//!   ([`MotionSpec`]) and its drive family's part ([`DriveSpec`]).
//!
//! - [`cansmc::CansmcAxis`]: one CANsmc servo slave as an axis, with the
//!   same [`AxisCommand`]s and [`AxisEvent`]s: the gateway interpolates a
//!   position set-point every CANsmc cycle, and can gear an axis to another
//!   slave's encoder.

#![deny(missing_docs, unreachable_pub)]
// A dependency nothing uses fails CI (clippy -D warnings). Test builds are
// left out: their dev-dependencies serve the integration tests.
#![cfg_attr(not(test), warn(unused_crate_dependencies))]

pub mod cansmc;
mod checks;
pub mod cia402;
pub mod lease;
pub mod process_data;
pub mod setpoint_stream;
pub mod signals;
pub mod spec;

pub use spec::{
    AxisSpec, CansmcDrive, Cia402Drive, DriveSpec, Gear, JogMode, MotionSpec, ProcessDataPath,
    TorqueSpec, display_decimals_for,
};

use cangate_canopen::cia402::ModeOfOperation;

use std::fmt;

/// How an axis executes moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PositionMode {
    /// CiA 402 profile position: the drive plans the profile.
    Profile,
    /// Cyclic synchronous position: the gateway plans and sends a set-point
    /// every SYNC period.
    Cyclic,
}

/// The CiA 402 mode of operation a drive runs an axis in (0x6060): set
/// per axis in the configuration, changed at run time at rest
/// ([`AxisCommand::SetMode`]). Homing (6) is not one: it runs from any of
/// them and returns to it.
///
/// What each command means per mode:
///
/// | mode | move | jog | torque | stop |
/// |---|---|---|---|---|
/// | profile position (1) | the drive plans | profile velocity (3) | refused | halt on 0x6084 |
/// | cyclic synchronous position (8) | the gateway's trapezoid, a position every SYNC | a trapezoid towards the soft limit | refused | the gateway's ramp |
/// | interpolated position (7) | as CSP, the position in 0x60C1:01 | as CSP | refused | the gateway's ramp |
/// | cyclic synchronous velocity (9) | refused | velocity set-points every SYNC, ramped within the acceleration | refused | the gateway ramps the velocity to 0 |
/// | cyclic synchronous torque (10) | refused | refused | 0x6071, velocity guarded | halt on 0x6084 |
/// | profile torque (4) | refused | refused | 0x6071 ramped by the drive at 0x6087, velocity guarded | halt on 0x6084 |
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DriveMode {
    /// Profile position (1): the drive plans each move.
    ProfilePosition,
    /// Cyclic synchronous position (8).
    CyclicPosition,
    /// Interpolated position (7), for drives without CSP.
    InterpolatedPosition,
    /// Cyclic synchronous velocity (9).
    CyclicVelocity,
    /// Cyclic synchronous torque (10).
    CyclicTorque,
    /// Profile torque (4).
    ProfileTorque,
}

impl DriveMode {
    /// Every mode.
    pub const ALL: [DriveMode; 6] = [
        DriveMode::ProfilePosition,
        DriveMode::CyclicPosition,
        DriveMode::InterpolatedPosition,
        DriveMode::CyclicVelocity,
        DriveMode::CyclicTorque,
        DriveMode::ProfileTorque,
    ];

    /// Its name in the configuration and the API: `profile_position`,
    /// `csp`, `ip`, `csv`, `cst`, `profile_torque`.
    pub const fn name(self) -> &'static str {
        match self {
            DriveMode::ProfilePosition => "profile_position",
            DriveMode::CyclicPosition => "csp",
            DriveMode::InterpolatedPosition => "ip",
            DriveMode::CyclicVelocity => "csv",
            DriveMode::CyclicTorque => "cst",
            DriveMode::ProfileTorque => "profile_torque",
        }
    }

    /// The mode of a [`DriveMode::name`].
    pub fn from_name(name: &str) -> Option<DriveMode> {
        DriveMode::ALL.into_iter().find(|m| m.name() == name)
    }

    /// The CiA 402 mode of operation.
    pub const fn operation(self) -> ModeOfOperation {
        match self {
            DriveMode::ProfilePosition => ModeOfOperation::ProfilePosition,
            DriveMode::CyclicPosition => ModeOfOperation::CyclicSynchronousPosition,
            DriveMode::InterpolatedPosition => ModeOfOperation::InterpolatedPosition,
            DriveMode::CyclicVelocity => ModeOfOperation::CyclicSynchronousVelocity,
            DriveMode::CyclicTorque => ModeOfOperation::CyclicSynchronousTorque,
            DriveMode::ProfileTorque => ModeOfOperation::ProfileTorque,
        }
    }

    /// The mode of a CiA 402 mode of operation, `None` for the modes an
    /// axis is not configured in (profile velocity, homing).
    pub fn from_operation(m: ModeOfOperation) -> Option<DriveMode> {
        DriveMode::ALL.into_iter().find(|d| d.operation() == m)
    }

    /// How moves run: cyclic for the modes that take a set-point with every
    /// SYNC from the gateway's plan (CSP, IP, CSV), profile for the others
    /// (the drive plans or follows a held command).
    pub const fn position_mode(self) -> PositionMode {
        match self {
            DriveMode::CyclicPosition
            | DriveMode::InterpolatedPosition
            | DriveMode::CyclicVelocity => PositionMode::Cyclic,
            _ => PositionMode::Profile,
        }
    }

    /// The torque modes (CST, profile torque): commanded by
    /// [`AxisCommand::SetTorque`].
    pub const fn is_torque(self) -> bool {
        matches!(self, DriveMode::CyclicTorque | DriveMode::ProfileTorque)
    }

    /// The mode an axis configured only by its position mode runs in.
    pub const fn of_position_mode(p: PositionMode) -> DriveMode {
        match p {
            PositionMode::Profile => DriveMode::ProfilePosition,
            PositionMode::Cyclic => DriveMode::CyclicPosition,
        }
    }
}

impl fmt::Display for DriveMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// How a stop decelerates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum StopKind {
    /// With the profile deceleration.
    Halt,
    /// CiA 402 quick stop.
    QuickStop,
}

/// What an axis is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Activity {
    /// At rest (enabled or not).
    Idle,
    /// Walking the drive state machine.
    Switching,
    /// Homing.
    Homing,
    /// Moving to a target.
    Moving,
    /// Jogging.
    Jogging,
    /// Decelerating to rest.
    Stopping,
}

/// The commands of the axis API.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AxisCommand {
    /// To operation enabled.
    Enable,
    /// Power stage off (ready to switch on).
    Disable,
    /// Run the configured homing method.
    Home,
    /// Move to `target` (or by it when `relative`), user units; `None`
    /// velocity/acceleration use the axis defaults.
    Move {
        /// Target or distance.
        target: f64,
        /// `target` is a distance from the latest target.
        relative: bool,
        /// Velocity limit.
        velocity: Option<f64>,
        /// Acceleration (and deceleration) limit.
        acceleration: Option<f64>,
    },
    /// Move at a signed velocity while repeated (dead-man).
    Jog {
        /// Signed velocity; 0 stops.
        velocity: f64,
        /// Acceleration limit.
        acceleration: Option<f64>,
    },
    /// Decelerate to rest.
    Stop,
    /// CiA 402 quick stop.
    QuickStop,
    /// Reset a drive fault.
    ResetFault,
    /// Drive with this torque (per mille of the rated torque, signed) in a
    /// torque mode (CST, profile torque), until a stop or another command;
    /// the axis stops when its velocity exceeds its maximum velocity.
    SetTorque {
        /// Per mille of the rated torque (0x6071), at most the axis's
        /// maximum torque.
        per_mille: f64,
    },
    /// Switch the drive to `mode`, at rest only.
    SetMode {
        /// The new mode.
        mode: DriveMode,
    },
}

impl AxisCommand {
    /// The command's kind.
    pub fn kind(&self) -> CommandKind {
        match self {
            AxisCommand::Enable => CommandKind::Enable,
            AxisCommand::Disable => CommandKind::Disable,
            AxisCommand::Home => CommandKind::Home,
            AxisCommand::Move { .. } => CommandKind::Move,
            AxisCommand::Jog { .. } => CommandKind::Jog,
            AxisCommand::Stop => CommandKind::Stop,
            AxisCommand::QuickStop => CommandKind::QuickStop,
            AxisCommand::ResetFault => CommandKind::ResetFault,
            AxisCommand::SetTorque { .. } => CommandKind::Torque,
            AxisCommand::SetMode { .. } => CommandKind::SetMode,
        }
    }

    /// Whether the command needs a control lease: everything but the
    /// stops (anyone may stop a machine).
    pub fn needs_control(&self) -> bool {
        !matches!(self, AxisCommand::Stop | AxisCommand::QuickStop)
    }
}

/// The kind of a command, for events and logs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CommandKind {
    /// [`AxisCommand::Enable`].
    Enable,
    /// [`AxisCommand::Disable`].
    Disable,
    /// [`AxisCommand::Home`].
    Home,
    /// [`AxisCommand::Move`], also one axis of a coordinated move.
    Move,
    /// [`AxisCommand::Jog`].
    Jog,
    /// [`AxisCommand::Stop`].
    Stop,
    /// [`AxisCommand::QuickStop`].
    QuickStop,
    /// [`AxisCommand::ResetFault`].
    ResetFault,
    /// [`AxisCommand::SetTorque`].
    Torque,
    /// [`AxisCommand::SetMode`].
    SetMode,
}

impl CommandKind {
    /// Lower-case name: `enable`, `move`, `quick stop`, …
    pub const fn name(self) -> &'static str {
        match self {
            CommandKind::Enable => "enable",
            CommandKind::Disable => "disable",
            CommandKind::Home => "home",
            CommandKind::Move => "move",
            CommandKind::Jog => "jog",
            CommandKind::Stop => "stop",
            CommandKind::QuickStop => "quick stop",
            CommandKind::ResetFault => "reset fault",
            CommandKind::Torque => "torque",
            CommandKind::SetMode => "set mode",
        }
    }
}

impl fmt::Display for CommandKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// How a command ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Outcome {
    /// Target reached, homing attained, state reached, at rest.
    Completed,
    /// Replaced by a later command.
    Superseded,
    /// Ended by a drive fault or a lost node.
    Fault,
    /// The drive did not follow in time.
    Timeout,
    /// Stopped before completing.
    Stopped,
}

impl Outcome {
    /// Lower-case name.
    pub const fn name(self) -> &'static str {
        match self {
            Outcome::Completed => "completed",
            Outcome::Superseded => "superseded",
            Outcome::Fault => "fault",
            Outcome::Timeout => "timeout",
            Outcome::Stopped => "stopped",
        }
    }
}

/// Identifies one command run on one axis.
pub type OpId = u64;

/// What an axis reports.
#[derive(Debug, Clone, PartialEq)]
pub enum AxisEvent {
    /// The drive accepted command `op` (a profile move: set-point
    /// acknowledged; others: at once).
    Accepted {
        /// The command.
        op: OpId,
    },
    /// Command `op` ended.
    Done {
        /// The command.
        op: OpId,
        /// Its kind.
        command: CommandKind,
        /// How it ended.
        outcome: Outcome,
        /// A sentence for people.
        detail: String,
    },
    /// The drive entered a fault (`code` from its EMCY, 0 if none came) or
    /// left it (`code` 0, empty text).
    Fault {
        /// CiA 301/402 error code.
        code: u16,
        /// Its name.
        text: String,
    },
    /// Touch probe 1 latched the position at an edge of its input.
    TouchProbe {
        /// The rising (positive) edge; false: the falling edge.
        rising: bool,
        /// The latched position (user units).
        position: f64,
    },
}

/// Why a command was refused before it reached the drive; nothing
/// changed. Each variant is a reason; the message says it to a person.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CommandError {
    /// A value no motion can be made of: not a finite number, not
    /// positive, or a profile that cannot be planned with it.
    #[error("{0}")]
    BadValue(String),
    /// A velocity or acceleration above the axis's configured maximum.
    #[error("{0}")]
    AboveMaximum(String),
    /// A target beyond a soft limit, or a jog further into one.
    #[error("{0}")]
    BeyondSoftLimit(String),
    /// The drive cannot be reached: its node or slave is lost, or no
    /// process data came from it yet.
    #[error("{0}")]
    DriveUnavailable(String),
    /// The drive is in fault.
    #[error("{0}")]
    InFault(String),
    /// The command needs an enabled axis.
    #[error("{0}")]
    NotEnabled(String),
    /// The axis is busy with what the command cannot join or interrupt:
    /// being disabled, homing, moving (before a coordinated move),
    /// following a gear.
    #[error("{0}")]
    Busy(String),
    /// The command needs cyclic position control the axis does not have
    /// now: a profile position axis, a cyclic axis outside its mode.
    #[error("{0}")]
    NotCyclic(String),
    /// A cyclic axis whose bus's SYNC is stopped: no set-point or feedback
    /// would come.
    #[error("{0}")]
    SyncStopped(String),
    /// The drive state machine has no way from the drive's state to the
    /// state the command asks for.
    #[error("{0}")]
    StateUnreachable(String),
    /// The axis's mode of operation has no such command (a move in CSV, a
    /// torque in CSP), or the drive does not support the mode asked for.
    #[error("{0}")]
    WrongMode(String),
}

impl CommandError {
    /// The same reason with `prefix` before its message (`axis X: `).
    pub fn prefixed(self, prefix: &str) -> Self {
        use CommandError as E;
        let p = |m: String| format!("{prefix}{m}");
        match self {
            E::BadValue(m) => E::BadValue(p(m)),
            E::AboveMaximum(m) => E::AboveMaximum(p(m)),
            E::BeyondSoftLimit(m) => E::BeyondSoftLimit(p(m)),
            E::DriveUnavailable(m) => E::DriveUnavailable(p(m)),
            E::InFault(m) => E::InFault(p(m)),
            E::NotEnabled(m) => E::NotEnabled(p(m)),
            E::Busy(m) => E::Busy(p(m)),
            E::NotCyclic(m) => E::NotCyclic(p(m)),
            E::SyncStopped(m) => E::SyncStopped(p(m)),
            E::StateUnreachable(m) => E::StateUnreachable(p(m)),
            E::WrongMode(m) => E::WrongMode(p(m)),
        }
    }
}

/// Conversion between user units and drive counts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Units {
    /// Drive counts per user unit (non-zero; negative inverts the
    /// direction).
    pub counts_per_unit: f64,
}

impl Units {
    /// Counts of a position in user units, rounded and saturated to the
    /// INTEGER32 range of the CiA 402 objects.
    pub fn to_counts(&self, user: f64) -> i32 {
        let c = (user * self.counts_per_unit).round();
        c.clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
    }

    /// Unsigned counts (velocity and acceleration magnitudes for 0x6081,
    /// 0x6083, 0x6084), saturated to UNSIGNED32.
    pub fn to_counts_unsigned(&self, user: f64) -> u32 {
        let c = (user * self.counts_per_unit).abs().round();
        c.clamp(0.0, f64::from(u32::MAX)) as u32
    }

    /// User units of a count value.
    pub fn from_counts(&self, counts: f64) -> f64 {
        counts / self.counts_per_unit
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_round_trip_and_saturate() {
        let u = Units {
            counts_per_unit: 1000.0,
        };
        assert_eq!(u.to_counts(12.5), 12_500);
        assert_eq!(u.to_counts(-0.0004), 0);
        assert_eq!(u.to_counts(-0.0006), -1);
        assert_eq!(u.to_counts(1e12), i32::MAX);
        assert_eq!(u.to_counts(-1e12), i32::MIN);
        assert_eq!(u.to_counts_unsigned(-20.0), 20_000);
        assert_eq!(u.from_counts(12_500.0), 12.5);
    }

    #[test]
    fn only_stops_need_no_control() {
        assert!(!AxisCommand::Stop.needs_control());
        assert!(!AxisCommand::QuickStop.needs_control());
        assert!(AxisCommand::Enable.needs_control());
        assert!(
            AxisCommand::Jog {
                velocity: 1.0,
                acceleration: None
            }
            .needs_control()
        );
    }
}
