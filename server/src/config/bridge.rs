//! The `[[bridge]]` sections: publishers of the gateway's streams to a
//! message broker (see docs/bridge.md). A bridge is read-only: it
//! publishes, it takes no commands.
//!
//! No secret is written in the configuration: passwords live in files the
//! configuration names (`password_file`), so `--print-config` and the log
//! show paths, never secrets.

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// One bridge to one broker (`[[bridge]]`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BridgeConfig {
    /// The bridge's name (in the log and the metrics' `bridge` label).
    pub name: String,
    /// The broker: `mqtt://host:port` (default port 1883),
    /// `mqtts://host:port` (TLS, default port 8883), `nats://host:port`
    /// (NATS with JetStream, default port 4222) or `tls://host:port`
    /// (NATS over TLS, default port 4222).
    pub url: String,
    /// The gateway's id in the topic tree (`cangate/v1/<format>/<gateway>/…`);
    /// default: the host name. Letters, digits, `-` and `_` only.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gateway: Option<String>,
    /// What to publish (default: status, node events, bus statistics).
    #[serde(default = "default_streams")]
    pub streams: Vec<BridgeStream>,
    /// The buses whose streams are published (empty: every bus).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub buses: Vec<String>,
    /// The payload formats, each its own topic tree (`pb`, `json`;
    /// default both).
    #[serde(default = "default_formats")]
    pub formats: Vec<BridgeFormat>,
    /// Messages held while the broker is away or slower than the gateway
    /// (per format). When full, the oldest not yet sent is dropped and a
    /// gap record says which. Default 10000.
    #[serde(default = "default_queue_size")]
    pub queue_size: u32,
    /// Frame filters in candump syntax (`123:7FF`, `18FF0000:1FFF0000`,
    /// `~` inverts) for the `frames` stream; empty: every frame.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub frame_filters: Vec<String>,
    /// Most frames published per second and bus; frames over the rate are
    /// counted in the batch as lost (FramesLost), not published. Default
    /// 1000; 0: no limit.
    #[serde(default = "default_frame_rate")]
    pub frame_rate_limit: u32,
    /// Longest time a frame waits for its batch, ms (default 100).
    #[serde(default = "default_frame_batch_ms")]
    pub frame_batch_ms: u64,
    /// Period of the `bus_stats` and `cansmc_status` streams, ms (default
    /// 1000).
    #[serde(default = "default_stats_interval_ms")]
    pub stats_interval_ms: u64,
    /// Shortest time between two states of one axis on `axis_state`, ms
    /// (default 100).
    #[serde(default = "default_axis_state_interval_ms")]
    pub axis_state_interval_ms: u64,
    /// The axes whose state and events are published (empty: every axis).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub axes: Vec<String>,
    /// User name (MQTT, NATS).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub username: Option<String>,
    /// A file holding the password of `username` (its first line).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub password_file: Option<PathBuf>,
    /// A file holding a NATS token (its first line).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub token_file: Option<PathBuf>,
    /// A file holding a NATS NKey seed (`SU…`, its first line).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nkey_file: Option<PathBuf>,
    /// A NATS credentials file (user JWT and NKey seed, `.creds`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub credentials_file: Option<PathBuf>,
    /// PEM CA certificate(s) to verify the broker with (`mqtts://`,
    /// `tls://`; default: the system's roots).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ca: Option<PathBuf>,
    /// PEM client certificate for TLS client authentication (with `key`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cert: Option<PathBuf>,
    /// PEM private key of `cert`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub key: Option<PathBuf>,
}

/// A stream a bridge can publish.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BridgeStream {
    /// The CANopen node events of each bus
    /// (`bus/<bus>/node/<id>/event`: boot-up, NMT state, heartbeat
    /// lost/recovered, EMCY, guarding).
    NodeEvents,
    /// Batches of frames of each bus (`bus/<bus>/frames`, QoS 0).
    Frames,
    /// The state and counters of each bus (`bus/<bus>/stats`).
    BusStats,
    /// Each axis's live state (`axis/<name>/state`, retained; at most one
    /// per `axis_state_interval_ms`, when it changed).
    AxisState,
    /// Each axis's events (`axis/<name>/event`).
    AxisEvents,
    /// Each handwheel's feed events (`handwheel/<name>/feed`).
    HandwheelFeed,
    /// Each CANsmc master's status (`cansmc/<master>/status`, every
    /// `stats_interval_ms`).
    CansmcStatus,
}

