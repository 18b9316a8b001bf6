//! CiA 402 (IEC 61800-7-201) drive profile: statusword, controlword, modes
//! of operation, the device state machine and a sans-IO driver that walks a
//! drive to a requested state.
//!
//! The power drive system state machine (CiA 402 §6.3) and the transition
//! numbers used throughout this module:
//!
//! | # | from | to | trigger (controlword) |
//! |---|---|---|---|
//! | 0 | power on | not ready to switch on | automatic |
//! | 1 | not ready to switch on | switch on disabled | automatic |
//! | 2 | switch on disabled | ready to switch on | shutdown 0x0006 |
//! | 3 | ready to switch on | switched on | switch on 0x0007 (or 0x000F: 3 then 4) |
//! | 4 | switched on | operation enabled | enable operation 0x000F |
//! | 5 | operation enabled | switched on | disable operation 0x0007 |
//! | 6 | switched on | ready to switch on | shutdown 0x0006 |
//! | 7 | ready to switch on | switch on disabled | disable voltage 0x0000 / quick stop 0x0002 |
//! | 8 | operation enabled | ready to switch on | shutdown 0x0006 |
//! | 9 | operation enabled | switch on disabled | disable voltage 0x0000 |
//! | 10 | switched on | switch on disabled | disable voltage 0x0000 / quick stop 0x0002 |
//! | 11 | operation enabled | quick stop active | quick stop 0x0002 |
//! | 12 | quick stop active | switch on disabled | disable voltage 0x0000, or automatic once stopped (option code 0..=4) |
//! | 13 | any | fault reaction active | a fault (automatic) |
//! | 14 | fault reaction active | fault | automatic |
//! | 15 | fault | switch on disabled | fault reset: rising edge of bit 7 (0x0080) |
//! | 16 | quick stop active | operation enabled | enable operation 0x000F (option code 5..=8 only) |
//!
//! The option code is the quick stop option code 0x605A.
//!
//! [`next_command`] plans the next controlword from any state to a target
//! state and [`StateMachineDriver`] runs that plan against statuswords and
//! ticks with a timeout:
//!
//! ```
//! use std::time::Duration;
//! use cangate_canopen::cia402::{
//!     Controlword, DriveState, DriverStep, StateMachineDriver, Statusword,
//! };
//!
//! let ms = Duration::from_millis;
//! let mut driver =
//!     StateMachineDriver::new(DriveState::OperationEnabled, ms(500), ms(0)).unwrap();
//! assert_eq!(
//!     driver.on_statusword(Statusword(0x0240), ms(1)),
//!     DriverStep::Send(Controlword::SHUTDOWN)
//! );
//! assert_eq!(
//!     driver.on_statusword(Statusword(0x0221), ms(2)),
//!     DriverStep::Send(Controlword::SWITCH_ON)
//! );
//! assert_eq!(
//!     driver.on_statusword(Statusword(0x0233), ms(3)),
//!     DriverStep::Send(Controlword::ENABLE_OPERATION)
//! );
//! assert_eq!(driver.on_statusword(Statusword(0x0237), ms(4)), DriverStep::Done(Ok(())));
//! ```

use std::fmt;
use std::str::FromStr;
use std::time::Duration;

use crate::ids::ObjectAddress;

/// Object dictionary addresses of the CiA 402 objects used here.
pub mod objects {
    use crate::ids::ObjectAddress;

    /// 0x603F error code (UNSIGNED16): the latest fault's EMCY code.
    pub const ERROR_CODE: ObjectAddress = ObjectAddress::new(0x603F, 0);
    /// 0x6040 controlword (UNSIGNED16).
    pub const CONTROLWORD: ObjectAddress = ObjectAddress::new(0x6040, 0);
    /// 0x6041 statusword (UNSIGNED16).
    pub const STATUSWORD: ObjectAddress = ObjectAddress::new(0x6041, 0);
    /// 0x605A quick stop option code (INTEGER16).
    pub const QUICK_STOP_OPTION_CODE: ObjectAddress = ObjectAddress::new(0x605A, 0);
    /// 0x6060 modes of operation (INTEGER8).
    pub const MODES_OF_OPERATION: ObjectAddress = ObjectAddress::new(0x6060, 0);
    /// 0x6061 modes of operation display (INTEGER8).
    pub const MODES_OF_OPERATION_DISPLAY: ObjectAddress = ObjectAddress::new(0x6061, 0);
    /// 0x6064 position actual value (INTEGER32).
    pub const POSITION_ACTUAL: ObjectAddress = ObjectAddress::new(0x6064, 0);
    /// 0x6065 following error window (UNSIGNED32; 0xFFFFFFFF = off).
    pub const FOLLOWING_ERROR_WINDOW: ObjectAddress = ObjectAddress::new(0x6065, 0);
    /// 0x6066 following error time out (UNSIGNED16, ms).
    pub const FOLLOWING_ERROR_TIMEOUT: ObjectAddress = ObjectAddress::new(0x6066, 0);
    /// 0x606C velocity actual value (INTEGER32).
    pub const VELOCITY_ACTUAL: ObjectAddress = ObjectAddress::new(0x606C, 0);
    /// 0x6077 torque actual value (INTEGER16, per mille of rated torque).
    pub const TORQUE_ACTUAL: ObjectAddress = ObjectAddress::new(0x6077, 0);
    /// 0x607A target position (INTEGER32).
    pub const TARGET_POSITION: ObjectAddress = ObjectAddress::new(0x607A, 0);
    /// 0x607C home offset (INTEGER32).
    pub const HOME_OFFSET: ObjectAddress = ObjectAddress::new(0x607C, 0);
    /// 0x607D:01 min software position limit (INTEGER32).
    pub const SOFTWARE_POSITION_LIMIT_MIN: ObjectAddress = ObjectAddress::new(0x607D, 1);
    /// 0x607D:02 max software position limit (INTEGER32).
    pub const SOFTWARE_POSITION_LIMIT_MAX: ObjectAddress = ObjectAddress::new(0x607D, 2);
    /// 0x6080 max motor speed (UNSIGNED32).
    pub const MAX_MOTOR_SPEED: ObjectAddress = ObjectAddress::new(0x6080, 0);
    /// 0x6081 profile velocity (UNSIGNED32).
    pub const PROFILE_VELOCITY: ObjectAddress = ObjectAddress::new(0x6081, 0);
    /// 0x6083 profile acceleration (UNSIGNED32).
    pub const PROFILE_ACCELERATION: ObjectAddress = ObjectAddress::new(0x6083, 0);
    /// 0x6084 profile deceleration (UNSIGNED32).
    pub const PROFILE_DECELERATION: ObjectAddress = ObjectAddress::new(0x6084, 0);
    /// 0x6085 quick stop deceleration (UNSIGNED32).
    pub const QUICK_STOP_DECELERATION: ObjectAddress = ObjectAddress::new(0x6085, 0);
    /// 0x6098 homing method (INTEGER8).
    pub const HOMING_METHOD: ObjectAddress = ObjectAddress::new(0x6098, 0);
    /// 0x6099:01 homing speed during search for switch (UNSIGNED32).
    pub const HOMING_SPEED_SWITCH: ObjectAddress = ObjectAddress::new(0x6099, 1);
    /// 0x6099:02 homing speed during search for zero (UNSIGNED32).
    pub const HOMING_SPEED_ZERO: ObjectAddress = ObjectAddress::new(0x6099, 2);
    /// 0x609A homing acceleration (UNSIGNED32).
    pub const HOMING_ACCELERATION: ObjectAddress = ObjectAddress::new(0x609A, 0);
    /// 0x60F4 following error actual value (INTEGER32).
    pub const FOLLOWING_ERROR_ACTUAL: ObjectAddress = ObjectAddress::new(0x60F4, 0);
    /// 0x60FF target velocity (INTEGER32).
    pub const TARGET_VELOCITY: ObjectAddress = ObjectAddress::new(0x60FF, 0);
    /// 0x6502 supported drive modes (UNSIGNED32, one bit per mode).
    pub const SUPPORTED_DRIVE_MODES: ObjectAddress = ObjectAddress::new(0x6502, 0);

    // The signals of an axis beyond its position: limit and home switches,
    // touch probe, torque limit (CiA 402-2, IEC 61800-7-201).

    /// 0x6072 max torque (UNSIGNED16, per mille of rated torque).
    pub const MAX_TORQUE: ObjectAddress = ObjectAddress::new(0x6072, 0);
    /// 0x60B1 velocity offset (INTEGER32, counts/s): a CSP drive's
    /// velocity feed-forward.
    pub const VELOCITY_OFFSET: ObjectAddress = ObjectAddress::new(0x60B1, 0);
    /// 0x60B2 torque offset (INTEGER16, per mille of rated torque): a CSP
    /// drive's torque feed-forward.
    pub const TORQUE_OFFSET: ObjectAddress = ObjectAddress::new(0x60B2, 0);
    /// 0x60B8 touch probe function (UNSIGNED16).
    pub const TOUCH_PROBE_FUNCTION: ObjectAddress = ObjectAddress::new(0x60B8, 0);
    /// 0x60B9 touch probe status (UNSIGNED16).
    pub const TOUCH_PROBE_STATUS: ObjectAddress = ObjectAddress::new(0x60B9, 0);
    /// 0x60BA touch probe 1 position latched at the positive edge
    /// (INTEGER32).
    pub const TOUCH_PROBE_1_POSITIVE: ObjectAddress = ObjectAddress::new(0x60BA, 0);
    /// 0x60BB touch probe 1 position latched at the negative edge
    /// (INTEGER32).
    pub const TOUCH_PROBE_1_NEGATIVE: ObjectAddress = ObjectAddress::new(0x60BB, 0);
    /// 0x60FD digital inputs (UNSIGNED32; bit 0 negative limit switch,
    /// bit 1 positive limit switch, bit 2 home switch).
    pub const DIGITAL_INPUTS: ObjectAddress = ObjectAddress::new(0x60FD, 0);
    /// 0x6071 target torque (INTEGER16, per mille of the rated torque):
    /// the set-point of the torque modes.
    pub const TARGET_TORQUE: ObjectAddress = ObjectAddress::new(0x6071, 0);
    /// 0x6087 torque slope (UNSIGNED32, per mille per second): the ramp of
    /// profile torque.
    pub const TORQUE_SLOPE: ObjectAddress = ObjectAddress::new(0x6087, 0);
    /// 0x60C1:01 interpolation data record, the position set-point of
    /// interpolated position (INTEGER32).
    pub const INTERPOLATION_DATA: ObjectAddress = ObjectAddress::new(0x60C1, 1);
    /// 0x60C2:01 interpolation time period value (UNSIGNED8).
    pub const INTERPOLATION_PERIOD_VALUE: ObjectAddress = ObjectAddress::new(0x60C2, 1);
    /// 0x60C2:02 interpolation time index (INTEGER8): the period is
    /// value · 10^index s.
    pub const INTERPOLATION_PERIOD_INDEX: ObjectAddress = ObjectAddress::new(0x60C2, 2);
}

