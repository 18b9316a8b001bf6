//! `[[bus]]`: CAN interfaces (SocketCAN or virtual), bit timing, budgets
//! and simulated faults.

use serde::{Deserialize, Serialize};

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

/// How much of each frame on a bus the log shows (target
/// `cangate::frames`, level info).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DecodeLevel {
    /// No line per frame.
    #[default]
    None,
    /// One line per frame: direction, identifier, length, data bytes.
    Summary,
    /// The summary, and CANopen frames in words (NMT, SYNC, EMCY, TIME,
    /// PDO, SDO, heartbeat, LSS).
    Decoded,
}

impl DecodeLevel {
    /// True for [`DecodeLevel::None`] (the default, left out of the
    /// printed configuration).
    pub fn is_none(&self) -> bool {
        *self == DecodeLevel::None
    }
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
    /// Virtual with `bit_timing` only: hand frames to the receivers up to
    /// this many µs after their completion, several at once, as a CAN
    /// adapter's interrupt coalescing does (0..=10000, default 0: each at
    /// its completion; timestamps stay exact). Saves CPU on busy cyclic
    /// buses; keep it well below the shortest cycle that has to react to
    /// a frame (a CANsmc cycle, a SYNC period).
    #[serde(default)]
    pub rx_coalesce_us: u32,
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
    /// How much of each frame the log shows: `none` (default), `summary`
    /// or `decoded`.
    #[serde(default, skip_serializing_if = "DecodeLevel::is_none")]
    pub decode: DecodeLevel,
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

    pub(super) fn fault_check(&self) -> Result<(), String> {
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
        if self.rx_coalesce_us != 0 && !(self.backend == BackendChoice::Virtual && self.bit_timing)
        {
            return Err(format!(
                "bus {:?}: rx_coalesce_us applies to virtual buses with bit_timing = true only",
                self.name
            ));
        }
        if self.rx_coalesce_us > MAX_RX_COALESCE_US {
            return Err(format!(
                "bus {:?}: rx_coalesce_us = {} exceeds {MAX_RX_COALESCE_US} (10 ms)",
                self.name, self.rx_coalesce_us
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

/// The longest receive coalescing window of a virtual bus, µs.
pub const MAX_RX_COALESCE_US: u32 = 10_000;

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
