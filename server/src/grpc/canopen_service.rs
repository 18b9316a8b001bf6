//! The `cangate.v1.Canopen` service: nodes, NMT, SDO, events.

use super::error::ApiError;
use super::forward::{
    AtShutdown, Forward, MessageStream, Received, spawn_forward, spawn_forwarding, stream_of,
};
use super::runtime_errors::{axis_active, lookup_error};
use super::sdo_session::{self, Caller, audit_write, check_role};
use crate::canopen::dcf_export::DcfExportError;
use crate::canopen::pdo_config::PdoConfigError;
use crate::canopen::program::{ProgramEvent, ProgramFailure, ProgramStartError};
use crate::canopen::{CanopenBus, CanopenError, SyncChangeError, TimeSendError};
use crate::convert::canopen::{
    data_type_from_pb, node_event_to_pb, node_events_lost_to_pb, node_to_pb, object_info_to_pb,
    pdo_from_pb, pdo_kind_from_pb, pdo_to_pb, program_outcome_to_pb, program_step_to_pb,
    sdo_transfer_to_pb, value_from_pb, value_from_pb_as, value_to_pb,
};
use crate::gateway::Gateway;
use crate::security::{Identity, RequestBudget};
use cangate_canopen::eds::Eds;
use cangate_canopen::master::SdoRequest;
use cangate_canopen::nmt::NmtCommand;
use cangate_canopen::pdo::PdoKind;
use cangate_canopen::program_download::{ProgramError, ProgramPlan, ProgramStep, ProgramTimeouts};
use cangate_canopen::sdo::{TransferOptions, TransferOutcome};
use cangate_canopen::value::Value;
use cangate_canopen::{NodeId, ObjectAddress};
use cangate_proto::v1 as pb;
use cangate_proto::v1::canopen_server::Canopen;
use std::sync::Arc;
use std::time::Duration;
use tonic::{Request, Response, Status};

/// Implementation of the Canopen service.
#[derive(Clone)]
pub struct CanopenService {
    gateway: Arc<Gateway>,
}

impl CanopenService {
    /// Serves the gateway's CANopen masters.
    pub fn new(gateway: Arc<Gateway>) -> Self {
        CanopenService { gateway }
    }

    fn master(&self, bus: &str) -> Result<&CanopenBus, ApiError> {
        master_of(&self.gateway, bus)
    }
}

/// The CANopen master of a bus: NOT_FOUND for an unknown bus,
/// FAILED_PRECONDITION for one without a master.
fn master_of<'g>(gateway: &'g Gateway, bus: &str) -> Result<&'g CanopenBus, ApiError> {
    gateway.bus(bus)?;
    gateway.canopen(bus).ok_or_else(|| {
        ApiError::FailedPrecondition(format!(
            "bus {bus:?} has no CANopen master (add a [[canopen]] section for it)"
        ))
    })
}

fn node_id(n: u32) -> Result<NodeId, ApiError> {
    NodeId::new(n).map_err(|e| ApiError::InvalidArgument(e.to_string()))
}

fn known_node(master: &CanopenBus, n: u32) -> Result<NodeId, ApiError> {
    let id = node_id(n)?;
    if !master.knows(id) {
        return Err(ApiError::NotFound {
            kind: "node",
            name: format!("{n} on bus {}", master.bus()),
            hint: " (not configured and never heard of; run ScanNetwork / `cangate scan` first)"
                .into(),
        });
    }
    Ok(id)
}

fn address(index: u32, sub: u32) -> Result<ObjectAddress, ApiError> {
    let index = u16::try_from(index).map_err(|_| {
        ApiError::InvalidArgument(format!("index 0x{index:X} does not fit 16 bits"))
    })?;
    let sub = u8::try_from(sub)
        .map_err(|_| ApiError::InvalidArgument(format!("sub-index {sub} does not fit 8 bits")))?;
    Ok(ObjectAddress::new(index, sub))
}

/// A node's EDS, or FAILED_PRECONDITION saying it has none (`why`: what
/// needed it).
fn node_eds(master: &CanopenBus, node: NodeId, why: &str) -> Result<Arc<Eds>, ApiError> {
    master.eds(node).ok_or_else(|| {
        ApiError::FailedPrecondition(format!(
            "node {node} on bus {} has no EDS, so {why} (give it one with `eds` in its \
             [[canopen.node]] section, or address objects by index and sub-index)",
            master.bus()
        ))
    })
}

/// The object of an SDO request: `object` resolved with the node's EDS
/// when given (index and sub-index must then be 0), else index:subindex.
fn target(
    master: &CanopenBus,
    node: NodeId,
    object: &str,
    index: u32,
    sub: u32,
) -> Result<ObjectAddress, ApiError> {
    if object.is_empty() {
        return address(index, sub);
    }
    if index != 0 || sub != 0 {
        return Err(ApiError::InvalidArgument(format!(
            "give the object either by name (object = {}) or by index/subindex \
             (0x{index:04X}:{sub:02X}), not both",
            crate::not_found::quote_prefix(object)
        )));
    }
    let eds = node_eds(master, node, "objects cannot be named")?;
    eds.od
        .resolve(object)
        .map_err(|e| lookup_error(e, master.bus(), node, &eds.od))
}

