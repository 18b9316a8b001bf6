//! The master's own heartbeat: `0x700 + master node [05]` every period, so
//! that drives configured to consume it (0x1016, written by their boot
//! procedure) stop on their own when the gateway dies or hangs.
//!
//! It runs as a task on the bus runtime, next to the bus owners and the
//! CANopen masters, on purpose: if that runtime stalls, the heartbeat stops
//! with it, and the drives see what really happened. A dedicated thread
//! would keep it alive while the master is dead.

use cangate_can::BusHandle;
use cangate_canopen::NodeId;
use cangate_canopen::heartbeat::HeartbeatProducer;
use std::time::Duration;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

/// Produces the heartbeat of `node` on `bus` every `period` until `cancel`
/// fires. Frames the bus refuses (bus-off, interface down) are counted in
/// the bus's own statistics and warned about once per outage.
pub fn spawn(
    bus: BusHandle,
    node: NodeId,
    period: Duration,
    cancel: CancellationToken,
) -> tokio::task::JoinHandle<()> {
    let span = tracing::info_span!("bus", bus = %bus.info().name);
    tokio::spawn(tracing::Instrument::instrument(
        async move {
            let origin = Instant::now();
            let mut producer = HeartbeatProducer::new(node, period);
            let mut failing = false;
            loop {
                if let Some(frame) = producer.on_tick(origin.elapsed()) {
                    match bus.send(vec![frame]).await {
                        Ok(()) => failing = false,
                        Err(e) if !failing => {
                            failing = true;
                            tracing::warn!(node = node.get(), error = %e.error, "master heartbeat not sent");
                        }
                        Err(_) => {}
                    }
                }
                let next = producer.next_deadline().unwrap_or_default();
                tokio::select! {
                    biased;
                    _ = cancel.cancelled() => break,
                    _ = tokio::time::sleep_until(origin + next) => {}
                }
            }
        },
        span,
    ))
}
