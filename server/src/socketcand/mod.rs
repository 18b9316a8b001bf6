//! The socketcand endpoint: an API edge beside gRPC for the tools that
//! already speak socketcand's text protocol over TCP (python-can's
//! `socketcand` interface, SavvyCAN, Kayak), configured by `[socketcand]`.
//!
//! [`protocol`] is the protocol without I/O; this module is the listener
//! and one task per connection. A connection is a client of the gateway
//! exactly as an `Bus.Attach` stream is:
//!
//! - **Who.** With authentication on, the client gives a bearer token in
//!   the open command, `< open can0 TOKEN >` (with python-can:
//!   `channel="can0 TOKEN"`); no token or an unknown one is answered with
//!   `< error … >` and the connection closes, and the peer's refusals are
//!   throttled as gRPC's are. Without authentication the configuration
//!   only lets the listener bind a loopback address, and every session is
//!   `anonymous` (engineer), counted by peer address.
//! - **Roles.** Opening a bus (receiving its frames) needs viewer, as
//!   `StreamFrames` does; each `send` needs engineer, as `SendFrames` and
//!   `Attach` do: a lower role's send is answered with `< error … >`,
//!   counted in `cangate_client_frames_refused_total` (reason
//!   `PERMISSION_DENIED`) and the connection goes on.
//! - **Limits.** A session counts as one streaming call of its client
//!   (call rate, `max_streams_per_client`), its queue comes out of
//!   `max_stream_queue_per_client`, and every frame it sends is charged to
//!   the client's raw frame budget and sent with
//!   [`cangate_can::BusHandle::send_as_client`] within the bus's client
//!   share, the budgets of gRPC clients with the same identity included.
//! - **Slots.** At `max_connections`, or `max_connections_per_peer` for
//!   one address, the oldest connection that has not opened a bus yet
//!   gives its slot to the newcomer (told why, closed): idle connections
//!   that never authenticate cannot lock out a client with a token. Only
//!   when every counted connection has a bus open is a newcomer refused.
//! - **A bus participant.** Each connection is one [`ClientId`]: other
//!   clients see its frames as received, marked with its sender (named
//!   `WHO via socketcand`); it does not receive its own frames (a
//!   SocketCAN raw socket's default).
//! - **BCM mode** ([`bcm`]): cyclic jobs run in the runtime's
//!   [`crate::cyclic`] sender of the session (as an Attach stream's do),
//!   on the session's [`ClientId`]; `add` and `update` need engineer, each
//!   frame is charged to the frame budget and sent within the bus's
//!   client share, one frame in flight, and a refused one stops its job
//!   with an `< error … >` line. Subscriptions and filters get a feed of
//!   their identifiers only. All of it ends with the session.
//! - **Slow readers.** Frames wait in the connection's queue; a client
//!   that reads too slowly loses frames (counted in
//!   `cangate_socketcand_frames_lost_total`; the protocol cannot tell it),
//!   never slowing the bus or anyone else. A write that does not complete
//!   within `write_timeout_ms` ends the connection.
//! - **python-can's handshake.** python-can reads each answer of the
//!   handshake with one `recv` and compares it whole, so the first frames
//!   after `< rawmode >`'s `< ok >` are held back [`RAW_SETTLE`] to keep
//!   them out of that read.
//! - **Shutdown.** Every connection ends with the gateway's cancellation
//!   token; the listener waits for them.

pub mod bcm;
pub mod protocol;

use crate::config::SocketcandConfig;
use crate::cyclic::{CyclicError, CyclicEvent, CyclicPolicy, CyclicSender};
use crate::gateway::Gateway;
use crate::participants::{SenderGuard, SenderNames};
use crate::security::auth::AUDIT_TARGET;
use crate::security::slots::{AcceptPolicy, SlotGuard, accept_connections, listen_on_bus_thread};
use crate::security::{FrameBudget, QueueReservation, Refusal, Role, SecurityLayer};
use bcm::{Bcm, format_bcm_frame, id_text};
use cangate_can::{
    AttachOptions, BusHandle, BusItem, CanId, ClientId, Frame, FrameSelector, PendingSend,
    SendError, SendFailure, Subscription,
};
use protocol::{Action, BcmCommand, Deframer, Mode, Session, format_error, format_frame};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::tcp::OwnedWriteHalf;
use tokio::net::{TcpListener, TcpStream};
use tokio::task::JoinHandle;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

