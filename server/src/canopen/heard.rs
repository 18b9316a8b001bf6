//! When each node-ID was last heard on a bus: any frame a node sends under
//! its own id in the predefined connection set (EMCY, TPDO 1..4 at their
//! default COB-IDs, SDO answers, heartbeat and boot-up). LSS asks it before
//! giving a device a node-ID, so that no device gets an id another device
//! uses ([`crate::canopen::lss`]).
//!
//! The master task notes what it receives anyway (EMCY, SDO answers and
//! heartbeats of every node, the TPDOs of the configured nodes but the axis
//! drives'); a listener of its own takes only the default TPDO COB-IDs of
//! the node-IDs no node is configured at, which carry no traffic on a bus
//! that runs as configured. The axis drives' TPDOs, which run at the SYNC
//! rate, are left out: their ids are configured, which LSS refuses anyway.
//! A frame counts for the node-ID its COB-ID is the default of, so a PDO
//! moved to another node's default COB-ID marks that id in use too: LSS
//! then refuses it, which errs on the side of the running machine.

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

/// What the listener takes: the default TPDO COB-IDs of every node-ID not
/// in `configured`; `None` when every id is configured.
fn selector(configured: &BTreeSet<u8>) -> Option<FrameSelector> {
    // The runs of node-IDs between configured ones.
    let mut runs = Vec::new();
    let mut start = None;
    for id in 1..=128u16 {
        let skip = id == 128 || configured.contains(&(id as u8));
        match (skip, start) {
            (false, None) => start = Some(id),
            (true, Some(s)) => {
                runs.push((s, id - 1));
                start = None;
            }
            _ => {}
        }
    }
    let mut filters = Vec::new();
    for base in cob::TPDO {
        for (first, last) in &runs {
            filters.extend(Filter::standard_range(base + first, base + last));
        }
    }
    // No filter would pass every frame.
    (!filters.is_empty()).then_some(FrameSelector {
        filters,
        error_frames: false,
        transmitted: false,
    })
}

/// The register of `bus`, with the listener for the node-IDs not in
/// `configured` (the master task feeds it the rest).
pub fn spawn(
    bus: &BusHandle,
    configured: &BTreeSet<u8>,
    cancel: CancellationToken,
) -> Arc<HeardNodes> {
    let heard = Arc::new(HeardNodes::default());
    let Some(selector) = selector(configured) else {
        return heard;
    };
    let mut sub = bus.subscribe(selector, 4096);
    let h = heard.clone();
    tokio::spawn(async move {
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
    heard
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
    fn the_listener_takes_the_tpdos_of_unconfigured_ids_only() {
        let sel = selector(&[3u8, 4].into_iter().collect()).unwrap();
        let passes = |id: u16| {
            let f = cangate_can::Frame::new(cangate_can::CanId::Standard(id), &[0]).unwrap();
            sel.filters.iter().any(|x| x.matches(&f))
        };
        for id in [0x181, 0x182, 0x185, 0x1FF, 0x485] {
            assert!(passes(id), "{id:03X}");
        }
        for id in [
            0x183, 0x184, 0x283, 0x484, 0x080, 0x100, 0x203, 0x703, 0x583, 0x7E5,
        ] {
            assert!(!passes(id), "{id:03X}");
        }
        assert!(selector(&(1..=127).collect()).is_none());
    }
}
