//! The `cangate.v1.Bus` service: list, send, stream.

use super::error::ApiError;
use crate::gateway::Gateway;
use crate::grpc::convert::bus::{
    bus_info_to_pb, filter_from_pb, frame_from_pb, item_to_pb, status_to_pb,
};
use cangate_can::{FrameSelector, TxClass};
use cangate_proto::v1 as pb;
use cangate_proto::v1::bus_server::Bus;
use std::pin::Pin;
use std::sync::Arc;
use tokio_stream::Stream;
use tonic::{Request, Response, Status};

/// Most frames in one SendFrames call.
pub const MAX_SEND_BATCH: usize = 10_000;
/// Most events per StreamFrames message.
pub const MAX_STREAM_BATCH: usize = 1024;
/// Default per-client stream buffer.
pub const DEFAULT_STREAM_QUEUE: usize = 8192;
/// A stream message with fewer events than this is "small"; small
/// messages come out of a budget ([`SMALL_MESSAGE_BURST`],
/// [`SMALL_MESSAGES_PER_S`]), and once it is spent a small message waits up
/// to [`COALESCE_LINGER`] for more events to join it.
///
/// Why: every message is at least one HTTP/2 DATA frame, and a client's
/// HTTP/2 layer (h2, the Rust one) limits how many small frames may wait
/// unread before it drops the connection ("too_many_data_frames"). A bus at
/// a few thousand frames/s otherwise yields one tiny message per frame,
/// which a reader that pauses (`cangate dump | less`) collects by the
/// thousand. Sixteen events make a message of several hundred bytes, above
/// h2's small-frame threshold of 256 bytes. The budget keeps the latency of
/// a reader that keeps up at zero (a request/response exchange over a
/// stream sends one small message per frame), and bounds the small
/// messages a paused reader can collect to the burst plus 200 per second.
pub const COALESCE_EVENTS: usize = 16;
/// Small messages sent at once, before lingering starts (see
/// [`COALESCE_EVENTS`]): about 256 KiB of h2 overhead at most.
pub const SMALL_MESSAGE_BURST: f64 = 1000.0;
/// Rate at which the small-message budget refills (see
/// [`COALESCE_EVENTS`]).
pub const SMALL_MESSAGES_PER_S: f64 = 200.0;
/// See [`COALESCE_EVENTS`].
pub const COALESCE_LINGER: std::time::Duration = std::time::Duration::from_millis(5);
/// Largest per-client stream buffer a client may ask for.
pub const MAX_STREAM_QUEUE: usize = 1_000_000;

/// Implementation of the Bus service.
#[derive(Clone)]
pub struct BusService {
    gateway: Arc<Gateway>,
}

impl BusService {
    /// Serves the gateway's buses.
    pub fn new(gateway: Arc<Gateway>) -> Self {
        BusService { gateway }
    }
}

type FrameStream = Pin<Box<dyn Stream<Item = Result<pb::StreamFramesResponse, Status>> + Send>>;

#[tonic::async_trait]
impl Bus for BusService {
    async fn list_buses(
        &self,
        _req: Request<pb::ListBusesRequest>,
    ) -> Result<Response<pb::ListBusesResponse>, Status> {
        let buses = self
            .gateway
            .buses()
            .map(|b| bus_info_to_pb(b.info(), &b.stats()))
            .collect();
        Ok(Response::new(pb::ListBusesResponse { buses }))
    }

    async fn get_bus(
        &self,
        req: Request<pb::GetBusRequest>,
    ) -> Result<Response<pb::BusInfo>, Status> {
        let bus = self.gateway.bus(&req.get_ref().bus)?;
        Ok(Response::new(bus_info_to_pb(bus.info(), &bus.stats())))
    }

    async fn send_frames(
        &self,
        req: Request<pb::SendFramesRequest>,
    ) -> Result<Response<pb::SendFramesResponse>, Status> {
        let req = req.into_inner();
        let bus = self.gateway.bus(&req.bus)?;
        if req.frames.is_empty() {
            return Err(
                ApiError::InvalidArgument("no frames to send: the batch is empty".into()).into(),
            );
        }
        if req.frames.len() > MAX_SEND_BATCH {
            return Err(ApiError::InvalidArgument(format!(
                "{} frames in one batch; at most {MAX_SEND_BATCH}",
                req.frames.len()
            ))
            .into());
        }
        let frames = req
            .frames
            .iter()
            .enumerate()
            .map(|(i, f)| frame_from_pb(f).map_err(|e| ApiError::bad_frame(i, e)))
            .collect::<Result<Vec<_>, _>>()?;
        let n = frames.len() as u32;
        // Within the bus's client share, behind the gateway's own frames.
        bus.send_as(TxClass::Client, frames)
            .await
            .map_err(ApiError::from)?;
        Ok(Response::new(pb::SendFramesResponse { sent: n }))
    }

