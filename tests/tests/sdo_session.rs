//! `Canopen.SdoSession` end to end: the real server on a virtual bus with
//! simulated drives, the generated client (to see the answers as sent) and
//! the typed `SdoSession`. Pipelined reads keep their ids, values and the
//! order per node; errors are answers and the stream goes on; roles and
//! the axis guard apply per request as for WriteSdo; a cancelled session
//! aborts its transfer and leaves the node usable.

use cangate_client::{DataType, Error, NodeId, ObjectAddress, SdoValue, pb};
use cangate_tests::axes::*;
use cangate_tests::*;
use pb::sdo_session_answer::Result as A;
use pb::sdo_session_request::Request as R;
use std::collections::HashMap;
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tonic::Code;

/// Nodes 3 and 4: simulated drives; node 5: the simulated drive of axis S
/// (process data by SDO, so no SYNC is needed).
const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"

[[canopen.node]]
id = 3
eds = "builtin:drive"
simulate = true

[[canopen.node]]
id = 4
eds = "builtin:drive"
simulate = true

[[canopen.node]]
id = 5
eds = "builtin:drive"
simulate = true

[[axis]]
name = "S"
bus = "can0"
node = 5
counts_per_unit = 1000.0
max_velocity = 50.0
max_acceleration = 500.0
process_data = "sdo"
sdo_poll_ms = 5
"#;

/// 0x1000 of the built-in drive.
const DEVICE_TYPE: u32 = 0x0002_0192;

fn node(id: u32) -> NodeId {
    NodeId::new(id).unwrap()
}

fn read(id: u64, node: u32, index: u32) -> pb::SdoSessionRequest {
    pb::SdoSessionRequest {
        id,
        request: Some(R::Read(pb::ReadSdoRequest {
            bus: "can0".into(),
            node,
            index,
            ..Default::default()
        })),
    }
}

fn write_raw(id: u64, node: u32, index: u32, raw: Vec<u8>, force: bool) -> pb::SdoSessionRequest {
    pb::SdoSessionRequest {
        id,
        request: Some(R::Write(pb::WriteSdoRequest {
            bus: "can0".into(),
            node,
            index,
            data: Some(pb::write_sdo_request::Data::Raw(raw)),
            force,
            ..Default::default()
        })),
    }
}

/// A session of the generated client: its request sender and answers.
async fn open(
    c: &cangate_client::Client,
) -> (
    mpsc::Sender<pb::SdoSessionRequest>,
    tonic::Streaming<pb::SdoSessionAnswer>,
) {
    let (tx, rx) = mpsc::channel(256);
    let answers = c
        .canopen_client()
        .sdo_session(ReceiverStream::new(rx))
        .await
        .expect("SdoSession opens")
        .into_inner();
    (tx, answers)
}

async fn next(answers: &mut tonic::Streaming<pb::SdoSessionAnswer>) -> pb::SdoSessionAnswer {
    tokio::time::timeout(WAIT, answers.message())
        .await
        .expect("an answer in time")
        .expect("the stream goes on")
        .expect("an answer, not the end")
}

fn error_of(a: &pb::SdoSessionAnswer) -> &pb::SdoSessionError {
    match &a.result {
        Some(A::Error(e)) => e,
        other => panic!("answer {}: expected an error, got {other:?}", a.id),
    }
}

