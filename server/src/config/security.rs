//! The `[security]` section of the configuration: tokens, client
//! certificate names, TLS files and per-client limits.

use serde::{Deserialize, Serialize};
use std::collections::HashSet;
use std::path::PathBuf;

/// Security settings (`[security]`).
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SecurityConfig {
    /// Allow listening on a non-loopback address without authentication
    /// (no `tokens` and no `clients`). Logged as a warning at every start.
    #[serde(default)]
    pub insecure: bool,
    /// Bearer tokens (`[[security.tokens]]`). With none here and no
    /// `clients`, authentication is off and every caller is `engineer`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tokens: Vec<TokenConfig>,
    /// Client certificate subject CNs and their roles
    /// (`[[security.clients]]`); needs `[security.tls] client_ca`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub clients: Vec<ClientCertConfig>,
    /// TLS for the gRPC listener (`[security.tls]`); absent: plaintext.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tls: Option<TlsConfig>,
    /// Per-client limits (`[security.limits]`).
    #[serde(default)]
    pub limits: LimitsConfig,
    /// Viewers may stop axes too (`Stop`, `QuickStop`, `StopAxes`): a
    /// wall-mounted status panel with a viewer token then has a working
    /// STOP ALL. Off by default: a viewer token is read-only. Nothing else
    /// a viewer may call changes.
    #[serde(default)]
    pub viewers_may_stop: bool,
}

/// One bearer token: who it is, its role, and the SHA-256 of the token
/// (the token itself is never stored).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TokenConfig {
    /// Identity name, shown in the audit log and in refusals (unique).
    pub name: String,
    /// `viewer`, `operator` or `engineer`.
    pub role: Role,
    /// Lower- or upper-case hex SHA-256 of the token's bytes
    /// (`cangate hash-token`, or `printf %s TOKEN | sha256sum`).
    pub sha256: String,
}

/// A client certificate subject common name and its role.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClientCertConfig {
    /// The subject CN of a client certificate signed by `tls.client_ca`.
    pub subject_cn: String,
    /// `viewer`, `operator` or `engineer`.
    pub role: Role,
}

/// TLS files (PEM). Re-read on SIGHUP.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TlsConfig {
    /// Server certificate chain (leaf first).
    pub cert: PathBuf,
    /// Server private key (PKCS#8, PKCS#1 or SEC1).
    pub key: PathBuf,
    /// CA certificate(s) that sign client certificates; set: mTLS.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub client_ca: Option<PathBuf>,
    /// With `client_ca`: refuse connections without a client certificate
    /// (otherwise a client may connect without one and use a token).
    #[serde(default)]
    pub require_client_cert: bool,
}

