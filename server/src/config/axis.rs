//! `[[axis]]`: CiA 402 drives as axes: units, limits, modes, stops.

use super::Config;
use cangate_axis::{
    AxisSpec, Cia402Drive, DriveMode, DriveSpec, MotionSpec, PositionMode, ProcessDataPath,
    StopKind, TorqueSpec, Units,
};
use cangate_canopen::NodeId;
use serde::{Deserialize, Serialize};
use std::time::Duration;

/// How an axis executes moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PositionModeChoice {
    /// CiA 402 profile position: the drive plans.
    #[default]
    Profile,
    /// Cyclic synchronous position: the gateway plans, a set-point per SYNC
    /// (needs `sync_period_us` on the bus's `[[canopen]]`).
    Cyclic,
}

/// The CiA 402 mode of operation an axis runs in (`mode`); see
/// [`DriveMode`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModeChoice {
    /// Profile position (1).
    ProfilePosition,
    /// Cyclic synchronous position (8).
    Csp,
    /// Interpolated position (7), for drives without CSP.
    Ip,
    /// Cyclic synchronous velocity (9).
    Csv,
    /// Cyclic synchronous torque (10).
    Cst,
    /// Profile torque (4).
    ProfileTorque,
}

impl ModeChoice {
    /// The runtime's mode.
    pub fn mode(self) -> DriveMode {
        match self {
            ModeChoice::ProfilePosition => DriveMode::ProfilePosition,
            ModeChoice::Csp => DriveMode::CyclicPosition,
            ModeChoice::Ip => DriveMode::InterpolatedPosition,
            ModeChoice::Csv => DriveMode::CyclicVelocity,
            ModeChoice::Cst => DriveMode::CyclicTorque,
            ModeChoice::ProfileTorque => DriveMode::ProfileTorque,
        }
    }
}

/// How an axis's process data (controlword, targets, statusword, actual
/// position and velocity) travels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ProcessDataChoice {
    /// PDOs, mapped by the gateway at the drive's boot (the normal case).
    #[default]
    Pdo,
    /// SDO: the gateway polls the feedback every `sdo_poll_ms` and writes
    /// changed objects; for drives whose PDOs cannot be mapped, or a bus
    /// without room for them. Profile position only.
    Sdo,
}

/// How a lapsed lease or dead-man timeout stops an axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StopChoice {
    /// Profile deceleration.
    #[default]
    Halt,
    /// CiA 402 quick stop.
    QuickStop,
}

/// The keys every axis has, whatever drives it: units, limits, the
/// defaults of moves, the stops and the time bounds. Flattened into
/// `[[axis]]` and `[[cansmc.axis]]` (which refuse unknown keys
/// themselves); [`CommonAxisConfig::motion`] is the runtime's
/// [`MotionSpec`]. Deserialized by hand so that a value of the wrong type
/// is reported with its key (serde's flattening would lose it).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CommonAxisConfig {
    /// User unit name, e.g. "mm" or "deg".
    pub unit: String,
    /// Drive (or slave encoder) counts per user unit (negative inverts the
    /// direction).
    pub counts_per_unit: f64,
    /// Soft limits in user units (both or none); a CiA 402 drive also gets
    /// them in its 0x607D at boot.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub min_position: Option<f64>,
    /// Soft limits in user units.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_position: Option<f64>,
    /// Velocity ceiling, units/s.
    pub max_velocity: f64,
    /// Acceleration ceiling, units/s².
    pub max_acceleration: f64,
    /// Velocity of moves that give none (default: a quarter of the maximum).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub default_velocity: Option<f64>,
    /// Acceleration of moves that give none (default: a quarter of the
    /// maximum).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub default_acceleration: Option<f64>,
    /// Deceleration of every stop (Stop, StopAxes, the jog dead-man, a lost
    /// lease, shutdown), units/s²; a stop brakes harder when the
    /// interrupted motion's own deceleration is higher (default: the
    /// maximum acceleration).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stop_deceleration: Option<f64>,
    /// Deceleration of a quick stop, units/s² (default: the maximum
    /// acceleration).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub quick_stop_deceleration: Option<f64>,
    /// The largest jerk of a streamed path, units/s³ (default: not
    /// bounded): a set-point stream refuses a point whose change of
    /// acceleration from the previous segment exceeds it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_jerk: Option<f64>,
    /// How a lapsed lease or dead-man timeout stops the axis.
    pub stop_on_loss: StopChoice,
    /// Jog dead-man time in ms.
    pub jog_deadman_ms: u32,
    /// Bound of each state change (and of a CiA 402 set-point acknowledge
    /// and mode switch), in ms.
    pub state_timeout_ms: u64,
    /// Bound of a homing run in ms.
    pub homing_timeout_ms: u64,
    /// In-position window, user units (default: 10 counts).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub in_position_window: Option<f64>,
    /// Decimals HMIs show positions with, 0..=6 (default: one count
    /// visible, at most 4).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub display_decimals: Option<u8>,
}

