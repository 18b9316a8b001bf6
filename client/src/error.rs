//! The client's error: transport, refusals, SDO aborts, timeouts, each
//! decoded from the gateway's richer error model (a `google.rpc.Status`
//! with an `ErrorInfo` and, for SDO errors, a `cangate.v1.SdoAbortDetails`
//! in `grpc-status-details-bin`; see the top of `canopen.proto`).

use crate::pb;
use prost::Message;
use std::collections::BTreeMap;
use std::fmt;
use std::time::Duration;
use tonic::Code;

/// `ErrorInfo.domain` of the gateway's errors.
pub const ERROR_DOMAIN: &str = "cangate.v1";

/// Type URL of the `cangate.v1.SdoAbortDetails` detail of SDO errors.
pub const SDO_ABORT_DETAILS_TYPE_URL: &str = "type.googleapis.com/cangate.v1.SdoAbortDetails";

/// Everything a call of this crate can fail with.
///
/// `Display` gives one line without repeating causes; [`std::error::Error::source`]
/// is always `None` (the causes are already in the line).
#[derive(Debug)]
#[non_exhaustive]
pub enum Error {
    /// The gateway could not be reached, or the connection failed during
    /// the call (refused, reset, TLS, HTTP/2). Retrying later may help.
    Transport {
        /// What failed, with its causes ("cannot connect to
        /// http://127.0.0.1:1: tcp connect error: Connection refused").
        message: String,
    },
    /// Input refused on this side, before anything was sent: a malformed
    /// URL, unusable connection options, a node id outside 1..=127, an
    /// object address that does not parse, a value that does not fit.
    InvalidInput {
        /// What is wrong.
        message: String,
    },
    /// A named thing does not exist on the gateway (NOT_FOUND not caused
    /// by an SDO abort): bus, node, axis, handwheel, CANsmc master or
    /// slave, ...
    NotFound {
        /// The kind of thing ("axis", "bus", "CANsmc master"; from the
        /// `ErrorInfo` metadata, "" when the gateway did not say).
        kind: String,
        /// The name asked for (at most its first 64 bytes; "" when the
        /// gateway did not say).
        name: String,
        /// The gateway's message (it may list the names that exist).
        message: String,
        /// The status as received.
        status: Box<tonic::Status>,
    },
    /// An SDO transfer ended with an abort: sent by the node, or by the
    /// gateway for a protocol violation or a cancelled transfer. (A node
    /// that does not answer is [`Error::Timeout`].)
    SdoAbort {
        /// Node id.
        node: u8,
        /// Object index.
        index: u16,
        /// Sub-index.
        subindex: u8,
        /// The CiA 301 abort code (0x06020000).
        code: u32,
        /// Its CiA 301 name ("object does not exist in the object
        /// dictionary").
        name: String,
        /// True when the node sent the abort, false when the gateway did.
        by_node: bool,
        /// The status as received (its code is the abort's class:
        /// NOT_FOUND, INVALID_ARGUMENT, OUT_OF_RANGE, FAILED_PRECONDITION,
        /// ABORTED).
        status: Box<tonic::Status>,
    },
    /// No answer in time: DEADLINE_EXCEEDED from the gateway (an SDO
    /// timeout, a drive that did not follow, a wait that ran out), or this
    /// client's own request or connect timeout.
    Timeout {
        /// What timed out.
        message: String,
        /// The status when the gateway sent it; `None` for this client's
        /// own timeouts.
        status: Option<Box<tonic::Status>>,
    },
    /// The gateway refused or failed the call for any other reason.
    Refused {
        /// The gRPC code.
        code: Code,
        /// The `ErrorInfo.reason` ("LEASE_REQUIRED", "BUS_OFF",
        /// "SHUTTING_DOWN", ...); the code's name ("FAILED_PRECONDITION")
        /// when the status had no `ErrorInfo` (e.g. refusals of the
        /// security layer).
        reason: String,
        /// The gateway's message.
        message: String,
        /// The status as received.
        status: Box<tonic::Status>,
    },
}

impl std::error::Error for Error {}

