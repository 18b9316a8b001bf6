//! The task that runs the CiA 402 axes of one CANopen bus: it feeds each
//! [`Cia402Axis`] the drive's decoded TPDOs, the master's SYNCs, node events
//! and time; sends the process images it returns as RPDOs (all frames of one
//! step in one batch, so a multi-axis stop leaves together); runs the SDO
//! writes it asks for; and answers command waiters.

use super::{AxisEventKind, AxisInfo, AxisUpdate, LatestStates};
use crate::canopen::{CanopenBus, NodeEventKind};
use cangate_axis::cia402::{AxisSnapshot, Cia402Axis, Output};
use cangate_axis::process_data::{encode_image, feedback_from_values};
use cangate_axis::{AxisCommand, AxisEvent, CommandError, OpId, Outcome};
use cangate_can::{CanId, Frame, Timestamp};
use cangate_canopen::master::SdoRequest;
use cangate_canopen::pdo::{PdoConfig, PdoKind};
use cangate_canopen::sdo::TransferOptions;
use cangate_canopen::{NodeId, ObjectAddress};
use cangate_motion::{AxisMove, Limits, SyncedMove};
use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::{broadcast, mpsc, oneshot};
use tokio_util::sync::CancellationToken;

/// How a command ended, for its caller.
#[derive(Debug)]
pub struct CommandReply {
    /// `None`: accepted (not waited for).
    pub outcome: Option<Outcome>,
    /// For people.
    pub detail: String,
    /// The axis right after.
    pub snapshot: AxisSnapshot,
}

type Waiter = oneshot::Receiver<CommandReply>;

/// Requests to a bus task.
pub enum BusRequest {
    /// One command.
    Command {
        /// Axis index in this task.
        local: usize,
        /// The command.
        cmd: AxisCommand,
        /// Reply at completion instead of acceptance.
        wait: bool,
        /// The waiter, or why the command was refused.
        reply: oneshot::Sender<Result<Waiter, CommandError>>,
    },
    /// Several commands applied in one step.
    Many {
        /// (axis, command).
        cmds: Vec<(usize, AxisCommand)>,
        /// As above.
        wait: bool,
        /// One result per command.
        reply: oneshot::Sender<Vec<Result<Waiter, CommandError>>>,
    },
    /// A coordinated cyclic move: (axis, target, velocity, acceleration).
    Coordinated {
        /// Targets.
        targets: Vec<(usize, f64, Option<f64>, Option<f64>)>,
        /// As above.
        wait: bool,
        /// The waiters (all or none).
        reply: oneshot::Sender<Result<Vec<Waiter>, CommandError>>,
    },
}

struct PendingReply {
    wait: bool,
    tx: oneshot::Sender<CommandReply>,
}

struct Slot {
    global: usize,
    info: AxisInfo,
    axis: Cia402Axis,
    rpdos: Vec<PdoConfig>,
    waiters: HashMap<OpId, PendingReply>,
    /// Bus time of the latest process data.
    at: Timestamp,
    /// The latest payload sent per RPDO COB-ID.
    last_sent: HashMap<u16, Vec<u8>>,
}

struct Task {
    master: CanopenBus,
    slots: Vec<Slot>,
    by_node: HashMap<NodeId, usize>,
    updates: broadcast::Sender<AxisUpdate>,
    latest: LatestStates,
    origin: Instant,
    frames: Vec<Frame>,
    sdo_done: mpsc::Sender<(usize, Result<(), String>)>,
}

