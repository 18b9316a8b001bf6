//! CANopen frames in words, for a person reading the traffic in a log:
//! NMT command and target, SYNC, EMCY code, TIME, PDO COB-ID, SDO request
//! or response with its command specifier, index:sub-index and abort code
//! name, heartbeat state, node guarding, LSS.
//!
//! The decoding is stateless: one frame at a time, by its COB-ID in the
//! predefined connection set (CiA 301 §7.3.5) and its first byte. What that
//! leaves open, settled here:
//! - a frame on a COB-ID a PDO was remapped to, or any frame outside the
//!   predefined set (extended id, FD, an unassigned id), has no words:
//!   [`describe`] returns `None` and the caller shows the raw frame;
//! - the segments inside an SDO block (CiA 301 §7.2.4.3.9, first byte =
//!   continuation bit and sequence number) cannot be told from other SDO
//!   frames without the transfer's state, so they read as whatever their
//!   first byte means as a command specifier;
//! - a frame too short for its service says so ("malformed") with its
//!   bytes, never panics.

use std::fmt::Write as _;

use cangate_can::Frame;

use crate::emcy::Emcy;
use crate::ids::{CobFunction, NodeId};
use crate::lss::{LSS_REQUEST_COB_ID, LSS_RESPONSE_COB_ID, cs as lss_cs};
use crate::nmt::{NmtState, parse_nmt};
use crate::sdo::AbortCode;
use crate::time_of_day::TimeOfDay;

/// The frame in words, or `None` when it is not a frame of the CANopen
/// predefined connection set (see the module's documentation).
pub fn describe(frame: &Frame) -> Option<String> {
    if frame.is_error() || frame.is_fd() || frame.is_extended() {
        return None;
    }
    let id = u16::try_from(frame.raw_id()).ok()?;
    let data = frame.data();
    if id == LSS_REQUEST_COB_ID || id == LSS_RESPONSE_COB_ID {
        return Some(lss(id == LSS_REQUEST_COB_ID, data));
    }
    let remote = frame.is_remote();
    Some(match CobFunction::classify(id) {
        CobFunction::Nmt => match parse_nmt(frame) {
            Some((cmd, target)) => format!("NMT {} → {}", cmd.name(), target_text(target)),
            None => malformed("NMT", data),
        },
        CobFunction::Sync => match data {
            [] => "SYNC".to_string(),
            [counter] => format!("SYNC counter {counter}"),
            _ => malformed("SYNC", data),
        },
        CobFunction::Emcy(node) => match Emcy::decode(frame) {
            Some(e) if e.is_reset() => format!("EMCY node {node}: error reset"),
            Some(e) => format!(
                "EMCY node {node}: 0x{:04X} {}, error register 0x{:02X}",
                e.code,
                e.code_name(),
                e.register
            ),
            None => malformed(&format!("EMCY node {node}"), data),
        },
        CobFunction::Time => match TimeOfDay::decode(data) {
            Ok(t) => format!(
                "TIME day {} since 1984-01-01, {} ms after midnight",
                t.days, t.ms
            ),
            Err(_) => malformed("TIME", data),
        },
        CobFunction::Tpdo(n, node) => pdo("TPDO", n, node, id, remote, data),
        CobFunction::Rpdo(n, node) => pdo("RPDO", n, node, id, remote, data),
        CobFunction::SdoRx(node) => sdo_request(node, data),
        CobFunction::SdoTx(node) => sdo_response(node, data),
        CobFunction::Heartbeat(node) => heartbeat(node, remote, data),
        CobFunction::Other => return None,
    })
}

fn target_text(target: Option<NodeId>) -> String {
    target.map_or_else(|| "all nodes".to_string(), |n| format!("node {n}"))
}

fn hex(data: &[u8]) -> String {
    let mut s = String::with_capacity(data.len() * 3);
    for (i, b) in data.iter().enumerate() {
        if i > 0 {
            s.push(' ');
        }
        let _ = write!(s, "{b:02X}");
    }
    s
}

fn malformed(what: &str, data: &[u8]) -> String {
    format!("{what} malformed: [{}]", hex(data))
}

fn pdo(kind: &str, n: u8, node: NodeId, id: u16, remote: bool, data: &[u8]) -> String {
    if remote {
        format!("{kind}{n} node {node} (0x{id:03X}) remote request")
    } else {
        format!("{kind}{n} node {node} (0x{id:03X}): [{}]", hex(data))
    }
}

