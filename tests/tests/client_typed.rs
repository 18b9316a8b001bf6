//! The typed client library end to end: the real server in-process on a
//! virtual bus with simulated drives, driven through `cangate_client`'s
//! typed methods (no generated stubs): SDO values of several types, SDO
//! aborts and timeouts decoded from the richer error model, NOT_FOUND,
//! the control lease guard (renewal past its TTL, loss, release on drop),
//! streams, and connecting (address without scheme, a silent listener).

mod common;

use cangate_client::{
    AxisUpdate, Client, ConnectOptions, DataType, Error, FrameEvent, FrameStreamOptions, NodeId,
    ObjectAddress, SdoOptions, SdoValue, can, pb,
};
use common::*;
use futures::StreamExt;
use std::time::{Duration, Instant};
use tonic::Code;

const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"
sync_period_us = 5000
sdo_timeout_ms = 200

[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true
heartbeat_timeout_ms = 300

[[canopen.node]]
id = 2
name = "spare drive"
eds = "builtin:drive"
simulate = true

[[canopen.node]]
id = 10
name = "absent"

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

fn node(id: u32) -> NodeId {
    NodeId::new(id).unwrap()
}

fn addr(text: &str) -> ObjectAddress {
    text.parse().unwrap()
}

/// A typed client of the server, connected by `host:port` (no scheme).
async fn typed_client(server: &cangate_server::RunningServer) -> Client {
    cangate_client::connect_with(
        &server.addr.to_string(),
        &ConnectOptions {
            request_timeout: Some(WAIT),
            ..Default::default()
        },
    )
    .await
    .expect("client connects without a scheme")
}

/// Waits (bounded) until axis X has process data from its booted drive.
async fn wait_ready(c: &Client) {
    let t0 = Instant::now();
    loop {
        let s = c.axis_status("X").await.unwrap();
        if !s.node_lost && s.state != cangate_client::DriveState::Unspecified as i32 {
            return;
        }
        assert!(t0.elapsed() < WAIT, "axis X never became ready: {s:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn typed_sdo_values_of_several_types() {
    let server = start_server(CONFIG).await;
    let c = typed_client(&server).await;
    let can0 = c.canopen("can0");
    let n2 = node(2);

    // Reads, typed by the request.
    let v = can0
        .read(n2, addr("0x1000"), DataType::Unsigned32)
        .await
        .unwrap();
    assert!(matches!(v, SdoValue::U32(t) if t & 0xFFFF == 402), "{v:?}");
    let v = can0
        .read(n2, addr("0x1008:00"), DataType::VisibleString)
        .await
        .unwrap();
    assert_eq!(v, SdoValue::VisibleString("cangate sim drive".into()));
    // Untyped: the gateway types it from the node's EDS.
    let v = can0
        .read(n2, addr("1018:1"), DataType::Unspecified)
        .await
        .unwrap();
    assert!(matches!(v, SdoValue::U32(_)), "{v:?}");

    // Writes of several types, read back typed.
    assert_eq!(can0.write(n2, addr("0x1017"), 150u16).await.unwrap(), 2);
    assert_eq!(
        can0.read(n2, addr("0x1017"), DataType::Unsigned16)
            .await
            .unwrap(),
        SdoValue::U16(150)
    );
    assert_eq!(
        can0.write(n2, addr("0x607C"), SdoValue::I32(-123_456))
            .await
            .unwrap(),
        4
    );
    assert_eq!(
        can0.read(n2, addr("0x607C"), DataType::Integer32)
            .await
            .unwrap(),
        SdoValue::I32(-123_456)
    );
    assert_eq!(can0.write(n2, addr("0x605A"), -2i16).await.unwrap(), 2);
    assert_eq!(
        can0.read(n2, addr("0x605A"), DataType::Unspecified)
            .await
            .unwrap(),
        SdoValue::I16(-2)
    );
    assert_eq!(
        can0.write(n2, addr("0x6098"), SdoValue::I8(-3))
            .await
            .unwrap(),
        1
    );
    assert_eq!(
        can0.read(n2, addr("0x6098"), DataType::Integer8)
            .await
            .unwrap(),
        SdoValue::I8(-3)
    );
    // A domain by block transfer, and the same bytes read untyped.
    let image: Vec<u8> = (0..600u32).map(|i| (i * 13 + 1) as u8).collect();
    let block = SdoOptions {
        timeout: Some(Duration::from_secs(1)),
        block: true,
    };
    assert_eq!(
        can0.write_with(n2, addr("0x2100"), SdoValue::Domain(image.clone()), block)
            .await
            .unwrap(),
        600
    );
    assert_eq!(
        can0.read_with(n2, addr("0x2100"), DataType::Domain, block)
            .await
            .unwrap(),
        SdoValue::Domain(image.clone())
    );
    assert_eq!(
        can0.read_bytes(n2, addr("0x2100"), SdoOptions::default())
            .await
            .unwrap(),
        image
    );

    // Nodes and scan, typed ids in, proto nodes out.
    let nodes = can0.nodes().await.unwrap();
    assert!(
        nodes.iter().any(|n| n.id == 2 && n.name == "spare drive"),
        "{nodes:?}"
    );
    assert_eq!(can0.node(n2).await.unwrap().name, "spare drive");
    let found = can0.scan(Some(Duration::from_millis(50))).await.unwrap();
    let ids: Vec<u32> = found.iter().map(|n| n.id).collect();
    assert_eq!(ids, [1, 2]);
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sdo_aborts_timeouts_and_not_found_are_typed_errors() {
    let server = start_server(CONFIG).await;
    let c = typed_client(&server).await;
    let can0 = c.canopen("can0");

    // The node's abort: the object does not exist.
    let e = can0
        .read(node(2), addr("0x5555:00"), DataType::Unsigned32)
        .await
        .unwrap_err();
    let Error::SdoAbort {
        node: n,
        index,
        subindex,
        code,
        ref name,
        by_node,
        ..
    } = e
    else {
        panic!("expected an SDO abort, got {e:?}");
    };
    assert_eq!((n, index, subindex), (2, 0x5555, 0));
    assert_eq!(code, 0x0602_0000);
    assert_eq!(name, "object does not exist in the object dictionary");
    assert!(by_node);
    assert_eq!(e.code(), Some(Code::NotFound));
    assert_eq!(e.reason().as_deref(), Some("SDO_ABORT"));
    assert_eq!(
        e.to_string(),
        "node 2, object 0x5555:00: SDO abort 0x06020000 object does not exist in the object \
         dictionary (sent by the node)"
    );
    // The raw status keeps the metadata header for tools.
    assert_eq!(
        e.status()
            .unwrap()
            .metadata()
            .get("cangate-sdo-abort")
            .unwrap()
            .to_str()
            .unwrap(),
        "0x06020000 object does not exist in the object dictionary"
    );
    let meta = cangate_client::error_metadata(&e);
    assert_eq!(meta["index"], "0x5555");
    assert_eq!(meta["aborted_by"], "node");

    // Writing a read-only object.
    let e = can0
        .write(node(2), addr("0x1000"), SdoValue::U32(1))
        .await
        .unwrap_err();
    assert!(
        matches!(
            e,
            Error::SdoAbort {
                code: 0x0601_0002,
                by_node: true,
                ..
            }
        ),
        "{e:?}"
    );
    assert_eq!(e.code(), Some(Code::FailedPrecondition));

    // A configured node that never answers: the gateway's SDO timeout.
    let e = can0
        .read(node(10), addr("0x1000"), DataType::Unsigned32)
        .await
        .unwrap_err();
    assert!(
        matches!(
            e,
            Error::Timeout {
                status: Some(_),
                ..
            }
        ),
        "{e:?}"
    );
    assert_eq!(e.reason().as_deref(), Some("SDO_TIMEOUT"));

    // Input refused before sending.
    assert!(matches!(NodeId::new(128), Err(Error::InvalidInput { .. })));
    assert!(matches!(
        "0x1000:".parse::<ObjectAddress>(),
        Err(Error::InvalidInput { .. })
    ));

    // NOT_FOUND: an axis, a bus, a node, with kind and name.
    let e = c.axis("Q").await.unwrap_err();
    assert!(
        matches!(&e, Error::NotFound { kind, name, .. } if kind == "axis" && name == "Q"),
        "{e:?}"
    );
    assert_eq!(e.reason().as_deref(), Some("AXIS_NOT_FOUND"));
    assert!(e.to_string().contains("axes: X"), "{e}");
    let e = c.move_to("Q", 1.0, &Default::default()).await.unwrap_err();
    assert!(matches!(e, Error::NotFound { .. }), "{e:?}");
    let e = c.canopen("nope").nodes().await.unwrap_err();
    assert!(
        matches!(&e, Error::NotFound { kind, .. } if kind == "bus"),
        "{e:?}"
    );
    let e = c.canopen("can0").node(node(99)).await.unwrap_err();
    assert_eq!(e.reason().as_deref(), Some("NODE_NOT_FOUND"), "{e:?}");

    // A refusal with its reason: a move without a lease.
    wait_ready(&c).await;
    let e = c.move_to("X", 1.0, &Default::default()).await.unwrap_err();
    assert!(
        matches!(&e, Error::Refused { code: Code::FailedPrecondition, reason, .. } if reason == "LEASE_REQUIRED"),
        "{e:?}"
    );
    assert!(e.meaning().contains("not in a state"), "{}", e.meaning());
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_lease_guard_renews_past_its_ttl_and_releases_on_drop() {
    let server = start_server(CONFIG).await;
    let a = typed_client(&server).await;
    let b = typed_client(&server).await;
    wait_ready(&a).await;

    // A short TTL: without renewal the lease would lapse after 300 ms.
    let lease = a
        .acquire_control_as(&["X"], Duration::from_millis(300), "client-a")
        .await
        .unwrap();
    assert_eq!(lease.axes(), ["X"]);
    assert!(lease.holder().starts_with("client-a"), "{}", lease.holder());
    tokio::time::sleep(Duration::from_millis(1200)).await;
    let st = lease.status();
    assert!(st.renewals >= 3, "{st:?}");
    // (A renewal may time out on a loaded machine; the next one covers it.)
    assert!(!st.lost, "{st:?}");
    // Still held: another client is refused, naming the holder.
    let e = b
        .acquire_control(&["X"], Duration::from_secs(1))
        .await
        .unwrap_err();
    assert!(
        matches!(&e, Error::Refused { reason, .. } if reason == "AXIS_CONTROLLED_BY_OTHER"),
        "{e:?}"
    );
    assert!(e.to_string().contains("client-a"), "{e}");
    // Commands with the lease work (enable, a waited move).
    let r = a.enable("X", &lease.options().wait(true)).await.unwrap();
    assert_eq!(r.outcome, cangate_client::Outcome::Completed, "{r:?}");
    let r = a
        .move_to(
            "X",
            0.5,
            &lease
                .move_options()
                .velocity(20.0)
                .acceleration(200.0)
                .wait(true),
        )
        .await
        .unwrap();
    assert_eq!(r.outcome, cangate_client::Outcome::Completed, "{r:?}");
    assert!((r.status.unwrap().position - 0.5).abs() < 0.01);

    // Dropped: released in the background; the other client gets it.
    drop(lease);
    let t0 = Instant::now();
    let lease_b = loop {
        match b.acquire_control(&["X"], Duration::from_secs(2)).await {
            Ok(l) => break l,
            Err(e) => {
                assert!(
                    t0.elapsed() < Duration::from_millis(1500),
                    "not released: {e}"
                );
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        }
    };
    // Released explicitly: the axes it covered.
    assert_eq!(lease_b.release().await.unwrap(), ["X"]);

    // A lease released behind the guard's back: the renewal fails and
    // the guard reports the loss.
    let lease = a
        .acquire_control(&["X"], Duration::from_millis(300))
        .await
        .unwrap();
    b.axes_client()
        .release_control(cangate_client::pb::ReleaseControlRequest {
            lease: lease.token().to_string(),
        })
        .await
        .unwrap();
    let lost = tokio::time::timeout(WAIT, lease.lost())
        .await
        .expect("the loss is seen");
    assert!(lost.lost);
    let err = lost.last_error.expect("the renewal's error");
    assert_eq!(err.reason().as_deref(), Some("LEASE_UNKNOWN"), "{err}");
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn streams_of_axis_updates_and_frames() {
    let server = start_server(CONFIG).await;
    let c = typed_client(&server).await;
    wait_ready(&c).await;

    let mut axes = c.watch_axes(&["X"], false).await.unwrap();
    let first = tokio::time::timeout(WAIT, axes.next())
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    assert!(
        matches!(&first, AxisUpdate::Status(s) if s.axis == "X"),
        "{first:?}"
    );
    // A control change shows up as a typed event.
    let lease = c
        .acquire_control(&["X"], Duration::from_secs(2))
        .await
        .unwrap();
    let t0 = Instant::now();
    loop {
        let u = tokio::time::timeout(WAIT, axes.next())
            .await
            .unwrap()
            .unwrap()
            .unwrap();
        if let AxisUpdate::ControlChange { axis, reason, .. } = &u {
            assert_eq!((axis.as_str(), reason.as_str()), ("X", "acquired"));
            break;
        }
        assert!(t0.elapsed() < WAIT);
    }
    lease.release().await.unwrap();

    // Frames: the bus state first, then the other call's frame (received
    // from a client, marked with its sender).
    let mut c2 = c.clone();
    let mut frames = c
        .frames(
            "can0",
            &FrameStreamOptions {
                filters: vec![can::Filter::exact_standard(0x123)],
                include_transmitted: true,
                ..Default::default()
            },
        )
        .await
        .unwrap();
    let first = tokio::time::timeout(WAIT, frames.next())
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    assert!(matches!(first, FrameEvent::State(_)), "{first:?}");
    let frame: can::Frame = "123#C0FFEE".parse().unwrap();
    assert_eq!(c2.send("can0", &[frame]).await.unwrap(), 1);
    let got = tokio::time::timeout(WAIT, frames.next())
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    let FrameEvent::Frame {
        frame: f,
        transmitted,
        origin,
        sender,
    } = got
    else {
        panic!("{got:?}");
    };
    assert!(!transmitted);
    assert_eq!(origin, pb::FrameOrigin::Client);
    assert!(sender.is_some_and(|s| s.id > 0), "named sender");
    assert_eq!(f.data(), frame.data());
    assert_eq!(f.raw_id(), 0x123);
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_listener_times_out_instead_of_hanging() {
    // Accepts connections and never says a word.
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let port = listener.local_addr().unwrap().port();
    let silent = tokio::spawn(async move {
        let mut held = Vec::new();
        while let Ok((socket, _)) = listener.accept().await {
            held.push(socket);
        }
    });
    let options = ConnectOptions {
        connect_timeout: Some(Duration::from_millis(300)),
        request_timeout: Some(Duration::from_millis(500)),
        ..Default::default()
    };

    // Plaintext: the TCP connection succeeds; the call times out.
    let t0 = Instant::now();
    let e = match cangate_client::connect_with(&format!("127.0.0.1:{port}"), &options).await {
        Ok(mut c) => c.list_buses().await.unwrap_err(),
        Err(e) => e,
    };
    assert!(matches!(e, Error::Timeout { status: None, .. }), "{e:?}");
    assert!(t0.elapsed() < Duration::from_secs(3), "{:?}", t0.elapsed());
    assert_eq!(e.code(), Some(Code::DeadlineExceeded));
    assert!(e.is_transient());

    // TLS: the handshake never completes; connecting times out.
    let t0 = Instant::now();
    let e = cangate_client::connect_with(&format!("https://127.0.0.1:{port}"), &options)
        .await
        .unwrap_err();
    assert!(matches!(e, Error::Timeout { status: None, .. }), "{e:?}");
    assert!(t0.elapsed() < Duration::from_secs(3), "{:?}", t0.elapsed());
    assert!(
        e.to_string().contains("connecting to https://127.0.0.1:"),
        "{e}"
    );
    silent.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn addresses_with_and_without_scheme_reach_the_server() {
    let server = start_server(CONFIG).await;
    for address in [
        server.addr.to_string(),
        format!("http://{}", server.addr),
        format!(" {} ", server.addr),
    ] {
        let mut c = cangate_client::connect(&address).await.unwrap();
        let buses = c.list_buses().await.unwrap();
        assert_eq!(buses.len(), 1, "{address}");
    }
    // Nobody listening: a transport error, said once.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let e = cangate_client::connect(&format!("127.0.0.1:{port}"))
        .await
        .unwrap_err();
    assert!(matches!(e, Error::Transport { .. }), "{e:?}");
    assert_eq!(e.to_string().matches("transport error").count(), 1, "{e}");
    server.shutdown();
}

/// The gateway answers every batch an attachment sends (SendDone or
/// SendRefused): `send_confirmed` returns once the frames went out, a
/// refusal is the error of the call that sent the batch (with the
/// gateway's code, reason and metadata), and `flush` waits for batches
/// sent without waiting and returns their refusal. A program that only
/// sends (it dropped the events) gets its answers too, and every frame it
/// sent before closing is on the bus.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_attachment_confirms_its_batches_and_returns_refusals() {
    let server = start_server(CONFIG).await;
    let c = typed_client(&server).await;
    let mut watch = c
        .frames(
            "can0",
            &FrameStreamOptions {
                // 0x7A0..=0x7BF: no node of CONFIG uses them.
                filters: vec![can::Filter {
                    id: 0x7A0,
                    mask: 0x7E0,
                    extended: Some(false),
                    inverted: false,
                }],
                low_latency: true,
                ..Default::default()
            },
        )
        .await
        .unwrap();
    let first = tokio::time::timeout(WAIT, watch.next()).await.unwrap();
    assert!(matches!(first, Some(Ok(FrameEvent::State(_)))), "{first:?}");

    let node = c
        .attach("can0", &cangate_client::AttachOptions::default())
        .await
        .unwrap();
    let sender = node.sender.clone();
    // Only sending: the events are not read (dropped).
    drop(node);
    let frame = |i: u8| -> can::Frame {
        format!("{:03X}#{i:02X}5A", 0x7A0 + u32::from(i))
            .parse()
            .unwrap()
    };
    for i in 0..15u8 {
        let confirmed = tokio::time::timeout(WAIT, sender.send_confirmed(&[frame(i)]))
            .await
            .expect("answered in time");
        assert_eq!(confirmed.unwrap(), u64::from(i) + 1, "sequence numbers");
    }
    // Refused: a CAN FD frame on an attachment without fd.
    let fd: can::Frame = "7BF##1AABB".parse().unwrap();
    let e = tokio::time::timeout(WAIT, sender.send_confirmed(&[frame(15), fd]))
        .await
        .expect("answered in time")
        .unwrap_err();
    assert_eq!(e.code(), Some(Code::InvalidArgument), "{e}");
    assert_eq!(e.reason().as_deref(), Some("INVALID_FRAME"), "{e}");
    assert_eq!(
        cangate_client::error_metadata(&e)
            .get("frame")
            .map(String::as_str),
        Some("1"),
        "{e}"
    );
    // Sent without waiting, then flushed: the frames go out, a refused
    // batch among them is the flush's error, once.
    for i in 16..20u8 {
        sender.send(&[frame(i)]).await.unwrap();
    }
    sender.send(&[fd]).await.unwrap();
    sender.send(&[frame(20)]).await.unwrap();
    let e = tokio::time::timeout(WAIT, sender.flush())
        .await
        .expect("answered in time")
        .unwrap_err();
    assert_eq!(e.reason().as_deref(), Some("INVALID_FRAME"), "{e}");
    tokio::time::timeout(WAIT, sender.flush())
        .await
        .expect("answered in time")
        .expect("the refusal was returned once");
    drop(sender);

    // Every frame confirmed is on the bus, in order; nothing of the
    // refused batches.
    let mut seen = Vec::new();
    while seen.len() < 20 {
        match tokio::time::timeout(WAIT, watch.next()).await {
            Ok(Some(Ok(FrameEvent::Frame { frame, .. }))) => seen.push(frame.raw_id()),
            Ok(Some(Ok(_))) => {}
            other => panic!("after {seen:x?}: {other:?}"),
        }
    }
    let want: Vec<u32> = (0..15).chain(16..21).map(|i| 0x7A0 + i).collect();
    assert_eq!(seen, want);
    server.shutdown();
}

/// One status per SYNC cycle: the drive sends two TPDOs per SYNC, which
/// the gateway may read in two batches; it publishes the axis's status
/// once both are in, so `axis watch` prints one line per cycle. Counted
/// over 100 SYNC periods by the bus timestamps of the SYNCs and of the
/// statuses' process data.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cyclic_axis_sends_one_status_per_sync() {
    const PERIODS: usize = 100;
    let server = start_server(CONFIG).await;
    let c = typed_client(&server).await;
    wait_ready(&c).await;
    let mut statuses = c.watch_axes(&["X"], false).await.unwrap();
    let mut syncs = c
        .clone()
        .stream_frames(pb::StreamFramesRequest {
            bus: "can0".into(),
            filters: vec![cangate_client::filter_to_pb(&can::Filter::exact_standard(
                0x080,
            ))],
            include_transmitted: true,
            low_latency: true,
            queue_length: 65_536,
            ..Default::default()
        })
        .await
        .unwrap();
    let mut sync_batch: Vec<pb::StreamEvent> = Vec::new();
    let mut sync_ns: Vec<u64> = Vec::new();
    let mut status_ns: Vec<u64> = Vec::new();
    // A few periods in, so that both streams are surely running.
    let first = 10;
    let done = |sync_ns: &Vec<u64>, status_ns: &Vec<u64>| {
        sync_ns.len() > first + PERIODS
            && status_ns
                .last()
                .is_some_and(|&t| t > sync_ns[first + PERIODS])
    };
    let deadline = tokio::time::Instant::now() + WAIT * 3;
    while !done(&sync_ns, &status_ns) {
        tokio::select! {
            _ = tokio::time::sleep_until(deadline) => {
                panic!("{} SYNCs, {} statuses in time", sync_ns.len(), status_ns.len())
            }
            s = statuses.next() => {
                if let Some(Ok(AxisUpdate::Status(s))) = s
                    && s.timestamp_us > 0
                {
                    status_ns.push(s.timestamp_us * 1000);
                }
            }
            m = syncs.message() => {
                sync_batch.extend(m.expect("SYNC stream").expect("SYNC stream on").events);
                for e in sync_batch.drain(..) {
                    match e.event {
                        Some(pb::stream_event::Event::Frame(f)) => sync_ns.push(f.timestamp_ns),
                        Some(pb::stream_event::Event::Lost(l)) => {
                            panic!("{} SYNCs lost to the test's stream", l.count)
                        }
                        _ => {}
                    }
                }
            }
        }
    }
    // Microseconds of the statuses against nanoseconds of the SYNCs.
    let (from, to) = (
        sync_ns[first] / 1000 * 1000,
        sync_ns[first + PERIODS] / 1000 * 1000,
    );
    let within = status_ns.iter().filter(|&&t| t > from && t <= to).count();
    // One per period; a cycle whose process data comes late may shift
    // one across either end of the window.
    assert!(
        (PERIODS - 2..=PERIODS + 2).contains(&within),
        "{within} statuses of X in {PERIODS} SYNC periods"
    );
    server.shutdown();
}
