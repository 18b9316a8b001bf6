//! The python package (`python/`, installed into the test venv by
//! `scripts/test` with `pip install ./python`) against the real server
//! in-process, with python-can and python-canopen as independent peers:
//!
//! - `python_stubs_match_the_protos`: the committed stubs are what the
//!   `.proto` files generate now (`python/generate_stubs.py --check`), so
//!   they never rot;
//! - `python_can_interface_through_attach`: plain python-can through
//!   `can.Bus(interface="cangate", channel="can0")`
//!   (`tests/python/python_can_peer.py`), with bearer tokens on: frames it
//!   sends (classic, extended, remote, CAN FD with BRS) seen by a Rust
//!   StreamFrames client, frames the Rust client sends received by it, the
//!   gateway applying its filters, timestamps, own frames only when asked,
//!   a refused message raised by its send, a slow reader's lost frames
//!   counted exactly, errors for an unknown bus, a bad token and FD on a
//!   classic bus, and the gateway's shutdown raised by recv;
//! - `python_can_with_block_sends_every_frame`: the 15 messages a
//!   `with can.Bus(interface="cangate", ...)` block sends all reach the bus
//!   (`tests/python/python_can_with.py`), and refusals are raised;
//! - `python_canopen_local_node_through_attach`: a python-canopen
//!   `LocalNode` (`tests/python/local_node.py --interface cangate`, object
//!   dictionary `tests/python/all_types.eds`) attached through the python-can
//!   interface as node 42 on can0 of the demo configuration, with the
//!   default limits: its boot-up seen by the gateway's master, every CiA 301
//!   basic data type read and written by the master over the gRPC SDO API
//!   and checked on the device side, then a 4 KiB segmented DOMAIN write
//!   checked byte for byte and read back;
//! - `python_canopen_local_node_through_attach_on_vcan`: the same with the
//!   gateway's can0 on a real SocketCAN vcan0 (in a VM via
//!   `scripts/vcan-vm` when this host has none; see `common/vcan.rs`), the
//!   device still attached through the gateway's Attach;
//! - `python_client_api`: the package's typed client
//!   (`tests/python/client_api.py`) on the demo: buses, SDO with typed
//!   values and abort errors, an axis moved under a lease context manager,
//!   node events and handwheel feed streams.
//!
//! The interpreter is `CANGATE_PYTHON` (the venv of `scripts/test`), else
//! `python3`. Without python-can, python-canopen, grpcio-tools or the
//! package the tests are skipped with the reason, except under `CI=true`,
//! where they fail instead.

#[path = "common/python_peer.rs"]
mod python_peer;
#[path = "common/vcan.rs"]
mod vcan;

use anyhow::{Context, Result, anyhow, ensure};
use cangate_client::pb;
use cangate_client::pb::node_event::Event as NodeEv;
use cangate_server::Config;
use python_peer::{PYTHON_ENV, Peer, python_or_skip, script};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The device's node id on can0 (the demo's own nodes are 1-4 and 10).
const NODE: u32 = 42;
/// Starting python and importing grpc, can and canopen: seconds on a loaded
/// machine, more under TCG in the VM.
const READY_WAIT: Duration = Duration::from_secs(90);
/// Per-step waits.
const WAIT: Duration = Duration::from_secs(10);
/// One bound for a whole scenario.
const SCENARIO_LIMIT: Duration = Duration::from_secs(240);

// ------------------------------------------------------------ python

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// What the tests here import: the independent peers and the package.
const MODULES: &[&str] = &["can", "canopen", "grpc_tools", "cangate"];

/// Runs an async scenario on its own runtime, bounded, and panics with its
/// error.
fn run(test: &str, scenario: impl std::future::Future<Output = Result<()>>) {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("tokio runtime");
    let started = Instant::now();
    let result = rt.block_on(async {
        tokio::time::timeout(SCENARIO_LIMIT, scenario)
            .await
            .unwrap_or_else(|_| Err(anyhow!("not finished within {SCENARIO_LIMIT:?}")))
    });
    rt.shutdown_timeout(Duration::from_secs(1));
    if let Err(e) = result {
        panic!("{test}: {e:?}");
    }
    eprintln!(
        "{test}: all checks passed in {:.2} s",
        started.elapsed().as_secs_f64()
    );
}

