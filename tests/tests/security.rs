//! Security end to end: bearer tokens and roles, TLS with reload, mTLS
//! client names, per-client limits, the audit log. The real server
//! in-process, the real client; certificates are made here with rcgen.

use cangate_client::{ConnectOptions, pb};
use cangate_tests::*;
use std::path::{Path, PathBuf};
use std::time::Duration;
use tonic::Code;

/// A fresh directory for one test's files.
fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("cangate-security-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A test CA that signs server and client certificates.
struct Ca {
    params: rcgen::CertificateParams,
    key: rcgen::KeyPair,
    pem: String,
}

impl Ca {
    fn new(name: &str) -> Ca {
        let key = rcgen::KeyPair::generate().unwrap();
        let mut params = rcgen::CertificateParams::new(Vec::<String>::new()).unwrap();
        params.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
        params
            .distinguished_name
            .push(rcgen::DnType::CommonName, name);
        params.key_usages = vec![
            rcgen::KeyUsagePurpose::KeyCertSign,
            rcgen::KeyUsagePurpose::DigitalSignature,
        ];
        let pem = params.self_signed(&key).unwrap().pem();
        Ca { params, key, pem }
    }

    /// (certificate PEM, key PEM) for `cn`; a server certificate for
    /// `localhost` when `server`.
    fn issue(&self, cn: &str, server: bool) -> (String, String) {
        let key = rcgen::KeyPair::generate().unwrap();
        let sans = if server {
            vec!["localhost".to_string()]
        } else {
            vec![]
        };
        let mut params = rcgen::CertificateParams::new(sans).unwrap();
        params
            .distinguished_name
            .push(rcgen::DnType::CommonName, cn);
        params.extended_key_usages = vec![if server {
            rcgen::ExtendedKeyUsagePurpose::ServerAuth
        } else {
            rcgen::ExtendedKeyUsagePurpose::ClientAuth
        }];
        let issuer = rcgen::Issuer::from_params(&self.params, &self.key);
        let cert = params.signed_by(&key, &issuer).unwrap();
        (cert.pem(), key.serialize_pem())
    }
}

fn write(path: &Path, text: &str) {
    std::fs::write(path, text).unwrap();
}

/// Connects to the server with TLS options (server name `localhost`).
async fn tls_client(
    server: &cangate_server::RunningServer,
    options: ConnectOptions,
) -> Result<cangate_client::Client, cangate_client::Error> {
    let options = ConnectOptions {
        tls_domain: Some("localhost".into()),
        ..options
    };
    cangate_client::connect_with(&format!("https://{}", server.addr), &options).await
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

fn one_frame() -> Vec<cangate_client::can::Frame> {
    vec!["123#01".parse().unwrap()]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tokens_give_roles_and_refusals_name_them() {
    let config = format!(
        "{ONE_BUS}{}",
        tokens_toml(&[
            ("wall-display", "viewer", "v-token"),
            ("hmi-1", "operator", "o-token"),
            ("service-pc", "engineer", "e-token"),
        ])
    );
    let server = start_server(&config).await;

    // No token, a wrong token.
    let mut anon = client(&server).await;
    let e = anon.list_buses().await.unwrap_err();
    assert_eq!(e.code(), Some(Code::Unauthenticated), "{e}");
    assert!(e.to_string().contains("missing bearer token"), "{e}");
    // Refusals carry the richer error model's reason like every error.
    assert_eq!(e.reason().as_deref(), Some("UNAUTHENTICATED"), "{e:?}");
    let e = with_token(&server, "guess")
        .await
        .list_buses()
        .await
        .unwrap_err();
    assert_eq!(e.code(), Some(Code::Unauthenticated), "{e}");
    assert!(e.to_string().contains("unknown token"), "{e}");

    // A viewer reads, but may not send.
    let mut viewer = with_token(&server, "v-token").await;
    assert_eq!(viewer.list_buses().await.unwrap().len(), 1);
    let e = viewer.send("can0", &one_frame()).await.unwrap_err();
    assert_eq!(e.code(), Some(Code::PermissionDenied), "{e}");
    assert!(
        e.to_string().contains("needs role engineer")
            && e.to_string().contains("wall-display holds role viewer"),
        "{e}"
    );
    let e = viewer
        .axes_client()
        .acquire_control(pb::AcquireControlRequest {
            axes: vec!["X".into()],
            ttl_ms: 1000,
            client_name: "t".into(),
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");

    // An operator takes leases (here: no such axis, so NOT_FOUND from the
    // service, past the security layer) but may not send raw frames.
    let operator = with_token(&server, "o-token").await;
    let e = operator
        .axes_client()
        .acquire_control(pb::AcquireControlRequest {
            axes: vec!["X".into()],
            ttl_ms: 1000,
            client_name: "t".into(),
        })
        .await
        .unwrap_err();
    assert!(
        !matches!(e.code(), Code::PermissionDenied | Code::Unauthenticated),
        "{e:?}"
    );
    let e = operator
        .canopen_client()
        .send_nmt(pb::SendNmtRequest {
            bus: "can0".into(),
            node: 0,
            command: pb::NmtCommand::Start as i32,
            force: false,
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
    assert!(e.message().contains("holds role operator"), "{e:?}");

    // An engineer may do everything.
    let mut engineer = with_token(&server, "e-token").await;
    assert_eq!(engineer.send("can0", &one_frame()).await.unwrap(), 1);

    // Health and reflection are public.
    let mut health = tonic_health::pb::health_client::HealthClient::new(anon.channel());
    let r = health
        .check(tonic_health::pb::HealthCheckRequest {
            service: String::new(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(
        r.status,
        tonic_health::pb::health_check_response::ServingStatus::Serving as i32
    );
    let mut reflection =
        tonic_reflection::pb::v1::server_reflection_client::ServerReflectionClient::new(
            anon.channel(),
        );
    let req = tonic_reflection::pb::v1::ServerReflectionRequest {
        host: String::new(),
        message_request: Some(
            tonic_reflection::pb::v1::server_reflection_request::MessageRequest::ListServices(
                String::new(),
            ),
        ),
    };
    let mut s = reflection
        .server_reflection_info(tokio_stream::iter([req]))
        .await
        .unwrap()
        .into_inner();
    assert!(s.message().await.unwrap().is_some());

    // The CLI's hash is the configuration's (printf %s abc | sha256sum).
    assert_eq!(
        cangate_client::hash_token("abc"),
        "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
    );
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_serves_and_a_reload_changes_the_certificate_for_new_connections() {
    let dir = temp_dir("reload");
    let (ca1, ca2) = (Ca::new("CA one"), Ca::new("CA two"));
    let (cert, key) = ca1.issue("localhost", true);
    write(&dir.join("server.pem"), &cert);
    write(&dir.join("server.key"), &key);
    write(&dir.join("ca1.pem"), &ca1.pem);
    write(&dir.join("ca2.pem"), &ca2.pem);
    let config = format!(
        "{ONE_BUS}[security.tls]\ncert = \"{}\"\nkey = \"{}\"\n",
        dir.join("server.pem").display(),
        dir.join("server.key").display()
    );
    let server = start_server(&config).await;
    let trust = |ca: &str| ConnectOptions {
        ca: Some(dir.join(ca)),
        ..Default::default()
    };

    let mut old = tls_client(&server, trust("ca1.pem")).await.unwrap();
    assert_eq!(old.list_buses().await.unwrap().len(), 1);
    // Plaintext is not spoken any more, and the other CA is not trusted.
    let plain = cangate_client::connect(&format!("http://{}", server.addr)).await;
    if let Ok(mut c) = plain {
        c.list_buses().await.unwrap_err();
    }
    assert!(tls_client(&server, trust("ca2.pem")).await.is_err());

    // New certificate files (another CA), then the SIGHUP handler's call.
    let (cert, key) = ca2.issue("localhost", true);
    write(&dir.join("server.pem"), &cert);
    write(&dir.join("server.key"), &key);
    let reloader = server.tls_reloader().expect("TLS configured");
    reloader.reload().unwrap();
    let mut new = tls_client(&server, trust("ca2.pem")).await.unwrap();
    assert_eq!(new.list_buses().await.unwrap().len(), 1);
    assert!(tls_client(&server, trust("ca1.pem")).await.is_err());
    // The connection made before the reload, and the bus, are still there.
    assert_eq!(old.list_buses().await.unwrap().len(), 1);
    assert_eq!(old.send("can0", &one_frame()).await.unwrap(), 1);

    // A broken key fails the reload and keeps the configuration in use.
    write(&dir.join("server.key"), "not a key");
    let e = reloader.reload().unwrap_err();
    assert!(e.to_string().contains("server.key"), "{e}");
    let mut again = tls_client(&server, trust("ca2.pem")).await.unwrap();
    assert_eq!(again.list_buses().await.unwrap().len(), 1);
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mtls_maps_certificate_names_to_roles() {
    let dir = temp_dir("mtls");
    let ca = Ca::new("cell CA");
    let (cert, key) = ca.issue("localhost", true);
    write(&dir.join("server.pem"), &cert);
    write(&dir.join("server.key"), &key);
    write(&dir.join("ca.pem"), &ca.pem);
    for cn in ["hmi-2", "stranger"] {
        let (cert, key) = ca.issue(cn, false);
        write(&dir.join(format!("{cn}.pem")), &cert);
        write(&dir.join(format!("{cn}.key")), &key);
    }
    let config = format!(
        "{ONE_BUS}[security.tls]\ncert = \"{}\"\nkey = \"{}\"\nclient_ca = \"{}\"\n\
         require_client_cert = true\n\
         [[security.clients]]\nsubject_cn = \"hmi-2\"\nrole = \"operator\"\n",
        dir.join("server.pem").display(),
        dir.join("server.key").display(),
        dir.join("ca.pem").display(),
    );
    let server = start_server(&config).await;
    let as_client = |cn: &str| ConnectOptions {
        ca: Some(dir.join("ca.pem")),
        cert: Some(dir.join(format!("{cn}.pem"))),
        key: Some(dir.join(format!("{cn}.key"))),
        ..Default::default()
    };

    // A mapped name gets its role: reads, and is refused engineering.
    let mut hmi = tls_client(&server, as_client("hmi-2")).await.unwrap();
    assert_eq!(hmi.list_buses().await.unwrap().len(), 1);
    let e = hmi.send("can0", &one_frame()).await.unwrap_err();
    assert_eq!(e.code(), Some(Code::PermissionDenied), "{e}");
    assert!(e.to_string().contains("hmi-2 holds role operator"), "{e}");

    // A valid certificate with a name the gateway does not know: no role.
    let mut stranger = tls_client(&server, as_client("stranger")).await.unwrap();
    let e = stranger.list_buses().await.unwrap_err();
    assert_eq!(e.code(), Some(Code::PermissionDenied), "{e}");
    assert!(e.to_string().contains("\"stranger\" has no role"), "{e}");

    // No certificate: the handshake is refused (TLS 1.3 clients learn it
    // at their first call).
    let none = ConnectOptions {
        ca: Some(dir.join("ca.pem")),
        ..Default::default()
    };
    if let Ok(mut c) = tls_client(&server, none).await {
        c.list_buses().await.unwrap_err();
    }
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_rate_limit_refuses_one_client_and_not_the_others() {
    let config = format!(
        "{ONE_BUS}{}[security.limits]\nrequests_per_second_per_client = 1\nburst = 5\n",
        tokens_toml(&[("busy", "viewer", "busy"), ("calm", "viewer", "calm")])
    );
    let server = start_server(&config).await;
    let mut busy = with_token(&server, "busy").await;
    let mut calm = with_token(&server, "calm").await;
    for _ in 0..5 {
        busy.list_buses().await.unwrap();
    }
    let e = busy.list_buses().await.unwrap_err();
    assert_eq!(e.code(), Some(Code::ResourceExhausted), "{e}");
    assert_eq!(e.reason().as_deref(), Some("RATE_LIMIT"), "{e:?}");
    assert!(
        e.to_string().contains("rate limit") && e.to_string().contains("busy"),
        "{e}"
    );
    calm.list_buses().await.unwrap();
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stream_concurrency_and_message_size_limits() {
    let config = format!(
        "{ONE_BUS}[[canopen]]\nbus = \"can0\"\nsdo_timeout_ms = 1500\n\
         [[canopen.node]]\nid = 99\nname = \"absent\"\n{}\
         [security.limits]\nrequests_per_second_per_client = 0\nmax_streams_per_client = 2\n\
         max_concurrent_requests_per_client = 1\nmax_message_bytes = 1024\n",
        tokens_toml(&[
            ("watcher", "viewer", "w"),
            ("other", "viewer", "o"),
            ("slow", "viewer", "s")
        ])
    );
    let server = start_server(&config).await;

    // Streams: two open, the third refused; another client is unaffected;
    // closing one frees its slot.
    let mut watcher = with_token(&server, "w").await;
    let (first, _) = open_stream(&mut watcher, stream_request("can0", vec![])).await;
    let (_second, _) = open_stream(&mut watcher, stream_request("can0", vec![])).await;
    let e = watcher
        .stream_frames(stream_request("can0", vec![]))
        .await
        .unwrap_err();
    assert_eq!(e.code(), Some(Code::ResourceExhausted), "{e}");
    assert!(e.to_string().contains("stream limit"), "{e}");
    let mut other = with_token(&server, "o").await;
    let (_o, _) = open_stream(&mut other, stream_request("can0", vec![])).await;
    drop(first);
    let reopened = tokio::time::timeout(WAIT, async {
        loop {
            match watcher.stream_frames(stream_request("can0", vec![])).await {
                Ok(s) => return s,
                Err(e) => {
                    assert_eq!(e.code(), Some(Code::ResourceExhausted), "{e}");
                    // The server sees the reset of the dropped stream a
                    // moment later.
                    tokio::time::sleep(Duration::from_millis(20)).await;
                }
            }
        }
    })
    .await
    .expect("a closed stream frees its slot");
    drop(reopened);

    // Concurrency: while a slow call (an SDO read of a configured node
    // that is not on the bus, which times out) runs, the same client's next call is refused at once.
    let slow = with_token(&server, "s").await;
    let mut slow2 = slow.clone();
    let read = tokio::spawn(async move {
        slow.clone()
            .canopen_client()
            .read_sdo(pb::ReadSdoRequest {
                bus: "can0".into(),
                node: 99,
                index: 0x1000,
                subindex: 0,
                r#type: 0,
                options: None,
                object: String::new(),
            })
            .await
    });
    // Let the slow call be admitted first (it runs 1.5 s): a list_buses
    // in flight when it arrives would get it refused instead.
    tokio::time::sleep(Duration::from_millis(300)).await;
    let refused = tokio::time::timeout(WAIT, async {
        loop {
            match slow2.list_buses().await {
                Ok(_) => tokio::task::yield_now().await,
                Err(e) => return e,
            }
        }
    })
    .await
    .expect("refused while the slow call runs");
    assert_eq!(refused.code(), Some(Code::ResourceExhausted), "{refused}");
    assert!(
        refused.to_string().contains("concurrency limit"),
        "{refused}"
    );
    let r = read.await.unwrap().unwrap_err();
    assert_eq!(r.code(), Code::DeadlineExceeded, "{r:?}");
    slow2.list_buses().await.unwrap();

    // Message size: a request over max_message_bytes.
    let e = other.get_bus(&"x".repeat(2000)).await.unwrap_err();
    assert_eq!(e.code(), Some(Code::ResourceExhausted), "{e}");
    assert!(e.to_string().contains("max_message_bytes = 1024"), "{e}");
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn state_changing_calls_and_refusals_are_audited() {
    let captured = cangate_tests::log::capture_log("cangate::audit=info");
    let config = format!(
        "{ONE_BUS}{}",
        tokens_toml(&[
            ("audit-eng", "engineer", "e"),
            ("audit-viewer", "viewer", "v")
        ])
    );
    let server = start_server(&config).await;
    let mut eng = with_token(&server, "e").await;
    let mut viewer = with_token(&server, "v").await;
    eng.send("can0", &one_frame()).await.unwrap();
    eng.list_buses().await.unwrap();
    viewer.send("can0", &one_frame()).await.unwrap_err();
    let text = captured.text();
    let lines: Vec<&str> = text.lines().collect();
    let sent = lines
        .iter()
        .find(|l| l.contains("who=audit-eng") && l.contains("/cangate.v1.Bus/SendFrames"))
        .unwrap_or_else(|| panic!("no audit line for the engineer's send in:\n{text}"));
    assert!(
        sent.contains("cangate::audit") && sent.contains("OK") && sent.contains("peer=127.0.0.1"),
        "{sent}"
    );
    assert!(
        !lines
            .iter()
            .any(|l| l.contains("who=audit-eng") && l.contains("ListBuses")),
        "reads are not audited:\n{text}"
    );
    let denied = lines
        .iter()
        .find(|l| l.contains("who=audit-viewer"))
        .unwrap_or_else(|| panic!("no audit line for the refusal in:\n{text}"));
    assert!(
        denied.contains("PERMISSION_DENIED") && denied.contains("SendFrames"),
        "{denied}"
    );
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lease_holder_names_the_authenticated_identity() {
    let config = format!(
        r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"

[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true

[[axis]]
name = "X"
bus = "can0"
node = 1
counts_per_unit = 1000.0
max_velocity = 10.0
max_acceleration = 100.0
{}"#,
        tokens_toml(&[("hmi-1", "operator", "o-token")])
    );
    let server = start_server(&config).await;
    let operator = with_token(&server, "o-token").await;
    let lease = operator
        .axes_client()
        .acquire_control(pb::AcquireControlRequest {
            axes: vec!["X".into()],
            ttl_ms: 1000,
            client_name: "panel".into(),
        })
        .await
        .unwrap()
        .into_inner();
    // The client's own name, then who the token says it is and from where:
    // what an HMI showing "controlled by" and the audit log need.
    assert!(
        lease.holder.starts_with("panel (hmi-1@127.0.0.1:"),
        "{}",
        lease.holder
    );
}

/// A viewer token cannot stop axes, unless `[security] viewers_may_stop`
/// is on (a wall-mounted status panel's STOP ALL); then it can stop, and
/// only stop. GetCaller tells the page which.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn viewers_stop_axes_only_where_the_configuration_lets_them() {
    let tokens = tokens_toml(&[("wall-panel", "viewer", "v"), ("hmi", "operator", "o")]);
    for allowed in [false, true] {
        let config = format!("{ONE_BUS}[security]\nviewers_may_stop = {allowed}\n{tokens}");
        let server = start_server(&config).await;
        let viewer = with_token(&server, "v").await;
        let caller = viewer.caller().await.expect("GetCaller");
        assert_eq!(caller.may_stop, allowed, "{caller:?}");
        let operator = with_token(&server, "o").await;
        assert!(operator.caller().await.expect("GetCaller").may_stop);
        let mut axes = viewer.axes_client();
        // No such axis here: past the security layer, a stop is NOT_FOUND.
        let stop = axes
            .stop_axes(pb::StopAxesRequest {
                axes: vec!["X".into()],
                ..Default::default()
            })
            .await
            .unwrap_err();
        let quick = axes
            .quick_stop(pb::AxisCommandRequest {
                axis: "X".into(),
                ..Default::default()
            })
            .await
            .unwrap_err();
        for e in [&stop, &quick] {
            if allowed {
                assert_eq!(e.code(), Code::NotFound, "{e:?}");
            } else {
                assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
                assert!(e.message().contains("needs role operator"), "{e:?}");
            }
        }
        // Moving stays an operator's.
        let e = axes
            .r#move(pb::MoveRequest {
                axis: "X".into(),
                target: 1.0,
                ..Default::default()
            })
            .await
            .unwrap_err();
        assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
    }
}
