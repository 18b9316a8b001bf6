//! [`SimNode`]: a simulated CANopen (CiA 301) slave built from an EDS.
//!
//! The node serves its object dictionary ([`SimStore`]) over SDO, follows
//! NMT commands, produces heartbeats (0x1017), transmits TPDOs and applies
//! RPDOs according to the PDO parameters in its object dictionary, reacts
//! to SYNC and produces EMCY messages on request. It is a pure state
//! machine: frames and time in, frames and [`SimEvent`]s out.
//!
//! | service | behaviour |
//! |---|---|
//! | NMT | boot-up on [`SimNode::start`], then pre-operational (with [`SimNodeOptions::running_at_start`]: already in that state, no boot-up, as a device found running); start/stop/pre-operational (start ignored with [`SimNodeOptions::refuses_nmt_start`]); reset node restores every default, reset communication restores 0x1000..=0x1FFF; both boot up again |
//! | heartbeat | every 0x1017 ms in every state after boot-up, and at once on every NMT state change (the period restarting from it); writes to 0x1017 restart the producer at once |
//! | node guarding | (unless [`SimNodeOptions::node_guarding`] is off) a remote frame to 0x700+n is answered with `[toggle << 7 \| state]` in every state after boot-up; the toggle bit starts at 0 after every boot-up and alternates with each answer. Life guarding: with 0x100C (guard time, ms) and 0x100D (life time factor) set, from the first request on, no request within their product sends EMCY 0x8130 once and applies 0x1029:01 like a heartbeat loss; the next request sends the EMCY reset |
//! | heartbeat consumer | every 0x1016 entry (node id in bits 16..=23, time in ms in bits 0..=15) monitors that node, starting with its first heartbeat; when none arrives within the time: [`SimEvent::HeartbeatLost`], EMCY 0x8130 (heartbeat error, error register generic + communication) and the 0x1029:01 communication error behaviour when the dictionary has it (0 pre-operational if operational, 2 stopped, else no change); without 0x1029 the device application reacts (a drive faults); [`SimEvent::HeartbeatRecovered`] on the next heartbeat; writes to 0x1016 and resets restart monitoring |
//! | SDO | expedited, segmented and block (optional) on 0x600+n/0x580+n, in pre-operational and operational |
//! | TPDO | operational only; parameters 0x1800+n and mapping 0x1A00+n read when needed; 0xFE/0xFF event-driven (sent on entering operational, on the event timer 0x180x:05, on [`SimNode::trigger_tpdo`] and optionally when a mapped value changes, respecting the inhibit time 0x180x:03), 1..=240 every n-th SYNC, 0 on the SYNC after an event, RTR answered when allowed |
//! | RPDO | operational only; parameters 0x1400+n and mapping 0x1600+n; 0xFE/0xFF applied at once, 0..=240 at the next SYNC |
//! | SYNC | COB-ID from 0x1005 (0x080 when absent) |
//! | EMCY | COB-ID from 0x1014 (0x080+n when absent); sets 0x1001 |
//! | LSS (CiA 305) | with [`SimNodeOptions::lss`]: an [`LssSlave`] with that identity (also the defaults of 0x1018:01..=04) on 0x7E5/0x7E4. With [`SimNodeOptions::lss_unconfigured`] the node starts without a node-ID: no boot-up, no heartbeat, no SDO, nothing but LSS, until a node-ID is configured and applied (switching back to the LSS waiting state applies it at once; an NMT reset node or reset communication applies a pending id, reset node first reloading the stored one). A new id rebuilds the node at that id (the dictionary back to its defaults) and boots it up. Bit timings are accepted (CiA 301 table, see [`LssSlave`]) but activating one changes nothing: the virtual bus has one bit timing |
//! | program download (CiA 302-3) | 0x1F50/0x1F51/0x1F56/0x1F57 sub 1 whatever the EDS says, with a flash delay and injectable faults: see [`crate::program`] |

use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

use cangate_can::{CanId, Filter, Frame};
use cangate_canopen::eds::Eds;
use cangate_canopen::emcy::{ErrorRegister, emcy_frame};
use cangate_canopen::heartbeat::{HeartbeatConsumer, HeartbeatEvent};
use cangate_canopen::ids::cob;
use cangate_canopen::lss::{LSS_REQUEST_COB_ID, LssIdentity, UNCONFIGURED_NODE_ID};
use cangate_canopen::lss_slave::{LssSlave, LssSlaveEvent};
use cangate_canopen::nmt::{NmtCommand, NmtReset, NmtSlave, NmtSlaveEvent, NmtState};
use cangate_canopen::od::ObjectDictionary;
use cangate_canopen::program_download::PROGRAM_DATA;
use cangate_canopen::sdo::{AbortCode, ObjectStore, SdoServer, ServerOptions};
use cangate_canopen::value::Value;
use cangate_canopen::{NodeId, ObjectAddress};

use crate::pdo::{self, Dir, MAX_PDOS, MapEntry, PdoComm, PdoParam, RPDO_COMM, TPDO_COMM};
use crate::program::{ProgramEffect, ProgramFaults, ProgramOptions, SimProgram};
use crate::store::SimStore;
use crate::{Device, SimError};

/// Error register.
const ERROR_REGISTER: ObjectAddress = ObjectAddress::new(0x1001, 0);
/// COB-ID SYNC.
const COB_ID_SYNC: u16 = 0x1005;
/// COB-ID EMCY.
const COB_ID_EMCY: u16 = 0x1014;
/// Producer heartbeat time.
const HEARTBEAT_TIME: ObjectAddress = ObjectAddress::new(0x1017, 0);
/// Consumer heartbeat time (array).
const CONSUMER_HEARTBEAT: u16 = 0x1016;
/// Error behaviour, sub 1: communication error.
const COMMUNICATION_ERROR_BEHAVIOUR: ObjectAddress = ObjectAddress::new(0x1029, 1);
/// Guard time in ms (life guarding).
const GUARD_TIME: ObjectAddress = ObjectAddress::new(0x100C, 0);
/// Life time factor (life guarding).
const LIFE_TIME_FACTOR: ObjectAddress = ObjectAddress::new(0x100D, 0);
/// EMCY code of a heartbeat consumer timeout (CiA 301 "heartbeat error").
pub const HEARTBEAT_ERROR_CODE: u16 = 0x8130;

/// How a [`SimNode`] behaves beyond what its EDS says.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SimNodeOptions {
    /// Serve SDO block transfers; without, block initiates are aborted with
    /// 0x05040001 as servers without block support do.
    pub block_transfer: bool,
    /// Segments per block offered for block downloads (1..=127).
    pub block_size: u8,
    /// Announce CRC support in block transfers.
    pub crc: bool,
    /// How long the SDO server waits for the client inside a transfer.
    pub sdo_timeout: Duration,
    /// Heartbeat producer time in ms replacing the EDS default of 0x1017
    /// (also what resets restore); `None` keeps the EDS value.
    pub heartbeat_ms: Option<u16>,
    /// Enforce the CiA 301 procedure for changing PDO parameters over SDO
    /// (invalidate the PDO before changing its COB-ID or mapping, mapping
    /// sub 0 = 0 while writing entries, entries must be mappable, at most 8
    /// bytes). When false, any value is accepted and a PDO whose mapping is
    /// unusable is simply not sent or applied.
    pub strict_pdo_config: bool,
    /// Treat a change of a value mapped into an event-driven (or type 0)
    /// TPDO as an event that transmits it (subject to the inhibit time).
    /// Off by default: a device model updating its position every
    /// millisecond would otherwise flood the bus unless an inhibit time is
    /// configured.
    pub tpdo_on_change: bool,
    /// Capacity of the event queue ([`SimNode::take_events`]); the oldest
    /// events are dropped beyond it.
    pub max_events: usize,
    /// Serve LSS (CiA 305) with this identity; it also becomes the default
    /// of 0x1018:01..=04 where the dictionary has them.
    pub lss: Option<LssIdentity>,
    /// With [`SimNodeOptions::lss`]: start without a node-ID (255), silent
    /// but for LSS, until one is configured.
    pub lss_unconfigured: bool,
    /// With [`SimNodeOptions::lss`]: answer fastscan in any LSS state while
    /// without a node-ID, as CANopenNode's LSS slave does
    /// ([`LssSlave::answering_fastscan_until_configured`]).
    pub lss_fastscan_until_configured: bool,
    /// The simulated flash of program download (CiA 302-3).
    pub program: ProgramOptions,
    /// The node was powered on before anyone listened: the first
    /// [`SimNode::start`] enters this state (pre-operational, operational
    /// or stopped) at once, heartbeat running, without a boot-up message,
    /// as a device found running by a (re)started master. Resets and power
    /// cycles boot as usual.
    pub running_at_start: Option<NmtState>,
    /// NMT start commands are ignored: the node stays where it is (a
    /// device whose application refuses to go operational).
    pub refuses_nmt_start: bool,
    /// Answer node guarding requests (remote frames to 0x700+n); without,
    /// they are ignored, as by stacks built without node guarding.
    pub node_guarding: bool,
}

impl Default for SimNodeOptions {
    fn default() -> Self {
        SimNodeOptions {
            block_transfer: true,
            block_size: 127,
            crc: true,
            sdo_timeout: Duration::from_secs(1),
            heartbeat_ms: None,
            strict_pdo_config: true,
            tpdo_on_change: false,
            max_events: 1024,
            lss: None,
            lss_unconfigured: false,
            lss_fastscan_until_configured: false,
            program: ProgramOptions::default(),
            running_at_start: None,
            refuses_nmt_start: false,
            node_guarding: true,
        }
    }
}

/// Something that happened to a [`SimNode`], for the device application.
#[derive(Debug, Clone, PartialEq)]
pub enum SimEvent {
    /// The NMT state changed (also reported for the boot-up after
    /// [`SimNode::start`] and after resets, from the state before).
    NmtStateChanged {
        /// The previous state.
        from: NmtState,
        /// The new state.
        to: NmtState,
    },
    /// An NMT reset was applied; the node has booted again.
    Reset {
        /// Which reset.
        kind: NmtReset,
    },
    /// An SDO download wrote an object.
    SdoWritten {
        /// The object.
        addr: ObjectAddress,
    },
    /// An RPDO was applied to the object dictionary.
    RpdoReceived {
        /// The RPDO number (1 = RPDO1, communication parameter 0x1400).
        pdo: u16,
        /// The objects written, in mapping order (dummy entries left out).
        objects: Vec<(ObjectAddress, Value)>,
    },
    /// An RPDO frame was shorter than its mapping and was not applied.
    RpdoLengthError {
        /// The RPDO number (1-based).
        pdo: u16,
        /// Mapped bytes.
        expected: usize,
        /// Bytes received.
        got: usize,
    },
    /// A SYNC was received (pre-operational or operational).
    Sync {
        /// The SYNC counter, if the frame carried one.
        counter: Option<u8>,
    },
    /// A node monitored by 0x1016 sent no heartbeat within its consumer
    /// time (reported once per loss; the node sent EMCY 0x8130).
    HeartbeatLost {
        /// The silent node.
        node: NodeId,
        /// Its consumer time.
        timeout: Duration,
    },
    /// A lost node's heartbeat came back.
    HeartbeatRecovered {
        /// The node.
        node: NodeId,
    },
    /// Life guarding: no node guarding request from the master within the
    /// node life time (0x100C × 0x100D); the node sent EMCY 0x8130.
    LifeGuardingLost {
        /// The node life time.
        life_time: Duration,
    },
    /// A guarding request came after a life guarding event; the node sent
    /// the EMCY error reset.
    LifeGuardingRecovered,
}

/// Transmission state of one TPDO.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct TpdoState {
    /// An event waits for transmission (entering operational, trigger,
    /// change of a mapped value).
    pending: bool,
    /// When the event timer elapses.
    timer: Option<Duration>,
    /// No event-driven transmission before this.
    inhibit_until: Duration,
    /// SYNCs counted towards the transmission type.
    syncs: u8,
}

/// The object store as the SDO server sees it: the store's checks plus,
/// optionally, the PDO configuration rules; remembers what was written.
struct SdoAccess<'a> {
    store: &'a mut SimStore,
    strict: bool,
    written: &'a mut Vec<(ObjectAddress, bool)>,
    program: &'a mut SimProgram,
    effect: &'a mut ProgramEffect,
    now: Duration,
}

impl ObjectStore for SdoAccess<'_> {
    fn read(&mut self, addr: ObjectAddress) -> Result<Vec<u8>, AbortCode> {
        if SimProgram::serves(addr) {
            return self.program.read(addr, self.now);
        }
        self.store.read(addr)
    }

    fn write(&mut self, addr: ObjectAddress, data: &[u8]) -> Result<(), AbortCode> {
        if SimProgram::serves(addr) {
            let effect = self.program.write(addr, data, self.now)?;
            if effect != ProgramEffect::None {
                *self.effect = effect;
            }
            self.written.push((addr, true));
            return Ok(());
        }
        let value = self.store.decode_write(addr, data)?;
        if self.strict {
            pdo::check_config_write(self.store, addr, &value)?;
        }
        let changed = self.store.put(addr, value);
        self.written.push((addr, changed));
        Ok(())
    }
}

