//! EDS/DCF files (CiA 306): the INI text that describes a device's object
//! dictionary, parsed into an [`Eds`].
//!
//! The format: `[Section]` headers, `Key=Value` lines and `;` comment lines;
//! section and key names are case-insensitive, lines may end in CRLF.
//! Numbers are decimal, `0x` hex or leading-`0` octal. Objects live in
//! sections named by their hex index (`[1017]`), sub-objects in
//! `[1018sub1]`; an ARRAY may instead give `CompactSubObj=n` (with optional
//! `[6000Name]`/`[6000Value]` sections). A DCF adds `ParameterValue` keys,
//! which take precedence over `DefaultValue`, and a `[DeviceComissioning]`
//! section.
//!
//! Every error names the line it is about.
//!
//! ```
//! use cangate_canopen::{eds::{Eds, SIM_DRIVE_EDS}, NodeId, ObjectAddress};
//! use cangate_canopen::value::Value;
//!
//! let eds = Eds::parse(SIM_DRIVE_EDS).unwrap();
//! let hb = eds.od.find("Producer heartbeat time").unwrap();
//! assert_eq!(hb.address, ObjectAddress::new(0x1017, 0));
//! let tpdo1 = eds.od.get(ObjectAddress::new(0x1800, 1)).unwrap();
//! assert_eq!(tpdo1.default_for_node(NodeId::new(5).unwrap()), Some(Value::Unsigned32(0x185)));
//! ```

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use crate::ids::{Index, NodeId, ObjectAddress, SubIndex};
use crate::od::{AccessType, DefaultValue, Object, ObjectDictionary, ObjectType, Variable};
use crate::value::{DataType, Value, ValueError};

/// `cangate-drive.eds`: a simulated CiA 402 servo drive.
pub const SIM_DRIVE_EDS: &str = include_str!("../eds/cangate-drive.eds");
/// `cangate-io.eds`: a simulated CiA 401 digital/analogue I/O node.
pub const SIM_IO_EDS: &str = include_str!("../eds/cangate-io.eds");
/// `cangate-handwheel.eds`: a simulated handwheel sending a feed byte.
pub const SIM_HANDWHEEL_EDS: &str = include_str!("../eds/cangate-handwheel.eds");

/// `SIM_DRIVE_EDS` as a CiA 402 drive with `axes` axes (1..=8) on one
/// node: every profile object 0x6000..=0x67FF again for axis n at index +
/// n × 0x800, and PDOs 4n + 1 ..= 4n + 4 (their communication and mapping
/// parameters) for it, the copies' default mappings naming that axis's
/// objects and their COB-IDs invalid until a master sets them (the
/// predefined connection set gives a node PDOs 1..=4 only).
///
/// # Panics
/// When `axes` is 0 or more than 8.
pub fn sim_drive_eds_with_axes(axes: u8) -> String {
    assert!(
        (1..=crate::cia402::MAX_DRIVE_AXES).contains(&axes),
        "a drive has 1..=8 axes"
    );
    // Sections: (header, body lines); the text before the first header
    // (comments) is kept as it is.
    let mut head = String::new();
    let mut sections: Vec<(String, Vec<String>)> = Vec::new();
    for line in SIM_DRIVE_EDS.lines() {
        if line.starts_with('[') {
            sections.push((line.to_string(), Vec::new()));
        } else if let Some((_, body)) = sections.last_mut() {
            body.push(line.to_string());
        } else {
            head.push_str(line);
            head.push('\n');
        }
    }
    // The index a section copied to axis n gets, if it is copied.
    let moved = |index: u16, n: u16| -> Option<u16> {
        let pdo = |first: u16| (first..first + 4).contains(&index).then_some(index + 4 * n);
        if (0x6000..0x6800).contains(&index) {
            Some(index + 0x800 * n)
        } else {
            pdo(0x1400)
                .or_else(|| pdo(0x1600))
                .or_else(|| pdo(0x1800))
                .or_else(|| pdo(0x1A00))
        }
    };
    let section_index = |header: &str| -> Option<(u16, String)> {
        let name = header.trim_start_matches('[').trim_end_matches(']');
        let (hex, rest) = name.split_at(name.len().min(4));
        let index = u16::from_str_radix(hex, 16).ok()?;
        (rest.is_empty() || rest.starts_with("sub")).then(|| (index, rest.to_string()))
    };
    let mut added: Vec<u16> = Vec::new();
    let mut copies: Vec<(String, Vec<String>)> = Vec::new();
    for n in 1..u16::from(axes) {
        for (header, body) in &sections {
            let Some((index, rest)) = section_index(header) else {
                continue;
            };
            let Some(to) = moved(index, n) else { continue };
            if rest.is_empty() {
                added.push(to);
            }
            let mapping = (0x1600..0x1800).contains(&to) || (0x1A00..0x1C00).contains(&to);
            let communication = (0x1400..0x1600).contains(&to) || (0x1800..0x1A00).contains(&to);
            let body = body
                .iter()
                .map(|line| {
                    if let Some(name) = line.strip_prefix("ParameterName=") {
                        return format!("ParameterName={name} (axis {})", n + 1);
                    }
                    let Some(value) = line.strip_prefix("DefaultValue=") else {
                        return line.clone();
                    };
                    if communication && rest == "sub1" {
                        return "DefaultValue=0x80000000".to_string();
                    }
                    match u32::from_str_radix(value.trim_start_matches("0x"), 16) {
                        Ok(entry) if mapping && rest != "sub0" && entry >> 16 != 0 => {
                            let object = (entry >> 16) as u16;
                            format!(
                                "DefaultValue=0x{:04X}{:04X}",
                                crate::cia402::profile_index(object, n as u8),
                                entry & 0xFFFF
                            )
                        }
                        _ => line.clone(),
                    }
                })
                .collect();
            copies.push((format!("[{to:04X}{rest}]"), body));
        }
    }
    let mut out = head;
    for (header, body) in sections.iter().chain(&copies) {
        out.push_str(header);
        out.push('\n');
        if header == "[OptionalObjects]" {
            let mut count = 0;
            for line in body {
                if let Some(("SupportedObjects", v)) = line.split_once('=') {
                    count = v.trim().parse::<usize>().unwrap_or(0);
                }
            }
            for line in body {
                if line.starts_with("SupportedObjects=") {
                    out.push_str(&format!("SupportedObjects={}\n", count + added.len()));
                } else if !line.trim().is_empty() {
                    out.push_str(line);
                    out.push('\n');
                }
            }
            for (i, index) in added.iter().enumerate() {
                out.push_str(&format!("{}=0x{index:04X}\n", count + i + 1));
            }
            out.push('\n');
            continue;
        }
        for line in body {
            let line = match line.split_once('=') {
                Some(("FileName", _)) if header == "[FileInfo]" => {
                    format!("FileName=cangate-drive-{axes}axis.eds")
                }
                Some(("Description", d)) if header == "[FileInfo]" => {
                    format!("Description={d}, {axes} axes")
                }
                _ => line.clone(),
            };
            out.push_str(&line);
            out.push('\n');
        }
    }
    out
}

/// The `[FileInfo]` section: free-text facts about the file itself.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct FileInfo {
    /// `FileName`.
    pub file_name: Option<String>,
    /// `FileVersion`.
    pub file_version: Option<String>,
    /// `FileRevision`.
    pub file_revision: Option<String>,
    /// `EDSVersion` (e.g. `4.0`).
    pub eds_version: Option<String>,
    /// `Description`.
    pub description: Option<String>,
    /// `CreatedBy`.
    pub created_by: Option<String>,
    /// `CreationDate` (mm-dd-yyyy).
    pub creation_date: Option<String>,
    /// `ModifiedBy`.
    pub modified_by: Option<String>,
    /// `ModificationDate` (mm-dd-yyyy).
    pub modification_date: Option<String>,
}