/// Runs the axes `list` (global index, info) of `master`'s bus.
pub async fn run(
    master: CanopenBus,
    list: Vec<(usize, AxisInfo)>,
    mut requests: mpsc::Receiver<BusRequest>,
    updates: broadcast::Sender<AxisUpdate>,
    latest: LatestStates,
    cancel: CancellationToken,
) {
    let mut pdos = master.pdos();
    let mut events = master.events();
    let mut syncs = master.syncs();
    let (sdo_done, mut sdo_results) = mpsc::channel(64);
    let slots = list
        .into_iter()
        .map(|(global, info)| {
            let rpdos = master
                .rpdos(info.node)
                .into_iter()
                .filter(|p| p.kind == PdoKind::Rpdo)
                .collect();
            Slot {
                global,
                axis: Cia402Axis::new(info.config.controller()),
                info,
                rpdos,
                waiters: HashMap::new(),
                at: Timestamp(0),
                last_sent: HashMap::new(),
            }
        })
        .collect::<Vec<_>>();
    let by_node = slots
        .iter()
        .enumerate()
        .map(|(i, s)| (s.info.node, i))
        .collect();
    let mut t = Task {
        master,
        slots,
        by_node,
        updates,
        latest,
        origin: Instant::now(),
        frames: Vec::new(),
        sdo_done,
    };
    let far = Duration::from_secs(3600);
    loop {
        let next = t
            .slots
            .iter()
            .filter_map(|s| s.axis.next_deadline())
            .min()
            .unwrap_or(t.now() + far);
        let deadline = t.origin + next;
        tokio::select! {
            biased;
            _ = cancel.cancelled() => break,
            r = requests.recv() => match r {
                Some(r) => t.on_request(r),
                None => break,
            },
            _ = syncs.recv() => {
                // A lagged receiver only means SYNCs came faster than we
                // ran; the next one is handled normally.
                let now = t.now();
                for i in 0..t.slots.len() {
                    let mut out = Vec::new();
                    t.slots[i].axis.on_sync(now, &mut out);
                    t.handle_with(i, out, true);
                }
            }
            p = pdos.recv() => match p {
                Ok(p) => {
                    if p.kind == PdoKind::Tpdo
                        && let Some(&i) = t.by_node.get(&p.node)
                    {
                        let fb = feedback_from_values(p.values.iter().map(|(m, v, _)| (m.addr, v)));
                        let now = t.now();
                        let mut out = Vec::new();
                        t.slots[i].at = p.at;
                        t.slots[i].axis.on_feedback(fb, now, &mut out);
                        t.handle(i, out);
                        t.publish_status(i);
                    }
                }
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    tracing::warn!(bus = %t.master.bus(), lost = n, "axis task missed process data updates (overloaded)");
                }
                Err(broadcast::error::RecvError::Closed) => break,
            },
            e = events.recv() => match e {
                Ok(e) => {
                    if let Some(&i) = t.by_node.get(&e.node) {
                        t.on_node_event(i, e.kind);
                    }
                }
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    tracing::warn!(bus = %t.master.bus(), lost = n, "axis task missed node events");
                }
                Err(broadcast::error::RecvError::Closed) => break,
            },
            Some((i, result)) = sdo_results.recv() => {
                let now = t.now();
                let mut out = Vec::new();
                t.slots[i].axis.on_sdo_done(result, now, &mut out);
                t.handle(i, out);
            }
            _ = tokio::time::sleep_until(deadline.into()) => {
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
        t.flush().await;
    }
}

impl Task {
    fn now(&self) -> Duration {
        self.origin.elapsed()
    }

    fn on_request(&mut self, r: BusRequest) {
        let now = self.now();
        match r {
            BusRequest::Command {
                local,
                cmd,
                wait,
                reply,
            } => {
                let r = self.start(local, cmd, wait, now);
                let _ = reply.send(r);
            }
            BusRequest::Many { cmds, wait, reply } => {
                let r = cmds
                    .into_iter()
                    .map(|(local, cmd)| self.start(local, cmd, wait, now))
                    .collect();
                let _ = reply.send(r);
            }
            BusRequest::Coordinated {
                targets,
                wait,
                reply,
            } => {
                let _ = reply.send(self.coordinated(targets, wait, now));
            }
        }
    }

    fn start(
        &mut self,
        i: usize,
        cmd: AxisCommand,
        wait: bool,
        now: Duration,
    ) -> Result<Waiter, CommandError> {
        let mut out = Vec::new();
        let op = self.slots[i].axis.command(cmd, now, &mut out)?;
        let (tx, rx) = oneshot::channel();
        self.slots[i].waiters.insert(op, PendingReply { wait, tx });
        self.handle(i, out);
        self.publish_status(i);
        Ok(rx)
    }