/// The keys of [`CommonAxisConfig`].
const COMMON_AXIS_KEYS: &[&str] = &[
    "unit",
    "counts_per_unit",
    "min_position",
    "max_position",
    "max_velocity",
    "max_acceleration",
    "default_velocity",
    "default_acceleration",
    "stop_deceleration",
    "quick_stop_deceleration",
    "max_jerk",
    "stop_on_loss",
    "jog_deadman_ms",
    "state_timeout_ms",
    "homing_timeout_ms",
    "in_position_window",
    "display_decimals",
];

impl<'de> Deserialize<'de> for CommonAxisConfig {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        // As a struct: a flattening parent then hands over these keys only
        // and still refuses the ones nobody takes.
        d.deserialize_struct("CommonAxisConfig", COMMON_AXIS_KEYS, CommonAxisVisitor)
    }
}

struct CommonAxisVisitor;

impl<'de> serde::de::Visitor<'de> for CommonAxisVisitor {
    type Value = CommonAxisConfig;

    fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("the keys of an axis")
    }

    fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<Self::Value, A::Error> {
        use serde::de::Error;
        fn value<'de, T: Deserialize<'de>, A: serde::de::MapAccess<'de>>(
            map: &mut A,
            key: &str,
        ) -> Result<T, A::Error> {
            map.next_value()
                .map_err(|e| A::Error::custom(format_args!("{key}: {e}")))
        }
        let mut c = CommonAxisConfig {
            unit: default_unit(),
            counts_per_unit: 0.0,
            min_position: None,
            max_position: None,
            max_velocity: 0.0,
            max_acceleration: 0.0,
            default_velocity: None,
            default_acceleration: None,
            stop_deceleration: None,
            quick_stop_deceleration: None,
            max_jerk: None,
            stop_on_loss: StopChoice::default(),
            jog_deadman_ms: default_jog_deadman_ms(),
            state_timeout_ms: default_state_timeout_ms(),
            homing_timeout_ms: default_homing_timeout_ms(),
            in_position_window: None,
            display_decimals: None,
        };
        let mut required = [false; 3];
        while let Some(key) = map.next_key::<String>()? {
            let k = key.as_str();
            match k {
                "unit" => c.unit = value(&mut map, k)?,
                "counts_per_unit" => (c.counts_per_unit, required[0]) = (value(&mut map, k)?, true),
                "min_position" => c.min_position = value(&mut map, k)?,
                "max_position" => c.max_position = value(&mut map, k)?,
                "max_velocity" => (c.max_velocity, required[1]) = (value(&mut map, k)?, true),
                "max_acceleration" => {
                    (c.max_acceleration, required[2]) = (value(&mut map, k)?, true)
                }
                "default_velocity" => c.default_velocity = value(&mut map, k)?,
                "default_acceleration" => c.default_acceleration = value(&mut map, k)?,
                "stop_deceleration" => c.stop_deceleration = value(&mut map, k)?,
                "quick_stop_deceleration" => c.quick_stop_deceleration = value(&mut map, k)?,
                "max_jerk" => c.max_jerk = value(&mut map, k)?,
                "stop_on_loss" => c.stop_on_loss = value(&mut map, k)?,
                "jog_deadman_ms" => c.jog_deadman_ms = value(&mut map, k)?,
                "state_timeout_ms" => c.state_timeout_ms = value(&mut map, k)?,
                "homing_timeout_ms" => c.homing_timeout_ms = value(&mut map, k)?,
                "in_position_window" => c.in_position_window = value(&mut map, k)?,
                "display_decimals" => c.display_decimals = value(&mut map, k)?,
                _ => return Err(A::Error::unknown_field(k, COMMON_AXIS_KEYS)),
            }
        }
        for (given, key) in
            required
                .into_iter()
                .zip(["counts_per_unit", "max_velocity", "max_acceleration"])
        {
            if !given {
                return Err(A::Error::missing_field(key));
            }
        }
        Ok(c)
    }
}

/// How long a move or stop may take beyond its plan before it times out.
const SETTLE_TIMEOUT: Duration = Duration::from_secs(2);

impl CommonAxisConfig {
    /// The runtime's description of these keys, defaults applied.
    pub fn motion(&self) -> MotionSpec {
        MotionSpec {
            units: Units {
                counts_per_unit: self.counts_per_unit,
            },
            unit: self.unit.clone(),
            min_position: self.min_position,
            max_position: self.max_position,
            max_velocity: self.max_velocity,
            max_acceleration: self.max_acceleration,
            default_velocity: self.default_velocity.unwrap_or(self.max_velocity / 4.0),
            default_acceleration: self
                .default_acceleration
                .unwrap_or(self.max_acceleration / 4.0),
            stop_deceleration: self.stop_deceleration.unwrap_or(self.max_acceleration),
            quick_stop_deceleration: self
                .quick_stop_deceleration
                .unwrap_or(self.max_acceleration),
            max_jerk: self.max_jerk,
            state_timeout: Duration::from_millis(self.state_timeout_ms),
            homing_timeout: Duration::from_millis(self.homing_timeout_ms),
            settle_timeout: SETTLE_TIMEOUT,
            jog_deadman: Duration::from_millis(u64::from(self.jog_deadman_ms)),
            in_position_window: self
                .in_position_window
                .unwrap_or(10.0 / self.counts_per_unit.abs()),
            display_decimals: self
                .display_decimals
                .unwrap_or_else(|| cangate_axis::display_decimals_for(self.counts_per_unit)),
        }
    }

