//! Two axes on one CiA 402 drive node end to end (CiA 402 multi-axis:
//! axis 1's objects at index + 0x800): the real server on a virtual bus
//! with the simulated two-axis drive (`builtin:drive2`), over gRPC. Each
//! axis enables and moves on its own; a stop or a quick stop of one leaves
//! the other moving; a node reset takes both; the drive guard refuses
//! program download, raw writes of either axis's process objects and NMT
//! while either axis is enabled.

use cangate_client::{Error, NodeId, ProgramOptions, pb};
use cangate_tests::axes::*;
use cangate_tests::*;
use tonic::Code;

/// A and B: axes 0 and 1 of the two-axis drive at node 3, cyclic
/// synchronous position on a 5 ms SYNC.
const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"
sync_period_us = 5000
sdo_timeout_ms = 200
# No master heartbeat for the drive to watch: on a loaded machine its
# loss would fault both axes, which is not what these tests are about.
master_heartbeat_ms = 0

[[canopen.node]]
id = 3
eds = "builtin:drive2"
simulate = true

[[axis]]
name = "A"
bus = "can0"
node = 3
mode = "csp"
counts_per_unit = 1000.0
min_position = -500.0
max_position = 500.0
max_velocity = 100.0
max_acceleration = 1000.0
jog_deadman_ms = 10000

[[axis]]
name = "B"
bus = "can0"
node = 3
drive_axis = 1
mode = "csp"
counts_per_unit = 1000.0
min_position = -500.0
max_position = 500.0
max_velocity = 100.0
max_acceleration = 1000.0
jog_deadman_ms = 10000
"#;

fn move_to(axis: &str, target: f64, lease: &str) -> pb::MoveRequest {
    pb::MoveRequest {
        axis: axis.into(),
        target,
        relative: false,
        velocity: 50.0,
        acceleration: 500.0,
        options: opts(lease, true),
    }
}

fn jog(axis: &str, velocity: f64, lease: &str) -> pb::JogRequest {
    pb::JogRequest {
        axis: axis.into(),
        velocity,
        acceleration: 0.0,
        options: opts(lease, false),
    }
}

async fn status(axes: &mut Axes, axis: &str) -> pb::AxisStatus {
    wait_status(axes, axis, |_| true).await
}

const ENABLED: i32 = pb::DriveState::OperationEnabled as i32;
const JOGGING: i32 = pb::AxisActivity::Jogging as i32;
const IDLE: i32 = pb::AxisActivity::Idle as i32;

