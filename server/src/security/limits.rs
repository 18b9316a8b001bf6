//! Per-client limits: calls in progress, call rate (token bucket), open
//! streams, and raw frames per second (a token bucket of frames, for
//! `SendFrames` and `Attach`: raw traffic is counted by its frames, not by
//! its calls, see [`FrameBudget`]). A client over a limit is refused at
//! once with RESOURCE_EXHAUSTED naming the limit; nobody waits, so one busy
//! client never stalls the others.
//!
//! Stops (`Stop`, `QuickStop`, `StopAxes`) have a budget of their own
//! (rate, burst and calls in progress): other calls never use it up, so a
//! client polling at its rate limit, or holding its every concurrency slot,
//! can still stop its machine. Stops do not use the general budget either.
//! And a stop is never refused here: a client over its stop budget gets
//! its stop admitted with a [`StopOverBudget`], and the axes service
//! refuses it only when every axis it names is at rest. A stop of a moving
//! axis always goes through, however many stops the same client (or, on a
//! gateway without tokens, another process on the same host) made.

use crate::config::LimitsConfig;
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
    stops_in_flight: u32,
    stop_tokens: f64,
    /// Sum of the queue lengths of the client's open streams.
    queued: u64,
    refilled: Instant,
    /// The raw frame bucket and when it was last refilled.
    frame_tokens: f64,
    frames_refilled: Instant,
}

impl ClientState {
    fn new(cfg: &LimitsConfig, now: Instant) -> Self {
        ClientState {
            in_flight: 0,
            streams: 0,
            tokens: f64::from(cfg.burst),
            stops_in_flight: 0,
            stop_tokens: f64::from(cfg.stop_burst),
            queued: 0,
            refilled: now,
            frame_tokens: f64::from(cfg.raw_frame_burst),
            frames_refilled: now,
        }
    }
}

/// What kind of call asks to be admitted: which budget it uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CallKind {
    /// A unary call.
    Unary,
    /// A server-streaming call (also holds a stream slot while open).
    Streaming,
    /// A stop: its own budget, see the module documentation.
    Stop,
    /// A unary call that sends raw frames (`SendFrames`): it counts as a
    /// call in progress, but not against the call rate; its frames are
    /// counted instead ([`FrameBudget`]).
    RawFrames,
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
    Stop,
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
                Kind::Stop => c.stops_in_flight = c.stops_in_flight.saturating_sub(1),
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
    /// For a streaming call: the client's queue budget.
    pub queue_budget: Option<StreamQueueBudget>,
    /// The client's raw frame budget (every admission but a stop's; the
    /// security layer hands it to the RPCs that send raw frames).
    pub frame_budget: Option<FrameBudget>,
    /// A stop admitted over its client's stop budget.
    pub stop_over_budget: Option<StopOverBudget>,
}