/// A simulated CANopen slave. See the [module documentation](self).
#[derive(Debug)]
pub struct SimNode {
    node: NodeId,
    options: SimNodeOptions,
    store: SimStore,
    nmt: NmtSlave,
    sdo: SdoServer,
    /// By 0-based TPDO number, for every 0x1800+n in the dictionary.
    tpdos: BTreeMap<u16, TpdoState>,
    /// By 0-based RPDO number, for every 0x1400+n in the dictionary: data
    /// of a synchronous RPDO waiting for the next SYNC.
    rpdos: BTreeMap<u16, Option<Vec<u8>>>,
    events: VecDeque<SimEvent>,
    dropped_events: u64,
    /// Monitors the nodes of 0x1016.
    consumer: HeartbeatConsumer,
    /// The latest time seen.
    now: Duration,
    /// Bumped by every dictionary write and reset, which may change
    /// [`SimNode::receive_filters`].
    filter_generation: u64,
    /// The toggle bit of the next node guarding answer.
    guard_toggle: bool,
    /// The LSS slave, with [`SimNodeOptions::lss`].
    lss: Option<LssSlave>,
    /// False while the node has no node-ID (LSS only).
    configured: bool,
    /// Life guarding: the latest guarding request (life guarding starts
    /// with the first one after boot-up), and whether its loss was
    /// reported.
    last_guarded: Option<Duration>,
    life_guarding_lost: bool,
    /// Program download (CiA 302-3).
    program: SimProgram,
}

impl SimNode {
    /// A node with the object dictionary of `eds` (defaults resolved for
    /// `node`), not yet started: call [`SimNode::start`].
    pub fn new(eds: &Eds, node: NodeId, options: SimNodeOptions) -> Self {
        Self::from_od(eds.od_with_dummies(), node, options)
    }

    /// A node from EDS/DCF text.
    pub fn from_eds_text(
        text: &str,
        node: NodeId,
        options: SimNodeOptions,
    ) -> Result<Self, SimError> {
        Ok(Self::from_od(
            Eds::parse(text)?.od_with_dummies(),
            node,
            options,
        ))
    }

    /// A node serving `od`.
    pub fn from_od(od: ObjectDictionary, node: NodeId, options: SimNodeOptions) -> Self {
        let mut store = SimStore::new(od, node);
        if let Some(ms) = options.heartbeat_ms {
            // Only fails when the EDS has no UNSIGNED16 0x1017; the
            // producer then runs from the option alone.
            let _ = store.set_default(HEARTBEAT_TIME, Value::Unsigned16(ms));
        }
        let present = |base: u16| -> Vec<u16> {
            (0..MAX_PDOS)
                .filter(|n| store.od().object(base + n).is_some())
                .collect()
        };
        let tpdos = present(TPDO_COMM)
            .into_iter()
            .map(|n| (n, TpdoState::default()))
            .collect();
        let rpdos = present(RPDO_COMM).into_iter().map(|n| (n, None)).collect();
        if let Some(id) = options.lss {
            for (sub, v) in (1u8..).zip(id.parts()) {
                // Only where the dictionary has the entry as UNSIGNED32.
                let _ = store.set_default(ObjectAddress::new(0x1018, sub), Value::Unsigned32(v));
            }
        }
        let lss = options.lss.map(|id| {
            let stored = if options.lss_unconfigured {
                UNCONFIGURED_NODE_ID
            } else {
                node.get()
            };
            let slave = LssSlave::new(id, stored);
            if options.lss_fastscan_until_configured {
                slave.answering_fastscan_until_configured()
            } else {
                slave
            }
        });
        let configured = lss.is_none() || !options.lss_unconfigured;
        let consumer = consumer_from(&store);
        let program = options.program;
        SimNode {
            lss,
            configured,
            consumer,
            node,
            sdo: SdoServer::new(node, Self::server_options(&options)),
            nmt: NmtSlave::new(node, heartbeat_ms(&store, &options)),
            options,
            store,
            tpdos,
            rpdos,
            filter_generation: 0,
            events: VecDeque::new(),
            dropped_events: 0,
            now: Duration::ZERO,
            guard_toggle: false,
            last_guarded: None,
            life_guarding_lost: false,
            program: SimProgram::new(program),
        }
    }

    fn server_options(options: &SimNodeOptions) -> ServerOptions {
        ServerOptions {
            block_transfer: options.block_transfer,
            block_size: options.block_size,
            crc: options.crc,
            timeout: options.sdo_timeout,
        }
    }

    /// The node id (while [`SimNode::is_configured`] is false, the id the
    /// node was created with, not in use).
    pub fn node_id(&self) -> NodeId {
        self.node
    }

    /// False while the node has no node-ID (LSS unconfigured).
    pub fn is_configured(&self) -> bool {
        self.configured
    }

    /// The LSS slave, if the node serves LSS.
    pub fn lss(&self) -> Option<&LssSlave> {
        self.lss.as_ref()
    }

    /// Handles an LSS request (0x7E5).
    fn on_lss(&mut self, frame: &Frame, now: Duration) -> Vec<Frame> {
        let Some(lss) = self.lss.as_mut() else {
            return Vec::new();
        };
        let (answer, events) = lss.on_frame(frame);
        let mut out: Vec<Frame> = answer.into_iter().collect();
        for ev in events {
            if let LssSlaveEvent::ApplyNodeId(id) = ev {
                out.extend(self.become_node(id, now));
            }
        }
        out
    }

    /// An NMT reset addressed to this LSS node: applies the pending (reset
    /// communication) or stored (reset node) node-ID when it differs from
    /// the one in use. `None`: nothing changed, handle the reset as usual.
    fn lss_reset(&mut self, frame: &Frame, now: Duration) -> Option<Vec<Frame>> {
        let lss = self.lss.as_mut()?;
        let (cmd, target) = cangate_canopen::nmt::parse_nmt(frame)?;
        let reset_node = match cmd {
            NmtCommand::ResetNode => true,
            NmtCommand::ResetCommunication => false,
            _ => return None,
        };
        if !self.configured || target.is_some_and(|t| t != self.node) {
            return None;
        }
        let active = lss.on_reset(reset_node);
        (active != self.node.get()).then(|| self.become_node(active, now))
    }

    /// Rebuilds the node at node-ID `id` (255: unconfigured, silent) and
    /// boots it up.
    fn become_node(&mut self, id: u8, now: Duration) -> Vec<Frame> {
        let node = NodeId::new(u32::from(id)).ok();
        let mut fresh = SimNode::from_od(
            self.store.od().clone(),
            node.unwrap_or(self.node),
            self.options.clone(),
        );
        fresh.lss = self.lss.take();
        fresh.configured = node.is_some();
        fresh.events = std::mem::take(&mut self.events);
        fresh.dropped_events = self.dropped_events;
        fresh.filter_generation = self.filter_generation + 1;
        *self = fresh;
        if self.configured {
            self.start(now)
        } else {
            Vec::new()
        }
    }

    /// The options in force.
    pub fn options(&self) -> &SimNodeOptions {
        &self.options
    }

    /// The NMT state ([`NmtState::Initialising`] until started).
    pub fn nmt_state(&self) -> NmtState {
        self.nmt.state()
    }

    /// The heartbeat producer period, `None` when off.
    pub fn heartbeat_period(&self) -> Option<Duration> {
        self.nmt.heartbeat_period()
    }

    /// The object dictionary structure.
    pub fn od(&self) -> &ObjectDictionary {
        self.store.od()
    }

    /// The object values.
    pub fn store(&self) -> &SimStore {
        &self.store
    }

    /// The current value of an object.
    pub fn get(&self, addr: ObjectAddress) -> Option<&Value> {
        self.store.get(addr)
    }

    /// Sets an object locally, as the device application does (e.g. a
    /// drive model updating 0x6041 statusword or 0x6064 position): the type
    /// must match; access rights and limits are not checked. Side effects
    /// apply as for a write over SDO (0x1017 restarts the heartbeat, PDO
    /// parameters reconfigure the PDO), timed at the latest `now` the node
    /// has seen.
    pub fn set(&mut self, addr: ObjectAddress, value: Value) -> Result<(), SimError> {
        let changed = self.store.set(addr, value)?;
        self.after_write(addr, changed, self.now);
        Ok(())
    }

    /// Takes the events that happened since the last call, oldest first.
    pub fn take_events(&mut self) -> Vec<SimEvent> {
        self.events.drain(..).collect()
    }

    /// Events dropped because the queue was full.
    pub fn dropped_events(&self) -> u64 {
        self.dropped_events
    }

    /// Powers the node on: returns the boot-up frame (0x700+n `[00]`) and
    /// enters pre-operational. Does nothing (returns no frame) if already
    /// started.
    pub fn start(&mut self, now: Duration) -> Vec<Frame> {
        self.now = now;
        if self.nmt.state() != NmtState::Initialising || !self.configured {
            return Vec::new();
        }
        let boot_up = self.nmt.boot(now);
        self.guard_toggle = false;
        self.last_guarded = None;
        self.life_guarding_lost = false;
        self.push_event(SimEvent::NmtStateChanged {
            from: NmtState::Initialising,
            to: NmtState::PreOperational,
        });
        let running = self.options.running_at_start.take();
        let command = match running {
            Some(NmtState::Operational) => Some(NmtCommand::Start),
            Some(NmtState::Stopped) => Some(NmtCommand::Stop),
            _ => None,
        };
        if let Some(cmd) = command {
            let mut out = Vec::new();
            if let Some(event) = self.nmt.on_command(cmd, now) {
                self.on_nmt(NmtState::PreOperational, event, now, &mut out);
            }
        }
        if running.is_some() {
            // It booted long ago: its boot-up went unheard.
            return Vec::new();
        }
        vec![boot_up]
    }

    /// Changes whenever [`SimNode::receive_filters`] may have changed (a
    /// dictionary write, a reset), so a runner asks only then.
    pub fn filter_generation(&self) -> u64 {
        self.filter_generation
    }

    /// The identifiers this node acts on, as acceptance filters: NMT, its
    /// SYNC (0x1005), its SDO requests (0x600+n), the COB-IDs of its valid
    /// RPDOs and, for remote requests, of its valid TPDOs. Frames outside
    /// them change nothing in [`SimNode::on_frame`]. They follow the
    /// dictionary (see [`SimNode::filter_generation`]).
    pub fn receive_filters(&self) -> Vec<Filter> {
        let sync = pdo::CobId::decode(self.store.u32_at(COB_ID_SYNC, 0).unwrap_or(0x80)).id;
        let store = &self.store;
        let rpdos = self
            .rpdos
            .keys()
            .filter_map(|&n| pdo::comm(store, Dir::Rx, n));
        let tpdos = self
            .tpdos
            .keys()
            .filter_map(|&n| pdo::comm(store, Dir::Tx, n));
        let consumed = self
            .consumer
            .nodes()
            .filter(|(_, st)| st.timeout.is_some())
            .map(|(n, _)| cob::HEARTBEAT + u16::from(n.get()));
        if !self.configured {
            return vec![Filter::exact_standard(LSS_REQUEST_COB_ID)];
        }
        let lss = self.lss.is_some().then_some(LSS_REQUEST_COB_ID);
        let mut filters: Vec<Filter> = [
            cob::NMT,
            cob::SDO_RX + u16::from(self.node.get()),
            // Node guarding requests.
            cob::HEARTBEAT + u16::from(self.node.get()),
        ]
        .into_iter()
        .chain(lss)
        .chain(consumed)
        .map(Filter::exact_standard)
        .chain(
            std::iter::once(sync)
                .chain(rpdos.chain(tpdos).map(|c| c.id))
                .map(|id| match id {
                    CanId::Standard(_) => Filter {
                        id: id.raw(),
                        mask: 0x7FF,
                        extended: Some(false),
                        inverted: false,
                    },
                    // A PDO may have been given an extended COB-ID.
                    CanId::Extended(_) => Filter {
                        id: id.raw(),
                        mask: 0x1FFF_FFFF,
                        extended: Some(true),
                        inverted: false,
                    },
                }),
        )
        .collect();
        filters.sort_by_key(|f| (f.extended, f.id));
        filters.dedup();
        filters
    }

    /// Handles a frame received at `now`; returns the frames to send.
    pub fn on_frame(&mut self, frame: &Frame, now: Duration) -> Vec<Frame> {
        self.now = now;
        let mut out = Vec::new();
        if frame.is_error() {
            return out;
        }
        if !frame.is_extended() && frame.raw_id() == u32::from(LSS_REQUEST_COB_ID) {
            return self.on_lss(frame, now);
        }
        if !self.configured {
            return out;
        }
        if let Some(frames) = self.lss_reset(frame, now) {
            return frames;
        }
        let before = self.nmt.state();
        if self.options.refuses_nmt_start
            && matches!(
                cangate_canopen::nmt::parse_nmt(frame),
                Some((NmtCommand::Start, target)) if target.is_none_or(|n| n == self.node)
            )
        {
            return out;
        }
        if let Some(event) = self.nmt.on_frame(frame, now) {
            self.on_nmt(before, event, now, &mut out);
            self.service_tpdos(now, &mut out);
            return out;
        }
        let state = self.nmt.state();
        if state == NmtState::Initialising {
            return out;
        }
        if let Some(node) = heartbeat_sender(frame) {
            if node == self.node && frame.is_remote() {
                if !self.options.node_guarding {
                    return out;
                }
                // Node guarding: answer with the toggle bit and the state.
                let toggle = if self.guard_toggle { 0x80 } else { 0x00 };
                self.guard_toggle = !self.guard_toggle;
                self.last_guarded = Some(now);
                if std::mem::take(&mut self.life_guarding_lost) {
                    self.push_event(SimEvent::LifeGuardingRecovered);
                    out.extend(self.clear_emcy());
                }
                out.push(
                    Frame::new(
                        CanId::Standard(cob::HEARTBEAT + u16::from(self.node.get())),
                        &[toggle | state.to_byte()],
                    )
                    .expect("a one-byte frame"),
                );
                return out;
            }
            if self
                .consumer
                .status(node)
                .is_some_and(|s| s.timeout.is_some())
            {
                let events = self.consumer.on_frame(frame, now);
                self.on_consumer_events(events, now, &mut out);
            }
            return out;
        }
        if self.is_sync(frame) {
            self.on_sync(frame, now, &mut out);
            return out;
        }
        if state != NmtState::Stopped {
            self.on_sdo(frame, now, &mut out);
        }
        if state == NmtState::Operational {
            if frame.is_remote() {
                self.on_tpdo_request(frame, now, &mut out);
            } else {
                self.on_rpdo(frame, now);
            }
        }
        self.service_tpdos(now, &mut out);
        out
    }

