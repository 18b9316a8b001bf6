//! The handwheel verbs of the `cangate` CLI: `cangate wheel …` over the
//! `Handwheels` service and `cangate sim …` over the `Simulator` service
//! (`proto/cangate/v1/handwheel.proto`).

use crate::cli_common::{Rpc, ctrl_c, now_us, positive, sleep_opt, status_error, time_text};
use anyhow::{Context, Result, bail};
use cangate_client::{Client, pb};
use clap::{Args, Subcommand, ValueEnum};
use serde_json::{Value, json};
use std::collections::HashMap;
use std::io::Write;
use std::time::Duration;

/// Bound of one statistics poll of `wheel watch`.
const POLL_TIMEOUT: Duration = Duration::from_secs(2);
/// Period of the counters lines of `wheel watch`.
const COUNTERS_PERIOD: Duration = Duration::from_secs(1);

/// Extra help of `cangate wheel`, shown after the options.
pub const WHEEL_HELP: &str = "\
Forms:
  cangate wheel [list [WHEEL…]]            table of handwheels
  cangate wheel show WHEEL                 one handwheel in detail
  cangate wheel mode WHEEL manual|auto     set the mode (SDO 0x2000, read back)
  cangate wheel watch [WHEEL…] [--coalesce-ms N] [--for SECONDS]

watch prints one line per feed event (time, wheel, axis, ±units, counter,
gap, flags DUP / COMP+n / BASE / BAD, note) and every second a counters
line per wheel; with --json one JSON object per event and no counters.
Units: feed units (detents × multiplier); bindings turn them into axis
jogs of the configured distance.";

/// `cangate wheel …`
#[derive(Args, Debug, PartialEq)]
pub struct WheelArgs {
    /// What to do (default: `list`).
    #[command(subcommand)]
    pub verb: Option<WheelVerb>,
}

/// The verbs of `cangate wheel`.
#[derive(Subcommand, Debug, PartialEq)]
pub enum WheelVerb {
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
    /// Feed events, one line each, and the counters every second, until
    /// Ctrl-C.
    Watch(WatchArgs),
}

/// The mode as typed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ModeArg {
    /// Feed frames (one per unit).
    Manual,
    /// No feed frames.
    #[value(name = "auto", alias = "automatic")]
    Automatic,
}

impl ModeArg {
    fn pb(self) -> pb::HandwheelMode {
        match self {
            ModeArg::Manual => pb::HandwheelMode::Manual,
            ModeArg::Automatic => pb::HandwheelMode::Automatic,
        }
    }
}

/// `wheel watch [WHEEL…] …`
#[derive(Args, Debug, PartialEq)]
pub struct WatchArgs {
    /// The handwheels (default: all).
    pub wheels: Vec<String>,
    /// One event per wheel, axis and direction per N ms window (units
    /// summed, flags combined) instead of one per frame.
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub coalesce_ms: u32,
    /// End after this many seconds.
    #[arg(long = "for", value_name = "SECONDS", value_parser = positive)]
    pub for_secs: Option<f64>,
}

/// `cangate sim …`
#[derive(Args, Debug, PartialEq)]
pub struct SimArgs {
    /// What to do.
    #[command(subcommand)]
    pub verb: SimVerb,
}

/// The verbs of `cangate sim`.
#[derive(Subcommand, Debug, PartialEq)]
pub enum SimVerb {
    /// Turn a simulated handwheel: `cangate sim turn hw1 --detents -20
    /// --axis X --mult 10`.
    Turn(TurnArgs),
    /// The gateway's simulated CANopen devices.
    List,
    /// Show a virtual bus's faults, or replace them: `cangate sim faults
    /// can0 --drop 0.01 --drop-id 0x77F --delay-us 500` (`--clear`: none).
    Faults(FaultArgs),
    /// Force a virtual bus off (`--recover`: back to error-active).
    BusOff {
        /// A virtual bus.
        bus: String,
        /// Recover instead.
        #[arg(long)]
        recover: bool,
    },
    /// Cut a simulated device's power: `cangate sim power-cycle can0 1
    /// --off-ms 500`; it boots with its power-on defaults.
    PowerCycle {
        /// The bus.
        bus: String,
        /// The node id.
        node: u32,
        /// How long the power stays off (default 100 ms).
        #[arg(long, value_name = "MS", default_value_t = 100)]
        off_ms: u32,
    },
    /// Make a simulated device send an EMCY: `cangate sim emcy can0 4
    /// 0x5000 --register 0x01 --data 0102`.
    Emcy {
        /// The bus.
        bus: String,
        /// The node id.
        node: u32,
        /// The error code (0x… or decimal).
        #[arg(value_parser = int_arg)]
        code: u32,
        /// The error register (default: generic error).
        #[arg(long, value_parser = int_arg, default_value = "0")]
        register: u32,
        /// Manufacturer bytes as hex, at most 5 (e.g. 0102).
        #[arg(long, value_parser = hex_bytes, default_value = "")]
        data: HexBytes,
    },
    /// Raise a fault in a simulated drive: `cangate sim drive-fault can0 1
    /// 0x2310`.
    DriveFault {
        /// The bus.
        bus: String,
        /// The node id.
        node: u32,
        /// The fault's EMCY code (0x1000..=0xFFFF).
        #[arg(value_parser = int_arg)]
        code: u32,
    },
    /// Set the inputs of a simulated I/O node: `cangate sim inputs can0 4
    /// --digital 0x01,0x80 --analogue 1000,-5`.
    Inputs {
        /// The bus.
        bus: String,
        /// The node id.
        node: u32,
        /// Digital input bytes for 0x6000 sub 1, 2, …
        #[arg(long, value_delimiter = ',', value_parser = byte_arg)]
        digital: Vec<u8>,
        /// Analogue inputs for 0x6401 sub 1, 2, …
        #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
        analogue: Vec<i32>,
    },
}

