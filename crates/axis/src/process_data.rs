//! The process data of a CiA 402 axis: which objects go in which PDO, and
//! the conversion between PDO values and [`ProcessImage`] / [`Feedback`].
//!
//! The standard layout the gateway writes to a drive at boot:
//!
//! | PDO | COB-ID | objects | transmission |
//! |---|---|---|---|
//! | RPDO1 | 0x200 + node | controlword 0x6040 (16), modes of operation 0x6060 (8) | event-driven (255): applied on receipt |
//! | RPDO2 | 0x300 + node | target position 0x607A (32), target velocity 0x60FF (32) | event-driven (255) |
//! | TPDO1 | 0x180 + node | statusword 0x6041 (16), position actual 0x6064 (32), modes of operation display 0x6061 (8) | every SYNC (1), or event-driven with an event timer without SYNC |
//! | TPDO2 | 0x280 + node | velocity actual 0x606C (32) | as TPDO1 |
//!
//! RPDO2 is sent before RPDO1 so a new set-point bit never arrives before
//! its target.
//!
//! The SDO fallback (`process_data = "sdo"`, profile position axes only):
//! no PDO is configured; the runtime reads [`SDO_FEEDBACK_OBJECTS`] by SDO
//! every poll period ([`feedback_from_sdo`]) and writes each changed
//! process image object by SDO, the controlword last ([`sdo_image_writes`]).

use cangate_canopen::NodeId;
use cangate_canopen::ObjectAddress;
use cangate_canopen::cia402::{MAX_DRIVE_AXES, axis_of, first_axis, objects as obj, on_axis};
use cangate_canopen::pdo::{MappedObject, PdoConfig, PdoError, PdoKind};
use cangate_canopen::value::Value;

use crate::cia402::{Feedback, ProcessImage};

/// How the drive's TPDOs are triggered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FeedbackTrigger {
    /// Every SYNC (transmission type 1).
    Sync,
    /// On change, and at least every `event_timer_ms` (type 255).
    Event {
        /// Event timer in ms.
        event_timer_ms: u16,
    },
}

fn pdo(
    kind: PdoKind,
    num: u16,
    node: NodeId,
    ty: u8,
    timer: u16,
    map: &[(ObjectAddress, u8)],
) -> PdoConfig {
    PdoConfig {
        kind,
        num,
        cob_id: kind
            .default_cob_id(num, node)
            .expect("PDO 1..=4 have default COB-IDs"),
        transmission_type: ty,
        inhibit_time: 0,
        event_timer_ms: timer,
        mapping: map
            .iter()
            .map(|&(addr, bits)| MappedObject { addr, bits })
            .collect(),
    }
}

/// The RPDOs (first) and TPDOs of the standard layout.
pub fn standard_pdos(node: NodeId, trigger: FeedbackTrigger) -> (Vec<PdoConfig>, Vec<PdoConfig>) {
    let (ty, timer) = match trigger {
        FeedbackTrigger::Sync => (1, 0),
        FeedbackTrigger::Event { event_timer_ms } => (255, event_timer_ms),
    };
    let rpdos = vec![
        pdo(
            PdoKind::Rpdo,
            1,
            node,
            255,
            0,
            &[(obj::CONTROLWORD, 16), (obj::MODES_OF_OPERATION, 8)],
        ),
        pdo(
            PdoKind::Rpdo,
            2,
            node,
            255,
            0,
            &[(obj::TARGET_POSITION, 32), (obj::TARGET_VELOCITY, 32)],
        ),
    ];
    let tpdos = vec![
        pdo(
            PdoKind::Tpdo,
            1,
            node,
            ty,
            timer,
            &[
                (obj::STATUSWORD, 16),
                (obj::POSITION_ACTUAL, 32),
                (obj::MODES_OF_OPERATION_DISPLAY, 8),
            ],
        ),
        pdo(
            PdoKind::Tpdo,
            2,
            node,
            ty,
            timer,
            &[(obj::VELOCITY_ACTUAL, 32)],
        ),
    ];
    (rpdos, tpdos)
}

/// The signal objects a drive's TPDOs may carry beyond the standard
/// layout (CiA 402-2): torque actual, digital inputs, touch probe status
/// and probe 1's latched positions. Following error actual (0x60F4) is
/// decoded too (see [`with_signal_tpdos`]).
pub const SIGNAL_OBJECTS: [ObjectAddress; 5] = [
    obj::TORQUE_ACTUAL,
    obj::DIGITAL_INPUTS,
    obj::TOUCH_PROBE_STATUS,
    obj::TOUCH_PROBE_1_POSITIVE,
    obj::TOUCH_PROBE_1_NEGATIVE,
];

