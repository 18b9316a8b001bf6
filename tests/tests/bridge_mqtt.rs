//! The plant bridge against a real MQTT broker (mosquitto): each test
//! starts its own broker on a free loopback port and stops it by its PID.
//! Outside CI a missing `mosquitto` (or `mosquitto_sub`) skips the test,
//! saying why; under `CI` it fails.
//!
//! - every message of a stream arrives in order with consecutive sequence
//!   numbers, in protobuf (a Rust subscriber) and in JSON (`mosquitto_sub`);
//! - the broker stopped mid-stream and started again: the consumer sees
//!   every sequence number or a gap record covering exactly the missing
//!   ones;
//! - the gateway killed with SIGKILL: the last will marks it offline; the
//!   next run has a new epoch and numbers from 1;
//! - the node events and the handwheel feed through the bridge equal the
//!   gRPC streams';
//! - a Python consumer (paho-mqtt, `CANGATE_PYTHON` or `python3`) reads
//!   the JSON tree in order;
//! - two gateways into one broker: `cangate fleet` lists both, one
//!   consumer sees both machines' axes.
//!
//! Every wait is for an event, bounded by a generous deadline.

#[path = "common/broker.rs"]
mod broker;
#[path = "common/python_peer.rs"]
mod python_peer;
#[path = "common/vcan.rs"]
mod vcan;

use broker::{BrokerProcess, bridge_config, start_gateway};
use cangate_client::pb;
use cangate_tests::*;
use prost::Message;
use rumqttc::{AsyncClient, Event, Incoming, MqttOptions, QoS};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;
use tokio::sync::mpsc;

/// Deadline of every wait here (a busy 2-core machine builds beside us).
const DEADLINE: Duration = Duration::from_secs(60);

/// The broker binary: on PATH, or where Debian puts it.
fn mosquitto() -> Option<PathBuf> {
    for dir in std::env::var("PATH")
        .unwrap_or_default()
        .split(':')
        .chain(["/usr/sbin", "/usr/local/sbin"])
    {
        let p = Path::new(dir).join("mosquitto");
        if p.is_file() {
            return Some(p);
        }
    }
    None
}

fn missing() -> Option<String> {
    if mosquitto().is_none() {
        return Some("mosquitto not found (apt-get install mosquitto)".into());
    }
    if Command::new("mosquitto_sub")
        .arg("--help")
        .output()
        .is_err()
    {
        return Some("mosquitto_sub not found (apt-get install mosquitto-clients)".into());
    }
    None
}

/// Skips (outside CI) or fails (under CI) when a broker tool is missing.
fn can_run(test: &str) -> bool {
    match missing() {
        None => true,
        Some(why) if std::env::var_os("CI").is_some() => panic!("{test}: {why}"),
        Some(why) => {
            eprintln!("skipping {test}: {why}");
            false
        }
    }
}

/// A mosquitto broker of this test, with persistence (so a consumer's
/// session and its queued messages survive a restart).
/// A mosquitto of the test's own.
struct Broker(BrokerProcess);

impl std::ops::Deref for Broker {
    type Target = BrokerProcess;
    fn deref(&self) -> &BrokerProcess {
        &self.0
    }
}

impl std::ops::DerefMut for Broker {
    fn deref_mut(&mut self) -> &mut BrokerProcess {
        &mut self.0
    }
}

impl Broker {
    fn start(name: &str) -> Broker {
        let p = BrokerProcess::prepare("bridge", name);
        std::fs::write(
            p.dir.join("mosquitto.conf"),
            format!(
                "listener {} 127.0.0.1\nallow_anonymous true\npersistence true\n\
                 persistence_location {}/\nmax_queued_messages 100000\n",
                p.port,
                p.dir.display()
            ),
        )
        .unwrap();
        let mut b = Broker(p);
        b.run();
        b
    }

    fn run(&mut self) {
        let mut command = Command::new(mosquitto().unwrap());
        command
            .arg("-c")
            .arg(self.dir.join("mosquitto.conf"))
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        self.0.run(command, DEADLINE, || "mosquitto".into());
    }

    /// Stops the broker (SIGTERM by PID: it saves its sessions) and waits
    /// for it to exit.
    fn stop(&mut self) {
        self.signal("-TERM");
    }

