//! The CANopen master of one bus, as one sans-IO state machine: SDO clients
//! for every node (one transfer at a time per node, queued; different nodes
//! concurrently), the heartbeat consumer, node guarding (for nodes guarded
//! instead of producing a heartbeat), the EMCY consumer and the LSS master
//! (CiA 305, see [`crate::lss`]): one LSS command at a time, its answers
//! (0x7E4) taken here like SDO responses. SYNC is produced elsewhere (by
//! the runner, with [`crate::sync::SyncProducer`]), on its own clock.
//!
//! The runner feeds it every received frame and ticks it at
//! [`Master::next_deadline`]; it answers with frames to send and events.
//!
//! Each node's SDO channel has two queues: the gateway's own transfers
//! (boot procedure, process data by SDO) go before those of API clients.
//! A client transfer that is running when a gateway transfer arrives is
//! not interrupted while the node answers, but from then on it waits at
//! most the master's default SDO timeout for each answer: a client cannot
//! hold a silent node's channel with a long timeout while the gateway
//! needs it. After a transfer the client side aborted (timeout, protocol
//! violation, cancel), the channel stays quiet for the SDO client's settle
//! time (see [`SdoClient::ready_at`]) before the next transfer starts.

use crate::emcy::{EmcyConsumer, EmcyEvent};
use crate::heartbeat::{HeartbeatConsumer, HeartbeatEvent};
use crate::ids::{CobFunction, NodeId, ObjectAddress};
use crate::lss::{LSS_RESPONSE_COB_ID, LssCommand, LssError, LssMaster, LssOutcome, LssStep};
use crate::nmt::NmtState;
use crate::node_guarding::{GuardingEvent, NodeGuarding};
use crate::sdo::{Progress, SdoClient, SdoError, StartError, TransferOptions, TransferOutcome};
use cangate_can::Frame;
use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

/// Identifies one SDO request of the application.
pub type RequestId = u64;

/// Whose SDO transfer it is, which decides its place in the node's queue.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum SdoPriority {
    /// The gateway's own work (boot procedure, axis process data by SDO,
    /// device profiles): served first.
    Gateway,
    /// An API client's request: served when no gateway transfer waits.
    Client,
}

/// An SDO transfer the application asks for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SdoRequest {
    /// Read an object.
    Upload {
        /// The object.
        addr: ObjectAddress,
        /// Protocol and timeout.
        opts: TransferOptions,
    },
    /// Write an object.
    Download {
        /// The object.
        addr: ObjectAddress,
        /// The value's bytes.
        data: Vec<u8>,
        /// Protocol and timeout.
        opts: TransferOptions,
    },
}

/// Something the master observed or finished.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum MasterEvent {
    /// From the heartbeat consumer.
    Heartbeat(HeartbeatEvent),
    /// From node guarding.
    Guarding(GuardingEvent),
    /// From the EMCY consumer.
    Emcy(EmcyEvent),
    /// An SDO request ended.
    SdoCompleted {
        /// The request.
        id: RequestId,
        /// The node.
        node: NodeId,
        /// The outcome.
        result: Result<TransferOutcome, SdoError>,
    },
    /// An SDO request could not start (bad options).
    SdoRejected {
        /// The request.
        id: RequestId,
        /// Why.
        error: StartError,
    },
    /// A response from the node was dropped: a late answer to a transfer
    /// the master had aborted, or one that came while no transfer ran.
    SdoResponseIgnored {
        /// The node.
        node: NodeId,
    },
    /// A state confirmation ([`Master::confirm_state`]) ended: the node
    /// reported operational (at once), or its deadline came with the last
    /// state it reported meanwhile (`None`: it reported nothing).
    /// [`NmtState::Initialising`]: it booted up meanwhile.
    StateConfirmed {
        /// The request.
        id: RequestId,
        /// The node.
        node: NodeId,
        /// What it reported.
        state: Option<NmtState>,
    },
    /// An LSS command ended (or was refused at once: busy, invalid).
    LssCompleted {
        /// The request.
        id: RequestId,
        /// The outcome.
        result: Result<LssOutcome, LssError>,
    },
}

/// Frames to send and events, produced by one input.
#[derive(Debug, Default)]
pub struct Output {
    /// Frames to send, in order.
    pub frames: Vec<Frame>,
    /// Events, in order.
    pub events: Vec<MasterEvent>,
}

