//! PDO parameters as a device reads them from its object dictionary
//! (CiA 301 §7.5.2.35–§7.5.2.38), and the CiA 301 rules for changing them.
//!
//! Everything is read from the [`SimStore`] when needed, so a master
//! reconfiguring a PDO over SDO is effective at once.

use std::time::Duration;

use cangate_can::CanId;
use cangate_canopen::ObjectAddress;
use cangate_canopen::od::ObjectType;
use cangate_canopen::sdo::AbortCode;
use cangate_canopen::value::Value;

use crate::store::SimStore;

/// RPDO communication parameters (0x1400 + n).
pub(crate) const RPDO_COMM: u16 = 0x1400;
/// RPDO mapping parameters (0x1600 + n).
pub(crate) const RPDO_MAP: u16 = 0x1600;
/// TPDO communication parameters (0x1800 + n).
pub(crate) const TPDO_COMM: u16 = 0x1800;
/// TPDO mapping parameters (0x1A00 + n).
pub(crate) const TPDO_MAP: u16 = 0x1A00;
/// PDOs per direction.
pub(crate) const MAX_PDOS: u16 = 512;
/// Mapping entries per PDO (CiA 301 allows 0x40; 8 bytes allow 8 whole-byte
/// objects, but entries are checked by total length).
const MAX_ENTRIES: u32 = 0x40;
/// Bytes of a classic CAN frame.
const MAX_PDO_LEN: usize = 8;

/// COB-ID bit 31: the PDO does not exist (is invalid).
const COB_INVALID: u32 = 0x8000_0000;
/// COB-ID bit 30: no RTR allowed on this PDO.
const COB_NO_RTR: u32 = 0x4000_0000;
/// COB-ID bit 29: 29-bit CAN identifier.
const COB_EXTENDED: u32 = 0x2000_0000;

/// Receive or transmit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Dir {
    /// RPDO: the bus writes the device.
    Rx,
    /// TPDO: the device sends.
    Tx,
}

impl Dir {
    fn comm(self) -> u16 {
        match self {
            Dir::Rx => RPDO_COMM,
            Dir::Tx => TPDO_COMM,
        }
    }
    fn map(self) -> u16 {
        match self {
            Dir::Rx => RPDO_MAP,
            Dir::Tx => TPDO_MAP,
        }
    }
}

/// Which PDO parameter object an index is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum PdoParam {
    /// Communication parameter of PDO `n` (0-based).
    Comm(Dir, u16),
    /// Mapping parameter of PDO `n` (0-based).
    Map(Dir, u16),
}

impl PdoParam {
    pub(crate) fn of(index: u16) -> Option<PdoParam> {
        let n = |base: u16| index - base;
        match index {
            0x1400..=0x15FF => Some(PdoParam::Comm(Dir::Rx, n(RPDO_COMM))),
            0x1600..=0x17FF => Some(PdoParam::Map(Dir::Rx, n(RPDO_MAP))),
            0x1800..=0x19FF => Some(PdoParam::Comm(Dir::Tx, n(TPDO_COMM))),
            0x1A00..=0x1BFF => Some(PdoParam::Map(Dir::Tx, n(TPDO_MAP))),
            _ => None,
        }
    }
}

/// A decoded COB-ID entry (sub-index 1 of a communication parameter).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct CobId {
    /// Bit 31 clear.
    pub valid: bool,
    /// Bit 30 clear.
    pub rtr_allowed: bool,
    /// The identifier (11 bits, or 29 with bit 29).
    pub id: CanId,
}

impl CobId {
    pub(crate) fn decode(raw: u32) -> CobId {
        let id = if raw & COB_EXTENDED != 0 {
            CanId::Extended(raw & 0x1FFF_FFFF)
        } else {
            CanId::Standard((raw & 0x7FF) as u16)
        };
        CobId {
            valid: raw & COB_INVALID == 0,
            rtr_allowed: raw & COB_NO_RTR == 0,
            id,
        }
    }
}

/// The communication parameters of a valid PDO.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct PdoComm {
    /// Its identifier.
    pub id: CanId,
    /// Remote requests are answered (TPDO).
    pub rtr_allowed: bool,
    /// Transmission type (sub 2; 0xFF when absent).
    pub ttype: u8,
    /// Inhibit time (sub 3, 100 µs units; TPDO).
    pub inhibit: Duration,
    /// Event timer (sub 5, ms; TPDO); `None` when 0 or absent.
    pub event: Option<Duration>,
}

impl PdoComm {
    /// Event-driven transmission (0xFE manufacturer specific, 0xFF device
    /// profile specific).
    pub(crate) fn event_driven(&self) -> bool {
        self.ttype >= 0xFE
    }
}