/// The canonical name of a code ("FAILED_PRECONDITION").
pub fn code_name(code: Code) -> &'static str {
    match code {
        Code::Ok => "OK",
        Code::Cancelled => "CANCELLED",
        Code::Unknown => "UNKNOWN",
        Code::InvalidArgument => "INVALID_ARGUMENT",
        Code::DeadlineExceeded => "DEADLINE_EXCEEDED",
        Code::NotFound => "NOT_FOUND",
        Code::AlreadyExists => "ALREADY_EXISTS",
        Code::PermissionDenied => "PERMISSION_DENIED",
        Code::ResourceExhausted => "RESOURCE_EXHAUSTED",
        Code::FailedPrecondition => "FAILED_PRECONDITION",
        Code::Aborted => "ABORTED",
        Code::OutOfRange => "OUT_OF_RANGE",
        Code::Unimplemented => "UNIMPLEMENTED",
        Code::Internal => "INTERNAL",
        Code::Unavailable => "UNAVAILABLE",
        Code::DataLoss => "DATA_LOSS",
        Code::Unauthenticated => "UNAUTHENTICATED",
    }
}

/// What a code means for a cangate call, for people.
pub fn code_meaning(code: Code) -> &'static str {
    match code {
        Code::Ok => "no error",
        Code::Cancelled => "the call was cancelled",
        Code::Unknown => "an unknown error",
        Code::InvalidArgument => "the request is malformed; nothing was done",
        Code::DeadlineExceeded => "no answer in time",
        Code::NotFound => "the named thing does not exist",
        Code::AlreadyExists => "it already exists",
        Code::PermissionDenied => "the caller may not do this",
        Code::ResourceExhausted => "a limit was reached (rate, concurrency, queue); retry later",
        Code::FailedPrecondition => {
            "the request is valid but the system is not in a state to do it (control held by \
             someone else, axis not enabled, bus off, read-only object, ...)"
        }
        Code::Aborted => "the operation was cut short (superseded, fault, protocol violation)",
        Code::OutOfRange => "a value beyond a configured or device limit",
        Code::Unimplemented => "the gateway does not offer this call",
        Code::Internal => "an internal error of the gateway",
        Code::Unavailable => {
            "the gateway or the bus is unavailable (shutting down, bus failed); retry later"
        }
        Code::DataLoss => "data was lost",
        Code::Unauthenticated => "no valid credentials",
    }
}

impl Error {
    /// An [`Error::InvalidInput`].
    pub(crate) fn invalid(message: impl Into<String>) -> Error {
        Error::InvalidInput {
            message: message.into(),
        }
    }

    /// This client's own timeout of `what` after `after`.
    pub(crate) fn client_timeout(what: &str, after: Duration) -> Error {
        Error::Timeout {
            message: format!("{what}: no answer within {after:?}"),
            status: None,
        }
    }

    /// A failure to connect to `url`, from tonic's transport error.
    pub(crate) fn connect(url: &str, e: &(dyn std::error::Error + 'static)) -> Error {
        let chain = flatten(e);
        if chain_has_timeout(e) {
            Error::Timeout {
                message: format!("connecting to {url}: {chain}"),
                status: None,
            }
        } else {
            Error::Transport {
                message: format!("cannot connect to {url}: {chain}"),
            }
        }
    }

    /// The gRPC code: the gateway's for errors it sent,
    /// DEADLINE_EXCEEDED for this client's timeouts, `None` for transport
    /// and input errors.
    pub fn code(&self) -> Option<Code> {
        match self {
            Error::Transport { .. } | Error::InvalidInput { .. } => None,
            Error::NotFound { .. } => Some(Code::NotFound),
            Error::SdoAbort { status, .. } => Some(status.code()),
            Error::Timeout { .. } => Some(Code::DeadlineExceeded),
            Error::Refused { code, .. } => Some(*code),
        }
    }

    /// The status as received from the gateway (code, message, metadata,
    /// details), when the gateway answered.
    pub fn status(&self) -> Option<&tonic::Status> {
        match self {
            Error::NotFound { status, .. }
            | Error::SdoAbort { status, .. }
            | Error::Refused { status, .. } => Some(status),
            Error::Timeout { status, .. } => status.as_deref(),
            Error::Transport { .. } | Error::InvalidInput { .. } => None,
        }
    }

    /// The `ErrorInfo.reason` of a gateway error ("AXIS_NOT_FOUND",
    /// "SDO_ABORT", "LEASE_REQUIRED", ...), when it sent one.
    pub fn reason(&self) -> Option<String> {
        match self {
            Error::Refused { reason, .. } => Some(reason.clone()),
            _ => self.status().and_then(error_info).map(|i| i.reason),
        }
    }

    /// What the code means, for people (see [`code_meaning`]); "" for
    /// transport and input errors.
    pub fn meaning(&self) -> &'static str {
        self.code().map_or("", code_meaning)
    }

