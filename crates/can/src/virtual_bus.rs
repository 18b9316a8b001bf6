//! The in-process virtual CAN bus: any number of named buses, each with any
//! number of participants ([`VirtualPort`]s). It is the demo's bus and the
//! test and benchmark bed.
//!
//! Without bit timing a frame is delivered to every other port immediately,
//! in the sender's context, which makes the bus fast (millions of frames/s).
//! With a [`BitTiming`] each frame occupies the bus for its modelled duration
//! (see [`crate::timing`]): frames queued by several senders go out one at a
//! time in arbitration order, delivered by a scheduler thread at their
//! modelled completion time and stamped with it. Fault injection can drop
//! frames (by probability or identifier), delay them, and force the bus off.

use crate::filter::Filter;
use crate::frame::{Frame, FrameKind, Timestamp};
use crate::send_error::SendError;
use crate::state::{BusState, BusStatus};
use crate::timing::{Arbiter, BitTiming, LoadMeter};
use std::collections::{HashMap, HashSet, VecDeque};
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, RwLock, Weak};
use std::time::{Duration, Instant};
use tokio::sync::futures::OwnedNotified;
use tokio::sync::{Notify, mpsc};

/// Configuration of one virtual bus.
#[derive(Debug, Clone, PartialEq)]
pub struct VirtualBusConfig {
    /// Model each frame's duration on the wire; `None` delivers instantly.
    pub bit_timing: Option<BitTiming>,
    /// Whether CAN FD frames are allowed.
    pub fd: bool,
    /// Receive queue length of each port; frames beyond it are counted as
    /// that port's overflows (like a socket's receive buffer).
    pub port_queue: usize,
    /// Seed of the fault-injection random generator (for reproducible runs).
    pub seed: u64,
    /// Bit-timed buses only: frames are handed to the ports up to this long
    /// after their modelled completion, together with the others that
    /// completed meanwhile, as a CAN adapter's receive-interrupt coalescing
    /// does (a USB adapter hands over frames per 1 ms USB frame). Their
    /// timestamps stay the model's exact completion times. Why: every
    /// hand-over wakes the scheduler thread and each receiving task; a
    /// cycle's back-to-back frames in one hand-over cost a fraction. Zero:
    /// each frame at its completion.
    pub rx_coalesce: Duration,
}

impl Default for VirtualBusConfig {
    fn default() -> Self {
        VirtualBusConfig {
            bit_timing: None,
            fd: true,
            port_queue: 16_384,
            seed: 0x5EED,
            rx_coalesce: Duration::ZERO,
        }
    }
}

/// Something a port receives.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PortEvent {
    /// A frame seen on the bus. `own` is true for this port's own frames
    /// echoed back after transmission (only for ports that asked for it).
    Frame {
        /// The frame, timestamped.
        frame: Frame,
        /// Sent by this port.
        own: bool,
    },
    /// The bus state changed.
    State(BusStatus),
}

/// Counters of a virtual bus.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct VirtualBusStats {
    /// Frames that completed transmission.
    pub transmitted: u64,
    /// Frames dropped by fault injection.
    pub dropped_by_fault: u64,
    /// Deliveries lost because a port's receive queue was full.
    pub port_overflows: u64,
}

struct FaultState {
    drop_probability: f64,
    drop_ids: HashSet<u32>,
    rng: fastrand::Rng,
}

struct PortShared {
    id: u64,
    tx: mpsc::Sender<PortEvent>,
    echo_own: bool,
    overflows: AtomicU64,
    /// The port's acceptance filters (`None`: every frame), read by the
    /// sender on every delivery.
    accept: RwLock<Option<Arc<[Filter]>>>,
    /// Which of its own frames an `echo_own` port gets back (`None`: all),
    /// read by the sender on every delivery of its own frames.
    echo: RwLock<Option<Arc<[Filter]>>>,
}

impl PortShared {
    /// Whether a frame is queued to this port. Error frames always are, as
    /// the filters select identifiers.
    fn accepts(&self, frame: &Frame) -> bool {
        match &*self.accept.read().expect("port filter lock") {
            None => true,
            Some(filters) => {
                frame.kind() == FrameKind::Error || filters.iter().any(|f| f.matches(frame))
            }
        }
    }

    /// Whether one of this port's own frames passes its echo filter (the
    /// acceptance filters are checked as well, by [`deliver`]). Error frames
    /// pass any non-empty list, as filters cannot select them by
    /// identifier; an empty list echoes nothing at all.
    fn echoes(&self, frame: &Frame) -> bool {
        match &*self.echo.read().expect("port echo filter lock") {
            None => true,
            Some(filters) => {
                !filters.is_empty()
                    && (frame.kind() == FrameKind::Error
                        || filters.iter().any(|f| f.matches(frame)))
            }
        }
    }

    fn set_echo_filters(&self, filters: Option<Vec<Filter>>) {
        *self.echo.write().expect("port echo filter lock") = filters.map(Arc::from);
    }

    fn echo_filters(&self) -> Option<Vec<Filter>> {
        self.echo
            .read()
            .expect("port echo filter lock")
            .as_deref()
            .map(<[Filter]>::to_vec)
    }
}

struct Inner {
    name: String,
    config: VirtualBusConfig,
    ports: RwLock<Vec<Arc<PortShared>>>,
    next_port: AtomicU64,
    faults_active: AtomicBool,
    faults: Mutex<FaultState>,
    delay_ns: AtomicU64,
    status: Mutex<BusStatus>,
    status_version: AtomicU64,
    status_notify: Arc<Notify>,
    origin: Instant,
    origin_wall: u64,
    // Set once (at creation for bit-timed buses, on the first delay fault
    // otherwise): read lock-free on every send.
    timed: std::sync::OnceLock<Arc<Timed>>,
    // The bus-off/down flag read on every send without taking `status`.
    refusing: AtomicBool,
    transmitted: AtomicU64,
    dropped: AtomicU64,
    overflows: AtomicU64,
}