fn heartbeat(node: NodeId, remote: bool, data: &[u8]) -> String {
    if remote {
        return format!("node guarding request to node {node}");
    }
    match data {
        [0x00] => format!("boot-up node {node}"),
        [b] => match (NmtState::from_byte(*b), NmtState::from_byte(b & 0x7F)) {
            (Some(state), _) => format!("heartbeat node {node}: {}", state.name()),
            // A node-guarding answer: the state with the toggle bit.
            (None, Some(state)) => format!(
                "node guarding node {node}: {} (toggle {})",
                state.name(),
                b >> 7
            ),
            (None, None) => malformed(&format!("heartbeat node {node}"), data),
        },
        _ => malformed(&format!("heartbeat node {node}"), data),
    }
}

/// Index and sub-index of an SDO frame's bytes 1..=3.
fn address(data: &[u8]) -> Option<String> {
    match data {
        [_, lo, hi, sub, ..] => Some(format!(
            "0x{:04X}:{sub:02X}",
            u16::from_le_bytes([*lo, *hi])
        )),
        _ => None,
    }
}

/// The bytes of an expedited transfer: `n` (bits 3..2) counts the unused
/// ones when `s` (bit 0) is set.
fn expedited(cs: u8, data: &[u8]) -> String {
    let len = if cs & 0x01 != 0 {
        4 - usize::from((cs >> 2) & 0x03)
    } else {
        4
    };
    hex(data.get(4..4 + len).unwrap_or(&[]))
}

fn abort(node: NodeId, direction: &str, data: &[u8]) -> String {
    match (address(data), data.get(4..8)) {
        (Some(at), Some(&[a, b, c, d])) => {
            let code = AbortCode::from(u32::from_le_bytes([a, b, c, d]));
            format!(
                "SDO abort {at} {direction} node {node}: 0x{:08X} {}",
                code.get(),
                code.name()
            )
        }
        _ => malformed(&format!("SDO abort {direction} node {node}"), data),
    }
}

/// Client → server (0x600 + node): the client command specifier is bits
/// 7..5 of byte 0.
fn sdo_request(node: NodeId, data: &[u8]) -> String {
    let Some(&cs) = data.first() else {
        return malformed(&format!("SDO request to node {node}"), data);
    };
    let at = address(data);
    let with_at = |what: &str| match &at {
        Some(at) => format!("SDO {what} {at} to node {node}"),
        None => malformed(&format!("SDO {what} to node {node}"), data),
    };
    match cs >> 5 {
        0 => format!(
            "SDO download segment to node {node}: toggle {}{}, [{}]",
            (cs >> 4) & 1,
            if cs & 1 != 0 { ", last" } else { "" },
            hex(data
                .get(1..8 - usize::from((cs >> 1) & 0x07))
                .unwrap_or(&[]))
        ),
        1 if cs & 0x02 != 0 => match &at {
            Some(at) => format!(
                "SDO download request {at} to node {node} (expedited): [{}]",
                expedited(cs, data)
            ),
            None => malformed(&format!("SDO download request to node {node}"), data),
        },
        1 => with_at("download request"),
        2 => with_at("upload request"),
        3 => format!(
            "SDO upload segment request to node {node}: toggle {}",
            (cs >> 4) & 1
        ),
        4 => abort(node, "to", data),
        5 => match cs & 0x03 {
            0 => with_at("block upload request"),
            1 => format!("SDO block upload end response to node {node}"),
            2 => format!("SDO block upload acknowledge to node {node}"),
            _ => format!("SDO block upload start to node {node}"),
        },
        6 => match cs & 0x01 {
            0 => with_at("block download request"),
            _ => format!("SDO block download end request to node {node}"),
        },
        _ => format!(
            "SDO request to node {node}: unknown command specifier 0x{cs:02X} [{}]",
            hex(data)
        ),
    }
}

