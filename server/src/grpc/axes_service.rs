//! The `cangate.v1.Axes` service: a thin shell over
//! [`Axes`](crate::axes::Axes): validation of the request, the caller's
//! identity and lease as a [`Caller`], conversion to protobuf. The control
//! rules and the audit of commands are the runtime's.

use super::error::ApiError;
use super::forward::{AtShutdown, MessageStream, Received, spawn_forward, stream_of};
use crate::axes::{Axes, AxisUpdate, Caller, CommandResult};
use crate::convert::axes::{event_pb, outcome_pb, resolution, status_pb};
use crate::gateway::Gateway;
use crate::security::StopOverBudget;
use cangate_axis::cia402::AxisSnapshot;
use cangate_axis::{
    AxisCommand, DriveMode, DriveSpec, Outcome, PositionMode, ProcessDataPath, StopKind,
};
use cangate_can::Timestamp;
use cangate_proto::v1 as pb;
use cangate_proto::v1::axes_server::Axes as AxesRpc;
use std::sync::Arc;
use std::time::Duration;
use tonic::{Request, Response, Status};

/// Implementation of the Axes service.
#[derive(Clone)]
pub struct AxesService {
    gateway: Arc<Gateway>,
    /// Longest `client_name` accepted, in bytes.
    max_name_bytes: usize,
}

/// `client_name` limit when none is configured (see
/// `[security.limits] max_name_bytes`).
pub const DEFAULT_MAX_NAME_BYTES: usize = 128;

impl AxesService {
    /// Serves the gateway's axes.
    pub fn new(gateway: Arc<Gateway>) -> Self {
        AxesService {
            gateway,
            max_name_bytes: DEFAULT_MAX_NAME_BYTES,
        }
    }

    /// Accepts `client_name`s of at most `bytes` bytes (names are copied
    /// into every axis status, so they must stay small).
    pub fn with_max_name_bytes(mut self, bytes: usize) -> Self {
        self.max_name_bytes = bytes;
        self
    }

    fn axes(&self) -> &Axes {
        self.gateway.axes()
    }

    fn axis_pb(&self, i: usize) -> pb::Axis {
        let m = self.axes();
        let spec = m.spec(i);
        let c = &spec.motion;
        let (process_data, sdo_poll) = match &spec.drive {
            DriveSpec::Cansmc(_) => (pb::ProcessDataPath::Unspecified, None),
            DriveSpec::Cia402(d) => match d.process_data {
                ProcessDataPath::Pdo => (pb::ProcessDataPath::Pdo, None),
                ProcessDataPath::Sdo { poll } => (pb::ProcessDataPath::Sdo, Some(poll)),
            },
        };
        pb::Axis {
            name: spec.name.clone(),
            backend: match spec.drive {
                DriveSpec::Cansmc(_) => pb::AxisBackend::Cansmc,
                DriveSpec::Cia402(_) => pb::AxisBackend::Cia402,
            } as i32,
            bus: spec.bus().to_string(),
            node: u32::from(spec.node()),
            unit: c.unit.clone(),
            counts_per_unit: c.units.counts_per_unit,
            display_decimals: u32::from(c.display_decimals),
            min_position: c.min_position,
            max_position: c.max_position,
            max_velocity: c.max_velocity,
            max_acceleration: c.max_acceleration,
            position_mode: match spec.position_mode() {
                PositionMode::Profile => pb::PositionMode::Profile,
                PositionMode::Cyclic => pb::PositionMode::Cyclic,
            } as i32,
            stop_on_loss: match spec.stop_on_loss {
                StopKind::Halt => pb::StopKind::Halt,
                StopKind::QuickStop => pb::StopKind::QuickStop,
            } as i32,
            jog_deadman_ms: c.jog_deadman.as_millis() as u32,
            status: Some(self.status_pb(i, None)),
            process_data: process_data as i32,
            sdo_poll_ms: sdo_poll.map_or(0, |p| p.as_millis() as u32),
            mode: match &spec.drive {
                DriveSpec::Cia402(d) => drive_mode_pb(d.mode),
                DriveSpec::Cansmc(_) => pb::DriveMode::Unspecified,
            } as i32,
            max_torque: match &spec.drive {
                DriveSpec::Cia402(d) => d.torque.max_torque,
                DriveSpec::Cansmc(_) => 0.0,
            },
        }
    }

