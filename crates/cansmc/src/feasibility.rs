//! Does a CANsmc configuration fit its cycle?
//!
//! # The arithmetic
//!
//! Worst-case length of a classic standard data frame with `n` data bytes
//! (spec, "Bus arithmetic"): `47 + 8n` bits (SOF, 11-bit id, RTR, IDE, r0,
//! DLC, data, 15-bit CRC, delimiters, ACK, 7-bit EOF and 3 bits interframe
//! space) plus at most `floor((34 + 8n - 1) / 4)` stuff bits (the stuffed
//! region is SOF..CRC, `34 + 8n` bits). That gives 111 + 24 = 135 bits for
//! 8 bytes and 47 + 8 = 55 bits for MST, as in the spec.
//!
//! One cycle (phase P2), measured from the start of MST on channel 0:
//!
//! ```text
//! ch0: |MST|--- T_int ---|MDT1|MDT2| ... |MDTn|
//! ch1:                        |r|DT1 |r|DT2| ... |r|DTn|-- guard --|
//!                                                      ^ last DT ends  ^ T_end_m
//! ```
//!
//! - `T_int` is the time after MST during which the application computes the
//!   cycle's command values; MDTs start at `T_int_end = MST + T_int`.
//! - The MDTs go back to back on channel 0 (`n × 135 µs`).
//! - Each slave answers its MDT after a response latency `r` with a DT on
//!   channel 1, so slave i's DT overlaps slave i+1's MDT. Channel 1 is a
//!   work-conserving queue whose i-th job is released at most
//!   `i × frame + r` after `T_int_end`; with n equal jobs it is empty at the
//!   latest `(n + 1) × frame + r` after `T_int_end`. (If actual MDTs are
//!   shorter than worst case the DTs may queue, but this bound still holds.)
//! - A guard time must remain before the cycle ends, so that the last DT
//!   reaches the master before `T_end_m` despite clock jitter.
//!
//! Hence the condition:
//! `MST + T_int + (n + 1) × frame8 + r + guard ≤ cycle time`, and
//! `n ≤ 61` (the address space).
//!
//! # Margin compared with the paper
//!
//! The paper publishes, at 1 Mbit/s, 10 / 20 / 40 / 61 slaves for
//! 2 / 4 / 8 / 16 ms. With the defaults here (`T_int` = 100 µs, `r` = 20 µs,
//! guard = 100 µs) [`max_slaves`] gives 11 / 26 / 56 / 61. The paper's
//! figures scale at about 200 µs per slave (5 slaves per ms) against 135 µs
//! of bus time per slave, so the published table keeps roughly a third of
//! the bus free — presumably for slave processing time, acyclic parameter
//! telegrams and software latency, which the paper does not quantify.
//! 16 ms is limited by the 61 addresses, not by bus time (bus time alone
//! would allow 115). Every published row is therefore feasible here, and
//! the extra headroom is the difference between the paper's conservative
//! sizing and the pure worst-case bus arithmetic.

use std::fmt;

use crate::telegram::{SmcAddress, TELEGRAM_LEN};

/// Default application time after MST (`T_int`), µs.
pub const DEFAULT_T_INT_US: u32 = 100;
/// Default slave response latency from the end of its MDT to the start of
/// its DT, µs.
pub const DEFAULT_RESPONSE_US: u32 = 20;
/// Default guard time before the end of the cycle, µs.
pub const DEFAULT_GUARD_US: u32 = 100;

/// Worst-case bits on the wire (including stuff bits and 3 bits of
/// interframe space) of a classic standard-id data frame with `data_len`
/// bytes (0..=8).
pub fn frame_bits_worst_case(data_len: usize) -> u32 {
    let n = data_len.min(8) as u32;
    let nominal = 47 + 8 * n;
    let stuffed_region = 34 + 8 * n;
    nominal + (stuffed_region - 1) / 4
}

