//! The `cangate.v1.Cansmc` service: the CANsmc masters' phase, counters,
//! cycle timing and slaves, slave parameters, restarts
//! (`proto/cangate/v1/cansmc.proto`).

use super::error::ApiError;
use super::forward::{MessageStream, Received, recv_counted, stream_of};
use crate::cansmc::CansmcMaster;
use crate::convert::cansmc::{event_pb, master_info_pb, status_pb};
use crate::gateway::Gateway;
use cangate_cansmc::telegram::SmcAddress;
use cangate_proto::v1 as pb;
use cangate_proto::v1::cansmc_server::Cansmc;
use std::sync::Arc;
use std::time::Duration;
use tonic::{Request, Response, Status};

/// Period of StreamCycleStats when the request gives none.
const DEFAULT_INTERVAL_MS: u32 = 1000;
/// Bounds of the period of StreamCycleStats.
const INTERVAL_MS: std::ops::RangeInclusive<u32> = 50..=60_000;
/// Events a stream keeps between two updates; more are counted as lost.
const MAX_PENDING_EVENTS: usize = 1000;

/// Implementation of the Cansmc service.
#[derive(Clone)]
pub struct CansmcService {
    gateway: Arc<Gateway>,
}

impl CansmcService {
    /// Serves the gateway's CANsmc masters.
    pub fn new(gateway: Arc<Gateway>) -> Self {
        CansmcService { gateway }
    }

    /// The master called `name`; "" is the only one.
    fn master(&self, name: &str) -> Result<&CansmcMaster, ApiError> {
        if !name.is_empty() {
            return Ok(self.gateway.cansmc(name)?);
        }
        let all: Vec<&CansmcMaster> = self.gateway.cansmc_masters().collect();
        match all.as_slice() {
            [one] => Ok(one),
            [] => Err(ApiError::NotFound {
                kind: "CANsmc master",
                name: String::new(),
                hint: " (this gateway has no [[cansmc]] master)".into(),
            }),
            many => Err(ApiError::InvalidArgument(format!(
                "name a CANsmc master: this gateway has several ({})",
                many.iter().map(|m| m.name()).collect::<Vec<_>>().join(", ")
            ))),
        }
    }
}

/// Names the master (and, for a refused write, the value) in the errors
/// the slave or the cycle caused; argument errors are clear as they are.
/// A slave address and parameter number from the wire: 1..=61, 16 bits.
fn parameter_target(address: u32, number: u32) -> Result<(SmcAddress, u16), ApiError> {
    let a = u8::try_from(address)
        .ok()
        .and_then(|a| SmcAddress::new(a).ok())
        .ok_or_else(|| {
            ApiError::InvalidArgument(format!("slave address {address} is outside 1..=61"))
        })?;
    let n = u16::try_from(number).map_err(|_| {
        ApiError::InvalidArgument(format!("parameter number {number} exceeds 65535"))
    })?;
    Ok((a, n))
}

fn parameter_context(master: &str, write: Option<i32>, e: ApiError) -> ApiError {
    let named = |m: String| format!("master {master}: {m}");
    match e {
        ApiError::FailedPrecondition(m) => ApiError::FailedPrecondition(match write {
            Some(v) => format!("{}; {v} was not written", named(m)),
            None => named(m),
        }),
        ApiError::DeadlineExceeded(m) => ApiError::DeadlineExceeded(named(m)),
        ApiError::Unavailable(m) => ApiError::Unavailable(named(m)),
        ApiError::Aborted(m) => ApiError::Aborted(named(m)),
        other => other,
    }
}

fn peer<T>(req: &Request<T>) -> String {
    super::caller(req)
}

type StatsStream = MessageStream<pb::CycleStatsUpdate>;

#[tonic::async_trait]
impl Cansmc for CansmcService {
    async fn list_masters(
        &self,
        _req: Request<pb::ListMastersRequest>,
    ) -> Result<Response<pb::ListMastersResponse>, Status> {
        Ok(Response::new(pb::ListMastersResponse {
            masters: self.gateway.cansmc_masters().map(master_info_pb).collect(),
        }))
    }

    async fn get_status(
        &self,
        req: Request<pb::GetCansmcStatusRequest>,
    ) -> Result<Response<pb::CansmcStatus>, Status> {
        let m = self.master(&req.get_ref().master)?;
        Ok(Response::new(status_pb(m, &m.status())))
    }

    async fn read_parameter(
        &self,
        req: Request<pb::ReadParameterRequest>,
    ) -> Result<Response<pb::ParameterValue>, Status> {
        let r = req.into_inner();
        let m = self.master(&r.master)?;
        let (address, number) = parameter_target(r.address, r.number)?;
        let value = m
            .parameter(address, number, None)
            .await
            .map_err(|e| parameter_context(m.name(), None, e.into()))?;
        Ok(Response::new(pb::ParameterValue {
            master: m.name().to_string(),
            address: r.address,
            number: r.number,
            value,
        }))
    }

