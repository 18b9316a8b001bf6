//! cangate-server: owns the CAN buses and serves them over gRPC.
//!
//! Three layers; every arrow points down (`server/tests/import_graph.rs`
//! fails on a module that names one above it, on an edge that names
//! another edge, or on a circle):
//!
//! 1. **API edge**: [`serve`] starts the gRPC server (services, health,
//!    reflection, the [`security`] and [`metrics`] layers, the Prometheus
//!    endpoint) and stops it; [`grpc`] holds the services, the stream forwarding and the one mapping of errors to
//!    gRPC statuses (`grpc::error::ApiError` exists only there);
//!    [`socketcand`] and [`cia309`] are edges beside gRPC (the socketcand
//!    text protocol, CiA 309-3's ASCII gateway protocol, for tools that
//!    speak them), under the same security; [`web`]
//!    serves the embedded dashboard's static files on the gRPC listener;
//!    [`bridge`] publishes the gateway's streams to MQTT brokers.
//!    The edges never name each other; only [`serve`] names them all.
//! 2. **Runtime**: [`gateway`] is the registry that starts and holds the
//!    buses and everything on them: the CANopen masters ([`canopen`]), the
//!    axis layer ([`axes`]) and its runners (the CiA 402 task of each bus,
//!    the cycle thread of each CANsmc master in [`cansmc`], both speaking
//!    [`axis_runner`]), the handwheels ([`handwheel`]) and the simulated
//!    devices ([`simulation`]). Its handles return typed errors
//!    ([`axes::AxisError`], [`cansmc::CansmcError`],
//!    [`handwheel::HandwheelError`], [`not_found::NotFound`]).
//! 3. **Configuration**: [`config`], one file per section, validated before
//!    anything starts; it names nothing else of the server.
//!
//! [`convert`] (every conversion between the runtime's types and the
//! protobuf messages) is shared by the edges that speak protobuf.
//! [`realtime`] (thread priorities) is used by the runtime's threads;
//! [`participants`] (who each client sender on a bus is) is the runtime's
//! register that every edge letting clients send shares; [`cyclic`] runs
//! the cyclic transmission jobs of those clients (socketcand's BCM mode,
//! Attach's `AttachCyclic`).

#![deny(missing_docs, unreachable_pub)]
// A dependency nothing uses fails CI (clippy -D warnings). Test builds are
// left out: their dev-dependencies serve the integration tests.
#![cfg_attr(not(test), warn(unused_crate_dependencies))]

pub mod axes;
pub mod axis_runner;
pub mod bridge;
pub mod canopen;
pub mod cansmc;
pub mod cia309;
pub mod config;
pub mod convert;
pub mod cyclic;
pub mod gateway;
pub mod grpc;
pub mod handwheel;
pub mod metrics;
pub mod not_found;
pub mod participants;
pub mod realtime;
pub mod security;
pub mod serve;
pub mod simulation;
pub mod socketcand;
pub mod traffic_log;
pub mod web;

pub use config::Config;
pub use gateway::Gateway;
pub use serve::{RunningServer, StartError, start};

// Dependencies of the `cangate-server` binary only (its command line and
// log output).
use {clap as _, tracing_subscriber as _};
