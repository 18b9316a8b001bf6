//! The CANopen verbs of the `cangate` CLI: nodes, scan, nmt, sdo, events.

use anyhow::{Context, Result, anyhow, bail};
use cangate_client::{Client, pb};
use clap::{Subcommand, ValueEnum};
use serde_json::json;
use std::io::Write;

/// NMT commands as typed on the command line.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum NmtVerb {
    /// Start (operational).
    Start,
    /// Stop.
    Stop,
    /// Enter pre-operational.
    Preop,
    /// Reset node.
    Reset,
    /// Reset communication.
    ResetComm,
}

/// `cangate sdo …`
#[derive(Subcommand, Debug)]
pub enum SdoVerb {
    /// Read an object: `cangate sdo read can0 5 0x1018:1 [--type u32]`.
    Read {
        /// Bus.
        bus: String,
        /// Node id.
        node: u32,
        /// Object: INDEX[:SUB] in hex (0x1018:1, 1017).
        object: String,
        /// Decode as this type: bool i8 i16 i32 i64 u8 u16 u32 u64 f32 f64
        /// vs (visible string) os (octet string) us (unicode) domain.
        #[arg(long = "type", short = 't')]
        ty: Option<String>,
        /// Use block transfer.
        #[arg(long)]
        block: bool,
        /// Answer timeout in ms (default: the gateway's, 500).
        #[arg(long)]
        timeout_ms: Option<u32>,
        /// Write the bytes read to this file (for domains).
        #[arg(long)]
        output: Option<std::path::PathBuf>,
    },
    /// Write an object: `cangate sdo write can0 5 0x1017:0 u16 100`.
    Write {
        /// Bus.
        bus: String,
        /// Node id.
        node: u32,
        /// Object: INDEX[:SUB] in hex.
        object: String,
        /// Type (as for read), or `raw` for hex bytes.
        ty: String,
        /// The value (decimal or 0x hex for integers, text for strings, hex
        /// bytes for os/domain/raw). Omit with --file.
        value: Option<String>,
        /// Take the bytes from this file (domains, firmware images).
        #[arg(long)]
        file: Option<std::path::PathBuf>,
        /// Use block transfer.
        #[arg(long)]
        block: bool,
        /// Answer timeout in ms.
        #[arg(long)]
        timeout_ms: Option<u32>,
    },
}

fn parse_object(text: &str) -> Result<(u32, u32)> {
    let (i, s) = text.split_once(':').unwrap_or((text, "0"));
    let hex =
        |t: &str| u32::from_str_radix(t.trim_start_matches("0x").trim_start_matches("0X"), 16);
    let index = hex(i).with_context(|| format!("object index {i:?} is not hex"))?;
    let sub = hex(s).with_context(|| format!("sub-index {s:?} is not hex"))?;
    if index > 0xFFFF || sub > 0xFF {
        bail!("object {text:?} out of range (index 0..FFFF, sub-index 0..FF)");
    }
    Ok((index, sub))
}

fn data_type(name: &str) -> Result<pb::DataType> {
    use pb::DataType as D;
    Ok(match name.to_ascii_lowercase().as_str() {
        "bool" => D::Boolean,
        "i8" => D::Integer8,
        "i16" => D::Integer16,
        "i32" => D::Integer32,
        "i64" => D::Integer64,
        "u8" => D::Unsigned8,
        "u16" => D::Unsigned16,
        "u32" => D::Unsigned32,
        "u64" => D::Unsigned64,
        "f32" => D::Real32,
        "f64" => D::Real64,
        "vs" => D::VisibleString,
        "os" => D::OctetString,
        "us" => D::UnicodeString,
        "domain" => D::Domain,
        other => bail!(
            "unknown type {other:?} (bool i8 i16 i32 i64 u8 u16 u32 u64 f32 f64 vs os us domain)"
        ),
    })
}

