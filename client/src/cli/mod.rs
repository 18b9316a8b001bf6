//! The `cangate` command line: a verb-first grammar that clap (derive)
//! parses and validates, one connection made from the global flags, output
//! as text or as canonical proto3 JSON of the RPCs' messages (pbjson), and
//! one error style for every verb (`cangate: <what failed>: <why>`, an exit
//! status per kind of failure, see [`exit`]).
//!
//! One module per command: [`axis`], [`lease`], [`sdo`], [`node`] (node,
//! nmt, scan, events, pdo), [`lss`] (LSS scan, set-id, inquire), [`flash`], [`bus`] (bus, send), [`dump`], [`replay`],
//! [`generate`] (gen), [`mount`], [`wheel`], [`sim`], [`smc`]; [`candump_log`] and
//! [`pcapng`] are the file formats of dump and replay, [`bus_writer`] the
//! Attach stream replay and gen send through.

pub(crate) mod axis;
pub(crate) mod bus;
pub(crate) mod bus_writer;
pub(crate) mod candump_log;
pub(crate) mod dump;
pub(crate) mod flash;
pub(crate) mod fleet;
pub(crate) mod generate;
pub(crate) mod lease;
pub(crate) mod lss;
pub(crate) mod mount;
pub(crate) mod node;
pub(crate) mod pcapng;
pub(crate) mod pdo;
pub(crate) mod replay;
pub(crate) mod sdo;
pub(crate) mod sim;
pub(crate) mod smc;
pub(crate) mod sync;
pub(crate) mod wheel;

use cangate_client::{Client, ConnectOptions, Error};
use clap::{Args, CommandFactory, Parser, Subcommand};
use serde::Serialize;
use std::fmt;
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

/// Exit statuses (also in `cangate --help` and docs/cli.md).
pub(crate) mod exit {
    /// Success.
    pub(crate) const OK: u8 = 0;
    /// The gateway refused the call, or a command did not complete
    /// (fault, superseded, stopped), or a local file could not be used.
    pub(crate) const FAILED: u8 = 1;
    /// Usage: bad arguments (clap), or input refused before sending.
    pub(crate) const USAGE: u8 = 2;
    /// A named thing does not exist (bus, node, axis, handwheel, master).
    pub(crate) const NOT_FOUND: u8 = 3;
    /// No answer in time (connect, request, SDO, wait).
    pub(crate) const TIMEOUT: u8 = 4;
    /// The gateway could not be reached (connection refused, reset, TLS).
    pub(crate) const UNREACHABLE: u8 = 5;
    /// An SDO transfer was aborted (the node's or the gateway's abort).
    pub(crate) const SDO_ABORT: u8 = 6;
    /// Interrupted (Ctrl-C) while a command ran.
    pub(crate) const INTERRUPTED: u8 = 130;
}

const AFTER_HELP: &str = "\
Output: text for people; --json prints the RPC's response message as
canonical proto3 JSON (one document; streams: one object per line).

Exit status: 0 success; 1 refused by the gateway or did not complete;
2 usage (bad arguments, invalid input); 3 not found; 4 timed out;
5 gateway unreachable; 6 SDO abort; 130 interrupted.";

/// Command-line client of the cangate CAN gateway.
#[derive(Parser, Debug)]
#[command(name = "cangate", version, after_help = AFTER_HELP)]
pub(crate) struct Cli {
    #[command(flatten)]
    pub(crate) connection: Connection,
    /// Print the response as canonical proto3 JSON (streams: one object
    /// per line).
    #[arg(long, global = true, help_heading = "Output")]
    pub(crate) json: bool,
    #[command(subcommand)]
    pub(crate) command: Command,
}