    type StreamFramesStream = FrameStream;

    async fn stream_frames(
        &self,
        req: Request<pb::StreamFramesRequest>,
    ) -> Result<Response<Self::StreamFramesStream>, Status> {
        // The queue comes out of the caller's budget ([security.limits]).
        let (queue, queue_reservation) = crate::security::stream_queue(
            &req,
            req.get_ref().queue_length,
            DEFAULT_STREAM_QUEUE,
            MAX_STREAM_QUEUE,
        )?;
        let req = req.into_inner();
        let bus = self.gateway.bus(&req.bus)?.clone();
        let filters = req
            .filters
            .iter()
            .map(filter_from_pb)
            .collect::<Result<Vec<_>, _>>()?;
        let max_batch = match req.max_batch as usize {
            0 => MAX_STREAM_BATCH,
            n => n.min(MAX_STREAM_BATCH),
        };
        let selector = FrameSelector {
            filters,
            error_frames: req.include_error_frames,
            transmitted: req.include_transmitted,
        };
        let mut sub = bus.subscribe(selector, queue);
        let cancel = self.gateway.shutdown_token();
        // A small channel: when the client reads slowly, back-pressure reaches
        // the subscription, whose drops are counted and reported in-stream.
        let (tx, rx) = tokio::sync::mpsc::channel::<Result<pb::StreamFramesResponse, Status>>(4);
        let stats = bus.stats();
        tokio::spawn(async move {
            let _queue_reservation = queue_reservation;
            let first = pb::StreamFramesResponse {
                events: vec![pb::StreamEvent {
                    event: Some(pb::stream_event::Event::State(status_to_pb(
                        stats.status,
                        stats.status_since.as_nanos(),
                    ))),
                }],
            };
            if tx.send(Ok(first)).await.is_err() {
                return;
            }
            let mut items = Vec::with_capacity(max_batch);
            let mut small_budget = SMALL_MESSAGE_BURST;
            let mut refilled = tokio::time::Instant::now();
            loop {
                items.clear();
                let n = tokio::select! {
                    _ = cancel.cancelled() => break,
                    _ = tx.closed() => break,
                    n = sub.recv_many(&mut items, max_batch) => n,
                };
                if n == 0 {
                    break; // the bus stopped
                }
                // A few events: from the small-message budget, or give more
                // a moment to join them (see COALESCE_EVENTS).
                let now = tokio::time::Instant::now();
                small_budget = (small_budget
                    + now.duration_since(refilled).as_secs_f64() * SMALL_MESSAGES_PER_S)
                    .min(SMALL_MESSAGE_BURST);
                refilled = now;
                let small = items.len() < COALESCE_EVENTS.min(max_batch);
                if small && small_budget >= 1.0 {
                    small_budget -= 1.0;
                } else if small {
                    let deadline = tokio::time::Instant::now() + COALESCE_LINGER;
                    while items.len() < COALESCE_EVENTS.min(max_batch) {
                        let room = max_batch - items.len();
                        tokio::select! {
                            _ = cancel.cancelled() => break,
                            _ = tokio::time::sleep_until(deadline) => break,
                            n = sub.recv_many(&mut items, room) => if n == 0 { break },
                        }
                    }
                }
                let since = bus.stats().status_since.as_nanos();
                let events = items.iter().map(|i| item_to_pb(i, since)).collect();
                tokio::select! {
                    _ = cancel.cancelled() => break,
                    r = tx.send(Ok(pb::StreamFramesResponse { events })) => if r.is_err() { break },
                }
            }
        });
        Ok(Response::new(Box::pin(
            tokio_stream::wrappers::ReceiverStream::new(rx),
        )))
    }

    type AttachStream = Pin<Box<dyn Stream<Item = Result<pb::AttachResponse, Status>> + Send>>;

    async fn attach(
        &self,
        _req: Request<tonic::Streaming<pb::AttachRequest>>,
    ) -> Result<Response<Self::AttachStream>, Status> {
        Err(Status::unimplemented("Attach is not served yet"))
    }
}
