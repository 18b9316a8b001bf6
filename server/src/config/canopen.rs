//! `[[canopen]]` and `[[canopen.node]]`: the CANopen master of a bus, its
//! nodes, their boot-time SDO writes and PDOs.

use serde::{Deserialize, Serialize};

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
    /// SYNC counter overflow value (0x1019): 0 sends SYNCs without data,
    /// 2..=240 adds a one-byte counter that runs 1..=value. Changeable at
    /// run time with `Canopen.SetSync`.
    #[serde(default)]
    pub sync_counter_overflow: u8,
    /// TIME producer period in ms (0 = TIME only on request; else at least
    /// 100): the master sends the host's UTC time as a CiA 301 TIME_OF_DAY
    /// on 0x100.
    #[serde(default)]
    pub time_period_ms: u64,
    /// Known nodes.
    #[serde(default, rename = "node")]
    pub nodes: Vec<NodeConfig>,
    // ---- the master's own heartbeat (see `check`) ----
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

/// The shortest period of periodic TIMEs, in ms: 10 frames a second on
/// 0x100 are more than any consumer needs to keep its clock (the TIME is
/// exact to the ms whenever it leaves), and a shorter period would take a
/// share of a slow bus for nothing (1 ms: 1,000 frames a second).
pub const MIN_TIME_PERIOD_MS: u64 = 100;

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

    pub(super) fn check(&self) -> Result<(), String> {
        let at = |m: String| format!("[[canopen]] bus {:?}: {m}", self.bus);
        if self.sync_counter_overflow == 1 || self.sync_counter_overflow > 240 {
            return Err(at(format!(
                "sync_counter_overflow {} is reserved: use 0 (no counter) or 2..=240",
                self.sync_counter_overflow
            )));
        }
        if self.time_period_ms > 0 && self.time_period_ms < MIN_TIME_PERIOD_MS {
            return Err(at(format!(
                "time_period_ms = {} is too short: at least {} ms (0 = TIME only on request)",
                self.time_period_ms, MIN_TIME_PERIOD_MS
            )));
        }
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
    /// device descriptions `builtin:drive`, `builtin:drive2` (the same
    /// drive with two axes), `builtin:io`, `builtin:handwheel`.
    #[serde(default)]
    pub eds: Option<String>,
    /// A DCF (CiA 306) whose `ParameterValue`s the boot procedure writes
    /// before the other boot writes (needs `boot = true`; `rw` objects
    /// only, PDOs as whole PDOs). Without `eds` it is the node's EDS too.
    #[serde(default)]
    pub dcf: Option<String>,
    /// Consumer heartbeat timeout in ms (0 = do not monitor).
    #[serde(default)]
    pub heartbeat_timeout_ms: u64,
    /// Node guarding (CiA 301) instead of the heartbeat: the master sends
    /// an RTR to 0x700+n every `guard_time_ms` (0 = not guarded). Needs
    /// `life_time_factor`; excludes `heartbeat_timeout_ms` and
    /// `heartbeat_producer_ms`.
    #[serde(default)]
    pub guard_time_ms: u64,
    /// Node guarding: unanswered requests in a row after which the node is
    /// lost (node life time = guard time × life time factor), 1..=255.
    #[serde(default)]
    pub life_time_factor: u8,
    /// Virtual buses only: run a simulated device from the EDS at this id.
    #[serde(default)]
    pub simulate: bool,
    /// Simulation only (`simulate = true`): the simulated device also
    /// serves LSS (CiA 305) with this identity and, unless `configured`,
    /// starts without a node-ID (255: silent but for LSS) until one is
    /// given to it over LSS (`cangate lss set-id`). `id` is then the id the
    /// master expects it at.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sim_lss: Option<SimLssConfig>,
    /// Simulation only (`simulate = true`): where the simulated device
    /// behaves as some real stacks do rather than by default (already
    /// running when the gateway starts, no heartbeat, no node guarding,
    /// refusing NMT start).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sim: Option<SimDeviceConfig>,
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

/// The LSS identity of a simulated node (`sim_lss = { serial = 1234 }`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimLssConfig {
    /// 0x1018:01 vendor-ID (default: the EDS's).
    #[serde(default)]
    pub vendor_id: Option<u32>,
    /// 0x1018:02 product code (default: the EDS's).
    #[serde(default)]
    pub product_code: Option<u32>,
    /// 0x1018:03 revision number (default: the EDS's).
    #[serde(default)]
    pub revision: Option<u32>,
    /// 0x1018:04 serial number.
    pub serial: u32,
    /// Start with the node's `id` (LSS only changes it) rather than
    /// without a node-ID.
    #[serde(default)]
    pub configured: bool,
    /// Answer LSS fastscan in any LSS state while without a node-ID, as
    /// CANopenNode's LSS slave does (a CiA 305 slave answers only in the
    /// waiting state).
    #[serde(default)]
    pub fastscan_until_configured: bool,
}

