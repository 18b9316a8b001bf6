//! Thin typed client for the cangate gateway.
//!
//! ```no_run
//! # async fn demo() -> Result<(), cangate_client::Error> {
//! let mut client = cangate_client::connect("http://127.0.0.1:50051").await?;
//! for bus in client.list_buses().await? {
//!     println!("{} {:?}", bus.name, bus.status);
//! }
//! let frame: cangate_client::can::Frame = "123#DEADBEEF".parse().unwrap();
//! client.send(&"can0", &[frame]).await?;
//! # Ok(()) }
//! ```
//!
//! The generated stubs and messages are re-exported as [`proto`], so every
//! RPC is reachable even where no helper exists yet.

pub use cangate_can as can;
pub use cangate_proto as proto;
pub use cangate_proto::v1 as pb;

use cangate_can::Frame;
use pb::bus_client::BusClient;
use tonic::transport::{Channel, Endpoint};

/// Default server address of the CLI and examples.
pub const DEFAULT_SERVER: &str = "http://127.0.0.1:50051";

/// Client errors.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The server could not be reached.
    #[error("cannot connect to {url}: {source}")]
    Connect {
        /// Server URL.
        url: String,
        /// Transport error.
        source: tonic::transport::Error,
    },
    /// The server refused or failed the call.
    #[error("{} ({:?})", .0.message(), .0.code())]
    Status(tonic::Status),
    /// The URL is malformed.
    #[error("bad server URL {0:?}")]
    BadUrl(String),
}

impl From<tonic::Status> for Error {
    fn from(s: tonic::Status) -> Self {
        Error::Status(s)
    }
}

impl Error {
    /// The gRPC status code, if the server answered.
    pub fn code(&self) -> Option<tonic::Code> {
        match self {
            Error::Status(s) => Some(s.code()),
            _ => None,
        }
    }
}

/// A connection to one gateway. Cheap to clone (one HTTP/2 connection).
#[derive(Clone, Debug)]
pub struct Client {
    channel: Channel,
}

/// Connects to a gateway (`http://host:port`).
pub async fn connect(url: &str) -> Result<Client, Error> {
    let endpoint = Endpoint::from_shared(url.to_string())
        .map_err(|_| Error::BadUrl(url.to_string()))?
        .tcp_nodelay(true)
        .connect_timeout(std::time::Duration::from_secs(5));
    let channel = endpoint.connect().await.map_err(|source| Error::Connect {
        url: url.to_string(),
        source,
    })?;
    Ok(Client { channel })
}

/// Converts a frame to its protobuf form (for SendFrames).
pub fn frame_to_pb(f: &Frame) -> pb::Frame {
    cangate_proto::frames::frame_to_pb(f, pb::Direction::Unspecified)
}

/// Converts a received protobuf frame back to a frame (with its timestamp).
pub fn frame_from_pb(f: &pb::Frame) -> Option<Frame> {
    cangate_proto::frames::frame_from_pb(f).ok()
}

pub use cangate_proto::frames::filter_to_pb;

impl Client {
    /// The underlying channel, for the generated clients of other services.
    pub fn channel(&self) -> Channel {
        self.channel.clone()
    }

    /// The generated Bus client.
    pub fn bus_client(&self) -> BusClient<Channel> {
        BusClient::new(self.channel.clone()).max_decoding_message_size(64 * 1024 * 1024)
    }

    /// The generated Canopen client.
    pub fn canopen_client(&self) -> pb::canopen_client::CanopenClient<Channel> {
        pb::canopen_client::CanopenClient::new(self.channel.clone())
            .max_decoding_message_size(64 * 1024 * 1024)
            .max_encoding_message_size(64 * 1024 * 1024)
    }

    /// The generated Axes client.
    pub fn axes_client(&self) -> pb::axes_client::AxesClient<Channel> {
        pb::axes_client::AxesClient::new(self.channel.clone())
            .max_decoding_message_size(64 * 1024 * 1024)
            .max_encoding_message_size(64 * 1024 * 1024)
    }

    /// The generated Handwheels client.
    pub fn handwheels_client(&self) -> pb::handwheels_client::HandwheelsClient<Channel> {
        pb::handwheels_client::HandwheelsClient::new(self.channel.clone())
            .max_decoding_message_size(64 * 1024 * 1024)
            .max_encoding_message_size(64 * 1024 * 1024)
    }

