//! `cangate axis …`: the Axes service (`axes.proto`) through the client
//! library.
//!
//! Commands that need control of their axes use the lease given with
//! `--lease` / `CANGATE_LEASE` (renewed by the library while the command
//! runs, kept afterwards), or take a [`ControlLease`] for their duration
//! (released at the end, also after an error or Ctrl-C).

use super::{
    App, Context, Failure, Result, ctrl_c, finite, label, positive, print_json, sleep_opt,
    time_text,
};
use cangate_client::{
    AxisUpdate, Client, CommandOptions, CommandResult, ControlLease, JogOptions, MoveOptions,
    StopOptions, pb,
};
use clap::{Args, Subcommand};
use futures::StreamExt;
use std::collections::HashMap;
use std::time::Duration;

/// Client name shown to others as the holder of the CLI's leases.
const CLIENT_NAME: &str = "cangate-cli";
/// TTL of the leases the CLI takes for one command.
const LEASE_TTL: Duration = Duration::from_secs(2);
/// Bound of the clean-up calls (release, stop after Ctrl-C).
const CLEANUP_TIMEOUT: Duration = Duration::from_secs(5);
/// Bound of the waited stop that ends a jog.
const JOG_STOP_WAIT: Duration = Duration::from_secs(30);

/// `cangate axis …`
#[derive(Args, Debug)]
pub(crate) struct AxisArgs {
    /// Use this control lease (`cangate lease acquire`) instead of taking
    /// one: renewed while the command runs, kept afterwards.
    #[arg(
        long,
        global = true,
        env = "CANGATE_LEASE",
        hide_env_values = true,
        value_name = "TOKEN"
    )]
    lease: Option<String>,
    #[command(subcommand)]
    verb: AxisVerb,
}

/// The verbs of `cangate axis`.
#[derive(Subcommand, Debug)]
enum AxisVerb {
    /// Table of axes (all, or the named ones): state, position, control.
    List {
        /// Only these axes.
        axes: Vec<String>,
    },
    /// One axis in detail: configuration and live state.
    Show {
        /// The axis.
        axis: String,
    },
    /// Switch the drives on (CiA 402 operation enabled).
    Enable(Simple),
    /// Switch the power stages off.
    Disable(Simple),
    /// Run the configured homing methods.
    Home(Simple),
    /// Reset drive faults (the axes then need `enable` again).
    ResetFault(Simple),
    /// Move to a position (or by a distance with --rel):
    /// `cangate axis move X -12.5 --vel 20 --wait`.
    Move(MoveArgs),
    /// Jog at a signed velocity while the command runs (dead-man): Ctrl-C
    /// or --for stops: `cangate axis jog X -5 --for 2`.
    Jog(JogArgs),
    /// Decelerate to rest; several axes are stopped together (one
    /// StopAxes). Needs no control.
    Stop(StopArgs),
    /// Live state and events, one line per update, until Ctrl-C.
    Watch(WatchArgs),
    /// Coordinated move of cyclic axes to absolute targets (start and
    /// arrive together): `cangate axis move-all X=10 Y=-5 --wait`.
    MoveAll(MoveAllArgs),
    /// Change an axis's CiA 402 mode, at rest:
    /// `cangate axis mode S csv --wait`.
    Mode(ModeArgs),
    /// Drive an axis in a torque mode (cst, profile_torque) with a torque
    /// in per mille of the rated torque while the command runs: Ctrl-C or
    /// --for stops it: `cangate axis torque T 50 --for 2`.
    Torque(TorqueArgs),
}

/// `mode AXIS MODE`
#[derive(Args, Debug)]
struct ModeArgs {
    /// The axis.
    axis: String,
    /// profile_position, csp, ip, csv, cst or profile_torque.
    #[arg(value_parser = parse_mode)]
    mode: pb::DriveMode,
    #[command(flatten)]
    wait: WaitArgs,
}

/// `torque AXIS PERMILLE …`
#[derive(Args, Debug)]
struct TorqueArgs {
    /// The axis.
    axis: String,
    /// Signed torque, per mille of the drive's rated torque.
    #[arg(allow_negative_numbers = true, value_name = "PERMILLE", value_parser = finite)]
    torque: f64,
    /// Stop by itself after this many seconds.
    #[arg(long = "for", value_name = "SECONDS", value_parser = positive)]
    for_secs: Option<f64>,
}

/// A mode's name as in the configuration.
fn parse_mode(text: &str) -> std::result::Result<pb::DriveMode, String> {
    Ok(match text {
        "profile_position" => pb::DriveMode::ProfilePosition,
        "csp" => pb::DriveMode::Csp,
        "ip" => pb::DriveMode::Ip,
        "csv" => pb::DriveMode::Csv,
        "cst" => pb::DriveMode::Cst,
        "profile_torque" => pb::DriveMode::ProfileTorque,
        _ => {
            return Err(format!(
                "{text:?} is not a mode: profile_position, csp, ip, csv, cst or profile_torque"
            ));
        }
    })
}

