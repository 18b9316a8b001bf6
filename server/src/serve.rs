//! The API edge: the gRPC server (services, health, reflection, the
//! security and metrics layers, gRPC-Web and CORS for browsers, the
//! Prometheus endpoint) in front of the gateway's runtime, and the running
//! server's shutdown.
//!
//! The layers, outermost first: the check of the host a browser request
//! names (against DNS rebinding, [`crate::web::HostCheckLayer`]), the
//! dashboard's static files (`GET`/`HEAD` only, [`crate::web`]), CORS (only for `[web] allowed_origins`),
//! gRPC-Web translation, metrics, security, the services. gRPC-Web is
//! translated before the security layer, so a browser's call is checked
//! exactly as a gRPC call is (token, roles, limits, audit, message size)
//! and its refusal travels back as a gRPC-Web status.
//!
//! Arrows run one way: this module uses [`crate::grpc`],
//! [`crate::security`], [`crate::metrics`] and the runtime
//! ([`crate::gateway`]); nothing below it names it.

use crate::config::Config;
use crate::gateway::Gateway;
use crate::grpc::axes_service::AxesService;
use crate::grpc::bus_service::BusService;
use crate::grpc::canopen_service::CanopenService;
use crate::grpc::cansmc_service::CansmcService;
use crate::grpc::handwheel_service::{HandwheelsService, SimulatorService};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

