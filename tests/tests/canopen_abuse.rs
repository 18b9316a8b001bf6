//! The CANopen service under misuse, end to end: cancelled transfers,
//! callers that hold a node's SDO channel, oversized writes, and requests
//! that used to be accepted silently. One test per defect of the hardening
//! issue (items 8, 9, 10, 11 and the CANopen part of 17).

use cangate_client::pb;
use cangate_client::pb::node_event::Event;
use cangate_tests::*;
use std::time::Duration;
use tonic::Code;

/// Node 1: a simulated drive with a boot procedure (no identity checks
/// configured); node 3: a simulated I/O node without one.
const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"
[[canopen]]
bus = "can0"
sdo_timeout_ms = 200
[[canopen.node]]
id = 1
name = "drive"
eds = "builtin:drive"
simulate = true
boot = true
heartbeat_producer_ms = 50
[[canopen.node.write]]
object = "0x6081:0"
type = "u32"
value = "2500"
[[canopen.node.rpdo]]
num = 1
mapping = ["6040:0:16", "607A:0:32"]
[[canopen.node]]
id = 3
eds = "builtin:io"
simulate = true
"#;

fn read(node: u32, index: u32, timeout_ms: u32) -> pb::ReadSdoRequest {
    pb::ReadSdoRequest {
        bus: "can0".into(),
        node,
        index,
        subindex: 0,
        r#type: pb::DataType::Unspecified as i32,
        options: Some(pb::SdoOptions {
            timeout_ms,
            block: false,
        }),
        object: String::new(),
    }
}

fn write_raw(node: u32, index: u32, data: Vec<u8>) -> pb::WriteSdoRequest {
    pb::WriteSdoRequest {
        bus: "can0".into(),
        node,
        index,
        subindex: 0,
        data: Some(pb::write_sdo_request::Data::Raw(data)),
        options: None,
        object: String::new(),
        force: false,
    }
}