/// enable, disable, home, reset-fault.
#[derive(Args, Debug)]
struct Simple {
    /// The axes (one command each, at once, under one lease).
    #[arg(required = true)]
    axes: Vec<String>,
    #[command(flatten)]
    wait: WaitArgs,
}

/// `--wait [--wait-timeout S]`
#[derive(Args, Debug, Clone, Copy, Default)]
struct WaitArgs {
    /// Return when the command has completed, failed or was superseded
    /// (exit 1 unless it completed).
    #[arg(long)]
    wait: bool,
    /// Bound of --wait in seconds (default: the gateway's, 60 s).
    #[arg(long, value_name = "SECONDS", requires = "wait", value_parser = positive)]
    wait_timeout: Option<f64>,
}

impl WaitArgs {
    fn bound(&self) -> Option<Duration> {
        self.wait_timeout.map(Duration::from_secs_f64)
    }

    fn command(&self) -> CommandOptions {
        CommandOptions {
            lease: None,
            wait: self.wait,
            wait_timeout: self.bound(),
        }
    }
}

/// `move AXIS POS …`
#[derive(Args, Debug)]
struct MoveArgs {
    /// The axis.
    axis: String,
    /// Target position (or distance with --rel), in the axis's unit.
    #[arg(allow_negative_numbers = true, value_name = "POS", value_parser = finite)]
    target: f64,
    /// Move by POS from the current target instead of to POS.
    #[arg(long, short = 'r', visible_alias = "relative")]
    rel: bool,
    /// Velocity (unit/s; default: the axis's).
    #[arg(long, value_parser = positive)]
    vel: Option<f64>,
    /// Acceleration and deceleration (unit/s²; default: the axis's).
    #[arg(long, value_parser = positive)]
    acc: Option<f64>,
    #[command(flatten)]
    wait: WaitArgs,
}

/// `jog AXIS VELOCITY …`
#[derive(Args, Debug)]
struct JogArgs {
    /// The axis.
    axis: String,
    /// Signed velocity (unit/s): -5 jogs backwards.
    #[arg(allow_negative_numbers = true, value_name = "VELOCITY", value_parser = finite)]
    velocity: f64,
    /// Acceleration (unit/s²; default: the axis's).
    #[arg(long, value_parser = positive)]
    acc: Option<f64>,
    /// Stop by itself after this many seconds.
    #[arg(long = "for", value_name = "SECONDS", value_parser = positive)]
    for_secs: Option<f64>,
}

/// `stop AXIS… | --all`
#[derive(Args, Debug)]
struct StopArgs {
    /// The axes.
    #[arg(required_unless_present = "all")]
    axes: Vec<String>,
    /// Every axis of the gateway.
    #[arg(long, conflicts_with = "axes")]
    all: bool,
    /// Quick stop: at the axis's quick_stop_deceleration (a CiA 402 drive
    /// leaves operation enabled) instead of its stop_deceleration.
    #[arg(long)]
    quick: bool,
    /// Return when all are at rest.
    #[arg(long)]
    wait: bool,
}

/// `watch [AXIS…]`
#[derive(Args, Debug)]
struct WatchArgs {
    /// The axes (default: all).
    axes: Vec<String>,
    /// Skip statuses identical to the previous one (an axis at rest is
    /// quiet).
    #[arg(long)]
    changes_only: bool,
    /// End after this many seconds.
    #[arg(long = "for", value_name = "SECONDS", value_parser = positive)]
    for_secs: Option<f64>,
}

/// `move-all AXIS=POS…`
#[derive(Args, Debug)]
struct MoveAllArgs {
    /// Absolute targets: X=10 Y=-2.5.
    #[arg(required = true, value_name = "AXIS=POS", value_parser = parse_target)]
    targets: Vec<(String, f64)>,
    /// Velocity limit of every axis (unit/s; default: the axes').
    #[arg(long, value_parser = positive)]
    vel: Option<f64>,
    /// Acceleration limit of every axis (unit/s²; default: the axes').
    #[arg(long, value_parser = positive)]
    acc: Option<f64>,
    #[command(flatten)]
    wait: WaitArgs,
}

fn parse_target(text: &str) -> Result<(String, f64), String> {
    let (axis, pos) = text
        .split_once('=')
        .ok_or_else(|| format!("{text:?} is not AXIS=POS"))?;
    if axis.is_empty() {
        return Err(format!("{text:?} has no axis name"));
    }
    Ok((axis.to_string(), finite(pos)?))
}

// ---------------------------------------------------------------- control

/// Control of some axes for one command: the `--lease` one adopted (kept
/// at the end), or one taken for the command (released at the end).
struct Held {
    lease: ControlLease,
    owned: bool,
}

impl Held {
    async fn take(app: &App, given: &Option<String>, axes: &[&str]) -> Result<Held> {
        match given {
            Some(token) => Ok(Held {
                lease: app
                    .client
                    .adopt_control(token)
                    .await
                    .ctx("the lease given with --lease / CANGATE_LEASE")?,
                owned: false,
            }),
            None => Ok(Held {
                lease: app
                    .client
                    .acquire_control_as(axes, LEASE_TTL, CLIENT_NAME)
                    .await
                    .ctx(format!("taking control of {}", axes.join(", ")))?,
                owned: true,
            }),
        }
    }

