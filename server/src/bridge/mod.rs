//! The plant bridge: an edge that publishes the gateway's streams to an
//! MQTT broker or to NATS JetStream ([`nats`]) (`[[bridge]]`,
//! docs/bridge.md). Read-only: it publishes, it takes no commands
//! (commands stay on gRPC with their roles, leases and dead-man).
//!
//! Each bridge and format (`pb`, `json`: each its own topic tree) is one
//! broker connection with its own [`queue::Queue`] and its own last will.
//! Sources (node events, frames, bus statistics) are read from the runtime
//! as the gRPC streams read them and wrapped in a `BridgeEnvelope`; the
//! publisher task numbers them per stream, holds them while the broker is
//! away and turns what it cannot hold into gap records.

pub mod nats;
pub mod queue;
mod tls;

use crate::axis_runner::AxisUpdate;
use crate::config::{BridgeConfig, BridgeFormat, BridgeStream, BrokerProtocol};
use crate::convert::bus::{bus_info_to_pb, item_to_pb};
use crate::convert::canopen::node_event_to_pb;
use crate::gateway::Gateway;
use cangate_can::FrameSelector;
use cangate_can::bus::BusItem;
use cangate_proto::v1 as pb;
use prost::Message;
use queue::{GapReason, Payload, Queue};
use rumqttc::{AsyncClient, Event, Incoming, LastWill, MqttOptions, Outgoing, QoS, Transport};
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

/// Publishes handed to the MQTT client and not yet settled, per
/// connection (the client's in-flight window).
const WINDOW: usize = 100;
/// Most events in one frame batch.
const MAX_BATCH: usize = 256;
/// Source items waiting for the publisher task.
const SOURCE_QUEUE: usize = 1024;

/// Why a bridge could not start.
#[derive(Debug, thiserror::Error)]
#[error("[[bridge]] {bridge:?}: {message}")]
pub struct BridgeError {
    /// The bridge.
    pub bridge: String,
    /// What is wrong (a file that cannot be read, …).
    pub message: String,
}

/// One thing a source hands to the publisher.
enum Source {
    /// A message of `stream`.
    Message {
        stream: String,
        acked: bool,
        retain: bool,
        timestamp_ns: u64,
        payload: Box<pb::bridge_envelope::Payload>,
    },
    /// `n` messages of `stream` the source dropped before the bridge read
    /// them.
    Lost { stream: String, n: u64 },
}

/// What is fixed for every message of one gateway run.
#[derive(Clone)]
struct Identity {
    gateway: String,
    epoch: u64,
    buses: Vec<String>,
    axes: Vec<String>,
}

impl Identity {
    fn status(&self, online: bool) -> pb::GatewayStatus {
        pb::GatewayStatus {
            online,
            gateway: self.gateway.clone(),
            version: env!("CARGO_PKG_VERSION").to_string(),
            buses: self.buses.clone(),
            axes: self.axes.clone(),
            started_ns: self.epoch,
        }
    }

    fn envelope(
        &self,
        stream: &str,
        seq: u64,
        timestamp_ns: u64,
        payload: pb::bridge_envelope::Payload,
    ) -> pb::BridgeEnvelope {
        pb::BridgeEnvelope {
            gateway: self.gateway.clone(),
            epoch: self.epoch,
            stream: stream.to_string(),
            seq,
            timestamp_ns,
            payload: Some(payload),
        }
    }
}

fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

/// An envelope in `format`: protobuf, or canonical proto3 JSON.
fn encode(format: BridgeFormat, envelope: &pb::BridgeEnvelope) -> Vec<u8> {
    match format {
        BridgeFormat::Pb => envelope.encode_to_vec(),
        BridgeFormat::Json => serde_json::to_vec(envelope).unwrap_or_default(),
    }
}

