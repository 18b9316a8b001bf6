//! The Axes service end to end: the real server on a virtual bus with
//! simulated CiA 402 drives, driven by the real client.

use cangate_client::pb;
use cangate_client::pb::axis_update::Update;
use cangate_tests::axes::*;
use cangate_tests::*;
use std::time::Duration;
use tonic::Code;

/// X, Y: cyclic; Z: profile; F: profile, a drive the test runs itself (to
/// inject faults and cut its heartbeat). SYNC every 5 ms.
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
heartbeat_timeout_ms = 300

[[canopen.node]]
id = 2
eds = "builtin:drive"
simulate = true
heartbeat_timeout_ms = 300

[[canopen.node]]
id = 4
eds = "builtin:drive"
simulate = true
heartbeat_timeout_ms = 300

[[canopen.node]]
id = 5
eds = "builtin:drive"
heartbeat_timeout_ms = 300

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
jog_deadman_ms = 5000

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

[[axis]]
name = "Z"
bus = "can0"
node = 4
counts_per_unit = 1000.0
display_decimals = 1
position_mode = "profile"
min_position = -100.0
max_position = 100.0
max_velocity = 50.0
max_acceleration = 500.0
homing_method = 19

[[axis]]
name = "F"
bus = "can0"
node = 5
counts_per_unit = 1000.0
min_position = -100.0
max_position = 100.0
max_velocity = 50.0
max_acceleration = 500.0
"#;

