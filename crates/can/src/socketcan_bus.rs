//! The Linux SocketCAN backend.
//!
//! One raw CAN FD-capable socket per interface (opened by the `socketcan`
//! crate), error frames enabled and decoded into [`BusStatus`]. When the
//! interface goes down or disappears, the backend reports [`BusState::Down`]
//! and reconnects with exponential backoff (100 ms up to 5 s) once the
//! interface is up again; it never gives up.
//!
//! # Receiving: nothing lost unseen
//!
//! Frames are read with our own `recvmsg` (through `nix`, no `unsafe`), which
//! takes two control messages: the kernel's receive time (`SO_TIMESTAMPNS`)
//! and its drop count (`SO_RXQ_OVFL`): the frames the kernel discarded
//! because the socket's receive buffer was full before we read them. That
//! count is cumulative per socket and rides on the next frame that does get
//! in, so the difference to the previous one is exactly the number of frames
//! lost just before that frame: [`SocketCanEvent::Lost`], which the bus task
//! reports in its statistics and, at that position, in every subscriber's
//! stream. The receive buffer's size is configurable
//! ([`SocketCanOptions::receive_buffer`]).
//!
//! # Transmitting: back-pressure without loss
//!
//! When the interface's queue (its queueing discipline, `txqueuelen`) is
//! full, the kernel refuses a frame with `ENOBUFS`, which no readiness event
//! announces the end of. Frames are therefore held in a bounded transmit
//! queue and offered again every [`TX_RETRY`]: the gateway's own frames
//! before bulk data and client raw frames, whatever the identifiers (a
//! client's flood on 0x001 must not hold back the SYNC), and in CAN
//! arbitration order within each (lowest identifier first, as the wire
//! would send them; FIFO among equal identifiers), so the gateway's own
//! SYNC (0x080), NMT (0x000) and set-points (RPDOs, 0x200-0x5FF) overtake
//! its SDO (0x580-0x67F) while the interface is congested (see
//! [`held_key`]). While nothing is held, frames
//! go straight to the socket in submission order. A frame held longer than
//! [`SocketCanOptions::transmit_timeout`], or pushed out of a full queue by a
//! more urgent one, is given up: counted ([`SocketCanEvent::Unsent`], the
//! bus's `tx_failed`), logged, and reported to a waiting sender.

use crate::budget::TxClass;
use crate::frame::{CanId, Frame, FrameKind, Timestamp};
use crate::send_error::{SendError, SendFailure};
use crate::state::{BusState, BusStatus, status_from_error_frame};
use nix::sys::socket::{ControlMessageOwned, MsgFlags, recvmsg, setsockopt, sockopt};
use socketcan::id::FdFlags;
use socketcan::{
    CanAnyFrame, CanDataFrame, CanFdFrame, CanRemoteFrame, EmbeddedFrame, ExtendedId, Id, Socket,
    SocketOptions, StandardId,
};
use std::collections::{BTreeMap, HashMap, VecDeque};
use std::io::IoSliceMut;
use std::os::fd::AsRawFd;
use std::time::Duration;
use tokio::io::Interest;
use tokio::io::unix::AsyncFd;
use tokio::sync::oneshot;
use tokio::time::Instant;

/// Events from the SocketCAN backend.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SocketCanEvent {
    /// A frame (data, remote or error) with its kernel timestamp.
    Frame(Frame),
    /// The interface state changed (down, up, error states from error frames).
    State(BusStatus),
    /// The kernel dropped this many received frames (the socket's receive
    /// buffer was full) just before the next [`SocketCanEvent::Frame`].
    Lost(u64),
    /// One of our frames was accepted by the kernel for transmission, stamped
    /// with that moment.
    Sent(Frame),
    /// One of our frames could not be sent (transmit queue full, held past
    /// the timeout, refused by the kernel, or the interface went away): the
    /// frame, so that the protocol that sent it can end what waits for an
    /// answer to it.
    Unsent(Frame),
}

/// Per-bus settings of the SocketCAN backend.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SocketCanOptions {
    /// The socket's receive buffer in bytes (`SO_RCVBUF`; the kernel doubles
    /// the value for its bookkeeping and, unless the process has
    /// `CAP_NET_ADMIN`, caps it at `net.core.rmem_max`). `None`: the
    /// kernel's default (`net.core.rmem_default`).
    pub receive_buffer: Option<usize>,
    /// Frames held for retry while the interface's queue is full.
    pub transmit_queue: usize,
    /// How long a held frame is offered again before it is given up.
    pub transmit_timeout: Duration,
}