    fn coordinated(
        &mut self,
        targets: Vec<(usize, f64, Option<f64>, Option<f64>)>,
        wait: bool,
        now: Duration,
    ) -> Result<Vec<Waiter>, CommandError> {
        let mut moves = Vec::new();
        for &(i, target, v, a) in &targets {
            let cfg = self.slots[i].axis.config();
            let v = v.unwrap_or(cfg.default_velocity);
            let a = a.unwrap_or(cfg.default_acceleration);
            if v > cfg.max_velocity || a > cfg.max_acceleration {
                return Err(CommandError::OutOfRange(format!(
                    "axis {}: velocity {v} / acceleration {a} exceed the maxima {} / {}",
                    self.slots[i].info.config.name, cfg.max_velocity, cfg.max_acceleration
                )));
            }
            let limits = Limits::symmetric(v, a).map_err(|e| {
                CommandError::InvalidArgument(format!(
                    "axis {}: {e}",
                    self.slots[i].info.config.name
                ))
            })?;
            moves.push(AxisMove::new(self.slots[i].axis.demand(), target, limits));
        }
        let plan =
            SyncedMove::new(moves).map_err(|e| CommandError::InvalidArgument(e.to_string()))?;
        // All or none: check every axis before starting any.
        for &(i, target, ..) in &targets {
            self.slots[i]
                .axis
                .check_coordinated(target)
                .map_err(|e| prefix(&self.slots[i].info.config.name, e))?;
        }
        let mut waiters = Vec::new();
        for (k, &(i, ..)) in targets.iter().enumerate() {
            let profile = plan.profile(k).expect("one profile per axis").clone();
            let ratio = plan
                .time_scale(k)
                .map_or(0.0, |l| if l.is_finite() { 1.0 / l } else { 0.0 });
            let mut out = Vec::new();
            let op = self.slots[i]
                .axis
                .start_coordinated(profile, ratio, now, &mut out)
                .map_err(|e| prefix(&self.slots[i].info.config.name, e))?;
            let (tx, rx) = oneshot::channel();
            self.slots[i].waiters.insert(op, PendingReply { wait, tx });
            self.handle(i, out);
            self.publish_status(i);
            waiters.push(rx);
        }
        Ok(waiters)
    }

