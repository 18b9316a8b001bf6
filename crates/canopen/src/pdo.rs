//! PDOs from the master's side (CiA 301 §7.2.2): the SDO write sequence that
//! configures a remote node's RPDO or TPDO, and encoding/decoding of PDO
//! payloads with a mapping and the object dictionary.

use crate::ids::{NodeId, ObjectAddress};
use crate::od::ObjectDictionary;
use crate::value::{DataType, Value, ValueError};

/// Receive (master → node) or transmit (node → master) PDO.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum PdoKind {
    /// RPDO: the node receives it.
    Rpdo,
    /// TPDO: the node transmits it.
    Tpdo,
}

impl PdoKind {
    /// Communication parameter index of PDO `num` (1-based).
    pub fn comm_index(self, num: u16) -> u16 {
        match self {
            PdoKind::Rpdo => 0x1400 + num - 1,
            PdoKind::Tpdo => 0x1800 + num - 1,
        }
    }
    /// Mapping parameter index of PDO `num` (1-based).
    pub fn map_index(self, num: u16) -> u16 {
        match self {
            PdoKind::Rpdo => 0x1600 + num - 1,
            PdoKind::Tpdo => 0x1A00 + num - 1,
        }
    }
    /// The predefined-connection-set COB-ID of PDO 1..=4.
    pub fn default_cob_id(self, num: u16, node: NodeId) -> Option<u16> {
        let base = match (self, num) {
            (PdoKind::Tpdo, 1..=4) => [0x180, 0x280, 0x380, 0x480][num as usize - 1],
            (PdoKind::Rpdo, 1..=4) => [0x200, 0x300, 0x400, 0x500][num as usize - 1],
            _ => return None,
        };
        Some(base + node.get() as u16)
    }
}

/// What a PDO parameter object is, for messages that name the object a
/// configuration step failed on: "COB-ID", "mapping entry 2", …; `None`
/// outside the PDO parameter ranges.
pub fn parameter_name(addr: ObjectAddress) -> Option<String> {
    let (index, sub) = (addr.index, addr.sub);
    let comm = matches!(index, 0x1400..=0x15FF | 0x1800..=0x19FF);
    let map = matches!(index, 0x1600..=0x17FF | 0x1A00..=0x1BFF);
    let what = match (comm, map, sub) {
        (true, _, 0) => "highest sub-index".to_string(),
        (true, _, 1) => "COB-ID".to_string(),
        (true, _, 2) => "transmission type".to_string(),
        (true, _, 3) => "inhibit time".to_string(),
        (true, _, 5) => "event timer".to_string(),
        (true, _, 6) => "SYNC start value".to_string(),
        (true, _, n) => format!("sub-index {n}"),
        (_, true, 0) => "number of mapped objects".to_string(),
        (_, true, n) => format!("mapping entry {n}"),
        _ => return None,
    };
    Some(what)
}

/// One mapped object: its address and length in bits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MappedObject {
    /// The object.
    pub addr: ObjectAddress,
    /// Its length in bits (whole bytes: 8, 16, 24, 32, …, 64).
    pub bits: u8,
}

impl MappedObject {
    /// The 32-bit mapping entry `index << 16 | sub << 8 | bits`.
    pub fn entry(self) -> u32 {
        (self.addr.index as u32) << 16 | (self.addr.sub as u32) << 8 | self.bits as u32
    }

    /// Parses a mapping entry.
    pub fn from_entry(e: u32) -> Self {
        MappedObject {
            addr: ObjectAddress::new((e >> 16) as u16, (e >> 8) as u8),
            bits: e as u8,
        }
    }
}

/// A PDO configuration to apply to a node.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PdoConfig {
    /// RPDO or TPDO.
    pub kind: PdoKind,
    /// PDO number, 1..=512.
    pub num: u16,
    /// 11-bit COB-ID.
    pub cob_id: u16,
    /// Transmission type: 0 acyclic synchronous, 1..=240 every n-th SYNC,
    /// 254/255 event-driven.
    pub transmission_type: u8,
    /// TPDO inhibit time in units of 100 µs (0 = none).
    pub inhibit_time: u16,
    /// Event timer in ms (0 = off).
    pub event_timer_ms: u16,
    /// The mapped objects, in payload order.
    pub mapping: Vec<MappedObject>,
}

