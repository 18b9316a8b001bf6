//! `Axes.StreamSetpoints` on CANsmc axes end to end: the real server with
//! a CANsmc master and two simulated servo slaves behind axes A and B
//! (4 ms cycle), the typed client's `SetpointStream`. The points play in
//! the master's cycle thread. Positions are compared, never wall times:
//! the client sends its points ahead of real time (a planner with a
//! look-ahead), so a loaded machine does not starve the buffer.

use cangate_client::Client;
use cangate_client::pb;
use cangate_tests::axes::*;
use cangate_tests::streams::{read_until, send_path, stream_options};
use cangate_tests::*;
use std::time::{Duration, Instant};
use tonic::Code;

/// A CANsmc master (demo timing) with two simulated servos, A and B.
const SMC: &str = r#"
[[bus]]
name = "smc0"
backend = "virtual"
bitrate = 1000000
bit_timing = true
rx_coalesce_us = 1000

[[bus]]
name = "smc1"
backend = "virtual"
bitrate = 1000000
bit_timing = true
rx_coalesce_us = 1000

[[cansmc]]
name = "smc"
command_bus = "smc0"
status_bus = "smc1"
cycle_time_us = 4000
lost_after = 50
handover_grace_ms = 56

[[cansmc.slave]]
address = 1
name = "A servo"
simulate = true

[[cansmc.slave]]
address = 2
name = "B servo"
simulate = true

[[cansmc.axis]]
name = "A"
address = 1
counts_per_unit = 10000.0
min_position = -100.0
max_position = 100.0
max_velocity = 20.0
max_acceleration = 200.0

[[cansmc.axis]]
name = "B"
address = 2
counts_per_unit = 10000.0
min_position = -100.0
max_position = 100.0
max_velocity = 20.0
max_acceleration = 200.0
"#;

/// A CiA 402 cyclic axis X beside the CANsmc axes.
const CIA402: &str = r#"
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
"#;

/// Bound of everything a test waits for.
const LONG: Duration = Duration::from_secs(60);

/// The server, a client, A and B enabled under the client's lease.
async fn setup() -> (
    cangate_server::RunningServer,
    Client,
    Axes,
    cangate_client::ControlLease,
) {
    let server = start_server(SMC).await;
    let c = client(&server).await;
    let mut axes: Axes = pb::axes_client::AxesClient::new(c.channel());
    wait_ready(&mut axes, &["A", "B"]).await;
    let lease = c
        .acquire_control_as(&["A", "B"], Duration::from_secs(5), "planner")
        .await
        .unwrap();
    for a in ["A", "B"] {
        axes.enable(cmd(a, lease.token(), true)).await.unwrap();
    }
    (server, c, axes, lease)
}

/// The actual position, velocity and activity of `axis`.
async fn state(axes: &mut Axes, axis: &str) -> (f64, f64, i32) {
    let s = axes
        .get_axis(pb::GetAxisRequest { axis: axis.into() })
        .await
        .unwrap()
        .into_inner()
        .status
        .unwrap();
    (s.position, s.velocity, s.activity)
}

