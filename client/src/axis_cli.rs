//! The axis verbs of the `cangate` CLI: `cangate axis …` over the `Axes`
//! service (`proto/cangate/v1/axes.proto`).
//!
//! The word after `axis` is either a verb (`list`, `stop`, `watch`, …) or an
//! axis name followed by its verb: `cangate axis X move 12.5` and
//! `cangate axis stop X Y`. Clap parses this as an optional positional
//! (the axis) in front of a subcommand (the verb): a word that is a verb
//! name is taken as the verb, anything else as the axis.
//!
//! Commands that need control of an axis take a lease for the duration of
//! the command ([`Control`]): acquired before, renewed in the background,
//! released after — also after an error or Ctrl-C.

use crate::cli_common::{Rpc, ctrl_c, positive, sleep_opt, status_error, time_text};
use anyhow::{Context, Result, anyhow, bail};
use cangate_client::{Client, pb};
use clap::{Args, Subcommand, ValueEnum};
use serde_json::{Value, json};
use std::collections::HashMap;
use std::io::Write;
use std::time::Duration;

type AxesClient = pb::axes_client::AxesClient<cangate_client::Transport>;

/// Client name shown to others as the holder of our leases.
const CLIENT_NAME: &str = "cangate-cli";
/// TTL of the leases the CLI takes (renewed every third of it).
const LEASE_TTL_MS: u32 = 2000;
/// Bound of the clean-up calls (release, stop after Ctrl-C).
const CLEANUP_TIMEOUT: Duration = Duration::from_secs(5);
/// Server-side bound of the stop that ends a jog, and the client-side one
/// around it.
const JOG_STOP_WAIT_MS: u32 = 30_000;

/// Extra help of `cangate axis`, shown after the options.
pub const AXIS_HELP: &str = "\
Forms:
  cangate axis [list [AXIS…]]              table of axes
  cangate axis AXIS [show]                 one axis in detail
  cangate axis AXIS enable|disable|home|reset-fault [--wait]
  cangate axis AXIS move POS [--rel] [--vel V] [--acc A] [--wait]
  cangate axis AXIS jog +|- --vel V [--acc A] [--for SECONDS]   (held until Ctrl-C)
  cangate axis AXIS stop|quick-stop [--wait]
  cangate axis stop AXIS… [--quick] [--wait]    (or --all)
  cangate axis watch [AXIS…] [--changes-only]
  cangate axis move-all AXIS=POS… [--vel V] [--acc A] [--wait]

The word after `axis` is a verb if it is one (list, show, enable, disable,
home, reset-fault, move, jog, stop, quick-stop, watch, move-all), otherwise
an axis name followed by its verb. Verbs over several axes (list, stop,
quick-stop, watch) take the names before or after the verb:
`axis X stop` = `axis stop X`. Values are in the axis's unit (mm, deg, …).

Control: enable, disable, home, reset-fault, move, jog and move-all take
control of their axes for the duration of the command (lease renewed in the
background, released at the end, also on Ctrl-C). With --lease TOKEN (or
CANGATE_LEASE) that existing lease is used, and kept. stop and quick-stop
need no control. Ctrl-C during home, move or move-all stops the axes.

Exit status: 0 on success; 1 on errors, and with --wait when a command did
not complete (fault, timeout, superseded, stopped).";

/// `cangate axis …`
#[derive(Args, Debug, PartialEq)]
pub struct AxisArgs {
    /// Axis name, before its verb: `cangate axis X move 10`.
    #[arg(value_name = "AXIS")]
    pub axis: Option<String>,
    /// Use this control lease (from AcquireControl) instead of taking one;
    /// it is renewed while the command runs and not released.
    #[arg(
        long,
        global = true,
        env = "CANGATE_LEASE",
        hide_env_values = true,
        value_name = "TOKEN"
    )]
    pub lease: Option<String>,
    /// What to do (default: `list`, or `show` after an axis name).
    #[command(subcommand)]
    pub verb: Option<AxisVerb>,
}

/// The verbs of `cangate axis`.
#[derive(Subcommand, Debug, PartialEq)]
pub enum AxisVerb {
    /// Table of axes (all, or the named ones): state, position, control.
    List {
        /// Only these axes.
        axes: Vec<String>,
    },
    /// One axis in detail: configuration and live state.
    #[command(override_usage = "cangate axis AXIS [show]")]
    Show,
    /// Switch the drive on (CiA 402 operation enabled).
    #[command(override_usage = "cangate axis AXIS enable [--wait [--timeout SECONDS]]")]
    Enable(WaitArgs),
    /// Switch the power stage off.
    #[command(override_usage = "cangate axis AXIS disable [--wait [--timeout SECONDS]]")]
    Disable(WaitArgs),
    /// Run the configured homing method.
    #[command(override_usage = "cangate axis AXIS home [--wait [--timeout SECONDS]]")]
    Home(WaitArgs),
    /// Reset a drive fault (the axis then needs `enable` again).
    #[command(override_usage = "cangate axis AXIS reset-fault [--wait [--timeout SECONDS]]")]
    ResetFault(WaitArgs),
    /// Move to a position (or by a distance with --rel).
    #[command(
        override_usage = "cangate axis AXIS move <POS> [--rel] [--vel V] [--acc A] [--wait [--timeout SECONDS]]"
    )]
    Move(MoveArgs),
    /// Jog while the command runs (dead-man): Ctrl-C or --for stops.
    #[command(override_usage = "cangate axis AXIS jog <+|-> --vel V [--acc A] [--for SECONDS]")]
    Jog(JogArgs),
    /// Decelerate to rest; several axes are stopped together (StopAxes).
    #[command(override_usage = "cangate axis AXIS stop [--quick] [--wait]\n       \
                      cangate axis stop AXIS... [--quick] [--wait [--timeout SECONDS]]\n       \
                      cangate axis stop --all [--quick] [--wait]")]
    Stop(StopArgs),
    /// CiA 402 quick stop (same as `stop --quick`).
    #[command(override_usage = "cangate axis AXIS quick-stop [--wait]\n       \
                      cangate axis quick-stop AXIS... [--wait [--timeout SECONDS]]\n       \
                      cangate axis quick-stop --all [--wait]")]
    QuickStop(StopArgs),
    /// Live state and events, one line per update, until Ctrl-C.
    #[command(override_usage = "cangate axis watch [AXIS...] [--changes-only] [--for SECONDS]")]
    Watch(WatchArgs),
    /// Coordinated move of several cyclic axes (start and arrive together).
    #[command(
        override_usage = "cangate axis move-all AXIS=POS... [--vel V] [--acc A] [--wait [--timeout SECONDS]]"
    )]
    MoveAll(MoveAllArgs),
}

/// `--wait [--timeout S]`
#[derive(Args, Debug, PartialEq, Clone, Copy, Default)]
pub struct WaitArgs {
    /// Return when the command has completed, failed or was superseded,
    /// and exit 1 unless it completed.
    #[arg(long)]
    pub wait: bool,
    /// Bound of --wait in seconds (default: the gateway's, 60 s).
    #[arg(long, value_name = "SECONDS", requires = "wait", value_parser = positive)]
    pub timeout: Option<f64>,
}

impl WaitArgs {
    fn timeout_ms(&self) -> u32 {
        self.timeout
            .map_or(0, |s| (s * 1e3).ceil().min(u32::MAX as f64) as u32)
    }
}

