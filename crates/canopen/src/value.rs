//! CiA 301 basic data types and typed values.
//!
//! [`DataType`] names a basic type by its CiA 301 code (`UNSIGNED16` is
//! `0x0006`); [`Value`] holds one typed value. Values travel on the bus
//! little-endian ([`Value::encode`], [`Value::decode`]) and are typed by
//! people as text ([`Value::parse`], [`Display`](fmt::Display)), so every
//! conversion checks sizes and ranges and fails with a [`ValueError`] that
//! says what was expected.
//!
//! ```
//! use cangate_canopen::value::{DataType, Value};
//!
//! let v = Value::parse(DataType::Unsigned16, "0x1234").unwrap();
//! assert_eq!(v.encode(), [0x34, 0x12]);
//! assert_eq!(Value::decode(DataType::Unsigned16, &[0x34, 0x12]).unwrap(), v);
//! assert_eq!(
//!     Value::parse(DataType::Unsigned8, "300").unwrap_err().to_string(),
//!     "value 300 does not fit UNSIGNED8 (0..=255)"
//! );
//! ```

use std::fmt;
use std::str::FromStr;

/// A CiA 301 basic data type (the `DataType` codes of an EDS).
///
/// The 24/40/48/56-bit integers are the CiA 301 odd-sized integer types.
/// Compound types (`PDO_MAPPING`, `IDENTITY`, …) and the time types are not
/// modelled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum DataType {
    /// `BOOLEAN` (0x0001): one byte, 0 or 1 (1 bit when PDO-mapped).
    Boolean,
    /// `INTEGER8` (0x0002).
    Integer8,
    /// `INTEGER16` (0x0003).
    Integer16,
    /// `INTEGER24` (0x0010).
    Integer24,
    /// `INTEGER32` (0x0004).
    Integer32,
    /// `INTEGER40` (0x0012).
    Integer40,
    /// `INTEGER48` (0x0013).
    Integer48,
    /// `INTEGER56` (0x0014).
    Integer56,
    /// `INTEGER64` (0x0015).
    Integer64,
    /// `UNSIGNED8` (0x0005).
    Unsigned8,
    /// `UNSIGNED16` (0x0006).
    Unsigned16,
    /// `UNSIGNED24` (0x0016).
    Unsigned24,
    /// `UNSIGNED32` (0x0007).
    Unsigned32,
    /// `UNSIGNED40` (0x0018).
    Unsigned40,
    /// `UNSIGNED48` (0x0019).
    Unsigned48,
    /// `UNSIGNED56` (0x001A).
    Unsigned56,
    /// `UNSIGNED64` (0x001B).
    Unsigned64,
    /// `REAL32` (0x0008): IEEE 754 single precision.
    Real32,
    /// `REAL64` (0x0011): IEEE 754 double precision.
    Real64,
    /// `VISIBLE_STRING` (0x0009): printable ASCII, any length.
    VisibleString,
    /// `OCTET_STRING` (0x000A): raw bytes.
    OctetString,
    /// `UNICODE_STRING` (0x000B): UTF-16LE code units.
    UnicodeString,
    /// `DOMAIN` (0x000F): an opaque block of bytes (firmware, files).
    Domain,
}

/// How a type's bytes are interpreted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Bool,
    Signed,
    Unsigned,
    Float,
    Visible,
    Octets,
    Unicode,
}

/// Per-type facts, in the declaration order of [`DataType`]:
/// (type, code, CiA 301 name, CLI short name, fixed size, kind).
type Row = (
    DataType,
    u16,
    &'static str,
    &'static str,
    Option<usize>,
    Kind,
);
const TABLE: [Row; 23] = {
    use DataType as D;
    use Kind as K;
    [
        (D::Boolean, 0x0001, "BOOLEAN", "bool", Some(1), K::Bool),
        (D::Integer8, 0x0002, "INTEGER8", "i8", Some(1), K::Signed),
        (D::Integer16, 0x0003, "INTEGER16", "i16", Some(2), K::Signed),
        (D::Integer24, 0x0010, "INTEGER24", "i24", Some(3), K::Signed),
        (D::Integer32, 0x0004, "INTEGER32", "i32", Some(4), K::Signed),
        (D::Integer40, 0x0012, "INTEGER40", "i40", Some(5), K::Signed),
        (D::Integer48, 0x0013, "INTEGER48", "i48", Some(6), K::Signed),
        (D::Integer56, 0x0014, "INTEGER56", "i56", Some(7), K::Signed),
        (D::Integer64, 0x0015, "INTEGER64", "i64", Some(8), K::Signed),
        (
            D::Unsigned8,
            0x0005,
            "UNSIGNED8",
            "u8",
            Some(1),
            K::Unsigned,
        ),
        (
            D::Unsigned16,
            0x0006,
            "UNSIGNED16",
            "u16",
            Some(2),
            K::Unsigned,
        ),
        (
            D::Unsigned24,
            0x0016,
            "UNSIGNED24",
            "u24",
            Some(3),
            K::Unsigned,
        ),
        (
            D::Unsigned32,
            0x0007,
            "UNSIGNED32",
            "u32",
            Some(4),
            K::Unsigned,
        ),
        (
            D::Unsigned40,
            0x0018,
            "UNSIGNED40",
            "u40",
            Some(5),
            K::Unsigned,
        ),
        (
            D::Unsigned48,
            0x0019,
            "UNSIGNED48",
            "u48",
            Some(6),
            K::Unsigned,
        ),
        (
            D::Unsigned56,
            0x001A,
            "UNSIGNED56",
            "u56",
            Some(7),
            K::Unsigned,
        ),
        (
            D::Unsigned64,
            0x001B,
            "UNSIGNED64",
            "u64",
            Some(8),
            K::Unsigned,
        ),
        (D::Real32, 0x0008, "REAL32", "f32", Some(4), K::Float),
        (D::Real64, 0x0011, "REAL64", "f64", Some(8), K::Float),
        (
            D::VisibleString,
            0x0009,
            "VISIBLE_STRING",
            "vs",
            None,
            K::Visible,
        ),
        (
            D::OctetString,
            0x000A,
            "OCTET_STRING",
            "os",
            None,
            K::Octets,
        ),
        (
            D::UnicodeString,
            0x000B,
            "UNICODE_STRING",
            "us",
            None,
            K::Unicode,
        ),
        (D::Domain, 0x000F, "DOMAIN", "domain", None, K::Octets),
    ]
};

