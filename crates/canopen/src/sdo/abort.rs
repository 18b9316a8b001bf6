//! SDO abort codes (CiA 301, table "SDO abort codes").

use std::fmt;

/// An SDO abort code as carried little-endian in bytes 4..8 of an abort
/// frame. Any `u32` is representable: devices also send vendor codes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct AbortCode(pub u32);

macro_rules! abort_codes {
    ($($(#[$doc:meta])* $name:ident = $value:literal, $text:literal;)*) => {
        impl AbortCode {
            $($(#[$doc])* pub const $name: AbortCode = AbortCode($value);)*
        }
        /// Every standard code with its CiA 301 text (lower-cased, no period).
        const STANDARD: &[(u32, &str)] = &[$(($value, $text)),*];
    };
}

abort_codes! {
    /// 0x05030000.
    TOGGLE_BIT_NOT_ALTERNATED = 0x0503_0000, "toggle bit not alternated";
    /// 0x05040000.
    TIMEOUT = 0x0504_0000, "SDO protocol timed out";
    /// 0x05040001.
    INVALID_COMMAND = 0x0504_0001, "client/server command specifier not valid or unknown";
    /// 0x05040002.
    INVALID_BLOCK_SIZE = 0x0504_0002, "invalid block size (block mode only)";
    /// 0x05040003.
    INVALID_SEQUENCE_NUMBER = 0x0504_0003, "invalid sequence number (block mode only)";
    /// 0x05040004.
    CRC_ERROR = 0x0504_0004, "CRC error (block mode only)";
    /// 0x05040005.
    OUT_OF_MEMORY = 0x0504_0005, "out of memory";
    /// 0x06010000.
    UNSUPPORTED_ACCESS = 0x0601_0000, "unsupported access to an object";
    /// 0x06010001.
    READ_OF_WRITE_ONLY = 0x0601_0001, "attempt to read a write only object";
    /// 0x06010002.
    WRITE_OF_READ_ONLY = 0x0601_0002, "attempt to write a read only object";
    /// 0x06020000.
    OBJECT_DOES_NOT_EXIST = 0x0602_0000, "object does not exist in the object dictionary";
    /// 0x06040041.
    CANNOT_MAP_TO_PDO = 0x0604_0041, "object cannot be mapped to the PDO";
    /// 0x06040042.
    PDO_LENGTH_EXCEEDED = 0x0604_0042,
        "the number and length of the objects to be mapped would exceed PDO length";
    /// 0x06040043.
    PARAMETER_INCOMPATIBILITY = 0x0604_0043, "general parameter incompatibility reason";
    /// 0x06040047.
    INTERNAL_INCOMPATIBILITY = 0x0604_0047, "general internal incompatibility in the device";
    /// 0x06060000.
    HARDWARE_ERROR = 0x0606_0000, "access failed due to a hardware error";
    /// 0x06070010.
    LENGTH_MISMATCH = 0x0607_0010,
        "data type does not match, length of service parameter does not match";
    /// 0x06070012.
    LENGTH_TOO_HIGH = 0x0607_0012, "data type does not match, length of service parameter too high";
    /// 0x06070013.
    LENGTH_TOO_LOW = 0x0607_0013, "data type does not match, length of service parameter too low";
    /// 0x06090011.
    SUB_INDEX_DOES_NOT_EXIST = 0x0609_0011, "sub-index does not exist";
    /// 0x06090030.
    INVALID_VALUE = 0x0609_0030, "invalid value for parameter (download only)";
    /// 0x06090031.
    VALUE_TOO_HIGH = 0x0609_0031, "value of parameter written too high (download only)";
    /// 0x06090032.
    VALUE_TOO_LOW = 0x0609_0032, "value of parameter written too low (download only)";
    /// 0x06090036.
    MAX_LESS_THAN_MIN = 0x0609_0036, "maximum value is less than minimum value";
    /// 0x060A0023.
    NO_SDO_CONNECTION = 0x060A_0023, "resource not available: SDO connection";
    /// 0x08000000.
    GENERAL_ERROR = 0x0800_0000, "general error";
    /// 0x08000020.
    CANNOT_TRANSFER = 0x0800_0020, "data cannot be transferred or stored to the application";
    /// 0x08000021.
    CANNOT_TRANSFER_LOCAL_CONTROL = 0x0800_0021,
        "data cannot be transferred or stored to the application because of local control";
    /// 0x08000022.
    CANNOT_TRANSFER_DEVICE_STATE = 0x0800_0022,
        "data cannot be transferred or stored to the application because of the present device state";
    /// 0x08000023.
    NO_OBJECT_DICTIONARY = 0x0800_0023,
        "object dictionary dynamic generation fails or no object dictionary is present";
    /// 0x08000024.
    NO_DATA_AVAILABLE = 0x0800_0024, "no data available";
}

impl AbortCode {
    /// The raw value.
    pub const fn get(self) -> u32 {
        self.0
    }

    /// The CiA 301 text of a standard code, or "unknown abort code".
    pub fn name(self) -> &'static str {
        STANDARD
            .iter()
            .find(|(v, _)| *v == self.0)
            .map_or("unknown abort code", |(_, text)| text)
    }

    /// True for the codes CiA 301 defines.
    pub fn is_standard(self) -> bool {
        STANDARD.iter().any(|(v, _)| *v == self.0)
    }

    /// Every code CiA 301 defines, in numeric order.
    pub fn standard() -> impl Iterator<Item = AbortCode> {
        STANDARD.iter().map(|(v, _)| AbortCode(*v))
    }
}

impl From<u32> for AbortCode {
    fn from(v: u32) -> Self {
        AbortCode(v)
    }
}

impl From<AbortCode> for u32 {
    fn from(c: AbortCode) -> Self {
        c.0
    }
}

impl fmt::Display for AbortCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:08X} ({})", self.0, self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_standard_code_has_a_unique_name() {
        let codes: Vec<_> = AbortCode::standard().collect();
        assert_eq!(codes.len(), 31);
        assert!(
            codes.windows(2).all(|w| w[0] < w[1]),
            "table sorted, no duplicates"
        );
        for c in &codes {
            assert!(c.is_standard());
            assert_ne!(c.name(), "unknown abort code");
        }
    }

    #[test]
    fn names_and_display() {
        assert_eq!(
            AbortCode(0x0607_0013).name(),
            "data type does not match, length of service parameter too low"
        );
        assert_eq!(
            AbortCode::LENGTH_TOO_LOW.to_string(),
            "0x06070013 (data type does not match, length of service parameter too low)"
        );
        assert_eq!(AbortCode::TIMEOUT.name(), "SDO protocol timed out");
        assert_eq!(AbortCode::NO_SDO_CONNECTION.get(), 0x060A_0023);
        assert_eq!(AbortCode(0x1234_5678).name(), "unknown abort code");
        assert!(!AbortCode(0).is_standard());
        assert_eq!(
            AbortCode(0x1234_5678).to_string(),
            "0x12345678 (unknown abort code)"
        );
        assert_eq!(u32::from(AbortCode::from(7)), 7);
    }
}