/// The `[DeviceInfo]` section: who made the device and what it supports.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct DeviceInfo {
    /// `VendorName`.
    pub vendor_name: String,
    /// `VendorNumber` (the CiA vendor id, as in 0x1018:01).
    pub vendor_number: Option<u32>,
    /// `ProductName`.
    pub product_name: String,
    /// `ProductNumber` (as in 0x1018:02).
    pub product_number: Option<u32>,
    /// `RevisionNumber` (as in 0x1018:03).
    pub revision_number: Option<u32>,
    /// `OrderCode`.
    pub order_code: String,
    /// Supported bit rates in kbit/s, from the `BaudRate_<kbit/s>=1` keys.
    pub baud_rates: Vec<u32>,
    /// `SimpleBootUpMaster`.
    pub simple_boot_up_master: bool,
    /// `SimpleBootUpSlave`.
    pub simple_boot_up_slave: bool,
    /// `Granularity`: PDO mapping granularity in bits (0 = no mapping, 8 =
    /// byte-wise).
    pub granularity: u8,
    /// `DynamicChannelsSupported`.
    pub dynamic_channels_supported: u8,
    /// `GroupMessaging`.
    pub group_messaging: bool,
    /// `NrOfRXPDO`.
    pub nr_of_rx_pdo: u16,
    /// `NrOfTXPDO`.
    pub nr_of_tx_pdo: u16,
    /// `LSS_Supported`.
    pub lss_supported: bool,
}

/// A DCF's `[DeviceComissioning]` section (CiA 306 spells it with one m;
/// `DeviceCommissioning` is accepted too).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Commissioning {
    /// `NodeID`.
    pub node_id: Option<NodeId>,
    /// `NodeName`.
    pub node_name: Option<String>,
    /// `Baudrate` in kbit/s.
    pub baud_rate: Option<u32>,
    /// `NetNumber`.
    pub net_number: Option<u32>,
    /// `NetworkName`.
    pub network_name: Option<String>,
    /// `CANopenManager`.
    pub canopen_manager: bool,
    /// `LSS_SerialNumber`.
    pub lss_serial_number: Option<u32>,
}

/// A parsed EDS or DCF.
#[derive(Debug, Clone, PartialEq)]
pub struct Eds {
    /// `[FileInfo]`.
    pub file_info: FileInfo,
    /// `[DeviceInfo]`.
    pub device_info: DeviceInfo,
    /// `[DeviceComissioning]`, present in DCFs.
    pub commissioning: Option<Commissioning>,
    /// The objects.
    pub od: ObjectDictionary,
    /// The basic types `[DummyUsage]` marks usable as gaps in a PDO
    /// mapping (`Dummy0005=1`: an UNSIGNED8 gap, mapping entry
    /// 0x00050008). They are data types, not objects: [`Eds::od`] does not
    /// hold them (a device serves them as DEFTYPE entries, see
    /// [`Eds::od_with_dummies`]).
    pub dummy_usage: Vec<DataType>,
}

/// Why an EDS/DCF could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum EdsError {
    /// The text is wrong at a line.
    #[error("line {line}: {kind}")]
    Parse {
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        kind: EdsErrorKind,
    },
    /// The file could not be read.
    #[error("cannot read {}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
}

impl EdsError {
    /// The line a parse error is about.
    pub fn line(&self) -> Option<usize> {
        match self {
            EdsError::Parse { line, .. } => Some(*line),
            EdsError::Io { .. } => None,
        }
    }

    /// What is wrong, for a parse error.
    pub fn kind(&self) -> Option<&EdsErrorKind> {
        match self {
            EdsError::Parse { kind, .. } => Some(kind),
            EdsError::Io { .. } => None,
        }
    }
}

/// What is wrong at a line of an EDS/DCF.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum EdsErrorKind {
    /// A line that is neither a section, a key nor a comment.
    #[error("expected \"[section]\", \"key=value\" or a \";\" comment, found {0:?}")]
    Syntax(String),
    /// A key before the first section.
    #[error("key {0:?} appears before any [section]")]
    KeyOutsideSection(String),
    /// A section given twice.
    #[error("section [{name}] already appeared on line {first}")]
    DuplicateSection {
        /// The section.
        name: String,
        /// Where it first appeared.
        first: usize,
    },
    /// A key given twice in a section.
    #[error("key {key} already appeared in [{section}] on line {first}")]
    DuplicateKey {
        /// The section.
        section: String,
        /// The key.
        key: String,
        /// Where it first appeared.
        first: usize,
    },
    /// A required key is absent (the line is the section header's).
    #[error("[{section}] has no {key} key")]
    MissingKey {
        /// The section.
        section: String,
        /// The key.
        key: &'static str,
    },
    /// A value that does not make sense for its key.
    #[error("{key}={text:?}: {reason}")]
    BadValue {
        /// The key.
        key: String,
        /// Its value.
        text: String,
        /// What is wrong.
        reason: String,
    },
    /// A value that is not valid for the object's data type.
    #[error("{key}={text:?}: {source}")]
    Value {
        /// The key.
        key: String,
        /// Its value.
        text: String,
        /// What is wrong.
        #[source]
        source: ValueError,
    },
    /// A `DataType` that is not a supported basic type.
    #[error("DataType {0:#06X} is not a supported basic type")]
    UnsupportedDataType(u16),
    /// An object list names an index that has no section.
    #[error("object {0:#06X} is listed but has no [{0:04X}] section")]
    MissingObject(Index),
    /// A sub-object section whose object has no section.
    #[error("[{0}] has no object section for its index")]
    OrphanSub(String),
    /// A sub-object section for an object that takes none.
    #[error("{object_type} object {index:#06X} cannot have sub-object sections")]
    UnexpectedSub {
        /// The object's index.
        index: Index,
        /// Its object type.
        object_type: ObjectType,
    },
    /// `SubNumber` disagrees with the sub-object sections.
    #[error("SubNumber={declared} but {found} sub-object sections are given for {index:#06X}")]
    SubNumberMismatch {
        /// The object's index.
        index: Index,
        /// `SubNumber`.
        declared: u64,
        /// Sub-object sections found.
        found: usize,
    },
}

fn error(line: usize, kind: EdsErrorKind) -> EdsError {
    EdsError::Parse { line, kind }
}

/// At most 80 characters of a text from the file, for an error message:
/// a line of a megabyte must not become a megabyte of log.
fn excerpt(text: &str) -> String {
    const MAX: usize = 80;
    match text.char_indices().nth(MAX) {
        Some((cut, _)) => format!("{}…", &text[..cut]),
        None => text.to_owned(),
    }
}

/// One `key=value` line.
struct Entry<'a> {
    key: &'a str,
    value: &'a str,
    line: usize,
}

