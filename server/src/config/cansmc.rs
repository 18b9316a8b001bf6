//! `[[cansmc]]`: a CANsmc master on two buses, its slaves and its axes.
//!
//! ```toml
//! [[cansmc]]
//! name = "smc"            # unique; the gRPC Cansmc service and CLI use it
//! command_bus = "smc0"    # channel 0: MST, MCT, MDT (master → slaves)
//! status_bus = "smc1"     # channel 1: DCT, DT (slaves → master)
//! cycle_time_us = 2000
//!
//! [[cansmc.slave]]
//! address = 1
//! name = "A servo"
//! simulate = true
//! parameters = [{ number = 4, value = 20000 }]   # written in P1
//!
//! [[cansmc.axis]]
//! name = "A"
//! address = 1
//! counts_per_unit = 1000.0
//! max_velocity = 200.0
//! max_acceleration = 2000.0
//! ```

use serde::{Deserialize, Serialize};
use std::collections::HashSet;
use std::time::Duration;

use super::{BusConfig, CommonAxisConfig};
use cangate_axis::{AxisSpec, CansmcDrive, DriveSpec, Gear, JogMode};
use cangate_cansmc::{CycleConfig, Infeasibility, SmcAddress};

/// One CANsmc master.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CansmcConfig {
    /// Unique name of the master.
    pub name: String,
    /// Channel 0 (master → slaves), a `[[bus]]` name.
    pub command_bus: String,
    /// Channel 1 (slaves → master), a `[[bus]]` name; both channels must
    /// have the same bit rate.
    pub status_bus: String,
    /// Cycle time of phase P2 in µs (default 2000).
    #[serde(default = "default_cycle_time_us")]
    pub cycle_time_us: u32,
    /// Time after MST during which the gateway computes the cycle's
    /// set-points, before the MDTs go out (`T_int`), µs (default 100).
    #[serde(default = "default_t_int_us")]
    pub t_int_us: u32,
    /// P0: wait for DCTs this long before resending MCTs, ms (default 50).
    #[serde(default = "default_connect_timeout_ms")]
    pub connect_timeout_ms: u64,
    /// P0: MCTs per slave before it is missing (default 3).
    #[serde(default = "default_connect_attempts")]
    pub connect_attempts: u32,
    /// Bound of one parameter request, ms (default 100).
    #[serde(default = "default_parameter_timeout_ms")]
    pub parameter_timeout_ms: u64,
    /// Consecutive missed DTs after which a slave is lost and its axes
    /// fault (default 3).
    #[serde(default = "default_lost_after")]
    pub lost_after: u32,
    /// How long after a cycle's end its DTs may still reach the master, ms
    /// (default 10): a DT is judged by its arrival time on the bus, and
    /// this covers the time between the wire and the cycle thread (a
    /// receive thread, a bus task or a bus simulation held up by a loaded
    /// host), so that the host's delay is not counted as the slave's miss.
    /// At most 14 cycles (the cycle counter's 16 values must tell the
    /// open cycles apart); a slave that stops answering is lost this much
    /// later.
    #[serde(default = "default_handover_grace_ms")]
    pub handover_grace_ms: u32,
    /// The cycle thread sleeps until at most this long before each MST,
    /// then waits actively, trading CPU for start-time jitter, µs (0 =
    /// sleep only). Default: 200 when the thread runs `SCHED_FIFO`
    /// (`rt_priority` set and granted), else 0: a thread of the default
    /// policy is preempted at the scheduler's whim anyway, and sleeping
    /// only keeps the MST jitter within 100 µs at p99 on a quiet host
    /// (`cansmc_bench` measures both) at a fraction of the CPU.
    #[serde(default)]
    pub spin_us: Option<u32>,
    /// Real-time priority of the cycle thread (Linux `SCHED_FIFO`, 1..=99;
    /// 0 = normal scheduling, the default). Without it a busy host can
    /// delay MSTs by milliseconds; it needs root or `CAP_SYS_NICE`, and a
    /// refusal is logged and the thread runs normally.
    #[serde(default)]
    pub rt_priority: u8,
    /// Bit rate for the feasibility check when the buses do not give one
    /// (default 1 Mbit/s).
    #[serde(default)]
    pub bitrate: Option<u32>,
    /// The slaves.
    #[serde(default, rename = "slave")]
    pub slaves: Vec<CansmcSlaveConfig>,
    /// Axes backed by slaves of this master.
    #[serde(default, rename = "axis", skip_serializing_if = "Vec::is_empty")]
    pub axes: Vec<CansmcAxisEntry>,
}