/// Default of [`SocketCanOptions::transmit_queue`].
pub const DEFAULT_TRANSMIT_QUEUE: usize = 1024;
/// Default of [`SocketCanOptions::transmit_timeout`]: long enough to ride
/// out a burst on a busy bus, short enough that a SYNC or set-point is not
/// sent when it is long stale.
pub const DEFAULT_TRANSMIT_TIMEOUT: Duration = Duration::from_millis(250);

impl Default for SocketCanOptions {
    fn default() -> Self {
        SocketCanOptions {
            receive_buffer: None,
            transmit_queue: DEFAULT_TRANSMIT_QUEUE,
            transmit_timeout: DEFAULT_TRANSMIT_TIMEOUT,
        }
    }
}

/// How soon held frames are offered again after `ENOBUFS`: no readiness
/// event announces room in the interface's queue, so it is polled. A
/// classic frame takes 50-130 µs at 1 Mbit/s, so a real adapter's default
/// queue of 10 frames drains in about a millisecond.
pub const TX_RETRY: Duration = Duration::from_millis(1);

/// Where the result of a [`SocketCanBus::queue`] batch goes once every
/// frame of it was sent or given up.
pub type SendReply = oneshot::Sender<Result<(), SendFailure>>;

/// Transmit counters of one SocketCAN bus since it was opened.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TxCounters {
    /// Times a frame was refused for lack of room (`ENOBUFS`, `EAGAIN`) and
    /// kept for another attempt.
    pub retries: u64,
    /// Frames given up (the sum of every [`SocketCanEvent::Unsent`]).
    pub unsent: u64,
    /// Frames held right now.
    pub queued: usize,
}

/// Something ready for the bus task, in order: events are returned by
/// [`SocketCanBus::recv`]; a reply is sent once the events before it (the
/// batch's [`SocketCanEvent::Sent`]) were handed over, so a sender that gets
/// its answer finds the frames counted.
enum Ready {
    Event(SocketCanEvent),
    Reply(SendReply, Result<(), SendFailure>),
}

struct Held {
    frame: Frame,
    batch: Option<u64>,
    deadline: Instant,
}

struct Batch {
    reply: SendReply,
    total: usize,
    sent: usize,
    open: usize,
    error: Option<SendError>,
}

/// Frames held for retry, in [`held_key`] order, and the batches waiting
/// for them.
#[derive(Default)]
struct TxQueue {
    /// Keyed by ([`held_key`], submission number).
    held: BTreeMap<(u64, u64), Held>,
    batches: HashMap<u64, Batch>,
    next_seq: u64,
    next_batch: u64,
}

/// A SocketCAN interface that survives the interface going away.
pub struct SocketCanBus {
    interface: String,
    options: SocketCanOptions,
    socket: Option<AsyncFd<socketcan::CanFdSocket>>,
    status: BusStatus,
    backoff: Duration,
    /// A state change to report before anything else.
    pending_state: Option<BusStatus>,
    /// Deadlines kept across calls: `recv` is cancelled whenever the bus
    /// task's select! picks another branch (every 20 ms tick).
    next_link_check: Option<Instant>,
    next_reconnect: Option<Instant>,
    /// The control-message buffer of `recvmsg`, allocated once.
    cmsg: Vec<u8>,
    /// The socket's cumulative drop count as last reported (per socket).
    kernel_drops_seen: u32,
    /// Frames the kernel dropped on every socket of this bus.
    rx_dropped: u64,
    tx: TxQueue,
    /// When held frames are offered again.
    retry_at: Option<Instant>,
    tx_counters: TxCounters,
    ready: VecDeque<Ready>,
    /// Frames given up since the last log line (logged at most once a
    /// second: under sustained congestion there is one per retry).
    unsent_unlogged: u64,
    unsent_logged_at: Option<Instant>,
}

impl std::fmt::Debug for SocketCanBus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SocketCanBus")
            .field("interface", &self.interface)
            .field("status", &self.status)
            .finish()
    }
}

const MIN_BACKOFF: Duration = Duration::from_millis(100);
const MAX_BACKOFF: Duration = Duration::from_secs(5);
/// How often a connected bus checks the interface's IFF_UP flag, so that
/// `ip link set dev X down` is noticed even when the bus is silent.
const LINK_POLL: Duration = Duration::from_millis(250);
/// `CAN_MTU` and `CANFD_MTU`: the sizes of `struct can_frame` and
/// `struct canfd_frame`.
const CAN_MTU: usize = 16;
const CANFD_MTU: usize = 72;
const CAN_EFF_FLAG: u32 = 0x8000_0000;
const CAN_RTR_FLAG: u32 = 0x4000_0000;
const CAN_ERR_FLAG: u32 = 0x2000_0000;
const CANFD_BRS: u8 = 0x01;
const CANFD_ESI: u8 = 0x02;

