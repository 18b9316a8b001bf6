//! Server configuration: a TOML file (or the embedded demo) plus
//! `CANGATE_…` environment overrides, validated before anything starts.
//!
//! Environment variables map onto keys with `__` between levels:
//! `CANGATE_LISTEN=0.0.0.0:50051`, `CANGATE_LOG__FORMAT=json`. The
//! variables the command-line client reads (`CANGATE_SERVER`,
//! `CANGATE_TOKEN`, `CANGATE_CA`, `CANGATE_CERT`, `CANGATE_KEY`) and
//! `CANGATE_CONFIG` are not configuration keys and are ignored here; any
//! other `CANGATE_` variable is ignored with a warning on stderr.

use serde::{Deserialize, Serialize};
use std::collections::{HashMap, HashSet};
use std::net::SocketAddr;

pub use crate::security::config::{
    ClientCertConfig, LimitsConfig, SecurityConfig, TlsConfig, TokenConfig,
};

/// The embedded demo configuration, used when no configuration file is given.
pub const DEMO_CONFIG: &str = include_str!("../../deploy/demo.toml");

/// Environment variables that override configuration keys (a trailing `__`
/// stands for every key below that table).
const ENV_KEYS: &[&str] = &[
    "CANGATE_LISTEN",
    "CANGATE_METRICS_LISTEN",
    "CANGATE_SHUTDOWN_TIMEOUT_MS",
    "CANGATE_RT_PRIORITY",
    "CANGATE_GRPC_RT_PRIORITY",
    "CANGATE_SECURITY__",
    "CANGATE_LOG__",
];

/// Environment variables with our prefix that belong to the client, not to
/// the server's configuration.
const CLIENT_VARIABLES: &[&str] = &[
    "CANGATE_SERVER",
    "CANGATE_TOKEN",
    "CANGATE_CA",
    "CANGATE_CERT",
    "CANGATE_KEY",
    "CANGATE_CONFIG",
];

/// The whole configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// gRPC listen address.
    #[serde(default = "default_listen")]
    pub listen: SocketAddr,
    /// Prometheus endpoint (`GET /metrics`), e.g. `127.0.0.1:9464`; none
    /// when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub metrics_listen: Option<SocketAddr>,
    /// Bound of the motion-safe shutdown on SIGTERM/SIGINT: moving axes get
    /// this long to come to rest before the rest of the gateway closes, ms
    /// (default 5000).
    #[serde(default = "default_shutdown_timeout_ms")]
    pub shutdown_timeout_ms: u64,
    /// `SCHED_FIFO` priority (1..=99) of the gateway's bus thread
    /// (`gateway-bus`: bus owners, CANopen masters, axis tasks) and of the
    /// CANopen SYNC producer threads, so that a frame is handled (and a
    /// SYNC sent) without waiting for other processes' time slices;
    /// 0 (default): the default policy. Its work per frame is bounded.
    /// Needs root or `CAP_SYS_NICE` (else a warning).
    #[serde(default, skip_serializing_if = "is_zero_u8")]
    pub rt_priority: u8,
    /// `SCHED_FIFO` priority (1..=99) of every thread of the gRPC runtime
    /// (streams, handwheel tasks); 0 (default): the default policy. Cuts
    /// the stream latency tail on a busy host, but a saturated gRPC
    /// runtime then starves every other process on its cores, local
    /// clients included: only for a host sized for the stream load.
    #[serde(default, skip_serializing_if = "is_zero_u8")]
    pub grpc_rt_priority: u8,
    /// Security settings.
    #[serde(default)]
    pub security: SecurityConfig,
    /// Logging.
    #[serde(default)]
    pub log: LogConfig,
    /// The CAN buses the gateway owns.
    #[serde(default, rename = "bus")]
    pub buses: Vec<BusConfig>,
    /// CANopen masters, one per bus at most.
    #[serde(default, rename = "canopen", skip_serializing_if = "Vec::is_empty")]
    pub canopen: Vec<CanopenConfig>,
    /// Axes (CiA 402 drives on CANopen buses).
    #[serde(default, rename = "axis", skip_serializing_if = "Vec::is_empty")]
    pub axes: Vec<AxisConfig>,
    /// CNC handwheels (CANopen nodes) and their axis bindings.
    #[serde(default, rename = "handwheel", skip_serializing_if = "Vec::is_empty")]
    pub handwheels: Vec<HandwheelConfig>,
    /// CANsmc masters (dual-bus motion control), their slaves and axes.
    #[serde(default, rename = "cansmc", skip_serializing_if = "Vec::is_empty")]
    pub cansmc: Vec<crate::cansmc::CansmcConfig>,
}

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
    fn validate(&self, cfg: &Config) -> Result<(), String> {
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
        }
    }

    fn validate(&self, cfg: &Config) -> Result<(), String> {
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

/// The CANopen master of one bus.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CanopenConfig {
    /// The bus (a `[[bus]]` name).
    pub bus: String,
    /// Default SDO timeout per answer, in ms.
    #[serde(default = "default_sdo_timeout_ms")]
    pub sdo_timeout_ms: u64,
    /// SYNC producer period in µs (0 = no SYNC). Drives of axes send their
    /// process data every SYNC; cyclic axes get a set-point every SYNC.
    #[serde(default)]
    pub sync_period_us: u64,
    /// Known nodes.
    #[serde(default, rename = "node")]
    pub nodes: Vec<NodeConfig>,
    // ---- the master's own heartbeat (see `master_heartbeat_check`) ----
    /// The gateway's node id as NMT master, for its own heartbeat
    /// (`0x700 + id`); no configured node may use it. Default 127, the
    /// highest id, where masters customarily sit, free in the demo.
    #[serde(default = "default_master_node_id")]
    pub master_node_id: u8,
    /// Period of the master's heartbeat in ms (default 100); 0: none, and
    /// drives are not told to watch it.
    #[serde(default = "default_master_heartbeat_ms")]
    pub master_heartbeat_ms: u16,
    /// Heartbeat consumer time the boot procedure writes into each axis
    /// drive's 0x1016:01 for the master's heartbeat, in ms (default 3 ×
    /// `master_heartbeat_ms`): a drive that hears no master heartbeat for
    /// this long faults (EMCY 0x8130) and stops with its quick stop ramp.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drive_heartbeat_timeout_ms: Option<u16>,
}