impl DataType {
    /// Every supported type, in declaration order.
    pub const ALL: [DataType; 23] = {
        let mut all = [DataType::Boolean; 23];
        let mut i = 0;
        while i < 23 {
            all[i] = TABLE[i].0;
            i += 1;
        }
        all
    };

    const fn row(self) -> &'static Row {
        &TABLE[self as usize]
    }

    const fn kind(self) -> Kind {
        self.row().5
    }

    /// True for INTEGER8..INTEGER64.
    pub const fn is_signed(self) -> bool {
        matches!(self.kind(), Kind::Signed)
    }

    /// The CiA 301 code (`UNSIGNED32` → `0x0007`).
    pub const fn code(self) -> u16 {
        self.row().1
    }

    /// The type with this CiA 301 code, if it is a supported basic type.
    pub fn from_code(code: u16) -> Option<DataType> {
        TABLE.iter().find(|row| row.1 == code).map(|row| row.0)
    }

    /// The CiA 301 name, e.g. `"UNSIGNED16"`.
    pub const fn name(self) -> &'static str {
        self.row().2
    }

    /// The short name used on the command line, e.g. `"u16"`.
    pub const fn short_name(self) -> &'static str {
        self.row().3
    }

    /// Encoded size in bytes; `None` for the variable-length string and
    /// domain types.
    pub const fn fixed_size(self) -> Option<usize> {
        self.row().4
    }

    /// Length in bits when mapped into a PDO (`BOOLEAN` is 1 bit); `None`
    /// for variable-length types.
    pub const fn bit_len(self) -> Option<u32> {
        match (self, self.fixed_size()) {
            (DataType::Boolean, _) => Some(1),
            (_, Some(n)) => Some(n as u32 * 8),
            (_, None) => None,
        }
    }

    /// True for the signed and unsigned integer types (not `BOOLEAN`).
    pub const fn is_integer(self) -> bool {
        matches!(self.kind(), Kind::Signed | Kind::Unsigned)
    }

    /// True for `REAL32` and `REAL64`.
    pub const fn is_float(self) -> bool {
        matches!(self.kind(), Kind::Float)
    }

    /// True for the variable-length types (strings and `DOMAIN`).
    pub const fn is_variable_size(self) -> bool {
        self.fixed_size().is_none()
    }

    /// The inclusive value range of an integer or boolean type.
    pub const fn integer_range(self) -> Option<(i128, i128)> {
        let bits = match self.fixed_size() {
            Some(n) => n as u32 * 8,
            None => return None,
        };
        match self.kind() {
            Kind::Bool => Some((0, 1)),
            Kind::Signed => Some((-(1i128 << (bits - 1)), (1i128 << (bits - 1)) - 1)),
            Kind::Unsigned => Some((0, (1i128 << bits) - 1)),
            _ => None,
        }
    }
}

impl fmt::Display for DataType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for DataType {
    type Err = ValueError;

    /// Accepts the CLI short names (`u8`, `i32`, `f64`, `vs`, `os`, `us`,
    /// `domain`, …) and the CiA 301 names (`UNSIGNED8`), case-insensitively.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let s = s.trim();
        TABLE
            .iter()
            .find(|row| row.2.eq_ignore_ascii_case(s) || row.3.eq_ignore_ascii_case(s))
            .map(|row| row.0)
            .ok_or_else(|| ValueError::UnknownType(s.to_owned()))
    }
}

