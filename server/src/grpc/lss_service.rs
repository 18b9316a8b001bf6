//! The `cangate.v1.Lss` service: layer setting services (CiA 305) on the
//! buses' CANopen masters. Conversions and the LSS error mapping live here;
//! the operations are the runtime's ([`crate::canopen::lss`]).

use super::error::ApiError;
use super::runtime_errors::axis_active;
use crate::canopen::lss::{LssReach, LssSession, LssTarget};
use crate::canopen::{CanopenBus, CanopenError};
use crate::gateway::Gateway;
use cangate_canopen::NodeId;
use cangate_canopen::lss::{IdentifyRange, LssCommand, LssError, LssIdentity, LssMode, LssOutcome};
use cangate_proto::v1 as pb;
use cangate_proto::v1::lss_server::Lss;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tonic::{Code, Request, Response, Status};

/// The longest answer timeout a caller may ask for.
pub const MAX_LSS_TIMEOUT_MS: u32 = 10_000;
/// The longest fastscan step time.
pub const MAX_FASTSCAN_STEP_MS: u32 = 1_000;
/// Answer timeout when the request says 0.
const DEFAULT_TIMEOUT_MS: u32 = 500;
/// Fastscan step time when the request says 0.
const DEFAULT_STEP_MS: u32 = 20;

/// Implementation of the Lss service.
#[derive(Clone)]
pub struct LssService {
    gateway: Arc<Gateway>,
}

impl LssService {
    /// Serves LSS on the gateway's CANopen buses.
    pub fn new(gateway: Arc<Gateway>) -> Self {
        LssService { gateway }
    }

    fn master(&self, bus: &str) -> Result<&CanopenBus, ApiError> {
        self.gateway.bus(bus)?;
        self.gateway.canopen(bus).ok_or_else(|| {
            ApiError::FailedPrecondition(format!(
                "bus {bus:?} has no CANopen master, which LSS runs on (add a [[canopen]] section for it)"
            ))
        })
    }

    fn session(&self, bus: &str, operation: &'static str) -> Result<LssSession, ApiError> {
        self.master(bus)?.lss_session(operation).map_err(lss_error)
    }

    /// Refuses an operation that reaches `reach` while it could reach an
    /// enabled axis's drive.
    fn reach(&self, bus: &str, reach: LssReach, operation: &str) -> Result<(), ApiError> {
        self.master(bus)?
            .check_lss_reach(reach, operation)
            .map_err(axis_active)
    }
}

/// The one mapping of LSS failures to API errors.
pub(crate) fn lss_error(e: CanopenError) -> ApiError {
    let message = e.to_string();
    match e {
        CanopenError::Lss(l) => match l {
            LssError::Timeout { command, after } => ApiError::refused(
                Code::DeadlineExceeded,
                "LSS_TIMEOUT",
                message,
                vec![
                    ("command", command.to_string()),
                    ("timeout_ms", after.as_millis().to_string()),
                ],
            ),
            LssError::Refused {
                command,
                error,
                spec_error,
            } => ApiError::refused(
                Code::FailedPrecondition,
                "LSS_REFUSED",
                message,
                vec![
                    ("command", command.to_string()),
                    ("error", error.to_string()),
                    ("spec_error", spec_error.to_string()),
                ],
            ),
            LssError::Protocol { command, .. } => ApiError::refused(
                Code::Aborted,
                "LSS_PROTOCOL_ERROR",
                message,
                vec![("command", command.to_string())],
            ),
            LssError::Busy { running } => ApiError::refused(
                Code::FailedPrecondition,
                "LSS_BUSY",
                message,
                vec![("operation", running.to_string())],
            ),
            LssError::Invalid { .. } => ApiError::InvalidArgument(message),
        },
        CanopenError::LssBusy { operation, .. } => ApiError::refused(
            Code::FailedPrecondition,
            "LSS_BUSY",
            message,
            vec![("operation", operation.to_string())],
        ),
        CanopenError::LssDeviceNotFound { serial, .. } => ApiError::refused(
            Code::NotFound,
            "LSS_DEVICE_NOT_FOUND",
            message,
            vec![("serial", format!("0x{serial:08X}"))],
        ),
        CanopenError::LssNodeIdInUse { node, .. } => ApiError::refused(
            Code::FailedPrecondition,
            "NODE_ID_IN_USE",
            message,
            vec![("node", node.to_string())],
        ),
        CanopenError::AxisActive(e) => axis_active(e),
        CanopenError::Send(f) => f.into(),
        CanopenError::Stopped => ApiError::ShuttingDown,
        e @ (CanopenError::Sdo(_) | CanopenError::CallerQueueFull { .. }) => {
            ApiError::FailedPrecondition(e.to_string())
        }
    }
}

