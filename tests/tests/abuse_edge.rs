//! The abuse suite at the API edge: what a careless or hostile client
//! tries, one test per item of the hardening issue owned here (5 stops
//! under limits, 7 leases bound to identities, 15 memory bounded by
//! configuration, 16 unauthenticated peers, 17 validation, 18 reflection
//! v1alpha). The real server in-process on the virtual bus, the real
//! client (or raw bytes where a client would refuse to send them).

use cangate_client::{ConnectOptions, pb};
use cangate_tests::axes::{Axes, acquire, cmd, enable, wait_ready};
use cangate_tests::*;
use prost::Message;
use prost::bytes::{Buf, BufMut};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tonic::Code;

/// One simulated drive as axis X (profile position), a second as Y, and a
/// simulated handwheel.
const AXES: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"

[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true

[[canopen.node]]
id = 2
eds = "builtin:drive"
simulate = true

[[canopen.node]]
id = 10
eds = "builtin:handwheel"
simulate = true

[[axis]]
name = "X"
bus = "can0"
node = 1
counts_per_unit = 1000.0
max_velocity = 10.0
max_acceleration = 100.0

[[axis]]
name = "Y"
bus = "can0"
node = 2
counts_per_unit = 1000.0
max_velocity = 10.0
max_acceleration = 100.0

[[handwheel]]
name = "hw1"
bus = "can0"
node = 10
"#;

fn tokens_toml(tokens: &[(&str, &str, &str)]) -> String {
    tokens
        .iter()
        .map(|(name, role, token)| {
            format!(
                "[[security.tokens]]\nname = \"{name}\"\nrole = \"{role}\"\nsha256 = \"{}\"\n",
                cangate_client::hash_token(token)
            )
        })
        .collect()
}

async fn with_token(server: &cangate_server::RunningServer, token: &str) -> cangate_client::Client {
    cangate_client::connect_with(
        &format!("http://{}", server.addr),
        &ConnectOptions {
            token: Some(token.into()),
            ..Default::default()
        },
    )
    .await
    .expect("client connects")
}

fn stop(axis: &str) -> pb::AxisCommandRequest {
    pb::AxisCommandRequest {
        axis: axis.into(),
        options: None,
    }
}

/// Item 5: a client polling at its rate limit (and so refused for other
/// calls) can still stop: 40 stops, none refused.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stops_are_never_refused_while_the_same_token_polls_at_its_limit() {
    let config = format!(
        "{AXES}{}[security.limits]\nrequests_per_second_per_client = 5\nburst = 5\n\
         max_concurrent_requests_per_client = 2\n",
        tokens_toml(&[("hmi", "operator", "op")])
    );
    let server = start_server(&config).await;
    let c = with_token(&server, "op").await;
    let mut poll: Axes = c.axes_client();
    wait_ready(&mut poll, &["X", "Y"]).await;
    // Spend the general budget: polls until one is refused.
    let mut refused = false;
    for _ in 0..50 {
        if let Err(e) = poll.get_axis(pb::GetAxisRequest { axis: "X".into() }).await {
            assert_eq!(e.code(), Code::ResourceExhausted, "{e}");
            refused = true;
            break;
        }
    }
    assert!(refused, "the rate limit of 5/s must refuse a poll");
    // A poller keeps the budget spent while the stops go out.
    let poller = {
        let mut poll = poll.clone();
        tokio::spawn(async move {
            let mut refusals = 0u32;
            for _ in 0..200 {
                if poll
                    .get_axis(pb::GetAxisRequest { axis: "X".into() })
                    .await
                    .is_err()
                {
                    refusals += 1;
                }
                tokio::time::sleep(Duration::from_millis(5)).await;
            }
            refusals
        })
    };
    let mut axes: Axes = c.axes_client();
    let mut stop_refusals = Vec::new();
    for i in 0..40 {
        let r = match i % 3 {
            0 => axes.stop(stop("X")).await.map(|_| ()),
            1 => axes.quick_stop(stop("Y")).await.map(|_| ()),
            _ => axes
                .stop_axes(pb::StopAxesRequest {
                    axes: vec!["X".into(), "Y".into()],
                    quick: false,
                    wait: false,
                })
                .await
                .map(|_| ()),
        };
        if let Err(e) = r {
            stop_refusals.push(format!("{:?}: {}", e.code(), e.message()));
        }
    }
    assert!(
        stop_refusals.is_empty(),
        "stops refused: {stop_refusals:#?}"
    );
    assert!(
        poller.await.unwrap() > 0,
        "the poller was at its limit meanwhile"
    );
    server.shutdown();
}