impl Entry<'_> {
    fn bad(&self, reason: impl Into<String>) -> EdsError {
        let (key, text, reason) = (excerpt(self.key), excerpt(self.value), reason.into());
        error(self.line, EdsErrorKind::BadValue { key, text, reason })
    }

    fn value_error(&self, source: ValueError) -> EdsError {
        let (key, text) = (excerpt(self.key), excerpt(self.value));
        let source = match source {
            ValueError::Invalid { ty, text, reason } => ValueError::Invalid {
                ty,
                text: excerpt(&text),
                reason,
            },
            other => other,
        };
        error(self.line, EdsErrorKind::Value { key, text, source })
    }

    /// The value as a CiA 306 number that fits `T`.
    fn number<T: TryFrom<u64>>(&self) -> Result<T, EdsError> {
        let v =
            Value::parse_eds(DataType::Unsigned64, self.value).map_err(|e| self.value_error(e))?;
        v.as_i128()
            .and_then(|v| T::try_from(u64::try_from(v).ok()?).ok())
            .ok_or_else(|| self.bad(format!("out of range (at most {})", max_of::<T>())))
    }
}

/// The largest `u64` that fits `T`, for error messages.
fn max_of<T: TryFrom<u64>>() -> u64 {
    (0..64)
        .map(|bits| u64::MAX >> bits)
        .find(|&m| T::try_from(m).is_ok())
        .unwrap_or(0)
}

/// One `[section]` with its entries.
struct Section<'a> {
    name: &'a str,
    line: usize,
    entries: Vec<Entry<'a>>,
}

impl<'a> Section<'a> {
    fn get(&self, key: &str) -> Option<&Entry<'a>> {
        self.entries
            .iter()
            .find(|e| e.key.eq_ignore_ascii_case(key))
    }

    fn text(&self, key: &str) -> Option<String> {
        self.get(key).map(|e| e.value.to_owned())
    }

    fn missing(&self, key: &'static str) -> EdsError {
        error(
            self.line,
            EdsErrorKind::MissingKey {
                section: self.name.to_owned(),
                key,
            },
        )
    }

    fn require(&self, key: &'static str) -> Result<&Entry<'a>, EdsError> {
        self.get(key).ok_or_else(|| self.missing(key))
    }

    /// An informative value of `[DeviceInfo]` or `[DeviceComissioning]`,
    /// given with a value: an empty one (`VendorNumber=`, as CANopenNode's
    /// reference EDS has) says nothing, like an absent one.
    fn given(&self, key: &str) -> Option<&Entry<'a>> {
        self.get(key).filter(|e| !e.value.trim().is_empty())
    }

    fn number<T: TryFrom<u64>>(&self, key: &str) -> Result<Option<T>, EdsError> {
        self.given(key).map(Entry::number).transpose()
    }

    /// A `0`/`1` flag; absent or empty means false.
    fn flag(&self, key: &str) -> Result<bool, EdsError> {
        match self.given(key) {
            None => Ok(false),
            Some(e) => match e.number::<u64>()? {
                0 => Ok(false),
                1 => Ok(true),
                _ => Err(e.bad("expected 0 or 1")),
            },
        }
    }
}

/// Splits the text into sections, checking the INI syntax.
fn lex(text: &str) -> Result<Vec<Section<'_>>, EdsError> {
    let mut sections: Vec<Section> = Vec::new();
    for (i, raw) in text.split('\n').enumerate() {
        let line = i + 1;
        let trimmed = raw.trim_start_matches('\u{feff}').trim();
        if trimmed.is_empty() || trimmed.starts_with(';') {
            continue;
        }
        if let Some(inner) = trimmed.strip_prefix('[') {
            let name = inner
                .strip_suffix(']')
                .map(str::trim)
                .filter(|n| !n.is_empty() && !n.contains(['[', ']']));
            let name = name.ok_or_else(|| error(line, EdsErrorKind::Syntax(excerpt(trimmed))))?;
            if let Some(first) = sections.iter().find(|s| s.name.eq_ignore_ascii_case(name)) {
                let kind = EdsErrorKind::DuplicateSection {
                    name: excerpt(name),
                    first: first.line,
                };
                return Err(error(line, kind));
            }
            sections.push(Section {
                name,
                line,
                entries: Vec::new(),
            });
        } else if let Some((key, value)) = trimmed
            .split_once('=')
            .filter(|(k, _)| !k.trim().is_empty())
        {
            let (key, value) = (key.trim(), value.trim());
            let section = sections
                .last_mut()
                .ok_or_else(|| error(line, EdsErrorKind::KeyOutsideSection(excerpt(key))))?;
            if let Some(first) = section.get(key) {
                let kind = EdsErrorKind::DuplicateKey {
                    section: excerpt(section.name),
                    key: excerpt(key),
                    first: first.line,
                };
                return Err(error(line, kind));
            }
            section.entries.push(Entry { key, value, line });
        } else {
            return Err(error(line, EdsErrorKind::Syntax(excerpt(trimmed))));
        }
    }
    Ok(sections)
}

/// What a section name denotes.
enum SectionKind {
    Object(Index),
    Sub(Index, SubIndex),
    Names(Index),
    Values(Index),
    Other,
}

fn classify(name: &str) -> SectionKind {
    let Some(index) = name
        .get(..4)
        .filter(|h| h.chars().all(|c| c.is_ascii_hexdigit()))
    else {
        return SectionKind::Other;
    };
    let Ok(index) = Index::from_str_radix(index, 16) else {
        return SectionKind::Other;
    };
    let rest = name[4..].to_ascii_lowercase();
    match rest.as_str() {
        "" => SectionKind::Object(index),
        "name" => SectionKind::Names(index),
        "value" => SectionKind::Values(index),
        _ => match rest
            .strip_prefix("sub")
            .filter(|s| (1..=2).contains(&s.len()))
        {
            Some(sub) => SubIndex::from_str_radix(sub, 16)
                .map_or(SectionKind::Other, |sub| SectionKind::Sub(index, sub)),
            None => SectionKind::Other,
        },
    }
}

/// Parses an optional typed value key (`DefaultValue`, `LowLimit`, …). An
/// empty value means "none", except for strings, where it is "".
fn typed<T>(
    section: &Section,
    key: &str,
    ty: DataType,
    parse: impl Fn(DataType, &str) -> Result<T, ValueError>,
) -> Result<Option<T>, EdsError> {
    let Some(entry) = section.get(key) else {
        return Ok(None);
    };
    let string_type = matches!(
        ty,
        DataType::VisibleString | DataType::UnicodeString | DataType::OctetString
    );
    if entry.value.is_empty() && !string_type {
        return Ok(None);
    }
    parse(ty, entry.value)
        .map(Some)
        .map_err(|e| entry.value_error(e))
}

/// Builds the variable described by an object or sub-object section.
fn variable(section: &Section, address: ObjectAddress, domain: bool) -> Result<Variable, EdsError> {
    let name = section.require("ParameterName")?.value.to_owned();
    let data_type = match section.get("DataType") {
        Some(e) => {
            let code: u16 = e.number()?;
            DataType::from_code(code)
                .ok_or_else(|| error(e.line, EdsErrorKind::UnsupportedDataType(code)))?
        }
        None if domain => DataType::Domain,
        None => return Err(section.missing("DataType")),
    };
    let access = match section.get("AccessType") {
        Some(e) => AccessType::from_str(e.value).map_err(|err| e.bad(err.to_string()))?,
        None if domain => AccessType::Rw,
        None => return Err(section.missing("AccessType")),
    };
    Ok(Variable {
        address,
        name,
        data_type,
        access,
        pdo_mappable: section.flag("PDOMapping")?,
        low_limit: typed(section, "LowLimit", data_type, Value::parse_eds)?,
        high_limit: typed(section, "HighLimit", data_type, Value::parse_eds)?,
        default: typed(section, "DefaultValue", data_type, DefaultValue::parse)?,
        parameter_value: typed(section, "ParameterValue", data_type, DefaultValue::parse)?,
    })
}

