//! `cangate-bench`: performance figures of the gateway.
//!
//! - `virtual-bus`: lossless frames/s between two ports of a virtual bus;
//! - `stream`: frames/s a gRPC StreamFrames client receives;
//! - `latency`: SendFrames → StreamFrames latency percentiles;
//! - `memory`: resident memory and idle CPU of the server binary running
//!   the demo;
//! - `all`: everything, with a summary table.
//!
//! Human-readable results go to stdout, followed by one JSON line with every
//! figure. `--quick` uses tiny counts for CI smoke runs. The exit status is 1
//! if a benchmark could not run, and with `--strict` also if a target is
//! missed.

mod latency;
mod memory;
mod stream;
mod vbus;

use anyhow::Result;
use cangate_bench::report::{self, Measure, Outcome, Target, Verdict};
use clap::{Parser, Subcommand};
use serde_json::json;
use std::future::Future;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

/// Benchmarks of the cangate gateway: virtual bus and gRPC stream
/// throughput, send→receive latency, server memory.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Cli {
    /// Tiny counts (a few seconds even in debug builds), for CI smoke runs.
    #[arg(long, global = true)]
    quick: bool,
    /// Exit with status 1 when a target is missed (not only on errors).
    #[arg(long, global = true)]
    strict: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Frames/s from one port to another on a virtual bus (no bit timing).
    VirtualBus {
        /// Frames to send [default: 5,000,000; --quick: 50,000].
        #[arg(long)]
        frames: Option<u64>,
    },
    /// Frames/s delivered to one gRPC StreamFrames client.
    Stream {
        /// Frames to send [default: 2,000,000; --quick: 20,000].
        #[arg(long)]
        frames: Option<u64>,
        /// Most frames outstanding between the device and the client
        /// [default: half the port queue].
        #[arg(long)]
        window: Option<u64>,
    },
    /// SendFrames → StreamFrames latency through the server.
    Latency {
        /// Recorded samples [default: 10,000; --quick: 200].
        #[arg(long)]
        samples: Option<u64>,
        /// Unrecorded warm-up round trips [default: 500; --quick: 20].
        #[arg(long)]
        warmup: Option<u64>,
    },
    /// Resident memory and idle CPU of the server binary running the
    /// embedded demo.
    Memory {
        /// Server binary [default: cangate-server next to this executable].
        #[arg(long)]
        server_bin: Option<PathBuf>,
    },
    /// Everything, with a summary table.
    All {
        /// Server binary for the memory benchmark.
        #[arg(long)]
        server_bin: Option<PathBuf>,
    },
    /// `all` and every benchmark binary (sdo_bench, unary_bench,
    /// axis_bench --scale, wheel_bench, cansmc_bench; built beside this
    /// one), then one table of their headline figures with targets, ratios
    /// and pass/fail.
    Report {
        /// Server binary for the memory benchmark.
        #[arg(long)]
        server_bin: Option<PathBuf>,
    },
}

