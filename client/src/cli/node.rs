//! CANopen nodes: `cangate node list|show|objects|dcf`, `nmt`, `scan`,
//! `events`.

use super::{App, Context, Result, ctrl_c, label, node_id, print_json};
use cangate_client::{NmtCommand, NodeId, SdoValue, pb};
use clap::{Args, Subcommand, ValueEnum};
use futures::StreamExt;
use std::time::Duration;

/// `cangate node …`
#[derive(Args, Debug)]
pub(crate) struct NodeArgs {
    #[command(subcommand)]
    verb: NodeVerb,
}

#[derive(Subcommand, Debug)]
enum NodeVerb {
    /// Table of CANopen nodes (configured and heard of): state, heartbeat,
    /// device, active error.
    List {
        /// Only this bus.
        bus: Option<String>,
    },
    /// One node in detail: identity, heartbeat, EMCY history.
    Show {
        /// Bus.
        bus: String,
        /// Node id.
        #[arg(value_parser = node_id)]
        node: NodeId,
    },
    /// The node's object dictionary from its EDS (no SDO transfer):
    /// address, name (as `sdo read`/`write` take it), type, access, PDO
    /// mappability, default and limits.
    Objects {
        /// Bus.
        bus: String,
        /// Node id.
        #[arg(value_parser = node_id)]
        node: NodeId,
        /// Only objects whose name or address contains this text
        /// (case-insensitive).
        #[arg(long, short = 'f', value_name = "TEXT")]
        filter: Option<String>,
    },
    /// The node's live values as a DCF (CiA 306): every readable object
    /// of its EDS read over SDO. Give the file to the node's `dcf` in the
    /// configuration and the boot procedure writes the values back.
    Dcf {
        /// Bus.
        bus: String,
        /// Node id.
        #[arg(value_parser = node_id)]
        node: NodeId,
        /// Write the DCF to this file (default: standard output).
        #[arg(long, short = 'o', value_name = "FILE")]
        output: Option<std::path::PathBuf>,
    },
}

/// `cangate nmt BUS COMMAND NODE|all`
#[derive(Args, Debug)]
pub(crate) struct NmtArgs {
    /// Bus.
    bus: String,
    /// The command.
    command: NmtArg,
    /// Node id, or `all` (broadcast; also 0).
    #[arg(value_parser = nmt_target, value_name = "NODE|all")]
    node: Target,
    /// Send it even to the drive of an enabled axis, which then faults
    /// (refused otherwise; needs the engineer role).
    #[arg(long)]
    force: bool,
}

/// One node, or every node (`None`).
#[derive(Debug, Clone, Copy)]
struct Target(Option<NodeId>);

/// NMT commands as typed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum NmtArg {
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

impl NmtArg {
    fn command(self) -> NmtCommand {
        match self {
            NmtArg::Start => NmtCommand::Start,
            NmtArg::Stop => NmtCommand::Stop,
            NmtArg::Preop => NmtCommand::EnterPreOperational,
            NmtArg::Reset => NmtCommand::ResetNode,
            NmtArg::ResetComm => NmtCommand::ResetCommunication,
        }
    }
}

/// `all` or 0: every node (`None`); else a node id.
fn nmt_target(text: &str) -> Result<Target, String> {
    match text.trim() {
        "all" | "0" => Ok(Target(None)),
        t => node_id(t).map(|n| Target(Some(n))),
    }
}

/// `cangate scan BUS`
#[derive(Args, Debug)]
pub(crate) struct ScanArgs {
    /// Bus.
    bus: String,
    /// Answer timeout per node id in ms (the gateway's default: 100).
    #[arg(long, value_name = "MS", value_parser = clap::value_parser!(u32).range(1..=10_000))]
    node_timeout_ms: Option<u32>,
}

/// `cangate events`
#[derive(Args, Debug)]
pub(crate) struct EventsArgs {
    /// Only this bus (default: every CANopen bus).
    #[arg(long)]
    bus: Option<String>,
    /// Only these node ids (repeatable).
    #[arg(long = "node", value_parser = node_id)]
    nodes: Vec<NodeId>,
}

/// `(secs.micros)` of a nanosecond timestamp.
pub(super) fn ns_text(ns: u64) -> String {
    super::time_text(ns / 1000)
}