/// Whether the interface exists (`Some`) and is administratively up.
pub fn interface_is_up(interface: &str) -> Option<bool> {
    let flags = std::fs::read_to_string(format!("/sys/class/net/{interface}/flags")).ok()?;
    let flags = u32::from_str_radix(flags.trim().trim_start_matches("0x"), 16).ok()?;
    Some(flags & 0x1 != 0)
}

impl SocketCanBus {
    /// Opens the interface with default options (see [`SocketCanBus::open_with`]).
    pub fn open(interface: &str) -> std::io::Result<Self> {
        Self::open_with(interface, SocketCanOptions::default())
    }

    /// Opens the interface. Fails if the interface does not exist, so a
    /// configuration error is caught at start-up; later disappearances are
    /// handled by reconnecting.
    pub fn open_with(interface: &str, options: SocketCanOptions) -> std::io::Result<Self> {
        if interface_is_up(interface).is_none() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::NotFound,
                format!("CAN interface {interface} does not exist"),
            ));
        }
        let mut bus = SocketCanBus {
            interface: interface.to_string(),
            options,
            socket: None,
            status: BusStatus::DOWN,
            backoff: MIN_BACKOFF,
            pending_state: None,
            next_link_check: None,
            next_reconnect: None,
            cmsg: nix::cmsg_space!(nix::sys::time::TimeSpec, u32),
            kernel_drops_seen: 0,
            rx_dropped: 0,
            tx: TxQueue::default(),
            retry_at: None,
            tx_counters: TxCounters::default(),
            ready: VecDeque::new(),
            unsent_unlogged: 0,
            unsent_logged_at: None,
        };
        if interface_is_up(interface) == Some(true) {
            bus.connect()?;
        }
        Ok(bus)
    }

    fn connect(&mut self) -> std::io::Result<()> {
        let sock = socketcan::CanFdSocket::open(&self.interface)?;
        sock.set_nonblocking(true)?;
        sock.set_error_filter_accept_all()?;
        sock.set_recv_timestamp(true)?;
        setsockopt(&sock, sockopt::RxqOvfl, &1).map_err(std::io::Error::from)?;
        if let Some(bytes) = self.options.receive_buffer {
            // Past net.core.rmem_max only with CAP_NET_ADMIN; otherwise the
            // kernel caps the plain option silently, so log what we got.
            if setsockopt(&sock, sockopt::RcvBufForce, &bytes).is_err() {
                setsockopt(&sock, sockopt::RcvBuf, &bytes).map_err(std::io::Error::from)?;
            }
            let effective = nix::sys::socket::getsockopt(&sock, sockopt::RcvBuf).ok();
            tracing::debug!(interface = %self.interface, requested = bytes, ?effective, "receive buffer set");
        }
        // `AsyncFd::new` is deprecated because a `T` that does not own its
        // descriptor could close it under the reactor; the socket owns its
        // descriptor (an `OwnedFd` inside) for as long as the `AsyncFd`
        // holds it, which is the condition of the unsafe `register`.
        #[allow(deprecated)]
        let sock = AsyncFd::new(sock)?;
        self.socket = Some(sock);
        self.kernel_drops_seen = 0;
        self.backoff = MIN_BACKOFF;
        self.set_status(BusStatus::UP);
        Ok(())
    }

    fn disconnect(&mut self, why: &std::io::Error) {
        if self.socket.take().is_some() {
            tracing::warn!(interface = %self.interface, error = %why, "CAN interface lost; reconnecting");
        }
        self.set_status(BusStatus::DOWN);
        let error = SendError::Down(self.interface.clone());
        let held = std::mem::take(&mut self.tx.held);
        for (_, h) in held {
            self.give_up(h.frame, h.batch, error.clone());
        }
        self.retry_at = None;
        self.log_unsent(Instant::now(), true);
    }

    fn set_status(&mut self, status: BusStatus) {
        if status != self.status {
            self.status = status;
            self.pending_state = Some(status);
        }
    }

    /// Interface name.
    pub fn interface(&self) -> &str {
        &self.interface
    }

    /// Current status.
    pub fn status(&self) -> BusStatus {
        self.status
    }

    /// Received frames the kernel dropped before they were read, since the
    /// bus was opened.
    pub fn rx_dropped(&self) -> u64 {
        self.rx_dropped
    }

    /// Transmit counters.
    pub fn tx_counters(&self) -> TxCounters {
        TxCounters {
            queued: self.tx.held.len(),
            ..self.tx_counters
        }
    }

    /// Waits for the next event. Never returns an error: failures become
    /// [`BusState::Down`] and reconnection attempts. Also offers held
    /// frames again when their retry is due, and answers the senders of
    /// finished batches.
    pub async fn recv(&mut self) -> SocketCanEvent {
        loop {
            if let Some(s) = self.pending_state.take() {
                return SocketCanEvent::State(s);
            }
            match self.ready.pop_front() {
                Some(Ready::Event(ev)) => return ev,
                Some(Ready::Reply(reply, result)) => {
                    let _ = reply.send(result);
                    continue;
                }
                None => {}
            }
            if self.retry_at.is_some_and(|at| at <= Instant::now()) {
                self.flush(Instant::now());
                continue;
            }
            if self.socket.is_none() {
                let at = *self
                    .next_reconnect
                    .get_or_insert_with(|| Instant::now() + self.backoff);
                tokio::time::sleep_until(at).await;
                self.next_reconnect = None;
                self.backoff = (self.backoff * 2).min(MAX_BACKOFF);
                if interface_is_up(&self.interface) == Some(true)
                    && let Err(e) = self.connect()
                {
                    tracing::debug!(interface = %self.interface, error = %e, "reconnect failed");
                }
                continue;
            }
            let check_at = *self
                .next_link_check
                .get_or_insert_with(|| Instant::now() + LINK_POLL);
            let retry_at = self.retry_at;
            let sock = self.socket.as_ref().expect("connected");
            let cmsg = &mut self.cmsg;
            let result = tokio::select! {
                r = sock.async_io(Interest::READABLE, |s| receive(s.as_raw_fd(), cmsg)) => Some(r),
                _ = tokio::time::sleep_until(check_at) => None,
                _ = sleep_until_some(retry_at) => continue,
            };
            match result {
                None => {
                    self.next_link_check = None;
                    if interface_is_up(&self.interface) != Some(true) {
                        self.disconnect(&std::io::Error::other("interface is down"));
                    }
                }
                Some(Err(e)) => self.disconnect(&e),
                Some(Ok(received)) => {
                    if let Some(total) = received.drops {
                        // Cumulative per socket, wrapping at 2^32.
                        let new = total.wrapping_sub(self.kernel_drops_seen);
                        self.kernel_drops_seen = total;
                        if new > 0 {
                            self.rx_dropped += u64::from(new);
                            if let Some(frame) = received.frame {
                                let ev = self.received(frame);
                                self.ready.push_back(Ready::Event(ev));
                            }
                            return SocketCanEvent::Lost(u64::from(new));
                        }
                    }
                    if let Some(frame) = received.frame {
                        return self.received(frame);
                    }
                }
            }
        }
    }

    /// Ends the bus: gives up every held frame, answers every waiting
    /// sender, and returns the events not yet taken by [`SocketCanBus::recv`]
    /// (the transmit outcomes among them still have to be counted).
    pub fn abandon(&mut self) -> Vec<SocketCanEvent> {
        let held = std::mem::take(&mut self.tx.held);
        for (_, h) in held {
            self.give_up(h.frame, h.batch, SendError::Down(self.interface.clone()));
        }
        self.retry_at = None;
        self.log_unsent(Instant::now(), true);
        let mut events = Vec::new();
        for r in self.ready.drain(..) {
            match r {
                Ready::Event(ev) => events.push(ev),
                Ready::Reply(reply, result) => {
                    let _ = reply.send(result);
                }
            }
        }
        events
    }

    fn received(&mut self, frame: Frame) -> SocketCanEvent {
        if let Some(s) = status_from_error_frame(&frame, self.status) {
            self.set_status(s);
        }
        SocketCanEvent::Frame(frame)
    }

    /// Queues a batch for transmission and sends what the interface takes
    /// right now, without waiting. The outcome of every frame comes out of
    /// [`SocketCanBus::recv`] ([`SocketCanEvent::Sent`] or
    /// [`SocketCanEvent::Unsent`]), followed by the batch's answer on
    /// `reply`: `Ok` when every frame was sent.
    pub fn queue(&mut self, frames: Vec<Frame>, reply: Option<SendReply>) {
        self.queue_as(TxClass::Control, frames, reply);
    }

    /// [`SocketCanBus::queue`] for frames of `class`: while frames are
    /// held, the gateway's own go first whatever the identifiers (see
    /// [`held_key`]), and a full queue gives up client frames first.
    pub fn queue_as(&mut self, class: TxClass, frames: Vec<Frame>, reply: Option<SendReply>) {
        let now = Instant::now();
        let batch = reply.map(|reply| {
            let id = self.tx.next_batch;
            self.tx.next_batch += 1;
            self.tx.batches.insert(
                id,
                Batch {
                    reply,
                    total: frames.len(),
                    sent: 0,
                    open: frames.len(),
                    error: None,
                },
            );
            id
        });
        if let Some(id) = batch
            && frames.is_empty()
        {
            self.finish_batch(id);
        }
        let refused = if self.socket.is_none() {
            Some(SendError::Down(self.interface.clone()))
        } else if self.status.state == BusState::BusOff {
            Some(SendError::BusOff(self.interface.clone()))
        } else {
            None
        };
        for frame in frames {
            if let Some(error) = &refused {
                self.give_up(frame, batch, error.clone());
                continue;
            }
            if to_socketcan(&frame).is_none() {
                self.give_up(
                    frame,
                    batch,
                    SendError::Io {
                        bus: self.interface.clone(),
                        message: format!("frame {frame} cannot be represented"),
                    },
                );
                continue;
            }
            let key = (held_key(class, &frame), self.tx.next_seq);
            self.tx.next_seq += 1;
            if self.tx.held.len() >= self.options.transmit_queue.max(1) {
                // Full: the least urgent frame makes room, or is this one.
                let last = *self.tx.held.keys().next_back().expect("queue is full");
                if key.0 >= last.0 {
                    self.give_up(frame, batch, self.queue_full());
                    continue;
                }
                let evicted = self.tx.held.remove(&last).expect("present");
                self.give_up(evicted.frame, evicted.batch, self.queue_full());
            }
            self.tx.held.insert(
                key,
                Held {
                    frame,
                    batch,
                    deadline: now + self.options.transmit_timeout,
                },
            );
            // Nothing else held: the interface has room, so this frame goes
            // to the socket now, before the next of its batch is looked
            // at. A batch keeps its order (a sender's frames leave in the
            // order it sent them, as on a socket of its own); arbitration
            // order applies only to frames held while the queue is full.
            if self.tx.held.len() == 1 {
                self.flush(now);
            }
        }
        self.flush(now);
        self.log_unsent(now, false);
    }

    fn queue_full(&self) -> SendError {
        SendError::Io {
            bus: self.interface.clone(),
            message: format!(
                "transmit queue full ({} frames waiting for the interface) and this frame \
                 was the least urgent",
                self.options.transmit_queue
            ),
        }
    }

    /// Writes held frames, most urgent first, until the kernel has no more
    /// room; gives up those held past their deadline.
    fn flush(&mut self, now: Instant) {
        self.retry_at = None;
        if self.tx.held.values().any(|h| h.deadline <= now) {
            let timeout = self.options.transmit_timeout;
            let expired: Vec<_> = self
                .tx
                .held
                .iter()
                .filter(|(_, h)| h.deadline <= now)
                .map(|(k, _)| *k)
                .collect();
            for key in expired {
                let h = self.tx.held.remove(&key).expect("present");
                self.give_up(
                    h.frame,
                    h.batch,
                    SendError::Io {
                        bus: self.interface.clone(),
                        message: format!(
                            "the interface's transmit queue stayed full for {} ms",
                            timeout.as_millis()
                        ),
                    },
                );
            }
        }
        while let Some(entry) = self.tx.held.first_entry() {
            let Some(sock) = self.socket.as_ref() else {
                return;
            };
            let frame = entry.get().frame;
            let result = match to_socketcan(&frame).expect("checked when queued") {
                CanAnyFrame::Fd(f) => sock.get_ref().write_frame(&f),
                CanAnyFrame::Normal(f) => sock.get_ref().write_frame(&f),
                CanAnyFrame::Remote(f) => sock.get_ref().write_frame(&f),
                CanAnyFrame::Error(_) => Ok(()),
            };
            match result {
                Ok(()) => {
                    let held = entry.remove();
                    let frame = held.frame.with_timestamp(Timestamp::now());
                    self.ready
                        .push_back(Ready::Event(SocketCanEvent::Sent(frame)));
                    if let Some(id) = held.batch
                        && let Some(b) = self.tx.batches.get_mut(&id)
                    {
                        b.sent += 1;
                        b.open -= 1;
                        if b.open == 0 {
                            self.finish_batch(id);
                        }
                    }
                }
                // No room in the interface's queue (ENOBUFS) or in the
                // socket's send buffer (EAGAIN): keep it for the next try.
                Err(e) if matches!(e.raw_os_error(), Some(libc::ENOBUFS) | Some(libc::EAGAIN)) => {
                    self.tx_counters.retries += 1;
                    self.retry_at = Some(now + TX_RETRY);
                    return;
                }
                Err(e) if matches!(e.raw_os_error(), Some(libc::ENETDOWN) | Some(libc::ENODEV)) => {
                    self.disconnect(&e);
                    return;
                }
                Err(e) => {
                    let held = entry.remove();
                    let error = if e.raw_os_error() == Some(libc::EINVAL) && frame.is_fd() {
                        SendError::FdNotSupported(self.interface.clone())
                    } else {
                        SendError::Io {
                            bus: self.interface.clone(),
                            message: e.to_string(),
                        }
                    };
                    self.give_up(held.frame, held.batch, error);
                }
            }
        }
    }

    /// Counts a frame as not sent and records why in its batch.
    fn give_up(&mut self, frame: Frame, batch: Option<u64>, error: SendError) {
        self.tx_counters.unsent += 1;
        self.unsent_unlogged += 1;
        self.ready
            .push_back(Ready::Event(SocketCanEvent::Unsent(frame)));
        if let Some(id) = batch
            && let Some(b) = self.tx.batches.get_mut(&id)
        {
            b.open -= 1;
            b.error.get_or_insert(error);
            if b.open == 0 {
                self.finish_batch(id);
            }
        }
    }

    fn finish_batch(&mut self, id: u64) {
        let Some(b) = self.tx.batches.remove(&id) else {
            return;
        };
        let result = match b.error {
            None => Ok(()),
            Some(error) => Err(SendFailure {
                sent: b.sent,
                total: b.total,
                error,
            }),
        };
        self.ready.push_back(Ready::Reply(b.reply, result));
    }

    /// One warning a second at most for frames given up.
    fn log_unsent(&mut self, now: Instant, force: bool) {
        if self.unsent_unlogged == 0 {
            return;
        }
        if !force
            && self
                .unsent_logged_at
                .is_some_and(|at| now < at + Duration::from_secs(1))
        {
            return;
        }
        tracing::warn!(
            interface = %self.interface,
            frames = self.unsent_unlogged,
            total = self.tx_counters.unsent,
            "frames not sent (interface queue full, timed out or interface down)"
        );
        self.unsent_unlogged = 0;
        self.unsent_logged_at = Some(now);
    }
}

