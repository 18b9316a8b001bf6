//! Emergency objects (CiA 301 §7.2.7): decoding, error code names from the
//! CiA 301 generic table and the CiA 402 (drives) table, error register
//! bits, a per-node EMCY consumer and a producer helper.
//!
//! An EMCY frame is 0x080+n with 8 bytes: error code (u16 little-endian),
//! error register (object 0x1001) and 5 manufacturer-specific bytes. Code
//! 0x0000 ("error reset or no error") tells that the node's errors are gone.

use std::collections::{BTreeMap, VecDeque};
use std::fmt;
use std::time::Duration;

use cangate_can::{CanId, Frame, FrameKind};

use crate::ids::{CobFunction, NodeId, cob};

/// One emergency message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Emcy {
    /// The producing node.
    pub node: NodeId,
    /// Emergency error code.
    pub code: u16,
    /// Error register (object 0x1001) at the time of the error.
    pub register: u8,
    /// Manufacturer-specific error field.
    pub manufacturer: [u8; 5],
}

impl Emcy {
    /// Decodes an EMCY frame (0x081..=0x0FF, classic data frame, exactly 8
    /// bytes); `None` for anything else.
    pub fn decode(frame: &Frame) -> Option<Emcy> {
        let node = emcy_node(frame)?;
        let &[lo, hi, register, m0, m1, m2, m3, m4] = frame.data() else {
            return None;
        };
        Some(Emcy {
            node,
            code: u16::from_le_bytes([lo, hi]),
            register,
            manufacturer: [m0, m1, m2, m3, m4],
        })
    }

    /// The frame carrying this message.
    pub fn to_frame(&self) -> Frame {
        emcy_frame(self.node, self.code, self.register, self.manufacturer)
    }

    /// True for code 0x0000 (error reset or no error).
    pub fn is_reset(&self) -> bool {
        self.code == 0
    }

    /// The name of the error code, see [`error_code_name`].
    pub fn code_name(&self) -> &'static str {
        error_code_name(self.code)
    }

    /// The decoded error register.
    pub fn error_register(&self) -> ErrorRegister {
        ErrorRegister(self.register)
    }
}

impl fmt::Display for Emcy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "node {} EMCY 0x{:04X} ({}), register 0x{:02X} [{}], manufacturer {:02X?}",
            self.node,
            self.code,
            self.code_name(),
            self.register,
            self.error_register(),
            self.manufacturer
        )
    }
}

/// The node of a 0x081..=0x0FF classic data frame.
fn emcy_node(frame: &Frame) -> Option<NodeId> {
    if frame.kind() != FrameKind::Data || frame.is_fd() || frame.is_extended() {
        return None;
    }
    match CobFunction::classify(frame.raw_id() as u16) {
        CobFunction::Emcy(node) => Some(node),
        _ => None,
    }
}

/// An EMCY frame: 0x080+n, `[code lo, code hi, register, manufacturer…]`.
pub fn emcy_frame(node: NodeId, code: u16, register: u8, manufacturer: [u8; 5]) -> Frame {
    let [lo, hi] = code.to_le_bytes();
    let [m0, m1, m2, m3, m4] = manufacturer;
    Frame::new(
        CanId::Standard(cob::EMCY + u16::from(node.get())),
        &[lo, hi, register, m0, m1, m2, m3, m4],
    )
    .expect("EMCY frame is a valid classic frame")
}

/// The error register (object 0x1001).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct ErrorRegister(pub u8);

impl ErrorRegister {
    /// Bit 0: generic error.
    pub const GENERIC: u8 = 0x01;
    /// Bit 1: current.
    pub const CURRENT: u8 = 0x02;
    /// Bit 2: voltage.
    pub const VOLTAGE: u8 = 0x04;
    /// Bit 3: temperature.
    pub const TEMPERATURE: u8 = 0x08;
    /// Bit 4: communication error (overrun, error state).
    pub const COMMUNICATION: u8 = 0x10;
    /// Bit 5: device profile specific.
    pub const DEVICE_PROFILE: u8 = 0x20;
    /// Bit 6: reserved (always 0).
    pub const RESERVED: u8 = 0x40;
    /// Bit 7: manufacturer specific.
    pub const MANUFACTURER: u8 = 0x80;