fn default_sdo_timeout_ms() -> u64 {
    500
}

fn default_master_node_id() -> u8 {
    127
}

fn default_master_heartbeat_ms() -> u16 {
    100
}

impl CanopenConfig {
    /// The master's heartbeat node and period, when it produces one.
    pub fn master_heartbeat(&self) -> Option<(u8, u16)> {
        (self.master_heartbeat_ms > 0).then_some((self.master_node_id, self.master_heartbeat_ms))
    }

    /// The consumer time written into axis drives' 0x1016, when the
    /// master produces a heartbeat.
    pub fn drive_heartbeat_timeout_ms(&self) -> Option<u16> {
        self.master_heartbeat()?;
        Some(
            self.drive_heartbeat_timeout_ms
                .unwrap_or(self.master_heartbeat_ms.saturating_mul(3)),
        )
    }

    fn master_heartbeat_check(&self) -> Result<(), String> {
        let at = |m: String| format!("[[canopen]] bus {:?}: {m}", self.bus);
        if !(1..=127).contains(&self.master_node_id) {
            return Err(at(format!(
                "master_node_id {} is out of range (1..=127)",
                self.master_node_id
            )));
        }
        if self.master_heartbeat_ms == 0 {
            return Ok(());
        }
        if let Some(n) = self
            .nodes
            .iter()
            .find(|n| n.id == u32::from(self.master_node_id))
        {
            return Err(at(format!(
                "node {} is the master's own node id (master_node_id, default 127); give the \
                 master another one",
                n.id
            )));
        }
        if let Some(t) = self.drive_heartbeat_timeout_ms
            && t <= self.master_heartbeat_ms
        {
            return Err(at(format!(
                "drive_heartbeat_timeout_ms = {t} must exceed master_heartbeat_ms = {} (2-3 \
                 periods are usual), or drives fault while the master is alive",
                self.master_heartbeat_ms
            )));
        }
        Ok(())
    }
}

/// A CANopen node the master knows in advance.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NodeConfig {
    /// Node id, 1..=127.
    pub id: u32,
    /// A name for people (e.g. "X axis drive").
    #[serde(default)]
    pub name: String,
    /// Object dictionary: an EDS/DCF file path, or one of the built-in
    /// device descriptions `builtin:drive`, `builtin:io`, `builtin:handwheel`.
    #[serde(default)]
    pub eds: Option<String>,
    /// Consumer heartbeat timeout in ms (0 = do not monitor).
    #[serde(default)]
    pub heartbeat_timeout_ms: u64,
    /// Virtual buses only: run a simulated device from the EDS at this id.
    #[serde(default)]
    pub simulate: bool,
    /// Run the boot procedure whenever the node boots: check the identity,
    /// write the configuration below, then NMT-start it.
    #[serde(default)]
    pub boot: bool,
    /// Boot check: expected device type (0x1000).
    #[serde(default)]
    pub device_type: Option<u32>,
    /// Boot check: expected vendor id (0x1018:01).
    #[serde(default)]
    pub vendor_id: Option<u32>,
    /// Boot check: expected product code (0x1018:02).
    #[serde(default)]
    pub product_code: Option<u32>,
    /// Boot: heartbeat producer time to write to 0x1017, in ms.
    #[serde(default)]
    pub heartbeat_producer_ms: Option<u16>,
    /// Boot: further SDO writes, in order.
    #[serde(default, rename = "write")]
    pub writes: Vec<SdoWriteConfig>,
    /// TPDOs to configure at boot (and to decode); without any, the EDS
    /// defaults are used for decoding.
    #[serde(default)]
    pub tpdo: Vec<PdoConfigEntry>,
    /// RPDOs to configure at boot (and to encode WritePdo); without any,
    /// the EDS defaults are used.
    #[serde(default)]
    pub rpdo: Vec<PdoConfigEntry>,
}

/// An SDO write of the boot procedure.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SdoWriteConfig {
    /// Object, `0x6060:0`.
    pub object: String,
    /// Type: bool i8 i16 i32 i64 u8 u16 u32 u64 f32 f64 vs os domain.
    #[serde(rename = "type")]
    pub ty: String,
    /// Value in text (decimal, 0x hex, string, hex bytes).
    pub value: String,
}

