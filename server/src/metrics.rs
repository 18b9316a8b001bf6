//! Prometheus metrics: the `metrics` facade with the Prometheus text
//! renderer, served by a minimal HTTP/1 endpoint of our own (`GET
//! /metrics`) on `metrics_listen`.
//!
//! Two kinds of series:
//! - counted where things happen (SDO requests, aborts, timeouts and their
//!   latency; heartbeat losses; EMCYs);
//! - read from the gateway's live state at each scrape (bus frames, errors,
//!   load, state, stream drops; handwheel feed statistics and binding drops;
//!   axis faults and node loss), so they are always exact.

use crate::gateway::Gateway;
use metrics_exporter_prometheus::{Matcher, PrometheusBuilder, PrometheusHandle};
use std::net::SocketAddr;
use std::sync::{Arc, OnceLock};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_util::sync::CancellationToken;

static HANDLE: OnceLock<PrometheusHandle> = OnceLock::new();

/// The process-wide recorder (installed on first use; the metrics facade
/// has one global recorder per process).
pub fn handle() -> &'static PrometheusHandle {
    HANDLE.get_or_init(|| {
        let builder = PrometheusBuilder::new()
            .set_buckets_for_metric(
                Matcher::Suffix("duration_seconds".into()),
                &[
                    0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25,
                    0.5, 1.0,
                ],
            )
            .expect("static buckets are valid");
        let recorder = builder.build_recorder();
        let handle = recorder.handle();
        // Another recorder may be installed already (a host application);
        // then ours still renders what it is given.
        let _ = metrics::set_global_recorder(recorder);
        describe();
        handle
    })
}