/// Waits until `axis` has moved on by more than 1 mm (in the direction
/// of `sign`) from where it is now, jogging and enabled: it keeps moving.
/// (Position, not the drive's instantaneous velocity, which a late SYNC
/// on a busy machine makes jump.)
async fn keeps_jogging(axes: &mut Axes, axis: &str, sign: f64) {
    let s = status(axes, axis).await;
    assert_eq!((s.state, s.activity), (ENABLED, JOGGING), "{axis}: {s:?}");
    let p = s.position;
    wait_status(axes, axis, |s| {
        sign * (s.position - p) > 1.0 && s.state == ENABLED && s.activity == JOGGING
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_axes_of_one_drive_move_and_stop_independently_and_a_node_reset_takes_both() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut axes = c.axes_client();
    wait_ready(&mut axes, &["A", "B"]).await;
    let lease = acquire(&mut axes, &["A", "B"], 20_000, "test").await;

    // Each enables on its own: B first, A still disabled.
    enable(&mut axes, "B", &lease).await;
    assert_ne!(status(&mut axes, "A").await.state, ENABLED);
    enable(&mut axes, "A", &lease).await;

    // Each moves on its own objects.
    let r = axes.r#move(move_to("A", 10.0, &lease)).await.unwrap();
    assert_eq!(r.into_inner().outcome, pb::Outcome::Completed as i32);
    let r = axes.r#move(move_to("B", -5.0, &lease)).await.unwrap();
    assert_eq!(r.into_inner().outcome, pb::Outcome::Completed as i32);
    let (a, b) = (status(&mut axes, "A").await, status(&mut axes, "B").await);
    assert!((a.position - 10.0).abs() < 0.05, "{a:?}");
    assert!((b.position + 5.0).abs() < 0.05, "{b:?}");

    // Both jog; B's stop leaves A jogging.
    axes.jog(jog("A", 20.0, &lease)).await.unwrap();
    axes.jog(jog("B", 20.0, &lease)).await.unwrap();
    keeps_jogging(&mut axes, "B", 1.0).await;
    let r = axes
        .stop(cmd("B", &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    let b = status(&mut axes, "B").await;
    assert_eq!((b.state, b.activity), (ENABLED, IDLE), "{b:?}");
    keeps_jogging(&mut axes, "A", 1.0).await;

    // A quick stop of A leaves B enabled and B can move meanwhile.
    axes.jog(jog("B", -20.0, &lease)).await.unwrap();
    let r = axes
        .quick_stop(cmd("A", &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    assert_ne!(status(&mut axes, "A").await.state, ENABLED);
    keeps_jogging(&mut axes, "B", -1.0).await;
    let r = axes
        .stop(cmd("B", &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");

    // A node reset (forced past the guard, as a power glitch would) takes
    // both axes out of operation enabled; both come back disabled.
    enable(&mut axes, "A", &lease).await;
    c.canopen_client()
        .send_nmt(pb::SendNmtRequest {
            bus: "can0".into(),
            node: 3,
            command: pb::NmtCommand::ResetNode as i32,
            force: true,
        })
        .await
        .expect("forced NMT reset");
    for axis in ["A", "B"] {
        let s = wait_status(&mut axes, axis, |s| {
            s.state == pb::DriveState::SwitchOnDisabled as i32 && !s.node_lost
        })
        .await;
        assert_ne!(s.state, ENABLED, "{axis}: {s:?}");
    }
    // Both enable again after the reset.
    enable(&mut axes, "A", &lease).await;
    enable(&mut axes, "B", &lease).await;
}

/// While one axis of the drive is enabled and the other is not (axis 1,
/// then axis 0), the node is still its drive: a program download, a raw
/// write of either axis's controlword and an NMT command to the node are
/// refused (AXIS_ACTIVE, naming the enabled axis); once neither is
/// enabled the download runs.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn any_enabled_axis_of_a_drive_node_guards_the_node() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut axes = c.axes_client();
    wait_ready(&mut axes, &["A", "B"]).await;
    let lease = acquire(&mut axes, &["A", "B"], 20_000, "test").await;
    let img = cangate_sim::program::test_image(2_000, 1);
    let download = |img: Vec<u8>| {
        let c = c.clone();
        async move {
            tokio::time::timeout(
                WAIT * 3,
                c.canopen("can0").download_program_with(
                    NodeId::new(3).unwrap(),
                    img,
                    &ProgramOptions::default(),
                    |_| {},
                ),
            )
            .await
            .expect("the download ends in time")
        }
    };
    for (on, off) in [("B", "A"), ("A", "B")] {
        enable(&mut axes, on, &lease).await;
        assert_ne!(status(&mut axes, off).await.state, ENABLED);
        match download(img.clone()).await {
            Err(Error::Refused {
                code,
                reason,
                message,
                ..
            }) => {
                assert_eq!(code, Code::FailedPrecondition);
                assert_eq!(reason, "AXIS_ACTIVE");
                assert!(message.contains(&format!("axis {on}")), "{message}");
            }
            other => panic!("{on} enabled: not refused: {other:?}"),
        }
        let mut control = c.canopen_client();
        for index in [0x6040, 0x6840] {
            let e = control
                .write_sdo(pb::WriteSdoRequest {
                    bus: "can0".into(),
                    node: 3,
                    index,
                    subindex: 0,
                    data: Some(pb::write_sdo_request::Data::Raw(vec![0x00, 0x00])),
                    ..Default::default()
                })
                .await
                .unwrap_err();
            assert_eq!(e.code(), Code::FailedPrecondition, "0x{index:04X}: {e:?}");
            assert!(
                e.message().contains(&format!("axis {on}")),
                "{}",
                e.message()
            );
        }
        let e = control
            .send_nmt(pb::SendNmtRequest {
                bus: "can0".into(),
                node: 3,
                command: pb::NmtCommand::ResetNode as i32,
                force: false,
            })
            .await
            .unwrap_err();
        assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
        assert_eq!(status(&mut axes, on).await.state, ENABLED);
        let r = axes
            .disable(cmd(on, &lease, true))
            .await
            .unwrap()
            .into_inner();
        assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    }
    download(img)
        .await
        .expect("a drive with no enabled axis takes a program");
}

/// A lapsed lease stops only the axes it held: B's lease lapses while both
/// axes of the drive jog; B comes to rest, A (under another lease) keeps
/// jogging, enabled.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lapsed_lease_of_one_axis_leaves_the_other_axis_of_the_drive_moving() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut axes = c.axes_client();
    wait_ready(&mut axes, &["A", "B"]).await;
    let lease_a = acquire(&mut axes, &["A"], 20_000, "keeps").await;
    // B's lease is never renewed: it lapses 4 s after it was taken.
    let lease_b = acquire(&mut axes, &["B"], 4_000, "lapses").await;
    enable(&mut axes, "B", &lease_b).await;
    axes.jog(jog("B", 20.0, &lease_b)).await.unwrap();
    enable(&mut axes, "A", &lease_a).await;
    axes.jog(jog("A", 20.0, &lease_a)).await.unwrap();
    keeps_jogging(&mut axes, "B", 1.0).await;
    let b = wait_status(&mut axes, "B", |s| s.activity == IDLE && s.velocity == 0.0).await;
    assert_eq!(b.state, ENABLED, "a halt keeps it enabled: {b:?}");
    assert!(b.position > 0.0, "{b:?}");
    keeps_jogging(&mut axes, "A", 1.0).await;
}
