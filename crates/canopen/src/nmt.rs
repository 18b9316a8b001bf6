//! Network management (CiA 301 §7.2.8): NMT states and commands, the NMT
//! command frame codec, and a pure NMT *slave* with a heartbeat producer for
//! simulated devices.
//!
//! NMT commands travel on COB-ID 0x000 with two bytes: the command specifier
//! and the target node id (0 = all nodes). A node announces itself with the
//! boot-up message 0x700+n `[0x00]` and then reports its state periodically
//! in heartbeats 0x700+n `[state]`.

use std::fmt;
use std::time::Duration;

use cangate_can::{CanId, Frame, FrameKind};

use crate::ids::{NodeId, cob};
use crate::sync::Periodic;

/// An NMT state as carried in heartbeat and boot-up messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmtState {
    /// Initialising; on the wire this is the boot-up message (0x00).
    Initialising,
    /// Stopped (0x04).
    Stopped,
    /// Operational (0x05).
    Operational,
    /// Pre-operational (0x7F).
    PreOperational,
}

impl NmtState {
    /// Decodes a heartbeat state byte; `None` for any other value (including
    /// a node-guarding reply with the toggle bit set).
    pub const fn from_byte(b: u8) -> Option<Self> {
        match b {
            0x00 => Some(NmtState::Initialising),
            0x04 => Some(NmtState::Stopped),
            0x05 => Some(NmtState::Operational),
            0x7F => Some(NmtState::PreOperational),
            _ => None,
        }
    }

    /// The heartbeat state byte.
    pub const fn to_byte(self) -> u8 {
        match self {
            NmtState::Initialising => 0x00,
            NmtState::Stopped => 0x04,
            NmtState::Operational => 0x05,
            NmtState::PreOperational => 0x7F,
        }
    }

    /// A lower-case human-readable name.
    pub const fn name(self) -> &'static str {
        match self {
            NmtState::Initialising => "initialising",
            NmtState::Stopped => "stopped",
            NmtState::Operational => "operational",
            NmtState::PreOperational => "pre-operational",
        }
    }
}

impl fmt::Display for NmtState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// An NMT node control command (command specifier).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmtCommand {
    /// Start remote node (0x01): enter operational.
    Start,
    /// Stop remote node (0x02): enter stopped.
    Stop,
    /// Enter pre-operational (0x80).
    EnterPreOperational,
    /// Reset node (0x81): reset application and communication, boot up.
    ResetNode,
    /// Reset communication (0x82): reset communication parameters, boot up.
    ResetCommunication,
}

impl NmtCommand {
    /// The command specifier byte.
    pub const fn cs(self) -> u8 {
        match self {
            NmtCommand::Start => 0x01,
            NmtCommand::Stop => 0x02,
            NmtCommand::EnterPreOperational => 0x80,
            NmtCommand::ResetNode => 0x81,
            NmtCommand::ResetCommunication => 0x82,
        }
    }

    /// Decodes a command specifier byte.
    pub const fn from_cs(cs: u8) -> Option<Self> {
        match cs {
            0x01 => Some(NmtCommand::Start),
            0x02 => Some(NmtCommand::Stop),
            0x80 => Some(NmtCommand::EnterPreOperational),
            0x81 => Some(NmtCommand::ResetNode),
            0x82 => Some(NmtCommand::ResetCommunication),
            _ => None,
        }
    }

    /// A lower-case human-readable name.
    pub const fn name(self) -> &'static str {
        match self {
            NmtCommand::Start => "start",
            NmtCommand::Stop => "stop",
            NmtCommand::EnterPreOperational => "enter pre-operational",
            NmtCommand::ResetNode => "reset node",
            NmtCommand::ResetCommunication => "reset communication",
        }
    }
}