fn nodes_table(nodes: &[pb::Node]) -> String {
    let mut text = format!(
        "{:<6} {:>4}  {:<16} {:<16} {:>8}  {:<10} {:<24} ERROR",
        "BUS", "NODE", "NAME", "STATE", "HB AGE", "DEVTYPE", "DEVICE"
    );
    for n in nodes {
        let age = match (n.heartbeat_age_ms, n.heartbeat_lost) {
            (_, true) => "LOST".to_string(),
            (Some(a), _) => format!("{a} ms"),
            (None, _) => "-".into(),
        };
        text.push_str(&format!(
            "\n{:<6} {:>4}  {:<16} {:<16} {:>8}  {:<10} {:<24} {}",
            n.bus,
            n.id,
            n.name,
            label::<pb::NmtState>(n.state),
            age,
            n.device_type
                .map_or_else(|| "-".into(), |d| format!("0x{d:08X}")),
            n.device_name,
            n.active_error
                .as_ref()
                .map(|e| format!("0x{:04X} {}", e.code, e.code_name))
                .unwrap_or_default()
        ));
    }
    text
}

fn node_text(n: &pb::Node) -> String {
    let mut rows: Vec<(&str, String)> = vec![
        ("node", format!("{}/{} {}", n.bus, n.id, n.name)),
        ("state", label::<pb::NmtState>(n.state)),
        (
            "heartbeat",
            match (n.heartbeat_age_ms, n.heartbeat_lost) {
                (_, true) => format!("LOST (timeout {} ms)", n.heartbeat_timeout_ms),
                (Some(a), _) => format!("{a} ms ago (timeout {} ms)", n.heartbeat_timeout_ms),
                (None, _) => "-".into(),
            },
        ),
        (
            "device type",
            n.device_type
                .map_or_else(|| "-".into(), |d| format!("0x{d:08X}")),
        ),
        ("device name", n.device_name.clone()),
        (
            "identity",
            n.identity.as_ref().map_or_else(
                || "-".into(),
                |i| {
                    format!(
                        "vendor 0x{:08X} product 0x{:08X} revision 0x{:08X} serial 0x{:08X}",
                        i.vendor_id, i.product_code, i.revision, i.serial
                    )
                },
            ),
        ),
        (
            "active error",
            n.active_error.as_ref().map_or_else(
                || "-".into(),
                |e| format!("0x{:04X} {}", e.code, e.code_name),
            ),
        ),
        ("boot-ups", n.boot_ups.to_string()),
        (
            "guarding",
            if n.monitoring == pb::LifeMonitoring::NodeGuarding as i32 {
                format!(
                    "guard time {} ms x {} (the heartbeat row is its answers), {} toggle errors",
                    n.guard_time_ms, n.life_time_factor, n.guarding_toggle_errors
                )
            } else {
                "-".into()
            },
        ),
        ("configured", if n.configured { "yes" } else { "no" }.into()),
    ];
    for e in &n.emcy_history {
        rows.push((
            "emcy",
            format!(
                "{} 0x{:04X} {} (register 0x{:02X})",
                ns_text(e.timestamp_ns),
                e.code,
                e.code_name,
                e.register
            ),
        ));
    }
    rows.iter()
        .map(|(k, v)| format!("{:<13} {v}", format!("{k}:")))
        .collect::<Vec<_>>()
        .join("\n")
}

/// A value of ObjectInfo as text ("-" when absent).
fn value_text(v: Option<&pb::Value>) -> String {
    v.and_then(|v| SdoValue::from_pb(v).ok())
        .map_or_else(|| "-".into(), |v| v.to_string())
}

/// True when `o`'s name or address contains `filter` (any case).
fn object_matches(o: &pb::ObjectInfo, filter: &str) -> bool {
    let f = filter.to_lowercase();
    o.name.to_lowercase().contains(&f)
        || format!("0x{:04x}:{:02x}", o.index, o.subindex).contains(&f)
}