/// Server → client (0x580 + node): the server command specifier is bits
/// 7..5 of byte 0.
fn sdo_response(node: NodeId, data: &[u8]) -> String {
    let Some(&cs) = data.first() else {
        return malformed(&format!("SDO response from node {node}"), data);
    };
    let at = address(data);
    let with_at = |what: &str| match &at {
        Some(at) => format!("SDO {what} {at} from node {node}"),
        None => malformed(&format!("SDO {what} from node {node}"), data),
    };
    match cs >> 5 {
        0 => format!(
            "SDO upload segment from node {node}: toggle {}{}, [{}]",
            (cs >> 4) & 1,
            if cs & 1 != 0 { ", last" } else { "" },
            hex(data
                .get(1..8 - usize::from((cs >> 1) & 0x07))
                .unwrap_or(&[]))
        ),
        1 => format!(
            "SDO download segment response from node {node}: toggle {}",
            (cs >> 4) & 1
        ),
        2 if cs & 0x02 != 0 => match &at {
            Some(at) => format!(
                "SDO upload response {at} from node {node} (expedited): [{}]",
                expedited(cs, data)
            ),
            None => malformed(&format!("SDO upload response from node {node}"), data),
        },
        2 => match (&at, data.get(4..8)) {
            (Some(at), Some(&[a, b, c, d])) if cs & 0x01 != 0 => format!(
                "SDO upload response {at} from node {node}: {} bytes follow",
                u32::from_le_bytes([a, b, c, d])
            ),
            _ => with_at("upload response"),
        },
        3 => with_at("download response"),
        4 => abort(node, "from", data),
        5 => match cs & 0x03 {
            0 => with_at("block download response"),
            1 => format!("SDO block download end response from node {node}"),
            _ => format!(
                "SDO block download acknowledge from node {node}: sequence {}, block size {}",
                data.get(1).copied().unwrap_or(0),
                data.get(2).copied().unwrap_or(0)
            ),
        },
        6 => match cs & 0x01 {
            0 => with_at("block upload response"),
            _ => format!("SDO block upload end request from node {node}"),
        },
        _ => format!(
            "SDO response from node {node}: unknown command specifier 0x{cs:02X} [{}]",
            hex(data)
        ),
    }
}

/// The name of an LSS command specifier (CiA 305).
fn lss_name(cs: u8) -> Option<&'static str> {
    Some(match cs {
        lss_cs::SWITCH_GLOBAL => "switch state global",
        lss_cs::CONFIGURE_NODE_ID => "configure node-ID",
        lss_cs::CONFIGURE_BIT_TIMING => "configure bit timing",
        lss_cs::ACTIVATE_BIT_TIMING => "activate bit timing",
        lss_cs::STORE_CONFIGURATION => "store configuration",
        lss_cs::SWITCH_SELECTIVE_VENDOR => "switch state selective vendor-ID",
        lss_cs::SWITCH_SELECTIVE_PRODUCT => "switch state selective product code",
        lss_cs::SWITCH_SELECTIVE_REVISION => "switch state selective revision number",
        lss_cs::SWITCH_SELECTIVE_SERIAL => "switch state selective serial number",
        lss_cs::SWITCH_SELECTIVE_RESPONSE => "switch state selective answer",
        lss_cs::IDENTIFY_VENDOR => "identify remote slave vendor-ID",
        lss_cs::IDENTIFY_PRODUCT => "identify remote slave product code",
        lss_cs::IDENTIFY_REVISION_LOW => "identify remote slave revision number low",
        lss_cs::IDENTIFY_REVISION_HIGH => "identify remote slave revision number high",
        lss_cs::IDENTIFY_SERIAL_LOW => "identify remote slave serial number low",
        lss_cs::IDENTIFY_SERIAL_HIGH => "identify remote slave serial number high",
        lss_cs::IDENTIFY_NON_CONFIGURED => "identify non-configured remote slave",
        lss_cs::IDENTIFY_SLAVE => "identify slave",
        lss_cs::IDENTIFY_NON_CONFIGURED_SLAVE => "identify non-configured slave",
        lss_cs::FASTSCAN => "fastscan",
        lss_cs::INQUIRE_VENDOR => "inquire vendor-ID",
        lss_cs::INQUIRE_PRODUCT => "inquire product code",
        lss_cs::INQUIRE_REVISION => "inquire revision number",
        lss_cs::INQUIRE_SERIAL => "inquire serial number",
        lss_cs::INQUIRE_NODE_ID => "inquire node-ID",
        _ => return None,
    })
}

