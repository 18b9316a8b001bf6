//! Random command sequences end to end: the embedded demo (a cyclic and a
//! profile CiA 402 axis, a CANsmc axis) driven through gRPC by the real
//! client, one task per axis at once. The model-based tests in
//! `crates/axis/tests` run thousands of sequences in virtual time; this is
//! the smaller run through the whole server, with the same invariants:
//!
//! - no call hangs (each is bounded) and none fails with an internal or
//!   unknown error;
//! - a waited-for command on a healthy simulated drive never ends TIMEOUT;
//! - the position never leaves the soft limits;
//! - never wedged: after stop, reset fault and enable, a move to 0
//!   completes there;
//! - commissioning by a second client (an engineer's connection without
//!   the lease) interleaved with the motion never disturbs an enabled
//!   axis: raw SDO writes to the drive's process objects, NMT commands,
//!   program download and LSS switch-global that reach an enabled axis's
//!   drive, and SYNC period changes under an enabled cyclic axis, are
//!   refused and leave the axis enabled; at rest they may run.
//!
//! A failure names the seed and the actions up to it; the sequence is a
//! function of the seed (`AXES_RANDOM_SEED=<n>` runs one seed).

use cangate_client::pb;
use cangate_tests::axes::{Axes, acquire, cmd, opts};
use std::time::Duration;
use tonic::Code;

/// Sequences per axis and actions per sequence.
const SEEDS: u64 = 4;
const ACTIONS: usize = 25;
/// Bound of any call (waited commands wait up to 10 s in the gateway).
const CALL_BOUND: Duration = Duration::from_secs(20);

struct Limits {
    min: f64,
    max: f64,
    max_velocity: f64,
    /// The CANopen node of a CiA 402 axis's drive (commissioning target).
    drive_node: Option<u32>,
    /// A cyclic (CSP) axis: it rides the SYNC.
    cyclic: bool,
}

/// SplitMix64: sequences reproducible from the seed alone.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn u8(&mut self, r: std::ops::Range<u8>) -> u8 {
        r.start + (self.next() % u64::from(r.end - r.start)) as u8
    }
    fn u64(&mut self, r: std::ops::Range<u64>) -> u64 {
        r.start + self.next() % (r.end - r.start)
    }
    fn f64(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn bool(&mut self) -> bool {
        self.next() & 1 == 1
    }
}

#[derive(Debug, Clone, Copy)]
enum Action {
    Enable,
    Disable,
    Home,
    Move {
        target: f64,
        relative: bool,
        wait: bool,
    },
    Jog {
        velocity: f64,
    },
    Stop {
        wait: bool,
    },
    QuickStop,
    ResetFault,
    Pause {
        ms: u64,
    },
    /// An engineer's operation on the axis's drive node, from a second
    /// client (CiA 402 axes only).
    Commission(Commissioning),
}

/// What a commissioning engineer does to the drive of a running machine.
#[derive(Debug, Clone, Copy)]
enum Commissioning {
    /// A raw SDO write of 0 to one of the drive's process objects
    /// (controlword: disable voltage; mode; targets).
    SdoWrite { index: u16 },
    /// An NMT command to the drive (START restores it afterwards).
    Nmt(pb::NmtCommand),
    /// A program download (the demo drives have no 0x1F50: at rest the
    /// node aborts it).
    ProgramDownload,
    /// LSS switch-global to configuration (and back to waiting).
    LssConfiguration,
    /// The bus's SYNC period changed (and restored at once).
    SyncPeriod,
}

fn action(rng: &mut Rng, l: &Limits) -> Action {
    // Targets near the middle, so that waited moves end in seconds; some
    // beyond the limits, which must be refused.
    let span = (l.max - l.min) / 2.0;
    match rng.u8(0..20) {
        0..=2 => Action::Enable,
        3 => Action::Disable,
        4 => Action::Home,
        5..=9 => Action::Move {
            target: if rng.u8(0..8) == 0 {
                l.max + span
            } else {
                (rng.f64() - 0.5) * 0.2 * span
            },
            relative: rng.bool(),
            wait: rng.bool(),
        },
        10..=11 => Action::Jog {
            velocity: (rng.f64() - 0.5) * l.max_velocity,
        },
        12..=13 => Action::Stop { wait: rng.bool() },
        14 => Action::QuickStop,
        15..=16 => Action::ResetFault,
        17..=18 if l.drive_node.is_some() => Action::Commission(match rng.u8(0..5) {
            0 => Commissioning::SdoWrite {
                index: [0x6040, 0x6060, 0x607A, 0x60FF][usize::from(rng.u8(0..4))],
            },
            1 => Commissioning::Nmt(
                [
                    pb::NmtCommand::EnterPreOperational,
                    pb::NmtCommand::Stop,
                    pb::NmtCommand::ResetCommunication,
                ][usize::from(rng.u8(0..3))],
            ),
            2 => Commissioning::ProgramDownload,
            // The SYNC period matters to the cyclic axes only.
            3 if !l.cyclic => Commissioning::LssConfiguration,
            3 | 4 if l.cyclic => Commissioning::SyncPeriod,
            _ => Commissioning::LssConfiguration,
        }),
        _ => Action::Pause {
            ms: rng.u64(0..300),
        },
    }
}

