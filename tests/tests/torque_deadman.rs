//! A torque command does not outlive its control: when the lease that set
//! it is released or lapses (its client died, or stopped renewing), the
//! target torque (0x6071) goes to 0 and the axis is brought to rest.

use cangate_client::pb;
use cangate_tests::axes::*;
use cangate_tests::*;
use std::time::{Duration, Instant};

/// T: a CST axis on simulated node 2 (guard at 30 mm/s), SYNC 5 ms.
const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"
sync_period_us = 5000

[[canopen.node]]
id = 2
eds = "builtin:drive"
simulate = true

[[axis]]
name = "T"
bus = "can0"
node = 2
counts_per_unit = 1000.0
mode = "cst"
min_position = -5000.0
max_position = 5000.0
max_velocity = 30.0
max_acceleration = 1000.0
max_torque = 300.0
"#;

const LONG: Duration = Duration::from_secs(30);

fn torque(per_mille: f64, lease: &str) -> pb::SetTorqueRequest {
    pb::SetTorqueRequest {
        axis: "T".into(),
        torque_per_mille: per_mille,
        options: opts(lease, false),
    }
}

/// The drive's target torque (0x6071, per mille), read by SDO.
async fn target_torque(c: &mut cangate_client::Client) -> i16 {
    let r = c
        .read_sdo(pb::ReadSdoRequest {
            bus: "can0".into(),
            node: 2,
            index: 0x6071,
            subindex: 0,
            r#type: 0,
            options: None,
            object: String::new(),
        })
        .await
        .unwrap();
    i16::from_le_bytes([r.raw[0], r.raw[1]])
}

/// T under 30 per mille, turning at more than 5 mm/s, under `lease`.
async fn turning(axes: &mut Axes, c: &mut cangate_client::Client, lease: &str) {
    enable(axes, "T", lease).await;
    let r = axes
        .set_torque(torque(30.0, lease))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Accepted as i32, "{r:?}");
    wait_status(axes, "T", |s| s.velocity > 5.0).await;
    assert_eq!(target_torque(c).await, 30);
}

/// Waits until the drive's target torque is 0 and T stands still, idle.
async fn torque_off_at_rest(axes: &mut Axes, c: &mut cangate_client::Client) {
    let t0 = Instant::now();
    loop {
        let s = status(axes, "T").await;
        let tq = target_torque(c).await;
        if tq == 0 && s.velocity.abs() < 0.01 && s.activity == pb::AxisActivity::Idle as i32 {
            return;
        }
        assert!(
            t0.elapsed() < LONG,
            "T still under torque {tq} or moving: {s:?}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

async fn status(axes: &mut Axes, axis: &str) -> pb::AxisStatus {
    axes.get_axis(pb::GetAxisRequest { axis: axis.into() })
        .await
        .unwrap()
        .into_inner()
        .status
        .unwrap()
}

async fn setup() -> (cangate_server::RunningServer, cangate_client::Client, Axes) {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut axes: Axes = pb::axes_client::AxesClient::new(c.channel());
    wait_ready(&mut axes, &["T"]).await;
    (server, c, axes)
}

/// The client releases its lease while its torque runs.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_released_lease_takes_the_torque_off_and_stops_the_axis() {
    let (server, mut c, mut axes) = setup().await;
    let lease = acquire(&mut axes, &["T"], 30_000, "torque").await;
    turning(&mut axes, &mut c, &lease).await;
    axes.release_control(pb::ReleaseControlRequest {
        lease: lease.clone(),
    })
    .await
    .unwrap();
    torque_off_at_rest(&mut axes, &mut c).await;
    server.shutdown();
}

/// The client stops renewing (it died): the lease lapses.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lapsed_lease_takes_the_torque_off_and_stops_the_axis() {
    let (server, mut c, mut axes) = setup().await;
    let lease = acquire(&mut axes, &["T"], 400, "dies").await;
    enable(&mut axes, "T", &lease).await;
    let r = axes
        .set_torque(torque(30.0, &lease))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Accepted as i32, "{r:?}");
    torque_off_at_rest(&mut axes, &mut c).await;
    server.shutdown();
}
