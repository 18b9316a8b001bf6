//! gRPC-Web on the gateway's own listener, spoken as a browser speaks it:
//! HTTP/1.1 by hand over a TCP connection, `application/grpc-web+proto`
//! and `application/grpc-web-text` bodies, the status in the trailer frame
//! (or in the headers of a trailers-only answer). Calls pass the same
//! security layer as gRPC (tokens, roles); CORS answers only the origins
//! `[web] allowed_origins` names. The dashboard's files are served at `/`
//! beside the API.

use base64::Engine;
use base64::engine::general_purpose::STANDARD as BASE64;
use cangate_client::pb;
use cangate_tests::*;
use prost::Message;
use std::net::SocketAddr;
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;

const PROTO: &str = "application/grpc-web+proto";
const TEXT: &str = "application/grpc-web-text";

/// An HTTP/1.1 response whose body is read as it arrives.
struct Response {
    status: u16,
    headers: Vec<(String, String)>,
    reader: BufReader<TcpStream>,
    /// `Some(n)`: a body of `n` bytes; `None`: chunked.
    length: Option<usize>,
    done: bool,
}

impl Response {
    fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }

    /// The next piece of the body; `None` at its end.
    async fn chunk(&mut self) -> Option<Vec<u8>> {
        if self.done {
            return None;
        }
        if let Some(n) = self.length {
            self.done = true;
            let mut body = vec![0; n];
            self.reader.read_exact(&mut body).await.expect("body");
            return Some(body);
        }
        let mut line = String::new();
        self.reader.read_line(&mut line).await.expect("chunk size");
        let size = usize::from_str_radix(line.trim(), 16).expect("chunk size is hex");
        let mut body = vec![0; size + 2];
        self.reader.read_exact(&mut body).await.expect("chunk");
        body.truncate(size);
        if size == 0 {
            self.done = true;
            return None;
        }
        Some(body)
    }

    /// The whole body.
    async fn body(&mut self) -> Vec<u8> {
        let mut all = Vec::new();
        while let Some(c) = tokio::time::timeout(WAIT, self.chunk())
            .await
            .expect("body in time")
        {
            all.extend(c);
        }
        all
    }
}

/// Sends one HTTP/1.1 request on a new connection.
async fn http(
    addr: SocketAddr,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &[u8],
) -> Response {
    let mut s = TcpStream::connect(addr).await.expect("connects");
    // The address as Host unless the test names another.
    let mut head = format!("{method} {path} HTTP/1.1\r\n");
    if !headers.iter().any(|(k, _)| k.eq_ignore_ascii_case("host")) {
        head.push_str(&format!("Host: {addr}\r\n"));
    }
    head.push_str(&format!("Content-Length: {}\r\n", body.len()));
    for (k, v) in headers {
        head.push_str(&format!("{k}: {v}\r\n"));
    }
    head.push_str("\r\n");
    s.write_all(head.as_bytes()).await.unwrap();
    s.write_all(body).await.unwrap();
    let mut reader = BufReader::new(s);
    let mut status_line = String::new();
    tokio::time::timeout(WAIT, reader.read_line(&mut status_line))
        .await
        .expect("answer in time")
        .expect("status line");
    let status: u16 = status_line
        .split(' ')
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or_else(|| panic!("bad status line {status_line:?}"));
    let mut headers = Vec::new();
    loop {
        let mut line = String::new();
        reader.read_line(&mut line).await.expect("header line");
        let line = line.trim_end();
        if line.is_empty() {
            break;
        }
        let (k, v) = line.split_once(':').expect("header has a colon");
        headers.push((k.trim().to_string(), v.trim().to_string()));
    }
    let find = |name: &str| {
        headers
            .iter()
            .find(|(k, _): &&(String, String)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.clone())
    };
    let length = if find("transfer-encoding").is_some_and(|v| v.contains("chunked")) {
        None
    } else {
        Some(find("content-length").map_or(0, |v| v.parse().expect("content-length")))
    };
    Response {
        status,
        headers,
        reader,
        length,
        done: false,
    }
}

/// One gRPC-Web message as a frame (flag 0, big-endian length).
fn frame(msg: &impl Message) -> Vec<u8> {
    let payload = msg.encode_to_vec();
    let mut f = vec![0u8];
    f.extend((payload.len() as u32).to_be_bytes());
    f.extend(payload);
    f
}

