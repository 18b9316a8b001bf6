//! Layer setting services (LSS, CiA 305), slave side: the state machine a
//! device runs on 0x7E5 (requests) / 0x7E4 (answers). See
//! [`crate::lss`] for the command table.
//!
//! What it settles where the spec leaves room (as CANopenNode's
//! `CO_LSSslave.c` does):
//!
//! - The slave starts in the waiting state. Switch state selective is
//!   matched part by part (0x40, 0x41, 0x42, 0x43 in this order; any
//!   mismatch or other order starts over); the match of all four switches
//!   to the configuration state and is answered 0x44.
//! - Configure node-ID, bit timing, activate, store and inquire are only
//!   served in the configuration state; elsewhere they are ignored
//!   (no answer).
//! - "Non-configured" means no valid *pending* node-ID (255): only such a
//!   slave answers identify non-configured (0x4C → 0x50) and fastscan, and
//!   fastscan only in the waiting state, unless made to answer it like
//!   CANopenNode's `CO_LSSslave.c` does
//!   ([`LssSlave::answering_fastscan_until_configured`]): in any LSS state
//!   while it has no node-ID, so that a device a fastscan found (and left
//!   in the configuration state) is found again by the next reset query
//!   until it is given an id. The reset query (BitChecked 0x80)
//!   restarts the slave's LSSPos at 0. A query is answered when LSSSub is
//!   its LSSPos and the bits from BitChecked up agree; a match with
//!   BitChecked 0 moves LSSPos to LSSNext, and when LSSNext is below LSSSub
//!   (the serial confirmed) the slave enters the configuration state.
//! - Identify remote slave (0x46..=0x4B) is answered in either state by a
//!   slave inside all the ranges, after the last of the six frames.
//! - The node-ID: the *pending* id is what 0x11 set; it becomes *active*
//!   ([`LssSlaveEvent::ApplyNodeId`]) when the slave goes back to the
//!   waiting state while it has no active id, and otherwise with the
//!   device's next NMT reset (communication or node) — the device asks
//!   [`LssSlave::on_reset`]. 0x17 stores the pending id (non-volatile
//!   memory); a power-on ([`LssSlave::power_on`]) or an NMT reset node
//!   starts from the stored id, 255 if none was ever stored.
//! - Bit timing: table 0 (CiA 301) indices 0..=4 and 6..=8 are accepted
//!   (index 5, 100 kbit/s, is reserved in CiA 301's table; 9 is automatic
//!   bit rate detection, not simulated).

use cangate_can::Frame;

use crate::lss::{
    FASTSCAN_RESET, LSS_REQUEST_COB_ID, LssIdentity, LssMode, UNCONFIGURED_NODE_ID, cs, decode,
    response_frame,
};

/// What the device must do after a request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LssSlaveEvent {
    /// Become node `id` (1..=127) now: reset communication with it and
    /// send the boot-up.
    ApplyNodeId(u8),
    /// The pending node-ID and bit timing were stored.
    Stored {
        /// The stored node-ID.
        node_id: u8,
    },
    /// Change to the configured bit timing after `switch_delay_ms`.
    ActivateBitTiming {
        /// Table selector.
        table: u8,
        /// Index.
        index: u8,
        /// Switch delay in ms.
        switch_delay_ms: u16,
    },
    /// The LSS state changed.
    ModeChanged(LssMode),
}

/// The LSS slave of one device. See the [module documentation](self).
#[derive(Debug, Clone)]
pub struct LssSlave {
    identity: LssIdentity,
    mode: LssMode,
    active: u8,
    pending: u8,
    stored: u8,
    can_store: bool,
    /// Switch selective: parts matched so far (0..=3).
    selective: u8,
    /// Identify remote: parts matched so far (0..=5).
    identify: u8,
    /// Fastscan LSSPos.
    lss_pos: u8,
    bit_timing: Option<(u8, u8)>,
    /// Answers fastscan in the configuration state too (CANopenNode).
    fastscan_in_any_state: bool,
}