/// `move POS …`
#[derive(Args, Debug, PartialEq, Clone, Copy)]
pub struct MoveArgs {
    /// Target position (or distance with --rel), in the axis's unit.
    #[arg(allow_negative_numbers = true, value_name = "POS")]
    pub target: f64,
    /// Move by POS from the current target instead of to POS.
    #[arg(long, short = 'r', visible_alias = "relative")]
    pub rel: bool,
    /// Velocity (unit/s; default: the axis's).
    #[arg(long, value_parser = positive)]
    pub vel: Option<f64>,
    /// Acceleration and deceleration (unit/s²; default: the axis's).
    #[arg(long, value_parser = positive)]
    pub acc: Option<f64>,
    #[command(flatten)]
    pub wait: WaitArgs,
}

/// Jog direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Direction {
    /// Positive.
    #[value(name = "+", alias = "pos")]
    Positive,
    /// Negative.
    #[value(name = "-", alias = "neg")]
    Negative,
}

/// `jog +|- --vel V …`
#[derive(Args, Debug, PartialEq, Clone, Copy)]
pub struct JogArgs {
    /// Direction: + (positive) or - (negative).
    #[arg(value_name = "+|-", hide_possible_values = true)]
    pub direction: Direction,
    /// Speed (unit/s).
    #[arg(long, value_parser = positive)]
    pub vel: f64,
    /// Acceleration (unit/s²; default: the axis's).
    #[arg(long, value_parser = positive)]
    pub acc: Option<f64>,
    /// Stop by itself after this many seconds.
    #[arg(long = "for", value_name = "SECONDS", value_parser = positive)]
    pub for_secs: Option<f64>,
}

/// `stop [AXIS…] …`
#[derive(Args, Debug, PartialEq)]
pub struct StopArgs {
    /// The axes (in addition to one named before the verb).
    pub axes: Vec<String>,
    /// Quick stop instead of the profile deceleration.
    #[arg(long)]
    pub quick: bool,
    /// Every axis of the gateway.
    #[arg(long, conflicts_with = "axes")]
    pub all: bool,
    #[command(flatten)]
    pub wait: WaitArgs,
}

/// `watch [AXIS…] …`
#[derive(Args, Debug, PartialEq)]
pub struct WatchArgs {
    /// The axes (default: all).
    pub axes: Vec<String>,
    /// Skip statuses identical to the previous one (an axis at rest is
    /// quiet).
    #[arg(long)]
    pub changes_only: bool,
    /// End after this many seconds.
    #[arg(long = "for", value_name = "SECONDS", value_parser = positive)]
    pub for_secs: Option<f64>,
}

/// `move-all AXIS=POS… …`
#[derive(Args, Debug, PartialEq)]
pub struct MoveAllArgs {
    /// Absolute targets: X=10 Y=-2.5.
    #[arg(required = true, value_name = "AXIS=POS", value_parser = parse_target)]
    pub targets: Vec<TargetArg>,
    /// Velocity limit of every axis (unit/s; default: the axes').
    #[arg(long, value_parser = positive)]
    pub vel: Option<f64>,
    /// Acceleration limit of every axis (unit/s²; default: the axes').
    #[arg(long, value_parser = positive)]
    pub acc: Option<f64>,
    #[command(flatten)]
    pub wait: WaitArgs,
}

/// One `AXIS=POS` of `move-all`.
#[derive(Debug, Clone, PartialEq)]
pub struct TargetArg {
    /// Axis name.
    pub axis: String,
    /// Absolute target.
    pub target: f64,
}

fn parse_target(text: &str) -> Result<TargetArg, String> {
    let (axis, pos) = text
        .split_once('=')
        .ok_or_else(|| format!("{text:?} is not AXIS=POS"))?;
    let target = pos
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
        .ok_or_else(|| format!("{pos:?} is not a position"))?;
    if axis.is_empty() {
        return Err(format!("{text:?} has no axis name"));
    }
    Ok(TargetArg {
        axis: axis.to_string(),
        target,
    })
}

// ------------------------------------------------------------ rpc helpers

/// Runs a clean-up call with a bound; a second Ctrl-C leaves at once. A
/// Ctrl-C in the first half second does not count: it is the same
/// impatient press (or a signal sent twice, as `timeout` does), and the
/// clean-up (a stop) matters more.
async fn cleanup<T>(what: &str, bound: Duration, f: impl Future<Output = T>) -> Option<T> {
    let again = async {
        tokio::time::sleep(Duration::from_millis(500)).await;
        ctrl_c().await;
    };
    tokio::select! {
        r = tokio::time::timeout(bound, f) => {
            if r.is_err() {
                eprintln!("cangate: {what}: no answer within {} s", bound.as_secs());
            }
            r.ok()
        }
        _ = again => {
            eprintln!("cangate: interrupted again during {what}; leaving");
            std::process::exit(130);
        }
    }
}

// ---------------------------------------------------------------- control

/// Control of a set of axes for the duration of one command.
struct Control {
    client: AxesClient,
    lease: String,
    /// Taken by us (released at the end) rather than given with --lease.
    owned: bool,
    renewer: tokio::task::JoinHandle<()>,
}

impl Control {
    /// Takes control of `axes`, or adopts the `given` lease.
    async fn take(client: &Client, axes: &[String], given: Option<String>) -> Result<Control> {
        let mut c = client.axes_client();
        let names = axes.join(", ");
        let (lease, ttl_ms, owned) = match given {
            Some(lease) => {
                // Renewing at once checks the token and learns its TTL.
                let l = c
                    .renew_control(pb::RenewControlRequest {
                        lease: lease.clone(),
                    })
                    .await
                    .rpc()
                    .context("the lease given with --lease / CANGATE_LEASE")?;
                (lease, l.ttl_ms, false)
            }
            None => {
                let l = c
                    .acquire_control(pb::AcquireControlRequest {
                        axes: axes.to_vec(),
                        ttl_ms: LEASE_TTL_MS,
                        client_name: CLIENT_NAME.to_string(),
                    })
                    .await
                    .rpc()
                    .with_context(|| format!("cannot take control of {names}"))?;
                (l.lease, l.ttl_ms, true)
            }
        };
        let ttl_ms = if ttl_ms == 0 { LEASE_TTL_MS } else { ttl_ms };
        let renewer = tokio::spawn(renew(c.clone(), lease.clone(), ttl_ms));
        Ok(Control {
            client: c,
            lease,
            owned,
            renewer,
        })
    }

    /// Stops renewing and gives the lease back (when it is ours).
    async fn release(self) {
        self.renewer.abort();
        if !self.owned {
            return;
        }
        let req = pb::ReleaseControlRequest {
            lease: self.lease.clone(),
        };
        let mut c = self.client.clone();
        if let Some(Err(e)) =
            cleanup("releasing control", CLEANUP_TIMEOUT, c.release_control(req)).await
        {
            eprintln!(
                "cangate: releasing control: {} (the lease lapses by itself)",
                status_error(e)
            );
        }
    }
}

impl Drop for Control {
    fn drop(&mut self) {
        self.renewer.abort();
    }
}

/// Renews `lease` every third of its TTL until aborted.
async fn renew(mut c: AxesClient, lease: String, ttl_ms: u32) {
    let period = Duration::from_millis(u64::from(ttl_ms / 3).max(10));
    let mut tick = tokio::time::interval_at(tokio::time::Instant::now() + period, period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut failing = false;
    loop {
        tick.tick().await;
        let r = c
            .renew_control(pb::RenewControlRequest {
                lease: lease.clone(),
            })
            .await;
        match r {
            Ok(_) => failing = false,
            Err(e) if !failing => {
                failing = true;
                eprintln!("cangate: renewing control failed: {}", status_error(e));
            }
            Err(_) => {}
        }
    }
}

// --------------------------------------------------------------- names

fn drive_state_name(s: i32) -> &'static str {
    use pb::DriveState as D;
    match D::try_from(s) {
        Ok(D::NotReadyToSwitchOn) => "not-ready-to-switch-on",
        Ok(D::SwitchOnDisabled) => "switch-on-disabled",
        Ok(D::ReadyToSwitchOn) => "ready-to-switch-on",
        Ok(D::SwitchedOn) => "switched-on",
        Ok(D::OperationEnabled) => "operation-enabled",
        Ok(D::QuickStopActive) => "quick-stop-active",
        Ok(D::FaultReactionActive) => "fault-reaction-active",
        Ok(D::Fault) => "fault",
        _ => "unknown",
    }
}