fn describe() {
    use metrics::{describe_counter, describe_gauge, describe_histogram};
    describe_counter!(
        "cangate_bus_frames_total",
        "Frames received (rx) and sent (tx) per bus."
    );
    describe_counter!(
        "cangate_bus_error_frames_total",
        "Error frames seen per bus."
    );
    describe_counter!(
        "cangate_bus_tx_failed_total",
        "Frames the bus refused to send."
    );
    describe_counter!(
        "cangate_bus_tx_retries_total",
        "Frames a SocketCAN interface refused for a full transmit queue (ENOBUFS) and the gateway offered again."
    );
    describe_gauge!(
        "cangate_bus_tx_queued",
        "Own frames waiting for room in a SocketCAN interface's transmit queue."
    );
    describe_counter!(
        "cangate_bus_rx_overflows_total",
        "Frames lost before the gateway read them (receive queue or SocketCAN receive buffer full), reported to every stream as lost."
    );
    describe_counter!(
        "cangate_client_frames_refused_total",
        "Client raw frames (SendFrames, Attach) not sent because their batch was refused, by bus and reason (FRAME_RATE_LIMIT, BUS_BUDGET_EXHAUSTED, INVALID_FRAME, BUS_OFF, ...)."
    );
    describe_counter!(
        "cangate_client_frames_withdrawn_total",
        "Client raw frames not sent because their sender gave the batch up first (a cancelled SendFrames, a closed Attach stream)."
    );
    describe_counter!(
        "cangate_bus_stream_drops_total",
        "Frames dropped for slow stream subscribers (each reported to them as lost)."
    );
    describe_counter!(
        "cangate_stream_messages_held_total",
        "Frame-stream messages of a few events that waited for more, after the stream's small-message burst, per bus (a reader can ask for low_latency)."
    );
    describe_gauge!(
        "cangate_bus_load_percent",
        "Bus load in percent of the bitrate."
    );
    describe_gauge!(
        "cangate_bus_up",
        "1 when the bus carries frames (up, error warning or error passive)."
    );
    describe_counter!(
        "cangate_sdo_requests_total",
        "SDO transfers by bus, node and result."
    );
    describe_histogram!(
        "cangate_sdo_duration_seconds",
        "SDO transfer latency by bus and node."
    );
    describe_counter!(
        "cangate_lss_commands_total",
        "LSS (CiA 305) commands by bus, command and result (ok, timeout, refused, protocol_error, busy, invalid)."
    );
    describe_counter!(
        "cangate_heartbeat_lost_total",
        "Heartbeat losses by bus and node."
    );
    describe_counter!("cangate_emcy_total", "EMCY messages by bus and node.");
    describe_counter!(
        "cangate_handwheel_frames_total",
        "Feed frames per handwheel."
    );
    describe_counter!(
        "cangate_handwheel_gaps_total",
        "Feed frames that followed lost ones."
    );
    describe_counter!(
        "cangate_handwheel_compensated_units_total",
        "Units compensated for lost frames."
    );
    describe_counter!(
        "cangate_handwheel_duplicates_total",
        "Repeated feed frames (not moved)."
    );
    describe_counter!(
        "cangate_handwheel_bad_frames_total",
        "Feed frames with an invalid axis or length."
    );
    describe_counter!(
        "cangate_handwheel_dropped_units_total",
        "Units a binding dropped, by reason."
    );
    describe_gauge!(
        "cangate_axis_fault",
        "1 while the axis is in fault or its node is lost."
    );
    describe_counter!(
        "cangate_rpc_requests_total",
        "gRPC calls by method and status code."
    );
    describe_counter!(
        "cangate_stream_lag_drops_total",
        "Items gRPC stream subscribers missed because they were too slow, by stream (bus frame streams: cangate_bus_stream_drops_total)."
    );
    describe_counter!(
        "cangate_pdo_received_total",
        "TPDOs received by bus, node and PDO number (rate() gives the PDO rate)."
    );
    describe_counter!(
        "cangate_sync_sent_total",
        "SYNC frames sent by the CANopen master, by bus."
    );
    describe_counter!(
        "cangate_sync_skipped_total",
        "SYNC periods without a SYNC, by bus: the SYNC thread woke too late for them, or the bus's queue was full."
    );
    describe_counter!(
        "cangate_cansmc_cycles_total",
        "CANsmc cycles started (MSTs sent), by master."
    );
    describe_counter!(
        "cangate_cansmc_overruns_total",
        "CANsmc cycles skipped because the cycle thread woke more than a cycle late."
    );
    describe_gauge!(
        "cangate_cansmc_phase",
        "CANsmc master phase: 0 idle, 1 P0, 2 P1, 3 P2, -1 start failed."
    );
    describe_gauge!(
        "cangate_cansmc_mst_jitter_us",
        "MST start lateness since P2 began, by master and quantile (0.5, 0.99, 0.999, 1 = max)."
    );
    describe_counter!(
        "cangate_cansmc_dts_total",
        "Drive telegrams by master, slave and result (valid, missed, late, counter_mismatch, reject)."
    );
    describe_counter!(
        "cangate_cansmc_slave_losses_total",
        "Times a CANsmc slave was declared lost."
    );
    describe_gauge!(
        "cangate_socketcand_connections",
        "Open connections of the socketcand endpoint."
    );
    describe_counter!(
        "cangate_socketcand_sessions_total",
        "socketcand connections by outcome (opened, refused_auth, refused_limit, refused_bus, too_many_connections, handshake_timeout)."
    );
    describe_counter!(
        "cangate_socketcand_frames_total",
        "Frames through the socketcand endpoint by bus and direction (in: sent by clients, out: reported to clients)."
    );
    describe_counter!(
        "cangate_socketcand_frames_lost_total",
        "Frames socketcand clients missed because they read too slowly, by bus."
    );
    describe_gauge!(
        "cangate_cia309_connections",
        "Open connections of the CiA 309-3 ASCII gateway."
    );
    describe_counter!(
        "cangate_cia309_sessions_total",
        "CiA 309-3 connections by outcome (opened, refused_auth, refused_limit, too_many_connections, evicted_before_login, handshake_timeout)."
    );
    describe_counter!(
        "cangate_cia309_commands_total",
        "CiA 309-3 commands by command (read, write, nmt, lss, events, info, login, too_long) and result (ok, error, refused)."
    );
    describe_counter!(
        "cangate_cia309_events_lost_total",
        "Event lines CiA 309-3 clients missed because they read too slowly, by bus."
    );
    describe_counter!(
        "cangate_socketcand_command_errors_total",
        "socketcand commands answered with an error, by kind (unknown, syntax, not_supported, too_long)."
    );
    describe_counter!(
        "cangate_bridge_published_total",
        "Messages a bridge wrote to its broker, by bridge and format (QoS 0 when written, QoS 1 when acknowledged)."
    );
    describe_counter!(
        "cangate_bridge_acknowledged_total",
        "QoS 1 messages the broker acknowledged, by bridge and format."
    );
    describe_gauge!(
        "cangate_bridge_queued",
        "Messages a bridge holds (waiting, and sent but not yet acknowledged), by bridge and format."
    );
    describe_counter!(
        "cangate_bridge_gap_messages_total",
        "Messages a bridge did not publish (each covered by a gap record), by bridge, format and reason (queue_full, source_lagged)."
    );
    describe_gauge!(
        "cangate_bridge_connected",
        "1 while a bridge is connected to its broker, by bridge and format."
    );
}

