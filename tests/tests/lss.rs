//! LSS (CiA 305) end to end on the virtual bus, with the real client: two
//! simulated devices start without a node-ID (`sim_lss`); fastscan finds
//! both; one is given node-ID 20, which the configuration expects (with a
//! boot procedure), stores it, boots up as node 20 and is booted by the
//! master (BootCompleted, GetNode operational), and keeps its id over an
//! NMT reset node; the other is given an id the configuration does not
//! know, without storing: its boot-up is a node event, and an NMT reset
//! node takes the id away again. Also: silence (timeouts), invalid ids,
//! unknown buses, and two LSS calls at once on one bus.

use cangate_client::pb;
use cangate_client::pb::node_event::Event;
use cangate_client::{Error, LssDevice, NodeId};
use cangate_tests::*;
use std::time::{Duration, Instant};

/// The identity of builtin:io (0x1018:01..=03 of its EDS) with two serials.
const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"

[[canopen.node]]
id = 20
name = "io, given its id by LSS"
eds = "builtin:io"
simulate = true
boot = true
heartbeat_timeout_ms = 1000
sim_lss = { serial = 0xCAFE }

[[canopen.node]]
id = 21
name = "another unconfigured io"
eds = "builtin:io"
simulate = true
sim_lss = { serial = 0xBEEF }
"#;

/// A bus with a CANopen master and no LSS device (and the metrics
/// endpoint).
const SILENT: &str = r#"
metrics_listen = "127.0.0.1:0"