/// Adds the signals to the standard layout's TPDOs (`tpdos`, from
/// [`standard_pdos`]), as far as the drive has them: `mappable` says
/// whether the drive has an object and lets it be mapped into a PDO,
/// `has_tpdo(n)` whether it has TPDO `n` (its communication and mapping
/// parameters). Each PDO stays within 8 bytes:
///
/// | PDO | COB-ID | objects added |
/// |---|---|---|
/// | TPDO2 | 0x280 + node | following error actual 0x60F4 (32), after the velocity |
/// | TPDO3 | 0x380 + node | torque actual 0x6077 (16), digital inputs 0x60FD (32), touch probe status 0x60B9 (16) |
/// | TPDO4 | 0x480 + node | touch probe 1 positive edge 0x60BA (32), negative edge 0x60BB (32) |
///
/// Transmitted like the others (every SYNC, or event-driven with the same
/// timer): one SYNC's TPDOs make one axis status. An object the drive
/// lacks is left out (the signal stays absent); a TPDO left with nothing
/// is not configured.
pub fn with_signal_tpdos(
    tpdos: &mut Vec<PdoConfig>,
    node: NodeId,
    trigger: FeedbackTrigger,
    mappable: impl Fn(ObjectAddress) -> bool,
    has_tpdo: impl Fn(u16) -> bool,
) {
    let (ty, timer) = match trigger {
        FeedbackTrigger::Sync => (1, 0),
        FeedbackTrigger::Event { event_timer_ms } => (255, event_timer_ms),
    };
    if mappable(obj::FOLLOWING_ERROR_ACTUAL)
        && let Some(tpdo2) = tpdos
            .iter_mut()
            .find(|p| p.num == 2 && p.kind == PdoKind::Tpdo)
        && tpdo2.len() + 4 <= 8
    {
        tpdo2.mapping.push(MappedObject {
            addr: obj::FOLLOWING_ERROR_ACTUAL,
            bits: 32,
        });
    }
    let layouts: [(u16, &[(ObjectAddress, u8)]); 2] = [
        (
            3,
            &[
                (obj::TORQUE_ACTUAL, 16),
                (obj::DIGITAL_INPUTS, 32),
                (obj::TOUCH_PROBE_STATUS, 16),
            ],
        ),
        (
            4,
            &[
                (obj::TOUCH_PROBE_1_POSITIVE, 32),
                (obj::TOUCH_PROBE_1_NEGATIVE, 32),
            ],
        ),
    ];
    for (num, map) in layouts {
        if !has_tpdo(num) || tpdos.iter().any(|p| p.num == num) {
            continue;
        }
        let present: Vec<(ObjectAddress, u8)> =
            map.iter().copied().filter(|(a, _)| mappable(*a)).collect();
        if !present.is_empty() {
            tpdos.push(pdo(PdoKind::Tpdo, num, node, ty, timer, &present));
        }
    }
}

/// RPDO3 of an axis not in a torque mode whose drive has a velocity
/// offset: the feed-forward of a position stream, velocity offset 0x60B1
/// (32 bits) and, with `torque`, torque offset 0x60B2 (16 bits): 6 bytes at
/// most, beside the CSP set-point RPDO (RPDO2, whose 8 bytes the target
/// position and velocity fill). Event-driven (255), as the set-point
/// RPDOs: sent with every SYNC of a stream.
pub fn feed_forward_rpdo(node: NodeId, torque: bool) -> PdoConfig {
    let mut map = vec![(obj::VELOCITY_OFFSET, 32)];
    if torque {
        map.push((obj::TORQUE_OFFSET, 16));
    }
    pdo(PdoKind::Rpdo, 3, node, 255, 0, &map)
}

/// RPDO3 of an axis in a torque mode: target torque 0x6071 (16 bits),
/// event-driven (255): the drive applies a torque set-point on receipt and
/// holds it. Mapped besides the standard layout for an axis configured in
/// a torque mode (`mode = "cst"` or `"profile_torque"`).
pub fn torque_rpdo(node: NodeId) -> PdoConfig {
    pdo(PdoKind::Rpdo, 3, node, 255, 0, &[(obj::TARGET_TORQUE, 16)])
}

/// RPDO2 of an interpolated position axis (a drive without CSP):
/// interpolation data record 0x60C1:01 (32) where the standard layout has
/// the target position, and the target velocity 0x60FF (32); event-driven
/// (255).
pub fn interpolated_rpdo(node: NodeId) -> PdoConfig {
    pdo(
        PdoKind::Rpdo,
        2,
        node,
        255,
        0,
        &[(obj::INTERPOLATION_DATA, 32), (obj::TARGET_VELOCITY, 32)],
    )
}

/// The interpolation time period 0x60C2 (value 0x60C2:01, index
/// 0x60C2:02: value · 10^index s) of a SYNC period, as exact as an
/// 8-bit value allows.
pub fn interpolation_period(period: std::time::Duration) -> (u8, i8) {
    let us = period.as_micros();
    for (div, index) in [(1000, -3), (100, -4), (10, -5), (1, -6)] {
        if us.is_multiple_of(div) && us / div <= 255 {
            return ((us / div) as u8, index);
        }
    }
    ((us / 1000).min(255) as u8, -3)
}