impl LssSlave {
    /// A slave with `identity` and the stored node-ID `stored` (255: none),
    /// powered on (waiting state, active = pending = stored).
    pub fn new(identity: LssIdentity, stored: u8) -> Self {
        let mut s = LssSlave {
            identity,
            mode: LssMode::Waiting,
            active: stored,
            pending: stored,
            stored,
            can_store: true,
            selective: 0,
            identify: 0,
            lss_pos: 0,
            bit_timing: None,
            fastscan_in_any_state: false,
        };
        s.power_on();
        s
    }

    /// Makes store configuration fail with error 1 (not supported).
    pub fn without_store(mut self) -> Self {
        self.can_store = false;
        self
    }

    /// Makes the slave answer fastscan in any LSS state while it has no
    /// node-ID, as CANopenNode's LSS slave does (CiA 305 has a slave
    /// answer only in the waiting state).
    pub fn answering_fastscan_until_configured(mut self) -> Self {
        self.fastscan_in_any_state = true;
        self
    }

    /// Power-on: waiting state, active and pending node-ID from the stored
    /// one.
    pub fn power_on(&mut self) {
        self.mode = LssMode::Waiting;
        self.active = self.stored;
        self.pending = self.stored;
        self.selective = 0;
        self.identify = 0;
        self.lss_pos = 0;
    }

    /// An NMT reset of the device: `node` true for reset node (the device
    /// restarts from the stored node-ID), false for reset communication
    /// (the pending id becomes active). Returns the node-ID active now.
    pub fn on_reset(&mut self, node: bool) -> u8 {
        if node {
            self.pending = self.stored;
        }
        self.active = self.pending;
        self.active
    }

    /// The identity.
    pub fn identity(&self) -> LssIdentity {
        self.identity
    }
    /// The LSS state.
    pub fn mode(&self) -> LssMode {
        self.mode
    }
    /// The active node-ID (255: none).
    pub fn active_node_id(&self) -> u8 {
        self.active
    }
    /// The pending node-ID (255: none).
    pub fn pending_node_id(&self) -> u8 {
        self.pending
    }
    /// The stored node-ID (255: none).
    pub fn stored_node_id(&self) -> u8 {
        self.stored
    }

    fn non_configured(&self) -> bool {
        self.pending == UNCONFIGURED_NODE_ID
    }

