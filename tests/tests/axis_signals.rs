//! The CiA 402 signals end to end (issue 28): torque, following error and
//! digital inputs in the axis status, the touch probe's latches as events,
//! a limit switch that stops the axis and lets it back off, a following
//! error fault that says why; against simulated drives over gRPC.

use cangate_client::pb;
use cangate_client::pb::axis_update::Update;
use cangate_client::{SetpointStreamOptions, setpoint};
use cangate_tests::axes::*;
use cangate_tests::*;
use std::time::Duration;
use tonic::Code;

/// X: cyclic, switches at -50 mm (negative limit), 0 mm (home), 50 mm
/// (positive limit), touch probe input at 20 mm. Y: cyclic with a tight
/// following error window. Z: profile, its signals not mapped. SYNC every
/// 5 ms.
const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"
sync_period_us = 5000
# No master heartbeat for the drives to watch: on a loaded machine its
# loss would fault them, which is not what these tests are about.
master_heartbeat_ms = 0

[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true
sim = { negative_limit_switch = -50000, positive_limit_switch = 50000, home_switch = 0, touch_probe = 20000 }

[[canopen.node]]
id = 2
eds = "builtin:drive"
simulate = true

[[canopen.node]]
id = 3
eds = "builtin:drive"
simulate = true

[[axis]]
name = "X"
bus = "can0"
node = 1
counts_per_unit = 1000.0
position_mode = "cyclic"
min_position = -200.0
max_position = 200.0
max_velocity = 100.0
max_acceleration = 1000.0
max_torque = 2000
signal_pdos = true

[[axis]]
name = "Y"
bus = "can0"
node = 2
counts_per_unit = 1000.0
position_mode = "cyclic"
min_position = -200.0
max_position = 200.0
max_velocity = 100.0
max_acceleration = 1000.0
following_error_window = 0.05
following_error_timeout_ms = 20
signal_pdos = true

[[axis]]
name = "Z"
bus = "can0"
node = 3
counts_per_unit = 1000.0
max_velocity = 100.0
max_acceleration = 1000.0
"#;

async fn setup() -> (cangate_server::RunningServer, Axes, String) {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut axes: Axes = pb::axes_client::AxesClient::new(c.channel());
    wait_ready(&mut axes, &["X", "Y"]).await;
    let lease = acquire(&mut axes, &["X", "Y"], 10_000, "signals").await;
    (server, axes, lease)
}

fn move_to(axis: &str, target: f64, lease: &str, wait: bool) -> pb::MoveRequest {
    pb::MoveRequest {
        axis: axis.into(),
        target,
        relative: false,
        velocity: 50.0,
        acceleration: 500.0,
        options: opts(lease, wait),
    }
}

async fn status(axes: &mut Axes, axis: &str) -> pb::AxisStatus {
    axes.get_axis(pb::GetAxisRequest { axis: axis.into() })
        .await
        .unwrap()
        .into_inner()
        .status
        .unwrap()
}

/// Reads StreamAxisState until `f` returns something (bounded).
async fn watch<T>(
    stream: &mut tonic::Streaming<pb::AxisUpdate>,
    mut f: impl FnMut(&Update) -> Option<T>,
) -> T {
    tokio::time::timeout(WAIT, async {
        loop {
            let u = stream.message().await.unwrap().expect("the stream goes on");
            if let Some(t) = u.update.as_ref().and_then(&mut f) {
                return t;
            }
        }
    })
    .await
    .expect("watched for too long")
}

async fn watch_axis(axes: &mut Axes, axis: &str) -> tonic::Streaming<pb::AxisUpdate> {
    axes.stream_axis_state(pb::StreamAxisStateRequest {
        axes: vec![axis.into()],
        changes_only: false,
    })
    .await
    .unwrap()
    .into_inner()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn signals_are_in_the_status_while_moving() {
    let (server, mut axes, lease) = setup().await;
    enable(&mut axes, "X", &lease).await;
    let s = status(&mut axes, "X").await;
    // At 0 mm: on the home switch, no limit switch; nothing latched.
    let inputs = s.digital_inputs.expect("0x60FD carried");
    assert!(inputs.home_switch && !inputs.positive_limit_switch && !inputs.negative_limit_switch);
    assert_eq!(inputs.raw, 0x4);
    assert_eq!(s.touch_probe_status, Some(0));
    assert_eq!(s.following_error_actual, Some(0.0));
    let mut stream = watch_axis(&mut axes, "X").await;
    axes.r#move(move_to("X", -30.0, &lease, false))
        .await
        .unwrap();
    // Moving: velocity, torque while accelerating, a following error.
    let (mut torque, mut lag, mut speed) = (false, false, false);
    let moving = watch(&mut stream, |u| match u {
        Update::Status(s) => {
            torque |= s.torque_actual.is_some_and(|t| t != 0);
            lag |= s.following_error_actual.is_some_and(|e| e.abs() > 0.0);
            speed |= s.velocity < -1.0;
            (torque && lag && speed).then(|| s.clone())
        }
        _ => None,
    })
    .await;
    assert!(
        moving.torque_actual.unwrap().abs() <= 2000,
        "bounded by max_torque: {moving:?}"
    );
    let done = wait_status(&mut axes, "X", |s| {
        s.activity == pb::AxisActivity::Idle as i32 && (s.position + 30.0).abs() < 0.01
    })
    .await;
    // Off the home switch now.
    assert_eq!(done.digital_inputs.unwrap().raw, 0);
    assert!(done.torque_actual.is_some(), "{done:?}");
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_limit_switch_stops_the_move_and_the_axis_backs_off() {
    let (server, mut axes, lease) = setup().await;
    enable(&mut axes, "X", &lease).await;
    let e = axes
        .r#move(move_to("X", 100.0, &lease, true))
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::Aborted, "{e:?}");
    assert!(
        e.message().contains("positive limit switch reached at 5"),
        "{e:?}"
    );
    let s = wait_status(&mut axes, "X", |s| {
        s.activity == pb::AxisActivity::Idle as i32 && s.velocity == 0.0
    })
    .await;
    assert!((50.0..60.0).contains(&s.position), "at the switch: {s:?}");
    assert_eq!(s.fault_text, "positive limit switch reached");
    assert_eq!(s.fault_code, 0);
    assert_eq!(s.state, pb::DriveState::OperationEnabled as i32);
    assert!(s.digital_inputs.unwrap().positive_limit_switch);
    // Further into it: refused, saying why.
    let e = axes
        .r#move(move_to("X", 120.0, &lease, false))
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::OutOfRange, "{e:?}");
    assert!(
        e.message().contains("positive limit switch is active"),
        "{e:?}"
    );
    // Away from it: the axis drives off the switch, and the fault clears.
    let r = axes
        .r#move(move_to("X", 10.0, &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    let s = status(&mut axes, "X").await;
    assert_eq!(s.fault_text, "");
    assert!(!s.digital_inputs.unwrap().positive_limit_switch);
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_touch_probe_latch_comes_as_an_event_with_the_position() {
    let (server, mut axes, lease) = setup().await;
    enable(&mut axes, "X", &lease).await;
    let arm = |lease: &str| pb::ArmTouchProbeRequest {
        axis: "X".into(),
        edge: pb::TouchProbeEdge::Rising as i32,
        continuous: false,
        options: opts(lease, false),
    };
    let e = axes.arm_touch_probe(arm("")).await.unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    // A drive whose process data does not carry the probe's status: a
    // latch would never be seen.
    wait_ready(&mut axes, &["Z"]).await;
    let z_lease = acquire(&mut axes, &["Z"], 10_000, "no probe").await;
    let e = axes
        .arm_touch_probe(pb::ArmTouchProbeRequest {
            axis: "Z".into(),
            ..arm(&z_lease)
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    assert!(e.message().contains("0x60B9"), "{e:?}");
    let z = status(&mut axes, "Z").await;
    assert!(
        z.digital_inputs.is_none()
            && z.torque_actual.is_none()
            && z.following_error_actual.is_none(),
        "not carried, absent: {z:?}"
    );
    let r = axes
        .arm_touch_probe(arm(&lease))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    assert!(r.detail.contains("0x60B8 = 0x0011"), "{r:?}");
    wait_status(&mut axes, "X", |s| s.touch_probe_status == Some(1)).await;
    let mut stream = watch_axis(&mut axes, "X").await;
    let r = axes
        .r#move(move_to("X", 30.0, &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    let latch = watch(&mut stream, |u| match u {
        Update::Event(pb::AxisEvent {
            kind: Some(pb::axis_event::Kind::TouchProbe(t)),
            ..
        }) => Some(*t),
        _ => None,
    })
    .await;
    assert_eq!(latch.probe, 1);
    assert_eq!(latch.edge, pb::TouchProbeEdge::Rising as i32);
    assert_eq!(latch.position, 20.0);
    wait_status(&mut axes, "X", |s| s.touch_probe_status == Some(3)).await;
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_following_error_fault_says_by_how_much() {
    let (server, mut axes, lease) = setup().await;
    enable(&mut axes, "Y", &lease).await;
    let mut stream = watch_axis(&mut axes, "Y").await;
    let e = axes
        .r#move(pb::MoveRequest {
            velocity: 100.0,
            acceleration: 1000.0,
            ..move_to("Y", 50.0, &lease, true)
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::Aborted, "{e:?}");
    let s = wait_status(&mut axes, "Y", |s| {
        s.fault_code == 0x8611 && s.fault_text.contains(" > ")
    })
    .await;
    assert!(
        s.fault_text
            .starts_with("following error beyond the window (")
            && s.fault_text.ends_with(" mm > 0.050 mm)"),
        "{s:?}"
    );
    let fault = watch(&mut stream, |u| match u {
        Update::Event(pb::AxisEvent {
            kind: Some(pb::axis_event::Kind::Fault(f)),
            ..
        }) if f.text.contains(" > ") => Some(f.clone()),
        _ => None,
    })
    .await;
    assert_eq!(fault.code, 0x8611);
    assert!(fault.active);
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_set_point_stream_into_a_limit_switch_ends_saying_so() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut axes: Axes = pb::axes_client::AxesClient::new(c.channel());
    wait_ready(&mut axes, &["X"]).await;
    let lease = c
        .acquire_control_as(&["X"], Duration::from_secs(5), "planner")
        .await
        .unwrap();
    enable(&mut axes, "X", lease.token()).await;
    let mut stream = c
        .stream_setpoints(
            &lease,
            &["X"],
            SetpointStreamOptions {
                depth: Duration::from_millis(50),
                extrapolate: Some(Duration::from_millis(50)),
                point_period: Some(Duration::from_millis(1)),
                status_period: Some(Duration::from_millis(10)),
            },
        )
        .await
        .unwrap();
    let sender = stream.sender().unwrap();
    // 30 mm/s from 0 on X (after a gentle start), towards 120 mm.
    let sending = tokio::spawn(async move {
        let start = std::time::Instant::now();
        for batch in (0..4000u64).collect::<Vec<_>>().chunks(10) {
            let due = Duration::from_millis(*batch.last().unwrap());
            if let Some(wait) = due.checked_sub(start.elapsed() + Duration::from_millis(300)) {
                tokio::time::sleep(wait).await;
            }
            let pts = batch
                .iter()
                .map(|&k| {
                    let s = k as f64 / 1000.0;
                    let x = if s < 0.1 {
                        150.0 * s * s
                    } else {
                        1.5 + 30.0 * (s - 0.1)
                    };
                    setpoint(k * 1000, vec![x])
                })
                .collect();
            if sender.send(pts).await.is_err() {
                return;
            }
        }
    });
    let mut seen = Vec::new();
    let end = tokio::time::timeout(Duration::from_secs(60), async {
        loop {
            match stream.status().await {
                Ok(Some(s)) => seen.push(s),
                Ok(None) => return Ok(()),
                Err(e) => return Err(e),
            }
        }
    })
    .await
    .expect("the stream ends");
    sending.abort();
    let err = end.expect_err("ended by the limit switch");
    assert_eq!(err.code(), Some(Code::Aborted), "{err:?}");
    let last = seen.last().unwrap();
    assert_eq!(
        last.ended,
        "LIMIT_SWITCH",
        "{last:?}\nX: {:?}",
        status(&mut axes, "X").await
    );
    assert!(err.to_string().contains("positive limit switch"), "{err}");
    // The signals came with the statuses.
    let carried = seen.iter().any(|s| {
        s.signals.len() == 1
            && s.signals[0].digital_inputs.is_some()
            && s.signals[0].torque_actual.is_some()
            && s.signals[0].velocity_actual.is_some()
    });
    assert!(carried, "{:?}", seen.first());
    let s = wait_status(&mut axes, "X", |s| {
        s.activity == pb::AxisActivity::Idle as i32 && s.velocity == 0.0
    })
    .await;
    assert!((50.0..60.0).contains(&s.position), "{s:?}");
    assert_eq!(s.fault_text, "positive limit switch reached");
    server.shutdown();
}

/// The demo's Y has a positive limit switch at 180 mm: a move beyond it
/// stops there, saying so, and Y moves back.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_demo_y_stops_at_its_limit_switch() {
    let mut config = cangate_server::Config::demo();
    config.listen = "127.0.0.1:0".parse().unwrap();
    let server = cangate_server::start(&config).await.expect("demo starts");
    let c = client(&server).await;
    let mut axes: Axes = pb::axes_client::AxesClient::new(c.channel());
    wait_ready(&mut axes, &["Y"]).await;
    let lease = acquire(&mut axes, &["Y"], 10_000, "demo limit switch").await;
    enable(&mut axes, "Y", &lease).await;
    let fast = |target: f64| pb::MoveRequest {
        velocity: 100.0,
        acceleration: 1000.0,
        ..move_to("Y", target, &lease, true)
    };
    let e = axes.r#move(fast(195.0)).await.unwrap_err();
    assert_eq!(e.code(), Code::Aborted, "{e:?}");
    assert!(
        e.message().contains("positive limit switch reached at 18"),
        "{e:?}"
    );
    let s = wait_status(&mut axes, "Y", |s| {
        s.activity == pb::AxisActivity::Idle as i32 && s.velocity == 0.0
    })
    .await;
    assert_eq!(s.fault_text, "positive limit switch reached", "{s:?}");
    let r = axes.r#move(fast(0.0)).await.unwrap().into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    assert!(
        status(&mut axes, "Y")
            .await
            .digital_inputs
            .unwrap()
            .home_switch
    );
    server.shutdown();
}
