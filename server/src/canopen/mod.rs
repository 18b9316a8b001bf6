//! The CANopen master runtime of one bus: one task that owns the sans-IO
//! [`Master`], feeds it the bus's frames and ticks, sends what it asks, and
//! answers the gRPC layer's commands. Also starts the simulated CANopen
//! devices configured on virtual buses.
//!
//! This module holds the handle ([`CanopenBus`]) and what it shares; the
//! task itself is in `master_task.rs`, the boot procedure of the
//! configured nodes in `boot.rs`.

use cangate_can::{BusHandle, BusItem, Filter, FrameSelector, Timestamp};
use cangate_canopen::eds::Eds;
use cangate_canopen::emcy::{Emcy, EmcyEvent};
use cangate_canopen::heartbeat::HeartbeatEvent;
use cangate_canopen::master::{Master, MasterEvent, Output, RequestId, SdoPriority, SdoRequest};
use cangate_canopen::nmt::{NmtCommand, NmtState, nmt_frame};
use cangate_canopen::node_guarding::GuardingEvent;
use cangate_canopen::pdo::{MappedObject, PdoConfig, PdoKind};
use cangate_canopen::sdo::{SdoError, TransferOutcome};
use cangate_canopen::value::Value;
use cangate_canopen::{NodeId, ObjectAddress};
use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, RwLock};
use std::time::{Duration, Instant};
use tokio::sync::{broadcast, mpsc, oneshot};
use tokio_util::sync::CancellationToken;
use tracing::Instrument as _;

mod boot;
pub mod dcf_export;
pub mod drive_guard;
pub mod handover;
pub mod heard;
pub mod lss;
pub mod master_heartbeat;
mod master_task;
pub mod pdo_config;
pub mod program;
pub mod scan;
pub mod sync_thread;
mod time_producer;

use boot::run_boot_supervisor;
use master_task::{MasterTask, master_selector, relay_tpdo, run_master};

/// Static facts about a node, from the configuration and from reads.
#[derive(Debug, Clone, Default)]
pub struct NodeFacts {
    /// Configured name.
    pub name: String,
    /// Configured (as opposed to discovered).
    pub configured: bool,
    /// The node's object dictionary, if an EDS is configured.
    pub eds: Option<Arc<Eds>>,
    /// The text of that EDS (a DCF export writes the values into it).
    pub eds_text: Option<Arc<str>>,
    /// 0x1000 device type, once read.
    pub device_type: Option<u32>,
    /// 0x1008 device name, once read.
    pub device_name: Option<String>,
    /// 0x1018:01..04, once read.
    pub identity: Option<[u32; 4]>,
    /// Consumer heartbeat timeout.
    pub heartbeat_timeout: Option<Duration>,
    /// Node guarding instead of the heartbeat: guard time and life time
    /// factor.
    pub guarding: Option<(Duration, u8)>,
    /// TPDOs the master decodes (configured, else the EDS defaults).
    pub tpdos: Vec<PdoConfig>,
    /// RPDOs WritePdo encodes (configured, else the EDS defaults).
    pub rpdos: Vec<PdoConfig>,
    /// What to do when the node boots, if anything.
    pub boot: Option<Arc<BootPlan>>,
    /// For a node that sends no heartbeat and is not guarded: the NMT
    /// state its boot procedure found (the answer to a node guarding
    /// request) or, when nothing answers that, left it in (pre-operational
    /// when not started, operational after NMT start: commanded, not
    /// confirmed). A heartbeat or guarding answer, once heard, wins.
    pub boot_state: Option<NmtState>,
    /// An axis task reads this node's TPDOs straight from the bus (and
    /// counts and relays them with [`CanopenBus::relay_tpdo`]), so the
    /// master's own subscription leaves them out: at a 1 ms SYNC that takes
    /// a task wake-up per PDO batch off the master.
    pub tpdos_read_by_axis: bool,
    /// 0x6502 supported drive modes as the boot procedure of a drive
    /// read it (axis drives only), per axis of the drive (0x6502 + n ×
    /// 0x800 for axis n of a multi-axis drive).
    pub supported_drive_modes: [Option<u32>; cangate_canopen::cia402::MAX_DRIVE_AXES as usize],
}