/// The longest SDO timeout a caller may ask for (`SdoOptions.timeout_ms`).
pub const MAX_SDO_TIMEOUT_MS: u32 = 60_000;
/// The longest per-node answer timeout of a ScanNetwork.
pub const MAX_SCAN_TIMEOUT_MS: u32 = 10_000;

fn options(o: Option<&pb::SdoOptions>) -> Result<TransferOptions, ApiError> {
    let o = o.cloned().unwrap_or_default();
    let mut opts = if o.block {
        TransferOptions::block()
    } else {
        TransferOptions::default()
    };
    if o.timeout_ms > MAX_SDO_TIMEOUT_MS {
        return Err(ApiError::InvalidArgument(format!(
            "SDO timeout_ms {} is above the maximum of {MAX_SDO_TIMEOUT_MS} ms",
            o.timeout_ms
        )));
    }
    if o.timeout_ms > 0 {
        opts = opts.with_timeout(Duration::from_millis(o.timeout_ms as u64));
    }
    Ok(opts)
}

/// Whose SDO requests these are, for the per-caller bound: the
/// authenticated identity, else the peer's address without the port (one
/// client with many connections is still one caller).
fn sdo_caller<T>(req: &Request<T>) -> String {
    match req.extensions().get::<crate::security::Identity>() {
        Some(id) if id.method != "none" => id.name.clone(),
        _ => req
            .remote_addr()
            .map_or_else(|| "an unknown peer".to_string(), |a| a.ip().to_string()),
    }
}

/// Node ids of a stream filter, each in 1..=127.
fn node_filter(nodes: &[u32]) -> Result<Vec<u32>, ApiError> {
    for &n in nodes {
        node_id(n).map_err(|e| ApiError::InvalidArgument(format!("nodes: {e}")))?;
    }
    Ok(nodes.to_vec())
}

fn map_err(node: NodeId, e: CanopenError) -> ApiError {
    match e {
        CanopenError::Sdo(error) => ApiError::Sdo {
            node: node.get(),
            error,
        },
        CanopenError::Send(f) => f.into(),
        CanopenError::Stopped => ApiError::ShuttingDown,
        e @ CanopenError::CallerQueueFull { .. } => ApiError::FailedPrecondition(e.to_string()),
        CanopenError::AxisActive(e) => axis_active(e),
        e @ (CanopenError::Lss(_)
        | CanopenError::LssBusy { .. }
        | CanopenError::LssNodeIdInUse { .. }
        | CanopenError::LssDeviceNotFound { .. }) => super::lss_service::lss_error(e),
    }
}

/// The shortest SYNC period SetSync accepts (0x1006 is in µs; below
/// 100 µs a classic CAN bus has no room for anything else).
pub const MIN_SYNC_PERIOD_US: u32 = 100;
/// The longest SYNC period SetSync accepts.
pub const MAX_SYNC_PERIOD_US: u32 = 10_000_000;
/// The longest TIME period: a day.
pub const MAX_TIME_PERIOD_MS: u32 = 86_400_000;

fn time_period_ms(m: &CanopenBus) -> u32 {
    m.time_period().map_or(0, |p| p.as_millis() as u32)
}

fn sync_status(m: &CanopenBus) -> pb::SyncStatus {
    let s = m.sync_settings();
    let (sent, skipped) = m.sync_counts();
    pb::SyncStatus {
        bus: m.bus().to_string(),
        running: s.running,
        period_us: s.period.as_micros() as u32,
        counter_overflow: u32::from(s.counter_overflow),
        sent,
        skipped,
        time_period_ms: time_period_ms(m),
    }
}

/// The PDO numbers ReadPdoConfig reads without a number: those the EDS
/// lists, or 1..=4 (the predefined connection set) without an EDS.
fn pdo_numbers(od: Option<&cangate_canopen::od::ObjectDictionary>, kind: PdoKind) -> Vec<u16> {
    match od {
        Some(od) => (1..=512)
            .filter(|&n| od.object(kind.comm_index(n)).is_some())
            .collect(),
        None => (1..=4).collect(),
    }
}

fn pdo_config_err(node: NodeId, e: PdoConfigError) -> ApiError {
    match e {
        e @ PdoConfigError::AxisDrive(_) => ApiError::FailedPrecondition(e.to_string()),
        PdoConfigError::Invalid(e) => ApiError::InvalidArgument(e.to_string()),
        PdoConfigError::Object { addr, what, source } => match map_err(node, source) {
            // The SDO error's code, reason and details, with the PDO
            // parameter it failed on.
            ApiError::Sdo { node, error } => ApiError::SdoInStep {
                node,
                step: "configure-pdo",
                context: format!("{addr} ({what})"),
                error,
            },
            other => other,
        },
    }
}

type EventStream = MessageStream<pb::NodeEvent>;
type ProgramStream = MessageStream<pb::DownloadProgramProgress>;
type PdoStream = MessageStream<pb::PdoMessage>;

#[tonic::async_trait]
impl Canopen for CanopenService {
    type DownloadProgramStream = ProgramStream;

