//! Cyclic transmission run by the gateway for a client: jobs that send a
//! frame (or a few in turn) every interval on the client's behalf, as the
//! Linux broadcast manager's `TX_SETUP` does for a socket. socketcand's BCM
//! mode (`add`, `update`, `delete`) and the `AttachCyclic` messages of a
//! `Bus.Attach` stream (python-can's `send_periodic`) both run their jobs
//! here.
//!
//! - [`CyclicJobs`] is the job table without I/O, driven by time given by
//!   the caller: a job's first frame goes out one interval after it was
//!   started (no burst at the start, as the kernel's `SETTIMER |
//!   STARTTIMER` without `TX_ANNOUNCE`), then one per interval; a job
//!   started again under the same key replaces the old one and restarts
//!   its timer; an update replaces its frames and keeps its timer; a job
//!   that fell behind (a stalled task) sends once and goes on one interval
//!   later, never a burst to catch up; a job with a duration ends once it
//!   has passed.
//! - [`CyclicSender`] runs one client's table in a task of its own, on the
//!   client's [`ClientId`] (other receivers see the frames as that
//!   client's), one frame in flight at a time. Before each frame the
//!   edge's [`CyclicPolicy`] admits it (role, the client's frame budget);
//!   a frame refused there or by the bus (bus-off, down, the client share
//!   full) ends its job, and the edge learns why from
//!   [`CyclicSender::next_event`]. Every job ends when the sender is
//!   dropped (the client's session or stream ended) or the gateway's
//!   cancellation token fires (shutdown); a frame still waiting for the
//!   bus then is withdrawn.

use cangate_can::{BusHandle, ClientId, Frame, SendFailure};
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::{Notify, mpsc};
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

/// The shortest interval a job may have.
pub const MIN_INTERVAL: Duration = Duration::from_millis(1);
/// Jobs one client (a socketcand session, an Attach stream) may have.
pub const MAX_JOBS: usize = 64;
/// Frames one job may send in turn.
pub const MAX_FRAMES_PER_JOB: usize = 256;

/// Why a job could not be started or changed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CyclicError {
    /// The interval is below [`MIN_INTERVAL`].
    #[error("the interval must be at least {} ms", MIN_INTERVAL.as_millis())]
    IntervalTooShort,
    /// [`MAX_JOBS`] jobs run already.
    #[error("at most {MAX_JOBS} cyclic jobs per client")]
    TooManyJobs,
    /// No frames, or more than [`MAX_FRAMES_PER_JOB`].
    #[error("a cyclic job sends 1 to {MAX_FRAMES_PER_JOB} frames in turn; {0} given")]
    FrameCount(usize),
    /// No job under the key.
    #[error("no such cyclic job")]
    NoSuchJob,
}

#[derive(Debug, Clone)]
struct Job {
    frames: Vec<Frame>,
    /// The frame that goes out next.
    turn: usize,
    interval: Duration,
    next: Duration,
    /// When the job ends by itself.
    end: Option<Duration>,
}

/// What [`CyclicJobs::due`] found at a time.
#[derive(Debug, PartialEq, Eq)]
pub struct Due<K> {
    /// The frames to send now, each with its job.
    pub send: Vec<(K, Frame)>,
    /// Jobs whose duration has passed (removed).
    pub finished: Vec<K>,
}

/// One client's cyclic jobs, by key (socketcand: the CAN identifier; an
/// Attach stream: the client's job number), without I/O.
#[derive(Debug)]
pub struct CyclicJobs<K> {
    jobs: BTreeMap<K, Job>,
}

impl<K> Default for CyclicJobs<K> {
    fn default() -> Self {
        CyclicJobs {
            jobs: BTreeMap::new(),
        }
    }
}

fn check_frames(frames: &[Frame]) -> Result<(), CyclicError> {
    if frames.is_empty() || frames.len() > MAX_FRAMES_PER_JOB {
        return Err(CyclicError::FrameCount(frames.len()));
    }
    Ok(())
}