    const NAMES: [&'static str; 8] = [
        "generic",
        "current",
        "voltage",
        "temperature",
        "communication",
        "device profile specific",
        "reserved",
        "manufacturer specific",
    ];

    /// True if any bit of `mask` is set.
    pub fn contains(self, mask: u8) -> bool {
        self.0 & mask != 0
    }

    /// The names of the set bits, least significant first.
    pub fn names(self) -> impl Iterator<Item = &'static str> {
        (0..8)
            .filter(move |bit| self.0 & (1 << bit) != 0)
            .map(|bit| Self::NAMES[bit])
    }
}

impl fmt::Display for ErrorRegister {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.0 == 0 {
            return f.write_str("no error");
        }
        for (i, name) in self.names().enumerate() {
            if i > 0 {
                f.write_str(", ")?;
            }
            f.write_str(name)?;
        }
        Ok(())
    }
}

/// The name of an emergency error code.
///
/// The exact code is looked up first in the CiA 301 generic table and the
/// CiA 402 drive table; otherwise the code falls back to its sub-group
/// (`0xXXX0`), its class (`0xXX00`), then its group (`0xX000`), so every
/// code gets a meaningful name. Codes outside every group (0x0001..=0x0FFF,
/// 0xA000..=0xEFFF) are "unknown error code".
pub fn error_code_name(code: u16) -> &'static str {
    if code == 0 {
        return "error reset or no error";
    }
    [code, code & 0xFFF0, code & 0xFF00, code & 0xF000]
        .into_iter()
        .filter(|&c| c != 0)
        .find_map(exact_code_name)
        .unwrap_or("unknown error code")
}

