//! The axis layer at run time: every configured axis, control leases, the
//! update stream, and one task per CANopen bus that runs the bus's CiA 402
//! axis controllers ([`cia402_task`]). CANsmc axes are run by their
//! master's cycle thread ([`crate::cansmc`]), which serves the same
//! [`crate::axis_runner::BusRequest`]s.
//!
//! The control rules (leases, stops never refused, the audit log) are
//! [`Axes`]'s own ([`control`]), so every caller gets them: the gRPC `Axes`
//! service, the handwheel binding, an embedding program.

pub mod cansmc_setpoints;
pub mod cia402_task;
pub mod control;
pub mod cyclic_setpoints;
pub mod sdo_process_data;
pub mod setpoint_streams;
mod touch_probe;

use crate::canopen::CanopenBus;
use crate::not_found::NotFound;
use cangate_axis::CommandError;
use cangate_axis::cia402::AxisSnapshot;
use cangate_axis::lease::LeaseError;
use cangate_axis::lease::{Lease, LeaseTable};
use cangate_axis::{Activity, AxisCommand, AxisSpec, DriveSpec, Outcome, PositionMode, StopKind};
use cangate_can::Timestamp;
use std::collections::{BTreeMap, HashMap, HashSet};
use std::sync::{Arc, Mutex, RwLock};
use std::time::{Duration, Instant};
use tokio::sync::{Notify, broadcast, mpsc, oneshot};
use tokio_util::sync::CancellationToken;

pub use crate::axis_runner::{AxisEventKind, AxisUpdate, LatestStates};
use crate::axis_runner::{AxisPort, BusRequest, CansmcPortAxis, CommandReply};
use cia402_task::TaskAxis;
pub use control::Caller;

/// Lease TTL bounds (ms).
pub const MIN_TTL_MS: u32 = 100;
/// Lease TTL bounds (ms).
pub const MAX_TTL_MS: u32 = 60_000;
/// Lease TTL when the client gives none (ms).
pub const DEFAULT_TTL_MS: u32 = 2_000;

struct AxisEntry {
    spec: AxisSpec,
    bus: mpsc::Sender<BusRequest>,
    /// Index within its bus task.
    local: usize,
    /// A CiA 402 axis's bus master and its task's cyclic set-point table
    /// (where set-point streams play).
    cyclic: Option<(CanopenBus, Arc<cyclic_setpoints::CyclicSetpoints>)>,
    /// A CANsmc axis's master's set-point streams (played by its cycle
    /// thread).
    cansmc: Option<Arc<cansmc_setpoints::CansmcSetpoints>>,
}

/// What [`Axes::start`] returns: the manager, its tasks, and the
/// CANsmc axes per master name for the cycle threads.
pub type Started = (
    Arc<Axes>,
    Vec<tokio::task::JoinHandle<()>>,
    BTreeMap<String, AxisPort>,
);

/// Every axis of the gateway.
pub struct Axes {
    axes: Vec<AxisEntry>,
    by_name: HashMap<String, usize>,
    leases: Mutex<LeaseTable>,
    leases_changed: Notify,
    /// Leases released since the expiry task last looked: it takes the
    /// torque off their axes, as for a lapsed lease.
    released: Mutex<Vec<Lease>>,
    origin: Instant,
    updates: broadcast::Sender<AxisUpdate>,
    latest: LatestStates,
    /// Set when the gateway shuts down: new commands are refused.
    closing: std::sync::atomic::AtomicBool,
}

/// The result of an axis command as the API reports it.
#[derive(Debug, Clone)]
pub struct CommandResult {
    /// `None`: accepted, not waited for.
    pub outcome: Option<Outcome>,
    /// For people.
    pub detail: String,
    /// The state right after.
    pub snapshot: Arc<AxisSnapshot>,
}

