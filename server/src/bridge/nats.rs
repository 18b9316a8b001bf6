//! The NATS side of the bridge (`nats://`, `tls://`): the same topic tree
//! as MQTT as NATS subjects (`/` → `.`), the same envelope and the same
//! [`Queue`]. Events, statistics, gap records and the status are
//! JetStream publishes acknowledged by a PubAck; each numbered message
//! carries `Nats-Msg-Id: <gateway>/<epoch>/<stream>/<seq>`, so what the
//! bridge sends again after a reconnect is dropped by the server as a
//! duplicate. Frame batches are plain core publishes (QoS 0's twin).
//!
//! NATS keeps no retained message and has no last will: the status goes
//! to a stream that keeps the last message of each subject
//! ([`STATUS_STREAM`]), is published again every [`HEARTBEAT`] while
//! connected, and marked offline at a clean stop; a status older than
//! three heartbeats is stale (docs/bridge.md says what a consumer sees).
//! The gateway also answers the NATS services API (`$SRV.PING`, `INFO`,
//! `STATS`) as service [`SERVICE_NAME`].

use super::queue::{Payload, Queue};
use super::{Identity, Source, body_of, now_ns, queue_source};
use crate::config::{BridgeConfig, BridgeFormat};
use async_nats::jetstream;
use async_nats::service::ServiceExt;
use cangate_proto::v1 as pb;
use futures::StreamExt;
use std::collections::HashMap;
use std::time::Duration;
use tokio::sync::mpsc;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

/// The stream of every gateway's status: the last message of each
/// subject `cangate.v1.<format>.<gateway>.status`.
pub const STATUS_STREAM: &str = "CANGATE_STATUS";
/// The status is published again this often while connected.
pub const HEARTBEAT: Duration = Duration::from_secs(5);
/// The name the gateway answers the services API with.
pub const SERVICE_NAME: &str = "cangate";
/// How long the events stream keeps messages.
const EVENTS_MAX_AGE: Duration = Duration::from_secs(24 * 3600);
/// How long the server remembers a `Nats-Msg-Id` (its duplicate window).
const DUPLICATE_WINDOW: Duration = Duration::from_secs(120);
/// Acknowledgements missing this long while connected: everything not
/// acknowledged is sent again (the server drops what it has).
const ACK_STALL: Duration = Duration::from_secs(10);
/// Pause before sending again after the server refused a publish (no
/// stream, stream full, …).
const REFUSED_PAUSE: Duration = Duration::from_secs(1);

/// A NATS subject token for one level of a topic: `.`, `*`, `>` and
/// white space are not allowed in a token and become `_`.
fn token(level: &str) -> String {
    if level.is_empty() {
        return "_".into();
    }
    level
        .chars()
        .map(|c| match c {
            '.' | '*' | '>' => '_',
            c if c.is_whitespace() => '_',
            c => c,
        })
        .collect()
}

/// The subject of `stream` in `format`'s tree: the MQTT topic with `/`
/// as `.`.
pub fn subject(format: BridgeFormat, gateway: &str, stream: &str) -> String {
    let mut s = format!("cangate.v1.{}.{}", format.level(), token(gateway));
    for level in stream.split('/') {
        s.push('.');
        s.push_str(&token(level));
    }
    s
}

/// The JetStream stream that keeps a gateway's events in `format`:
/// `CANGATE_<gateway>_<PB|JSON>`.
pub fn events_stream_name(format: BridgeFormat, gateway: &str) -> String {
    format!("CANGATE_{gateway}_{}", format.level().to_ascii_uppercase())
}

/// The events stream's configuration: every acknowledged subject of the
/// gateway's tree but the status (its own stream) and the frames (core
/// publishes, not kept).
fn events_stream(format: BridgeFormat, gateway: &str) -> jetstream::stream::Config {
    let root = format!("cangate.v1.{}.{}", format.level(), token(gateway));
    jetstream::stream::Config {
        name: events_stream_name(format, gateway),
        description: Some(format!(
            "cangate gateway {gateway}: events, statistics and gap records ({})",
            format.level()
        )),
        subjects: [
            "bus.*.node.*.event",
            "bus.*.stats",
            "bus.*.gap",
            "gap",
            "axis.>",
            "handwheel.>",
            "cansmc.>",
        ]
        .iter()
        .map(|s| format!("{root}.{s}"))
        .collect(),
        storage: jetstream::stream::StorageType::File,
        retention: jetstream::stream::RetentionPolicy::Limits,
        max_age: EVENTS_MAX_AGE,
        duplicate_window: DUPLICATE_WINDOW,
        ..Default::default()
    }
}