/// Sleeps until `at`, or forever.
async fn sleep_until_some(at: Option<Instant>) {
    match at {
        Some(at) => tokio::time::sleep_until(at).await,
        None => std::future::pending().await,
    }
}

/// What one `recvmsg` brought.
struct Received {
    /// `None` for something that is not a CAN frame we know.
    frame: Option<Frame>,
    /// The socket's cumulative drop count, when the kernel sent it (it
    /// does once it is non-zero).
    drops: Option<u32>,
}

/// Reads one frame with its control messages from the non-blocking socket.
fn receive(fd: std::os::fd::RawFd, cmsg: &mut [u8]) -> std::io::Result<Received> {
    let mut buf = [0u8; CANFD_MTU];
    let (bytes, stamp, drops) = {
        let mut iov = [IoSliceMut::new(&mut buf)];
        let msg = recvmsg::<()>(fd, &mut iov, Some(cmsg), MsgFlags::MSG_TRUNC)
            .map_err(std::io::Error::from)?;
        let mut stamp = None;
        let mut drops = None;
        for c in msg.cmsgs().map_err(std::io::Error::from)? {
            match c {
                ControlMessageOwned::ScmTimestampns(ts) => {
                    let ns = ts.tv_sec() as i128 * 1_000_000_000 + ts.tv_nsec() as i128;
                    stamp = u64::try_from(ns).ok().map(Timestamp);
                }
                ControlMessageOwned::RxqOvfl(n) => drops = Some(n),
                _ => {}
            }
        }
        (msg.bytes, stamp, drops)
    };
    let frame =
        parse_frame(&buf, bytes).map(|f| f.with_timestamp(stamp.unwrap_or_else(Timestamp::now)));
    Ok(Received { frame, drops })
}

