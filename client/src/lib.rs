//! Typed client for the cangate gateway.
//!
//! ```no_run
//! use cangate_client::{MoveOptions, NodeId, SdoValue, DataType};
//! use std::time::Duration;
//!
//! # async fn demo() -> Result<(), cangate_client::Error> {
//! // `host:port` or a URL; see `connect_with` for tokens, TLS and timeouts.
//! let client = cangate_client::connect("127.0.0.1:50051").await?;
//!
//! // SDO, typed: a value of the proto's CiA 301 types, addresses as 0x607A:00.
//! let can0 = client.canopen("can0");
//! let drive = NodeId::new(1)?;
//! let name = can0.read(drive, "0x1008".parse()?, DataType::VisibleString).await?;
//! can0.write(drive, "0x1017:00".parse()?, SdoValue::U16(100)).await?;
//! # let _ = name;
//!
//! // Axes: a lease renewed in the background, released when dropped.
//! let lease = client.acquire_control(&["X"], Duration::from_secs(2)).await?;
//! client.enable("X", &lease.options().wait(true)).await?;
//! client
//!     .move_to("X", 12.5, &MoveOptions::default().velocity(20.0).wait(true).lease(&lease))
//!     .await?;
//! lease.release().await?;
//!
//! // Errors are typed: SDO aborts, timeouts, not found, refusals.
//! match can0.read(drive, "0x5555".parse()?, DataType::Unsigned32).await {
//!     Err(cangate_client::Error::SdoAbort { code, name, .. }) => println!("0x{code:08X} {name}"),
//!     other => println!("{other:?}"),
//! }
//! # Ok(()) }
//! ```
//!
//! Methods per service: buses ([`Client::list_buses`], [`Client::send`],
//! [`Client::frames`]), CANopen ([`Client::canopen`] gives a [`Canopen`]
//! handle: nodes, NMT, scan, SDO, node events), axes ([`Client::move_to`],
//! [`Client::jog`], [`Client::stop`], [`Client::stop_axes`],
//! [`Client::watch_axes`], ...), control leases ([`ControlLease`]),
//! handwheels and CANsmc masters. Every error is an [`Error`].
//!
//! The generated stubs and messages are re-exported as [`proto`] and
//! [`pb`], so every RPC is reachable even where no helper exists
//! ([`Client::axes_client`], ...).

#![deny(missing_docs, unreachable_pub)]
// A dependency nothing uses fails CI (clippy -D warnings). Test builds are
// left out: their dev-dependencies serve the integration tests.
#![cfg_attr(not(test), warn(unused_crate_dependencies))]

pub use cangate_can as can;
pub use cangate_proto as proto;
pub use cangate_proto::v1 as pb;

mod axes;
mod bus;
mod canopen;
mod cansmc;
mod connect;
mod error;
#[cfg(feature = "fleet")]
pub mod fleet;
mod handwheel;
mod lease;
mod lss;
mod program;
mod sdo;
mod sdo_session;
pub mod setpoint_trial;
mod setpoints;
mod streams;

pub use axes::{AxisUpdate, CommandOptions, CommandResult, JogOptions, MoveOptions, StopOptions};
pub use bus::{
    AttachEvent, AttachOptions, AttachSender, Attachment, FrameEvent, FrameStreamOptions,
};
pub use canopen::Canopen;
pub use connect::{
    BearerToken, CONNECTION_WINDOW, ConnectOptions, DEFAULT_CONNECT_TIMEOUT, DEFAULT_SERVER,
    STREAM_WINDOW, connect, connect_with, hash_token,
};
pub use error::{
    ERROR_DOMAIN, Error, SDO_ABORT_DETAILS_TYPE_URL, code_meaning, code_name, error_info,
    error_metadata, sdo_abort_details,
};
pub use lease::{ControlLease, LeaseStatus};
pub use lss::{Lss, LssDevice};
pub use pb::{AxisActivity, DriveState, HandwheelMode, NmtCommand, Outcome};
pub use program::ProgramOptions;
pub use sdo::{DataType, NodeId, Object, ObjectAddress, SdoOptions, SdoValue};
pub use sdo_session::SdoSession;
pub use setpoints::{
    SetpointSender, SetpointStream, SetpointStreamOptions, setpoint, torque_setpoint,
    velocity_setpoint,
};
pub use streams::EventStream;

use std::future::Future;
use std::time::Duration;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::Channel;

/// What every generated client of a [`Client`] runs on: the channel with
/// the bearer token added to each call.
pub type Transport = InterceptedService<Channel, BearerToken>;

/// The largest message the generated clients of a [`Client`] send or
/// accept.
const MAX_MESSAGE: usize = 64 * 1024 * 1024;

/// A connection to one gateway. Cheap to clone (one HTTP/2 connection).
#[derive(Clone, Debug)]
pub struct Client {
    channel: Transport,
    request_timeout: Option<Duration>,
}