    /// True for errors worth retrying later: transport failures, timeouts,
    /// UNAVAILABLE and RESOURCE_EXHAUSTED.
    pub fn is_transient(&self) -> bool {
        matches!(self, Error::Transport { .. } | Error::Timeout { .. })
            || matches!(
                self.code(),
                Some(Code::Unavailable | Code::ResourceExhausted)
            )
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Transport { message } => write!(f, "transport error: {message}"),
            Error::InvalidInput { message } => write!(f, "invalid input: {message}"),
            Error::NotFound { message, .. } => write!(f, "{message}"),
            Error::SdoAbort {
                node,
                index,
                subindex,
                code,
                name,
                by_node,
                ..
            } => write!(
                f,
                "node {node}, object 0x{index:04X}:{subindex:02X}: SDO abort 0x{code:08X} {name} \
                 (sent by the {})",
                if *by_node { "node" } else { "gateway" }
            ),
            Error::Timeout { message, .. } => write!(f, "timed out: {message}"),
            Error::Refused {
                code,
                reason,
                message,
                ..
            } => {
                if message.is_empty() {
                    write!(f, "{}", code_meaning(*code))?;
                } else {
                    write!(f, "{message}")?;
                }
                if reason == code_name(*code) {
                    write!(f, " ({reason})")
                } else {
                    write!(f, " ({reason}, {})", code_name(*code))
                }
            }
        }
    }
}

/// The `google.rpc.ErrorInfo` of a status, if it carries one.
pub fn error_info(status: &tonic::Status) -> Option<tonic_types::ErrorInfo> {
    use tonic_types::StatusExt;
    status.get_details_error_info()
}

/// The `cangate.v1.SdoAbortDetails` an error status carries: the gateway
/// packs it as a `google.protobuf.Any` in the `google.rpc.Status` of
/// `grpc-status-details-bin` (the standard richer error model), next to a
/// `google.rpc.ErrorInfo`. `None` for errors not caused by an SDO transfer.
pub fn sdo_abort_details(status: &tonic::Status) -> Option<pb::SdoAbortDetails> {
    tonic_types::Status::decode(status.details())
        .ok()?
        .details
        .iter()
        .find(|any| any.type_url == SDO_ABORT_DETAILS_TYPE_URL)
        .and_then(|any| pb::SdoAbortDetails::decode(any.value.as_slice()).ok())
}