/// Waits for `want` among node events.
async fn wait_event(
    events: &mut tonic::Streaming<pb::NodeEvent>,
    what: &str,
    want: impl Fn(&Event) -> bool,
) {
    tokio::time::timeout(WAIT, async {
        loop {
            let ev = events.message().await.unwrap().expect("event stream open");
            if let Some(e) = ev.event
                && want(&e)
            {
                return;
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("no {what} in time"));
}

/// Waits until a transfer of `index` with `node` shows in ListSdoTransfers
/// with some bytes moved.
async fn wait_transfer_running(c: &cangate_client::Client, node: u32, index: u32) {
    tokio::time::timeout(WAIT, async {
        loop {
            let list = c
                .canopen_client()
                .list_sdo_transfers(pb::ListSdoTransfersRequest { bus: "can0".into() })
                .await
                .unwrap()
                .into_inner();
            if list
                .transfers
                .iter()
                .any(|t| t.node == node && t.index == index && t.transferred > 0)
            {
                return;
            }
            tokio::task::yield_now().await;
        }
    })
    .await
    .expect("the transfer runs");
}

/// Item 8: a segmented transfer dropped by its caller mid-way is aborted by
/// the gateway; the node's late answer to it must not be taken as the next
/// request's ("protocol violation … expected an upload initiate response,
/// got command byte 0x30").
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn next_request_after_a_cancelled_segmented_transfer_succeeds() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let image: Vec<u8> = (0..256 * 1024u32).map(|i| (i * 13 + 1) as u8).collect();
    for round in 0..6 {
        // Writes, then reads (segmented both ways, not block).
        let call = if round % 2 == 0 {
            let mut cc = c.canopen_client();
            let w = write_raw(1, 0x2100, image.clone());
            tokio::spawn(async move { cc.write_sdo(w).await.map(|_| ()) })
        } else {
            let mut cc = c.canopen_client();
            let r = read(1, 0x2100, 0);
            tokio::spawn(async move { cc.read_sdo(r).await.map(|_| ()) })
        };
        wait_transfer_running(&c, 1, 0x2100).await;
        call.abort();
        let _ = call.await;
        let r = tokio::time::timeout(WAIT, c.canopen_client().read_sdo(read(1, 0x1000, 0)))
            .await
            .expect("answer in time")
            .unwrap_or_else(|e| panic!("round {round}: the read after the cancel failed: {e}"))
            .into_inner();
        assert_eq!(r.raw, vec![0x92, 0x01, 0x02, 0x00], "round {round}");
        if round == 0 {
            // Give the domain its content for the reads.
            c.canopen_client()
                .write_sdo(pb::WriteSdoRequest {
                    options: Some(pb::SdoOptions {
                        timeout_ms: 0,
                        block: true,
                    }),
                    ..write_raw(1, 0x2100, image.clone())
                })
                .await
                .expect("block write of the image");
        }
    }
}

/// Item 9: a ReadSdo with a long timeout to a node that does not answer
/// (stopped) must not hold the node's boot procedure: when the node boots,
/// the caller's transfer gives way after the bus's SDO timeout and the
/// boot completes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_read_with_a_long_timeout_does_not_hold_the_boot_procedure() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut events = node_events(&c, vec![1]).await;
    // The node may have booted before the stream opened: reset it.
    send_nmt(&c, 1, pb::NmtCommand::ResetNode).await;
    wait_event(&mut events, "first boot", |e| {
        matches!(e, Event::BootCompleted(_))
    })
    .await;
    // A stopped node ignores SDO (the NMT frame is on the bus before any
    // later request): this read would wait its full minute.
    send_nmt(&c, 1, pb::NmtCommand::Stop).await;
    let mut cc = c.canopen_client();
    let hold = tokio::spawn(async move {
        let started = std::time::Instant::now();
        let r = cc.read_sdo(read(1, 0x1000, 60_000)).await;
        (r.map(|_| ()), started.elapsed())
    });
    tokio::time::timeout(WAIT, async {
        loop {
            let list = c
                .canopen_client()
                .list_sdo_transfers(pb::ListSdoTransfersRequest { bus: "can0".into() })
                .await
                .unwrap()
                .into_inner();
            if list
                .transfers
                .iter()
                .any(|t| t.node == 1 && t.index == 0x1000)
            {
                return;
            }
            tokio::task::yield_now().await;
        }
    })
    .await
    .expect("the read runs");
    send_nmt(&c, 1, pb::NmtCommand::ResetNode).await;
    wait_event(&mut events, "boot completed while the read was open", |e| {
        assert!(!matches!(e, Event::BootFailed(_)), "{e:?}");
        matches!(e, Event::BootCompleted(_))
    })
    .await;
    let (r, took) = tokio::time::timeout(WAIT, hold).await.unwrap().unwrap();
    let e = r.expect_err("the silent read cannot succeed");
    assert_eq!(e.code(), Code::DeadlineExceeded, "{e}");
    assert!(took < Duration::from_secs(30), "the read held for {took:?}");
}

/// Item 9: timeouts are bounded, and one caller cannot queue more than 8
/// requests with a node.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sdo_timeouts_and_each_callers_queue_are_bounded() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let e = c
        .canopen_client()
        .read_sdo(read(1, 0x1000, u32::MAX))
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e}");
    assert!(e.message().contains("60000"), "{e}");

    // Node 3 stopped: every read waits for its timeout.
    send_nmt(&c, 3, pb::NmtCommand::Stop).await;
    let mut held = Vec::new();
    for _ in 0..8 {
        let mut cc = c.canopen_client();
        held.push(tokio::spawn(async move {
            cc.read_sdo(read(3, 0x1000, 20_000)).await
        }));
    }
    // A ninth is refused once the eight are in (each probe that is not
    // refused is dropped again, which frees its place).
    let refusal = tokio::time::timeout(WAIT, async {
        loop {
            let probe = tokio::time::timeout(
                Duration::from_millis(100),
                c.canopen_client().read_sdo(read(3, 0x1000, 20_000)),
            )
            .await;
            if let Ok(Err(e)) = probe {
                return e;
            }
        }
    })
    .await
    .expect("the ninth request is refused");
    assert_eq!(refusal.code(), Code::FailedPrecondition, "{refusal}");
    assert!(
        refusal.message().contains("8 SDO requests"),
        "{}",
        refusal.message()
    );
    for h in held {
        h.abort();
    }
}