    /// The generated Cansmc client (CANsmc masters).
    pub fn cansmc_client(&self) -> pb::cansmc_client::CansmcClient<Channel> {
        pb::cansmc_client::CansmcClient::new(self.channel.clone())
            .max_decoding_message_size(64 * 1024 * 1024)
            .max_encoding_message_size(64 * 1024 * 1024)
    }

    /// Every CANsmc master, briefly.
    pub async fn list_cansmc_masters(&mut self) -> Result<Vec<pb::CansmcMasterInfo>, Error> {
        Ok(self
            .cansmc_client()
            .list_masters(pb::ListMastersRequest {})
            .await?
            .into_inner()
            .masters)
    }

    /// The full state of a CANsmc master ("" = the gateway's only one).
    pub async fn cansmc_status(&mut self, master: &str) -> Result<pb::CansmcStatus, Error> {
        Ok(self
            .cansmc_client()
            .get_status(pb::GetCansmcStatusRequest {
                master: master.to_string(),
            })
            .await?
            .into_inner())
    }

    /// The generated Simulator client (simulated devices of the gateway).
    pub fn simulator_client(&self) -> pb::simulator_client::SimulatorClient<Channel> {
        pb::simulator_client::SimulatorClient::new(self.channel.clone())
            .max_decoding_message_size(64 * 1024 * 1024)
            .max_encoding_message_size(64 * 1024 * 1024)
    }

    /// Every configured handwheel with its statistics.
    pub async fn list_handwheels(&mut self) -> Result<Vec<pb::Handwheel>, Error> {
        Ok(self
            .handwheels_client()
            .list_handwheels(pb::ListHandwheelsRequest {})
            .await?
            .into_inner()
            .handwheels)
    }

    /// One handwheel.
    pub async fn get_handwheel(&mut self, handwheel: &str) -> Result<pb::Handwheel, Error> {
        Ok(self
            .handwheels_client()
            .get_handwheel(pb::GetHandwheelRequest {
                handwheel: handwheel.to_string(),
            })
            .await?
            .into_inner())
    }

    /// Every configured axis with its live state.
    pub async fn list_axes(&mut self) -> Result<Vec<pb::Axis>, Error> {
        Ok(self
            .axes_client()
            .list_axes(pb::ListAxesRequest {})
            .await?
            .into_inner()
            .axes)
    }

    /// One axis.
    pub async fn get_axis(&mut self, axis: &str) -> Result<pb::Axis, Error> {
        Ok(self
            .axes_client()
            .get_axis(pb::GetAxisRequest {
                axis: axis.to_string(),
            })
            .await?
            .into_inner())
    }

    /// Reads an object over SDO.
    pub async fn read_sdo(
        &mut self,
        req: pb::ReadSdoRequest,
    ) -> Result<pb::ReadSdoResponse, Error> {
        Ok(self.canopen_client().read_sdo(req).await?.into_inner())
    }

    /// Writes an object over SDO.
    pub async fn write_sdo(
        &mut self,
        req: pb::WriteSdoRequest,
    ) -> Result<pb::WriteSdoResponse, Error> {
        Ok(self.canopen_client().write_sdo(req).await?.into_inner())
    }

    /// Every bus with live statistics.
    pub async fn list_buses(&mut self) -> Result<Vec<pb::BusInfo>, Error> {
        Ok(self
            .bus_client()
            .list_buses(pb::ListBusesRequest {})
            .await?
            .into_inner()
            .buses)
    }

    /// One bus.
    pub async fn get_bus(&mut self, bus: &str) -> Result<pb::BusInfo, Error> {
        Ok(self
            .bus_client()
            .get_bus(pb::GetBusRequest {
                bus: bus.to_string(),
            })
            .await?
            .into_inner())
    }

    /// Sends frames in order on a bus.
    pub async fn send(&mut self, bus: &str, frames: &[Frame]) -> Result<u32, Error> {
        self.send_pb(bus, frames.iter().map(frame_to_pb).collect())
            .await
    }

    /// Sends protobuf frames as given (no local validation).
    pub async fn send_pb(&mut self, bus: &str, frames: Vec<pb::Frame>) -> Result<u32, Error> {
        Ok(self
            .bus_client()
            .send_frames(pb::SendFramesRequest {
                bus: bus.to_string(),
                frames,
            })
            .await?
            .into_inner()
            .sent)
    }

    /// Opens a frame stream.
    pub async fn stream_frames(
        &mut self,
        request: pb::StreamFramesRequest,
    ) -> Result<tonic::Streaming<pb::StreamFramesResponse>, Error> {
        Ok(self.bus_client().stream_frames(request).await?.into_inner())
    }
}