fn parse_hex_bytes(text: &str) -> Result<Vec<u8>> {
    let clean: String = text
        .chars()
        .filter(|c| !c.is_whitespace() && *c != ':')
        .collect();
    let clean = clean.trim_start_matches("0x");
    if !clean.len().is_multiple_of(2) {
        bail!("{text:?} is not a sequence of hex bytes");
    }
    (0..clean.len())
        .step_by(2)
        .map(|i| {
            u8::from_str_radix(&clean[i..i + 2], 16).map_err(|_| anyhow!("{text:?} is not hex"))
        })
        .collect()
}

fn parse_int(text: &str) -> Result<i128> {
    let t = text.trim();
    let (neg, t) = t.strip_prefix('-').map(|r| (true, r)).unwrap_or((false, t));
    let v = if let Some(h) = t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        i128::from_str_radix(h, 16)
    } else {
        t.parse::<i128>()
    }
    .with_context(|| format!("{text:?} is not an integer"))?;
    Ok(if neg { -v } else { v })
}

fn make_value(ty: pb::DataType, text: &str) -> Result<pb::Value> {
    use pb::DataType as D;
    use pb::value::Value as V;
    let value = match ty {
        D::Boolean => V::BoolValue(matches!(text, "1" | "true" | "on" | "yes")),
        D::Integer8 | D::Integer16 | D::Integer32 | D::Integer64 => {
            V::IntValue(i64::try_from(parse_int(text)?).context("value too large")?)
        }
        D::Unsigned8 | D::Unsigned16 | D::Unsigned32 | D::Unsigned64 => {
            let v = parse_int(text)?;
            V::UintValue(
                u64::try_from(v)
                    .map_err(|_| anyhow!("{text} is negative or too large for an unsigned type"))?,
            )
        }
        D::Real32 | D::Real64 => V::RealValue(
            text.parse()
                .with_context(|| format!("{text:?} is not a number"))?,
        ),
        D::VisibleString | D::UnicodeString => V::StringValue(text.to_string()),
        D::OctetString | D::Domain => V::BytesValue(parse_hex_bytes(text)?),
        D::Unspecified => bail!("no type"),
    };
    Ok(pb::Value {
        r#type: ty as i32,
        value: Some(value),
    })
}

fn show_value(v: &pb::Value) -> String {
    use pb::value::Value as V;
    match &v.value {
        Some(V::BoolValue(b)) => b.to_string(),
        Some(V::IntValue(i)) => i.to_string(),
        Some(V::UintValue(u)) => format!("{u} (0x{u:X})"),
        Some(V::RealValue(f)) => f.to_string(),
        Some(V::StringValue(s)) => format!("{s:?}"),
        Some(V::BytesValue(b)) => b
            .iter()
            .map(|x| format!("{x:02X}"))
            .collect::<Vec<_>>()
            .join(" "),
        None => "-".into(),
    }
}

/// Shows the progress of the running transfer of `node` on stderr until
/// the returned guard is dropped (polls ListSdoTransfers every 100 ms).
fn progress_bar(client: &Client, bus: &str, node: u32) -> tokio::task::JoinHandle<()> {
    let mut c = client.canopen_client();
    let bus = bus.to_string();
    tokio::spawn(async move {
        let started = std::time::Instant::now();
        loop {
            tokio::time::sleep(std::time::Duration::from_millis(100)).await;
            let Ok(r) = c
                .list_sdo_transfers(pb::ListSdoTransfersRequest { bus: bus.clone() })
                .await
            else {
                continue;
            };
            let Some(t) = r
                .into_inner()
                .transfers
                .into_iter()
                .find(|t| t.node == node)
            else {
                continue;
            };
            let rate = t.transferred as f64 / 1e3 / started.elapsed().as_secs_f64().max(1e-6);
            let line = match t.total {
                Some(total) if total > 0 => {
                    let pct = t.transferred as f64 * 100.0 / total as f64;
                    let bar = "#".repeat((pct / 5.0) as usize);
                    format!(
                        "[{bar:<20}] {pct:5.1} %  {} / {} bytes  {rate:.1} kB/s  ({})",
                        t.transferred, total, t.protocol
                    )
                }
                _ => format!("{} bytes  {rate:.1} kB/s  ({})", t.transferred, t.protocol),
            };
            eprint!("\r{line}   ");
        }
    })
}

