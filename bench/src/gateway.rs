//! The gateway under test: its configuration, the runtimes it and the
//! benchmark's own tasks run on, starting and stopping it, and the handles
//! a benchmark takes from it.
//!
//! The gateway always runs in the benchmark's process (the `memory`
//! benchmark's child process aside), on a free loopback port, so that a
//! benchmark needs nothing but itself.

use anyhow::{Context, Result, anyhow};
use cangate_can::VirtualBus;
use cangate_server::{Config, RunningServer};
use std::time::Duration;

/// A `[security.limits]` table that switches the per-client limits off, to
/// append to a benchmark's configuration: a benchmark measures the gateway,
/// not its defences, and all its clients share one address.
pub const NO_CLIENT_LIMITS: &str = "
[security.limits]
max_concurrent_requests_per_client = 0
requests_per_second_per_client = 0
max_streams_per_client = 0
raw_frames_per_second_per_client = 0
sdo_requests_per_client_and_node = 0
";

/// The same as [`NO_CLIENT_LIMITS`] on a parsed configuration (the demo's,
/// which has its own limits table).
pub fn lift_client_limits(config: &mut Config) {
    config.security.limits.max_concurrent_requests_per_client = 0;
    config.security.limits.requests_per_second_per_client = 0;
    config.security.limits.max_streams_per_client = 0;
    config.security.limits.raw_frames_per_second_per_client = 0;
    config.security.limits.sdo_requests_per_client_and_node = 0;
}

/// Parses a configuration written by a benchmark.
pub fn config(text: &str) -> Result<Config> {
    Config::from_toml(text).map_err(|e| anyhow!("benchmark configuration: {e}"))
}

/// Worker threads of the gateway's runtime, as the server binary has
/// them (tokio's default: one per CPU). The benchmarks that run the
/// gateway in their own process give its runtime this many.
pub fn gateway_workers() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// A multi-threaded runtime builder with `workers` threads named `name`
/// and every driver enabled, for what the caller still wants to set
/// (thread start hooks). The names matter: CPU time is read per thread
/// name ([`crate::host::thread_cpu`]).
pub fn runtime_builder(name: &str, workers: usize) -> tokio::runtime::Builder {
    let mut b = tokio::runtime::Builder::new_multi_thread();
    b.worker_threads(workers).thread_name(name).enable_all();
    b
}

/// A multi-threaded runtime with `workers` threads named `name`: the
/// gateway's, the simulated devices' or the benchmark client's, each on its
/// own so that their CPU time and their wake-ups can be told apart.
pub fn runtime(name: &str, workers: usize) -> Result<tokio::runtime::Runtime> {
    runtime_builder(name, workers)
        .build()
        .with_context(|| format!("building the {name} runtime"))
}

/// Starts the gateway on the current runtime.
pub async fn start(config: &Config) -> Result<RunningServer> {
    cangate_server::start(config)
        .await
        .map_err(|e| anyhow!("starting the gateway: {e}"))
}

/// Starts the gateway on `rt`, from outside any runtime; the gateway's
/// tasks then run on `rt`'s threads.
pub fn start_on(rt: &tokio::runtime::Runtime, config: &Config) -> Result<RunningServer> {
    rt.block_on(start(config))
}

/// Starts the gateway with one virtual bus `can0` (FD, no bit timing, so
/// that the figures are the gateway's and not a bus rate's) and no client
/// limits: the bench of the `stream` and `latency` figures.
pub async fn start_can0() -> Result<RunningServer> {
    let text = format!(
        r#"
listen = "127.0.0.1:0"

[log]
level = "warn"

[[bus]]
name = "can0"
backend = "virtual"
fd = true
{NO_CLIENT_LIMITS}"#
    );
    start(&config(&text)?).await
}

/// The URL a client connects to.
pub fn url(server: &RunningServer) -> String {
    format!("http://{}", server.addr)
}

/// The gateway's virtual bus `name`, to attach simulated devices or
/// watching ports to.
pub fn virtual_bus(server: &RunningServer, name: &str) -> Result<VirtualBus> {
    server
        .gateway()
        .network()
        .get(name)
        .with_context(|| format!("the gateway has no virtual bus {name}"))
}

/// Shuts the gateway down and waits (5 s at most) for it to finish, so
/// that the next benchmark starts on a quiet machine.
pub async fn stop(server: RunningServer) {
    server.shutdown();
    let _ = server.wait(Duration::from_secs(5)).await;
}

/// The gateway with `can0` ([`start_can0`]) on a runtime of its own, with
/// the server binary's worker count ([`gateway_workers`]), so
/// that the benchmark's clients, on the caller's runtime, reach it across
/// threads as a client process would.
pub struct OwnRuntimeGateway {
    runtime: tokio::runtime::Runtime,
    /// The gateway.
    pub server: RunningServer,
}

impl OwnRuntimeGateway {
    /// Starts it (from a task on another runtime).
    pub async fn start_can0() -> Result<OwnRuntimeGateway> {
        let runtime = runtime("gateway", gateway_workers())?;
        let server = runtime.spawn(start_can0()).await??;
        Ok(OwnRuntimeGateway { runtime, server })
    }

    /// Stops the gateway, then its runtime.
    pub async fn stop(self) {
        let _ = self.runtime.spawn(stop(self.server)).await;
        // Dropping a runtime inside another one's task would block it.
        self.runtime.shutdown_background();
    }
}