/// What shutdown's first step did to the axes in motion.
#[derive(Debug, Default)]
pub struct ShutdownStops {
    /// One line per stopped axis for the log.
    pub lines: Vec<String>,
    /// Axes that were not at rest within the bound (and were quick-stopped
    /// through the controlword); the server exits non-zero when any are.
    pub not_at_rest: Vec<String>,
}

/// How long shutdown waits for the quick stop of an axis that did not come
/// to rest within `shutdown_timeout_ms`: long enough for the controlword to
/// reach the drive and the drive to confirm, not to wait out its ramp.
const QUICK_STOP_GRACE: Duration = Duration::from_secs(1);

impl Axes {
    /// Starts the axis tasks (one per CANopen bus with axes) and hands
    /// over the CANsmc axes: one [`AxisPort`] per CANsmc master with axes
    /// (by master name), for its cycle thread to serve. An axis's index is
    /// its position in `specs`.
    pub fn start(
        specs: &[AxisSpec],
        masters: &BTreeMap<String, CanopenBus>,
        cancel: CancellationToken,
    ) -> Result<Started, String> {
        let (updates, _) = broadcast::channel(8192);
        let total = specs.len();
        let latest: LatestStates = Arc::new(RwLock::new(vec![None; total]));
        let mut per_bus: BTreeMap<&str, Vec<TaskAxis>> = BTreeMap::new();
        let mut per_master: BTreeMap<&str, Vec<CansmcPortAxis>> = BTreeMap::new();
        for (global, spec) in specs.iter().enumerate() {
            let name = spec.name.clone();
            match &spec.drive {
                DriveSpec::Cia402(d) => per_bus.entry(d.bus.as_str()).or_default().push(TaskAxis {
                    global,
                    name,
                    drive: d.clone(),
                    controller: d.controller(spec.motion.clone()),
                }),
                DriveSpec::Cansmc(d) => {
                    per_master
                        .entry(d.master.as_str())
                        .or_default()
                        .push(CansmcPortAxis {
                            global,
                            name,
                            controller: d.controller(spec.motion.clone()),
                        })
                }
            }
        }
        let mut axes: Vec<Option<AxisEntry>> = (0..total).map(|_| None).collect();
        let mut ports = BTreeMap::new();
        for (master, list) in per_master {
            let (tx, rx) = mpsc::channel(256);
            let streams = Arc::new(cansmc_setpoints::CansmcSetpoints::new(
                list.iter().map(|a| a.name.clone()),
            ));
            for (local, a) in list.iter().enumerate() {
                axes[a.global] = Some(AxisEntry {
                    spec: specs[a.global].clone(),
                    bus: tx.clone(),
                    local,
                    cyclic: None,
                    cansmc: Some(streams.clone()),
                });
            }
            ports.insert(
                master.to_string(),
                AxisPort {
                    requests: rx,
                    axes: list,
                    updates: updates.clone(),
                    latest: latest.clone(),
                    streams,
                },
            );
        }
        let mut tasks = Vec::new();
        for (bus, list) in per_bus {
            let master = masters
                .get(bus)
                .ok_or_else(|| format!("bus {bus:?} has no CANopen master"))?
                .clone();
            let (tx, rx) = mpsc::channel(256);
            let globals: Vec<usize> = list.iter().map(|a| a.global).collect();
            let (task, table) = cia402_task::spawn(
                master.clone(),
                list,
                rx,
                updates.clone(),
                latest.clone(),
                cancel.child_token(),
            );
            for (local, global) in globals.into_iter().enumerate() {
                axes[global] = Some(AxisEntry {
                    spec: specs[global].clone(),
                    bus: tx.clone(),
                    local,
                    cyclic: Some((master.clone(), table.clone())),
                    cansmc: None,
                });
            }
            tasks.push(task);
        }
        let axes: Vec<AxisEntry> = axes
            .into_iter()
            .map(|a| a.expect("every axis placed"))
            .collect();
        let by_name = axes
            .iter()
            .enumerate()
            .map(|(i, a)| (a.spec.name.clone(), i))
            .collect();
        let manager = Arc::new(Axes {
            axes,
            by_name,
            leases: Mutex::new(LeaseTable::new()),
            leases_changed: Notify::new(),
            released: Mutex::new(Vec::new()),
            origin: Instant::now(),
            updates,
            latest,
            closing: std::sync::atomic::AtomicBool::new(false),
        });
        tasks.push(tokio::spawn(run_lease_expiry(manager.clone(), cancel)));
        Ok((manager, tasks, ports))
    }

