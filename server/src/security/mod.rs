//! Security of the gRPC API, applied in one place for every RPC (a tower
//! layer in front of all services, and the TLS acceptor):
//!
//! - [`roles`]: the one table classifying every RPC by the role it needs;
//! - [`auth`]: identities from bearer tokens or client certificates, the
//!   role check, limits and the audit log (`cangate::audit`);
//! - [`limits`]: per-client concurrency, rate and stream limits;
//! - [`tls`]: TLS/mTLS with certificates reloaded on SIGHUP;
//! - [`status`]: the final status of every response tidied in one place
//!   (undecodable requests are INVALID_ARGUMENT, messages stay short).

pub mod auth;
pub mod limits;
pub mod roles;
pub mod status;
pub mod tls;

pub use crate::config::{Role, SecurityConfig};
pub use auth::{SecurityLayer, SecurityService};
pub use limits::{QueueReservation, StreamQueueBudget};
pub use tls::{ConnInfo, TlsError, TlsReloader};

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

/// The queue length of a new stream asking for `requested` events (0: the
/// service's `default`), within the caller's budget (see
/// [`StreamQueueBudget`]); the reservation must be held while the stream
/// is open. Without a budget (a call that did not pass the security
/// layer) the request is only capped at `max`.
///
/// # Errors
/// RESOURCE_EXHAUSTED when the caller's open streams hold its whole
/// queue budget.
pub fn stream_queue<T>(
    req: &tonic::Request<T>,
    requested: u32,
    default: usize,
    max: usize,
) -> Result<(usize, Option<QueueReservation>), tonic::Status> {
    match req.extensions().get::<StreamQueueBudget>() {
        Some(budget) => budget
            .reserve(requested, default)
            .map(|(n, r)| (n.min(max), Some(r)))
            .map_err(|e| tonic::Status::resource_exhausted(e.0)),
        None => Ok((
            match requested as usize {
                0 => default,
                n => n.min(max),
            },
            None,
        )),
    }
}
