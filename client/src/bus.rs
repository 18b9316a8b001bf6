//! The Bus service: list, get, send, stream frames, attach as a bus
//! participant.

use crate::error::Error;
use crate::streams::{self, EventStream};
use crate::{Client, can, frame_to_pb, pb};
use futures::StreamExt;
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::{Notify, mpsc};

/// What to stream from a bus ([`Client::frames`]).
#[derive(Debug, Clone, Default)]
pub struct FrameStreamOptions {
    /// A frame passes if it matches any filter; none pass every frame.
    pub filters: Vec<can::Filter>,
    /// Also the frames the gateway's own protocol stacks send. (Frames
    /// other clients send come without it, as received frames marked with
    /// their sender.)
    pub include_transmitted: bool,
    /// Also SocketCAN error frames.
    pub include_error_frames: bool,
    /// Events the gateway buffers for this stream before it drops (and
    /// reports) frames; `None`: the gateway's default (8192).
    pub queue_length: Option<u32>,
    /// Every event at once, however small the message (the request's
    /// `low_latency`). Without it the gateway, after a burst, lets a few
    /// events wait up to 5 ms for more. This client tolerates small
    /// messages (its stream window bounds what waits unread), but with
    /// more than two such streams on one connection a reader that pauses
    /// can exhaust the HTTP/2 limit on unread small frames and lose the
    /// connection: set it for request/response exchanges and live views.
    pub low_latency: bool,
}

/// One item of a frame stream.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum FrameEvent {
    /// A frame that passed the filters, with its timestamp.
    Frame {
        /// The frame.
        frame: can::Frame,
        /// True when the gateway's own protocol stacks sent it; false when
        /// it was received (from another node, or from a client: see
        /// `origin`).
        transmitted: bool,
        /// Who put it on the bus.
        origin: pb::FrameOrigin,
        /// With [`pb::FrameOrigin::Client`]: which client call sent it.
        sender: Option<pb::FrameSender>,
    },
    /// The gateway dropped this many frames for this stream here (it was
    /// read too slowly), or the kernel dropped them before the gateway
    /// read them.
    Lost(u64),
    /// The bus state (also the first item of every stream).
    State(pb::BusStatus),
}

impl FrameEvent {
    fn from_pb(e: pb::StreamEvent) -> Option<FrameEvent> {
        use pb::stream_event::Event;
        Some(match e.event? {
            Event::Frame(f) => FrameEvent::Frame {
                transmitted: f.direction == pb::Direction::Tx as i32,
                origin: f.origin(),
                frame: crate::frame_from_pb(&f)?,
                sender: f.sender,
            },
            Event::Lost(l) => FrameEvent::Lost(l.count),
            Event::State(s) => FrameEvent::State(s),
        })
    }
}

/// How a client attaches to a bus ([`Client::attach`]).
#[derive(Debug, Clone, Default)]
pub struct AttachOptions {
    /// Frames to receive: a frame passes if it matches any filter; none
    /// pass every frame. What it sends is not filtered.
    pub filters: Vec<can::Filter>,
    /// Also receive its own frames once they went out (as
    /// `AttachEvent::Frame { own: true, .. }`).
    pub receive_own: bool,
    /// Receive and send CAN FD frames (the bus must be an FD bus).
    pub fd: bool,
    /// Also receive SocketCAN error frames.
    pub include_error_frames: bool,
    /// Events the gateway buffers for it before it drops (and reports)
    /// frames; `None`: the gateway's default (8192).
    pub queue_length: Option<u32>,
    /// Every event at once, however small the message (the request's
    /// `low_latency`). Without it the gateway, after a burst, lets a few
    /// events wait up to 5 ms for more. This client tolerates small
    /// messages (its stream window bounds what waits unread), but with
    /// more than two such streams on one connection a reader that pauses
    /// can exhaust the HTTP/2 limit on unread small frames and lose the
    /// connection: set it for request/response exchanges and live views.
    pub low_latency: bool,
}

