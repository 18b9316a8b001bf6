//! The one place where domain errors become gRPC statuses.
//!
//! Every status built here follows the standard gRPC richer error model:
//! its `grpc-status-details-bin` trailer is an encoded `google.rpc.Status`
//! (same code and message) whose details hold
//!
//! - a `google.rpc.ErrorInfo` with domain [`ERROR_DOMAIN`], a stable
//!   upper-snake `reason` per kind of error (see [`ApiError::reason`]) and
//!   string metadata naming what the error is about;
//! - for errors caused by an SDO transfer, also a `cangate.v1.SdoAbortDetails`
//!   packed as a `google.protobuf.Any` (type URL
//!   [`SDO_ABORT_DETAILS_TYPE_URL`]); the abort is also in the metadata key
//!   `cangate-sdo-abort`.
//!
//! The contract (reasons, metadata keys) is documented at the top of
//! `canopen.proto`; the unit tests below pin it.

use cangate_can::{FrameError, SendError, SendFailure};
use cangate_canopen::sdo::SdoError;
use prost::Message;
use tonic::{Code, Status};
use tonic_types::pb as rpc;

/// `ErrorInfo.domain` of every error of the gateway.
pub const ERROR_DOMAIN: &str = "cangate.v1";

/// Type URL of the `cangate.v1.SdoAbortDetails` detail of SDO errors.
pub const SDO_ABORT_DETAILS_TYPE_URL: &str = "type.googleapis.com/cangate.v1.SdoAbortDetails";

/// Response metadata key with the SDO abort as text ("0x06010002 attempt
/// to write a read only object").
pub const SDO_ABORT_METADATA: &str = "cangate-sdo-abort";

/// Type URL of `google.rpc.ErrorInfo`.
const ERROR_INFO_TYPE_URL: &str = "type.googleapis.com/google.rpc.ErrorInfo";

/// The message in the details is cut to this many bytes, as the gateway's
/// `grpc-message` is (see `security::status`).
const MAX_DETAILS_MESSAGE: usize = 1024;

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
    /// An SDO transfer of one step of a longer procedure (a program
    /// download, a PDO configuration) failed: as [`ApiError::Sdo`], with
    /// the step in the message and in the metadata key "step".
    #[error("node {node}, {context}: {error}")]
    SdoInStep {
        /// Node id.
        node: u8,
        /// The step's stable name ("download-data").
        step: &'static str,
        /// The step for people ("downloading the program data 0x1F50").
        context: String,
        /// The failure.
        error: SdoError,
    },
    /// A refusal with a reason finer than its code (see
    /// [`ApiError::refused`]).
    #[error("{message}")]
    Refused {
        /// The gRPC code.
        code: Code,
        /// The `ErrorInfo.reason`: upper snake case, stable.
        reason: &'static str,
        /// For people.
        message: String,
        /// `ErrorInfo.metadata` entries.
        metadata: Vec<(&'static str, String)>,
    },
}

pub use crate::not_found::{QUOTE_BYTES, quote_prefix};

/// The start of `s`, at most `max` bytes, cut at a character boundary.
fn cut(s: &str, max: usize) -> &str {
    if s.len() <= max {
        return s;
    }
    let mut end = max;
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    &s[..end]
}

impl ApiError {
    /// A malformed frame in a batch.
    pub fn bad_frame(index: usize, err: impl std::fmt::Display) -> Self {
        ApiError::Refused {
            code: Code::InvalidArgument,
            reason: "INVALID_FRAME",
            message: format!("frame {index}: {err}"),
            metadata: vec![("frame", index.to_string())],
        }
    }

