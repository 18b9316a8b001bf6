//! Set-point streams of velocities on the embedded demo's spindle S (node
//! 5, cyclic synchronous velocity): each SYNC's velocity goes to 0x60FF,
//! every point and step inside S's velocity and acceleration limits, and
//! every end of the stream ramps S's velocity to 0. The client sends
//! ahead of real time (a look-ahead), so a loaded machine does not starve
//! the buffer.

use cangate_client::pb;
use cangate_client::{SetpointSender, setpoint, velocity_setpoint};
use cangate_tests::axes::*;
use cangate_tests::streams::{events, read_until, refusals, send_points, stream_options};
use cangate_tests::*;
use std::time::{Duration, Instant};
use tonic::Code;

/// Bound of everything a test waits for.
const LONG: Duration = Duration::from_secs(60);

/// The demo, a client, S enabled under the client's lease.
async fn demo() -> (
    cangate_server::RunningServer,
    cangate_client::Client,
    Axes,
    cangate_client::ControlLease,
) {
    let mut config = cangate_server::Config::demo();
    config.listen = "127.0.0.1:0".parse().unwrap();
    let server = cangate_server::start(&config).await.expect("demo starts");
    let c = client(&server).await;
    let mut axes: Axes = pb::axes_client::AxesClient::new(c.channel());
    wait_ready(&mut axes, &["S"]).await;
    let lease = c
        .acquire_control_as(&["S"], Duration::from_secs(5), "spindle")
        .await
        .unwrap();
    enable(&mut axes, "S", lease.token()).await;
    (server, c, axes, lease)
}

/// S's velocity profile (rev/s) at `s` seconds: up at 80 rev/s² to 20
/// rev/s, held, down at 80 rev/s² from 0.75 s: at rest from 1 s on (15
/// rev in all).
fn spin(s: f64) -> f64 {
    (80.0 * s).min(20.0).min((80.0 * (1.0 - s)).max(0.0))
}

/// Sends `velocity` sampled every ms for client times 0..`points` ms, in
/// batches of 10, never more than 300 ms ahead of real time.
fn send_velocities(
    sender: SetpointSender,
    points: u64,
    velocity: impl Fn(f64) -> f64 + Send + 'static,
) -> tokio::task::JoinHandle<()> {
    send_points(sender, points, Duration::from_millis(300), move |k| {
        velocity_setpoint(k * 1000, vec![velocity(k as f64 / 1000.0)])
    })
}

/// The drive's velocity never went beyond the streamed profile's 20
/// rev/s (and its first-order lag's overshoot).
fn assert_within_limits(seen: &[pb::SetpointStreamStatus]) {
    for s in seen {
        let v = s.signals[0].velocity_actual.unwrap_or(0.0);
        assert!(v.abs() <= 21.0, "{v} rev/s: {s:?}");
    }
}

