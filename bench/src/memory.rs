//! `memory`: resident memory and idle CPU of the real server binary running
//! the embedded demo.
//!
//! Spawns `cangate-server --listen 127.0.0.1:<free port>` (by default the
//! binary next to this one, i.e. the same target profile), waits until it
//! answers a gRPC ListBuses call, lets it settle, reads `VmRSS` (and the peak
//! `VmHWM`) from `/proc/<pid>/status`, then the CPU time its threads use
//! over an idle window with no client (the demo at rest: SYNC, heartbeats,
//! the CANsmc cycle and the simulated devices answering them), per thread
//! from `/proc/<pid>/task`, and stops it with SIGTERM.

use anyhow::{Context, Result};
use cangate_bench::child::{ServerChild, default_server_binary};
use cangate_bench::host::{process_thread_cpu, status_kib};
use cangate_bench::report::{Measure, Outcome, Target};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Target: RSS below this many MiB.
pub const TARGET_MIB: f64 = 40.0;
/// Settle time before reading the RSS.
pub const SETTLE: Duration = Duration::from_secs(1);
/// Settle time with `--quick`.
pub const QUICK_SETTLE: Duration = Duration::from_millis(200);
/// How long the server may take to answer its first call.
const READY_TIMEOUT: Duration = Duration::from_secs(15);

const LABEL: &str = "server RSS (embedded demo)";
const IDLE_LABEL: &str = "idle demo CPU (% of one core)";
/// Target: the demo at rest below this share of one core.
pub const IDLE_TARGET_PERCENT: f64 = 10.0;
/// The idle window over which CPU time is measured.
pub const IDLE_WINDOW: Duration = Duration::from_secs(10);
/// The idle window with `--quick`.
pub const QUICK_IDLE_WINDOW: Duration = Duration::from_millis(500);

/// Runs the benchmark with `binary` (or the default one).
pub async fn run(
    binary: Option<PathBuf>,
    settle: Duration,
    idle: Duration,
) -> Result<Vec<Measure>> {
    let explicit = binary.is_some();
    let binary = match binary {
        Some(b) => b,
        None => default_server_binary()?,
    };
    if !binary.is_file() {
        let profile = if cfg!(debug_assertions) {
            ""
        } else {
            " --release"
        };
        let why = if explicit {
            format!("{} not found", binary.display())
        } else {
            format!(
                "{} not found; build it with `cargo build{profile} -p cangate-server` or pass --server-bin",
                binary.display()
            )
        };
        println!("memory: skipped: {why}");
        let details = json!({ "binary": binary.display().to_string() });
        return Ok(vec![
            Measure::new(
                "memory",
                LABEL,
                "MiB",
                Target::Below(TARGET_MIB),
                Outcome::Skipped(why.clone()),
                details.clone(),
            ),
            Measure::new(
                "memory",
                IDLE_LABEL,
                "%",
                Target::Below(IDLE_TARGET_PERCENT),
                Outcome::Skipped(why),
                details,
            ),
        ]);
    }
    measure(&binary, settle, idle).await
}

async fn measure(binary: &Path, settle: Duration, idle: Duration) -> Result<Vec<Measure>> {
    println!(
        "memory: {} --listen 127.0.0.1:<free port> (embedded demo), RSS {} ms after the first ListBuses answer",
        binary.display(),
        settle.as_millis()
    );
    let mut server = ServerChild::start(binary, &[], READY_TIMEOUT).await?;
    let pid = server.pid();
    let (ready, buses) = (server.ready_after, server.buses);
    tokio::time::sleep(settle).await;

    let status = std::fs::read_to_string(format!("/proc/{pid}/status"))
        .with_context(|| format!("reading /proc/{pid}/status"))?;
    let rss_kib = status_kib(&status, "VmRSS").context("no VmRSS in /proc/<pid>/status")?;
    let hwm_kib = status_kib(&status, "VmHWM");
    let threads = status_kib(&status, "Threads");

    // Idle CPU: every thread's CPU time at both ends of the window (a
    // thread that started or ended inside it counts from zero / not at
    // all; the demo's threads all start before it is ready).
    let before = process_thread_cpu(pid).context("reading the server's threads")?;
    let window_start = Instant::now();
    tokio::time::sleep(idle).await;
    let after = process_thread_cpu(pid).context("reading the server's threads")?;
    let window = window_start.elapsed().as_secs_f64();
    // Threads of one name together (the runtime's workers, the buses'
    // schedulers), the busiest first.
    let mut by_name = std::collections::BTreeMap::<String, f64>::new();
    for (tid, name, secs) in &after {
        let start = before
            .iter()
            .find(|(t, _, _)| t == tid)
            .map_or(0.0, |(_, _, s)| *s);
        *by_name.entry(name.clone()).or_default() += (secs - start) / window * 100.0;
    }
    let mut per_thread: Vec<(String, f64)> = by_name.into_iter().collect();
    per_thread.sort_by(|a, b| b.1.total_cmp(&a.1));
    let idle_percent: f64 = per_thread.iter().map(|(_, p)| p).sum();

    let exit = server.terminate()?;
    let graceful = exit.is_some_and(|s| s.success());

    let mib = rss_kib as f64 / 1024.0;
    println!(
        "  RSS {mib:.1} MiB (peak {} MiB, {} threads), {buses} buses, ready after {} ms, SIGTERM shutdown {}",
        hwm_kib.map_or("?".into(), |k| format!("{:.1}", k as f64 / 1024.0)),
        threads.map_or("?".into(), |t| t.to_string()),
        ready.as_millis(),
        if graceful { "clean" } else { "NOT clean" },
    );
    let busiest: Vec<String> = per_thread
        .iter()
        .filter(|(_, p)| *p >= 0.05)
        .map(|(n, p)| format!("{n} {p:.1} %"))
        .collect();
    println!(
        "  idle CPU over {window:.1} s: {idle_percent:.1} % of one core ({})",
        if busiest.is_empty() {
            "no thread above 0.05 %".to_string()
        } else {
            busiest.join(", ")
        }
    );
    let idle_measure = Measure::value(
        "memory",
        IDLE_LABEL,
        idle_percent,
        "%",
        Target::Below(IDLE_TARGET_PERCENT),
        json!({
            "window_s": window,
            "threads_percent": per_thread
                .iter()
                .map(|(n, p)| json!({ "thread": n, "percent": p }))
                .collect::<Vec<_>>(),
        }),
    );
    Ok(vec![
        Measure::value(
            "memory",
            LABEL,
            mib,
            "MiB",
            Target::Below(TARGET_MIB),
            json!({
                "binary": binary.display().to_string(),
                "rss_kib": rss_kib,
                "peak_rss_kib": hwm_kib,
                "threads": threads,
                "buses": buses,
                "ready_ms": ready.as_millis() as u64,
                "settle_ms": settle.as_millis() as u64,
                "graceful_shutdown": graceful,
            }),
        ),
        idle_measure,
    ])
}