/// PDO numbers one axis of a multi-axis drive takes: axis `n` has PDOs
/// 4n + 1 ..= 4n + 4 (RPDO and TPDO each), the first axis the standard
/// layout's 1..=4.
pub const PDOS_PER_AXIS: u16 = 4;

/// The first COB-ID of the PDOs of further axes (axis 1..=7 of a drive
/// node): the predefined connection set (CiA 301) gives each node-ID only
/// PDOs 1..=4, so these take blocks of eight from the range CiA 301 leaves
/// free for PDOs, 0x680..=0x6DF: RPDO n of a block at block + n − 1, TPDO
/// n at block + 4 + n − 1.
pub const FURTHER_AXIS_COB_BASE: u16 = 0x680;

/// Blocks of eight COB-IDs in 0x680..=0x6DF: further axes one bus can
/// have.
pub const FURTHER_AXIS_BLOCKS: u16 = 12;

/// The COB-ID of PDO `num` (1..=4 within its axis) of kind `kind` in
/// further-axis block `block` (0..12, see [`FURTHER_AXIS_COB_BASE`]).
pub fn further_axis_cob_id(kind: PdoKind, num: u16, block: u16) -> u16 {
    let base = FURTHER_AXIS_COB_BASE + 8 * block;
    match kind {
        PdoKind::Rpdo => base + num - 1,
        PdoKind::Tpdo => base + 4 + num - 1,
    }
}

/// Moves a layout of the first axis (from [`standard_pdos`] and friends)
/// to axis `drive_axis` of the drive: PDO `n` becomes `n` + 4 ×
/// `drive_axis`, every mapped profile object the same object of that axis
/// (index + 0x800 × `drive_axis`), and the COB-IDs those of further-axis
/// block `block` ([`further_axis_cob_id`]). Axis 0 stays as it is.
pub fn relocate_to_axis(pdos: &mut [PdoConfig], drive_axis: u8, block: u16) {
    if drive_axis == 0 {
        return;
    }
    for p in pdos {
        let num = p.num;
        p.cob_id = further_axis_cob_id(p.kind, num, block);
        p.num = num + PDOS_PER_AXIS * u16::from(drive_axis);
        for m in &mut p.mapping {
            m.addr = on_axis(m.addr, drive_axis);
        }
    }
}

/// The drive axis whose objects PDO `p` maps: that of its first profile
/// object (a PDO of the axis layout maps one axis's objects only); `None`
/// when it maps none.
pub fn pdo_drive_axis(p: &PdoConfig) -> Option<u8> {
    p.mapping
        .iter()
        .find_map(|m| axis_of(m.addr))
        .map(|(axis, _)| axis)
        .filter(|a| *a < MAX_DRIVE_AXES)
}

/// The RPDO frames (COB-ID, payload) carrying `image`, for every RPDO that
/// maps at least one image object, those without the controlword first.
///
/// # Errors
/// A [`PdoError`] when an RPDO maps an object the image does not hold.
pub fn encode_image(
    image: &ProcessImage,
    rpdos: &[PdoConfig],
) -> Result<Vec<(u16, Vec<u8>)>, PdoError> {
    let values = [
        (obj::CONTROLWORD, Value::Unsigned16(image.controlword)),
        (obj::MODES_OF_OPERATION, Value::Integer8(image.mode)),
        (
            obj::TARGET_POSITION,
            Value::Integer32(image.target_position),
        ),
        (
            obj::TARGET_VELOCITY,
            Value::Integer32(image.target_velocity),
        ),
        (obj::TARGET_TORQUE, Value::Integer16(image.target_torque)),
        // An interpolated position axis: the position set-point.
        (
            obj::INTERPOLATION_DATA,
            Value::Integer32(image.target_position),
        ),
    ];
    let mut frames: Vec<(bool, u16, Vec<u8>)> = Vec::new();
    for p in rpdos {
        let relevant = p
            .mapping
            .iter()
            .any(|m| values.iter().any(|(a, _)| *a == first_axis(m.addr)));
        if !relevant {
            continue;
        }
        let has_cw = p
            .mapping
            .iter()
            .any(|m| first_axis(m.addr) == obj::CONTROLWORD);
        // The objects of the drive axis the PDO maps.
        let axis = pdo_drive_axis(p).unwrap_or(0);
        let on_its_axis = values.clone().map(|(a, v)| (on_axis(a, axis), v));
        frames.push((has_cw, p.cob_id, p.encode(&on_its_axis)?));
    }
    frames.sort_by_key(|(cw, _, _)| *cw);
    Ok(frames.into_iter().map(|(_, c, d)| (c, d)).collect())
}