struct TimedState {
    /// Senders are (port, lane): each lane of a port is a transmit FIFO of
    /// its own (see [`VirtualSender::send_batch_in_lane`]).
    arbiter: Arbiter<(u64, u8)>,
    delayed: VecDeque<(u64, Frame, u64)>,
    load: LoadMeter,
    shutdown: bool,
    /// The model time the scheduler thread sleeps until (`None`: it runs,
    /// or sleeps until the next enqueue). An enqueue wakes it only when
    /// its frames could be due earlier than that.
    sleeping_until: Option<u64>,
}

struct Timed {
    state: Mutex<TimedState>,
    wake: Condvar,
}

/// A named virtual bus. Cheap to clone; all clones are the same bus.
#[derive(Clone)]
pub struct VirtualBus {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for VirtualBus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VirtualBus")
            .field("name", &self.inner.name)
            .finish()
    }
}

impl VirtualBus {
    /// Creates a bus. Prefer [`VirtualNetwork::bus`] to share buses by name.
    pub fn new(name: &str, config: VirtualBusConfig) -> Self {
        let origin_wall = Timestamp::now().as_nanos();
        let seed = config.seed;
        let bus = VirtualBus {
            inner: Arc::new(Inner {
                name: name.to_string(),
                config,
                ports: RwLock::new(Vec::new()),
                next_port: AtomicU64::new(1),
                faults_active: AtomicBool::new(false),
                faults: Mutex::new(FaultState {
                    drop_probability: 0.0,
                    drop_ids: HashSet::new(),
                    rng: fastrand::Rng::with_seed(seed),
                }),
                delay_ns: AtomicU64::new(0),
                status: Mutex::new(BusStatus::UP),
                status_version: AtomicU64::new(0),
                status_notify: Arc::new(Notify::new()),
                origin: Instant::now(),
                origin_wall,
                timed: std::sync::OnceLock::new(),
                refusing: AtomicBool::new(false),
                transmitted: AtomicU64::new(0),
                dropped: AtomicU64::new(0),
                overflows: AtomicU64::new(0),
            }),
        };
        if bus.inner.config.bit_timing.is_some() {
            bus.timed();
        }
        bus
    }

    /// The bus name.
    pub fn name(&self) -> &str {
        &self.inner.name
    }

    /// The configuration.
    pub fn config(&self) -> &VirtualBusConfig {
        &self.inner.config
    }

    /// Attaches a participant. `echo_own` makes the port receive its own
    /// frames back once they completed transmission (with the bus timestamp),
    /// as SocketCAN's `CAN_RAW_RECV_OWN_MSGS` does; which of them can be
    /// narrowed with [`VirtualPort::set_echo_filters`].
    pub fn connect(&self, echo_own: bool) -> VirtualPort {
        let (tx, rx) = mpsc::channel(self.inner.config.port_queue.max(1));
        let shared = Arc::new(PortShared {
            id: self.inner.next_port.fetch_add(1, Ordering::Relaxed),
            tx,
            echo_own,
            overflows: AtomicU64::new(0),
            accept: RwLock::new(None),
            echo: RwLock::new(None),
        });
        self.inner
            .ports
            .write()
            .expect("port list lock")
            .push(shared.clone());
        VirtualPort {
            bus: self.clone(),
            seen_status: self.inner.status_version.load(Ordering::Acquire),
            shared,
            rx,
            status_wait: None,
        }
    }

    /// Current state.
    pub fn status(&self) -> BusStatus {
        *self.inner.status.lock().expect("status lock")
    }

    /// Counters.
    pub fn stats(&self) -> VirtualBusStats {
        VirtualBusStats {
            transmitted: self.inner.transmitted.load(Ordering::Relaxed),
            dropped_by_fault: self.inner.dropped.load(Ordering::Relaxed),
            port_overflows: self.inner.overflows.load(Ordering::Relaxed),
        }
    }

    /// Bus load in percent over the last second (bit-timed buses only).
    pub fn load_percent(&self) -> Option<f64> {
        let timed = self.inner.timed.get()?.clone();
        self.inner.config.bit_timing?;
        let now = self.model_now();
        Some(
            timed
                .state
                .lock()
                .expect("timed state")
                .load
                .load_percent(now),
        )
    }

    /// Frames of every port waiting for the bus now, except those in
    /// transmit lane `lane` (0 without bit timing: nothing waits there).
    /// The gateway holds its clients' frames (lane 2) back while others
    /// wait: they take only time no one else needs.
    pub fn waiting_outside_lane(&self, lane: u8) -> usize {
        let Some(timed) = self.inner.timed.get() else {
            return 0;
        };
        let now = self.model_now();
        timed
            .state
            .lock()
            .expect("timed state")
            .arbiter
            .queued_by(now, |(_, l)| *l != lane)
    }

    /// Model time: nanoseconds since the bus was created.
    pub fn model_now(&self) -> u64 {
        self.inner.origin.elapsed().as_nanos() as u64
    }

    /// Converts model time to a wall-clock timestamp.
    pub fn timestamp_of(&self, model_ns: u64) -> Timestamp {
        Timestamp(self.inner.origin_wall + model_ns)
    }

    // ---- fault injection ----

    /// Drops each frame with probability `p` (0.0..=1.0).
    pub fn set_drop_probability(&self, p: f64) {
        let mut f = self.inner.faults.lock().expect("faults lock");
        f.drop_probability = p.clamp(0.0, 1.0);
        self.update_faults_active(&f);
    }

    /// Drops every frame with one of these identifiers.
    pub fn set_drop_ids(&self, ids: impl IntoIterator<Item = u32>) {
        let mut f = self.inner.faults.lock().expect("faults lock");
        f.drop_ids = ids.into_iter().collect();
        self.update_faults_active(&f);
    }

    /// Delays every delivery by `delay` (after its bus time, if any).
    pub fn set_delay(&self, delay: Duration) {
        self.inner
            .delay_ns
            .store(delay.as_nanos() as u64, Ordering::Release);
        if !delay.is_zero() {
            self.timed();
        }
        let f = self.inner.faults.lock().expect("faults lock");
        self.update_faults_active(&f);
    }

