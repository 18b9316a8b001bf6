//! When each node-ID was last heard on a bus: any frame a node sends under
//! its own id in the predefined connection set (EMCY, TPDO 1..4 at their
//! default COB-IDs, SDO answers, heartbeat and boot-up). LSS asks it before
//! giving a device a node-ID, so that no device gets an id another device
//! uses ([`crate::canopen::lss`]).
//!
//! One task per bus listens to those COB-IDs, except the TPDOs of axis
//! drives: those run at the SYNC rate, their nodes are configured (which
//! LSS refuses anyway), and leaving them out keeps this task from waking
//! with every SYNC.

use cangate_can::{BusHandle, BusItem, Filter, FrameSelector};
use cangate_canopen::NodeId;
use cangate_canopen::ids::{CobFunction, cob};
use std::collections::BTreeSet;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};
use tokio_util::sync::CancellationToken;

/// How long a node-ID counts as in use after its last frame.
pub const IN_USE_FOR: Duration = Duration::from_secs(60);

/// Last frame time of every node-ID of one bus.
#[derive(Debug)]
pub struct HeardNodes {
    origin: Instant,
    /// Per node-ID (index 1..=127): ms after `origin` + 1 of the last
    /// frame; 0 = never heard.
    last: [AtomicU64; 128],
}

impl Default for HeardNodes {
    fn default() -> Self {
        HeardNodes {
            origin: Instant::now(),
            last: std::array::from_fn(|_| AtomicU64::new(0)),
        }
    }
}

impl HeardNodes {
    /// Notes a frame (frames that are no node's own are ignored).
    pub fn record(&self, raw_id: u32, extended: bool) {
        if extended || raw_id > 0x7FF {
            return;
        }
        let node = match CobFunction::classify(raw_id as u16) {
            CobFunction::Emcy(n)
            | CobFunction::Tpdo(_, n)
            | CobFunction::SdoTx(n)
            | CobFunction::Heartbeat(n) => n,
            _ => return,
        };
        let ms = self.origin.elapsed().as_millis() as u64 + 1;
        self.last[usize::from(node.get())].store(ms, Ordering::Relaxed);
    }

    /// How long ago `node` was last heard, if ever.
    pub fn heard_ago(&self, node: NodeId) -> Option<Duration> {
        match self.last[usize::from(node.get())].load(Ordering::Relaxed) {
            0 => None,
            ms => Some(
                self.origin
                    .elapsed()
                    .saturating_sub(Duration::from_millis(ms - 1)),
            ),
        }
    }

    /// Whether `node` sent a frame within [`IN_USE_FOR`].
    pub fn in_use(&self, node: NodeId) -> Option<Duration> {
        self.heard_ago(node).filter(|ago| *ago <= IN_USE_FOR)
    }
}

impl super::CanopenBus {
    /// When this bus's node-IDs were last heard.
    pub fn heard(&self) -> &HeardNodes {
        &self.heard
    }
}

/// What the listener takes: every node's own COB-IDs except the TPDOs of
/// `axis_drives`.
fn selector(axis_drives: &BTreeSet<u8>) -> FrameSelector {
    let mut filters = Filter::standard_range(cob::EMCY + 1, cob::EMCY + 0x7F);
    filters.extend(Filter::standard_range(cob::SDO_TX + 1, cob::SDO_TX + 0x7F));
    filters.extend(Filter::standard_range(
        cob::HEARTBEAT + 1,
        cob::HEARTBEAT + 0x7F,
    ));
    // The runs of node-IDs between axis drives.
    let mut runs = Vec::new();
    let mut start = None;
    for id in 1..=128u16 {
        let skip = id == 128 || axis_drives.contains(&(id as u8));
        match (skip, start) {
            (false, None) => start = Some(id),
            (true, Some(s)) => {
                runs.push((s, id - 1));
                start = None;
            }
            _ => {}
        }
    }
    for base in cob::TPDO {
        for (first, last) in &runs {
            filters.extend(Filter::standard_range(base + first, base + last));
        }
    }
    FrameSelector {
        filters,
        error_frames: false,
        transmitted: false,
    }
}

/// Starts the listener of `bus`; `axis_drives` are the node-IDs of its
/// axis drives.
pub fn spawn(
    bus: &BusHandle,
    axis_drives: &BTreeSet<u8>,
    cancel: CancellationToken,
) -> (Arc<HeardNodes>, tokio::task::JoinHandle<()>) {
    let heard = Arc::new(HeardNodes::default());
    let mut sub = bus.subscribe(selector(axis_drives), 4096);
    let h = heard.clone();
    let task = tokio::spawn(async move {
        let mut items = Vec::with_capacity(256);
        loop {
            let n = tokio::select! {
                _ = cancel.cancelled() => return,
                n = sub.recv_many(&mut items, 256) => n,
            };
            if n == 0 {
                return;
            }
            for item in items.drain(..) {
                if let BusItem::Frame { frame, .. } = item {
                    h.record(frame.raw_id(), frame.is_extended());
                }
            }
        }
    });
    (heard, task)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_nodes_own_frames_mark_it_heard() {
        let h = HeardNodes::default();
        let n = |i| NodeId::new(i).unwrap();
        for (cob, node) in [
            (0x081, 1),
            (0x185, 5),
            (0x2FF, 127),
            (0x4A0, 0x20),
            (0x5A1, 0x21),
            (0x722, 0x22),
        ] {
            assert_eq!(h.in_use(n(node)), None);
            h.record(cob, false);
            assert!(h.in_use(n(node)).is_some(), "{cob:03X}");
        }
        // SYNC, TIME, RPDOs, SDO requests, LSS and extended frames are no
        // node's own.
        for cob in [0x080, 0x100, 0x203, 0x603, 0x7E4, 0x7E5] {
            h.record(cob, false);
        }
        h.record(0x703, true);
        assert_eq!(h.in_use(n(3)), None);
    }

    #[test]
    fn the_listener_leaves_out_the_axis_drives_tpdos() {
        let sel = selector(&[3u8, 4].into_iter().collect());
        let passes = |id: u16| {
            let f = cangate_can::Frame::new(cangate_can::CanId::Standard(id), &[0]).unwrap();
            sel.filters.iter().any(|x| x.matches(&f))
        };
        for id in [0x181, 0x182, 0x185, 0x1FF, 0x485, 0x703, 0x583, 0x083] {
            assert!(passes(id), "{id:03X}");
        }
        for id in [0x183, 0x184, 0x283, 0x484, 0x080, 0x100, 0x203, 0x7E5] {
            assert!(!passes(id), "{id:03X}");
        }
    }
}
