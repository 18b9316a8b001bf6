//! Node guarding, master side (CiA 301 §7.2.8.3.1): the alternative to the
//! heartbeat for nodes that do not produce one.
//!
//! Every guard time the master sends a remote frame (RTR, DLC 1) to
//! 0x700+n; the node answers `[toggle << 7 | state]`: bits 0..=6 its NMT
//! state (4 stopped, 5 operational, 127 pre-operational), bit 7 a toggle
//! bit that starts at 0 after the node's boot-up and alternates with every
//! answer.
//!
//! - A request still unanswered when the next one is due is a missed
//!   answer. After *life time factor* missed answers in a row — the node
//!   life time (guard time × life time factor) counted from the first
//!   unanswered request, without a valid answer — the node is reported lost
//!   ([`GuardingEvent::Lost`]), once; polling goes on, and its next answer
//!   reports it recovered ([`GuardingEvent::Recovered`]).
//! - An answer with the wrong toggle bit is reported
//!   ([`GuardingEvent::ToggleError`]), counted and not accepted as a sign of
//!   life (the request stays unanswered); the expected toggle follows the
//!   received one, so a single slip is one error, not an error on every
//!   answer from then on. The first answer after a loss is accepted with
//!   either toggle (the node may have reset meanwhile).
//! - A boot-up message (`[0x00]`) resets the expected toggle to 0 and
//!   records the node as pre-operational; it is no answer to a request.
//! - Remote frames on 0x700+n (the master's own requests, looped back) are
//!   ignored.
//!
//! The guarding is a sans-IO state machine like the rest of the crate:
//! [`NodeGuarding::on_tick`] returns the requests to send,
//! [`NodeGuarding::next_deadline`] says when it must run next.
//!
//! Life guarding (the node watching the master's requests) is the node's
//! business and not part of this module.

use std::collections::BTreeMap;
use std::time::Duration;

use cangate_can::{CanId, Frame, FrameKind};

use crate::ids::{CobFunction, NodeId};
use crate::nmt::NmtState;

/// What the guarding of a node observed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum GuardingEvent {
    /// A boot-up message (0x700+n `[0x00]`): the toggle restarts at 0.
    BootUp {
        /// The node.
        node: NodeId,
    },
    /// The node reported a different state (`from` is `None` the first
    /// time).
    StateChanged {
        /// The node.
        node: NodeId,
        /// The previous state, if known.
        from: Option<NmtState>,
        /// The new state.
        to: NmtState,
    },
    /// Guard time × life time factor without a valid answer. Reported once
    /// per loss.
    Lost {
        /// The node.
        node: NodeId,
        /// When its last valid answer arrived (`None`: never answered).
        last_seen: Option<Duration>,
        /// The node life time (guard time × life time factor).
        life_time: Duration,
    },
    /// A valid answer from a node that was lost.
    Recovered {
        /// The node.
        node: NodeId,
        /// The state it reported.
        state: NmtState,
        /// Time since the last valid answer before the loss (since guarding
        /// started if it never answered).
        after: Duration,
    },
    /// An answer with the wrong toggle bit.
    ToggleError {
        /// The node.
        node: NodeId,
        /// The toggle bit expected.
        expected: bool,
        /// The answer byte.
        data: u8,
    },
    /// A 0x700+n data frame that is no guarding answer (length other than
    /// 1, or no NMT state in bits 0..=6).
    Malformed {
        /// The node.
        node: NodeId,
        /// The payload.
        data: Vec<u8>,
    },
}

/// What the master knows about one guarded node.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GuardStatus {
    /// Guard time: the request period.
    pub guard_time: Duration,
    /// Missed answers in a row that make the node lost.
    pub life_time_factor: u8,
    /// The last reported state.
    pub state: Option<NmtState>,
    /// When the last valid answer (or boot-up) arrived.
    pub last_seen: Option<Duration>,
    /// True between a loss and the next valid answer.
    pub lost: bool,
    /// Requests sent.
    pub requests: u64,
    /// Requests not answered before the next one was due, in a row.
    pub missed: u32,
    /// Answers with a wrong toggle bit.
    pub toggle_errors: u64,
    /// Malformed answers.
    pub malformed: u64,
    /// Boot-up messages received.
    pub boot_ups: u64,
    /// The toggle bit the next answer must carry.
    expected_toggle: bool,
    /// A request is waiting for its answer.
    outstanding: bool,
    /// When the next request is due (`None`: at the first tick).
    next_request: Option<Duration>,
    /// When guarding started (the first request).
    started: Option<Duration>,
}