/// The status stream's configuration (shared by every gateway).
pub fn status_stream() -> jetstream::stream::Config {
    jetstream::stream::Config {
        name: STATUS_STREAM.into(),
        description: Some("cangate gateways' statuses: the last of each".into()),
        subjects: vec!["cangate.v1.*.*.status".into()],
        storage: jetstream::stream::StorageType::File,
        retention: jetstream::stream::RetentionPolicy::Limits,
        max_messages_per_subject: 1,
        ..Default::default()
    }
}

/// The first line of a secret's file (the secret itself never in the
/// message).
fn first_line(what: &str, path: &std::path::Path) -> Result<String, String> {
    let text =
        std::fs::read_to_string(path).map_err(|e| format!("{what} {}: {e}", path.display()))?;
    Ok(text.lines().next().unwrap_or("").trim().to_string())
}

/// The connection options of bridge `b`: its credentials (read from their
/// files now) and TLS. Nothing secret is in an error message.
pub(super) fn options(
    b: &BridgeConfig,
    client_name: String,
    tls: bool,
) -> Result<async_nats::ConnectOptions, String> {
    let mut o = async_nats::ConnectOptions::new().name(client_name);
    if let Some(user) = &b.username {
        let pass = match &b.password_file {
            Some(p) => first_line("password_file", p)?,
            None => String::new(),
        };
        o = o.user_and_password(user.clone(), pass);
    }
    if let Some(p) = &b.token_file {
        o = o.token(first_line("token_file", p)?);
    }
    if let Some(p) = &b.nkey_file {
        let seed = first_line("nkey_file", p)?;
        if !seed.starts_with("SU") {
            return Err(format!(
                "nkey_file {}: not a user NKey seed (SU…)",
                p.display()
            ));
        }
        o = o.nkey(seed);
    }
    if let Some(p) = &b.credentials_file {
        let text = std::fs::read_to_string(p)
            .map_err(|e| format!("credentials_file {}: {e}", p.display()))?;
        o = o.credentials(&text).map_err(|_| {
            format!(
                "credentials_file {}: not a NATS credentials file (a user JWT and an NKey seed)",
                p.display()
            )
        })?;
    }
    if tls {
        let config = super::tls::client_config(b)?;
        o = o.tls_client_config((*config).clone()).require_tls(true);
    }
    Ok(o.retry_on_initial_connect()
        .max_reconnects(None)
        .ping_interval(HEARTBEAT)
        .reconnect_delay_callback(|attempts| {
            let ms = 250u64.saturating_mul(1u64 << attempts.min(5));
            Duration::from_millis(ms.min(5000))
        }))
}

/// What the client's connection did.
enum Link {
    Connected,
    Disconnected,
    /// The streams are in place for the connection of this generation.
    Ready(u64),
}

/// One NATS connection: its queue, and whether it answers the services
/// API.
pub(super) struct NatsPublisher {
    pub(super) bridge: String,
    pub(super) format: BridgeFormat,
    pub(super) identity: Identity,
    pub(super) queue: Queue<Vec<u8>>,
    /// Answer `$SRV.PING/INFO/STATS` (one connection per bridge does).
    pub(super) service: bool,
}

/// The publisher's view of the connection.
struct State {
    /// Bumped whenever what was sent is given up on (disconnect, refused
    /// publish, stalled acknowledgements): acknowledgements of an older
    /// generation are ignored, their messages having been put back.
    generation: u64,
    /// The queue may hand messages over.
    up: bool,
    next_id: u16,
    /// After a refused publish: when to try again.
    retry_at: Option<Instant>,
    /// Since when acknowledgements are awaited without any coming.
    waiting_since: Option<Instant>,
    /// A refusal was logged since the last acknowledgement.
    refusal_logged: bool,
}