fn lss(request: bool, data: &[u8]) -> String {
    let kind = if request { "LSS request" } else { "LSS answer" };
    let Some(&cs) = data.first() else {
        return malformed(kind, data);
    };
    let Some(name) = lss_name(cs) else {
        return format!(
            "{kind}: unknown command specifier 0x{cs:02X} [{}]",
            hex(data)
        );
    };
    let arg = data.get(1).copied().unwrap_or(0);
    let detail = match (request, cs) {
        (true, lss_cs::SWITCH_GLOBAL) => match arg {
            0 => ": waiting".to_string(),
            1 => ": configuration".to_string(),
            _ => format!(": mode {arg}"),
        },
        (true, lss_cs::CONFIGURE_NODE_ID) => format!(": {arg}"),
        (true, lss_cs::CONFIGURE_BIT_TIMING) => {
            format!(": table {arg}, index {}", data.get(2).copied().unwrap_or(0))
        }
        (true, lss_cs::ACTIVATE_BIT_TIMING) => format!(
            ": switch delay {} ms",
            u16::from_le_bytes([arg, data.get(2).copied().unwrap_or(0)])
        ),
        (
            false,
            lss_cs::CONFIGURE_NODE_ID | lss_cs::CONFIGURE_BIT_TIMING | lss_cs::STORE_CONFIGURATION,
        ) => {
            format!(": error code {arg}")
        }
        (false, c) if (lss_cs::INQUIRE_VENDOR..=lss_cs::INQUIRE_NODE_ID).contains(&c) => {
            match data.get(1..5) {
                Some(&[a, b, c, d]) => format!(": 0x{:08X}", u32::from_le_bytes([a, b, c, d])),
                _ => String::new(),
            }
        }
        (_, c)
            if (lss_cs::SWITCH_SELECTIVE_VENDOR..=lss_cs::SWITCH_SELECTIVE_SERIAL).contains(&c)
                || (lss_cs::IDENTIFY_VENDOR..=lss_cs::IDENTIFY_SERIAL_HIGH).contains(&c) =>
        {
            match data.get(1..5) {
                Some(&[a, b, c, d]) => format!(": 0x{:08X}", u32::from_le_bytes([a, b, c, d])),
                _ => String::new(),
            }
        }
        _ => String::new(),
    };
    format!("{kind}: {name}{detail}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use cangate_can::CanId;

    fn frame(id: u16, data: &[u8]) -> Frame {
        Frame::new(CanId::Standard(id), data).unwrap()
    }

    fn text(id: u16, data: &[u8]) -> String {
        describe(&frame(id, data)).unwrap()
    }

    #[test]
    fn nmt_command_and_target() {
        assert_eq!(text(0x000, &[0x01, 0x05]), "NMT start → node 5");
        assert_eq!(text(0x000, &[0x81, 0x00]), "NMT reset node → all nodes");
        assert_eq!(text(0x000, &[0x99, 0x05]), "NMT malformed: [99 05]");
    }

    #[test]
    fn sync_with_and_without_counter() {
        assert_eq!(text(0x080, &[]), "SYNC");
        assert_eq!(text(0x080, &[7]), "SYNC counter 7");
    }

    #[test]
    fn emcy_code_and_register() {
        // Code 0x8130 (life guard error or heartbeat error), register 0x11.
        assert_eq!(
            text(0x085, &[0x30, 0x81, 0x11, 0, 0, 0, 0, 0]),
            format!(
                "EMCY node 5: 0x8130 {}, error register 0x11",
                crate::emcy::error_code_name(0x8130)
            )
        );
        assert_eq!(text(0x085, &[0; 8]), "EMCY node 5: error reset");
        assert_eq!(text(0x085, &[1, 2]), "EMCY node 5 malformed: [01 02]");
    }

    #[test]
    fn time_of_day() {
        // 1000 ms after midnight of day 2.
        assert_eq!(
            text(0x100, &[0xE8, 0x03, 0, 0, 0x02, 0x00]),
            "TIME day 2 since 1984-01-01, 1000 ms after midnight"
        );
    }

    #[test]
    fn pdo_cob_id_and_bytes() {
        assert_eq!(text(0x185, &[1, 2, 3]), "TPDO1 node 5 (0x185): [01 02 03]");
        assert_eq!(text(0x30A, &[0xFF]), "RPDO2 node 10 (0x30A): [FF]");
        let rtr = Frame::new_remote(CanId::Standard(0x285), 8).unwrap();
        assert_eq!(
            describe(&rtr).unwrap(),
            "TPDO2 node 5 (0x285) remote request"
        );
    }

    #[test]
    fn sdo_upload_request() {
        assert_eq!(
            text(0x605, &[0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]),
            "SDO upload request 0x1000:00 to node 5"
        );
    }

    #[test]
    fn sdo_expedited_transfers() {
        // Upload response, 4 bytes (n = 0): device type 0x00020192.
        assert_eq!(
            text(0x585, &[0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00]),
            "SDO upload response 0x1000:00 from node 5 (expedited): [92 01 02 00]"
        );
        // Download request, 2 bytes (n = 2): 0x6040:00 = 0x000F.
        assert_eq!(
            text(0x601, &[0x2B, 0x40, 0x60, 0x00, 0x0F, 0x00, 0, 0]),
            "SDO download request 0x6040:00 to node 1 (expedited): [0F 00]"
        );
        assert_eq!(
            text(0x581, &[0x60, 0x40, 0x60, 0x00, 0, 0, 0, 0]),
            "SDO download response 0x6040:00 from node 1"
        );
    }

    #[test]
    fn sdo_segmented_transfers() {
        assert_eq!(
            text(0x585, &[0x41, 0x08, 0x10, 0x00, 0x0B, 0, 0, 0]),
            "SDO upload response 0x1008:00 from node 5: 11 bytes follow"
        );
        assert_eq!(
            text(0x605, &[0x60, 0, 0, 0, 0, 0, 0, 0]),
            "SDO upload segment request to node 5: toggle 0"
        );
        // Last segment (c = 1), 4 unused bytes (n = 4), toggle 1.
        assert_eq!(
            text(0x585, &[0x19, b'a', b'b', b'c', 0, 0, 0, 0]),
            "SDO upload segment from node 5: toggle 1, last, [61 62 63]"
        );
        assert_eq!(
            text(0x605, &[0x00, 1, 2, 3, 4, 5, 6, 7]),
            "SDO download segment to node 5: toggle 0, [01 02 03 04 05 06 07]"
        );
    }

    #[test]
    fn sdo_abort_with_its_cia_name() {
        assert_eq!(
            text(0x585, &[0x80, 0x00, 0x20, 0x01, 0x00, 0x00, 0x02, 0x06]),
            "SDO abort 0x2000:01 from node 5: 0x06020000 object does not exist in the object \
             dictionary"
        );
        assert_eq!(
            text(0x605, &[0x80, 0x00, 0x10, 0x00, 0x00, 0x00, 0x04, 0x05]),
            format!(
                "SDO abort 0x1000:00 to node 5: 0x05040000 {}",
                AbortCode::from(0x0504_0000).name()
            )
        );
        assert_eq!(
            text(0x585, &[0x80, 0x00]),
            "SDO abort from node 5 malformed: [80 00]"
        );
    }

    #[test]
    fn sdo_block_transfers() {
        assert_eq!(
            text(0x605, &[0xC6, 0x00, 0x1F, 0x00, 0x10, 0, 0, 0]),
            "SDO block download request 0x1F00:00 to node 5"
        );
        assert_eq!(
            text(0x585, &[0xA2, 0x05, 0x7F, 0, 0, 0, 0, 0]),
            "SDO block download acknowledge from node 5: sequence 5, block size 127"
        );
        assert_eq!(
            text(0x605, &[0xA3, 0, 0, 0, 0, 0, 0, 0]),
            "SDO block upload start to node 5"
        );
    }

    #[test]
    fn heartbeat_boot_up_and_guarding() {
        assert_eq!(text(0x705, &[0x00]), "boot-up node 5");
        assert_eq!(text(0x705, &[0x05]), "heartbeat node 5: operational");
        assert_eq!(text(0x705, &[0x7F]), "heartbeat node 5: pre-operational");
        assert_eq!(
            text(0x705, &[0x85]),
            "node guarding node 5: operational (toggle 1)"
        );
        let rtr = Frame::new_remote(CanId::Standard(0x705), 1).unwrap();
        assert_eq!(describe(&rtr).unwrap(), "node guarding request to node 5");
    }

    #[test]
    fn lss_requests_and_answers() {
        assert_eq!(
            text(0x7E5, &[0x04, 0x01, 0, 0, 0, 0, 0, 0]),
            "LSS request: switch state global: configuration"
        );
        assert_eq!(
            text(0x7E5, &[0x11, 0x0A, 0, 0, 0, 0, 0, 0]),
            "LSS request: configure node-ID: 10"
        );
        assert_eq!(
            text(0x7E4, &[0x11, 0x00, 0, 0, 0, 0, 0, 0]),
            "LSS answer: configure node-ID: error code 0"
        );
        assert_eq!(
            text(0x7E4, &[0x5A, 0x78, 0x56, 0x34, 0x12, 0, 0, 0]),
            "LSS answer: inquire vendor-ID: 0x12345678"
        );
    }

    #[test]
    fn frames_outside_the_predefined_set_have_no_words() {
        assert_eq!(describe(&frame(0x7E0, &[1])), None);
        let ext = Frame::new(CanId::Extended(0x605), &[0x40, 0, 0x10, 0]).unwrap();
        assert_eq!(describe(&ext), None);
    }
}
