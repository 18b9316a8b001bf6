//! `peer_bench`: cangate against the gateways users would pick instead, on
//! real SocketCAN (`vcan0`), each path measured the same way for both.
//!
//! ```text
//! cargo build --release -p cangate-server     # started from beside this binary
//! CANGATE_PEER_SOCKETCAND=/path/socketcand CANGATE_PEER_CANOPEND=/path/canopend \
//!     cargo run --release -p cangate-bench --bin peer_bench      # --samples N, --quick
//! ```
//!
//! Paths (each latency is one complete call, timed by the caller; the
//! gateways alternate in blocks, each going first in turn, so that drift
//! of the machine hits all alike):
//!
//! 1. **raw round trip**: a python-can program sends a frame and waits for
//!    the answer (the next identifier) of a responder on vcan0 (a thread
//!    of this benchmark on a raw SocketCAN socket): through `socketcand`
//!    (python-can interface `socketcand`) and through `cangate-server`
//!    (interface `cangate`, Bus.Attach). One script for both,
//!    `bench/python/raw_round_trip.py`; the same script on python-can's
//!    own `socketcan` interface, no gateway, gives the floor of the path,
//!    and on its `socketcand` interface to cangate's socketcand endpoint
//!    the same client against both servers.
//! 2. **SDO expedited read** of 0x1017 from node 5 (the same responder
//!    thread plays the node): CANopenNode's `canopend` over its CiA 309-3
//!    ASCII gateway on TCP (`[seq] 5 r 0x1017 0 u16`) against `ReadSdo`,
//!    both from Rust clients in this process; and the same ASCII client
//!    against cangate's own CiA 309-3 endpoint (`[cia309]`).
//! 3. **a call that touches no bus**: `canopend`'s `set node 5` against
//!    cangate's `GetBus` (the cost of the call itself), and `set node 5`
//!    against cangate's CiA 309-3 endpoint.
//!
//! For every path also the server's CPU per call: user plus system time of
//! the server process (socketcand: with the process it forks per client)
//! from `/proc/<pid>/stat` over the timed blocks, divided by the calls.
//!
//! Run on a host without vcan0 it re-runs itself inside the repository's
//! QEMU guest (`scripts/vcan-vm`, as the real-SocketCAN tests do; inside,
//! `CANGATE_VM=1`). That guest is software-emulated: only the ratios mean
//! something. The peers' binaries come from `CANGATE_PEER_SOCKETCAND` and
//! `CANGATE_PEER_CANOPEND`; a missing one skips its comparison, saying so,
//! as does a host where no VM can start, unless `--strict` or `CI=true`
//! (then exit 1). Output: progress, a markdown table, one JSON line with
//! every figure.

use anyhow::{Context, Result, anyhow, bail};
use cangate_bench::gateway::NO_CLIENT_LIMITS;
use cangate_bench::host::{child_pids, process_cpu_seconds, process_thread_cpu};
use cangate_bench::stats::{Percentiles, histogram, record_ns};
use cangate_client::{Client, pb};
use clap::Parser;
use hdrhistogram::Histogram;
use serde_json::{Value as Json, json};
use socketcan::{
    CanFilter, CanFrame, CanSocket, EmbeddedFrame as _, Frame as _, Socket as _,
    SocketOptions as _, StandardId,
};
use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, ExitCode, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// The raw round trip's requests: even identifiers 0x100..=0x10E (this
/// value under [`RAW_REQUEST_MASK`]), each answered with the next
/// identifier. Each client of the path has its own pair, so that none
/// receives the others' traffic.
const RAW_REQUEST: u16 = 0x100;
const RAW_REQUEST_MASK: u16 = 0x7F1;
/// The request identifiers of the raw round trip's four clients.
const RAW_VIA_SOCKETCAND: u16 = 0x100;
const RAW_VIA_CANGATE: u16 = 0x102;
const RAW_DIRECT: u16 = 0x104;
const RAW_VIA_CANGATE_SOCKETCAND: u16 = 0x106;
/// The node the SDO reads go to (played by the responder thread).
const NODE: u8 = 5;
/// SDO request (client → server) and response COB-IDs of [`NODE`].
const SDO_RX: u16 = 0x600 + NODE as u16;
const SDO_TX: u16 = 0x580 + NODE as u16;
/// What the responder answers for 0x1017 (UNSIGNED16).
const HEARTBEAT_VALUE: u16 = 1000;
/// canopend's own node id: any but [`NODE`] and cangate's master (127).
const CANOPEND_NODE: u8 = 1;
/// The python side of the raw round trip.
const RAW_SCRIPT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/python/raw_round_trip.py");
/// The guest's time limit unless `CANGATE_VM_TIMEOUT` says otherwise.
const GUEST_TIMEOUT_SECS: &str = "1800";
/// How long a server may take to accept its first client (the emulated
/// guest is slow to start processes).
const START_LIMIT: Duration = Duration::from_secs(60);

/// cangate against socketcand and CANopenNode's canopend on vcan0.
#[derive(Parser, Debug)]
#[command(about)]
struct Args {
    /// Timed calls per gateway and path [default: 1000; --quick: 100].
    #[arg(long)]
    samples: Option<usize>,
    /// Blocks the samples are split into; the gateways alternate block by
    /// block [default: 10; --quick: 2].
    #[arg(long)]
    blocks: Option<usize>,
    /// Untimed calls per gateway and path first [default: 50; --quick: 10].
    #[arg(long)]
    warmup: Option<usize>,
    /// Small counts, for a smoke run.
    #[arg(long)]
    quick: bool,
    /// Exit 1 instead of skipping when a peer is missing or no VM can start
    /// (also when `CI=true`).
    #[arg(long)]
    strict: bool,
    /// The socketcand binary.
    #[arg(long, env = "CANGATE_PEER_SOCKETCAND")]
    socketcand: Option<PathBuf>,
    /// CANopenNode's canopend binary (CANopenLinux), with the CiA 309-3
    /// gateway.
    #[arg(long, env = "CANGATE_PEER_CANOPEND")]
    canopend: Option<PathBuf>,
    /// Python with python-can and the project's `cangate` package
    /// [default: target/python/bin/python of this workspace, else python3].
    #[arg(long, env = "CANGATE_PYTHON")]
    python: Option<PathBuf>,
    /// The SocketCAN interface.
    #[arg(long, default_value = "vcan0")]
    iface: String,
}