// ------------------------------------------------------------ stubs

#[test]
fn python_stubs_match_the_protos() {
    let Some(python) = python_or_skip("python_stubs_match_the_protos", MODULES) else {
        return;
    };
    run("python_stubs_match_the_protos", async {
        let generator = repo().join("python/generate_stubs.py");
        let mut p = Peer::spawn(&python, &generator, &["--check"], &[])?;
        p.expect("stubs up to date", READY_WAIT, |l| {
            l.starts_with("stubs up to date")
        })
        .await?;
        p.finish(WAIT).await
    });
}

// ------------------------------------------------------------ python-can

const TOKEN: &str = "python-can-token";

fn python_can_config() -> String {
    format!(
        "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\nfd = true\nbitrate = 1000000\n\
         [[bus]]\nname = \"classic\"\nbackend = \"virtual\"\nbitrate = 500000\n\
         [[security.tokens]]\nname = \"python\"\nrole = \"engineer\"\nsha256 = \"{}\"\n",
        cangate_client::hash_token(TOKEN)
    )
}

fn std_frame(id: u32, data: &[u8]) -> pb::Frame {
    pb::Frame {
        id,
        data: data.to_vec(),
        ..Default::default()
    }
}

#[test]
fn python_can_interface_through_attach() {
    let Some(python) = python_or_skip("python_can_interface_through_attach", MODULES) else {
        return;
    };
    run(
        "python_can_interface_through_attach",
        python_can_scenario(python),
    );
}