    fn token(&self) -> Option<String> {
        Some(self.lease.token().to_string())
    }

    /// Gives back a lease taken for the command; keeps an adopted one.
    async fn finish(self) {
        if !self.owned {
            return;
        }
        if let Some(Err(e)) = cleanup("releasing control", self.lease.release()).await {
            eprintln!("cangate: releasing control: {e} (the lease lapses by itself)");
        }
    }
}

/// Runs a clean-up call with a bound; a second Ctrl-C leaves at once (one
/// within half a second of the first counts as the same press).
async fn cleanup<T>(what: &str, f: impl Future<Output = T>) -> Option<T> {
    let again = async {
        tokio::time::sleep(Duration::from_millis(500)).await;
        super::forget_ctrl_c();
        ctrl_c().await;
    };
    tokio::select! {
        r = tokio::time::timeout(CLEANUP_TIMEOUT, f) => {
            if r.is_err() {
                eprintln!("cangate: {what}: no answer within {} s", CLEANUP_TIMEOUT.as_secs());
            }
            r.ok()
        }
        _ = again => {
            eprintln!("cangate: interrupted again during {what}; leaving");
            std::process::exit(i32::from(super::exit::INTERRUPTED));
        }
    }
}

/// Stops `axes` after Ctrl-C or a failure (best effort, not waited for).
async fn stop_after(client: &Client, axes: &[&str], why: &str) {
    eprintln!("cangate: {why}: stopping {}", axes.join(", "));
    let r = cleanup("stopping", async {
        match axes {
            [one] => client.stop(one, false).await.map(|_| ()),
            _ => client
                .stop_axes(axes, StopOptions::default())
                .await
                .map(|_| ()),
        }
    })
    .await;
    if let Some(Err(e)) = r {
        eprintln!("cangate: stopping {}: {e}", axes.join(", "));
    }
}

// ------------------------------------------------------------- outcomes

/// `move completed — target reached at 12.500 mm`
fn outcome_text(command: &str, outcome: pb::Outcome, detail: &str) -> String {
    use pb::Outcome as O;
    let phrase = match outcome {
        O::Fault => "ended by a fault".to_string(),
        O::Timeout => "timed out".to_string(),
        O::Unspecified => "ended (outcome unknown)".to_string(),
        other => label::<pb::Outcome>(other as i32),
    };
    if detail.is_empty() {
        format!("{command} {phrase}")
    } else {
        format!("{command} {phrase} — {detail}")
    }
}

/// Whether an outcome counts as success. Faults and timeouts never do;
/// with `waited`, only completion does (and, for a stop, "stopped").
fn outcome_ok(outcome: pb::Outcome, waited: bool, is_stop: bool) -> bool {
    use pb::Outcome as O;
    match outcome {
        O::Completed | O::Accepted => true,
        O::Stopped => is_stop || !waited,
        O::Superseded => !waited,
        _ => false,
    }
}

/// The axis a result is about: its status's, else the one asked for.
fn result_axis(r: &CommandResult, asked: &str) -> String {
    match &r.status {
        Some(s) if !s.axis.is_empty() => s.axis.clone(),
        _ => asked.to_string(),
    }
}

/// Prints the results of a command on some axes (request order): one line
/// each, or the response message with --json (`AxisCommandResponse` for
/// one axis, `MultiAxisResponse` for several); exit 1 when one failed.
fn report(
    app: &App,
    axes: &[&str],
    command: &str,
    results: &[CommandResult],
    waited: bool,
    is_stop: bool,
) -> Result<()> {
    let mut failed = Vec::new();
    for (i, r) in results.iter().enumerate() {
        let axis = result_axis(r, axes.get(i).copied().unwrap_or(""));
        let line = format!("{axis}: {}", outcome_text(command, r.outcome, &r.detail));
        if outcome_ok(r.outcome, waited, is_stop) {
            if !app.json {
                app.line(&line)?;
            }
        } else {
            failed.push(line);
        }
    }
    if app.json {
        match results {
            [one] => print_json(&one.to_pb())?,
            _ => print_json(&pb::MultiAxisResponse {
                results: results.iter().map(CommandResult::to_pb).collect(),
            })?,
        }
    }
    match failed.as_slice() {
        [] => Ok(()),
        [one] => Err(Failure::failed("", one.clone())),
        _ => Err(Failure::failed(
            format!("{command} of {} axes", results.len()),
            failed.join("; "),
        )),
    }
}

// -------------------------------------------------------------- commands