impl Args {
    fn samples(&self) -> usize {
        self.samples.unwrap_or(if self.quick { 100 } else { 1000 })
    }
    fn blocks(&self) -> usize {
        self.blocks
            .unwrap_or(if self.quick { 2 } else { 10 })
            .clamp(1, self.samples().max(1))
    }
    /// How long each server's idle CPU is measured.
    fn idle_secs(&self) -> f64 {
        if self.quick { 1.0 } else { 3.0 }
    }
    fn warmup(&self) -> usize {
        self.warmup.unwrap_or(if self.quick { 10 } else { 50 })
    }
    fn python(&self) -> PathBuf {
        self.python.clone().unwrap_or_else(|| {
            let venv = workspace_root().join("target/python/bin/python");
            if venv.is_file() {
                venv
            } else {
                "python3".into()
            }
        })
    }
}

fn main() -> ExitCode {
    let args = Args::parse();
    let strict = args.strict || in_ci();
    if strict {
        // A strict run that would skip a comparison fails before anything
        // starts, saying why.
        if let Err(why) = peer_binary("CANGATE_PEER_SOCKETCAND", args.socketcand.as_ref())
            .and(peer_binary("CANGATE_PEER_CANOPEND", args.canopend.as_ref()))
        {
            eprintln!("peer_bench: --strict / CI=true, and {why}");
            return ExitCode::FAILURE;
        }
    }
    match plan(&args.iface, strict) {
        Ok(Plan::Here) => match run(&args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("peer_bench: {e:#}");
                ExitCode::FAILURE
            }
        },
        Ok(Plan::Vm(runner)) => rerun_in_vm(&runner, strict),
        Ok(Plan::Unavailable(why)) => skip_or_fail(strict, &why),
        Err(e) => {
            eprintln!("peer_bench: {e:#}");
            ExitCode::FAILURE
        }
    }
}

// ---------------------------------------------------------------------------
// Where to run (as tests/tests/common/vcan.rs)
// ---------------------------------------------------------------------------

enum Plan {
    /// The interface exists: measure in this process.
    Here,
    /// Re-run this binary inside the VM with this runner.
    Vm(PathBuf),
    /// No way to get a real SocketCAN interface here.
    Unavailable(String),
}

fn in_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| v.eq_ignore_ascii_case("true") || v == "1")
}

fn inside_vm() -> bool {
    std::env::var("CANGATE_VM").is_ok_and(|v| v == "1")
}

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn plan(iface: &str, strict: bool) -> Result<Plan> {
    if Path::new("/sys/class/net").join(iface).exists() {
        return Ok(Plan::Here);
    }
    if inside_vm() {
        // The VM always creates vcan0: its absence is a broken runner, not
        // a reason to skip.
        bail!("running inside the VM (CANGATE_VM=1) but {iface} does not exist");
    }
    let runner = workspace_root().join("scripts/vcan-vm");
    if !runner.is_file() {
        return Ok(Plan::Unavailable(format!(
            "no {iface} here and no VM runner at {}",
            runner.display()
        )));
    }
    // scripts/vcan-vm installs QEMU with apt when allowed: strict runs (CI)
    // want that; a plain run on a developer machine does not install
    // system packages.
    let has_qemu = std::env::split_paths(&std::env::var_os("PATH").unwrap_or_default())
        .any(|dir| dir.join("qemu-system-x86_64").is_file());
    if !strict && !has_qemu {
        return Ok(Plan::Unavailable(format!(
            "no {iface} on this host and qemu-system-x86_64 is not installed; \
             run `scripts/vcan-vm --setup` once to install what the VM needs"
        )));
    }
    Ok(Plan::Vm(runner))
}

fn skip_or_fail(strict: bool, why: &str) -> ExitCode {
    if strict {
        eprintln!("peer_bench: cannot run (--strict / CI=true): {why}");
        ExitCode::FAILURE
    } else {
        println!("skipped: peer_bench: {why}");
        ExitCode::SUCCESS
    }
}

/// Runs this binary with the same arguments inside the guest, its output
/// streaming to ours; the guest's exit status is ours, except the runner's
/// "could not start a VM" (125).
fn rerun_in_vm(runner: &Path, strict: bool) -> ExitCode {
    let exe = match std::env::current_exe() {
        Ok(exe) => exe,
        Err(e) => {
            eprintln!("peer_bench: cannot find this executable: {e}");
            return ExitCode::FAILURE;
        }
    };
    let mut cmd = Command::new(runner);
    cmd.arg("--")
        .arg(&exe)
        .args(std::env::args_os().skip(1))
        .stdin(Stdio::null());
    if std::env::var_os("CANGATE_VM_TIMEOUT").is_none() {
        cmd.env("CANGATE_VM_TIMEOUT", GUEST_TIMEOUT_SECS);
    }
    if !strict && std::env::var_os("CANGATE_VM_INSTALL").is_none() {
        cmd.env("CANGATE_VM_INSTALL", "0");
    }
    println!(
        "no vcan0 here: re-running in the QEMU guest (software-emulated: compare ratios, not times)"
    );
    match cmd.status() {
        Ok(s) if s.success() => ExitCode::SUCCESS,
        Ok(s) if s.code() == Some(125) => skip_or_fail(
            strict,
            &format!("{} could not run a VM (exit 125)", runner.display()),
        ),
        Ok(s) => {
            eprintln!("peer_bench: the run inside the VM failed ({s})");
            ExitCode::FAILURE
        }
        Err(e) => skip_or_fail(strict, &format!("cannot start {}: {e}", runner.display())),
    }
}

// ---------------------------------------------------------------------------
// The responder: the far end of every path, one for both gateways
// ---------------------------------------------------------------------------

/// A thread on a raw socket answering the raw round trip's requests
/// and playing an SDO server as node [`NODE`].
struct Responder {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<()>>>,
}