async fn bounded<T>(
    what: &str,
    f: impl std::future::Future<Output = Result<tonic::Response<T>, tonic::Status>>,
) -> Result<Result<T, tonic::Status>, String> {
    match tokio::time::timeout(CALL_BOUND, f).await {
        Err(_) => Err(format!("{what} did not return within {CALL_BOUND:?}")),
        Ok(Ok(r)) => Ok(Ok(r.into_inner())),
        Ok(Err(s)) if matches!(s.code(), Code::Internal | Code::Unknown | Code::Unavailable) => {
            Err(format!("{what} failed: {:?} {}", s.code(), s.message()))
        }
        Ok(Err(s)) => Ok(Err(s)),
    }
}

fn check_outcome(
    what: &str,
    r: &Result<pb::AxisCommandResponse, tonic::Status>,
    waited: bool,
) -> Result<(), String> {
    if let Ok(r) = r
        && waited
        && r.outcome == pb::Outcome::Timeout as i32
    {
        return Err(format!(
            "{what} ended TIMEOUT on a healthy drive: {}",
            r.detail
        ));
    }
    Ok(())
}

/// What a call ended with, for the summary: an outcome or a status code.
fn ended(r: &Result<pb::AxisCommandResponse, tonic::Status>) -> String {
    match r {
        Ok(r) => format!("{:?}", pb::Outcome::try_from(r.outcome).unwrap_or_default()),
        Err(s) => format!("{:?}", s.code()),
    }
}

async fn run_action(
    axes: &mut Axes,
    engineer: &cangate_client::Client,
    axis: &str,
    lease: &str,
    a: Action,
    l: &Limits,
) -> Result<String, String> {
    let what = format!("{a:?}");
    match a {
        Action::Commission(op) => commission(axes, engineer, axis, op, l).await,
        Action::Enable => {
            let r = bounded(&what, axes.enable(cmd(axis, lease, true))).await?;
            check_outcome(&what, &r, true).map(|()| ended(&r))
        }
        Action::Disable => {
            let r = bounded(&what, axes.disable(cmd(axis, lease, true))).await?;
            check_outcome(&what, &r, true).map(|()| ended(&r))
        }
        Action::Home => bounded(&what, axes.home(cmd(axis, lease, false)))
            .await
            .map(|r| ended(&r)),
        Action::Move {
            target,
            relative,
            wait,
        } => {
            let r = bounded(
                &what,
                axes.r#move(pb::MoveRequest {
                    axis: axis.into(),
                    target,
                    relative,
                    velocity: l.max_velocity / 2.0,
                    acceleration: 0.0,
                    options: opts(lease, wait),
                }),
            )
            .await?;
            check_outcome(&what, &r, wait).map(|()| ended(&r))
        }
        Action::Jog { velocity } => bounded(
            &what,
            axes.jog(pb::JogRequest {
                axis: axis.into(),
                velocity,
                acceleration: 0.0,
                options: opts(lease, false),
            }),
        )
        .await
        .map(|r| ended(&r)),
        Action::Stop { wait } => {
            let r = bounded(&what, axes.stop(cmd(axis, lease, wait))).await?;
            check_outcome(&what, &r, wait).map(|()| ended(&r))
        }
        Action::QuickStop => {
            let r = bounded(&what, axes.quick_stop(cmd(axis, lease, true))).await?;
            check_outcome(&what, &r, true).map(|()| ended(&r))
        }
        Action::ResetFault => {
            let r = bounded(&what, axes.reset_fault(cmd(axis, lease, true))).await?;
            check_outcome(&what, &r, true).map(|()| ended(&r))
        }
        Action::Pause { ms } => {
            tokio::time::sleep(Duration::from_millis(ms)).await;
            Ok("paused".into())
        }
    }
}