/// Starts every configured bridge: one publisher task per bridge and
/// format, with its sources. They end with `shutdown`, after publishing
/// the offline status.
pub fn start(
    bridges: &[BridgeConfig],
    gateway: Arc<Gateway>,
    shutdown: CancellationToken,
) -> Result<Vec<JoinHandle<()>>, BridgeError> {
    let epoch = now_ns();
    let mut tasks = Vec::new();
    for b in bridges {
        let err = |message: String| BridgeError {
            bridge: b.name.clone(),
            message,
        };
        let broker = b.broker().map_err(err)?;
        let gateway_id = b.gateway_id().map_err(err)?;
        let password = match &b.password_file {
            Some(p) if broker.protocol == BrokerProtocol::Mqtt => {
                Some(first_line(p).map_err(|e| err(format!("password_file {e}")))?)
            }
            _ => None,
        };
        let tls = if broker.tls && broker.protocol == BrokerProtocol::Mqtt {
            Some(tls::client_config(b).map_err(err)?)
        } else {
            None
        };
        let identity = Identity {
            gateway: gateway_id,
            epoch,
            buses: (gateway.buses())
                .map(|h| h.name().to_string())
                .filter(|n| b.buses.is_empty() || b.buses.contains(n))
                .collect(),
            axes: (0..gateway.axes().len())
                .map(|i| gateway.axes().name(i).to_string())
                .collect(),
        };
        if broker.protocol == BrokerProtocol::Nats {
            for (i, &format) in b.formats.iter().enumerate() {
                let client_name =
                    format!("cangate-{}-{}-{}", identity.gateway, b.name, format.level());
                let options = nats::options(b, client_name, broker.tls).map_err(err)?;
                let (tx, rx) = mpsc::channel(SOURCE_QUEUE);
                start_sources(b, &gateway, &tx, &shutdown);
                drop(tx);
                let publisher = nats::NatsPublisher {
                    bridge: b.name.clone(),
                    format,
                    identity: identity.clone(),
                    queue: Queue::new(b.queue_size as usize, WINDOW),
                    service: i == 0,
                };
                let url = format!("nats://{}:{}", broker.host, broker.port);
                tasks.push(tokio::spawn(publisher.run(
                    url,
                    options,
                    rx,
                    shutdown.clone(),
                )));
            }
            continue;
        }
        for &format in &b.formats {
            let mut options = MqttOptions::new(
                format!("cangate-{}-{}-{}", identity.gateway, b.name, format.level()),
                broker.host.clone(),
                broker.port,
            );
            options
                .set_clean_session(true)
                .set_keep_alive(Duration::from_secs(5))
                .set_inflight(WINDOW as u16)
                .set_max_packet_size(1 << 20, 1 << 20)
                .set_last_will(LastWill::new(
                    topic(format, &identity.gateway, "status"),
                    encode(
                        format,
                        &identity.envelope(
                            "status",
                            0,
                            epoch,
                            pb::bridge_envelope::Payload::Status(identity.status(false)),
                        ),
                    ),
                    QoS::AtLeastOnce,
                    true,
                ));
            if let Some(user) = &b.username {
                options.set_credentials(user.clone(), password.clone().unwrap_or_default());
            }
            if let Some(tls) = &tls {
                options.set_transport(Transport::tls_with_config(
                    rumqttc::TlsConfiguration::Rustls(tls.clone()),
                ));
            }
            let (tx, rx) = mpsc::channel(SOURCE_QUEUE);
            start_sources(b, &gateway, &tx, &shutdown);
            drop(tx);
            let publisher = Publisher {
                bridge: b.name.clone(),
                format,
                identity: identity.clone(),
                queue: Queue::new(b.queue_size as usize, WINDOW),
                client: None,
            };
            tasks.push(tokio::spawn(publisher.run(options, rx, shutdown.clone())));
        }
    }
    Ok(tasks)
}

/// The first line of a secret's file (the secret itself never in the
/// message).
fn first_line(path: &std::path::Path) -> Result<String, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(text.lines().next().unwrap_or("").to_string())
}

