//! Heartbeat consumer (CiA 301 §7.2.8.3.2) for many nodes, and the
//! master's own heartbeat producer ([`HeartbeatProducer`]).
//!
//! Every heartbeat or boot-up frame (0x700+n) updates the node's NMT state
//! and last-seen time. Nodes with a consumer heartbeat time (object 0x1016)
//! are additionally monitored: as in CiA 301, monitoring of a node starts
//! with its first heartbeat, and when no further heartbeat arrives within the
//! timeout the node is reported lost exactly once, then recovered on its next
//! heartbeat. Nodes without a timeout are tracked but never lost.
//!
//! A boot-up message (`[0x00]`) means the node has entered pre-operational:
//! the consumer records it as [`NmtState::PreOperational`].
//!
//! Node guarding (master RTR to 0x700+n, reply `[toggle | state]`, guard
//! time × life time factor) is [`crate::node_guarding`]; the master routes a
//! guarded node's 0x700+n frames there instead. Seen here, guarding replies
//! with bit 7 set and RTR frames are reported as [`HeartbeatEvent::Malformed`].

use std::collections::BTreeMap;
use std::time::Duration;

use cangate_can::{Frame, FrameKind};

use crate::ids::{CobFunction, NodeId};
use crate::nmt::NmtState;

/// Why a 0x700+n frame is not a valid heartbeat.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MalformedHeartbeat {
    /// A remote frame (node-guarding request).
    Remote,
    /// A data length other than 1.
    Length(usize),
    /// A state byte that is no NMT state.
    UnknownState(u8),
}

/// What the consumer observed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum HeartbeatEvent {
    /// A boot-up message (0x700+n `[0x00]`).
    BootUp {
        /// The node.
        node: NodeId,
    },
    /// The node reported a different state (`from` is `None` the first time
    /// the node is heard).
    StateChanged {
        /// The node.
        node: NodeId,
        /// The previous state, if known.
        from: Option<NmtState>,
        /// The new state.
        to: NmtState,
    },
    /// No heartbeat within the consumer timeout. Reported once per loss.
    HeartbeatLost {
        /// The node.
        node: NodeId,
        /// When its last heartbeat arrived.
        last_seen: Duration,
        /// The configured consumer timeout.
        timeout: Duration,
    },
    /// A heartbeat from a node that was lost.
    HeartbeatRecovered {
        /// The node.
        node: NodeId,
        /// The state it reported.
        state: NmtState,
        /// How long it was silent (now − last heartbeat before the loss).
        after: Duration,
    },
    /// A 0x700+n frame that is no valid heartbeat; it does not count as a
    /// sign of life.
    Malformed {
        /// The node.
        node: NodeId,
        /// The payload (empty for a remote frame).
        data: Vec<u8>,
        /// What is wrong with it.
        reason: MalformedHeartbeat,
    },
}

/// What the consumer knows about one node.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct NodeStatus {
    /// The last reported state (boot-up is recorded as pre-operational).
    pub state: Option<NmtState>,
    /// When the last valid heartbeat or boot-up arrived.
    pub last_seen: Option<Duration>,
    /// Consumer timeout; `None` = not monitored.
    pub timeout: Option<Duration>,
    /// True between a loss and the next heartbeat.
    pub lost: bool,
    /// Boot-up messages received.
    pub boot_ups: u64,
    /// Malformed heartbeat frames received.
    pub malformed: u64,
}

impl NodeStatus {
    /// Time since the last heartbeat.
    pub fn age(&self, now: Duration) -> Option<Duration> {
        self.last_seen.map(|t| now.saturating_sub(t))
    }

    fn deadline(&self) -> Option<Duration> {
        if self.lost {
            return None;
        }
        Some(self.last_seen?.saturating_add(self.timeout?))
    }
}

/// Heartbeat consumer for any number of nodes.
#[derive(Debug, Clone, Default)]
pub struct HeartbeatConsumer {
    nodes: BTreeMap<NodeId, NodeStatus>,
    malformed: u64,
}

