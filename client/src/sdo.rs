//! CANopen addressing and typed SDO values: [`NodeId`], [`ObjectAddress`],
//! [`Object`] (an address or a name from the EDS), [`SdoValue`],
//! [`SdoOptions`].

use crate::error::Error;
use crate::pb;
use std::fmt;
use std::str::FromStr;
use std::time::Duration;

pub use crate::pb::DataType;

/// A CANopen node id, 1..=127 (checked when made).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct NodeId(u8);

impl NodeId {
    /// A node id; [`Error::InvalidInput`] outside 1..=127.
    pub fn new(id: u32) -> Result<NodeId, Error> {
        match u8::try_from(id) {
            Ok(v @ 1..=127) => Ok(NodeId(v)),
            _ => Err(Error::invalid(format!(
                "node id {id} is out of range (CANopen node ids are 1..=127)"
            ))),
        }
    }

    /// The id.
    pub fn get(self) -> u8 {
        self.0
    }
}

impl TryFrom<u32> for NodeId {
    type Error = Error;
    fn try_from(id: u32) -> Result<NodeId, Error> {
        NodeId::new(id)
    }
}

impl TryFrom<u8> for NodeId {
    type Error = Error;
    fn try_from(id: u8) -> Result<NodeId, Error> {
        NodeId::new(u32::from(id))
    }
}

impl FromStr for NodeId {
    type Err = Error;
    /// Decimal, or hex with `0x`.
    fn from_str(s: &str) -> Result<NodeId, Error> {
        let t = s.trim();
        let v = match t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
            Some(h) => u32::from_str_radix(h, 16),
            None => t.parse(),
        }
        .map_err(|_| Error::invalid(format!("node id {s:?} is not a number")))?;
        NodeId::new(v)
    }
}

impl fmt::Display for NodeId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

impl From<NodeId> for u32 {
    fn from(n: NodeId) -> u32 {
        u32::from(n.0)
    }
}

/// An object dictionary address. Parses from and shows as `0x607A:00`
/// (index and sub-index in hex, `0x` optional, `:sub` optional = 0).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ObjectAddress {
    /// Index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
}

impl ObjectAddress {
    /// An address.
    pub const fn new(index: u16, sub: u8) -> ObjectAddress {
        ObjectAddress { index, sub }
    }
}

impl FromStr for ObjectAddress {
    type Err = Error;
    fn from_str(s: &str) -> Result<ObjectAddress, Error> {
        let bad = |what: &str| {
            Error::invalid(format!(
                "object address {s:?}: {what} (expected e.g. 0x607A:00, hex)"
            ))
        };
        let t = s.trim();
        let (i, sub) = t.split_once(':').unwrap_or((t, "0"));
        let hex = |x: &str| {
            let x = x.trim();
            let x = x
                .strip_prefix("0x")
                .or_else(|| x.strip_prefix("0X"))
                .unwrap_or(x);
            if x.is_empty() {
                None
            } else {
                u32::from_str_radix(x, 16).ok()
            }
        };
        let index = hex(i).ok_or_else(|| bad("the index is not hex"))?;
        let sub = hex(sub).ok_or_else(|| bad("the sub-index is not hex"))?;
        Ok(ObjectAddress {
            index: u16::try_from(index).map_err(|_| bad("index above 0xFFFF"))?,
            sub: u8::try_from(sub).map_err(|_| bad("sub-index above 0xFF"))?,
        })
    }
}

impl fmt::Display for ObjectAddress {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:04X}:{:02X}", self.index, self.sub)
    }
}

impl From<(u16, u8)> for ObjectAddress {
    fn from((index, sub): (u16, u8)) -> ObjectAddress {
        ObjectAddress { index, sub }
    }
}

/// An object as a request names it: by address, or by name from the
/// node's EDS (resolved by the gateway: `Manufacturer device name`,
/// `Identity object.Serial number`, `0x1018.Vendor-ID`).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Object {
    /// Index and sub-index.
    Address(ObjectAddress),
    /// A name the gateway resolves with the node's EDS
    /// (`ReadSdoRequest.object`); the node needs an EDS.
    Name(String),
}