/// How long the frame feed waits after `< rawmode >` is answered (see the
/// module documentation).
pub const RAW_SETTLE: Duration = Duration::from_millis(50);
/// Most frames written at once.
const FEED_BATCH: usize = 256;

/// What every connection shares.
struct Shared {
    config: SocketcandConfig,
    gateway: Arc<Gateway>,
    security: SecurityLayer,
    senders: Arc<SenderNames>,
}

/// Binds `[socketcand] listen` and serves until `shutdown`, on the bus
/// thread ([`listen_on_bus_thread`] says why); returns the bound address
/// and the listener's task (it ends once every connection has).
///
/// # Errors
/// The address cannot be bound.
pub fn start(
    config: &SocketcandConfig,
    gateway: Arc<Gateway>,
    security: SecurityLayer,
    senders: Arc<SenderNames>,
    shutdown: CancellationToken,
) -> std::io::Result<(SocketAddr, JoinHandle<()>)> {
    if security.authentication() && !config.listen.ip().is_loopback() {
        tracing::warn!(
            addr = %config.listen,
            "socketcand listens on the network: its tokens cross it in clear text (socketcand has no TLS)"
        );
    }
    let bus_side = gateway.bus_runtime().clone();
    let shared = Arc::new(Shared {
        config: config.clone(),
        gateway,
        security,
        senders,
    });
    listen_on_bus_thread(&bus_side, config.listen, move |listener| {
        accept_loop(listener, shared, shutdown)
    })
}

async fn accept_loop(listener: TcpListener, shared: Arc<Shared>, shutdown: CancellationToken) {
    let policy = AcceptPolicy {
        name: "socketcand",
        max: shared.config.max_connections as usize,
        per_peer: shared.config.max_connections_per_peer as usize,
        write_timeout: Duration::from_millis(shared.config.write_timeout_ms),
        refusal: format_error,
        on_refused: || crate::metrics::socketcand_session("too_many_connections"),
    };
    let stop = shutdown.clone();
    accept_connections(listener, policy, shutdown, move |stream, peer, slot| {
        connection(stream, peer, shared.clone(), stop.clone(), slot)
    })
    .await;
}

/// Counts an open connection while it lives.
struct Open;

impl Open {
    fn new() -> Self {
        crate::metrics::socketcand_connections(1.0);
        Open
    }
}

impl Drop for Open {
    fn drop(&mut self) {
        crate::metrics::socketcand_connections(-1.0);
    }
}

/// A bus opened by a session.
struct Opened {
    bus: BusHandle,
    client: ClientId,
    who: String,
    role: Role,
    budget: Option<FrameBudget>,
    queue: usize,
    /// Held while the session is open: its stream slot, queue share and
    /// sender name.
    _stream: Option<crate::security::limits::Permit>,
    _queue: Option<QueueReservation>,
    _name: SenderGuard,
    /// Sends refused for the role (logged once, summed up at the end).
    refused_role: u64,
}

/// Why a connection ends.
enum End {
    /// The peer closed, or reading failed.
    PeerGone,
    /// Writing failed or timed out.
    WriteFailed,
    /// The protocol or a limit ended it (the reason was written).
    Closed,
    /// The gateway shuts down.
    Shutdown,
}

/// The writing half with its timeout.
struct Writer {
    half: OwnedWriteHalf,
    timeout: Duration,
}

impl Writer {
    /// Writes all of `bytes`, failing when the peer does not take them
    /// within the timeout. What the socket's buffer takes at once is
    /// written without arming the timeout: nearly every answer, and the
    /// timer (a clock read, a timer-wheel entry) is then not needed.
    async fn write(&mut self, bytes: &[u8]) -> Result<(), End> {
        let rest = match self.half.try_write(bytes) {
            Ok(n) if n == bytes.len() => return Ok(()),
            Ok(n) => &bytes[n..],
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => bytes,
            Err(_) => return Err(End::WriteFailed),
        };
        match tokio::time::timeout(self.timeout, self.half.write_all(rest)).await {
            Ok(Ok(())) => Ok(()),
            _ => Err(End::WriteFailed),
        }
    }
}

