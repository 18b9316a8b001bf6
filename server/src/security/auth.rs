//! The security layer in front of every service: it finds out who calls
//! (bearer token, else verified client certificate), checks the role the
//! [access table](super::roles) asks for, applies the per-client
//! [limits](super::limits) and the message size limit, and writes
//! state-changing calls and refusals to the audit log (tracing target
//! `cangate::audit`).

use super::limits::{
    Admission, CallKind, FrameBudget, Limits, PeerRefusals, Permit, StreamQueueBudget,
};
use super::roles::{self, Access, Rule};
use super::tls::ConnInfo;
use super::{Identity, Role};
use crate::config::{SecurityConfig, parse_sha256};
use bytes::Buf;
use http_body::Frame;
use sha2::{Digest, Sha256};
use std::collections::HashMap;
use std::net::IpAddr;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::{Duration, Instant};
use subtle::ConstantTimeEq;
use tonic::body::Body;

/// The audit log's tracing target.
pub const AUDIT_TARGET: &str = "cangate::audit";

/// The hex SHA-256 of a token, as the configuration stores it.
pub fn hash_token(token: &str) -> String {
    Sha256::digest(token.as_bytes())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

#[derive(Debug)]
struct TokenEntry {
    name: String,
    role: Role,
    digest: [u8; 32],
}

/// Why a caller is refused before its call runs.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Refusal {
    /// No usable credentials.
    #[error("{0}")]
    Unauthenticated(String),
    /// Known, but not allowed.
    #[error("{0}")]
    PermissionDenied(String),
    /// Over a limit.
    #[error("{0}")]
    ResourceExhausted(String),
    /// The RPC is not in the access table.
    #[error("{0}")]
    Unclassified(String),
}

impl Refusal {
    fn status(&self) -> tonic::Status {
        match self {
            Refusal::Unauthenticated(m) => {
                super::refused(tonic::Code::Unauthenticated, "UNAUTHENTICATED", m.clone())
            }
            Refusal::PermissionDenied(m) => super::refused(
                tonic::Code::PermissionDenied,
                "PERMISSION_DENIED",
                m.clone(),
            ),
            Refusal::ResourceExhausted(m) => super::refused(
                tonic::Code::ResourceExhausted,
                super::limit_reason(m),
                m.clone(),
            ),
            Refusal::Unclassified(m) => {
                super::refused(tonic::Code::Unimplemented, "NOT_CLASSIFIED", m.clone())
            }
        }
    }
}

/// Identities: token hashes and certificate names.
#[derive(Debug)]
pub struct Authenticator {
    tokens: Vec<TokenEntry>,
    clients: HashMap<String, Role>,
}

impl Authenticator {
    /// From the `[security]` section (validated already: bad hashes are
    /// skipped here, never panicked on).
    pub fn new(config: &SecurityConfig) -> Self {
        Authenticator {
            tokens: config
                .tokens
                .iter()
                .filter_map(|t| {
                    Some(TokenEntry {
                        name: t.name.clone(),
                        role: t.role,
                        digest: parse_sha256(&t.sha256)?,
                    })
                })
                .collect(),
            clients: config
                .clients
                .iter()
                .map(|c| (c.subject_cn.clone(), c.role))
                .collect(),
        }
    }

    /// Authentication is on (some identity is configured).
    pub fn enabled(&self) -> bool {
        !self.tokens.is_empty() || !self.clients.is_empty()
    }

    /// The identity behind a token, comparing the digest with every
    /// configured one in constant time (no early exit, so the time taken
    /// says nothing about which or how many bytes matched).
    fn by_token(&self, token: &str) -> Option<Identity> {
        let digest: [u8; 32] = Sha256::digest(token.as_bytes()).into();
        let mut found = None;
        for t in &self.tokens {
            if bool::from(t.digest.ct_eq(&digest)) {
                found = Some(t);
            }
        }
        found.map(|t| Identity {
            name: t.name.clone(),
            role: t.role,
            method: "token",
        })
    }

