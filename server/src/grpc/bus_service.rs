//! The `cangate.v1.Bus` service: list, send, stream, attach.
//!
//! Clients send as bus participants (see "Clients are bus participants" in
//! bus.proto): each `SendFrames` call and each `Attach` stream is one
//! sender, a [`ClientId`] whose frames the bus delivers to everyone else as
//! received; [`SenderNames`] says who each sender is, for the streams that
//! show its frames.

use super::error::ApiError;
use super::forward::{AtShutdown, Forward, Received, Source, spawn_forwarding};
use crate::convert::bus::{
    bus_info_to_pb, filter_from_pb, frame_from_pb, item_to_attach_pb, item_to_pb, status_to_pb,
};
use crate::cyclic::{CyclicError, CyclicEvent, CyclicPolicy, CyclicSender};
use crate::gateway::Gateway;
use crate::participants::{SenderGuard, SenderNames};
use crate::security::{FrameBudget, StreamQueueBudget};
use cangate_can::{
    AttachOptions, BusHandle, BusItem, ClientId, Frame, FrameSelector, SendFailure, Subscription,
};
use cangate_proto::v1 as pb;
use cangate_proto::v1::bus_server::Bus;
use std::pin::Pin;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc;
use tokio_stream::Stream;
use tokio_util::sync::CancellationToken;
use tonic::{Code, Request, Response, Status};

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
/// How long an Attach stream may take to send its AttachOpen.
pub const ATTACH_OPEN_TIMEOUT: Duration = Duration::from_secs(10);
/// Implementation of the Bus service.
#[derive(Clone)]
pub struct BusService {
    gateway: Arc<Gateway>,
    senders: Arc<SenderNames>,
}

impl BusService {
    /// Serves the gateway's buses.
    pub fn new(gateway: Arc<Gateway>) -> Self {
        Self::with_senders(gateway, Arc::default())
    }

    /// Serves the gateway's buses, naming client frames from `senders`,
    /// which other edges (the socketcand endpoint) register their clients
    /// in too.
    pub fn with_senders(gateway: Arc<Gateway>, senders: Arc<SenderNames>) -> Self {
        BusService { gateway, senders }
    }
}

type FrameStream = Pin<Box<dyn Stream<Item = Result<pb::StreamFramesResponse, Status>> + Send>>;

/// A batch of client frames that was not (completely) sent.
struct Refusal {
    error: ApiError,
    sent: usize,
    total: usize,
}

impl From<SendFailure> for Refusal {
    fn from(f: SendFailure) -> Self {
        Refusal {
            sent: f.sent,
            total: f.total,
            error: ApiError::from(f),
        }
    }
}

/// Sends a client's batch as a bus participant: a batch of 1..=10,000
/// frames, within the client's raw frame budget (one token per frame, taken
/// before the frames are validated: a batch refused for a malformed frame
/// costs its size too), validated as a whole, then in the client class of
/// the bus. With `fd` false (an attachment without CAN FD), FD frames are
/// refused.
async fn send_client_frames(
    bus: &BusHandle,
    client: ClientId,
    frames: &[pb::Frame],
    fd: bool,
    budget: Option<&FrameBudget>,
) -> Result<(), Refusal> {
    let result = try_send_client_frames(bus, client, frames, fd, budget).await;
    if let Err(r) = &result {
        crate::metrics::client_frames_refused(
            bus.name(),
            r.error.reason(),
            (r.total - r.sent) as u64,
        );
    }
    result
}