/// What woke the connection's loop.
enum Event {
    Shutdown,
    /// Every slot is taken and this connection, which has not opened a
    /// bus, gave its slot to a newcomer.
    Evicted,
    Deadline,
    Read(std::io::Result<usize>),
    Items(usize),
    FeedReady,
    /// A throttled report of BCM mode is due.
    BcmDue,
    /// A cyclic job ended by itself (a frame of it was refused).
    Cyclic(CyclicEvent<CanId, String>),
    Sent(Result<(), SendFailure>),
}

/// The outcome of the frame in flight (never returns without one).
async fn outcome_of(in_flight: &mut Option<PendingSend>) -> Result<(), SendFailure> {
    match in_flight {
        Some(p) => p.wait().await,
        None => std::future::pending().await,
    }
}

/// The next items of an active feed (never returns without one).
async fn next_items(sub: &mut Option<Subscription>, items: &mut Vec<BusItem>) -> usize {
    match sub {
        Some(s) => s.recv_many(items, FEED_BATCH).await,
        None => std::future::pending().await,
    }
}

async fn connection(
    stream: TcpStream,
    peer: SocketAddr,
    shared: Arc<Shared>,
    shutdown: CancellationToken,
    slot: SlotGuard,
) {
    let _open = Open::new();
    let _ = stream.set_nodelay(true);
    let (mut reader, half) = stream.into_split();
    let mut writer = Writer {
        half,
        timeout: Duration::from_millis(shared.config.write_timeout_ms),
    };
    let mut opened: Option<Opened> = None;
    let end = serve(
        &mut reader,
        &mut writer,
        peer,
        &shared,
        &shutdown,
        &slot,
        &mut opened,
    )
    .await;
    if let Some(o) = &opened {
        if o.refused_role > 0 {
            tracing::warn!(
                target: AUDIT_TARGET,
                who = %o.who,
                role = o.role.as_str(),
                bus = o.bus.name(),
                refused = o.refused_role,
                "socketcand session ended; its sends were refused: they need role engineer"
            );
        }
        tracing::info!(
            who = %o.who,
            bus = o.bus.name(),
            reason = match end {
                End::PeerGone => "peer closed",
                End::WriteFailed => "write failed or timed out",
                End::Closed => "closed by the gateway",
                End::Shutdown => "shutdown",
            },
            "socketcand session ended"
        );
    }
}