    /// Who calls: the bearer token when one is sent, else the verified
    /// client certificate's CN.
    pub fn identify(
        &self,
        authorization: Option<&http::HeaderValue>,
        conn: Option<&ConnInfo>,
    ) -> Result<Identity, Refusal> {
        if !self.enabled() {
            return Ok(Identity {
                name: "anonymous".into(),
                role: Role::Engineer,
                method: "none",
            });
        }
        if let Some(value) = authorization {
            let token = value
                .to_str()
                .ok()
                .and_then(|v| {
                    v.strip_prefix("Bearer ")
                        .or_else(|| v.strip_prefix("bearer "))
                })
                .map(str::trim)
                .filter(|t| !t.is_empty())
                .ok_or_else(|| {
                    Refusal::Unauthenticated(
                        "malformed authorization metadata: expected \"Bearer <token>\"".into(),
                    )
                })?;
            return self
                .by_token(token)
                .ok_or_else(|| Refusal::Unauthenticated("unknown token".into()));
        }
        if let Some(cn) = conn.and_then(|c| c.peer_cn.as_deref()) {
            return match self.clients.get(cn) {
                Some(&role) => Ok(Identity {
                    name: cn.to_string(),
                    role,
                    method: "certificate",
                }),
                None => Err(Refusal::PermissionDenied(format!(
                    "client certificate CN {cn:?} has no role ([[security.clients]])"
                ))),
            };
        }
        Err(Refusal::Unauthenticated(
            "missing bearer token (metadata \"authorization: Bearer <token>\")".into(),
        ))
    }
}

struct Shared {
    auth: Authenticator,
    /// `[security] viewers_may_stop`.
    viewers_may_stop: bool,
    limits: Limits,
    max_message_bytes: u32,
    refusals: PeerRefusals,
    audit_gate: AuditGate,
}

/// Bounds the audit lines of refused calls: a token bucket for all peers
/// together; refusals beyond it are counted per peer and written as one
/// summary line per peer every `audit_summary_interval_s`.
struct AuditGate {
    rate: f64,
    state: Mutex<AuditGateState>,
}

struct AuditGateState {
    tokens: f64,
    refilled: Instant,
    /// Refusals left out since the last summary, per peer.
    suppressed: HashMap<String, u64>,
}

/// Peers a summary names one by one; the rest are summed up.
/// The RPC whose requests may exceed `max_message_bytes`: a program image
/// travels in one message.
pub const PROGRAM_DOWNLOAD_METHOD: &str = "/cangate.v1.Canopen/DownloadProgram";
/// Its largest request: a 16 MiB image plus the other fields.
pub const MAX_PROGRAM_MESSAGE_BYTES: u32 = 16 * 1024 * 1024 + 64 * 1024;

const SUMMARY_PEERS: usize = 20;

impl AuditGate {
    fn new(rate: u32) -> Self {
        let burst = f64::from(rate.max(1)) * 2.0;
        AuditGate {
            rate: f64::from(rate),
            state: Mutex::new(AuditGateState {
                tokens: burst,
                refilled: Instant::now(),
                suppressed: HashMap::new(),
            }),
        }
    }

    /// Whether this refusal of `peer` gets its own audit line (else it is
    /// counted for the next summary).
    fn admit(&self, peer: &str) -> bool {
        if self.rate <= 0.0 {
            return true;
        }
        let mut st = self.state.lock().unwrap_or_else(|p| p.into_inner());
        let now = Instant::now();
        let elapsed = now.saturating_duration_since(st.refilled).as_secs_f64();
        st.tokens = (st.tokens + elapsed * self.rate).min(self.rate * 2.0);
        st.refilled = now;
        if st.tokens >= 1.0 {
            st.tokens -= 1.0;
            return true;
        }
        if st.suppressed.len() < 10 * SUMMARY_PEERS || st.suppressed.contains_key(peer) {
            *st.suppressed.entry(peer.to_string()).or_default() += 1;
        } else {
            *st.suppressed.entry("other peers".to_string()).or_default() += 1;
        }
        false
    }