fn activity_name(a: i32) -> &'static str {
    use pb::AxisActivity as A;
    match A::try_from(a) {
        Ok(A::Idle) => "idle",
        Ok(A::Switching) => "switching",
        Ok(A::Homing) => "homing",
        Ok(A::Moving) => "moving",
        Ok(A::Jogging) => "jogging",
        Ok(A::Stopping) => "stopping",
        _ => "unknown",
    }
}

fn backend_name(b: i32) -> &'static str {
    match pb::AxisBackend::try_from(b) {
        Ok(pb::AxisBackend::Cia402) => "cia402",
        Ok(pb::AxisBackend::Cansmc) => "cansmc",
        _ => "unknown",
    }
}

fn position_mode_name(m: i32) -> &'static str {
    match pb::PositionMode::try_from(m) {
        Ok(pb::PositionMode::Profile) => "profile",
        Ok(pb::PositionMode::Cyclic) => "cyclic",
        _ => "unknown",
    }
}

/// "pdo", "sdo every 10 ms", or "-" (CANsmc axes).
fn process_data_text(a: &pb::Axis) -> String {
    match pb::ProcessDataPath::try_from(a.process_data) {
        Ok(pb::ProcessDataPath::Pdo) => "pdo".into(),
        Ok(pb::ProcessDataPath::Sdo) => format!("sdo every {} ms", a.sdo_poll_ms),
        _ => "-".into(),
    }
}

fn stop_kind_name(k: i32) -> &'static str {
    match pb::StopKind::try_from(k) {
        Ok(pb::StopKind::Halt) => "halt",
        Ok(pb::StopKind::QuickStop) => "quick-stop",
        _ => "unknown",
    }
}

/// Machine name of an outcome (JSON).
fn outcome_name(o: i32) -> &'static str {
    use pb::Outcome as O;
    match O::try_from(o) {
        Ok(O::Accepted) => "accepted",
        Ok(O::Completed) => "completed",
        Ok(O::Superseded) => "superseded",
        Ok(O::Fault) => "fault",
        Ok(O::Timeout) => "timeout",
        Ok(O::Stopped) => "stopped",
        _ => "unspecified",
    }
}

/// Human phrase of an outcome ("move completed", "move timed out").
fn outcome_phrase(o: i32) -> &'static str {
    use pb::Outcome as O;
    match O::try_from(o) {
        Ok(O::Accepted) => "accepted",
        Ok(O::Completed) => "completed",
        Ok(O::Superseded) => "superseded",
        Ok(O::Fault) => "ended by a fault",
        Ok(O::Timeout) => "timed out",
        Ok(O::Stopped) => "stopped",
        _ => "ended (outcome unknown)",
    }
}

/// `move completed — target reached at 12.500 mm`
fn outcome_text(command: &str, outcome: i32, detail: &str) -> String {
    let phrase = outcome_phrase(outcome);
    if detail.is_empty() {
        format!("{command} {phrase}")
    } else {
        format!("{command} {phrase} — {detail}")
    }
}

/// `X: move completed — target reached at 12.500 mm`
pub fn format_outcome(axis: &str, command: &str, outcome: i32, detail: &str) -> String {
    format!("{axis}: {}", outcome_text(command, outcome, detail))
}

/// Whether an outcome counts as success. Faults and timeouts never do;
/// with `waited`, only completion does (and, for a stop, "stopped").
pub fn outcome_ok(outcome: i32, waited: bool, is_stop: bool) -> bool {
    use pb::Outcome as O;
    match O::try_from(outcome) {
        Ok(O::Completed | O::Accepted) => true,
        Ok(O::Stopped) => is_stop || !waited,
        Ok(O::Superseded) => !waited,
        _ => false,
    }
}

// ------------------------------------------------------------- formatting

/// The fault of a status: null when there is none. A fault without a code
/// (a drive fault without an EMCY, a lost node) has its text.
fn fault_json(code: u32, text: &str) -> Value {
    if code == 0 && text.is_empty() {
        Value::Null
    } else {
        json!({"code": format!("0x{code:04X}"), "text": text})
    }
}

fn status_json(s: &pb::AxisStatus, unit: Option<&str>) -> Value {
    let mut v = json!({
        "axis": s.axis,
        "state": drive_state_name(s.state),
        "statusword": format!("0x{:04X}", s.statusword),
        "mode": s.mode,
        "activity": activity_name(s.activity),
        "position": s.position,
        "velocity": s.velocity,
        "demand_position": s.demand_position,
        "following_error": s.following_error,
        "homed": s.homed,
        "node_lost": s.node_lost,
        "fault": fault_json(s.fault_code, &s.fault_text),
        "controlled_by": s.controlled_by,
        "lease_remaining_ms": s.lease_remaining_ms,
        "timestamp_us": s.timestamp_us,
    });
    if let Some(u) = unit {
        v["unit"] = json!(u);
    }
    v
}

fn axis_json(a: &pb::Axis) -> Value {
    json!({
        "name": a.name,
        "backend": backend_name(a.backend),
        "bus": a.bus,
        "node": a.node,
        "unit": a.unit,
        "counts_per_unit": a.counts_per_unit,
        "min_position": a.min_position,
        "max_position": a.max_position,
        "max_velocity": a.max_velocity,
        "max_acceleration": a.max_acceleration,
        "position_mode": position_mode_name(a.position_mode),
        "process_data": process_data_text(a),
        "stop_on_loss": stop_kind_name(a.stop_on_loss),
        "jog_deadman_ms": a.jog_deadman_ms,
        "status": a.status.as_ref().map(|s| status_json(s, None)),
    })
}

fn result_json(axis: &str, command: &str, r: &pb::AxisCommandResponse) -> Value {
    json!({
        "axis": axis,
        "command": command,
        "outcome": outcome_name(r.outcome),
        "detail": r.detail,
        "status": r.status.as_ref().map(|s| status_json(s, None)),
    })
}

fn fault_text(s: &pb::AxisStatus) -> String {
    if s.fault_code != 0 {
        format!("0x{:04X} {}", s.fault_code, s.fault_text)
    } else if s.node_lost {
        "node lost".to_string()
    } else if !s.fault_text.is_empty() {
        s.fault_text.clone()
    } else {
        "-".to_string()
    }
}

/// One line of `watch` for a status.
fn status_line(s: &pb::AxisStatus, unit: &str) -> String {
    let mut line = format!(
        "{}  {:<8} {:<21} {:<9} pos {:>12.3} {unit}  vel {:>10.3} {unit}/s  ferr {:.3}",
        time_text(s.timestamp_us),
        s.axis,
        drive_state_name(s.state),
        activity_name(s.activity),
        s.position,
        s.velocity,
        s.following_error,
    );
    if s.fault_code != 0 || s.node_lost || !s.fault_text.is_empty() {
        line.push_str("  FAULT ");
        line.push_str(&fault_text(s));
    }
    line
}