/// A stop admitted although its client spent its stop budget (rate or
/// stops in progress), with the limit as a message: the stop may be
/// refused with it (RESOURCE_EXHAUSTED) only when every axis it names is
/// at rest. Put into the request's extensions by the security layer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StopOverBudget(pub String);

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

    /// Admits one call of `client` of the given kind, or says which limit
    /// it exceeds.
    pub fn admit(&self, client: &str, kind: CallKind) -> Result<Admission, LimitExceeded> {
        self.admit_at(client, kind, Instant::now())
    }

    fn admit_at(
        &self,
        client: &str,
        kind: CallKind,
        now: Instant,
    ) -> Result<Admission, LimitExceeded> {
        let streaming = kind == CallKind::Streaming;
        let cfg = &self.inner.config;
        let mut clients = self.inner.clients.lock().unwrap_or_else(|p| p.into_inner());
        if clients.len() > PRUNE_ABOVE {
            clients.retain(|_, c| {
                c.in_flight > 0
                    || c.streams > 0
                    || c.stops_in_flight > 0
                    || c.queued > 0
                    || now.duration_since(c.refilled) < IDLE_FORGET
            });
        }
        let key: Arc<str> = match clients.get_key_value(client) {
            Some((k, _)) => k.clone(),
            None => {
                let k: Arc<str> = Arc::from(client);
                clients.insert(k.clone(), ClientState::new(cfg, now));
                k
            }
        };
        let Some(c) = clients.get_mut(&key) else {
            // Inserted just above under the same lock.
            return Err(LimitExceeded("internal: client state missing".into()));
        };
        // Refill first, so that an idle client always has its burst.
        let elapsed = now.saturating_duration_since(c.refilled).as_secs_f64();
        let rate = f64::from(cfg.requests_per_second_per_client);
        if rate > 0.0 {
            c.tokens = (c.tokens + elapsed * rate).min(f64::from(cfg.burst));
        }
        let stop_rate = f64::from(cfg.stop_requests_per_second_per_client);
        if stop_rate > 0.0 {
            c.stop_tokens = (c.stop_tokens + elapsed * stop_rate).min(f64::from(cfg.stop_burst));
        }
        c.refilled = now;
        if kind == CallKind::Stop {
            // Never refused here (see the module documentation): over the
            // budget, the stop carries the limit it exceeds.
            let over = if cfg.max_concurrent_stops_per_client > 0
                && c.stops_in_flight >= cfg.max_concurrent_stops_per_client
            {
                Some(format!(
                    "stop concurrency limit: {} stops in progress for {client} \
                     (max_concurrent_stops_per_client = {})",
                    c.stops_in_flight, cfg.max_concurrent_stops_per_client
                ))
            } else if stop_rate > 0.0 && c.stop_tokens < 1.0 {
                Some(format!(
                    "stop rate limit: {client} exceeds stop_requests_per_second_per_client \
                     = {} (stop_burst = {})",
                    cfg.stop_requests_per_second_per_client, cfg.stop_burst
                ))
            } else {
                if stop_rate > 0.0 {
                    c.stop_tokens -= 1.0;
                }
                None
            };
            c.stops_in_flight += 1;
            return Ok(Admission {
                in_flight: Some(Permit {
                    inner: self.inner.clone(),
                    key,
                    kind: Kind::Stop,
                }),
                stream: None,
                queue_budget: None,
                frame_budget: None,
                stop_over_budget: over.map(StopOverBudget),
            });
        }
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
        if rate > 0.0 && kind != CallKind::RawFrames {
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
        let queue_budget = streaming.then(|| StreamQueueBudget {
            limits: self.clone(),
            key: key.clone(),
        });
        let frame_budget = Some(FrameBudget {
            limits: self.clone(),
            key: key.clone(),
        });
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
        Ok(Admission {
            in_flight,
            stream,
            queue_budget,
            frame_budget,
            stop_over_budget: None,
        })
    }
}

/// A stream's share of its client's queue budget; given back when dropped
/// (the stream's task holds it while it runs).
#[derive(Debug)]
pub struct QueueReservation {
    inner: Arc<Inner>,
    key: Arc<str>,
    events: u64,
}

impl Drop for QueueReservation {
    fn drop(&mut self) {
        let mut clients = self.inner.clients.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(c) = clients.get_mut(&self.key) {
            c.queued = c.queued.saturating_sub(self.events);
        }
    }
}

/// The queue budget of the client making a streaming call: put into the
/// request's extensions by the security layer, used by services whose
/// streams buffer events for the client (`queue_length`).
#[derive(Debug, Clone)]
pub struct StreamQueueBudget {
    limits: Limits,
    key: Arc<str>,
}

