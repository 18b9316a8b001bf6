//! Shutdown: the cancellation the signal handler fires ends the server
//! promptly and every stream cleanly (no error); axes still moving when the
//! motion bound runs out are quick-stopped through their controlword.

use cangate_client::pb;
use cangate_tests::*;
use std::time::Duration;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_ends_streams_cleanly_and_promptly() {
    let server = start_server(ONE_BUS).await;
    let mut a = client(&server).await;
    let mut b = client(&server).await;
    let (mut s1, _) = open_stream(&mut a, stream_request("can0", vec![])).await;
    let (mut s2, _) = open_stream(&mut b, stream_request("can0", vec![])).await;
    let addr = server.addr;
    let started = std::time::Instant::now();
    // What SIGINT/SIGTERM do in cangate-server's main.
    server.shutdown();
    for s in [&mut s1, &mut s2] {
        let end = tokio::time::timeout(WAIT, s.message())
            .await
            .expect("stream ends in time");
        assert!(
            matches!(end, Ok(None)),
            "stream ends cleanly with OK, got {end:?}"
        );
    }
    server
        .wait(Duration::from_secs(5))
        .await
        .expect("server stops within 5 s");
    assert!(started.elapsed() < Duration::from_secs(5));
    // The listener is closed once it has stopped.
    assert!(
        cangate_client::connect(&format!("http://{addr}"))
            .await
            .is_err()
    );
}

/// A cyclic axis on a drive the test runs itself (node 5), with a gentle
/// deceleration so that a stop from jog speed outlasts a short shutdown
/// bound.
const SLOW_STOP_AXIS: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"
sync_period_us = 5000

[[canopen.node]]
id = 5
eds = "builtin:drive"
heartbeat_timeout_ms = 300

[[axis]]
name = "S"
bus = "can0"
node = 5
counts_per_unit = 1000.0
position_mode = "cyclic"
min_position = -1000.0
max_position = 1000.0
max_velocity = 100.0
max_acceleration = 20.0
jog_deadman_ms = 5000
"#;

/// The server of [`SLOW_STOP_AXIS`] with its drive, the axis enabled and
/// jogging at `velocity` mm/s (its lease held by the caller's test).
async fn jogging_slow_stop_axis(
    velocity: f64,
) -> (
    cangate_server::RunningServer,
    cangate_sim::DeviceHandle<cangate_sim::SimDrive>,
    tokio_util::sync::CancellationToken,
) {
    use cangate_tests::axes::*;
    let server = start_server(SLOW_STOP_AXIS).await;
    let c = client(&server).await;
    let mut axes = c.axes_client();
    let (drive, cancel) = run_drive(&server, 5, Some(100));
    wait_status(&mut axes, "S", |s| s.state != 0 && !s.node_lost).await;
    let lease = acquire(&mut axes, &["S"], 10_000, "test").await;
    enable(&mut axes, "S", &lease).await;
    axes.jog(pb::JogRequest {
        axis: "S".into(),
        velocity,
        acceleration: 0.0,
        options: opts(&lease, false),
    })
    .await
    .unwrap();
    (server, drive, cancel)
}

/// Waits until axis S is beyond `position` mm.
async fn wait_position_above(server: &cangate_server::RunningServer, position: f64) {
    let mut axes = client(server).await.axes_client();
    cangate_tests::axes::wait_status(&mut axes, "S", |s| s.position > position).await;
}

/// Shutdown whose stop does not finish within the bound: the gateway is a
/// cyclic drive's trajectory, so before it leaves it quick-stops the drive
/// through the controlword (the drive then ramps down on its own), and it
/// reports the axis as not at rest (the server exits non-zero).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_quick_stops_a_cyclic_axis_that_is_not_at_rest_in_time() {
    use cangate_canopen::cia402::DriveState;
    let (server, drive, _cancel) = jogging_slow_stop_axis(40.0).await;
    // Past the ramp to 40 mm/s (it covers 40 mm).
    wait_position_above(&server, 45.0).await;
    // 40 mm/s at 20 mm/s² needs 2 s to stop: far more than the bound.
    let not_at_rest = server.shutdown_safely(Duration::from_millis(200)).await;
    assert_eq!(not_at_rest, vec!["S".to_string()]);
    let state = drive.with(|d| d.state());
    assert!(
        matches!(
            state,
            DriveState::QuickStopActive | DriveState::SwitchOnDisabled
        ),
        "the drive got the quick stop through its controlword: {state:?}"
    );
    server.wait(Duration::from_secs(10)).await.unwrap();
}

/// Shutdown with every axis brought to rest in time reports none.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_reports_no_axis_when_all_came_to_rest() {
    let (server, drive, _cancel) = jogging_slow_stop_axis(5.0).await;
    // Past the ramp to 5 mm/s (it covers 0.625 mm).
    wait_position_above(&server, 1.0).await;
    // 5 mm/s at 20 mm/s² stops in 0.25 s.
    let stops = server
        .gateway()
        .axes()
        .stop_for_shutdown(Duration::from_secs(5))
        .await;
    assert!(stops.not_at_rest.is_empty(), "{stops:?}");
    assert_eq!(stops.lines.len(), 1, "{stops:?}");
    assert!(stops.lines[0].starts_with("S: completed"), "{stops:?}");
    // At rest as the axis layer defines it: the stopping ramp is over, what
    // is left is at most the last set-point's interpolation (a count or
    // two), well inside the 10-count in-position window. The drive's
    // instantaneous velocity is not compared: on a 5 ms SYNC one count per
    // period is already 200 counts/s.
    let at_completion = drive.with(|d| d.position());
    server.shutdown();
    // The drive settles on the held set-point by itself.
    let settled = async {
        loop {
            let (v, p) = drive.with(|d| (d.velocity(), d.position()));
            if v.abs() < 0.5 {
                return p;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    };
    let at_rest = tokio::time::timeout(Duration::from_secs(5), settled)
        .await
        .expect("the drive settles after the stop");
    assert!(
        (at_rest - at_completion).abs() <= 10.0,
        "the drive moved {} counts after the stop completed",
        at_rest - at_completion
    );
    server.wait(Duration::from_secs(10)).await.unwrap();
}