/// Counts `n` client raw frames of a refused (or part-sent) `SendFrames`
/// or `Attach` batch that were not sent, by bus and reason (the client
/// itself is told by the refusal).
pub fn client_frames_refused(bus: &str, reason: String, n: u64) {
    metrics::counter!(
        "cangate_client_frames_refused_total",
        "bus" => bus.to_string(),
        "reason" => reason
    )
    .increment(n);
}

/// One more (`+1`) or one fewer (`-1`) open socketcand connection.
pub fn socketcand_connections(delta: f64) {
    metrics::gauge!("cangate_socketcand_connections").increment(delta);
}

/// A socketcand connection's outcome (see the metric's description).
pub fn socketcand_session(result: &'static str) {
    metrics::counter!("cangate_socketcand_sessions_total", "result" => result).increment(1);
}

/// `n` frames through the socketcand endpoint (`in` or `out`).
pub fn socketcand_frames(bus: &str, direction: &'static str, n: u64) {
    metrics::counter!(
        "cangate_socketcand_frames_total",
        "bus" => bus.to_string(),
        "direction" => direction
    )
    .increment(n);
}

/// `n` frames a slow socketcand client missed.
pub fn socketcand_lost(bus: &str, n: u64) {
    metrics::counter!("cangate_socketcand_frames_lost_total", "bus" => bus.to_string())
        .increment(n);
}

/// A socketcand command answered with an error.
pub fn socketcand_command_error(kind: &'static str) {
    metrics::counter!("cangate_socketcand_command_errors_total", "kind" => kind).increment(1);
}

/// One more (`+1`) or one fewer (`-1`) open CiA 309-3 connection.
pub fn cia309_connections(delta: f64) {
    metrics::gauge!("cangate_cia309_connections").increment(delta);
}

/// A CiA 309-3 connection's outcome (see the metric's description).
pub fn cia309_session(result: &'static str) {
    metrics::counter!("cangate_cia309_sessions_total", "result" => result).increment(1);
}

/// A CiA 309-3 command and its result (`ok`, `error`, `refused`).
pub fn cia309_command(command: &'static str, result: &'static str) {
    metrics::counter!("cangate_cia309_commands_total", "command" => command, "result" => result)
        .increment(1);
}

/// `n` event lines a slow CiA 309-3 client missed.
pub fn cia309_events_lost(bus: &str, n: u64) {
    metrics::counter!("cangate_cia309_events_lost_total", "bus" => bus.to_string()).increment(n);
}

/// The labels of one bridge connection (bridge name, format).
fn bridge_labels(bridge: &str, format: &'static str) -> [(&'static str, String); 2] {
    [
        ("bridge", bridge.to_string()),
        ("format", format.to_string()),
    ]
}

/// `written` messages a bridge published at QoS 0 and `acknowledged` at
/// QoS 1 that its broker acknowledged.
pub fn bridge_settled(bridge: &str, format: &'static str, written: u64, acknowledged: u64) {
    let labels = bridge_labels(bridge, format);
    metrics::counter!("cangate_bridge_published_total", &labels).increment(written + acknowledged);
    metrics::counter!("cangate_bridge_acknowledged_total", &labels).increment(acknowledged);
}