/// One item an attached client receives ([`Attachment::events`]).
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum AttachEvent {
    /// A frame on the bus that passed the filters, with its timestamp.
    Frame {
        /// The frame.
        frame: can::Frame,
        /// True for this client's own frame (only with
        /// [`AttachOptions::receive_own`]); false for everything it
        /// received.
        own: bool,
        /// Who put it on the bus: another node, the gateway's own stacks,
        /// a client (this one, when `own`).
        origin: pb::FrameOrigin,
        /// With [`pb::FrameOrigin::Client`]: which client call sent it.
        sender: Option<pb::FrameSender>,
    },
    /// The gateway dropped this many frames for this client here (it read
    /// too slowly), or the kernel dropped them before the gateway read
    /// them.
    Lost(u64),
    /// The bus state (also the first item).
    State(pb::BusStatus),
    /// A batch this client sent was refused, or failed part-way: the
    /// sequence number [`AttachSender::send`] returned for it, the frames
    /// sent, and the code, reason and metadata of the richer error model.
    /// (The call that waited for the batch, [`AttachSender::send_confirmed`]
    /// or [`AttachSender::flush`], also returns it as an error.)
    Refused(pb::SendRefused),
    /// A cyclic job of this client ([`AttachSender::start_cyclic`]) ended
    /// by itself: its duration passed (code 0), or one of its frames was
    /// refused (the code and reason of the refusal).
    CyclicStopped(pb::CyclicStopped),
}

impl AttachEvent {
    fn from_pb(e: pb::AttachEvent) -> Option<AttachEvent> {
        use pb::attach_event::Event;
        Some(match e.event? {
            Event::Frame(f) => AttachEvent::Frame {
                own: f.direction == pb::Direction::Tx as i32,
                origin: f.origin(),
                frame: crate::frame_from_pb(&f)?,
                sender: f.sender,
            },
            Event::Lost(l) => AttachEvent::Lost(l.count),
            Event::State(s) => AttachEvent::State(s),
            Event::Refused(r) => AttachEvent::Refused(r),
            Event::CyclicStopped(c) => AttachEvent::CyclicStopped(c),
            // Acknowledgements are the sender's business (see
            // AttachSender::send_confirmed), not events.
            Event::Opened(_) | Event::Done(_) => return None,
        })
    }
}

/// A client attached to a bus as a participant ([`Client::attach`]): what
/// it sends with [`Attachment::sender`] reaches the wire, the gateway's own
/// protocol stacks and the other clients' streams; [`Attachment::events`]
/// delivers what the bus carries. Dropping both ends the attachment.
///
/// The gateway answers every batch sent with an acknowledgement once its
/// frames went out, or a refusal (`SendDone`, `SendRefused` in bus.proto),
/// in the same stream as the events: a task of the attachment reads it,
/// keeps the answers for the sender and passes the events on. While
/// `events` is held but not read, the answers wait behind the unread
/// events (and the gateway drops frames for this client as for any slow
/// reader); a program that only sends drops `events`. Dropping both ends
/// the call at once, batches still queued with it: call
/// [`AttachSender::flush`] first to know that everything sent went out.
pub struct Attachment {
    /// Sends frames (cloneable; dropping every clone ends this client's
    /// sending, receiving goes on).
    pub sender: AttachSender,
    /// What the bus delivers to this client, starting with the bus state.
    pub events: EventStream<AttachEvent>,
    /// The bus, as it was when the attachment opened.
    pub bus: pb::BusInfo,
    /// This attachment's sender number: the `FrameSender.id` the other
    /// receivers see on its frames.
    pub sender_id: u64,
    /// Who this client is to the others (`FrameSender.client`).
    pub client: String,
}

impl std::fmt::Debug for Attachment {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Attachment")
            .field("bus", &self.bus.name)
            .field("sender_id", &self.sender_id)
            .field("client", &self.client)
            .finish()
    }
}