    /// Writes the summary of the refusals left out, if any.
    fn summarize(&self, interval: Duration) {
        let suppressed = {
            let mut st = self.state.lock().unwrap_or_else(|p| p.into_inner());
            std::mem::take(&mut st.suppressed)
        };
        if suppressed.is_empty() {
            return;
        }
        let total: u64 = suppressed.values().sum();
        let mut peers: Vec<(String, u64)> = suppressed.into_iter().collect();
        peers.sort_by_key(|p| std::cmp::Reverse(p.1));
        let named: Vec<String> = peers
            .iter()
            .take(SUMMARY_PEERS)
            .map(|(p, n)| format!("{p}: {n}"))
            .collect();
        let others = peers.len().saturating_sub(SUMMARY_PEERS);
        tracing::warn!(
            target: AUDIT_TARGET,
            refused = total,
            peers = peers.len(),
            by_peer = %named.join(", "),
            others,
            interval_s = interval.as_secs(),
            "refused calls not logged one by one (audit_refusals_per_second)"
        );
    }
}

/// The tower layer (see the module documentation). Cheap to clone.
#[derive(Clone)]
pub struct SecurityLayer {
    shared: Arc<Shared>,
}

impl std::fmt::Debug for SecurityLayer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SecurityLayer")
            .field("authentication", &self.shared.auth.enabled())
            .finish_non_exhaustive()
    }
}

impl SecurityLayer {
    /// From the `[security]` section. Within a tokio runtime, a task
    /// writes the summaries of refusals left out of the audit log; it ends
    /// with the last clone of the layer.
    pub fn new(config: &SecurityConfig) -> Self {
        let l = &config.limits;
        let shared = Arc::new(Shared {
            auth: Authenticator::new(config),
            viewers_may_stop: config.viewers_may_stop,
            limits: Limits::new(l.clone()),
            max_message_bytes: l.max_message_bytes,
            refusals: PeerRefusals::new(l.refusals_per_second_per_peer, l.refusal_burst),
            audit_gate: AuditGate::new(l.audit_refusals_per_second),
        });
        let interval = Duration::from_secs(u64::from(l.audit_summary_interval_s.max(1)));
        if let Ok(rt) = tokio::runtime::Handle::try_current() {
            let weak = Arc::downgrade(&shared);
            rt.spawn(async move {
                let mut tick = tokio::time::interval(interval);
                tick.tick().await;
                loop {
                    tick.tick().await;
                    let Some(shared) = weak.upgrade() else {
                        return;
                    };
                    shared.audit_gate.summarize(interval);
                }
            });
        }
        SecurityLayer { shared }
    }
}

/// What a session on a listener other than gRPC (the socketcand
/// endpoint) holds once admitted: counted as one streaming call of its
/// client, with the same keys, budgets and stream slot as an `Attach`.
#[derive(Debug)]
pub struct SessionAdmission {
    /// Who it is.
    pub identity: Identity,
    /// Its stream slot (`max_streams_per_client`), held while it is open.
    pub stream: Option<Permit>,
    /// Its client's queue budget.
    pub queue_budget: Option<StreamQueueBudget>,
    /// Its client's raw frame budget.
    pub frame_budget: Option<FrameBudget>,
}

impl SecurityLayer {
    /// Authentication is on (tokens or client certificates configured).
    pub fn authentication(&self) -> bool {
        self.shared.auth.enabled()
    }