/// The boot procedure of a node (in the spirit of CiA 302): check, write
/// the configuration, start.
#[derive(Debug, Clone, Default)]
pub struct BootPlan {
    /// Expected 0x1000.
    pub device_type: Option<u32>,
    /// Expected 0x1018:01.
    pub vendor_id: Option<u32>,
    /// Expected 0x1018:02.
    pub product_code: Option<u32>,
    /// SDO writes in order (heartbeat producer, PDO configuration, extra).
    pub writes: Vec<(ObjectAddress, Vec<u8>)>,
    /// A node the gateway only watches (no `boot`, no axis): its device
    /// type and identity are read so that GetNode shows them, and nothing
    /// is checked, written or started.
    pub identify_only: bool,
    /// Bits of 0x6502 supported drive modes the node must have (the mode
    /// its axis is configured in), per axis of the drive: (axis, bits),
    /// read at 0x6502 + axis × 0x800; empty checks nothing.
    pub required_modes: Vec<(u8, u32)>,
}

/// A decoded PDO.
#[derive(Debug, Clone)]
pub struct PdoUpdate {
    /// The node.
    pub node: NodeId,
    /// RPDO or TPDO.
    pub kind: PdoKind,
    /// PDO number.
    pub num: u16,
    /// COB-ID.
    pub cob_id: u16,
    /// Bus timestamp.
    pub at: Timestamp,
    /// The mapped values.
    pub values: Vec<(MappedObject, Value, String)>,
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
    /// Heartbeat overdue (for a guarded node: its life time ran out).
    pub heartbeat_lost: bool,
    /// Node guarding answers with a wrong toggle bit.
    pub guarding_toggle_errors: u64,
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
    /// Heartbeat overdue, or node guarding lost (`guarding`).
    HeartbeatLost {
        /// Timeout (for node guarding the node life time).
        timeout: Duration,
        /// Detected by node guarding rather than the heartbeat consumer.
        guarding: bool,
    },
    /// Heartbeat back, or a guarding answer after a guarding loss.
    HeartbeatRecovered {
        /// Reported state.
        state: NmtState,
        /// Silence.
        after: Duration,
        /// Seen by node guarding rather than the heartbeat consumer.
        guarding: bool,
    },
    /// A node guarding answer with the wrong toggle bit.
    GuardingToggleError {
        /// The answer byte.
        data: u8,
        /// The toggle bit expected.
        expected: bool,
        /// Toggle errors of the node so far.
        count: u64,
    },
    /// EMCY error or reset.
    Emcy(Emcy),
    /// The boot procedure checked, configured and started the node.
    BootCompleted {
        /// The node was found running when the gateway started (no boot-up
        /// heard): it kept its state (a drive stays enabled), only what
        /// differed from the configuration was written.
        adopted: bool,
    },
    /// The boot procedure failed; the node was not started.
    BootFailed {
        /// Why.
        reason: String,
    },
}

/// The shortest period of periodic TIMEs a bus takes, from the
/// configuration's bound ([`crate::config::MIN_TIME_PERIOD_MS`]), for the
/// API to refuse a shorter one the same way.
pub const MIN_TIME_PERIOD: Duration = Duration::from_millis(crate::config::MIN_TIME_PERIOD_MS);

/// SDO requests one API caller may have queued or running per node by
/// default (`[security.limits] sdo_requests_per_client_and_node`): a
/// caller cannot fill a node's SDO channel for everyone else.
pub const MAX_CLIENT_SDO_PER_NODE: usize = 8;