/// The feedback in a set of decoded PDO values (any mapping).
pub fn feedback_from_values<'a>(
    values: impl IntoIterator<Item = (ObjectAddress, &'a Value)>,
) -> Feedback {
    let mut fb = Feedback::default();
    for (addr, v) in values {
        let i = v.as_i128();
        match first_axis(addr) {
            a if a == obj::STATUSWORD => fb.statusword = i.map(|x| x as u16),
            a if a == obj::POSITION_ACTUAL => fb.position = i.map(|x| x as i32),
            a if a == obj::VELOCITY_ACTUAL => fb.velocity = i.map(|x| x as i32),
            a if a == obj::MODES_OF_OPERATION_DISPLAY => fb.mode_display = i.map(|x| x as i8),
            a if a == obj::FOLLOWING_ERROR_ACTUAL => fb.following_error = i.map(|x| x as i32),
            a if a == obj::TORQUE_ACTUAL => fb.torque = i.map(|x| x as i16),
            a if a == obj::DIGITAL_INPUTS => fb.digital_inputs = i.map(|x| x as u32),
            a if a == obj::TOUCH_PROBE_STATUS => fb.touch_probe_status = i.map(|x| x as u16),
            a if a == obj::TOUCH_PROBE_1_POSITIVE => fb.touch_probe_positive = i.map(|x| x as i32),
            a if a == obj::TOUCH_PROBE_1_NEGATIVE => fb.touch_probe_negative = i.map(|x| x as i32),
            _ => {}
        }
    }
    fb
}

/// The feedback carried by one received TPDO payload, read straight from
/// its mapping: no intermediate [`Value`]s and no allocation, because the
/// axis runtime does this for every TPDO of every drive (thousands a
/// second). Gives the same result as [`PdoConfig::decode`] followed by
/// [`feedback_from_values`] with a CiA 402 object dictionary: the signed
/// objects (positions, velocity, mode display) are sign-extended from their
/// mapped length, the statusword is not.
///
/// # Errors
/// [`PdoError::ShortPayload`] when `data` is shorter than the mapping.
pub fn feedback_from_pdo(cfg: &PdoConfig, data: &[u8]) -> Result<Feedback, PdoError> {
    let need = cfg.len();
    if data.len() < need {
        return Err(PdoError::ShortPayload {
            need,
            got: data.len(),
        });
    }
    let mut fb = Feedback::default();
    let mut at = 0;
    for m in &cfg.mapping {
        let n = m.bits as usize / 8;
        let bytes = &data[at..at + n];
        at += n;
        let a = first_axis(m.addr);
        let known = a == obj::STATUSWORD
            || a == obj::POSITION_ACTUAL
            || a == obj::VELOCITY_ACTUAL
            || a == obj::MODES_OF_OPERATION_DISPLAY
            || a == obj::FOLLOWING_ERROR_ACTUAL
            || SIGNAL_OBJECTS.contains(&a);
        if !known {
            continue;
        }
        // At most 64 bits fit a classic PDO; anything else is not a value
        // of these objects.
        if n == 0 || n > 8 {
            return Err(PdoError::TooLong(u32::from(m.bits)));
        }
        let mut raw = [0u8; 8];
        raw[..n].copy_from_slice(bytes);
        let unsigned = u64::from_le_bytes(raw);
        let shift = 64 - 8 * n as u32;
        let signed = ((unsigned << shift) as i64) >> shift;
        match a {
            a if a == obj::STATUSWORD => fb.statusword = Some(unsigned as u16),
            a if a == obj::POSITION_ACTUAL => fb.position = Some(signed as i32),
            a if a == obj::VELOCITY_ACTUAL => fb.velocity = Some(signed as i32),
            a if a == obj::MODES_OF_OPERATION_DISPLAY => fb.mode_display = Some(signed as i8),
            a if a == obj::TORQUE_ACTUAL => fb.torque = Some(signed as i16),
            a if a == obj::DIGITAL_INPUTS => fb.digital_inputs = Some(unsigned as u32),
            a if a == obj::TOUCH_PROBE_STATUS => fb.touch_probe_status = Some(unsigned as u16),
            a if a == obj::TOUCH_PROBE_1_POSITIVE => fb.touch_probe_positive = Some(signed as i32),
            a if a == obj::TOUCH_PROBE_1_NEGATIVE => fb.touch_probe_negative = Some(signed as i32),
            _ => fb.following_error = Some(signed as i32),
        }
    }
    Ok(fb)
}

/// The objects a drive's feedback is read from when its process data goes
/// by SDO (`process_data = "sdo"`, for drives or buses without usable
/// PDOs), in the order one poll reads them.
pub const SDO_FEEDBACK_OBJECTS: [ObjectAddress; 4] = [
    obj::STATUSWORD,
    obj::POSITION_ACTUAL,
    obj::VELOCITY_ACTUAL,
    obj::MODES_OF_OPERATION_DISPLAY,
];

/// [`SDO_FEEDBACK_OBJECTS`] of axis `drive_axis` of the drive.
pub fn sdo_feedback_objects(drive_axis: u8) -> [ObjectAddress; 4] {
    SDO_FEEDBACK_OBJECTS.map(|a| on_axis(a, drive_axis))
}