/// A payload format: its own topic tree.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BridgeFormat {
    /// Protobuf (`cangate/v1/pb/…`).
    Pb,
    /// Canonical proto3 JSON (`cangate/v1/json/…`).
    Json,
}

impl BridgeFormat {
    /// The topic level naming the format.
    pub fn level(self) -> &'static str {
        match self {
            BridgeFormat::Pb => "pb",
            BridgeFormat::Json => "json",
        }
    }
}

fn default_streams() -> Vec<BridgeStream> {
    vec![BridgeStream::NodeEvents, BridgeStream::BusStats]
}
fn default_formats() -> Vec<BridgeFormat> {
    vec![BridgeFormat::Pb, BridgeFormat::Json]
}
fn default_queue_size() -> u32 {
    10_000
}
fn default_frame_rate() -> u32 {
    1000
}
fn default_frame_batch_ms() -> u64 {
    100
}
fn default_stats_interval_ms() -> u64 {
    1000
}
fn default_axis_state_interval_ms() -> u64 {
    100
}

/// The broker's protocol.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BrokerProtocol {
    /// MQTT 3.1.1.
    Mqtt,
    /// NATS with JetStream.
    Nats,
}

/// The broker address of a bridge URL.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BrokerAddress {
    /// The protocol.
    pub protocol: BrokerProtocol,
    /// Host name or address.
    pub host: String,
    /// TCP port.
    pub port: u16,
    /// TLS (`mqtts://`, `tls://`).
    pub tls: bool,
}

impl BridgeConfig {
    /// The broker's host, port and whether it speaks TLS.
    pub fn broker(&self) -> Result<BrokerAddress, String> {
        let (protocol, tls, rest) = if let Some(r) = self.url.strip_prefix("mqtt://") {
            (BrokerProtocol::Mqtt, false, r)
        } else if let Some(r) = self.url.strip_prefix("mqtts://") {
            (BrokerProtocol::Mqtt, true, r)
        } else if let Some(r) = self.url.strip_prefix("nats://") {
            (BrokerProtocol::Nats, false, r)
        } else if let Some(r) = self.url.strip_prefix("tls://") {
            (BrokerProtocol::Nats, true, r)
        } else {
            return Err(format!(
                "[[bridge]] {:?}: url {:?} is not mqtt://host:port, mqtts://host:port, \
                 nats://host:port or tls://host:port",
                self.name, self.url
            ));
        };
        let rest = rest.trim_end_matches('/');
        let (host, port) = match rest.rsplit_once(':') {
            Some((h, p)) if !h.ends_with(']') || h.starts_with('[') => {
                let port = p.parse::<u16>().map_err(|_| {
                    format!("[[bridge]] {:?}: port {p:?} is not a number", self.name)
                })?;
                (h, port)
            }
            _ => (
                rest,
                match (protocol, tls) {
                    (BrokerProtocol::Nats, _) => 4222,
                    (BrokerProtocol::Mqtt, true) => 8883,
                    (BrokerProtocol::Mqtt, false) => 1883,
                },
            ),
        };
        let host = host.trim_start_matches('[').trim_end_matches(']');
        if host.is_empty() || host.contains('/') || host.contains('@') {
            return Err(format!(
                "[[bridge]] {:?}: url {:?} needs a host (no user or path in it; \
                 use username and password_file)",
                self.name, self.url
            ));
        }
        Ok(BrokerAddress {
            protocol,
            host: host.to_string(),
            port,
            tls,
        })
    }

    /// The gateway id, checked: the configured one or the host name.
    pub fn gateway_id(&self) -> Result<String, String> {
        let id = match &self.gateway {
            Some(g) => g.clone(),
            None => host_name(),
        };
        if id.is_empty()
            || !id
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        {
            return Err(format!(
                "[[bridge]] {:?}: gateway id {id:?} must be letters, digits, - and _ \
                 (it is a topic level)",
                self.name
            ));
        }
        Ok(id)
    }