/// Item 7: with authentication on, a lease serves the identity that
/// acquired it; another identity presenting the token is refused with a
/// reason, except for stops.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lease_token_does_not_work_for_another_identity() {
    let config = format!(
        "{AXES}{}",
        tokens_toml(&[
            ("operator-1", "operator", "op1"),
            ("engineer-1", "engineer", "en1")
        ])
    );
    let server = start_server(&config).await;
    let mut owner: Axes = with_token(&server, "op1").await.axes_client();
    let mut other: Axes = with_token(&server, "en1").await.axes_client();
    wait_ready(&mut owner, &["X"]).await;
    let lease = acquire(&mut owner, &["X"], 10_000, "panel").await;

    let e = other.enable(cmd("X", &lease, false)).await.unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied, "{e}");
    assert!(
        e.message().contains("belongs to token operator-1")
            && e.message().contains("not to token engineer-1"),
        "{e}"
    );
    let e = other
        .r#move(pb::MoveRequest {
            axis: "X".into(),
            target: 1.0,
            options: cangate_tests::axes::opts(&lease, false),
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied, "{e}");
    let e = other
        .renew_control(pb::RenewControlRequest {
            lease: lease.clone(),
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied, "{e}");
    let e = other
        .release_control(pb::ReleaseControlRequest {
            lease: lease.clone(),
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied, "{e}");
    // Stops are for anyone who may stop, with or without the token.
    other.stop(cmd("X", &lease, false)).await.unwrap();
    other.quick_stop(cmd("X", "", false)).await.unwrap();
    // The owner still holds the axis and commands it.
    enable(&mut owner, "X", &lease).await;
    owner
        .release_control(pb::ReleaseControlRequest { lease })
        .await
        .unwrap();
    server.shutdown();
}

/// Item 15: caller-chosen sizes are bounded by configuration: a 1 MB
/// client name is refused with a short message, a name of the maximum
/// keeps ListAxes small, an unknown 20 KB axis name is quoted by its
/// start, and stream queues are capped per stream and per client.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn caller_sizes_are_bounded_by_configuration() {
    let config = format!(
        "{AXES}[security.limits]\nmax_stream_queue = 1000\nmax_stream_queue_per_client = 2500\n"
    );
    let server = start_server(&config).await;
    let c = client(&server).await;
    let mut axes: Axes = c.axes_client();
    let e = axes
        .acquire_control(pb::AcquireControlRequest {
            axes: vec!["X".into()],
            ttl_ms: 1000,
            client_name: "n".repeat(1 << 20),
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e}");
    assert!(
        e.message()
            .contains("client_name has 1048576 bytes, at most 128")
            && e.message().len() < 200,
        "{}",
        e.message()
    );
    // A name at the limit is accepted, and every status stays small.
    acquire(&mut axes, &["X", "Y"], 10_000, &"n".repeat(128)).await;
    let list = axes
        .list_axes(pb::ListAxesRequest {})
        .await
        .unwrap()
        .into_inner();
    assert!(list.encoded_len() < 16 * 1024, "{}", list.encoded_len());
    // An unknown name of 20 KB: the error names its start and length.
    let e = axes
        .get_axis(pb::GetAxisRequest {
            axis: "q".repeat(20_000),
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::NotFound, "{e}");
    assert!(
        e.message().contains("(20000 bytes)") && e.message().len() < 300,
        "{}",
        e.message()
    );

    // Stream queues: 1 M asked, 1000 given; 2500 per client in total.
    let mut bus = c.bus_client();
    let mut open = Vec::new();
    for _ in 0..2 {
        let mut req = stream_request("can0", vec![]);
        req.queue_length = 1_000_000;
        open.push(bus.stream_frames(req).await.expect("within the budget"));
    }
    let mut req = stream_request("can0", vec![]);
    req.queue_length = 501;
    let e = bus.stream_frames(req.clone()).await.unwrap_err();
    assert_eq!(e.code(), Code::ResourceExhausted, "{e}");
    assert!(
        e.message().contains("max_stream_queue_per_client = 2500"),
        "{e}"
    );
    req.queue_length = 500;
    open.push(bus.stream_frames(req.clone()).await.expect("fits exactly"));
    // A closed stream gives its share back (once the server saw it end).
    open.remove(0);
    req.queue_length = 1000;
    let t0 = std::time::Instant::now();
    loop {
        match bus.stream_frames(req.clone()).await {
            Ok(s) => {
                open.push(s);
                break;
            }
            Err(e) if e.code() == Code::ResourceExhausted && t0.elapsed() < WAIT => {
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
            Err(e) => panic!("the closed stream's share never came back: {e}"),
        }
    }
    server.shutdown();
}

/// Item 16: a peer sending bad tokens is refused cheaply after a few, its
/// refusals reach the audit log as a bounded number of lines plus a
/// summary, public RPCs stay open to it; connections that never speak
/// HTTP/2, or connect and stay idle, are closed, while one with an open
/// stream stays.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unauthenticated_peers_are_limited_and_idle_connections_closed() {
    let captured = cangate_tests::log::capture_log("cangate::audit=info");
    let config = format!(
        "{ONE_BUS}{}[security.limits]\nrefusals_per_second_per_peer = 5\nrefusal_burst = 10\n\
         audit_refusals_per_second = 5\naudit_summary_interval_s = 1\nhandshake_timeout_s = 1\n\
         idle_connection_timeout_s = 1\n",
        tokens_toml(&[("viewer", "viewer", "good")])
    );
    let server = start_server(&config).await;
    let mut bad = with_token(&server, "wrong").await;
    let t0 = std::time::Instant::now();
    let (mut unauthenticated, mut cheap) = (0u32, 0u32);
    for _ in 0..300 {
        match bad.list_buses().await {
            Err(e) if e.code() == Some(Code::Unauthenticated) => unauthenticated += 1,
            Err(e) if e.code() == Some(Code::ResourceExhausted) => {
                assert!(e.to_string().contains("too many refused calls"), "{e}");
                cheap += 1;
            }
            other => panic!("{other:?}"),
        }
    }
    let secs = t0.elapsed().as_secs_f64();
    // The burst plus what the rate gave back meanwhile.
    assert!(
        f64::from(unauthenticated) <= 10.0 + 5.0 * secs + 1.0,
        "{unauthenticated} credential checks in {secs:.2} s"
    );
    assert!(cheap > 0);
    // Public RPCs are not blocked for the peer.
    let mut health = tonic_health::pb::health_client::HealthClient::new(bad.channel());
    health
        .check(tonic_health::pb::HealthCheckRequest {
            service: String::new(),
        })
        .await
        .expect("health stays open");
    // Audit: a bounded number of refusal lines, then a summary.
    let t1 = std::time::Instant::now();
    let text = loop {
        let text = captured.text();
        if text.contains("refused calls not logged one by one") || t1.elapsed() > WAIT {
            break text;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    let lines = text
        .lines()
        .filter(|l| l.contains("ListBuses") && l.contains("who=unidentified"))
        .count();
    assert!(
        (lines as f64) <= 10.0 + 5.0 * (secs + 1.0) + 1.0,
        "{lines} audit lines for 300 refusals in {secs:.2} s"
    );
    let summary = text
        .lines()
        .find(|l| l.contains("refused calls not logged one by one"))
        .unwrap_or_else(|| panic!("no summary in:\n{text}"));
    assert!(summary.contains("127.0.0.1"), "{summary}");

    // A connection that never sends the HTTP/2 preface is closed.
    let mut silent = tokio::net::TcpStream::connect(server.addr).await.unwrap();
    let mut buf = [0u8; 256];
    let closed = tokio::time::timeout(WAIT, async {
        loop {
            match silent.read(&mut buf).await {
                Ok(0) | Err(_) => return,
                Ok(_) => {} // the server's SETTINGS
            }
        }
    })
    .await;
    assert!(
        closed.is_ok(),
        "a connection without HTTP/2 preface stays open"
    );
    // One that speaks HTTP/2 and then stays idle is closed too.
    let mut idle = tokio::net::TcpStream::connect(server.addr).await.unwrap();
    idle.write_all(b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n\0\0\0\x04\0\0\0\0\0")
        .await
        .unwrap();
    let closed = tokio::time::timeout(WAIT, async {
        loop {
            match idle.read(&mut buf).await {
                Ok(0) | Err(_) => return,
                Ok(_) => {} // the server's SETTINGS, its ack, a GOAWAY
            }
        }
    })
    .await;
    assert!(closed.is_ok(), "an idle HTTP/2 connection stays open");
    // A connection with an open stream is not idle: after several idle
    // timeouts it still carries frames.
    let mut viewer = with_token(&server, "good").await;
    let (mut stream, mut pending) = open_stream(&mut viewer, stream_request("can0", vec![])).await;
    tokio::time::sleep(Duration::from_millis(2500)).await;
    let device = server
        .gateway()
        .network()
        .get("can0")
        .unwrap()
        .connect(false);
    let frame: cangate_client::can::Frame = "123#42".parse().unwrap();
    device.send(&frame).unwrap();
    let frames = read_frames(&mut stream, &mut pending, 1).await;
    assert_eq!(frames[0].id, 0x123);
    server.shutdown();
}

/// A connection that sends only the HTTP/2 preface, or half an HTTP/1.1
/// header, and then nothing, is closed after `handshake_timeout_s`, not
/// after the (long) idle timeout: before its first request it is still
/// in its handshake.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connections_without_a_first_request_are_closed_after_the_handshake_timeout() {
    let server = start_server(&format!(
        "{ONE_BUS}[security.limits]\nhandshake_timeout_s = 1\nidle_connection_timeout_s = 3600\n"
    ))
    .await;
    let inputs: [&[u8]; 3] = [
        b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n",
        b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n\0\0\0\x04\0\0\0\0\0",
        b"POST /cangate.v1.Bus/ListBuses HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: applic",
    ];
    for input in inputs {
        let mut conn = tokio::net::TcpStream::connect(server.addr).await.unwrap();
        conn.write_all(input).await.unwrap();
        let mut buf = [0u8; 256];
        let closed = tokio::time::timeout(WAIT, async {
            loop {
                match conn.read(&mut buf).await {
                    Ok(0) | Err(_) => return,
                    Ok(_) => {} // SETTINGS, its ack, a GOAWAY
                }
            }
        })
        .await;
        assert!(
            closed.is_ok(),
            "a connection without a request stays open: {:?}",
            String::from_utf8_lossy(input)
        );
    }
    // A client that calls is served as before.
    client(&server)
        .await
        .list_buses()
        .await
        .expect("a call goes through");
    server.shutdown();
}

/// A codec that sends raw bytes, to put undecodable protobuf on the wire.
#[derive(Default)]
struct RawCodec;

struct RawEncoder;
struct RawDecoder;

impl tonic::codec::Encoder for RawEncoder {
    type Item = Vec<u8>;
    type Error = tonic::Status;
    fn encode(
        &mut self,
        item: Vec<u8>,
        dst: &mut tonic::codec::EncodeBuf<'_>,
    ) -> Result<(), Self::Error> {
        dst.put_slice(&item);
        Ok(())
    }
}

impl tonic::codec::Decoder for RawDecoder {
    type Item = Vec<u8>;
    type Error = tonic::Status;
    fn decode(
        &mut self,
        src: &mut tonic::codec::DecodeBuf<'_>,
    ) -> Result<Option<Vec<u8>>, Self::Error> {
        let mut out = vec![0; src.remaining()];
        src.copy_to_slice(&mut out);
        Ok(Some(out))
    }
}

impl tonic::codec::Codec for RawCodec {
    type Encode = Vec<u8>;
    type Decode = Vec<u8>;
    type Encoder = RawEncoder;
    type Decoder = RawDecoder;
    fn encoder(&mut self) -> RawEncoder {
        RawEncoder
    }
    fn decoder(&mut self) -> RawDecoder {
        RawDecoder
    }
}

/// Item 17: requests that used to be accepted silently are refused with a
/// reason: a duplicate axis in StopAxes, velocities and accelerations a
/// drive cannot carry out (1e-300, NaN, infinite, negative, huge), a
/// non-finite target, a feed window of 49 days, configuration values no
/// drive can honour, and bytes that are not protobuf.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unchecked_values_are_refused_with_a_reason() {
    let server = start_server(AXES).await;
    let c = client(&server).await;
    let mut axes: Axes = c.axes_client();
    wait_ready(&mut axes, &["X"]).await;
    let e = axes
        .stop_axes(pb::StopAxesRequest {
            axes: vec!["X".into(), "X".into()],
            quick: false,
            wait: false,
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e}");
    assert!(e.message().contains("axis X is named twice"), "{e}");

    let lease = acquire(&mut axes, &["X"], 10_000, "abuse").await;
    enable(&mut axes, "X", &lease).await;
    let mv = |target: f64, velocity: f64, acceleration: f64| pb::MoveRequest {
        axis: "X".into(),
        target,
        relative: false,
        velocity,
        acceleration,
        options: cangate_tests::axes::opts(&lease, false),
    };
    for (req, code, words) in [
        (
            mv(1.0, 1e-300, 0.0),
            Code::InvalidArgument,
            "would never end",
        ),
        (
            mv(1.0, 0.0, 1e-300),
            Code::InvalidArgument,
            "would never end",
        ),
        (
            mv(1.0, f64::NAN, 0.0),
            Code::InvalidArgument,
            "must be positive",
        ),
        (
            mv(1.0, f64::INFINITY, 0.0),
            Code::InvalidArgument,
            "must be positive",
        ),
        (
            mv(1.0, -1.0, 0.0),
            Code::InvalidArgument,
            "must be positive",
        ),
        (
            mv(1.0, 0.0, -5.0),
            Code::InvalidArgument,
            "must be positive",
        ),
        (
            mv(1.0, 1e308, 0.0),
            Code::OutOfRange,
            "exceeds the axis maximum",
        ),
        (
            mv(1.0, 0.0, 1e308),
            Code::OutOfRange,
            "exceeds the axis maximum",
        ),
        (mv(f64::NAN, 0.0, 0.0), Code::InvalidArgument, "finite"),
        (mv(f64::INFINITY, 0.0, 0.0), Code::InvalidArgument, "finite"),
    ] {
        let what = format!("{req:?}");
        let e = axes.r#move(req).await.unwrap_err();
        assert_eq!(e.code(), code, "{what}: {e}");
        assert!(e.message().contains(words), "{what}: {e}");
    }

    let mut wheels = c.handwheels_client();
    let e = wheels
        .stream_feed(pb::StreamFeedRequest {
            handwheels: vec![],
            coalesce_ms: u32::MAX,
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e}");
    assert!(e.message().contains("coalesce_ms"), "{e}");

    // Undecodable protobuf: field 1 (the axis name) claims 255 bytes and
    // none follow.
    let mut grpc = tonic::client::Grpc::new(c.channel());
    grpc.ready().await.unwrap();
    let e = grpc
        .unary::<Vec<u8>, Vec<u8>, _>(
            tonic::Request::new(vec![0x0A, 0xFF, 0x01]),
            tonic::codegen::http::uri::PathAndQuery::from_static("/cangate.v1.Axes/GetAxis"),
            RawCodec,
        )
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e}");
    assert!(e.message().contains("decode"), "{e}");
    server.shutdown();

    // Configuration values no drive or dead-man can honour stop start-up.
    for (from, to, words) in [
        (
            "max_acceleration = 100.0\n\n[[axis]]\nname = \"Y\"",
            "max_acceleration = 100.0\njog_deadman_ms = 4294967295\n\n[[axis]]\nname = \"Y\"",
            "jog_deadman_ms = 4294967295 is above the maximum",
        ),
        (
            "max_acceleration = 100.0\n\n[[axis]]\nname = \"Y\"",
            "max_acceleration = 1e308\n\n[[axis]]\nname = \"Y\"",
            "max_acceleration = 1e308",
        ),
    ] {
        assert!(AXES.contains(from));
        let text = format!("listen = \"127.0.0.1:0\"\n{}", AXES.replacen(from, to, 1));
        let e = cangate_server::Config::from_toml(&text)
            .expect_err("refused at start-up")
            .to_string();
        assert!(e.contains(words), "{e}");
    }
}

/// Item 18: tools speaking only `grpc.reflection.v1alpha` are served.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reflection_answers_v1alpha_clients() {
    use tonic_reflection::pb::v1alpha::server_reflection_client::ServerReflectionClient;
    use tonic_reflection::pb::v1alpha::server_reflection_request::MessageRequest;
    use tonic_reflection::pb::v1alpha::server_reflection_response::MessageResponse;
    let server = start_server(ONE_BUS).await;
    let c = client(&server).await;
    let mut reflection = ServerReflectionClient::new(c.channel());
    let req = tonic_reflection::pb::v1alpha::ServerReflectionRequest {
        host: String::new(),
        message_request: Some(MessageRequest::ListServices(String::new())),
    };
    let mut stream = reflection
        .server_reflection_info(tokio_stream::iter([req]))
        .await
        .expect("v1alpha is served")
        .into_inner();
    let resp = stream.message().await.unwrap().unwrap();
    let Some(MessageResponse::ListServicesResponse(list)) = resp.message_response else {
        panic!("{resp:?}")
    };
    assert!(list.service.iter().any(|s| s.name == "cangate.v1.Bus"));
    server.shutdown();
}