impl HeartbeatConsumer {
    /// A consumer that monitors no node yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Monitors `node` with a consumer timeout; a zero timeout stops
    /// monitoring (as 0 in object 0x1016 does).
    pub fn monitor(&mut self, node: NodeId, timeout: Duration) {
        let st = self.nodes.entry(node).or_default();
        if timeout.is_zero() {
            st.timeout = None;
            st.lost = false;
        } else {
            st.timeout = Some(timeout);
        }
    }

    /// Stops monitoring `node` (it stays tracked).
    pub fn unmonitor(&mut self, node: NodeId) {
        self.monitor(node, Duration::ZERO);
    }

    /// Decodes an object 0x1016 sub-entry (bits 16..=23 node id, bits 0..=15
    /// time in ms); `None` when the entry is unused (node 0 or > 127, or time
    /// 0).
    pub fn parse_od_entry(value: u32) -> Option<(NodeId, Duration)> {
        let node = NodeId::new((value >> 16) & 0xFF).ok()?;
        let ms = value & 0xFFFF;
        (ms != 0).then(|| (node, Duration::from_millis(u64::from(ms))))
    }

    /// Handles a received frame; frames other than 0x700+n are ignored.
    pub fn on_frame(&mut self, frame: &Frame, now: Duration) -> Vec<HeartbeatEvent> {
        let mut events = Vec::new();
        if frame.kind() == FrameKind::Error || frame.is_extended() {
            return events;
        }
        let CobFunction::Heartbeat(node) = CobFunction::classify(frame.raw_id() as u16) else {
            return events;
        };
        // A heartbeat arriving after the deadline is late even if no tick ran
        // in between: report the loss first so results do not depend on
        // call order.
        self.expire(node, now, &mut events);
        let st = self.nodes.entry(node).or_default();
        let data = frame.data();
        let parsed = match data {
            _ if frame.is_remote() => Err(MalformedHeartbeat::Remote),
            &[b] => NmtState::from_byte(b).ok_or(MalformedHeartbeat::UnknownState(b)),
            _ => Err(MalformedHeartbeat::Length(data.len())),
        };
        let reported = match parsed {
            Ok(s) => s,
            Err(reason) => {
                st.malformed += 1;
                self.malformed += 1;
                events.push(HeartbeatEvent::Malformed {
                    node,
                    data: data.to_vec(),
                    reason,
                });
                return events;
            }
        };
        let boot_up = reported == NmtState::Initialising;
        let to = if boot_up {
            NmtState::PreOperational
        } else {
            reported
        };
        if st.lost {
            st.lost = false;
            let after = st.age(now).unwrap_or_default();
            events.push(HeartbeatEvent::HeartbeatRecovered {
                node,
                state: to,
                after,
            });
        }
        if boot_up {
            st.boot_ups += 1;
            events.push(HeartbeatEvent::BootUp { node });
        }
        if st.state != Some(to) {
            events.push(HeartbeatEvent::StateChanged {
                node,
                from: st.state,
                to,
            });
            st.state = Some(to);
        }
        st.last_seen = Some(now);
        events
    }

    /// Reports every monitored node whose timeout has expired at `now`
    /// (deadline = last heartbeat + timeout, inclusive).
    pub fn on_tick(&mut self, now: Duration) -> Vec<HeartbeatEvent> {
        let due: Vec<NodeId> = self
            .nodes
            .iter()
            .filter(|(_, st)| st.deadline().is_some_and(|d| now >= d))
            .map(|(&n, _)| n)
            .collect();
        let mut events = Vec::new();
        for node in due {
            self.expire(node, now, &mut events);
        }
        events
    }

    /// The earliest time at which a monitored node would be lost.
    pub fn next_deadline(&self) -> Option<Duration> {
        self.nodes.values().filter_map(NodeStatus::deadline).min()
    }