/// Whether a fault event reports a fault (true) or its clearing. Gateways
/// before `Fault.active` never set it; from them a clearing is code 0 with
/// no text.
fn fault_active(f: &pb::Fault) -> bool {
    f.active || f.code != 0 || !f.text.is_empty()
}

/// One line of `watch` for an event; `None` for an empty event.
fn event_line(e: &pb::AxisEvent) -> Option<String> {
    use pb::axis_event::Kind;
    let what = match e.kind.as_ref()? {
        Kind::MotionDone(m) => outcome_text(&m.command, m.outcome, &m.detail),
        Kind::Fault(f) if !fault_active(f) => "fault cleared".to_string(),
        Kind::Fault(f) if f.code == 0 => format!("FAULT {}", f.text),
        Kind::Fault(f) => format!("FAULT 0x{:04X} {}", f.code, f.text),
        Kind::Control(c) => {
            let holder = if c.holder.is_empty() {
                "nobody"
            } else {
                &c.holder
            };
            let mut t = format!("control {}: now {holder}", c.reason);
            if !c.previous.is_empty() {
                t.push_str(&format!(", was {}", c.previous));
            }
            t
        }
        Kind::Node(n) if n.lost => format!("NODE LOST: {}", n.reason),
        Kind::Node(n) => format!("node back: {}", n.reason),
        Kind::Lost(n) => format!("{n} updates lost (this client read too slowly)"),
    };
    Some(format!(
        "{}  {:<8} {what}",
        time_text(e.timestamp_us),
        e.axis
    ))
}

fn event_json(e: &pb::AxisEvent) -> Option<Value> {
    use pb::axis_event::Kind;
    let mut v = match e.kind.as_ref()? {
        Kind::MotionDone(m) => json!({
            "event": "motion_done",
            "command": m.command,
            "outcome": outcome_name(m.outcome),
            "detail": m.detail,
        }),
        Kind::Fault(f) => json!({
            "event": "fault",
            "active": fault_active(f),
            "code": format!("0x{:04X}", f.code),
            "text": f.text,
        }),
        Kind::Control(c) => json!({
            "event": "control",
            "holder": c.holder,
            "previous": c.previous,
            "reason": c.reason,
        }),
        Kind::Node(n) => json!({
            "event": if n.lost { "node_lost" } else { "node_back" },
            "reason": n.reason,
        }),
        Kind::Lost(n) => json!({"event": "lost", "count": n}),
    };
    v["axis"] = json!(e.axis);
    v["timestamp_us"] = json!(e.timestamp_us);
    Some(v)
}

// -------------------------------------------------------------- commands

/// Checks what clap cannot: a verb that needs an axis got one, before
/// anything is sent.
pub fn validate(args: &AxisArgs) -> Result<()> {
    let per_axis = match &args.verb {
        Some(AxisVerb::Show) => Some("show"),
        Some(AxisVerb::Enable(_)) => Some("enable"),
        Some(AxisVerb::Disable(_)) => Some("disable"),
        Some(AxisVerb::Home(_)) => Some("home"),
        Some(AxisVerb::ResetFault(_)) => Some("reset-fault"),
        Some(AxisVerb::Move(_)) => Some("move"),
        Some(AxisVerb::Jog(_)) => Some("jog"),
        _ => None,
    };
    if let Some(verb) = per_axis
        && args.axis.is_none()
    {
        bail!("`{verb}` needs an axis before it: cangate axis AXIS {verb} …");
    }
    match &args.verb {
        Some(AxisVerb::MoveAll(_)) if args.axis.is_some() => bail!(
            "move-all takes AXIS=POS pairs after it, not an axis before it: \
             cangate axis move-all X=10 Y=20"
        ),
        Some(AxisVerb::Stop(s) | AxisVerb::QuickStop(s))
            if !s.all && s.axes.is_empty() && args.axis.is_none() =>
        {
            bail!("name the axes to stop (cangate axis stop X Y), or give --all")
        }
        _ => Ok(()),
    }
}

/// `cangate axis …`
pub async fn run(client: &mut Client, as_json: bool, args: AxisArgs) -> Result<()> {
    validate(&args)?;
    let AxisArgs { axis, lease, verb } = args;
    let ctx = Ctx {
        client: client.clone(),
        json: as_json,
        lease,
    };
    let need = |verb: &str| {
        axis.clone()
            .ok_or_else(|| anyhow!("`{verb}` needs an axis: cangate axis AXIS {verb} …"))
    };
    let with_named = |axes: Vec<String>| axis.iter().cloned().chain(axes).collect::<Vec<_>>();
    match verb {
        None => match &axis {
            None => list(&ctx, &[]).await,
            Some(a) => show(&ctx, a).await,
        },
        Some(AxisVerb::List { axes }) => list(&ctx, &with_named(axes)).await,
        Some(AxisVerb::Show) => show(&ctx, &need("show")?).await,
        Some(AxisVerb::Enable(w)) => single(&ctx, &need("enable")?, Cmd::Enable, w).await,
        Some(AxisVerb::Disable(w)) => single(&ctx, &need("disable")?, Cmd::Disable, w).await,
        Some(AxisVerb::Home(w)) => single(&ctx, &need("home")?, Cmd::Home, w).await,
        Some(AxisVerb::ResetFault(w)) => {
            single(&ctx, &need("reset-fault")?, Cmd::ResetFault, w).await
        }
        Some(AxisVerb::Move(m)) => {
            let cmd = Cmd::Move {
                target: m.target,
                relative: m.rel,
                velocity: m.vel.unwrap_or(0.0),
                acceleration: m.acc.unwrap_or(0.0),
            };
            single(&ctx, &need("move")?, cmd, m.wait).await
        }
        Some(AxisVerb::Jog(j)) => jog(&ctx, &need("jog")?, j).await,
        Some(AxisVerb::Stop(s)) => {
            let quick = s.quick;
            stop(&ctx, with_named(s.axes), quick, s.all, s.wait).await
        }
        Some(AxisVerb::QuickStop(s)) => stop(&ctx, with_named(s.axes), true, s.all, s.wait).await,
        Some(AxisVerb::Watch(w)) => {
            watch(&ctx, with_named(w.axes), w.changes_only, w.for_secs).await
        }
        Some(AxisVerb::MoveAll(m)) => move_all(&ctx, m).await,
    }
}

/// What every command needs.
struct Ctx {
    client: Client,
    json: bool,
    lease: Option<String>,
}

impl Ctx {
    /// Control for `axes`: the given lease or a new one.
    async fn control(&self, axes: &[String]) -> Result<Control> {
        Control::take(&self.client, axes, self.lease.clone()).await
    }
}

/// A single-axis command.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Cmd {
    Enable,
    Disable,
    Home,
    ResetFault,
    Stop,
    QuickStop,
    Move {
        target: f64,
        relative: bool,
        velocity: f64,
        acceleration: f64,
    },
}

impl Cmd {
    fn name(self) -> &'static str {
        match self {
            Cmd::Enable => "enable",
            Cmd::Disable => "disable",
            Cmd::Home => "home",
            Cmd::ResetFault => "reset-fault",
            Cmd::Stop => "stop",
            Cmd::QuickStop => "quick-stop",
            Cmd::Move { .. } => "move",
        }
    }

    fn is_stop(self) -> bool {
        matches!(self, Cmd::Stop | Cmd::QuickStop)
    }

    /// Whether Ctrl-C while it runs should stop the axis.
    fn moves(self) -> bool {
        matches!(self, Cmd::Home | Cmd::Move { .. })
    }
}

