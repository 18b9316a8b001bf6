//! `Axes.StreamSetpoints` end to end: the real server with two simulated
//! cyclic drives, the typed client's `SetpointStream`. Positions are
//! compared, never wall times: the client sends its points ahead of real
//! time (as a planner with a look-ahead does), so a loaded machine does
//! not starve the buffer.

use cangate_client::pb;
use cangate_client::{Client, setpoint};
use cangate_tests::axes::*;
use cangate_tests::streams::{events, read_until, send_path, stream_options};
use cangate_tests::*;
use std::time::{Duration, Instant};
use tonic::Code;

/// Two simulated cyclic drives, X and Y, on a 5 ms SYNC.
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
"#;

/// Bound of everything a test waits for.
const LONG: Duration = Duration::from_secs(60);

/// The server, a client, X and Y enabled under the client's lease.
async fn setup() -> (
    cangate_server::RunningServer,
    Client,
    Axes,
    cangate_client::ControlLease,
) {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut axes: Axes = pb::axes_client::AxesClient::new(c.channel());
    wait_ready(&mut axes, &["X", "Y"]).await;
    let lease = c
        .acquire_control_as(&["X", "Y"], Duration::from_secs(5), "planner")
        .await
        .unwrap();
    for a in ["X", "Y"] {
        axes.enable(cmd(a, lease.token(), true)).await.unwrap();
    }
    (server, c, axes, lease)
}

fn has_event(seen: &[pb::SetpointStreamStatus], kind: pb::SetpointEventKind) -> bool {
    events(seen).iter().any(|e| e.kind == kind as i32)
}

/// The drive's actual position and velocity of `axis`.
async fn actual(axes: &mut Axes, axis: &str) -> (f64, f64) {
    let s = axes
        .get_axis(pb::GetAxisRequest { axis: axis.into() })
        .await
        .unwrap()
        .into_inner()
        .status
        .unwrap();
    (s.position, s.velocity)
}