impl StreamQueueBudget {
    /// The queue length a stream gets for `requested` events (0: the
    /// service's `default`), at most `max_stream_queue`, and the
    /// reservation to hold while the stream is open.
    ///
    /// # Errors
    /// When the client's open streams already hold
    /// `max_stream_queue_per_client` events between them.
    pub fn reserve(
        &self,
        requested: u32,
        default: usize,
    ) -> Result<(usize, QueueReservation), LimitExceeded> {
        let cfg = &self.limits.inner.config;
        let events = match requested {
            0 => default as u64,
            n => u64::from(n),
        }
        .clamp(1, u64::from(cfg.max_stream_queue));
        let mut clients = self
            .limits
            .inner
            .clients
            .lock()
            .unwrap_or_else(|p| p.into_inner());
        let Some(c) = clients.get_mut(&self.key) else {
            return Err(LimitExceeded("internal: client state missing".into()));
        };
        let total = u64::from(cfg.max_stream_queue_per_client);
        if c.queued + events > total {
            return Err(LimitExceeded(format!(
                "stream queue limit: {} has streams open with {} queued events between them; \
                 {events} more would exceed max_stream_queue_per_client = {total} (ask for a \
                 smaller queue_length or close a stream)",
                self.key, c.queued
            )));
        }
        c.queued += events;
        Ok((
            events as usize,
            QueueReservation {
                inner: self.limits.inner.clone(),
                key: self.key.clone(),
                events,
            },
        ))
    }
}

/// The raw frame budget of the client making a call that sends raw frames
/// (`SendFrames`, `Attach`): put into the request's extensions by the
/// security layer, charged by the service per batch, one token per frame
/// (`raw_frames_per_second_per_client`, `raw_frame_burst`).
///
/// Why frames and not calls: one call may carry 10,000 frames, and an
/// attached client sends many batches over one call; what a client costs
/// the bus and the gateway is its frames.
#[derive(Debug, Clone)]
pub struct FrameBudget {
    limits: Limits,
    key: Arc<str>,
}

impl FrameBudget {
    /// Takes `frames` tokens for a batch, or refuses the whole batch
    /// (nothing taken) saying which limit it exceeds.
    ///
    /// # Errors
    /// When the client's bucket holds fewer than `frames` tokens (a batch
    /// larger than `raw_frame_burst` never passes).
    pub fn take(&self, frames: u64) -> Result<(), LimitExceeded> {
        self.take_at(frames, Instant::now())
    }

    fn take_at(&self, frames: u64, now: Instant) -> Result<(), LimitExceeded> {
        let cfg = &self.limits.inner.config;
        let rate = f64::from(cfg.raw_frames_per_second_per_client);
        if rate <= 0.0 {
            return Ok(());
        }
        let burst = f64::from(cfg.raw_frame_burst);
        let mut clients = self
            .limits
            .inner
            .clients
            .lock()
            .unwrap_or_else(|p| p.into_inner());
        // Pruned meanwhile (idle for a minute): a fresh, full bucket.
        let c = clients
            .entry(self.key.clone())
            .or_insert_with(|| ClientState::new(cfg, now));
        let elapsed = now.saturating_duration_since(c.frames_refilled);
        c.frame_tokens = (c.frame_tokens + elapsed.as_secs_f64() * rate).min(burst);
        c.frames_refilled = now;
        // Activity keeps the entry from being pruned.
        c.refilled = c.refilled.max(now);
        let wanted = frames as f64;
        if wanted > burst {
            return Err(LimitExceeded(format!(
                "frame rate limit: a batch of {frames} frames is larger than raw_frame_burst = \
                 {} of {}: send smaller batches",
                cfg.raw_frame_burst, self.key
            )));
        }
        if c.frame_tokens < wanted {
            return Err(LimitExceeded(format!(
                "frame rate limit: {} exceeds raw_frames_per_second_per_client = {} \
                 (raw_frame_burst = {}); {frames} frames refused, none sent",
                self.key, cfg.raw_frames_per_second_per_client, cfg.raw_frame_burst
            )));
        }
        c.frame_tokens -= wanted;
        Ok(())
    }
}

impl FrameBudget {
    /// The same client's call budget, for an RPC whose messages are calls
    /// of their own (an SdoSession's requests).
    pub fn requests(&self) -> RequestBudget {
        RequestBudget {
            limits: self.limits.clone(),
            key: self.key.clone(),
        }
    }
}

