//! Validated CANopen identifiers in CiA 301 terms: node ids, object
//! dictionary addresses and the predefined connection set (COB-ID map).

use std::fmt;

/// A CANopen node id, 1..=127.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct NodeId(u8);

/// A node id outside 1..=127.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("node id {0} is out of range (CANopen node ids are 1..=127)")]
pub struct BadNodeId(pub u32);

impl NodeId {
    /// Validates a node id.
    pub fn new(id: u32) -> Result<Self, BadNodeId> {
        if (1..=127).contains(&id) {
            Ok(NodeId(id as u8))
        } else {
            Err(BadNodeId(id))
        }
    }
    /// The raw value.
    pub fn get(self) -> u8 {
        self.0
    }
}

impl fmt::Display for NodeId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// An object dictionary index.
pub type Index = u16;
/// An object dictionary sub-index.
pub type SubIndex = u8;

/// An object dictionary address: index and sub-index, shown as `0x1018:01`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ObjectAddress {
    /// Index.
    pub index: Index,
    /// Sub-index.
    pub sub: SubIndex,
}

impl ObjectAddress {
    /// Builds an address.
    pub const fn new(index: Index, sub: SubIndex) -> Self {
        ObjectAddress { index, sub }
    }
}

impl fmt::Display for ObjectAddress {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:04X}:{:02X}", self.index, self.sub)
    }
}

/// COB-ID function codes of the CiA 301 predefined connection set.
pub mod cob {
    /// NMT module control (master → all).
    pub const NMT: u16 = 0x000;
    /// SYNC.
    pub const SYNC: u16 = 0x080;
    /// EMCY base (+ node id).
    pub const EMCY: u16 = 0x080;
    /// TIME stamp.
    pub const TIME: u16 = 0x100;
    /// TPDO1..4 bases (+ node id).
    pub const TPDO: [u16; 4] = [0x180, 0x280, 0x380, 0x480];
    /// RPDO1..4 bases (+ node id).
    pub const RPDO: [u16; 4] = [0x200, 0x300, 0x400, 0x500];
    /// SDO server → client (tx from the node's view) base (+ node id).
    pub const SDO_TX: u16 = 0x580;
    /// SDO client → server (rx from the node's view) base (+ node id).
    pub const SDO_RX: u16 = 0x600;
    /// NMT error control: heartbeat, boot-up, node guarding (+ node id).
    pub const HEARTBEAT: u16 = 0x700;
}

/// What a standard-frame COB-ID means in the predefined connection set.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CobFunction {
    /// NMT command.
    Nmt,
    /// SYNC.
    Sync,
    /// EMCY from a node.
    Emcy(NodeId),
    /// TIME stamp.
    Time,
    /// TPDO n (1..=4) from a node.
    Tpdo(u8, NodeId),
    /// RPDO n (1..=4) to a node.
    Rpdo(u8, NodeId),
    /// SDO response from a server node.
    SdoTx(NodeId),
    /// SDO request to a server node.
    SdoRx(NodeId),
    /// Heartbeat / boot-up of a node.
    Heartbeat(NodeId),
    /// Not part of the predefined set.
    Other,
}

impl CobFunction {
    /// Classifies an 11-bit COB-ID.
    pub fn classify(cob_id: u16) -> Self {
        match cob_id {
            0x000 => return CobFunction::Nmt,
            0x080 => return CobFunction::Sync,
            0x100 => return CobFunction::Time,
            _ => {}
        }
        let node = match NodeId::new((cob_id & 0x7F) as u32) {
            Ok(n) => n,
            Err(_) => return CobFunction::Other,
        };
        match cob_id & 0x780 {
            0x080 => CobFunction::Emcy(node),
            0x180 => CobFunction::Tpdo(1, node),
            0x200 => CobFunction::Rpdo(1, node),
            0x280 => CobFunction::Tpdo(2, node),
            0x300 => CobFunction::Rpdo(2, node),
            0x380 => CobFunction::Tpdo(3, node),
            0x400 => CobFunction::Rpdo(3, node),
            0x480 => CobFunction::Tpdo(4, node),
            0x500 => CobFunction::Rpdo(4, node),
            0x580 => CobFunction::SdoTx(node),
            0x600 => CobFunction::SdoRx(node),
            0x700 => CobFunction::Heartbeat(node),
            _ => CobFunction::Other,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_id_range() {
        assert!(NodeId::new(0).is_err());
        assert!(NodeId::new(1).is_ok());
        assert!(NodeId::new(127).is_ok());
        assert_eq!(NodeId::new(128), Err(BadNodeId(128)));
    }

    #[test]
    fn classify_predefined_set() {
        let n5 = NodeId::new(5).unwrap();
        assert_eq!(CobFunction::classify(0x000), CobFunction::Nmt);
        assert_eq!(CobFunction::classify(0x080), CobFunction::Sync);
        assert_eq!(CobFunction::classify(0x085), CobFunction::Emcy(n5));
        assert_eq!(CobFunction::classify(0x185), CobFunction::Tpdo(1, n5));
        assert_eq!(CobFunction::classify(0x505), CobFunction::Rpdo(4, n5));
        assert_eq!(CobFunction::classify(0x585), CobFunction::SdoTx(n5));
        assert_eq!(CobFunction::classify(0x605), CobFunction::SdoRx(n5));
        assert_eq!(CobFunction::classify(0x705), CobFunction::Heartbeat(n5));
        assert_eq!(CobFunction::classify(0x780), CobFunction::Other);
    }
}