fn object_type(section: &Section) -> Result<ObjectType, EdsError> {
    match section.get("ObjectType") {
        None => Ok(ObjectType::Var), // CiA 306: a missing ObjectType means VAR
        Some(e) => ObjectType::from_code(e.number()?)
            .ok_or_else(|| e.bad("not an object code (0x0, 0x2, 0x5 to 0x9)")),
    }
}

/// The sub-index named by a `[xxxxName]`/`[xxxxValue]` key, 1..=count.
fn compact_key(entry: &Entry, count: u8) -> Result<SubIndex, EdsError> {
    let sub = Value::parse_eds(DataType::Unsigned8, entry.key)
        .ok()
        .and_then(|v| v.as_u32());
    sub.and_then(|s| SubIndex::try_from(s).ok())
        .filter(|s| (1..=count).contains(s))
        .ok_or_else(|| entry.bad(format!("key must be a sub-index from 1 to {count}")))
}

/// Expands `CompactSubObj=n`: sub 0 holds n, subs 1..=n share the object
/// section's type, access and default, named from `[xxxxName]` or
/// `"<ParameterName> <sub>"`, configured from `[xxxxValue]`.
fn compact_array(
    object: &mut Object,
    section: &Section,
    count_entry: &Entry,
    names: Option<&Section>,
    values: Option<&Section>,
) -> Result<(), EdsError> {
    let count: u8 = count_entry.number()?;
    if count == 0 || count == 255 {
        return Err(count_entry.bad("expected 1 to 254 sub-objects"));
    }
    let mut sub0 = Variable::new(
        ObjectAddress::new(object.index, 0),
        "Number of entries",
        DataType::Unsigned8,
        AccessType::Ro,
    );
    sub0.default = Some(DefaultValue::fixed(Value::Unsigned8(count)));
    object.subs.insert(0, sub0);
    let template = variable(section, ObjectAddress::new(object.index, 1), false)?;
    for sub in 1..=count {
        let mut v = template.clone();
        v.address.sub = sub;
        v.name = format!("{} {sub}", object.name);
        object.subs.insert(sub, v);
    }
    for e in names
        .iter()
        .flat_map(|s| &s.entries)
        .filter(|e| !e.key.eq_ignore_ascii_case("NrOfEntries"))
    {
        if let Some(v) = object.subs.get_mut(&compact_key(e, count)?) {
            v.name = e.value.to_owned();
        }
    }
    for e in values
        .iter()
        .flat_map(|s| &s.entries)
        .filter(|e| !e.key.eq_ignore_ascii_case("NrOfEntries"))
    {
        if let Some(v) = object.subs.get_mut(&compact_key(e, count)?) {
            v.parameter_value =
                Some(DefaultValue::parse(v.data_type, e.value).map_err(|err| e.value_error(err))?);
        }
    }
    Ok(())
}

/// Builds one object from its section and its sub-object sections.
fn object(
    index: Index,
    section: &Section,
    subs: Vec<(SubIndex, &Section)>,
    names: Option<&Section>,
    values: Option<&Section>,
) -> Result<Object, EdsError> {
    let name = section.require("ParameterName")?.value;
    let object_type = object_type(section)?;
    let mut object = Object::new(index, name, object_type);
    if !object_type.is_compound() {
        if let Some((_, sub)) = subs.first() {
            return Err(error(
                sub.line,
                EdsErrorKind::UnexpectedSub { index, object_type },
            ));
        }
        if object_type != ObjectType::Null {
            let domain = object_type == ObjectType::Domain;
            object
                .subs
                .insert(0, variable(section, ObjectAddress::new(index, 0), domain)?);
        }
        return Ok(object);
    }
    if let (ObjectType::Array, Some(count)) = (object_type, section.get("CompactSubObj")) {
        if let Some((_, sub)) = subs.first() {
            return Err(error(
                sub.line,
                EdsErrorKind::UnexpectedSub { index, object_type },
            ));
        }
        compact_array(&mut object, section, count, names, values)?;
        return Ok(object);
    }
    for (sub, s) in &subs {
        let domain = object_type_of_sub(s)? == ObjectType::Domain;
        if object
            .subs
            .insert(*sub, variable(s, ObjectAddress::new(index, *sub), domain)?)
            .is_some()
        {
            let first = subs
                .iter()
                .find(|(n, _)| n == sub)
                .map_or(0, |(_, f)| f.line);
            return Err(error(
                s.line,
                EdsErrorKind::DuplicateSection {
                    name: s.name.to_owned(),
                    first,
                },
            ));
        }
    }
    if let Some(e) = section.get("SubNumber") {
        let declared: u64 = e.number()?;
        if declared != subs.len() as u64 {
            return Err(error(
                e.line,
                EdsErrorKind::SubNumberMismatch {
                    index,
                    declared,
                    found: subs.len(),
                },
            ));
        }
    }
    Ok(object)
}

/// A sub-object section may only describe a VAR (or DOMAIN).
fn object_type_of_sub(section: &Section) -> Result<ObjectType, EdsError> {
    let t = object_type(section)?;
    match (t, section.get("ObjectType")) {
        (ObjectType::Var | ObjectType::Domain, _) | (_, None) => Ok(t),
        (_, Some(e)) => Err(e.bad("a sub-object must be a VAR (0x7) or DOMAIN (0x2)")),
    }
}

/// Checks `[MandatoryObjects]`-style lists; returns (index, line) pairs.
fn object_list(section: &Section) -> Result<Vec<(Index, usize)>, EdsError> {
    let count_entry = section.require("SupportedObjects")?;
    let count: u16 = count_entry.number()?;
    let mut listed = Vec::new();
    for e in section
        .entries
        .iter()
        .filter(|e| !e.key.eq_ignore_ascii_case("SupportedObjects"))
    {
        let n = Value::parse_eds(DataType::Unsigned16, e.key)
            .ok()
            .and_then(|v| v.as_u32());
        if !n.is_some_and(|n| (1..=u32::from(count)).contains(&n)) {
            return Err(e.bad(format!(
                "key must be a position from 1 to SupportedObjects={count}"
            )));
        }
        listed.push((e.number()?, e.line));
    }
    if listed.len() != usize::from(count) {
        return Err(count_entry.bad(format!("{} objects are listed", listed.len())));
    }
    Ok(listed)
}