#[derive(Debug)]
struct NodeSdo {
    client: SdoClient,
    running: Option<(RequestId, SdoPriority)>,
    /// Waiting requests, the gateway's first.
    gateway_queue: VecDeque<(RequestId, SdoRequest)>,
    client_queue: VecDeque<(RequestId, SdoRequest)>,
}

impl NodeSdo {
    fn queued(&self) -> bool {
        !self.gateway_queue.is_empty() || !self.client_queue.is_empty()
    }
}

/// The master of one bus.
#[derive(Debug)]
pub struct Master {
    sdo: BTreeMap<NodeId, NodeSdo>,
    sdo_timeout: Duration,
    heartbeat: HeartbeatConsumer,
    guarding: NodeGuarding,
    emcy: EmcyConsumer,
    lss: LssMaster,
    /// The request of the running LSS command.
    lss_request: Option<RequestId>,
    /// State confirmations waiting for the node's next report.
    confirms: BTreeMap<RequestId, Confirm>,
}

/// A [`Master::confirm_state`] in progress.
#[derive(Debug, Clone, Copy)]
struct Confirm {
    node: NodeId,
    deadline: Duration,
    /// A guarding request went out whose answer is not yet in: the next
    /// 0x700+n data frame is that answer (toggle bit in bit 7).
    probe_outstanding: bool,
    /// The latest state reported that was not operational.
    last: Option<NmtState>,
}

impl Master {
    /// A master whose SDO requests time out after `sdo_timeout` by default.
    pub fn new(sdo_timeout: Duration) -> Self {
        Master {
            sdo: BTreeMap::new(),
            sdo_timeout,
            heartbeat: HeartbeatConsumer::new(),
            guarding: NodeGuarding::new(),
            emcy: EmcyConsumer::default(),
            lss: LssMaster::new(),
            lss_request: None,
            confirms: BTreeMap::new(),
        }
    }

    /// Waits up to `timeout` for `node` to report its NMT state: the first
    /// report of operational ends it at once; otherwise its deadline ends
    /// it with the last state reported (a report that left the node before
    /// it saw an NMT command just sent is not final). Reports are
    /// heartbeats and node guarding answers; with `probe`, one node
    /// guarding request (a remote frame to 0x700+n) asks a node that sends
    /// no heartbeat and is not guarded, and its answer is taken here, not
    /// by the heartbeat consumer. The end comes as
    /// [`MasterEvent::StateConfirmed`] with `id`.
    ///
    /// A probe starts the node's life guarding when its guard time and
    /// life time factor (0x100C, 0x100D) are both set: probe only nodes
    /// where they are not.
    pub fn confirm_state(
        &mut self,
        id: RequestId,
        node: NodeId,
        probe: bool,
        timeout: Duration,
        now: Duration,
        out: &mut Output,
    ) {
        let probe = probe && !self.guarding.is_guarded(node);
        if probe {
            out.frames.push(NodeGuarding::request_frame(node));
        }
        self.confirms.insert(
            id,
            Confirm {
                node,
                deadline: now + timeout,
                probe_outstanding: probe,
                last: None,
            },
        );
    }

    /// Drops a state confirmation (its caller gave up).
    pub fn confirm_cancel(&mut self, id: RequestId) {
        self.confirms.remove(&id);
    }

    /// Feeds a 0x700+n data frame to the state confirmations of its node;
    /// true when it was the answer to a probe (nobody else takes it).
    fn on_state_report(&mut self, node: NodeId, frame: &Frame, out: &mut Output) -> bool {
        let &[byte] = frame.data() else {
            return false;
        };
        if frame.is_remote() {
            return false;
        }
        let Some(state) = NmtState::from_byte(byte & 0x7F) else {
            return false;
        };
        let mut probe_answer = false;
        let mut done = Vec::new();
        for (&id, c) in self.confirms.iter_mut().filter(|(_, c)| c.node == node) {
            probe_answer |= std::mem::take(&mut c.probe_outstanding);
            if matches!(state, NmtState::Operational | NmtState::Initialising) {
                done.push((id, state));
            } else {
                c.last = Some(state);
            }
        }
        for (id, state) in done {
            self.confirms.remove(&id);
            out.events.push(MasterEvent::StateConfirmed {
                id,
                node,
                state: Some(state),
            });
        }
        probe_answer && byte != 0
    }

