//! The SYNC producers of a gateway's CANopen buses, on one thread.
//!
//! tokio's timers have a resolution of 1 ms, so a SYNC of 1 ms produced
//! from a task comes out late and periods get skipped. This thread sleeps
//! with the OS's high-resolution timer to each absolute deadline of the
//! sans-IO [`SyncProducer`]s (no drift: deadline k is origin + k × period)
//! and sends the frames; periods it cannot make in time are counted by the
//! producer and logged, never silently lost. No busy waiting: the thread
//! costs nothing between SYNCs.
//!
//! One thread serves every bus of the gateway: producers start on a grid
//! common to their period, so buses with the same period are due together
//! and cost one wake-up per period between them, not one each (see
//! "Wake-ups cost more than frames" in docs/design.md).
//!
//! Each SYNC's batch also carries what the [`SyncRider`]s add: the cyclic
//! set-points of CSP axes, sampled here ([`crate::axes::cyclic_setpoints`])
//! on the SYNC's nominal grid, told how many periods went without a SYNC
//! ([`SyncTick`]) so that a skipped period is never a double step.

use cangate_can::{BusHandle, Frame};
use cangate_canopen::sync::SyncProducer;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, Weak};
use std::time::{Duration, Instant};
use tokio_util::sync::CancellationToken;

/// Frames that leave with every SYNC, right after it in the same batch: the
/// cyclic set-points of CSP axes. Called on the SYNC thread, so it must be
/// quick and never block on anything but a short lock.
///
/// Why on this thread: a set-point computed by the task that runs the axes
/// needs that task woken by every SYNC, a thread hand-over per period that
/// dominated the gateway's CPU at a 1 ms SYNC. Sampling a trajectory here
/// costs well under a microsecond per axis.
pub trait SyncRider: Send + Sync {
    /// Appends this rider's frames for the SYNC of `tick`.
    fn on_sync(&self, tick: SyncTick, frames: &mut Vec<Frame>);

    /// Why the SYNC may not stop or change its period now (a cyclic axis
    /// that is moving would lose its set-points mid-move), or `None`.
    fn sync_change_veto(&self) -> Option<String> {
        None
    }
}

/// One SYNC as its riders see it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SyncTick {
    /// When the SYNC was due: its place on the period grid, not when the
    /// thread got to send it (a set-point is for its SYNC).
    pub at: Instant,
    /// The periods that went without a SYNC since the previous SYNC sent
    /// (the thread woke too late for them, or the bus's queue was full),
    /// as time: what a cyclic plan holds back by, so that it advances one
    /// period per SYNC sent.
    pub missed: Duration,
}

impl SyncTick {
    /// A SYNC at `at` right one period after the previous one.
    pub fn on_time(at: Instant) -> SyncTick {
        SyncTick {
            at,
            missed: Duration::ZERO,
        }
    }
}

/// The SYNC `producer` sends at `now`, if one is due: the frame, the
/// SYNC's due time on the grid, and the periods skipped before it (with
/// `unsent` periods whose SYNC was built but not sent).
pub(crate) fn due_sync(
    producer: &mut SyncProducer,
    now: Duration,
    unsent: u64,
) -> Option<(Frame, Duration, Duration)> {
    let skipped_before = producer.skipped();
    let frame = producer.on_tick(now)?;
    let skipped = producer.skipped() - skipped_before + unsent;
    let period = producer.period();
    let due = producer
        .next_deadline()
        .map_or(now, |next| next.saturating_sub(period));
    let missed = period.saturating_mul(u32::try_from(skipped).unwrap_or(u32::MAX));
    Some((frame, due, missed))
}

/// The riders of one SYNC producer. Held weakly: a rider whose owner ended
/// drops out at the next SYNC.
pub type SyncRiders = Arc<Mutex<Vec<Weak<dyn SyncRider>>>>;

/// What the thread did, for the metrics (`cangate_sync_sent_total`,
/// `cangate_sync_skipped_total`) and benchmarks: counters, so that nobody
/// is woken per SYNC to count it.
#[derive(Debug, Default)]
pub struct SyncCounts {
    /// SYNC frames handed to the bus.
    pub sent: AtomicU64,
    /// Periods without a SYNC: the thread woke too late for them, or the
    /// bus task's queue was full (the thread serves every bus, so it never
    /// waits for one).
    pub skipped: AtomicU64,
}