/// The messages a bridge holds now.
pub fn bridge_queued(bridge: &str, format: &'static str, n: usize) {
    metrics::gauge!("cangate_bridge_queued", &bridge_labels(bridge, format)).set(n as f64);
}

/// `n` messages a bridge did not publish, recorded in a gap.
pub fn bridge_gap(bridge: &str, format: &'static str, reason: &'static str, n: u64) {
    let [b, f] = bridge_labels(bridge, format);
    metrics::counter!(
        "cangate_bridge_gap_messages_total",
        &[b, f, ("reason", reason.to_string())]
    )
    .increment(n);
}

/// Whether a bridge is connected to its broker.
pub fn bridge_connected(bridge: &str, format: &'static str, up: bool) {
    metrics::gauge!("cangate_bridge_connected", &bridge_labels(bridge, format)).set(if up {
        1.0
    } else {
        0.0
    });
}

/// Counts `n` items a gRPC stream subscriber missed because it was too
/// slow (the stream itself tells the client how many).
pub fn stream_lag(stream: &'static str, n: u64) {
    metrics::counter!("cangate_stream_lag_drops_total", "stream" => stream).increment(n);
}

/// Refreshes the series read from live state.
fn refresh(gateway: &Gateway) {
    use metrics::{counter, gauge};
    for bus in gateway.buses() {
        let name = bus.name().to_string();
        let s = bus.stats();
        counter!("cangate_bus_frames_total", "bus" => name.clone(), "direction" => "rx")
            .absolute(s.rx_frames);
        counter!("cangate_bus_frames_total", "bus" => name.clone(), "direction" => "tx")
            .absolute(s.tx_frames);
        counter!("cangate_bus_error_frames_total", "bus" => name.clone()).absolute(s.error_frames);
        counter!("cangate_bus_tx_failed_total", "bus" => name.clone()).absolute(s.tx_failed);
        counter!("cangate_bus_stream_drops_total", "bus" => name.clone())
            .absolute(s.subscriber_drops);
        counter!("cangate_bus_tx_retries_total", "bus" => name.clone()).absolute(s.tx_retries);
        gauge!("cangate_bus_tx_queued", "bus" => name.clone()).set(s.tx_queued as f64);
        counter!("cangate_bus_rx_overflows_total", "bus" => name.clone()).absolute(s.rx_overflows);
        counter!("cangate_client_frames_withdrawn_total", "bus" => name.clone())
            .absolute(s.client_frames_withdrawn);
        gauge!("cangate_bus_load_percent", "bus" => name.clone()).set(s.load_percent);
        let up = matches!(
            bus.status().state,
            cangate_can::BusState::Up
                | cangate_can::BusState::ErrorWarning
                | cangate_can::BusState::ErrorPassive
        );
        gauge!("cangate_bus_up", "bus" => name).set(if up { 1.0 } else { 0.0 });
    }
    let wheels = gateway.handwheels();
    for i in 0..wheels.len() {
        let w = wheels.wheel(i);
        let name = w.config.name.clone();
        let s = w.stats.lock().expect("stats lock").clone();
        counter!("cangate_handwheel_frames_total", "handwheel" => name.clone()).absolute(s.frames);
        counter!("cangate_handwheel_gaps_total", "handwheel" => name.clone()).absolute(s.gaps);
        counter!("cangate_handwheel_compensated_units_total", "handwheel" => name.clone())
            .absolute(s.compensated_units);
        counter!("cangate_handwheel_duplicates_total", "handwheel" => name.clone())
            .absolute(s.duplicates);
        counter!("cangate_handwheel_bad_frames_total", "handwheel" => name.clone())
            .absolute(s.bad_frames);
        let b = w.binding.lock().expect("binding lock").clone();
        for (reason, v) in [
            ("backlog", b.dropped_backlog),
            ("not_manual", b.dropped_not_manual),
            ("not_enabled", b.dropped_not_enabled),
            ("not_controlled", b.dropped_not_controlled),
            ("unbound", b.dropped_unbound),
        ] {
            counter!("cangate_handwheel_dropped_units_total", "handwheel" => name.clone(), "reason" => reason)
                .absolute(v);
        }
    }
    for master in gateway.canopen_buses() {
        if master.sync_cob_id().is_some() {
            let (sent, skipped) = master.sync_counts();
            counter!("cangate_sync_sent_total", "bus" => master.bus().to_string()).absolute(sent);
            counter!("cangate_sync_skipped_total", "bus" => master.bus().to_string())
                .absolute(skipped);
        }
        for (node, num, n) in master.tpdo_counts() {
            counter!("cangate_pdo_received_total", "bus" => master.bus().to_string(), "node" => node.get().to_string(), "pdo" => num.to_string())
                .absolute(n);
        }
    }
    for m in gateway.cansmc_masters() {
        let name = m.name().to_string();
        let st = m.status();
        counter!("cangate_cansmc_cycles_total", "master" => name.clone())
            .absolute(st.counters.cycles);
        counter!("cangate_cansmc_overruns_total", "master" => name.clone())
            .absolute(st.counters.overruns);
        use cangate_cansmc::master::Phase;
        gauge!("cangate_cansmc_phase", "master" => name.clone()).set(match st.phase {
            Phase::Idle => 0.0,
            Phase::Connecting => 1.0,
            Phase::Parameterising => 2.0,
            Phase::Cyclic => 3.0,
            Phase::Failed => -1.0,
        });
        for (q, v) in [
            ("0.5", st.jitter.p50_us),
            ("0.99", st.jitter.p99_us),
            ("0.999", st.jitter.p999_us),
            ("1", st.jitter.max_us),
        ] {
            gauge!("cangate_cansmc_mst_jitter_us", "master" => name.clone(), "quantile" => q)
                .set(v);
        }
        for s in &st.slaves {
            let slave = s.address.to_string();
            let c = s.counters;
            for (result, v) in [
                ("valid", c.dts),
                ("missed", c.missed),
                ("late", c.late),
                ("counter_mismatch", c.counter_mismatch),
                ("reject", c.rejects),
            ] {
                counter!("cangate_cansmc_dts_total", "master" => name.clone(), "slave" => slave.clone(), "result" => result)
                    .absolute(v);
            }
            counter!("cangate_cansmc_slave_losses_total", "master" => name.clone(), "slave" => slave)
                .absolute(c.losses);
        }
    }
    let axes = gateway.axes();
    for i in 0..axes.len() {
        let fault = axes
            .latest(i)
            .is_none_or(|(s, _)| s.fault.is_some() || s.node_lost.is_some());
        metrics::gauge!("cangate_axis_fault", "axis" => axes.name(i).to_string()).set(if fault {
            1.0
        } else {
            0.0
        });
    }
}