impl<K: Ord + Copy> CyclicJobs<K> {
    /// Starts a job sending `frames` in turn, one every `interval`, the
    /// first at `now + interval`, until `duration` (if any) has passed;
    /// replaces a job of the same key.
    ///
    /// # Errors
    /// An interval below [`MIN_INTERVAL`], a wrong number of frames,
    /// [`MAX_JOBS`] other jobs already.
    pub fn start(
        &mut self,
        key: K,
        frames: Vec<Frame>,
        interval: Duration,
        duration: Option<Duration>,
        now: Duration,
    ) -> Result<(), CyclicError> {
        if interval < MIN_INTERVAL {
            return Err(CyclicError::IntervalTooShort);
        }
        check_frames(&frames)?;
        if !self.jobs.contains_key(&key) && self.jobs.len() >= MAX_JOBS {
            return Err(CyclicError::TooManyJobs);
        }
        self.jobs.insert(
            key,
            Job {
                frames,
                turn: 0,
                interval,
                next: now + interval,
                end: duration.map(|d| now + d),
            },
        );
        Ok(())
    }

    /// Replaces a job's frames, its timer going on.
    ///
    /// # Errors
    /// No job under the key, or a wrong number of frames.
    pub fn update(&mut self, key: K, frames: Vec<Frame>) -> Result<(), CyclicError> {
        check_frames(&frames)?;
        let job = self.jobs.get_mut(&key).ok_or(CyclicError::NoSuchJob)?;
        if job.turn >= frames.len() {
            job.turn = 0;
        }
        job.frames = frames;
        Ok(())
    }

    /// Ends a job.
    ///
    /// # Errors
    /// No job under the key.
    pub fn stop(&mut self, key: K) -> Result<(), CyclicError> {
        self.jobs
            .remove(&key)
            .map(|_| ())
            .ok_or(CyclicError::NoSuchJob)
    }

    /// Whether a job runs under the key.
    pub fn contains(&self, key: K) -> bool {
        self.jobs.contains_key(&key)
    }

    /// Whether no job runs.
    pub fn is_empty(&self) -> bool {
        self.jobs.is_empty()
    }

    /// The next time something is due ([`CyclicJobs::due`]).
    pub fn next_deadline(&self) -> Option<Duration> {
        self.jobs
            .values()
            .map(|j| j.end.map_or(j.next, |e| e.min(j.next)))
            .min()
    }

    /// What is due at `now`: each job's frame once (its next time one
    /// interval on, or `now` plus one interval when it fell behind by
    /// more), and the jobs whose duration has passed.
    pub fn due(&mut self, now: Duration) -> Due<K> {
        let mut send = Vec::new();
        let mut finished = Vec::new();
        for (key, job) in &mut self.jobs {
            if job.end.is_some_and(|e| e <= now) {
                finished.push(*key);
                continue;
            }
            if job.next <= now {
                send.push((*key, job.frames[job.turn]));
                job.turn = (job.turn + 1) % job.frames.len();
                job.next += job.interval;
                if job.next <= now {
                    // Behind (a stalled task): no burst to catch up.
                    job.next = now + job.interval;
                }
            }
        }
        for key in &finished {
            self.jobs.remove(key);
        }
        Due { send, finished }
    }
}

/// What an edge decides about its client's cyclic frames.
pub trait CyclicPolicy: Send + 'static {
    /// Why a frame was refused, in the edge's terms.
    type Refusal: Send + 'static;

    /// Before a frame goes to the bus: may it (the client's role, its
    /// frame budget)? A refusal ends the frame's job.
    ///
    /// # Errors
    /// The refusal to report.
    fn admit(&mut self, frame: &Frame) -> Result<(), Self::Refusal>;

    /// The bus's outcome of an admitted frame (counted by the edge); a
    /// refusal ends the frame's job.
    ///
    /// # Errors
    /// The refusal to report.
    fn sent(&mut self, outcome: Result<(), SendFailure>) -> Result<(), Self::Refusal>;
}

/// A job that ended by itself.
#[derive(Debug)]
pub enum CyclicEvent<K, R> {
    /// One of its frames was refused: the job is gone.
    Refused {
        /// The job.
        key: K,
        /// Why, from the edge's [`CyclicPolicy`].
        refusal: R,
    },
    /// Its duration has passed.
    Finished {
        /// The job.
        key: K,
    },
}

/// The state the task and the handle share.
struct Shared<K> {
    jobs: Mutex<CyclicJobs<K>>,
    /// A job was started, changed or stopped: the task looks again.
    changed: Notify,
    started: Instant,
}

