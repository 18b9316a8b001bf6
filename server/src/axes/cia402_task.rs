//! The task that runs the CiA 402 axes of one CANopen bus: it feeds each
//! [`Cia402Axis`] the drive's decoded TPDOs, the master's SYNCs, node events
//! and time; sends the process images it returns as RPDOs (all frames of one
//! step in one batch, so a multi-axis stop leaves together); runs the SDO
//! writes it asks for; and answers command waiters.
//!
//! The process data does not go through the CANopen master task: this task
//! subscribes to its drives' TPDOs on the bus directly and decodes them
//! from their mapping: a task hop and a decoded, allocated update less per
//! PDO (why that matters: "Wake-ups cost more than frames" in
//! docs/design.md). The master still does
//! NMT, heartbeats, EMCY and SDO, and this task hands it each TPDO for the
//! counters and the StreamPdo subscribers ([`CanopenBus::relay_tpdo`]).
//!
//! The cyclic set-points of CSP axes are not sent from here: the master's
//! SYNC thread samples each axis's published plan and sends the set-point
//! RPDO with the SYNC ([`super::cyclic_setpoints`]). This task publishes
//! the plans (all changed ones of a turn at once, so a multi-axis command
//! starts in one SYNC) and hands the samples back to the axes when it
//! wakes for the drives' answers: it is not woken by the SYNC itself.
//!
//! An axis configured with `process_data = "sdo"` has no PDOs: its images
//! go to, and its feedback comes from, a worker polling by SDO
//! ([`super::sdo_process_data`]).

use super::cyclic_setpoints::{CyclicSetpoints, SetpointLayout, StreamEnd};
use super::sdo_process_data::{self, SdoReport, SdoWorker};
use crate::axis_runner::{
    AxisEventKind, AxisRunner, AxisUpdate, BusRequest, CoordinatedTarget, LatestStates, Waiter,
    Waiters, for_axis, prepare_coordinated,
};
use crate::canopen::{CanopenBus, NodeEventKind};
use cangate_axis::cia402::{Cia402Axis, Cia402Config, CyclicPlan, CyclicSample, Output};
use cangate_axis::process_data::{encode_image, feedback_from_pdo, pdo_drive_axis};
use cangate_axis::{
    AxisCommand, AxisEvent, Cia402Drive, CommandError, PositionMode, ProcessDataPath,
};
use cangate_can::{BusItem, CanId, Filter, Frame, FrameSelector, Subscription, Timestamp};
use cangate_canopen::cia402::DriveState;
use cangate_canopen::pdo::{PdoConfig, PdoKind};
use cangate_canopen::{NodeId, ObjectAddress};
use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::{broadcast, mpsc};
use tokio_util::sync::CancellationToken;
use tracing::Instrument as _;

/// An axis of a bus task: its index among all axes, its name, its drive
/// and its controller's configuration.
pub struct TaskAxis {
    /// Index among all axes of the gateway.
    pub global: usize,
    /// The axis's name.
    pub name: String,
    /// The drive.
    pub drive: Cia402Drive,
    /// The controller's configuration.
    pub controller: Cia402Config,
}

struct Slot {
    global: usize,
    name: String,
    node: NodeId,
    axis: Cia402Axis,
    rpdos: Vec<PdoConfig>,
    waiters: Waiters,
    /// Bus time of the latest process data.
    at: Timestamp,
    /// The SDO fallback's worker, if the axis uses it.
    sdo: Option<SdoLink>,
    /// A cyclic axis's set-point RPDO, sent by the SYNC thread.
    setpoint: Option<SetpointLayout>,
    /// The plan published to the SYNC thread (as published; the SYNC
    /// thread's copy fixes a trajectory's start when it first samples it).
    published: Option<CyclicPlan>,
    /// The set-point RPDO's payload as last handed to the SYNC thread, the
    /// target position masked.
    setpoint_payload: Vec<u8>,
    /// Tells the CANopen operations whether this axis is active.
    drive_guard: crate::canopen::drive_guard::DriveRegistration,
    /// A boot procedure of the drive completed since the gateway started
    /// (or since its last boot-up). Until then its process data is not
    /// used: a drive found running may still have PDOs mapped otherwise,
    /// and a set-point sent into such a mapping could land on its
    /// controlword.
    booted: bool,
    /// Where the axis's own log lines happen (inside the bus's span).
    span: tracing::Span,
}

