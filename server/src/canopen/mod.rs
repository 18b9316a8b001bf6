//! The CANopen master runtime of one bus: one task that owns the sans-IO
//! [`Master`], feeds it the bus's frames and ticks, sends what it asks, and
//! answers the gRPC layer's commands. Also starts the simulated CANopen
//! devices configured on virtual buses.

use cangate_can::{BusHandle, BusItem, FrameSelector, Timestamp};
use cangate_canopen::NodeId;
use cangate_canopen::eds::Eds;
use cangate_canopen::emcy::{Emcy, EmcyEvent};
use cangate_canopen::heartbeat::HeartbeatEvent;
use cangate_canopen::master::{Master, MasterEvent, Output, RequestId, SdoRequest};
use cangate_canopen::nmt::{NmtCommand, NmtState, nmt_frame};
use cangate_canopen::sdo::{SdoError, TransferOutcome};
use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, RwLock};
use std::time::{Duration, Instant};
use tokio::sync::{broadcast, mpsc, oneshot};
use tokio_util::sync::CancellationToken;

/// Static facts about a node, from the configuration and from reads.
#[derive(Debug, Clone, Default)]
pub struct NodeFacts {
    /// Configured name.
    pub name: String,
    /// Configured (as opposed to discovered).
    pub configured: bool,
    /// The node's object dictionary, if an EDS is configured.
    pub eds: Option<Arc<Eds>>,
    /// 0x1000 device type, once read.
    pub device_type: Option<u32>,
    /// 0x1008 device name, once read.
    pub device_name: Option<String>,
    /// 0x1018:01..04, once read.
    pub identity: Option<[u32; 4]>,
    /// Consumer heartbeat timeout.
    pub heartbeat_timeout: Option<Duration>,
}

/// A node's live state as the master sees it.
#[derive(Debug, Clone)]
pub struct NodeSnapshot {
    /// Node id.
    pub id: NodeId,
    /// Static facts.
    pub facts: NodeFacts,
    /// Last NMT state.
    pub state: Option<NmtState>,
    /// Time since the last heartbeat.
    pub heartbeat_age: Option<Duration>,
    /// Heartbeat overdue.
    pub heartbeat_lost: bool,
    /// Boot-ups seen.
    pub boot_ups: u64,
    /// Active error.
    pub active_error: Option<(Emcy, Timestamp)>,
    /// Recent EMCYs.
    pub emcy_history: Vec<(Emcy, Timestamp)>,
}

/// An event for StreamNodeEvents.
#[derive(Debug, Clone)]
pub struct NodeEvent {
    /// Node.
    pub node: NodeId,
    /// When.
    pub at: Timestamp,
    /// What.
    pub kind: NodeEventKind,
}

/// What happened to a node.
#[derive(Debug, Clone)]
pub enum NodeEventKind {
    /// Boot-up message.
    BootUp,
    /// NMT state change.
    StateChanged {
        /// Previous state.
        from: Option<NmtState>,
        /// New state.
        to: NmtState,
    },
    /// Heartbeat overdue.
    HeartbeatLost {
        /// Timeout.
        timeout: Duration,
    },
    /// Heartbeat back.
    HeartbeatRecovered {
        /// Reported state.
        state: NmtState,
        /// Silence.
        after: Duration,
    },
    /// EMCY error or reset.
    Emcy(Emcy),
}

enum Command {
    Sdo {
        node: NodeId,
        req: SdoRequest,
        reply: oneshot::Sender<Result<TransferOutcome, SdoError>>,
    },
    Nmt {
        cmd: NmtCommand,
        target: Option<NodeId>,
        reply: oneshot::Sender<Result<(), cangate_can::SendFailure>>,
    },
    Snapshot {
        reply: oneshot::Sender<Vec<NodeSnapshot>>,
    },
}