    async fn write_parameter(
        &self,
        req: Request<pb::WriteParameterRequest>,
    ) -> Result<Response<pb::ParameterValue>, Status> {
        let peer = peer(&req);
        let r = req.into_inner();
        let m = self.master(&r.master)?;
        let (address, number) = parameter_target(r.address, r.number)?;
        let res = m
            .parameter(address, number, Some(r.value))
            .await
            .map_err(|e| parameter_context(m.name(), Some(r.value), e.into()));
        tracing::info!(target: "cangate::audit", %peer, master = %m.name(), slave = r.address, parameter = r.number, value = r.value, result = %res.as_ref().map_or_else(|e| e.to_string(), |v| format!("ok ({v})")), "CANsmc parameter write");
        let value = res?;
        Ok(Response::new(pb::ParameterValue {
            master: m.name().to_string(),
            address: r.address,
            number: r.number,
            value,
        }))
    }

    type StreamCycleStatsStream = StatsStream;

    async fn stream_cycle_stats(
        &self,
        req: Request<pb::StreamCycleStatsRequest>,
    ) -> Result<Response<Self::StreamCycleStatsStream>, Status> {
        let r = req.into_inner();
        let m = self.master(&r.master)?.clone();
        let interval_ms = match r.interval_ms {
            0 => DEFAULT_INTERVAL_MS,
            ms if INTERVAL_MS.contains(&ms) => ms,
            ms => {
                return Err(ApiError::InvalidArgument(format!(
                    "interval_ms {ms} is outside {}..={} (0 = {DEFAULT_INTERVAL_MS})",
                    INTERVAL_MS.start(),
                    INTERVAL_MS.end()
                ))
                .into());
            }
        };
        // Subscribed before the first status: no event falls in between.
        let mut events = m.events();
        let shutdown = self.gateway.shutdown_token();
        let (tx, out) = tokio::sync::mpsc::channel(16);
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_millis(u64::from(interval_ms)));
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            let mut pending = Vec::new();
            let mut lost: u64 = 0;
            let mut events_open = true;
            loop {
                tokio::select! {
                    biased;
                    _ = shutdown.cancelled() => {
                        let _ = tx.send(Err(super::error::ApiError::ShuttingDown.into())).await;
                        return;
                    }
                    _ = tx.closed() => return,
                    e = recv_counted("StreamCycleStats", &mut events), if events_open => match e {
                        Some(Received::Item(e)) if pending.len() < MAX_PENDING_EVENTS => pending.push(event_pb(e)),
                        Some(Received::Item(_)) => lost += 1,
                        Some(Received::Lost(n)) => lost += n,
                        None => events_open = false,
                    },
                    _ = tick.tick() => {
                        let update = pb::CycleStatsUpdate {
                            status: Some(status_pb(&m, &m.status())),
                            events: std::mem::take(&mut pending),
                            events_lost: std::mem::take(&mut lost),
                        };
                        if tx.send(Ok(update)).await.is_err() {
                            return;
                        }
                    }
                }
            }
        });
        Ok(Response::new(stream_of(out)))
    }

    async fn restart(
        &self,
        req: Request<pb::RestartRequest>,
    ) -> Result<Response<pb::RestartResponse>, Status> {
        let peer = peer(&req);
        let r = req.into_inner();
        let m = self.master(&r.master)?;
        let res = m.restart().await;
        tracing::info!(target: "cangate::audit", %peer, master = %m.name(), result = %res.as_ref().map_or_else(|e| e.to_string(), |_| "ok".into()), "CANsmc master restart");
        res?;
        Ok(Response::new(pb::RestartResponse {
            master: m.name().to_string(),
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parameter_errors_name_the_master() {
        let e = parameter_context(
            "smc",
            Some(7),
            ApiError::FailedPrecondition("slave 1 refused parameter 3".into()),
        );
        assert_eq!(
            e.to_string(),
            "master smc: slave 1 refused parameter 3; 7 was not written"
        );
        let e = parameter_context("smc", None, ApiError::DeadlineExceeded("late".into()));
        assert_eq!(e.to_string(), "master smc: late");
        let e = parameter_context("smc", None, ApiError::InvalidArgument("bad".into()));
        assert_eq!(e.to_string(), "bad");
    }

    #[test]
    fn a_parameter_target_off_the_protocol_is_an_invalid_argument() {
        let (a, n) = parameter_target(61, 65_535).unwrap();
        assert_eq!((a.get(), n), (61, 65_535));
        for (address, number, says) in [
            (0, 1, "slave address 0 is outside 1..=61"),
            (62, 1, "slave address 62 is outside 1..=61"),
            (300, 1, "slave address 300 is outside 1..=61"),
            (1, 70_000, "parameter number 70000 exceeds 65535"),
        ] {
            match parameter_target(address, number) {
                Err(ApiError::InvalidArgument(m)) => assert_eq!(m, says),
                other => panic!("{address}/{number}: {other:?}"),
            }
        }
    }
}
