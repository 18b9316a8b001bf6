//! The CANopen master end to end: the real server with simulated nodes on
//! the virtual bus, driven through the gRPC Canopen service by the real
//! client.

use cangate_client::pb;
use cangate_client::pb::node_event::Event;
use cangate_tests::*;
use std::time::Duration;
use tonic::Code;

const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"
fd = true
[[canopen]]
bus = "can0"
sdo_timeout_ms = 200
[[canopen.node]]
id = 1
name = "drive"
eds = "builtin:drive"
heartbeat_timeout_ms = 150
simulate = true
[[canopen.node]]
id = 3
eds = "builtin:io"
simulate = true
[[canopen.node]]
id = 10
name = "absent"
"#;

fn read(node: u32, index: u32, sub: u32, ty: pb::DataType) -> pb::ReadSdoRequest {
    pb::ReadSdoRequest {
        bus: "can0".into(),
        node,
        index,
        subindex: sub,
        r#type: ty as i32,
        options: None,
        object: String::new(),
    }
}

fn uint(ty: pb::DataType, v: u64) -> pb::Value {
    pb::Value {
        r#type: ty as i32,
        value: Some(pb::value::Value::UintValue(v)),
    }
}

fn write(
    node: u32,
    index: u32,
    sub: u32,
    data: pb::write_sdo_request::Data,
    block: bool,
) -> pb::WriteSdoRequest {
    pb::WriteSdoRequest {
        bus: "can0".into(),
        node,
        index,
        subindex: sub,
        data: Some(data),
        options: Some(pb::SdoOptions {
            timeout_ms: 0,
            block,
        }),
        object: String::new(),
        force: false,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sdo_reads_and_writes_every_protocol() {
    let server = start_server(CONFIG).await;
    let mut c = client(&server).await;

    // Expedited read, typed from the request.
    let r = c
        .read_sdo(read(1, 0x1000, 0, pb::DataType::Unsigned32))
        .await
        .unwrap();
    assert_eq!(r.raw, vec![0x92, 0x01, 0x02, 0x00]);
    assert_eq!(
        r.value.unwrap().value,
        Some(pb::value::Value::UintValue(0x0002_0192))
    );
    // Segmented read, typed from the node's EDS.
    let r = c
        .read_sdo(read(1, 0x1008, 0, pb::DataType::Unspecified))
        .await
        .unwrap();
    assert_eq!(
        r.value.unwrap().value,
        Some(pb::value::Value::StringValue("cangate sim drive".into()))
    );
    // Expedited write and read back.
    let w = write(
        1,
        0x1017,
        0,
        pb::write_sdo_request::Data::Value(uint(pb::DataType::Unsigned16, 120)),
        false,
    );
    assert_eq!(c.write_sdo(w).await.unwrap().bytes, 2);
    let r = c
        .read_sdo(read(1, 0x1017, 0, pb::DataType::Unspecified))
        .await
        .unwrap();
    assert_eq!(r.raw, vec![120, 0]);

    // Block download and block upload of a 4 KiB domain, and segmented too.
    let image: Vec<u8> = (0..4096u32).map(|i| (i * 7 + 3) as u8).collect();
    for block in [true, false] {
        let w = write(
            1,
            0x2100,
            0,
            pb::write_sdo_request::Data::Raw(image.clone()),
            block,
        );
        assert_eq!(c.write_sdo(w).await.unwrap().bytes, 4096);
        let mut req = read(1, 0x2100, 0, pb::DataType::Unspecified);
        req.options = Some(pb::SdoOptions {
            timeout_ms: 0,
            block,
        });
        assert_eq!(c.read_sdo(req).await.unwrap().raw, image, "block = {block}");
    }
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sdo_errors_reach_the_client_typed() {
    let server = start_server(CONFIG).await;
    let mut c = client(&server).await;

    // A node abort: code and CiA name in the status details and metadata.
    let w = write(
        1,
        0x1000,
        0,
        pb::write_sdo_request::Data::Raw(vec![1, 2, 3, 4]),
        false,
    );
    let err = c.write_sdo(w).await.unwrap_err();
    let Some(status) = err.status() else {
        panic!("{err}")
    };
    assert_eq!(status.code(), Code::FailedPrecondition);
    let details = cangate_client::sdo_abort_details(status).expect("SdoAbortDetails");
    assert_eq!(details.code, 0x0601_0002);
    assert_eq!(details.name, "attempt to write a read only object");
    assert_eq!((details.index, details.subindex), (0x1000, 0));
    assert!(details.from_node);
    assert_eq!(
        status
            .metadata()
            .get("cangate-sdo-abort")
            .unwrap()
            .to_str()
            .unwrap(),
        "0x06010002 attempt to write a read only object"
    );
    assert!(
        status.message().contains("0x06010002"),
        "{}",
        status.message()
    );

    // Object that does not exist: NOT_FOUND with the abort.
    let err = c
        .read_sdo(read(1, 0x5555, 0, pb::DataType::Unspecified))
        .await
        .unwrap_err();
    assert_eq!(err.code(), Some(Code::NotFound));
    assert!(err.to_string().contains("0x06020000"), "{err}");

    // Wrong length for the object's type: the node answers 0x0607001x.
    let w = write(
        1,
        0x1017,
        0,
        pb::write_sdo_request::Data::Raw(vec![1, 2, 3, 4]),
        false,
    );
    let err = c.write_sdo(w).await.unwrap_err();
    assert_eq!(err.code(), Some(Code::InvalidArgument), "{err}");

    // A value that does not fit its type never reaches the bus.
    let w = write(
        1,
        0x1017,
        0,
        pb::write_sdo_request::Data::Value(uint(pb::DataType::Unsigned8, 300)),
        false,
    );
    let err = c.write_sdo(w).await.unwrap_err();
    assert_eq!(err.code(), Some(Code::InvalidArgument));
    assert!(err.to_string().contains("does not fit UNSIGNED8"), "{err}");

    // A configured node that does not answer: DEADLINE_EXCEEDED after the
    // bus's SDO timeout (200 ms here), never a hang.
    let started = std::time::Instant::now();
    let err = c
        .read_sdo(read(10, 0x1000, 0, pb::DataType::Unspecified))
        .await
        .unwrap_err();
    assert_eq!(err.code(), Some(Code::DeadlineExceeded), "{err}");
    assert!(started.elapsed() >= Duration::from_millis(200));

    // Unknown node, bad node id, bus without a master.
    let err = c
        .read_sdo(read(42, 0x1000, 0, pb::DataType::Unspecified))
        .await
        .unwrap_err();
    assert_eq!(err.code(), Some(Code::NotFound));
    let err = c
        .read_sdo(read(128, 0x1000, 0, pb::DataType::Unspecified))
        .await
        .unwrap_err();
    assert_eq!(err.code(), Some(Code::InvalidArgument));
    assert!(err.to_string().contains("1..=127"), "{err}");
    let mut r = read(1, 0x1000, 0, pb::DataType::Unspecified);
    r.bus = "nope".into();
    assert_eq!(
        c.read_sdo(r).await.unwrap_err().code(),
        Some(Code::NotFound)
    );
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scan_finds_exactly_the_nodes_present() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let r = c
        .canopen_client()
        .scan_network(pb::ScanNetworkRequest {
            bus: "can0".into(),
            timeout_ms: 50,
        })
        .await
        .unwrap()
        .into_inner();
    let found: Vec<(u32, Option<u32>, String)> = r
        .nodes
        .iter()
        .map(|n| (n.id, n.device_type, n.device_name.clone()))
        .collect();
    assert_eq!(
        found,
        vec![
            (1, Some(0x0002_0192), "cangate sim drive".to_string()),
            (3, Some(0x000F_0191), "cangate sim io".to_string()),
        ]
    );
    let identity = r.nodes[0].identity.unwrap();
    assert_eq!(identity.vendor_id, 0x0000_04D2);
    server.shutdown();
}

/// Reads node events until `pred` matches one (bounded).
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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nmt_heartbeat_loss_recovery_and_emcy_events() {
    let server = start_server(CONFIG).await;
    let vbus = server.gateway().network().get("can0").unwrap();
    let c = client(&server).await;
    let mut events = node_events(&c, vec![1]).await;

    // NMT start → the node reports operational in its heartbeat.
    send_nmt(&c, 1, pb::NmtCommand::Start).await;
    wait_event(&mut events, "operational", |e| {
        matches!(&e.event, Some(Event::StateChanged(s)) if s.to == pb::NmtState::Operational as i32)
    })
    .await;

    // The node's heartbeat disappears from the bus (fault injection): lost,
    // then recovered when it comes back.
    vbus.set_drop_ids([0x701]);
    let lost = wait_event(&mut events, "heartbeat lost", |e| {
        matches!(e.event, Some(Event::HeartbeatLost(_)))
    })
    .await;
    assert_eq!(lost.node, 1);
    let node = get_node(&c, 1).await;
    assert!(node.heartbeat_lost);
    vbus.set_drop_ids([]);
    wait_event(&mut events, "heartbeat recovered", |e| {
        matches!(e.event, Some(Event::HeartbeatRecovered(_)))
    })
    .await;

    // An EMCY from node 1: decoded with its CiA name, kept as active error.
    let port = vbus.connect(false);
    port.send(&"081#1023020000000000".parse().unwrap()).unwrap();
    let ev = wait_event(&mut events, "EMCY", |e| {
        matches!(e.event, Some(Event::Emcy(_)))
    })
    .await;
    let Some(Event::Emcy(emcy)) = ev.event else {
        unreachable!()
    };
    assert_eq!(emcy.code, 0x2310);
    assert_eq!(emcy.code_name, "continuous over-current");
    assert!(
        emcy.register_bits.iter().any(|b| b == "current"),
        "{:?}",
        emcy.register_bits
    );
    let node = get_node(&c, 1).await;
    assert_eq!(node.active_error.unwrap().code, 0x2310);
    // Error reset clears it.
    port.send(&"081#0000000000000000".parse().unwrap()).unwrap();
    wait_event(
        &mut events,
        "EMCY reset",
        |e| matches!(&e.event, Some(Event::Emcy(m)) if m.code == 0),
    )
    .await;
    let node = get_node(&c, 1).await;
    assert!(node.active_error.is_none());
    assert_eq!(node.emcy_history.len(), 2);
    server.shutdown();
}

/// An application embedding the gateway runs a task on its bus runtime
/// (`Gateway::bus_runtime`): the task is on the `gateway-bus` thread, and
/// its SDO read is answered without leaving it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_task_on_the_bus_runtime_reads_by_sdo() {
    use cangate_canopen::master::SdoRequest;
    use cangate_canopen::sdo::{TransferOptions, TransferOutcome};
    use cangate_canopen::{NodeId, ObjectAddress};

    let server = start_server(CONFIG).await;
    let master = server.gateway().canopen("can0").unwrap().clone();
    let (thread, read) = server
        .gateway()
        .bus_runtime()
        .spawn(async move {
            let thread = std::thread::current().name().map(str::to_string);
            let req = SdoRequest::Upload {
                addr: ObjectAddress::new(0x1000, 0),
                opts: TransferOptions::default(),
            };
            (thread, master.sdo(NodeId::new(1).unwrap(), req).await)
        })
        .await
        .unwrap();
    assert_eq!(thread.as_deref(), Some("gateway-bus"));
    match read {
        Ok(TransferOutcome::Uploaded(bytes)) => assert_eq!(bytes, [0x92, 0x01, 0x02, 0x00]),
        other => panic!("device type read: {other:?}"),
    }
}