    fn now(&self) -> Duration {
        self.origin.elapsed()
    }

    /// Number of axes.
    pub fn len(&self) -> usize {
        self.axes.len()
    }

    /// Whether there are no axes.
    pub fn is_empty(&self) -> bool {
        self.axes.is_empty()
    }

    /// The index of a named axis.
    pub fn index(&self, name: &str) -> Result<usize, AxisError> {
        self.by_name.get(name).copied().ok_or_else(|| {
            AxisError::NotFound(NotFound::among(
                "axis",
                "axes",
                name,
                self.axes.iter().map(|a| a.spec.name.as_str()),
            ))
        })
    }

    /// The description of axis `i`.
    pub fn spec(&self, i: usize) -> &AxisSpec {
        &self.axes[i].spec
    }

    /// Name of axis `i`.
    pub fn name(&self, i: usize) -> &str {
        &self.axes[i].spec.name
    }

    /// Latest state of axis `i` (`None` before its first process data).
    pub fn latest(&self, i: usize) -> Option<(Arc<AxisSnapshot>, Timestamp)> {
        self.latest.read().expect("latest lock")[i].clone()
    }

    /// Whether every axis of `idx` is known to be at rest: standing still,
    /// its node present, and running no motion command (idle, or a stop or
    /// state change that found it still). A stop may be throttled only then
    /// (a client over its stop budget); a stop of an axis that moves,
    /// brakes, homes, follows a gear, or whose state is unknown, never is.
    pub fn all_at_rest(&self, idx: &[usize]) -> bool {
        let latest = self.latest.read().expect("latest lock");
        idx.iter().all(|&i| {
            let Some((s, _)) = latest.get(i).and_then(Option::as_ref) else {
                return false;
            };
            // The controllers' own "at rest".
            let still = self.axes[i].spec.motion.rest_speed();
            matches!(
                s.activity,
                Activity::Idle | Activity::Stopping | Activity::Switching
            ) && s.node_lost.is_none()
                && s.velocity.abs() <= still
        })
    }

    /// Who controls axis `i` and for how much longer.
    pub fn control(&self, i: usize) -> Option<(String, Duration)> {
        let now = self.now();
        let leases = self.leases.lock().expect("lease lock");
        leases
            .holder_of(self.name(i))
            .map(|l| (l.holder.clone(), l.expires.saturating_sub(now)))
    }

    /// Subscribes to every axis's updates.
    pub fn subscribe(&self) -> broadcast::Receiver<AxisUpdate> {
        self.updates.subscribe()
    }

    fn publish_control(&self, lease: &Lease, holder: &str, previous: &str, reason: &str) {
        for a in &lease.axes {
            if let Some(&i) = self.by_name.get(a) {
                let _ = self.updates.send(AxisUpdate::Event {
                    axis: i,
                    at: Timestamp::now(),
                    event: AxisEventKind::Control {
                        holder: holder.to_string(),
                        previous: previous.to_string(),
                        reason: reason.to_string(),
                    },
                });
            }
        }
    }

    fn closing(&self) -> bool {
        self.closing.load(std::sync::atomic::Ordering::SeqCst)
    }