/// The axis task's side of an SDO fallback worker.
struct SdoLink {
    worker: SdoWorker,
    /// Polls and writes failed in a row.
    failures: u32,
    /// This link declared the node lost.
    lost: bool,
    /// The drive booted and its boot procedure has not completed (or it
    /// failed): answers to polls do not make the axis usable until one
    /// completes.
    booting: bool,
}

/// What the task's SDO helpers send back.
struct SdoInbox {
    /// The end of an axis's parameter writes ([`Output::SdoWrites`]).
    results: mpsc::Receiver<(usize, Result<(), String>)>,
    /// The SDO fallback workers' polls and failures.
    reports: mpsc::Receiver<(usize, SdoReport)>,
}

/// Failed SDO polls or writes in a row after which the axis reports its
/// node lost: one failure can be a clash with another SDO client, three at
/// a 10 ms poll (each waiting for the SDO timeout) are a drive that does
/// not answer.
const SDO_FAILURES_LOST: u32 = 3;

struct Task {
    master: CanopenBus,
    slots: Vec<Slot>,
    /// The slots of each node: one per axis of a multi-axis drive. Its
    /// node events (NMT, heartbeat, boot) reach every one.
    by_node: HashMap<NodeId, Vec<usize>>,
    /// The drives' TPDOs by COB-ID: (slot, mapping).
    tpdos: HashMap<u16, (usize, PdoConfig)>,
    /// The cyclic axes' set-points, shared with the master's SYNC thread.
    setpoints: Arc<CyclicSetpoints>,
    /// Reused for the samples taken from `setpoints`.
    samples: Vec<(usize, CyclicSample)>,
    /// Slots with feedback not yet published.
    dirty: Vec<bool>,
    /// Each TPDO's bit among its drive's TPDOs (see `round`).
    tpdo_bit: HashMap<u16, u32>,
    /// Per slot: the bits of all its drive's TPDOs, and of those received
    /// since its status was last published. A status is published once
    /// the drive's TPDOs of one SYNC are all in (they may come in two
    /// batches of the subscription), so that one cycle makes one status;
    /// a TPDO that comes again before the others closes the round with
    /// what came (one was lost, or is sent on change only).
    round_full: Vec<u32>,
    round: Vec<u32>,
    /// Reused for the controllers' outputs.
    scratch: Vec<Output>,
    updates: broadcast::Sender<AxisUpdate>,
    latest: LatestStates,
    origin: Instant,
    frames: Vec<Frame>,
    sdo_done: mpsc::Sender<(usize, Result<(), String>)>,
}

/// Frames the task's bus subscription may queue: at a 1 ms SYNC with a
/// dozen drives that is more than a second of process data.
const PROCESS_DATA_QUEUE: usize = 16_384;

