//! One owner task per bus, and the cheap handle everyone else uses.
//!
//! The owner task holds the backend (socket or virtual port). Senders go
//! through a bounded queue to it; received and transmitted frames fan out to
//! any number of [`Subscription`]s, each with its own filter and bounded
//! queue. A subscriber that does not keep up never slows the bus or the
//! other subscribers: the frames it misses are counted and, as soon as it has
//! room again, it receives a [`BusItem::Lost`] notice with the exact number
//! of matching frames it missed, in the position where they were missed.
//!
//! Clients of the gateway are participants of the bus, with the loopback
//! semantics of SocketCAN, which delivers the frames one socket sends to the
//! host's other sockets. A client's frames ([`BusHandle::send_as_client`])
//! are marked with its [`ClientId`] ([`Frame::sender`]) and go out in the
//! client class (see [`crate::budget`]); once they are on the bus (the
//! virtual bus's echo, stamped with their bus time; SocketCAN: when the
//! interface took them) the bus task delivers them, still marked, to every
//! other subscriber as received frames ([`Direction::Rx`]), whether or not
//! it asked for the gateway's own transmissions: so the gateway's protocol
//! stacks see them as they see a device's frames. The client's own
//! subscription ([`BusHandle::attach`]) gets them back only if it asked
//! ([`AttachOptions::receive_own`]), as [`Direction::Tx`]. An attached
//! client receives the gateway's own transmissions as any node would (they
//! come as [`Direction::Tx`] without a sender: the gateway's, not its own).

use crate::budget::{Pacer, TxClass, TxShares};
use crate::filter::{Filter, FrameSelector};
use crate::frame::{ClientId, Frame, Timestamp};
use crate::socketcan_bus::{SocketCanBus, SocketCanEvent};
use crate::state::BusStatus;
use crate::timing::{BitTiming, LoadMeter, Stuffing};
use crate::virtual_bus::{PortEvent, SendError, VirtualPort};
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::{mpsc, oneshot};
use tokio_util::sync::CancellationToken;

/// Which kind of backend a bus runs on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BackendKind {
    /// Linux SocketCAN interface.
    SocketCan,
    /// In-process virtual bus.
    Virtual,
}

/// Static description of a bus.
#[derive(Debug, Clone, PartialEq)]
pub struct BusInfo {
    /// Name clients use (e.g. `can0`).
    pub name: String,
    /// Backend kind.
    pub kind: BackendKind,
    /// Interface name (SocketCAN) or virtual bus name.
    pub interface: String,
    /// Whether CAN FD frames may be sent.
    pub fd: bool,
    /// Nominal bitrate in bit/s if known (used for the load figure).
    pub bitrate: Option<u32>,
    /// CAN FD data bitrate in bit/s if known.
    pub data_bitrate: Option<u32>,
    /// Whether the virtual bus models bit timing.
    pub bit_timed: bool,
    /// Stuff-bit counting used for the load figure (match the virtual bus's
    /// model; real controllers stuff exactly).
    pub stuffing: Stuffing,
}

/// The backend a bus task owns.
// One per bus, moved once into its task: the size difference costs nothing.
#[allow(clippy::large_enum_variant)]
pub enum Backend {
    /// A SocketCAN interface.
    SocketCan(SocketCanBus),
    /// A port on a virtual bus, connected with `echo_own = true` so that our
    /// own transmissions come back stamped with their bus time. The bus
    /// handle narrows that echo to the frames someone needs (see
    /// [`VirtualPort::set_echo_filters`]): the others would wake the bus
    /// task for nothing.
    Virtual(VirtualPort),
}

impl std::fmt::Debug for Backend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Backend::SocketCan(s) => s.fmt(f),
            Backend::Virtual(v) => v.fmt(f),
        }
    }
}

enum BackendEvent {
    Frame {
        frame: Frame,
        own: bool,
    },
    State(BusStatus),
    /// Received frames the kernel dropped before the gateway read them
    /// (SocketCAN), just before the next frame.
    Lost(u64),
    /// An own frame accepted for transmission (SocketCAN; the virtual bus
    /// counts at send time and echoes).
    Sent(Frame),
    /// Own frames given up (SocketCAN transmit queue).
    Unsent(u64),
}

impl Backend {
    /// Waits for events and appends them to `out`. `port_events` is the
    /// virtual port's receive buffer, owned by the caller so that it is
    /// allocated once, not at every wake-up (the bus task polls this anew
    /// each loop turn).
    async fn next(&mut self, out: &mut Vec<BackendEvent>, port_events: &mut Vec<PortEvent>) {
        match self {
            Backend::SocketCan(s) => out.push(match s.recv().await {
                SocketCanEvent::Frame(frame) => BackendEvent::Frame { frame, own: false },
                SocketCanEvent::State(st) => BackendEvent::State(st),
                SocketCanEvent::Lost(n) => BackendEvent::Lost(n),
                SocketCanEvent::Sent(frame) => BackendEvent::Sent(frame),
                SocketCanEvent::Unsent(n) => BackendEvent::Unsent(n),
            }),
            Backend::Virtual(p) => {
                p.recv_many(port_events, 256).await;
                out.extend(port_events.drain(..).map(|ev| match ev {
                    PortEvent::Frame { frame, own } => BackendEvent::Frame { frame, own },
                    PortEvent::State(st) => BackendEvent::State(st),
                }));
            }
        }
    }

    /// Sends a batch in order; on failure, how many went out and why.
    /// SocketCAN batches are queued instead (see [`SocketCanBus::queue`]).
    fn send_batch_in_lane(&mut self, frames: &[Frame], lane: u8) -> Result<(), (usize, SendError)> {
        match self {
            Backend::SocketCan(_) => Ok(()),
            Backend::Virtual(p) => p.send_batch_in_lane(frames, lane).map_err(|e| (0, e)),
        }
    }

    fn status(&self) -> BusStatus {
        match self {
            Backend::SocketCan(s) => s.status(),
            Backend::Virtual(p) => p.bus().status(),
        }
    }

    fn overflows(&self) -> u64 {
        match self {
            Backend::SocketCan(s) => s.rx_dropped(),
            Backend::Virtual(p) => p.overflows(),
        }
    }
}

/// Whether a subscriber received a frame or its side sent it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Received: from another node, or sent by a client of the gateway
    /// other than the subscriber's own ([`Frame::sender`] says which).
    Rx,
    /// Transmitted: by the gateway's own stacks (no [`Frame::sender`]), or,
    /// for an attached client's subscription, by that client itself.
    Tx,
}

/// How a client of the gateway attached to a bus receives
/// ([`BusHandle::attach`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AttachOptions {
    /// The frames it receives. `transmitted` is ignored: a participant
    /// receives the gateway's own transmissions as any node on the bus does.
    pub selector: FrameSelector,
    /// Also its own frames, once they are on the bus, as [`Direction::Tx`]
    /// (SocketCAN's `CAN_RAW_RECV_OWN_MSGS`).
    pub receive_own: bool,
    /// Whether CAN FD frames are delivered to it (SocketCAN's
    /// `CAN_RAW_FD_FRAMES`); without, they are left out like frames its
    /// filters do not pass.
    pub fd: bool,
    /// Items it may have queued before it starts losing frames.
    pub queue: usize,
}

/// What a subscription delivers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BusItem {
    /// A frame that passed the subscription's selector.
    Frame {
        /// The frame with its timestamp.
        frame: Frame,
        /// Received or transmitted.
        direction: Direction,
    },
    /// This many frames were dropped here: matching frames because the
    /// subscriber did not keep up, and (SocketCAN) frames the kernel
    /// dropped before the gateway read them, whatever their identifier.
    Lost(u64),
    /// The bus state changed.
    State(BusStatus),
}

/// A frame batch could not be sent completely.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{error} ({sent} of {total} frames sent)")]
pub struct SendFailure {
    /// Frames of the batch that were sent before the failure.
    pub sent: usize,
    /// Frames in the batch.
    pub total: usize,
    /// Why sending stopped.
    pub error: SendError,
}

/// A client's batch queued by [`BusHandle::queue_as_client`], whose
/// outcome is still to be learnt.
#[derive(Debug)]
pub struct PendingSend {
    state: Pending,
    bus: BusHandle,
    /// The bus's echo filter still counts this batch (a virtual bus).
    echo_open: bool,
    /// Set when this is dropped before the outcome is known: the bus task
    /// then withdraws the frames of the batch it has not sent yet.
    withdraw: Option<Arc<AtomicBool>>,
}

impl Drop for PendingSend {
    /// A batch given up before its outcome (the client cancelled its call
    /// or went away) is withdrawn: the frames still waiting for the share
    /// are never sent, and counted ([`BusStats::client_frames_withdrawn`]).
    fn drop(&mut self) {
        if let Pending::Waiting { rx, .. } = &mut self.state {
            if let Ok(r) = rx.try_recv() {
                let _ = self.settle(r);
                return;
            }
            if let Some(w) = &self.withdraw {
                w.store(true, Ordering::Release);
                // The bus task ends the echo count of what it withdraws.
                self.echo_open = false;
            }
        }
    }
}

#[derive(Debug)]
enum Pending {
    Done(Result<(), SendFailure>),
    Waiting {
        rx: oneshot::Receiver<Result<(), SendFailure>>,
        total: usize,
    },
}

impl PendingSend {
    /// The outcome, if it is known already (without waiting or being woken
    /// for it); `None`: still queued, ask again or await
    /// [`PendingSend::outcome`].
    pub fn try_outcome(&mut self) -> Option<Result<(), SendFailure>> {
        let r = match &mut self.state {
            Pending::Done(r) => r.clone(),
            Pending::Waiting { rx, total } => match rx.try_recv() {
                Ok(r) => r,
                Err(oneshot::error::TryRecvError::Empty) => return None,
                Err(oneshot::error::TryRecvError::Closed) => Err(self.bus.down(*total)),
            },
        };
        self.state = Pending::Done(r.clone());
        Some(self.settle(r))
    }

    /// What [`BusHandle::send_as_client`] would have returned.
    pub async fn outcome(mut self) -> Result<(), SendFailure> {
        self.wait().await
    }

    /// [`PendingSend::outcome`] without giving the batch up: cancel-safe
    /// (dropped before it is ready, it can be awaited or asked again).
    pub async fn wait(&mut self) -> Result<(), SendFailure> {
        let r = match &mut self.state {
            Pending::Done(r) => r.clone(),
            Pending::Waiting { rx, total } => {
                let total = *total;
                rx.await.unwrap_or_else(|_| Err(self.bus.down(total)))
            }
        };
        self.state = Pending::Done(r.clone());
        self.settle(r)
    }

    /// Frames that were not sent have no echo to wait for (counted once,
    /// however often the outcome is asked for).
    fn settle(&mut self, r: Result<(), SendFailure>) -> Result<(), SendFailure> {
        if std::mem::take(&mut self.echo_open)
            && let Err(f) = &r
        {
            client_echo_end(&self.bus.shared, (f.total - f.sent) as u64);
        }
        r
    }
}

/// Live counters of a bus.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BusStats {
    /// Frames received from other nodes (incl. error frames).
    pub rx_frames: u64,
    /// Frames sent by this gateway.
    pub tx_frames: u64,
    /// Payload bytes received.
    pub rx_bytes: u64,
    /// Payload bytes sent.
    pub tx_bytes: u64,
    /// Error frames received.
    pub error_frames: u64,
    /// Frames the backend refused to send, or gave up on (SocketCAN: held
    /// past the transmit timeout or pushed out of the full transmit queue).
    pub tx_failed: u64,
    /// SocketCAN: times a frame was refused for lack of room in the
    /// interface's queue (`ENOBUFS`) and kept for another attempt.
    pub tx_retries: u64,
    /// SocketCAN: own frames waiting for room in the interface's queue.
    pub tx_queued: u64,
    /// Frames lost before the gateway read them: the virtual bus's receive
    /// queue overflowed, or the kernel dropped them because the SocketCAN
    /// socket's receive buffer was full (`SO_RXQ_OVFL`). Every subscriber
    /// was told with a [`BusItem::Lost`] in its stream (SocketCAN).
    pub rx_overflows: u64,
    /// Frames dropped for subscribers that did not keep up (all subscribers).
    pub subscriber_drops: u64,
    /// Client raw frames held back by the bus's client share (see
    /// [`TxShares`]) before they went out.
    pub client_frames_delayed: u64,
    /// Client raw frames refused because too many were already waiting for
    /// the client share ([`MAX_BUDGET_QUEUED`]).
    pub client_frames_refused: u64,
    /// Client raw frames withdrawn before they went out: their sender gave
    /// the batch up (a cancelled call, a closed stream).
    pub client_frames_withdrawn: u64,
    /// Bulk frames (SDO block transfers) held back by the bus's bulk share.
    pub bulk_frames_delayed: u64,
    /// Client and bulk frames waiting right now for their share.
    pub budget_queued: u64,
    /// Bus load in percent over the last second (needs a bitrate).
    pub load_percent: f64,
    /// Current subscribers.
    pub subscribers: usize,
    /// State and error counters.
    pub status: BusStatus,
    /// When the state last changed.
    pub status_since: Timestamp,
}