/// `cangate axis …`
pub(crate) async fn run(app: &App, args: AxisArgs) -> Result<()> {
    let lease = args.lease;
    match args.verb {
        AxisVerb::List { axes } => list(app, &axes).await,
        AxisVerb::Show { axis } => show(app, &axis).await,
        AxisVerb::Enable(s) => simple(app, &lease, Cmd::Enable, s).await,
        AxisVerb::Disable(s) => simple(app, &lease, Cmd::Disable, s).await,
        AxisVerb::Home(s) => simple(app, &lease, Cmd::Home, s).await,
        AxisVerb::ResetFault(s) => simple(app, &lease, Cmd::ResetFault, s).await,
        AxisVerb::Move(m) => move_one(app, &lease, m).await,
        AxisVerb::Jog(j) => jog(app, &lease, j).await,
        AxisVerb::Stop(s) => stop(app, s).await,
        AxisVerb::Watch(w) => watch(app, w).await,
        AxisVerb::MoveAll(m) => move_all(app, &lease, m).await,
        AxisVerb::Mode(m) => set_mode(app, &lease, m).await,
        AxisVerb::Torque(t) => torque(app, &lease, t).await,
    }
}

/// The commands without parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Cmd {
    Enable,
    Disable,
    Home,
    ResetFault,
}

impl Cmd {
    fn name(self) -> &'static str {
        match self {
            Cmd::Enable => "enable",
            Cmd::Disable => "disable",
            Cmd::Home => "home",
            Cmd::ResetFault => "reset-fault",
        }
    }

    async fn send(
        self,
        client: &Client,
        axis: &str,
        options: &CommandOptions,
    ) -> std::result::Result<CommandResult, cangate_client::Error> {
        match self {
            Cmd::Enable => client.enable(axis, options).await,
            Cmd::Disable => client.disable(axis, options).await,
            Cmd::Home => client.home(axis, options).await,
            Cmd::ResetFault => client.reset_fault(axis, options).await,
        }
    }
}

/// enable, disable, home, reset-fault of one or more axes, at once.
async fn simple(app: &App, given: &Option<String>, cmd: Cmd, s: Simple) -> Result<()> {
    let axes: Vec<&str> = s.axes.iter().map(String::as_str).collect();
    let held = Held::take(app, given, &axes).await?;
    let options = CommandOptions {
        lease: held.token(),
        ..s.wait.command()
    };
    let options = &options;
    let all = futures::future::join_all(axes.iter().map(|&axis| async move {
        cmd.send(&app.client, axis, options)
            .await
            .ctx(format!("{axis}: {}", cmd.name()))
    }));
    let results = tokio::select! {
        r = all => r,
        _ = ctrl_c() => {
            if cmd == Cmd::Home {
                stop_after(&app.client, &axes, "interrupted").await;
            }
            held.finish().await;
            return Err(Failure::interrupted(format!("{} {}", cmd.name(), axes.join(", "))));
        }
    };
    held.finish().await;
    let (done, mut failed): (Vec<_>, Vec<_>) = results.into_iter().partition(Result::is_ok);
    match failed.len() {
        0 => {
            let done: Vec<CommandResult> = done.into_iter().flatten().collect();
            report(app, &axes, cmd.name(), &done, s.wait.wait, false)
        }
        1 => Err(failed.pop().and_then(Result::err).expect("one failure")),
        n => Err(Failure::failed(
            format!("{} of {n} of {} axes", cmd.name(), axes.len()),
            failed
                .into_iter()
                .filter_map(Result::err)
                .map(|e| e.to_string())
                .collect::<Vec<_>>()
                .join("; "),
        )),
    }
}

/// `move AXIS POS`
async fn move_one(app: &App, given: &Option<String>, m: MoveArgs) -> Result<()> {
    let axis = m.axis.as_str();
    let held = Held::take(app, given, &[axis]).await?;
    let options = MoveOptions {
        velocity: m.vel,
        acceleration: m.acc,
        wait: m.wait.wait,
        wait_timeout: m.wait.bound(),
        lease: held.token(),
    };
    let call = async {
        if m.rel {
            app.client.move_by(axis, m.target, &options).await
        } else {
            app.client.move_to(axis, m.target, &options).await
        }
    };
    let result = tokio::select! {
        r = call => r.ctx(format!("{axis}: move")),
        _ = ctrl_c() => {
            stop_after(&app.client, &[axis], "interrupted").await;
            Err(Failure::interrupted(format!("{axis}: move")))
        }
        status = held.lease.lost() => Err(Failure::failed(
            format!("{axis}: move"),
            format!("control lost: {}", status.last_error.map_or("the lease lapsed".into(), |e| e.to_string())),
        )),
    };
    held.finish().await;
    report(app, &[axis], "move", &[result?], m.wait.wait, false)
}

