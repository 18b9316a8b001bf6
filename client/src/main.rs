//! `cangate`: command-line client of the cangate gateway.

use anyhow::{Context, Result, bail};
use cangate_client::can::{Filter, Frame};
use cangate_client::{Client, DEFAULT_SERVER, pb};
use clap::{Parser, Subcommand};
use serde_json::json;
use std::io::Write;

mod axis_cli;
mod canopen_cli;
mod cli_common;
mod smc_cli;
mod wheel_cli;
use canopen_cli::{NmtVerb, SdoVerb};

/// Command-line client of the cangate CAN gateway.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Cli {
    /// Gateway URL.
    #[arg(long, global = true, env = "CANGATE_SERVER", default_value = DEFAULT_SERVER)]
    server: String,
    /// Machine-readable output: one JSON document, or one JSON object per
    /// line for streams.
    #[arg(long, global = true)]
    json: bool,
    /// Bearer token for a gateway with authentication.
    #[arg(long, global = true, env = "CANGATE_TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// PEM CA certificate that signs the gateway's certificate: connects
    /// with TLS (http:// becomes https://).
    #[arg(long, global = true, env = "CANGATE_CA")]
    ca: Option<std::path::PathBuf>,
    /// PEM client certificate for mutual TLS (with --key).
    #[arg(long, global = true, env = "CANGATE_CERT", requires = "key")]
    cert: Option<std::path::PathBuf>,
    /// PEM private key of --cert.
    #[arg(long, global = true, env = "CANGATE_KEY", requires = "cert")]
    key: Option<std::path::PathBuf>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// List buses with state and live statistics.
    Buses,
    /// Print frames of a bus, like candump.
    Dump {
        /// Bus name.
        bus: String,
        /// Filters in candump syntax: <id>:<mask> (match) or <id>~<mask>
        /// (inverted); repeatable, a frame passing any filter is shown.
        #[arg(long = "filter", short = 'f')]
        filters: Vec<Filter>,
        /// Stop after N frames.
        #[arg(short = 'n')]
        count: Option<u64>,
        /// Also show frames the gateway transmitted.
        #[arg(long)]
        tx: bool,
        /// Also show error frames.
        #[arg(long)]
        errors: bool,
    },
    /// Send frames in cansend syntax: 123#DEADBEEF, 1F334455#11, 123#R,
    /// 123##1AABB (CAN FD, flags nibble after ##).
    Send {
        /// Bus name.
        bus: String,
        /// One or more frames, sent in order.
        #[arg(required = true)]
        frames: Vec<String>,
    },
    /// List CANopen nodes (configured and discovered) with state and errors.
    Nodes {
        /// Only this bus.
        bus: Option<String>,
    },
    /// Find the CANopen nodes on a bus (SDO read of 0x1000 at every id).
    Scan {
        /// Bus.
        bus: String,
        /// Per-node answer timeout in ms.
        #[arg(long, default_value_t = 100)]
        timeout_ms: u32,
    },
    /// Send an NMT command: `cangate nmt can0 start 5` (node 0: all nodes).
    Nmt {
        /// Bus.
        bus: String,
        /// Command.
        command: NmtVerb,
        /// Node id, 0 for all.
        node: u32,
    },
    /// Read or write CANopen objects over SDO.
    Sdo {
        #[command(subcommand)]
        verb: SdoVerb,
    },
    /// Stream decoded TPDOs (named, typed values).
    Pdo {
        /// Only this bus.
        bus: Option<String>,
        /// Only these node ids.
        #[arg(long = "node")]
        nodes: Vec<u32>,
    },
    /// Stream CANopen node events (boot-up, state, heartbeat, EMCY).
    Events {
        /// Only this bus.
        #[arg(long)]
        bus: Option<String>,
        /// Only these node ids.
        #[arg(long = "node")]
        nodes: Vec<u32>,
    },
    /// Axes (CiA 402 drives): list, show, watch, enable, home, move, jog,
    /// stop: `cangate axis X move 12.5 --wait`, `cangate axis stop X Y`.
    #[command(after_help = axis_cli::AXIS_HELP)]
    Axis(axis_cli::AxisArgs),
    /// Handwheels (manual pulse generators): list, show, mode, watch:
    /// `cangate wheel mode hw1 manual`, `cangate wheel watch hw1`.
    #[command(after_help = wheel_cli::WHEEL_HELP)]
    Wheel(wheel_cli::WheelArgs),
    /// Simulated devices of the gateway: `cangate sim turn hw1 --detents 20`.
    Sim(wheel_cli::SimArgs),
    /// CANsmc masters (dual-bus motion control): list, status, param,
    /// restart, watch: `cangate smc status`, `cangate smc param get 1 3`.
    #[command(after_help = smc_cli::SMC_HELP)]
    Smc(smc_cli::SmcArgs),
    /// Print the SHA-256 of a token for the server's [[security.tokens]]
    /// sha256 (reads the token from standard input when not given, so it
    /// stays out of the shell history). Needs no gateway.
    HashToken {
        /// The token.
        token: Option<String>,
    },
}

