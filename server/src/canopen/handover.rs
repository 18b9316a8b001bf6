//! The hand-over of a request between a caller's thread and the bus thread
//! (`gateway-bus`), spinning briefly instead of sleeping where the answer
//! is due within microseconds.
//!
//! Why: an SDO read of a device on a virtual bus takes ~3 µs on the bus
//! thread, but a caller on another runtime (a gRPC handler, an embedding
//! application's control loop) paid two thread wake-ups on top, ~25 µs
//! each on a virtual machine: the bus thread asleep when the request came,
//! the caller asleep when the answer came. Here the caller keeps polling
//! its reply for a short budget before it sleeps, and the bus thread keeps
//! polling its queues for that budget after each request, so that a caller
//! issuing requests back to back finds both sides awake.
//!
//! The spin is bounded and adaptive: the caller spins only while the
//! recent answers on this bus came within the budget (a real bus at
//! 1 Mbit/s answers in hundreds of µs: nobody spins there), never on the
//! bus thread itself (it would wait for itself), and not at all with a
//! budget of 0 ([`Handover::off`]). A caller whose own thread would have to
//! produce the answer (a device simulated on the caller's single-threaded
//! runtime) loses one budget, then the slow answers stop the spinning.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};
use tokio::sync::{Notify, oneshot};

/// One bus's hand-over: the spin budget, the recent answer time and the
/// bus thread's keep-awake deadline.
#[derive(Clone)]
pub struct Handover {
    inner: Arc<Inner>,
}

struct Inner {
    /// How long a side spins in ns (0: never).
    budget_ns: AtomicU64,
    /// The runtime of the bus thread (its callers must not spin).
    bus_runtime: Option<tokio::runtime::Id>,
    /// A moving average of recent answer times in ns (what decides whether
    /// the next caller spins).
    recent_ns: AtomicU64,
    origin: Instant,
    /// Until when (ns since `origin`) the bus thread stays awake.
    awake_until_ns: AtomicU64,
    wake: Notify,
}

impl Handover {
    /// A hand-over that spins up to `budget` on either side, for the bus
    /// whose thread runs the current runtime (call it on the bus thread's
    /// runtime, where the master is spawned).
    pub fn new(budget: Duration) -> Handover {
        Handover {
            inner: Arc::new(Inner {
                budget_ns: AtomicU64::new(nanos(budget)),
                bus_runtime: tokio::runtime::Handle::try_current().ok().map(|h| h.id()),
                recent_ns: AtomicU64::new(0),
                origin: Instant::now(),
                awake_until_ns: AtomicU64::new(0),
                wake: Notify::new(),
            }),
        }
    }

    /// No spinning: every hand-over sleeps and is woken.
    pub fn off() -> Handover {
        Handover::new(Duration::ZERO)
    }

    /// Whether a request sent now should poll for its answer: a budget is
    /// set, this bus's recent answers came within it, and the caller is not
    /// on the bus thread (polling there would wait for itself).
    pub fn spins(&self) -> bool {
        let budget = self.budget_ns();
        let on_bus_thread = match (
            self.inner.bus_runtime,
            tokio::runtime::Handle::try_current(),
        ) {
            (Some(bus), Ok(current)) => bus == current.id(),
            _ => false,
        };
        budget > 0 && self.inner.recent_ns.load(Ordering::Relaxed) <= budget && !on_bus_thread
    }

    /// Changes the budget (0: never spin).
    pub fn set_budget(&self, budget: Duration) {
        self.inner.budget_ns.store(nanos(budget), Ordering::Relaxed);
    }

    fn budget_ns(&self) -> u64 {
        self.inner.budget_ns.load(Ordering::Relaxed)
    }

    /// Awaits `reply`; with `spins` ([`Handover::spins`] when the request
    /// was sent) it polls for up to the budget first, then sleeps.
    pub async fn reply<T>(&self, mut reply: oneshot::Receiver<T>, spins: bool) -> Option<T> {
        let budget = Duration::from_nanos(self.budget_ns());
        if budget.is_zero() {
            // Nobody spins: the answer times, which only decide spinning,
            // are not needed (two clock reads per request spared).
            return reply.await.ok();
        }
        let started = Instant::now();
        let r = match spins.then(|| poll_for(&mut reply, started, budget)) {
            Some(Polled::Answer(v)) => Some(v),
            Some(Polled::SenderGone) => None,
            Some(Polled::NotYet) | None => reply.await.ok(),
        };
        self.learn(started.elapsed());
        r
    }

    /// Folds one answer time into the moving average (1/8 weight): one slow
    /// answer does not stop the spinning, a run of them does.
    fn learn(&self, took: Duration) {
        let ns = nanos(took);
        let old = self.inner.recent_ns.load(Ordering::Relaxed);
        let new = if old == 0 { ns } else { old - old / 8 + ns / 8 };
        self.inner.recent_ns.store(new, Ordering::Relaxed);
    }