    /// Everything known about `node`.
    pub fn status(&self, node: NodeId) -> Option<&NodeStatus> {
        self.nodes.get(&node)
    }

    /// All tracked nodes, by node id.
    pub fn nodes(&self) -> impl Iterator<Item = (NodeId, &NodeStatus)> {
        self.nodes.iter().map(|(&n, st)| (n, st))
    }

    /// The node's last reported state.
    pub fn state(&self, node: NodeId) -> Option<NmtState> {
        self.status(node)?.state
    }

    /// When the node's last valid heartbeat arrived.
    pub fn last_seen(&self, node: NodeId) -> Option<Duration> {
        self.status(node)?.last_seen
    }

    /// Time since the node's last valid heartbeat.
    pub fn age(&self, node: NodeId, now: Duration) -> Option<Duration> {
        self.status(node)?.age(now)
    }

    /// True while the node is lost.
    pub fn is_lost(&self, node: NodeId) -> bool {
        self.status(node).is_some_and(|st| st.lost)
    }

    /// Malformed heartbeat frames received from all nodes.
    pub fn malformed_total(&self) -> u64 {
        self.malformed
    }

    fn expire(&mut self, node: NodeId, now: Duration, events: &mut Vec<HeartbeatEvent>) {
        let Some(st) = self.nodes.get_mut(&node) else {
            return;
        };
        if let (Some(last_seen), Some(timeout), Some(deadline)) =
            (st.last_seen, st.timeout, st.deadline())
            && now >= deadline
        {
            st.lost = true;
            events.push(HeartbeatEvent::HeartbeatLost {
                node,
                last_seen,
                timeout,
            });
        }
    }
}

/// A heartbeat producer (CiA 301 §7.2.8.3.2.1) for a node the application
/// itself is, e.g. the master: one `0x700 + node [state]` frame every
/// period, the first at once. Devices that consume it (0x1016) stop when it
/// stops, so it must come from the same place as the rest of the master's
/// work: if that place hangs, the heartbeat stops too.
///
/// Each frame is due one period after the previous one was due (no drift);
/// after a stall longer than a period the next is due at once and the
/// schedule restarts from then (no burst of missed frames).
#[derive(Debug, Clone)]
pub struct HeartbeatProducer {
    node: NodeId,
    period: Duration,
    state: NmtState,
    next: Option<Duration>,
    sent: u64,
}

impl HeartbeatProducer {
    /// Produces the heartbeat of `node` every `period` (at least 1 ms),
    /// reporting [`NmtState::Operational`].
    pub fn new(node: NodeId, period: Duration) -> Self {
        HeartbeatProducer {
            node,
            period: period.max(Duration::from_millis(1)),
            state: NmtState::Operational,
            next: None,
            sent: 0,
        }
    }

    /// The producing node.
    pub fn node(&self) -> NodeId {
        self.node
    }

    /// The period.
    pub fn period(&self) -> Duration {
        self.period
    }

    /// Sets the state the next heartbeats report.
    pub fn set_state(&mut self, state: NmtState) {
        self.state = state;
    }

    /// Heartbeats produced so far.
    pub fn sent(&self) -> u64 {
        self.sent
    }

    /// When [`HeartbeatProducer::on_tick`] produces the next frame; `None`
    /// before the first tick (due at once).
    pub fn next_deadline(&self) -> Option<Duration> {
        self.next
    }