    /// Runs what is due at `now` (heartbeat, SDO timeout, event-driven
    /// TPDOs); returns the frames to send.
    pub fn on_tick(&mut self, now: Duration) -> Vec<Frame> {
        self.now = now;
        let mut out = Vec::new();
        if !self.configured {
            return out;
        }
        out.extend(self.nmt.on_tick(now));
        out.extend(self.sdo.on_tick(now));
        // Ends a finished flashing (its deadline passes).
        let _ = self.program.flash_status(now);
        if self.nmt.state() != NmtState::Initialising {
            let events = self.consumer.on_tick(now);
            self.on_consumer_events(events, now, &mut out);
            self.life_guard(now, &mut out);
        }
        self.service_tpdos(now, &mut out);
        out
    }

    /// The node life time (0x100C guard time × 0x100D life time factor),
    /// when both are set.
    fn life_time(&self) -> Option<Duration> {
        let guard_ms = self.get(GUARD_TIME).and_then(Value::as_u32)?;
        let factor = self.get(LIFE_TIME_FACTOR).and_then(Value::as_u32)?;
        (guard_ms > 0 && factor > 0)
            .then(|| Duration::from_millis(u64::from(guard_ms) * u64::from(factor)))
    }

    /// When life guarding reports a loss, if it is watching.
    fn life_guard_deadline(&self) -> Option<Duration> {
        if self.life_guarding_lost {
            return None;
        }
        Some(self.last_guarded? + self.life_time()?)
    }

    /// Life guarding (CiA 301): the master's guarding requests stopped for
    /// the node life time: EMCY 0x8130 (life guard error), once, and the
    /// communication error behaviour (0x1029:01) as for a heartbeat loss.
    fn life_guard(&mut self, now: Duration, out: &mut Vec<Frame>) {
        let Some(deadline) = self.life_guard_deadline() else {
            return;
        };
        if now < deadline {
            return;
        }
        self.life_guarding_lost = true;
        let life_time = self.life_time().unwrap_or_default();
        self.push_event(SimEvent::LifeGuardingLost { life_time });
        out.extend(self.inject_emcy(
            HEARTBEAT_ERROR_CODE,
            ErrorRegister::GENERIC | ErrorRegister::COMMUNICATION,
            [0; 5],
        ));
        self.communication_error(now, out);
    }

    /// When [`SimNode::on_tick`] must run next; `None` when nothing is
    /// scheduled.
    pub fn next_deadline(&self) -> Option<Duration> {
        if !self.configured {
            return None;
        }
        let tpdos = self
            .tpdos
            .iter()
            .filter_map(|(&n, st)| self.tpdo_due(n, st));
        let running = self.nmt.state() != NmtState::Initialising;
        let consumer = running.then(|| self.consumer.next_deadline()).flatten();
        let life_guard = running.then(|| self.life_guard_deadline()).flatten();
        [
            self.nmt.next_deadline(),
            self.sdo.next_deadline(),
            consumer,
            life_guard,
            self.program.next_deadline(),
        ]
        .into_iter()
        .flatten()
        .chain(tpdos)
        .min()
    }

    /// Produces an emergency message: sets the error register (0x1001) to
    /// `register` and returns the EMCY frame `[code lo, code hi, register,
    /// manufacturer…]` on the COB-ID of 0x1014 (0x080+n when absent).
    ///
    /// Returns `None` (after still setting 0x1001) when EMCY may not be
    /// sent: before start-up, in the stopped state, or with the EMCY COB-ID
    /// marked invalid (bit 31).
    pub fn inject_emcy(&mut self, code: u16, register: u8, manufacturer: [u8; 5]) -> Option<Frame> {
        self.set_error_register(register);
        self.emcy(code, register, manufacturer)
    }

    /// Clears the error state: sets 0x1001 to 0 and returns the "error
    /// reset" EMCY (code 0x0000, all bytes zero); `None` as for
    /// [`SimNode::inject_emcy`].
    pub fn clear_emcy(&mut self) -> Option<Frame> {
        self.set_error_register(0);
        self.emcy(0, 0, [0; 5])
    }

    /// Requests transmission of TPDO `pdo` (1-based) as an application
    /// event: an event-driven TPDO is sent at the next tick (after its
    /// inhibit time), a type 0 TPDO at the next SYNC. Returns false if the
    /// node has no such TPDO.
    pub fn trigger_tpdo(&mut self, pdo: u16) -> bool {
        let Some(st) = pdo.checked_sub(1).and_then(|n| self.tpdos.get_mut(&n)) else {
            return false;
        };
        st.pending = true;
        true
    }

    // ---- NMT ----

    fn on_nmt(
        &mut self,
        before: NmtState,
        event: NmtSlaveEvent,
        now: Duration,
        out: &mut Vec<Frame>,
    ) {
        match event {
            NmtSlaveEvent::StateChanged { from, to } => {
                self.push_event(SimEvent::NmtStateChanged { from, to });
                if self.nmt.heartbeat_period().is_some() {
                    // The new state is told at once, the next heartbeat a
                    // period later (as CANopenNode does): a master that
                    // started the node need not wait a period to know.
                    out.push(cangate_canopen::nmt::heartbeat_frame(self.node, to));
                    self.nmt.set_heartbeat_ms(self.heartbeat_ms(), now);
                }
                if to == NmtState::Operational || from == NmtState::Operational {
                    self.reset_pdos(to == NmtState::Operational);
                }
                if to == NmtState::Stopped {
                    // SDO is not available while stopped: drop any transfer.
                    self.sdo = SdoServer::new(self.node, Self::server_options(&self.options));
                }
            }
            NmtSlaveEvent::Reset { kind, boot_up } => {
                self.filter_generation += 1;
                match kind {
                    NmtReset::Node => self.store.restore_defaults(),
                    NmtReset::Communication => self.store.restore_range(0x1000..=0x1FFF),
                }
                self.sdo = SdoServer::new(self.node, Self::server_options(&self.options));
                self.reset_pdos(false);
                self.nmt.set_heartbeat_ms(self.heartbeat_ms(), now);
                self.consumer = consumer_from(&self.store);
                self.guard_toggle = false;
                self.last_guarded = None;
                self.life_guarding_lost = false;
                out.push(boot_up);
                self.push_event(SimEvent::Reset { kind });
                if before != NmtState::PreOperational {
                    self.push_event(SimEvent::NmtStateChanged {
                        from: before,
                        to: NmtState::PreOperational,
                    });
                }
            }
        }
    }

    fn heartbeat_ms(&self) -> u16 {
        heartbeat_ms(&self.store, &self.options)
    }

    // ---- SDO and side effects of writes ----

    fn on_sdo(&mut self, frame: &Frame, now: Duration, out: &mut Vec<Frame>) {
        if self.program_gate(frame, now, out) {
            return;
        }
        let mut written = Vec::new();
        let mut effect = ProgramEffect::None;
        let mut access = SdoAccess {
            store: &mut self.store,
            strict: self.options.strict_pdo_config,
            written: &mut written,
            program: &mut self.program,
            effect: &mut effect,
            now,
        };
        out.extend(self.sdo.on_frame(frame, now, &mut access));
        for (addr, changed) in written {
            self.push_event(SimEvent::SdoWritten { addr });
            self.after_write(addr, changed, now);
        }
        if effect == ProgramEffect::Reset {
            // The start was confirmed above; now the node resets into the
            // program.
            let before = self.nmt.state();
            if let Some(event) = self.nmt.on_command(NmtCommand::ResetNode, now) {
                self.on_nmt(before, event, now, out);
            }
        }
    }

    /// Program download checks before the SDO server sees `frame`: a
    /// download of 0x1F50 refused at its initiate (program running,
    /// flashing), and the injected abort during the data download. True
    /// when the frame was handled here.
    fn program_gate(&mut self, frame: &Frame, now: Duration, out: &mut Vec<Frame>) -> bool {
        let request = cob::SDO_RX + u16::from(self.node.get());
        if frame.id() != CanId::Standard(request) || frame.is_remote() || frame.data().is_empty() {
            return false;
        }
        let mut p = [0u8; 8];
        let n = frame.data().len().min(8);
        p[..n].copy_from_slice(&frame.data()[..n]);
        let addr = ObjectAddress::new(u16::from_le_bytes([p[1], p[2]]), p[3]);
        let response = cob::SDO_TX + u16::from(self.node.get());
        let abort = |addr: ObjectAddress, code: AbortCode| {
            let [lo, hi] = addr.index.to_le_bytes();
            let c = code.get().to_le_bytes();
            Frame::new(
                CanId::Standard(response),
                &[0x80, lo, hi, addr.sub, c[0], c[1], c[2], c[3]],
            )
            .expect("an 8-byte frame")
        };
        let initiate_download = p[0] & 0xE0 == 0x20;
        let initiate_block_download = p[0] & 0xE0 == 0xC0 && p[0] & 0x01 == 0;
        let idle = self.sdo.active_transfer().is_none();
        if idle && (initiate_download || initiate_block_download) && addr.index == PROGRAM_DATA {
            if let Err(code) = self.program.check_download_start(addr.sub, now) {
                out.push(abort(addr, code));
                return true;
            }
            return false;
        }
        if let Some(active) = self.sdo.active_transfer()
            && active.index == PROGRAM_DATA
            && p[0] != 0x80
            && let Some(code) = self.program.on_data(7)
        {
            out.push(abort(active, code));
            self.sdo = SdoServer::new(self.node, Self::server_options(&self.options));
            return true;
        }
        false
    }

    /// Arms faults of the next program download (see [`crate::program`]).
    pub fn set_program_faults(&mut self, faults: ProgramFaults) {
        self.program.set_faults(faults);
    }

    /// The program download state (0x1F5x).
    pub fn program(&self) -> &SimProgram {
        &self.program
    }

    /// Takes over the program of `other` (its "flash"): what survives a
    /// power cycle.
    pub fn keep_program_of(&mut self, other: &SimNode) {
        self.program = other.program.clone();
    }

    /// Applies what a written object changes in the node's behaviour.
    fn after_write(&mut self, addr: ObjectAddress, changed: bool, now: Duration) {
        self.filter_generation += 1;
        if addr == HEARTBEAT_TIME {
            self.nmt.set_heartbeat_ms(self.heartbeat_ms(), now);
        }
        if addr.index == CONSUMER_HEARTBEAT {
            // A changed entry restarts monitoring with the next heartbeat.
            self.consumer = consumer_from(&self.store);
        }
        let operational = self.nmt.state() == NmtState::Operational;
        match PdoParam::of(addr.index) {
            Some(PdoParam::Comm(Dir::Tx, n)) if addr.sub == 5 => {
                let event = pdo::comm(&self.store, Dir::Tx, n).and_then(|c| c.event);
                if let Some(st) = self.tpdos.get_mut(&n) {
                    st.timer = event.filter(|_| operational).map(|e| now + e);
                }
            }
            Some(PdoParam::Comm(Dir::Tx, n) | PdoParam::Map(Dir::Tx, n)) => {
                if let Some(st) = self.tpdos.get_mut(&n) {
                    *st = TpdoState {
                        pending: operational,
                        ..TpdoState::default()
                    };
                }
            }
            Some(PdoParam::Comm(Dir::Rx, n) | PdoParam::Map(Dir::Rx, n)) => {
                if let Some(buffered) = self.rpdos.get_mut(&n) {
                    *buffered = None;
                }
            }
            None if changed && self.options.tpdo_on_change && operational => {
                self.mark_tpdos_mapping(addr);
            }
            None => {}
        }
    }

    /// Marks the event-driven and type 0 TPDOs that map `addr` as pending.
    fn mark_tpdos_mapping(&mut self, addr: ObjectAddress) {
        let store = &self.store;
        for (&n, st) in self.tpdos.iter_mut() {
            let Some(comm) = pdo::comm(store, Dir::Tx, n) else {
                continue;
            };
            let maps =
                pdo::mapping(store, Dir::Tx, n).is_ok_and(|m| m.iter().any(|e| e.addr == addr));
            if maps && (comm.event_driven() || comm.ttype == 0) {
                st.pending = true;
            }
        }
    }

    // ---- PDOs ----

    /// Fresh TPDO states (every event-driven TPDO pending when entering
    /// operational) and no buffered RPDO data.
    fn reset_pdos(&mut self, operational: bool) {
        for st in self.tpdos.values_mut() {
            *st = TpdoState {
                pending: operational,
                ..TpdoState::default()
            };
        }
        for buffered in self.rpdos.values_mut() {
            *buffered = None;
        }
    }

    /// When an event-driven TPDO must be looked at, if it is active.
    fn tpdo_due(&self, n: u16, st: &TpdoState) -> Option<Duration> {
        if self.nmt.state() != NmtState::Operational {
            return None;
        }
        pdo::comm(&self.store, Dir::Tx, n).filter(PdoComm::event_driven)?;
        let due = if st.pending { Some(self.now) } else { st.timer }?;
        Some(due.max(st.inhibit_until))
    }