impl Eds {
    /// Parses EDS or DCF text.
    ///
    /// Object sections are read whether or not the object lists name them;
    /// every listed object must have a section. `[DummyUsage]` entries set
    /// to 1 go to [`Eds::dummy_usage`]. Empty informative values (`[DeviceInfo]`
    /// `VendorNumber=`) are taken as absent.
    pub fn parse(text: &str) -> Result<Eds, EdsError> {
        let sections = lex(text)?;
        let find = |name: &str| sections.iter().find(|s| s.name.eq_ignore_ascii_case(name));

        let file_info = match find("FileInfo") {
            Some(s) => FileInfo {
                file_name: s.text("FileName"),
                file_version: s.text("FileVersion"),
                file_revision: s.text("FileRevision"),
                eds_version: s.text("EDSVersion"),
                description: s.text("Description"),
                created_by: s.text("CreatedBy"),
                creation_date: s.text("CreationDate"),
                modified_by: s.text("ModifiedBy"),
                modification_date: s.text("ModificationDate"),
            },
            None => FileInfo::default(),
        };

        let device_info = match find("DeviceInfo") {
            Some(s) => {
                let mut baud_rates = Vec::new();
                for rate in [10, 20, 50, 125, 250, 500, 800, 1000] {
                    if s.flag(&format!("BaudRate_{rate}"))? {
                        baud_rates.push(rate);
                    }
                }
                DeviceInfo {
                    vendor_name: s.text("VendorName").unwrap_or_default(),
                    vendor_number: s.number("VendorNumber")?,
                    product_name: s.text("ProductName").unwrap_or_default(),
                    product_number: s.number("ProductNumber")?,
                    revision_number: s.number("RevisionNumber")?,
                    order_code: s.text("OrderCode").unwrap_or_default(),
                    baud_rates,
                    simple_boot_up_master: s.flag("SimpleBootUpMaster")?,
                    simple_boot_up_slave: s.flag("SimpleBootUpSlave")?,
                    granularity: s.number("Granularity")?.unwrap_or(0),
                    dynamic_channels_supported: s.number("DynamicChannelsSupported")?.unwrap_or(0),
                    group_messaging: s.flag("GroupMessaging")?,
                    nr_of_rx_pdo: s.number("NrOfRXPDO")?.unwrap_or(0),
                    nr_of_tx_pdo: s.number("NrOfTXPDO")?.unwrap_or(0),
                    lss_supported: s.flag("LSS_Supported")?,
                }
            }
            None => DeviceInfo::default(),
        };

        let commissioning = match find("DeviceComissioning").or_else(|| find("DeviceCommissioning"))
        {
            Some(s) => Some(Commissioning {
                node_id: match s.given("NodeID") {
                    Some(e) => {
                        Some(NodeId::new(e.number()?).map_err(|err| e.bad(err.to_string()))?)
                    }
                    None => None,
                },
                node_name: s.text("NodeName"),
                baud_rate: s.number("Baudrate")?,
                net_number: s.number("NetNumber")?,
                network_name: s.text("NetworkName"),
                canopen_manager: s.flag("CANopenManager")?,
                lss_serial_number: s.number("LSS_SerialNumber")?,
            }),
            None => None,
        };

        // Group the object sections.
        let mut objects = Vec::new();
        let mut subs: BTreeMap<Index, Vec<(SubIndex, &Section)>> = BTreeMap::new();
        let (mut names, mut values) = (BTreeMap::new(), BTreeMap::new());
        for s in &sections {
            match classify(s.name) {
                SectionKind::Object(index) => objects.push((index, s)),
                SectionKind::Sub(index, sub) => subs.entry(index).or_default().push((sub, s)),
                SectionKind::Names(index) => {
                    names.insert(index, s);
                }
                SectionKind::Values(index) => {
                    values.insert(index, s);
                }
                SectionKind::Other => {}
            }
        }
        let mut od = ObjectDictionary::new();
        for (index, s) in objects {
            let own_subs = subs.remove(&index).unwrap_or_default();
            od.insert(object(
                index,
                s,
                own_subs,
                names.get(&index).copied(),
                values.get(&index).copied(),
            )?);
        }
        if let Some((_, s)) = subs.values().flatten().min_by_key(|(_, s)| s.line) {
            return Err(error(s.line, EdsErrorKind::OrphanSub(s.name.to_owned())));
        }

        for list in ["MandatoryObjects", "OptionalObjects", "ManufacturerObjects"] {
            for (index, line) in find(list).map(object_list).transpose()?.unwrap_or_default() {
                if od.object(index).is_none() {
                    return Err(error(line, EdsErrorKind::MissingObject(index)));
                }
            }
        }

        let mut dummy_usage = Vec::new();
        if let Some(s) = find("DummyUsage") {
            for e in &s.entries {
                let ty = e
                    .key
                    .get(5..)
                    .and_then(|hex| u16::from_str_radix(hex, 16).ok())
                    .and_then(DataType::from_code);
                match ty {
                    Some(ty) if e.key.len() == 9 && e.key[..5].eq_ignore_ascii_case("Dummy") => {
                        if s.flag(e.key)? && !dummy_usage.contains(&ty) {
                            dummy_usage.push(ty);
                        }
                    }
                    _ => return Err(e.bad("expected Dummy0001 to Dummy001B for a basic type")),
                }
            }
        }

        Ok(Eds {
            file_info,
            device_info,
            commissioning,
            od,
            dummy_usage,
        })
    }

    /// Reads and parses an EDS/DCF file (UTF-8, or Latin-1 as older tools
    /// write).
    pub fn from_path(path: impl AsRef<Path>) -> Result<Eds, EdsError> {
        Eds::parse(&Eds::read_text(path)?)
    }

    /// The text of an EDS/DCF file, as [`Eds::from_path`] reads it (bytes
    /// that are not UTF-8 taken as Latin-1).
    pub fn read_text(path: impl AsRef<Path>) -> Result<String, EdsError> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|source| EdsError::Io {
            path: path.to_owned(),
            source,
        })?;
        Ok(String::from_utf8(bytes)
            .unwrap_or_else(|e| e.into_bytes().iter().map(|&b| char::from(b)).collect()))
    }

    /// The dictionary as a device serves it: [`Eds::od`] plus a DEFTYPE
    /// entry for each type of [`Eds::dummy_usage`], so that its PDO
    /// mappings may use them as gaps (what a device simulated from the EDS
    /// needs).
    pub fn od_with_dummies(&self) -> ObjectDictionary {
        let mut od = self.od.clone();
        for &ty in &self.dummy_usage {
            if od.object(ty.code()).is_some() {
                continue;
            }
            let mut v = Variable::new(
                ObjectAddress::new(ty.code(), 0),
                ty.name(),
                ty,
                AccessType::Rw,
            );
            v.pdo_mappable = true;
            let mut o = Object::var(v);
            o.object_type = ObjectType::DefType;
            od.insert(o);
        }
        od
    }

    /// The node id configured by a DCF's `[DeviceComissioning]`.
    pub fn node_id(&self) -> Option<NodeId> {
        self.commissioning.as_ref()?.node_id
    }
}

