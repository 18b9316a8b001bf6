//! The `[socketcand]` section: an optional listener speaking the
//! socketcand protocol (raw mode) for tools that already speak it
//! (python-can's `socketcand` interface, SavvyCAN, Kayak).

use serde::{Deserialize, Serialize};
use std::net::SocketAddr;

/// The socketcand listener (`[socketcand]`); absent: off.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SocketcandConfig {
    /// Listen address, e.g. `127.0.0.1:29536` (socketcand's own default
    /// port); port 0 picks a free port. Without authentication it must be
    /// a loopback address.
    pub listen: SocketAddr,
    /// Connections open at once (see `max_connections_per_peer` for who
    /// gives up a slot to a newcomer).
    #[serde(default = "default_max_connections")]
    pub max_connections: u32,
    /// Connections open at once from one address. At either limit, the
    /// oldest connection that has not opened a bus yet is closed to make
    /// room (from that address, at this one); only when every one has a
    /// bus open is the new one refused.
    #[serde(default = "default_max_connections_per_peer")]
    pub max_connections_per_peer: u32,
    /// The buses clients may open (empty: every bus).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub buses: Vec<String>,
    /// Frames queued for one client before it loses frames (counted), out
    /// of its `max_stream_queue_per_client` as a stream's queue is.
    #[serde(default = "default_queue_length")]
    pub queue_length: u32,
    /// Longest command (`<` to `>`) in bytes; a longer one ends the
    /// connection.
    #[serde(default = "default_max_command_bytes")]
    pub max_command_bytes: u32,
    /// Time from connecting to a successful `< open … >`, ms.
    #[serde(default = "default_handshake_timeout_ms")]
    pub handshake_timeout_ms: u64,
    /// A connection in BCM mode (bus open, no frame feed) that sends
    /// nothing for this long is closed, s (0: never). Raw mode connections
    /// are receiving and are never idle; a dead peer is found by TCP
    /// keepalive and by `write_timeout_ms`.
    #[serde(default = "default_idle_timeout_s")]
    pub idle_timeout_s: u64,
    /// A write to the client that does not complete within this long ends
    /// the connection (a client that stopped reading), ms.
    #[serde(default = "default_write_timeout_ms")]
    pub write_timeout_ms: u64,
}

fn default_max_connections() -> u32 {
    16
}
fn default_max_connections_per_peer() -> u32 {
    8
}
fn default_queue_length() -> u32 {
    8192
}
fn default_max_command_bytes() -> u32 {
    1024
}
fn default_handshake_timeout_ms() -> u64 {
    10_000
}
fn default_idle_timeout_s() -> u64 {
    300
}
fn default_write_timeout_ms() -> u64 {
    10_000
}

impl SocketcandConfig {
    /// A listener on `listen` with the defaults.
    pub fn new(listen: SocketAddr) -> Self {
        SocketcandConfig {
            listen,
            max_connections: default_max_connections(),
            max_connections_per_peer: default_max_connections_per_peer(),
            buses: Vec::new(),
            queue_length: default_queue_length(),
            max_command_bytes: default_max_command_bytes(),
            handshake_timeout_ms: default_handshake_timeout_ms(),
            idle_timeout_s: default_idle_timeout_s(),
            write_timeout_ms: default_write_timeout_ms(),
        }
    }