/// Starts the task running the axes `list` of
/// `master`'s bus. Subscribes to the process data before returning, so
/// nothing the drives send after this point is missed. Returns the task
/// and its cyclic set-point table (indexed like `list`), where set-point
/// streams of its axes are opened.
pub fn spawn(
    master: CanopenBus,
    list: Vec<TaskAxis>,
    requests: mpsc::Receiver<BusRequest>,
    updates: broadcast::Sender<AxisUpdate>,
    latest: LatestStates,
    cancel: CancellationToken,
) -> (tokio::task::JoinHandle<()>, Arc<CyclicSetpoints>) {
    // The task and its axes log inside the bus's span.
    let bus_span = tracing::info_span!("bus", bus = %master.bus());
    let _in_bus = bus_span.enter();
    let events = master.events();
    let (sdo_done, sdo_results) = mpsc::channel(64);
    let (sdo_reports_tx, sdo_reports) = mpsc::channel(64);
    let mut tpdos = HashMap::new();
    let axes_cyclic: Vec<bool> = list
        .iter()
        .map(|a| a.drive.mode.position_mode() == PositionMode::Cyclic)
        .collect();
    let slots = list
        .into_iter()
        .enumerate()
        .map(|(i, a)| {
            let node = a.drive.node;
            // A multi-axis drive's PDOs: those mapping this axis's objects.
            let drive_axis = a.drive.drive_axis;
            let ours = |p: &PdoConfig| pdo_drive_axis(p).unwrap_or(0) == drive_axis;
            let rpdos: Vec<PdoConfig> = master
                .rpdos(node)
                .into_iter()
                .filter(|p| p.kind == PdoKind::Rpdo && ours(p))
                .collect();
            for p in master
                .tpdos(node)
                .into_iter()
                .filter(|p| p.kind == PdoKind::Tpdo && ours(p))
            {
                tpdos.insert(p.cob_id, (i, p));
            }
            let sdo = match a.drive.process_data {
                ProcessDataPath::Pdo => None,
                ProcessDataPath::Sdo { poll } => Some(SdoLink {
                    worker: sdo_process_data::spawn(
                        master.clone(),
                        node,
                        drive_axis,
                        i,
                        poll,
                        sdo_reports_tx.clone(),
                        cancel.clone(),
                    ),
                    failures: 0,
                    lost: false,
                    booting: false,
                }),
            };
            let span = tracing::info_span!("axis", axis = %a.name);
            let cyclic = a.drive.mode.position_mode() == PositionMode::Cyclic;
            // Every PDO axis: one configured in a profile mode may change
            // to a cyclic one at run time (SetMode).
            let setpoint = sdo
                .is_none()
                .then(|| SetpointLayout::find(&rpdos))
                .flatten();
            if cyclic && setpoint.is_none() {
                tracing::error!(parent: &span, "cyclic axis without an RPDO mapping the target position (0x607A, 32 bits): it gets no set-points");
            }
            let drive_guard = master.drive_guard().register(node, &a.name);
            Slot {
                drive_guard,
                global: a.global,
                axis: Cia402Axis::new(a.controller),
                name: a.name,
                node,
                rpdos,
                waiters: Waiters::default(),
                at: Timestamp(0),
                sdo,
                setpoint,
                published: None,
                setpoint_payload: Vec::new(),
                booted: false,
                span,
            }
        })
        .collect::<Vec<_>>();
    let mut filters: Vec<Filter> = tpdos.keys().map(|&c| Filter::exact_standard(c)).collect();
    // Without any filter a selector passes everything; this task wants
    // nothing then (no PDO-driven axes): an inverted match-all filter
    // keeps it that way.
    if filters.is_empty() {
        filters.push(Filter {
            id: 0,
            mask: 0,
            extended: None,
            inverted: true,
        });
    }
    let sub = master.bus_handle().subscribe(
        FrameSelector {
            filters,
            error_frames: false,
            transmitted: false,
        },
        PROCESS_DATA_QUEUE,
    );
    let mut by_node: HashMap<NodeId, Vec<usize>> = HashMap::new();
    for (i, s) in slots.iter().enumerate() {
        by_node.entry(s.node).or_default().push(i);
    }
    let origin = Instant::now();
    let setpoints = Arc::new(CyclicSetpoints::new(
        origin,
        slots.iter().map(|s| s.name.clone()),
    ));
    for (i, s) in slots.iter().enumerate() {
        setpoints.set_velocity_offset(i, s.setpoint.as_ref().and_then(|l| l.velocity_offset));
        if s.sdo.is_none() {
            setpoints.set_torque_rpdo(i, super::cyclic_setpoints::TorqueLayout::find(&s.rpdos));
            setpoints.set_feed_forward_rpdo(
                i,
                super::cyclic_setpoints::FeedForwardLayout::find(&s.rpdos),
            );
        }
    }
    let configured_cyclic = axes_cyclic.iter().any(|&c| c);
    if slots.iter().any(|s| s.setpoint.is_some())
        && (configured_cyclic || !master.sync_settings().period.is_zero())
    {
        let rider: Arc<dyn crate::canopen::sync_thread::SyncRider> = setpoints.clone();
        if !master.add_sync_rider(Arc::downgrade(&rider)) {
            // The configuration refuses cyclic axes without a SYNC period;
            // this is a SYNC thread that could not start (logged there).
            tracing::error!("cyclic axes without a SYNC: they get no set-points");
        }
    }
    let mut tpdo_bit = HashMap::new();
    let mut round_full = vec![0u32; slots.len()];
    let mut cobs: Vec<(u16, usize)> = tpdos.iter().map(|(&c, &(i, _))| (c, i)).collect();
    cobs.sort_unstable();
    for (cob, i) in cobs {
        let bit = 1u32 << round_full[i].count_ones().min(31);
        round_full[i] |= bit;
        tpdo_bit.insert(cob, bit);
    }
    let t = Task {
        master,
        dirty: vec![false; slots.len()],
        tpdo_bit,
        round: vec![0; round_full.len()],
        round_full,
        slots,
        by_node,
        tpdos,
        setpoints,
        samples: Vec::new(),
        scratch: Vec::new(),
        updates,
        latest,
        origin,
        frames: Vec::new(),
        sdo_done,
    };
    let table = t.setpoints.clone();
    let task = tokio::spawn(
        run(
            t,
            sub,
            events,
            requests,
            SdoInbox {
                results: sdo_results,
                reports: sdo_reports,
            },
            cancel,
        )
        .instrument(bus_span.clone()),
    );
    (task, table)
}

