//! The CANsmc verbs of the `cangate` CLI: `cangate smc …` over the `Cansmc`
//! service (`proto/cangate/v1/cansmc.proto`).
//!
//! A master argument is optional everywhere: without it the gateway's only
//! master is meant (the server resolves the empty name, and says so when
//! there are several).

use crate::cli_common::{Rpc, ctrl_c, positive, sleep_opt, status_error, time_text};
use anyhow::{Context, Result, bail};
use cangate_client::{Client, pb};
use clap::{Args, Subcommand};
use serde_json::{Value, json};
use std::io::Write;
use std::time::{Duration, Instant};

/// How long `smc restart` waits for the master to be back in P2.
const RESTART_WAIT: Duration = Duration::from_secs(15);

/// Extra help of `cangate smc`, shown after the options.
pub const SMC_HELP: &str = "\
Forms:
  cangate smc [list]                                   table of masters
  cangate smc status [MASTER]                          phase, counters, jitter, slaves
  cangate smc param get ADDRESS NUMBER [--master M]    read a slave parameter
  cangate smc param set ADDRESS NUMBER VALUE [--master M]
  cangate smc restart [MASTER]                         back through P0/P1, waits for P2
  cangate smc watch [MASTER] [--interval-ms N] [--for SECONDS]

MASTER defaults to the gateway's only master. Parameter numbers and values
take decimal or 0x hex (standard parameters: 1 position feedback, 2
velocity unit, 3 encoder resolution (read-only), 4 following error limit,
5 maximum velocity). Status word flags: RDY ready, EN enabled, FLT fault,
POS target reached, HOM homed, FE following error, PE parameter error.
Slave counters: DTS valid DTs, MISSED cycles without a DT, LATE DTs after
their cycle, MISMATCH wrong counter echo, REJ rejects, MALF malformed,
LOSSES times lost, MISS consecutive misses now.

watch prints the master's events (phase changes, slaves connecting, lost,
recovered) and one summary line per interval; with --json one JSON object
per update.";

/// `cangate smc …`
#[derive(Args, Debug, PartialEq)]
pub struct SmcArgs {
    /// What to do (default: `list`).
    #[command(subcommand)]
    pub verb: Option<SmcVerb>,
}

/// The verbs of `cangate smc`.
#[derive(Subcommand, Debug, PartialEq)]
pub enum SmcVerb {
    /// Table of masters: phase, cycle time, buses, slaves, axes.
    List,
    /// One master in detail: phase, counters, cycle jitter and a table of
    /// its slaves.
    Status {
        /// Master name (default: the only master).
        master: Option<String>,
    },
    /// Read or write a slave parameter.
    Param {
        #[command(subcommand)]
        verb: ParamVerb,
    },
    /// Restart a master through P0/P1; waits until it is back in P2 (or
    /// failed to start).
    Restart {
        /// Master name (default: the only master).
        master: Option<String>,
    },
    /// The master's events and a summary line every interval, until
    /// Ctrl-C.
    Watch(WatchArgs),
}

/// The verbs of `cangate smc param`.
#[derive(Subcommand, Debug, PartialEq)]
pub enum ParamVerb {
    /// Read a parameter: `cangate smc param get 1 3`.
    Get {
        /// Slave address 1..=61.
        address: u32,
        /// Parameter number (decimal or 0x hex).
        #[arg(value_parser = number)]
        number: u32,
        /// Master name (default: the only master).
        #[arg(long)]
        master: Option<String>,
    },
    /// Write a parameter: `cangate smc param set 1 4 30000`.
    Set {
        /// Slave address 1..=61.
        address: u32,
        /// Parameter number (decimal or 0x hex).
        #[arg(value_parser = number)]
        number: u32,
        /// Value (decimal, may be negative, or 0x hex).
        #[arg(value_parser = value, allow_negative_numbers = true)]
        value: i32,
        /// Master name (default: the only master).
        #[arg(long)]
        master: Option<String>,
    },
}