/// An SDO upload of a feedback object that does not hold a value of the
/// object's CiA 402 type.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{addr} answered {got} bytes; CiA 402 defines it as {need} bytes")]
pub struct SdoFeedbackError {
    /// The object.
    pub addr: ObjectAddress,
    /// Bytes its type has.
    pub need: usize,
    /// Bytes the drive sent.
    pub got: usize,
}

/// The feedback in one SDO poll: `uploads` are the payloads of
/// [`SDO_FEEDBACK_OBJECTS`], in that order.
///
/// # Errors
/// [`SdoFeedbackError`] when a payload has the wrong length (a drive that
/// maps these objects differently is not a CiA 402 drive we can run).
pub fn feedback_from_sdo(uploads: &[Vec<u8>; 4]) -> Result<Feedback, SdoFeedbackError> {
    fn exact<const N: usize>(
        addr: ObjectAddress,
        data: &[u8],
    ) -> Result<[u8; N], SdoFeedbackError> {
        // An expedited upload without size indication brings all 4 bytes
        // (CiA 301 leaves the unused ones undefined): the value is the
        // first N.
        let data = if data.len() == 4 && N < 4 {
            &data[..N]
        } else {
            data
        };
        data.try_into().map_err(|_| SdoFeedbackError {
            addr,
            need: N,
            got: data.len(),
        })
    }
    let [sw, pos, vel, mode] = SDO_FEEDBACK_OBJECTS;
    Ok(Feedback {
        statusword: Some(u16::from_le_bytes(exact(sw, &uploads[0])?)),
        position: Some(i32::from_le_bytes(exact(pos, &uploads[1])?)),
        velocity: Some(i32::from_le_bytes(exact(vel, &uploads[2])?)),
        mode_display: Some(i8::from_le_bytes(exact(mode, &uploads[3])?)),
        ..Feedback::default()
    })
}

/// The SDO writes that bring a drive from `last` (what was written before;
/// `None`: unknown, write everything) to `image`: only the objects that
/// changed, the targets and the mode before the controlword, so a
/// new-set-point or enable edge never acts on a stale target or mode (the
/// same order [`encode_image`] gives the RPDOs).
///
/// The objects are those of axis `drive_axis` of the drive
/// ([`cangate_canopen::cia402::profile_index`]).
pub fn sdo_image_writes(
    drive_axis: u8,
    last: Option<&ProcessImage>,
    image: &ProcessImage,
) -> Vec<(ObjectAddress, Vec<u8>)> {
    let mut writes = first_axis_image_writes(last, image);
    for (addr, _) in &mut writes {
        *addr = on_axis(*addr, drive_axis);
    }
    writes
}

