//! `[[axis]]`: CiA 402 drives as axes: units, limits, modes, stops.

use super::Config;
use serde::{Deserialize, Serialize};

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
    /// User unit name, e.g. "mm" or "deg".
    #[serde(default = "default_unit")]
    pub unit: String,
    /// Drive counts per user unit (negative inverts the direction).
    pub counts_per_unit: f64,
    /// `profile` (default) or `cyclic`.
    #[serde(default)]
    pub position_mode: PositionModeChoice,
    /// Soft limits in user units (both or none); also written to the
    /// drive's 0x607D at boot.
    #[serde(default)]
    pub min_position: Option<f64>,
    /// Soft limits in user units.
    #[serde(default)]
    pub max_position: Option<f64>,
    /// Velocity ceiling, units/s.
    pub max_velocity: f64,
    /// Acceleration ceiling, units/s².
    pub max_acceleration: f64,
    /// Velocity of moves that give none (default: a quarter of the maximum).
    #[serde(default)]
    pub default_velocity: Option<f64>,
    /// Acceleration of moves that give none (default: a quarter of the
    /// maximum).
    #[serde(default)]
    pub default_acceleration: Option<f64>,
    /// Deceleration of every stop (Stop, StopAxes, the jog dead-man, a lost
    /// lease, shutdown), units/s²; a stop brakes harder when the
    /// interrupted motion's own deceleration is higher (default: the
    /// maximum acceleration).
    #[serde(default)]
    pub stop_deceleration: Option<f64>,
    /// Deceleration of a CiA 402 quick stop, units/s² (default: the maximum
    /// acceleration).
    #[serde(default)]
    pub quick_stop_deceleration: Option<f64>,
    /// Homing method written to 0x6098 at boot (CiA 402; e.g. 35 = current
    /// position is home, 17..=30 = move to a switch).
    #[serde(default = "default_homing_method")]
    pub homing_method: i8,
    /// How a lapsed lease or dead-man timeout stops the axis.
    #[serde(default)]
    pub stop_on_loss: StopChoice,
    /// Jog dead-man time in ms.
    #[serde(default = "default_jog_deadman_ms")]
    pub jog_deadman_ms: u32,
    /// Bound of each CiA 402 state change, set-point acknowledge and mode
    /// switch, in ms.
    #[serde(default = "default_state_timeout_ms")]
    pub state_timeout_ms: u64,
    /// Bound of a homing run in ms.
    #[serde(default = "default_homing_timeout_ms")]
    pub homing_timeout_ms: u64,
    /// In-position window of cyclic moves, user units (default: 10 counts).
    #[serde(default)]
    pub in_position_window: Option<f64>,
    /// `pdo` (default) or `sdo`: the fallback for drives without usable
    /// PDOs (profile position axes only).
    #[serde(default)]
    pub process_data: ProcessDataChoice,
    /// With `process_data = "sdo"`: how often the statusword, position,
    /// velocity and mode display are read, in ms (four SDO uploads each
    /// time).
    #[serde(default = "default_sdo_poll_ms")]
    pub sdo_poll_ms: u32,
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
pub fn motion_bounds(
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
pub fn stop_decelerations(
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

impl AxisConfig {
    /// The controller configuration.
    pub fn controller(&self) -> cangate_axis::cia402::Cia402Config {
        use cangate_axis::{PositionMode, Units};
        cangate_axis::cia402::Cia402Config {
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
            position_mode: match self.position_mode {
                PositionModeChoice::Profile => PositionMode::Profile,
                PositionModeChoice::Cyclic => PositionMode::Cyclic,
            },
            state_timeout: std::time::Duration::from_millis(self.state_timeout_ms),
            homing_timeout: std::time::Duration::from_millis(self.homing_timeout_ms),
            in_position_window: self
                .in_position_window
                .unwrap_or(10.0 / self.counts_per_unit.abs()),
            settle_timeout: std::time::Duration::from_secs(2),
            jog_deadman: std::time::Duration::from_millis(u64::from(self.jog_deadman_ms)),
            stop_deceleration: self.stop_deceleration.unwrap_or(self.max_acceleration),
            quick_stop_deceleration: self
                .quick_stop_deceleration
                .unwrap_or(self.max_acceleration),
        }
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
        if self.position_mode == PositionModeChoice::Cyclic && master.sync_period_us == 0 {
            return Err(format!(
                "axis {}: position_mode = \"cyclic\" needs a SYNC: set sync_period_us on \
                 [[canopen]] bus {:?}",
                self.name, self.bus
            ));
        }
        let positive = |what: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!(
                    "axis {}: {what} must be positive, got {v}",
                    self.name
                ))
            }
        };
        if !self.counts_per_unit.is_finite() || self.counts_per_unit == 0.0 {
            return Err(format!(
                "axis {}: counts_per_unit must be a non-zero number",
                self.name
            ));
        }
        positive("max_velocity", self.max_velocity)?;
        positive("max_acceleration", self.max_acceleration)?;
        if let Some(v) = self.default_velocity {
            positive("default_velocity", v)?;
            if v > self.max_velocity {
                return Err(format!(
                    "axis {}: default_velocity {v} exceeds max_velocity {}",
                    self.name, self.max_velocity
                ));
            }
        }
        if let Some(a) = self.default_acceleration {
            positive("default_acceleration", a)?;
            if a > self.max_acceleration {
                return Err(format!(
                    "axis {}: default_acceleration {a} exceeds max_acceleration {}",
                    self.name, self.max_acceleration
                ));
            }
        }
        if let Some(w) = self.in_position_window {
            positive("in_position_window", w)?;
        }
        stop_decelerations(
            &self.name,
            self.counts_per_unit,
            [
                ("stop_deceleration", self.stop_deceleration),
                ("quick_stop_deceleration", self.quick_stop_deceleration),
            ],
        )?;
        match (self.min_position, self.max_position) {
            (Some(a), Some(b)) if !(a.is_finite() && b.is_finite() && a < b) => Err(format!(
                "axis {}: min_position {a} must be below max_position {b}",
                self.name
            )),
            (Some(_), None) | (None, Some(_)) => Err(format!(
                "axis {}: give both min_position and max_position, or neither",
                self.name
            )),
            _ => Ok(()),
        }?;
        if self.jog_deadman_ms == 0 || self.state_timeout_ms == 0 || self.homing_timeout_ms == 0 {
            return Err(format!(
                "axis {}: jog_deadman_ms, state_timeout_ms and homing_timeout_ms must be positive",
                self.name
            ));
        }
        motion_bounds(
            &self.name,
            self.counts_per_unit,
            self.max_velocity,
            self.max_acceleration,
            [
                ("jog_deadman_ms", u64::from(self.jog_deadman_ms)),
                ("state_timeout_ms", self.state_timeout_ms),
                ("homing_timeout_ms", self.homing_timeout_ms),
            ],
        )?;
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
        let ctl = c.axes[0].controller();
        assert_eq!(ctl.stop_deceleration, 100.0);
        assert_eq!(ctl.quick_stop_deceleration, 100.0);
        let c = Config::from_toml(&format!(
            "{BASE}stop_deceleration = 250.0\nquick_stop_deceleration = 400.0\n"
        ))
        .unwrap();
        let ctl = c.axes[0].controller();
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
}