/// Waits until `axis` stands within 0.01 of `at`.
async fn wait_standing(axes: &mut Axes, axis: &str, at: f64) {
    let t0 = Instant::now();
    loop {
        let (p, v) = actual(axes, axis).await;
        if (p - at).abs() < 0.01 && v.abs() < 0.01 {
            return;
        }
        assert!(
            t0.elapsed() < LONG,
            "{axis} at {p} moving at {v}, expected to stand at {at}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// A circle of radius 10 on X/Y, one point per ms: the angular speed
/// ramps up over 0.5 s to one turn per second, holds for a turn, ramps
/// down over 0.5 s (3π in all): it ends at rest at (-20, 0).
fn circle(s: f64) -> Vec<f64> {
    let w = 2.0 * std::f64::consts::PI;
    let theta = if s < 0.5 {
        w * s * s
    } else if s < 1.5 {
        w * 0.25 + w * (s - 0.5)
    } else {
        let r = (2.0 - s).max(0.0);
        w * 1.25 + w * 0.25 - w * r * r
    };
    vec![-10.0 + 10.0 * theta.cos(), 10.0 * theta.sin()]
}

fn off_circle(p: &[f64]) -> f64 {
    ((p[0] + 10.0).hypot(p[1]) - 10.0).abs()
}

/// A circle streamed at 1 kHz arrives on the circle: every commanded
/// position reported lies within 0.2 mm of it, every actual one within
/// 1.5 mm (radius 10); the stream
/// ends when the client finishes, with the axes at rest at the circle's
/// end, every point accepted.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_streamed_circle_arrives_on_the_circle_and_ends_at_rest() {
    let (server, c, mut axes, lease) = setup().await;
    let mut stream = c
        .stream_setpoints(&lease, &["X", "Y"], stream_options())
        .await
        .unwrap();
    let sender = stream.sender().unwrap();
    let sending = send_path(sender, 0, 2001, Duration::from_millis(500), circle);
    sending.await.unwrap();
    stream.finish();
    let mut seen = Vec::new();
    let end = read_until(&mut stream, &mut seen, |_| false).await.unwrap();
    assert!(end.is_none(), "a finished stream ends OK");
    let last = seen.last().unwrap();
    assert_eq!(
        last.state,
        pb::SetpointStreamState::SetpointStreamEnded as i32
    );
    assert_eq!(last.ended, "CLIENT_ENDED");
    let counters = last.counters.unwrap();
    assert_eq!(counters.received, 2001, "{counters:?}");
    assert_eq!(counters.refused, 0, "{counters:?}");
    // Every point played to the end: none dropped by the ramp to rest.
    assert_eq!(counters.dropped, 0, "{counters:?}");
    let mut moved = 0;
    for s in &seen {
        assert!(
            off_circle(&s.commanded_positions) < 0.2,
            "commanded {:?} is off the circle",
            s.commanded_positions
        );
        // Each axis's actual position is its latest process data: on a
        // loaded machine one may be a SYNC or two older than the other
        // (0.3 mm of travel per 5 ms at full speed), hence the bound.
        if s.actual_positions.iter().all(|p| p.is_finite()) {
            assert!(
                off_circle(&s.actual_positions) < 1.5,
                "actual {:?} is off the circle",
                s.actual_positions
            );
        }
        if s.commanded_positions[1].abs() > 5.0 {
            moved += 1;
        }
    }
    assert!(moved > 0, "the statuses saw the circle");
    assert!(
        (last.commanded_positions[0] + 20.0).abs() < 1e-3,
        "{last:?}"
    );
    assert!(last.commanded_positions[1].abs() < 1e-3, "{last:?}");
    wait_standing(&mut axes, "X", -20.0).await;
    wait_standing(&mut axes, "Y", 0.0).await;
    server.shutdown();
}

/// A client that stops sending mid-motion gets UNDERRUN; the axes ramp to
/// rest; the stream resumes from where they stand; a client that then
/// cancels leaves them at rest.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_underrun_is_reported_brings_the_axes_to_rest_and_the_stream_resumes() {
    let (server, c, mut axes, lease) = setup().await;
    let mut stream = c
        .stream_setpoints(&lease, &["X", "Y"], stream_options())
        .await
        .unwrap();
    // Up to 20 mm/s on X at 200 mm/s², then nothing more.
    let ramp = |s: f64| {
        let x = if s < 0.1 {
            100.0 * s * s
        } else {
            1.0 + 20.0 * (s - 0.1)
        };
        vec![x, 0.0]
    };
    send_path(
        stream.sender().unwrap(),
        0,
        300,
        Duration::from_millis(500),
        ramp,
    )
    .await
    .unwrap();
    let mut seen = Vec::new();
    let rest = read_until(&mut stream, &mut seen, |s| {
        has_event(
            std::slice::from_ref(s),
            pb::SetpointEventKind::SetpointEventAtRest,
        )
    })
    .await
    .unwrap()
    .expect("the stream stays open after an underrun");
    assert!(has_event(
        &seen,
        pb::SetpointEventKind::SetpointEventUnderrun
    ));
    assert_eq!(rest.counters.unwrap().underruns, 1);
    // The axes went on past the last point (5.18) and stopped ahead.
    let x = rest.commanded_positions[0];
    assert!(x > 5.18, "{x}");
    wait_standing(&mut axes, "X", x).await;
    // Resumed where the axes stand: back to 0 gently, then finish.
    let back = move |s: f64| {
        let d = if s < 1.0 {
            x * (1.0 - (std::f64::consts::PI * s).cos()) / 2.0
        } else {
            x
        };
        vec![x - d, 0.0]
    };
    send_path(
        stream.sender().unwrap(),
        10_000_000,
        1001,
        Duration::from_millis(500),
        back,
    )
    .await
    .unwrap();
    stream.finish();
    let end = read_until(&mut stream, &mut seen, |_| false).await.unwrap();
    assert!(end.is_none());
    let last = seen.last().unwrap();
    assert_eq!(last.counters.unwrap().refused, 0, "{last:?}");
    assert!(last.commanded_positions[0].abs() < 1e-3, "{last:?}");
    wait_standing(&mut axes, "X", 0.0).await;
    server.shutdown();
}

/// Points that break a limit are refused with the reason and the axis,
/// never sent: the axes stay where they are.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_point_beyond_the_limits_is_refused_and_not_sent() {
    let (server, c, mut axes, lease) = setup().await;
    let mut stream = c
        .stream_setpoints(&lease, &["X", "Y"], stream_options())
        .await
        .unwrap();
    stream
        .send(vec![
            setpoint(0, vec![0.0, 0.0]),
            // 5 mm in 1 ms: 5000 mm/s.
            setpoint(1000, vec![5.0, 0.0]),
            setpoint(2000, vec![0.0, f64::NAN]),
            setpoint(3000, vec![0.0, 0.0]),
        ])
        .await
        .unwrap();
    let mut seen = Vec::new();
    read_until(&mut stream, &mut seen, |s| s.counters.unwrap().refused >= 2)
        .await
        .unwrap()
        .unwrap();
    let refused: Vec<_> = events(&seen)
        .into_iter()
        .filter(|e| e.kind == pb::SetpointEventKind::SetpointEventPointRefused as i32)
        .collect();
    assert_eq!(refused.len(), 2, "{refused:?}");
    assert_eq!(refused[0].reason, "TOO_FAST");
    assert_eq!(refused[0].axis, "X");
    assert_eq!(refused[0].t_us, 1000);
    assert!(
        refused[0].detail.contains("maximum velocity"),
        "{:?}",
        refused[0]
    );
    assert_eq!(refused[1].reason, "NOT_FINITE");
    assert_eq!(refused[1].axis, "Y");
    stream.finish();
    let end = read_until(&mut stream, &mut seen, |_| false).await.unwrap();
    assert!(end.is_none());
    for s in &seen {
        assert_eq!(s.commanded_positions, vec![0.0, 0.0], "{s:?}");
    }
    let (x, _) = actual(&mut axes, "X").await;
    assert!(x.abs() < 0.01, "X moved to {x}");
    server.shutdown();
}