impl NatsPublisher {
    pub(super) async fn run(
        mut self,
        url: String,
        options: async_nats::ConnectOptions,
        mut sources: mpsc::Receiver<Source>,
        shutdown: CancellationToken,
    ) {
        let format = self.format.level();
        let (link_tx, mut link_rx) = mpsc::unbounded_channel();
        let events = link_tx.clone();
        let options = options.event_callback(move |e| {
            let events = events.clone();
            async move {
                let _ = match e {
                    async_nats::Event::Connected => events.send(Link::Connected),
                    async_nats::Event::Disconnected => events.send(Link::Disconnected),
                    _ => Ok(()),
                };
            }
        });
        let client = match options.connect(url.as_str()).await {
            Ok(c) => c,
            Err(e) => {
                tracing::error!(bridge = %self.bridge, format, error = %e, "NATS client");
                return;
            }
        };
        let inbox = client.new_inbox();
        let mut acks = match client.subscribe(format!("{inbox}.>")).await {
            Ok(s) => s,
            Err(e) => {
                tracing::error!(bridge = %self.bridge, format, error = %e, "NATS subscription");
                return;
            }
        };
        let service = if self.service {
            self.start_service(&client).await
        } else {
            None
        };
        let js = jetstream::new(client.clone());
        let mut st = State {
            generation: 0,
            up: false,
            next_id: 0,
            retry_at: None,
            waiting_since: None,
            refusal_logged: false,
        };
        let mut heartbeat = tokio::time::interval(HEARTBEAT);
        heartbeat.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let mut sources_open = true;
        loop {
            tokio::select! {
                biased;
                _ = shutdown.cancelled() => break,
                l = link_rx.recv() => match l {
                    Some(Link::Connected) => self.prepare(&js, &st, &link_tx),
                    Some(Link::Disconnected) => self.give_back(&mut st, "broker connection lost"),
                    Some(Link::Ready(g)) if g == st.generation && !st.up => self.ready(&mut st),
                    Some(Link::Ready(_)) => {}
                    None => break,
                },
                m = acks.next() => match m {
                    Some(m) => self.on_ack(&inbox, &m, &mut st),
                    None => break,
                },
                s = sources.recv(), if sources_open => match s {
                    Some(s) => queue_source(&mut self.queue, &self.bridge, self.format, &self.identity, s),
                    None => sources_open = false,
                },
                _ = async { tokio::time::sleep_until(st.retry_at.unwrap()).await }, if st.retry_at.is_some() => {
                    st.retry_at = None;
                    if client.connection_state() == async_nats::connection::State::Connected {
                        self.prepare(&js, &st, &link_tx);
                    }
                }
                _ = heartbeat.tick() => {
                    if st.up {
                        if st.waiting_since.is_some_and(|t| t.elapsed() >= ACK_STALL) {
                            self.give_back(&mut st, "no acknowledgement from JetStream");
                            st.retry_at = Some(Instant::now());
                        } else {
                            self.push_status(true);
                        }
                    }
                }
            }
            self.pump(&client, &inbox, &mut st).await;
        }
        self.goodbye(&client, &inbox, &mut acks, &st).await;
        if let Some(s) = service {
            let _ = s.stop().await;
        }
        let _ = client.flush().await;
    }

    /// Makes sure the streams exist (an existing stream of the name is
    /// used as it is; one that cannot be created is logged, publishing
    /// goes on: a stream the operator made may cover the subjects), then
    /// reports the connection ready.
    fn prepare(&self, js: &jetstream::Context, st: &State, link: &mpsc::UnboundedSender<Link>) {
        let (js, link, generation) = (js.clone(), link.clone(), st.generation);
        let events = events_stream(self.format, &self.identity.gateway);
        let (bridge, format) = (self.bridge.clone(), self.format.level());
        tokio::spawn(async move {
            for config in [events, status_stream()] {
                let name = config.name.clone();
                if let Err(e) = js.get_or_create_stream(config).await {
                    tracing::warn!(%bridge, format, stream = %name, error = %e,
                        "JetStream stream not created; publishing to the subjects anyway");
                }
            }
            let _ = link.send(Link::Ready(generation));
        });
    }

    fn ready(&mut self, st: &mut State) {
        st.up = true;
        st.waiting_since = None;
        self.queue.on_connected();
        self.push_status(true);
        crate::metrics::bridge_connected(&self.bridge, self.format.level(), true);
        tracing::info!(bridge = %self.bridge, format = self.format.level(), "connected to NATS");
    }

