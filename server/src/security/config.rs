//! The `[security]` section of the configuration: tokens, client
//! certificate names, TLS files and per-client limits.

use super::Role;
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
    #[serde(default = "default_rate")]
    pub requests_per_second_per_client: u32,
    /// Calls one client may make at once above the rate (bucket size).
    #[serde(default = "default_burst")]
    pub burst: u32,
    /// Server-streaming calls one client may hold open.
    #[serde(default = "default_streams")]
    pub max_streams_per_client: u32,
    /// Largest request message in bytes (an SDO domain write carries its
    /// data in one message).
    #[serde(default = "default_message_bytes")]
    pub max_message_bytes: u32,
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

impl Default for LimitsConfig {
    fn default() -> Self {
        LimitsConfig {
            max_concurrent_requests_per_client: default_concurrent(),
            requests_per_second_per_client: default_rate(),
            burst: default_burst(),
            max_streams_per_client: default_streams(),
            max_message_bytes: default_message_bytes(),
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
            if super::auth::parse_sha256(&t.sha256).is_none() {
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
        if self.limits.burst == 0 && self.limits.requests_per_second_per_client > 0 {
            return Err(
                "[security.limits] burst must be at least 1 when requests_per_second_per_client \
                 is set"
                    .into(),
            );
        }
        Ok(())
    }
}