/// The topic of `stream` in `format`'s tree.
fn topic(format: BridgeFormat, gateway: &str, stream: &str) -> String {
    format!("cangate/v1/{}/{gateway}/{stream}", format.level())
}

/// Spawns the source tasks of bridge `b`, feeding `tx`.
fn start_sources(
    b: &BridgeConfig,
    gateway: &Gateway,
    tx: &mpsc::Sender<Source>,
    shutdown: &CancellationToken,
) {
    let wanted = |bus: &str| b.buses.is_empty() || b.buses.iter().any(|n| n == bus);
    let state = b.streams.contains(&BridgeStream::AxisState);
    let events = b.streams.contains(&BridgeStream::AxisEvents);
    if state || events {
        let m = gateway.axes().clone();
        let streams = AxisStreams {
            wanted: (0..m.len())
                .map(|i| b.axes.is_empty() || b.axes.iter().any(|a| a == m.name(i)))
                .collect(),
            state_every: state.then(|| Duration::from_millis(b.axis_state_interval_ms)),
            events,
        };
        let rx = m.subscribe();
        tokio::spawn(axes(m, rx, streams, tx.clone(), shutdown.clone()));
    }
    for &stream in &b.streams {
        match stream {
            BridgeStream::NodeEvents => {
                for m in gateway.canopen_buses().filter(|m| wanted(m.bus())) {
                    let bus = m.bus().to_string();
                    let events = m.events();
                    tokio::spawn(node_events(bus, events, tx.clone(), shutdown.clone()));
                }
            }
            BridgeStream::BusStats => {
                for h in gateway.buses().filter(|h| wanted(h.name())) {
                    let every = Duration::from_millis(b.stats_interval_ms);
                    tokio::spawn(bus_stats(h.clone(), every, tx.clone(), shutdown.clone()));
                }
            }
            BridgeStream::AxisState | BridgeStream::AxisEvents => {}
            BridgeStream::HandwheelFeed => {
                let wheels = gateway.handwheels().clone();
                let rx = wheels.subscribe();
                tokio::spawn(handwheel_feed(wheels, rx, tx.clone(), shutdown.clone()));
            }
            BridgeStream::CansmcStatus => {
                for m in gateway.cansmc_masters() {
                    let every = Duration::from_millis(b.stats_interval_ms);
                    tokio::spawn(cansmc_status(
                        m.clone(),
                        every,
                        tx.clone(),
                        shutdown.clone(),
                    ));
                }
            }
            BridgeStream::Frames => {
                let filters = b.filters().unwrap_or_default();
                for h in gateway.buses().filter(|h| wanted(h.name())) {
                    let selector = FrameSelector {
                        filters: filters.clone(),
                        ..FrameSelector::default()
                    };
                    let sub = h.subscribe(selector, b.queue_size as usize);
                    let batching = Batching {
                        wait: Duration::from_millis(b.frame_batch_ms),
                        rate: b.frame_rate_limit,
                    };
                    let bus = h.name().to_string();
                    tokio::spawn(frames(bus, sub, batching, tx.clone(), shutdown.clone()));
                }
            }
        }
    }
}

/// What of the axes a bridge publishes.
struct AxisStreams {
    /// Per axis index: published or not.
    wanted: Vec<bool>,
    /// Shortest time between two states of one axis.
    state_every: Option<Duration>,
    events: bool,
}