    /// Clears all drop and delay faults.
    pub fn clear_faults(&self) {
        self.set_drop_probability(0.0);
        self.set_drop_ids([]);
        self.set_delay(Duration::ZERO);
    }

    /// Forces the bus into bus-off: sends fail until [`VirtualBus::recover`].
    pub fn force_bus_off(&self) {
        self.set_status(BusStatus {
            state: BusState::BusOff,
            tx_errors: 256,
            rx_errors: 0,
        });
    }

    /// Ends a forced bus-off (or any injected state): the bus is up again.
    pub fn recover(&self) {
        self.set_status(BusStatus::UP);
    }

    /// Injects any state (e.g. error-passive with counters).
    pub fn set_status(&self, status: BusStatus) {
        *self.inner.status.lock().expect("status lock") = status;
        self.inner
            .refusing
            .store(!status.state.can_send(), Ordering::Release);
        self.inner.status_version.fetch_add(1, Ordering::AcqRel);
        self.inner.status_notify.notify_waiters();
    }

    fn update_faults_active(&self, f: &FaultState) {
        let active = f.drop_probability > 0.0
            || !f.drop_ids.is_empty()
            || self.inner.delay_ns.load(Ordering::Acquire) > 0;
        self.inner.faults_active.store(active, Ordering::Release);
    }

    fn timed(&self) -> Arc<Timed> {
        self.inner
            .timed
            .get_or_init(|| {
                let timed = Arc::new(Timed {
                    state: Mutex::new(TimedState {
                        arbiter: Arbiter::new(self.inner.config.bit_timing),
                        delayed: VecDeque::new(),
                        load: LoadMeter::new(1_000_000_000),
                        shutdown: false,
                        sleeping_until: None,
                    }),
                    wake: Condvar::new(),
                });
                let weak = Arc::downgrade(&self.inner);
                let t2 = timed.clone();
                std::thread::Builder::new()
                    .name(format!("vbus-{}", self.inner.name))
                    .spawn(move || scheduler_thread(weak, t2))
                    .expect("spawn virtual bus scheduler thread");
                timed
            })
            .clone()
    }

    /// Queues frames from one port. A batch is queued atomically (one lock,
    /// one enqueue time), as a controller's transmit FIFO filled in one go:
    /// on a bit-timed bus the frames then go out back to back.
    fn send_from(&self, port: u64, lane: u8, frames: &[Frame]) -> Result<(), SendError> {
        self.send_from_at(port, lane, frames, None)
    }

    /// [`VirtualBus::send_from`], queued at model time `ready_ns` (at most
    /// now) instead of now on a bit-timed bus.
    fn send_from_at(
        &self,
        port: u64,
        lane: u8,
        frames: &[Frame],
        ready_ns: Option<u64>,
    ) -> Result<(), SendError> {
        let inner = &self.inner;
        if inner.refusing.load(Ordering::Acquire) {
            match inner.status.lock().expect("status lock").state {
                BusState::BusOff => return Err(SendError::BusOff(inner.name.clone())),
                BusState::Down => return Err(SendError::Down(inner.name.clone())),
                _ => {}
            }
        }
        if !inner.config.fd && frames.iter().any(|f| f.is_fd()) {
            return Err(SendError::FdNotSupported(inner.name.clone()));
        }
        let faulty = inner.faults_active.load(Ordering::Acquire);
        let mut faults = faulty.then(|| inner.faults.lock().expect("faults lock"));
        let mut dropped = |frame: &Frame| {
            let Some(f) = faults.as_mut() else {
                return false;
            };
            let drop = f.drop_ids.contains(&frame.raw_id())
                || (f.drop_probability > 0.0 && f.rng.f64() < f.drop_probability);
            if drop {
                inner.dropped.fetch_add(1, Ordering::Relaxed);
            }
            drop
        };
        match inner.timed.get() {
            Some(t) => {
                let mut st = t.state.lock().expect("timed state");
                // Read under the lock, so that enqueue times follow the
                // enqueue order.
                let now = self.model_now();
                let now = ready_ns.map_or(now, |t| t.min(now));
                let mut queued = false;
                for frame in frames {
                    if !dropped(frame) {
                        st.arbiter.enqueue(*frame, (port, lane), now);
                        queued = true;
                    }
                }
                // The arbiter's decisions do not depend on when it runs,
                // so a scheduler that will wake before these frames can
                // be due (no frame is shorter than the shortest frame)
                // need not wake now: that saves a wake-up per sent batch.
                let earliest_due = now
                    + st.arbiter.timing().map_or(0, |t| t.shortest_frame_ns())
                    + coalesce_ns(&inner.config);
                let wake = queued && st.sleeping_until.is_none_or(|until| until > earliest_due);
                drop(st);
                if wake {
                    t.wake.notify_one();
                }
            }
            None => {
                let now = Timestamp::now();
                for frame in frames {
                    if !dropped(frame) {
                        inner.transmitted.fetch_add(1, Ordering::Relaxed);
                        deliver(inner, port, &frame.with_timestamp(now));
                    }
                }
            }
        }
        Ok(())
    }
}

fn deliver(inner: &Inner, from: u64, frame: &Frame) {
    let ports = inner.ports.read().expect("port list lock");
    for p in ports.iter() {
        let own = p.id == from;
        // Own frames go back only to ports that asked for them, and only
        // those the echo filter selects; the acceptance filters apply to
        // them as well (as `CAN_RAW_FILTER` does to looped-back frames).
        if (own && !(p.echo_own && p.echoes(frame))) || !p.accepts(frame) {
            continue;
        }
        match p.tx.try_send(PortEvent::Frame { frame: *frame, own }) {
            Ok(()) => {}
            Err(mpsc::error::TrySendError::Full(_)) => {
                p.overflows.fetch_add(1, Ordering::Relaxed);
                inner.overflows.fetch_add(1, Ordering::Relaxed);
            }
            Err(mpsc::error::TrySendError::Closed(_)) => {}
        }
    }
}