impl Object {
    /// The request fields `(index, subindex, object)`.
    pub(crate) fn fields(&self) -> (u32, u32, String) {
        match self {
            Object::Address(a) => (a.index.into(), a.sub.into(), String::new()),
            Object::Name(n) => (0, 0, n.clone()),
        }
    }
}

impl From<ObjectAddress> for Object {
    fn from(a: ObjectAddress) -> Object {
        Object::Address(a)
    }
}

impl From<(u16, u8)> for Object {
    fn from(a: (u16, u8)) -> Object {
        Object::Address(a.into())
    }
}

impl From<&str> for Object {
    /// As [`Object::from_str`].
    fn from(text: &str) -> Object {
        text.parse()
            .unwrap_or_else(|_| Object::Name(text.to_string()))
    }
}

impl From<String> for Object {
    /// As [`Object::from_str`].
    fn from(text: String) -> Object {
        Object::from(text.as_str())
    }
}

impl FromStr for Object {
    type Err = Error;
    /// An address when the text starts with a digit and has only hex
    /// digits, `x` and `:` (`0x1018:01`, `1017`; refused when it does not
    /// parse as one, `0x10000`), else a name (`Producer heartbeat time`,
    /// `0x1018.Vendor-ID`; a name of hex letters such as `Feed` stays a
    /// name). Empty text is refused.
    fn from_str(s: &str) -> Result<Object, Error> {
        let t = s.trim();
        if t.is_empty() {
            return Err(Error::invalid("an empty object name"));
        }
        let address_like = t.starts_with(|c: char| c.is_ascii_digit())
            && t.chars()
                .all(|c| c.is_ascii_hexdigit() || matches!(c, 'x' | 'X' | ':'));
        if address_like {
            return t.parse().map(Object::Address);
        }
        Ok(Object::Name(t.to_string()))
    }
}

impl fmt::Display for Object {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Object::Address(a) => a.fmt(f),
            Object::Name(n) => write!(f, "{n:?}"),
        }
    }
}

/// A typed object value: the CiA 301 type and its value. Maps one to one
/// to the proto's `Value` (type + oneof).
#[derive(Debug, Clone, PartialEq)]
pub enum SdoValue {
    /// BOOLEAN.
    Bool(bool),
    /// INTEGER8.
    I8(i8),
    /// INTEGER16.
    I16(i16),
    /// INTEGER32.
    I32(i32),
    /// INTEGER64.
    I64(i64),
    /// UNSIGNED8.
    U8(u8),
    /// UNSIGNED16.
    U16(u16),
    /// UNSIGNED32.
    U32(u32),
    /// UNSIGNED64.
    U64(u64),
    /// REAL32.
    F32(f32),
    /// REAL64.
    F64(f64),
    /// VISIBLE_STRING.
    VisibleString(String),
    /// UNICODE_STRING.
    UnicodeString(String),
    /// OCTET_STRING.
    OctetString(Vec<u8>),
    /// DOMAIN (any bytes; also what a read without a known type gives).
    Domain(Vec<u8>),
}

impl SdoValue {
    /// The CiA 301 type.
    pub fn data_type(&self) -> DataType {
        match self {
            SdoValue::Bool(_) => DataType::Boolean,
            SdoValue::I8(_) => DataType::Integer8,
            SdoValue::I16(_) => DataType::Integer16,
            SdoValue::I32(_) => DataType::Integer32,
            SdoValue::I64(_) => DataType::Integer64,
            SdoValue::U8(_) => DataType::Unsigned8,
            SdoValue::U16(_) => DataType::Unsigned16,
            SdoValue::U32(_) => DataType::Unsigned32,
            SdoValue::U64(_) => DataType::Unsigned64,
            SdoValue::F32(_) => DataType::Real32,
            SdoValue::F64(_) => DataType::Real64,
            SdoValue::VisibleString(_) => DataType::VisibleString,
            SdoValue::UnicodeString(_) => DataType::UnicodeString,
            SdoValue::OctetString(_) => DataType::OctetString,
            SdoValue::Domain(_) => DataType::Domain,
        }
    }

