//! The one place where domain errors become gRPC statuses.

use cangate_can::{FrameError, SendError, SendFailure};
use tonic::{Code, Status};

/// An error a request can end with, before it becomes a [`Status`].
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// A named thing (bus, node, axis) does not exist.
    #[error("{kind} {name:?} not found{hint}")]
    NotFound {
        /// What kind of thing.
        kind: &'static str,
        /// The name asked for.
        name: String,
        /// Extra help, e.g. the names that do exist.
        hint: String,
    },
    /// The request is malformed.
    #[error("{0}")]
    InvalidArgument(String),
    /// The request is valid but the system is not in a state to do it.
    #[error("{0}")]
    FailedPrecondition(String),
    /// The bus failed while carrying out the request.
    #[error("{0}")]
    Unavailable(String),
    /// The server is shutting down.
    #[error("the gateway is shutting down")]
    ShuttingDown,
}

impl ApiError {
    /// A malformed frame in a batch.
    pub fn bad_frame(index: usize, err: impl std::fmt::Display) -> Self {
        ApiError::InvalidArgument(format!("frame {index}: {err}"))
    }
}

impl From<FrameError> for ApiError {
    fn from(e: FrameError) -> Self {
        ApiError::InvalidArgument(e.to_string())
    }
}

impl From<SendFailure> for ApiError {
    fn from(f: SendFailure) -> Self {
        match &f.error {
            SendError::FdNotSupported(_) => ApiError::InvalidArgument(format!(
                "{}; send classic frames or enable fd in the bus configuration",
                f.error
            )),
            SendError::BusOff(_) | SendError::Down(_) if f.sent == 0 => {
                ApiError::FailedPrecondition(format!("{}; nothing was sent", f.error))
            }
            _ => ApiError::Unavailable(f.to_string()),
        }
    }
}

impl From<ApiError> for Status {
    fn from(e: ApiError) -> Self {
        let code = match &e {
            ApiError::NotFound { .. } => Code::NotFound,
            ApiError::InvalidArgument(_) => Code::InvalidArgument,
            ApiError::FailedPrecondition(_) => Code::FailedPrecondition,
            ApiError::Unavailable(_) | ApiError::ShuttingDown => Code::Unavailable,
        };
        Status::new(code, e.to_string())
    }
}