/// `move-all X=10 Y=20 …`: one coordinated MoveAxes.
async fn move_all(app: &App, given: &Option<String>, m: MoveAllArgs) -> Result<()> {
    let axes: Vec<&str> = m.targets.iter().map(|(a, _)| a.as_str()).collect();
    let targets: Vec<(&str, f64)> = m.targets.iter().map(|(a, t)| (a.as_str(), *t)).collect();
    let held = Held::take(app, given, &axes).await?;
    let options = MoveOptions {
        velocity: m.vel,
        acceleration: m.acc,
        wait: m.wait.wait,
        wait_timeout: m.wait.bound(),
        lease: held.token(),
    };
    let names = axes.join(", ");
    let result = tokio::select! {
        r = app.client.move_axes(&targets, &options) => r.ctx(format!("{names}: move-all")),
        _ = ctrl_c() => {
            stop_after(&app.client, &axes, "interrupted").await;
            Err(Failure::interrupted(format!("{names}: move-all")))
        }
    };
    if matches!(&result, Err(f) if f.exit_code() == super::exit::TIMEOUT) {
        // The axes may still be moving: the wait ran out, not the move.
        stop_after(&app.client, &axes, "not all arrived in time").await;
    }
    held.finish().await;
    report(app, &axes, "move", &result?, m.wait.wait, false)
}

/// `stop AXIS… [--quick] [--wait]` or `stop --all`
async fn stop(app: &App, s: StopArgs) -> Result<()> {
    let names: Vec<String> = if s.all {
        let all = app
            .client
            .clone()
            .list_axes()
            .await
            .ctx("listing the axes")?;
        all.into_iter().map(|a| a.name).collect()
    } else {
        s.axes
    };
    if names.is_empty() {
        return Err(Failure::failed("stop --all", "the gateway has no axes"));
    }
    let axes: Vec<&str> = names.iter().map(String::as_str).collect();
    let command = if s.quick { "quick-stop" } else { "stop" };
    let what = format!("{}: {command}", axes.join(", "));
    let call = async {
        match axes.as_slice() {
            [one] if s.quick => app.client.quick_stop(one, s.wait).await.map(|r| vec![r]),
            [one] => app.client.stop(one, s.wait).await.map(|r| vec![r]),
            _ => {
                let options = StopOptions {
                    quick: s.quick,
                    wait: s.wait,
                };
                app.client.stop_axes(&axes, options).await
            }
        }
    };
    let results = tokio::select! {
        r = call => r.ctx(what)?,
        _ = ctrl_c() => return Err(Failure::interrupted(what)),
    };
    report(app, &axes, command, &results, s.wait, true)
}

/// How a jog ended.
enum JogEnd {
    /// Ctrl-C.
    Interrupted,
    /// `--for` ran out.
    TimeUp,
    /// The gateway ended it (stopped by someone, dead-man, fault, …).
    Ended(pb::Outcome, String),
}

/// Jog repeat period: a third of the dead-man time.
fn jog_period(deadman_ms: u32) -> Duration {
    if deadman_ms == 0 {
        return Duration::from_millis(100);
    }
    Duration::from_millis(u64::from(deadman_ms / 3).clamp(10, 1000))
}

/// `jog AXIS VELOCITY`: Jog repeated within the dead-man time until
/// Ctrl-C, `--for` or the gateway ending it; then a waited stop.
/// `mode AXIS MODE`
async fn set_mode(app: &App, given: &Option<String>, m: ModeArgs) -> Result<()> {
    let axis = m.axis.as_str();
    let held = Held::take(app, given, &[axis]).await?;
    let options = CommandOptions {
        lease: held.token(),
        ..m.wait.command()
    };
    let result = app
        .client
        .set_mode(axis, m.mode, &options)
        .await
        .ctx(format!("{axis}: mode"));
    held.finish().await;
    report(app, &[axis], "mode", &[result?], m.wait.wait, false)
}

/// `torque AXIS PERMILLE`: the torque runs until Ctrl-C, --for, or the
/// gateway ends it (a stop, its velocity guard); then the axis is stopped.
async fn torque(app: &App, given: &Option<String>, t: TorqueArgs) -> Result<()> {
    let axis = t.axis.as_str();
    let held = Held::take(app, given, &[axis]).await?;
    let mut updates = app.client.watch_axes(&[axis], true).await.ok();
    let options = CommandOptions {
        lease: held.token(),
        ..CommandOptions::default()
    };
    let started = app
        .client
        .set_torque(axis, t.torque, &options)
        .await
        .ctx(format!("{axis}: torque"));
    if let Err(e) = started {
        held.finish().await;
        return Err(e);
    }
    if !app.json {
        eprintln!("{axis}: torque {:+.1} per mille — Ctrl-C to stop", t.torque);
    }
    let ended: Option<(pb::Outcome, String)> = {
        let interrupt = ctrl_c();
        tokio::pin!(interrupt);
        let time_up = sleep_opt(t.for_secs);
        tokio::pin!(time_up);
        loop {
            tokio::select! {
                _ = &mut interrupt => break None,
                _ = &mut time_up => break None,
                u = async {
                    match updates.as_mut() {
                        Some(s) => s.next().await,
                        None => std::future::pending().await,
                    }
                } => match u {
                    Some(Ok(AxisUpdate::MotionDone { command, outcome, detail, .. })) if command == "torque" => {
                        break Some((outcome, detail));
                    }
                    Some(Ok(_)) => {}
                    Some(Err(_)) | None => updates = None,
                },
            }
        }
    };
    let result = match ended {
        Some((outcome, detail)) => Err(Failure::failed(
            "",
            format!("{axis}: {}", outcome_text("torque", outcome, &detail)),
        )),
        None => app
            .client
            .stop(axis, true)
            .await
            .ctx(format!("{axis}: stopping the torque"))
            .and_then(|r| report(app, &[axis], "stop", &[r], true, true)),
    };
    held.finish().await;
    result
}

