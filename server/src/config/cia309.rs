//! The `[cia309]` section: an optional listener speaking the CiA 309-3
//! ASCII gateway protocol (CANopenNode's `canopend` command set) for the
//! tools and scripts that already speak it (`cocomm`, a socket and a line).

use serde::{Deserialize, Serialize};
use std::net::SocketAddr;

/// The CiA 309-3 listener (`[cia309]`); absent: off.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Cia309Config {
    /// Listen address, e.g. `127.0.0.1:60000`; port 0 picks a free port.
    /// Without authentication it must be a loopback address.
    pub listen: SocketAddr,
    /// The CANopen buses, in network order: network 1 is the first
    /// (empty: every bus with a CANopen master, in configuration order).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub buses: Vec<String>,
    /// Connections open at once.
    #[serde(default = "default_max_connections")]
    pub max_connections: u32,
    /// Connections open at once from one address. At either limit, the
    /// oldest connection that has not logged in yet gives its slot to the
    /// newcomer; only when every one has is the newcomer refused.
    #[serde(default = "default_max_connections_per_peer")]
    pub max_connections_per_peer: u32,
    /// Longest command line in bytes (a domain written as base64 takes
    /// four bytes for three); a longer one ends the connection.
    #[serde(default = "default_max_line_bytes")]
    pub max_line_bytes: u32,
    /// SDO timeout of a new connection, ms (`set sdo_timeout` changes it
    /// for the connection), as canopend's default.
    #[serde(default = "default_sdo_timeout_ms")]
    pub sdo_timeout_ms: u16,
    /// With authentication on: time from connecting to a successful
    /// `login`, ms.
    #[serde(default = "default_handshake_timeout_ms")]
    pub handshake_timeout_ms: u64,
    /// A connection that sends nothing for this long is closed, s (0:
    /// never).
    #[serde(default = "default_idle_timeout_s")]
    pub idle_timeout_s: u64,
    /// A write to the client that does not complete within this long ends
    /// the connection (a client that stopped reading), ms.
    #[serde(default = "default_write_timeout_ms")]
    pub write_timeout_ms: u64,
    /// Event lines queued for one client before it loses some (counted).
    #[serde(default = "default_event_queue")]
    pub event_queue: u32,
}

fn default_max_connections() -> u32 {
    16
}
fn default_max_connections_per_peer() -> u32 {
    8
}
fn default_max_line_bytes() -> u32 {
    16_384
}
fn default_sdo_timeout_ms() -> u16 {
    500
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
fn default_event_queue() -> u32 {
    1024
}

impl Cia309Config {
    /// A listener on `listen` with the defaults.
    pub fn new(listen: SocketAddr) -> Self {
        Cia309Config {
            listen,
            buses: Vec::new(),
            max_connections: default_max_connections(),
            max_connections_per_peer: default_max_connections_per_peer(),
            max_line_bytes: default_max_line_bytes(),
            sdo_timeout_ms: default_sdo_timeout_ms(),
            handshake_timeout_ms: default_handshake_timeout_ms(),
            idle_timeout_s: default_idle_timeout_s(),
            write_timeout_ms: default_write_timeout_ms(),
            event_queue: default_event_queue(),
        }
    }

    /// Checks the values and the rules that tie the listener to
    /// `[security]`: `authentication` (tokens or client certificates
    /// configured) and `tokens` (bearer tokens configured).
    pub(super) fn check(&self, authentication: bool, tokens: bool) -> Result<(), String> {
        if !authentication && !self.listen.ip().is_loopback() {
            return Err(format!(
                "[cia309] listen = {} is reachable from the network, and the gateway has no \
                 authentication: anyone who reaches it could write objects and send NMT \
                 commands. Without tokens it must listen on loopback (127.0.0.1 or ::1); \
                 [security] insecure does not cover it. Configure [[security.tokens]] (clients \
                 then send [1] login TOKEN first) or listen on 127.0.0.1",
                self.listen
            ));
        }
        if authentication && !tokens {
            return Err(
                "[cia309] needs [[security.tokens]] when authentication is on: a client proves \
                 who it is with [1] login TOKEN (client certificates need TLS, which the \
                 ASCII gateway does not speak)"
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
            (
                "max_line_bytes",
                u64::from(self.max_line_bytes),
                256..=1_048_576,
            ),
            ("sdo_timeout_ms", u64::from(self.sdo_timeout_ms), 1..=65_535),
            (
                "handshake_timeout_ms",
                self.handshake_timeout_ms,
                100..=600_000,
            ),
            ("idle_timeout_s", self.idle_timeout_s, 0..=86_400),
            ("write_timeout_ms", self.write_timeout_ms, 100..=600_000),
            ("event_queue", u64::from(self.event_queue), 16..=1_000_000),
        ] {
            if !range.contains(&value) {
                return Err(format!(
                    "[cia309] {key} = {value} is out of range ({}..={})",
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

    const BUS: &str =
        "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\n[[canopen]]\nbus = \"can0\"\n";
    const TOKEN: &str = "[[security.tokens]]\nname = \"eng\"\nrole = \"engineer\"\n\
        sha256 = \"9f86d081884c7d659a2feaa0c55ad015a3bf4f1b2b0b822cd15d6c15b0f00a08\"\n";

    fn err(text: &str) -> String {
        Config::from_toml(text).unwrap_err().to_string()
    }

    #[test]
    fn cia309_is_off_by_default_and_loopback_without_authentication() {
        assert!(Config::demo().cia309.is_none());
        let c =
            Config::from_toml(&format!("{BUS}[cia309]\nlisten = \"127.0.0.1:60000\"\n")).unwrap();
        let s = c.cia309.unwrap();
        assert_eq!((s.max_connections, s.sdo_timeout_ms), (16, 500));
        let e = err(&format!(
            "{BUS}[security]\ninsecure = true\n[cia309]\nlisten = \"0.0.0.0:60000\"\n"
        ));
        assert!(e.contains("must listen on loopback"), "{e}");
        Config::from_toml(&format!(
            "listen = \"0.0.0.0:50051\"\n{BUS}[cia309]\nlisten = \"0.0.0.0:60000\"\n{TOKEN}"
        ))
        .unwrap();
    }

    #[test]
    fn cia309_mistakes_are_named() {
        let e = err(&format!(
            "{BUS}[cia309]\nlisten = \"127.0.0.1:60000\"\nbuses = [\"can9\"]\n"
        ));
        assert!(
            e.contains("names \"can9\", which has no CANopen master"),
            "{e}"
        );
        let e = err(&format!(
            "{BUS}[cia309]\nlisten = \"127.0.0.1:60000\"\nmax_connections = 0\n"
        ));
        assert!(e.contains("max_connections = 0 is out of range"), "{e}");
        let e = err(&format!("{BUS}[cia309]\nlisten = \"127.0.0.1:50051\"\n"));
        assert!(e.contains("already the address of another listener"), "{e}");
        let e = err(&format!(
            "{BUS}[cia309]\nlisten = \"127.0.0.1:1\"\nbogus = 1\n"
        ));
        assert!(e.contains("bogus"), "{e}");
    }
}
