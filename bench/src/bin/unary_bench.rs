//! `unary_bench`: what one gRPC call that touches no bus costs the gateway.
//!
//! ```text
//! cargo run --release -p cangate-bench --bin unary_bench            # full run
//! cargo run -p cangate-bench --bin unary_bench -- --quick            # CI smoke
//! ```
//!
//! The gateway (embedded, its gRPC runtime with one worker per CPU as the
//! server binary) and one client on a runtime of its own thread, over
//! loopback TCP. The client calls `Bus.GetBus` (answered from the bus's
//! counters) back to back; the figures are the round trip's p50/p99 and
//! the CPU time of the gateway's gRPC threads per call, which is the
//! server's whole cost of a call without the bus (`peer_bench` compares
//! it with canopend's in the VM).
//!
//! Human-readable results, then one JSON line.

use anyhow::Result;
use cangate_bench::{gateway, host, report, stats};
use clap::Parser;
use serde_json::json;
use std::process::ExitCode;
use std::time::Instant;

/// Server CPU and latency of a unary call without the bus.
#[derive(Parser, Debug)]
#[command(about)]
struct Args {
    /// Tiny counts, for CI smoke runs.
    #[arg(long)]
    quick: bool,
    /// Timed calls.
    #[arg(long, default_value_t = 20_000)]
    calls: u64,
}

fn main() -> ExitCode {
    let args = Args::parse();
    host::exit_code("unary_bench", false, bench(&args))
}

fn bench(args: &Args) -> Result<bool> {
    let (calls, warmup) = if args.quick {
        (200, 50)
    } else {
        (args.calls, 2_000)
    };
    let text = format!(
        "listen = \"127.0.0.1:0\"\n[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\n{}",
        gateway::NO_CLIENT_LIMITS
    );
    let config = gateway::config(&text)?;
    let workers = gateway::gateway_workers();
    let gateway_rt = gateway::runtime("gateway", workers)?;
    let server = gateway::start_on(&gateway_rt, &config)?;
    let url = gateway::url(&server);
    let client_rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .thread_name("bench-client")
        .build()?;
    println!(
        "{}: {calls} GetBus calls, gateway runtime with {workers} workers",
        report::banner("unary_bench", args.quick)
    );
    let (hist, cpu, wall) = client_rt.block_on(async {
        let mut c = cangate_client::connect(&url).await?;
        for _ in 0..warmup {
            c.get_bus("can0").await?;
        }
        let mut hist = stats::histogram();
        let before = host::thread_cpu()?;
        let t0 = Instant::now();
        for _ in 0..calls {
            let t = Instant::now();
            c.get_bus("can0").await?;
            stats::record_ns(&mut hist, t.elapsed().as_nanos() as u64);
        }
        let wall = t0.elapsed().as_secs_f64();
        let after = host::thread_cpu()?;
        // Only the gRPC runtime's workers ("gateway"), not the bus thread.
        let grpc = |threads: &[(String, f64)]| -> f64 {
            threads
                .iter()
                .filter(|(name, _)| name == "gateway")
                .map(|(_, s)| s)
                .sum()
        };
        let cpu = grpc(&after) - grpc(&before);
        anyhow::Ok((hist, cpu, wall))
    })?;
    server.shutdown();
    drop(client_rt);
    drop(gateway_rt);
    let us = |q: f64| hist.value_at_quantile(q) as f64 / 1000.0;
    let cpu_us = cpu / calls as f64 * 1e6;
    println!(
        "GetBus round trip p50 {:.1} µs, p99 {:.1} µs; {:.0} calls/s; gateway gRPC CPU {cpu_us:.1} µs per call",
        us(0.5),
        us(0.99),
        calls as f64 / wall
    );
    println!(
        "{}",
        json!({"bench": "unary_bench", "calls": calls, "p50_us": us(0.5), "p99_us": us(0.99),
               "server_cpu_us_per_call": cpu_us})
    );
    Ok(true)
}