    /// Sends every event-driven TPDO that is due at `now`.
    fn service_tpdos(&mut self, now: Duration, out: &mut Vec<Frame>) {
        if self.nmt.state() != NmtState::Operational {
            return;
        }
        let store = &self.store;
        for (&n, st) in self.tpdos.iter_mut() {
            let Some(comm) = pdo::comm(store, Dir::Tx, n).filter(PdoComm::event_driven) else {
                continue;
            };
            let timer_due = st.timer.is_some_and(|t| t <= now);
            if !(st.pending || timer_due) || now < st.inhibit_until {
                continue;
            }
            // The timer restarts with every transmission; a timer that
            // elapsed keeps its phase unless the tick came a period late.
            let base = match st.timer {
                Some(t) if timer_due && !st.pending => t,
                _ => now,
            };
            st.timer = comm.event.map(|e| {
                let next = base + e;
                if next > now { next } else { now + e }
            });
            st.pending = false;
            if let Some(frame) = tpdo_frame(store, n, &comm) {
                st.inhibit_until = now + comm.inhibit;
                out.push(frame);
            }
        }
    }

    fn is_sync(&self, frame: &Frame) -> bool {
        let raw = self.store.u32_at(COB_ID_SYNC, 0).unwrap_or(0x80);
        !frame.is_remote() && !frame.is_fd() && frame.id() == pdo::CobId::decode(raw).id
    }

    fn on_sync(&mut self, frame: &Frame, now: Duration, out: &mut Vec<Frame>) {
        self.push_event(SimEvent::Sync {
            counter: frame.data().first().copied(),
        });
        if self.nmt.state() != NmtState::Operational {
            return;
        }
        // Synchronous RPDOs take effect at the SYNC after their reception.
        let buffered: Vec<(u16, Vec<u8>)> = self
            .rpdos
            .iter_mut()
            .filter_map(|(&n, b)| Some((n, b.take()?)))
            .collect();
        for (n, data) in buffered {
            if let Ok(entries) = pdo::mapping(&self.store, Dir::Rx, n) {
                self.apply_rpdo(n, &entries, &data, now);
            }
        }
        let store = &self.store;
        for (&n, st) in self.tpdos.iter_mut() {
            let Some(comm) = pdo::comm(store, Dir::Tx, n) else {
                continue;
            };
            let send = match comm.ttype {
                0 => std::mem::take(&mut st.pending),
                t @ 1..=240 => {
                    st.syncs = st.syncs.saturating_add(1);
                    let due = st.syncs >= t;
                    if due {
                        st.syncs = 0;
                    }
                    due
                }
                _ => false,
            };
            if send {
                out.extend(tpdo_frame(store, n, &comm));
            }
        }
        self.service_tpdos(now, out);
    }

    /// Answers a remote request for a TPDO that allows RTR.
    fn on_tpdo_request(&mut self, frame: &Frame, now: Duration, out: &mut Vec<Frame>) {
        let store = &self.store;
        for (&n, st) in self.tpdos.iter_mut() {
            let Some(comm) = pdo::comm(store, Dir::Tx, n) else {
                continue;
            };
            if comm.id != frame.id() || !comm.rtr_allowed {
                continue;
            }
            if let Some(f) = tpdo_frame(store, n, &comm) {
                if comm.event_driven() {
                    st.inhibit_until = now + comm.inhibit;
                }
                out.push(f);
            }
        }
    }

    fn on_rpdo(&mut self, frame: &Frame, now: Duration) {
        if frame.is_fd() {
            return;
        }
        let matching: Vec<(u16, PdoComm)> = self
            .rpdos
            .keys()
            .filter_map(|&n| Some((n, pdo::comm(&self.store, Dir::Rx, n)?)))
            .filter(|(_, c)| c.id == frame.id())
            .collect();
        for (n, comm) in matching {
            let Ok(entries) = pdo::mapping(&self.store, Dir::Rx, n) else {
                continue;
            };
            if entries.is_empty() {
                continue;
            }
            let len: usize = entries.iter().map(|e| e.len).sum();
            let data = frame.data();
            if data.len() < len {
                self.push_event(SimEvent::RpdoLengthError {
                    pdo: n + 1,
                    expected: len,
                    got: data.len(),
                });
                continue;
            }
            if comm.ttype <= 240 {
                self.rpdos.insert(n, Some(data[..len].to_vec()));
            } else {
                self.apply_rpdo(n, &entries, &data[..len], now);
            }
        }
    }

    fn apply_rpdo(&mut self, n: u16, entries: &[MapEntry], data: &[u8], now: Duration) {
        let mut objects = Vec::with_capacity(entries.len());
        let mut offset = 0;
        for e in entries {
            let bytes = &data[offset..offset + e.len];
            offset += e.len;
            if e.dummy {
                continue;
            }
            let Some(var) = self.store.variable(e.addr) else {
                continue;
            };
            let Ok(value) = Value::decode(var.data_type, bytes) else {
                continue;
            };
            let changed = self.store.put(e.addr, value.clone());
            objects.push((e.addr, value));
            self.after_write(e.addr, changed, now);
        }
        self.push_event(SimEvent::RpdoReceived {
            pdo: n + 1,
            objects,
        });
    }

    // ---- heartbeat consumer ----

    fn on_consumer_events(
        &mut self,
        events: Vec<HeartbeatEvent>,
        now: Duration,
        out: &mut Vec<Frame>,
    ) {
        for event in events {
            match event {
                HeartbeatEvent::HeartbeatLost { node, timeout, .. } => {
                    self.push_event(SimEvent::HeartbeatLost { node, timeout });
                    out.extend(self.inject_emcy(
                        HEARTBEAT_ERROR_CODE,
                        ErrorRegister::GENERIC | ErrorRegister::COMMUNICATION,
                        [node.get(), 0, 0, 0, 0],
                    ));
                    self.communication_error(now, out);
                }
                HeartbeatEvent::HeartbeatRecovered { node, .. } => {
                    self.push_event(SimEvent::HeartbeatRecovered { node });
                }
                _ => {}
            }
        }
    }

    /// The communication error behaviour (0x1029:01): 0 pre-operational
    /// (from operational), 1 no change, 2 stopped.
    fn communication_error(&mut self, now: Duration, out: &mut Vec<Frame>) {
        let command = match self
            .get(COMMUNICATION_ERROR_BEHAVIOUR)
            .and_then(Value::as_u32)
        {
            Some(0) if self.nmt.state() == NmtState::Operational => {
                Some(NmtCommand::EnterPreOperational)
            }
            Some(2) => Some(NmtCommand::Stop),
            _ => None,
        };
        if let Some(cmd) = command {
            let before = self.nmt.state();
            if let Some(e) = self.nmt.on_command(cmd, now) {
                self.on_nmt(before, e, now, out);
            }
        }
    }

    // ---- EMCY ----

    fn set_error_register(&mut self, register: u8) {
        let changed = self.store.put(ERROR_REGISTER, Value::Unsigned8(register));
        self.after_write(ERROR_REGISTER, changed, self.now);
    }

    fn emcy(&self, code: u16, register: u8, manufacturer: [u8; 5]) -> Option<Frame> {
        if !matches!(
            self.nmt.state(),
            NmtState::PreOperational | NmtState::Operational
        ) {
            return None;
        }
        let standard = emcy_frame(self.node, code, register, manufacturer);
        let Some(raw) = self.store.u32_at(COB_ID_EMCY, 0) else {
            return Some(standard);
        };
        let cob = pdo::CobId::decode(raw);
        if !cob.valid {
            return None;
        }
        Frame::new(cob.id, standard.data()).ok()
    }

    fn push_event(&mut self, event: SimEvent) {
        if self.options.max_events == 0 {
            self.dropped_events += 1;
            return;
        }
        while self.events.len() >= self.options.max_events {
            self.events.pop_front();
            self.dropped_events += 1;
        }
        self.events.push_back(event);
    }
}

/// A consumer monitoring every node of the 0x1016 entries in use.
fn consumer_from(store: &SimStore) -> HeartbeatConsumer {
    let mut consumer = HeartbeatConsumer::new();
    let count = store
        .get(ObjectAddress::new(CONSUMER_HEARTBEAT, 0))
        .and_then(Value::as_u32)
        .unwrap_or(0);
    for sub in 1..=count.min(127) as u8 {
        let entry = store
            .get(ObjectAddress::new(CONSUMER_HEARTBEAT, sub))
            .and_then(Value::as_u32);
        if let Some((node, timeout)) = entry.and_then(HeartbeatConsumer::parse_od_entry) {
            consumer.monitor(node, timeout);
        }
    }
    consumer
}

/// The node of a heartbeat frame (0x701..=0x77F, standard).
fn heartbeat_sender(frame: &Frame) -> Option<NodeId> {
    if frame.is_extended() {
        return None;
    }
    let id = frame.raw_id();
    let base = u32::from(cob::HEARTBEAT);
    (base + 1..=base + 127)
        .contains(&id)
        .then(|| NodeId::new(id - base).ok())
        .flatten()
}

/// The heartbeat producer time: 0x1017, else the option, else off.
fn heartbeat_ms(store: &SimStore, options: &SimNodeOptions) -> u16 {
    match store.get(HEARTBEAT_TIME).and_then(Value::as_u32) {
        Some(ms) => u16::try_from(ms).unwrap_or(u16::MAX),
        None => options.heartbeat_ms.unwrap_or(0),
    }
}

/// The frame of TPDO `n`: its mapped objects concatenated; `None` when the
/// mapping is disabled or unusable.
fn tpdo_frame(store: &SimStore, n: u16, comm: &PdoComm) -> Option<Frame> {
    let entries = pdo::mapping(store, Dir::Tx, n).ok()?;
    if entries.is_empty() {
        return None;
    }
    let mut data = Vec::with_capacity(8);
    for e in &entries {
        let mut bytes = store.get(e.addr).map(Value::encode).unwrap_or_default();
        bytes.resize(e.len, 0);
        data.extend_from_slice(&bytes);
    }
    Frame::new(comm.id, &data).ok()
}

impl Device for SimNode {
    fn start(&mut self, now: Duration) -> Vec<Frame> {
        SimNode::start(self, now)
    }
    fn on_frame(&mut self, frame: &Frame, now: Duration) -> Vec<Frame> {
        SimNode::on_frame(self, frame, now)
    }
    fn on_tick(&mut self, now: Duration) -> Vec<Frame> {
        SimNode::on_tick(self, now)
    }
    fn next_deadline(&self) -> Option<Duration> {
        SimNode::next_deadline(self)
    }
    fn receive_filters(&self) -> Option<Vec<Filter>> {
        Some(SimNode::receive_filters(self))
    }
    fn filter_generation(&self) -> u64 {
        SimNode::filter_generation(self)
    }
}

#[cfg(test)]
mod tests {
    use std::collections::VecDeque;

    use cangate_can::CanId;
    use cangate_canopen::eds::{SIM_DRIVE_EDS, SIM_IO_EDS};
    use cangate_canopen::sdo::{SdoClient, SdoError, TransferOptions, TransferOutcome};
    use proptest::prelude::*;

    use super::*;

    const MS: Duration = Duration::from_millis(1);

    fn node(id: u32) -> NodeId {
        NodeId::new(id).unwrap()
    }

    fn at(index: u16, sub: u8) -> ObjectAddress {
        ObjectAddress::new(index, sub)
    }

    fn drive_with(options: SimNodeOptions) -> SimNode {
        SimNode::from_eds_text(SIM_DRIVE_EDS, node(5), options).unwrap()
    }

    /// The drive at node 5, booted at t = 0, events taken.
    fn drive() -> SimNode {
        let mut sim = drive_with(SimNodeOptions::default());
        sim.start(Duration::ZERO);
        sim.take_events();
        sim
    }

    /// The drive, operational since t = 0 (its first TPDOs discarded).
    fn operational() -> SimNode {
        let mut sim = drive();
        sim.on_frame(&frame(0x000, &[0x01, 0x05]), Duration::ZERO);
        sim.take_events();
        sim
    }

    fn h(s: &str) -> Vec<u8> {
        s.split_whitespace()
            .map(|b| u8::from_str_radix(b, 16).unwrap())
            .collect()
    }

    fn frame(id: u16, data: &[u8]) -> Frame {
        Frame::new(CanId::Standard(id), data).unwrap()
    }

    fn wire(frames: &[Frame]) -> Vec<(u32, Vec<u8>)> {
        frames
            .iter()
            .map(|f| (f.raw_id(), f.data().to_vec()))
            .collect()
    }

    /// Sends an SDO request (hex) to node 5; returns the reply bytes.
    fn sdo(sim: &mut SimNode, request: &str, now: Duration) -> Vec<(u32, Vec<u8>)> {
        wire(&sim.on_frame(&frame(0x605, &h(request)), now))
    }

    fn reply(response: &str) -> Vec<(u32, Vec<u8>)> {
        vec![(0x585, h(response))]
    }

    #[test]
    fn boots_up_into_pre_operational() {
        let mut sim = drive_with(SimNodeOptions::default());
        assert_eq!(sim.nmt_state(), NmtState::Initialising);
        // Nothing happens before start-up.
        assert!(
            sim.on_frame(&frame(0x605, &h("40 00 10 00 00 00 00 00")), MS)
                .is_empty()
        );
        assert_eq!(sim.next_deadline(), None);
        assert_eq!(wire(&sim.start(Duration::ZERO)), [(0x705, vec![0x00])]);
        assert_eq!(sim.nmt_state(), NmtState::PreOperational);
        assert_eq!(
            sim.take_events(),
            [SimEvent::NmtStateChanged {
                from: NmtState::Initialising,
                to: NmtState::PreOperational
            }]
        );
        assert!(sim.start(MS).is_empty(), "a second start does nothing");
        // The EDS heartbeat time is 1000 ms.
        assert_eq!(sim.next_deadline(), Some(Duration::from_secs(1)));
        assert_eq!(
            wire(&sim.on_tick(Duration::from_secs(1))),
            [(0x705, vec![0x7F])]
        );
    }

