//! Layer setting services (CiA 305): `cangate lss scan|set-id|inquire`.

use super::{App, Context, Result, node_id, print_json};
use cangate_client::{LssDevice, NodeId, pb};
use clap::{Args, Subcommand};
use std::time::Duration;

/// `cangate lss …`
#[derive(Args, Debug)]
pub(crate) struct LssArgs {
    #[command(subcommand)]
    verb: LssVerb,
}

#[derive(Subcommand, Debug)]
enum LssVerb {
    /// Find every unconfigured device (no node-ID) by LSS fastscan and
    /// print their identities (vendor, product, revision, serial).
    Scan {
        /// Bus.
        bus: String,
        /// How long each fastscan step listens, in ms (the gateway's
        /// default: 20); a scan takes 133 steps per device.
        #[arg(long, value_name = "MS", value_parser = clap::value_parser!(u32).range(1..=1000))]
        step_ms: Option<u32>,
    },
    /// Give a device a node-ID: the unconfigured device with this serial
    /// number (found by fastscan), or, with --vendor, --product and
    /// --revision too, the device with that whole identity (configured or
    /// not). Stored in the device unless --no-store; the device then boots
    /// up with it.
    SetId {
        /// Bus.
        bus: String,
        /// Serial number (0x1018:04; decimal or 0x hex).
        #[arg(long, value_parser = number)]
        serial: u32,
        /// Vendor-ID (0x1018:01).
        #[arg(long, value_parser = number, requires_all = ["product", "revision"])]
        vendor: Option<u32>,
        /// Product code (0x1018:02).
        #[arg(long, value_parser = number, requires_all = ["vendor", "revision"])]
        product: Option<u32>,
        /// Revision number (0x1018:03).
        #[arg(long, value_parser = number, requires_all = ["vendor", "product"])]
        revision: Option<u32>,
        /// The node-ID, 1..=127.
        #[arg(value_parser = node_id)]
        node: NodeId,
        /// Configure only; do not store (lost at the device's next reset
        /// or power cycle).
        #[arg(long)]
        no_store: bool,
        /// Give the id even when it is in use (heard on the bus in the last
        /// minute, an axis's drive's, or configured for another device).
        #[arg(long)]
        force: bool,
    },
    /// Identity and node-ID of the only device on the bus (or of the one
    /// with --vendor/--product/--revision/--serial).
    Inquire {
        /// Bus.
        bus: String,
        /// Vendor-ID.
        #[arg(long, value_parser = number, requires_all = ["product", "revision", "serial"])]
        vendor: Option<u32>,
        /// Product code.
        #[arg(long, value_parser = number, requires_all = ["vendor", "revision", "serial"])]
        product: Option<u32>,
        /// Revision number.
        #[arg(long, value_parser = number, requires_all = ["vendor", "product", "serial"])]
        revision: Option<u32>,
        /// Serial number.
        #[arg(long, value_parser = number, requires_all = ["vendor", "product", "revision"])]
        serial: Option<u32>,
    },
}

/// A clap value parser: a u32 in decimal or 0x hex.
fn number(text: &str) -> std::result::Result<u32, String> {
    let t = text.trim();
    let r = match t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        Some(h) => u32::from_str_radix(h, 16),
        None => t.parse(),
    };
    r.map_err(|_| format!("{text:?} is not a 32-bit number (decimal or 0x hex)"))
}

fn identity_text(i: &pb::LssIdentity) -> String {
    format!(
        "vendor 0x{:08X}  product 0x{:08X}  revision 0x{:08X}  serial 0x{:08X} ({})",
        i.vendor_id, i.product_code, i.revision, i.serial, i.serial
    )
}