async fn python_can_scenario(python: PathBuf) -> Result<()> {
    let server = cangate_tests::start_server(&python_can_config()).await;
    let mut c = cangate_client::connect_with(
        &format!("http://{}", server.addr),
        &cangate_client::ConnectOptions {
            token: Some(TOKEN.into()),
            ..Default::default()
        },
    )
    .await?;
    let (mut watch, mut pending) =
        cangate_tests::open_stream(&mut c, cangate_tests::stream_request("can0", vec![])).await;

    let peer_script = script("python_can_peer.py");
    let mut p = Peer::spawn(
        &python,
        &peer_script,
        &[] as &[&str],
        &[
            ("CANGATE_SERVER", format!("http://{}", server.addr)),
            ("CANGATE_TOKEN", TOKEN.into()),
        ],
    )?;
    p.expect_line("READY", READY_WAIT).await?;
    p.expect_line("SENT", WAIT).await?;

    // 1. What python-can sent, as the gateway's other clients see it.
    let seen = cangate_tests::read_frames(&mut watch, &mut pending, 4).await;
    let summary: Vec<_> = seen
        .iter()
        .map(|f| {
            (
                f.id,
                f.extended,
                f.remote,
                f.remote_dlc,
                f.fd,
                f.brs,
                f.data.len(),
            )
        })
        .collect();
    ensure!(
        summary
            == [
                (0x123, false, false, 0, false, false, 4),
                (0x1F33_4455, true, false, 0, false, false, 1),
                (0x123, false, true, 4, false, false, 0),
                (0x7AB, false, false, 0, true, true, 64),
            ],
        "python-can's frames as seen by StreamFrames: {summary:x?}"
    );
    ensure!(seen[0].data == [0xDE, 0xAD, 0xBE, 0xEF], "{:?}", seen[0]);
    ensure!(
        seen[3].data == (0..64).collect::<Vec<u8>>(),
        "{:?}",
        seen[3]
    );
    let sender = seen[0]
        .sender
        .clone()
        .context("a client frame names its sender")?;
    for f in &seen {
        ensure!(
            f.origin == pb::FrameOrigin::Client as i32
                && f.direction == pb::Direction::Rx as i32
                && f.sender.as_ref() == Some(&sender),
            "origin/sender of {f:?}"
        );
    }
    ensure!(
        sender.client.contains("python@127.0.0.1:"),
        "the sender is the token's identity: {sender:?}"
    );

    // 2. What the Rust client sends, received by python-can.
    let mut fd = std_frame(0x10A, &(0..48).collect::<Vec<u8>>());
    fd.fd = true;
    let ext = pb::Frame {
        extended: true,
        ..std_frame(0x105, &[3])
    };
    let frames = vec![std_frame(0x105, &[1]), std_frame(0x205, &[2]), ext, fd];
    let n = frames.len();
    c.send_pb("can0", frames).await?;
    p.say(&format!("GO {n}"))?;
    p.expect_line("RECEIVED", WAIT * 2).await?;

    // 3. A slow reader loses frames, and is told exactly how many.
    p.expect_line("SLOW", WAIT).await?;
    let flood = 3000u32;
    let frames: Vec<_> = (0..flood)
        .map(|i| std_frame(0x3FF, &i.to_le_bytes()))
        .collect();
    c.send_pb("can0", frames).await?;
    p.say(&format!("FLOOD {flood}"))?;
    let line = p
        .expect("LOST", WAIT * 2, |l| l.starts_with("LOST "))
        .await?;
    eprintln!("slow reader of {flood} frames: received and lost: {line}");

    // 4. The gateway shuts down: recv raises CanOperationError with the
    // gateway's status (also when the bus task ends before the stream's
    // forwarder sees the shutdown).
    p.expect_line("WAITING", WAIT).await?;
    server.shutdown();
    let end = p.expect("END", WAIT, |l| l.starts_with("END ")).await?;
    ensure!(
        end.contains("UNAVAILABLE: the gateway is shutting down"),
        "recv should raise the gateway's shutdown: {end}"
    );
    p.finish(WAIT).await?;
    // Graceful shutdown waits for the connections to close.
    drop((watch, c));
    server
        .wait(Duration::from_secs(5))
        .await
        .map_err(|e| anyhow!("shutdown: {e}"))?;
    Ok(())
}

/// The issue's program: `with can.Bus(interface="cangate", ...) as bus:
/// bus.send(msg)` 15 times. Every frame reaches the bus before the block
/// ends (`tests/python/python_can_with.py`), with `send` waiting for the
/// gateway's confirmation and with it only queueing (the end of the block
/// sends them); a refusal is raised by its `send`, or at the end of the
/// block.
#[test]
fn python_can_with_block_sends_every_frame() {
    let Some(python) = python_or_skip("python_can_with_block_sends_every_frame", MODULES) else {
        return;
    };
    run("python_can_with_block_sends_every_frame", async {
        let server = cangate_tests::start_server(&python_can_config()).await;
        let mut c = cangate_client::connect_with(
            &format!("http://{}", server.addr),
            &cangate_client::ConnectOptions {
                token: Some(TOKEN.into()),
                ..Default::default()
            },
        )
        .await?;
        let (mut watch, mut pending) =
            cangate_tests::open_stream(&mut c, cangate_tests::stream_request("can0", vec![])).await;
        let mut p = Peer::spawn(
            &python,
            &script("python_can_with.py"),
            &[] as &[&str],
            &[
                ("CANGATE_SERVER", format!("http://{}", server.addr)),
                ("CANGATE_TOKEN", TOKEN.into()),
            ],
        )?;
        p.expect_line("READY", READY_WAIT).await?;
        for first in [0x200u32, 0x300] {
            p.expect_line("SENT 15", WAIT).await?;
            let seen = cangate_tests::read_frames(&mut watch, &mut pending, 15).await;
            let got: Vec<(u32, Vec<u8>)> = seen.iter().map(|f| (f.id, f.data.clone())).collect();
            let want: Vec<(u32, Vec<u8>)> = (0..15u8)
                .map(|i| (first + u32::from(i), vec![i, 0x5A]))
                .collect();
            ensure!(got == want, "the block's frames on can0: {got:x?}");
        }
        for _ in 0..2 {
            let refused = p
                .expect("REFUSED", WAIT, |l| l.starts_with("REFUSED "))
                .await?;
            ensure!(refused.contains("INVALID_FRAME"), "{refused}");
        }
        p.finish(WAIT).await?;
        drop((watch, c));
        server.shutdown();
        server
            .wait(Duration::from_secs(5))
            .await
            .map_err(|e| anyhow!("shutdown: {e}"))
    });
}

