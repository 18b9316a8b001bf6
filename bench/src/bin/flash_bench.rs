//! `flash_bench`: throughput of a program download (CiA 302-3,
//! `Canopen.DownloadProgram`) of a 256 KiB image into a simulated node on
//! the virtual bus at 1 Mbit/s with bit timing, against the SDO block
//! transfer ceiling of that bus.
//!
//! ```text
//! cargo run --release -p cangate-bench --bin flash_bench
//! cargo run --release -p cangate-bench --bin flash_bench -- --kib 64 --runs 1   # quicker
//! ```
//!
//! The gateway runs in this process with two timed buses: `share50` with
//! the default `bulk_share_percent` (50: block download sub-blocks may use
//! half the bus time, so that the gateway's own traffic always finds the
//! bus) and `share100` with `bulk_share_percent = 100`. The image is
//! downloaded through gRPC by the typed client (`download_program_with`),
//! and the data step's bytes per second (`DownloadProgramOutcome`) is
//! compared with:
//!
//! - the **block ceiling**: one block of 127 segments × 7 bytes confirmed by
//!   one ack frame, i.e. 889 bytes per (127 segment frames + 1 ack frame)
//!   of bus time; each frame's bits counted exactly (identifier, control,
//!   data, CRC-15, stuff bits of its real content, tail and 3-bit
//!   intermission, as the virtual bus models them) and, for reference,
//!   with worst-case stuffing (135 bits per 8-byte frame);
//! - the **transfer ceiling**: the bus time of every frame of this very
//!   transfer (initiate, segments, acks, end), the best any SDO client can
//!   do on that bus with no turnaround time at all.
//!
//! A 4 MiB image is also downloaded on an untimed virtual bus (the request
//! is above the default 4 MiB max_message_bytes), to show it works and how
//! long the gateway itself takes.
//!
//! Prints a table and one JSON line with every figure. Measured on the
//! development machine (2 cores, release build, 3 runs each): ceiling
//! 59.0 KiB/s (segment frames 115 bits on average, ack 121 bits);
//! `share100` 58.1 KiB/s (98.5 % of it), `share50` 23.7 KiB/s (40 % of it,
//! 80 % of its half share); 4 MiB untimed: data 0.26 s, whole download
//! 4.4 s (of which 4.1 s the simulated flash time).

use anyhow::{Context, Result, bail};
use cangate_bench::sdo_wire::{firmware, frame, transfer_bus_ns};
use cangate_can::{BitTiming, Stuffing};
use cangate_client::{NodeId, ProgramOptions};
use clap::Parser;
use serde_json::json;
use std::time::Instant;

const NODE: u8 = 5;

#[derive(Parser, Debug)]
#[command(about = "Program download throughput against the SDO block ceiling")]
struct Args {
    /// Image size in KiB.
    #[arg(long, default_value_t = 256)]
    kib: usize,
    /// Downloads per bus (the best and the mean are reported).
    #[arg(long, default_value_t = 3)]
    runs: usize,
    /// Skip the 4 MiB download on the untimed bus.
    #[arg(long)]
    no_big: bool,
}

fn config() -> String {
    let mut t = String::from("listen = \"127.0.0.1:0\"\n");
    for (bus, share) in [("share50", None), ("share100", Some(100))] {
        t.push_str(&format!(
            "[[bus]]\nname = \"{bus}\"\nbackend = \"virtual\"\nbitrate = 1000000\nbit_timing = true\nqueue = 65536\n"
        ));
        if let Some(s) = share {
            t.push_str(&format!("bulk_share_percent = {s}\n"));
        }
    }
    t.push_str("[[bus]]\nname = \"fast\"\nbackend = \"virtual\"\nqueue = 65536\n");
    for bus in ["share50", "share100", "fast"] {
        t.push_str(&format!(
            "[[canopen]]\nbus = \"{bus}\"\nsdo_timeout_ms = 1000\n[[canopen.node]]\nid = {NODE}\neds = \"builtin:io\"\nsimulate = true\nheartbeat_timeout_ms = 3000\n"
        ));
    }
    t
}

/// Bytes per second of whole blocks: 889 bytes per 127 segments + 1 ack,
/// the segments' bits averaged over `data`'s real content.
fn block_ceiling(t: &BitTiming, data: &[u8]) -> (f64, f64, f64) {
    let req = 0x600 + u16::from(NODE);
    let chunks: Vec<&[u8]> = data.chunks(7).filter(|c| c.len() == 7).collect();
    let seg_ns: u64 = chunks
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let mut p = [0u8; 8];
            p[0] = (k % 127) as u8 + 1;
            p[1..].copy_from_slice(c);
            t.frame_duration_ns(&frame(req, &p))
        })
        .sum();
    let seg_ns = seg_ns as f64 / chunks.len() as f64;
    let ack_ns = t.frame_duration_ns(&frame(
        0x580 + u16::from(NODE),
        &[0xA2, 127, 127, 0, 0, 0, 0, 0],
    )) as f64;
    let block_ns = 127.0 * seg_ns + ack_ns;
    (889.0 / (block_ns / 1e9), seg_ns, ack_ns)
}