    /// Handles a frame: the answer to send, if any, and what the device
    /// must do. Frames other than 0x7E5 requests are ignored.
    pub fn on_frame(&mut self, frame: &Frame) -> (Option<Frame>, Vec<LssSlaveEvent>) {
        let mut events = Vec::new();
        let Some(req) = decode(frame, LSS_REQUEST_COB_ID) else {
            return (None, events);
        };
        let p = req.payload;
        let value = req.u32();
        let configuring = self.mode == LssMode::Configuration;
        let answer = match req.cs {
            cs::SWITCH_GLOBAL => {
                match p[0] {
                    0 => self.enter_waiting(&mut events),
                    1 => self.set_mode(LssMode::Configuration, &mut events),
                    _ => {}
                }
                None
            }
            c @ cs::SWITCH_SELECTIVE_VENDOR..=cs::SWITCH_SELECTIVE_SERIAL => {
                let part = c - cs::SWITCH_SELECTIVE_VENDOR;
                if self.mode != LssMode::Waiting {
                    None
                } else if part == self.selective
                    && self.identity.parts()[usize::from(part)] == value
                {
                    if part == 3 {
                        self.selective = 0;
                        self.set_mode(LssMode::Configuration, &mut events);
                        Some(response_frame(cs::SWITCH_SELECTIVE_RESPONSE, &[]))
                    } else {
                        self.selective += 1;
                        None
                    }
                } else {
                    self.selective = 0;
                    None
                }
            }
            cs::CONFIGURE_NODE_ID if configuring => {
                let id = p[0];
                let error = if (1..=127).contains(&id) || id == UNCONFIGURED_NODE_ID {
                    self.pending = id;
                    0
                } else {
                    1
                };
                Some(response_frame(cs::CONFIGURE_NODE_ID, &[error, 0]))
            }
            cs::CONFIGURE_BIT_TIMING if configuring => {
                let ok = p[0] == 0 && matches!(p[1], 0..=4 | 6..=8);
                if ok {
                    self.bit_timing = Some((p[0], p[1]));
                }
                Some(response_frame(
                    cs::CONFIGURE_BIT_TIMING,
                    &[if ok { 0 } else { 1 }, 0],
                ))
            }
            cs::ACTIVATE_BIT_TIMING if configuring => {
                if let Some((table, index)) = self.bit_timing {
                    events.push(LssSlaveEvent::ActivateBitTiming {
                        table,
                        index,
                        switch_delay_ms: u16::from_le_bytes([p[0], p[1]]),
                    });
                }
                None
            }
            cs::STORE_CONFIGURATION if configuring => {
                let error = if self.can_store {
                    self.stored = self.pending;
                    events.push(LssSlaveEvent::Stored {
                        node_id: self.stored,
                    });
                    0
                } else {
                    1
                };
                Some(response_frame(cs::STORE_CONFIGURATION, &[error, 0]))
            }
            c @ cs::INQUIRE_VENDOR..=cs::INQUIRE_SERIAL if configuring => {
                let v = self.identity.parts()[usize::from(c - cs::INQUIRE_VENDOR)];
                Some(response_frame(c, &v.to_le_bytes()))
            }
            cs::INQUIRE_NODE_ID if configuring => {
                Some(response_frame(cs::INQUIRE_NODE_ID, &[self.active]))
            }
            c @ cs::IDENTIFY_VENDOR..=cs::IDENTIFY_SERIAL_HIGH => {
                let step = c - cs::IDENTIFY_VENDOR;
                let id = self.identity;
                let ok = step == self.identify
                    && match step {
                        0 => id.vendor_id == value,
                        1 => id.product_code == value,
                        2 => id.revision >= value,
                        3 => id.revision <= value,
                        4 => id.serial >= value,
                        _ => id.serial <= value,
                    };
                if !ok {
                    self.identify = 0;
                    None
                } else if step == 5 {
                    self.identify = 0;
                    Some(response_frame(cs::IDENTIFY_SLAVE, &[]))
                } else {
                    self.identify += 1;
                    None
                }
            }
            cs::IDENTIFY_NON_CONFIGURED if self.non_configured() => {
                Some(response_frame(cs::IDENTIFY_NON_CONFIGURED_SLAVE, &[]))
            }
            cs::FASTSCAN
                if self.non_configured()
                    && (self.mode == LssMode::Waiting || self.fastscan_in_any_state) =>
            {
                self.fastscan(value, p[4], p[5], p[6], &mut events)
            }
            _ => None,
        };
        (answer, events)
    }

    fn fastscan(
        &mut self,
        id_number: u32,
        bit_checked: u8,
        sub: u8,
        next: u8,
        events: &mut Vec<LssSlaveEvent>,
    ) -> Option<Frame> {
        if bit_checked == FASTSCAN_RESET {
            self.lss_pos = 0;
            return Some(response_frame(cs::IDENTIFY_SLAVE, &[]));
        }
        if bit_checked > 31 || sub > 3 || next > 3 || sub != self.lss_pos {
            return None;
        }
        let mask = u32::MAX << bit_checked;
        if (self.identity.parts()[usize::from(sub)] ^ id_number) & mask != 0 {
            return None;
        }
        if bit_checked == 0 {
            self.lss_pos = next;
            if next < sub {
                self.set_mode(LssMode::Configuration, events);
            }
        }
        Some(response_frame(cs::IDENTIFY_SLAVE, &[]))
    }

    fn set_mode(&mut self, mode: LssMode, events: &mut Vec<LssSlaveEvent>) {
        if self.mode != mode {
            self.mode = mode;
            events.push(LssSlaveEvent::ModeChanged(mode));
        }
        self.selective = 0;
    }

    fn enter_waiting(&mut self, events: &mut Vec<LssSlaveEvent>) {
        self.set_mode(LssMode::Waiting, events);
        if self.active == UNCONFIGURED_NODE_ID && self.pending != UNCONFIGURED_NODE_ID {
            self.active = self.pending;
            events.push(LssSlaveEvent::ApplyNodeId(self.active));
        }
    }
}
