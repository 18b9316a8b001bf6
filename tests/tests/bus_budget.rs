//! Client raw frames never starve the gateway's own traffic: on the
//! 1 Mbit/s bit-timed virtual bus, a `SendFrames` flood at more than the
//! bus rate leaves the SYNC on time in at least 99.9 % of its periods and
//! no heartbeat is lost, whatever identifier the flood uses; the frames
//! held back are counted. `SendFrames` refuses fields that do not belong to
//! the frame's kind.

use cangate_can::{BitTiming, BusItem, FrameSelector, TxShares};
use cangate_client::can::{CanId, Frame};
use cangate_client::pb;
use cangate_tests::*;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// A SYNC every millisecond; two simulated drives whose heartbeats (every
/// 100 ms) the master supervises with a 300 ms consumer time.
const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"
bitrate = 1000000
bit_timing = true
[[canopen]]
bus = "can0"
sync_period_us = 1000
[[canopen.node]]
id = 1
eds = "builtin:drive"
heartbeat_timeout_ms = 300
simulate = true
[[canopen.node]]
id = 2
eds = "builtin:drive"
heartbeat_timeout_ms = 300
simulate = true
"#;

const SYNC_PERIOD_NS: u64 = 1_000_000;
const WINDOW: Duration = Duration::from_secs(3);

/// What the flood did to the SYNC.
#[derive(Debug)]
struct SyncReport {
    /// SYNC periods of the window.
    periods: u64,
    /// Periods without a SYNC on the wire.
    missed: u64,
    /// Periods the SYNC thread itself skipped (woke too late: the host,
    /// not the bus).
    skipped_by_producer: u64,
    /// Client frames that went out during the window.
    flood_frames: u64,
    /// The longest any SYNC can have waited for the bus (the busy stretch
    /// that ended when it started).
    longest_wait_ns: u64,
    /// SYNCs that can have waited for the bus 90 % of a period or more:
    /// the periods the bus, not the host, can have cost.
    waited_most_of_a_period: u64,
}

/// Runs a flood of 8-byte frames on `flood_id` from two clients, each
/// offering 1,000 frames every 100 ms (20,000 frames/s against a bus that
/// carries about 8,500), and watches the SYNC on the wire for [`WINDOW`].
async fn flood_and_watch_sync(server: &cangate_server::RunningServer, flood_id: u16) -> SyncReport {
    let bus = server.gateway().bus("can0").unwrap().clone();
    let master = server.gateway().canopen("can0").unwrap();
    // Every frame on the wire, to see how long the bus was busy before
    // each SYNC.
    let mut wire = bus.subscribe(
        FrameSelector {
            filters: Vec::new(),
            error_frames: false,
            transmitted: true,
        },
        1 << 20,
    );
    let stop = Arc::new(AtomicBool::new(false));
    let mut flooders = Vec::new();
    for _ in 0..2 {
        let mut c = client(server).await;
        let stop = stop.clone();
        flooders.push(tokio::spawn(async move {
            let batch: Vec<Frame> = (0..1000u64)
                .map(|i| Frame::new(CanId::Standard(flood_id), &i.to_le_bytes()).unwrap())
                .collect();
            let mut every = tokio::time::interval(Duration::from_millis(100));
            every.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
            while !stop.load(Ordering::Relaxed) {
                every.tick().await;
                c.send("can0", &batch).await.expect("flood accepted");
            }
        }));
    }
    // Let the flood fill every queue before measuring.
    tokio::time::sleep(Duration::from_millis(300)).await;
    while wire.try_recv().is_some() {}
    let (_, skipped_before) = master.sync_counts();
    let timing = BitTiming::new(1_000_000);
    let mut flood_frames = 0u64;
    let mut stamps = Vec::new();
    let mut busy_waits = Vec::new();
    // The busy stretch so far: back-to-back frames since `busy_since`.
    let (mut busy_since, mut busy_until) = (0u64, 0u64);
    let watch = async {
        loop {
            let frame = match wire.recv().await.expect("bus running") {
                BusItem::Frame { frame, .. } => frame,
                BusItem::Lost(n) => panic!("the watcher lost {n} frames"),
                BusItem::State(_) => continue,
            };
            let end = frame.timestamp().as_nanos();
            let start = end - timing.frame_duration_ns(&frame);
            if start != busy_until {
                busy_since = start;
            }
            if frame.raw_id() == 0x080 {
                stamps.push(end);
                // The longest the SYNC can have waited for the bus: since
                // the bus became busy without a break before it.
                busy_waits.push(start - busy_since);
            } else if frame.raw_id() == u32::from(flood_id) {
                flood_frames += 1;
            }
            busy_until = end;
        }
    };
    let _ = tokio::time::timeout(WINDOW, watch).await;
    let (_, skipped_after) = master.sync_counts();
    stop.store(true, Ordering::Relaxed);
    for f in flooders {
        tokio::time::timeout(WAIT, f).await.unwrap().unwrap();
    }
    assert!(stamps.len() > 100, "SYNCs on the wire: {}", stamps.len());
    // Each SYNC goes in a slot of the SYNC period that begins just before
    // the SYNC's usual phase (the most frequent one, in 20 us steps: the
    // SYNCs that found the bus free), so a SYNC held back by almost a whole
    // period still counts for its own period; one held back longer leaves
    // its period empty. The producer counts the periods it skipped itself.
    const STEP: u64 = 20_000;
    let mut phases = vec![0u32; (SYNC_PERIOD_NS / STEP) as usize];
    for &t in &stamps {
        phases[((t % SYNC_PERIOD_NS) / STEP) as usize] += 1;
    }
    let usual = (0..phases.len()).max_by_key(|&i| phases[i]).unwrap() as u64;
    let origin = (usual * STEP + SYNC_PERIOD_NS - STEP) % SYNC_PERIOD_NS;
    let slot = |t: u64| (t + SYNC_PERIOD_NS - origin) / SYNC_PERIOD_NS;
    let first = slot(stamps[0]);
    let last = slot(*stamps.last().unwrap());
    let hit: std::collections::BTreeSet<u64> = stamps.iter().map(|&t| slot(t)).collect();
    let periods = last - first + 1;
    SyncReport {
        periods,
        missed: periods - hit.len() as u64,
        skipped_by_producer: skipped_after - skipped_before,
        flood_frames,
        longest_wait_ns: busy_waits.iter().copied().max().unwrap_or(0),
        waited_most_of_a_period: busy_waits
            .iter()
            .filter(|&&w| w >= SYNC_PERIOD_NS * 9 / 10)
            .count() as u64,
    }
}

