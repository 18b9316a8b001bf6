//! Device configuration files (CiA 306 DCF): a node's live values written
//! into its EDS, and a DCF's `ParameterValue`s turned into the SDO writes a
//! boot procedure applies (in the spirit of CiA 302-2's configuration
//! manager).
//!
//! What CiA 306 leaves open, settled here:
//!
//! - **Export** keeps the EDS text as it is (comments, vendor keys,
//!   `CompactSubObj`) and adds one `ParameterValue=` per value to the
//!   section of its object or sub-object (replacing one already there);
//!   sub-objects of a `CompactSubObj` array get theirs in a
//!   `[xxxxValue]` section. The `[DeviceComissioning]` section is replaced.
//!   Unsigned integers are written in hex, signed ones in decimal, octet
//!   strings as hex bytes; DOMAIN values are not written (CiA 306 keeps
//!   them in separate files), nor are empty octet strings.
//! - **Apply** writes the `ParameterValue`s of `rw` objects only: `rww`
//!   and `rwr` objects are process data (a controlword written at boot
//!   could enable a drive), `ro`/`const` cannot be written, and `wo`
//!   objects are commands. The access is the node's EDS's, not the DCF's
//!   own (a DCF is a file anyone edits: `AccessType=rw` on the
//!   controlword must not make it a configuration value); an object the
//!   EDS lacks is not written. Without an EDS the DCF's access is all
//!   there is. The CiA 402 objects that command motion
//!   ([`CIA402_COMMAND_OBJECTS`]) are never written, whatever any file
//!   says. Store/restore (0x1010, 0x1011) and program
//!   download (0x1F50..=0x1F57) are left out: writing their values back
//!   would trigger them. PDO parameters (0x1400..=0x1BFF) are written as
//!   whole PDOs with the CiA 301 sequence ([`PdoConfig::sdo_writes`]), in
//!   place of their single values; a PDO the DCF leaves invalid is written
//!   invalid. The other writes go in index order.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;

use crate::eds::Commissioning;
use crate::ids::{NodeId, ObjectAddress};
use crate::od::{AccessType, ObjectDictionary};
use crate::pdo::{PdoConfig, PdoError, PdoKind};
use crate::value::Value;

/// The CiA 402 objects through which a master commands a drive's motion:
/// controlword, modes of operation, target position, target velocity,
/// target torque.
pub const CIA402_COMMAND_OBJECTS: [u16; 5] = [0x6040, 0x6060, 0x607A, 0x60FF, 0x6071];

/// Objects whose values are never written back from a DCF.
fn never_applied(index: u16) -> bool {
    matches!(index, 0x1010 | 0x1011 | 0x1F50..=0x1F57)
}

/// The boot writes of a DCF, and the values it carries that are not
/// written for a reason worth telling.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ConfigurationWrites {
    /// The SDO writes, in order.
    pub writes: Vec<(ObjectAddress, Vec<u8>)>,
    /// Values left out against what the DCF says of them (a CiA 402
    /// command object, or an object the DCF calls `rw` that the node's EDS
    /// does not), with the reason.
    pub skipped: Vec<(ObjectAddress, String)>,
}

/// The PDO an object belongs to, for the PDO parameter ranges.
fn pdo_of(index: u16) -> Option<(PdoKind, u16)> {
    match index {
        0x1400..=0x15FF => Some((PdoKind::Rpdo, index - 0x1400 + 1)),
        0x1600..=0x17FF => Some((PdoKind::Rpdo, index - 0x1600 + 1)),
        0x1800..=0x19FF => Some((PdoKind::Tpdo, index - 0x1800 + 1)),
        0x1A00..=0x1BFF => Some((PdoKind::Tpdo, index - 0x1A00 + 1)),
        _ => None,
    }
}

