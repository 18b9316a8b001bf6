//! Security of the gRPC API, applied in one place for every RPC (a tower
//! layer in front of all services, and the TLS acceptor):
//!
//! - [`roles`]: the one table classifying every RPC by the role it needs;
//! - [`auth`]: identities from bearer tokens or client certificates, the
//!   role check, limits and the audit log (`cangate::audit`);
//! - [`limits`]: per-client concurrency, rate and stream limits;
//! - [`slots`]: connection slots of the text-protocol endpoints;
//! - [`tls`]: TLS/mTLS with certificates reloaded on SIGHUP;
//! - [`status`]: the final status of every response tidied in one place
//!   (undecodable requests are INVALID_ARGUMENT, messages stay short).

pub mod auth;
pub mod limits;
pub mod roles;
pub mod slots;
pub mod status;
pub mod tls;

pub use crate::config::{Role, SecurityConfig};
pub use auth::{Refusal, SecurityLayer, SecurityService, SessionAdmission};
pub use limits::{FrameBudget, QueueReservation, RequestBudget, StopOverBudget, StreamQueueBudget};
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
    stream_queue_from(
        req.extensions().get::<StreamQueueBudget>(),
        requested,
        default,
        max,
    )
}

/// [`stream_queue`] with the budget taken from the request beforehand (a
/// bidirectional stream whose first message asks for the queue).
///
/// # Errors
/// As [`stream_queue`].
pub fn stream_queue_from(
    budget: Option<&StreamQueueBudget>,
    requested: u32,
    default: usize,
    max: usize,
) -> Result<(usize, Option<QueueReservation>), tonic::Status> {
    match budget {
        Some(budget) => budget
            .reserve(requested, default)
            .map(|(n, r)| (n.min(max), Some(r)))
            .map_err(|e| refused(tonic::Code::ResourceExhausted, "STREAM_QUEUE_LIMIT", e.0)),
        None => Ok((
            match requested as usize {
                0 => default,
                n => n.min(max),
            },
            None,
        )),
    }
}

/// A refusal of the security layer as a status with the richer error
/// model's `ErrorInfo` (domain `cangate.v1`, `reason`), like every other
/// error of the gateway, so that clients can match on the reason.
pub fn refused(code: tonic::Code, reason: &str, message: impl Into<String>) -> tonic::Status {
    use tonic_types::{ErrorDetails, StatusExt};
    tonic::Status::with_error_details(
        code,
        message,
        ErrorDetails::with_error_info(reason, "cangate.v1", std::collections::HashMap::new()),
    )
}

/// The reason of a limit refusal, from the limit its message names.
pub(crate) fn limit_reason(message: &str) -> &'static str {
    [
        ("concurrency limit", "CONCURRENCY_LIMIT"),
        ("rate limit", "RATE_LIMIT"),
        ("frame rate limit", "FRAME_RATE_LIMIT"),
        ("stream limit", "STREAM_LIMIT"),
        ("message size limit", "MESSAGE_SIZE_LIMIT"),
    ]
    .into_iter()
    .find(|(prefix, _)| message.starts_with(prefix))
    .map_or("RESOURCE_EXHAUSTED", |(_, reason)| reason)
}