/// A client's call rate (`requests_per_second_per_client`, `burst`) for
/// the requests inside a stream: put into the request's extensions by the
/// security layer for the RPCs that carry requests (an SdoSession), taken
/// by the service per request, so a session costs what the same unary
/// calls would.
#[derive(Debug, Clone)]
pub struct RequestBudget {
    limits: Limits,
    key: Arc<str>,
}

impl RequestBudget {
    /// Takes one call's token, or says which limit it exceeds.
    ///
    /// # Errors
    /// When the client's bucket is empty.
    pub fn take(&self) -> Result<(), LimitExceeded> {
        let now = Instant::now();
        let cfg = &self.limits.inner.config;
        let rate = f64::from(cfg.requests_per_second_per_client);
        if rate <= 0.0 {
            return Ok(());
        }
        let mut clients = self
            .limits
            .inner
            .clients
            .lock()
            .unwrap_or_else(|p| p.into_inner());
        let c = clients
            .entry(self.key.clone())
            .or_insert_with(|| ClientState::new(cfg, now));
        let elapsed = now.saturating_duration_since(c.refilled).as_secs_f64();
        c.tokens = (c.tokens + elapsed * rate).min(f64::from(cfg.burst));
        c.refilled = now;
        if c.tokens < 1.0 {
            return Err(LimitExceeded(format!(
                "rate limit: {} exceeds requests_per_second_per_client = {} (burst = {})",
                self.key, cfg.requests_per_second_per_client, cfg.burst
            )));
        }
        c.tokens -= 1.0;
        Ok(())
    }
}

/// Refused calls per peer address (bad or missing credentials): a token
/// bucket per address. While an address's bucket is empty its calls are
/// refused before their credentials are checked, so a peer guessing
/// tokens costs the gateway a table look-up per call, not a hash and an
/// audit line.
#[derive(Debug)]
pub struct PeerRefusals {
    rate: f64,
    burst: f64,
    peers: Mutex<HashMap<std::net::IpAddr, (f64, Instant)>>,
}

impl PeerRefusals {
    /// `rate` refusals per second with `burst` (rate 0: no limit).
    pub fn new(rate: u32, burst: u32) -> Self {
        PeerRefusals {
            rate: f64::from(rate),
            burst: f64::from(burst),
            peers: Mutex::new(HashMap::new()),
        }
    }

    /// The configured rate, for messages.
    pub fn rate(&self) -> f64 {
        self.rate
    }

    fn refill(&self, entry: &mut (f64, Instant), now: Instant) {
        let elapsed = now.saturating_duration_since(entry.1).as_secs_f64();
        entry.0 = (entry.0 + elapsed * self.rate).min(self.burst);
        entry.1 = now;
    }

    /// Whether `peer` has used up its refusals (calls from it are refused
    /// at once until its bucket refills).
    pub fn blocked(&self, peer: std::net::IpAddr) -> bool {
        self.blocked_at(peer, Instant::now())
    }

    fn blocked_at(&self, peer: std::net::IpAddr, now: Instant) -> bool {
        if self.rate <= 0.0 {
            return false;
        }
        let mut peers = self.peers.lock().unwrap_or_else(|p| p.into_inner());
        match peers.get_mut(&peer) {
            Some(e) => {
                self.refill(e, now);
                e.0 < 1.0
            }
            None => false,
        }
    }

    /// Counts one refusal of `peer`.
    pub fn record(&self, peer: std::net::IpAddr) {
        self.record_at(peer, Instant::now());
    }

