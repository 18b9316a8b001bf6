//! The `cangate.v1.Handwheels` and `cangate.v1.Simulator` services.

use super::error::ApiError;
use super::forward::{
    MessageStream, Received, batches_of, broadcast_batches, recv_counted, stream_of,
};
use crate::convert::handwheel::{event_pb, merge, wheel_pb};
use crate::gateway::Gateway;
use crate::handwheel::{Handwheels, Mode, WheelFeed};
use cangate_canopen::handwheel::HandwheelAxis;
use cangate_proto::v1 as pb;
use cangate_proto::v1::handwheels_server::Handwheels as HandwheelsRpc;
use cangate_proto::v1::simulator_server::Simulator;
use cangate_sim::{FrameLoss, Multiplier};
use std::sync::Arc;
use std::time::Duration;
use tonic::{Request, Response, Status};

/// Longest feed window a client may ask for: events are held for this
/// long, so a window of hours would hold a wheel's events indefinitely.
pub const MAX_COALESCE_MS: u32 = 10_000;
/// Most events per StreamFeedBatches message.
pub const MAX_FEED_BATCH: usize = 1024;

/// Implementation of the Handwheels service.
#[derive(Clone)]
pub struct HandwheelsService {
    gateway: Arc<Gateway>,
}

impl HandwheelsService {
    /// Serves the gateway's handwheels.
    pub fn new(gateway: Arc<Gateway>) -> Self {
        HandwheelsService { gateway }
    }

    fn wheels(&self) -> &Handwheels {
        self.gateway.handwheels()
    }
}

type FeedStream = MessageStream<pb::FeedEvent>;

#[tonic::async_trait]
impl HandwheelsRpc for HandwheelsService {
    async fn list_handwheels(
        &self,
        _req: Request<pb::ListHandwheelsRequest>,
    ) -> Result<Response<pb::ListHandwheelsResponse>, Status> {
        let m = self.wheels();
        Ok(Response::new(pb::ListHandwheelsResponse {
            handwheels: (0..m.len()).map(|i| wheel_pb(m, i)).collect(),
        }))
    }

    async fn get_handwheel(
        &self,
        req: Request<pb::GetHandwheelRequest>,
    ) -> Result<Response<pb::Handwheel>, Status> {
        let m = self.wheels();
        let i = m.index(&req.get_ref().handwheel)?;
        // The mode is read from the wheel when not known yet.
        if m.wheel(i).mode.lock().expect("mode lock").is_none() {
            let _ = m.read_mode(i).await;
        }
        Ok(Response::new(wheel_pb(m, i)))
    }

    async fn set_mode(
        &self,
        req: Request<pb::SetModeRequest>,
    ) -> Result<Response<pb::Handwheel>, Status> {
        let peer = super::caller(&req);
        let r = req.into_inner();
        let m = self.wheels();
        let i = m.index(&r.handwheel)?;
        let mode = match pb::HandwheelMode::try_from(r.mode) {
            Ok(pb::HandwheelMode::Manual) => Mode::Manual,
            Ok(pb::HandwheelMode::Automatic) => Mode::Automatic,
            _ => {
                return Err(
                    ApiError::InvalidArgument("mode must be MANUAL or AUTOMATIC".into()).into(),
                );
            }
        };
        let res = m.set_mode(i, mode).await;
        tracing::info!(target: "cangate::audit", %peer, handwheel = %r.handwheel, ?mode, result = %res.as_ref().map_or_else(|e| e.to_string(), |_| "ok".into()), "handwheel mode");
        res?;
        Ok(Response::new(wheel_pb(m, i)))
    }

    type StreamFeedStream = FeedStream;

    async fn stream_feed(
        &self,
        req: Request<pb::StreamFeedRequest>,
    ) -> Result<Response<Self::StreamFeedStream>, Status> {
        let r = req.into_inner();
        if r.coalesce_ms != 0 {
            return Ok(Response::new(stream_of(self.windowed_feed(r)?)));
        }
        // One event per message: batches of one.
        let one = |mut events: Vec<pb::FeedEvent>| events.remove(0);
        Ok(Response::new(self.direct_feed(&r, 1, one)?))
    }

    type StreamFeedBatchesStream = MessageStream<pb::FeedEventBatch>;

    async fn stream_feed_batches(
        &self,
        req: Request<pb::StreamFeedRequest>,
    ) -> Result<Response<Self::StreamFeedBatchesStream>, Status> {
        let r = req.into_inner();
        let batch = |events| pb::FeedEventBatch { events };
        if r.coalesce_ms != 0 {
            return Ok(Response::new(batches_of(
                self.windowed_feed(r)?,
                MAX_FEED_BATCH,
                batch,
            )));
        }
        Ok(Response::new(self.direct_feed(
            &r,
            MAX_FEED_BATCH,
            batch,
        )?))
    }
}

