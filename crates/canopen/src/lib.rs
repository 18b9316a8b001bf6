//! Sans-IO CANopen (CiA 301) protocol core.
//!
//! Every service here is a state machine over frames and time: it takes a
//! received [`cangate_can::Frame`] or a tick with the current time and
//! returns frames to send and events for the application. Nothing here
//! touches a socket, sleeps or needs an async runtime, so every exchange is
//! tested with exact byte vectors and a virtual clock.
//!
//! Time convention: every `now` is a [`std::time::Duration`] measured from an
//! arbitrary origin chosen by the runner (monotonic). Tests pass virtual time.

#![deny(missing_docs, unreachable_pub)]
// A dependency nothing uses fails CI (clippy -D warnings). Test builds are
// left out: their dev-dependencies serve the integration tests.
#![cfg_attr(not(test), warn(unused_crate_dependencies))]

pub mod cia402;
pub mod dcf;
pub mod decode;
pub mod eds;
pub mod emcy;
pub mod handwheel;
pub mod heartbeat;
pub mod ids;
pub mod lss;
pub mod lss_slave;
pub mod master;
pub mod nmt;
pub mod node_guarding;
pub mod od;
pub mod pdo;
pub mod program_download;
pub mod sdo;
pub mod sync;
pub mod time_of_day;
pub mod value;

pub use ids::{BadNodeId, CobFunction, NodeId, ObjectAddress};