/// What the SYNC producer should do: changed at run time through
/// [`SyncControl::set`], taken up by the thread at its next wake-up (at the
/// latest one period or 100 ms later).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SyncSettings {
    /// Producing, or stopped.
    pub running: bool,
    /// Communication cycle period (0x1006).
    pub period: Duration,
    /// Counter overflow value (0x1019): 0 = no counter, 2..=240.
    pub counter_overflow: u8,
}

/// Wakes the SYNC thread when something it serves changes (a bus added,
/// settings set), so that a stopped SYNC starts at once.
#[derive(Debug, Default)]
struct Wake {
    changes: Mutex<u64>,
    changed: Condvar,
}

impl Wake {
    fn notify(&self) {
        *self.changes.lock().expect("SYNC wake lock") += 1;
        self.changed.notify_all();
    }

    fn changes(&self) -> u64 {
        *self.changes.lock().expect("SYNC wake lock")
    }

    /// Blocks while nothing changed since `seen` was read, at most `max`.
    fn wait(&self, seen: u64, max: Duration) {
        let changes = self.changes.lock().expect("SYNC wake lock");
        if *changes == seen {
            let _ = self.changed.wait_timeout(changes, max);
        }
    }
}

/// The settings of one bus's SYNC, with a generation that counts changes.
#[derive(Debug)]
pub struct SyncControl {
    settings: Mutex<(SyncSettings, u64)>,
    wake: Arc<Wake>,
}

impl SyncControl {
    /// Settings as given, generation 0, not served by a thread.
    pub fn new(settings: SyncSettings) -> SyncControl {
        SyncControl {
            settings: Mutex::new((settings, 0)),
            wake: Arc::default(),
        }
    }

    /// The current settings.
    pub fn get(&self) -> SyncSettings {
        self.settings.lock().expect("SYNC settings lock").0
    }

    /// Replaces the settings; the thread restarts this bus's schedule (and
    /// the counter at 1) with them.
    pub fn set(&self, settings: SyncSettings) {
        {
            let mut s = self.settings.lock().expect("SYNC settings lock");
            s.0 = settings;
            s.1 += 1;
        }
        self.wake.notify();
    }

    fn generation(&self) -> (SyncSettings, u64) {
        *self.settings.lock().expect("SYNC settings lock")
    }
}

/// A producer for `settings`, started on its period's grid at or before
/// `now` (so that buses of the same period are due together); `None` when
/// stopped or invalid (the API checks settings before they get here).
fn producer_for(settings: SyncSettings, now: Duration) -> Option<SyncProducer> {
    if !settings.running {
        return None;
    }
    match SyncProducer::new(settings.period, settings.counter_overflow) {
        Ok(mut p) => {
            p.start(on_grid(now, settings.period));
            Some(p)
        }
        Err(e) => {
            tracing::error!(error = %e, "SYNC settings refused");
            None
        }
    }
}

/// The last multiple of `period` at or before `now`.
fn on_grid(now: Duration, period: Duration) -> Duration {
    let period = period.as_nanos().max(1);
    let k = now.as_nanos() / period;
    Duration::from_nanos(u64::try_from(k * period).unwrap_or(u64::MAX))
}

/// One bus served by the SYNC thread.
struct Registration {
    bus: BusHandle,
    control: Arc<SyncControl>,
    counts: Arc<SyncCounts>,
    riders: SyncRiders,
    /// The bus's master stopped: the thread drops it.
    cancel: CancellationToken,
}

/// The SYNC thread of a gateway: started with the first bus added, it
/// produces the SYNC of every bus added until the gateway's `cancel`.
#[derive(Clone)]
pub struct SyncThread {
    shared: Arc<ThreadShared>,
}

struct ThreadShared {
    wake: Arc<Wake>,
    /// Buses added since the thread last looked.
    added: Mutex<Vec<Registration>>,
    started: Mutex<bool>,
    rt_priority: u8,
    cancel: CancellationToken,
}

