//! Simulated CANopen devices.
//!
//! A device here is a sans-IO state machine, like the protocol core in
//! `cangate_canopen`: it takes received frames and ticks with the current
//! time and returns the frames to send. Nothing in the device logic touches
//! a socket, sleeps or needs an async runtime, so every exchange is tested
//! with exact byte vectors and a virtual clock.
//!
//! - [`canopen_node`]: [`SimNode`], a CiA 301 slave built from an EDS (NMT
//!   slave with heartbeat, SDO server, TPDOs/RPDOs, SYNC, EMCY).
//! - [`store`]: [`SimStore`], the object dictionary values the node serves,
//!   with the access, size and limit checks of a real device.
//! - [`runner`] (feature `runtime`, on by default): runs any [`Device`] on a
//!   [`cangate_can::VirtualPort`].
//!
//! Time convention: every `now` is a [`std::time::Duration`] measured from an
//! arbitrary origin chosen by the runner (monotonic). Tests pass virtual time.
//!
//! Device models (e.g. a CiA 402 drive) are built on top of [`SimNode`]: they
//! own one, forward frames and ticks to it, read what the master wrote
//! ([`SimNode::take_events`], [`SimNode::get`]), update their process values
//! ([`SimNode::set`]) and implement [`Device`] themselves, so the same runner
//! drives them.

#![deny(missing_docs, unreachable_pub)]
// A dependency nothing uses fails CI (clippy -D warnings). Test builds are
// left out: their dev-dependencies serve the integration tests.
#![cfg_attr(not(test), warn(unused_crate_dependencies))]

use std::time::Duration;

use cangate_can::{Filter, Frame};
use cangate_canopen::ObjectAddress;
use cangate_canopen::eds::EdsError;
use cangate_canopen::value::DataType;

pub mod canopen_node;
#[cfg(feature = "runtime")]
pub mod cansmc_runner;
pub mod cansmc_slave;
pub mod drive;
pub mod handwheel;
mod pdo;
pub mod program;
#[cfg(feature = "runtime")]
pub mod runner;
pub mod store;

pub use canopen_node::{SimEvent, SimNode, SimNodeOptions};
#[cfg(feature = "runtime")]
pub use cansmc_runner::{CansmcSlaveHandle, spawn_cansmc_slaves};
pub use cansmc_slave::{
    SimCansmcCounters, SimCansmcFault, SimCansmcMode, SimCansmcReply, SimCansmcServo,
    SimCansmcSlave, SimCansmcSlaveOptions,
};
pub use drive::{SimDrive, SimDriveInputs, SimDriveOptions, TorqueModel};
pub use handwheel::{FrameLoss, Multiplier, SimHandwheel, SimHandwheelOptions};
#[cfg(feature = "runtime")]
pub use runner::{DeviceHandle, spawn_device, spawn_device_on_bus, spawn_node};
pub use store::SimStore;

/// A simulated device as a sans-IO state machine.
///
/// The runner calls [`Device::start`] once, then [`Device::on_frame`] for
/// every frame seen on the bus and [`Device::on_tick`] whenever
/// [`Device::next_deadline`] has passed (calling it earlier or more often is
/// harmless). Every returned frame is sent in order.
pub trait Device {
    /// Powers the device on at `now`; returns the frames to send (for a
    /// CANopen node, the boot-up message).
    fn start(&mut self, now: Duration) -> Vec<Frame>;
    /// Handles a frame received at `now`; returns the frames to send.
    fn on_frame(&mut self, frame: &Frame, now: Duration) -> Vec<Frame>;
    /// Runs everything that is due at `now`; returns the frames to send.
    fn on_tick(&mut self, now: Duration) -> Vec<Frame>;
    /// When [`Device::on_tick`] must run next; `None` when nothing is
    /// scheduled. A deadline at or before the last `now` means "as soon as
    /// possible".
    fn next_deadline(&self) -> Option<Duration>;
    /// The frames the device acts on, as acceptance filters for its port
    /// (see [`cangate_can::VirtualPort::set_filters`]); `None`: every
    /// frame. The runner asks again after every batch, before sending the
    /// batch's answers, so a frame that the answer invites (an RPDO on a
    /// COB-ID just configured) is already let through.
    fn receive_filters(&self) -> Option<Vec<Filter>> {
        None
    }
    /// A number that changes whenever [`Device::receive_filters`] may have
    /// changed: the runner asks for the filters only then (they are built
    /// from the device's state, and the runner turns at every frame batch).
    fn filter_generation(&self) -> u64 {
        0
    }
}

impl<D: Device + ?Sized> Device for Box<D> {
    fn start(&mut self, now: Duration) -> Vec<Frame> {
        (**self).start(now)
    }
    fn on_frame(&mut self, frame: &Frame, now: Duration) -> Vec<Frame> {
        (**self).on_frame(frame, now)
    }
    fn on_tick(&mut self, now: Duration) -> Vec<Frame> {
        (**self).on_tick(now)
    }
    fn next_deadline(&self) -> Option<Duration> {
        (**self).next_deadline()
    }
    fn receive_filters(&self) -> Option<Vec<Filter>> {
        (**self).receive_filters()
    }
    fn filter_generation(&self) -> u64 {
        (**self).filter_generation()
    }
}

/// A device that can be powered on afresh: the state it has after its power
/// was cut (the power-on defaults of its object dictionary, its options
/// kept), for [`runner::DeviceHandle::power_cycle`].
pub trait PowerOn {
    /// The device as it is when power returns, not yet started.
    fn powered_on(&self) -> Self;
}

impl PowerOn for SimNode {
    fn powered_on(&self) -> Self {
        let mut node = SimNode::from_od(self.od().clone(), self.node_id(), self.options().clone());
        node.keep_program_of(self);
        node
    }
}

/// A drive loses its position with its power, as one with an incremental
/// encoder does: it must be homed again.
impl PowerOn for SimDrive {
    fn powered_on(&self) -> Self {
        let mut drive = SimDrive::from_od(
            self.node().od().clone(),
            self.node().node_id(),
            self.options().clone(),
        );
        drive.node_mut().keep_program_of(self.node());
        drive
    }
}

/// Why a simulated device could not be built or an object not be accessed
/// locally.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// The EDS text is invalid.
    #[error("invalid EDS: {0}")]
    Eds(#[source] Box<EdsError>),
    /// No variable at this address.
    #[error("object {0} does not exist in the object dictionary")]
    NoSuchObject(ObjectAddress),
    /// A value of another type than the variable's.
    #[error("object {addr} holds {expected} values, got a {got} value")]
    TypeMismatch {
        /// The object.
        addr: ObjectAddress,
        /// Its type.
        expected: DataType,
        /// The type of the value given.
        got: DataType,
    },
}

impl From<EdsError> for SimError {
    fn from(e: EdsError) -> Self {
        SimError::Eds(Box::new(e))
    }
}
