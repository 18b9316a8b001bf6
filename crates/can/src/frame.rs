//! The CAN frame model: classic CAN 2.0 (standard and extended identifiers,
//! data and remote frames), CAN FD (up to 64 bytes, BRS/ESI) and SocketCAN
//! error frames, each with a receive/transmit timestamp.
//!
//! Every constructor validates its input, so a [`Frame`] that exists is a
//! frame the wire can carry.

use std::fmt;
use std::time::{SystemTime, UNIX_EPOCH};

/// Largest 11-bit identifier.
pub const MAX_STANDARD_ID: u16 = 0x7FF;
/// Largest 29-bit identifier.
pub const MAX_EXTENDED_ID: u32 = 0x1FFF_FFFF;
/// Payload limit of a classic CAN frame.
pub const CLASSIC_MAX_LEN: usize = 8;
/// Payload limit of a CAN FD frame.
pub const FD_MAX_LEN: usize = 64;
/// The payload lengths a CAN FD frame can have (DLC 0..=15).
pub const FD_LENGTHS: [usize; 16] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64];

/// Why a frame could not be built.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// A standard identifier above 0x7FF.
    #[error(
        "identifier 0x{0:X} does not fit in 11 bits (standard ids are 0x000..=0x7FF; use an extended id)"
    )]
    StandardIdOutOfRange(u32),
    /// An extended identifier above 0x1FFFFFFF.
    #[error(
        "identifier 0x{0:X} does not fit in 29 bits (extended ids are 0x00000000..=0x1FFFFFFF)"
    )]
    ExtendedIdOutOfRange(u32),
    /// More than 8 data bytes on a classic frame.
    #[error("{0} data bytes do not fit in a classic CAN frame (at most 8; use CAN FD for more)")]
    ClassicTooLong(usize),
    /// A CAN FD payload length that no DLC encodes.
    #[error("{0} data bytes is not a valid CAN FD length (valid: 0-8, 12, 16, 20, 24, 32, 48, 64)")]
    BadFdLength(usize),
    /// A remote frame asking for more than 8 bytes.
    #[error("remote frame DLC {0} is out of range (0..=8)")]
    RemoteDlcOutOfRange(u8),
    /// Remote frames do not exist in CAN FD.
    #[error("CAN FD has no remote frames")]
    RemoteFd,
}

/// A CAN identifier: 11-bit standard or 29-bit extended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum CanId {
    /// 11-bit identifier (CAN 2.0A).
    Standard(u16),
    /// 29-bit identifier (CAN 2.0B).
    Extended(u32),
}

impl CanId {
    /// A standard id, rejecting values above 0x7FF.
    pub fn standard(id: u32) -> Result<Self, FrameError> {
        if id > MAX_STANDARD_ID as u32 {
            return Err(FrameError::StandardIdOutOfRange(id));
        }
        Ok(CanId::Standard(id as u16))
    }

    /// An extended id, rejecting values above 0x1FFFFFFF.
    pub fn extended(id: u32) -> Result<Self, FrameError> {
        if id > MAX_EXTENDED_ID {
            return Err(FrameError::ExtendedIdOutOfRange(id));
        }
        Ok(CanId::Extended(id))
    }

    /// Builds an id from its raw value and format flag.
    pub fn new(id: u32, extended: bool) -> Result<Self, FrameError> {
        if extended {
            Self::extended(id)
        } else {
            Self::standard(id)
        }
    }

    /// The numeric identifier without any format flag.
    pub fn raw(self) -> u32 {
        match self {
            CanId::Standard(id) => id as u32,
            CanId::Extended(id) => id,
        }
    }

    /// True for a 29-bit identifier.
    pub fn is_extended(self) -> bool {
        matches!(self, CanId::Extended(_))
    }

    /// The arbitration priority key: a lower key wins arbitration.
    ///
    /// A standard frame beats an extended frame whose 11 most significant
    /// bits are equal (its IDE bit is dominant), which this key encodes by
    /// comparing the base id first, then the IDE bit, then the extension.
    pub fn arbitration_key(self) -> u64 {
        match self {
            CanId::Standard(id) => (id as u64) << 19,
            CanId::Extended(id) => {
                let base = (id >> 18) as u64;
                let ext = (id & 0x3FFFF) as u64;
                (base << 19) | (1 << 18) | ext
            }
        }
    }
}

impl fmt::Display for CanId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CanId::Standard(id) => write!(f, "{id:03X}"),
            CanId::Extended(id) => write!(f, "{id:08X}"),
        }
    }
}