    async fn download_program(
        &self,
        req: Request<pb::DownloadProgramRequest>,
    ) -> Result<Response<Self::DownloadProgramStream>, Status> {
        let caller = sdo_caller(&req);
        let req = req.into_inner();
        let m = self.master(&req.bus)?;
        let node = known_node(m, req.node)?;
        let plan = program_plan(node, req)?;
        let total = plan.image.len() as u64;
        let events = m.download_program(plan, &caller).map_err(|e| match e {
            ProgramStartError::AxisActive(e) => axis_active(e),
            e @ ProgramStartError::Busy { .. } => ApiError::refused(
                tonic::Code::FailedPrecondition,
                "PROGRAM_DOWNLOAD_RUNNING",
                e.to_string(),
                vec![("node", node.get().to_string())],
            ),
        })?;
        let (tx, rx) = tokio::sync::mpsc::channel(64);
        let mut last = pb::DownloadProgramProgress {
            bytes_total: total,
            ..Default::default()
        };
        spawn_forwarding(
            events,
            tx,
            Vec::new(),
            self.gateway.shutdown_token(),
            AtShutdown::Unavailable,
            move |ev| match ev {
                Some(Received::Item(ProgramEvent::Progress {
                    step,
                    bytes_done,
                    total,
                })) => {
                    last.step = program_step_to_pb(step) as i32;
                    last.bytes_done = bytes_done as u64;
                    last.bytes_total = total as u64;
                    Forward::Send(last)
                }
                Some(Received::Item(ProgramEvent::Finished(Ok(o)))) => {
                    last.bytes_done = o.bytes as u64;
                    last.outcome = Some(program_outcome_to_pb(&o));
                    Forward::Last(Ok(last))
                }
                Some(Received::Item(ProgramEvent::Finished(Err(e)))) => {
                    Forward::Last(Err(program_error(node, e).into()))
                }
                // A queue loses nothing.
                Some(Received::Lost(_)) => Forward::Skip,
                // The download's task ended without a word: the gateway is
                // going away.
                None => Forward::Last(Err(ApiError::ShuttingDown.into())),
            },
        );
        Ok(Response::new(Box::pin(
            tokio_stream::wrappers::ReceiverStream::new(rx),
        )))
    }

    async fn list_nodes(
        &self,
        req: Request<pb::ListNodesRequest>,
    ) -> Result<Response<pb::ListNodesResponse>, Status> {
        let bus = req.into_inner().bus;
        let masters: Vec<&CanopenBus> = if bus.is_empty() {
            self.gateway.canopen_buses().collect()
        } else {
            vec![self.master(&bus)?]
        };
        let mut nodes = Vec::new();
        for m in masters {
            let snap = m.snapshot().await.map_err(|_| ApiError::ShuttingDown)?;
            nodes.extend(snap.iter().map(|n| node_to_pb(m.bus(), n)));
        }
        Ok(Response::new(pb::ListNodesResponse { nodes }))
    }

    async fn get_node(
        &self,
        req: Request<pb::GetNodeRequest>,
    ) -> Result<Response<pb::Node>, Status> {
        let req = req.into_inner();
        let m = self.master(&req.bus)?;
        let id = known_node(m, req.node)?;
        let snap = m.snapshot().await.map_err(|_| ApiError::ShuttingDown)?;
        let n = snap
            .iter()
            .find(|n| n.id == id)
            .ok_or_else(|| ApiError::NotFound {
                kind: "node",
                name: req.node.to_string(),
                hint: String::new(),
            })?;
        Ok(Response::new(node_to_pb(m.bus(), n)))
    }

    async fn send_nmt(
        &self,
        req: Request<pb::SendNmtRequest>,
    ) -> Result<Response<pb::SendNmtResponse>, Status> {
        let req = req.into_inner();
        let m = self.master(&req.bus)?;
        let target = if req.node == 0 {
            None
        } else {
            Some(node_id(req.node)?)
        };
        let cmd = match pb::NmtCommand::try_from(req.command) {
            Ok(pb::NmtCommand::Start) => NmtCommand::Start,
            Ok(pb::NmtCommand::Stop) => NmtCommand::Stop,
            Ok(pb::NmtCommand::EnterPreOperational) => NmtCommand::EnterPreOperational,
            Ok(pb::NmtCommand::ResetNode) => NmtCommand::ResetNode,
            Ok(pb::NmtCommand::ResetCommunication) => NmtCommand::ResetCommunication,
            _ => {
                return Err(ApiError::InvalidArgument(format!(
                    "NMT command {} is not one of START, STOP, ENTER_PRE_OPERATIONAL, RESET_NODE, RESET_COMMUNICATION",
                    req.command
                ))
                .into());
            }
        };
        m.client_nmt(cmd, target, req.force)
            .await
            .map_err(|e| map_err(target.unwrap_or(NodeId::new(1).expect("1 is valid")), e))?;
        Ok(Response::new(pb::SendNmtResponse {}))
    }

    async fn read_sdo(
        &self,
        req: Request<pb::ReadSdoRequest>,
    ) -> Result<Response<pb::ReadSdoResponse>, Status> {
        let caller = sdo_caller(&req);
        let m = self.master(&req.get_ref().bus)?;
        Ok(Response::new(read_sdo(m, req.into_inner(), &caller).await?))
    }

