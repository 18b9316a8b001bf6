//! The simulated CiA 402 drives of the demo answer like drives: enabled by
//! controlword writes over SDO, a profile-position move reaches its target
//! and the TPDO stream shows the position getting there.

use cangate_client::pb;
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
"#;

fn raw(index: u32, sub: u32, data: Vec<u8>) -> pb::WriteSdoRequest {
    pb::WriteSdoRequest {
        bus: "can0".into(),
        node: 1,
        index,
        subindex: sub,
        data: Some(pb::write_sdo_request::Data::Raw(data)),
        options: None,
        object: String::new(),
        force: false,
    }
}

async fn statusword(c: &mut cangate_client::Client) -> u16 {
    let r = c
        .read_sdo(pb::ReadSdoRequest {
            bus: "can0".into(),
            node: 1,
            index: 0x6041,
            subindex: 0,
            r#type: 0,
            options: None,
            object: String::new(),
        })
        .await
        .unwrap();
    u16::from_le_bytes([r.raw[0], r.raw[1]])
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn simulated_drive_enables_and_moves() {
    let server = start_server(CONFIG).await;
    let mut c = client(&server).await;
    assert_eq!(
        statusword(&mut c).await & 0x006F,
        0x0040,
        "switch on disabled after boot"
    );

    c.write_sdo(raw(0x6060, 0, vec![1])).await.unwrap(); // profile position
    c.write_sdo(raw(0x6081, 0, 50_000u32.to_le_bytes().to_vec()))
        .await
        .unwrap();
    for (cw, state) in [(0x0006u16, 0x0021u16), (0x0007, 0x0023), (0x000F, 0x0027)] {
        c.write_sdo(raw(0x6040, 0, cw.to_le_bytes().to_vec()))
            .await
            .unwrap();
        assert_eq!(
            statusword(&mut c).await & 0x006F,
            state,
            "after controlword {cw:#06X}"
        );
    }

    let mut pdos = c
        .canopen_client()
        .stream_pdo(pb::StreamPdoRequest {
            bus: "can0".into(),
            nodes: vec![1],
        })
        .await
        .unwrap()
        .into_inner();
    // NMT start so the TPDOs flow, then a new set-point (bit 4) to 10,000.
    send_nmt(&c, 1, pb::NmtCommand::Start).await;
    c.write_sdo(raw(0x607A, 0, 10_000i32.to_le_bytes().to_vec()))
        .await
        .unwrap();
    c.write_sdo(raw(0x6040, 0, 0x001Fu16.to_le_bytes().to_vec()))
        .await
        .unwrap();
    c.write_sdo(raw(0x6040, 0, 0x000Fu16.to_le_bytes().to_vec()))
        .await
        .unwrap();

    // TPDO1 (statusword, position actual) until the target is reached.
    let mut last = i64::MIN;
    tokio::time::timeout(WAIT, async {
        loop {
            let m = pdos.message().await.unwrap().unwrap();
            if m.pdo != 1 {
                continue;
            }
            let sw = match m.values[0].value.as_ref().unwrap().value {
                Some(pb::value::Value::UintValue(v)) => v as u16,
                ref other => panic!("{other:?}"),
            };
            let pos = match m.values[1].value.as_ref().unwrap().value {
                Some(pb::value::Value::IntValue(v)) => v,
                ref other => panic!("{other:?}"),
            };
            assert!(
                pos >= last,
                "position never moves backwards: {last} -> {pos}"
            );
            last = pos;
            if pos == 10_000 && sw & 0x0400 != 0 {
                return;
            }
        }
    })
    .await
    .expect("the move reaches 10,000 with target reached");
    server.shutdown();
}
