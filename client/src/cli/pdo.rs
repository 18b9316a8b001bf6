//! Process data objects: `cangate pdo watch|show|map|disable`.

use super::node::ns_text;
use super::{App, Cause, Context, Failure, Result, ctrl_c, node_id};
use cangate_client::{NodeId, SdoValue, pb};
use clap::{Args, Subcommand};

/// `cangate pdo …`
#[derive(Args, Debug)]
pub(crate) struct PdoArgs {
    #[command(subcommand)]
    verb: PdoVerb,
}

#[derive(Subcommand, Debug)]
enum PdoVerb {
    /// Decoded TPDOs (named, typed values) as they arrive, until Ctrl-C.
    Watch {
        /// Only this bus (default: every CANopen bus).
        bus: Option<String>,
        /// Only these node ids (repeatable).
        #[arg(long = "node", value_parser = node_id)]
        nodes: Vec<NodeId>,
    },
    /// A node's PDO configuration as the node holds it (read over SDO):
    /// COB-ID, valid, transmission type, inhibit time, event timer,
    /// mapped objects.
    Show {
        /// Bus.
        bus: String,
        /// Node id.
        #[arg(value_parser = node_id)]
        node: NodeId,
        /// Only this PDO: tpdo1, rpdo2, … (default: all).
        #[arg(value_parser = pdo_name)]
        pdo: Option<PdoName>,
    },
    /// Maps objects into a PDO and enables it (CiA 301 sequence): `pdo map
    /// can0 5 tpdo1 0x6041:0 0x6064:0 --sync 1`. An object is INDEX:SUB
    /// (its length from the EDS), INDEX:SUB/BITS, or its EDS name.
    Map {
        /// Bus.
        bus: String,
        /// Node id.
        #[arg(value_parser = node_id)]
        node: NodeId,
        /// The PDO: tpdo1, rpdo2, …
        #[arg(value_parser = pdo_name)]
        pdo: PdoName,
        /// The objects, in payload order (none: an empty PDO).
        objects: Vec<String>,
        /// Synchronous: sent (TPDO) or applied (RPDO) every N-th SYNC
        /// (transmission type N, 1..=240; 0: acyclic synchronous).
        #[arg(long, value_name = "N", conflicts_with = "transmission_type")]
        sync: Option<u8>,
        /// The transmission type as a number (default 255: event-driven).
        #[arg(long = "type", value_name = "TYPE")]
        transmission_type: Option<u8>,
        /// TPDO inhibit time in units of 100 µs.
        #[arg(long, value_name = "N100US", default_value_t = 0)]
        inhibit: u16,
        /// Event timer in ms (0: off).
        #[arg(long, value_name = "MS", default_value_t = 0)]
        event_timer: u16,
        /// COB-ID (default: the predefined one of PDO 1..4).
        #[arg(long, value_parser = parse_u32)]
        cob_id: Option<u32>,
        /// Configure the PDO but leave it disabled.
        #[arg(long)]
        disabled: bool,
    },
    /// Disables a PDO (COB-ID invalid), its mapping kept.
    Disable {
        /// Bus.
        bus: String,
        /// Node id.
        #[arg(value_parser = node_id)]
        node: NodeId,
        /// The PDO: tpdo1, rpdo2, …
        #[arg(value_parser = pdo_name)]
        pdo: PdoName,
    },
}

/// `tpdo1`, `rpdo4`, …
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct PdoName {
    kind: pb::PdoKind,
    num: u32,
}

fn pdo_name(text: &str) -> std::result::Result<PdoName, String> {
    let lower = text.to_ascii_lowercase();
    let (kind, num) = if let Some(n) = lower.strip_prefix("tpdo") {
        (pb::PdoKind::Tpdo, n)
    } else if let Some(n) = lower.strip_prefix("rpdo") {
        (pb::PdoKind::Rpdo, n)
    } else {
        return Err(format!(
            "{text:?} is not a PDO: write tpdo1..tpdo512 or rpdo1..rpdo512"
        ));
    };
    match num.parse::<u32>() {
        Ok(num @ 1..=512) => Ok(PdoName { kind, num }),
        _ => Err(format!("{text:?}: the PDO number must be 1..=512")),
    }
}