fn timeout(ms: u32) -> Result<Duration, ApiError> {
    if ms > MAX_LSS_TIMEOUT_MS {
        return Err(ApiError::InvalidArgument(format!(
            "LSS timeout_ms {ms} is above the maximum of {MAX_LSS_TIMEOUT_MS} ms"
        )));
    }
    Ok(Duration::from_millis(u64::from(if ms == 0 {
        DEFAULT_TIMEOUT_MS
    } else {
        ms
    })))
}

fn byte(what: &str, v: u32) -> Result<u8, ApiError> {
    u8::try_from(v)
        .map_err(|_| ApiError::InvalidArgument(format!("{what} {v} does not fit 8 bits")))
}

fn identity_from_pb(i: &pb::LssIdentity) -> LssIdentity {
    LssIdentity {
        vendor_id: i.vendor_id,
        product_code: i.product_code,
        revision: i.revision,
        serial: i.serial,
    }
}

/// The mode of a SwitchGlobal: only waiting (0) and configuration (1)
/// exist (CiA 305); another number is refused rather than read as 0.
fn lss_mode(mode: i32) -> Result<LssMode, ApiError> {
    match pb::LssMode::try_from(mode) {
        Ok(pb::LssMode::Waiting) => Ok(LssMode::Waiting),
        Ok(pb::LssMode::Configuration) => Ok(LssMode::Configuration),
        Err(_) => Err(ApiError::InvalidArgument(format!(
            "LSS mode {mode} does not exist: 0 (waiting) or 1 (configuration)"
        ))),
    }
}

/// The ranges of an IdentifyRemote; an inverted one (low above high)
/// matches no device, so it is refused rather than sent.
fn identify_range(r: &pb::IdentifyRemoteRequest) -> Result<IdentifyRange, ApiError> {
    for (what, low, high) in [
        ("revision", r.revision_low, r.revision_high),
        ("serial number", r.serial_low, r.serial_high),
    ] {
        if low > high {
            return Err(ApiError::InvalidArgument(format!(
                "the {what} range is inverted: low 0x{low:08X} is above high 0x{high:08X}"
            )));
        }
    }
    Ok(IdentifyRange {
        vendor_id: r.vendor_id,
        product_code: r.product_code,
        revision_low: r.revision_low,
        revision_high: r.revision_high,
        serial_low: r.serial_low,
        serial_high: r.serial_high,
    })
}

fn identity_to_pb(i: LssIdentity) -> pb::LssIdentity {
    pb::LssIdentity {
        vendor_id: i.vendor_id,
        product_code: i.product_code,
        revision: i.revision,
        serial: i.serial,
    }
}

fn ack(outcome: LssOutcome) -> Response<pb::LssAck> {
    Response::new(pb::LssAck {
        confirmed: outcome == LssOutcome::Confirmed,
    })
}

fn present(outcome: LssOutcome) -> Response<pb::IdentifyResponse> {
    Response::new(pb::IdentifyResponse {
        present: outcome == LssOutcome::Present(true),
    })
}

type Reply<T> = Result<Response<T>, Status>;

impl LssService {
    async fn one(
        &self,
        bus: &str,
        command: LssCommand,
        timeout: Duration,
    ) -> Result<LssOutcome, ApiError> {
        let s = self.session(bus, command.name())?;
        s.run(command, timeout).await.map_err(lss_error)
    }

    /// One LSS command behind the runtime's guards
    /// ([`CanopenBus::client_lss`]: an enabled axis's drive out of reach,
    /// a node-ID in use refused unless `force`).
    async fn guarded(
        &self,
        bus: &str,
        command: LssCommand,
        timeout: Duration,
        force: bool,
    ) -> Result<LssOutcome, ApiError> {
        self.master(bus)?
            .client_lss(command, timeout, force)
            .await
            .map_err(lss_error)
    }
}

