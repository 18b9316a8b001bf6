//! `sdo_session_bench`: expedited SDO reads through `Canopen.SdoSession`
//! against unary `ReadSdo`, in the same run.
//!
//! ```text
//! cargo run --release -p cangate-bench --bin sdo_session_bench            # full run
//! cargo run -p cangate-bench --bin sdo_session_bench -- --quick            # CI smoke
//! ```
//!
//! The gateway (embedded, its gRPC runtime as the server binary's) with two
//! simulated drives on a virtual bus without bit timing, and one client on
//! a runtime of its own thread over loopback TCP, reading 0x1017:
//!
//! 1. unary ReadSdo back to back (one outstanding);
//! 2. the session with one request outstanding (the stream's cost per read
//!    against a call's);
//! 3. the session pipelined: `--depth` requests outstanding, split over
//!    the two drives (reads/s; the latency then includes the queue).
//!
//! Human-readable results, then one JSON line.

use anyhow::Result;
use cangate_bench::{gateway, host, report, stats};
use cangate_client::{DataType, NodeId, ObjectAddress};
use clap::Parser;
use serde_json::json;
use std::collections::VecDeque;
use std::process::ExitCode;
use std::time::Instant;

/// Session against unary SDO reads.
#[derive(Parser, Debug)]
#[command(about)]
struct Args {
    /// Tiny counts, for CI smoke runs.
    #[arg(long)]
    quick: bool,
    /// Timed reads per mode.
    #[arg(long, default_value_t = 5_000)]
    reads: u64,
    /// Requests outstanding in the pipelined mode.
    #[arg(long, default_value_t = 32)]
    depth: usize,
}

fn main() -> ExitCode {
    let args = Args::parse();
    host::exit_code("sdo_session_bench", false, bench(&args))
}

const OBJECT: ObjectAddress = ObjectAddress::new(0x1017, 0);

fn bench(args: &Args) -> Result<bool> {
    let (reads, warmup) = if args.quick {
        (200, 50)
    } else {
        (args.reads, 500)
    };
    let text = format!(
        "listen = \"127.0.0.1:0\"\n[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\n\
         [[canopen]]\nbus = \"can0\"\n\
         [[canopen.node]]\nid = 1\neds = \"builtin:drive\"\nsimulate = true\n\
         [[canopen.node]]\nid = 2\neds = \"builtin:drive\"\nsimulate = true\n{}",
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
        "{}: {reads} reads of 0x1017 per mode, pipelined depth {}, gateway runtime with {workers} workers",
        report::banner("sdo_session_bench", args.quick),
        args.depth
    );
    let n1 = NodeId::new(1)?;
    let n2 = NodeId::new(2)?;
    let results = client_rt.block_on(async {
        let c = cangate_client::connect(&url).await?;
        let co = c.canopen("can0");
        let mut out = Vec::new();

        // 1. Unary.
        for _ in 0..warmup {
            co.read(n1, OBJECT, DataType::Unsigned16).await?;
        }
        let mut hist = stats::histogram();
        let t0 = Instant::now();
        for _ in 0..reads {
            let t = Instant::now();
            co.read(n1, OBJECT, DataType::Unsigned16).await?;
            stats::record(&mut hist, t.elapsed());
        }
        out.push(("unary ReadSdo", hist, t0.elapsed().as_secs_f64()));

        // 2. Session, one outstanding.
        let s = co.sdo_session().await?;
        for _ in 0..warmup {
            s.read(n1, OBJECT, DataType::Unsigned16).await?;
        }
        let mut hist = stats::histogram();
        let t0 = Instant::now();
        for _ in 0..reads {
            let t = Instant::now();
            s.read(n1, OBJECT, DataType::Unsigned16).await?;
            stats::record(&mut hist, t.elapsed());
        }
        out.push((
            "SdoSession, 1 outstanding",
            hist,
            t0.elapsed().as_secs_f64(),
        ));

        // 3. Session, pipelined over the two drives.
        let mut hist = stats::histogram();
        let mut window = VecDeque::new();
        let t0 = Instant::now();
        for i in 0..reads {
            if window.len() >= args.depth {
                let (t, f): (Instant, _) = window.pop_front().expect("not empty");
                let _: cangate_client::SdoValue = futures_await(f).await?;
                stats::record(&mut hist, t.elapsed());
            }
            let node = if i % 2 == 0 { n1 } else { n2 };
            window.push_back((Instant::now(), s.read(node, OBJECT, DataType::Unsigned16)));
        }
        while let Some((t, f)) = window.pop_front() {
            futures_await(f).await?;
            stats::record(&mut hist, t.elapsed());
        }
        out.push((
            "SdoSession, pipelined (2 nodes)",
            hist,
            t0.elapsed().as_secs_f64(),
        ));
        s.close().await;
        anyhow::Ok(out)
    })?;
    server.shutdown();
    drop(client_rt);
    drop(gateway_rt);
    let mut figures = Vec::new();
    for (mode, hist, wall) in &results {
        let us = |q: f64| hist.value_at_quantile(q) as f64 / 1000.0;
        let rate = reads as f64 / wall;
        println!(
            "{mode:<34} p50 {:>8.1} µs  p99 {:>8.1} µs  {rate:>8.0} reads/s",
            us(0.5),
            us(0.99)
        );
        figures.push(
            json!({"mode": mode, "p50_us": us(0.5), "p99_us": us(0.99), "reads_per_s": rate}),
        );
    }
    println!(
        "{}",
        json!({"bench": "sdo_session_bench", "profile": report::build_profile(), "reads": reads,
               "depth": args.depth, "modes": figures})
    );
    Ok(true)
}

/// Awaits a boxed read future (keeps the loop above readable).
async fn futures_await(
    f: futures::future::BoxFuture<'static, Result<cangate_client::SdoValue, cangate_client::Error>>,
) -> Result<cangate_client::SdoValue> {
    Ok(f.await?)
}