/// A `struct can_frame` (`n` = 16) or `struct canfd_frame` (72) as our
/// frame; `None` for other sizes or invalid contents.
fn parse_frame(buf: &[u8; CANFD_MTU], n: usize) -> Option<Frame> {
    let can_id = u32::from_ne_bytes([buf[0], buf[1], buf[2], buf[3]]);
    let len = usize::from(buf[4]);
    let flags = buf[5];
    let extended = can_id & CAN_EFF_FLAG != 0;
    let raw = can_id & if extended { 0x1FFF_FFFF } else { 0x7FF };
    match n {
        CAN_MTU if can_id & CAN_ERR_FLAG != 0 => {
            let mut data = [0u8; 8];
            data.copy_from_slice(&buf[8..16]);
            Some(Frame::new_error(can_id & 0x1FFF_FFFF, data))
        }
        CAN_MTU if can_id & CAN_RTR_FLAG != 0 => {
            Frame::new_remote(CanId::new(raw, extended).ok()?, buf[4]).ok()
        }
        CAN_MTU => Frame::new(CanId::new(raw, extended).ok()?, buf.get(8..8 + len.min(8))?).ok(),
        CANFD_MTU => Frame::new_fd(
            CanId::new(raw, extended).ok()?,
            buf.get(8..8 + len)?,
            flags & CANFD_BRS != 0,
            flags & CANFD_ESI != 0,
        )
        .ok(),
        _ => None,
    }
}