    fn url(&self) -> String {
        format!("mqtt://127.0.0.1:{}", self.port)
    }
}

/// A message a subscriber received: topic and envelope.
type Received = (String, pb::BridgeEnvelope);

/// A protobuf consumer: a persistent session (QoS 1) on `filter`, so that
/// it misses nothing the broker accepted, even across a broker restart.
fn subscribe(port: u16, id: &str, filter: &str) -> mpsc::UnboundedReceiver<Received> {
    let mut options = MqttOptions::new(id, "127.0.0.1", port);
    options
        .set_clean_session(false)
        .set_keep_alive(Duration::from_secs(5))
        .set_max_packet_size(1 << 20, 1 << 20);
    let (client, mut events) = AsyncClient::new(options, 100);
    let (tx, rx) = mpsc::unbounded_channel();
    let filter = filter.to_string();
    tokio::spawn(async move {
        loop {
            match events.poll().await {
                Ok(Event::Incoming(Incoming::ConnAck(ack))) => {
                    if !ack.session_present {
                        client.subscribe(&filter, QoS::AtLeastOnce).await.unwrap();
                    }
                }
                Ok(Event::Incoming(Incoming::Publish(p))) => {
                    let env = pb::BridgeEnvelope::decode(p.payload.as_ref())
                        .expect("a pb topic carries a BridgeEnvelope");
                    if tx.send((p.topic.clone(), env)).is_err() {
                        return;
                    }
                }
                Ok(_) => {}
                Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
            }
        }
    });
    rx
}

/// The next message of the gateway (the subscription probes left out).
async fn next(rx: &mut mpsc::UnboundedReceiver<Received>) -> Received {
    loop {
        let (topic, env) = tokio::time::timeout(DEADLINE, rx.recv())
            .await
            .expect("a message in time")
            .expect("the subscriber runs");
        if env.stream != "probe" {
            return (topic, env);
        }
    }
}

/// The sequence numbers of `stream` received, and its gap records' ranges.
#[derive(Default)]
struct Ledger {
    seqs: Vec<u64>,
    gaps: Vec<(u64, u64)>,
}

impl Ledger {
    fn take(&mut self, stream: &str, env: &pb::BridgeEnvelope) {
        match &env.payload {
            Some(pb::bridge_envelope::Payload::Gap(g)) if g.stream == stream => {
                assert_eq!(g.count, g.last_seq - g.first_seq + 1);
                self.gaps.push((g.first_seq, g.last_seq));
            }
            _ if env.stream == stream => self.seqs.push(env.seq),
            _ => {}
        }
    }