/// A PDO to configure.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PdoConfigEntry {
    /// PDO number, 1..=512.
    pub num: u16,
    /// COB-ID (default: the predefined connection set for PDOs 1..=4).
    #[serde(default)]
    pub cob_id: Option<u16>,
    /// 0 acyclic sync, 1..=240 every n-th SYNC, 254/255 event-driven.
    #[serde(default = "default_transmission_type")]
    pub transmission_type: u8,
    /// TPDO inhibit time in 100 µs units.
    #[serde(default)]
    pub inhibit_time: u16,
    /// Event timer in ms.
    #[serde(default)]
    pub event_timer_ms: u16,
    /// Mapped objects `INDEX:SUB:BITS` in hex:hex:decimal, e.g. `6041:0:16`.
    pub mapping: Vec<String>,
}

fn default_transmission_type() -> u8 {
    255
}

/// Parses `6041:0` / `0x6041:00` into an address.
pub fn parse_object(text: &str) -> Result<cangate_canopen::ObjectAddress, String> {
    let hex = |t: &str| {
        u32::from_str_radix(
            t.trim().trim_start_matches("0x").trim_start_matches("0X"),
            16,
        )
    };
    let (i, s) = text.split_once(':').unwrap_or((text, "0"));
    let index = hex(i).map_err(|_| format!("object {text:?}: index is not hex"))?;
    let sub = hex(s).map_err(|_| format!("object {text:?}: sub-index is not hex"))?;
    if index > 0xFFFF || sub > 0xFF {
        return Err(format!("object {text:?} is out of range"));
    }
    Ok(cangate_canopen::ObjectAddress::new(index as u16, sub as u8))
}

impl PdoConfigEntry {
    /// The PDO configuration for `node`.
    pub fn to_pdo(
        &self,
        kind: cangate_canopen::pdo::PdoKind,
        node: cangate_canopen::NodeId,
    ) -> Result<cangate_canopen::pdo::PdoConfig, String> {
        use cangate_canopen::pdo::{MappedObject, PdoConfig};
        let mapping = self
            .mapping
            .iter()
            .map(|m| {
                let (obj, bits) = m
                    .rsplit_once(':')
                    .filter(|(o, _)| o.contains(':'))
                    .ok_or_else(|| format!("mapping entry {m:?} is not INDEX:SUB:BITS"))?;
                let addr = parse_object(obj)?;
                let bits: u8 = bits
                    .parse()
                    .map_err(|_| format!("mapping entry {m:?}: bits must be a number"))?;
                Ok(MappedObject { addr, bits })
            })
            .collect::<Result<Vec<_>, String>>()?;
        let cob_id = match self.cob_id {
            Some(c) => c,
            None => kind
                .default_cob_id(self.num, node)
                .ok_or_else(|| format!("PDO {} has no default COB-ID; give cob_id", self.num))?,
        };
        let cfg = PdoConfig {
            kind,
            num: self.num,
            cob_id,
            transmission_type: self.transmission_type,
            inhibit_time: self.inhibit_time,
            event_timer_ms: self.event_timer_ms,
            mapping,
        };
        cfg.validate().map_err(|e| e.to_string())?;
        Ok(cfg)
    }
}

impl NodeConfig {
    /// Loads the configured EDS.
    pub fn load_eds(&self) -> Result<Option<cangate_canopen::eds::Eds>, String> {
        use cangate_canopen::eds::{Eds, SIM_DRIVE_EDS, SIM_HANDWHEEL_EDS, SIM_IO_EDS};
        let Some(src) = self.eds.as_deref() else {
            return Ok(None);
        };
        let parsed = match src {
            "builtin:drive" => Eds::parse(SIM_DRIVE_EDS),
            "builtin:io" => Eds::parse(SIM_IO_EDS),
            "builtin:handwheel" => Eds::parse(SIM_HANDWHEEL_EDS),
            path if path.starts_with("builtin:") => {
                return Err(format!(
                    "unknown built-in EDS {path:?} (builtin:drive, builtin:io, builtin:handwheel)"
                ));
            }
            path => Eds::from_path(path),
        };
        parsed.map(Some).map_err(|e| format!("EDS {src:?}: {e}"))
    }
}

fn is_zero_u8(v: &u8) -> bool {
    *v == 0
}

fn default_shutdown_timeout_ms() -> u64 {
    5000
}

fn default_listen() -> SocketAddr {
    SocketAddr::from(([127, 0, 0, 1], 50051))
}

/// Log output.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LogConfig {
    /// `human` or `json` (one JSON object per line).
    #[serde(default)]
    pub format: LogFormat,
    /// Filter in `tracing` EnvFilter syntax, e.g. `info,cangate_can=debug`.
    /// `RUST_LOG` overrides it.
    #[serde(default = "default_level")]
    pub level: String,
}

impl Default for LogConfig {
    fn default() -> Self {
        LogConfig {
            format: LogFormat::Human,
            level: default_level(),
        }
    }
}

fn default_level() -> String {
    "info".to_string()
}

/// Log format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LogFormat {
    /// Human-readable lines.
    #[default]
    Human,
    /// One JSON object per line.
    Json,
}