async fn jog(app: &App, given: &Option<String>, j: JogArgs) -> Result<()> {
    let axis = j.axis.as_str();
    let info = app.client.axis(axis).await.ctx(format!("{axis}: jog"))?;
    let period = jog_period(info.jog_deadman_ms);
    let held = Held::take(app, given, &[axis]).await?;
    // The state stream tells when the gateway ends the jog (someone pressed
    // stop, a fault): then it must not be restarted by the next Jog.
    let mut updates = app.client.watch_axes(&[axis], true).await.ok();
    let options = JogOptions {
        acceleration: j.acc,
        lease: held.token(),
    };
    let jog_once = || async {
        let r = app
            .client
            .jog(axis, j.velocity, &options)
            .await
            .ctx(format!("{axis}: jog"))?;
        if outcome_ok(r.outcome, false, false) {
            Ok(())
        } else {
            Err(Failure::failed(
                "",
                format!("{axis}: {}", outcome_text("jog", r.outcome, &r.detail)),
            ))
        }
    };

    let mut started = false;
    let ended: Result<JogEnd> = async {
        let interrupt = ctrl_c();
        tokio::pin!(interrupt);
        let time_up = sleep_opt(j.for_secs);
        tokio::pin!(time_up);
        tokio::select! {
            r = jog_once() => r?,
            _ = &mut interrupt => return Ok(JogEnd::Interrupted),
        }
        started = true;
        if !app.json {
            eprintln!(
                "{axis}: jogging at {:+.3} {}/s — Ctrl-C to stop",
                j.velocity, info.unit
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
                    jog_once().await
                } => r?,
                u = async {
                    match updates.as_mut() {
                        Some(s) => s.next().await,
                        None => std::future::pending().await,
                    }
                } => match u {
                    Some(Ok(AxisUpdate::MotionDone { command, outcome, detail, .. })) if command == "jog" => {
                        return Ok(JogEnd::Ended(outcome, detail));
                    }
                    Some(Ok(_)) => {}
                    Some(Err(_)) | None => updates = None,
                },
                status = held.lease.lost() => {
                    return Err(Failure::failed(
                        format!("{axis}: jog"),
                        format!("control lost: {}", status.last_error.map_or("the lease lapsed".into(), |e| e.to_string())),
                    ));
                }
            }
        }
    }
    .await;

    let result = match ended {
        Ok(JogEnd::Ended(outcome, detail)) => Err(Failure::failed(
            "",
            format!("{axis}: {}", outcome_text("jog", outcome, &detail)),
        )),
        // Ctrl-C is the normal end of a jog held by hand.
        Ok(JogEnd::Interrupted | JogEnd::TimeUp) => {
            let stopped =
                tokio::time::timeout(JOG_STOP_WAIT + CLEANUP_TIMEOUT, app.client.stop(axis, true))
                    .await;
            match stopped {
                Ok(r) => r
                    .ctx(format!("{axis}: stopping the jog"))
                    .and_then(|r| report(app, &[axis], "stop", &[r], true, true)),
                Err(_) => Err(Failure::failed(
                    format!("{axis}: stopping the jog"),
                    "the axis did not come to rest in time",
                )),
            }
        }
        Err(e) => {
            if started {
                stop_after(&app.client, &[axis], "jog failed").await;
            }
            Err(e)
        }
    };
    held.finish().await;
    result
}

// ------------------------------------------------------------- formatting

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

/// "pdo", "sdo every 10 ms", or "-" (CANsmc axes).
fn process_data_text(a: &pb::Axis) -> String {
    match pb::ProcessDataPath::try_from(a.process_data) {
        Ok(pb::ProcessDataPath::Pdo) => "pdo".into(),
        Ok(pb::ProcessDataPath::Sdo) => format!("sdo every {} ms", a.sdo_poll_ms),
        _ => "-".into(),
    }
}

