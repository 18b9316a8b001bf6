//! An axis task reads its drive's TPDOs from the bus itself (not through
//! the CANopen master task). What the master used to do with them must
//! still happen: StreamPdo shows them decoded and named, and the per-TPDO
//! receive counters count them; the axis itself follows the drive.

use cangate_client::pb;
use cangate_client::pb::axis_update::Update;
use cangate_tests::*;

const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"
sync_period_us = 5000

[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true
heartbeat_timeout_ms = 300

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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn axis_tpdos_reach_stream_pdo_the_counters_and_the_axis() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;

    // StreamPdo: TPDO1 of the axis's drive, decoded with the EDS names.
    let mut pdos = c
        .canopen_client()
        .stream_pdo(pb::StreamPdoRequest {
            bus: "can0".into(),
            nodes: vec![1],
        })
        .await
        .unwrap()
        .into_inner();
    let tpdo1 = tokio::time::timeout(WAIT, async {
        loop {
            let m = pdos.message().await.unwrap().unwrap();
            if m.pdo == 1 {
                return m;
            }
        }
    })
    .await
    .expect("TPDO1 of the axis drive on StreamPdo");
    assert_eq!(tpdo1.node, 1);
    assert_eq!(tpdo1.cob_id, 0x181);
    let objects: Vec<(u32, u32)> = tpdo1.values.iter().map(|v| (v.index, v.subindex)).collect();
    assert_eq!(objects, vec![(0x6041, 0), (0x6064, 0), (0x6061, 0)]);
    assert!(
        tpdo1.values.iter().all(|v| !v.name.is_empty()),
        "named from the EDS: {:?}",
        tpdo1.values
    );

    // The receive counters count the TPDOs the axis task reads.
    let master = server.gateway().canopen("can0").expect("CANopen master");
    let count = |num: u16| {
        master
            .tpdo_counts()
            .iter()
            .find(|(node, n, _)| node.get() == 1 && *n == num)
            .map(|(_, _, count)| *count)
            .unwrap_or(0)
    };
    tokio::time::timeout(WAIT, async {
        while count(1) == 0 || count(2) == 0 {
            tokio::time::sleep(std::time::Duration::from_millis(5)).await;
        }
    })
    .await
    .expect("TPDO1 and TPDO2 counted");

    // The axis follows the drive: a status with the drive's state.
    let mut axes = c.axes_client();
    let mut states = axes
        .stream_axis_state(pb::StreamAxisStateRequest {
            axes: vec!["X".into()],
            changes_only: false,
        })
        .await
        .unwrap()
        .into_inner();
    tokio::time::timeout(WAIT, async {
        loop {
            let u = states.message().await.unwrap().unwrap();
            if let Some(Update::Status(s)) = u.update
                && s.state != 0
                && s.timestamp_us > 0
            {
                return;
            }
        }
    })
    .await
    .expect("axis status from the drive's TPDOs");
}