impl<K> Shared<K> {
    fn jobs(&self) -> std::sync::MutexGuard<'_, CyclicJobs<K>> {
        self.jobs.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// One client's cyclic jobs, running in a task of their own (see the
/// module documentation); dropping it ends them all.
pub struct CyclicSender<K, R> {
    shared: Arc<Shared<K>>,
    events: mpsc::UnboundedReceiver<CyclicEvent<K, R>>,
    /// Ends the task (on drop, or with the gateway's token).
    stop: CancellationToken,
}

impl<K, R> Drop for CyclicSender<K, R> {
    fn drop(&mut self) {
        self.stop.cancel();
    }
}

impl<K, R> std::fmt::Debug for CyclicSender<K, R> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CyclicSender").finish_non_exhaustive()
    }
}

impl<K, R> CyclicSender<K, R>
where
    K: Ord + Copy + Send + 'static,
    R: Send + 'static,
{
    /// Starts the task of `client`'s jobs on `bus`, each frame admitted by
    /// `policy`; it ends when this is dropped or `shutdown` fires.
    pub fn spawn<P: CyclicPolicy<Refusal = R>>(
        bus: BusHandle,
        client: ClientId,
        policy: P,
        shutdown: &CancellationToken,
    ) -> Self {
        let shared = Arc::new(Shared {
            jobs: Mutex::new(CyclicJobs::default()),
            changed: Notify::new(),
            started: Instant::now(),
        });
        let (tx, events) = mpsc::unbounded_channel();
        let stop = shutdown.child_token();
        tokio::spawn(run(shared.clone(), bus, client, policy, tx, stop.clone()));
        CyclicSender {
            shared,
            events,
            stop,
        }
    }

    fn now(&self) -> Duration {
        self.shared.started.elapsed()
    }

    /// Starts (or restarts, replacing it) the job `key` (see
    /// [`CyclicJobs::start`]).
    ///
    /// # Errors
    /// As [`CyclicJobs::start`].
    pub fn start(
        &self,
        key: K,
        frames: Vec<Frame>,
        interval: Duration,
        duration: Option<Duration>,
    ) -> Result<(), CyclicError> {
        let now = self.now();
        self.shared
            .jobs()
            .start(key, frames, interval, duration, now)?;
        self.shared.changed.notify_one();
        Ok(())
    }

    /// Replaces the frames of the job `key`, its timer going on.
    ///
    /// # Errors
    /// As [`CyclicJobs::update`].
    pub fn update(&self, key: K, frames: Vec<Frame>) -> Result<(), CyclicError> {
        self.shared.jobs().update(key, frames)?;
        self.shared.changed.notify_one();
        Ok(())
    }

    /// Ends the job `key`: no frame of it is sent after this returns
    /// (one already handed to the bus may still go out).
    ///
    /// # Errors
    /// No such job.
    pub fn stop(&self, key: K) -> Result<(), CyclicError> {
        self.shared.jobs().stop(key)?;
        self.shared.changed.notify_one();
        Ok(())
    }

    /// Whether any job runs.
    pub fn active(&self) -> bool {
        !self.shared.jobs().is_empty()
    }

    /// The next job that ended by itself (never returns while none does).
    pub async fn next_event(&mut self) -> CyclicEvent<K, R> {
        match self.events.recv().await {
            Some(e) => e,
            // The task ended (shutdown): nothing more comes.
            None => std::future::pending().await,
        }
    }
}