    /// The frame filters, parsed.
    pub fn filters(&self) -> Result<Vec<cangate_can::Filter>, String> {
        (self.frame_filters.iter())
            .map(|f| {
                f.parse()
                    .map_err(|e| format!("[[bridge]] {:?}: {e}", self.name))
            })
            .collect()
    }

    /// Checks of the section on its own.
    pub fn check(&self) -> Result<(), String> {
        let name = &self.name;
        if name.is_empty() {
            return Err("[[bridge]]: a bridge has an empty name".into());
        }
        let broker = self.broker()?;
        self.gateway_id()?;
        self.filters()?;
        if self.formats.is_empty() {
            return Err(format!("[[bridge]] {name:?}: formats is empty"));
        }
        if self.queue_size == 0 {
            return Err(format!(
                "[[bridge]] {name:?}: queue_size must be at least 1"
            ));
        }
        if self.frame_batch_ms == 0
            || self.stats_interval_ms == 0
            || self.axis_state_interval_ms == 0
        {
            return Err(format!(
                "[[bridge]] {name:?}: frame_batch_ms, stats_interval_ms and \
                 axis_state_interval_ms must be at least 1"
            ));
        }
        if self.cert.is_some() != self.key.is_some() {
            return Err(format!("[[bridge]] {name:?}: give cert and key together"));
        }
        let nats_auth = [
            self.token_file.is_some(),
            self.nkey_file.is_some(),
            self.credentials_file.is_some(),
        ];
        if broker.protocol == BrokerProtocol::Mqtt && nats_auth.contains(&true) {
            return Err(format!(
                "[[bridge]] {name:?}: token_file, nkey_file and credentials_file are for \
                 nats:// and tls://"
            ));
        }
        let ways = nats_auth.iter().filter(|&&w| w).count() + usize::from(self.username.is_some());
        if ways > 1 {
            return Err(format!(
                "[[bridge]] {name:?}: give one of username, token_file, nkey_file and \
                 credentials_file"
            ));
        }
        if !broker.tls && (self.ca.is_some() || self.cert.is_some()) {
            return Err(format!(
                "[[bridge]] {name:?}: ca, cert and key need an mqtts:// or tls:// url"
            ));
        }
        if self.password_file.is_some() && self.username.is_none() {
            return Err(format!(
                "[[bridge]] {name:?}: password_file needs a username"
            ));
        }
        Ok(())
    }
}