/// `sim faults BUS …`
#[derive(Args, Debug, PartialEq)]
pub struct FaultArgs {
    /// A virtual bus.
    pub bus: String,
    /// Drop each frame with this probability (0..1).
    #[arg(long = "drop", value_name = "P", value_parser = probability)]
    pub drop_probability: Option<f64>,
    /// Drop every frame with this identifier (repeatable).
    #[arg(long = "drop-id", value_name = "ID", value_parser = int_arg)]
    pub drop_ids: Vec<u32>,
    /// Deliver every frame this many µs late.
    #[arg(long, value_name = "US")]
    pub delay_us: Option<u64>,
    /// Remove every drop and delay fault.
    #[arg(long, conflicts_with_all = ["drop_probability", "drop_ids", "delay_us"])]
    pub clear: bool,
}

/// Bytes typed as hex.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct HexBytes(pub Vec<u8>);

/// `0x…` hex or decimal.
fn int_arg(text: &str) -> Result<u32, String> {
    let t = text.trim();
    let parsed = match t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        Some(hex) => u32::from_str_radix(hex, 16),
        None => t.parse(),
    };
    parsed.map_err(|_| format!("{text:?} is not a number (decimal or 0x…)"))
}

fn byte_arg(text: &str) -> Result<u8, String> {
    let v = int_arg(text)?;
    u8::try_from(v).map_err(|_| format!("{text:?} does not fit a byte"))
}

fn hex_bytes(text: &str) -> Result<HexBytes, String> {
    let t: String = text.chars().filter(|c| !c.is_whitespace()).collect();
    if !t.len().is_multiple_of(2) {
        return Err(format!("{text:?}: hex bytes come in pairs of digits"));
    }
    (0..t.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&t[i..i + 2], 16).map_err(|_| format!("{text:?} is not hex")))
        .collect::<Result<Vec<u8>, String>>()
        .map(HexBytes)
}

/// The wheel's axis selector as typed (any case).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
#[value(rename_all = "UPPER")]
pub enum AxisArg {
    /// X.
    X,
    /// Y.
    Y,
    /// Z.
    Z,
    /// W.
    W,
    /// V.
    V,
}

impl AxisArg {
    fn pb(self) -> pb::WheelAxis {
        match self {
            AxisArg::X => pb::WheelAxis::X,
            AxisArg::Y => pb::WheelAxis::Y,
            AxisArg::Z => pb::WheelAxis::Z,
            AxisArg::W => pb::WheelAxis::W,
            AxisArg::V => pb::WheelAxis::V,
        }
    }
}

/// `sim turn WHEEL --detents N …`
#[derive(Args, Debug, PartialEq)]
pub struct TurnArgs {
    /// Simulated handwheel name.
    pub wheel: String,
    /// Signed detents (negative: the other way).
    #[arg(long, allow_negative_numbers = true, value_name = "N")]
    pub detents: i32,
    /// Set the axis selector first (X Y Z W V; default: keep).
    #[arg(long, ignore_case = true, hide_possible_values = true)]
    pub axis: Option<AxisArg>,
    /// Set the multiplier first: 1, 10 or 100 (default: keep).
    #[arg(long, value_name = "1|10|100", value_parser = multiplier)]
    pub mult: Option<u32>,
    /// Lose each feed frame of this turn with this probability (0..1).
    #[arg(long, value_name = "P", value_parser = probability)]
    pub loss: Option<f64>,
    /// Never lose more than this many frames in a row (default: the
    /// gateway's, 14, the most a nibble counter detects).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    pub max_consecutive_loss: Option<u32>,
}

fn multiplier(text: &str) -> Result<u32, String> {
    match text.parse::<u32>() {
        Ok(m @ (1 | 10 | 100)) => Ok(m),
        _ => Err(format!("{text:?} is not 1, 10 or 100")),
    }
}

fn probability(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(p) if (0.0..=1.0).contains(&p) => Ok(p),
        _ => Err(format!("{text:?} is not a probability 0..1")),
    }
}

// ------------------------------------------------------------ rpc helpers

// ------------------------------------------------------------- formatting

/// The wheel axes in the order of the per-axis statistics.
const AXES: [pb::WheelAxis; 5] = [
    pb::WheelAxis::X,
    pb::WheelAxis::Y,
    pb::WheelAxis::Z,
    pb::WheelAxis::W,
    pb::WheelAxis::V,
];

fn wheel_axis_name(a: i32) -> &'static str {
    match pb::WheelAxis::try_from(a) {
        Ok(pb::WheelAxis::X) => "X",
        Ok(pb::WheelAxis::Y) => "Y",
        Ok(pb::WheelAxis::Z) => "Z",
        Ok(pb::WheelAxis::W) => "W",
        Ok(pb::WheelAxis::V) => "V",
        _ => "?",
    }
}

fn mode_name(m: i32) -> &'static str {
    match pb::HandwheelMode::try_from(m) {
        Ok(pb::HandwheelMode::Manual) => "manual",
        Ok(pb::HandwheelMode::Automatic) => "automatic",
        _ => "unknown",
    }
}