/// Serves `GET /metrics` on `addr` until `cancel` fires; returns the bound
/// address.
pub async fn serve(
    addr: SocketAddr,
    gateway: Arc<Gateway>,
    cancel: CancellationToken,
) -> std::io::Result<SocketAddr> {
    let listener = tokio::net::TcpListener::bind(addr).await?;
    let local = listener.local_addr()?;
    let handle = handle();
    tokio::spawn(async move {
        loop {
            let (mut sock, _) = tokio::select! {
                _ = cancel.cancelled() => return,
                a = listener.accept() => match a {
                    Ok(a) => a,
                    Err(_) => continue,
                },
            };
            let gateway = gateway.clone();
            tokio::spawn(async move {
                // One request per connection, bounded in size and time.
                let mut buf = Vec::with_capacity(1024);
                let read = tokio::time::timeout(Duration::from_secs(5), async {
                    let mut chunk = [0u8; 1024];
                    while !buf.windows(4).any(|w| w == b"\r\n\r\n") && buf.len() < 8192 {
                        let n = sock.read(&mut chunk).await?;
                        if n == 0 {
                            break;
                        }
                        buf.extend_from_slice(&chunk[..n]);
                    }
                    Ok::<_, std::io::Error>(())
                })
                .await;
                if !matches!(read, Ok(Ok(()))) {
                    return;
                }
                let line = buf.split(|b| *b == b'\n').next().unwrap_or_default();
                let (status, ctype, body) =
                    if line.starts_with(b"GET /metrics ") || line.starts_with(b"GET / ") {
                        refresh(&gateway);
                        (
                            "200 OK",
                            "text/plain; version=0.0.4; charset=utf-8",
                            handle.render(),
                        )
                    } else {
                        (
                            "404 Not Found",
                            "text/plain; charset=utf-8",
                            "GET /metrics\n".to_string(),
                        )
                    };
                let head = format!(
                    "HTTP/1.1 {status}\r\nContent-Type: {ctype}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
                    body.len()
                );
                let _ = sock.write_all(head.as_bytes()).await;
                let _ = sock.write_all(body.as_bytes()).await;
                let _ = sock.shutdown().await;
            });
        }
    });
    Ok(local)
}