/// The objects of axis `n` of a multi-axis drive are those of the first
/// axis at index + `n` × 0x800 (CiA 402, IEC 61800-7-201: each further
/// logical device of the profile area 0x6000..=0x9FFF): 0x6040 of axis 1
/// is 0x6840.
pub const AXIS_INDEX_OFFSET: u16 = 0x800;

/// Axes one drive node can have: the profile area 0x6000..=0x9FFF holds
/// eight times 0x800 objects.
pub const MAX_DRIVE_AXES: u8 = 8;

/// The first index of the profile area.
const PROFILE_AREA: u16 = 0x6000;

/// The index of profile object `base` (an index of the first axis,
/// 0x6000..=0x67FF) on axis `drive_axis` (0..=7) of its drive: `base` +
/// `drive_axis` × 0x800. Indexes outside the first axis's range (the
/// communication area, a vendor's objects) are the node's and stay as
/// they are.
///
/// # Panics
/// When `drive_axis` is 8 or more (the configuration refuses it).
pub const fn profile_index(base: u16, drive_axis: u8) -> u16 {
    assert!(drive_axis < MAX_DRIVE_AXES, "a drive has at most 8 axes");
    if base >= PROFILE_AREA && base < PROFILE_AREA + AXIS_INDEX_OFFSET {
        base + AXIS_INDEX_OFFSET * drive_axis as u16
    } else {
        base
    }
}

/// `addr` of the first axis as the same object of axis `drive_axis`
/// ([`profile_index`]).
pub const fn on_axis(addr: ObjectAddress, drive_axis: u8) -> ObjectAddress {
    ObjectAddress::new(profile_index(addr.index, drive_axis), addr.sub)
}

/// Which axis a profile object belongs to, and the same object of the
/// first axis: `(1, 0x6040:00)` for 0x6840:00. `None` outside the profile
/// area 0x6000..=0x9FFF.
pub const fn axis_of(addr: ObjectAddress) -> Option<(u8, ObjectAddress)> {
    if addr.index < PROFILE_AREA || addr.index > 0x9FFF {
        return None;
    }
    let rel = addr.index - PROFILE_AREA;
    Some((
        (rel / AXIS_INDEX_OFFSET) as u8,
        ObjectAddress::new(PROFILE_AREA + rel % AXIS_INDEX_OFFSET, addr.sub),
    ))
}

/// `addr` as the same object of the first axis (what [`objects`] names):
/// 0x6840:00 → 0x6040:00; other addresses unchanged.
pub const fn first_axis(addr: ObjectAddress) -> ObjectAddress {
    match axis_of(addr) {
        Some((_, base)) => base,
        None => addr,
    }
}

/// A state of the CiA 402 power drive system state machine, as decoded from
/// the statusword.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DriveState {
    /// Not ready to switch on (`xxxx xxxx x0xx 0000`): initialising.
    NotReadyToSwitchOn,
    /// Switch on disabled (`x1xx 0000`): initialised, power stage off.
    SwitchOnDisabled,
    /// Ready to switch on (`x01x 0001`).
    ReadyToSwitchOn,
    /// Switched on (`x011 0011`): power stage on, drive function disabled.
    SwitchedOn,
    /// Operation enabled (`x011 0111`): the motor is controlled.
    OperationEnabled,
    /// Quick stop active (`x001 0111`).
    QuickStopActive,
    /// Fault reaction active (`x0xx 1111`).
    FaultReactionActive,
    /// Fault (`x0xx 1000`).
    Fault,
    /// A statusword matching none of the patterns above.
    Unknown,
}

impl DriveState {
    /// The eight states of the state machine (without [`DriveState::Unknown`]).
    pub const ALL: [DriveState; 8] = [
        DriveState::NotReadyToSwitchOn,
        DriveState::SwitchOnDisabled,
        DriveState::ReadyToSwitchOn,
        DriveState::SwitchedOn,
        DriveState::OperationEnabled,
        DriveState::QuickStopActive,
        DriveState::FaultReactionActive,
        DriveState::Fault,
    ];

    /// The states a master can request (and [`next_command`] can reach):
    /// switch on disabled, ready to switch on, switched on, operation
    /// enabled and quick stop active.
    pub const fn is_commandable(self) -> bool {
        matches!(
            self,
            DriveState::SwitchOnDisabled
                | DriveState::ReadyToSwitchOn
                | DriveState::SwitchedOn
                | DriveState::OperationEnabled
                | DriveState::QuickStopActive
        )
    }

    /// The lower-case name used in the standard, e.g. `"switch on disabled"`.
    pub const fn name(self) -> &'static str {
        match self {
            DriveState::NotReadyToSwitchOn => "not ready to switch on",
            DriveState::SwitchOnDisabled => "switch on disabled",
            DriveState::ReadyToSwitchOn => "ready to switch on",
            DriveState::SwitchedOn => "switched on",
            DriveState::OperationEnabled => "operation enabled",
            DriveState::QuickStopActive => "quick stop active",
            DriveState::FaultReactionActive => "fault reaction active",
            DriveState::Fault => "fault",
            DriveState::Unknown => "unknown",
        }
    }

    /// The statusword bits 0..=3, 5 and 6 that encode this state, with every
    /// "don't care" bit clear except bit 5 (quick stop) in the states whose
    /// pattern leaves it open but a drive reports it set (ready to switch
    /// on, switched on, operation enabled): switch on disabled 0x0040,
    /// ready to switch on 0x0021, switched on 0x0023, operation enabled
    /// 0x0027, quick stop active 0x0007, fault reaction active 0x000F,
    /// fault 0x0008, not ready to switch on 0x0000. `None` for
    /// [`DriveState::Unknown`].
    pub const fn statusword_bits(self) -> Option<u16> {
        Some(match self {
            DriveState::NotReadyToSwitchOn => 0x0000,
            DriveState::SwitchOnDisabled => 0x0040,
            DriveState::ReadyToSwitchOn => 0x0021,
            DriveState::SwitchedOn => 0x0023,
            DriveState::OperationEnabled => 0x0027,
            DriveState::QuickStopActive => 0x0007,
            DriveState::FaultReactionActive => 0x000F,
            DriveState::Fault => 0x0008,
            DriveState::Unknown => return None,
        })
    }

    /// The transition a drive in this state takes on `command` (see the
    /// [module documentation](self)), `None` when the command does nothing
    /// here.
    ///
    /// "Switch on + enable operation" (0x000F) in ready to switch on yields
    /// transition 3 to switched on; applying the same command again yields
    /// 4, as a drive does in one go. Transition 16 (quick stop active →
    /// operation enabled) is returned for any quick stop active drive; a
    /// drive takes it only with a quick stop option code of 5..=8.
    pub const fn on_command(self, command: Command) -> Option<Transition> {
        use Command as C;
        use DriveState as S;
        let (number, to) = match (self, command) {
            (S::SwitchOnDisabled, C::Shutdown) => (2, S::ReadyToSwitchOn),
            (S::ReadyToSwitchOn, C::SwitchOn | C::EnableOperation) => (3, S::SwitchedOn),
            (S::SwitchedOn, C::EnableOperation) => (4, S::OperationEnabled),
            (S::OperationEnabled, C::SwitchOn) => (5, S::SwitchedOn),
            (S::SwitchedOn, C::Shutdown) => (6, S::ReadyToSwitchOn),
            (S::ReadyToSwitchOn, C::DisableVoltage | C::QuickStop) => (7, S::SwitchOnDisabled),
            (S::OperationEnabled, C::Shutdown) => (8, S::ReadyToSwitchOn),
            (S::OperationEnabled, C::DisableVoltage) => (9, S::SwitchOnDisabled),
            (S::SwitchedOn, C::DisableVoltage | C::QuickStop) => (10, S::SwitchOnDisabled),
            (S::OperationEnabled, C::QuickStop) => (11, S::QuickStopActive),
            (S::QuickStopActive, C::DisableVoltage) => (12, S::SwitchOnDisabled),
            (S::Fault, C::FaultReset) => (15, S::SwitchOnDisabled),
            (S::QuickStopActive, C::EnableOperation) => (16, S::OperationEnabled),
            _ => return None,
        };
        Some(Transition { number, to })
    }
}

impl fmt::Display for DriveState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A transition of the state machine: its number in the standard and the
/// state it leads to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Transition {
    /// The transition number (2..=12, 15, 16 for commanded transitions).
    pub number: u8,
    /// The new state.
    pub to: DriveState,
}

/// The statusword (0x6041).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Statusword(pub u16);