    /// The status of axis `i`: `snap` or the latest known.
    fn status_pb(&self, i: usize, snap: Option<(&AxisSnapshot, Timestamp)>) -> pb::AxisStatus {
        let m = self.axes();
        let latest = m.latest(i);
        let (snapshot, at) = match (snap, &latest) {
            (Some((s, t)), _) => (Some(s), t),
            (None, Some((s, t))) => (Some(s.as_ref()), *t),
            (None, None) => (None, Timestamp(0)),
        };
        status_pb(m, i, snapshot, at)
    }

    fn result_pb(&self, i: usize, r: CommandResult) -> pb::AxisCommandResponse {
        pb::AxisCommandResponse {
            outcome: outcome_pb(r.outcome) as i32,
            detail: r.detail,
            status: Some(self.status_pb(i, Some((&r.snapshot, Timestamp::now())))),
        }
    }

    async fn run(
        &self,
        peer: String,
        owner: Option<String>,
        axis: &str,
        cmd: AxisCommand,
        options: Option<pb::CommandOptions>,
    ) -> Result<pb::AxisCommandResponse, ApiError> {
        let m = self.axes();
        let i = m.index(axis)?;
        let opts = options.unwrap_or_default();
        let caller = Caller::new(peer)
            .with_identity(owner)
            .with_lease(opts.lease);
        let wait_timeout = Duration::from_millis(match opts.wait_timeout_ms {
            0 => 60_000,
            t => u64::from(t),
        });
        let res = m.command(i, cmd, &caller, opts.wait, wait_timeout).await?;
        if opts.wait {
            check_outcome(axis, &res)?;
        }
        Ok(self.result_pb(i, res))
    }
}

impl AxesService {
    /// A stop of a client over its stop budget ([`StopOverBudget`]) is
    /// refused only when every axis it names is at rest: a stop of an axis
    /// in motion always goes through.
    fn check_stop_budget<T>(&self, req: &Request<T>, idx: &[usize]) -> Result<(), ApiError> {
        let Some(over) = req.extensions().get::<StopOverBudget>() else {
            return Ok(());
        };
        refuse_resting_stop(self.axes(), over, idx)
    }

    /// A command without parameters (Enable, Stop, …) on the request's axis.
    async fn simple(
        &self,
        req: Request<pb::AxisCommandRequest>,
        cmd: AxisCommand,
    ) -> Result<Response<pb::AxisCommandResponse>, Status> {
        let peer = peer(&req);
        let owner = owner(&req);
        let r = req.into_inner();
        Ok(Response::new(
            self.run(peer, owner, &r.axis, cmd, r.options).await?,
        ))
    }
}

/// With `wait`, a command that did not complete ends the call with an
/// error code that says why (the outcome is in the message).
fn check_outcome(axis: &str, r: &CommandResult) -> Result<(), ApiError> {
    match r.outcome {
        None | Some(Outcome::Completed) => Ok(()),
        Some(Outcome::Timeout) => Err(ApiError::DeadlineExceeded(format!(
            "axis {axis}: {}",
            r.detail
        ))),
        Some(o) => Err(ApiError::Aborted(format!(
            "axis {axis}: {}: {}",
            o.name(),
            r.detail
        ))),
    }
}

/// The refusal of a stop over its client's budget when all its axes are at
/// rest (see [`AxesService::check_stop_budget`]).
fn refuse_resting_stop(m: &Axes, over: &StopOverBudget, idx: &[usize]) -> Result<(), ApiError> {
    if !m.all_at_rest(idx) {
        return Ok(());
    }
    Err(ApiError::refused(
        tonic::Code::ResourceExhausted,
        "STOP_BUDGET_EXHAUSTED",
        format!(
            "{}; refused because every axis named is at rest (a stop of a moving axis is \
             never refused)",
            over.0
        ),
        Vec::new(),
    ))
}

fn peer<T>(req: &Request<T>) -> String {
    super::caller(req)
}

/// The identity a lease is bound to: the authenticated caller (`token
/// operator-1`, `certificate hmi-2`), none with authentication off.
fn owner<T>(req: &Request<T>) -> Option<String> {
    req.extensions()
        .get::<crate::security::Identity>()
        .filter(|id| id.method != "none")
        .map(|id| format!("{} {}", id.method, id.name))
}

/// A move's velocity or acceleration: 0 for the axis default, else
/// positive, finite and not below the drive's resolution (the maximum is
/// the axis layer's check).
fn motion_value(
    what: &str,
    v: f64,
    counts_per_unit: f64,
    unit: &str,
) -> Result<Option<f64>, ApiError> {
    let v = positive_or_default(what, v)?;
    let least = resolution(counts_per_unit);
    if let Some(v) = v
        && v < least
    {
        return Err(ApiError::InvalidArgument(format!(
            "{what} {v:e} {unit} is below what the drive can carry out (one count: {least} \
             {unit}); the move would never end"
        )));
    }
    Ok(v)
}

