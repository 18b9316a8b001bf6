//! `cangate_bench`: the measuring code the benchmark binaries share.
//!
//! Every benchmark here (the `cangate-bench` binary and `sdo_bench`,
//! `axis_bench`, `wheel_bench`, `cansmc_bench`, `soak_bench`) starts the real
//! gateway in its own process, drives it through the real client or its
//! runtime handles, and prints human-readable figures and one JSON line.
//! `peer_bench` is the exception: it runs the release `cangate-server` as a
//! child process on SocketCAN, beside the other gateways it compares with. What
//! they have in common lives here, so that a percentile, a "no client
//! limits" configuration or a CPU reading means the same thing in every
//! figure:
//!
//! - [`stats`]: HDR histograms of latencies and their percentiles;
//! - [`report`]: headline figures against their targets, the summary table,
//!   the banner line;
//! - [`gateway`]: the gateway's configuration, its runtimes, starting and
//!   stopping it, the handles a benchmark takes from it;
//! - [`axes`]: waiting for axes and holding a control lease to command them;
//! - [`host`]: this process's threads' CPU time and memory, and the exit
//!   status of a benchmark;
//! - [`child`]: the server binary as a child process.

#![deny(missing_docs, unreachable_pub)]
// A dependency nothing uses fails CI (clippy -D warnings). Test builds are
// left out: their dev-dependencies serve the integration tests.
#![cfg_attr(not(test), warn(unused_crate_dependencies))]

pub mod axes;
pub mod child;
pub mod gateway;
pub mod host;
pub mod report;
pub mod sdo_wire;
pub mod stats;
pub mod suite;

// Dependencies of the bench binaries only.
use {
    async_nats as _, cangate_canopen as _, cangate_cansmc as _, clap as _, futures as _,
    prost as _, rumqttc as _, socketcan as _, tokio_stream as _, tokio_util as _,
};