fn read_u32(a: &pb::SdoSessionAnswer) -> u32 {
    match &a.result {
        Some(A::Read(r)) => match SdoValue::from_pb(r.value.as_ref().expect("typed by the EDS")) {
            Ok(v) => u32::try_from(v.as_u64().expect("a number")).unwrap(),
            Err(e) => panic!("{e}"),
        },
        other => panic!("answer {}: expected a read, got {other:?}", a.id),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pipelined_reads_to_two_nodes_keep_ids_values_and_order_per_node() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let co = c.canopen("can0");
    for n in [3, 4] {
        co.write(node(n), ObjectAddress::new(0x1017, 0), 1000u16 + n as u16)
            .await
            .expect("heartbeat time written");
    }
    let (tx, mut answers) = open(&c).await;
    // Ids not in order of sending, to see they are the client's.
    let id = |i: u64| 1_000_000 - i * 7;
    let mut expected = HashMap::new();
    for i in 0..100u64 {
        let n = if i % 2 == 0 { 3 } else { 4 };
        let index = if i % 3 == 0 { 0x1000 } else { 0x1017 };
        expected.insert(
            id(i),
            (
                n,
                i,
                if index == 0x1000 {
                    DEVICE_TYPE
                } else {
                    1000 + n
                },
            ),
        );
        tx.send(read(id(i), n, index)).await.unwrap();
    }
    drop(tx);
    let mut last_seq: HashMap<u32, u64> = HashMap::new();
    for _ in 0..100 {
        let a = next(&mut answers).await;
        let (n, seq, value) = expected
            .remove(&a.id)
            .unwrap_or_else(|| panic!("unknown or repeated id {}", a.id));
        assert_eq!(read_u32(&a), value, "id {} (node {n})", a.id);
        if let Some(before) = last_seq.insert(n, seq) {
            assert!(
                before < seq,
                "node {n}: request {seq} answered after {before}"
            );
        }
    }
    assert!(expected.is_empty());
    // All sent and answered: the stream ends.
    assert!(answers.message().await.expect("a clean end").is_none());

    // The same with the typed client: 100 futures at once.
    let s = co.sdo_session().await.unwrap();
    let reads: Vec<_> = (0..100u32)
        .map(|i| {
            let n = 3 + i % 2;
            (
                n,
                s.read(
                    node(n),
                    ObjectAddress::new(0x1017, 0),
                    DataType::Unspecified,
                ),
            )
        })
        .collect();
    for (n, r) in reads {
        assert_eq!(r.await.unwrap(), SdoValue::U16(1000 + n as u16));
    }
    s.close().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_write_then_a_read_of_the_same_object_in_one_session() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let s = c.canopen("can0").sdo_session().await.unwrap();
    // Both sent before either answer is awaited: the order per node holds.
    let w = s.write(node(3), "Producer heartbeat time", 1234u16);
    let r = s.read(
        node(3),
        ObjectAddress::new(0x1017, 0),
        DataType::Unspecified,
    );
    assert_eq!(w.await.unwrap(), 2);
    assert_eq!(r.await.unwrap(), SdoValue::U16(1234));
    s.close().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn errors_are_typed_answers_and_the_stream_goes_on() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let (tx, mut answers) = open(&c).await;

    // A write to the read-only device type: the node's abort.
    tx.send(write_raw(1, 3, 0x1000, vec![1, 0, 0, 0], false))
        .await
        .unwrap();
    let a = next(&mut answers).await;
    assert_eq!(a.id, 1);
    let e = error_of(&a);
    assert_eq!(e.reason, "SDO_ABORT", "{e:?}");
    let abort = e.abort.as_ref().expect("SdoAbortDetails");
    assert_eq!(abort.code, 0x0601_0002, "{e:?}");
    assert!(abort.from_node);
    assert_eq!((abort.index, abort.subindex), (0x1000, 0));
    assert_eq!(e.metadata["abort_code"], "0x06010002");
    assert_eq!(e.metadata["abort_name"], abort.name);
    assert_eq!(e.metadata["node"], "3");

    // The same stream goes on.
    tx.send(read(2, 3, 0x1000)).await.unwrap();
    let a = next(&mut answers).await;
    assert_eq!((a.id, read_u32(&a)), (2, DEVICE_TYPE));

    // An unknown node, an unknown bus, a request without read or write.
    tx.send(read(3, 99, 0x1000)).await.unwrap();
    tx.send(pb::SdoSessionRequest {
        request: Some(R::Read(pb::ReadSdoRequest {
            bus: "nope".into(),
            node: 3,
            index: 0x1000,
            ..Default::default()
        })),
        id: 4,
    })
    .await
    .unwrap();
    tx.send(pb::SdoSessionRequest {
        id: 5,
        request: None,
    })
    .await
    .unwrap();
    let mut got = HashMap::new();
    for _ in 0..3 {
        let a = next(&mut answers).await;
        let e = error_of(&a).clone();
        got.insert(a.id, (Code::from(e.code), e.reason, e.abort.is_none()));
    }
    assert_eq!(
        got[&3],
        (Code::NotFound, "NODE_NOT_FOUND".to_string(), true),
        "{got:?}"
    );
    assert_eq!(got[&4], (Code::NotFound, "BUS_NOT_FOUND".to_string(), true));
    assert_eq!(
        got[&5],
        (Code::InvalidArgument, "INVALID_ARGUMENT".to_string(), true)
    );
    tx.send(read(6, 4, 0x1000)).await.unwrap();
    let a = next(&mut answers).await;
    assert_eq!((a.id, read_u32(&a)), (6, DEVICE_TYPE));

    // The typed client types them as the unary calls' errors.
    let s = c.canopen("can0").sdo_session().await.unwrap();
    let e = s
        .write(node(3), ObjectAddress::new(0x1000, 0), 5u32)
        .await
        .expect_err("read-only");
    assert!(
        matches!(
            e,
            Error::SdoAbort {
                node: 3,
                code: 0x0601_0002,
                by_node: true,
                ..
            }
        ),
        "{e:?}"
    );
    let e = s
        .read(
            node(99),
            ObjectAddress::new(0x1000, 0),
            DataType::Unsigned32,
        )
        .await
        .expect_err("no node 99");
    assert!(
        matches!(e, Error::NotFound { ref kind, .. } if kind == "node"),
        "{e:?}"
    );
    assert_eq!(
        s.read(node(3), ObjectAddress::new(0x1000, 0), DataType::Unsigned32)
            .await
            .unwrap(),
        SdoValue::U32(DEVICE_TYPE)
    );
}

async fn with_token(
    server: &cangate_server::RunningServer,
    token: &str,
) -> Result<cangate_client::Client, Error> {
    cangate_client::connect_with(
        &format!("http://{}", server.addr),
        &cangate_client::ConnectOptions {
            token: Some(token.into()),
            ..Default::default()
        },
    )
    .await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_viewer_reads_but_its_writes_are_refused_as_for_write_sdo() {
    // The only test of this file that captures the log (once per process).
    let log = cangate_tests::log::capture_log("cangate::audit=info");
    let tokens: String = [("wall", "viewer", "v-token"), ("pc", "engineer", "e-token")]
        .iter()
        .map(|(name, role, token)| {
            format!(
                "[[security.tokens]]\nname = \"{name}\"\nrole = \"{role}\"\nsha256 = \"{}\"\n",
                cangate_client::hash_token(token)
            )
        })
        .collect();
    let server = start_server(&format!("{CONFIG}{tokens}")).await;
    let viewer = with_token(&server, "v-token").await.unwrap();
    // The unary call's refusal, for comparison.
    let unary = viewer
        .canopen("can0")
        .write(node(3), ObjectAddress::new(0x1017, 0), 7u16)
        .await
        .expect_err("a viewer may not WriteSdo");
    assert_eq!(unary.code(), Some(Code::PermissionDenied));

    let (tx, mut answers) = open(&viewer).await;
    tx.send(write_raw(1, 3, 0x1017, vec![7, 0], false))
        .await
        .unwrap();
    tx.send(read(2, 3, 0x1017)).await.unwrap();
    // A second refused write: answered as the first, not audited again.
    tx.send(write_raw(3, 3, 0x1017, vec![8, 0], false))
        .await
        .unwrap();
    let a = next(&mut answers).await;
    let e = error_of(&a);
    assert_eq!(
        (a.id, Code::from(e.code), e.reason.as_str()),
        (1, Code::PermissionDenied, "PERMISSION_DENIED")
    );
    assert!(
        e.message.contains("engineer") && e.message.contains("wall holds role viewer"),
        "{}",
        e.message
    );
    // Nothing was written.
    let a = next(&mut answers).await;
    assert_eq!(a.id, 2);
    assert_ne!(read_u32(&a), 7);
    let a = next(&mut answers).await;
    assert_eq!(
        (a.id, error_of(&a).reason.as_str()),
        (3, "PERMISSION_DENIED")
    );

    let engineer = with_token(&server, "e-token").await.unwrap();
    let s = engineer.canopen("can0").sdo_session().await.unwrap();
    assert_eq!(
        s.write(node(3), ObjectAddress::new(0x1017, 0), 7u16)
            .await
            .unwrap(),
        2
    );
    drop(tx);
    // Both writes are in the audit log, as WriteSdo calls would be (the
    // session itself is a viewer's call, not audited as a change).
    let text = log.text();
    let line = |who: &str| {
        text.lines()
            .find(|l| l.contains(&format!("who={who}")) && l.contains("SdoSession write"))
            .unwrap_or_else(|| panic!("no audit line of {who}'s session write in:\n{text}"))
            .to_string()
    };
    let engineer_line = line("pc");
    assert!(
        engineer_line.contains("OK") && engineer_line.contains("node=3"),
        "{engineer_line}"
    );
    assert!(
        line("wall").contains("PERMISSION_DENIED"),
        "{}",
        line("wall")
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_write_to_an_enabled_axis_drive_is_refused_unless_forced() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut axes = c.axes_client();
    wait_status(&mut axes, "S", |s| s.state != 0 && !s.node_lost).await;
    let lease = acquire(&mut axes, &["S"], 10_000, "test").await;
    enable(&mut axes, "S", &lease).await;

    let (tx, mut answers) = open(&c).await;
    tx.send(write_raw(1, 5, 0x6040, vec![0, 0], false))
        .await
        .unwrap();
    let a = next(&mut answers).await;
    let e = error_of(&a);
    assert_eq!(
        (Code::from(e.code), e.reason.as_str()),
        (Code::FailedPrecondition, "AXIS_ACTIVE"),
        "{e:?}"
    );
    assert_eq!(e.metadata["axis"], "S");
    assert!(e.message.contains("axis S"), "{}", e.message);
    let s = wait_status(&mut axes, "S", |_| true).await;
    assert_eq!(s.state, pb::DriveState::OperationEnabled as i32, "{s:?}");
    // Forced, it is written (the controlword the drive already has).
    tx.send(write_raw(2, 5, 0x6040, vec![0x0F, 0], true))
        .await
        .unwrap();
    let a = next(&mut answers).await;
    assert!(
        matches!(a.result, Some(A::Write(ref w)) if w.bytes == 2),
        "{a:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cancelled_session_aborts_its_transfer_and_the_node_stays_usable() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let image: Vec<u8> = (0..256 * 1024u32).map(|i| (i * 13 + 1) as u8).collect();
    let s = c.canopen("can0").sdo_session().await.unwrap();
    let write = s.write_request(pb::WriteSdoRequest {
        node: 3,
        index: 0x2100,
        data: Some(pb::write_sdo_request::Data::Raw(image)),
        ..Default::default()
    });
    // Wait until the segmented download moves bytes.
    let transfers = || async {
        c.canopen_client()
            .list_sdo_transfers(pb::ListSdoTransfersRequest { bus: "can0".into() })
            .await
            .unwrap()
            .into_inner()
            .transfers
    };
    tokio::time::timeout(WAIT, async {
        while !transfers()
            .await
            .iter()
            .any(|t| t.node == 3 && t.index == 0x2100 && t.transferred > 0)
        {
            tokio::task::yield_now().await;
        }
    })
    .await
    .expect("the transfer runs");
    drop(s);
    assert!(write.await.is_err(), "the cancelled write has no result");
    // The gateway drops the transfer.
    tokio::time::timeout(WAIT, async {
        while transfers().await.iter().any(|t| t.node == 3) {
            tokio::task::yield_now().await;
        }
    })
    .await
    .expect("the cancelled transfer ends");
    // The node answers the next request, in a new session.
    let s = c.canopen("can0").sdo_session().await.unwrap();
    assert_eq!(
        tokio::time::timeout(
            WAIT,
            s.read(node(3), ObjectAddress::new(0x1000, 0), DataType::Unsigned32)
        )
        .await
        .expect("answer in time")
        .unwrap(),
        SdoValue::U32(DEVICE_TYPE)
    );
}

/// Each request of a session counts against the client's call rate
/// (`requests_per_second_per_client`) as a unary call would: over it, the
/// request is a RATE_LIMIT answer and the session goes on.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn session_requests_count_against_the_call_rate() {
    // One call a second, five at once: opening the session takes one.
    let limits = "[security.limits]\nrequests_per_second_per_client = 1\nburst = 5\n";
    let server = start_server(&format!("{CONFIG}{limits}")).await;
    let c = client(&server).await;
    let (tx, mut answers) = open(&c).await;
    // Requests to an unknown node: answered at once, without the bus.
    for id in 1..=20 {
        tx.send(read(id, 99, 0x1000)).await.unwrap();
    }
    let mut reasons = Vec::new();
    for _ in 1..=20 {
        let a = next(&mut answers).await;
        let e = error_of(&a);
        if e.reason == "RATE_LIMIT" {
            assert_eq!(Code::from(e.code), Code::ResourceExhausted, "{e:?}");
        }
        reasons.push(e.reason.clone());
    }
    let limited = reasons.iter().filter(|r| *r == "RATE_LIMIT").count();
    // At most 4 tokens were left, plus one a second meanwhile.
    assert!(limited >= 10, "{reasons:?}");
    assert!(
        reasons.contains(&"NODE_NOT_FOUND".to_string()),
        "{reasons:?}"
    );
}
