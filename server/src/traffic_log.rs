//! The traffic of a bus in the log, as its `decode` level asks
//! ([`DecodeLevel`]): one line per frame on the target `cangate::frames`
//! (level info), received and transmitted alike, inside the bus's span.
//!
//! A subscriber of its own reads the frames, so a bus without a decode
//! level costs nothing, and a slow log only loses lines (counted in a line
//! of their own), never delays the bus.

use crate::config::DecodeLevel;
use cangate_can::{BusHandle, BusItem, Direction, Frame, FrameSelector};
use std::fmt::Write as _;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;
use tracing::Instrument as _;

/// Frames queued for the log before it counts them as lost.
const QUEUE: usize = 4096;

/// Starts logging `bus`'s frames at `level` (nothing for
/// [`DecodeLevel::None`]); ends with the bus or at `cancel`.
pub fn spawn(
    name: &str,
    bus: &BusHandle,
    level: DecodeLevel,
    cancel: CancellationToken,
) -> Option<JoinHandle<()>> {
    if level == DecodeLevel::None {
        return None;
    }
    let mut frames = bus.subscribe(FrameSelector::all(), QUEUE);
    let span = tracing::info_span!("bus", bus = %name);
    Some(tokio::spawn(
        async move {
            loop {
                let item = tokio::select! {
                    biased;
                    () = cancel.cancelled() => return,
                    item = frames.recv() => item,
                };
                match item {
                    Some(BusItem::Frame { frame, direction }) => {
                        tracing::info!(target: "cangate::frames", "{}", line(&frame, direction, level));
                    }
                    Some(BusItem::Lost(n)) => {
                        tracing::info!(target: "cangate::frames", "{n} frames not logged (the log fell behind)");
                    }
                    Some(BusItem::State(_)) => {}
                    None => return,
                }
            }
        }
        .instrument(span),
    ))
}

/// One frame's line: direction, identifier, length, data bytes, and with
/// [`DecodeLevel::Decoded`] the frame in words.
pub fn line(frame: &Frame, direction: Direction, level: DecodeLevel) -> String {
    let mut s = String::with_capacity(80);
    s.push_str(match direction {
        Direction::Rx => "rx ",
        Direction::Tx => "tx ",
    });
    if frame.is_error() {
        let _ = write!(s, "error frame 0x{:08X}", frame.raw_id());
    } else if frame.is_extended() {
        let _ = write!(s, "{:08X}", frame.raw_id());
    } else {
        let _ = write!(s, "{:03X}", frame.raw_id());
    }
    if frame.is_remote() {
        let _ = write!(s, " [{}] remote", frame.dlc());
    } else {
        let _ = write!(s, " [{}]", frame.data().len());
        for b in frame.data() {
            let _ = write!(s, " {b:02X}");
        }
    }
    if frame.is_fd() {
        s.push_str(" (FD)");
    }
    if level == DecodeLevel::Decoded
        && let Some(words) = cangate_canopen::decode::describe(frame)
    {
        s.push_str(" — ");
        s.push_str(&words);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use cangate_can::CanId;

    #[test]
    fn summary_and_decoded_lines() {
        let f = Frame::new(
            CanId::Standard(0x605),
            &[0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0],
        )
        .unwrap();
        assert_eq!(
            line(&f, Direction::Tx, DecodeLevel::Summary),
            "tx 605 [8] 40 00 10 00 00 00 00 00"
        );
        assert_eq!(
            line(&f, Direction::Tx, DecodeLevel::Decoded),
            "tx 605 [8] 40 00 10 00 00 00 00 00 — SDO upload request 0x1000:00 to node 5"
        );
        let ext = Frame::new(CanId::Extended(0x1234_5678), &[1]).unwrap();
        assert_eq!(
            line(&ext, Direction::Rx, DecodeLevel::Decoded),
            "rx 12345678 [1] 01"
        );
    }
}