/// Item 10: a raw write larger than the object is refused before anything
/// is sent; variable-size and unknown objects take any size.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn raw_writes_larger_than_the_object_are_refused_at_once() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let e = tokio::time::timeout(
        WAIT,
        c.canopen_client()
            .write_sdo(write_raw(1, 0x6040, vec![0; 1 << 20])),
    )
    .await
    .expect("refused at once")
    .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e}");
    assert!(
        e.message().contains("2 bytes") && e.message().contains("1048576 bytes"),
        "{}",
        e.message()
    );
    // A value of the right size still goes through.
    c.canopen_client()
        .write_sdo(write_raw(1, 0x6040, vec![0x06, 0x00]))
        .await
        .expect("2 bytes to a 2-byte object");
    // A domain takes any size.
    c.canopen_client()
        .write_sdo(write_raw(1, 0x2100, vec![7; 300]))
        .await
        .expect("a domain takes any size");
}

/// Item 11: after the boot procedure read 0x1000 and 0x1018, GetNode and
/// ListNodes show them without a ScanNetwork.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn boot_procedure_fills_device_type_and_identity() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut events = node_events(&c, vec![1]).await;
    // The node may have booted before the stream opened: reset it.
    send_nmt(&c, 1, pb::NmtCommand::ResetNode).await;
    wait_event(&mut events, "boot completed", |e| {
        matches!(e, Event::BootCompleted(_))
    })
    .await;
    let n = get_node(&c, 1).await;
    assert_eq!(n.device_type, Some(0x0002_0192));
    let id = n.identity.expect("identity after boot");
    assert_eq!(id.vendor_id, 0x0000_04D2);
    let listed = c
        .canopen_client()
        .list_nodes(pb::ListNodesRequest { bus: "can0".into() })
        .await
        .unwrap()
        .into_inner();
    let n = listed.nodes.iter().find(|n| n.id == 1).unwrap();
    assert_eq!(n.device_type, Some(0x0002_0192));
    assert_eq!(n.identity.as_ref().map(|i| i.vendor_id), Some(0x0000_04D2));
}

/// Item 17 (CANopen): requests that used to be accepted silently.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_canopen_requests_are_refused() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let value = |index: u32, ty: pb::DataType, v: u64| pb::PdoValue {
        index,
        subindex: 0,
        name: String::new(),
        value: Some(pb::Value {
            r#type: ty as i32,
            value: Some(pb::value::Value::UintValue(v)),
        }),
    };
    let pdo = |values: Vec<pb::PdoValue>| pb::WritePdoRequest {
        bus: "can0".into(),
        node: 1,
        pdo: 1,
        values,
    };
    let mapped = vec![
        value(0x6040, pb::DataType::Unsigned16, 0x0F),
        value(0x607A, pb::DataType::Integer32, 1000),
    ];
    let mut cc = c.canopen_client();
    cc.write_pdo(pdo(mapped.clone()))
        .await
        .expect("the mapped objects");
    let mut extra = mapped.clone();
    extra.push(value(0x6060, pb::DataType::Integer8, 1));
    let e = cc.write_pdo(pdo(extra)).await.unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e}");
    assert!(e.message().contains("0x6060"), "{}", e.message());
    let mut twice = mapped.clone();
    twice.push(value(0x6040, pb::DataType::Unsigned16, 0x06));
    let e = cc.write_pdo(pdo(twice)).await.unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e}");

    let e = cc
        .stream_node_events(pb::StreamNodeEventsRequest {
            bus: "can0".into(),
            nodes: vec![0, 200],
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e}");
    let e = cc
        .stream_pdo(pb::StreamPdoRequest {
            bus: "can0".into(),
            nodes: vec![999],
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e}");
    let e = cc
        .scan_network(pb::ScanNetworkRequest {
            bus: "can0".into(),
            timeout_ms: 49 * 24 * 3600 * 1000,
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e}");
    assert!(e.message().contains("10000"), "{}", e.message());
}