/// The axes' states (retained, at most one per `state_every` and axis,
/// only when changed: the latest is published when the time comes) and
/// events. A state that came too soon waits for the axis's next turn, so
/// the last state of a move is always published.
async fn axes(
    axes: Arc<crate::axes::Axes>,
    mut rx: tokio::sync::broadcast::Receiver<AxisUpdate>,
    streams: AxisStreams,
    tx: mpsc::Sender<Source>,
    shutdown: CancellationToken,
) {
    use crate::convert::axes::{event_pb, status_pb};
    use tokio::sync::broadcast::error::RecvError;
    use tokio::time::Instant;
    let n = axes.len();
    let mut last_sent: Vec<Option<Arc<cangate_axis::cia402::AxisSnapshot>>> = vec![None; n];
    let mut next_at: Vec<Instant> = vec![Instant::now(); n];
    type Latest = Option<(
        Arc<cangate_axis::cia402::AxisSnapshot>,
        cangate_can::Timestamp,
    )>;
    // The current state first, so a consumer sees every axis at once (an
    // axis at rest sends no new state).
    let mut pending: Vec<Latest> = (0..n)
        .map(|i| {
            (streams.wanted[i] && streams.state_every.is_some())
                .then(|| axes.latest(i))
                .flatten()
        })
        .collect();
    loop {
        let due = (0..n)
            .filter(|&i| pending[i].is_some())
            .map(|i| next_at[i])
            .min();
        let received = tokio::select! {
            biased;
            _ = shutdown.cancelled() => return,
            _ = async { tokio::time::sleep_until(due.unwrap()).await }, if due.is_some() => None,
            r = rx.recv() => Some(r),
        };
        let mut out = Vec::new();
        match received {
            Some(Ok(AxisUpdate::Status { axis, snapshot, at }))
                if streams.wanted[axis]
                    && streams.state_every.is_some()
                    && last_sent[axis].as_deref() != Some(snapshot.as_ref()) =>
            {
                pending[axis] = Some((snapshot, at));
            }
            Some(Ok(AxisUpdate::Event { axis, at, event }))
                if streams.wanted[axis] && streams.events =>
            {
                let ev = event_pb(&axes, axis, at, event);
                out.push(Source::Message {
                    stream: format!("axis/{}/event", axes.name(axis)),
                    acked: true,
                    retain: false,
                    timestamp_ns: at.0,
                    payload: Box::new(pb::bridge_envelope::Payload::AxisEvent(ev)),
                });
            }
            // Which axes the lost updates were of is unknown: states are
            // superseded by the next, events are counted here.
            Some(Err(RecvError::Lagged(k))) if streams.events => out.push(Source::Lost {
                stream: "axis_events".into(),
                n: k,
            }),
            Some(Err(RecvError::Closed)) => return,
            _ => {}
        }
        let now = Instant::now();
        if let Some(every) = streams.state_every {
            for i in 0..n {
                if next_at[i] <= now
                    && let Some((snapshot, at)) = pending[i].take()
                {
                    let st = status_pb(&axes, i, Some(&snapshot), at);
                    last_sent[i] = Some(snapshot);
                    next_at[i] = now + every;
                    out.push(Source::Message {
                        stream: format!("axis/{}/state", axes.name(i)),
                        acked: true,
                        retain: true,
                        timestamp_ns: at.0,
                        payload: Box::new(pb::bridge_envelope::Payload::AxisStatus(st)),
                    });
                }
            }
        }
        for source in out {
            if tx.send(source).await.is_err() {
                return;
            }
        }
    }
}

/// The handwheels' feed events, one stream per wheel.
async fn handwheel_feed(
    wheels: Arc<crate::handwheel::Handwheels>,
    mut rx: tokio::sync::broadcast::Receiver<crate::handwheel::WheelFeed>,
    tx: mpsc::Sender<Source>,
    shutdown: CancellationToken,
) {
    use crate::convert::handwheel::event_pb;
    use tokio::sync::broadcast::error::RecvError;
    loop {
        let received = tokio::select! {
            biased;
            _ = shutdown.cancelled() => return,
            r = rx.recv() => r,
        };
        let source = match received {
            Ok(f) => {
                let ev = event_pb(&wheels, &f);
                Source::Message {
                    stream: format!("handwheel/{}/feed", ev.handwheel),
                    acked: true,
                    retain: false,
                    timestamp_ns: f.at.0,
                    payload: Box::new(pb::bridge_envelope::Payload::Feed(ev)),
                }
            }
            Err(RecvError::Lagged(n)) => Source::Lost {
                stream: "handwheel_feed".into(),
                n,
            },
            Err(RecvError::Closed) => return,
        };
        if tx.send(source).await.is_err() {
            return;
        }
    }
}