    #[test]
    fn answers_node_guarding_with_toggle_and_state() {
        let mut sim = drive_with(SimNodeOptions {
            heartbeat_ms: Some(0),
            ..SimNodeOptions::default()
        });
        let rtr = Frame::new_remote(CanId::Standard(0x705), 1).unwrap();
        // Not before boot-up.
        assert!(sim.on_frame(&rtr, MS).is_empty());
        sim.start(Duration::ZERO);
        // No heartbeat: guarding is the only sign of life.
        assert_eq!(sim.next_deadline(), None);
        assert!(accepted(&sim).contains(&0x705));
        assert_eq!(wire(&sim.on_frame(&rtr, 10 * MS)), [(0x705, vec![0x7F])]);
        assert_eq!(wire(&sim.on_frame(&rtr, 20 * MS)), [(0x705, vec![0xFF])]);
        sim.on_frame(&frame(0x000, &[0x01, 0x05]), 25 * MS);
        assert_eq!(wire(&sim.on_frame(&rtr, 30 * MS)), [(0x705, vec![0x05])]);
        sim.on_frame(&frame(0x000, &[0x02, 0x05]), 35 * MS);
        assert_eq!(wire(&sim.on_frame(&rtr, 40 * MS)), [(0x705, vec![0x84])]);
        // Other nodes' requests are not answered.
        let other = Frame::new_remote(CanId::Standard(0x706), 1).unwrap();
        assert!(sim.on_frame(&other, 45 * MS).is_empty());
        // A reset restarts the toggle at 0.
        sim.on_frame(&frame(0x000, &[0x82, 0x05]), 50 * MS);
        assert_eq!(wire(&sim.on_frame(&rtr, 60 * MS)), [(0x705, vec![0x7F])]);
    }

    /// Stacks differ: a device found running (no boot-up heard), one with
    /// heartbeat 0 and no node guarding, one refusing NMT start.
    #[test]
    fn found_running_silent_or_refusing_to_start() {
        let mut sim = drive_with(SimNodeOptions {
            running_at_start: Some(NmtState::Operational),
            heartbeat_ms: Some(100),
            ..SimNodeOptions::default()
        });
        assert!(sim.start(Duration::ZERO).is_empty(), "no boot-up");
        assert_eq!(sim.nmt_state(), NmtState::Operational);
        assert_eq!(wire(&sim.on_tick(100 * MS))[..1], [(0x705, vec![0x05])]);
        // A reset boots as usual, and so would a power cycle.
        assert_eq!(sim.options().running_at_start, None);
        let out = sim.on_frame(&frame(0x000, &[0x81, 0x05]), 150 * MS);
        assert_eq!(wire(&out), [(0x705, vec![0x00])]);

        let mut sim = drive_with(SimNodeOptions {
            heartbeat_ms: Some(0),
            node_guarding: false,
            refuses_nmt_start: true,
            ..SimNodeOptions::default()
        });
        sim.start(Duration::ZERO);
        assert_eq!(sim.next_deadline(), None);
        let rtr = Frame::new_remote(CanId::Standard(0x705), 1).unwrap();
        assert!(sim.on_frame(&rtr, 10 * MS).is_empty());
        sim.on_frame(&frame(0x000, &[0x01, 0x05]), 20 * MS);
        sim.on_frame(&frame(0x000, &[0x01, 0x00]), 30 * MS);
        assert_eq!(sim.nmt_state(), NmtState::PreOperational);
        // Other commands still apply; SDO still answers.
        sim.on_frame(&frame(0x000, &[0x02, 0x05]), 40 * MS);
        assert_eq!(sim.nmt_state(), NmtState::Stopped);
    }

    #[test]
    fn life_guarding_reports_a_silent_master_once_and_its_return() {
        let mut sim = drive_with(SimNodeOptions {
            heartbeat_ms: Some(0),
            ..SimNodeOptions::default()
        });
        sim.start(Duration::ZERO);
        sim.set(GUARD_TIME, Value::Unsigned16(100)).unwrap();
        sim.set(LIFE_TIME_FACTOR, Value::Unsigned8(3)).unwrap();
        sim.take_events();
        // Not watching before the first request.
        assert_eq!(sim.next_deadline(), None);
        let rtr = Frame::new_remote(CanId::Standard(0x705), 1).unwrap();
        sim.on_frame(&rtr, 1000 * MS);
        sim.on_frame(&rtr, 1100 * MS);
        // The node life time runs from the latest request: 300 ms.
        assert_eq!(sim.next_deadline(), Some(1400 * MS));
        assert!(sim.on_tick(1399 * MS).is_empty());
        let out = sim.on_tick(1400 * MS);
        assert_eq!(wire(&out), [(0x085, vec![0x30, 0x81, 0x11, 0, 0, 0, 0, 0])]);
        assert_eq!(
            sim.take_events(),
            [SimEvent::LifeGuardingLost {
                life_time: 300 * MS
            }]
        );
        // Once.
        assert_eq!(sim.next_deadline(), None);
        assert!(sim.on_tick(2000 * MS).is_empty());
        // The next request: the error reset, then the answer.
        let out = sim.on_frame(&rtr, 2100 * MS);
        assert_eq!(wire(&out), [(0x085, vec![0; 8]), (0x705, vec![0x7F])]);
        assert_eq!(sim.take_events(), [SimEvent::LifeGuardingRecovered]);
        assert_eq!(sim.next_deadline(), Some(2400 * MS));
        // A guard time of 0 stops life guarding.
        sim.set(GUARD_TIME, Value::Unsigned16(0)).unwrap();
        assert_eq!(sim.next_deadline(), None);
    }

    /// The identifiers of a node's acceptance filters (all standard, exact).
    fn accepted(sim: &SimNode) -> Vec<u32> {
        sim.receive_filters()
            .iter()
            .map(|f| {
                assert_eq!(
                    (f.mask, f.extended, f.inverted),
                    (0x7FF, Some(false), false)
                );
                f.id
            })
            .collect()
    }

    #[test]
    fn receive_filters_follow_the_pdo_and_sync_configuration() {
        let mut sim = drive();
        // NMT, SYNC, TPDO1/2 (remote requests), RPDO1/2, SDO requests.
        assert_eq!(
            accepted(&sim),
            [0x000, 0x080, 0x185, 0x205, 0x285, 0x305, 0x605, 0x705]
        );
        // RPDO1 invalidated, then moved to 0x2AB (the CiA 301 procedure);
        // every write tells the runner to look again.
        let generation = sim.filter_generation();
        assert_eq!(
            sdo(&mut sim, "23 00 14 01 05 02 00 80", MS),
            reply("60 00 14 01 00 00 00 00")
        );
        assert!(!accepted(&sim).contains(&0x205));
        assert!(sim.filter_generation() > generation);
        sdo(&mut sim, "23 00 14 01 AB 02 00 00", MS);
        assert_eq!(
            accepted(&sim),
            [0x000, 0x080, 0x185, 0x285, 0x2AB, 0x305, 0x605, 0x705]
        );
        // A SYNC COB-ID of 0x081 replaces 0x080.
        sdo(&mut sim, "23 05 10 00 81 00 00 00", MS);
        assert!(accepted(&sim).contains(&0x081) && !accepted(&sim).contains(&0x080));
    }

    #[test]
    fn expedited_read_of_the_device_type() {
        let mut sim = drive();
        assert_eq!(
            sdo(&mut sim, "40 00 10 00 00 00 00 00", MS),
            reply("43 00 10 00 92 01 02 00")
        );
        assert_eq!(
            sdo(&mut sim, "40 18 10 02 00 00 00 00", MS),
            reply("43 18 10 02 02 04 00 00")
        );
        // COB-IDs are resolved for the node id.
        assert_eq!(
            sdo(&mut sim, "40 00 18 01 00 00 00 00", MS),
            reply("43 00 18 01 85 01 00 00")
        );
    }

    #[test]
    fn heartbeat_time_write_takes_effect_at_once() {
        let mut sim = drive();
        let t0 = 10 * MS;
        assert_eq!(
            sdo(&mut sim, "2B 17 10 00 64 00 00 00", t0),
            reply("60 17 10 00 00 00 00 00")
        );
        assert_eq!(
            sim.take_events(),
            [SimEvent::SdoWritten {
                addr: at(0x1017, 0)
            }]
        );
        assert_eq!(sim.get(at(0x1017, 0)), Some(&Value::Unsigned16(100)));
        for k in 1..=5u32 {
            let due = t0 + 100 * MS * k;
            assert_eq!(sim.next_deadline(), Some(due));
            assert!(sim.on_tick(due - MS).is_empty());
            assert_eq!(wire(&sim.on_tick(due)), [(0x705, vec![0x7F])]);
        }
        // 0 switches the producer off.
        sdo(&mut sim, "2B 17 10 00 00 00 00 00", Duration::from_secs(1));
        assert_eq!(sim.next_deadline(), None);
    }

    #[test]
    fn sdo_aborts() {
        let mut sim = drive();
        let cases = [
            // Write to a read-only object.
            ("23 00 10 00 01 02 03 04", "80 00 10 00 02 00 01 06"),
            // Write to a const object.
            ("2F 18 10 00 05 00 00 00", "80 18 10 00 02 00 01 06"),
            // Unknown object.
            ("40 00 20 00 00 00 00 00", "80 00 20 00 00 00 02 06"),
            // Unknown sub-index.
            ("40 18 10 09 00 00 00 00", "80 18 10 09 11 00 09 06"),
            // UNSIGNED32 written to an UNSIGNED16: too long.
            ("23 17 10 00 64 00 00 00", "80 17 10 00 12 00 07 06"),
            // UNSIGNED8 written to an UNSIGNED16: too short.
            ("2F 17 10 00 64 00 00 00", "80 17 10 00 13 00 07 06"),
            // Profile velocity above its HighLimit of 1000000.
            ("23 81 60 00 80 84 1E 00", "80 81 60 00 31 00 09 06"),
        ];
        for (request, abort) in cases {
            assert_eq!(sdo(&mut sim, request, MS), reply(abort), "{request}");
        }
        assert_eq!(sim.get(at(0x1017, 0)), Some(&Value::Unsigned16(1000)));
        assert!(sim.take_events().is_empty());
    }

    #[test]
    fn sdo_aborts_for_access_and_limits_of_a_custom_eds() {
        let text = "[2000]\nParameterName=Limited\nDataType=0x0003\nAccessType=rw\n\
                    DefaultValue=0\nLowLimit=-10\nHighLimit=10\n\
                    [2001]\nParameterName=Secret\nDataType=0x0007\nAccessType=wo\nDefaultValue=0\n";
        let mut sim = SimNode::from_eds_text(text, node(5), SimNodeOptions::default()).unwrap();
        sim.start(Duration::ZERO);
        assert_eq!(
            sdo(&mut sim, "40 01 20 00 00 00 00 00", MS),
            reply("80 01 20 00 01 00 01 06")
        );
        assert_eq!(
            sdo(&mut sim, "23 01 20 00 01 02 03 04", MS),
            reply("60 01 20 00 00 00 00 00")
        );
        assert_eq!(
            sdo(&mut sim, "2B 00 20 00 F5 FF 00 00", MS),
            reply("80 00 20 00 32 00 09 06")
        );
        assert_eq!(
            sdo(&mut sim, "2B 00 20 00 0B 00 00 00", MS),
            reply("80 00 20 00 31 00 09 06")
        );
        assert_eq!(
            sdo(&mut sim, "2B 00 20 00 F6 FF 00 00", MS),
            reply("60 00 20 00 00 00 00 00")
        );
        assert_eq!(sim.get(at(0x2000, 0)), Some(&Value::Integer16(-10)));
        // No heartbeat object and no override: no heartbeat.
        assert_eq!(sim.next_deadline(), None);
        assert!(matches!(
            SimNode::from_eds_text("[1000\n", node(1), SimNodeOptions::default()),
            Err(SimError::Eds(_))
        ));
    }

    #[test]
    fn nmt_start_gives_operational_heartbeats_and_tpdos() {
        let mut sim = drive();
        sim.set(at(0x6041, 0), Value::Unsigned16(0x0637)).unwrap();
        sim.set(at(0x6064, 0), Value::Integer32(0x1234_5678))
            .unwrap();
        sim.set(at(0x606C, 0), Value::Integer32(-2)).unwrap();
        sim.set(at(0x6077, 0), Value::Integer16(300)).unwrap();
        // Entering operational tells it with a heartbeat and sends the
        // event-driven TPDOs at once.
        let tpdo1 = (0x185, h("37 06 78 56 34 12"));
        let tpdo2 = (0x285, h("FE FF FF FF 2C 01"));
        assert_eq!(
            wire(&sim.on_frame(&frame(0x000, &[0x01, 0x05]), Duration::ZERO)),
            [(0x705, vec![0x05]), tpdo1.clone(), tpdo2.clone()]
        );
        assert_eq!(
            sim.take_events(),
            [SimEvent::NmtStateChanged {
                from: NmtState::PreOperational,
                to: NmtState::Operational
            }]
        );
        // Then every 100 ms (event timer 0x1800:05), and the heartbeat says
        // operational.
        let mut sent = Vec::new();
        while let Some(due) = sim.next_deadline().filter(|d| *d <= Duration::from_secs(1)) {
            for f in wire(&sim.on_tick(due)) {
                sent.push((due.as_millis(), f));
            }
        }
        let at_ms = |id: u32| -> Vec<u128> {
            sent.iter()
                .filter(|(_, (i, _))| *i == id)
                .map(|(t, _)| *t)
                .collect()
        };
        let every_100: Vec<u128> = (1..=10).map(|k| k * 100).collect();
        assert_eq!(at_ms(0x185), every_100);
        assert_eq!(at_ms(0x285), every_100);
        assert_eq!(at_ms(0x705), [1000]);
        assert!(sent.contains(&(1000, (0x705, vec![0x05]))));
        assert!(sent.contains(&(500, tpdo1.clone())));
        // A new position shows in the next TPDO.
        sim.set(at(0x6064, 0), Value::Integer32(-1)).unwrap();
        let next = sim.on_tick(Duration::from_millis(1100));
        assert_eq!(wire(&next)[0], (0x185, h("37 06 FF FF FF FF")));

        // Stopped: no TPDOs, heartbeat 0x04 at once and a period later, SDO
        // ignored.
        assert_eq!(
            wire(&sim.on_frame(&frame(0x000, &[0x02, 0x05]), Duration::from_millis(1150))),
            [(0x705, vec![0x04])]
        );
        assert_eq!(
            wire(&sim.on_tick(Duration::from_millis(2150))),
            [(0x705, vec![0x04])]
        );
        assert!(sdo(&mut sim, "40 00 10 00 00 00 00 00", Duration::from_secs(2)).is_empty());
        assert_eq!(sim.next_deadline(), Some(Duration::from_millis(3150)));
        // Commands for other nodes are ignored.
        assert!(
            sim.on_frame(&frame(0x000, &[0x01, 0x06]), Duration::from_secs(2))
                .is_empty()
        );
        assert_eq!(sim.nmt_state(), NmtState::Stopped);
    }