/// The communication parameters of PDO `n`, or `None` when it does not
/// exist or is invalid.
pub(crate) fn comm(store: &SimStore, dir: Dir, n: u16) -> Option<PdoComm> {
    let index = dir.comm() + n;
    let cob = CobId::decode(store.u32_at(index, 1)?);
    if !cob.valid {
        return None;
    }
    let ttype = store.u32_at(index, 2).map_or(0xFF, |t| t as u8);
    let inhibit = store.u32_at(index, 3).unwrap_or(0);
    let event = store.u32_at(index, 5).unwrap_or(0);
    Some(PdoComm {
        id: cob.id,
        rtr_allowed: cob.rtr_allowed,
        ttype,
        inhibit: Duration::from_micros(u64::from(inhibit) * 100),
        event: (event > 0).then(|| Duration::from_millis(u64::from(event))),
    })
}

/// One mapped object.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct MapEntry {
    /// The object.
    pub addr: ObjectAddress,
    /// Its length in bytes.
    pub len: usize,
    /// A dummy entry (a DEFTYPE index: the bytes are skipped).
    pub dummy: bool,
}

/// Checks one mapping entry (`index << 16 | sub << 8 | bits`): the object
/// exists, is PDO-mappable with the right access for the direction, and the
/// length is its whole size in bits (only whole bytes are supported).
fn entry(store: &SimStore, dir: Dir, raw: u32) -> Result<MapEntry, AbortCode> {
    let addr = ObjectAddress::new((raw >> 16) as u16, (raw >> 8) as u8);
    let bits = raw & 0xFF;
    let var = store.variable(addr).ok_or(AbortCode::CANNOT_MAP_TO_PDO)?;
    let dummy = store
        .od()
        .object(addr.index)
        .is_some_and(|o| o.object_type == ObjectType::DefType);
    let size = var
        .data_type
        .fixed_size()
        .ok_or(AbortCode::CANNOT_MAP_TO_PDO)?;
    let access_ok = match dir {
        Dir::Rx => dummy || var.access.is_writable(),
        Dir::Tx => !dummy && var.access.is_readable(),
    };
    if !var.pdo_mappable || !access_ok || bits != size as u32 * 8 {
        return Err(AbortCode::CANNOT_MAP_TO_PDO);
    }
    Ok(MapEntry {
        addr,
        len: size,
        dummy,
    })
}

/// Checks a whole mapping of `count` entries.
fn entries(
    store: &SimStore,
    dir: Dir,
    count: u32,
    mut raw_at: impl FnMut(u8) -> Option<u32>,
) -> Result<Vec<MapEntry>, AbortCode> {
    if count > MAX_ENTRIES {
        return Err(AbortCode::PDO_LENGTH_EXCEEDED);
    }
    let mut out = Vec::with_capacity(count as usize);
    let mut total = 0;
    for sub in 1..=count as u8 {
        let raw = raw_at(sub).ok_or(AbortCode::CANNOT_MAP_TO_PDO)?;
        let e = entry(store, dir, raw)?;
        total += e.len;
        if total > MAX_PDO_LEN {
            return Err(AbortCode::PDO_LENGTH_EXCEEDED);
        }
        out.push(e);
    }
    Ok(out)
}

/// The current mapping of PDO `n`, checked; empty when mapping is disabled
/// (sub 0 = 0).
pub(crate) fn mapping(store: &SimStore, dir: Dir, n: u16) -> Result<Vec<MapEntry>, AbortCode> {
    let index = dir.map() + n;
    let count = store
        .u32_at(index, 0)
        .ok_or(AbortCode::OBJECT_DOES_NOT_EXIST)?;
    entries(store, dir, count, |sub| store.u32_at(index, sub))
}

/// The restricted CAN identifiers of CiA 301 (§7.3.5), which no
/// configurable COB-ID may use.
fn restricted(id: CanId) -> bool {
    let CanId::Standard(id) = id else {
        return false;
    };
    matches!(
        id,
        0x000
            | 0x001..=0x07F
            | 0x101..=0x180
            | 0x581..=0x5FF
            | 0x601..=0x67F
            | 0x6E0..=0x6FF
            | 0x701..=0x77F
            | 0x780..=0x7FF
    )
}

