//! Helpers of the Axes end-to-end tests: commands with a lease, waiting
//! for a status, a drive the test runs itself (to fault it or switch it
//! off).

use crate::WAIT;
use cangate_client::pb;
use cangate_sim::{DeviceHandle, SimDrive, SimDriveOptions, SimNodeOptions};
use std::time::Duration;
use tokio_util::sync::CancellationToken;

/// The Axes client.
pub type Axes = pb::axes_client::AxesClient<cangate_client::Transport>;

/// Takes control of `names` for `ttl_ms` as `who`; the lease token.
pub async fn acquire(axes: &mut Axes, names: &[&str], ttl_ms: u32, who: &str) -> String {
    axes.acquire_control(pb::AcquireControlRequest {
        axes: names.iter().map(|s| s.to_string()).collect(),
        ttl_ms,
        client_name: who.into(),
    })
    .await
    .unwrap()
    .into_inner()
    .lease
}

/// Command options with `lease`, waiting for completion when `wait`.
pub fn opts(lease: &str, wait: bool) -> Option<pb::CommandOptions> {
    Some(pb::CommandOptions {
        lease: lease.into(),
        wait,
        wait_timeout_ms: 10_000,
    })
}

/// A parameterless command (Enable, Home, ResetFault, …) of `axis`.
pub fn cmd(axis: &str, lease: &str, wait: bool) -> pb::AxisCommandRequest {
    pb::AxisCommandRequest {
        axis: axis.into(),
        options: opts(lease, wait),
    }
}

/// Waits (polling slowly: some tests run under a low rate limit) until
/// every axis of `names` has process data from its booted drive.
pub async fn wait_ready(axes: &mut Axes, names: &[&str]) {
    let t0 = std::time::Instant::now();
    for name in names {
        loop {
            let s = axes
                .get_axis(pb::GetAxisRequest {
                    axis: name.to_string(),
                })
                .await
                .unwrap()
                .into_inner()
                .status
                .unwrap();
            if !s.node_lost && s.state != pb::DriveState::Unspecified as i32 {
                break;
            }
            assert!(t0.elapsed() < 3 * WAIT, "axis {name} never came up: {s:?}");
            tokio::time::sleep(Duration::from_millis(250)).await;
        }
    }
}

/// Enables `axis` and checks it reached OPERATION_ENABLED.
pub async fn enable(axes: &mut Axes, axis: &str, lease: &str) {
    let r = axes
        .enable(cmd(axis, lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    assert_eq!(
        r.status.unwrap().state,
        pb::DriveState::OperationEnabled as i32
    );
}

/// Polls GetAxis (every 20 ms, bounded by [`WAIT`]) until `f` holds.
pub async fn wait_status(
    axes: &mut Axes,
    axis: &str,
    f: impl Fn(&pb::AxisStatus) -> bool,
) -> pb::AxisStatus {
    let t0 = std::time::Instant::now();
    loop {
        let s = axes
            .get_axis(pb::GetAxisRequest { axis: axis.into() })
            .await
            .unwrap()
            .into_inner()
            .status
            .unwrap();
        if f(&s) {
            return s;
        }
        assert!(t0.elapsed() < WAIT, "{s:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// Runs a simulated drive at `node` on the server's virtual `can0`, on the
/// test's side (cancel the token to switch it off).
pub fn run_drive(
    server: &cangate_server::RunningServer,
    node: u32,
    heartbeat_ms: Option<u16>,
) -> (DeviceHandle<SimDrive>, CancellationToken) {
    let port = server
        .gateway()
        .network()
        .get("can0")
        .expect("virtual can0")
        .connect(false);
    let drive = SimDrive::bundled(
        cangate_canopen::NodeId::new(node).unwrap(),
        SimDriveOptions {
            node: SimNodeOptions {
                heartbeat_ms,
                ..SimNodeOptions::default()
            },
            ..SimDriveOptions::default()
        },
    );
    let handle = DeviceHandle::new(drive);
    let cancel = CancellationToken::new();
    cangate_sim::spawn_device(port, handle.clone(), cancel.clone());
    (handle, cancel)
}