    async fn write_sdo(
        &self,
        req: Request<pb::WriteSdoRequest>,
    ) -> Result<Response<pb::WriteSdoResponse>, Status> {
        let caller = sdo_caller(&req);
        let m = self.master(&req.get_ref().bus)?;
        Ok(Response::new(
            write_sdo(m, req.into_inner(), &caller).await?,
        ))
    }

    type SdoSessionStream = MessageStream<pb::SdoSessionAnswer>;

    async fn sdo_session(
        &self,
        req: Request<tonic::Streaming<pb::SdoSessionRequest>>,
    ) -> Result<Response<Self::SdoSessionStream>, Status> {
        let caller = Arc::new(Caller {
            name: sdo_caller(&req),
            identity: req.extensions().get::<Identity>().cloned(),
            refused_writes: Default::default(),
            budget: req.extensions().get::<RequestBudget>().cloned(),
        });
        let gateway = self.gateway.clone();
        Ok(Response::new(sdo_session::serve(
            gateway.shutdown_token(),
            req.into_inner(),
            move |request| session_answer(gateway.clone(), caller.clone(), request),
        )))
    }

    async fn list_objects(
        &self,
        req: Request<pb::ListObjectsRequest>,
    ) -> Result<Response<pb::ListObjectsResponse>, Status> {
        let req = req.into_inner();
        let m = self.master(&req.bus)?;
        let node = known_node(m, req.node)?;
        let eds = node_eds(m, node, "its objects are not known")?;
        let objects = eds
            .od
            .variables()
            .map(|v| object_info_to_pb(&eds.od, v, node))
            .collect();
        Ok(Response::new(pb::ListObjectsResponse { objects }))
    }

    async fn list_sdo_transfers(
        &self,
        req: Request<pb::ListSdoTransfersRequest>,
    ) -> Result<Response<pb::ListSdoTransfersResponse>, Status> {
        let m = self.master(&req.get_ref().bus)?;
        let list = m.transfers().await.map_err(|_| ApiError::ShuttingDown)?;
        let transfers = list
            .iter()
            .map(|(node, p)| sdo_transfer_to_pb(*node, p))
            .collect();
        Ok(Response::new(pb::ListSdoTransfersResponse { transfers }))
    }

    async fn scan_network(
        &self,
        req: Request<pb::ScanNetworkRequest>,
    ) -> Result<Response<pb::ScanNetworkResponse>, Status> {
        let caller = sdo_caller(&req);
        let req = req.into_inner();
        let m = self.master(&req.bus)?.clone();
        if req.timeout_ms > MAX_SCAN_TIMEOUT_MS {
            return Err(ApiError::InvalidArgument(format!(
                "scan timeout_ms {} is above the maximum of {MAX_SCAN_TIMEOUT_MS} ms",
                req.timeout_ms
            ))
            .into());
        }
        let timeout = Duration::from_millis(if req.timeout_ms == 0 {
            100
        } else {
            req.timeout_ms as u64
        });
        let ids = m.scan(timeout, caller.as_str()).await;
        let snap = m.snapshot().await.map_err(|_| ApiError::ShuttingDown)?;
        let nodes = snap
            .iter()
            .filter(|n| ids.contains(&n.id))
            .map(|n| node_to_pb(m.bus(), n))
            .collect();
        Ok(Response::new(pb::ScanNetworkResponse { nodes }))
    }

    type StreamPdoStream = PdoStream;

    async fn stream_pdo(
        &self,
        req: Request<pb::StreamPdoRequest>,
    ) -> Result<Response<Self::StreamPdoStream>, Status> {
        let req = req.into_inner();
        let masters: Vec<CanopenBus> = if req.bus.is_empty() {
            self.gateway.canopen_buses().cloned().collect()
        } else {
            vec![self.master(&req.bus)?.clone()]
        };
        let only = node_filter(&req.nodes)?;
        let (tx, rx) = tokio::sync::mpsc::channel(1024);
        let cancel = self.gateway.shutdown_token();
        for m in masters {
            let only = only.clone();
            let mut lost = 0u64;
            spawn_forward(
                "StreamPdo",
                m.pdos(),
                tx.clone(),
                Vec::new(),
                cancel.clone(),
                AtShutdown::End,
                move |received| {
                    let u = match received {
                        Received::Item(u) => u,
                        // Told with the next message (lost_before).
                        Received::Lost(n) => {
                            lost += n;
                            return None;
                        }
                    };
                    if !only.is_empty() && !only.contains(&(u.node.get() as u32)) {
                        return None;
                    }
                    Some(pb::PdoMessage {
                        bus: m.bus().to_string(),
                        node: u.node.get() as u32,
                        pdo: u.num as u32,
                        cob_id: u.cob_id as u32,
                        timestamp_ns: u.at.as_nanos(),
                        values: u
                            .values
                            .iter()
                            .map(|(mo, v, name)| pb::PdoValue {
                                index: mo.addr.index as u32,
                                subindex: mo.addr.sub as u32,
                                name: name.clone(),
                                value: Some(value_to_pb(v)),
                            })
                            .collect(),
                        lost_before: std::mem::take(&mut lost),
                    })
                },
            );
        }
        Ok(Response::new(stream_of(rx)))
    }