    /// Admits a session of a peer that identifies itself with a bearer
    /// token given in its own protocol (socketcand's `< open BUS TOKEN >`)
    /// rather than in gRPC metadata: the same identities, the same
    /// refusal throttling per peer address, the same per-client limits as
    /// a streaming call (one call against the call rate, one stream slot).
    /// With authentication off every session is `anonymous` with role
    /// engineer, counted by its peer address, as gRPC calls are.
    ///
    /// # Errors
    /// No or an unknown token (Unauthenticated), a peer refused too often
    /// or a client over its limits (ResourceExhausted).
    pub fn admit_session(
        &self,
        token: Option<&str>,
        peer: IpAddr,
    ) -> Result<SessionAdmission, Refusal> {
        let shared = &self.shared;
        let identity = if shared.auth.enabled() {
            if shared.refusals.blocked(peer) {
                return Err(Refusal::ResourceExhausted(format!(
                    "too many refused attempts from {peer}: refused without checking \
                     credentials until fewer arrive (refusals_per_second_per_peer = {})",
                    shared.refusals.rate()
                )));
            }
            let found = token.and_then(|t| shared.auth.by_token(t));
            match (token, found) {
                (_, Some(id)) => id,
                (None, None) => {
                    shared.refusals.record(peer);
                    return Err(Refusal::Unauthenticated(
                        "missing token: the gateway has authentication on; open with \
                         < open BUS TOKEN >"
                            .into(),
                    ));
                }
                (Some(_), None) => {
                    shared.refusals.record(peer);
                    return Err(Refusal::Unauthenticated("unknown token".into()));
                }
            }
        } else {
            Identity {
                name: "anonymous".into(),
                role: Role::Engineer,
                method: "none",
            }
        };
        let key = if identity.method == "none" {
            format!("peer {peer}")
        } else {
            format!("{} {}", identity.method, identity.name)
        };
        let admission = shared
            .limits
            .admit(&key, CallKind::Streaming)
            .map_err(|e| Refusal::ResourceExhausted(e.0))?;
        Ok(SessionAdmission {
            identity,
            stream: admission.stream,
            queue_budget: admission.queue_budget,
            frame_budget: admission.frame_budget,
        })
    }
}

impl<S> tower::Layer<S> for SecurityLayer {
    type Service = SecurityService<S>;
    fn layer(&self, inner: S) -> Self::Service {
        SecurityService {
            inner,
            shared: self.shared.clone(),
        }
    }
}

/// See [`SecurityLayer`].
#[derive(Clone)]
pub struct SecurityService<S> {
    inner: S,
    shared: Arc<Shared>,
}

/// What the audit record of one call says.
#[derive(Debug)]
struct Audit {
    who: String,
    role: &'static str,
    method: String,
    peer: String,
    start: Instant,
}

impl Audit {
    fn emit(&self, code: tonic::Code, message: &str) {
        let duration_ms = self.start.elapsed().as_secs_f64() * 1000.0;
        let code = crate::metrics::code_name(code);
        if code == "OK" {
            tracing::info!(
                target: AUDIT_TARGET,
                who = %self.who,
                role = self.role,
                method = %self.method,
                peer = %self.peer,
                code,
                duration_ms,
                "rpc"
            );
        } else {
            tracing::warn!(
                target: AUDIT_TARGET,
                who = %self.who,
                role = self.role,
                method = %self.method,
                peer = %self.peer,
                code,
                duration_ms,
                message,
                "rpc"
            );
        }
    }
}

/// A refused call: who it was (when known) and why.
struct Denied {
    identity: Option<Identity>,
    refusal: Refusal,
}

/// At most this much of a caller-chosen string (a method path) goes into
/// a message or an audit line.
const QUOTE_BYTES: usize = 96;

/// The start of a caller-chosen string, cut at a character boundary.
fn clipped(s: &str) -> std::borrow::Cow<'_, str> {
    if s.len() <= QUOTE_BYTES {
        return s.into();
    }
    let mut end = QUOTE_BYTES;
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}… ({} bytes)", &s[..end], s.len()).into()
}