/// `cangate-bench report`: see [`cangate_bench::suite`].
async fn report_all(quick: bool, strict: bool, server_bin: Option<PathBuf>) -> ExitCode {
    use cangate_bench::suite;
    let mut measures = virtual_bus(quick, None).await;
    measures.extend(stream_bench(quick, None, None).await);
    measures.extend(latency_bench(quick, None, None).await);
    measures.extend(memory_bench(quick, server_bin).await);
    let mut rows = suite::measure_rows(&measures);
    let q: &[&str] = if quick { &["--quick"] } else { &[] };
    // The binaries block this thread while they run: nothing else runs
    // here meanwhile, and their CPU figures want the machine to themselves.
    let with = |extra: &[&'static str]| [q, extra].concat();
    rows.extend(tokio::task::block_in_place(|| {
        let mut r = suite::bin_rows("sdo_bench", q, suite::sdo_rows);
        r.extend(suite::bin_rows("unary_bench", q, suite::unary_rows));
        r.extend(suite::bin_rows(
            "axis_bench",
            &with(&["--scale"]),
            suite::axis_rows,
        ));
        r.extend(suite::bin_rows("wheel_bench", q, suite::wheel_rows));
        r.extend(suite::bin_rows("cansmc_bench", q, suite::cansmc_rows));
        r
    }));
    println!(
        "\n## cangate-bench report ({} build{})",
        report::build_profile(),
        if quick {
            ", --quick: smoke counts, not figures"
        } else {
            ""
        }
    );
    suite::print_rows(&rows);
    let failures = rows.iter().filter(|r| r.is_failure()).count();
    println!(
        "{}",
        json!({
            "cangate_bench": "report",
            "quick": quick,
            "failures": failures,
            "rows": rows.iter().map(|r| json!({"measure": r.measure, "result": r.result,
                "target": r.target, "ratio": r.ratio, "verdict": r.verdict})).collect::<Vec<_>>(),
        })
    );
    let errors = rows.iter().filter(|r| r.verdict == "ERROR").count();
    if errors > 0 || (strict && failures > 0) {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}

/// Runs one benchmark; an error becomes an error measure so that `all`
/// carries on with the others.
async fn guarded<F>(
    bench: &'static str,
    label: &'static str,
    unit: &'static str,
    target: Target,
    f: F,
) -> Vec<Measure>
where
    F: Future<Output = Result<Vec<Measure>>>,
{
    match f.await {
        Ok(m) => m,
        Err(e) => {
            let msg = format!("{e:#}");
            eprintln!("{bench}: error: {msg}");
            vec![Measure::new(
                bench,
                label,
                unit,
                target,
                Outcome::Error(msg),
                serde_json::Value::Null,
            )]
        }
    }
}

fn pick(value: Option<u64>, quick: bool, quick_default: u64, default: u64) -> u64 {
    value.unwrap_or(if quick { quick_default } else { default })
}

async fn virtual_bus(quick: bool, frames: Option<u64>) -> Vec<Measure> {
    let frames = pick(frames, quick, vbus::QUICK_FRAMES, vbus::FRAMES);
    guarded(
        "virtual-bus",
        "virtual bus throughput (lossless)",
        "frames/s",
        Target::AtLeast(vbus::TARGET),
        vbus::run(frames),
    )
    .await
}

async fn stream_bench(quick: bool, frames: Option<u64>, window: Option<u64>) -> Vec<Measure> {
    let frames = pick(frames, quick, stream::QUICK_FRAMES, stream::FRAMES);
    guarded(
        "stream",
        "gRPC StreamFrames to 1 client",
        "frames/s",
        Target::AtLeast(stream::TARGET),
        stream::run(frames, window),
    )
    .await
}

async fn latency_bench(quick: bool, samples: Option<u64>, warmup: Option<u64>) -> Vec<Measure> {
    let samples = pick(samples, quick, latency::QUICK_SAMPLES, latency::SAMPLES);
    let warmup = pick(warmup, quick, latency::QUICK_WARMUP, latency::WARMUP);
    guarded(
        "latency",
        "send->receive latency p99",
        "µs",
        Target::Below(latency::TARGET_P99_US),
        latency::run(samples, warmup),
    )
    .await
}

async fn memory_bench(quick: bool, server_bin: Option<PathBuf>) -> Vec<Measure> {
    let settle = if quick {
        memory::QUICK_SETTLE
    } else {
        memory::SETTLE
    };
    guarded(
        "memory",
        "server RSS (embedded demo)",
        "MiB",
        Target::Below(memory::TARGET_MIB),
        memory::run(
            server_bin,
            settle,
            if quick {
                memory::QUICK_IDLE_WINDOW
            } else {
                memory::IDLE_WINDOW
            },
        ),
    )
    .await
}

#[tokio::main]
async fn main() -> ExitCode {
    let cli = Cli::parse();
    let quick = cli.quick;
    let started = Instant::now();
    let command = match &cli.command {
        Command::VirtualBus { .. } => "virtual-bus",
        Command::Stream { .. } => "stream",
        Command::Latency { .. } => "latency",
        Command::Memory { .. } => "memory",
        Command::All { .. } => "all",
        Command::Report { .. } => "report",
    };
    let profile = report::build_profile();
    println!(
        "cangate-bench {command} ({profile} build{}, {} CPUs)",
        if quick { ", --quick" } else { "" },
        std::thread::available_parallelism().map_or(0, |n| n.get())
    );
    if profile == "debug" && !quick {
        println!("note: a debug build; use --release for meaningful figures");
    }
    println!();

    let measures = match cli.command {
        Command::VirtualBus { frames } => virtual_bus(quick, frames).await,
        Command::Stream { frames, window } => stream_bench(quick, frames, window).await,
        Command::Latency { samples, warmup } => latency_bench(quick, samples, warmup).await,
        Command::Memory { server_bin } => memory_bench(quick, server_bin).await,
        Command::All { server_bin } => {
            let mut all = virtual_bus(quick, None).await;
            println!();
            all.extend(stream_bench(quick, None, None).await);
            println!();
            all.extend(latency_bench(quick, None, None).await);
            println!();
            all.extend(memory_bench(quick, server_bin).await);
            all
        }
        Command::Report { server_bin } => return report_all(quick, cli.strict, server_bin).await,
    };

    report::print_table(&measures);
    let errors = measures
        .iter()
        .filter(|m| m.verdict() == Verdict::Error)
        .count();
    let missed = measures
        .iter()
        .filter(|m| m.verdict() == Verdict::Fail)
        .count();
    let skipped = measures
        .iter()
        .filter(|m| m.verdict() == Verdict::Skip)
        .count();
    let summary = json!({
        "cangate_bench": command,
        "profile": profile,
        "quick": quick,
        "cpus": std::thread::available_parallelism().map_or(0, |n| n.get()),
        "seconds": started.elapsed().as_secs_f64(),
        "all_pass": errors == 0 && missed == 0,
        "errors": errors,
        "missed": missed,
        "skipped": skipped,
        "results": measures.iter().map(Measure::to_json).collect::<Vec<_>>(),
    });
    println!("{summary}");
    if errors > 0 || (cli.strict && missed > 0) {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}
