//! The CiA 309-3 ASCII gateway (`[cia309]`) end to end, with a plain TCP
//! client writing canopend's command lines and reading its answers byte
//! for byte:
//!
//! - reads and writes of every data type (expedited and segmented, and a
//!   block transfer) against a simulated node built from
//!   `tests/python/all_types.eds`, the EDS defaults read first;
//! - an SDO abort reported with its code, an absent node's timeout as
//!   0x05040000;
//! - NMT, and the event line of a node's boot-up after `reset node`, to a
//!   client that asked for event lines only;
//! - unknown commands and bad syntax answered with canopend's codes;
//! - two clients at once, each with its own defaults, commands pipelined;
//! - tokens and roles: login first, an unknown token closes, a viewer
//!   reads but may not write or send NMT, an engineer may;
//! - the runtime's guards: a write to an enabled axis's controlword, NMT
//!   that stops its drive, LSS that reaches it, an RPDO that maps its
//!   controlword (here and through gRPC's WritePdo): refused, the axis
//!   stays enabled;
//! - lely's PDO commands: `write pdo` sends the I/O module's RPDO (its
//!   outputs change), `read pdo` answers the last TPDO received.

use cangate_client::pb;
use cangate_server::{Config, RunningServer};
use cangate_tests::axes::*;
use cangate_tests::*;
use std::net::SocketAddr;
use std::path::Path;
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};

/// A drive with an SDO-polled axis (node 3), the all-types node (5) and
/// an I/O module (7), on one virtual bus.
fn config(extra: &str) -> String {
    let eds = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/all_types.eds");
    format!(
        r#"listen = "127.0.0.1:0"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"
sdo_timeout_ms = 200

[[canopen.node]]
id = 3
eds = "builtin:drive"
simulate = true

[[canopen.node]]
id = 5
eds = "{}"
simulate = true

[[canopen.node]]
id = 7
eds = "builtin:io"
simulate = true
heartbeat_producer_ms = 100
heartbeat_timeout_ms = 500

[[axis]]
name = "S"
bus = "can0"
node = 3
counts_per_unit = 1000.0
min_position = -100.0
max_position = 100.0
max_velocity = 50.0
max_acceleration = 500.0
process_data = "sdo"
sdo_poll_ms = 5

[cia309]
listen = "127.0.0.1:0"
{extra}"#,
        eds.display()
    )
}

async fn server(extra: &str) -> RunningServer {
    let c = Config::from_toml(&config(extra)).expect("valid configuration");
    cangate_server::start(&c).await.expect("server starts")
}

const VIEWER: &str = "viewer-secret";
const ENGINEER: &str = "engineer-secret";

async fn token_server() -> RunningServer {
    use cangate_server::security::auth::hash_token;
    server(&format!(
        "[[security.tokens]]\nname = \"viewer-1\"\nrole = \"viewer\"\nsha256 = \"{}\"\n\
         [[security.tokens]]\nname = \"eng-1\"\nrole = \"engineer\"\nsha256 = \"{}\"\n",
        hash_token(VIEWER),
        hash_token(ENGINEER)
    ))
    .await
}

/// A plain TCP client of the gateway.
struct Gw {
    reader: BufReader<OwnedReadHalf>,
    writer: OwnedWriteHalf,
}

impl Gw {
    async fn connect(server: &RunningServer) -> Gw {
        let addr: SocketAddr = server.cia309_addr.expect("cia309 configured");
        let stream = TcpStream::connect(addr).await.expect("connects");
        let (r, w) = stream.into_split();
        Gw {
            reader: BufReader::new(r),
            writer: w,
        }
    }

    async fn send(&mut self, lines: &str) {
        self.writer
            .write_all(lines.as_bytes())
            .await
            .expect("write to the gateway");
    }

    /// The next line, `\n` included; empty at the end of the stream.
    async fn line(&mut self) -> String {
        let mut line = String::new();
        tokio::time::timeout(WAIT, self.reader.read_line(&mut line))
            .await
            .expect("an answer in time")
            .expect("read from the gateway");
        line
    }

    /// The next line within `limit` (for answers that take long).
    async fn line_within(&mut self, limit: std::time::Duration) -> String {
        let mut line = String::new();
        tokio::time::timeout(limit, self.reader.read_line(&mut line))
            .await
            .expect("an answer in time")
            .expect("read from the gateway");
        line
    }