    #[test]
    fn rpdo_writes_the_object_dictionary() {
        let mut sim = drive();
        let rpdo1 = frame(0x205, &h("0F 00 40 E2 01 00"));
        // Not operational: ignored.
        assert!(sim.on_frame(&rpdo1, MS).is_empty());
        assert_eq!(sim.get(at(0x6040, 0)), Some(&Value::Unsigned16(0)));
        sim.on_frame(&frame(0x000, &[0x01, 0x00]), MS);
        sim.take_events();
        sim.on_frame(&rpdo1, 2 * MS);
        assert_eq!(sim.get(at(0x6040, 0)), Some(&Value::Unsigned16(0x000F)));
        assert_eq!(sim.get(at(0x607A, 0)), Some(&Value::Integer32(123_456)));
        assert_eq!(
            sim.take_events(),
            [SimEvent::RpdoReceived {
                pdo: 1,
                objects: vec![
                    (at(0x6040, 0), Value::Unsigned16(0x000F)),
                    (at(0x607A, 0), Value::Integer32(123_456)),
                ]
            }]
        );
        // RPDO2: controlword + target velocity; longer frames use the
        // leading bytes.
        sim.on_frame(&frame(0x305, &h("06 00 E8 03 00 00 AA BB")), 3 * MS);
        assert_eq!(sim.get(at(0x6040, 0)), Some(&Value::Unsigned16(6)));
        assert_eq!(sim.get(at(0x60FF, 0)), Some(&Value::Integer32(1000)));
        sim.take_events();
        // A short frame is not applied.
        sim.on_frame(&frame(0x205, &h("07 00 01")), 4 * MS);
        assert_eq!(sim.get(at(0x6040, 0)), Some(&Value::Unsigned16(6)));
        assert_eq!(
            sim.take_events(),
            [SimEvent::RpdoLengthError {
                pdo: 1,
                expected: 6,
                got: 3
            }]
        );
    }

    #[test]
    fn synchronous_rpdo_applies_at_the_next_sync() {
        let mut sim = operational();
        sdo(&mut sim, "2F 00 14 02 01 00 00 00", MS);
        sim.on_frame(&frame(0x205, &h("0F 00 01 00 00 00")), 2 * MS);
        assert_eq!(sim.get(at(0x6040, 0)), Some(&Value::Unsigned16(0)));
        sim.on_frame(&frame(0x080, &[]), 3 * MS);
        assert_eq!(sim.get(at(0x6040, 0)), Some(&Value::Unsigned16(0x0F)));
        assert_eq!(sim.get(at(0x607A, 0)), Some(&Value::Integer32(1)));
    }

    #[test]
    fn synchronous_tpdo_every_nth_sync() {
        let mut sim = operational();
        // TPDO1 every second SYNC.
        assert_eq!(
            sdo(&mut sim, "2F 00 18 02 02 00 00 00", MS),
            reply("60 00 18 02 00 00 00 00")
        );
        sim.set(at(0x6041, 0), Value::Unsigned16(0x0237)).unwrap();
        sim.take_events();
        let sync = frame(0x080, &[]);
        let tpdo1 = (0x185, h("37 02 00 00 00 00"));
        assert!(sim.on_frame(&sync, 2 * MS).is_empty());
        assert_eq!(wire(&sim.on_frame(&sync, 3 * MS)), vec![tpdo1.clone()]);
        assert!(sim.on_frame(&sync, 4 * MS).is_empty());
        assert_eq!(wire(&sim.on_frame(&sync, 5 * MS)), vec![tpdo1.clone()]);
        assert_eq!(sim.take_events(), vec![SimEvent::Sync { counter: None }; 4]);
        // TPDO1 is no longer on the event timer; TPDO2 still is.
        let ticked = wire(&sim.on_tick(Duration::from_millis(100)));
        assert_eq!(ticked.iter().map(|f| f.0).collect::<Vec<_>>(), [0x285]);

        // Type 0: once per application event, at the next SYNC.
        sdo(&mut sim, "2F 00 18 02 00 00 00 00", 6 * MS);
        sim.on_frame(&sync, 7 * MS); // the reconfiguration counts as an event
        assert!(sim.on_frame(&sync, 8 * MS).is_empty());
        assert!(sim.trigger_tpdo(1));
        assert!(!sim.trigger_tpdo(5));
        assert!(!sim.trigger_tpdo(0));
        assert_eq!(wire(&sim.on_frame(&frame(0x080, &[7]), 9 * MS)), [tpdo1]);
        assert!(sim.on_frame(&sync, 10 * MS).is_empty());
    }

    #[test]
    fn remote_request_for_a_tpdo() {
        let mut sim = operational();
        let rtr = Frame::new_remote(CanId::Standard(0x185), 6).unwrap();
        assert_eq!(
            wire(&sim.on_frame(&rtr, MS)),
            [(0x185, h("00 00 00 00 00 00"))]
        );
        // RTR not allowed (bit 30).
        sdo(&mut sim, "23 00 18 01 85 01 00 40", 2 * MS);
        assert!(sim.on_frame(&rtr, 3 * MS).is_empty());
    }

    #[test]
    fn reset_node_restores_defaults_and_boots() {
        let mut sim = operational();
        sdo(&mut sim, "2B 17 10 00 64 00 00 00", MS);
        sim.set(at(0x6064, 0), Value::Integer32(42)).unwrap();
        sim.take_events();
        let out = sim.on_frame(&frame(0x000, &[0x81, 0x05]), 2 * MS);
        assert_eq!(wire(&out), [(0x705, vec![0x00])]);
        assert_eq!(sim.nmt_state(), NmtState::PreOperational);
        assert_eq!(sim.get(at(0x1017, 0)), Some(&Value::Unsigned16(1000)));
        assert_eq!(sim.get(at(0x6064, 0)), Some(&Value::Integer32(0)));
        assert_eq!(sim.heartbeat_period(), Some(Duration::from_secs(1)));
        assert_eq!(sim.next_deadline(), Some(2 * MS + Duration::from_secs(1)));
        assert_eq!(
            sim.take_events(),
            [
                SimEvent::Reset {
                    kind: NmtReset::Node
                },
                SimEvent::NmtStateChanged {
                    from: NmtState::Operational,
                    to: NmtState::PreOperational
                }
            ]
        );

        // Reset communication keeps the application values.
        sdo(&mut sim, "2B 17 10 00 64 00 00 00", 3 * MS);
        sim.set(at(0x6064, 0), Value::Integer32(7)).unwrap();
        let out = sim.on_frame(&frame(0x000, &[0x82, 0x00]), 4 * MS);
        assert_eq!(wire(&out), [(0x705, vec![0x00])]);
        assert_eq!(sim.get(at(0x1017, 0)), Some(&Value::Unsigned16(1000)));
        assert_eq!(sim.get(at(0x6064, 0)), Some(&Value::Integer32(7)));
    }

    #[test]
    fn segmented_read_of_the_device_name() {
        let mut sim = drive();
        let exchange = [
            ("40 08 10 00 00 00 00 00", "41 08 10 00 11 00 00 00"),
            ("60 00 00 00 00 00 00 00", "00 63 61 6E 67 61 74 65"), // "cangate"
            ("70 00 00 00 00 00 00 00", "10 20 73 69 6D 20 64 72"), // " sim dr"
            ("60 00 00 00 00 00 00 00", "09 69 76 65 00 00 00 00"), // "ive", last
        ];
        for (request, response) in exchange {
            assert_eq!(sdo(&mut sim, request, MS), reply(response), "{request}");
        }
    }

    /// Runs an SDO client against the node until the transfer completes;
    /// the node answers nothing that was still queued then.
    fn run_client(
        sim: &mut SimNode,
        client: &mut SdoClient,
        first: Vec<Frame>,
        now: &mut Duration,
    ) -> Result<TransferOutcome, SdoError> {
        let (done, late) = run_to_end(sim, client, first, now);
        assert!(late.is_empty(), "answers after the end: {late:?}");
        done
    }

    /// Runs a transfer until the client completes; frames still queued
    /// then are delivered to the node (as on a bus) and its answers
    /// returned.
    fn run_to_end(
        sim: &mut SimNode,
        client: &mut SdoClient,
        first: Vec<Frame>,
        now: &mut Duration,
    ) -> (Result<TransferOutcome, SdoError>, Vec<Frame>) {
        let mut queue: VecDeque<Frame> = first.into();
        while let Some(f) = queue.pop_front() {
            *now += Duration::from_micros(100);
            if f.raw_id() == 0x605 {
                let replies = sim.on_frame(&f, *now);
                queue.extend(replies.into_iter().filter(|r| r.raw_id() == 0x585));
            } else {
                let step = client.on_frame(&f, *now);
                queue.extend(step.frames);
                if let Some(done) = step.completed {
                    let late = queue
                        .drain(..)
                        .filter(|f| f.raw_id() == 0x605)
                        .flat_map(|f| sim.on_frame(&f, *now))
                        .collect();
                    return (done, late);
                }
            }
        }
        panic!("transfer stalled")
    }

    #[test]
    fn program_download_by_block_transfer_with_flash_delay_and_faults() {
        use crate::program::{INITIAL_IDENTIFICATION, ProgramFaults, crc32};
        let mut sim = drive();
        let mut client = SdoClient::new(node(5));
        let mut now = MS;
        let data = at(0x1F50, 1);
        let image: Vec<u8> = (0..10_000u32).map(|i| (i * 13 % 251) as u8).collect();
        // Refused at the initiate while the program runs.
        let first = client
            .start_download(data, image.clone(), TransferOptions::block(), now)
            .unwrap();
        let (r, _) = run_to_end(&mut sim, &mut client, first, &mut now);
        assert_eq!(
            r,
            Err(SdoError::Aborted {
                addr: data,
                code: AbortCode::CANNOT_TRANSFER_DEVICE_STATE
            })
        );
        assert_eq!(
            sdo(&mut sim, "40 56 1F 01 00 00 00 00", now),
            reply("43 56 1F 01 00 00 01 00")
        );
        // Stop, then the abort injected at byte 1000.
        assert_eq!(
            sdo(&mut sim, "2F 51 1F 01 00 00 00 00", now),
            reply("60 51 1F 01 00 00 00 00")
        );
        sim.set_program_faults(ProgramFaults {
            abort_at: Some((1000, AbortCode::HARDWARE_ERROR)),
            ..ProgramFaults::default()
        });
        let first = client
            .start_download(data, image.clone(), TransferOptions::block(), now)
            .unwrap();
        let (r, _) = run_to_end(&mut sim, &mut client, first, &mut now);
        assert_eq!(
            r,
            Err(SdoError::Aborted {
                addr: data,
                code: AbortCode::HARDWARE_ERROR
            })
        );
        // Once: the next download goes through, the flash is busy for
        // 10 KiB x 1 ms.
        now += Duration::from_millis(100);
        let first = client
            .start_download(data, image.clone(), TransferOptions::block(), now)
            .unwrap();
        let (r, _) = run_to_end(&mut sim, &mut client, first, &mut now);
        assert_eq!(r, Ok(TransferOutcome::Downloaded));
        assert_eq!(
            sdo(&mut sim, "40 57 1F 01 00 00 00 00", now),
            reply("43 57 1F 01 01 00 00 00")
        );
        // Starting while flashing is refused.
        assert_eq!(
            sdo(&mut sim, "2F 51 1F 01 01 00 00 00", now),
            reply("80 51 1F 01 22 00 00 08")
        );
        now += Duration::from_millis(10);
        assert!(sim.next_deadline().is_some_and(|d| d <= now));
        let _ = sim.on_tick(now);
        assert_eq!(
            sdo(&mut sim, "40 57 1F 01 00 00 00 00", now),
            reply("43 57 1F 01 00 00 00 00")
        );
        let id = crc32(&image);
        assert_ne!(id, INITIAL_IDENTIFICATION);
        sim.take_events();
        // Start: confirmed, then the boot-up.
        let out = wire(&sim.on_frame(&frame(0x605, &h("2F 51 1F 01 01 00 00 00")), now));
        assert_eq!(
            out,
            vec![(0x585, h("60 51 1F 01 00 00 00 00")), (0x705, vec![0x00])]
        );
        assert_eq!(sim.nmt_state(), NmtState::PreOperational);
        let mut expect = h("43 56 1F 01");
        expect.extend(id.to_le_bytes());
        assert_eq!(
            sdo(&mut sim, "40 56 1F 01 00 00 00 00", now),
            vec![(0x585, expect)]
        );
        // The program survives a power cycle.
        let fresh = crate::PowerOn::powered_on(&sim);
        assert_eq!(fresh.program().identification(), id);
    }