impl Statusword {
    /// Bit 0: ready to switch on.
    pub const READY_TO_SWITCH_ON: u16 = 1 << 0;
    /// Bit 1: switched on.
    pub const SWITCHED_ON: u16 = 1 << 1;
    /// Bit 2: operation enabled.
    pub const OPERATION_ENABLED: u16 = 1 << 2;
    /// Bit 3: fault.
    pub const FAULT: u16 = 1 << 3;
    /// Bit 4: voltage enabled (high voltage applied to the power stage).
    pub const VOLTAGE_ENABLED: u16 = 1 << 4;
    /// Bit 5: quick stop (active low: 0 = a quick stop is being executed).
    pub const QUICK_STOP: u16 = 1 << 5;
    /// Bit 6: switch on disabled.
    pub const SWITCH_ON_DISABLED: u16 = 1 << 6;
    /// Bit 7: warning.
    pub const WARNING: u16 = 1 << 7;
    /// Bit 9: remote (the controlword is processed).
    pub const REMOTE: u16 = 1 << 9;
    /// Bit 10: target reached (mode specific).
    pub const TARGET_REACHED: u16 = 1 << 10;
    /// Bit 11: internal limit active.
    pub const INTERNAL_LIMIT: u16 = 1 << 11;
    /// Bit 12, operation mode specific: set-point acknowledge (profile
    /// position), speed = 0 (profile velocity), homing attained (homing),
    /// drive follows the command value (cyclic synchronous modes).
    pub const OMS_12: u16 = 1 << 12;
    /// Bit 13, operation mode specific: following error (position modes),
    /// max slippage error (profile velocity), homing error (homing).
    pub const OMS_13: u16 = 1 << 13;

    /// The bits that encode the state (0..=3, 5, 6).
    pub const STATE_MASK: u16 = 0x006F;

    /// The state encoded in bits 0..=3, 5 and 6.
    pub const fn state(self) -> DriveState {
        let w = self.0;
        if w & 0x004F == 0x0000 {
            DriveState::NotReadyToSwitchOn
        } else if w & 0x004F == 0x0040 {
            DriveState::SwitchOnDisabled
        } else if w & 0x006F == 0x0021 {
            DriveState::ReadyToSwitchOn
        } else if w & 0x006F == 0x0023 {
            DriveState::SwitchedOn
        } else if w & 0x006F == 0x0027 {
            DriveState::OperationEnabled
        } else if w & 0x006F == 0x0007 {
            DriveState::QuickStopActive
        } else if w & 0x004F == 0x000F {
            DriveState::FaultReactionActive
        } else if w & 0x004F == 0x0008 {
            DriveState::Fault
        } else {
            DriveState::Unknown
        }
    }

    /// A statusword with the canonical bits of `state` (see
    /// [`DriveState::statusword_bits`]; 0 for [`DriveState::Unknown`]).
    pub const fn from_state(state: DriveState) -> Statusword {
        match state.statusword_bits() {
            Some(bits) => Statusword(bits),
            None => Statusword(0),
        }
    }

    /// The raw value.
    pub const fn bits(self) -> u16 {
        self.0
    }

    /// True if every bit of `mask` is set.
    pub const fn contains(self, mask: u16) -> bool {
        self.0 & mask == mask
    }

    /// This statusword with the bits of `mask` set (`on`) or cleared.
    #[must_use]
    pub const fn with(self, mask: u16, on: bool) -> Statusword {
        if on {
            Statusword(self.0 | mask)
        } else {
            Statusword(self.0 & !mask)
        }
    }

    /// Bit 3: fault.
    pub const fn fault(self) -> bool {
        self.contains(Self::FAULT)
    }

    /// Bit 4: voltage enabled.
    pub const fn voltage_enabled(self) -> bool {
        self.contains(Self::VOLTAGE_ENABLED)
    }

    /// Bit 5 clear: a quick stop is being executed.
    pub const fn quick_stop_active(self) -> bool {
        !self.contains(Self::QUICK_STOP)
    }

    /// Bit 7: warning.
    pub const fn warning(self) -> bool {
        self.contains(Self::WARNING)
    }

    /// Bit 9: remote (the drive processes the controlword).
    pub const fn remote(self) -> bool {
        self.contains(Self::REMOTE)
    }

    /// Bit 10: target reached.
    pub const fn target_reached(self) -> bool {
        self.contains(Self::TARGET_REACHED)
    }

    /// Bit 11: internal limit active.
    pub const fn internal_limit(self) -> bool {
        self.contains(Self::INTERNAL_LIMIT)
    }

    /// Bit 12 in profile position mode: set-point acknowledge.
    pub const fn set_point_acknowledge(self) -> bool {
        self.contains(Self::OMS_12)
    }

    /// Bit 12 in homing mode: homing attained.
    pub const fn homing_attained(self) -> bool {
        self.contains(Self::OMS_12)
    }

    /// Bit 12 in profile velocity mode: speed is zero.
    pub const fn speed_zero(self) -> bool {
        self.contains(Self::OMS_12)
    }

    /// Bit 12 in the cyclic synchronous modes: the drive follows the
    /// command value.
    pub const fn drive_follows(self) -> bool {
        self.contains(Self::OMS_12)
    }

    /// Bit 13 in the position modes: following error.
    pub const fn following_error(self) -> bool {
        self.contains(Self::OMS_13)
    }

    /// Bit 13 in homing mode: homing error.
    pub const fn homing_error(self) -> bool {
        self.contains(Self::OMS_13)
    }

    /// The homing status from bits 13, 12 and 10 (homing mode only).
    pub const fn homing_status(self) -> HomingStatus {
        match (
            self.homing_error(),
            self.homing_attained(),
            self.target_reached(),
        ) {
            (false, false, false) => HomingStatus::InProgress,
            (false, false, true) => HomingStatus::Interrupted,
            (false, true, false) => HomingStatus::AttainedTargetNotReached,
            (false, true, true) => HomingStatus::Completed,
            (true, false, false) => HomingStatus::ErrorMoving,
            (true, false, true) => HomingStatus::ErrorStopped,
            (true, true, _) => HomingStatus::Reserved,
        }
    }
}

impl fmt::Display for Statusword {
    /// `0x0237 (operation enabled, voltage enabled, remote)`: the state and
    /// the set flag bits 4, 7, 9..=13 (bits 12 and 13 by number, as their
    /// meaning depends on the mode).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:04X} ({}", self.0, self.state())?;
        let flags = [
            (Self::VOLTAGE_ENABLED, "voltage enabled"),
            (Self::WARNING, "warning"),
            (Self::REMOTE, "remote"),
            (Self::TARGET_REACHED, "target reached"),
            (Self::INTERNAL_LIMIT, "internal limit"),
            (Self::OMS_12, "bit 12"),
            (Self::OMS_13, "bit 13"),
        ];
        for (mask, name) in flags {
            if self.contains(mask) {
                write!(f, ", {name}")?;
            }
        }
        f.write_str(")")
    }
}

/// The homing status (statusword bits 13, 12, 10 in homing mode).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum HomingStatus {
    /// 0 0 0: homing procedure in progress.
    InProgress,
    /// 0 0 1: homing interrupted or not started.
    Interrupted,
    /// 0 1 0: homing attained, but target not reached.
    AttainedTargetNotReached,
    /// 0 1 1: homing procedure completed successfully.
    Completed,
    /// 1 0 0: homing error, velocity not 0.
    ErrorMoving,
    /// 1 0 1: homing error, velocity is 0.
    ErrorStopped,
    /// 1 1 x: reserved.
    Reserved,
}

/// A state machine command, decoded from the controlword bits 0..=3 and 7
/// by a drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Command {
    /// Shutdown (`0xxx x110`): transitions 2, 6, 8.
    Shutdown,
    /// Switch on or disable operation (`0xxx 0111`): transitions 3, 5.
    SwitchOn,
    /// Enable operation or switch on + enable operation (`0xxx 1111`):
    /// transitions 3+4, 4, 16.
    EnableOperation,
    /// Disable voltage (`0xxx xx0x`): transitions 7, 9, 10, 12.
    DisableVoltage,
    /// Quick stop (`0xxx x01x`): transitions 7, 10, 11.
    QuickStop,
    /// Fault reset (rising edge of bit 7): transition 15.
    FaultReset,
}

impl Command {
    /// The controlword that issues this command (mode-specific bits clear).
    pub const fn controlword(self) -> Controlword {
        match self {
            Command::Shutdown => Controlword::SHUTDOWN,
            Command::SwitchOn => Controlword::SWITCH_ON,
            Command::EnableOperation => Controlword::ENABLE_OPERATION,
            Command::DisableVoltage => Controlword::DISABLE_VOLTAGE,
            Command::QuickStop => Controlword::QUICK_STOP,
            Command::FaultReset => Controlword::FAULT_RESET,
        }
    }

    /// A lower-case name, e.g. `"enable operation"`.
    pub const fn name(self) -> &'static str {
        match self {
            Command::Shutdown => "shutdown",
            Command::SwitchOn => "switch on",
            Command::EnableOperation => "enable operation",
            Command::DisableVoltage => "disable voltage",
            Command::QuickStop => "quick stop",
            Command::FaultReset => "fault reset",
        }
    }
}

impl fmt::Display for Command {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The controlword (0x6040).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Controlword(pub u16);

impl Controlword {
    /// Shutdown: 0x0006.
    pub const SHUTDOWN: Controlword = Controlword(0x0006);
    /// Switch on: 0x0007.
    pub const SWITCH_ON: Controlword = Controlword(0x0007);
    /// Enable operation (also "switch on + enable operation"): 0x000F.
    pub const ENABLE_OPERATION: Controlword = Controlword(0x000F);
    /// Disable voltage: 0x0000.
    pub const DISABLE_VOLTAGE: Controlword = Controlword(0x0000);
    /// Quick stop: 0x0002.
    pub const QUICK_STOP: Controlword = Controlword(0x0002);
    /// Disable operation: 0x0007 (the same bits as switch on).
    pub const DISABLE_OPERATION: Controlword = Controlword(0x0007);
    /// Fault reset: 0x0080; acts on the rising edge of bit 7, so the bit
    /// must have been clear in the controlword before.
    pub const FAULT_RESET: Controlword = Controlword(0x0080);