/// [`VirtualBusConfig::rx_coalesce`] in ns where it applies (bit-timed
/// buses).
fn coalesce_ns(config: &VirtualBusConfig) -> u64 {
    if config.bit_timing.is_some() {
        u64::try_from(config.rx_coalesce.as_nanos()).unwrap_or(u64::MAX)
    } else {
        0
    }
}

/// Delivers frames of a timed bus at their modelled completion time (up to
/// [`VirtualBusConfig::rx_coalesce`] later, several at once).
fn scheduler_thread(bus: Weak<Inner>, timed: Arc<Timed>) {
    // Timed waits end within a µs of the deadline, not the default 50 µs.
    crate::precise_wait::fine_timer_slack();
    let mut st = timed.state.lock().expect("timed state");
    loop {
        st.sleeping_until = None;
        if st.shutdown {
            return;
        }
        let Some(inner) = bus.upgrade() else { return };
        let coalesce = coalesce_ns(&inner.config);
        let now = inner.origin.elapsed().as_nanos() as u64;
        let delay = inner.delay_ns.load(Ordering::Acquire);
        let done = st.arbiter.advance(now);
        if let Some(timing) = st.arbiter.timing() {
            for t in &done {
                let busy = timing.frame_duration_ns(&t.frame);
                st.load.record(t.end_ns, busy);
            }
        }
        for t in done {
            st.delayed
                .push_back((t.end_ns + delay, t.frame, t.sender.0));
        }
        let mut due = Vec::new();
        while let Some(&(at, _, _)) = st.delayed.front() {
            if at > now {
                break;
            }
            let (at, frame, from) = st.delayed.pop_front().expect("front exists");
            due.push((
                frame.with_timestamp(Timestamp(inner.origin_wall + at)),
                from,
            ));
        }
        // The next hand-over: the earliest waiting frame's time, else the
        // arbiter's next step (its decisions do not depend on when it
        // runs, so it is only run when something may be due), plus the
        // coalescing window.
        let next = match st.delayed.front() {
            Some(&(at, _, _)) => Some(at),
            None => st.arbiter.next_deadline(),
        }
        .map(|at| at + coalesce);
        if !due.is_empty() {
            drop(st);
            inner
                .transmitted
                .fetch_add(due.len() as u64, Ordering::Relaxed);
            for (frame, from) in &due {
                deliver(&inner, *from, frame);
            }
            st = timed.state.lock().expect("timed state");
            continue;
        }
        drop(inner);
        st = match next {
            // No active wait for the exact instant: timestamps are the
            // model's, so a wake-up some µs late (timer slack 1 µs, set at
            // the thread's start) delays only the hand-over, and spinning
            // for every frame cost an idle demo a tenth of a core per bus.
            Some(deadline) => {
                let wait = Duration::from_nanos(deadline.saturating_sub(now));
                st.sleeping_until = Some(deadline);
                timed.wake.wait_timeout(st, wait).expect("timed state").0
            }
            // Idle: wake on the next enqueue, and now and then to notice
            // that the bus was dropped.
            None => {
                timed
                    .wake
                    .wait_timeout(st, Duration::from_millis(200))
                    .expect("timed state")
                    .0
            }
        };
    }
}

impl Drop for Inner {
    fn drop(&mut self) {
        if let Some(t) = self.timed.take() {
            t.state.lock().expect("timed state").shutdown = true;
            t.wake.notify_all();
        }
    }
}

/// One participant of a virtual bus: sends frames, receives everyone
/// else's. Dropping it detaches it from the bus.
pub struct VirtualPort {
    bus: VirtualBus,
    shared: Arc<PortShared>,
    rx: mpsc::Receiver<PortEvent>,
    seen_status: u64,
    /// The wait for the next state change, kept from one receive to the
    /// next until it fires: a fresh one per receive would register with and
    /// unregister from the bus's state notifier on every frame batch.
    status_wait: Option<Pin<Box<OwnedNotified>>>,
}

impl std::fmt::Debug for VirtualPort {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VirtualPort")
            .field("bus", &self.bus.name())
            .field("id", &self.shared.id)
            .finish()
    }
}

impl VirtualPort {
    /// The bus this port is attached to.
    pub fn bus(&self) -> &VirtualBus {
        &self.bus
    }

    /// Queues a frame for transmission.
    pub fn send(&self, frame: &Frame) -> Result<(), SendError> {
        self.bus
            .send_from(self.shared.id, 0, std::slice::from_ref(frame))
    }

    /// Queues frames for transmission in one go (see [`VirtualBus`]: on a
    /// bit-timed bus they go out back to back). All or nothing: a refusal
    /// (bus-off, FD on a classic bus) queues none of them.
    pub fn send_batch(&self, frames: &[Frame]) -> Result<(), SendError> {
        self.bus.send_from(self.shared.id, 0, frames)
    }

    /// [`VirtualPort::send_batch`] in one of the port's transmit lanes (see
    /// [`VirtualSender::send_batch_in_lane`]).
    pub fn send_batch_in_lane(&self, frames: &[Frame], lane: u8) -> Result<(), SendError> {
        self.bus.send_from(self.shared.id, lane, frames)
    }

    /// A handle that sends as this port from any thread (the port itself
    /// stays with its owner, which receives).
    pub fn sender(&self) -> VirtualSender {
        VirtualSender {
            bus: self.bus.clone(),
            port: self.shared.clone(),
        }
    }

    /// Sets the port's acceptance filters, as SocketCAN's `CAN_RAW_FILTER`
    /// or a CAN controller's acceptance registers do: frames that match none
    /// of `filters` are not queued to this port, so they neither wake its
    /// owner nor cost their sender the delivery. `None` (the default)
    /// accepts every frame; an empty list only error frames and state
    /// changes.
    ///
    /// Why: on a real bus a transmitter pays the same whoever listens; here
    /// the sender's thread delivers to every port itself, so a device that
    /// declares what it listens to keeps the virtual bus's cost close to a
    /// real one's (a simulated drive needs its own RPDOs, not the other
    /// drives').
    pub fn set_filters(&self, filters: Option<Vec<Filter>>) {
        *self.shared.accept.write().expect("port filter lock") = filters.map(Arc::from);
    }