async fn send(
    c: &mut AxesClient,
    axis: &str,
    cmd: Cmd,
    options: pb::CommandOptions,
) -> Result<pb::AxisCommandResponse> {
    let req = || pb::AxisCommandRequest {
        axis: axis.to_string(),
        options: Some(options.clone()),
    };
    let r = match cmd {
        Cmd::Enable => c.enable(req()).await,
        Cmd::Disable => c.disable(req()).await,
        Cmd::Home => c.home(req()).await,
        Cmd::ResetFault => c.reset_fault(req()).await,
        Cmd::Stop => c.stop(req()).await,
        Cmd::QuickStop => c.quick_stop(req()).await,
        Cmd::Move {
            target,
            relative,
            velocity,
            acceleration,
        } => {
            c.r#move(pb::MoveRequest {
                axis: axis.to_string(),
                target,
                relative,
                velocity,
                acceleration,
                options: Some(options.clone()),
            })
            .await
        }
    };
    r.rpc().with_context(|| format!("{axis}: {}", cmd.name()))
}

/// Stops `axes` after Ctrl-C or a client-side timeout (best effort, not
/// waited for).
async fn stop_after(client: &Client, axes: &[String], why: &str) {
    eprintln!("cangate: {why}: stopping {}", axes.join(", "));
    let mut c = client.axes_client();
    let r = cleanup("stopping", CLEANUP_TIMEOUT, async {
        match axes {
            [one] => send(&mut c, one, Cmd::Stop, pb::CommandOptions::default())
                .await
                .map(|_| ()),
            _ => c
                .stop_axes(pb::StopAxesRequest {
                    axes: axes.to_vec(),
                    quick: false,
                    wait: false,
                })
                .await
                .rpc()
                .map(|_| ()),
        }
    })
    .await;
    if let Some(Err(e)) = r {
        eprintln!("cangate: stopping failed: {e:#}");
    }
}

/// Prints the result of a command on one axis; an error when it failed.
fn report(
    as_json: bool,
    axis: &str,
    command: &str,
    r: &pb::AxisCommandResponse,
    waited: bool,
    is_stop: bool,
) -> Result<()> {
    let line = format_outcome(axis, command, r.outcome, &r.detail);
    let ok = outcome_ok(r.outcome, waited, is_stop);
    let mut out = std::io::stdout().lock();
    if as_json {
        writeln!(out, "{}", result_json(axis, command, r))?;
    } else if ok {
        writeln!(out, "{line}")?;
    }
    out.flush()?;
    if ok { Ok(()) } else { Err(anyhow!(line)) }
}

/// Prints the results of a command on several axes (request order).
fn report_multi(
    as_json: bool,
    axes: &[String],
    command: &str,
    results: &[pb::AxisCommandResponse],
    waited: bool,
    is_stop: bool,
) -> Result<()> {
    let name = |i: usize, r: &pb::AxisCommandResponse| -> String {
        match &r.status {
            Some(s) if !s.axis.is_empty() => s.axis.clone(),
            _ => axes.get(i).cloned().unwrap_or_default(),
        }
    };
    let mut out = std::io::stdout().lock();
    let mut failed = 0;
    let mut docs = Vec::new();
    for (i, r) in results.iter().enumerate() {
        let axis = name(i, r);
        let ok = outcome_ok(r.outcome, waited, is_stop);
        if !ok {
            failed += 1;
        }
        if as_json {
            docs.push(result_json(&axis, command, r));
            continue;
        }
        let line = format_outcome(&axis, command, r.outcome, &r.detail);
        if ok {
            writeln!(out, "{line}")?;
        } else {
            eprintln!("cangate: {line}");
        }
    }
    if as_json {
        writeln!(out, "{}", serde_json::to_string_pretty(&docs)?)?;
    }
    out.flush()?;
    if failed > 0 {
        bail!(
            "{command}: {failed} of {} axes did not succeed",
            results.len()
        );
    }
    Ok(())
}

/// enable, disable, home, reset-fault, move, stop, quick-stop on one axis.
async fn single(ctx: &Ctx, axis: &str, cmd: Cmd, w: WaitArgs) -> Result<()> {
    let control = if cmd.is_stop() {
        None
    } else {
        Some(ctx.control(&[axis.to_string()]).await?)
    };
    let options = pb::CommandOptions {
        lease: control
            .as_ref()
            .map(|c| c.lease.clone())
            .unwrap_or_default(),
        wait: w.wait,
        wait_timeout_ms: w.timeout_ms(),
    };
    let mut c = ctx.client.axes_client();
    let result = tokio::select! {
        r = send(&mut c, axis, cmd, options) => r,
        _ = ctrl_c() => {
            if cmd.moves() {
                stop_after(&ctx.client, &[axis.to_string()], "interrupted").await;
            }
            Err(anyhow!("{axis}: {} interrupted", cmd.name()))
        }
    };
    if let Some(control) = control {
        control.release().await;
    }
    report(ctx.json, axis, cmd.name(), &result?, w.wait, cmd.is_stop())
}

/// `stop` / `quick-stop` of one or several axes.
async fn stop(ctx: &Ctx, axes: Vec<String>, quick: bool, all: bool, w: WaitArgs) -> Result<()> {
    let axes = if all {
        ctx.client
            .clone()
            .list_axes()
            .await?
            .into_iter()
            .map(|a| a.name)
            .collect()
    } else {
        axes
    };
    let cmd = if quick { Cmd::QuickStop } else { Cmd::Stop };
    match axes.as_slice() {
        [] if all => bail!("the gateway has no axes"),
        [] => bail!("name the axes to stop (cangate axis stop X Y), or --all"),
        [one] => single(ctx, one, cmd, w).await,
        _ => {
            let mut c = ctx.client.axes_client();
            let req = pb::StopAxesRequest {
                axes: axes.clone(),
                quick,
                wait: w.wait,
            };
            let names = axes.join(", ");
            let r = tokio::select! {
                r = c.stop_axes(req) => r.rpc().with_context(|| format!("{names}: {}", cmd.name()))?,
                _ = sleep_opt(w.timeout) => bail!("{names}: not all at rest within {} s", w.timeout.unwrap_or_default()),
                _ = ctrl_c() => bail!("{names}: {} interrupted", cmd.name()),
            };
            report_multi(ctx.json, &axes, cmd.name(), &r.results, w.wait, true)
        }
    }
}

/// `move-all X=10 Y=20 …`: one coordinated MoveAxes.
async fn move_all(ctx: &Ctx, m: MoveAllArgs) -> Result<()> {
    let axes: Vec<String> = m.targets.iter().map(|t| t.axis.clone()).collect();
    let control = ctx.control(&axes).await?;
    let req = pb::MoveAxesRequest {
        targets: m
            .targets
            .iter()
            .map(|t| pb::AxisTarget {
                axis: t.axis.clone(),
                target: t.target,
                velocity: m.vel.unwrap_or(0.0),
                acceleration: m.acc.unwrap_or(0.0),
            })
            .collect(),
        lease: control.lease.clone(),
        wait: m.wait.wait,
    };
    let mut c = ctx.client.axes_client();
    let names = axes.join(", ");
    // A client-side --timeout or Ctrl-C leaves the axes moving: stop them.
    let result = tokio::select! {
        r = c.move_axes(req) => r.rpc().with_context(|| format!("{names}: move-all")),
        _ = sleep_opt(m.wait.timeout) => {
            let t = m.wait.timeout.unwrap_or_default();
            stop_after(&ctx.client, &axes, &format!("not all arrived within {t} s")).await;
            Err(anyhow!("{names}: move-all timed out after {t} s"))
        }
        _ = ctrl_c() => {
            stop_after(&ctx.client, &axes, "interrupted").await;
            Err(anyhow!("{names}: move-all interrupted"))
        }
    };
    control.release().await;
    report_multi(
        ctx.json,
        &axes,
        "move",
        &result?.results,
        m.wait.wait,
        false,
    )
}