fn options(block: bool, timeout_ms: Option<u32>) -> pb::SdoOptions {
    pb::SdoOptions {
        timeout_ms: timeout_ms.unwrap_or(0),
        block,
    }
}

/// `cangate sdo …`
pub async fn sdo(client: &mut Client, as_json: bool, verb: SdoVerb) -> Result<()> {
    match verb {
        SdoVerb::Read {
            bus,
            node,
            object,
            ty,
            block,
            timeout_ms,
            output,
        } => {
            let (index, subindex) = parse_object(&object)?;
            let ty = ty
                .as_deref()
                .map(data_type)
                .transpose()?
                .unwrap_or(pb::DataType::Unspecified);
            let started = std::time::Instant::now();
            let bar = output.as_ref().map(|_| progress_bar(client, &bus, node));
            let r = client
                .read_sdo(pb::ReadSdoRequest {
                    bus,
                    node,
                    index,
                    subindex,
                    r#type: ty as i32,
                    options: Some(options(block, timeout_ms)),
                })
                .await;
            if let Some(bar) = bar {
                bar.abort();
                eprintln!();
            }
            let r = r?;
            let elapsed = started.elapsed();
            if let Some(path) = &output {
                std::fs::write(path, &r.raw)
                    .with_context(|| format!("writing {}", path.display()))?;
                eprintln!(
                    "{} bytes written to {} in {:.1} ms ({:.1} kB/s)",
                    r.raw.len(),
                    path.display(),
                    elapsed.as_secs_f64() * 1e3,
                    r.raw.len() as f64 / 1e3 / elapsed.as_secs_f64().max(1e-9)
                );
            }
            if output.is_some() {
                return Ok(());
            }
            if as_json {
                println!(
                    "{}",
                    json!({
                        "raw": r.raw.iter().map(|b| format!("{b:02X}")).collect::<String>(),
                        "value": r.value.as_ref().map(show_value),
                    })
                );
            } else if let Some(v) = &r.value {
                println!("{}", show_value(v));
            } else {
                println!(
                    "{}",
                    r.raw
                        .iter()
                        .map(|b| format!("{b:02X}"))
                        .collect::<Vec<_>>()
                        .join(" ")
                );
            }
        }
        SdoVerb::Write {
            bus,
            node,
            object,
            ty,
            value,
            file,
            block,
            timeout_ms,
        } => {
            let (index, subindex) = parse_object(&object)?;
            let data = match (&file, &value) {
                (Some(path), _) => pb::write_sdo_request::Data::Raw(
                    std::fs::read(path).with_context(|| format!("reading {}", path.display()))?,
                ),
                (None, Some(text)) if ty == "raw" => {
                    pb::write_sdo_request::Data::Raw(parse_hex_bytes(text)?)
                }
                (None, Some(text)) => {
                    pb::write_sdo_request::Data::Value(make_value(data_type(&ty)?, text)?)
                }
                (None, None) => bail!("give a value or --file"),
            };
            let started = std::time::Instant::now();
            let bar = file.as_ref().map(|_| progress_bar(client, &bus, node));
            let r = client
                .write_sdo(pb::WriteSdoRequest {
                    bus,
                    node,
                    index,
                    subindex,
                    data: Some(data),
                    options: Some(options(block, timeout_ms)),
                })
                .await;
            if let Some(bar) = bar {
                bar.abort();
                eprintln!();
            }
            let r = r?;
            let elapsed = started.elapsed();
            if as_json {
                println!(
                    "{}",
                    json!({"bytes": r.bytes, "ms": elapsed.as_secs_f64() * 1e3})
                );
            } else if file.is_some() {
                eprintln!(
                    "{} bytes written in {:.1} ms ({:.1} kB/s)",
                    r.bytes,
                    elapsed.as_secs_f64() * 1e3,
                    r.bytes as f64 / 1e3 / elapsed.as_secs_f64().max(1e-9)
                );
            }
        }
    }
    Ok(())
}