impl SyncThread {
    /// The thread, not started yet; it will run with the gateway's
    /// `rt_priority` (0: none), as its bus threads: a SYNC is the bus's
    /// clock, and a late wake-up skips a period.
    pub fn new(rt_priority: u8, cancel: CancellationToken) -> SyncThread {
        SyncThread {
            shared: Arc::new(ThreadShared {
                wake: Arc::default(),
                added: Mutex::default(),
                started: Mutex::new(false),
                rt_priority,
                cancel,
            }),
        }
    }

    /// Produces `bus`'s SYNC from now on, while the returned control's
    /// settings say `running` (stopped, it costs nothing), until `cancel`.
    /// Fails only when the thread cannot be started.
    pub fn add(
        &self,
        bus: BusHandle,
        settings: SyncSettings,
        counts: Arc<SyncCounts>,
        riders: SyncRiders,
        cancel: CancellationToken,
    ) -> std::io::Result<Arc<SyncControl>> {
        let control = Arc::new(SyncControl {
            settings: Mutex::new((settings, 0)),
            wake: self.shared.wake.clone(),
        });
        {
            let mut started = self.shared.started.lock().expect("SYNC thread lock");
            if !*started {
                let shared = self.shared.clone();
                std::thread::Builder::new()
                    .name("sync-canopen".into())
                    .spawn(move || run(&shared))?;
                *started = true;
            }
        }
        self.shared
            .added
            .lock()
            .expect("SYNC thread lock")
            .push(Registration {
                bus,
                control: control.clone(),
                counts,
                riders,
                cancel,
            });
        self.shared.wake.notify();
        Ok(control)
    }
}

/// A bus's SYNC as the thread runs it.
struct Producing {
    reg: Registration,
    /// Generation of the settings the producer follows (`None`: not read).
    generation: Option<u64>,
    producer: Option<SyncProducer>,
    /// Skips of producers replaced by a change of settings.
    skipped_before: u64,
    /// SYNCs not sent because the bus task's queue was full.
    not_queued: u64,
    /// Of those, the ones since the latest SYNC sent: the riders hold back
    /// by them at the next.
    unsent: u64,
    reported_skips: u64,
    last_report: Instant,
    /// Room for the riders' set-points without a reallocation.
    frames_capacity: usize,
}

impl Producing {
    fn new(reg: Registration) -> Producing {
        Producing {
            reg,
            generation: None,
            producer: None,
            skipped_before: 0,
            not_queued: 0,
            unsent: 0,
            reported_skips: 0,
            last_report: Instant::now(),
            frames_capacity: 1,
        }
    }

    /// Takes up changed settings: a new schedule from `now`.
    fn follow_settings(&mut self, now: Duration) {
        let (settings, generation) = self.reg.control.generation();
        if self.generation != Some(generation) {
            self.generation = Some(generation);
            self.skipped_before += self.producer.as_ref().map_or(0, SyncProducer::skipped);
            self.producer = producer_for(settings, now);
        }
    }

    fn next_deadline(&self) -> Option<Duration> {
        self.producer.as_ref()?.next_deadline()
    }