/// The host name (`/proc/sys/kernel/hostname`, else `$HOSTNAME`, else
/// `cangate`).
fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .or_else(|| std::env::var("HOSTNAME").ok())
        .map(|h| h.trim().to_string())
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "cangate".to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bridge(toml: &str) -> Result<BridgeConfig, String> {
        let c: BridgeConfig = toml::from_str(toml).map_err(|e| e.to_string())?;
        c.check().map(|()| c)
    }

    #[test]
    fn a_minimal_bridge_takes_the_defaults() {
        let b =
            bridge("name = \"plant\"\nurl = \"mqtt://127.0.0.1:1884\"\ngateway = \"m1\"").unwrap();
        assert_eq!(
            b.broker().unwrap(),
            BrokerAddress {
                protocol: BrokerProtocol::Mqtt,
                host: "127.0.0.1".into(),
                port: 1884,
                tls: false
            }
        );
        assert_eq!(b.formats, [BridgeFormat::Pb, BridgeFormat::Json]);
        assert_eq!(
            b.streams,
            [BridgeStream::NodeEvents, BridgeStream::BusStats]
        );
        assert_eq!(b.queue_size, 10_000);
        let tls = bridge("name = \"p\"\nurl = \"mqtts://broker.plant\"\ngateway = \"m1\"").unwrap();
        assert_eq!(tls.broker().unwrap().port, 8883);
        let nats = bridge("name = \"p\"\nurl = \"nats://broker.plant\"\ngateway = \"m1\"").unwrap();
        assert_eq!(
            nats.broker().unwrap(),
            BrokerAddress {
                protocol: BrokerProtocol::Nats,
                host: "broker.plant".into(),
                port: 4222,
                tls: false
            }
        );
        let nats_tls =
            bridge("name = \"p\"\nurl = \"tls://broker.plant:4443\"\ngateway = \"m1\"").unwrap();
        assert_eq!(nats_tls.broker().unwrap().port, 4443);
        assert!(nats_tls.broker().unwrap().tls);
    }

    #[test]
    fn print_config_shows_the_password_file_never_a_password() {
        let text = "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\n\n[[bridge]]\n\
                    name = \"plant\"\nurl = \"mqtt://h\"\ngateway = \"m1\"\n\
                    username = \"m1\"\npassword_file = \"/run/secrets/mqtt\"\n";
        let c = crate::config::Config::from_toml(text).unwrap();
        let printed = c.to_toml();
        assert!(
            printed.contains("password_file = \"/run/secrets/mqtt\""),
            "{printed}"
        );
        assert_eq!(crate::config::Config::from_toml(&printed).unwrap(), c);
        let e = crate::config::Config::from_toml(&text.replace("password_file", "password"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("password"),
            "a password in the file is refused: {e}"
        );
    }

    #[test]
    fn print_config_shows_the_nats_secret_files_never_a_secret() {
        for key in ["token_file", "nkey_file", "credentials_file"] {
            let text = format!(
                "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\n\n[[bridge]]\n\
                 name = \"plant\"\nurl = \"nats://h\"\ngateway = \"m1\"\n\
                 {key} = \"/run/secrets/nats\"\n"
            );
            let c = crate::config::Config::from_toml(&text).unwrap();
            let printed = c.to_toml();
            assert!(
                printed.contains(&format!("{key} = \"/run/secrets/nats\"")),
                "{printed}"
            );
            assert_eq!(crate::config::Config::from_toml(&printed).unwrap(), c);
        }
        for key in ["token", "nkey", "credentials"] {
            let text = format!("name = \"p\"\nurl = \"nats://h\"\n{key} = \"s3cret\"\n");
            let e = bridge(&text).unwrap_err();
            assert!(
                e.contains("unknown field"),
                "a secret in the file is refused: {e}"
            );
        }
    }

    #[test]
    fn unknown_keys_and_bad_values_are_refused() {
        let base = "name = \"p\"\ngateway = \"m1\"\n";
        for (extra, says) in [
            ("url = \"mqtt://h\"\npassword = \"x\"", "unknown field"),
            ("url = \"http://h\"", "is not mqtt://"),
            ("url = \"mqtt://user:pw@h:1883\"", "no user"),
            ("url = \"mqtt://h:x\"", "is not a number"),
            (
                "url = \"mqtt://h\"\nstreams = [\"axes\"]",
                "unknown variant",
            ),
            ("url = \"mqtt://h\"\nformats = []", "formats is empty"),
            (
                "url = \"mqtt://h\"\naxis_state_interval_ms = 0",
                "at least 1",
            ),
            ("url = \"mqtt://h\"\nqueue_size = 0", "queue_size"),
            (
                "url = \"mqtt://h\"\nframe_filters = [\"12x\"]",
                "is not <id>:<mask>",
            ),
            ("url = \"mqtt://h\"\nca = \"/ca.pem\"", "need an mqtts://"),
            ("url = \"nats://h\"\nca = \"/ca.pem\"", "or tls://"),
            ("url = \"mqtt://h\"\ntoken_file = \"/t\"", "are for nats://"),
            (
                "url = \"nats://h\"\ntoken_file = \"/t\"\nnkey_file = \"/n\"",
                "give one of",
            ),
            (
                "url = \"mqtts://h\"\ncert = \"/c.pem\"",
                "cert and key together",
            ),
            (
                "url = \"mqtt://h\"\npassword_file = \"/pw\"",
                "needs a username",
            ),
        ] {
            let e = bridge(&format!("{base}{extra}")).unwrap_err();
            assert!(e.contains(says), "{extra}: {e}");
        }
        let e = bridge("name = \"p\"\nurl = \"mqtt://h\"\ngateway = \"a/b\"").unwrap_err();
        assert!(e.contains("topic level"), "{e}");
    }
}