/// Why a value could not be decoded, parsed or accepted.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ValueError {
    /// The byte count does not match a fixed-size type.
    #[error("wrong size for {ty}: expected {expected} bytes, got {got}")]
    WrongSize {
        /// The type being decoded.
        ty: DataType,
        /// Its size.
        expected: usize,
        /// The bytes received.
        got: usize,
    },
    /// An integer outside the type's range.
    #[error("value {value} does not fit {ty} ({min}..={max})")]
    OutOfRange {
        /// The target type.
        ty: DataType,
        /// The value given.
        value: i128,
        /// Smallest allowed value.
        min: i128,
        /// Largest allowed value.
        max: i128,
    },
    /// Text that is not a value of the type.
    #[error("invalid {ty} value {text:?}: {reason}")]
    Invalid {
        /// The target type.
        ty: DataType,
        /// The text given.
        text: String,
        /// What is wrong with it.
        reason: String,
    },
    /// A `VISIBLE_STRING` holding something other than printable ASCII.
    #[error("VISIBLE_STRING may only hold printable ASCII, found {ch:?} at byte {offset}")]
    NotVisible {
        /// The offending character (a byte shown as a char when decoding).
        ch: char,
        /// Its byte offset.
        offset: usize,
    },
    /// A `UNICODE_STRING` that is not valid UTF-16LE.
    #[error("UNICODE_STRING is not valid UTF-16LE: {0}")]
    BadUtf16(&'static str),
    /// A type name that is not known.
    #[error(
        "unknown data type {0:?} (expected bool, i8, i16, i32, i64, u8, u16, u32, u64, f32, f64, vs, os, us, domain or a CiA 301 name such as UNSIGNED16)"
    )]
    UnknownType(String),
    /// A value of one type given where another was expected.
    #[error("expected a {expected} value, got {got}")]
    TypeMismatch {
        /// The type required.
        expected: DataType,
        /// The type given.
        got: DataType,
    },
    /// A value below an object's `LowLimit`.
    #[error("value {value} is below the low limit {limit}")]
    BelowLimit {
        /// The value, as displayed.
        value: String,
        /// The limit, as displayed.
        limit: String,
    },
    /// A value above an object's `HighLimit`.
    #[error("value {value} is above the high limit {limit}")]
    AboveLimit {
        /// The value, as displayed.
        value: String,
        /// The limit, as displayed.
        limit: String,
    },
}

/// One typed CiA 301 value.
///
/// Odd-sized integers are held in the next larger Rust integer; a value
/// built directly outside its type's range is truncated by
/// [`encode`](Value::encode) (use [`Value::from_integer`] to range-check).
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// A `BOOLEAN`.
    Boolean(bool),
    /// An `INTEGER8`.
    Integer8(i8),
    /// An `INTEGER16`.
    Integer16(i16),
    /// An `INTEGER24`.
    Integer24(i32),
    /// An `INTEGER32`.
    Integer32(i32),
    /// An `INTEGER40`.
    Integer40(i64),
    /// An `INTEGER48`.
    Integer48(i64),
    /// An `INTEGER56`.
    Integer56(i64),
    /// An `INTEGER64`.
    Integer64(i64),
    /// An `UNSIGNED8`.
    Unsigned8(u8),
    /// An `UNSIGNED16`.
    Unsigned16(u16),
    /// An `UNSIGNED24`.
    Unsigned24(u32),
    /// An `UNSIGNED32`.
    Unsigned32(u32),
    /// An `UNSIGNED40`.
    Unsigned40(u64),
    /// An `UNSIGNED48`.
    Unsigned48(u64),
    /// An `UNSIGNED56`.
    Unsigned56(u64),
    /// An `UNSIGNED64`.
    Unsigned64(u64),
    /// A `REAL32`.
    Real32(f32),
    /// A `REAL64`.
    Real64(f64),
    /// A `VISIBLE_STRING`.
    VisibleString(String),
    /// An `OCTET_STRING`.
    OctetString(Vec<u8>),
    /// A `UNICODE_STRING`.
    UnicodeString(String),
    /// A `DOMAIN`.
    Domain(Vec<u8>),
}

/// Number syntax: the CLI's (decimal, `0x` hex, `0b` binary) or CiA 306's
/// (decimal, `0x` hex, leading-`0` octal; signed hex as two's complement).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Syntax {
    Cli,
    Eds,
}

impl Value {
    /// The type of this value.
    pub fn data_type(&self) -> DataType {
        use DataType as D;
        match self {
            Value::Boolean(_) => D::Boolean,
            Value::Integer8(_) => D::Integer8,
            Value::Integer16(_) => D::Integer16,
            Value::Integer24(_) => D::Integer24,
            Value::Integer32(_) => D::Integer32,
            Value::Integer40(_) => D::Integer40,
            Value::Integer48(_) => D::Integer48,
            Value::Integer56(_) => D::Integer56,
            Value::Integer64(_) => D::Integer64,
            Value::Unsigned8(_) => D::Unsigned8,
            Value::Unsigned16(_) => D::Unsigned16,
            Value::Unsigned24(_) => D::Unsigned24,
            Value::Unsigned32(_) => D::Unsigned32,
            Value::Unsigned40(_) => D::Unsigned40,
            Value::Unsigned48(_) => D::Unsigned48,
            Value::Unsigned56(_) => D::Unsigned56,
            Value::Unsigned64(_) => D::Unsigned64,
            Value::Real32(_) => D::Real32,
            Value::Real64(_) => D::Real64,
            Value::VisibleString(_) => D::VisibleString,
            Value::OctetString(_) => D::OctetString,
            Value::UnicodeString(_) => D::UnicodeString,
            Value::Domain(_) => D::Domain,
        }
    }

    /// The zero value of a type: `false`, `0`, `0.0` or empty.
    pub fn zero(ty: DataType) -> Value {
        match ty.kind() {
            Kind::Float if ty == DataType::Real32 => Value::Real32(0.0),
            Kind::Float => Value::Real64(0.0),
            Kind::Visible => Value::VisibleString(String::new()),
            Kind::Unicode => Value::UnicodeString(String::new()),
            Kind::Octets if ty == DataType::Domain => Value::Domain(Vec::new()),
            Kind::Octets => Value::OctetString(Vec::new()),
            Kind::Bool | Kind::Signed | Kind::Unsigned => Value::int_unchecked(ty, 0),
        }
    }

    /// Builds an integer (or boolean) value, checking the type's range.
    pub fn from_integer(ty: DataType, value: i128) -> Result<Value, ValueError> {
        let Some((min, max)) = ty.integer_range() else {
            return Err(ValueError::Invalid {
                ty,
                text: value.to_string(),
                reason: "not an integer type".into(),
            });
        };
        if !(min..=max).contains(&value) {
            return Err(ValueError::OutOfRange {
                ty,
                value,
                min,
                max,
            });
        }
        Ok(Value::int_unchecked(ty, value))
    }