impl Responder {
    fn start(iface: &str) -> Result<Responder> {
        let sock = CanSocket::open(iface).with_context(|| format!("opening {iface}"))?;
        // Woken only by what it answers: the gateways' own traffic
        // (canopend's heartbeats, their echoes) stays in the kernel.
        sock.set_filters(&[
            CanFilter::new(RAW_REQUEST.into(), RAW_REQUEST_MASK.into()),
            CanFilter::new(SDO_RX.into(), 0x7FF),
        ])?;
        // A blocking read with a timeout, not a poll per frame: the stop
        // flag is seen within 100 ms and each frame costs one syscall.
        sock.set_read_timeout(Duration::from_millis(100))?;
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let thread =
            std::thread::Builder::new()
                .name("responder".into())
                .spawn(move || -> Result<()> {
                    while !flag.load(Ordering::Relaxed) {
                        let frame = match sock.read_frame() {
                            Ok(f) => f,
                            Err(e) if is_timeout(&e) => continue,
                            Err(e) => return Err(anyhow!("responder: reading: {e}")),
                        };
                        // A lost answer shows as the client's timeout; this
                        // says whose it was, and the responder carries on.
                        if let Some(reply) = answer(&frame)
                            && let Err(e) = sock.write_frame_insist(&reply)
                        {
                            eprintln!("responder: answering {:03X}: {e}", frame.raw_id());
                        }
                    }
                    Ok(())
                })?;
        Ok(Responder {
            stop,
            thread: Some(thread),
        })
    }

    fn stop(mut self) -> Result<()> {
        self.stop.store(true, Ordering::Relaxed);
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(r)) => r,
            Some(Err(_)) => bail!("the responder thread panicked"),
            None => Ok(()),
        }
    }
}

fn is_timeout(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
    )
}

/// The responder's answer to `frame`, if it answers it.
fn answer(frame: &CanFrame) -> Option<CanFrame> {
    if frame.is_extended() || frame.is_remote_frame() {
        return None;
    }
    let id = u16::try_from(frame.raw_id()).ok()?;
    let data = frame.data();
    let reply = |id: u16, data: &[u8]| CanFrame::new(StandardId::new(id)?, data);
    match id {
        _ if id & RAW_REQUEST_MASK == RAW_REQUEST => reply(id + 1, data),
        SDO_RX if data.len() == 8 => reply(SDO_TX, &sdo_answer(data)),
        _ => None,
    }
}

/// An SDO server's answer to request `req` (8 bytes): uploads of 0x1017
/// give [`HEARTBEAT_VALUE`] (2 bytes, expedited), of anything else 4 zero
/// bytes; downloads are acknowledged; the rest is aborted.
fn sdo_answer(req: &[u8]) -> [u8; 8] {
    let (index_lo, index_hi, sub) = (req[1], req[2], req[3]);
    match req[0] >> 5 {
        // Initiate upload.
        2 if u16::from_le_bytes([index_lo, index_hi]) == 0x1017 => {
            let [lo, hi] = HEARTBEAT_VALUE.to_le_bytes();
            // Expedited, size indicated, 2 bytes.
            [0x4B, index_lo, index_hi, sub, lo, hi, 0, 0]
        }
        2 => [0x43, index_lo, index_hi, sub, 0, 0, 0, 0],
        // Initiate download.
        1 => [0x60, index_lo, index_hi, sub, 0, 0, 0, 0],
        // Abort: command specifier not valid (0x0504_0001).
        _ => [0x80, index_lo, index_hi, sub, 0x01, 0x00, 0x04, 0x05],
    }
}

// ---------------------------------------------------------------------------
// Server processes
// ---------------------------------------------------------------------------

/// A server started by the benchmark; killed when dropped.
struct Server {
    name: &'static str,
    child: Child,
    /// Where its output goes.
    log: PathBuf,
}

impl Server {
    /// Starts `cmd` with its output in `<dir>/<name>.log` (shown when it
    /// fails to start) and none of our `CANGATE_*` variables: cangate-server
    /// would take some as overrides of the benchmark's configuration.
    fn spawn(name: &'static str, dir: &Path, cmd: &mut Command) -> Result<Server> {
        let log = dir.join(format!("{name}.log"));
        let out = std::fs::File::create(&log)?;
        for (key, _) in std::env::vars_os() {
            if key.to_string_lossy().starts_with("CANGATE_") {
                cmd.env_remove(key);
            }
        }
        let child = cmd
            .stdin(Stdio::null())
            .stdout(out.try_clone()?)
            .stderr(out)
            .spawn()
            .with_context(|| format!("starting {name}"))?;
        Ok(Server { name, child, log })
    }

    fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Fails if the server has exited (while the caller waits for it),
    /// with the end of its output.
    fn check_alive(&mut self) -> Result<()> {
        match self.child.try_wait()? {
            Some(status) => {
                let out = std::fs::read_to_string(&self.log).unwrap_or_default();
                let tail: Vec<&str> = out.lines().rev().take(20).collect();
                let tail: Vec<&str> = tail.into_iter().rev().collect();
                bail!("{} exited ({status}):\n{}", self.name, tail.join("\n"))
            }
            None => Ok(()),
        }
    }

    /// The CPU the server has used so far: its own threads by name and,
    /// with `children`, the processes it forked (socketcand serves each
    /// client from its own process). None when that cannot be read.
    fn cpu(&self, children: bool) -> Option<Cpu> {
        let pid = self.pid();
        let total = process_cpu_seconds(pid).ok()?;
        let mut cpu = Cpu {
            total,
            parts: BTreeMap::new(),
        };
        for (_, name, secs) in process_thread_cpu(pid).ok()? {
            *cpu.parts.entry(name).or_default() += secs;
        }
        if children {
            let kids = child_pids(pid);
            if kids.is_empty() {
                // No /proc/<pid>/task/<pid>/children: the work is not seen.
                return None;
            }
            for kid in kids {
                let secs = process_cpu_seconds(kid).unwrap_or(0.0);
                cpu.total += secs;
                *cpu.parts.entry("client process".into()).or_default() += secs;
            }
        }
        Some(cpu)
    }
}

/// CPU seconds of a server: in all, and by thread name (or forked
/// process).
#[derive(Debug, Clone, Default, PartialEq)]
struct Cpu {
    /// User plus system time of the process (and its children), from
    /// `/proc/<pid>/stat`.
    total: f64,
    /// The same by thread name, from `/proc/<pid>/task/*/stat`.
    parts: BTreeMap<String, f64>,
}

impl Cpu {
    /// `self - earlier`, the CPU spent in between.
    fn since(&self, earlier: &Cpu) -> Cpu {
        Cpu {
            total: self.total - earlier.total,
            parts: self
                .parts
                .iter()
                .map(|(k, v)| (k.clone(), v - earlier.parts.get(k).unwrap_or(&0.0)))
                .collect(),
        }
    }

