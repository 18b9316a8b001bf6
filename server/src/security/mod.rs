//! Security of the gRPC API, applied in one place for every RPC (a tower
//! layer in front of all services, and the TLS acceptor):
//!
//! - [`roles`]: the one table classifying every RPC by the role it needs;
//! - [`auth`]: identities from bearer tokens or client certificates, the
//!   role check, limits and the audit log (`cangate::audit`);
//! - [`limits`]: per-client concurrency, rate and stream limits;
//! - [`tls`]: TLS/mTLS with certificates reloaded on SIGHUP;
//! - [`config`]: the `[security]` configuration section.

pub mod auth;
pub mod config;
pub mod limits;
pub mod roles;
pub mod tls;

pub use auth::{SecurityLayer, SecurityService};
pub use config::SecurityConfig;
pub use tls::{ConnInfo, TlsError, TlsReloader};

use serde::{Deserialize, Serialize};

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

/// Who made a call; put into the request extensions by the security
/// layer, so services can name the caller (`request.extensions()`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Identity {
    /// Token name, certificate CN, or `anonymous` (authentication off or a
    /// public RPC).
    pub name: String,
    /// Its role.
    pub role: Role,
    /// How it was established: `token`, `certificate` or `none`.
    pub method: &'static str,
}