fn layout_name(l: i32) -> &'static str {
    match pb::CounterLayout::try_from(l) {
        Ok(pb::CounterLayout::Nibble) => "nibble",
        Ok(pb::CounterLayout::Bits67) => "bits6-7",
        _ => "unknown",
    }
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
        .map(|(n, a)| format!("{}{n:+}", wheel_axis_name(a as i32)))
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
        wheel_axis_name(b.wheel_axis),
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

/// Signed units: `+3`, `-1`, `+0` for a repeat, ` 0` for a bad frame.
fn signed_units(e: &pb::FeedEvent) -> String {
    let sign = match e.direction.signum() {
        1 => '+',
        -1 => '-',
        _ => ' ',
    };
    format!("{sign}{}", e.units)
}

/// One line of `wheel watch` for a feed event.
pub fn event_line(e: &pb::FeedEvent) -> String {
    let mut line = format!(
        "{}  {:<8} {} {:>5}  seq {:>2}  gap {:>2}",
        time_text(e.timestamp_us),
        e.handwheel,
        wheel_axis_name(e.axis),
        signed_units(e),
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

/// One JSON line of `wheel watch --json`.
pub fn event_json(e: &pb::FeedEvent) -> Value {
    json!({
        "handwheel": e.handwheel,
        "timestamp_us": e.timestamp_us,
        "axis": (e.axis != pb::WheelAxis::Unspecified as i32).then(|| wheel_axis_name(e.axis)),
        "direction": e.direction,
        "units": e.units,
        "compensated": e.compensated,
        "sequence": e.sequence,
        "gap": e.gap,
        "duplicate": e.duplicate,
        "compensated_flag": e.compensated_flag,
        "baseline": e.baseline,
        "bad": e.bad,
        "note": e.note,
        "raw": e.raw,
        "frames": e.frames,
        "lost_before": e.lost_before,
    })
}

/// The counters line of `wheel watch`, from GetHandwheel.
pub fn counters_line(w: &pb::Handwheel, now_us: u64) -> String {
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

fn per_axis_json(v: &[u64]) -> Value {
    let map: serde_json::Map<String, Value> = AXES
        .iter()
        .enumerate()
        .map(|(i, a)| {
            (
                wheel_axis_name(*a as i32).to_string(),
                json!(v.get(i).copied().unwrap_or(0)),
            )
        })
        .collect();
    Value::Object(map)
}

fn wheel_json(w: &pb::Handwheel) -> Value {
    let s = w.stats.clone().unwrap_or_default();
    let b = w.binding.clone().unwrap_or_default();
    let net: serde_json::Map<String, Value> = net_units(&s)
        .iter()
        .zip(AXES)
        .map(|(n, a)| (wheel_axis_name(a as i32).to_string(), json!(*n as i64)))
        .collect();
    json!({
        "name": w.name,
        "bus": w.bus,
        "node": w.node,
        "counter_layout": layout_name(w.counter_layout),
        "mode": mode_name(w.mode),
        "node_lost": w.node_lost,
        "simulated": w.simulated,
        "stats": {
            "frames": s.frames,
            "positive_units": per_axis_json(&s.positive_units),
            "negative_units": per_axis_json(&s.negative_units),
            "net_units": net,
            "gaps": s.gaps,
            "compensated_units": s.compensated_units,
            "duplicates": s.duplicates,
            "bad_frames": s.bad_frames,
            "baselines": s.baselines,
            "baseline_resets": s.baseline_resets,
        },
        "bindings": w.bindings.iter().map(|x| json!({
            "wheel_axis": wheel_axis_name(x.wheel_axis),
            "axis": x.axis,
            "distance_per_unit": x.distance_per_unit,
        })).collect::<Vec<_>>(),
        "max_units_per_s": w.max_units_per_s,
        "stop_within_ms": w.stop_within_ms,
        "binding": {
            "units": b.units,
            "executed_units": b.executed_units,
            "pending_units": b.pending_units,
            "dropped_not_manual": b.dropped_not_manual,
            "dropped_backlog": b.dropped_backlog,
            "dropped_not_enabled": b.dropped_not_enabled,
            "dropped_not_controlled": b.dropped_not_controlled,
            "dropped_unbound": b.dropped_unbound,
            "blocked": b.blocked,
        },
    })
}

// -------------------------------------------------------------- commands

/// `cangate wheel …`
pub async fn run(client: &mut Client, as_json: bool, args: WheelArgs) -> Result<()> {
    match args.verb {
        None => list(client, as_json, &[]).await,
        Some(WheelVerb::List { wheels }) => list(client, as_json, &wheels).await,
        Some(WheelVerb::Show { wheel }) => show(client, as_json, &wheel).await,
        Some(WheelVerb::Mode { wheel, mode }) => set_mode(client, as_json, &wheel, mode).await,
        Some(WheelVerb::Watch(w)) => watch(client, as_json, w).await,
    }
}

/// `cangate sim …`
pub async fn sim(client: &mut Client, as_json: bool, args: SimArgs) -> Result<()> {
    let mut sim = client.simulator_client();
    let print = |text: String, value: Value| -> Result<()> {
        let mut out = std::io::stdout().lock();
        if as_json {
            writeln!(out, "{value}")?;
        } else {
            writeln!(out, "{text}")?;
        }
        out.flush()?;
        Ok(())
    };
    match args.verb {
        SimVerb::Turn(t) => turn(client, as_json, t).await,
        SimVerb::List => {
            let r = sim
                .list_simulated_devices(pb::ListSimulatedDevicesRequest {})
                .await
                .rpc()?;
            let text = r
                .devices
                .iter()
                .map(device_text)
                .collect::<Vec<_>>()
                .join("\n");
            let json = Value::Array(r.devices.iter().map(device_json).collect());
            print(
                if text.is_empty() {
                    "no simulated devices".into()
                } else {
                    text
                },
                json,
            )
        }
        SimVerb::Faults(f) => {
            let changing = f.clear
                || f.drop_probability.is_some()
                || !f.drop_ids.is_empty()
                || f.delay_us.is_some();
            let r = if changing {
                sim.set_bus_faults(pb::SetBusFaultsRequest {
                    bus: f.bus.clone(),
                    drop_probability: f.drop_probability.unwrap_or(0.0),
                    drop_ids: f.drop_ids,
                    delay_us: f.delay_us.unwrap_or(0),
                })
                .await
                .rpc()
            } else {
                sim.get_bus_faults(pb::GetBusFaultsRequest { bus: f.bus.clone() })
                    .await
                    .rpc()
            }
            .with_context(|| format!("{}: faults", f.bus))?;
            print(faults_text(&r), faults_json(&r))
        }
        SimVerb::BusOff { bus, recover } => {
            let r = sim
                .set_bus_off(pb::SetBusOffRequest {
                    bus: bus.clone(),
                    bus_off: !recover,
                })
                .await
                .rpc()
                .with_context(|| format!("{bus}: bus-off"))?;
            print(faults_text(&r), faults_json(&r))
        }
        SimVerb::PowerCycle { bus, node, off_ms } => {
            let r = sim
                .power_cycle_device(pb::PowerCycleDeviceRequest {
                    bus: bus.clone(),
                    node,
                    off_ms,
                })
                .await
                .rpc()
                .with_context(|| format!("{bus} node {node}: power cycle"))?;
            print(
                format!(
                    "{}: power off for {off_ms} ms, then it boots",
                    device_text(&r)
                ),
                device_json(&r),
            )
        }
        SimVerb::Emcy {
            bus,
            node,
            code,
            register,
            data,
        } => {
            let r = sim
                .send_emcy(pb::SendEmcyRequest {
                    bus: bus.clone(),
                    node,
                    code,
                    error_register: register,
                    manufacturer: data.0,
                })
                .await
                .rpc()
                .with_context(|| format!("{bus} node {node}: EMCY"))?;
            print(
                format!("{}: sent EMCY {code:#06x}", device_text(&r)),
                device_json(&r),
            )
        }
        SimVerb::DriveFault { bus, node, code } => {
            let r = sim
                .raise_drive_fault(pb::RaiseDriveFaultRequest {
                    bus: bus.clone(),
                    node,
                    code,
                })
                .await
                .rpc()
                .with_context(|| format!("{bus} node {node}: drive fault"))?;
            print(
                format!("{}: fault {code:#06x} raised", device_text(&r)),
                device_json(&r),
            )
        }
        SimVerb::Inputs {
            bus,
            node,
            digital,
            analogue,
        } => {
            let r = sim
                .set_io_inputs(pb::SetIoInputsRequest {
                    bus: bus.clone(),
                    node,
                    digital,
                    analogue,
                })
                .await
                .rpc()
                .with_context(|| format!("{bus} node {node}: inputs"))?;
            let digital: Vec<String> = r.digital.iter().map(|b| format!("{b:#04x}")).collect();
            print(
                format!(
                    "{bus} node {node}: digital [{}] analogue {:?}",
                    digital.join(", "),
                    r.analogue
                ),
                json!({"bus": bus, "node": node, "digital": r.digital, "analogue": r.analogue}),
            )
        }
    }
}

fn device_kind_name(k: i32) -> &'static str {
    match pb::SimulatedDeviceKind::try_from(k) {
        Ok(pb::SimulatedDeviceKind::Node) => "node",
        Ok(pb::SimulatedDeviceKind::Drive) => "drive",
        Ok(pb::SimulatedDeviceKind::Handwheel) => "handwheel",
        _ => "?",
    }
}

fn device_text(d: &pb::SimulatedDevice) -> String {
    format!(
        "{} node {} ({}): {}",
        d.bus,
        d.node,
        device_kind_name(d.kind),
        d.nmt_state
    )
}

fn device_json(d: &pb::SimulatedDevice) -> Value {
    json!({
        "bus": d.bus,
        "node": d.node,
        "kind": device_kind_name(d.kind),
        "powered": d.powered,
        "nmt_state": d.nmt_state,
    })
}

fn faults_text(f: &pb::BusFaults) -> String {
    let ids: Vec<String> = f.drop_ids.iter().map(|id| format!("{id:#x}")).collect();
    format!(
        "{}: drop {} ids [{}] delay {} µs{}  ({} frames dropped so far)",
        f.bus,
        f.drop_probability,
        ids.join(", "),
        f.delay_us,
        if f.bus_off { "  BUS-OFF" } else { "" },
        f.dropped_by_fault
    )
}

fn faults_json(f: &pb::BusFaults) -> Value {
    json!({
        "bus": f.bus,
        "drop_probability": f.drop_probability,
        "drop_ids": f.drop_ids,
        "delay_us": f.delay_us,
        "bus_off": f.bus_off,
        "dropped_by_fault": f.dropped_by_fault,
    })
}

/// The user unit of every axis, for the bindings; empty when the axes
/// cannot be listed (the units are decoration).
async fn axis_units(client: &Client) -> HashMap<String, String> {
    match client.clone().list_axes().await {
        Ok(axes) => axes.into_iter().map(|a| (a.name, a.unit)).collect(),
        Err(_) => HashMap::new(),
    }
}

async fn list_wheels(client: &Client) -> Result<Vec<pb::Handwheel>> {
    client
        .handwheels_client()
        .list_handwheels(pb::ListHandwheelsRequest {})
        .await
        .rpc()
        .map(|r| r.handwheels)
}

async fn get_wheel(client: &Client, wheel: &str) -> Result<pb::Handwheel> {
    client
        .handwheels_client()
        .get_handwheel(pb::GetHandwheelRequest {
            handwheel: wheel.to_string(),
        })
        .await
        .rpc()
}

/// `wheel list [WHEEL…]`
async fn list(client: &Client, as_json: bool, names: &[String]) -> Result<()> {
    let mut wheels = list_wheels(client).await?;
    if !names.is_empty() {
        if let Some(unknown) = names.iter().find(|n| !wheels.iter().any(|w| &w.name == *n)) {
            bail!("unknown handwheel {unknown:?}");
        }
        wheels.retain(|w| names.contains(&w.name));
    }
    if as_json {
        let list: Vec<_> = wheels.iter().map(wheel_json).collect();
        let mut out = std::io::stdout().lock();
        writeln!(out, "{}", serde_json::to_string_pretty(&list)?)?;
        return Ok(());
    }
    let units = if wheels.iter().any(|w| !w.bindings.is_empty()) {
        axis_units(client).await
    } else {
        HashMap::new()
    };
    let mut out = std::io::stdout().lock();
    writeln!(
        out,
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
    )?;
    for w in &wheels {
        let s = w.stats.clone().unwrap_or_default();
        let b = w.binding.clone().unwrap_or_default();
        writeln!(
            out,
            "{:<8} {:<10} {:<8} {:<9} {:<4} {:<4} {:>8} {:<14} {:>11} {:>5} {:>5} {:<22} {:>13} {}",
            w.name,
            format!("{}/{}", w.bus, w.node),
            layout_name(w.counter_layout),
            mode_name(w.mode),
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
        )?;
    }
    out.flush()?;
    Ok(())
}

/// `wheel show WHEEL`
async fn show(client: &Client, as_json: bool, wheel: &str) -> Result<()> {
    let w = get_wheel(client, wheel).await?;
    if as_json {
        let mut out = std::io::stdout().lock();
        writeln!(out, "{}", serde_json::to_string_pretty(&wheel_json(&w))?)?;
        return Ok(());
    }
    let units = if w.bindings.is_empty() {
        HashMap::new()
    } else {
        axis_units(client).await
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
                    wheel_axis_name(*a as i32),
                    p as i128 - n as i128
                )
            })
        })
        .collect::<Vec<_>>();
    let mut rows: Vec<(&str, String)> = vec![
        ("handwheel", w.name.clone()),
        ("bus/node", format!("{}/{}", w.bus, w.node)),
        (
            "simulated",
            if w.simulated { "yes" } else { "no" }.to_string(),
        ),
        ("counter layout", layout.to_string()),
        ("mode", mode_name(w.mode).to_string()),
        (
            "node",
            if w.node_lost {
                "LOST (heartbeat timeout)"
            } else {
                "ok"
            }
            .to_string(),
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
    let mut out = std::io::stdout().lock();
    for (k, v) in rows {
        writeln!(out, "{:<15} {v}", format!("{k}:"))?;
    }
    out.flush()?;
    Ok(())
}

/// `wheel mode WHEEL manual|auto`
async fn set_mode(client: &Client, as_json: bool, wheel: &str, mode: ModeArg) -> Result<()> {
    let want = mode.pb();
    let w = client
        .handwheels_client()
        .set_mode(pb::SetModeRequest {
            handwheel: wheel.to_string(),
            mode: want as i32,
        })
        .await
        .rpc()
        .with_context(|| format!("{wheel}: mode {}", mode_name(want as i32)))?;
    if as_json {
        let mut out = std::io::stdout().lock();
        writeln!(
            out,
            "{}",
            json!({"handwheel": w.name, "mode": mode_name(w.mode)})
        )?;
    } else {
        let mut out = std::io::stdout().lock();
        writeln!(out, "{}: mode {}", w.name, mode_name(w.mode))?;
    }
    if w.mode != want as i32 {
        bail!(
            "{wheel}: the wheel reports mode {}, not {} as asked",
            mode_name(w.mode),
            mode_name(want as i32)
        );
    }
    Ok(())
}

/// Polls the statistics of the watched wheels every second and hands them
/// to the printing loop.
async fn poll_counters(
    client: Client,
    wheels: Vec<String>,
    tx: tokio::sync::mpsc::Sender<Result<Vec<pb::Handwheel>>>,
) {
    let mut tick = tokio::time::interval(COUNTERS_PERIOD);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    tick.tick().await; // the first tick is immediate
    loop {
        tick.tick().await;
        let fetch = async {
            if wheels.is_empty() {
                list_wheels(&client).await
            } else {
                let mut all = Vec::with_capacity(wheels.len());
                for w in &wheels {
                    all.push(get_wheel(&client, w).await?);
                }
                Ok(all)
            }
        };
        let r = match tokio::time::timeout(POLL_TIMEOUT, fetch).await {
            Ok(r) => r,
            Err(_) => Err(anyhow::anyhow!(
                "no answer within {} s",
                POLL_TIMEOUT.as_secs()
            )),
        };
        if tx.send(r).await.is_err() {
            return;
        }
    }
}

/// `wheel watch [WHEEL…]`
async fn watch(client: &Client, as_json: bool, args: WatchArgs) -> Result<()> {
    let WatchArgs {
        wheels,
        coalesce_ms,
        for_secs,
    } = args;
    let mut s = client
        .handwheels_client()
        .stream_feed(pb::StreamFeedRequest {
            handwheels: wheels.clone(),
            coalesce_ms,
        })
        .await
        .rpc()
        .context("watch")?;
    let (tx, mut counters) = tokio::sync::mpsc::channel(1);
    let poller = (!as_json).then(|| tokio::spawn(poll_counters(client.clone(), wheels, tx)));
    let _stop_poller = AbortOnDrop(poller);
    let time_up = sleep_opt(for_secs);
    tokio::pin!(time_up);
    let stdout = std::io::stdout();
    loop {
        tokio::select! {
            m = s.message() => {
                let Some(e) = m.map_err(status_error).context("watch")? else {
                    return Ok(());
                };
                let mut out = stdout.lock();
                if as_json {
                    writeln!(out, "{}", event_json(&e))?;
                } else {
                    writeln!(out, "{}", event_line(&e))?;
                }
                out.flush()?;
            }
            Some(r) = counters.recv() => match r {
                Ok(ws) => {
                    let now = now_us();
                    let mut out = stdout.lock();
                    for w in &ws {
                        writeln!(out, "{}", counters_line(w, now))?;
                    }
                    out.flush()?;
                }
                Err(e) => eprintln!("cangate: counters: {e:#}"),
            },
            _ = ctrl_c() => return Ok(()),
            _ = &mut time_up => return Ok(()),
        }
    }
}

/// Aborts a background task when the command ends, however it ends.
struct AbortOnDrop(Option<tokio::task::JoinHandle<()>>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        if let Some(h) = &self.0 {
            h.abort();
        }
    }
}

