//! The gRPC listener's connections: plaintext or TLS (optionally mutual),
//! with the certificate, key and client CA re-read on demand (SIGHUP) and
//! used for new connections; connections already open keep theirs, and
//! the buses are never touched.
//!
//! Each connection carries a [`ConnInfo`] (peer address and, with mTLS,
//! the verified client certificate's subject CN) into every request's
//! extensions, where the security layer reads it.

use crate::config::TlsConfig;
use rustls_pki_types::pem::PemObject;
use rustls_pki_types::{CertificateDer, PrivateKeyDer};
use std::io;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::{Arc, RwLock};
use std::task::{Context, Poll};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio_rustls::rustls;
use tokio_util::sync::CancellationToken;

/// The HTTP/2 client connection preface (RFC 9113, 3.4): a connection
/// has completed its handshake once this many bytes have arrived.
const PREFACE_LEN: usize = 24;

/// How long connections may take to start speaking HTTP/2 and may stay
/// without any call: a client that never speaks, or one that connected and
/// went quiet, must not hold a socket forever.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConnTimeouts {
    /// From accept to the end of the TLS handshake, and again from then
    /// to the complete HTTP/2 preface and the first call: a connection
    /// that sends only the preface, or half a request's header, is closed
    /// this long after it came.
    pub handshake: Duration,
    /// With no call in progress for this long, the connection is closed
    /// (`None`: never).
    pub idle: Option<Duration>,
}

impl ConnTimeouts {
    /// From the `[security.limits]` section.
    pub fn from_limits(l: &crate::config::LimitsConfig) -> Self {
        ConnTimeouts {
            handshake: Duration::from_secs(u64::from(l.handshake_timeout_s.max(1))),
            idle: (l.idle_connection_timeout_s > 0)
                .then(|| Duration::from_secs(u64::from(l.idle_connection_timeout_s))),
        }
    }
}

/// The calls in progress on one connection, so that the connection can
/// tell when it has been idle (counted by the security layer).
#[derive(Debug, Default)]
pub struct ConnCalls {
    open: std::sync::atomic::AtomicU32,
    /// A call has begun on the connection (its first request's header
    /// arrived complete).
    started: std::sync::atomic::AtomicBool,
    /// When the last call ended (or the connection was accepted).
    idle_since: std::sync::Mutex<Option<tokio::time::Instant>>,
}

/// One call on a connection; ends it when dropped.
#[derive(Debug)]
pub struct CallGuard(Arc<ConnCalls>);

impl ConnCalls {
    /// A call begins; it lasts until the guard is dropped.
    pub fn begin(self: &Arc<Self>) -> CallGuard {
        self.started
            .store(true, std::sync::atomic::Ordering::SeqCst);
        self.open.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        CallGuard(self.clone())
    }

    /// Since when no call has been open, or `None` while one is.
    fn idle_since(&self) -> Option<tokio::time::Instant> {
        if self.open.load(std::sync::atomic::Ordering::SeqCst) > 0 {
            return None;
        }
        *self.idle_since.lock().unwrap_or_else(|p| p.into_inner())
    }
}

impl Drop for CallGuard {
    fn drop(&mut self) {
        let mut since = self.0.idle_since.lock().unwrap_or_else(|p| p.into_inner());
        if self
            .0
            .open
            .fetch_sub(1, std::sync::atomic::Ordering::SeqCst)
            == 1
        {
            *since = Some(tokio::time::Instant::now());
        }
    }
}

/// Why the TLS files could not be used.
#[derive(Debug, thiserror::Error)]
pub enum TlsError {
    /// A file could not be read or holds no usable PEM item.
    #[error("TLS {what} {path}: {message}")]
    File {
        /// `cert`, `key` or `client_ca`.
        what: &'static str,
        /// The path.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// rustls refused the combination (e.g. key does not match cert).
    #[error("TLS configuration: {0}")]
    Config(String),
}

/// Facts about one connection, in every request's extensions.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConnInfo {
    /// The listener's address.
    pub local_addr: Option<SocketAddr>,
    /// The client's address.
    pub remote_addr: Option<SocketAddr>,
    /// The connection is TLS.
    pub tls: bool,
    /// Subject CN of the client certificate rustls verified against
    /// `client_ca` (none without mTLS or without a client certificate).
    pub peer_cn: Option<String>,
    /// The calls in progress on this connection (none for connections
    /// made elsewhere, e.g. in tests).
    pub calls: Option<CallsHandle>,
}