impl<S> SecurityService<S> {
    /// Decides on a call: its identity and the limits it holds, or why not.
    fn admit(
        &self,
        rule: Option<&'static Rule>,
        method: &str,
        authorization: Option<&http::HeaderValue>,
        conn: Option<&ConnInfo>,
    ) -> Result<(Identity, Admission), Denied> {
        let Some(rule) = rule else {
            return Err(Denied {
                identity: None,
                refusal: Refusal::Unclassified(format!(
                    "{} is not classified in the gateway's access table: refused",
                    clipped(method)
                )),
            });
        };
        let peer_ip: Option<IpAddr> = conn.and_then(|c| c.remote_addr).map(|a| a.ip());
        // A peer that keeps failing to authenticate is refused before its
        // credentials are looked at. Public RPCs stay open to it, and so do
        // stops: an operator behind the same address must still be able to
        // stop a machine.
        if let (Access::Role(_), Some(ip)) = (rule.access, peer_ip)
            && !roles::is_stop(rule)
            && self.shared.auth.enabled()
            && self.shared.refusals.blocked(ip)
        {
            return Err(Denied {
                identity: None,
                refusal: Refusal::ResourceExhausted(format!(
                    "too many refused calls from {ip}: its calls are refused without checking \
                     credentials until fewer arrive (refusals_per_second_per_peer = {})",
                    self.shared.refusals.rate()
                )),
            });
        }
        let identity = match rule.access {
            Access::Public => Identity {
                name: "anonymous".into(),
                role: Role::Viewer,
                method: "none",
            },
            Access::Role(needed) => {
                let id = self
                    .shared
                    .auth
                    .identify(authorization, conn)
                    .map_err(|refusal| {
                        if let Some(ip) = peer_ip {
                            self.shared.refusals.record(ip);
                        }
                        Denied {
                            identity: None,
                            refusal,
                        }
                    })?;
                // A stop needs an operator, or a viewer where the
                // configuration lets viewers stop.
                let stop_by_viewer =
                    self.shared.viewers_may_stop && id.role == Role::Viewer && roles::is_stop(rule);
                if id.role < needed && !stop_by_viewer {
                    let msg = format!(
                        "{} needs role {needed}; {} holds role {}",
                        clipped(method),
                        id.name,
                        id.role
                    );
                    return Err(Denied {
                        identity: Some(id),
                        refusal: Refusal::PermissionDenied(msg),
                    });
                }
                id
            }
        };
        // Limits count per identity; anonymous callers per peer IP.
        let key = if identity.method == "none" {
            conn.and_then(|c| c.remote_addr).map_or_else(
                || "unknown peer".to_string(),
                |a| format!("peer {}", a.ip()),
            )
        } else {
            format!("{} {}", identity.method, identity.name)
        };
        let kind = if roles::is_stop(rule) {
            CallKind::Stop
        } else if roles::sends_raw_frames(rule) && !rule.streaming {
            CallKind::RawFrames
        } else if rule.streaming {
            CallKind::Streaming
        } else {
            CallKind::Unary
        };
        match self.shared.limits.admit(&key, kind) {
            Ok(a) => Ok((identity, a)),
            Err(e) => Err(Denied {
                identity: Some(identity),
                refusal: Refusal::ResourceExhausted(e.0),
            }),
        }
    }
}

type BoxFuture<T> = Pin<Box<dyn std::future::Future<Output = T> + Send>>;

