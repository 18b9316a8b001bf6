//! Boot procedure (identity check, configuration by SDO, NMT start) and
//! PDOs end to end: the configured TPDO arrives decoded and named on
//! StreamPdo; WritePdo reaches the node's object dictionary.

use cangate_client::pb;
use cangate_client::pb::node_event::Event;
use cangate_tests::*;

const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"
[[canopen]]
bus = "can0"
[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true
boot = true
device_type = 0x00020192
vendor_id = 0x000004D2
heartbeat_producer_ms = 50
[[canopen.node.write]]
object = "0x6081:0"
type = "u32"
value = "2500"
[[canopen.node.tpdo]]
num = 1
transmission_type = 255
event_timer_ms = 20
mapping = ["6041:0:16", "6081:0:32", "6060:0:8"]
[[canopen.node.rpdo]]
num = 1
mapping = ["6040:0:16", "607A:0:32"]
[[canopen.node]]
id = 3
eds = "builtin:io"
simulate = true
boot = true
device_type = 0x12345678
[[canopen.node]]
id = 4
eds = "builtin:io"
simulate = true
boot = true
vendor_id = 0x00000BAD
[[canopen.node]]
id = 5
eds = "builtin:io"
simulate = true
boot = true
[[canopen.node.write]]
object = "0x1000:0"
type = "u32"
value = "1"
"#;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn boot_procedure_configures_and_starts_and_pdos_flow() {
    // Subscribe before the nodes boot: start the server, then read events
    // from its history via GetNode state and the streams.
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut pdos = c
        .canopen_client()
        .stream_pdo(pb::StreamPdoRequest {
            bus: "can0".into(),
            nodes: vec![1],
        })
        .await
        .unwrap()
        .into_inner();

    // The TPDO as configured at boot arrives decoded with EDS names; the
    // extra write (0x6081 = 2500) is visible in it.
    let msg = tokio::time::timeout(WAIT, pdos.message())
        .await
        .expect("TPDO in time")
        .unwrap()
        .unwrap();
    assert_eq!((msg.node, msg.pdo, msg.cob_id), (1, 1, 0x181));
    let idx: Vec<(u32, String)> = msg
        .values
        .iter()
        .map(|v| (v.index, v.name.clone()))
        .collect();
    assert_eq!(idx.len(), 3);
    assert_eq!(idx[0].0, 0x6041);
    assert_eq!(idx[1].0, 0x6081);
    assert_eq!(idx[2].0, 0x6060);
    assert!(idx[0].1.to_lowercase().contains("statusword"), "{idx:?}");
    assert_eq!(
        msg.values[1].value.as_ref().unwrap().value,
        Some(pb::value::Value::UintValue(2500))
    );
    assert!(msg.timestamp_ns > 0);

    // Node 1 was started; node 3's identity check failed, it stays
    // pre-operational and the failure is recorded with its reason.
    // (The master learns the state from the node's next heartbeat.)
    tokio::time::timeout(WAIT, async {
        loop {
            let node1 = get_node(&c, 1).await;
            if node1.state == pb::NmtState::Operational as i32 {
                return;
            }
            tokio::time::sleep(std::time::Duration::from_millis(10)).await;
        }
    })
    .await
    .expect("node 1 reports operational");
    let heartbeat = c
        .clone()
        .read_sdo(pb::ReadSdoRequest {
            bus: "can0".into(),
            node: 1,
            index: 0x1017,
            subindex: 0,
            r#type: 0,
            options: None,
            object: String::new(),
        })
        .await
        .unwrap();
    assert_eq!(heartbeat.raw, vec![50, 0]);

    // Node 3 gets a reset: the boot procedure runs again and fails again,
    // reported as an event with the reason.
    let mut events = node_events(&c, vec![3]).await;
    send_nmt(&c, 3, pb::NmtCommand::ResetNode).await;
    let reason = tokio::time::timeout(WAIT, async {
        loop {
            let ev = events.message().await.unwrap().unwrap();
            if let Some(Event::BootFailed(f)) = ev.event {
                return f.reason;
            }
        }
    })
    .await
    .expect("boot failure reported");
    assert!(reason.contains("device type mismatch"), "{reason}");
    assert!(
        reason.contains("0x000F0191") && reason.contains("0x12345678"),
        "{reason}"
    );
    let node3 = get_node(&c, 3).await;
    assert_eq!(node3.state, pb::NmtState::PreOperational as i32);

    // The other failure paths: a vendor id mismatch, and a configured SDO
    // write the node refuses (0x1000 is read-only). Each is reported with
    // its reason and the node is not started.
    let mut events = node_events(&c, vec![1, 4, 5]).await;
    send_nmt(&c, 0, pb::NmtCommand::ResetCommunication).await;
    let mut reasons = std::collections::BTreeMap::new();
    // Node 1 reboots too: the RPDO below must wait for its boot procedure
    // to start it again (an RPDO to a pre-operational node is ignored).
    let mut node1_booted = false;
    tokio::time::timeout(WAIT, async {
        while reasons.len() < 2 || !node1_booted {
            let ev = events.message().await.unwrap().unwrap();
            match ev.event {
                Some(Event::BootFailed(f)) => {
                    reasons.insert(ev.node, f.reason);
                }
                Some(Event::BootCompleted(_)) if ev.node == 1 => node1_booted = true,
                _ => {}
            }
        }
    })
    .await
    .expect("both boot failures and node 1's boot reported");
    assert!(reasons[&4].contains("vendor id mismatch"), "{reasons:?}");
    assert!(
        reasons[&5].contains("writing 0x1000:00") && reasons[&5].contains("0x06010002"),
        "{reasons:?}"
    );

    // WritePdo: RPDO1 of the drive EDS maps controlword + target position.
    let v = |index, ty: pb::DataType, value| pb::PdoValue {
        index,
        subindex: 0,
        name: String::new(),
        value: Some(pb::Value {
            r#type: ty as i32,
            value: Some(value),
        }),
    };
    let r = c
        .canopen_client()
        .write_pdo(pb::WritePdoRequest {
            bus: "can0".into(),
            node: 1,
            pdo: 1,
            values: vec![
                v(
                    0x6040,
                    pb::DataType::Unsigned16,
                    pb::value::Value::UintValue(0x0F),
                ),
                v(
                    0x607A,
                    pb::DataType::Integer32,
                    pb::value::Value::IntValue(-1000),
                ),
            ],
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.data, vec![0x0F, 0x00, 0x18, 0xFC, 0xFF, 0xFF]);
    let target = tokio::time::timeout(WAIT, async {
        loop {
            let r = c
                .clone()
                .read_sdo(pb::ReadSdoRequest {
                    bus: "can0".into(),
                    node: 1,
                    index: 0x607A,
                    subindex: 0,
                    r#type: 0,
                    options: None,
                    object: String::new(),
                })
                .await
                .unwrap();
            if r.raw == vec![0x18, 0xFC, 0xFF, 0xFF] {
                return r;
            }
            // Poll, do not hammer: the per-client rate limit applies to
            // tests too.
            tokio::time::sleep(std::time::Duration::from_millis(5)).await;
        }
    })
    .await
    .expect("the RPDO reached the node");
    assert_eq!(
        target.value.unwrap().value,
        Some(pb::value::Value::IntValue(-1000))
    );

    // A value that does not fit the mapping is refused before the bus.
    let err = c
        .canopen_client()
        .write_pdo(pb::WritePdoRequest {
            bus: "can0".into(),
            node: 1,
            pdo: 1,
            values: vec![v(
                0x6040,
                pb::DataType::Unsigned16,
                pb::value::Value::UintValue(0x0F),
            )],
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::InvalidArgument);
    server.shutdown();
}