/// A shared handle on a connection's [`ConnCalls`]; equal when it is the
/// same connection.
#[derive(Debug, Clone)]
pub struct CallsHandle(pub Arc<ConnCalls>);

impl PartialEq for CallsHandle {
    fn eq(&self, other: &Self) -> bool {
        Arc::ptr_eq(&self.0, &other.0)
    }
}
impl Eq for CallsHandle {}

fn file_error(what: &'static str, path: &std::path::Path, message: String) -> TlsError {
    TlsError::File {
        what,
        path: path.display().to_string(),
        message,
    }
}

fn read_certs(
    what: &'static str,
    path: &std::path::Path,
) -> Result<Vec<CertificateDer<'static>>, TlsError> {
    let pem = std::fs::read(path).map_err(|e| file_error(what, path, e.to_string()))?;
    let certs = CertificateDer::pem_slice_iter(&pem)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| file_error(what, path, e.to_string()))?;
    if certs.is_empty() {
        return Err(file_error(what, path, "no CERTIFICATE in the file".into()));
    }
    Ok(certs)
}

/// Builds the rustls server configuration from the files (ring provider,
/// ALPN h2 as gRPC needs).
pub fn load(config: &TlsConfig) -> Result<Arc<rustls::ServerConfig>, TlsError> {
    let certs = read_certs("cert", &config.cert)?;
    let key_pem =
        std::fs::read(&config.key).map_err(|e| file_error("key", &config.key, e.to_string()))?;
    let key = PrivateKeyDer::from_pem_slice(&key_pem)
        .map_err(|e| file_error("key", &config.key, e.to_string()))?;
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let builder = rustls::ServerConfig::builder_with_provider(provider.clone())
        .with_safe_default_protocol_versions()
        .map_err(|e| TlsError::Config(e.to_string()))?;
    let builder = match &config.client_ca {
        Some(ca) => {
            let mut roots = rustls::RootCertStore::empty();
            for c in read_certs("client_ca", ca)? {
                roots
                    .add(c)
                    .map_err(|e| file_error("client_ca", ca, e.to_string()))?;
            }
            let verifier = rustls::server::WebPkiClientVerifier::builder_with_provider(
                Arc::new(roots),
                provider,
            );
            // Without require_client_cert a client may come without a
            // certificate (and use a token); one it presents is verified.
            let verifier = if config.require_client_cert {
                verifier
            } else {
                verifier.allow_unauthenticated()
            };
            let verifier = verifier
                .build()
                .map_err(|e| TlsError::Config(e.to_string()))?;
            builder.with_client_cert_verifier(verifier)
        }
        None => builder.with_no_client_auth(),
    };
    let mut server = builder
        .with_single_cert(certs, key)
        .map_err(|e| TlsError::Config(e.to_string()))?;
    server.alpn_protocols = vec![b"h2".to_vec()];
    Ok(Arc::new(server))
}

/// The current TLS configuration, replaceable while the server runs.
/// Cheap to clone.
#[derive(Clone)]
pub struct TlsReloader {
    files: TlsConfig,
    current: Arc<RwLock<Arc<rustls::ServerConfig>>>,
}

impl std::fmt::Debug for TlsReloader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TlsReloader")
            .field("files", &self.files)
            .finish_non_exhaustive()
    }
}

impl TlsReloader {
    /// Loads the files once.
    pub fn new(files: TlsConfig) -> Result<Self, TlsError> {
        let current = load(&files)?;
        Ok(TlsReloader {
            files,
            current: Arc::new(RwLock::new(current)),
        })
    }

    /// Re-reads the files; new connections use them. On error the old
    /// configuration stays in use.
    pub fn reload(&self) -> Result<(), TlsError> {
        let fresh = load(&self.files)?;
        let mut current = self.current.write().unwrap_or_else(|p| p.into_inner());
        *current = fresh;
        Ok(())
    }