/// What a gRPC-Web response body holds: its messages and its trailers.
#[derive(Debug, Default)]
struct Frames {
    messages: Vec<Vec<u8>>,
    trailers: Vec<(String, String)>,
}

impl Frames {
    /// Takes the complete frames off the front of `buf`.
    fn take(&mut self, buf: &mut Vec<u8>) {
        while buf.len() >= 5 {
            let len = u32::from_be_bytes(buf[1..5].try_into().unwrap()) as usize;
            if buf.len() < 5 + len {
                return;
            }
            let flag = buf[0];
            let payload: Vec<u8> = buf.drain(..5 + len).skip(5).collect();
            if flag & 0x80 != 0 {
                let text = String::from_utf8(payload).expect("trailers are text");
                for line in text.split("\r\n").filter(|l| !l.is_empty()) {
                    let (k, v) = line.split_once(':').expect("trailer has a colon");
                    self.trailers
                        .push((k.trim().to_ascii_lowercase(), v.trim().to_string()));
                }
            } else {
                self.messages.push(payload);
            }
        }
    }

    fn trailer(&self, name: &str) -> Option<&str> {
        self.trailers
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v.as_str())
    }
}

/// Decodes gRPC-Web text: base64 of each message on its own, so padding
/// may come in the middle; every 4 characters decode alone.
fn unbase64(text: &[u8]) -> Vec<u8> {
    let clean: Vec<u8> = text
        .iter()
        .copied()
        .filter(|b| !b.is_ascii_whitespace())
        .collect();
    assert_eq!(clean.len() % 4, 0, "base64 comes in groups of 4");
    clean
        .chunks(4)
        .flat_map(|g| BASE64.decode(g).expect("valid base64"))
        .collect()
}

/// A unary gRPC-Web call: (response, frames of its body).
async fn unary(
    addr: SocketAddr,
    path: &str,
    content_type: &str,
    msg: &impl Message,
    extra: &[(&str, &str)],
) -> (Response, Frames) {
    let body = match content_type {
        TEXT => BASE64.encode(frame(msg)).into_bytes(),
        _ => frame(msg),
    };
    let mut headers = vec![
        ("Content-Type", content_type),
        ("Accept", content_type),
        ("X-Grpc-Web", "1"),
    ];
    headers.extend_from_slice(extra);
    let mut resp = http(addr, "POST", path, &headers, &body).await;
    let raw = resp.body().await;
    let mut bytes = if content_type == TEXT {
        unbase64(&raw)
    } else {
        raw
    };
    let mut frames = Frames::default();
    frames.take(&mut bytes);
    assert!(bytes.is_empty(), "no partial frame left over");
    (resp, frames)
}

/// The call's status: from the trailer frame, or from the headers of a
/// trailers-only answer.
fn grpc_status(resp: &Response, frames: &Frames) -> (i32, String) {
    let code = frames
        .trailer("grpc-status")
        .or_else(|| resp.header("grpc-status"))
        .expect("a grpc-status in trailers or headers");
    let message = frames
        .trailer("grpc-message")
        .or_else(|| resp.header("grpc-message"))
        .unwrap_or("");
    (
        code.parse().expect("numeric status"),
        percent_decoded(message),
    )
}

/// `grpc-message` is percent-encoded (the gRPC HTTP/2 spec).
fn percent_decoded(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%'
            && let Some(v) = s
                .get(i + 1..i + 3)
                .and_then(|h| u8::from_str_radix(h, 16).ok())
        {
            out.push(v);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).expect("UTF-8 message")
}

const LIST_BUSES: &str = "/cangate.v1.Bus/ListBuses";

#[tokio::test]
async fn unary_call_in_binary_and_text() {
    let server = start_server(ONE_BUS).await;
    for ct in [PROTO, TEXT] {
        let (resp, frames) =
            unary(server.addr, LIST_BUSES, ct, &pb::ListBusesRequest {}, &[]).await;
        assert_eq!(resp.status, 200, "{ct}");
        assert!(
            resp.header("content-type")
                .is_some_and(|v| v.starts_with(ct)),
            "{ct}: {:?}",
            resp.headers
        );
        assert_eq!(grpc_status(&resp, &frames), (0, String::new()), "{ct}");
        assert!(
            frames.trailer("grpc-status").is_some(),
            "{ct}: an answer with a message carries its status in a trailer frame"
        );
        assert_eq!(frames.messages.len(), 1, "{ct}");
        let list = pb::ListBusesResponse::decode(&frames.messages[0][..]).unwrap();
        let names: Vec<&str> = list.buses.iter().map(|b| b.name.as_str()).collect();
        assert_eq!(names, ["can0"], "{ct}");
    }
    server.shutdown();
}

