//! CiA 402 axes whose process data goes by SDO (`process_data = "sdo"`),
//! end to end: the real server on a virtual bus without SYNC, simulated
//! drives, the real client. No PDO is used; the wire shows the SDO writes
//! of the set-point handshake; a drive that stops answering faults its
//! axis and a rebooted one is usable again.

use cangate_client::pb;
use cangate_tests::axes::*;
use cangate_tests::*;
use tonic::Code;

/// S: a simulated drive run by the server. T: a drive the test runs (to
/// switch it off), with no heartbeat consumer: only the SDO polls notice.
const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"
sdo_timeout_ms = 100

[[canopen.node]]
id = 3
eds = "builtin:drive"
simulate = true

[[canopen.node]]
id = 6
eds = "builtin:drive"

[[axis]]
name = "S"
bus = "can0"
node = 3
counts_per_unit = 1000.0
min_position = -100.0
max_position = 100.0
max_velocity = 50.0
max_acceleration = 500.0
process_data = "sdo"
sdo_poll_ms = 5

[[axis]]
name = "T"
bus = "can0"
node = 6
counts_per_unit = 1000.0
max_velocity = 50.0
max_acceleration = 500.0
process_data = "sdo"
sdo_poll_ms = 5
"#;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_sdo_axis_enables_homes_and_moves_without_any_pdo() {
    let server = start_server(CONFIG).await;
    let mut c = client(&server).await;
    let mut axes = c.axes_client();
    let a = axes
        .get_axis(pb::GetAxisRequest { axis: "S".into() })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(a.process_data, pb::ProcessDataPath::Sdo as i32);
    assert_eq!(a.sdo_poll_ms, 5);
    // The state comes from the polls.
    let s = wait_status(&mut axes, "S", |s| s.state != 0 && !s.node_lost).await;
    assert_eq!(s.state, pb::DriveState::SwitchOnDisabled as i32, "{s:?}");

    // The axis's RPDO COB-IDs (the gateway must send nothing there) and its
    // SDO requests. (The drive's own default TPDOs may run: the gateway
    // neither maps nor uses them.)
    let (mut frames, mut pending) = open_stream(
        &mut c,
        pb::StreamFramesRequest {
            include_transmitted: true,
            ..stream_request(
                "can0",
                vec![standard_id(0x203), standard_id(0x303), standard_id(0x603)],
            )
        },
    )
    .await;

    let lease = acquire(&mut axes, &["S"], 10_000, "test").await;
    enable(&mut axes, "S", &lease).await;
    let r = axes
        .home(cmd("S", &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    assert!(r.status.unwrap().homed);
    let r = axes
        .r#move(pb::MoveRequest {
            axis: "S".into(),
            target: 2.0,
            relative: false,
            velocity: 50.0,
            acceleration: 500.0,
            options: opts(&lease, true),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    let s = wait_status(&mut axes, "S", |s| (s.position - 2.0).abs() < 0.011).await;
    assert_eq!(s.state, pb::DriveState::OperationEnabled as i32);

    // The wire: the SDO downloads (expedited, size indicated) in order up
    // to the end of the set-point handshake (controlword 0x2F: bit 4
    // cleared after the acknowledge), and not one PDO.
    let mut downloads: Vec<Vec<u8>> = Vec::new();
    let clear = vec![0x2B, 0x40, 0x60, 0x00, 0x2F, 0x00, 0x00, 0x00];
    let mut seen_set_point = false;
    while !(seen_set_point && downloads.last() == Some(&clear)) {
        for f in read_frames(&mut frames, &mut pending, 1).await {
            assert_eq!(
                f.id, 0x603,
                "the gateway sent an RPDO to the SDO axis: {f:?}"
            );
            if matches!(f.data.first(), Some(0x23 | 0x27 | 0x2B | 0x2F)) {
                if f.data[..6] == [0x2B, 0x40, 0x60, 0x00, 0x3F, 0x00] {
                    seen_set_point = true;
                }
                downloads.push(f.data);
            }
        }
    }
    // The target (2000 counts) goes before the new set-point edge.
    let target = [0x23, 0x7A, 0x60, 0x00, 0xD0, 0x07, 0x00, 0x00];
    let at_target = downloads
        .iter()
        .rposition(|d| d[..] == target)
        .unwrap_or_else(|| panic!("no 0x607A = 2000 write in {downloads:02X?}"));
    let at_edge = downloads
        .iter()
        .rposition(|d| d[..6] == [0x2B, 0x40, 0x60, 0x00, 0x3F, 0x00])
        .unwrap();
    assert!(at_target < at_edge, "{downloads:02X?}");
    assert_eq!(
        downloads.last().unwrap(),
        &clear,
        "handshake ends with bit 4 cleared"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_sdo_drive_faults_its_axis_until_it_is_back() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut axes = c.axes_client();
    let (_drive, off) = run_drive(&server, 6, None);
    wait_status(&mut axes, "T", |s| s.state != 0 && !s.node_lost).await;
    let lease = acquire(&mut axes, &["T"], 10_000, "test").await;
    enable(&mut axes, "T", &lease).await;

    // Switched off: the polls time out, and after three in a row the axis
    // reports its node lost, naming the SDO failure.
    off.cancel();
    let s = wait_status(&mut axes, "T", |s| s.node_lost).await;
    assert!(
        s.fault_text.contains("process data by SDO failed"),
        "{}",
        s.fault_text
    );
    let e = axes.enable(cmd("T", &lease, false)).await.unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition);
    assert!(e.message().contains("node is lost"), "{}", e.message());

    // Switched on again: boot-up, boot procedure, polls answer, usable.
    let (_drive, _on) = run_drive(&server, 6, None);
    wait_status(&mut axes, "T", |s| !s.node_lost && s.state != 0).await;
    enable(&mut axes, "T", &lease).await;
}

/// The status's ErrorInfo reason and its metadata value `key`.
fn reason_and(e: &tonic::Status, key: &str) -> (String, String) {
    let info = cangate_client::error_info(e).expect("ErrorInfo");
    let value = info.metadata.get(key).cloned().unwrap_or_default();
    (info.reason, value)
}

fn write_u16(node: u32, index: u32, value: u16, force: bool) -> pb::WriteSdoRequest {
    pb::WriteSdoRequest {
        bus: "can0".into(),
        node,
        index,
        subindex: 0,
        data: Some(pb::write_sdo_request::Data::Raw(
            value.to_le_bytes().to_vec(),
        )),
        options: None,
        object: String::new(),
        force,
    }
}

/// A raw SDO write to the controlword, mode, targets or program control of
/// an enabled axis's drive is refused (AXIS_ACTIVE, naming the axis) before
/// anything reaches the drive; other objects are written; `force` writes;
/// once the axis is disabled the same write goes through.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn raw_sdo_writes_to_an_enabled_axis_drive_are_refused_unless_forced() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut axes = c.axes_client();
    let mut co = c.canopen_client();
    wait_status(&mut axes, "S", |s| s.state != 0 && !s.node_lost).await;
    let lease = acquire(&mut axes, &["S"], 10_000, "test").await;
    enable(&mut axes, "S", &lease).await;

    for (index, bytes) in [
        (0x6040, 0u16),
        (0x6060, 1),
        (0x607A, 0),
        (0x60FF, 0),
        (0x6071, 0),
        (0x1F51, 0),
    ] {
        let e = co
            .write_sdo(write_u16(3, index, bytes, false))
            .await
            .unwrap_err();
        assert_eq!(e.code(), Code::FailedPrecondition, "0x{index:04X}: {e:?}");
        assert_eq!(
            reason_and(&e, "axis"),
            ("AXIS_ACTIVE".to_string(), "S".to_string()),
            "0x{index:04X}"
        );
        assert!(e.message().contains("axis S"), "{}", e.message());
    }
    let s = wait_status(&mut axes, "S", |_| true).await;
    assert_eq!(s.state, pb::DriveState::OperationEnabled as i32, "{s:?}");

    // Another object of the drive: written.
    co.write_sdo(pb::WriteSdoRequest {
        data: Some(pb::write_sdo_request::Data::Raw(
            500u32.to_le_bytes().to_vec(),
        )),
        ..write_u16(3, 0x6083, 0, false)
    })
    .await
    .expect("profile acceleration");
    // Forced (an engineer's decision): the controlword the axis holds.
    co.write_sdo(write_u16(3, 0x6040, 0x000F, true))
        .await
        .expect("forced controlword");

    // Disabled: the drive is free again.
    let r = axes
        .disable(cmd("S", &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    co.write_sdo(write_u16(3, 0x6040, 0x0006, false))
        .await
        .expect("the controlword of a disabled axis's drive");
}

/// NMT commands that take a drive out of operational (it would stop
/// receiving its set-points mid-move) are refused while its axis is
/// enabled, to the drive and to all nodes; START is not; `force` sends
/// them; a disabled axis's drive takes them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nmt_commands_that_stop_an_enabled_axis_drive_are_refused_unless_forced() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut axes = c.axes_client();
    let mut co = c.canopen_client();
    wait_status(&mut axes, "S", |s| s.state != 0 && !s.node_lost).await;
    let lease = acquire(&mut axes, &["S"], 10_000, "test").await;
    enable(&mut axes, "S", &lease).await;
    let nmt = |node: u32, command: pb::NmtCommand, force: bool| pb::SendNmtRequest {
        bus: "can0".into(),
        node,
        command: command as i32,
        force,
    };
    for node in [3, 0] {
        for command in [
            pb::NmtCommand::Stop,
            pb::NmtCommand::EnterPreOperational,
            pb::NmtCommand::ResetNode,
            pb::NmtCommand::ResetCommunication,
        ] {
            let e = co.send_nmt(nmt(node, command, false)).await.unwrap_err();
            assert_eq!(
                e.code(),
                Code::FailedPrecondition,
                "{command:?} to {node}: {e:?}"
            );
            assert_eq!(
                reason_and(&e, "axis"),
                ("AXIS_ACTIVE".to_string(), "S".to_string()),
                "{command:?} to {node}"
            );
        }
        co.send_nmt(nmt(node, pb::NmtCommand::Start, false))
            .await
            .expect("START is never refused");
    }
    let s = wait_status(&mut axes, "S", |_| true).await;
    assert_eq!(s.state, pb::DriveState::OperationEnabled as i32, "{s:?}");
    // Forced (the typed client's and the CLI's `--force`): sent; the node
    // goes pre-operational (this SDO-driven axis keeps its drive; an axis
    // with PDOs loses its process data and faults).
    let can0 = c.canopen("can0");
    let drive = cangate_client::NodeId::new(3).unwrap();
    can0.nmt_forced(Some(drive), pb::NmtCommand::EnterPreOperational)
        .await
        .expect("a forced pre-operational");
    let t0 = std::time::Instant::now();
    loop {
        let n = can0.node(drive).await.expect("node 3");
        if n.state == pb::NmtState::PreOperational as i32 {
            break;
        }
        assert!(t0.elapsed() < WAIT, "node 3 stays {n:?}");
        tokio::time::sleep(std::time::Duration::from_millis(20)).await;
    }
    co.send_nmt(nmt(3, pb::NmtCommand::Start, false))
        .await
        .expect("start");
    // Disabled: the drive takes them again.
    let r = axes
        .disable(cmd("S", &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    co.send_nmt(nmt(3, pb::NmtCommand::EnterPreOperational, false))
        .await
        .expect("pre-operational for a disabled axis's drive");
    co.send_nmt(nmt(3, pb::NmtCommand::Start, false))
        .await
        .expect("start");
}