/// What kind of frame this is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FrameKind {
    /// A data frame (classic or FD).
    Data,
    /// A remote transmission request (classic only); `len` is the requested DLC.
    Remote,
    /// A SocketCAN error frame: the id carries the error class bits
    /// (`CAN_ERR_*`), the 8 data bytes the details.
    Error,
}

/// Nanoseconds since the UNIX epoch; 0 means "not stamped".
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Timestamp(pub u64);

impl Timestamp {
    /// The current wall-clock time.
    pub fn now() -> Self {
        let d = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .unwrap_or_default();
        Timestamp(d.as_nanos() as u64)
    }

    /// Nanoseconds since the UNIX epoch.
    pub fn as_nanos(self) -> u64 {
        self.0
    }
}

/// One CAN frame.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Frame {
    id: CanId,
    kind: FrameKind,
    fd: bool,
    brs: bool,
    esi: bool,
    /// Payload length for data/error frames; requested DLC for remote frames.
    len: u8,
    data: [u8; FD_MAX_LEN],
    timestamp: Timestamp,
}

impl Frame {
    /// A classic data frame with 0..=8 bytes.
    pub fn new(id: CanId, data: &[u8]) -> Result<Self, FrameError> {
        if data.len() > CLASSIC_MAX_LEN {
            return Err(FrameError::ClassicTooLong(data.len()));
        }
        Ok(Self::raw(id, FrameKind::Data, false, false, false, data))
    }

    /// A CAN FD data frame; `data.len()` must be one of [`FD_LENGTHS`].
    pub fn new_fd(id: CanId, data: &[u8], brs: bool, esi: bool) -> Result<Self, FrameError> {
        if !FD_LENGTHS.contains(&data.len()) {
            return Err(FrameError::BadFdLength(data.len()));
        }
        Ok(Self::raw(id, FrameKind::Data, true, brs, esi, data))
    }

    /// A classic remote frame requesting `dlc` bytes (0..=8).
    pub fn new_remote(id: CanId, dlc: u8) -> Result<Self, FrameError> {
        if dlc as usize > CLASSIC_MAX_LEN {
            return Err(FrameError::RemoteDlcOutOfRange(dlc));
        }
        let mut f = Self::raw(id, FrameKind::Remote, false, false, false, &[]);
        f.len = dlc;
        Ok(f)
    }

    /// A SocketCAN error frame: `class` is the `CAN_ERR_*` bit set.
    pub fn new_error(class: u32, data: [u8; 8]) -> Self {
        Self::raw(
            CanId::Extended(class & MAX_EXTENDED_ID),
            FrameKind::Error,
            false,
            false,
            false,
            &data,
        )
    }

    /// Builds any frame from its parts, with the same validation as the
    /// specific constructors. Used where frames arrive as plain fields (gRPC,
    /// text).
    pub fn from_parts(
        id: u32,
        extended: bool,
        kind: FrameKind,
        fd: bool,
        brs: bool,
        esi: bool,
        data: &[u8],
        remote_dlc: u8,
    ) -> Result<Self, FrameError> {
        let cid = CanId::new(id, extended)?;
        match kind {
            FrameKind::Remote if fd => Err(FrameError::RemoteFd),
            FrameKind::Remote => Self::new_remote(cid, remote_dlc),
            FrameKind::Data if fd => Self::new_fd(cid, data, brs, esi),
            FrameKind::Data => Self::new(cid, data),
            FrameKind::Error => {
                let mut d = [0u8; 8];
                let n = data.len().min(8);
                d[..n].copy_from_slice(&data[..n]);
                Ok(Self::new_error(id, d))
            }
        }
    }

    fn raw(id: CanId, kind: FrameKind, fd: bool, brs: bool, esi: bool, data: &[u8]) -> Self {
        let mut buf = [0u8; FD_MAX_LEN];
        buf[..data.len()].copy_from_slice(data);
        Frame {
            id,
            kind,
            fd,
            brs: fd && brs,
            esi: fd && esi,
            len: data.len() as u8,
            data: buf,
            timestamp: Timestamp::default(),
        }
    }

