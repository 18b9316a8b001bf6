//! `virtual-bus`: frames/s from one port to another on a virtual bus
//! without bit timing.
//!
//! The sender is a plain thread calling [`VirtualPort::send`] (delivery
//! happens in the sender's context: a `try_send` into the receiver's
//! bounded queue). The receiver is a task draining its queue with
//! `recv_many` in batches of up to [`RECV_BATCH`]. Two passes:
//!
//! - **windowed** (the headline figure): the sender never has more than
//!   `port_queue / 2` frames outstanding (sent but not yet counted by the
//!   receiver, which publishes its count through an atomic after every
//!   batch), so the queue cannot overflow and the figure is lossless
//!   delivered throughput;
//! - **unthrottled**: the sender blasts; frames that find the queue full are
//!   counted by the port as overflows.

use anyhow::{Context, Result, bail};
use cangate_bench::report::{Measure, Target};
use cangate_can::{CanId, Frame, PortEvent, VirtualBus, VirtualBusConfig};
use serde_json::json;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};
use tokio::sync::Notify;

/// Most events taken from the port per `recv_many`.
pub const RECV_BATCH: usize = 1024;
/// Default frame count.
pub const FRAMES: u64 = 5_000_000;
/// Frame count with `--quick`.
pub const QUICK_FRAMES: u64 = 50_000;
/// Target, frames/s.
pub const TARGET: f64 = 1_000_000.0;

/// The result of one pass.
#[derive(Debug, Clone, Copy)]
struct Pass {
    sent: u64,
    received: u64,
    overflows: u64,
    out_of_order: u64,
    elapsed: Duration,
    /// Times the sender had to wait for the receiver.
    waits: u64,
    /// `recv_many` calls that returned frames.
    batches: u64,
}

impl Pass {
    fn rate(&self) -> f64 {
        self.received as f64 / self.elapsed.as_secs_f64()
    }
}

/// One pass; `window` limits the frames outstanding, `None` blasts.
/// `batch` > 1 sends with `VirtualPort::send_batch` (one call per `batch`
/// frames, as a driver with a transmit FIFO would), else one `send` per frame.
async fn pass(frames: u64, window: Option<u64>, batch: u64) -> Result<Pass> {
    let bus = VirtualBus::new("bench", VirtualBusConfig::default());
    let tx = bus.connect(false);
    let mut rx = bus.connect(false);
    let received = Arc::new(AtomicU64::new(0));
    let done = Arc::new(Notify::new());
    let id = CanId::standard(0x123)?;

    let start = Instant::now();
    let sender = {
        let received = received.clone();
        let done = done.clone();
        std::thread::Builder::new()
            .name("vbus-sender".into())
            .spawn(move || -> Result<u64> {
                let mut waits = 0u64;
                let mut chunk = Vec::with_capacity(batch as usize);
                for seq in 0..frames {
                    if let Some(w) = window {
                        let mut spins = 0u32;
                        while seq - received.load(Ordering::Acquire) >= w {
                            if spins < 100 {
                                std::hint::spin_loop();
                            } else {
                                std::thread::yield_now();
                            }
                            spins += 1;
                        }
                        if spins > 0 {
                            waits += 1;
                        }
                    }
                    if batch <= 1 {
                        tx.send(&Frame::new(id, &seq.to_le_bytes())?)?;
                    } else {
                        chunk.push(Frame::new(id, &seq.to_le_bytes())?);
                        if chunk.len() as u64 == batch || seq + 1 == frames {
                            tx.send_batch(&chunk)?;
                            chunk.clear();
                        }
                    }
                }
                done.notify_one();
                // `tx` is dropped here, after the last send.
                Ok(waits)
            })
            .context("spawning the sender thread")?
    };

    let mut buf = Vec::with_capacity(RECV_BATCH);
    let (mut got, mut out_of_order, mut next_seq, mut batches) = (0u64, 0u64, 0u64, 0u64);
    let mut sender_done = false;
    let deadline = Duration::from_secs(120);
    loop {
        if sender_done && got + rx.overflows() >= frames {
            break;
        }
        buf.clear();
        if sender_done {
            // Everything not lost is already queued.
            rx.recv_many(&mut buf, RECV_BATCH).await;
        } else {
            tokio::select! {
                biased;
                _ = rx.recv_many(&mut buf, RECV_BATCH) => {}
                _ = done.notified() => sender_done = true,
            }
        }
        for ev in &buf {
            if let PortEvent::Frame { frame, .. } = ev {
                let seq = u64::from_le_bytes(frame.data().try_into().unwrap_or_default());
                if seq < next_seq {
                    out_of_order += 1;
                }
                next_seq = seq + 1;
                got += 1;
            }
        }
        if !buf.is_empty() {
            batches += 1;
        }
        received.store(got, Ordering::Release);
        if start.elapsed() > deadline {
            bail!("stalled: {got} of {frames} frames after {deadline:?}");
        }
    }
    let elapsed = start.elapsed();
    let waits = sender
        .join()
        .map_err(|_| anyhow::anyhow!("sender thread panicked"))??;
    Ok(Pass {
        sent: frames,
        received: got,
        overflows: rx.overflows(),
        out_of_order,
        elapsed,
        waits,
        batches,
    })
}