    async fn write_pdo(
        &self,
        req: Request<pb::WritePdoRequest>,
    ) -> Result<Response<pb::WritePdoResponse>, Status> {
        let req = req.into_inner();
        let m = self.master(&req.bus)?;
        let node = known_node(m, req.node)?;
        let num = u16::try_from(req.pdo).unwrap_or(0);
        let cfg = m.rpdo(node, num).ok_or_else(|| ApiError::NotFound {
            kind: "RPDO",
            name: format!("{} of node {}", req.pdo, req.node),
            hint: " (configure it under [[canopen.node.rpdo]] or give the node an EDS)".into(),
        })?;
        // An RPDO that commands an enabled or moving axis's drive is the
        // axis's, as a raw SDO write of those objects is.
        m.check_rpdo_write(node, &cfg)
            .map_err(|e| map_err(node, CanopenError::AxisActive(e)))?;
        let values =
            req.values
                .iter()
                .map(|v| {
                    let addr = address(v.index, v.subindex)?;
                    let value =
                        value_from_pb(v.value.as_ref().ok_or_else(|| {
                            ApiError::InvalidArgument(format!("{addr}: no value"))
                        })?)?;
                    Ok((addr, value))
                })
                .collect::<Result<Vec<_>, ApiError>>()?;
        // Every value must name a mapped object, once: a value the PDO
        // does not carry would otherwise be dropped without a word.
        for (i, (addr, _)) in values.iter().enumerate() {
            if !cfg.mapping.iter().any(|mo| mo.addr == *addr) {
                let mapped: Vec<String> =
                    cfg.mapping.iter().map(|mo| mo.addr.to_string()).collect();
                return Err(ApiError::InvalidArgument(format!(
                    "RPDO {} of node {} does not map {addr} (it maps {})",
                    req.pdo,
                    req.node,
                    if mapped.is_empty() {
                        "nothing".to_string()
                    } else {
                        mapped.join(", ")
                    }
                ))
                .into());
            }
            if values[..i].iter().any(|(a, _)| a == addr) {
                return Err(ApiError::InvalidArgument(format!(
                    "{addr} is given more than once for RPDO {} of node {}",
                    req.pdo, req.node
                ))
                .into());
            }
        }
        let data = cfg
            .encode(&values)
            .map_err(|e| ApiError::InvalidArgument(e.to_string()))?;
        m.send_pdo(cfg.cob_id, &data)
            .await
            .map_err(|e| map_err(node, e))?;
        Ok(Response::new(pb::WritePdoResponse { data }))
    }

    async fn read_pdo_config(
        &self,
        req: Request<pb::ReadPdoConfigRequest>,
    ) -> Result<Response<pb::ReadPdoConfigResponse>, Status> {
        let caller = sdo_caller(&req);
        let req = req.into_inner();
        let m = self.master(&req.bus)?;
        let node = known_node(m, req.node)?;
        let opts = options(req.options.as_ref())?;
        let kinds = match pdo_kind_from_pb(req.kind)? {
            Some(k) => vec![k],
            None => vec![PdoKind::Rpdo, PdoKind::Tpdo],
        };
        let eds = m.eds(node);
        let od = eds.as_deref().map(|e| &e.od);
        let mut pdos = Vec::new();
        for kind in kinds {
            let nums: Vec<u16> = match req.pdo {
                0 => pdo_numbers(od, kind),
                n => vec![
                    u16::try_from(n)
                        .ok()
                        .filter(|n| (1..=512).contains(n))
                        .ok_or_else(|| {
                            ApiError::InvalidArgument(format!(
                                "PDO number {n} is out of range (1..=512)"
                            ))
                        })?,
                ],
            };
            for num in nums {
                match m.read_pdo(node, kind, num, opts, &caller).await {
                    Ok(Some(p)) => pdos.push(pdo_to_pb(&p, od)),
                    Ok(None) => {}
                    Err(e) => return Err(pdo_config_err(node, e).into()),
                }
            }
        }
        Ok(Response::new(pb::ReadPdoConfigResponse { pdos }))
    }

    async fn configure_pdo(
        &self,
        req: Request<pb::ConfigurePdoRequest>,
    ) -> Result<Response<pb::ConfigurePdoResponse>, Status> {
        let caller = sdo_caller(&req);
        let req = req.into_inner();
        let m = self.master(&req.bus)?;
        let node = known_node(m, req.node)?;
        let opts = options(req.options.as_ref())?;
        let given = req.pdo.as_ref().ok_or_else(|| {
            ApiError::InvalidArgument("pdo: the PDO's parameters are missing".into())
        })?;
        let eds = m.eds(node);
        let od = eds.as_deref().map(|e| &e.od);
        let pdo = pdo_from_pb(given, node, od)?;
        let writes = m
            .configure_pdo(node, &pdo, opts, &caller)
            .await
            .map_err(|e| pdo_config_err(node, e))?;
        Ok(Response::new(pb::ConfigurePdoResponse {
            pdo: Some(pdo_to_pb(&pdo, od)),
            writes: writes
                .iter()
                .map(|(addr, data)| {
                    let hex: Vec<String> = data.iter().map(|b| format!("{b:02X}")).collect();
                    format!("{addr} = {}", hex.join(" "))
                })
                .collect(),
        }))
    }