async fn run(
    mut t: Task,
    mut sub: Subscription,
    mut events: broadcast::Receiver<crate::canopen::NodeEvent>,
    mut requests: mpsc::Receiver<BusRequest>,
    SdoInbox {
        mut results,
        mut reports,
    }: SdoInbox,
    cancel: CancellationToken,
) {
    let far = Duration::from_secs(3600);
    let mut items = Vec::with_capacity(256);
    // One timer, moved only when the axes' next deadline changes: a fresh
    // timer per loop turn registers and cancels a timer-wheel entry for
    // every process data batch.
    let sleep = tokio::time::sleep_until((t.origin + far).into());
    tokio::pin!(sleep);
    let mut armed: Option<Option<Duration>> = None;
    // One cancellation future for the whole loop: a fresh one per turn
    // registers with and unregisters from the token's waiter list at every
    // wake-up of this hot task.
    let cancelled = cancel.cancelled();
    tokio::pin!(cancelled);
    loop {
        let next = t.slots.iter().filter_map(|s| s.axis.next_deadline()).min();
        if armed != Some(next) {
            let at = next.unwrap_or(t.now() + far);
            sleep.as_mut().reset((t.origin + at).into());
            armed = Some(next);
        }
        tokio::select! {
            biased;
            _ = &mut cancelled => break,
            r = requests.recv() => match r {
                Some(r) => {
                    // New trajectories start from the latest SYNC's demand.
                    t.take_samples();
                    t.on_request(r);
                }
                None => break,
            },
            n = sub.recv_many(&mut items, 256) => {
                if n == 0 {
                    // The bus stopped.
                    break;
                }
                t.take_samples();
                for item in items.drain(..) {
                    t.on_bus_item(item);
                }
                t.publish_dirty();
            }
            e = events.recv() => match e {
                Ok(e) => {
                    let slots = t.by_node.get(&e.node).cloned().unwrap_or_default();
                    for i in slots {
                        t.on_node_event(i, e.kind.clone());
                    }
                }
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    tracing::warn!(lost = n, "axis task missed node events");
                }
                Err(broadcast::error::RecvError::Closed) => break,
            },
            Some((i, result)) = results.recv() => {
                let now = t.now();
                let mut out = Vec::new();
                t.slots[i].axis.on_sdo_done(result, now, &mut out);
                t.handle(i, out);
            }
            Some((i, report)) = reports.recv() => t.on_sdo_report(i, report),
            _ = &mut sleep => {
                armed = None;
                t.take_samples();
                let now = t.now();
                for i in 0..t.slots.len() {
                    if t.slots[i].axis.next_deadline().is_some_and(|d| d <= now) {
                        let mut out = Vec::new();
                        t.slots[i].axis.on_tick(now, &mut out);
                        t.handle(i, out);
                        t.publish_status(i);
                    }
                }
            }
        }
        t.publish_plans();
        t.flush().await;
    }
}

impl Task {
    fn now(&self) -> Duration {
        self.origin.elapsed()
    }

    /// One frame (or notice) of the process data subscription.
    fn on_bus_item(&mut self, item: BusItem) {
        let frame = match item {
            BusItem::Frame { frame, .. } => {
                if frame.is_extended() {
                    return;
                }
                frame
            }
            BusItem::Lost(n) => {
                tracing::warn!(lost = n, "axis task missed process data (overloaded)");
                return;
            }
            BusItem::State(_) => return,
        };
        let cob = frame.raw_id() as u16;
        let Some(&(i, _)) = self.tpdos.get(&cob) else {
            return;
        };
        let bit = self.tpdo_bit.get(&cob).copied().unwrap_or(0);
        if self.round[i] & bit != 0 {
            self.round[i] = 0;
            if std::mem::take(&mut self.dirty[i]) {
                self.publish_status(i);
            }
        }
        self.round[i] |= bit;
        let Some((_, cfg)) = self.tpdos.get(&cob) else {
            return;
        };
        self.master.relay_tpdo(&frame);
        if !self.slots[i].booted {
            return;
        }
        match feedback_from_pdo(cfg, frame.data()) {
            Ok(fb) => {
                let now = self.now();
                let mut out = std::mem::take(&mut self.scratch);
                self.slots[i].at = frame.timestamp();
                self.slots[i].axis.on_feedback(fb, now, &mut out);
                self.handle_with(i, &mut out);
                self.scratch = out;
                // Published once the drive's TPDOs of this SYNC are all
                // in (see `round`).
                self.dirty[i] = true;
            }
            Err(e) => {
                tracing::debug!(parent: &self.slots[i].span, cob_id = cob_hex(frame.raw_id()), error = %e, "undecodable TPDO")
            }
        }
    }