fn positive_or_default(what: &str, v: f64) -> Result<Option<f64>, ApiError> {
    if v == 0.0 {
        Ok(None)
    } else if v.is_finite() && v > 0.0 {
        Ok(Some(v))
    } else {
        Err(ApiError::InvalidArgument(format!(
            "{what} must be positive (0 = the axis default), got {v}"
        )))
    }
}

type UpdateStream = MessageStream<pb::AxisUpdate>;

#[tonic::async_trait]
impl AxesRpc for AxesService {
    async fn list_axes(
        &self,
        _req: Request<pb::ListAxesRequest>,
    ) -> Result<Response<pb::ListAxesResponse>, Status> {
        let axes = (0..self.axes().len()).map(|i| self.axis_pb(i)).collect();
        Ok(Response::new(pb::ListAxesResponse { axes }))
    }

    async fn get_axis(
        &self,
        req: Request<pb::GetAxisRequest>,
    ) -> Result<Response<pb::Axis>, Status> {
        let i = self.axes().index(&req.get_ref().axis)?;
        Ok(Response::new(self.axis_pb(i)))
    }

    async fn acquire_control(
        &self,
        req: Request<pb::AcquireControlRequest>,
    ) -> Result<Response<pb::ControlLease>, Status> {
        let peer = peer(&req);
        let owner = owner(&req);
        let r = req.into_inner();
        if r.client_name.len() > self.max_name_bytes {
            return Err(ApiError::InvalidArgument(format!(
                "client_name has {} bytes, at most {} are accepted \
                 ([security.limits] max_name_bytes)",
                r.client_name.len(),
                self.max_name_bytes
            ))
            .into());
        }
        if let Some(bad) = r.client_name.chars().find(|c| c.is_control()) {
            return Err(ApiError::InvalidArgument(format!(
                "client_name contains the control character {bad:?}"
            ))
            .into());
        }
        let holder = if r.client_name.is_empty() {
            peer.clone()
        } else {
            format!("{} ({peer})", r.client_name)
        };
        let lease = self.axes().acquire(
            &r.axes,
            // 0: the default.
            (r.ttl_ms != 0).then(|| Duration::from_millis(u64::from(r.ttl_ms))),
            holder.clone(),
            owner,
        );
        tracing::info!(target: "cangate::audit", %peer, %holder, axes = ?r.axes, result = %lease.as_ref().map_or_else(|e| format!("refused: {e}"), |_| "granted".into()), "acquire control");
        let lease = lease?;
        Ok(Response::new(pb::ControlLease {
            lease: lease.token,
            axes: lease.axes,
            holder: lease.holder,
            ttl_ms: lease.ttl.as_millis() as u32,
        }))
    }

    async fn renew_control(
        &self,
        req: Request<pb::RenewControlRequest>,
    ) -> Result<Response<pb::ControlLease>, Status> {
        let caller = Caller::new(peer(&req))
            .with_identity(owner(&req))
            .with_lease(req.into_inner().lease);
        let lease = self.axes().renew(&caller)?;
        Ok(Response::new(pb::ControlLease {
            lease: lease.token,
            axes: lease.axes,
            holder: lease.holder,
            ttl_ms: lease.ttl.as_millis() as u32,
        }))
    }

    async fn release_control(
        &self,
        req: Request<pb::ReleaseControlRequest>,
    ) -> Result<Response<pb::ReleaseControlResponse>, Status> {
        let peer = peer(&req);
        let caller = Caller::new(peer.clone())
            .with_identity(owner(&req))
            .with_lease(req.into_inner().lease);
        let lease = self.axes().release(&caller)?;
        tracing::info!(target: "cangate::audit", %peer, holder = %lease.holder, axes = ?lease.axes, "release control");
        Ok(Response::new(pb::ReleaseControlResponse {
            axes: lease.axes,
        }))
    }

    async fn enable(
        &self,
        req: Request<pb::AxisCommandRequest>,
    ) -> Result<Response<pb::AxisCommandResponse>, Status> {
        self.simple(req, AxisCommand::Enable).await
    }

    async fn disable(
        &self,
        req: Request<pb::AxisCommandRequest>,
    ) -> Result<Response<pb::AxisCommandResponse>, Status> {
        self.simple(req, AxisCommand::Disable).await
    }