#[tokio::test]
async fn server_stream_delivers_a_frame_sent_over_grpc() {
    let server = start_server(ONE_BUS).await;
    let req = stream_request("can0", vec![]);
    let mut resp = http(
        server.addr,
        "POST",
        "/cangate.v1.Bus/StreamFrames",
        &[
            ("Content-Type", PROTO),
            ("Accept", PROTO),
            ("X-Grpc-Web", "1"),
        ],
        &frame(&req),
    )
    .await;
    assert_eq!(resp.status, 200);
    assert_eq!(resp.length, None, "a stream is sent chunked");
    let mut buf = Vec::new();
    let mut frames = Frames::default();
    // The stream starts with the bus state: then the subscription is in
    // place and the frame sent next must arrive.
    let mut sent = false;
    let mut seen = None;
    while seen.is_none() {
        let chunk = tokio::time::timeout(WAIT, resp.chunk())
            .await
            .expect("stream data in time")
            .expect("stream not ended");
        buf.extend(chunk);
        frames.take(&mut buf);
        for m in frames.messages.drain(..) {
            let msg = pb::StreamFramesResponse::decode(&m[..]).unwrap();
            for ev in msg.events {
                if let Some(pb::stream_event::Event::Frame(f)) = ev.event
                    && f.id == 0x5A5
                {
                    seen = Some(f);
                }
            }
            if !sent {
                sent = true;
                client(&server)
                    .await
                    .bus_client()
                    .send_frames(pb::SendFramesRequest {
                        bus: "can0".into(),
                        frames: vec![pb::Frame {
                            id: 0x5A5,
                            data: vec![0xDE, 0xAD],
                            ..Default::default()
                        }],
                    })
                    .await
                    .expect("frame sent over gRPC");
            }
        }
    }
    assert_eq!(seen.unwrap().data, [0xDE, 0xAD]);
    assert!(frames.trailers.is_empty(), "the stream is still open");
    server.shutdown();
}

fn tokens_toml() -> String {
    [("hmi", "viewer", "v-token"), ("op", "operator", "o-token")]
        .iter()
        .map(|(name, role, token)| {
            format!(
                "[[security.tokens]]\nname = \"{name}\"\nrole = \"{role}\"\nsha256 = \"{}\"\n",
                cangate_client::hash_token(token)
            )
        })
        .collect()
}

#[tokio::test]
async fn the_security_layer_checks_grpc_web_calls() {
    let server = start_server(&format!("{}{ONE_BUS}", tokens_toml())).await;
    let addr = server.addr;
    // No token: refused, the status readable by a gRPC-Web client.
    let (resp, frames) = unary(addr, LIST_BUSES, PROTO, &pb::ListBusesRequest {}, &[]).await;
    assert_eq!(resp.status, 200);
    let (code, message) = grpc_status(&resp, &frames);
    assert_eq!(code, tonic::Code::Unauthenticated as i32, "{message}");
    assert!(message.contains("missing bearer token"), "{message}");
    assert!(frames.messages.is_empty());
    // An unknown token: refused too, in text mode as well.
    let (resp, frames) = unary(
        addr,
        LIST_BUSES,
        TEXT,
        &pb::ListBusesRequest {},
        &[("Authorization", "Bearer nope")],
    )
    .await;
    assert_eq!(
        grpc_status(&resp, &frames).0,
        tonic::Code::Unauthenticated as i32
    );
    // A viewer's token reads.
    let (resp, frames) = unary(
        addr,
        LIST_BUSES,
        PROTO,
        &pb::ListBusesRequest {},
        &[("Authorization", "Bearer v-token")],
    )
    .await;
    assert_eq!(grpc_status(&resp, &frames).0, 0);
    assert_eq!(frames.messages.len(), 1);
    // Roles hold: a viewer may not send frames, an operator neither
    // (raw frames need an engineer), and the refusal names the role.
    let send = pb::SendFramesRequest {
        bus: "can0".into(),
        frames: vec![pb::Frame {
            id: 0x1,
            ..Default::default()
        }],
    };
    for token in ["Bearer v-token", "Bearer o-token"] {
        let (resp, frames) = unary(
            addr,
            "/cangate.v1.Bus/SendFrames",
            PROTO,
            &send,
            &[("Authorization", token)],
        )
        .await;
        let (code, message) = grpc_status(&resp, &frames);
        assert_eq!(code, tonic::Code::PermissionDenied as i32, "{message}");
        assert!(message.contains("needs role engineer"), "{message}");
    }
    server.shutdown();
}