impl fmt::Display for NmtCommand {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

fn std_frame(id: u16, data: &[u8]) -> Frame {
    Frame::new(CanId::Standard(id), data).expect("CANopen frame is a valid classic frame")
}

/// The NMT command frame: COB-ID 0x000, data `[cs, node]`, node 0 when
/// `target` is `None` (broadcast to all nodes).
pub fn nmt_frame(cmd: NmtCommand, target: Option<NodeId>) -> Frame {
    std_frame(cob::NMT, &[cmd.cs(), target.map_or(0, NodeId::get)])
}

/// Decodes an NMT command frame into the command and its target (`None` =
/// all nodes). Anything else yields `None`: another COB-ID, an extended id,
/// a remote, error or FD frame, a length other than 2, an unknown command
/// specifier or a node id above 127.
pub fn parse_nmt(frame: &Frame) -> Option<(NmtCommand, Option<NodeId>)> {
    if frame.id() != CanId::Standard(cob::NMT) || frame.kind() != FrameKind::Data || frame.is_fd() {
        return None;
    }
    let &[cs, node] = frame.data() else {
        return None;
    };
    let cmd = NmtCommand::from_cs(cs)?;
    let target = match node {
        0 => None,
        n => Some(NodeId::new(u32::from(n)).ok()?),
    };
    Some((cmd, target))
}

/// The heartbeat frame of `node` in `state`: 0x700+n `[state]`.
pub fn heartbeat_frame(node: NodeId, state: NmtState) -> Frame {
    std_frame(cob::HEARTBEAT + u16::from(node.get()), &[state.to_byte()])
}

/// The boot-up frame of `node`: 0x700+n `[0x00]`.
pub fn boot_up_frame(node: NodeId) -> Frame {
    heartbeat_frame(node, NmtState::Initialising)
}

/// Which reset an NMT command asked the device to perform.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmtReset {
    /// Reset node: the device resets its application (manufacturer and
    /// profile areas) and communication parameters.
    Node,
    /// Reset communication: the device resets its communication parameters
    /// (0x1000..=0x1FFF) only.
    Communication,
}

/// What an NMT command did to an [`NmtSlave`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NmtSlaveEvent {
    /// The node changed state.
    StateChanged {
        /// The previous state.
        from: NmtState,
        /// The new state.
        to: NmtState,
    },
    /// The node was reset and has booted again: the device must apply the
    /// reset to its object dictionary, then send `boot_up`. The slave is now
    /// pre-operational and its heartbeat schedule restarted.
    Reset {
        /// Which reset.
        kind: NmtReset,
        /// The boot-up frame to send.
        boot_up: Frame,
    },
}

/// A pure NMT slave state machine with a heartbeat producer, for simulated
/// devices.
///
/// Life cycle: [`NmtSlave::new`] (initialising) → [`NmtSlave::boot`] sends
/// the boot-up frame and enters pre-operational → NMT commands addressed to
/// the node or broadcast move it between pre-operational, operational and
/// stopped; resets boot it again. Heartbeats are produced in every state
/// after boot-up (including stopped), every 0x1017 ms when that is non-zero.
#[derive(Debug, Clone)]
pub struct NmtSlave {
    node: NodeId,
    state: NmtState,
    heartbeat_period: Duration,
    schedule: Option<Periodic>,
}

impl NmtSlave {
    /// A slave in the initialising state with a heartbeat producer period in
    /// ms (object 0x1017; 0 = no heartbeat). Nothing is sent until
    /// [`NmtSlave::boot`].
    pub fn new(node: NodeId, heartbeat_ms: u16) -> Self {
        NmtSlave {
            node,
            state: NmtState::Initialising,
            heartbeat_period: Duration::from_millis(u64::from(heartbeat_ms)),
            schedule: None,
        }
    }

    /// The node id.
    pub fn node(&self) -> NodeId {
        self.node
    }

    /// The current state.
    pub fn state(&self) -> NmtState {
        self.state
    }

    /// Finishes initialisation: enters pre-operational, starts the heartbeat
    /// producer (first heartbeat at `now + period`) and returns the boot-up
    /// frame to send.
    pub fn boot(&mut self, now: Duration) -> Frame {
        self.state = NmtState::PreOperational;
        self.restart_heartbeat(now);
        boot_up_frame(self.node)
    }

    /// Handles a received frame; frames that are not a valid NMT command for
    /// this node (or all nodes) are ignored.
    pub fn on_frame(&mut self, frame: &Frame, now: Duration) -> Option<NmtSlaveEvent> {
        match parse_nmt(frame)? {
            (cmd, None) => self.on_command(cmd, now),
            (cmd, Some(n)) if n == self.node => self.on_command(cmd, now),
            _ => None,
        }
    }

    /// Applies a command already known to be addressed to this node. Before
    /// [`NmtSlave::boot`] every command is ignored; a command that leaves
    /// the state unchanged yields `None`.
    pub fn on_command(&mut self, cmd: NmtCommand, now: Duration) -> Option<NmtSlaveEvent> {
        if self.state == NmtState::Initialising {
            return None;
        }
        let to = match cmd {
            NmtCommand::Start => NmtState::Operational,
            NmtCommand::Stop => NmtState::Stopped,
            NmtCommand::EnterPreOperational => NmtState::PreOperational,
            NmtCommand::ResetNode | NmtCommand::ResetCommunication => {
                let kind = if cmd == NmtCommand::ResetNode {
                    NmtReset::Node
                } else {
                    NmtReset::Communication
                };
                let boot_up = self.boot(now);
                return Some(NmtSlaveEvent::Reset { kind, boot_up });
            }
        };
        let from = self.state;
        if from == to {
            return None;
        }
        self.state = to;
        Some(NmtSlaveEvent::StateChanged { from, to })
    }

