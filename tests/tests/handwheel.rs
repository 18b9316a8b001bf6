//! Handwheels end to end: simulated wheels on the virtual bus, the real
//! server, the real client; feed events, compensation, mode, axis binding.

use cangate_client::pb;
use cangate_tests::*;
use futures::StreamExt;
use std::time::{Duration, Instant};
use tonic::Code;

/// hw1 (node 10) jogs X with a deep backlog (exact totals); hw2 (node 11)
/// jogs Y at 1000 units/s with a 200 ms backlog (even output, drops).
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
id = 10
eds = "builtin:handwheel"
simulate = true
heartbeat_timeout_ms = 300

[[canopen.node]]
id = 11
eds = "builtin:handwheel"
simulate = true
heartbeat_timeout_ms = 300

[[axis]]
name = "X"
bus = "can0"
node = 1
counts_per_unit = 1000.0
position_mode = "cyclic"
max_velocity = 100.0
max_acceleration = 1000.0

[[axis]]
name = "Y"
bus = "can0"
node = 2
counts_per_unit = 1000.0
position_mode = "cyclic"
max_velocity = 100.0
max_acceleration = 1000.0

[[handwheel]]
name = "hw1"
bus = "can0"
node = 10
max_units_per_s = 20000.0
stop_within_ms = 1000

[[handwheel.bind]]
wheel_axis = "X"
axis = "X"
distance_per_unit = 0.001

[[handwheel]]
name = "hw2"
bus = "can0"
node = 11
max_units_per_s = 1000.0
stop_within_ms = 200

[[handwheel.bind]]
wheel_axis = "Y"
axis = "Y"
distance_per_unit = 0.001
"#;

type Axes = pb::axes_client::AxesClient<cangate_client::Transport>;
type Wheels = pb::handwheels_client::HandwheelsClient<cangate_client::Transport>;
type Sim = pb::simulator_client::SimulatorClient<cangate_client::Transport>;

struct Bed {
    server: cangate_server::RunningServer,
    axes: Axes,
    wheels: Wheels,
    sim: Sim,
}