/// The sending half of an [`Attachment`].
#[derive(Debug, Clone)]
pub struct AttachSender {
    shared: Arc<SenderShared>,
    /// Held by every clone: the reader task learns from its channel
    /// closing that nobody can send any more.
    _alive: mpsc::Sender<()>,
}

#[derive(Debug)]
struct SenderShared {
    tx: mpsc::Sender<pb::AttachRequest>,
    /// The next sequence number; taken under this lock together with the
    /// queueing of its message, so that messages leave in sequence order
    /// (the gateway answers them in the order sent).
    next: tokio::sync::Mutex<u64>,
    timeout: Option<Duration>,
    /// Shared with the stream's reader task (which must not hold `tx`:
    /// the last sender dropped ends the client's messages).
    answers: Arc<Answers>,
}

/// Most refusals of batches nobody waits for that are kept for
/// [`AttachSender::flush`]; older ones are only counted.
const KEPT_REFUSALS: usize = 1000;

/// The gateway's answers to this attachment's batches.
#[derive(Debug, Default)]
struct Answers {
    state: Mutex<AnswerState>,
    changed: Notify,
}

#[derive(Debug, Default)]
struct AnswerState {
    /// Every batch up to this sequence number was answered (done or
    /// refused): the gateway answers in order.
    answered: u64,
    /// Refusals no call has returned yet, by sequence number.
    refused: BTreeMap<u64, pb::SendRefused>,
    /// Refusals dropped from `refused` beyond [`KEPT_REFUSALS`].
    refusals_dropped: u64,
    /// Why the stream ended, once it did: no more answers come.
    ended: Option<String>,
}

impl Answers {
    fn lock(&self) -> std::sync::MutexGuard<'_, AnswerState> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn done(&self, sequence: u64) {
        let mut s = self.lock();
        s.answered = s.answered.max(sequence);
        drop(s);
        self.changed.notify_waiters();
    }

    fn refused(&self, r: &pb::SendRefused) {
        let mut s = self.lock();
        s.answered = s.answered.max(r.sequence);
        s.refused.insert(r.sequence, r.clone());
        while s.refused.len() > KEPT_REFUSALS {
            s.refused.pop_first();
            s.refusals_dropped += 1;
        }
        drop(s);
        self.changed.notify_waiters();
    }

    fn ended(&self, why: String) {
        self.lock().ended.get_or_insert(why);
        self.changed.notify_waiters();
    }

    /// Waits until every batch up to `sequence` is answered; `only`: the
    /// refusal of that batch alone counts, else the first refusal kept.
    async fn wait(&self, sequence: u64, only: bool) -> Result<(), Error> {
        loop {
            let changed = self.changed.notified();
            {
                let mut s = self.lock();
                let refusal = if only {
                    s.refused.remove(&sequence)
                } else {
                    s.refused.pop_first().map(|(_, r)| r)
                };
                if let Some(r) = refusal {
                    let more = std::mem::take(&mut s.refusals_dropped) as usize
                        + if only {
                            0
                        } else {
                            std::mem::take(&mut s.refused).len()
                        };
                    return Err(refusal_error(&r, more));
                }
                if s.answered >= sequence {
                    return Ok(());
                }
                if let Some(why) = &s.ended {
                    return Err(Error::Transport {
                        message: format!(
                            "the attachment's stream ended before batch {sequence} was \
                             acknowledged: {why}"
                        ),
                    });
                }
            }
            changed.await;
        }
    }
}

/// A refusal as the error of the call that waited for it: the gateway's
/// code, reason, message and metadata, as if the call had been refused
/// (`more`: other refusals reported with it).
fn refusal_error(r: &pb::SendRefused, more: usize) -> Error {
    use tonic_types::{ErrorDetails, StatusExt};
    let mut message = format!(
        "batch {} refused ({} of {} frames sent): {}",
        r.sequence, r.sent, r.total, r.message
    );
    if more > 0 {
        message.push_str(&format!(" (and {more} more batches refused)"));
    }
    let status = tonic::Status::with_error_details(
        tonic::Code::from_i32(r.code),
        message,
        ErrorDetails::with_error_info(r.reason.clone(), crate::ERROR_DOMAIN, r.metadata.clone()),
    );
    Error::from(status)
}