impl Client {
    /// The underlying channel (with the token interceptor), for the
    /// generated clients of other services.
    pub fn channel(&self) -> Transport {
        self.channel.clone()
    }

    /// The bound of each call ([`ConnectOptions::request_timeout`]).
    pub fn request_timeout(&self) -> Option<Duration> {
        self.request_timeout
    }

    /// The same connection with another bound of each call (`None`: none).
    pub fn with_request_timeout(&self, timeout: Option<Duration>) -> Client {
        Client {
            channel: self.channel.clone(),
            request_timeout: timeout,
        }
    }

    /// The generated Bus client.
    pub fn bus_client(&self) -> pb::bus_client::BusClient<Transport> {
        pb::bus_client::BusClient::new(self.channel.clone()).max_decoding_message_size(MAX_MESSAGE)
    }

    /// The generated Canopen client.
    pub fn canopen_client(&self) -> pb::canopen_client::CanopenClient<Transport> {
        pb::canopen_client::CanopenClient::new(self.channel.clone())
            .max_decoding_message_size(MAX_MESSAGE)
            .max_encoding_message_size(MAX_MESSAGE)
    }

    /// The generated Axes client.
    pub fn axes_client(&self) -> pb::axes_client::AxesClient<Transport> {
        pb::axes_client::AxesClient::new(self.channel.clone())
            .max_decoding_message_size(MAX_MESSAGE)
            .max_encoding_message_size(MAX_MESSAGE)
    }

    /// The generated Handwheels client.
    pub fn handwheels_client(&self) -> pb::handwheels_client::HandwheelsClient<Transport> {
        pb::handwheels_client::HandwheelsClient::new(self.channel.clone())
            .max_decoding_message_size(MAX_MESSAGE)
            .max_encoding_message_size(MAX_MESSAGE)
    }

    /// The generated Cansmc client (CANsmc masters).
    pub fn cansmc_client(&self) -> pb::cansmc_client::CansmcClient<Transport> {
        pb::cansmc_client::CansmcClient::new(self.channel.clone())
            .max_decoding_message_size(MAX_MESSAGE)
            .max_encoding_message_size(MAX_MESSAGE)
    }

    /// The generated Simulator client (simulated devices of the gateway).
    pub fn simulator_client(&self) -> pb::simulator_client::SimulatorClient<Transport> {
        pb::simulator_client::SimulatorClient::new(self.channel.clone())
            .max_decoding_message_size(MAX_MESSAGE)
            .max_encoding_message_size(MAX_MESSAGE)
    }

    /// The generated Session client.
    pub fn session_client(&self) -> pb::session_client::SessionClient<Transport> {
        pb::session_client::SessionClient::new(self.channel.clone())
    }

    /// Who this client is to the gateway: its token's (or certificate's)
    /// name and role, or `anonymous` when the gateway has authentication
    /// off.
    pub async fn caller(&self) -> Result<pb::Caller, Error> {
        self.call(
            "GetCaller",
            None,
            self.session_client().get_caller(pb::GetCallerRequest {}),
        )
        .await
    }

    /// Runs one call of a generated client (unary, or the opening of a
    /// stream) within the request timeout plus `extra` (a wait the gateway
    /// was asked to do), its error typed: for the RPCs without a helper.
    /// `what` names the call in a timeout's message.
    ///
    /// ```no_run
    /// # async fn demo(client: cangate_client::Client) -> Result<(), cangate_client::Error> {
    /// use cangate_client::pb;
    /// let faults = client
    ///     .call("GetBusFaults", None, client.simulator_client().get_bus_faults(
    ///         pb::GetBusFaultsRequest { bus: "can0".into() },
    ///     ))
    ///     .await?;
    /// # let _ = faults; Ok(()) }
    /// ```
    pub async fn call<T>(
        &self,
        what: &str,
        extra: Option<Duration>,
        call: impl Future<Output = Result<tonic::Response<T>, tonic::Status>>,
    ) -> Result<T, Error> {
        let result = match self.request_timeout {
            Some(limit) => {
                let limit = limit + extra.unwrap_or_default();
                tokio::time::timeout(limit, call)
                    .await
                    .map_err(|_| Error::client_timeout(what, limit))?
            }
            None => call.await,
        };
        result.map(tonic::Response::into_inner).map_err(Error::from)
    }
}

/// Converts a frame to its protobuf form (for SendFrames).
pub fn frame_to_pb(f: &can::Frame) -> pb::Frame {
    cangate_proto::frames::frame_to_pb(f, pb::Direction::Unspecified)
}

/// Converts a received protobuf frame back to a frame (with its timestamp).
pub fn frame_from_pb(f: &pb::Frame) -> Option<can::Frame> {
    cangate_proto::frames::frame_from_pb(f).ok()
}

pub use cangate_proto::frames::filter_to_pb;

// Dependencies of the `cangate` binary only (feature "cli").
#[cfg(feature = "cli")]
use {clap as _, clap_complete as _, fastrand as _, serde as _, serde_json as _};
