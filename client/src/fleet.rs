//! The gateways a broker has seen: the retained statuses their plant
//! bridges publish (`cangate/v1/pb/<gateway>/status`, see docs/bridge.md).

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