/// The connection's loop; returns why it ended.
async fn serve(
    reader: &mut tokio::net::tcp::OwnedReadHalf,
    writer: &mut Writer,
    peer: SocketAddr,
    shared: &Shared,
    shutdown: &CancellationToken,
    slot: &SlotGuard,
    opened: &mut Option<Opened>,
) -> End {
    let cfg = &shared.config;
    if let Err(e) = writer.write(b"< hi >").await {
        return e;
    }
    let mut session = Session::new();
    let mut deframer = Deframer::new(cfg.max_command_bytes as usize);
    let handshake_deadline = Instant::now() + Duration::from_millis(cfg.handshake_timeout_ms);
    let idle = (cfg.idle_timeout_s > 0).then(|| Duration::from_secs(cfg.idle_timeout_s));
    let mut last_read = Instant::now();
    let mut feed: Option<Subscription> = None;
    // When a new feed's frames may start to go out (`None`: now). Compared
    // with the clock only while set, not at every wake-up.
    let mut feed_from: Option<Instant> = None;
    let mut buf = vec![0u8; 4096];
    let mut items: Vec<BusItem> = Vec::with_capacity(FEED_BATCH);
    let mut out = String::new();
    // The last frame sent, until its outcome is known: one at a time, so a
    // flooding client waits for the bus as before. A session with a feed is
    // not woken when a frame leaves (its next wake-up is usually the
    // answer): the outcome is picked up at its next wake-up or before its
    // next send; the bus's failures (bus-off, down) reach the feed too.
    let mut in_flight: Option<PendingSend> = None;
    // BCM mode's receive operations, on the session's clock, and its
    // cyclic jobs (started with the first `add`).
    let mut bcm = Bcm::default();
    let mut cyclic: Option<CyclicSender<CanId, String>> = None;
    let started = Instant::now();
    // The identifiers the BCM feed was built for.
    let mut fed: Vec<cangate_can::CanId> = Vec::new();
    // The feed is raw mode's (every frame).
    let mut raw_feed = false;
    loop {
        if let (Some(o), Some(p)) = (opened.as_ref(), in_flight.as_mut())
            && let Some(outcome) = p.try_outcome()
        {
            in_flight = None;
            if let Err(message) = sent(o, outcome)
                && let Err(e) = writer.write(format_error(&message).as_bytes()).await
            {
                return e;
            }
        }
        // A session with a feed, cyclic jobs or subscriptions is busy, not
        // idle.
        let busy = feed.is_some() || bcm.active() || cyclic.as_ref().is_some_and(|c| c.active());
        let deadline = match (&opened, busy) {
            (None, _) => Some(handshake_deadline),
            (Some(_), false) => idle.map(|i| last_read + i),
            (Some(_), true) => None,
        };
        let bcm_due = bcm.next_deadline().map(|d| started + d);
        if feed_from.is_some_and(|t| Instant::now() >= t) {
            feed_from = None;
        }
        let waiting_to_feed = feed.is_some() && feed_from.is_some();
        let feeding = feed.is_some() && !waiting_to_feed;
        let event = tokio::select! {
            biased;
            _ = shutdown.cancelled() => Event::Shutdown,
            _ = slot.evicted().cancelled(), if opened.is_none() => Event::Evicted,
            _ = tokio::time::sleep_until(deadline.unwrap_or_else(Instant::now)),
                if deadline.is_some() => Event::Deadline,
            r = reader.read(&mut buf) => Event::Read(r),
            _ = tokio::time::sleep_until(feed_from.unwrap_or(started)), if waiting_to_feed => Event::FeedReady,
            n = next_items(&mut feed, &mut items), if feeding => Event::Items(n),
            _ = tokio::time::sleep_until(bcm_due.unwrap_or_else(Instant::now)),
                if bcm_due.is_some() => Event::BcmDue,
            r = outcome_of(&mut in_flight), if in_flight.is_some() && !feeding => Event::Sent(r),
            e = next_cyclic_event(&mut cyclic) => Event::Cyclic(e),
        };
        match event {
            Event::Shutdown => return End::Shutdown,
            Event::Evicted => {
                crate::metrics::socketcand_session("evicted_before_open");
                let what = "closed before a bus was opened: every connection slot is taken \
                            (max_connections, max_connections_per_peer) and a new client needs one";
                let _ = writer.write(format_error(what).as_bytes()).await;
                return End::Closed;
            }
            Event::FeedReady => {}
            Event::BcmDue => {
                let Some(o) = opened.as_mut() else {
                    continue;
                };
                let report = bcm.due(started.elapsed());
                out.clear();
                for f in &report {
                    out.push_str(&format_bcm_frame(f));
                }
                if !report.is_empty() {
                    crate::metrics::socketcand_frames(o.bus.name(), "out", report.len() as u64);
                    if let Err(e) = writer.write(out.as_bytes()).await {
                        return e;
                    }
                }
            }
            Event::Cyclic(event) => {
                // A cyclic frame the gateway refused (budget, bus) ended its
                // job: it would be refused every period.
                if let CyclicEvent::Refused { key, refusal } = event {
                    let line =
                        format_error(&format!("cyclic job {} stopped: {refusal}", id_text(key)));
                    if let Err(e) = writer.write(line.as_bytes()).await {
                        return e;
                    }
                }
            }
            Event::Sent(outcome) => {
                in_flight = None;
                if let Some(o) = opened.as_ref()
                    && let Err(message) = sent(o, outcome)
                    && let Err(e) = writer.write(format_error(&message).as_bytes()).await
                {
                    return e;
                }
            }
            Event::Deadline => {
                let what = if opened.is_none() {
                    crate::metrics::socketcand_session("handshake_timeout");
                    format!(
                        "no bus opened within {} ms (handshake_timeout_ms)",
                        cfg.handshake_timeout_ms
                    )
                } else {
                    format!(
                        "idle for {} s without a command (idle_timeout_s)",
                        cfg.idle_timeout_s
                    )
                };
                let _ = writer.write(format_error(&what).as_bytes()).await;
                return End::Closed;
            }
            Event::Items(0) => {
                // The bus stopped: the gateway shuts down.
                return End::Shutdown;
            }
            Event::Items(_) => {
                let Some(o) = opened.as_ref() else {
                    items.clear();
                    continue;
                };
                out.clear();
                let mut frames = 0u64;
                let raw = session.mode() == Mode::Raw;
                let now = started.elapsed();
                for item in items.drain(..) {
                    match item {
                        BusItem::Frame { frame, .. } if raw => {
                            if let Some(line) = format_frame(&frame) {
                                out.push_str(&line);
                                frames += 1;
                            }
                        }
                        BusItem::Frame { frame, .. } => {
                            if !frame.is_remote()
                                && !frame.is_error()
                                && let Some(f) = bcm.on_frame(&frame, now)
                            {
                                out.push_str(&format_bcm_frame(&f));
                                frames += 1;
                            }
                        }
                        BusItem::Lost(n) => {
                            crate::metrics::socketcand_lost(o.bus.name(), n);
                            tracing::debug!(who = %o.who, lost = n, "socketcand client too slow");
                        }
                        BusItem::State(_) => {}
                    }
                }
                if frames > 0 {
                    crate::metrics::socketcand_frames(o.bus.name(), "out", frames);
                    if let Err(e) = writer.write(out.as_bytes()).await {
                        return e;
                    }
                }
            }
            Event::Read(Ok(0) | Err(_)) => return End::PeerGone,
            Event::Read(Ok(n)) => {
                last_read = Instant::now();
                deframer.push(&buf[..n]);
                loop {
                    let element = match deframer.next_element() {
                        Ok(Some(e)) => e,
                        Ok(None) => break,
                        Err(e) => {
                            crate::metrics::socketcand_command_error("too_long");
                            let _ = writer.write(format_error(&e.to_string()).as_bytes()).await;
                            return End::Closed;
                        }
                    };
                    let action = session.on_element(&element);
                    match action {
                        Action::Reply(line) => {
                            if line.starts_with("< error") {
                                crate::metrics::socketcand_command_error(
                                    if line.contains("not supported") {
                                        "not_supported"
                                    } else if line.contains("unknown command") {
                                        "unknown"
                                    } else {
                                        "syntax"
                                    },
                                );
                            }
                            if let Err(e) = writer.write(line.as_bytes()).await {
                                return e;
                            }
                        }
                        Action::Close(line) => {
                            crate::metrics::socketcand_command_error("not_supported");
                            let _ = writer.write(line.as_bytes()).await;
                            return End::Closed;
                        }
                        Action::Open { bus, token } => {
                            match open(shared, peer, &bus, token.as_deref()) {
                                Ok(o) => {
                                    *opened = Some(o);
                                    slot.opened();
                                    session.opened();
                                    if let Err(e) = writer.write(b"< ok >").await {
                                        return e;
                                    }
                                }
                                Err(message) => {
                                    let _ = writer.write(format_error(&message).as_bytes()).await;
                                    return End::Closed;
                                }
                            }
                        }
                        Action::Feed(on) => {
                            let Some(o) = opened.as_ref() else {
                                return End::Closed;
                            };
                            if on && !raw_feed {
                                raw_feed = true;
                                feed = Some(o.bus.attach(
                                    o.client,
                                    AttachOptions {
                                        selector: FrameSelector {
                                            filters: Vec::new(),
                                            error_frames: false,
                                            transmitted: true,
                                        },
                                        receive_own: false,
                                        fd: o.bus.info().fd,
                                        queue: o.queue,
                                    },
                                ));
                                feed_from = Some(Instant::now() + RAW_SETTLE);
                            } else if !on {
                                // BCM mode: only the subscribed frames.
                                raw_feed = false;
                                feed = bcm_feed(o, &bcm);
                                fed = feed_ids(&bcm);
                                feed_from = None;
                            }
                            if let Err(e) = writer.write(b"< ok >").await {
                                return e;
                            }
                        }
                        Action::Send(frame) => {
                            let Some(o) = opened.as_mut() else {
                                return End::Closed;
                            };
                            let refused = match send_frame(o, frame, &mut in_flight, shutdown).await
                            {
                                Ok(r) => r,
                                Err(e) => return e,
                            };
                            for message in refused {
                                if let Err(e) =
                                    writer.write(format_error(&message).as_bytes()).await
                                {
                                    return e;
                                }
                            }
                        }
                        Action::Bcm(command) => {
                            let Some(o) = opened.as_mut() else {
                                return End::Closed;
                            };
                            let result = match command {
                                BcmCommand::Add { .. } | BcmCommand::Update(_)
                                    if o.role < Role::Engineer =>
                                {
                                    Err(format!(
                                        "cyclic transmission needs role engineer; {} holds role {}",
                                        o.who,
                                        o.role.as_str()
                                    ))
                                }
                                BcmCommand::Add { interval, frame } => cyclic
                                    .get_or_insert_with(|| cyclic_sender(o, shutdown))
                                    .start(frame.id(), vec![frame], interval, None)
                                    .map_err(|e| match e {
                                        CyclicError::IntervalTooShort => {
                                            format!("add: {e} (send sends a frame once)")
                                        }
                                        CyclicError::TooManyJobs => format!(
                                            "add: at most {} cyclic jobs per session",
                                            crate::cyclic::MAX_JOBS
                                        ),
                                        e => format!("add: {e}"),
                                    }),
                                BcmCommand::Update(frame) => cyclic
                                    .as_ref()
                                    .ok_or(CyclicError::NoSuchJob)
                                    .and_then(|c| c.update(frame.id(), vec![frame]))
                                    .map_err(|_| {
                                        format!(
                                            "update: no cyclic job for {} (add one first)",
                                            id_text(frame.id())
                                        )
                                    }),
                                BcmCommand::Delete(id) => cyclic
                                    .as_ref()
                                    .ok_or(CyclicError::NoSuchJob)
                                    .and_then(|c| c.stop(id))
                                    .map_err(|_| {
                                        format!("delete: no cyclic job for {}", id_text(id))
                                    }),
                                BcmCommand::Receive { id, mask, throttle } => {
                                    bcm.receive(id, mask, throttle)
                                }
                                BcmCommand::Unsubscribe(id) => bcm.unsubscribe(id),
                            };
                            if session.mode() == Mode::Bcm {
                                let ids = feed_ids(&bcm);
                                if ids != fed {
                                    feed = bcm_feed(o, &bcm);
                                    feed_from = None;
                                    fed = ids;
                                }
                            }
                            if let Err(message) = result
                                && let Err(e) =
                                    writer.write(format_error(&message).as_bytes()).await
                            {
                                return e;
                            }
                        }
                    }
                }
            }
        }
    }
}