    /// Builds an integer value, wrapping `value` into the type's width
    /// (two's complement), as a device adding to a register would.
    /// Returns `None` for non-integer types.
    pub fn from_integer_wrapping(ty: DataType, value: i128) -> Option<Value> {
        if !ty.is_integer() {
            return None;
        }
        let n = ty.fixed_size()?;
        Value::decode(ty, &value.to_le_bytes()[..n]).ok()
    }

    /// `value` must be in range for the integer or boolean type `ty`.
    fn int_unchecked(ty: DataType, v: i128) -> Value {
        use DataType as D;
        match ty {
            D::Boolean => Value::Boolean(v != 0),
            D::Integer8 => Value::Integer8(v as i8),
            D::Integer16 => Value::Integer16(v as i16),
            D::Integer24 => Value::Integer24(v as i32),
            D::Integer32 => Value::Integer32(v as i32),
            D::Integer40 => Value::Integer40(v as i64),
            D::Integer48 => Value::Integer48(v as i64),
            D::Integer56 => Value::Integer56(v as i64),
            D::Integer64 => Value::Integer64(v as i64),
            D::Unsigned8 => Value::Unsigned8(v as u8),
            D::Unsigned16 => Value::Unsigned16(v as u16),
            D::Unsigned24 => Value::Unsigned24(v as u32),
            D::Unsigned32 => Value::Unsigned32(v as u32),
            D::Unsigned40 => Value::Unsigned40(v as u64),
            D::Unsigned48 => Value::Unsigned48(v as u64),
            D::Unsigned56 => Value::Unsigned56(v as u64),
            D::Unsigned64 => Value::Unsigned64(v as u64),
            _ => Value::zero(ty),
        }
    }

    /// The value of an integer or boolean (`false` = 0, `true` = 1).
    pub fn as_i128(&self) -> Option<i128> {
        Some(match *self {
            Value::Boolean(b) => b as i128,
            Value::Integer8(v) => v.into(),
            Value::Integer16(v) => v.into(),
            Value::Integer24(v) | Value::Integer32(v) => v.into(),
            Value::Integer40(v) | Value::Integer48(v) | Value::Integer56(v) => v.into(),
            Value::Integer64(v) => v.into(),
            Value::Unsigned8(v) => v.into(),
            Value::Unsigned16(v) => v.into(),
            Value::Unsigned24(v) | Value::Unsigned32(v) => v.into(),
            Value::Unsigned40(v) | Value::Unsigned48(v) | Value::Unsigned56(v) => v.into(),
            Value::Unsigned64(v) => v.into(),
            _ => return None,
        })
    }

    /// An integer value that fits `u32` (COB-IDs, PDO mapping entries).
    pub fn as_u32(&self) -> Option<u32> {
        self.as_i128().and_then(|v| u32::try_from(v).ok())
    }

    /// A number (integer or float) as `f64`, possibly rounded.
    pub fn as_f64(&self) -> Option<f64> {
        match *self {
            Value::Real32(v) => Some(v.into()),
            Value::Real64(v) => Some(v),
            _ => self.as_i128().map(|v| v as f64),
        }
    }

    /// The text of a visible or unicode string.
    pub fn as_str(&self) -> Option<&str> {
        match self {
            Value::VisibleString(s) | Value::UnicodeString(s) => Some(s),
            _ => None,
        }
    }

    /// The bytes of an octet string or domain.
    pub fn as_bytes(&self) -> Option<&[u8]> {
        match self {
            Value::OctetString(b) | Value::Domain(b) => Some(b),
            _ => None,
        }
    }

    /// Encodes as CiA 301 bytes: little-endian numbers, strings without a
    /// terminator, `UNICODE_STRING` as UTF-16LE.
    pub fn encode(&self) -> Vec<u8> {
        match self {
            Value::Real32(v) => v.to_le_bytes().to_vec(),
            Value::Real64(v) => v.to_le_bytes().to_vec(),
            Value::VisibleString(s) => s.as_bytes().to_vec(),
            Value::UnicodeString(s) => s.encode_utf16().flat_map(u16::to_le_bytes).collect(),
            Value::OctetString(b) | Value::Domain(b) => b.clone(),
            _ => match (self.as_i128(), self.data_type().fixed_size()) {
                (Some(v), Some(n)) => v.to_le_bytes()[..n].to_vec(),
                _ => Vec::new(), // unreachable: every other variant is an integer
            },
        }
    }