    async fn home(
        &self,
        req: Request<pb::AxisCommandRequest>,
    ) -> Result<Response<pb::AxisCommandResponse>, Status> {
        self.simple(req, AxisCommand::Home).await
    }

    async fn r#move(
        &self,
        req: Request<pb::MoveRequest>,
    ) -> Result<Response<pb::AxisCommandResponse>, Status> {
        let peer = peer(&req);
        let owner = owner(&req);
        let r = req.into_inner();
        let i = self.axes().index(&r.axis)?;
        let c = &self.axes().spec(i).motion;
        let cmd = AxisCommand::Move {
            target: r.target,
            relative: r.relative,
            velocity: motion_value(
                "velocity",
                r.velocity,
                c.units.counts_per_unit,
                &format!("{}/s", c.unit),
            )?,
            acceleration: motion_value(
                "acceleration",
                r.acceleration,
                c.units.counts_per_unit,
                &format!("{}/s²", c.unit),
            )?,
        };
        Ok(Response::new(
            self.run(peer, owner, &r.axis, cmd, r.options).await?,
        ))
    }

    async fn jog(
        &self,
        req: Request<pb::JogRequest>,
    ) -> Result<Response<pb::AxisCommandResponse>, Status> {
        let peer = peer(&req);
        let owner = owner(&req);
        let r = req.into_inner();
        let i = self.axes().index(&r.axis)?;
        let c = &self.axes().spec(i).motion;
        let cmd = AxisCommand::Jog {
            velocity: r.velocity,
            acceleration: motion_value(
                "acceleration",
                r.acceleration,
                c.units.counts_per_unit,
                &format!("{}/s²", c.unit),
            )?,
        };
        Ok(Response::new(
            self.run(peer, owner, &r.axis, cmd, r.options).await?,
        ))
    }

    async fn stop(
        &self,
        req: Request<pb::AxisCommandRequest>,
    ) -> Result<Response<pb::AxisCommandResponse>, Status> {
        let i = self.axes().index(&req.get_ref().axis)?;
        self.check_stop_budget(&req, &[i])?;
        self.simple(req, AxisCommand::Stop).await
    }

    async fn quick_stop(
        &self,
        req: Request<pb::AxisCommandRequest>,
    ) -> Result<Response<pb::AxisCommandResponse>, Status> {
        let i = self.axes().index(&req.get_ref().axis)?;
        self.check_stop_budget(&req, &[i])?;
        self.simple(req, AxisCommand::QuickStop).await
    }

    async fn reset_fault(
        &self,
        req: Request<pb::AxisCommandRequest>,
    ) -> Result<Response<pb::AxisCommandResponse>, Status> {
        self.simple(req, AxisCommand::ResetFault).await
    }

    async fn arm_touch_probe(
        &self,
        req: Request<pb::ArmTouchProbeRequest>,
    ) -> Result<Response<pb::AxisCommandResponse>, Status> {
        use cangate_axis::signals::ProbeEdges;
        let peer = peer(&req);
        let owner = owner(&req);
        let r = req.into_inner();
        let m = self.axes();
        let i = m.index(&r.axis)?;
        let edges = match pb::TouchProbeEdge::try_from(r.edge) {
            Ok(pb::TouchProbeEdge::Unspecified) => ProbeEdges::Off,
            Ok(pb::TouchProbeEdge::Rising) => ProbeEdges::Rising,
            Ok(pb::TouchProbeEdge::Falling) => ProbeEdges::Falling,
            Ok(pb::TouchProbeEdge::Both) => ProbeEdges::Both,
            Err(_) => {
                return Err(ApiError::InvalidArgument(format!(
                    "edge {} is no TouchProbeEdge",
                    r.edge
                ))
                .into());
            }
        };
        let caller = Caller::new(peer)
            .with_identity(owner)
            .with_lease(r.options.unwrap_or_default().lease);
        let res = m
            .arm_touch_probe(i, edges, r.continuous, &caller)
            .await
            .map_err(ApiError::from)?;
        Ok(Response::new(self.result_pb(i, res)))
    }

    async fn set_torque(
        &self,
        req: Request<pb::SetTorqueRequest>,
    ) -> Result<Response<pb::AxisCommandResponse>, Status> {
        let peer = peer(&req);
        let owner = owner(&req);
        let r = req.into_inner();
        let cmd = AxisCommand::SetTorque {
            per_mille: r.torque_per_mille,
        };
        Ok(Response::new(
            self.run(peer, owner, &r.axis, cmd, r.options).await?,
        ))
    }

    async fn set_mode(
        &self,
        req: Request<pb::SetAxisModeRequest>,
    ) -> Result<Response<pb::AxisCommandResponse>, Status> {
        let peer = peer(&req);
        let owner = owner(&req);
        let r = req.into_inner();
        let mode = pb::DriveMode::try_from(r.mode)
            .ok()
            .and_then(drive_mode_from_pb)
            .ok_or_else(|| {
                ApiError::InvalidArgument(format!(
                    "mode {} is not a mode of operation: give one of DRIVE_MODE_PROFILE_POSITION, \
                     _CSP, _IP, _CSV, _CST, _PROFILE_TORQUE",
                    r.mode
                ))
            })?;
        let cmd = AxisCommand::SetMode { mode };
        Ok(Response::new(
            self.run(peer, owner, &r.axis, cmd, r.options).await?,
        ))
    }

    async fn stop_axes(
        &self,
        req: Request<pb::StopAxesRequest>,
    ) -> Result<Response<pb::MultiAxisResponse>, Status> {
        let peer = peer(&req);
        let over_budget = req.extensions().get::<StopOverBudget>().cloned();
        let r = req.into_inner();
        let m = self.axes();
        if r.axes.is_empty() {
            return Err(ApiError::InvalidArgument("name at least one axis".into()).into());
        }
        let idx = r
            .axes
            .iter()
            .map(|a| m.index(a))
            .collect::<Result<Vec<_>, _>>()?;
        let mut seen = std::collections::HashSet::new();
        for (name, i) in r.axes.iter().zip(&idx) {
            if !seen.insert(*i) {
                return Err(ApiError::InvalidArgument(format!(
                    "axis {name} is named twice (name each axis once)"
                ))
                .into());
            }
        }
        if let Some(over) = &over_budget {
            refuse_resting_stop(m, over, &idx)?;
        }
        let kind = if r.quick {
            StopKind::QuickStop
        } else {
            StopKind::Halt
        };
        let results = m.stop_many(&idx, kind, r.wait, &Caller::new(peer)).await?;
        let mut out = Vec::new();
        for (i, res) in idx.iter().zip(results) {
            out.push(match res {
                Ok(res) => self.result_pb(*i, res),
                Err(e) => pb::AxisCommandResponse {
                    outcome: pb::Outcome::Unspecified as i32,
                    detail: e.to_string(),
                    status: Some(self.status_pb(*i, None)),
                },
            });
        }
        Ok(Response::new(pb::MultiAxisResponse { results: out }))
    }

    async fn move_axes(
        &self,
        req: Request<pb::MoveAxesRequest>,
    ) -> Result<Response<pb::MultiAxisResponse>, Status> {
        let peer = peer(&req);
        let owner = owner(&req);
        let r = req.into_inner();
        let m = self.axes();
        let caller = Caller::new(peer).with_identity(owner).with_lease(r.lease);
        let mut targets = Vec::new();
        let mut seen = std::collections::HashSet::new();
        for t in &r.targets {
            let i = m.index(&t.axis)?;
            if !seen.insert(i) {
                return Err(
                    ApiError::InvalidArgument(format!("axis {} is named twice", t.axis)).into(),
                );
            }
            if !t.target.is_finite() {
                return Err(ApiError::InvalidArgument(format!(
                    "axis {}: target must be finite",
                    t.axis
                ))
                .into());
            }
            let c = &m.spec(i).motion;
            targets.push((
                i,
                t.target,
                motion_value(
                    "velocity",
                    t.velocity,
                    c.units.counts_per_unit,
                    &format!("{}/s", c.unit),
                )?,
                motion_value(
                    "acceleration",
                    t.acceleration,
                    c.units.counts_per_unit,
                    &format!("{}/s²", c.unit),
                )?,
            ));
        }
        let results = m.move_coordinated(targets.clone(), &caller, r.wait).await?;
        let mut out = Vec::new();
        for ((i, ..), res) in targets.iter().zip(results) {
            let res = res?;
            if r.wait {
                check_outcome(m.name(*i), &res)?;
            }
            out.push(self.result_pb(*i, res));
        }
        Ok(Response::new(pb::MultiAxisResponse { results: out }))
    }

    type StreamSetpointsStream = MessageStream<pb::SetpointStreamStatus>;

    async fn stream_setpoints(
        &self,
        req: Request<tonic::Streaming<pb::SetpointStreamRequest>>,
    ) -> Result<Response<Self::StreamSetpointsStream>, Status> {
        let caller = Caller::new(peer(&req)).with_identity(owner(&req));
        let stream = super::setpoint_streams::serve(
            self.gateway.axes().clone(),
            caller,
            req.into_inner(),
            self.gateway.shutdown_token(),
        )
        .await?;
        Ok(Response::new(stream))
    }

    type StreamAxisStateStream = UpdateStream;

    async fn stream_axis_state(
        &self,
        req: Request<pb::StreamAxisStateRequest>,
    ) -> Result<Response<Self::StreamAxisStateStream>, Status> {
        let r = req.into_inner();
        let gateway = self.gateway.clone();
        let m = gateway.axes().clone();
        let wanted: Option<Vec<bool>> = if r.axes.is_empty() {
            None
        } else {
            let mut w = vec![false; m.len()];
            for a in &r.axes {
                w[m.index(a)?] = true;
            }
            Some(w)
        };
        let rx = m.subscribe();
        let changes_only = r.changes_only;
        let shutdown = gateway.shutdown_token();
        let (tx, out) = tokio::sync::mpsc::channel(1024);
        // The current state first, so a watcher sees every axis at once.
        let initial: Vec<pb::AxisUpdate> = (0..m.len())
            .filter(|i| wanted.as_ref().is_none_or(|w| w[*i]))
            .map(|i| {
                let l = m.latest(i);
                let at = l.as_ref().map_or(Timestamp(0), |(_, t)| *t);
                pb::AxisUpdate {
                    update: Some(pb::axis_update::Update::Status(status_pb(
                        &m,
                        i,
                        l.as_ref().map(|(s, _)| s.as_ref()),
                        at,
                    ))),
                }
            })
            .collect();
        let mut last: Vec<Option<Arc<AxisSnapshot>>> = vec![None; m.len()];
        spawn_forward(
            "StreamAxisState",
            rx,
            tx,
            initial,
            shutdown,
            AtShutdown::Unavailable,
            move |received| {
                let update = match received {
                    Received::Item(AxisUpdate::Status { axis, snapshot, at }) => {
                        if wanted.as_ref().is_some_and(|w| !w[axis])
                            || (changes_only && last[axis].as_deref() == Some(snapshot.as_ref()))
                        {
                            return None;
                        }
                        last[axis] = Some(snapshot.clone());
                        pb::axis_update::Update::Status(status_pb(&m, axis, Some(&snapshot), at))
                    }
                    Received::Item(AxisUpdate::Event { axis, at, event }) => {
                        if wanted.as_ref().is_some_and(|w| !w[axis]) {
                            return None;
                        }
                        pb::axis_update::Update::Event(event_pb(&m, axis, at, event))
                    }
                    Received::Lost(n) => pb::axis_update::Update::Event(pb::AxisEvent {
                        axis: String::new(),
                        timestamp_us: Timestamp::now().0 / 1000,
                        kind: Some(pb::axis_event::Kind::Lost(n)),
                    }),
                };
                Some(pb::AxisUpdate {
                    update: Some(update),
                })
            },
        );
        Ok(Response::new(stream_of(out)))
    }
}