/// Up to 20 mm/s on X at 200 mm/s², for 2 s.
fn line(s: f64) -> Vec<f64> {
    let x = if s < 0.1 {
        100.0 * s * s
    } else {
        1.0 + 20.0 * (s - 0.1)
    };
    vec![x, 0.0]
}

/// StopAxes of one axis during a stream (by another client, without a
/// lease) stops both axes and ends the stream with ABORTED, saying why;
/// other commands on a streamed axis are refused meanwhile.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stop_axes_during_a_stream_stops_the_axes_and_ends_the_stream() {
    let (server, c, mut axes, lease) = setup().await;
    let mut stream = c
        .stream_setpoints(&lease, &["X", "Y"], stream_options())
        .await
        .unwrap();
    let sending = send_path(
        stream.sender().unwrap(),
        0,
        2000,
        Duration::from_millis(500),
        line,
    );
    let mut seen = Vec::new();
    read_until(&mut stream, &mut seen, |s| s.commanded_positions[0] > 2.0)
        .await
        .unwrap()
        .unwrap();
    let status = axes
        .get_axis(pb::GetAxisRequest { axis: "X".into() })
        .await
        .unwrap()
        .into_inner()
        .status
        .unwrap();
    assert_eq!(
        status.activity,
        pb::AxisActivity::Moving as i32,
        "a streamed axis shows as moving: {status:?}"
    );
    let busy = axes
        .r#move(pb::MoveRequest {
            axis: "Y".into(),
            target: 1.0,
            relative: false,
            velocity: 0.0,
            acceleration: 0.0,
            options: opts(lease.token(), false),
        })
        .await
        .unwrap_err();
    assert_eq!(busy.code(), Code::FailedPrecondition, "{busy:?}");
    assert!(busy.message().contains("set-point stream"), "{busy:?}");

    let other = client(&server).await;
    let mut other: Axes = pb::axes_client::AxesClient::new(other.channel());
    let stopped = other
        .stop_axes(pb::StopAxesRequest {
            axes: vec!["Y".into()],
            quick: false,
            wait: true,
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(
        stopped.results[0].outcome,
        pb::Outcome::Completed as i32,
        "{stopped:?}"
    );
    let end = read_until(&mut stream, &mut seen, |_| false).await;
    let err = end.expect_err("a stopped stream ends with an error");
    assert_eq!(err.code(), Some(Code::Aborted), "{err:?}");
    assert!(err.to_string().contains("axis Y was stopped"), "{err}");
    let last = seen.last().unwrap();
    assert_eq!(last.ended, "STOPPED");
    sending.abort();
    let x = last.commanded_positions[0];
    assert!(x < 40.0, "stopped early, at {x}");
    wait_standing(&mut axes, "X", x).await;
    // At rest for good: no point moves it any more.
    tokio::time::sleep(Duration::from_millis(100)).await;
    let (x2, _) = actual(&mut axes, "X").await;
    assert!((x2 - x).abs() < 0.01, "{x2} after {x}");
    server.shutdown();
}

/// A lease released during a stream ends it with the axes at rest.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lost_lease_ends_the_stream_at_rest() {
    let (server, c, mut axes, lease) = setup().await;
    let mut stream = c
        .stream_setpoints(&lease, &["X", "Y"], stream_options())
        .await
        .unwrap();
    let sending = send_path(
        stream.sender().unwrap(),
        0,
        2000,
        Duration::from_millis(500),
        line,
    );
    let mut seen = Vec::new();
    read_until(&mut stream, &mut seen, |s| s.commanded_positions[0] > 2.0)
        .await
        .unwrap()
        .unwrap();
    lease.release().await.unwrap();
    let err = read_until(&mut stream, &mut seen, |_| false)
        .await
        .expect_err("a stream whose lease is gone ends with an error");
    assert_eq!(err.code(), Some(Code::Aborted), "{err:?}");
    let last = seen.last().unwrap();
    assert_eq!(last.ended, "LEASE_LOST", "{last:?}");
    sending.abort();
    wait_standing(&mut axes, "X", last.commanded_positions[0]).await;
    server.shutdown();
}