/// The SDO writes that apply `od`'s `ParameterValue`s to node `node`,
/// with the access of each object taken from the node's EDS `eds` when
/// there is one (see the [module documentation](self) for which and in
/// what order).
pub fn configuration_writes(
    od: &ObjectDictionary,
    eds: Option<&ObjectDictionary>,
    node: NodeId,
) -> Result<ConfigurationWrites, PdoError> {
    let mut writes = Vec::new();
    let mut skipped = Vec::new();
    let mut pdos = BTreeSet::new();
    for var in od.variables() {
        let Some(value) = var.parameter_value.as_ref().map(|p| p.resolve(node)) else {
            continue;
        };
        let index = var.address.index;
        if let Some(pdo) = pdo_of(index) {
            pdos.insert(pdo);
            continue;
        }
        if CIA402_COMMAND_OBJECTS.contains(&index) {
            skipped.push((
                var.address,
                "a CiA 402 object that commands motion: never written from a DCF".to_string(),
            ));
            continue;
        }
        let access = match eds {
            Some(eds) => match eds.get(var.address) {
                Some(e) => e.access,
                None => {
                    skipped.push((var.address, "not in the node's EDS".to_string()));
                    continue;
                }
            },
            None => var.access,
        };
        if access != AccessType::Rw || never_applied(index) {
            if var.access == AccessType::Rw && access != AccessType::Rw {
                skipped.push((
                    var.address,
                    format!(
                        "the DCF says rw, the node's EDS says {}: not a configuration value",
                        access.as_str()
                    ),
                ));
            }
            continue;
        }
        writes.push((var.address, value.encode()));
    }
    for (kind, num) in pdos {
        match PdoConfig::from_od(od, kind, num, node) {
            Some(cfg) => writes.extend(cfg.sdo_writes()?),
            None => {
                // Invalid in the DCF: written invalid, mapping untouched.
                let cob = ObjectAddress::new(kind.comm_index(num), 1);
                if let Some(v) = od
                    .get(cob)
                    .and_then(|v| v.default_for_node(node))
                    .and_then(|v| v.as_u32())
                {
                    writes.push((cob, (v | 0x8000_0000).to_le_bytes().to_vec()));
                }
            }
        }
    }
    Ok(ConfigurationWrites { writes, skipped })
}

/// A value as a DCF writes it; `None` for values a DCF does not carry.
fn dcf_text(value: &Value) -> Option<String> {
    Some(match value {
        Value::Boolean(b) => u8::from(*b).to_string(),
        Value::Real32(f) => format!("{f:?}"),
        Value::Real64(f) => format!("{f:?}"),
        Value::VisibleString(s) | Value::UnicodeString(s) => s.clone(),
        Value::OctetString(b) if !b.is_empty() => b.iter().map(|b| format!("{b:02X}")).collect(),
        Value::OctetString(_) | Value::Domain(_) => return None,
        v => match (v.data_type().is_signed(), v.as_i128()) {
            (true, Some(i)) => i.to_string(),
            (false, Some(u)) => format!("0x{u:X}"),
            (_, None) => return None,
        },
    })
}

/// What an INI section header names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Header {
    /// `[1017]`.
    Object(u16),
    /// `[1018sub1]`.
    Sub(u16, u8),
    /// `[6000Value]`.
    CompactValues(u16),
    /// `[DeviceComissioning]`.
    Commissioning,
    /// Anything else.
    Other,
}

fn header(line: &str) -> Option<Header> {
    let name = line.trim().strip_prefix('[')?.strip_suffix(']')?.trim();
    let lower = name.to_ascii_lowercase();
    let hex4 = |s: &str| {
        (s.len() == 4)
            .then(|| u16::from_str_radix(s, 16).ok())
            .flatten()
    };
    Some(if let Some(i) = hex4(&lower) {
        Header::Object(i)
    } else if let (Some(i), Some(sub)) = (
        lower.get(..4).and_then(hex4),
        lower.get(4..).and_then(|r| r.strip_prefix("sub")),
    ) {
        match u8::from_str_radix(sub, 16) {
            Ok(s) => Header::Sub(i, s),
            Err(_) => Header::Other,
        }
    } else if let (Some(i), Some("value")) = (lower.get(..4).and_then(hex4), lower.get(4..)) {
        Header::CompactValues(i)
    } else if lower == "devicecomissioning" || lower == "devicecommissioning" {
        Header::Commissioning
    } else {
        Header::Other
    })
}

