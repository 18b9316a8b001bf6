//! The signals of a CiA 402 drive beyond position and velocity: torque,
//! following error, digital inputs (limit and home switches) and touch
//! probe 1, and the supervision the gateway configures at boot (following
//! error window and time-out, max torque).
//!
//! Bit layouts (CiA 402-2, IEC 61800-7-201, objects 0x60FD, 0x60B8 and
//! 0x60B9; the same in ETG.6010 for CiA 402 over EtherCAT):
//!
//! | object | bit | meaning |
//! |---|---|---|
//! | 0x60FD digital inputs | 0 | negative limit switch |
//! | | 1 | positive limit switch |
//! | | 2 | home switch |
//! | | 3 | interlock; 16..=31 manufacturer-specific |
//! | 0x60B8 touch probe function | 0 | probe 1 enabled |
//! | | 1 | 0 = first event only, 1 = continuous |
//! | | 2..=3 | trigger source: 00 = the probe 1 input |
//! | | 4 | latch at the positive (rising) edge |
//! | | 5 | latch at the negative (falling) edge |
//! | 0x60B9 touch probe status | 0 | probe 1 enabled |
//! | | 1 | probe 1 positive edge position stored (0x60BA) |
//! | | 2 | probe 1 negative edge position stored (0x60BB) |

use std::time::Duration;

use cangate_canopen::ObjectAddress;
use cangate_canopen::cia402::objects as obj;

use crate::Units;

/// 0x60FD bit 0.
pub const NEGATIVE_LIMIT_SWITCH: u32 = 1 << 0;
/// 0x60FD bit 1.
pub const POSITIVE_LIMIT_SWITCH: u32 = 1 << 1;
/// 0x60FD bit 2.
pub const HOME_SWITCH: u32 = 1 << 2;

/// One of the two limit switches of a drive, named by the drive's
/// direction (a negative `counts_per_unit` turns the user's directions).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LimitSwitch {
    /// 0x60FD bit 0.
    Negative,
    /// 0x60FD bit 1.
    Positive,
}

impl LimitSwitch {
    /// "negative" or "positive".
    pub const fn name(self) -> &'static str {
        match self {
            LimitSwitch::Negative => "negative",
            LimitSwitch::Positive => "positive",
        }
    }

    /// The drive direction (counts) that runs into it: -1 or +1.
    pub const fn drive_direction(self) -> f64 {
        match self {
            LimitSwitch::Negative => -1.0,
            LimitSwitch::Positive => 1.0,
        }
    }

    /// What the axis status says while it is active.
    pub fn reached(self) -> String {
        format!("{} limit switch reached", self.name())
    }

    /// Whether a motion of `user_delta` (user units, any sign) heads into
    /// it on an axis with `units`.
    pub fn is_into(self, user_delta: f64, units: Units) -> bool {
        user_delta * units.counts_per_unit.signum() * self.drive_direction() > 0.0
    }
}

/// The drive's signals as its process data carries them; `None`: not
/// carried (the drive's PDOs do not map it, the process data goes by SDO,
/// or nothing arrived yet). Never filled in by the gateway.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DriveSignals {
    /// 0x6077 torque actual, per mille of rated torque.
    pub torque: Option<i16>,
    /// 0x60F4 following error actual, user units.
    pub following_error: Option<f64>,
    /// 0x60FD digital inputs, raw.
    pub digital_inputs: Option<u32>,
    /// 0x60B9 touch probe status, raw.
    pub touch_probe_status: Option<u16>,
}

impl DriveSignals {
    /// The active limit switch (the negative one when both are).
    pub fn limit_switch(&self) -> Option<LimitSwitch> {
        let bits = self.digital_inputs?;
        if bits & NEGATIVE_LIMIT_SWITCH != 0 {
            Some(LimitSwitch::Negative)
        } else if bits & POSITIVE_LIMIT_SWITCH != 0 {
            Some(LimitSwitch::Positive)
        } else {
            None
        }
    }