/// `smc watch [MASTER] …`
#[derive(Args, Debug, PartialEq)]
pub struct WatchArgs {
    /// Master name (default: the only master).
    pub master: Option<String>,
    /// Period of the summary lines in ms (50..=60000).
    #[arg(long, value_name = "N", default_value_t = 1000,
          value_parser = clap::value_parser!(u32).range(50..=60_000))]
    pub interval_ms: u32,
    /// End after this many seconds.
    #[arg(long = "for", value_name = "SECONDS", value_parser = positive)]
    pub for_secs: Option<f64>,
}

/// A parameter number: decimal or 0x hex, 0..=65535.
fn number(text: &str) -> Result<u32, String> {
    let n = parse_int(text).ok_or_else(|| format!("{text:?} is not a number"))?;
    u16::try_from(n)
        .map(u32::from)
        .map_err(|_| format!("{text:?} is not a parameter number 0..=65535"))
}

/// A parameter value: decimal (signed) or 0x hex (the 32 bits as written).
fn value(text: &str) -> Result<i32, String> {
    let n = parse_int(text).ok_or_else(|| format!("{text:?} is not a number"))?;
    if let Some(hex) = text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        return u32::from_str_radix(hex, 16)
            .map(|v| v as i32)
            .map_err(|_| format!("{text:?} does not fit 32 bits"));
    }
    i32::try_from(n).map_err(|_| format!("{text:?} does not fit a 32-bit signed value"))
}

fn parse_int(text: &str) -> Option<i64> {
    match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => i64::from_str_radix(hex, 16).ok(),
        None => text.parse().ok(),
    }
}

// ------------------------------------------------------------- formatting

fn phase_name(p: i32) -> &'static str {
    match pb::CansmcPhase::try_from(p) {
        Ok(pb::CansmcPhase::Idle) => "idle",
        Ok(pb::CansmcPhase::P0) => "P0",
        Ok(pb::CansmcPhase::P1) => "P1",
        Ok(pb::CansmcPhase::P2) => "P2",
        Ok(pb::CansmcPhase::Failed) => "failed",
        _ => "unknown",
    }
}

fn state_name(s: i32) -> &'static str {
    match pb::CansmcSlaveState::try_from(s) {
        Ok(pb::CansmcSlaveState::Connecting) => "connecting",
        Ok(pb::CansmcSlaveState::Connected) => "connected",
        Ok(pb::CansmcSlaveState::Missing) => "missing",
        Ok(pb::CansmcSlaveState::Operational) => "operational",
        Ok(pb::CansmcSlaveState::Lost) => "lost",
        _ => "unknown",
    }
}

fn bitrate_text(b: u32) -> String {
    if b == 0 {
        "-".into()
    } else if b.is_multiple_of(1000) {
        format!("{}k", b / 1000)
    } else {
        b.to_string()
    }
}

/// `0x101B RDY EN POS HOM` (the raw word, then the flags set).
pub fn status_word_text(w: &pb::CansmcStatusWord) -> String {
    let mut s = format!("0x{:04X}", w.raw);
    for (set, name) in [
        (w.ready, "RDY"),
        (w.enabled, "EN"),
        (w.fault, "FLT"),
        (w.target_reached, "POS"),
        (w.homed, "HOM"),
        (w.following_error, "FE"),
        (w.parameter_error, "PE"),
    ] {
        if set {
            s.push(' ');
            s.push_str(name);
        }
    }
    s
}

fn hex16(v: Option<u32>) -> String {
    v.map_or_else(|| "-".into(), |v| format!("0x{v:04X}"))
}

/// `cycles 123  overruns 0  …`
pub fn master_counters_text(c: &pb::CansmcMasterCounters) -> String {
    format!(
        "cycles {}  overruns {}  MDT slots missed {}  foreign frames {}  stray parameter answers {}",
        c.cycles, c.overruns, c.mdt_slots_missed, c.foreign_frames, c.stray_parameter_answers
    )
}

fn us(v: f64) -> String {
    if v >= 100.0 || v.fract() == 0.0 {
        format!("{v:.0} µs")
    } else {
        format!("{v:.1} µs")
    }
}