enum Command {
    Sdo {
        node: NodeId,
        priority: SdoPriority,
        req: SdoRequest,
        reply: oneshot::Sender<Result<TransferOutcome, SdoError>>,
        /// The caller polls for the answer ([`handover`]): the bus thread
        /// stays awake for its next request.
        spins: bool,
    },
    Nmt {
        cmd: NmtCommand,
        target: Option<NodeId>,
        reply: oneshot::Sender<Result<(), cangate_can::SendFailure>>,
    },
    Snapshot {
        reply: oneshot::Sender<Vec<NodeSnapshot>>,
    },
    Transfers {
        reply: oneshot::Sender<Vec<(NodeId, cangate_canopen::sdo::Progress)>>,
    },
    ConfirmState {
        node: NodeId,
        /// Send NMT start first (the confirmation is in place before the
        /// node can answer it).
        start: bool,
        probe: bool,
        timeout: Duration,
        reply: oneshot::Sender<Option<NmtState>>,
    },
    Lss {
        command: cangate_canopen::lss::LssCommand,
        timeout: Duration,
        reply: oneshot::Sender<
            Result<cangate_canopen::lss::LssOutcome, cangate_canopen::lss::LssError>,
        >,
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
    /// An LSS command failed (timeout, refusal, protocol violation, bad
    /// argument).
    #[error(transparent)]
    Lss(#[from] cangate_canopen::lss::LssError),
    /// Another LSS operation runs on this bus (LSS is bus-global: one at a
    /// time).
    #[error(
        "bus {bus}: an LSS operation ({operation}) is already running; LSS is bus-global, one operation at a time"
    )]
    LssBusy {
        /// The bus.
        bus: String,
        /// The running operation.
        operation: &'static str,
    },
    /// No unconfigured device with this serial number answered a fastscan.
    #[error(
        "bus {bus}: no unconfigured device with serial number 0x{serial:08X} (fastscan found {found})"
    )]
    LssDeviceNotFound {
        /// The bus.
        bus: String,
        /// The serial asked for.
        serial: u32,
        /// What the scan found, for the message.
        found: String,
    },
    /// LSS would give a device a node-ID another device uses.
    #[error(
        "bus {bus}: node-ID {node} is in use: {why}; a second device with it would take \
         over its messages (give another id, or force it)"
    )]
    LssNodeIdInUse {
        /// The bus.
        bus: String,
        /// The node-ID asked for.
        node: u8,
        /// Who uses it.
        why: String,
    },
    /// The operation would disturb an enabled or moving axis.
    #[error(transparent)]
    AxisActive(#[from] drive_guard::AxisActive),
    /// The caller already has as many SDO requests queued or running with
    /// this node as one caller may.
    #[error(
        "{caller} already has {limit} SDO requests queued or running with node {node} (the limit per caller and node); wait for them to finish"
    )]
    CallerQueueFull {
        /// Who asked.
        caller: String,
        /// The node.
        node: u8,
        /// The limit.
        limit: usize,
    },
}

/// Why the SYNC producer's settings were not changed.
#[derive(Debug, thiserror::Error)]
pub enum SyncChangeError {
    /// This master has no SYNC thread (it could not start; logged).
    #[error("this bus's SYNC producer is not running (its thread could not start; see the log)")]
    NoProducer,
    /// A period or counter the producer cannot use.
    #[error(transparent)]
    Invalid(cangate_canopen::sync::SyncConfigError),
    /// A SYNC rider refuses the stop or the new period now.
    #[error("{0}")]
    Vetoed(String),
}