/// Authorises the session and opens the bus, or says why not (the
/// connection then closes, as socketcand's does after a failed open).
fn open(
    shared: &Shared,
    peer: SocketAddr,
    bus: &str,
    token: Option<&str>,
) -> Result<Opened, String> {
    let cfg = &shared.config;
    let allowed = cfg.buses.is_empty() || cfg.buses.iter().any(|b| b == bus);
    let handle = match shared.gateway.bus(bus) {
        Ok(h) if allowed => h.clone(),
        _ => {
            crate::metrics::socketcand_session("refused_bus");
            tracing::info!(%peer, bus, "socketcand: no such bus (or not in [socketcand] buses)");
            // socketcand's own answer.
            return Err("could not open bus".into());
        }
    };
    let admission = shared
        .security
        .admit_session(token, peer.ip())
        .map_err(|refusal| {
            let (result, message) = match &refusal {
                Refusal::ResourceExhausted(m) => ("refused_limit", m.clone()),
                other => ("refused_auth", other.to_string()),
            };
            crate::metrics::socketcand_session(result);
            tracing::warn!(
                target: AUDIT_TARGET,
                who = "unidentified",
                method = "socketcand open",
                bus,
                %peer,
                message = %message,
                "socketcand session refused"
            );
            message
        })?;
    let identity = admission.identity;
    // Receiving needs viewer, which every role holds; sending is checked
    // per frame.
    let (queue, reservation) = match &admission.queue_budget {
        Some(b) => b
            .reserve(cfg.queue_length, cfg.queue_length as usize)
            .map(|(n, r)| (n, Some(r)))
            .map_err(|e| {
                crate::metrics::socketcand_session("refused_limit");
                e.0
            })?,
        None => (cfg.queue_length as usize, None),
    };
    let who = if identity.method == "none" {
        peer.to_string()
    } else {
        format!("{}@{peer}", identity.name)
    };
    let client = ClientId::next();
    let name = shared
        .senders
        .register(client, format!("{who} via socketcand"));
    crate::metrics::socketcand_session("opened");
    tracing::info!(
        target: AUDIT_TARGET,
        who = %who,
        role = identity.role.as_str(),
        method = "socketcand open",
        bus,
        sender = client.get(),
        "socketcand session opened"
    );
    Ok(Opened {
        bus: handle,
        client,
        who,
        role: identity.role,
        budget: admission.frame_budget,
        queue,
        _stream: admission.stream,
        _queue: reservation,
        _name: name,
        refused_role: 0,
    })
}