/// Time of `bits` at `bitrate`, in ns, rounded up.
fn bits_ns(bits: u32, bitrate: u32) -> u64 {
    (u64::from(bits) * 1_000_000_000).div_ceil(u64::from(bitrate))
}

/// Why a configuration cannot even be evaluated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FeasibilityError {
    /// The bit rate is 0.
    #[error("bit rate must be positive")]
    ZeroBitrate,
    /// The cycle time is 0.
    #[error("cycle time must be positive")]
    ZeroCycleTime,
}

/// A CANsmc cycle configuration to check.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CycleConfig {
    /// Bit rate of both channels, bit/s.
    pub bitrate: u32,
    /// Number of slaves (one MDT and one DT each per cycle).
    pub slaves: u32,
    /// Cycle time, µs.
    pub cycle_time_us: u32,
    /// Application time after MST before the first MDT (`T_int`), µs.
    pub t_int_us: u32,
    /// Slave response latency, end of MDT to start of DT, µs.
    pub response_us: u32,
    /// Guard time between the last DT and the end of the cycle, µs.
    pub guard_us: u32,
}

impl CycleConfig {
    /// A configuration with the default `T_int`, response latency and guard.
    pub fn new(bitrate: u32, slaves: u32, cycle_time_us: u32) -> Self {
        CycleConfig {
            bitrate,
            slaves,
            cycle_time_us,
            t_int_us: DEFAULT_T_INT_US,
            response_us: DEFAULT_RESPONSE_US,
            guard_us: DEFAULT_GUARD_US,
        }
    }

    /// Computes the cycle's timing.
    pub fn check(&self) -> Result<FeasibilityReport, FeasibilityError> {
        if self.bitrate == 0 {
            return Err(FeasibilityError::ZeroBitrate);
        }
        if self.cycle_time_us == 0 {
            return Err(FeasibilityError::ZeroCycleTime);
        }
        let us = |v: u32| u64::from(v) * 1_000;
        let mst_bits = frame_bits_worst_case(0);
        let telegram_bits = frame_bits_worst_case(TELEGRAM_LEN);
        let mst_ns = bits_ns(mst_bits, self.bitrate);
        let telegram_ns = bits_ns(telegram_bits, self.bitrate);
        let n = u64::from(self.slaves);
        let t_int_end_ns = mst_ns + us(self.t_int_us);
        let mdts_end_ns = t_int_end_ns + n * telegram_ns;
        let last_dt_end_ns = if n == 0 {
            t_int_end_ns
        } else {
            t_int_end_ns + (n + 1) * telegram_ns + us(self.response_us)
        };
        let required_ns = last_dt_end_ns + us(self.guard_us);
        let cycle_ns = us(self.cycle_time_us);
        let mut problems = Vec::new();
        if required_ns > cycle_ns {
            problems.push(Infeasibility::BusTime);
        }
        if self.slaves > u32::from(SmcAddress::MAX) {
            problems.push(Infeasibility::TooManySlaves);
        }
        Ok(FeasibilityReport {
            config: *self,
            mst_bits,
            telegram_bits,
            mst_ns,
            telegram_ns,
            t_int_end_ns,
            mdts_end_ns,
            last_dt_end_ns,
            required_ns,
            cycle_ns,
            problems,
        })
    }
}

/// Why a configuration does not fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Infeasibility {
    /// The traffic plus `T_int` and guard exceed the cycle time.
    BusTime,
    /// More than 61 slaves: there are not enough addresses.
    TooManySlaves,
}

