//! `latency`: send → receive latency through the server.
//!
//! Client A calls SendFrames with one frame whose payload is a sequence
//! number; client B (its own connection) streams the same bus with
//! `include_transmitted = true` and sees the gateway's transmission of that
//! frame. One frame at a time: the clock starts just before SendFrames and
//! stops when B's stream yields the frame with that sequence number. The
//! SendFrames round trip (until A's call returns) is recorded as well.

use anyhow::{Context, Result, bail};
use cangate_bench::gateway;
use cangate_bench::report::{Measure, Target};
use cangate_bench::stats::{self, Percentiles};
use cangate_can::{CanId, Frame};
use cangate_client::pb;
use cangate_client::pb::stream_event::Event;
use hdrhistogram::Histogram;
use serde_json::json;
use std::time::{Duration, Instant};

/// Default samples.
pub const SAMPLES: u64 = 10_000;
/// Default warm-up round trips (not recorded).
pub const WARMUP: u64 = 500;
/// Samples with `--quick`.
pub const QUICK_SAMPLES: u64 = 200;
/// Warm-up with `--quick`.
pub const QUICK_WARMUP: u64 = 20;
/// Target: p99 below this many microseconds.
pub const TARGET_P99_US: f64 = 1000.0;
/// One sample may take at most this long.
const SAMPLE_TIMEOUT: Duration = Duration::from_secs(5);

/// Waits for the frame carrying `seq` on the stream; returns when it came.
async fn wait_for(
    stream: &mut tonic::Streaming<pb::StreamFramesResponse>,
    seq: u64,
) -> Result<Instant> {
    let want = seq.to_le_bytes();
    loop {
        let msg = stream.message().await?.context("the stream ended early")?;
        let now = Instant::now();
        for ev in &msg.events {
            match &ev.event {
                Some(Event::Frame(f)) if f.data[..] == want[..] => return Ok(now),
                Some(Event::Lost(l)) => bail!("the stream lost {} frames", l.count),
                _ => {}
            }
        }
    }
}

fn print_hist(name: &str, p: &Percentiles) {
    println!(
        "  {name:<22} p50 {:>8.1} µs   p90 {:>8.1} µs   p99 {:>8.1} µs   max {:>8.1} µs",
        p.p50_us, p.p90_us, p.p99_us, p.max_us
    );
}

/// Runs the benchmark.
pub async fn run(samples: u64, warmup: u64) -> Result<Vec<Measure>> {
    println!(
        "latency: {samples} samples after {warmup} warm-up, client A SendFrames(1 frame) -> client B StreamFrames (include_transmitted), one at a time"
    );
    let gateway = gateway::OwnRuntimeGateway::start_can0().await?;
    let result = measure(&gateway.server, samples, warmup).await;
    gateway.stop().await;
    result
}

async fn measure(
    server: &cangate_server::RunningServer,
    samples: u64,
    warmup: u64,
) -> Result<Vec<Measure>> {
    let url = gateway::url(server);
    let mut a = cangate_client::connect(&url).await?;
    let mut b = cangate_client::connect(&url).await?;
    let mut stream = b
        .stream_frames(pb::StreamFramesRequest {
            bus: "can0".into(),
            filters: vec![],
            include_transmitted: true,
            include_error_frames: false,
            max_batch: 0,
            queue_length: 0,
            // One frame at a time, each read at once: the case it is for.
            low_latency: true,
        })
        .await?;
    let first = tokio::time::timeout(SAMPLE_TIMEOUT, stream.message())
        .await
        .context("no first StreamFrames message")??;
    if first.is_none() {
        bail!("the stream ended at once");
    }

    let id = CanId::standard(0x100)?;
    let mut e2e: Histogram<u64> = stats::histogram();
    let mut rpc: Histogram<u64> = stats::histogram();
    let start = Instant::now();
    for seq in 0..warmup + samples {
        let frame = Frame::new(id, &seq.to_le_bytes())?;
        let t0 = Instant::now();
        let send = async {
            let r = a.send("can0", &[frame]).await;
            (r, Instant::now())
        };
        let (sent, received) = tokio::time::timeout(SAMPLE_TIMEOUT, async {
            tokio::join!(send, wait_for(&mut stream, seq))
        })
        .await
        .with_context(|| format!("sample {seq} took longer than {SAMPLE_TIMEOUT:?}"))?;
        let (sent, sent_at) = sent;
        sent.with_context(|| format!("SendFrames of sample {seq}"))?;
        let received = received?;
        if seq >= warmup {
            stats::record(&mut e2e, received - t0);
            stats::record(&mut rpc, sent_at - t0);
        }
    }
    let secs = start.elapsed().as_secs_f64();
    let (e2e, rpc) = (Percentiles::of(&e2e), Percentiles::of(&rpc));
    print_hist("send -> stream receipt", &e2e);
    print_hist("SendFrames round trip", &rpc);
    println!("  {} round trips in {secs:.2} s", warmup + samples);
    Ok(vec![Measure::value(
        "latency",
        "send->receive latency p99",
        e2e.p99_us,
        "µs",
        Target::Below(TARGET_P99_US),
        json!({
            "send_to_receive": e2e.to_json(),
            "send_frames_rpc": rpc.to_json(),
            "warmup": warmup,
            "seconds": secs,
        }),
    )])
}