/// A CORS preflight for a gRPC-Web call from `origin`.
async fn preflight(addr: SocketAddr, origin: &str) -> Response {
    let mut resp = http(
        addr,
        "OPTIONS",
        LIST_BUSES,
        &[
            ("Origin", origin),
            ("Access-Control-Request-Method", "POST"),
            (
                "Access-Control-Request-Headers",
                "authorization,content-type,x-grpc-web,x-user-agent",
            ),
        ],
        &[],
    )
    .await;
    resp.body().await;
    resp
}

#[tokio::test]
async fn cors_answers_the_configured_origins_only() {
    let hmi = "https://hmi.example.com";
    let server = start_server(&format!("[web]\nallowed_origins = [\"{hmi}\"]\n{ONE_BUS}")).await;
    let resp = preflight(server.addr, hmi).await;
    assert!(resp.status < 300, "{}", resp.status);
    assert_eq!(resp.header("access-control-allow-origin"), Some(hmi));
    let allowed = resp
        .header("access-control-allow-headers")
        .unwrap_or_default()
        .to_ascii_lowercase();
    for h in ["authorization", "content-type", "x-grpc-web"] {
        assert!(allowed.contains(h), "{h} not in {allowed:?}");
    }
    // The call itself carries the origin's permission and exposes the
    // status headers to the page.
    let (resp, frames) = unary(
        server.addr,
        LIST_BUSES,
        PROTO,
        &pb::ListBusesRequest {},
        &[("Origin", hmi)],
    )
    .await;
    assert_eq!(grpc_status(&resp, &frames).0, 0);
    assert_eq!(resp.header("access-control-allow-origin"), Some(hmi));
    assert!(
        resp.header("access-control-expose-headers")
            .is_some_and(|v| v.contains("grpc-status")),
        "{:?}",
        resp.headers
    );
    // Another origin gets no permission.
    let other = preflight(server.addr, "https://evil.example.com").await;
    assert_eq!(other.header("access-control-allow-origin"), None);
    server.shutdown();

    // By default no other origin is allowed at all.
    let server = start_server(ONE_BUS).await;
    let resp = preflight(server.addr, hmi).await;
    assert_eq!(resp.header("access-control-allow-origin"), None);
    assert!(resp.status >= 400, "{}", resp.status);
    server.shutdown();
}

#[tokio::test]
async fn the_dashboard_is_served_beside_the_api() {
    let server = start_server(ONE_BUS).await;
    let mut page = http(server.addr, "GET", "/", &[], &[]).await;
    assert_eq!(page.status, 200);
    assert_eq!(
        page.header("content-type"),
        Some("text/html; charset=utf-8")
    );
    let csp = page
        .header("content-security-policy")
        .expect("a Content-Security-Policy")
        .to_string();
    assert!(csp.contains("script-src 'self'"), "{csp}");
    assert!(csp.contains("connect-src 'self'"), "{csp}");
    let html = String::from_utf8(page.body().await).unwrap();
    assert!(html.contains("<script defer src=\"/app.js\">"), "{html}");
    for (path, ct) in [
        ("/app.js", "text/javascript; charset=utf-8"),
        ("/app.css", "text/css; charset=utf-8"),
    ] {
        let mut r = http(server.addr, "GET", path, &[], &[]).await;
        assert_eq!(r.status, 200, "{path}");
        assert_eq!(r.header("content-type"), Some(ct), "{path}");
        assert!(!r.body().await.is_empty(), "{path}");
    }
    // HEAD answers the headers only.
    let head = http(server.addr, "HEAD", "/app.js", &[], &[]).await;
    assert_eq!(head.status, 200);
    // Unknown paths, gRPC paths included, are 404 for GET.
    for path in ["/nope", "/app.js.map", LIST_BUSES] {
        let mut r = http(server.addr, "GET", path, &[], &[]).await;
        assert_eq!(r.status, 404, "{path}");
        r.body().await;
    }
    // The API still answers beside the files.
    let (resp, frames) = unary(
        server.addr,
        LIST_BUSES,
        PROTO,
        &pb::ListBusesRequest {},
        &[],
    )
    .await;
    assert_eq!(grpc_status(&resp, &frames).0, 0);
    server.shutdown();

    // [web] enabled = false: no files, the API as before.
    let server = start_server(&format!("[web]\nenabled = false\n{ONE_BUS}")).await;
    let mut r = http(server.addr, "GET", "/", &[], &[]).await;
    assert_eq!(r.status, 404);
    r.body().await;
    let (resp, frames) = unary(server.addr, LIST_BUSES, TEXT, &pb::ListBusesRequest {}, &[]).await;
    assert_eq!(grpc_status(&resp, &frames).0, 0);
    server.shutdown();
}

