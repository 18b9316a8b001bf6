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

use cangate_canopen::NodeId;
use cangate_canopen::ObjectAddress;
use cangate_canopen::ds402::objects as obj;
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
    ];
    let mut frames: Vec<(bool, u16, Vec<u8>)> = Vec::new();
    for p in rpdos {
        let relevant = p
            .mapping
            .iter()
            .any(|m| values.iter().any(|(a, _)| *a == m.addr));
        if !relevant {
            continue;
        }
        let has_cw = p.mapping.iter().any(|m| m.addr == obj::CONTROLWORD);
        frames.push((has_cw, p.cob_id, p.encode(&values)?));
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
        match addr {
            a if a == obj::STATUSWORD => fb.statusword = i.map(|x| x as u16),
            a if a == obj::POSITION_ACTUAL => fb.position = i.map(|x| x as i32),
            a if a == obj::VELOCITY_ACTUAL => fb.velocity = i.map(|x| x as i32),
            a if a == obj::MODES_OF_OPERATION_DISPLAY => fb.mode_display = i.map(|x| x as i8),
            a if a == obj::FOLLOWING_ERROR_ACTUAL => fb.following_error = i.map(|x| x as i32),
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
        let a = m.addr;
        let known = a == obj::STATUSWORD
            || a == obj::POSITION_ACTUAL
            || a == obj::VELOCITY_ACTUAL
            || a == obj::MODES_OF_OPERATION_DISPLAY
            || a == obj::FOLLOWING_ERROR_ACTUAL;
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
            _ => fb.following_error = Some(signed as i32),
        }
    }
    Ok(fb)
}

#[cfg(test)]
mod tests {
    use super::*;

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
                following_error: None
            }
        );
    }

    #[test]
    fn feedback_from_pdo_matches_the_generic_decode() {
        let node = NodeId::new(3).unwrap();
        let (_, tpdos) = standard_pdos(node, FeedbackTrigger::Sync);
        let eds = cangate_canopen::eds::Eds::parse(cangate_canopen::eds::SIM_DRIVE_EDS)
            .expect("bundled drive EDS");
        let od = &eds.od;
        let payloads: [&[u8]; 4] = [
            &[0x37, 0x12, 0xFB, 0xFF, 0xFF, 0xFF, 0x08],
            &[0x27, 0x06, 0x10, 0x27, 0x00, 0x00, 0xFF],
            &[0x00, 0x80, 0x00, 0x00, 0x00, 0x80, 0x01],
            &[0x7F, 0x00, 0x00, 0xFF],
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
}
