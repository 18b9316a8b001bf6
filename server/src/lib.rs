//! cangate-server: owns the CAN buses and serves them over gRPC.
//!
//! - [`config`]: configuration file, environment overrides, embedded demo.
//! - [`serve`]: the API edge: the gRPC server, its layers, start-up and
//!   shutdown of the running server.
//! - [`gateway`]: the runtime's registry: buses, masters, axes, handwheels.
//! - [`grpc`]: the gRPC services and protobuf conversions.
//! - [`canopen`]: the CANopen master runtime of each bus.
//! - [`cansmc`]: the CANsmc masters (dual-bus motion control), their cycle
//!   threads and axes.
//! - [`axes`]: the axis layer (CiA 402 drives), control leases.
//! - [`handwheel`]: CNC handwheels: feed decoding, mode, axis binding.
//! - [`metrics`]: the Prometheus endpoint.
//! - [`security`]: roles, tokens, TLS/mTLS, limits, audit log.
//! - [`simulation`]: simulated devices and virtual-bus faults at run time.
//! - [`error`]: the one mapping from domain errors to gRPC statuses.

pub mod axes;
pub mod axis_runner;
pub mod canopen;
pub mod cansmc;
pub mod config;
pub mod error;
pub mod gateway;
pub mod grpc;
pub mod handwheel;
pub mod metrics;
pub mod not_found;
pub mod realtime;
pub mod security;
pub mod serve;
pub mod simulation;

pub use config::Config;
pub use gateway::Gateway;
pub use serve::{RunningServer, StartError, start};
