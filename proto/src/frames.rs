//! The one conversion between [`cangate_can::Frame`] and the protobuf
//! `Frame`, shared by the server and the client.

use crate::v1 as pb;
use cangate_can::{Filter, Frame, FrameError, FrameKind, Timestamp};

/// A frame to its protobuf form, with the direction code (`pb::Direction`);
/// its origin and sender are left unset (the server sets them for streams).
pub fn frame_to_pb(f: &Frame, direction: pb::Direction) -> pb::Frame {
    pb::Frame {
        id: f.raw_id(),
        extended: f.is_extended(),
        remote: f.is_remote(),
        fd: f.is_fd(),
        brs: f.brs(),
        esi: f.esi(),
        data: f.data().to_vec(),
        remote_dlc: if f.is_remote() { f.dlc() as u32 } else { 0 },
        error: f.is_error(),
        timestamp_ns: f.timestamp().as_nanos(),
        direction: direction as i32,
        origin: pb::FrameOrigin::Unspecified as i32,
        sender: None,
    }
}

/// A protobuf frame to a validated frame, with its timestamp. Error frames
/// are accepted (they are received, never sent: the server refuses them in
/// SendFrames before calling this).
pub fn frame_from_pb(f: &pb::Frame) -> Result<Frame, FrameError> {
    if f.remote && !f.data.is_empty() {
        return Err(FrameError::RemoteWithData(f.data.len()));
    }
    let kind = if f.error {
        FrameKind::Error
    } else if f.remote {
        FrameKind::Remote
    } else {
        FrameKind::Data
    };
    let dlc = u8::try_from(f.remote_dlc).unwrap_or(u8::MAX);
    Frame::from_parts(f.id, f.extended, kind, f.fd, f.brs, f.esi, &f.data, dlc)
        .map(|fr| fr.with_timestamp(Timestamp(f.timestamp_ns)))
}

/// A filter to its protobuf form.
pub fn filter_to_pb(f: &Filter) -> pb::FrameFilter {
    pb::FrameFilter {
        id: f.id,
        mask: f.mask,
        format: match f.extended {
            None => pb::IdFormat::Any,
            Some(false) => pb::IdFormat::Standard,
            Some(true) => pb::IdFormat::Extended,
        } as i32,
        invert: f.inverted,
    }
}