/// Why a PDO configuration or payload is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PdoError {
    /// More than 64 bits mapped.
    #[error("the mapping needs {0} bits; a classic CAN PDO carries at most 64")]
    TooLong(u32),
    /// A mapped length that is not whole bytes.
    #[error("mapped object {0} has {1} bits; only whole bytes are supported")]
    NotWholeBytes(ObjectAddress, u8),
    /// PDO number outside 1..=512.
    #[error("PDO number {0} is out of range (1..=512)")]
    BadNumber(u16),
    /// Payload shorter than the mapping.
    #[error("PDO payload has {got} bytes, the mapping needs {need}")]
    ShortPayload {
        /// Bytes needed.
        need: usize,
        /// Bytes received.
        got: usize,
    },
    /// A value for an object the mapping does not contain, or missing.
    #[error("no value given for mapped object {0}")]
    MissingValue(ObjectAddress),
    /// A value of the wrong type/size.
    #[error("mapped object {0}: {1}")]
    Value(ObjectAddress, ValueError),
}

impl PdoConfig {
    /// Checks the mapping fits one classic frame in whole bytes.
    pub fn validate(&self) -> Result<(), PdoError> {
        if !(1..=512).contains(&self.num) {
            return Err(PdoError::BadNumber(self.num));
        }
        let mut total = 0u32;
        for m in &self.mapping {
            if m.bits == 0 || m.bits % 8 != 0 {
                return Err(PdoError::NotWholeBytes(m.addr, m.bits));
            }
            total += m.bits as u32;
        }
        if total > 64 {
            return Err(PdoError::TooLong(total));
        }
        Ok(())
    }

    /// The SDO writes that apply this configuration, in the order CiA 301
    /// prescribes: invalidate the PDO (COB-ID bit 31), set the transmission
    /// parameters, disable the mapping (count 0), write the entries, enable
    /// the mapping (count n), and finally validate the PDO with its COB-ID.
    pub fn sdo_writes(&self) -> Result<Vec<(ObjectAddress, Vec<u8>)>, PdoError> {
        self.sdo_writes_leaving(true)
    }

    /// [`PdoConfig::sdo_writes`], with the last write (the COB-ID made
    /// valid) left out when `enable` is false: the PDO is configured but
    /// stays disabled.
    pub fn sdo_writes_leaving(
        &self,
        enable: bool,
    ) -> Result<Vec<(ObjectAddress, Vec<u8>)>, PdoError> {
        self.validate()?;
        let comm = self.kind.comm_index(self.num);
        let map = self.kind.map_index(self.num);
        let cob = self.cob_id as u32;
        let mut w = vec![
            (
                ObjectAddress::new(comm, 1),
                (cob | 0x8000_0000).to_le_bytes().to_vec(),
            ),
            (ObjectAddress::new(comm, 2), vec![self.transmission_type]),
        ];
        if self.kind == PdoKind::Tpdo {
            w.push((
                ObjectAddress::new(comm, 3),
                self.inhibit_time.to_le_bytes().to_vec(),
            ));
        }
        // RPDO sub-index 5 (deadline monitoring) is optional in CiA 301 and
        // missing on many devices: only written when asked for.
        if self.kind == PdoKind::Tpdo || self.event_timer_ms > 0 {
            w.push((
                ObjectAddress::new(comm, 5),
                self.event_timer_ms.to_le_bytes().to_vec(),
            ));
        }
        w.push((ObjectAddress::new(map, 0), vec![0]));
        for (i, m) in self.mapping.iter().enumerate() {
            w.push((
                ObjectAddress::new(map, i as u8 + 1),
                m.entry().to_le_bytes().to_vec(),
            ));
        }
        w.push((ObjectAddress::new(map, 0), vec![self.mapping.len() as u8]));
        if enable {
            w.push((ObjectAddress::new(comm, 1), cob.to_le_bytes().to_vec()));
        }
        Ok(w)
    }