/// `sim turn WHEEL --detents N …`
async fn turn(client: &Client, as_json: bool, t: TurnArgs) -> Result<()> {
    let r = client
        .simulator_client()
        .turn_handwheel(pb::TurnHandwheelRequest {
            handwheel: t.wheel.clone(),
            detents: t.detents,
            axis: t.axis.map_or(pb::WheelAxis::Unspecified, AxisArg::pb) as i32,
            multiplier: t.mult.unwrap_or(0),
            loss: t.loss.unwrap_or(0.0),
            max_consecutive_loss: t.max_consecutive_loss.unwrap_or(0),
        })
        .await
        .rpc()
        .with_context(|| format!("{}: turn", t.wheel))?;
    let mut out = std::io::stdout().lock();
    if as_json {
        writeln!(
            out,
            "{}",
            json!({
                "handwheel": t.wheel,
                "detents": t.detents,
                "pending_units": r.pending_units,
                "discarded_units": r.discarded_units,
            })
        )?;
    } else {
        writeln!(
            out,
            "{}: turned {:+} detents, {} units pending{}",
            t.wheel,
            t.detents,
            r.pending_units,
            if r.discarded_units > 0 {
                format!(
                    ", {} discarded (the wheel sends feed only in manual mode)",
                    r.discarded_units
                )
            } else {
                String::new()
            }
        )?;
    }
    out.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Cli, Command};
    use clap::Parser;

    fn wheel_verb(argv: &[&str]) -> WheelVerb {
        let cli = Cli::try_parse_from(argv).unwrap_or_else(|e| panic!("{argv:?}: {e}"));
        match cli.command {
            Command::Wheel(WheelArgs { verb: Some(v) }) => v,
            other => panic!("{other:?}"),
        }
    }

    fn turn_args(argv: &[&str]) -> TurnArgs {
        let cli = Cli::try_parse_from(argv).unwrap_or_else(|e| panic!("{argv:?}: {e}"));
        match cli.command {
            Command::Sim(SimArgs {
                verb: SimVerb::Turn(t),
            }) => t,
            other => panic!("{other:?}"),
        }
    }

    fn sim_verb(argv: &[&str]) -> SimVerb {
        let cli = Cli::try_parse_from(argv).unwrap_or_else(|e| panic!("{argv:?}: {e}"));
        match cli.command {
            Command::Sim(SimArgs { verb }) => verb,
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn parses_the_fault_verbs() {
        assert_eq!(
            sim_verb(&[
                "cangate",
                "sim",
                "faults",
                "can0",
                "--drop",
                "0.25",
                "--drop-id",
                "0x77F",
                "--drop-id",
                "1",
                "--delay-us",
                "500"
            ]),
            SimVerb::Faults(FaultArgs {
                bus: "can0".into(),
                drop_probability: Some(0.25),
                drop_ids: vec![0x77F, 1],
                delay_us: Some(500),
                clear: false,
            })
        );
        assert!(
            Cli::try_parse_from(["cangate", "sim", "faults", "can0", "--clear", "--drop", "1"])
                .is_err()
        );
        assert!(Cli::try_parse_from(["cangate", "sim", "faults", "can0", "--drop", "2"]).is_err());
        assert_eq!(
            sim_verb(&[
                "cangate", "sim", "emcy", "can0", "4", "0x5000", "--data", "0102"
            ]),
            SimVerb::Emcy {
                bus: "can0".into(),
                node: 4,
                code: 0x5000,
                register: 0,
                data: HexBytes(vec![1, 2]),
            }
        );
        assert_eq!(
            sim_verb(&[
                "cangate",
                "sim",
                "inputs",
                "can0",
                "4",
                "--digital",
                "0x01,128",
                "--analogue",
                "-5,7"
            ]),
            SimVerb::Inputs {
                bus: "can0".into(),
                node: 4,
                digital: vec![1, 128],
                analogue: vec![-5, 7],
            }
        );
        assert_eq!(
            sim_verb(&["cangate", "sim", "power-cycle", "can0", "1"]),
            SimVerb::PowerCycle {
                bus: "can0".into(),
                node: 1,
                off_ms: 100
            }
        );
        assert_eq!(
            sim_verb(&["cangate", "sim", "bus-off", "can0", "--recover"]),
            SimVerb::BusOff {
                bus: "can0".into(),
                recover: true
            }
        );
        assert!(matches!(
            sim_verb(&["cangate", "sim", "drive-fault", "can0", "1", "8960"]),
            SimVerb::DriveFault { code: 8960, .. }
        ));
    }

    #[test]
    fn parses_mode() {
        assert_eq!(
            wheel_verb(&["cangate", "wheel", "mode", "hw1", "manual"]),
            WheelVerb::Mode {
                wheel: "hw1".into(),
                mode: ModeArg::Manual
            }
        );
        for word in ["auto", "automatic"] {
            assert_eq!(
                wheel_verb(&["cangate", "wheel", "mode", "hw1", word]),
                WheelVerb::Mode {
                    wheel: "hw1".into(),
                    mode: ModeArg::Automatic
                },
                "{word}"
            );
        }
        assert!(Cli::try_parse_from(["cangate", "wheel", "mode", "hw1", "fast"]).is_err());
        assert!(Cli::try_parse_from(["cangate", "wheel", "mode", "hw1"]).is_err());
        assert_eq!(ModeArg::Manual.pb(), pb::HandwheelMode::Manual);
        assert_eq!(ModeArg::Automatic.pb(), pb::HandwheelMode::Automatic);
    }

    #[test]
    fn parses_watch_list_and_show() {
        assert_eq!(
            wheel_verb(&["cangate", "wheel", "watch", "hw1", "--coalesce-ms", "50"]),
            WheelVerb::Watch(WatchArgs {
                wheels: vec!["hw1".into()],
                coalesce_ms: 50,
                for_secs: None,
            })
        );
        assert_eq!(
            wheel_verb(&["cangate", "wheel", "watch", "hw1", "hw2", "--for", "2.5"]),
            WheelVerb::Watch(WatchArgs {
                wheels: vec!["hw1".into(), "hw2".into()],
                coalesce_ms: 0,
                for_secs: Some(2.5),
            })
        );
        assert!(
            Cli::try_parse_from(["cangate", "wheel", "watch", "hw1", "--coalesce-ms", "-1"])
                .is_err()
        );
        assert!(Cli::try_parse_from(["cangate", "wheel", "watch", "--for", "0"]).is_err());
        let cli = Cli::try_parse_from(["cangate", "wheel", "list", "--json"]).unwrap();
        assert!(cli.json);
        assert!(matches!(
            cli.command,
            Command::Wheel(WheelArgs {
                verb: Some(WheelVerb::List { ref wheels })
            }) if wheels.is_empty()
        ));
        let cli = Cli::try_parse_from(["cangate", "wheel"]).unwrap();
        assert!(matches!(
            cli.command,
            Command::Wheel(WheelArgs { verb: None })
        ));
        assert_eq!(
            wheel_verb(&["cangate", "wheel", "show", "hw1"]),
            WheelVerb::Show {
                wheel: "hw1".into()
            }
        );
        assert!(Cli::try_parse_from(["cangate", "wheel", "show"]).is_err());
    }

    #[test]
    fn parses_sim_turn() {
        assert_eq!(
            turn_args(&[
                "cangate",
                "sim",
                "turn",
                "hw1",
                "--detents",
                "-20",
                "--axis",
                "x",
                "--mult",
                "10",
                "--loss",
                "0.1",
            ]),
            TurnArgs {
                wheel: "hw1".into(),
                detents: -20,
                axis: Some(AxisArg::X),
                mult: Some(10),
                loss: Some(0.1),
                max_consecutive_loss: None,
            }
        );
        let t = turn_args(&[
            "cangate",
            "sim",
            "turn",
            "hw1",
            "--detents",
            "20",
            "--axis",
            "Z",
            "--max-consecutive-loss",
            "3",
        ]);
        assert_eq!(
            (t.detents, t.axis, t.mult, t.max_consecutive_loss),
            (20, Some(AxisArg::Z), None, Some(3))
        );
        assert_eq!(AxisArg::Z.pb(), pb::WheelAxis::Z);
        for bad in [
            &["cangate", "sim", "turn", "hw1"][..],
            &[
                "cangate",
                "sim",
                "turn",
                "hw1",
                "--detents",
                "1",
                "--mult",
                "5",
            ],
            &[
                "cangate",
                "sim",
                "turn",
                "hw1",
                "--detents",
                "1",
                "--mult",
                "0",
            ],
            &[
                "cangate",
                "sim",
                "turn",
                "hw1",
                "--detents",
                "1",
                "--axis",
                "q",
            ],
            &[
                "cangate",
                "sim",
                "turn",
                "hw1",
                "--detents",
                "1",
                "--loss",
                "1.5",
            ],
            &[
                "cangate",
                "sim",
                "turn",
                "hw1",
                "--detents",
                "1",
                "--loss",
                "-0.1",
            ],
            &[
                "cangate",
                "sim",
                "turn",
                "hw1",
                "--detents",
                "1",
                "--max-consecutive-loss",
                "0",
            ],
            &["cangate", "sim", "turn", "--detents", "1"],
        ] {
            assert!(Cli::try_parse_from(bad).is_err(), "{bad:?}");
        }
        for m in ["1", "10", "100"] {
            let t = turn_args(&[
                "cangate",
                "sim",
                "turn",
                "hw1",
                "--detents",
                "1",
                "--mult",
                m,
            ]);
            assert_eq!(t.mult, Some(m.parse().unwrap()));
        }
    }

    fn feed(units: u32, direction: i32) -> pb::FeedEvent {
        pb::FeedEvent {
            handwheel: "hw1".into(),
            timestamp_us: 1_700_000_000_123_456,
            axis: pb::WheelAxis::X as i32,
            direction,
            units,
            sequence: 5,
            gap: 1,
            raw: 0x51,
            frames: 1,
            ..Default::default()
        }
    }

    #[test]
    fn event_lines() {
        assert_eq!(
            event_line(&feed(1, 1)),
            "(1700000000.123456)  hw1      X    +1  seq  5  gap  1"
        );
        let mut e = feed(3, -1);
        e.sequence = 12;
        e.gap = 3;
        e.compensated = 2;
        e.compensated_flag = true;
        assert_eq!(
            event_line(&e),
            "(1700000000.123456)  hw1      X    -3  seq 12  gap  3  COMP+2"
        );
        let mut e = feed(0, 1);
        e.gap = 0;
        e.duplicate = true;
        e.lost_before = 4;
        assert_eq!(
            event_line(&e),
            "(1700000000.123456)  hw1      X    +0  seq  5  gap  0  DUP  \
             [4 events lost before this one: this client read too slowly]"
        );
        let mut e = feed(0, 0);
        e.axis = pb::WheelAxis::Unspecified as i32;
        e.bad = true;
        e.note = "invalid axis code 7".into();
        assert_eq!(
            event_line(&e),
            "(1700000000.123456)  hw1      ?     0  seq  5  gap  1  BAD — invalid axis code 7"
        );
        let mut e = feed(10, 1);
        e.axis = pb::WheelAxis::Y as i32;
        e.baseline = true;
        e.frames = 10;
        e.note = "first frame".into();
        assert_eq!(
            event_line(&e),
            "(1700000000.123456)  hw1      Y   +10  seq  5  gap  1  10 frames  BASE — first frame"
        );

        let j = event_json(&feed(1, -1));
        assert_eq!(j["handwheel"], "hw1");
        assert_eq!(j["axis"], "X");
        assert_eq!(j["direction"], -1);
        assert_eq!(j["timestamp_us"], 1_700_000_000_123_456u64);
        let mut e = feed(0, 0);
        e.axis = 0;
        assert!(event_json(&e)["axis"].is_null());
    }

    fn wheel() -> pb::Handwheel {
        pb::Handwheel {
            name: "hw1".into(),
            bus: "can0".into(),
            node: 32,
            counter_layout: pb::CounterLayout::Nibble as i32,
            mode: pb::HandwheelMode::Manual as i32,
            stats: Some(pb::FeedStats {
                frames: 120,
                positive_units: vec![100, 0, 0, 0, 0],
                negative_units: vec![2, 3],
                gaps: 2,
                compensated_units: 5,
                duplicates: 1,
                ..Default::default()
            }),
            bindings: vec![pb::AxisBinding {
                wheel_axis: pb::WheelAxis::X as i32,
                axis: "X".into(),
                distance_per_unit: 0.001,
            }],
            binding: Some(pb::BindingStats {
                executed_units: 90,
                dropped_backlog: 2,
                dropped_not_enabled: 1,
                ..Default::default()
            }),
            ..Default::default()
        }
    }

    #[test]
    fn counters_bindings_and_json() {
        let w = wheel();
        assert_eq!(
            counters_line(&w, 1_700_000_001_000_000),
            "(1700000001.000000)  hw1      counters: frames 120  units X+98 Y-3  \
             gaps 2 (compensated 5)  duplicates 1  bad 0  binding executed 90 dropped 3 pending 0"
        );
        let units = HashMap::from([("X".to_string(), "mm".to_string())]);
        assert_eq!(bindings_text(&w, &units), "X->X 0.001mm");
        assert_eq!(bindings_text(&w, &HashMap::new()), "X->X 0.001");
        assert_eq!(net_units_text(&pb::FeedStats::default()), "0");
        let j = wheel_json(&w);
        assert_eq!(j["mode"], "manual");
        assert_eq!(j["counter_layout"], "nibble");
        assert_eq!(j["stats"]["net_units"]["X"], 98);
        assert_eq!(j["stats"]["net_units"]["Y"], -3);
        assert_eq!(j["stats"]["negative_units"]["V"], 0);
        assert_eq!(j["bindings"][0]["wheel_axis"], "X");
        assert_eq!(j["binding"]["dropped_backlog"], 2);
    }
}
