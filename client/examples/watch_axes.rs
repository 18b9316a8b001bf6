//! Prints the live state of axes, one line per status update, and their
//! events (motion done, faults, control changes, node loss).
//!
//! ```sh
//! cargo run -p cangate-server &                      # the demo on 127.0.0.1:50051
//! cargo run -p cangate-client --example watch_axes -- X Z
//! cargo run -p cangate-client --example watch_axes -- --server 10.0.0.5:50051 --changes-only
//! ```
//!
//! Options: `--server ADDR` (default `CANGATE_SERVER` or 127.0.0.1:50051),
//! `--changes-only` (skip identical statuses), `--for SECONDS` (stop after);
//! the rest are axis names (none: all axes). Ctrl-C ends it.

use cangate_client::{AxisUpdate, ConnectOptions, DriveState, pb};
use futures::StreamExt;
use std::time::Duration;

#[tokio::main]
async fn main() {
    if let Err(e) = run().await {
        eprintln!("watch_axes: {e}");
        std::process::exit(1);
    }
}

async fn run() -> Result<(), Box<dyn std::error::Error>> {
    let mut server = std::env::var("CANGATE_SERVER").unwrap_or_else(|_| "127.0.0.1:50051".into());
    let mut changes_only = false;
    let mut limit = None;
    let mut axes = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--server" => server = args.next().ok_or("--server needs an address")?,
            "--changes-only" => changes_only = true,
            "--for" => {
                let s: f64 = args.next().ok_or("--for needs seconds")?.parse()?;
                limit = Some(Duration::from_secs_f64(s));
            }
            _ => axes.push(a),
        }
    }
    let options = ConnectOptions {
        request_timeout: Some(Duration::from_secs(10)),
        ..Default::default()
    };
    let client = cangate_client::connect_with(&server, &options).await?;
    let names: Vec<&str> = axes.iter().map(String::as_str).collect();
    let mut updates = client.watch_axes(&names, changes_only).await?;
    let deadline = async {
        match limit {
            Some(d) => tokio::time::sleep(d).await,
            None => std::future::pending().await,
        }
    };
    tokio::pin!(deadline);
    loop {
        let update = tokio::select! {
            u = updates.next() => u,
            _ = tokio::signal::ctrl_c() => return Ok(()),
            _ = &mut deadline => return Ok(()),
        };
        match update {
            None => {
                println!("the gateway ended the stream");
                return Ok(());
            }
            Some(Err(e)) => return Err(e.into()),
            Some(Ok(u)) => println!("{}", line(&u)),
        }
    }
}

fn line(u: &AxisUpdate) -> String {
    match u {
        AxisUpdate::Status(s) => {
            let state = DriveState::try_from(s.state)
                .map_or("?", |d| d.as_str_name().trim_start_matches("DRIVE_STATE_"));
            let activity = pb::AxisActivity::try_from(s.activity).map_or("?", |a| {
                a.as_str_name().trim_start_matches("AXIS_ACTIVITY_")
            });
            let mut text = format!(
                "{:<3} {state:<22} {activity:<9} pos {:>10.3} vel {:>9.3} ferr {:>7.3}",
                s.axis, s.position, s.velocity, s.following_error
            );
            if s.homed {
                text.push_str(" homed");
            }
            if !s.controlled_by.is_empty() {
                text.push_str(&format!(" held by {}", s.controlled_by));
            }
            if !s.fault_text.is_empty() {
                text.push_str(&format!(" FAULT 0x{:04X} {}", s.fault_code, s.fault_text));
            }
            text
        }
        AxisUpdate::MotionDone {
            axis,
            command,
            outcome,
            detail,
        } => format!(
            "{axis:<3} {command} ended: {} {detail}",
            outcome.as_str_name().trim_start_matches("OUTCOME_")
        ),
        AxisUpdate::Fault {
            axis,
            code,
            text,
            active,
        } => {
            if *active {
                format!("{axis:<3} fault 0x{code:04X} {text}")
            } else {
                format!("{axis:<3} fault cleared")
            }
        }
        AxisUpdate::ControlChange {
            axis,
            holder,
            reason,
            ..
        } => format!("{axis:<3} control: {reason} {holder}"),
        AxisUpdate::NodeLink { axis, lost, reason } => format!(
            "{axis:<3} node {}: {reason}",
            if *lost { "lost" } else { "back" }
        ),
        AxisUpdate::Lost(n) => format!("(this stream missed {n} updates)"),
        _ => format!("{u:?}"),
    }
}