/// Where the gateway is and how to reach it.
#[derive(Args, Debug, Clone)]
#[command(next_help_heading = "Connection (every verb)")]
pub(crate) struct Connection {
    /// Gateway address: host:port, or a URL (http://, https://).
    #[arg(
        long,
        global = true,
        env = "CANGATE_SERVER",
        default_value = "127.0.0.1:50051",
        value_name = "HOST:PORT|URL"
    )]
    pub(crate) server: String,
    /// Bound of establishing the connection (TCP and TLS), in ms.
    #[arg(
        long,
        global = true,
        env = "CANGATE_CONNECT_TIMEOUT_MS",
        default_value_t = 5000,
        value_name = "MS",
        value_parser = clap::value_parser!(u64).range(1..)
    )]
    pub(crate) connect_timeout_ms: u64,
    /// Bound of each request, in ms (0: none). Streams are bounded only
    /// until they start; waited commands add their own wait bound.
    #[arg(
        long,
        global = true,
        env = "CANGATE_TIMEOUT_MS",
        default_value_t = 10_000,
        value_name = "MS"
    )]
    pub(crate) timeout_ms: u64,
    /// Bearer token for a gateway with authentication.
    #[arg(long, global = true, env = "CANGATE_TOKEN", hide_env_values = true)]
    pub(crate) token: Option<String>,
    /// PEM CA certificate that signs the gateway's certificate: connects
    /// with TLS.
    #[arg(long, global = true, env = "CANGATE_CA", value_name = "PEM")]
    pub(crate) ca: Option<PathBuf>,
    /// PEM client certificate for mutual TLS (with --key).
    #[arg(
        long,
        global = true,
        env = "CANGATE_CERT",
        requires = "key",
        value_name = "PEM"
    )]
    pub(crate) cert: Option<PathBuf>,
    /// PEM private key of --cert.
    #[arg(
        long,
        global = true,
        env = "CANGATE_KEY",
        requires = "cert",
        value_name = "PEM"
    )]
    pub(crate) key: Option<PathBuf>,
    /// The name the gateway's certificate must carry, when it is not the
    /// host of --server.
    #[arg(long, global = true, env = "CANGATE_TLS_DOMAIN", value_name = "NAME")]
    pub(crate) tls_domain: Option<String>,
}

impl Connection {
    fn options(&self) -> ConnectOptions {
        ConnectOptions {
            token: self.token.clone(),
            ca: self.ca.clone(),
            cert: self.cert.clone(),
            key: self.key.clone(),
            tls_domain: self.tls_domain.clone(),
            connect_timeout: Some(Duration::from_millis(self.connect_timeout_ms)),
            request_timeout: (self.timeout_ms > 0).then(|| Duration::from_millis(self.timeout_ms)),
        }
    }
}