/// python-can's own `bus.send_periodic()` on the cangate interface
/// (`tests/python/python_can_periodic.py`): the job runs in the gateway at
/// its period (ten frames take at least ten periods), `modify_data`
/// changes its data, `stop` ends it (nothing of it follows the frame sent
/// after the stop), and a program that dies without stopping its task
/// takes the job along.
#[test]
fn python_can_send_periodic_runs_in_the_gateway() {
    let Some(python) = python_or_skip("python_can_send_periodic_runs_in_the_gateway", MODULES)
    else {
        return;
    };
    run("python_can_send_periodic_runs_in_the_gateway", async {
        let server = cangate_tests::start_server(&python_can_config()).await;
        let mut c = cangate_client::connect_with(
            &format!("http://{}", server.addr),
            &cangate_client::ConnectOptions {
                token: Some(TOKEN.into()),
                ..Default::default()
            },
        )
        .await?;
        let on = |id| cangate_tests::stream_request("can0", vec![cangate_tests::standard_id(id)]);
        let (mut watch, mut pending) = cangate_tests::open_stream(&mut c, on(0x3A0)).await;
        let mut p = Peer::spawn(
            &python,
            &script("python_can_periodic.py"),
            &[] as &[&str],
            &[
                ("CANGATE_SERVER", format!("http://{}", server.addr)),
                ("CANGATE_TOKEN", TOKEN.into()),
                // This checkout's package, whatever the interpreter has.
                (
                    "PYTHONPATH",
                    repo().join("python/src").display().to_string(),
                ),
            ],
        )?;
        p.expect_line("READY", READY_WAIT).await?;
        p.expect_line("OPEN", WAIT).await?;
        // The job starts after this: ten frames, the first one period
        // after its start, cannot all come before ten periods from here.
        let started = Instant::now();
        p.say("GO")?;
        p.expect_line("STARTED", WAIT).await?;
        let mut seen = Vec::new();
        while seen.len() < 10 {
            seen.extend(cangate_tests::read_frames(&mut watch, &mut pending, 1).await);
        }
        ensure!(
            started.elapsed() >= Duration::from_millis(10 * 20),
            "ten frames of a 20 ms job within {:?}",
            started.elapsed()
        );
        ensure!(seen.iter().all(|f| f.data == [1]), "{seen:?}");
        p.say("MODIFY")?;
        p.expect_line("MODIFIED", WAIT).await?;
        let mut data = Vec::new();
        while !data.contains(&vec![2u8]) {
            let frames = cangate_tests::read_frames(&mut watch, &mut pending, 1).await;
            data.extend(frames.into_iter().map(|f| f.data));
        }
        p.say("STOP")?;
        p.expect_line("STOPPED", WAIT).await?;
        // The frame sent after the stop comes after every frame of the job.
        let mut data = Vec::new();
        while !data.contains(&vec![0xFFu8]) {
            let frames = cangate_tests::read_frames(&mut watch, &mut pending, 1).await;
            data.extend(frames.into_iter().map(|f| f.data));
        }
        ensure!(
            data.last() == Some(&vec![0xFF]),
            "frames after the stop: {data:?}"
        );
        cangate_tests::assert_quiet(&mut watch).await;

        // A program that dies takes its job along.
        let (mut watch, mut pending) = cangate_tests::open_stream(&mut c, on(0x3A1)).await;
        p.say("DIE")?;
        p.expect_line("DYING", WAIT).await?;
        cangate_tests::read_frames(&mut watch, &mut pending, 1).await;
        p.say("EXIT")?;
        p.finish(WAIT).await?;
        let deadline = Instant::now() + WAIT;
        while let Ok(m) = tokio::time::timeout(Duration::from_millis(500), watch.message()).await {
            m?.context("the stream ended")?;
            ensure!(
                Instant::now() < deadline,
                "the dead program's job still runs"
            );
        }
        drop((watch, c));
        server.shutdown();
        server
            .wait(Duration::from_secs(5))
            .await
            .map_err(|e| anyhow!("shutdown: {e}"))
    });
}