/// Exact entries of the CiA 301 and CiA 402 tables (CiA 301 names where
/// both define a code).
fn exact_code_name(code: u16) -> Option<&'static str> {
    Some(match code {
        // CiA 301 generic table.
        0x1000 => "generic error",
        0x2000 => "current",
        0x2100 => "current, device input side",
        0x2200 => "current inside the device",
        0x2300 => "current, device output side",
        0x3000 => "voltage",
        0x3100 => "mains voltage",
        0x3200 => "voltage inside the device",
        0x3300 => "output voltage",
        0x4000 => "temperature",
        0x4100 => "ambient temperature",
        0x4200 => "device temperature",
        0x5000 => "device hardware",
        0x6000 => "device software",
        0x6100 => "internal software",
        0x6200 => "user software",
        0x6300 => "data set",
        0x7000 => "additional modules",
        0x8000 => "monitoring",
        0x8100 => "communication",
        0x8110 => "CAN overrun (objects lost)",
        0x8120 => "CAN in error passive mode",
        0x8130 => "life guard error or heartbeat error",
        0x8140 => "recovered from bus off",
        0x8150 => "CAN-ID collision",
        0x8200 => "protocol error",
        0x8210 => "PDO not processed due to length error",
        0x8220 => "PDO length exceeded",
        0x8230 => "DAM MPDO not processed, destination object not available",
        0x8240 => "unexpected SYNC data length",
        0x8250 => "RPDO timeout",
        0x9000 => "external error",
        0xF000 => "additional functions",
        0xFF00 => "device specific",
        // CiA 402 (IEC 61800-7-201) drive table.
        0x2110 => "short circuit/earth leakage (input)",
        0x2120 => "earth leakage (input)",
        0x2121 => "earth leakage phase L1",
        0x2122 => "earth leakage phase L2",
        0x2123 => "earth leakage phase L3",
        0x2130 => "short circuit (input)",
        0x2131 => "short circuit phases L1-L2",
        0x2132 => "short circuit phases L2-L3",
        0x2133 => "short circuit phases L3-L1",
        0x2211 => "internal current no. 1",
        0x2212 => "internal current no. 2",
        0x2213 => "over-current in ramp function",
        0x2214 => "over-current in the sequence",
        0x2220 => "continuous over-current (device internal)",
        0x2221 => "continuous over-current no. 1",
        0x2222 => "continuous over-current no. 2",
        0x2230 => "short circuit/earth leakage (device internal)",
        0x2240 => "earth leakage (device internal)",
        0x2250 => "short circuit (device internal)",
        0x2310 => "continuous over-current",
        0x2311 => "continuous over-current no. 1",
        0x2312 => "continuous over-current no. 2",
        0x2320 => "short circuit/earth leakage (motor-side)",
        0x2330 => "earth leakage (motor-side)",
        0x2331 => "earth leakage phase U",
        0x2332 => "earth leakage phase V",
        0x2333 => "earth leakage phase W",
        0x2340 => "short circuit (motor-side)",
        0x2341 => "short circuit phases U-V",
        0x2342 => "short circuit phases V-W",
        0x2343 => "short circuit phases W-U",
        0x3110 => "mains over-voltage",
        0x3111 => "mains over-voltage phase L1",
        0x3112 => "mains over-voltage phase L2",
        0x3113 => "mains over-voltage phase L3",
        0x3120 => "mains under-voltage",
        0x3121 => "mains under-voltage phase L1",
        0x3122 => "mains under-voltage phase L2",
        0x3123 => "mains under-voltage phase L3",
        0x3130 => "phase failure",
        0x3131 => "phase failure L1",
        0x3132 => "phase failure L2",
        0x3133 => "phase failure L3",
        0x3134 => "phase sequence",
        0x3140 => "mains frequency",
        0x3141 => "mains frequency too great",
        0x3142 => "mains frequency too small",
        0x3210 => "DC link over-voltage",
        0x3211 => "DC link over-voltage no. 1",
        0x3212 => "DC link over-voltage no. 2",
        0x3220 => "DC link under-voltage",
        0x3221 => "DC link under-voltage no. 1",
        0x3222 => "DC link under-voltage no. 2",
        0x3230 => "load error",
        0x3310 => "output over-voltage",
        0x3311 => "output over-voltage phase U",
        0x3312 => "output over-voltage phase V",
        0x3313 => "output over-voltage phase W",
        0x3320 => "armature circuit",
        0x3321 => "armature circuit interrupted",
        0x3330 => "field circuit",
        0x3331 => "field circuit interrupted",
        0x4110 => "excess ambient temperature",
        0x4120 => "too low ambient temperature",
        0x4130 => "temperature supply air",
        0x4140 => "temperature air outlet",
        0x4210 => "excess temperature device",
        0x4220 => "too low temperature device",
        0x4300 => "drive temperature",
        0x4310 => "excess temperature drive",
        0x4320 => "too low temperature drive",
        0x4400 => "supply temperature",
        0x4410 => "excess temperature supply",
        0x4420 => "too low temperature supply",
        0x5100 => "supply",
        0x5110 => "supply low voltage",
        0x5111 => "U1 = supply ±15 V",
        0x5112 => "U2 = supply +24 V",
        0x5113 => "U3 = supply +5 V",
        0x5120 => "supply intermediate circuit",
        0x5200 => "control",
        0x5210 => "measurement circuit",
        0x5220 => "computing circuit",
        0x5300 => "operating unit",
        0x5400 => "power section",
        0x5410 => "output stages",
        0x5420 => "chopper",
        0x5430 => "input stages",
        0x5440 => "contacts",
        0x5441 => "contact 1 (manufacturer specific)",
        0x5442 => "contact 2 (manufacturer specific)",
        0x5443 => "contact 3 (manufacturer specific)",
        0x5444 => "contact 4 (manufacturer specific)",
        0x5445 => "contact 5 (manufacturer specific)",
        0x5450 => "fuses",
        0x5500 => "data storage",
        0x5510 => "working memory",
        0x5520 => "program memory",
        0x5530 => "non-volatile data memory",
        0x6010 => "software reset (watchdog)",
        0x6310 => "loss of parameters",
        0x6320 => "parameter error",
        0x7100 => "power",
        0x7110 => "brake chopper",
        0x7111 => "failure brake chopper",
        0x7112 => "over-current brake chopper",
        0x7113 => "protective circuit brake chopper",
        0x7120 => "motor",
        0x7121 => "motor blocked",
        0x7122 => "motor error or commutation malfunction",
        0x7123 => "motor tilted",
        0x7200 => "measurement circuit",
        0x7300 => "sensor",
        0x7301 => "tacho fault",
        0x7302 => "tacho wrong polarity",
        0x7303 => "resolver 1 fault",
        0x7304 => "resolver 2 fault",
        0x7305 => "incremental sensor 1 fault",
        0x7306 => "incremental sensor 2 fault",
        0x7307 => "incremental sensor 3 fault",
        0x7310 => "speed",
        0x7320 => "position",
        0x7400 => "computation circuit",
        0x7500 => "communication",
        0x7510 => "serial interface no. 1",
        0x7520 => "serial interface no. 2",
        0x7600 => "data storage (external)",
        0x8300 => "torque control",
        0x8311 => "excess torque",
        0x8312 => "difficult start up",
        0x8313 => "standstill torque",
        0x8321 => "insufficient torque",
        0x8331 => "torque fault",
        0x8400 => "velocity speed controller",
        0x8500 => "position controller",
        0x8600 => "positioning controller",
        0x8611 => "following error",
        0x8612 => "reference limit",
        0x8700 => "sync controller",
        0x8800 => "winding controller",
        0x8900 => "process data monitoring",
        0x8A00 => "control",
        0xF001 => "deceleration",
        0xF002 => "sub-synchronous run",
        0xF003 => "lifting mechanism",
        0xF004 => "control",
        _ => return None,
    })
}

