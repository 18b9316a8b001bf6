//! Per-client limits: calls in progress, call rate (token bucket) and open
//! streams. A client over a limit is refused at once with
//! RESOURCE_EXHAUSTED naming the limit; nobody waits, so one busy client
//! never stalls the others.

use super::config::LimitsConfig;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Entries idle this long are forgotten (when the table grows).
const IDLE_FORGET: Duration = Duration::from_secs(60);
/// Table size above which idle entries are pruned.
const PRUNE_ABOVE: usize = 1024;

#[derive(Debug)]
struct ClientState {
    in_flight: u32,
    streams: u32,
    tokens: f64,
    refilled: Instant,
}

#[derive(Debug)]
struct Inner {
    config: LimitsConfig,
    clients: Mutex<HashMap<Arc<str>, ClientState>>,
}

/// The limits of every client. Cheap to clone.
#[derive(Debug, Clone)]
pub struct Limits {
    inner: Arc<Inner>,
}

/// A refused call: which limit, as the message the caller gets.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct LimitExceeded(pub String);

#[derive(Debug, Clone, Copy)]
enum Kind {
    InFlight,
    Stream,
}

/// Holds one unit of a limit; gives it back when dropped.
#[derive(Debug)]
pub struct Permit {
    inner: Arc<Inner>,
    key: Arc<str>,
    kind: Kind,
}

impl Drop for Permit {
    fn drop(&mut self) {
        // A poisoned lock only means another thread panicked while holding
        // it; the counters are still consistent enough to release.
        let mut clients = self.inner.clients.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(c) = clients.get_mut(&self.key) {
            match self.kind {
                Kind::InFlight => c.in_flight = c.in_flight.saturating_sub(1),
                Kind::Stream => c.streams = c.streams.saturating_sub(1),
            }
        }
    }
}

/// What an admitted call holds: its in-flight slot and, for a streaming
/// call, its stream slot.
#[derive(Debug)]
pub struct Admission {
    /// Released when the handler has answered.
    pub in_flight: Option<Permit>,
    /// Released when the response stream ends or is dropped.
    pub stream: Option<Permit>,
}

impl Limits {
    /// Limits as configured (0 turns one off).
    pub fn new(config: LimitsConfig) -> Self {
        Limits {
            inner: Arc::new(Inner {
                config,
                clients: Mutex::new(HashMap::new()),
            }),
        }
    }

    /// Admits one call of `client` (a streaming one when `streaming`), or
    /// says which limit it exceeds.
    pub fn admit(&self, client: &str, streaming: bool) -> Result<Admission, LimitExceeded> {
        self.admit_at(client, streaming, Instant::now())
    }

    fn admit_at(
        &self,
        client: &str,
        streaming: bool,
        now: Instant,
    ) -> Result<Admission, LimitExceeded> {
        let cfg = &self.inner.config;
        let mut clients = self.inner.clients.lock().unwrap_or_else(|p| p.into_inner());
        if clients.len() > PRUNE_ABOVE {
            clients.retain(|_, c| {
                c.in_flight > 0 || c.streams > 0 || now.duration_since(c.refilled) < IDLE_FORGET
            });
        }
        let key: Arc<str> = match clients.get_key_value(client) {
            Some((k, _)) => k.clone(),
            None => {
                let k: Arc<str> = Arc::from(client);
                clients.insert(
                    k.clone(),
                    ClientState {
                        in_flight: 0,
                        streams: 0,
                        tokens: f64::from(cfg.burst),
                        refilled: now,
                    },
                );
                k
            }
        };
        let Some(c) = clients.get_mut(&key) else {
            // Inserted just above under the same lock.
            return Err(LimitExceeded("internal: client state missing".into()));
        };
        // Refill first, so that an idle client always has its burst.
        let rate = f64::from(cfg.requests_per_second_per_client);
        if rate > 0.0 {
            let elapsed = now.saturating_duration_since(c.refilled).as_secs_f64();
            c.tokens = (c.tokens + elapsed * rate).min(f64::from(cfg.burst));
        }
        c.refilled = now;
        if cfg.max_concurrent_requests_per_client > 0
            && c.in_flight >= cfg.max_concurrent_requests_per_client
        {
            return Err(LimitExceeded(format!(
                "concurrency limit: {} calls in progress for {client} \
                 (max_concurrent_requests_per_client = {})",
                c.in_flight, cfg.max_concurrent_requests_per_client
            )));
        }
        if streaming && cfg.max_streams_per_client > 0 && c.streams >= cfg.max_streams_per_client {
            return Err(LimitExceeded(format!(
                "stream limit: {} streams open for {client} (max_streams_per_client = {})",
                c.streams, cfg.max_streams_per_client
            )));
        }
        if rate > 0.0 {
            if c.tokens < 1.0 {
                return Err(LimitExceeded(format!(
                    "rate limit: {client} exceeds requests_per_second_per_client = {} \
                     (burst = {})",
                    cfg.requests_per_second_per_client, cfg.burst
                )));
            }
            c.tokens -= 1.0;
        }
        c.in_flight += 1;
        let in_flight = Some(Permit {
            inner: self.inner.clone(),
            key: key.clone(),
            kind: Kind::InFlight,
        });
        let stream = if streaming {
            c.streams += 1;
            Some(Permit {
                inner: self.inner.clone(),
                key,
                kind: Kind::Stream,
            })
        } else {
            None
        };
        Ok(Admission { in_flight, stream })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits(concurrent: u32, rate: u32, burst: u32, streams: u32) -> Limits {
        Limits::new(LimitsConfig {
            max_concurrent_requests_per_client: concurrent,
            requests_per_second_per_client: rate,
            burst,
            max_streams_per_client: streams,
            max_message_bytes: 1024,
        })
    }

    #[test]
    fn token_bucket_allows_the_burst_then_the_rate() {
        let l = limits(0, 10, 3, 0);
        let t0 = Instant::now();
        for _ in 0..3 {
            l.admit_at("a", false, t0).unwrap();
        }
        let e = l.admit_at("a", false, t0).unwrap_err();
        assert!(e.0.starts_with("rate limit"), "{e}");
        // Another client is not affected.
        l.admit_at("b", false, t0).unwrap();
        // 100 ms at 10/s gives one call back.
        l.admit_at("a", false, t0 + Duration::from_millis(100))
            .unwrap();
        assert!(
            l.admit_at("a", false, t0 + Duration::from_millis(100))
                .is_err()
        );
    }

    #[test]
    fn concurrency_and_streams_are_released_on_drop() {
        let l = limits(2, 0, 0, 1);
        let a = l.admit("a", false).unwrap();
        let b = l.admit("a", true).unwrap();
        let e = l.admit("a", false).unwrap_err();
        assert!(e.0.starts_with("concurrency limit"), "{e}");
        drop(a);
        let e = l.admit("a", true).unwrap_err();
        assert!(e.0.starts_with("stream limit"), "{e}");
        // The stream's handler answered, the stream stays open.
        let Admission { in_flight, stream } = b;
        drop(in_flight);
        assert!(l.admit("a", true).is_err());
        drop(stream);
        l.admit("a", true).unwrap();
    }

    #[test]
    fn zero_turns_limits_off() {
        let l = limits(0, 0, 0, 0);
        let held: Vec<_> = (0..1000).map(|_| l.admit("a", true).unwrap()).collect();
        assert_eq!(held.len(), 1000);
    }
}