    /// Decodes CiA 301 bytes as a value of type `ty`.
    ///
    /// Fixed-size types need exactly their size. A `VISIBLE_STRING` has its
    /// trailing NULs trimmed and must then be printable ASCII (tab, CR and
    /// LF allowed); a `UNICODE_STRING` is UTF-16LE with trailing NULs
    /// trimmed.
    pub fn decode(ty: DataType, bytes: &[u8]) -> Result<Value, ValueError> {
        if let Some(expected) = ty.fixed_size()
            && bytes.len() != expected
        {
            return Err(ValueError::WrongSize {
                ty,
                expected,
                got: bytes.len(),
            });
        }
        match ty.kind() {
            Kind::Bool | Kind::Signed | Kind::Unsigned => {
                let negative =
                    ty.kind() == Kind::Signed && bytes.last().is_some_and(|b| b & 0x80 != 0);
                let mut buf = [if negative { 0xFF } else { 0 }; 16];
                buf[..bytes.len()].copy_from_slice(bytes);
                Value::from_integer(ty, i128::from_le_bytes(buf))
            }
            Kind::Float => Ok(
                match (<[u8; 4]>::try_from(bytes), <[u8; 8]>::try_from(bytes)) {
                    (Ok(b), _) => Value::Real32(f32::from_le_bytes(b)),
                    (_, Ok(b)) => Value::Real64(f64::from_le_bytes(b)),
                    _ => unreachable!("size checked above"),
                },
            ),
            Kind::Visible => {
                let end = bytes.iter().rposition(|&b| b != 0).map_or(0, |i| i + 1);
                let text: String = bytes[..end].iter().map(|&b| b as char).collect();
                check_visible(&text)?;
                Ok(Value::VisibleString(text))
            }
            Kind::Unicode => {
                if !bytes.len().is_multiple_of(2) {
                    return Err(ValueError::BadUtf16("odd number of bytes"));
                }
                let mut units: Vec<u16> = bytes
                    .chunks_exact(2)
                    .map(|c| u16::from_le_bytes([c[0], c[1]]))
                    .collect();
                while units.last() == Some(&0) {
                    units.pop();
                }
                String::from_utf16(&units)
                    .map(Value::UnicodeString)
                    .map_err(|_| ValueError::BadUtf16("unpaired surrogate"))
            }
            Kind::Octets if ty == DataType::Domain => Ok(Value::Domain(bytes.to_vec())),
            Kind::Octets => Ok(Value::OctetString(bytes.to_vec())),
        }
    }

    /// Parses command-line text as a value of type `ty`.
    ///
    /// * integers: decimal, `0x` hex or `0b` binary, optional sign; the
    ///   type's range is checked;
    /// * `BOOLEAN`: `true`/`false`, `1`/`0`, `on`/`off`, `yes`/`no`;
    /// * `REAL32`/`REAL64`: decimal or exponent notation, `inf`, `NaN`;
    /// * `VISIBLE_STRING` (printable ASCII) and `UNICODE_STRING`: the text
    ///   as is;
    /// * `OCTET_STRING`/`DOMAIN`: hex bytes, e.g. `DE AD BE EF`,
    ///   `deadbeef`, `de:ad:be:ef` or `0xDEADBEEF`.
    ///
    /// Parsing the [`Display`](fmt::Display) output gives the value back.
    pub fn parse(ty: DataType, text: &str) -> Result<Value, ValueError> {
        Value::parse_with(ty, text, Syntax::Cli)
    }

    /// Parses a value written in an EDS/DCF file (CiA 306): as
    /// [`Value::parse`], but a leading `0` means octal, `0b` is not
    /// special, and signed types also accept hex two's complement
    /// (`0xFFFF` as `INTEGER16` is -1).
    pub fn parse_eds(ty: DataType, text: &str) -> Result<Value, ValueError> {
        Value::parse_with(ty, text, Syntax::Eds)
    }

    fn parse_with(ty: DataType, text: &str, syntax: Syntax) -> Result<Value, ValueError> {
        let invalid = |reason: String| ValueError::Invalid {
            ty,
            text: text.to_owned(),
            reason,
        };
        let t = text.trim();
        match ty.kind() {
            Kind::Bool => match t.to_ascii_lowercase().as_str() {
                "true" | "on" | "yes" => Ok(Value::Boolean(true)),
                "false" | "off" | "no" => Ok(Value::Boolean(false)),
                _ => Value::from_integer(ty, parse_int(t, syntax).map_err(invalid)?.0),
            },
            Kind::Signed | Kind::Unsigned => {
                let (mut v, hex) = parse_int(t, syntax).map_err(invalid)?;
                if let (Syntax::Eds, true, Kind::Signed, Some(n)) =
                    (syntax, hex, ty.kind(), ty.fixed_size())
                    && v >= 1 << (n * 8 - 1)
                    && v < 1 << (n * 8)
                {
                    v -= 1 << (n * 8); // two's complement written in hex
                }
                Value::from_integer(ty, v)
            }
            Kind::Float => {
                let looks_infinite = t.to_ascii_lowercase().contains("inf");
                let too_big = || invalid(format!("out of range for {ty}"));
                if ty == DataType::Real32 {
                    let v: f32 = t.parse().map_err(|_| invalid("not a number".into()))?;
                    if v.is_infinite() && !looks_infinite {
                        return Err(too_big());
                    }
                    Ok(Value::Real32(v))
                } else {
                    let v: f64 = t.parse().map_err(|_| invalid("not a number".into()))?;
                    if v.is_infinite() && !looks_infinite {
                        return Err(too_big());
                    }
                    Ok(Value::Real64(v))
                }
            }
            Kind::Visible => {
                check_visible(text)?;
                Ok(Value::VisibleString(text.to_owned()))
            }
            Kind::Unicode => Ok(Value::UnicodeString(text.to_owned())),
            Kind::Octets => {
                let bytes = parse_hex_bytes(t).map_err(invalid)?;
                Ok(if ty == DataType::Domain {
                    Value::Domain(bytes)
                } else {
                    Value::OctetString(bytes)
                })
            }
        }
    }
}