impl GuardStatus {
    /// The node life time: guard time × life time factor.
    pub fn life_time(&self) -> Duration {
        self.guard_time * u32::from(self.life_time_factor)
    }

    /// Time since the last valid answer.
    pub fn age(&self, now: Duration) -> Option<Duration> {
        self.last_seen.map(|t| now.saturating_sub(t))
    }
}

/// The master's node guarding of any number of nodes.
#[derive(Debug, Clone, Default)]
pub struct NodeGuarding {
    nodes: BTreeMap<NodeId, GuardStatus>,
}

impl NodeGuarding {
    /// Guards no node yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Guards `node` with `guard_time` (at least 1 ms) and
    /// `life_time_factor` (at least 1); the first request goes out at the
    /// next tick. A guard time or factor of 0 stops guarding the node (as
    /// 0 in objects 0x100C/0x100D does).
    pub fn guard(&mut self, node: NodeId, guard_time: Duration, life_time_factor: u8) {
        if guard_time.is_zero() || life_time_factor == 0 {
            self.nodes.remove(&node);
            return;
        }
        self.nodes.insert(
            node,
            GuardStatus {
                guard_time: guard_time.max(Duration::from_millis(1)),
                life_time_factor,
                state: None,
                last_seen: None,
                lost: false,
                requests: 0,
                missed: 0,
                toggle_errors: 0,
                malformed: 0,
                boot_ups: 0,
                expected_toggle: false,
                outstanding: false,
                next_request: None,
                started: None,
            },
        );
    }

    /// True when `node` is guarded.
    pub fn is_guarded(&self, node: NodeId) -> bool {
        self.nodes.contains_key(&node)
    }

    /// Everything known about a guarded node.
    pub fn status(&self, node: NodeId) -> Option<&GuardStatus> {
        self.nodes.get(&node)
    }

    /// All guarded nodes, by node id.
    pub fn nodes(&self) -> impl Iterator<Item = (NodeId, &GuardStatus)> {
        self.nodes.iter().map(|(&n, st)| (n, st))
    }

    /// The guarding request to `node`: a remote frame to 0x700+n, DLC 1.
    pub fn request_frame(node: NodeId) -> Frame {
        Frame::new_remote(CanId::Standard(0x700 + u16::from(node.get())), 1)
            .expect("0x700+n with DLC 1 is a valid remote frame")
    }

    /// Handles a received frame; frames other than 0x700+n data frames of
    /// guarded nodes are ignored.
    pub fn on_frame(&mut self, frame: &Frame, now: Duration) -> Vec<GuardingEvent> {
        let mut events = Vec::new();
        if frame.kind() == FrameKind::Error || frame.is_extended() || frame.is_remote() {
            return events;
        }
        let CobFunction::Heartbeat(node) = CobFunction::classify(frame.raw_id() as u16) else {
            return events;
        };
        let Some(st) = self.nodes.get_mut(&node) else {
            return events;
        };
        let byte = match frame.data() {
            &[b] => b,
            data => {
                st.malformed += 1;
                events.push(GuardingEvent::Malformed {
                    node,
                    data: data.to_vec(),
                });
                return events;
            }
        };
        let toggle = byte & 0x80 != 0;
        let Some(reported) = NmtState::from_byte(byte & 0x7F) else {
            st.malformed += 1;
            events.push(GuardingEvent::Malformed {
                node,
                data: vec![byte],
            });
            return events;
        };
        if reported == NmtState::Initialising {
            if toggle {
                st.malformed += 1;
                events.push(GuardingEvent::Malformed {
                    node,
                    data: vec![byte],
                });
                return events;
            }
            st.boot_ups += 1;
            st.expected_toggle = false;
            events.push(GuardingEvent::BootUp { node });
            Self::set_state(node, st, NmtState::PreOperational, &mut events);
            return events;
        }
        if toggle != st.expected_toggle && !st.lost {
            st.toggle_errors += 1;
            events.push(GuardingEvent::ToggleError {
                node,
                expected: st.expected_toggle,
                data: byte,
            });
            st.expected_toggle = !toggle;
            return events;
        }
        st.expected_toggle = !toggle;
        st.outstanding = false;
        st.missed = 0;
        if st.lost {
            st.lost = false;
            let since = st.last_seen.or(st.started).unwrap_or(now);
            events.push(GuardingEvent::Recovered {
                node,
                state: reported,
                after: now.saturating_sub(since),
            });
        }
        Self::set_state(node, st, reported, &mut events);
        st.last_seen = Some(now);
        events
    }