/// The CiA 301 rules for writing PDO parameters over SDO (as CANopenNode
/// enforces them), checked before `value` is stored at `addr`:
///
/// - COB-ID (sub 1): an 11-bit id must leave bits 11..=28 zero, a valid id
///   may not be a restricted one, and the id of a valid PDO may not change
///   without invalidating it first (bit 31) → 0x06090030;
/// - transmission type (sub 2): 0xF1..=0xFB (TPDO) or 0xF1..=0xFD (RPDO)
///   are reserved → 0x06090030;
/// - inhibit time (TPDO sub 3) only while the PDO is invalid → 0x06090030;
/// - mapping: only while the PDO is invalid, and entries only while sub 0
///   is 0 → 0x06010000; each entry must be mappable → 0x06040041; sub 0 = n
///   checks the n entries together (at most 8 bytes) → 0x06040042.
pub(crate) fn check_config_write(
    store: &SimStore,
    addr: ObjectAddress,
    value: &Value,
) -> Result<(), AbortCode> {
    let Some(param) = PdoParam::of(addr.index) else {
        return Ok(());
    };
    let new = value.as_u32().unwrap_or(0);
    match param {
        PdoParam::Comm(dir, n) => {
            let index = dir.comm() + n;
            let current = store.u32_at(index, 1).map(CobId::decode);
            let valid = current.is_some_and(|c| c.valid);
            match addr.sub {
                1 => {
                    let cob = CobId::decode(new);
                    let bad_bits = new & COB_EXTENDED == 0 && new & 0x1FFF_F800 != 0;
                    let moved = valid && current.is_some_and(|c| c.id != cob.id);
                    if bad_bits || (cob.valid && (moved || restricted(cob.id))) {
                        return Err(AbortCode::INVALID_VALUE);
                    }
                }
                2 => {
                    let reserved = match dir {
                        Dir::Tx => (0xF1..=0xFB).contains(&new),
                        Dir::Rx => (0xF1..=0xFD).contains(&new),
                    };
                    if reserved {
                        return Err(AbortCode::INVALID_VALUE);
                    }
                }
                3 if dir == Dir::Tx && valid => return Err(AbortCode::INVALID_VALUE),
                _ => {}
            }
            Ok(())
        }
        PdoParam::Map(dir, n) => {
            let index = dir.map() + n;
            let valid = store
                .u32_at(dir.comm() + n, 1)
                .is_some_and(|raw| CobId::decode(raw).valid);
            if valid {
                return Err(AbortCode::UNSUPPORTED_ACCESS);
            }
            if addr.sub == 0 {
                entries(store, dir, new, |sub| store.u32_at(index, sub)).map(|_| ())
            } else if store.u32_at(index, 0).unwrap_or(0) != 0 {
                Err(AbortCode::UNSUPPORTED_ACCESS)
            } else if new == 0 {
                Ok(())
            } else {
                entry(store, dir, new).map(|_| ())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cangate_canopen::NodeId;
    use cangate_canopen::eds::{Eds, SIM_DRIVE_EDS};

    fn drive() -> SimStore {
        SimStore::new(
            Eds::parse(SIM_DRIVE_EDS).unwrap().od_with_dummies(),
            NodeId::new(5).unwrap(),
        )
    }

    fn at(index: u16, sub: u8) -> ObjectAddress {
        ObjectAddress::new(index, sub)
    }

    #[test]
    fn default_parameters() {
        let s = drive();
        let t1 = comm(&s, Dir::Tx, 0).unwrap();
        assert_eq!(t1.id, CanId::Standard(0x185));
        assert_eq!(t1.ttype, 0xFF);
        assert_eq!(t1.event, Some(Duration::from_millis(100)));
        assert_eq!(
            comm(&s, Dir::Tx, 1).unwrap().inhibit,
            Duration::from_millis(1)
        );
        assert_eq!(comm(&s, Dir::Tx, 2), None);
        let m = mapping(&s, Dir::Tx, 0).unwrap();
        assert_eq!(
            m.iter().map(|e| (e.addr, e.len)).collect::<Vec<_>>(),
            [(at(0x6041, 0), 2), (at(0x6064, 0), 4)]
        );
        // Read-only objects cannot be received.
        assert_eq!(
            entry(&s, Dir::Rx, 0x6041_0010),
            Err(AbortCode::CANNOT_MAP_TO_PDO)
        );
        // Dummies only in RPDOs.
        assert!(entry(&s, Dir::Rx, 0x0005_0008).unwrap().dummy);
        assert!(entry(&s, Dir::Tx, 0x0005_0008).is_err());
        // Partial objects are not supported.
        assert!(entry(&s, Dir::Tx, 0x6064_0010).is_err());
        assert!(entry(&s, Dir::Tx, 0x1017_0010).is_err());
        assert_eq!(
            CobId::decode(0xA000_1234),
            CobId {
                valid: false,
                rtr_allowed: true,
                id: CanId::Extended(0x1234)
            }
        );
    }

    #[test]
    fn restricted_ids() {
        for id in [
            0x000,
            0x05F,
            0x101,
            0x17F,
            0x180,
            0x5FF,
            0x600 + 1,
            0x6E0,
            0x705,
            0x7FF,
        ] {
            assert!(restricted(CanId::Standard(id)), "{id:#X}");
        }
        for id in [0x080, 0x100, 0x185, 0x200, 0x580, 0x600, 0x6DF] {
            assert!(!restricted(CanId::Standard(id)), "{id:#X}");
        }
        assert!(!restricted(CanId::Extended(0x001)));
    }
}