/// `4000 samples  p50 3 µs  p99 25 µs  p99.9 80 µs  max 310 µs  mean 4.1 µs`
pub fn jitter_text(j: &pb::CycleJitter) -> String {
    if j.samples == 0 {
        return "no samples yet".into();
    }
    format!(
        "{} samples  p50 {}  p99 {}  p99.9 {}  max {}  mean {}",
        j.samples,
        us(j.p50_us),
        us(j.p99_us),
        us(j.p999_us),
        us(j.max_us),
        us(j.mean_us)
    )
}

/// The slave table of `smc status`.
pub fn slave_table(slaves: &[pb::CansmcSlave]) -> String {
    let name_w = slaves
        .iter()
        .map(|s| s.name.chars().count())
        .max()
        .unwrap_or(0)
        .clamp(4, 40);
    let axis_w = slaves
        .iter()
        .map(|s| s.axis.chars().count())
        .max()
        .unwrap_or(0)
        .max(4);
    let mut out = format!(
        "{:>4} {:<name_w$} {:<3} {:<11} {:<axis_w$} {:<6} {:<8} {:<24} {:>9} {:>6} {:>5} {:>8} {:>4} {:>4} {:>6} {:>4}\n",
        "ADDR",
        "NAME",
        "REQ",
        "STATE",
        "AXIS",
        "DEVICE",
        "FIRMWARE",
        "STATUS",
        "DTS",
        "MISSED",
        "LATE",
        "MISMATCH",
        "REJ",
        "MALF",
        "LOSSES",
        "MISS",
    );
    for s in slaves {
        let c = s.counters.unwrap_or_default();
        let name: String = s.name.chars().take(name_w).collect();
        out.push_str(&format!(
            "{:>4} {:<name_w$} {:<3} {:<11} {:<axis_w$} {:<6} {:<8} {:<24} {:>9} {:>6} {:>5} {:>8} {:>4} {:>4} {:>6} {:>4}\n",
            s.address,
            if name.is_empty() { "-" } else { &name },
            if s.required { "yes" } else { "no" },
            state_name(s.state),
            if s.axis.is_empty() { "-" } else { &s.axis },
            hex16(s.device_type),
            hex16(s.firmware_version),
            s.status_word
                .as_ref()
                .map_or_else(|| "-".into(), status_word_text),
            c.dts,
            c.missed,
            c.late,
            c.counter_mismatch,
            c.rejects,
            c.malformed,
            c.losses,
            s.consecutive_misses,
        ));
    }
    out
}

/// `smc status` as text.
pub fn status_text(st: &pb::CansmcStatus) -> String {
    let mut out = format!(
        "{}: phase {}  cycle {}  cycle time {} µs  {} bit/s  starts {}\n",
        st.master,
        phase_name(st.phase),
        st.cycle,
        st.cycle_time_us,
        bitrate_text(st.bitrate),
        st.starts
    );
    if let Some(e) = &st.start_error {
        out.push_str(&format!("start error: {e}\n"));
    }
    out.push_str(&format!(
        "master:  {}\n",
        master_counters_text(&st.counters.unwrap_or_default())
    ));
    out.push_str(&format!(
        "jitter:  {}\n",
        jitter_text(&st.jitter.unwrap_or_default())
    ));
    out.push_str(&slave_table(&st.slaves));
    out
}

fn status_word_json(w: &pb::CansmcStatusWord) -> Value {
    json!({
        "raw": w.raw,
        "ready": w.ready,
        "enabled": w.enabled,
        "fault": w.fault,
        "target_reached": w.target_reached,
        "homed": w.homed,
        "following_error": w.following_error,
        "parameter_error": w.parameter_error,
        "counter_echo": w.counter_echo,
    })
}