/// Runs `op` on the drive of `axis` from the engineer's client and checks
/// the guard: refused (FAILED_PRECONDITION, AXIS_ACTIVE naming the axis)
/// when the axis was enabled, and the axis still enabled afterwards.
async fn commission(
    axes: &mut Axes,
    engineer: &cangate_client::Client,
    axis: &str,
    op: Commissioning,
    l: &Limits,
) -> Result<String, String> {
    let Some(node) = l.drive_node else {
        return Ok("no drive node".into());
    };
    let what = format!("{op:?} on axis {axis}'s drive (node {node})");
    let enabled = |s: &pb::AxisStatus| s.state == pb::DriveState::OperationEnabled as i32;
    let before = status(axes, axis).await?;
    let mut co = engineer.canopen_client();
    let boot_ups_before = boot_ups(&mut co, node).await?;
    let outcome: Result<(), (Option<Code>, Option<String>, String)> = match op {
        Commissioning::SdoWrite { index } => bounded(
            &what,
            co.write_sdo(pb::WriteSdoRequest {
                bus: "can0".into(),
                node,
                index: u32::from(index),
                subindex: 0,
                data: Some(pb::write_sdo_request::Data::Raw(vec![0; 2])),
                ..Default::default()
            }),
        )
        .await?
        .map(|_| ())
        .map_err(status_parts),
        Commissioning::Nmt(command) => {
            let nmt = |command: pb::NmtCommand| pb::SendNmtRequest {
                bus: "can0".into(),
                node,
                command: command as i32,
                force: false,
            };
            let r = bounded(&what, co.send_nmt(nmt(command)))
                .await?
                .map(|_| ())
                .map_err(status_parts);
            if r.is_ok() && command == pb::NmtCommand::ResetCommunication {
                // The node reboots: the engineer waits for its boot-up.
                let deadline = tokio::time::Instant::now() + CALL_BOUND;
                while boot_ups(&mut co, node).await? <= boot_ups_before {
                    if tokio::time::Instant::now() > deadline {
                        return Err(format!("after {what} node {node} sent no boot-up"));
                    }
                    tokio::time::sleep(Duration::from_millis(20)).await;
                }
            }
            if r.is_ok() {
                // The engineer puts the node back where it was.
                bounded("NMT START", co.send_nmt(nmt(pb::NmtCommand::Start)))
                    .await?
                    .map_err(|s| format!("NMT START refused: {s:?}"))?;
            }
            r
        }
        Commissioning::ProgramDownload => {
            match tokio::time::timeout(
                CALL_BOUND,
                engineer.canopen("can0").download_program_with(
                    cangate_client::NodeId::new(node).expect("a node id"),
                    vec![0x5A; 64],
                    &Default::default(),
                    |_| {},
                ),
            )
            .await
            {
                Err(_) => return Err(format!("{what} did not return within {CALL_BOUND:?}")),
                Ok(Ok(_)) => Ok(()),
                Ok(Err(e)) => Err((e.code(), e.reason(), e.to_string())),
            }
        }
        Commissioning::LssConfiguration => {
            let mut lss = engineer.lss_client();
            let switch = |mode: pb::LssMode| pb::SwitchGlobalRequest {
                bus: "can0".into(),
                mode: mode as i32,
            };
            let r = bounded(&what, lss.switch_global(switch(pb::LssMode::Configuration)))
                .await?
                .map(|_| ())
                .map_err(status_parts);
            // Back to waiting whatever the answer (waiting is harmless).
            let _ = bounded(
                "LSS waiting",
                lss.switch_global(switch(pb::LssMode::Waiting)),
            )
            .await?;
            r
        }
        Commissioning::SyncPeriod => {
            let period = |us: u32| pb::SetSyncRequest {
                bus: "can0".into(),
                period_us: Some(us),
                ..Default::default()
            };
            let r = bounded(&what, co.set_sync(period(5_000)))
                .await?
                .map(|_| ())
                .map_err(status_parts);
            if r.is_ok() {
                // Refused only while a cyclic axis is enabled (its drive
                // came up meanwhile): the guard at work; the period stays.
                let back = bounded("SYNC period back", co.set_sync(period(10_000))).await?;
                if let Err(s) = back
                    && s.code() != Code::FailedPrecondition
                {
                    return Err(format!("restoring the SYNC period: {s:?}"));
                }
            }
            r
        }
    };
    let mut after = status(axes, axis).await?;
    if !enabled(&before) {
        // At rest the operation may have run, and a program download
        // boots the node again: the engineer waits for the drive to be
        // back before the operator goes on.
        let deadline = tokio::time::Instant::now() + CALL_BOUND;
        while after.node_lost || after.state == 0 {
            if tokio::time::Instant::now() > deadline {
                return Err(format!(
                    "after {what} the drive did not come back: {after:?}"
                ));
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
            after = status(axes, axis).await?;
        }
    }
    match (&outcome, enabled(&before)) {
        (Ok(()), true) => Err(format!(
            "{what} was accepted while the axis was enabled (state before {}, after {})",
            before.state, after.state
        )),
        (Err((code, _, message)), true) => {
            if *code != Some(Code::FailedPrecondition) {
                return Err(format!(
                    "{what} on an enabled axis ended {code:?}, not FAILED_PRECONDITION: {message}"
                ));
            }
            if !enabled(&after) {
                return Err(format!(
                    "{what} was refused but the axis left operation enabled (state {}): {message}",
                    after.state
                ));
            }
            Ok("refused".into())
        }
        (Ok(()), false) => Ok("done at rest".into()),
        (Err((code, _, _)), false) => Ok(format!("{code:?} at rest")),
    }
}

/// How many boot-ups the gateway has seen from `node`.
async fn boot_ups(
    co: &mut cangate_client::pb::canopen_client::CanopenClient<cangate_client::Transport>,
    node: u32,
) -> Result<u64, String> {
    let n = bounded(
        "GetNode",
        co.get_node(pb::GetNodeRequest {
            bus: "can0".into(),
            node,
        }),
    )
    .await?
    .map_err(|s| format!("GetNode: {s:?}"))?;
    Ok(n.boot_ups)
}

fn status_parts(s: tonic::Status) -> (Option<Code>, Option<String>, String) {
    (Some(s.code()), None, s.message().to_string())
}

async fn status(axes: &mut Axes, axis: &str) -> Result<pb::AxisStatus, String> {
    let a = bounded(
        "GetAxis",
        axes.get_axis(pb::GetAxisRequest { axis: axis.into() }),
    )
    .await?
    .map_err(|s| format!("GetAxis: {s:?}"))?;
    a.status.ok_or_else(|| format!("axis {axis} has no status"))
}

async fn position(axes: &mut Axes, axis: &str) -> Result<f64, String> {
    let a = bounded(
        "GetAxis",
        axes.get_axis(pb::GetAxisRequest { axis: axis.into() }),
    )
    .await?
    .map_err(|s| format!("GetAxis: {s:?}"))?;
    Ok(a.status.map_or(0.0, |s| s.position))
}

/// One seeded sequence on `axis`, then the recovery; the actions so far
/// in the error.
async fn sequence(
    client: &cangate_client::Client,
    engineer: &cangate_client::Client,
    axes: &mut Axes,
    axis: &str,
    seed: u64,
    l: &Limits,
) -> Result<(), String> {
    // Each axis its own sequence of the seed.
    let mut rng = Rng(seed.wrapping_mul(1_000_003) ^ u64::from(axis.as_bytes()[0]));
    // The client library's guard renews the lease in the background for
    // the whole sequence (a waited command may outlast a short TTL).
    let guard = client
        .acquire_control_as(&[axis], Duration::from_secs(30), "random sequences")
        .await
        .map_err(|e| format!("axis {axis}: AcquireControl: {e}"))?;
    let lease = guard.token().to_string();
    let mut done = Vec::new();
    let tolerance = (l.max - l.min) * 0.01;
    let fail =
        |done: &[Action], e: String| format!("axis {axis}, seed {seed}: {e}\n  after {done:?}");
    let mut tally = std::collections::BTreeMap::<String, u32>::new();
    for _ in 0..ACTIONS {
        let a = action(&mut rng, l);
        done.push(a);
        let how = run_action(axes, engineer, axis, &lease, a, l)
            .await
            .map_err(|e| fail(&done, e))?;
        let kind = format!("{a:?}");
        let kind = kind.split([' ', '{']).next().unwrap_or_default();
        *tally.entry(format!("{kind} {how}")).or_default() += 1;
        let p = position(axes, axis).await.map_err(|e| fail(&done, e))?;
        if p < l.min - tolerance || p > l.max + tolerance {
            return Err(fail(
                &done,
                format!("position {p} outside [{}, {}]", l.min, l.max),
            ));
        }
    }
    // Never wedged: stop, reset, enable, and a move to 0 completes there.
    let recover = [
        Action::Stop { wait: true },
        Action::ResetFault,
        Action::Enable,
    ];
    for a in recover {
        done.push(a);
        run_action(axes, engineer, axis, &lease, a, l)
            .await
            .map_err(|e| fail(&done, e))?;
    }
    let r = bounded(
        "final Move",
        axes.r#move(pb::MoveRequest {
            axis: axis.into(),
            target: 0.0,
            relative: false,
            velocity: l.max_velocity / 2.0,
            acceleration: 0.0,
            options: opts(&lease, true),
        }),
    )
    .await
    .map_err(|e| fail(&done, e))?
    .map_err(|s| {
        fail(
            &done,
            format!("final Move refused: {:?} {}", s.code(), s.message()),
        )
    })?;
    if r.outcome != pb::Outcome::Completed as i32 {
        return Err(fail(
            &done,
            format!("final Move ended {:?}: {}", r.outcome, r.detail),
        ));
    }
    let p = position(axes, axis).await.map_err(|e| fail(&done, e))?;
    if p.abs() > 0.05 {
        return Err(fail(&done, format!("final Move completed at {p}, not 0")));
    }
    guard
        .release()
        .await
        .map_err(|e| fail(&done, format!("ReleaseControl: {e}")))?;
    eprintln!("axis {axis}, seed {seed}: {tally:?}");
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn random_command_sequences_leave_every_axis_commandable() {
    let mut config = cangate_server::Config::demo();
    config.listen = "127.0.0.1:0".parse().unwrap();
    config.metrics_listen = None;
    let server = cangate_server::start(&config).await.expect("demo starts");
    let client = cangate_tests::client(&server).await;
    // The commissioning engineer: a connection of its own.
    let engineer = cangate_tests::client(&server).await;
    let mut axes = client.axes_client();
    // Each axis once its drive reports.
    let list = axes
        .list_axes(pb::ListAxesRequest {})
        .await
        .unwrap()
        .into_inner();
    let seeds: Vec<u64> = match std::env::var("AXES_RANDOM_SEED") {
        Ok(s) => vec![s.parse().expect("AXES_RANDOM_SEED is a number")],
        Err(_) => (1..=SEEDS).collect(),
    };
    let mut tasks = Vec::new();
    for (name, drive_node, cyclic) in [
        ("X", Some(1), true),
        ("Z", Some(4), false),
        ("A", None, false),
    ] {
        let a = list
            .axes
            .iter()
            .find(|a| a.name == name)
            .unwrap_or_else(|| panic!("the demo has axis {name}"))
            .clone();
        let limits = Limits {
            min: a.min_position.unwrap_or(-100.0),
            max: a.max_position.unwrap_or(100.0),
            max_velocity: a.max_velocity,
            drive_node,
            cyclic,
        };
        let mut axes = client.axes_client();
        let seeds = seeds.clone();
        let client = client.clone();
        let engineer = engineer.clone();
        tasks.push(tokio::spawn(async move {
            cangate_tests::axes::wait_status(&mut axes, name, |s| s.state != 0 && !s.node_lost)
                .await;
            for seed in seeds {
                sequence(&client, &engineer, &mut axes, name, seed, &limits).await?;
            }
            Ok::<(), String>(())
        }));
    }
    let mut failures = Vec::new();
    for t in tasks {
        if let Err(e) = t.await.expect("sequence task") {
            failures.push(e);
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The demo's profile axis Z homes on the drive's reference switch
/// (method 19): from either end of its range the homing completes within
/// its bound (the simulated drive's search speed covers the range well
/// within `homing_timeout_ms`; at 1 mm/s a homing from 30 mm ran out of
/// time), and an axis that homed moves on.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_demo_profile_axis_homes_from_both_ends_of_its_range() {
    let mut config = cangate_server::Config::demo();
    config.listen = "127.0.0.1:0".parse().unwrap();
    config.metrics_listen = None;
    let server = cangate_server::start(&config).await.expect("demo starts");
    let client = cangate_tests::client(&server).await;
    let mut axes = client.axes_client();
    cangate_tests::axes::wait_status(&mut axes, "Z", |s| s.state != 0 && !s.node_lost).await;
    let lease = acquire(&mut axes, &["Z"], 60_000, "homing test").await;
    cangate_tests::axes::enable(&mut axes, "Z", &lease).await;
    for end in [90.0, -90.0] {
        let r = axes
            .r#move(pb::MoveRequest {
                axis: "Z".into(),
                target: end,
                relative: false,
                velocity: 50.0,
                acceleration: 0.0,
                options: opts(&lease, true),
            })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
        let r = axes
            .home(cmd("Z", &lease, true))
            .await
            .unwrap_or_else(|s| panic!("home from {end} mm: {:?} {}", s.code(), s.message()))
            .into_inner();
        assert_eq!(
            r.outcome,
            pb::Outcome::Completed as i32,
            "from {end} mm: {r:?}"
        );
        let status = r.status.unwrap();
        assert!(status.homed, "{status:?}");
    }
}