    /// The identifier.
    pub fn id(&self) -> CanId {
        self.id
    }
    /// The numeric identifier.
    pub fn raw_id(&self) -> u32 {
        self.id.raw()
    }
    /// True for a 29-bit identifier.
    pub fn is_extended(&self) -> bool {
        self.id.is_extended()
    }
    /// Data, remote or error frame.
    pub fn kind(&self) -> FrameKind {
        self.kind
    }
    /// True for a remote transmission request.
    pub fn is_remote(&self) -> bool {
        self.kind == FrameKind::Remote
    }
    /// True for a SocketCAN error frame.
    pub fn is_error(&self) -> bool {
        self.kind == FrameKind::Error
    }
    /// True for a CAN FD frame.
    pub fn is_fd(&self) -> bool {
        self.fd
    }
    /// CAN FD bit rate switch.
    pub fn brs(&self) -> bool {
        self.brs
    }
    /// CAN FD error state indicator.
    pub fn esi(&self) -> bool {
        self.esi
    }
    /// The payload (empty for remote frames).
    pub fn data(&self) -> &[u8] {
        match self.kind {
            FrameKind::Remote => &[],
            _ => &self.data[..self.len as usize],
        }
    }
    /// The DLC field: payload length code (FD lengths above 8 map to 9..=15),
    /// or the requested length of a remote frame.
    pub fn dlc(&self) -> u8 {
        if self.kind == FrameKind::Remote || self.len <= 8 {
            self.len
        } else {
            FD_LENGTHS
                .iter()
                .position(|&l| l == self.len as usize)
                .unwrap_or(15) as u8
        }
    }
    /// When the frame was seen on (or accepted for) the bus.
    pub fn timestamp(&self) -> Timestamp {
        self.timestamp
    }
    /// The same frame with a timestamp.
    pub fn with_timestamp(mut self, ts: Timestamp) -> Self {
        self.timestamp = ts;
        self
    }
    /// Sets the timestamp.
    pub fn set_timestamp(&mut self, ts: Timestamp) {
        self.timestamp = ts;
    }
}

impl fmt::Debug for Frame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Frame({self})")
    }
}

/// Formats like `cansend` input: `123#DEADBEEF`, `1F334455#11`, `123#R`,
/// `123##1AABB` (FD, flags nibble after `##`).
impl fmt::Display for Frame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.id)?;
        match self.kind {
            FrameKind::Remote => {
                write!(f, "#R")?;
                if self.len > 0 {
                    write!(f, "{}", self.len)?;
                }
                Ok(())
            }
            FrameKind::Error | FrameKind::Data if !self.fd => {
                write!(f, "#")?;
                for b in self.data() {
                    write!(f, "{b:02X}")?;
                }
                Ok(())
            }
            _ => {
                let flags = (self.brs as u8) | ((self.esi as u8) << 1);
                write!(f, "##{flags:X}")?;
                for b in self.data() {
                    write!(f, "{b:02X}")?;
                }
                Ok(())
            }
        }
    }
}

/// Why a `cansend`-style frame text could not be parsed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ParseFrameError {
    /// No `#` separator.
    #[error("expected <id>#<data>, <id>#R or <id>##<flags><data>, got {0:?}")]
    Syntax(String),
    /// The id is not 3 (standard) or 8 (extended) hex digits.
    #[error("identifier {0:?} must be 3 hex digits (standard) or 8 hex digits (extended)")]
    Id(String),
    /// Payload is not hex pairs.
    #[error("data {0:?} is not a sequence of hex byte pairs")]
    Data(String),
    /// The frame itself is invalid.
    #[error(transparent)]
    Frame(#[from] FrameError),
}

impl std::str::FromStr for Frame {
    type Err = ParseFrameError;

    /// Parses `cansend` syntax: `<id>#{data}` classic, `<id>#R{len}` remote,
    /// `<id>##<flags>{data}` CAN FD. A 3-digit id is standard, an 8-digit id
    /// extended. Data bytes may be separated by `.` as in cansend.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let s = s.trim();
        let (id_txt, rest) = s
            .split_once('#')
            .ok_or_else(|| ParseFrameError::Syntax(s.to_string()))?;
        let extended = match id_txt.len() {
            3 => false,
            8 => true,
            _ => return Err(ParseFrameError::Id(id_txt.to_string())),
        };
        let id =
            u32::from_str_radix(id_txt, 16).map_err(|_| ParseFrameError::Id(id_txt.to_string()))?;
        let cid = CanId::new(id, extended)?;
        if let Some(fd_rest) = rest.strip_prefix('#') {
            let mut chars = fd_rest.chars();
            let flags = chars
                .next()
                .and_then(|c| c.to_digit(16))
                .ok_or_else(|| ParseFrameError::Syntax(s.to_string()))?;
            let data = parse_hex(chars.as_str())?;
            return Ok(Frame::new_fd(cid, &data, flags & 1 != 0, flags & 2 != 0)?);
        }
        if let Some(r) = rest.strip_prefix(['R', 'r']) {
            let dlc = if r.is_empty() {
                0
            } else {
                r.parse::<u8>()
                    .map_err(|_| ParseFrameError::Syntax(s.to_string()))?
            };
            return Ok(Frame::new_remote(cid, dlc)?);
        }
        let data = parse_hex(rest)?;
        Ok(Frame::new(cid, &data)?)
    }
}

