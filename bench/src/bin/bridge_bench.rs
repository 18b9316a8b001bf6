//! `bridge_bench`: the plant bridge to MQTT (mosquitto) and to NATS
//! JetStream (nats-server), each against the direct gRPC stream in the
//! same run.
//!
//! ```text
//! cargo run --release -p cangate-bench --bin bridge_bench            # full run
//! cargo run -p cangate-bench --bin bridge_bench -- --quick            # smoke
//! ```
//!
//! The gateway (embedded, on its own runtime of threads named `gateway`)
//! with one virtual bus and a simulated CANopen node 5, a bridge of node
//! events in protobuf to a broker the benchmark starts on a free loopback
//! port. A port on the virtual bus plays node 5 sending EMCY frames, each
//! numbered in its manufacturer bytes; the benchmark's client (its own
//! thread) reads them as `NodeEvent`s from the gRPC stream and from the
//! broker (MQTT QoS 1 subscription; NATS core subscription to the subject
//! JetStream stores):
//!
//! 1. latency: `--latency-events` EMCYs at `--rate` a second; bus →
//!    gateway → broker → subscriber, next to bus → gateway → gRPC stream,
//!    p50/p99 (send to receive, one clock);
//! 2. throughput: `--events` EMCYs with at most `--window` not yet seen
//!    by the broker's subscriber (the gRPC stream closed): events/s
//!    delivered, gap records seen (must be 0), and the gateway's CPU time
//!    (its runtime's threads: the bus, the CANopen master, the bridge and
//!    its broker client) per 1,000 events.
//!
//! A broker that is not installed is skipped, saying so. Human-readable
//! results, then one JSON line.

use anyhow::{Context, Result, bail};
use cangate_bench::{gateway, host, report, stats};
use cangate_can::{CanId, Frame};
use cangate_client::pb;
use clap::Parser;
use futures::StreamExt;
use prost::Message;
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};
use tokio::sync::{Notify, mpsc};

/// The bridge to MQTT and NATS against the gRPC stream.
#[derive(Parser, Debug)]
#[command(about)]
struct Args {
    /// Tiny counts, for smoke runs.
    #[arg(long)]
    quick: bool,
    /// Events of the latency phase.
    #[arg(long, default_value_t = 2_000)]
    latency_events: u64,
    /// Events a second in the latency phase.
    #[arg(long, default_value_t = 500)]
    rate: u64,
    /// Events of the throughput phase.
    #[arg(long, default_value_t = 20_000)]
    events: u64,
    /// Events sent and not yet seen by the broker's subscriber, at most.
    #[arg(long, default_value_t = 256)]
    window: u64,
    /// Only this broker: mqtt or nats (default: both).
    #[arg(long)]
    only: Option<String>,
}

/// Gives up when nothing arrives for this long.
const STALL: Duration = Duration::from_secs(20);

fn main() -> ExitCode {
    let args = Args::parse();
    host::exit_code("bridge_bench", false, bench(&args))
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Kind {
    Mqtt,
    Nats,
}

impl Kind {
    fn name(self) -> &'static str {
        match self {
            Kind::Mqtt => "MQTT (mosquitto)",
            Kind::Nats => "NATS JetStream (nats-server)",
        }
    }
    fn binary(self) -> &'static str {
        match self {
            Kind::Mqtt => "mosquitto",
            Kind::Nats => "nats-server",
        }
    }
}

/// A broker process of this run, stopped (by PID) on drop.
struct Broker {
    kind: Kind,
    port: u16,
    dir: PathBuf,
    child: Child,
}

fn find(binary: &str) -> Option<PathBuf> {
    std::env::var("PATH")
        .unwrap_or_default()
        .split(':')
        .chain(["/usr/sbin", "/usr/local/sbin"])
        .map(|d| Path::new(d).join(binary))
        .find(|p| p.is_file())
}