    fn acceptor(&self) -> tokio_rustls::TlsAcceptor {
        let current = self.current.read().unwrap_or_else(|p| p.into_inner());
        tokio_rustls::TlsAcceptor::from(current.clone())
    }
}

/// One accepted connection, plaintext or TLS, that closes itself when it
/// does not complete its HTTP/2 preface in time or stays idle too long
/// (see [`ConnTimeouts`]).
pub struct Conn {
    io: ConnIo,
    info: ConnInfo,
    calls: Arc<ConnCalls>,
    timeouts: ConnTimeouts,
    /// Bytes read so far, up to the preface's length.
    preface_seen: usize,
    /// When the preface must be complete.
    handshake_deadline: tokio::time::Instant,
    /// Wakes the connection to check its deadlines.
    timer: Pin<Box<tokio::time::Sleep>>,
}

impl Conn {
    fn new(io: ConnIo, mut info: ConnInfo, timeouts: ConnTimeouts) -> Self {
        let now = tokio::time::Instant::now();
        let calls = Arc::new(ConnCalls::default());
        *calls.idle_since.lock().unwrap_or_else(|p| p.into_inner()) = Some(now);
        info.calls = Some(CallsHandle(calls.clone()));
        let handshake_deadline = now + timeouts.handshake;
        Conn {
            io,
            info,
            calls,
            timeouts,
            preface_seen: 0,
            handshake_deadline,
            timer: Box::pin(tokio::time::sleep_until(handshake_deadline)),
        }
    }

    /// Whether the connection must close now, and why; else when to look
    /// again.
    fn check(&self, now: tokio::time::Instant) -> Result<tokio::time::Instant, &'static str> {
        if self.preface_seen < PREFACE_LEN {
            if now >= self.handshake_deadline {
                return Err("no HTTP/2 preface within handshake_timeout_s");
            }
            return Ok(self.handshake_deadline);
        }
        // Until its first call a connection is still in its handshake: a
        // preface alone, or half an HTTP/1.1 header, holds a socket no
        // longer than the handshake timeout (not the idle timeout).
        if !self.calls.started.load(std::sync::atomic::Ordering::SeqCst) {
            if now >= self.handshake_deadline {
                return Err("no request within handshake_timeout_s");
            }
            return Ok(self.handshake_deadline);
        }
        let Some(idle) = self.timeouts.idle else {
            // Nothing to watch: look again rarely.
            return Ok(now + Duration::from_secs(3600));
        };
        match self.calls.idle_since() {
            // A call is open; a call's end sets `idle_since`, which the
            // next look (at most `idle` later) sees.
            None => Ok(now + idle),
            Some(since) if now >= since + idle => Err("idle for idle_connection_timeout_s"),
            Some(since) => Ok(since + idle),
        }
    }
}

enum ConnIo {
    Plain(TcpStream),
    Tls(Box<tokio_rustls::server::TlsStream<TcpStream>>),
}

impl tonic::transport::server::Connected for Conn {
    type ConnectInfo = ConnInfo;
    fn connect_info(&self) -> ConnInfo {
        self.info.clone()
    }
}

impl AsyncRead for Conn {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let before = buf.filled().len();
        let polled = match &mut this.io {
            ConnIo::Plain(s) => Pin::new(s).poll_read(cx, buf),
            ConnIo::Tls(s) => Pin::new(s.as_mut()).poll_read(cx, buf),
        };
        if polled.is_ready() {
            this.preface_seen =
                (this.preface_seen + (buf.filled().len() - before)).min(PREFACE_LEN);
            return polled;
        }
        // Nothing to read: the connection waits, so look at its deadlines
        // (the timer wakes this task when the next one is due).
        loop {
            if this.timer.as_mut().poll(cx).is_pending() {
                return Poll::Pending;
            }
            match this.check(tokio::time::Instant::now()) {
                Ok(next) => this.timer.as_mut().reset(next),
                Err(why) => {
                    tracing::info!(peer = ?this.info.remote_addr, "connection closed: {why}");
                    // End of stream: the HTTP/2 server closes the connection.
                    return Poll::Ready(Ok(()));
                }
            }
        }
    }
}