/// Opening is refused with a code and a message that say why.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn opening_is_refused_without_a_lease_or_with_bad_arguments() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut axes: Axes = pb::axes_client::AxesClient::new(c.channel());
    wait_ready(&mut axes, &["X", "Y"]).await;
    let open = |token: &str, names: &[&str], o| {
        let c = c.clone();
        let token = token.to_string();
        let names: Vec<String> = names.iter().map(|s| s.to_string()).collect();
        async move {
            let names: Vec<&str> = names.iter().map(String::as_str).collect();
            c.stream_setpoints_with_token(&token, &names, o)
                .await
                .err()
                .expect("refused")
        }
    };
    let e = open("", &["X"], stream_options()).await;
    assert_eq!(e.code(), Some(Code::FailedPrecondition), "{e:?}");
    assert_eq!(e.reason().as_deref(), Some("LEASE_REQUIRED"), "{e:?}");
    let e = open("", &["W"], stream_options()).await;
    assert_eq!(e.code(), Some(Code::NotFound), "{e:?}");
    let e = open("", &[], stream_options()).await;
    assert_eq!(e.code(), Some(Code::InvalidArgument), "{e:?}");
    let lease = c
        .acquire_control(&["X", "Y"], Duration::from_secs(5))
        .await
        .unwrap();
    let mut zero = stream_options();
    zero.depth = Duration::ZERO;
    let e = open(lease.token(), &["X"], zero).await;
    assert_eq!(e.code(), Some(Code::InvalidArgument), "{e:?}");
    let e = open(lease.token(), &["X", "X"], stream_options()).await;
    assert_eq!(e.code(), Some(Code::InvalidArgument), "{e:?}");
    // Not enabled yet.
    let e = open(lease.token(), &["X"], stream_options()).await;
    assert_eq!(e.code(), Some(Code::FailedPrecondition), "{e:?}");
    assert!(e.to_string().contains("not enabled"), "{e}");
    // Already in another stream.
    axes.enable(cmd("X", lease.token(), true)).await.unwrap();
    let _first = c
        .stream_setpoints(&lease, &["X"], stream_options())
        .await
        .unwrap();
    let e = open(lease.token(), &["X"], stream_options()).await;
    assert_eq!(e.code(), Some(Code::FailedPrecondition), "{e:?}");
    assert!(
        e.to_string().contains("already in a set-point stream"),
        "{e}"
    );
    server.shutdown();
}