impl FromStr for Eds {
    type Err = EdsError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Eds::parse(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(n: u32) -> NodeId {
        NodeId::new(n).unwrap()
    }

    fn at(index: Index, sub: SubIndex) -> ObjectAddress {
        ObjectAddress::new(index, sub)
    }

    /// The error a text fails with: (line, message).
    fn fails(text: &str) -> (usize, String) {
        let err = Eds::parse(text).unwrap_err();
        (err.line().unwrap(), err.kind().unwrap().to_string())
    }

    #[test]
    fn the_two_axis_drive_has_each_profile_object_and_four_pdos_again_0x800_on() {
        let eds = Eds::parse(&sim_drive_eds_with_axes(2)).unwrap();
        let od = &eds.od;
        for index in [0x6840, 0x6841, 0x687A, 0x68FF, 0x6D02, 0x6860, 0x68B8] {
            assert!(od.get(at(index, 0)).is_some(), "{index:04X}");
        }
        assert!(od.get(at(0x687D, 2)).is_some());
        assert!(od.get(at(0x7041, 0)).is_none(), "two axes only");
        // PDOs 5.. of the second axis: invalid COB-IDs, mappings of its
        // objects.
        let default = |a| {
            od.get(a)
                .and_then(|v| v.default_for_node(node(3)))
                .and_then(|v| v.as_u32())
        };
        assert_eq!(default(at(0x1804, 1)), Some(0x8000_0000));
        assert_eq!(default(at(0x1404, 1)), Some(0x8000_0000));
        assert_eq!(default(at(0x1A04, 1)), Some(0x6841_0010));
        assert_eq!(default(at(0x1A00, 1)), Some(0x6041_0010));
        assert!(od.get(at(0x1A07, 0)).is_some());
        assert!(od.get(at(0x1406, 0)).is_some());
        // One axis: the bundled drive as it is.
        let one = Eds::parse(&sim_drive_eds_with_axes(1)).unwrap();
        assert!(one.od.get(at(0x6841, 0)).is_none());
        assert!(one.od.get(at(0x6041, 0)).is_some());
    }

    const MINIMAL: &str =
        "[1000]\nParameterName=Device type\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x191\n";

    /// A megabyte line is named by its first 80 characters, not echoed.
    #[test]
    fn errors_quote_at_most_80_characters_of_a_line() {
        let long = "x".repeat(1_400_000);
        let (_, msg) = fails(&format!("[1000]\n{long}\n"));
        assert!(
            msg.len() < 300 && msg.contains(&format!("{}…", &long[..80])),
            "{}",
            msg.chars().take(300).collect::<String>()
        );
        let (_, msg) = fails(&format!("{long}=1\n{MINIMAL}"));
        assert!(
            msg.len() < 300,
            "{}",
            msg.chars().take(300).collect::<String>()
        );
        let text = MINIMAL.replace("DefaultValue=0x191", &format!("DefaultValue=0x{long}"));
        let (_, msg) = fails(&text);
        assert!(
            msg.len() < 400,
            "{}",
            msg.chars().take(400).collect::<String>()
        );
    }

    #[test]
    fn drive_eds() {
        let eds = Eds::parse(SIM_DRIVE_EDS).unwrap();
        let info = &eds.device_info;
        assert_eq!(info.vendor_number, Some(0x4D2));
        assert_eq!(info.product_name, "cangate sim drive");
        assert_eq!(info.baud_rates, [125, 250, 500, 1000]);
        assert_eq!(
            (info.nr_of_rx_pdo, info.nr_of_tx_pdo, info.granularity),
            (2, 2, 8)
        );
        assert!(info.simple_boot_up_slave && !info.lss_supported);
        assert_eq!(
            eds.file_info.file_name.as_deref(),
            Some("cangate-drive.eds")
        );
        assert_eq!(eds.commissioning, None);

        let od = &eds.od;
        let n5 = node(5);
        let default = |a| od.get(a).unwrap().default_for_node(n5).unwrap();
        assert_eq!(default(at(0x1000, 0)), Value::Unsigned32(0x0002_0192));
        assert_eq!(
            default(at(0x1008, 0)),
            Value::VisibleString("cangate sim drive".into())
        );
        assert_eq!(od.get(at(0x1008, 0)).unwrap().access, AccessType::Const);
        assert_eq!(default(at(0x1014, 0)), Value::Unsigned32(0x85));
        assert_eq!(default(at(0x1017, 0)), Value::Unsigned16(1000));
        let identity = od.object(0x1018).unwrap();
        assert_eq!(identity.object_type, ObjectType::Record);
        assert_eq!(identity.subs.len(), 5);
        assert_eq!(
            od.find("identity object.vendor-id").unwrap().address,
            at(0x1018, 1)
        );
        assert_eq!(default(at(0x1018, 1)), Value::Unsigned32(0x4D2));
        assert_eq!(default(at(0x1200, 1)), Value::Unsigned32(0x605));
        assert_eq!(default(at(0x1200, 2)), Value::Unsigned32(0x585));
        assert_eq!(default(at(0x1400, 1)), Value::Unsigned32(0x205));
        assert_eq!(default(at(0x1401, 1)), Value::Unsigned32(0x305));
        assert_eq!(default(at(0x1800, 1)), Value::Unsigned32(0x185));
        assert_eq!(default(at(0x1801, 1)), Value::Unsigned32(0x285));
        assert!(od.get(at(0x1800, 4)).is_none()); // reserved sub-index left out
        assert_eq!(default(at(0x1800, 5)), Value::Unsigned16(100));

        // Default PDO mappings point at mappable objects of the right size.
        let mapping = |index: Index| -> Vec<u32> {
            let n = default(at(index, 0)).as_u32().unwrap() as u8;
            (1..=n)
                .map(|s| default(at(index, s)).as_u32().unwrap())
                .collect()
        };
        assert_eq!(mapping(0x1600), [0x6040_0010, 0x607A_0020]);
        assert_eq!(mapping(0x1601), [0x6040_0010, 0x60FF_0020]);
        assert_eq!(mapping(0x1A00), [0x6041_0010, 0x6064_0020]);
        assert_eq!(mapping(0x1A01), [0x606C_0020, 0x6077_0010]);
        for index in [0x1600, 0x1601, 0x1A00, 0x1A01] {
            for entry in mapping(index) {
                let target = at((entry >> 16) as u16, (entry >> 8) as u8);
                assert_eq!(
                    od.get(target).unwrap().pdo_mapping_entry(),
                    Some(entry),
                    "{target}"
                );
            }
        }

        let cw = od.find("controlword").unwrap();
        assert_eq!(
            (cw.address, cw.data_type, cw.access, cw.pdo_mappable),
            (at(0x6040, 0), DataType::Unsigned16, AccessType::Rww, true)
        );
        let sw = od.get(at(0x6041, 0)).unwrap();
        assert_eq!((sw.access, sw.pdo_mappable), (AccessType::Ro, true));
        assert_eq!(od.get(at(0x6060, 0)).unwrap().data_type, DataType::Integer8);
        assert_eq!(
            od.get(at(0x6077, 0)).unwrap().data_type,
            DataType::Integer16
        );
        assert_eq!(od.object(0x607D).unwrap().object_type, ObjectType::Array);
        assert_eq!(default(at(0x607D, 1)), Value::Integer32(i32::MIN)); // written 0x80000000
        assert_eq!(default(at(0x607D, 2)), Value::Integer32(i32::MAX));
        assert_eq!(od.object(0x6099).unwrap().subs.len(), 3);
        assert_eq!(default(at(0x6502, 0)), Value::Unsigned32(0x3ED));
        let velocity = od.get(at(0x6081, 0)).unwrap();
        assert!(velocity.check(&Value::Unsigned32(2_000_000)).is_err());
        assert!(velocity.check(&Value::Unsigned32(5_000)).is_ok());

        let fw = od.find("firmware image").unwrap();
        assert_eq!(
            (fw.address, fw.data_type, fw.access),
            (at(0x2100, 0), DataType::Domain, AccessType::Rw)
        );
        assert_eq!(od.object(0x2100).unwrap().object_type, ObjectType::Domain);
        assert_eq!(fw.default, None);
        // [DummyUsage] lists the types usable as PDO gaps; they are no
        // objects of the dictionary.
        assert!(eds.dummy_usage.contains(&DataType::Unsigned8));
        assert!(od.object(0x0005).is_none());
        assert_eq!(
            eds.od_with_dummies().get(at(0x0005, 0)).unwrap().name,
            "UNSIGNED8"
        );
    }

    #[test]
    fn io_eds() {
        let eds = Eds::parse(SIM_IO_EDS).unwrap();
        let od = &eds.od;
        let default = |a| od.get(a).unwrap().default_for_node(node(0x22)).unwrap();
        assert_eq!(default(at(0x1000, 0)), Value::Unsigned32(0x000F_0191));
        // 0x6000 uses CompactSubObj with a [6000Name] section.
        let inputs = od.object(0x6000).unwrap();
        assert_eq!(
            (inputs.object_type, inputs.subs.len()),
            (ObjectType::Array, 3)
        );
        assert_eq!(default(at(0x6000, 0)), Value::Unsigned8(2));
        let di = od.get(at(0x6000, 2)).unwrap();
        assert_eq!(
            (di.name.as_str(), di.data_type, di.access, di.pdo_mappable),
            (
                "Read input 9h-10h",
                DataType::Unsigned8,
                AccessType::Ro,
                true
            )
        );
        let outputs = od.object(0x6200).unwrap();
        assert_eq!(outputs.sub(1).unwrap().access, AccessType::Rww);
        // 0x6401 is compact without names: generated ones.
        assert_eq!(
            od.get(at(0x6401, 2)).unwrap().name,
            "Read analogue input 16-bit 2"
        );
        assert_eq!(
            od.get(at(0x6401, 2)).unwrap().data_type,
            DataType::Integer16
        );
        assert_eq!(default(at(0x6423, 0)), Value::Boolean(false));
        assert_eq!(default(at(0x1800, 1)), Value::Unsigned32(0x1A2));
        assert_eq!(default(at(0x1400, 1)), Value::Unsigned32(0x222));
        assert_eq!(default(at(0x1A00, 0)), Value::Unsigned8(4));
        assert_eq!(default(at(0x1A00, 3)), Value::Unsigned32(0x6401_0110));
        assert_eq!(default(at(0x1600, 2)), Value::Unsigned32(0x6200_0208));
    }

    #[test]
    fn handwheel_eds() {
        let eds = Eds::parse(SIM_HANDWHEEL_EDS).unwrap();
        let od = &eds.od;
        assert_eq!(
            od.get(at(0x1000, 0)).unwrap().default_for_node(node(1)),
            Some(Value::Unsigned32(0))
        );
        let mode = od.find("mode").unwrap();
        assert_eq!(
            (mode.address, mode.data_type, mode.access),
            (at(0x2000, 0), DataType::Unsigned8, AccessType::Rw)
        );
        let feed = od.find("feed").unwrap();
        assert_eq!(feed.pdo_mapping_entry(), Some(0x2001_0008));
        assert_eq!(
            od.get(at(0x1A00, 0)).unwrap().default_for_node(node(1)),
            Some(Value::Unsigned8(1))
        );
        assert_eq!(
            od.get(at(0x1A00, 1)).unwrap().default_for_node(node(1)),
            Some(Value::Unsigned32(0x2001_0008))
        );
        assert_eq!(
            od.get(at(0x1800, 1)).unwrap().default_for_node(node(9)),
            Some(Value::Unsigned32(0x189))
        );
    }

    #[test]
    fn dcf_parameter_value_and_commissioning() {
        let dcf = "[DeviceComissioning]\nNodeID=0x0A\nNodeName=axis1\nBaudrate=500\n\
                   [1017]\nParameterName=Producer heartbeat time\nDataType=0x0006\nAccessType=rw\n\
                   DefaultValue=0\nParameterValue=250\n\
                   [1014]\nParameterName=COB-ID EMCY\nDataType=0x0007\nAccessType=rw\n\
                   DefaultValue=$NODEID+0x80\nParameterValue=\n";
        let eds = Eds::parse(dcf).unwrap();
        let n = eds.node_id().unwrap();
        assert_eq!(n.get(), 10);
        let c = eds.commissioning.as_ref().unwrap();
        assert_eq!(
            (c.node_name.as_deref(), c.baud_rate),
            (Some("axis1"), Some(500))
        );
        let hb = eds.od.get(at(0x1017, 0)).unwrap();
        assert_eq!(hb.default, Some(DefaultValue::fixed(Value::Unsigned16(0))));
        assert_eq!(hb.default_for_node(n), Some(Value::Unsigned16(250)));
        // An empty ParameterValue falls back to the default.
        assert_eq!(
            eds.od.get(at(0x1014, 0)).unwrap().default_for_node(n),
            Some(Value::Unsigned32(0x8A))
        );
        assert_eq!(eds.od.defaults_for_node(n).count(), 2);
        let (line, msg) = fails("[DeviceComissioning]\nNodeID=200\n");
        assert_eq!((line, msg.contains("out of range")), (2, true));
    }

    #[test]
    fn crlf_comments_case_and_octal() {
        let text = "\u{feff}; leading comment\r\n[fileinfo]\r\nFILENAME=x.eds\r\n\r\n  ; indented comment\r\n\
                    [optionalobjects]\r\nsupportedobjects=1\r\n1=0x1017\r\n\
                    [1017]\r\nparametername = Producer heartbeat time \r\nOBJECTTYPE=7\r\ndatatype=06\r\n\
                    ACCESSTYPE=RW\r\ndefaultvalue=010\r\npdomapping=0\r\n";
        let eds = Eds::parse(text).unwrap();
        assert_eq!(eds.file_info.file_name.as_deref(), Some("x.eds"));
        let hb = eds.od.get(at(0x1017, 0)).unwrap();
        assert_eq!(hb.name, "Producer heartbeat time");
        assert_eq!(hb.access, AccessType::Rw);
        assert_eq!(hb.default, Some(DefaultValue::fixed(Value::Unsigned16(8)))); // octal
        // Lower-case hex section names and "SUB".
        let rec = "[1a00]\nParameterName=TPDO1 mapping\nObjectType=0x9\nSubNumber=1\n\
                   [1a00SUB0]\nParameterName=Count\nDataType=0x0005\nAccessType=rw\nDefaultValue=0\n";
        assert_eq!(
            Eds::parse(rec).unwrap().od.get(at(0x1A00, 0)).unwrap().name,
            "Count"
        );
        assert_eq!(Eds::parse(MINIMAL).unwrap().od.len(), 1);
    }

    #[test]
    fn errors_name_the_line() {
        let cases: &[(&str, usize, &str)] = &[
            (
                "[1000]\nParameterName=x\nnonsense\n",
                3,
                "expected \"[section]\", \"key=value\" or a \";\" comment, found \"nonsense\"",
            ),
            ("Key=1\n", 1, "key \"Key\" appears before any [section]"),
            ("[1000\n", 1, "found \"[1000\""),
            ("[A]\n[a]\n", 2, "section [a] already appeared on line 1"),
            (
                "[A]\nk=1\nK=2\n",
                3,
                "key K already appeared in [A] on line 2",
            ),
            (
                "[1000]\nDataType=0x0007\nAccessType=ro\n",
                1,
                "[1000] has no ParameterName key",
            ),
            (
                "[1000]\nParameterName=x\nAccessType=ro\n",
                1,
                "[1000] has no DataType key",
            ),
            (
                "[1000]\nParameterName=x\nDataType=0x0007\n",
                1,
                "[1000] has no AccessType key",
            ),
            (
                "[1000]\nParameterName=x\nDataType=0x0007\nAccessType=rx\n",
                4,
                "unknown access type \"rx\"",
            ),
            (
                "[1000]\nParameterName=x\nDataType=0x000C\nAccessType=ro\n",
                3,
                "DataType 0x000C is not a supported basic type",
            ),
            (
                "[1000]\nParameterName=x\nDataType=0x0005\nAccessType=ro\nDefaultValue=300\n",
                5,
                "DefaultValue=\"300\": value 300 does not fit UNSIGNED8 (0..=255)",
            ),
            (
                "[1000]\nParameterName=x\nDataType=0x0005\nAccessType=ro\nDefaultValue=$NODEID+0x180\n",
                5,
                "does not fit UNSIGNED8",
            ),
            (
                "[1000]\nParameterName=x\nDataType=0x0007\nAccessType=ro\nPDOMapping=2\n",
                5,
                "expected 0 or 1",
            ),
            (
                "[1000]\nParameterName=x\nObjectType=0x3\n",
                3,
                "not an object code",
            ),
            (
                "[1000]\nParameterName=x\nDataType=zz\nAccessType=ro\n",
                3,
                "DataType=\"zz\"",
            ),
            (
                "[1018sub1]\nParameterName=x\nDataType=0x0007\nAccessType=ro\n",
                1,
                "[1018sub1] has no object section",
            ),
            (
                "[1017]\nParameterName=x\nDataType=0x0006\nAccessType=rw\n[1017sub0]\nParameterName=y\n",
                5,
                "VAR object 0x1017 cannot have sub-object sections",
            ),
            (
                "[1018]\nParameterName=x\nObjectType=0x9\nSubNumber=2\n[1018sub0]\nParameterName=n\nDataType=0x0005\nAccessType=ro\n",
                4,
                "SubNumber=2 but 1 sub-object sections are given for 0x1018",
            ),
            (
                "[OptionalObjects]\nSupportedObjects=1\n1=0x1017\n",
                3,
                "object 0x1017 is listed but has no [1017] section",
            ),
            (
                "[OptionalObjects]\nSupportedObjects=2\n1=0x1017\n",
                2,
                "1 objects are listed",
            ),
            (
                "[OptionalObjects]\nSupportedObjects=1\n2=0x1017\n",
                3,
                "key must be a position from 1 to SupportedObjects=1",
            ),
            (
                "[DeviceInfo]\nGranularity=300\n",
                2,
                "out of range (at most 255)",
            ),
            (
                "[DummyUsage]\nDummy0099=1\n",
                2,
                "expected Dummy0001 to Dummy001B",
            ),
        ];
        for &(text, line, message) in cases {
            let (got_line, got) = fails(text);
            assert_eq!(got_line, line, "{text:?}: {got}");
            assert!(got.contains(message), "{text:?}: {got:?} lacks {message:?}");
        }
        // The full message leads with the line number.
        let err = Eds::parse(
            "[1000]\nParameterName=x\nDataType=0x0005\nAccessType=ro\nDefaultValue=300\n",
        )
        .unwrap_err();
        assert_eq!(
            err.to_string(),
            "line 5: DefaultValue=\"300\": value 300 does not fit UNSIGNED8 (0..=255)"
        );
    }

    /// CANopenNode's reference EDS leaves the informative numbers of
    /// `[DeviceInfo]` empty and lists every dummy type in `[DummyUsage]`.
    #[test]
    fn empty_informative_values_are_absent_and_dummies_are_no_objects() {
        let text = "[DeviceInfo]\nVendorName=\nVendorNumber=\nProductName=\nProductNumber=\n\
                    RevisionNumber=0\nOrderCode=\nBaudRate_250=1\nSimpleBootUpSlave=\n\
                    Granularity=8\nNrOfRXPDO=\n\
                    [DummyUsage]\nDummy0001=0\nDummy0002=1\nDummy0003=1\nDummy0004=1\n\
                    Dummy0005=1\nDummy0006=1\nDummy0007=1\n"
            .to_string()
            + MINIMAL;
        let eds = Eds::parse(&text).unwrap();
        let info = &eds.device_info;
        assert_eq!(info.vendor_number, None);
        assert_eq!(info.product_number, None);
        assert_eq!(info.revision_number, Some(0));
        assert_eq!(info.nr_of_rx_pdo, 0);
        assert!(!info.simple_boot_up_slave);
        assert_eq!(info.baud_rates, [250]);
        // The dummies are data types a PDO mapping may use as gaps, not
        // objects of the dictionary: no listing, no DCF export reads them.
        assert_eq!(
            eds.dummy_usage,
            [
                DataType::Integer8,
                DataType::Integer16,
                DataType::Integer32,
                DataType::Unsigned8,
                DataType::Unsigned16,
                DataType::Unsigned32,
            ]
        );
        assert!(eds.od.object(0x0002).is_none());
        assert!(eds.od.object(0x0007).is_none());
        assert_eq!(
            eds.od.variables().map(|v| v.address).collect::<Vec<_>>(),
            [at(0x1000, 0)]
        );
        // A device simulated from the EDS serves them as DEFTYPE entries.
        let served = eds.od_with_dummies();
        let dummy = served.object(0x0005).unwrap();
        assert_eq!(dummy.object_type, ObjectType::DefType);
        assert!(served.object(0x0001).is_none());
        // An empty flag is absent too; one that is neither 0 nor 1 is an
        // error.
        let eds = Eds::parse("[DummyUsage]\nDummy0005=\n").unwrap();
        assert!(eds.dummy_usage.is_empty());
        let (line, message) = fails("[DummyUsage]\nDummy0005=2\n");
        assert_eq!(line, 2);
        assert!(message.contains("expected 0 or 1"), "{message}");
    }

    #[test]
    fn compact_arrays() {
        let text = "[6000]\nParameterName=Read input 8-bit\nObjectType=0x8\nDataType=0x0005\nAccessType=ro\n\
                    PDOMapping=1\nCompactSubObj=3\nDefaultValue=7\n\
                    [6000Name]\nNrOfEntries=1\n2=Second\n[6000Value]\nNrOfEntries=1\n3=0x10\n";
        let od = Eds::parse(text).unwrap().od;
        let o = od.object(0x6000).unwrap();
        assert_eq!(o.subs.len(), 4);
        assert_eq!(o.sub(0).unwrap().name, "Number of entries");
        assert_eq!(o.sub(1).unwrap().name, "Read input 8-bit 1");
        assert_eq!(o.sub(2).unwrap().name, "Second");
        assert_eq!(
            o.sub(3).unwrap().default_for_node(node(1)),
            Some(Value::Unsigned8(16))
        );
        assert_eq!(
            o.sub(1).unwrap().default_for_node(node(1)),
            Some(Value::Unsigned8(7))
        );
        let bad = text.replace("2=Second", "9=Ninth");
        assert_eq!(
            fails(&bad),
            (
                11,
                "9=\"Ninth\": key must be a sub-index from 1 to 3".into()
            )
        );
    }

    #[test]
    fn from_path_reads_files() {
        let dir = std::env::temp_dir().join(format!("cangate-eds-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("latin1.eds");
        // Latin-1 "é" (0xE9) in a name, as older tools write.
        let mut bytes =
            b"[1008]\nParameterName=Nom du p\xE9riph\xE9rique\nDataType=0x0009\nAccessType=const\n"
                .to_vec();
        bytes.extend_from_slice(b"DefaultValue=sim\n");
        std::fs::write(&path, bytes).unwrap();
        let eds = Eds::from_path(&path).unwrap();
        assert_eq!(
            eds.od.get(at(0x1008, 0)).unwrap().name,
            "Nom du périphérique"
        );
        std::fs::remove_dir_all(&dir).unwrap();
        let err = Eds::from_path(dir.join("missing.eds")).unwrap_err();
        assert!(err.to_string().starts_with("cannot read "), "{err}");
        assert_eq!(err.line(), None);
    }
}