/// Why the server could not start.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    /// The runtime (a bus, a master, an axis) could not start.
    #[error(transparent)]
    Gateway(#[from] crate::gateway::BootError),
    /// The listen address could not be bound.
    #[error("cannot listen on {addr}: {source}")]
    Listen {
        /// The address.
        addr: SocketAddr,
        /// The OS error.
        source: std::io::Error,
    },
    /// The TLS files could not be used.
    #[error("{0}")]
    Tls(#[from] crate::security::TlsError),
    /// A broker bridge could not start.
    #[error("{0}")]
    Bridge(crate::bridge::BridgeError),
}

/// A started server.
pub struct RunningServer {
    /// The address the gRPC server listens on (useful with port 0).
    pub addr: SocketAddr,
    /// The Prometheus endpoint's address, when configured.
    pub metrics_addr: Option<SocketAddr>,
    /// The socketcand endpoint's address, when configured.
    pub socketcand_addr: Option<SocketAddr>,
    /// The CiA 309-3 gateway's address, when configured.
    pub cia309_addr: Option<SocketAddr>,
    gateway: Arc<Gateway>,
    shutdown: CancellationToken,
    server: JoinHandle<Result<(), tonic::transport::Error>>,
    bus_tasks: Vec<JoinHandle<()>>,
    socketcand: Option<JoinHandle<()>>,
    cia309: Option<JoinHandle<()>>,
    bridges: Vec<JoinHandle<()>>,
    tls: Option<crate::security::TlsReloader>,
}

impl RunningServer {
    /// The gateway (buses, virtual network).
    pub fn gateway(&self) -> &Arc<Gateway> {
        &self.gateway
    }

    /// The TLS configuration's reload handle (SIGHUP calls
    /// [`crate::security::TlsReloader::reload`]); none without TLS.
    pub fn tls_reloader(&self) -> Option<crate::security::TlsReloader> {
        self.tls.clone()
    }

    /// The token that stops everything.
    pub fn shutdown_token(&self) -> CancellationToken {
        self.shutdown.clone()
    }

    /// Shuts down with the machine in mind: new axis commands are refused,
    /// moving axes are stopped (halt or quick stop per their
    /// `stop_on_loss`) and awaited at most `motion_bound`; then streams
    /// end, buses close and the server stops (see
    /// [`RunningServer::shutdown`]). An axis not at rest within
    /// `motion_bound` is quick-stopped through its controlword first; the
    /// returned names are those axes (empty: every axis was at rest), for
    /// the exit status.
    pub async fn shutdown_safely(&self, motion_bound: Duration) -> Vec<String> {
        let stops = self.gateway.axes().stop_for_shutdown(motion_bound).await;
        for line in &stops.lines {
            tracing::warn!(target: "cangate::audit", "shutdown stopped axis {line}");
        }
        if !stops.not_at_rest.is_empty() {
            tracing::error!(
                "shutdown: {} not at rest within {} ms (quick-stopped through the controlword)",
                stops.not_at_rest.join(", "),
                motion_bound.as_millis()
            );
        }
        self.shutdown();
        stops.not_at_rest
    }

    /// Starts a graceful shutdown: streams end, buses close, the server stops.
    pub fn shutdown(&self) {
        self.shutdown.cancel();
    }

    /// Waits until the server has stopped (after [`RunningServer::shutdown`]
    /// or a signal), at most `limit`: the gRPC server, the socketcand
    /// endpoint, the bus tasks and the CANsmc cycle threads (so no MDT
    /// leaves after this returns); then aborts whatever is left.
    pub async fn wait(self, limit: Duration) -> Result<(), String> {
        let gateway = self.gateway.clone();
        let all = async {
            let r = self.server.await;
            if let Some(t) = self.socketcand {
                let _ = t.await;
            }
            if let Some(t) = self.cia309 {
                let _ = t.await;
            }
            for t in self.bridges {
                let _ = t.await;
            }
            for t in self.bus_tasks {
                let _ = t.await;
            }
            gateway.join_cansmc_threads().await;
            r
        };
        match tokio::time::timeout(limit, all).await {
            Ok(Ok(Ok(()))) => Ok(()),
            Ok(Ok(Err(e))) => Err(format!("gRPC server failed: {e}")),
            Ok(Err(e)) => Err(format!("gRPC server task failed: {e}")),
            Err(_) => Err(format!("shutdown did not finish within {limit:?}")),
        }
    }
}

/// CORS for the origins `[web] allowed_origins` names; none (no layer)
/// when it names none: the gateway's own page is same-origin. A preflight
/// from any other origin is answered without `access-control-allow-*`
/// headers, which browsers take as a refusal.
fn cors_layer(web: &crate::config::WebConfig) -> Option<tower_http::cors::CorsLayer> {
    use http::{HeaderName, HeaderValue, Method};
    use tower_http::cors::{AllowOrigin, CorsLayer};
    if web.allowed_origins.is_empty() {
        return None;
    }
    let origins: Vec<HeaderValue> = web
        .allowed_origins
        .iter()
        // Validated already ([web] allowed_origins holds origins only).
        .filter_map(|o| HeaderValue::from_str(o).ok())
        .collect();
    let header = HeaderName::from_static;
    Some(
        CorsLayer::new()
            .allow_origin(AllowOrigin::list(origins))
            .allow_methods([Method::POST])
            .allow_headers([
                http::header::AUTHORIZATION,
                http::header::CONTENT_TYPE,
                header("x-grpc-web"),
                header("x-user-agent"),
                header("grpc-timeout"),
                header("connect-protocol-version"),
                header("connect-timeout-ms"),
            ])
            .expose_headers([
                header("grpc-status"),
                header("grpc-message"),
                header("grpc-status-details-bin"),
            ])
            .max_age(Duration::from_secs(600)),
    )
}

/// Opens the buses, binds the listen address (`config.listen`; port 0 picks
/// a free port) and serves the gRPC API until the shutdown token fires.
pub async fn start(config: &Config) -> Result<RunningServer, StartError> {
    // TLS files first: a bad certificate must stop start-up before any bus
    // is opened.
    let tls = match &config.security.tls {
        Some(t) => Some(crate::security::TlsReloader::new(t.clone())?),
        None => None,
    };
    let shutdown = CancellationToken::new();
    let (gateway, bus_tasks) = Gateway::start(config, shutdown.clone())?;
    let gateway = Arc::new(gateway);
    let listener = tokio::net::TcpListener::bind(config.listen)
        .await
        .map_err(|source| StartError::Listen {
            addr: config.listen,
            source,
        })?;
    let addr = listener.local_addr().map_err(|source| StartError::Listen {
        addr: config.listen,
        source,
    })?;

    let (health_reporter, health_service) = tonic_health::server::health_reporter();
    health_reporter
        .set_serving::<cangate_proto::v1::bus_server::BusServer<BusService>>()
        .await;
    // Reflection under both names: grpc.reflection.v1 and the older
    // v1alpha that many tools (grpcio-reflection, older grpcurl, GUIs)
    // still speak.
    let reflection_builder = || {
        tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(cangate_proto::FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
    };
    let reflection = reflection_builder()
        .build_v1()
        .expect("the embedded descriptor sets are valid");
    let reflection_v1alpha = reflection_builder()
        .build_v1alpha()
        .expect("the embedded descriptor sets are valid");

    // Requests are bounded by [security.limits] max_message_bytes (the
    // security layer refuses larger ones first, naming the limit).
    let max_in = match config.security.limits.max_message_bytes {
        0 => usize::MAX,
        n => n as usize,
    };
    // One register of client senders for every edge that has them, so
    // that a stream names a socketcand client's frames too.
    let senders = Arc::new(crate::participants::SenderNames::default());
    let bus_service = cangate_proto::v1::bus_server::BusServer::new(BusService::with_senders(
        gateway.clone(),
        senders.clone(),
    ))
    .max_decoding_message_size(max_in);
    let canopen_service =
        cangate_proto::v1::canopen_server::CanopenServer::new(CanopenService::new(gateway.clone()))
            // DownloadProgram carries an image in one message; the security
            // layer keeps max_message_bytes for every other method.
            .max_decoding_message_size(
                max_in.max(crate::security::auth::MAX_PROGRAM_MESSAGE_BYTES as usize),
            )
            .max_encoding_message_size(64 * 1024 * 1024);
    health_reporter
        .set_serving::<cangate_proto::v1::canopen_server::CanopenServer<CanopenService>>()
        .await;
    let axes_service = cangate_proto::v1::axes_server::AxesServer::new(
        AxesService::new(gateway.clone())
            .with_max_name_bytes(config.security.limits.max_name_bytes as usize),
    )
    .max_decoding_message_size(max_in);
    health_reporter
        .set_serving::<cangate_proto::v1::axes_server::AxesServer<AxesService>>()
        .await;
    let handwheels_service = cangate_proto::v1::handwheels_server::HandwheelsServer::new(
        HandwheelsService::new(gateway.clone()),
    )
    .max_decoding_message_size(max_in);
    health_reporter
        .set_serving::<cangate_proto::v1::handwheels_server::HandwheelsServer<HandwheelsService>>()
        .await;
    let cansmc_service =
        cangate_proto::v1::cansmc_server::CansmcServer::new(CansmcService::new(gateway.clone()));
    let lss_service = cangate_proto::v1::lss_server::LssServer::new(
        crate::grpc::lss_service::LssService::new(gateway.clone()),
    )
    .max_decoding_message_size(max_in);
    health_reporter
        .set_serving::<cangate_proto::v1::lss_server::LssServer<crate::grpc::lss_service::LssService>>()
        .await;
    let session_service = cangate_proto::v1::session_server::SessionServer::new(
        crate::grpc::session_service::SessionService::new(
            config.security.authentication(),
            config.security.viewers_may_stop,
        ),
    );
    health_reporter
        .set_serving::<cangate_proto::v1::cansmc_server::CansmcServer<CansmcService>>()
        .await;
    // The Simulator service exists only when there is something to simulate.
    let simulator_service =
        (gateway.handwheels().any_simulated() || !gateway.simulation().is_empty()).then(|| {
            cangate_proto::v1::simulator_server::SimulatorServer::new(SimulatorService::new(
                gateway.clone(),
            ))
            .max_decoding_message_size(max_in)
        });
    // Plaintext or TLS connections, each carrying its peer (and client
    // certificate CN) to the security layer.
    let incoming = crate::security::tls::incoming(
        listener,
        tls.clone(),
        crate::security::tls::ConnTimeouts::from_limits(&config.security.limits),
        shutdown.clone(),
    );
    let security = crate::security::SecurityLayer::new(&config.security);
    let token = shutdown.clone();
    let server = tokio::spawn(
        tonic::transport::Server::builder()
            .tcp_nodelay(true)
            // What a client may have sent ahead of the gateway on one
            // stream: a client's raw frames waiting in the transport wait
            // for the bus's client share, so this bounds how long a flood
            // goes on after the client stopped (64 KiB: about 4,000
            // frames, where 1 MiB held a minute of a 30 % share).
            .initial_stream_window_size(64 * 1024)
            // Browsers speak gRPC-Web over HTTP/1.1 (over TLS too, as
            // long as the certificate offers no h2 ALPN to them).
            .accept_http1(true)
            .layer(RequestSpanLayer)
            .layer(crate::web::HostCheckLayer::new(
                crate::web::AllowedHosts::new(addr.ip(), &config.web.allowed_hosts),
            ))
            .layer(crate::web::StaticLayer::new(config.web.enabled))
            .layer(tower::util::option_layer(cors_layer(&config.web)))
            .layer(tonic_web::GrpcWebLayer::new())
            .layer(crate::metrics::RpcMetricsLayer)
            .layer(security.clone())
            .add_service(health_service)
            .add_service(reflection)
            .add_service(reflection_v1alpha)
            .add_service(bus_service)
            .add_service(canopen_service)
            .add_service(axes_service)
            .add_service(handwheels_service)
            .add_service(cansmc_service)
            .add_service(session_service)
            .add_service(lss_service)
            .add_optional_service(simulator_service)
            .serve_with_incoming_shutdown(incoming, async move { token.cancelled().await }),
    );
    if config.metrics_listen.is_some() {
        crate::metrics::handle();
    }
    let metrics_addr = match config.metrics_listen {
        Some(m) => Some(
            crate::metrics::serve(m, gateway.clone(), shutdown.clone())
                .await
                .map_err(|source| StartError::Listen { addr: m, source })?,
        ),
        None => None,
    };
    // The socketcand endpoint shares the security layer (identities,
    // limits per client, refusal throttling) with gRPC.
    let (cia309_addr, cia309) = match &config.cia309 {
        Some(c) => {
            // Network n is the n-th CANopen bus listed, else of the
            // configuration.
            let nets: Vec<String> = if c.buses.is_empty() {
                config.canopen.iter().map(|m| m.bus.clone()).collect()
            } else {
                c.buses.clone()
            };
            let (a, task) = crate::cia309::start(
                c,
                gateway.clone(),
                &nets,
                security.clone(),
                shutdown.clone(),
            )
            .map_err(|source| {
                shutdown.cancel();
                StartError::Listen {
                    addr: c.listen,
                    source,
                }
            })?;
            (Some(a), Some(task))
        }
        None => (None, None),
    };
    let (socketcand_addr, socketcand) = match &config.socketcand {
        Some(s) => {
            let (a, task) =
                crate::socketcand::start(s, gateway.clone(), security, senders, shutdown.clone())
                    .map_err(|source| {
                    // Nothing of this start-up may stay running.
                    shutdown.cancel();
                    StartError::Listen {
                        addr: s.listen,
                        source,
                    }
                })?;
            (Some(a), Some(task))
        }
        None => (None, None),
    };
    // The broker bridges publish what the streams carry; a broker that is
    // away is not a reason to refuse to start (they connect when it is
    // there), a file they cannot read is.
    let bridges = crate::bridge::start(&config.bridges, gateway.clone(), shutdown.clone())
        .map_err(|e| {
            shutdown.cancel();
            StartError::Bridge(e)
        })?;
    if config.security.authentication() && tls.is_none() && !addr.ip().is_loopback() {
        tracing::warn!(
            %addr,
            "authentication without [security.tls]: bearer tokens cross the network in clear text"
        );
    }
    tracing::info!(
        %addr,
        metrics = ?metrics_addr,
        socketcand = ?socketcand_addr,
        cia309 = ?cia309_addr,
        buses = gateway.buses().count(),
        tls = tls.is_some(),
        authentication = config.security.authentication(),
        "cangate gateway listening"
    );
    Ok(RunningServer {
        addr,
        metrics_addr,
        socketcand_addr,
        cia309_addr,
        gateway,
        shutdown,
        server,
        bus_tasks,
        socketcand,
        cia309,
        bridges,
        tls,
    })
}

/// Serves every call inside a `request` span with its method (the URI
/// path) and the peer's address, so that each line logged on its behalf
/// (by the edge or by the runtime it calls) says which call it belongs to.
#[derive(Debug, Clone, Copy)]
struct RequestSpanLayer;

impl<S> tower::Layer<S> for RequestSpanLayer {
    type Service = RequestSpan<S>;
    fn layer(&self, inner: S) -> Self::Service {
        RequestSpan { inner }
    }
}

/// See [`RequestSpanLayer`].
#[derive(Debug, Clone)]
struct RequestSpan<S> {
    inner: S,
}

impl<S, B> tower::Service<http::Request<B>> for RequestSpan<S>
where
    S: tower::Service<http::Request<B>>,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = tracing::instrument::Instrumented<S::Future>;

    fn poll_ready(
        &mut self,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, req: http::Request<B>) -> Self::Future {
        let peer = req
            .extensions()
            .get::<crate::security::tls::ConnInfo>()
            .and_then(|c| c.remote_addr)
            .map_or_else(|| "unknown".to_string(), |a| a.to_string());
        let span = tracing::info_span!("request", method = %req.uri().path(), %peer);
        let fut = span.in_scope(|| self.inner.call(req));
        tracing::Instrument::instrument(fut, span)
    }
}