    /// Everything sent and not acknowledged goes back to the queue, to be
    /// sent again (same `Nats-Msg-Id`) when the connection is ready.
    fn give_back(&mut self, st: &mut State, why: &str) {
        st.generation += 1;
        st.waiting_since = None;
        let was_up = std::mem::replace(&mut st.up, false);
        self.queue.on_disconnected();
        crate::metrics::bridge_connected(&self.bridge, self.format.level(), false);
        if was_up {
            tracing::warn!(bridge = %self.bridge, format = self.format.level(), "{why}");
        }
    }

    fn push_status(&mut self, online: bool) {
        let status = self.identity.envelope(
            "status",
            0,
            now_ns(),
            pb::bridge_envelope::Payload::Status(self.identity.status(online)),
        );
        self.queue
            .push_state_first("status", true, super::encode(self.format, &status));
    }

    /// A PubAck (or a refusal) on `<inbox>.<generation>.<id>`.
    fn on_ack(&mut self, inbox: &str, m: &async_nats::Message, st: &mut State) {
        let Some((generation, id)) = m
            .subject
            .strip_prefix(inbox)
            .and_then(|r| r.strip_prefix('.'))
            .and_then(|r| r.split_once('.'))
            .and_then(|(g, i)| Some((g.parse::<u64>().ok()?, i.parse::<u16>().ok()?)))
        else {
            return;
        };
        if generation != st.generation || !st.up {
            return;
        }
        let refusal = match &m.status {
            Some(s) if !s.is_success() => Some(format!(
                "status {s}{}",
                m.description
                    .as_deref()
                    .map(|d| format!(" {d}"))
                    .unwrap_or_default()
            )),
            _ => match serde_json::from_slice::<serde_json::Value>(&m.payload) {
                Ok(v) if v.get("error").is_some() => Some(v["error"].to_string()),
                Ok(v) if v.get("stream").is_some() => None,
                _ => Some("not a PubAck".into()),
            },
        };
        match refusal {
            None => {
                let s = self.queue.on_acked(id);
                crate::metrics::bridge_settled(
                    &self.bridge,
                    self.format.level(),
                    0,
                    s.acknowledged,
                );
                st.refusal_logged = false;
                st.waiting_since = (self.queue.unsettled() > 0).then(Instant::now);
            }
            Some(why) => {
                if !st.refusal_logged {
                    tracing::warn!(bridge = %self.bridge, format = self.format.level(),
                        %why, "JetStream refused a publish; sending again");
                    st.refusal_logged = true;
                }
                self.give_back(st, "JetStream refused a publish");
                st.retry_at = Some(Instant::now() + REFUSED_PAUSE);
            }
        }
    }

    /// Hands the client what the queue and the window allow.
    async fn pump(&mut self, client: &async_nats::Client, inbox: &str, st: &mut State) {
        let format = self.format.level();
        if st.up {
            while let Some(item) = self.queue.next_to_send() {
                st.next_id = st.next_id.wrapping_add(1).max(1);
                let id = st.next_id;
                let subject = subject(self.format, &self.identity.gateway, &item.stream);
                let gap = matches!(item.payload, Payload::Gap(_));
                let body = body_of(
                    &self.identity,
                    self.format,
                    &item.stream,
                    item.seq,
                    item.payload,
                );
                let sent = if item.acked {
                    let mut headers = async_nats::HeaderMap::new();
                    if item.seq > 0 {
                        headers.insert(
                            "Nats-Msg-Id",
                            format!(
                                "{}/{}/{}/{}",
                                self.identity.gateway, self.identity.epoch, item.stream, item.seq
                            )
                            .as_str(),
                        );
                    }
                    let reply = format!("{inbox}.{}.{id}", st.generation);
                    st.waiting_since.get_or_insert_with(Instant::now);
                    client
                        .publish_with_reply_and_headers(subject, reply, headers, body.into())
                        .await
                } else {
                    client.publish(subject, body.into()).await
                };
                if let Err(e) = sent {
                    tracing::debug!(bridge = %self.bridge, format, gap, error = %e, "publish");
                }
                let s = self.queue.on_written(id);
                crate::metrics::bridge_settled(&self.bridge, format, s.written, 0);
            }
        }
        crate::metrics::bridge_queued(
            &self.bridge,
            format,
            self.queue.waiting() + self.queue.unsettled(),
        );
    }