/// A gateway shutting down during a stream stops the streamed axes first
/// (a streamed axis is in motion although no command of its own runs),
/// and waits until they are at rest.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_during_a_stream_brings_the_axes_to_rest_first() {
    let (server, c, _axes, lease) = setup().await;
    let mut stream = c
        .stream_setpoints(&lease, &["X", "Y"], stream_options())
        .await
        .unwrap();
    let sending = send_path(
        stream.sender().unwrap(),
        0,
        2000,
        Duration::from_millis(500),
        line,
    );
    let mut seen = Vec::new();
    read_until(&mut stream, &mut seen, |s| s.commanded_positions[0] > 2.0)
        .await
        .unwrap()
        .unwrap();
    let stops = server
        .gateway()
        .axes()
        .stop_for_shutdown(Duration::from_secs(10))
        .await;
    assert!(stops.not_at_rest.is_empty(), "{stops:?}");
    assert!(
        stops.lines.iter().any(|l| l.starts_with("X: completed")),
        "{stops:?}"
    );
    let err = read_until(&mut stream, &mut seen, |_| false)
        .await
        .expect_err("the stream ends with the stop");
    assert_eq!(err.code(), Some(Code::Aborted), "{err:?}");
    assert_eq!(seen.last().unwrap().ended, "STOPPED");
    sending.abort();
    server.shutdown();
}

/// A client that cancels its stream mid-motion (drops it) leaves the axes
/// at rest: they ramp down from where they are.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cancelled_stream_brings_the_axes_to_rest() {
    let (server, c, mut axes, lease) = setup().await;
    let mut stream = c
        .stream_setpoints(&lease, &["X", "Y"], stream_options())
        .await
        .unwrap();
    let sending = send_path(
        stream.sender().unwrap(),
        0,
        2000,
        Duration::from_millis(500),
        line,
    );
    let mut seen = Vec::new();
    read_until(&mut stream, &mut seen, |s| s.commanded_positions[0] > 2.0)
        .await
        .unwrap()
        .unwrap();
    sending.abort();
    drop(stream);
    // 20 mm/s at the stop deceleration stops within a few mm.
    let t0 = Instant::now();
    loop {
        let s = axes
            .get_axis(pb::GetAxisRequest { axis: "X".into() })
            .await
            .unwrap()
            .into_inner()
            .status
            .unwrap();
        if s.activity == pb::AxisActivity::Idle as i32 && s.velocity.abs() < 0.01 {
            assert!(s.position < 10.0, "stopped at {}", s.position);
            break;
        }
        assert!(t0.elapsed() < LONG, "X still moving: {s:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    // At rest for good.
    let (x, _) = actual(&mut axes, "X").await;
    wait_standing(&mut axes, "X", x).await;
    server.shutdown();
}