    /// Checks what serde cannot, for axis `name` of either drive family.
    pub(super) fn validate(&self, name: &str) -> Result<(), String> {
        let positive = |what: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!("axis {name}: {what} must be positive, got {v}"))
            }
        };
        if !self.counts_per_unit.is_finite() || self.counts_per_unit == 0.0 {
            return Err(format!(
                "axis {name}: counts_per_unit must be a non-zero number"
            ));
        }
        positive("max_velocity", self.max_velocity)?;
        positive("max_acceleration", self.max_acceleration)?;
        if let Some(v) = self.default_velocity {
            positive("default_velocity", v)?;
            if v > self.max_velocity {
                return Err(format!(
                    "axis {name}: default_velocity {v} exceeds max_velocity {}",
                    self.max_velocity
                ));
            }
        }
        if let Some(a) = self.default_acceleration {
            positive("default_acceleration", a)?;
            if a > self.max_acceleration {
                return Err(format!(
                    "axis {name}: default_acceleration {a} exceeds max_acceleration {}",
                    self.max_acceleration
                ));
            }
        }
        if let Some(w) = self.in_position_window {
            positive("in_position_window", w)?;
        }
        if let Some(d) = self.display_decimals
            && d > 6
        {
            return Err(format!(
                "axis {name}: display_decimals {d} is more than 6 (a µm of a metre)"
            ));
        }
        if let Some(j) = self.max_jerk
            && !(j.is_finite() && j > 0.0)
        {
            return Err(format!("axis {name}: max_jerk must be positive, got {j}"));
        }
        stop_decelerations(
            name,
            self.counts_per_unit,
            [
                ("stop_deceleration", self.stop_deceleration),
                ("quick_stop_deceleration", self.quick_stop_deceleration),
            ],
        )?;
        match (self.min_position, self.max_position) {
            (Some(a), Some(b)) if !(a.is_finite() && b.is_finite() && a < b) => Err(format!(
                "axis {name}: min_position {a} must be below max_position {b}"
            )),
            (Some(_), None) | (None, Some(_)) => Err(format!(
                "axis {name}: give both min_position and max_position, or neither"
            )),
            _ => Ok(()),
        }?;
        if self.jog_deadman_ms == 0 || self.state_timeout_ms == 0 || self.homing_timeout_ms == 0 {
            return Err(format!(
                "axis {name}: jog_deadman_ms, state_timeout_ms and homing_timeout_ms must be positive"
            ));
        }
        motion_bounds(
            name,
            self.counts_per_unit,
            self.max_velocity,
            self.max_acceleration,
            [
                ("jog_deadman_ms", u64::from(self.jog_deadman_ms)),
                ("state_timeout_ms", self.state_timeout_ms),
                ("homing_timeout_ms", self.homing_timeout_ms),
            ],
        )
    }
}

impl StopChoice {
    /// The runtime's stop kind.
    pub fn kind(self) -> StopKind {
        match self {
            StopChoice::Halt => StopKind::Halt,
            StopChoice::QuickStop => StopKind::QuickStop,
        }
    }
}

impl PositionModeChoice {
    /// The runtime's position mode.
    pub fn mode(self) -> PositionMode {
        match self {
            PositionModeChoice::Profile => PositionMode::Profile,
            PositionModeChoice::Cyclic => PositionMode::Cyclic,
        }
    }
}