impl AttachSender {
    /// Sends frames, in order, after those sent before. Returns once the
    /// batch is on its way, with the sequence number a refusal of it will
    /// carry ([`AttachEvent::Refused`]): the gateway reports refusals (a
    /// malformed frame, the raw frame budget spent, bus-off) in the event
    /// stream, and [`AttachSender::flush`] returns them. Waits while the
    /// gateway holds earlier batches back (its pacing of client frames
    /// reaches here as flow control), at most the client's request
    /// timeout. [`AttachSender::send_confirmed`] waits until the frames
    /// are out.
    pub async fn send(&self, frames: &[can::Frame]) -> Result<u64, Error> {
        self.send_pb(frames.iter().map(frame_to_pb).collect()).await
    }

    /// [`AttachSender::send`] with protobuf frames as given (no local
    /// validation).
    pub async fn send_pb(&self, frames: Vec<pb::Frame>) -> Result<u64, Error> {
        let queue = async {
            let mut next = self.shared.next.lock().await;
            let sequence = *next;
            let msg = pb::AttachRequest {
                message: Some(pb::attach_request::Message::Send(pb::AttachSend {
                    frames,
                    sequence,
                })),
            };
            self.shared
                .tx
                .send(msg)
                .await
                .map_err(|_| Error::Transport {
                    message: "the attachment's stream has ended".into(),
                })?;
            *next += 1;
            Ok(sequence)
        };
        match self.shared.timeout {
            Some(limit) => tokio::time::timeout(limit, queue)
                .await
                .map_err(|_| Error::client_timeout("Attach send", limit))?,
            None => queue.await,
        }
    }

    /// Sends frames and waits until the gateway acknowledged that they all
    /// went out (handed to the interface, as `SendFrames` returns), at most
    /// the client's request timeout. A refusal of this batch is its error,
    /// with the gateway's code, reason and metadata (see
    /// [`Error::reason`]); the batch's sequence number otherwise.
    pub async fn send_confirmed(&self, frames: &[can::Frame]) -> Result<u64, Error> {
        self.send_pb_confirmed(frames.iter().map(frame_to_pb).collect())
            .await
    }

    /// [`AttachSender::send_confirmed`] with protobuf frames as given (no
    /// local validation).
    pub async fn send_pb_confirmed(&self, frames: Vec<pb::Frame>) -> Result<u64, Error> {
        let sequence = self.send_pb(frames).await?;
        self.wait(sequence, true).await?;
        Ok(sequence)
    }

    /// Waits until every batch sent so far (by any clone) was answered by
    /// the gateway, at most the client's request timeout. Returns the
    /// first refusal that no call returned yet (of a batch sent with
    /// [`AttachSender::send`]; the error says how many more there were),
    /// once: a program that sends without waiting and flushes at the end
    /// learns that something was not sent.
    pub async fn flush(&self) -> Result<(), Error> {
        let last = *self.shared.next.lock().await - 1;
        self.wait(last, false).await
    }

    /// Starts (or restarts, replacing it) the cyclic job `job`, which the
    /// gateway runs for this client: `frames` in turn, one every
    /// `interval`, the first one interval from now, until `duration` has
    /// passed (None: until stopped) or the attachment ends (see
    /// `AttachCyclic` in bus.proto). Waits until the gateway took it, at
    /// most the client's request timeout; its refusal is the error.
    pub async fn start_cyclic(
        &self,
        job: u32,
        frames: &[can::Frame],
        interval: Duration,
        duration: Option<Duration>,
    ) -> Result<(), Error> {
        let cyclic = pb::AttachCyclic {
            job,
            frames: frames.iter().map(frame_to_pb).collect(),
            interval_ns: interval.as_nanos().max(1) as u64,
            duration_ns: duration.map_or(0, |d| d.as_nanos().max(1) as u64),
            sequence: 0,
        };
        self.request_confirmed(pb::attach_request::Message::Cyclic(cyclic))
            .await
    }

