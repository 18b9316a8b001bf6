//! The one place where domain errors become gRPC statuses.

use cangate_can::{FrameError, SendError, SendFailure};
use cangate_canopen::sdo::SdoError;
use prost::Message;
use tonic::{Code, Status};

/// An error a request can end with, before it becomes a [`Status`].
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// A named thing (bus, node, axis) does not exist. The name is the
    /// caller's: only its start is quoted.
    #[error("{kind} {} not found{hint}", quote_prefix(.name))]
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
    /// The caller is known but may not do this (e.g. use another
    /// identity's lease).
    #[error("{0}")]
    PermissionDenied(String),
    /// The bus failed while carrying out the request.
    #[error("{0}")]
    Unavailable(String),
    /// A value beyond a configured limit (soft limit, maximum velocity).
    #[error("{0}")]
    OutOfRange(String),
    /// The device did not follow in time, or a wait ran out.
    #[error("{0}")]
    DeadlineExceeded(String),
    /// A command was cut short (superseded, fault).
    #[error("{0}")]
    Aborted(String),
    /// The server is shutting down.
    #[error("the gateway is shutting down")]
    ShuttingDown,
    /// An SDO transfer failed.
    #[error("node {node}: {error}")]
    Sdo {
        /// Node id.
        node: u8,
        /// The failure.
        error: SdoError,
    },
}

/// At most this many bytes of a caller-chosen string go into a message.
pub const QUOTE_BYTES: usize = 64;

/// A caller-chosen string quoted for a message: in full when short, else
/// its start and its length, so that no message grows with the caller's
/// input.
pub fn quote_prefix(s: &str) -> String {
    if s.len() <= QUOTE_BYTES {
        return format!("{s:?}");
    }
    let mut end = QUOTE_BYTES;
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    format!("{:?}… ({} bytes)", &s[..end], s.len())
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

impl From<cangate_axis::CommandError> for ApiError {
    fn from(e: cangate_axis::CommandError) -> Self {
        use cangate_axis::CommandError as E;
        match e {
            E::OutOfRange(m) => ApiError::OutOfRange(m),
            E::InvalidArgument(m) => ApiError::InvalidArgument(m),
            E::FailedPrecondition(m) => ApiError::FailedPrecondition(m),
        }
    }
}

impl From<cangate_axis::lease::LeaseError> for ApiError {
    fn from(e: cangate_axis::lease::LeaseError) -> Self {
        match e {
            cangate_axis::lease::LeaseError::OtherIdentity { .. } => {
                ApiError::PermissionDenied(e.to_string())
            }
            _ => ApiError::FailedPrecondition(e.to_string()),
        }
    }
}

/// The gRPC code for an SDO abort code: the class of the abort decides.
fn sdo_code(error: &SdoError) -> Code {
    let abort = error.abort_code().get();
    match error {
        SdoError::Timeout { .. } => Code::DeadlineExceeded,
        SdoError::Protocol { .. } | SdoError::Cancelled { .. } => Code::Aborted,
        SdoError::Aborted { .. } => match abort {
            0x0602_0000 | 0x0609_0011 => Code::NotFound,
            0x0607_0010..=0x0607_0013 => Code::InvalidArgument,
            0x0609_0030..=0x0609_0036 => Code::OutOfRange,
            0x0601_0000..=0x0601_0002 | 0x0800_0020..=0x0800_0024 => Code::FailedPrecondition,
            _ => Code::Aborted,
        },
    }
}

fn sdo_status(error: &SdoError, message: String) -> Status {
    let abort = error.abort_code();
    let addr = match error {
        SdoError::Aborted { addr, .. }
        | SdoError::Protocol { addr, .. }
        | SdoError::Timeout { addr, .. }
        | SdoError::Cancelled { addr, .. } => *addr,
    };
    let details = cangate_proto::v1::SdoAbortDetails {
        code: abort.get(),
        name: abort.name().to_string(),
        index: addr.index as u32,
        subindex: addr.sub as u32,
        from_node: matches!(error, SdoError::Aborted { .. }),
    };
    let mut status = Status::with_details(sdo_code(error), message, details.encode_to_vec().into());
    let text = format!("0x{:08X} {}", abort.get(), abort.name());
    if let Ok(v) = text.parse() {
        status.metadata_mut().insert("cangate-sdo-abort", v);
    }
    status
}

impl From<ApiError> for Status {
    fn from(e: ApiError) -> Self {
        if let ApiError::Sdo { error, .. } = &e {
            return sdo_status(error, e.to_string());
        }
        let code = match &e {
            ApiError::NotFound { .. } => Code::NotFound,
            ApiError::InvalidArgument(_) => Code::InvalidArgument,
            ApiError::FailedPrecondition(_) => Code::FailedPrecondition,
            ApiError::PermissionDenied(_) => Code::PermissionDenied,
            ApiError::Unavailable(_) | ApiError::ShuttingDown => Code::Unavailable,
            ApiError::OutOfRange(_) => Code::OutOfRange,
            ApiError::DeadlineExceeded(_) => Code::DeadlineExceeded,
            ApiError::Aborted(_) => Code::Aborted,
            ApiError::Sdo { error, .. } => sdo_code(error),
        };
        Status::new(code, e.to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn caller_names_are_quoted_by_their_start_only() {
        let long = "x".repeat(20_000);
        let s = Status::from(ApiError::NotFound {
            kind: "axis",
            name: long,
            hint: " (axes: X)".into(),
        });
        assert_eq!(s.code(), Code::NotFound);
        assert!(s.message().len() < 200, "{}", s.message());
        assert!(s.message().contains("(20000 bytes)"), "{}", s.message());
        // Multi-byte characters are cut at a boundary.
        let q = quote_prefix(&"é".repeat(100));
        assert!(q.contains("(200 bytes)"), "{q}");
        assert_eq!(quote_prefix("X"), "\"X\"");
    }
}