    /// A report of an axis's SDO fallback worker.
    fn on_sdo_report(&mut self, i: usize, report: SdoReport) {
        let mut out = Vec::new();
        let slot = &mut self.slots[i];
        let span = slot.span.clone();
        let Some(link) = slot.sdo.as_mut() else {
            return;
        };
        let mut node_event = None;
        match report {
            SdoReport::Feedback(_) if !slot.booted => return,
            SdoReport::Feedback(fb) => {
                link.failures = 0;
                if std::mem::take(&mut link.lost) && !link.booting {
                    slot.axis.on_node_back(false, &mut out);
                    node_event = Some((false, "the drive answers SDO polls again".to_string()));
                }
                slot.at = Timestamp::now();
                slot.axis.on_feedback(fb, self.origin.elapsed(), &mut out);
            }
            SdoReport::Failed(e) => {
                link.failures += 1;
                if link.failures == 1 {
                    tracing::warn!(parent: &span, error = %e, "SDO process data failed");
                }
                if link.failures >= SDO_FAILURES_LOST && !link.lost {
                    link.lost = true;
                    let reason = format!(
                        "process data by SDO failed {} times in a row: {e}",
                        link.failures
                    );
                    slot.axis.on_node_lost(&reason, &mut out);
                    node_event = Some((true, reason));
                }
            }
        }
        if let Some((lost, reason)) = node_event {
            self.publish_node_link(i, lost, reason);
        }
        self.handle(i, out);
        self.publish_status(i);
    }

    /// Hands the SYNC thread's latest set-point of each cyclic axis to
    /// the axis: its demand follows, a finished trajectory completes.
    fn take_samples(&mut self) {
        let mut samples = std::mem::take(&mut self.samples);
        self.setpoints.take_samples(&mut samples);
        if !samples.is_empty() {
            let now = self.now();
            let mut out = std::mem::take(&mut self.scratch);
            for (i, sample) in samples.drain(..) {
                self.slots[i].axis.on_cyclic_sample(&sample, now, &mut out);
                self.handle_with(i, &mut out);
            }
            self.scratch = out;
        }
        self.samples = samples;
    }

    /// Publishes to the SYNC thread every cyclic axis's plan that changed
    /// this turn, in one go: a multi-axis command starts in one SYNC.
    fn publish_plans(&mut self) {
        let mut changed = Vec::new();
        for (i, slot) in self.slots.iter_mut().enumerate() {
            let Some(layout) = &slot.setpoint else {
                continue;
            };
            let plan = slot.axis.cyclic_plan();
            if plan == slot.published {
                continue;
            }
            // The RPDO's other values from the image as it stands.
            let payload = match encode_image(&slot.axis.image(), std::slice::from_ref(&layout.rpdo))
            {
                Ok(mut frames) => frames.pop().map(|(_, d)| d).unwrap_or_default(),
                Err(e) => {
                    tracing::error!(parent: &slot.span, error = %e, "cannot encode the set-point RPDO");
                    continue;
                }
            };
            slot.setpoint_payload = layout.masked(&payload);
            if plan.as_ref().is_some_and(CyclicPlan::is_moving)
                && slot.axis.current_op().is_none()
                && let Some(sw) = slot.axis.snapshot().signals.limit_switch()
            {
                // A ramp without a command, on a limit switch: the
                // switch's stop. A stream the axis plays in ends saying so
                // (else the ramp ends it as stopped).
                self.setpoints.end_stream_of(
                    i,
                    super::cyclic_setpoints::StreamEnd::LimitSwitch {
                        axis: slot.name.clone(),
                        switch: sw.name(),
                    },
                );
            }
            changed.push((i, plan.clone(), layout.rpdo.cob_id, payload, layout.offset));
            slot.published = plan;
        }
        if !changed.is_empty() {
            self.setpoints.publish(changed);
        }
    }

    /// Publishes the status of every axis that had feedback since the last
    /// call and has its drive's TPDOs of the cycle all in.
    fn publish_dirty(&mut self) {
        for i in 0..self.slots.len() {
            if self.dirty[i] && self.round[i] & self.round_full[i] == self.round_full[i] {
                self.dirty[i] = false;
                self.round[i] = 0;
                self.publish_status(i);
            }
        }
    }

    fn on_request(&mut self, r: BusRequest) {
        let now = self.now();
        self.dispatch(r, now);
    }