    /// A PDO as read from a node: the raw COB-ID entry (sub 1, with its
    /// flag bits), transmission type, inhibit time, event timer and the
    /// mapping entries. Returns the configuration and whether the PDO is
    /// valid (bit 31 clear). Entries of 0 bits (dummy gaps some devices
    /// report for unused slots) are kept, so the layout stays exact.
    pub fn from_parameters(
        kind: PdoKind,
        num: u16,
        cob_entry: u32,
        transmission_type: u8,
        inhibit_time: u16,
        event_timer_ms: u16,
        entries: &[u32],
    ) -> (PdoConfig, bool) {
        (
            PdoConfig {
                kind,
                num,
                cob_id: (cob_entry & 0x7FF) as u16,
                transmission_type,
                inhibit_time,
                event_timer_ms,
                mapping: entries
                    .iter()
                    .map(|&e| MappedObject::from_entry(e))
                    .collect(),
            },
            cob_entry & 0x8000_0000 == 0,
        )
    }

    /// The PDO configuration an object dictionary holds by default for a
    /// node (EDS defaults with `$NODEID` resolved); `None` if the PDO does
    /// not exist or is invalid (COB-ID bit 31).
    pub fn from_od(od: &ObjectDictionary, kind: PdoKind, num: u16, node: NodeId) -> Option<Self> {
        let comm = kind.comm_index(num);
        let map = kind.map_index(num);
        let u = |addr: ObjectAddress| {
            od.get(addr)
                .and_then(|v| v.default_for_node(node))
                .and_then(|v| v.as_i128())
        };
        let cob = u(ObjectAddress::new(comm, 1))? as u32;
        if cob & 0x8000_0000 != 0 || cob & 0x2000_0000 != 0 {
            return None;
        }
        let count = u(ObjectAddress::new(map, 0)).unwrap_or(0) as u8;
        let mapping = (1..=count)
            .filter_map(|i| u(ObjectAddress::new(map, i)))
            .map(|e| MappedObject::from_entry(e as u32))
            .filter(|m| m.bits > 0)
            .collect();
        Some(PdoConfig {
            kind,
            num,
            cob_id: (cob & 0x7FF) as u16,
            transmission_type: u(ObjectAddress::new(comm, 2)).unwrap_or(255) as u8,
            inhibit_time: u(ObjectAddress::new(comm, 3)).unwrap_or(0) as u16,
            event_timer_ms: u(ObjectAddress::new(comm, 5)).unwrap_or(0) as u16,
            mapping,
        })
    }

    /// Payload bytes of this PDO.
    pub fn len(&self) -> usize {
        self.mapping.iter().map(|m| m.bits as usize / 8).sum()
    }

    /// True when nothing is mapped.
    pub fn is_empty(&self) -> bool {
        self.mapping.is_empty()
    }

    /// Decodes a received payload into one value per mapped object, typed by
    /// the object dictionary (raw unsigned integers where it does not know
    /// the object).
    pub fn decode(
        &self,
        od: Option<&ObjectDictionary>,
        data: &[u8],
    ) -> Result<Vec<(MappedObject, Value)>, PdoError> {
        let need = self.len();
        if data.len() < need {
            return Err(PdoError::ShortPayload {
                need,
                got: data.len(),
            });
        }
        let mut at = 0;
        let mut out = Vec::with_capacity(self.mapping.len());
        for m in &self.mapping {
            let n = m.bits as usize / 8;
            let bytes = &data[at..at + n];
            at += n;
            let ty = od
                .and_then(|od| od.get(m.addr))
                .map(|v| v.data_type)
                .filter(|t| t.fixed_size() == Some(n))
                .unwrap_or(match n {
                    1 => DataType::Unsigned8,
                    2 => DataType::Unsigned16,
                    3 => DataType::Unsigned24,
                    4 => DataType::Unsigned32,
                    5 => DataType::Unsigned40,
                    6 => DataType::Unsigned48,
                    7 => DataType::Unsigned56,
                    _ => DataType::Unsigned64,
                });
            let v = Value::decode(ty, bytes).map_err(|e| PdoError::Value(m.addr, e))?;
            out.push((*m, v));
        }
        Ok(out)
    }