/// [`send_client_frames`] before the refusal is counted.
async fn try_send_client_frames(
    bus: &BusHandle,
    client: ClientId,
    frames: &[pb::Frame],
    fd: bool,
    budget: Option<&FrameBudget>,
) -> Result<(), Refusal> {
    let total = frames.len();
    let refuse = |error| Refusal {
        error,
        sent: 0,
        total,
    };
    if frames.is_empty() {
        return Err(refuse(ApiError::InvalidArgument(
            "no frames to send: the batch is empty".into(),
        )));
    }
    if total > MAX_SEND_BATCH {
        return Err(refuse(ApiError::InvalidArgument(format!(
            "{total} frames in one batch; at most {MAX_SEND_BATCH}"
        ))));
    }
    if let Some(b) = budget {
        b.take(total as u64).map_err(|e| {
            refuse(ApiError::refused(
                Code::ResourceExhausted,
                "FRAME_RATE_LIMIT",
                e.0,
                vec![("frames", total.to_string())],
            ))
        })?;
    }
    let frames = client_frames_from_pb(frames, fd).map_err(refuse)?;
    // Within the bus's client share, behind the gateway's own frames.
    bus.send_as_client(client, frames)
        .await
        .map_err(Refusal::from)
}

/// A client's frames, validated as a whole (`fd` false: FD frames are
/// refused).
fn client_frames_from_pb(frames: &[pb::Frame], fd: bool) -> Result<Vec<Frame>, ApiError> {
    frames
        .iter()
        .enumerate()
        .map(|(i, f)| match frame_from_pb(f) {
            Ok(frame) if frame.is_fd() && !fd => Err(ApiError::bad_frame(
                i,
                "a CAN FD frame, and this stream was attached without fd",
            )),
            Ok(frame) => Ok(frame),
            Err(e) => Err(ApiError::bad_frame(i, e)),
        })
        .collect()
}

/// What an attached client's cyclic frames go through (its frames were
/// validated when the job started): its raw frame budget, then the bus,
/// each refusal counted as a refused AttachSend is.
struct AttachCyclicPolicy {
    bus: String,
    budget: Option<FrameBudget>,
}

impl CyclicPolicy for AttachCyclicPolicy {
    type Refusal = ApiError;

    fn admit(&mut self, _frame: &Frame) -> Result<(), ApiError> {
        let Some(b) = &self.budget else {
            return Ok(());
        };
        b.take(1).map_err(|e| {
            crate::metrics::client_frames_refused(&self.bus, "FRAME_RATE_LIMIT".into(), 1);
            ApiError::refused(
                Code::ResourceExhausted,
                "FRAME_RATE_LIMIT",
                e.0,
                vec![("frames", "1".to_string())],
            )
        })
    }

    fn sent(&mut self, outcome: Result<(), SendFailure>) -> Result<(), ApiError> {
        outcome.map_err(|f| {
            let e = ApiError::from(f);
            crate::metrics::client_frames_refused(&self.bus, e.reason(), 1);
            e
        })
    }
}

/// An attached client's cyclic jobs.
type AttachCyclicJobs = CyclicSender<u32, ApiError>;

/// The next event of an attached client's cyclic jobs (never returns
/// without them).
async fn next_cyclic_event(jobs: &mut Option<AttachCyclicJobs>) -> CyclicEvent<u32, ApiError> {
    match jobs {
        Some(j) => j.next_event().await,
        None => std::future::pending().await,
    }
}

/// Starts or changes a job as an AttachCyclic asks.
fn attach_cyclic(
    jobs: &mut Option<AttachCyclicJobs>,
    msg: &pb::AttachCyclic,
    bus: &BusHandle,
    client: ClientId,
    fd: bool,
    budget: Option<&FrameBudget>,
    cancel: &CancellationToken,
) -> Result<(), ApiError> {
    let frames = client_frames_from_pb(&msg.frames, fd)?;
    let result = if msg.interval_ns == 0 {
        match jobs {
            Some(j) => j.update(msg.job, frames),
            None => Err(CyclicError::NoSuchJob),
        }
    } else {
        let duration = (msg.duration_ns > 0).then(|| Duration::from_nanos(msg.duration_ns));
        jobs.get_or_insert_with(|| {
            let policy = AttachCyclicPolicy {
                bus: bus.name().to_string(),
                budget: budget.cloned(),
            };
            CyclicSender::spawn(bus.clone(), client, policy, cancel)
        })
        .start(
            msg.job,
            frames,
            Duration::from_nanos(msg.interval_ns),
            duration,
        )
    };
    result.map_err(|e| match e {
        CyclicError::TooManyJobs => ApiError::refused(
            Code::ResourceExhausted,
            "CYCLIC_JOB_LIMIT",
            e.to_string(),
            vec![("job", msg.job.to_string())],
        ),
        CyclicError::NoSuchJob => ApiError::InvalidArgument(format!(
            "cyclic job {} does not run: start it with an interval first",
            msg.job
        )),
        e => ApiError::InvalidArgument(format!("cyclic job {}: {e}", msg.job)),
    })
}