/// One axis: a CiA 402 drive (a configured CANopen node) in user units.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisConfig {
    /// Unique name, e.g. "X".
    pub name: String,
    /// The bus (with a `[[canopen]]` master).
    pub bus: String,
    /// The drive's node id (configured under that master).
    pub node: u32,
    /// Which axis of a multi-axis drive node this is, 0..=7 (default 0):
    /// its CiA 402 objects are at index + 0x800 × `drive_axis` (0x6840
    /// is the controlword of axis 1). Every axis of one node has its own.
    #[serde(default)]
    pub drive_axis: u8,
    /// Units, limits, stops, time bounds.
    #[serde(flatten)]
    pub common: CommonAxisConfig,
    /// `profile` (default) or `cyclic`.
    #[serde(default)]
    pub position_mode: PositionModeChoice,
    /// The CiA 402 mode the axis starts in: `profile_position`, `csp`,
    /// `ip`, `csv`, `cst` or `profile_torque`; by default the one of
    /// `position_mode` (profile: `profile_position`, cyclic: `csp`).
    #[serde(default)]
    pub mode: Option<ModeChoice>,
    /// Max torque in per mille of the drive's rated torque: written to
    /// 0x6072 at boot (the drive's own limit), and the largest torque a
    /// torque command may ask for; absent: the drive keeps its own 0x6072
    /// and commands are bounded by 1000.
    #[serde(default)]
    pub max_torque: Option<f64>,
    /// Profile torque's ramp (0x6087, written at boot for a torque axis),
    /// per mille per second (default 10000).
    #[serde(default)]
    pub torque_slope: Option<f64>,
    /// Homing method written to 0x6098 at boot (CiA 402; e.g. 35 = current
    /// position is home, 17..=30 = move to a switch).
    #[serde(default = "default_homing_method")]
    pub homing_method: i8,
    /// `pdo` (default) or `sdo`: the fallback for drives without usable
    /// PDOs (profile position axes only).
    #[serde(default)]
    pub process_data: ProcessDataChoice,
    /// With `process_data = "sdo"`: how often the statusword, position,
    /// velocity and mode display are read, in ms (four SDO uploads each
    /// time).
    #[serde(default = "default_sdo_poll_ms")]
    pub sdo_poll_ms: u32,
    /// Following error window in user units, written to 0x6065 at boot
    /// (in counts); absent: the drive's own.
    #[serde(default)]
    pub following_error_window: Option<f64>,
    /// Following error time out in ms, written to 0x6066 at boot; absent:
    /// the drive's own.
    #[serde(default)]
    pub following_error_timeout_ms: Option<u16>,
    /// Map the drive's signals (torque, following error, digital inputs,
    /// touch probe) into TPDO2..4 where its EDS has them. Off by default:
    /// up to two more frames per SYNC from each drive, bus time a fast
    /// SYNC with several drives may not have, so the integrator turns it
    /// on where the bus has room.
    #[serde(default)]
    pub signal_pdos: bool,
}

/// The upper bounds of an axis's motion settings, for both drive
/// families: `times` are (`jog_deadman_ms`, `state_timeout_ms`,
/// `homing_timeout_ms`) with their names.
///
/// A dead-man that waits longer than [`MAX_JOG_DEADMAN_MS`] no longer
/// stops a jog whose client went away, and the timeouts bound every
/// command's wait. A drive takes velocities and accelerations as
/// UNSIGNED32 counts per second (CiA 402 0x6081, 0x6083, 0x6084): a
/// maximum beyond that cannot be carried out, and would let any command
/// through unchecked.
fn motion_bounds(
    axis: &str,
    counts_per_unit: f64,
    max_velocity: f64,
    max_acceleration: f64,
    times: [(&str, u64); 3],
) -> Result<(), String> {
    for ((what, value), max) in times.into_iter().zip([
        MAX_JOG_DEADMAN_MS,
        MAX_STATE_TIMEOUT_MS,
        MAX_HOMING_TIMEOUT_MS,
    ]) {
        if value > max {
            return Err(format!(
                "axis {axis}: {what} = {value} is above the maximum of {max} ms"
            ));
        }
    }
    let counts = counts_per_unit.abs();
    for (what, value, per) in [
        ("max_velocity", max_velocity, "s"),
        ("max_acceleration", max_acceleration, "s²"),
    ] {
        if value * counts > f64::from(u32::MAX) {
            return Err(format!(
                "axis {axis}: {what} = {value:e} is {:.3e} counts/{per} at counts_per_unit = \
                 {counts_per_unit}, more than a drive takes (4294967295 counts/{per})",
                value * counts
            ));
        }
    }
    Ok(())
}

/// The stop decelerations of an axis, for both drive families: positive,
/// and within what a drive takes as UNSIGNED32 counts/s² (0x6084).
fn stop_decelerations(
    axis: &str,
    counts_per_unit: f64,
    values: [(&str, Option<f64>); 2],
) -> Result<(), String> {
    for (what, value) in values {
        let Some(value) = value else { continue };
        if !(value.is_finite() && value > 0.0) {
            return Err(format!("axis {axis}: {what} must be positive, got {value}"));
        }
        if value * counts_per_unit.abs() > f64::from(u32::MAX) {
            return Err(format!(
                "axis {axis}: {what} = {value:e} is more than a drive takes (4294967295 \
                 counts/s² at counts_per_unit = {counts_per_unit})"
            ));
        }
    }
    Ok(())
}

/// Longest jog dead-man time accepted, ms.
pub const MAX_JOG_DEADMAN_MS: u64 = 10_000;
/// Longest CiA 402 state timeout accepted, ms.
pub const MAX_STATE_TIMEOUT_MS: u64 = 60_000;
/// Longest homing timeout accepted, ms (one hour).
pub const MAX_HOMING_TIMEOUT_MS: u64 = 3_600_000;

fn default_sdo_poll_ms() -> u32 {
    10
}

fn default_unit() -> String {
    "mm".into()
}
fn default_homing_method() -> i8 {
    35
}
fn default_jog_deadman_ms() -> u32 {
    500
}
fn default_state_timeout_ms() -> u64 {
    1000
}
fn default_homing_timeout_ms() -> u64 {
    30_000
}

impl TryFrom<&AxisConfig> for AxisSpec {
    type Error = String;