fn state_name(s: i32) -> &'static str {
    match pb::NmtState::try_from(s) {
        Ok(pb::NmtState::Initialising) => "initialising",
        Ok(pb::NmtState::Stopped) => "stopped",
        Ok(pb::NmtState::Operational) => "operational",
        Ok(pb::NmtState::PreOperational) => "pre-operational",
        _ => "unknown",
    }
}

fn print_nodes(nodes: &[pb::Node], as_json: bool) -> Result<()> {
    if as_json {
        let list: Vec<_> = nodes
            .iter()
            .map(|n| {
                json!({
                    "bus": n.bus, "id": n.id, "name": n.name, "state": state_name(n.state),
                    "heartbeat_age_ms": n.heartbeat_age_ms, "heartbeat_lost": n.heartbeat_lost,
                    "device_type": n.device_type, "device_name": n.device_name,
                    "identity": n.identity.as_ref().map(|i| json!({"vendor_id": i.vendor_id, "product_code": i.product_code, "revision": i.revision, "serial": i.serial})),
                    "active_error": n.active_error.as_ref().map(|e| json!({"code": format!("0x{:04X}", e.code), "name": e.code_name})),
                    "emcy_count": n.emcy_history.len(), "boot_ups": n.boot_ups, "configured": n.configured,
                })
            })
            .collect();
        println!("{}", serde_json::to_string_pretty(&list)?);
        return Ok(());
    }
    println!(
        "{:<6} {:>4}  {:<16} {:<16} {:>8}  {:<10} {:<24} ERROR",
        "BUS", "NODE", "NAME", "STATE", "HB AGE", "DEVTYPE", "DEVICE"
    );
    for n in nodes {
        let age = match (n.heartbeat_age_ms, n.heartbeat_lost) {
            (_, true) => "LOST".to_string(),
            (Some(a), _) => format!("{a} ms"),
            (None, _) => "-".into(),
        };
        println!(
            "{:<6} {:>4}  {:<16} {:<16} {:>8}  {:<10} {:<24} {}",
            n.bus,
            n.id,
            n.name,
            state_name(n.state),
            age,
            n.device_type
                .map(|d| format!("0x{d:08X}"))
                .unwrap_or("-".into()),
            n.device_name,
            n.active_error
                .as_ref()
                .map(|e| format!("0x{:04X} {}", e.code, e.code_name))
                .unwrap_or_default()
        );
    }
    Ok(())
}

/// `cangate nodes`
pub async fn nodes(client: &mut Client, as_json: bool, bus: Option<String>) -> Result<()> {
    let r = client
        .canopen_client()
        .list_nodes(pb::ListNodesRequest {
            bus: bus.unwrap_or_default(),
        })
        .await?
        .into_inner();
    print_nodes(&r.nodes, as_json)
}

/// `cangate scan BUS`
pub async fn scan(client: &mut Client, as_json: bool, bus: String, timeout_ms: u32) -> Result<()> {
    let r = client
        .canopen_client()
        .scan_network(pb::ScanNetworkRequest { bus, timeout_ms })
        .await?
        .into_inner();
    print_nodes(&r.nodes, as_json)
}

/// `cangate nmt BUS CMD NODE`
pub async fn nmt(client: &mut Client, bus: String, verb: NmtVerb, node: u32) -> Result<()> {
    let command = match verb {
        NmtVerb::Start => pb::NmtCommand::Start,
        NmtVerb::Stop => pb::NmtCommand::Stop,
        NmtVerb::Preop => pb::NmtCommand::EnterPreOperational,
        NmtVerb::Reset => pb::NmtCommand::ResetNode,
        NmtVerb::ResetComm => pb::NmtCommand::ResetCommunication,
    };
    client
        .canopen_client()
        .send_nmt(pb::SendNmtRequest {
            bus,
            node,
            command: command as i32,
        })
        .await?;
    Ok(())
}