    /// Changes the frames of the running cyclic job `job`, its timer going
    /// on; waits as [`AttachSender::start_cyclic`] does.
    pub async fn modify_cyclic(&self, job: u32, frames: &[can::Frame]) -> Result<(), Error> {
        let cyclic = pb::AttachCyclic {
            job,
            frames: frames.iter().map(frame_to_pb).collect(),
            interval_ns: 0,
            duration_ns: 0,
            sequence: 0,
        };
        self.request_confirmed(pb::attach_request::Message::Cyclic(cyclic))
            .await
    }

    /// Stops the cyclic job `job` (one that does not run is no error);
    /// once this returns, none of its frames is sent any more.
    pub async fn stop_cyclic(&self, job: u32) -> Result<(), Error> {
        let stop = pb::AttachCyclicStop { job, sequence: 0 };
        self.request_confirmed(pb::attach_request::Message::CyclicStop(stop))
            .await
    }

    /// Queues a message with the next sequence number and waits for its
    /// answer.
    async fn request_confirmed(
        &self,
        mut message: pb::attach_request::Message,
    ) -> Result<(), Error> {
        let queue = async {
            let mut next = self.shared.next.lock().await;
            let sequence = *next;
            match &mut message {
                pb::attach_request::Message::Cyclic(c) => c.sequence = sequence,
                pb::attach_request::Message::CyclicStop(c) => c.sequence = sequence,
                pb::attach_request::Message::Send(s) => s.sequence = sequence,
                pb::attach_request::Message::Open(_) => {}
            }
            let msg = pb::AttachRequest {
                message: Some(message),
            };
            self.shared
                .tx
                .send(msg)
                .await
                .map_err(|_| Error::Transport {
                    message: "the attachment's stream has ended".into(),
                })?;
            *next += 1;
            Ok::<u64, Error>(sequence)
        };
        let sequence = match self.shared.timeout {
            Some(limit) => tokio::time::timeout(limit, queue)
                .await
                .map_err(|_| Error::client_timeout("Attach send", limit))?,
            None => queue.await,
        }?;
        self.wait(sequence, true).await
    }

    async fn wait(&self, sequence: u64, only: bool) -> Result<(), Error> {
        let waiting = self.shared.answers.wait(sequence, only);
        match self.shared.timeout {
            Some(limit) => tokio::time::timeout(limit, waiting)
                .await
                .map_err(|_| Error::client_timeout("Attach acknowledgement", limit))?,
            None => waiting.await,
        }
    }
}

/// Reads an Attach stream: answers to the sender, the rest to `events`
/// (while anyone holds it; when nobody does, they are dropped). Ends when
/// the stream does, or when nobody can send and nobody receives (which
/// ends the call).
async fn read_attach_stream(
    mut stream: tonic::Streaming<pb::AttachResponse>,
    answers: Arc<Answers>,
    events: mpsc::Sender<Vec<Result<AttachEvent, Error>>>,
    mut alive: mpsc::Receiver<()>,
) {
    use pb::attach_event::Event;
    let mut senders_gone = false;
    loop {
        let message = tokio::select! {
            m = stream.message() => m,
            _ = alive.recv(), if !senders_gone => {
                senders_gone = true;
                if events.is_closed() { break }
                continue;
            }
            _ = events.closed(), if senders_gone => break,
        };
        let batch = match message {
            Ok(Some(m)) => m,
            Ok(None) => {
                answers.ended("the gateway ended the stream".into());
                break;
            }
            Err(status) => {
                let e = Error::from(status);
                answers.ended(e.to_string());
                let _ = events.send(vec![Err(e)]).await;
                break;
            }
        };
        let mut items = Vec::with_capacity(batch.events.len());
        for e in batch.events {
            match &e.event {
                Some(Event::Done(d)) => answers.done(d.sequence),
                Some(Event::Refused(r)) => answers.refused(r),
                _ => {}
            }
            if let Some(item) = AttachEvent::from_pb(e) {
                items.push(Ok(item));
            }
        }
        if !items.is_empty() && !events.is_closed() {
            // Waits while the events are not read (flow control reaches
            // the gateway); fails once nobody holds them.
            let _ = events.send(items).await;
        }
    }
    answers.ended("the attachment was closed".into());
}