#[tonic::async_trait]
impl Lss for LssService {
    async fn fastscan(&self, req: Request<pb::FastscanRequest>) -> Reply<pb::FastscanResponse> {
        let r = req.into_inner();
        if r.step_time_ms > MAX_FASTSCAN_STEP_MS {
            return Err(ApiError::InvalidArgument(format!(
                "step_time_ms {} is above the maximum of {MAX_FASTSCAN_STEP_MS} ms",
                r.step_time_ms
            ))
            .into());
        }
        if r.max_devices > 127 {
            return Err(ApiError::InvalidArgument(format!(
                "max_devices {} is above 127",
                r.max_devices
            ))
            .into());
        }
        let step = Duration::from_millis(u64::from(if r.step_time_ms == 0 {
            DEFAULT_STEP_MS
        } else {
            r.step_time_ms
        }));
        let min = self.master(&r.bus)?.min_fastscan_step();
        if step < min {
            return Err(ApiError::InvalidArgument(format!(
                "step_time_ms {} is shorter than bus {} can answer a fastscan step in: at least \
                 {} ms (a request and its answer at the bus's bitrate, and the device's turn-around)",
                step.as_millis(),
                r.bus,
                min.as_millis()
            ))
            .into());
        }
        let max = if r.max_devices == 0 {
            32
        } else {
            r.max_devices as usize
        };
        let s = self.session(&r.bus, "fastscan")?;
        let started = Instant::now();
        let found = s.fastscan(step, max).await.map_err(lss_error)?;
        Ok(Response::new(pb::FastscanResponse {
            devices: found.into_iter().map(identity_to_pb).collect(),
            elapsed_ms: started.elapsed().as_millis() as u64,
        }))
    }

    async fn switch_global(&self, req: Request<pb::SwitchGlobalRequest>) -> Reply<pb::LssAck> {
        let r = req.into_inner();
        let mode = lss_mode(r.mode)?;
        let t = timeout(0)?;
        Ok(ack(self
            .guarded(&r.bus, LssCommand::SwitchGlobal(mode), t, false)
            .await?))
    }

    async fn switch_selective(
        &self,
        req: Request<pb::SwitchSelectiveRequest>,
    ) -> Reply<pb::LssAck> {
        let r = req.into_inner();
        let id = r
            .identity
            .as_ref()
            .map(identity_from_pb)
            .ok_or_else(|| ApiError::InvalidArgument("identity is required".into()))?;
        let t = timeout(r.timeout_ms)?;
        Ok(ack(self
            .guarded(&r.bus, LssCommand::SwitchSelective(id), t, false)
            .await?))
    }

    async fn configure_node_id(
        &self,
        req: Request<pb::ConfigureNodeIdRequest>,
    ) -> Reply<pb::LssAck> {
        let r = req.into_inner();
        if !(1..=127).contains(&r.node_id) && r.node_id != 255 {
            return Err(ApiError::InvalidArgument(format!(
                "node_id {} is out of range (1..=127, or 255 to take the node-ID away)",
                r.node_id
            ))
            .into());
        }
        let t = timeout(r.timeout_ms)?;
        Ok(ack(self
            .guarded(
                &r.bus,
                LssCommand::ConfigureNodeId(r.node_id as u8),
                t,
                r.force,
            )
            .await?))
    }

    async fn configure_bit_timing(
        &self,
        req: Request<pb::ConfigureBitTimingRequest>,
    ) -> Reply<pb::LssAck> {
        let r = req.into_inner();
        let cmd = LssCommand::ConfigureBitTiming {
            table: byte("table", r.table)?,
            index: byte("index", r.index)?,
        };
        let t = timeout(r.timeout_ms)?;
        Ok(ack(self.guarded(&r.bus, cmd, t, false).await?))
    }

    async fn activate_bit_timing(
        &self,
        req: Request<pb::ActivateBitTimingRequest>,
    ) -> Reply<pb::LssAck> {
        let r = req.into_inner();
        let switch_delay_ms = u16::try_from(r.switch_delay_ms).map_err(|_| {
            ApiError::InvalidArgument(format!(
                "switch_delay_ms {} is above 65535",
                r.switch_delay_ms
            ))
        })?;
        let t = timeout(0)?;
        Ok(ack(self
            .guarded(
                &r.bus,
                LssCommand::ActivateBitTiming { switch_delay_ms },
                t,
                false,
            )
            .await?))
    }

    async fn store_configuration(
        &self,
        req: Request<pb::StoreConfigurationRequest>,
    ) -> Reply<pb::LssAck> {
        let r = req.into_inner();
        let t = timeout(r.timeout_ms)?;
        Ok(ack(self
            .guarded(&r.bus, LssCommand::StoreConfiguration, t, false)
            .await?))
    }