/// `cangate events`
pub async fn events(
    client: &mut Client,
    as_json: bool,
    bus: Option<String>,
    nodes: Vec<u32>,
) -> Result<()> {
    let mut s = client
        .canopen_client()
        .stream_node_events(pb::StreamNodeEventsRequest {
            bus: bus.unwrap_or_default(),
            nodes,
        })
        .await?
        .into_inner();
    loop {
        let ev = tokio::select! {
            e = s.message() => e?,
            _ = tokio::signal::ctrl_c() => return Ok(()),
        };
        let Some(ev) = ev else { return Ok(()) };
        use pb::node_event::Event as E;
        let what = match &ev.event {
            Some(E::BootUp(_)) => "boot-up".to_string(),
            Some(E::StateChanged(c)) => {
                format!("state {} -> {}", state_name(c.from), state_name(c.to))
            }
            Some(E::HeartbeatLost(l)) => format!("heartbeat lost (timeout {} ms)", l.timeout_ms),
            Some(E::HeartbeatRecovered(r)) => format!(
                "heartbeat recovered after {} ms ({})",
                r.silent_ms,
                state_name(r.state)
            ),
            Some(E::Emcy(e)) => format!(
                "EMCY 0x{:04X} {} (register 0x{:02X})",
                e.code, e.code_name, e.register
            ),
            Some(E::Lost(l)) => format!("{} events lost (this client read too slowly)", l.count),
            Some(E::BootCompleted(_)) => "boot procedure completed, node started".to_string(),
            Some(E::BootFailed(f)) => format!("boot procedure FAILED: {}", f.reason),
            None => continue,
        };
        if as_json {
            writeln!(
                std::io::stdout(),
                "{}",
                json!({"bus": ev.bus, "node": ev.node, "timestamp_ns": ev.timestamp_ns, "event": what})
            )?;
        } else {
            let secs = ev.timestamp_ns / 1_000_000_000;
            let micros = (ev.timestamp_ns % 1_000_000_000) / 1000;
            writeln!(
                std::io::stdout(),
                "({secs}.{micros:06})  {}  node {:>3}  {what}",
                ev.bus,
                ev.node
            )?;
        }
    }
}

/// `cangate pdo [BUS]`: decoded TPDOs as they arrive.
pub async fn pdo(
    client: &mut Client,
    as_json: bool,
    bus: Option<String>,
    nodes: Vec<u32>,
) -> Result<()> {
    let mut s = client
        .canopen_client()
        .stream_pdo(pb::StreamPdoRequest {
            bus: bus.unwrap_or_default(),
            nodes,
        })
        .await?
        .into_inner();
    loop {
        let msg = tokio::select! {
            m = s.message() => m?,
            _ = tokio::signal::ctrl_c() => return Ok(()),
        };
        let Some(m) = msg else { return Ok(()) };
        if m.lost_before > 0 {
            eprintln!(
                "cangate: {} PDOs lost (this client read too slowly)",
                m.lost_before
            );
        }
        if as_json {
            let values: Vec<_> = m
                .values
                .iter()
                .map(|v| json!({"index": format!("0x{:04X}", v.index), "sub": v.subindex, "name": v.name, "value": v.value.as_ref().map(show_value)}))
                .collect();
            writeln!(
                std::io::stdout(),
                "{}",
                json!({"bus": m.bus, "node": m.node, "pdo": m.pdo, "cob_id": format!("0x{:03X}", m.cob_id), "timestamp_ns": m.timestamp_ns, "values": values})
            )?;
        } else {
            let values: Vec<String> = m
                .values
                .iter()
                .map(|v| {
                    let name = if v.name.is_empty() {
                        format!("0x{:04X}:{:02X}", v.index, v.subindex)
                    } else {
                        v.name.clone()
                    };
                    format!(
                        "{name}={}",
                        v.value.as_ref().map(show_value).unwrap_or_default()
                    )
                })
                .collect();
            let secs = m.timestamp_ns / 1_000_000_000;
            let micros = (m.timestamp_ns % 1_000_000_000) / 1000;
            writeln!(
                std::io::stdout(),
                "({secs}.{micros:06})  {}  node {:>3}  TPDO{} {:03X}  {}",
                m.bus,
                m.node,
                m.pdo,
                m.cob_id,
                values.join("  ")
            )?;
        }
    }
}