fn parse_u32(text: &str) -> std::result::Result<u32, String> {
    let t = text.trim();
    let r = match t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        Some(hex) => u32::from_str_radix(hex, 16),
        None => t.parse(),
    };
    r.map_err(|_| format!("{text:?} is not a number (decimal or 0x hex)"))
}

/// An object of `pdo map`: `INDEX:SUB[/BITS]` (hex index, sub-index hex
/// with 0x or decimal), or an EDS name.
fn mapped_object(text: &str) -> std::result::Result<pb::PdoMappedObject, String> {
    let starts_numeric = text.chars().next().is_some_and(|c| c.is_ascii_digit());
    if !starts_numeric {
        return Ok(pb::PdoMappedObject {
            object: text.to_string(),
            ..Default::default()
        });
    }
    let (addr, bits) = match text.split_once('/') {
        Some((a, b)) => (
            a,
            b.parse::<u32>()
                .map_err(|_| format!("{text:?}: {b:?} is not a length in bits"))?,
        ),
        None => (text, 0),
    };
    let (index, sub) = addr
        .split_once(':')
        .ok_or_else(|| format!("{text:?}: write INDEX:SUB (0x6041:0), optionally /BITS"))?;
    let index = u32::from_str_radix(index.trim_start_matches("0x").trim_start_matches("0X"), 16)
        .map_err(|_| format!("{text:?}: {index:?} is not a hex index"))?;
    let subindex = parse_u32(sub)?;
    Ok(pb::PdoMappedObject {
        index,
        subindex,
        bits,
        ..Default::default()
    })
}

fn kind_text(kind: i32) -> &'static str {
    match pb::PdoKind::try_from(kind) {
        Ok(pb::PdoKind::Rpdo) => "RPDO",
        Ok(pb::PdoKind::Tpdo) => "TPDO",
        _ => "PDO",
    }
}

fn transmission_text(t: u32) -> String {
    match t {
        0 => "0 (acyclic synchronous)".into(),
        1 => "1 (every SYNC)".into(),
        2..=240 => format!("{t} (every {t}th SYNC)"),
        252 | 253 => format!("{t} (on RTR)"),
        254 | 255 => format!("{t} (event-driven)"),
        _ => format!("{t} (reserved)"),
    }
}

/// One PDO as `pdo show` prints it.
pub(crate) fn pdo_config_text(p: &pb::PdoConfiguration) -> String {
    let mut text = format!(
        "{}{:<3} 0x{:03X}  {:<8}  type {}  inhibit {} µs  event timer {} ms",
        kind_text(p.kind),
        p.pdo,
        p.cob_id,
        if p.enabled { "enabled" } else { "disabled" },
        transmission_text(p.transmission_type),
        u64::from(p.inhibit_time_100us) * 100,
        p.event_timer_ms
    );
    if p.mapping.is_empty() {
        text.push_str("\n    (nothing mapped)");
    }
    for m in &p.mapping {
        text.push_str(&format!(
            "\n    0x{:04X}:{:02X}/{:<2}  {}",
            m.index, m.subindex, m.bits, m.name
        ));
    }
    text
}

fn pdo_text(m: &pb::PdoMessage) -> String {
    let values: Vec<String> = m
        .values
        .iter()
        .map(|v| {
            let name = if v.name.is_empty() {
                format!("0x{:04X}:{:02X}", v.index, v.subindex)
            } else {
                v.name.clone()
            };
            let value = v
                .value
                .as_ref()
                .and_then(|v| SdoValue::from_pb(v).ok())
                .map_or_else(|| "-".to_string(), |v| v.to_string());
            format!("{name}={value}")
        })
        .collect();
    format!(
        "{}  {}  node {:>3}  TPDO{} {:03X}  {}",
        ns_text(m.timestamp_ns),
        m.bus,
        m.node,
        m.pdo,
        m.cob_id,
        values.join("  ")
    )
}