    fn on_node_event(&mut self, i: usize, kind: NodeEventKind) {
        let mut out = Vec::new();
        let (lost, reason) = match kind {
            NodeEventKind::HeartbeatLost { timeout, guarding } => {
                let r = if guarding {
                    format!(
                        "no node guarding answer for {} ms (life time)",
                        timeout.as_millis()
                    )
                } else {
                    format!("no heartbeat for {} ms", timeout.as_millis())
                };
                self.slots[i].axis.on_node_lost(&r, &mut out);
                (true, r)
            }
            NodeEventKind::HeartbeatRecovered { guarding, .. } => {
                self.slots[i].axis.on_node_back(false, &mut out);
                let back = if guarding {
                    "node guarding answers back"
                } else {
                    "heartbeat back"
                };
                (false, back.to_string())
            }
            NodeEventKind::BootUp => {
                self.slots[i].booted = false;
                if let Some(link) = &mut self.slots[i].sdo {
                    link.booting = true;
                }
                let r = "node rebooted; waiting for its boot procedure".to_string();
                self.slots[i].axis.on_node_lost(&r, &mut out);
                (true, r)
            }
            NodeEventKind::BootCompleted { adopted } => {
                self.slots[i].booted = true;
                let drive_axis = self.slots[i].axis.config().drive_axis;
                if let Some(mask) = self
                    .master
                    .supported_drive_modes(self.slots[i].node, drive_axis)
                {
                    self.slots[i].axis.set_supported_modes(mask);
                }
                if let Some(link) = &mut self.slots[i].sdo {
                    link.booting = false;
                    // Before any image the reboot leads to.
                    link.worker
                        .forget
                        .store(true, std::sync::atomic::Ordering::Release);
                }
                // An adopted drive kept its state: the axis takes it as it
                // finds it (no reboot, nothing forgotten).
                self.slots[i].axis.on_node_back(!adopted, &mut out);
                let what = if adopted {
                    "boot procedure completed (drive found running, adopted)"
                } else {
                    "boot procedure completed"
                };
                (false, what.to_string())
            }
            NodeEventKind::BootFailed { reason } => {
                if let Some(link) = &mut self.slots[i].sdo {
                    // Not usable until a boot procedure completes.
                    link.booting = true;
                }
                let r = format!("boot failed: {reason}");
                self.slots[i].axis.on_node_lost(&r, &mut out);
                (true, r)
            }
            NodeEventKind::Emcy(e) => {
                self.slots[i].axis.on_emcy(e.code, e.code_name(), &mut out);
                self.handle(i, out);
                self.publish_status(i);
                return;
            }
            NodeEventKind::StateChanged { .. } | NodeEventKind::GuardingToggleError { .. } => {
                return;
            }
        };
        self.publish_node_link(i, lost, reason);
        self.handle(i, out);
        self.publish_status(i);
    }

    /// Turns the controller's outputs into frames, SDO jobs, events and
    /// waiter replies.
    fn handle(&mut self, i: usize, mut outputs: Vec<Output>) {
        self.handle_with(i, &mut outputs);
    }

    /// As [`Task::handle`], draining `outputs` (a reused buffer). While the
    /// SYNC thread sends a cyclic axis's set-points, its set-point RPDO is
    /// not sent from here: a set-point from this task could be older than
    /// the one the SYNC thread just sent, and overwrite it in the drive.
    /// A change of that RPDO's other values goes to the SYNC thread.
    fn handle_with(&mut self, i: usize, outputs: &mut Vec<Output>) {
        for o in outputs.drain(..) {
            match o {
                Output::Image(image) if self.slots[i].sdo.is_some() => {
                    self.send_sdo_image(i, image)
                }
                Output::Image(image) => match encode_image(&image, &self.slots[i].rpdos) {
                    Ok(frames) => {
                        // A torque stream's torque RPDO is the SYNC
                        // thread's: the axis's own (a torque of 0) would
                        // cut into the stream's ramp.
                        let streamed_torque = self.setpoints.torque_stream_cob(i);
                        let slot = &mut self.slots[i];
                        for (cob, data) in frames {
                            if streamed_torque == Some(cob) {
                                continue;
                            }
                            if let Some(layout) = &slot.setpoint
                                && slot.published.is_some()
                                && layout.rpdo.cob_id == cob
                            {
                                let masked = layout.masked(&data);
                                if masked != slot.setpoint_payload {
                                    slot.setpoint_payload = masked;
                                    self.setpoints.set_payload(i, data);
                                }
                                continue;
                            }
                            if let Ok(f) = Frame::new(CanId::Standard(cob), &data) {
                                self.frames.push(f);
                            }
                        }
                    }
                    Err(e) => {
                        tracing::error!(parent: &self.slots[i].span, error = %e, "cannot encode the axis RPDOs")
                    }
                },
                Output::SdoWrites(writes) => self.spawn_sdo(i, writes),
                Output::Event(e) => self.on_axis_event(i, e),
            }
        }
    }

