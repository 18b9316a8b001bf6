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
//!
//! This module holds the handle and the types it shares with the task;
//! the owner task itself (sending, pacing, fan-out) is in `task.rs`.

use crate::budget::{Pacer, TxClass, TxShares};
use crate::filter::{Filter, FrameSelector};
use crate::frame::{ClientId, Frame, Timestamp};
use crate::send_error::{SendError, SendFailure};
use crate::socketcan_bus::{SocketCanBus, SocketCanEvent};
use crate::state::BusStatus;
use crate::timing::{BitTiming, LoadMeter, Stuffing};
use crate::virtual_bus::{PortEvent, VirtualPort};
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::{mpsc, oneshot};
use tokio_util::sync::CancellationToken;

mod task;

use task::{client_echo_begin, client_echo_end, run_bus, update_echo};

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
    /// An own frame given up (SocketCAN transmit queue).
    Unsent(Frame),
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
                SocketCanEvent::Unsent(frame) => BackendEvent::Unsent(frame),
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
    /// The gateway's own frames the interface gave up (see
    /// [`BusHandle::subscribe_unsent`]).
    unsent: tokio::sync::broadcast::Sender<Frame>,
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

/// Given-up frames kept for a [`BusHandle::subscribe_unsent`] receiver
/// that has not taken them yet.
const UNSENT_NOTICES: usize = 64;

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
            unsent: tokio::sync::broadcast::channel(UNSENT_NOTICES).0,
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

    /// Every frame the interface gave up from now on (its transmit queue
    /// stayed full past the backend's timeout, or the interface went
    /// away), whoever sent it. A protocol stack that submits requests
    /// without waiting for their outcome ([`BusHandle::submit`]) and waits
    /// for an answer ends that wait at once instead of at its own timeout. Frames given up while the
    /// receiver lags behind by more than a few dozen are skipped (the
    /// receiver sees `Lagged`; they are still counted in `tx_failed`).
    /// Virtual buses give nothing up.
    pub fn subscribe_unsent(&self) -> tokio::sync::broadcast::Receiver<Frame> {
        self.shared.unsent.subscribe()
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

#[cfg(test)]
mod tests;