/// The task of a [`CyclicSender`].
async fn run<K, P>(
    shared: Arc<Shared<K>>,
    bus: BusHandle,
    client: ClientId,
    mut policy: P,
    events: mpsc::UnboundedSender<CyclicEvent<K, P::Refusal>>,
    stop: CancellationToken,
) where
    K: Ord + Copy + Send + 'static,
    P: CyclicPolicy,
{
    loop {
        let deadline = shared.jobs().next_deadline();
        tokio::select! {
            biased;
            _ = stop.cancelled() => return,
            _ = shared.changed.notified() => continue,
            _ = tokio::time::sleep_until(
                deadline.map_or_else(Instant::now, |d| shared.started + d)
            ), if deadline.is_some() => {}
        }
        let due = shared.jobs().due(shared.started.elapsed());
        for key in due.finished {
            let _ = events.send(CyclicEvent::Finished { key });
        }
        for (key, frame) in due.send {
            // Stopped or replaced while an earlier frame was in flight.
            if !shared.jobs().contains(key) {
                continue;
            }
            let outcome = match policy.admit(&frame) {
                Err(refusal) => Err(refusal),
                Ok(()) => {
                    // One frame in flight: the next waits for this one's
                    // outcome, so a slow bus slows the jobs down (they skip
                    // the periods they miss) instead of queueing frames.
                    let sent = tokio::select! {
                        biased;
                        _ = stop.cancelled() => return,
                        r = async { bus.queue_as_client(client, vec![frame]).await.outcome().await } => r,
                    };
                    policy.sent(sent)
                }
            };
            if let Err(refusal) = outcome {
                let _ = shared.jobs().stop(key);
                let _ = events.send(CyclicEvent::Refused { key, refusal });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cangate_can::CanId;

    fn frame(id: u16, data: &[u8]) -> Frame {
        Frame::new(CanId::Standard(id), data).unwrap()
    }

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    fn sent<K: Copy>(d: &Due<K>) -> Vec<Frame> {
        d.send.iter().map(|(_, f)| *f).collect()
    }

    #[test]
    fn a_job_sends_every_interval_from_one_interval_on() {
        let mut j = CyclicJobs::default();
        j.start(
            1u32,
            vec![frame(0x123, &[0x11, 0x22])],
            ms(100),
            None,
            ms(0),
        )
        .unwrap();
        assert_eq!(j.next_deadline(), Some(ms(100)));
        assert!(j.due(ms(99)).send.is_empty());
        assert_eq!(sent(&j.due(ms(100))), vec![frame(0x123, &[0x11, 0x22])]);
        assert_eq!(j.next_deadline(), Some(ms(200)));
        // Update: new content, same timer.
        j.update(1, vec![frame(0x123, &[0x33])]).unwrap();
        assert_eq!(j.next_deadline(), Some(ms(200)));
        assert_eq!(sent(&j.due(ms(200))), vec![frame(0x123, &[0x33])]);
        // Behind by several periods: one frame, no burst.
        assert_eq!(j.due(ms(750)).send.len(), 1);
        assert_eq!(j.next_deadline(), Some(ms(850)));
        // Started again: the timer restarts.
        j.start(1, vec![frame(0x123, &[0x44])], ms(100), None, ms(800))
            .unwrap();
        assert_eq!(j.next_deadline(), Some(ms(900)));
        j.stop(1).unwrap();
        assert_eq!(j.next_deadline(), None);
        assert!(j.is_empty());
        assert_eq!(
            j.update(1, vec![frame(0x123, &[1])]),
            Err(CyclicError::NoSuchJob)
        );
        assert_eq!(j.stop(1), Err(CyclicError::NoSuchJob));
        assert_eq!(
            j.start(
                2,
                vec![frame(0x1, &[])],
                Duration::from_micros(10),
                None,
                ms(0)
            ),
            Err(CyclicError::IntervalTooShort)
        );
        assert_eq!(
            j.start(2, vec![], ms(10), None, ms(0)),
            Err(CyclicError::FrameCount(0))
        );
    }

    #[test]
    fn several_frames_go_in_turn_and_a_duration_ends_the_job() {
        let mut j = CyclicJobs::default();
        let (a, b) = (frame(0x10, &[1]), frame(0x10, &[2]));
        j.start(7u32, vec![a, b], ms(10), Some(ms(35)), ms(0))
            .unwrap();
        assert_eq!(sent(&j.due(ms(10))), vec![a]);
        assert_eq!(sent(&j.due(ms(20))), vec![b]);
        assert_eq!(sent(&j.due(ms(30))), vec![a]);
        // The end comes before the next frame.
        assert_eq!(j.next_deadline(), Some(ms(35)));
        let d = j.due(ms(35));
        assert!(d.send.is_empty());
        assert_eq!(d.finished, vec![7]);
        assert!(j.is_empty());
        // An update with fewer frames starts over at the first.
        j.start(1, vec![a, b], ms(10), None, ms(0)).unwrap();
        assert_eq!(sent(&j.due(ms(10))), vec![a]);
        j.update(1, vec![b]).unwrap();
        assert_eq!(sent(&j.due(ms(20))), vec![b]);
    }

    #[test]
    fn jobs_are_bounded_per_client() {
        let mut j = CyclicJobs::default();
        for i in 0..MAX_JOBS as u16 {
            j.start(i, vec![frame(i, &[])], ms(10), None, ms(0))
                .unwrap();
        }
        assert_eq!(
            j.start(0x700, vec![frame(0x700, &[])], ms(10), None, ms(0)),
            Err(CyclicError::TooManyJobs)
        );
        // Replacing an existing job is fine.
        j.start(0, vec![frame(0, &[1])], ms(20), None, ms(5))
            .unwrap();
    }
}