/// DNS rebinding: a page of `attacker.test` whose name is re-pointed at
/// the gateway's address calls it same-origin, but its requests name
/// `attacker.test`. Refused (gRPC-Web: PERMISSION_DENIED naming the
/// setting; the dashboard: 403) and nothing reaches the bus; loopback
/// names and `[web] allowed_hosts` are served, and native gRPC (which no
/// page can make) under any name.
#[tokio::test]
async fn browser_requests_for_a_foreign_host_are_refused() {
    let server = start_server(&format!(
        "[web]\nallowed_hosts = [\"gateway.example\"]\n{ONE_BUS}"
    ))
    .await;
    let mut device = server
        .gateway()
        .network()
        .get("can0")
        .unwrap()
        .connect(false);
    let send = |id: u32| pb::SendFramesRequest {
        bus: "can0".into(),
        frames: vec![pb::Frame {
            id,
            data: vec![0x42],
            ..Default::default()
        }],
    };
    const SEND: &str = "/cangate.v1.Bus/SendFrames";
    let port = server.addr.port();
    for ct in [PROTO, TEXT] {
        for host in ["attacker.test".to_string(), format!("attacker.test:{port}")] {
            let origin = format!("http://{host}");
            let (resp, frames) = unary(
                server.addr,
                SEND,
                ct,
                &send(0x1A2),
                &[("Host", &host), ("Origin", &origin)],
            )
            .await;
            let (code, message) = grpc_status(&resp, &frames);
            assert_eq!(
                code, 7,
                "{ct} {host}: PERMISSION_DENIED, got {code} {message}"
            );
            assert!(message.contains("[web] allowed_hosts"), "{message}");
        }
    }
    // Without Origin too (HTTP/1.1 is a browser's).
    let (resp, frames) = unary(
        server.addr,
        SEND,
        PROTO,
        &send(0x1A2),
        &[("Host", "attacker.test")],
    )
    .await;
    assert_eq!(grpc_status(&resp, &frames).0, 7);
    // The dashboard is not served under the foreign name either.
    let mut r = http(server.addr, "GET", "/", &[("Host", "attacker.test")], &[]).await;
    assert_eq!(r.status, 403);
    let body = String::from_utf8(r.body().await).unwrap();
    assert!(body.contains("allowed_hosts"), "{body}");
    // Loopback names and the configured name are served.
    for host in [
        format!("localhost:{port}"),
        format!("127.0.0.1:{port}"),
        "localhost".to_string(),
        format!("[::1]:{port}"),
        format!("gateway.example:{port}"),
    ] {
        let (resp, frames) =
            unary(server.addr, SEND, PROTO, &send(0x123), &[("Host", &host)]).await;
        assert_eq!(grpc_status(&resp, &frames).0, 0, "{host}");
    }
    // Native gRPC names any host: no page can make such a call.
    let channel = tonic::transport::Endpoint::from_shared(format!("http://{}", server.addr))
        .unwrap()
        .origin(format!("http://gateway.lan:{port}").parse().unwrap())
        .connect()
        .await
        .unwrap();
    pb::bus_client::BusClient::new(channel)
        .send_frames(send(0x124))
        .await
        .expect("native gRPC under its host name");
    // On the bus: the allowed ones only, none of the refused 0x1A2.
    let mut ids = Vec::new();
    while ids.len() < 6 {
        match tokio::time::timeout(WAIT, device.recv())
            .await
            .expect("frames on the bus")
        {
            cangate_can::PortEvent::Frame { frame, .. } => ids.push(frame.raw_id()),
            cangate_can::PortEvent::State(_) => {}
        }
    }
    assert_eq!(ids, [0x123, 0x123, 0x123, 0x123, 0x123, 0x124]);
    assert!(
        device.try_recv().is_none(),
        "a refused frame reached the bus"
    );
    server.shutdown();
}