/// Which wheels a feed subscriber asked for.
struct Subscription {
    /// Per wheel index; `None`: every wheel.
    wanted: Option<Vec<bool>>,
}

impl Subscription {
    fn wants(&self, f: &WheelFeed) -> bool {
        self.wanted.as_ref().is_none_or(|w| w[f.wheel])
    }
}

impl HandwheelsService {
    /// The wheels `r` asks for, after checking its names and window.
    fn subscription(&self, r: &pb::StreamFeedRequest) -> Result<Subscription, Status> {
        let m = self.wheels();
        if r.coalesce_ms > MAX_COALESCE_MS {
            return Err(ApiError::InvalidArgument(format!(
                "coalesce_ms {} is above the maximum of {MAX_COALESCE_MS} ms",
                r.coalesce_ms
            ))
            .into());
        }
        let wanted = if r.handwheels.is_empty() {
            None
        } else {
            let mut w = vec![false; m.len()];
            for h in &r.handwheels {
                w[m.index(h)?] = true;
            }
            Some(w)
        };
        Ok(Subscription { wanted })
    }

    /// The feed events `r` asks for without a window, in messages of up to
    /// `max` events, read from the feed by the transport's task itself: no
    /// forwarding task per subscriber, half the wake-ups per event.
    fn direct_feed<B: Send + 'static>(
        &self,
        r: &pb::StreamFeedRequest,
        max: usize,
        batch: fn(Vec<pb::FeedEvent>) -> B,
    ) -> Result<MessageStream<B>, Status> {
        let sub = self.subscription(r)?;
        let m = self.gateway.handwheels().clone();
        let mut lost: u64 = 0;
        let map = move |received| match received {
            Received::Item(f) => sub.wants(&f).then(|| {
                let mut ev = event_pb(&m, &f);
                ev.lost_before = std::mem::take(&mut lost);
                ev
            }),
            Received::Lost(n) => {
                lost += n;
                None
            }
        };
        Ok(broadcast_batches(
            "StreamFeed",
            self.wheels().subscribe(),
            self.gateway.shutdown_token(),
            max,
            map,
            batch,
        ))
    }

    /// The feed events `r` asks for, summed per window of `coalesce_ms`
    /// (not 0: see [`Self::direct_feed`]) by a task of their own; the
    /// receiver ends when the client goes away or the gateway shuts down.
    fn windowed_feed(
        &self,
        r: pb::StreamFeedRequest,
    ) -> Result<tokio::sync::mpsc::Receiver<Result<pb::FeedEvent, Status>>, Status> {
        let sub = self.subscription(&r)?;
        let gateway = self.gateway.clone();
        let m = gateway.handwheels().clone();
        let mut rx = m.subscribe();
        let shutdown = gateway.shutdown_token();
        let coalesce = Duration::from_millis(u64::from(r.coalesce_ms.max(1)));
        let (tx, out) = tokio::sync::mpsc::channel(4096);
        tokio::spawn(async move {
            let mut lost: u64 = 0;
            // Open windows: (wheel, axis, direction) → summary.
            let mut window: Vec<((usize, i32, i32), pb::FeedEvent)> = Vec::new();
            let mut flush = tokio::time::interval(coalesce);
            flush.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            loop {
                tokio::select! {
                    _ = shutdown.cancelled() => {
                        let _ = tx.send(Err(super::error::ApiError::ShuttingDown.into())).await;
                        return;
                    }
                    _ = tx.closed() => return,
                    _ = flush.tick() => {
                        for (_, ev) in window.drain(..) {
                            if tx.send(Ok(ev)).await.is_err() {
                                return;
                            }
                        }
                    }
                    f = recv_counted("StreamFeed", &mut rx) => {
                        let f = match f {
                            Some(Received::Item(f)) => f,
                            Some(Received::Lost(n)) => {
                                lost += n;
                                continue;
                            }
                            None => return,
                        };
                        if !sub.wants(&f) {
                            continue;
                        }
                        let mut ev = event_pb(&m, &f);
                        ev.lost_before = std::mem::take(&mut lost);
                        let key = (f.wheel, ev.axis, ev.direction);
                        match window.iter_mut().find(|(k, _)| *k == key) {
                            Some((_, acc)) => {
                                let lb = ev.lost_before;
                                merge(acc, ev);
                                acc.lost_before += lb;
                            }
                            None => window.push((key, ev)),
                        }
                    }
                }
            }
        });
        Ok(out)
    }
}

/// Implementation of the Simulator service.
#[derive(Clone)]
pub struct SimulatorService {
    gateway: Arc<Gateway>,
}

impl SimulatorService {
    /// Serves the gateway's simulated devices.
    pub fn new(gateway: Arc<Gateway>) -> Self {
        SimulatorService { gateway }
    }
}

