//! `soak_bench`: the embedded demo under mixed load and CPU contention.
//!
//! ```text
//! cargo run --release -p cangate-bench --bin soak_bench -- --minutes 10
//! cargo run -p cangate-bench --bin soak_bench -- --quick      # CI smoke
//! ```
//!
//! The demo configuration (virtual buses can0, smc0, smc1 with their
//! simulated drives, handwheel, I/O node and CANsmc slaves) runs on its own
//! runtime in this process, while for the whole run:
//!
//! - frame streams read can0 (with the gateway's own frames) and smc0, one
//!   of them pausing 5 s in every 20 s (a reader that stalls);
//! - SDO reads go to the three drives, one after another, without pause;
//! - the cyclic axes X and Y, the profile axis Z and the CANsmc axes A and B
//!   move to random targets (waiting for completion), some moves are
//!   stopped half-way and Z sometimes homes; a faulted axis is reset;
//! - raw frames (id 0x7F0, 500 frames/s) are sent on can0;
//! - `--hogs` threads spin at the default priority (by default one per
//!   core), so the gateway competes for the CPU.
//!
//! At the end it prints what went wrong (call errors by code, stream
//! transport errors, frames lost to slow readers, SYNC periods skipped,
//! heartbeats lost, CANsmc DTs not answered in time, slave losses, axis
//! faults), the process's resident memory at start and end, then one JSON
//! line. The gateway's counters come from its Prometheus endpoint, as an
//! operator would read them. Exit 1 if the run could not start; with
//! `--strict` also if a SYNC period or heartbeat was lost, a CANsmc DT was
//! missed or a stream broke.

use anyhow::{Context, Result};
use cangate_bench::axes::{self, AxesClient};
use cangate_bench::{gateway, host};
use cangate_client::pb;
use cangate_server::RunningServer;
use cangate_server::config::DEMO_CONFIG;
use clap::Parser;
use serde_json::json;
use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// The embedded demo under mixed load and CPU contention.
#[derive(Parser, Debug, Clone)]
#[command(about)]
struct Args {
    /// Length of the run.
    #[arg(long, default_value_t = 10.0)]
    minutes: f64,
    /// A 5-second run, for CI smoke runs.
    #[arg(long)]
    quick: bool,
    /// Busy threads competing for the CPU (default: one per core).
    #[arg(long)]
    hogs: Option<usize>,
    /// Exit 1 when a SYNC period or heartbeat was lost, a CANsmc DT was
    /// missed or a stream broke.
    #[arg(long)]
    strict: bool,
}

/// What the load clients saw.
#[derive(Default)]
struct Seen {
    /// Calls by "method: code".
    calls: Mutex<BTreeMap<String, u64>>,
    /// Failed calls by "method: code: message" (messages as the server
    /// wrote them, so the printout says what went wrong).
    errors: Mutex<BTreeMap<String, u64>>,
    /// Axis command outcomes by "axis command outcome".
    outcomes: Mutex<BTreeMap<String, u64>>,
    stream_frames: AtomicU64,
    stream_lost: AtomicU64,
    stream_errors: AtomicU64,
    raw_sent: AtomicU64,
}

impl Seen {
    fn call<T>(&self, method: &str, r: &Result<T, tonic::Status>) {
        let code = match r {
            Ok(_) => "OK".to_string(),
            Err(s) => format!("{:?}", s.code()),
        };
        if let Err(s) = r {
            *self
                .errors
                .lock()
                .expect("errors")
                .entry(format!("{method}: {code}: {}", s.message()))
                .or_default() += 1;
        }
        *self
            .calls
            .lock()
            .expect("calls")
            .entry(format!("{method}: {code}"))
            .or_default() += 1;
    }

    /// Counts the background renewals of a lease guard: each success as
    /// a RenewControl call, and the latest failure (if the renewing ended
    /// failing) as an error.
    fn renewals(&self, status: &cangate_client::LeaseStatus) {
        *self
            .calls
            .lock()
            .expect("calls")
            .entry("RenewControl: OK".into())
            .or_default() += status.renewals;
        if let Some(e) = &status.last_error {
            self.call::<()>("RenewControl", &Err(status_of(e)));
        }
    }

    fn outcome(&self, axis: &str, command: &str, r: &pb::AxisCommandResponse) {
        let name = pb::Outcome::try_from(r.outcome)
            .map(|o| o.as_str_name().trim_start_matches("OUTCOME_").to_string())
            .unwrap_or_else(|_| r.outcome.to_string());
        *self
            .outcomes
            .lock()
            .expect("outcomes")
            .entry(format!("{axis} {command} {name}"))
            .or_default() += 1;
    }