    #[test]
    fn block_transfer_of_the_firmware_domain() {
        let mut sim = drive();
        let mut client = SdoClient::new(node(5));
        let mut now = MS;
        let image: Vec<u8> = (0..4096u32).map(|i| (i * 7 % 251) as u8).collect();
        let fw = at(0x2100, 0);
        let first = client
            .start_download(fw, image.clone(), TransferOptions::block(), now)
            .unwrap();
        assert_eq!(first[0].data()[0] & 0xE0, 0xC0, "block download initiate");
        assert_eq!(
            run_client(&mut sim, &mut client, first, &mut now),
            Ok(TransferOutcome::Downloaded)
        );
        assert_eq!(sim.get(fw), Some(&Value::Domain(image.clone())));
        assert_eq!(sim.take_events(), [SimEvent::SdoWritten { addr: fw }]);
        let first = client
            .start_upload(fw, TransferOptions::block(), now)
            .unwrap();
        assert_eq!(
            run_client(&mut sim, &mut client, first, &mut now),
            Ok(TransferOutcome::Uploaded(image.clone()))
        );
        // Segmented works as well.
        let first = client
            .start_upload(fw, TransferOptions::default(), now)
            .unwrap();
        assert_eq!(
            run_client(&mut sim, &mut client, first, &mut now),
            Ok(TransferOutcome::Uploaded(image))
        );
        assert_eq!(sim.next_deadline(), Some(Duration::from_secs(1)));
    }

    #[test]
    fn block_transfer_can_be_switched_off() {
        let mut sim = drive_with(SimNodeOptions {
            block_transfer: false,
            ..SimNodeOptions::default()
        });
        sim.start(Duration::ZERO);
        assert_eq!(
            sdo(&mut sim, "C6 00 21 00 00 10 00 00", MS),
            reply("80 00 21 00 01 00 04 05")
        );
        // The client falls back to segmented.
        let mut client = SdoClient::new(node(5));
        let mut now = MS;
        let first = client
            .start_download(at(0x2100, 0), vec![1; 100], TransferOptions::block(), now)
            .unwrap();
        assert_eq!(
            run_client(&mut sim, &mut client, first, &mut now),
            Ok(TransferOutcome::Downloaded)
        );
        assert_eq!(sim.get(at(0x2100, 0)), Some(&Value::Domain(vec![1; 100])));
    }

    #[test]
    fn sdo_timeout_aborts_the_transfer() {
        let mut sim = drive_with(SimNodeOptions {
            heartbeat_ms: Some(0),
            sdo_timeout: 50 * MS,
            ..SimNodeOptions::default()
        });
        sim.start(Duration::ZERO);
        assert_eq!(sim.next_deadline(), None);
        sdo(&mut sim, "21 00 21 00 10 00 00 00", MS);
        assert_eq!(sim.next_deadline(), Some(51 * MS));
        assert_eq!(
            wire(&sim.on_tick(51 * MS)),
            reply("80 00 21 00 00 00 04 05")
        );
        assert_eq!(sim.next_deadline(), None);
    }

    #[test]
    fn emergency_messages() {
        let mut sim = drive();
        let f = sim.inject_emcy(0x2310, 0x03, [1, 2, 3, 4, 5]).unwrap();
        assert_eq!(wire(&[f]), [(0x085, h("10 23 03 01 02 03 04 05"))]);
        assert_eq!(
            sdo(&mut sim, "40 01 10 00 00 00 00 00", MS),
            reply("4F 01 10 00 03 00 00 00")
        );
        let f = sim.clear_emcy().unwrap();
        assert_eq!(wire(&[f]), [(0x085, h("00 00 00 00 00 00 00 00"))]);
        assert_eq!(sim.get(at(0x1001, 0)), Some(&Value::Unsigned8(0)));
        // A reconfigured EMCY COB-ID, then an invalid one.
        sdo(&mut sim, "23 14 10 00 90 00 00 00", MS);
        assert_eq!(
            sim.inject_emcy(0x1000, 1, [0; 5]).map(|f| f.raw_id()),
            Some(0x090)
        );
        sdo(&mut sim, "23 14 10 00 85 00 00 80", MS);
        assert_eq!(sim.inject_emcy(0x1000, 1, [0; 5]), None);
        sdo(&mut sim, "23 14 10 00 85 00 00 00", MS);
        // Not in stopped, but 0x1001 is still set.
        sim.on_frame(&frame(0x000, &[0x02, 0x05]), MS);
        assert_eq!(sim.inject_emcy(0x4210, 0x09, [0; 5]), None);
        assert_eq!(sim.get(at(0x1001, 0)), Some(&Value::Unsigned8(0x09)));
        // Not before start-up.
        let mut fresh = drive_with(SimNodeOptions::default());
        assert_eq!(fresh.inject_emcy(0x1000, 1, [0; 5]), None);
    }

    #[test]
    fn tpdo_reconfiguration_follows_the_cia_301_procedure() {
        let mut sim = operational();
        let t = 5 * MS;
        // Mapping cannot change while the PDO is valid.
        assert_eq!(
            sdo(&mut sim, "2F 00 1A 00 00 00 00 00", t),
            reply("80 00 1A 00 00 00 01 06")
        );
        // Nor can its COB-ID.
        assert_eq!(
            sdo(&mut sim, "23 00 18 01 90 01 00 00", t),
            reply("80 00 18 01 30 00 09 06")
        );
        // Nor its inhibit time.
        assert_eq!(
            sdo(&mut sim, "2B 00 18 03 0A 00 00 00", t),
            reply("80 00 18 03 30 00 09 06")
        );
        // Reserved transmission types.
        assert_eq!(
            sdo(&mut sim, "2F 00 18 02 F1 00 00 00", t),
            reply("80 00 18 02 30 00 09 06")
        );
        // 1. Invalidate.
        assert_eq!(
            sdo(&mut sim, "23 00 18 01 85 01 00 80", t),
            reply("60 00 18 01 00 00 00 00")
        );
        assert_eq!(sim.next_deadline(), Some(100 * MS), "only TPDO2 left");
        // Entries only while sub 0 is 0.
        assert_eq!(
            sdo(&mut sim, "23 00 1A 01 20 00 64 60", t),
            reply("80 00 1A 01 00 00 01 06")
        );
        // 2. Disable the mapping, 3. write entries.
        assert_eq!(
            sdo(&mut sim, "2F 00 1A 00 00 00 00 00", t),
            reply("60 00 1A 00 00 00 00 00")
        );
        // Not mappable, partial objects, variable-size objects.
        for entry in ["10 00 17 10", "10 00 64 60", "00 00 08 10"] {
            assert_eq!(
                sdo(&mut sim, &format!("23 00 1A 01 {entry}"), t),
                reply("80 00 1A 01 41 00 04 06"),
                "{entry}"
            );
        }
        for (sub, entry) in [(1, "20 00 64 60"), (2, "20 00 6C 60"), (3, "10 00 41 60")] {
            assert_eq!(
                sdo(&mut sim, &format!("23 00 1A {sub:02X} {entry}"), t),
                reply(&format!("60 00 1A {sub:02X} 00 00 00 00"))
            );
        }
        // More than 8 bytes.
        assert_eq!(
            sdo(&mut sim, "2F 00 1A 00 03 00 00 00", t),
            reply("80 00 1A 00 42 00 04 06")
        );
        // 4. Enable two entries, 5. validate on a new COB-ID.
        sdo(&mut sim, "2F 00 1A 00 02 00 00 00", t);
        // Restricted COB-IDs are refused.
        assert_eq!(
            sdo(&mut sim, "23 00 18 01 05 06 00 00", t),
            reply("80 00 18 01 30 00 09 06")
        );
        sim.set(at(0x6064, 0), Value::Integer32(1)).unwrap();
        sim.set(at(0x606C, 0), Value::Integer32(2)).unwrap();
        let out = wire(&sim.on_frame(&frame(0x605, &h("23 00 18 01 90 01 00 00")), t));
        assert_eq!(
            out,
            [
                (0x585, h("60 00 18 01 00 00 00 00")),
                (0x190, h("01 00 00 00 02 00 00 00"))
            ],
            "valid again: sent at once, on its new id"
        );
        // The event timer follows 0x1800:05.
        sdo(&mut sim, "2B 00 18 05 0A 00 00 00", 6 * MS);
        assert_eq!(sim.next_deadline(), Some(16 * MS));
        assert_eq!(wire(&sim.on_tick(16 * MS))[0].0, 0x190);
        sdo(&mut sim, "2B 00 18 05 00 00 00 00", 17 * MS);
        assert_eq!(sim.next_deadline(), Some(100 * MS));
    }

    #[test]
    fn lenient_pdo_configuration() {
        let mut sim = drive_with(SimNodeOptions {
            strict_pdo_config: false,
            ..SimNodeOptions::default()
        });
        sim.start(Duration::ZERO);
        sim.on_frame(&frame(0x000, &[0x01, 0x05]), Duration::ZERO);
        // Mapping changed while valid: accepted, effective at once.
        assert_eq!(
            sdo(&mut sim, "2F 00 1A 00 01 00 00 00", MS),
            [(0x585, h("60 00 1A 00 00 00 00 00")), (0x185, h("00 00"))]
        );
        // An unusable mapping is not sent (and does not spin the timer).
        assert_eq!(
            sdo(&mut sim, "23 00 1A 01 10 00 17 10", 2 * MS),
            reply("60 00 1A 01 00 00 00 00")
        );
        assert!(sim.on_tick(2 * MS).is_empty());
        assert!(
            sim.on_tick(Duration::from_millis(100))
                .iter()
                .all(|f| f.raw_id() != 0x185)
        );
        assert!(sim.next_deadline().unwrap() > 2 * MS);
    }

    #[test]
    fn tpdo_on_change_respects_the_inhibit_time() {
        let mut sim = drive_with(SimNodeOptions {
            tpdo_on_change: true,
            ..SimNodeOptions::default()
        });
        sim.start(Duration::ZERO);
        sim.on_frame(&frame(0x000, &[0x01, 0x05]), Duration::ZERO);
        let t = 10 * MS;
        sim.on_tick(t);
        // TPDO1 has no inhibit time: sent at the next tick.
        sim.set(at(0x6064, 0), Value::Integer32(5)).unwrap();
        assert_eq!(sim.next_deadline(), Some(t));
        assert_eq!(wire(&sim.on_tick(t)), [(0x185, h("00 00 05 00 00 00"))]);
        // Setting the same value again is no change.
        sim.set(at(0x6064, 0), Value::Integer32(5)).unwrap();
        assert!(sim.on_tick(t).is_empty());
        // TPDO2 has an inhibit time of 1 ms.
        sim.set(at(0x606C, 0), Value::Integer32(1)).unwrap();
        assert_eq!(wire(&sim.on_tick(t))[0].0, 0x285);
        sim.set(at(0x606C, 0), Value::Integer32(2)).unwrap();
        assert_eq!(sim.next_deadline(), Some(t + MS));
        assert!(sim.on_tick(t + MS / 2).is_empty());
        assert_eq!(
            wire(&sim.on_tick(t + MS)),
            [(0x285, h("02 00 00 00 00 00"))]
        );
        // Not operational: no events (the next heartbeat is a period after
        // the one the state change sent).
        sim.on_frame(&frame(0x000, &[0x80, 0x05]), t + 2 * MS);
        sim.set(at(0x6064, 0), Value::Integer32(6)).unwrap();
        assert_eq!(
            sim.next_deadline(),
            Some(t + 2 * MS + Duration::from_secs(1))
        );
    }

    #[test]
    fn io_node_and_heartbeat_override() {
        // The I/O EDS has no heartbeat; the option sets one.
        let mut io = SimNode::from_eds_text(
            SIM_IO_EDS,
            node(0x22),
            SimNodeOptions {
                heartbeat_ms: Some(250),
                ..SimNodeOptions::default()
            },
        )
        .unwrap();
        assert_eq!(wire(&io.start(Duration::ZERO)), [(0x722, vec![0x00])]);
        assert_eq!(io.next_deadline(), Some(250 * MS));
        // And resets keep the override.
        io.on_frame(&frame(0x000, &[0x81, 0x22]), MS);
        assert_eq!(io.get(at(0x1017, 0)), Some(&Value::Unsigned16(250)));
        // RPDO1 drives the digital outputs.
        io.on_frame(&frame(0x000, &[0x01, 0x22]), 2 * MS);
        io.on_frame(&frame(0x222, &[0xA5, 0x5A]), 3 * MS);
        assert_eq!(io.get(at(0x6200, 1)), Some(&Value::Unsigned8(0xA5)));
        assert_eq!(io.get(at(0x6200, 2)), Some(&Value::Unsigned8(0x5A)));
    }

    #[test]
    fn event_queue_is_bounded() {
        let mut sim = drive_with(SimNodeOptions {
            max_events: 3,
            ..SimNodeOptions::default()
        });
        sim.start(Duration::ZERO);
        for i in 0..5u8 {
            sim.on_frame(&frame(0x080, &[i + 1]), MS);
        }
        assert_eq!(sim.dropped_events(), 3);
        assert_eq!(
            sim.take_events(),
            [3, 4, 5].map(|c| SimEvent::Sync { counter: Some(c) })
        );
    }