    /// The runtime's description of a `[[axis]]`.
    fn try_from(c: &AxisConfig) -> Result<AxisSpec, String> {
        let node = NodeId::new(c.node).map_err(|e| format!("axis {}: {e}", c.name))?;
        Ok(AxisSpec {
            name: c.name.clone(),
            motion: c.common.motion(),
            stop_on_loss: c.common.stop_on_loss.kind(),
            drive: DriveSpec::Cia402(Cia402Drive {
                bus: c.bus.clone(),
                node,
                mode: c.drive_mode(),
                torque: c.torque(),
                process_data: match c.process_data {
                    ProcessDataChoice::Pdo => ProcessDataPath::Pdo,
                    ProcessDataChoice::Sdo => ProcessDataPath::Sdo {
                        poll: Duration::from_millis(u64::from(c.sdo_poll_ms)),
                    },
                },
                homing_method: c.homing_method,
                supervision: cangate_axis::signals::Supervision {
                    following_error_window: c.following_error_window,
                    following_error_timeout: c
                        .following_error_timeout_ms
                        .map(|ms| Duration::from_millis(u64::from(ms))),
                    // Checked to be within 0x6072's range.
                    max_torque: c.max_torque.map(|t| t.round() as u16),
                },
                signal_pdos: c.signal_pdos,
                drive_axis: c.drive_axis,
            }),
        })
    }
}

impl AxisConfig {
    /// The mode the axis starts in: `mode`, else `position_mode`'s.
    pub fn drive_mode(&self) -> DriveMode {
        self.mode.map_or_else(
            || DriveMode::of_position_mode(self.position_mode.mode()),
            ModeChoice::mode,
        )
    }

    /// The torque bounds; the target torque is in the process data of an
    /// axis configured in a torque mode.
    pub fn torque(&self) -> TorqueSpec {
        let d = TorqueSpec::default();
        TorqueSpec {
            max_torque: self.max_torque.unwrap_or(d.max_torque),
            torque_slope: self.torque_slope.unwrap_or(d.torque_slope),
            in_process_data: self.drive_mode().is_torque()
                && self.process_data == ProcessDataChoice::Pdo,
        }
    }

    /// Whether the axis runs on the SYNC: configured cyclic, or in a mode
    /// that takes a set-point every SYNC.
    pub fn is_cyclic(&self) -> bool {
        self.drive_mode().position_mode() == PositionMode::Cyclic
    }

    fn validate_mode(&self) -> Result<(), String> {
        let name = &self.name;
        if let Some(m) = self.mode {
            let m = m.mode();
            let from_position = DriveMode::of_position_mode(self.position_mode.mode());
            if self.position_mode != PositionModeChoice::default()
                && m.position_mode() != self.position_mode.mode()
            {
                return Err(format!(
                    "axis {name}: mode = \"{m}\" contradicts position_mode = \"{}\" (leave \
                     position_mode out: mode says it; {from_position} is position_mode's mode)",
                    match self.position_mode {
                        PositionModeChoice::Profile => "profile",
                        PositionModeChoice::Cyclic => "cyclic",
                    }
                ));
            }
        }
        for (what, value, max) in [
            ("max_torque", self.max_torque, 32_767.0),
            ("torque_slope", self.torque_slope, f64::from(u32::MAX)),
        ] {
            if let Some(v) = value
                && !(v.is_finite() && v > 0.0 && v <= max)
            {
                return Err(format!(
                    "axis {name}: {what} must be positive and at most {max} (per mille), got {v}"
                ));
            }
        }
        if self.process_data == ProcessDataChoice::Sdo
            && self.mode.is_some()
            && self.drive_mode() != DriveMode::ProfilePosition
        {
            return Err(format!(
                "axis {name}: process_data = \"sdo\" needs mode = \"profile_position\": the \
                 other modes take set-points in the process data",
            ));
        }
        Ok(())
    }