struct Subscriber {
    selector: FrameSelector,
    /// The attached client this subscription belongs to: its own frames
    /// come back only with `receive_own`.
    client: Option<ClientId>,
    receive_own: bool,
    /// CAN FD frames are delivered (false only for an attached client that
    /// did not ask for them).
    fd: bool,
    tx: mpsc::Sender<BusItem>,
    pending_lost: u64,
    pending_state: bool,
    lost_total: Arc<AtomicU64>,
}

impl Subscriber {
    /// Offers an item; returns false if the subscriber is gone.
    fn offer(&mut self, item: BusItem, drops: &AtomicU64) -> bool {
        if self.pending_lost > 0 {
            match self.tx.try_send(BusItem::Lost(self.pending_lost)) {
                Ok(()) => self.pending_lost = 0,
                Err(mpsc::error::TrySendError::Full(_)) => {
                    self.count_lost(drops);
                    return true;
                }
                Err(mpsc::error::TrySendError::Closed(_)) => return false,
            }
        }
        match self.tx.try_send(item) {
            Ok(()) => true,
            Err(mpsc::error::TrySendError::Full(_)) => {
                self.count_lost(drops);
                true
            }
            Err(mpsc::error::TrySendError::Closed(_)) => false,
        }
    }

    fn count_lost(&mut self, drops: &AtomicU64) {
        self.pending_lost += 1;
        self.lost_total.fetch_add(1, Ordering::Relaxed);
        drops.fetch_add(1, Ordering::Relaxed);
    }

    /// Delivers pending notices if there is room now.
    fn flush(&mut self, status: BusStatus) -> bool {
        if self.pending_lost > 0 {
            match self.tx.try_send(BusItem::Lost(self.pending_lost)) {
                Ok(()) => self.pending_lost = 0,
                Err(mpsc::error::TrySendError::Full(_)) => return true,
                Err(mpsc::error::TrySendError::Closed(_)) => return false,
            }
        }
        if self.pending_state {
            match self.tx.try_send(BusItem::State(status)) {
                Ok(()) => self.pending_state = false,
                Err(mpsc::error::TrySendError::Full(_)) => return true,
                Err(mpsc::error::TrySendError::Closed(_)) => return false,
            }
        }
        !self.tx.is_closed()
    }
}

#[derive(Default)]
struct Counters {
    rx_frames: AtomicU64,
    tx_frames: AtomicU64,
    rx_bytes: AtomicU64,
    tx_bytes: AtomicU64,
    error_frames: AtomicU64,
    tx_failed: AtomicU64,
    tx_retries: AtomicU64,
    tx_queued: AtomicU64,
    rx_overflows: AtomicU64,
    subscriber_drops: AtomicU64,
    load_millipercent: AtomicU64,
    client_delayed: AtomicU64,
    client_refused: AtomicU64,
    client_withdrawn: AtomicU64,
    bulk_delayed: AtomicU64,
    budget_queued: AtomicU64,
    /// Client frames sent on a virtual bus whose echo has not come back
    /// yet; while there are any, the echo filter lets every own frame
    /// through (see [`client_echo_begin`]).
    client_echo: AtomicU64,
}

struct Shared {
    info: BusInfo,
    tx: mpsc::Sender<TxRequest>,
    /// Virtual buses are sent to directly from the caller's task: the
    /// virtual port is thread-safe, and skipping the hop through the bus
    /// task takes a task wake-up off every request/response exchange. The
    /// bus task still publishes the frames (as TX) from the bus's echo,
    /// whose filter, set through this sender, follows the subscribers (see
    /// [`update_echo`]).
    direct: Option<crate::virtual_bus::VirtualSender>,
    /// Guarded by this lock, as is the echo filter derived from them: a
    /// change and its filter update are one step, so two updates cannot
    /// land in the wrong order and leave a too narrow filter behind.
    subscribers: Mutex<Vec<Subscriber>>,
    counters: Counters,
    status: Mutex<(BusStatus, Timestamp)>,
    /// Client and bulk frames to the bus task, which paces them to their
    /// shares; `None` where they go as the gateway's own (see
    /// [`budgeted`]).
    paced: Option<mpsc::Sender<PacedRequest>>,
    /// [`TxShares::client_percent`] and [`TxShares::bulk_percent`], read
    /// by the bus task at every release, so a change applies at once.
    client_percent: AtomicU8,
    bulk_percent: AtomicU8,
}

/// Client or bulk frames waiting for their share of the bus.
struct PacedRequest {
    class: TxClass,
    frames: Vec<Frame>,
    /// Frames of `frames` released so far.
    released: usize,
    /// Whether the share held this request back at least once (its frames
    /// then count as delayed).
    held: bool,
    reply: Option<oneshot::Sender<Result<(), SendFailure>>>,
    /// Set by the [`PendingSend`] given up before the outcome: the frames
    /// not released yet are withdrawn.
    withdraw: Option<Arc<AtomicBool>>,
}

impl PacedRequest {
    fn withdrawn(&self) -> bool {
        self.withdraw
            .as_ref()
            .is_some_and(|w| w.load(Ordering::Acquire))
    }
}

/// Most bus time (at the bus's full rate) of one client batch queued at
/// once for the client share: longer batches go a chunk at a time (see
/// [`BusHandle::send_as_client`]). 20 ms: a few hundred frames, enough for
/// the share's full rate at every wake-up of the bus task, and a bounded
/// backlog, withdrawn at once when the client gives the batch up.
pub const CLIENT_CHUNK_BUS_TIME_NS: u64 = 20_000_000;

/// Most client or bulk frames that may wait for their share at once; a
/// client batch beyond it is refused (the gateway's memory is bounded by
/// configuration, not by callers).
pub const MAX_BUDGET_QUEUED: u64 = 50_000;

/// The largest burst of a share, in time of its pacer (see [`Pacer`]): the
/// bus task wakes about every millisecond (the timer's resolution) and
/// releases what accumulated, so a released chunk occupies the bus for at
/// most this times the share, plus one frame: a chunk of client frames that
/// win every arbitration holds a SYNC back by at most that (300 us at the
/// default 30 % share), well within its period.
const PACER_TOLERANCE_NS: u64 = 1_000_000;

/// Whether a bus paces client and bulk frames: where frames take time on a
/// wire (a SocketCAN interface with a known bitrate, a bit-timed virtual
/// bus). On a virtual bus without bit timing frames take no bus time, so
/// none can crowd out another.
fn budgeted(info: &BusInfo) -> bool {
    match info.kind {
        BackendKind::SocketCan => info.bitrate.is_some(),
        BackendKind::Virtual => info.bit_timed,
    }
}

/// The bus time a frame takes on a paced bus (see [`budgeted`]; a bit-timed
/// virtual bus without a configured bitrate runs at 1 Mbit/s).
fn pacing_timing(info: &BusInfo) -> BitTiming {
    let bitrate = info.bitrate.unwrap_or(1_000_000);
    BitTiming {
        bitrate,
        data_bitrate: info.data_bitrate.unwrap_or(bitrate),
        stuffing: info.stuffing,
    }
}

struct TxRequest {
    frames: Vec<Frame>,
    /// `None` for fire-and-forget submissions: failures are counted and
    /// logged by the bus task instead.
    reply: Option<oneshot::Sender<Result<(), SendFailure>>>,
}

/// A cloneable handle to a running bus.
#[derive(Clone)]
pub struct BusHandle {
    shared: Arc<Shared>,
}

impl std::fmt::Debug for BusHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BusHandle")
            .field("name", &self.shared.info.name)
            .finish()
    }
}

/// Frames a subscriber may have queued before it starts losing frames.
pub const DEFAULT_SUBSCRIPTION_QUEUE: usize = 8192;

impl BusHandle {
    /// Starts the owner task of a bus. The task ends when `cancel` fires,
    /// which also ends every subscription.
    pub fn spawn(
        info: BusInfo,
        backend: Backend,
        cancel: CancellationToken,
    ) -> (BusHandle, tokio::task::JoinHandle<()>) {
        let (tx, rx) = mpsc::channel(1024);
        let (paced, paced_rx) = if budgeted(&info) {
            let (tx, rx) = mpsc::channel(1024);
            (Some(tx), Some(rx))
        } else {
            (None, None)
        };
        let shares = TxShares::default();
        let status = backend.status();
        let direct = match &backend {
            Backend::Virtual(p) => Some(p.sender()),
            Backend::SocketCan(_) => None,
        };
        let shared = Arc::new(Shared {
            info,
            tx,
            direct,
            subscribers: Mutex::new(Vec::new()),
            counters: Counters::default(),
            status: Mutex::new((status, Timestamp::now())),
            paced,
            client_percent: AtomicU8::new(shares.client_percent),
            bulk_percent: AtomicU8::new(shares.bulk_percent),
        });
        // No subscribers yet: no echo unless the load meter needs it.
        update_echo(
            &shared,
            &shared.subscribers.lock().expect("subscriber lock"),
        );
        // Everything the bus task logs is in the bus's span.
        let span = tracing::info_span!("bus", bus = %shared.info.name);
        let task = tokio::spawn(tracing::Instrument::instrument(
            run_bus(backend, shared.clone(), rx, paced_rx, cancel),
            span,
        ));
        (BusHandle { shared }, task)
    }

    /// Static description.
    pub fn info(&self) -> &BusInfo {
        &self.shared.info
    }

    /// The bus name.
    pub fn name(&self) -> &str {
        &self.shared.info.name
    }

    /// Current state and error counters.
    pub fn status(&self) -> BusStatus {
        self.shared.status.lock().expect("status lock").0
    }

    /// Sets the shares of the bus's time that client raw frames and bulk
    /// transfers may use (effective for the next frames released). Only
    /// buses whose frames take time on a wire pace them (a SocketCAN
    /// interface with a bitrate, a bit-timed virtual bus).
    pub fn set_tx_shares(&self, shares: TxShares) -> Result<(), String> {
        shares.validate()?;
        let s = &self.shared;
        s.client_percent
            .store(shares.client_percent, Ordering::Relaxed);
        s.bulk_percent.store(shares.bulk_percent, Ordering::Relaxed);
        Ok(())
    }

    /// The shares in force.
    pub fn tx_shares(&self) -> TxShares {
        TxShares {
            client_percent: self.shared.client_percent.load(Ordering::Relaxed),
            bulk_percent: self.shared.bulk_percent.load(Ordering::Relaxed),
        }
    }

    /// Sends a batch as [`BusHandle::send`] does, in its class: client raw
    /// frames and bulk data wait for their share of the bus (see
    /// [`crate::budget`]) behind the gateway's own frames, and the call
    /// returns when the last of them went to the interface. A client batch
    /// is refused when [`MAX_BUDGET_QUEUED`] frames already wait.
    pub async fn send_as(&self, class: TxClass, frames: Vec<Frame>) -> Result<(), SendFailure> {
        let total = frames.len();
        match self.queue_as(class, frames, None).await? {
            None => Ok(()),
            Some(outcome) => outcome.await.unwrap_or_else(|_| Err(self.down(total))),
        }
    }