/// Which backend a bus uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BackendChoice {
    /// Linux SocketCAN interface.
    Socketcan,
    /// In-process virtual bus.
    Virtual,
}

/// Stuff-bit counting of the virtual bus's bit-timing model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StuffingChoice {
    /// Count the stuff bits each frame really needs.
    #[default]
    Exact,
    /// Assume the worst case.
    WorstCase,
}

/// One bus.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BusConfig {
    /// Name clients use (unique).
    pub name: String,
    /// `socketcan` or `virtual`.
    pub backend: BackendChoice,
    /// SocketCAN interface (`can0`, `vcan0`); for virtual buses the virtual
    /// bus name (default: the bus name), so two entries can share one.
    #[serde(default)]
    pub interface: Option<String>,
    /// Allow CAN FD frames.
    #[serde(default)]
    pub fd: bool,
    /// Nominal bitrate in bit/s: the load figure of every backend, and the
    /// bit-timing model of a virtual bus with `bit_timing = true`.
    #[serde(default)]
    pub bitrate: Option<u32>,
    /// CAN FD data-phase bitrate in bit/s.
    #[serde(default)]
    pub data_bitrate: Option<u32>,
    /// Virtual only: model each frame's time on the wire and arbitration.
    #[serde(default)]
    pub bit_timing: bool,
    /// Virtual only: stuff-bit counting of the timing model.
    #[serde(default)]
    pub stuffing: StuffingChoice,
    /// Share of the bus's time, in percent (1..=100, default 30), that
    /// client raw frames (`SendFrames`) may use; beyond it they wait, behind
    /// the gateway's own SYNC, set-points and NMT. 100: no limit. Applies
    /// where frames take time on a wire: SocketCAN with a `bitrate`, and
    /// virtual buses with `bit_timing`.
    #[serde(default)]
    pub client_share_percent: Option<u8>,
    /// Share of the bus's time, in percent (1..=100, default 50), that bulk
    /// SDO data (block download sub-blocks) may use (as
    /// `client_share_percent`).
    #[serde(default)]
    pub bulk_share_percent: Option<u8>,
    /// Virtual only: receive queue length of each participant.
    #[serde(default)]
    pub queue: Option<usize>,
    /// SocketCAN only: the socket's receive buffer in bytes (`SO_RCVBUF`,
    /// 1024..=67108864; the kernel doubles it, and caps it at
    /// `net.core.rmem_max` unless the gateway has `CAP_NET_ADMIN`). Frames
    /// the kernel drops when it is full are counted (`rx_overflows`) and
    /// reported to every stream. Default: the kernel's.
    #[serde(default)]
    pub receive_buffer: Option<usize>,
    /// SocketCAN only: own frames held while the interface's transmit queue
    /// is full (1..=65536, default 1024); when full, the least urgent
    /// (highest identifier) frame is given up and counted.
    #[serde(default)]
    pub transmit_queue: Option<usize>,
    /// SocketCAN only: how long a held frame is offered again before it is
    /// given up and counted (1..=10000 ms, default 250).
    #[serde(default)]
    pub transmit_timeout_ms: Option<u32>,
    // ---- fault injection, virtual only (see `fault_check`); also at run
    // time through the Simulator service ----
    /// Virtual only: drop each frame with this probability (0..=1) before
    /// any participant receives it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drop_probability: Option<f64>,
    /// Virtual only: drop every frame with one of these identifiers.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub drop_ids: Vec<u32>,
    /// Virtual only: deliver every frame this many µs late (at most 10 s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub delay_us: Option<u64>,
    /// Virtual only: seed of the drop generator, for reproducible runs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fault_seed: Option<u64>,
}

impl BusConfig {
    /// The interface or virtual bus name.
    pub fn interface(&self) -> &str {
        self.interface.as_deref().unwrap_or(&self.name)
    }

    /// Whether any fault injection is configured.
    pub fn has_faults(&self) -> bool {
        self.drop_probability.is_some_and(|p| p > 0.0)
            || !self.drop_ids.is_empty()
            || self.delay_us.is_some_and(|d| d > 0)
    }

    fn fault_check(&self) -> Result<(), String> {
        let configured = self.has_faults() || self.fault_seed.is_some();
        if configured && self.backend != BackendChoice::Virtual {
            return Err(format!(
                "bus {:?}: drop_probability, drop_ids, delay_us and fault_seed apply to virtual \
                 buses only",
                self.name
            ));
        }
        if let Some(p) = self.drop_probability
            && !(0.0..=1.0).contains(&p)
        {
            return Err(format!(
                "bus {:?}: drop_probability = {p} is not a probability (0..=1)",
                self.name
            ));
        }
        if let Some(id) = self.drop_ids.iter().find(|&&id| id > 0x1FFF_FFFF) {
            return Err(format!(
                "bus {:?}: drop_ids: {id:#x} is no CAN identifier (at most 0x1FFFFFFF)",
                self.name
            ));
        }
        if let Some(d) = self.delay_us
            && d > MAX_FAULT_DELAY_US
        {
            return Err(format!(
                "bus {:?}: delay_us = {d} exceeds {MAX_FAULT_DELAY_US} (10 s)",
                self.name
            ));
        }
        Ok(())
    }
}

/// The longest injected delivery delay, µs.
pub const MAX_FAULT_DELAY_US: u64 = 10_000_000;