/// A status as JSON (enum names as text).
pub fn status_json(st: &pb::CansmcStatus) -> Value {
    let c = st.counters.unwrap_or_default();
    let j = st.jitter.unwrap_or_default();
    json!({
        "master": st.master,
        "phase": phase_name(st.phase),
        "cycle": st.cycle,
        "cycle_time_us": st.cycle_time_us,
        "bitrate": st.bitrate,
        "start_error": st.start_error,
        "starts": st.starts,
        "counters": {
            "cycles": c.cycles,
            "overruns": c.overruns,
            "mdt_slots_missed": c.mdt_slots_missed,
            "foreign_frames": c.foreign_frames,
            "stray_parameter_answers": c.stray_parameter_answers,
        },
        "jitter": {
            "samples": j.samples,
            "p50_us": j.p50_us,
            "p99_us": j.p99_us,
            "p999_us": j.p999_us,
            "max_us": j.max_us,
            "mean_us": j.mean_us,
        },
        "slaves": st.slaves.iter().map(|s| {
            let c = s.counters.unwrap_or_default();
            json!({
                "address": s.address,
                "name": s.name,
                "required": s.required,
                "state": state_name(s.state),
                "device_type": s.device_type,
                "firmware_version": s.firmware_version,
                "status_word": s.status_word.as_ref().map(status_word_json),
                "counters": {
                    "dts": c.dts,
                    "missed": c.missed,
                    "late": c.late,
                    "counter_mismatch": c.counter_mismatch,
                    "rejects": c.rejects,
                    "malformed": c.malformed,
                    "losses": c.losses,
                    "mdts": c.mdts,
                },
                "consecutive_misses": s.consecutive_misses,
                "axis": (!s.axis.is_empty()).then_some(&s.axis),
            })
        }).collect::<Vec<_>>(),
        "timestamp_us": st.timestamp_us,
    })
}

fn master_json(m: &pb::CansmcMasterInfo) -> Value {
    json!({
        "name": m.name,
        "command_bus": m.command_bus,
        "status_bus": m.status_bus,
        "cycle_time_us": m.cycle_time_us,
        "phase": phase_name(m.phase),
        "bitrate": m.bitrate,
        "slave_addresses": m.slave_addresses,
        "axes": m.axes,
    })
}

fn event_text(e: &pb::CansmcEvent) -> String {
    use pb::cansmc_event::Event;
    match &e.event {
        Some(Event::Phase(p)) => format!("phase {}", phase_name(*p)),
        Some(Event::Slave(s)) => format!("slave {}: {}", s.address, s.what),
        None => "?".into(),
    }
}

fn event_json(e: &pb::CansmcEvent) -> Value {
    use pb::cansmc_event::Event;
    match &e.event {
        Some(Event::Phase(p)) => json!({"timestamp_us": e.timestamp_us, "phase": phase_name(*p)}),
        Some(Event::Slave(s)) => {
            json!({"timestamp_us": e.timestamp_us, "slave": s.address, "what": s.what})
        }
        None => json!({"timestamp_us": e.timestamp_us}),
    }
}

/// The totals a watch line compares with the previous update.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Totals {
    dts: u64,
    missed: u64,
    late: u64,
    mismatch: u64,
    rejects: u64,
    overruns: u64,
    slots_missed: u64,
}

impl Totals {
    /// Sums over the master and its slaves.
    pub fn of(st: &pb::CansmcStatus) -> Totals {
        let m = st.counters.unwrap_or_default();
        let mut t = Totals {
            overruns: m.overruns,
            slots_missed: m.mdt_slots_missed,
            ..Totals::default()
        };
        for s in &st.slaves {
            let c = s.counters.unwrap_or_default();
            t.dts += c.dts;
            t.missed += c.missed;
            t.late += c.late;
            t.mismatch += c.counter_mismatch;
            t.rejects += c.rejects;
        }
        t
    }
}