    /// A refusal with its own `ErrorInfo.reason` (upper snake case, stable
    /// once published: clients match on it) and metadata.
    pub fn refused(
        code: Code,
        reason: &'static str,
        message: impl Into<String>,
        metadata: Vec<(&'static str, String)>,
    ) -> Self {
        ApiError::Refused {
            code,
            reason,
            message: message.into(),
            metadata,
        }
    }

    /// The gRPC code.
    pub fn code(&self) -> Code {
        match self {
            ApiError::NotFound { .. } => Code::NotFound,
            ApiError::InvalidArgument(_) => Code::InvalidArgument,
            ApiError::FailedPrecondition(_) => Code::FailedPrecondition,
            ApiError::PermissionDenied(_) => Code::PermissionDenied,
            ApiError::Unavailable(_) | ApiError::ShuttingDown => Code::Unavailable,
            ApiError::OutOfRange(_) => Code::OutOfRange,
            ApiError::DeadlineExceeded(_) => Code::DeadlineExceeded,
            ApiError::Aborted(_) => Code::Aborted,
            ApiError::Sdo { error, .. } | ApiError::SdoInStep { error, .. } => sdo_code(error),
            ApiError::Refused { code, .. } => *code,
        }
    }

    /// The `ErrorInfo.reason`: `<KIND>_NOT_FOUND` (`AXIS_NOT_FOUND`,
    /// `BUS_NOT_FOUND`, `CANSMC_MASTER_NOT_FOUND`, ...), `SDO_ABORT`,
    /// `SDO_TIMEOUT`, `SDO_PROTOCOL_ERROR`, `SDO_CANCELLED`,
    /// `SDO_NOT_SENT`, `SHUTTING_DOWN`, the reason of a [`ApiError::Refused`], else the
    /// code's name (`INVALID_ARGUMENT`, `FAILED_PRECONDITION`, ...).
    pub fn reason(&self) -> String {
        match self {
            ApiError::NotFound { kind, .. } => format!("{}_NOT_FOUND", upper_snake(kind)),
            ApiError::InvalidArgument(_) => "INVALID_ARGUMENT".into(),
            ApiError::FailedPrecondition(_) => "FAILED_PRECONDITION".into(),
            ApiError::PermissionDenied(_) => "PERMISSION_DENIED".into(),
            ApiError::Unavailable(_) => "UNAVAILABLE".into(),
            ApiError::OutOfRange(_) => "OUT_OF_RANGE".into(),
            ApiError::DeadlineExceeded(_) => "DEADLINE_EXCEEDED".into(),
            ApiError::Aborted(_) => "ABORTED".into(),
            ApiError::ShuttingDown => "SHUTTING_DOWN".into(),
            ApiError::Sdo { error, .. } | ApiError::SdoInStep { error, .. } => match error {
                SdoError::Aborted { .. } => "SDO_ABORT",
                SdoError::Timeout { .. } => "SDO_TIMEOUT",
                SdoError::Protocol { .. } => "SDO_PROTOCOL_ERROR",
                SdoError::Cancelled { .. } => "SDO_CANCELLED",
                SdoError::NotSent { .. } => "SDO_NOT_SENT",
            }
            .into(),
            ApiError::Refused { reason, .. } => (*reason).into(),
        }
    }

    /// The `ErrorInfo.metadata`.
    pub fn metadata(&self) -> Vec<(&'static str, String)> {
        match self {
            ApiError::NotFound { kind, name, .. } => vec![
                ("kind", (*kind).to_string()),
                ("name", cut(name, QUOTE_BYTES).to_string()),
            ],
            ApiError::SdoInStep {
                node, step, error, ..
            } => {
                let mut m = ApiError::Sdo {
                    node: *node,
                    error: error.clone(),
                }
                .metadata();
                m.push(("step", (*step).to_string()));
                m
            }
            ApiError::Sdo { node, error } => {
                let abort = error.abort_code();
                let addr = sdo_address(error);
                vec![
                    ("abort_code", format!("0x{:08X}", abort.get())),
                    ("abort_name", abort.name().to_string()),
                    ("node", node.to_string()),
                    ("index", format!("0x{:04X}", addr.index)),
                    ("subindex", addr.sub.to_string()),
                    (
                        "aborted_by",
                        if matches!(error, SdoError::Aborted { .. }) {
                            "node"
                        } else {
                            "gateway"
                        }
                        .to_string(),
                    ),
                ]
            }
            ApiError::Refused { metadata, .. } => metadata.clone(),
            _ => Vec::new(),
        }
    }
}

/// "CANsmc master" → "CANSMC_MASTER".
fn upper_snake(kind: &str) -> String {
    let mut out = String::with_capacity(kind.len());
    for c in kind.chars() {
        if c.is_ascii_alphanumeric() {
            out.push(c.to_ascii_uppercase());
        } else if !out.is_empty() && !out.ends_with('_') {
            out.push('_');
        }
    }
    while out.ends_with('_') {
        out.pop();
    }
    out
}

impl From<crate::convert::InvalidArgument> for ApiError {
    fn from(e: crate::convert::InvalidArgument) -> Self {
        ApiError::InvalidArgument(e.0)
    }
}

impl From<crate::convert::InvalidArgument> for Status {
    fn from(e: crate::convert::InvalidArgument) -> Self {
        ApiError::from(e).into()
    }
}

impl From<FrameError> for ApiError {
    fn from(e: FrameError) -> Self {
        ApiError::refused(
            Code::InvalidArgument,
            "INVALID_FRAME",
            e.to_string(),
            vec![],
        )
    }
}

impl From<SendFailure> for ApiError {
    fn from(f: SendFailure) -> Self {
        let bus = match &f.error {
            SendError::BusOff(b) | SendError::Down(b) | SendError::FdNotSupported(b) => b.clone(),
            SendError::BudgetExhausted { bus, .. } | SendError::Io { bus, .. } => bus.clone(),
        };
        let metadata = vec![
            ("bus", cut(&bus, QUOTE_BYTES).to_string()),
            ("sent", f.sent.to_string()),
            ("total", f.total.to_string()),
        ];
        let reason = match &f.error {
            SendError::BusOff(_) => "BUS_OFF",
            SendError::Down(_) => "BUS_DOWN",
            SendError::FdNotSupported(_) => "CAN_FD_NOT_SUPPORTED",
            SendError::BudgetExhausted { .. } => "BUS_BUDGET_EXHAUSTED",
            SendError::Io { .. } => "SEND_FAILED",
        };
        match &f.error {
            SendError::FdNotSupported(_) => ApiError::refused(
                Code::InvalidArgument,
                reason,
                format!(
                    "{}; send classic frames or enable fd in the bus configuration",
                    f.error
                ),
                metadata,
            ),
            SendError::BusOff(_) | SendError::Down(_) if f.sent == 0 => ApiError::refused(
                Code::FailedPrecondition,
                reason,
                format!("{}; nothing was sent", f.error),
                metadata,
            ),
            _ => ApiError::refused(Code::Unavailable, reason, f.to_string(), metadata),
        }
    }
}

impl From<cangate_axis::lease::LeaseError> for ApiError {
    fn from(e: cangate_axis::lease::LeaseError) -> Self {
        use cangate_axis::lease::LeaseError as E;
        let (code, reason, metadata) = match &e {
            E::Held { axis, holder } => (
                Code::FailedPrecondition,
                "AXIS_CONTROLLED_BY_OTHER",
                vec![("axis", axis.clone()), ("holder", holder.clone())],
            ),
            E::NoLease { axis } => (
                Code::FailedPrecondition,
                "LEASE_REQUIRED",
                vec![("axis", axis.clone())],
            ),
            E::Unknown => (Code::FailedPrecondition, "LEASE_UNKNOWN", vec![]),
            E::NotCovered { axis } => (
                Code::FailedPrecondition,
                "LEASE_NOT_COVERING_AXIS",
                vec![("axis", axis.clone())],
            ),
            E::OtherIdentity { .. } => (Code::PermissionDenied, "LEASE_OTHER_IDENTITY", vec![]),
        };
        ApiError::refused(code, reason, e.to_string(), metadata)
    }
}

/// The gRPC code for an SDO abort code: the class of the abort decides.
fn sdo_code(error: &SdoError) -> Code {
    let abort = error.abort_code().get();
    match error {
        SdoError::Timeout { .. } => Code::DeadlineExceeded,
        // The bus could not carry the request now; the same call later may.
        SdoError::NotSent { .. } => Code::Unavailable,
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

fn sdo_address(error: &SdoError) -> cangate_canopen::ObjectAddress {
    match error {
        SdoError::Aborted { addr, .. }
        | SdoError::Protocol { addr, .. }
        | SdoError::Timeout { addr, .. }
        | SdoError::Cancelled { addr, .. }
        | SdoError::NotSent { addr } => *addr,
    }
}

/// The `cangate.v1.SdoAbortDetails` of an SDO failure.
fn sdo_details(error: &SdoError) -> cangate_proto::v1::SdoAbortDetails {
    let abort = error.abort_code();
    let addr = sdo_address(error);
    cangate_proto::v1::SdoAbortDetails {
        code: abort.get(),
        name: abort.name().to_string(),
        index: addr.index as u32,
        subindex: addr.sub as u32,
        from_node: matches!(error, SdoError::Aborted { .. }),
    }
}

/// A status with an encoded `google.rpc.Status` in its details: the
/// `ErrorInfo` first, then `extra` details (type URL, encoded message).
fn rich_status(
    code: Code,
    message: String,
    reason: String,
    metadata: Vec<(&'static str, String)>,
    extra: Vec<(&'static str, Vec<u8>)>,
) -> Status {
    let info = rpc::ErrorInfo {
        reason,
        domain: ERROR_DOMAIN.to_string(),
        metadata: metadata
            .into_iter()
            .map(|(k, v)| (k.to_string(), v))
            .collect(),
    };
    let mut body = rpc::Status {
        code: code as i32,
        message: cut(&message, MAX_DETAILS_MESSAGE).to_string(),
        details: Vec::new(),
    };
    for (type_url, value) in [(ERROR_INFO_TYPE_URL, info.encode_to_vec())]
        .into_iter()
        .chain(extra)
    {
        // A google.protobuf.Any (the type comes from tonic-types' Status).
        body.details.push(Default::default());
        let any = body.details.last_mut().expect("just pushed");
        any.type_url = type_url.to_string();
        any.value = value;
    }
    Status::with_details(code, message, body.encode_to_vec().into())
}

impl From<ApiError> for Status {
    fn from(e: ApiError) -> Self {
        let code = e.code();
        let reason = e.reason();
        let metadata = e.metadata();
        let message = e.to_string();
        let (ApiError::Sdo { error, .. } | ApiError::SdoInStep { error, .. }) = &e else {
            return rich_status(code, message, reason, metadata, Vec::new());
        };
        let details = sdo_details(error);
        let any = (SDO_ABORT_DETAILS_TYPE_URL, details.encode_to_vec());
        let mut status = rich_status(code, message, reason, metadata, vec![any]);
        let text = format!("0x{:08X} {}", details.code, details.name);
        if let Ok(v) = text.parse() {
            status.metadata_mut().insert(SDO_ABORT_METADATA, v);
        }
        status
    }
}

/// The answer of a failed SdoSession request: the same code, message,
/// ErrorInfo reason and metadata, and SDO abort as the status the unary
/// call would have returned.
impl From<ApiError> for cangate_proto::v1::SdoSessionError {
    fn from(e: ApiError) -> Self {
        let abort = match &e {
            ApiError::Sdo { error, .. } | ApiError::SdoInStep { error, .. } => {
                Some(sdo_details(error))
            }
            _ => None,
        };
        cangate_proto::v1::SdoSessionError {
            code: e.code() as i32,
            message: cut(&e.to_string(), MAX_DETAILS_MESSAGE).to_string(),
            reason: e.reason(),
            metadata: e
                .metadata()
                .into_iter()
                .map(|(k, v)| (k.to_string(), v))
                .collect(),
            abort,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cangate_canopen::ObjectAddress;
    use cangate_canopen::sdo::AbortCode;
    use std::collections::HashMap;
    use std::time::Duration;
    use tonic_types::StatusExt;

    /// The google.rpc.Status of a status, its ErrorInfo and the type URLs
    /// of its details.
    fn rich(s: &Status) -> (rpc::Status, rpc::ErrorInfo, Vec<String>) {
        let body = rpc::Status::decode(s.details()).expect("a google.rpc.Status");
        assert_eq!(body.code, s.code() as i32);
        assert_eq!(body.message, s.message());
        let info = s.get_details_error_info().expect("an ErrorInfo");
        assert_eq!(info.domain, ERROR_DOMAIN);
        let urls = body.details.iter().map(|a| a.type_url.clone()).collect();
        let info = rpc::ErrorInfo {
            reason: info.reason,
            domain: info.domain,
            metadata: info.metadata,
        };
        (body, info, urls)
    }

    fn meta(info: &rpc::ErrorInfo) -> HashMap<&str, &str> {
        info.metadata
            .iter()
            .map(|(k, v)| (k.as_str(), v.as_str()))
            .collect()
    }

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
        let (_, info, _) = rich(&s);
        assert_eq!(info.metadata["name"].len(), QUOTE_BYTES);
        // Multi-byte characters are cut at a boundary.
        let q = quote_prefix(&"é".repeat(100));
        assert!(q.contains("(200 bytes)"), "{q}");
        assert_eq!(quote_prefix("X"), "\"X\"");
    }

    #[test]
    fn not_found_names_the_kind_in_the_reason() {
        for (kind, reason) in [
            ("axis", "AXIS_NOT_FOUND"),
            ("bus", "BUS_NOT_FOUND"),
            ("CANsmc master", "CANSMC_MASTER_NOT_FOUND"),
            ("simulated device", "SIMULATED_DEVICE_NOT_FOUND"),
            ("RPDO", "RPDO_NOT_FOUND"),
        ] {
            let s = Status::from(ApiError::NotFound {
                kind,
                name: "Q".into(),
                hint: String::new(),
            });
            let (body, info, urls) = rich(&s);
            assert_eq!(info.reason, reason);
            assert_eq!(meta(&info), HashMap::from([("kind", kind), ("name", "Q")]));
            assert_eq!(urls, [ERROR_INFO_TYPE_URL]);
            assert_eq!(body.details.len(), 1);
            assert!(s.metadata().get(SDO_ABORT_METADATA).is_none());
        }
    }

    #[test]
    fn every_kind_of_error_carries_a_reason() {
        let cases = [
            (ApiError::InvalidArgument("m".into()), "INVALID_ARGUMENT"),
            (
                ApiError::FailedPrecondition("m".into()),
                "FAILED_PRECONDITION",
            ),
            (ApiError::PermissionDenied("m".into()), "PERMISSION_DENIED"),
            (ApiError::Unavailable("m".into()), "UNAVAILABLE"),
            (ApiError::OutOfRange("m".into()), "OUT_OF_RANGE"),
            (ApiError::DeadlineExceeded("m".into()), "DEADLINE_EXCEEDED"),
            (ApiError::Aborted("m".into()), "ABORTED"),
            (ApiError::ShuttingDown, "SHUTTING_DOWN"),
            (ApiError::bad_frame(3, "too long"), "INVALID_FRAME"),
        ];
        for (e, reason) in cases {
            let code = e.code();
            let s = Status::from(e);
            assert_eq!(s.code(), code);
            let (_, info, _) = rich(&s);
            assert_eq!(info.reason, reason, "{s:?}");
        }
        let s = Status::from(ApiError::ShuttingDown);
        assert_eq!(s.code(), Code::Unavailable);
        assert_eq!(s.message(), "the gateway is shutting down");
    }

    #[test]
    fn send_failures_and_leases_have_their_own_reasons() {
        let f = |error, sent| SendFailure {
            sent,
            total: 2,
            error,
        };
        let s = Status::from(ApiError::from(f(SendError::BusOff("can0".into()), 0)));
        assert_eq!(s.code(), Code::FailedPrecondition);
        let (_, info, _) = rich(&s);
        assert_eq!(info.reason, "BUS_OFF");
        assert_eq!(
            meta(&info),
            HashMap::from([("bus", "can0"), ("sent", "0"), ("total", "2")])
        );
        let s = Status::from(ApiError::from(f(SendError::Down("can0".into()), 1)));
        assert_eq!(s.code(), Code::Unavailable);
        assert_eq!(rich(&s).1.reason, "BUS_DOWN");
        let s = Status::from(ApiError::from(f(SendError::FdNotSupported("c".into()), 0)));
        assert_eq!(s.code(), Code::InvalidArgument);
        assert_eq!(rich(&s).1.reason, "CAN_FD_NOT_SUPPORTED");

        use cangate_axis::lease::LeaseError;
        let s = Status::from(ApiError::from(LeaseError::Held {
            axis: "X".into(),
            holder: "hmi (1.2.3.4:5)".into(),
        }));
        assert_eq!(s.code(), Code::FailedPrecondition);
        let (_, info, _) = rich(&s);
        assert_eq!(info.reason, "AXIS_CONTROLLED_BY_OTHER");
        assert_eq!(
            meta(&info),
            HashMap::from([("axis", "X"), ("holder", "hmi (1.2.3.4:5)")])
        );
        let s = Status::from(ApiError::from(LeaseError::OtherIdentity {
            owner: "a".into(),
            caller: "b".into(),
        }));
        assert_eq!(s.code(), Code::PermissionDenied);
        assert_eq!(rich(&s).1.reason, "LEASE_OTHER_IDENTITY");
    }

    fn sdo_error(error: SdoError) -> Status {
        Status::from(ApiError::Sdo { node: 5, error })
    }

    #[test]
    fn a_node_abort_carries_error_info_and_sdo_abort_details() {
        let s = sdo_error(SdoError::Aborted {
            addr: ObjectAddress::new(0x607A, 0),
            code: AbortCode(0x0607_0013),
        });
        assert_eq!(s.code(), Code::InvalidArgument);
        let (body, info, urls) = rich(&s);
        assert_eq!(info.reason, "SDO_ABORT");
        assert_eq!(
            meta(&info),
            HashMap::from([
                ("abort_code", "0x06070013"),
                (
                    "abort_name",
                    "data type does not match, length of service parameter too low"
                ),
                ("node", "5"),
                ("index", "0x607A"),
                ("subindex", "0"),
                ("aborted_by", "node"),
            ])
        );
        assert_eq!(urls, [ERROR_INFO_TYPE_URL, SDO_ABORT_DETAILS_TYPE_URL]);
        let details = cangate_proto::v1::SdoAbortDetails::decode(&*body.details[1].value).unwrap();
        assert_eq!(details.code, 0x0607_0013);
        assert_eq!((details.index, details.subindex), (0x607A, 0));
        assert!(details.from_node);
        assert_eq!(
            s.metadata()
                .get(SDO_ABORT_METADATA)
                .unwrap()
                .to_str()
                .unwrap(),
            "0x06070013 data type does not match, length of service parameter too low"
        );
        assert!(s.message().starts_with("node 5: "), "{}", s.message());
    }

    #[test]
    fn gateway_side_sdo_failures_say_so() {
        let addr = ObjectAddress::new(0x1000, 0);
        let s = sdo_error(SdoError::Timeout {
            addr,
            timeout: Duration::from_millis(500),
        });
        assert_eq!(s.code(), Code::DeadlineExceeded);
        let (body, info, _) = rich(&s);
        assert_eq!(info.reason, "SDO_TIMEOUT");
        assert_eq!(info.metadata["abort_code"], "0x05040000");
        assert_eq!(info.metadata["aborted_by"], "gateway");
        let details = cangate_proto::v1::SdoAbortDetails::decode(&*body.details[1].value).unwrap();
        assert!(!details.from_node);

        let s = sdo_error(SdoError::Protocol {
            addr,
            code: AbortCode(0x0504_0001),
            detail: "bad command".into(),
        });
        assert_eq!(s.code(), Code::Aborted);
        let (_, info, _) = rich(&s);
        assert_eq!(info.reason, "SDO_PROTOCOL_ERROR");
        assert_eq!(info.metadata["aborted_by"], "gateway");

        let s = sdo_error(SdoError::Cancelled {
            addr,
            code: AbortCode(0x0504_0001),
        });
        assert_eq!(rich(&s).1.reason, "SDO_CANCELLED");

        // A request the interface gave up: worth retrying later.
        let s = sdo_error(SdoError::NotSent { addr });
        assert_eq!(s.code(), Code::Unavailable);
        let (_, info, _) = rich(&s);
        assert_eq!(info.reason, "SDO_NOT_SENT");
        assert_eq!(info.metadata["aborted_by"], "gateway");
        assert_eq!(info.metadata["abort_code"], "0x08000000");
    }

    #[test]
    fn abort_classes_map_to_codes() {
        let addr = ObjectAddress::new(0x2000, 1);
        for (abort, code) in [
            (0x0602_0000, Code::NotFound),
            (0x0609_0011, Code::NotFound),
            (0x0607_0010, Code::InvalidArgument),
            (0x0609_0031, Code::OutOfRange),
            (0x0601_0002, Code::FailedPrecondition),
            (0x0800_0022, Code::FailedPrecondition),
            (0x060A_0023, Code::Aborted),
        ] {
            let s = sdo_error(SdoError::Aborted {
                addr,
                code: AbortCode(abort),
            });
            assert_eq!(s.code(), code, "0x{abort:08X}");
            assert_eq!(rich(&s).1.reason, "SDO_ABORT");
        }
    }

    #[test]
    fn long_messages_are_cut_in_the_details_only() {
        let long = "é".repeat(2000);
        let s = Status::from(ApiError::FailedPrecondition(long.clone()));
        assert_eq!(s.message(), long);
        let (body, _, _) = rpc::Status::decode(s.details())
            .map(|b| (b, (), ()))
            .unwrap();
        assert!(body.message.len() <= MAX_DETAILS_MESSAGE);
        assert!(long.starts_with(&body.message));
    }

    #[test]
    fn kinds_become_upper_snake() {
        assert_eq!(upper_snake("CANsmc master"), "CANSMC_MASTER");
        assert_eq!(upper_snake(" a--b "), "A_B");
        assert_eq!(upper_snake("RPDO"), "RPDO");
    }
}
