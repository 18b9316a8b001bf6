//! `cangate fleet --broker URL`: the gateways an MQTT broker or a NATS
//! server has seen, from the statuses of their plant bridges. Needs no
//! gateway.

use super::{Failure, Result, print_json_line};
use clap::Args;
use std::time::Duration;

/// `cangate fleet`
#[derive(Args, Debug)]
pub(crate) struct FleetArgs {
    /// The broker: mqtt://host[:port], nats://host[:port] or
    /// tls://host[:port].
    #[arg(long, value_name = "URL")]
    broker: String,
    /// How long to wait for the broker, ms.
    #[arg(long, value_name = "MS", default_value_t = 5000)]
    wait_ms: u64,
}

/// Lists the gateways: id, online or offline, version, start time, buses
/// and axes; with --json one GatewayStatus a line.
pub(crate) async fn run(args: FleetArgs, json: bool) -> Result<()> {
    let found = cangate_client::fleet::gateways(&args.broker, Duration::from_millis(args.wait_ms))
        .await
        .map_err(|e| Failure::failed("fleet", e.to_string()))?;
    if json {
        for s in found.values() {
            print_json_line(s)?;
        }
        return Ok(());
    }
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    writeln!(
        out,
        "{:<20} {:<8} {:<10} {:<20} BUSES / AXES",
        "GATEWAY", "STATE", "VERSION", "STARTED (ns)"
    )?;
    for s in found.values() {
        writeln!(
            out,
            "{:<20} {:<8} {:<10} {:<20} {} / {}",
            s.gateway,
            if s.online { "online" } else { "offline" },
            s.version,
            s.started_ns,
            s.buses.join(","),
            s.axes.join(","),
        )?;
    }
    out.flush()?;
    Ok(())
}