impl AsyncWrite for Conn {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        match &mut self.get_mut().io {
            ConnIo::Plain(s) => Pin::new(s).poll_write(cx, buf),
            ConnIo::Tls(s) => Pin::new(s.as_mut()).poll_write(cx, buf),
        }
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        match &mut self.get_mut().io {
            ConnIo::Plain(s) => Pin::new(s).poll_write_vectored(cx, bufs),
            ConnIo::Tls(s) => Pin::new(s.as_mut()).poll_write_vectored(cx, bufs),
        }
    }

    fn is_write_vectored(&self) -> bool {
        match &self.io {
            ConnIo::Plain(s) => s.is_write_vectored(),
            ConnIo::Tls(s) => s.is_write_vectored(),
        }
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        match &mut self.get_mut().io {
            ConnIo::Plain(s) => Pin::new(s).poll_flush(cx),
            ConnIo::Tls(s) => Pin::new(s.as_mut()).poll_flush(cx),
        }
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        match &mut self.get_mut().io {
            ConnIo::Plain(s) => Pin::new(s).poll_shutdown(cx),
            ConnIo::Tls(s) => Pin::new(s.as_mut()).poll_shutdown(cx),
        }
    }
}

/// Accepts connections until `shutdown` fires, doing TLS handshakes (when
/// `tls` is given) in their own tasks so that a slow client never delays
/// another's connection; the stream is what tonic serves.
pub fn incoming(
    listener: TcpListener,
    tls: Option<TlsReloader>,
    timeouts: ConnTimeouts,
    shutdown: CancellationToken,
) -> tokio_stream::wrappers::ReceiverStream<Result<Conn, io::Error>> {
    let (tx, rx) = tokio::sync::mpsc::channel(64);
    let local_addr = listener.local_addr().ok();
    tokio::spawn(async move {
        loop {
            let (stream, peer) = tokio::select! {
                _ = shutdown.cancelled() => return,
                a = listener.accept() => match a {
                    Ok(a) => a,
                    Err(e) => {
                        // E.g. out of file descriptors: wait a little
                        // instead of spinning.
                        tracing::warn!("accept failed: {e}");
                        tokio::time::sleep(Duration::from_millis(50)).await;
                        continue;
                    }
                },
            };
            // Small messages (single frames, commands) must not wait for
            // Nagle's algorithm.
            let _ = stream.set_nodelay(true);
            let mut info = ConnInfo {
                local_addr,
                remote_addr: Some(peer),
                tls: false,
                peer_cn: None,
                calls: None,
            };
            match &tls {
                None => {
                    let conn = Conn::new(ConnIo::Plain(stream), info, timeouts);
                    if tx.send(Ok(conn)).await.is_err() {
                        return;
                    }
                }
                Some(tls) => {
                    let acceptor = tls.acceptor();
                    let tx = tx.clone();
                    tokio::spawn(async move {
                        let tls_stream =
                            match tokio::time::timeout(timeouts.handshake, acceptor.accept(stream))
                                .await
                            {
                                Ok(Ok(s)) => s,
                                Ok(Err(e)) => {
                                    tracing::info!(%peer, "TLS handshake failed: {e}");
                                    return;
                                }
                                Err(_) => {
                                    tracing::info!(%peer, "TLS handshake timed out");
                                    return;
                                }
                            };
                        info.tls = true;
                        info.peer_cn = tls_stream
                            .get_ref()
                            .1
                            .peer_certificates()
                            .and_then(|c| c.first())
                            .and_then(|c| subject_cn(c.as_ref()));
                        let conn = Conn::new(ConnIo::Tls(Box::new(tls_stream)), info, timeouts);
                        let _ = tx.send(Ok(conn)).await;
                    });
                }
            }
        }
    });
    tokio_stream::wrappers::ReceiverStream::new(rx)
}