fn default_cycle_time_us() -> u32 {
    2000
}
fn default_t_int_us() -> u32 {
    cangate_cansmc::feasibility::DEFAULT_T_INT_US
}
fn default_connect_timeout_ms() -> u64 {
    50
}
fn default_connect_attempts() -> u32 {
    3
}
fn default_parameter_timeout_ms() -> u64 {
    100
}
fn default_lost_after() -> u32 {
    3
}
fn default_handover_grace_ms() -> u32 {
    10
}
/// `spin_us` when not configured and the cycle thread runs `SCHED_FIFO`.
pub const DEFAULT_FIFO_SPIN_US: u32 = 200;
fn default_true() -> bool {
    true
}

/// What a slave is asked every cycle when no axis drives it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CyclicChoice {
    /// Position MDT holding 0, not enabled: the DT reports the position.
    #[default]
    Position,
    /// Encoder request (function 0x07): the DT reports the encoder count
    /// (a gear source).
    Encoder,
    /// Digital I/O (function 0x06): the DT reports the inputs.
    Io,
}

/// A parameter written in phase P1.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParameterWrite {
    /// Parameter number (1–5 standard, ≥ 0x1000 device specific).
    pub number: u16,
    /// Value.
    pub value: i32,
}

/// One slave of a master.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CansmcSlaveConfig {
    /// Address 1..=61.
    pub address: u8,
    /// For people.
    #[serde(default)]
    pub name: String,
    /// The master refuses to start without it (default true); an optional
    /// slave that does not answer is reported and left out.
    #[serde(default = "default_true")]
    pub required: bool,
    /// What it is asked every cycle when no axis drives it.
    #[serde(default)]
    pub cyclic: CyclicChoice,
    /// Written in P1, in order.
    #[serde(default)]
    pub parameters: Vec<ParameterWrite>,
    /// Run a simulated slave at this address on the master's virtual buses.
    #[serde(default)]
    pub simulate: bool,
    /// Simulation: a free-running external encoder, counts/s (the slave's
    /// encoder count is its motor position otherwise).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sim_encoder_velocity: Option<f64>,
}

/// An axis backed by a CANsmc slave.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CansmcAxisEntry {
    /// Unique axis name (among all axes of the gateway).
    pub name: String,
    /// The slave (configured under the same master).
    pub address: u8,
    /// Units, limits, stops, time bounds.
    #[serde(flatten)]
    pub common: CommonAxisConfig,
    /// Homing method byte of the homing MDT (default 1).
    #[serde(default = "default_homing_method")]
    pub homing_method: u8,
    /// Electronic gearing: follow this slave's encoder count while enabled.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gear_source: Option<u8>,
    /// Follower counts per source count (default 1).
    #[serde(default = "default_ratio")]
    pub gear_ratio: f64,
    /// `interpolated` (default): the gateway ramps jogs and sends position
    /// set-points; `velocity`: jogs use the slave's velocity mode (the
    /// gateway writes parameter 2 = 1, unit 0.001 r/min, in P1).
    #[serde(default)]
    pub jog_mode: JogModeChoice,
    /// Encoder counts per motor revolution (the slave's parameter 3), for
    /// velocity-mode jogs (default 10000).
    #[serde(default = "default_counts_per_rev")]
    pub counts_per_rev: u32,
}

/// How a CANsmc axis jogs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum JogModeChoice {
    /// Position set-points from the gateway's velocity ramp.
    #[default]
    Interpolated,
    /// The slave's velocity mode (function 0x03).
    Velocity,
}

fn default_counts_per_rev() -> u32 {
    10_000
}

fn default_homing_method() -> u8 {
    1
}
fn default_ratio() -> f64 {
    1.0
}

impl CansmcAxisEntry {
    /// The runtime's description of this axis of `master`.
    pub fn spec(&self, master: &CansmcConfig) -> Result<AxisSpec, String> {
        let address =
            SmcAddress::new(self.address).map_err(|e| format!("axis {}: {e}", self.name))?;
        Ok(AxisSpec {
            name: self.name.clone(),
            motion: self.common.motion(),
            stop_on_loss: self.common.stop_on_loss.kind(),
            drive: DriveSpec::Cansmc(CansmcDrive {
                master: master.name.clone(),
                command_bus: master.command_bus.clone(),
                address,
                cycle_time: master.cycle_time(),
                homing_method: self.homing_method,
                gear: self.gear_source.map(|source| Gear {
                    source,
                    ratio: self.gear_ratio,
                }),
                jog_mode: match self.jog_mode {
                    JogModeChoice::Interpolated => JogMode::Interpolated,
                    JogModeChoice::Velocity => JogMode::SlaveVelocity,
                },
                counts_per_rev: self.counts_per_rev,
            }),
        })
    }
}

