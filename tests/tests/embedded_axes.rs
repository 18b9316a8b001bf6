//! The axes as an embedding program sees them: the server's runtime called
//! directly (no gRPC) gets the same control rules as a remote client.

use cangate_axis::lease::LeaseError;
use cangate_axis::{AxisCommand, Outcome};
use cangate_client::pb;
use cangate_server::axes::{AxisError, Caller};
use cangate_tests::axes::*;
use cangate_tests::*;

/// One simulated cyclic drive, axis X.
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

/// While a remote client holds X's control lease, an embedding program's
/// command without a lease is refused by the runtime itself, naming the
/// holder; its stop is never refused.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_direct_command_without_the_lease_is_refused_and_a_stop_is_not() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut remote: Axes = pb::axes_client::AxesClient::new(c.channel());
    wait_ready(&mut remote, &["X"]).await;
    let _lease = acquire(&mut remote, &["X"], 60_000, "remote").await;

    let axes = server.gateway().axes().clone();
    let x = axes.index("X").unwrap();
    let embedded = Caller::new("embedding program");
    let refused = axes
        .command(x, AxisCommand::Enable, &embedded, false, WAIT)
        .await
        .expect_err("an enable without the lease must be refused");
    assert!(
        matches!(refused, AxisError::Lease(LeaseError::Held { .. })),
        "{refused:?}"
    );
    assert!(
        refused.to_string().contains("controlled by remote"),
        "{refused}"
    );

    let stopped = axes
        .command(x, AxisCommand::Stop, &embedded, true, WAIT)
        .await
        .expect("a stop is never refused");
    assert_eq!(stopped.outcome, Some(Outcome::Completed), "{stopped:?}");
    let many = axes
        .stop_many(&[x], cangate_axis::StopKind::QuickStop, true, &embedded)
        .await
        .unwrap();
    assert!(many[0].is_ok(), "{many:?}");
    server.shutdown();
}

/// An embedding program that acquires the axis itself commands it with
/// its lease, and a remote client is then refused.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_direct_caller_with_its_lease_commands_the_axis() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut remote: Axes = pb::axes_client::AxesClient::new(c.channel());
    wait_ready(&mut remote, &["X"]).await;

    let axes = server.gateway().axes().clone();
    let x = axes.index("X").unwrap();
    let lease = axes
        .acquire(
            &["X".to_string()],
            Some(std::time::Duration::from_secs(60)),
            "embedded".into(),
            None,
        )
        .unwrap();
    let embedded = Caller::new("embedding program").with_lease(lease.token.clone());
    let enabled = axes
        .command(x, AxisCommand::Enable, &embedded, true, WAIT)
        .await
        .expect("the lease holder commands the axis");
    assert_eq!(enabled.outcome, Some(Outcome::Completed), "{enabled:?}");

    let e = remote
        .disable(cmd("X", "", false))
        .await
        .expect_err("a remote client without the lease is refused");
    assert!(e.message().contains("controlled by embedded"), "{e:?}");
    axes.release(&embedded).unwrap();
    server.shutdown();
}