/// The order in which held frames are offered to the interface: by class
/// first (the gateway's own, then bulk data, then client raw frames), in
/// arbitration order within a class. Why not arbitration order alone: a
/// client flooding identifier 0x001 would then be written before the SYNC
/// (0x080) and the set-points every time the interface had room, and its
/// backlog would hold them back for as long as it lasted.
pub fn held_key(class: TxClass, frame: &Frame) -> u64 {
    (u64::from(class.lane()) << 40) | arbitration_key(frame)
}

/// The order in which CAN arbitration would send frames: the 11-bit base
/// identifier first, then a standard frame before an extended one with the
/// same base, then the extended bits, and a data frame before a remote
/// request with the same identifier.
pub fn arbitration_key(frame: &Frame) -> u64 {
    let id = u64::from(frame.raw_id());
    let rtr = u64::from(frame.kind() == FrameKind::Remote);
    let (base, ide, low) = if frame.is_extended() {
        (id >> 18, 1, id & 0x3_FFFF)
    } else {
        (id, 0, 0)
    };
    (((base << 1 | ide) << 18 | low) << 1) | rtr
}

fn hal_id(id: CanId) -> Option<Id> {
    Some(match id {
        CanId::Standard(i) => Id::Standard(StandardId::new(i)?),
        CanId::Extended(i) => Id::Extended(ExtendedId::new(i)?),
    })
}