    /// Sends a client's frames as [`BusHandle::send_as`] does in the client
    /// class, marked as sent by `client` ([`Frame::sender`]): once they are
    /// on the bus, every other subscriber receives them as received frames,
    /// and the client's own subscription, if it asked, as transmitted (see
    /// the module documentation). Returns when the last of them went to the
    /// interface, within the bus's client share.
    ///
    /// Where the client share paces frames, a batch longer than
    /// [`CLIENT_CHUNK_BUS_TIME_NS`] of bus time is queued a chunk at a
    /// time, the next once the last is on the bus: no client has more than
    /// that waiting in front of the wire, and a batch given up (this
    /// future dropped) stops within it (see [`PendingSend`]).
    pub async fn send_as_client(
        &self,
        client: ClientId,
        frames: Vec<Frame>,
    ) -> Result<(), SendFailure> {
        /// The frames of later chunks, counted as withdrawn when the
        /// call is given up before it queued them.
        struct Unqueued<'a>(&'a Shared, usize);
        impl Drop for Unqueued<'_> {
            fn drop(&mut self) {
                (self.0.counters.client_withdrawn).fetch_add(self.1 as u64, Ordering::Relaxed);
            }
        }
        let total = frames.len();
        let mut sent = 0;
        let mut rest = frames;
        let mut unqueued = Unqueued(&self.shared, total);
        loop {
            let n = self.client_chunk_len(&rest);
            let tail = rest.split_off(n);
            let chunk = std::mem::replace(&mut rest, tail);
            let len = chunk.len();
            unqueued.1 = rest.len();
            let outcome = self.queue_as_client(client, chunk).await.outcome().await;
            unqueued.1 = 0;
            if let Err(f) = outcome {
                return Err(SendFailure {
                    sent: sent + f.sent,
                    total,
                    error: f.error,
                });
            }
            sent += len;
            if rest.is_empty() {
                return Ok(());
            }
        }
    }

    /// How many of `frames` go in the next chunk of
    /// [`BusHandle::send_as_client`]: all where client frames are not
    /// paced, else those within [`CLIENT_CHUNK_BUS_TIME_NS`] (at least one).
    fn client_chunk_len(&self, frames: &[Frame]) -> usize {
        if self.paced_sender(TxClass::Client).is_none() {
            return frames.len();
        }
        let timing = pacing_timing(&self.shared.info);
        let mut busy = 0u64;
        for (i, f) in frames.iter().enumerate() {
            busy += timing.frame_duration_ns(f);
            if busy > CLIENT_CHUNK_BUS_TIME_NS {
                return i.max(1);
            }
        }
        frames.len()
    }

    /// Queues a client's frames as [`BusHandle::send_as_client`] sends
    /// them and returns once they are in the bus task's queue (waiting
    /// only while it is full); their outcome comes later from the
    /// [`PendingSend`]. A session that keeps one batch pending at a time
    /// (awaiting the last outcome before it queues the next) keeps the
    /// backpressure of waiting for each send, without being woken when a
    /// frame leaves: a request/response client's next wake-up is then its
    /// answer, not its own frame's confirmation.
    pub async fn queue_as_client(&self, client: ClientId, frames: Vec<Frame>) -> PendingSend {
        let frames: Vec<Frame> = frames
            .into_iter()
            .map(|f| f.with_sender(Some(client)))
            .collect();
        // On the virtual bus the frames are published from the port's
        // echo, which must let them through until they are back.
        let echoed = self.shared.direct.is_some();
        if echoed {
            client_echo_begin(&self.shared, frames.len() as u64);
        }
        let total = frames.len();
        let withdraw = Arc::new(AtomicBool::new(false));
        let state = match self
            .queue_as(TxClass::Client, frames, Some(withdraw.clone()))
            .await
        {
            Ok(Some(rx)) => Pending::Waiting { rx, total },
            Ok(None) => Pending::Done(Ok(())),
            Err(f) => Pending::Done(Err(f)),
        };
        PendingSend {
            state,
            bus: self.clone(),
            echo_open: echoed,
            withdraw: Some(withdraw),
        }
    }

    /// Queues a batch in its class after the checks of
    /// [`BusHandle::send_as`]: the receiver of its outcome, or `None` when
    /// it was sent at once (a virtual bus, not paced). Waits only while the
    /// queue is full.
    async fn queue_as(
        &self,
        class: TxClass,
        frames: Vec<Frame>,
        withdraw: Option<Arc<AtomicBool>>,
    ) -> Result<Option<oneshot::Receiver<Result<(), SendFailure>>>, SendFailure> {
        self.check(&frames)?;
        let total = frames.len();
        let (reply, rx) = oneshot::channel();
        if let Some(paced) = self.paced_sender(class) {
            if class == TxClass::Client {
                self.admit_client(total)?;
            }
            let c = &self.shared.counters;
            c.budget_queued.fetch_add(total as u64, Ordering::Relaxed);
            let request = PacedRequest {
                class,
                frames,
                released: 0,
                held: false,
                reply: Some(reply),
                withdraw,
            };
            if paced.send(request).await.is_err() {
                c.budget_queued.fetch_sub(total as u64, Ordering::Relaxed);
                return Err(self.down(total));
            }
            return Ok(Some(rx));
        }
        if let Some(direct) = &self.shared.direct {
            return self.send_direct(direct, &frames).map(|()| None);
        }
        let request = TxRequest {
            frames,
            reply: Some(reply),
        };
        self.shared
            .tx
            .send(request)
            .await
            .map_err(|_| self.down(total))?;
        Ok(Some(rx))
    }

    /// A batch of `total` frames the bus task is no longer there to send.
    fn down(&self, total: usize) -> SendFailure {
        SendFailure {
            sent: 0,
            total,
            error: SendError::Down(self.name().to_string()),
        }
    }

    /// Queues a batch as [`BusHandle::submit`] does, in its class (see
    /// [`BusHandle::send_as`]), without waiting for it to be sent.
    pub async fn submit_as(&self, class: TxClass, frames: Vec<Frame>) -> Result<(), SendFailure> {
        let Some(paced) = self.paced_sender(class) else {
            return self.submit(frames).await;
        };
        self.check(&frames)?;
        let total = frames.len();
        if class == TxClass::Client {
            self.admit_client(total)?;
        }
        self.shared
            .counters
            .budget_queued
            .fetch_add(total as u64, Ordering::Relaxed);
        let request = PacedRequest {
            class,
            frames,
            released: 0,
            held: false,
            reply: None,
            withdraw: None,
        };
        paced.send(request).await.map_err(|_| {
            self.shared
                .counters
                .budget_queued
                .fetch_sub(total as u64, Ordering::Relaxed);
            SendFailure {
                sent: 0,
                total,
                error: SendError::Down(self.name().to_string()),
            }
        })
    }

    /// The bus task's queue for paced frames of `class`; `None` when the
    /// class is not paced here (the gateway's own frames, a bus that paces
    /// nothing, a share of 100 %).
    fn paced_sender(&self, class: TxClass) -> Option<&mpsc::Sender<PacedRequest>> {
        let paced = self.shared.paced.as_ref()?;
        (self.tx_shares().percent(class) < 100).then_some(paced)
    }

    fn admit_client(&self, total: usize) -> Result<(), SendFailure> {
        let c = &self.shared.counters;
        let queued = c.budget_queued.load(Ordering::Relaxed);
        if queued > 0 && queued + total as u64 > MAX_BUDGET_QUEUED {
            c.client_refused.fetch_add(total as u64, Ordering::Relaxed);
            return Err(SendFailure {
                sent: 0,
                total,
                error: SendError::BudgetExhausted {
                    bus: self.name().to_string(),
                    queued,
                    percent: self.tx_shares().client_percent,
                },
            });
        }
        Ok(())
    }

    /// Checks a batch against what this bus can carry right now, without
    /// sending anything.
    pub fn check(&self, frames: &[Frame]) -> Result<(), SendFailure> {
        let fail = |error| SendFailure {
            sent: 0,
            total: frames.len(),
            error,
        };
        if !self.shared.info.fd && frames.iter().any(|f| f.is_fd()) {
            return Err(fail(SendError::FdNotSupported(self.name().to_string())));
        }
        match self.status().state {
            crate::state::BusState::BusOff => Err(fail(SendError::BusOff(self.name().to_string()))),
            crate::state::BusState::Down => Err(fail(SendError::Down(self.name().to_string()))),
            _ => Ok(()),
        }
    }

    /// Sends a batch of frames in order. Checks the whole batch first, so a
    /// batch that cannot be sent sends nothing; a failure part-way (the
    /// interface vanished) reports how many frames went out.
    pub async fn send(&self, frames: Vec<Frame>) -> Result<(), SendFailure> {
        self.send_as(TxClass::Control, frames).await
    }

    /// Queues a batch for sending without waiting for the bus task to send
    /// it (protocol stacks on a hot path: the answer comes back on the bus
    /// anyway). The same checks as [`BusHandle::send`] run first; a failure
    /// later is counted in `tx_failed` and logged. Falls back to waiting
    /// when the bus task's queue is full, so nothing is dropped.
    pub async fn submit(&self, frames: Vec<Frame>) -> Result<(), SendFailure> {
        let Some(frames) = self.try_submit(frames)? else {
            return Ok(());
        };
        let total = frames.len();
        let request = TxRequest {
            frames,
            reply: None,
        };
        self.shared.tx.send(request).await.map_err(|_| SendFailure {
            sent: 0,
            total,
            error: SendError::Down(self.name().to_string()),
        })
    }

    /// [`BusHandle::submit`] without a runtime, for a thread of its own
    /// (the SYNC producer): `Ok(None)` when the batch was sent or queued,
    /// `Ok(Some(frames))` when the bus task's queue is full and the caller
    /// has to wait with [`BusHandle::submit`].
    pub fn try_submit(&self, frames: Vec<Frame>) -> Result<Option<Vec<Frame>>, SendFailure> {
        self.check(&frames)?;
        if let Some(direct) = &self.shared.direct {
            return self.send_direct(direct, &frames).map(|()| None);
        }
        let total = frames.len();
        let request = TxRequest {
            frames,
            reply: None,
        };
        match self.shared.tx.try_send(request) {
            Ok(()) => Ok(None),
            Err(mpsc::error::TrySendError::Full(request)) => Ok(Some(request.frames)),
            Err(mpsc::error::TrySendError::Closed(_)) => Err(SendFailure {
                sent: 0,
                total,
                error: SendError::Down(self.name().to_string()),
            }),
        }
    }

    fn send_direct(
        &self,
        direct: &crate::virtual_bus::VirtualSender,
        frames: &[Frame],
    ) -> Result<(), SendFailure> {
        let c = &self.shared.counters;
        match direct.send_batch(frames) {
            Ok(()) => {
                c.tx_frames
                    .fetch_add(frames.len() as u64, Ordering::Relaxed);
                let bytes: usize = frames.iter().map(|f| f.data().len()).sum();
                c.tx_bytes.fetch_add(bytes as u64, Ordering::Relaxed);
                Ok(())
            }
            Err(error) => {
                c.tx_failed
                    .fetch_add(frames.len() as u64, Ordering::Relaxed);
                Err(SendFailure {
                    sent: 0,
                    total: frames.len(),
                    error,
                })
            }
        }
    }

    /// Subscribes to frames passing `selector` and to state changes, with a
    /// queue of `queue` items. Frames of the gateway's clients come as
    /// received ([`Direction::Rx`], marked with their [`Frame::sender`]).
    pub fn subscribe(&self, selector: FrameSelector, queue: usize) -> Subscription {
        self.add_subscriber(selector, queue, None, false, true)
    }

    /// Attaches a client of the gateway to the bus as a participant: the
    /// subscription through which it receives (see the module
    /// documentation). What it sends goes through
    /// [`BusHandle::send_as_client`] with the same `client`.
    pub fn attach(&self, client: ClientId, options: AttachOptions) -> Subscription {
        let selector = FrameSelector {
            transmitted: true,
            ..options.selector
        };
        self.add_subscriber(
            selector,
            options.queue,
            Some(client),
            options.receive_own,
            options.fd,
        )
    }

    fn add_subscriber(
        &self,
        selector: FrameSelector,
        queue: usize,
        client: Option<ClientId>,
        receive_own: bool,
        fd: bool,
    ) -> Subscription {
        let (tx, rx) = mpsc::channel(queue.max(2));
        let lost_total = Arc::new(AtomicU64::new(0));
        let transmitted = selector.transmitted;
        let mut subs = self.shared.subscribers.lock().expect("subscriber lock");
        subs.push(Subscriber {
            selector,
            client,
            receive_own,
            fd,
            tx,
            pending_lost: 0,
            pending_state: false,
            lost_total: lost_total.clone(),
        });
        // Widened before the subscription is returned (and under the lock
        // the bus task needs to fan out), so that every frame sent after
        // this call that the new subscriber wants is echoed.
        if transmitted {
            update_echo(&self.shared, &subs);
        }
        drop(subs);
        Subscription { rx, lost_total }
    }

    /// Replaces the selector of the subscription `key` names, under the
    /// fan-out's lock: every frame after this call is matched with the new
    /// selector, none is lost or delivered twice in the change. `false` if
    /// the subscription has ended.
    pub fn reselect(&self, key: &SubscriptionKey, selector: FrameSelector) -> bool {
        let mut subs = self.shared.subscribers.lock().expect("subscriber lock");
        let Some(s) = subs.iter_mut().find(|s| Arc::ptr_eq(&s.lost_total, &key.0)) else {
            return false;
        };
        let transmitted = s.selector.transmitted || selector.transmitted;
        s.selector = selector;
        if transmitted {
            update_echo(&self.shared, &subs);
        }
        true
    }

    /// The echo filter of the virtual port (see [`update_echo`]).
    #[cfg(test)]
    fn echo_filters(&self) -> Option<Vec<Filter>> {
        self.shared.direct.as_ref().and_then(|d| d.echo_filters())
    }

    /// Live counters.
    pub fn stats(&self) -> BusStats {
        let c = &self.shared.counters;
        let (status, since) = *self.shared.status.lock().expect("status lock");
        BusStats {
            rx_frames: c.rx_frames.load(Ordering::Relaxed),
            tx_frames: c.tx_frames.load(Ordering::Relaxed),
            rx_bytes: c.rx_bytes.load(Ordering::Relaxed),
            tx_bytes: c.tx_bytes.load(Ordering::Relaxed),
            error_frames: c.error_frames.load(Ordering::Relaxed),
            tx_failed: c.tx_failed.load(Ordering::Relaxed),
            tx_retries: c.tx_retries.load(Ordering::Relaxed),
            tx_queued: c.tx_queued.load(Ordering::Relaxed),
            rx_overflows: c.rx_overflows.load(Ordering::Relaxed),
            subscriber_drops: c.subscriber_drops.load(Ordering::Relaxed),
            client_frames_delayed: c.client_delayed.load(Ordering::Relaxed),
            client_frames_refused: c.client_refused.load(Ordering::Relaxed),
            client_frames_withdrawn: c.client_withdrawn.load(Ordering::Relaxed),
            bulk_frames_delayed: c.bulk_delayed.load(Ordering::Relaxed),
            budget_queued: c.budget_queued.load(Ordering::Relaxed),
            load_percent: c.load_millipercent.load(Ordering::Relaxed) as f64 / 1000.0,
            subscribers: self
                .shared
                .subscribers
                .lock()
                .expect("subscriber lock")
                .len(),
            status,
            status_since: since,
        }
    }
}