impl Broker {
    fn start(kind: Kind) -> Result<Option<Broker>> {
        let Some(binary) = find(kind.binary()) else {
            return Ok(None);
        };
        let port = std::net::TcpListener::bind("127.0.0.1:0")?
            .local_addr()?
            .port();
        let dir = std::env::temp_dir().join(format!(
            "cangate-bridge-bench-{}-{}",
            kind.binary(),
            std::process::id()
        ));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir)?;
        let mut cmd = Command::new(binary);
        match kind {
            Kind::Mqtt => {
                std::fs::write(
                    dir.join("mosquitto.conf"),
                    format!(
                        "listener {port} 127.0.0.1\nallow_anonymous true\nmax_queued_messages 1000000\n"
                    ),
                )?;
                cmd.arg("-c").arg(dir.join("mosquitto.conf"));
            }
            Kind::Nats => {
                cmd.args(["-a", "127.0.0.1", "-p", &port.to_string(), "-js", "-sd"])
                    .arg(dir.join("js"));
            }
        }
        let child = cmd
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .with_context(|| format!("starting {}", kind.binary()))?;
        let broker = Broker {
            kind,
            port,
            dir,
            child,
        };
        let deadline = Instant::now() + STALL;
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            if Instant::now() > deadline {
                bail!("{} does not listen", kind.binary());
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        Ok(Some(broker))
    }

    fn url(&self) -> String {
        match self.kind {
            Kind::Mqtt => format!("mqtt://127.0.0.1:{}", self.port),
            Kind::Nats => format!("nats://127.0.0.1:{}", self.port),
        }
    }
}

impl Drop for Broker {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// Send times (ns since `base`, 0: not sent) and what each reader saw.
struct Ledger {
    base: Instant,
    sent: Vec<AtomicU64>,
    /// Events seen by the broker's subscriber.
    broker_seen: AtomicU64,
    /// Gap records the broker's subscriber saw.
    gaps: AtomicU64,
    notify: Notify,
}

impl Ledger {
    fn sent_at(&self, i: u64) -> Option<Duration> {
        let ns = self.sent.get(i as usize)?.load(Ordering::Acquire);
        (ns > 0).then(|| Duration::from_nanos(ns))
    }

