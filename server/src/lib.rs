//! cangate-server: owns the CAN buses and serves them over gRPC.
//!
//! - [`config`]: configuration file, environment overrides, embedded demo.
//! - [`gateway`]: start-up, the running server and shutdown.
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
pub mod canopen;
pub mod cansmc;
pub mod config;
pub mod error;
pub mod gateway;
pub mod grpc;
pub mod handwheel;
pub mod metrics;
pub mod realtime;
pub mod security;
pub mod simulation;

pub use config::Config;
pub use gateway::{Gateway, RunningServer, StartError, start};
