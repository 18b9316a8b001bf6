//! Conversions between the protobuf messages and the domain types. Generated
//! types stop here: nothing below the gRPC layer sees them.

use super::InvalidArgument;
use cangate_can::bus::{BackendKind, BusItem, BusStats, Direction};
use cangate_can::{BusInfo, BusState, BusStatus, ClientId, Filter, Frame};
use cangate_proto::v1 as pb;

/// A protobuf frame from SendFrames to a validated frame to send.
pub fn frame_from_pb(f: &pb::Frame) -> Result<Frame, cangate_can::FrameError> {
    if f.error {
        return Err(cangate_can::FrameError::ErrorFrameNotSendable);
    }
    cangate_proto::frames::frame_from_pb(f)
}

/// A frame of a subscription to its protobuf form, as the stream's
/// receiver sees it: `viewer` is the attached client whose stream it is
/// (`None`: a StreamFrames stream, the gateway's view). The origin follows
/// from the frame's sender and direction: a client's frame (marked), the
/// gateway's own (transmitted, unmarked) or another node's; an attached
/// client receives everything but its own frames (see `Direction` in
/// bus.proto). `name_of` names a sender (FrameSender.client).
pub fn frame_to_pb(
    f: &Frame,
    direction: Direction,
    viewer: Option<ClientId>,
    name_of: &mut impl FnMut(ClientId) -> String,
) -> pb::Frame {
    let sender = f.sender();
    let origin = match (sender, direction) {
        (Some(_), _) => pb::FrameOrigin::Client,
        (None, Direction::Tx) => pb::FrameOrigin::Gateway,
        (None, Direction::Rx) => pb::FrameOrigin::Bus,
    };
    let direction = match viewer {
        Some(me) if sender != Some(me) => Direction::Rx,
        _ => direction,
    };
    let d = match direction {
        Direction::Rx => pb::Direction::Rx,
        Direction::Tx => pb::Direction::Tx,
    };
    let mut p = cangate_proto::frames::frame_to_pb(f, d);
    p.origin = origin as i32;
    p.sender = sender.map(|c| pb::FrameSender {
        id: c.get(),
        client: name_of(c),
    });
    p
}

/// A protobuf filter to a domain filter.
pub fn filter_from_pb(f: &pb::FrameFilter) -> Result<Filter, InvalidArgument> {
    let extended = match pb::IdFormat::try_from(f.format) {
        Ok(pb::IdFormat::Any) => None,
        Ok(pb::IdFormat::Standard) => Some(false),
        Ok(pb::IdFormat::Extended) => Some(true),
        Err(_) => {
            return Err(InvalidArgument(format!(
                "filter format {} is not a known IdFormat",
                f.format
            )));
        }
    };
    if f.id > cangate_can::frame::MAX_EXTENDED_ID || f.mask > cangate_can::frame::MAX_EXTENDED_ID {
        return Err(InvalidArgument(format!(
            "filter {:X}:{:X} has bits above the 29-bit identifier range",
            f.id, f.mask
        )));
    }
    Ok(Filter {
        id: f.id,
        mask: f.mask,
        extended,
        inverted: f.invert,
    })
}

/// A status to protobuf.
pub fn status_to_pb(s: BusStatus, since_ns: u64) -> pb::BusStatus {
    pb::BusStatus {
        state: match s.state {
            BusState::Up => pb::BusState::Up,
            BusState::ErrorWarning => pb::BusState::ErrorWarning,
            BusState::ErrorPassive => pb::BusState::ErrorPassive,
            BusState::BusOff => pb::BusState::BusOff,
            BusState::Down => pb::BusState::Down,
        } as i32,
        tx_errors: s.tx_errors as u32,
        rx_errors: s.rx_errors as u32,
        since_ns,
    }
}

/// A bus description with its live statistics.
pub fn bus_info_to_pb(info: &BusInfo, stats: &BusStats) -> pb::BusInfo {
    pb::BusInfo {
        name: info.name.clone(),
        backend: match info.kind {
            BackendKind::SocketCan => pb::BackendKind::Socketcan,
            BackendKind::Virtual => pb::BackendKind::Virtual,
        } as i32,
        interface: info.interface.clone(),
        fd: info.fd,
        bitrate: info.bitrate.unwrap_or(0),
        data_bitrate: info.data_bitrate.unwrap_or(0),
        bit_timed: info.bit_timed,
        status: Some(status_to_pb(stats.status, stats.status_since.as_nanos())),
        statistics: Some(pb::BusStatistics {
            rx_frames: stats.rx_frames,
            tx_frames: stats.tx_frames,
            rx_bytes: stats.rx_bytes,
            tx_bytes: stats.tx_bytes,
            error_frames: stats.error_frames,
            tx_failed: stats.tx_failed,
            tx_retries: stats.tx_retries,
            tx_queued: stats.tx_queued,
            rx_overflows: stats.rx_overflows,
            subscriber_drops: stats.subscriber_drops,
            load_percent: stats.load_percent,
            subscribers: stats.subscribers as u32,
        }),
    }
}

/// A subscription item to a StreamFrames event (see [`frame_to_pb`]).
pub fn item_to_pb(
    item: &BusItem,
    since_ns: u64,
    name_of: &mut impl FnMut(ClientId) -> String,
) -> pb::StreamEvent {
    use pb::stream_event::Event;
    let event = match item {
        BusItem::Frame { frame, direction } => {
            Event::Frame(frame_to_pb(frame, *direction, None, name_of))
        }
        BusItem::Lost(n) => Event::Lost(pb::FramesLost { count: *n }),
        BusItem::State(s) => Event::State(status_to_pb(*s, since_ns)),
    };
    pb::StreamEvent { event: Some(event) }
}

/// A subscription item to an event of the Attach stream of `viewer`.
pub fn item_to_attach_pb(
    item: &BusItem,
    since_ns: u64,
    viewer: ClientId,
    name_of: &mut impl FnMut(ClientId) -> String,
) -> pb::AttachEvent {
    use pb::attach_event::Event;
    let event = match item {
        BusItem::Frame { frame, direction } => {
            Event::Frame(frame_to_pb(frame, *direction, Some(viewer), name_of))
        }
        BusItem::Lost(n) => Event::Lost(pb::FramesLost { count: *n }),
        BusItem::State(s) => Event::State(status_to_pb(*s, since_ns)),
    };
    pb::AttachEvent { event: Some(event) }
}