/// The verbs.
#[derive(Subcommand, Debug)]
pub(crate) enum Command {
    /// Axes (CiA 402 drives, CANsmc slaves): list, show, enable, home,
    /// move, jog, stop, watch, move-all.
    Axis(axis::AxisArgs),
    /// Control leases: acquire (prints the token), renew, release.
    Lease(lease::LeaseArgs),
    /// Read or write CANopen objects over SDO.
    Sdo(sdo::SdoArgs),
    /// CANopen nodes: list, show.
    Node(node::NodeArgs),
    /// Send an NMT command: `cangate nmt can0 start 5` (`all`: every node).
    Nmt(node::NmtArgs),
    /// Download a program into a CANopen node (CiA 302-3): `cangate flash
    /// can0 5 fw.bin [--program 1] [--expect-id 0x..] [--clear]`.
    Flash(flash::FlashArgs),
    /// Find the CANopen nodes on a bus (SDO read of 0x1000 at every id).
    Scan(node::ScanArgs),
    /// CANopen node events (boot-up, state, heartbeat, EMCY), until Ctrl-C.
    Events(node::EventsArgs),
    /// Process data objects: watch decoded TPDOs; show, map and disable a
    /// node's PDOs at run time.
    Pdo(pdo::PdoArgs),
    /// The SYNC producer of a CANopen bus: status, start, stop, period,
    /// counter.
    Sync(sync::SyncArgs),
    /// The TIME producer of a CANopen bus: send the time now, or every
    /// period.
    Time(sync::TimeArgs),
    /// Layer setting services (CiA 305): find unconfigured devices
    /// (fastscan), give them node-IDs, inquire.
    Lss(lss::LssArgs),
    /// The gateways an MQTT broker or NATS server has seen (their plant
    /// bridges' statuses): `cangate fleet --broker mqtt://broker:1883` or
    /// `nats://broker:4222`. Needs no gateway.
    Fleet(fleet::FleetArgs),
    /// Buses: list, show.
    Bus(bus::BusArgs),
    /// Same as `bus list`.
    #[command(hide = true)]
    Buses,
    /// Print the frames of buses, like candump, until Ctrl-C: text, candump
    /// log (--log), pcapng for Wireshark (--pcap FILE), JSON.
    Dump(dump::DumpArgs),
    /// Send frames in cansend syntax: 123#DEADBEEF 1F334455#11 123#R
    /// 123##1AABB (CAN FD: flags nibble after ##).
    Send(bus::SendArgs),
    /// A bus of the gateway as a local SocketCAN interface, both ways,
    /// until Ctrl-C: `cangate mount can0 vcan5` (creates vcan5 when it may).
    Mount(mount::MountArgs),
    /// Play a candump log onto buses, like canplayer: timing kept (or
    /// --fast), buses renamed with TARGET=SOURCE.
    Replay(replay::ReplayArgs),
    /// Send generated frames, like cangen: identifiers, lengths and data
    /// random, incrementing or fixed, at a rate.
    Gen(generate::GenArgs),
    /// Handwheels (manual pulse generators): list, show, mode, watch.
    Wheel(wheel::WheelArgs),
    /// Simulated devices of the gateway: turn a wheel, bus faults, power
    /// cycle, EMCY, drive faults, I/O inputs.
    Sim(sim::SimArgs),
    /// CANsmc masters: list, status, param, restart, watch.
    Smc(smc::SmcArgs),
    /// Who this client is to the gateway: its token's name and role.
    Whoami,
    /// Print the SHA-256 of a token for the server's [[security.tokens]]
    /// sha256 (reads the token from standard input when not given). Needs
    /// no gateway.
    HashToken {
        /// The token.
        token: Option<String>,
    },
    /// Print a shell completion script: `cangate completions bash >
    /// /etc/bash_completion.d/cangate`. Needs no gateway.
    Completions {
        /// The shell.
        shell: clap_complete::Shell,
    },
}

// ------------------------------------------------------------------ errors

/// A failed command: what failed, and why.
#[derive(Debug)]
pub(crate) struct Failure {
    what: String,
    cause: Cause,
}

/// Why a command failed.
#[derive(Debug)]
pub(crate) enum Cause {
    /// A call of the client library failed.
    Api(Error),
    /// The command ran but did not do what was asked (exit 1).
    Failed(String),
    /// Input refused on this side (exit 2).
    Usage(String),
    /// Local input or output (a file, the terminal).
    Io(std::io::Error),
    /// Ctrl-C.
    Interrupted,
}

impl Failure {
    /// A command that ran but did not do what was asked.
    pub(crate) fn failed(what: impl Into<String>, why: impl Into<String>) -> Failure {
        Failure {
            what: what.into(),
            cause: Cause::Failed(why.into()),
        }
    }

    /// Input refused on this side.
    pub(crate) fn usage(what: impl Into<String>, why: impl Into<String>) -> Failure {
        Failure {
            what: what.into(),
            cause: Cause::Usage(why.into()),
        }
    }

    /// Interrupted by Ctrl-C.
    pub(crate) fn interrupted(what: impl Into<String>) -> Failure {
        Failure {
            what: what.into(),
            cause: Cause::Interrupted,
        }
    }

    /// The exit status (see [`exit`]).
    pub(crate) fn exit_code(&self) -> u8 {
        match &self.cause {
            Cause::Api(e) => match e {
                Error::Transport { .. } => exit::UNREACHABLE,
                Error::InvalidInput { .. } => exit::USAGE,
                Error::NotFound { .. } => exit::NOT_FOUND,
                Error::SdoAbort { .. } => exit::SDO_ABORT,
                Error::Timeout { .. } => exit::TIMEOUT,
                _ => exit::FAILED,
            },
            Cause::Failed(_) | Cause::Io(_) => exit::FAILED,
            Cause::Usage(_) => exit::USAGE,
            Cause::Interrupted => exit::INTERRUPTED,
        }
    }

    /// Our standard output was closed by its reader (`cangate dump | head`):
    /// the reader has enough, no error.
    fn is_broken_pipe(&self) -> bool {
        matches!(&self.cause, Cause::Io(e) if e.kind() == std::io::ErrorKind::BrokenPipe)
    }
}