    /// Shutdown, first step: refuses every new command and control
    /// request, then stops the axes that move (halt or quick stop per
    /// their `stop_on_loss`) and waits until they are at rest, at most
    /// `bound`. An axis still moving then is quick-stopped through its
    /// controlword, so its drive ramps down on its own: a cyclic drive
    /// would otherwise hold or chase its last set-point once the gateway,
    /// which is its trajectory, has gone.
    pub async fn stop_for_shutdown(&self, bound: Duration) -> ShutdownStops {
        self.closing
            .store(true, std::sync::atomic::Ordering::SeqCst);
        let mut stops = Vec::new();
        for i in 0..self.axes.len() {
            if self.in_motion(i) {
                let cmd = stop_command(self.spec(i).stop_on_loss);
                stops.push((i, cmd));
            }
        }
        let mut report = ShutdownStops {
            lines: Vec::new(),
            not_at_rest: Vec::new(),
        };
        if stops.is_empty() {
            return report;
        }
        let results: Vec<Option<Result<CommandResult, AxisError>>> =
            match tokio::time::timeout(bound, self.many(stops.clone(), true)).await {
                Ok(Ok(results)) => results.into_iter().map(Some).collect(),
                Ok(Err(e)) => {
                    report.lines.push(format!("stopping: {e}"));
                    (0..stops.len()).map(|_| None).collect()
                }
                Err(_) => (0..stops.len()).map(|_| None).collect(),
            };
        let mut unsettled = Vec::new();
        for ((i, _), r) in stops.iter().zip(results) {
            let name = self.name(*i).to_string();
            let completed = matches!(
                &r,
                Some(Ok(CommandResult {
                    outcome: Some(Outcome::Completed),
                    ..
                }))
            );
            match r {
                Some(Ok(r)) => report.lines.push(format!(
                    "{name}: {} ({})",
                    r.outcome.map_or("accepted", Outcome::name),
                    r.detail
                )),
                Some(Err(e)) => report.lines.push(format!("{name}: {e}")),
                None => report.lines.push(format!(
                    "{name}: not at rest within {} ms",
                    bound.as_millis()
                )),
            }
            // A completed stop is at rest by definition; the latest
            // published state may still lag behind it.
            if !completed {
                unsettled.push(*i);
            }
        }
        if unsettled.is_empty() {
            return report;
        }
        let quick: Vec<(usize, AxisCommand)> = unsettled
            .iter()
            .map(|&i| (i, AxisCommand::QuickStop))
            .collect();
        let quick_results: Vec<Option<Result<CommandResult, AxisError>>> =
            match tokio::time::timeout(QUICK_STOP_GRACE, self.many(quick, true)).await {
                Ok(Ok(results)) => results.into_iter().map(Some).collect(),
                _ => (0..unsettled.len()).map(|_| None).collect(),
            };
        for (&i, r) in unsettled.iter().zip(quick_results) {
            let name = self.name(i).to_string();
            report.lines.push(match r {
                Some(Ok(r)) => format!(
                    "{name}: quick stop through the controlword: {} ({})",
                    r.outcome.map_or("accepted", Outcome::name),
                    r.detail
                ),
                Some(Err(e)) => format!("{name}: quick stop through the controlword: {e}"),
                None => format!(
                    "{name}: quick stop sent through the controlword, not at rest within {} ms more",
                    QUICK_STOP_GRACE.as_millis()
                ),
            });
            report.not_at_rest.push(name);
        }
        report
    }

    /// Whether axis `i` was last seen moving, homing, jogging or stopping,
    /// or plays a set-point stream (no command of its own runs then).
    fn in_motion(&self, i: usize) -> bool {
        self.in_stream(i)
            || self.latest(i).is_some_and(|(s, _)| {
                matches!(
                    s.activity,
                    Activity::Moving | Activity::Jogging | Activity::Homing | Activity::Stopping
                )
            })
    }