    /// Whether `switch` is active (false when the inputs are not carried).
    pub fn is_active(&self, switch: LimitSwitch) -> bool {
        let bit = match switch {
            LimitSwitch::Negative => NEGATIVE_LIMIT_SWITCH,
            LimitSwitch::Positive => POSITIVE_LIMIT_SWITCH,
        };
        self.digital_inputs.is_some_and(|b| b & bit != 0)
    }
}

/// Which edges of its input touch probe 1 latches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProbeEdges {
    /// The probe is switched off.
    Off,
    /// The rising (positive) edge.
    Rising,
    /// The falling (negative) edge.
    Falling,
    /// Both edges.
    Both,
}

/// The 0x60B8 value that arms touch probe 1 on its input for `edges`,
/// latching the first event only or, `continuous`, every one.
pub fn touch_probe_function(edges: ProbeEdges, continuous: bool) -> u16 {
    let edge_bits = match edges {
        ProbeEdges::Off => return 0,
        ProbeEdges::Rising => 0x10,
        ProbeEdges::Falling => 0x20,
        ProbeEdges::Both => 0x30,
    };
    0x01 | if continuous { 0x02 } else { 0 } | edge_bits
}

/// Turns touch probe 1's status and latched positions, as the process
/// data brings them, into latch events: an edge's position is reported
/// once its "stored" bit (0x60B9 bit 1 or 2) rose and the position object
/// (0x60BA, 0x60BB) came, and again whenever the position changes while
/// the bit stays set (continuous mode).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TouchProbeTracker {
    status: Option<u16>,
    /// Per edge (rising, falling): stored bit seen, position not reported
    /// yet; and the latest position received.
    pending: [bool; 2],
    latest: [Option<i32>; 2],
}

impl TouchProbeTracker {
    /// Takes one update; returns the latches it completes as (rising,
    /// counts).
    pub fn on_feedback(
        &mut self,
        status: Option<u16>,
        positive: Option<i32>,
        negative: Option<i32>,
    ) -> Vec<(bool, i32)> {
        let mut latched = Vec::new();
        if let Some(st) = status {
            let before = self.status.replace(st).unwrap_or(0);
            for (k, bit) in [(0, 2u16), (1, 4u16)] {
                if st & bit != 0 && before & bit == 0 {
                    self.pending[k] = true;
                }
                if st & bit == 0 {
                    self.pending[k] = false;
                }
            }
        }
        let stored = self.status.unwrap_or(0);
        for (k, bit, value) in [(0, 2u16, positive), (1, 4u16, negative)] {
            let Some(v) = value else {
                continue;
            };
            let changed = self.latest[k].replace(v) != Some(v);
            if stored & bit != 0 && (std::mem::take(&mut self.pending[k]) || changed) {
                latched.push((k == 0, v));
            }
        }
        latched
    }
}

/// Supervision the gateway writes to a CiA 402 drive at boot; `None`
/// leaves the drive's own value.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Supervision {
    /// 0x6065 following error window (user units; written in counts).
    pub following_error_window: Option<f64>,
    /// 0x6066 following error time out.
    pub following_error_timeout: Option<Duration>,
    /// 0x6072 max torque (per mille of rated torque).
    pub max_torque: Option<u16>,
}