/// A live feed of a bus's frames and state changes. Ends (returns `None`)
/// when the bus task stops.
#[derive(Debug)]
pub struct Subscription {
    rx: mpsc::Receiver<BusItem>,
    lost_total: Arc<AtomicU64>,
}

impl Subscription {
    /// The next item, or `None` when the bus stopped.
    pub async fn recv(&mut self) -> Option<BusItem> {
        self.rx.recv().await
    }

    /// Up to `limit` items (waits for at least one); 0 when the bus stopped.
    pub async fn recv_many(&mut self, buf: &mut Vec<BusItem>, limit: usize) -> usize {
        self.rx.recv_many(buf, limit).await
    }

    /// An item if one is queued.
    pub fn try_recv(&mut self) -> Option<BusItem> {
        self.rx.try_recv().ok()
    }

    /// All frames this subscription has missed so far.
    pub fn lost_total(&self) -> u64 {
        self.lost_total.load(Ordering::Relaxed)
    }

    /// What names this subscription for [`BusHandle::reselect`].
    pub fn key(&self) -> SubscriptionKey {
        SubscriptionKey(self.lost_total.clone())
    }
}

/// Names a [`Subscription`] for [`BusHandle::reselect`] without holding
/// its queue. (The loss counter is shared by exactly one subscription and
/// its subscriber entry, so it identifies both.)
#[derive(Debug, Clone)]
pub struct SubscriptionKey(Arc<AtomicU64>);

async fn run_bus(
    mut backend: Backend,
    shared: Arc<Shared>,
    mut requests: mpsc::Receiver<TxRequest>,
    mut paced_rx: Option<mpsc::Receiver<PacedRequest>>,
    cancel: CancellationToken,
) {
    let timing = shared.info.bitrate.map(|bitrate| BitTiming {
        bitrate,
        data_bitrate: shared.info.data_bitrate.unwrap_or(bitrate),
        stuffing: shared.info.stuffing,
    });
    let mut load = LoadMeter::new(1_000_000_000);
    let mut events = Vec::with_capacity(256);
    let mut port_events = Vec::with_capacity(256);
    let mut tick = tokio::time::interval(Duration::from_millis(20));
    // A virtual port's receive overflows as far as the subscribers were
    // told (SocketCAN reports its drops as events; a virtual port only
    // counts them).
    let mut virtual_lost_told = 0u64;
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    tracing::info!(backend = ?shared.info.kind, interface = %shared.info.interface, "bus started");
    // One cancellation future for the whole loop: a fresh one per turn
    // registers with and unregisters from the token's waiter list at every
    // wake-up of this hot task.
    let cancelled = cancel.cancelled();
    tokio::pin!(cancelled);
    let mut paced = Paced::new(pacing_timing(&shared.info));
    loop {
        tokio::select! {
            biased;
            _ = &mut cancelled => break,
            req = requests.recv() => {
                let Some(req) = req else { break };
                if let Backend::SocketCan(s) = &mut backend {
                    // Held and retried while the interface is congested:
                    // the outcomes come back as backend events, the answer
                    // after them.
                    s.queue(req.frames, req.reply);
                    store_tx_counters(&shared, &backend);
                    continue;
                }
                let result = send_now(&mut backend, &shared, &req.frames, TxClass::Control);
                match req.reply {
                    Some(reply) => {
                        let _ = reply.send(result);
                    }
                    None => {
                        if let Err(e) = result {
                            tracing::warn!(error = %e, "submitted frames not sent");
                        }
                    }
                }
            }
            _ = backend.next(&mut events, &mut port_events) => {
                for ev in events.drain(..) {
                    match ev {
                        BackendEvent::Frame { frame, own } => {
                            record_load(&mut load, timing, &frame);
                            if own {
                                if frame.sender().is_some() {
                                    client_echo_end(&shared, 1);
                                }
                                fanout(&shared, &frame, Direction::Tx);
                                continue;
                            }
                            // Another node's: a mark of another process's
                            // client (a second gateway on the same virtual
                            // bus) means nothing here.
                            let frame = frame.with_sender(None);
                            let c = &shared.counters;
                            c.rx_frames.fetch_add(1, Ordering::Relaxed);
                            c.rx_bytes.fetch_add(frame.data().len() as u64, Ordering::Relaxed);
                            if frame.is_error() {
                                c.error_frames.fetch_add(1, Ordering::Relaxed);
                            }
                            fanout(&shared, &frame, Direction::Rx);
                        }
                        BackendEvent::Sent(frame) => {
                            let c = &shared.counters;
                            c.tx_frames.fetch_add(1, Ordering::Relaxed);
                            c.tx_bytes.fetch_add(frame.data().len() as u64, Ordering::Relaxed);
                            record_load(&mut load, timing, &frame);
                            fanout(&shared, &frame, Direction::Tx);
                        }
                        BackendEvent::Unsent(n) => {
                            shared.counters.tx_failed.fetch_add(n, Ordering::Relaxed);
                        }
                        BackendEvent::Lost(n) => {
                            shared.counters.rx_overflows.store(backend.overflows(), Ordering::Relaxed);
                            fanout_lost(&shared, n);
                        }
                        BackendEvent::State(status) => {
                            tracing::info!(state = %status.state, tec = status.tx_errors, rec = status.rx_errors, "bus state changed");
                            publish_state(&shared, status);
                        }
                    }
                }
                tell_virtual_losses(&backend, &shared, &mut virtual_lost_told);
            }
            req = recv_paced(&mut paced_rx) => {
                match req {
                    Some(req) => {
                        paced.push(req);
                        paced.release(&mut backend, &shared);
                    }
                    None => paced_rx = None,
                }
            }
            _ = paced.wait() => paced.release(&mut backend, &shared),
            _ = tick.tick() => {
                let status = shared.status.lock().expect("status lock").0;
                let mut subs = shared.subscribers.lock().expect("subscriber lock");
                retain_subscribers(&shared, &mut subs, |s| s.flush(status));
                drop(subs);
                let pct = load.load_percent(Timestamp::now().as_nanos());
                shared.counters.load_millipercent.store((pct * 1000.0) as u64, Ordering::Relaxed);
                shared.counters.rx_overflows.store(backend.overflows(), Ordering::Relaxed);
                tell_virtual_losses(&backend, &shared, &mut virtual_lost_told);
                store_tx_counters(&shared, &backend);
            }
        }
    }
    if let Backend::SocketCan(s) = &mut backend {
        // Frames still held are given up and counted, as are outcomes not
        // yet taken: the counters add up after the bus stopped too.
        let c = &shared.counters;
        for ev in s.abandon() {
            match ev {
                SocketCanEvent::Sent(f) => {
                    c.tx_frames.fetch_add(1, Ordering::Relaxed);
                    c.tx_bytes
                        .fetch_add(f.data().len() as u64, Ordering::Relaxed);
                }
                SocketCanEvent::Unsent(n) => {
                    c.tx_failed.fetch_add(n, Ordering::Relaxed);
                }
                _ => {}
            }
        }
        store_tx_counters(&shared, &backend);
    }
    // Dropping the senders ends every subscription's stream.
    shared.subscribers.lock().expect("subscriber lock").clear();
    tracing::info!("bus stopped");
}

/// Sends a batch to a virtual bus (in the class's lane) and counts it;
/// SocketCAN batches go through [`SocketCanBus::queue`] instead. The bus
/// task publishes the frames (as TX) from the virtual port's echo, whose
/// filter only ever leaves out frames that no subscriber and not the load
/// meter needs (see [`echo_filters_for`]).
fn send_now(
    backend: &mut Backend,
    shared: &Shared,
    frames: &[Frame],
    class: TxClass,
) -> Result<(), SendFailure> {
    let total = frames.len();
    let result = match backend.send_batch_in_lane(frames, class.lane()) {
        Ok(()) => Ok(()),
        Err((sent, error)) => Err(SendFailure { sent, total, error }),
    };
    let sent = match &result {
        Ok(()) => total,
        Err(f) => f.sent,
    };
    let c = &shared.counters;
    c.tx_frames.fetch_add(sent as u64, Ordering::Relaxed);
    c.tx_failed
        .fetch_add((total - sent) as u64, Ordering::Relaxed);
    let bytes: usize = frames[..sent].iter().map(|f| f.data().len()).sum();
    c.tx_bytes.fetch_add(bytes as u64, Ordering::Relaxed);
    result
}

async fn recv_paced(rx: &mut Option<mpsc::Receiver<PacedRequest>>) -> Option<PacedRequest> {
    match rx {
        Some(rx) => rx.recv().await,
        None => std::future::pending().await,
    }
}

/// The client and bulk frames a bus task holds back, and their pacers.
struct Paced {
    timing: BitTiming,
    /// Bulk, then client requests, each in arrival order.
    queues: [VecDeque<PacedRequest>; 2],
    pacers: [Pacer; 2],
    origin: tokio::time::Instant,
    /// When the next held frame may go.
    next: Option<tokio::time::Instant>,
}

impl Paced {
    const CLASSES: [TxClass; 2] = [TxClass::Bulk, TxClass::Client];

    fn new(timing: BitTiming) -> Self {
        Paced {
            timing,
            queues: Default::default(),
            pacers: [
                Pacer::new(PACER_TOLERANCE_NS),
                Pacer::new(PACER_TOLERANCE_NS),
            ],
            origin: tokio::time::Instant::now(),
            next: None,
        }
    }

    fn push(&mut self, req: PacedRequest) {
        let i = usize::from(req.class == TxClass::Client);
        self.queues[i].push_back(req);
    }

    /// Resolves when held frames may go (never when none are held).
    async fn wait(&self) {
        match self.next {
            Some(at) => tokio::time::sleep_until(at).await,
            None => std::future::pending().await,
        }
    }