impl fmt::Display for Failure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if !self.what.is_empty() {
            write!(f, "{}: ", self.what)?;
        }
        match &self.cause {
            Cause::Api(e) => write!(f, "{e}"),
            Cause::Failed(s) | Cause::Usage(s) => f.write_str(s),
            Cause::Io(e) => write!(f, "{e}"),
            Cause::Interrupted => f.write_str("interrupted"),
        }
    }
}

impl From<std::io::Error> for Failure {
    fn from(e: std::io::Error) -> Failure {
        Failure {
            what: "writing the output".into(),
            cause: Cause::Io(e),
        }
    }
}

impl From<serde_json::Error> for Failure {
    fn from(e: serde_json::Error) -> Failure {
        // Keeps the kind: a closed pipe stays a closed pipe.
        let kind = e.io_error_kind().unwrap_or(std::io::ErrorKind::Other);
        Failure::from(std::io::Error::new(kind, e))
    }
}

/// A command's result.
pub(crate) type Result<T, E = Failure> = std::result::Result<T, E>;

/// Says what failed, once, in front of the library's error.
pub(crate) trait Context<T> {
    /// The error with `what` (e.g. "sdo read on can0").
    fn ctx(self, what: impl Into<String>) -> Result<T>;
}

impl<T> Context<T> for std::result::Result<T, Error> {
    fn ctx(self, what: impl Into<String>) -> Result<T> {
        self.map_err(|e| Failure {
            what: what.into(),
            cause: Cause::Api(e),
        })
    }
}

impl<T> Context<T> for std::result::Result<T, std::io::Error> {
    fn ctx(self, what: impl Into<String>) -> Result<T> {
        self.map_err(|e| Failure {
            what: what.into(),
            cause: Cause::Io(e),
        })
    }
}

// ------------------------------------------------------------------ output

/// What every verb needs: the connection and the output format.
pub(crate) struct App {
    /// The gateway.
    pub(crate) client: Client,
    /// `--json`.
    pub(crate) json: bool,
}

impl App {
    /// Prints one line of text (text mode).
    pub(crate) fn line(&self, text: impl fmt::Display) -> Result<()> {
        let mut out = std::io::stdout().lock();
        writeln!(out, "{text}")?;
        out.flush()?;
        Ok(())
    }

    /// Prints `text` in text mode, `message` as JSON with --json.
    pub(crate) fn show<M: Serialize>(&self, text: impl fmt::Display, message: &M) -> Result<()> {
        if self.json {
            print_json(message)
        } else {
            self.line(text)
        }
    }

    /// Prints one item of a stream: `text` in text mode, `message` as one
    /// JSON line with --json.
    pub(crate) fn item<M: Serialize>(&self, text: impl fmt::Display, message: &M) -> Result<()> {
        if self.json {
            print_json_line(message)
        } else {
            self.line(text)
        }
    }
}

/// A message as one pretty-printed JSON document.
pub(crate) fn print_json<M: Serialize>(message: &M) -> Result<()> {
    let mut out = std::io::stdout().lock();
    serde_json::to_writer_pretty(&mut out, message)?;
    writeln!(out)?;
    out.flush()?;
    Ok(())
}

/// A message as one JSON line.
pub(crate) fn print_json_line<M: Serialize>(message: &M) -> Result<()> {
    let mut out = std::io::stdout().lock();
    serde_json::to_writer(&mut out, message)?;
    writeln!(out)?;
    out.flush()?;
    Ok(())
}

/// The name of a proto enum value for people: `DRIVE_STATE_OPERATION_ENABLED`
/// becomes `operation-enabled` (the enum's prefix is that of its zero
/// value); `?N` for a value this client does not know. One function for
/// every enum, from the names the proto gives.
pub(crate) fn label<E>(value: i32) -> String
where
    E: TryFrom<i32> + Serialize,
{
    let name = |v: i32| -> Option<String> {
        let e = E::try_from(v).ok()?;
        match serde_json::to_value(&e).ok()? {
            serde_json::Value::String(s) => Some(s),
            _ => None,
        }
    };
    let (Some(full), Some(zero)) = (name(value), name(0)) else {
        return format!("?{value}");
    };
    let prefix = zero.rfind('_').map_or("", |i| &zero[..=i]);
    full.strip_prefix(prefix)
        .unwrap_or(&full)
        .to_ascii_lowercase()
        .replace('_', "-")
}