/// `cangate pdo …`
pub(crate) async fn run(app: &App, a: PdoArgs) -> Result<()> {
    match a.verb {
        PdoVerb::Watch { bus, nodes } => watch(app, bus, nodes).await,
        PdoVerb::Show { bus, node, pdo } => {
            let what = format!("reading the PDOs of node {node} on {bus}");
            let pdos = app
                .client
                .canopen(&bus)
                .pdo_config(node, pdo.map(|p| p.kind), pdo.map_or(0, |p| p.num))
                .await
                .ctx(&what)?;
            if app.json {
                return super::print_json(&pdos);
            }
            if pdos.is_empty() {
                app.line(format!("node {node} on {bus} has no such PDO"))?;
            }
            for p in &pdos {
                app.line(pdo_config_text(p))?;
            }
            Ok(())
        }
        PdoVerb::Map {
            bus,
            node,
            pdo,
            objects,
            sync,
            transmission_type,
            inhibit,
            event_timer,
            cob_id,
            disabled,
        } => {
            let mapping = objects
                .iter()
                .map(|o| mapped_object(o))
                .collect::<std::result::Result<Vec<_>, String>>()
                .map_err(|m| Failure {
                    what: "pdo map".into(),
                    cause: Cause::Usage(m),
                })?;
            let config = pb::PdoConfiguration {
                kind: pdo.kind as i32,
                pdo: pdo.num,
                cob_id: cob_id.unwrap_or(0),
                enabled: !disabled,
                transmission_type: u32::from(sync.or(transmission_type).unwrap_or(255)),
                inhibit_time_100us: u32::from(inhibit),
                event_timer_ms: u32::from(event_timer),
                mapping,
            };
            configure(app, &bus, node, config).await
        }
        PdoVerb::Disable { bus, node, pdo } => {
            let what = format!(
                "reading {}{} of node {node} on {bus}",
                kind_text(pdo.kind as i32),
                pdo.num
            );
            let current = app
                .client
                .canopen(&bus)
                .pdo_config(node, Some(pdo.kind), pdo.num)
                .await
                .ctx(&what)?;
            let Some(mut config) = current.into_iter().next() else {
                return Err(Failure {
                    what,
                    cause: Cause::Failed(format!("node {node} has no such PDO")),
                });
            };
            config.enabled = false;
            configure(app, &bus, node, config).await
        }
    }
}

async fn configure(app: &App, bus: &str, node: NodeId, config: pb::PdoConfiguration) -> Result<()> {
    let what = format!(
        "configuring {}{} of node {node} on {bus}",
        kind_text(config.kind),
        config.pdo
    );
    let r = app
        .client
        .canopen(bus)
        .configure_pdo(node, config)
        .await
        .ctx(&what)?;
    if app.json {
        return super::print_json(&r);
    }
    if let Some(p) = &r.pdo {
        app.line(pdo_config_text(p))?;
    }
    Ok(())
}

/// `cangate pdo watch [BUS] [--node N]`
async fn watch(app: &App, bus: Option<String>, nodes: Vec<NodeId>) -> Result<()> {
    let req = pb::StreamPdoRequest {
        bus: bus.unwrap_or_default(),
        nodes: nodes.iter().map(|n| u32::from(*n)).collect(),
    };
    let mut s = app
        .client
        .call(
            "StreamPdo",
            None,
            app.client.canopen_client().stream_pdo(req),
        )
        .await
        .ctx("watching PDOs")?;
    loop {
        let m = tokio::select! {
            m = s.message() => m.map_err(cangate_client::Error::from).ctx("watching PDOs")?,
            _ = ctrl_c() => return Ok(()),
        };
        let Some(m) = m else { return Ok(()) };
        if m.lost_before > 0 && !app.json {
            eprintln!(
                "cangate: {} PDOs lost (this client read too slowly)",
                m.lost_before
            );
        }
        app.item(pdo_text(&m), &m)?;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pdo_names_and_objects() {
        assert_eq!(
            pdo_name("TPDO1"),
            Ok(PdoName {
                kind: pb::PdoKind::Tpdo,
                num: 1
            })
        );
        assert_eq!(pdo_name("rpdo512").map(|p| p.num), Ok(512));
        assert!(pdo_name("tpdo0").is_err());
        assert!(pdo_name("pdo1").is_err());
        let o = mapped_object("0x6041:0").unwrap();
        assert_eq!((o.index, o.subindex, o.bits), (0x6041, 0, 0));
        let o = mapped_object("6064:0x00/32").unwrap();
        assert_eq!((o.index, o.subindex, o.bits), (0x6064, 0, 32));
        assert_eq!(mapped_object("Statusword").unwrap().object, "Statusword");
        assert!(mapped_object("0x6041").is_err());
        assert!(mapped_object("0x6041:0/x").is_err());
    }
}