impl BusConfig {
    /// The bus's shares for client raw frames and bulk data, checked.
    pub fn tx_shares(&self) -> Result<cangate_can::TxShares, String> {
        let defaults = cangate_can::TxShares::default();
        let shares = cangate_can::TxShares {
            client_percent: self.client_share_percent.unwrap_or(defaults.client_percent),
            bulk_percent: self.bulk_share_percent.unwrap_or(defaults.bulk_percent),
        };
        shares
            .validate()
            .map_err(|e| format!("bus {:?}: {e}", self.name))?;
        Ok(shares)
    }
}

/// A configuration that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read or parsed (includes unknown keys, with
    /// their name).
    #[error("configuration: {0}")]
    Load(#[from] config::ConfigError),
    /// The values are inconsistent.
    #[error("configuration: {0}")]
    Invalid(String),
}

impl Config {
    /// Loads `path` (or the embedded demo when `None`), applies the
    /// `CANGATE_…` environment, and validates.
    pub fn load(path: Option<&std::path::Path>) -> Result<Config, ConfigError> {
        let mut env = HashMap::new();
        for (k, v) in std::env::vars() {
            if !k.starts_with("CANGATE_") || CLIENT_VARIABLES.contains(&k.as_str()) {
                continue;
            }
            // Only the keys that can be overridden from the environment are
            // taken; other CANGATE_ variables belong to other tools (tests,
            // scripts) and must not break start-up, but a typo is reported.
            if ENV_KEYS
                .iter()
                .any(|p| k == *p || (p.ends_with("__") && k.starts_with(p)))
            {
                env.insert(k, v);
            } else {
                eprintln!(
                    "cangate-server: ignoring environment variable {k}: not a configuration \
                     override (those are {})",
                    ENV_KEYS.join(", ")
                );
            }
        }
        Self::load_with_env(path, env)
    }