    /// Bit 0: switch on.
    pub const SWITCH_ON_BIT: u16 = 1 << 0;
    /// Bit 1: enable voltage.
    pub const ENABLE_VOLTAGE_BIT: u16 = 1 << 1;
    /// Bit 2: quick stop (active low).
    pub const QUICK_STOP_BIT: u16 = 1 << 2;
    /// Bit 3: enable operation.
    pub const ENABLE_OPERATION_BIT: u16 = 1 << 3;
    /// Bit 4 in profile position mode: new set-point.
    pub const NEW_SET_POINT_BIT: u16 = 1 << 4;
    /// Bit 4 in homing mode: homing operation start.
    pub const HOMING_START_BIT: u16 = 1 << 4;
    /// Bit 5 in profile position mode: change set immediately.
    pub const CHANGE_SET_IMMEDIATELY_BIT: u16 = 1 << 5;
    /// Bit 6 in profile position mode: the target is relative.
    pub const RELATIVE_BIT: u16 = 1 << 6;
    /// Bit 7: fault reset (rising edge).
    pub const FAULT_RESET_BIT: u16 = 1 << 7;
    /// Bit 8: halt.
    pub const HALT_BIT: u16 = 1 << 8;
    /// Bit 9 in profile position mode: change on set-point.
    pub const CHANGE_ON_SET_POINT_BIT: u16 = 1 << 9;

    /// The bits that carry the state machine command (0..=3 and 7).
    pub const COMMAND_MASK: u16 = 0x008F;

    /// The raw value.
    pub const fn bits(self) -> u16 {
        self.0
    }

    /// True if every bit of `mask` is set.
    pub const fn contains(self, mask: u16) -> bool {
        self.0 & mask == mask
    }

    /// This controlword with the bits of `mask` set (`on`) or cleared.
    #[must_use]
    pub const fn with(self, mask: u16, on: bool) -> Controlword {
        if on {
            Controlword(self.0 | mask)
        } else {
            Controlword(self.0 & !mask)
        }
    }

    /// This controlword's mode-specific bits (4..=6, 8..=15) with the
    /// command bits (0..=3, 7) of `command`, e.g. to send a state machine
    /// command without disturbing a set-point handshake.
    #[must_use]
    pub const fn with_command(self, command: Controlword) -> Controlword {
        Controlword((self.0 & !Self::COMMAND_MASK) | (command.0 & Self::COMMAND_MASK))
    }

    /// The command these bits select, as a drive decodes it; bit 7 set
    /// reads as [`Command::FaultReset`] (which acts only on its rising
    /// edge, see [`Controlword::command_after`]).
    pub const fn command(self) -> Command {
        let w = self.0;
        if w & Self::FAULT_RESET_BIT != 0 {
            Command::FaultReset
        } else if w & Self::ENABLE_VOLTAGE_BIT == 0 {
            Command::DisableVoltage
        } else if w & Self::QUICK_STOP_BIT == 0 {
            Command::QuickStop
        } else if w & Self::SWITCH_ON_BIT == 0 {
            Command::Shutdown
        } else if w & Self::ENABLE_OPERATION_BIT == 0 {
            Command::SwitchOn
        } else {
            Command::EnableOperation
        }
    }

    /// The command a drive acts on when this controlword follows
    /// `previous`: [`Command::FaultReset`] only on the rising edge of bit
    /// 7, `None` while bit 7 stays set, else [`Controlword::command`].
    pub const fn command_after(self, previous: Controlword) -> Option<Command> {
        if self.fault_reset() {
            if previous.fault_reset() {
                None
            } else {
                Some(Command::FaultReset)
            }
        } else {
            Some(self.command())
        }
    }

    /// Bit 4 in profile position mode: new set-point.
    pub const fn new_set_point(self) -> bool {
        self.contains(Self::NEW_SET_POINT_BIT)
    }

    /// Bit 4 in homing mode: homing operation start.
    pub const fn homing_start(self) -> bool {
        self.contains(Self::HOMING_START_BIT)
    }

    /// Bit 5 in profile position mode: change set immediately.
    pub const fn change_set_immediately(self) -> bool {
        self.contains(Self::CHANGE_SET_IMMEDIATELY_BIT)
    }

    /// Bit 6 in profile position mode: relative target.
    pub const fn relative(self) -> bool {
        self.contains(Self::RELATIVE_BIT)
    }

    /// Bit 7: fault reset.
    pub const fn fault_reset(self) -> bool {
        self.contains(Self::FAULT_RESET_BIT)
    }

    /// Bit 8: halt.
    pub const fn halt(self) -> bool {
        self.contains(Self::HALT_BIT)
    }
}

impl fmt::Display for Controlword {
    /// `0x000F (enable operation)`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:04X} ({})", self.0, self.command())
    }
}

/// A mode of operation (0x6060 / 0x6061).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ModeOfOperation {
    /// Profile position (1).
    ProfilePosition,
    /// Profile velocity (3).
    ProfileVelocity,
    /// Profile torque (4).
    ProfileTorque,
    /// Homing (6).
    Homing,
    /// Interpolated position (7).
    InterpolatedPosition,
    /// Cyclic synchronous position (8).
    CyclicSynchronousPosition,
    /// Cyclic synchronous velocity (9).
    CyclicSynchronousVelocity,
    /// Cyclic synchronous torque (10).
    CyclicSynchronousTorque,
}

impl ModeOfOperation {
    /// Every mode, in code order.
    pub const ALL: [ModeOfOperation; 8] = [
        ModeOfOperation::ProfilePosition,
        ModeOfOperation::ProfileVelocity,
        ModeOfOperation::ProfileTorque,
        ModeOfOperation::Homing,
        ModeOfOperation::InterpolatedPosition,
        ModeOfOperation::CyclicSynchronousPosition,
        ModeOfOperation::CyclicSynchronousVelocity,
        ModeOfOperation::CyclicSynchronousTorque,
    ];

    /// The INTEGER8 code written to 0x6060.
    pub const fn code(self) -> i8 {
        match self {
            ModeOfOperation::ProfilePosition => 1,
            ModeOfOperation::ProfileVelocity => 3,
            ModeOfOperation::ProfileTorque => 4,
            ModeOfOperation::Homing => 6,
            ModeOfOperation::InterpolatedPosition => 7,
            ModeOfOperation::CyclicSynchronousPosition => 8,
            ModeOfOperation::CyclicSynchronousVelocity => 9,
            ModeOfOperation::CyclicSynchronousTorque => 10,
        }
    }

    /// The mode with this code; `None` for 0 (no mode), 2 (velocity mode,
    /// not modelled), 5 (reserved), manufacturer modes and anything else.
    pub const fn from_code(code: i8) -> Option<ModeOfOperation> {
        Some(match code {
            1 => ModeOfOperation::ProfilePosition,
            3 => ModeOfOperation::ProfileVelocity,
            4 => ModeOfOperation::ProfileTorque,
            6 => ModeOfOperation::Homing,
            7 => ModeOfOperation::InterpolatedPosition,
            8 => ModeOfOperation::CyclicSynchronousPosition,
            9 => ModeOfOperation::CyclicSynchronousVelocity,
            10 => ModeOfOperation::CyclicSynchronousTorque,
            _ => return None,
        })
    }

    /// The mode's bit in 0x6502 supported drive modes.
    pub const fn supported_mask(self) -> u32 {
        1 << match self {
            ModeOfOperation::ProfilePosition => 0,
            ModeOfOperation::ProfileVelocity => 2,
            ModeOfOperation::ProfileTorque => 3,
            ModeOfOperation::Homing => 5,
            ModeOfOperation::InterpolatedPosition => 6,
            ModeOfOperation::CyclicSynchronousPosition => 7,
            ModeOfOperation::CyclicSynchronousVelocity => 8,
            ModeOfOperation::CyclicSynchronousTorque => 9,
        }
    }

    /// The modes a 0x6502 value declares.
    pub fn supported(mask: u32) -> impl Iterator<Item = ModeOfOperation> {
        Self::ALL
            .into_iter()
            .filter(move |m| mask & m.supported_mask() != 0)
    }

    /// The short name: `pp`, `pv`, `pt`, `hm`, `ip`, `csp`, `csv`, `cst`.
    pub const fn short_name(self) -> &'static str {
        match self {
            ModeOfOperation::ProfilePosition => "pp",
            ModeOfOperation::ProfileVelocity => "pv",
            ModeOfOperation::ProfileTorque => "pt",
            ModeOfOperation::Homing => "hm",
            ModeOfOperation::InterpolatedPosition => "ip",
            ModeOfOperation::CyclicSynchronousPosition => "csp",
            ModeOfOperation::CyclicSynchronousVelocity => "csv",
            ModeOfOperation::CyclicSynchronousTorque => "cst",
        }
    }

    /// The lower-case name, e.g. `"profile position"`.
    pub const fn name(self) -> &'static str {
        match self {
            ModeOfOperation::ProfilePosition => "profile position",
            ModeOfOperation::ProfileVelocity => "profile velocity",
            ModeOfOperation::ProfileTorque => "profile torque",
            ModeOfOperation::Homing => "homing",
            ModeOfOperation::InterpolatedPosition => "interpolated position",
            ModeOfOperation::CyclicSynchronousPosition => "cyclic synchronous position",
            ModeOfOperation::CyclicSynchronousVelocity => "cyclic synchronous velocity",
            ModeOfOperation::CyclicSynchronousTorque => "cyclic synchronous torque",
        }
    }
}

impl fmt::Display for ModeOfOperation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A text that names no mode of operation.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "unknown mode of operation {0:?}; expected pp, pv, pt, hm, ip, csp, csv, cst, \
     a full name or a code (1, 3, 4, 6..=10)"
)]
pub struct BadMode(pub String);

impl FromStr for ModeOfOperation {
    type Err = BadMode;

    /// Accepts the short name, the full name (spaces, `-` or `_`) or the
    /// code, case-insensitively.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let t = s.trim();
        if let Ok(code) = t.parse::<i8>() {
            return Self::from_code(code).ok_or_else(|| BadMode(s.to_owned()));
        }
        let norm: String = t
            .chars()
            .map(|c| match c {
                '-' | '_' => ' ',
                c => c.to_ascii_lowercase(),
            })
            .collect();
        Self::ALL
            .into_iter()
            .find(|m| m.short_name() == norm || m.name() == norm)
            .ok_or_else(|| BadMode(s.to_owned()))
    }
}