    fn add(&mut self, other: &Cpu) {
        self.total += other.total;
        for (k, v) in &other.parts {
            *self.parts.entry(k.clone()).or_default() += v;
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The CPU `server` uses doing nothing for `secs`, in % of one core: the
/// floor under its per-call figures.
fn idle_percent(server: &Server, secs: f64) -> Option<f64> {
    let before = server.cpu(false)?;
    std::thread::sleep(Duration::from_secs_f64(secs));
    let after = server.cpu(false)?;
    Some(after.since(&before).total / secs * 100.0)
}

/// A loopback port nobody listens on right now.
fn free_port() -> Result<u16> {
    Ok(TcpListener::bind("127.0.0.1:0")?.local_addr()?.port())
}

/// Connects to `port` once the server listens; the connection is kept
/// (canopend serves one client at a time, so a probe that closes could
/// race the real client).
fn connect_when_up(server: &mut Server, port: u16) -> Result<TcpStream> {
    let deadline = Instant::now() + START_LIMIT;
    loop {
        server.check_alive()?;
        match TcpStream::connect(("127.0.0.1", port)) {
            Ok(s) => return Ok(s),
            Err(_) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(50)),
            Err(e) => bail!("{} does not accept connections on {port}: {e}", server.name),
        }
    }
}

/// cangate-server from this build (beside this executable), with bus can0
/// on `iface`, a CANopen master knowing node [`NODE`], no SYNC, no
/// heartbeat, no per-client limits: a gateway doing nothing but what the
/// benchmark asks.
fn start_cangate(
    dir: &Path,
    iface: &str,
    rt: &tokio::runtime::Runtime,
) -> Result<(Server, Client, String, u16, u16)> {
    let exe = std::env::current_exe()?.with_file_name("cangate-server");
    if !exe.is_file() {
        bail!(
            "{} is not built (cargo build --release -p cangate-server)",
            exe.display()
        );
    }
    let port = free_port()?;
    let socketcand_port = free_port()?;
    let cia309_port = free_port()?;
    let config = dir.join("cangate.toml");
    std::fs::write(
        &config,
        format!(
            r#"listen = "127.0.0.1:{port}"

[log]
level = "error"

[socketcand]
listen = "127.0.0.1:{socketcand_port}"

[cia309]
listen = "127.0.0.1:{cia309_port}"

[[bus]]
name = "can0"
backend = "socketcan"
interface = "{iface}"
fd = false
bitrate = 1000000

[[canopen]]
bus = "can0"
sync_period_us = 0
master_heartbeat_ms = 0

[[canopen.node]]
id = {NODE}
name = "responder"
eds = "builtin:drive"
heartbeat_timeout_ms = 0
{NO_CLIENT_LIMITS}"#
        ),
    )?;
    let mut server = Server::spawn(
        "cangate-server",
        dir,
        Command::new(&exe).arg("--config").arg(&config),
    )?;
    let url = format!("http://127.0.0.1:{port}");
    let deadline = Instant::now() + START_LIMIT;
    loop {
        server.check_alive()?;
        let attempt = rt.block_on(async {
            let mut c = cangate_client::connect(&url).await?;
            c.get_bus("can0").await?;
            Ok::<_, cangate_client::Error>(c)
        });
        match attempt {
            Ok(client) => return Ok((server, client, url, socketcand_port, cia309_port)),
            Err(_) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(100)),
            Err(e) => bail!("cangate-server did not answer on {url}: {e}"),
        }
    }
}

// ---------------------------------------------------------------------------
// Clients
// ---------------------------------------------------------------------------

/// `bench/python/raw_round_trip.py`, connected and warmed up, waiting for
/// block sizes.
struct PythonClient {
    child: Child,
    /// None once closed, which ends the script.
    stdin: Option<ChildStdin>,
    stdout: BufReader<ChildStdout>,
}

impl PythonClient {
    /// The script sending requests `request_id` (see [`RAW_REQUEST`])
    /// through the interface and gateway of `gateway_args`.
    fn start(
        python: &Path,
        warmup: usize,
        request_id: u16,
        gateway_args: &[String],
    ) -> Result<PythonClient> {
        let mut child = Command::new(python)
            .arg(RAW_SCRIPT)
            .args(gateway_args)
            .arg(format!("--request-id={request_id:#x}"))
            .arg(format!("--warmup={warmup}"))
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .with_context(|| format!("starting {}", python.display()))?;
        let stdin = child.stdin.take().context("python stdin")?;
        let stdout = BufReader::new(child.stdout.take().context("python stdout")?);
        let mut client = PythonClient {
            child,
            stdin: Some(stdin),
            stdout,
        };
        let line = client.line()?;
        if line.trim() != "ready" {
            bail!("raw_round_trip.py said {line:?} instead of ready");
        }
        Ok(client)
    }

    fn line(&mut self) -> Result<String> {
        let mut line = String::new();
        if self.stdout.read_line(&mut line)? == 0 {
            let status = self.child.wait()?;
            bail!("raw_round_trip.py ended ({status}); its error is above");
        }
        Ok(line)
    }