    /// Selects which of its own frames a port connected with `echo_own`
    /// gets back: `None` (the default) echoes every own frame, `Some(list)`
    /// only those matching one of `filters` (and own error frames, which
    /// filters cannot select by identifier, if the list is not empty); an
    /// empty list echoes none. The acceptance filters of
    /// [`VirtualPort::set_filters`] still apply to own frames too, so this
    /// can only narrow the echo. No effect on a port without `echo_own`, and
    /// none on what other ports receive.
    ///
    /// Why: the sender's thread pays for every delivery, and an echo wakes
    /// the port's owner. An owner that needs only some of its own frames
    /// back (the gateway's bus task: only those a subscriber asked to see
    /// as transmitted) should neither wake for the others nor make its
    /// senders queue them, as SocketCAN's `CAN_RAW_RECV_OWN_MSGS` left off
    /// spares a socket its own frames.
    pub fn set_echo_filters(&self, filters: Option<Vec<Filter>>) {
        self.shared.set_echo_filters(filters);
    }

    /// The echo filter set by [`VirtualPort::set_echo_filters`].
    pub fn echo_filters(&self) -> Option<Vec<Filter>> {
        self.shared.echo_filters()
    }

    /// Frames this port could not receive because its queue was full.
    pub fn overflows(&self) -> u64 {
        self.shared.overflows.load(Ordering::Relaxed)
    }

    fn status_event(&mut self) -> Option<PortEvent> {
        let v = self.bus.inner.status_version.load(Ordering::Acquire);
        if v != self.seen_status {
            self.seen_status = v;
            return Some(PortEvent::State(self.bus.status()));
        }
        None
    }

    /// Waits for the next event. State changes are never lost (the latest
    /// state is reported); frames beyond the queue length are counted in
    /// [`VirtualPort::overflows`].
    pub async fn recv(&mut self) -> PortEvent {
        loop {
            // Armed before the check, so a change right after it wakes us.
            arm(&mut self.status_wait, &self.bus.inner.status_notify);
            if let Some(ev) = self.status_event() {
                return ev;
            }
            let wait = arm(&mut self.status_wait, &self.bus.inner.status_notify);
            let changed = tokio::select! {
                biased;
                _ = wait => true,
                ev = self.rx.recv() => {
                    // The port holds the bus, so the sender side lives as
                    // long as we do; `None` cannot happen.
                    if let Some(ev) = ev { return ev; }
                    false
                }
            };
            if changed {
                self.status_wait = None;
            }
        }
    }

    /// Receives up to `limit` events into `buf` (waiting for at least one).
    pub async fn recv_many(&mut self, buf: &mut Vec<PortEvent>, limit: usize) -> usize {
        loop {
            // Armed before the check, so a change right after it wakes us.
            arm(&mut self.status_wait, &self.bus.inner.status_notify);
            if let Some(ev) = self.status_event() {
                buf.push(ev);
                return 1;
            }
            let wait = arm(&mut self.status_wait, &self.bus.inner.status_notify);
            let changed = tokio::select! {
                biased;
                _ = wait => true,
                n = self.rx.recv_many(buf, limit) => {
                    if n > 0 { return n; }
                    false
                }
            };
            if changed {
                self.status_wait = None;
            }
        }
    }

    /// Takes an event without waiting.
    pub fn try_recv(&mut self) -> Option<PortEvent> {
        if let Some(ev) = self.status_event() {
            return Some(ev);
        }
        self.rx.try_recv().ok()
    }
}

/// The armed wait for a state change of a port. A wait that is already
/// armed was created before the caller's latest check of the state
/// version, so a change after that check is not missed (`notify_waiters`
/// reaches every future created before it).
fn arm<'a>(
    slot: &'a mut Option<Pin<Box<OwnedNotified>>>,
    notify: &Arc<Notify>,
) -> Pin<&'a mut OwnedNotified> {
    slot.get_or_insert_with(|| Box::pin(notify.clone().notified_owned()))
        .as_mut()
}

impl Drop for VirtualPort {
    fn drop(&mut self) {
        if let Ok(mut ports) = self.bus.inner.ports.write() {
            ports.retain(|p| p.id != self.shared.id);
        }
    }
}

/// Sends frames as one port of a virtual bus (see [`VirtualPort::sender`]).
#[derive(Clone)]
pub struct VirtualSender {
    bus: VirtualBus,
    /// The port's shared part: its id to send as, and its echo filter, which
    /// the sender's holder may set while the port itself is owned elsewhere.
    port: Arc<PortShared>,
}

impl std::fmt::Debug for VirtualSender {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VirtualSender")
            .field("bus", &self.bus.name())
            .field("port", &self.port.id)
            .finish()
    }
}

impl VirtualSender {
    /// Queues frames as [`VirtualPort::send_batch`] does.
    pub fn send_batch(&self, frames: &[Frame]) -> Result<(), SendError> {
        self.bus.send_from(self.port.id, 0, frames)
    }

    /// Queues frames that became ready at `ready` (a timestamp of this
    /// bus's clock, e.g. the modelled end of the frame they answer) rather
    /// than now: on a bit-timed bus they contend for the bus from then on,
    /// so their modelled transmission and timestamps do not depend on how
    /// late the host ran the sender. For simulated devices, which answer on
    /// the model's time. A `ready` in the future counts as now; frames
    /// queued earlier by any port are not overtaken (model time never runs
    /// backwards in the arbiter). Without bit timing: as
    /// [`VirtualSender::send_batch`].
    pub fn send_batch_ready_at(&self, frames: &[Frame], ready: Timestamp) -> Result<(), SendError> {
        let ready_ns = ready.as_nanos().saturating_sub(self.bus.inner.origin_wall);
        self.bus
            .send_from_at(self.port.id, 0, frames, Some(ready_ns))
    }