/// Per-client limits; a client is an identity when authentication is on,
/// else a peer IP address. 0 turns a limit off.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimitsConfig {
    /// Calls of one client being handled at once (a stream counts until its
    /// handler has returned the stream).
    #[serde(default = "default_concurrent")]
    pub max_concurrent_requests_per_client: u32,
    /// Sustained calls per second of one client (token bucket rate).
    /// `SendFrames` calls are not counted here but by their frames
    /// (`raw_frames_per_second_per_client`).
    #[serde(default = "default_rate")]
    pub requests_per_second_per_client: u32,
    /// Calls one client may make at once above the rate (bucket size).
    #[serde(default = "default_burst")]
    pub burst: u32,
    /// Sustained raw frames per second one client may send through
    /// `SendFrames` and `Attach` (token bucket rate, one token per frame);
    /// a batch beyond it is refused as a whole (RESOURCE_EXHAUSTED,
    /// FRAME_RATE_LIMIT).
    #[serde(default = "default_frame_rate")]
    pub raw_frames_per_second_per_client: u32,
    /// Raw frames one client may send at once above that rate (bucket
    /// size; also the largest batch that can pass).
    #[serde(default = "default_frame_burst")]
    pub raw_frame_burst: u32,
    /// Server-streaming calls one client may hold open.
    #[serde(default = "default_streams")]
    pub max_streams_per_client: u32,
    /// Largest request message in bytes (an SDO domain write carries its
    /// data in one message).
    #[serde(default = "default_message_bytes")]
    pub max_message_bytes: u32,
    /// Sustained stops (`Stop`, `QuickStop`, `StopAxes`) per second of one
    /// client: a budget of their own that other calls never use up.
    #[serde(default = "default_stop_rate")]
    pub stop_requests_per_second_per_client: u32,
    /// Stops one client may make at once above their rate.
    #[serde(default = "default_stop_burst")]
    pub stop_burst: u32,
    /// Stops of one client being handled at once (a waited stop counts
    /// until the axis is at rest).
    #[serde(default = "default_concurrent_stops")]
    pub max_concurrent_stops_per_client: u32,
    /// SDO requests one client may have queued or running with one node
    /// (0: no limit): one client cannot fill a node's SDO channel for
    /// everyone else. Clients without an identity are told apart by their
    /// address, so many unauthenticated clients on one host share it.
    #[serde(default = "default_sdo_per_node")]
    pub sdo_requests_per_client_and_node: u32,
    /// Largest `queue_length` of one stream, in events; a larger request
    /// is served with this many.
    #[serde(default = "default_stream_queue")]
    pub max_stream_queue: u32,
    /// Sum of the `queue_length`s of one client's open streams; a stream
    /// beyond it is refused (RESOURCE_EXHAUSTED).
    #[serde(default = "default_stream_queue_per_client")]
    pub max_stream_queue_per_client: u32,
    /// Longest caller-chosen name (`client_name`), in bytes (1..=4096).
    #[serde(default = "default_name_bytes")]
    pub max_name_bytes: u32,
    /// Refused calls (bad or missing credentials) one peer address may
    /// make per second; beyond this and `refusal_burst`, its calls are
    /// refused at once, without checking credentials or writing an audit
    /// line each.
    #[serde(default = "default_refusal_rate")]
    pub refusals_per_second_per_peer: u32,
    /// Refused calls one peer address may make at once above the rate.
    #[serde(default = "default_refusal_burst")]
    pub refusal_burst: u32,
    /// Audit lines for refused calls per second (all peers together);
    /// those beyond are counted and summed up per peer in one line every
    /// `audit_summary_interval_s`.
    #[serde(default = "default_audit_refusals")]
    pub audit_refusals_per_second: u32,
    /// Seconds between the summaries of refusals left out of the audit log.
    #[serde(default = "default_audit_summary")]
    pub audit_summary_interval_s: u32,
    /// Seconds a connection may take from accept to a complete HTTP/2
    /// preface (after TLS, which is bounded by the same time); then it is
    /// closed.
    #[serde(default = "default_handshake_s")]
    pub handshake_timeout_s: u32,
    /// Seconds a connection may stay open with no call in progress (no
    /// request, no open stream); then it is closed. 0: never.
    #[serde(default = "default_idle_s")]
    pub idle_connection_timeout_s: u32,
}

fn default_concurrent() -> u32 {
    64
}
fn default_rate() -> u32 {
    200
}
fn default_burst() -> u32 {
    400
}
fn default_streams() -> u32 {
    32
}
fn default_message_bytes() -> u32 {
    4 * 1024 * 1024
}
fn default_frame_rate() -> u32 {
    5_000
}
fn default_frame_burst() -> u32 {
    10_000
}
fn default_stop_rate() -> u32 {
    50
}
fn default_stop_burst() -> u32 {
    100
}
fn default_concurrent_stops() -> u32 {
    32
}
fn default_stream_queue() -> u32 {
    65_536
}
fn default_stream_queue_per_client() -> u32 {
    262_144
}
fn default_name_bytes() -> u32 {
    128
}
fn default_refusal_rate() -> u32 {
    10
}
fn default_refusal_burst() -> u32 {
    20
}
fn default_audit_refusals() -> u32 {
    10
}
fn default_audit_summary() -> u32 {
    10
}
fn default_handshake_s() -> u32 {
    10
}
fn default_sdo_per_node() -> u32 {
    8
}
fn default_idle_s() -> u32 {
    300
}

impl Default for LimitsConfig {
    fn default() -> Self {
        LimitsConfig {
            max_concurrent_requests_per_client: default_concurrent(),
            requests_per_second_per_client: default_rate(),
            burst: default_burst(),
            raw_frames_per_second_per_client: default_frame_rate(),
            raw_frame_burst: default_frame_burst(),
            max_streams_per_client: default_streams(),
            max_message_bytes: default_message_bytes(),
            stop_requests_per_second_per_client: default_stop_rate(),
            stop_burst: default_stop_burst(),
            max_concurrent_stops_per_client: default_concurrent_stops(),
            sdo_requests_per_client_and_node: default_sdo_per_node(),
            max_stream_queue: default_stream_queue(),
            max_stream_queue_per_client: default_stream_queue_per_client(),
            max_name_bytes: default_name_bytes(),
            refusals_per_second_per_peer: default_refusal_rate(),
            refusal_burst: default_refusal_burst(),
            audit_refusals_per_second: default_audit_refusals(),
            audit_summary_interval_s: default_audit_summary(),
            handshake_timeout_s: default_handshake_s(),
            idle_connection_timeout_s: default_idle_s(),
        }
    }
}

impl SecurityConfig {
    /// True when callers must authenticate (tokens or client names given).
    pub fn authentication(&self) -> bool {
        !self.tokens.is_empty() || !self.clients.is_empty()
    }