    /// Whether axis `i` plays a set-point stream.
    pub fn in_stream(&self, i: usize) -> bool {
        let e = &self.axes[i];
        e.cyclic
            .as_ref()
            .is_some_and(|(_, table)| table.in_stream(e.local))
            || e.cansmc
                .as_ref()
                .is_some_and(|table| table.in_stream(e.local))
    }

    /// Grants control of `axes` (names) to `holder`, bound to `identity`
    /// when the caller has one (see [`LeaseTable::bind_owner`]): bound
    /// before the token leaves the runtime, so no other identity can ever
    /// have used it.
    pub fn acquire(
        &self,
        axes: &[String],
        ttl: Option<Duration>,
        holder: String,
        identity: Option<String>,
    ) -> Result<Lease, AxisError> {
        if self.closing() {
            return Err(AxisError::ShuttingDown);
        }
        if axes.is_empty() {
            return Err(AxisError::BadAxisList("name at least one axis".into()));
        }
        let mut seen = HashSet::new();
        for a in axes {
            self.index(a)?;
            if !seen.insert(a) {
                return Err(AxisError::BadAxisList(format!("axis {a} is named twice")));
            }
        }
        let ttl = ttl
            .unwrap_or(Duration::from_millis(u64::from(DEFAULT_TTL_MS)))
            .clamp(
                Duration::from_millis(u64::from(MIN_TTL_MS)),
                Duration::from_millis(u64::from(MAX_TTL_MS)),
            );
        // The token is the control: 128 bits from the OS, not guessable.
        let mut raw = [0u8; 16];
        getrandom::fill(&mut raw).map_err(|e| {
            AxisError::Unavailable(format!("no OS randomness for a lease token: {e}"))
        })?;
        let token: String = raw.iter().map(|b| format!("{b:02x}")).collect();
        let lease = {
            let mut leases = self.leases.lock().expect("lease lock");
            let lease = leases.acquire(token, holder.clone(), axes.to_vec(), ttl, self.now())?;
            if let Some(identity) = identity {
                leases.bind_owner(&lease.token, identity)?;
            }
            lease
        };
        self.leases_changed.notify_one();
        self.publish_control(&lease, &holder, "", "acquired");
        Ok(lease)
    }

    /// Extends a lease (the owner check is the caller's, see
    /// [`Axes::renew`]).
    fn renew_token(&self, token: &str) -> Result<Lease, AxisError> {
        let lease = self
            .leases
            .lock()
            .expect("lease lock")
            .renew(token, self.now())?;
        self.leases_changed.notify_one();
        Ok(lease)
    }

    /// Ends a lease (the owner check is the caller's, see
    /// [`Axes::release`]).
    fn release_token(&self, token: &str) -> Result<Lease, AxisError> {
        let lease = self.leases.lock().expect("lease lock").release(token)?;
        // A torque command never ends by itself: it must not outlive the
        // control that set it (the expiry task stops it).
        self.released
            .lock()
            .expect("released leases lock")
            .push(lease.clone());
        self.leases_changed.notify_one();
        self.publish_control(&lease, "", &lease.holder, "released");
        Ok(lease)
    }

    /// Checks that `caller` may present lease `token` (see
    /// [`LeaseTable::check_owner`]).
    fn check_lease_owner(&self, token: &str, caller: Option<&str>) -> Result<(), AxisError> {
        Ok(self
            .leases
            .lock()
            .expect("lease lock")
            .check_owner(token, caller)?)
    }

    /// Checks that `token` controls axis `i` (renewing it); the holder's
    /// name for the audit log.
    fn authorize(&self, i: usize, token: &str) -> Result<String, AxisError> {
        let mut leases = self.leases.lock().expect("lease lock");
        let token = (!token.is_empty()).then_some(token);
        leases.authorize(self.name(i), token, self.now())?;
        let holder = leases
            .holder_of(self.name(i))
            .map(|l| l.holder.clone())
            .unwrap_or_default();
        drop(leases);
        self.leases_changed.notify_one();
        Ok(holder)
    }