/// A job that ended by itself, as its in-stream notice.
fn cyclic_stopped_to_pb(event: CyclicEvent<u32, ApiError>) -> pb::AttachEvent {
    let stopped = match event {
        CyclicEvent::Finished { key } => pb::CyclicStopped {
            job: key,
            code: 0,
            message: "its duration has passed".into(),
            reason: String::new(),
        },
        CyclicEvent::Refused { key, refusal } => pb::CyclicStopped {
            job: key,
            code: refusal.code() as i32,
            message: format!("a frame of it was refused: {refusal}"),
            reason: refusal.reason(),
        },
    };
    pb::AttachEvent {
        event: Some(pb::attach_event::Event::CyclicStopped(stopped)),
    }
}

/// How a stream batches its events into messages.
#[derive(Clone, Copy, Debug)]
struct Batching {
    /// Most events per message.
    max_batch: usize,
    /// Every event at once, without the small-message budget (the
    /// request's `low_latency`, see [`COALESCE_EVENTS`]).
    low_latency: bool,
}

impl Batching {
    /// From a request's `max_batch` (0: the default) and `low_latency`.
    fn from_request(max_batch: u32, low_latency: bool) -> Self {
        let max_batch = match max_batch as usize {
            0 => MAX_STREAM_BATCH,
            n => n.min(MAX_STREAM_BATCH),
        };
        Batching {
            max_batch,
            low_latency,
        }
    }
}

/// Which stream messages may go out with only a few events (see
/// [`COALESCE_EVENTS`]): pure, so its arithmetic is tested with explicit
/// instants.
#[derive(Debug)]
struct SmallMessagePacer {
    /// Small messages that may go at once; refills at
    /// [`SMALL_MESSAGES_PER_S`] up to [`SMALL_MESSAGE_BURST`].
    budget: f64,
    refilled: tokio::time::Instant,
    /// The reader asked for every event at once.
    low_latency: bool,
}

impl SmallMessagePacer {
    fn new(low_latency: bool, now: tokio::time::Instant) -> Self {
        SmallMessagePacer {
            budget: SMALL_MESSAGE_BURST,
            refilled: now,
            low_latency,
        }
    }

    /// For a message of `events` events (`enough` make it not small):
    /// `None` to send it now, or how long to wait for more events.
    fn linger(
        &mut self,
        now: tokio::time::Instant,
        events: usize,
        enough: usize,
    ) -> Option<Duration> {
        self.budget = (self.budget
            + now.saturating_duration_since(self.refilled).as_secs_f64() * SMALL_MESSAGES_PER_S)
            .min(SMALL_MESSAGE_BURST);
        self.refilled = now;
        if self.low_latency || events >= enough {
            None
        } else if self.budget >= 1.0 {
            self.budget -= 1.0;
            None
        } else {
            Some(COALESCE_LINGER)
        }
    }
}

