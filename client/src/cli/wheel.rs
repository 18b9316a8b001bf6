//! `cangate wheel …`: the Handwheels service (`handwheel.proto`).

use super::{
    App, Context, Failure, Result, ctrl_c, label, now_us, positive, print_json, sleep_opt,
    time_text,
};
use cangate_client::{Client, HandwheelMode, pb};
use clap::{Args, Subcommand, ValueEnum};
use futures::StreamExt;
use std::collections::HashMap;
use std::time::Duration;

/// Bound of one statistics poll of `wheel watch`.
const POLL_TIMEOUT: Duration = Duration::from_secs(2);
/// Period of the counters lines of `wheel watch`.
const COUNTERS_PERIOD: Duration = Duration::from_secs(1);

/// `cangate wheel …`
#[derive(Args, Debug)]
pub(crate) struct WheelArgs {
    #[command(subcommand)]
    verb: WheelVerb,
}

#[derive(Subcommand, Debug)]
enum WheelVerb {
    /// Table of handwheels (all, or the named ones): mode, node, feed
    /// statistics, bindings.
    List {
        /// Only these handwheels.
        wheels: Vec<String>,
    },
    /// One handwheel in detail.
    Show {
        /// Handwheel name.
        wheel: String,
    },
    /// Set the mode: manual (feed frames) or auto (none); prints the mode
    /// the wheel confirmed.
    Mode {
        /// Handwheel name.
        wheel: String,
        /// manual, or auto (automatic).
        mode: ModeArg,
    },
    /// Feed events, one line each (time, wheel, axis, ±units, counter, gap,
    /// flags DUP / COMP+n / BASE / BAD, note), and the counters every
    /// second, until Ctrl-C. With --json one `FeedEvent` per line and no
    /// counters.
    Watch {
        /// The handwheels (default: all).
        wheels: Vec<String>,
        /// One event per wheel, axis and direction per N ms window (units
        /// summed, flags combined) instead of one per frame.
        #[arg(long, value_name = "N")]
        coalesce_ms: Option<u32>,
        /// End after this many seconds.
        #[arg(long = "for", value_name = "SECONDS", value_parser = positive)]
        for_secs: Option<f64>,
    },
}

/// The mode as typed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum ModeArg {
    /// Feed frames (one per unit).
    Manual,
    /// No feed frames.
    #[value(name = "auto", alias = "automatic")]
    Automatic,
}

/// The wheel axes in the order of the per-axis statistics.
const AXES: [pb::WheelAxis; 5] = [
    pb::WheelAxis::X,
    pb::WheelAxis::Y,
    pb::WheelAxis::Z,
    pb::WheelAxis::W,
    pb::WheelAxis::V,
];

fn wheel_axis(a: i32) -> String {
    label::<pb::WheelAxis>(a).to_uppercase()
}

/// Net units (positive − negative) per wheel axis, X to V.
fn net_units(s: &pb::FeedStats) -> [i128; 5] {
    let at = |v: &[u64], i: usize| v.get(i).copied().unwrap_or(0) as i128;
    std::array::from_fn(|i| at(&s.positive_units, i) - at(&s.negative_units, i))
}

/// `X+98 Y-3` (axes with a non-zero net only), `0` when none moved.
fn net_units_text(s: &pb::FeedStats) -> String {
    let parts: Vec<String> = net_units(s)
        .iter()
        .zip(AXES)
        .filter(|(n, _)| **n != 0)
        .map(|(n, a)| format!("{}{n:+}", wheel_axis(a as i32)))
        .collect();
    if parts.is_empty() {
        "0".to_string()
    } else {
        parts.join(" ")
    }
}

/// All units dropped by the binding, whatever the reason.
fn dropped(b: &pb::BindingStats) -> u64 {
    b.dropped_backlog
        + b.dropped_not_manual
        + b.dropped_not_enabled
        + b.dropped_not_controlled
        + b.dropped_unbound
}

/// `X->X 0.001mm` (the unit when known).
fn binding_text(b: &pb::AxisBinding, units: &HashMap<String, String>) -> String {
    let unit = units.get(&b.axis).map_or("", String::as_str);
    format!(
        "{}->{} {}{unit}",
        wheel_axis(b.wheel_axis),
        b.axis,
        b.distance_per_unit
    )
}

