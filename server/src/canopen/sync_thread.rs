//! The SYNC producer of a CANopen bus on its own thread.
//!
//! tokio's timers have a resolution of 1 ms, so a SYNC of 1 ms produced
//! from a task comes out late and periods get skipped. This thread sleeps
//! with the OS's high-resolution timer to each absolute deadline of the
//! sans-IO [`SyncProducer`] (no drift: deadline k is origin + k × period)
//! and sends the frame; periods it cannot make in time are counted by the
//! producer and logged, never silently lost. No busy waiting: the thread
//! costs nothing between SYNCs.
//!
//! Each SYNC's batch also carries what the [`SyncRider`]s add: the cyclic
//! set-points of CSP axes, sampled here at the SYNC's time
//! ([`crate::axes::cyclic_setpoints`]).

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
    /// Appends this rider's frames for the SYNC sent at `at`.
    fn on_sync(&self, at: Instant, frames: &mut Vec<Frame>);

    /// Why the SYNC may not stop or change its period now (a cyclic axis
    /// that is moving would lose its set-points mid-move), or `None`.
    fn sync_change_veto(&self) -> Option<String> {
        None
    }
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
    /// Periods skipped because the thread woke too late for them.
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

/// The shared settings of one SYNC thread and the condition variable that
/// wakes a stopped thread when they change.
#[derive(Debug)]
pub struct SyncControl {
    settings: Mutex<(SyncSettings, u64)>,
    changed: Condvar,
}

impl SyncControl {
    /// Settings as given, generation 0.
    pub fn new(settings: SyncSettings) -> SyncControl {
        SyncControl {
            settings: Mutex::new((settings, 0)),
            changed: Condvar::new(),
        }
    }

    /// The current settings.
    pub fn get(&self) -> SyncSettings {
        self.settings.lock().expect("SYNC settings lock").0
    }

    /// Replaces the settings; the thread restarts its schedule (and the
    /// counter at 1) with them.
    pub fn set(&self, settings: SyncSettings) {
        let mut s = self.settings.lock().expect("SYNC settings lock");
        s.0 = settings;
        s.1 += 1;
        self.changed.notify_all();
    }

    fn generation(&self) -> (SyncSettings, u64) {
        *self.settings.lock().expect("SYNC settings lock")
    }

    /// Blocks while stopped and unchanged since `generation`, at most
    /// `max`.
    fn wait_while_stopped(&self, generation: u64, max: Duration) {
        let s = self.settings.lock().expect("SYNC settings lock");
        if s.1 == generation && !s.0.running {
            let _ = self.changed.wait_timeout(s, max);
        }
    }
}

/// A producer for `settings`, started at `now`; `None` when stopped or
/// invalid (the API checks settings before they get here).
fn producer_for(settings: SyncSettings, now: Duration) -> Option<SyncProducer> {
    if !settings.running {
        return None;
    }
    match SyncProducer::new(settings.period, settings.counter_overflow) {
        Ok(mut p) => {
            p.start(now);
            Some(p)
        }
        Err(e) => {
            tracing::error!(error = %e, "SYNC settings refused");
            None
        }
    }
}

/// Starts the thread; it ends when `cancel` fires. It produces while
/// `control`'s settings say `running`, and waits without cost otherwise.
pub fn spawn(
    bus: BusHandle,
    control: Arc<SyncControl>,
    rt_priority: u8,
    counts: Arc<SyncCounts>,
    riders: SyncRiders,
    cancel: CancellationToken,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    let name = format!("sync-{}", bus.name());
    std::thread::Builder::new().name(name).spawn(move || {
        // The gateway's `rt_priority` (0: none), as for its bus thread: a
        // SYNC is the bus's clock, and a late wake-up skips a period.
        crate::realtime::enter(rt_priority, "sync");
        // The frames go through the bus handle's async API; a tiny runtime
        // of this thread drives those calls.
        let rt = match tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
        {
            Ok(rt) => rt,
            Err(e) => {
                tracing::error!(bus = %bus.name(), error = %e, "SYNC producer could not start");
                return;
            }
        };
        let origin = Instant::now();
        let (settings, mut generation) = control.generation();
        let mut producer = producer_for(settings, Duration::ZERO);
        // Skips of producers replaced by a change of settings.
        let mut skipped_before = 0;
        let mut reported_skips = 0;
        let mut frames_capacity = 1;
        let mut last_report = Instant::now();
        while !cancel.is_cancelled() {
            let (settings, now_generation) = control.generation();
            if now_generation != generation {
                generation = now_generation;
                skipped_before += producer.as_ref().map_or(0, SyncProducer::skipped);
                producer = producer_for(settings, origin.elapsed());
            }
            let Some(producer) = producer.as_mut() else {
                control.wait_while_stopped(generation, Duration::from_millis(100));
                continue;
            };
            let Some(deadline) = producer.next_deadline() else {
                continue;
            };
            let wait = (origin + deadline).saturating_duration_since(Instant::now());
            // Wake at least every 100 ms to notice a shutdown.
            std::thread::sleep(wait.min(Duration::from_millis(100)));
            if let Some(frame) = producer.on_tick(origin.elapsed()) {
                // Room for the riders' set-points without a reallocation.
                let mut frames = Vec::with_capacity(frames_capacity);
                frames.push(frame);
                let at = Instant::now();
                riders.lock().expect("SYNC riders lock").retain(|r| {
                    let Some(r) = r.upgrade() else {
                        return false;
                    };
                    r.on_sync(at, &mut frames);
                    true
                });
                // Without entering the runtime unless the bus task's queue
                // is full (a virtual bus is sent to right here).
                frames_capacity = frames_capacity.max(frames.len());
                let sent = match bus.try_submit(frames) {
                    Ok(Some(frames)) => rt.block_on(bus.submit(frames)),
                    Ok(None) => Ok(()),
                    Err(e) => Err(e),
                };
                if let Err(e) = sent {
                    tracing::warn!(bus = %bus.name(), error = %e, "SYNC not sent");
                }
                counts.sent.fetch_add(1, Ordering::Relaxed);
            }
            let skipped = skipped_before + producer.skipped();
            counts.skipped.store(skipped, Ordering::Relaxed);
            if skipped != reported_skips && last_report.elapsed() >= Duration::from_secs(10) {
                tracing::warn!(
                    bus = %bus.name(),
                    skipped = skipped - reported_skips,
                    sent = counts.sent.load(Ordering::Relaxed),
                    "SYNC periods skipped: the producer thread was not scheduled in time"
                );
                reported_skips = skipped;
                last_report = Instant::now();
            }
        }
    })
}