/// The status of one CANsmc master, every `every`.
async fn cansmc_status(
    master: crate::cansmc::CansmcMaster,
    every: Duration,
    tx: mpsc::Sender<Source>,
    shutdown: CancellationToken,
) {
    let stream = format!("cansmc/{}/status", master.name());
    let mut tick = tokio::time::interval(every);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            biased;
            _ = shutdown.cancelled() => return,
            _ = tick.tick() => {}
        }
        let status = crate::convert::cansmc::status_pb(&master, &master.status());
        let source = Source::Message {
            stream: stream.clone(),
            acked: true,
            retain: false,
            timestamp_ns: now_ns(),
            payload: Box::new(pb::bridge_envelope::Payload::CansmcStatus(status)),
        };
        if tx.send(source).await.is_err() {
            return;
        }
    }
}

/// The node events of one bus, one stream per node.
async fn node_events(
    bus: String,
    mut events: tokio::sync::broadcast::Receiver<crate::canopen::NodeEvent>,
    tx: mpsc::Sender<Source>,
    shutdown: CancellationToken,
) {
    use tokio::sync::broadcast::error::RecvError;
    loop {
        let received = tokio::select! {
            biased;
            _ = shutdown.cancelled() => return,
            r = events.recv() => r,
        };
        let source = match received {
            Ok(ev) => {
                let msg = node_event_to_pb(&bus, &ev);
                Source::Message {
                    stream: format!("bus/{bus}/node/{}/event", ev.node.get()),
                    acked: true,
                    retain: false,
                    timestamp_ns: msg.timestamp_ns,
                    payload: Box::new(pb::bridge_envelope::Payload::NodeEvent(msg)),
                }
            }
            // Which nodes the lost events were of is unknown: a gap of the
            // bus's `node_events` stream stands for them.
            Err(RecvError::Lagged(n)) => Source::Lost {
                stream: format!("bus/{bus}/node_events"),
                n,
            },
            Err(RecvError::Closed) => return,
        };
        if tx.send(source).await.is_err() {
            return;
        }
    }
}

/// The statistics of one bus, every `every`.
async fn bus_stats(
    bus: cangate_can::bus::BusHandle,
    every: Duration,
    tx: mpsc::Sender<Source>,
    shutdown: CancellationToken,
) {
    let stream = format!("bus/{}/stats", bus.name());
    let mut tick = tokio::time::interval(every);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            biased;
            _ = shutdown.cancelled() => return,
            _ = tick.tick() => {}
        }
        let info = bus_info_to_pb(bus.info(), &bus.stats());
        let source = Source::Message {
            stream: stream.clone(),
            acked: true,
            retain: false,
            timestamp_ns: now_ns(),
            payload: Box::new(pb::bridge_envelope::Payload::Bus(info)),
        };
        if tx.send(source).await.is_err() {
            return;
        }
    }
}

/// How frames are batched.
struct Batching {
    /// Longest a frame waits for its batch.
    wait: Duration,
    /// Most frames per second (0: no limit).
    rate: u32,
}

