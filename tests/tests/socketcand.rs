//! The socketcand endpoint with independent clients: the real server
//! in-process (the demo configuration, `[socketcand]` on `127.0.0.1:0`)
//! and python-can 4.6.1's `socketcand` interface and python `canopen`
//! (`tests/python/socketcand_peer.py`) as its clients:
//!
//! - python-can sends (standard, extended, empty frames): a gRPC stream
//!   sees them as client frames, named `… via socketcand`;
//! - python-can receives frames a gRPC client sends, through python-can's
//!   filters (python-can filters in software: the socketcand protocol has
//!   no filter command in raw mode), and the demo bus's own traffic;
//! - python `canopen` SDO uploads and downloads, expedited and segmented,
//!   and an abort, against the demo's simulated I/O module (node 3);
//! - tokens and roles: no token and an unknown token are refused at open,
//!   a viewer's send is refused (python-can raises the `< error … >` line)
//!   and never reaches the bus, an engineer's goes through;
//! - malformed input from a plain TCP client, answered line by line.
//!
//! The python interpreter is `CANGATE_PYTHON` (the venv `scripts/test`
//! builds in `target/python`), else `python3`. Without python-can and
//! canopen the python tests are skipped, except under `CI=true`, where
//! they fail instead.

#[path = "common/python_peer.rs"]
mod python_peer;
#[path = "common/vcan.rs"]
mod vcan;

use cangate_client::pb;
use cangate_server::{Config, RunningServer};
use cangate_tests::*;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// Starting python and importing python-can/canopen takes a second or two;
/// a loaded CI runner more.
const PY_WAIT: Duration = Duration::from_secs(60);

/// The python interpreter with python-can and canopen, or `None` after
/// reporting the skip (a failure under CI).
fn python(test: &str) -> Option<PathBuf> {
    python_peer::python_or_skip(test, &["can", "canopen"])
}

/// A running `socketcand_peer.py`: its stdout lines, its stdin.
struct Peer(python_peer::Peer);

impl Peer {
    fn start(python: &Path, addr: SocketAddr, channel: &str, mode: &str, rest: &[&str]) -> Peer {
        let (ip, port) = (addr.ip().to_string(), addr.port().to_string());
        let mut args = vec![ip.as_str(), port.as_str(), channel, mode];
        args.extend_from_slice(rest);
        let script = python_peer::script("socketcand_peer.py");
        Peer(python_peer::Peer::spawn(python, &script, &args, &[]).expect("python starts"))
    }

    /// The next line, bounded.
    async fn line(&mut self) -> String {
        self.0
            .next_line(PY_WAIT)
            .await
            .expect("a line from the peer")
    }

    /// Lines up to (without) `DONE`, which must come.
    async fn rest(&mut self) -> Vec<String> {
        self.0
            .lines_until("DONE", PY_WAIT)
            .await
            .expect("the peer's lines up to DONE")
    }

    fn say(&mut self, line: &str) {
        self.0.say(line).expect("write to the peer");
    }
}

/// The demo configuration with the socketcand endpoint on a free port.
async fn demo_server() -> RunningServer {
    let mut c = Config::demo();
    c.listen = "127.0.0.1:0".parse().unwrap();
    c.socketcand = Some(cangate_server::config::SocketcandConfig::new(
        "127.0.0.1:0".parse().unwrap(),
    ));
    cangate_server::start(&c).await.expect("server starts")
}

const VIEWER: &str = "viewer-secret";
const ENGINEER: &str = "engineer-secret";

/// One fast bus, tokens for a viewer and an engineer.
async fn token_server() -> RunningServer {
    use cangate_server::security::auth::hash_token;
    let text = format!(
        "listen = \"127.0.0.1:0\"\n{ONE_BUS}\
         [socketcand]\nlisten = \"127.0.0.1:0\"\n\
         [[security.tokens]]\nname = \"viewer-1\"\nrole = \"viewer\"\nsha256 = \"{}\"\n\
         [[security.tokens]]\nname = \"eng-1\"\nrole = \"engineer\"\nsha256 = \"{}\"\n",
        hash_token(VIEWER),
        hash_token(ENGINEER)
    );
    let c = Config::from_toml(&text).expect("valid");
    cangate_server::start(&c).await.expect("server starts")
}

fn exact(id: u32, extended: bool) -> pb::FrameFilter {
    pb::FrameFilter {
        id,
        mask: if extended { 0x1FFF_FFFF } else { 0x7FF },
        format: if extended {
            pb::IdFormat::Extended as i32
        } else {
            pb::IdFormat::Standard as i32
        },
        invert: false,
    }
}

fn data_frame(id: u32, extended: bool, data: &[u8]) -> pb::Frame {
    pb::Frame {
        id,
        extended,
        data: data.to_vec(),
        ..Default::default()
    }
}

