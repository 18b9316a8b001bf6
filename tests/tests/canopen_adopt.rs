//! A (re)started gateway next to a running machine: the simulated devices
//! were running before the gateway started (`sim = { start = … }`), so no
//! boot-up is heard. The master boots every configured node by SDO all
//! the same (CiA 302): identity read and checked, configuration written,
//! NMT start; a drive found in operation enabled is adopted without being
//! disabled (its axis shows it enabled at its position and moves it
//! without an Enable). A node with heartbeat 0 is shown in its state; a
//! node that refuses NMT start is reported as such, not as started.

use cangate_client::pb;
use cangate_client::pb::node_event::Event;
use cangate_tests::axes::*;
use cangate_tests::*;
use std::time::Duration;

const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"
sync_period_us = 10000

# A drive enabled and holding at 12.345 mm before the gateway started.
[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true
heartbeat_timeout_ms = 1000
vendor_id = 0x000004D2
sim = { start = "operation_enabled", position = 12345 }
[[canopen.node.write]]
object = "0x6081:0"
type = "u32"
value = "2500"

# An I/O node running without a heartbeat (0x1017 = 0).
[[canopen.node]]
id = 3
eds = "builtin:io"
simulate = true
boot = true
sim = { start = "operational", heartbeat_ms = 0 }

# Pre-operational, with a heartbeat, and refusing to start.
[[canopen.node]]
id = 4
eds = "builtin:io"
simulate = true
boot = true
heartbeat_timeout_ms = 1000
sim = { start = "pre_operational", refuses_nmt_start = true }

# Boots with the gateway, no heartbeat, refusing to start: node guarding
# tells.
[[canopen.node]]
id = 5
eds = "builtin:io"
simulate = true
boot = true
sim = { heartbeat_ms = 0, refuses_nmt_start = true }

# Watched only (no boot, no axis): identified, never started.
[[canopen.node]]
id = 9
eds = "builtin:io"
simulate = true
heartbeat_timeout_ms = 1000
sim = { start = "pre_operational" }

# Running, no heartbeat, no node guarding: only SDO answers.
[[canopen.node]]
id = 6
eds = "builtin:io"
simulate = true
boot = true
sim = { start = "operational", heartbeat_ms = 0, node_guarding = false }

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

/// Polls GetNode (bounded by [`WAIT`]) until `f` holds.
async fn wait_node(
    c: &cangate_client::Client,
    node: u32,
    f: impl Fn(&pb::Node) -> bool,
) -> pb::Node {
    let t0 = std::time::Instant::now();
    loop {
        let n = get_node(c, node).await;
        if f(&n) {
            return n;
        }
        assert!(t0.elapsed() < WAIT, "node {node}: {n:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn running_nodes_are_booted_and_a_running_drive_is_adopted() {
    let server = start_server(CONFIG).await;
    let mut c = client(&server).await;
    // Everything the gateway sends to node 1's controlword and to NMT.
    let (mut frames, mut pending) = open_stream(
        &mut c,
        pb::StreamFramesRequest {
            filters: vec![standard_id(0x000), standard_id(0x201)],
            ..frames_on("can0", 0x000)
        },
    )
    .await;
    let mut events = node_events(&c, vec![]).await;

    // Node 1: identity read and checked, configuration written, started;
    // boot completed although it never sent a boot-up.
    let node1 = wait_node(&c, 1, |n| {
        n.identity.is_some() && n.state == pb::NmtState::Operational as i32
    })
    .await;
    assert_eq!(node1.identity.unwrap().vendor_id, 0x4D2);
    assert_eq!(node1.boot_ups, 0);
    let velocity = c
        .clone()
        .read_sdo(pb::ReadSdoRequest {
            bus: "can0".into(),
            node: 1,
            index: 0x6081,
            subindex: 0,
            r#type: 0,
            options: None,
            object: String::new(),
        })
        .await
        .unwrap();
    assert_eq!(velocity.raw, 2500u32.to_le_bytes());

    // Its axis shows the drive as it is: enabled, at 12.345 mm, holding.
    let mut axes = c.axes_client();
    let s = wait_status(&mut axes, "X", |s| {
        s.state == pb::DriveState::OperationEnabled as i32
    })
    .await;
    assert!((s.position - 12.345).abs() < 0.01, "{s:?}");
    assert!(!s.node_lost, "{s:?}");
    // And moves it without an Enable: it was never disabled.
    let lease = acquire(&mut axes, &["X"], 10_000, "adopt test").await;
    let r = axes
        .r#move(pb::MoveRequest {
            axis: "X".into(),
            target: 13.0,
            relative: false,
            velocity: 10.0,
            acceleration: 100.0,
            options: opts(&lease, true),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    let s = r.status.unwrap();
    assert_eq!(s.state, pb::DriveState::OperationEnabled as i32);
    assert!((s.position - 13.0).abs() < 0.05, "{s:?}");

    // Node 3 (heartbeat 0): identity read, shown operational (its node
    // guarding answer says so).
    let node3 = wait_node(&c, 3, |n| n.state == pb::NmtState::Operational as i32).await;
    assert!(node3.identity.is_some(), "{node3:?}");
    assert!(node3.heartbeat_age_ms.is_none(), "no heartbeat: {node3:?}");
    // Node 6 (heartbeat 0, no node guarding): started, shown operational.
    let node6 = wait_node(&c, 6, |n| n.state == pb::NmtState::Operational as i32).await;
    assert!(node6.identity.is_some(), "{node6:?}");

    // Node 9, watched only: its identity is shown, and it was left
    // pre-operational (no NMT start).
    let node9 = wait_node(&c, 9, |n| n.identity.is_some()).await;
    assert_eq!(
        node9.state,
        pb::NmtState::PreOperational as i32,
        "{node9:?}"
    );

    // Nothing the gateway sent reset a node or took the drive out of
    // operation enabled (the move's controlwords included).
    let mut seen = Vec::new();
    while let Ok(Ok(Some(msg))) =
        tokio::time::timeout(Duration::from_millis(100), frames.message()).await
    {
        pending.extend(msg.events);
    }
    for ev in pending {
        if let Some(pb::stream_event::Event::Frame(f)) = ev.event {
            seen.push((f.id, f.data));
        }
    }
    for (id, data) in &seen {
        match id {
            0x000 => assert!(
                !matches!(data[0], 0x81 | 0x82),
                "an NMT reset went out: {data:02X?}"
            ),
            _ => {
                let cw = u16::from_le_bytes([data[0], data[1]]);
                assert_eq!(cw & 0x0F, 0x0F, "controlword {cw:#06x} sent to the drive");
            }
        }
    }

    // Nodes 4 and 5 refuse NMT start: they stay pre-operational (4 by its
    // heartbeat, 5 by node guarding), and their boot says so rather than
    // "started". Reset (the event stream may have opened after their
    // first boot), each boots up and is booted again.
    for n in [4, 5] {
        let node = wait_node(&c, n, |n| n.state == pb::NmtState::PreOperational as i32).await;
        assert!(node.identity.is_some(), "{node:?}");
        send_nmt(&c, n, pb::NmtCommand::ResetNode).await;
    }
    let mut failed = std::collections::BTreeMap::new();
    tokio::time::timeout(WAIT, async {
        while failed.len() < 2 {
            let ev = events.message().await.unwrap().expect("stream open");
            match ev.event {
                Some(Event::BootFailed(f)) => {
                    failed.insert(ev.node, f.reason);
                }
                Some(Event::BootCompleted(_)) => {
                    assert!(
                        ![4, 5].contains(&ev.node),
                        "node {} reported started",
                        ev.node
                    )
                }
                _ => {}
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("boot results: failed {failed:?}"));
    assert_eq!(failed.keys().copied().collect::<Vec<_>>(), [4, 5]);
    for reason in failed.values() {
        assert!(reason.contains("still reports pre-operational"), "{reason}");
    }
    for n in [4, 5] {
        let node = get_node(&c, n).await;
        assert_eq!(node.state, pb::NmtState::PreOperational as i32, "{node:?}");
    }
    server.shutdown();
}

/// Two running I/O nodes the gateway cannot reach at its start (their
/// answers are dropped, as on a disconnected segment): both are found
/// absent. Reconnected, neither sends a boot-up; the one with a heartbeat
/// is booted as soon as it is heard, the one without at the next retry.
const UNREACHABLE_AT_START: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"
drop_ids = [0x587, 0x588, 0x708]

[[canopen]]
bus = "can0"
sdo_timeout_ms = 200

[[canopen.node]]
id = 7
eds = "builtin:io"
simulate = true
boot = true
sim = { start = "operational", heartbeat_ms = 0, node_guarding = false }

[[canopen.node]]
id = 8
eds = "builtin:io"
simulate = true
boot = true
heartbeat_timeout_ms = 1000
sim = { start = "operational", heartbeat_ms = 100 }
"#;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nodes_absent_at_the_start_are_booted_when_heard_or_at_the_next_retry() {
    let log = cangate_tests::log::capture_log("cangate_server::canopen::boot=info");
    let server = start_server(UNREACHABLE_AT_START).await;
    let vbus = server.gateway().network().get("can0").unwrap();
    let c = client(&server).await;
    // Both boots end with nothing found.
    let t0 = std::time::Instant::now();
    let absent = |node: u32| {
        let text = log.text();
        text.lines()
            .any(|l| l.contains(&format!("node{{node={node}}}")) && l.contains("does not answer"))
    };
    while !(absent(7) && absent(8)) {
        assert!(t0.elapsed() < WAIT, "{}", log.text());
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(get_node(&c, 7).await.identity.is_none());
    assert!(get_node(&c, 8).await.identity.is_none());

    // Reconnected: no boot-up, yet both are checked and adopted.
    vbus.set_drop_ids([]);
    for node in [7, 8] {
        let n = wait_node(&c, node, |n| {
            n.identity.is_some() && n.state == pb::NmtState::Operational as i32
        })
        .await;
        assert_eq!(n.boot_ups, 0, "{n:?}");
    }
}