// ------------------------------------------------------------ python-canopen

/// The demo configuration on an ephemeral port, its CANopen part on can0
/// with the default limits (the CANsmc buses are left out: nothing to do
/// with can0).
fn demo_can0() -> Config {
    let mut c = Config::demo();
    c.listen = "127.0.0.1:0".parse().expect("address");
    c.cansmc.clear();
    c.buses.retain(|b| b.name == "can0");
    c
}

#[test]
fn python_canopen_local_node_through_attach() {
    let Some(python) = python_or_skip("python_canopen_local_node_through_attach", MODULES) else {
        return;
    };
    run("python_canopen_local_node_through_attach", async {
        let server = cangate_server::start(&demo_can0()).await?;
        local_node_scenario(&python, &server).await?;
        server.shutdown();
        server
            .wait(Duration::from_secs(5))
            .await
            .map_err(|e| anyhow!("shutdown: {e}"))
    });
}

#[test]
fn python_client_api() {
    let Some(python) = python_or_skip("python_client_api", MODULES) else {
        return;
    };
    run("python_client_api", async {
        let server = cangate_server::start(&demo_can0()).await?;
        let api_script = script("client_api.py");
        let mut p = Peer::spawn(
            &python,
            &api_script,
            &[] as &[&str],
            &[("CANGATE_SERVER", format!("http://{}", server.addr))],
        )?;
        p.expect_line("client api: all checks passed", READY_WAIT)
            .await?;
        p.finish(WAIT).await?;
        server.shutdown();
        server
            .wait(Duration::from_secs(5))
            .await
            .map_err(|e| anyhow!("shutdown: {e}"))
    });
}

/// The package's example `python/examples/stream_circle.py`: half a turn of
/// the circle streamed at 1 kHz on the demo's X and Y through 5 ms of
/// injected jitter, none refused, the stream ended by the client (the
/// example's exit status says so). The buffer is deep (500 ms) so that a
/// loaded host does not make it underrun: the figures are the benchmark's.
#[test]
fn python_stream_circle_example() {
    let Some(python) = python_or_skip("python_stream_circle_example", MODULES) else {
        return;
    };
    run("python_stream_circle_example", async {
        let server = cangate_server::start(&demo_can0()).await?;
        let example =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../python/examples/stream_circle.py");
        let mut p = Peer::spawn(
            &python,
            &example,
            &["--turns", "0.5", "--jitter-ms", "5", "--depth-ms", "500"],
            &[("CANGATE_SERVER", format!("http://{}", server.addr))],
        )?;
        let ended = p
            .expect("the stream's end", READY_WAIT, |l| {
                l.starts_with("circle r=")
            })
            .await?;
        ensure!(ended.ends_with("ended CLIENT_ENDED"), "{ended}");
        let counts = p
            .expect("the counters", WAIT, |l| l.starts_with("points received"))
            .await?;
        ensure!(counts.contains(", refused 0,"), "{counts}");
        p.finish(WAIT).await?;
        server.shutdown();
        server
            .wait(Duration::from_secs(5))
            .await
            .map_err(|e| anyhow!("shutdown: {e}"))
    });
}

/// A simulated drive in cyclic synchronous torque (T) on can0, for the
/// torque stream of `torque_stream.py`.
const TORQUE_CONFIG: &str = r#"
listen = "127.0.0.1:0"