    /// Checks the values and the rules that tie the listener to
    /// `[security]`: `authentication` (tokens or client certificates
    /// configured) and `tokens` (bearer tokens configured).
    pub(super) fn check(&self, authentication: bool, tokens: bool) -> Result<(), String> {
        if !authentication && !self.listen.ip().is_loopback() {
            return Err(format!(
                "[socketcand] listen = {} is reachable from the network, and the gateway has no \
                 authentication: anyone who reaches it could send raw frames. socketcand \
                 without tokens must listen on loopback (127.0.0.1 or ::1); \
                 [security] insecure does not cover it. Configure [[security.tokens]] (clients \
                 then open with < open BUS TOKEN >) or listen on 127.0.0.1",
                self.listen
            ));
        }
        if authentication && !tokens {
            return Err(
                "[socketcand] needs [[security.tokens]] when authentication is on: a socketcand \
                 client proves who it is with a token in < open BUS TOKEN > (client \
                 certificates need TLS, which socketcand does not speak)"
                    .into(),
            );
        }
        for (key, value, range) in [
            ("max_connections", u64::from(self.max_connections), 1..=4096),
            (
                "max_connections_per_peer",
                u64::from(self.max_connections_per_peer),
                1..=4096,
            ),
            ("queue_length", u64::from(self.queue_length), 16..=1_000_000),
            (
                "max_command_bytes",
                u64::from(self.max_command_bytes),
                64..=65536,
            ),
            (
                "handshake_timeout_ms",
                self.handshake_timeout_ms,
                100..=600_000,
            ),
            ("idle_timeout_s", self.idle_timeout_s, 0..=86_400),
            ("write_timeout_ms", self.write_timeout_ms, 100..=600_000),
        ] {
            if !range.contains(&value) {
                return Err(format!(
                    "[socketcand] {key} = {value} is out of range ({}..={})",
                    range.start(),
                    range.end()
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use crate::config::Config;

    const BUS: &str = "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\n";
    const TOKEN: &str = "[[security.tokens]]\nname = \"eng\"\nrole = \"engineer\"\n\
        sha256 = \"9f86d081884c7d659a2feaa0c55ad015a3bf4f1b2b0b822cd15d6c15b0f00a08\"\n";

    fn err(text: &str) -> String {
        Config::from_toml(text).unwrap_err().to_string()
    }

    #[test]
    fn socketcand_is_off_by_default_and_loopback_without_authentication() {
        assert!(Config::demo().socketcand.is_none());
        let c = Config::from_toml(&format!(
            "{BUS}[socketcand]\nlisten = \"127.0.0.1:29536\"\nbuses = [\"can0\"]\n"
        ))
        .unwrap();
        let s = c.socketcand.unwrap();
        assert_eq!((s.max_connections, s.queue_length), (16, 8192));
        // Without tokens, never on the network: not even with insecure.
        let e = err(&format!(
            "{BUS}[security]\ninsecure = true\n[socketcand]\nlisten = \"0.0.0.0:29536\"\n"
        ));
        assert!(e.contains("must listen on loopback"), "{e}");
        // With tokens it may.
        Config::from_toml(&format!(
            "listen = \"0.0.0.0:50051\"\n{BUS}[socketcand]\nlisten = \"0.0.0.0:29536\"\n{TOKEN}"
        ))
        .unwrap();
    }

    #[test]
    fn socketcand_mistakes_are_named() {
        let e = err(&format!(
            "{BUS}[socketcand]\nlisten = \"127.0.0.1:29536\"\nbuses = [\"can9\"]\n"
        ));
        assert!(e.contains("names \"can9\", which is not configured"), "{e}");
        let e = err(&format!(
            "{BUS}[socketcand]\nlisten = \"127.0.0.1:29536\"\nmax_connections = 0\n"
        ));
        assert!(e.contains("max_connections = 0 is out of range"), "{e}");
        let e = err(&format!(
            "{BUS}[socketcand]\nlisten = \"127.0.0.1:50051\"\n"
        ));
        assert!(e.contains("already the address of another listener"), "{e}");
        let e = err(&format!(
            "{BUS}[socketcand]\nlisten = \"127.0.0.1:1\"\nbogus = 1\n"
        ));
        assert!(e.contains("bogus"), "{e}");
        // Certificates only: a socketcand client has no way to prove who
        // it is.
        let e = err(&format!(
            "{BUS}[socketcand]\nlisten = \"127.0.0.1:1\"\n[[security.clients]]\n\
             subject_cn = \"hmi\"\nrole = \"viewer\"\n[security.tls]\ncert = \"c\"\nkey = \"k\"\n\
             client_ca = \"ca\"\n"
        ));
        assert!(e.contains("needs [[security.tokens]]"), "{e}");
    }
}