/// One received EMCY with its reception time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EmcyRecord {
    /// When it was received.
    pub at: Duration,
    /// The message.
    pub emcy: Emcy,
}

/// What the consumer observed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum EmcyEvent {
    /// A node reported an error.
    Error(Emcy),
    /// A node sent "error reset or no error" (code 0x0000).
    Reset {
        /// The reset message (its register tells what is still set).
        emcy: Emcy,
        /// The error that was active until now, if any.
        cleared: Option<Emcy>,
    },
    /// A 0x081..=0x0FF frame that is not an 8-byte EMCY.
    Malformed {
        /// The node.
        node: NodeId,
        /// The payload (empty for a remote frame).
        data: Vec<u8>,
    },
}

/// Per-node EMCY state.
#[derive(Debug, Clone, Default)]
pub struct NodeEmcy {
    /// The latest error not yet cleared by an error reset.
    pub active: Option<Emcy>,
    /// The error register of the latest EMCY (error or reset).
    pub register: u8,
    /// The latest messages, oldest first, at most the consumer's limit.
    pub history: VecDeque<EmcyRecord>,
    /// EMCY messages received (errors and resets).
    pub received: u64,
    /// Malformed frames received.
    pub malformed: u64,
}

/// EMCY consumer for any number of nodes.
#[derive(Debug, Clone)]
pub struct EmcyConsumer {
    history_limit: usize,
    nodes: BTreeMap<NodeId, NodeEmcy>,
}

impl Default for EmcyConsumer {
    fn default() -> Self {
        Self::new(Self::DEFAULT_HISTORY)
    }
}

impl EmcyConsumer {
    /// Default per-node history length.
    pub const DEFAULT_HISTORY: usize = 32;

    /// A consumer keeping the last `history_limit` messages per node.
    pub fn new(history_limit: usize) -> Self {
        EmcyConsumer {
            history_limit,
            nodes: BTreeMap::new(),
        }
    }

    /// Handles a received frame; frames other than 0x081..=0x0FF data frames
    /// are ignored (0x080 is SYNC).
    pub fn on_frame(&mut self, frame: &Frame, now: Duration) -> Option<EmcyEvent> {
        let node = match (frame.kind(), frame.is_extended()) {
            (FrameKind::Error, _) | (_, true) => return None,
            _ => match CobFunction::classify(frame.raw_id() as u16) {
                CobFunction::Emcy(node) => node,
                _ => return None,
            },
        };
        let st = self.nodes.entry(node).or_default();
        let Some(emcy) = Emcy::decode(frame) else {
            st.malformed += 1;
            return Some(EmcyEvent::Malformed {
                node,
                data: frame.data().to_vec(),
            });
        };
        st.received += 1;
        st.register = emcy.register;
        if self.history_limit > 0 {
            if st.history.len() >= self.history_limit {
                st.history.pop_front();
            }
            st.history.push_back(EmcyRecord { at: now, emcy });
        }
        Some(if emcy.is_reset() {
            EmcyEvent::Reset {
                emcy,
                cleared: st.active.take(),
            }
        } else {
            st.active = Some(emcy);
            EmcyEvent::Error(emcy)
        })
    }