impl fmt::Display for Value {
    /// Human-readable text that [`Value::parse`] accepts back. With `{:#}`,
    /// unsigned integers are shown as zero-padded hex (`0x00020192`).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Value::Boolean(b) => write!(f, "{b}"),
            Value::Real32(v) => write!(f, "{v}"),
            Value::Real64(v) => write!(f, "{v}"),
            Value::VisibleString(s) | Value::UnicodeString(s) => f.write_str(s),
            Value::OctetString(b) | Value::Domain(b) => {
                for (i, byte) in b.iter().enumerate() {
                    let sep = if i == 0 { "" } else { " " };
                    write!(f, "{sep}{byte:02X}")?;
                }
                Ok(())
            }
            _ => {
                let v = self.as_i128().unwrap_or_default();
                let ty = self.data_type();
                match ty.fixed_size() {
                    Some(n) if f.alternate() && ty.kind() == Kind::Unsigned => {
                        write!(f, "0x{v:0w$X}", w = n * 2)
                    }
                    _ => write!(f, "{v}"),
                }
            }
        }
    }
}

/// Checks that `text` is printable ASCII (plus tab, CR, LF).
fn check_visible(text: &str) -> Result<(), ValueError> {
    match text
        .char_indices()
        .find(|&(_, c)| !(c.is_ascii_graphic() || matches!(c, ' ' | '\t' | '\r' | '\n')))
    {
        Some((offset, ch)) => Err(ValueError::NotVisible { ch, offset }),
        None => Ok(()),
    }
}

/// Parses an integer; returns the value and whether it was written in hex.
fn parse_int(t: &str, syntax: Syntax) -> Result<(i128, bool), String> {
    let (negative, rest) = match t.as_bytes().first() {
        Some(b'-') => (true, &t[1..]),
        Some(b'+') => (false, &t[1..]),
        _ => (false, t),
    };
    let lower = rest.to_ascii_lowercase();
    let (radix, digits, name) = if let Some(d) = lower.strip_prefix("0x") {
        (16, d, "hex")
    } else if let (Syntax::Cli, Some(d)) = (syntax, lower.strip_prefix("0b")) {
        (2, d, "binary")
    } else if syntax == Syntax::Eds && lower.len() > 1 && lower.starts_with('0') {
        (8, &lower[1..], "octal")
    } else {
        (10, lower.as_str(), "decimal")
    };
    if digits.is_empty() {
        return Err("expected a number".into());
    }
    if !digits.chars().all(|c| c.is_digit(radix)) {
        return Err(format!("not a {name} number"));
    }
    let magnitude = u128::from_str_radix(digits, radix)
        .ok()
        .and_then(|m| i128::try_from(m).ok())
        .ok_or("number too large")?;
    Ok((if negative { -magnitude } else { magnitude }, radix == 16))
}