    /// Hands an image to the axis's SDO worker. A full queue (the drive
    /// stopped answering for 64 images) drops it, loudly: the axis's state
    /// timeout then fails the command that produced it.
    fn send_sdo_image(&self, i: usize, image: cangate_axis::cia402::ProcessImage) {
        let Some(link) = &self.slots[i].sdo else {
            return;
        };
        if let Err(mpsc::error::TrySendError::Full(_)) = link.worker.images.try_send(image) {
            tracing::error!(
                parent: &self.slots[i].span,
                "process image dropped: the drive's SDO queue is full (the drive does not answer)"
            );
        }
    }

    fn spawn_sdo(&self, i: usize, writes: Vec<(ObjectAddress, Vec<u8>)>) {
        let master = self.master.clone();
        let node = self.slots[i].node;
        let done = self.sdo_done.clone();
        tokio::spawn(async move {
            let result = sdo_process_data::download_all(&master, node, writes).await;
            let _ = done.send((i, result)).await;
        });
    }

    fn on_axis_event(&mut self, i: usize, e: AxisEvent) {
        // The drive guard, GetAxis and the status stream know the state
        // that ended a command before the command's caller does: a client
        // that reads the axis after its Disable completed must not see it
        // enabled, nor be refused by the guard.
        self.publish_status(i);
        // A cyclic axis that stopped sending set-points (disabled, lost)
        // withdraws its plan now, not at the end of this turn: a client
        // that changes the SYNC right after its Disable completed must not
        // be vetoed by the plan of an axis that is no longer enabled.
        // (Only a withdrawal: new plans of a multi-axis command still go
        // out together, from publish_plans.)
        let slot = &mut self.slots[i];
        if let Some(layout) = &slot.setpoint
            && slot.published.is_some()
            && slot.axis.cyclic_plan().is_none()
        {
            self.setpoints
                .publish([(i, None, layout.rpdo.cob_id, Vec::new(), layout.offset)]);
            slot.published = None;
        }
        // Likewise an axis that starts sending set-points at rest (its
        // Enable completed) publishes its holding plan now: a client that
        // opens a set-point stream right after must find the axis served.
        if slot.setpoint.is_some()
            && slot.published.is_none()
            && slot.axis.cyclic_plan().is_some_and(|p| !p.is_moving())
        {
            self.publish_plans();
        }
        let slot = &mut self.slots[i];
        let axis = &slot.axis;
        slot.waiters.dispatch(
            e,
            &slot.name,
            slot.global,
            || axis.snapshot(),
            Some(&self.updates),
        );
    }

    /// Tells the axis's stream subscribers that its node went away or came
    /// back, and why.
    fn publish_node_link(&self, i: usize, lost: bool, reason: String) {
        let _ = self.updates.send(AxisUpdate::Event {
            axis: self.slots[i].global,
            at: Timestamp::now(),
            event: AxisEventKind::Node { lost, reason },
        });
    }

    fn publish_status(&mut self, i: usize) {
        let slot = &self.slots[i];
        let mut snapshot = slot.axis.snapshot();
        if snapshot.activity != cangate_axis::Activity::Moving && self.setpoints.in_torque_stream(i)
        {
            // The torque command that holds a torque stream's drive ended:
            // its guard stopped it (the velocity, or a stop from here past
            // a soft limit), a stop reached it, or the drive left
            // operation enabled. The stream's torques ramp to 0.
            let axis = slot.name.clone();
            let reason = match slot.axis.guard() {
                _ if snapshot.state != Some(DriveState::OperationEnabled) => {
                    StreamEnd::AxisLeft { axis }
                }
                Some(why) => StreamEnd::TorqueGuard {
                    axis,
                    why: why.to_string(),
                },
                None => StreamEnd::Stopped { axis },
            };
            self.setpoints.end_stream_of(i, reason);
        }
        // A streamed axis runs no command of its own, yet it moves.
        if snapshot.activity == cangate_axis::Activity::Idle && self.setpoints.in_stream(i) {
            snapshot.activity = cangate_axis::Activity::Moving;
        }
        let snapshot = Arc::new(snapshot);
        slot.drive_guard.publish(
            snapshot.state,
            snapshot.activity == cangate_axis::Activity::Idle,
        );
        self.latest.write().expect("latest lock")[slot.global] = Some((snapshot.clone(), slot.at));
        let _ = self.updates.send(AxisUpdate::Status {
            axis: slot.global,
            snapshot,
            at: slot.at,
        });
    }