/// The frames of one bus, in batches of at most [`MAX_BATCH`] events or
/// `wait`, at most `rate` frames a second (the rest counted as lost in the
/// batch).
async fn frames(
    bus: String,
    mut sub: cangate_can::bus::Subscription,
    batching: Batching,
    tx: mpsc::Sender<Source>,
    shutdown: CancellationToken,
) {
    let stream = format!("bus/{bus}/frames");
    let mut name_of = |id: cangate_can::ClientId| format!("{id:?}");
    let mut buf = Vec::new();
    let mut window_start = tokio::time::Instant::now();
    let mut in_window: u32 = 0;
    loop {
        let mut batch: Vec<pb::StreamEvent> = Vec::new();
        let mut deadline = None;
        let mut over_rate = 0u64;
        while batch.len() < MAX_BATCH {
            buf.clear();
            let got = match deadline {
                None => tokio::select! {
                    biased;
                    _ = shutdown.cancelled() => return,
                    n = sub.recv_many(&mut buf, MAX_BATCH - batch.len()) => n,
                },
                Some(d) => tokio::select! {
                    biased;
                    _ = shutdown.cancelled() => return,
                    _ = tokio::time::sleep_until(d) => break,
                    n = sub.recv_many(&mut buf, MAX_BATCH - batch.len()) => n,
                },
            };
            if got == 0 {
                return;
            }
            let now = tokio::time::Instant::now();
            deadline.get_or_insert(now + batching.wait);
            for item in &buf {
                if let BusItem::Frame { .. } = item
                    && batching.rate > 0
                {
                    if now.duration_since(window_start) >= Duration::from_secs(1) {
                        window_start = now;
                        in_window = 0;
                    }
                    if in_window >= batching.rate {
                        over_rate += 1;
                        continue;
                    }
                    in_window += 1;
                }
                if over_rate > 0 {
                    batch.push(pb::StreamEvent {
                        event: Some(pb::stream_event::Event::Lost(pb::FramesLost {
                            count: over_rate,
                        })),
                    });
                    over_rate = 0;
                }
                batch.push(item_to_pb(item, 0, &mut name_of));
            }
        }
        if over_rate > 0 {
            batch.push(pb::StreamEvent {
                event: Some(pb::stream_event::Event::Lost(pb::FramesLost {
                    count: over_rate,
                })),
            });
        }
        if batch.is_empty() {
            continue;
        }
        let timestamp_ns = batch
            .iter()
            .find_map(|e| match &e.event {
                Some(pb::stream_event::Event::Frame(f)) => Some(f.timestamp_ns),
                _ => None,
            })
            .unwrap_or_else(now_ns);
        let source = Source::Message {
            stream: stream.clone(),
            acked: false,
            retain: false,
            timestamp_ns,
            payload: Box::new(pb::bridge_envelope::Payload::Frames(
                pb::StreamFramesResponse { events: batch },
            )),
        };
        if tx.send(source).await.is_err() {
            return;
        }
    }
}

/// What the connection task tells the publisher; `u64` is the
/// connection's generation (a new client per connection, so nothing handed
/// to an old one can be written on a new one).
enum Connection {
    /// A new client, connecting.
    Client(u64, AsyncClient),
    /// An event of the client's event loop.
    Event(u64, Event),
    /// The connection ended.
    Down(u64, String),
}

/// One broker connection: its queue and its client.
struct Publisher {
    bridge: String,
    format: BridgeFormat,
    identity: Identity,
    queue: Queue<Vec<u8>>,
    /// The current client, and whether its connection is up.
    client: Option<(u64, AsyncClient, bool)>,
}

impl Publisher {
    async fn run(
        mut self,
        options: MqttOptions,
        mut sources: mpsc::Receiver<Source>,
        shutdown: CancellationToken,
    ) {
        let (conn_tx, mut conn_rx) = mpsc::unbounded_channel();
        let stop_connection = CancellationToken::new();
        let connection = tokio::spawn(connect_loop(options, conn_tx, stop_connection.clone()));
        let mut sources_open = true;
        loop {
            tokio::select! {
                biased;
                _ = shutdown.cancelled() => break,
                c = conn_rx.recv() => match c {
                    Some(c) => self.on_connection(c),
                    None => break,
                },
                s = sources.recv(), if sources_open => match s {
                    Some(s) => self.on_source(s),
                    None => sources_open = false,
                },
            }
            self.pump();
        }
        self.goodbye(&mut conn_rx).await;
        stop_connection.cancel();
        let _ = connection.await;
    }

