//! Connecting: the URL (with or without scheme), credentials, TLS and the
//! client's timeouts.

use crate::error::Error;
use crate::{Client, Transport};
use std::path::PathBuf;
use std::time::Duration;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Certificate, ClientTlsConfig, Endpoint, Identity};

/// Default server address of the CLI and examples.
pub const DEFAULT_SERVER: &str = "http://127.0.0.1:50051";

/// Connect timeout when [`ConnectOptions::connect_timeout`] is `None`.
pub const DEFAULT_CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

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

/// How to reach a gateway beyond its address: credentials, TLS, timeouts.
/// `ConnectOptions::default()` is plaintext, no token, a 5 s connect
/// timeout and no request timeout.
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
    /// Bound of establishing the connection (TCP, and TLS when used);
    /// `None`: [`DEFAULT_CONNECT_TIMEOUT`]. Past it, [`Error::Timeout`].
    pub connect_timeout: Option<Duration>,
    /// Bound of each call of this crate's methods, from sending the
    /// request to its answer (for streams: to the start of the stream);
    /// waited axis commands add their wait bound to it. Past it,
    /// [`Error::Timeout`] and the call is cancelled. `None`: no bound on
    /// this side (the gateway bounds its own work: SDO timeouts, waits),
    /// so a peer that accepts the connection and never answers makes a
    /// call wait forever; set it where that matters.
    pub request_timeout: Option<Duration>,
}

impl std::fmt::Debug for ConnectOptions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ConnectOptions")
            .field("token", &self.token.as_ref().map(|_| "<redacted>"))
            .field("ca", &self.ca)
            .field("cert", &self.cert)
            .field("key", &self.key)
            .field("tls_domain", &self.tls_domain)
            .field("connect_timeout", &self.connect_timeout)
            .field("request_timeout", &self.request_timeout)
            .finish()
    }
}

/// Connects to a gateway without credentials: `http://host:port`, or
/// `host:port` (plaintext).
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

/// The URL to dial: a scheme added when missing (`https` with TLS, else
/// `http`), `http://` turned into `https://` with TLS.
pub(crate) fn normalize_url(url: &str, tls: bool) -> String {
    let url = url.trim();
    match url.split_once("://") {
        Some(("http", rest)) if tls => format!("https://{rest}"),
        Some(_) => url.to_string(),
        None if tls => format!("https://{url}"),
        None => format!("http://{url}"),
    }
}

/// Connects to a gateway with a token, TLS and timeouts. The address is a
/// URL (`http://host:port`, `https://host:port`) or `host:port`.
pub async fn connect_with(url: &str, options: &ConnectOptions) -> Result<Client, Error> {
    let read = |p: &PathBuf| {
        std::fs::read(p).map_err(|e| Error::invalid(format!("cannot read {}: {e}", p.display())))
    };
    let url = normalize_url(url, options.ca.is_some());
    let connect_timeout = options.connect_timeout.unwrap_or(DEFAULT_CONNECT_TIMEOUT);
    let mut endpoint = Endpoint::from_shared(url.clone())
        .map_err(|_| Error::invalid(format!("bad server URL {url:?}")))?
        .tcp_nodelay(true)
        .connect_timeout(connect_timeout)
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
                return Err(Error::invalid(
                    "a client certificate needs both --cert and --key",
                ));
            }
        }
        if let Some(d) = &options.tls_domain {
            tls = tls.domain_name(d.clone());
        }
        endpoint = endpoint
            .tls_config(tls)
            .map_err(|e| Error::connect(&url, &e))?;
    }
    let token = options
        .token
        .as_deref()
        .map(|t| {
            format!("Bearer {t}")
                .parse::<tonic::metadata::AsciiMetadataValue>()
                .map_err(|_| Error::invalid("the token is not valid gRPC metadata"))
        })
        .transpose()?;
    // tonic bounds the TCP connect only; this bounds the TLS handshake too.
    let channel = tokio::time::timeout(connect_timeout, endpoint.connect())
        .await
        .map_err(|_| Error::client_timeout(&format!("connecting to {url}"), connect_timeout))?
        .map_err(|e| Error::connect(&url, &e))?;
    Ok(Client {
        channel: InterceptedService::new(channel, BearerToken(token)) as Transport,
        request_timeout: options.request_timeout,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_without_scheme_get_one() {
        assert_eq!(
            normalize_url("127.0.0.1:50051", false),
            "http://127.0.0.1:50051"
        );
        assert_eq!(normalize_url(" gw:1 ", true), "https://gw:1");
        assert_eq!(normalize_url("http://gw:1", true), "https://gw:1");
        assert_eq!(normalize_url("http://gw:1", false), "http://gw:1");
        assert_eq!(normalize_url("https://gw:1", false), "https://gw:1");
        assert_eq!(normalize_url("[::1]:5", false), "http://[::1]:5");
    }

    #[test]
    fn tokens_hash_like_sha256sum() {
        assert_eq!(
            hash_token("abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }

    #[test]
    fn options_never_show_the_token() {
        let o = ConnectOptions {
            token: Some("secret".into()),
            ..Default::default()
        };
        assert!(!format!("{o:?}").contains("secret"));
        assert!(!format!("{:?}", BearerToken(Some("x".parse().unwrap()))).contains('x'));
    }

    #[tokio::test]
    async fn bad_input_is_refused_before_connecting() {
        let e = connect("http://exa mple:1").await.unwrap_err();
        assert!(matches!(e, Error::InvalidInput { .. }), "{e:?}");
        let e = connect_with(
            "127.0.0.1:1",
            &ConnectOptions {
                cert: Some("c.pem".into()),
                ..Default::default()
            },
        )
        .await
        .unwrap_err();
        assert!(matches!(e, Error::InvalidInput { .. }), "{e:?}");
    }

    #[tokio::test]
    async fn a_refused_connection_is_a_transport_error_said_once() {
        // A port nobody listens on: bind, learn the port, close.
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let e = connect(&format!("127.0.0.1:{port}")).await.unwrap_err();
        assert!(matches!(e, Error::Transport { .. }), "{e:?}");
        let text = e.to_string();
        assert!(
            text.starts_with("transport error: cannot connect to http://127.0.0.1:"),
            "{text}"
        );
        assert_eq!(text.matches("transport error").count(), 1, "{text}");
        assert!(std::error::Error::source(&e).is_none());
    }
}