    /// Everything known about `node`.
    pub fn node(&self, node: NodeId) -> Option<&NodeEmcy> {
        self.nodes.get(&node)
    }

    /// The node's active error, if any.
    pub fn active(&self, node: NodeId) -> Option<&Emcy> {
        self.node(node)?.active.as_ref()
    }

    /// The node's recent messages, oldest first.
    pub fn history(&self, node: NodeId) -> impl Iterator<Item = &EmcyRecord> {
        self.node(node).into_iter().flat_map(|st| st.history.iter())
    }

    /// All nodes with an active error.
    pub fn active_errors(&self) -> impl Iterator<Item = &Emcy> {
        self.nodes.values().filter_map(|st| st.active.as_ref())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn n(id: u32) -> NodeId {
        NodeId::new(id).unwrap()
    }

    fn frame(id: u16, data: &[u8]) -> Frame {
        Frame::new(CanId::Standard(id), data).unwrap()
    }

    #[test]
    fn decodes_continuous_over_current() {
        let f = frame(0x085, &[0x10, 0x23, 0x02, 0, 0, 0, 0, 0]);
        let e = Emcy::decode(&f).unwrap();
        assert_eq!(
            e,
            Emcy {
                node: n(5),
                code: 0x2310,
                register: 0x02,
                manufacturer: [0; 5]
            }
        );
        assert_eq!(e.code_name(), "continuous over-current");
        assert_eq!(e.error_register().names().collect::<Vec<_>>(), ["current"]);
        assert!(e.error_register().contains(ErrorRegister::CURRENT));
        assert_eq!(e.to_frame(), f);
        assert_eq!(
            e.to_string(),
            "node 5 EMCY 0x2310 (continuous over-current), register 0x02 [current], \
             manufacturer [00, 00, 00, 00, 00]"
        );
    }

    #[test]
    fn producer_frame_bytes() {
        let f = emcy_frame(n(0x7F), 0x8611, 0x81, [1, 2, 3, 4, 5]);
        assert_eq!(f.id(), CanId::Standard(0x0FF));
        assert_eq!(f.data(), &[0x11, 0x86, 0x81, 1, 2, 3, 4, 5]);
    }

    #[test]
    fn rejects_non_emcy_frames() {
        assert_eq!(Emcy::decode(&frame(0x080, &[0; 8])), None);
        assert_eq!(Emcy::decode(&frame(0x085, &[0; 7])), None);
        assert_eq!(Emcy::decode(&frame(0x185, &[0; 8])), None);
        assert_eq!(
            Emcy::decode(&Frame::new(CanId::Extended(0x085), &[0; 8]).unwrap()),
            None
        );
        assert_eq!(
            Emcy::decode(&Frame::new_remote(CanId::Standard(0x085), 8).unwrap()),
            None
        );
    }

    #[test]
    fn code_names() {
        assert_eq!(error_code_name(0x0000), "error reset or no error");
        assert_eq!(error_code_name(0x3210), "DC link over-voltage");
        assert_eq!(error_code_name(0x8611), "following error");
        assert_eq!(
            error_code_name(0x8130),
            "life guard error or heartbeat error"
        );
        assert_eq!(error_code_name(0x7305), "incremental sensor 1 fault");
        assert_eq!(error_code_name(0x7121), "motor blocked");
        // Fallbacks: sub-group, class, group.
        assert_eq!(error_code_name(0x3114), "mains over-voltage");
        assert_eq!(error_code_name(0x2399), "current, device output side");
        assert_eq!(error_code_name(0x8F12), "monitoring");
        assert_eq!(error_code_name(0xFF42), "device specific");
        assert_eq!(error_code_name(0xF0AB), "additional functions");
        assert_eq!(error_code_name(0x0001), "unknown error code");
        assert_eq!(error_code_name(0xB000), "unknown error code");
        // Every code in a defined group has a name of that group or finer.
        for code in 0x1000u16..=0x9FFF {
            assert_ne!(error_code_name(code), "unknown error code", "{code:04X}");
        }
    }

    #[test]
    fn error_register_names() {
        assert_eq!(ErrorRegister(0).to_string(), "no error");
        assert_eq!(
            ErrorRegister(0x95).to_string(),
            "generic, voltage, communication, manufacturer specific"
        );
        assert_eq!(ErrorRegister(0xFF).names().count(), 8);
    }

    #[test]
    fn consumer_tracks_active_error_and_reset() {
        let mut c = EmcyConsumer::default();
        let err = frame(0x085, &[0x10, 0x23, 0x03, 0, 0, 0, 0, 0]);
        let Some(EmcyEvent::Error(e)) = c.on_frame(&err, Duration::from_secs(1)) else {
            panic!("expected an error event");
        };
        assert_eq!(c.active(n(5)), Some(&e));
        assert_eq!(c.active_errors().count(), 1);
        assert_eq!(c.node(n(5)).unwrap().register, 0x03);
        let reset = frame(0x085, &[0; 8]);
        match c.on_frame(&reset, Duration::from_secs(2)) {
            Some(EmcyEvent::Reset { emcy, cleared }) => {
                assert!(emcy.is_reset());
                assert_eq!(cleared, Some(e));
            }
            other => panic!("unexpected {other:?}"),
        }
        assert_eq!(c.active(n(5)), None);
        assert_eq!(c.node(n(5)).unwrap().register, 0);
        let hist: Vec<_> = c.history(n(5)).map(|r| (r.at, r.emcy.code)).collect();
        assert_eq!(
            hist,
            [
                (Duration::from_secs(1), 0x2310),
                (Duration::from_secs(2), 0)
            ]
        );
        assert_eq!(c.history(n(6)).count(), 0);
        // SYNC and other ids are ignored.
        assert_eq!(c.on_frame(&frame(0x080, &[]), Duration::ZERO), None);
        assert_eq!(c.on_frame(&frame(0x705, &[0]), Duration::ZERO), None);
    }

    #[test]
    fn consumer_history_is_bounded_and_malformed_counted() {
        let mut c = EmcyConsumer::new(4);
        for i in 0..10u16 {
            let f = emcy_frame(n(1), 0x1000 + i, 1, [0; 5]);
            c.on_frame(&f, Duration::from_millis(u64::from(i)));
        }
        let codes: Vec<u16> = c.history(n(1)).map(|r| r.emcy.code).collect();
        assert_eq!(codes, [0x1006, 0x1007, 0x1008, 0x1009]);
        assert_eq!(c.node(n(1)).unwrap().received, 10);
        assert_eq!(
            c.on_frame(&frame(0x081, &[1, 2, 3]), Duration::ZERO),
            Some(EmcyEvent::Malformed {
                node: n(1),
                data: vec![1, 2, 3]
            })
        );
        assert_eq!(c.node(n(1)).unwrap().malformed, 1);
        assert_eq!(c.active(n(1)).unwrap().code, 0x1009);
    }

    proptest! {
        #[test]
        fn random_frames_never_panic(
            frames in proptest::collection::vec(
                (0u32..0x800, any::<bool>(), any::<bool>(),
                 proptest::collection::vec(any::<u8>(), 0..=8)),
                0..64,
            )
        ) {
            let mut c = EmcyConsumer::new(3);
            for (i, (id, extended, remote, data)) in frames.into_iter().enumerate() {
                let cid = if extended { CanId::Extended(id) } else { CanId::Standard(id as u16) };
                let f = if remote {
                    Frame::new_remote(cid, data.len() as u8).unwrap()
                } else {
                    Frame::new(cid, &data).unwrap()
                };
                if let Some(EmcyEvent::Error(e) | EmcyEvent::Reset { emcy: e, .. }) =
                    c.on_frame(&f, Duration::from_millis(i as u64))
                {
                    let _ = e.to_string();
                    prop_assert_eq!(e.to_frame(), f);
                }
            }
            for (_, st) in c.nodes.iter() {
                prop_assert!(st.history.len() <= 3);
            }
        }
    }
}
