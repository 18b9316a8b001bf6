//! Bus states and error counters, and the decoding of SocketCAN error
//! frames into them.

use crate::frame::Frame;

/// The state of a bus as the controller (or the virtual bus) reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BusState {
    /// Error-active: working normally.
    Up,
    /// Error counters above the warning level (96).
    ErrorWarning,
    /// Error counters above 127: the controller may not send active error flags.
    ErrorPassive,
    /// Transmit error counter above 255: the controller left the bus.
    BusOff,
    /// The interface is down or gone; the gateway is reconnecting.
    Down,
}

impl BusState {
    /// Lower-case name, as shown to users.
    pub fn name(self) -> &'static str {
        match self {
            BusState::Up => "up",
            BusState::ErrorWarning => "error-warning",
            BusState::ErrorPassive => "error-passive",
            BusState::BusOff => "bus-off",
            BusState::Down => "down",
        }
    }

    /// Whether frames can be sent in this state.
    pub fn can_send(self) -> bool {
        !matches!(self, BusState::BusOff | BusState::Down)
    }
}

impl std::fmt::Display for BusState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// State plus the controller's error counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BusStatus {
    /// The state.
    pub state: BusState,
    /// Transmit error counter (TEC), where known.
    pub tx_errors: u16,
    /// Receive error counter (REC), where known.
    pub rx_errors: u16,
}

impl BusStatus {
    /// A healthy bus with zero counters.
    pub const UP: BusStatus = BusStatus {
        state: BusState::Up,
        tx_errors: 0,
        rx_errors: 0,
    };
    /// A bus that is down.
    pub const DOWN: BusStatus = BusStatus {
        state: BusState::Down,
        tx_errors: 0,
        rx_errors: 0,
    };

    /// A status with zero counters.
    pub fn new(state: BusState) -> Self {
        BusStatus {
            state,
            tx_errors: 0,
            rx_errors: 0,
        }
    }
}

// SocketCAN error class bits (linux/can/error.h).
const CAN_ERR_CRTL: u32 = 0x0000_0004;
const CAN_ERR_BUSOFF: u32 = 0x0000_0040;
const CAN_ERR_RESTARTED: u32 = 0x0000_0100;
const CAN_ERR_CNT: u32 = 0x0000_0200;
// data[1] controller status bits.
const CAN_ERR_CRTL_RX_WARNING: u8 = 0x04;
const CAN_ERR_CRTL_TX_WARNING: u8 = 0x08;
const CAN_ERR_CRTL_RX_PASSIVE: u8 = 0x10;
const CAN_ERR_CRTL_TX_PASSIVE: u8 = 0x20;
const CAN_ERR_CRTL_ACTIVE: u8 = 0x40;

/// Derives the bus status an error frame reports, given the previous one.
/// Returns `None` when the frame says nothing about the state (e.g. a lost
/// arbitration or a protocol violation report alone).
pub fn status_from_error_frame(frame: &Frame, previous: BusStatus) -> Option<BusStatus> {
    if !frame.is_error() {
        return None;
    }
    let class = frame.raw_id();
    let d = frame.data();
    let byte = |i: usize| d.get(i).copied().unwrap_or(0);
    let mut status = previous;
    let mut changed = false;
    if class & CAN_ERR_CNT != 0 {
        status.tx_errors = byte(6) as u16;
        status.rx_errors = byte(7) as u16;
        changed = true;
    }
    if class & CAN_ERR_BUSOFF != 0 {
        status.state = BusState::BusOff;
        return Some(status);
    }
    if class & CAN_ERR_RESTARTED != 0 {
        status.state = BusState::Up;
        changed = true;
    }
    if class & CAN_ERR_CRTL != 0 {
        let c = byte(1);
        if c & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE) != 0 {
            status.state = BusState::ErrorPassive;
        } else if c & (CAN_ERR_CRTL_RX_WARNING | CAN_ERR_CRTL_TX_WARNING) != 0 {
            status.state = BusState::ErrorWarning;
        } else if c & CAN_ERR_CRTL_ACTIVE != 0 {
            status.state = BusState::Up;
        }
        changed = true;
    }
    changed.then_some(status)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decodes_controller_states_and_counters() {
        let passive = Frame::new_error(CAN_ERR_CRTL | CAN_ERR_CNT, [0, 0x20, 0, 0, 0, 0, 130, 5]);
        let s = status_from_error_frame(&passive, BusStatus::UP).unwrap();
        assert_eq!(s.state, BusState::ErrorPassive);
        assert_eq!((s.tx_errors, s.rx_errors), (130, 5));

        let warn = Frame::new_error(CAN_ERR_CRTL, [0, 0x04, 0, 0, 0, 0, 0, 0]);
        assert_eq!(
            status_from_error_frame(&warn, BusStatus::UP).unwrap().state,
            BusState::ErrorWarning
        );
        let off = Frame::new_error(CAN_ERR_BUSOFF, [0; 8]);
        assert_eq!(
            status_from_error_frame(&off, s).unwrap().state,
            BusState::BusOff
        );
        let restarted = Frame::new_error(CAN_ERR_RESTARTED, [0; 8]);
        assert_eq!(
            status_from_error_frame(&restarted, s).unwrap().state,
            BusState::Up
        );
        // Lost arbitration alone says nothing about the state.
        let lostarb = Frame::new_error(0x2, [0; 8]);
        assert_eq!(status_from_error_frame(&lostarb, BusStatus::UP), None);
    }
}