    async fn get_sync(
        &self,
        req: Request<pb::GetSyncRequest>,
    ) -> Result<Response<pb::SyncStatus>, Status> {
        let m = self.master(&req.get_ref().bus)?;
        Ok(Response::new(sync_status(m)))
    }

    async fn set_sync(
        &self,
        req: Request<pb::SetSyncRequest>,
    ) -> Result<Response<pb::SyncStatus>, Status> {
        let req = req.into_inner();
        let m = self.master(&req.bus)?;
        let mut s = m.sync_settings();
        if let Some(running) = req.running {
            s.running = running;
        }
        if let Some(us) = req.period_us {
            if !(MIN_SYNC_PERIOD_US..=MAX_SYNC_PERIOD_US).contains(&us) {
                return Err(ApiError::InvalidArgument(format!(
                    "SYNC period {us} µs is outside {MIN_SYNC_PERIOD_US}..={MAX_SYNC_PERIOD_US} µs"
                ))
                .into());
            }
            s.period = Duration::from_micros(u64::from(us));
        }
        if let Some(c) = req.counter_overflow {
            s.counter_overflow = u8::try_from(c)
                .ok()
                .filter(|c| *c == 0 || (2..=240).contains(c))
                .ok_or_else(|| {
                    ApiError::InvalidArgument(format!(
                        "SYNC counter overflow {c} is reserved: use 0 (no counter) or 2..=240"
                    ))
                })?;
        }
        m.set_sync(s).map_err(|e| match e {
            SyncChangeError::Invalid(e) => ApiError::InvalidArgument(e.to_string()),
            SyncChangeError::Vetoed(why) => ApiError::FailedPrecondition(format!(
                "the SYNC of bus {} cannot stop or change its period now: {why}",
                m.bus()
            )),
            e @ SyncChangeError::NoProducer => ApiError::Unavailable(e.to_string()),
        })?;
        Ok(Response::new(sync_status(m)))
    }

    async fn set_time(
        &self,
        req: Request<pb::SetTimeRequest>,
    ) -> Result<Response<pb::SetTimeResponse>, Status> {
        let req = req.into_inner();
        let m = self.master(&req.bus)?;
        if let Some(ms) = req.period_ms {
            if ms > MAX_TIME_PERIOD_MS {
                return Err(ApiError::InvalidArgument(format!(
                    "TIME period {ms} ms is above one day ({MAX_TIME_PERIOD_MS} ms)"
                ))
                .into());
            }
            let least = crate::canopen::MIN_TIME_PERIOD;
            if ms > 0 && Duration::from_millis(u64::from(ms)) < least {
                return Err(ApiError::InvalidArgument(format!(
                    "TIME period {ms} ms is too short: give at least {} ms (0 stops the periodic TIME)",
                    least.as_millis()
                ))
                .into());
            }
            m.set_time_period((ms > 0).then(|| Duration::from_millis(u64::from(ms))));
        }
        let sent = if req.send_now {
            let t = m.send_time().await.map_err(|e| match e {
                TimeSendError::Send(f) => ApiError::from(f),
                e @ TimeSendError::Clock(_) => ApiError::FailedPrecondition(e.to_string()),
            })?;
            Some(pb::TimeOfDay {
                ms_after_midnight: t.ms,
                days_since_1984: u32::from(t.days),
                unix_ms: t.to_unix().as_millis() as u64,
            })
        } else {
            None
        };
        Ok(Response::new(pb::SetTimeResponse {
            sent,
            time_period_ms: time_period_ms(m),
        }))
    }

    async fn export_dcf(
        &self,
        req: Request<pb::ExportDcfRequest>,
    ) -> Result<Response<pb::ExportDcfResponse>, Status> {
        let caller = sdo_caller(&req);
        let req = req.into_inner();
        let m = self.master(&req.bus)?;
        let node = known_node(m, req.node)?;
        let opts = options(req.options.as_ref())?;
        let export = m
            .export_dcf(node, opts, &caller)
            .await
            .map_err(|e| match e {
                e @ DcfExportError::NoEds(_) => ApiError::FailedPrecondition(e.to_string()),
                DcfExportError::Canopen(e) => map_err(node, e),
            })?;
        Ok(Response::new(pb::ExportDcfResponse {
            dcf: export.text,
            objects_read: export.read as u32,
            skipped: export
                .skipped
                .into_iter()
                .map(|(a, reason)| pb::SkippedObject {
                    index: u32::from(a.index),
                    subindex: u32::from(a.sub),
                    reason,
                })
                .collect(),
        }))
    }

    type StreamNodeEventsStream = EventStream;

    async fn stream_node_events(
        &self,
        req: Request<pb::StreamNodeEventsRequest>,
    ) -> Result<Response<Self::StreamNodeEventsStream>, Status> {
        let req = req.into_inner();
        let masters: Vec<CanopenBus> = if req.bus.is_empty() {
            self.gateway.canopen_buses().cloned().collect()
        } else {
            vec![self.master(&req.bus)?.clone()]
        };
        let only: Vec<u32> = node_filter(&req.nodes)?;
        let (tx, rx) = tokio::sync::mpsc::channel(256);
        let cancel = self.gateway.shutdown_token();
        for m in masters {
            let only = only.clone();
            spawn_forward(
                "StreamNodeEvents",
                m.events(),
                tx.clone(),
                Vec::new(),
                cancel.clone(),
                AtShutdown::End,
                move |received| match received {
                    Received::Item(ev) => (only.is_empty()
                        || only.contains(&(ev.node.get() as u32)))
                    .then(|| node_event_to_pb(m.bus(), &ev)),
                    Received::Lost(n) => Some(node_events_lost_to_pb(m.bus(), n)),
                },
            );
        }
        Ok(Response::new(stream_of(rx)))
    }
}