/// The result of [`CycleConfig::check`]. Times are ns from the start of MST.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FeasibilityReport {
    /// The configuration checked.
    pub config: CycleConfig,
    /// Worst-case MST length, bits.
    pub mst_bits: u32,
    /// Worst-case length of an 8-byte telegram (MDT or DT), bits.
    pub telegram_bits: u32,
    /// MST duration.
    pub mst_ns: u64,
    /// MDT/DT duration.
    pub telegram_ns: u64,
    /// `T_int_end`: the first MDT starts here.
    pub t_int_end_ns: u64,
    /// The last MDT ends here (channel 0 idle afterwards).
    pub mdts_end_ns: u64,
    /// The last DT ends here at the latest (channel 1).
    pub last_dt_end_ns: u64,
    /// `last_dt_end_ns` plus the guard time.
    pub required_ns: u64,
    /// The cycle time.
    pub cycle_ns: u64,
    /// Empty when feasible.
    pub problems: Vec<Infeasibility>,
}

impl FeasibilityReport {
    /// True if the configuration fits.
    pub fn is_feasible(&self) -> bool {
        self.problems.is_empty()
    }

    /// Cycle time left over (negative when over budget), ns.
    pub fn slack_ns(&self) -> i64 {
        self.cycle_ns as i64 - self.required_ns as i64
    }

    /// Share of the cycle channel 1 is busy with DTs, 0..=1 (may exceed 1).
    pub fn status_load(&self) -> f64 {
        (u64::from(self.config.slaves) * self.telegram_ns) as f64 / self.cycle_ns as f64
    }
}

impl fmt::Display for FeasibilityReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let c = &self.config;
        let us = |ns: u64| ns as f64 / 1000.0;
        writeln!(
            f,
            "CANsmc cycle: {} slaves, {} µs cycle, {} bit/s",
            c.slaves, c.cycle_time_us, c.bitrate
        )?;
        writeln!(
            f,
            "  MST  {} bits = {:.3} µs; MDT/DT {} bits = {:.3} µs (worst-case stuffing, incl. IFS)",
            self.mst_bits,
            us(self.mst_ns),
            self.telegram_bits,
            us(self.telegram_ns)
        )?;
        writeln!(
            f,
            "  T_int_end = MST {:.3} + T_int {} = {:.3} µs",
            us(self.mst_ns),
            c.t_int_us,
            us(self.t_int_end_ns)
        )?;
        writeln!(
            f,
            "  MDTs end  = {:.3} + {} x {:.3} = {:.3} µs (channel 0)",
            us(self.t_int_end_ns),
            c.slaves,
            us(self.telegram_ns),
            us(self.mdts_end_ns)
        )?;
        writeln!(
            f,
            "  last DT   = {:.3} + ({} + 1) x {:.3} + response {} = {:.3} µs (channel 1, DT i overlaps MDT i+1)",
            us(self.t_int_end_ns),
            c.slaves,
            us(self.telegram_ns),
            c.response_us,
            us(self.last_dt_end_ns)
        )?;
        writeln!(
            f,
            "  required  = {:.3} + guard {} = {:.3} µs of {:.3} µs; slack {:.3} µs",
            us(self.last_dt_end_ns),
            c.guard_us,
            us(self.required_ns),
            us(self.cycle_ns),
            self.slack_ns() as f64 / 1000.0
        )?;
        if self.is_feasible() {
            write!(f, "  feasible")
        } else {
            let why: Vec<&str> = self
                .problems
                .iter()
                .map(|p| match p {
                    Infeasibility::BusTime => "does not fit the cycle time",
                    Infeasibility::TooManySlaves => "more than 61 slaves",
                })
                .collect();
            write!(f, "  NOT feasible: {}", why.join(", "))
        }
    }
}

/// The largest slave count (at most 61) that fits `template`'s bit rate,
/// cycle time, `T_int`, response latency and guard time (its `slaves` field
/// is ignored). 0 if not even one slave fits.
pub fn max_slaves(template: CycleConfig) -> Result<u32, FeasibilityError> {
    let mut best = 0;
    for n in 1..=u32::from(SmcAddress::MAX) {
        let report = CycleConfig {
            slaves: n,
            ..template
        }
        .check()?;
        if report.is_feasible() {
            best = n;
        } else {
            break;
        }
    }
    // Surface configuration errors even when the loop did not run them.
    template.check()?;
    Ok(best)
}
