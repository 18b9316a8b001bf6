//! The feed-forward of a position stream end to end: a simulated CSP
//! drive whose EDS has the velocity and torque offsets (the builtin
//! drive) gets them mapped in RPDO3 and, with every SYNC of a stream, the
//! client's feed-forward interpolated (0x60B1 in counts/s, 0x60B2 in per
//! mille; the drive records them, read back by SDO); the status says the
//! feed-forward is sent; once the stream is over both offsets are 0.

use cangate_client::pb;
use cangate_client::{DataType, NodeId, ObjectAddress, SdoValue, SetpointStreamOptions};
use cangate_tests::axes::*;
use cangate_tests::streams::read_until;
use cangate_tests::*;
use std::time::Duration;

/// P: CSP on node 3, 1000 counts/mm. SYNC every 5 ms.
const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"
sync_period_us = 5000

[[canopen.node]]
id = 3
eds = "builtin:drive"
simulate = true

[[axis]]
name = "P"
bus = "can0"
node = 3
counts_per_unit = 1000.0
mode = "csp"
min_position = -200.0
max_position = 200.0
max_velocity = 100.0
max_acceleration = 1000.0
max_torque = 300.0
"#;

/// The path (mm) at `s` seconds: from rest up to 10 mm/s at 100 mm/s²
/// (0.1 s), on at 10 mm/s; its velocity the feed-forward.
fn path(s: f64) -> (f64, f64) {
    if s < 0.1 {
        (50.0 * s * s, 100.0 * s)
    } else {
        (0.5 + 10.0 * (s - 0.1), 10.0)
    }
}

async fn read_offsets(c: &cangate_client::Client) -> (i32, i16) {
    let co = c.canopen("can0");
    let node = NodeId::new(3).unwrap();
    let v = co
        .read(node, ObjectAddress::new(0x60B1, 0), DataType::Integer32)
        .await
        .unwrap();
    let t = co
        .read(node, ObjectAddress::new(0x60B2, 0), DataType::Integer16)
        .await
        .unwrap();
    match (v, t) {
        (SdoValue::I32(v), SdoValue::I16(t)) => (v, t),
        other => panic!("{other:?}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_feed_forward_of_a_position_stream_reaches_the_drive() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut axes = c.axes_client();
    wait_ready(&mut axes, &["P"]).await;
    let lease = c
        .acquire_control_as(&["P"], Duration::from_secs(5), "feed-forward")
        .await
        .unwrap();
    enable(&mut axes, "P", lease.token()).await;
    let options = SetpointStreamOptions {
        depth: Duration::from_millis(50),
        extrapolate: Some(Duration::from_millis(50)),
        point_period: Some(Duration::from_millis(1)),
        status_period: Some(Duration::from_millis(10)),
    };
    let mut stream = c.stream_setpoints(&lease, &["P"], options).await.unwrap();
    // 3 s of path, all sent at once (the client's clock runs ahead: the
    // playout follows the fastest arrival, so it plays in real time).
    let points: Vec<pb::Setpoint> = (0..3000u64)
        .map(|k| {
            let (x, v) = path(k as f64 / 1000.0);
            pb::Setpoint {
                t_us: k * 1000,
                positions: vec![x],
                velocities: vec![v],
                torques: vec![40.0],
            }
        })
        .collect();
    for batch in points.chunks(500) {
        stream.send(batch.to_vec()).await.unwrap();
    }
    let mut seen = Vec::new();
    let s = read_until(&mut stream, &mut seen, |s| {
        s.commanded_positions.first().is_some_and(|x| *x > 2.0)
    })
    .await
    .unwrap()
    .expect("P moves at 10 mm/s");
    assert_eq!(s.velocity_feed_forward_sent, [true]);
    assert_eq!(s.torque_feed_forward_sent, [true]);
    // At 10 mm/s: 10 000 counts/s, 40 per mille.
    assert_eq!(read_offsets(&c).await, (10_000, 40));
    drop(stream);
    wait_status(&mut axes, "P", |s| {
        s.activity == pb::AxisActivity::Idle as i32 && s.velocity.abs() < 0.01
    })
    .await;
    assert_eq!(read_offsets(&c).await, (0, 0));
    server.shutdown();
}
