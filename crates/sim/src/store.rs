//! The values of a simulated device's object dictionary.
//!
//! [`SimStore`] holds one typed [`Value`] per variable of an
//! [`ObjectDictionary`], initialised from the EDS defaults with `$NODEID`
//! resolved. Access over the bus ([`ObjectStore`], used by the SDO server)
//! is checked like a real device checks it; local access by the device
//! application ([`SimStore::set`]) only checks the type, so the application
//! can update read-only process values such as a statusword.

use std::collections::BTreeMap;
use std::ops::RangeInclusive;

use cangate_canopen::ids::Index;
use cangate_canopen::od::{ObjectDictionary, Variable};
use cangate_canopen::sdo::{AbortCode, ObjectStore};
use cangate_canopen::value::{Value, ValueError};
use cangate_canopen::{NodeId, ObjectAddress};

use crate::SimError;

/// The object dictionary values of one simulated node.
#[derive(Debug, Clone)]
pub struct SimStore {
    od: ObjectDictionary,
    node: NodeId,
    defaults: BTreeMap<ObjectAddress, Value>,
    values: BTreeMap<ObjectAddress, Value>,
}

impl SimStore {
    /// A store holding every variable of `od` at its default for `node`
    /// (the `ParameterValue` or `DefaultValue` with `$NODEID` resolved); a
    /// variable without a default starts at zero (empty for strings and
    /// domains).
    pub fn new(od: ObjectDictionary, node: NodeId) -> Self {
        let defaults: BTreeMap<_, _> = od
            .variables()
            .map(|v| {
                let value = v
                    .default_for_node(node)
                    .filter(|d| d.data_type() == v.data_type)
                    .unwrap_or_else(|| Value::zero(v.data_type));
                (v.address, value)
            })
            .collect();
        SimStore {
            od,
            node,
            values: defaults.clone(),
            defaults,
        }
    }

    /// The object dictionary (structure, types, access rights, limits).
    pub fn od(&self) -> &ObjectDictionary {
        &self.od
    }

    /// The node id defaults were resolved for.
    pub fn node(&self) -> NodeId {
        self.node
    }

    /// The variable at `addr`.
    pub fn variable(&self, addr: ObjectAddress) -> Option<&Variable> {
        self.od.get(addr)
    }

    /// The current value at `addr`.
    pub fn get(&self, addr: ObjectAddress) -> Option<&Value> {
        self.values.get(&addr)
    }

    /// The default value at `addr` (what a reset restores).
    pub fn default_value(&self, addr: ObjectAddress) -> Option<&Value> {
        self.defaults.get(&addr)
    }

    /// Sets a value locally, as the device application does: the type must
    /// match, access rights and limits are not checked. Returns whether the
    /// value changed.
    pub fn set(&mut self, addr: ObjectAddress, value: Value) -> Result<bool, SimError> {
        self.check_type(addr, &value)?;
        Ok(self.put(addr, value))
    }

    /// Sets the value *and* the default of `addr` (the default is what
    /// resets restore), e.g. to configure a node differently from its EDS.
    pub fn set_default(&mut self, addr: ObjectAddress, value: Value) -> Result<(), SimError> {
        self.check_type(addr, &value)?;
        self.defaults.insert(addr, value.clone());
        self.values.insert(addr, value);
        Ok(())
    }

    /// Restores every value to its default (NMT reset node).
    pub fn restore_defaults(&mut self) {
        self.values.clone_from(&self.defaults);
    }

    /// Restores the values of the objects in `indices` to their defaults
    /// (NMT reset communication restores 0x1000..=0x1FFF).
    pub fn restore_range(&mut self, indices: RangeInclusive<Index>) {
        let from = ObjectAddress::new(*indices.start(), 0);
        let to = ObjectAddress::new(*indices.end(), u8::MAX);
        for (addr, value) in self.defaults.range(from..=to) {
            self.values.insert(*addr, value.clone());
        }
    }

    /// The checks of an SDO upload: the variable exists and is readable.
    /// Unknown index → 0x06020000, unknown sub-index → 0x06090011,
    /// write-only → 0x06010001.
    pub fn check_read(&self, addr: ObjectAddress) -> Result<&Variable, AbortCode> {
        let var = self.lookup(addr)?;
        if !var.access.is_readable() {
            return Err(AbortCode::READ_OF_WRITE_ONLY);
        }
        Ok(var)
    }