/// Waits until S's drive stands still (and is idle, unless `streaming`:
/// an axis in an open stream counts as moving).
async fn wait_at_rest(axes: &mut Axes, streaming: bool) -> pb::AxisStatus {
    let t0 = Instant::now();
    loop {
        let s = axes
            .get_axis(pb::GetAxisRequest { axis: "S".into() })
            .await
            .unwrap()
            .into_inner()
            .status
            .unwrap();
        if s.velocity.abs() < 0.01 && (streaming || s.activity == pb::AxisActivity::Idle as i32) {
            return s;
        }
        assert!(t0.elapsed() < LONG, "S still turning: {s:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// Velocities streamed to the CSV spindle play through to the drive (it
/// turns at 20 rev/s), the predicted path is the velocities' integral, and
/// the stream ends with S at rest, every point played. Points beyond the
/// limits are refused, and a velocity stream starts from rest.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn velocities_stream_to_the_csv_spindle_and_it_ends_at_rest() {
    let (server, c, mut axes, lease) = demo().await;
    let mut stream = c
        .stream_setpoints(&lease, &["S"], stream_options())
        .await
        .unwrap();
    // Not from rest, then a position (no csv point), refused / caught.
    stream
        .send(vec![velocity_setpoint(0, vec![10.0])])
        .await
        .unwrap();
    let mut seen = Vec::new();
    read_until(&mut stream, &mut seen, |s| {
        s.counters.as_ref().is_some_and(|c| c.refused == 1)
    })
    .await
    .unwrap()
    .unwrap();
    assert_eq!(refusals(&seen), ["NOT_FROM_REST"]);
    // The profile, with a point above 50 rev/s and a jump of velocity
    // (20 rev/s in 1 ms) in the middle: both refused, not played.
    stream
        .send(
            (0..=500u64)
                .map(|k| velocity_setpoint(k * 1000, vec![spin(k as f64 / 1000.0)]))
                .collect(),
        )
        .await
        .unwrap();
    stream
        .send(vec![
            velocity_setpoint(500_500, vec![60.0]),
            velocity_setpoint(500_600, vec![40.0]),
        ])
        .await
        .unwrap();
    let sending = send_velocities(stream.sender().unwrap(), 1100, spin);
    // Points 0..=500 were sent already: the sender's first 501 are
    // refused as not after the previous one.
    let turning = read_until(&mut stream, &mut seen, |s| {
        s.signals[0].velocity_actual.is_some_and(|v| v > 19.0)
    })
    .await
    .unwrap()
    .expect("S turns at 20 rev/s");
    assert_eq!(turning.ended, "");
    sending.await.unwrap();
    stream.finish();
    read_until(&mut stream, &mut seen, |_| false)
        .await
        .expect("the stream ends normally");
    let last = seen.last().unwrap();
    assert_eq!(last.ended, "CLIENT_ENDED", "{last:?}");
    let r = refusals(&seen);
    assert_eq!(
        &r[..3],
        ["NOT_FROM_REST", "TOO_FAST", "TOO_HARD_ACCELERATION"]
    );
    assert!(r[3..].iter().all(|x| x == "NOT_AFTER_PREVIOUS"), "{r:?}");
    let c = last.counters.unwrap();
    assert_eq!(c.received, c.accepted + c.refused, "{c:?}");
    assert_eq!(c.accepted, c.played + c.late + c.dropped, "{c:?}");
    assert_eq!(c.played + c.late, 1100, "{c:?}");
    // 15 rev predicted (where no point came late; a SYNC the loaded host
    // skipped moves the prediction on by the drive's travel meanwhile),
    // and the drive integrated the same velocities.
    let p = last.commanded_positions[0];
    assert!(c.late > 0 || p > 14.95, "{p}");
    assert_within_limits(&seen);
    let s = wait_at_rest(&mut axes, false).await;
    assert!((s.position - p).abs() < 1.0, "{s:?} predicted {p}");
    server.shutdown();
}

/// The client stops sending with S at 20 rev/s: after the extrapolation S
/// ramps to rest inside its deceleration (UNDERRUN, AT_REST), the stream
/// stays open, and resumes from rest.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_underrun_at_speed_ramps_the_spindle_to_rest_and_the_stream_resumes() {
    let (server, c, mut axes, lease) = demo().await;
    let mut stream = c
        .stream_setpoints(&lease, &["S"], stream_options())
        .await
        .unwrap();
    // Up to 20 rev/s and no further point.
    let sending = send_velocities(stream.sender().unwrap(), 500, spin);
    let mut seen = Vec::new();
    read_until(&mut stream, &mut seen, |s| {
        events(std::slice::from_ref(s))
            .iter()
            .any(|e| e.kind == pb::SetpointEventKind::SetpointEventAtRest as i32)
    })
    .await
    .unwrap()
    .expect("S comes to rest");
    sending.await.unwrap();
    assert!(
        events(&seen)
            .iter()
            .any(|e| e.kind == pb::SetpointEventKind::SetpointEventUnderrun as i32)
    );
    assert_within_limits(&seen);
    wait_at_rest(&mut axes, true).await;
    // Resumed from rest: a short spin.
    let t0 = 10_000_000u64;
    let points: Vec<_> = (0..=300u64)
        .map(|k| {
            let s = k as f64 / 1000.0;
            velocity_setpoint(
                t0 + k * 1000,
                vec![(50.0 * s).min(50.0 * (0.3 - s)).max(0.0)],
            )
        })
        .collect();
    stream.send(points).await.unwrap();
    stream.finish();
    read_until(&mut stream, &mut seen, |_| false)
        .await
        .expect("the stream ends normally");
    let last = seen.last().unwrap();
    assert_eq!(last.ended, "CLIENT_ENDED", "{last:?}");
    assert!(refusals(&seen).is_empty(), "{:?}", refusals(&seen));
    let c = last.counters.unwrap();
    assert_eq!(c.underruns, 1, "{c:?}");
    assert_eq!(c.accepted, c.played + c.late + c.dropped, "{c:?}");
    wait_at_rest(&mut axes, false).await;
    server.shutdown();
}

/// A lost lease ends a velocity stream with S ramped to rest; a stream
/// never mixes positions (csp) and velocities (csv).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lost_lease_ramps_the_spindle_to_rest_and_modes_do_not_mix() {
    let (server, c, mut axes, lease) = demo().await;
    let mut stream = c
        .stream_setpoints(&lease, &["S"], stream_options())
        .await
        .unwrap();
    let sending = send_velocities(stream.sender().unwrap(), 3000, |s| (80.0 * s).min(20.0));
    let mut seen = Vec::new();
    read_until(&mut stream, &mut seen, |s| {
        s.signals[0].velocity_actual.is_some_and(|v| v > 19.0)
    })
    .await
    .unwrap()
    .expect("S turns at 20 rev/s");
    lease.release().await.unwrap();
    let err = read_until(&mut stream, &mut seen, |_| false)
        .await
        .expect_err("a stream whose lease is gone ends with an error");
    assert_eq!(err.code(), Some(Code::Aborted), "{err:?}");
    assert_eq!(seen.last().unwrap().ended, "LEASE_LOST");
    sending.abort();
    assert_within_limits(&seen);
    wait_at_rest(&mut axes, false).await;

    let lease = c
        .acquire_control(&["X", "S"], Duration::from_secs(5))
        .await
        .unwrap();
    wait_ready(&mut axes, &["X"]).await;
    enable(&mut axes, "X", lease.token()).await;
    let e = c
        .stream_setpoints(&lease, &["X", "S"], stream_options())
        .await
        .err()
        .expect("refused");
    assert_eq!(e.code(), Some(Code::FailedPrecondition), "{e:?}");
    assert!(e.to_string().contains("not both"), "{e}");
    // A position point on a velocity stream is a protocol error.
    let mut stream = c
        .stream_setpoints(&lease, &["S"], stream_options())
        .await
        .unwrap();
    stream.send(vec![setpoint(0, vec![0.0])]).await.unwrap();
    let e = read_until(&mut stream, &mut seen, |_| false)
        .await
        .expect_err("positions on a csv stream");
    assert_eq!(e.code(), Some(Code::InvalidArgument), "{e:?}");
    server.shutdown();
}
