//! The gateways a broker has seen: the retained statuses their plant
//! bridges publish (`cangate/v1/pb/<gateway>/status`, see docs/bridge.md);
//! on NATS, the last status of each gateway in the JetStream stream
//! `CANGATE_STATUS`.

use crate::pb;
use prost::Message;
use rumqttc::{AsyncClient, Event, Incoming, MqttOptions, QoS, SubscribeFilter};
use std::collections::BTreeMap;
use std::time::Duration;

/// Why the statuses could not be read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FleetError(pub String);

impl std::fmt::Display for FleetError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for FleetError {}

/// Host and port of an `mqtt://host[:port]` URL.
fn broker(url: &str) -> Result<(String, u16), FleetError> {
    let rest = url
        .strip_prefix("mqtt://")
        .ok_or_else(|| FleetError(format!("broker {url:?} is not mqtt://host[:port]")))?;
    let rest = rest.trim_end_matches('/');
    match rest.rsplit_once(':') {
        Some((h, p)) => Ok((
            h.to_string(),
            p.parse()
                .map_err(|_| FleetError(format!("broker port {p:?} is not a number")))?,
        )),
        None => Ok((rest.to_string(), 1883)),
    }
}

/// The status each gateway last left on the broker at `url`, by gateway
/// id: online ones and those whose last will said offline. Waits at most
/// `timeout` for the broker.
///
/// All retained statuses are in once a probe published after the
/// subscription comes back: the broker sends a subscription's retained
/// messages before it handles the client's next packet.
pub async fn gateways(
    url: &str,
    timeout: Duration,
) -> Result<BTreeMap<String, pb::GatewayStatus>, FleetError> {
    if url.starts_with("nats://") || url.starts_with("tls://") {
        return match tokio::time::timeout(timeout, nats_gateways(url)).await {
            Ok(r) => r,
            Err(_) => Err(FleetError(format!(
                "broker {url}: no answer within {timeout:?}"
            ))),
        };
    }
    let (host, port) = broker(url)?;
    let nonce = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    let id = format!("cangate-fleet-{}-{nonce}", std::process::id());
    let probe = format!("cangate/fleet-probe/{id}");
    let mut options = MqttOptions::new(id, host, port);
    options
        .set_clean_session(true)
        .set_keep_alive(Duration::from_secs(5))
        .set_max_packet_size(1 << 20, 1 << 20);
    let (client, mut events) = AsyncClient::new(options, 10);
    let mut found = BTreeMap::new();
    let read = async {
        loop {
            let event = events
                .poll()
                .await
                .map_err(|e| FleetError(format!("broker {url}: {e}")))?;
            match event {
                Event::Incoming(Incoming::ConnAck(_)) => {
                    let filters = [
                        SubscribeFilter::new("cangate/v1/pb/+/status".into(), QoS::AtLeastOnce),
                        SubscribeFilter::new(probe.clone(), QoS::AtLeastOnce),
                    ];
                    client
                        .subscribe_many(filters)
                        .await
                        .map_err(|e| FleetError(e.to_string()))?;
                }
                Event::Incoming(Incoming::SubAck(_)) => {
                    client
                        .publish(probe.clone(), QoS::AtLeastOnce, false, Vec::new())
                        .await
                        .map_err(|e| FleetError(e.to_string()))?;
                }
                Event::Incoming(Incoming::Publish(p)) if p.topic == probe => return Ok(()),
                Event::Incoming(Incoming::Publish(p)) => {
                    if let Ok(env) = pb::BridgeEnvelope::decode(p.payload.as_ref())
                        && let Some(pb::bridge_envelope::Payload::Status(s)) = env.payload
                    {
                        found.insert(s.gateway.clone(), s);
                    }
                }
                _ => {}
            }
        }
    };
    match tokio::time::timeout(timeout, read).await {
        Ok(r) => r?,
        Err(_) => {
            return Err(FleetError(format!(
                "broker {url}: no answer within {timeout:?}"
            )));
        }
    }
    let _ = client.try_disconnect();
    Ok(found)
}

/// The stream where every gateway's bridge keeps its last status (the
/// gateway's `bridge::nats::STATUS_STREAM`).
const NATS_STATUS_STREAM: &str = "CANGATE_STATUS";
/// A bridge publishes its status again this often while it is connected
/// (the gateway's `bridge::nats::HEARTBEAT`).
const NATS_HEARTBEAT_NS: u64 = 5_000_000_000;

/// Whether an online status published at `published_ns` is stale at
/// `now_ns`: three heartbeats missed, so the gateway was killed, lost
/// power or its network (NATS has no last will to say so).
pub fn stale(published_ns: u64, now_ns: u64) -> bool {
    now_ns.saturating_sub(published_ns) > 3 * NATS_HEARTBEAT_NS
}

/// The last status of each gateway in the NATS server's status stream;
/// an online status that is [`stale`] is reported offline.
async fn nats_gateways(url: &str) -> Result<BTreeMap<String, pb::GatewayStatus>, FleetError> {
    use async_nats::jetstream::context::GetStreamErrorKind;
    use futures::StreamExt;
    let fail = |e: &dyn std::fmt::Display| FleetError(format!("broker {url}: {e}"));
    let client = async_nats::ConnectOptions::new()
        .name("cangate-fleet")
        .connect(url)
        .await
        .map_err(|e| fail(&e))?;
    let js = async_nats::jetstream::new(client.clone());
    let stream = match js.get_stream(NATS_STATUS_STREAM).await {
        Ok(s) => s,
        Err(e) => {
            if let GetStreamErrorKind::JetStream(j) = e.kind()
                && j.error_code() == async_nats::jetstream::ErrorCode::STREAM_NOT_FOUND
            {
                return Ok(BTreeMap::new());
            }
            return Err(fail(&e));
        }
    };
    // Each subject with its message count.
    let mut subjects = Vec::new();
    let mut listed = stream
        .info_with_subjects("cangate.v1.pb.*.status")
        .await
        .map_err(|e| fail(&e))?;
    while let Some(s) = listed.next().await {
        subjects.push(s.map_err(|e| fail(&e))?);
    }
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0);
    let mut found = BTreeMap::new();
    for subject in subjects {
        let m = stream
            .get_last_raw_message_by_subject(&subject.0)
            .await
            .map_err(|e| fail(&e))?;
        if let Ok(env) = pb::BridgeEnvelope::decode(m.payload.as_ref())
            && let Some(pb::bridge_envelope::Payload::Status(mut s)) = env.payload
        {
            if s.online && stale(env.timestamp_ns, now) {
                s.online = false;
            }
            found.insert(s.gateway.clone(), s);
        }
    }
    Ok(found)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_status_three_heartbeats_old_is_stale() {
        let t = 1_000 * NATS_HEARTBEAT_NS;
        assert!(!stale(t, t));
        assert!(!stale(t, t + 3 * NATS_HEARTBEAT_NS));
        assert!(stale(t, t + 3 * NATS_HEARTBEAT_NS + 1));
        assert!(!stale(t, t - 1), "a clock a little behind is not stale");
    }
}