    /// Every number up to `last` received or in a gap, and none both.
    fn check_complete(&self, last: u64) {
        let got: BTreeSet<u64> = self.seqs.iter().copied().collect();
        let mut gapped = BTreeSet::new();
        for &(a, b) in &self.gaps {
            for s in a..=b {
                assert!(gapped.insert(s), "seq {s} in two gap records");
                assert!(!got.contains(&s), "seq {s} received and in a gap");
            }
        }
        for s in 1..=last {
            assert!(
                got.contains(&s) || gapped.contains(&s),
                "seq {s} neither received nor in a gap (gaps {:?})",
                self.gaps
            );
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stream_messages_arrive_in_order_in_pb_and_json() {
    if !can_run("stream_messages_arrive_in_order_in_pb_and_json") {
        return;
    }
    let broker = Broker::start("order");
    let mut pb_rx = subscribe(broker.port, "order-pb", "cangate/v1/pb/m1/#");
    // The JSON consumer: mosquitto_sub, the first 20 statistics messages.
    let json = Command::new("mosquitto_sub")
        .args(["-h", "127.0.0.1", "-p", &broker.port.to_string()])
        .args([
            "-t",
            "cangate/v1/json/m1/bus/can0/stats",
            "-q",
            "1",
            "-C",
            "20",
        ])
        .stdout(Stdio::piped())
        .spawn()
        .expect("mosquitto_sub starts");
    // The subscriptions are in place before the gateway starts: the broker
    // has answered the Rust consumer's connection (its first poll) once a
    // retained-less topic is subscribed; wait for both by a probe message.
    let probe = wait_subscribed(broker.port, &mut pb_rx, "cangate/v1/pb/m1/probe").await;
    assert_eq!(probe, "cangate/v1/pb/m1/probe");

    let server = start_gateway(&bridge_config(
        &broker.url(),
        "m1",
        "streams = [\"bus_stats\", \"node_events\"]\nstats_interval_ms = 20",
    ))
    .await;

    let mut ledger = Ledger::default();
    let mut epoch = None;
    let mut status = None;
    while ledger.seqs.len() < 40 {
        let (topic, env) = next(&mut pb_rx).await;
        assert_eq!(env.gateway, "m1");
        assert_eq!(topic, format!("cangate/v1/pb/m1/{}", env.stream));
        if let Some(pb::bridge_envelope::Payload::Status(s)) = &env.payload {
            status = Some(s.clone());
            continue;
        }
        assert_eq!(*epoch.get_or_insert(env.epoch), env.epoch, "one epoch");
        ledger.take("bus/can0/stats", &env);
    }
    let status = status.expect("the retained status came first");
    assert!(status.online);
    assert_eq!(status.buses, ["can0"]);
    assert!(ledger.gaps.is_empty(), "{:?}", ledger.gaps);
    assert_eq!(
        ledger.seqs,
        (1..=40).collect::<Vec<_>>(),
        "in order, from 1"
    );

    let out = tokio::task::spawn_blocking(move || json.wait_with_output())
        .await
        .unwrap()
        .expect("mosquitto_sub ends after 20 messages");
    let text = String::from_utf8(out.stdout).unwrap();
    let seqs: Vec<u64> = text
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).expect("one JSON envelope a line");
            assert_eq!(v["gateway"], "m1");
            assert!(v["bus"]["statistics"].is_object(), "{l}");
            // proto3 JSON writes 64-bit integers as strings.
            v["seq"].as_str().unwrap().parse().unwrap()
        })
        .collect();
    // It subscribed at about the time the gateway started: from wherever
    // it came in, consecutive.
    assert_eq!(seqs.len(), 20);
    assert!(seqs.windows(2).all(|w| w[1] == w[0] + 1), "{seqs:?}");
    server.shutdown();
}

/// Publishes a probe on `topic` until the consumer `rx` receives it (its
/// subscription is then in place) and returns the topic.
async fn wait_subscribed(
    port: u16,
    rx: &mut mpsc::UnboundedReceiver<Received>,
    topic: &str,
) -> String {
    let mut options = MqttOptions::new(format!("probe-{port}"), "127.0.0.1", port);
    options.set_keep_alive(Duration::from_secs(5));
    let (client, mut events) = AsyncClient::new(options, 10);
    let poller = tokio::spawn(async move { while events.poll().await.is_ok() {} });
    let probe = pb::BridgeEnvelope {
        stream: "probe".into(),
        ..Default::default()
    };
    let found = tokio::time::timeout(DEADLINE, async {
        loop {
            client
                .publish(topic, QoS::AtLeastOnce, false, probe.encode_to_vec())
                .await
                .unwrap();
            if let Ok(Some((t, _))) =
                tokio::time::timeout(Duration::from_millis(500), rx.recv()).await
            {
                return t;
            }
        }
    })
    .await
    .expect("the consumer is subscribed in time");
    poller.abort();
    found
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_broker_restart_loses_nothing_without_a_gap_record() {
    if !can_run("a_broker_restart_loses_nothing_without_a_gap_record") {
        return;
    }
    let mut broker = Broker::start("restart");
    let mut rx = subscribe(broker.port, "restart-pb", "cangate/v1/pb/m2/#");
    wait_subscribed(broker.port, &mut rx, "cangate/v1/pb/m2/probe").await;
    // A small queue: while the broker is away it overflows.
    let server = start_gateway(&bridge_config(
        &broker.url(),
        "m2",
        "streams = [\"bus_stats\"]\nformats = [\"pb\"]\nstats_interval_ms = 10\nqueue_size = 5",
    ))
    .await;
    let stream = "bus/can0/stats";
    let mut ledger = Ledger::default();
    while ledger.seqs.len() < 10 {
        let (_, env) = next(&mut rx).await;
        ledger.take(stream, &env);
    }
    broker.stop();
    // Away until the queue has overflowed (a gap is recorded).
    let gaps = || {
        cangate_server::metrics::handle()
            .render()
            .lines()
            .filter(|l| {
                l.starts_with("cangate_bridge_gap_messages_total{") && l.contains("bridge=\"m2\"")
            })
            .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
            .sum::<f64>()
    };
    tokio::time::timeout(DEADLINE, async {
        while gaps() == 0.0 {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    })
    .await
    .expect("the queue overflows while the broker is away");
    broker.run();
    // Everything up to well after the restart, received or in a gap.
    let mut last = 0;
    while ledger.gaps.is_empty() || last < ledger.gaps.iter().map(|g| g.1).max().unwrap() + 20 {
        let (_, env) = next(&mut rx).await;
        ledger.take(stream, &env);
        if env.stream == stream {
            last = last.max(env.seq);
        }
    }
    ledger.check_complete(last);
    assert!(ledger.gaps.iter().all(|g| g.0 > 10), "{:?}", ledger.gaps);
    server.shutdown();
}

/// The environment variable that makes the child test run a gateway.
const CHILD_ENV: &str = "CANGATE_BRIDGE_CHILD_BROKER";
const CHILD_TEST: &str = "bridge_gateway_child";

/// Run by [`a_killed_gateway_is_offline_and_the_next_run_starts_a_new_epoch`]
/// as a separate process: a gateway bridged to the broker in
/// [`CHILD_ENV`], until it is killed.
#[test]
#[ignore = "run by a_killed_gateway_is_offline_and_the_next_run_starts_a_new_epoch"]
fn bridge_gateway_child() {
    let Ok(url) = std::env::var(CHILD_ENV) else {
        return;
    };
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let _server = start_gateway(&bridge_config(
            &url,
            "m3",
            "streams = [\"bus_stats\"]\nformats = [\"pb\"]\nstats_interval_ms = 50",
        ))
        .await;
        println!("STARTED");
        std::future::pending::<()>().await;
    });
}