    /// Sends one command line, returns its answer line.
    async fn ask(&mut self, command: &str) -> String {
        self.send(&format!("{command}\r\n")).await;
        self.line().await
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_data_type_is_read_and_written_as_canopend_does() {
    let server = server("").await;
    let mut gw = Gw::connect(&server).await;
    assert_eq!(gw.ask("[1] set node 5").await, "[1] OK\r\n");
    // The EDS defaults, each printed as its type.
    for (command, answer) in [
        ("[2] r 0x2100 0 b", "[2] 1\r\n"),
        ("[3] r 0x2101 0 i8", "[3] -5\r\n"),
        ("[4] r 0x2102 0 i16", "[4] -1234\r\n"),
        ("[5] r 0x2103 0 i32", "[5] -123456789\r\n"),
        ("[6] r 0x2104 0 i64", "[6] -1234567890123\r\n"),
        ("[7] r 0x2105 0 u8", "[7] 200\r\n"),
        ("[8] r 0x2106 0 u16", "[8] 60000\r\n"),
        ("[9] r 0x2107 0 x32", "[9] 0xDEADBEEF\r\n"),
        ("[10] r 0x2108 0 x64", "[10] 0x0123456789ABCDEF\r\n"),
        ("[11] r 0x2109 0 r32", "[11] 1.5\r\n"),
        ("[12] r 0x210A 0 r64", "[12] -2.25\r\n"),
        // Segmented uploads.
        ("[13] r 0x210B 0 vs", "[13] \"cangate all types\"\r\n"),
        ("[14] r 0x210C 0 os", "[14] AQKg/w==\r\n"),
        ("[15] r 0x2107 0", "[15] EF BE AD DE\r\n"),
        ("[16] r 0x2107 0 u32", "[16] 3735928559\r\n"),
    ] {
        assert_eq!(gw.ask(command).await, answer, "{command}");
    }
    // Writes, read back.
    for (write, read, answer) in [
        ("w 0x2100 0 b 0", "r 0x2100 0 b", "0"),
        ("w 0x2101 0 i8 -128", "r 0x2101 0 i8", "-128"),
        ("w 0x2102 0 i16 0x7FFF", "r 0x2102 0 i16", "32767"),
        ("w 0x2103 0 i32 -2", "r 0x2103 0 i32", "-2"),
        (
            "w 0x2104 0 i64 -9223372036854775808",
            "r 0x2104 0 i64",
            "-9223372036854775808",
        ),
        ("w 0x2105 0 u8 7", "r 0x2105 0 x8", "0x07"),
        ("w 0x2106 0 u16 1000", "r 0x2106 0 u16", "1000"),
        ("w 0x2107 0 x32 0x12345678", "r 0x2107 0 u32", "305419896"),
        (
            "w 0x2108 0 u64 18446744073709551615",
            "r 0x2108 0 u64",
            "18446744073709551615",
        ),
        ("w 0x2109 0 r32 -0.125", "r 0x2109 0 r32", "-0.125"),
        ("w 0x210A 0 r64 1e10", "r 0x210A 0 r64", "1e+10"),
        // Segmented downloads.
        (
            "w 0x210B 0 vs \"say \"\"hi\"\" # not a comment\"",
            "r 0x210B 0 vs",
            "\"say \"\"hi\"\" # not a comment\"",
        ),
        (
            "w 0x210C 0 os AAECAwQFBgc=",
            "r 0x210C 0 hex",
            "00 01 02 03 04 05 06 07",
        ),
        ("w 0x210D 0 hex 0102 03 # bytes", "r 0x210D 0 d", "AQID"),
    ] {
        assert_eq!(
            gw.ask(&format!("[20] {write}")).await,
            "[20] OK\r\n",
            "{write}"
        );
        assert_eq!(
            gw.ask(&format!("[21] {read}")).await,
            format!("[21] {answer}\r\n"),
            "{read}"
        );
    }
    // Block transfers both ways.
    assert_eq!(gw.ask("[30] set sdo_block 1").await, "[30] OK\r\n");
    let big: Vec<u8> = (0..200u32).map(|i| i as u8).collect();
    let b64 = base64(&big);
    assert_eq!(
        gw.ask(&format!("[31] w 0x210D 0 d {b64}")).await,
        "[31] OK\r\n"
    );
    assert_eq!(gw.ask("[32] r 0x210D 0 d").await, format!("[32] {b64}\r\n"));
}

/// Base64 for the test's own values (RFC 2045, padded).
fn base64(data: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for c in data.chunks(3) {
        let n = (u32::from(c[0]) << 16)
            | (u32::from(*c.get(1).unwrap_or(&0)) << 8)
            | u32::from(*c.get(2).unwrap_or(&0));
        for i in 0..4 {
            out.push(if i <= c.len() {
                char::from(T[((n >> (18 - 6 * i)) & 63) as usize])
            } else {
                '='
            });
        }
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sdo_aborts_and_timeouts_are_reported_with_their_codes() {
    let server = server("").await;
    let mut gw = Gw::connect(&server).await;
    assert_eq!(
        gw.ask("[1] 5 read 0x5FFF 0 u8").await,
        "[1] ERROR:0x06020000 #Object does not exist in the object dictionary.\r\n"
    );
    // Writing a read-only object.
    assert!(
        gw.ask("[2] 5 write 0x1000 0 u32 1")
            .await
            .starts_with("[2] ERROR:0x06010002 #"),
    );
    // Nobody at node 99: the client's own abort after the timeout.
    assert_eq!(gw.ask("[3] set sdo_timeout 50").await, "[3] OK\r\n");
    assert_eq!(
        gw.ask("[4] 99 read 0x1000 0 u32").await,
        "[4] ERROR:0x05040000 #SDO protocol timed out.\r\n"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unknown_commands_and_bad_syntax_get_canopends_codes() {
    let server = server("").await;
    let mut gw = Gw::connect(&server).await;
    for (command, answer) in [
        ("[1] bogus", "[1] ERROR:100 #Request not supported.\r\n"),
        ("[2] 5 read", "[2] ERROR:101 #Syntax error.\r\n"),
        (
            "[3] read 0x1000 0",
            "[3] ERROR:105 #No default node set.\r\n",
        ),
        ("[4] 200 start", "[4] ERROR:107 #Unsupported node.\r\n"),
        ("[5] 2 5 start", "[5] ERROR:106 #Unsupported net.\r\n"),
        (
            "[6] 5 write 0x2105 0 u8 300",
            "[6] ERROR:101 #Syntax error.\r\n",
        ),
        (
            "[7] 5 write 0x2105 0 t 1",
            "[7] ERROR:101 #Syntax error.\r\n",
        ),
        ("[8] led", "[8] ERROR:100 #Request not supported.\r\n"),
        ("# only a comment", "\r\n"),
    ] {
        assert_eq!(gw.ask(command).await, answer, "{command}");
    }
    // Help: lines joined by \n, the last ending with \r\n.
    gw.send("[9] help\r\n").await;
    let mut text = String::new();
    while !text.ends_with("\r\n") {
        text.push_str(&gw.line().await);
    }
    assert!(text.contains("r[ead] <index> <subindex>"), "{text}");
    // Still serving.
    assert_eq!(gw.ask("[10] 5 r 0x2105 0 u8").await, "[10] 200\r\n");
    // A line longer than max_line_bytes ends the connection.
    gw.send(&format!("[11] {}\r\n", "x".repeat(20_000))).await;
    let closing = gw.line().await;
    assert!(
        closing.starts_with("# closed: a command line longer than"),
        "{closing}"
    );
    assert_eq!(gw.line().await, "", "closed");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nmt_and_a_boot_up_event_line_to_the_client_that_asked() {
    let server = server("").await;
    let mut listener = Gw::connect(&server).await;
    let mut quiet = Gw::connect(&server).await;
    let mut commander = Gw::connect(&server).await;
    assert_eq!(listener.ask("[1] set events 1").await, "[1] OK\r\n");
    assert_eq!(commander.ask("[1] 7 preop").await, "[1] OK\r\n");
    assert_eq!(commander.ask("[2] 7 start").await, "[2] OK\r\n");
    assert_eq!(commander.ask("[3] 7 reset node").await, "[3] OK\r\n");
    // The boot-up of node 7 reaches the listener (other event lines of the
    // bus may come first).
    loop {
        let l = listener.line().await;
        assert!(!l.is_empty(), "the listener's connection closed");
        if l == "1 7 BOOT_UP\r\n" {
            break;
        }
        assert!(
            l.starts_with("1 ") && l.ends_with("\r\n"),
            "an event line: {l:?}"
        );
    }
    // The client that did not ask gets answers only.
    assert!(
        quiet
            .ask("[4] 7 r 0x1000 0 x32")
            .await
            .starts_with("[4] 0x")
    );
    // NMT to every node (node 0).
    assert_eq!(commander.ask("[5] 0 start").await, "[5] OK\r\n");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_clients_at_once_each_with_its_defaults_and_pipelined_commands() {
    let server = server("").await;
    let mut a = Gw::connect(&server).await;
    let mut b = Gw::connect(&server).await;
    assert_eq!(a.ask("[1] set node 5").await, "[1] OK\r\n");
    assert_eq!(b.ask("[1] set node 7").await, "[1] OK\r\n");
    // Three commands in one write each, both clients at once: answers in
    // order, each from the client's own default node.
    a.send("[2] r 0x2105 0 u8\r\n[3] r 0x2106 0 u16\n[4] r 0x1018 0 u8\r\n")
        .await;
    b.send("[2] r 0x1018 0 u8\r\n[3] r 0x5FFF 0\r\n[4] r 0x1017 0 u16\r\n")
        .await;
    assert_eq!(a.line().await, "[2] 200\r\n");
    assert_eq!(a.line().await, "[3] 60000\r\n");
    assert_eq!(a.line().await, "[4] 4\r\n");
    assert_eq!(b.line().await, "[2] 4\r\n");
    assert!(b.line().await.starts_with("[3] ERROR:0x06020000"));
    let heartbeat = b.line().await;
    assert!(
        heartbeat.starts_with("[4] ") && !heartbeat.contains("ERROR"),
        "{heartbeat}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tokens_and_roles_as_for_grpc() {
    let server = token_server().await;
    // Before a login only help is answered.
    let mut viewer = Gw::connect(&server).await;
    assert!(
        viewer.ask("[1] 5 r 0x2105 0 u8").await.starts_with(
            "[1] ERROR:102 #Request not processed due to internal state. log in first"
        )
    );
    assert!(
        viewer
            .ask("[2] set node 5")
            .await
            .starts_with("[2] ERROR:102 #")
    );
    assert_eq!(
        viewer.ask(&format!("[3] login {VIEWER}")).await,
        "[3] OK\r\n"
    );
    assert_eq!(viewer.ask("[4] 5 r 0x2105 0 u8").await, "[4] 200\r\n");
    let refused = viewer.ask("[5] 5 w 0x2105 0 u8 1").await;
    assert!(
        refused.starts_with("[5] ERROR:102 #") && refused.contains("needs role engineer"),
        "{refused}"
    );
    assert!(
        viewer
            .ask("[6] 7 stop")
            .await
            .contains("needs role engineer")
    );
    assert!(
        viewer
            .ask("[7] lss_switch_glob 1")
            .await
            .contains("needs role engineer")
    );
    assert!(
        viewer
            .ask("[7] write pdo 25 2 1 1")
            .await
            .contains("write_pdo needs role engineer")
    );
    assert_eq!(
        viewer.ask("[8] 5 r 0x2105 0 u8").await,
        "[8] 200\r\n",
        "unchanged"
    );

    let mut engineer = Gw::connect(&server).await;
    assert_eq!(
        engineer.ask(&format!("[1] login {ENGINEER}")).await,
        "[1] OK\r\n"
    );
    assert_eq!(engineer.ask("[2] 5 w 0x2105 0 u8 1").await, "[2] OK\r\n");
    assert_eq!(viewer.ask("[9] 5 r 0x2105 0 u8").await, "[9] 1\r\n");

    // An unknown token: refused, and the connection closes.
    let mut stranger = Gw::connect(&server).await;
    let refused = stranger.ask("[1] login nope").await;
    assert!(
        refused.starts_with("[1] ERROR:102 #") && refused.contains("unknown token"),
        "{refused}"
    );
    assert_eq!(stranger.line().await, "", "closed");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_enabled_axis_drive_is_guarded_as_for_grpc() {
    let server = server("").await;
    let c = client(&server).await;
    let mut axes = c.axes_client();
    wait_status(&mut axes, "S", |s| s.state != 0 && !s.node_lost).await;
    let lease = acquire(&mut axes, &["S"], 10_000, "test").await;
    enable(&mut axes, "S", &lease).await;

    let mut gw = Gw::connect(&server).await;
    let refused = gw.ask("[1] 3 w 0x6040 0 u16 0").await;
    assert!(
        refused.starts_with("[1] ERROR:102 #Request not processed due to internal state. ")
            && refused.contains("axis S"),
        "{refused}"
    );
    for command in ["[2] 3 stop", "[3] 0 reset node", "[4] lss_switch_glob 1"] {
        let a = gw.ask(command).await;
        assert!(
            a.contains("ERROR:102") && a.contains("axis S"),
            "{command}: {a}"
        );
    }
    // Reading the drive is fine; so is NMT start.
    let status = gw.ask("[5] 3 r 0x6041 0 u16").await;
    assert!(!status.contains("ERROR"), "{status}");
    assert_eq!(gw.ask("[6] 3 start").await, "[6] OK\r\n");
    let s = wait_status(&mut axes, "S", |_| true).await;
    assert_eq!(s.state, pb::DriveState::OperationEnabled as i32, "{s:?}");

    // Disabled: the same write goes through.
    let r = axes
        .disable(cmd("S", &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    assert_eq!(gw.ask("[7] 3 w 0x6040 0 u16 6").await, "[7] OK\r\n");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pdo_commands_write_an_rpdo_and_read_the_last_tpdo() {
    let server = server("").await;
    let mut gw = Gw::connect(&server).await;
    // RPDOs count in operational.
    assert_eq!(gw.ask("[0] 7 start").await, "[0] OK\r\n");
    // Node 7's RPDO 1 (PDO 25) maps its two output bytes 0x6200:01, :02.
    assert_eq!(gw.ask("[1] write pdo 25 2 0xA5 0x5A").await, "[1] OK\r\n");
    assert_eq!(gw.ask("[2] 7 r 0x6200 1 u8").await, "[2] 165\r\n");
    assert_eq!(gw.ask("[3] 7 r 0x6200 2 x8").await, "[3] 0x5A\r\n");
    for (command, code) in [
        // One value short; a value too large for its 8 bits.
        ("[4] write pdo 25 1 0xA5", "101"),
        ("[4] write pdo 25 2 0x100 0", "101"),
        // Node 7 has no RPDO 4; node 1 is not configured.
        ("[4] write pdo 28 0", "102"),
        ("[4] read pdo 1", "102"),
    ] {
        let a = gw.ask(command).await;
        assert!(
            a.starts_with(&format!("[4] ERROR:{code} #")),
            "{command}: {a}"
        );
    }

    // Node 7's TPDO 1 (PDO 25): 0x6000:01, :02 (8 bits), 0x6401:01, :02
    // (16 bits), as the node sent it last. The simulated module sends
    // its own once when it starts: the frame is put on the bus until the
    // gateway answers with it.
    let vbus = server.gateway().network().get("can0").unwrap();
    let node = vbus.connect(false);
    let tpdo: cangate_client::can::Frame = "187#112233445566FF".parse().unwrap();
    let want = "[5] 1 pdo 4 0x11 0x22 0x4433 0x6655\r\n";
    let deadline = tokio::time::Instant::now() + WAIT;
    loop {
        node.send(&tpdo).unwrap();
        let a = gw.ask("[5] read pdo 25").await;
        if a == want {
            break;
        }
        assert!(
            a.starts_with("[5] 1 pdo 4 ") || a.contains("received yet"),
            "{a}"
        );
        assert!(tokio::time::Instant::now() < deadline, "last answer {a}");
        tokio::task::yield_now().await;
    }
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_rpdo_that_commands_an_enabled_axis_drive_is_refused() {
    // Axis S on PDOs: node 3's RPDO 1 (PDO 9) carries its controlword and
    // mode of operation.
    let text = config("").replace("process_data = \"sdo\"\nsdo_poll_ms = 5\n", "");
    let c = Config::from_toml(&text).expect("valid configuration");
    let server = cangate_server::start(&c).await.expect("server starts");
    let c = client(&server).await;
    let mut axes = c.axes_client();
    wait_status(&mut axes, "S", |s| s.state != 0 && !s.node_lost).await;
    let lease = acquire(&mut axes, &["S"], 10_000, "test").await;
    enable(&mut axes, "S", &lease).await;
    let mut gw = Gw::connect(&server).await;
    let refused = gw.ask("[1] write pdo 9 2 0 0").await;
    assert!(
        refused.starts_with("[1] ERROR:102 #Request not processed due to internal state. ")
            && refused.contains("axis S")
            && refused.contains("0x6040"),
        "{refused}"
    );
    // gRPC's WritePdo keeps the same rule.
    let value = |index: u32, ty: pb::DataType, v: pb::value::Value| pb::PdoValue {
        index,
        subindex: 0,
        name: String::new(),
        value: Some(pb::Value {
            r#type: ty as i32,
            value: Some(v),
        }),
    };
    let e = c
        .canopen_client()
        .write_pdo(pb::WritePdoRequest {
            bus: "can0".into(),
            node: 3,
            pdo: 1,
            values: vec![
                value(
                    0x6040,
                    pb::DataType::Unsigned16,
                    pb::value::Value::UintValue(0),
                ),
                value(
                    0x6060,
                    pb::DataType::Integer8,
                    pb::value::Value::IntValue(0),
                ),
            ],
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), tonic::Code::FailedPrecondition, "{e:?}");
    assert!(e.message().contains("axis S"), "{e:?}");
    let s = wait_status(&mut axes, "S", |_| true).await;
    assert_eq!(s.state, pb::DriveState::OperationEnabled as i32, "{s:?}");
    server.shutdown();
}

/// Skips event lines up to `want`, which must come.
async fn event(gw: &mut Gw, want: &str) {
    loop {
        let l = gw.line().await;
        assert!(!l.is_empty(), "the connection closed before {want:?}");
        if l == want {
            return;
        }
        assert!(
            l.starts_with("1 ") && l.ends_with("\r\n"),
            "an event line: {l:?}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_emcy_becomes_an_event_line() {
    let server = server("").await;
    let mut gw = Gw::connect(&server).await;
    assert_eq!(gw.ask("[1] set events 1").await, "[1] OK\r\n");
    client(&server)
        .await
        .simulator_client()
        .send_emcy(pb::SendEmcyRequest {
            bus: "can0".into(),
            node: 7,
            code: 0x2310,
            error_register: 0x03,
            manufacturer: vec![1, 2, 3, 4, 255],
        })
        .await
        .expect("EMCY sent");
    event(&mut gw, "1 7 EMCY 2310 03 1 2 3 4 255\r\n").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_connection_that_does_not_log_in_is_closed() {
    use cangate_server::security::auth::hash_token;
    let server = server(&format!(
        "handshake_timeout_ms = 200\n\
         [[security.tokens]]\nname = \"eng-1\"\nrole = \"engineer\"\nsha256 = \"{}\"\n",
        hash_token(ENGINEER)
    ))
    .await;
    let mut gw = Gw::connect(&server).await;
    assert_eq!(
        gw.line().await,
        "# closed: no login within 200 ms (handshake_timeout_ms)\r\n"
    );
    assert_eq!(gw.line().await, "", "closed");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lss_commands_give_an_unconfigured_device_its_node_id() {
    let c = Config::from_toml(&config("").replace(
        "[cia309]",
        "[[canopen.node]]\nid = 30\neds = \"builtin:io\"\nsimulate = true\n\
         sim_lss = { serial = 0xCAFE }\n\n[cia309]",
    ))
    .expect("valid configuration");
    let server = cangate_server::start(&c).await.expect("server starts");
    let mut gw = Gw::connect(&server).await;
    let mut events = Gw::connect(&server).await;
    assert_eq!(events.ask("[1] set events 1").await, "[1] OK\r\n");
    gw.send("[1] _lss_fastscan 20\r\n").await;
    // About 130 fastscan steps of 20 ms; on a loaded runner more.
    let found = gw.line_within(6 * WAIT).await;
    assert!(
        found.starts_with("[1] 0x") && found.ends_with(" 0x0000CAFE\r\n"),
        "{found}"
    );
    assert_eq!(gw.ask("[2] lss_get_node").await, "[2] 0xFF\r\n");
    // Node 5 answers on the bus: its id is not given to another device.
    let refused = gw.ask("[3] lss_set_node 5").await;
    assert!(
        refused.starts_with("[3] ERROR:102 #") && refused.contains("in use"),
        "{refused}"
    );
    assert_eq!(gw.ask("[4] lss_set_node 31").await, "[4] OK\r\n");
    assert_eq!(gw.ask("[5] lss_switch_glob 0").await, "[5] OK\r\n");
    event(&mut events, "1 31 BOOT_UP\r\n").await;
    assert_eq!(gw.ask("[6] 31 r 0x1018 4 x32").await, "[6] 0x0000CAFE\r\n");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lss_allnodes_numbers_every_unconfigured_device() {
    let c = Config::from_toml(&config("").replace(
        "[cia309]",
        "[[canopen.node]]\nid = 30\neds = \"builtin:io\"\nsimulate = true\n\
         sim_lss = { serial = 0xCAFE }\n\n\
         [[canopen.node]]\nid = 31\neds = \"builtin:io\"\nsimulate = true\n\
         sim_lss = { serial = 0xBEEF }\n\n[cia309]",
    ))
    .expect("valid configuration");
    let server = cangate_server::start(&c).await.expect("server starts");
    let mut gw = Gw::connect(&server).await;
    gw.send("[1] lss_allnodes 20 40 0\r\n").await;
    let mut lines = Vec::new();
    loop {
        // Three fastscans of about 130 steps of 20 ms, on a loaded runner
        // more: the answer comes whole at the end.
        let l = gw.line_within(6 * WAIT).await;
        assert!(!l.is_empty(), "closed after {lines:?}");
        let last = l.starts_with("[1] ");
        lines.push(l);
        if last {
            break;
        }
    }
    assert_eq!(lines.len(), 4, "{lines:?}");
    assert!(
        lines[0].starts_with("# Node-ID 40 assigned to: 0x"),
        "{lines:?}"
    );
    assert!(
        lines[1].starts_with("# Node-ID 41 assigned to: 0x"),
        "{lines:?}"
    );
    let serials: Vec<&str> = lines[..2]
        .iter()
        .map(|l| l.trim_end().rsplit(' ').next().unwrap())
        .collect();
    assert!(
        serials.contains(&"0x0000CAFE") && serials.contains(&"0x0000BEEF"),
        "{lines:?}"
    );
    assert_eq!(lines[2], "# Found 2 nodes, search finished.\n");
    assert_eq!(lines[3], "[1] OK\r\n");
}

/// The connections are served on the bus thread (that is what makes a
/// command cheap): a flood of pipelined commands from several clients at
/// once must not hold up the bus side. Node 7's heartbeat (100 ms, consumed
/// with a 500 ms timeout on that same thread) is never lost, every command
/// is answered in order, and a gRPC read meanwhile is answered too.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_flood_of_commands_does_not_hold_up_the_bus_side() {
    const CLIENTS: usize = 4;
    const COMMANDS: usize = 400;
    let server = server("").await;
    let c = client(&server).await;
    let mut events = node_events(&c, vec![7]).await;
    let addr = server.cia309_addr.expect("cia309 configured");
    let floods: Vec<_> = (0..CLIENTS)
        .map(|k| {
            tokio::spawn(async move {
                let stream = TcpStream::connect(addr).await.expect("connects");
                let (r, w) = stream.into_split();
                let mut gw = Gw {
                    reader: BufReader::new(r),
                    writer: w,
                };
                // Every command in one write: the gateway reads them back
                // to back. Reads of the node and commands that touch no
                // bus, alternating.
                let command = |i: usize| {
                    if (i + k).is_multiple_of(2) {
                        (format!("[{i}] 7 r 0x1018 0 u8\r\n"), format!("[{i}] 4\r\n"))
                    } else {
                        (format!("[{i}] set node 7\r\n"), format!("[{i}] OK\r\n"))
                    }
                };
                let lines: String = (0..COMMANDS).map(|i| command(i).0).collect();
                gw.send(&lines).await;
                for i in 0..COMMANDS {
                    assert_eq!(gw.line().await, command(i).1, "client {k}, command {i}");
                }
            })
        })
        .collect();
    // A gRPC client reads meanwhile.
    let identity = c
        .canopen("can0")
        .read_bytes(
            cangate_client::NodeId::new(7).expect("node id"),
            cangate_client::ObjectAddress::new(0x1018, 1),
            Default::default(),
        )
        .await
        .expect("a gRPC read during the flood");
    assert_eq!(identity.len(), 4);
    for f in floods {
        f.await.expect("a flooding client");
    }
    while let Ok(ev) =
        tokio::time::timeout(std::time::Duration::from_millis(50), events.message()).await
    {
        let ev = ev.expect("event stream").expect("event stream open");
        assert!(
            !matches!(ev.event, Some(pb::node_event::Event::HeartbeatLost(_))),
            "heartbeat lost under the flood: {ev:?}"
        );
    }
    assert!(!get_node(&c, 7).await.heartbeat_lost);
}