    fn set_state(
        node: NodeId,
        st: &mut GuardStatus,
        to: NmtState,
        events: &mut Vec<GuardingEvent>,
    ) {
        if st.state != Some(to) {
            events.push(GuardingEvent::StateChanged {
                node,
                from: st.state,
                to,
            });
            st.state = Some(to);
        }
    }

    /// Sends the requests due at `now` (into `frames`) and reports nodes
    /// whose life time has run out.
    pub fn on_tick(&mut self, now: Duration, frames: &mut Vec<Frame>) -> Vec<GuardingEvent> {
        let mut events = Vec::new();
        for (&node, st) in self.nodes.iter_mut() {
            let due = st.next_request.unwrap_or(now);
            if now < due {
                continue;
            }
            if st.started.is_none() {
                st.started = Some(now);
            }
            if st.outstanding {
                st.missed = st.missed.saturating_add(1);
                if st.missed >= u32::from(st.life_time_factor) && !st.lost {
                    st.lost = true;
                    events.push(GuardingEvent::Lost {
                        node,
                        last_seen: st.last_seen,
                        life_time: st.life_time(),
                    });
                }
            }
            // On the guard-time grid; after a stall, from now (no burst).
            let after = due + st.guard_time;
            st.next_request = Some(if after <= now {
                now + st.guard_time
            } else {
                after
            });
            st.outstanding = true;
            st.requests += 1;
            frames.push(Self::request_frame(node));
        }
        events
    }