    /// Sends what the shares allow now, replies for the requests that
    /// completed, and sets when to come back.
    fn release(&mut self, backend: &mut Backend, shared: &Shared) {
        let now = tokio::time::Instant::now();
        let now_ns = now.duration_since(self.origin).as_nanos() as u64;
        let c = &shared.counters;
        let mut next_ns: Option<u64> = None;
        for (i, class) in Self::CLASSES.into_iter().enumerate() {
            let percent = match class {
                TxClass::Client => shared.client_percent.load(Ordering::Relaxed),
                _ => shared.bulk_percent.load(Ordering::Relaxed),
            };
            if self.queues[i].iter().any(PacedRequest::withdrawn) {
                self.queues[i].retain(|req| {
                    if !req.withdrawn() {
                        return true;
                    }
                    withdraw(backend, shared, req);
                    false
                });
            }
            // Client frames take only time no one else needs: while other
            // frames wait for the wire they are held, whatever their
            // identifiers, so that a flood of them cannot build a backlog
            // of the gateway's own frames and the devices' answers (which
            // an overloaded bus carries for seconds after the flood).
            if class == TxClass::Client && !self.queues[i].is_empty() && others_waiting(backend) {
                if let Some(req) = self.queues[i].front_mut()
                    && !req.held
                {
                    req.held = true;
                    c.client_delayed
                        .fetch_add((req.frames.len() - req.released) as u64, Ordering::Relaxed);
                }
                let retry = now_ns + CONGESTION_RETRY_NS;
                next_ns = Some(next_ns.map_or(retry, |n| n.min(retry)));
                continue;
            }
            while let Some(req) = self.queues[i].front_mut() {
                let total = req.frames.len();
                let mut end = req.released;
                while end < total
                    && (percent >= 100
                        || self.pacers[i].try_take(
                            self.timing.frame_duration_ns(&req.frames[end]),
                            percent,
                            now_ns,
                        ))
                {
                    end += 1;
                }
                let start = req.released;
                if end > start {
                    c.budget_queued
                        .fetch_sub((total - start) as u64, Ordering::Relaxed);
                    let last = end == total;
                    let outcome = match backend {
                        Backend::SocketCan(s) => {
                            // The answer comes with the last chunk's outcome.
                            let reply = if last { req.reply.take() } else { None };
                            s.queue_as(
                                class,
                                req.frames[start..end].to_vec(),
                                reply.map(|r| offset_reply(r, start, total)),
                            );
                            Ok(())
                        }
                        Backend::Virtual(_) => {
                            send_now(backend, shared, &req.frames[start..end], class)
                        }
                    };
                    if let Err(f) = outcome {
                        // The rest of the request is not sent either.
                        c.tx_failed
                            .fetch_add((total - end) as u64, Ordering::Relaxed);
                        if let Some(reply) = req.reply.take()
                            && let Err(Err(f)) = reply.send(Err(SendFailure {
                                sent: start + f.sent,
                                total,
                                error: f.error,
                            }))
                            && class == TxClass::Client
                            && matches!(backend, Backend::Virtual(_))
                        {
                            // Its sender gave it up: the echo count of the
                            // frames not sent ends here, not in its
                            // [`PendingSend`].
                            client_echo_end(shared, (f.total - f.sent) as u64);
                        }
                        self.queues[i].pop_front();
                        continue;
                    }
                    req.released = end;
                    if last {
                        if let Some(reply) = req.reply.take() {
                            let _ = reply.send(Ok(()));
                        }
                        self.queues[i].pop_front();
                        continue;
                    }
                    c.budget_queued
                        .fetch_add((total - end) as u64, Ordering::Relaxed);
                }
                // Held back: counted once per request, all frames still held.
                if !req.held {
                    req.held = true;
                    let delayed = match class {
                        TxClass::Client => &c.client_delayed,
                        _ => &c.bulk_delayed,
                    };
                    delayed.fetch_add((total - end) as u64, Ordering::Relaxed);
                }
                let ready = self.pacers[i].ready_at();
                next_ns = Some(next_ns.map_or(ready, |n| n.min(ready)));
                break;
            }
        }
        self.next = next_ns.map(|ns| self.origin + Duration::from_nanos(ns));
    }
}

/// How soon client frames held back for other frames waiting (see
/// [`others_waiting`]) are looked at again.
const CONGESTION_RETRY_NS: u64 = 500_000;

/// Whether frames other than client frames wait for the wire: on a
/// bit-timed virtual bus, any port's frames outside the client lane; on
/// SocketCAN, frames held because the interface's queue was full.
fn others_waiting(backend: &Backend) -> bool {
    match backend {
        Backend::Virtual(p) => p.bus().waiting_outside_lane(TxClass::Client.lane()) > 0,
        Backend::SocketCan(s) => s.tx_counters().queued > 0,
    }
}

/// Drops what a given-up request has not released yet: counted, its
/// echo count ended (its [`PendingSend`] is gone and will not), logged.
fn withdraw(backend: &Backend, shared: &Shared, req: &PacedRequest) {
    let unsent = (req.frames.len() - req.released) as u64;
    let c = &shared.counters;
    c.budget_queued.fetch_sub(unsent, Ordering::Relaxed);
    c.client_withdrawn.fetch_add(unsent, Ordering::Relaxed);
    if matches!(backend, Backend::Virtual(_)) {
        client_echo_end(shared, unsent);
    }
    tracing::info!(
        bus = %shared.info.name,
        sender = ?req.frames.first().and_then(Frame::sender),
        withdrawn = unsent,
        sent = req.released,
        "client frames withdrawn: their sender gave the batch up"
    );
}

/// A reply for the last chunk of a paced request, answered for the whole
/// request: frames sent before that chunk count as sent.
fn offset_reply(
    reply: oneshot::Sender<Result<(), SendFailure>>,
    before: usize,
    total: usize,
) -> oneshot::Sender<Result<(), SendFailure>> {
    if before == 0 {
        return reply;
    }
    let (tx, rx) = oneshot::channel::<Result<(), SendFailure>>();
    tokio::spawn(async move {
        let result = match rx.await {
            Ok(Ok(())) => Ok(()),
            Ok(Err(f)) => Err(SendFailure {
                sent: before + f.sent,
                total,
                error: f.error,
            }),
            Err(_) => return,
        };
        let _ = reply.send(result);
    });
    tx
}

fn record_load(load: &mut LoadMeter, timing: Option<BitTiming>, frame: &Frame) {
    if let Some(t) = timing {
        load.record(frame.timestamp().as_nanos(), t.frame_duration_ns(frame));
    }
}

/// Delivers a frame to the subscribers that want it. `on_bus` says how the
/// bus task got it: [`Direction::Rx`] from another node (to everyone, as
/// received), [`Direction::Tx`] one of this gateway's own, which is either
/// its stacks' (to the subscribers to transmitted frames, attached clients
/// among them, as transmitted) or a client's (see [`Frame::sender`]: to
/// every other subscriber as received, to the client's own subscription as
/// transmitted if it asked for its own frames).
fn fanout(shared: &Shared, frame: &Frame, on_bus: Direction) {
    let drops = &shared.counters.subscriber_drops;
    let sender = match on_bus {
        Direction::Rx => None,
        Direction::Tx => frame.sender(),
    };
    let mut subs = shared.subscribers.lock().expect("subscriber lock");
    retain_subscribers(shared, &mut subs, |s| {
        let direction = match (on_bus, sender) {
            (Direction::Rx, _) => Direction::Rx,
            (Direction::Tx, None) if s.selector.transmitted => Direction::Tx,
            (Direction::Tx, None) => return true,
            (Direction::Tx, Some(c)) if s.client == Some(c) => {
                if !s.receive_own {
                    return true;
                }
                Direction::Tx
            }
            (Direction::Tx, Some(_)) => Direction::Rx,
        };
        if !s.selector.matches(frame) || (frame.is_fd() && !s.fd) {
            return !s.tx.is_closed();
        }
        s.offer(
            BusItem::Frame {
                frame: *frame,
                direction,
            },
            drops,
        )
    });
}

/// Counts `n` client frames about to be sent on a virtual bus, whose echo
/// the bus task needs to publish them. The first of them opens the echo
/// filter to every own frame, before they are sent; the counting happens
/// under the subscriber lock, as every change of the echo filter does, so a
/// second sender cannot send before the filter is open.
///
/// Why not a filter by identifier, as for the subscribers to transmitted
/// frames: a client's frame goes to every subscriber whose selector it
/// passes, the gateway's stacks included, whose filters together are wide.
/// An echo that never comes (a frame dropped by fault injection, an echo
/// lost to a full receive queue) leaves the filter open: the bus task then
/// wakes for own frames no one wants, which costs time, not frames.
fn client_echo_begin(shared: &Shared, n: u64) {
    if n == 0 {
        return;
    }
    let subs = shared.subscribers.lock().expect("subscriber lock");
    if shared.counters.client_echo.fetch_add(n, Ordering::AcqRel) == 0 {
        update_echo(shared, &subs);
    }
}

/// `n` counted client frames came back (or were not sent after all): when
/// none is outstanding any more, the echo filter narrows again. Lock-free
/// unless the count reaches zero; a sender counting anew meanwhile holds
/// the lock while it opens the filter, and the count is read again under
/// it.
fn client_echo_end(shared: &Shared, n: u64) {
    if n == 0 {
        return;
    }
    let c = &shared.counters.client_echo;
    let before = c
        .fetch_update(Ordering::AcqRel, Ordering::Acquire, |v| {
            Some(v.saturating_sub(n))
        })
        .unwrap_or(0);
    if before <= n {
        let subs = shared.subscribers.lock().expect("subscriber lock");
        update_echo(shared, &subs);
    }
}

/// Frames a virtual port dropped because its receive queue was full since
/// the subscribers were last told (`told`): every subscriber learns of
/// them, as of a SocketCAN interface's drops. (Among them may be echoes of
/// client frames: those frames went out on the bus, but the gateway could
/// not publish them.)
fn tell_virtual_losses(backend: &Backend, shared: &Shared, told: &mut u64) {
    if let Backend::Virtual(p) = backend {
        let now = p.overflows();
        if now > *told {
            shared.counters.rx_overflows.store(now, Ordering::Relaxed);
            fanout_lost(shared, now - *told);
            *told = now;
        }
    }
}

/// Frames lost before the gateway read them (their identifiers unknown):
/// every subscriber learns of them at this position of its stream.
fn fanout_lost(shared: &Shared, n: u64) {
    let mut subs = shared.subscribers.lock().expect("subscriber lock");
    retain_subscribers(shared, &mut subs, |s| {
        s.pending_lost += n;
        s.lost_total.fetch_add(n, Ordering::Relaxed);
        match s.tx.try_send(BusItem::Lost(s.pending_lost)) {
            Ok(()) => {
                s.pending_lost = 0;
                true
            }
            Err(mpsc::error::TrySendError::Full(_)) => true,
            Err(mpsc::error::TrySendError::Closed(_)) => false,
        }
    });
}

fn store_tx_counters(shared: &Shared, backend: &Backend) {
    if let Backend::SocketCan(s) = backend {
        let t = s.tx_counters();
        let c = &shared.counters;
        c.tx_retries.store(t.retries, Ordering::Relaxed);
        c.tx_queued.store(t.queued as u64, Ordering::Relaxed);
    }
}

fn publish_state(shared: &Shared, status: BusStatus) {
    {
        let mut st = shared.status.lock().expect("status lock");
        if st.0 == status {
            return;
        }
        *st = (status, Timestamp::now());
    }
    let mut subs = shared.subscribers.lock().expect("subscriber lock");
    retain_subscribers(shared, &mut subs, |s| {
        match s.tx.try_send(BusItem::State(status)) {
            Ok(()) => true,
            Err(mpsc::error::TrySendError::Full(_)) => {
                s.pending_state = true;
                true
            }
            Err(mpsc::error::TrySendError::Closed(_)) => false,
        }
    });
}

/// `retain_mut` on the subscriber list (locked by the caller) that narrows
/// the echo filter when a subscriber to transmitted frames went away. Only
/// then: the removal count is taken in the same pass, so the hot path
/// (every frame's fan-out) pays no extra pass and no filter update.
fn retain_subscribers(
    shared: &Shared,
    subs: &mut Vec<Subscriber>,
    mut keep: impl FnMut(&mut Subscriber) -> bool,
) {
    let mut removed_transmitted = 0usize;
    subs.retain_mut(|s| {
        let kept = keep(s);
        if !kept && s.selector.transmitted {
            removed_transmitted += 1;
        }
        kept
    });
    if removed_transmitted > 0 {
        update_echo(shared, subs);
    }
}