struct Run {
    data_bps: f64,
    data_s: f64,
    total_s: f64,
}

async fn download(c: &cangate_client::Client, bus: &str, image: &[u8]) -> Result<Run> {
    let t0 = Instant::now();
    let o = c
        .canopen(bus)
        .download_program_with(
            NodeId::new(u32::from(NODE))?,
            image.to_vec(),
            &ProgramOptions::default(),
            |_| {},
        )
        .await
        .with_context(|| format!("download on {bus}"))?;
    let total_s = t0.elapsed().as_secs_f64();
    Ok(Run {
        data_bps: o.data_bytes_per_second,
        data_s: o.data_duration_ms as f64 / 1000.0,
        total_s,
    })
}

#[tokio::main]
async fn main() -> Result<()> {
    let args = Args::parse();
    if args.runs == 0 || args.kib == 0 {
        bail!("--runs and --kib must be at least 1");
    }
    let cfg = cangate_server::Config::from_toml(&config())?;
    let server = cangate_server::start(&cfg).await?;
    let client = cangate_client::connect(&format!("http://{}", server.addr)).await?;
    let image = firmware(args.kib * 1024);
    let exact = BitTiming::new(1_000_000);
    let worst = BitTiming {
        stuffing: Stuffing::WorstCase,
        ..exact
    };
    let (block_exact, seg_ns, ack_ns) = block_ceiling(&exact, &image);
    let (block_worst, _, _) = block_ceiling(&worst, &image);
    let transfer =
        image.len() as f64 / (transfer_bus_ns(&exact, NODE, &image, true, false) as f64 / 1e9);
    let kib = |bps: f64| bps / 1024.0;

    println!(
        "program download of {} KiB into a simulated node at 1 Mbit/s (virtual bus, bit timing)",
        args.kib
    );
    println!(
        "block ceiling, exact stuffing: 127 x {seg_ns:.0} ns segments + {ack_ns:.0} ns ack per 889 bytes = {:.1} KiB/s",
        kib(block_exact)
    );
    println!(
        "block ceiling, worst-case stuffing (135-bit frames): {:.1} KiB/s; whole-transfer ceiling (every frame of this transfer): {:.1} KiB/s",
        kib(block_worst),
        kib(transfer)
    );
    println!(
        "\n{:<10} {:>6} {:>11} {:>11} {:>10} {:>14} {:>10}",
        "bus", "run", "data s", "data KiB/s", "ratio", "ratio x share", "total s"
    );
    let mut results = serde_json::Map::new();
    for (bus, share) in [("share50", 0.5), ("share100", 1.0)] {
        let mut runs = Vec::new();
        for k in 0..args.runs {
            let r = download(&client, bus, &image).await?;
            println!(
                "{bus:<10} {:>6} {:>11.3} {:>11.1} {:>9.1}% {:>13.1}% {:>10.3}",
                k + 1,
                r.data_s,
                kib(r.data_bps),
                r.data_bps / block_exact * 100.0,
                r.data_bps / (block_exact * share) * 100.0,
                r.total_s
            );
            runs.push(r);
        }
        let best = runs.iter().map(|r| r.data_bps).fold(0.0, f64::max);
        let mean = runs.iter().map(|r| r.data_bps).sum::<f64>() / runs.len() as f64;
        let mean_total = runs.iter().map(|r| r.total_s).sum::<f64>() / runs.len() as f64;
        results.insert(
            bus.into(),
            json!({
                "bulk_share_percent": share * 100.0,
                "best_data_KiB_per_s": kib(best),
                "mean_data_KiB_per_s": kib(mean),
                "best_ratio_to_block_ceiling_pct": best / block_exact * 100.0,
                "mean_ratio_to_block_ceiling_pct": mean / block_exact * 100.0,
                "best_ratio_to_share_of_ceiling_pct": best / (block_exact * share) * 100.0,
                "mean_total_s": mean_total,
            }),
        );
    }
    if !args.no_big {
        let big = firmware(4 * 1024 * 1024);
        let r = download(&client, "fast", &big).await?;
        println!(
            "\n4 MiB image on an untimed virtual bus: data {:.2} s ({:.0} KiB/s), whole download {:.2} s",
            r.data_s,
            kib(r.data_bps),
            r.total_s
        );
        results.insert(
            "big_4MiB_untimed".into(),
            json!({"data_s": r.data_s, "data_KiB_per_s": kib(r.data_bps), "total_s": r.total_s}),
        );
    }
    results.insert("image_KiB".into(), json!(args.kib));
    results.insert(
        "block_ceiling_exact_KiB_per_s".into(),
        json!(kib(block_exact)),
    );
    results.insert(
        "block_ceiling_worst_case_KiB_per_s".into(),
        json!(kib(block_worst)),
    );
    results.insert("transfer_ceiling_KiB_per_s".into(), json!(kib(transfer)));
    results.insert("segment_ns".into(), json!(seg_ns));
    results.insert("ack_ns".into(), json!(ack_ns));
    println!("{}", serde_json::Value::Object(results));
    server.shutdown();
    Ok(())
}