    fn arbitrary_frame() -> impl Strategy<Value = Frame> {
        let ids = prop_oneof![
            Just(0x000u16),
            Just(0x080),
            Just(0x185),
            Just(0x205),
            Just(0x305),
            Just(0x605),
            0u16..0x800,
        ];
        (
            ids,
            any::<bool>(),
            proptest::collection::vec(any::<u8>(), 0..=8),
        )
            .prop_map(|(id, remote, data)| {
                if remote {
                    Frame::new_remote(CanId::Standard(id), data.len() as u8).unwrap()
                } else {
                    Frame::new(CanId::Standard(id), &data).unwrap()
                }
            })
    }

    /// SDO writes that reconfigure the node in interesting ways.
    fn config_write() -> impl Strategy<Value = Frame> {
        let requests = [
            "2B 17 10 00 0A 00 00 00",
            "2B 17 10 00 00 00 00 00",
            "2B 00 18 05 01 00 00 00",
            "2B 00 18 05 00 00 00 00",
            "2F 00 18 02 01 00 00 00",
            "2F 00 18 02 00 00 00 00",
            "2F 00 18 02 FF 00 00 00",
            "23 00 18 01 85 01 00 80",
            "23 00 18 01 85 01 00 00",
            "2F 00 1A 00 00 00 00 00",
            "2F 00 1A 00 02 00 00 00",
            "2B 01 18 03 FF FF 00 00",
        ];
        proptest::sample::select(requests.to_vec())
            .prop_map(|r| Frame::new(CanId::Standard(0x605), &h(r)).unwrap())
    }

    proptest! {
        #[test]
        fn random_traffic_never_panics_or_spins(
            steps in proptest::collection::vec(
                (prop_oneof![arbitrary_frame(), config_write(), Just(frame(0x000, &[0x01, 0x00]))],
                 0u64..200_000),
                1..60,
            ),
            strict in any::<bool>(),
            on_change in any::<bool>(),
        ) {
            let mut sim = drive_with(SimNodeOptions {
                strict_pdo_config: strict,
                tpdo_on_change: on_change,
                ..SimNodeOptions::default()
            });
            sim.start(Duration::ZERO);
            let mut now = Duration::ZERO;
            for (f, dt) in steps {
                now += Duration::from_micros(dt);
                let _ = sim.on_frame(&f, now);
                let _ = sim.set(at(0x6064, 0), Value::Integer32(dt as i32));
                let _ = sim.on_tick(now);
                if let Some(d) = sim.next_deadline() {
                    prop_assert!(d > now, "deadline {d:?} not after {now:?}");
                }
            }
        }
    }

    /// Runs `sim` in virtual time until `until`; returns the frames sent
    /// with their times.
    fn run_until<D: Device>(sim: &mut D, until: Duration) -> Vec<(Duration, Frame)> {
        let mut got = Vec::new();
        while let Some(t) = sim.next_deadline() {
            if t > until {
                break;
            }
            got.extend(sim.on_tick(t).into_iter().map(|f| (t, f)));
        }
        got
    }

    /// 0x1016:01 = master 127, 300 ms, written over SDO.
    fn consume_master(sim: &mut SimNode, now: Duration) {
        // 300 = 0x012C, node 0x7F.
        assert_eq!(
            sdo(sim, "23 16 10 01 2C 01 7F 00", now),
            [(0x585, h("60 16 10 01 00 00 00 00"))]
        );
    }

    #[test]
    fn heartbeat_consumer_times_out_once_with_emcy_8130_and_recovers() {
        let mut sim = operational();
        consume_master(&mut sim, Duration::ZERO);
        assert!(
            sim.receive_filters()
                .contains(&Filter::exact_standard(0x77F)),
            "listens to the master's heartbeat"
        );
        // Monitoring starts with the first heartbeat.
        assert!(
            run_until(&mut sim, 2000 * MS)
                .iter()
                .all(|(_, f)| f.raw_id() != 0x85)
        );
        let master_hb = frame(0x77F, &[0x05]);
        for t in [2000u64, 2100, 2200, 2300] {
            sim.on_frame(&master_hb, Duration::from_millis(t));
        }
        sim.take_events();
        // Silent from 2300 ms on: lost at 2600 ms exactly, reported once.
        let out = run_until(&mut sim, 5000 * MS);
        let emcy: Vec<_> = out.iter().filter(|(_, f)| f.raw_id() == 0x85).collect();
        assert_eq!(emcy.len(), 1, "{out:?}");
        assert_eq!(emcy[0].0, 2600 * MS);
        assert_eq!(emcy[0].1.data(), [0x30, 0x81, 0x11, 0x7F, 0, 0, 0, 0]);
        assert_eq!(sim.get(ERROR_REGISTER), Some(&Value::Unsigned8(0x11)));
        let events = sim.take_events();
        assert!(events.contains(&SimEvent::HeartbeatLost {
            node: node(127),
            timeout: 300 * MS
        }));
        // No 0x1029 in this dictionary: the NMT state stays.
        assert_eq!(sim.nmt_state(), NmtState::Operational);
        sim.on_frame(&master_hb, 6000 * MS);
        assert_eq!(
            sim.take_events(),
            [SimEvent::HeartbeatRecovered { node: node(127) }]
        );
        // A zero entry stops monitoring.
        sdo(&mut sim, "23 16 10 01 00 00 00 00", 6000 * MS);
        assert!(
            run_until(&mut sim, 9000 * MS)
                .iter()
                .all(|(_, f)| f.raw_id() != 0x85)
        );
    }

    #[test]
    fn heartbeat_in_time_keeps_the_consumer_quiet() {
        let mut sim = operational();
        consume_master(&mut sim, Duration::ZERO);
        let master_hb = frame(0x77F, &[0x05]);
        let mut t = Duration::ZERO;
        while t < 10 * 1000 * MS {
            sim.on_frame(&master_hb, t);
            // 299 ms apart: always just in time.
            t += 299 * MS;
            let out = run_until(&mut sim, t - MS);
            assert!(out.iter().all(|(_, f)| f.raw_id() != 0x85), "{out:?}");
        }
        assert!(
            sim.take_events()
                .iter()
                .all(|e| !matches!(e, SimEvent::HeartbeatLost { .. }))
        );
    }

    #[test]
    fn a_drive_faults_and_stops_when_the_master_heartbeat_stops() {
        use crate::drive::{SimDrive, SimDriveOptions};
        use cangate_canopen::cia402::DriveState;
        let mut d = SimDrive::bundled(node(5), SimDriveOptions::default());
        d.start(Duration::ZERO);
        d.on_frame(&frame(0x000, &[0x01, 0x05]), Duration::ZERO);
        let sdo_w = |d: &mut SimDrive, req: &str, now: Duration| {
            let out = d.on_frame(&frame(0x605, &h(req)), now);
            assert!(
                out.iter()
                    .any(|f| f.raw_id() == 0x585 && f.data()[0] == 0x60),
                "{req}: {out:?}"
            );
        };
        // Profile velocity (3) at 20 000 inc/s, then enable.
        sdo_w(&mut d, "2F 60 60 00 03 00 00 00", Duration::ZERO);
        sdo_w(&mut d, "23 FF 60 00 20 4E 00 00", Duration::ZERO);
        for cw in ["06", "07", "0F"] {
            sdo_w(
                &mut d,
                &format!("2B 40 60 00 {cw} 00 00 00"),
                Duration::ZERO,
            );
        }
        sdo_w(&mut d, "23 16 10 01 2C 01 7F 00", Duration::ZERO);
        let master_hb = frame(0x77F, &[0x05]);
        let mut t = Duration::ZERO;
        while t <= 1000 * MS {
            d.on_frame(&master_hb, t);
            t += 100 * MS;
            run_until(&mut d, t - MS);
        }
        assert_eq!(d.state(), DriveState::OperationEnabled);
        assert!(d.velocity() > 19_000.0, "jogging: {}", d.velocity());
        // The master dies after its heartbeat at 1000 ms.
        let out = run_until(&mut d, 1300 * MS - MS);
        assert!(out.iter().all(|(_, f)| f.raw_id() != 0x85));
        assert_eq!(d.state(), DriveState::OperationEnabled);
        let out = run_until(&mut d, 1300 * MS);
        assert!(
            out.iter()
                .any(|(_, f)| f.raw_id() == 0x85 && f.data()[..2] == [0x30, 0x81]),
            "EMCY 0x8130: {out:?}"
        );
        assert_eq!(d.state(), DriveState::FaultReactionActive);
        assert_eq!(d.error_code(), 0x8130);
        // It brakes with the quick stop deceleration and ends in fault.
        run_until(&mut d, 3000 * MS);
        assert_eq!(d.state(), DriveState::Fault);
        assert_eq!(d.velocity(), 0.0);
    }
}

#[cfg(test)]
mod lss_tests {
    use super::*;
    use cangate_canopen::eds::SIM_IO_EDS;
    use cangate_canopen::lss::{LssCommand, LssMaster, LssOutcome, request_frame};

    const MS: Duration = Duration::from_millis(1);
    const ID: LssIdentity = LssIdentity {
        vendor_id: 0x4D2,
        product_code: 0x10,
        revision: 1,
        serial: 0xCAFE,
    };

    fn unconfigured() -> SimNode {
        let options = SimNodeOptions {
            lss: Some(ID),
            lss_unconfigured: true,
            heartbeat_ms: Some(100),
            ..SimNodeOptions::default()
        };
        SimNode::from_eds_text(SIM_IO_EDS, NodeId::new(20).unwrap(), options).unwrap()
    }

    fn frame(id: u16, data: &[u8]) -> Frame {
        Frame::new(CanId::Standard(id), data).unwrap()
    }

    /// Runs an LSS command of a master against the node.
    fn lss(
        sim: &mut SimNode,
        cmd: LssCommand,
    ) -> (
        Result<LssOutcome, cangate_canopen::lss::LssError>,
        Vec<Frame>,
    ) {
        let mut m = LssMaster::new();
        let mut now = Duration::ZERO;
        let mut step = m.start(cmd, 100 * MS, now);
        let mut other = Vec::new();
        loop {
            for f in &step.frames {
                for a in sim.on_frame(f, now) {
                    if a.raw_id() == 0x7E4 {
                        if let Some(r) = m.on_frame(&a, now).completed {
                            return (r, other);
                        }
                    } else {
                        other.push(a);
                    }
                }
            }
            if let Some(r) = step.completed {
                return (r, other);
            }
            now = m.next_deadline().unwrap();
            step = m.on_tick(now);
        }
    }

    #[test]
    fn an_unconfigured_node_is_silent_until_given_an_id() {
        let mut sim = unconfigured();
        assert!(sim.start(Duration::ZERO).is_empty());
        assert_eq!(sim.next_deadline(), None);
        assert_eq!(sim.receive_filters(), vec![Filter::exact_standard(0x7E5)]);
        // No SDO server, no NMT.
        assert!(
            sim.on_frame(&frame(0x614, &[0x40, 0, 0x10, 0, 0, 0, 0, 0]), MS)
                .is_empty()
        );
        assert!(sim.on_frame(&frame(0x000, &[0x81, 0]), MS).is_empty());

        let (r, _) = lss(
            &mut sim,
            LssCommand::Fastscan {
                step_time: 10 * MS,
                max_nodes: 4,
            },
        );
        assert_eq!(r, Ok(LssOutcome::Found(vec![ID])));
        // Found: in the configuration state.
        let (r, _) = lss(&mut sim, LssCommand::ConfigureNodeId(20));
        assert_eq!(r, Ok(LssOutcome::Confirmed));
        let (r, _) = lss(&mut sim, LssCommand::StoreConfiguration);
        assert_eq!(r, Ok(LssOutcome::Confirmed));
        // Back to waiting: boots as node 20.
        let out = sim.on_frame(&request_frame(0x04, &[0]), 2 * MS);
        assert_eq!(out, vec![frame(0x714, &[0x00])]);
        assert!(sim.is_configured());
        assert_eq!(sim.nmt_state(), NmtState::PreOperational);
        // 0x1018 carries the LSS identity.
        assert_eq!(
            sim.get(ObjectAddress::new(0x1018, 4)),
            Some(&Value::Unsigned32(0xCAFE))
        );
        // Reset node: the stored id, boots again as 20.
        let out = sim.on_frame(&frame(0x000, &[0x81, 20]), 3 * MS);
        assert_eq!(out, vec![frame(0x714, &[0x00])]);
    }

    #[test]
    fn an_id_not_stored_is_lost_with_reset_node_and_moved_with_reset_communication() {
        let mut sim = unconfigured();
        sim.start(Duration::ZERO);
        lss(&mut sim, LssCommand::SwitchSelective(ID)).0.unwrap();
        lss(&mut sim, LssCommand::ConfigureNodeId(20)).0.unwrap();
        sim.on_frame(&request_frame(0x04, &[0]), MS);
        assert_eq!(sim.node_id().get(), 20);
        // Configured: a new pending id moves with reset communication.
        lss(&mut sim, LssCommand::SwitchSelective(ID)).0.unwrap();
        lss(&mut sim, LssCommand::ConfigureNodeId(21)).0.unwrap();
        assert!(sim.on_frame(&request_frame(0x04, &[0]), MS).is_empty());
        let out = sim.on_frame(&frame(0x000, &[0x82, 20]), 2 * MS);
        assert_eq!(out, vec![frame(0x715, &[0x00])]);
        // Nothing stored: reset node leaves it without an id.
        assert!(sim.on_frame(&frame(0x000, &[0x81, 0]), 3 * MS).is_empty());
        assert!(!sim.is_configured());
    }
}