fn parse_hex(s: &str) -> Result<Vec<u8>, ParseFrameError> {
    let clean: String = s.chars().filter(|&c| c != '.').collect();
    if clean.len() % 2 != 0 {
        return Err(ParseFrameError::Data(s.to_string()));
    }
    (0..clean.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&clean[i..i + 2], 16))
        .collect::<Result<Vec<u8>, _>>()
        .map_err(|_| ParseFrameError::Data(s.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn id_ranges_are_enforced() {
        assert!(CanId::standard(0x7FF).is_ok());
        assert_eq!(
            CanId::standard(0x800),
            Err(FrameError::StandardIdOutOfRange(0x800))
        );
        assert!(CanId::extended(0x1FFF_FFFF).is_ok());
        assert_eq!(
            CanId::extended(0x2000_0000),
            Err(FrameError::ExtendedIdOutOfRange(0x2000_0000))
        );
    }

    #[test]
    fn classic_length_is_enforced() {
        let id = CanId::Standard(0x123);
        assert!(Frame::new(id, &[0; 8]).is_ok());
        assert_eq!(Frame::new(id, &[0; 9]), Err(FrameError::ClassicTooLong(9)));
        assert_eq!(
            Frame::new_remote(id, 9),
            Err(FrameError::RemoteDlcOutOfRange(9))
        );
    }

    #[test]
    fn fd_lengths_and_dlc() {
        let id = CanId::Standard(0x1);
        for (dlc, &len) in FD_LENGTHS.iter().enumerate() {
            let f = Frame::new_fd(id, &vec![0xAA; len], true, false).unwrap();
            assert_eq!(f.dlc() as usize, dlc);
            assert_eq!(f.data().len(), len);
        }
        assert_eq!(
            Frame::new_fd(id, &[0; 9], false, false),
            Err(FrameError::BadFdLength(9))
        );
        assert_eq!(
            Frame::new_fd(id, &[0; 65], false, false),
            Err(FrameError::BadFdLength(65))
        );
    }

    #[test]
    fn parse_and_format_cansend_syntax() {
        let f: Frame = "123#DEADBEEF".parse().unwrap();
        assert_eq!(f.id(), CanId::Standard(0x123));
        assert_eq!(f.data(), &[0xDE, 0xAD, 0xBE, 0xEF]);
        assert_eq!(f.to_string(), "123#DEADBEEF");

        let f: Frame = "1F334455#11.22".parse().unwrap();
        assert_eq!(f.id(), CanId::Extended(0x1F33_4455));
        assert_eq!(f.data(), &[0x11, 0x22]);
        assert_eq!(f.to_string(), "1F334455#1122");

        let f: Frame = "123#R".parse().unwrap();
        assert!(f.is_remote());
        assert_eq!(f.dlc(), 0);
        let f: Frame = "123#R3".parse().unwrap();
        assert_eq!(f.dlc(), 3);
        assert_eq!(f.to_string(), "123#R3");

        let f: Frame = "123##1AABBCCDDEEFF001122334455".parse().unwrap();
        assert!(f.is_fd() && f.brs() && !f.esi());
        assert_eq!(f.data().len(), 12);
        assert_eq!(f.to_string(), "123##1AABBCCDDEEFF001122334455");

        assert!(matches!(
            "800#00".parse::<Frame>(),
            Err(ParseFrameError::Frame(FrameError::StandardIdOutOfRange(
                0x800
            )))
        ));
        assert!(matches!(
            "12#00".parse::<Frame>(),
            Err(ParseFrameError::Id(_))
        ));
        assert!(matches!(
            "123#0".parse::<Frame>(),
            Err(ParseFrameError::Data(_))
        ));
        assert!(matches!(
            "123#001122334455667788".parse::<Frame>(),
            Err(ParseFrameError::Frame(FrameError::ClassicTooLong(9)))
        ));
    }

    #[test]
    fn arbitration_order_standard_before_extended_with_same_base() {
        let std = CanId::Standard(0x100).arbitration_key();
        let ext_same_base = CanId::Extended(0x100 << 18).arbitration_key();
        let lower_std = CanId::Standard(0x0FF).arbitration_key();
        assert!(lower_std < std);
        assert!(std < ext_same_base);
        assert!(CanId::Extended(0x3FFFF).arbitration_key() < CanId::Standard(1).arbitration_key());
    }
}