struct ChildGuard(Child);

impl Drop for ChildGuard {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn gateway_process(url: &str) -> ChildGuard {
    ChildGuard(
        Command::new(std::env::current_exe().unwrap())
            .args(["--exact", CHILD_TEST, "--ignored", "--nocapture"])
            .env(CHILD_ENV, url)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("the gateway process starts"),
    )
}

/// The first statistics message of a run, and the statuses before it.
async fn first_stats(rx: &mut mpsc::UnboundedReceiver<Received>) -> pb::BridgeEnvelope {
    loop {
        let (_, env) = next(rx).await;
        if env.stream == "bus/can0/stats" {
            return env;
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_killed_gateway_is_offline_and_the_next_run_starts_a_new_epoch() {
    if !can_run("a_killed_gateway_is_offline_and_the_next_run_starts_a_new_epoch") {
        return;
    }
    let broker = Broker::start("will");
    let mut rx = subscribe(broker.port, "will-pb", "cangate/v1/pb/m3/#");
    wait_subscribed(broker.port, &mut rx, "cangate/v1/pb/m3/probe").await;

    let mut first = gateway_process(&broker.url());
    let one = first_stats(&mut rx).await;
    assert_eq!(one.seq, 1);
    // SIGKILL: no goodbye; the broker publishes the last will.
    let _ = Command::new("kill")
        .args(["-KILL", &first.0.id().to_string()])
        .status();
    let _ = first.0.wait();
    let offline = loop {
        let (topic, env) = next(&mut rx).await;
        if let Some(pb::bridge_envelope::Payload::Status(s)) = env.payload {
            assert_eq!(topic, "cangate/v1/pb/m3/status");
            if !s.online {
                break s;
            }
        }
    };
    assert_eq!(offline.gateway, "m3");
    assert_eq!(
        offline.started_ns, one.epoch,
        "the will names the run that died"
    );

    let _second = gateway_process(&broker.url());
    let (status, stats) = loop {
        let (_, env) = next(&mut rx).await;
        if let Some(pb::bridge_envelope::Payload::Status(s)) = &env.payload
            && s.online
        {
            break (s.clone(), first_stats(&mut rx).await);
        }
    };
    assert_ne!(status.started_ns, one.epoch, "a new epoch");
    assert_eq!(stats.epoch, status.started_ns);
    assert_eq!(stats.seq, 1, "numbers start again from 1");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn node_events_through_the_bridge_equal_the_grpc_stream() {
    if !can_run("node_events_through_the_bridge_equal_the_grpc_stream") {
        return;
    }
    let broker = Broker::start("events");
    let mut rx = subscribe(
        broker.port,
        "events-pb",
        "cangate/v1/pb/m4/bus/can0/node/5/event",
    );
    wait_subscribed(
        broker.port,
        &mut rx,
        "cangate/v1/pb/m4/bus/can0/node/5/event",
    )
    .await;
    let server = start_gateway(&bridge_config(
        &broker.url(),
        "m4",
        "streams = [\"node_events\"]\nformats = [\"pb\"]",
    ))
    .await;
    let c = client(&server).await;
    let mut grpc = node_events(&c, vec![5]).await;
    // A reset: the node goes through its boot again (state changes and a
    // boot-up), seen by both.
    send_nmt(&c, 5, pb::NmtCommand::ResetNode).await;
    // Up to its boot-up.
    let mut from_grpc = Vec::new();
    while !(from_grpc.last())
        .is_some_and(|e: &pb::NodeEvent| matches!(e.event, Some(pb::node_event::Event::BootUp(_))))
    {
        let ev = tokio::time::timeout(DEADLINE, grpc.message())
            .await
            .expect("a node event in time")
            .unwrap()
            .expect("the stream goes on");
        from_grpc.push(ev);
    }
    let t0 = from_grpc[0].timestamp_ns;
    let mut from_bridge = Vec::new();
    let mut seqs = Vec::new();
    while from_bridge.len() < from_grpc.len() {
        let (_, env) = next(&mut rx).await;
        let Some(pb::bridge_envelope::Payload::NodeEvent(ev)) = env.payload else {
            continue;
        };
        seqs.push(env.seq);
        if ev.timestamp_ns >= t0 {
            from_bridge.push(ev);
        }
    }
    assert_eq!(from_bridge, from_grpc);
    assert_eq!(
        seqs,
        (1..=seqs.len() as u64).collect::<Vec<_>>(),
        "consecutive from 1"
    );
    server.shutdown();
}

/// A simulated handwheel (node 10) and a drive as axis X (node 1).
const WHEEL_AND_AXIS: &str = r#"
[[canopen.node]]
id = 10
eds = "builtin:handwheel"
simulate = true

[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true

[[handwheel]]
name = "hw1"
bus = "can0"
node = 10
counter = "nibble"

[[axis]]
name = "X"
bus = "can0"
node = 1
counts_per_unit = 1000.0
max_velocity = 100.0
max_acceleration = 1000.0
"#;

/// `config` with the wheel and the axis (their sections after the bridge's
/// own keys would belong to it, so they go before).
fn config_with_wheel(url: &str, gateway: &str, extra: &str) -> String {
    let base = bridge_config(url, gateway, extra);
    let (head, bridge) = base.split_once("[[bridge]]").unwrap();
    format!("{head}{WHEEL_AND_AXIS}\n[[bridge]]{bridge}")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_handwheel_feed_through_the_bridge_equals_the_grpc_stream() {
    if !can_run("the_handwheel_feed_through_the_bridge_equals_the_grpc_stream") {
        return;
    }
    let broker = Broker::start("feed");
    let mut rx = subscribe(
        broker.port,
        "feed-pb",
        "cangate/v1/pb/m5/handwheel/hw1/feed",
    );
    wait_subscribed(broker.port, &mut rx, "cangate/v1/pb/m5/handwheel/hw1/feed").await;
    let server = start_gateway(&config_with_wheel(
        &broker.url(),
        "m5",
        "streams = [\"handwheel_feed\"]\nformats = [\"pb\"]",
    ))
    .await;
    let c = client(&server).await;
    let mut wheels = pb::handwheels_client::HandwheelsClient::new(c.channel());
    // A wheel feeds in manual mode only.
    wheels
        .set_mode(pb::SetModeRequest {
            handwheel: "hw1".into(),
            mode: pb::HandwheelMode::Manual as i32,
        })
        .await
        .unwrap();
    let mut grpc = wheels
        .stream_feed(pb::StreamFeedRequest {
            handwheels: vec!["hw1".into()],
            coalesce_ms: 0,
        })
        .await
        .unwrap()
        .into_inner();
    pb::simulator_client::SimulatorClient::new(c.channel())
        .turn_handwheel(pb::TurnHandwheelRequest {
            handwheel: "hw1".into(),
            detents: 40,
            axis: pb::WheelAxis::X as i32,
            multiplier: 1,
            loss: 0.0,
            max_consecutive_loss: 0,
        })
        .await
        .unwrap();
    let units = |evs: &[pb::FeedEvent]| evs.iter().map(|e| e.units).sum::<u32>();
    let mut from_grpc = Vec::new();
    while units(&from_grpc) < 40 {
        let ev = tokio::time::timeout(DEADLINE, grpc.message())
            .await
            .expect("a feed event in time")
            .unwrap()
            .expect("the stream goes on");
        from_grpc.push(ev);
    }
    let mut from_bridge = Vec::new();
    let mut seqs = Vec::new();
    while from_bridge.len() < from_grpc.len() {
        let (_, env) = next(&mut rx).await;
        let Some(pb::bridge_envelope::Payload::Feed(ev)) = env.payload else {
            continue;
        };
        seqs.push(env.seq);
        if ev.timestamp_us >= from_grpc[0].timestamp_us {
            from_bridge.push(ev);
        }
    }
    assert_eq!(from_bridge, from_grpc);
    assert_eq!(seqs, (1..=seqs.len() as u64).collect::<Vec<_>>());
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_gateways_are_listed_by_fleet_and_seen_by_one_consumer() {
    if !can_run("two_gateways_are_listed_by_fleet_and_seen_by_one_consumer") {
        return;
    }
    let broker = Broker::start("fleet");
    let extra = "streams = [\"axis_state\"]\naxis_state_interval_ms = 50";
    let g1 = start_gateway(&config_with_wheel(&broker.url(), "g1", extra)).await;
    let g2 = start_gateway(&config_with_wheel(&broker.url(), "g2", extra)).await;
    // The retained state of each gateway's axis X, in JSON: mosquitto_sub
    // gets the retained messages of both at once (waiting, by the
    // protobuf tree, until both are there first).
    let mut rx = subscribe(broker.port, "fleet-pb", "cangate/v1/pb/+/axis/+/state");
    let mut seen = BTreeSet::new();
    while seen.len() < 2 {
        let (topic, env) = next(&mut rx).await;
        if let Some(pb::bridge_envelope::Payload::AxisStatus(s)) = &env.payload {
            assert_eq!(topic, format!("cangate/v1/pb/{}/axis/X/state", env.gateway));
            assert_eq!(s.axis, "X");
            seen.insert(env.gateway.clone());
        }
    }
    let out = Command::new("mosquitto_sub")
        .args(["-h", "127.0.0.1", "-p", &broker.port.to_string()])
        .args(["-t", "cangate/v1/json/+/axis/+/state", "-C", "2", "-v"])
        .output()
        .expect("mosquitto_sub runs");
    let text = String::from_utf8(out.stdout).unwrap();
    let gateways: BTreeSet<String> = text
        .lines()
        .map(|l| {
            let (topic, json) = l.split_once(' ').unwrap();
            let v: serde_json::Value = serde_json::from_str(json).unwrap();
            assert_eq!(v["axisStatus"]["axis"], "X", "{l}");
            assert!(topic.ends_with("/axis/X/state"), "{topic}");
            v["gateway"].as_str().unwrap().to_string()
        })
        .collect();
    assert_eq!(
        gateways,
        BTreeSet::from(["g1".to_string(), "g2".to_string()])
    );
    g1.shutdown();
    g2.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_python_consumer_reads_the_json_tree_in_order() {
    let test = "a_python_consumer_reads_the_json_tree_in_order";
    if !can_run(test) {
        return;
    }
    let Some(python) = python_peer::python_or_skip(test, &["paho.mqtt"]) else {
        return;
    };
    let broker = Broker::start("python");
    let port = broker.port.to_string();
    let script = python_peer::script("mqtt_consumer.py");
    let topic = "cangate/v1/json/m6/bus/can0/stats";
    let mut consumer =
        python_peer::Peer::spawn(&python, &script, &["127.0.0.1", &port, topic, "25"], &[])
            .expect("python starts");
    consumer
        .expect_line("READY", DEADLINE)
        .await
        .expect("the consumer subscribed");
    let server = start_gateway(&bridge_config(
        &broker.url(),
        "m6",
        "streams = [\"bus_stats\"]\nformats = [\"json\"]\nstats_interval_ms = 20",
    ))
    .await;
    let lines = consumer
        .lines_until("DONE", DEADLINE)
        .await
        .expect("25 envelopes");
    let seqs: Vec<u64> = lines
        .iter()
        .map(|l| {
            let rest = l.strip_prefix("SEQ bus/can0/stats ").expect(l);
            rest.parse().unwrap()
        })
        .collect();
    assert_eq!(seqs, (1..=25).collect::<Vec<_>>());
    server.shutdown();
}

/// A measurement, not a check: frames a second carried bus → bridge →
/// mosquitto → subscriber (protobuf, batched at QoS 0), and whether any
/// were lost. `cargo test -p cangate-tests --test bridge_mqtt
/// measure_frames -- --ignored --nocapture`
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "a measurement; run by hand with --ignored --nocapture"]
async fn measure_frames_through_the_bridge() {
    if !can_run("measure_frames_through_the_bridge") {
        return;
    }
    const FRAMES: usize = 200_000;
    const BATCH: usize = 500;
    let broker = Broker::start("measure");
    let mut rx = subscribe(
        broker.port,
        "measure-pb",
        "cangate/v1/pb/m7/bus/can0/frames",
    );
    wait_subscribed(broker.port, &mut rx, "cangate/v1/pb/m7/bus/can0/frames").await;
    let server = start_gateway(&format!(
        "[security.limits]\nraw_frames_per_second_per_client = 10000000\nraw_frame_burst = 1000000\n{}",
        bridge_config(
            &broker.url(),
            "m7",
            "streams = [\"frames\"]\nformats = [\"pb\"]\nframe_rate_limit = 0\nqueue_size = 100000",
        )
    ))
    .await;
    let c = client(&server).await;
    let t0 = std::time::Instant::now();
    let sender = tokio::spawn(async move {
        let mut bus = c.bus_client();
        for b in 0..FRAMES / BATCH {
            let frames = (0..BATCH)
                .map(|i| pb::Frame {
                    id: 0x100 + ((b * BATCH + i) % 0x400) as u32,
                    data: ((b * BATCH + i) as u64).to_le_bytes().to_vec(),
                    ..Default::default()
                })
                .collect();
            bus.send_frames(pb::SendFramesRequest {
                bus: "can0".into(),
                frames,
            })
            .await
            .expect("frames sent");
        }
    });
    let (mut frames, mut lost, mut messages, mut gaps) = (0u64, 0u64, 0u64, 0u64);
    let mut seqs = Vec::new();
    while frames + lost < FRAMES as u64 {
        let (_, env) = match tokio::time::timeout(Duration::from_secs(10), rx.recv()).await {
            Ok(Some(m)) => m,
            _ => break,
        };
        match env.payload {
            Some(pb::bridge_envelope::Payload::Frames(b)) => {
                messages += 1;
                seqs.push(env.seq);
                for e in b.events {
                    match e.event {
                        Some(pb::stream_event::Event::Frame(_)) => frames += 1,
                        Some(pb::stream_event::Event::Lost(l)) => lost += l.count,
                        _ => {}
                    }
                }
            }
            Some(pb::bridge_envelope::Payload::Gap(g)) => gaps += g.count,
            _ => {}
        }
    }
    let secs = t0.elapsed().as_secs_f64();
    sender.await.unwrap();
    let missing_seqs = seqs.windows(2).filter(|w| w[1] != w[0] + 1).count();
    println!(
        "MEASURED {frames} frames in {messages} batches in {secs:.2} s: {:.0} frames/s, \
         {lost} lost at the source, {gaps} batches in gap records, {missing_seqs} holes in seq",
        frames as f64 / secs
    );
    server.shutdown();
}