/// How a jog ended.
enum JogEnd {
    /// Ctrl-C.
    Interrupted,
    /// `--for` ran out.
    TimeUp,
    /// The gateway ended it (stopped by someone, dead-man, fault, …).
    Ended(pb::MotionDone),
}

/// Jog repeat period: a third of the dead-man time.
fn jog_period(deadman_ms: u32) -> Duration {
    if deadman_ms == 0 {
        return Duration::from_millis(100);
    }
    Duration::from_millis(u64::from(deadman_ms / 3).clamp(10, 1000))
}

/// Next item of an optional stream; pends forever once it is gone.
async fn next_update(s: &mut Option<tonic::Streaming<pb::AxisUpdate>>) -> Option<pb::AxisUpdate> {
    let Some(stream) = s.as_mut() else {
        return std::future::pending().await;
    };
    match stream.message().await {
        Ok(Some(u)) => Some(u),
        _ => {
            *s = None;
            None
        }
    }
}

/// `jog +|- --vel V`: Jog repeated within the dead-man time until Ctrl-C,
/// `--for` or the gateway ending it; then Stop.
async fn jog(ctx: &Ctx, axis: &str, j: JogArgs) -> Result<()> {
    let mut c = ctx.client.axes_client();
    let info = c
        .get_axis(pb::GetAxisRequest {
            axis: axis.to_string(),
        })
        .await
        .rpc()
        .with_context(|| axis.to_string())?;
    let period = jog_period(info.jog_deadman_ms);
    let velocity = match j.direction {
        Direction::Positive => j.vel,
        Direction::Negative => -j.vel,
    };
    let control = ctx.control(&[axis.to_string()]).await?;
    // The state stream tells when the gateway ends the jog (someone pressed
    // stop, a fault): then it must not be restarted by the next Jog.
    let mut updates = c
        .stream_axis_state(pb::StreamAxisStateRequest {
            axes: vec![axis.to_string()],
            changes_only: true,
        })
        .await
        .ok()
        .map(tonic::Response::into_inner);
    let req = pb::JogRequest {
        axis: axis.to_string(),
        velocity,
        acceleration: j.acc.unwrap_or(0.0),
        options: Some(pb::CommandOptions {
            lease: control.lease.clone(),
            wait: false,
            wait_timeout_ms: 0,
        }),
    };
    let jog_once = |mut c: AxesClient, req: pb::JogRequest| async move {
        let r = c
            .jog(req)
            .await
            .rpc()
            .with_context(|| format!("{axis}: jog"))?;
        if outcome_ok(r.outcome, false, false) {
            Ok(r)
        } else {
            Err(anyhow!(format_outcome(axis, "jog", r.outcome, &r.detail)))
        }
    };

    let mut started = false;
    let ended: Result<JogEnd> = async {
        let interrupt = ctrl_c();
        tokio::pin!(interrupt);
        let time_up = sleep_opt(j.for_secs);
        tokio::pin!(time_up);
        tokio::select! {
            r = jog_once(c.clone(), req.clone()) => { r?; }
            _ = &mut interrupt => return Ok(JogEnd::Interrupted),
        }
        started = true;
        if !ctx.json {
            eprintln!(
                "{axis}: jogging at {velocity:+.3} {}/s — Ctrl-C to stop",
                info.unit
            );
        }
        let mut tick = tokio::time::interval_at(tokio::time::Instant::now() + period, period);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tokio::select! {
                _ = &mut interrupt => return Ok(JogEnd::Interrupted),
                _ = &mut time_up => return Ok(JogEnd::TimeUp),
                r = async {
                    tick.tick().await;
                    jog_once(c.clone(), req.clone()).await
                } => { r?; }
                u = next_update(&mut updates) => {
                    use pb::axis_event::Kind;
                    use pb::axis_update::Update;
                    if let Some(pb::AxisUpdate { update: Some(Update::Event(e)) }) = u
                        && let Some(Kind::MotionDone(done)) = e.kind
                        && done.command == "jog"
                    {
                        return Ok(JogEnd::Ended(done));
                    }
                }
            }
        }
    }
    .await;

    let result = match ended {
        Ok(JogEnd::Ended(done)) => {
            // The gateway ended the jog: no stop needed, but it did not end
            // as asked.
            if ctx.json {
                let doc = json!({"axis": axis, "command": "jog", "outcome": outcome_name(done.outcome), "detail": done.detail});
                // An error follows anyway; a closed stdout changes nothing.
                let _ = writeln!(std::io::stdout(), "{doc}");
            }
            Err(anyhow!(format_outcome(
                axis,
                "jog",
                done.outcome,
                &done.detail
            )))
        }
        Ok(JogEnd::Interrupted | JogEnd::TimeUp) => {
            let options = pb::CommandOptions {
                lease: String::new(),
                wait: true,
                wait_timeout_ms: JOG_STOP_WAIT_MS,
            };
            let bound = Duration::from_millis(u64::from(JOG_STOP_WAIT_MS) + 5000);
            match cleanup(
                "stopping the jog",
                bound,
                send(&mut c, axis, Cmd::Stop, options),
            )
            .await
            {
                Some(Ok(r)) => report(ctx.json, axis, "stop", &r, true, true),
                Some(Err(e)) => Err(e),
                None => Err(anyhow!("{axis}: the stop did not complete in time")),
            }
        }
        Err(e) => {
            if started {
                stop_quietly(&ctx.client, axis).await;
            }
            Err(e)
        }
    };
    control.release().await;
    result
}

/// Stops an axis after an error (no message unless the stop fails too).
async fn stop_quietly(client: &Client, axis: &str) {
    let mut c = client.axes_client();
    let r = cleanup(
        "stopping",
        CLEANUP_TIMEOUT,
        send(&mut c, axis, Cmd::Stop, pb::CommandOptions::default()),
    )
    .await;
    if let Some(Err(e)) = r {
        eprintln!("cangate: stopping failed: {e:#}");
    }
}

/// `list [AXIS…]`
async fn list(ctx: &Ctx, names: &[String]) -> Result<()> {
    let mut axes = ctx.client.clone().list_axes().await?;
    if !names.is_empty() {
        if let Some(unknown) = names.iter().find(|n| !axes.iter().any(|a| &a.name == *n)) {
            bail!("unknown axis {unknown:?}");
        }
        axes.retain(|a| names.contains(&a.name));
    }
    let mut out = std::io::stdout().lock();
    if ctx.json {
        let list: Vec<_> = axes.iter().map(axis_json).collect();
        writeln!(out, "{}", serde_json::to_string_pretty(&list)?)?;
        return Ok(());
    }
    writeln!(
        out,
        "{:<8} {:<7} {:<10} {:<21} {:<9} {:>16} {:>18} {:<5} {:<24} CONTROLLED BY",
        "AXIS",
        "BACKEND",
        "BUS/NODE",
        "STATE",
        "ACTIVITY",
        "POSITION",
        "VELOCITY",
        "HOMED",
        "FAULT"
    )?;
    for a in &axes {
        let s = a.status.clone().unwrap_or_default();
        writeln!(
            out,
            "{:<8} {:<7} {:<10} {:<21} {:<9} {:>16} {:>18} {:<5} {:<24} {}",
            a.name,
            backend_name(a.backend),
            format!("{}/{}", a.bus, a.node),
            drive_state_name(s.state),
            activity_name(s.activity),
            format!("{:.3} {}", s.position, a.unit),
            format!("{:.3} {}/s", s.velocity, a.unit),
            if s.homed { "yes" } else { "no" },
            fault_text(&s),
            if s.controlled_by.is_empty() {
                "-"
            } else {
                &s.controlled_by
            },
        )?;
    }
    out.flush()?;
    Ok(())
}