    /// The value as an unsigned integer (unsigned types, non-negative
    /// signed ones, booleans as 0/1).
    pub fn as_u64(&self) -> Option<u64> {
        match *self {
            SdoValue::Bool(b) => Some(u64::from(b)),
            SdoValue::U8(v) => Some(v.into()),
            SdoValue::U16(v) => Some(v.into()),
            SdoValue::U32(v) => Some(v.into()),
            SdoValue::U64(v) => Some(v),
            _ => self.as_i64().and_then(|v| u64::try_from(v).ok()),
        }
    }

    /// The value as a signed integer (any integer that fits).
    pub fn as_i64(&self) -> Option<i64> {
        match *self {
            SdoValue::I8(v) => Some(v.into()),
            SdoValue::I16(v) => Some(v.into()),
            SdoValue::I32(v) => Some(v.into()),
            SdoValue::I64(v) => Some(v),
            SdoValue::Bool(_)
            | SdoValue::U8(_)
            | SdoValue::U16(_)
            | SdoValue::U32(_)
            | SdoValue::U64(_) => self.as_u64().and_then(|v| i64::try_from(v).ok()),
            _ => None,
        }
    }

    /// The value as a float (reals, and integers).
    pub fn as_f64(&self) -> Option<f64> {
        match *self {
            SdoValue::F32(v) => Some(v.into()),
            SdoValue::F64(v) => Some(v),
            SdoValue::U64(v) => Some(v as f64),
            _ => self.as_i64().map(|v| v as f64),
        }
    }

    /// The text of a string value.
    pub fn as_str(&self) -> Option<&str> {
        match self {
            SdoValue::VisibleString(s) | SdoValue::UnicodeString(s) => Some(s),
            _ => None,
        }
    }

    /// The bytes of an octet string or domain.
    pub fn as_bytes(&self) -> Option<&[u8]> {
        match self {
            SdoValue::OctetString(b) | SdoValue::Domain(b) => Some(b),
            _ => None,
        }
    }

    /// The proto `Value`.
    pub fn to_pb(&self) -> pb::Value {
        use pb::value::Value as V;
        let value = match self {
            SdoValue::Bool(b) => V::BoolValue(*b),
            SdoValue::I8(_) | SdoValue::I16(_) | SdoValue::I32(_) | SdoValue::I64(_) => {
                V::IntValue(self.as_i64().unwrap_or_default())
            }
            SdoValue::U8(_) | SdoValue::U16(_) | SdoValue::U32(_) | SdoValue::U64(_) => {
                V::UintValue(self.as_u64().unwrap_or_default())
            }
            SdoValue::F32(v) => V::RealValue(f64::from(*v)),
            SdoValue::F64(v) => V::RealValue(*v),
            SdoValue::VisibleString(s) | SdoValue::UnicodeString(s) => V::StringValue(s.clone()),
            SdoValue::OctetString(b) | SdoValue::Domain(b) => V::BytesValue(b.clone()),
        };
        pb::Value {
            r#type: self.data_type() as i32,
            value: Some(value),
        }
    }