pub(crate) async fn run(app: &App, a: LssArgs) -> Result<()> {
    match a.verb {
        LssVerb::Scan { bus, step_ms } => {
            let step = step_ms.map(|ms| Duration::from_millis(u64::from(ms)));
            let started = std::time::Instant::now();
            let found = app
                .client
                .lss(&bus)
                .fastscan(step)
                .await
                .ctx(format!("LSS fastscan on {bus}"))?;
            if app.json {
                return print_json(&pb::FastscanResponse {
                    devices: found,
                    elapsed_ms: started.elapsed().as_millis() as u64,
                });
            }
            if found.is_empty() {
                return app.line("no unconfigured device answered");
            }
            let lines: Vec<String> = found.iter().map(identity_text).collect();
            app.line(lines.join("\n"))
        }
        LssVerb::SetId {
            bus,
            serial,
            vendor,
            product,
            revision,
            node,
            no_store,
            force,
        } => {
            let device = match (vendor, product, revision) {
                (Some(vendor_id), Some(product_code), Some(revision)) => {
                    LssDevice::Identity(pb::LssIdentity {
                        vendor_id,
                        product_code,
                        revision,
                        serial,
                    })
                }
                _ => LssDevice::Serial(serial),
            };
            let lss = app.client.lss(&bus);
            let assigned = if force {
                lss.assign_node_id_forced(device, node, !no_store).await
            } else {
                lss.assign_node_id(device, node, !no_store).await
            };
            let r = assigned.ctx(format!("LSS: giving node-ID {node} on {bus}"))?;
            if app.json {
                return print_json(&r);
            }
            let previous = match r.previous_node_id {
                255 => "none".to_string(),
                n => n.to_string(),
            };
            app.line(format!(
                "node-ID {} {} (was {previous}): {}",
                r.node_id,
                if r.stored {
                    "set and stored"
                } else {
                    "set, not stored"
                },
                identity_text(&r.identity.unwrap_or_default())
            ))
        }
        LssVerb::Inquire {
            bus,
            vendor,
            product,
            revision,
            serial,
        } => {
            let identity = match (vendor, product, revision, serial) {
                (Some(vendor_id), Some(product_code), Some(revision), Some(serial)) => {
                    Some(pb::LssIdentity {
                        vendor_id,
                        product_code,
                        revision,
                        serial,
                    })
                }
                _ => None,
            };
            let (identity, node) = app
                .client
                .lss(&bus)
                .inquire(identity)
                .await
                .ctx(format!("LSS inquire on {bus}"))?;
            if app.json {
                return print_json(&pb::InquireResponse {
                    identity: Some(identity),
                    node_id: node,
                });
            }
            let node = match node {
                255 => "none (unconfigured)".to_string(),
                n => n.to_string(),
            };
            app.line(format!("{}\nnode-ID {node}", identity_text(&identity)))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    fn parse(args: &[&str]) -> LssVerb {
        #[derive(Parser)]
        struct T {
            #[command(subcommand)]
            verb: LssVerb,
        }
        T::try_parse_from(std::iter::once("lss").chain(args.iter().copied()))
            .map(|t| t.verb)
            .unwrap_or_else(|e| panic!("{e}"))
    }

    #[test]
    fn set_id_takes_a_serial_or_a_whole_identity() {
        let LssVerb::SetId {
            serial,
            vendor,
            node,
            no_store,
            force,
            ..
        } = parse(&["set-id", "can0", "--serial", "0xCAFE", "20"])
        else {
            panic!()
        };
        assert_eq!(
            (serial, vendor, node.get(), no_store, force),
            (0xCAFE, None, 20, false, false)
        );
        let LssVerb::SetId { force, .. } =
            parse(&["set-id", "can0", "--serial", "0xCAFE", "1", "--force"])
        else {
            panic!()
        };
        assert!(force);
        let LssVerb::SetId {
            vendor,
            product,
            revision,
            no_store,
            ..
        } = parse(&[
            "set-id",
            "can0",
            "--serial",
            "7",
            "--vendor",
            "0x4D2",
            "--product",
            "16",
            "--revision",
            "1",
            "21",
            "--no-store",
        ])
        else {
            panic!()
        };
        assert_eq!(
            (vendor, product, revision, no_store),
            (Some(0x4D2), Some(16), Some(1), true)
        );
    }
}
