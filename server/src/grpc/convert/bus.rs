//! Conversions between the protobuf messages and the domain types. Generated
//! types stop here: nothing below the gRPC layer sees them.

use crate::grpc::error::ApiError;
use cangate_can::bus::{BackendKind, BusItem, BusStats, Direction};
use cangate_can::{BusInfo, BusState, BusStatus, Filter, Frame};
use cangate_proto::v1 as pb;

/// A protobuf frame from SendFrames to a validated frame to send.
pub fn frame_from_pb(f: &pb::Frame) -> Result<Frame, cangate_can::FrameError> {
    if f.error {
        return Err(cangate_can::FrameError::ErrorFrameNotSendable);
    }
    cangate_proto::frames::frame_from_pb(f)
}

/// A frame with its direction to its protobuf form.
pub fn frame_to_pb(f: &Frame, direction: Direction) -> pb::Frame {
    let d = match direction {
        Direction::Rx => pb::Direction::Rx,
        Direction::Tx => pb::Direction::Tx,
    };
    cangate_proto::frames::frame_to_pb(f, d)
}

/// A protobuf filter to a domain filter.
pub fn filter_from_pb(f: &pb::FrameFilter) -> Result<Filter, ApiError> {
    let extended = match pb::IdFormat::try_from(f.format) {
        Ok(pb::IdFormat::Any) => None,
        Ok(pb::IdFormat::Standard) => Some(false),
        Ok(pb::IdFormat::Extended) => Some(true),
        Err(_) => {
            return Err(ApiError::InvalidArgument(format!(
                "filter format {} is not a known IdFormat",
                f.format
            )));
        }
    };
    if f.id > cangate_can::frame::MAX_EXTENDED_ID || f.mask > cangate_can::frame::MAX_EXTENDED_ID {
        return Err(ApiError::InvalidArgument(format!(
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

/// A subscription item to a stream event.
pub fn item_to_pb(item: &BusItem, since_ns: u64) -> pb::StreamEvent {
    use pb::stream_event::Event;
    let event = match item {
        BusItem::Frame { frame, direction } => Event::Frame(frame_to_pb(frame, *direction)),
        BusItem::Lost(n) => Event::Lost(pb::FramesLost { count: *n }),
        BusItem::State(s) => Event::State(status_to_pb(*s, since_ns)),
    };
    pb::StreamEvent { event: Some(event) }
}