/// One line of `watch` for a status.
fn status_line(s: &pb::AxisStatus, unit: &str) -> String {
    let mut line = format!(
        "{}  {:<8} {:<21} {:<9} pos {:>12.3} {unit}  vel {:>10.3} {unit}/s  ferr {:.3}",
        time_text(s.timestamp_us),
        s.axis,
        label::<pb::DriveState>(s.state),
        label::<pb::AxisActivity>(s.activity),
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

/// Whether a fault event reports a fault (true) or its clearing.
fn fault_active(f: &pb::Fault) -> bool {
    f.active || f.code != 0 || !f.text.is_empty()
}

/// One line of `watch` for an event; `None` for an empty event.
fn event_line(e: &pb::AxisEvent) -> Option<String> {
    use pb::axis_event::Kind;
    let what = match e.kind.as_ref()? {
        Kind::MotionDone(m) => outcome_text(
            &m.command,
            pb::Outcome::try_from(m.outcome).unwrap_or_default(),
            &m.detail,
        ),
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
        Kind::TouchProbe(t) => format!(
            "touch probe {} latched at {} ({} edge)",
            t.probe,
            t.position,
            match pb::TouchProbeEdge::try_from(t.edge) {
                Ok(pb::TouchProbeEdge::Falling) => "falling",
                _ => "rising",
            }
        ),
    };
    Some(format!(
        "{}  {:<8} {what}",
        time_text(e.timestamp_us),
        e.axis
    ))
}

/// `list [AXIS…]`
async fn list(app: &App, names: &[String]) -> Result<()> {
    let mut axes = app
        .client
        .clone()
        .list_axes()
        .await
        .ctx("listing the axes")?;
    if !names.is_empty() {
        if let Some(unknown) = names.iter().find(|n| !axes.iter().any(|a| &a.name == *n)) {
            // The gateway's own answer: NOT_FOUND naming the axes it has.
            app.client
                .axis(unknown)
                .await
                .ctx(format!("axis {unknown}"))?;
        }
        axes.retain(|a| names.contains(&a.name));
    }
    if app.json {
        return print_json(&pb::ListAxesResponse { axes });
    }
    let mut text = format!(
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
    );
    for a in &axes {
        let s = a.status.clone().unwrap_or_default();
        text.push_str(&format!(
            "\n{:<8} {:<7} {:<10} {:<21} {:<9} {:>16} {:>18} {:<5} {:<24} {}",
            a.name,
            label::<pb::AxisBackend>(a.backend),
            format!("{}/{}", a.bus, a.node),
            label::<pb::DriveState>(s.state),
            label::<pb::AxisActivity>(s.activity),
            format!("{:.3} {}", s.position, a.unit),
            format!("{:.3} {}/s", s.velocity, a.unit),
            if s.homed { "yes" } else { "no" },
            fault_text(&s),
            if s.controlled_by.is_empty() {
                "-"
            } else {
                &s.controlled_by
            },
        ));
    }
    app.line(text)
}

/// `show AXIS`
async fn show(app: &App, axis: &str) -> Result<()> {
    let a = app.client.axis(axis).await.ctx(format!("axis {axis}"))?;
    let u = &a.unit;
    let limit = |l: Option<f64>| l.map_or("none".to_string(), |v| format!("{v:.3} {u}"));
    let s = a.status.clone().unwrap_or_default();
    let rows: Vec<(&str, String)> = vec![
        ("axis", a.name.clone()),
        ("backend", label::<pb::AxisBackend>(a.backend)),
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
        ("position mode", label::<pb::PositionMode>(a.position_mode)),
        ("process data", process_data_text(&a)),
        ("stop on loss", label::<pb::StopKind>(a.stop_on_loss)),
        ("jog dead-man", format!("{} ms", a.jog_deadman_ms)),
        (
            "state",
            format!(
                "{} (statusword 0x{:04X}, mode {})",
                label::<pb::DriveState>(s.state),
                s.statusword,
                s.mode
            ),
        ),
        ("activity", label::<pb::AxisActivity>(s.activity)),
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
    let text = rows
        .iter()
        .map(|(k, v)| format!("{:<17} {v}", format!("{k}:")))
        .collect::<Vec<_>>()
        .join("\n");
    app.show(text, &a)
}

/// `watch [AXIS…]`: each `AxisUpdate` as a line (or a JSON line).
async fn watch(app: &App, w: WatchArgs) -> Result<()> {
    let units: HashMap<String, String> = if app.json {
        HashMap::new()
    } else {
        let axes = app
            .client
            .clone()
            .list_axes()
            .await
            .ctx("listing the axes")?;
        axes.into_iter().map(|a| (a.name, a.unit)).collect()
    };
    let req = pb::StreamAxisStateRequest {
        axes: w.axes,
        changes_only: w.changes_only,
    };
    let mut s = app
        .client
        .call(
            "StreamAxisState",
            None,
            app.client.axes_client().stream_axis_state(req),
        )
        .await
        .ctx("watching the axes")?;
    let time_up = sleep_opt(w.for_secs);
    tokio::pin!(time_up);
    loop {
        let m = tokio::select! {
            m = s.message() => m.map_err(cangate_client::Error::from).ctx("watching the axes")?,
            _ = ctrl_c() => return Ok(()),
            _ = &mut time_up => return Ok(()),
        };
        let Some(update) = m else { return Ok(()) };
        use pb::axis_update::Update;
        let text = match &update.update {
            Some(Update::Status(st)) => Some(status_line(
                st,
                units.get(&st.axis).map_or("", String::as_str),
            )),
            Some(Update::Event(e)) => event_line(e),
            None => None,
        };
        if let Some(text) = text {
            app.item(text, &update)?;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Cli, Command};
    use super::*;
    use clap::Parser;

    fn axis(argv: &[&str]) -> AxisArgs {
        let mut all = vec!["cangate", "axis"];
        all.extend_from_slice(argv);
        match Cli::try_parse_from(&all) {
            Ok(Cli {
                command: Command::Axis(a),
                ..
            }) => a,
            Ok(other) => panic!("{other:?}"),
            Err(e) => panic!("{all:?}: {e}"),
        }
    }

    fn refused(argv: &[&str]) -> bool {
        let mut all = vec!["cangate", "axis"];
        all.extend_from_slice(argv);
        Cli::try_parse_from(&all).is_err()
    }

    #[test]
    fn move_takes_negative_positions_and_flags_anywhere() {
        let a = axis(&[
            "move", "X", "-12.5", "--rel", "--vel", "20", "--wait", "--json",
        ]);
        let AxisVerb::Move(m) = a.verb else { panic!() };
        assert_eq!((m.axis.as_str(), m.target, m.rel), ("X", -12.5, true));
        assert_eq!((m.vel, m.wait.wait), (Some(20.0), true));
        assert!(refused(&["move", "X"]));
        assert!(refused(&["move", "X", "nan"]));
        assert!(refused(&["move", "X", "1", "--vel", "-1"]));
        // The wait bound only with --wait.
        assert!(refused(&["move", "X", "1", "--wait-timeout", "3"]));
    }

    #[test]
    fn jog_takes_a_signed_velocity() {
        let a = axis(&["jog", "X", "-5", "--for", "2"]);
        let AxisVerb::Jog(j) = a.verb else { panic!() };
        assert_eq!(
            (j.axis.as_str(), j.velocity, j.for_secs),
            ("X", -5.0, Some(2.0))
        );
        assert!(refused(&["jog", "X"]));
    }

    #[test]
    fn stop_names_axes_or_all() {
        let a = axis(&["stop", "X", "Y", "--quick", "--wait"]);
        let AxisVerb::Stop(s) = a.verb else { panic!() };
        assert_eq!(s.axes, ["X", "Y"]);
        assert!(s.quick && s.wait && !s.all);
        let a = axis(&["stop", "--all"]);
        let AxisVerb::Stop(s) = a.verb else { panic!() };
        assert!(s.all);
        assert!(refused(&["stop"]));
        assert!(refused(&["stop", "X", "--all"]));
    }

    #[test]
    fn simple_verbs_take_axes_and_the_lease() {
        let a = axis(&[
            "enable",
            "X",
            "Y",
            "--wait",
            "--wait-timeout",
            "3",
            "--lease",
            "tok",
        ]);
        assert_eq!(a.lease.as_deref(), Some("tok"));
        let AxisVerb::Enable(s) = a.verb else {
            panic!()
        };
        assert_eq!(s.axes, ["X", "Y"]);
        assert_eq!(s.wait.bound(), Some(Duration::from_secs(3)));
        assert!(refused(&["home"]));
        assert!(matches!(
            axis(&["reset-fault", "Z"]).verb,
            AxisVerb::ResetFault(_)
        ));
    }

    #[test]
    fn move_all_takes_targets() {
        let a = axis(&["move-all", "X=10", "Y=-5", "--vel", "20"]);
        let AxisVerb::MoveAll(m) = a.verb else {
            panic!()
        };
        assert_eq!(
            m.targets,
            [("X".to_string(), 10.0), ("Y".to_string(), -5.0)]
        );
        assert!(refused(&["move-all", "X:10"]));
        assert!(refused(&["move-all", "=1"]));
        assert!(refused(&["move-all"]));
    }

    #[test]
    fn outcomes() {
        use pb::Outcome as O;
        assert_eq!(
            outcome_text("move", O::Completed, "target reached at 12.500 mm"),
            "move completed — target reached at 12.500 mm"
        );
        assert_eq!(outcome_text("home", O::Timeout, ""), "home timed out");
        assert!(outcome_ok(O::Accepted, false, false));
        assert!(!outcome_ok(O::Superseded, true, false));
        assert!(outcome_ok(O::Stopped, true, true));
        assert!(!outcome_ok(O::Fault, false, false));
        assert_eq!(jog_period(500), Duration::from_millis(166));
        assert_eq!(jog_period(0), Duration::from_millis(100));
    }

    #[test]
    fn status_and_event_lines() {
        let s = pb::AxisStatus {
            axis: "X".into(),
            state: pb::DriveState::Fault as i32,
            fault_text: "drive fault (no EMCY received)".into(),
            ..Default::default()
        };
        let line = status_line(&s, "mm");
        assert!(line.contains(" fault "), "{line}");
        assert!(
            line.contains("FAULT drive fault (no EMCY received)"),
            "{line}"
        );
        let e = pb::AxisEvent {
            axis: "X".into(),
            timestamp_us: 1_700_000_000_123_456,
            kind: Some(pb::axis_event::Kind::MotionDone(pb::MotionDone {
                command: "move".into(),
                outcome: pb::Outcome::Completed as i32,
                detail: "target reached at 12.500 mm".into(),
            })),
        };
        assert_eq!(
            event_line(&e).unwrap(),
            "(1700000000.123456)  X        move completed — target reached at 12.500 mm"
        );
    }
}