    /// Monitors a node's heartbeat with a consumer timeout.
    pub fn monitor_heartbeat(&mut self, node: NodeId, timeout: Duration) {
        self.heartbeat.monitor(node, timeout);
    }

    /// Guards a node (CiA 301 node guarding): an RTR to 0x700+n every
    /// `guard_time`, lost after `life_time_factor` unanswered requests in a
    /// row. The node's 0x700+n frames go to the guarding, not to the
    /// heartbeat consumer (a node uses one or the other).
    pub fn guard_node(&mut self, node: NodeId, guard_time: Duration, life_time_factor: u8) {
        self.heartbeat.unmonitor(node);
        self.guarding.guard(node, guard_time, life_time_factor);
    }

    /// Node guarding (states, toggle errors, losses).
    pub fn guarding(&self) -> &NodeGuarding {
        &self.guarding
    }

    /// The heartbeat consumer (states, ages).
    pub fn heartbeat(&self) -> &HeartbeatConsumer {
        &self.heartbeat
    }

    /// The EMCY consumer (active errors, history).
    pub fn emcy(&self) -> &EmcyConsumer {
        &self.emcy
    }

    fn node_sdo(&mut self, node: NodeId) -> &mut NodeSdo {
        let timeout = self.sdo_timeout;
        self.sdo.entry(node).or_insert_with(|| NodeSdo {
            client: SdoClient::new(node).with_default_timeout(timeout),
            running: None,
            gateway_queue: VecDeque::new(),
            client_queue: VecDeque::new(),
        })
    }

    /// Queues an SDO request of the gateway's own ([`SdoPriority::Gateway`]);
    /// it starts at once if the node's channel is idle (and settled).
    pub fn sdo(
        &mut self,
        id: RequestId,
        node: NodeId,
        req: SdoRequest,
        now: Duration,
        out: &mut Output,
    ) {
        self.sdo_as(id, node, SdoPriority::Gateway, req, now, out);
    }

    /// Queues an SDO request with `priority`; it starts at once if the
    /// node's channel is idle (and settled).
    pub fn sdo_as(
        &mut self,
        id: RequestId,
        node: NodeId,
        priority: SdoPriority,
        req: SdoRequest,
        now: Duration,
        out: &mut Output,
    ) {
        let patience = self.sdo_timeout;
        let n = self.node_sdo(node);
        match priority {
            SdoPriority::Gateway => {
                n.gateway_queue.push_back((id, req));
                if matches!(n.running, Some((_, SdoPriority::Client))) {
                    n.client.limit_timeout(patience);
                }
            }
            SdoPriority::Client => n.client_queue.push_back((id, req)),
        }
        Self::start_next(n, now, out);
    }

    fn start_next(n: &mut NodeSdo, now: Duration, out: &mut Output) {
        if n.client.ready_at().is_some_and(|at| now < at) {
            return;
        }
        while n.running.is_none() {
            let (id, req, priority) = if let Some((id, req)) = n.gateway_queue.pop_front() {
                (id, req, SdoPriority::Gateway)
            } else if let Some((id, req)) = n.client_queue.pop_front() {
                (id, req, SdoPriority::Client)
            } else {
                return;
            };
            let started = match req {
                SdoRequest::Upload { addr, opts } => n.client.start_upload(addr, opts, now),
                SdoRequest::Download { addr, data, opts } => {
                    n.client.start_download(addr, data, opts, now)
                }
            };
            match started {
                Ok(frames) => {
                    n.running = Some((id, priority));
                    out.frames.extend(frames);
                }
                Err(error) => out.events.push(MasterEvent::SdoRejected { id, error }),
            }
        }
    }

    /// Drops a request: removed if queued, aborted (0x08000000 general
    /// error) if running. The caller stops waiting for it.
    pub fn cancel(&mut self, id: RequestId, now: Duration, out: &mut Output) {
        for n in self.sdo.values_mut() {
            n.gateway_queue.retain(|(q, _)| *q != id);
            n.client_queue.retain(|(q, _)| *q != id);
            if n.running.is_some_and(|(r, _)| r == id) {
                let step = n.client.cancel(crate::sdo::AbortCode::GENERAL_ERROR, now);
                out.frames.extend(step.frames);
                n.running = None;
                Self::start_next(n, now, out);
            }
        }
    }