    fn record_at(&self, peer: std::net::IpAddr, now: Instant) {
        if self.rate <= 0.0 {
            return;
        }
        let mut peers = self.peers.lock().unwrap_or_else(|p| p.into_inner());
        if peers.len() > PRUNE_ABOVE {
            let burst = self.burst;
            let rate = self.rate;
            // Forget addresses whose bucket is full again.
            peers.retain(|_, e| {
                e.0 + now.saturating_duration_since(e.1).as_secs_f64() * rate < burst
            });
        }
        let e = peers.entry(peer).or_insert((self.burst, now));
        self.refill(e, now);
        e.0 = (e.0 - 1.0).max(0.0);
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
            ..LimitsConfig::default()
        })
    }

    const UNARY: CallKind = CallKind::Unary;
    const STREAM: CallKind = CallKind::Streaming;

    #[test]
    fn a_peer_with_too_many_refusals_is_blocked_until_its_bucket_refills() {
        let r = PeerRefusals::new(2, 3);
        let t0 = Instant::now();
        let a: std::net::IpAddr = [10, 0, 0, 1].into();
        let b: std::net::IpAddr = [10, 0, 0, 2].into();
        for _ in 0..3 {
            assert!(!r.blocked_at(a, t0));
            r.record_at(a, t0);
        }
        assert!(r.blocked_at(a, t0));
        assert!(!r.blocked_at(b, t0), "other peers are not affected");
        // Half a second at 2/s gives one refusal back.
        assert!(!r.blocked_at(a, t0 + Duration::from_millis(500)));
        assert!(!PeerRefusals::new(0, 0).blocked_at(a, t0));
    }

    #[test]
    fn stops_have_their_own_budget() {
        // One call in progress at most, 1/s with a burst of 2: the general
        // budget is spent and its only slot held.
        let l = limits(1, 1, 2, 0);
        let t0 = Instant::now();
        let held = l.admit_at("a", UNARY, t0).unwrap();
        assert!(l.admit_at("a", UNARY, t0).is_err());
        // 40 stops in a second, each answered before the next: all pass
        // (the default stop budget), and they leave the general one alone.
        for i in 0..40u64 {
            let at = t0 + Duration::from_millis(i * 25);
            let stop = l.admit_at("a", CallKind::Stop, at);
            assert!(stop.is_ok(), "stop {i}: {stop:?}");
        }
        drop(held);
        l.admit_at("a", UNARY, t0 + Duration::from_secs(1)).unwrap();
        // The stop budget is bounded too, by its own numbers; a stop over it
        // is still admitted (never refused here), marked with the limit.
        let l = Limits::new(LimitsConfig {
            stop_requests_per_second_per_client: 1,
            stop_burst: 2,
            max_concurrent_stops_per_client: 8,
            ..LimitsConfig::default()
        });
        for _ in 0..2 {
            let a = l.admit_at("a", CallKind::Stop, t0).unwrap();
            assert_eq!(a.stop_over_budget, None);
        }
        let over = l.admit_at("a", CallKind::Stop, t0).unwrap();
        let e = over.stop_over_budget.expect("over the budget");
        assert!(e.0.starts_with("stop rate limit"), "{e:?}");
        // Another client's budget is its own.
        let b = l.admit_at("b", CallKind::Stop, t0).unwrap();
        assert_eq!(b.stop_over_budget, None);
        // ...and the general budget is untouched by them.
        l.admit_at("a", UNARY, t0).unwrap();
    }

    #[test]
    fn token_bucket_allows_the_burst_then_the_rate() {
        let l = limits(0, 10, 3, 0);
        let t0 = Instant::now();
        for _ in 0..3 {
            l.admit_at("a", UNARY, t0).unwrap();
        }
        let e = l.admit_at("a", UNARY, t0).unwrap_err();
        assert!(e.0.starts_with("rate limit"), "{e}");
        // Another client is not affected.
        l.admit_at("b", UNARY, t0).unwrap();
        // 100 ms at 10/s gives one call back.
        l.admit_at("a", UNARY, t0 + Duration::from_millis(100))
            .unwrap();
        assert!(
            l.admit_at("a", UNARY, t0 + Duration::from_millis(100))
                .is_err()
        );
    }

    #[test]
    fn concurrency_and_streams_are_released_on_drop() {
        let l = limits(2, 0, 0, 1);
        let a = l.admit("a", UNARY).unwrap();
        let b = l.admit("a", STREAM).unwrap();
        let e = l.admit("a", UNARY).unwrap_err();
        assert!(e.0.starts_with("concurrency limit"), "{e}");
        drop(a);
        let e = l.admit("a", STREAM).unwrap_err();
        assert!(e.0.starts_with("stream limit"), "{e}");
        // The stream's handler answered, the stream stays open.
        let Admission {
            in_flight, stream, ..
        } = b;
        drop(in_flight);
        assert!(l.admit("a", STREAM).is_err());
        drop(stream);
        l.admit("a", STREAM).unwrap();
    }

    #[test]
    fn stream_queues_are_capped_per_stream_and_per_client() {
        let l = Limits::new(LimitsConfig {
            max_stream_queue: 1000,
            max_stream_queue_per_client: 2500,
            ..LimitsConfig::default()
        });
        let a = l.admit("a", STREAM).unwrap();
        let budget = a.queue_budget.clone().unwrap();
        // 1 M asked, the per-stream cap given; 0 asks for the default.
        let (n1, r1) = budget.reserve(1_000_000, 8192).unwrap();
        assert_eq!(n1, 1000);
        let (n2, _r2) = budget.reserve(0, 500).unwrap();
        assert_eq!(n2, 500);
        let (_, r3) = budget.reserve(1000, 8192).unwrap();
        let e = budget.reserve(1000, 8192).unwrap_err();
        assert!(e.0.contains("max_stream_queue_per_client = 2500"), "{e}");
        // Another client has its own budget.
        let b = l.admit("b", STREAM).unwrap();
        b.queue_budget.unwrap().reserve(1000, 0).unwrap();
        // A closed stream gives its share back.
        drop((r1, r3));
        budget.reserve(1000, 8192).unwrap();
    }

    #[test]
    fn raw_frames_are_counted_by_frames_not_calls() {
        let l = Limits::new(LimitsConfig {
            requests_per_second_per_client: 1,
            burst: 1,
            raw_frames_per_second_per_client: 1000,
            raw_frame_burst: 2000,
            ..LimitsConfig::default()
        });
        let t0 = Instant::now();
        // SendFrames calls do not use the call budget (1/s here)...
        let mut budget = None;
        for _ in 0..10 {
            let a = l.admit_at("a", CallKind::RawFrames, t0).unwrap();
            budget = a.frame_budget;
        }
        let budget = budget.unwrap();
        // ...their frames use the frame budget: the burst, then the rate.
        budget.take_at(1500, t0).unwrap();
        let e = budget.take_at(600, t0).unwrap_err();
        assert!(e.0.starts_with("frame rate limit"), "{e}");
        assert!(
            e.0.contains("raw_frames_per_second_per_client = 1000"),
            "{e}"
        );
        budget.take_at(500, t0).unwrap();
        // 100 ms at 1000/s gives 100 frames back.
        budget
            .take_at(100, t0 + Duration::from_millis(100))
            .unwrap();
        assert!(budget.take_at(1, t0 + Duration::from_millis(100)).is_err());
        // A batch larger than the burst never passes, and says why.
        let e = budget
            .take_at(2001, t0 + Duration::from_secs(60))
            .unwrap_err();
        assert!(e.0.contains("larger than raw_frame_burst"), "{e}");
        // Other clients have their own; a unary call still takes a token.
        let b = l.admit_at("b", UNARY, t0).unwrap();
        b.frame_budget.unwrap().take_at(2000, t0).unwrap();
        assert!(l.admit_at("b", UNARY, t0).is_err());
        // 0 turns the frame limit off.
        let off = Limits::new(LimitsConfig {
            raw_frames_per_second_per_client: 0,
            ..LimitsConfig::default()
        });
        let a = off.admit_at("a", UNARY, t0).unwrap();
        a.frame_budget.unwrap().take_at(1_000_000, t0).unwrap();
    }

    #[test]
    fn zero_turns_limits_off() {
        let l = limits(0, 0, 0, 0);
        let held: Vec<_> = (0..1000).map(|_| l.admit("a", STREAM).unwrap()).collect();
        assert_eq!(held.len(), 1000);
    }
}