/// Forwards a subscription into a stream: `first` messages, then the items
/// in batches as `batching` says, each batch made a message by
/// `message`. Ends when the client goes away, the bus stops or the gateway
/// shuts down (`at_shutdown`). `hold` is kept as long as the stream runs.
#[allow(clippy::too_many_arguments)]
fn spawn_subscription_forward<M: Send + 'static>(
    sub: Subscription,
    bus: BusHandle,
    tx: mpsc::Sender<Result<M, Status>>,
    first: Vec<M>,
    batching: Batching,
    cancel: CancellationToken,
    at_shutdown: AtShutdown,
    mut message: impl FnMut(&[BusItem], u64) -> M + Send + 'static,
    hold: impl Send + 'static,
) {
    let source = BusBatches {
        sub,
        bus: bus.clone(),
        batching,
        pacer: SmallMessagePacer::new(batching.low_latency, tokio::time::Instant::now()),
        cancel: cancel.clone(),
        _hold: hold,
    };
    spawn_forwarding(source, tx, first, cancel, at_shutdown, move |received| {
        match received {
            Some(Received::Item(items)) => {
                let since = bus.stats().status_since.as_nanos();
                Forward::Send(message(&items, since))
            }
            // A subscription's losses are items of their own.
            Some(Received::Lost(_)) | None => Forward::Skip,
        }
    });
}

/// A bus subscription read in batches: at most `max_batch` items, and a
/// small batch waits a little for more when the small-message budget is
/// spent (see [`SmallMessagePacer`]).
struct BusBatches<H> {
    sub: Subscription,
    bus: BusHandle,
    batching: Batching,
    pacer: SmallMessagePacer,
    /// Ends a batch's wait at shutdown.
    cancel: CancellationToken,
    /// Held as long as the stream runs (a queue reservation).
    _hold: H,
}

impl<H: Send + 'static> Source for BusBatches<H> {
    type Item = Vec<BusItem>;

    async fn next(&mut self) -> Option<Received<Vec<BusItem>>> {
        let max_batch = self.batching.max_batch;
        let mut items = Vec::new();
        if self.sub.recv_many(&mut items, max_batch).await == 0 {
            return None;
        }
        let enough = COALESCE_EVENTS.min(max_batch);
        let now = tokio::time::Instant::now();
        if let Some(linger) = self.pacer.linger(now, items.len(), enough) {
            metrics::counter!("cangate_stream_messages_held_total", "bus" => self.bus.name().to_string())
                .increment(1);
            let deadline = now + linger;
            while items.len() < enough {
                let room = max_batch - items.len();
                tokio::select! {
                    _ = self.cancel.cancelled() => break,
                    _ = tokio::time::sleep_until(deadline) => break,
                    n = self.sub.recv_many(&mut items, room) => if n == 0 { break },
                }
            }
        }
        Some(Received::Item(items))
    }
}

/// An Attach stream that broke its protocol.
fn attach_protocol(message: impl Into<String>) -> Status {
    ApiError::refused(Code::InvalidArgument, "ATTACH_PROTOCOL", message, vec![]).into()
}