    /// Queues frames in one of the port's transmit lanes. On a bit-timed
    /// bus each lane is a transmit FIFO of its own, whose head takes part
    /// in arbitration like another node's, as a controller's separate
    /// transmit mailboxes do: frames in lane 0 (what
    /// [`VirtualSender::send_batch`] uses) never wait behind a backlog in
    /// another lane. Without bit timing lanes make no difference.
    pub fn send_batch_in_lane(&self, frames: &[Frame], lane: u8) -> Result<(), SendError> {
        self.bus.send_from(self.port.id, lane, frames)
    }

    /// Sets the port's echo filter, as [`VirtualPort::set_echo_filters`]
    /// does, for a holder of the sender only (the port's owner is another
    /// task). Takes effect for every delivery that starts after the call.
    pub fn set_echo_filters(&self, filters: Option<Vec<Filter>>) {
        self.port.set_echo_filters(filters);
    }

    /// The port's echo filter (see [`VirtualPort::set_echo_filters`]).
    pub fn echo_filters(&self) -> Option<Vec<Filter>> {
        self.port.echo_filters()
    }
}

/// A set of named virtual buses, so that the server and simulated devices
/// find the same bus by name.
#[derive(Clone, Default)]
pub struct VirtualNetwork {
    buses: Arc<Mutex<HashMap<String, VirtualBus>>>,
}

impl std::fmt::Debug for VirtualNetwork {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VirtualNetwork").finish()
    }
}

impl VirtualNetwork {
    /// An empty network.
    pub fn new() -> Self {
        Self::default()
    }

    /// The bus with this name, created with `config` if it does not exist
    /// (an existing bus keeps its configuration).
    pub fn bus(&self, name: &str, config: VirtualBusConfig) -> VirtualBus {
        self.buses
            .lock()
            .expect("network lock")
            .entry(name.to_string())
            .or_insert_with(|| VirtualBus::new(name, config))
            .clone()
    }