fn objects_table(objects: &[pb::ObjectInfo]) -> String {
    let mut text = format!(
        "{:<10} {:<44} {:<15} {:<6} {:<3}  {:<18} LIMITS",
        "OBJECT", "NAME", "TYPE", "ACCESS", "PDO", "DEFAULT"
    );
    for o in objects {
        let ty = if o.r#type == 0 {
            format!("0x{:04X}", o.type_code)
        } else {
            label::<pb::DataType>(o.r#type)
        };
        let default = match (&o.default_value, o.default_text.as_str()) {
            (Some(v), _) => value_text(Some(v)),
            (None, "") => "-".into(),
            (None, t) => t.to_string(),
        };
        let limits = match (&o.low_limit, &o.high_limit) {
            (None, None) => String::new(),
            (low, high) => format!(
                "{}..{}",
                value_text(low.as_ref()),
                value_text(high.as_ref())
            ),
        };
        text.push_str(&format!(
            "\n0x{:04X}:{:02X} {:<44} {:<15} {:<6} {:<3}  {:<18} {}",
            o.index,
            o.subindex,
            o.name,
            ty,
            label::<pb::ObjectAccess>(o.access),
            if o.pdo_mappable { "yes" } else { "" },
            default,
            limits
        ));
    }
    text
}

/// `cangate node …`
pub(crate) async fn run(app: &App, args: NodeArgs) -> Result<()> {
    match args.verb {
        NodeVerb::Dcf { bus, node, output } => {
            let r = app
                .client
                .canopen(&bus)
                .export_dcf(node)
                .await
                .ctx(format!("exporting node {node} on {bus} as a DCF"))?;
            if app.json {
                return print_json(&r);
            }
            for s in &r.skipped {
                eprintln!(
                    "cangate: 0x{:04X}:{:02X} left out: {}",
                    s.index, s.subindex, s.reason
                );
            }
            match output {
                Some(path) => {
                    std::fs::write(&path, &r.dcf).ctx(format!("writing {}", path.display()))?;
                    eprintln!(
                        "cangate: {} values of node {node} written to {} ({} left out)",
                        r.objects_read,
                        path.display(),
                        r.skipped.len()
                    );
                    Ok(())
                }
                None => {
                    use std::io::Write;
                    let mut out = std::io::stdout().lock();
                    out.write_all(r.dcf.as_bytes())?;
                    out.flush()?;
                    Ok(())
                }
            }
        }
        NodeVerb::List { bus } => {
            let bus = bus.unwrap_or_default();
            let nodes = app
                .client
                .canopen(&bus)
                .nodes()
                .await
                .ctx("listing the nodes")?;
            if app.json {
                return print_json(&pb::ListNodesResponse { nodes });
            }
            app.line(nodes_table(&nodes))
        }
        NodeVerb::Show { bus, node } => {
            let n = app
                .client
                .canopen(&bus)
                .node(node)
                .await
                .ctx(format!("{bus} node {node}"))?;
            app.show(node_text(&n), &n)
        }
        NodeVerb::Objects { bus, node, filter } => {
            let mut objects = app
                .client
                .canopen(&bus)
                .objects(node)
                .await
                .ctx(format!("objects of {bus} node {node}"))?;
            if let Some(f) = &filter {
                objects.retain(|o| object_matches(o, f));
            }
            if app.json {
                return print_json(&pb::ListObjectsResponse { objects });
            }
            app.line(objects_table(&objects))
        }
    }
}

/// `cangate nmt BUS COMMAND NODE|all`
pub(crate) async fn nmt(app: &App, a: NmtArgs) -> Result<()> {
    let can = app.client.canopen(&a.bus);
    let command = a.command.command();
    let what = format!(
        "nmt {} to {} on {}",
        label::<NmtCommand>(command as i32),
        a.node.0.map_or("all nodes".into(), |n| format!("node {n}")),
        a.bus
    );
    match a.node.0 {
        _ if a.force => can.nmt_forced(a.node.0, command).await,
        Some(n) => can.nmt(n, command).await,
        None => can.nmt_all(command).await,
    }
    .ctx(what)?;
    if app.json {
        print_json(&pb::SendNmtResponse {})?;
    }
    Ok(())
}

/// `cangate scan BUS`
pub(crate) async fn scan(app: &App, a: ScanArgs) -> Result<()> {
    let timeout = a
        .node_timeout_ms
        .map(|ms| Duration::from_millis(u64::from(ms)));
    // 127 node ids, one after the other: the request bound grows with them.
    let per_node = timeout.unwrap_or(Duration::from_millis(100));
    let client = match app.client.request_timeout() {
        Some(bound) => app
            .client
            .with_request_timeout(Some(bound + per_node * 127)),
        None => app.client.clone(),
    };
    let nodes = client
        .canopen(&a.bus)
        .scan(timeout)
        .await
        .ctx(format!("scanning {}", a.bus))?;
    if app.json {
        return print_json(&pb::ScanNetworkResponse { nodes });
    }
    app.line(nodes_table(&nodes))
}

