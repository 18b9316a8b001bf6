//! The Bus service: list, get, send, stream frames.

use crate::error::Error;
use crate::streams::{self, EventStream};
use crate::{Client, can, frame_to_pb, pb};

/// What to stream from a bus ([`Client::frames`]).
#[derive(Debug, Clone, Default)]
pub struct FrameStreamOptions {
    /// A frame passes if it matches any filter; none pass every frame.
    pub filters: Vec<can::Filter>,
    /// Also the frames the gateway sends (its own stacks' and clients').
    pub include_transmitted: bool,
    /// Also SocketCAN error frames.
    pub include_error_frames: bool,
    /// Events the gateway buffers for this stream before it drops (and
    /// reports) frames; `None`: the gateway's default (8192).
    pub queue_length: Option<u32>,
}

/// One item of a frame stream.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum FrameEvent {
    /// A frame that passed the filters, with its timestamp.
    Frame {
        /// The frame.
        frame: can::Frame,
        /// True when the gateway sent it, false when it was received.
        transmitted: bool,
    },
    /// The gateway dropped this many frames for this stream here (it was
    /// read too slowly), or the kernel dropped them before the gateway
    /// read them.
    Lost(u64),
    /// The bus state (also the first item of every stream).
    State(pb::BusStatus),
}

impl FrameEvent {
    fn from_pb(e: pb::StreamEvent) -> Option<FrameEvent> {
        use pb::stream_event::Event;
        Some(match e.event? {
            Event::Frame(f) => FrameEvent::Frame {
                transmitted: f.direction == pb::Direction::Tx as i32,
                frame: crate::frame_from_pb(&f)?,
            },
            Event::Lost(l) => FrameEvent::Lost(l.count),
            Event::State(s) => FrameEvent::State(s),
        })
    }
}

impl Client {
    /// Every bus with live statistics.
    pub async fn list_buses(&mut self) -> Result<Vec<pb::BusInfo>, Error> {
        let r = self
            .call(
                "ListBuses",
                None,
                self.bus_client().list_buses(pb::ListBusesRequest {}),
            )
            .await?;
        Ok(r.buses)
    }

    /// One bus.
    pub async fn get_bus(&mut self, bus: &str) -> Result<pb::BusInfo, Error> {
        let req = pb::GetBusRequest {
            bus: bus.to_string(),
        };
        self.call("GetBus", None, self.bus_client().get_bus(req))
            .await
    }

    /// Sends frames in order on a bus; the number sent (all of them).
    pub async fn send(&mut self, bus: &str, frames: &[can::Frame]) -> Result<u32, Error> {
        self.send_pb(bus, frames.iter().map(frame_to_pb).collect())
            .await
    }

    /// Sends protobuf frames as given (no local validation).
    pub async fn send_pb(&mut self, bus: &str, frames: Vec<pb::Frame>) -> Result<u32, Error> {
        let req = pb::SendFramesRequest {
            bus: bus.to_string(),
            frames,
        };
        let r = self
            .call("SendFrames", None, self.bus_client().send_frames(req))
            .await?;
        Ok(r.sent)
    }

    /// Opens a frame stream (the generated one: batches of events).
    pub async fn stream_frames(
        &mut self,
        request: pb::StreamFramesRequest,
    ) -> Result<tonic::Streaming<pb::StreamFramesResponse>, Error> {
        self.call(
            "StreamFrames",
            None,
            self.bus_client().stream_frames(request),
        )
        .await
    }

    /// The frames, losses and state changes of a bus, one item each, as
    /// they happen (starting with the bus state).
    pub async fn frames(
        &self,
        bus: &str,
        options: &FrameStreamOptions,
    ) -> Result<EventStream<FrameEvent>, Error> {
        let req = pb::StreamFramesRequest {
            bus: bus.to_string(),
            filters: options.filters.iter().map(crate::filter_to_pb).collect(),
            include_transmitted: options.include_transmitted,
            include_error_frames: options.include_error_frames,
            max_batch: 0,
            queue_length: options.queue_length.unwrap_or(0),
        };
        let s = self
            .call("StreamFrames", None, self.bus_client().stream_frames(req))
            .await?;
        Ok(streams::flat_map(s, |batch: pb::StreamFramesResponse| {
            batch
                .events
                .into_iter()
                .filter_map(FrameEvent::from_pb)
                .collect::<Vec<_>>()
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stream_events_become_frame_events() {
        use pb::stream_event::Event;
        let frame: can::Frame = "123#DEADBEEF".parse().unwrap();
        let mut p = frame_to_pb(&frame);
        p.direction = pb::Direction::Tx as i32;
        let e = FrameEvent::from_pb(pb::StreamEvent {
            event: Some(Event::Frame(p)),
        })
        .unwrap();
        assert_eq!(
            e,
            FrameEvent::Frame {
                frame,
                transmitted: true
            }
        );
        let lost = FrameEvent::from_pb(pb::StreamEvent {
            event: Some(Event::Lost(pb::FramesLost { count: 3 })),
        });
        assert_eq!(lost, Some(FrameEvent::Lost(3)));
        assert_eq!(FrameEvent::from_pb(pb::StreamEvent { event: None }), None);
    }
}