// --------------------------------------------------------------- helpers

/// Ctrl-C presses (SIGINT) not yet taken by [`ctrl_c`], one permit each.
static INTERRUPTS: tokio::sync::Semaphore = tokio::sync::Semaphore::const_new(0);
static LISTENING: std::sync::Once = std::sync::Once::new();

/// The next Ctrl-C (SIGINT); never resolves if the handler cannot be
/// installed. The first call installs the handler, which then counts
/// every press: a press that comes while the caller is busy elsewhere (a
/// loop between two `select!`s) is kept for the next call, not lost, as
/// `tokio::signal::ctrl_c` (which only sees presses after its own first
/// poll) would lose it - a scripted SIGINT to `cangate mount` did.
pub(crate) async fn ctrl_c() {
    LISTENING.call_once(|| {
        // Registered here, synchronously: a press right after this call
        // is already counted.
        if let Ok(mut sigint) =
            tokio::signal::unix::signal(tokio::signal::unix::SignalKind::interrupt())
        {
            tokio::spawn(async move {
                while sigint.recv().await.is_some() {
                    INTERRUPTS.add_permits(1);
                }
            });
        }
    });
    match INTERRUPTS.acquire().await {
        Ok(press) => press.forget(),
        Err(_) => std::future::pending::<()>().await,
    }
}

/// Forgets the Ctrl-C presses [`ctrl_c`] has not taken yet.
pub(crate) fn forget_ctrl_c() {
    while let Ok(press) = INTERRUPTS.try_acquire() {
        press.forget();
    }
}

/// Sleeps `secs`, or forever when `None`.
pub(crate) async fn sleep_opt(secs: Option<f64>) {
    match secs {
        Some(s) => tokio::time::sleep(Duration::from_secs_f64(s)).await,
        None => std::future::pending().await,
    }
}

/// A clap value parser: a finite number above 0.
pub(crate) fn positive(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("{text:?} is not a positive number")),
    }
}

/// A clap value parser: a finite number.
pub(crate) fn finite(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(format!("{text:?} is not a number")),
    }
}

/// A clap value parser: decimal or 0x hex.
pub(crate) fn int_arg(text: &str) -> Result<u32, String> {
    let t = text.trim();
    let parsed = match t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        Some(hex) => u32::from_str_radix(hex, 16),
        None => t.parse(),
    };
    parsed.map_err(|_| format!("{text:?} is not a number (decimal or 0x…)"))
}

/// A clap value parser: a CANopen node id (1..=127, decimal or 0x hex).
pub(crate) fn node_id(text: &str) -> Result<cangate_client::NodeId, String> {
    text.parse::<cangate_client::NodeId>().map_err(|e| match e {
        Error::InvalidInput { message } => message,
        other => other.to_string(),
    })
}

/// A clap value parser: a probability 0..1.
pub(crate) fn probability(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(p) if (0.0..=1.0).contains(&p) => Ok(p),
        _ => Err(format!("{text:?} is not a probability 0..1")),
    }
}

/// Now, µs since the Unix epoch.
pub(crate) fn now_us() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64)
}

/// `(1712345678.123456)`, like candump; the local clock when the gateway
/// gave no time.
pub(crate) fn time_text(us: u64) -> String {
    let us = if us == 0 { now_us() } else { us };
    format!("({}.{:06})", us / 1_000_000, us % 1_000_000)
}

/// Bytes as hex, `sep` between them.
pub(crate) fn hex(data: &[u8], sep: &str) -> String {
    data.iter()
        .map(|b| format!("{b:02X}"))
        .collect::<Vec<_>>()
        .join(sep)
}

