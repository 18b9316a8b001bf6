//! The CiA 402 modes end to end: the real server on a virtual bus with
//! simulated drives, over gRPC: a jog in cyclic synchronous velocity, a
//! torque in cyclic synchronous torque with its velocity guard, stops in
//! each mode, the mode change at rest only, and interpolated position on
//! a drive without CSP.

use cangate_client::pb;
use cangate_sim::{DeviceHandle, SimDrive, SimDriveOptions, SimNodeOptions};
use cangate_tests::axes::*;
use cangate_tests::*;
use tokio_util::sync::CancellationToken;
use tonic::Code;

/// V: CSV; T: CST (guard at 30 mm/s); P: CSP; I: interpolated position on
/// node 4, a drive without CSP the test runs; N: configured CSP on node
/// 5, also without CSP. SYNC every 5 ms.
const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"
sync_period_us = 5000

[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true

[[canopen.node]]
id = 2
eds = "builtin:drive"
simulate = true

[[canopen.node]]
id = 3
eds = "builtin:drive"
simulate = true

[[canopen.node]]
id = 4
eds = "builtin:drive"

[[canopen.node]]
id = 5
eds = "builtin:drive"

[[axis]]
name = "V"
bus = "can0"
node = 1
counts_per_unit = 1000.0
mode = "csv"
min_position = -500.0
max_position = 500.0
max_velocity = 100.0
max_acceleration = 1000.0
jog_deadman_ms = 5000

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

[[axis]]
name = "P"
bus = "can0"
node = 3
counts_per_unit = 1000.0
mode = "csp"
min_position = -200.0
max_position = 200.0
max_velocity = 100.0
max_acceleration = 1000.0
jog_deadman_ms = 5000

[[axis]]
name = "I"
bus = "can0"
node = 4
counts_per_unit = 1000.0
mode = "ip"
min_position = -200.0
max_position = 200.0
max_velocity = 100.0
max_acceleration = 1000.0

[[axis]]
name = "N"
bus = "can0"
node = 5
counts_per_unit = 1000.0
mode = "csp"
max_velocity = 100.0
max_acceleration = 1000.0
"#;

/// PP, PV, HM, IP: a drive without CSP (and without CSV or torque
/// modes).
const NO_CSP: u32 = 0x65;

/// Runs a simulated drive without CSP at `node` on the server's `can0`.
fn drive_without_csp(
    server: &cangate_server::RunningServer,
    node: u32,
) -> (DeviceHandle<SimDrive>, CancellationToken) {
    let port = server
        .gateway()
        .network()
        .get("can0")
        .expect("virtual can0")
        .connect(false);
    let drive = SimDrive::bundled(
        cangate_canopen::NodeId::new(node).unwrap(),
        SimDriveOptions {
            node: SimNodeOptions::default(),
            supported_modes: Some(NO_CSP),
            ..SimDriveOptions::default()
        },
    );
    let handle = DeviceHandle::new(drive);
    let cancel = CancellationToken::new();
    cangate_sim::spawn_device(port, handle.clone(), cancel.clone());
    (handle, cancel)
}

async fn setup() -> (cangate_server::RunningServer, Axes, Vec<CancellationToken>) {
    let server = start_server(CONFIG).await;
    let drives = [4, 5].map(|n| drive_without_csp(&server, n).1);
    let c = client(&server).await;
    let mut axes = c.axes_client();
    wait_ready(&mut axes, &["V", "T", "P", "I"]).await;
    (server, axes, drives.to_vec())
}

fn jog(axis: &str, velocity: f64, lease: &str) -> pb::JogRequest {
    pb::JogRequest {
        axis: axis.into(),
        velocity,
        acceleration: 200.0,
        options: opts(lease, false),
    }
}

fn set_mode(axis: &str, mode: pb::DriveMode, lease: &str) -> pb::SetAxisModeRequest {
    pb::SetAxisModeRequest {
        axis: axis.into(),
        mode: mode as i32,
        options: opts(lease, true),
    }
}

fn torque(axis: &str, per_mille: f64, lease: &str, wait: bool) -> pb::SetTorqueRequest {
    pb::SetTorqueRequest {
        axis: axis.into(),
        torque_per_mille: per_mille,
        options: opts(lease, wait),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn csv_jogs_and_stops_at_rest() {
    let (_server, mut axes, _drives) = setup().await;
    let lease = acquire(&mut axes, &["V"], 30_000, "csv").await;
    enable(&mut axes, "V", &lease).await;
    let info = axes
        .get_axis(pb::GetAxisRequest { axis: "V".into() })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(info.mode, pb::DriveMode::Csv as i32);
    assert_eq!(info.status.unwrap().mode, 9);
    // A move has no meaning in CSV.
    let e = axes
        .r#move(pb::MoveRequest {
            axis: "V".into(),
            target: 10.0,
            relative: false,
            velocity: 0.0,
            acceleration: 0.0,
            options: opts(&lease, false),
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    assert!(e.message().contains("csv"), "{}", e.message());
    axes.jog(jog("V", 20.0, &lease)).await.unwrap();
    wait_status(&mut axes, "V", |s| (s.velocity - 20.0).abs() < 1.0).await;
    let r = axes
        .stop(cmd("V", &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    let s = r.status.unwrap();
    assert!(s.velocity.abs() < 0.1, "{s:?}");
    assert_eq!(s.activity, pb::AxisActivity::Idle as i32);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cst_torque_is_guarded_against_a_runaway_and_stops() {
    let (_server, mut axes, _drives) = setup().await;
    let lease = acquire(&mut axes, &["T"], 30_000, "cst").await;
    enable(&mut axes, "T", &lease).await;
    // Above max_torque.
    let e = axes
        .set_torque(torque("T", 400.0, &lease, false))
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::OutOfRange, "{e:?}");
    // 30 per mille: the unloaded simulated motor settles near 20 mm/s,
    // under the guard; Stop brakes it on the drive's halt ramp.
    let r = axes
        .set_torque(torque("T", 30.0, &lease, false))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Accepted as i32, "{r:?}");
    wait_status(&mut axes, "T", |s| s.velocity > 5.0).await;
    let r = axes
        .stop(cmd("T", &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    assert!(r.status.unwrap().velocity.abs() < 0.1);
    // 200 per mille would run the unloaded motor to 190 mm/s: the guard
    // stops it past 30 mm/s, and the waited command says so.
    let e = axes
        .set_torque(torque("T", 200.0, &lease, true))
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::Aborted, "{e:?}");
    assert!(
        e.message().contains("exceeded max_velocity 30"),
        "{}",
        e.message()
    );
    let s = wait_status(&mut axes, "T", |s| {
        s.activity == pb::AxisActivity::Idle as i32
    })
    .await;
    assert!(s.velocity.abs() < 0.1, "{s:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_mode_changes_at_rest_only() {
    let (_server, mut axes, _drives) = setup().await;
    let lease = acquire(&mut axes, &["P"], 30_000, "modes").await;
    enable(&mut axes, "P", &lease).await;
    // At rest: to CSV, done when the drive shows mode 9.
    let r = axes
        .set_mode(set_mode("P", pb::DriveMode::Csv, &lease))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    assert_eq!(r.status.unwrap().mode, 9);
    // Moving: refused, the jog runs on.
    axes.jog(jog("P", 10.0, &lease)).await.unwrap();
    wait_status(&mut axes, "P", |s| s.velocity > 5.0).await;
    let e = axes
        .set_mode(set_mode("P", pb::DriveMode::Csp, &lease))
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    assert!(e.message().contains("only at rest"), "{}", e.message());
    let s = axes
        .get_axis(pb::GetAxisRequest { axis: "P".into() })
        .await
        .unwrap()
        .into_inner()
        .status
        .unwrap();
    assert_eq!(s.mode, 9);
    assert_eq!(s.activity, pb::AxisActivity::Jogging as i32);
    // A torque mode without 0x6071 in the process data: refused.
    let e = axes
        .set_mode(set_mode("P", pb::DriveMode::Cst, &lease))
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    // Stopped: back to CSP, and a move runs.
    axes.stop(cmd("P", &lease, true)).await.unwrap();
    let r = axes
        .set_mode(set_mode("P", pb::DriveMode::Csp, &lease))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.status.unwrap().mode, 8);
    let at = r.outcome;
    assert_eq!(at, pb::Outcome::Completed as i32);
    let r = axes
        .r#move(pb::MoveRequest {
            axis: "P".into(),
            target: 5.0,
            relative: true,
            velocity: 50.0,
            acceleration: 500.0,
            options: opts(&lease, true),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn interpolated_position_moves_a_drive_without_csp() {
    let (_server, mut axes, _drives) = setup().await;
    let lease = acquire(&mut axes, &["I"], 30_000, "ip").await;
    enable(&mut axes, "I", &lease).await;
    let r = axes
        .r#move(pb::MoveRequest {
            axis: "I".into(),
            target: 10.0,
            relative: false,
            velocity: 50.0,
            acceleration: 500.0,
            options: opts(&lease, true),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    let s = r.status.unwrap();
    assert_eq!(s.mode, 7);
    assert!((s.position - 10.0).abs() <= 0.01, "{s:?}");
    // The drive has no CSP, nor CSV (its 0x6502, read at its boot).
    for (mode, name) in [(pb::DriveMode::Csp, "csp"), (pb::DriveMode::Csv, "csv")] {
        let e = axes
            .set_mode(set_mode("I", mode, &lease))
            .await
            .unwrap_err();
        assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
        assert!(
            e.message().contains(&format!("does not support {name}")),
            "{}",
            e.message()
        );
    }
    // A stop mid-move in IP ends at rest.
    axes.r#move(pb::MoveRequest {
        axis: "I".into(),
        target: -50.0,
        relative: false,
        velocity: 50.0,
        acceleration: 500.0,
        options: opts(&lease, false),
    })
    .await
    .unwrap();
    wait_status(&mut axes, "I", |s| s.velocity < -5.0).await;
    let r = axes
        .stop(cmd("I", &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    // N is configured in CSP on a drive without it: its boot fails and
    // says why.
    let s = wait_status(&mut axes, "N", |s| {
        s.fault_text.contains("does not support")
    })
    .await;
    assert!(s.node_lost, "{s:?}");
    assert!(
        s.fault_text.contains("cyclic synchronous position"),
        "{}",
        s.fault_text
    );
}
