//! Identifier/mask receive filters, with the semantics of SocketCAN's
//! `CAN_RAW_FILTER` and the `candump` text syntax.

use crate::frame::{Frame, FrameKind};

/// One receive filter: a frame matches when `(frame_id & mask) == (id & mask)`,
/// optionally restricted to one identifier format, optionally inverted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Filter {
    /// Identifier to compare with.
    pub id: u32,
    /// Bits of the identifier that must match.
    pub mask: u32,
    /// `Some(true)`: only extended frames; `Some(false)`: only standard
    /// frames; `None`: both.
    pub extended: Option<bool>,
    /// Match everything the filter would not match (`~` in candump syntax).
    pub inverted: bool,
}

impl Filter {
    /// A filter that matches exactly one standard identifier.
    pub fn exact_standard(id: u16) -> Self {
        Filter {
            id: id as u32,
            mask: 0x7FF,
            extended: Some(false),
            inverted: false,
        }
    }

    /// Filters that together match exactly the standard identifiers
    /// `first..=last`: the range split into aligned power-of-two blocks
    /// (at most 20 filters for any range), so a subscriber can take a
    /// range without its neighbours (EMCY 0x081..=0x0FF without SYNC 0x080).
    pub fn standard_range(first: u16, last: u16) -> Vec<Filter> {
        let last = u32::from(last.min(0x7FF));
        let mut next = u32::from(first);
        let mut out = Vec::new();
        while next <= last {
            // The largest block aligned at `next` that stays inside the range.
            let mut size = if next == 0 {
                0x800
            } else {
                1 << next.trailing_zeros()
            };
            while next + size - 1 > last {
                size /= 2;
            }
            out.push(Filter {
                id: next,
                mask: 0x7FF & !(size - 1),
                extended: Some(false),
                inverted: false,
            });
            next += size;
        }
        out
    }

    /// True if the frame passes this filter.
    pub fn matches(&self, frame: &Frame) -> bool {
        let format_ok = self.extended.is_none_or(|e| e == frame.is_extended());
        let hit = format_ok && (frame.raw_id() & self.mask) == (self.id & self.mask);
        hit != self.inverted
    }
}

/// Why a filter text could not be parsed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("filter {0:?} is not <id>:<mask> or <id>~<mask> in hex (e.g. 123:7FF, 18FF0000:1FFF0000)")]
pub struct ParseFilterError(pub String);

impl std::str::FromStr for Filter {
    type Err = ParseFilterError;

    /// `candump` syntax: `<id>:<mask>` matches, `<id>~<mask>` inverts.
    /// An 8-digit id selects extended frames only; a shorter one matches
    /// both formats (as candump does).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let err = || ParseFilterError(s.to_string());
        let (id_txt, mask_txt, inverted) = if let Some((a, b)) = s.split_once(':') {
            (a, b, false)
        } else if let Some((a, b)) = s.split_once('~') {
            (a, b, true)
        } else {
            return Err(err());
        };
        let id = u32::from_str_radix(id_txt, 16).map_err(|_| err())?;
        let mask = u32::from_str_radix(mask_txt, 16).map_err(|_| err())?;
        if id > crate::frame::MAX_EXTENDED_ID || mask > crate::frame::MAX_EXTENDED_ID {
            return Err(err());
        }
        Ok(Filter {
            id,
            mask,
            extended: (id_txt.len() == 8).then_some(true),
            inverted,
        })
    }
}

/// What a subscriber wants to see: frames passing any of the filters (all
/// frames when there are none), and optionally error frames.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct FrameSelector {
    /// Pass frames matching any of these; empty passes all data/remote frames.
    pub filters: Vec<Filter>,
    /// Also pass SocketCAN error frames (never matched by id filters).
    pub error_frames: bool,
    /// Also pass frames this gateway transmitted.
    pub transmitted: bool,
}

impl FrameSelector {
    /// Everything: all frames, error frames and our own transmissions.
    pub fn all() -> Self {
        FrameSelector {
            filters: Vec::new(),
            error_frames: true,
            transmitted: true,
        }
    }

    /// True if the frame passes.
    pub fn matches(&self, frame: &Frame) -> bool {
        if frame.kind() == FrameKind::Error {
            return self.error_frames;
        }
        self.filters.is_empty() || self.filters.iter().any(|f| f.matches(frame))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::CanId;

    fn f(id: CanId) -> Frame {
        Frame::new(id, &[1]).unwrap()
    }

    #[test]
    fn candump_syntax() {
        let flt: Filter = "123:7FF".parse().unwrap();
        assert!(flt.matches(&f(CanId::Standard(0x123))));
        assert!(!flt.matches(&f(CanId::Standard(0x124))));
        let flt: Filter = "100:700".parse().unwrap();
        assert!(flt.matches(&f(CanId::Standard(0x1AB))));
        assert!(!flt.matches(&f(CanId::Standard(0x2AB))));
        let flt: Filter = "123~7FF".parse().unwrap();
        assert!(!flt.matches(&f(CanId::Standard(0x123))));
        assert!(flt.matches(&f(CanId::Standard(0x124))));
        let flt: Filter = "1F334455:1FFFFFFF".parse().unwrap();
        assert!(flt.matches(&f(CanId::Extended(0x1F33_4455))));
        assert!(!flt.matches(&f(CanId::Standard(0x455))));
        assert!("123".parse::<Filter>().is_err());
        assert!("xyz:7FF".parse::<Filter>().is_err());
    }

    #[test]
    fn selector_or_semantics_and_error_frames() {
        let sel = FrameSelector {
            filters: vec!["100:7FF".parse().unwrap(), "200:7FF".parse().unwrap()],
            error_frames: false,
            transmitted: true,
        };
        assert!(sel.matches(&f(CanId::Standard(0x100))));
        assert!(sel.matches(&f(CanId::Standard(0x200))));
        assert!(!sel.matches(&f(CanId::Standard(0x300))));
        let err = Frame::new_error(0x40, [0; 8]);
        assert!(!sel.matches(&err));
        assert!(FrameSelector::all().matches(&err));
    }

    #[test]
    fn standard_range_matches_exactly_the_range() {
        for (first, last) in [
            (0x081, 0x0FF),
            (0x580, 0x5FF),
            (0, 0x7FF),
            (0x123, 0x123),
            (5, 0x700),
        ] {
            let filters = Filter::standard_range(first, last);
            assert!(filters.len() <= 20, "{first:X}..{last:X}: {filters:?}");
            for id in 0..=0x7FFu16 {
                let hit = filters
                    .iter()
                    .any(|flt| flt.matches(&f(CanId::Standard(id))));
                assert_eq!(hit, (first..=last).contains(&id), "id {id:X}");
            }
            assert!(
                !filters
                    .iter()
                    .any(|flt| flt.matches(&f(CanId::Extended(u32::from(first)))))
            );
        }
        assert_eq!(Filter::standard_range(0x081, 0x0FF).len(), 7);
    }
}