/// The longest flash or boot timeout of DownloadProgram, ms.
const MAX_PROGRAM_WAIT_MS: u32 = 600_000;
/// The largest program image.
const MAX_PROGRAM_IMAGE: usize = 16 * 1024 * 1024;

fn program_plan(node: NodeId, req: pb::DownloadProgramRequest) -> Result<ProgramPlan, ApiError> {
    if req.image.is_empty() {
        return Err(ApiError::InvalidArgument(
            "the program image is empty".into(),
        ));
    }
    if req.image.len() > MAX_PROGRAM_IMAGE {
        return Err(ApiError::InvalidArgument(format!(
            "the program image has {} bytes, at most {MAX_PROGRAM_IMAGE} are accepted",
            req.image.len()
        )));
    }
    let program = match req.program {
        0 => 1,
        p @ 1..=254 => p as u8,
        p => {
            return Err(ApiError::InvalidArgument(format!(
                "program number {p} is outside 1..=254"
            )));
        }
    };
    let wait = |what: &str, ms: u32, default: Duration| -> Result<Duration, ApiError> {
        match ms {
            0 => Ok(default),
            ms if ms > MAX_PROGRAM_WAIT_MS => Err(ApiError::InvalidArgument(format!(
                "{what} {ms} is above the maximum of {MAX_PROGRAM_WAIT_MS} ms"
            ))),
            ms => Ok(Duration::from_millis(u64::from(ms))),
        }
    };
    let defaults = ProgramTimeouts::default();
    let timeouts = ProgramTimeouts {
        flash: wait("flash_timeout_ms", req.flash_timeout_ms, defaults.flash)?,
        boot: wait("boot_timeout_ms", req.boot_timeout_ms, defaults.boot)?,
        poll_interval: defaults.poll_interval,
    };
    Ok(ProgramPlan {
        node,
        program,
        image: req.image,
        expected_identification: req.expected_identification,
        clear: req.clear,
        timeouts,
    })
}

/// A failed program download as the API reports it (see DownloadProgram
/// in canopen.proto).
fn program_error(node: NodeId, f: ProgramFailure) -> ApiError {
    let step_meta = |step: ProgramStep| ("step", step.name().to_string());
    match f {
        ProgramFailure::Program(ProgramError::Sdo { step, error })
        | ProgramFailure::Gateway {
            step,
            error: CanopenError::Sdo(error),
        } => ApiError::SdoInStep {
            node: node.get(),
            step: step.name(),
            context: step.to_string(),
            error,
        },
        ProgramFailure::Gateway { error, .. } => map_err(node, error),
        ProgramFailure::AxisActive(e, _) => axis_active(e),
        ProgramFailure::Program(e) => {
            let message = format!("node {node}, {e}");
            match e {
                ProgramError::Flash { status } => ApiError::refused(
                    tonic::Code::Aborted,
                    "PROGRAM_FLASH_ERROR",
                    message,
                    vec![
                        step_meta(ProgramStep::WaitFlash),
                        ("flash_status", format!("0x{:08X}", status.0)),
                        ("flash_error", status.error_code().to_string()),
                        ("flash_error_name", status.error_name().to_string()),
                    ],
                ),
                ProgramError::FlashTimeout { last, .. } => ApiError::refused(
                    tonic::Code::DeadlineExceeded,
                    "PROGRAM_FLASH_TIMEOUT",
                    message,
                    vec![
                        step_meta(ProgramStep::WaitFlash),
                        ("flash_status", format!("0x{:08X}", last.0)),
                    ],
                ),
                ProgramError::NoBootUp { .. } => ApiError::refused(
                    tonic::Code::DeadlineExceeded,
                    "PROGRAM_NO_BOOT_UP",
                    message,
                    vec![step_meta(ProgramStep::WaitBootUp)],
                ),
                ProgramError::IdentificationMismatch { expected, found } => ApiError::refused(
                    tonic::Code::Aborted,
                    "PROGRAM_IDENTIFICATION_MISMATCH",
                    message,
                    vec![
                        step_meta(ProgramStep::ReadIdentificationAfter),
                        ("expected", format!("0x{expected:08X}")),
                        ("found", format!("0x{found:08X}")),
                    ],
                ),
                ProgramError::BadValue { step, .. } => ApiError::refused(
                    tonic::Code::Aborted,
                    "ABORTED",
                    message,
                    vec![step_meta(step)],
                ),
                ProgramError::Sdo { .. } => unreachable!("matched above"),
            }
        }
    }
}