    /// Runs a command on axis `i` without any control check (the callers
    /// are [`Axes::command`] and shutdown); returns when the drive accepted
    /// it, or with `wait` when it ended (bounded by `wait_timeout`).
    async fn dispatch(
        &self,
        i: usize,
        cmd: AxisCommand,
        wait: bool,
        wait_timeout: Duration,
    ) -> Result<CommandResult, AxisError> {
        if self.closing() {
            return Err(AxisError::ShuttingDown);
        }
        let entry = &self.axes[i];
        let (reply, rx) = oneshot::channel();
        entry
            .bus
            .send(BusRequest::Command {
                local: entry.local,
                cmd,
                wait,
                reply,
            })
            .await
            .map_err(|_| AxisError::ShuttingDown)?;
        let waiter = rx.await.map_err(|_| AxisError::ShuttingDown)??;
        self.await_reply(i, waiter, wait, wait_timeout).await
    }

    /// Queues a command on axis `i` without waiting for its acceptance and
    /// without any control check (see [`Axes::submit`]).
    fn enqueue(&self, i: usize, cmd: AxisCommand) -> Result<(), AxisError> {
        if self.closing() {
            return Err(AxisError::ShuttingDown);
        }
        let entry = &self.axes[i];
        let (reply, _rx) = oneshot::channel();
        entry
            .bus
            .try_send(BusRequest::Command {
                local: entry.local,
                cmd,
                wait: false,
                reply,
            })
            .map_err(|e| AxisError::Unavailable(format!("axis {}: {e}", self.name(i))))
    }

    async fn await_reply(
        &self,
        i: usize,
        waiter: oneshot::Receiver<CommandReply>,
        wait: bool,
        wait_timeout: Duration,
    ) -> Result<CommandResult, AxisError> {
        // Without `wait` the command returns at the drive's acceptance,
        // which takes at most a few state timeouts.
        let bound = if wait {
            wait_timeout
        } else {
            self.spec(i).motion.state_timeout * 3 + Duration::from_secs(1)
        };
        match tokio::time::timeout(bound, waiter).await {
            Ok(Ok(r)) => Ok(CommandResult {
                outcome: r.outcome,
                detail: r.detail,
                snapshot: Arc::new(r.snapshot),
            }),
            Ok(Err(_)) => Err(AxisError::ShuttingDown),
            Err(_) => Err(AxisError::NoAnswer(format!(
                "axis {}: no {} within {} ms (the command keeps running; watch StreamAxisState)",
                self.name(i),
                if wait { "completion" } else { "acceptance" },
                bound.as_millis()
            ))),
        }
    }

    /// Stops several axes at once (per bus in one batch of frames); see
    /// [`Axes::stop_many`].
    async fn stop_batch(
        &self,
        axes: &[usize],
        kind: StopKind,
        wait: bool,
    ) -> Result<Vec<Result<CommandResult, AxisError>>, AxisError> {
        let cmd = stop_command(kind);
        let items: Vec<(usize, AxisCommand)> = axes.iter().map(|&i| (i, cmd)).collect();
        self.many(items, wait).await
    }