    fn errors(&self) -> u64 {
        self.calls
            .lock()
            .expect("calls")
            .iter()
            .filter(|(k, _)| !k.ends_with(": OK"))
            .map(|(_, n)| n)
            .sum()
    }
}

/// A small deterministic generator (xorshift64*): a soak run is
/// repeatable in what it asks, not in how the host schedules it.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform in [lo, hi).
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn main() -> ExitCode {
    let args = Args::parse();
    host::exit_code("soak_bench", args.strict, run(&args))
}

fn run(args: &Args) -> Result<bool> {
    let duration = if args.quick {
        Duration::from_secs(5)
    } else {
        Duration::from_secs_f64(args.minutes * 60.0)
    };
    let hogs = args.hogs.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(2)
    });
    // The demo as shipped, on free ports; the per-client limits are off
    // because the load clients are the point here (the abuse tests cover
    // the limits).
    let text = DEMO_CONFIG.replacen(
        "listen = \"127.0.0.1:50051\"",
        "listen = \"127.0.0.1:0\"\nmetrics_listen = \"127.0.0.1:0\"",
        1,
    );
    let mut config = gateway::config(&text)?;
    gateway::lift_client_limits(&mut config);
    let gateway_rt = gateway::runtime("gateway", gateway::gateway_workers())?;
    let server = gateway::start_on(&gateway_rt, &config)?;
    let metrics_addr = server.metrics_addr.context("metrics endpoint")?;
    let load_rt = gateway::runtime("load", 2)?;
    let seen = Arc::new(Seen::default());
    let ready = load_rt.block_on(wait_ready(&server))?;
    let rss_start = host::rss_kib();
    let before = scrape(metrics_addr)?;
    let started = Instant::now();
    let stop = Arc::new(AtomicBool::new(false));
    let hog_threads: Vec<_> = (0..hogs)
        .map(|i| {
            let stop = stop.clone();
            std::thread::Builder::new()
                .name(format!("hog-{i}"))
                .spawn(move || {
                    let mut x = 0u64;
                    while !stop.load(Ordering::Relaxed) {
                        for _ in 0..10_000 {
                            x = std::hint::black_box(x.wrapping_mul(31).wrapping_add(7));
                        }
                    }
                })
                .expect("spawn hog")
        })
        .collect();
    load_rt.block_on(load(&server, &seen, duration, &ready));
    stop.store(true, Ordering::Relaxed);
    for h in hog_threads {
        let _ = h.join();
    }
    let elapsed = started.elapsed();
    let after = scrape(metrics_addr)?;
    let rss_end = host::rss_kib();
    server.shutdown();
    let _ = gateway_rt.block_on(server.wait(Duration::from_secs(10)));

    let delta = |name: &str, label: Option<&str>| -> f64 {
        let sum = |m: &BTreeMap<String, f64>| -> f64 {
            m.iter()
                .filter(|(k, _)| metric_name(k) == name && label.is_none_or(|l| k.contains(l)))
                .map(|(_, v)| v)
                .sum()
        };
        sum(&after) - sum(&before)
    };
    let syncs_sent = delta("cangate_sync_sent_total", None);
    let syncs_skipped = delta("cangate_sync_skipped_total", None);
    let heartbeats_lost = delta("cangate_heartbeat_lost_total", None);
    let dts_valid = delta("cangate_cansmc_dts_total", Some("result=\"valid\""));
    // Rejects are answers (a slave refusing a command), not misses.
    let dts_missed = ["missed", "late", "counter_mismatch"]
        .iter()
        .map(|r| delta("cangate_cansmc_dts_total", Some(&format!("result=\"{r}\""))))
        .sum::<f64>();
    let slave_losses = delta("cangate_cansmc_slave_losses_total", None);
    let overruns = delta("cangate_cansmc_overruns_total", None);
    let stream_drops = delta("cangate_bus_stream_drops_total", None);
    let lag_drops = delta("cangate_stream_lag_drops_total", None);
    let tx_failed = delta("cangate_bus_tx_failed_total", None);
    let emcys = delta("cangate_emcy_total", None);
    let faulted: Vec<String> = after
        .iter()
        .filter(|(k, v)| metric_name(k) == "cangate_axis_fault" && **v > 0.0)
        .map(|(k, _)| k.clone())
        .collect();
    let errors = seen.errors();
    let stream_errors = seen.stream_errors.load(Ordering::Relaxed);
    let sync_kept = if syncs_sent + syncs_skipped > 0.0 {
        100.0 * syncs_sent / (syncs_sent + syncs_skipped)
    } else {
        0.0
    };

    println!(
        "soak: {:.1} min of the demo, {hogs} CPU hog thread(s), started with {} axes ready",
        elapsed.as_secs_f64() / 60.0,
        ready.len()
    );
    println!("  calls:");
    for (k, n) in seen.calls.lock().expect("calls").iter() {
        println!("    {k:<40} {n}");
    }
    let failed = seen.errors.lock().expect("errors");
    if !failed.is_empty() {
        println!("  failed calls:");
        for (k, n) in failed.iter() {
            println!("    {n:>6} x {k}");
        }
    }
    drop(failed);
    println!("  axis command outcomes:");
    for (k, n) in seen.outcomes.lock().expect("outcomes").iter() {
        println!("    {k:<40} {n}");
    }
    println!(
        "  streams: {} frames, {} lost to the paused reader (FramesLost), {} transport errors",
        seen.stream_frames.load(Ordering::Relaxed),
        seen.stream_lost.load(Ordering::Relaxed),
        stream_errors
    );
    println!(
        "  raw frames sent: {}; bus transmissions failed: {tx_failed}",
        seen.raw_sent.load(Ordering::Relaxed)
    );
    println!(
        "  SYNC: {syncs_sent} sent, {syncs_skipped} periods skipped ({sync_kept:.3} % kept); heartbeats lost: {heartbeats_lost}; EMCYs: {emcys}"
    );
    println!(
        "  CANsmc: {dts_valid} valid DTs, {dts_missed} missed, late or with a wrong counter; {slave_losses} slave losses; {overruns} cycle overruns"
    );
    println!("  stream drops (bus fan-out): {stream_drops}; gRPC stream lag drops: {lag_drops}");
    println!(
        "  axes faulted at the end: {}",
        if faulted.is_empty() {
            "none".to_string()
        } else {
            faulted.join(", ")
        }
    );
    println!(
        "  RSS: {} KiB at start, {} KiB at end",
        rss_start.unwrap_or(0),
        rss_end.unwrap_or(0)
    );
    let clean = syncs_skipped == 0.0
        && heartbeats_lost == 0.0
        && dts_missed == 0.0
        && slave_losses == 0.0
        && stream_errors == 0;
    println!(
        "{}",
        json!({
            "bench": "soak",
            "minutes": elapsed.as_secs_f64() / 60.0,
            "hogs": hogs,
            "call_errors": errors,
            "calls": *seen.calls.lock().expect("calls"),
            "outcomes": *seen.outcomes.lock().expect("outcomes"),
            "stream_frames": seen.stream_frames.load(Ordering::Relaxed),
            "stream_lost": seen.stream_lost.load(Ordering::Relaxed),
            "stream_errors": stream_errors,
            "raw_sent": seen.raw_sent.load(Ordering::Relaxed),
            "tx_failed": tx_failed,
            "syncs_sent": syncs_sent,
            "syncs_skipped": syncs_skipped,
            "heartbeats_lost": heartbeats_lost,
            "emcys": emcys,
            "dts_valid": dts_valid,
            "dts_missed": dts_missed,
            "slave_losses": slave_losses,
            "cansmc_overruns": overruns,
            "stream_drops": stream_drops,
            "lag_drops": lag_drops,
            "faulted_axes": faulted,
            "rss_kib_start": rss_start,
            "rss_kib_end": rss_end,
            "clean": clean,
        })
    );
    Ok(clean)
}