impl<S> tower::Service<http::Request<Body>> for SecurityService<S>
where
    S: tower::Service<http::Request<Body>, Response = http::Response<Body>>,
    S::Future: Send + 'static,
    S::Error: Send + 'static,
{
    type Response = http::Response<Body>;
    type Error = S::Error;
    type Future = BoxFuture<Result<Self::Response, Self::Error>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, mut req: http::Request<Body>) -> Self::Future {
        let start = Instant::now();
        let method = req.uri().path().to_string();
        let program_download = method == PROGRAM_DOWNLOAD_METHOD;
        let conn = req.extensions().get::<ConnInfo>().cloned();
        // Services read the peer with `Request::remote_addr`, which knows
        // tonic's own connection types only.
        if let Some(c) = &conn {
            req.extensions_mut()
                .insert(tonic::transport::server::TcpConnectInfo {
                    local_addr: c.local_addr,
                    remote_addr: c.remote_addr,
                });
        }
        let peer = conn
            .as_ref()
            .and_then(|c| c.remote_addr)
            .map_or_else(|| "unknown".to_string(), |a| a.to_string());
        // The call counts as open on its connection until its response
        // ends (for the idle-connection timeout).
        let call_guard = conn
            .as_ref()
            .and_then(|c| c.calls.as_ref())
            .map(|c| c.0.begin());
        let rule = roles::lookup(&method);
        let decision = self.admit(
            rule,
            &method,
            req.headers().get(http::header::AUTHORIZATION),
            conn.as_ref(),
        );
        let (
            identity,
            Admission {
                in_flight,
                stream,
                queue_budget,
                frame_budget,
                stop_over_budget,
            },
        ) = match decision {
            Ok(d) => d,
            Err(Denied { identity, refusal }) => {
                let status = refusal.status();
                let peer_ip = conn
                    .as_ref()
                    .and_then(|c| c.remote_addr)
                    .map_or_else(|| "unknown".to_string(), |a| a.ip().to_string());
                if self.shared.audit_gate.admit(&peer_ip) {
                    let audit = Audit {
                        who: identity
                            .as_ref()
                            .map_or_else(|| "unidentified".to_string(), |i| i.name.clone()),
                        role: identity.as_ref().map_or("none", |i| i.role.as_str()),
                        method: clipped(&method).into_owned(),
                        peer,
                        start,
                    };
                    audit.emit(status.code(), status.message());
                }
                drop(call_guard);
                return Box::pin(std::future::ready(Ok(status.into_http())));
            }
        };
        let audit = rule.filter(|r| roles::state_changing(r)).map(|_| Audit {
            who: identity.name.clone(),
            role: identity.role.as_str(),
            method,
            peer,
            start,
        });
        req.extensions_mut().insert(identity);
        if let Some(b) = stop_over_budget {
            req.extensions_mut().insert(b);
        }
        if let Some(b) = queue_budget {
            req.extensions_mut().insert(b);
        }
        if let Some(b) = &frame_budget
            && rule.is_some_and(roles::carries_requests)
        {
            req.extensions_mut().insert(b.requests());
        }
        if let Some(b) = frame_budget
            && rule.is_some_and(roles::sends_raw_frames)
        {
            req.extensions_mut().insert(b);
        }
        let mut limit = self.shared.max_message_bytes;
        if limit > 0 && program_download {
            // A program image travels in one message (see
            // Canopen.DownloadProgram); engineers only, checked above.
            limit = limit.max(MAX_PROGRAM_MESSAGE_BYTES);
        }
        if limit > 0 {
            req = req.map(|b| Body::new(SizeLimited::new(b, limit)));
        }
        let fut = self.inner.call(req);
        Box::pin(async move {
            let mut resp = fut.await?;
            // The handler has answered: the call no longer counts as in
            // progress; a stream keeps its stream slot until it ends.
            drop(in_flight);
            super::status::tidy(resp.headers_mut());
            let header_code = resp
                .headers()
                .get("grpc-status")
                .and_then(|v| v.to_str().ok())
                .and_then(|v| v.parse::<i32>().ok())
                .map(tonic::Code::from);
            Ok(resp.map(|body| {
                Body::new(Guarded {
                    inner: body,
                    _stream: stream,
                    _call: call_guard,
                    audit,
                    code: header_code,
                })
            }))
        })
    }
}