    /// Sends the SYNC, with the riders' frames, if one is due at `now`.
    fn tick(&mut self, origin: Instant, now: Duration) {
        let Some(producer) = self.producer.as_mut() else {
            return;
        };
        let bus = &self.reg.bus;
        if let Some((frame, due, missed)) = due_sync(producer, now, self.unsent) {
            let mut frames = Vec::with_capacity(self.frames_capacity);
            frames.push(frame);
            let tick = SyncTick {
                at: origin + due,
                missed,
            };
            self.reg
                .riders
                .lock()
                .expect("SYNC riders lock")
                .retain(|r| {
                    let Some(r) = r.upgrade() else {
                        return false;
                    };
                    r.on_sync(tick, &mut frames);
                    true
                });
            self.frames_capacity = self.frames_capacity.max(frames.len());
            // Never waits: a bus whose task's queue is full (its interface
            // stalled) must not hold up the other buses' SYNCs. A virtual
            // bus is sent to right here.
            match bus.try_submit(frames) {
                Ok(None) => {
                    self.unsent = 0;
                    self.reg.counts.sent.fetch_add(1, Ordering::Relaxed);
                }
                Ok(Some(_)) => {
                    self.not_queued += 1;
                    self.unsent += 1;
                }
                Err(e) => {
                    tracing::warn!(bus = %bus.name(), error = %e, "SYNC not sent");
                    self.unsent = 0;
                    self.reg.counts.sent.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        let skipped = self.skipped_before + producer.skipped() + self.not_queued;
        self.reg.counts.skipped.store(skipped, Ordering::Relaxed);
        if skipped != self.reported_skips && self.last_report.elapsed() >= Duration::from_secs(10) {
            tracing::warn!(
                bus = %bus.name(),
                skipped = skipped - self.reported_skips,
                sent = self.reg.counts.sent.load(Ordering::Relaxed),
                "SYNC periods skipped: the SYNC thread was not scheduled in time, or the bus's queue was full"
            );
            self.reported_skips = skipped;
            self.last_report = Instant::now();
        }
    }
}

/// The thread: sleeps to the earliest deadline of its buses, sends what
/// is due, takes up added buses and changed settings at each wake-up.
fn run(shared: &ThreadShared) {
    crate::realtime::enter(shared.rt_priority, "sync");
    let origin = Instant::now();
    let mut buses: Vec<Producing> = Vec::new();
    while !shared.cancel.is_cancelled() {
        let seen = shared.wake.changes();
        buses.extend(
            shared
                .added
                .lock()
                .expect("SYNC thread lock")
                .drain(..)
                .map(Producing::new),
        );
        buses.retain(|b| !b.reg.cancel.is_cancelled());
        let now = origin.elapsed();
        for b in &mut buses {
            b.follow_settings(now);
        }
        let Some(next) = buses.iter().filter_map(Producing::next_deadline).min() else {
            // Nothing to produce: until a change (or a shutdown check).
            shared.wake.wait(seen, Duration::from_millis(100));
            continue;
        };
        let wait = (origin + next).saturating_duration_since(Instant::now());
        // Wake at least every 100 ms to notice a shutdown.
        std::thread::sleep(wait.min(Duration::from_millis(100)));
        let now = origin.elapsed();
        for b in &mut buses {
            b.tick(origin, now);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cangate_can::{
        Backend, BackendKind, BusInfo, PortEvent, Stuffing, VirtualBus, VirtualBusConfig,
        VirtualPort,
    };

    #[test]
    fn producers_start_on_their_periods_grid() {
        let ms = Duration::from_millis;
        assert_eq!(on_grid(Duration::from_micros(2_500), ms(1)), ms(2));
        assert_eq!(on_grid(ms(3), ms(1)), ms(3));
        assert_eq!(on_grid(ms(7), ms(10)), Duration::ZERO);
        assert_eq!(on_grid(ms(7), Duration::ZERO), ms(7));
        // Two buses of one period started apart are due at the same times.
        let settings = SyncSettings {
            running: true,
            period: ms(1),
            counter_overflow: 0,
        };
        let a = producer_for(settings, Duration::from_micros(100)).unwrap();
        let b = producer_for(settings, Duration::from_micros(900)).unwrap();
        assert_eq!(a.next_deadline(), Some(ms(1)));
        assert_eq!(a.next_deadline(), b.next_deadline());
        assert!(
            producer_for(
                SyncSettings {
                    running: false,
                    ..settings
                },
                ms(1)
            )
            .is_none()
        );
    }

    /// A SYNC is due on its grid whenever the thread gets to it; the
    /// periods it skipped, and SYNCs built but not sent, are what its
    /// riders hold back by.
    #[test]
    fn a_late_sync_is_due_on_its_grid_and_says_what_was_missed() {
        let ms = Duration::from_millis;
        let mut p = SyncProducer::new(ms(1), 0).unwrap();
        p.start(Duration::ZERO);
        assert!(due_sync(&mut p, Duration::from_micros(900), 0).is_none());
        let (frame, due, missed) = due_sync(&mut p, Duration::from_micros(1_300), 0).unwrap();
        assert_eq!(frame.raw_id(), 0x80);
        assert_eq!((due, missed), (ms(1), Duration::ZERO));
        // Woken 3.4 periods late: the SYNC of 5 ms, 2..=4 skipped.
        let (_, due, missed) = due_sync(&mut p, Duration::from_micros(5_400), 0).unwrap();
        assert_eq!((due, missed), (ms(5), ms(3)));
        // On time again, after one SYNC that was not sent.
        let (_, due, missed) = due_sync(&mut p, ms(6), 1).unwrap();
        assert_eq!((due, missed), (ms(6), ms(1)));
    }

    fn bus(name: &str, cancel: &CancellationToken) -> (BusHandle, VirtualPort) {
        let vbus = VirtualBus::new(name, VirtualBusConfig::default());
        let info = BusInfo {
            name: name.into(),
            kind: BackendKind::Virtual,
            interface: name.into(),
            fd: false,
            bitrate: None,
            data_bitrate: None,
            bit_timed: false,
            stuffing: Stuffing::Exact,
        };
        let (h, _) = BusHandle::spawn(info, Backend::Virtual(vbus.connect(true)), cancel.clone());
        (h, vbus.connect(false))
    }

    /// SYNCs seen on `port` within `d`.
    async fn syncs(port: &mut VirtualPort, d: Duration) -> usize {
        let mut n = 0;
        let end = tokio::time::Instant::now() + d;
        while let Ok(e) = tokio::time::timeout_at(end, port.recv()).await {
            if matches!(e, PortEvent::Frame { frame, .. } if frame.raw_id() == 0x80) {
                n += 1;
            }
        }
        n
    }

    /// One thread serves several buses, each with its own settings: one
    /// started at run time, one stopped while the other runs on, one
    /// dropped when its master's token is cancelled.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn one_thread_serves_every_bus_with_its_own_settings() {
        let gateway = CancellationToken::new();
        let thread = SyncThread::new(0, gateway.clone());
        let (a, mut port_a) = bus("a", &gateway);
        let (b, mut port_b) = bus("b", &gateway);
        let period = Duration::from_millis(5);
        let running = SyncSettings {
            running: true,
            period,
            counter_overflow: 0,
        };
        let stopped = SyncSettings {
            running: false,
            ..running
        };
        let counts_a = Arc::new(SyncCounts::default());
        let master_b = gateway.child_token();
        let ctl_a = thread
            .add(
                a,
                running,
                counts_a.clone(),
                SyncRiders::default(),
                gateway.child_token(),
            )
            .unwrap();
        let ctl_b = thread
            .add(
                b,
                stopped,
                Arc::default(),
                SyncRiders::default(),
                master_b.clone(),
            )
            .unwrap();
        let window = Duration::from_millis(300);
        assert!(syncs(&mut port_a, window).await > 10, "a produces");
        assert_eq!(
            syncs(&mut port_b, Duration::from_millis(50)).await,
            0,
            "b is stopped"
        );
        ctl_b.set(running);
        assert!(
            syncs(&mut port_b, window).await > 10,
            "b started at run time"
        );
        ctl_a.set(stopped);
        tokio::time::sleep(Duration::from_millis(20)).await;
        while port_a.try_recv().is_some() {}
        let sent = counts_a.sent.load(Ordering::Relaxed);
        assert!(sent > 10);
        let (quiet_a, busy_b) =
            tokio::join!(syncs(&mut port_a, window), syncs(&mut port_b, window));
        assert_eq!(quiet_a, 0, "a stopped");
        assert!(busy_b > 10, "b runs on");
        assert_eq!(counts_a.sent.load(Ordering::Relaxed), sent);
        master_b.cancel();
        tokio::time::sleep(Duration::from_millis(20)).await;
        while port_b.try_recv().is_some() {}
        assert_eq!(
            syncs(&mut port_b, Duration::from_millis(100)).await,
            0,
            "b dropped"
        );
        gateway.cancel();
    }
}