    /// The services API: `$SRV.PING|INFO|STATS[.cangate[.<id>]]`, with the
    /// gateway's id, epoch, buses and axes as metadata.
    async fn start_service(
        &self,
        client: &async_nats::Client,
    ) -> Option<async_nats::service::Service> {
        let id = &self.identity;
        let metadata = HashMap::from([
            ("gateway".to_string(), id.gateway.clone()),
            ("epoch".to_string(), id.epoch.to_string()),
            ("buses".to_string(), id.buses.join(",")),
            ("axes".to_string(), id.axes.join(",")),
        ]);
        match client
            .service_builder()
            .description(format!("cangate gateway {}", id.gateway))
            .metadata(metadata)
            .start(SERVICE_NAME, env!("CARGO_PKG_VERSION"))
            .await
        {
            Ok(s) => Some(s),
            Err(e) => {
                tracing::warn!(bridge = %self.bridge, error = %e, "NATS services API not started");
                None
            }
        }
    }

    /// At shutdown: the offline status, waiting at most a moment for its
    /// PubAck.
    async fn goodbye(
        &mut self,
        client: &async_nats::Client,
        inbox: &str,
        acks: &mut async_nats::Subscriber,
        st: &State,
    ) {
        if !st.up {
            return;
        }
        let status = self.identity.envelope(
            "status",
            0,
            now_ns(),
            pb::bridge_envelope::Payload::Status(self.identity.status(false)),
        );
        let reply = format!("{inbox}.goodbye");
        let subject = subject(self.format, &self.identity.gateway, "status");
        if client
            .publish_with_reply(
                subject,
                reply.clone(),
                super::encode(self.format, &status).into(),
            )
            .await
            .is_err()
        {
            return;
        }
        let acked = async {
            while let Some(m) = acks.next().await {
                if m.subject.as_str() == reply {
                    return;
                }
            }
        };
        let _ = tokio::time::timeout(Duration::from_secs(2), acked).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn subjects_are_the_topics_with_dots() {
        assert_eq!(
            subject(BridgeFormat::Json, "press-7", "bus/can0/node/5/event"),
            "cangate.v1.json.press-7.bus.can0.node.5.event"
        );
        assert_eq!(
            subject(BridgeFormat::Pb, "m1", "axis/x.1 a*/state"),
            "cangate.v1.pb.m1.axis.x_1_a_.state",
            "a level never splits into two tokens nor holds a wildcard"
        );
        assert_eq!(events_stream_name(BridgeFormat::Pb, "m1"), "CANGATE_m1_PB");
    }

    #[test]
    fn the_events_stream_covers_every_acknowledged_subject_but_status_and_frames() {
        let config = events_stream(BridgeFormat::Json, "m1");
        let covered = |s: &str| {
            let tokens: Vec<&str> = s.split('.').collect();
            config.subjects.iter().any(|f| {
                let pattern: Vec<&str> = f.split('.').collect();
                let mut i = 0;
                for (k, p) in pattern.iter().enumerate() {
                    if *p == ">" {
                        return tokens.len() > k;
                    }
                    if i >= tokens.len() || (*p != "*" && *p != tokens[i]) {
                        return false;
                    }
                    i += 1;
                }
                i == tokens.len()
            })
        };
        for stream in [
            "bus/can0/node/5/event",
            "bus/can0/stats",
            "bus/can0/gap",
            "gap",
            "axis/X/state",
            "axis/X/event",
            "handwheel/hw1/feed",
            "cansmc/m/status",
        ] {
            assert!(
                covered(&subject(BridgeFormat::Json, "m1", stream)),
                "{stream}"
            );
        }
        for stream in ["status", "bus/can0/frames"] {
            assert!(
                !covered(&subject(BridgeFormat::Json, "m1", stream)),
                "{stream}"
            );
        }
        assert!(!covered(&subject(BridgeFormat::Pb, "m1", "bus/can0/stats")));
        assert!(!covered(&subject(
            BridgeFormat::Json,
            "m2",
            "bus/can0/stats"
        )));
        assert_eq!(config.duplicate_window, DUPLICATE_WINDOW);
    }
}