    /// Encodes values (one per mapped object, found by address) into a
    /// payload. An object mapped more than once (dummy entries filling
    /// gaps, often of different sizes) takes its values in order: the
    /// n-th entry of an address the n-th value given for it, or the last
    /// one when fewer are given.
    pub fn encode(&self, values: &[(ObjectAddress, Value)]) -> Result<Vec<u8>, PdoError> {
        let mut data = Vec::with_capacity(self.len());
        let mut used: Vec<(ObjectAddress, usize)> = Vec::new();
        for m in &self.mapping {
            let nth = match used.iter_mut().find(|(a, _)| *a == m.addr) {
                Some((_, n)) => {
                    *n += 1;
                    *n - 1
                }
                None => {
                    used.push((m.addr, 1));
                    0
                }
            };
            let mut given = values.iter().filter(|(a, _)| *a == m.addr);
            let (_, v) = given
                .clone()
                .nth(nth)
                .or_else(|| given.next_back())
                .ok_or(PdoError::MissingValue(m.addr))?;
            let bytes = v.encode();
            if bytes.len() != m.bits as usize / 8 {
                return Err(PdoError::Value(
                    m.addr,
                    ValueError::WrongSize {
                        ty: v.data_type(),
                        expected: m.bits as usize / 8,
                        got: bytes.len(),
                    },
                ));
            }
            data.extend(bytes);
        }
        Ok(data)
    }
}

#[cfg(test)]
mod parameter_tests {
    use super::*;

    #[test]
    fn parameter_names() {
        let n = |i, s| parameter_name(ObjectAddress::new(i, s));
        assert_eq!(n(0x1800, 1).as_deref(), Some("COB-ID"));
        assert_eq!(n(0x1401, 2).as_deref(), Some("transmission type"));
        assert_eq!(n(0x1A03, 0).as_deref(), Some("number of mapped objects"));
        assert_eq!(n(0x1600, 4).as_deref(), Some("mapping entry 4"));
        assert_eq!(n(0x6041, 0), None);
    }

