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
use std::path::PathBuf;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Certificate, Channel, ClientTlsConfig, Endpoint, Identity};

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
    /// The connection options cannot be used (unreadable certificate
    /// files, a token that is not valid metadata, a key without a cert).
    #[error("{0}")]
    Options(String),
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

    /// The status as received, if the server answered.
    pub fn status(&self) -> Option<&tonic::Status> {
        match self {
            Error::Status(s) => Some(s),
            _ => None,
        }
    }
}

/// Adds `authorization: Bearer <token>` to every call (when a token is
/// set). Its `Debug` never shows the token.
#[derive(Clone, Default)]
pub struct BearerToken(Option<tonic::metadata::AsciiMetadataValue>);

impl std::fmt::Debug for BearerToken {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_some() {
            "BearerToken(<redacted>)"
        } else {
            "BearerToken(none)"
        })
    }
}

impl tonic::service::Interceptor for BearerToken {
    fn call(&mut self, mut req: tonic::Request<()>) -> Result<tonic::Request<()>, tonic::Status> {
        if let Some(v) = &self.0 {
            req.metadata_mut().insert("authorization", v.clone());
        }
        Ok(req)
    }
}

/// What every generated client of a [`Client`] runs on: the channel with
/// the bearer token added to each call.
pub type Transport = InterceptedService<Channel, BearerToken>;

/// How to reach a gateway beyond its URL: credentials and TLS.
#[derive(Clone, Default)]
pub struct ConnectOptions {
    /// Bearer token (`--token`, `CANGATE_TOKEN`).
    pub token: Option<String>,
    /// PEM CA certificate to trust; set: TLS (an `http://` URL becomes
    /// `https://`).
    pub ca: Option<PathBuf>,
    /// PEM client certificate for mTLS (with `key`).
    pub cert: Option<PathBuf>,
    /// PEM private key of `cert`.
    pub key: Option<PathBuf>,
    /// The name the server certificate must carry, when it differs from
    /// the URL's host.
    pub tls_domain: Option<String>,
}

impl std::fmt::Debug for ConnectOptions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ConnectOptions")
            .field("token", &self.token.as_ref().map(|_| "<redacted>"))
            .field("ca", &self.ca)
            .field("cert", &self.cert)
            .field("key", &self.key)
            .field("tls_domain", &self.tls_domain)
            .finish()
    }
}

/// A connection to one gateway. Cheap to clone (one HTTP/2 connection).
#[derive(Clone, Debug)]
pub struct Client {
    channel: Transport,
}

/// Connects to a gateway (`http://host:port`) without credentials.
pub async fn connect(url: &str) -> Result<Client, Error> {
    connect_with(url, &ConnectOptions::default()).await
}

/// The hex SHA-256 of a token, as the server's `[[security.tokens]]`
/// `sha256` wants it (same as `printf %s TOKEN | sha256sum`).
pub fn hash_token(token: &str) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(token.as_bytes())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// HTTP/2 flow-control window of each call (stream) of a connection.
///
/// Why this size: the HTTP/2 layer (h2) guards against peers that send
/// many small DATA frames by limiting how much framing overhead may wait
/// unread, to half the connection window (256 bytes per frame less its
/// payload). A caller that stops reading a frame stream (`cangate dump |
/// less`) lets the gateway fill the stream's window, in the worst case
/// with one small message per CAN frame; above the limit h2 closes the
/// whole connection ("too_many_data_frames"). A stream window this small
/// keeps that worst case (128 KiB of 35-byte messages: about 0.8 MiB of
/// overhead) well below the limit of [`CONNECTION_WINDOW`] / 2, even with
/// two paused streams; the gateway then holds back and reports the frames
/// the reader missed as `FramesLost`. It still carries a saturated CAN FD
/// bus over a 50 ms round trip.
pub const STREAM_WINDOW: u32 = 128 * 1024;

/// HTTP/2 flow-control window of a whole connection (see
/// [`STREAM_WINDOW`]).
pub const CONNECTION_WINDOW: u32 = 4 * 1024 * 1024;