impl CansmcConfig {
    /// The cycle time.
    pub fn cycle_time(&self) -> Duration {
        Duration::from_micros(u64::from(self.cycle_time_us))
    }

    /// The bit rate the feasibility check uses.
    pub fn effective_bitrate(&self, buses: &[BusConfig]) -> u32 {
        buses
            .iter()
            .find(|b| b.name == self.command_bus)
            .and_then(|b| b.bitrate)
            .or(self.bitrate)
            .unwrap_or(1_000_000)
    }

    /// Checks what serde cannot, including whether the cycle fits the bus
    /// (the arithmetic is in the message when it does not).
    pub fn validate(&self, buses: &[BusConfig]) -> Result<(), String> {
        let name = &self.name;
        if name.is_empty() || name.contains(char::is_whitespace) {
            return Err(format!(
                "[[cansmc]] name {name:?} must be non-empty without spaces"
            ));
        }
        for (what, bus) in [
            ("command_bus", &self.command_bus),
            ("status_bus", &self.status_bus),
        ] {
            if !buses.iter().any(|b| &b.name == bus) {
                return Err(format!(
                    "cansmc {name}: {what} {bus:?} is not a configured [[bus]]"
                ));
            }
        }
        if self.command_bus == self.status_bus {
            return Err(format!(
                "cansmc {name}: command_bus and status_bus must be two different buses"
            ));
        }
        let rate = |b: &str| buses.iter().find(|x| x.name == b).and_then(|x| x.bitrate);
        if let (Some(a), Some(b)) = (rate(&self.command_bus), rate(&self.status_bus))
            && a != b
        {
            return Err(format!(
                "cansmc {name}: both channels must run at the same bit rate ({} has {a}, {} has {b})",
                self.command_bus, self.status_bus
            ));
        }
        if self.cycle_time_us < 100 {
            return Err(format!(
                "cansmc {name}: cycle_time_us {} is below 100 µs",
                self.cycle_time_us
            ));
        }
        if self.t_int_us >= self.cycle_time_us {
            return Err(format!(
                "cansmc {name}: t_int_us {} must be shorter than the cycle ({} µs)",
                self.t_int_us, self.cycle_time_us
            ));
        }
        if self.connect_attempts == 0
            || self.lost_after == 0
            || self.connect_timeout_ms == 0
            || self.parameter_timeout_ms == 0
        {
            return Err(format!(
                "cansmc {name}: connect_attempts, lost_after, connect_timeout_ms and \
                 parameter_timeout_ms must be positive"
            ));
        }
        if u64::from(self.handover_grace_ms) * 1000 > 14 * u64::from(self.cycle_time_us) {
            return Err(format!(
                "cansmc {name}: handover_grace_ms {} is longer than 14 cycles ({} ms): the cycle \
                 counter's 16 values could no longer tell the open cycles apart",
                self.handover_grace_ms,
                14 * u64::from(self.cycle_time_us) / 1000
            ));
        }
        if self.rt_priority > 99 {
            return Err(format!(
                "cansmc {name}: rt_priority {} must be 0 (off) or 1..=99",
                self.rt_priority
            ));
        }
        if self.slaves.is_empty() {
            return Err(format!(
                "cansmc {name}: configure at least one [[cansmc.slave]]"
            ));
        }
        let mut addresses = HashSet::new();
        for s in &self.slaves {
            SmcAddress::new(s.address).map_err(|e| format!("cansmc {name}: {e}"))?;
            if !addresses.insert(s.address) {
                return Err(format!(
                    "cansmc {name}: slave address {} is configured twice",
                    s.address
                ));
            }
        }
        // One MDT and one DT per slave plus the parameter slot.
        let mut cycle = CycleConfig::new(
            self.effective_bitrate(buses),
            self.slaves.len() as u32 + 1,
            self.cycle_time_us,
        );
        cycle.t_int_us = self.t_int_us;
        let report = cycle.check().map_err(|e| format!("cansmc {name}: {e}"))?;
        // The slot is not an address: only the bus time counts here (the
        // addresses are unique in 1..=61 anyway).
        if report.problems.contains(&Infeasibility::BusTime) {
            return Err(format!(
                "cansmc {name}: {} slaves (+1 parameter slot) do not fit a {} µs cycle:\n{report}",
                self.slaves.len(),
                self.cycle_time_us
            ));
        }
        let mut axis_slaves = HashSet::new();
        for a in &self.axes {
            let an = &a.name;
            if an.is_empty() || an.contains(char::is_whitespace) {
                return Err(format!("axis name {an:?} must be non-empty without spaces"));
            }
            if !addresses.contains(&a.address) {
                return Err(format!(
                    "axis {an}: slave {} is not configured under cansmc {name}",
                    a.address
                ));
            }
            if !axis_slaves.insert(a.address) {
                return Err(format!(
                    "axis {an}: slave {} already backs another axis",
                    a.address
                ));
            }
            a.common.validate(an)?;
            if a.counts_per_rev == 0 {
                return Err(format!("axis {an}: counts_per_rev must be positive"));
            }
            if let Some(src) = a.gear_source {
                if !addresses.contains(&src) {
                    return Err(format!(
                        "axis {an}: gear_source {src} is not a slave of cansmc {name}"
                    ));
                }
                if src == a.address {
                    return Err(format!("axis {an}: an axis cannot be geared to itself"));
                }
                if !(a.gear_ratio.is_finite() && a.gear_ratio != 0.0) {
                    return Err(format!("axis {an}: gear_ratio must be a non-zero number"));
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use crate::config::Config;

    fn config(cycle_us: u32, slaves: u8, extra: &str) -> String {
        let mut t = format!(
            "[[bus]]\nname = \"smc0\"\nbackend = \"virtual\"\nbitrate = 1000000\n\
             [[bus]]\nname = \"smc1\"\nbackend = \"virtual\"\nbitrate = 1000000\n\
             [[cansmc]]\nname = \"m\"\ncommand_bus = \"smc0\"\nstatus_bus = \"smc1\"\n\
             cycle_time_us = {cycle_us}\n"
        );
        for a in 1..=slaves {
            t.push_str(&format!("[[cansmc.slave]]\naddress = {a}\n"));
        }
        t.push_str(extra);
        t
    }

    #[test]
    fn the_papers_slave_counts_are_accepted_and_an_overload_is_refused_with_the_arithmetic() {
        for (cycle, n) in [(2000, 10), (4000, 20), (8000, 40), (16000, 61)] {
            Config::from_toml(&config(cycle, n, "")).unwrap();
        }
        let e = Config::from_toml(&config(2000, 15, ""))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("15 slaves (+1 parameter slot) do not fit a 2000 µs cycle"),
            "{e}"
        );
        assert!(e.contains("135 bits") && e.contains("NOT feasible"), "{e}");
    }

    #[test]
    fn bad_cansmc_configurations_are_refused_with_a_reason() {
        let cases = [
            (
                config(2000, 2, "[[cansmc.slave]]\naddress = 2\n"),
                "slave address 2 is configured twice",
            ),
            (
                config(2000, 1, "[[cansmc.slave]]\naddress = 62\n"),
                "outside 1..=61",
            ),
            (
                config(
                    2000,
                    2,
                    "[[cansmc.axis]]\nname = \"A\"\naddress = 1\ncounts_per_unit = 1.0\n\
                     max_velocity = 1.0\nmax_acceleration = 1.0\ngear_source = 1\n",
                ),
                "cannot be geared to itself",
            ),
            (
                config(
                    2000,
                    1,
                    "[[cansmc.axis]]\nname = \"A\"\naddress = 5\ncounts_per_unit = 1.0\n\
                     max_velocity = 1.0\nmax_acceleration = 1.0\n",
                ),
                "slave 5 is not configured under cansmc m",
            ),
            (config(50, 1, ""), "below 100 µs"),
        ];
        for (text, want) in cases {
            let e = Config::from_toml(&text).unwrap_err().to_string();
            assert!(e.contains(want), "{want:?} not in {e}");
        }
    }

    #[test]
    fn the_hand_over_grace_is_at_most_fourteen_cycles() {
        let with_grace = |ms: u32| {
            config(4000, 1, "").replace(
                "cycle_time_us = 4000\n",
                &format!("cycle_time_us = 4000\nhandover_grace_ms = {ms}\n"),
            )
        };
        let c = Config::from_toml(&with_grace(56)).unwrap();
        assert_eq!(c.cansmc[0].handover_grace_ms, 56);
        let e = Config::from_toml(&with_grace(57)).unwrap_err().to_string();
        assert!(e.contains("longer than 14 cycles (56 ms)"), "{e}");
        let c = Config::from_toml(&config(4000, 1, "")).unwrap();
        assert_eq!(c.cansmc[0].handover_grace_ms, 10);
    }
}
