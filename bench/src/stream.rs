//! `stream`: gRPC StreamFrames throughput to one client.
//!
//! The server runs in-process (one virtual bus `can0` without bit timing,
//! a free loopback port). A port attached to the server's virtual bus plays
//! a device and blasts frames; the client counts the frames (and any
//! `Lost` notices) arriving on its stream. The device sender is windowed
//! against the client's count: at most `window` frames may be outstanding
//! (sent but not yet counted by the client), which keeps both the server's
//! port queue and the subscription queue from overflowing, so the figure is
//! lossless end-to-end throughput. The server batches up to 1024 events per
//! StreamFrames message; frames per message is reported.

use anyhow::{Context, Result, bail};
use cangate_bench::gateway;
use cangate_bench::report::{Measure, Target, human};
use cangate_can::{CanId, Frame, VirtualBusConfig};
use cangate_client::pb;
use cangate_client::pb::stream_event::Event;
use cangate_server::RunningServer;
use serde_json::json;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};
use tokio::sync::Notify;

/// Default frame count.
pub const FRAMES: u64 = 2_000_000;
/// Frame count with `--quick`.
pub const QUICK_FRAMES: u64 = 20_000;
/// Target, frames/s.
pub const TARGET: f64 = 200_000.0;
/// Subscription queue the client asks for.
pub const QUEUE_LENGTH: u32 = 65_536;
/// Frames the device sends before yielding to the other tasks.
const SEND_CHUNK: u64 = 1024;
/// Gives up when the client sees nothing for this long.
const STALL: Duration = Duration::from_secs(10);

/// Counts shared between the client reader and the device sender.
#[derive(Default)]
struct Progress {
    frames: AtomicU64,
    lost: AtomicU64,
    notify: Notify,
}

impl Progress {
    fn accounted(&self) -> u64 {
        self.frames.load(Ordering::Acquire) + self.lost.load(Ordering::Acquire)
    }
}

/// What the client saw.
struct ClientCount {
    frames: u64,
    lost: u64,
    messages: u64,
    out_of_order: u64,
    end: Instant,
}

/// Runs the benchmark; `window` defaults to half the server's port queue.
pub async fn run(frames: u64, window: Option<u64>) -> Result<Vec<Measure>> {
    let port_queue = VirtualBusConfig::default().port_queue as u64;
    let window = window
        .unwrap_or(port_queue / 2)
        .clamp(1, port_queue.min(QUEUE_LENGTH as u64));
    println!(
        "stream: {frames} frames, device port -> server -> StreamFrames -> 1 client, window {window}, subscription queue {QUEUE_LENGTH}"
    );
    let gateway = gateway::OwnRuntimeGateway::start_can0().await?;
    let result = measure(&gateway.server, frames, window).await;
    gateway.stop().await;
    result
}

async fn measure(server: &RunningServer, frames: u64, window: u64) -> Result<Vec<Measure>> {
    let device = gateway::virtual_bus(server, "can0")?.connect(false);
    let mut client = cangate_client::connect(&gateway::url(server)).await?;
    let mut stream = client
        .stream_frames(pb::StreamFramesRequest {
            bus: "can0".into(),
            filters: vec![],
            include_transmitted: false,
            include_error_frames: false,
            max_batch: 0,
            queue_length: QUEUE_LENGTH,
            low_latency: false,
        })
        .await?;
    // The first message is the bus state: the subscription is live.
    let first = tokio::time::timeout(STALL, stream.message())
        .await
        .context("no first StreamFrames message")??
        .context("the stream ended at once")?;
    if !matches!(
        first.events.first().and_then(|e| e.event.as_ref()),
        Some(Event::State(_))
    ) {
        bail!("the first stream event is not the bus state");
    }

    let progress = Arc::new(Progress::default());
    let reader = {
        let progress = progress.clone();
        tokio::spawn(async move {
            let mut c = ClientCount {
                frames: 0,
                lost: 0,
                messages: 0,
                out_of_order: 0,
                end: Instant::now(),
            };
            let mut next_seq = 0u64;
            while c.frames + c.lost < frames {
                let msg = tokio::time::timeout(STALL, stream.message())
                    .await
                    .map_err(|_| {
                        anyhow::anyhow!(
                            "stalled: {} frames + {} lost of {frames} after {STALL:?} without a message",
                            c.frames,
                            c.lost
                        )
                    })??
                    .context("the stream ended early")?;
                let mut had_frames = false;
                for ev in &msg.events {
                    match &ev.event {
                        Some(Event::Frame(f)) => {
                            let seq = u64::from_le_bytes(f.data[..].try_into().unwrap_or_default());
                            if seq < next_seq {
                                c.out_of_order += 1;
                            }
                            next_seq = seq + 1;
                            c.frames += 1;
                            had_frames = true;
                        }
                        Some(Event::Lost(l)) => {
                            c.lost += l.count;
                            progress.lost.store(c.lost, Ordering::Release);
                        }
                        _ => {}
                    }
                }
                if had_frames {
                    c.messages += 1;
                }
                progress.frames.store(c.frames, Ordering::Release);
                progress.notify.notify_one();
            }
            c.end = Instant::now();
            anyhow::Ok(c)
        })
    };

    let id = CanId::standard(0x321)?;
    let start = Instant::now();
    let mut seq = 0u64;
    let mut waits = 0u64;
    while seq < frames {
        let outstanding = seq.saturating_sub(progress.accounted());
        if outstanding >= window {
            waits += 1;
            let notified = progress.notify.notified();
            if seq.saturating_sub(progress.accounted()) >= window {
                if reader.is_finished() {
                    break; // it failed; its error is reported below
                }
                let _ = tokio::time::timeout(Duration::from_millis(100), notified).await;
            }
            continue;
        }
        let n = (window - outstanding).min(SEND_CHUNK).min(frames - seq);
        for s in seq..seq + n {
            device.send(&Frame::new(id, &s.to_le_bytes())?)?;
        }
        seq += n;
        tokio::task::yield_now().await;
    }
    let c = reader.await.context("the client reader panicked")??;
    let secs = (c.end - start).as_secs_f64();
    let fps = c.frames as f64 / secs;
    let mps = c.messages as f64 / secs;
    let per_msg = c.frames as f64 / c.messages.max(1) as f64;
    let overflows = device.bus().stats().port_overflows;
    println!(
        "  {:>10} frames/s delivered  ({} of {frames} frames in {secs:.3} s, {} lost, {} overflows, {} out of order)",
        human(fps),
        c.frames,
        c.lost,
        overflows,
        c.out_of_order
    );
    println!(
        "  {:>10} messages/s, {per_msg:.1} frames/message on average; device waited for the window {waits} times",
        human(mps)
    );
    Ok(vec![Measure::value(
        "stream",
        "gRPC StreamFrames to 1 client",
        fps,
        "frames/s",
        Target::AtLeast(TARGET),
        json!({
            "frames_sent": frames,
            "frames_received": c.frames,
            "lost": c.lost,
            "port_overflows": overflows,
            "out_of_order": c.out_of_order,
            "seconds": secs,
            "messages": c.messages,
            "messages_per_s": mps,
            "frames_per_message": per_msg,
            "window": window,
            "queue_length": QUEUE_LENGTH,
            "sender_waits": waits,
        }),
    )])
}