/// Why a TIME frame was not sent.
#[derive(Debug, thiserror::Error)]
pub enum TimeSendError {
    /// The host's clock is before 1984.
    #[error("the host's clock cannot be sent: {0}")]
    Clock(#[from] cangate_canopen::time_of_day::TimeOfDayError),
    /// The bus refused the frame.
    #[error(transparent)]
    Send(#[from] cangate_can::SendFailure),
}

/// Handle to the CANopen master of one bus.
#[derive(Clone)]
pub struct CanopenBus {
    bus: String,
    handle: BusHandle,
    pdos: broadcast::Sender<PdoUpdate>,
    commands: mpsc::Sender<Command>,
    events: broadcast::Sender<NodeEvent>,
    facts: Arc<RwLock<BTreeMap<NodeId, NodeFacts>>>,
    /// SYNCs sent and periods skipped by this master's SYNC thread.
    sync_counts: Arc<sync_thread::SyncCounts>,
    /// The SYNC thread's settings, changed at run time.
    sync_control: Arc<sync_thread::SyncControl>,
    /// The TIME producer's period (`None`: only on request).
    time_period: Arc<tokio::sync::watch::Sender<Option<Duration>>>,
    /// What the SYNC thread sends after each SYNC.
    sync_riders: sync_thread::SyncRiders,
    /// The COB-ID of the SYNC this master produces, if it produces one.
    sync_cob_id: Option<u16>,
    /// Every configured TPDO by COB-ID.
    tpdos: TpdoRoutes,
    /// The master task's subscription, widened or narrowed when a TPDO's
    /// COB-ID changes at run time.
    master_sub: cangate_can::SubscriptionKey,
    /// SDO requests of API callers in flight, by node and caller.
    client_sdo: Arc<Mutex<HashMap<(NodeId, String), usize>>>,
    /// The most of them per caller and node (0: no limit).
    client_sdo_limit: usize,
    /// The LSS operation running on this bus, if any (see [`lss`]).
    lss_operation: Arc<Mutex<Option<&'static str>>>,
    /// Nodes with a program download running.
    programs: program::Downloads,
    /// How requests and answers cross to the bus thread and back.
    handover: handover::Handover,
    /// The axes' drives on this bus and whether their axes are active.
    drive_guard: Arc<drive_guard::DriveGuard>,
    /// When each node-ID was last heard.
    heard: Arc<heard::HeardNodes>,
    /// The default SDO answer timeout.
    sdo_timeout: Duration,
}

/// One API caller's SDO request counted against
/// [`MAX_CLIENT_SDO_PER_NODE`] while it lives.
struct ClientSdoSlot {
    counts: Arc<Mutex<HashMap<(NodeId, String), usize>>>,
    key: (NodeId, String),
}

impl Drop for ClientSdoSlot {
    fn drop(&mut self) {
        let mut counts = self.counts.lock().expect("client SDO counts lock");
        if let Some(n) = counts.get_mut(&self.key) {
            *n -= 1;
            if *n == 0 {
                counts.remove(&self.key);
            }
        }
    }
}

/// Every decoded TPDO by COB-ID, changed when a PDO is reconfigured at run
/// time ([`CanopenBus::configure_pdo`]).
type TpdoRoutes = Arc<RwLock<HashMap<u16, TpdoRoute>>>;

/// A configured TPDO: how to decode it, and its receive counter.
struct TpdoRoute {
    node: NodeId,
    cfg: PdoConfig,
    eds: Option<Arc<Eds>>,
    count: AtomicU64,
    /// The last one received ([`CanopenBus::last_tpdo`]).
    last: Mutex<Option<cangate_can::Frame>>,
}

impl CanopenBus {
    /// Starts the master task of `bus`.
    pub fn spawn(
        bus: BusHandle,
        sdo_timeout: Duration,
        sync: sync_thread::SyncSettings,
        time_period: Option<Duration>,
        sync_thread: &sync_thread::SyncThread,
        configured: BTreeMap<NodeId, NodeFacts>,
        cancel: CancellationToken,
    ) -> (CanopenBus, tokio::task::JoinHandle<()>) {
        // The master's tasks log inside the bus's span.
        let span = tracing::info_span!("bus", bus = %bus.name());
        let _in_bus = span.enter();
        let (commands, rx) = mpsc::channel(1024);
        let (events, _) = broadcast::channel(4096);
        let (pdos, _) = broadcast::channel(16_384);
        let sync_counts = Arc::new(sync_thread::SyncCounts::default());
        let sync_riders = sync_thread::SyncRiders::default();
        let tpdos: HashMap<u16, TpdoRoute> = configured
            .iter()
            .flat_map(|(id, f)| {
                f.tpdos.iter().map(move |p| {
                    (
                        p.cob_id,
                        TpdoRoute {
                            node: *id,
                            cfg: p.clone(),
                            eds: f.eds.clone(),
                            count: AtomicU64::new(0),
                            last: Mutex::new(None),
                        },
                    )
                })
            })
            .collect();
        // Subscribe before returning, so that nothing the nodes send after
        // this point (their boot-up, typically) is missed.
        let sub = bus.subscribe(master_selector(&configured), 65_536);
        let known = configured.keys().map(|id| id.get()).collect();
        let heard = heard::spawn(&bus, &known, cancel.clone());
        // Nodes without a boot plan are identified, nothing more.
        let identify_only = Arc::new(BootPlan {
            identify_only: true,
            ..BootPlan::default()
        });
        let boots: Vec<(NodeId, Arc<BootPlan>)> = configured
            .iter()
            .map(|(id, f)| (*id, f.boot.clone().unwrap_or_else(|| identify_only.clone())))
            .collect();
        let facts = Arc::new(RwLock::new(configured));
        // The SYNC thread serves every master, stopped without a period,
        // so that the SYNC can be started at run time.
        let mut sync_cob_id = None;
        let sync_control = match sync_thread.add(
            bus.clone(),
            sync,
            sync_counts.clone(),
            sync_riders.clone(),
            cancel.clone(),
        ) {
            Ok(control) => {
                sync_cob_id = Some(cangate_canopen::ids::cob::SYNC);
                control
            }
            Err(e) => {
                tracing::error!(error = %e, "cannot start the SYNC producer thread");
                Arc::new(sync_thread::SyncControl::new(sync))
            }
        };
        let (time_period, time_rx) = tokio::sync::watch::channel(time_period);
        let time_period = Arc::new(time_period);
        tokio::spawn(time_producer::run(bus.clone(), time_rx, cancel.clone()).in_current_span());
        let handle = CanopenBus {
            bus: bus.name().to_string(),
            handle: bus.clone(),
            pdos: pdos.clone(),
            commands,
            events: events.clone(),
            facts: facts.clone(),
            sync_counts,
            sync_control,
            time_period,
            sync_riders,
            sync_cob_id,
            tpdos: Arc::new(RwLock::new(tpdos)),
            master_sub: sub.key(),
            client_sdo: Arc::default(),
            client_sdo_limit: MAX_CLIENT_SDO_PER_NODE,
            lss_operation: Arc::default(),
            programs: program::Downloads::default(),
            handover: handover::Handover::off(),
            drive_guard: Arc::default(),
            heard,
            sdo_timeout,
        };
        tokio::spawn(handle.handover.clone().keep_awake(cancel.clone()));
        let mut master = Master::new(sdo_timeout);
        for (id, f) in facts.read().expect("facts lock").iter() {
            if let Some(t) = f.heartbeat_timeout {
                master.monitor_heartbeat(*id, t);
            }
            if let Some((guard_time, factor)) = f.guarding {
                master.guard_node(*id, guard_time, factor);
            }
        }
        let boot_events = handle.events();
        let task = tokio::spawn(
            run_master(MasterTask {
                master,
                bus,
                sub,
                commands: rx,
                events,
                tpdos: handle.tpdos.clone(),
                pdos,
                facts,
                handover: handle.handover.clone(),
                heard: handle.heard.clone(),
                cancel: cancel.clone(),
            })
            .in_current_span(),
        );
        if !boots.is_empty() {
            tokio::spawn(
                run_boot_supervisor(handle.clone(), boot_events, boots, cancel).in_current_span(),
            );
        }
        (handle, task)
    }

    /// The SYNC producer's settings now.
    pub fn sync_settings(&self) -> sync_thread::SyncSettings {
        self.sync_control.get()
    }

    /// Starts, stops or re-times the SYNC producer. A stop or a change of
    /// period is refused while a SYNC rider vetoes it (a cyclic axis
    /// moving); a start, or a change of the counter alone while running,
    /// never is. Settings equal to the current ones change nothing.
    pub fn set_sync(
        &self,
        settings: sync_thread::SyncSettings,
    ) -> Result<sync_thread::SyncSettings, SyncChangeError> {
        if self.sync_cob_id.is_none() {
            return Err(SyncChangeError::NoProducer);
        }
        cangate_canopen::sync::SyncProducer::new(settings.period, settings.counter_overflow)
            .map_err(SyncChangeError::Invalid)?;
        let current = self.sync_control.get();
        if settings == current {
            return Ok(current);
        }
        let interrupts =
            current.running && (!settings.running || settings.period != current.period);
        if interrupts {
            let riders = self.sync_riders.lock().expect("SYNC riders lock");
            if let Some(why) = riders
                .iter()
                .filter_map(std::sync::Weak::upgrade)
                .find_map(|r| r.sync_change_veto())
            {
                return Err(SyncChangeError::Vetoed(why));
            }
        }
        self.sync_control.set(settings);
        tracing::info!(
            bus = %self.bus,
            running = settings.running,
            period_us = settings.period.as_micros() as u64,
            counter_overflow = settings.counter_overflow,
            "SYNC producer changed"
        );
        Ok(settings)
    }

    /// Sends one TIME frame with the host's time now; returns what it sent.
    pub async fn send_time(
        &self,
    ) -> Result<cangate_canopen::time_of_day::TimeOfDay, TimeSendError> {
        let t = time_producer::now()?;
        self.handle.submit(vec![t.frame()]).await?;
        Ok(t)
    }

    /// The TIME producer's period (`None`: only on request).
    pub fn time_period(&self) -> Option<Duration> {
        *self.time_period.borrow()
    }

    /// Sets the TIME producer's period (`None`: stop); the next TIME goes
    /// out one period from now.
    pub fn set_time_period(&self, period: Option<Duration>) {
        self.time_period.send_replace(period);
    }

    /// This master with `limit` SDO requests per API caller and node (0: no
    /// limit) instead of [`MAX_CLIENT_SDO_PER_NODE`].
    pub fn with_client_sdo_limit(mut self, limit: usize) -> CanopenBus {
        self.client_sdo_limit = limit;
        self
    }

    /// Callers off the bus thread poll up to `budget` for an SDO answer due
    /// that soon (see [`handover`]; 0: they sleep), on every clone of this
    /// master.
    pub fn set_handover_spin(&self, budget: Duration) {
        self.handover.set_budget(budget);
    }

    /// SYNCs sent so far, and SYNC periods without a SYNC because the SYNC
    /// thread was not scheduled in time or the bus's queue was full (both 0
    /// without a SYNC period).
    pub fn sync_counts(&self) -> (u64, u64) {
        (
            self.sync_counts.sent.load(Ordering::Relaxed),
            self.sync_counts.skipped.load(Ordering::Relaxed),
        )
    }

    /// The COB-ID of the SYNC this master produces (its SYNC thread
    /// runs), for tasks that follow the SYNC on the bus itself: with
    /// `transmitted` in their selector they see each SYNC as it goes out.
    pub fn sync_cob_id(&self) -> Option<u16> {
        self.sync_cob_id
    }

    /// Has `rider`'s frames sent right after every SYNC of this master, in
    /// the SYNC's batch, until `rider` is dropped. `false` (and nothing
    /// registered) when this master produces no SYNC.
    pub fn add_sync_rider(&self, rider: std::sync::Weak<dyn sync_thread::SyncRider>) -> bool {
        if self.sync_cob_id.is_none() {
            return false;
        }
        self.sync_riders
            .lock()
            .expect("SYNC riders lock")
            .push(rider);
        true
    }

    /// The bus this master runs on.
    pub fn bus_handle(&self) -> &BusHandle {
        &self.handle
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

    /// Runs one SDO transfer of the gateway's own (boot procedure, axis
    /// process data, device profiles): it goes before API callers'.
    pub async fn sdo(
        &self,
        node: NodeId,
        req: SdoRequest,
    ) -> Result<TransferOutcome, CanopenError> {
        self.run_sdo(node, SdoPriority::Gateway, req).await
    }

    /// Runs one SDO transfer for an API caller (`caller` names it: an
    /// identity or a peer address): after the gateway's own transfers, and
    /// refused when the caller already has its limit of requests with this
    /// node ([`CanopenBus::with_client_sdo_limit`]).
    pub async fn client_sdo(
        &self,
        node: NodeId,
        req: SdoRequest,
        caller: &str,
    ) -> Result<TransferOutcome, CanopenError> {
        let key = (node, caller.to_string());
        let _slot = {
            let mut counts = self.client_sdo.lock().expect("client SDO counts lock");
            let n = counts.entry(key.clone()).or_insert(0);
            if self.client_sdo_limit > 0 && *n >= self.client_sdo_limit {
                return Err(CanopenError::CallerQueueFull {
                    caller: caller.to_string(),
                    node: node.get(),
                    limit: self.client_sdo_limit,
                });
            }
            *n += 1;
            ClientSdoSlot {
                counts: self.client_sdo.clone(),
                key,
            }
        };
        self.run_sdo(node, SdoPriority::Client, req).await
    }

    async fn run_sdo(
        &self,
        node: NodeId,
        priority: SdoPriority,
        req: SdoRequest,
    ) -> Result<TransferOutcome, CanopenError> {
        let (reply, rx) = oneshot::channel();
        let started = Instant::now();
        let spins = self.handover.spins();
        self.commands
            .send(Command::Sdo {
                node,
                priority,
                req,
                reply,
                spins,
            })
            .await
            .map_err(|_| CanopenError::Stopped)?;
        let r = self
            .handover
            .reply(rx, spins)
            .await
            .ok_or(CanopenError::Stopped)?;
        let result = match &r {
            Ok(_) => "ok",
            Err(SdoError::Timeout { .. }) => "timeout",
            Err(SdoError::NotSent { .. }) => "not_sent",
            Err(SdoError::Aborted { .. }) => "aborted_by_node",
            Err(_) => "aborted",
        };
        let node_label = node.get().to_string();
        metrics::counter!("cangate_sdo_requests_total", "bus" => self.bus.clone(), "node" => node_label.clone(), "result" => result)
            .increment(1);
        metrics::histogram!("cangate_sdo_duration_seconds", "bus" => self.bus.clone(), "node" => node_label)
            .record(started.elapsed().as_secs_f64());
        Ok(r?)
    }

    /// Sends an NMT command for a client: refused (unless `force`) when
    /// it would take an active axis's drive out of operational — every
    /// command but START, to the drive or to all nodes.
    pub async fn client_nmt(
        &self,
        cmd: NmtCommand,
        target: Option<NodeId>,
        force: bool,
    ) -> Result<(), CanopenError> {
        if !force && cmd != NmtCommand::Start {
            let operation = format!("NMT {cmd:?}");
            match target {
                Some(node) => self.check_drive_idle(node, &operation)?,
                None => {
                    if let Some((node, _)) = self.drive_guard.active_drives().first() {
                        self.check_drive_idle(*node, &format!("{operation} to all nodes"))?;
                    }
                }
            }
        }
        self.nmt(cmd, target).await
    }

    /// Sends an NMT command. A node known only by what its boot procedure
    /// left it in ([`NodeFacts::boot_state`]) is then in the state
    /// commanded (after a reset: unknown until its boot-up).
    pub async fn nmt(&self, cmd: NmtCommand, target: Option<NodeId>) -> Result<(), CanopenError> {
        let (reply, rx) = oneshot::channel();
        self.commands
            .send(Command::Nmt { cmd, target, reply })
            .await
            .map_err(|_| CanopenError::Stopped)?;
        rx.await.map_err(|_| CanopenError::Stopped)??;
        let commanded = match cmd {
            NmtCommand::Start => Some(NmtState::Operational),
            NmtCommand::Stop => Some(NmtState::Stopped),
            NmtCommand::EnterPreOperational => Some(NmtState::PreOperational),
            NmtCommand::ResetNode | NmtCommand::ResetCommunication => None,
        };
        let mut facts = self.facts.write().expect("facts lock");
        for (id, f) in facts.iter_mut() {
            if f.boot_state.is_some() && target.is_none_or(|t| t == *id) {
                f.boot_state = commanded;
            }
        }
        Ok(())
    }

    /// Sends NMT start to `node` (when `start`) and returns the NMT state
    /// it reports from then on within `timeout` (see
    /// [`Master::confirm_state`]): operational as soon as it says so, else
    /// the last state it reported, `None` if nothing came. With `probe`,
    /// one node guarding request asks a node that sends no heartbeat.
    pub async fn confirm_state(
        &self,
        node: NodeId,
        start: bool,
        probe: bool,
        timeout: Duration,
    ) -> Result<Option<NmtState>, CanopenError> {
        let (reply, rx) = oneshot::channel();
        self.commands
            .send(Command::ConfirmState {
                node,
                start,
                probe,
                timeout,
                reply,
            })
            .await
            .map_err(|_| CanopenError::Stopped)?;
        rx.await.map_err(|_| CanopenError::Stopped)
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

    /// SDO transfers in progress.
    pub async fn transfers(
        &self,
    ) -> Result<Vec<(NodeId, cangate_canopen::sdo::Progress)>, CanopenError> {
        let (reply, rx) = oneshot::channel();
        self.commands
            .send(Command::Transfers { reply })
            .await
            .map_err(|_| CanopenError::Stopped)?;
        rx.await.map_err(|_| CanopenError::Stopped)
    }

    /// Subscribes to node events.
    pub fn events(&self) -> broadcast::Receiver<NodeEvent> {
        self.events.subscribe()
    }

    /// TPDOs received per configured TPDO: (node, PDO number, count).
    pub fn tpdo_counts(&self) -> Vec<(NodeId, u16, u64)> {
        let mut counts: Vec<_> = self
            .tpdos
            .read()
            .expect("TPDO routes lock")
            .values()
            .map(|r| (r.node, r.cfg.num, r.count.load(Ordering::Relaxed)))
            .collect();
        counts.sort_by_key(|(node, num, _)| (*node, *num));
        counts
    }

    /// Accounts for a received frame if it is a configured TPDO: counts it
    /// and, when someone listens ([`CanopenBus::pdos`]), decodes and
    /// publishes it. The master does this for the TPDOs it subscribes to;
    /// an axis task that reads its drives' TPDOs itself
    /// ([`NodeFacts::tpdos_read_by_axis`]) calls it for those. Building the
    /// update allocates, so nothing is built without a listener.
    pub fn relay_tpdo(&self, frame: &cangate_can::Frame) {
        relay_tpdo(&self.tpdos, &self.pdos, frame);
    }

    /// The last TPDO `num` received from `node` (counted and relayed as
    /// [`CanopenBus::relay_tpdo`] says), with its configuration; `None`
    /// when the node has no such TPDO configured, `Some((cfg, None))` when
    /// none was received yet.
    pub fn last_tpdo(
        &self,
        node: NodeId,
        num: u16,
    ) -> Option<(PdoConfig, Option<cangate_can::Frame>)> {
        let routes = self.tpdos.read().expect("TPDO routes lock");
        routes
            .values()
            .find(|r| r.node == node && r.cfg.num == num)
            .map(|r| {
                let last = *r.last.lock().unwrap_or_else(|p| p.into_inner());
                (r.cfg.clone(), last)
            })
    }

    /// Subscribes to decoded TPDOs.
    pub fn pdos(&self) -> broadcast::Receiver<PdoUpdate> {
        self.pdos.subscribe()
    }

    /// The TPDO configurations of a node.
    pub fn tpdos(&self, node: NodeId) -> Vec<PdoConfig> {
        self.facts
            .read()
            .expect("facts lock")
            .get(&node)
            .map(|f| f.tpdos.clone())
            .unwrap_or_default()
    }

    /// The RPDO configuration of a node.
    pub fn rpdo(&self, node: NodeId, num: u16) -> Option<PdoConfig> {
        self.facts
            .read()
            .expect("facts lock")
            .get(&node)
            .and_then(|f| f.rpdos.iter().find(|p| p.num == num).cloned())
    }

    /// 0x6502 supported drive modes of axis `drive_axis` of an axis
    /// drive, as its latest boot procedure read it.
    pub fn supported_drive_modes(&self, node: NodeId, drive_axis: u8) -> Option<u32> {
        self.facts
            .read()
            .expect("facts lock")
            .get(&node)
            .and_then(|f| {
                f.supported_drive_modes
                    .get(usize::from(drive_axis))
                    .copied()
                    .flatten()
            })
    }

    /// The RPDO configurations of a node.
    pub fn rpdos(&self, node: NodeId) -> Vec<PdoConfig> {
        self.facts
            .read()
            .expect("facts lock")
            .get(&node)
            .map(|f| f.rpdos.clone())
            .unwrap_or_default()
    }

    /// Sends frames (process data) in one batch, in order.
    pub async fn send_frames(&self, frames: Vec<cangate_can::Frame>) -> Result<(), CanopenError> {
        self.handle.submit(frames).await?;
        Ok(())
    }

    /// Sends an RPDO payload.
    pub async fn send_pdo(&self, cob_id: u16, data: &[u8]) -> Result<(), CanopenError> {
        let frame =
            cangate_can::Frame::new(cangate_can::CanId::Standard(cob_id), data).map_err(|e| {
                CanopenError::Send(cangate_can::SendFailure {
                    sent: 0,
                    total: 1,
                    error: cangate_can::SendError::Io {
                        bus: self.bus.clone(),
                        message: e.to_string(),
                    },
                })
            })?;
        self.handle.send(vec![frame]).await?;
        Ok(())
    }

    fn emit(&self, node: NodeId, kind: NodeEventKind) {
        let _ = self.events.send(NodeEvent {
            node,
            at: Timestamp::now(),
            kind,
        });
    }
}
