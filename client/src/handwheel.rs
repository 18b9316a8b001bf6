//! The Handwheels service (and turning a simulated wheel).

use crate::canopen::millis;
use crate::error::Error;
use crate::streams::{self, EventStream};
use crate::{Client, pb};
use std::time::Duration;

impl Client {
    /// Every configured handwheel with its statistics.
    pub async fn list_handwheels(&mut self) -> Result<Vec<pb::Handwheel>, Error> {
        let r = self
            .call(
                "ListHandwheels",
                None,
                self.handwheels_client()
                    .list_handwheels(pb::ListHandwheelsRequest {}),
            )
            .await?;
        Ok(r.handwheels)
    }

    /// One handwheel.
    pub async fn get_handwheel(&mut self, handwheel: &str) -> Result<pb::Handwheel, Error> {
        self.handwheel(handwheel).await
    }

    /// One handwheel: mode, feed statistics, bindings.
    pub async fn handwheel(&self, handwheel: &str) -> Result<pb::Handwheel, Error> {
        let req = pb::GetHandwheelRequest {
            handwheel: handwheel.to_string(),
        };
        self.call(
            "GetHandwheel",
            None,
            self.handwheels_client().get_handwheel(req),
        )
        .await
    }

    /// Sets a wheel's mode (manual: it sends feed; automatic: it does not),
    /// confirmed by reading it back.
    pub async fn set_handwheel_mode(
        &self,
        handwheel: &str,
        mode: pb::HandwheelMode,
    ) -> Result<pb::Handwheel, Error> {
        let req = pb::SetModeRequest {
            handwheel: handwheel.to_string(),
            mode: mode as i32,
        };
        self.call("SetMode", None, self.handwheels_client().set_mode(req))
            .await
    }

    /// Feed events of `handwheels` (empty: all): one per feed frame, or
    /// per `coalesce` window summed per wheel, axis and direction.
    pub async fn handwheel_feed(
        &self,
        handwheels: &[&str],
        coalesce: Option<Duration>,
    ) -> Result<EventStream<pb::FeedEvent>, Error> {
        let req = pb::StreamFeedRequest {
            handwheels: handwheels.iter().map(|h| h.to_string()).collect(),
            coalesce_ms: coalesce.map_or(0, millis),
        };
        // Batches: cheaper for the gateway when it falls behind (many
        // subscribers); the events come out one by one all the same.
        let s = self
            .call(
                "StreamFeedBatches",
                None,
                self.handwheels_client().stream_feed_batches(req),
            )
            .await?;
        Ok(streams::flat_map(s, |b: pb::FeedEventBatch| b.events))
    }

    /// Turns a simulated handwheel by `detents` (signed) on wheel axis
    /// `axis` (`Unspecified` keeps the selector) with `multiplier` (1, 10,
    /// 100; 0 keeps it): the wheel sends the feed frames (in manual mode).
    /// Only gateways with simulated wheels offer it.
    pub async fn turn_simulated_handwheel(
        &self,
        handwheel: &str,
        detents: i32,
        axis: pb::WheelAxis,
        multiplier: u32,
    ) -> Result<pb::TurnHandwheelResponse, Error> {
        let req = pb::TurnHandwheelRequest {
            handwheel: handwheel.to_string(),
            detents,
            axis: axis as i32,
            multiplier,
            loss: 0.0,
            max_consecutive_loss: 0,
        };
        self.call(
            "TurnHandwheel",
            None,
            self.simulator_client().turn_handwheel(req),
        )
        .await
    }
}
