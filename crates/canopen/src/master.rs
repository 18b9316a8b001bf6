//! The CANopen master of one bus, as one sans-IO state machine: SDO clients
//! for every node (one transfer at a time per node, queued; different nodes
//! concurrently), the heartbeat consumer, the EMCY consumer and the SYNC
//! producer.
//!
//! The runner feeds it every received frame and ticks it at
//! [`Master::next_deadline`]; it answers with frames to send and events.

use crate::emcy::{EmcyConsumer, EmcyEvent};
use crate::heartbeat::{HeartbeatConsumer, HeartbeatEvent};
use crate::ids::{CobFunction, NodeId, ObjectAddress};
use crate::sdo::{Progress, SdoClient, SdoError, StartError, TransferOptions, TransferOutcome};
use crate::sync::SyncProducer;
use cangate_can::Frame;
use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

/// Identifies one SDO request of the application.
pub type RequestId = u64;

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
    running: Option<RequestId>,
    queue: VecDeque<(RequestId, SdoRequest)>,
}

/// The master of one bus.
#[derive(Debug)]
pub struct Master {
    sdo: BTreeMap<NodeId, NodeSdo>,
    sdo_timeout: Duration,
    heartbeat: HeartbeatConsumer,
    emcy: EmcyConsumer,
    sync: Option<SyncProducer>,
}

impl Master {
    /// A master whose SDO requests time out after `sdo_timeout` by default.
    pub fn new(sdo_timeout: Duration) -> Self {
        Master {
            sdo: BTreeMap::new(),
            sdo_timeout,
            heartbeat: HeartbeatConsumer::new(),
            emcy: EmcyConsumer::default(),
            sync: None,
        }
    }

    /// Monitors a node's heartbeat with a consumer timeout.
    pub fn monitor_heartbeat(&mut self, node: NodeId, timeout: Duration) {
        self.heartbeat.monitor(node, timeout);
    }

    /// Starts producing SYNC.
    pub fn start_sync(&mut self, mut producer: SyncProducer, now: Duration) {
        producer.start(now);
        self.sync = Some(producer);
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
            queue: VecDeque::new(),
        })
    }

    /// Queues an SDO request; it starts at once if the node's channel is idle.
    pub fn sdo(
        &mut self,
        id: RequestId,
        node: NodeId,
        req: SdoRequest,
        now: Duration,
        out: &mut Output,
    ) {
        let n = self.node_sdo(node);
        n.queue.push_back((id, req));
        Self::start_next(n, now, out);
    }

    fn start_next(n: &mut NodeSdo, now: Duration, out: &mut Output) {
        while n.running.is_none() {
            let Some((id, req)) = n.queue.pop_front() else {
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
                    n.running = Some(id);
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
            n.queue.retain(|(q, _)| *q != id);
            if n.running == Some(id) {
                let step = n.client.cancel(crate::sdo::AbortCode::GENERAL_ERROR);
                out.frames.extend(step.frames);
                n.running = None;
                Self::start_next(n, now, out);
            }
        }
    }

    /// Progress of a running request.
    pub fn progress(&self, id: RequestId) -> Option<Progress> {
        self.sdo
            .values()
            .find(|n| n.running == Some(id))
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
        match CobFunction::classify(frame.raw_id() as u16) {
            CobFunction::SdoTx(node) => {
                if let Some(n) = self.sdo.get_mut(&node) {
                    let step = n.client.on_frame(frame, now);
                    Self::finish_step(node, n, step, now, out);
                }
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

    fn finish_step(
        node: NodeId,
        n: &mut NodeSdo,
        step: crate::sdo::Step,
        now: Duration,
        out: &mut Output,
    ) {
        out.frames.extend(step.frames);
        if let Some(result) = step.completed {
            if let Some(id) = n.running.take() {
                out.events
                    .push(MasterEvent::SdoCompleted { id, node, result });
            }
            Self::start_next(n, now, out);
        }
    }

    /// Advances time: SDO timeouts, heartbeat losses, SYNC.
    pub fn on_tick(&mut self, now: Duration, out: &mut Output) {
        for (&node, n) in self.sdo.iter_mut() {
            if n.client.next_deadline().is_some_and(|d| d <= now) {
                let step = n.client.on_tick(now);
                Self::finish_step(node, n, step, now, out);
            }
        }
        out.events.extend(
            self.heartbeat
                .on_tick(now)
                .into_iter()
                .map(MasterEvent::Heartbeat),
        );
        if let Some(sync) = self.sync.as_mut()
            && let Some(f) = sync.on_tick(now)
        {
            out.frames.push(f);
        }
    }

    /// When [`Master::on_tick`] next has something to do.
    pub fn next_deadline(&self) -> Option<Duration> {
        self.sdo
            .values()
            .filter_map(|n| n.client.next_deadline())
            .chain(self.heartbeat.next_deadline())
            .chain(self.sync.as_ref().and_then(|s| s.next_deadline()))
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
        m.sdo(1, node(2), upload(0x1000), t, &mut out);
        m.sdo(2, node(2), upload(0x1017), t, &mut out);
        m.sdo(3, node(3), upload(0x1000), t, &mut out);
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

    #[test]
    fn sdo_timeout_with_virtual_time() {
        let mut m = Master::new(Duration::from_millis(500));
        let mut out = Output::default();
        m.sdo(7, node(9), upload(0x1000), Duration::ZERO, &mut out);
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
    fn cancel_aborts_running_and_starts_next() {
        let mut m = Master::new(Duration::from_millis(500));
        let mut out = Output::default();
        m.sdo(1, node(2), upload(0x1000), Duration::ZERO, &mut out);
        m.sdo(2, node(2), upload(0x1017), Duration::ZERO, &mut out);
        let mut out = Output::default();
        m.cancel(1, Duration::ZERO, &mut out);
        assert_eq!(out.frames[0].data()[0], 0x80);
        assert_eq!(out.frames[1].data()[..4], [0x40, 0x17, 0x10, 0x00]);
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
}