[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"
sync_period_us = 5000

[[canopen.node]]
id = 2
eds = "builtin:drive"
simulate = true

[[axis]]
name = "T"
bus = "can0"
node = 2
counts_per_unit = 1000.0
mode = "cst"
min_position = -5000.0
max_position = 5000.0
max_velocity = 30.0
max_acceleration = 1000.0
max_torque = 300.0
torque_slope = 2000.0
"#;

#[test]
fn python_torque_stream() {
    let Some(python) = python_or_skip("python_torque_stream", MODULES) else {
        return;
    };
    run("python_torque_stream", async {
        let config = Config::from_toml(TORQUE_CONFIG)?;
        let server = cangate_server::start(&config).await?;
        let mut p = Peer::spawn(
            &python,
            &script("torque_stream.py"),
            &[] as &[&str],
            &[("CANGATE_SERVER", format!("http://{}", server.addr))],
        )?;
        p.expect_line("torque stream: all checks passed", READY_WAIT)
            .await?;
        p.finish(WAIT).await?;
        server.shutdown();
        server
            .wait(Duration::from_secs(5))
            .await
            .map_err(|e| anyhow!("shutdown: {e}"))
    });
}

/// Must equal the function name below: the VM re-runs exactly this test.
const VCAN_TEST: &str = "python_canopen_local_node_through_attach_on_vcan";

#[test]
fn python_canopen_local_node_through_attach_on_vcan() {
    let plan = vcan::plan("vcan0");
    if let vcan::Plan::Unavailable(reason) = &plan {
        return vcan::skip_or_fail(VCAN_TEST, reason);
    }
    let Some(python) = python_or_skip(VCAN_TEST, MODULES) else {
        return;
    };
    match plan {
        vcan::Plan::Here => run(VCAN_TEST, async {
            // can0 is the kernel's vcan0; the master's SDO timeout is
            // generous for python under TCG.
            let config = Config::from_toml(
                "listen = \"127.0.0.1:0\"\n\
                 [[bus]]\nname = \"can0\"\nbackend = \"socketcan\"\ninterface = \"vcan0\"\n\
                 [[canopen]]\nbus = \"can0\"\nsdo_timeout_ms = 2000\n",
            )
            .map_err(|e| anyhow!("{e}"))?;
            let server = cangate_server::start(&config).await?;
            local_node_scenario(&python, &server).await?;
            server.shutdown();
            server
                .wait(Duration::from_secs(5))
                .await
                .map_err(|e| anyhow!("shutdown: {e}"))
        }),
        vcan::Plan::Vm(runner) => {
            let python = python.to_string_lossy().into_owned();
            vcan::run_in_vm(&runner, VCAN_TEST, &[(PYTHON_ENV, python.as_str())]);
        }
        vcan::Plan::Unavailable(_) => unreachable!(),
    }
}

/// The value of `ty` in a typed SDO request or response.
fn value(ty: pb::DataType, v: pb::value::Value) -> pb::Value {
    pb::Value {
        r#type: ty as i32,
        value: Some(v),
    }
}

/// Every basic type of all_types.eds: object, type, the EDS default, a new
/// value and its encoding on the bus.
fn every_type() -> Vec<(
    u32,
    pb::DataType,
    pb::value::Value,
    pb::value::Value,
    Vec<u8>,
)> {
    use pb::DataType as T;
    use pb::value::Value as V;
    vec![
        (
            0x2100,
            T::Boolean,
            V::BoolValue(true),
            V::BoolValue(false),
            vec![0],
        ),
        (
            0x2101,
            T::Integer8,
            V::IntValue(-5),
            V::IntValue(-128),
            vec![0x80],
        ),
        (
            0x2102,
            T::Integer16,
            V::IntValue(-1234),
            V::IntValue(32767),
            vec![0xFF, 0x7F],
        ),
        (
            0x2103,
            T::Integer32,
            V::IntValue(-123_456_789),
            V::IntValue(-2),
            vec![0xFE, 0xFF, 0xFF, 0xFF],
        ),
        (
            0x2104,
            T::Integer64,
            V::IntValue(-1_234_567_890_123),
            V::IntValue(i64::MIN),
            i64::MIN.to_le_bytes().to_vec(),
        ),
        (
            0x2105,
            T::Unsigned8,
            V::UintValue(200),
            V::UintValue(255),
            vec![0xFF],
        ),
        (
            0x2106,
            T::Unsigned16,
            V::UintValue(60000),
            V::UintValue(0x1234),
            vec![0x34, 0x12],
        ),
        (
            0x2107,
            T::Unsigned32,
            V::UintValue(0xDEAD_BEEF),
            V::UintValue(0xFFFF_FFFF),
            vec![0xFF; 4],
        ),
        (
            0x2108,
            T::Unsigned64,
            V::UintValue(0x0123_4567_89AB_CDEF),
            V::UintValue(u64::MAX - 1),
            (u64::MAX - 1).to_le_bytes().to_vec(),
        ),
        (
            0x2109,
            T::Real32,
            V::RealValue(1.5),
            V::RealValue(-0.375),
            (-0.375f32).to_le_bytes().to_vec(),
        ),
        (
            0x210A,
            T::Real64,
            V::RealValue(-2.25),
            V::RealValue(1e300),
            1e300f64.to_le_bytes().to_vec(),
        ),
        (
            0x210B,
            T::VisibleString,
            V::StringValue("cangate all types".into()),
            V::StringValue("written by the gateway's master".into()),
            b"written by the gateway's master".to_vec(),
        ),
        (
            0x210C,
            T::OctetString,
            V::BytesValue(vec![0x01, 0x02, 0xA0, 0xFF]),
            V::BytesValue(vec![0x00, 0xFF, 0x10, 0x20, 0x30, 0x40, 0x50, 0x60, 0x70]),
            vec![0x00, 0xFF, 0x10, 0x20, 0x30, 0x40, 0x50, 0x60, 0x70],
        ),
    ]
}

/// The device's protocol: `WRITE iiii:ss <hex>` for each SDO download it
/// stored; exactly `data` at `index:00`.
async fn local_node_scenario(python: &Path, server: &cangate_server::RunningServer) -> Result<()> {
    let t0 = Instant::now();
    let step = |name: &str| eprintln!("[{:>6.2} s] {name}", t0.elapsed().as_secs_f64());
    let c = cangate_client::connect(&format!("http://{}", server.addr)).await?;
    let mut events = c
        .canopen_client()
        .stream_node_events(pb::StreamNodeEventsRequest {
            bus: "can0".into(),
            nodes: vec![NODE],
        })
        .await?
        .into_inner();

    step("starting the python-canopen LocalNode, attached through the cangate interface");
    let node_script = script("local_node.py");
    let eds = script("all_types.eds");
    let mut dev = Peer::spawn(
        python,
        &node_script,
        &[
            "--interface",
            "cangate",
            "--channel",
            "can0",
            "--node-id",
            &NODE.to_string(),
            "--eds",
            &eds.to_string_lossy(),
            "--max-seconds",
            "240",
        ],
        &[("CANGATE_SERVER", format!("http://{}", server.addr))],
    )?;
    dev.expect_line("READY", READY_WAIT).await?;

    step("boot-up seen by the gateway's master");
    let deadline = Instant::now() + WAIT;
    loop {
        let ev = tokio::time::timeout_at(deadline.into(), events.message())
            .await
            .map_err(|_| anyhow!("no boot-up of node {NODE} within {WAIT:?}"))??
            .ok_or_else(|| anyhow!("node event stream ended"))?;
        if matches!(ev.event, Some(NodeEv::BootUp(_))) {
            break;
        }
        eprintln!("  node event: {ev:?}");
    }
    let node = c
        .canopen_client()
        .get_node(pb::GetNodeRequest {
            bus: "can0".into(),
            node: NODE,
        })
        .await?
        .into_inner();
    ensure!(node.boot_ups == 1, "GetNode after the boot-up: {node:?}");

    let read = |index: u32, ty: pb::DataType| pb::ReadSdoRequest {
        bus: "can0".into(),
        node: NODE,
        index,
        subindex: 0,
        r#type: ty as i32,
        options: None,
        object: String::new(),
    };
    let write = |index: u32, v: pb::Value| pb::WriteSdoRequest {
        bus: "can0".into(),
        node: NODE,
        index,
        subindex: 0,
        data: Some(pb::write_sdo_request::Data::Value(v)),
        options: None,
        object: String::new(),
        force: false,
    };
    let mut canopen = c.canopen_client();

    step("SDO reads of every basic type (the EDS defaults)");
    let r = canopen
        .read_sdo(read(0x1008, pb::DataType::VisibleString))
        .await?
        .into_inner();
    ensure!(
        r.raw == b"python-canopen via cangate Attach",
        "0x1008: {:?}",
        String::from_utf8_lossy(&r.raw)
    );
    for (index, ty, default, _, _) in every_type() {
        let r = canopen.read_sdo(read(index, ty)).await?.into_inner();
        ensure!(
            r.value == Some(value(ty, default.clone())),
            "0x{index:04X} {ty:?}: read {:?} (raw {:02X?}), expected {default:?}",
            r.value,
            r.raw
        );
    }

    step("SDO writes of every basic type, checked on the device, read back");
    for (index, ty, _, new, bytes) in every_type() {
        let w = canopen
            .write_sdo(write(index, value(ty, new.clone())))
            .await
            .with_context(|| format!("writing 0x{index:04X} {ty:?}"))?
            .into_inner();
        ensure!(
            w.bytes as usize == bytes.len(),
            "0x{index:04X}: wrote {} bytes",
            w.bytes
        );
        dev.expect_stored(u16::try_from(index)?, 0, &bytes, WAIT)
            .await?;
        let r = canopen.read_sdo(read(index, ty)).await?.into_inner();
        ensure!(
            r.value == Some(value(ty, new.clone())),
            "0x{index:04X} {ty:?}: read back {:?}, expected {new:?}",
            r.value
        );
    }

    step("4 KiB segmented DOMAIN write, checked byte for byte on the device");
    let image: Vec<u8> = (0..4096u32).map(|i| (i * 131 + 7) as u8).collect();
    let started = Instant::now();
    let w = canopen
        .write_sdo(write(
            0x210D,
            value(
                pb::DataType::Domain,
                pb::value::Value::BytesValue(image.clone()),
            ),
        ))
        .await
        .context("the 4 KiB segmented write with the default limits")?
        .into_inner();
    let write_time = started.elapsed();
    ensure!(w.bytes == 4096, "wrote {} bytes", w.bytes);
    dev.expect_stored(0x210D, 0, &image, WAIT).await?;
    let started = Instant::now();
    let r = canopen
        .read_sdo(read(0x210D, pb::DataType::Domain))
        .await?
        .into_inner();
    let read_time = started.elapsed();
    ensure!(
        r.raw == image,
        "read back {} bytes, not the image",
        r.raw.len()
    );
    eprintln!(
        "4 KiB DOMAIN through the attached python-canopen node: segmented write {:.0} ms, \
         segmented read {:.0} ms",
        write_time.as_secs_f64() * 1e3,
        read_time.as_secs_f64() * 1e3
    );

    step("stopping the device: no frame lost for it");
    dev.say("QUIT")?;
    let lost = dev.expect("LOST", WAIT, |l| l.starts_with("LOST ")).await?;
    ensure!(
        lost == "LOST 0",
        "the gateway dropped frames for the device: {lost}"
    );
    dev.expect_line("BYE", WAIT).await?;
    dev.finish(WAIT).await?;
    step("done");
    Ok(())
}