    /// `n` round trips; their latencies in ns.
    fn block(&mut self, n: usize) -> Result<Vec<u64>> {
        let stdin = self.stdin.as_mut().context("python's input is closed")?;
        writeln!(stdin, "{n}")?;
        stdin.flush()?;
        let line = self.line()?;
        let v: Json = serde_json::from_str(&line)
            .with_context(|| format!("raw_round_trip.py printed {line:?}"))?;
        let ns: Vec<u64> = v["ns"]
            .as_array()
            .context("no ns in the python block")?
            .iter()
            .filter_map(Json::as_u64)
            .collect();
        if ns.len() != n {
            bail!("raw_round_trip.py timed {} of {n} round trips", ns.len());
        }
        Ok(ns)
    }
}

impl Drop for PythonClient {
    fn drop(&mut self) {
        // Ending its input ends the script, which closes its connection
        // as a program would; killed if it does not within 5 s.
        drop(self.stdin.take());
        let deadline = Instant::now() + Duration::from_secs(5);
        while Instant::now() < deadline && matches!(self.child.try_wait(), Ok(None)) {
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A client of canopend's CiA 309-3 ASCII gateway on TCP: one command at
/// a time, `[seq] command` → `[seq] answer`.
struct AsciiGateway {
    writer: TcpStream,
    reader: BufReader<TcpStream>,
    seq: u64,
}

impl AsciiGateway {
    fn new(stream: TcpStream) -> Result<AsciiGateway> {
        stream.set_nodelay(true)?;
        stream.set_read_timeout(Some(Duration::from_secs(5)))?;
        Ok(AsciiGateway {
            reader: BufReader::new(stream.try_clone()?),
            writer: stream,
            seq: 0,
        })
    }

    /// The answer to `command`, without its sequence number; an `ERROR:`
    /// answer is an error.
    fn command(&mut self, command: &str) -> Result<String> {
        self.seq += 1;
        // One write per command, as a client program would send it.
        self.writer
            .write_all(format!("[{}] {command}\r\n", self.seq).as_bytes())?;
        let mut line = String::new();
        if self.reader.read_line(&mut line)? == 0 {
            bail!("canopend closed the connection");
        }
        let tag = format!("[{}] ", self.seq);
        let answer = line
            .trim_end()
            .strip_prefix(&tag)
            .with_context(|| format!("canopend answered {line:?} to {tag}{command}"))?;
        if answer.starts_with("ERROR") {
            bail!("canopend: {command}: {answer}");
        }
        Ok(answer.to_string())
    }
}

// ---------------------------------------------------------------------------
// Alternating blocks
// ---------------------------------------------------------------------------

/// One gateway's half of a comparison.
struct Side<'a> {
    /// Runs `n` timed calls, returns each one's latency in ns.
    calls: Box<dyn FnMut(usize) -> Result<Vec<u64>> + 'a>,
    /// The server's CPU so far (None: not measurable).
    cpu: Box<dyn Fn() -> Option<Cpu> + 'a>,
}

/// What one side measured.
struct Measured {
    latency: Histogram<u64>,
    /// The server's CPU over the timed blocks.
    cpu: Option<Cpu>,
}

impl Measured {
    fn percentiles(&self) -> Percentiles {
        Percentiles::of(&self.latency)
    }

    fn calls(&self) -> f64 {
        self.latency.len().max(1) as f64
    }

    /// Server CPU per call in µs.
    fn cpu_us_per_call(&self) -> Option<f64> {
        self.cpu.as_ref().map(|c| c.total * 1e6 / self.calls())
    }

    /// The same by thread (or process), largest first, without those
    /// under 1 µs.
    fn cpu_parts_us_per_call(&self) -> Vec<(String, f64)> {
        let mut parts: Vec<(String, f64)> = self
            .cpu
            .iter()
            .flat_map(|c| &c.parts)
            .map(|(k, v)| (k.clone(), v * 1e6 / self.calls()))
            .filter(|(_, v)| *v >= 1.0)
            .collect();
        parts.sort_by(|a, b| b.1.total_cmp(&a.1));
        parts
    }

    fn to_json(&self) -> Json {
        let mut v = self.percentiles().to_json();
        v["server_cpu_us_per_call"] = json!(self.cpu_us_per_call());
        v["server_cpu_us_per_call_by_thread"] = self
            .cpu_parts_us_per_call()
            .into_iter()
            .map(|(k, v)| (k, json!(v)))
            .collect::<serde_json::Map<_, _>>()
            .into();
        v
    }
}

/// `samples` timed calls of each side in `blocks` blocks, the sides taking
/// turns (block k starts with side k mod n), after `warmup` untimed calls
/// each.
fn alternate(
    sides: &mut [Side<'_>],
    samples: usize,
    blocks: usize,
    warmup: usize,
) -> Result<Vec<Measured>> {
    if warmup > 0 {
        for side in sides.iter_mut() {
            (side.calls)(warmup)?;
        }
    }
    let mut out: Vec<Measured> = sides
        .iter()
        .map(|_| Measured {
            latency: histogram(),
            cpu: Some(Cpu::default()),
        })
        .collect();
    for block in 0..blocks {
        // The last block takes the remainder.
        let n = samples / blocks
            + if block + 1 == blocks {
                samples % blocks
            } else {
                0
            };
        for k in 0..sides.len() {
            let i = (block + k) % sides.len();
            let side = &mut sides[i];
            let before = (side.cpu)();
            let ns = (side.calls)(n)?;
            let after = (side.cpu)();
            for v in ns {
                record_ns(&mut out[i].latency, v);
            }
            out[i].cpu = match (out[i].cpu.take(), before, after) {
                (Some(mut sum), Some(b), Some(a)) => {
                    sum.add(&a.since(&b));
                    Some(sum)
                }
                _ => None,
            };
        }
    }
    Ok(out)
}

/// Times `n` calls of `call`.
fn timed(n: usize, mut call: impl FnMut() -> Result<()>) -> Result<Vec<u64>> {
    let mut ns = Vec::with_capacity(n);
    for _ in 0..n {
        let start = Instant::now();
        call()?;
        ns.push(u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX));
    }
    Ok(ns)
}

// ---------------------------------------------------------------------------
// The run
// ---------------------------------------------------------------------------

/// One path's outcome: the peer's side (or why it was skipped) and ours.
struct Comparison {
    key: &'static str,
    path: &'static str,
    peer: &'static str,
    peer_side: std::result::Result<Measured, String>,
    cangate: Measured,
    /// The same calls without a gateway, where the path has that.
    floor: Option<Measured>,
    /// cangate through the peer's protocol and client, where it speaks it.
    cangate_as_peer: Option<Measured>,
}

/// A peer's binary from its variable, or why there is none.
fn peer_binary(var: &str, path: Option<&PathBuf>) -> std::result::Result<PathBuf, String> {
    match path {
        None => Err(format!("{var} is not set (the path of the peer's binary)")),
        Some(p) if !p.is_file() => Err(format!("{var}={} is not a file", p.display())),
        Some(p) => Ok(p.clone()),
    }
}

/// Measures every path.
fn run(args: &Args) -> Result<()> {
    let (samples, blocks, warmup) = (args.samples(), args.blocks(), args.warmup());
    println!(
        "peer_bench on {} ({}): {samples} calls per gateway and path in {blocks} alternating blocks, {warmup} warm-up calls",
        args.iface,
        if inside_vm() {
            "QEMU guest, software-emulated: compare ratios"
        } else {
            "this host"
        }
    );
    let dir = std::env::temp_dir().join(format!("peer_bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let result = run_in(args, &dir);
    let _ = std::fs::remove_dir_all(&dir);
    let (comparisons, idle) = result?;
    print_table(&comparisons);
    for c in &comparisons {
        let parts: Vec<String> = c
            .cangate
            .cpu_parts_us_per_call()
            .iter()
            .map(|(name, v)| format!("{name} {}", us(*v)))
            .collect();
        println!(
            "cangate-server CPU per call by thread, {}: {} µs",
            c.key,
            parts.join(", ")
        );
    }
    let mut json = to_json(args, &comparisons);
    json["idle_cpu_percent"] = json!(idle);
    println!("{json}");
    Ok(())
}

/// The idle CPU of each server (% of one core) by name.
type Idle = BTreeMap<&'static str, f64>;

fn run_in(args: &Args, dir: &Path) -> Result<(Vec<Comparison>, Idle)> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let responder = Responder::start(&args.iface)?;
    let (cangate, client, url, socketcand_port, cia309_port) =
        start_cangate(dir, &args.iface, &rt)?;
    let mut idle = Idle::new();
    if let Some(p) = idle_percent(&cangate, args.idle_secs()) {
        idle.insert("cangate-server", p);
    }
    let mut out = vec![raw_round_trip(args, dir, &cangate, &url, socketcand_port)?];
    let (sdo, no_bus) = canopen_paths(args, dir, &rt, &cangate, &client, cia309_port, &mut idle)?;
    out.push(sdo);
    out.push(no_bus);
    for (name, p) in &idle {
        println!("idle CPU of {name}: {p:.1} % of one core");
    }
    drop(cangate);
    responder.stop()?;
    Ok((out, idle))
}

/// Path 1: python-can through socketcand and through cangate's Attach
/// (and through cangate's socketcand endpoint, on port `cangate_socketcand`).
fn raw_round_trip(
    args: &Args,
    dir: &Path,
    cangate: &Server,
    url: &str,
    cangate_socketcand: u16,
) -> Result<Comparison> {
    let (samples, blocks, warmup) = (args.samples(), args.blocks(), args.warmup());
    let python = args.python();
    let probe = Command::new(&python)
        .args(["-c", "import can, cangate.can_interface"])
        .status();
    if !probe.is_ok_and(|s| s.success()) {
        bail!(
            "{} cannot import python-can and the cangate package (CANGATE_PYTHON; scripts/test builds target/python)",
            python.display()
        );
    }
    let peer = peer_binary("CANGATE_PEER_SOCKETCAND", args.socketcand.as_ref());
    println!("raw round trip (python-can, responder on {}):", args.iface);
    let mut ours = PythonClient::start(
        &python,
        warmup,
        RAW_VIA_CANGATE,
        &[
            "cangate".into(),
            "--channel=can0".into(),
            format!("--server={url}"),
        ],
    )?;
    let cangate_side = Side {
        calls: Box::new(|n| ours.block(n)),
        cpu: Box::new(|| cangate.cpu(false)),
    };
    let mut ours_as_socketcand = PythonClient::start(
        &python,
        warmup,
        RAW_VIA_CANGATE_SOCKETCAND,
        &[
            "socketcand".into(),
            "--channel=can0".into(),
            format!("--port={cangate_socketcand}"),
        ],
    )?;
    let cangate_as_peer_side = Side {
        calls: Box::new(|n| ours_as_socketcand.block(n)),
        cpu: Box::new(|| cangate.cpu(false)),
    };
    let mut direct = PythonClient::start(
        &python,
        warmup,
        RAW_DIRECT,
        &["socketcan".into(), format!("--channel={}", args.iface)],
    )?;
    // Timed in the same alternation, so that it is the floor of the same
    // moments; no server, so no CPU.
    let floor_side = Side {
        calls: Box::new(|n| direct.block(n)),
        cpu: Box::new(|| None),
    };
    let (peer_side, cangate, floor, cangate_as_peer) = match peer {
        Ok(bin) => {
            let port = free_port()?;
            // -l lo: listen on loopback; -n: no discovery beacon.
            let mut socketcand = Server::spawn(
                "socketcand",
                dir,
                Command::new(&bin).args([
                    "-i",
                    &args.iface,
                    "-l",
                    "lo",
                    "-n",
                    "-p",
                    &port.to_string(),
                ]),
            )?;
            // socketcand forks a process per client: this probe's ends
            // when it closes.
            drop(connect_when_up(&mut socketcand, port)?);
            let mut theirs = PythonClient::start(
                &python,
                warmup,
                RAW_VIA_SOCKETCAND,
                &[
                    "socketcand".into(),
                    format!("--channel={}", args.iface),
                    format!("--port={port}"),
                ],
            )?;
            let peer_side = Side {
                calls: Box::new(|n| theirs.block(n)),
                cpu: Box::new(|| socketcand.cpu(true)),
            };
            let mut sides = [peer_side, cangate_side, floor_side, cangate_as_peer_side];
            let [p, c, f, s] = four(alternate(&mut sides, samples, blocks, 0)?)?;
            (Ok(p), c, f, s)
        }
        Err(why) => {
            println!("  skipped: socketcand: {why}");
            let mut sides = [cangate_side, floor_side, cangate_as_peer_side];
            let [c, f, s] = three(alternate(&mut sides, samples, blocks, 0)?)?;
            (Err(why), c, f, s)
        }
    };
    Ok(Comparison {
        key: "raw_round_trip",
        path: "raw frame round trip, python-can client",
        peer: "socketcand",
        peer_side,
        cangate,
        floor: Some(floor),
        cangate_as_peer: Some(cangate_as_peer),
    })
}

fn three(m: Vec<Measured>) -> Result<[Measured; 3]> {
    m.try_into()
        .map_err(|m: Vec<Measured>| anyhow!("{} results for 3 sides", m.len()))
}

fn four(m: Vec<Measured>) -> Result<[Measured; 4]> {
    m.try_into()
        .map_err(|m: Vec<Measured>| anyhow!("{} results for 4 sides", m.len()))
}

/// Paths 2 and 3: an SDO read and a call without bus, canopend against
/// cangate (gRPC, and its CiA 309-3 endpoint on port `cia309_port` with
/// canopend's client).
fn canopen_paths(
    args: &Args,
    dir: &Path,
    rt: &tokio::runtime::Runtime,
    cangate: &Server,
    client: &Client,
    cia309_port: u16,
    idle: &mut Idle,
) -> Result<(Comparison, Comparison)> {
    let (samples, blocks, warmup) = (args.samples(), args.blocks(), args.warmup());
    let read = pb::ReadSdoRequest {
        bus: "can0".into(),
        node: NODE.into(),
        index: 0x1017,
        subindex: 0,
        r#type: 0,
        options: None,
        object: String::new(),
    };
    let expected = HEARTBEAT_VALUE.to_le_bytes();
    let mut sdo_client = client.clone();
    let cangate_sdo = Side {
        calls: Box::new(move |n| {
            timed(n, || {
                let r = rt.block_on(sdo_client.read_sdo(read.clone()))?;
                if r.raw != expected {
                    bail!("ReadSdo 0x1017 gave {:?}", r.raw);
                }
                Ok(())
            })
        }),
        cpu: Box::new(|| cangate.cpu(false)),
    };
    let mut bus_client = client.clone();
    let cangate_no_bus = Side {
        calls: Box::new(move |n| {
            timed(n, || {
                rt.block_on(bus_client.get_bus("can0"))?;
                Ok(())
            })
        }),
        cpu: Box::new(|| cangate.cpu(false)),
    };
    // The same ASCII client against cangate's CiA 309-3 endpoint.
    let mut ours = AsciiGateway::new(
        TcpStream::connect(("127.0.0.1", cia309_port)).context("cangate's CiA 309-3 endpoint")?,
    )?;
    let ours = std::cell::RefCell::new(&mut ours);
    let ascii_read = |gw: &mut AsciiGateway| -> Result<()> {
        let v = gw.command(&format!("{NODE} r 0x1017 0 u16"))?;
        if v != HEARTBEAT_VALUE.to_string() {
            bail!("read 0x1017 as {v:?}");
        }
        Ok(())
    };
    let ascii_set_node = |gw: &mut AsciiGateway| -> Result<()> {
        let v = gw.command(&format!("set node {NODE}"))?;
        if v != "OK" {
            bail!("set node answered {v:?}");
        }
        Ok(())
    };
    let ours_sdo = Side {
        calls: Box::new(|n| timed(n, || ascii_read(&mut ours.borrow_mut()))),
        cpu: Box::new(|| cangate.cpu(false)),
    };
    let ours_no_bus = Side {
        calls: Box::new(|n| timed(n, || ascii_set_node(&mut ours.borrow_mut()))),
        cpu: Box::new(|| cangate.cpu(false)),
    };
    let sdo_path = "SDO expedited read 0x1017, Rust client";
    let no_bus_path = "unary call without bus (cangate GetBus, canopend `set node`)";
    let peer = peer_binary("CANGATE_PEER_CANOPEND", args.canopend.as_ref());
    println!(
        "SDO read and call without bus (Rust clients, node {NODE} on {}):",
        args.iface
    );
    let (sdo, no_bus) = match peer {
        Ok(bin) => {
            let port = free_port()?;
            // Its storage files go to the temporary directory.
            let mut canopend = Server::spawn(
                "canopend",
                dir,
                Command::new(&bin)
                    .arg(&args.iface)
                    .args(["-i", &CANOPEND_NODE.to_string()])
                    .args(["-c", &format!("tcp-{port}")])
                    .arg("-s")
                    .arg(dir.join("canopend_"))
                    .current_dir(dir),
            )?;
            let mut gw = AsciiGateway::new(connect_when_up(&mut canopend, port)?)?;
            if let Some(p) = idle_percent(&canopend, args.idle_secs()) {
                idle.insert("canopend", p);
            }
            let gw = std::cell::RefCell::new(&mut gw);
            let peer_sdo = Side {
                calls: Box::new(|n| {
                    timed(n, || {
                        let v = gw.borrow_mut().command(&format!("{NODE} r 0x1017 0 u16"))?;
                        if v != HEARTBEAT_VALUE.to_string() {
                            bail!("canopend read 0x1017 as {v:?}");
                        }
                        Ok(())
                    })
                }),
                cpu: Box::new(|| canopend.cpu(false)),
            };
            let mut sides = [peer_sdo, cangate_sdo, ours_sdo];
            let [p, c, o] = three(alternate(&mut sides, samples, blocks, warmup)?)?;
            let sdo = (p, c, o);
            let peer_no_bus = Side {
                calls: Box::new(|n| {
                    timed(n, || {
                        let v = gw.borrow_mut().command(&format!("set node {NODE}"))?;
                        if v != "OK" {
                            bail!("canopend answered set node with {v:?}");
                        }
                        Ok(())
                    })
                }),
                cpu: Box::new(|| canopend.cpu(false)),
            };
            let mut sides = [peer_no_bus, cangate_no_bus, ours_no_bus];
            let [p, c, o] = three(alternate(&mut sides, samples, blocks, warmup)?)?;
            ((Ok(sdo.0), sdo.1, sdo.2), (Ok(p), c, o))
        }
        Err(why) => {
            println!("  skipped: canopend: {why}");
            let [sdo, ours_sdo]: [Measured; 2] =
                alternate(&mut [cangate_sdo, ours_sdo], samples, blocks, warmup)?
                    .try_into()
                    .map_err(|_| anyhow!("two sides"))?;
            let [no_bus, ours_no_bus]: [Measured; 2] =
                alternate(&mut [cangate_no_bus, ours_no_bus], samples, blocks, warmup)?
                    .try_into()
                    .map_err(|_| anyhow!("two sides"))?;
            (
                (Err(why.clone()), sdo, ours_sdo),
                (Err(why), no_bus, ours_no_bus),
            )
        }
    };
    Ok((
        Comparison {
            key: "sdo_expedited_read",
            path: sdo_path,
            peer: "canopend (CiA 309-3 over TCP)",
            peer_side: sdo.0,
            cangate: sdo.1,
            floor: None,
            cangate_as_peer: Some(sdo.2),
        },
        Comparison {
            key: "no_bus_call",
            path: no_bus_path,
            peer: "canopend (CiA 309-3 over TCP)",
            peer_side: no_bus.0,
            cangate: no_bus.1,
            floor: None,
            cangate_as_peer: Some(no_bus.2),
        },
    ))
}

// ---------------------------------------------------------------------------
// Output
// ---------------------------------------------------------------------------

fn us(v: f64) -> String {
    if v >= 100.0 {
        format!("{v:.0}")
    } else {
        format!("{v:.1}")
    }
}

fn print_table(comparisons: &[Comparison]) {
    println!();
    println!("| path | peer | peer p50 / p99 | cangate p50 / p99 | cangate ÷ peer (p50 / p99) |");
    println!("| --- | --- | --- | --- | --- |");
    for c in comparisons {
        let ours = c.cangate.percentiles();
        let ours_cell = format!("{} / {} µs", us(ours.p50_us), us(ours.p99_us));
        match &c.peer_side {
            Ok(peer) => {
                let theirs = peer.percentiles();
                println!(
                    "| {} | {} | {} / {} µs | {ours_cell} | {:.2}× / {:.2}× |",
                    c.path,
                    c.peer,
                    us(theirs.p50_us),
                    us(theirs.p99_us),
                    ours.p50_us / theirs.p50_us,
                    ours.p99_us / theirs.p99_us,
                );
            }
            Err(why) => println!(
                "| {} | {} | skipped: {why} | {ours_cell} | – |",
                c.path, c.peer
            ),
        }
        let ours_cpu = c.cangate.cpu_us_per_call();
        let theirs_cpu = c
            .peer_side
            .as_ref()
            .ok()
            .and_then(Measured::cpu_us_per_call);
        let cell = |v: Option<f64>| v.map_or("–".into(), |v| format!("{} µs", us(v)));
        let ratio = match (ours_cpu, theirs_cpu) {
            (Some(o), Some(t)) if t > 0.0 => format!("{:.2}×", o / t),
            _ => "–".into(),
        };
        println!(
            "| … server CPU per call | | {} | {} | {ratio} |",
            cell(theirs_cpu),
            cell(ours_cpu)
        );
        if let Some(via) = &c.cangate_as_peer {
            let v = via.percentiles();
            let (ratio, cpu_ratio) = match &c.peer_side {
                Ok(peer) => {
                    let t = peer.percentiles();
                    let cpu = match (via.cpu_us_per_call(), peer.cpu_us_per_call()) {
                        (Some(o), Some(t)) if t > 0.0 => format!("{:.2}×", o / t),
                        _ => "–".into(),
                    };
                    (
                        format!("{:.2}× / {:.2}×", v.p50_us / t.p50_us, v.p99_us / t.p99_us),
                        cpu,
                    )
                }
                Err(_) => ("–".into(), "–".into()),
            };
            // The peer's own protocol, served by cangate.
            let endpoint = if c.key == "raw_round_trip" {
                "socketcand"
            } else {
                "CiA 309-3"
            };
            println!(
                "| … the same client to cangate's {endpoint} endpoint | | | {} / {} µs | {ratio} |",
                us(v.p50_us),
                us(v.p99_us)
            );
            println!(
                "| … its server CPU per call | | | {} | {cpu_ratio} |",
                cell(via.cpu_us_per_call())
            );
        }
        if let Some(floor) = &c.floor {
            let f = floor.percentiles();
            println!(
                "| … the same without a gateway | python-can `socketcan` | {} / {} µs | – | – |",
                us(f.p50_us),
                us(f.p99_us)
            );
        }
    }
    println!();
}

fn to_json(args: &Args, comparisons: &[Comparison]) -> Json {
    let mut paths = serde_json::Map::new();
    for c in comparisons {
        let (peer, ratios) = match &c.peer_side {
            Ok(p) => {
                let (o, t) = (c.cangate.percentiles(), p.percentiles());
                let cpu = match (c.cangate.cpu_us_per_call(), p.cpu_us_per_call()) {
                    (Some(o), Some(t)) if t > 0.0 => json!(o / t),
                    _ => Json::Null,
                };
                (
                    p.to_json(),
                    json!({"p50": o.p50_us / t.p50_us, "p99": o.p99_us / t.p99_us, "server_cpu": cpu}),
                )
            }
            Err(why) => (json!({"skipped": why}), Json::Null),
        };
        paths.insert(
            c.key.into(),
            json!({
                "path": c.path,
                "peer_name": c.peer,
                "peer": peer,
                "cangate": c.cangate.to_json(),
                "without_gateway": c.floor.as_ref().map(|f| f.percentiles().to_json()),
                "cangate_as_peer": c.cangate_as_peer.as_ref().map(Measured::to_json),
                "cangate_over_peer": ratios,
            }),
        );
    }
    json!({
        "bench": "peer_bench",
        "iface": args.iface,
        "vm": inside_vm(),
        "samples": args.samples(),
        "blocks": args.blocks(),
        "warmup": args.warmup(),
        "paths": paths,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(id: u16, data: &[u8]) -> CanFrame {
        CanFrame::new(StandardId::new(id).unwrap(), data).unwrap()
    }

    #[test]
    fn responder_answers_raw_and_sdo() {
        let r = answer(&frame(RAW_REQUEST, &[1, 2, 3])).unwrap();
        assert_eq!(answer(&frame(0x10E, &[])).unwrap().raw_id(), 0x10F);
        assert!(answer(&frame(0x101, &[])).is_none());
        assert!(answer(&frame(0x110, &[])).is_none());
        assert_eq!((r.raw_id(), r.data()), (0x101, &[1u8, 2, 3][..]));
        let r = answer(&frame(0x605, &[0x40, 0x17, 0x10, 0, 0, 0, 0, 0])).unwrap();
        assert_eq!(r.raw_id(), 0x585);
        assert_eq!(r.data(), &[0x4B, 0x17, 0x10, 0, 0xE8, 0x03, 0, 0]);
        let r = answer(&frame(0x605, &[0x23, 0x00, 0x10, 0, 1, 2, 3, 4])).unwrap();
        assert_eq!(r.data()[0], 0x60);
        assert!(answer(&frame(0x606, &[0x40, 0x17, 0x10, 0, 0, 0, 0, 0])).is_none());
        assert!(answer(&frame(0x605, &[0x40])).is_none());
    }

    #[test]
    fn alternating_blocks_split_the_samples() {
        let order = std::cell::RefCell::new(Vec::new());
        let mut sides = [
            Side {
                calls: Box::new(|n| {
                    order.borrow_mut().push(('a', n));
                    Ok(vec![1000; n])
                }),
                cpu: Box::new(|| {
                    Some(Cpu {
                        total: 1.0,
                        parts: BTreeMap::from([("main".to_string(), 1.0)]),
                    })
                }),
            },
            Side {
                calls: Box::new(|n| {
                    order.borrow_mut().push(('b', n));
                    Ok(vec![2000; n])
                }),
                cpu: Box::new(|| None),
            },
        ];
        let m = alternate(&mut sides, 7, 3, 1).unwrap();
        drop(sides);
        assert_eq!(
            order.into_inner(),
            [
                ('a', 1),
                ('b', 1),
                ('a', 2),
                ('b', 2),
                ('b', 2),
                ('a', 2),
                ('a', 3),
                ('b', 3)
            ]
        );
        assert_eq!(m[0].latency.len(), 7);
        assert_eq!(m[0].cpu_us_per_call(), Some(0.0));
        assert!(m[0].cpu_parts_us_per_call().is_empty());
        assert_eq!(m[1].cpu_us_per_call(), None);
    }
}
