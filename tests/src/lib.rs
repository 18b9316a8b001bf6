//! The end-to-end test harness of cangate: what the tests in `tests/tests/`
//! share to run the real server in-process and drive it with the real
//! client.
//!
//! - this module: a server on `127.0.0.1:0` with virtual buses
//!   ([`start_server`], [`ONE_BUS`]), a connected [`client`], frame streams
//!   read with timeouts ([`open_stream`], [`read_frames`], [`assert_quiet`])
//!   and the CANopen calls most tests make on `can0` ([`node_events`],
//!   [`send_nmt`], [`get_node`]);
//! - [`axes`]: commands under a control lease, waiting for an axis status,
//!   a simulated drive the test runs itself (to fault it or switch it off);
//! - [`log`]: the process's log captured, for tests of what is logged.
//!
//! Every helper panics with a message on failure (these are tests), and
//! every wait is bounded by [`WAIT`], so that a broken build fails instead
//! of hanging. A test file uses it as `use cangate_tests::*;`. Running
//! against a real SocketCAN `vcan0` is `tests/tests/common/vcan.rs`,
//! included by path by the tests that need it.

#![deny(missing_docs, unreachable_pub)]
// A dependency nothing uses fails CI (clippy -D warnings). Test builds are
// left out: their dev-dependencies serve the integration tests.
#![cfg_attr(not(test), warn(unused_crate_dependencies))]

pub mod axes;
pub mod log;
pub mod streams;

use cangate_client::pb;
use cangate_client::pb::stream_event::Event;
use cangate_server::{Config, RunningServer};
use std::time::Duration;

/// Every wait in these tests is bounded by this, so a broken build fails
/// instead of hanging.
pub const WAIT: Duration = Duration::from_secs(10);

/// A server on an ephemeral port with the given `[[bus]]` sections.
pub async fn start_server(buses_toml: &str) -> RunningServer {
    let text = format!("listen = \"127.0.0.1:0\"\n{buses_toml}");
    let config = Config::from_toml(&text).expect("test configuration is valid");
    cangate_server::start(&config).await.expect("server starts")
}

/// One fast virtual bus `can0` (FD, no bit timing).
pub const ONE_BUS: &str =
    "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\nfd = true\nbitrate = 1000000\n";

/// A client connected to the server.
pub async fn client(server: &RunningServer) -> cangate_client::Client {
    cangate_client::connect(&format!("http://{}", server.addr))
        .await
        .expect("client connects")
}

/// A stream request for `bus` with filters.
pub fn stream_request(bus: &str, filters: Vec<pb::FrameFilter>) -> pb::StreamFramesRequest {
    pb::StreamFramesRequest {
        bus: bus.to_string(),
        filters,
        include_transmitted: false,
        include_error_frames: false,
        max_batch: 0,
        queue_length: 0,
        low_latency: false,
    }
}

/// A filter passing exactly the standard (11-bit) identifier `id`.
pub fn standard_id(id: u32) -> pb::FrameFilter {
    pb::FrameFilter {
        id,
        mask: 0x7FF,
        format: pb::IdFormat::Standard as i32,
        invert: false,
    }
}

/// A stream request for the frames on standard identifier `id` of `bus`,
/// the gateway's own included (its requests to a node, say).
pub fn frames_on(bus: &str, id: u32) -> pb::StreamFramesRequest {
    let mut r = stream_request(bus, vec![standard_id(id)]);
    r.include_transmitted = true;
    r
}

/// Opens a stream and consumes the initial state event, so that the
/// subscription is known to be in place before the test sends anything.
pub async fn open_stream(
    client: &mut cangate_client::Client,
    req: pb::StreamFramesRequest,
) -> (
    tonic::Streaming<pb::StreamFramesResponse>,
    Vec<pb::StreamEvent>,
) {
    let mut s = client.stream_frames(req).await.expect("stream opens");
    let first = tokio::time::timeout(WAIT, s.message())
        .await
        .expect("initial state in time")
        .expect("stream ok")
        .expect("stream not ended");
    assert!(
        matches!(
            first.events.first().and_then(|e| e.event.as_ref()),
            Some(Event::State(_))
        ),
        "a stream starts with the bus state"
    );
    let rest = first.events[1..].to_vec();
    (s, rest)
}

/// Reads events until `n` frames arrived (other events are returned too).
pub async fn read_frames(
    stream: &mut tonic::Streaming<pb::StreamFramesResponse>,
    pending: &mut Vec<pb::StreamEvent>,
    n: usize,
) -> Vec<pb::Frame> {
    let mut frames = Vec::new();
    loop {
        for ev in pending.drain(..) {
            if let Some(Event::Frame(f)) = ev.event {
                frames.push(f);
            }
        }
        if frames.len() >= n {
            return frames;
        }
        let msg = tokio::time::timeout(WAIT, stream.message())
            .await
            .unwrap_or_else(|_| panic!("only {} of {n} frames arrived in time", frames.len()))
            .expect("stream ok")
            .expect("stream not ended");
        pending.extend(msg.events);
    }
}

/// Asserts that nothing more arrives within a short while.
pub async fn assert_quiet(stream: &mut tonic::Streaming<pb::StreamFramesResponse>) {
    if let Ok(msg) = tokio::time::timeout(Duration::from_millis(200), stream.message()).await {
        panic!("unexpected stream message: {msg:?}");
    }
}

/// Node events of `can0` for these nodes.
pub async fn node_events(
    c: &cangate_client::Client,
    nodes: Vec<u32>,
) -> tonic::Streaming<pb::NodeEvent> {
    c.canopen_client()
        .stream_node_events(pb::StreamNodeEventsRequest {
            bus: "can0".into(),
            nodes,
        })
        .await
        .expect("node event stream opens")
        .into_inner()
}

/// Sends an NMT command on `can0` (node 0: all).
pub async fn send_nmt(c: &cangate_client::Client, node: u32, command: pb::NmtCommand) {
    c.canopen_client()
        .send_nmt(pb::SendNmtRequest {
            bus: "can0".into(),
            node,
            command: command as i32,
            force: false,
        })
        .await
        .expect("NMT command accepted");
}

/// A node of `can0` as the master sees it.
pub async fn get_node(c: &cangate_client::Client, node: u32) -> pb::Node {
    c.canopen_client()
        .get_node(pb::GetNodeRequest {
            bus: "can0".into(),
            node,
        })
        .await
        .expect("GetNode")
        .into_inner()
}

/// The answer (status line, headers, body) of a plain HTTP GET of `path`
/// from `addr` (the metrics endpoint).
pub async fn http_get(addr: std::net::SocketAddr, path: &str) -> String {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    s.write_all(format!("GET {path} HTTP/1.1\r\nHost: x\r\n\r\n").as_bytes())
        .await
        .unwrap();
    let mut out = String::new();
    tokio::time::timeout(WAIT, s.read_to_string(&mut out))
        .await
        .expect("answer in time")
        .unwrap();
    out
}

/// The gateway's Prometheus metrics text (`metrics_listen` at `addr`).
pub async fn scrape_metrics(addr: std::net::SocketAddr) -> String {
    http_get(addr, "/metrics").await
}