    fn format_label(&self) -> &'static str {
        self.format.level()
    }

    fn on_connection(&mut self, c: Connection) {
        let format = self.format_label();
        match c {
            Connection::Client(generation, client) => {
                self.client = Some((generation, client, false))
            }
            Connection::Event(generation, event) => {
                let Some((current, _, up)) = &mut self.client else {
                    return;
                };
                if *current != generation {
                    return;
                }
                match event {
                    Event::Incoming(Incoming::ConnAck(_)) => {
                        *up = true;
                        let status = self.identity.envelope(
                            "status",
                            0,
                            now_ns(),
                            pb::bridge_envelope::Payload::Status(self.identity.status(true)),
                        );
                        self.queue
                            .push_state_first("status", true, encode(self.format, &status));
                        self.queue.on_connected();
                        crate::metrics::bridge_connected(&self.bridge, format, true);
                        tracing::info!(bridge = %self.bridge, format, "connected to the broker");
                    }
                    Event::Outgoing(Outgoing::Publish(pkid)) => {
                        let s = self.queue.on_written(pkid);
                        crate::metrics::bridge_settled(&self.bridge, format, s.written, 0);
                    }
                    Event::Incoming(Incoming::PubAck(ack)) => {
                        let s = self.queue.on_acked(ack.pkid);
                        crate::metrics::bridge_settled(&self.bridge, format, 0, s.acknowledged);
                    }
                    _ => {}
                }
            }
            Connection::Down(generation, why) => {
                if self
                    .client
                    .as_ref()
                    .is_some_and(|(g, _, _)| *g == generation)
                {
                    let was_up = self.client.take().is_some_and(|(_, _, up)| up);
                    self.queue.on_disconnected();
                    crate::metrics::bridge_connected(&self.bridge, format, false);
                    if was_up {
                        tracing::warn!(bridge = %self.bridge, format, %why, "broker connection lost");
                    } else {
                        tracing::debug!(bridge = %self.bridge, format, %why, "broker not reachable");
                    }
                }
            }
        }
    }

    fn on_source(&mut self, s: Source) {
        queue_source(
            &mut self.queue,
            &self.bridge,
            self.format,
            &self.identity,
            s,
        );
    }

    /// Hands the client what the queue and the window allow.
    fn pump(&mut self) {
        let Some((_, client, true)) = &self.client else {
            crate::metrics::bridge_queued(&self.bridge, self.format_label(), self.held());
            return;
        };
        while let Some(item) = self.queue.next_to_send() {
            let body = body_of(
                &self.identity,
                self.format,
                &item.stream,
                item.seq,
                item.payload,
            );
            let qos = if item.acked {
                QoS::AtLeastOnce
            } else {
                QoS::AtMostOnce
            };
            let t = topic(self.format, &self.identity.gateway, &item.stream);
            // The window is smaller than the client's channel, so this
            // fails only when the connection is ending: its Down puts the
            // item back.
            let _ = client.try_publish(t, qos, item.retain, body);
        }
        crate::metrics::bridge_queued(&self.bridge, self.format_label(), self.held());
    }

    fn held(&self) -> usize {
        self.queue.waiting() + self.queue.unsettled()
    }

    /// At shutdown: the offline status (retained), then a clean
    /// disconnect, waiting at most a moment for the broker.
    async fn goodbye(&mut self, conn_rx: &mut mpsc::UnboundedReceiver<Connection>) {
        let Some((generation, client, true)) = self.client.clone() else {
            return;
        };
        let status = self.identity.envelope(
            "status",
            0,
            now_ns(),
            pb::bridge_envelope::Payload::Status(self.identity.status(false)),
        );
        let t = topic(self.format, &self.identity.gateway, "status");
        if client
            .try_publish(t, QoS::AtLeastOnce, true, encode(self.format, &status))
            .is_err()
        {
            return;
        }
        // The goodbye was handed last: its written report is the one that
        // comes when the queue has none outstanding; the queue's own
        // reports are still settled on the way.
        let acked = async {
            let mut goodbye = None;
            while let Some(c) = conn_rx.recv().await {
                match c {
                    Connection::Event(g, Event::Outgoing(Outgoing::Publish(pkid)))
                        if g == generation =>
                    {
                        if self.queue.handed() == 0 {
                            goodbye = Some(pkid);
                        } else {
                            self.queue.on_written(pkid);
                        }
                    }
                    Connection::Event(g, Event::Incoming(Incoming::PubAck(ack)))
                        if g == generation =>
                    {
                        if goodbye == Some(ack.pkid) {
                            return;
                        }
                        self.queue.on_acked(ack.pkid);
                    }
                    Connection::Down(..) => return,
                    _ => {}
                }
            }
        };
        let _ = tokio::time::timeout(Duration::from_secs(2), acked).await;
        let _ = client.try_disconnect();
    }
}