/// The EDS (or DCF) text `eds_text` with `values` as `ParameterValue`s and
/// `commissioning` as its `[DeviceComissioning]` section: a DCF. `od` is
/// the dictionary parsed from that text: it tells VAR objects (value in
/// the object's section) from compact arrays (values in `[xxxxValue]`).
pub fn write_dcf(
    eds_text: &str,
    od: &ObjectDictionary,
    values: &BTreeMap<ObjectAddress, Value>,
    commissioning: &Commissioning,
) -> String {
    let texts: BTreeMap<ObjectAddress, String> = values
        .iter()
        .filter_map(|(a, v)| Some((*a, dcf_text(v)?)))
        .collect();
    // Where each value goes: its own section, else its array's Value list.
    let mut sections: BTreeSet<(u16, Option<u8>)> = BTreeSet::new();
    for line in eds_text.lines() {
        match header(line) {
            Some(Header::Object(i)) => {
                sections.insert((i, None));
            }
            Some(Header::Sub(i, s)) => {
                sections.insert((i, Some(s)));
            }
            _ => {}
        }
    }
    let is_var = |i: u16| od.object(i).is_some_and(|o| !o.object_type.is_compound());
    let section_of = |a: ObjectAddress| -> Option<Header> {
        if sections.contains(&(a.index, Some(a.sub))) {
            Some(Header::Sub(a.index, a.sub))
        } else if a.sub == 0 && is_var(a.index) && sections.contains(&(a.index, None)) {
            Some(Header::Object(a.index))
        } else {
            None
        }
    };
    let mut out = String::with_capacity(eds_text.len() + texts.len() * 32);
    // The value owed to the section being copied, written at its end.
    let mut owed: Option<&str> = None;
    let mut skipping = false;
    let flush = |out: &mut String, owed: &mut Option<&str>| {
        if let Some(v) = owed.take() {
            let _ = writeln!(out, "ParameterValue={v}");
        }
    };
    for line in eds_text.lines() {
        if let Some(h) = header(line) {
            flush(&mut out, &mut owed);
            // Replaced below: the old commissioning and compact values.
            skipping = match h {
                Header::Commissioning => true,
                Header::CompactValues(i) => texts.keys().any(|a| a.index == i && a.sub > 0),
                _ => false,
            };
            if skipping {
                continue;
            }
            owed = texts
                .iter()
                .find(|(a, _)| section_of(**a) == Some(h))
                .map(|(_, t)| t.as_str());
            // A blank line before the owed value reads better: keep the
            // section's lines first.
            out.push_str(line.trim_end());
            out.push('\n');
            continue;
        }
        if skipping {
            continue;
        }
        let key = line.split('=').next().unwrap_or("").trim();
        if owed.is_some() && key.eq_ignore_ascii_case("ParameterValue") {
            continue;
        }
        if line.trim().is_empty() {
            flush(&mut out, &mut owed);
        }
        out.push_str(line.trim_end());
        out.push('\n');
    }
    flush(&mut out, &mut owed);
    // The appended sections follow after one blank line, however the
    // text ended (so that writing a DCF again gives the same text).
    while out.ends_with("\n\n") {
        out.pop();
    }
    // Values of sub-objects without a section of their own.
    let mut compact: BTreeMap<u16, Vec<(u8, &str)>> = BTreeMap::new();
    for (a, t) in &texts {
        if a.sub > 0 && section_of(*a).is_none() && od.get(*a).is_some() {
            compact.entry(a.index).or_default().push((a.sub, t));
        }
    }
    for (index, entries) in compact {
        let _ = writeln!(out, "\n[{index:04X}Value]\nNrOfEntries={}", entries.len());
        for (sub, t) in entries {
            let _ = writeln!(out, "{sub}={t}");
        }
    }
    let c = commissioning;
    let _ = writeln!(out, "\n[DeviceComissioning]");
    if let Some(n) = c.node_id {
        let _ = writeln!(out, "NodeID={}", n.get());
    }
    if let Some(n) = &c.node_name {
        let _ = writeln!(out, "NodeName={n}");
    }
    if let Some(b) = c.baud_rate {
        let _ = writeln!(out, "Baudrate={b}");
    }
    if let Some(n) = c.net_number {
        let _ = writeln!(out, "NetNumber={n}");
    }
    if let Some(n) = &c.network_name {
        let _ = writeln!(out, "NetworkName={n}");
    }
    let _ = writeln!(out, "CANopenManager={}", u8::from(c.canopen_manager));
    if let Some(s) = c.lss_serial_number {
        let _ = writeln!(out, "LSS_SerialNumber=0x{s:X}");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eds::{Eds, SIM_DRIVE_EDS, SIM_IO_EDS};

    fn node(n: u32) -> NodeId {
        NodeId::new(n).unwrap()
    }

    /// Every readable value of the EDS's defaults, some changed.
    fn live_values(eds: &Eds, n: NodeId) -> BTreeMap<ObjectAddress, Value> {
        eds.od
            .variables()
            .filter(|v| v.access.is_readable())
            .filter_map(|v| Some((v.address, v.default_for_node(n)?)))
            .collect()
    }

    #[test]
    fn a_written_dcf_parses_back_to_the_same_dictionary_with_the_values() {
        for text in [SIM_DRIVE_EDS, SIM_IO_EDS] {
            let eds = Eds::parse(text).unwrap();
            let mut values = live_values(&eds, node(5));
            values.insert(ObjectAddress::new(0x1017, 0), Value::Unsigned16(77));
            values.insert(
                ObjectAddress::new(0x1008, 0),
                Value::VisibleString("renamed = yes".into()),
            );
            let commissioning = Commissioning {
                node_id: Some(node(5)),
                node_name: Some("X axis drive".into()),
                baud_rate: Some(1000),
                network_name: Some("can0".into()),
                ..Commissioning::default()
            };
            let dcf = write_dcf(text, &eds.od, &values, &commissioning);
            let back = Eds::parse(&dcf).unwrap_or_else(|e| panic!("the DCF does not parse: {e}"));
            assert_eq!(back.commissioning, Some(commissioning));
            for (addr, v) in &values {
                let var = back.od.get(*addr).unwrap();
                // The count of a CompactSubObj array has no place for a
                // value (it is fixed by CompactSubObj).
                let compact_count = addr.sub == 0
                    && !text
                        .to_ascii_lowercase()
                        .contains(&format!("[{:04x}sub0]", addr.index))
                    && back
                        .od
                        .object(addr.index)
                        .is_some_and(|o| o.object_type.is_compound());
                let Some(text) = dcf_text(v).filter(|_| !compact_count) else {
                    assert!(var.parameter_value.is_none());
                    continue;
                };
                let got = var
                    .parameter_value
                    .as_ref()
                    .unwrap_or_else(|| panic!("{addr}: no ParameterValue for {text}"))
                    .resolve(node(5));
                assert_eq!(&got, v, "{addr}");
            }
            // Nothing else changed.
            let mut stripped = back.od.clone();
            for v in values.keys() {
                if let Some(var) = stripped.get_mut(*v) {
                    var.parameter_value = None;
                }
            }
            assert_eq!(stripped, eds.od);
            // Written again from the DCF: the same text.
            let again = write_dcf(&dcf, &back.od, &values, &back.commissioning.unwrap());
            assert!(again == dcf, "writing the DCF again changed it");
        }
    }

    #[test]
    fn compact_arrays_get_a_value_section() {
        let text = "[FileInfo]\nFileName=x.eds\n\n[6000]\nParameterName=Inputs\nObjectType=0x8\n\
                    DataType=0x0005\nAccessType=rw\nCompactSubObj=3\nDefaultValue=0\n";
        let eds = Eds::parse(text).unwrap();
        let values = BTreeMap::from([
            (ObjectAddress::new(0x6000, 1), Value::Unsigned8(1)),
            (ObjectAddress::new(0x6000, 3), Value::Unsigned8(0xAB)),
        ]);
        let dcf = write_dcf(text, &eds.od, &values, &Commissioning::default());
        assert!(
            dcf.contains("\n\n[6000Value]\nNrOfEntries=2\n1=0x1\n3=0xAB\n"),
            "{dcf}"
        );
        let back = Eds::parse(&dcf).unwrap();
        let pv = |s| {
            back.od
                .get(ObjectAddress::new(0x6000, s))
                .unwrap()
                .parameter_value
                .as_ref()
                .map(|p| p.resolve(node(1)))
        };
        assert_eq!(pv(1), Some(Value::Unsigned8(1)));
        assert_eq!(pv(2), None);
        assert_eq!(pv(3), Some(Value::Unsigned8(0xAB)));
    }

    #[test]
    fn applied_writes_are_rw_objects_and_whole_pdos() {
        let mut eds = Eds::parse(SIM_DRIVE_EDS).unwrap();
        let n = node(5);
        let set = |eds: &mut Eds, index, sub, v: Value| {
            eds.od
                .get_mut(ObjectAddress::new(index, sub))
                .unwrap()
                .parameter_value = Some(crate::od::DefaultValue::fixed(v));
        };
        set(&mut eds, 0x1017, 0, Value::Unsigned16(77));
        // The controlword is process data: never written from a DCF.
        set(&mut eds, 0x6040, 0, Value::Unsigned16(0x0F));
        // TPDO1: event timer 25 ms.
        set(&mut eds, 0x1800, 5, Value::Unsigned16(25));
        let writes = configuration_writes(&eds.od, None, n).unwrap().writes;
        assert_eq!(writes[0], (ObjectAddress::new(0x1017, 0), vec![77, 0]));
        assert!(!writes.iter().any(|(a, _)| a.index == 0x6040), "{writes:?}");
        let tpdo1 = PdoConfig::from_od(&eds.od, PdoKind::Tpdo, 1, n).unwrap();
        assert_eq!(tpdo1.event_timer_ms, 25);
        assert_eq!(&writes[1..], &tpdo1.sdo_writes().unwrap()[..]);
        // Nothing set, nothing written.
        let plain = Eds::parse(SIM_DRIVE_EDS).unwrap();
        assert_eq!(
            configuration_writes(&plain.od, Some(&plain.od), n).unwrap(),
            ConfigurationWrites::default()
        );
    }

    /// A DCF that calls the controlword and a status object `rw`: the
    /// node's EDS decides, and the CiA 402 command objects are never
    /// written; both are told.
    #[test]
    fn access_comes_from_the_eds_and_command_objects_are_never_written() {
        let eds = Eds::parse(SIM_DRIVE_EDS).unwrap();
        let mut dcf = Eds::parse(SIM_DRIVE_EDS).unwrap();
        let n = node(5);
        for (index, v) in [
            (0x6040, Value::Unsigned16(0x000F)),
            (0x6041, Value::Unsigned16(0x0237)),
            (0x6081, Value::Unsigned32(1234)),
        ] {
            let var = dcf.od.get_mut(ObjectAddress::new(index, 0)).unwrap();
            var.access = AccessType::Rw;
            var.parameter_value = Some(crate::od::DefaultValue::fixed(v));
        }
        let out = configuration_writes(&dcf.od, Some(&eds.od), n).unwrap();
        assert_eq!(
            out.writes,
            vec![(
                ObjectAddress::new(0x6081, 0),
                1234u32.to_le_bytes().to_vec()
            )]
        );
        let skipped: Vec<(u16, &str)> = out
            .skipped
            .iter()
            .map(|(a, why)| (a.index, why.as_str()))
            .collect();
        assert_eq!(skipped.len(), 2, "{skipped:?}");
        assert_eq!(skipped[0].0, 0x6040);
        assert!(skipped[0].1.contains("CiA 402"), "{skipped:?}");
        assert_eq!(skipped[1].0, 0x6041);
        assert!(skipped[1].1.contains("EDS says ro"), "{skipped:?}");
        // Without the EDS the DCF's access is all there is, and still the
        // controlword is not written.
        let out = configuration_writes(&dcf.od, None, n).unwrap();
        assert!(
            !out.writes.iter().any(|(a, _)| a.index == 0x6040),
            "{:?}",
            out.writes
        );
        // An object the EDS lacks (an I/O module's EDS has no 0x6081).
        let small = Eds::parse(SIM_IO_EDS).unwrap();
        let out = configuration_writes(&dcf.od, Some(&small.od), n).unwrap();
        assert!(out.writes.iter().all(|(a, _)| small.od.get(*a).is_some()));
        assert!(
            out.skipped
                .iter()
                .any(|(a, why)| a.index == 0x6081 && why.contains("not in the node's EDS")),
            "{:?}",
            out.skipped
        );
    }

    #[test]
    fn headers() {
        assert_eq!(header("[1017]"), Some(Header::Object(0x1017)));
        assert_eq!(header("[1018sub1]"), Some(Header::Sub(0x1018, 1)));
        assert_eq!(header("[1A00SUB1F]"), Some(Header::Sub(0x1A00, 0x1F)));
        assert_eq!(header("[6000Value]"), Some(Header::CompactValues(0x6000)));
        assert_eq!(header("[DeviceComissioning]"), Some(Header::Commissioning));
        assert_eq!(header("[FileInfo]"), Some(Header::Other));
        assert_eq!(header("Key=1"), None);
    }
}