    fn on_node_event(&mut self, i: usize, kind: NodeEventKind) {
        let mut out = Vec::new();
        let (lost, reason) = match kind {
            NodeEventKind::HeartbeatLost { timeout } => {
                let r = format!("no heartbeat for {} ms", timeout.as_millis());
                self.slots[i].axis.on_node_lost(&r, &mut out);
                (true, r)
            }
            NodeEventKind::HeartbeatRecovered { .. } => {
                self.slots[i].axis.on_node_back(false, &mut out);
                (false, "heartbeat back".to_string())
            }
            NodeEventKind::BootUp => {
                let r = "node rebooted; waiting for its boot procedure".to_string();
                self.slots[i].axis.on_node_lost(&r, &mut out);
                (true, r)
            }
            NodeEventKind::BootCompleted => {
                self.slots[i].axis.on_node_back(true, &mut out);
                (false, "boot procedure completed".to_string())
            }
            NodeEventKind::BootFailed { reason } => {
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
            NodeEventKind::StateChanged { .. } => return,
        };
        let _ = self.updates.send(AxisUpdate::Event {
            axis: self.slots[i].global,
            at: Timestamp::now(),
            event: AxisEventKind::Node { lost, reason },
        });
        self.handle(i, out);
        self.publish_status(i);
    }

    /// Turns the controller's outputs into frames, SDO jobs, events and
    /// waiter replies.
    fn handle(&mut self, i: usize, outputs: Vec<Output>) {
        self.handle_with(i, outputs, false);
    }

    /// As [`Task::handle`]; `cyclic` images (the set-point of every SYNC)
    /// send only the RPDO with the target position and those whose payload
    /// changed: the controlword RPDO is not repeated 1000 times a second.
    fn handle_with(&mut self, i: usize, outputs: Vec<Output>, cyclic: bool) {
        for o in outputs {
            match o {
                Output::Image(image) => match encode_image(&image, &self.slots[i].rpdos) {
                    Ok(frames) => {
                        let slot = &mut self.slots[i];
                        for (cob, data) in frames {
                            let setpoint = slot.rpdos.iter().any(|p| {
                                p.cob_id == cob
                                    && p.mapping.iter().any(|m| {
                                        m.addr == cangate_canopen::ds402::objects::TARGET_POSITION
                                    })
                            });
                            if cyclic && !setpoint && slot.last_sent.get(&cob) == Some(&data) {
                                continue;
                            }
                            if let Ok(f) = Frame::new(CanId::Standard(cob), &data) {
                                self.frames.push(f);
                            }
                            slot.last_sent.insert(cob, data);
                        }
                    }
                    Err(e) => {
                        tracing::error!(axis = %self.slots[i].info.config.name, error = %e, "cannot encode the axis RPDOs")
                    }
                },
                Output::SdoWrites(writes) => self.spawn_sdo(i, writes),
                Output::Event(e) => self.on_axis_event(i, e),
            }
        }
    }

    fn spawn_sdo(&self, i: usize, writes: Vec<(ObjectAddress, Vec<u8>)>) {
        let master = self.master.clone();
        let node = self.slots[i].info.node;
        let done = self.sdo_done.clone();
        tokio::spawn(async move {
            let mut result = Ok(());
            for (addr, data) in writes {
                let r = master
                    .sdo(
                        node,
                        SdoRequest::Download {
                            addr,
                            data,
                            opts: TransferOptions::default(),
                        },
                    )
                    .await;
                if let Err(e) = r {
                    result = Err(format!("writing {addr}: {e}"));
                    break;
                }
            }
            let _ = done.send((i, result)).await;
        });
    }

    fn on_axis_event(&mut self, i: usize, e: AxisEvent) {
        let slot = &mut self.slots[i];
        match e {
            AxisEvent::Accepted { op } => {
                if slot.waiters.get(&op).is_some_and(|w| !w.wait)
                    && let Some(w) = slot.waiters.remove(&op)
                {
                    let _ = w.tx.send(CommandReply {
                        outcome: None,
                        detail: "accepted by the drive".into(),
                        snapshot: slot.axis.snapshot(),
                    });
                }
            }
            AxisEvent::Done {
                op,
                command,
                outcome,
                detail,
            } => {
                tracing::info!(target: "cangate::audit", axis = %slot.info.config.name, command = %command, outcome = outcome.name(), %detail, "axis command ended");
                if let Some(w) = slot.waiters.remove(&op) {
                    let _ = w.tx.send(CommandReply {
                        outcome: Some(outcome),
                        detail: detail.clone(),
                        snapshot: slot.axis.snapshot(),
                    });
                }
                let _ = self.updates.send(AxisUpdate::Event {
                    axis: slot.global,
                    at: Timestamp::now(),
                    event: AxisEventKind::MotionDone {
                        command,
                        outcome,
                        detail,
                    },
                });
            }
            AxisEvent::Fault { code, text } => {
                if code == 0 && text.is_empty() {
                    tracing::info!(axis = %slot.info.config.name, "axis fault cleared");
                } else if code == 0 && text.contains("rebooted") {
                    // Every start-up: the drive boots, the boot procedure
                    // configures it; not worth a warning.
                    tracing::info!(axis = %slot.info.config.name, %text, "axis waits for its drive");
                } else {
                    tracing::warn!(axis = %slot.info.config.name, code = format!("0x{code:04X}"), %text, "axis fault");
                }
                let _ = self.updates.send(AxisUpdate::Event {
                    axis: slot.global,
                    at: Timestamp::now(),
                    event: AxisEventKind::Fault { code, text },
                });
            }
        }
    }

    fn publish_status(&mut self, i: usize) {
        let slot = &self.slots[i];
        let snapshot = Arc::new(slot.axis.snapshot());
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
            tracing::warn!(bus = %self.master.bus(), error = %e, "axis process data not sent");
        }
    }
}

fn prefix(axis: &str, e: CommandError) -> CommandError {
    match e {
        CommandError::OutOfRange(m) => CommandError::OutOfRange(format!("axis {axis}: {m}")),
        CommandError::InvalidArgument(m) => {
            CommandError::InvalidArgument(format!("axis {axis}: {m}"))
        }
        CommandError::FailedPrecondition(m) => {
            CommandError::FailedPrecondition(format!("axis {axis}: {m}"))
        }
    }
}