    /// Starts an LSS command (CiA 305, bus-global: one at a time; a second
    /// one completes at once with [`LssError::Busy`]). Its end comes as
    /// [`MasterEvent::LssCompleted`] with `id`.
    pub fn lss(
        &mut self,
        id: RequestId,
        command: LssCommand,
        timeout: Duration,
        now: Duration,
        out: &mut Output,
    ) {
        let busy = self.lss.running().is_some();
        let step = self.lss.start(command, timeout, now);
        if !busy && step.completed.is_none() {
            self.lss_request = Some(id);
        }
        out.frames.extend(step.frames);
        if let Some(result) = step.completed {
            out.events.push(MasterEvent::LssCompleted { id, result });
        }
    }

    /// Drops the running LSS command if it is `id` (its caller gave up).
    pub fn lss_cancel(&mut self, id: RequestId) {
        if self.lss_request == Some(id) {
            self.lss.cancel();
            self.lss_request = None;
        }
    }

    /// The running LSS command's name, if any.
    pub fn lss_running(&self) -> Option<&'static str> {
        self.lss.running()
    }

    fn lss_step(&mut self, step: LssStep, out: &mut Output) {
        out.frames.extend(step.frames);
        if let Some(result) = step.completed
            && let Some(id) = self.lss_request.take()
        {
            out.events.push(MasterEvent::LssCompleted { id, result });
        }
    }

    /// Progress of a running request.
    pub fn progress(&self, id: RequestId) -> Option<Progress> {
        self.sdo
            .values()
            .find(|n| n.running.is_some_and(|(r, _)| r == id))
            .and_then(|n| n.client.progress())
    }

    /// Every running transfer with its progress.
    pub fn transfers(&self) -> Vec<(NodeId, Progress)> {
        self.sdo
            .iter()
            .filter_map(|(&node, n)| n.client.progress().map(|p| (node, p)))
            .collect()
    }

    /// Feeds a received frame.
    pub fn on_frame(&mut self, frame: &Frame, now: Duration, out: &mut Output) {
        if frame.is_extended() || frame.is_fd() || frame.is_error() {
            return;
        }
        if frame.raw_id() == u32::from(LSS_RESPONSE_COB_ID) {
            let step = self.lss.on_frame(frame, now);
            self.lss_step(step, out);
            return;
        }
        match CobFunction::classify(frame.raw_id() as u16) {
            CobFunction::SdoTx(node) => {
                if let Some(n) = self.sdo.get_mut(&node) {
                    let ignored = n.client.ignored_responses();
                    let step = n.client.on_frame(frame, now);
                    if n.client.ignored_responses() != ignored {
                        out.events.push(MasterEvent::SdoResponseIgnored { node });
                    }
                    Self::finish_step(node, n, step, now, out);
                }
            }
            CobFunction::Heartbeat(node) if self.on_state_report(node, frame, out) => {}
            CobFunction::Heartbeat(node) if self.guarding.is_guarded(node) => {
                out.events.extend(
                    self.guarding
                        .on_frame(frame, now)
                        .into_iter()
                        .map(MasterEvent::Guarding),
                );
            }
            CobFunction::Heartbeat(_) => {
                out.events.extend(
                    self.heartbeat
                        .on_frame(frame, now)
                        .into_iter()
                        .map(MasterEvent::Heartbeat),
                );
            }
            CobFunction::Emcy(_) => {
                if let Some(ev) = self.emcy.on_frame(frame, now) {
                    out.events.push(MasterEvent::Emcy(ev));
                }
            }
            _ => {}
        }
    }

    /// One of the master's own frames was given up by the interface (its
    /// transmit queue stayed full past the backend's timeout). An SDO
    /// request ends its transfer at once with [`crate::sdo::SdoError::NotSent`]
    /// rather than after the SDO timeout: the caller learns why, and the
    /// node's channel is free for the next request. Other frames change
    /// nothing here (the bus counts them).
    pub fn on_unsent(&mut self, frame: &Frame, now: Duration, out: &mut Output) {
        if frame.is_extended() || frame.is_fd() || frame.is_error() {
            return;
        }
        if let CobFunction::SdoRx(node) = CobFunction::classify(frame.raw_id() as u16)
            && let Some(n) = self.sdo.get_mut(&node)
        {
            let step = n.client.on_request_unsent(frame.data(), now);
            Self::finish_step(node, n, step, now, out);
        }
    }

    fn finish_step(
        node: NodeId,
        n: &mut NodeSdo,
        step: crate::sdo::Step,
        now: Duration,
        out: &mut Output,
    ) {
        out.frames.extend(step.frames);
        if let Some(result) = step.completed {
            if let Some((id, _)) = n.running.take() {
                out.events
                    .push(MasterEvent::SdoCompleted { id, node, result });
            }
            Self::start_next(n, now, out);
        }
    }

    /// Advances time: SDO timeouts, heartbeat losses, guarding requests and
    /// losses, LSS timeouts.
    pub fn on_tick(&mut self, now: Duration, out: &mut Output) {
        for (&node, n) in self.sdo.iter_mut() {
            let settled = n.client.ready_at().is_some_and(|at| at <= now);
            if settled || n.client.next_deadline().is_some_and(|d| d <= now) {
                let step = n.client.on_tick(now);
                Self::finish_step(node, n, step, now, out);
            }
            if settled && n.running.is_none() {
                Self::start_next(n, now, out);
            }
        }
        out.events.extend(
            self.heartbeat
                .on_tick(now)
                .into_iter()
                .map(MasterEvent::Heartbeat),
        );
        out.events.extend(
            self.guarding
                .on_tick(now, &mut out.frames)
                .into_iter()
                .map(MasterEvent::Guarding),
        );
        if self.lss.next_deadline().is_some_and(|d| d <= now) {
            let step = self.lss.on_tick(now);
            self.lss_step(step, out);
        }
        let due: Vec<RequestId> = self
            .confirms
            .iter()
            .filter(|(_, c)| c.deadline <= now)
            .map(|(&id, _)| id)
            .collect();
        for id in due {
            if let Some(c) = self.confirms.remove(&id) {
                out.events.push(MasterEvent::StateConfirmed {
                    id,
                    node: c.node,
                    state: c.last,
                });
            }
        }
    }

    /// When [`Master::on_tick`] next has something to do.
    pub fn next_deadline(&self) -> Option<Duration> {
        self.sdo
            .values()
            .filter_map(|n| {
                // A settling channel with work waiting must be ticked when
                // it is quiet again.
                let settle = n.client.ready_at().filter(|_| n.queued());
                n.client.next_deadline().into_iter().chain(settle).min()
            })
            .chain(self.heartbeat.next_deadline())
            .chain(self.guarding.next_deadline())
            .chain(self.lss.next_deadline())
            .chain(self.confirms.values().map(|c| c.deadline))
            .min()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cangate_can::CanId;

    fn node(n: u32) -> NodeId {
        NodeId::new(n).unwrap()
    }

    fn frame(id: u16, data: &[u8]) -> Frame {
        Frame::new(CanId::Standard(id), data).unwrap()
    }

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    fn upload(index: u16) -> SdoRequest {
        SdoRequest::Upload {
            addr: ObjectAddress::new(index, 0),
            opts: TransferOptions::default(),
        }
    }

    #[test]
    fn requests_to_one_node_are_queued_and_to_others_concurrent() {
        let mut m = Master::new(Duration::from_millis(500));
        let t = Duration::ZERO;
        let mut out = Output::default();
        m.sdo_as(1, node(2), SdoPriority::Client, upload(0x1000), t, &mut out);
        m.sdo_as(2, node(2), SdoPriority::Client, upload(0x1017), t, &mut out);
        m.sdo_as(3, node(3), SdoPriority::Client, upload(0x1000), t, &mut out);
        // Node 2's second request waits; node 3's starts at once.
        let ids: Vec<u32> = out.frames.iter().map(|f| f.raw_id()).collect();
        assert_eq!(ids, vec![0x602, 0x603]);
        assert_eq!(out.frames[0].data(), &[0x40, 0x00, 0x10, 0, 0, 0, 0, 0]);

        let mut out = Output::default();
        m.on_frame(
            &frame(0x582, &[0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00]),
            t,
            &mut out,
        );
        assert_eq!(
            out.events,
            vec![MasterEvent::SdoCompleted {
                id: 1,
                node: node(2),
                result: Ok(TransferOutcome::Uploaded(vec![0x92, 0x01, 0x02, 0x00]))
            }]
        );
        // The queued request goes out right after.
        assert_eq!(out.frames.len(), 1);
        assert_eq!(out.frames[0].data()[..4], [0x40, 0x17, 0x10, 0x00]);
    }

    fn confirmed(out: &Output) -> Vec<(RequestId, Option<NmtState>)> {
        out.events
            .iter()
            .filter_map(|e| match e {
                MasterEvent::StateConfirmed { id, state, .. } => Some((*id, *state)),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn state_confirmation_by_heartbeat_waits_for_operational_until_its_deadline() {
        let ms = Duration::from_millis;
        let mut m = Master::new(ms(500));
        let mut out = Output::default();
        m.confirm_state(1, node(5), false, ms(300), ms(0), &mut out);
        // No probe for a node that sends heartbeats.
        assert!(out.frames.is_empty());
        assert_eq!(m.next_deadline(), Some(ms(300)));
        // A heartbeat that left before the node saw its NMT start is no
        // verdict; operational ends it at once.
        m.on_frame(&frame(0x705, &[0x7F]), ms(10), &mut out);
        assert!(confirmed(&out).is_empty());
        m.on_frame(&frame(0x705, &[0x05]), ms(110), &mut out);
        assert_eq!(confirmed(&out), [(1, Some(NmtState::Operational))]);
        // The heartbeat consumer saw both.
        assert_eq!(m.heartbeat().state(node(5)), Some(NmtState::Operational));

        // A node that stays pre-operational: the deadline tells.
        let mut out = Output::default();
        m.confirm_state(2, node(6), false, ms(300), ms(0), &mut out);
        m.on_frame(&frame(0x706, &[0x7F]), ms(100), &mut out);
        m.on_frame(&frame(0x706, &[0x7F]), ms(200), &mut out);
        m.on_tick(ms(299), &mut out);
        assert!(confirmed(&out).is_empty());
        m.on_tick(ms(300), &mut out);
        assert_eq!(confirmed(&out), [(2, Some(NmtState::PreOperational))]);
        assert_eq!(m.next_deadline(), None);

        // A silent node: nothing reported.
        let mut out = Output::default();
        m.confirm_state(3, node(7), false, ms(300), ms(0), &mut out);
        m.on_tick(ms(300), &mut out);
        assert_eq!(confirmed(&out), [(3, None)]);
    }

    #[test]
    fn state_probe_asks_by_node_guarding_and_takes_the_answer() {
        let ms = Duration::from_millis;
        let mut m = Master::new(ms(500));
        let mut out = Output::default();
        m.confirm_state(1, node(5), true, ms(500), ms(0), &mut out);
        assert_eq!(out.frames.len(), 1);
        assert!(out.frames[0].is_remote());
        assert_eq!(out.frames[0].raw_id(), 0x705);
        // The answer (toggle bit 0, pre-operational) is the probe's: the
        // heartbeat consumer does not take it for a heartbeat.
        m.on_frame(&frame(0x705, &[0x7F]), ms(2), &mut out);
        assert_eq!(m.heartbeat().state(node(5)), None);
        m.on_tick(ms(500), &mut out);
        assert_eq!(confirmed(&out), [(1, Some(NmtState::PreOperational))]);

        // The next probe's answer carries the toggle bit: operational.
        let mut out = Output::default();
        m.confirm_state(2, node(5), true, ms(500), ms(600), &mut out);
        m.on_frame(&frame(0x705, &[0x85]), ms(601), &mut out);
        assert_eq!(confirmed(&out), [(2, Some(NmtState::Operational))]);
        assert!(
            out.events
                .iter()
                .all(|e| !matches!(e, MasterEvent::Heartbeat(_))),
            "{:?}",
            out.events
        );

        // A guarded node gets no extra request: its guarding answers tell.
        let mut m = Master::new(ms(500));
        m.guard_node(node(9), ms(100), 3);
        let mut out = Output::default();
        m.confirm_state(3, node(9), true, ms(500), ms(0), &mut out);
        assert!(out.frames.is_empty());
        m.on_frame(&frame(0x709, &[0x05]), ms(5), &mut out);
        assert_eq!(confirmed(&out), [(3, Some(NmtState::Operational))]);
    }

    #[test]
    fn sdo_timeout_with_virtual_time() {
        let mut m = Master::new(Duration::from_millis(500));
        let mut out = Output::default();
        m.sdo_as(
            7,
            node(9),
            SdoPriority::Client,
            upload(0x1000),
            Duration::ZERO,
            &mut out,
        );
        assert_eq!(m.next_deadline(), Some(Duration::from_millis(500)));
        let mut out = Output::default();
        m.on_tick(Duration::from_millis(499), &mut out);
        assert!(out.events.is_empty());
        m.on_tick(Duration::from_millis(500), &mut out);
        // Abort 0x05040000 sent, request completed with a timeout.
        assert_eq!(
            out.frames[0].data(),
            &[0x80, 0x00, 0x10, 0x00, 0x00, 0x00, 0x04, 0x05]
        );
        assert!(matches!(
            &out.events[0],
            MasterEvent::SdoCompleted {
                id: 7,
                result: Err(SdoError::Timeout { .. }),
                ..
            }
        ));
    }

    #[test]
    fn an_sdo_request_the_interface_gave_up_ends_its_transfer_at_once() {
        let mut m = Master::new(Duration::from_millis(500));
        let mut out = Output::default();
        m.sdo_as(
            7,
            node(9),
            SdoPriority::Client,
            upload(0x1000),
            ms(0),
            &mut out,
        );
        m.sdo_as(
            8,
            node(9),
            SdoPriority::Client,
            upload(0x1017),
            ms(0),
            &mut out,
        );
        let request = out.frames[0];
        assert_eq!(request.raw_id(), 0x609);
        assert_eq!(request.data()[..4], [0x40, 0x00, 0x10, 0x00]);

        // Another node's request, a heartbeat and a frame that is not the
        // one in flight change nothing.
        let mut out = Output::default();
        m.on_unsent(&frame(0x60A, request.data()), ms(20), &mut out);
        m.on_unsent(&frame(0x709, &[0x05]), ms(20), &mut out);
        m.on_unsent(
            &frame(0x609, &[0x40, 0x17, 0x10, 0, 0, 0, 0, 0]),
            ms(20),
            &mut out,
        );
        assert!(out.frames.is_empty() && out.events.is_empty(), "{out:?}");

        // The initiate itself: the transfer ends now, not at 500 ms, with
        // an abort 0x08000000 in case the server holds a transfer.
        m.on_unsent(&request, ms(20), &mut out);
        assert_eq!(
            out.frames[0].data(),
            &[0x80, 0x00, 0x10, 0x00, 0x00, 0x00, 0x00, 0x08]
        );
        assert!(
            matches!(
                &out.events[..],
                [MasterEvent::SdoCompleted {
                    id: 7,
                    result: Err(SdoError::NotSent { .. }),
                    ..
                }]
            ),
            "{:?}",
            out.events
        );
        // The next request gets the channel once it settled.
        let mut out = Output::default();
        m.on_tick(ms(20) + crate::sdo::DEFAULT_SETTLE_TIME, &mut out);
        assert_eq!(out.frames[0].data()[..4], [0x40, 0x17, 0x10, 0x00]);
        // The first request's frame reported again (late) does not touch it.
        let mut out = Output::default();
        m.on_unsent(&request, ms(200), &mut out);
        assert!(out.events.is_empty(), "{:?}", out.events);
    }

    #[test]
    fn cancel_aborts_running_and_starts_next() {
        let mut m = Master::new(Duration::from_millis(500));
        let mut out = Output::default();
        m.sdo_as(
            1,
            node(2),
            SdoPriority::Client,
            upload(0x1000),
            Duration::ZERO,
            &mut out,
        );
        m.sdo_as(
            2,
            node(2),
            SdoPriority::Client,
            upload(0x1017),
            Duration::ZERO,
            &mut out,
        );
        let mut out = Output::default();
        m.cancel(1, Duration::ZERO, &mut out);
        assert_eq!(out.frames.len(), 1);
        assert_eq!(out.frames[0].data()[0], 0x80);
        // The next request waits for the channel to settle.
        let settle = crate::sdo::DEFAULT_SETTLE_TIME;
        assert_eq!(m.next_deadline(), Some(settle));
        let mut out = Output::default();
        m.on_tick(settle, &mut out);
        assert_eq!(out.frames[0].data()[..4], [0x40, 0x17, 0x10, 0x00]);
    }

    #[test]
    fn heartbeat_and_emcy_are_dispatched() {
        let mut m = Master::new(Duration::from_millis(500));
        m.monitor_heartbeat(node(5), Duration::from_millis(100));
        let mut out = Output::default();
        m.on_frame(&frame(0x705, &[0x00]), Duration::ZERO, &mut out);
        assert!(matches!(
            out.events[0],
            MasterEvent::Heartbeat(HeartbeatEvent::BootUp { .. })
        ));
        let mut out = Output::default();
        m.on_frame(
            &frame(0x085, &[0x10, 0x23, 0x02, 0, 0, 0, 0, 0]),
            Duration::ZERO,
            &mut out,
        );
        assert!(
            matches!(&out.events[0], MasterEvent::Emcy(EmcyEvent::Error(e)) if e.code == 0x2310)
        );
        let mut out = Output::default();
        m.on_tick(Duration::from_millis(100), &mut out);
        assert!(matches!(
            out.events[0],
            MasterEvent::Heartbeat(HeartbeatEvent::HeartbeatLost { .. })
        ));
    }

    #[test]
    fn lss_runs_beside_sdo_one_command_at_a_time() {
        use crate::lss::{LssCommand, LssError, LssOutcome};
        let ms = Duration::from_millis(1);
        let mut m = Master::new(500 * ms);
        let mut out = Output::default();
        m.lss(
            1,
            LssCommand::ConfigureNodeId(20),
            100 * ms,
            Duration::ZERO,
            &mut out,
        );
        assert_eq!(out.frames.len(), 1);
        assert_eq!(out.frames[0].raw_id(), 0x7E5);
        assert_eq!(m.lss_running(), Some("configure node-ID"));
        // A second command is refused at once; the first keeps running.
        m.lss(
            2,
            LssCommand::StoreConfiguration,
            100 * ms,
            Duration::ZERO,
            &mut out,
        );
        assert!(matches!(
            &out.events[..],
            [MasterEvent::LssCompleted {
                id: 2,
                result: Err(LssError::Busy { .. })
            }]
        ));
        // SDO goes on meanwhile.
        let mut out = Output::default();
        m.sdo_as(
            3,
            node(2),
            SdoPriority::Client,
            upload(0x1000),
            ms,
            &mut out,
        );
        assert_eq!(out.frames[0].raw_id(), 0x602);
        assert_eq!(m.next_deadline(), Some(100 * ms));
        let mut out = Output::default();
        m.on_frame(
            &frame(0x7E4, &[0x11, 0, 0, 0, 0, 0, 0, 0]),
            2 * ms,
            &mut out,
        );
        assert_eq!(
            out.events,
            vec![MasterEvent::LssCompleted {
                id: 1,
                result: Ok(LssOutcome::Confirmed)
            }]
        );
        assert_eq!(m.lss_running(), None);
        // A cancelled command frees the master; its late answer is dropped.
        let mut out = Output::default();
        m.lss(
            4,
            LssCommand::StoreConfiguration,
            100 * ms,
            3 * ms,
            &mut out,
        );
        m.lss_cancel(4);
        assert_eq!(m.lss_running(), None);
        let mut out = Output::default();
        m.on_frame(
            &frame(0x7E4, &[0x17, 0, 0, 0, 0, 0, 0, 0]),
            4 * ms,
            &mut out,
        );
        assert!(out.events.is_empty());
    }

    #[test]
    fn guarded_nodes_are_polled_and_their_answers_go_to_the_guarding() {
        let ms = Duration::from_millis(1);
        let mut m = Master::new(500 * ms);
        m.guard_node(node(5), 100 * ms, 2);
        assert_eq!(m.next_deadline(), Some(Duration::ZERO));
        let mut out = Output::default();
        m.on_tick(Duration::ZERO, &mut out);
        assert_eq!(out.frames.len(), 1);
        assert_eq!(out.frames[0].raw_id(), 0x705);
        assert!(out.frames[0].is_remote());
        let mut out = Output::default();
        m.on_frame(&frame(0x705, &[0x05]), ms, &mut out);
        assert_eq!(
            out.events,
            vec![MasterEvent::Guarding(GuardingEvent::StateChanged {
                node: node(5),
                from: None,
                to: crate::nmt::NmtState::Operational
            })]
        );
        // The heartbeat consumer did not see it.
        assert_eq!(m.heartbeat().state(node(5)), None);
        assert_eq!(m.next_deadline(), Some(100 * ms));
        for t in [100, 200] {
            let mut out = Output::default();
            m.on_tick(t * ms, &mut out);
            assert!(out.events.is_empty());
        }
        let mut out = Output::default();
        m.on_tick(300 * ms, &mut out);
        assert!(matches!(
            out.events[..],
            [MasterEvent::Guarding(GuardingEvent::Lost { .. })]
        ));
    }
}