/// Connects to a gateway with a token and/or TLS.
pub async fn connect_with(url: &str, options: &ConnectOptions) -> Result<Client, Error> {
    let read = |p: &PathBuf| {
        std::fs::read(p).map_err(|e| Error::Options(format!("cannot read {}: {e}", p.display())))
    };
    let url = match (&options.ca, url.strip_prefix("http://")) {
        (Some(_), Some(rest)) => format!("https://{rest}"),
        _ => url.to_string(),
    };
    let mut endpoint = Endpoint::from_shared(url.clone())
        .map_err(|_| Error::BadUrl(url.clone()))?
        .tcp_nodelay(true)
        .connect_timeout(std::time::Duration::from_secs(5))
        .initial_stream_window_size(STREAM_WINDOW)
        .initial_connection_window_size(CONNECTION_WINDOW);
    if options.ca.is_some() || options.cert.is_some() || url.starts_with("https://") {
        let mut tls = ClientTlsConfig::new();
        if let Some(ca) = &options.ca {
            tls = tls.ca_certificate(Certificate::from_pem(read(ca)?));
        }
        match (&options.cert, &options.key) {
            (Some(cert), Some(key)) => {
                tls = tls.identity(Identity::from_pem(read(cert)?, read(key)?));
            }
            (None, None) => {}
            _ => {
                return Err(Error::Options(
                    "a client certificate needs both --cert and --key".into(),
                ));
            }
        }
        if let Some(d) = &options.tls_domain {
            tls = tls.domain_name(d.clone());
        }
        endpoint = endpoint.tls_config(tls).map_err(|source| Error::Connect {
            url: url.clone(),
            source,
        })?;
    }
    let token = options
        .token
        .as_deref()
        .map(|t| {
            format!("Bearer {t}")
                .parse::<tonic::metadata::AsciiMetadataValue>()
                .map_err(|_| Error::Options("the token is not valid gRPC metadata".into()))
        })
        .transpose()?;
    let channel = endpoint.connect().await.map_err(|source| Error::Connect {
        url: url.clone(),
        source,
    })?;
    Ok(Client {
        channel: InterceptedService::new(channel, BearerToken(token)),
    })
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

/// Type URL of the `cangate.v1.SdoAbortDetails` detail of SDO errors.
pub const SDO_ABORT_DETAILS_TYPE_URL: &str = "type.googleapis.com/cangate.v1.SdoAbortDetails";

/// The `cangate.v1.SdoAbortDetails` an error status carries: the gateway
/// packs it as a `google.protobuf.Any` in the `google.rpc.Status` of
/// `grpc-status-details-bin` (the standard richer error model), next to a
/// `google.rpc.ErrorInfo`. `None` for errors not caused by an SDO transfer.
pub fn sdo_abort_details(status: &tonic::Status) -> Option<pb::SdoAbortDetails> {
    use prost::Message;
    tonic_types::Status::decode(status.details())
        .ok()?
        .details
        .iter()
        .find(|any| any.type_url == SDO_ABORT_DETAILS_TYPE_URL)
        .and_then(|any| pb::SdoAbortDetails::decode(any.value.as_slice()).ok())
}

impl Client {
    /// The underlying channel (with the token interceptor), for the
    /// generated clients of other services.
    pub fn channel(&self) -> Transport {
        self.channel.clone()
    }

    /// The generated Bus client.
    pub fn bus_client(&self) -> BusClient<Transport> {
        BusClient::new(self.channel.clone()).max_decoding_message_size(64 * 1024 * 1024)
    }

    /// The generated Canopen client.
    pub fn canopen_client(&self) -> pb::canopen_client::CanopenClient<Transport> {
        pb::canopen_client::CanopenClient::new(self.channel.clone())
            .max_decoding_message_size(64 * 1024 * 1024)
            .max_encoding_message_size(64 * 1024 * 1024)
    }

    /// The generated Axes client.
    pub fn axes_client(&self) -> pb::axes_client::AxesClient<Transport> {
        pb::axes_client::AxesClient::new(self.channel.clone())
            .max_decoding_message_size(64 * 1024 * 1024)
            .max_encoding_message_size(64 * 1024 * 1024)
    }

    /// The generated Handwheels client.
    pub fn handwheels_client(&self) -> pb::handwheels_client::HandwheelsClient<Transport> {
        pb::handwheels_client::HandwheelsClient::new(self.channel.clone())
            .max_decoding_message_size(64 * 1024 * 1024)
            .max_encoding_message_size(64 * 1024 * 1024)
    }

    /// The generated Cansmc client (CANsmc masters).
    pub fn cansmc_client(&self) -> pb::cansmc_client::CansmcClient<Transport> {
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
    pub fn simulator_client(&self) -> pb::simulator_client::SimulatorClient<Transport> {
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