    #[test]
    fn a_disabled_configuration_leaves_the_cob_id_invalid() {
        let node = NodeId::new(5).unwrap();
        let cfg = PdoConfig {
            kind: PdoKind::Tpdo,
            num: 1,
            cob_id: PdoKind::Tpdo.default_cob_id(1, node).unwrap(),
            transmission_type: 1,
            inhibit_time: 0,
            event_timer_ms: 0,
            mapping: vec![MappedObject {
                addr: ObjectAddress::new(0x6041, 0),
                bits: 16,
            }],
        };
        let on = cfg.sdo_writes().unwrap();
        let off = cfg.sdo_writes_leaving(false).unwrap();
        assert_eq!(&on[..on.len() - 1], &off[..]);
        assert_eq!(
            off[0],
            (ObjectAddress::new(0x1800, 1), vec![0x85, 0x01, 0, 0x80])
        );
        assert_eq!(on.last().unwrap().1, vec![0x85, 0x01, 0, 0]);
        let (read, valid) =
            PdoConfig::from_parameters(PdoKind::Tpdo, 1, 0x8000_0185, 1, 0, 0, &[0x6041_0010]);
        assert_eq!((read, valid), (cfg, false));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eds::{Eds, SIM_DRIVE_EDS};

    fn node(n: u32) -> NodeId {
        NodeId::new(n).unwrap()
    }

    #[test]
    fn an_object_mapped_twice_with_different_sizes_encodes_what_it_decoded() {
        // Found by the `pdo` fuzz target: two dummy entries for UNSIGNED8
        // (0x0005), one of 24 and one of 8 bits; encoding took the first
        // decoded value for both and refused the 3-byte value for the
        // 1-byte entry.
        let dummy = ObjectAddress::new(0x0005, 0);
        let cfg = PdoConfig {
            kind: PdoKind::Rpdo,
            num: 1,
            cob_id: 0x205,
            transmission_type: 255,
            inhibit_time: 0,
            event_timer_ms: 0,
            mapping: vec![
                MappedObject {
                    addr: dummy,
                    bits: 24,
                },
                MappedObject {
                    addr: ObjectAddress::new(0x6040, 0),
                    bits: 16,
                },
                MappedObject {
                    addr: dummy,
                    bits: 8,
                },
            ],
        };
        let payload = [1, 2, 3, 0x0F, 0x00, 9];
        let values = cfg.decode(None, &payload).unwrap();
        let pairs: Vec<_> = values.iter().map(|(m, v)| (m.addr, v.clone())).collect();
        assert_eq!(cfg.encode(&pairs).unwrap(), payload);
    }

    #[test]
    fn configuration_follows_the_cia301_procedure_write_for_write() {
        let cfg = PdoConfig {
            kind: PdoKind::Tpdo,
            num: 1,
            cob_id: 0x185,
            transmission_type: 1,
            inhibit_time: 10,
            event_timer_ms: 0,
            mapping: vec![
                MappedObject {
                    addr: ObjectAddress::new(0x6041, 0),
                    bits: 16,
                },
                MappedObject {
                    addr: ObjectAddress::new(0x6064, 0),
                    bits: 32,
                },
            ],
        };
        let writes = cfg.sdo_writes().unwrap();
        let expect: Vec<(u16, u8, Vec<u8>)> = vec![
            (0x1800, 1, vec![0x85, 0x01, 0x00, 0x80]), // invalidate
            (0x1800, 2, vec![0x01]),                   // every SYNC
            (0x1800, 3, vec![0x0A, 0x00]),             // inhibit 1 ms
            (0x1800, 5, vec![0x00, 0x00]),             // no event timer
            (0x1A00, 0, vec![0x00]),                   // disable mapping
            (0x1A00, 1, vec![0x10, 0x00, 0x41, 0x60]), // 0x60410010
            (0x1A00, 2, vec![0x20, 0x00, 0x64, 0x60]), // 0x60640020
            (0x1A00, 0, vec![0x02]),                   // enable mapping
            (0x1800, 1, vec![0x85, 0x01, 0x00, 0x00]), // validate
        ];
        let got: Vec<(u16, u8, Vec<u8>)> = writes
            .into_iter()
            .map(|(a, d)| (a.index, a.sub, d))
            .collect();
        assert_eq!(got, expect);
    }

    #[test]
    fn mapping_limits() {
        let mut cfg = PdoConfig {
            kind: PdoKind::Rpdo,
            num: 1,
            cob_id: 0x205,
            transmission_type: 255,
            inhibit_time: 0,
            event_timer_ms: 0,
            mapping: vec![MappedObject {
                addr: ObjectAddress::new(0x6040, 0),
                bits: 12,
            }],
        };
        assert!(matches!(cfg.validate(), Err(PdoError::NotWholeBytes(..))));
        cfg.mapping = vec![
            MappedObject {
                addr: ObjectAddress::new(0x607A, 0),
                bits: 32
            };
            3
        ];
        assert_eq!(cfg.validate(), Err(PdoError::TooLong(96)));
        // RPDOs have no inhibit time write, and no event timer unless set.
        cfg.mapping.truncate(1);
        assert_eq!(cfg.sdo_writes().unwrap().len(), 6);
        cfg.event_timer_ms = 100;
        assert_eq!(cfg.sdo_writes().unwrap().len(), 7);
    }

    #[test]
    fn defaults_from_the_drive_eds_decode_and_encode() {
        let eds = Eds::parse(SIM_DRIVE_EDS).unwrap();
        let tpdo1 = PdoConfig::from_od(&eds.od, PdoKind::Tpdo, 1, node(5)).unwrap();
        assert_eq!(tpdo1.cob_id, 0x185);
        assert_eq!(
            tpdo1.mapping.iter().map(|m| m.entry()).collect::<Vec<_>>(),
            vec![0x6041_0010, 0x6064_0020]
        );
        let values = tpdo1
            .decode(Some(&eds.od), &[0x37, 0x06, 0xE8, 0x03, 0x00, 0x00])
            .unwrap();
        assert_eq!(values[0].1, Value::Unsigned16(0x0637));
        assert_eq!(values[1].1, Value::Integer32(1000));
        assert!(matches!(
            tpdo1.decode(Some(&eds.od), &[1, 2, 3]),
            Err(PdoError::ShortPayload { need: 6, got: 3 })
        ));

        let rpdo1 = PdoConfig::from_od(&eds.od, PdoKind::Rpdo, 1, node(5)).unwrap();
        assert_eq!(rpdo1.cob_id, 0x205);
        let data = rpdo1
            .encode(&[
                (ObjectAddress::new(0x607A, 0), Value::Integer32(-2)),
                (ObjectAddress::new(0x6040, 0), Value::Unsigned16(0x000F)),
            ])
            .unwrap();
        assert_eq!(data, vec![0x0F, 0x00, 0xFE, 0xFF, 0xFF, 0xFF]);
        assert!(matches!(
            rpdo1.encode(&[(ObjectAddress::new(0x6040, 0), Value::Unsigned16(0))]),
            Err(PdoError::MissingValue(_))
        ));
    }
}