/// The next controlword that moves a drive from `current` towards
/// `target`, given the `previous` controlword sent; `None` when the drive
/// is there, when it must get out of a transient state on its own (not
/// ready to switch on, fault reaction active), or when `target` cannot be
/// requested (see [`DriveState::is_commandable`]).
///
/// The walk, from any state:
///
/// - fault: fault reset, as a rising edge of bit 7: when `previous` has
///   bit 7 set, first disable voltage (0x0000) to clear it, then 0x0080;
/// - switch on disabled: shutdown;
/// - ready to switch on: switch on (upwards) or disable voltage;
/// - switched on: enable operation (upwards), shutdown (to ready to switch
///   on) or disable voltage;
/// - operation enabled: quick stop, disable operation, shutdown or disable
///   voltage, whichever reaches the target in one transition;
/// - quick stop active: enable operation (transition 16) to operation
///   enabled, else disable voltage (12). A drive whose quick stop option
///   code is 1..=4 ignores the former and goes to switch on disabled by
///   itself once stopped; the walk continues from there;
/// - an unknown statusword: disable voltage.
///
/// The commands carry no mode-specific bits; merge them with
/// [`Controlword::with_command`] if needed.
pub fn next_command(
    current: DriveState,
    target: DriveState,
    previous: Controlword,
) -> Option<Controlword> {
    use DriveState as S;
    if current == target || !target.is_commandable() {
        return None;
    }
    Some(match current {
        S::NotReadyToSwitchOn | S::FaultReactionActive => return None,
        S::Fault if previous.fault_reset() => Controlword::DISABLE_VOLTAGE,
        S::Fault => Controlword::FAULT_RESET,
        S::Unknown => Controlword::DISABLE_VOLTAGE,
        S::SwitchOnDisabled => Controlword::SHUTDOWN,
        S::ReadyToSwitchOn => match target {
            S::SwitchOnDisabled => Controlword::DISABLE_VOLTAGE,
            _ => Controlword::SWITCH_ON,
        },
        S::SwitchedOn => match target {
            S::SwitchOnDisabled => Controlword::DISABLE_VOLTAGE,
            S::ReadyToSwitchOn => Controlword::SHUTDOWN,
            _ => Controlword::ENABLE_OPERATION,
        },
        S::OperationEnabled => match target {
            S::SwitchOnDisabled => Controlword::DISABLE_VOLTAGE,
            S::ReadyToSwitchOn => Controlword::SHUTDOWN,
            S::SwitchedOn => Controlword::DISABLE_OPERATION,
            _ => Controlword::QUICK_STOP,
        },
        S::QuickStopActive => match target {
            S::OperationEnabled => Controlword::ENABLE_OPERATION,
            _ => Controlword::DISABLE_VOLTAGE,
        },
    })
}

/// What the master was doing, for error messages: `"enabling"` for
/// operation enabled, `"disabling"` for switch on disabled, …
fn goal(target: DriveState) -> &'static str {
    match target {
        DriveState::OperationEnabled => "enabling",
        DriveState::SwitchedOn => "switching on",
        DriveState::ReadyToSwitchOn => "shutting down",
        DriveState::SwitchOnDisabled => "disabling",
        DriveState::QuickStopActive => "quick stopping",
        _ => "changing state",
    }
}

/// What to check when a drive stays in `state`.
fn stuck_hint(state: DriveState, statusword: Option<Statusword>) -> &'static str {
    if statusword.is_some_and(|sw| !sw.remote() && state != DriveState::Unknown) {
        return "the remote bit (9) is clear: the drive does not accept controlwords from \
                the network (local control)";
    }
    match state {
        DriveState::NotReadyToSwitchOn => "the drive is still initialising",
        DriveState::SwitchOnDisabled => "check DC link / STO",
        DriveState::ReadyToSwitchOn => "check DC link voltage (main power) and enable inputs",
        DriveState::SwitchedOn => "check enable inputs and the mode of operation (0x6060)",
        DriveState::OperationEnabled => {
            "the drive ignores the controlword; check that 0x6040 is written"
        }
        DriveState::QuickStopActive => {
            "the quick stop does not complete; check quick stop option code (0x605A)"
        }
        DriveState::FaultReactionActive => "the fault reaction does not complete",
        DriveState::Fault => "fault reset not accepted; read error code 0x603F",
        DriveState::Unknown => "the statusword encodes no CiA 402 state",
    }
}

/// Why a [`StateMachineDriver`] gave up.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum StateMachineError {
    /// The requested state cannot be commanded.
    #[error(
        "'{0}' cannot be requested; request switch on disabled, ready to switch on, \
         switched on, operation enabled or quick stop active"
    )]
    UnreachableTarget(DriveState),
    /// The drive stayed in one state for the whole timeout.
    #[error(
        "drive stuck in '{state}' for {} ms while {}; {}",
        .elapsed.as_millis(),
        goal(*.target),
        stuck_hint(*.state, Some(*.statusword))
    )]
    Stuck {
        /// The state the drive stayed in.
        state: DriveState,
        /// Its latest statusword.
        statusword: Statusword,
        /// The state requested.
        target: DriveState,
        /// How long it stayed there.
        elapsed: Duration,
    },
    /// No statusword arrived within the timeout.
    #[error(
        "no statusword received for {} ms while {}; check that 0x6041 is read or \
         mapped into a TPDO",
        .elapsed.as_millis(),
        goal(*.target)
    )]
    NoStatusword {
        /// The state requested.
        target: DriveState,
        /// How long the driver waited.
        elapsed: Duration,
    },
    /// The drive went back into fault after every fault reset.
    #[error(
        "drive still in fault after {resets} fault resets while {}; read error code 0x603F",
        goal(*.target)
    )]
    FaultPersists {
        /// The state requested.
        target: DriveState,
        /// Fault resets sent.
        resets: u32,
    },
}

/// What a [`StateMachineDriver`] wants next.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DriverStep {
    /// Write this controlword to 0x6040 (SDO or RPDO) now.
    Send(Controlword),
    /// Nothing to send; feed the next statusword or tick.
    Wait,
    /// Finished: the drive reached the target, or the driver gave up. Every
    /// later call returns the same.
    Done(Result<(), StateMachineError>),
}

/// A sans-IO helper that walks a drive to a target state: feed it every
/// statusword received ([`StateMachineDriver::on_statusword`]) and tick it
/// at [`StateMachineDriver::next_deadline`]; send every controlword it
/// returns.
///
/// It sends the [`next_command`] for the state reported. After sending it
/// waits for the drive to change state before sending a different command,
/// or for the retry interval (100 ms by default) to pass, after which it
/// sends the planned command again: that repeats a lost write, and in
/// fault produces a new rising edge of bit 7. It fails when the drive stays
/// in one state for the timeout ([`StateMachineError::Stuck`]), when no
/// statusword arrives for the timeout, or when the drive is in fault again
/// after the maximum number of fault resets (3 by default).
#[derive(Debug, Clone)]
pub struct StateMachineDriver {
    target: DriveState,
    timeout: Duration,
    retry: Duration,
    max_fault_resets: u32,
    started: Duration,
    last_sent: Controlword,
    sent_at: Option<Duration>,
    /// The drive changed state since the last send.
    reacted: bool,
    statusword: Option<Statusword>,
    state_since: Duration,
    fault_resets: u32,
    done: Option<Result<(), StateMachineError>>,
}

impl StateMachineDriver {
    /// Default interval before a command is repeated.
    pub const DEFAULT_RETRY: Duration = Duration::from_millis(100);
    /// Default number of fault resets before giving up.
    pub const DEFAULT_MAX_FAULT_RESETS: u32 = 3;

    /// A driver towards `target`, started at `now`, assuming the previous
    /// controlword was 0x0000 (see [`StateMachineDriver::with_previous`]).
    /// `timeout` bounds the time the drive may stay in any one state (and
    /// the wait for the first statusword).
    pub fn new(
        target: DriveState,
        timeout: Duration,
        now: Duration,
    ) -> Result<Self, StateMachineError> {
        if !target.is_commandable() {
            return Err(StateMachineError::UnreachableTarget(target));
        }
        Ok(StateMachineDriver {
            target,
            timeout,
            retry: Self::DEFAULT_RETRY,
            max_fault_resets: Self::DEFAULT_MAX_FAULT_RESETS,
            started: now,
            last_sent: Controlword::DISABLE_VOLTAGE,
            sent_at: None,
            reacted: false,
            statusword: None,
            state_since: now,
            fault_resets: 0,
            done: None,
        })
    }

    /// The controlword the drive holds now (e.g. read from 0x6040), so that
    /// a fault reset starts with a proper edge.
    #[must_use]
    pub fn with_previous(mut self, previous: Controlword) -> Self {
        self.last_sent = previous;
        self
    }

    /// How long to wait for a reaction before repeating a command.
    #[must_use]
    pub fn with_retry(mut self, retry: Duration) -> Self {
        self.retry = retry;
        self
    }

    /// How many fault resets to send before giving up.
    #[must_use]
    pub fn with_max_fault_resets(mut self, resets: u32) -> Self {
        self.max_fault_resets = resets;
        self
    }

    /// The requested state.
    pub fn target(&self) -> DriveState {
        self.target
    }

    /// The state of the latest statusword, if any.
    pub fn state(&self) -> Option<DriveState> {
        self.statusword.map(Statusword::state)
    }

    /// The latest statusword, if any.
    pub fn statusword(&self) -> Option<Statusword> {
        self.statusword
    }

    /// The latest controlword sent (or the one given to
    /// [`StateMachineDriver::with_previous`]).
    pub fn last_controlword(&self) -> Controlword {
        self.last_sent
    }

    /// The outcome, once finished.
    pub fn result(&self) -> Option<&Result<(), StateMachineError>> {
        self.done.as_ref()
    }