/// One summary line of `smc watch`: totals, with the change since the
/// previous update in parentheses.
pub fn watch_line(st: &pb::CansmcStatus, prev: Option<Totals>) -> String {
    let t = Totals::of(st);
    let d = |now: u64, before: fn(&Totals) -> u64| match prev {
        Some(p) => format!("{now} (+{})", now.saturating_sub(before(&p))),
        None => now.to_string(),
    };
    let operational = st
        .slaves
        .iter()
        .filter(|s| s.state == pb::CansmcSlaveState::Operational as i32)
        .count();
    let mut line = format!(
        "{}  {}  {}  cycle {}  slaves {}/{} operational  DTs {}  missed {}  late {}  mismatch {}  rejects {}  overruns {}  slots missed {}  jitter p99 {} max {}",
        time_text(st.timestamp_us),
        st.master,
        phase_name(st.phase),
        st.cycle,
        operational,
        st.slaves.len(),
        d(t.dts, |p| p.dts),
        d(t.missed, |p| p.missed),
        d(t.late, |p| p.late),
        d(t.mismatch, |p| p.mismatch),
        d(t.rejects, |p| p.rejects),
        d(t.overruns, |p| p.overruns),
        d(t.slots_missed, |p| p.slots_missed),
        us(st.jitter.unwrap_or_default().p99_us),
        us(st.jitter.unwrap_or_default().max_us),
    );
    for s in &st.slaves {
        if s.state != pb::CansmcSlaveState::Operational as i32 {
            line.push_str(&format!("  [slave {} {}]", s.address, state_name(s.state)));
        }
    }
    if let Some(e) = &st.start_error {
        line.push_str(&format!("  start error: {e}"));
    }
    line
}

// -------------------------------------------------------------- commands

/// `cangate smc …`
pub async fn run(client: &Client, as_json: bool, args: SmcArgs) -> Result<()> {
    match args.verb {
        None | Some(SmcVerb::List) => list(client, as_json).await,
        Some(SmcVerb::Status { master }) => status(client, as_json, master).await,
        Some(SmcVerb::Param { verb }) => param(client, as_json, verb).await,
        Some(SmcVerb::Restart { master }) => restart(client, as_json, master).await,
        Some(SmcVerb::Watch(w)) => watch(client, as_json, w).await,
    }
}

/// The name to show in messages before the server told us.
fn label(master: &Option<String>) -> &str {
    master.as_deref().unwrap_or("smc")
}

async fn get_status(client: &Client, master: &Option<String>) -> Result<pb::CansmcStatus> {
    client
        .cansmc_client()
        .get_status(pb::GetCansmcStatusRequest {
            master: master.clone().unwrap_or_default(),
        })
        .await
        .rpc()
        .with_context(|| format!("{}: status", label(master)))
}

/// `smc list`
async fn list(client: &Client, as_json: bool) -> Result<()> {
    let masters = client
        .cansmc_client()
        .list_masters(pb::ListMastersRequest {})
        .await
        .rpc()
        .context("list CANsmc masters")?
        .masters;
    let mut out = std::io::stdout().lock();
    if as_json {
        let list: Vec<_> = masters.iter().map(master_json).collect();
        writeln!(out, "{}", serde_json::to_string_pretty(&list)?)?;
        return Ok(());
    }
    writeln!(
        out,
        "{:<10} {:<7} {:>8} {:<16} {:>8} {:<16} AXES",
        "MASTER", "PHASE", "CYCLE", "BUSES (CH0/CH1)", "BITRATE", "SLAVES"
    )?;
    for m in &masters {
        let slaves = m
            .slave_addresses
            .iter()
            .map(u32::to_string)
            .collect::<Vec<_>>()
            .join(",");
        writeln!(
            out,
            "{:<10} {:<7} {:>8} {:<16} {:>8} {:<16} {}",
            m.name,
            phase_name(m.phase),
            format!("{} µs", m.cycle_time_us),
            format!("{}/{}", m.command_bus, m.status_bus),
            bitrate_text(m.bitrate),
            slaves,
            if m.axes.is_empty() {
                "-".to_string()
            } else {
                m.axes.join(",")
            }
        )?;
    }
    out.flush()?;
    Ok(())
}

/// `smc status [MASTER]`
async fn status(client: &Client, as_json: bool, master: Option<String>) -> Result<()> {
    let st = get_status(client, &master).await?;
    let mut out = std::io::stdout().lock();
    if as_json {
        writeln!(out, "{}", serde_json::to_string_pretty(&status_json(&st))?)?;
    } else {
        write!(out, "{}", status_text(&st))?;
    }
    out.flush()?;
    Ok(())
}

