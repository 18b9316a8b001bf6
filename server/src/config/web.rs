//! The `[web]` section: gRPC-Web on the gateway's own listener and the
//! built-in dashboard served at `/`.

use serde::{Deserialize, Serialize};

/// Browser access (`[web]`): the dashboard and gRPC-Web.
///
/// gRPC-Web is served whenever the gateway runs (it is the same API behind
/// the same security layer); `enabled` only decides whether the dashboard's
/// static files are served at `/`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WebConfig {
    /// Serve the built-in dashboard at `/` (default true).
    #[serde(default = "default_enabled")]
    pub enabled: bool,
    /// Origins of other pages allowed to call the API with gRPC-Web
    /// (CORS), e.g. `https://hmi.example.com:8443`: scheme, host and
    /// optional port, nothing else. Empty (default): only the gateway's
    /// own page, which is same-origin and needs no CORS.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub allowed_origins: Vec<String>,
    /// Host names (or addresses) under which browsers may reach the
    /// gateway besides loopback names and its own addresses, e.g.
    /// `gateway.example.com`; a port is ignored. A browser request naming
    /// any other host is refused (DNS rebinding).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub allowed_hosts: Vec<String>,
}

fn default_enabled() -> bool {
    true
}

impl Default for WebConfig {
    fn default() -> Self {
        WebConfig {
            enabled: default_enabled(),
            allowed_origins: Vec::new(),
            allowed_hosts: Vec::new(),
        }
    }
}

impl WebConfig {
    /// Checks that every allowed origin is an origin as browsers send it
    /// in the `Origin` header (`http[s]://host[:port]`, no path, no
    /// wildcard), so that a typo is named at start-up instead of silently
    /// matching nothing.
    pub fn validate(&self) -> Result<(), String> {
        for o in &self.allowed_origins {
            let bad = |why: &str| {
                Err(format!(
                    "[web] allowed_origins: {o:?} {why} (expected e.g. \"https://hmi.example.com\" \
                     or \"http://192.168.1.20:8080\")"
                ))
            };
            let Some(rest) = o
                .strip_prefix("http://")
                .or_else(|| o.strip_prefix("https://"))
            else {
                return bad("does not start with http:// or https://");
            };
            if rest.is_empty() {
                return bad("has no host");
            }
            if rest.contains('/') {
                return bad("has a path (an origin is scheme, host and port only)");
            }
            if rest.contains('*') {
                return bad("has a wildcard (name each origin)");
            }
            if !rest
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b"-.:[]".contains(&b))
            {
                return bad("has characters an origin cannot have");
            }
        }
        for h in &self.allowed_hosts {
            let bad = |why: &str| {
                Err(format!(
                    "[web] allowed_hosts: {h:?} {why} (expected a host name or address as \
                     browsers send it in Host, e.g. \"gateway.example.com\" or \"192.168.1.20\")"
                ))
            };
            if h.is_empty() {
                return bad("is empty");
            }
            if h.contains("://") || h.contains('/') {
                return bad("is a URL (give the host only)");
            }
            if h.contains('*') {
                return bad("has a wildcard (name each host)");
            }
            if !h
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b"-.:[]_".contains(&b))
            {
                return bad("has characters a host cannot have");
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn origins_are_checked() {
        let ok = WebConfig {
            enabled: true,
            allowed_origins: vec![
                "https://hmi.example.com".into(),
                "http://192.168.1.20:8080".into(),
                "http://[::1]:3000".into(),
            ],
            allowed_hosts: vec!["gateway.example.com".into(), "[fd00::1]:50051".into()],
        };
        ok.validate().unwrap();
        for (bad, why) in [
            ("hmi.example.com", "http://"),
            ("https://hmi.example.com/", "path"),
            ("https://*.example.com", "wildcard"),
            ("*", "http://"),
            ("https://", "no host"),
            ("https://a b", "characters"),
        ] {
            let c = WebConfig {
                enabled: true,
                allowed_origins: vec![bad.into()],
                allowed_hosts: Vec::new(),
            };
            let e = c.validate().unwrap_err();
            assert!(e.contains(why), "{bad}: {e}");
        }
        for (bad, why) in [
            ("http://gateway.example.com", "URL"),
            ("*.example.com", "wildcard"),
            ("", "empty"),
            ("a b", "characters"),
        ] {
            let c = WebConfig {
                allowed_hosts: vec![bad.into()],
                ..WebConfig::default()
            };
            let e = c.validate().unwrap_err();
            assert!(e.contains(why) && e.contains("allowed_hosts"), "{bad}: {e}");
        }
    }
}
