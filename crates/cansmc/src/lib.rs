//! Sans-IO CANsmc protocol core (CAN for Synchronous Motion Control).
//!
//! CANsmc runs one master and up to 61 slaves over two CAN channels at the
//! same bit rate: channel 0 carries the master's telegrams (MST, MCT, MDT),
//! channel 1 the slaves' answers (DCT, DT). This crate implements the wire
//! specification `shared/specs/cansmc.md`:
//!
//! - [`telegram`]: the typed telegrams and their exact encoding to and from
//!   [`cangate_can::Frame`], rejecting every frame the spec does not allow.
//! - [`feasibility`]: the bus-time arithmetic that tells whether a bit rate,
//!   slave count and cycle time fit together, and the largest slave count
//!   for a cycle time.
//!
//! Nothing here touches a socket, sleeps or needs an async runtime.

#![deny(missing_docs, unreachable_pub)]
// A dependency nothing uses fails CI (clippy -D warnings). Test builds are
// left out: their dev-dependencies serve the integration tests.
#![cfg_attr(not(test), warn(unused_crate_dependencies))]

pub mod feasibility;
pub mod master;
pub mod slave;
pub mod telegram;

pub use feasibility::{
    CycleConfig, FeasibilityError, FeasibilityReport, Infeasibility, frame_bits_worst_case,
    max_slaves,
};
pub use slave::{ParameterError, Sample, SlaveApplication, SlavePhase, SlaveProtocol, SlaveStats};
pub use telegram::{
    BROADCAST, Channel, CodecError, Command, ControlWord, CycleCounter, Feedback, Function,
    ParameterAccess, RejectReason, SmcAddress, StatusWord, Telegram,
};