impl Client {
    /// Attaches to a bus as another node on it (see `Bus.Attach` in
    /// bus.proto): returns once the gateway opened the attachment, with
    /// the sending half and the stream of what the bus delivers.
    ///
    /// ```no_run
    /// # async fn demo(client: cangate_client::Client) -> Result<(), cangate_client::Error> {
    /// use cangate_client::{AttachEvent, AttachOptions};
    /// use futures::StreamExt;
    /// let mut node = client.attach("can0", &AttachOptions::default()).await?;
    /// node.sender.send(&["581#4B00100000000000".parse().unwrap()]).await?;
    /// while let Some(event) = node.events.next().await {
    ///     if let AttachEvent::Frame { frame, .. } = event? {
    ///         println!("{frame}");
    ///     }
    /// }
    /// # Ok(()) }
    /// ```
    pub async fn attach(&self, bus: &str, options: &AttachOptions) -> Result<Attachment, Error> {
        let (tx, rx) = mpsc::channel::<pb::AttachRequest>(16);
        let open = pb::AttachRequest {
            message: Some(pb::attach_request::Message::Open(pb::AttachOpen {
                bus: bus.to_string(),
                filters: options.filters.iter().map(crate::filter_to_pb).collect(),
                receive_own: options.receive_own,
                fd: options.fd,
                include_error_frames: options.include_error_frames,
                max_batch: 0,
                queue_length: options.queue_length.unwrap_or(0),
                low_latency: options.low_latency,
            })),
        };
        tx.try_send(open).map_err(|_| Error::Transport {
            message: "cannot queue the attachment's opening".into(),
        })?;
        let outbound =
            futures::stream::unfold(rx, |mut rx| async move { rx.recv().await.map(|m| (m, rx)) });
        let mut stream = self
            .call("Attach", None, self.bus_client().attach(outbound))
            .await?;
        let first = match self.request_timeout() {
            Some(limit) => tokio::time::timeout(limit, stream.message())
                .await
                .map_err(|_| Error::client_timeout("Attach", limit))?,
            None => stream.message().await,
        }
        .map_err(Error::from)?
        .ok_or_else(|| Error::Transport {
            message: "the gateway ended the Attach stream before opening it".into(),
        })?;
        let mut events = first.events.into_iter();
        let Some(pb::attach_event::Event::Opened(opened)) = events.next().and_then(|e| e.event)
        else {
            return Err(Error::Transport {
                message: "the Attach stream did not start with AttachOpened".into(),
            });
        };
        let rest: Vec<Result<AttachEvent, Error>> =
            events.filter_map(AttachEvent::from_pb).map(Ok).collect();
        let answers = Arc::new(Answers::default());
        let shared = Arc::new(SenderShared {
            tx,
            next: tokio::sync::Mutex::new(1),
            timeout: self.request_timeout(),
            answers: answers.clone(),
        });
        // As many batches of events as the gateway's own forwarding holds:
        // a reader that pauses is felt by the gateway at once.
        let (events_tx, events_rx) = mpsc::channel(4);
        let (alive, alive_rx) = mpsc::channel(1);
        tokio::spawn(read_attach_stream(stream, answers, events_tx, alive_rx));
        let later = futures::stream::unfold(events_rx, |mut rx| async move {
            rx.recv()
                .await
                .map(|batch| (futures::stream::iter(batch), rx))
        })
        .flatten();
        Ok(Attachment {
            sender: AttachSender {
                shared,
                _alive: alive,
            },
            events: futures::stream::iter(rest).chain(later).boxed(),
            bus: opened.bus.unwrap_or_default(),
            sender_id: opened.sender_id,
            client: opened.client,
        })
    }