    /// A proto `Value` typed: its type decides the variant; an integer
    /// that does not fit its type, a value of the wrong kind for its type,
    /// or an unknown type is [`Error::InvalidInput`].
    pub fn from_pb(v: &pb::Value) -> Result<SdoValue, Error> {
        use pb::value::Value as V;
        let ty = DataType::try_from(v.r#type).unwrap_or(DataType::Unspecified);
        let bad = || {
            Error::invalid(format!(
                "value {:?} does not fit type {}",
                v.value,
                ty.as_str_name()
            ))
        };
        fn int<T: TryFrom<i64>>(v: &Option<V>) -> Option<T> {
            match v {
                Some(V::IntValue(i)) => T::try_from(*i).ok(),
                Some(V::UintValue(u)) => i64::try_from(*u).ok().and_then(|i| T::try_from(i).ok()),
                _ => None,
            }
        }
        fn uint<T: TryFrom<u64>>(v: &Option<V>) -> Option<T> {
            match v {
                Some(V::UintValue(u)) => T::try_from(*u).ok(),
                Some(V::IntValue(i)) => u64::try_from(*i).ok().and_then(|u| T::try_from(u).ok()),
                _ => None,
            }
        }
        let real = || match v.value {
            Some(V::RealValue(r)) => Some(r),
            _ => None,
        };
        let text = || match &v.value {
            Some(V::StringValue(s)) => Some(s.clone()),
            _ => None,
        };
        let bytes = || match &v.value {
            Some(V::BytesValue(b)) => Some(b.clone()),
            _ => None,
        };
        let out = match ty {
            DataType::Boolean => match v.value {
                Some(V::BoolValue(b)) => Some(SdoValue::Bool(b)),
                _ => None,
            },
            DataType::Integer8 => int(&v.value).map(SdoValue::I8),
            DataType::Integer16 => int(&v.value).map(SdoValue::I16),
            DataType::Integer32 => int(&v.value).map(SdoValue::I32),
            DataType::Integer64 => int(&v.value).map(SdoValue::I64),
            DataType::Unsigned8 => uint(&v.value).map(SdoValue::U8),
            DataType::Unsigned16 => uint(&v.value).map(SdoValue::U16),
            DataType::Unsigned32 => uint(&v.value).map(SdoValue::U32),
            DataType::Unsigned64 => uint(&v.value).map(SdoValue::U64),
            DataType::Real32 => real().map(|r| SdoValue::F32(r as f32)),
            DataType::Real64 => real().map(SdoValue::F64),
            DataType::VisibleString => text().map(SdoValue::VisibleString),
            DataType::UnicodeString => text().map(SdoValue::UnicodeString),
            DataType::OctetString => bytes().map(SdoValue::OctetString),
            DataType::Domain => bytes().map(SdoValue::Domain),
            DataType::Unspecified => None,
        };
        out.ok_or_else(bad)
    }
}

impl fmt::Display for SdoValue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SdoValue::Bool(b) => write!(f, "{b}"),
            SdoValue::F32(v) => write!(f, "{v}"),
            SdoValue::F64(v) => write!(f, "{v}"),
            SdoValue::VisibleString(s) | SdoValue::UnicodeString(s) => write!(f, "{s:?}"),
            SdoValue::OctetString(b) | SdoValue::Domain(b) => {
                for x in b {
                    write!(f, "{x:02X}")?;
                }
                Ok(())
            }
            SdoValue::U8(_) | SdoValue::U16(_) | SdoValue::U32(_) | SdoValue::U64(_) => {
                let v = self.as_u64().unwrap_or_default();
                write!(f, "{v} (0x{v:X})")
            }
            _ => write!(f, "{}", self.as_i64().unwrap_or_default()),
        }
    }
}

macro_rules! from_native {
    ($($t:ty => $v:ident),*) => {$(
        impl From<$t> for SdoValue {
            fn from(x: $t) -> SdoValue {
                SdoValue::$v(x)
            }
        }
    )*};
}
from_native!(bool => Bool, i8 => I8, i16 => I16, i32 => I32, i64 => I64, u8 => U8, u16 => U16,
    u32 => U32, u64 => U64, f32 => F32, f64 => F64, String => VisibleString);

impl From<&str> for SdoValue {
    fn from(s: &str) -> SdoValue {
        SdoValue::VisibleString(s.to_string())
    }
}

/// Options of one SDO transfer.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SdoOptions {
    /// Timeout for each answer of the node (`None`: the bus default,
    /// normally 500 ms; at most 60 s).
    pub timeout: Option<Duration>,
    /// Use SDO block transfer (falls back to segmented if the node
    /// refuses).
    pub block: bool,
}