/// How a simulated device behaves (`sim = { start = "operational",
/// heartbeat_ms = 0 }`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimDeviceConfig {
    /// Its state when the gateway starts: `boot` (default: it boots with
    /// the gateway and sends its boot-up), or it was running before and
    /// the gateway hears no boot-up: `pre_operational`, `operational`, or
    /// (a CiA 402 drive) `operation_enabled`: operational, and the drive
    /// enabled in `mode` at `position`, holding.
    #[serde(default)]
    pub start: SimStart,
    /// Heartbeat producer time in ms (0x1017; 0: none, as CANopenNode's
    /// default). Default: a third of `heartbeat_timeout_ms`, else 100.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub heartbeat_ms: Option<u16>,
    /// Answer node guarding requests (default true).
    #[serde(default = "default_true")]
    pub node_guarding: bool,
    /// Ignore NMT start: the device stays pre-operational.
    #[serde(default)]
    pub refuses_nmt_start: bool,
    /// `start = "operation_enabled"`: the CiA 402 mode of operation
    /// (default 8, cyclic synchronous position).
    #[serde(default = "default_sim_mode")]
    pub mode: i8,
    /// `start = "operation_enabled"`: the drive's position in increments.
    #[serde(default)]
    pub position: i32,
    /// A drive's negative limit switch (0x60FD bit 0): active at and below
    /// this physical position, increments.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub negative_limit_switch: Option<i32>,
    /// A drive's positive limit switch (0x60FD bit 1): active at and above.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub positive_limit_switch: Option<i32>,
    /// A drive's home switch (0x60FD bit 2): active at and above.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub home_switch: Option<i32>,
    /// A drive's touch probe 1 input: active at and above (crossing it
    /// upwards is the rising edge).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub touch_probe: Option<i32>,
}

fn default_true() -> bool {
    true
}

fn default_sim_mode() -> i8 {
    8
}

/// The state of a simulated device when the gateway starts.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SimStart {
    /// Boots with the gateway (boot-up message, pre-operational).
    #[default]
    Boot,
    /// Already pre-operational.
    PreOperational,
    /// Already operational.
    Operational,
    /// Already operational, and the drive in operation enabled.
    OperationEnabled,
}

impl SimDeviceConfig {
    pub(super) fn check(&self, node: u32) -> Result<(), String> {
        if self.start == SimStart::OperationEnabled
            && cangate_canopen::cia402::ModeOfOperation::from_code(self.mode).is_none()
        {
            return Err(format!(
                "node {node}: sim.mode {} is no CiA 402 mode of operation (1 profile position, \
                 3 profile velocity, 6 homing, 8 cyclic synchronous position, ...)",
                self.mode
            ));
        }
        Ok(())
    }
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
    /// Node guarding as (guard time, life time factor), when configured.
    pub fn guarding(&self) -> Option<(std::time::Duration, u8)> {
        (self.guard_time_ms > 0 && self.life_time_factor > 0).then(|| {
            (
                std::time::Duration::from_millis(self.guard_time_ms),
                self.life_time_factor,
            )
        })
    }

    /// The node guarding keys: both or neither, and not together with the
    /// heartbeat (a CiA 301 node uses one or the other).
    pub(super) fn guarding_check(&self) -> Result<(), String> {
        match (self.guard_time_ms > 0, self.life_time_factor > 0) {
            (false, false) => return Ok(()),
            (true, false) => {
                return Err(format!(
                    "node {}: guard_time_ms needs life_time_factor (1..=255; the node is lost \
                     after that many unanswered guarding requests)",
                    self.id
                ));
            }
            (false, true) => {
                return Err(format!(
                    "node {}: life_time_factor needs guard_time_ms (the guarding request \
                     period)",
                    self.id
                ));
            }
            (true, true) => {}
        }
        if self.guard_time_ms > u64::from(u16::MAX) {
            return Err(format!(
                "node {}: guard_time_ms = {} is out of range (1..=65535, object 0x100C)",
                self.id, self.guard_time_ms
            ));
        }
        if self.heartbeat_timeout_ms > 0 || self.heartbeat_producer_ms.is_some_and(|t| t > 0) {
            return Err(format!(
                "node {}: node guarding (guard_time_ms, life_time_factor) and the heartbeat \
                 (heartbeat_timeout_ms, heartbeat_producer_ms) exclude each other: a CiA 301 \
                 node is watched by one or the other; remove one",
                self.id
            ));
        }
        Ok(())
    }

    /// Loads the configured EDS (the DCF of `dcf` when no `eds` is
    /// given): what it parses to, and its text (for a DCF export).
    pub fn load_eds(
        &self,
    ) -> Result<Option<(cangate_canopen::eds::Eds, std::sync::Arc<str>)>, String> {
        use cangate_canopen::eds::{Eds, SIM_DRIVE_EDS, SIM_HANDWHEEL_EDS, SIM_IO_EDS};
        let Some(src) = self.eds.as_deref().or(self.dcf.as_deref()) else {
            return Ok(None);
        };
        let text = match src {
            "builtin:drive" => Ok(SIM_DRIVE_EDS.to_string()),
            "builtin:drive2" => Ok(cangate_canopen::eds::sim_drive_eds_with_axes(2)),
            "builtin:io" => Ok(SIM_IO_EDS.to_string()),
            "builtin:handwheel" => Ok(SIM_HANDWHEEL_EDS.to_string()),
            path if path.starts_with("builtin:") => {
                return Err(format!(
                    "unknown built-in EDS {path:?} (builtin:drive, builtin:drive2, builtin:io, \
                     builtin:handwheel)"
                ));
            }
            path => Eds::read_text(path),
        };
        let text = text.map_err(|e| format!("EDS {src:?}: {e}"))?;
        let eds = Eds::parse(&text).map_err(|e| format!("EDS {src:?}: {e}"))?;
        Ok(Some((eds, text.into())))
    }

    /// Loads the DCF whose `ParameterValue`s the boot procedure writes.
    pub fn load_dcf(&self) -> Result<Option<cangate_canopen::eds::Eds>, String> {
        let Some(path) = self.dcf.as_deref() else {
            return Ok(None);
        };
        cangate_canopen::eds::Eds::from_path(path)
            .map(Some)
            .map_err(|e| format!("DCF {path:?}: {e}"))
    }
}
