//! `[[handwheel]]`: CNC handwheels, their feed layout and axis bindings.

use serde::{Deserialize, Serialize};
use std::collections::HashSet;

use super::Config;
use super::PositionModeChoice;

/// Where the feed counter sits in the handwheel's feed byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CounterChoice {
    /// Bits 4-7, step 1 (the spec's default).
    #[default]
    Nibble,
    /// Bits 6-7, step 4 (the paper's experiment).
    #[serde(rename = "bits6_7")]
    Bits67,
}

/// A CNC handwheel: a CANopen node sending one feed TPDO per unit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HandwheelConfig {
    /// Unique name, e.g. "hw1".
    pub name: String,
    /// The bus (with a `[[canopen]]` master).
    pub bus: String,
    /// The wheel's node id (configured under that master).
    pub node: u32,
    /// Counter layout of the feed byte.
    #[serde(default)]
    pub counter: CounterChoice,
    /// Even output: units executed per second at most.
    #[serde(default = "default_max_units_per_s")]
    pub max_units_per_s: f64,
    /// Even output: the backlog holds at most this much time at the
    /// maximum rate; when the wheel stops the axis stops within it. Units
    /// beyond are dropped and counted.
    #[serde(default = "default_stop_within_ms")]
    pub stop_within_ms: u32,
    /// Wheel axis selector position → gateway axis.
    #[serde(default)]
    pub bind: Vec<HandwheelBinding>,
}

/// One binding of a wheel axis to a gateway axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HandwheelBinding {
    /// The wheel's selector position: X, Y, Z, W or V.
    pub wheel_axis: String,
    /// A cyclic `[[axis]]` name.
    pub axis: String,
    /// Distance per feed unit, in the axis's user unit.
    pub distance_per_unit: f64,
}

fn default_max_units_per_s() -> f64 {
    1000.0
}
fn default_stop_within_ms() -> u32 {
    200
}

impl HandwheelBinding {
    /// The wheel axis.
    pub fn wheel_axis(&self) -> Result<cangate_canopen::handwheel::HandwheelAxis, String> {
        use cangate_canopen::handwheel::HandwheelAxis as A;
        match self.wheel_axis.to_ascii_uppercase().as_str() {
            "X" => Ok(A::X),
            "Y" => Ok(A::Y),
            "Z" => Ok(A::Z),
            "W" => Ok(A::W),
            "V" => Ok(A::V),
            other => Err(format!("wheel_axis {other:?} is not one of X, Y, Z, W, V")),
        }
    }
}

impl HandwheelConfig {
    pub(super) fn validate(&self, cfg: &Config) -> Result<(), String> {
        let name = &self.name;
        if name.is_empty() || name.contains(char::is_whitespace) {
            return Err(format!(
                "handwheel name {name:?} must be non-empty without spaces"
            ));
        }
        let Some(master) = cfg.canopen.iter().find(|c| c.bus == self.bus) else {
            return Err(format!(
                "handwheel {name}: bus {:?} has no [[canopen]] master",
                self.bus
            ));
        };
        if !master.nodes.iter().any(|n| n.id == self.node) {
            return Err(format!(
                "handwheel {name}: node {} is not configured under [[canopen]] bus {:?}",
                self.node, self.bus
            ));
        }
        if !(self.max_units_per_s.is_finite() && self.max_units_per_s > 0.0)
            || self.stop_within_ms == 0
        {
            return Err(format!(
                "handwheel {name}: max_units_per_s and stop_within_ms must be positive"
            ));
        }
        let mut seen = HashSet::new();
        for b in &self.bind {
            let wa = b
                .wheel_axis()
                .map_err(|e| format!("handwheel {name}: {e}"))?;
            if !seen.insert(wa) {
                return Err(format!(
                    "handwheel {name}: wheel axis {} is bound twice",
                    b.wheel_axis
                ));
            }
            let Some(axis) = cfg.axes.iter().find(|a| a.name == b.axis) else {
                return Err(format!(
                    "handwheel {name}: bound axis {:?} is not configured",
                    b.axis
                ));
            };
            if axis.position_mode != PositionModeChoice::Cyclic {
                return Err(format!(
                    "handwheel {name}: axis {} must be cyclic (position_mode = \"cyclic\"): \
                     the gateway paces handwheel motion every SYNC",
                    b.axis
                ));
            }
            if !(b.distance_per_unit.is_finite() && b.distance_per_unit > 0.0) {
                return Err(format!(
                    "handwheel {name}: distance_per_unit must be positive"
                ));
            }
        }
        Ok(())
    }
}