/// Numbers and queues what a source handed over, and counts the gaps it
/// made.
fn queue_source(
    queue: &mut Queue<Vec<u8>>,
    bridge: &str,
    format: BridgeFormat,
    identity: &Identity,
    s: Source,
) {
    match s {
        Source::Message {
            stream,
            acked,
            retain,
            timestamp_ns,
            payload,
        } => {
            queue.push(&stream, acked, retain, |seq| {
                encode(
                    format,
                    &identity.envelope(&stream, seq, timestamp_ns, *payload),
                )
            });
        }
        Source::Lost { stream, n } => queue.lost(&stream, n),
    }
    let (full, lagged) = queue.take_new_gaps();
    if full > 0 {
        crate::metrics::bridge_gap(bridge, format.level(), "queue_full", full);
    }
    if lagged > 0 {
        crate::metrics::bridge_gap(bridge, format.level(), "source_lagged", lagged);
    }
}

/// The bytes of a queue item: a message as queued, a gap record encoded
/// now.
fn body_of(
    identity: &Identity,
    format: BridgeFormat,
    stream: &str,
    seq: u64,
    payload: Payload<Vec<u8>>,
) -> Vec<u8> {
    match payload {
        Payload::Message(bytes) => bytes,
        Payload::Gap(g) => {
            let gap = pb::BridgeGap {
                stream: g.stream,
                first_seq: g.first,
                last_seq: g.last,
                count: g.last - g.first + 1,
                reason: match g.reason {
                    GapReason::QueueFull => pb::GapReason::QueueFull,
                    GapReason::SourceLagged => pb::GapReason::SourceLagged,
                } as i32,
            };
            let env = identity.envelope(
                stream,
                seq,
                now_ns(),
                pb::bridge_envelope::Payload::Gap(gap),
            );
            encode(format, &env)
        }
    }
}

/// Connects, runs the client's event loop until the connection ends, and
/// connects again after a pause (0.25 s, doubling to 5 s), each time with a
/// new client.
async fn connect_loop(
    options: MqttOptions,
    tx: mpsc::UnboundedSender<Connection>,
    stop: CancellationToken,
) {
    let mut pause = Duration::from_millis(250);
    for generation in 1.. {
        let (client, mut events) = AsyncClient::new(options.clone(), WINDOW + 16);
        if tx.send(Connection::Client(generation, client)).is_err() {
            return;
        }
        loop {
            let r = tokio::select! {
                biased;
                _ = stop.cancelled() => return,
                r = events.poll() => r,
            };
            match r {
                Ok(event) => {
                    if matches!(event, Event::Incoming(Incoming::ConnAck(_))) {
                        pause = Duration::from_millis(250);
                    }
                    if tx.send(Connection::Event(generation, event)).is_err() {
                        return;
                    }
                }
                Err(e) => {
                    let _ = tx.send(Connection::Down(generation, e.to_string()));
                    break;
                }
            }
        }
        tokio::select! {
            _ = stop.cancelled() => return,
            _ = tokio::time::sleep(pause) => {}
        }
        pause = (pause * 2).min(Duration::from_secs(5));
    }
}