    /// Changes the heartbeat producer period (0x1017 in ms, 0 = off); a
    /// running producer restarts its schedule at `now`.
    pub fn set_heartbeat_ms(&mut self, ms: u16, now: Duration) {
        self.heartbeat_period = Duration::from_millis(u64::from(ms));
        if self.state != NmtState::Initialising {
            self.restart_heartbeat(now);
        }
    }

    /// The heartbeat producer period, `None` when off.
    pub fn heartbeat_period(&self) -> Option<Duration> {
        (!self.heartbeat_period.is_zero()).then_some(self.heartbeat_period)
    }

    /// Returns the heartbeat frame to send if one is due at `now`.
    pub fn on_tick(&mut self, now: Duration) -> Option<Frame> {
        self.schedule.as_mut()?.poll(now)?;
        Some(heartbeat_frame(self.node, self.state))
    }

    /// When the next heartbeat is due; `None` when the producer is off or
    /// the node has not booted.
    pub fn next_deadline(&self) -> Option<Duration> {
        self.schedule.as_ref().map(Periodic::next_deadline)
    }

    fn restart_heartbeat(&mut self, now: Duration) {
        self.schedule = self
            .heartbeat_period()
            .map(|period| Periodic::new(now, period));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn n(id: u32) -> NodeId {
        NodeId::new(id).unwrap()
    }

    fn bytes(f: &Frame) -> (u32, Vec<u8>) {
        (f.raw_id(), f.data().to_vec())
    }

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn state_bytes_round_trip() {
        for s in [
            NmtState::Initialising,
            NmtState::Stopped,
            NmtState::Operational,
            NmtState::PreOperational,
        ] {
            assert_eq!(NmtState::from_byte(s.to_byte()), Some(s));
        }
        assert_eq!(NmtState::from_byte(0x85), None);
        assert_eq!(NmtState::PreOperational.to_string(), "pre-operational");
        assert_eq!(NmtState::Operational.to_byte(), 0x05);
    }

    #[test]
    fn command_frames_exact_bytes() {
        let cases = [
            (NmtCommand::Start, Some(n(5)), [0x01, 0x05]),
            (NmtCommand::Stop, Some(n(5)), [0x02, 0x05]),
            (NmtCommand::EnterPreOperational, Some(n(127)), [0x80, 0x7F]),
            (NmtCommand::ResetNode, Some(n(1)), [0x81, 0x01]),
            (NmtCommand::ResetCommunication, Some(n(0x22)), [0x82, 0x22]),
            (NmtCommand::Start, None, [0x01, 0x00]),
            (NmtCommand::Stop, None, [0x02, 0x00]),
            (NmtCommand::EnterPreOperational, None, [0x80, 0x00]),
            (NmtCommand::ResetNode, None, [0x81, 0x00]),
            (NmtCommand::ResetCommunication, None, [0x82, 0x00]),
        ];
        for (cmd, target, data) in cases {
            let f = nmt_frame(cmd, target);
            assert_eq!(f.id(), CanId::Standard(0x000));
            assert_eq!(f.data(), &data, "{cmd}");
            assert_eq!(parse_nmt(&f), Some((cmd, target)));
        }
    }

    #[test]
    fn parse_rejects_malformed() {
        let std = |id, d: &[u8]| Frame::new(CanId::Standard(id), d).unwrap();
        assert_eq!(parse_nmt(&std(0x000, &[0x01])), None);
        assert_eq!(parse_nmt(&std(0x000, &[0x01, 0x05, 0x00])), None);
        assert_eq!(parse_nmt(&std(0x000, &[0x03, 0x05])), None);
        assert_eq!(parse_nmt(&std(0x000, &[0x01, 0x80])), None);
        assert_eq!(parse_nmt(&std(0x001, &[0x01, 0x05])), None);
        assert_eq!(
            parse_nmt(&Frame::new(CanId::Extended(0), &[0x01, 0x05]).unwrap()),
            None
        );
        assert_eq!(
            parse_nmt(&Frame::new_remote(CanId::Standard(0), 2).unwrap()),
            None
        );
    }

    #[test]
    fn heartbeat_and_boot_up_frames() {
        assert_eq!(bytes(&boot_up_frame(n(5))), (0x705, vec![0x00]));
        assert_eq!(
            bytes(&heartbeat_frame(n(0x7F), NmtState::PreOperational)),
            (0x77F, vec![0x7F])
        );
    }

    #[test]
    fn slave_boots_and_follows_commands() {
        let mut s = NmtSlave::new(n(5), 0);
        assert_eq!(s.state(), NmtState::Initialising);
        // Commands before boot-up are ignored.
        assert_eq!(s.on_frame(&nmt_frame(NmtCommand::Start, None), MS), None);
        assert_eq!(bytes(&s.boot(MS)), (0x705, vec![0x00]));
        assert_eq!(s.state(), NmtState::PreOperational);
        assert_eq!(
            s.on_frame(&nmt_frame(NmtCommand::Start, Some(n(5))), MS),
            Some(NmtSlaveEvent::StateChanged {
                from: NmtState::PreOperational,
                to: NmtState::Operational
            })
        );
        // Addressed to another node: ignored.
        assert_eq!(
            s.on_frame(&nmt_frame(NmtCommand::Stop, Some(n(6))), MS),
            None
        );
        // Same state again: no event.
        assert_eq!(s.on_frame(&nmt_frame(NmtCommand::Start, None), MS), None);
        assert_eq!(
            s.on_frame(&nmt_frame(NmtCommand::Stop, None), MS),
            Some(NmtSlaveEvent::StateChanged {
                from: NmtState::Operational,
                to: NmtState::Stopped
            })
        );
        assert_eq!(
            s.on_frame(&nmt_frame(NmtCommand::EnterPreOperational, None), MS),
            Some(NmtSlaveEvent::StateChanged {
                from: NmtState::Stopped,
                to: NmtState::PreOperational
            })
        );
    }

    #[test]
    fn slave_resets_boot_again() {
        let mut s = NmtSlave::new(n(9), 0);
        s.boot(Duration::ZERO);
        s.on_command(NmtCommand::Start, Duration::ZERO);
        for (cmd, kind) in [
            (NmtCommand::ResetNode, NmtReset::Node),
            (NmtCommand::ResetCommunication, NmtReset::Communication),
        ] {
            s.on_command(NmtCommand::Start, Duration::ZERO);
            match s.on_frame(&nmt_frame(cmd, Some(n(9))), MS) {
                Some(NmtSlaveEvent::Reset { kind: k, boot_up }) => {
                    assert_eq!(k, kind);
                    assert_eq!(bytes(&boot_up), (0x709, vec![0x00]));
                }
                other => panic!("unexpected {other:?}"),
            }
            assert_eq!(s.state(), NmtState::PreOperational);
        }
    }

    #[test]
    fn slave_heartbeat_producer() {
        let mut s = NmtSlave::new(n(3), 100);
        assert_eq!(s.next_deadline(), None);
        assert_eq!(s.on_tick(Duration::from_secs(1)), None);
        s.boot(Duration::ZERO);
        assert_eq!(s.next_deadline(), Some(100 * MS));
        assert_eq!(s.on_tick(99 * MS), None);
        assert_eq!(bytes(&s.on_tick(100 * MS).unwrap()), (0x703, vec![0x7F]));
        s.on_command(NmtCommand::Start, 150 * MS);
        assert_eq!(bytes(&s.on_tick(203 * MS).unwrap()), (0x703, vec![0x05]));
        assert_eq!(s.next_deadline(), Some(300 * MS));
        s.on_command(NmtCommand::Stop, 250 * MS);
        assert_eq!(bytes(&s.on_tick(300 * MS).unwrap()), (0x703, vec![0x04]));
        // A reset restarts the schedule from the reset time.
        s.on_command(NmtCommand::ResetCommunication, 310 * MS);
        assert_eq!(s.next_deadline(), Some(410 * MS));
        // Turning the producer off.
        s.set_heartbeat_ms(0, 320 * MS);
        assert_eq!(s.next_deadline(), None);
        assert_eq!(s.on_tick(Duration::from_secs(9)), None);
        s.set_heartbeat_ms(50, Duration::from_secs(10));
        assert_eq!(s.next_deadline(), Some(Duration::from_secs(10) + 50 * MS));
    }

    proptest! {
        #[test]
        fn random_frames_never_panic_the_slave(
            id in 0u32..0x800,
            extended in any::<bool>(),
            remote in any::<bool>(),
            data in proptest::collection::vec(any::<u8>(), 0..=8),
            t in 0u64..1_000_000,
        ) {
            let cid = if extended { CanId::Extended(id) } else { CanId::Standard(id as u16) };
            let frame = if remote {
                Frame::new_remote(cid, data.len() as u8).unwrap()
            } else {
                Frame::new(cid, &data).unwrap()
            };
            let mut s = NmtSlave::new(n(1), 10);
            s.boot(Duration::ZERO);
            let now = Duration::from_micros(t);
            let _ = parse_nmt(&frame);
            let _ = s.on_frame(&frame, now);
            let _ = s.on_tick(now);
        }
    }
}