#[tonic::async_trait]
impl Simulator for SimulatorService {
    async fn turn_handwheel(
        &self,
        req: Request<pb::TurnHandwheelRequest>,
    ) -> Result<Response<pb::TurnHandwheelResponse>, Status> {
        let r = req.into_inner();
        let m = self.gateway.handwheels();
        let i = m.index(&r.handwheel)?;
        let Some(sim) = m.wheel(i).sim.clone() else {
            return Err(ApiError::FailedPrecondition(format!(
                "handwheel {} is not simulated by the gateway",
                r.handwheel
            ))
            .into());
        };
        let axis = match pb::WheelAxis::try_from(r.axis) {
            Ok(pb::WheelAxis::Unspecified) => None,
            Ok(pb::WheelAxis::X) => Some(HandwheelAxis::X),
            Ok(pb::WheelAxis::Y) => Some(HandwheelAxis::Y),
            Ok(pb::WheelAxis::Z) => Some(HandwheelAxis::Z),
            Ok(pb::WheelAxis::W) => Some(HandwheelAxis::W),
            Ok(pb::WheelAxis::V) => Some(HandwheelAxis::V),
            Err(_) => return Err(ApiError::InvalidArgument("unknown axis".into()).into()),
        };
        let mult = match r.multiplier {
            0 => None,
            1 => Some(Multiplier::X1),
            10 => Some(Multiplier::X10),
            100 => Some(Multiplier::X100),
            other => {
                return Err(ApiError::InvalidArgument(format!(
                    "multiplier must be 1, 10 or 100, got {other}"
                ))
                .into());
            }
        };
        if !(0.0..=1.0).contains(&r.loss) {
            return Err(ApiError::InvalidArgument(format!(
                "loss must be a probability 0..1, got {}",
                r.loss
            ))
            .into());
        }
        let loss = if r.loss > 0.0 {
            FrameLoss::Random {
                probability: r.loss,
                max_consecutive: if r.max_consecutive_loss == 0 {
                    14
                } else {
                    r.max_consecutive_loss
                },
                seed: fastrand::u64(..),
            }
        } else {
            FrameLoss::None
        };
        let (pending, discarded) = sim.with(|w| {
            if let Some(a) = axis {
                w.set_axis(a);
            }
            if let Some(x) = mult {
                w.set_multiplier(x);
            }
            w.set_frame_loss(loss);
            let before = w.stats().discarded_units;
            w.turn(r.detents);
            (w.pending_units(), w.stats().discarded_units - before)
        });
        Ok(Response::new(pb::TurnHandwheelResponse {
            pending_units: pending,
            discarded_units: discarded,
        }))
    }

    async fn list_simulated_devices(
        &self,
        _req: Request<pb::ListSimulatedDevicesRequest>,
    ) -> Result<Response<pb::ListSimulatedDevicesResponse>, Status> {
        super::simulator_service::list(&self.gateway)
    }

    async fn set_bus_faults(
        &self,
        req: Request<pb::SetBusFaultsRequest>,
    ) -> Result<Response<pb::BusFaults>, Status> {
        super::simulator_service::set_bus_faults(&self.gateway, req.into_inner())
    }

    async fn get_bus_faults(
        &self,
        req: Request<pb::GetBusFaultsRequest>,
    ) -> Result<Response<pb::BusFaults>, Status> {
        super::simulator_service::get_bus_faults(&self.gateway, req.into_inner())
    }

    async fn set_bus_off(
        &self,
        req: Request<pb::SetBusOffRequest>,
    ) -> Result<Response<pb::BusFaults>, Status> {
        super::simulator_service::set_bus_off(&self.gateway, req.into_inner())
    }

    async fn power_cycle_device(
        &self,
        req: Request<pb::PowerCycleDeviceRequest>,
    ) -> Result<Response<pb::SimulatedDevice>, Status> {
        super::simulator_service::power_cycle(&self.gateway, req.into_inner())
    }

    async fn send_emcy(
        &self,
        req: Request<pb::SendEmcyRequest>,
    ) -> Result<Response<pb::SimulatedDevice>, Status> {
        super::simulator_service::send_emcy(&self.gateway, req.into_inner())
    }

    async fn raise_drive_fault(
        &self,
        req: Request<pb::RaiseDriveFaultRequest>,
    ) -> Result<Response<pb::SimulatedDevice>, Status> {
        super::simulator_service::raise_drive_fault(&self.gateway, req.into_inner())
    }

    async fn set_io_inputs(
        &self,
        req: Request<pb::SetIoInputsRequest>,
    ) -> Result<Response<pb::SetIoInputsResponse>, Status> {
        super::simulator_service::set_io_inputs(&self.gateway, req.into_inner())
    }

    async fn set_program_faults(
        &self,
        req: Request<pb::SetProgramFaultsRequest>,
    ) -> Result<Response<pb::ProgramFaults>, Status> {
        super::simulator_service::set_program_faults(&self.gateway, req.into_inner())
    }
}
