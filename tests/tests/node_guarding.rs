//! CiA 301 node guarding end to end: a simulated node configured with
//! `guard_time_ms`/`life_time_factor` produces no heartbeat; the master
//! sends an RTR to 0x705 every guard time, the node answers with its toggle
//! bit and NMT state, GetNode shows it alive; when its answers stop (fault
//! injection on the virtual bus) a guarding loss is reported after about
//! the life time, and its next answer recovers it.

use cangate_client::pb;
use cangate_client::pb::node_event::Event;
use cangate_tests::*;
use std::time::{Duration, Instant};

const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"

[[canopen.node]]
id = 5
name = "guarded io"
eds = "builtin:io"
simulate = true
guard_time_ms = 100
life_time_factor = 3
"#;

const GUARD_TIME: Duration = Duration::from_millis(100);
const LIFE_TIME: Duration = Duration::from_millis(300);

async fn wait_event(
    s: &mut tonic::Streaming<pb::NodeEvent>,
    what: &str,
    pred: impl Fn(&pb::NodeEvent) -> bool,
) -> pb::NodeEvent {
    tokio::time::timeout(WAIT, async {
        loop {
            let ev = s.message().await.unwrap().expect("stream open");
            if pred(&ev) {
                return ev;
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("no {what} event in time"))
}

/// Frames on 0x705, the gateway's own requests included.
fn guarding_frames() -> pb::StreamFramesRequest {
    frames_on("can0", 0x705)
}

async fn set_drop_ids(c: &cangate_client::Client, ids: Vec<u32>) {
    pb::simulator_client::SimulatorClient::new(c.channel())
        .set_bus_faults(pb::SetBusFaultsRequest {
            bus: "can0".into(),
            drop_ids: ids,
            ..Default::default()
        })
        .await
        .expect("SetBusFaults");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_guarded_node_is_polled_lost_and_recovered() {
    let server = start_server(CONFIG).await;
    let mut c = client(&server).await;
    let mut events = node_events(&c, vec![5]).await;
    let (mut frames, mut pending) = open_stream(&mut c, guarding_frames()).await;

    // Requests (RTR, DLC 1) every guard time, each answered with one byte:
    // the toggle alternates, the state is pre-operational (0x7F).
    let seen = read_frames(&mut frames, &mut pending, 12).await;
    let requests: Vec<&pb::Frame> = seen.iter().filter(|f| f.remote).collect();
    let answers: Vec<&pb::Frame> = seen.iter().filter(|f| !f.remote).collect();
    assert!(requests.len() >= 5, "{seen:?}");
    assert!(
        requests.iter().all(|f| f.remote_dlc == 1),
        "requests have DLC 1: {requests:?}"
    );
    for w in requests.windows(2) {
        let gap = Duration::from_nanos(w[1].timestamp_ns - w[0].timestamp_ns);
        assert!(
            gap >= GUARD_TIME - Duration::from_millis(10) && gap <= GUARD_TIME * 3,
            "requests {gap:?} apart, guard time {GUARD_TIME:?}"
        );
    }
    assert!(answers.len() >= 4, "{seen:?}");
    for w in answers.windows(2) {
        assert_eq!(w[0].data.len(), 1);
        assert_eq!(w[0].data[0] & 0x7F, 0x7F, "pre-operational: {w:?}");
        assert_ne!(w[0].data[0] & 0x80, w[1].data[0] & 0x80, "toggle: {w:?}");
    }

    // GetNode: guarded, alive, with the state from the answers.
    let node = get_node(&c, 5).await;
    assert_eq!(node.monitoring, pb::LifeMonitoring::NodeGuarding as i32);
    assert_eq!((node.guard_time_ms, node.life_time_factor), (100, 3));
    assert_eq!(node.heartbeat_timeout_ms, 0);
    assert_eq!(node.state, pb::NmtState::PreOperational as i32);
    assert!(!node.heartbeat_lost);
    assert!(
        node.heartbeat_age_ms.is_some_and(|a| a <= 300),
        "age of the last answer: {node:?}"
    );

    // NMT start: the answers carry the new state.
    send_nmt(&c, 5, pb::NmtCommand::Start).await;
    wait_event(&mut events, "operational", |e| {
        matches!(&e.event, Some(Event::StateChanged(s)) if s.to == pb::NmtState::Operational as i32)
    })
    .await;
    assert_eq!(
        get_node(&c, 5).await.state,
        pb::NmtState::Operational as i32
    );

    // An answer with the toggle bit of the previous one (a duplicate sent
    // by someone else) is a toggle error: reported and counted.
    let port = server
        .gateway()
        .network()
        .get("can0")
        .unwrap()
        .connect(false);
    let last = loop {
        let f = read_frames(&mut frames, &mut pending, 1).await.remove(0);
        if !f.remote {
            break f.data[0];
        }
    };
    port.send(&cangate_can::Frame::new(cangate_can::CanId::Standard(0x705), &[last]).unwrap())
        .unwrap();
    let ev = wait_event(&mut events, "toggle error", |e| {
        matches!(e.event, Some(Event::GuardingToggleError(_)))
    })
    .await;
    let Some(Event::GuardingToggleError(t)) = ev.event else {
        unreachable!()
    };
    assert_eq!(t.data & 0x7F, 0x05, "{t:?}");
    assert_eq!(t.count, 1);
    assert_eq!(get_node(&c, 5).await.guarding_toggle_errors, 1);
    drop(frames);

    // The node's answers (and the requests) vanish: lost after about the
    // life time, reported as a guarding loss.
    let t0 = Instant::now();
    set_drop_ids(&c, vec![0x705]).await;
    let ev = wait_event(&mut events, "guarding lost", |e| {
        matches!(e.event, Some(Event::HeartbeatLost(_)))
    })
    .await;
    let silent = t0.elapsed();
    let Some(Event::HeartbeatLost(lost)) = ev.event else {
        unreachable!()
    };
    assert_eq!(lost.monitoring, pb::LifeMonitoring::NodeGuarding as i32);
    assert_eq!(lost.timeout_ms, 300);
    // The last answered request was at most one guard time before the
    // drop; the loss comes life time factor unanswered requests later.
    assert!(
        silent >= LIFE_TIME - GUARD_TIME && silent <= LIFE_TIME + GUARD_TIME * 6,
        "lost {silent:?} after the answers stopped (life time {LIFE_TIME:?})"
    );
    assert!(get_node(&c, 5).await.heartbeat_lost);

    // Answers again: recovered, in its state.
    set_drop_ids(&c, vec![]).await;
    let ev = wait_event(&mut events, "guarding recovered", |e| {
        matches!(e.event, Some(Event::HeartbeatRecovered(_)))
    })
    .await;
    let Some(Event::HeartbeatRecovered(back)) = ev.event else {
        unreachable!()
    };
    assert_eq!(back.monitoring, pb::LifeMonitoring::NodeGuarding as i32);
    assert_eq!(back.state, pb::NmtState::Operational as i32);
    assert!(back.silent_ms >= 200, "{back:?}");
    let node = get_node(&c, 5).await;
    assert!(!node.heartbeat_lost);
    assert_eq!(node.state, pb::NmtState::Operational as i32);
}

const LIFE_GUARDING: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"

[[canopen.node]]
id = 6
name = "guarded io, booted"
eds = "builtin:io"
simulate = true
boot = true
guard_time_ms = 100
life_time_factor = 3
"#;

/// Life guarding, the node's side: the boot procedure writes the guard
/// time and life time factor into 0x100C/0x100D, and when the master's
/// requests stop reaching the node it reports a life guard error (EMCY
/// 0x8130), and the error reset when they come back.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_booted_guarded_node_life_guards_the_master() {
    let server = start_server(LIFE_GUARDING).await;
    let c = client(&server).await;
    let mut events = node_events(&c, vec![6]).await;
    // Booted (maybe before the stream opened): started by the master.
    tokio::time::timeout(WAIT, async {
        while get_node(&c, 6).await.state != pb::NmtState::Operational as i32 {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("node 6 booted and started");
    let co = c.canopen("can0");
    let node = cangate_client::NodeId::new(6).unwrap();
    let read = |index| {
        let co = co.clone();
        async move {
            co.read_bytes(
                node,
                cangate_client::ObjectAddress::new(index, 0),
                Default::default(),
            )
            .await
            .unwrap()
        }
    };
    assert_eq!(
        read(0x100C).await,
        vec![100, 0],
        "guard time written at boot"
    );
    assert_eq!(
        read(0x100D).await,
        vec![3],
        "life time factor written at boot"
    );

    // The requests (and answers) vanish: the node's life guarding fires.
    set_drop_ids(&c, vec![0x706]).await;
    let ev = wait_event(
        &mut events,
        "life guard EMCY",
        |e| matches!(&e.event, Some(Event::Emcy(m)) if m.code == 0x8130),
    )
    .await;
    let Some(Event::Emcy(emcy)) = ev.event else {
        unreachable!()
    };
    assert_eq!(
        emcy.register & 0x11,
        0x11,
        "generic + communication: {emcy:?}"
    );
    // Requests again: the node resets the error.
    set_drop_ids(&c, vec![]).await;
    wait_event(
        &mut events,
        "EMCY error reset",
        |e| matches!(&e.event, Some(Event::Emcy(m)) if m.code == 0),
    )
    .await;
}

#[test]
fn guarding_keys_are_validated() {
    let cfg = |node: &str| {
        cangate_server::Config::from_toml(&format!(
            "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\n[[canopen]]\nbus = \"can0\"\n\
             [[canopen.node]]\nid = 5\n{node}"
        ))
    };
    let err = |node: &str| cfg(node).unwrap_err().to_string();
    assert!(err("guard_time_ms = 100").contains("needs life_time_factor"));
    assert!(err("life_time_factor = 3").contains("needs guard_time_ms"));
    assert!(
        err("guard_time_ms = 100\nlife_time_factor = 3\nheartbeat_timeout_ms = 300")
            .contains("exclude each other")
    );
    assert!(
        err("guard_time_ms = 100\nlife_time_factor = 3\nheartbeat_producer_ms = 100")
            .contains("exclude each other")
    );
    assert!(err("guard_time_ms = 70000\nlife_time_factor = 3").contains("out of range"));
    let c = cfg("guard_time_ms = 100\nlife_time_factor = 3").unwrap();
    assert_eq!(
        c.canopen[0].nodes[0].guarding(),
        Some((Duration::from_millis(100), 3))
    );
}
