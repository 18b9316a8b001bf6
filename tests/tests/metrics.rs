//! The Prometheus endpoint: after some traffic the named series are there
//! with the right values.

use cangate_client::pb;
use cangate_tests::*;

const CONFIG: &str = r#"
metrics_listen = "127.0.0.1:0"

[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"

[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true
heartbeat_timeout_ms = 300
"#;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_endpoint_exposes_bus_and_sdo_series() {
    let server = start_server(CONFIG).await;
    let addr = server.metrics_addr.expect("metrics configured");
    let mut c = client(&server).await;
    // Traffic: two SDO reads (one ok, one aborted: no such object) and a
    // frame.
    c.read_sdo(pb::ReadSdoRequest {
        bus: "can0".into(),
        node: 1,
        index: 0x1000,
        subindex: 0,
        r#type: 0,
        options: None,
        object: String::new(),
    })
    .await
    .unwrap();
    c.read_sdo(pb::ReadSdoRequest {
        bus: "can0".into(),
        node: 1,
        index: 0x5FFF,
        subindex: 0,
        r#type: 0,
        options: None,
        object: String::new(),
    })
    .await
    .unwrap_err();
    c.send("can0", &["123#01".parse().unwrap()]).await.unwrap();
    // A refused batch: its frame is counted by reason.
    let bad = pb::Frame {
        id: 0x800,
        ..Default::default()
    };
    c.send_pb("can0", vec![bad]).await.unwrap_err();
    let text = http_get(addr, "/metrics").await;
    assert!(text.starts_with("HTTP/1.1 200 OK"), "{text}");
    for series in [
        "cangate_bus_frames_total{bus=\"can0\",direction=\"rx\"}",
        "cangate_bus_frames_total{bus=\"can0\",direction=\"tx\"}",
        "cangate_bus_up{bus=\"can0\"} 1",
        "cangate_bus_load_percent{bus=\"can0\"}",
        "cangate_bus_stream_drops_total{bus=\"can0\"}",
        "cangate_client_frames_refused_total{bus=\"can0\",reason=\"INVALID_FRAME\"} 1",
        "cangate_sdo_requests_total{bus=\"can0\",node=\"1\",result=\"ok\"}",
        "cangate_sdo_requests_total{bus=\"can0\",node=\"1\",result=\"aborted_by_node\"}",
        "cangate_sdo_duration_seconds_bucket{bus=\"can0\",node=\"1\",le=\"0.001\"}",
        "# HELP cangate_sdo_duration_seconds",
        "cangate_rpc_requests_total{method=\"/cangate.v1.Canopen/ReadSdo\",code=\"OK\"}",
        "cangate_rpc_requests_total{method=\"/cangate.v1.Canopen/ReadSdo\",code=\"NOT_FOUND\"}",
    ] {
        assert!(text.contains(series), "missing {series} in:\n{text}");
    }
    let tx: f64 = text
        .lines()
        .find(|l| l.starts_with("cangate_bus_frames_total{bus=\"can0\",direction=\"tx\"}"))
        .and_then(|l| l.rsplit(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap();
    assert!(tx >= 3.0, "two SDO requests and a frame were sent: {tx}");
    assert!(http_get(addr, "/nope").await.starts_with("HTTP/1.1 404"));
}

const CANSMC_CONFIG: &str = r#"
metrics_listen = "127.0.0.1:0"

[[bus]]
name = "smc0"
backend = "virtual"

[[bus]]
name = "smc1"
backend = "virtual"

[[cansmc]]
name = "m"
command_bus = "smc0"
status_bus = "smc1"
cycle_time_us = 4000
lost_after = 50

[[cansmc.slave]]
address = 1
simulate = true

[[cansmc.slave]]
address = 2
simulate = true
"#;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_endpoint_exposes_cansmc_cycle_series() {
    let server = start_server(CANSMC_CONFIG).await;
    let addr = server.metrics_addr.expect("metrics configured");
    let master = server.gateway().cansmc("m").unwrap().clone();
    let deadline = tokio::time::Instant::now() + WAIT;
    while master.status().slaves.iter().any(|s| s.counters.dts < 10) {
        assert!(
            tokio::time::Instant::now() < deadline,
            "no DTs: {:?}",
            master.status()
        );
        tokio::time::sleep(std::time::Duration::from_millis(20)).await;
    }
    let text = http_get(addr, "/metrics").await;
    for series in [
        "cangate_cansmc_phase{master=\"m\"} 3",
        "cangate_cansmc_cycles_total{master=\"m\"}",
        "cangate_cansmc_overruns_total{master=\"m\"}",
        "cangate_cansmc_mst_jitter_us{master=\"m\",quantile=\"0.99\"}",
        "cangate_cansmc_dts_total{master=\"m\",slave=\"2\",result=\"missed\"}",
        "cangate_cansmc_slave_losses_total{master=\"m\",slave=\"1\"}",
    ] {
        assert!(text.contains(series), "missing {series} in:\n{text}");
    }
    let valid: f64 = text
        .lines()
        .find(|l| {
            l.starts_with("cangate_cansmc_dts_total{master=\"m\",slave=\"1\",result=\"valid\"}")
        })
        .and_then(|l| l.rsplit(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap();
    assert!(valid >= 10.0, "{valid}");
}

const PDO_CONFIG: &str = r#"
metrics_listen = "127.0.0.1:0"

[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"
sync_period_us = 5000

[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true
heartbeat_timeout_ms = 1000

[[axis]]
name = "X"
bus = "can0"
node = 1
counts_per_unit = 1000.0
max_velocity = 100.0
max_acceleration = 1000.0
"#;

/// The value of the first series line starting with `prefix`.
fn value(text: &str, prefix: &str) -> Option<f64> {
    text.lines()
        .find(|l| l.starts_with(prefix))
        .and_then(|l| l.rsplit(' ').next())
        .and_then(|v| v.parse().ok())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_endpoint_counts_received_pdos() {
    let server = start_server(PDO_CONFIG).await;
    let addr = server.metrics_addr.expect("metrics configured");
    let series = "cangate_pdo_received_total{bus=\"can0\",node=\"1\",pdo=\"1\"}";
    let deadline = tokio::time::Instant::now() + WAIT;
    let first = loop {
        let text = http_get(addr, "/metrics").await;
        match value(&text, series) {
            Some(v) if v > 0.0 => break v,
            _ => {}
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "no {series}:\n{text}"
        );
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    };
    // TPDO1 comes every SYNC (5 ms): the count grows.
    tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    let text = http_get(addr, "/metrics").await;
    let later = value(&text, series).unwrap();
    assert!(later > first, "{first} -> {later}");
    // The SYNC producer's counters: at 5 ms, well over 20 SYNCs by now;
    // the skipped count is there (0 or a few on a busy machine).
    let sent = value(&text, "cangate_sync_sent_total{bus=\"can0\"}").expect("SYNC counter");
    assert!(sent >= 20.0, "{sent}");
    assert!(
        value(&text, "cangate_sync_skipped_total{bus=\"can0\"}").is_some(),
        "{text}"
    );
}