    /// Checks what serde cannot.
    pub fn validate(&self) -> Result<(), String> {
        let mut names = HashSet::new();
        let mut hashes = HashSet::new();
        for t in &self.tokens {
            if t.name.is_empty() {
                return Err("[[security.tokens]]: a token has an empty name".into());
            }
            if !names.insert(t.name.as_str()) {
                return Err(format!(
                    "[[security.tokens]]: name {:?} is used twice",
                    t.name
                ));
            }
            if parse_sha256(&t.sha256).is_none() {
                return Err(format!(
                    "[[security.tokens]] {:?}: sha256 must be 64 hex digits (the SHA-256 of the \
                     token: `cangate hash-token` or `printf %s TOKEN | sha256sum`)",
                    t.name
                ));
            }
            if !hashes.insert(t.sha256.to_ascii_lowercase()) {
                return Err(format!(
                    "[[security.tokens]] {:?}: the same token hash is configured twice",
                    t.name
                ));
            }
        }
        let mut cns = HashSet::new();
        for c in &self.clients {
            if c.subject_cn.is_empty() {
                return Err("[[security.clients]]: empty subject_cn".into());
            }
            if !cns.insert(c.subject_cn.as_str()) {
                return Err(format!(
                    "[[security.clients]]: subject_cn {:?} is configured twice",
                    c.subject_cn
                ));
            }
        }
        let mtls = self.tls.as_ref().is_some_and(|t| t.client_ca.is_some());
        if !self.clients.is_empty() && !mtls {
            return Err(
                "[[security.clients]] maps client certificates, which needs [security.tls] \
                 with client_ca"
                    .into(),
            );
        }
        if let Some(t) = &self.tls
            && t.require_client_cert
            && t.client_ca.is_none()
        {
            return Err("[security.tls] require_client_cert = true needs client_ca".into());
        }
        let l = &self.limits;
        if l.burst == 0 && l.requests_per_second_per_client > 0 {
            return Err(
                "[security.limits] burst must be at least 1 when requests_per_second_per_client \
                 is set"
                    .into(),
            );
        }
        if l.raw_frame_burst == 0 && l.raw_frames_per_second_per_client > 0 {
            return Err("[security.limits] raw_frame_burst must be at least 1 when \
                 raw_frames_per_second_per_client is set"
                .into());
        }
        if l.stop_burst == 0 && l.stop_requests_per_second_per_client > 0 {
            return Err("[security.limits] stop_burst must be at least 1 when \
                 stop_requests_per_second_per_client is set"
                .into());
        }
        if l.refusal_burst == 0 && l.refusals_per_second_per_peer > 0 {
            return Err("[security.limits] refusal_burst must be at least 1 when \
                 refusals_per_second_per_peer is set"
                .into());
        }
        if l.max_stream_queue == 0 || l.max_stream_queue_per_client < l.max_stream_queue {
            return Err(format!(
                "[security.limits] max_stream_queue must be at least 1 and at most \
                 max_stream_queue_per_client ({} and {} given)",
                l.max_stream_queue, l.max_stream_queue_per_client
            ));
        }
        if !(1..=4096).contains(&l.max_name_bytes) {
            return Err(format!(
                "[security.limits] max_name_bytes must be 1..=4096, got {}",
                l.max_name_bytes
            ));
        }
        if !(1..=3600).contains(&l.handshake_timeout_s)
            || !(1..=3600).contains(&l.audit_summary_interval_s)
        {
            return Err(format!(
                "[security.limits] handshake_timeout_s and audit_summary_interval_s must be \
                 1..=3600 s, got {} and {}",
                l.handshake_timeout_s, l.audit_summary_interval_s
            ));
        }
        Ok(())
    }
}

/// What a caller may do. Ordered: `Engineer` ⊇ `Operator` ⊇ `Viewer`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// Read and stream only.
    Viewer,
    /// Axis commands, handwheel modes, control leases.
    Operator,
    /// SDO/PDO writes, NMT, raw frames, the simulator.
    Engineer,
}

impl Role {
    /// The name used in the configuration and in messages.
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Viewer => "viewer",
            Role::Operator => "operator",
            Role::Engineer => "engineer",
        }
    }
}

impl std::fmt::Display for Role {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Parses a hex SHA-256 digest (64 hex digits, either case).
pub fn parse_sha256(hex: &str) -> Option<[u8; 32]> {
    let hex = hex.as_bytes();
    if hex.len() != 64 {
        return None;
    }
    let mut out = [0u8; 32];
    for (i, pair) in hex.chunks_exact(2).enumerate() {
        let digit = |c: u8| (c as char).to_digit(16);
        out[i] = u8::try_from(digit(pair[0])? * 16 + digit(pair[1])?).ok()?;
    }
    Some(out)
}