/// The messages of an error and its causes, joined with ": ", each once
/// (tonic's "transport error" wrappers add nothing and are left out).
fn flatten(e: &(dyn std::error::Error + 'static)) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut cur = Some(e);
    while let Some(err) = cur {
        let text = err.to_string();
        let useless = text.is_empty() || text == "transport error";
        if !useless && !parts.iter().any(|p| p.contains(&text)) {
            parts.push(text);
        }
        cur = err.source();
    }
    if parts.is_empty() {
        "transport error".to_string()
    } else {
        parts.join(": ")
    }
}

fn chain_has_timeout(e: &(dyn std::error::Error + 'static)) -> bool {
    let mut cur = Some(e);
    while let Some(err) = cur {
        if err.is::<tonic::TimeoutExpired>()
            || err
                .downcast_ref::<std::io::Error>()
                .is_some_and(|io| io.kind() == std::io::ErrorKind::TimedOut)
            || err.to_string().contains("timed out")
        {
            return true;
        }
        cur = err.source();
    }
    false
}

impl From<tonic::Status> for Error {
    fn from(status: tonic::Status) -> Self {
        let info = error_info(&status).filter(|i| i.domain == ERROR_DOMAIN);
        // Failures of this side's transport (no answer from the gateway):
        // tonic keeps their cause as the status's source.
        if info.is_none()
            && let Some(source) = std::error::Error::source(&status)
        {
            if chain_has_timeout(source) {
                return Error::Timeout {
                    message: flatten(source),
                    status: None,
                };
            }
            let chain = flatten(source);
            let first = status.message();
            let message = if first.is_empty() || first == "transport error" || chain.contains(first)
            {
                chain
            } else {
                format!("{first}: {chain}")
            };
            return Error::Transport { message };
        }
        let meta = |key: &str| {
            info.as_ref()
                .and_then(|i| i.metadata.get(key).cloned())
                .unwrap_or_default()
        };
        let message = status.message().to_string();
        let reason = info.as_ref().map(|i| i.reason.clone());
        if status.code() == Code::DeadlineExceeded {
            return Error::Timeout {
                message,
                status: Some(Box::new(status)),
            };
        }
        if let Some(d) = sdo_abort_details(&status) {
            return Error::SdoAbort {
                node: meta("node").parse().unwrap_or(0),
                index: u16::try_from(d.index).unwrap_or(u16::MAX),
                subindex: u8::try_from(d.subindex).unwrap_or(u8::MAX),
                code: d.code,
                name: d.name,
                by_node: d.from_node,
                status: Box::new(status),
            };
        }
        if status.code() == Code::NotFound {
            return Error::NotFound {
                kind: meta("kind"),
                name: meta("name"),
                message,
                status: Box::new(status),
            };
        }
        Error::Refused {
            code: status.code(),
            reason: reason.unwrap_or_else(|| code_name(status.code()).to_string()),
            message,
            status: Box::new(status),
        }
    }
}

/// `ErrorInfo.metadata` of a gateway error as a sorted map (empty when
/// there is none).
pub fn error_metadata(error: &Error) -> BTreeMap<String, String> {
    error
        .status()
        .and_then(error_info)
        .map(|i| i.metadata.into_iter().collect())
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;
    use tonic_types::pb as rpc;

    const ERROR_INFO_TYPE_URL: &str = "type.googleapis.com/google.rpc.ErrorInfo";

    /// A status as the gateway builds it.
    fn rich(
        code: Code,
        message: &str,
        reason: &str,
        metadata: &[(&str, &str)],
        sdo: Option<pb::SdoAbortDetails>,
    ) -> tonic::Status {
        let info = rpc::ErrorInfo {
            reason: reason.into(),
            domain: ERROR_DOMAIN.into(),
            metadata: metadata
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect(),
        };
        let mut body = rpc::Status {
            code: code as i32,
            message: message.into(),
            details: Vec::new(),
        };
        let mut push = |url: &str, value: Vec<u8>| {
            body.details.push(Default::default());
            let any = body.details.last_mut().unwrap();
            any.type_url = url.into();
            any.value = value;
        };
        push(ERROR_INFO_TYPE_URL, info.encode_to_vec());
        if let Some(d) = sdo {
            push(SDO_ABORT_DETAILS_TYPE_URL, d.encode_to_vec());
        }
        tonic::Status::with_details(code, message, body.encode_to_vec().into())
    }

    #[test]
    fn an_sdo_abort_is_decoded_from_the_rich_details() {
        let s = rich(
            Code::NotFound,
            "node 5: the SDO server aborted ...",
            "SDO_ABORT",
            &[("node", "5"), ("abort_code", "0x06020000")],
            Some(pb::SdoAbortDetails {
                code: 0x0602_0000,
                name: "object does not exist in the object dictionary".into(),
                index: 0x607A,
                subindex: 0,
                from_node: true,
            }),
        );
        let e = Error::from(s);
        let Error::SdoAbort {
            node,
            index,
            subindex,
            code,
            ref name,
            by_node,
            ..
        } = e
        else {
            panic!("{e:?}")
        };
        assert_eq!((node, index, subindex, code), (5, 0x607A, 0, 0x0602_0000));
        assert_eq!(name, "object does not exist in the object dictionary");
        assert!(by_node);
        assert_eq!(e.code(), Some(Code::NotFound));
        assert_eq!(e.reason().as_deref(), Some("SDO_ABORT"));
        assert_eq!(
            e.to_string(),
            "node 5, object 0x607A:00: SDO abort 0x06020000 object does not exist in the object \
             dictionary (sent by the node)"
        );
        assert!(std::error::Error::source(&e).is_none());
    }

    #[test]
    fn not_found_refused_and_timeouts() {
        let e = Error::from(rich(
            Code::NotFound,
            "axis \"Q\" not found (axes: X)",
            "AXIS_NOT_FOUND",
            &[("kind", "axis"), ("name", "Q")],
            None,
        ));
        assert!(
            matches!(&e, Error::NotFound { kind, name, .. } if kind == "axis" && name == "Q"),
            "{e:?}"
        );
        assert_eq!(e.to_string(), "axis \"Q\" not found (axes: X)");
        assert_eq!(error_metadata(&e)["kind"], "axis");

        let e = Error::from(rich(
            Code::FailedPrecondition,
            "axis X needs control",
            "LEASE_REQUIRED",
            &[("axis", "X")],
            None,
        ));
        assert!(
            matches!(&e, Error::Refused { code: Code::FailedPrecondition, reason, .. } if reason == "LEASE_REQUIRED"),
            "{e:?}"
        );
        assert_eq!(
            e.to_string(),
            "axis X needs control (LEASE_REQUIRED, FAILED_PRECONDITION)"
        );
        assert!(e.meaning().contains("not in a state"));

        // No ErrorInfo (the security layer): the code's name is the reason.
        let e = Error::from(tonic::Status::resource_exhausted("rate limit"));
        assert_eq!(e.to_string(), "rate limit (RESOURCE_EXHAUSTED)");
        assert_eq!(e.code(), Some(Code::ResourceExhausted));
        assert!(e.is_transient());

        let e = Error::from(rich(
            Code::DeadlineExceeded,
            "node 10: no answer",
            "SDO_TIMEOUT",
            &[],
            Some(pb::SdoAbortDetails::default()),
        ));
        assert!(
            matches!(
                &e,
                Error::Timeout {
                    status: Some(_),
                    ..
                }
            ),
            "{e:?}"
        );
        assert_eq!(e.reason().as_deref(), Some("SDO_TIMEOUT"));
        assert_eq!(e.to_string(), "timed out: node 10: no answer");
    }

    #[test]
    fn transport_failures_do_not_repeat_their_causes() {
        #[derive(Debug)]
        struct Outer(std::io::Error);
        impl fmt::Display for Outer {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("transport error")
            }
        }
        impl std::error::Error for Outer {
            fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
                Some(&self.0)
            }
        }
        let io = std::io::Error::new(std::io::ErrorKind::ConnectionRefused, "connection refused");
        let e = Error::connect("http://h:1", &Outer(io));
        assert_eq!(
            e.to_string(),
            "transport error: cannot connect to http://h:1: connection refused"
        );
        let io = std::io::Error::new(std::io::ErrorKind::TimedOut, "deadline has elapsed");
        let e = Error::connect("http://h:1", &Outer(io));
        assert!(matches!(e, Error::Timeout { status: None, .. }), "{e:?}");

        // A status made by tonic from a transport error keeps it as source.
        let io = std::io::Error::new(std::io::ErrorKind::BrokenPipe, "broken pipe");
        let s = tonic::Status::from_error(Box::new(Outer(io)));
        let e = Error::from(s);
        assert!(matches!(e, Error::Transport { .. }), "{e:?}");
        assert!(
            !e.to_string().contains("transport error: transport error"),
            "{e}"
        );
        assert_eq!(e.code(), None);
    }

    #[test]
    fn codes_have_names_and_meanings() {
        assert_eq!(code_name(Code::FailedPrecondition), "FAILED_PRECONDITION");
        assert!(!code_meaning(Code::Unavailable).is_empty());
    }
}