/// One line of `events`.
fn event_text(ev: &pb::NodeEvent) -> Option<String> {
    use pb::node_event::Event as E;
    let state = label::<pb::NmtState>;
    let what = match ev.event.as_ref()? {
        E::BootUp(_) => "boot-up".to_string(),
        E::StateChanged(c) => format!("state {} -> {}", state(c.from), state(c.to)),
        E::HeartbeatLost(l) if l.monitoring == pb::LifeMonitoring::NodeGuarding as i32 => {
            format!("node guarding lost (life time {} ms)", l.timeout_ms)
        }
        E::HeartbeatLost(l) => format!("heartbeat lost (timeout {} ms)", l.timeout_ms),
        E::HeartbeatRecovered(r) => format!(
            "{} recovered after {} ms ({})",
            if r.monitoring == pb::LifeMonitoring::NodeGuarding as i32 {
                "node guarding"
            } else {
                "heartbeat"
            },
            r.silent_ms,
            state(r.state)
        ),
        E::GuardingToggleError(t) => format!(
            "node guarding toggle error: answer 0x{:02X}, toggle {} expected ({} so far)",
            t.data,
            u8::from(t.expected_toggle),
            t.count
        ),
        E::Emcy(e) => format!(
            "EMCY 0x{:04X} {} (register 0x{:02X})",
            e.code, e.code_name, e.register
        ),
        E::Lost(l) => format!("{} events lost (this client read too slowly)", l.count),
        E::BootCompleted(_) => "boot procedure completed, node started".to_string(),
        E::BootFailed(f) => format!("boot procedure FAILED: {}", f.reason),
    };
    Some(format!(
        "{}  {}  node {:>3}  {what}",
        ns_text(ev.timestamp_ns),
        ev.bus,
        ev.node
    ))
}

/// `cangate events [--bus B] [--node N]`
pub(crate) async fn events(app: &App, a: EventsArgs) -> Result<()> {
    let bus = a.bus.unwrap_or_default();
    let mut s = app
        .client
        .canopen(&bus)
        .events(&a.nodes)
        .await
        .ctx("node events")?;
    loop {
        let ev = tokio::select! {
            e = s.next() => e,
            _ = ctrl_c() => return Ok(()),
        };
        let Some(ev) = ev else { return Ok(()) };
        let ev = ev.ctx("node events")?;
        if let Some(text) = event_text(&ev) {
            app.item(text, &ev)?;
        }
    }
}

/// One line of `pdo watch`.
#[cfg(test)]
mod tests {
    use super::super::{Cli, Command};
    use super::*;
    use clap::Parser;

    #[test]
    fn nmt_takes_a_node_or_all() {
        let parse = |argv: &[&str]| {
            let mut all = vec!["cangate", "nmt"];
            all.extend_from_slice(argv);
            Cli::try_parse_from(&all).map(|c| match c.command {
                Command::Nmt(a) => (a.command, a.node.0.map(NodeId::get), a.force),
                other => panic!("{other:?}"),
            })
        };
        assert_eq!(
            parse(&["can0", "start", "5"]).unwrap(),
            (NmtArg::Start, Some(5), false)
        );
        assert_eq!(
            parse(&["can0", "reset-comm", "all"]).unwrap(),
            (NmtArg::ResetComm, None, false)
        );
        assert_eq!(
            parse(&["can0", "preop", "0"]).unwrap(),
            (NmtArg::Preop, None, false)
        );
        assert_eq!(
            parse(&["can0", "stop", "3", "--force"]).unwrap(),
            (NmtArg::Stop, Some(3), true)
        );
        assert!(parse(&["can0", "start", "128"]).is_err());
        assert!(parse(&["can0", "jump", "1"]).is_err());
    }

    #[test]
    fn event_lines() {
        let ev = pb::NodeEvent {
            bus: "can0".into(),
            node: 3,
            timestamp_ns: 1_700_000_000_123_456_789,
            event: Some(pb::node_event::Event::StateChanged(pb::StateChange {
                from: pb::NmtState::PreOperational as i32,
                to: pb::NmtState::Operational as i32,
            })),
        };
        assert_eq!(
            event_text(&ev).unwrap(),
            "(1700000000.123456)  can0  node   3  state pre-operational -> operational"
        );
    }
}