    async fn inquire(&self, req: Request<pb::InquireRequest>) -> Reply<pb::InquireResponse> {
        let r = req.into_inner();
        let t = timeout(r.timeout_ms)?;
        let identity = r.identity.as_ref().map(identity_from_pb);
        self.reach(
            &r.bus,
            identity.map_or(LssReach::AllDevices, LssReach::Identity),
            "inquire",
        )?;
        let s = self.session(&r.bus, "inquire")?;
        let (identity, node_id) = s.inquire(identity, t).await.map_err(lss_error)?;
        Ok(Response::new(pb::InquireResponse {
            identity: Some(identity_to_pb(identity)),
            node_id: u32::from(node_id),
        }))
    }

    async fn identify_remote(
        &self,
        req: Request<pb::IdentifyRemoteRequest>,
    ) -> Reply<pb::IdentifyResponse> {
        let r = req.into_inner();
        let t = timeout(r.timeout_ms)?;
        let range = identify_range(&r)?;
        Ok(present(
            self.one(&r.bus, LssCommand::IdentifyRemote(range), t)
                .await?,
        ))
    }

    async fn identify_non_configured(
        &self,
        req: Request<pb::IdentifyNonConfiguredRequest>,
    ) -> Reply<pb::IdentifyResponse> {
        let r = req.into_inner();
        let t = timeout(r.timeout_ms)?;
        Ok(present(
            self.one(&r.bus, LssCommand::IdentifyNonConfigured, t)
                .await?,
        ))
    }

    async fn assign_node_id(
        &self,
        req: Request<pb::AssignNodeIdRequest>,
    ) -> Reply<pb::AssignNodeIdResponse> {
        let r = req.into_inner();
        let node = NodeId::new(r.node_id).map_err(|e| ApiError::InvalidArgument(e.to_string()))?;
        let target = match &r.device {
            Some(pb::assign_node_id_request::Device::Identity(i)) => {
                LssTarget::Identity(identity_from_pb(i))
            }
            Some(pb::assign_node_id_request::Device::Serial(s)) => LssTarget::Serial(*s),
            None => {
                return Err(ApiError::InvalidArgument(
                    "give the device: its identity or its serial number".into(),
                )
                .into());
            }
        };
        let t = timeout(r.timeout_ms)?;
        let s = self.session(&r.bus, "assign node-ID")?;
        let done = s
            .assign_node_id(target, node, r.store, r.force, t)
            .await
            .map_err(lss_error)?;
        Ok(Response::new(pb::AssignNodeIdResponse {
            identity: Some(identity_to_pb(done.identity)),
            previous_node_id: u32::from(done.previous),
            node_id: u32::from(node.get()),
            stored: done.stored,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lss_errors_map_to_codes_and_reasons() {
        let cases = [
            (
                CanopenError::Lss(LssError::Timeout {
                    command: "inquire",
                    after: Duration::from_millis(500),
                }),
                Code::DeadlineExceeded,
                "LSS_TIMEOUT",
            ),
            (
                CanopenError::Lss(LssError::Refused {
                    command: "store configuration",
                    error: 1,
                    spec_error: 0,
                }),
                Code::FailedPrecondition,
                "LSS_REFUSED",
            ),
            (
                CanopenError::Lss(LssError::Protocol {
                    command: "fastscan",
                    reason: "lost".into(),
                }),
                Code::Aborted,
                "LSS_PROTOCOL_ERROR",
            ),
            (
                CanopenError::LssBusy {
                    bus: "can0".into(),
                    operation: "fastscan",
                },
                Code::FailedPrecondition,
                "LSS_BUSY",
            ),
            (
                CanopenError::LssDeviceNotFound {
                    bus: "can0".into(),
                    serial: 7,
                    found: "no unconfigured device".into(),
                },
                Code::NotFound,
                "LSS_DEVICE_NOT_FOUND",
            ),
            (
                CanopenError::Lss(LssError::Invalid {
                    command: "configure node-ID",
                    reason: "0".into(),
                }),
                Code::InvalidArgument,
                "INVALID_ARGUMENT",
            ),
        ];
        for (e, code, reason) in cases {
            let a = lss_error(e);
            assert_eq!((a.code(), a.reason().as_str()), (code, reason), "{a}");
        }
        let a = lss_error(CanopenError::Lss(LssError::Refused {
            command: "configure node-ID",
            error: 0xFF,
            spec_error: 9,
        }));
        assert!(
            a.metadata().contains(&("spec_error", "9".into())),
            "{:?}",
            a.metadata()
        );
        assert!(
            a.to_string().contains("implementation-specific error 9"),
            "{a}"
        );
    }
}