/// `AXIS [show]`
async fn show(ctx: &Ctx, axis: &str) -> Result<()> {
    let a = ctx.client.clone().get_axis(axis).await?;
    let mut out = std::io::stdout().lock();
    if ctx.json {
        writeln!(out, "{}", serde_json::to_string_pretty(&axis_json(&a))?)?;
        return Ok(());
    }
    let u = &a.unit;
    let limit = |l: Option<f64>| l.map_or("none".to_string(), |v| format!("{v:.3} {u}"));
    let s = a.status.clone().unwrap_or_default();
    let rows: Vec<(&str, String)> = vec![
        ("axis", a.name.clone()),
        ("backend", backend_name(a.backend).to_string()),
        ("bus/node", format!("{}/{}", a.bus, a.node)),
        ("unit", format!("{u} ({} counts/{u})", a.counts_per_unit)),
        (
            "soft limits",
            format!("{} .. {}", limit(a.min_position), limit(a.max_position)),
        ),
        ("max velocity", format!("{:.3} {u}/s", a.max_velocity)),
        (
            "max acceleration",
            format!("{:.3} {u}/s²", a.max_acceleration),
        ),
        (
            "position mode",
            position_mode_name(a.position_mode).to_string(),
        ),
        ("process data", process_data_text(&a)),
        ("stop on loss", stop_kind_name(a.stop_on_loss).to_string()),
        ("jog dead-man", format!("{} ms", a.jog_deadman_ms)),
        (
            "state",
            format!(
                "{} (statusword 0x{:04X}, mode {})",
                drive_state_name(s.state),
                s.statusword,
                s.mode
            ),
        ),
        ("activity", activity_name(s.activity).to_string()),
        ("position", format!("{:.3} {u}", s.position)),
        ("velocity", format!("{:.3} {u}/s", s.velocity)),
        ("demand position", format!("{:.3} {u}", s.demand_position)),
        ("following error", format!("{:.3} {u}", s.following_error)),
        ("homed", if s.homed { "yes" } else { "no" }.to_string()),
        ("fault", fault_text(&s)),
        (
            "controlled by",
            if s.controlled_by.is_empty() {
                "-".to_string()
            } else {
                format!(
                    "{} (lease lapses in {} ms)",
                    s.controlled_by, s.lease_remaining_ms
                )
            },
        ),
    ];
    for (k, v) in rows {
        writeln!(out, "{:<17} {v}", format!("{k}:"))?;
    }
    out.flush()?;
    Ok(())
}