/// Sets the virtual port's echo filter to what `subs` (the whole, locked
/// subscriber list) and the load meter need; no-op for SocketCAN, whose
/// own frames are published at send time.
///
/// Why: with the echo on for everything, each frame the gateway sends
/// (1 kHz SYNC, set-points from other threads) wakes the bus task only to
/// find no one who wants it. A filter that is too wide is harmless (the
/// fan-out still applies each subscriber's selector); one too narrow loses
/// frames, which is why it is widened before a subscriber is added.
fn update_echo(shared: &Shared, subs: &[Subscriber]) {
    if let Some(direct) = &shared.direct {
        // A bitrate means the load meter (`timing` in `run_bus`), which
        // needs every frame on the bus, own ones included; client frames
        // on their way need their echo too (see [`client_echo_begin`]).
        let all = shared.info.bitrate.is_some()
            || shared.counters.client_echo.load(Ordering::Acquire) > 0;
        direct.set_echo_filters(echo_filters_for(all, subs));
    }
}

/// The echo filter that covers the own frames `subs` want: `None` (all)
/// when `all` is asked for (the load meter, client frames on their way) or
/// for a subscriber without filters (which takes every frame), else the
/// union of the filters of the subscribers to transmitted frames (empty:
/// none wants any; attached clients are among them). Own error frames pass
/// any non-empty echo filter, so subscribers that want them are covered
/// too.
fn echo_filters_for(all: bool, subs: &[Subscriber]) -> Option<Vec<Filter>> {
    if all {
        return None;
    }
    let mut union: Vec<Filter> = Vec::new();
    for s in subs.iter().filter(|s| s.selector.transmitted) {
        if s.selector.filters.is_empty() {
            return None;
        }
        for f in &s.selector.filters {
            if !union.contains(f) {
                union.push(*f);
            }
        }
    }
    Some(union)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::Filter;
    use crate::frame::CanId;
    use crate::virtual_bus::{VirtualBus, VirtualBusConfig};

    fn start(bus: &VirtualBus) -> (BusHandle, CancellationToken) {
        start_with_bitrate(bus, Some(1_000_000))
    }

    /// `bitrate: None`: no load meter, so the echo follows the subscribers.
    fn start_with_bitrate(
        bus: &VirtualBus,
        bitrate: Option<u32>,
    ) -> (BusHandle, CancellationToken) {
        let cancel = CancellationToken::new();
        let info = BusInfo {
            name: "can0".into(),
            kind: BackendKind::Virtual,
            interface: bus.name().into(),
            fd: true,
            bitrate,
            data_bitrate: None,
            bit_timed: false,
            stuffing: Stuffing::Exact,
        };
        let (h, _) = BusHandle::spawn(info, Backend::Virtual(bus.connect(true)), cancel.clone());
        (h, cancel)
    }

    fn frame(id: u32) -> Frame {
        Frame::new(CanId::standard(id).unwrap(), &[id as u8]).unwrap()
    }

    #[tokio::test]
    async fn filtered_subscription_sees_matching_rx_and_tx() {
        let vbus = VirtualBus::new("v", VirtualBusConfig::default());
        let (h, _c) = start(&vbus);
        let mut sub = h.subscribe(
            FrameSelector {
                filters: vec![Filter::exact_standard(0x10)],
                error_frames: false,
                transmitted: true,
            },
            16,
        );
        let peer = vbus.connect(false);
        peer.send(&frame(0x11)).unwrap();
        peer.send(&frame(0x10)).unwrap();
        h.send(vec![frame(0x10), frame(0x12)]).await.unwrap();
        let a = sub.recv().await.unwrap();
        let b = sub.recv().await.unwrap();
        assert!(
            matches!(a, BusItem::Frame { direction: Direction::Rx, frame } if frame.raw_id() == 0x10)
        );
        assert!(
            matches!(b, BusItem::Frame { direction: Direction::Tx, frame } if frame.raw_id() == 0x10)
        );
        assert!(sub.try_recv().is_none());
        let st = h.stats();
        assert_eq!((st.rx_frames, st.tx_frames), (2, 2));
    }

    #[tokio::test]
    async fn slow_subscriber_gets_exact_lost_count_in_place() {
        let vbus = VirtualBus::new("v", VirtualBusConfig::default());
        let (h, _c) = start(&vbus);
        let mut slow = h.subscribe(FrameSelector::default(), 4);
        let mut fast = h.subscribe(FrameSelector::default(), 10_000);
        let peer = vbus.connect(false);
        for i in 0..100 {
            peer.send(&frame(i)).unwrap();
        }
        for _ in 0..100 {
            assert!(matches!(fast.recv().await, Some(BusItem::Frame { .. })));
        }
        // The slow one has the first 4 frames queued, then the notice for
        // the other 96.
        for i in 0..4 {
            assert!(
                matches!(slow.recv().await, Some(BusItem::Frame { frame, .. }) if frame.raw_id() == i)
            );
        }
        assert_eq!(slow.recv().await, Some(BusItem::Lost(96)));
        assert_eq!(slow.lost_total(), 96);
        assert_eq!(h.stats().subscriber_drops, 96);
        peer.send(&frame(0x7F)).unwrap();
        assert!(
            matches!(slow.recv().await, Some(BusItem::Frame { frame, .. }) if frame.raw_id() == 0x7F)
        );
    }

    #[tokio::test]
    async fn bus_off_is_reported_and_refuses_sends() {
        let vbus = VirtualBus::new("v", VirtualBusConfig::default());
        let (h, _c) = start(&vbus);
        let mut sub = h.subscribe(FrameSelector::default(), 16);
        vbus.force_bus_off();
        assert!(
            matches!(sub.recv().await, Some(BusItem::State(s)) if s.state == crate::state::BusState::BusOff)
        );
        let err = h.send(vec![frame(1)]).await.unwrap_err();
        assert_eq!(err.sent, 0);
        assert!(matches!(err.error, SendError::BusOff(_)));
        let err = h.try_submit(vec![frame(1)]).unwrap_err();
        assert!(matches!(err.error, SendError::BusOff(_)));
    }

    /// The SYNC thread's path: sent from a plain thread, no runtime, and
    /// published as TX like any other send.
    #[tokio::test]
    async fn try_submit_sends_without_a_runtime() {
        let vbus = VirtualBus::new("v", VirtualBusConfig::default());
        let mut other = vbus.connect(false);
        let (h, _c) = start(&vbus);
        let mut sub = h.subscribe(
            FrameSelector {
                transmitted: true,
                ..FrameSelector::default()
            },
            16,
        );
        let sender = h.clone();
        let r = std::thread::spawn(move || sender.try_submit(vec![frame(0x80)]))
            .join()
            .unwrap();
        assert!(matches!(r, Ok(None)));
        assert!(
            matches!(other.recv().await, crate::virtual_bus::PortEvent::Frame { frame, .. } if frame.raw_id() == 0x80)
        );
        assert!(
            matches!(sub.recv().await, Some(BusItem::Frame { direction: Direction::Tx, frame }) if frame.raw_id() == 0x80)
        );
        assert_eq!(h.stats().tx_frames, 1);
    }

    /// A virtual bus whose ports queue a single event: the gateway port's
    /// overflows then count the echoes sent to it while the bus task did
    /// not run. (A `#[tokio::test]` runs on one thread, so the bus task
    /// only runs when the test awaits something pending, and sending on a
    /// virtual bus never does.)
    fn one_slot_bus() -> VirtualBus {
        VirtualBus::new(
            "v",
            VirtualBusConfig {
                port_queue: 1,
                ..VirtualBusConfig::default()
            },
        )
    }

    fn tx_selector(filters: Vec<Filter>) -> FrameSelector {
        FrameSelector {
            filters,
            error_frames: false,
            transmitted: true,
        }
    }

    /// The next item of a subscription; a test fails rather than hangs
    /// when it does not come.
    async fn next_item(sub: &mut Subscription) -> BusItem {
        tokio::time::timeout(Duration::from_secs(5), sub.recv())
            .await
            .expect("an item within 5 s")
            .expect("bus running")
    }

    async fn next_frame(sub: &mut Subscription) -> (u32, Direction) {
        loop {
            match next_item(sub).await {
                BusItem::Frame { frame, direction } => return (frame.raw_id(), direction),
                BusItem::State(_) => {}
                BusItem::Lost(n) => panic!("lost {n}"),
            }
        }
    }

    #[tokio::test]
    async fn reselect_changes_what_a_subscription_gets_from_the_next_frame() {
        let vbus = VirtualBus::new("v", VirtualBusConfig::default());
        let (h, _c) = start_with_bitrate(&vbus, None);
        let mut sub = h.subscribe(
            FrameSelector {
                filters: vec![Filter::exact_standard(0x181)],
                ..FrameSelector::default()
            },
            16,
        );
        let peer = vbus.connect(false);
        peer.send(&frame(0x181)).unwrap();
        peer.send(&frame(0x1A0)).unwrap();
        assert_eq!(next_frame(&mut sub).await, (0x181, Direction::Rx));
        assert!(h.reselect(
            &sub.key(),
            FrameSelector {
                filters: vec![Filter::exact_standard(0x1A0)],
                ..FrameSelector::default()
            }
        ));
        peer.send(&frame(0x181)).unwrap();
        peer.send(&frame(0x1A0)).unwrap();
        assert_eq!(next_frame(&mut sub).await, (0x1A0, Direction::Rx));
        assert!(sub.try_recv().is_none(), "0x181 no longer passes");
        let key = sub.key();
        drop(sub);
        peer.send(&frame(0x1A0)).unwrap();
        // The bus task drops an ended subscriber at its next fan-out.
        for _ in 0..100 {
            if !h.reselect(&key, FrameSelector::default()) {
                return;
            }
            tokio::time::sleep(std::time::Duration::from_millis(5)).await;
        }
        panic!("an ended subscription is still reselectable");
    }

    #[tokio::test]
    async fn own_frames_are_echoed_only_for_subscribers_to_transmitted() {
        let vbus = one_slot_bus();
        let (h, _c) = start_with_bitrate(&vbus, None);
        // Set at spawn: no subscriber, so no echo.
        assert_eq!(h.echo_filters(), Some(Vec::new()));
        let mut rx_only = h.subscribe(FrameSelector::default(), 16);
        assert_eq!(h.echo_filters(), Some(Vec::new()));

        // Sent from this task, the bus task not running in between: with
        // an echo, the second and third frame would overflow the port.
        h.send(vec![frame(0x080)]).await.unwrap();
        h.send(vec![frame(0x181)]).await.unwrap();
        h.try_submit(vec![frame(0x080)]).unwrap();
        assert_eq!(vbus.stats().port_overflows, 0, "nothing was echoed");
        assert_eq!(h.stats().tx_frames, 3, "counted at send time");

        // A subscriber to transmitted 0x080: 0x080 is echoed, 0x181 not.
        let mut tx = h.subscribe(tx_selector(vec![Filter::exact_standard(0x080)]), 16);
        assert_eq!(h.echo_filters(), Some(vec![Filter::exact_standard(0x080)]));
        h.send(vec![frame(0x181), frame(0x080), frame(0x181)])
            .await
            .unwrap();
        assert_eq!(vbus.stats().port_overflows, 0, "only 0x080 was echoed");
        assert_eq!(next_frame(&mut tx).await, (0x080, Direction::Tx));
        h.submit(vec![frame(0x080), frame(0x181)]).await.unwrap();
        assert_eq!(next_frame(&mut tx).await, (0x080, Direction::Tx));
        assert!(tx.try_recv().is_none());
        assert!(rx_only.try_recv().is_none(), "no Tx for an Rx subscriber");

        // Gone: the next fan-out (a peer's frame) narrows the echo again.
        drop(tx);
        let peer = vbus.connect(false);
        peer.send(&frame(0x700)).unwrap();
        assert_eq!(next_frame(&mut rx_only).await, (0x700, Direction::Rx));
        assert_eq!(h.echo_filters(), Some(Vec::new()));
        drop(peer); // Its one-slot queue would overflow, not ours.
        h.send(vec![frame(0x080), frame(0x080)]).await.unwrap();
        assert_eq!(vbus.stats().port_overflows, 0, "nothing was echoed");
    }

    #[tokio::test]
    async fn echo_filter_is_the_union_of_the_transmitted_selectors() {
        let vbus = VirtualBus::new("v", VirtualBusConfig::default());
        let (h, _c) = start_with_bitrate(&vbus, None);
        let a = Filter::exact_standard(0x080);
        let b = Filter::exact_standard(0x181);
        let _rx_only = h.subscribe(
            FrameSelector {
                filters: vec![Filter::exact_standard(0x700)],
                ..FrameSelector::default()
            },
            16,
        );
        let sub_a = h.subscribe(tx_selector(vec![a]), 16);
        let _sub_ab = h.subscribe(tx_selector(vec![a, b]), 16);
        assert_eq!(h.echo_filters(), Some(vec![a, b]), "deduplicated union");
        // No filters: every frame, so the whole echo.
        let all = h.subscribe(tx_selector(Vec::new()), 16);
        assert_eq!(h.echo_filters(), None);
        drop((all, sub_a));
        // A state change fans out too, and drops the closed subscribers.
        vbus.force_bus_off();
        tokio::time::timeout(Duration::from_secs(5), async {
            while h.echo_filters().is_none() {
                tokio::time::sleep(Duration::from_millis(1)).await;
            }
        })
        .await
        .expect("echo filter narrowed");
        assert_eq!(h.echo_filters(), Some(vec![a, b]));
    }

    /// Transmitted frames from every send path and thread reach a
    /// subscriber in order with the echo narrowed to its filter.
    #[tokio::test]
    async fn filtered_echo_keeps_every_wanted_tx_frame_in_order() {
        let vbus = VirtualBus::new("v", VirtualBusConfig::default());
        let (h, _c) = start_with_bitrate(&vbus, None);
        let mut sub = h.subscribe(tx_selector(vec![Filter::exact_standard(0x080)]), 4096);
        let sender = h.clone();
        let thread = std::thread::spawn(move || {
            for i in 0..500u16 {
                let f = Frame::new(CanId::Standard(0x080), &i.to_le_bytes()).unwrap();
                assert!(sender.try_submit(vec![f, frame(0x181)]).unwrap().is_none());
            }
        });
        for i in 0..500u16 {
            let f = Frame::new(CanId::Standard(0x200), &i.to_le_bytes()).unwrap();
            h.send(vec![f, frame(0x080)]).await.unwrap();
        }
        thread.join().unwrap();
        let (mut from_thread, mut from_task) = (0u16, 0);
        while from_thread < 500 || from_task < 500 {
            match next_item(&mut sub).await {
                BusItem::Frame { frame, direction } => {
                    assert_eq!((frame.raw_id(), direction), (0x080, Direction::Tx));
                    if frame.data().len() == 2 {
                        let i = u16::from_le_bytes([frame.data()[0], frame.data()[1]]);
                        assert_eq!(i, from_thread, "in order");
                        from_thread += 1;
                    } else {
                        from_task += 1;
                    }
                }
                other => panic!("{other:?}"),
            }
        }
        assert!(sub.try_recv().is_none());
        assert_eq!(h.stats().tx_frames, 2000);
    }

    /// With a bitrate the load meter needs every frame: the echo stays on
    /// whatever the subscribers want.
    #[tokio::test]
    async fn bus_with_bitrate_keeps_echoing_everything() {
        let vbus = one_slot_bus();
        let (h, _c) = start_with_bitrate(&vbus, Some(1_000_000));
        assert_eq!(h.echo_filters(), None);
        let tx = h.subscribe(tx_selector(vec![Filter::exact_standard(0x080)]), 16);
        assert_eq!(h.echo_filters(), None);
        h.send(vec![frame(0x181), frame(0x181), frame(0x181)])
            .await
            .unwrap();
        assert_eq!(vbus.stats().port_overflows, 2, "all three echoed");
        drop(tx);
        tokio::time::sleep(Duration::from_millis(60)).await;
        assert_eq!(h.echo_filters(), None);
        assert!(h.stats().load_percent > 0.0, "own frames metered");
    }

    /// A bit-timed 1 Mbit/s virtual bus and its gateway handle (paced).
    fn start_bit_timed() -> (VirtualBus, BusHandle, CancellationToken) {
        let vbus = VirtualBus::new(
            "timed",
            VirtualBusConfig {
                bit_timing: Some(BitTiming::new(1_000_000)),
                ..VirtualBusConfig::default()
            },
        );
        let cancel = CancellationToken::new();
        let info = BusInfo {
            name: "can0".into(),
            kind: BackendKind::Virtual,
            interface: vbus.name().into(),
            fd: false,
            bitrate: Some(1_000_000),
            data_bitrate: None,
            bit_timed: true,
            stuffing: Stuffing::Exact,
        };
        let (h, _) = BusHandle::spawn(info, Backend::Virtual(vbus.connect(true)), cancel.clone());
        (vbus, h, cancel)
    }

    /// [`start_bit_timed`] with client frames paced to 1 % of the bus.
    fn start_client_share_1() -> (VirtualBus, BusHandle, CancellationToken) {
        let (vbus, h, c) = start_bit_timed();
        h.set_tx_shares(TxShares {
            client_percent: 1,
            bulk_percent: 50,
        })
        .unwrap();
        (vbus, h, c)
    }

    /// Client frames on the highest-priority identifier, paced to 1 % of
    /// the bus: the gateway's own frame, sent after them, reaches the other
    /// node long before the last of them, and the client's call lasts at
    /// least as long as its share allows.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn client_frames_are_paced_behind_own_frames() {
        let (vbus, h, _c) = start_client_share_1();
        let mut peer = vbus.connect(false);
        let flood: Vec<Frame> = (0..100u8)
            .map(|i| Frame::new(CanId::Standard(0x001), &[i; 8]).unwrap())
            .collect();
        let started = std::time::Instant::now();
        let client = h.clone();
        let flood_task = tokio::spawn(async move { client.send_as(TxClass::Client, flood).await });
        // Let the first chunk go out, then send an own frame.
        loop {
            if let PortEvent::Frame { frame, .. } = peer.recv().await {
                assert_eq!(frame.raw_id(), 0x001);
                break;
            }
        }
        h.send(vec![frame(0x080)]).await.unwrap();
        let mut position = None;
        let mut seen = 1;
        while seen < 101 {
            let PortEvent::Frame { frame, .. } =
                tokio::time::timeout(Duration::from_secs(10), peer.recv())
                    .await
                    .expect("frames keep coming")
            else {
                continue;
            };
            if frame.raw_id() == 0x080 {
                position = Some(seen);
            }
            seen += 1;
        }
        tokio::time::timeout(Duration::from_secs(10), flood_task)
            .await
            .unwrap()
            .unwrap()
            .unwrap();
        let position = position.expect("own frame sent");
        assert!(
            position <= 50,
            "own frame only after {position} client frames"
        );
        // 100 frames of about 111 us at 1 %: about 11 ms of wall time per
        // frame after the first burst.
        assert!(
            started.elapsed() >= Duration::from_millis(500),
            "{:?}",
            started.elapsed()
        );
        let st = h.stats();
        assert!(st.client_frames_delayed >= 90, "{st:?}");
        assert_eq!(st.budget_queued, 0);
        assert_eq!(st.tx_frames, 101);
    }

    /// A queued client batch comes back at once; its outcome is known
    /// without waiting once it is on the bus, and a batch the bus could
    /// not send reports why (and leaves no echo outstanding).
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn queued_client_frames_report_their_outcome_later() {
        let (vbus, h, _c) = start_client_share_1();
        let mut peer = vbus.connect(false);
        let client = ClientId::next();
        let mut one = h.queue_as_client(client, vec![frame(0x123)]).await;
        let got = tokio::time::timeout(Duration::from_secs(5), peer.recv())
            .await
            .expect("the queued frame arrives");
        assert!(matches!(got, PortEvent::Frame { frame, .. } if frame.raw_id() == 0x123));
        let outcome = loop {
            if let Some(o) = one.try_outcome() {
                break o;
            }
            tokio::time::sleep(Duration::from_millis(1)).await;
        };
        assert_eq!(outcome, Ok(()));
        // At 1 % of 1 Mbit/s, 200 frames take about 2 s: bus-off comes
        // first and the rest are not sent.
        let many = h.queue_as_client(client, vec![frame(0x124); 200]).await;
        vbus.force_bus_off();
        let err = tokio::time::timeout(Duration::from_secs(10), many.outcome())
            .await
            .expect("an outcome, not a hang")
            .unwrap_err();
        assert!(err.sent < 200, "{err}");
        assert_eq!(h.shared.counters.client_echo.load(Ordering::Relaxed), 0);
        // Refused before the queue: known at once.
        let mut refused = h.queue_as_client(client, vec![frame(0x125)]).await;
        for _ in 0..2 {
            // The same answer however often it is asked.
            assert!(matches!(
                refused.try_outcome(),
                Some(Err(SendFailure {
                    error: SendError::BusOff(_),
                    ..
                }))
            ));
        }
        assert_eq!(h.shared.counters.client_echo.load(Ordering::Relaxed), 0);
    }

    /// A client batch given up before its outcome (the [`PendingSend`]
    /// dropped: a cancelled call, a closed stream) is withdrawn: what the
    /// share had not let out yet is never sent, and counted; the frames
    /// of the client's next batch follow the ones that did go out.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_dropped_client_batch_is_withdrawn() {
        let (vbus, h, _c) = start_client_share_1();
        let mut peer = vbus.connect(false);
        let client = ClientId::next();
        // About 11 s at 1 % of the bus.
        let pending = h.queue_as_client(client, vec![frame(0x001); 1000]).await;
        // The first frames go out, then the client goes away.
        loop {
            if let PortEvent::Frame { frame, .. } = peer.recv().await {
                assert_eq!(frame.raw_id(), 0x001);
                break;
            }
        }
        drop(pending);
        let t0 = std::time::Instant::now();
        let withdrawn = loop {
            let st = h.stats();
            if st.client_frames_withdrawn > 0 {
                break st.client_frames_withdrawn;
            }
            assert!(t0.elapsed() < Duration::from_secs(10), "{st:?}");
            tokio::time::sleep(Duration::from_millis(1)).await;
        };
        assert!(withdrawn >= 900, "{withdrawn} withdrawn");
        let st = h.stats();
        assert_eq!(st.budget_queued, 0, "{st:?}");
        // A marker behind the sent ones in the client's FIFO: when it
        // arrives, everything that went out before it has too.
        h.send_as_client(client, vec![frame(0x7FE)]).await.unwrap();
        let mut sent = 1u64;
        loop {
            match tokio::time::timeout(Duration::from_secs(10), peer.recv())
                .await
                .expect("the marker arrives")
            {
                PortEvent::Frame { frame, .. } if frame.raw_id() == 0x001 => sent += 1,
                PortEvent::Frame { frame, .. } if frame.raw_id() == 0x7FE => break,
                _ => {}
            }
        }
        assert_eq!(sent + withdrawn, 1000, "{sent} sent, {withdrawn} withdrawn");
        // The echo count is back to zero: nothing is waited for.
        let t0 = std::time::Instant::now();
        while h.shared.counters.client_echo.load(Ordering::Relaxed) != 0 {
            assert!(t0.elapsed() < Duration::from_secs(10));
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
    }

    /// Client frames take only time nobody else needs: a client's frames
    /// on the highest-priority identifier, queued while another node has
    /// a backlog, go out after the whole backlog, although each of them
    /// would have won its arbitration.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn client_frames_wait_while_other_frames_wait_for_the_wire() {
        let (vbus, h, _c) = start_bit_timed();
        let mut watcher = vbus.connect(false);
        let device = vbus.connect(false);
        // About 20 ms of the device's frames, queued at once.
        device.send_batch(&vec![frame(0x701); 200]).unwrap();
        h.send_as_client(ClientId::next(), vec![frame(0x001); 5])
            .await
            .unwrap();
        let mut order = Vec::new();
        while order.len() < 205 {
            if let PortEvent::Frame { frame, .. } =
                tokio::time::timeout(Duration::from_secs(10), watcher.recv())
                    .await
                    .expect("frames keep coming")
            {
                order.push(frame.raw_id());
            }
        }
        let first_client = order.iter().position(|&id| id == 0x001).unwrap();
        assert_eq!(first_client, 200, "a client frame overtook the backlog");
        assert!(h.stats().client_frames_delayed >= 5);
    }

    /// A long client batch waits in front of the wire a chunk of
    /// [`CLIENT_CHUNK_BUS_TIME_NS`] at a time (back-pressure), never as a
    /// whole: the client's backlog there is bounded in bus time.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_long_client_batch_waits_a_chunk_at_a_time() {
        let (vbus, h, _c) = start_client_share_1();
        let mut peer = vbus.connect(false);
        let client = h.clone();
        let batch = vec![frame(0x001); 1000];
        let one = BitTiming::new(1_000_000).frame_duration_ns(&batch[0]);
        let chunk = CLIENT_CHUNK_BUS_TIME_NS / one;
        let sending =
            tokio::spawn(async move { client.send_as_client(ClientId::next(), batch).await });
        let mut most = 0;
        let mut seen = 0;
        while seen < 40 {
            most = most.max(h.stats().budget_queued);
            if let Ok(PortEvent::Frame { .. }) =
                tokio::time::timeout(Duration::from_millis(1), peer.recv()).await
            {
                seen += 1;
            }
        }
        assert!(most > 0 && most <= chunk, "{most} queued, chunk {chunk}");
        // Given up: the rest of its chunk is withdrawn, the later chunks
        // are never queued; all of them count as withdrawn.
        sending.abort();
        let _ = sending.await;
        let t0 = std::time::Instant::now();
        let st = loop {
            let st = h.stats();
            if st.client_frames_withdrawn + st.tx_frames == 1000 {
                break st;
            }
            assert!(t0.elapsed() < Duration::from_secs(10), "{st:?}");
            tokio::time::sleep(Duration::from_millis(1)).await;
        };
        // About 40 sent at 1 %: nearly all the rest withdrawn.
        assert!(st.client_frames_withdrawn >= 500, "{st:?}");
        assert_eq!(st.budget_queued, 0, "{st:?}");
    }

    /// A client that keeps queueing while its share is used up is refused
    /// beyond [`MAX_BUDGET_QUEUED`] frames, with a reason; nothing of the
    /// refused batch is sent, and it is counted.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn client_backlog_is_bounded() {
        let (_vbus, h, _c) = start_client_share_1();
        let batch = |n: usize| vec![frame(0x100); n];
        h.submit_as(TxClass::Client, batch(40_000)).await.unwrap();
        let err = h.send_as(TxClass::Client, batch(20_000)).await.unwrap_err();
        assert_eq!(err.sent, 0);
        assert!(
            matches!(err.error, SendError::BudgetExhausted { percent: 1, .. }),
            "{err}"
        );
        assert!(err.to_string().contains("client_share_percent"), "{err}");
        let st = h.stats();
        assert_eq!(st.client_frames_refused, 20_000);
        assert!(st.budget_queued > 30_000, "{st:?}");
        // Bulk data is not refused: its transfers pace themselves.
        h.submit_as(TxClass::Bulk, batch(20_000)).await.unwrap();
        assert!(
            h.set_tx_shares(TxShares {
                client_percent: 0,
                bulk_percent: 50
            })
            .is_err()
        );
    }

    /// Where frames take no bus time, client frames go out at once.
    #[tokio::test]
    async fn untimed_bus_does_not_pace() {
        let vbus = VirtualBus::new("v", VirtualBusConfig::default());
        let (h, _c) = start(&vbus);
        let mut peer = vbus.connect(false);
        h.send_as(TxClass::Client, vec![frame(0x001); 1000])
            .await
            .unwrap();
        for _ in 0..1000 {
            assert!(matches!(peer.recv().await, PortEvent::Frame { .. }));
        }
        assert_eq!(h.stats().client_frames_delayed, 0);
    }

    fn attach_options(filters: Vec<Filter>, receive_own: bool, fd: bool) -> AttachOptions {
        AttachOptions {
            selector: FrameSelector {
                filters,
                ..FrameSelector::default()
            },
            receive_own,
            fd,
            queue: 64,
        }
    }

    /// The next frame of a subscription with its direction and sender.
    async fn next_marked(sub: &mut Subscription) -> (u32, Direction, Option<ClientId>) {
        loop {
            match next_item(sub).await {
                BusItem::Frame { frame, direction } => {
                    return (frame.raw_id(), direction, frame.sender());
                }
                BusItem::State(_) => {}
                BusItem::Lost(n) => panic!("lost {n}"),
            }
        }
    }

    /// Loopback: a client's frame reaches the wire, every other subscriber
    /// as received (also one that did not ask for transmitted frames, as
    /// the gateway's stacks do not), marked with its sender, and its own
    /// subscription only when asked, as transmitted.
    #[tokio::test]
    async fn client_frames_reach_the_other_subscribers_as_received() {
        let vbus = VirtualBus::new("v", VirtualBusConfig::default());
        let (h, _c) = start(&vbus);
        let mut wire = vbus.connect(false);
        let mut stack = h.subscribe(FrameSelector::default(), 16);
        let mut monitor = h.subscribe(tx_selector(Vec::new()), 16);
        let (a, b) = (ClientId::next(), ClientId::next());
        assert_ne!(a, b);
        let mut own = h.attach(a, attach_options(Vec::new(), true, true));
        let mut quiet = h.attach(a, attach_options(Vec::new(), false, true));
        let mut other = h.attach(b, attach_options(Vec::new(), false, true));

        h.send_as_client(a, vec![frame(0x123)]).await.unwrap();
        assert!(
            matches!(wire.recv().await, PortEvent::Frame { frame, .. } if frame.raw_id() == 0x123)
        );
        let rx = (0x123, Direction::Rx, Some(a));
        assert_eq!(next_marked(&mut stack).await, rx);
        assert_eq!(next_marked(&mut monitor).await, rx);
        assert_eq!(next_marked(&mut other).await, rx);
        assert_eq!(
            next_marked(&mut own).await,
            (0x123, Direction::Tx, Some(a)),
            "its own frame, asked for"
        );

        // The gateway's own frame: transmitted, to the monitor and to the
        // attached clients (nodes on the bus), not to the plain subscriber.
        h.send(vec![frame(0x080)]).await.unwrap();
        let tx = (0x080, Direction::Tx, None);
        assert_eq!(next_marked(&mut monitor).await, tx);
        assert_eq!(next_marked(&mut own).await, tx);
        assert_eq!(next_marked(&mut quiet).await, tx, "not its own frame");
        assert_eq!(next_marked(&mut other).await, tx);
        assert!(stack.try_recv().is_none());

        // A device's frame: received by everyone, unmarked.
        vbus.connect(false).send(&frame(0x701)).unwrap();
        for sub in [&mut stack, &mut monitor, &mut own, &mut quiet, &mut other] {
            assert_eq!(next_marked(sub).await, (0x701, Direction::Rx, None));
        }
        for sub in [&mut stack, &mut monitor, &mut own, &mut quiet, &mut other] {
            assert!(sub.try_recv().is_none());
        }
        let st = h.stats();
        assert_eq!((st.tx_frames, st.rx_frames), (2, 1));
    }

    /// An attached client's filters apply to what it receives, and without
    /// `fd` it gets no CAN FD frames (as a SocketCAN socket without
    /// `CAN_RAW_FD_FRAMES`); the others still get its FD frames.
    #[tokio::test]
    async fn attached_client_filters_and_fd() {
        let vbus = VirtualBus::new("v", VirtualBusConfig::default());
        let (h, _c) = start(&vbus);
        let (a, b) = (ClientId::next(), ClientId::next());
        let mut classic = h.attach(
            a,
            attach_options(vec![Filter::exact_standard(0x100)], true, false),
        );
        let mut all = h.attach(b, attach_options(Vec::new(), false, true));
        let fd = Frame::new_fd(CanId::Standard(0x100), &[1; 12], true, false).unwrap();
        h.send_as_client(b, vec![fd, frame(0x200), frame(0x100)])
            .await
            .unwrap();
        assert_eq!(
            next_marked(&mut classic).await,
            (0x100, Direction::Rx, Some(b))
        );
        assert!(classic.try_recv().is_none(), "no FD frame, nothing else");
        assert!(all.try_recv().is_none(), "its own frames, not asked for");
        h.send_as_client(a, vec![fd]).await.unwrap();
        let (id, direction, sender) = next_marked(&mut all).await;
        assert_eq!((id, direction, sender), (0x100, Direction::Rx, Some(a)));
        h.send(vec![frame(0x100)]).await.unwrap();
        assert_eq!(
            next_marked(&mut classic).await,
            (0x100, Direction::Tx, None),
            "not its own FD frame, but the gateway's next one"
        );
    }

    /// On a bus whose echo follows the subscribers (no load meter), client
    /// frames still reach the subscribers that did not ask for transmitted
    /// frames: the echo opens for them and narrows again once they are
    /// back.
    #[tokio::test]
    async fn client_frames_open_a_narrowed_echo_until_they_are_back() {
        let vbus = VirtualBus::new("v", VirtualBusConfig::default());
        let (h, _c) = start_with_bitrate(&vbus, None);
        let mut stack = h.subscribe(
            FrameSelector {
                filters: vec![Filter::exact_standard(0x581)],
                ..FrameSelector::default()
            },
            16,
        );
        assert_eq!(h.echo_filters(), Some(Vec::new()));
        let client = ClientId::next();
        for round in 0..3u8 {
            h.send_as_client(client, vec![frame(0x581), frame(0x582)])
                .await
                .unwrap();
            assert_eq!(
                next_marked(&mut stack).await,
                (0x581, Direction::Rx, Some(client)),
                "round {round}"
            );
            // Both echoes are back once the bus task handled the second.
            tokio::time::timeout(Duration::from_secs(5), async {
                while h.echo_filters() != Some(Vec::new()) {
                    tokio::time::sleep(Duration::from_millis(1)).await;
                }
            })
            .await
            .expect("echo narrowed again");
        }
        // A refused batch does not leave the echo open either.
        vbus.force_bus_off();
        assert!(h.send_as_client(client, vec![frame(0x581)]).await.is_err());
        assert_eq!(h.echo_filters(), Some(Vec::new()));
        assert!(stack.try_recv().is_none());
    }

    /// A frame of another node that carries a client mark (another gateway
    /// on the same virtual bus) is received like any other frame: unmarked.
    #[tokio::test]
    async fn marks_of_other_nodes_are_dropped() {
        let vbus = VirtualBus::new("v", VirtualBusConfig::default());
        let (h, _c) = start(&vbus);
        let mut sub = h.subscribe(FrameSelector::default(), 16);
        let marked = frame(0x321).with_sender(Some(ClientId::next()));
        vbus.connect(false).send(&marked).unwrap();
        assert_eq!(next_marked(&mut sub).await, (0x321, Direction::Rx, None));
    }

    /// Paced client frames on a bit-timed bus reach the other subscribers
    /// with their bus time, in order; a dropped attachment leaves no
    /// subscriber behind.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn paced_client_frames_are_delivered_with_their_bus_time() {
        let (_vbus, h, _c) = start_bit_timed();
        let mut stack = h.subscribe(FrameSelector::default(), 256);
        let client = ClientId::next();
        let own = h.attach(client, attach_options(Vec::new(), true, false));
        assert_eq!(h.stats().subscribers, 2);
        let before = Timestamp::now();
        let batch: Vec<Frame> = (0..100u8)
            .map(|i| Frame::new(CanId::Standard(0x123), &[i; 8]).unwrap())
            .collect();
        h.send_as_client(client, batch).await.unwrap();
        let mut last = before;
        for i in 0..100u8 {
            let BusItem::Frame { frame, direction } = next_item(&mut stack).await else {
                panic!("a frame");
            };
            assert_eq!((direction, frame.sender()), (Direction::Rx, Some(client)));
            assert_eq!(frame.data(), [i; 8], "in order");
            assert!(frame.timestamp() > last, "bus time");
            last = frame.timestamp();
        }
        drop(own);
        tokio::time::timeout(Duration::from_secs(5), async {
            while h.stats().subscribers != 1 {
                tokio::time::sleep(Duration::from_millis(5)).await;
            }
        })
        .await
        .expect("the attachment's subscription is gone");
    }

    #[tokio::test]
    async fn cancel_ends_subscriptions() {
        let vbus = VirtualBus::new("v", VirtualBusConfig::default());
        let (h, c) = start(&vbus);
        let mut sub = h.subscribe(FrameSelector::default(), 16);
        c.cancel();
        assert_eq!(sub.recv().await, None);
    }
}