/// Queues one frame of the session as a bus participant, or says why not
/// (counted as a refused client frame, as gRPC's refusals are); its
/// outcome goes through [`sent`].
async fn queue(o: &mut Opened, frame: Frame) -> Result<PendingSend, String> {
    let bus = o.bus.name().to_string();
    let refuse = |reason: &str, message: String| {
        crate::metrics::client_frames_refused(&bus, reason.to_string(), 1);
        message
    };
    if o.role < Role::Engineer {
        o.refused_role += 1;
        if o.refused_role == 1 {
            tracing::warn!(
                target: AUDIT_TARGET,
                who = %o.who,
                role = o.role.as_str(),
                method = "socketcand send",
                bus = %bus,
                "refused: sending raw frames needs role engineer"
            );
        }
        return Err(refuse(
            "PERMISSION_DENIED",
            format!(
                "send needs role engineer; {} holds role {}",
                o.who,
                o.role.as_str()
            ),
        ));
    }
    if frame.is_fd() && !o.bus.info().fd {
        return Err(refuse(
            "CAN_FD_NOT_SUPPORTED",
            format!("bus {bus} is not configured for CAN FD"),
        ));
    }
    if let Some(b) = &o.budget {
        b.take(1).map_err(|e| refuse("FRAME_RATE_LIMIT", e.0))?;
    }
    Ok(o.bus.queue_as_client(o.client, vec![frame]).await)
}