/// `watch [AXIS…]`
async fn watch(
    ctx: &Ctx,
    axes: Vec<String>,
    changes_only: bool,
    for_secs: Option<f64>,
) -> Result<()> {
    let units: HashMap<String, String> = ctx
        .client
        .clone()
        .list_axes()
        .await?
        .into_iter()
        .map(|a| (a.name, a.unit))
        .collect();
    let mut s = ctx
        .client
        .axes_client()
        .stream_axis_state(pb::StreamAxisStateRequest { axes, changes_only })
        .await
        .rpc()
        .context("watch")?;
    let time_up = sleep_opt(for_secs);
    tokio::pin!(time_up);
    let stdout = std::io::stdout();
    loop {
        let m = tokio::select! {
            m = s.message() => m.map_err(status_error)?,
            _ = ctrl_c() => return Ok(()),
            _ = &mut time_up => return Ok(()),
        };
        let Some(update) = m else { return Ok(()) };
        use pb::axis_update::Update;
        let (line, doc) = match &update.update {
            Some(Update::Status(st)) => {
                let unit = units.get(&st.axis).map(String::as_str);
                if ctx.json {
                    (None, Some(status_json(st, unit)))
                } else {
                    (Some(status_line(st, unit.unwrap_or(""))), None)
                }
            }
            Some(Update::Event(e)) => {
                if ctx.json {
                    (None, event_json(e))
                } else {
                    (event_line(e), None)
                }
            }
            None => (None, None),
        };
        let mut out = stdout.lock();
        if let Some(l) = line {
            writeln!(out, "{l}")?;
        }
        if let Some(d) = doc {
            writeln!(out, "{d}")?;
        }
        out.flush()?;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Cli, Command};
    use clap::{CommandFactory, Parser};

    fn axis_args(argv: &[&str]) -> AxisArgs {
        let cli = Cli::try_parse_from(argv).unwrap_or_else(|e| panic!("{argv:?}: {e}"));
        match cli.command {
            Command::Axis(a) => a,
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_fault_without_a_code_shows_in_status_lines_and_json() {
        let s = pb::AxisStatus {
            axis: "X".into(),
            state: pb::DriveState::Fault as i32,
            fault_code: 0,
            fault_text: "drive fault (no EMCY received)".into(),
            ..Default::default()
        };
        let line = status_line(&s, "mm");
        assert!(
            line.contains("FAULT drive fault (no EMCY received)"),
            "{line}"
        );
        assert_eq!(
            status_json(&s, None)["fault"]["text"],
            "drive fault (no EMCY received)"
        );
        let ok = pb::AxisStatus {
            axis: "X".into(),
            ..Default::default()
        };
        assert!(!status_line(&ok, "mm").contains("FAULT"));
        assert!(status_json(&ok, None)["fault"].is_null());
    }

    #[test]
    fn cli_definition_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn parses_axis_then_move() {
        let a = axis_args(&[
            "cangate", "axis", "X", "move", "12.5", "--vel", "20", "--wait",
        ]);
        assert_eq!(a.axis.as_deref(), Some("X"));
        assert_eq!(
            a.verb,
            Some(AxisVerb::Move(MoveArgs {
                target: 12.5,
                rel: false,
                vel: Some(20.0),
                acc: None,
                wait: WaitArgs {
                    wait: true,
                    timeout: None
                },
            }))
        );
    }

    #[test]
    fn parses_negative_relative_move_with_global_flags_after() {
        let cli = Cli::try_parse_from([
            "cangate", "axis", "Y", "move", "-3", "--rel", "--acc", "100", "--json",
        ])
        .unwrap();
        assert!(cli.json);
        let Command::Axis(a) = cli.command else {
            panic!()
        };
        let Some(AxisVerb::Move(m)) = a.verb else {
            panic!()
        };
        assert_eq!((m.target, m.rel, m.acc), (-3.0, true, Some(100.0)));
    }

    #[test]
    fn parses_stop_then_axes() {
        let a = axis_args(&["cangate", "axis", "stop", "X", "Y", "--quick"]);
        assert_eq!(a.axis, None);
        assert_eq!(
            a.verb,
            Some(AxisVerb::Stop(StopArgs {
                axes: vec!["X".into(), "Y".into()],
                quick: true,
                all: false,
                wait: WaitArgs::default(),
            }))
        );
    }

    #[test]
    fn parses_axis_then_stop() {
        let a = axis_args(&["cangate", "axis", "X", "stop", "--wait"]);
        assert_eq!(a.axis.as_deref(), Some("X"));
        let Some(AxisVerb::Stop(s)) = a.verb else {
            panic!()
        };
        assert!(s.axes.is_empty() && s.wait.wait && !s.quick);
    }

    #[test]
    fn parses_jog_both_directions() {
        for (dir, expected) in [("+", Direction::Positive), ("-", Direction::Negative)] {
            let a = axis_args(&[
                "cangate", "axis", "X", "jog", dir, "--vel", "5", "--for", "2",
            ]);
            assert_eq!(
                a.verb,
                Some(AxisVerb::Jog(JogArgs {
                    direction: expected,
                    vel: 5.0,
                    acc: None,
                    for_secs: Some(2.0),
                }))
            );
        }
        // The speed is required and positive (the direction gives the sign).
        assert!(Cli::try_parse_from(["cangate", "axis", "X", "jog", "+"]).is_err());
        assert!(Cli::try_parse_from(["cangate", "axis", "X", "jog", "+", "--vel", "-5"]).is_err());
    }

    #[test]
    fn parses_simple_verbs_watch_list_and_move_all() {
        let a = axis_args(&[
            "cangate",
            "axis",
            "X",
            "reset-fault",
            "--wait",
            "--timeout",
            "3",
        ]);
        assert_eq!(
            a.verb,
            Some(AxisVerb::ResetFault(WaitArgs {
                wait: true,
                timeout: Some(3.0)
            }))
        );
        // --timeout only with --wait.
        assert!(Cli::try_parse_from(["cangate", "axis", "X", "home", "--timeout", "3"]).is_err());

        let a = axis_args(&["cangate", "axis", "watch", "X", "Y", "--changes-only"]);
        let Some(AxisVerb::Watch(w)) = a.verb else {
            panic!()
        };
        assert_eq!(w.axes, ["X", "Y"]);
        assert!(w.changes_only);

        let a = axis_args(&["cangate", "axis"]);
        assert_eq!((a.axis, a.verb), (None, None));
        let a = axis_args(&["cangate", "axis", "X"]);
        assert_eq!((a.axis.as_deref(), a.verb), (Some("X"), None));

        let a = axis_args(&[
            "cangate", "axis", "move-all", "X=10", "Y=-2.5", "--vel", "20", "--wait",
        ]);
        let Some(AxisVerb::MoveAll(m)) = a.verb else {
            panic!()
        };
        assert_eq!(
            m.targets,
            [
                TargetArg {
                    axis: "X".into(),
                    target: 10.0
                },
                TargetArg {
                    axis: "Y".into(),
                    target: -2.5
                }
            ]
        );
        assert!(Cli::try_parse_from(["cangate", "axis", "move-all", "X:10"]).is_err());
    }

    #[test]
    fn verbs_without_their_axis_are_refused_before_connecting() {
        for argv in [
            &["cangate", "axis", "enable"][..],
            &["cangate", "axis", "move", "10"],
            &["cangate", "axis", "jog", "+", "--vel", "1"],
            &["cangate", "axis", "stop"],
            &["cangate", "axis", "X", "move-all", "Y=1"],
        ] {
            assert!(validate(&axis_args(argv)).is_err(), "{argv:?}");
        }
        for argv in [
            &["cangate", "axis"][..],
            &["cangate", "axis", "X"],
            &["cangate", "axis", "X", "stop"],
            &["cangate", "axis", "stop", "--all"],
            &["cangate", "axis", "watch"],
            &["cangate", "axis", "move-all", "X=1", "Y=2"],
        ] {
            assert!(validate(&axis_args(argv)).is_ok(), "{argv:?}");
        }
    }

    #[test]
    fn lease_option_is_global_to_the_verbs() {
        let a = axis_args(&["cangate", "axis", "X", "enable", "--lease", "tok"]);
        assert_eq!(a.lease.as_deref(), Some("tok"));
    }

    #[test]
    fn formats_outcomes() {
        use pb::Outcome as O;
        assert_eq!(
            format_outcome(
                "X",
                "move",
                O::Completed as i32,
                "target reached at 12.500 mm"
            ),
            "X: move completed — target reached at 12.500 mm"
        );
        assert_eq!(
            format_outcome("Y", "enable", O::Completed as i32, ""),
            "Y: enable completed"
        );
        assert_eq!(
            format_outcome(
                "X",
                "move",
                O::Fault as i32,
                "fault 0x2310 continuous over-current"
            ),
            "X: move ended by a fault — fault 0x2310 continuous over-current"
        );
        assert_eq!(
            format_outcome(
                "X",
                "home",
                O::Timeout as i32,
                "homing did not complete in time"
            ),
            "X: home timed out — homing did not complete in time"
        );
        assert_eq!(
            format_outcome("X", "move", O::Superseded as i32, "superseded by stop"),
            "X: move superseded — superseded by stop"
        );
    }

    #[test]
    fn outcome_exit_status() {
        use pb::Outcome as O;
        // Without --wait: accepted is success, faults and timeouts are not.
        assert!(outcome_ok(O::Accepted as i32, false, false));
        assert!(!outcome_ok(O::Fault as i32, false, false));
        assert!(!outcome_ok(O::Timeout as i32, false, false));
        // With --wait: only completion.
        assert!(outcome_ok(O::Completed as i32, true, false));
        for o in [
            O::Superseded,
            O::Stopped,
            O::Fault,
            O::Timeout,
            O::Unspecified,
        ] {
            assert!(!outcome_ok(o as i32, true, false), "{o:?}");
        }
        // A stop that reports "stopped" did what was asked.
        assert!(outcome_ok(O::Stopped as i32, true, true));
    }

    #[test]
    fn jog_period_is_a_third_of_the_dead_man() {
        assert_eq!(jog_period(500), Duration::from_millis(166));
        assert_eq!(jog_period(0), Duration::from_millis(100));
        assert_eq!(jog_period(9), Duration::from_millis(10));
    }

    #[test]
    fn event_lines() {
        use pb::axis_event::Kind;
        let e = pb::AxisEvent {
            axis: "X".into(),
            timestamp_us: 1_700_000_000_123_456,
            kind: Some(Kind::MotionDone(pb::MotionDone {
                command: "move".into(),
                outcome: pb::Outcome::Completed as i32,
                detail: "target reached at 12.500 mm".into(),
            })),
        };
        assert_eq!(
            event_line(&e).unwrap(),
            "(1700000000.123456)  X        move completed — target reached at 12.500 mm"
        );
        let j = event_json(&e).unwrap();
        assert_eq!(j["event"], "motion_done");
        assert_eq!(j["outcome"], "completed");
        assert_eq!(j["axis"], "X");
    }

    #[test]
    fn fault_events_say_whether_the_fault_is_active() {
        use pb::axis_event::Kind;
        let fault = |code: u32, text: &str, active: bool| pb::AxisEvent {
            axis: "X".into(),
            timestamp_us: 1_700_000_000_123_456,
            kind: Some(Kind::Fault(pb::Fault {
                code,
                text: text.into(),
                active,
            })),
        };
        let line = |e: &pb::AxisEvent| event_line(e).unwrap();
        let e = fault(0x2310, "continuous over-current", true);
        assert!(line(&e).ends_with("X        FAULT 0x2310 continuous over-current"));
        assert_eq!(event_json(&e).unwrap()["active"], true);
        // A lost node has no code, and is no clearing.
        let e = fault(0, "node lost: no heartbeat for 300 ms", true);
        assert!(line(&e).ends_with("X        FAULT node lost: no heartbeat for 300 ms"));
        assert_eq!(event_json(&e).unwrap()["active"], true);
        let e = fault(0, "", false);
        assert!(line(&e).ends_with("X        fault cleared"));
        let j = event_json(&e).unwrap();
        assert_eq!(
            (j["event"].as_str(), j["active"].as_bool()),
            (Some("fault"), Some(false))
        );
        // A gateway without `active`: a text still means a fault.
        assert!(fault_active(&pb::Fault {
            code: 0,
            text: "node lost: boot failed".into(),
            active: false,
        }));
    }
}