async fn check_flood(flood_id: u16) {
    let server = start_server(CONFIG).await;
    let mut c = client(&server).await;
    let mut events = node_events(&c, vec![1, 2]).await;
    // Both drives heard from before the flood.
    for node in [1, 2] {
        let t0 = std::time::Instant::now();
        while get_node(&c, node).await.heartbeat_age_ms.is_none() {
            assert!(t0.elapsed() < WAIT, "node {node} never sent a heartbeat");
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }
    let report = flood_and_watch_sync(&server, flood_id).await;
    // Periods without a SYNC on the wire are the producer's own skips (the
    // host did not run its thread in time) or SYNCs held back for most of
    // a period: by the bus only if it was busy all that time.
    println!(
        "flood on {flood_id:#05x}: SYNC periods kept {:.3} % on the wire ({} of {} empty, {} of them skipped by the producer thread); {} SYNCs after 90 % of a period of busy bus",
        100.0 * (report.periods - report.missed) as f64 / report.periods as f64,
        report.missed,
        report.periods,
        report.skipped_by_producer,
        report.waited_most_of_a_period
    );
    assert!(
        report.waited_most_of_a_period * 1000 <= report.periods,
        "{} of {} SYNCs found the bus busy for most of a period ({report:?})",
        report.waited_most_of_a_period,
        report.periods
    );
    // No heartbeat was lost.
    while let Ok(ev) = tokio::time::timeout(Duration::from_millis(50), events.message()).await {
        let ev = ev.unwrap().expect("event stream open");
        assert!(
            !matches!(ev.event, Some(pb::node_event::Event::HeartbeatLost(_))),
            "heartbeat lost under the flood: {ev:?}"
        );
    }
    for node in [1, 2] {
        assert!(!get_node(&c, node).await.heartbeat_lost, "node {node}");
    }
    // The frames held back were counted, in the bus statistics too.
    let stats = c.get_bus("can0").await.unwrap().statistics.unwrap();
    let own = server.gateway().bus("can0").unwrap().stats();
    assert!(own.client_frames_delayed > 1000, "{own:?}");
    assert_eq!(own.client_frames_refused, 0, "{own:?}");
    // The flood had its share (30 % of 3 s: up to 8,100 frames of 111 us)
    // and no more.
    assert!(
        (2_000..=9_000).contains(&report.flood_frames),
        "{report:?} {stats:?}"
    );
    println!(
        "flood on {flood_id:#05x}: {} client frames in {WINDOW:?}, longest SYNC wait for the bus {} us, load {:.1} %",
        report.flood_frames,
        report.longest_wait_ns / 1000,
        stats.load_percent
    );
    server.shutdown();
}

/// A flood on the lowest-priority identifier loses every arbitration, so
/// what held the SYNC back was the queue in front of the wire; one on the
/// highest-priority identifier wins every arbitration, so only its share
/// of the bus keeps room for the SYNC. (One after the other: two floods at
/// once would load a two-core host with two bit-timed buses.)
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn floods_leave_sync_and_heartbeats_alone() {
    check_flood(0x7F0).await;
    check_flood(0x001).await;
}

/// The shares are configuration, and a bad one is refused with its name.
#[tokio::test]
async fn shares_are_configured_per_bus() {
    let server = start_server(&format!(
        "{}client_share_percent = 10\nbulk_share_percent = 80\n",
        "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\nbitrate = 1000000\nbit_timing = true\n"
    ))
    .await;
    assert_eq!(
        server.gateway().bus("can0").unwrap().tx_shares(),
        TxShares {
            client_percent: 10,
            bulk_percent: 80
        }
    );
    server.shutdown();
    let bad = cangate_server::Config::from_toml(
        "listen = \"127.0.0.1:0\"\n[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\nclient_share_percent = 0\n",
    )
    .unwrap_err()
    .to_string();
    assert!(bad.contains("client_share_percent = 0"), "{bad}");
}

/// `brs`, `esi` and `remote_dlc` on a classic data frame were accepted and
/// dropped; they are refused with what to do instead.
#[tokio::test]
async fn classic_frames_with_fd_fields_are_refused() {
    let server = start_server(ONE_BUS).await;
    let mut bus = client(&server).await.bus_client();
    let frame = |brs, esi, remote_dlc| pb::Frame {
        id: 0x123,
        data: vec![1, 2],
        brs,
        esi,
        remote_dlc,
        ..Default::default()
    };
    for (f, says) in [
        (frame(true, false, 0), "brs is a CAN FD flag"),
        (frame(false, true, 0), "esi is a CAN FD flag"),
        (
            frame(false, false, 3),
            "remote_dlc 3 is only for remote frames",
        ),
    ] {
        let err = bus
            .send_frames(pb::SendFramesRequest {
                bus: "can0".into(),
                frames: vec![f],
            })
            .await
            .unwrap_err();
        assert_eq!(err.code(), tonic::Code::InvalidArgument, "{err:?}");
        assert!(err.message().contains(says), "{}", err.message());
    }
    assert_eq!(server.gateway().bus("can0").unwrap().stats().tx_frames, 0);
    server.shutdown();
}

/// Two simulated drives under cyclic axes that jog on a 1 ms SYNC, with
/// heartbeats supervised at 300 ms: a bus the gateway's own cycle keeps
/// about 70 % busy, and a client share of 50 %, more than is left.
fn cyclic_config() -> String {
    let mut config = String::from(
        "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\nbitrate = 1000000\nbit_timing = true\n\
         client_share_percent = 50\n[[canopen]]\nbus = \"can0\"\nsync_period_us = 1000\n",
    );
    for (i, axis) in ["X", "Y"].iter().enumerate() {
        config.push_str(&format!(
            "[[canopen.node]]\nid = {node}\neds = \"builtin:drive\"\nheartbeat_timeout_ms = 300\n\
             simulate = true\n[[axis]]\nname = \"{axis}\"\nbus = \"can0\"\nnode = {node}\n\
             counts_per_unit = 1000.0\nposition_mode = \"cyclic\"\nmin_position = -2000.0\n\
             max_position = 2000.0\nmax_velocity = 100.0\nmax_acceleration = 1000.0\n",
            node = i + 1
        ));
    }
    config
}

/// An attached client floods the highest-priority identifier (500 frames
/// per message, as fast as the gateway takes them) while two cyclic axes
/// jog on a 1 ms SYNC, then goes away: the SYNC keeps its period on the
/// wire during the flood and after it, no heartbeat is lost and no axis
/// faults. Client frames take only bus time nobody else needs: a flood
/// that took its share of a busy bus regardless built a backlog of the
/// gateway's and the drives' frames that grew for as long as it lasted
/// and took seconds to drain. Times are the bus's own timestamps.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_attach_flood_leaves_the_sync_and_moving_axes_alone() {
    use cangate_client::AttachOptions;
    use cangate_tests::axes::{acquire, enable, opts, wait_ready};
    const FLOOD: Duration = Duration::from_secs(3);
    const AFTER: Duration = Duration::from_secs(2);
    let server = start_server(&cyclic_config()).await;
    let c = client(&server).await;
    let mut events = node_events(&c, vec![1, 2]).await;
    let mut axes = c.axes_client();
    wait_ready(&mut axes, &["X", "Y"]).await;
    let lease = acquire(&mut axes, &["X", "Y"], 60_000, "test").await;
    for a in ["X", "Y"] {
        enable(&mut axes, a, &lease).await;
    }
    let bus = server.gateway().bus("can0").unwrap().clone();
    let mut wire = bus.subscribe(
        FrameSelector {
            filters: Vec::new(),
            error_frames: false,
            transmitted: true,
        },
        1 << 22,
    );
    for a in ["X", "Y"] {
        let r = axes
            .jog(pb::JogRequest {
                axis: a.into(),
                velocity: 5.0,
                acceleration: 0.0,
                options: opts(&lease, false),
            })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(r.outcome, pb::Outcome::Accepted as i32, "{a}: {r:?}");
    }
    let attached = c.attach("can0", &AttachOptions::default()).await.unwrap();
    let flood = tokio::spawn(async move {
        let batch: Vec<Frame> = (0..500u64)
            .map(|i| Frame::new(CanId::Standard(0x001), &i.to_le_bytes()).unwrap())
            .collect();
        let t0 = std::time::Instant::now();
        while t0.elapsed() < FLOOD {
            // Held back by the gateway's pacing: offered again.
            if let Ok(r) =
                tokio::time::timeout(Duration::from_millis(100), attached.sender.send(&batch)).await
            {
                r.expect("flood accepted");
            }
        }
        drop(attached);
        cangate_can::Timestamp::now().as_nanos()
    });
    let mut syncs = Vec::new();
    let mut flood_frames = 0u64;
    // The longest a SYNC can have waited for the bus: the busy stretch
    // that ended when it started (the bus's doing, not the host's).
    let timing = BitTiming::new(1_000_000);
    let (mut busy_since, mut busy_until, mut longest_busy_wait) = (0u64, 0u64, 0u64);
    let watch = async {
        loop {
            let frame = match wire.recv().await.expect("bus running") {
                BusItem::Frame { frame, .. } => frame,
                BusItem::Lost(n) => panic!("the watcher lost {n} frames"),
                BusItem::State(_) => continue,
            };
            let end = frame.timestamp().as_nanos();
            let start = end - timing.frame_duration_ns(&frame);
            if start != busy_until {
                busy_since = start;
            }
            busy_until = end;
            match frame.raw_id() {
                0x080 => {
                    syncs.push(end);
                    longest_busy_wait = longest_busy_wait.max(start - busy_since);
                }
                0x001 => flood_frames += 1,
                _ => {}
            }
        }
    };
    let _ = tokio::time::timeout(FLOOD + AFTER, watch).await;
    let stopped = flood.await.unwrap();
    let longest = syncs
        .windows(2)
        .map(|w| w[1] - w[0])
        .max()
        .expect("SYNCs on the wire");
    let (_, skipped) = server.gateway().canopen("can0").unwrap().sync_counts();
    println!(
        "{flood_frames} flood frames on the wire; {} SYNCs, longest gap {} us ({skipped} \
         periods skipped by the producer), longest SYNC wait for the bus {} us; {:?}",
        syncs.len(),
        longest / 1000,
        longest_busy_wait / 1000,
        bus.stats()
    );
    // No SYNC found the bus busy without a break for more than 100
    // periods (a generous bound: about 10 here, where the client's frames
    // fill the time the cycle leaves; with the flood taking its share
    // regardless, the backlog it built kept the bus busy for seconds).
    assert!(
        longest_busy_wait <= 100 * SYNC_PERIOD_NS,
        "a SYNC waited {} us for the bus",
        longest_busy_wait / 1000
    );
    // And the SYNC kept going: no gap of more than a quarter of a second
    // (generous for a loaded host, whose thread may wake late).
    assert!(
        longest <= 250 * SYNC_PERIOD_NS,
        "a SYNC gap of {} ms",
        longest / 1_000_000
    );
    assert!(
        *syncs.last().unwrap() > stopped + AFTER.as_nanos() as u64 / 4,
        "no SYNC after the flood"
    );
    assert!(bus.stats().client_frames_delayed > 0);
    while let Ok(ev) = tokio::time::timeout(Duration::from_millis(50), events.message()).await {
        let ev = ev.unwrap().expect("event stream open");
        assert!(
            !matches!(ev.event, Some(pb::node_event::Event::HeartbeatLost(_))),
            "heartbeat lost under the flood: {ev:?}"
        );
    }
    for node in [1, 2] {
        assert!(!get_node(&c, node).await.heartbeat_lost, "node {node}");
    }
    for a in ["X", "Y"] {
        let st = axes
            .get_axis(pb::GetAxisRequest { axis: a.into() })
            .await
            .unwrap()
            .into_inner()
            .status
            .unwrap();
        assert_eq!(st.fault_code, 0, "{a}: {st:?}");
        assert!(!st.node_lost, "{a}: {st:?}");
    }
    server.shutdown();
}