    /// On the bus thread, as a polling caller's request arrives: keep the
    /// thread awake for the budget (that caller's next request is likely to
    /// follow its answer closely).
    pub fn spinning_caller_arrived(&self) {
        let budget = self.budget_ns();
        if budget == 0 {
            return;
        }
        let until = self.inner.origin.elapsed() + Duration::from_nanos(budget);
        self.inner
            .awake_until_ns
            .store(nanos(until), Ordering::Relaxed);
        self.inner.wake.notify_one();
    }

    /// The task on the bus thread that keeps it awake (yielding, so every
    /// other task of the thread still runs) until the deadline of the last
    /// request has passed, then sleeps until the next request.
    pub async fn keep_awake(self, cancel: tokio_util::sync::CancellationToken) {
        loop {
            tokio::select! {
                _ = cancel.cancelled() => return,
                _ = self.inner.wake.notified() => {}
            }
            while nanos(self.inner.origin.elapsed())
                < self.inner.awake_until_ns.load(Ordering::Relaxed)
            {
                tokio::task::yield_now().await;
            }
        }
    }
}

/// `d` in ns, saturating (a u64 of ns is 584 years).
fn nanos(d: Duration) -> u64 {
    d.as_nanos().min(u128::from(u64::MAX)) as u64
}

enum Polled<T> {
    Answer(T),
    /// The bus side dropped the request (stopped).
    SenderGone,
    /// No answer within the budget: sleep on it.
    NotYet,
}

/// Polls `reply` until it holds a value or `budget` has passed since
/// `started`.
fn poll_for<T>(reply: &mut oneshot::Receiver<T>, started: Instant, budget: Duration) -> Polled<T> {
    loop {
        match reply.try_recv() {
            Ok(v) => return Polled::Answer(v),
            // A receiver that saw the channel closed must not be awaited.
            Err(oneshot::error::TryRecvError::Closed) => return Polled::SenderGone,
            Err(oneshot::error::TryRecvError::Empty) if started.elapsed() < budget => {
                std::hint::spin_loop()
            }
            Err(oneshot::error::TryRecvError::Empty) => return Polled::NotYet,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn on_runtime<F: std::future::Future>(f: F) -> F::Output {
        tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
            .unwrap()
            .block_on(f)
    }

    #[test]
    fn no_budget_never_spins() {
        let h = Handover::off();
        assert!(!h.spins());
        h.spinning_caller_arrived();
        assert_eq!(h.inner.awake_until_ns.load(Ordering::Relaxed), 0);
    }

    #[test]
    fn callers_on_the_bus_runtime_do_not_spin_others_do() {
        let bus = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        let h = bus.block_on(async { Handover::new(Duration::from_micros(100)) });
        assert!(!bus.block_on(async { h.spins() }));
        assert!(on_runtime(async { h.spins() }));
        // Outside any runtime (a blocking embedding thread) too.
        assert!(h.spins());
    }

    #[test]
    fn slow_answers_stop_the_spinning_and_fast_ones_bring_it_back() {
        let h = Handover::new(Duration::from_micros(100));
        assert!(h.spins());
        for _ in 0..40 {
            h.learn(Duration::from_millis(1));
        }
        assert!(!h.spins(), "answers of 1 ms are not polled for");
        // One fast answer is not enough, a run of them is.
        h.learn(Duration::from_micros(2));
        assert!(!h.spins());
        for _ in 0..40 {
            h.learn(Duration::from_micros(2));
        }
        assert!(h.spins());
    }

    #[test]
    fn the_answer_arrives_whether_it_comes_while_polling_or_after() {
        let h = Handover::new(Duration::from_micros(200));
        on_runtime(async {
            // Ready before the poll.
            let (tx, rx) = oneshot::channel();
            tx.send(1).unwrap();
            assert_eq!(h.reply(rx, true).await, Some(1));
            // Long after the budget: the await takes over.
            let (tx, rx) = oneshot::channel();
            let sender = std::thread::spawn(move || {
                std::thread::sleep(Duration::from_millis(20));
                tx.send(2).unwrap();
            });
            assert_eq!(h.reply(rx, true).await, Some(2));
            sender.join().unwrap();
            // A dropped sender is an error, polled or not.
            let (tx, rx) = oneshot::channel::<u8>();
            drop(tx);
            assert_eq!(h.reply(rx, true).await, None);
            let (tx, rx) = oneshot::channel::<u8>();
            drop(tx);
            assert_eq!(h.reply(rx, false).await, None);
        });
    }

    #[test]
    fn the_keeper_lets_the_threads_other_tasks_run_and_ends_on_cancel() {
        on_runtime(async {
            let h = Handover::new(Duration::from_millis(30));
            let cancel = tokio_util::sync::CancellationToken::new();
            let task = tokio::spawn(h.clone().keep_awake(cancel.clone()));
            // The keeper yields while awake: other tasks of the thread run.
            h.spinning_caller_arrived();
            let started = Instant::now();
            let mut turns = 0u32;
            while started.elapsed() < Duration::from_millis(10) {
                tokio::task::yield_now().await;
                turns += 1;
            }
            assert!(turns > 1);
            cancel.cancel();
            task.await.unwrap();
        });
    }
}