impl SdoOptions {
    pub(crate) fn to_pb(self) -> pb::SdoOptions {
        pb::SdoOptions {
            timeout_ms: self.timeout.map_or(0, |t| {
                u32::try_from(t.as_millis()).unwrap_or(u32::MAX).max(1)
            }),
            block: self.block,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_ids_are_checked() {
        assert_eq!(NodeId::new(1).unwrap().get(), 1);
        assert_eq!(NodeId::new(127).unwrap().get(), 127);
        for bad in [0, 128, 300] {
            let e = NodeId::new(bad).unwrap_err();
            assert!(matches!(e, Error::InvalidInput { .. }), "{e:?}");
            assert!(e.to_string().contains("1..=127"), "{e}");
        }
        assert_eq!("0x7F".parse::<NodeId>().unwrap().get(), 127);
        assert_eq!(" 5".parse::<NodeId>().unwrap().to_string(), "5");
        assert!("x".parse::<NodeId>().is_err());
        assert!(NodeId::try_from(0u8).is_err());
    }

    #[test]
    fn object_addresses_parse_and_show_in_hex() {
        let a: ObjectAddress = "0x607A:00".parse().unwrap();
        assert_eq!(a, ObjectAddress::new(0x607A, 0));
        assert_eq!(a.to_string(), "0x607A:00");
        assert_eq!(
            "1018:4".parse::<ObjectAddress>().unwrap(),
            ObjectAddress::new(0x1018, 4)
        );
        assert_eq!(
            "0x1008".parse::<ObjectAddress>().unwrap(),
            ObjectAddress::new(0x1008, 0)
        );
        assert_eq!(
            "0X2000:0x1F".parse::<ObjectAddress>().unwrap(),
            ObjectAddress::new(0x2000, 0x1F)
        );
        for bad in [
            "",
            "0x",
            "0x10000",
            "0x1000:100",
            "zz",
            "0x1000:",
            "0x1000:g",
        ] {
            assert!(bad.parse::<ObjectAddress>().is_err(), "{bad:?}");
        }
        let round = ObjectAddress::new(0x1A00, 0xAB);
        assert_eq!(round.to_string().parse::<ObjectAddress>().unwrap(), round);
    }

    #[test]
    fn values_round_trip_through_the_proto() {
        let all = [
            SdoValue::Bool(true),
            SdoValue::I8(-128),
            SdoValue::I16(-2),
            SdoValue::I32(i32::MIN),
            SdoValue::I64(i64::MAX),
            SdoValue::U8(255),
            SdoValue::U16(65535),
            SdoValue::U32(0xDEAD_BEEF),
            SdoValue::U64(u64::MAX),
            SdoValue::F32(1.5),
            SdoValue::F64(-2.25),
            SdoValue::VisibleString("cangate".into()),
            SdoValue::UnicodeString("é".into()),
            SdoValue::OctetString(vec![1, 2]),
            SdoValue::Domain(vec![0; 3]),
        ];
        for v in all {
            let p = v.to_pb();
            assert_eq!(p.r#type, v.data_type() as i32);
            assert_eq!(SdoValue::from_pb(&p).unwrap(), v);
        }
    }

    #[test]
    fn values_that_do_not_fit_their_type_are_refused() {
        use pb::value::Value as V;
        let v = |ty: DataType, value: V| pb::Value {
            r#type: ty as i32,
            value: Some(value),
        };
        assert!(SdoValue::from_pb(&v(DataType::Unsigned8, V::UintValue(256))).is_err());
        assert!(SdoValue::from_pb(&v(DataType::Integer8, V::IntValue(-129))).is_err());
        assert!(SdoValue::from_pb(&v(DataType::Unsigned32, V::IntValue(-1))).is_err());
        assert!(SdoValue::from_pb(&v(DataType::Real32, V::StringValue("x".into()))).is_err());
        assert!(SdoValue::from_pb(&v(DataType::Unspecified, V::UintValue(1))).is_err());
        // An unsigned value sent as int_value is accepted when it fits.
        assert_eq!(
            SdoValue::from_pb(&v(DataType::Unsigned16, V::IntValue(7))).unwrap(),
            SdoValue::U16(7)
        );
    }

    #[test]
    fn accessors_and_display() {
        assert_eq!(SdoValue::U32(0x1234).as_u64(), Some(0x1234));
        assert_eq!(SdoValue::I16(-1).as_u64(), None);
        assert_eq!(SdoValue::I16(-1).as_i64(), Some(-1));
        assert_eq!(SdoValue::U64(u64::MAX).as_i64(), None);
        assert_eq!(SdoValue::F32(0.5).as_f64(), Some(0.5));
        assert_eq!(SdoValue::from("x").as_str(), Some("x"));
        assert_eq!(SdoValue::U16(10).to_string(), "10 (0xA)");
        assert_eq!(SdoValue::Domain(vec![0xDE, 0xAD]).to_string(), "DEAD");
        assert_eq!(SdoValue::from(5u8), SdoValue::U8(5));
        assert_eq!(
            SdoOptions {
                timeout: Some(Duration::from_micros(10)),
                block: true
            }
            .to_pb()
            .timeout_ms,
            1
        );
    }
}