    /// When the next request is due (at once for a node not yet polled).
    pub fn next_deadline(&self) -> Option<Duration> {
        self.nodes
            .values()
            .map(|st| st.next_request.unwrap_or_default())
            .min()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    fn n(id: u32) -> NodeId {
        NodeId::new(id).unwrap()
    }

    fn answer(node: u16, byte: u8) -> Frame {
        Frame::new(CanId::Standard(0x700 + node), &[byte]).unwrap()
    }

    /// Ticks at `now`; the frames sent as (id, remote, dlc).
    fn tick(g: &mut NodeGuarding, now: Duration) -> (Vec<(u32, bool, usize)>, Vec<GuardingEvent>) {
        let mut frames = Vec::new();
        let ev = g.on_tick(now, &mut frames);
        let f = frames
            .iter()
            .map(|f| (f.raw_id(), f.is_remote(), usize::from(f.dlc())))
            .collect();
        (f, ev)
    }

    #[test]
    fn requests_every_guard_time_and_answers_with_alternating_toggle() {
        let mut g = NodeGuarding::new();
        g.guard(n(5), 100 * MS, 3);
        assert_eq!(g.next_deadline(), Some(Duration::ZERO));
        let (f, ev) = tick(&mut g, Duration::ZERO);
        assert_eq!(f, vec![(0x705, true, 1)]);
        assert!(ev.is_empty());
        assert_eq!(g.next_deadline(), Some(100 * MS));
        assert_eq!(tick(&mut g, 99 * MS).0, vec![]);
        // First answer: toggle 0, pre-operational.
        assert_eq!(
            g.on_frame(&answer(5, 0x7F), 2 * MS),
            vec![GuardingEvent::StateChanged {
                node: n(5),
                from: None,
                to: NmtState::PreOperational
            }]
        );
        // The master's own request looped back is ignored.
        assert!(
            g.on_frame(&NodeGuarding::request_frame(n(5)), 3 * MS)
                .is_empty()
        );
        for k in 1..=10u32 {
            let t = k * 100 * MS;
            assert_eq!(tick(&mut g, t), (vec![(0x705, true, 1)], vec![]));
            let toggle = if k % 2 == 1 { 0x80 } else { 0x00 };
            assert!(g.on_frame(&answer(5, toggle | 0x7F), t + 2 * MS).is_empty());
        }
        let st = g.status(n(5)).unwrap();
        assert_eq!((st.requests, st.missed, st.toggle_errors), (11, 0, 0));
        assert_eq!(st.last_seen, Some(1002 * MS));
        assert_eq!(st.life_time(), 300 * MS);
        assert!(!st.lost);
    }

    #[test]
    fn state_changes_seen_in_the_answer() {
        let mut g = NodeGuarding::new();
        g.guard(n(3), 50 * MS, 2);
        tick(&mut g, Duration::ZERO);
        g.on_frame(&answer(3, 0x7F), MS);
        tick(&mut g, 50 * MS);
        assert_eq!(
            g.on_frame(&answer(3, 0x85), 51 * MS),
            vec![GuardingEvent::StateChanged {
                node: n(3),
                from: Some(NmtState::PreOperational),
                to: NmtState::Operational
            }]
        );
        tick(&mut g, 100 * MS);
        assert_eq!(
            g.on_frame(&answer(3, 0x04), 101 * MS),
            vec![GuardingEvent::StateChanged {
                node: n(3),
                from: Some(NmtState::Operational),
                to: NmtState::Stopped
            }]
        );
        assert_eq!(g.status(n(3)).unwrap().state, Some(NmtState::Stopped));
    }

    #[test]
    fn missing_answers_until_the_life_time_then_recovery() {
        let mut g = NodeGuarding::new();
        g.guard(n(7), 100 * MS, 3);
        tick(&mut g, Duration::ZERO);
        g.on_frame(&answer(7, 0x05), MS);
        // The node goes silent after its answer to the request at 0.
        // Requests at 100 (answered? no), 200, 300: misses counted when the
        // next request is due: 200 → 1, 300 → 2, 400 → 3 = lost.
        for t in [100, 200, 300] {
            let (f, ev) = tick(&mut g, t * MS);
            assert_eq!(f, vec![(0x707, true, 1)]);
            assert!(ev.is_empty(), "{t}: {ev:?}");
        }
        assert_eq!(g.status(n(7)).unwrap().missed, 2);
        let (f, ev) = tick(&mut g, 400 * MS);
        assert_eq!(f, vec![(0x707, true, 1)]);
        assert_eq!(
            ev,
            vec![GuardingEvent::Lost {
                node: n(7),
                last_seen: Some(MS),
                life_time: 300 * MS
            }]
        );
        assert!(g.status(n(7)).unwrap().lost);
        // Reported once; polling goes on.
        for t in [500, 600, 700] {
            let (f, ev) = tick(&mut g, t * MS);
            assert_eq!(f.len(), 1);
            assert!(ev.is_empty());
        }
        // The first answer after the loss recovers, whatever its toggle.
        assert_eq!(
            g.on_frame(&answer(7, 0x85), 702 * MS),
            vec![GuardingEvent::Recovered {
                node: n(7),
                state: NmtState::Operational,
                after: 701 * MS
            }]
        );
        let st = g.status(n(7)).unwrap();
        assert!(!st.lost);
        assert_eq!(st.missed, 0);
        // The toggle continues from the received one.
        tick(&mut g, 800 * MS);
        assert!(g.on_frame(&answer(7, 0x05), 801 * MS).is_empty());
        assert_eq!(g.status(n(7)).unwrap().toggle_errors, 0);
    }

    #[test]
    fn a_node_that_never_answers_is_lost_after_the_life_time() {
        let mut g = NodeGuarding::new();
        g.guard(n(9), 20 * MS, 2);
        assert!(tick(&mut g, 1000 * MS).1.is_empty());
        assert!(tick(&mut g, 1020 * MS).1.is_empty());
        assert_eq!(
            tick(&mut g, 1040 * MS).1,
            vec![GuardingEvent::Lost {
                node: n(9),
                last_seen: None,
                life_time: 40 * MS
            }]
        );
        assert_eq!(
            g.on_frame(&answer(9, 0x7F), 1050 * MS)[0],
            GuardingEvent::Recovered {
                node: n(9),
                state: NmtState::PreOperational,
                after: 50 * MS
            }
        );
    }

    #[test]
    fn toggle_error_is_counted_reported_and_not_a_sign_of_life() {
        let mut g = NodeGuarding::new();
        g.guard(n(4), 100 * MS, 2);
        tick(&mut g, Duration::ZERO);
        g.on_frame(&answer(4, 0x05), MS);
        tick(&mut g, 100 * MS);
        // Expected toggle 1, got 0.
        assert_eq!(
            g.on_frame(&answer(4, 0x05), 101 * MS),
            vec![GuardingEvent::ToggleError {
                node: n(4),
                expected: true,
                data: 0x05
            }]
        );
        let st = g.status(n(4)).unwrap();
        assert_eq!(st.toggle_errors, 1);
        assert_eq!(st.last_seen, Some(MS));
        // The request stays unanswered: a miss at 200.
        tick(&mut g, 200 * MS);
        assert_eq!(g.status(n(4)).unwrap().missed, 1);
        // Resynchronised: the node's next answer (toggle 1) is valid.
        assert!(g.on_frame(&answer(4, 0x85), 201 * MS).is_empty());
        let st = g.status(n(4)).unwrap();
        assert_eq!((st.toggle_errors, st.missed), (1, 0));
        assert_eq!(st.last_seen, Some(201 * MS));
        // Repeated wrong toggles keep the node from counting as alive.
        tick(&mut g, 300 * MS);
        assert_eq!(g.on_frame(&answer(4, 0x85), 301 * MS).len(), 1);
        tick(&mut g, 400 * MS);
        assert_eq!(g.on_frame(&answer(4, 0x85), 401 * MS).len(), 1);
        assert!(matches!(
            tick(&mut g, 500 * MS).1[..],
            [GuardingEvent::Lost { .. }]
        ));
        assert_eq!(g.status(n(4)).unwrap().toggle_errors, 3);
    }

    #[test]
    fn boot_up_restarts_the_toggle() {
        let mut g = NodeGuarding::new();
        g.guard(n(2), 100 * MS, 3);
        tick(&mut g, Duration::ZERO);
        g.on_frame(&answer(2, 0x05), MS);
        // Expected toggle is now 1; the node resets and boots.
        assert_eq!(
            g.on_frame(&answer(2, 0x00), 50 * MS),
            vec![
                GuardingEvent::BootUp { node: n(2) },
                GuardingEvent::StateChanged {
                    node: n(2),
                    from: Some(NmtState::Operational),
                    to: NmtState::PreOperational
                }
            ]
        );
        tick(&mut g, 100 * MS);
        assert!(g.on_frame(&answer(2, 0x7F), 101 * MS).is_empty());
        assert_eq!(g.status(n(2)).unwrap().toggle_errors, 0);
        assert_eq!(g.status(n(2)).unwrap().boot_ups, 1);
    }

    #[test]
    fn malformed_answers_and_unguarded_nodes() {
        let mut g = NodeGuarding::new();
        g.guard(n(6), 100 * MS, 3);
        tick(&mut g, Duration::ZERO);
        for data in [&[][..], &[0x05, 0x00], &[0x81], &[0x80]] {
            let f = Frame::new(CanId::Standard(0x706), data).unwrap();
            assert_eq!(
                g.on_frame(&f, MS),
                vec![GuardingEvent::Malformed {
                    node: n(6),
                    data: data.to_vec()
                }]
            );
        }
        assert_eq!(g.status(n(6)).unwrap().malformed, 4);
        assert_eq!(g.status(n(6)).unwrap().last_seen, None);
        // Other nodes and other COB-IDs are not guarded here.
        assert!(g.on_frame(&answer(8, 0x05), MS).is_empty());
        assert!(
            g.on_frame(&Frame::new(CanId::Standard(0x186), &[0x05]).unwrap(), MS)
                .is_empty()
        );
        // Guard time 0 stops guarding.
        g.guard(n(6), Duration::ZERO, 3);
        assert!(!g.is_guarded(n(6)));
        assert_eq!(g.next_deadline(), None);
    }

    #[test]
    fn a_stall_sends_one_request_not_a_burst() {
        let mut g = NodeGuarding::new();
        g.guard(n(1), 100 * MS, 10);
        tick(&mut g, Duration::ZERO);
        let (f, _) = tick(&mut g, 1050 * MS);
        assert_eq!(f.len(), 1);
        assert_eq!(g.next_deadline(), Some(1150 * MS));
        assert_eq!(tick(&mut g, 1050 * MS).0.len(), 0);
    }
}