    /// Handles a statusword received at `now`.
    pub fn on_statusword(&mut self, statusword: Statusword, now: Duration) -> DriverStep {
        if let Some(done) = &self.done {
            return DriverStep::Done(done.clone());
        }
        let state = statusword.state();
        if self.state() != Some(state) {
            self.state_since = now;
            self.reacted = true;
        }
        self.statusword = Some(statusword);
        if state == self.target {
            return self.finish(Ok(()));
        }
        self.plan(now)
    }

    /// Checks the timeout and retries at `now`.
    pub fn on_tick(&mut self, now: Duration) -> DriverStep {
        if let Some(done) = &self.done {
            return DriverStep::Done(done.clone());
        }
        self.plan(now)
    }

    /// When [`StateMachineDriver::on_tick`] must run next; `None` once
    /// finished.
    pub fn next_deadline(&self) -> Option<Duration> {
        if self.done.is_some() {
            return None;
        }
        let stuck = self.state_since + self.timeout;
        let retry = self.sent_at.map(|t| t + self.retry);
        Some(retry.map_or(stuck, |r| r.min(stuck)))
    }

    fn finish(&mut self, result: Result<(), StateMachineError>) -> DriverStep {
        self.done = Some(result.clone());
        DriverStep::Done(result)
    }

    fn plan(&mut self, now: Duration) -> DriverStep {
        let Some(statusword) = self.statusword else {
            let elapsed = now.saturating_sub(self.started);
            if elapsed >= self.timeout {
                return self.finish(Err(StateMachineError::NoStatusword {
                    target: self.target,
                    elapsed,
                }));
            }
            return DriverStep::Wait;
        };
        let state = statusword.state();
        let elapsed = now.saturating_sub(self.state_since);
        if elapsed >= self.timeout {
            return self.finish(Err(StateMachineError::Stuck {
                state,
                statusword,
                target: self.target,
                elapsed,
            }));
        }
        let Some(command) = next_command(state, self.target, self.last_sent) else {
            return DriverStep::Wait;
        };
        let retry_due = self.sent_at.is_none_or(|t| now >= t + self.retry);
        let send = retry_due || (command != self.last_sent && self.reacted);
        if !send {
            return DriverStep::Wait;
        }
        if command.fault_reset() && !self.last_sent.fault_reset() {
            if self.fault_resets >= self.max_fault_resets {
                return self.finish(Err(StateMachineError::FaultPersists {
                    target: self.target,
                    resets: self.fault_resets,
                }));
            }
            self.fault_resets += 1;
        }
        self.last_sent = command;
        self.sent_at = Some(now);
        self.reacted = false;
        DriverStep::Send(command)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use DriveState as S;

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn profile_objects_of_further_axes_are_0x800_apart() {
        assert_eq!(profile_index(0x6040, 0), 0x6040);
        assert_eq!(profile_index(0x6040, 1), 0x6840);
        assert_eq!(profile_index(0x6041, 1), 0x6841);
        assert_eq!(profile_index(0x607A, 1), 0x687A);
        assert_eq!(profile_index(0x6502, 1), 0x6D02);
        assert_eq!(profile_index(0x60FF, 7), 0x98FF);
        // The node's own objects are the same for every axis.
        assert_eq!(profile_index(0x1017, 3), 0x1017);
        assert_eq!(profile_index(0x2100, 1), 0x2100);
        assert_eq!(
            on_axis(objects::SOFTWARE_POSITION_LIMIT_MAX, 2),
            ObjectAddress::new(0x707D, 2)
        );
        assert_eq!(
            axis_of(ObjectAddress::new(0x6D02, 0)),
            Some((1, objects::SUPPORTED_DRIVE_MODES))
        );
        assert_eq!(axis_of(ObjectAddress::new(0x9FFF, 0)).map(|a| a.0), Some(7));
        assert_eq!(axis_of(ObjectAddress::new(0x1A00, 1)), None);
        assert_eq!(axis_of(ObjectAddress::new(0xA000, 0)), None);
        assert_eq!(
            first_axis(ObjectAddress::new(0x6841, 0)),
            objects::STATUSWORD
        );
        assert_eq!(
            first_axis(ObjectAddress::new(0x1018, 1)),
            ObjectAddress::new(0x1018, 1)
        );
    }

    #[test]
    fn statusword_decodes_every_state() {
        let cases: &[(u16, DriveState)] = &[
            (0x0000, S::NotReadyToSwitchOn),
            (0x0010, S::NotReadyToSwitchOn),
            (0x0020, S::NotReadyToSwitchOn),
            (0x0040, S::SwitchOnDisabled),
            (0x0250, S::SwitchOnDisabled),
            (0x0260, S::SwitchOnDisabled),
            (0x0021, S::ReadyToSwitchOn),
            (0x0231, S::ReadyToSwitchOn),
            (0x0023, S::SwitchedOn),
            (0x0233, S::SwitchedOn),
            (0x0027, S::OperationEnabled),
            (0x0237, S::OperationEnabled),
            (0x1637, S::OperationEnabled),
            (0xFFB7, S::OperationEnabled),
            (0x0007, S::QuickStopActive),
            (0x0617, S::QuickStopActive),
            (0x000F, S::FaultReactionActive),
            (0x002F, S::FaultReactionActive),
            (0x021F, S::FaultReactionActive),
            (0x0008, S::Fault),
            (0x0208, S::Fault),
            (0x0238, S::Fault),
            // Undefined patterns.
            (0x0001, S::Unknown),
            (0x0041, S::Unknown),
            (0x0048, S::Unknown),
            (0x0009, S::Unknown),
            (0x0025, S::Unknown),
        ];
        for &(sw, state) in cases {
            assert_eq!(Statusword(sw).state(), state, "0x{sw:04X}");
        }
        // Only bits 0..=3, 5 and 6 matter.
        for sw in 0..=u16::MAX {
            assert_eq!(
                Statusword(sw).state(),
                Statusword(sw & Statusword::STATE_MASK).state()
            );
        }
        // The canonical bits of every state decode to it.
        for state in DriveState::ALL {
            assert_eq!(Statusword::from_state(state).state(), state);
            let with_flags = Statusword::from_state(state).0 | 0xFF90;
            assert_eq!(Statusword(with_flags).state(), state);
        }
        assert_eq!(Statusword::from_state(S::Unknown), Statusword(0));
    }

    #[test]
    fn statusword_flags() {
        let sw = Statusword(0x3E97);
        assert!(sw.voltage_enabled());
        assert!(sw.warning());
        assert!(sw.remote());
        assert!(sw.target_reached());
        assert!(sw.internal_limit());
        assert!(sw.set_point_acknowledge() && sw.homing_attained());
        assert!(sw.speed_zero() && sw.drive_follows());
        assert!(sw.following_error() && sw.homing_error());
        assert!(sw.quick_stop_active());
        assert!(!sw.fault());
        let none = Statusword(0x0027);
        assert!(!none.voltage_enabled() && !none.warning() && !none.remote());
        assert!(!none.target_reached() && !none.internal_limit());
        assert!(!none.set_point_acknowledge() && !none.following_error());
        assert!(!none.quick_stop_active());
        assert_eq!(
            Statusword(0x0237).with(Statusword::TARGET_REACHED, true),
            Statusword(0x0637)
        );
        assert_eq!(
            Statusword(0x0637).with(Statusword::TARGET_REACHED, false),
            Statusword(0x0237)
        );
        assert_eq!(
            Statusword(0x0237).to_string(),
            "0x0237 (operation enabled, voltage enabled, remote)"
        );
        assert_eq!(
            Statusword(0x1E37).to_string(),
            "0x1E37 (operation enabled, voltage enabled, remote, target reached, \
             internal limit, bit 12)"
        );
    }

    #[test]
    fn homing_status_bits() {
        let cases = [
            (0x0237, HomingStatus::InProgress),
            (0x0637, HomingStatus::Interrupted),
            (0x1237, HomingStatus::AttainedTargetNotReached),
            (0x1637, HomingStatus::Completed),
            (0x2237, HomingStatus::ErrorMoving),
            (0x2637, HomingStatus::ErrorStopped),
            (0x3237, HomingStatus::Reserved),
        ];
        for (sw, status) in cases {
            assert_eq!(Statusword(sw).homing_status(), status, "0x{sw:04X}");
        }
    }

    #[test]
    fn controlword_commands() {
        use Command as C;
        let cases: &[(u16, Command)] = &[
            (0x0006, C::Shutdown),
            (0x000E, C::Shutdown),
            (0x0007, C::SwitchOn),
            (0x000F, C::EnableOperation),
            (0x001F, C::EnableOperation),
            (0x017F, C::EnableOperation),
            (0x0000, C::DisableVoltage),
            (0x0001, C::DisableVoltage),
            (0x0004, C::DisableVoltage),
            (0x000D, C::DisableVoltage),
            (0x0002, C::QuickStop),
            (0x0003, C::QuickStop),
            (0x000B, C::QuickStop),
            (0x0080, C::FaultReset),
            (0x008F, C::FaultReset),
        ];
        for &(cw, cmd) in cases {
            assert_eq!(Controlword(cw).command(), cmd, "0x{cw:04X}");
        }
        for cmd in [
            C::Shutdown,
            C::SwitchOn,
            C::EnableOperation,
            C::DisableVoltage,
            C::QuickStop,
            C::FaultReset,
        ] {
            assert_eq!(cmd.controlword().command(), cmd);
        }
        assert_eq!(Controlword::SHUTDOWN.bits(), 0x0006);
        assert_eq!(Controlword::SWITCH_ON.bits(), 0x0007);
        assert_eq!(Controlword::ENABLE_OPERATION.bits(), 0x000F);
        assert_eq!(Controlword::DISABLE_VOLTAGE.bits(), 0x0000);
        assert_eq!(Controlword::QUICK_STOP.bits(), 0x0002);
        assert_eq!(Controlword::DISABLE_OPERATION.bits(), 0x0007);
        assert_eq!(Controlword::FAULT_RESET.bits(), 0x0080);
        assert_eq!(Controlword(0x000F).to_string(), "0x000F (enable operation)");
    }

    #[test]
    fn controlword_mode_bits() {
        let cw = Controlword::ENABLE_OPERATION
            .with(Controlword::NEW_SET_POINT_BIT, true)
            .with(Controlword::CHANGE_SET_IMMEDIATELY_BIT, true)
            .with(Controlword::RELATIVE_BIT, true)
            .with(Controlword::HALT_BIT, true);
        assert_eq!(cw, Controlword(0x017F));
        assert!(cw.new_set_point() && cw.homing_start());
        assert!(cw.change_set_immediately() && cw.relative() && cw.halt());
        assert!(!cw.fault_reset());
        // A state command keeps the handshake bits.
        assert_eq!(
            cw.with_command(Controlword::QUICK_STOP),
            Controlword(0x0172)
        );
        assert_eq!(
            Controlword(0x0172).with(Controlword::HALT_BIT, false),
            Controlword(0x0072)
        );
    }

    #[test]
    fn fault_reset_acts_on_the_rising_edge_only() {
        let off = Controlword(0x0000);
        let on = Controlword::FAULT_RESET;
        assert_eq!(on.command_after(off), Some(Command::FaultReset));
        assert_eq!(on.command_after(on), None);
        assert_eq!(Controlword(0x008F).command_after(on), None);
        assert_eq!(off.command_after(on), Some(Command::DisableVoltage));
        assert_eq!(
            Controlword(0x000F).command_after(on),
            Some(Command::EnableOperation)
        );
        // A drive in fault: the edge resets it, holding the bit does not.
        let apply = |prev: Controlword, cw: Controlword| {
            cw.command_after(prev).and_then(|c| S::Fault.on_command(c))
        };
        assert_eq!(
            apply(off, on).map(|t| (t.number, t.to)),
            Some((15, S::SwitchOnDisabled))
        );
        assert_eq!(apply(on, on), None);
        assert_eq!(apply(Controlword(0x000F), Controlword(0x000F)), None);
    }

    /// Every transition of the state diagram, and commands that do nothing.
    #[test]
    fn state_diagram_transitions() {
        use Command as C;
        let transitions: &[(DriveState, u16, u8, DriveState)] = &[
            (S::SwitchOnDisabled, 0x0006, 2, S::ReadyToSwitchOn),
            (S::ReadyToSwitchOn, 0x0007, 3, S::SwitchedOn),
            (S::ReadyToSwitchOn, 0x000F, 3, S::SwitchedOn),
            (S::SwitchedOn, 0x000F, 4, S::OperationEnabled),
            (S::OperationEnabled, 0x0007, 5, S::SwitchedOn),
            (S::SwitchedOn, 0x0006, 6, S::ReadyToSwitchOn),
            (S::ReadyToSwitchOn, 0x0000, 7, S::SwitchOnDisabled),
            (S::ReadyToSwitchOn, 0x0002, 7, S::SwitchOnDisabled),
            (S::OperationEnabled, 0x0006, 8, S::ReadyToSwitchOn),
            (S::OperationEnabled, 0x0000, 9, S::SwitchOnDisabled),
            (S::SwitchedOn, 0x0000, 10, S::SwitchOnDisabled),
            (S::SwitchedOn, 0x0002, 10, S::SwitchOnDisabled),
            (S::OperationEnabled, 0x0002, 11, S::QuickStopActive),
            (S::QuickStopActive, 0x0000, 12, S::SwitchOnDisabled),
            (S::Fault, 0x0080, 15, S::SwitchOnDisabled),
            (S::QuickStopActive, 0x000F, 16, S::OperationEnabled),
        ];
        for &(from, cw, number, to) in transitions {
            let cmd = Controlword(cw).command_after(Controlword(0)).unwrap();
            assert_eq!(
                from.on_command(cmd),
                Some(Transition { number, to }),
                "{from} + 0x{cw:04X}"
            );
        }
        let none: &[(DriveState, Command)] = &[
            (S::SwitchOnDisabled, C::SwitchOn),
            (S::SwitchOnDisabled, C::EnableOperation),
            (S::SwitchOnDisabled, C::DisableVoltage),
            (S::SwitchOnDisabled, C::QuickStop),
            (S::SwitchOnDisabled, C::FaultReset),
            (S::ReadyToSwitchOn, C::Shutdown),
            (S::SwitchedOn, C::SwitchOn),
            (S::OperationEnabled, C::EnableOperation),
            (S::QuickStopActive, C::QuickStop),
            (S::QuickStopActive, C::Shutdown),
            (S::QuickStopActive, C::SwitchOn),
            (S::Fault, C::EnableOperation),
            (S::Fault, C::DisableVoltage),
        ];
        for &(from, cmd) in none {
            assert_eq!(from.on_command(cmd), None, "{from} + {cmd}");
        }
        // The transient states take no command at all.
        for cmd in [
            C::Shutdown,
            C::SwitchOn,
            C::EnableOperation,
            C::DisableVoltage,
            C::QuickStop,
            C::FaultReset,
        ] {
            for from in [S::NotReadyToSwitchOn, S::FaultReactionActive, S::Unknown] {
                assert_eq!(from.on_command(cmd), None);
            }
        }
    }

    /// An ideal drive: applies the controlword's command until it yields no
    /// transition, takes the automatic transitions 1 and 14, and (quick
    /// stop option code 2) leaves quick stop active by itself.
    fn ideal_drive(state: DriveState, prev: Controlword, cw: Controlword) -> DriveState {
        let mut state = match state {
            S::NotReadyToSwitchOn => S::SwitchOnDisabled,
            S::FaultReactionActive => S::Fault,
            S::QuickStopActive => S::SwitchOnDisabled,
            s => s,
        };
        if let Some(cmd) = cw.command_after(prev) {
            while let Some(t) = state.on_command(cmd) {
                state = t.to;
            }
        }
        state
    }

    /// Walks from `from` to `to` with the planner and an ideal drive;
    /// returns the controlwords sent.
    fn walk(from: DriveState, to: DriveState, mut prev: Controlword) -> Vec<u16> {
        let mut state = from;
        let mut sent = Vec::new();
        for _ in 0..10 {
            if state == to {
                return sent;
            }
            match next_command(state, to, prev) {
                Some(cw) => {
                    sent.push(cw.bits());
                    state = ideal_drive(state, prev, cw);
                    prev = cw;
                }
                None => state = ideal_drive(state, prev, prev),
            }
        }
        panic!("{from} → {to} did not converge: {sent:04X?}");
    }

    #[test]
    fn planner_to_operation_enabled_from_every_state() {
        let oe = S::OperationEnabled;
        let z = Controlword(0);
        assert_eq!(walk(S::NotReadyToSwitchOn, oe, z), [0x06, 0x07, 0x0F]);
        assert_eq!(walk(S::SwitchOnDisabled, oe, z), [0x06, 0x07, 0x0F]);
        assert_eq!(walk(S::ReadyToSwitchOn, oe, z), [0x07, 0x0F]);
        assert_eq!(walk(S::SwitchedOn, oe, z), [0x0F]);
        assert_eq!(walk(S::OperationEnabled, oe, z), [0u16; 0]);
        // Transition 16 where the drive allows it (the planner's first
        // choice); the ideal drive here leaves quick stop by itself.
        assert_eq!(
            next_command(S::QuickStopActive, oe, Controlword::QUICK_STOP),
            Some(Controlword::ENABLE_OPERATION)
        );
        assert_eq!(
            walk(S::QuickStopActive, oe, Controlword::QUICK_STOP),
            [0x0F, 0x06, 0x07, 0x0F]
        );
        assert_eq!(
            walk(S::FaultReactionActive, oe, z),
            [0x80, 0x06, 0x07, 0x0F]
        );
        assert_eq!(walk(S::Fault, oe, z), [0x80, 0x06, 0x07, 0x0F]);
        // Bit 7 already set: clear it first for a rising edge.
        assert_eq!(
            walk(S::Fault, oe, Controlword::FAULT_RESET),
            [0x00, 0x80, 0x06, 0x07, 0x0F]
        );
        assert_eq!(
            next_command(S::Unknown, oe, z),
            Some(Controlword::DISABLE_VOLTAGE)
        );
    }

    #[test]
    fn planner_to_switch_on_disabled_from_every_state() {
        let sod = S::SwitchOnDisabled;
        let z = Controlword(0x000F);
        assert_eq!(walk(S::NotReadyToSwitchOn, sod, z), [0u16; 0]);
        assert_eq!(walk(S::SwitchOnDisabled, sod, z), [0u16; 0]);
        assert_eq!(walk(S::ReadyToSwitchOn, sod, z), [0x00]);
        assert_eq!(walk(S::SwitchedOn, sod, z), [0x00]);
        assert_eq!(walk(S::OperationEnabled, sod, z), [0x00]);
        assert_eq!(walk(S::QuickStopActive, sod, z), [0x00]);
        assert_eq!(walk(S::FaultReactionActive, sod, z), [0x80]);
        assert_eq!(walk(S::Fault, sod, z), [0x80]);
        assert_eq!(walk(S::Fault, sod, Controlword(0x0080)), [0x00, 0x80]);
        // Waiting states and targets that cannot be requested.
        assert_eq!(
            next_command(S::NotReadyToSwitchOn, S::OperationEnabled, z),
            None
        );
        assert_eq!(next_command(S::FaultReactionActive, sod, z), None);
        for target in [
            S::Fault,
            S::FaultReactionActive,
            S::NotReadyToSwitchOn,
            S::Unknown,
        ] {
            assert_eq!(next_command(S::OperationEnabled, target, z), None);
        }
    }

    #[test]
    fn planner_other_targets() {
        let z = Controlword(0);
        assert_eq!(walk(S::OperationEnabled, S::SwitchedOn, z), [0x07]);
        assert_eq!(walk(S::OperationEnabled, S::ReadyToSwitchOn, z), [0x06]);
        assert_eq!(walk(S::SwitchedOn, S::ReadyToSwitchOn, z), [0x06]);
        assert_eq!(walk(S::SwitchOnDisabled, S::SwitchedOn, z), [0x06, 0x07]);
        assert_eq!(walk(S::Fault, S::ReadyToSwitchOn, z), [0x80, 0x06]);
        // Quick stop from operation enabled (transition 11).
        assert_eq!(
            next_command(S::OperationEnabled, S::QuickStopActive, z),
            Some(Controlword::QUICK_STOP)
        );
        assert_eq!(
            next_command(S::SwitchOnDisabled, S::QuickStopActive, z),
            Some(Controlword::SHUTDOWN)
        );
        assert_eq!(
            next_command(S::SwitchedOn, S::QuickStopActive, z),
            Some(Controlword::ENABLE_OPERATION)
        );
        assert_eq!(
            next_command(S::QuickStopActive, S::SwitchedOn, z),
            Some(Controlword::DISABLE_VOLTAGE)
        );
    }

    #[test]
    fn quick_stop_and_back() {
        let t = S::OperationEnabled
            .on_command(Controlword::QUICK_STOP.command())
            .unwrap();
        assert_eq!((t.number, t.to), (11, S::QuickStopActive));
        assert_eq!(
            Statusword::from_state(t.to).with(Statusword::REMOTE, true),
            Statusword(0x0207)
        );
        assert!(Statusword(0x0217).quick_stop_active());
        let back = S::QuickStopActive
            .on_command(Controlword::ENABLE_OPERATION.command())
            .unwrap();
        assert_eq!((back.number, back.to), (16, S::OperationEnabled));
        let off = S::QuickStopActive
            .on_command(Controlword::DISABLE_VOLTAGE.command())
            .unwrap();
        assert_eq!((off.number, off.to), (12, S::SwitchOnDisabled));
    }

    #[test]
    fn modes_of_operation() {
        let codes: Vec<i8> = ModeOfOperation::ALL.iter().map(|m| m.code()).collect();
        assert_eq!(codes, [1, 3, 4, 6, 7, 8, 9, 10]);
        for m in ModeOfOperation::ALL {
            assert_eq!(ModeOfOperation::from_code(m.code()), Some(m));
            assert_eq!(m.short_name().parse::<ModeOfOperation>(), Ok(m));
            assert_eq!(m.name().parse::<ModeOfOperation>(), Ok(m));
            assert_eq!(m.code().to_string().parse::<ModeOfOperation>(), Ok(m));
        }
        for code in [0, 2, 5, 11, -1, i8::MIN] {
            assert_eq!(ModeOfOperation::from_code(code), None);
        }
        assert_eq!(
            "Cyclic-Synchronous_Position".parse(),
            Ok(ModeOfOperation::CyclicSynchronousPosition)
        );
        assert!("2".parse::<ModeOfOperation>().is_err());
        assert!("servo".parse::<ModeOfOperation>().is_err());
        // The simulated drive's 0x6502: PP, PV, HM, CSP, CSV.
        let supported: Vec<_> = ModeOfOperation::supported(0x1A5)
            .map(ModeOfOperation::short_name)
            .collect();
        assert_eq!(supported, ["pp", "pv", "hm", "csp", "csv"]);
    }

    #[test]
    fn driver_enables_a_drive_from_fault() {
        let mut d = StateMachineDriver::new(S::OperationEnabled, 500 * MS, Duration::ZERO)
            .unwrap()
            .with_previous(Controlword(0x0080));
        assert_eq!(d.on_tick(MS), DriverStep::Wait);
        // Bit 7 was set: clear it, then the edge.
        assert_eq!(
            d.on_statusword(Statusword(0x0208), 2 * MS),
            DriverStep::Send(Controlword(0x0000))
        );
        // A stale statusword does not toggle bit 7 before the retry time.
        assert_eq!(
            d.on_statusword(Statusword(0x0208), 3 * MS),
            DriverStep::Wait
        );
        assert_eq!(d.next_deadline(), Some(102 * MS));
        assert_eq!(d.on_tick(102 * MS), DriverStep::Send(Controlword(0x0080)));
        assert_eq!(
            d.on_statusword(Statusword(0x0240), 103 * MS),
            DriverStep::Send(Controlword::SHUTDOWN)
        );
        assert_eq!(
            d.on_statusword(Statusword(0x0221), 104 * MS),
            DriverStep::Send(Controlword::SWITCH_ON)
        );
        assert_eq!(
            d.on_statusword(Statusword(0x0233), 105 * MS),
            DriverStep::Send(Controlword::ENABLE_OPERATION)
        );
        assert_eq!(
            d.on_statusword(Statusword(0x0233), 106 * MS),
            DriverStep::Wait
        );
        assert_eq!(
            d.on_statusword(Statusword(0x0637), 107 * MS),
            DriverStep::Done(Ok(()))
        );
        assert_eq!(d.result(), Some(&Ok(())));
        assert_eq!(d.on_tick(10_000 * MS), DriverStep::Done(Ok(())));
        assert_eq!(d.next_deadline(), None);
        assert_eq!(d.last_controlword(), Controlword::ENABLE_OPERATION);
        assert_eq!(d.state(), Some(S::OperationEnabled));
    }

    #[test]
    fn driver_times_out_naming_the_stuck_state() {
        let mut d = StateMachineDriver::new(S::OperationEnabled, 500 * MS, Duration::ZERO).unwrap();
        let sod = Statusword(0x0240);
        assert_eq!(
            d.on_statusword(sod, Duration::ZERO),
            DriverStep::Send(Controlword::SHUTDOWN)
        );
        let mut sent = vec![(0, 0x0006)];
        let mut now;
        let err = loop {
            now = d.next_deadline().unwrap();
            match d.on_tick(now) {
                DriverStep::Send(cw) => sent.push((now.as_millis(), cw.bits())),
                DriverStep::Wait => {}
                DriverStep::Done(r) => break r.unwrap_err(),
            }
            assert_eq!(d.on_statusword(sod, now), DriverStep::Wait);
        };
        // Repeated every 100 ms, then given up after 500 ms.
        assert_eq!(sent, [(0, 6), (100, 6), (200, 6), (300, 6), (400, 6)]);
        assert_eq!(now, 500 * MS);
        assert_eq!(
            err.to_string(),
            "drive stuck in 'switch on disabled' for 500 ms while enabling; check DC link / STO"
        );
        assert_eq!(
            err,
            StateMachineError::Stuck {
                state: S::SwitchOnDisabled,
                statusword: sod,
                target: S::OperationEnabled,
                elapsed: 500 * MS,
            }
        );
    }

    #[test]
    fn driver_timeout_restarts_with_every_state_change() {
        let mut d = StateMachineDriver::new(S::OperationEnabled, 500 * MS, Duration::ZERO).unwrap();
        d.on_statusword(Statusword(0x0240), Duration::ZERO);
        d.on_statusword(Statusword(0x0221), 400 * MS);
        assert_eq!(
            d.on_tick(800 * MS),
            DriverStep::Send(Controlword::SWITCH_ON)
        );
        let DriverStep::Done(Err(err)) = d.on_tick(900 * MS) else {
            panic!("expected a timeout");
        };
        assert_eq!(
            err.to_string(),
            "drive stuck in 'ready to switch on' for 500 ms while enabling; check DC link \
             voltage (main power) and enable inputs"
        );
        // A drive in local control says so.
        let mut d = StateMachineDriver::new(S::SwitchOnDisabled, 200 * MS, Duration::ZERO).unwrap();
        d.on_statusword(Statusword(0x0037), Duration::ZERO);
        let DriverStep::Done(Err(err)) = d.on_tick(200 * MS) else {
            panic!("expected a timeout");
        };
        assert_eq!(
            err.to_string(),
            "drive stuck in 'operation enabled' for 200 ms while disabling; the remote bit \
             (9) is clear: the drive does not accept controlwords from the network (local \
             control)"
        );
    }

    #[test]
    fn driver_without_statusword_and_with_persistent_fault() {
        let mut d = StateMachineDriver::new(S::OperationEnabled, 300 * MS, 100 * MS).unwrap();
        assert_eq!(d.next_deadline(), Some(400 * MS));
        assert_eq!(d.on_tick(399 * MS), DriverStep::Wait);
        let DriverStep::Done(Err(err)) = d.on_tick(400 * MS) else {
            panic!("expected a timeout");
        };
        assert_eq!(
            err.to_string(),
            "no statusword received for 300 ms while enabling; check that 0x6041 is read or \
             mapped into a TPDO"
        );

        let mut d = StateMachineDriver::new(S::SwitchOnDisabled, 10_000 * MS, Duration::ZERO)
            .unwrap()
            .with_retry(10 * MS)
            .with_max_fault_resets(2);
        let fault = Statusword(0x0208);
        let mut sent = Vec::new();
        let mut now = Duration::ZERO;
        let err = loop {
            match d.on_statusword(fault, now) {
                DriverStep::Send(cw) => sent.push(cw.bits()),
                DriverStep::Wait => {}
                DriverStep::Done(r) => break r.unwrap_err(),
            }
            now += MS;
        };
        assert_eq!(sent, [0x80, 0x00, 0x80, 0x00]);
        assert_eq!(now, 40 * MS);
        assert_eq!(
            err.to_string(),
            "drive still in fault after 2 fault resets while disabling; read error code 0x603F"
        );
    }

    #[test]
    fn driver_rejects_targets_that_cannot_be_requested() {
        for target in [
            S::Fault,
            S::FaultReactionActive,
            S::NotReadyToSwitchOn,
            S::Unknown,
        ] {
            let err = StateMachineDriver::new(target, MS, Duration::ZERO).unwrap_err();
            assert_eq!(err, StateMachineError::UnreachableTarget(target));
        }
        assert_eq!(
            StateMachineError::UnreachableTarget(S::Fault).to_string(),
            "'fault' cannot be requested; request switch on disabled, ready to switch on, \
             switched on, operation enabled or quick stop active"
        );
        // Already there: done at the first statusword, nothing sent.
        let mut d = StateMachineDriver::new(S::SwitchOnDisabled, MS, Duration::ZERO).unwrap();
        assert_eq!(
            d.on_statusword(Statusword(0x0250), Duration::ZERO),
            DriverStep::Done(Ok(()))
        );
    }
}