    /// Every bus with live statistics.
    pub async fn list_buses(&mut self) -> Result<Vec<pb::BusInfo>, Error> {
        let r = self
            .call(
                "ListBuses",
                None,
                self.bus_client().list_buses(pb::ListBusesRequest {}),
            )
            .await?;
        Ok(r.buses)
    }

    /// One bus.
    pub async fn get_bus(&mut self, bus: &str) -> Result<pb::BusInfo, Error> {
        let req = pb::GetBusRequest {
            bus: bus.to_string(),
        };
        self.call("GetBus", None, self.bus_client().get_bus(req))
            .await
    }

    /// Sends frames in order on a bus; the number sent (all of them).
    pub async fn send(&mut self, bus: &str, frames: &[can::Frame]) -> Result<u32, Error> {
        self.send_pb(bus, frames.iter().map(frame_to_pb).collect())
            .await
    }

    /// Sends protobuf frames as given (no local validation).
    pub async fn send_pb(&mut self, bus: &str, frames: Vec<pb::Frame>) -> Result<u32, Error> {
        let req = pb::SendFramesRequest {
            bus: bus.to_string(),
            frames,
        };
        let r = self
            .call("SendFrames", None, self.bus_client().send_frames(req))
            .await?;
        Ok(r.sent)
    }

    /// Opens a frame stream (the generated one: batches of events).
    pub async fn stream_frames(
        &mut self,
        request: pb::StreamFramesRequest,
    ) -> Result<tonic::Streaming<pb::StreamFramesResponse>, Error> {
        self.call(
            "StreamFrames",
            None,
            self.bus_client().stream_frames(request),
        )
        .await
    }

    /// The frames, losses and state changes of a bus, one item each, as
    /// they happen (starting with the bus state).
    pub async fn frames(
        &self,
        bus: &str,
        options: &FrameStreamOptions,
    ) -> Result<EventStream<FrameEvent>, Error> {
        let req = pb::StreamFramesRequest {
            bus: bus.to_string(),
            filters: options.filters.iter().map(crate::filter_to_pb).collect(),
            include_transmitted: options.include_transmitted,
            include_error_frames: options.include_error_frames,
            max_batch: 0,
            queue_length: options.queue_length.unwrap_or(0),
            low_latency: options.low_latency,
        };
        let s = self
            .call("StreamFrames", None, self.bus_client().stream_frames(req))
            .await?;
        Ok(streams::flat_map(s, |batch: pb::StreamFramesResponse| {
            batch
                .events
                .into_iter()
                .filter_map(FrameEvent::from_pb)
                .collect::<Vec<_>>()
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stream_events_become_frame_events() {
        use pb::stream_event::Event;
        let frame: can::Frame = "123#DEADBEEF".parse().unwrap();
        let mut p = frame_to_pb(&frame);
        p.direction = pb::Direction::Tx as i32;
        let e = FrameEvent::from_pb(pb::StreamEvent {
            event: Some(Event::Frame(p)),
        })
        .unwrap();
        assert_eq!(
            e,
            FrameEvent::Frame {
                frame,
                transmitted: true,
                origin: pb::FrameOrigin::Unspecified,
                sender: None,
            }
        );
        let lost = FrameEvent::from_pb(pb::StreamEvent {
            event: Some(Event::Lost(pb::FramesLost { count: 3 })),
        });
        assert_eq!(lost, Some(FrameEvent::Lost(3)));
        assert_eq!(FrameEvent::from_pb(pb::StreamEvent { event: None }), None);
    }
}