impl Supervision {
    /// The boot writes (exact CiA 402 types: UNSIGNED32, UNSIGNED16,
    /// UNSIGNED16).
    pub fn boot_writes(&self, units: Units) -> Vec<(ObjectAddress, Vec<u8>)> {
        let mut w = Vec::new();
        if let Some(window) = self.following_error_window {
            w.push((
                obj::FOLLOWING_ERROR_WINDOW,
                units.to_counts_unsigned(window).to_le_bytes().to_vec(),
            ));
        }
        if let Some(t) = self.following_error_timeout {
            let ms = u16::try_from(t.as_millis()).unwrap_or(u16::MAX);
            w.push((obj::FOLLOWING_ERROR_TIMEOUT, ms.to_le_bytes().to_vec()));
        }
        if let Some(m) = self.max_torque {
            w.push((obj::MAX_TORQUE, m.to_le_bytes().to_vec()));
        }
        w
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn supervision_boot_writes_exact_bytes() {
        let units = Units {
            counts_per_unit: -1000.0,
        };
        let s = Supervision {
            following_error_window: Some(2.5),
            following_error_timeout: Some(Duration::from_millis(20)),
            max_torque: Some(1500),
        };
        assert_eq!(
            s.boot_writes(units),
            vec![
                (ObjectAddress::new(0x6065, 0), vec![0xC4, 0x09, 0x00, 0x00]),
                (ObjectAddress::new(0x6066, 0), vec![0x14, 0x00]),
                (ObjectAddress::new(0x6072, 0), vec![0xDC, 0x05]),
            ]
        );
        assert!(Supervision::default().boot_writes(units).is_empty());
    }

    #[test]
    fn limit_switches_from_the_digital_inputs() {
        let mut s = DriveSignals::default();
        assert_eq!(s.limit_switch(), None);
        s.digital_inputs = Some(0x0000_0006);
        assert_eq!(s.limit_switch(), Some(LimitSwitch::Positive));
        assert!(!s.is_active(LimitSwitch::Negative));
        s.digital_inputs = Some(0x0001_0001);
        assert_eq!(s.limit_switch(), Some(LimitSwitch::Negative));
        let up = Units {
            counts_per_unit: 1000.0,
        };
        let down = Units {
            counts_per_unit: -1000.0,
        };
        assert!(LimitSwitch::Positive.is_into(1.0, up));
        assert!(!LimitSwitch::Positive.is_into(-1.0, up));
        assert!(LimitSwitch::Positive.is_into(-1.0, down));
        assert!(LimitSwitch::Negative.is_into(1.0, down));
    }

    #[test]
    fn touch_probe_function_values() {
        assert_eq!(touch_probe_function(ProbeEdges::Rising, false), 0x0011);
        assert_eq!(touch_probe_function(ProbeEdges::Falling, true), 0x0023);
        assert_eq!(touch_probe_function(ProbeEdges::Both, false), 0x0031);
        assert_eq!(touch_probe_function(ProbeEdges::Off, true), 0);
    }

    #[test]
    fn touch_probe_latches_once_per_store_and_per_change() {
        let mut t = TouchProbeTracker::default();
        // Armed, nothing stored: positions are not latches.
        assert!(t.on_feedback(Some(0x01), None, None).is_empty());
        assert!(t.on_feedback(None, Some(0), Some(0)).is_empty());
        // Bit 1 rises (TPDO3), the position follows (TPDO4).
        assert!(t.on_feedback(Some(0x03), None, None).is_empty());
        assert_eq!(t.on_feedback(None, Some(1500), Some(0)), [(true, 1500)]);
        // The next cycles repeat it: nothing new.
        assert!(t.on_feedback(Some(0x03), None, None).is_empty());
        assert!(t.on_feedback(None, Some(1500), Some(0)).is_empty());
        // Continuous: a new position with the bit still set.
        assert_eq!(t.on_feedback(None, Some(1700), Some(0)), [(true, 1700)]);
        // The same position latched again after a re-arm.
        assert!(t.on_feedback(Some(0x01), None, None).is_empty());
        assert!(t.on_feedback(None, Some(1700), Some(0)).is_empty());
        assert!(t.on_feedback(Some(0x05), None, None).is_empty());
        assert_eq!(t.on_feedback(None, Some(1700), Some(-20)), [(false, -20)]);
        // Status and position in one update (one PDO mapping both).
        let mut t = TouchProbeTracker::default();
        assert_eq!(t.on_feedback(Some(0x03), Some(9), None), [(true, 9)]);
    }
}
