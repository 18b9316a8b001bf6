//! CAN frame model and bus backends.
//!
//! - [`budget`]: traffic classes and the pacing of client and bulk frames.
//! - [`frame`]: classic and FD frames, identifiers, `cansend` text syntax.
//! - [`filter`]: id/mask receive filters (`candump` syntax).
//! - [`timing`]: bit-exact frame durations, arbitration, bus load (pure).
//! - [`virtual_bus`]: the in-process bus with bit timing and fault injection.
//! - [`socketcan_bus`]: Linux SocketCAN with reconnection.
//! - [`send_error`]: why frames were not sent (shared by backends and bus).
//! - [`bus`]: one owner task per bus and the handle everyone else uses.
//! - [`precise_wait`]: waiting for an instant with little CPU.
//! - [`arrival`]: the time a core is given for a frame that waited.

#![deny(missing_docs, unreachable_pub)]
// A dependency nothing uses fails CI (clippy -D warnings). Test builds are
// left out: their dev-dependencies serve the integration tests.
#![cfg_attr(not(test), warn(unused_crate_dependencies))]

pub mod arrival;
pub mod budget;
#[cfg(feature = "runtime")]
pub mod bus;
pub mod filter;
pub mod frame;
#[cfg(feature = "runtime")]
pub mod precise_wait;
#[cfg(feature = "runtime")]
pub mod send_error;
#[cfg(feature = "runtime")]
pub mod socketcan_bus;
pub mod state;
pub mod timing;
#[cfg(feature = "runtime")]
pub mod virtual_bus;

pub use arrival::ArrivalClock;
pub use budget::{TxClass, TxShares};
#[cfg(feature = "runtime")]
pub use bus::{
    AttachOptions, Backend, BackendKind, BusHandle, BusInfo, BusItem, BusStats, Direction,
    PendingSend, Subscription, SubscriptionKey,
};
pub use filter::{Filter, FrameSelector};
pub use frame::{CanId, ClientId, Frame, FrameError, FrameKind, ParseFrameError, Timestamp};
#[cfg(feature = "runtime")]
pub use send_error::{SendError, SendFailure};
pub use state::{BusState, BusStatus};
pub use timing::{BitTiming, Stuffing};
#[cfg(feature = "runtime")]
pub use virtual_bus::{
    PortEvent, VirtualBus, VirtualBusConfig, VirtualNetwork, VirtualPort, VirtualSender,
};