    /// The checks of an SDO download, returning the decoded value without
    /// storing it:
    /// - unknown index → 0x06020000, unknown sub-index → 0x06090011;
    /// - `ro`/`const` → 0x06010002;
    /// - fixed-size types need exactly their size: more → 0x06070012,
    ///   less → 0x06070013 (strings and domains take any length);
    /// - bytes that are not a value of the type (a `VISIBLE_STRING` with
    ///   unprintable characters, odd-length `UNICODE_STRING`) → 0x06070010,
    ///   a `BOOLEAN` other than 0/1 → 0x06090030;
    /// - `LowLimit`/`HighLimit` → 0x06090032/0x06090031.
    pub fn decode_write(&self, addr: ObjectAddress, data: &[u8]) -> Result<Value, AbortCode> {
        let var = self.lookup(addr)?;
        if !var.access.is_writable() {
            return Err(AbortCode::WRITE_OF_READ_ONLY);
        }
        if let Some(size) = var.data_type.fixed_size() {
            if data.len() > size {
                return Err(AbortCode::LENGTH_TOO_HIGH);
            }
            if data.len() < size {
                return Err(AbortCode::LENGTH_TOO_LOW);
            }
        }
        let value = Value::decode(var.data_type, data).map_err(|e| match e {
            ValueError::OutOfRange { .. } => AbortCode::INVALID_VALUE,
            _ => AbortCode::LENGTH_MISMATCH,
        })?;
        var.check(&value).map_err(|e| match e {
            ValueError::BelowLimit { .. } => AbortCode::VALUE_TOO_LOW,
            ValueError::AboveLimit { .. } => AbortCode::VALUE_TOO_HIGH,
            _ => AbortCode::LENGTH_MISMATCH,
        })?;
        Ok(value)
    }

    /// Stores a value without any check; returns whether it changed.
    pub(crate) fn put(&mut self, addr: ObjectAddress, value: Value) -> bool {
        match self.values.get_mut(&addr) {
            Some(old) if *old == value => false,
            Some(old) => {
                *old = value;
                true
            }
            None => false,
        }
    }

    /// An integer value that fits `u32` (COB-IDs, mapping entries, times).
    pub(crate) fn u32_at(&self, index: Index, sub: u8) -> Option<u32> {
        self.get(ObjectAddress::new(index, sub))?.as_u32()
    }

    fn lookup(&self, addr: ObjectAddress) -> Result<&Variable, AbortCode> {
        let object = self
            .od
            .object(addr.index)
            .ok_or(AbortCode::OBJECT_DOES_NOT_EXIST)?;
        object
            .sub(addr.sub)
            .ok_or(AbortCode::SUB_INDEX_DOES_NOT_EXIST)
    }

    fn check_type(&self, addr: ObjectAddress, value: &Value) -> Result<(), SimError> {
        let var = self.od.get(addr).ok_or(SimError::NoSuchObject(addr))?;
        if var.data_type != value.data_type() {
            return Err(SimError::TypeMismatch {
                addr,
                expected: var.data_type,
                got: value.data_type(),
            });
        }
        Ok(())
    }
}

/// SDO access with the checks of [`SimStore::check_read`] and
/// [`SimStore::decode_write`].
impl ObjectStore for SimStore {
    fn read(&mut self, addr: ObjectAddress) -> Result<Vec<u8>, AbortCode> {
        self.check_read(addr)?;
        Ok(self
            .values
            .get(&addr)
            .map(Value::encode)
            .unwrap_or_default())
    }

