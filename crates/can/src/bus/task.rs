//! The owner task of one bus: it holds the backend, sends what the handle
//! queues (the gateway's frames at once, client and bulk frames paced by
//! their share), and fans every frame and state change out to the
//! subscribers.

use super::*;

pub(super) async fn run_bus(
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
                        BackendEvent::Unsent(frame) => {
                            shared.counters.tx_failed.fetch_add(1, Ordering::Relaxed);
                            if shared.unsent.receiver_count() > 0 {
                                let _ = shared.unsent.send(frame);
                            }
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
                SocketCanEvent::Unsent(_) => {
                    c.tx_failed.fetch_add(1, Ordering::Relaxed);
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
pub(super) fn client_echo_begin(shared: &Shared, n: u64) {
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
pub(super) fn client_echo_end(shared: &Shared, n: u64) {
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
pub(super) fn update_echo(shared: &Shared, subs: &[Subscriber]) {
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