/// The API's name of a mode of operation.
fn drive_mode_pb(m: DriveMode) -> pb::DriveMode {
    match m {
        DriveMode::ProfilePosition => pb::DriveMode::ProfilePosition,
        DriveMode::CyclicPosition => pb::DriveMode::Csp,
        DriveMode::InterpolatedPosition => pb::DriveMode::Ip,
        DriveMode::CyclicVelocity => pb::DriveMode::Csv,
        DriveMode::CyclicTorque => pb::DriveMode::Cst,
        DriveMode::ProfileTorque => pb::DriveMode::ProfileTorque,
    }
}

/// The mode of operation an API value names (`None`: UNSPECIFIED).
fn drive_mode_from_pb(m: pb::DriveMode) -> Option<DriveMode> {
    Some(match m {
        pb::DriveMode::Unspecified => return None,
        pb::DriveMode::ProfilePosition => DriveMode::ProfilePosition,
        pb::DriveMode::Csp => DriveMode::CyclicPosition,
        pb::DriveMode::Ip => DriveMode::InterpolatedPosition,
        pb::DriveMode::Csv => DriveMode::CyclicVelocity,
        pb::DriveMode::Cst => DriveMode::CyclicTorque,
        pb::DriveMode::ProfileTorque => DriveMode::ProfileTorque,
    })
}