#[tokio::main]
async fn main() {
    let cli = Cli::parse();
    if let Err(e) = run(cli).await {
        // `cangate dump can0 | head` closes our stdout: that is the reader
        // saying "enough", not an error.
        let broken_pipe = e
            .chain()
            .filter_map(|c| c.downcast_ref::<std::io::Error>())
            .any(|io| io.kind() == std::io::ErrorKind::BrokenPipe);
        if broken_pipe {
            std::process::exit(0);
        }
        eprintln!("cangate: {e:#}");
        std::process::exit(1);
    }
}

async fn run(cli: Cli) -> Result<()> {
    if let Command::Axis(args) = &cli.command {
        axis_cli::validate(args)?;
    }
    if let Command::HashToken { token } = &cli.command {
        let token = match token {
            Some(t) => t.clone(),
            None => {
                let mut line = String::new();
                std::io::stdin()
                    .read_line(&mut line)
                    .context("reading the token from standard input")?;
                line.trim_end_matches(['\r', '\n']).to_string()
            }
        };
        if token.is_empty() {
            bail!("empty token");
        }
        println!("{}", cangate_client::hash_token(&token));
        return Ok(());
    }
    let options = cangate_client::ConnectOptions {
        token: cli.token.clone(),
        ca: cli.ca.clone(),
        cert: cli.cert.clone(),
        key: cli.key.clone(),
        tls_domain: None,
        ..Default::default()
    };
    let mut client = cangate_client::connect_with(&cli.server, &options).await?;
    match cli.command {
        Command::HashToken { .. } => Ok(()),
        Command::Buses => buses(&mut client, cli.json).await,
        Command::Dump {
            bus,
            filters,
            count,
            tx,
            errors,
        } => dump(&mut client, cli.json, &bus, &filters, count, tx, errors).await,
        Command::Nodes { bus } => canopen_cli::nodes(&mut client, cli.json, bus).await,
        Command::Scan { bus, timeout_ms } => {
            canopen_cli::scan(&mut client, cli.json, bus, timeout_ms).await
        }
        Command::Nmt { bus, command, node } => {
            canopen_cli::nmt(&mut client, bus, command, node).await
        }
        Command::Sdo { verb } => canopen_cli::sdo(&mut client, cli.json, verb).await,
        Command::Pdo { bus, nodes } => canopen_cli::pdo(&mut client, cli.json, bus, nodes).await,
        Command::Events { bus, nodes } => {
            canopen_cli::events(&mut client, cli.json, bus, nodes).await
        }
        Command::Axis(args) => axis_cli::run(&mut client, cli.json, args).await,
        Command::Wheel(args) => wheel_cli::run(&mut client, cli.json, args).await,
        Command::Sim(args) => wheel_cli::sim(&mut client, cli.json, args).await,
        Command::Smc(args) => smc_cli::run(&client, cli.json, args).await,
        Command::Send { bus, frames } => {
            let frames = frames
                .iter()
                .map(|t| t.parse::<Frame>().with_context(|| format!("frame {t:?}")))
                .collect::<Result<Vec<_>>>()?;
            let sent = client.send(&bus, &frames).await?;
            if cli.json {
                println!("{}", json!({ "bus": bus, "sent": sent }));
            }
            Ok(())
        }
    }
}

fn state_name(state: i32) -> &'static str {
    match pb::BusState::try_from(state) {
        Ok(pb::BusState::Up) => "up",
        Ok(pb::BusState::ErrorWarning) => "error-warning",
        Ok(pb::BusState::ErrorPassive) => "error-passive",
        Ok(pb::BusState::BusOff) => "bus-off",
        Ok(pb::BusState::Down) => "down",
        _ => "unknown",
    }
}

async fn buses(client: &mut Client, as_json: bool) -> Result<()> {
    let buses = client.list_buses().await?;
    if as_json {
        let list: Vec<_> = buses
            .iter()
            .map(|b| {
                let st = b.status.unwrap_or_default();
                let s = b.statistics.unwrap_or_default();
                json!({
                    "name": b.name,
                    "backend": if b.backend == pb::BackendKind::Socketcan as i32 { "socketcan" } else { "virtual" },
                    "interface": b.interface,
                    "fd": b.fd,
                    "bitrate": b.bitrate,
                    "data_bitrate": b.data_bitrate,
                    "bit_timed": b.bit_timed,
                    "state": state_name(st.state),
                    "tx_errors": st.tx_errors,
                    "rx_errors": st.rx_errors,
                    "rx_frames": s.rx_frames,
                    "tx_frames": s.tx_frames,
                    "error_frames": s.error_frames,
                    "tx_failed": s.tx_failed,
                    "rx_overflows": s.rx_overflows,
                    "subscriber_drops": s.subscriber_drops,
                    "load_percent": s.load_percent,
                    "subscribers": s.subscribers,
                })
            })
            .collect();
        println!("{}", serde_json::to_string_pretty(&list)?);
        return Ok(());
    }
    println!(
        "{:<8} {:<9} {:<10} {:<14} {:>9} {:>10} {:>10} {:>7} {:>6}",
        "BUS", "BACKEND", "INTERFACE", "STATE", "BITRATE", "RX", "TX", "ERRORS", "LOAD%"
    );
    for b in buses {
        let st = b.status.unwrap_or_default();
        let s = b.statistics.unwrap_or_default();
        let backend = if b.backend == pb::BackendKind::Socketcan as i32 {
            "socketcan"
        } else {
            "virtual"
        };
        let bitrate = if b.bitrate > 0 {
            format!("{}k{}", b.bitrate / 1000, if b.fd { "/FD" } else { "" })
        } else {
            "-".into()
        };
        println!(
            "{:<8} {:<9} {:<10} {:<14} {:>9} {:>10} {:>10} {:>7} {:>6.1}",
            b.name,
            backend,
            b.interface,
            format!(
                "{} ({}/{})",
                state_name(st.state),
                st.tx_errors,
                st.rx_errors
            ),
            bitrate,
            s.rx_frames,
            s.tx_frames,
            s.error_frames + s.tx_failed,
            s.load_percent
        );
    }
    Ok(())
}