    async fn flush(&mut self) {
        if self.frames.is_empty() {
            return;
        }
        let frames = std::mem::take(&mut self.frames);
        if let Err(e) = self.master.send_frames(frames).await {
            tracing::warn!(error = %e, "axis process data not sent");
        }
    }
}

fn cob_hex(id: u32) -> String {
    format!("0x{id:03X}")
}

impl Task {
    /// An axis that plays a set-point stream takes no command but a stop,
    /// which ends the stream.
    fn check_streams(&self, i: usize, cmd: &AxisCommand) -> Result<(), CommandError> {
        if matches!(cmd, AxisCommand::Stop | AxisCommand::QuickStop) {
            // A stop wins over a set-point stream, at once: the stream's
            // axes ramp to rest from the next SYNC on, whoever stops.
            self.setpoints.stop_stream_of(i);
            return Ok(());
        }
        if self.setpoints.in_stream(i) {
            return Err(CommandError::Busy(format!(
                "axis {} plays a set-point stream: end the stream or stop the axis first",
                self.slots[i].name
            )));
        }
        Ok(())
    }

    /// A cyclic axis gets its set-points with every SYNC and its drive
    /// reports with every SYNC: with the bus's SYNC stopped (SetSync) it
    /// takes no command but a stop or a disable, which would otherwise
    /// wait for a SYNC that never comes.
    fn check_sync(&self, i: usize, cmd: &AxisCommand) -> Result<(), CommandError> {
        let stopping = matches!(
            cmd,
            AxisCommand::Stop | AxisCommand::QuickStop | AxisCommand::Disable
        );
        let axis = &self.slots[i].axis;
        if let AxisCommand::SetMode { mode } = cmd
            && mode.position_mode() == PositionMode::Cyclic
            && !self.master.sync_settings().running
        {
            return Err(CommandError::SyncStopped(format!(
                "mode {mode} takes a set-point with every SYNC and the SYNC of bus {} is not \
                 running (configure sync_period_us, or start it: `cangate sync {} start`, SetSync)",
                self.master.bus(),
                self.master.bus()
            )));
        }
        let cyclic = axis.mode().position_mode() == PositionMode::Cyclic;
        if stopping
            || !cyclic
            || self.slots[i].setpoint.is_none()
            || self.master.sync_settings().running
        {
            return Ok(());
        }
        Err(CommandError::SyncStopped(format!(
            "axis {} is cyclic and the SYNC of bus {} is stopped (start it: `cangate sync {} \
             start`, SetSync)",
            self.slots[i].name,
            self.master.bus(),
            self.master.bus()
        )))
    }
}

impl AxisRunner for Task {
    fn start_command(
        &mut self,
        i: usize,
        cmd: AxisCommand,
        wait: bool,
        now: Duration,
    ) -> Result<Waiter, CommandError> {
        self.check_streams(i, &cmd)?;
        self.check_sync(i, &cmd)?;
        let mut out = Vec::new();
        let op = self.slots[i].axis.command(cmd, now, &mut out)?;
        let rx = self.slots[i].waiters.add(op, wait);
        self.handle(i, out);
        self.publish_status(i);
        Ok(rx)
    }

    fn start_coordinated(
        &mut self,
        targets: Vec<CoordinatedTarget>,
        wait: bool,
        now: Duration,
    ) -> Result<Vec<Waiter>, CommandError> {
        for t in &targets {
            self.check_streams(t.0, &AxisCommand::Enable)?;
            self.check_sync(t.0, &AxisCommand::Enable)?;
        }
        let slots = &self.slots;
        let plan = prepare_coordinated(&targets, |i| (slots[i].name.as_str(), &slots[i].axis))?;
        let mut waiters = Vec::new();
        for ((profile, ratio), &(i, ..)) in plan.into_iter().zip(&targets) {
            let mut out = Vec::new();
            let op = self.slots[i]
                .axis
                .start_coordinated(profile, ratio, now, &mut out)
                .map_err(|e| for_axis(&self.slots[i].name, e))?;
            waiters.push(self.slots[i].waiters.add(op, wait));
            self.handle(i, out);
            self.publish_status(i);
        }
        Ok(waiters)
    }
}