/// The sending half of an Attach stream: each AttachSend, AttachCyclic
/// and AttachCyclicStop in order, answered in the stream with its SendDone
/// or SendRefused, and the notices of cyclic jobs that ended by
/// themselves; ends when the client goes away, breaks the protocol or the
/// gateway shuts down, and its cyclic jobs with it. After the client's
/// half-close it holds the sender's name and runs the cyclic jobs until
/// the stream ends.
#[allow(clippy::too_many_arguments)]
async fn attach_sends(
    mut inbound: tonic::Streaming<pb::AttachRequest>,
    bus: BusHandle,
    client: ClientId,
    fd: bool,
    budget: Option<FrameBudget>,
    tx: mpsc::Sender<Result<pb::AttachResponse, Status>>,
    cancel: CancellationToken,
    _name: SenderGuard,
) {
    use pb::attach_request::Message;
    let mut cyclic: Option<AttachCyclicJobs> = None;
    let mut half_closed = false;
    loop {
        let msg = tokio::select! {
            biased;
            _ = cancel.cancelled() => return,
            _ = tx.closed() => return,
            e = next_cyclic_event(&mut cyclic) => {
                let message = pb::AttachResponse {
                    events: vec![cyclic_stopped_to_pb(e)],
                };
                tokio::select! {
                    _ = cancel.cancelled() => return,
                    r = tx.send(Ok(message)) => if r.is_err() { return },
                }
                continue;
            }
            m = inbound.message(), if !half_closed => m,
        };
        let (sequence, answer) = match msg {
            Ok(Some(pb::AttachRequest {
                message: Some(Message::Send(send)),
            })) => {
                let sending = send_client_frames(&bus, client, &send.frames, fd, budget.as_ref());
                let result = tokio::select! {
                    _ = cancel.cancelled() => return,
                    _ = tx.closed() => return,
                    r = sending => r,
                };
                (
                    send.sequence,
                    result
                        .map(|()| send.frames.len())
                        .map_err(|r| (r.sent, r.total, r.error)),
                )
            }
            Ok(Some(pb::AttachRequest {
                message: Some(Message::Cyclic(c)),
            })) => {
                let result =
                    attach_cyclic(&mut cyclic, &c, &bus, client, fd, budget.as_ref(), &cancel);
                (
                    c.sequence,
                    result.map(|()| 0).map_err(|e| (0, c.frames.len(), e)),
                )
            }
            Ok(Some(pb::AttachRequest {
                message: Some(Message::CyclicStop(stop)),
            })) => {
                // Stopping a job that does not run is no error: it does not
                // run afterwards either way.
                if let Some(j) = &cyclic {
                    let _ = j.stop(stop.job);
                }
                (stop.sequence, Ok(0))
            }
            Ok(Some(pb::AttachRequest { message })) => {
                let what = if message.is_some() {
                    "a second AttachOpen: the stream is open already"
                } else {
                    "a message with neither open nor send"
                };
                let _ = tokio::time::timeout(
                    Duration::from_secs(1),
                    tx.send(Err(attach_protocol(what))),
                )
                .await;
                return;
            }
            Ok(None) => {
                // Half-closed: nothing more to send; receiving and the
                // cyclic jobs go on.
                half_closed = true;
                continue;
            }
            // The client went away (cancelled, reset: nobody to tell), or
            // its messages failed (too large, undecodable): the stream ends
            // with that status.
            Err(status) => {
                let _ = tokio::time::timeout(Duration::from_secs(1), tx.send(Err(status))).await;
                return;
            }
        };
        // Every message is answered: done, or refused with the reason.
        let event = match answer {
            Ok(sent) => pb::AttachEvent {
                event: Some(pb::attach_event::Event::Done(pb::SendDone {
                    sequence,
                    sent: sent as u32,
                })),
            },
            Err((sent, total, error)) => send_refused_to_pb(sequence, sent, total, &error),
        };
        let message = pb::AttachResponse {
            events: vec![event],
        };
        tokio::select! {
            _ = cancel.cancelled() => return,
            r = tx.send(Ok(message)) => if r.is_err() { return },
        }
    }
}

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
        let who = super::caller(&req);
        let budget = req.extensions().get::<FrameBudget>().cloned();
        let req = req.into_inner();
        let bus = self.gateway.bus(&req.bus)?;
        // This call is one sender, as one socket is.
        let client = ClientId::next();
        let _name = self.senders.register(client, who);
        send_client_frames(bus, client, &req.frames, true, budget.as_ref())
            .await
            .map_err(|r| r.error)?;
        Ok(Response::new(pb::SendFramesResponse {
            sent: req.frames.len() as u32,
        }))
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
        let batching = Batching::from_request(req.max_batch, req.low_latency);
        let selector = FrameSelector {
            filters,
            error_frames: req.include_error_frames,
            transmitted: req.include_transmitted,
        };
        let sub = bus.subscribe(selector, queue);
        let cancel = self.gateway.shutdown_token();
        // A small channel: when the client reads slowly, back-pressure reaches
        // the subscription, whose drops are counted and reported in-stream.
        let (tx, rx) = mpsc::channel::<Result<pb::StreamFramesResponse, Status>>(4);
        let stats = bus.stats();
        let first = pb::StreamFramesResponse {
            events: vec![pb::StreamEvent {
                event: Some(pb::stream_event::Event::State(status_to_pb(
                    stats.status,
                    stats.status_since.as_nanos(),
                ))),
            }],
        };
        let mut name_of = self.senders.lookup();
        spawn_subscription_forward(
            sub,
            bus,
            tx,
            vec![first],
            batching,
            cancel,
            AtShutdown::End,
            move |items, since| pb::StreamFramesResponse {
                events: items
                    .iter()
                    .map(|i| item_to_pb(i, since, &mut name_of))
                    .collect(),
            },
            queue_reservation,
        );
        Ok(Response::new(Box::pin(
            tokio_stream::wrappers::ReceiverStream::new(rx),
        )))
    }

    type AttachStream = Pin<Box<dyn Stream<Item = Result<pb::AttachResponse, Status>> + Send>>;

    async fn attach(
        &self,
        req: Request<tonic::Streaming<pb::AttachRequest>>,
    ) -> Result<Response<Self::AttachStream>, Status> {
        use pb::attach_request::Message;
        let who = super::caller(&req);
        let budget = req.extensions().get::<FrameBudget>().cloned();
        let queue_budget = req.extensions().get::<StreamQueueBudget>().cloned();
        let mut inbound = req.into_inner();
        let cancel = self.gateway.shutdown_token();
        let first = tokio::select! {
            _ = cancel.cancelled() => return Err(ApiError::ShuttingDown.into()),
            m = tokio::time::timeout(ATTACH_OPEN_TIMEOUT, inbound.message()) => m,
        };
        let open = match first {
            Err(_) => {
                return Err(attach_protocol(format!(
                    "no AttachOpen within {} s",
                    ATTACH_OPEN_TIMEOUT.as_secs()
                )));
            }
            Ok(Err(status)) => return Err(status),
            Ok(Ok(None)) => {
                return Err(attach_protocol(
                    "the client ended its messages before an AttachOpen",
                ));
            }
            Ok(Ok(Some(pb::AttachRequest {
                message: Some(Message::Open(open)),
            }))) => open,
            Ok(Ok(Some(_))) => {
                return Err(attach_protocol("the first message must be an AttachOpen"));
            }
        };
        let bus = self.gateway.bus(&open.bus)?.clone();
        let filters = open
            .filters
            .iter()
            .map(filter_from_pb)
            .collect::<Result<Vec<_>, _>>()?;
        if open.fd && !bus.info().fd {
            return Err(ApiError::refused(
                Code::InvalidArgument,
                "CAN_FD_NOT_SUPPORTED",
                format!(
                    "bus {} is not configured for CAN FD; attach without fd",
                    bus.name()
                ),
                vec![("bus", bus.name().to_string())],
            )
            .into());
        }
        let batching = Batching::from_request(open.max_batch, open.low_latency);
        // The queue comes out of the caller's budget ([security.limits]).
        let (queue, queue_reservation) = crate::security::stream_queue_from(
            queue_budget.as_ref(),
            open.queue_length,
            DEFAULT_STREAM_QUEUE,
            MAX_STREAM_QUEUE,
        )?;
        let client = ClientId::next();
        let name = self.senders.register(client, who.clone());
        let sub = bus.attach(
            client,
            AttachOptions {
                selector: FrameSelector {
                    filters,
                    error_frames: open.include_error_frames,
                    transmitted: true,
                },
                receive_own: open.receive_own,
                fd: open.fd,
                queue,
            },
        );
        let stats = bus.stats();
        let first = pb::AttachResponse {
            events: vec![
                pb::AttachEvent {
                    event: Some(pb::attach_event::Event::Opened(pb::AttachOpened {
                        bus: Some(bus_info_to_pb(bus.info(), &stats)),
                        sender_id: client.get(),
                        client: who,
                        queue_length: queue as u32,
                    })),
                },
                pb::AttachEvent {
                    event: Some(pb::attach_event::Event::State(status_to_pb(
                        stats.status,
                        stats.status_since.as_nanos(),
                    ))),
                },
            ],
        };
        let (tx, rx) = mpsc::channel::<Result<pb::AttachResponse, Status>>(4);
        let mut name_of = self.senders.lookup();
        spawn_subscription_forward(
            sub,
            bus.clone(),
            tx.clone(),
            vec![first],
            batching,
            cancel.clone(),
            AtShutdown::Unavailable,
            move |items, since| pb::AttachResponse {
                events: items
                    .iter()
                    .map(|i| item_to_attach_pb(i, since, client, &mut name_of))
                    .collect(),
            },
            queue_reservation,
        );
        tokio::spawn(attach_sends(
            inbound, bus, client, open.fd, budget, tx, cancel, name,
        ));
        Ok(Response::new(Box::pin(
            tokio_stream::wrappers::ReceiverStream::new(rx),
        )))
    }
}