/// ReadSdo, for the unary call and an SdoSession alike (`caller`: whose
/// request, see [`sdo_caller`]).
async fn read_sdo(
    m: &CanopenBus,
    req: pb::ReadSdoRequest,
    caller: &str,
) -> Result<pb::ReadSdoResponse, ApiError> {
    let node = known_node(m, req.node)?;
    let addr = target(m, node, &req.object, req.index, req.subindex)?;
    let ty = match data_type_from_pb(req.r#type)? {
        Some(t) => Some(t),
        None => m
            .eds(node)
            .and_then(|e| e.od.get(addr).map(|v| v.data_type)),
    };
    let opts = options(req.options.as_ref())?;
    let out = m
        .client_sdo(node, SdoRequest::Upload { addr, opts }, caller)
        .await
        .map_err(|e| map_err(node, e))?;
    let TransferOutcome::Uploaded(raw) = out else {
        return Err(ApiError::Unavailable("unexpected SDO outcome".into()));
    };
    let value = match ty {
        Some(t) => Some(value_to_pb(&Value::decode(t, &raw).map_err(|e| {
            ApiError::InvalidArgument(format!("{addr} read {} bytes but: {e}", raw.len()))
        })?)),
        None => None,
    };
    Ok(pb::ReadSdoResponse { raw, value })
}

/// WriteSdo, for the unary call and an SdoSession alike. The caller's role
/// is checked before (security/roles.rs): `force` is its decision.
async fn write_sdo(
    m: &CanopenBus,
    req: pb::WriteSdoRequest,
    caller: &str,
) -> Result<pb::WriteSdoResponse, ApiError> {
    let node = known_node(m, req.node)?;
    let addr = target(m, node, &req.object, req.index, req.subindex)?;
    // Only an engineer reaches here (WriteSdo's role in security/roles.rs,
    // checked per request in an SdoSession), so `force` is an engineer's
    // decision.
    if !req.force {
        m.check_sdo_write(node, addr).map_err(axis_active)?;
    }
    let opts = options(req.options.as_ref())?;
    let data = match req.data {
        Some(pb::write_sdo_request::Data::Raw(b)) => {
            // Checked before anything is sent: a value larger than a
            // fixed-size object would otherwise stream to the node until
            // it aborts. Objects the EDS does not know, or of variable
            // size (strings, domains), take any size.
            if let Some(var) = m.eds(node).and_then(|e| e.od.get(addr).cloned())
                && let Some(size) = var.data_type.fixed_size()
                && b.len() > size
            {
                return Err(ApiError::InvalidArgument(format!(
                    "{addr} ({}) is {} of {size} bytes; {} bytes do not fit",
                    var.name,
                    var.data_type,
                    b.len()
                )));
            }
            b
        }
        Some(pb::write_sdo_request::Data::Value(v)) => {
            let var = m.eds(node).and_then(|e| e.od.get(addr).cloned());
            let value = match (data_type_from_pb(v.r#type)?, &var) {
                (Some(_), _) => value_from_pb(&v)?,
                // No type given: the EDS has it.
                (None, Some(var)) => value_from_pb_as(&v, var.data_type).map_err(|e| {
                    ApiError::InvalidArgument(format!(
                        "{addr} ({}, {}): {e}",
                        var.name, var.data_type
                    ))
                })?,
                (None, None) => {
                    return Err(ApiError::InvalidArgument(format!(
                        "the value has no data type, and the gateway has no EDS entry \
                         for {addr} of node {node} to take it from: give the type"
                    )));
                }
            };
            if let Some(var) = var {
                var.check(&value).map_err(|e| {
                    ApiError::InvalidArgument(format!("{addr} ({}): {e}", var.name))
                })?;
            }
            value.encode()
        }
        None => {
            return Err(ApiError::InvalidArgument(
                "nothing to write: give value or raw".into(),
            ));
        }
    };
    let n = data.len() as u32;
    m.client_sdo(node, SdoRequest::Download { addr, data, opts }, caller)
        .await
        .map_err(|e| map_err(node, e))?;
    Ok(pb::WriteSdoResponse { bytes: n })
}

/// Runs one request of an SdoSession as ReadSdo/WriteSdo: its answer.
async fn session_answer(
    gateway: Arc<Gateway>,
    caller: Arc<Caller>,
    request: pb::SdoSessionRequest,
) -> pb::SdoSessionAnswer {
    use pb::sdo_session_answer::Result as A;
    use pb::sdo_session_request::Request as R;
    let result = match request.request {
        Some(R::Read(q)) => async {
            check_role(&caller, "ReadSdo")?;
            let m = master_of(&gateway, &q.bus)?;
            read_sdo(m, q, &caller.name).await
        }
        .await
        .map(A::Read),
        Some(R::Write(q)) => {
            let (bus, node, index, sub, object) =
                (q.bus.clone(), q.node, q.index, q.subindex, q.object.clone());
            let result = async {
                check_role(&caller, "WriteSdo")?;
                let m = master_of(&gateway, &q.bus)?;
                write_sdo(m, q, &caller.name).await
            }
            .await;
            audit_write(&caller, &bus, node, index, sub, &object, &result);
            result.map(A::Write)
        }
        None => Err(ApiError::InvalidArgument(
            "an SdoSession request needs read or write".into(),
        )),
    };
    pb::SdoSessionAnswer {
        id: request.id,
        result: Some(result.unwrap_or_else(|e| A::Error(e.into()))),
    }
}