fn print_pass(name: &str, p: &Pass) {
    println!(
        "  {name:<12} {:>10} frames/s delivered  ({} of {} frames in {:.3} s, {} overflows, {} out of order, {:.1} frames per recv_many, sender waited {} times)",
        cangate_bench::report::human(p.rate()),
        p.received,
        p.sent,
        p.elapsed.as_secs_f64(),
        p.overflows,
        p.out_of_order,
        p.received as f64 / p.batches.max(1) as f64,
        p.waits,
    );
}

fn pass_json(p: &Pass) -> serde_json::Value {
    json!({
        "frames_sent": p.sent,
        "frames_received": p.received,
        "overflows": p.overflows,
        "out_of_order": p.out_of_order,
        "seconds": p.elapsed.as_secs_f64(),
        "frames_per_s": p.rate(),
        "sender_waits": p.waits,
        "recv_batches": p.batches,
        "frames_per_batch": p.received as f64 / p.batches.max(1) as f64,
    })
}

/// Runs both passes.
/// Frames per `send_batch` call in the batched pass.
const BATCH: u64 = 64;

pub async fn run(frames: u64) -> Result<Vec<Measure>> {
    let queue = VirtualBusConfig::default().port_queue as u64;
    let window = (queue / 2).max(1);
    println!(
        "virtual-bus: {frames} frames, 1 sender thread -> 1 receiver task (recv_many <= {RECV_BATCH}), port queue {queue}"
    );
    let windowed = pass(frames, Some(window), 1).await?;
    print_pass("windowed", &windowed);
    let blast = pass(frames, None, 1).await?;
    print_pass("unthrottled", &blast);
    let batched = pass(frames, Some(window), BATCH).await?;
    print_pass("batched", &batched);
    if windowed.overflows > 0 || windowed.received != frames {
        bail!(
            "the windowed pass lost frames ({} overflows, {} of {frames} received)",
            windowed.overflows,
            windowed.received
        );
    }
    let batched_measure = Measure::value(
        "virtual-bus",
        "virtual bus throughput, send_batch of 64 (lossless)",
        batched.rate(),
        "frames/s",
        Target::AtLeast(TARGET),
        json!({ "batch": BATCH, "pass": pass_json(&batched) }),
    );
    Ok(vec![
        batched_measure,
        Measure::value(
            "virtual-bus",
            "virtual bus throughput (lossless)",
            windowed.rate(),
            "frames/s",
            Target::AtLeast(TARGET),
            json!({
                "window": window,
                "port_queue": queue,
                "recv_batch": RECV_BATCH,
                "windowed": pass_json(&windowed),
                "unthrottled": pass_json(&blast),
            }),
        ),
    ])
    .map(|mut v: Vec<Measure>| {
        v.reverse();
        v
    })
}