fn first_axis_image_writes(
    last: Option<&ProcessImage>,
    image: &ProcessImage,
) -> Vec<(ObjectAddress, Vec<u8>)> {
    let changed = |f: fn(&ProcessImage) -> i64| last.is_none_or(|l| f(l) != f(image));
    let mut writes = Vec::with_capacity(4);
    if changed(|i| i64::from(i.target_position)) {
        writes.push((
            obj::TARGET_POSITION,
            image.target_position.to_le_bytes().to_vec(),
        ));
    }
    if changed(|i| i64::from(i.target_velocity)) {
        writes.push((
            obj::TARGET_VELOCITY,
            image.target_velocity.to_le_bytes().to_vec(),
        ));
    }
    // Only a torque set-point other than 0 is ever written: a drive
    // without 0x6071 (every axis but a torque mode's) never sees one.
    if last.map_or(0, |l| l.target_torque) != image.target_torque {
        writes.push((
            obj::TARGET_TORQUE,
            image.target_torque.to_le_bytes().to_vec(),
        ));
    }
    if changed(|i| i64::from(i.mode)) {
        writes.push((obj::MODES_OF_OPERATION, image.mode.to_le_bytes().to_vec()));
    }
    if changed(|i| i64::from(i.controlword)) {
        writes.push((obj::CONTROLWORD, image.controlword.to_le_bytes().to_vec()));
    }
    writes
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Axis 1 of a two-axis drive at node 5: PDOs 5.., COB-IDs of the
    /// first further-axis block (0x680..), its objects at + 0x800.
    #[test]
    fn a_second_drive_axis_gets_its_own_pdos_objects_and_exact_bytes() {
        let node = NodeId::new(5).unwrap();
        let (mut rpdos, mut tpdos) = standard_pdos(node, FeedbackTrigger::Sync);
        relocate_to_axis(&mut rpdos, 1, 0);
        relocate_to_axis(&mut tpdos, 1, 0);
        let nums: Vec<(u16, u16)> = rpdos
            .iter()
            .chain(&tpdos)
            .map(|p| (p.num, p.cob_id))
            .collect();
        assert_eq!(nums, [(5, 0x680), (6, 0x681), (5, 0x684), (6, 0x685)]);
        assert_eq!(pdo_drive_axis(&rpdos[0]), Some(1));
        // RPDO5's mapping as written at boot: 0x1604:01 = 0x68400010.
        let writes = rpdos[0].sdo_writes().unwrap();
        assert!(
            writes.contains(&(ObjectAddress::new(0x1604, 1), vec![0x10, 0x00, 0x40, 0x68])),
            "{writes:?}"
        );
        assert!(
            writes.contains(&(ObjectAddress::new(0x1604, 2), vec![0x08, 0x00, 0x60, 0x68])),
            "{writes:?}"
        );
        let image = ProcessImage {
            controlword: 0x000F,
            mode: 8,
            target_position: 1000,
            target_velocity: 0,
            target_torque: 0,
        };
        assert_eq!(
            encode_image(&image, &rpdos).unwrap(),
            vec![
                (0x681, vec![0xE8, 0x03, 0, 0, 0, 0, 0, 0]),
                (0x680, vec![0x0F, 0x00, 0x08]),
            ]
        );
        // TPDO5: statusword 0x6841, position 0x6864, mode display 0x6861.
        let fb = feedback_from_pdo(&tpdos[0], &[0x37, 0x02, 0x10, 0x27, 0, 0, 8]).unwrap();
        assert_eq!(
            (fb.statusword, fb.position, fb.mode_display),
            (Some(0x0237), Some(10_000), Some(8))
        );
        // The SDO fallback writes the controlword to 0x6840: an expedited
        // download of 2 bytes, 2B 40 68 00 0F 00 00 00 on 0x605.
        let writes = sdo_image_writes(1, None, &image);
        let (addr, data) = writes.last().unwrap().clone();
        assert_eq!(addr, ObjectAddress::new(0x6840, 0));
        let mut client = cangate_canopen::sdo::SdoClient::new(node);
        let frames = client
            .start_download(
                addr,
                data,
                cangate_canopen::sdo::TransferOptions::default(),
                std::time::Duration::ZERO,
            )
            .unwrap();
        assert_eq!(frames[0].raw_id(), 0x605);
        assert_eq!(
            frames[0].data(),
            [0x2B, 0x40, 0x68, 0x00, 0x0F, 0x00, 0x00, 0x00]
        );
        assert_eq!(sdo_feedback_objects(1)[0], ObjectAddress::new(0x6841, 0));
    }

    #[test]
    fn image_goes_out_target_first_with_exact_bytes() {
        let node = NodeId::new(5).unwrap();
        let (rpdos, tpdos) = standard_pdos(node, FeedbackTrigger::Sync);
        assert_eq!(rpdos[0].cob_id, 0x205);
        assert_eq!(tpdos[0].cob_id, 0x185);
        assert_eq!(tpdos[0].transmission_type, 1);
        let image = ProcessImage {
            controlword: 0x003F,
            mode: 1,
            target_position: 10_000,
            target_velocity: -2,
            target_torque: 0,
        };
        let frames = encode_image(&image, &rpdos).unwrap();
        assert_eq!(
            frames,
            vec![
                (0x305, vec![0x10, 0x27, 0, 0, 0xFE, 0xFF, 0xFF, 0xFF]),
                (0x205, vec![0x3F, 0x00, 0x01]),
            ]
        );
    }

    #[test]
    fn feedback_from_decoded_values() {
        let values = [
            (obj::STATUSWORD, Value::Unsigned16(0x1237)),
            (obj::POSITION_ACTUAL, Value::Integer32(-5)),
            (obj::MODES_OF_OPERATION_DISPLAY, Value::Integer8(8)),
            (ObjectAddress::new(0x2000, 0), Value::Unsigned8(1)),
        ];
        let fb = feedback_from_values(values.iter().map(|(a, v)| (*a, v)));
        assert_eq!(
            fb,
            Feedback {
                statusword: Some(0x1237),
                position: Some(-5),
                velocity: None,
                mode_display: Some(8),
                ..Feedback::default()
            }
        );
    }

    #[test]
    fn feedback_from_pdo_matches_the_generic_decode() {
        let node = NodeId::new(3).unwrap();
        let (_, mut tpdos) = standard_pdos(node, FeedbackTrigger::Sync);
        with_signal_tpdos(&mut tpdos, node, FeedbackTrigger::Sync, |_| true, |_| true);
        let eds = cangate_canopen::eds::Eds::parse(cangate_canopen::eds::SIM_DRIVE_EDS)
            .expect("bundled drive EDS");
        let od = &eds.od;
        let payloads: [&[u8]; 5] = [
            &[0x37, 0x12, 0xFB, 0xFF, 0xFF, 0xFF, 0x08],
            &[0x27, 0x06, 0x10, 0x27, 0x00, 0x00, 0xFF],
            &[0x00, 0x80, 0x00, 0x00, 0x00, 0x80, 0x01],
            &[0x7F, 0x00, 0x00, 0xFF],
            &[0x9C, 0xFF, 0x05, 0, 0, 0x80, 0x03, 0x00],
        ];
        for p in &tpdos {
            for data in payloads {
                let generic = p
                    .decode(Some(od), data)
                    .map(|values| feedback_from_values(values.iter().map(|(m, v)| (m.addr, v))));
                let direct = feedback_from_pdo(p, data);
                match (generic, direct) {
                    (Ok(g), Ok(d)) => assert_eq!(g, d, "PDO {} payload {data:02X?}", p.num),
                    (Err(_), Err(_)) => {}
                    (g, d) => panic!("PDO {}: generic {g:?}, direct {d:?}", p.num),
                }
            }
        }
    }
    #[test]
    fn signal_tpdos_with_exact_mapping_writes() {
        let node = NodeId::new(5).unwrap();
        let (_, mut tpdos) = standard_pdos(node, FeedbackTrigger::Sync);
        with_signal_tpdos(&mut tpdos, node, FeedbackTrigger::Sync, |_| true, |_| true);
        let writes: Vec<Vec<(ObjectAddress, Vec<u8>)>> =
            tpdos.iter().map(|p| p.sdo_writes().unwrap()).collect();
        let w = |i: u16, s: u8, d: &[u8]| (ObjectAddress::new(i, s), d.to_vec());
        // TPDO2: velocity, then following error actual.
        assert_eq!(
            writes[1],
            vec![
                w(0x1801, 1, &[0x85, 0x02, 0x00, 0x80]),
                w(0x1801, 2, &[0x01]),
                w(0x1801, 3, &[0x00, 0x00]),
                w(0x1801, 5, &[0x00, 0x00]),
                w(0x1A01, 0, &[0x00]),
                w(0x1A01, 1, &[0x20, 0x00, 0x6C, 0x60]),
                w(0x1A01, 2, &[0x20, 0x00, 0xF4, 0x60]),
                w(0x1A01, 0, &[0x02]),
                w(0x1801, 1, &[0x85, 0x02, 0x00, 0x00]),
            ]
        );
        // TPDO3: torque, digital inputs, probe status (8 bytes).
        assert_eq!(
            writes[2],
            vec![
                w(0x1802, 1, &[0x85, 0x03, 0x00, 0x80]),
                w(0x1802, 2, &[0x01]),
                w(0x1802, 3, &[0x00, 0x00]),
                w(0x1802, 5, &[0x00, 0x00]),
                w(0x1A02, 0, &[0x00]),
                w(0x1A02, 1, &[0x10, 0x00, 0x77, 0x60]),
                w(0x1A02, 2, &[0x20, 0x00, 0xFD, 0x60]),
                w(0x1A02, 3, &[0x10, 0x00, 0xB9, 0x60]),
                w(0x1A02, 0, &[0x03]),
                w(0x1802, 1, &[0x85, 0x03, 0x00, 0x00]),
            ]
        );
        // TPDO4: probe 1's latched positions.
        assert_eq!(
            writes[3],
            vec![
                w(0x1803, 1, &[0x85, 0x04, 0x00, 0x80]),
                w(0x1803, 2, &[0x01]),
                w(0x1803, 3, &[0x00, 0x00]),
                w(0x1803, 5, &[0x00, 0x00]),
                w(0x1A03, 0, &[0x00]),
                w(0x1A03, 1, &[0x20, 0x00, 0xBA, 0x60]),
                w(0x1A03, 2, &[0x20, 0x00, 0xBB, 0x60]),
                w(0x1A03, 0, &[0x02]),
                w(0x1803, 1, &[0x85, 0x04, 0x00, 0x00]),
            ]
        );
        // The decode: TPDO3 and TPDO4 payloads.
        let fb = feedback_from_pdo(&tpdos[2], &[0x9C, 0xFF, 0x05, 0, 0, 0, 0x03, 0x00]).unwrap();
        assert_eq!(
            fb,
            Feedback {
                torque: Some(-100),
                digital_inputs: Some(5),
                touch_probe_status: Some(3),
                ..Feedback::default()
            }
        );
        let fb = feedback_from_pdo(&tpdos[3], &[0xDC, 0x05, 0, 0, 0xFF, 0xFF, 0xFF, 0xFF]).unwrap();
        assert_eq!(
            (fb.touch_probe_positive, fb.touch_probe_negative),
            (Some(1500), Some(-1))
        );
    }

    #[test]
    fn signal_tpdos_only_what_the_drive_has() {
        let node = NodeId::new(5).unwrap();
        let standard = standard_pdos(node, FeedbackTrigger::Sync).1;
        // A drive without any of them (or without TPDO3/4): the standard
        // layout unchanged.
        let mut tpdos = standard.clone();
        with_signal_tpdos(&mut tpdos, node, FeedbackTrigger::Sync, |_| false, |_| true);
        assert_eq!(tpdos, standard);
        let mut tpdos = standard.clone();
        with_signal_tpdos(
            &mut tpdos,
            node,
            FeedbackTrigger::Sync,
            |a| a == obj::DIGITAL_INPUTS || a == obj::TOUCH_PROBE_1_POSITIVE,
            |n| n == 3,
        );
        assert_eq!(tpdos.len(), 3);
        assert_eq!(tpdos[1], standard[1]);
        assert_eq!(tpdos[2].cob_id, 0x385);
        assert_eq!(
            tpdos[2].mapping,
            vec![MappedObject {
                addr: obj::DIGITAL_INPUTS,
                bits: 32
            }]
        );
    }

    #[test]
    fn sdo_image_writes_only_what_changed_controlword_last() {
        let image = ProcessImage {
            controlword: 0x001F,
            mode: 1,
            target_position: 10_000,
            target_velocity: -2,
            target_torque: 0,
        };
        // Nothing known: everything, targets and mode before the controlword.
        assert_eq!(
            sdo_image_writes(0, None, &image),
            vec![
                (obj::TARGET_POSITION, vec![0x10, 0x27, 0x00, 0x00]),
                (obj::TARGET_VELOCITY, vec![0xFE, 0xFF, 0xFF, 0xFF]),
                (obj::MODES_OF_OPERATION, vec![0x01]),
                (obj::CONTROLWORD, vec![0x1F, 0x00]),
            ]
        );
        assert!(sdo_image_writes(0, Some(&image), &image).is_empty());
        // A new set-point: the target, then the controlword edge.
        let next = ProcessImage {
            controlword: 0x003F,
            target_position: -1,
            ..image
        };
        assert_eq!(
            sdo_image_writes(0, Some(&image), &next),
            vec![
                (obj::TARGET_POSITION, vec![0xFF, 0xFF, 0xFF, 0xFF]),
                (obj::CONTROLWORD, vec![0x3F, 0x00]),
            ]
        );
        // Homing: the mode alone.
        let homing = ProcessImage { mode: 6, ..image };
        assert_eq!(
            sdo_image_writes(0, Some(&image), &homing),
            vec![(obj::MODES_OF_OPERATION, vec![0x06])]
        );
    }

    #[test]
    fn feedback_from_sdo_uploads_and_wrong_sizes() {
        let uploads = [
            vec![0x37, 0x16],
            vec![0xFB, 0xFF, 0xFF, 0xFF],
            vec![0x10, 0x27, 0x00, 0x00],
            vec![0xFA],
        ];
        assert_eq!(
            feedback_from_sdo(&uploads).unwrap(),
            Feedback {
                statusword: Some(0x1637),
                position: Some(-5),
                velocity: Some(10_000),
                mode_display: Some(-6),
                ..Feedback::default()
            }
        );
        // Expedited without size indication: 4 bytes, the value first.
        let mut unsized_ = uploads.clone();
        unsized_[0] = vec![0x37, 0x16, 0xAA, 0xBB];
        unsized_[3] = vec![0xFA, 0, 0, 0];
        assert_eq!(feedback_from_sdo(&unsized_), feedback_from_sdo(&uploads));
        let mut short = uploads.clone();
        short[1] = vec![0x01, 0x02];
        let e = feedback_from_sdo(&short).unwrap_err();
        assert_eq!(
            e,
            SdoFeedbackError {
                addr: obj::POSITION_ACTUAL,
                need: 4,
                got: 2
            }
        );
        assert!(e.to_string().contains("0x6064"), "{e}");
    }

    /// The feed-forward RPDO3 as written at boot (node 5): invalid, event
    /// driven, velocity offset 0x60B1 (32 bits) then torque offset 0x60B2
    /// (16 bits), valid at 0x405; 6 bytes. Never part of the image (the
    /// SYNC thread sends it).
    #[test]
    fn the_feed_forward_rpdo_maps_the_velocity_and_torque_offsets() {
        let node = NodeId::new(5).unwrap();
        let p = feed_forward_rpdo(node, true);
        assert_eq!(p.cob_id, 0x405);
        let w = |i: u16, s: u8, d: &[u8]| (ObjectAddress::new(i, s), d.to_vec());
        assert_eq!(
            p.sdo_writes().unwrap(),
            vec![
                w(0x1402, 1, &[0x05, 0x04, 0x00, 0x80]),
                w(0x1402, 2, &[0xFF]),
                w(0x1602, 0, &[0]),
                w(0x1602, 1, &[0x20, 0x00, 0xB1, 0x60]),
                w(0x1602, 2, &[0x10, 0x00, 0xB2, 0x60]),
                w(0x1602, 0, &[2]),
                w(0x1402, 1, &[0x05, 0x04, 0x00, 0x00]),
            ]
        );
        assert_eq!(feed_forward_rpdo(node, false).mapping.len(), 1);
        let image = ProcessImage::default();
        assert!(encode_image(&image, &[p]).unwrap().is_empty());
    }
}