async fn setup() -> (cangate_server::RunningServer, Axes) {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut axes = c.axes_client();
    // Wait (bounded) until the drives' process data flows.
    let t0 = std::time::Instant::now();
    loop {
        let list = axes
            .list_axes(pb::ListAxesRequest {})
            .await
            .unwrap()
            .into_inner()
            .axes;
        let ready = list.iter().filter(|a| a.name != "F").all(|a| {
            a.status
                .as_ref()
                .is_some_and(|s| s.state != 0 && !s.node_lost)
        });
        if ready {
            break;
        }
        assert!(t0.elapsed() < WAIT, "axes did not come up: {list:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    (server, axes)
}

fn move_req(axis: &str, target: f64, lease: &str, wait: bool) -> pb::MoveRequest {
    pb::MoveRequest {
        axis: axis.into(),
        target,
        relative: false,
        velocity: 50.0,
        acceleration: 500.0,
        options: opts(lease, wait),
    }
}

/// A frame stream of `can0` with the gateway's own frames included,
/// passing exactly the standard identifiers `ids`.
async fn exact_ids_with_transmitted(
    c: &mut cangate_client::Client,
    ids: &[u32],
) -> (
    tonic::Streaming<pb::StreamFramesResponse>,
    Vec<pb::StreamEvent>,
) {
    let filters = ids
        .iter()
        .map(|&id| pb::FrameFilter {
            id,
            mask: 0x7FF,
            format: 0,
            invert: false,
        })
        .collect();
    open_stream(
        c,
        pb::StreamFramesRequest {
            include_transmitted: true,
            ..stream_request("can0", filters)
        },
    )
    .await
}

/// Coordinated-move targets at each axis's default velocity and
/// acceleration.
fn at_default_limits(targets: &[(&str, f64)]) -> Vec<pb::AxisTarget> {
    targets
        .iter()
        .map(|&(axis, target)| pb::AxisTarget {
            axis: axis.into(),
            target,
            velocity: 0.0,
            acceleration: 0.0,
        })
        .collect()
}

async fn status_stream(axes: &mut Axes, names: &[&str]) -> tonic::Streaming<pb::AxisUpdate> {
    axes.stream_axis_state(pb::StreamAxisStateRequest {
        axes: names.iter().map(|s| s.to_string()).collect(),
        changes_only: false,
    })
    .await
    .unwrap()
    .into_inner()
}

/// Reads the stream until `f` matches (bounded).
async fn until<T>(
    s: &mut tonic::Streaming<pb::AxisUpdate>,
    mut f: impl FnMut(&pb::AxisUpdate) -> Option<T>,
) -> T {
    tokio::time::timeout(WAIT, async {
        loop {
            let u = s.message().await.unwrap().expect("stream open");
            if let Some(t) = f(&u) {
                return t;
            }
        }
    })
    .await
    .expect("the awaited update arrives")
}

/// ListAxes tells an HMI how many decimals to show: Z's configured 1, the
/// others one count of their 1000 per mm.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn each_axis_says_how_many_decimals_to_show() {
    let (_server, mut axes) = setup().await;
    let list = axes
        .list_axes(pb::ListAxesRequest {})
        .await
        .unwrap()
        .into_inner()
        .axes;
    let decimals: Vec<(String, u32)> = list
        .iter()
        .map(|a| (a.name.clone(), a.display_decimals))
        .collect();
    for (name, d) in &decimals {
        assert_eq!(*d, if name == "Z" { 1 } else { 3 }, "{decimals:?}");
    }
}

/// The lease outlives the waited homing and move however slow the host
/// (a lapsed lease would stop the axis, as it should).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn enable_home_move_reaches_the_target_on_the_stream() {
    let (_server, mut axes) = setup().await;
    let mut stream = status_stream(&mut axes, &["X"]).await;
    let lease = acquire(&mut axes, &["X"], 30_000, "test").await;
    enable(&mut axes, "X", &lease).await;
    let r = axes
        .home(cmd("X", &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    assert!(r.status.unwrap().homed);
    let r = axes
        .r#move(move_req("X", 12.5, &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    // "target reached at 12.497 mm": within the in-position window.
    let at: f64 = r
        .detail
        .trim_start_matches("target reached at ")
        .trim_end_matches(" mm")
        .parse()
        .unwrap_or_else(|_| panic!("{}", r.detail));
    assert!((at - 12.5).abs() <= 0.010, "{}", r.detail);
    // The status stream shows the position getting there.
    let p = until(&mut stream, |u| match &u.update {
        Some(Update::Status(s)) if (s.position - 12.5).abs() < 0.011 => Some(s.position),
        _ => None,
    })
    .await;
    assert!((p - 12.5).abs() < 0.011);
    let a = axes
        .get_axis(pb::GetAxisRequest { axis: "X".into() })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(a.unit, "mm");
    assert_eq!(a.position_mode, pb::PositionMode::Cyclic as i32);
    let st = a.status.unwrap();
    assert!(st.homed);
    assert!(
        st.controlled_by.starts_with("test ("),
        "{}",
        st.controlled_by
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn profile_move_uses_the_set_point_handshake_on_the_wire() {
    let (server, mut axes) = setup().await;
    let mut c = client(&server).await;
    let lease = acquire(&mut axes, &["Z"], 30_000, "test").await;
    enable(&mut axes, "Z", &lease).await;
    // Homing method 19 runs to the reference switch.
    let r = axes
        .home(cmd("Z", &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    let (mut frames, mut pending) = open_stream(
        &mut c,
        pb::StreamFramesRequest {
            include_transmitted: true,
            ..stream_request(
                "can0",
                vec![
                    pb::FrameFilter {
                        id: 0x204,
                        mask: 0x7FF,
                        format: 0,
                        invert: false,
                    },
                    pb::FrameFilter {
                        id: 0x304,
                        mask: 0x7FF,
                        format: 0,
                        invert: false,
                    },
                ],
            )
        },
    )
    .await;
    let r = axes
        .r#move(move_req("Z", 2.0, &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    let got: Vec<(u32, Vec<u8>)> = read_frames(&mut frames, &mut pending, 4)
        .await
        .iter()
        .take(4)
        .map(|f| (f.id, f.data.clone()))
        .collect();
    // 0x6081/0x6083/0x6084 went by SDO first; then the target (2000
    // counts) before the controlword with new set-point + change set
    // immediately (0x3F, mode 1), and bit 4 cleared after the acknowledge.
    assert_eq!(
        got,
        vec![
            (0x304, vec![0xD0, 0x07, 0, 0, 0, 0, 0, 0]),
            (0x204, vec![0x3F, 0x00, 0x01]),
            (0x304, vec![0xD0, 0x07, 0, 0, 0, 0, 0, 0]),
            (0x204, vec![0x2F, 0x00, 0x01]),
        ]
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn soft_limits_and_bad_values_are_refused_with_clear_codes() {
    let (_server, mut axes) = setup().await;
    let lease = acquire(&mut axes, &["X"], 2000, "test").await;
    // Not enabled yet.
    let e = axes
        .r#move(move_req("X", 1.0, &lease, false))
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    assert!(e.message().contains("call Enable"), "{}", e.message());
    enable(&mut axes, "X", &lease).await;
    let e = axes
        .r#move(move_req("X", 250.0, &lease, false))
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::OutOfRange);
    assert!(
        e.message().contains("max_position = 200 mm"),
        "{}",
        e.message()
    );
    let mut m = move_req("X", 1.0, &lease, false);
    m.velocity = 1000.0;
    let e = axes.r#move(m).await.unwrap_err();
    assert_eq!(e.code(), Code::OutOfRange, "{e:?}");
    let mut m = move_req("X", 1.0, &lease, false);
    m.velocity = -1.0;
    let e = axes.r#move(m).await.unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e:?}");
    let e = axes
        .r#move(move_req("nope", 1.0, &lease, false))
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::NotFound);
    assert!(e.message().contains("axes: X, Y, Z, F"), "{}", e.message());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn control_is_exclusive_and_names_the_holder() {
    let (server, mut a) = setup().await;
    let mut b = client(&server).await.axes_client();
    let lease = acquire(&mut a, &["X", "Y"], 2000, "hmi-a").await;
    let e = b
        .acquire_control(pb::AcquireControlRequest {
            axes: vec!["Y".into()],
            ttl_ms: 1000,
            client_name: "hmi-b".into(),
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition);
    assert!(
        e.message().contains("controlled by hmi-a ("),
        "{}",
        e.message()
    );
    // Commands without the lease, or with a foreign one, are refused.
    let e = b.enable(cmd("X", "", false)).await.unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition);
    assert!(e.message().contains("hmi-a"), "{}", e.message());
    let e = b.enable(cmd("Z", "", false)).await.unwrap_err();
    assert!(e.message().contains("AcquireControl"), "{}", e.message());
    // Anyone may stop.
    let r = b.stop(cmd("X", "", true)).await.unwrap().into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    // After release, b gets it.
    let released = a
        .release_control(pb::ReleaseControlRequest {
            lease: lease.clone(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(released.axes, vec!["X", "Y"]);
    acquire(&mut b, &["Y"], 1000, "hmi-b").await;
    let e = a
        .renew_control(pb::RenewControlRequest { lease })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lapsed_lease_stops_a_jogging_axis_within_the_ttl() {
    let (server, mut axes) = setup().await;
    let mut watcher = client(&server).await.axes_client();
    let mut stream = status_stream(&mut watcher, &["X"]).await;
    let lease = {
        // A client that jogs and then vanishes without releasing.
        let mut gone = client(&server).await.axes_client();
        let lease = acquire(&mut gone, &["X"], 300, "crashing-hmi").await;
        enable(&mut gone, "X", &lease).await;
        let r = gone
            .jog(pb::JogRequest {
                axis: "X".into(),
                velocity: 20.0,
                acceleration: 0.0,
                options: opts(&lease, false),
            })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(r.outcome, pb::Outcome::Accepted as i32);
        lease
    };
    let t0 = std::time::Instant::now();
    // The lease lapses (300 ms TTL; the jog's own dead-man is 5 s here)…
    let reason = until(&mut stream, |u| match &u.update {
        Some(Update::Event(pb::AxisEvent {
            kind: Some(pb::axis_event::Kind::Control(c)),
            ..
        })) if c.previous.starts_with("crashing-hmi") => Some(c.reason.clone()),
        _ => None,
    })
    .await;
    assert!(reason.contains("lapsed"), "{reason}");
    // …and the jog ends stopped, then the axis is at rest.
    let done = until(&mut stream, |u| match &u.update {
        Some(Update::Event(pb::AxisEvent {
            kind: Some(pb::axis_event::Kind::MotionDone(d)),
            ..
        })) if d.command == "jog" => Some(d.clone()),
        _ => None,
    })
    .await;
    assert_eq!(done.outcome, pb::Outcome::Stopped as i32, "{done:?}");
    let elapsed = t0.elapsed();
    assert!(elapsed < Duration::from_secs(3), "{elapsed:?}");
    until(&mut stream, |u| match &u.update {
        Some(Update::Status(s))
            if s.activity == pb::AxisActivity::Idle as i32 && s.velocity == 0.0 =>
        {
            Some(())
        }
        _ => None,
    })
    .await;
    // The token is dead.
    let e = axes
        .renew_control(pb::RenewControlRequest { lease })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn synchronised_quick_stop_goes_out_in_one_sync_period() {
    let (server, mut axes) = setup().await;
    let mut c = client(&server).await;
    let lease = acquire(&mut axes, &["X", "Y"], 5000, "test").await;
    for a in ["X", "Y"] {
        enable(&mut axes, a, &lease).await;
        axes.jog(pb::JogRequest {
            axis: a.into(),
            velocity: 20.0,
            acceleration: 0.0,
            options: opts(&lease, false),
        })
        .await
        .unwrap();
    }
    tokio::time::sleep(Duration::from_millis(100)).await;
    let (mut frames, mut pending) =
        exact_ids_with_transmitted(&mut c, &[0x080, 0x201, 0x202]).await;
    let r = axes
        .stop_axes(pb::StopAxesRequest {
            axes: vec!["X".into(), "Y".into()],
            quick: true,
            wait: true,
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.results.len(), 2);
    for res in &r.results {
        assert_eq!(res.outcome, pb::Outcome::Completed as i32, "{res:?}");
    }
    // The first quick-stop controlword of each drive, and the SYNCs.
    let mut seen = Vec::new();
    let mut qs = [None, None];
    let t0 = std::time::Instant::now();
    while qs.iter().any(Option::is_none) {
        assert!(t0.elapsed() < WAIT);
        for f in read_frames(&mut frames, &mut pending, 1).await {
            seen.push(f.id);
            if f.id == 0x201 || f.id == 0x202 {
                let cw = u16::from_le_bytes([f.data[0], f.data[1]]);
                if cw & 0x0087 == 0x0002 {
                    let k = (f.id - 0x201) as usize;
                    qs[k].get_or_insert(seen.len() - 1);
                }
            }
        }
    }
    let (a, b) = (qs[0].unwrap(), qs[1].unwrap());
    let (lo, hi) = (a.min(b), a.max(b));
    assert!(
        !seen[lo..=hi].contains(&0x080),
        "a SYNC between the two quick stops: {seen:03X?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn coordinated_move_arrives_together() {
    let (_server, mut axes) = setup().await;
    let lease = acquire(&mut axes, &["X", "Y"], 5000, "test").await;
    enable(&mut axes, "X", &lease).await;
    enable(&mut axes, "Y", &lease).await;
    let t0 = std::time::Instant::now();
    let r = axes
        .move_axes(pb::MoveAxesRequest {
            targets: at_default_limits(&[("X", 30.0), ("Y", -5.0)]),
            lease: lease.clone(),
            wait: true,
        })
        .await
        .unwrap()
        .into_inner();
    assert!(t0.elapsed() < WAIT);
    for res in &r.results {
        assert_eq!(res.outcome, pb::Outcome::Completed as i32, "{res:?}");
    }
    let x = r.results[0].status.clone().unwrap();
    let y = r.results[1].status.clone().unwrap();
    assert!((x.position - 30.0).abs() < 0.011, "{x:?}");
    assert!((y.position + 5.0).abs() < 0.011, "{y:?}");
    // A profile axis cannot take part.
    let e = axes
        .move_axes(pb::MoveAxesRequest {
            targets: vec![pb::AxisTarget {
                axis: "Z".into(),
                target: 1.0,
                velocity: 0.0,
                acceleration: 0.0,
            }],
            lease,
            wait: false,
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
}

/// The cyclic set-points leave with the SYNC (sent by the master's SYNC
/// thread): during a coordinated move of X and Y, every SYNC period carries
/// exactly one set-point RPDO (RPDO2: 0x301, 0x302) per axis, the SYNC
/// first; the set-points climb the trapezoid within the axis limits; and
/// at rest the SYNCs keep carrying the target.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cyclic_set_points_ride_every_sync_one_per_axis() {
    let (server, mut axes) = setup().await;
    let mut c = client(&server).await;
    let lease = acquire(&mut axes, &["X", "Y"], 5000, "test").await;
    enable(&mut axes, "X", &lease).await;
    enable(&mut axes, "Y", &lease).await;
    let (mut frames, mut pending) =
        exact_ids_with_transmitted(&mut c, &[0x080, 0x301, 0x302]).await;
    let r = axes
        .move_axes(pb::MoveAxesRequest {
            targets: at_default_limits(&[("X", 20.0), ("Y", -4.0)]),
            lease,
            wait: true,
        })
        .await
        .unwrap()
        .into_inner();
    for res in &r.results {
        assert_eq!(res.outcome, pb::Outcome::Completed as i32, "{res:?}");
    }
    // The stream from before the move to a few periods at rest after it
    // (at 5 ms per SYNC, 3 frames a period; the move takes 0.3 s).
    let mut seen = Vec::new();
    let mut at_rest = 0;
    while at_rest < 5 * 3 {
        assert!(seen.len() < 3 * 1000, "X never held its target");
        let f = read_frames(&mut frames, &mut pending, 1).await;
        let arrived = |f: &pb::Frame| f.id == 0x301 && f.data[..4] == 20_000i32.to_le_bytes();
        if at_rest > 0 || f.iter().any(arrived) {
            at_rest += f.len();
        }
        seen.extend(f);
    }
    let first_sync = seen.iter().position(|f| f.id == 0x080).expect("a SYNC");
    let mut periods: Vec<Vec<(u32, i32)>> = Vec::new();
    for f in &seen[first_sync..] {
        if f.id == 0x080 {
            periods.push(Vec::new());
        } else {
            let target = i32::from_le_bytes([f.data[0], f.data[1], f.data[2], f.data[3]]);
            periods.last_mut().unwrap().push((f.id, target));
        }
    }
    // The last period may still be on its way.
    periods.pop();
    assert!(periods.len() >= 60, "{} periods", periods.len());
    for (k, p) in periods.iter().enumerate() {
        let mut ids: Vec<u32> = p.iter().map(|(id, _)| *id).collect();
        ids.sort_unstable();
        assert_eq!(ids, [0x301, 0x302], "period {k}: {p:?}");
    }
    let x: Vec<i32> = periods
        .iter()
        .map(|p| p.iter().find(|(id, _)| *id == 0x301).unwrap().1)
        .collect();
    // 100 mm/s at 1000 counts/mm: at most 500 counts per 5 ms period. A
    // SYNC the thread sent late (a loaded CI machine) samples later and
    // makes a longer step: the bound holds for nearly all periods.
    let steps: Vec<i32> = x.windows(2).map(|w| w[1] - w[0]).collect();
    assert!(steps.iter().all(|s| (0..=2500).contains(s)), "{steps:?}");
    let within = steps.iter().filter(|s| **s <= 501).count();
    assert!(within * 10 >= steps.len() * 9, "{steps:?}");
    assert!(steps.iter().filter(|s| **s > 0).count() >= 30, "{steps:?}");
    assert_eq!(*x.last().unwrap(), 20_000, "X holds its target at rest");
    let y_last = periods
        .last()
        .unwrap()
        .iter()
        .find(|(id, _)| *id == 0x302)
        .unwrap()
        .1;
    assert_eq!(y_last, -4_000, "Y holds its target at rest");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fault_then_reset_then_enable_again() {
    let (server, mut axes) = setup().await;
    let (drive, _cancel) = run_drive(&server, 5, Some(100));
    wait_status(&mut axes, "F", |s| s.state != 0 && !s.node_lost).await;
    let mut stream = status_stream(&mut axes, &["F"]).await;
    let lease = acquire(&mut axes, &["F"], 5000, "test").await;
    enable(&mut axes, "F", &lease).await;
    axes.r#move(move_req("F", 50.0, &lease, false))
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    drive.send_with(|d| d.inject_fault(0x2310));
    let fault = until(&mut stream, |u| match &u.update {
        Some(Update::Event(pb::AxisEvent {
            kind: Some(pb::axis_event::Kind::Fault(f)),
            ..
        })) if f.code == 0x2310 => Some(f.clone()),
        _ => None,
    })
    .await;
    assert_eq!(fault.text, "continuous over-current");
    assert!(fault.active, "{fault:?}");
    let s = wait_status(&mut axes, "F", |s| s.state == pb::DriveState::Fault as i32).await;
    assert_eq!(s.fault_code, 0x2310);
    let e = axes.enable(cmd("F", &lease, true)).await.unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition);
    assert!(e.message().contains("ResetFault"), "{}", e.message());
    let reset_at_us = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_micros() as u64;
    let r = axes
        .reset_fault(cmd("F", &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    // The clearing is a fault event too, no longer active, and only after
    // the reset: every fault event before it says active.
    let (cleared, at) = until(&mut stream, |u| match &u.update {
        Some(Update::Event(pb::AxisEvent {
            kind: Some(pb::axis_event::Kind::Fault(f)),
            timestamp_us,
            ..
        })) => {
            assert!(
                f.active || *timestamp_us >= reset_at_us,
                "fault cleared before the reset: {f:?}"
            );
            (!f.active).then(|| (f.clone(), *timestamp_us))
        }
        _ => None,
    })
    .await;
    assert_eq!(
        (cleared.code, cleared.text.as_str()),
        (0, ""),
        "{cleared:?}"
    );
    assert!(at >= reset_at_us, "{at} < {reset_at_us}");
    enable(&mut axes, "F", &lease).await;
    let s = wait_status(&mut axes, "F", |s| s.fault_code == 0).await;
    assert_eq!(s.fault_text, "");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn heartbeat_loss_faults_the_axis_until_the_node_is_back() {
    let (server, mut axes) = setup().await;
    let (_drive, cancel) = run_drive(&server, 5, Some(100));
    wait_status(&mut axes, "F", |s| s.state != 0 && !s.node_lost).await;
    let lease = acquire(&mut axes, &["F"], 10_000, "test").await;
    enable(&mut axes, "F", &lease).await;
    cancel.cancel();
    let s = wait_status(&mut axes, "F", |s| s.node_lost).await;
    assert!(s.fault_text.starts_with("node lost: no heartbeat"), "{s:?}");
    let e = axes.enable(cmd("F", &lease, false)).await.unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition);
    assert!(e.message().contains("node is lost"), "{}", e.message());
    // The drive comes back (power cycle): boot-up, boot procedure, usable.
    let (_drive, _cancel) = run_drive(&server, 5, Some(100));
    wait_status(&mut axes, "F", |s| !s.node_lost && s.state != 0).await;
    enable(&mut axes, "F", &lease).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_stops_a_jogging_axis_and_refuses_new_commands() {
    let (server, mut axes) = setup().await;
    let (drive, _cancel) = run_drive(&server, 5, Some(100));
    wait_status(&mut axes, "F", |s| s.state != 0 && !s.node_lost).await;
    let lease = acquire(&mut axes, &["F"], 10_000, "test").await;
    enable(&mut axes, "F", &lease).await;
    axes.jog(pb::JogRequest {
        axis: "F".into(),
        velocity: 20.0,
        acceleration: 0.0,
        options: opts(&lease, false),
    })
    .await
    .unwrap();
    wait_status(&mut axes, "F", |s| s.velocity > 10.0).await;
    // What SIGTERM does (main.rs), first step: stop the motion.
    let report = server
        .gateway()
        .axes()
        .stop_for_shutdown(Duration::from_secs(5))
        .await;
    assert_eq!(report.lines.len(), 1, "{report:?}");
    assert!(report.lines[0].starts_with("F: completed"), "{report:?}");
    assert!(report.not_at_rest.is_empty(), "{report:?}");
    assert!(drive.with(|d| d.velocity()).abs() < 1.0);
    // New commands are refused from now on.
    let e = axes.enable(cmd("F", &lease, false)).await.unwrap_err();
    assert_eq!(e.code(), Code::Unavailable, "{e:?}");
    let e = axes
        .acquire_control(pb::AcquireControlRequest {
            axes: vec!["X".into()],
            ttl_ms: 1000,
            client_name: "late".into(),
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::Unavailable);
    server.shutdown_safely(Duration::from_secs(1)).await;
    server.wait(Duration::from_secs(10)).await.unwrap();
}