/// Why a CANopen command did not complete.
#[derive(Debug, thiserror::Error)]
pub enum CanopenError {
    /// The SDO transfer failed.
    #[error(transparent)]
    Sdo(#[from] SdoError),
    /// The bus refused the frame.
    #[error(transparent)]
    Send(#[from] cangate_can::SendFailure),
    /// The master task stopped (shutdown).
    #[error("the CANopen master of this bus has stopped")]
    Stopped,
}

/// Handle to the CANopen master of one bus.
#[derive(Clone)]
pub struct CanopenBus {
    bus: String,
    commands: mpsc::Sender<Command>,
    events: broadcast::Sender<NodeEvent>,
    facts: Arc<RwLock<BTreeMap<NodeId, NodeFacts>>>,
}

impl CanopenBus {
    /// Starts the master task of `bus`.
    pub fn spawn(
        bus: BusHandle,
        sdo_timeout: Duration,
        configured: BTreeMap<NodeId, NodeFacts>,
        cancel: CancellationToken,
    ) -> (CanopenBus, tokio::task::JoinHandle<()>) {
        let (commands, rx) = mpsc::channel(1024);
        let (events, _) = broadcast::channel(4096);
        let facts = Arc::new(RwLock::new(configured));
        let handle = CanopenBus {
            bus: bus.name().to_string(),
            commands,
            events: events.clone(),
            facts: facts.clone(),
        };
        let mut master = Master::new(sdo_timeout);
        for (id, f) in facts.read().expect("facts lock").iter() {
            if let Some(t) = f.heartbeat_timeout {
                master.monitor_heartbeat(*id, t);
            }
        }
        // Subscribe before returning, so that nothing the nodes send after
        // this point (their boot-up, typically) is missed.
        let sub = bus.subscribe(FrameSelector::default(), 65_536);
        let task = tokio::spawn(run_master(master, bus, sub, rx, events, facts, cancel));
        (handle, task)
    }

    /// Bus name.
    pub fn bus(&self) -> &str {
        &self.bus
    }

    /// Whether a node is configured or has been heard of.
    pub fn knows(&self, node: NodeId) -> bool {
        self.facts.read().expect("facts lock").contains_key(&node)
    }

    /// The node's configured EDS, if any.
    pub fn eds(&self, node: NodeId) -> Option<Arc<Eds>> {
        self.facts
            .read()
            .expect("facts lock")
            .get(&node)
            .and_then(|f| f.eds.clone())
    }

    /// Records facts learnt about a node (scan, boot procedure).
    pub fn learn(&self, node: NodeId, update: impl FnOnce(&mut NodeFacts)) {
        let mut facts = self.facts.write().expect("facts lock");
        update(facts.entry(node).or_default());
    }

    /// Runs one SDO transfer.
    pub async fn sdo(
        &self,
        node: NodeId,
        req: SdoRequest,
    ) -> Result<TransferOutcome, CanopenError> {
        let (reply, rx) = oneshot::channel();
        self.commands
            .send(Command::Sdo { node, req, reply })
            .await
            .map_err(|_| CanopenError::Stopped)?;
        Ok(rx.await.map_err(|_| CanopenError::Stopped)??)
    }

    /// Sends an NMT command.
    pub async fn nmt(&self, cmd: NmtCommand, target: Option<NodeId>) -> Result<(), CanopenError> {
        let (reply, rx) = oneshot::channel();
        self.commands
            .send(Command::Nmt { cmd, target, reply })
            .await
            .map_err(|_| CanopenError::Stopped)?;
        Ok(rx.await.map_err(|_| CanopenError::Stopped)??)
    }

    /// Every known node.
    pub async fn snapshot(&self) -> Result<Vec<NodeSnapshot>, CanopenError> {
        let (reply, rx) = oneshot::channel();
        self.commands
            .send(Command::Snapshot { reply })
            .await
            .map_err(|_| CanopenError::Stopped)?;
        rx.await.map_err(|_| CanopenError::Stopped)
    }

    /// Subscribes to node events.
    pub fn events(&self) -> broadcast::Receiver<NodeEvent> {
        self.events.subscribe()
    }
}

struct Pending {
    reply: oneshot::Sender<Result<TransferOutcome, SdoError>>,
}

async fn run_master(
    mut master: Master,
    bus: BusHandle,
    mut sub: cangate_can::Subscription,
    mut commands: mpsc::Receiver<Command>,
    events: broadcast::Sender<NodeEvent>,
    facts: Arc<RwLock<BTreeMap<NodeId, NodeFacts>>>,
    cancel: CancellationToken,
) {
    let origin = Instant::now();
    let origin_wall = Timestamp::now();
    let mut pending: HashMap<RequestId, Pending> = HashMap::new();
    let mut next_id: RequestId = 1;
    let mut items = Vec::with_capacity(256);
    let mut gc = tokio::time::interval(Duration::from_millis(100));
    gc.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let far = Duration::from_secs(3600);
    loop {
        let mut out = Output::default();
        let deadline = origin + master.next_deadline().unwrap_or(origin.elapsed() + far);
        tokio::select! {
            biased;
            _ = cancel.cancelled() => break,
            n = sub.recv_many(&mut items, 256) => {
                if n == 0 {
                    break;
                }
                let now = origin.elapsed();
                for item in items.drain(..) {
                    match item {
                        BusItem::Frame { frame, .. } => master.on_frame(&frame, now, &mut out),
                        BusItem::Lost(n) => tracing::warn!(bus = %bus.name(), lost = n, "CANopen master missed frames (overloaded)"),
                        BusItem::State(_) => {}
                    }
                }
            }
            cmd = commands.recv() => {
                let Some(cmd) = cmd else { break };
                let now = origin.elapsed();
                match cmd {
                    Command::Sdo { node, req, reply } => {
                        let id = next_id;
                        next_id += 1;
                        pending.insert(id, Pending { reply });
                        master.sdo(id, node, req, now, &mut out);
                    }
                    Command::Nmt { cmd, target, reply } => {
                        let r = bus.send(vec![nmt_frame(cmd, target)]).await;
                        let _ = reply.send(r);
                    }
                    Command::Snapshot { reply } => {
                        let _ = reply.send(snapshot(&master, &facts, origin_wall, now));
                    }
                }
            }
            _ = tokio::time::sleep_until(deadline.into()) => {
                master.on_tick(origin.elapsed(), &mut out);
            }
            _ = gc.tick() => {
                // Callers that gave up (client cancelled, deadline) free
                // their node's SDO channel for the next request.
                let gone: Vec<RequestId> = pending
                    .iter()
                    .filter(|(_, p)| p.reply.is_closed())
                    .map(|(id, _)| *id)
                    .collect();
                for id in gone {
                    pending.remove(&id);
                    master.cancel(id, origin.elapsed(), &mut out);
                }
            }
        }
        if !out.frames.is_empty()
            && let Err(e) = bus.send(std::mem::take(&mut out.frames)).await
        {
            tracing::warn!(bus = %bus.name(), error = %e, "CANopen master could not send");
        }
        for ev in out.events {
            handle_event(ev, &mut pending, &events, &facts);
        }
    }
    tracing::info!(bus = %bus.name(), "CANopen master stopped");
}

fn handle_event(
    ev: MasterEvent,
    pending: &mut HashMap<RequestId, Pending>,
    events: &broadcast::Sender<NodeEvent>,
    facts: &RwLock<BTreeMap<NodeId, NodeFacts>>,
) {
    let at = Timestamp::now();
    let (node, kind) = match ev {
        MasterEvent::SdoCompleted { id, result, .. } => {
            if let Some(p) = pending.remove(&id) {
                let _ = p.reply.send(result);
            }
            return;
        }
        MasterEvent::SdoRejected { id, error } => {
            // Dropping the reply tells the caller the request failed.
            pending.remove(&id);
            tracing::warn!(%error, "SDO request rejected");
            return;
        }
        MasterEvent::Heartbeat(hb) => match hb {
            HeartbeatEvent::BootUp { node } => (node, NodeEventKind::BootUp),
            HeartbeatEvent::StateChanged { node, from, to } => {
                (node, NodeEventKind::StateChanged { from, to })
            }
            HeartbeatEvent::HeartbeatLost { node, timeout, .. } => {
                tracing::warn!(node = node.get(), ?timeout, "heartbeat lost");
                (node, NodeEventKind::HeartbeatLost { timeout })
            }
            HeartbeatEvent::HeartbeatRecovered { node, state, after } => {
                tracing::info!(node = node.get(), ?after, "heartbeat recovered");
                (node, NodeEventKind::HeartbeatRecovered { state, after })
            }
            HeartbeatEvent::Malformed { node, .. } => {
                tracing::debug!(node = node.get(), "malformed heartbeat");
                return;
            }
        },
        MasterEvent::Emcy(e) => match e {
            EmcyEvent::Error(emcy) | EmcyEvent::Reset { emcy, .. } => {
                tracing::warn!(
                    node = emcy.node.get(),
                    code = format!("0x{:04X}", emcy.code),
                    name = emcy.code_name(),
                    "EMCY"
                );
                (emcy.node, NodeEventKind::Emcy(emcy))
            }
            EmcyEvent::Malformed { .. } => return,
        },
    };
    facts.write().expect("facts lock").entry(node).or_default();
    let _ = events.send(NodeEvent { node, at, kind });
}

fn snapshot(
    master: &Master,
    facts: &RwLock<BTreeMap<NodeId, NodeFacts>>,
    origin_wall: Timestamp,
    now: Duration,
) -> Vec<NodeSnapshot> {
    // The master keeps monotonic times since `origin`; clients get wall time.
    let wall = |at: Duration| Timestamp(origin_wall.as_nanos() + at.as_nanos() as u64);
    let facts = facts.read().expect("facts lock");
    facts
        .iter()
        .map(|(&id, f)| {
            let hb = master.heartbeat().status(id);
            let emcy = master.emcy().node(id);
            let history: Vec<(Emcy, Timestamp)> = emcy
                .map(|e| e.history.iter().map(|r| (r.emcy, wall(r.at))).collect())
                .unwrap_or_default();
            let active = emcy.and_then(|e| e.active).map(|a| {
                let t = history
                    .iter()
                    .rev()
                    .find(|(h, _)| *h == a)
                    .map(|(_, t)| *t)
                    .unwrap_or_default();
                (a, t)
            });
            NodeSnapshot {
                id,
                facts: f.clone(),
                state: hb.and_then(|s| s.state),
                heartbeat_age: hb.and_then(|s| s.age(now)),
                heartbeat_lost: hb.is_some_and(|s| s.lost),
                boot_ups: hb.map(|s| s.boot_ups).unwrap_or(0),
                active_error: active,
                emcy_history: history,
            }
        })
        .collect()
}