/// A response body that holds a stream slot and the connection's open
/// call until it ends or is dropped, tidies the final status (see
/// [`super::status`]) and writes the audit record with it.
struct Guarded {
    inner: Body,
    _stream: Option<Permit>,
    _call: Option<super::tls::CallGuard>,
    audit: Option<Audit>,
    code: Option<tonic::Code>,
}

impl Guarded {
    fn finish(&mut self, code: tonic::Code, message: &str) {
        if let Some(a) = self.audit.take() {
            a.emit(code, message);
        }
    }
}

impl Drop for Guarded {
    fn drop(&mut self) {
        // Ended without trailers: a trailers-only answer (code in the
        // headers), or the client went away.
        let code = self.code.unwrap_or(tonic::Code::Cancelled);
        self.finish(code, "");
    }
}

impl http_body::Body for Guarded {
    type Data = bytes::Bytes;
    type Error = tonic::Status;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Self::Data>, Self::Error>>> {
        let mut polled = Pin::new(&mut self.inner).poll_frame(cx);
        if let Poll::Ready(Some(Ok(frame))) = &mut polled
            && let Some(trailers) = frame.trailers_mut()
        {
            super::status::tidy(trailers);
            let code = trailers
                .get("grpc-status")
                .and_then(|v| v.to_str().ok())
                .and_then(|v| v.parse::<i32>().ok())
                .map_or(tonic::Code::Unknown, tonic::Code::from);
            let message = trailers
                .get("grpc-message")
                .and_then(|v| v.to_str().ok())
                .unwrap_or("")
                .to_string();
            self.code = Some(code);
            self.finish(code, &message);
        }
        polled
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.inner.size_hint()
    }
}

/// A request body that refuses a gRPC message longer than the limit as
/// soon as its 5-byte prefix arrives, with RESOURCE_EXHAUSTED naming the
/// limit (tonic's own check, kept as a second line, says OUT_OF_RANGE).
struct SizeLimited {
    inner: Body,
    limit: u32,
    /// Bytes of the current message prefix seen so far.
    prefix: [u8; 5],
    prefix_len: usize,
    /// Bytes of the current message body still to pass.
    remaining: u64,
}

impl SizeLimited {
    fn new(inner: Body, limit: u32) -> Self {
        SizeLimited {
            inner,
            limit,
            prefix: [0; 5],
            prefix_len: 0,
            remaining: 0,
        }
    }

    /// Walks the message framing through one data chunk.
    fn check(&mut self, mut data: &[u8]) -> Result<(), tonic::Status> {
        while !data.is_empty() {
            if self.remaining > 0 {
                let n = usize::try_from(self.remaining)
                    .unwrap_or(usize::MAX)
                    .min(data.len());
                self.remaining -= n as u64;
                data = &data[n..];
                continue;
            }
            let n = (5 - self.prefix_len).min(data.len());
            self.prefix[self.prefix_len..self.prefix_len + n].copy_from_slice(&data[..n]);
            self.prefix_len += n;
            data = &data[n..];
            if self.prefix_len == 5 {
                self.prefix_len = 0;
                let len = u32::from_be_bytes([
                    self.prefix[1],
                    self.prefix[2],
                    self.prefix[3],
                    self.prefix[4],
                ]);
                if len > self.limit {
                    return Err(super::refused(
                        tonic::Code::ResourceExhausted,
                        "MESSAGE_SIZE_LIMIT",
                        format!(
                            "message size limit: the request message has {len} bytes, more \
                             than max_message_bytes = {}",
                            self.limit
                        ),
                    ));
                }
                self.remaining = u64::from(len);
            }
        }
        Ok(())
    }
}