    /// The heartbeat frame when one is due at `now`.
    pub fn on_tick(&mut self, now: Duration) -> Option<Frame> {
        let due = self.next.unwrap_or(now);
        if now < due {
            return None;
        }
        let after = due + self.period;
        self.next = Some(if after <= now {
            now + self.period
        } else {
            after
        });
        self.sent += 1;
        Some(crate::nmt::heartbeat_frame(self.node, self.state))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cangate_can::CanId;
    use proptest::prelude::*;

    const MS: Duration = Duration::from_millis(1);

    fn n(id: u32) -> NodeId {
        NodeId::new(id).unwrap()
    }

    fn hb(node: u16, data: &[u8]) -> Frame {
        Frame::new(CanId::Standard(0x700 + node), data).unwrap()
    }

    #[test]
    fn boot_up_detection() {
        let mut c = HeartbeatConsumer::new();
        let ev = c.on_frame(&hb(5, &[0x00]), 10 * MS);
        assert_eq!(
            ev,
            vec![
                HeartbeatEvent::BootUp { node: n(5) },
                HeartbeatEvent::StateChanged {
                    node: n(5),
                    from: None,
                    to: NmtState::PreOperational
                },
            ]
        );
        assert_eq!(c.state(n(5)), Some(NmtState::PreOperational));
        assert_eq!(c.status(n(5)).unwrap().boot_ups, 1);
        // The first pre-operational heartbeat after boot-up is no change.
        assert!(c.on_frame(&hb(5, &[0x7F]), 20 * MS).is_empty());
        // Re-boot from operational.
        c.on_frame(&hb(5, &[0x05]), 30 * MS);
        let ev = c.on_frame(&hb(5, &[0x00]), 40 * MS);
        assert_eq!(ev[0], HeartbeatEvent::BootUp { node: n(5) });
        assert_eq!(
            ev[1],
            HeartbeatEvent::StateChanged {
                node: n(5),
                from: Some(NmtState::Operational),
                to: NmtState::PreOperational
            }
        );
    }

    #[test]
    fn state_changes_and_age() {
        let mut c = HeartbeatConsumer::new();
        assert_eq!(
            c.on_frame(&hb(3, &[0x7F]), MS),
            vec![HeartbeatEvent::StateChanged {
                node: n(3),
                from: None,
                to: NmtState::PreOperational
            }]
        );
        assert!(c.on_frame(&hb(3, &[0x7F]), 2 * MS).is_empty());
        assert_eq!(
            c.on_frame(&hb(3, &[0x05]), 3 * MS),
            vec![HeartbeatEvent::StateChanged {
                node: n(3),
                from: Some(NmtState::PreOperational),
                to: NmtState::Operational
            }]
        );
        assert_eq!(
            c.on_frame(&hb(3, &[0x04]), 4 * MS),
            vec![HeartbeatEvent::StateChanged {
                node: n(3),
                from: Some(NmtState::Operational),
                to: NmtState::Stopped
            }]
        );
        assert_eq!(c.last_seen(n(3)), Some(4 * MS));
        assert_eq!(c.age(n(3), 10 * MS), Some(6 * MS));
        assert_eq!(c.state(n(4)), None);
        // Not monitored: never lost, no deadline.
        assert_eq!(c.next_deadline(), None);
        assert!(c.on_tick(Duration::from_secs(100)).is_empty());
        assert!(!c.is_lost(n(3)));
        // Other COB-IDs are ignored.
        assert!(
            c.on_frame(&Frame::new(CanId::Standard(0x185), &[0]).unwrap(), MS)
                .is_empty()
        );
        assert!(
            c.on_frame(&Frame::new(CanId::Extended(0x705), &[0]).unwrap(), MS)
                .is_empty()
        );
        assert!(c.on_frame(&hb(0, &[0x05]), MS).is_empty());
    }

    #[test]
    fn loss_and_recovery() {
        let mut c = HeartbeatConsumer::new();
        c.monitor(n(7), 150 * MS);
        // Monitoring starts with the first heartbeat.
        assert_eq!(c.next_deadline(), None);
        assert!(c.on_tick(Duration::from_secs(10)).is_empty());
        let t0 = Duration::from_secs(10);
        c.on_frame(&hb(7, &[0x05]), t0);
        assert_eq!(c.next_deadline(), Some(t0 + 150 * MS));
        // Heartbeats every 100 ms keep it alive.
        for k in 1..=5u32 {
            assert!(c.on_tick(t0 + k * 100 * MS - MS).is_empty());
            assert!(c.on_frame(&hb(7, &[0x05]), t0 + k * 100 * MS).is_empty());
        }
        let last = t0 + 500 * MS;
        assert!(c.on_tick(last + 149 * MS).is_empty());
        let lost = HeartbeatEvent::HeartbeatLost {
            node: n(7),
            last_seen: last,
            timeout: 150 * MS,
        };
        assert_eq!(c.on_tick(last + 150 * MS), vec![lost]);
        assert!(c.is_lost(n(7)));
        assert_eq!(c.next_deadline(), None);
        // Not repeated on later ticks.
        for k in 1..=50u32 {
            assert!(c.on_tick(last + 150 * MS + k * 10 * MS).is_empty());
        }
        let ev = c.on_frame(&hb(7, &[0x05]), last + Duration::from_secs(2));
        assert_eq!(
            ev,
            vec![HeartbeatEvent::HeartbeatRecovered {
                node: n(7),
                state: NmtState::Operational,
                after: Duration::from_secs(2)
            }]
        );
        assert!(!c.is_lost(n(7)));
        assert_eq!(
            c.next_deadline(),
            Some(last + Duration::from_secs(2) + 150 * MS)
        );
    }

    #[test]
    fn late_heartbeat_without_tick_reports_loss_then_recovery() {
        let mut c = HeartbeatConsumer::new();
        c.monitor(n(2), 100 * MS);
        c.on_frame(&hb(2, &[0x7F]), Duration::ZERO);
        let ev = c.on_frame(&hb(2, &[0x00]), 300 * MS);
        assert_eq!(
            ev,
            vec![
                HeartbeatEvent::HeartbeatLost {
                    node: n(2),
                    last_seen: Duration::ZERO,
                    timeout: 100 * MS
                },
                HeartbeatEvent::HeartbeatRecovered {
                    node: n(2),
                    state: NmtState::PreOperational,
                    after: 300 * MS
                },
                HeartbeatEvent::BootUp { node: n(2) },
            ]
        );
    }

    #[test]
    fn many_nodes_and_deadlines() {
        let mut c = HeartbeatConsumer::new();
        c.monitor(n(1), 100 * MS);
        c.monitor(n(2), 300 * MS);
        c.on_frame(&hb(1, &[0x05]), Duration::ZERO);
        c.on_frame(&hb(2, &[0x05]), Duration::ZERO);
        c.on_frame(&hb(3, &[0x05]), Duration::ZERO);
        assert_eq!(c.next_deadline(), Some(100 * MS));
        assert_eq!(c.on_tick(100 * MS).len(), 1);
        assert_eq!(c.next_deadline(), Some(300 * MS));
        c.unmonitor(n(2));
        assert_eq!(c.next_deadline(), None);
        assert!(c.on_tick(Duration::from_secs(1)).is_empty());
        assert_eq!(c.nodes().count(), 3);
    }

    #[test]
    fn od_entry_parsing() {
        assert_eq!(
            HeartbeatConsumer::parse_od_entry(0x0005_00C8),
            Some((n(5), 200 * MS))
        );
        assert_eq!(HeartbeatConsumer::parse_od_entry(0x0005_0000), None);
        assert_eq!(HeartbeatConsumer::parse_od_entry(0x0000_00C8), None);
        assert_eq!(HeartbeatConsumer::parse_od_entry(0x0080_00C8), None);
    }

    #[test]
    fn malformed_heartbeats_are_counted() {
        let mut c = HeartbeatConsumer::new();
        c.monitor(n(4), 100 * MS);
        c.on_frame(&hb(4, &[0x05]), Duration::ZERO);
        let cases: Vec<(Frame, MalformedHeartbeat)> = vec![
            (hb(4, &[]), MalformedHeartbeat::Length(0)),
            (hb(4, &[0x05, 0x00]), MalformedHeartbeat::Length(2)),
            (hb(4, &[0x85]), MalformedHeartbeat::UnknownState(0x85)),
            (hb(4, &[0x01]), MalformedHeartbeat::UnknownState(0x01)),
            (
                Frame::new_remote(CanId::Standard(0x704), 1).unwrap(),
                MalformedHeartbeat::Remote,
            ),
        ];
        for (i, (f, reason)) in cases.iter().enumerate() {
            let ev = c.on_frame(f, MS * (10 + i as u32));
            assert_eq!(
                ev,
                vec![HeartbeatEvent::Malformed {
                    node: n(4),
                    data: f.data().to_vec(),
                    reason: *reason
                }]
            );
        }
        assert_eq!(c.status(n(4)).unwrap().malformed, 5);
        assert_eq!(c.malformed_total(), 5);
        // Malformed frames are no sign of life and do not change the state.
        assert_eq!(c.state(n(4)), Some(NmtState::Operational));
        assert_eq!(c.last_seen(n(4)), Some(Duration::ZERO));
        assert_eq!(c.on_tick(100 * MS).len(), 1);
    }

    proptest! {
        #[test]
        fn random_frames_never_panic(
            frames in proptest::collection::vec(
                (0u32..0x800, any::<bool>(), any::<bool>(),
                 proptest::collection::vec(any::<u8>(), 0..=8), 0u64..200),
                0..64,
            )
        ) {
            let mut c = HeartbeatConsumer::new();
            for node in 1..=127 {
                c.monitor(n(node), Duration::from_millis(u64::from(node)));
            }
            let mut now = Duration::ZERO;
            for (id, extended, remote, data, dt) in frames {
                now += Duration::from_millis(dt);
                let cid = if extended { CanId::Extended(id) } else { CanId::Standard(id as u16) };
                let frame = if remote {
                    Frame::new_remote(cid, data.len() as u8).unwrap()
                } else {
                    Frame::new(cid, &data).unwrap()
                };
                let _ = c.on_frame(&frame, now);
                let _ = c.on_tick(now);
                if let Some(d) = c.next_deadline() {
                    prop_assert!(d > now);
                }
            }
        }
    }

    #[test]
    fn producer_sends_at_once_then_every_period_without_drift_or_bursts() {
        let mut p = HeartbeatProducer::new(n(127), 100 * MS);
        let f = p.on_tick(Duration::ZERO).unwrap();
        assert_eq!((f.raw_id(), f.data()), (0x77F, &[0x05][..]));
        assert_eq!(p.next_deadline(), Some(100 * MS));
        assert!(p.on_tick(99 * MS).is_none());
        // Late by 30 ms: sent, and the next stays on the 100 ms grid.
        assert!(p.on_tick(130 * MS).is_some());
        assert_eq!(p.next_deadline(), Some(200 * MS));
        // A stall of a second: one frame, then every period from now.
        assert!(p.on_tick(1250 * MS).is_some());
        assert!(p.on_tick(1250 * MS).is_none());
        assert_eq!(p.next_deadline(), Some(1350 * MS));
        p.set_state(NmtState::PreOperational);
        assert_eq!(p.on_tick(1350 * MS).unwrap().data(), [0x7F]);
        assert_eq!(p.sent(), 4);
    }

    #[test]
    fn producer_feeds_a_consumer_that_never_times_out() {
        let mut p = HeartbeatProducer::new(n(127), 100 * MS);
        let mut c = HeartbeatConsumer::new();
        c.monitor(n(127), 300 * MS);
        let mut now = Duration::ZERO;
        while now < 10_000 * MS {
            if let Some(f) = p.on_tick(now) {
                assert!(
                    c.on_frame(&f, now)
                        .iter()
                        .all(|e| !matches!(e, HeartbeatEvent::HeartbeatLost { .. }))
                );
            }
            assert!(c.on_tick(now).is_empty());
            now = p.next_deadline().unwrap();
        }
        assert!(!c.is_lost(n(127)));
    }
}