    /// Runs commands on several axes; those on one bus are applied in one
    /// step of its task, so their frames leave together.
    async fn many(
        &self,
        items: Vec<(usize, AxisCommand)>,
        wait: bool,
    ) -> Result<Vec<Result<CommandResult, AxisError>>, AxisError> {
        // (bus task, [(position in `items`, axis in the task, command)])
        type BusBatch = (mpsc::Sender<BusRequest>, Vec<(usize, usize, AxisCommand)>);
        let mut by_bus: Vec<BusBatch> = Vec::new();
        for (pos, (i, cmd)) in items.iter().enumerate() {
            let e = &self.axes[*i];
            match by_bus.iter_mut().find(|(tx, _)| tx.same_channel(&e.bus)) {
                Some((_, list)) => list.push((pos, e.local, *cmd)),
                None => by_bus.push((e.bus.clone(), vec![(pos, e.local, *cmd)])),
            }
        }
        let mut waiters: Vec<Option<Result<oneshot::Receiver<CommandReply>, AxisError>>> =
            (0..items.len()).map(|_| None).collect();
        for (tx, list) in by_bus {
            let (reply, rx) = oneshot::channel();
            let cmds = list.iter().map(|(_, l, c)| (*l, *c)).collect();
            tx.send(BusRequest::Many { cmds, wait, reply })
                .await
                .map_err(|_| AxisError::ShuttingDown)?;
            let results = rx.await.map_err(|_| AxisError::ShuttingDown)?;
            for ((pos, _, _), r) in list.iter().zip(results) {
                waiters[*pos] = Some(r.map_err(AxisError::from));
            }
        }
        let mut out = Vec::new();
        for ((i, _), w) in items.iter().zip(waiters) {
            out.push(match w.expect("every item answered") {
                Ok(rx) => {
                    self.await_reply(*i, rx, wait, Duration::from_secs(60))
                        .await
                }
                Err(e) => Err(e),
            });
        }
        Ok(out)
    }

    /// Starts a coordinated cyclic move: (axis, target, velocity,
    /// acceleration) per axis, all on one bus, without any control check
    /// (see [`Axes::move_coordinated`]).
    async fn dispatch_coordinated(
        &self,
        targets: Vec<crate::axis_runner::CoordinatedTarget>,
        wait: bool,
    ) -> Result<Vec<Result<CommandResult, AxisError>>, AxisError> {
        if targets.is_empty() {
            return Err(AxisError::BadAxisList("name at least one axis".into()));
        }
        let first = &self.axes[targets[0].0];
        for (i, ..) in &targets {
            let e = &self.axes[*i];
            if !e.bus.same_channel(&first.bus) {
                return Err(AxisError::NotCoordinable(format!(
                    "a coordinated move needs all axes on one bus: {} is on {}, {} on {}",
                    first.spec.name,
                    first.spec.bus(),
                    e.spec.name,
                    e.spec.bus()
                )));
            }
            if e.spec.position_mode() != PositionMode::Cyclic {
                return Err(AxisError::NotCoordinable(format!(
                    "a coordinated move needs cyclic (CSP) axes; {} is a profile position axis",
                    e.spec.name
                )));
            }
        }
        let (reply, rx) = oneshot::channel();
        first
            .bus
            .send(BusRequest::Coordinated {
                targets: targets
                    .iter()
                    .map(|(i, t, v, a)| (self.axes[*i].local, *t, *v, *a))
                    .collect(),
                wait,
                reply,
            })
            .await
            .map_err(|_| AxisError::ShuttingDown)?;
        let waiters = rx.await.map_err(|_| AxisError::ShuttingDown)??;
        let mut out = Vec::new();
        for ((i, ..), rx) in targets.iter().zip(waiters) {
            out.push(
                self.await_reply(*i, rx, wait, Duration::from_secs(120))
                    .await,
            );
        }
        Ok(out)
    }
}

/// The command of a stop of `kind`.
fn stop_command(kind: StopKind) -> AxisCommand {
    match kind {
        StopKind::Halt => AxisCommand::Stop,
        StopKind::QuickStop => AxisCommand::QuickStop,
    }
}

/// Whether a torque command runs on the axis: it moves (or pushes) in a
/// torque mode (profile torque 4, cyclic synchronous torque 10).
fn under_torque(s: &AxisSnapshot) -> bool {
    s.activity == Activity::Moving && matches!(s.mode, 4 | 10)
}

