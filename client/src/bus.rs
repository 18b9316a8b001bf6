//! The Bus service: list, get, send, stream frames, attach as a bus
//! participant.

use crate::error::Error;
use crate::streams::{self, EventStream};
use crate::{Client, can, frame_to_pb, pb};
use futures::StreamExt;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use tokio::sync::mpsc;

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
    Refused(pb::SendRefused),
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
            Event::Opened(_) => return None,
        })
    }
}

/// A client attached to a bus as a participant ([`Client::attach`]): what
/// it sends with [`Attachment::sender`] reaches the wire, the gateway's own
/// protocol stacks and the other clients' streams; [`Attachment::events`]
/// delivers what the bus carries. Dropping both ends the attachment.
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
    tx: mpsc::Sender<pb::AttachRequest>,
    next: Arc<AtomicU64>,
    timeout: Option<Duration>,
}

impl AttachSender {
    /// Sends frames, in order, after those sent before. Returns once the
    /// batch is on its way, with the sequence number a refusal of it will
    /// carry ([`AttachEvent::Refused`]): the gateway reports refusals (a
    /// malformed frame, the raw frame budget spent, bus-off) in the event
    /// stream, not here. Waits while the gateway holds earlier batches back
    /// (its pacing of client frames reaches here as flow control), at most
    /// the client's request timeout.
    pub async fn send(&self, frames: &[can::Frame]) -> Result<u64, Error> {
        self.send_pb(frames.iter().map(frame_to_pb).collect()).await
    }

    /// [`AttachSender::send`] with protobuf frames as given (no local
    /// validation).
    pub async fn send_pb(&self, frames: Vec<pb::Frame>) -> Result<u64, Error> {
        let sequence = self.next.fetch_add(1, Ordering::Relaxed);
        let msg = pb::AttachRequest {
            message: Some(pb::attach_request::Message::Send(pb::AttachSend {
                frames,
                sequence,
            })),
        };
        let gone = || Error::Transport {
            message: "the attachment's stream has ended".into(),
        };
        match self.timeout {
            Some(limit) => tokio::time::timeout(limit, self.tx.send(msg))
                .await
                .map_err(|_| Error::client_timeout("Attach send", limit))?
                .map_err(|_| gone())?,
            None => self.tx.send(msg).await.map_err(|_| gone())?,
        }
        Ok(sequence)
    }
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
        let later = streams::flat_map(stream, |batch: pb::AttachResponse| {
            batch
                .events
                .into_iter()
                .filter_map(AttachEvent::from_pb)
                .collect::<Vec<_>>()
        });
        Ok(Attachment {
            sender: AttachSender {
                tx,
                next: Arc::new(AtomicU64::new(1)),
                timeout: self.request_timeout(),
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