/// One DER element: (tag, contents, rest). Only what certificates use:
/// single-byte tags, definite lengths up to 4 length bytes.
fn der(input: &[u8]) -> Option<(u8, &[u8], &[u8])> {
    let (&tag, rest) = input.split_first()?;
    let (&first, mut rest) = rest.split_first()?;
    let len = if first < 0x80 {
        usize::from(first)
    } else {
        let n = usize::from(first & 0x7F);
        if n == 0 || n > 4 || rest.len() < n {
            return None;
        }
        let mut len = 0usize;
        for &b in &rest[..n] {
            len = (len << 8) | usize::from(b);
        }
        rest = &rest[n..];
        len
    };
    if rest.len() < len {
        return None;
    }
    Some((tag, &rest[..len], &rest[len..]))
}

const SEQUENCE: u8 = 0x30;
const SET: u8 = 0x31;
/// id-at-commonName, 2.5.4.3.
const CN_OID: &[u8] = &[0x55, 0x04, 0x03];

/// The subject common name of a DER X.509 certificate (the first CN when
/// there are several). Written by hand: the certificate was verified by
/// rustls already, and this walk needs a few lines, not an X.509 crate.
pub fn subject_cn(cert: &[u8]) -> Option<String> {
    let (SEQUENCE, cert, _) = der(cert)? else {
        return None;
    };
    let (SEQUENCE, tbs, _) = der(cert)? else {
        return None;
    };
    let mut rest = tbs;
    // Optional [0] EXPLICIT version.
    if rest.first() == Some(&0xA0) {
        rest = der(rest)?.2;
    }
    // serialNumber, signature, issuer, validity.
    for _ in 0..4 {
        rest = der(rest)?.2;
    }
    let (SEQUENCE, mut name, _) = der(rest)? else {
        return None;
    };
    while !name.is_empty() {
        let (tag, mut rdn, next) = der(name)?;
        name = next;
        if tag != SET {
            return None;
        }
        while !rdn.is_empty() {
            let (tag, atv, next) = der(rdn)?;
            rdn = next;
            if tag != SEQUENCE {
                return None;
            }
            let (0x06, oid, value) = der(atv)? else {
                return None;
            };
            if oid != CN_OID {
                continue;
            }
            let (vtag, text, _) = der(value)?;
            return match vtag {
                // UTF8String, PrintableString, TeletexString, IA5String.
                0x0C | 0x13 | 0x14 | 0x16 => Some(String::from_utf8_lossy(text).into_owned()),
                // BMPString: UTF-16BE.
                0x1E => {
                    let units: Vec<u16> = text
                        .chunks_exact(2)
                        .map(|c| u16::from_be_bytes([c[0], c[1]]))
                        .collect();
                    Some(String::from_utf16_lossy(&units))
                }
                _ => None,
            };
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cert_with(dn: rcgen::DistinguishedName) -> Vec<u8> {
        let key = rcgen::KeyPair::generate().unwrap();
        let mut params = rcgen::CertificateParams::new(vec!["localhost".into()]).unwrap();
        params.distinguished_name = dn;
        params.self_signed(&key).unwrap().der().to_vec()
    }

    #[test]
    fn subject_cn_is_found_among_other_attributes() {
        let mut dn = rcgen::DistinguishedName::new();
        dn.push(rcgen::DnType::CountryName, "DE");
        dn.push(rcgen::DnType::OrganizationName, "Machine Works");
        dn.push(rcgen::DnType::CommonName, "hmi-2");
        assert_eq!(subject_cn(&cert_with(dn)).as_deref(), Some("hmi-2"));
        let mut dn = rcgen::DistinguishedName::new();
        dn.push(rcgen::DnType::OrganizationName, "no cn");
        assert_eq!(subject_cn(&cert_with(dn)), None);
        assert_eq!(subject_cn(b"\x30\x03\x02\x01"), None);
        assert_eq!(subject_cn(&[]), None);
    }

    #[test]
    fn a_missing_or_bad_file_is_named() {
        let e = load(&TlsConfig {
            cert: "/nonexistent/cert.pem".into(),
            key: "/nonexistent/key.pem".into(),
            client_ca: None,
            require_client_cert: false,
        })
        .unwrap_err();
        assert!(
            e.to_string().contains("TLS cert /nonexistent/cert.pem"),
            "{e}"
        );
    }
}
