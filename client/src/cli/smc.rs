//! `cangate smc …`: CANsmc masters (`cansmc.proto`).
//!
//! A master argument is optional everywhere: without it the gateway's only
//! master is meant (the gateway resolves the empty name, and says so when
//! there are several).

use super::{
    App, Context, Failure, Result, ctrl_c, label, positive, print_json, sleep_opt, time_text,
};
use cangate_client::pb;
use clap::{Args, Subcommand};
use std::time::{Duration, Instant};

/// How long `smc restart` waits for the master to be back in P2.
const RESTART_WAIT: Duration = Duration::from_secs(15);

const SMC_HELP: &str = "\
Parameter numbers and values take decimal or 0x hex (standard parameters:
1 position feedback, 2 velocity unit, 3 encoder resolution (read-only), 4
following error limit, 5 maximum velocity). Status word flags: RDY ready,
EN enabled, FLT fault, POS target reached, HOM homed, FE following error,
PE parameter error. Slave counters: DTS valid DTs, MISSED cycles without a
DT, LATE DTs after their cycle, MISMATCH wrong counter echo, REJ rejects,
MALF malformed, LOSSES times lost, MISS consecutive misses now.";

/// `cangate smc …`
#[derive(Args, Debug)]
#[command(after_help = SMC_HELP)]
pub(crate) struct SmcArgs {
    #[command(subcommand)]
    verb: SmcVerb,
}

#[derive(Subcommand, Debug)]
enum SmcVerb {
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
    /// The master's events (phase changes, slaves connecting, lost,
    /// recovered) and a summary line every interval, until Ctrl-C.
    Watch {
        /// Master name (default: the only master).
        master: Option<String>,
        /// Period of the summary lines in ms (50..=60000).
        #[arg(long, value_name = "N", default_value_t = 1000,
              value_parser = clap::value_parser!(u32).range(50..=60_000))]
        interval_ms: u32,
        /// End after this many seconds.
        #[arg(long = "for", value_name = "SECONDS", value_parser = positive)]
        for_secs: Option<f64>,
    },
}

#[derive(Subcommand, Debug)]
enum ParamVerb {
    /// Read a parameter: `cangate smc param get 1 3`.
    Get {
        /// Slave address 1..=61.
        #[arg(value_parser = clap::value_parser!(u32).range(1..=61))]
        address: u32,
        /// Parameter number (decimal or 0x hex).
        #[arg(value_parser = number)]
        number: u32,
        /// Master name (default: the only master).
        #[arg(long)]
        master: Option<String>,
    },
    /// Write a parameter: `cangate smc param set 1 4 -30000`.
    Set {
        /// Slave address 1..=61.
        #[arg(value_parser = clap::value_parser!(u32).range(1..=61))]
        address: u32,
        /// Parameter number (decimal or 0x hex).
        #[arg(value_parser = number)]
        number: u32,
        /// Value (decimal, may be negative, or 0x hex for the 32 bits).
        #[arg(value_parser = value, allow_negative_numbers = true)]
        value: i32,
        /// Master name (default: the only master).
        #[arg(long)]
        master: Option<String>,
    },
}

fn parse_int(text: &str) -> Option<i64> {
    match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => i64::from_str_radix(hex, 16).ok(),
        None => text.parse().ok(),
    }
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
    if let Some(hex) = text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        return u32::from_str_radix(hex, 16)
            .map(|v| v as i32)
            .map_err(|_| format!("{text:?} does not fit 32 bits"));
    }
    let n = parse_int(text).ok_or_else(|| format!("{text:?} is not a number"))?;
    i32::try_from(n).map_err(|_| format!("{text:?} does not fit a 32-bit signed value"))
}

/// `idle`, `P0`, `P1`, `P2`, `failed`.
fn phase_name(p: i32) -> String {
    let l = label::<pb::CansmcPhase>(p);
    if l.starts_with('p') && l.len() == 2 {
        l.to_uppercase()
    } else {
        l
    }
}