async fn setup() -> Bed {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut axes = c.axes_client();
    let t0 = Instant::now();
    loop {
        let list = axes
            .list_axes(pb::ListAxesRequest {})
            .await
            .unwrap()
            .into_inner()
            .axes;
        if list.iter().all(|a| {
            a.status
                .as_ref()
                .is_some_and(|s| s.state != 0 && !s.node_lost)
        }) {
            break;
        }
        assert!(t0.elapsed() < WAIT, "axes did not come up");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    Bed {
        wheels: pb::handwheels_client::HandwheelsClient::new(c.channel()),
        sim: pb::simulator_client::SimulatorClient::new(c.channel()),
        axes,
        server,
    }
}

/// Enables `axis` under a short-lived lease, then gives control back (so
/// the wheel can take it).
async fn enable(axes: &mut Axes, axis: &str) {
    let lease = axes
        .acquire_control(pb::AcquireControlRequest {
            axes: vec![axis.into()],
            ttl_ms: 2000,
            client_name: "test".into(),
        })
        .await
        .unwrap()
        .into_inner()
        .lease;
    let r = axes
        .enable(pb::AxisCommandRequest {
            axis: axis.into(),
            options: Some(pb::CommandOptions {
                lease: lease.clone(),
                wait: true,
                wait_timeout_ms: 5000,
            }),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    axes.release_control(pb::ReleaseControlRequest { lease })
        .await
        .unwrap();
}

async fn set_mode(w: &mut Wheels, wheel: &str, mode: pb::HandwheelMode) -> pb::Handwheel {
    w.set_mode(pb::SetModeRequest {
        handwheel: wheel.into(),
        mode: mode as i32,
    })
    .await
    .unwrap()
    .into_inner()
}

async fn get(w: &mut Wheels, wheel: &str) -> pb::Handwheel {
    w.get_handwheel(pb::GetHandwheelRequest {
        handwheel: wheel.into(),
    })
    .await
    .unwrap()
    .into_inner()
}

async fn axis_status(axes: &mut Axes, axis: &str) -> pb::AxisStatus {
    axes.get_axis(pb::GetAxisRequest { axis: axis.into() })
        .await
        .unwrap()
        .into_inner()
        .status
        .unwrap()
}

/// Waits (bounded) until the wheel's statistics stop changing.
async fn settle(w: &mut Wheels, wheel: &str) -> pb::Handwheel {
    let t0 = Instant::now();
    let mut last = get(w, wheel).await.stats;
    loop {
        tokio::time::sleep(Duration::from_millis(150)).await;
        let h = get(w, wheel).await;
        if h.stats == last && h.stats.as_ref().is_some_and(|s| s.frames > 0) {
            return h;
        }
        last = h.stats.clone();
        assert!(t0.elapsed() < WAIT, "feed did not settle: {h:?}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lossy_feed_is_compensated_exactly_and_moves_the_bound_axis_exactly() {
    let mut b = setup().await;
    enable(&mut b.axes, "X").await;
    let h = set_mode(&mut b.wheels, "hw1", pb::HandwheelMode::Manual).await;
    assert_eq!(h.mode, pb::HandwheelMode::Manual as i32);
    assert!(h.simulated);
    let mut feed = b
        .wheels
        .stream_feed(pb::StreamFeedRequest {
            handwheels: vec!["hw1".into()],
            coalesce_ms: 0,
        })
        .await
        .unwrap()
        .into_inner();
    // 200 detents at x10 with 10 % random frame loss (at most 14 in a row).
    b.sim
        .turn_handwheel(pb::TurnHandwheelRequest {
            handwheel: "hw1".into(),
            detents: 200,
            axis: pb::WheelAxis::X as i32,
            multiplier: 10,
            loss: 0.1,
            max_consecutive_loss: 14,
        })
        .await
        .unwrap();
    // The stream's units (1 + compensated per frame) add up to 2000.
    let mut units = 0u32;
    let mut compensated = 0u32;
    let t0 = Instant::now();
    while units < 2000 {
        let ev = tokio::time::timeout(WAIT, feed.message())
            .await
            .unwrap_or_else(|_| panic!("feed stalled at {units} units ({compensated} compensated)"))
            .unwrap()
            .unwrap();
        assert_eq!(ev.lost_before, 0);
        assert!(!ev.bad && !ev.duplicate, "{ev:?}");
        assert_eq!(ev.direction, 1);
        assert_eq!(ev.axis, pb::WheelAxis::X as i32);
        units += ev.units;
        compensated += ev.compensated;
        assert!(t0.elapsed() < WAIT);
    }
    assert_eq!(units, 2000);
    assert!(compensated > 0, "10 % loss must have been compensated");
    let h = settle(&mut b.wheels, "hw1").await;
    let s = h.stats.unwrap();
    assert_eq!(s.positive_units[0], 2000, "{s:?}");
    assert_eq!(u64::from(compensated), s.compensated_units);
    assert_eq!(s.frames + s.compensated_units, 2000);
    let binding = h.binding.unwrap();
    assert_eq!(binding.executed_units, 2000, "{binding:?}");
    assert_balanced(&binding);
    // The bound axis moved exactly 2000 × 1 µm.
    let t0 = Instant::now();
    loop {
        let st = axis_status(&mut b.axes, "X").await;
        if st.activity == pb::AxisActivity::Idle as i32 && (st.position - 2.0).abs() <= 0.010 {
            assert!((st.demand_position - 2.0).abs() < 1e-9, "{st:?}");
            assert!(st.controlled_by.starts_with("handwheel hw1"), "{st:?}");
            break;
        }
        assert!(t0.elapsed() < WAIT, "{st:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// StreamFeedBatches carries StreamFeed's events, in the same order, a
/// batch at a time; the typed client's feed (on batches) yields them one
/// by one.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn batched_feed_carries_the_same_events_in_order() {
    let mut b = setup().await;
    set_mode(&mut b.wheels, "hw1", pb::HandwheelMode::Manual).await;
    let req = pb::StreamFeedRequest {
        handwheels: vec!["hw1".into()],
        coalesce_ms: 0,
    };
    let mut single = b
        .wheels
        .stream_feed(req.clone())
        .await
        .unwrap()
        .into_inner();
    let mut batches = b
        .wheels
        .stream_feed_batches(req)
        .await
        .unwrap()
        .into_inner();
    let typed_client = client(&b.server).await;
    let mut typed = typed_client.handwheel_feed(&["hw1"], None).await.unwrap();
    b.sim
        .turn_handwheel(pb::TurnHandwheelRequest {
            handwheel: "hw1".into(),
            detents: 300,
            axis: pb::WheelAxis::Y as i32,
            multiplier: 1,
            loss: 0.0,
            max_consecutive_loss: 0,
        })
        .await
        .unwrap();
    let key = |e: &pb::FeedEvent| (e.sequence, e.timestamp_us, e.units, e.axis, e.direction);
    let mut one_by_one = Vec::new();
    while one_by_one.len() < 300 {
        let ev = tokio::time::timeout(WAIT, single.message())
            .await
            .expect("StreamFeed in time")
            .unwrap()
            .expect("StreamFeed open");
        one_by_one.push(key(&ev));
    }
    let mut batched = Vec::new();
    while batched.len() < 300 {
        let batch = tokio::time::timeout(WAIT, batches.message())
            .await
            .expect("StreamFeedBatches in time")
            .unwrap()
            .expect("StreamFeedBatches open");
        assert!(!batch.events.is_empty(), "a batch has at least one event");
        batched.extend(batch.events.iter().map(key));
    }
    let mut from_typed = Vec::new();
    while from_typed.len() < 300 {
        let ev = tokio::time::timeout(WAIT, typed.next())
            .await
            .expect("typed feed in time")
            .expect("typed feed open")
            .unwrap();
        from_typed.push(key(&ev));
    }
    assert_eq!(batched, one_by_one);
    assert_eq!(from_typed, one_by_one);
    assert_eq!(one_by_one.iter().map(|k| k.2).sum::<u32>(), 300);
}

/// `units = executed + dropped + pending`, as the API reports them.
fn assert_balanced(b: &pb::BindingStats) {
    let dropped = b.dropped_backlog
        + b.dropped_not_manual
        + b.dropped_not_enabled
        + b.dropped_not_controlled
        + b.dropped_unbound;
    assert_eq!(
        b.units,
        b.executed_units + dropped + b.pending_units,
        "the binding counters do not add up: {b:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn automatic_mode_sends_no_feed_and_nothing_is_replayed_in_manual_mode() {
    let mut b = setup().await;
    enable(&mut b.axes, "X").await;
    let start = axis_status(&mut b.axes, "X").await.position;
    let h = set_mode(&mut b.wheels, "hw1", pb::HandwheelMode::Automatic).await;
    assert_eq!(h.mode, pb::HandwheelMode::Automatic as i32);
    let frames_before = h.stats.unwrap().frames;
    let mut feed = b
        .wheels
        .stream_feed(pb::StreamFeedRequest {
            handwheels: vec![],
            coalesce_ms: 0,
        })
        .await
        .unwrap()
        .into_inner();
    // 100 000 units turned in automatic mode.
    let r = b
        .sim
        .turn_handwheel(pb::TurnHandwheelRequest {
            handwheel: "hw1".into(),
            detents: 1000,
            axis: pb::WheelAxis::X as i32,
            multiplier: 100,
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.pending_units, 0, "nothing queued in automatic mode");
    assert_eq!(r.discarded_units, 100_000);
    assert!(
        tokio::time::timeout(Duration::from_millis(300), feed.message())
            .await
            .is_err(),
        "no feed in automatic mode"
    );
    assert_eq!(
        get(&mut b.wheels, "hw1").await.stats.unwrap().frames,
        frames_before
    );
    // Switching to manual replays nothing: no feed, the axis stays put.
    set_mode(&mut b.wheels, "hw1", pb::HandwheelMode::Manual).await;
    assert!(
        tokio::time::timeout(Duration::from_millis(500), feed.message())
            .await
            .is_err(),
        "turns made in automatic mode were replayed in manual mode"
    );
    let st = axis_status(&mut b.axes, "X").await;
    assert!((st.position - start).abs() < 0.01, "X moved: {st:?}");
    // A turn in manual mode moves it, and the counters add up.
    b.sim
        .turn_handwheel(pb::TurnHandwheelRequest {
            handwheel: "hw1".into(),
            detents: 50,
            multiplier: 1,
            ..Default::default()
        })
        .await
        .unwrap();
    let ev = tokio::time::timeout(WAIT, feed.message())
        .await
        .expect("feed after manual")
        .unwrap()
        .unwrap();
    assert!(
        ev.baseline,
        "the first frame after a mode change is a baseline: {ev:?}"
    );
    let binding = wait_binding(&mut b.wheels, "hw1", |x| x.executed_units == 50).await;
    assert_balanced(&binding);
    let s = get(&mut b.wheels, "hw1").await.stats.unwrap();
    assert_eq!(s.positive_units[0], binding.units, "{s:?} {binding:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bursts_are_paced_evenly_excess_is_dropped_and_the_axis_stops_in_time() {
    let mut b = setup().await;
    enable(&mut b.axes, "Y").await;
    set_mode(&mut b.wheels, "hw2", pb::HandwheelMode::Manual).await;
    let mut c = client(&b.server).await;
    let (mut frames, mut pending) = open_stream(
        &mut c,
        pb::StreamFramesRequest {
            include_transmitted: true,
            ..stream_request(
                "can0",
                vec![pb::FrameFilter {
                    id: 0x302,
                    mask: 0x7FF,
                    format: 0,
                    invert: false,
                }],
            )
        },
    )
    .await;
    // One idle set-point first (the axis at rest), so the motion's start is
    // seen after it: without this wait the first set-point on the stream
    // could already be a moving one when the wheel's feed reaches the axis
    // before the next SYNC.
    let idle = read_frames(&mut frames, &mut pending, 1).await;
    // 500 units within ~35 ms (the wheel sends 15 000 frames/s).
    b.sim
        .turn_handwheel(pb::TurnHandwheelRequest {
            handwheel: "hw2".into(),
            detents: 50,
            axis: pb::WheelAxis::Y as i32,
            multiplier: 10,
            ..Default::default()
        })
        .await
        .unwrap();
    let h = settle(&mut b.wheels, "hw2").await;
    let s = h.stats.unwrap();
    assert_eq!(s.positive_units[1], 500);
    let binding = h.binding.unwrap();
    // 1000 units/s with a 200 ms backlog: about 200 units run (plus those
    // already paced out while the burst arrived), the rest is dropped and
    // reported, never run late.
    assert_eq!(
        binding.executed_units + binding.dropped_backlog,
        500,
        "{binding:?}"
    );
    assert!((200..=320).contains(&binding.executed_units), "{binding:?}");
    // Set-points (RPDO2 of node 2, one per 5 ms SYNC) while it moves, with
    // their bus timestamps: the demand advances at the paced rate, 1000
    // units/s × 1 µm = 1000 counts/s, never faster over any 100 ms, and the
    // executed units take about executed/1000 s (even, not at once).
    let target_of =
        |f: &pb::Frame| i32::from_le_bytes([f.data[0], f.data[1], f.data[2], f.data[3]]);
    let expected = binding.executed_units as i32;
    let mut setpoints: Vec<(f64, i32)> = idle
        .iter()
        .map(|f| (f.timestamp_ns as f64 / 1e9, target_of(f)))
        .collect();
    assert_eq!(setpoints[0].1, 0, "the axis rests at 0 before the burst");
    let t0 = Instant::now();
    loop {
        let got = read_frames(&mut frames, &mut pending, 1).await;
        setpoints.extend(
            got.iter()
                .map(|f| (f.timestamp_ns as f64 / 1e9, target_of(f))),
        );
        if setpoints.last().map(|s| s.1) == Some(expected) {
            break;
        }
        assert!(
            t0.elapsed() < WAIT,
            "never reached {expected}: {setpoints:?}"
        );
    }
    let start = setpoints.iter().position(|s| s.1 != 0).expect("it moved");
    let end = setpoints.iter().position(|s| s.1 == expected).unwrap();
    // The set-point before the first move (or the first one seen, when the
    // stream's first frame already moved).
    let duration = setpoints[end].0 - setpoints[start.saturating_sub(1)].0;
    let nominal = f64::from(expected) / 1000.0;
    assert!(
        duration >= nominal * 0.7 && duration <= nominal + 1.0,
        "{expected} counts in {duration:.3} s (nominal {nominal:.3} s): {:?}",
        setpoints
            .iter()
            .map(|(t, c)| (((t - setpoints[0].0) * 1000.0).round(), *c))
            .collect::<Vec<_>>()
    );
    for (k, a) in setpoints[start..=end].iter().enumerate() {
        for b in &setpoints[start + k..=end] {
            let dt = b.0 - a.0;
            // Bus timestamps carry the send jitter of a busy machine: the
            // bound has room for it (an unpaced burst would be ~10× over).
            if dt >= 0.1 {
                let rate = f64::from(b.1 - a.1) / dt;
                assert!(rate <= 1300.0, "{rate:.0} counts/s over {dt:.3} s");
                break;
            }
        }
    }
    // The demand stopped with the feed (above); the drive settles in
    // position right after (its following lag is a few ms).
    let settled = Instant::now();
    loop {
        let st = axis_status(&mut b.axes, "Y").await;
        if st.activity == pb::AxisActivity::Idle as i32 {
            break;
        }
        assert!(settled.elapsed() < Duration::from_secs(1), "{st:?}");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_requests_are_refused_clearly() {
    let mut b = setup().await;
    let e = b
        .wheels
        .get_handwheel(pb::GetHandwheelRequest {
            handwheel: "nope".into(),
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::NotFound);
    assert!(
        e.message().contains("handwheels: hw1, hw2"),
        "{}",
        e.message()
    );
    let e = b
        .wheels
        .set_mode(pb::SetModeRequest {
            handwheel: "hw1".into(),
            mode: 0,
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument);
    let e = b
        .sim
        .turn_handwheel(pb::TurnHandwheelRequest {
            handwheel: "hw1".into(),
            detents: 1,
            multiplier: 5,
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument);
    // While the wheel holds X in manual mode, others cannot take it.
    enable(&mut b.axes, "X").await;
    set_mode(&mut b.wheels, "hw1", pb::HandwheelMode::Manual).await;
    let t0 = Instant::now();
    loop {
        let r = b
            .axes
            .acquire_control(pb::AcquireControlRequest {
                axes: vec!["X".into()],
                ttl_ms: 1000,
                client_name: "hmi".into(),
            })
            .await;
        match r {
            Err(e) => {
                assert_eq!(e.code(), Code::FailedPrecondition);
                assert!(e.message().contains("handwheel hw1"), "{}", e.message());
                break;
            }
            Ok(l) => {
                // The wheel had not taken it yet: give it back and retry.
                b.axes
                    .release_control(pb::ReleaseControlRequest {
                        lease: l.into_inner().lease,
                    })
                    .await
                    .unwrap();
            }
        }
        assert!(t0.elapsed() < WAIT);
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// Waits (bounded) until the wheel's binding statistics satisfy `f`.
async fn wait_binding(
    w: &mut Wheels,
    wheel: &str,
    f: impl Fn(&pb::BindingStats) -> bool,
) -> pb::BindingStats {
    let t0 = Instant::now();
    loop {
        let b = get(w, wheel).await.binding.unwrap_or_default();
        if f(&b) {
            return b;
        }
        assert!(t0.elapsed() < WAIT, "{b:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_blocked_binding_names_the_holder_until_the_wheel_leaves_manual_mode() {
    let mut b = setup().await;
    // An HMI holds X: the wheel in manual mode cannot take it, and says why.
    b.axes
        .acquire_control(pb::AcquireControlRequest {
            axes: vec!["X".into()],
            ttl_ms: 30_000,
            client_name: "hmi".into(),
        })
        .await
        .unwrap();
    set_mode(&mut b.wheels, "hw1", pb::HandwheelMode::Manual).await;
    let blocked = wait_binding(&mut b.wheels, "hw1", |s| !s.blocked.is_empty()).await;
    assert!(blocked.blocked.contains("hmi"), "{blocked:?}");
    // In automatic mode the wheel wants nothing: no stale refusal stays.
    set_mode(&mut b.wheels, "hw1", pb::HandwheelMode::Automatic).await;
    wait_binding(&mut b.wheels, "hw1", |s| s.blocked.is_empty()).await;
}

/// Every feed variant (one event per message, batches, a window) ends with
/// UNAVAILABLE "shutting down" when the gateway shuts down, also without a
/// single event, and the server stops in time.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn feeds_end_with_unavailable_at_shutdown() {
    let mut b = setup().await;
    let req = |coalesce_ms| pb::StreamFeedRequest {
        handwheels: vec!["hw1".into()],
        coalesce_ms,
    };
    let mut single = b.wheels.stream_feed(req(0)).await.unwrap().into_inner();
    let mut windowed = b.wheels.stream_feed(req(20)).await.unwrap().into_inner();
    let mut batches = b
        .wheels
        .stream_feed_batches(req(0))
        .await
        .unwrap()
        .into_inner();
    b.server.shutdown();
    // How each ended: the gateway's own status, not a broken connection.
    fn end<T: std::fmt::Debug>(r: Result<Option<T>, tonic::Status>, which: &str) {
        match r {
            Err(s) => {
                assert_eq!(s.code(), tonic::Code::Unavailable, "{which}: {s:?}");
                assert!(s.message().contains("shutting down"), "{which}: {s:?}");
            }
            Ok(m) => panic!("{which}: expected UNAVAILABLE, got {m:?}"),
        }
    }
    let single = tokio::time::timeout(WAIT, single.message()).await;
    let windowed = tokio::time::timeout(WAIT, windowed.message()).await;
    let batches = tokio::time::timeout(WAIT, batches.message()).await;
    end(single.expect("in time"), "StreamFeed");
    end(windowed.expect("in time"), "StreamFeed with a window");
    end(batches.expect("in time"), "StreamFeedBatches");
    b.server
        .wait(Duration::from_secs(5))
        .await
        .expect("server stops within 5 s");
}