async fn client_with(server: &RunningServer, token: &str) -> cangate_client::Client {
    cangate_client::connect_with(
        &format!("http://{}", server.addr),
        &cangate_client::ConnectOptions {
            token: Some(token.to_string()),
            ..Default::default()
        },
    )
    .await
    .expect("client connects")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn python_can_sends_and_grpc_streams_see_a_marked_client() {
    let Some(py) = python("python_can_sends_and_grpc_streams_see_a_marked_client") else {
        return;
    };
    let server = demo_server().await;
    let addr = server.socketcand_addr.expect("socketcand listens");
    let mut c = client(&server).await;
    let (mut stream, mut pending) = open_stream(
        &mut c,
        stream_request(
            "can0",
            vec![
                exact(0x123, false),
                exact(0x1ABC_DEF0, true),
                exact(0x7FF, false),
            ],
        ),
    )
    .await;
    let mut peer = Peer::start(&py, addr, "can0", "send", &[]);
    assert_eq!(peer.line().await, "OPEN");
    assert_eq!(peer.line().await, "SENT 3");
    let frames = read_frames(&mut stream, &mut pending, 3).await;
    let got: Vec<(u32, bool, Vec<u8>)> = frames
        .iter()
        .map(|f| (f.id, f.extended, f.data.clone()))
        .collect();
    assert_eq!(
        got,
        [
            (0x123, false, vec![1, 2, 3]),
            (0x1ABC_DEF0, true, vec![0xDE, 0xAD]),
            (0x7FF, false, vec![]),
        ]
    );
    for f in &frames {
        assert_eq!(f.origin, pb::FrameOrigin::Client as i32, "{f:?}");
        let sender = f.sender.as_ref().expect("a client frame names its sender");
        assert!(sender.id > 0);
        assert!(
            sender.client.ends_with(" via socketcand") && sender.client.starts_with("127.0.0.1:"),
            "{sender:?}"
        );
    }
    // One connection is one sender.
    assert!(frames.windows(2).all(|w| w[0].sender == w[1].sender));
    peer.say("seen");
    assert!(peer.rest().await.is_empty());
    server.shutdown();
    server.wait(WAIT).await.expect("clean shutdown");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn python_can_receives_grpc_frames_through_its_filters() {
    let Some(py) = python("python_can_receives_grpc_frames_through_its_filters") else {
        return;
    };
    let server = demo_server().await;
    let addr = server.socketcand_addr.expect("socketcand listens");
    let c = client(&server).await;
    let mut peer = Peer::start(&py, addr, "can0", "receive", &[]);
    assert_eq!(peer.line().await, "READY");
    let sent_after = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64();
    c.bus_client()
        .send_frames(pb::SendFramesRequest {
            bus: "can0".into(),
            frames: vec![
                data_frame(0x322, false, &[0]),
                data_frame(0x321, false, &[1]),
                data_frame(0x1BAD_CAFE, true, &[2, 2]),
                data_frame(0x1BAD_CAFF, true, &[0]),
                data_frame(0x321, false, &[]),
            ],
        })
        .await
        .expect("frames sent");
    let rx = peer.rest().await;
    let fields: Vec<Vec<&str>> = rx.iter().map(|l| l.split(' ').collect()).collect();
    let summary: Vec<String> = fields.iter().map(|f| f[..4].join(" ")).collect();
    assert_eq!(
        summary,
        ["RX 321 std 01", "RX 1BADCAFE ext 0202", "RX 321 std -"],
        "only the filtered frames, in order, the demo bus's own traffic left out"
    );
    // Timestamps: the gateway's wall-clock receive time, secs.usecs.
    for f in &fields {
        let ts: f64 = f[4].parse().expect("a timestamp");
        assert!((ts - sent_after).abs() < 30.0, "{ts} vs {sent_after}");
    }
    server.shutdown();
    server.wait(WAIT).await.expect("clean shutdown");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn python_can_sees_the_demo_bus_traffic() {
    let Some(py) = python("python_can_sees_the_demo_bus_traffic") else {
        return;
    };
    let server = demo_server().await;
    let addr = server.socketcand_addr.expect("socketcand listens");
    let mut peer = Peer::start(&py, addr, "can0", "unfiltered", &[]);
    let ids = peer.line().await;
    assert!(ids.starts_with("IDS "), "{ids}");
    // The master's SYNC (0x80) every 10 ms, and more.
    let ids: Vec<&str> = ids[4..].split(' ').collect();
    assert!(ids.contains(&"80"), "{ids:?}");
    assert!(ids.len() >= 3, "{ids:?}");
    assert!(peer.rest().await.is_empty());
    server.shutdown();
    server.wait(WAIT).await.expect("clean shutdown");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn python_canopen_sdo_over_socketcand_against_a_simulated_node() {
    let Some(py) = python("python_canopen_sdo_over_socketcand_against_a_simulated_node") else {
        return;
    };
    let server = demo_server().await;
    let addr = server.socketcand_addr.expect("socketcand listens");
    let c = client(&server).await;
    // Node 3 has booted and the master heard its heartbeat.
    let until = tokio::time::Instant::now() + WAIT;
    loop {
        let n = get_node(&c, 3).await;
        if n.heartbeat_age_ms.is_some()
            && ![
                pb::NmtState::Unknown as i32,
                pb::NmtState::Initialising as i32,
            ]
            .contains(&n.state)
        {
            break;
        }
        assert!(tokio::time::Instant::now() < until, "node 3 booted: {n:?}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let mut peer = Peer::start(&py, addr, "can0", "sdo", &["3"]);
    let lines = peer.rest().await;
    assert_eq!(
        lines,
        [
            "UPLOAD 1008 cangate_sim_io",
            "UPLOAD 1018.1 d2040000",
            "READBACK 6200.1 5a",
            "READBACK 6200.2 a5",
            "ABORT 06020000",
        ]
    );
    // The gateway's own master reads what python wrote.
    let read = c
        .canopen_client()
        .read_sdo(pb::ReadSdoRequest {
            bus: "can0".into(),
            node: 3,
            index: 0x6200,
            subindex: 2,
            ..Default::default()
        })
        .await
        .expect("ReadSdo")
        .into_inner();
    assert_eq!(read.raw, [0xA5]);
    server.shutdown();
    server.wait(WAIT).await.expect("clean shutdown");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tokens_and_roles_apply_to_socketcand_clients() {
    let Some(py) = python("tokens_and_roles_apply_to_socketcand_clients") else {
        return;
    };
    let server = token_server().await;
    let addr = server.socketcand_addr.expect("socketcand listens");
    // No token, an unknown token: refused at open.
    let mut peer = Peer::start(&py, addr, "can0", "refused_open", &[]);
    let l = peer.line().await;
    assert!(
        l.starts_with("REFUSED") && l.contains("missing token") && l.contains("open BUS TOKEN"),
        "{l}"
    );
    drop(peer);
    let mut peer = Peer::start(&py, addr, "can0 not-a-token", "refused_open", &[]);
    let l = peer.line().await;
    assert!(
        l.starts_with("REFUSED") && l.contains("unknown token"),
        "{l}"
    );
    drop(peer);
    // A viewer opens (receives) but cannot send.
    let mut c = client_with(&server, ENGINEER).await;
    let (mut stream, pending) =
        open_stream(&mut c, stream_request("can0", vec![exact(0x124, false)])).await;
    let mut peer = Peer::start(&py, addr, &format!("can0 {VIEWER}"), "refused_send", &[]);
    assert_eq!(peer.line().await, "OPEN");
    let l = peer.line().await;
    assert!(
        l.starts_with("REFUSED") && l.contains("send needs role engineer"),
        "{l}"
    );
    assert!(l.contains("viewer-1@127.0.0.1:"), "{l}");
    assert!(peer.rest().await.is_empty());
    assert!(pending.is_empty());
    assert_quiet(&mut stream).await;
    // An engineer's frames go through.
    let (mut stream, mut pending) = open_stream(
        &mut c,
        stream_request("can0", vec![exact(0x123, false), exact(0x7FF, false)]),
    )
    .await;
    let mut peer = Peer::start(&py, addr, &format!("can0 {ENGINEER}"), "send", &[]);
    assert_eq!(peer.line().await, "OPEN");
    assert_eq!(peer.line().await, "SENT 3");
    let frames = read_frames(&mut stream, &mut pending, 2).await;
    let sender = frames[0].sender.as_ref().expect("sender");
    assert!(
        sender.client.starts_with("eng-1@127.0.0.1:") && sender.client.ends_with("via socketcand"),
        "{sender:?}"
    );
    peer.say("seen");
    assert!(peer.rest().await.is_empty());
    server.shutdown();
    server.wait(WAIT).await.expect("clean shutdown");
}

/// A plain TCP client of the endpoint.
struct Raw {
    stream: tokio::net::TcpStream,
    buf: Vec<u8>,
}

impl Raw {
    async fn connect(addr: SocketAddr) -> Raw {
        let stream = tokio::net::TcpStream::connect(addr)
            .await
            .expect("connects");
        Raw {
            stream,
            buf: Vec::new(),
        }
    }

    async fn send(&mut self, bytes: &[u8]) {
        self.stream.write_all(bytes).await.expect("write");
    }

    /// The next `< … >` element within `d`, or None.
    async fn element_within(&mut self, d: Duration) -> Option<String> {
        tokio::time::timeout(d, self.element()).await.ok().flatten()
    }

    /// The next `< … >` element, or None when the server closed.
    async fn element(&mut self) -> Option<String> {
        loop {
            if let Some(end) = self.buf.iter().position(|&b| b == b'>') {
                let e: Vec<u8> = self.buf.drain(..=end).collect();
                return Some(String::from_utf8(e).expect("ASCII").trim().to_string());
            }
            let mut chunk = [0u8; 4096];
            let n = tokio::time::timeout(WAIT, self.stream.read(&mut chunk))
                .await
                .expect("an answer in time")
                .unwrap_or(0);
            if n == 0 {
                return None;
            }
            self.buf.extend_from_slice(&chunk[..n]);
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_input_is_answered_and_the_endpoint_goes_on() {
    let text = format!(
        "listen = \"127.0.0.1:0\"\n{ONE_BUS}[socketcand]\nlisten = \"127.0.0.1:0\"\n\
         max_command_bytes = 64\nhandshake_timeout_ms = 500\n"
    );
    let server = cangate_server::start(&Config::from_toml(&text).unwrap())
        .await
        .expect("server starts");
    let addr = server.socketcand_addr.expect("socketcand listens");
    let mut r = Raw::connect(addr).await;
    assert_eq!(r.element().await.as_deref(), Some("< hi >"));
    // Before a bus is open.
    r.send(b"garbage< send 123 0 >< echo >").await;
    assert_eq!(
        r.element().await.as_deref(),
        Some("< error open a bus first (open BUS) >")
    );
    assert_eq!(r.element().await.as_deref(), Some("< echo >"));
    r.send(b"< open can0 >").await;
    assert_eq!(r.element().await.as_deref(), Some("< ok >"));
    // In BCM mode every line is answered, in order; valid sends are silent.
    r.send(
        b"< send 800 0 >< send 123 9 1 2 3 4 5 6 7 8 9 >< frobnicate >< muxfilter 0 0 123 2 FF >\
          < controlmode >< isotpmode >< send 123 1 zz >< \xff >< open can0 >< send 1 0 >< echo >",
    )
    .await;
    let mut answers = Vec::new();
    for _ in 0..10 {
        answers.push(r.element().await.expect("an answer"));
    }
    assert_eq!(
        answers,
        [
            "< error send: identifier 0x800 does not fit in 11 bits (standard ids are 0x000..=0x7FF; use an extended id) >",
            "< error send: the length must be a decimal number 0..=8 (sendfd for CAN FD) >",
            "< error unknown command >",
            "< error muxfilter is not supported by cangate >",
            "< error controlmode is not supported by cangate >",
            "< error isotpmode is not supported by cangate >",
            "< error send: bad data byte zz >",
            "< error a command must be ASCII text >",
            "< error a bus is open already: one bus per connection >",
            "< echo >",
        ]
    );
    // One < … > per command: a nested send is refused, never executed
    // (the stray closing brackets after it are dropped as junk).
    r.send(b"< < < send 1A2 1 00 > > >< echo >").await;
    let e = r.element().await.expect("an answer");
    assert!(e.starts_with("< error malformed command"), "{e}");
    assert_eq!(r.element().await.as_deref(), Some("< echo >"));
    // Raw mode: frames of others arrive as < frame … > lines.
    r.send(b"< rawmode >").await;
    assert_eq!(r.element().await.as_deref(), Some("< ok >"));
    let c = client(&server).await;
    c.bus_client()
        .send_frames(pb::SendFramesRequest {
            bus: "can0".into(),
            frames: vec![data_frame(0x1A, false, &[0xAB, 0x01])],
        })
        .await
        .expect("sent");
    let line = r.element().await.expect("a frame");
    let words: Vec<&str> = line.split(' ').collect();
    assert_eq!(
        (words[0], words[1], words[2], words[4], words[5]),
        ("<", "frame", "01A", "AB01", ">"),
        "{line}"
    );
    assert!(words[3].len() > 7 && words[3].as_bytes()[words[3].len() - 7] == b'.');
    // A command longer than max_command_bytes ends the connection.
    r.send(&[b'<'; 100]).await;
    assert_eq!(
        r.element().await.as_deref(),
        Some("< error a command longer than 64 bytes >")
    );
    assert_eq!(r.element().await, None);
    // A connection that never opens a bus is closed after the handshake
    // timeout.
    let mut idle = Raw::connect(addr).await;
    assert_eq!(idle.element().await.as_deref(), Some("< hi >"));
    assert_eq!(
        idle.element().await.as_deref(),
        Some("< error no bus opened within 500 ms (handshake_timeout_ms) >")
    );
    assert_eq!(idle.element().await, None);
    // An unknown bus: socketcand's answer, then closed.
    let mut r = Raw::connect(addr).await;
    assert_eq!(r.element().await.as_deref(), Some("< hi >"));
    r.send(b"< open nope >").await;
    assert_eq!(
        r.element().await.as_deref(),
        Some("< error could not open bus >")
    );
    assert_eq!(r.element().await, None);
    // The endpoint is still there.
    let mut r = Raw::connect(addr).await;
    assert_eq!(r.element().await.as_deref(), Some("< hi >"));
    // A raw-mode client is let go at shutdown.
    r.send(b"< open can0 >< rawmode >").await;
    assert_eq!(r.element().await.as_deref(), Some("< ok >"));
    assert_eq!(r.element().await.as_deref(), Some("< ok >"));
    server.shutdown();
    assert_eq!(r.element().await, None);
    server.wait(WAIT).await.expect("clean shutdown");
}

/// The per-client raw frame budget and the connection limit hold for
/// socketcand clients as for gRPC ones: frames beyond the budget are
/// answered with an error line naming the limit and never reach the bus;
/// a connection beyond `max_connections` is told why and closed; the
/// others go on.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frame_budget_and_connection_limit_apply_to_socketcand_clients() {
    let text = format!(
        "listen = \"127.0.0.1:0\"\n{ONE_BUS}[socketcand]\nlisten = \"127.0.0.1:0\"\n\
         max_connections = 2\n\
         [security.limits]\nraw_frames_per_second_per_client = 1\nraw_frame_burst = 10\n"
    );
    let server = cangate_server::start(&Config::from_toml(&text).unwrap())
        .await
        .expect("server starts");
    let addr = server.socketcand_addr.expect("socketcand listens");
    let mut c = client(&server).await;
    let (mut watch, mut pending) =
        open_stream(&mut c, stream_request("can0", vec![exact(0x123, false)])).await;

    let mut r = Raw::connect(addr).await;
    assert_eq!(r.element().await.as_deref(), Some("< hi >"));
    r.send(b"< open can0 >< rawmode >").await;
    assert_eq!(r.element().await.as_deref(), Some("< ok >"));
    assert_eq!(r.element().await.as_deref(), Some("< ok >"));
    // 30 frames at once against a burst of 10 (and 1 more per second).
    let sends: String = (0..30).map(|i| format!("< send 123 1 {i:02x} >")).collect();
    r.send(sends.as_bytes()).await;
    r.send(b"< echo >").await;
    let mut refused = 0;
    loop {
        let e = r.element().await.expect("an answer");
        if e == "< echo >" {
            break;
        }
        assert!(
            e.starts_with("< error ") && e.contains("raw_frames_per_second_per_client = 1"),
            "{e}"
        );
        refused += 1;
    }
    // The burst, and what one per second refilled meanwhile (a loaded
    // machine may take a few seconds over the 30).
    assert!((15..=20).contains(&refused), "{refused} refused");
    let sent = 30 - refused;
    let frames = read_frames(&mut watch, &mut pending, sent).await;
    assert_eq!(frames.len(), sent);
    // The burst went first, in order; whatever went later kept its order.
    let data: Vec<u8> = frames.iter().map(|f| f.data[0]).collect();
    assert_eq!(data[..10], (0..10).collect::<Vec<u8>>());
    assert!(data.windows(2).all(|w| w[0] < w[1]), "{data:?}");
    // Nothing beyond them reached the bus.
    let more = tokio::time::timeout(Duration::from_millis(300), watch.message()).await;
    if let Ok(Ok(Some(m))) = more {
        assert!(
            !m.events
                .iter()
                .any(|e| matches!(e.event, Some(pb::stream_event::Event::Frame(_)))),
            "a refused frame reached the bus: {m:?}"
        );
    }

    // A second connection fits, a third is told why and closed (both
    // others have a bus open, so neither gives its slot up).
    let mut second = Raw::connect(addr).await;
    assert_eq!(second.element().await.as_deref(), Some("< hi >"));
    second.send(b"< open can0 >").await;
    assert_eq!(second.element().await.as_deref(), Some("< ok >"));
    let mut third = Raw::connect(addr).await;
    assert_eq!(
        third.element().await.as_deref(),
        Some("< error too many connections (max_connections = 2) >")
    );
    assert_eq!(
        third.element().await,
        None,
        "the third connection is closed"
    );
    // The first one goes on.
    r.send(b"< echo >").await;
    assert_eq!(r.element().await.as_deref(), Some("< echo >"));
    drop(second);
    server.shutdown();
}

/// Idle connections that never open a bus cannot lock a client with a
/// token out: with every slot taken by them, a newcomer takes the oldest
/// one's slot (that one is told why and closed) and opens its bus; only
/// connections with a bus open keep their slots. The same holds per
/// address (`max_connections_per_peer`), and a peer whose connections
/// all have a bus open is refused with the setting named.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_connections_give_their_slots_to_clients_that_open_a_bus() {
    use cangate_server::security::auth::hash_token;
    let text = format!(
        "listen = \"127.0.0.1:0\"\n{ONE_BUS}\
         [socketcand]\nlisten = \"127.0.0.1:0\"\nmax_connections = 4\nmax_connections_per_peer = 3\n\
         [[security.tokens]]\nname = \"eng-1\"\nrole = \"engineer\"\nsha256 = \"{}\"\n",
        hash_token(ENGINEER)
    );
    let server = cangate_server::start(&Config::from_toml(&text).unwrap())
        .await
        .expect("server starts");
    let addr = server.socketcand_addr.expect("socketcand listens");
    // An attacker holds every slot with connections that never open a
    // bus (all from 127.0.0.1: the per-peer limit evicts its own first).
    let mut idle = Vec::new();
    for _ in 0..6 {
        let mut r = Raw::connect(addr).await;
        assert_eq!(r.element().await.as_deref(), Some("< hi >"));
        idle.push(r);
    }
    // Three per address: the first three were closed for the later ones.
    for r in idle.iter_mut().take(3) {
        let e = r.element().await.expect("told why");
        assert!(
            e.starts_with("< error closed before a bus was opened")
                && e.contains("max_connections_per_peer"),
            "{e}"
        );
        assert_eq!(r.element().await, None);
    }
    // The user with a token gets in at once and opens its bus.
    let mut users = Vec::new();
    for _ in 0..3 {
        let mut u = Raw::connect(addr).await;
        assert_eq!(u.element().await.as_deref(), Some("< hi >"));
        u.send(format!("< open can0 {ENGINEER} >").as_bytes()).await;
        assert_eq!(u.element().await.as_deref(), Some("< ok >"));
        users.push(u);
    }
    // Each user took an idle connection's slot.
    for r in idle.iter_mut().skip(3) {
        assert!(
            r.element()
                .await
                .expect("told why")
                .starts_with("< error closed before")
        );
        assert_eq!(r.element().await, None);
    }
    // Three sessions with a bus open: the address is full, and nothing
    // gives way.
    let mut refused = Raw::connect(addr).await;
    assert_eq!(
        refused.element().await.as_deref(),
        Some("< error too many connections from 127.0.0.1 (max_connections_per_peer = 3) >")
    );
    assert_eq!(refused.element().await, None);
    // The users go on.
    for u in &mut users {
        u.send(b"< echo >").await;
        assert_eq!(u.element().await.as_deref(), Some("< echo >"));
    }
    server.shutdown();
}

/// `cangate_socketcand_frames_lost_total` of bus can0 on the gateway's
/// metrics endpoint (0 before the first loss).
async fn socketcand_lost(metrics: SocketAddr) -> u64 {
    let text = scrape_metrics(metrics).await;
    text.lines()
        .find(|l| {
            l.starts_with("cangate_socketcand_frames_lost_total{") && l.contains("bus=\"can0\"")
        })
        .and_then(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
        .map_or(0, |v| v as u64)
}

/// A socketcand client that stops reading loses frames at the gateway
/// (counted in the metric; socketcand's protocol cannot tell it) and hurts
/// nobody: a gRPC client streaming the same frames loses only what the
/// gateway itself could not take from the flood (reported to it as lost
/// frames, as to every subscriber), and the slow client's connection works
/// again once it reads. Every frame is accounted for on both.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slow_socketcand_reader_loses_frames_and_nobody_else_does() {
    const FLOOD: u64 = 200_000;
    let text = format!(
        "listen = \"127.0.0.1:0\"\nmetrics_listen = \"127.0.0.1:0\"\n{ONE_BUS}\
         [socketcand]\nlisten = \"127.0.0.1:0\"\nqueue_length = 1024\n\
         write_timeout_ms = 600000\n\
         [security.limits]\nraw_frames_per_second_per_client = 0\n\
         max_stream_queue = 1000000\nmax_stream_queue_per_client = 1000000\n"
    );
    let server = cangate_server::start(&Config::from_toml(&text).unwrap())
        .await
        .expect("server starts");
    let addr = server.socketcand_addr.expect("socketcand listens");
    let metrics = server.metrics_addr.expect("metrics listen");
    let lost_before = socketcand_lost(metrics).await;

    // The slow client: a small receive buffer, so that the kernel's
    // buffers do not absorb the flood; it opens can0 and stops reading.
    // (For as long as the flood takes, which on a loaded host exceeds the
    // default write_timeout_ms of 10 s that would end its connection: the
    // configuration above allows 10 minutes.)
    let socket = tokio::net::TcpSocket::new_v4().expect("socket");
    socket.set_recv_buffer_size(4096).expect("SO_RCVBUF");
    let stream = socket.connect(addr).await.expect("connects");
    let mut slow = Raw {
        stream,
        buf: Vec::new(),
    };
    assert_eq!(slow.element().await.as_deref(), Some("< hi >"));
    slow.send(b"< open can0 >< rawmode >").await;
    assert_eq!(slow.element().await.as_deref(), Some("< ok >"));
    assert_eq!(slow.element().await.as_deref(), Some("< ok >"));
    // Past the frames' hold after rawmode (RAW_SETTLE).
    tokio::time::sleep(Duration::from_millis(100)).await;

    // A gRPC client streaming the same frames with room for all of them.
    let mut c = client(&server).await;
    let mut req = stream_request("can0", vec![exact(0x321, false)]);
    req.queue_length = FLOOD as u32 + 1000;
    let (mut watch, mut pending) = open_stream(&mut c, req).await;
    let sender = client(&server).await;
    let flood = tokio::spawn(async move {
        for batch in 0..FLOOD / 10_000 {
            let frames = (0..10_000)
                .map(|i| data_frame(0x321, false, &((batch * 10_000 + i) as u32).to_le_bytes()))
                .collect();
            sender
                .bus_client()
                .send_frames(pb::SendFramesRequest {
                    bus: "can0".into(),
                    frames,
                })
                .await
                .expect("flood batch sent");
        }
    });
    let (mut seen, mut grpc_lost) = (0u64, 0u64);
    while seen + grpc_lost < FLOOD {
        let m = tokio::time::timeout(WAIT, watch.message())
            .await
            .unwrap_or_else(|_| panic!("the gRPC stream stalled: {seen} frames, {grpc_lost} lost"))
            .expect("stream ok")
            .expect("stream open");
        pending.extend(m.events);
        for ev in pending.drain(..) {
            match ev.event {
                Some(pb::stream_event::Event::Frame(_)) => seen += 1,
                Some(pb::stream_event::Event::Lost(l)) => grpc_lost += l.count,
                _ => {}
            }
        }
    }
    flood.await.expect("flood");
    // The gRPC client lost only what the gateway itself lost.
    let gateway_lost = server
        .gateway()
        .buses()
        .find(|b| b.name() == "can0")
        .expect("can0")
        .stats()
        .rx_overflows;
    assert_eq!(grpc_lost, gateway_lost, "{seen} frames seen");

    // Reading again, the slow client gets the frames still queued for it
    // and the answer to its echo (which may overtake the last queued
    // frames): the connection survived.
    slow.send(b"< echo >").await;
    let mut frames = 0u64;
    let mut echoed = false;
    loop {
        let next = tokio::time::timeout(Duration::from_millis(500), slow.element()).await;
        let Ok(e) = next else { break }; // quiet: everything was read
        let e = e.expect("the connection is open");
        if e == "< echo >" {
            echoed = true;
            continue;
        }
        assert!(e.starts_with("< frame 321 "), "{e}");
        frames += 1;
    }
    assert!(echoed, "the slow client's echo was answered");
    // The loss notice reaches the connection (and the metric) once its
    // queue has room again: within the bus task's next tick after the
    // reading resumed.
    let deadline = tokio::time::Instant::now() + WAIT;
    let mut lost = socketcand_lost(metrics).await - lost_before;
    while frames + lost < FLOOD && tokio::time::Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(20)).await;
        lost = socketcand_lost(metrics).await - lost_before;
    }
    assert!(
        lost > gateway_lost,
        "the slow client lost {lost}, no more than the gateway's own {gateway_lost}"
    );
    assert_eq!(
        frames + lost,
        FLOOD,
        "what the slow client received and what it lost are the flood"
    );
    server.shutdown();
}

/// Every frame a session sends is accounted for: on the bus, or answered
/// with an error line, also when the bus fails while the session's frame
/// waits in the bus's queue (here its client share of 1 % paces the
/// frames, and the bus goes off while they trickle out). Each session has
/// one frame in flight, whose outcome it reports later.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_socketcand_send_reaches_the_bus_or_is_answered_with_an_error() {
    let text = "listen = \"127.0.0.1:0\"\n[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\n\
         bitrate = 1000000\nbit_timing = true\nclient_share_percent = 1\n\
         [socketcand]\nlisten = \"127.0.0.1:0\"\n";
    let server = cangate_server::start(&Config::from_toml(text).unwrap())
        .await
        .expect("server starts");
    let vbus = server.gateway().network().get("can0").unwrap();
    let mut peer = vbus.connect(false);
    let addr = server.socketcand_addr.expect("socketcand listens");
    let mut r = Raw::connect(addr).await;
    assert_eq!(r.element().await.as_deref(), Some("< hi >"));
    r.send(b"< open can0 >").await;
    assert_eq!(r.element().await.as_deref(), Some("< ok >"));
    r.send(b"< rawmode >").await;
    assert_eq!(r.element().await.as_deref(), Some("< ok >"));
    // At 1 % of 1 Mbit/s these take over half a second: the bus goes off
    // while they trickle out even when this test's sleep runs long.
    const SENDS: usize = 100;
    let mut sends = Vec::new();
    for i in 0..SENDS {
        sends.extend_from_slice(format!("< send 123 1 {i:02X} >").as_bytes());
    }
    r.send(&sends).await;
    tokio::time::sleep(Duration::from_millis(30)).await;
    vbus.force_bus_off();
    let mut errors = Vec::new();
    let mut on_bus = 0;
    let deadline = tokio::time::Instant::now() + WAIT;
    while on_bus + errors.len() < SENDS && tokio::time::Instant::now() < deadline {
        while let Some(event) = peer.try_recv() {
            if matches!(event, cangate_can::PortEvent::Frame { frame, .. } if frame.raw_id() == 0x123)
            {
                on_bus += 1;
            }
        }
        if let Some(e) = r.element_within(Duration::from_millis(50)).await {
            assert!(e.starts_with("< error"), "{e}");
            errors.push(e);
        }
    }
    assert_eq!(
        on_bus + errors.len(),
        SENDS,
        "{on_bus} frames on the bus, errors: {errors:?}"
    );
    assert!(!errors.is_empty(), "the bus went off before all were sent");
    assert!(errors.iter().all(|e| e.contains("bus-off")), "{errors:?}");
}

/// BCM mode (socketcand's default after open): a cyclic job sends every
/// interval as the session's client (a gRPC stream sees it), `update`
/// changes its content without stopping it, `delete` ends it; `subscribe`
/// reports one identifier's frames, `filter` only the content changes
/// under its mask, in BCM mode's `< frame … >` layout; a viewer's cyclic
/// job is refused; raw mode takes no BCM jobs.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bcm_mode_runs_cyclic_jobs_subscriptions_and_content_filters() {
    let server = token_server().await;
    let addr = server.socketcand_addr.expect("socketcand configured");
    let mut c = client_with(&server, ENGINEER).await;
    let (mut stream, mut pending) =
        open_stream(&mut c, stream_request("can0", vec![exact(0x123, false)])).await;

    let mut r = Raw::connect(addr).await;
    assert_eq!(r.element().await.as_deref(), Some("< hi >"));
    r.send(format!("< open can0 {ENGINEER} >").as_bytes()).await;
    assert_eq!(r.element().await.as_deref(), Some("< ok >"));
    r.send(b"< add 0 20000 123 2 11 22 >").await;
    let frames = read_frames(&mut stream, &mut pending, 3).await;
    assert!(
        frames
            .iter()
            .all(|f| f.id == 0x123 && f.data == [0x11, 0x22]),
        "{frames:?}"
    );
    r.send(b"< update 123 1 33 >").await;
    // Frames already on their way may still carry the old content.
    loop {
        let f = read_frames(&mut stream, &mut pending, 1).await.remove(0);
        if f.data == [0x33] {
            break;
        }
        assert_eq!(f.data, [0x11, 0x22]);
    }
    r.send(b"< delete 123 >< delete 123 >").await;
    assert_eq!(
        r.element().await.as_deref(),
        Some("< error delete: no cyclic job for 123 >"),
        "the first delete ended the job"
    );

    // Receiving: one identifier, and content changes.
    r.send(b"< subscribe 0 0 321 >< filter 0 0 456 1 FF >< echo >")
        .await;
    assert_eq!(r.element().await.as_deref(), Some("< echo >"));
    c.bus_client()
        .send_frames(pb::SendFramesRequest {
            bus: "can0".into(),
            frames: vec![
                data_frame(0x322, false, &[0]),
                data_frame(0x321, false, &[1]),
                data_frame(0x456, false, &[1, 0]),
                data_frame(0x456, false, &[1, 9]),
                data_frame(0x456, false, &[2, 0]),
            ],
        })
        .await
        .expect("sent");
    let mut lines = Vec::new();
    for _ in 0..3 {
        let e = r.element().await.expect("a frame");
        // `< frame ID SECS.USECS DATA… >`: the timestamp left out.
        let words: Vec<&str> = e.split(' ').collect();
        assert_eq!((words[0], words[1]), ("<", "frame"), "{e}");
        lines.push(format!("{} {}", words[2], words[4..].join(" ")));
    }
    assert_eq!(lines, ["321 01  >", "456 01 00  >", "456 02 00  >"]);
    r.send(b"< unsubscribe 321 >< unsubscribe 321 >").await;
    assert_eq!(
        r.element().await.as_deref(),
        Some("< error unsubscribe: no subscription or filter for 321 >")
    );

    // A viewer may receive but not send cyclically.
    let mut v = Raw::connect(addr).await;
    assert_eq!(v.element().await.as_deref(), Some("< hi >"));
    v.send(format!("< open can0 {VIEWER} >").as_bytes()).await;
    assert_eq!(v.element().await.as_deref(), Some("< ok >"));
    v.send(b"< add 0 20000 124 0 >").await;
    let e = v.element().await.expect("a refusal");
    assert!(e.contains("cyclic transmission needs role engineer"), "{e}");
    // Raw mode takes no BCM jobs.
    r.send(b"< rawmode >< add 0 20000 125 0 >").await;
    assert_eq!(r.element().await.as_deref(), Some("< ok >"));
    let e = loop {
        let e = r.element().await.expect("an answer");
        if e.starts_with("< error") {
            break e;
        }
    };
    assert_eq!(
        e,
        "< error BCM jobs and subscriptions work in BCM mode (send bcmmode first) >"
    );
}

/// Cyclic frames count in the client's raw frame budget: a job faster than
/// the budget is stopped with an error line at its first refused frame.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cyclic_job_over_the_frame_budget_is_stopped() {
    let text = format!(
        "listen = \"127.0.0.1:0\"\n{ONE_BUS}\
         [socketcand]\nlisten = \"127.0.0.1:0\"\n\
         [security.limits]\nraw_frames_per_second_per_client = 5\nraw_frame_burst = 5\n"
    );
    let c = Config::from_toml(&text).expect("valid");
    let server = cangate_server::start(&c).await.expect("server starts");
    let mut r = Raw::connect(server.socketcand_addr.unwrap()).await;
    assert_eq!(r.element().await.as_deref(), Some("< hi >"));
    r.send(b"< open can0 >").await;
    assert_eq!(r.element().await.as_deref(), Some("< ok >"));
    r.send(b"< add 0 1000 123 1 AA >").await;
    let e = r.element().await.expect("the job's refusal");
    assert!(
        e.starts_with("< error cyclic job 123 stopped: ") && e.contains("frame rate limit"),
        "{e}"
    );
    r.send(b"< delete 123 >").await;
    assert_eq!(
        r.element().await.as_deref(),
        Some("< error delete: no cyclic job for 123 >"),
        "the job is gone"
    );
}
