//! The master's own heartbeat and the drives that watch it: the gateway
//! produces `0x77F [05]` (node 127 by default) every 100 ms, the boot
//! procedure writes each axis drive's consumer time (0x1016:01), and a drive
//! that stops hearing it faults (EMCY 0x8130) and stops on its own.
//!
//! Two ways the heartbeat stops: dropped on the virtual bus by fault
//! injection (the gateway lives on, the drive must still stop), and the
//! gateway process killed with SIGKILL mid-jog while the drive runs in
//! another process on a kernel `vcan0` (in the VM when the host has none;
//! see `common/vcan.rs`).

#[path = "common/vcan.rs"]
mod vcan;

use cangate_client::pb;
use cangate_tests::axes::{Axes, acquire, enable, opts, wait_status};
use cangate_tests::*;
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// One profile axis X on a simulated drive (node 1).
const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"

[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true
heartbeat_timeout_ms = 300

[[axis]]
name = "X"
bus = "can0"
node = 1
counts_per_unit = 1000.0
max_velocity = 100.0
max_acceleration = 1000.0
"#;

/// The master's heartbeat period and the drives' consumer time (defaults).
const PERIOD: Duration = Duration::from_millis(100);
const CONSUMER: Duration = Duration::from_millis(300);

async fn axis_ready(axes: &mut Axes) {
    wait_status(axes, "X", |s| s.state != 0 && !s.node_lost).await;
}

/// A frame stream of `can0` with the gateway's own frames (its heartbeat)
/// and these standard identifiers.
fn own_and(ids: &[u32]) -> pb::StreamFramesRequest {
    let mut r = stream_request(
        "can0",
        ids.iter()
            .map(|&id| pb::FrameFilter {
                id,
                mask: 0x7FF,
                format: pb::IdFormat::Standard as i32,
                invert: false,
            })
            .collect(),
    );
    r.include_transmitted = true;
    r
}

/// Jogs X at `velocity` and keeps the jog alive (dead-man) until `until`.
async fn jog_for(axes: &mut Axes, lease: &str, velocity: f64, until: Duration) {
    let t0 = Instant::now();
    while t0.elapsed() < until {
        axes.jog(pb::JogRequest {
            axis: "X".into(),
            velocity,
            acceleration: 0.0,
            options: opts(lease, false),
        })
        .await
        .expect("jog accepted");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_master_heartbeat_is_produced_and_the_drive_told_to_watch_it() {
    let server = start_server(CONFIG).await;
    let mut c = client(&server).await;
    let mut axes = c.axes_client();
    axis_ready(&mut axes).await;
    let (mut frames, mut pending) = open_stream(&mut c, own_and(&[0x77F])).await;
    let got: Vec<_> = read_frames(&mut frames, &mut pending, 4).await;
    for f in &got {
        assert_eq!((f.id, f.data.as_slice()), (0x77F, &[0x05][..]), "{f:?}");
    }
    // About one per period (bus timestamps; a loaded host may stretch one).
    let span = (got[3].timestamp_ns - got[0].timestamp_ns) as f64 / 1e6;
    assert!(span >= 250.0, "3 periods in {span} ms");
    // The boot procedure configured the consumer: node 127, 300 ms.
    let r = c
        .read_sdo(pb::ReadSdoRequest {
            bus: "can0".into(),
            node: 1,
            index: 0x1016,
            subindex: 1,
            r#type: 0,
            options: None,
            object: String::new(),
        })
        .await
        .unwrap();
    assert_eq!(r.raw, (127u32 << 16 | 300).to_le_bytes());
}

#[test]
fn master_heartbeat_keys_are_validated() {
    let cfg = |extra: &str| {
        cangate_server::Config::from_toml(&format!(
            "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\n[[canopen]]\nbus = \"can0\"\n{extra}\n\
             [[canopen.node]]\nid = 5\n"
        ))
    };
    let err = |extra: &str| cfg(extra).expect_err(extra).to_string();
    assert!(err("master_node_id = 5").contains("master's own node id"));
    assert!(err("master_node_id = 0").contains("out of range"));
    assert!(
        err("master_heartbeat_ms = 100\ndrive_heartbeat_timeout_ms = 100").contains("must exceed")
    );
    let c = cfg("master_node_id = 100\nmaster_heartbeat_ms = 50").unwrap();
    assert_eq!(c.canopen[0].master_heartbeat(), Some((100, 50)));
    assert_eq!(c.canopen[0].drive_heartbeat_timeout_ms(), Some(150));
    let off = cfg("master_heartbeat_ms = 0").unwrap();
    assert_eq!(off.canopen[0].master_heartbeat(), None);
    assert_eq!(off.canopen[0].drive_heartbeat_timeout_ms(), None);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_jogging_drive_faults_and_stops_when_the_master_heartbeat_is_dropped() {
    let server = start_server(CONFIG).await;
    let mut c = client(&server).await;
    let mut axes = c.axes_client();
    axis_ready(&mut axes).await;
    let lease = acquire(&mut axes, &["X"], 10_000, "test").await;
    enable(&mut axes, "X", &lease).await;
    jog_for(&mut axes, &lease, 20.0, Duration::from_millis(500)).await;
    wait_status(&mut axes, "X", |s| s.velocity > 19.0).await;
    let (mut frames, mut pending) = open_stream(&mut c, own_and(&[0x77F, 0x081])).await;
    // A heartbeat the drive heard, then the fault.
    let mut last_heartbeat = None;
    while last_heartbeat.is_none() {
        let f = read_frames(&mut frames, &mut pending, 1).await.remove(0);
        if f.id == 0x77F {
            last_heartbeat = Some(f.timestamp_ns);
        }
    }
    // The gateway keeps jogging, but its heartbeat no longer reaches the
    // drive.
    let mut sim = pb::simulator_client::SimulatorClient::new(c.channel());
    sim.set_bus_faults(pb::SetBusFaultsRequest {
        bus: "can0".into(),
        drop_ids: vec![0x77F],
        ..Default::default()
    })
    .await
    .unwrap();
    let jog = {
        let mut axes = axes.clone();
        let lease = lease.clone();
        tokio::spawn(async move {
            // Until the axis refuses: it is in fault.
            let t0 = Instant::now();
            while t0.elapsed() < Duration::from_secs(5) {
                let r = axes
                    .jog(pb::JogRequest {
                        axis: "X".into(),
                        velocity: 20.0,
                        acceleration: 0.0,
                        options: opts(&lease, false),
                    })
                    .await;
                if r.is_err() {
                    return;
                }
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        })
    };
    // The last heartbeat the drive heard, then its EMCY 0x8130.
    let emcy = loop {
        let f = read_frames(&mut frames, &mut pending, 1).await.remove(0);
        match f.id {
            0x77F => last_heartbeat = Some(f.timestamp_ns),
            _ if f.data.starts_with(&[0x30, 0x81]) => break f,
            _ => {}
        }
    };
    let last = last_heartbeat.expect("heartbeats seen before the drop");
    let after = Duration::from_nanos(emcy.timestamp_ns - last);
    assert!(
        after >= CONSUMER - Duration::from_millis(20),
        "EMCY {after:?} after the last heartbeat: before the consumer time"
    );
    assert!(
        after <= CONSUMER + PERIOD + Duration::from_secs(1),
        "EMCY only {after:?} after the last heartbeat"
    );
    // The axis shows why, and the drive stops although the gateway jogs on.
    let st = wait_status(&mut axes, "X", |s| s.fault_code == 0x8130).await;
    assert!(!st.fault_text.is_empty(), "{st:?}");
    wait_status(&mut axes, "X", |s| s.velocity.abs() < 1e-9).await;
    jog.await.unwrap();
}

// ------------------------------------------------ two processes on vcan0

/// Must equal the function names below: the VM and the child re-run them.
const KILL_TEST: &str = "gateway_killed_mid_jog_the_drive_in_another_process_stops";
const CHILD_TEST: &str = "gateway_process_for_the_kill_test";
/// Set in the child's environment: run the gateway there.
const CHILD_ENV: &str = "CANGATE_TEST_GATEWAY_CHILD";
const IFACE: &str = "vcan0";

/// The child's gateway: the drive (node 1) is not simulated here, it runs
/// in the parent process on the same `vcan0`.
fn child_config() -> String {
    format!(
        "listen = \"127.0.0.1:0\"\n\
         [[bus]]\nname = \"can0\"\nbackend = \"socketcan\"\ninterface = \"{IFACE}\"\n\
         [[canopen]]\nbus = \"can0\"\n\
         [[canopen.node]]\nid = 1\neds = \"builtin:drive\"\nheartbeat_timeout_ms = 1000\n\
         [[axis]]\nname = \"X\"\nbus = \"can0\"\nnode = 1\ncounts_per_unit = 1000.0\n\
         max_velocity = 100.0\nmax_acceleration = 1000.0\n"
    )
}

#[test]
#[ignore = "the gateway process of the kill test; it starts it itself"]
fn gateway_process_for_the_kill_test() {
    if std::env::var_os(CHILD_ENV).is_none() {
        return;
    }
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let config = cangate_server::Config::from_toml(&child_config()).unwrap();
        let server = cangate_server::start(&config).await.unwrap();
        println!("LISTEN {}", server.addr);
        // Until the parent kills it; bounded in case the parent died first.
        tokio::time::sleep(Duration::from_secs(120)).await;
    });
}

#[test]
fn gateway_killed_mid_jog_the_drive_in_another_process_stops() {
    match vcan::plan(IFACE) {
        vcan::Plan::Here => run_kill_test(),
        vcan::Plan::Vm(runner) => vcan::run_in_vm(&runner, KILL_TEST, &[]),
        vcan::Plan::Unavailable(reason) => vcan::skip_or_fail(KILL_TEST, &reason),
    }
}

/// Kills the child with SIGKILL when the test ends, however it ends.
struct ChildGuard(std::process::Child);

impl Drop for ChildGuard {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn run_kill_test() {
    use cangate_canopen::cia402::DriveState;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        // The gateway: this test binary again, running the child test.
        let mut child = ChildGuard(
            Command::new(std::env::current_exe().unwrap())
                .args(["--exact", CHILD_TEST, "--ignored", "--nocapture"])
                .env(CHILD_ENV, "1")
                .stdin(Stdio::null())
                .stdout(Stdio::piped())
                .stderr(Stdio::inherit())
                .spawn()
                .expect("the gateway process starts"),
        );
        let stdout = child.0.stdout.take().unwrap();
        let addr = tokio::task::spawn_blocking(move || {
            BufReader::new(stdout)
                .lines()
                .map_while(Result::ok)
                .find_map(|l| l.strip_prefix("LISTEN ").map(str::to_string))
        });
        let addr = tokio::time::timeout(Duration::from_secs(60), addr)
            .await
            .expect("the gateway listens in time")
            .unwrap()
            .expect("the gateway printed its address");

        // The drive, in this process, on the kernel's vcan0.
        let cancel = tokio_util::sync::CancellationToken::new();
        let info = cangate_can::BusInfo {
            name: "vcan0".into(),
            kind: cangate_can::BackendKind::SocketCan,
            interface: IFACE.into(),
            fd: false,
            bitrate: None,
            data_bitrate: None,
            bit_timed: false,
            stuffing: cangate_can::Stuffing::Exact,
        };
        let socket = cangate_can::socketcan_bus::SocketCanBus::open(IFACE).expect("vcan0 opens");
        let (bus, _bus_task) = cangate_can::BusHandle::spawn(
            info,
            cangate_can::Backend::SocketCan(socket),
            cancel.clone(),
        );
        let drive = cangate_sim::DeviceHandle::new(cangate_sim::SimDrive::bundled(
            cangate_canopen::NodeId::new(1).unwrap(),
            cangate_sim::SimDriveOptions {
                node: cangate_sim::SimNodeOptions {
                    heartbeat_ms: Some(100),
                    ..Default::default()
                },
                ..Default::default()
            },
        ));
        cangate_sim::spawn_device_on_bus(bus, drive.clone(), cancel.clone());

        let c = cangate_client::connect(&format!("http://{addr}"))
            .await
            .expect("client connects");
        let mut axes = c.axes_client();
        axis_ready(&mut axes).await;
        let lease = acquire(&mut axes, &["X"], 10_000, "test").await;
        enable(&mut axes, "X", &lease).await;
        jog_for(&mut axes, &lease, 20.0, Duration::from_millis(500)).await;
        let (state, velocity, consumer) = drive.with(|d| {
            (
                d.state(),
                d.velocity(),
                d.node()
                    .get(cangate_canopen::ObjectAddress::new(0x1016, 1))
                    .and_then(|v| v.as_u32()),
            )
        });
        assert_eq!(state, DriveState::OperationEnabled);
        assert!(velocity > 19_000.0, "jogging at {velocity} inc/s");
        assert_eq!(
            consumer,
            Some(127 << 16 | 300),
            "0x1016:01 from the boot procedure"
        );

        // kill -9 mid-jog.
        let killed = Instant::now();
        child.0.kill().expect("SIGKILL");
        child.0.wait().unwrap();
        let reaction = loop {
            let state = drive.with(|d| d.state());
            if state != DriveState::OperationEnabled {
                break killed.elapsed();
            }
            assert!(
                killed.elapsed() < Duration::from_secs(5),
                "the drive still runs {:?} after the gateway died",
                killed.elapsed()
            );
            tokio::time::sleep(Duration::from_millis(2)).await;
        };
        let (code, lost) = drive.with(|d| {
            let lost = d
                .take_events()
                .into_iter()
                .any(|e| matches!(e, cangate_sim::SimEvent::HeartbeatLost { .. }));
            (d.error_code(), lost)
        });
        assert_eq!(code, 0x8130, "heartbeat error");
        assert!(lost, "the drive's consumer reported the loss");
        // Within the consumer time of the last heartbeat (sent up to one
        // period before the kill); slack for the process and VM scheduling.
        eprintln!("{KILL_TEST}: the drive faulted {reaction:?} after SIGKILL");
        assert!(
            reaction <= CONSUMER + Duration::from_millis(300),
            "faulted only {reaction:?} after the kill"
        );
        let t0 = Instant::now();
        while drive.with(|d| d.velocity()) != 0.0 {
            assert!(
                t0.elapsed() < Duration::from_secs(5),
                "the drive did not stop"
            );
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        assert_eq!(drive.with(|d| d.state()), DriveState::Fault);
        cancel.cancel();
    });
}