/// Counts a queued frame's outcome; a failure becomes the error line's
/// message.
fn sent(o: &Opened, outcome: Result<(), SendFailure>) -> Result<(), String> {
    count_outcome(o.bus.name(), outcome)
}

/// [`sent`] for a bus by name.
fn count_outcome(bus: &str, outcome: Result<(), SendFailure>) -> Result<(), String> {
    match outcome {
        Ok(()) => {
            crate::metrics::socketcand_frames(bus, "in", 1);
            Ok(())
        }
        Err(f) => {
            let reason = match &f.error {
                SendError::BusOff(_) => "BUS_OFF",
                SendError::Down(_) => "BUS_DOWN",
                SendError::FdNotSupported(_) => "CAN_FD_NOT_SUPPORTED",
                SendError::BudgetExhausted { .. } => "BUS_BUDGET_EXHAUSTED",
                _ => "SEND_FAILED",
            };
            crate::metrics::client_frames_refused(bus, reason.to_string(), 1);
            Err(f.error.to_string())
        }
    }
}

/// Sends one frame of the session (a `send`, or a cyclic job's frame) with
/// one frame in flight: waits for the last one's outcome first. The
/// refusals to report (of the last frame, of this one).
async fn send_frame(
    o: &mut Opened,
    frame: Frame,
    in_flight: &mut Option<PendingSend>,
    shutdown: &CancellationToken,
) -> Result<Vec<String>, End> {
    let mut refused = Vec::new();
    if let Some(p) = in_flight.take() {
        let outcome = tokio::select! {
            biased;
            _ = shutdown.cancelled() => return Err(End::Shutdown),
            r = p.outcome() => r,
        };
        refused.extend(sent(o, outcome).err());
    }
    let queued = tokio::select! {
        biased;
        _ = shutdown.cancelled() => return Err(End::Shutdown),
        r = queue(o, frame) => r,
    };
    match queued {
        // Known at once: refused before the queue, or sent right away (an
        // unpaced virtual bus).
        Ok(mut p) => match p.try_outcome() {
            Some(outcome) => refused.extend(sent(o, outcome).err()),
            None => *in_flight = Some(p),
        },
        Err(message) => refused.push(message),
    }
    Ok(refused)
}