/// Hex bytes as typed: `DEADBEEF`, `de ad be ef`, `de:ad`, `0x0102`.
pub(crate) fn hex_bytes(text: &str) -> Result<Vec<u8>, String> {
    let clean: String = text
        .chars()
        .filter(|c| !c.is_whitespace() && *c != ':')
        .collect();
    let clean = clean
        .strip_prefix("0x")
        .or_else(|| clean.strip_prefix("0X"))
        .unwrap_or(&clean);
    if !clean.len().is_multiple_of(2) || !clean.is_ascii() {
        return Err(format!("{text:?} is not a sequence of hex bytes"));
    }
    (0..clean.len())
        .step_by(2)
        .map(|i| {
            u8::from_str_radix(&clean[i..i + 2], 16).map_err(|_| format!("{text:?} is not hex"))
        })
        .collect()
}

/// Aborts a background task when dropped, however the command ends.
pub(crate) struct AbortOnDrop(pub(crate) Option<tokio::task::JoinHandle<()>>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        if let Some(h) = &self.0 {
            h.abort();
        }
    }
}

// -------------------------------------------------------------------- run

/// Parses the command line, runs the verb, reports a failure once.
pub(crate) async fn main() -> ExitCode {
    let cli = Cli::parse_from(sdo::hoist_write_options(std::env::args_os().collect()));
    match run(cli).await {
        Ok(()) => ExitCode::from(exit::OK),
        Err(f) if f.is_broken_pipe() => ExitCode::from(exit::OK),
        Err(f) => {
            eprintln!("cangate: {f}");
            ExitCode::from(f.exit_code())
        }
    }
}

async fn run(cli: Cli) -> Result<()> {
    // Verbs that need no gateway.
    if let Command::Fleet(a) = cli.command {
        return fleet::run(a, cli.json).await;
    }
    match &cli.command {
        Command::HashToken { token } => return hash_token(token.clone()),
        Command::Completions { shell } => {
            let mut cmd = Cli::command();
            // Made whole first, then written: a reader that closes early
            // (`| head -1`) is a broken pipe, which ends us quietly.
            let mut script = Vec::new();
            clap_complete::generate(*shell, &mut cmd, "cangate", &mut script);
            let mut out = std::io::stdout().lock();
            out.write_all(&script)?;
            out.flush()?;
            return Ok(());
        }
        // Input clap cannot check alone, refused before connecting.
        Command::Sdo(a) => a.check()?,
        Command::Replay(a) => a.check()?,
        _ => {}
    }
    let client = connect(&cli.connection).await?;
    let app = App {
        client,
        json: cli.json,
    };
    match cli.command {
        Command::Axis(a) => axis::run(&app, a).await,
        Command::Lease(a) => lease::run(&app, a).await,
        Command::Sdo(a) => sdo::run(&app, a).await,
        Command::Node(a) => node::run(&app, a).await,
        Command::Nmt(a) => node::nmt(&app, a).await,
        Command::Scan(a) => node::scan(&app, a).await,
        Command::Lss(a) => lss::run(&app, a).await,
        Command::Flash(a) => flash::run(&app, a).await,
        Command::Events(a) => node::events(&app, a).await,
        Command::Pdo(a) => pdo::run(&app, a).await,
        Command::Sync(a) => sync::sync(&app, a).await,
        Command::Time(a) => sync::time(&app, a).await,
        Command::Bus(a) => bus::run(&app, a).await,
        Command::Buses => bus::list(&app).await,
        Command::Dump(a) => dump::dump(&app, a).await,
        Command::Send(a) => bus::send(&app, a).await,
        Command::Replay(a) => replay::replay(&app, a).await,
        Command::Mount(a) => mount::mount(&app, a).await,
        Command::Gen(a) => generate::generate(&app, a).await,
        Command::Wheel(a) => wheel::run(&app, a).await,
        Command::Sim(a) => sim::run(&app, a).await,
        Command::Smc(a) => smc::run(&app, a).await,
        Command::Whoami => whoami(&app).await,
        Command::HashToken { .. } | Command::Completions { .. } | Command::Fleet(_) => Ok(()),
    }
}