/// Parses hex bytes separated by nothing, spaces, `:`, `-` or `,`; each
/// group may carry a `0x` prefix.
fn parse_hex_bytes(t: &str) -> Result<Vec<u8>, String> {
    let mut bytes = Vec::new();
    for group in t.split(|c: char| c.is_whitespace() || matches!(c, ':' | '-' | ',')) {
        let group = group
            .strip_prefix("0x")
            .or_else(|| group.strip_prefix("0X"))
            .unwrap_or(group);
        let nibbles = group
            .chars()
            .map(|c| c.to_digit(16).map(|d| d as u8))
            .collect::<Option<Vec<u8>>>()
            .ok_or_else(|| format!("{group:?} is not hex"))?;
        if !nibbles.len().is_multiple_of(2) {
            return Err(format!("odd number of hex digits in {group:?}"));
        }
        bytes.extend(nibbles.chunks(2).map(|p| (p[0] << 4) | p[1]));
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use DataType as D;
    use proptest::prelude::*;

    fn round_trip(v: &Value) {
        let ty = v.data_type();
        let bytes = v.encode();
        if let Some(n) = ty.fixed_size() {
            assert_eq!(bytes.len(), n, "{ty}");
        }
        assert_eq!(&Value::decode(ty, &bytes).unwrap(), v, "decode {ty}");
        assert_eq!(
            &Value::parse(ty, &v.to_string()).unwrap(),
            v,
            "parse {ty} {v}"
        );
    }

    #[test]
    fn table_matches_declaration_order_and_codes() {
        for (i, row) in TABLE.iter().enumerate() {
            assert_eq!(row.0 as usize, i);
            assert_eq!(DataType::from_code(row.1), Some(row.0));
            assert_eq!(row.3.parse::<DataType>().unwrap(), row.0);
            assert_eq!(row.2.to_lowercase().parse::<DataType>().unwrap(), row.0);
        }
        assert_eq!(D::Unsigned32.code(), 0x0007);
        assert_eq!(D::Domain.code(), 0x000F);
        assert_eq!(D::Unsigned64.code(), 0x001B);
        assert_eq!(DataType::from_code(0x000C), None); // TIME_OF_DAY
        assert_eq!(D::Integer24.fixed_size(), Some(3));
        assert_eq!(D::VisibleString.fixed_size(), None);
        assert_eq!(D::Boolean.bit_len(), Some(1));
        assert_eq!(D::Integer16.bit_len(), Some(16));
        assert_eq!(D::Integer8.integer_range(), Some((-128, 127)));
        assert_eq!(D::Unsigned64.integer_range(), Some((0, u64::MAX.into())));
        assert!(matches!(
            "u128".parse::<DataType>(),
            Err(ValueError::UnknownType(_))
        ));
    }

    #[test]
    fn every_type_round_trips() {
        for ty in DataType::ALL {
            round_trip(&Value::zero(ty));
        }
        let samples = [
            Value::Boolean(true),
            Value::Integer24(-(1 << 23)),
            Value::Unsigned24(0xFF_FFFF),
            Value::Integer40(-(1 << 39)),
            Value::Unsigned48((1 << 48) - 1),
            Value::Integer56((1 << 55) - 1),
            Value::Unsigned56(0x12_3456_789A_BCDE),
            Value::Real32(-1.5e-3),
            Value::Real64(6.02e23),
            Value::VisibleString("cangate sim drive".into()),
            Value::UnicodeString("Grüße, 世界 🎉".into()),
            Value::OctetString(vec![0xDE, 0xAD, 0xBE, 0xEF]),
            Value::Domain(vec![0; 300]),
        ];
        for v in &samples {
            round_trip(v);
        }
    }

    #[test]
    fn little_endian_encoding() {
        assert_eq!(
            Value::Unsigned32(0x0002_0192).encode(),
            [0x92, 0x01, 0x02, 0x00]
        );
        assert_eq!(Value::Integer16(-2).encode(), [0xFE, 0xFF]);
        assert_eq!(Value::Integer24(-2).encode(), [0xFE, 0xFF, 0xFF]);
        assert_eq!(Value::Real32(1.0).encode(), [0, 0, 0x80, 0x3F]);
        assert_eq!(
            Value::UnicodeString("Aé".into()).encode(),
            [0x41, 0, 0xE9, 0]
        );
        assert_eq!(
            Value::decode(D::Integer24, &[0, 0, 0x80]).unwrap(),
            Value::Integer24(-(1 << 23))
        );
    }

    #[test]
    fn wrong_sizes_are_typed_errors() {
        let err = Value::decode(D::Unsigned16, &[1, 2, 3]).unwrap_err();
        assert_eq!(
            err,
            ValueError::WrongSize {
                ty: D::Unsigned16,
                expected: 2,
                got: 3
            }
        );
        assert_eq!(
            err.to_string(),
            "wrong size for UNSIGNED16: expected 2 bytes, got 3"
        );
        assert!(Value::decode(D::Real64, &[0; 4]).is_err());
        assert!(Value::decode(D::Boolean, &[]).is_err());
        assert_eq!(
            Value::decode(D::Boolean, &[2]).unwrap_err().to_string(),
            "value 2 does not fit BOOLEAN (0..=1)"
        );
    }

    #[test]
    fn strings_decode_strictly() {
        let v = Value::decode(D::VisibleString, b"drive\0\0").unwrap();
        assert_eq!(v, Value::VisibleString("drive".into()));
        assert_eq!(
            Value::decode(D::VisibleString, b"a\x01b").unwrap_err(),
            ValueError::NotVisible {
                ch: '\u{1}',
                offset: 1
            }
        );
        assert!(Value::decode(D::VisibleString, b"a\0b").is_err());
        assert!(Value::parse(D::VisibleString, "café").is_err());
        assert_eq!(
            Value::decode(D::UnicodeString, &[0x41, 0, 0, 0]).unwrap(),
            Value::UnicodeString("A".into())
        );
        assert_eq!(
            Value::decode(D::UnicodeString, &[0x41]).unwrap_err(),
            ValueError::BadUtf16("odd number of bytes")
        );
        assert!(Value::decode(D::UnicodeString, &[0x00, 0xD8]).is_err()); // lone surrogate
    }

    #[test]
    fn cli_integers_check_ranges() {
        let err = Value::parse(D::Unsigned8, "300").unwrap_err();
        assert_eq!(
            err.to_string(),
            "value 300 does not fit UNSIGNED8 (0..=255)"
        );
        assert_eq!(
            Value::parse(D::Unsigned8, "0xff").unwrap(),
            Value::Unsigned8(255)
        );
        assert_eq!(
            Value::parse(D::Unsigned8, "0b101").unwrap(),
            Value::Unsigned8(5)
        );
        assert_eq!(
            Value::parse(D::Unsigned16, " 010 ").unwrap(),
            Value::Unsigned16(10)
        ); // decimal on the CLI
        assert_eq!(
            Value::parse(D::Integer8, "-128").unwrap(),
            Value::Integer8(-128)
        );
        assert_eq!(
            Value::parse(D::Integer8, "0xFF").unwrap_err().to_string(),
            "value 255 does not fit INTEGER8 (-128..=127)"
        );
        assert!(Value::parse(D::Unsigned32, "-1").is_err());
        assert_eq!(
            Value::parse(D::Unsigned64, "18446744073709551615").unwrap(),
            Value::Unsigned64(u64::MAX)
        );
        assert!(Value::parse(D::Unsigned64, "18446744073709551616").is_err());
        let err = Value::parse(D::Unsigned16, "12a").unwrap_err();
        assert_eq!(
            err.to_string(),
            "invalid UNSIGNED16 value \"12a\": not a decimal number"
        );
        assert!(Value::parse(D::Unsigned16, "0x").is_err());
        assert!(Value::parse(D::Unsigned16, "").is_err());
        assert!(Value::parse(D::Unsigned64, &"9".repeat(50)).is_err());
        assert_eq!(
            Value::parse(D::Boolean, "ON").unwrap(),
            Value::Boolean(true)
        );
        assert_eq!(
            Value::parse(D::Boolean, "0").unwrap(),
            Value::Boolean(false)
        );
        assert!(Value::parse(D::Boolean, "2").is_err());
    }

    #[test]
    fn eds_number_syntax() {
        assert_eq!(
            Value::parse_eds(D::Unsigned16, "010").unwrap(),
            Value::Unsigned16(8)
        );
        assert_eq!(
            Value::parse_eds(D::Unsigned16, "0").unwrap(),
            Value::Unsigned16(0)
        );
        assert_eq!(
            Value::parse_eds(D::Integer16, "0xFFFF").unwrap(),
            Value::Integer16(-1)
        );
        assert_eq!(
            Value::parse_eds(D::Integer32, "0x80000000").unwrap(),
            Value::Integer32(i32::MIN)
        );
        assert!(Value::parse_eds(D::Integer16, "0x10000").is_err());
        assert!(Value::parse_eds(D::Unsigned16, "09").is_err()); // not octal
    }

    #[test]
    fn cli_floats_and_bytes() {
        assert_eq!(Value::parse(D::Real32, "1.5").unwrap(), Value::Real32(1.5));
        assert_eq!(
            Value::parse(D::Real64, "-2e3").unwrap(),
            Value::Real64(-2000.0)
        );
        assert!(Value::parse(D::Real32, "1e39").is_err());
        assert!(Value::parse(D::Real32, "abc").is_err());
        assert_eq!(
            Value::parse(D::Real32, "inf").unwrap(),
            Value::Real32(f32::INFINITY)
        );
        let dead = vec![0xDE, 0xAD, 0xBE, 0xEF];
        for text in [
            "DE AD BE EF",
            "deadbeef",
            "de:ad:be:ef",
            "0xDEADBEEF",
            " dead beef ",
        ] {
            assert_eq!(
                Value::parse(D::OctetString, text).unwrap(),
                Value::OctetString(dead.clone())
            );
        }
        assert_eq!(Value::parse(D::Domain, "").unwrap(), Value::Domain(vec![]));
        assert!(
            Value::parse(D::Domain, "abc")
                .unwrap_err()
                .to_string()
                .contains("odd number of hex digits")
        );
        assert!(Value::parse(D::OctetString, "zz").is_err());
    }

    #[test]
    fn display_and_helpers() {
        assert_eq!(Value::Unsigned32(0x0002_0192).to_string(), "131474");
        assert_eq!(
            format!("{:#}", Value::Unsigned32(0x0002_0192)),
            "0x00020192"
        );
        assert_eq!(format!("{:#}", Value::Integer8(-3)), "-3");
        assert_eq!(Value::OctetString(vec![1, 0xAB]).to_string(), "01 AB");
        assert_eq!(Value::Unsigned16(7).as_u32(), Some(7));
        assert_eq!(Value::Integer8(-1).as_u32(), None);
        assert_eq!(Value::Real32(0.5).as_f64(), Some(0.5));
        assert_eq!(
            Value::from_integer_wrapping(D::Unsigned8, 300),
            Some(Value::Unsigned8(44))
        );
        assert_eq!(
            Value::from_integer_wrapping(D::Integer8, 255),
            Some(Value::Integer8(-1))
        );
        assert!(Value::from_integer(D::Real32, 1).is_err());
    }

    macro_rules! int_props {
        ($($name:ident: $variant:ident($strategy:expr);)*) => {
            proptest! {
                $(#[test] fn $name(v in $strategy) { round_trip(&Value::$variant(v)); })*
            }
        };
    }

    int_props! {
        prop_bool: Boolean(any::<bool>());
        prop_i8: Integer8(any::<i8>());
        prop_i16: Integer16(any::<i16>());
        prop_i24: Integer24(-(1i32 << 23)..(1 << 23));
        prop_i32: Integer32(any::<i32>());
        prop_i40: Integer40(-(1i64 << 39)..(1 << 39));
        prop_i48: Integer48(-(1i64 << 47)..(1 << 47));
        prop_i56: Integer56(-(1i64 << 55)..(1 << 55));
        prop_i64: Integer64(any::<i64>());
        prop_u8: Unsigned8(any::<u8>());
        prop_u16: Unsigned16(any::<u16>());
        prop_u24: Unsigned24(0u32..(1 << 24));
        prop_u32: Unsigned32(any::<u32>());
        prop_u40: Unsigned40(0u64..(1 << 40));
        prop_u48: Unsigned48(0u64..(1 << 48));
        prop_u56: Unsigned56(0u64..(1 << 56));
        prop_u64: Unsigned64(any::<u64>());
        prop_f32: Real32(proptest::num::f32::NORMAL | proptest::num::f32::SUBNORMAL | proptest::num::f32::ZERO);
        prop_f64: Real64(proptest::num::f64::NORMAL | proptest::num::f64::SUBNORMAL | proptest::num::f64::ZERO);
        prop_visible: VisibleString("[ -~]{0,40}");
        prop_unicode: UnicodeString("\\PC{0,20}");
        prop_octets: OctetString(proptest::collection::vec(any::<u8>(), 0..40));
        prop_domain: Domain(proptest::collection::vec(any::<u8>(), 0..40));
    }

    proptest! {
        #[test]
        fn prop_out_of_range_rejected(v in 256i64..100_000) {
            let err = Value::parse(D::Unsigned8, &v.to_string()).unwrap_err();
            prop_assert_eq!(err, ValueError::OutOfRange { ty: D::Unsigned8, value: v.into(), min: 0, max: 255 });
        }

        #[test]
        fn prop_hex_equals_decimal(v in any::<u32>()) {
            prop_assert_eq!(
                Value::parse(D::Unsigned32, &format!("0x{v:X}")).unwrap(),
                Value::parse(D::Unsigned32, &v.to_string()).unwrap()
            );
        }
    }
}