/// `smc param get|set …`
async fn param(client: &Client, as_json: bool, verb: ParamVerb) -> Result<()> {
    let mut smc = client.cansmc_client();
    let (r, what) = match verb {
        ParamVerb::Get {
            address,
            number,
            master,
        } => {
            let r = smc
                .read_parameter(pb::ReadParameterRequest {
                    master: master.clone().unwrap_or_default(),
                    address,
                    number,
                })
                .await
                .rpc()
                .with_context(|| {
                    format!(
                        "{}: read parameter {number} of slave {address}",
                        label(&master)
                    )
                })?;
            (r, "read")
        }
        ParamVerb::Set {
            address,
            number,
            value,
            master,
        } => {
            let r = smc
                .write_parameter(pb::WriteParameterRequest {
                    master: master.clone().unwrap_or_default(),
                    address,
                    number,
                    value,
                })
                .await
                .rpc()
                .with_context(|| {
                    format!(
                        "{}: write {value} to parameter {number} of slave {address}",
                        label(&master)
                    )
                })?;
            (r, "written")
        }
    };
    let mut out = std::io::stdout().lock();
    if as_json {
        writeln!(
            out,
            "{}",
            json!({
                "master": r.master,
                "address": r.address,
                "number": r.number,
                "value": r.value,
                "access": if what == "read" { "read" } else { "write" },
            })
        )?;
    } else {
        writeln!(
            out,
            "{} slave {} parameter {} = {} ({what})",
            r.master, r.address, r.number, r.value
        )?;
    }
    out.flush()?;
    Ok(())
}