    /// The bus with this name, if it exists.
    pub fn get(&self, name: &str) -> Option<VirtualBus> {
        self.buses.lock().expect("network lock").get(name).cloned()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::CanId;
    use crate::timing::Stuffing;

    fn frame(id: u32, data: &[u8]) -> Frame {
        Frame::new(CanId::standard(id).unwrap(), data).unwrap()
    }

    async fn next_frame(port: &mut VirtualPort) -> Frame {
        loop {
            if let PortEvent::Frame { frame, .. } = port.recv().await {
                return frame;
            }
        }
    }

    #[tokio::test]
    async fn frames_reach_every_other_port_but_not_the_sender() {
        let bus = VirtualBus::new("t", VirtualBusConfig::default());
        let mut a = bus.connect(false);
        let mut b = bus.connect(false);
        let mut c = bus.connect(false);
        a.send(&frame(0x123, &[1, 2])).unwrap();
        assert_eq!(next_frame(&mut b).await.data(), &[1, 2]);
        assert_eq!(next_frame(&mut c).await.data(), &[1, 2]);
        assert!(a.try_recv().is_none());
    }

    #[tokio::test]
    async fn acceptance_filters_keep_other_frames_out_of_a_port() {
        let bus = VirtualBus::new("t", VirtualBusConfig::default());
        let a = bus.connect(false);
        let mut drive = bus.connect(false);
        let mut monitor = bus.connect(false);
        drive.set_filters(Some(vec![
            Filter::exact_standard(0x000),
            Filter::exact_standard(0x205),
        ]));
        for id in [0x206, 0x205, 0x000, 0x605] {
            a.send(&frame(id, &[id as u8])).unwrap();
        }
        assert_eq!(next_frame(&mut drive).await.raw_id(), 0x205);
        assert_eq!(next_frame(&mut drive).await.raw_id(), 0x000);
        assert!(drive.try_recv().is_none(), "0x206 and 0x605 were filtered");
        // Error frames pass any filter; other ports see everything.
        a.send(&Frame::new_error(0x0000_0004, [0; 8])).unwrap();
        assert!(next_frame(&mut drive).await.is_error());
        let mut got = Vec::new();
        for _ in 0..4 {
            got.push(next_frame(&mut monitor).await.raw_id());
        }
        assert_eq!(got, [0x206, 0x205, 0x000, 0x605]);
        // Back to everything.
        drive.set_filters(None);
        a.send(&frame(0x206, &[])).unwrap();
        assert_eq!(next_frame(&mut drive).await.raw_id(), 0x206);
        // Nothing but errors and state.
        drive.set_filters(Some(Vec::new()));
        a.send(&frame(0x000, &[])).unwrap();
        assert!(drive.try_recv().is_none());
    }

    /// The ids of the own frames queued to a port, in order.
    fn own_ids(port: &mut VirtualPort) -> Vec<u32> {
        let mut ids = Vec::new();
        while let Some(ev) = port.try_recv() {
            if let PortEvent::Frame { frame, own: true } = ev {
                ids.push(frame.raw_id());
            }
        }
        ids
    }

    #[tokio::test]
    async fn echo_filters_select_which_own_frames_come_back() {
        let bus = VirtualBus::new("t", VirtualBusConfig::default());
        let mut gw = bus.connect(true);
        let peer = bus.connect(false);
        let mut monitor = bus.connect(false);
        let send_all = |gw: &VirtualPort| {
            gw.send(&frame(0x123, &[1])).unwrap();
            gw.send(&frame(0x080, &[])).unwrap();
            gw.send(&Frame::new_error(0x0000_0004, [0; 8])).unwrap();
        };
        let error_id = Frame::new_error(0x0000_0004, [0; 8]).raw_id();

        // Default: every own frame comes back.
        assert_eq!(gw.echo_filters(), None);
        send_all(&gw);
        assert_eq!(own_ids(&mut gw), [0x123, 0x080, error_id]);

        // Only 0x123 (and the error frame, which no id filter selects).
        gw.set_echo_filters(Some(vec![Filter::exact_standard(0x123)]));
        assert_eq!(gw.echo_filters(), Some(vec![Filter::exact_standard(0x123)]));
        send_all(&gw);
        assert_eq!(own_ids(&mut gw), [0x123, error_id]);

        // An empty list: no echo at all, not even of error frames.
        gw.set_echo_filters(Some(Vec::new()));
        send_all(&gw);
        assert!(gw.try_recv().is_none(), "nothing echoed");

        // Others' frames and what other ports see are not affected.
        peer.send(&frame(0x080, &[2])).unwrap();
        peer.send(&frame(0x7FF, &[3])).unwrap();
        match gw.try_recv() {
            Some(PortEvent::Frame { frame, own: false }) => assert_eq!(frame.raw_id(), 0x080),
            other => panic!("{other:?}"),
        }
        assert_eq!(next_frame(&mut gw).await.raw_id(), 0x7FF);
        let mut seen = Vec::new();
        while let Some(PortEvent::Frame { frame, own }) = monitor.try_recv() {
            assert!(!own);
            seen.push(frame.raw_id());
        }
        let all = [0x123, 0x080, error_id];
        let expected: Vec<u32> = [all, all, all]
            .concat()
            .into_iter()
            .chain([0x080, 0x7FF])
            .collect();
        assert_eq!(seen, expected);

        // The sender handle sets the same filter; back to everything.
        let sender = gw.sender();
        sender.set_echo_filters(Some(vec![Filter::exact_standard(0x080)]));
        assert_eq!(gw.echo_filters(), Some(vec![Filter::exact_standard(0x080)]));
        sender
            .send_batch(&[frame(0x123, &[]), frame(0x080, &[])])
            .unwrap();
        assert_eq!(own_ids(&mut gw), [0x080]);
        sender.set_echo_filters(None);
        assert_eq!(sender.echo_filters(), None);
        sender
            .send_batch(&[frame(0x123, &[]), frame(0x080, &[])])
            .unwrap();
        assert_eq!(own_ids(&mut gw), [0x123, 0x080]);

        // The acceptance filters still apply to own frames: the echo filter
        // only narrows.
        gw.set_filters(Some(vec![Filter::exact_standard(0x080)]));
        send_all(&gw);
        assert_eq!(own_ids(&mut gw), [0x080, error_id]);
    }

    #[tokio::test]
    async fn echo_filters_apply_at_completion_on_a_bit_timed_bus() {
        let bus = VirtualBus::new(
            "timed",
            VirtualBusConfig {
                bit_timing: Some(BitTiming::new(1_000_000)),
                ..Default::default()
            },
        );
        let mut gw = bus.connect(true);
        let mut peer = bus.connect(false);
        gw.set_echo_filters(Some(vec![Filter::exact_standard(0x123)]));
        gw.send_batch(&[frame(0x080, &[]), frame(0x123, &[]), frame(0x080, &[])])
            .unwrap();
        for id in [0x080, 0x123, 0x080] {
            assert_eq!(next_frame(&mut peer).await.raw_id(), id);
        }
        // Delivered to the peer in order, so the echo was decided by now.
        assert_eq!(own_ids(&mut gw), [0x123]);
    }

    /// With receive coalescing, frames are handed over no earlier than the
    /// window after their completion, each stamped with its own modelled
    /// completion time; and a frame queued while the scheduler sleeps
    /// towards a later hand-over is still delivered (the enqueue need not
    /// wake it, but must not be forgotten).
    #[tokio::test]
    async fn coalesced_frames_arrive_together_with_exact_timestamps() {
        let timing = BitTiming::new(1_000_000);
        let bus = VirtualBus::new(
            "coalesced",
            VirtualBusConfig {
                bit_timing: Some(timing),
                // Far longer than the burst: the hand-over cannot happen
                // between its frames, however busy the host.
                rx_coalesce: Duration::from_millis(300),
                ..Default::default()
            },
        );
        let gw = bus.connect(false);
        let mut peer = bus.connect(false);
        let burst = [
            frame(0x100, &[1; 8]),
            frame(0x101, &[2; 8]),
            frame(0x102, &[3; 8]),
        ];
        gw.send_batch(&burst).unwrap();
        // A frame of another sender, queued while the scheduler waits.
        let other = bus.connect(false);
        other.send(&frame(0x200, &[])).unwrap();
        let first = next_frame(&mut peer).await;
        // No lower bound on the hand-over's time: the window is the longest
        // a completed frame waits, and a scheduler woken early (an enqueue
        // before it went to sleep, a spurious wake-up) hands over what has
        // completed by then. What the window guarantees is tested below:
        // nothing is lost or reordered, and timestamps stay the model's.
        let mut rest = Vec::new();
        for _ in 0..3 {
            rest.push(next_frame(&mut peer).await);
        }
        assert_eq!(
            rest.iter().map(|f| f.raw_id()).collect::<Vec<_>>(),
            [0x101, 0x102, 0x200],
            "the burst and the frame queued meanwhile, in bus order"
        );
        // Timestamps are the model's: back to back, one frame time apart.
        assert_eq!(
            rest[0].timestamp().0 - first.timestamp().0,
            timing.frame_duration_ns(&burst[1])
        );
        assert_eq!(
            rest[1].timestamp().0 - rest[0].timestamp().0,
            timing.frame_duration_ns(&burst[2])
        );
    }

    /// Each lane of a port is a transmit FIFO of its own on a bit-timed
    /// bus: a frame in lane 0 overtakes the backlog in lane 2 (it waits
    /// only for the frame on the wire), while in the same lane it would
    /// wait behind all of it.
    #[tokio::test]
    async fn lanes_of_a_port_arbitrate_like_separate_nodes() {
        let bus = VirtualBus::new(
            "timed",
            VirtualBusConfig {
                bit_timing: Some(BitTiming::new(1_000_000)),
                ..Default::default()
            },
        );
        let gw = bus.connect(false);
        let mut peer = bus.connect(false);
        let backlog = vec![frame(0x7F0, &[0; 8]); 50];
        gw.send_batch_in_lane(&backlog, 2).unwrap();
        gw.send_batch_in_lane(&[frame(0x080, &[])], 0).unwrap();
        gw.send_batch_in_lane(&backlog, 2).unwrap();
        gw.send_batch_in_lane(&[frame(0x081, &[])], 2).unwrap();
        let mut ids = Vec::new();
        for _ in 0..102 {
            ids.push(next_frame(&mut peer).await.raw_id());
        }
        assert_eq!(ids[1], 0x080, "lane 0 overtakes lane 2's backlog");
        assert_eq!(ids[101], 0x081, "lane 2 stays in order");
        assert!(ids[2..101].iter().all(|&id| id == 0x7F0));
    }

    #[tokio::test]
    async fn fd_refused_on_classic_bus() {
        let bus = VirtualBus::new(
            "classic",
            VirtualBusConfig {
                fd: false,
                ..Default::default()
            },
        );
        let a = bus.connect(false);
        let fd = Frame::new_fd(CanId::Standard(1), &[0; 12], false, false).unwrap();
        assert!(matches!(a.send(&fd), Err(SendError::FdNotSupported(_))));
    }

    #[tokio::test]
    async fn bus_off_refuses_and_reports() {
        let bus = VirtualBus::new("t", VirtualBusConfig::default());
        let a = bus.connect(false);
        let mut b = bus.connect(false);
        bus.force_bus_off();
        assert!(matches!(
            b.recv().await,
            PortEvent::State(BusStatus {
                state: BusState::BusOff,
                ..
            })
        ));
        assert!(matches!(a.send(&frame(1, &[])), Err(SendError::BusOff(_))));
        bus.recover();
        assert_eq!(b.recv().await, PortEvent::State(BusStatus::UP));
        a.send(&frame(1, &[])).unwrap();
        assert_eq!(next_frame(&mut b).await.raw_id(), 1);
    }

    #[tokio::test]
    async fn drop_faults_count() {
        let bus = VirtualBus::new("t", VirtualBusConfig::default());
        let a = bus.connect(false);
        let mut b = bus.connect(false);
        bus.set_drop_ids([0x100]);
        a.send(&frame(0x100, &[])).unwrap();
        a.send(&frame(0x101, &[])).unwrap();
        assert_eq!(next_frame(&mut b).await.raw_id(), 0x101);
        bus.set_drop_ids([]);
        bus.set_drop_probability(0.5);
        for _ in 0..1000 {
            a.send(&frame(0x200, &[])).unwrap();
        }
        let dropped = bus.stats().dropped_by_fault - 1;
        assert!((350..650).contains(&dropped), "{dropped}");
    }

    #[tokio::test]
    async fn overflow_is_counted_per_port() {
        let bus = VirtualBus::new(
            "t",
            VirtualBusConfig {
                port_queue: 4,
                ..Default::default()
            },
        );
        let a = bus.connect(false);
        let b = bus.connect(false);
        for i in 0..10 {
            a.send(&frame(i, &[])).unwrap();
        }
        assert_eq!(b.overflows(), 6);
        assert_eq!(bus.stats().port_overflows, 6);
    }

    #[tokio::test]
    async fn bit_timed_bus_stamps_modelled_times_and_echoes_own() {
        let bus = VirtualBus::new(
            "timed",
            VirtualBusConfig {
                bit_timing: Some(BitTiming {
                    stuffing: Stuffing::WorstCase,
                    ..BitTiming::new(1_000_000)
                }),
                ..Default::default()
            },
        );
        let mut a = bus.connect(true);
        let mut b = bus.connect(false);
        for i in 0..100u32 {
            a.send(&frame(0x100, &i.to_le_bytes().repeat(2))).unwrap();
        }
        let mut stamps = Vec::new();
        for _ in 0..100 {
            stamps.push(next_frame(&mut b).await.timestamp().as_nanos());
        }
        for w in stamps.windows(2) {
            assert_eq!(w[1] - w[0], 135_000);
        }
        // The sender sees its own frames with the same bus timestamps.
        match a.recv().await {
            PortEvent::Frame { frame, own } => {
                assert!(own);
                assert_eq!(frame.timestamp().as_nanos(), stamps[0]);
            }
            other => panic!("{other:?}"),
        }
        let load = bus.load_percent().unwrap();
        assert!(load > 0.0 && load <= 100.0);
    }

    #[tokio::test]
    async fn an_answer_ready_at_its_request_is_stamped_on_model_time_however_late_it_is_sent() {
        let bus = VirtualBus::new(
            "timed",
            VirtualBusConfig {
                bit_timing: Some(BitTiming {
                    stuffing: Stuffing::WorstCase,
                    ..BitTiming::new(1_000_000)
                }),
                ..Default::default()
            },
        );
        let master = bus.connect(false);
        let mut device = bus.connect(false);
        let mut observer = bus.connect(false);
        master.send(&frame(0x100, &[0; 8])).unwrap();
        let request = next_frame(&mut device).await;
        let ended = request.timestamp();
        // The device's host thread runs 20 ms late: its answer is still
        // stamped one frame time after the request, as if sent at once.
        std::thread::sleep(Duration::from_millis(20));
        device
            .sender()
            .send_batch_ready_at(&[frame(0x200, &[1; 8])], ended)
            .unwrap();
        // A ready time in the future counts as now.
        device
            .sender()
            .send_batch_ready_at(&[frame(0x201, &[2; 8])], Timestamp(u64::MAX))
            .unwrap();
        assert_eq!(next_frame(&mut observer).await.raw_id(), 0x100);
        let answer = next_frame(&mut observer).await;
        assert_eq!(answer.raw_id(), 0x200);
        assert_eq!(answer.timestamp().as_nanos() - ended.as_nanos(), 135_000);
        let later = next_frame(&mut observer).await;
        assert_eq!(later.raw_id(), 0x201);
        assert!(later.timestamp().as_nanos() >= ended.as_nanos() + 20_000_000);
    }

    #[tokio::test]
    async fn delay_fault_delays_delivery() {
        let bus = VirtualBus::new("t", VirtualBusConfig::default());
        let a = bus.connect(false);
        let mut b = bus.connect(false);
        bus.set_delay(Duration::from_millis(30));
        let t0 = Instant::now();
        a.send(&frame(0x7, &[])).unwrap();
        next_frame(&mut b).await;
        assert!(t0.elapsed() >= Duration::from_millis(30));
    }
}