/// Converts our frame to the socketcan crate's.
pub fn to_socketcan(frame: &Frame) -> Option<CanAnyFrame> {
    let id = hal_id(frame.id())?;
    Some(match frame.kind() {
        FrameKind::Data if frame.is_fd() => {
            let mut flags = FdFlags::empty();
            if frame.brs() {
                flags |= FdFlags::BRS;
            }
            if frame.esi() {
                flags |= FdFlags::ESI;
            }
            CanAnyFrame::Fd(CanFdFrame::with_flags(id, frame.data(), flags)?)
        }
        FrameKind::Data => CanAnyFrame::Normal(CanDataFrame::new(id, frame.data())?),
        FrameKind::Remote => {
            CanAnyFrame::Remote(CanRemoteFrame::new_remote(id, frame.dlc() as usize)?)
        }
        FrameKind::Error => return None,
    })
}

/// Converts the socketcan crate's frame to ours.
pub fn from_socketcan(any: &CanAnyFrame) -> Option<Frame> {
    use socketcan::Frame as _;
    let cid = |ext: bool, raw: u32| CanId::new(raw, ext).ok();
    match any {
        CanAnyFrame::Normal(f) => Frame::new(cid(f.is_extended(), f.raw_id())?, f.data()).ok(),
        CanAnyFrame::Remote(f) => {
            Frame::new_remote(cid(f.is_extended(), f.raw_id())?, f.dlc() as u8).ok()
        }
        CanAnyFrame::Fd(f) => Frame::new_fd(
            cid(f.is_extended(), f.raw_id())?,
            f.data(),
            f.is_brs(),
            f.flags().contains(FdFlags::ESI),
        )
        .ok(),
        CanAnyFrame::Error(f) => {
            let mut data = [0u8; 8];
            let d = f.data();
            data[..d.len().min(8)].copy_from_slice(&d[..d.len().min(8)]);
            Some(Frame::new_error(f.id_word() & 0x1FFF_FFFF, data))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conversion_round_trips() {
        let frames: Vec<Frame> = [
            "123#DEADBEEF",
            "1F334455#0102",
            "123#R4",
            "7FF#",
            "00000001##3AABBCCDDEEFF001122334455",
        ]
        .iter()
        .map(|s| s.parse().unwrap())
        .collect();
        for f in frames {
            let back = from_socketcan(&to_socketcan(&f).unwrap()).unwrap();
            assert_eq!(back, f, "{f}");
        }
    }

    /// A `struct can_frame` (`fd` false) or `struct canfd_frame` as the
    /// kernel hands it to `recvmsg`.
    fn raw(can_id: u32, len: u8, flags: u8, data: &[u8], fd: bool) -> ([u8; CANFD_MTU], usize) {
        let mut buf = [0u8; CANFD_MTU];
        buf[..4].copy_from_slice(&can_id.to_ne_bytes());
        buf[4] = len;
        buf[5] = flags;
        buf[8..8 + data.len()].copy_from_slice(data);
        (buf, if fd { CANFD_MTU } else { CAN_MTU })
    }

    #[test]
    fn kernel_structures_parse() {
        let cases = [
            (
                raw(0x123, 4, 0, &[0xDE, 0xAD, 0xBE, 0xEF], false),
                "123#DEADBEEF",
            ),
            (
                raw(0x1F33_4455 | CAN_EFF_FLAG, 2, 0, &[1, 2], false),
                "1F334455#0102",
            ),
            (raw(0x123 | CAN_RTR_FLAG, 4, 0, &[], false), "123#R4"),
            (raw(0x7FF, 0, 0, &[], false), "7FF#"),
            (
                raw(
                    1 | CAN_EFF_FLAG,
                    16,
                    CANFD_BRS | CANFD_ESI | 0x04,
                    &[
                        0xAA, 0xBB, 0xCC, 0xDD, 0xEE, 0xFF, 0, 0x11, 0x22, 0x33, 0x44, 0x55, 0, 0,
                        0, 0,
                    ],
                    true,
                ),
                "00000001##3AABBCCDDEEFF00112233445500000000",
            ),
            (raw(0x456, 0, CANFD_BRS, &[], true), "456##1"),
        ];
        for ((buf, n), text) in cases {
            let want: Frame = text.parse().unwrap();
            assert_eq!(parse_frame(&buf, n), Some(want), "{text}");
        }
        let (buf, n) = raw(
            CAN_ERR_FLAG | 0x04,
            8,
            0,
            &[0, 0x10, 0, 0, 0, 0, 0, 0],
            false,
        );
        let err = parse_frame(&buf, n).unwrap();
        assert!(err.is_error());
        assert_eq!(parse_frame(&[0; CANFD_MTU], 20), None, "unknown size");
    }

    /// Held frames: the gateway's own before bulk and client frames,
    /// whatever their identifiers; arbitration order within a class.
    #[test]
    fn held_frames_put_the_gateways_own_first() {
        let f = |s: &str| -> Frame { s.parse().unwrap() };
        let order = [
            held_key(TxClass::Control, &f("000#01")),
            held_key(TxClass::Control, &f("080#")),
            held_key(TxClass::Control, &f("1FFFFFFF#")),
            held_key(TxClass::Bulk, &f("001#")),
            held_key(TxClass::Bulk, &f("601#")),
            held_key(TxClass::Client, &f("000#")),
            held_key(TxClass::Client, &f("001#")),
            held_key(TxClass::Client, &f("1FFFFFFF#R")),
        ];
        assert!(order.windows(2).all(|w| w[0] < w[1]), "{order:?}");
    }

    #[test]
    fn arbitration_order_is_the_wire_order() {
        let keys: Vec<u64> = [
            "000#01",
            "080#",
            "123#",
            "123#R",
            "048C0000#",
            "048C0001#",
            "124#",
            "7FF#",
            "1FFFFFFF#",
        ]
        .iter()
        .map(|s| arbitration_key(&s.parse().unwrap()))
        .collect();
        assert!(keys.windows(2).all(|w| w[0] < w[1]), "{keys:?}");
    }
}
