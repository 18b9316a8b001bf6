//! The runtime's typed errors as API errors: each reason gets its gRPC
//! code here, at the edge, and nowhere in the runtime.

use super::error::ApiError;
use crate::axes::AxisError;
use crate::canopen::drive_guard::AxisActive;
use crate::cansmc::CansmcError;
use crate::handwheel::HandwheelError;
use crate::not_found::NotFound;
use crate::not_found::quote_prefix;
use cangate_axis::CommandError;
use cangate_canopen::NodeId;
use cangate_canopen::od::{LookupError, ObjectDictionary};
use cangate_cansmc::master::ParameterError;

/// An operation refused because the node drives an enabled axis
/// (FAILED_PRECONDITION, reason AXIS_ACTIVE, metadata `axis` and `node`).
pub(crate) fn axis_active(e: AxisActive) -> ApiError {
    ApiError::refused(
        tonic::Code::FailedPrecondition,
        "AXIS_ACTIVE",
        e.to_string(),
        vec![("axis", e.axis.clone()), ("node", e.node.get().to_string())],
    )
}

impl From<NotFound> for ApiError {
    fn from(e: NotFound) -> Self {
        ApiError::NotFound {
            kind: e.kind,
            name: e.name,
            hint: e.hint,
        }
    }
}

impl From<AxisError> for ApiError {
    fn from(e: AxisError) -> Self {
        match e {
            AxisError::NotFound(e) => e.into(),
            AxisError::BadAxisList(m) => ApiError::InvalidArgument(m),
            AxisError::Refused(e) => e.into(),
            AxisError::Lease(e) => e.into(),
            AxisError::NotCoordinable(m) => ApiError::FailedPrecondition(m),
            AxisError::NotStreamable(m) => ApiError::FailedPrecondition(m),
            AxisError::Unavailable(m) => ApiError::Unavailable(m),
            AxisError::NoAnswer(m) => ApiError::DeadlineExceeded(m),
            AxisError::ShuttingDown => ApiError::ShuttingDown,
            AxisError::Sdo { node, error } => match error {
                crate::canopen::CanopenError::Sdo(error) => ApiError::Sdo {
                    node: node.get(),
                    error,
                },
                crate::canopen::CanopenError::Stopped => ApiError::ShuttingDown,
                e @ crate::canopen::CanopenError::Send(_) => ApiError::Unavailable(e.to_string()),
                e => ApiError::FailedPrecondition(e.to_string()),
            },
        }
    }
}

/// A refused axis command: a malformed value is INVALID_ARGUMENT, a value
/// beyond a configured limit OUT_OF_RANGE, and what the axis's state
/// forbids FAILED_PRECONDITION.
impl From<CommandError> for ApiError {
    fn from(e: CommandError) -> Self {
        use CommandError as E;
        match e {
            E::BadValue(m) => ApiError::InvalidArgument(m),
            E::AboveMaximum(m) | E::BeyondSoftLimit(m) => ApiError::OutOfRange(m),
            E::DriveUnavailable(m)
            | E::InFault(m)
            | E::NotEnabled(m)
            | E::Busy(m)
            | E::NotCyclic(m)
            | E::SyncStopped(m)
            | E::StateUnreachable(m)
            | E::WrongMode(m) => ApiError::FailedPrecondition(m),
        }
    }
}

impl From<CansmcError> for ApiError {
    fn from(e: CansmcError) -> Self {
        match e {
            CansmcError::NotFound(e) => e.into(),
            CansmcError::Parameter(e) => match e {
                ParameterError::UnknownSlave(a) => ApiError::NotFound {
                    kind: "CANsmc slave",
                    name: a.to_string(),
                    hint: String::new(),
                },
                ParameterError::Refused { .. } | ParameterError::Rejected { .. } => {
                    ApiError::FailedPrecondition(e.to_string())
                }
                ParameterError::Timeout { .. } => ApiError::DeadlineExceeded(e.to_string()),
                ParameterError::Unavailable { .. } => ApiError::Unavailable(e.to_string()),
                ParameterError::Cancelled => ApiError::Aborted(e.to_string()),
            },
            CansmcError::NoAnswer(m) => ApiError::DeadlineExceeded(m),
            CansmcError::ShuttingDown => ApiError::ShuttingDown,
        }
    }
}

impl From<HandwheelError> for ApiError {
    fn from(e: HandwheelError) -> Self {
        match e {
            HandwheelError::NotFound(e) => e.into(),
            HandwheelError::Device(m) => ApiError::FailedPrecondition(m),
            HandwheelError::Sdo { node, error } => ApiError::Sdo { node, error },
            HandwheelError::Unavailable(m) => ApiError::Unavailable(m),
        }
    }
}

/// An object name (`ReadSdoRequest.object`) that the EDS of node `node`
/// on `bus` does not resolve to one object: OBJECT_NOT_FOUND, or
/// INVALID_ARGUMENT naming every candidate by address and full name.
pub(crate) fn lookup_error(
    e: LookupError,
    bus: &str,
    node: NodeId,
    od: &ObjectDictionary,
) -> ApiError {
    match e {
        LookupError::NotFound(query) => ApiError::NotFound {
            kind: "object",
            name: query,
            hint: format!(
                " in the EDS of node {node} on bus {bus} (`cangate node objects {bus} {node}` \
                 lists its objects)"
            ),
        },
        LookupError::Ambiguous { query, matches } => {
            const SHOWN: usize = 12;
            let mut candidates: Vec<String> = matches
                .iter()
                .take(SHOWN)
                .map(|a| match od.full_name(*a) {
                    Some(name) => format!("{a} ({name})"),
                    None => a.to_string(),
                })
                .collect();
            if matches.len() > SHOWN {
                candidates.push(format!("and {} more", matches.len() - SHOWN));
            }
            ApiError::InvalidArgument(format!(
                "object {} is ambiguous on node {node} on bus {bus}: it names {}; give one \
                 of them in full",
                quote_prefix(&query),
                candidates.join(", ")
            ))
        }
    }
}

/// For handlers that return a [`tonic::Status`] directly.
macro_rules! into_status {
    ($($t:ty),*) => {$(
        impl From<$t> for tonic::Status {
            fn from(e: $t) -> Self {
                ApiError::from(e).into()
            }
        }
    )*};
}
into_status!(NotFound, AxisError, CansmcError, HandwheelError);

#[cfg(test)]
mod tests {
    use super::*;
    use tonic::Code;

    #[test]
    fn each_refusal_reason_gets_its_code_and_keeps_its_message() {
        use CommandError as E;
        for (e, code) in [
            (E::BadValue("m".into()), Code::InvalidArgument),
            (E::AboveMaximum("m".into()), Code::OutOfRange),
            (E::BeyondSoftLimit("m".into()), Code::OutOfRange),
            (E::DriveUnavailable("m".into()), Code::FailedPrecondition),
            (E::InFault("m".into()), Code::FailedPrecondition),
            (E::NotEnabled("m".into()), Code::FailedPrecondition),
            (E::Busy("m".into()), Code::FailedPrecondition),
            (E::NotCyclic("m".into()), Code::FailedPrecondition),
            (E::SyncStopped("m".into()), Code::FailedPrecondition),
            (E::StateUnreachable("m".into()), Code::FailedPrecondition),
            (E::WrongMode("m".into()), Code::FailedPrecondition),
        ] {
            let e = e.prefixed("axis X: ");
            let status = tonic::Status::from(AxisError::Refused(e.clone()));
            assert_eq!(status.code(), code, "{e:?}");
            assert_eq!(status.message(), "axis X: m", "{e:?}");
        }
    }
}