/// Stops the moving axes of leases that lapse, at their expiry, and the
/// torque of leases released.
async fn run_lease_expiry(m: Arc<Axes>, cancel: CancellationToken) {
    loop {
        let next = m.leases.lock().expect("lease lock").next_expiry();
        let sleep = match next {
            Some(at) => at.saturating_sub(m.now()),
            None => Duration::from_secs(3600),
        };
        tokio::select! {
            _ = cancel.cancelled() => return,
            // A change may be a release to act on (or a renewal: nothing
            // lapses then).
            _ = m.leases_changed.notified() => {}
            _ = tokio::time::sleep(sleep) => {}
        }
        let released = std::mem::take(&mut *m.released.lock().expect("released leases lock"));
        let lapsed = m.leases.lock().expect("lease lock").expire(m.now());
        for (lease, lapsed) in
            (released.into_iter().map(|l| (l, false))).chain(lapsed.into_iter().map(|l| (l, true)))
        {
            if lapsed {
                let reason = format!("lapsed: not renewed within {} ms", lease.ttl.as_millis());
                tracing::warn!(target: "cangate::audit", holder = %lease.holder, axes = ?lease.axes, "control lease lapsed; stopping its moving axes");
                m.publish_control(&lease, "", &lease.holder, &reason);
            }
            let mut stops = Vec::new();
            for name in &lease.axes {
                let Some(&i) = m.by_name.get(name) else {
                    continue;
                };
                // A set-point stream ends by itself on a lost lease; the
                // stop also covers a session that is held up. A released
                // lease leaves its moves and jogs to end by themselves
                // (a jog at its dead-man), but not a torque: that only a
                // stop ends.
                let moving = if lapsed {
                    m.in_stream(i)
                        || m.latest(i).is_some_and(|(s, _)| {
                            matches!(
                                s.activity,
                                Activity::Moving | Activity::Jogging | Activity::Homing
                            )
                        })
                } else {
                    !m.in_stream(i) && m.latest(i).is_some_and(|(s, _)| under_torque(&s))
                };
                if moving {
                    let cmd = stop_command(m.spec(i).stop_on_loss);
                    stops.push((i, cmd));
                }
            }
            if !stops.is_empty() {
                let m2 = m.clone();
                tokio::spawn(async move {
                    if let Err(e) = m2.many(stops, false).await {
                        tracing::error!(error = %e, "could not stop the axes of a lost lease");
                    }
                });
            }
        }
    }
}

/// Why an axis request failed, by reason; the API edge maps each to its
/// gRPC status.
#[derive(Debug, thiserror::Error)]
pub enum AxisError {
    /// No such axis.
    #[error(transparent)]
    NotFound(#[from] NotFound),
    /// The axes named are no list the call can take: none, or one named
    /// twice.
    #[error("{0}")]
    BadAxisList(String),
    /// The axis controller refused the command (out of range, invalid,
    /// not possible in the axis's state); nothing changed.
    #[error(transparent)]
    Refused(#[from] CommandError),
    /// The control lease does not allow it (missing, expired, held by
    /// another, presented by another identity).
    #[error(transparent)]
    Lease(#[from] LeaseError),
    /// A coordinated move over axes that cannot move together (another
    /// bus, a profile-position axis).
    #[error("{0}")]
    NotCoordinable(String),
    /// A set-point stream over axes that cannot be streamed now (not
    /// cyclic, not enabled, moving, in another stream, on another bus).
    #[error("{0}")]
    NotStreamable(String),
    /// The axis's runner cannot take the request (queue full, no OS
    /// randomness for a lease token).
    #[error("{0}")]
    Unavailable(String),
    /// No acceptance or completion within the bound (the command keeps
    /// running).
    #[error("{0}")]
    NoAnswer(String),
    /// The gateway is shutting down.
    #[error("the gateway is shutting down")]
    ShuttingDown,
    /// An SDO transfer the request needed failed.
    #[error("{error}")]
    Sdo {
        /// The drive's node.
        node: cangate_canopen::NodeId,
        /// The failure.
        error: crate::canopen::CanopenError,
    },
}