fn hex(data: &[u8], sep: &str) -> String {
    data.iter()
        .map(|b| format!("{b:02X}"))
        .collect::<Vec<_>>()
        .join(sep)
}

async fn dump(
    client: &mut Client,
    as_json: bool,
    bus: &str,
    filters: &[Filter],
    count: Option<u64>,
    tx: bool,
    errors: bool,
) -> Result<()> {
    let mut stream = client
        .stream_frames(pb::StreamFramesRequest {
            bus: bus.to_string(),
            filters: filters.iter().map(cangate_client::filter_to_pb).collect(),
            include_transmitted: tx,
            include_error_frames: errors,
            max_batch: 0,
            queue_length: 0,
        })
        .await?;
    let mut seen = 0u64;
    let stdout = std::io::stdout();
    loop {
        let msg = tokio::select! {
            m = stream.message() => m?,
            _ = tokio::signal::ctrl_c() => break,
        };
        let Some(msg) = msg else { break };
        let mut out = stdout.lock();
        for ev in msg.events {
            use pb::stream_event::Event;
            match ev.event {
                Some(Event::Frame(f)) => {
                    print_frame(&mut out, as_json, bus, &f)?;
                    seen += 1;
                    if count.is_some_and(|n| seen >= n) {
                        out.flush()?;
                        return Ok(());
                    }
                }
                Some(Event::Lost(l)) => {
                    if as_json {
                        writeln!(out, "{}", json!({"bus": bus, "lost": l.count}))?;
                    } else {
                        eprintln!(
                            "cangate: {bus}: {} frames lost (this client read too slowly)",
                            l.count
                        );
                    }
                }
                Some(Event::State(s)) => {
                    if as_json {
                        writeln!(
                            out,
                            "{}",
                            json!({"bus": bus, "state": state_name(s.state), "tx_errors": s.tx_errors, "rx_errors": s.rx_errors})
                        )?;
                    } else {
                        eprintln!(
                            "cangate: {bus}: state {} (tx errors {}, rx errors {})",
                            state_name(s.state),
                            s.tx_errors,
                            s.rx_errors
                        );
                    }
                }
                None => {}
            }
        }
        out.flush()?;
    }
    if let Some(n) = count
        && seen < n
    {
        bail!("stream ended after {seen} of {n} frames");
    }
    Ok(())
}

fn print_frame(out: &mut impl Write, as_json: bool, bus: &str, f: &pb::Frame) -> Result<()> {
    let id = if f.extended {
        format!("{:08X}", f.id)
    } else {
        format!("{:03X}", f.id)
    };
    let dir = if f.direction == pb::Direction::Tx as i32 {
        "TX"
    } else {
        "RX"
    };
    if as_json {
        writeln!(
            out,
            "{}",
            json!({
                "bus": bus,
                "timestamp_ns": f.timestamp_ns,
                "direction": dir.to_lowercase(),
                "id": id,
                "extended": f.extended,
                "remote": f.remote,
                "fd": f.fd,
                "brs": f.brs,
                "esi": f.esi,
                "error": f.error,
                "dlc": if f.remote { f.remote_dlc as usize } else { f.data.len() },
                "data": hex(&f.data, ""),
            })
        )?;
        return Ok(());
    }
    let secs = f.timestamp_ns / 1_000_000_000;
    let micros = (f.timestamp_ns % 1_000_000_000) / 1000;
    let body = if f.remote {
        format!("[{}]  remote request", f.remote_dlc)
    } else if f.fd {
        format!("[{:02}]  {}", f.data.len(), hex(&f.data, " "))
    } else {
        format!("[{}]  {}", f.data.len(), hex(&f.data, " "))
    };
    let kind = if f.error {
        " ERROR"
    } else if f.fd {
        if f.brs { " FD/BRS" } else { " FD" }
    } else {
        ""
    };
    writeln!(
        out,
        "({secs}.{micros:06})  {bus}  {dir}  {id:>8}{kind}   {body}"
    )?;
    Ok(())
}