    /// Like [`Config::load`] with an explicit environment (for tests).
    pub fn load_with_env(
        path: Option<&std::path::Path>,
        env: HashMap<String, String>,
    ) -> Result<Config, ConfigError> {
        let builder = config::Config::builder();
        let builder = match path {
            Some(p) => builder.add_source(config::File::from(p).format(config::FileFormat::Toml)),
            None => builder.add_source(config::File::from_str(
                DEMO_CONFIG,
                config::FileFormat::Toml,
            )),
        };
        let cfg: Config = builder
            .add_source(
                config::Environment::with_prefix("CANGATE")
                    .prefix_separator("_")
                    .separator("__")
                    .try_parsing(true)
                    .source(Some(env)),
            )
            .build()?
            .try_deserialize()?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Parses TOML text (no environment), and validates.
    pub fn from_toml(text: &str) -> Result<Config, ConfigError> {
        let cfg: Config = config::Config::builder()
            .add_source(config::File::from_str(text, config::FileFormat::Toml))
            .build()?
            .try_deserialize()?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// The embedded demo.
    pub fn demo() -> Config {
        Self::from_toml(DEMO_CONFIG).expect("the embedded demo configuration is valid")
    }

    /// Checks what serde cannot: unique names, sensible values.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.security.validate().map_err(ConfigError::Invalid)?;
        // A gateway that moves axes must not be reachable from the network
        // without authentication unless someone said so explicitly.
        if !self.listen.ip().is_loopback()
            && !self.security.insecure
            && !self.security.authentication()
        {
            return Err(ConfigError::Invalid(format!(
                "listen = {} is reachable from the network without authentication: anyone \
                 who reaches it can move the axes. Configure [[security.tokens]] or \
                 [[security.clients]], listen on 127.0.0.1 (and tunnel), or accept the risk \
                 with [security] insecure = true (env CANGATE_SECURITY__INSECURE=true)",
                self.listen
            )));
        }
        let mut names = HashSet::new();
        let mut interfaces = HashSet::new();
        for b in &self.buses {
            if b.name.is_empty() {
                return Err(ConfigError::Invalid("a bus has an empty name".into()));
            }
            if !names.insert(b.name.as_str()) {
                return Err(ConfigError::Invalid(format!(
                    "bus {:?} is configured twice",
                    b.name
                )));
            }
            if b.backend == BackendChoice::Socketcan && !interfaces.insert(b.interface()) {
                return Err(ConfigError::Invalid(format!(
                    "SocketCAN interface {:?} is used by two buses",
                    b.interface()
                )));
            }
            if b.bitrate == Some(0) || b.data_bitrate == Some(0) {
                return Err(ConfigError::Invalid(format!(
                    "bus {:?}: bitrate must be positive",
                    b.name
                )));
            }
            if b.bit_timing && b.bitrate.is_none() {
                return Err(ConfigError::Invalid(format!(
                    "bus {:?}: bit_timing needs a bitrate",
                    b.name
                )));
            }
            b.fault_check().map_err(ConfigError::Invalid)?;
            b.tx_shares().map_err(ConfigError::Invalid)?;
            if b.backend == BackendChoice::Socketcan && (b.bit_timing || b.queue.is_some()) {
                return Err(ConfigError::Invalid(format!(
                    "bus {:?}: bit_timing and queue apply to virtual buses only",
                    b.name
                )));
            }
            if b.backend != BackendChoice::Socketcan
                && (b.receive_buffer.is_some()
                    || b.transmit_queue.is_some()
                    || b.transmit_timeout_ms.is_some())
            {
                return Err(ConfigError::Invalid(format!(
                    "bus {:?}: receive_buffer, transmit_queue and transmit_timeout_ms apply to \
                     SocketCAN buses only",
                    b.name
                )));
            }
            for (key, value, range) in [
                ("receive_buffer", b.receive_buffer, 1024..=64 << 20),
                ("transmit_queue", b.transmit_queue, 1..=65536),
                (
                    "transmit_timeout_ms",
                    b.transmit_timeout_ms.map(|v| v as usize),
                    1..=10_000,
                ),
            ] {
                if let Some(v) = value
                    && !range.contains(&v)
                {
                    return Err(ConfigError::Invalid(format!(
                        "bus {:?}: {key} = {v} is out of range ({}..={})",
                        b.name,
                        range.start(),
                        range.end()
                    )));
                }
            }
        }
        let mut masters = HashSet::new();
        for c in &self.canopen {
            let Some(bus) = self.buses.iter().find(|b| b.name == c.bus) else {
                return Err(ConfigError::Invalid(format!(
                    "[[canopen]] names bus {:?}, which is not configured",
                    c.bus
                )));
            };
            c.master_heartbeat_check().map_err(ConfigError::Invalid)?;
            if !masters.insert(c.bus.as_str()) {
                return Err(ConfigError::Invalid(format!(
                    "bus {:?} has two [[canopen]] sections",
                    c.bus
                )));
            }
            let mut ids = HashSet::new();
            for n in &c.nodes {
                if !(1..=127).contains(&n.id) {
                    return Err(ConfigError::Invalid(format!(
                        "bus {:?}: node id {} is out of range (1..=127)",
                        c.bus, n.id
                    )));
                }
                if !ids.insert(n.id) {
                    return Err(ConfigError::Invalid(format!(
                        "bus {:?}: node {} is configured twice",
                        c.bus, n.id
                    )));
                }
                if n.simulate && bus.backend != BackendChoice::Virtual {
                    return Err(ConfigError::Invalid(format!(
                        "bus {:?}: node {} can only be simulated on a virtual bus",
                        c.bus, n.id
                    )));
                }
                if n.simulate && n.eds.is_none() {
                    return Err(ConfigError::Invalid(format!(
                        "bus {:?}: simulated node {} needs an eds",
                        c.bus, n.id
                    )));
                }
                let invalid = |e: String| {
                    ConfigError::Invalid(format!("bus {:?}: node {}: {e}", c.bus, n.id))
                };
                n.load_eds().map_err(invalid)?;
                let node =
                    cangate_canopen::NodeId::new(n.id).map_err(|e| invalid(e.to_string()))?;
                for p in &n.tpdo {
                    p.to_pdo(cangate_canopen::pdo::PdoKind::Tpdo, node)
                        .map_err(invalid)?;
                }
                for p in &n.rpdo {
                    p.to_pdo(cangate_canopen::pdo::PdoKind::Rpdo, node)
                        .map_err(invalid)?;
                }
                for w in &n.writes {
                    parse_object(&w.object).map_err(invalid)?;
                    let ty: cangate_canopen::value::DataType =
                        w.ty.parse()
                            .map_err(|e| invalid(format!("write {}: {e}", w.object)))?;
                    cangate_canopen::value::Value::parse(ty, &w.value)
                        .map_err(|e| invalid(format!("write {}: {e}", w.object)))?;
                }
            }
        }
        let mut wheel_names = HashSet::new();
        for h in &self.handwheels {
            h.validate(self).map_err(ConfigError::Invalid)?;
            if !wheel_names.insert(h.name.as_str()) {
                return Err(ConfigError::Invalid(format!(
                    "handwheel {:?} is configured twice",
                    h.name
                )));
            }
        }
        let mut axis_names = HashSet::new();
        let mut axis_nodes = HashSet::new();
        for a in &self.axes {
            a.validate(self).map_err(ConfigError::Invalid)?;
            if !axis_names.insert(a.name.as_str()) {
                return Err(ConfigError::Invalid(format!(
                    "axis {:?} is configured twice",
                    a.name
                )));
            }
            if !axis_nodes.insert((a.bus.as_str(), a.node)) {
                return Err(ConfigError::Invalid(format!(
                    "axis {}: node {} on bus {:?} already backs another axis",
                    a.name, a.node, a.bus
                )));
            }
        }
        if self.shutdown_timeout_ms == 0 || self.shutdown_timeout_ms > 600_000 {
            return Err(ConfigError::Invalid(format!(
                "shutdown_timeout_ms = {} must be between 1 and 600000",
                self.shutdown_timeout_ms
            )));
        }
        for (key, v) in [
            ("rt_priority", self.rt_priority),
            ("grpc_rt_priority", self.grpc_rt_priority),
        ] {
            if v > 99 {
                return Err(ConfigError::Invalid(format!(
                    "{key} = {v} must be 0 (off) or 1..=99"
                )));
            }
        }
        let mut smc_names = HashSet::new();
        let mut smc_buses = HashSet::new();
        for c in &self.cansmc {
            c.validate(&self.buses).map_err(ConfigError::Invalid)?;
            if !smc_names.insert(c.name.as_str()) {
                return Err(ConfigError::Invalid(format!(
                    "cansmc {:?} is configured twice",
                    c.name
                )));
            }
            for bus in [&c.command_bus, &c.status_bus] {
                if !smc_buses.insert(bus.as_str()) || masters.contains(bus.as_str()) {
                    return Err(ConfigError::Invalid(format!(
                        "cansmc {}: bus {bus:?} is already used by another master",
                        c.name
                    )));
                }
            }
            for a in &c.axes {
                if !axis_names.insert(a.name.as_str()) {
                    return Err(ConfigError::Invalid(format!(
                        "axis {:?} is configured twice",
                        a.name
                    )));
                }
            }
        }
        Ok(())
    }

    /// The effective configuration as TOML (for `--print-config`).
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_else(|e| format!("# cannot render: {e}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn demo_is_valid_and_has_the_demo_buses() {
        let c = Config::demo();
        let names: Vec<_> = c.buses.iter().map(|b| b.name.as_str()).collect();
        assert_eq!(names, ["can0", "smc0", "smc1"]);
        let nodes: Vec<_> = c.canopen[0].nodes.iter().map(|n| n.id).collect();
        assert_eq!(nodes, [1, 2, 3, 4, 10]);
        assert_eq!(c.handwheels[0].name, "hw1");
        assert_eq!(c.listen, default_listen());
        let axes: Vec<_> = c.axes.iter().map(|a| (a.name.as_str(), a.node)).collect();
        assert_eq!(axes, [("X", 1), ("Y", 2), ("Z", 4)]);
        assert_eq!(c.canopen[0].sync_period_us, 10_000);
    }

    const AXIS_BASE: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"
[[canopen]]
bus = "can0"
[[canopen.node]]
id = 1
eds = "builtin:drive"
"#;

    fn axis_err(axis: &str) -> String {
        Config::from_toml(&format!("{AXIS_BASE}[[axis]]\n{axis}"))
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn axis_configuration_mistakes_are_named() {
        let ok = "name = \"X\"\nbus = \"can0\"\nnode = 1\ncounts_per_unit = 1000.0\n\
                  max_velocity = 10.0\nmax_acceleration = 100.0\n";
        Config::from_toml(&format!("{AXIS_BASE}[[axis]]\n{ok}")).unwrap();
        let e = axis_err(&ok.replace("node = 1", "node = 9"));
        assert!(e.contains("node 9 is not configured"), "{e}");
        let e = axis_err(&ok.replace("bus = \"can0\"", "bus = \"can9\""));
        assert!(e.contains("has no [[canopen]] master"), "{e}");
        let e = axis_err(&format!("{ok}position_mode = \"cyclic\"\n"));
        assert!(e.contains("needs a SYNC: set sync_period_us"), "{e}");
        let e = axis_err(&format!("{ok}min_position = 5.0\nmax_position = -5.0\n"));
        assert!(e.contains("must be below max_position"), "{e}");
        let e = axis_err(&format!("{ok}min_position = 5.0\n"));
        assert!(e.contains("give both"), "{e}");
        let e = axis_err(&ok.replace("counts_per_unit = 1000.0", "counts_per_unit = 0.0"));
        assert!(e.contains("counts_per_unit"), "{e}");
        let e = axis_err(&format!("{ok}default_velocity = 20.0\n"));
        assert!(e.contains("exceeds max_velocity"), "{e}");
        // Values no drive or dead-man can honour are refused at start-up.
        let e = axis_err(&format!("{ok}jog_deadman_ms = 4294967295\n"));
        assert!(
            e.contains("jog_deadman_ms = 4294967295 is above the maximum of 10000 ms"),
            "{e}"
        );
        let e = axis_err(&ok.replace("max_acceleration = 100.0", "max_acceleration = 1e308"));
        assert!(
            e.contains("max_acceleration = 1e308") && e.contains("counts/s²"),
            "{e}"
        );
        let e = axis_err(&format!("{ok}homing_timeout_ms = 9223372036854775807\n"));
        assert!(e.contains("homing_timeout_ms"), "{e}");
        // The SDO fallback: profile position only, a sane poll period.
        let sdo = format!("{ok}process_data = \"sdo\"\n");
        Config::from_toml(&format!("{AXIS_BASE}[[axis]]\n{sdo}")).unwrap();
        let e = Config::from_toml(&format!(
            "{}[[axis]]\n{sdo}position_mode = \"cyclic\"\n",
            AXIS_BASE.replace(
                "bus = \"can0\"\n[[canopen.node]]",
                "bus = \"can0\"\nsync_period_us = 1000\n[[canopen.node]]"
            )
        ))
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("process_data = \"sdo\" needs position_mode = \"profile\""),
            "{e}"
        );
        let e = axis_err(&format!("{sdo}sdo_poll_ms = 0\n"));
        assert!(e.contains("sdo_poll_ms must be 1..=10000"), "{e}");
        let e = axis_err(&format!("{ok}process_data = \"rpc\"\n"));
        assert!(e.contains("rpc") && e.contains("process_data"), "{e}");
        let two = format!(
            "{AXIS_BASE}[[axis]]\n{ok}[[axis]]\n{}",
            ok.replace("\"X\"", "\"Y\"")
        );
        let e = Config::from_toml(&two).unwrap_err().to_string();
        assert!(e.contains("already backs another axis"), "{e}");
    }

    #[test]
    fn real_time_priorities_are_off_by_default_and_bounded() {
        let c = Config::from_toml("").unwrap();
        assert_eq!((c.rt_priority, c.grpc_rt_priority), (0, 0));
        let c = Config::from_toml("rt_priority = 10\ngrpc_rt_priority = 5\n").unwrap();
        assert_eq!((c.rt_priority, c.grpc_rt_priority), (10, 5));
        for key in ["rt_priority", "grpc_rt_priority"] {
            let e = Config::from_toml(&format!("{key} = 100\n"))
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(&format!("{key} = 100 must be 0 (off) or 1..=99")),
                "{e}"
            );
        }
    }

    #[test]
    fn non_loopback_listen_needs_insecure() {
        let e = Config::from_toml("listen = \"0.0.0.0:50051\"\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("without authentication") && e.contains("insecure = true"),
            "{e}"
        );
        let c =
            Config::from_toml("listen = \"0.0.0.0:50051\"\n[security]\ninsecure = true\n").unwrap();
        assert!(c.security.insecure);
        let env = HashMap::from([
            ("CANGATE_LISTEN".to_string(), "0.0.0.0:1".to_string()),
            ("CANGATE_SECURITY__INSECURE".to_string(), "true".to_string()),
        ]);
        assert!(Config::load_with_env(None, env).is_ok());
        Config::from_toml("listen = \"[::1]:50051\"\n").unwrap();
    }

    #[test]
    fn security_section_shape_and_checks() {
        let hash = crate::security::auth::hash_token("t");
        let text = format!(
            "listen = \"0.0.0.0:50051\"\n[[security.tokens]]\nname = \"hmi-1\"\nrole = \"operator\"\n\
             sha256 = \"{hash}\"\n[security.limits]\nburst = 10\n"
        );
        // Authentication configured: a network address is fine.
        let c = Config::from_toml(&text).unwrap();
        assert_eq!(c.security.tokens[0].role, crate::security::Role::Operator);
        assert_eq!(c.security.limits.burst, 10);
        assert_eq!(c.security.limits.requests_per_second_per_client, 200);
        assert_eq!(Config::from_toml(&c.to_toml()).unwrap(), c);
        let env = HashMap::from([(
            "CANGATE_SECURITY__LIMITS__BURST".to_string(),
            "100".to_string(),
        )]);
        let c = Config::load_with_env(None, env).unwrap();
        assert_eq!(c.security.limits.burst, 100);
        for (bad, why) in [
            (text.replace(&hash, "abc"), "64 hex digits"),
            (text.replace("operator", "admin"), "admin"),
            (
                "[[security.clients]]\nsubject_cn = \"a\"\nrole = \"viewer\"\n".to_string(),
                "client_ca",
            ),
            (
                "[security.tls]\ncert = \"c\"\nkey = \"k\"\nrequire_client_cert = true\n"
                    .to_string(),
                "needs client_ca",
            ),
        ] {
            let e = Config::from_toml(&bad).unwrap_err().to_string();
            assert!(e.contains(why), "{why}: {e}");
        }
    }

    #[test]
    fn unknown_keys_are_named() {
        let err = Config::from_toml("listen = \"127.0.0.1:1\"\nlisen = 3\n").unwrap_err();
        assert!(err.to_string().contains("lisen"), "{err}");
        let err = Config::from_toml("[[bus]]\nname = \"a\"\nbackend = \"virtual\"\nbitrat = 5\n")
            .unwrap_err();
        assert!(err.to_string().contains("bitrat"), "{err}");
    }

    #[test]
    fn duplicate_bus_is_refused() {
        let err = Config::from_toml(
            "[[bus]]\nname = \"a\"\nbackend = \"virtual\"\n[[bus]]\nname = \"a\"\nbackend = \"virtual\"\n",
        )
        .unwrap_err();
        assert!(
            err.to_string().contains("\"a\" is configured twice"),
            "{err}"
        );
    }

    #[test]
    fn environment_overrides_and_client_variables_are_ignored() {
        let env = HashMap::from([
            ("CANGATE_LISTEN".to_string(), "127.0.0.1:6000".to_string()),
            ("CANGATE_LOG__FORMAT".to_string(), "json".to_string()),
            ("CANGATE_RT_PRIORITY".to_string(), "20".to_string()),
            ("CANGATE_GRPC_RT_PRIORITY".to_string(), "10".to_string()),
            (
                "CANGATE_SHUTDOWN_TIMEOUT_MS".to_string(),
                "2500".to_string(),
            ),
        ]);
        let c = Config::load_with_env(None, env).unwrap();
        assert_eq!(c.listen.port(), 6000);
        assert_eq!(c.log.format, LogFormat::Json);
        assert_eq!((c.rt_priority, c.grpc_rt_priority), (20, 10));
        assert_eq!(c.shutdown_timeout_ms, 2500);
    }

    #[test]
    fn print_config_round_trips() {
        let c = Config::demo();
        assert_eq!(Config::from_toml(&c.to_toml()).unwrap(), c);
    }
}