    fn write(&mut self, addr: ObjectAddress, data: &[u8]) -> Result<(), AbortCode> {
        let value = self.decode_write(addr, data)?;
        self.put(addr, value);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cangate_canopen::eds::{Eds, SIM_DRIVE_EDS};

    fn at(index: u16, sub: u8) -> ObjectAddress {
        ObjectAddress::new(index, sub)
    }

    const LIMITS_EDS: &str = "[2000]\nParameterName=Limited\nDataType=0x0003\nAccessType=rw\n\
        DefaultValue=0\nLowLimit=-10\nHighLimit=10\n\
        [2001]\nParameterName=Write only\nDataType=0x0007\nAccessType=wo\nDefaultValue=0\n\
        [2002]\nParameterName=Text\nDataType=0x0009\nAccessType=rw\nDefaultValue=abc\n\
        [2003]\nParameterName=Flag\nDataType=0x0001\nAccessType=rw\nDefaultValue=0\n";

    fn store(text: &str, node: u32) -> SimStore {
        SimStore::new(
            Eds::parse(text).unwrap().od_with_dummies(),
            NodeId::new(node).unwrap(),
        )
    }

    #[test]
    fn defaults_are_resolved_for_the_node() {
        let s = store(SIM_DRIVE_EDS, 5);
        assert_eq!(s.get(at(0x1800, 1)), Some(&Value::Unsigned32(0x185)));
        assert_eq!(s.get(at(0x1014, 0)), Some(&Value::Unsigned32(0x85)));
        assert_eq!(s.get(at(0x2100, 0)), Some(&Value::Domain(Vec::new())));
        assert_eq!(
            s.get(at(0x1008, 0)),
            Some(&Value::VisibleString("cangate sim drive".into()))
        );
        assert_eq!(s.get(at(0x9999, 0)), None);
    }

    #[test]
    fn sdo_access_checks() {
        let mut s = store(LIMITS_EDS, 1);
        let w = |s: &mut SimStore, a, d: &[u8]| ObjectStore::write(s, a, d);
        assert_eq!(w(&mut s, at(0x2000, 0), &[5, 0]), Ok(()));
        assert_eq!(s.get(at(0x2000, 0)), Some(&Value::Integer16(5)));
        assert_eq!(
            w(&mut s, at(0x2000, 0), &[11, 0]),
            Err(AbortCode::VALUE_TOO_HIGH)
        );
        assert_eq!(
            w(&mut s, at(0x2000, 0), &(-11i16).to_le_bytes()),
            Err(AbortCode::VALUE_TOO_LOW)
        );
        assert_eq!(
            w(&mut s, at(0x2000, 0), &[1, 0, 0]),
            Err(AbortCode::LENGTH_TOO_HIGH)
        );
        assert_eq!(
            w(&mut s, at(0x2000, 0), &[1]),
            Err(AbortCode::LENGTH_TOO_LOW)
        );
        assert_eq!(s.get(at(0x2000, 0)), Some(&Value::Integer16(5)));
        assert_eq!(s.read(at(0x2001, 0)), Err(AbortCode::READ_OF_WRITE_ONLY));
        assert_eq!(w(&mut s, at(0x2001, 0), &[1, 2, 3, 4]), Ok(()));
        assert_eq!(s.read(at(0x2003, 0)), Ok(vec![0]));
        assert_eq!(
            w(&mut s, at(0x2003, 0), &[2]),
            Err(AbortCode::INVALID_VALUE)
        );
        assert_eq!(
            w(&mut s, at(0x2002, 0), &[0x01]),
            Err(AbortCode::LENGTH_MISMATCH)
        );
        assert_eq!(w(&mut s, at(0x2002, 0), b"a longer text"), Ok(()));
        assert_eq!(s.read(at(0x2002, 0)), Ok(b"a longer text".to_vec()));
        assert_eq!(s.read(at(0x3000, 0)), Err(AbortCode::OBJECT_DOES_NOT_EXIST));
        assert_eq!(
            s.read(at(0x2000, 1)),
            Err(AbortCode::SUB_INDEX_DOES_NOT_EXIST)
        );
    }

    #[test]
    fn local_access_and_resets() {
        let mut s = store(SIM_DRIVE_EDS, 5);
        // Read-only for the bus, writable for the application.
        assert_eq!(
            ObjectStore::write(&mut s, at(0x6041, 0), &[1, 0]),
            Err(AbortCode::WRITE_OF_READ_ONLY)
        );
        assert!(s.set(at(0x6041, 0), Value::Unsigned16(0x237)).unwrap());
        assert!(!s.set(at(0x6041, 0), Value::Unsigned16(0x237)).unwrap());
        assert!(matches!(
            s.set(at(0x6041, 0), Value::Unsigned32(1)),
            Err(SimError::TypeMismatch { .. })
        ));
        assert!(matches!(
            s.set(at(0x6041, 1), Value::Unsigned16(1)),
            Err(SimError::NoSuchObject(_))
        ));
        s.set(at(0x1017, 0), Value::Unsigned16(50)).unwrap();
        s.restore_range(0x1000..=0x1FFF);
        assert_eq!(s.get(at(0x1017, 0)), Some(&Value::Unsigned16(1000)));
        assert_eq!(s.get(at(0x6041, 0)), Some(&Value::Unsigned16(0x237)));
        s.restore_defaults();
        assert_eq!(s.get(at(0x6041, 0)), Some(&Value::Unsigned16(0)));
        s.set_default(at(0x1017, 0), Value::Unsigned16(20)).unwrap();
        s.restore_defaults();
        assert_eq!(s.get(at(0x1017, 0)), Some(&Value::Unsigned16(20)));
    }
}
