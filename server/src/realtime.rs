//! Opt-in real-time scheduling (Linux `SCHED_FIFO`) for the gateway's
//! latency-critical threads: the bus thread `gateway-bus` and the threads
//! of the gRPC runtime (top-level `rt_priority`), and a CANsmc master's
//! cycle thread (its own `rt_priority`).
//!
//! Why: a frame crosses two gateway thread wake-ups on its way to a
//! client (the bus thread, then a gRPC worker). Under the default policy
//! a woken thread whose CPU runs a CPU-bound job (a compiler, say) can wait
//! for that job's time slice to end, up to a scheduler tick (4 ms at
//! `HZ=250`) per wake-up; `wheel_bench` traced with `perf sched` showed
//! nearly every feed event slower than 1 ms waiting in exactly that state.
//! A `SCHED_FIFO` thread preempts such jobs at once. It needs root or
//! `CAP_SYS_NICE`; without them the gateway logs a warning and runs as
//! before. The kernel's real-time throttling (by default 95 % of each
//! second) keeps a runaway thread from locking up the host.

use std::sync::atomic::{AtomicBool, Ordering};

/// Puts the calling thread under `SCHED_FIFO` at `priority` (1..=99).
pub fn set_fifo(priority: u8) -> Result<(), String> {
    use thread_priority::{
        RealtimeThreadSchedulePolicy, ThreadPriority, ThreadPriorityValue, ThreadSchedulePolicy,
        set_thread_priority_and_policy, thread_native_id,
    };
    let value = ThreadPriorityValue::try_from(priority)?;
    set_thread_priority_and_policy(
        thread_native_id(),
        ThreadPriority::Crossplatform(value),
        ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
    )
    .map_err(|e| format!("{e:?}"))
}

/// Applies `priority` (0: nothing) to the calling thread, a gateway thread
/// named `what`; logs the outcome, a failure once per process.
pub fn enter(priority: u8, what: &str) {
    static WARNED: AtomicBool = AtomicBool::new(false);
    if priority == 0 {
        return;
    }
    match set_fifo(priority) {
        Ok(()) => tracing::debug!(thread = what, priority, "runs with SCHED_FIFO"),
        Err(e) => {
            if !WARNED.swap(true, Ordering::Relaxed) {
                tracing::warn!(thread = what, priority, error = %e, "rt_priority: could not get real-time priority (needs root or CAP_SYS_NICE); latency depends on the host's load");
            }
        }
    }
}

/// For `tokio::runtime::Builder::on_thread_start` of the gRPC runtime:
/// every thread of that runtime gets `priority` (0: nothing).
pub fn on_grpc_thread_start(priority: u8) -> impl Fn() + Send + Sync + 'static {
    move || enter(priority, "grpc runtime")
}

/// Whether this process may use `SCHED_FIFO` at `priority`: tried on a
/// short-lived thread of its own.
pub fn available(priority: u8) -> Result<(), String> {
    std::thread::spawn(move || set_fifo(priority))
        .join()
        .map_err(|_| "probe thread panicked".to_string())?
}