fn state_name(s: i32) -> String {
    label::<pb::CansmcSlaveState>(s)
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
fn status_word_text(w: &pb::CansmcStatusWord) -> String {
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
fn master_counters_text(c: &pb::CansmcMasterCounters) -> String {
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
fn jitter_text(j: &pb::CycleJitter) -> String {
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
fn slave_table(slaves: &[pb::CansmcSlave]) -> String {
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
fn status_text(st: &pb::CansmcStatus) -> String {
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
        jitter_text(&st.jitter.clone().unwrap_or_default())
    ));
    out.push_str(&slave_table(&st.slaves));
    out
}

fn event_text(e: &pb::CansmcEvent) -> String {
    use pb::cansmc_event::Event;
    match &e.event {
        Some(Event::Phase(p)) => format!("phase {}", phase_name(*p)),
        Some(Event::Slave(s)) => format!("slave {}: {}", s.address, s.what),
        None => "?".into(),
    }
}

/// The totals a watch line compares with the previous update.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Totals {
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
    fn of(st: &pb::CansmcStatus) -> Totals {
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
fn watch_line(st: &pb::CansmcStatus, prev: Option<Totals>) -> String {
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
        us(st.jitter.as_ref().map_or(0.0, |j| j.p99_us)),
        us(st.jitter.as_ref().map_or(0.0, |j| j.max_us)),
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

/// The name to show in messages before the gateway told it.
fn name(master: &Option<String>) -> &str {
    master.as_deref().unwrap_or("the CANsmc master")
}

/// `cangate smc …`
pub(crate) async fn run(app: &App, args: SmcArgs) -> Result<()> {
    let c = &app.client;
    match args.verb {
        SmcVerb::List => {
            let masters = c
                .clone()
                .list_cansmc_masters()
                .await
                .ctx("listing the CANsmc masters")?;
            if app.json {
                return print_json(&pb::ListMastersResponse { masters });
            }
            let mut text = format!(
                "{:<10} {:<7} {:>8} {:<16} {:>8} {:<16} AXES",
                "MASTER", "PHASE", "CYCLE", "BUSES (CH0/CH1)", "BITRATE", "SLAVES"
            );
            for m in &masters {
                let slaves: Vec<String> = m.slave_addresses.iter().map(u32::to_string).collect();
                text.push_str(&format!(
                    "\n{:<10} {:<7} {:>8} {:<16} {:>8} {:<16} {}",
                    m.name,
                    phase_name(m.phase),
                    format!("{} µs", m.cycle_time_us),
                    format!("{}/{}", m.command_bus, m.status_bus),
                    bitrate_text(m.bitrate),
                    slaves.join(","),
                    if m.axes.is_empty() {
                        "-".to_string()
                    } else {
                        m.axes.join(",")
                    }
                ));
            }
            app.line(text)
        }
        SmcVerb::Status { master } => {
            let st = c
                .smc_status(master.as_deref().unwrap_or(""))
                .await
                .ctx(format!("status of {}", name(&master)))?;
            app.show(status_text(&st).trim_end(), &st)
        }
        SmcVerb::Param { verb } => {
            let (r, access) = match verb {
                ParamVerb::Get {
                    address,
                    number,
                    master,
                } => {
                    let req = pb::ReadParameterRequest {
                        master: master.clone().unwrap_or_default(),
                        address,
                        number,
                    };
                    let r = c
                        .call("ReadParameter", None, c.cansmc_client().read_parameter(req))
                        .await
                        .ctx(format!(
                            "{}: reading parameter {number} of slave {address}",
                            name(&master)
                        ))?;
                    (r, "read")
                }
                ParamVerb::Set {
                    address,
                    number,
                    value,
                    master,
                } => {
                    let req = pb::WriteParameterRequest {
                        master: master.clone().unwrap_or_default(),
                        address,
                        number,
                        value,
                    };
                    let r = c
                        .call(
                            "WriteParameter",
                            None,
                            c.cansmc_client().write_parameter(req),
                        )
                        .await
                        .ctx(format!(
                            "{}: writing {value} to parameter {number} of slave {address}",
                            name(&master)
                        ))?;
                    (r, "written")
                }
            };
            app.show(
                format!(
                    "{} slave {} parameter {} = {} ({access})",
                    r.master, r.address, r.number, r.value
                ),
                &r,
            )
        }
        SmcVerb::Restart { master } => restart(app, master).await,
        SmcVerb::Watch {
            master,
            interval_ms,
            for_secs,
        } => watch(app, master, interval_ms, for_secs).await,
    }
}

/// `smc restart [MASTER]`: restarts, then waits for P2 or a failed start.
async fn restart(app: &App, master: Option<String>) -> Result<()> {
    let c = &app.client;
    let what = format!("restart of {}", name(&master));
    let m = master.clone().unwrap_or_default();
    let before = c.smc_status(&m).await.ctx(what.clone())?;
    let req = pb::RestartRequest { master: m.clone() };
    c.call("Restart", None, c.cansmc_client().restart(req))
        .await
        .ctx(what.clone())?;
    let t0 = Instant::now();
    let st = loop {
        let st = c.smc_status(&m).await.ctx(what.clone())?;
        let settled =
            st.phase == pb::CansmcPhase::P2 as i32 || st.phase == pb::CansmcPhase::Failed as i32;
        if st.starts > before.starts && settled {
            break st;
        }
        if t0.elapsed() > RESTART_WAIT {
            return Err(Failure::failed(
                what,
                format!(
                    "still in phase {} {} s after the restart",
                    phase_name(st.phase),
                    RESTART_WAIT.as_secs()
                ),
            ));
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    app.show(
        format!(
            "{}: restarted (start {}), phase {} after {:.1} s",
            st.master,
            st.starts,
            phase_name(st.phase),
            t0.elapsed().as_secs_f64()
        ),
        &st,
    )?;
    if st.phase == pb::CansmcPhase::Failed as i32 {
        return Err(Failure::failed(
            what,
            format!(
                "the start failed: {}",
                st.start_error.as_deref().unwrap_or("no reason given")
            ),
        ));
    }
    Ok(())
}

/// `smc watch [MASTER]`: each `CycleStatsUpdate` as lines (or a JSON line).
async fn watch(
    app: &App,
    master: Option<String>,
    interval_ms: u32,
    for_secs: Option<f64>,
) -> Result<()> {
    let c = &app.client;
    let what = format!("watching {}", name(&master));
    let req = pb::StreamCycleStatsRequest {
        master: master.clone().unwrap_or_default(),
        interval_ms,
    };
    let mut s = c
        .call(
            "StreamCycleStats",
            None,
            c.cansmc_client().stream_cycle_stats(req),
        )
        .await
        .ctx(what.clone())?;
    let time_up = sleep_opt(for_secs);
    tokio::pin!(time_up);
    let mut prev = None;
    loop {
        let m = tokio::select! {
            m = s.message() => m.map_err(cangate_client::Error::from).ctx(what.clone())?,
            _ = ctrl_c() => return Ok(()),
            _ = &mut time_up => return Ok(()),
        };
        let Some(u) = m else { return Ok(()) };
        let st = u.status.clone().unwrap_or_default();
        let mut lines = Vec::new();
        for e in &u.events {
            lines.push(format!(
                "{}  {}  {}",
                time_text(e.timestamp_us),
                st.master,
                event_text(e)
            ));
        }
        if u.events_lost > 0 {
            lines.push(format!(
                "{}  {}  [{} events lost: this client read too slowly]",
                time_text(st.timestamp_us),
                st.master,
                u.events_lost
            ));
        }
        lines.push(watch_line(&st, prev));
        app.item(lines.join("\n"), &u)?;
        prev = Some(Totals::of(&st));
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Cli, Command};
    use super::*;
    use clap::Parser;

    fn verb(argv: &[&str]) -> SmcVerb {
        let mut all = vec!["cangate", "smc"];
        all.extend_from_slice(argv);
        match Cli::try_parse_from(&all) {
            Ok(Cli {
                command: Command::Smc(a),
                ..
            }) => a.verb,
            Ok(other) => panic!("{other:?}"),
            Err(e) => panic!("{all:?}: {e}"),
        }
    }

    #[test]
    fn parses_the_verbs() {
        assert!(matches!(
            verb(&["status"]),
            SmcVerb::Status { master: None }
        ));
        let SmcVerb::Param {
            verb:
                ParamVerb::Set {
                    address,
                    number,
                    value,
                    master,
                },
        } = verb(&["param", "set", "3", "0x4", "-2000", "--master", "smc"])
        else {
            panic!()
        };
        assert_eq!(
            (address, number, value, master.as_deref()),
            (3, 4, -2000, Some("smc"))
        );
        assert!(Cli::try_parse_from(["cangate", "smc", "param", "get", "62", "1"]).is_err());
        assert!(Cli::try_parse_from(["cangate", "smc", "watch", "--interval-ms", "10"]).is_err());
    }

    #[test]
    fn numbers_and_values() {
        assert_eq!(value("0xFFFFFFFF"), Ok(-1));
        assert_eq!(value("-5"), Ok(-5));
        assert!(value("4294967296").is_err());
        assert_eq!(number("0x10"), Ok(16));
        assert!(number("70000").is_err());
        assert_eq!(phase_name(pb::CansmcPhase::P2 as i32), "P2");
        assert_eq!(phase_name(pb::CansmcPhase::Failed as i32), "failed");
    }
}
