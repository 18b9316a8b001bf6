//! Axes as a benchmark's client commands them: waiting until their drives
//! are up, then holding a control lease (commands need one) and enabling
//! them.

use anyhow::{Result, bail};
use cangate_client::pb;
use std::time::{Duration, Instant};

/// The generated Axes client on the client's transport.
pub type AxesClient = pb::axes_client::AxesClient<cangate_client::Transport>;

/// Whether an axis can take commands: its drive reports a state and its
/// node is not lost.
pub fn is_up(axis: &pb::Axis) -> bool {
    axis.status
        .as_ref()
        .is_some_and(|s| s.state != 0 && !s.node_lost)
}

/// The names of the axes that are up ([`is_up`]) and how many axes the
/// gateway has.
pub async fn axes_up(axes: &mut AxesClient) -> Result<(Vec<String>, usize)> {
    let list = axes
        .list_axes(pb::ListAxesRequest {})
        .await?
        .into_inner()
        .axes;
    let up = list
        .iter()
        .filter(|a| is_up(a))
        .map(|a| a.name.clone())
        .collect();
    Ok((up, list.len()))
}

/// Waits until every axis of `names` is up; an error after `limit`.
pub async fn wait_up(axes: &mut AxesClient, names: &[&str], limit: Duration) -> Result<()> {
    let t0 = Instant::now();
    loop {
        let (up, _) = axes_up(axes).await?;
        if names.iter().all(|n| up.iter().any(|u| u == n)) {
            return Ok(());
        }
        if t0.elapsed() > limit {
            bail!("axes did not come up within {limit:?}: only {up:?} of {names:?}");
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// The options of a command under `lease`; with `wait`, the call returns
/// when the command completed (or failed), at most `wait_timeout` later.
pub fn command_options(
    lease: &str,
    wait: bool,
    wait_timeout: Duration,
) -> Option<pb::CommandOptions> {
    Some(pb::CommandOptions {
        lease: lease.into(),
        wait,
        wait_timeout_ms: u32::try_from(wait_timeout.as_millis()).unwrap_or(u32::MAX),
    })
}

/// Takes control of `names` for `ttl` (renewed by the caller if it runs
/// longer) under `client_name`; returns the lease token.
pub async fn acquire(
    axes: &mut AxesClient,
    names: &[&str],
    ttl: Duration,
    client_name: &str,
) -> Result<String, tonic::Status> {
    Ok(axes
        .acquire_control(pb::AcquireControlRequest {
            axes: names.iter().map(|s| s.to_string()).collect(),
            ttl_ms: u32::try_from(ttl.as_millis()).unwrap_or(u32::MAX),
            client_name: client_name.into(),
        })
        .await?
        .into_inner()
        .lease)
}

/// Takes control of `names` for a minute and enables each of them, waiting
/// for every enable to complete: axes ready to move. Returns the lease.
pub async fn take(axes: &mut AxesClient, names: &[&str], client_name: &str) -> Result<String> {
    let lease = acquire(axes, names, Duration::from_secs(60), client_name).await?;
    for n in names {
        let r = axes
            .enable(pb::AxisCommandRequest {
                axis: n.to_string(),
                options: command_options(&lease, true, Duration::from_secs(30)),
            })
            .await?
            .into_inner();
        if r.outcome != pb::Outcome::Completed as i32 {
            bail!("enable {n}: {}", r.detail);
        }
    }
    Ok(lease)
}