    /// The latency of event `i`, received now.
    fn latency(&self, i: u64) -> Option<Duration> {
        Some(self.base.elapsed().saturating_sub(self.sent_at(i)?))
    }
}

/// The EMCY number `i` of node 5 (its manufacturer bytes carry `i`).
fn emcy(i: u64) -> Result<Frame> {
    let n = (i as u32).to_le_bytes();
    let data = [0x00, 0x10, 0x01, n[0], n[1], n[2], n[3], 0];
    Ok(Frame::new(CanId::standard(0x085)?, &data)?)
}

/// The number an EMCY node event carries.
fn number(ev: &pb::NodeEvent) -> Option<u64> {
    match &ev.event {
        Some(pb::node_event::Event::Emcy(e)) if e.manufacturer.len() >= 4 => Some(u64::from(
            u32::from_le_bytes(e.manufacturer[..4].try_into().ok()?),
        )),
        _ => None,
    }
}

/// An envelope from the broker: its node event's number into the
/// latency histogram (in the latency phase) and the count.
fn on_envelope(
    env: &pb::BridgeEnvelope,
    ledger: &Ledger,
    hist: &std::sync::Mutex<hdrhistogram::Histogram<u64>>,
    latency_events: u64,
) {
    match &env.payload {
        Some(pb::bridge_envelope::Payload::NodeEvent(ev)) => {
            if let Some(i) = number(ev) {
                if i < latency_events
                    && let Some(d) = ledger.latency(i)
                {
                    stats::record(&mut hist.lock().unwrap(), d);
                }
                ledger.broker_seen.fetch_add(1, Ordering::AcqRel);
                ledger.notify.notify_waiters();
            }
        }
        Some(pb::bridge_envelope::Payload::Gap(g)) => {
            ledger.gaps.fetch_add(g.count, Ordering::AcqRel);
            ledger.notify.notify_waiters();
        }
        _ => {}
    }
}

/// Subscribes to the gateway's node events on the broker; returns once
/// the subscription is in place.
async fn subscribe(
    broker: &Broker,
    ledger: Arc<Ledger>,
    hist: Arc<std::sync::Mutex<hdrhistogram::Histogram<u64>>>,
    latency_events: u64,
) -> Result<tokio::task::JoinHandle<()>> {
    match broker.kind {
        Kind::Mqtt => {
            use rumqttc::{AsyncClient, Event, Incoming, MqttOptions, QoS};
            let mut options = MqttOptions::new("bridge-bench", "127.0.0.1", broker.port);
            options
                .set_keep_alive(Duration::from_secs(5))
                .set_max_packet_size(1 << 20, 1 << 20)
                .set_inflight(1000);
            let (client, mut events) = AsyncClient::new(options, 1000);
            client
                .subscribe("cangate/v1/pb/bench/bus/+/#", QoS::AtLeastOnce)
                .await?;
            let (ready_tx, ready_rx) = tokio::sync::oneshot::channel();
            let task = tokio::spawn(async move {
                let mut ready = Some(ready_tx);
                let _client = client;
                while let Ok(event) = events.poll().await {
                    match event {
                        Event::Incoming(Incoming::SubAck(_)) => {
                            if let Some(r) = ready.take() {
                                let _ = r.send(());
                            }
                        }
                        Event::Incoming(Incoming::Publish(p)) => {
                            if let Ok(env) = pb::BridgeEnvelope::decode(p.payload.as_ref()) {
                                on_envelope(&env, &ledger, &hist, latency_events);
                            }
                        }
                        _ => {}
                    }
                }
            });
            tokio::time::timeout(STALL, ready_rx)
                .await
                .context("no SUBACK")??;
            Ok(task)
        }
        Kind::Nats => {
            let client = async_nats::connect(broker.url()).await?;
            let mut sub = client.subscribe("cangate.v1.pb.bench.bus.>").await?;
            client.flush().await?;
            Ok(tokio::spawn(async move {
                let _client = client;
                while let Some(m) = sub.next().await {
                    if let Ok(env) = pb::BridgeEnvelope::decode(m.payload.as_ref()) {
                        on_envelope(&env, &ledger, &hist, latency_events);
                    }
                }
            }))
        }
    }
}

/// The connected gauge of bridge `name`.
fn bridge_connected(name: &str) -> bool {
    cangate_server::metrics::handle().render().lines().any(|l| {
        l.starts_with("cangate_bridge_connected{")
            && l.contains(&format!("bridge=\"{name}\""))
            && l.ends_with(" 1")
    })
}

/// The measurements against one broker.
fn measure(kind: Kind, args: &Args, latency_events: u64, events: u64) -> Result<Option<Value>> {
    let Some(broker) = Broker::start(kind)? else {
        println!(
            "{}: skipped, {} is not installed",
            kind.name(),
            kind.binary()
        );
        return Ok(None);
    };
    let text = format!(
        "listen = \"127.0.0.1:0\"\n[log]\nlevel = \"warn\"\n\
         [[bus]]\nname = \"can0\"\nbackend = \"virtual\"\nfd = true\n\
         [[canopen]]\nbus = \"can0\"\n\
         [[canopen.node]]\nid = 5\neds = \"builtin:io\"\nsimulate = true\n\
         [[bridge]]\nname = \"{}\"\nurl = \"{}\"\ngateway = \"bench\"\n\
         streams = [\"node_events\"]\nformats = [\"pb\"]\nqueue_size = 1000000\n{}",
        kind.binary(),
        broker.url(),
        gateway::NO_CLIENT_LIMITS
    );
    let config = gateway::config(&text)?;
    let gateway_rt = gateway::runtime("gateway", gateway::gateway_workers())?;
    let server = gateway::start_on(&gateway_rt, &config)?;
    let url = gateway::url(&server);
    let device = gateway::virtual_bus(&server, "can0")?.connect(false);
    let client_rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .thread_name("bench-client")
        .build()?;
    let total = latency_events + events;
    let ledger = Arc::new(Ledger {
        base: Instant::now(),
        sent: (0..total).map(|_| AtomicU64::new(0)).collect(),
        broker_seen: AtomicU64::new(0),
        gaps: AtomicU64::new(0),
        notify: Notify::new(),
    });
    let send = |i: u64| -> Result<()> {
        ledger.sent[i as usize].store(
            ledger.base.elapsed().as_nanos().max(1) as u64,
            Ordering::Release,
        );
        device.send(&emcy(i)?)?;
        Ok(())
    };
    let result = client_rt.block_on(async {
        let broker_hist = Arc::new(std::sync::Mutex::new(stats::histogram()));
        tokio::time::timeout(STALL, async {
            while !bridge_connected(kind.binary()) {
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        })
        .await
        .context("the bridge does not connect")?;
        let sub = subscribe(&broker, ledger.clone(), broker_hist.clone(), latency_events).await?;
        // The gRPC stream of node 5's events.
        let c = cangate_client::connect(&url).await?;
        let mut grpc = c
            .canopen_client()
            .stream_node_events(pb::StreamNodeEventsRequest {
                bus: "can0".into(),
                nodes: vec![5],
            })
            .await?
            .into_inner();
        let (grpc_tx, mut grpc_rx) = mpsc::unbounded_channel();
        let grpc_ledger = ledger.clone();
        let grpc_reader = tokio::spawn(async move {
            let mut hist = stats::histogram();
            let mut seen = 0;
            while seen < latency_events {
                let Ok(Some(ev)) = grpc.message().await else {
                    break;
                };
                if let Some(i) = number(&ev) {
                    if let Some(d) = grpc_ledger.latency(i) {
                        stats::record(&mut hist, d);
                    }
                    seen += 1;
                }
            }
            let _ = grpc_tx.send(hist);
        });

        // 1. Latency, paced.
        let mut tick =
            tokio::time::interval(Duration::from_nanos(1_000_000_000 / args.rate.max(1)));
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        for i in 0..latency_events {
            tick.tick().await;
            send(i)?;
        }
        let grpc_hist = tokio::time::timeout(STALL, grpc_rx.recv())
            .await
            .context("the gRPC stream stalled")?
            .context("the gRPC reader ended")?;
        grpc_reader.abort();
        wait_seen(&ledger, latency_events).await?;

        // 2. Throughput, windowed against the broker's subscriber.
        let cpu0 = host::cpu_seconds(&host::thread_cpu()?, &["gateway"]);
        let t0 = Instant::now();
        let mut i = latency_events;
        while i < total {
            let seen = ledger.broker_seen.load(Ordering::Acquire);
            if i - seen >= args.window {
                let notified = ledger.notify.notified();
                if i - ledger.broker_seen.load(Ordering::Acquire) >= args.window {
                    let _ = tokio::time::timeout(Duration::from_millis(100), notified).await;
                }
                if ledger.gaps.load(Ordering::Acquire) > 0 {
                    break;
                }
                continue;
            }
            let n = (args.window - (i - seen)).min(total - i);
            for k in i..i + n {
                send(k)?;
            }
            i += n;
            tokio::task::yield_now().await;
        }
        wait_seen(&ledger, total).await?;
        let secs = t0.elapsed().as_secs_f64();
        let cpu = host::cpu_seconds(&host::thread_cpu()?, &["gateway"]) - cpu0;
        sub.abort();
        let broker_hist = broker_hist.lock().unwrap().clone();
        anyhow::Ok((grpc_hist, broker_hist, secs, cpu))
    });
    gateway_rt.block_on(gateway::stop(server));
    drop(client_rt);
    drop(gateway_rt);
    let (grpc_hist, broker_hist, secs, cpu) = result?;
    let gaps = ledger.gaps.load(Ordering::Acquire);
    let rate = events as f64 / secs;
    let cpu_ms_per_1000 = cpu * 1000.0 / events as f64 * 1000.0;
    let us = |h: &hdrhistogram::Histogram<u64>, q: f64| stats::quantile_us(h, q);
    println!("{}:", kind.name());
    println!(
        "  latency, bus -> gRPC stream                 p50 {:>8.1} µs  p99 {:>8.1} µs  ({} events at {}/s)",
        us(&grpc_hist, 0.5),
        us(&grpc_hist, 0.99),
        grpc_hist.len(),
        args.rate
    );
    println!(
        "  latency, bus -> bridge -> broker -> sub     p50 {:>8.1} µs  p99 {:>8.1} µs  ({} events)",
        us(&broker_hist, 0.5),
        us(&broker_hist, 0.99),
        broker_hist.len()
    );
    println!(
        "  throughput {:>8.0} events/s to the subscriber, {gaps} in gap records ({events} events, window {}); \
         gateway CPU {cpu_ms_per_1000:.1} ms per 1,000 events",
        rate, args.window
    );
    if gaps > 0 {
        println!("  NOT SUSTAINED: {gaps} events in gap records (a smaller --window holds less)");
    }
    Ok(Some(json!({
        "broker": kind.binary(),
        "grpc_p50_us": us(&grpc_hist, 0.5), "grpc_p99_us": us(&grpc_hist, 0.99),
        "bridge_p50_us": us(&broker_hist, 0.5), "bridge_p99_us": us(&broker_hist, 0.99),
        "events_per_s": rate, "gap_events": gaps,
        "gateway_cpu_ms_per_1000_events": cpu_ms_per_1000,
    })))
}

/// Waits until the broker's subscriber has seen `n` events (or a gap).
async fn wait_seen(ledger: &Ledger, n: u64) -> Result<()> {
    let mut last = ledger.broker_seen.load(Ordering::Acquire);
    let mut since = Instant::now();
    loop {
        let notified = ledger.notify.notified();
        let seen = ledger.broker_seen.load(Ordering::Acquire);
        if seen + ledger.gaps.load(Ordering::Acquire) >= n {
            return Ok(());
        }
        if seen != last {
            last = seen;
            since = Instant::now();
        } else if since.elapsed() > STALL {
            bail!("the broker's subscriber stalled at {seen} of {n} events");
        }
        let _ = tokio::time::timeout(Duration::from_millis(100), notified).await;
    }
}

fn bench(args: &Args) -> Result<bool> {
    let (latency_events, events) = if args.quick {
        (200, 1_000)
    } else {
        (args.latency_events, args.events)
    };
    println!(
        "{}: {latency_events} events for latency at {}/s, {events} for throughput (window {})",
        report::banner("bridge_bench", args.quick),
        args.rate,
        args.window
    );
    // The metrics recorder before any gateway: the bridge's connected
    // gauge is set once, at its connection.
    cangate_server::metrics::handle();
    let mut figures = Vec::new();
    for kind in [Kind::Mqtt, Kind::Nats] {
        if args.only.as_deref().is_some_and(|o| {
            !kind.binary().starts_with(o) && !kind.name().to_lowercase().starts_with(o)
        }) {
            continue;
        }
        if let Some(f) = measure(kind, args, latency_events, events)? {
            figures.push(f);
        }
    }
    println!(
        "{}",
        json!({"bench": "bridge_bench", "profile": report::build_profile(),
               "latency_events": latency_events, "events": events, "brokers": figures})
    );
    Ok(true)
}