/// Waits until `axis` stands idle within 0.01 of `at` (any place when
/// `None`); where it stands.
async fn wait_standing(axes: &mut Axes, axis: &str, at: Option<f64>) -> f64 {
    let t0 = Instant::now();
    loop {
        let (p, v, activity) = state(axes, axis).await;
        if at.is_none_or(|a| (p - a).abs() < 0.01)
            && v.abs() < 0.01
            && activity == pb::AxisActivity::Idle as i32
        {
            return p;
        }
        assert!(
            t0.elapsed() < LONG,
            "{axis} at {p} moving at {v} ({activity}), expected to stand at {at:?}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// A circle of radius 2 on A/B, one point per ms: the angular speed ramps
/// up over 0.5 s to one turn per second, holds for a turn, ramps down over
/// 0.5 s: it ends at rest at (-4, 0). At most 12.6 mm/s and 80 mm/s².
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
    vec![-2.0 + 2.0 * theta.cos(), 2.0 * theta.sin()]
}

fn off_circle(p: &[f64]) -> f64 {
    ((p[0] + 2.0).hypot(p[1]) - 2.0).abs()
}

/// Up to 20 mm/s on A at 200 mm/s², for 2 s.
fn line(s: f64) -> Vec<f64> {
    let x = if s < 0.1 {
        100.0 * s * s
    } else {
        1.0 + 20.0 * (s - 0.1)
    };
    vec![x, 0.0]
}

/// A circle streamed at 1 kHz to two CANsmc axes arrives on the circle:
/// every commanded position reported lies within 0.05 mm of it (radius 2),
/// every actual one within 0.5 mm; the stream ends when the client
/// finishes, with the axes at rest at the circle's end.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_streamed_circle_on_cansmc_axes_arrives_on_the_circle_and_ends_at_rest() {
    let (server, c, mut axes, lease) = setup().await;
    let mut stream = c
        .stream_setpoints(&lease, &["A", "B"], stream_options())
        .await
        .unwrap();
    let sending = send_path(
        stream.sender().unwrap(),
        0,
        2001,
        Duration::from_millis(500),
        circle,
    );
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
    assert_eq!(counters.dropped, 0, "{counters:?}");
    let mut moved = 0;
    for s in &seen {
        assert!(
            off_circle(&s.commanded_positions) < 0.05,
            "commanded {:?} is off the circle",
            s.commanded_positions
        );
        // Each axis's actual position is its latest published state
        // (every 10 ms): one may be a cycle or two older than the other.
        if s.actual_positions.iter().all(|p| p.is_finite()) {
            assert!(
                off_circle(&s.actual_positions) < 0.5,
                "actual {:?} is off the circle",
                s.actual_positions
            );
        }
        if s.commanded_positions[1].abs() > 1.0 {
            moved += 1;
        }
    }
    assert!(moved > 0, "the statuses saw the circle");
    assert!((last.commanded_positions[0] + 4.0).abs() < 1e-3, "{last:?}");
    assert!(last.commanded_positions[1].abs() < 1e-3, "{last:?}");
    wait_standing(&mut axes, "A", Some(-4.0)).await;
    wait_standing(&mut axes, "B", Some(0.0)).await;
    server.shutdown();
}

/// StopAxes of one CANsmc axis during a stream (by another client,
/// without a lease) stops both axes and ends the stream with ABORTED,
/// saying why; other commands on a streamed axis are refused meanwhile.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stop_axes_during_a_cansmc_stream_stops_the_axes_and_ends_the_stream() {
    let (server, c, mut axes, lease) = setup().await;
    let mut stream = c
        .stream_setpoints(&lease, &["A", "B"], stream_options())
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
    let (_, _, activity) = state(&mut axes, "A").await;
    assert_eq!(
        activity,
        pb::AxisActivity::Moving as i32,
        "a streamed axis shows as moving"
    );
    let busy = axes
        .r#move(pb::MoveRequest {
            axis: "B".into(),
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
            axes: vec!["B".into()],
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
    assert!(err.to_string().contains("axis B was stopped"), "{err}");
    let last = seen.last().unwrap();
    assert_eq!(last.ended, "STOPPED");
    sending.abort();
    let x = last.commanded_positions[0];
    assert!(x < 40.0, "stopped early, at {x}");
    wait_standing(&mut axes, "A", Some(x)).await;
    // The axes take commands again.
    let moved = axes
        .r#move(pb::MoveRequest {
            axis: "B".into(),
            target: 0.5,
            relative: false,
            velocity: 0.0,
            acceleration: 0.0,
            options: opts(lease.token(), true),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(moved.outcome, pb::Outcome::Completed as i32, "{moved:?}");
    server.shutdown();
}

/// A client that cancels its stream mid-motion (drops it) leaves the
/// CANsmc axes at rest: they ramp down from where they are.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cancelled_cansmc_stream_brings_the_axes_to_rest() {
    let (server, c, mut axes, lease) = setup().await;
    let mut stream = c
        .stream_setpoints(&lease, &["A", "B"], stream_options())
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
    let x = wait_standing(&mut axes, "A", None).await;
    assert!(x > 2.0 && x < 10.0, "stopped at {x}");
    server.shutdown();
}

/// A stream over a CANsmc axis and a CiA 402 axis is refused, saying why.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stream_mixing_cansmc_and_cia402_axes_is_refused() {
    let server = start_server(&format!("{SMC}\n{CIA402}")).await;
    let c = client(&server).await;
    let mut axes: Axes = pb::axes_client::AxesClient::new(c.channel());
    wait_ready(&mut axes, &["A"]).await;
    let lease = c
        .acquire_control(&["A", "X"], Duration::from_secs(5))
        .await
        .unwrap();
    let e = c
        .stream_setpoints(&lease, &["A", "X"], stream_options())
        .await
        .err()
        .expect("refused");
    assert_eq!(e.code(), Some(Code::FailedPrecondition), "{e:?}");
    let text = e.to_string();
    assert!(
        text.contains("CANsmc axis of master smc") && text.contains("CiA 402 axis on bus can0"),
        "{text}"
    );
    server.shutdown();
}