/// A tower layer counting every gRPC call by method and status code
/// (`cangate_rpc_requests_total`). The code is the one in the response
/// headers (errors returned at once, "trailers-only"); calls whose status
/// comes in the trailers (successes, and errors ending a stream) count as
/// `OK`, as their headers promise no error.
#[derive(Debug, Clone, Copy, Default)]
pub struct RpcMetricsLayer;

impl<S> tower::Layer<S> for RpcMetricsLayer {
    type Service = RpcMetrics<S>;
    fn layer(&self, inner: S) -> Self::Service {
        RpcMetrics { inner }
    }
}

/// See [`RpcMetricsLayer`].
#[derive(Debug, Clone)]
pub struct RpcMetrics<S> {
    inner: S,
}

impl<S, B, RB> tower::Service<http::Request<B>> for RpcMetrics<S>
where
    S: tower::Service<http::Request<B>, Response = http::Response<RB>>,
    S::Future: Send + 'static,
    S::Error: 'static,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = std::pin::Pin<
        Box<dyn std::future::Future<Output = Result<Self::Response, Self::Error>> + Send>,
    >;

    fn poll_ready(
        &mut self,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, req: http::Request<B>) -> Self::Future {
        let method = req.uri().path().to_string();
        let fut = self.inner.call(req);
        Box::pin(async move {
            let r = fut.await;
            if let Ok(resp) = &r {
                let code = resp
                    .headers()
                    .get("grpc-status")
                    .and_then(|v| v.to_str().ok())
                    .and_then(|v| v.parse::<i32>().ok())
                    .map_or("OK", |c| code_name(tonic::Code::from(c)));
                metrics::counter!("cangate_rpc_requests_total", "method" => method, "code" => code)
                    .increment(1);
            }
            r
        })
    }
}

/// The canonical upper-case name of a gRPC status code.
pub(crate) fn code_name(c: tonic::Code) -> &'static str {
    use tonic::Code as C;
    match c {
        C::Ok => "OK",
        C::Cancelled => "CANCELLED",
        C::Unknown => "UNKNOWN",
        C::InvalidArgument => "INVALID_ARGUMENT",
        C::DeadlineExceeded => "DEADLINE_EXCEEDED",
        C::NotFound => "NOT_FOUND",
        C::AlreadyExists => "ALREADY_EXISTS",
        C::PermissionDenied => "PERMISSION_DENIED",
        C::ResourceExhausted => "RESOURCE_EXHAUSTED",
        C::FailedPrecondition => "FAILED_PRECONDITION",
        C::Aborted => "ABORTED",
        C::OutOfRange => "OUT_OF_RANGE",
        C::Unimplemented => "UNIMPLEMENTED",
        C::Internal => "INTERNAL",
        C::Unavailable => "UNAVAILABLE",
        C::DataLoss => "DATA_LOSS",
        C::Unauthenticated => "UNAUTHENTICATED",
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn stream_lag_is_counted_per_stream() {
        let h = super::handle();
        super::stream_lag("StreamAxisState", 3);
        super::stream_lag("StreamAxisState", 2);
        let text = h.render();
        assert!(
            text.contains("cangate_stream_lag_drops_total{stream=\"StreamAxisState\"} 5"),
            "{text}"
        );
    }
}