/// Connects, and checks that a gateway answers within the connect
/// timeout: a plaintext HTTP/2 connection is "made" as soon as TCP is, so
/// a peer that accepts and never answers would otherwise hold the first
/// request for its whole bound. Any answer counts (also a refusal: the
/// token may not allow ListBuses); only silence or a broken connection
/// fails, with exit 4 or 5.
async fn connect(c: &Connection) -> Result<Client> {
    let client = cangate_client::connect_with(&c.server, &c.options())
        .await
        .ctx("")?;
    let bound = Duration::from_millis(c.connect_timeout_ms);
    let probe = client.with_request_timeout(Some(bound));
    match probe.clone().list_buses().await {
        Err(Error::Timeout { status: None, .. }) => Err(Failure {
            what: format!("connecting to {}", c.server),
            cause: Cause::Api(Error::Timeout {
                message: format!(
                    "the peer accepted the connection but no gateway answered within {} ms",
                    bound.as_millis()
                ),
                status: None,
            }),
        }),
        Err(e @ Error::Transport { .. }) => Err(e).ctx(format!("connecting to {}", c.server)),
        Ok(_) | Err(_) => Ok(client),
    }
}

/// `cangate whoami`: `wall-screen: viewer (token)`.
async fn whoami(app: &App) -> Result<()> {
    let c = app.client.caller().await.ctx("asking who this client is")?;
    let text = format!(
        "{}: {} ({}{})",
        c.name,
        label::<cangate_client::pb::CallerRole>(c.role),
        c.method,
        if c.authentication {
            ""
        } else {
            ", the gateway has authentication off"
        }
    );
    app.show(text, &c)
}

/// `cangate hash-token [TOKEN]`
fn hash_token(token: Option<String>) -> Result<()> {
    let token = match token {
        Some(t) => t,
        None => {
            let mut line = String::new();
            std::io::stdin()
                .read_line(&mut line)
                .ctx("reading the token from standard input")?;
            line.trim_end_matches(['\r', '\n']).to_string()
        }
    };
    if token.is_empty() {
        return Err(Failure::usage("hash-token", "empty token"));
    }
    let mut out = std::io::stdout().lock();
    writeln!(out, "{}", cangate_client::hash_token(&token))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use cangate_client::pb;

    #[test]
    fn the_cli_definition_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn enum_labels_come_from_the_proto_names() {
        assert_eq!(
            label::<pb::DriveState>(pb::DriveState::OperationEnabled as i32),
            "operation-enabled"
        );
        assert_eq!(
            label::<pb::NmtState>(pb::NmtState::PreOperational as i32),
            "pre-operational"
        );
        assert_eq!(
            label::<pb::Outcome>(pb::Outcome::Completed as i32),
            "completed"
        );
        assert_eq!(label::<pb::BusState>(999), "?999");
    }

    #[test]
    fn connection_flags() {
        let cli = Cli::try_parse_from([
            "cangate",
            "bus",
            "list",
            "--server",
            "gw:1",
            "--connect-timeout-ms",
            "250",
            "--timeout-ms",
            "0",
        ])
        .unwrap();
        let o = cli.connection.options();
        assert_eq!(cli.connection.server, "gw:1");
        assert_eq!(o.connect_timeout, Some(Duration::from_millis(250)));
        assert_eq!(o.request_timeout, None);
        assert!(
            Cli::try_parse_from(["cangate", "bus", "list", "--connect-timeout-ms", "0"]).is_err()
        );
    }

    #[test]
    fn exit_codes_per_error() {
        let f = |e: Error| Failure {
            what: String::new(),
            cause: Cause::Api(e),
        };
        assert_eq!(
            f(Error::Transport {
                message: "x".into()
            })
            .exit_code(),
            exit::UNREACHABLE
        );
        assert_eq!(
            f(Error::Timeout {
                message: "x".into(),
                status: None
            })
            .exit_code(),
            exit::TIMEOUT
        );
        assert_eq!(Failure::failed("a", "b").to_string(), "a: b");
        assert_eq!(Failure::usage("", "b").exit_code(), exit::USAGE);
    }

    #[test]
    fn hex_bytes_parse() {
        assert_eq!(hex_bytes("DEAD beef").unwrap(), [0xDE, 0xAD, 0xBE, 0xEF]);
        assert_eq!(hex_bytes("0x0102").unwrap(), [1, 2]);
        assert_eq!(hex_bytes("").unwrap(), Vec::<u8>::new());
        assert!(hex_bytes("123").is_err());
        assert!(hex_bytes("zz").is_err());
    }
}