/// The next event of the session's cyclic jobs (never returns without
/// them).
async fn next_cyclic_event(
    cyclic: &mut Option<CyclicSender<CanId, String>>,
) -> CyclicEvent<CanId, String> {
    match cyclic {
        Some(c) => c.next_event().await,
        None => std::future::pending().await,
    }
}

/// What the session's cyclic frames go through: the checks of a `send`
/// (the role was checked by `add`), counted as its frames are.
struct SessionCyclic {
    bus: String,
    fd: bool,
    budget: Option<FrameBudget>,
}

impl CyclicPolicy for SessionCyclic {
    type Refusal = String;

    fn admit(&mut self, frame: &Frame) -> Result<(), String> {
        let refuse = |reason: &str, message: String| {
            crate::metrics::client_frames_refused(&self.bus, reason.to_string(), 1);
            message
        };
        if frame.is_fd() && !self.fd {
            return Err(refuse(
                "CAN_FD_NOT_SUPPORTED",
                format!("bus {} is not configured for CAN FD", self.bus),
            ));
        }
        if let Some(b) = &self.budget {
            b.take(1).map_err(|e| refuse("FRAME_RATE_LIMIT", e.0))?;
        }
        Ok(())
    }

    fn sent(&mut self, outcome: Result<(), SendFailure>) -> Result<(), String> {
        count_outcome(&self.bus, outcome)
    }
}

/// The session's cyclic sender, on its client.
fn cyclic_sender(o: &Opened, shutdown: &CancellationToken) -> CyclicSender<CanId, String> {
    let policy = SessionCyclic {
        bus: o.bus.name().to_string(),
        fd: o.bus.info().fd,
        budget: o.budget.clone(),
    };
    CyclicSender::spawn(o.bus.clone(), o.client, policy, shutdown)
}

/// The identifiers BCM mode receives.
fn feed_ids(bcm: &Bcm) -> Vec<cangate_can::CanId> {
    bcm.receive_ids()
}

/// BCM mode's feed: the frames of the subscribed identifiers (none
/// without a subscription).
fn bcm_feed(o: &Opened, bcm: &Bcm) -> Option<Subscription> {
    let ids = bcm.receive_ids();
    if ids.is_empty() {
        return None;
    }
    let filters = ids
        .into_iter()
        .map(|id| cangate_can::Filter {
            id: id.raw(),
            mask: if id.is_extended() { 0x1FFF_FFFF } else { 0x7FF },
            extended: Some(id.is_extended()),
            inverted: false,
        })
        .collect();
    Some(o.bus.attach(
        o.client,
        AttachOptions {
            selector: FrameSelector {
                filters,
                error_frames: false,
                transmitted: true,
            },
            receive_own: false,
            fd: o.bus.info().fd,
            queue: o.queue,
        },
    ))
}