[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"
"#;

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

fn refused_reason(e: &Error) -> Option<&str> {
    match e {
        Error::Refused { reason, .. } => Some(reason),
        _ => None,
    }
}

/// The embedded demo has one device without a node-ID, so that the
/// README's `cangate lss scan can0` and `lss set-id can0 --serial 0xCAFE 20`
/// work on it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_demo_has_a_device_for_lss() {
    let mut config = cangate_server::Config::demo();
    config.listen = "127.0.0.1:0".parse().unwrap();
    config.cansmc.clear();
    config.buses.retain(|b| b.name == "can0");
    let server = cangate_server::start(&config).await.expect("demo starts");
    let c = client(&server).await;
    let lss = c.lss("can0");
    let found = lss.fastscan(None).await.expect("fastscan");
    assert_eq!(
        found.iter().map(|i| i.serial).collect::<Vec<_>>(),
        vec![0xCAFE],
        "{found:?}"
    );
    lss.assign_node_id(LssDevice::Serial(0xCAFE), NodeId::new(20).unwrap(), true)
        .await
        .expect("assign node-ID 20");
    let deadline = Instant::now() + WAIT;
    while get_node(&c, 20).await.state != pb::NmtState::Operational as i32 {
        assert!(Instant::now() < deadline, "demo node 20 never operational");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unconfigured_nodes_are_found_given_ids_and_booted() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let lss = c.lss("can0");
    let mut events = node_events(&c, vec![]).await;

    // Both devices are silent: no boot-up, no SDO.
    assert!(lss.identify_non_configured().await.unwrap());
    let started = Instant::now();
    let found = lss.fastscan(None).await.expect("fastscan");
    let scan_time = started.elapsed();
    let serials: Vec<u32> = found.iter().map(|i| i.serial).collect();
    assert_eq!(serials, vec![0xBEEF, 0xCAFE], "lowest first: {found:?}");
    let io = found[1];
    assert_eq!(found[0].vendor_id, io.vendor_id);
    assert!(io.vendor_id != 0, "the EDS's vendor id: {io:?}");
    eprintln!("fastscan of 2 devices: {scan_time:?}");

    // Node 20 is expected by the configuration: assign, store, boot.
    let r = lss
        .assign_node_id(LssDevice::Serial(0xCAFE), NodeId::new(20).unwrap(), true)
        .await
        .expect("assign node-ID 20");
    assert_eq!(r.previous_node_id, 255);
    assert_eq!((r.node_id, r.stored), (20, true));
    assert_eq!(r.identity, Some(io));
    wait_event(&mut events, "boot-up of node 20", |e| {
        e.node == 20 && matches!(e.event, Some(Event::BootUp(_)))
    })
    .await;
    wait_event(&mut events, "boot completed of node 20", |e| {
        e.node == 20 && matches!(e.event, Some(Event::BootCompleted(_)))
    })
    .await;
    // Started by the boot procedure: its heartbeats say operational.
    let deadline = Instant::now() + WAIT;
    let node = loop {
        let node = get_node(&c, 20).await;
        if node.state == pb::NmtState::Operational as i32 {
            break node;
        }
        assert!(
            Instant::now() < deadline,
            "node 20 never operational: {node:?}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    assert!(node.configured);
    let id = node.identity.expect("identity read at boot");
    assert_eq!(id.serial, 0xCAFE);

    // Inquire the configured device by identity: node-ID 20.
    let (got, node_id) = lss.inquire(Some(io)).await.expect("inquire");
    assert_eq!((got, node_id), (io, 20));
    // Only the other one is left unconfigured.
    let found = lss.fastscan(None).await.expect("second fastscan");
    assert_eq!(
        found.iter().map(|i| i.serial).collect::<Vec<_>>(),
        vec![0xBEEF]
    );

    // Stored: an NMT reset node brings it back as node 20.
    send_nmt(&c, 20, pb::NmtCommand::ResetNode).await;
    wait_event(&mut events, "boot-up after reset node", |e| {
        e.node == 20 && matches!(e.event, Some(Event::BootUp(_)))
    })
    .await;

    // The other one at an id nobody configured, not stored.
    let other = found[0];
    let r = lss
        .assign_node_id(LssDevice::Identity(other), NodeId::new(42).unwrap(), false)
        .await
        .expect("assign node-ID 42");
    assert!(!r.stored);
    wait_event(&mut events, "boot-up of the unknown node 42", |e| {
        e.node == 42 && matches!(e.event, Some(Event::BootUp(_)))
    })
    .await;
    let node = get_node(&c, 42).await;
    assert!(!node.configured, "heard of, not configured: {node:?}");
    // Not stored: reset node takes the id away; it is found again.
    send_nmt(&c, 42, pb::NmtCommand::ResetNode).await;
    let deadline = Instant::now() + WAIT;
    loop {
        let found = lss.fastscan(None).await.expect("fastscan");
        if found.iter().any(|i| i.serial == 0xBEEF) {
            break;
        }
        assert!(Instant::now() < deadline, "node 42 never lost its id");
    }
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn silence_is_a_timeout_and_bad_requests_are_refused() {
    let server = start_server(SILENT).await;
    let c = client(&server).await;
    let lss = c.lss("can0");
    // Nobody there: fastscan finds nothing (one step), identify says no.
    let started = Instant::now();
    assert!(lss.fastscan(None).await.unwrap().is_empty());
    assert!(started.elapsed() < Duration::from_secs(2));
    assert!(!lss.identify_non_configured().await.unwrap());
    // A confirmed command without an answer: DEADLINE_EXCEEDED.
    let e = lss.inquire(None).await.unwrap_err();
    assert!(matches!(e, Error::Timeout { .. }), "{e:?}");
    let e = lss
        .assign_node_id(
            LssDevice::Identity(pb::LssIdentity {
                vendor_id: 1,
                product_code: 2,
                revision: 3,
                serial: 4,
            }),
            NodeId::new(5).unwrap(),
            true,
        )
        .await
        .unwrap_err();
    assert!(matches!(e, Error::Timeout { .. }), "{e:?}");
    // By serial: fastscan finds no such device.
    let e = lss
        .assign_node_id(LssDevice::Serial(9), NodeId::new(5).unwrap(), true)
        .await
        .unwrap_err();
    assert!(matches!(e, Error::NotFound { .. }), "{e:?}");

    // Invalid ids and arguments: INVALID_ARGUMENT before anything is sent.
    let mut raw = c.lss_client();
    for node_id in [0, 128, 254, 1000] {
        let s = raw
            .configure_node_id(pb::ConfigureNodeIdRequest {
                bus: "can0".into(),
                node_id,
                timeout_ms: 0,
                force: false,
            })
            .await
            .unwrap_err();
        assert_eq!(s.code(), tonic::Code::InvalidArgument, "{node_id}: {s:?}");
    }
    for node_id in [0, 128] {
        let s = raw
            .assign_node_id(pb::AssignNodeIdRequest {
                bus: "can0".into(),
                device: Some(pb::assign_node_id_request::Device::Serial(1)),
                node_id,
                store: false,
                timeout_ms: 0,
                force: false,
            })
            .await
            .unwrap_err();
        assert_eq!(s.code(), tonic::Code::InvalidArgument, "{node_id}: {s:?}");
    }
    let s = raw
        .fastscan(pb::FastscanRequest {
            bus: "can0".into(),
            step_time_ms: 5000,
            max_devices: 0,
        })
        .await
        .unwrap_err();
    assert_eq!(s.code(), tonic::Code::InvalidArgument);
    // Unknown bus: NOT_FOUND.
    let e = c.lss("nope").fastscan(None).await.unwrap_err();
    assert!(matches!(e, Error::NotFound { .. }), "{e:?}");

    // The commands are counted by result.
    let metrics = scrape_metrics(server.metrics_addr.expect("metrics configured")).await;
    let line = |command: &str, result: &str| {
        metrics.lines().find(|l| {
            l.starts_with("cangate_lss_commands_total{")
                && l.contains(&format!("command=\"{command}\""))
                && l.contains(&format!("result=\"{result}\""))
        })
    };
    assert!(line("inquire", "timeout").is_some(), "{metrics}");
    assert!(line("fastscan", "ok").is_some(), "{metrics}");
    assert!(line("switch state global", "ok").is_some(), "{metrics}");
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_lss_operation_per_bus_at_a_time() {
    let server = start_server(CONFIG).await;
    let mut c = client(&server).await;
    let lss = c.lss("can0");
    // The master's LSS requests (0x7E5), to see the fastscan under way
    // before probing: a probe sent first would hold the bus's LSS itself
    // and refuse the scan instead.
    let (mut lss_requests, mut pending) = open_stream(&mut c, frames_on("can0", 0x7E5)).await;
    // A fastscan of two devices takes a few hundred steps; meanwhile every
    // other LSS call on the bus is refused with LSS_BUSY.
    let scan = tokio::spawn({
        let lss = lss.clone();
        async move { lss.fastscan(None).await }
    });
    const FASTSCAN: u8 = 0x51; // CiA 305 command specifier
    while read_frames(&mut lss_requests, &mut pending, 1).await[0].data[0] != FASTSCAN {}
    let deadline = Instant::now() + WAIT;
    let busy = loop {
        match lss.identify_non_configured().await {
            Err(e) if refused_reason(&e) == Some("LSS_BUSY") => break e,
            Err(e) => panic!("unexpected {e:?}"),
            Ok(_) => {
                assert!(Instant::now() < deadline, "never busy");
                tokio::time::sleep(Duration::from_millis(5)).await;
            }
        }
    };
    match &busy {
        Error::Refused { code, message, .. } => {
            assert_eq!(*code, tonic::Code::FailedPrecondition);
            assert!(message.contains("fastscan"), "{message}");
        }
        other => panic!("{other:?}"),
    }
    let e = lss
        .assign_node_id(LssDevice::Serial(0xCAFE), NodeId::new(20).unwrap(), false)
        .await
        .unwrap_err();
    assert_eq!(refused_reason(&e), Some("LSS_BUSY"), "{e:?}");
    // The scan itself was not disturbed.
    let found = scan.await.unwrap().expect("fastscan");
    assert_eq!(found.len(), 2, "{found:?}");
    // Free again.
    assert!(lss.identify_non_configured().await.unwrap());
    server.shutdown();
}

#[test]
fn sim_lss_is_validated() {
    let cfg = |node: &str| {
        cangate_server::Config::from_toml(&format!(
            "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\n[[canopen]]\nbus = \"can0\"\n\
             [[canopen.node]]\nid = 5\neds = \"builtin:io\"\n{node}"
        ))
    };
    let err = |node: &str| cfg(node).unwrap_err().to_string();
    assert!(err("sim_lss = { serial = 1 }").contains("add simulate = true"));
    assert!(err("simulate = true\nsim_lss = { }").contains("serial"));
    assert!(err("simulate = true\nsim_lss = { serial = 1, colour = 2 }").contains("colour"));
    let c = cfg("simulate = true\nsim_lss = { serial = 0xCAFE, vendor_id = 7 }").unwrap();
    let l = c.canopen[0].nodes[0].sim_lss.as_ref().unwrap();
    assert_eq!(
        (l.serial, l.vendor_id, l.configured),
        (0xCAFE, Some(7), false)
    );
}

/// The single commands, step by step as a tool would send them: the
/// devices stay in their LSS state between calls.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn single_commands_step_by_step_and_refusals() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let lss = c.lss("can0");
    let mut raw = c.lss_client();
    let mut events = node_events(&c, vec![]).await;
    let found = lss.fastscan(None).await.unwrap();
    let cafe = *found.iter().find(|i| i.serial == 0xCAFE).unwrap();

    // Identify remote: a range around the serial, and one beside it.
    let identify = |low: u32, high: u32| pb::IdentifyRemoteRequest {
        bus: "can0".into(),
        vendor_id: cafe.vendor_id,
        product_code: cafe.product_code,
        revision_low: 0,
        revision_high: u32::MAX,
        serial_low: low,
        serial_high: high,
        timeout_ms: 100,
    };
    let r = raw.identify_remote(identify(0xC000, 0xCFFF)).await.unwrap();
    assert!(r.into_inner().present);
    let r = raw.identify_remote(identify(0xD000, 0xDFFF)).await.unwrap();
    assert!(!r.into_inner().present);

    // Select one device, configure it, step by step.
    lss.switch_selective(cafe).await.expect("switch selective");
    lss.configure_bit_timing(0, 3).await.expect("250 kbit/s");
    // Index 5 is reserved in the CiA 301 table: the device refuses (1).
    let e = lss.configure_bit_timing(0, 5).await.unwrap_err();
    match &e {
        cangate_client::Error::Refused {
            code,
            reason,
            status,
            ..
        } => {
            assert_eq!(
                (*code, reason.as_str()),
                (tonic::Code::FailedPrecondition, "LSS_REFUSED")
            );
            assert!(status.message().contains("error 1"), "{status:?}");
        }
        other => panic!("{other:?}"),
    }
    lss.activate_bit_timing(100).await.expect("unconfirmed");
    lss.configure_node_id(33).await.expect("configure node-ID");
    lss.store_configuration().await.expect("store");
    // Back to waiting: the unconfigured device takes node-ID 33.
    lss.switch_global(pb::LssMode::Waiting).await.unwrap();
    wait_event(&mut events, "boot-up of node 33", |e| {
        e.node == 33 && matches!(e.event, Some(Event::BootUp(_)))
    })
    .await;
    // A device that has a node-ID: AssignNodeId moves it with NMT reset
    // communication.
    let r = lss
        .assign_node_id(LssDevice::Identity(cafe), NodeId::new(34).unwrap(), true)
        .await
        .expect("move 33 to 34");
    assert_eq!(r.previous_node_id, 33);
    wait_event(&mut events, "boot-up of node 34", |e| {
        e.node == 34 && matches!(e.event, Some(Event::BootUp(_)))
    })
    .await;
    server.shutdown();
}

/// Node 1: an I/O module that runs (boot-up, heartbeat). Node 30: a drive
/// the configuration expects, not there. Node 3: axis X's drive. Two
/// unconfigured I/O devices (0xCAFE, 0xBEEF) for the ids.
const IN_USE: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"
sdo_timeout_ms = 200

[[canopen.node]]
id = 1
eds = "builtin:io"
simulate = true

[[canopen.node]]
id = 3
eds = "builtin:drive"
simulate = true

[[canopen.node]]
id = 30
eds = "builtin:drive"

[[canopen.node]]
id = 20
eds = "builtin:io"
simulate = true
sim_lss = { serial = 0xCAFE }

[[canopen.node]]
id = 21
eds = "builtin:io"
simulate = true
sim_lss = { serial = 0xBEEF }

[[axis]]
name = "X"
bus = "can0"
node = 3
counts_per_unit = 1000.0
max_velocity = 50.0
max_acceleration = 500.0
process_data = "sdo"
sdo_poll_ms = 5
"#;

fn refusal(e: &Error) -> (&str, &str) {
    match e {
        Error::Refused {
            code,
            reason,
            message,
            ..
        } => {
            assert_eq!(*code, tonic::Code::FailedPrecondition, "{e:?}");
            (reason, message)
        }
        other => panic!("not refused: {other:?}"),
    }
}

/// `lss set-id --serial 0xCAFE 1` while node 1 runs made a second node 1.
/// An id heard on the bus, an axis's drive's, or configured for a device
/// of another identity is refused (NODE_ID_IN_USE, nothing configured);
/// forced, it is given; a free id is given as before.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_id_in_use_is_refused_unless_forced() {
    let server = start_server(IN_USE).await;
    let c = client(&server).await;
    let lss = c.lss("can0");
    let id = |n| NodeId::new(n).unwrap();
    // Node 1 has been heard (its boot-up and heartbeat).
    let deadline = Instant::now() + WAIT;
    while get_node(&c, 1).await.state != pb::NmtState::PreOperational as i32
        && get_node(&c, 1).await.state != pb::NmtState::Operational as i32
    {
        assert!(Instant::now() < deadline, "node 1 never heard");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }

    let e = lss
        .assign_node_id(LssDevice::Serial(0xCAFE), id(1), false)
        .await
        .unwrap_err();
    let (reason, message) = refusal(&e);
    assert_eq!(reason, "NODE_ID_IN_USE");
    assert!(message.contains("node 1 sent a frame"), "{message}");
    let e = lss
        .assign_node_id(LssDevice::Serial(0xCAFE), id(3), false)
        .await
        .unwrap_err();
    let (reason, message) = refusal(&e);
    assert_eq!(reason, "NODE_ID_IN_USE");
    assert!(message.contains("axis X"), "{message}");
    // Configured for a drive (product 0x402); this is an I/O module.
    let e = lss
        .assign_node_id(LssDevice::Serial(0xCAFE), id(30), false)
        .await
        .unwrap_err();
    let (reason, message) = refusal(&e);
    assert_eq!(reason, "NODE_ID_IN_USE");
    assert!(message.contains("product 0x00000402"), "{message}");
    // Nothing was given: both devices are still unconfigured, node 1 is
    // still the I/O module it was.
    let found = lss.fastscan(Some(Duration::from_millis(5))).await.unwrap();
    assert_eq!(found.len(), 2, "{found:?}");
    let serial = c
        .canopen("can0")
        .read(
            id(1),
            cangate_client::ObjectAddress::new(0x1018, 4),
            cangate_client::DataType::Unsigned32,
        )
        .await
        .unwrap();
    assert_ne!(serial, cangate_client::SdoValue::U32(0xCAFE));

    // The id it is configured for: given.
    lss.assign_node_id(LssDevice::Serial(0xCAFE), id(20), false)
        .await
        .expect("node-ID 20");
    // Forced: an engineer's decision.
    let r = lss
        .assign_node_id_forced(LssDevice::Serial(0xBEEF), id(30), false)
        .await
        .expect("forced node-ID 30");
    assert_eq!(r.node_id, 30);
}

/// While axis X is enabled, LSS commands that reach every device (or
/// whichever is in the configuration state) are refused with AXIS_ACTIVE
/// naming the axis; fastscan and identify, which only reach unconfigured
/// devices, run.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lss_that_reaches_an_enabled_axis_drive_is_refused() {
    use cangate_tests::axes::*;
    let server = start_server(IN_USE).await;
    let c = client(&server).await;
    let mut axes = c.axes_client();
    wait_status(&mut axes, "X", |s| s.state != 0 && !s.node_lost).await;
    let lease = acquire(&mut axes, &["X"], 10_000, "test").await;
    enable(&mut axes, "X", &lease).await;
    let lss = c.lss("can0");

    let e = lss
        .switch_global(pb::LssMode::Configuration)
        .await
        .unwrap_err();
    let (reason, message) = refusal(&e);
    assert_eq!(reason, "AXIS_ACTIVE");
    assert!(message.contains("axis X"), "{message}");
    let e = lss.inquire(None).await.unwrap_err();
    assert_eq!(refusal(&e).0, "AXIS_ACTIVE");
    let e = lss.configure_node_id(40).await.unwrap_err();
    assert_eq!(refusal(&e).0, "AXIS_ACTIVE");
    assert!(lss.identify_non_configured().await.unwrap());
    let found = lss.fastscan(Some(Duration::from_millis(5))).await.unwrap();
    assert_eq!(found.len(), 2, "{found:?}");

    let r = axes
        .disable(cmd("X", &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    lss.switch_global(pb::LssMode::Configuration)
        .await
        .expect("no axis active");
    lss.switch_global(pb::LssMode::Waiting).await.unwrap();
}

/// Two devices that answer fastscan until they have a node-ID, as
/// CANopenNode's LSS slave does, and a bus with bit timing.
const ANSWERING: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[bus]]
name = "slow"
backend = "virtual"
bitrate = 125000
bit_timing = true

[[canopen]]
bus = "can0"

[[canopen.node]]
id = 20
eds = "builtin:io"
simulate = true
sim_lss = { serial = 0xCAFE, fastscan_until_configured = true }

[[canopen.node]]
id = 21
eds = "builtin:io"
simulate = true
sim_lss = { serial = 0xBEEF, fastscan_until_configured = true }

[[canopen]]
bus = "slow"
"#;

/// A scan ends when it finds a device again, listing it once; the device
/// it hides is found once the first has its id; set-id by serial gives
/// each its id; a step the bus cannot answer in is refused.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn devices_answering_until_configured_are_scanned_and_given_ids() {
    let server = start_server(ANSWERING).await;
    let c = client(&server).await;
    let lss = c.lss("can0");
    let step = Some(Duration::from_millis(5));
    let serials = |found: Vec<pb::LssIdentity>| found.iter().map(|i| i.serial).collect::<Vec<_>>();

    // 0xBEEF, the lower, answers again and again: found once, the scan
    // ends (bounded by WAIT here; without the fix it ran 32 searches).
    let found = tokio::time::timeout(WAIT, lss.fastscan(step))
        .await
        .expect("the scan ends")
        .unwrap();
    assert_eq!(serials(found), vec![0xBEEF]);
    // 0xCAFE is hidden behind it: not found, and the message says why.
    let e = lss
        .assign_node_id(LssDevice::Serial(0xCAFE), NodeId::new(20).unwrap(), false)
        .await
        .unwrap_err();
    assert_eq!(e.code(), Some(tonic::Code::NotFound), "{e:?}");
    assert!(
        format!("{e:?}").contains("keeps answering fastscan"),
        "{e:?}"
    );
    let mut events = node_events(&c, vec![]).await;
    for (serial, node) in [(0xBEEF, 21u32), (0xCAFE, 20)] {
        let r = lss
            .assign_node_id(LssDevice::Serial(serial), NodeId::new(node).unwrap(), false)
            .await
            .unwrap_or_else(|e| panic!("serial 0x{serial:X}: {e:?}"));
        assert_eq!(r.node_id, node);
        wait_event(&mut events, "the boot-up", |e| {
            e.node == node && matches!(e.event, Some(Event::BootUp(_)))
        })
        .await;
        if serial == 0xBEEF {
            let found = lss.fastscan(step).await.unwrap();
            assert_eq!(serials(found), vec![0xCAFE], "the hidden one");
        }
    }
    assert!(lss.fastscan(step).await.unwrap().is_empty());

    // 1 ms at 125 kbit/s: two frames alone take 2.2 ms.
    let e = c
        .lss("slow")
        .fastscan(Some(Duration::from_millis(1)))
        .await
        .unwrap_err();
    assert_eq!(e.code(), Some(tonic::Code::InvalidArgument), "{e:?}");
    assert!(e.to_string().contains("at least 5 ms"), "{e}");
    c.lss("slow")
        .fastscan(Some(Duration::from_millis(5)))
        .await
        .expect("5 ms is enough");
}