    pub(super) fn validate(&self, cfg: &Config) -> Result<(), String> {
        if self.name.is_empty() || self.name.contains(char::is_whitespace) {
            return Err(format!(
                "axis name {:?} must be non-empty without spaces",
                self.name
            ));
        }
        let Some(master) = cfg.canopen.iter().find(|c| c.bus == self.bus) else {
            return Err(format!(
                "axis {}: bus {:?} has no [[canopen]] master",
                self.name, self.bus
            ));
        };
        if !master.nodes.iter().any(|n| n.id == self.node) {
            return Err(format!(
                "axis {}: node {} is not configured under [[canopen]] bus {:?}",
                self.name, self.node, self.bus
            ));
        }
        if self.drive_axis >= cangate_canopen::cia402::MAX_DRIVE_AXES {
            return Err(format!(
                "axis {}: drive_axis {} is more than a drive node has (0..=7: CiA 402 puts \
                 axis n's objects at index + n × 0x800, up to 0x9FFF)",
                self.name, self.drive_axis
            ));
        }
        if self.drive_axis > 0
            && let Some(node) = master.nodes.iter().find(|n| n.id == self.node)
            && let Ok(Some((eds, _))) = node.load_eds()
        {
            let statusword = cangate_canopen::cia402::profile_index(0x6041, self.drive_axis);
            if eds
                .od
                .get(cangate_canopen::ObjectAddress::new(statusword, 0))
                .is_none()
            {
                return Err(format!(
                    "axis {}: drive_axis = {} but node {}'s EDS has no such axis (no \
                     statusword 0x{statusword:04X})",
                    self.name, self.drive_axis, self.node
                ));
            }
        }
        if self.position_mode == PositionModeChoice::Cyclic && master.sync_period_us == 0 {
            return Err(format!(
                "axis {}: position_mode = \"cyclic\" needs a SYNC: set sync_period_us on \
                 [[canopen]] bus {:?}",
                self.name, self.bus
            ));
        }
        if self.is_cyclic() && master.sync_period_us == 0 {
            return Err(format!(
                "axis {}: mode = \"{}\" needs a SYNC: set sync_period_us on [[canopen]] bus {:?}",
                self.name,
                self.drive_mode(),
                self.bus
            ));
        }
        self.validate_mode()?;
        self.common.validate(&self.name)?;
        if self.process_data == ProcessDataChoice::Sdo {
            if self.position_mode == PositionModeChoice::Cyclic {
                return Err(format!(
                    "axis {}: process_data = \"sdo\" needs position_mode = \"profile\": a \
                     cyclic set-point every SYNC cannot go by SDO",
                    self.name
                ));
            }
            if !(1..=10_000).contains(&self.sdo_poll_ms) {
                return Err(format!(
                    "axis {}: sdo_poll_ms must be 1..=10000, got {}",
                    self.name, self.sdo_poll_ms
                ));
            }
        }
        if let Some(w) = self.following_error_window {
            let counts = w * self.common.counts_per_unit.abs();
            // 0xFFFFFFFF switches the drive's supervision off (CiA 402).
            if !(w.is_finite() && w > 0.0) || counts >= f64::from(u32::MAX) {
                return Err(format!(
                    "axis {}: following_error_window must be positive and below 4294967295 \
                     counts, got {w}",
                    self.name
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::super::Config;

    const BASE: &str = "listen = \"127.0.0.1:0\"\n[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\n\
                        [[canopen]]\nbus = \"can0\"\n[[canopen.node]]\nid = 1\neds = \"builtin:drive\"\n\
                        [[axis]]\nname = \"X\"\nbus = \"can0\"\nnode = 1\ncounts_per_unit = 1000.0\n\
                        max_velocity = 10.0\nmax_acceleration = 100.0\n";

    #[test]
    fn stop_decelerations_default_to_the_maximum_and_must_be_positive() {
        let c = Config::from_toml(BASE).unwrap();
        let ctl = c.axes[0].common.motion();
        assert_eq!(ctl.stop_deceleration, 100.0);
        assert_eq!(ctl.quick_stop_deceleration, 100.0);
        let c = Config::from_toml(&format!(
            "{BASE}stop_deceleration = 250.0\nquick_stop_deceleration = 400.0\n"
        ))
        .unwrap();
        let ctl = c.axes[0].common.motion();
        assert_eq!(ctl.stop_deceleration, 250.0);
        assert_eq!(ctl.quick_stop_deceleration, 400.0);
        for bad in [
            "stop_deceleration = 0.0",
            "quick_stop_deceleration = -1.0",
            "stop_deceleration = 1e308",
        ] {
            let e = Config::from_toml(&format!("{BASE}{bad}\n"))
                .unwrap_err()
                .to_string();
            let key = bad.split(' ').next().unwrap();
            assert!(e.contains(&format!("axis X: {key}")), "{bad}: {e}");
        }
    }

    #[test]
    fn max_jerk_is_optional_and_must_be_positive() {
        let c = Config::from_toml(BASE).unwrap();
        assert_eq!(c.axes[0].common.motion().max_jerk, None);
        let c = Config::from_toml(&format!("{BASE}max_jerk = 50000.0\n")).unwrap();
        assert_eq!(c.axes[0].common.motion().max_jerk, Some(50_000.0));
        let e = Config::from_toml(&format!("{BASE}max_jerk = 0.0\n"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("axis X: max_jerk must be positive"), "{e}");
    }

    #[test]
    fn the_mode_is_named_validated_and_needs_what_it_uses() {
        let c = Config::from_toml(BASE).unwrap();
        assert_eq!(
            c.axes[0].drive_mode(),
            cangate_axis::DriveMode::ProfilePosition
        );
        let c = Config::from_toml(&format!("{BASE}mode = \"cst\"\nmax_torque = 300.0\n")).unwrap();
        let torque = c.axes[0].torque();
        assert_eq!(
            c.axes[0].drive_mode(),
            cangate_axis::DriveMode::CyclicTorque
        );
        assert_eq!((torque.max_torque, torque.in_process_data), (300.0, true));
        let err = |extra: &str| {
            Config::from_toml(&format!("{BASE}{extra}"))
                .unwrap_err()
                .to_string()
        };
        // The cyclic modes take a set-point every SYNC.
        let e = err("mode = \"csv\"\n");
        assert!(e.contains("mode = \"csv\" needs a SYNC"), "{e}");
        let e = err("mode = \"servo\"\n");
        assert!(e.contains("servo"), "{e}");
        let synced = BASE.replace(
            "bus = \"can0\"\n[[canopen.node]]",
            "bus = \"can0\"\nsync_period_us = 1000\n[[canopen.node]]",
        );
        Config::from_toml(&format!("{synced}mode = \"csv\"\n")).unwrap();
        let e = Config::from_toml(&format!(
            "{synced}position_mode = \"cyclic\"\nmode = \"profile_position\"\n"
        ))
        .unwrap_err()
        .to_string();
        assert!(e.contains("contradicts"), "{e}");
        let e = err("mode = \"cst\"\nmax_torque = 0.0\n");
        assert!(e.contains("axis X: max_torque must be positive"), "{e}");
        let e = err("mode = \"profile_torque\"\nprocess_data = \"sdo\"\n");
        assert!(e.contains("needs mode = \"profile_position\""), "{e}");
    }

    #[test]
    fn display_decimals_show_one_count_unless_configured() {
        let c = Config::from_toml(BASE).unwrap();
        let counts = c.axes[0].common.counts_per_unit;
        assert_eq!(
            c.axes[0].common.motion().display_decimals,
            cangate_axis::display_decimals_for(counts)
        );
        let c = Config::from_toml(&format!("{BASE}display_decimals = 1\n")).unwrap();
        assert_eq!(c.axes[0].common.motion().display_decimals, 1);
        let e = Config::from_toml(&format!("{BASE}display_decimals = 7\n"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("axis X: display_decimals 7 is more than 6"),
            "{e}"
        );
        for (counts, want) in [
            (1000.0, 3),
            (-200.0, 3),
            (10.0, 1),
            (1.0, 0),
            (1e7, 4),
            (0.5, 0),
        ] {
            assert_eq!(cangate_axis::display_decimals_for(counts), want, "{counts}");
        }
    }

    const BOTH: &str = "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\n\
                        [[bus]]\nname = \"smc0\"\nbackend = \"virtual\"\n\
                        [[bus]]\nname = \"smc1\"\nbackend = \"virtual\"\n\
                        [[canopen]]\nbus = \"can0\"\nsync_period_us = 2000\n\
                        [[canopen.node]]\nid = 3\neds = \"builtin:drive\"\n\
                        [[axis]]\nname = \"X\"\nbus = \"can0\"\nnode = 3\nunit = \"deg\"\n\
                        counts_per_unit = -200.0\nposition_mode = \"cyclic\"\n\
                        min_position = -90.0\nmax_position = 90.0\nmax_velocity = 40.0\n\
                        max_acceleration = 400.0\ndefault_velocity = 20.0\n\
                        quick_stop_deceleration = 800.0\nstop_on_loss = \"quick_stop\"\n\
                        jog_deadman_ms = 250\nstate_timeout_ms = 700\nhoming_timeout_ms = 9000\n\
                        homing_method = 17\n\
                        [[cansmc]]\nname = \"m\"\ncommand_bus = \"smc0\"\nstatus_bus = \"smc1\"\n\
                        cycle_time_us = 4000\n\
                        [[cansmc.slave]]\naddress = 1\n[[cansmc.slave]]\naddress = 2\n\
                        [[cansmc.axis]]\nname = \"A\"\naddress = 2\ncounts_per_unit = 1000\n\
                        max_velocity = 10.0\nmax_acceleration = 100.0\nin_position_window = 0.5\n\
                        stop_deceleration = 150.0\ngear_source = 1\ngear_ratio = -2.0\n\
                        jog_mode = \"velocity\"\ncounts_per_rev = 4096\nhoming_method = 3\n";

    #[test]
    fn both_axis_kinds_become_their_axis_spec() {
        use cangate_axis::*;
        use std::time::Duration;
        let specs = Config::from_toml(BOTH).unwrap().axis_specs().unwrap();
        let x = AxisSpec {
            name: "X".into(),
            motion: MotionSpec {
                units: Units {
                    counts_per_unit: -200.0,
                },
                unit: "deg".into(),
                min_position: Some(-90.0),
                max_position: Some(90.0),
                max_velocity: 40.0,
                max_acceleration: 400.0,
                default_velocity: 20.0,
                default_acceleration: 100.0,
                stop_deceleration: 400.0,
                quick_stop_deceleration: 800.0,
                max_jerk: None,
                state_timeout: Duration::from_millis(700),
                homing_timeout: Duration::from_millis(9000),
                settle_timeout: Duration::from_secs(2),
                jog_deadman: Duration::from_millis(250),
                in_position_window: 0.05,
                display_decimals: 3,
            },
            stop_on_loss: StopKind::QuickStop,
            drive: DriveSpec::Cia402(Cia402Drive {
                bus: "can0".into(),
                node: cangate_canopen::NodeId::new(3).unwrap(),
                mode: cangate_axis::DriveMode::CyclicPosition,
                torque: cangate_axis::TorqueSpec::default(),
                process_data: ProcessDataPath::Pdo,
                homing_method: 17,
                supervision: Default::default(),
                signal_pdos: false,
                drive_axis: 0,
            }),
        };
        let a = AxisSpec {
            name: "A".into(),
            motion: MotionSpec {
                units: Units {
                    counts_per_unit: 1000.0,
                },
                unit: "mm".into(),
                min_position: None,
                max_position: None,
                max_velocity: 10.0,
                max_acceleration: 100.0,
                default_velocity: 2.5,
                default_acceleration: 25.0,
                stop_deceleration: 150.0,
                quick_stop_deceleration: 100.0,
                max_jerk: None,
                state_timeout: Duration::from_millis(1000),
                homing_timeout: Duration::from_millis(30_000),
                settle_timeout: Duration::from_secs(2),
                jog_deadman: Duration::from_millis(500),
                in_position_window: 0.5,
                display_decimals: 3,
            },
            stop_on_loss: StopKind::Halt,
            drive: DriveSpec::Cansmc(CansmcDrive {
                master: "m".into(),
                command_bus: "smc0".into(),
                address: cangate_cansmc::SmcAddress::new(2).unwrap(),
                cycle_time: Duration::from_micros(4000),
                homing_method: 3,
                gear: Some(Gear {
                    source: 1,
                    ratio: -2.0,
                }),
                jog_mode: JogMode::SlaveVelocity,
                counts_per_rev: 4096,
            }),
        };
        assert_eq!(specs, [x, a]);
        assert_eq!(specs[0].bus(), "can0");
        assert_eq!((specs[1].bus(), specs[1].node()), ("smc0", 2));
        assert_eq!(specs[1].position_mode(), PositionMode::Cyclic);
        // The SDO fallback carries its poll period.
        let sdo = BASE.to_string() + "process_data = \"sdo\"\nsdo_poll_ms = 25\n";
        let spec = &Config::from_toml(&sdo).unwrap().axis_specs().unwrap()[0];
        let DriveSpec::Cia402(d) = &spec.drive else {
            panic!("{spec:?}")
        };
        assert_eq!(
            d.process_data,
            ProcessDataPath::Sdo {
                poll: Duration::from_millis(25)
            }
        );
    }

    #[test]
    fn unknown_keys_of_both_axis_kinds_are_refused_by_name() {
        Config::from_toml(BOTH).unwrap();
        for (after, key) in [
            // A typo of a shared key, in each kind of axis.
            ("homing_method = 17\n", "max_velocty = 1.0"),
            ("homing_method = 3\n", "max_velocty = 1.0"),
            // A key of the other drive family.
            ("homing_method = 17\n", "gear_ratio = 2.0"),
            ("homing_method = 3\n", "sdo_poll_ms = 20"),
            ("homing_method = 3\n", "position_mode = \"cyclic\""),
        ] {
            let text = BOTH.replace(after, &format!("{after}{key}\n"));
            assert_ne!(text, BOTH);
            let e = Config::from_toml(&text).unwrap_err().to_string();
            let name = key.split(' ').next().unwrap();
            assert!(e.contains(&format!("unknown field `{name}`")), "{key}: {e}");
        }
    }

    #[test]
    fn both_axis_kinds_check_their_shared_keys_alike() {
        for (axis, after) in [("X", "homing_method = 17\n"), ("A", "homing_method = 3\n")] {
            for (bad, want) in [
                (
                    "default_acceleration = 1e6",
                    "default_acceleration 1000000 exceeds max_acceleration",
                ),
                (
                    "jog_deadman_ms = 0",
                    "jog_deadman_ms, state_timeout_ms and homing_timeout_ms must be positive",
                ),
                (
                    "state_timeout_ms = 60001",
                    "state_timeout_ms = 60001 is above the maximum of 60000 ms",
                ),
                (
                    "stop_deceleration = -1.0",
                    "stop_deceleration must be positive",
                ),
                (
                    "in_position_window = 0.0",
                    "in_position_window must be positive",
                ),
            ] {
                // Without the keys the cases set.
                let text = BOTH
                    .replace("stop_deceleration = 150.0\n", "")
                    .replace("in_position_window = 0.5\n", "")
                    .replace("jog_deadman_ms = 250\nstate_timeout_ms = 700\n", "")
                    .replace(after, &format!("{after}{bad}\n"));
                let e = Config::from_toml(&text).unwrap_err().to_string();
                assert!(
                    e.contains(&format!("axis {axis}: {want}")),
                    "{axis} {bad}: {e}"
                );
            }
        }
    }

    #[test]
    fn a_shared_key_of_the_wrong_type_or_missing_is_named() {
        for (axis, key) in [
            ("X", "max_velocity = 40.0\n"),
            ("A", "max_velocity = 10.0\n"),
        ] {
            let text = BOTH.replace(key, "max_velocity = \"fast\"\n");
            let e = Config::from_toml(&text).unwrap_err().to_string();
            assert!(
                e.contains("max_velocity: invalid type: string \"fast\""),
                "{axis}: {e}"
            );
            let e = Config::from_toml(&BOTH.replace(key, ""))
                .unwrap_err()
                .to_string();
            assert!(e.contains("max_velocity"), "{axis}: {e}");
        }
    }
}