/// A refused (or part-sent) AttachSend as its in-stream notice: the
/// error's code, reason and metadata as the richer error model has them.
fn send_refused_to_pb(
    sequence: u64,
    sent: usize,
    total: usize,
    error: &ApiError,
) -> pb::AttachEvent {
    pb::AttachEvent {
        event: Some(pb::attach_event::Event::Refused(pb::SendRefused {
            sequence,
            sent: sent as u32,
            total: total as u32,
            code: error.code() as i32,
            message: error.to_string(),
            reason: error.reason(),
            metadata: error
                .metadata()
                .into_iter()
                .map(|(k, v)| (k.to_string(), v))
                .collect(),
        })),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::time::Instant;

    #[test]
    fn small_messages_go_at_once_for_a_burst_then_at_the_refill_rate() {
        let t0 = Instant::now();
        let mut p = SmallMessagePacer::new(false, t0);
        for _ in 0..SMALL_MESSAGE_BURST as usize {
            assert_eq!(p.linger(t0, 1, COALESCE_EVENTS), None);
        }
        assert_eq!(p.linger(t0, 1, COALESCE_EVENTS), Some(COALESCE_LINGER));
        // A message of enough events never waits.
        assert_eq!(p.linger(t0, COALESCE_EVENTS, COALESCE_EVENTS), None);
        // One small message per 1/SMALL_MESSAGES_PER_S.
        let step = Duration::from_secs_f64(1.0 / SMALL_MESSAGES_PER_S);
        assert_eq!(p.linger(t0 + step, 1, COALESCE_EVENTS), None);
        assert_eq!(
            p.linger(t0 + step, 1, COALESCE_EVENTS),
            Some(COALESCE_LINGER)
        );
        // A long pause refills the burst, no more.
        let later = t0 + Duration::from_secs(3600);
        for _ in 0..SMALL_MESSAGE_BURST as usize {
            assert_eq!(p.linger(later, 1, COALESCE_EVENTS), None);
        }
        assert_eq!(p.linger(later, 1, COALESCE_EVENTS), Some(COALESCE_LINGER));
    }

    #[test]
    fn a_low_latency_reader_never_waits() {
        let t0 = Instant::now();
        let mut p = SmallMessagePacer::new(true, t0);
        for _ in 0..10 * SMALL_MESSAGE_BURST as usize {
            assert_eq!(p.linger(t0, 1, COALESCE_EVENTS), None);
        }
    }

    #[test]
    fn batching_defaults_and_caps_max_batch() {
        assert_eq!(Batching::from_request(0, false).max_batch, MAX_STREAM_BATCH);
        assert_eq!(Batching::from_request(5, true).max_batch, 5);
        assert_eq!(
            Batching::from_request(u32::MAX, false).max_batch,
            MAX_STREAM_BATCH
        );
        assert!(Batching::from_request(0, true).low_latency);
    }
}