/// `smc restart [MASTER]`: restarts, then waits for P2 or a failed start.
async fn restart(client: &Client, as_json: bool, master: Option<String>) -> Result<()> {
    let before = get_status(client, &master).await?;
    client
        .cansmc_client()
        .restart(pb::RestartRequest {
            master: master.clone().unwrap_or_default(),
        })
        .await
        .rpc()
        .with_context(|| format!("{}: restart", label(&master)))?;
    let t0 = Instant::now();
    let st = loop {
        let st = get_status(client, &master).await?;
        let settled =
            st.phase == pb::CansmcPhase::P2 as i32 || st.phase == pb::CansmcPhase::Failed as i32;
        if st.starts > before.starts && settled {
            break st;
        }
        if t0.elapsed() > RESTART_WAIT {
            bail!(
                "{}: still in phase {} {} s after the restart",
                st.master,
                phase_name(st.phase),
                RESTART_WAIT.as_secs()
            );
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    let mut out = std::io::stdout().lock();
    if as_json {
        writeln!(out, "{}", serde_json::to_string_pretty(&status_json(&st))?)?;
    } else {
        writeln!(
            out,
            "{}: restarted (start {}), phase {} after {:.1} s",
            st.master,
            st.starts,
            phase_name(st.phase),
            t0.elapsed().as_secs_f64()
        )?;
    }
    out.flush()?;
    if st.phase == pb::CansmcPhase::Failed as i32 {
        bail!(
            "{}: the start failed: {}",
            st.master,
            st.start_error.as_deref().unwrap_or("no reason given")
        );
    }
    Ok(())
}

/// `smc watch [MASTER]`
async fn watch(client: &Client, as_json: bool, args: WatchArgs) -> Result<()> {
    let WatchArgs {
        master,
        interval_ms,
        for_secs,
    } = args;
    let mut s = client
        .cansmc_client()
        .stream_cycle_stats(pb::StreamCycleStatsRequest {
            master: master.clone().unwrap_or_default(),
            interval_ms,
        })
        .await
        .rpc()
        .with_context(|| format!("{}: watch", label(&master)))?;
    let time_up = sleep_opt(for_secs);
    tokio::pin!(time_up);
    let stdout = std::io::stdout();
    let mut prev = None;
    loop {
        tokio::select! {
            m = s.message() => {
                let Some(u) = m.map_err(status_error).with_context(|| format!("{}: watch", label(&master)))? else {
                    return Ok(());
                };
                let st = u.status.unwrap_or_default();
                let mut out = stdout.lock();
                if as_json {
                    writeln!(out, "{}", json!({
                        "status": status_json(&st),
                        "events": u.events.iter().map(event_json).collect::<Vec<_>>(),
                        "events_lost": u.events_lost,
                    }))?;
                } else {
                    for e in &u.events {
                        writeln!(out, "{}  {}  {}", time_text(e.timestamp_us), st.master, event_text(e))?;
                    }
                    if u.events_lost > 0 {
                        writeln!(out, "{}  {}  [{} events lost: this client read too slowly]", time_text(st.timestamp_us), st.master, u.events_lost)?;
                    }
                    writeln!(out, "{}", watch_line(&st, prev))?;
                }
                out.flush()?;
                prev = Some(Totals::of(&st));
            }
            _ = ctrl_c() => return Ok(()),
            _ = &mut time_up => return Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Cli, Command};
    use clap::Parser;

    fn verb(argv: &[&str]) -> SmcVerb {
        let cli = Cli::try_parse_from(argv).unwrap_or_else(|e| panic!("{argv:?}: {e}"));
        match cli.command {
            Command::Smc(SmcArgs { verb: Some(v) }) => v,
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn parses_the_verbs() {
        let cli = Cli::try_parse_from(["cangate", "smc"]).unwrap();
        assert!(matches!(cli.command, Command::Smc(SmcArgs { verb: None })));
        assert_eq!(verb(&["cangate", "smc", "list"]), SmcVerb::List);
        assert_eq!(
            verb(&["cangate", "smc", "status"]),
            SmcVerb::Status { master: None }
        );
        assert_eq!(
            verb(&["cangate", "smc", "status", "smc"]),
            SmcVerb::Status {
                master: Some("smc".into())
            }
        );
        assert_eq!(
            verb(&["cangate", "smc", "restart", "m2"]),
            SmcVerb::Restart {
                master: Some("m2".into())
            }
        );
        assert_eq!(
            verb(&["cangate", "smc", "param", "get", "1", "3"]),
            SmcVerb::Param {
                verb: ParamVerb::Get {
                    address: 1,
                    number: 3,
                    master: None
                }
            }
        );
        assert_eq!(
            verb(&[
                "cangate", "smc", "param", "set", "2", "0x1000", "-5", "--master", "m2"
            ]),
            SmcVerb::Param {
                verb: ParamVerb::Set {
                    address: 2,
                    number: 0x1000,
                    value: -5,
                    master: Some("m2".into())
                }
            }
        );
        assert_eq!(
            verb(&["cangate", "smc", "param", "set", "1", "4", "0xFFFFFFFF"]),
            SmcVerb::Param {
                verb: ParamVerb::Set {
                    address: 1,
                    number: 4,
                    value: -1,
                    master: None
                }
            }
        );
        assert_eq!(
            verb(&[
                "cangate",
                "smc",
                "watch",
                "--interval-ms",
                "100",
                "--for",
                "2"
            ]),
            SmcVerb::Watch(WatchArgs {
                master: None,
                interval_ms: 100,
                for_secs: Some(2.0),
            })
        );
        assert_eq!(
            verb(&["cangate", "smc", "watch", "smc"]),
            SmcVerb::Watch(WatchArgs {
                master: Some("smc".into()),
                interval_ms: 1000,
                for_secs: None,
            })
        );
        let cli = Cli::try_parse_from(["cangate", "smc", "status", "--json"]).unwrap();
        assert!(cli.json);
        for bad in [
            &["cangate", "smc", "param", "get", "1"][..],
            &["cangate", "smc", "param", "get", "1", "70000"],
            &["cangate", "smc", "param", "get", "x", "3"],
            &["cangate", "smc", "param", "set", "1", "4"],
            &["cangate", "smc", "param", "set", "1", "4", "3000000000"],
            &["cangate", "smc", "watch", "--interval-ms", "10"],
            &["cangate", "smc", "watch", "--interval-ms", "70000"],
            &["cangate", "smc", "frobnicate"],
        ] {
            assert!(Cli::try_parse_from(bad).is_err(), "{bad:?}");
        }
    }

    fn slave(address: u32, state: pb::CansmcSlaveState) -> pb::CansmcSlave {
        pb::CansmcSlave {
            address,
            name: "A servo".into(),
            required: true,
            state: state as i32,
            device_type: Some(1),
            firmware_version: Some(0x0102),
            status_word: Some(pb::CansmcStatusWord {
                raw: 0x301B,
                ready: true,
                enabled: true,
                target_reached: true,
                homed: true,
                counter_echo: 3,
                ..Default::default()
            }),
            counters: Some(pb::CansmcSlaveCounters {
                dts: 1000,
                missed: 2,
                mdts: 1002,
                ..Default::default()
            }),
            consecutive_misses: 0,
            axis: "A".into(),
        }
    }

    fn status() -> pb::CansmcStatus {
        pb::CansmcStatus {
            master: "smc".into(),
            phase: pb::CansmcPhase::P2 as i32,
            cycle: 1234,
            cycle_time_us: 2000,
            bitrate: 1_000_000,
            start_error: None,
            starts: 1,
            counters: Some(pb::CansmcMasterCounters {
                cycles: 1235,
                ..Default::default()
            }),
            slaves: vec![
                slave(1, pb::CansmcSlaveState::Operational),
                slave(2, pb::CansmcSlaveState::Lost),
            ],
            jitter: Some(pb::CycleJitter {
                samples: 1234,
                p50_us: 3.0,
                p99_us: 25.0,
                p999_us: 80.0,
                max_us: 310.25,
                mean_us: 4.125,
            }),
            timestamp_us: 1_700_000_000_000_000,
        }
    }

    #[test]
    fn texts() {
        let st = status();
        assert_eq!(
            status_word_text(st.slaves[0].status_word.as_ref().unwrap()),
            "0x301B RDY EN POS HOM"
        );
        assert_eq!(
            jitter_text(st.jitter.as_ref().unwrap()),
            "1234 samples  p50 3 µs  p99 25 µs  p99.9 80 µs  max 310 µs  mean 4.1 µs"
        );
        assert_eq!(jitter_text(&pb::CycleJitter::default()), "no samples yet");
        let text = status_text(&st);
        assert!(
            text.starts_with(
                "smc: phase P2  cycle 1234  cycle time 2000 µs  1000k bit/s  starts 1\n"
            ),
            "{text}"
        );
        assert!(
            text.contains("\nmaster:  cycles 1235  overruns 0"),
            "{text}"
        );
        let rows: Vec<&str> = text.lines().skip(3).collect();
        assert_eq!(rows.len(), 3, "{text}");
        assert!(rows[0].starts_with("ADDR NAME"), "{text}");
        assert!(
            rows[1].contains("A servo") && rows[1].contains("operational"),
            "{text}"
        );
        assert!(
            rows[1].contains("0x0001") && rows[1].contains("0x0102"),
            "{text}"
        );
        assert!(rows[2].contains("lost"), "{text}");

        let line = watch_line(&st, None);
        assert!(
            line.starts_with("(1700000000.000000)  smc  P2  cycle 1234  slaves 1/2 operational  DTs 2000  missed 4"),
            "{line}"
        );
        assert!(line.ends_with("  [slave 2 lost]"), "{line}");
        let mut prev = Totals::of(&st);
        prev.dts -= 500;
        let line = watch_line(&st, Some(prev));
        assert!(line.contains("DTs 2000 (+500)  missed 4 (+0)"), "{line}");

        let j = status_json(&st);
        assert_eq!(j["phase"], "P2");
        assert_eq!(j["slaves"][0]["state"], "operational");
        assert_eq!(j["slaves"][0]["status_word"]["homed"], true);
        assert_eq!(j["slaves"][1]["counters"]["missed"], 2);
        assert_eq!(j["jitter"]["max_us"], 310.25);
        assert!(j["start_error"].is_null());
    }

    #[test]
    fn numbers_and_values() {
        assert_eq!(number("3"), Ok(3));
        assert_eq!(number("0x1000"), Ok(0x1000));
        assert!(number("65536").is_err());
        assert!(number("-1").is_err());
        assert_eq!(value("-30000"), Ok(-30000));
        assert_eq!(value("0x10"), Ok(16));
        assert_eq!(value("0x80000000"), Ok(i32::MIN));
        assert!(value("0x100000000").is_err());
        assert!(value("2147483648").is_err());
    }
}
