//! `wheel_bench`: handwheel feed events, bus to gRPC client.
//!
//! ```text
//! cargo run --release -p cangate-bench --bin wheel_bench            # full run
//! cargo run -p cangate-bench --bin wheel_bench -- --quick            # CI smoke
//! ```
//!
//! A simulated handwheel (run by the benchmark on its own runtime, so the
//! gateway only sees frames) streams feed TPDOs at a steady rate (7 000
//! frames/s by default, about what a busy 1 Mbit/s bus carries besides
//! other traffic) for the measurement time.
//!
//! 1. **One subscriber**: latency from the frame's bus timestamp
//!    (`FeedEvent.timestamp_us`) to the client holding the event, p50/p99;
//!    events lost anywhere (sent by the wheel − received by the gateway −
//!    delivered). Target: p99 < 1 ms, zero lost.
//! 2. **100 concurrent subscribers** (10 HTTP/2 connections × 10 streams;
//!    `--connections N` to share them otherwise):
//!    events delivered per second in total, p99 latency, lost.
//!
//! Scheduling: by default the gateway runs with `rt_priority = 10` (its bus
//! thread under `SCHED_FIFO`) and, for run 1, `grpc_rt_priority = 10` (its
//! gRPC runtime too); run 2 keeps the gRPC runtime at the default policy
//! (`--grpc-rt-fanout` to change that: saturated, it starves the client).
//! The benchmark's client and the simulated wheel keep the default policy
//! unless `--client-rt-priority` is given. Without root or `CAP_SYS_NICE`
//! the first line says FIFO is not available and everything runs at the
//! default policy.
//!
//! Human-readable results, then one JSON line. Exit 1 if it could not run;
//! with `--strict` also if a target is missed.

use anyhow::{Context, Result, anyhow, bail};
use cangate_bench::stats::{self, Percentiles};
use cangate_bench::{gateway, host, report};
use cangate_client::pb;
use cangate_sim::{DeviceHandle, SimHandwheel, SimHandwheelOptions, SimNodeOptions};
use clap::Parser;
use hdrhistogram::Histogram;
use serde_json::json;
use std::process::ExitCode;
use std::time::{Duration, Instant};
use tokio_util::sync::CancellationToken;

/// Handwheel feed latency and fan-out.
#[derive(Parser, Debug, Clone)]
#[command(about)]
struct Args {
    /// Tiny counts, for CI smoke runs.
    #[arg(long)]
    quick: bool,
    /// Exit 1 when a target is missed.
    #[arg(long)]
    strict: bool,
    /// Feed frames per second.
    #[arg(long, default_value_t = 7000)]
    rate: u32,
    /// Seconds of each measurement.
    #[arg(long, default_value_t = 10.0)]
    seconds: f64,
    /// Writes every event of the one-subscriber run to this file (one line
    /// each: receive time and bus timestamp in us since the epoch), to see
    /// when the slow ones happen.
    #[arg(long)]
    trace: Option<std::path::PathBuf>,
    /// Only the one-subscriber run.
    #[arg(long)]
    one_only: bool,
    /// The gateway's `rt_priority` (`SCHED_FIFO` for its bus thread; the
    /// simulated wheel and the client keep the default policy); 0: the
    /// default policy.
    #[arg(long, default_value_t = 10)]
    rt_priority: u8,
    /// The gateway's `grpc_rt_priority` (`SCHED_FIFO` for its gRPC runtime,
    /// which runs the handwheel task and the streams); 0: the default
    /// policy. Applies to the one-subscriber run only: the 100-subscriber
    /// run saturates the gRPC runtime, which under FIFO starves the
    /// benchmark's own client (see README).
    #[arg(long, default_value_t = 10)]
    grpc_rt_priority: u8,
    /// `SCHED_FIFO` for the 100-subscriber run's gRPC runtime too.
    #[arg(long)]
    grpc_rt_fanout: bool,
    /// `SCHED_FIFO` for the benchmark's client runtime too (0: default
    /// policy). The latency includes the client's own wake-up; on a loaded
    /// host that is the client's scheduling, not the gateway's.
    #[arg(long, default_value_t = 0)]
    client_rt_priority: u8,
    /// HTTP/2 connections the fan-out run's subscribers share (each event
    /// costs the gateway one socket write per connection).
    #[arg(long, default_value_t = 10)]
    connections: usize,
}