impl http_body::Body for SizeLimited {
    type Data = bytes::Bytes;
    type Error = tonic::Status;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Self::Data>, Self::Error>>> {
        let polled = Pin::new(&mut self.inner).poll_frame(cx);
        if let Poll::Ready(Some(Ok(frame))) = &polled
            && let Some(data) = frame.data_ref()
            && let Err(status) = self.check(data.chunk())
        {
            return Poll::Ready(Some(Err(status)));
        }
        polled
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.inner.size_hint()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{ClientCertConfig, TokenConfig};

    fn auth() -> Authenticator {
        Authenticator::new(&SecurityConfig {
            tokens: vec![TokenConfig {
                name: "hmi-1".into(),
                role: Role::Operator,
                sha256: hash_token("s3cret").to_uppercase(),
            }],
            clients: vec![ClientCertConfig {
                subject_cn: "hmi-2".into(),
                role: Role::Viewer,
            }],
            ..Default::default()
        })
    }

    fn bearer(t: &str) -> http::HeaderValue {
        http::HeaderValue::from_str(&format!("Bearer {t}")).unwrap()
    }

    fn conn(cn: Option<&str>) -> ConnInfo {
        ConnInfo {
            local_addr: None,
            remote_addr: None,
            tls: true,
            peer_cn: cn.map(str::to_string),
            calls: None,
        }
    }

    #[test]
    fn hashes_are_sha256_hex() {
        // printf %s abc | sha256sum
        assert_eq!(
            hash_token("abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        assert!(parse_sha256(&hash_token("x")).is_some());
        assert!(parse_sha256("abc").is_none());
        assert!(parse_sha256(&"g".repeat(64)).is_none());
    }

    #[test]
    fn tokens_then_certificates_identify_callers() {
        let a = auth();
        let id = a.identify(Some(&bearer("s3cret")), None).unwrap();
        assert_eq!((id.name.as_str(), id.role), ("hmi-1", Role::Operator));
        assert_eq!(
            a.identify(Some(&bearer("wrong")), None),
            Err(Refusal::Unauthenticated("unknown token".into()))
        );
        let e = a.identify(None, None).unwrap_err();
        assert!(e.to_string().contains("missing bearer token"), "{e}");
        let e = a
            .identify(Some(&http::HeaderValue::from_static("Basic x")), None)
            .unwrap_err();
        assert!(matches!(e, Refusal::Unauthenticated(_)), "{e}");
        let id = a.identify(None, Some(&conn(Some("hmi-2")))).unwrap();
        assert_eq!((id.name.as_str(), id.role), ("hmi-2", Role::Viewer));
        let e = a.identify(None, Some(&conn(Some("stranger")))).unwrap_err();
        assert!(matches!(e, Refusal::PermissionDenied(_)), "{e}");
        // A token decides over the certificate.
        let id = a
            .identify(Some(&bearer("s3cret")), Some(&conn(Some("hmi-2"))))
            .unwrap();
        assert_eq!(id.name, "hmi-1");
    }

    #[test]
    fn without_identities_everyone_is_engineer() {
        let a = Authenticator::new(&SecurityConfig::default());
        assert!(!a.enabled());
        assert_eq!(a.identify(None, None).unwrap().role, Role::Engineer);
    }

    #[test]
    fn size_limit_reads_prefixes_across_chunks() {
        let mut s = SizeLimited::new(Body::empty(), 10);
        // A 3-byte message, then the prefix of an 11-byte one split in two.
        s.check(&[0, 0, 0, 0, 3, 1, 2]).unwrap();
        s.check(&[3, 0, 0]).unwrap();
        let e = s.check(&[0, 0, 11]).unwrap_err();
        assert_eq!(e.code(), tonic::Code::ResourceExhausted);
        assert!(e.message().contains("max_message_bytes = 10"), "{e:?}");
        let mut s = SizeLimited::new(Body::empty(), 10);
        s.check(&[0, 0, 0, 0, 10]).unwrap();
        s.check(&[0; 10]).unwrap();
        s.check(&[0, 0, 0, 0, 0]).unwrap();
    }
}