/// Waits until every axis reports a drive state (20 s at most); returns the
/// names of those that do.
async fn wait_ready(server: &RunningServer) -> Result<Vec<String>> {
    let mut c: AxesClient = cangate_client::connect(&gateway::url(server))
        .await?
        .axes_client();
    let t0 = Instant::now();
    loop {
        let (up, total) = axes::axes_up(&mut c).await?;
        if up.len() == total || t0.elapsed() > Duration::from_secs(20) {
            return Ok(up);
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

async fn load(server: &RunningServer, seen: &Arc<Seen>, duration: Duration, ready: &[String]) {
    let url = gateway::url(server);
    let deadline = tokio::time::Instant::now() + duration;
    let mut tasks = tokio::task::JoinSet::new();
    for (bus, tx, pause) in [
        ("can0", true, false),
        ("smc0", false, true),
        ("can0", false, false),
    ] {
        tasks.spawn(stream_load(
            url.clone(),
            seen.clone(),
            deadline,
            bus,
            tx,
            pause,
        ));
    }
    tasks.spawn(sdo_load(url.clone(), seen.clone(), deadline));
    tasks.spawn(raw_load(url.clone(), seen.clone(), deadline));
    let limits: BTreeMap<&str, f64> = [
        ("X", 180.0),
        ("Y", 180.0),
        ("Z", 90.0),
        ("A", 90.0),
        ("B", 90.0),
    ]
    .into_iter()
    .collect();
    for (seed, (axis, limit)) in limits.into_iter().enumerate() {
        if ready.iter().any(|r| r == axis) {
            tasks.spawn(axis_load(
                url.clone(),
                seen.clone(),
                deadline,
                axis,
                limit,
                seed as u64 + 1,
            ));
        }
    }
    while tasks.join_next().await.is_some() {}
}

async fn stream_load(
    url: String,
    seen: Arc<Seen>,
    deadline: tokio::time::Instant,
    bus: &'static str,
    include_transmitted: bool,
    pauses: bool,
) {
    let Ok(c) = cangate_client::connect(&url).await else {
        seen.stream_errors.fetch_add(1, Ordering::Relaxed);
        return;
    };
    let t0 = tokio::time::Instant::now();
    while tokio::time::Instant::now() < deadline {
        let r = c
            .bus_client()
            .stream_frames(pb::StreamFramesRequest {
                bus: bus.into(),
                include_transmitted,
                ..Default::default()
            })
            .await;
        seen.call("StreamFrames", &r);
        let Ok(r) = r else {
            tokio::time::sleep(Duration::from_millis(100)).await;
            continue;
        };
        let mut s = r.into_inner();
        loop {
            if pauses && (t0.elapsed().as_secs() % 20) >= 15 {
                // The reader stalls; the gateway must tell it what it lost.
                tokio::time::sleep(Duration::from_secs(1)).await;
                if tokio::time::Instant::now() >= deadline {
                    return;
                }
                continue;
            }
            match tokio::time::timeout_at(deadline, s.message()).await {
                Err(_) => return,
                Ok(Ok(Some(m))) => {
                    for e in m.events {
                        match e.event {
                            Some(pb::stream_event::Event::Frame(_)) => {
                                seen.stream_frames.fetch_add(1, Ordering::Relaxed);
                            }
                            Some(pb::stream_event::Event::Lost(l)) => {
                                seen.stream_lost.fetch_add(l.count, Ordering::Relaxed);
                            }
                            _ => {}
                        }
                    }
                }
                Ok(Ok(None)) | Ok(Err(_)) => {
                    seen.stream_errors.fetch_add(1, Ordering::Relaxed);
                    break;
                }
            }
        }
    }
}

async fn sdo_load(url: String, seen: Arc<Seen>, deadline: tokio::time::Instant) {
    let Ok(c) = cangate_client::connect(&url).await else {
        seen.call::<()>("ReadSdo", &Err(tonic::Status::unavailable("connect")));
        return;
    };
    let mut canopen = c.canopen_client();
    let reads = [(1, 0x1008, 0), (2, 0x1018, 1), (4, 0x6064, 0)];
    let mut n = 0usize;
    while tokio::time::Instant::now() < deadline {
        let (node, index, subindex) = reads[n % reads.len()];
        n += 1;
        let r = canopen
            .read_sdo(pb::ReadSdoRequest {
                bus: "can0".into(),
                node,
                index,
                subindex,
                ..Default::default()
            })
            .await;
        seen.call("ReadSdo", &r);
        if r.is_err() {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }
}

async fn raw_load(url: String, seen: Arc<Seen>, deadline: tokio::time::Instant) {
    let Ok(c) = cangate_client::connect(&url).await else {
        return;
    };
    let mut bus = c.bus_client();
    let mut tick = tokio::time::interval(Duration::from_millis(20));
    let mut n = 0u32;
    while tokio::time::Instant::now() < deadline {
        tick.tick().await;
        let frames = (0..10)
            .map(|_| {
                n = n.wrapping_add(1);
                pb::Frame {
                    id: 0x7F0,
                    data: n.to_le_bytes().to_vec(),
                    ..Default::default()
                }
            })
            .collect();
        let r = bus
            .send_frames(pb::SendFramesRequest {
                bus: "can0".into(),
                frames,
            })
            .await;
        if let Ok(ok) = &r {
            seen.raw_sent
                .fetch_add(u64::from(ok.get_ref().sent), Ordering::Relaxed);
        }
        seen.call("SendFrames", &r);
    }
}

async fn axis_load(
    url: String,
    seen: Arc<Seen>,
    deadline: tokio::time::Instant,
    axis: &'static str,
    limit: f64,
    seed: u64,
) {
    let Ok(c) = cangate_client::connect(&url).await else {
        return;
    };
    let mut axes = c.axes_client();
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15 ^ seed);
    // The client library's lease guard renews it beside the commands, as
    // an HMI keeps its lease; what the renewals met is counted at the end.
    let lease = c
        .acquire_control_as(&[axis], Duration::from_secs(5), &format!("soak-{axis}"))
        .await;
    seen.call("AcquireControl", &lease.as_ref().map_err(status_of));
    let Ok(guard) = lease else { return };
    let lease = guard.token().to_string();
    // Longer than the longest move: A and B cross their ±90 mm at their
    // default 5 mm/s in 36 s.
    let opts = |wait: bool| axes::command_options(&lease, wait, Duration::from_secs(60));
    let simple = |wait: bool| pb::AxisCommandRequest {
        axis: axis.into(),
        options: opts(wait),
    };
    let mut enabled = false;
    let mut n = 0u64;
    while tokio::time::Instant::now() < deadline {
        n += 1;
        if !enabled {
            let r = axes.reset_fault(simple(true)).await;
            seen.call("ResetFault", &r);
            let r = axes.enable(simple(true)).await;
            seen.call("Enable", &r);
            if let Ok(r) = &r {
                seen.outcome(axis, "Enable", r.get_ref());
                enabled = r.get_ref().outcome == pb::Outcome::Completed as i32;
            }
            if !enabled {
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
            continue;
        }
        if axis == "Z" && n.is_multiple_of(10) {
            let r = axes.home(simple(true)).await;
            seen.call("Home", &r);
            if let Ok(r) = &r {
                seen.outcome(axis, "Home", r.get_ref());
            }
            continue;
        }
        let interrupt = n.is_multiple_of(7);
        let r = axes
            .r#move(pb::MoveRequest {
                axis: axis.into(),
                target: rng.range(-limit, limit),
                relative: false,
                velocity: 0.0,
                acceleration: 0.0,
                options: opts(!interrupt),
            })
            .await;
        seen.call(&format!("{axis} Move"), &r);
        match &r {
            Ok(r) => seen.outcome(axis, "Move", r.get_ref()),
            Err(s) if s.code() == tonic::Code::FailedPrecondition => enabled = false,
            Err(_) => {}
        }
        if interrupt {
            tokio::time::sleep(Duration::from_millis(rng.range(20.0, 300.0) as u64)).await;
            let r = axes.stop(simple(true)).await;
            seen.call("Stop", &r);
            if let Ok(r) = &r {
                seen.outcome(axis, "Stop", r.get_ref());
            }
        }
    }
    let r = axes.stop(simple(true)).await;
    seen.call("Stop", &r);
    seen.renewals(&guard.status());
    let r = guard.release().await;
    seen.call("ReleaseControl", &r.map_err(|e| status_of(&e)));
}

/// A client library error as the gRPC status it carries (a transport
/// failure as UNAVAILABLE), to count it like the other calls.
fn status_of(e: &cangate_client::Error) -> tonic::Status {
    e.status()
        .cloned()
        .unwrap_or_else(|| tonic::Status::unavailable(e.to_string()))
}

/// The gateway's Prometheus text as (series, value).
fn scrape(addr: std::net::SocketAddr) -> Result<BTreeMap<String, f64>> {
    let mut s = std::net::TcpStream::connect(addr)?;
    s.set_read_timeout(Some(Duration::from_secs(10)))?;
    write!(
        s,
        "GET /metrics HTTP/1.0\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )?;
    let mut body = String::new();
    s.read_to_string(&mut body)?;
    let body = body
        .split_once("\r\n\r\n")
        .map(|(_, b)| b)
        .context("no HTTP body")?;
    Ok(body
        .lines()
        .filter(|l| !l.starts_with('#'))
        .filter_map(|l| {
            let (series, value) = l.rsplit_once(' ')?;
            Some((series.to_string(), value.parse().ok()?))
        })
        .collect())
}

fn metric_name(series: &str) -> &str {
    series.split('{').next().unwrap_or(series)
}