fn bindings_text(w: &pb::Handwheel, units: &HashMap<String, String>) -> String {
    if w.bindings.is_empty() {
        return "-".to_string();
    }
    w.bindings
        .iter()
        .map(|b| binding_text(b, units))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The flags of an event: `DUP COMP+2 BASE BAD`.
fn event_flags(e: &pb::FeedEvent) -> String {
    let mut flags = Vec::new();
    if e.duplicate {
        flags.push("DUP".to_string());
    }
    if e.compensated_flag || e.compensated > 0 {
        flags.push(format!("COMP+{}", e.compensated));
    }
    if e.baseline {
        flags.push("BASE".to_string());
    }
    if e.bad {
        flags.push("BAD".to_string());
    }
    flags.join(" ")
}

/// One line of `wheel watch` for a feed event.
fn event_line(e: &pb::FeedEvent) -> String {
    let sign = match e.direction.signum() {
        1 => '+',
        -1 => '-',
        _ => ' ',
    };
    let mut line = format!(
        "{}  {:<8} {} {:>5}  seq {:>2}  gap {:>2}",
        time_text(e.timestamp_us),
        e.handwheel,
        wheel_axis(e.axis),
        format!("{sign}{}", e.units),
        e.sequence,
        e.gap,
    );
    if e.frames > 1 {
        line.push_str(&format!("  {} frames", e.frames));
    }
    let flags = event_flags(e);
    if !flags.is_empty() {
        line.push_str("  ");
        line.push_str(&flags);
    }
    if !e.note.is_empty() {
        line.push_str(" — ");
        line.push_str(&e.note);
    }
    if e.lost_before > 0 {
        line.push_str(&format!(
            "  [{} events lost before this one: this client read too slowly]",
            e.lost_before
        ));
    }
    line
}

/// The counters line of `wheel watch`.
fn counters_line(w: &pb::Handwheel, now_us: u64) -> String {
    let s = w.stats.clone().unwrap_or_default();
    let b = w.binding.clone().unwrap_or_default();
    let mut line = format!(
        "{}  {:<8} counters: frames {}  units {}  gaps {} (compensated {})  duplicates {}  bad {}  binding executed {} dropped {} pending {}",
        time_text(now_us),
        w.name,
        s.frames,
        net_units_text(&s),
        s.gaps,
        s.compensated_units,
        s.duplicates,
        s.bad_frames,
        b.executed_units,
        dropped(&b),
        b.pending_units,
    );
    if w.node_lost {
        line.push_str("  NODE LOST");
    }
    if !b.blocked.is_empty() {
        line.push_str("  blocked: ");
        line.push_str(&b.blocked);
    }
    line
}

/// The user unit of every axis, for the bindings; empty when the axes
/// cannot be listed (the units are decoration).
async fn axis_units(client: &Client) -> HashMap<String, String> {
    match client.clone().list_axes().await {
        Ok(axes) => axes.into_iter().map(|a| (a.name, a.unit)).collect(),
        Err(_) => HashMap::new(),
    }
}

/// `cangate wheel …`
pub(crate) async fn run(app: &App, args: WheelArgs) -> Result<()> {
    match args.verb {
        WheelVerb::List { wheels } => list(app, &wheels).await,
        WheelVerb::Show { wheel } => show(app, &wheel).await,
        WheelVerb::Mode { wheel, mode } => {
            let want = match mode {
                ModeArg::Manual => HandwheelMode::Manual,
                ModeArg::Automatic => HandwheelMode::Automatic,
            };
            let what = format!("{wheel}: mode {}", label::<HandwheelMode>(want as i32));
            let w = app
                .client
                .set_handwheel_mode(&wheel, want)
                .await
                .ctx(what.clone())?;
            let got = label::<HandwheelMode>(w.mode);
            app.show(format!("{}: mode {got}", w.name), &w)?;
            if w.mode != want as i32 {
                return Err(Failure::failed(
                    what,
                    format!("the wheel reports mode {got}"),
                ));
            }
            Ok(())
        }
        WheelVerb::Watch {
            wheels,
            coalesce_ms,
            for_secs,
        } => watch(app, wheels, coalesce_ms, for_secs).await,
    }
}

/// `wheel list [WHEEL…]`
async fn list(app: &App, names: &[String]) -> Result<()> {
    let mut wheels = app
        .client
        .clone()
        .list_handwheels()
        .await
        .ctx("listing the handwheels")?;
    if !names.is_empty() {
        if let Some(unknown) = names.iter().find(|n| !wheels.iter().any(|w| &w.name == *n)) {
            // The gateway's own answer: NOT_FOUND naming the wheels it has.
            app.client
                .handwheel(unknown)
                .await
                .ctx(format!("handwheel {unknown}"))?;
        }
        wheels.retain(|w| names.contains(&w.name));
    }
    if app.json {
        return print_json(&pb::ListHandwheelsResponse { handwheels: wheels });
    }
    let units = if wheels.iter().any(|w| !w.bindings.is_empty()) {
        axis_units(&app.client).await
    } else {
        HashMap::new()
    };
    let mut text = format!(
        "{:<8} {:<10} {:<8} {:<9} {:<4} {:<4} {:>8} {:<14} {:>11} {:>5} {:>5} {:<22} {:>13} BLOCKED",
        "WHEEL",
        "BUS/NODE",
        "LAYOUT",
        "MODE",
        "LOST",
        "SIM",
        "FRAMES",
        "UNITS",
        "GAPS/COMP",
        "DUP",
        "BAD",
        "BINDINGS",
        "EXEC/DROP",
    );
    for w in &wheels {
        let s = w.stats.clone().unwrap_or_default();
        let b = w.binding.clone().unwrap_or_default();
        text.push_str(&format!(
            "\n{:<8} {:<10} {:<8} {:<9} {:<4} {:<4} {:>8} {:<14} {:>11} {:>5} {:>5} {:<22} {:>13} {}",
            w.name,
            format!("{}/{}", w.bus, w.node),
            label::<pb::CounterLayout>(w.counter_layout),
            label::<HandwheelMode>(w.mode),
            if w.node_lost { "yes" } else { "no" },
            if w.simulated { "yes" } else { "no" },
            s.frames,
            net_units_text(&s),
            format!("{}/{}", s.gaps, s.compensated_units),
            s.duplicates,
            s.bad_frames,
            bindings_text(w, &units),
            format!("{}/{}", b.executed_units, dropped(&b)),
            if b.blocked.is_empty() {
                "-"
            } else {
                &b.blocked
            },
        ));
    }
    app.line(text)
}

/// `wheel show WHEEL`
async fn show(app: &App, wheel: &str) -> Result<()> {
    let w = app
        .client
        .handwheel(wheel)
        .await
        .ctx(format!("handwheel {wheel}"))?;
    if app.json {
        return print_json(&w);
    }
    let units = if w.bindings.is_empty() {
        HashMap::new()
    } else {
        axis_units(&app.client).await
    };
    let s = w.stats.clone().unwrap_or_default();
    let b = w.binding.clone().unwrap_or_default();
    let layout = match pb::CounterLayout::try_from(w.counter_layout) {
        Ok(pb::CounterLayout::Nibble) => "nibble (bits 4-7, up to 14 lost frames detectable)",
        Ok(pb::CounterLayout::Bits67) => "bits6-7 (step 4, up to 3 lost frames detectable)",
        _ => "unknown",
    };
    let per_axis = AXES
        .iter()
        .enumerate()
        .filter_map(|(i, a)| {
            let p = s.positive_units.get(i).copied().unwrap_or(0);
            let n = s.negative_units.get(i).copied().unwrap_or(0);
            (p != 0 || n != 0).then(|| {
                format!(
                    "{} +{p} -{n} (net {:+})",
                    wheel_axis(*a as i32),
                    p as i128 - n as i128
                )
            })
        })
        .collect::<Vec<_>>();
    let mut rows: Vec<(&str, String)> = vec![
        ("handwheel", w.name.clone()),
        ("bus/node", format!("{}/{}", w.bus, w.node)),
        ("simulated", if w.simulated { "yes" } else { "no" }.into()),
        ("counter layout", layout.to_string()),
        ("mode", label::<HandwheelMode>(w.mode)),
        (
            "node",
            if w.node_lost {
                "LOST (heartbeat timeout)"
            } else {
                "ok"
            }
            .into(),
        ),
        ("frames", s.frames.to_string()),
        (
            "units",
            if per_axis.is_empty() {
                "0".to_string()
            } else {
                per_axis.join(", ")
            },
        ),
        (
            "gaps",
            format!("{} ({} units compensated)", s.gaps, s.compensated_units),
        ),
        ("duplicates", s.duplicates.to_string()),
        ("bad frames", s.bad_frames.to_string()),
        (
            "baselines",
            format!("{} ({} after an outage)", s.baselines, s.baseline_resets),
        ),
    ];
    if w.bindings.is_empty() {
        rows.push(("bindings", "none".to_string()));
    }
    for x in &w.bindings {
        rows.push(("binding", binding_text(x, &units)));
    }
    rows.extend([
        (
            "output limit",
            format!(
                "{} units/s, backlog {} ms",
                w.max_units_per_s, w.stop_within_ms
            ),
        ),
        (
            "executed",
            format!(
                "{} of {} units ({} pending)",
                b.executed_units, b.units, b.pending_units
            ),
        ),
        (
            "dropped",
            format!(
                "{} units (not manual {}, backlog {}, axis not enabled {}, not controlled {}, unbound {})",
                dropped(&b),
                b.dropped_not_manual,
                b.dropped_backlog,
                b.dropped_not_enabled,
                b.dropped_not_controlled,
                b.dropped_unbound
            ),
        ),
        (
            "blocked",
            if b.blocked.is_empty() {
                "-".to_string()
            } else {
                b.blocked.clone()
            },
        ),
    ]);
    let text = rows
        .iter()
        .map(|(k, v)| format!("{:<15} {v}", format!("{k}:")))
        .collect::<Vec<_>>()
        .join("\n");
    app.line(text)
}

/// Polls the statistics of the watched wheels every second and hands them
/// to the printing loop.
async fn poll_counters(
    client: Client,
    wheels: Vec<String>,
    tx: tokio::sync::mpsc::Sender<std::result::Result<Vec<pb::Handwheel>, String>>,
) {
    let client = client.with_request_timeout(Some(POLL_TIMEOUT));
    let mut tick = tokio::time::interval(COUNTERS_PERIOD);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    tick.tick().await; // the first tick is immediate
    loop {
        tick.tick().await;
        let r = if wheels.is_empty() {
            client.clone().list_handwheels().await
        } else {
            let mut all = Vec::with_capacity(wheels.len());
            let mut failed = None;
            for w in &wheels {
                match client.handwheel(w).await {
                    Ok(h) => all.push(h),
                    Err(e) => {
                        failed = Some(e);
                        break;
                    }
                }
            }
            failed.map_or(Ok(all), Err)
        };
        if tx.send(r.map_err(|e| e.to_string())).await.is_err() {
            return;
        }
    }
}

/// `wheel watch [WHEEL…]`
async fn watch(
    app: &App,
    wheels: Vec<String>,
    coalesce_ms: Option<u32>,
    for_secs: Option<f64>,
) -> Result<()> {
    let names: Vec<&str> = wheels.iter().map(String::as_str).collect();
    let coalesce = coalesce_ms.map(|ms| Duration::from_millis(u64::from(ms)));
    let mut s = app
        .client
        .handwheel_feed(&names, coalesce)
        .await
        .ctx("watching the handwheels")?;
    let (tx, mut counters) = tokio::sync::mpsc::channel(1);
    let poller =
        (!app.json).then(|| tokio::spawn(poll_counters(app.client.clone(), wheels.clone(), tx)));
    let _stop_poller = super::AbortOnDrop(poller);
    let time_up = sleep_opt(for_secs);
    tokio::pin!(time_up);
    loop {
        tokio::select! {
            e = s.next() => {
                let Some(e) = e else { return Ok(()) };
                let e = e.ctx("watching the handwheels")?;
                app.item(event_line(&e), &e)?;
            }
            Some(r) = counters.recv() => match r {
                Ok(ws) => {
                    let now = now_us();
                    let lines: Vec<String> = ws.iter().map(|w| counters_line(w, now)).collect();
                    app.line(lines.join("\n"))?;
                }
                Err(e) => eprintln!("cangate: handwheel counters: {e}"),
            },
            _ = ctrl_c() => return Ok(()),
            _ = &mut time_up => return Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Cli, Command};
    use super::*;
    use clap::Parser;

    fn verb(argv: &[&str]) -> WheelVerb {
        let mut all = vec!["cangate", "wheel"];
        all.extend_from_slice(argv);
        match Cli::try_parse_from(&all) {
            Ok(Cli {
                command: Command::Wheel(a),
                ..
            }) => a.verb,
            Ok(other) => panic!("{other:?}"),
            Err(e) => panic!("{all:?}: {e}"),
        }
    }

    #[test]
    fn parses_the_verbs() {
        assert!(matches!(
            verb(&["mode", "hw1", "auto"]),
            WheelVerb::Mode {
                mode: ModeArg::Automatic,
                ..
            }
        ));
        assert!(matches!(
            verb(&["mode", "hw1", "automatic"]),
            WheelVerb::Mode {
                mode: ModeArg::Automatic,
                ..
            }
        ));
        let WheelVerb::Watch {
            wheels,
            coalesce_ms,
            for_secs,
        } = verb(&["watch", "hw1", "--coalesce-ms", "50", "--for", "1"])
        else {
            panic!()
        };
        assert_eq!(
            (wheels, coalesce_ms, for_secs),
            (vec!["hw1".to_string()], Some(50), Some(1.0))
        );
        assert!(Cli::try_parse_from(["cangate", "wheel", "mode", "hw1", "sideways"]).is_err());
    }

    #[test]
    fn event_and_counter_lines() {
        let e = pb::FeedEvent {
            handwheel: "hw1".into(),
            timestamp_us: 1_700_000_000_000_001,
            axis: pb::WheelAxis::X as i32,
            direction: -1,
            units: 3,
            compensated: 2,
            sequence: 7,
            gap: 2,
            ..Default::default()
        };
        let line = event_line(&e);
        assert!(
            line.contains("hw1      X    -3  seq  7  gap  2  COMP+2"),
            "{line}"
        );
        let w = pb::Handwheel {
            name: "hw1".into(),
            stats: Some(pb::FeedStats {
                frames: 5,
                positive_units: vec![10, 0, 0, 0, 0],
                negative_units: vec![2, 3, 0, 0, 0],
                ..Default::default()
            }),
            ..Default::default()
        };
        assert!(counters_line(&w, 1).contains("units X+8 Y-3"));
    }
}