const NODE: u32 = 10;

struct Run {
    sent: u64,
    gateway_frames: u64,
    delivered: u64,
    lost_reported: u64,
    hist: Histogram<u64>,
    wall: f64,
    /// (receive us, bus timestamp us) per event, when traced.
    trace: Vec<(u64, u64)>,
}

/// Starts the gateway and the wheel, opens `subscribers` streams over
/// `connections` connections, turns the wheel for `seconds`.
/// `SCHED_FIFO` priorities of one run (0: the default policy).
#[derive(Debug, Clone, Copy)]
struct Sched {
    /// The gateway's bus thread.
    rt_priority: u8,
    /// The gateway's gRPC runtime.
    grpc_rt_priority: u8,
    /// The benchmark's client runtime.
    client_rt_priority: u8,
}

fn run(
    rate: u32,
    seconds: f64,
    connections: usize,
    subscribers: usize,
    trace: bool,
    sched: Sched,
) -> Result<Run> {
    let Sched {
        rt_priority,
        grpc_rt_priority,
        client_rt_priority,
    } = sched;
    let text = format!(
        "listen = \"127.0.0.1:0\"\nrt_priority = {rt_priority}\n[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\nqueue = 65536\n\
         [[canopen]]\nbus = \"can0\"\n[[canopen.node]]\nid = {NODE}\neds = \"builtin:handwheel\"\n\
         [[handwheel]]\nname = \"hw1\"\nbus = \"can0\"\nnode = {NODE}\n{}",
        gateway::NO_CLIENT_LIMITS
    );
    let config = gateway::config(&text)?;
    // As the server's own runtime (`main.rs`), with two workers.
    let gateway_rt = gateway::runtime_builder("gateway", gateway::gateway_workers())
        .on_thread_start(cangate_server::realtime::on_grpc_thread_start(
            grpc_rt_priority,
        ))
        .build()?;
    let server = gateway::start_on(&gateway_rt, &config)?;
    let sim_rt = gateway::runtime("sim", 1)?;
    let cancel = CancellationToken::new();
    let port = gateway::virtual_bus(&server, "can0")?.connect(false);
    let wheel = SimHandwheel::bundled(
        cangate_canopen::NodeId::new(NODE).map_err(|e| anyhow!("{e}"))?,
        SimHandwheelOptions {
            node: SimNodeOptions {
                heartbeat_ms: Some(100),
                ..SimNodeOptions::default()
            },
            frame_rate: rate,
            ..SimHandwheelOptions::default()
        },
    );
    let handle = DeviceHandle::new(wheel);
    {
        let _g = sim_rt.enter();
        cangate_sim::spawn_device(port, handle.clone(), cancel.clone());
    }
    let url = gateway::url(&server);
    let client_rt = gateway::runtime_builder("client", 1)
        .on_thread_start(move || {
            if client_rt_priority > 0 {
                let _ = cangate_server::realtime::set_fifo(client_rt_priority);
            }
        })
        .build()?;
    let result = client_rt.block_on(async move {
        let mut clients = Vec::new();
        for _ in 0..connections {
            clients.push(cangate_client::connect(&url).await?);
        }
        let mut wheels = clients[0].handwheels_client();
        // Wait for the wheel to be booted (NMT-started) and switch it on.
        let t0 = Instant::now();
        loop {
            let r = wheels
                .set_mode(pb::SetModeRequest {
                    handwheel: "hw1".into(),
                    mode: pb::HandwheelMode::Manual as i32,
                })
                .await;
            if r.is_ok() {
                break;
            }
            if t0.elapsed() > Duration::from_secs(10) {
                bail!("the wheel did not come up: {r:?}");
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        tokio::time::sleep(Duration::from_millis(300)).await;
        let frames_before = wheels
            .get_handwheel(pb::GetHandwheelRequest {
                handwheel: "hw1".into(),
            })
            .await?
            .into_inner()
            .stats
            .map_or(0, |s| s.frames);
        // Subscribers.
        let stop = CancellationToken::new();
        let mut tasks = Vec::new();
        for k in 0..subscribers {
            let mut w = clients[k % connections].handwheels_client();
            // Batches (each message what was ready): the cheap way for
            // many subscribers, one event per message when keeping up.
            let mut s = w
                .stream_feed_batches(pb::StreamFeedRequest {
                    handwheels: vec!["hw1".into()],
                    coalesce_ms: 0,
                })
                .await?
                .into_inner();
            let stop = stop.clone();
            tasks.push(tokio::spawn(async move {
                let mut h = stats::histogram();
                let (mut n, mut lost) = (0u64, 0u64);
                let mut tr = Vec::new();
                if trace {
                    tr.reserve(2 * (f64::from(rate) * seconds) as usize);
                }
                loop {
                    let m = tokio::select! {
                        _ = stop.cancelled() => break,
                        m = s.message() => m,
                    };
                    let Ok(Some(batch)) = m else { break };
                    let now_us = cangate_can::Timestamp::now().0 / 1000;
                    for ev in batch.events {
                        n += 1;
                        lost += ev.lost_before;
                        stats::record_ns(&mut h, now_us.saturating_sub(ev.timestamp_us) * 1000);
                        if trace {
                            tr.push((now_us, ev.timestamp_us));
                        }
                    }
                }
                (n, lost, h, tr)
            }));
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
        // Turn: enough units for the whole measurement at `rate`.
        let units = (f64::from(rate) * seconds).ceil() as i32;
        let sent_before = handle.with(|w| w.stats().frames);
        let t0 = Instant::now();
        handle.with(|w| w.turn(units));
        // Wait until the wheel has sent everything, then a little longer.
        loop {
            tokio::time::sleep(Duration::from_millis(50)).await;
            if handle.with(|w| w.pending_units()) == 0 {
                break;
            }
            if t0.elapsed() > Duration::from_secs_f64(seconds * 3.0 + 5.0) {
                bail!("the wheel did not finish sending");
            }
        }
        let wall = t0.elapsed().as_secs_f64();
        tokio::time::sleep(Duration::from_millis(300)).await;
        stop.cancel();
        let sent = handle.with(|w| w.stats().frames) - sent_before;
        let gateway_frames = wheels
            .get_handwheel(pb::GetHandwheelRequest {
                handwheel: "hw1".into(),
            })
            .await?
            .into_inner()
            .stats
            .map_or(0, |s| s.frames)
            - frames_before;
        let mut hist = stats::histogram();
        let (mut delivered, mut lost_reported) = (0, 0);
        let mut trace = Vec::new();
        for t in tasks {
            let (n, lost, h, tr) = t.await?;
            delivered += n;
            lost_reported += lost;
            hist.add(h)?;
            trace.extend(tr);
        }
        Ok::<_, anyhow::Error>(Run {
            sent,
            gateway_frames,
            delivered,
            lost_reported,
            hist,
            wall,
            trace,
        })
    });
    cancel.cancel();
    server.shutdown();
    drop(client_rt);
    drop(sim_rt);
    drop(gateway_rt);
    result
}

fn main() -> ExitCode {
    let args = Args::parse();
    host::exit_code("wheel_bench", args.strict, bench(&args))
}

fn bench(args: &Args) -> Result<bool> {
    let seconds = if args.quick { 0.5 } else { args.seconds };
    let fanout = if args.quick { 10 } else { 100 };
    let policy = |key: &str, p: u8| match p {
        0 => format!("{key} 0: default scheduling"),
        p => match cangate_server::realtime::available(p) {
            Ok(()) => format!("{key} {p}: SCHED_FIFO"),
            Err(e) => format!("{key} {p}: NOT available ({e}), default scheduling"),
        },
    };
    let rt = format!(
        "gateway {}, {}",
        policy("rt_priority", args.rt_priority),
        policy("grpc_rt_priority", args.grpc_rt_priority)
    );
    let rt = if args.client_rt_priority > 0 {
        format!("{rt}; client rt_priority {}", args.client_rt_priority)
    } else {
        rt
    };
    println!(
        "{}: {} feed frames/s for {seconds} s; {rt}",
        report::banner("wheel_bench", args.quick),
        args.rate
    );
    let one = run(
        args.rate,
        seconds,
        1,
        1,
        args.trace.is_some(),
        Sched {
            rt_priority: args.rt_priority,
            grpc_rt_priority: args.grpc_rt_priority,
            client_rt_priority: args.client_rt_priority,
        },
    )?;
    // Latencies in ms.
    let ms = |h: &Histogram<u64>| {
        let p = Percentiles::of(h);
        [p.p50_us, p.p90_us, p.p99_us, p.max_us].map(|us| us / 1000.0)
    };
    let [p50, p90, p99, max] = ms(&one.hist);
    let lost_one = one.sent - one.delivered;
    let ok_one = p99 < 1.0 && lost_one == 0 && one.gateway_frames == one.sent;
    println!(
        "1. one subscriber: {} frames sent, {} decoded by the gateway, {} delivered ({} lost); \
         bus -> client p50 {:.3} ms, p90 {:.3} ms, p99 {:.3} ms, max {:.3} ms (target p99 < 1 ms, 0 lost: {})",
        one.sent,
        one.gateway_frames,
        one.delivered,
        lost_one,
        p50,
        p90,
        p99,
        max,
        if ok_one { "met" } else { "MISSED" }
    );
    if let Some(path) = &args.trace {
        let mut text = String::from("# receive_us bus_us (since the UNIX epoch)\n");
        for (rx, bus) in &one.trace {
            text.push_str(&format!("{rx} {bus}\n"));
        }
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
    }
    let one_json = json!({"sent": one.sent, "gateway": one.gateway_frames, "delivered": one.delivered,
                          "p50_ms": p50, "p90_ms": p90,
                          "p99_ms": p99, "max_ms": max});
    let fanout_json = if args.one_only {
        serde_json::Value::Null
    } else {
        let many = run(
            args.rate,
            seconds,
            args.connections.clamp(1, fanout),
            fanout,
            false,
            Sched {
                rt_priority: args.rt_priority,
                grpc_rt_priority: if args.grpc_rt_fanout {
                    args.grpc_rt_priority
                } else {
                    0
                },
                client_rt_priority: args.client_rt_priority,
            },
        )?;
        let per_s = many.delivered as f64 / many.wall;
        let [p50, _, p99, _] = ms(&many.hist);
        let expected = many.sent * fanout as u64;
        println!(
            "2. {fanout} subscribers: {:.0} events/s delivered in total ({} of {} expected, {} reported lost); \
             p50 {:.3} ms, p99 {:.3} ms",
            per_s, many.delivered, expected, many.lost_reported, p50, p99
        );
        json!({"subscribers": fanout, "delivered": many.delivered, "expected": expected,
               "lost_reported": many.lost_reported, "per_s": per_s,
               "p50_ms": p50, "p99_ms": p99})
    };
    println!(
        "{}",
        json!({
            "bench": "wheel",
            "quick": args.quick,
            "rate": args.rate,
            "rt_priority": args.rt_priority,
            "grpc_rt_priority": args.grpc_rt_priority,
            "grpc_rt_fanout": args.grpc_rt_fanout,
            "client_rt_priority": args.client_rt_priority,
            "one": one_json,
            "fanout": fanout_json,
        })
    );
    Ok(ok_one)
}
