//! The CiA 309-3 ASCII gateway: an API edge beside gRPC for the tools and
//! scripts that speak CANopenNode's `canopend` command set over TCP
//! (`[1] 4 read 0x1017 0 u16`), configured by `[cia309]`.
//!
//! [`protocol`] is the protocol without I/O; this module is the listener
//! and one task per connection. Unlike canopend, which serves one
//! connection at a time, every connection is served at once, each with
//! its own defaults (network, node, SDO timeout, block mode); a
//! connection's commands run one after the other, in order.
//!
//! - **Who.** With authentication on, a client logs in with a bearer token
//!   as its first command, `[1] login TOKEN` → `[1] OK`: a command of the
//!   protocol's own shape, so a line-by-line client (`cocomm -f`, a
//!   script) only adds one line; a token in front of every command would
//!   change every line. Before it, every command but `help` is answered
//!   with error 102 saying so; an unknown token is answered with error 102
//!   and the connection closes (refusals throttled per peer as gRPC's
//!   are); a connection that has not logged in within
//!   `handshake_timeout_ms` is closed. Without authentication the
//!   configuration only lets the listener bind a loopback address, and
//!   every connection is `anonymous` (engineer), counted by peer address.
//! - **Roles**, as the gRPC methods doing the same (the access table in
//!   [`crate::security::roles`] decides): `read` is `ReadSdo` (viewer),
//!   `write` is `WriteSdo` and NMT is `SendNmt` (engineer), the LSS
//!   commands are the `Lss` methods (fastscan and inquiries operator, the
//!   configuration commands engineer), `set events` is
//!   `StreamNodeEvents` (viewer). A refusal is error 102 with the reason;
//!   the connection goes on.
//! - **Guards** are the runtime's, as for gRPC: a write to an enabled
//!   axis's drive objects ([`crate::canopen::drive_guard`]), an NMT command
//!   that would take an enabled axis's drive out of operational
//!   ([`CanopenBus::client_nmt`]), LSS that reaches an enabled axis's drive
//!   or gives a device a node-ID in use ([`CanopenBus::client_lss`]) are
//!   refused with error 102; this edge has no `force`.
//! - **Limits.** A connection counts as one streaming call of its client
//!   (call rate, `max_streams_per_client`); its SDO requests are the
//!   client's (`sdo_requests_per_client_and_node`). Connection slots as
//!   for socketcand ([`crate::security::slots`]). A line longer than
//!   `max_line_bytes` ends the connection; so does a write that does not
//!   complete within `write_timeout_ms`, and `idle_timeout_s` without a
//!   command (unless event lines are on).
//! - **Event lines** (`set events 1`): boot-ups, EMCYs, heartbeat losses
//!   and returns of every network, queued per connection (`event_queue`;
//!   a client that reads too slowly loses lines, counted in
//!   `cangate_cia309_events_lost_total`, never slowing anyone else).
//! - **Shutdown.** Every connection ends with the gateway's cancellation
//!   token (a command in progress is abandoned); the listener waits for
//!   them.

pub mod protocol;

use crate::canopen::{CanopenBus, CanopenError, NodeEvent, NodeEventKind};
use crate::config::Cia309Config;
use crate::gateway::Gateway;
use crate::security::auth::AUDIT_TARGET;
use crate::security::roles::{Access, lookup};
use crate::security::slots::{AcceptPolicy, SlotGuard, accept_connections, listen_on_bus_thread};
use crate::security::{Refusal, Role, SecurityLayer};
use cangate_canopen::lss::{InquireWhat, LssCommand, LssError, LssMode, LssOutcome};
use cangate_canopen::master::SdoRequest;
use cangate_canopen::nmt::NmtCommand;
use cangate_canopen::sdo::{AbortCode, SdoError, TransferOptions, TransferOutcome};
use cangate_canopen::{NodeId, ObjectAddress};
use protocol::{Action, ErrorCode, LineBuffer, Lss, Nmt, Session};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::tcp::OwnedWriteHalf;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{broadcast, mpsc};
use tokio::task::JoinHandle;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

/// Answer timeout of an LSS command.
const LSS_TIMEOUT: Duration = Duration::from_millis(1000);
/// Fastscan step time when `_lss_fastscan` gives none (canopend's).
const FASTSCAN_STEP: Duration = Duration::from_millis(100);

/// What every connection shares.
struct Shared {
    config: Cia309Config,
    security: SecurityLayer,
    /// Network n is `nets[n - 1]`.
    nets: Vec<CanopenBus>,
}

/// Binds `[cia309] listen` and serves until `shutdown`, on the bus thread
/// ([`listen_on_bus_thread`] says why); `nets` are the CANopen buses in
/// network order. Returns the bound address and the listener's task (it
/// ends once every connection has).
///
/// # Errors
/// The address cannot be bound.
pub fn start(
    config: &Cia309Config,
    gateway: Arc<Gateway>,
    nets: &[String],
    security: SecurityLayer,
    shutdown: CancellationToken,
) -> std::io::Result<(SocketAddr, JoinHandle<()>)> {
    if security.authentication() && !config.listen.ip().is_loopback() {
        tracing::warn!(
            addr = %config.listen,
            "the CiA 309-3 gateway listens on the network: its tokens cross it in clear text"
        );
    }
    let nets = nets
        .iter()
        .filter_map(|b| gateway.canopen(b).cloned())
        .collect();
    let shared = Arc::new(Shared {
        config: config.clone(),
        security,
        nets,
    });
    listen_on_bus_thread(gateway.bus_runtime(), config.listen, move |listener| {
        accept_loop(listener, shared, shutdown)
    })
}

async fn accept_loop(listener: TcpListener, shared: Arc<Shared>, shutdown: CancellationToken) {
    let policy = AcceptPolicy {
        name: "CiA 309-3",
        max: shared.config.max_connections as usize,
        per_peer: shared.config.max_connections_per_peer as usize,
        write_timeout: Duration::from_millis(shared.config.write_timeout_ms),
        refusal: |message| format!("# closed: {message}\r\n"),
        on_refused: || crate::metrics::cia309_session("too_many_connections"),
    };
    let stop = shutdown.clone();
    accept_connections(listener, policy, shutdown, move |stream, peer, slot| {
        connection(stream, peer, shared.clone(), stop.clone(), slot)
    })
    .await;
}

/// Counts an open connection while it lives.
struct Open;

impl Open {
    fn new() -> Self {
        crate::metrics::cia309_connections(1.0);
        Open
    }
}

impl Drop for Open {
    fn drop(&mut self) {
        crate::metrics::cia309_connections(-1.0);
    }
}

/// An authenticated client.
struct Client {
    who: String,
    role: Role,
    /// Whose SDO requests these are (the per-caller bound): the identity,
    /// else the peer's address.
    caller: String,
    /// Held while the connection lives: its stream slot.
    _stream: Option<crate::security::limits::Permit>,
}

/// Why a connection ends.
enum End {
    /// The peer closed, or reading or writing failed.
    Gone,
    /// The gateway closed it (the reason was written).
    Closed,
    /// The gateway shuts down.
    Shutdown,
}

/// The writing half with its timeout.
struct Writer {
    half: OwnedWriteHalf,
    timeout: Duration,
}

impl Writer {
    /// Writes all of `bytes`, failing when the peer does not take them
    /// within the timeout. What the socket's buffer takes at once is
    /// written without arming the timeout: nearly every answer, and the
    /// timer (a clock read, a timer-wheel entry) is then not needed.
    async fn write(&mut self, bytes: &[u8]) -> Result<(), End> {
        let rest = match self.half.try_write(bytes) {
            Ok(n) if n == bytes.len() => return Ok(()),
            Ok(n) => &bytes[n..],
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => bytes,
            Err(_) => return Err(End::Gone),
        };
        match tokio::time::timeout(self.timeout, self.half.write_all(rest)).await {
            Ok(Ok(())) => Ok(()),
            _ => Err(End::Gone),
        }
    }
}

/// The next event line (never returns without events on).
async fn next_event(events: &mut Option<mpsc::Receiver<String>>) -> Option<String> {
    match events {
        Some(rx) => rx.recv().await,
        None => std::future::pending().await,
    }
}

async fn connection(
    stream: TcpStream,
    peer: SocketAddr,
    shared: Arc<Shared>,
    shutdown: CancellationToken,
    slot: SlotGuard,
) {
    let _open = Open::new();
    let _ = stream.set_nodelay(true);
    let (mut reader, half) = stream.into_split();
    let mut writer = Writer {
        half,
        timeout: Duration::from_millis(shared.config.write_timeout_ms),
    };
    let mut conn = Connection {
        shared: &shared,
        peer,
        session: Session::new(shared.nets.len() as u16, shared.config.sdo_timeout_ms),
        client: None,
        events: None,
        shutdown: &shutdown,
    };
    let end = conn.serve(&mut reader, &mut writer, &slot).await;
    if let Some(c) = &conn.client {
        tracing::info!(
            who = %c.who,
            reason = match end {
                End::Gone => "peer closed, or a read or write failed",
                End::Closed => "closed by the gateway",
                End::Shutdown => "shutdown",
            },
            "CiA 309-3 connection ended"
        );
    }
}

/// One connection's state.
struct Connection<'a> {
    shared: &'a Shared,
    peer: SocketAddr,
    session: Session,
    client: Option<Client>,
    /// Event lines, while `set events 1`.
    events: Option<mpsc::Receiver<String>>,
    shutdown: &'a CancellationToken,
}

/// What a command did, for the connection.
enum Done {
    /// Write this and go on.
    Answer(String),
    /// Write this and close.
    Close(String),
}

impl Connection<'_> {
    async fn serve(
        &mut self,
        reader: &mut tokio::net::tcp::OwnedReadHalf,
        writer: &mut Writer,
        slot: &SlotGuard,
    ) -> End {
        let cfg = &self.shared.config;
        let authentication = self.shared.security.authentication();
        if !authentication {
            match self.admit(None) {
                Ok(()) => slot.opened(),
                Err(message) => {
                    let _ = writer
                        .write(format!("# closed: {message}\r\n").as_bytes())
                        .await;
                    return End::Closed;
                }
            }
        }
        let mut lines = LineBuffer::new(cfg.max_line_bytes as usize);
        let handshake_deadline = Instant::now() + Duration::from_millis(cfg.handshake_timeout_ms);
        let idle = (cfg.idle_timeout_s > 0).then(|| Duration::from_secs(cfg.idle_timeout_s));
        let mut last_read = Instant::now();
        let mut buf = vec![0u8; 4096];
        loop {
            let deadline = match (&self.client, &self.events) {
                (None, _) => Some(handshake_deadline),
                (Some(_), None) => idle.map(|i| last_read + i),
                (Some(_), Some(_)) => None,
            };
            tokio::select! {
                biased;
                _ = self.shutdown.cancelled() => return End::Shutdown,
                _ = slot.evicted().cancelled(), if self.client.is_none() => {
                    crate::metrics::cia309_session("evicted_before_login");
                    let _ = writer.write(b"# closed: not logged in, and every connection slot \
                        is taken (max_connections, max_connections_per_peer): a new client \
                        needs one\r\n").await;
                    return End::Closed;
                }
                _ = tokio::time::sleep_until(deadline.unwrap_or_else(Instant::now)),
                    if deadline.is_some() => {
                    let what = if self.client.is_none() {
                        crate::metrics::cia309_session("handshake_timeout");
                        format!("no login within {} ms (handshake_timeout_ms)", cfg.handshake_timeout_ms)
                    } else {
                        format!("idle for {} s without a command (idle_timeout_s)", cfg.idle_timeout_s)
                    };
                    let _ = writer.write(format!("# closed: {what}\r\n").as_bytes()).await;
                    return End::Closed;
                }
                Some(line) = next_event(&mut self.events) => {
                    if let Err(e) = writer.write(line.as_bytes()).await {
                        return e;
                    }
                }
                r = reader.read(&mut buf) => {
                    let n = match r {
                        Ok(0) | Err(_) => return End::Gone,
                        Ok(n) => n,
                    };
                    last_read = Instant::now();
                    lines.push(&buf[..n]);
                    loop {
                        let line = match lines.next_line() {
                            Ok(Some(l)) => l,
                            Ok(None) => break,
                            Err(e) => {
                                crate::metrics::cia309_command("too_long", "refused");
                                let _ = writer.write(format!("# closed: {e} (max_line_bytes)\r\n").as_bytes()).await;
                                return End::Closed;
                            }
                        };
                        // Before a login the line is only read, against
                        // a copy: it changes no setting of the session.
                        let action = if self.client.is_none() {
                            self.session.clone().on_line(&line)
                        } else {
                            self.session.on_line(&line)
                        };
                        let done = tokio::select! {
                            biased;
                            _ = self.shutdown.cancelled() => return End::Shutdown,
                            d = self.execute(action, slot) => d,
                        };
                        match done {
                            Done::Answer(a) => {
                                if let Err(e) = writer.write(a.as_bytes()).await {
                                    return e;
                                }
                            }
                            Done::Close(a) => {
                                let _ = writer.write(a.as_bytes()).await;
                                return End::Closed;
                            }
                        }
                    }
                }
            }
        }
    }

    /// Admits the connection with `token` (none without authentication),
    /// or says why not.
    fn admit(&mut self, token: Option<&str>) -> Result<(), String> {
        let admission = self
            .shared
            .security
            .admit_session(token, self.peer.ip())
            .map_err(|refusal| {
                let (result, message) = match &refusal {
                    Refusal::ResourceExhausted(m) => ("refused_limit", m.clone()),
                    Refusal::Unauthenticated(_) if token.is_some() => {
                        ("refused_auth", "unknown token".to_string())
                    }
                    other => ("refused_auth", other.to_string()),
                };
                crate::metrics::cia309_session(result);
                tracing::warn!(
                    target: AUDIT_TARGET,
                    who = "unidentified",
                    method = "cia309 login",
                    peer = %self.peer,
                    message = %message,
                    "CiA 309-3 session refused"
                );
                message
            })?;
        let identity = admission.identity;
        let (who, caller) = if identity.method == "none" {
            (self.peer.to_string(), self.peer.ip().to_string())
        } else {
            (format!("{}@{}", identity.name, self.peer), identity.name)
        };
        crate::metrics::cia309_session("opened");
        tracing::info!(
            target: AUDIT_TARGET,
            who = %who,
            role = identity.role.as_str(),
            method = "cia309 login",
            "CiA 309-3 session opened"
        );
        self.client = Some(Client {
            who,
            role: identity.role,
            caller,
            _stream: admission.stream,
        });
        Ok(())
    }

    /// The gRPC method whose access rule a command follows.
    fn method(action: &Action) -> Option<&'static str> {
        Some(match action {
            Action::Read { .. } => "/cangate.v1.Canopen/ReadSdo",
            Action::Write { .. } => "/cangate.v1.Canopen/WriteSdo",
            Action::Nmt { .. } => "/cangate.v1.Canopen/SendNmt",
            Action::Events { .. } => "/cangate.v1.Canopen/StreamNodeEvents",
            Action::Info { .. } => "/cangate.v1.Session/GetCaller",
            Action::ReadPdo { .. } => "/cangate.v1.Canopen/StreamPdo",
            Action::WritePdo { .. } => "/cangate.v1.Canopen/WritePdo",
            Action::Lss { command, .. } => match command {
                Lss::SwitchGlobal(_) => "/cangate.v1.Lss/SwitchGlobal",
                Lss::SwitchSelective(_) => "/cangate.v1.Lss/SwitchSelective",
                Lss::SetNode(_) => "/cangate.v1.Lss/ConfigureNodeId",
                Lss::ConfigureBitRate { .. } => "/cangate.v1.Lss/ConfigureBitTiming",
                Lss::ActivateBitRate(_) => "/cangate.v1.Lss/ActivateBitTiming",
                Lss::Store => "/cangate.v1.Lss/StoreConfiguration",
                Lss::InquireAddress(_) | Lss::GetNode => "/cangate.v1.Lss/Inquire",
                Lss::Fastscan(_) => "/cangate.v1.Lss/Fastscan",
                Lss::AllNodes { .. } => "/cangate.v1.Lss/AssignNodeId",
            },
            Action::Reply(_) | Action::Login { .. } => return None,
        })
    }

    async fn execute(&mut self, action: Action, slot: &SlotGuard) -> Done {
        let name = action.name();
        let seq = seq_of(&action);
        if let Action::Login { seq, token } = &action {
            if !self.shared.security.authentication() {
                return Done::Answer(protocol::format_ok(*seq));
            }
            return match self.admit(Some(token)) {
                Ok(()) => {
                    slot.opened();
                    crate::metrics::cia309_command(name, "ok");
                    Done::Answer(protocol::format_ok(*seq))
                }
                Err(message) => Done::Close(protocol::format_error(
                    *seq,
                    ErrorCode::INTERNAL_STATE,
                    Some(&message),
                )),
            };
        }
        if let Action::Reply(text) = action {
            // Help and the answers to unreadable lines are for anyone;
            // the session's settings need a login like every other
            // command.
            if self.client.is_none() && text.starts_with('[') && !text.contains("ERROR:") {
                return Done::Answer(login_first(seq_in(&text)));
            }
            return Done::Answer(text);
        }
        let Some(client) = &self.client else {
            return Done::Answer(login_first(seq));
        };
        if let Some(method) = Self::method(&action) {
            let needs = match lookup(method).map(|r| r.access) {
                Some(Access::Role(r)) => r,
                Some(Access::Public) => Role::Viewer,
                // Not classified: refused (fail closed).
                None => Role::Engineer,
            };
            if client.role < needs {
                crate::metrics::cia309_command(name, "refused");
                tracing::warn!(
                    target: AUDIT_TARGET,
                    who = %client.who,
                    role = client.role.as_str(),
                    method = %format!("cia309 {name}"),
                    "refused: needs role {}", needs.as_str()
                );
                return Done::Answer(protocol::format_error(
                    seq,
                    ErrorCode::INTERNAL_STATE,
                    Some(&format!(
                        "{name} needs role {}; {} holds role {}",
                        needs.as_str(),
                        client.who,
                        client.role.as_str()
                    )),
                ));
            }
        }
        let answer = self.run(action).await;
        crate::metrics::cia309_command(
            name,
            if answer.contains("ERROR:") {
                "error"
            } else {
                "ok"
            },
        );
        Done::Answer(answer)
    }

    /// Carries out an authorised command; the answer.
    async fn run(&mut self, action: Action) -> String {
        let client = self.client.as_ref().expect("authorised");
        let opts = {
            let o = if self.session.sdo_block {
                TransferOptions::block()
            } else {
                TransferOptions::default()
            };
            o.with_timeout(Duration::from_millis(u64::from(
                self.session.sdo_timeout_ms,
            )))
        };
        match action {
            Action::Read {
                seq,
                net,
                node,
                index,
                sub,
                ty,
            } => {
                let (m, node) = match self.target(seq, net, node) {
                    Ok(t) => t,
                    Err(e) => return e,
                };
                let addr = ObjectAddress::new(index, sub);
                match m
                    .client_sdo(node, SdoRequest::Upload { addr, opts }, &client.caller)
                    .await
                {
                    Ok(TransferOutcome::Uploaded(raw)) => protocol::format_value(seq, ty, &raw),
                    Ok(_) => protocol::format_ok(seq),
                    Err(e) => error_answer(seq, e, None),
                }
            }
            Action::Write {
                seq,
                net,
                node,
                index,
                sub,
                data,
            } => {
                let (m, node) = match self.target(seq, net, node) {
                    Ok(t) => t,
                    Err(e) => return e,
                };
                let addr = ObjectAddress::new(index, sub);
                if let Err(e) = m.check_sdo_write(node, addr) {
                    return self.refused(seq, "write", CanopenError::AxisActive(e));
                }
                tracing::info!(
                    target: AUDIT_TARGET,
                    who = %client.who,
                    method = "cia309 write",
                    bus = m.bus(),
                    node = node.get(),
                    object = %addr,
                    bytes = data.len(),
                    "CiA 309-3 SDO write"
                );
                match m
                    .client_sdo(
                        node,
                        SdoRequest::Download { addr, data, opts },
                        &client.caller,
                    )
                    .await
                {
                    Ok(_) => protocol::format_ok(seq),
                    Err(e @ CanopenError::AxisActive(_)) => self.refused(seq, "write", e),
                    Err(e) => error_answer(seq, e, None),
                }
            }
            Action::Nmt {
                seq,
                net,
                node,
                command,
            } => {
                let Some(m) = self.net(net) else {
                    return protocol::format_error(seq, ErrorCode::UNSUPPORTED_NET, None);
                };
                let target = match node {
                    0 => None,
                    n => match NodeId::new(u32::from(n)) {
                        Ok(id) => Some(id),
                        Err(_) => {
                            return protocol::format_error(seq, ErrorCode::UNSUPPORTED_NODE, None);
                        }
                    },
                };
                let cmd = match command {
                    Nmt::Start => NmtCommand::Start,
                    Nmt::Stop => NmtCommand::Stop,
                    Nmt::PreOperational => NmtCommand::EnterPreOperational,
                    Nmt::ResetNode => NmtCommand::ResetNode,
                    Nmt::ResetCommunication => NmtCommand::ResetCommunication,
                };
                tracing::info!(
                    target: AUDIT_TARGET,
                    who = %client.who,
                    method = "cia309 nmt",
                    bus = m.bus(),
                    node,
                    command = ?cmd,
                    "CiA 309-3 NMT"
                );
                match m.client_nmt(cmd, target, false).await {
                    Ok(()) => protocol::format_ok(seq),
                    Err(e @ CanopenError::AxisActive(_)) => self.refused(seq, "NMT", e),
                    Err(e) => error_answer(seq, e, None),
                }
            }
            Action::Lss { seq, net, command } => {
                let Some(m) = self.net(net) else {
                    return protocol::format_error(seq, ErrorCode::UNSUPPORTED_NET, None);
                };
                tracing::info!(
                    target: AUDIT_TARGET,
                    who = %client.who,
                    method = "cia309 lss",
                    bus = m.bus(),
                    command = ?command,
                    "CiA 309-3 LSS"
                );
                let m = m.clone();
                lss(&m, seq, command).await
            }
            Action::Events { seq, on } => {
                if on && self.events.is_none() {
                    self.events = Some(self.subscribe());
                } else if !on {
                    self.events = None;
                }
                protocol::format_ok(seq)
            }
            Action::Info { seq } => {
                let mut lines: Vec<String> = self
                    .shared
                    .nets
                    .iter()
                    .enumerate()
                    .map(|(i, m)| format!("network {}: bus {}", i + 1, m.bus()))
                    .collect();
                lines.push(format!(
                    "you are {}, role {}",
                    client.who,
                    client.role.as_str()
                ));
                protocol::format_comment_lines(seq, &lines)
            }
            Action::ReadPdo {
                seq,
                net,
                node,
                pdo,
            } => {
                let (m, node) = match self.target(seq, net, node) {
                    Ok(t) => t,
                    Err(e) => return e,
                };
                read_pdo(&m, seq, net, node, pdo)
            }
            Action::WritePdo {
                seq,
                net,
                node,
                pdo,
                values,
            } => {
                let (m, node) = match self.target(seq, net, node) {
                    Ok(t) => t,
                    Err(e) => return e,
                };
                let Some(cfg) = m.rpdo(node, pdo) else {
                    return protocol::format_error(
                        seq,
                        ErrorCode::INTERNAL_STATE,
                        Some(&format!(
                            "node {node} has no RPDO {pdo} (configure it under \
                             [[canopen.node.rpdo]] or give the node an EDS)"
                        )),
                    );
                };
                // The guard first: whatever the values, an RPDO that
                // commands an active axis's drive is not the client's.
                if let Err(e) = m.check_rpdo_write(node, &cfg) {
                    return self.refused(seq, "write pdo", CanopenError::AxisActive(e));
                }
                let data = match rpdo_payload(&cfg, seq, node, &values) {
                    Ok(d) => d,
                    Err(answer) => return answer,
                };
                tracing::info!(
                    target: AUDIT_TARGET,
                    who = %client.who,
                    method = "cia309 write pdo",
                    bus = m.bus(),
                    node = node.get(),
                    pdo,
                    cob_id = cfg.cob_id,
                    "CiA 309-3 PDO write"
                );
                match m.send_pdo(cfg.cob_id, &data).await {
                    Ok(()) => protocol::format_ok(seq),
                    Err(e) => error_answer(seq, e, None),
                }
            }
            Action::Reply(text) => text,
            Action::Login { seq, .. } => protocol::format_ok(seq),
        }
    }

    fn net(&self, net: u16) -> Option<&CanopenBus> {
        self.shared.nets.get(usize::from(net).checked_sub(1)?)
    }

    fn target(&self, seq: u32, net: u16, node: u8) -> Result<(CanopenBus, NodeId), String> {
        let m = self
            .net(net)
            .ok_or_else(|| protocol::format_error(seq, ErrorCode::UNSUPPORTED_NET, None))?;
        let node = NodeId::new(u32::from(node))
            .map_err(|_| protocol::format_error(seq, ErrorCode::UNSUPPORTED_NODE, None))?;
        Ok((m.clone(), node))
    }

    /// A command the runtime's guard refused: logged, error 102 with why.
    fn refused(&self, seq: u32, what: &str, e: CanopenError) -> String {
        if let Some(c) = &self.client {
            tracing::warn!(
                target: AUDIT_TARGET,
                who = %c.who,
                method = %format!("cia309 {what}"),
                "refused: {e}"
            );
        }
        protocol::format_error(seq, ErrorCode::INTERNAL_STATE, Some(&e.to_string()))
    }

    /// Event lines of every network into a queue of the connection's;
    /// the forwarding tasks end with the queue.
    fn subscribe(&self) -> mpsc::Receiver<String> {
        let (tx, rx) = mpsc::channel(self.shared.config.event_queue as usize);
        for (i, m) in self.shared.nets.iter().enumerate() {
            let net = (i + 1) as u16;
            let mut events = m.events();
            let tx = tx.clone();
            let shutdown = self.shutdown.clone();
            let bus = m.bus().to_string();
            tokio::spawn(async move {
                loop {
                    let ev = tokio::select! {
                        biased;
                        _ = shutdown.cancelled() => break,
                        _ = tx.closed() => break,
                        ev = events.recv() => ev,
                    };
                    match ev {
                        Ok(ev) => {
                            if let Some(line) = event_line(net, &ev)
                                && tx.try_send(line).is_err()
                            {
                                crate::metrics::cia309_events_lost(&bus, 1);
                            }
                        }
                        Err(broadcast::error::RecvError::Lagged(n)) => {
                            crate::metrics::cia309_events_lost(&bus, n);
                        }
                        Err(broadcast::error::RecvError::Closed) => break,
                    }
                }
            });
        }
        rx
    }
}

/// The sequence of an action (0 for a local answer).
fn seq_of(action: &Action) -> u32 {
    match action {
        Action::Reply(text) => seq_in(text),
        Action::Read { seq, .. }
        | Action::Write { seq, .. }
        | Action::Nmt { seq, .. }
        | Action::Lss { seq, .. }
        | Action::Events { seq, .. }
        | Action::Login { seq, .. }
        | Action::Info { seq }
        | Action::ReadPdo { seq, .. }
        | Action::WritePdo { seq, .. } => *seq,
    }
}

/// The sequence of an answer line `[seq] …`.
fn seq_in(text: &str) -> u32 {
    text.strip_prefix('[')
        .and_then(|t| t.split_once(']'))
        .and_then(|(n, _)| n.parse().ok())
        .unwrap_or(0)
}

fn login_first(seq: u32) -> String {
    protocol::format_error(
        seq,
        ErrorCode::INTERNAL_STATE,
        Some("log in first: [1] login TOKEN"),
    )
}

/// The event line of a node event, for those CiA 309-3 has a line for.
fn event_line(net: u16, ev: &NodeEvent) -> Option<String> {
    use protocol::Event;
    let event = match &ev.kind {
        NodeEventKind::BootUp => Event::BootUp,
        NodeEventKind::Emcy(e) => Event::Emcy {
            code: e.code,
            register: e.register,
            manufacturer: e.manufacturer,
        },
        NodeEventKind::HeartbeatLost { guarding, .. } => Event::Lost {
            guarding: *guarding,
        },
        NodeEventKind::HeartbeatRecovered {
            guarding: false, ..
        } => Event::HeartbeatStarted,
        _ => return None,
    };
    Some(protocol::format_event(net, ev.node.get(), &event))
}

/// `read pdo`: the mapped values of the last TPDO `pdo` of `node`, as
/// unsigned numbers of their bits.
fn read_pdo(m: &CanopenBus, seq: u32, net: u16, node: NodeId, pdo: u16) -> String {
    let refuse = |why: String| protocol::format_error(seq, ErrorCode::INTERNAL_STATE, Some(&why));
    let (cfg, last) = match m.last_tpdo(node, pdo) {
        None => {
            return refuse(format!(
                "node {node} has no TPDO {pdo} (configure it under [[canopen.node.tpdo]] or \
                 give the node an EDS)"
            ));
        }
        Some((_, None)) => return refuse(format!("no TPDO {pdo} of node {node} received yet")),
        Some((cfg, Some(frame))) => (cfg, frame),
    };
    let data = last.data();
    let mut values = Vec::with_capacity(cfg.mapping.len());
    let mut at = 0;
    for mo in &cfg.mapping {
        let len = usize::from(mo.bits / 8);
        let Some(bytes) = data.get(at..at + len) else {
            return refuse(format!(
                "TPDO {pdo} of node {node} came with {} bytes; its mapping needs more",
                data.len()
            ));
        };
        values.push(
            bytes
                .iter()
                .rev()
                .fold(0u64, |v, b| (v << 8) | u64::from(*b)),
        );
        at += len;
    }
    protocol::format_pdo(seq, net, &values)
}

/// `write pdo`: the payload of `values` for the RPDO `cfg`, or the answer
/// refusing them.
fn rpdo_payload(
    cfg: &cangate_canopen::pdo::PdoConfig,
    seq: u32,
    node: NodeId,
    values: &[u64],
) -> Result<Vec<u8>, String> {
    let pdo = cfg.num;
    let syntax = |why: String| protocol::format_error(seq, ErrorCode::SYNTAX, Some(&why));
    if values.len() != cfg.mapping.len() {
        return Err(syntax(format!(
            "RPDO {pdo} of node {node} maps {} objects; {} values given",
            cfg.mapping.len(),
            values.len()
        )));
    }
    let mut data = Vec::with_capacity(8);
    for (mo, v) in cfg.mapping.iter().zip(values) {
        let bits = u32::from(mo.bits);
        if bits < 64 && v >> bits != 0 {
            return Err(syntax(format!(
                "{v:#x} does not fit the {bits} bits of {}",
                mo.addr
            )));
        }
        data.extend_from_slice(&v.to_le_bytes()[..usize::from(mo.bits / 8)]);
    }
    Ok(data)
}

/// The answer of a failed runtime call. `lss` names the LSS command for
/// the LSS error codes that depend on it.
fn error_answer(seq: u32, e: CanopenError, lss: Option<&Lss>) -> String {
    let error = |code, detail: Option<String>| protocol::format_error(seq, code, detail.as_deref());
    match e {
        CanopenError::Sdo(s) => match s {
            SdoError::Aborted { code, .. }
            | SdoError::Protocol { code, .. }
            | SdoError::Cancelled { code, .. } => {
                protocol::format_abort(seq, code.get(), code.name())
            }
            // The client's own abort, as canopend reports its timeout.
            SdoError::Timeout { .. } => {
                let code = AbortCode(0x0504_0000);
                protocol::format_abort(seq, code.get(), code.name())
            }
            // The interface gave the request up: the gateway could not
            // carry the command out now.
            e @ SdoError::NotSent { .. } => error(ErrorCode::INTERNAL_STATE, Some(e.to_string())),
        },
        CanopenError::Send(f) => match f.error {
            cangate_can::SendError::BusOff(_) => error(ErrorCode::BUS_OFF, Some(f.to_string())),
            _ => error(ErrorCode::INTERNAL_STATE, Some(f.to_string())),
        },
        CanopenError::Lss(LssError::Timeout { .. }) => error(ErrorCode::TIMEOUT, None),
        CanopenError::Lss(LssError::Refused {
            error: 0xFF,
            spec_error,
            ..
        }) => error(
            ErrorCode::LSS_MANUFACTURER,
            Some(format!("implementation-specific error {spec_error}")),
        ),
        CanopenError::Lss(e @ LssError::Refused { .. }) => {
            let code = match lss {
                Some(Lss::SetNode(_)) => ErrorCode::LSS_NODE_ID,
                Some(Lss::ConfigureBitRate { .. }) => ErrorCode::LSS_BIT_RATE,
                Some(Lss::Store) => ErrorCode::LSS_STORE,
                _ => ErrorCode::INTERNAL_STATE,
            };
            error(code, Some(e.to_string()))
        }
        e => error(ErrorCode::INTERNAL_STATE, Some(e.to_string())),
    }
}

/// Runs an LSS command through the runtime's guards; the answer.
async fn lss(m: &CanopenBus, seq: u32, command: Lss) -> String {
    let one = |c: LssCommand| m.client_lss(c, LSS_TIMEOUT, false);
    let fail = |e| error_answer(seq, e, Some(&command));
    let inquire = |what| async move {
        match m
            .client_lss(LssCommand::Inquire(what), LSS_TIMEOUT, false)
            .await
        {
            Ok(LssOutcome::Value(v)) => Ok(v),
            Ok(_) => Err(CanopenError::Stopped),
            Err(e) => Err(e),
        }
    };
    let simple = match command {
        Lss::SwitchGlobal(config) => Some(LssCommand::SwitchGlobal(if config {
            LssMode::Configuration
        } else {
            LssMode::Waiting
        })),
        Lss::SwitchSelective(id) => Some(LssCommand::SwitchSelective(
            cangate_canopen::lss::LssIdentity::from_parts(id),
        )),
        Lss::SetNode(id) => Some(LssCommand::ConfigureNodeId(id)),
        Lss::ConfigureBitRate { table, index } => {
            Some(LssCommand::ConfigureBitTiming { table, index })
        }
        Lss::ActivateBitRate(ms) => Some(LssCommand::ActivateBitTiming {
            switch_delay_ms: ms,
        }),
        Lss::Store => Some(LssCommand::StoreConfiguration),
        _ => None,
    };
    if let Some(c) = simple {
        return match one(c).await {
            Ok(_) => protocol::format_ok(seq),
            Err(e) => fail(e),
        };
    }
    match command {
        Lss::GetNode => match inquire(InquireWhat::NodeId).await {
            Ok(v) => protocol::format_lss_node_id(seq, v as u8),
            Err(e) => fail(e),
        },
        Lss::InquireAddress(Some(part)) => {
            let what = match part {
                0 => InquireWhat::VendorId,
                1 => InquireWhat::ProductCode,
                2 => InquireWhat::Revision,
                _ => InquireWhat::Serial,
            };
            match inquire(what).await {
                Ok(v) => protocol::format_lss_value(seq, v),
                Err(e) => fail(e),
            }
        }
        Lss::InquireAddress(None) => {
            let mut id = [0u32; 4];
            for (part, what) in id.iter_mut().zip([
                InquireWhat::VendorId,
                InquireWhat::ProductCode,
                InquireWhat::Revision,
                InquireWhat::Serial,
            ]) {
                match inquire(what).await {
                    Ok(v) => *part = v,
                    Err(e) => return fail(e),
                }
            }
            protocol::format_lss_address(seq, id)
        }
        Lss::Fastscan(ms) => {
            let step = ms
                .filter(|&ms| ms > 0)
                .map_or(FASTSCAN_STEP, |ms| Duration::from_millis(u64::from(ms)))
                .max(m.min_fastscan_step());
            match one(LssCommand::Fastscan {
                step_time: step,
                max_nodes: 1,
            })
            .await
            {
                // The device found stays in the configuration state, as
                // canopend leaves it.
                Ok(LssOutcome::Found(ids)) => match ids.first() {
                    Some(i) => protocol::format_lss_address(
                        seq,
                        [i.vendor_id, i.product_code, i.revision, i.serial],
                    ),
                    None => protocol::format_error(seq, ErrorCode::TIMEOUT, None),
                },
                Ok(_) => protocol::format_error(seq, ErrorCode::INTERNAL_STATE, None),
                Err(e) => fail(e),
            }
        }
        Lss::AllNodes {
            step_ms,
            first,
            store,
        } => {
            let step = step_ms
                .filter(|&ms| ms > 0)
                .map_or(FASTSCAN_STEP, |ms| Duration::from_millis(u64::from(ms)))
                .max(m.min_fastscan_step());
            all_nodes(m, seq, step, first, store).await
        }
        _ => protocol::format_error(seq, ErrorCode::NOT_SUPPORTED, None),
    }
}

/// `lss_allnodes`: fastscan for one unconfigured device, give it the next
/// node-ID (each through the runtime's guards: an id in use stops the
/// scan), store it if asked, back to waiting (it takes the id); again
/// until fastscan finds none, or node-ID 127 was given. Reported as
/// canopend does: a `#` line per device, then the count, then `OK`.
async fn all_nodes(m: &CanopenBus, seq: u32, step: Duration, first: u8, store: bool) -> String {
    let mut lines = Vec::new();
    let mut node = first;
    let mut found = 0;
    let run = |c: LssCommand| m.client_lss(c, LSS_TIMEOUT, false);
    let fail = |lines: &[String], e: CanopenError| {
        let mut out = String::new();
        for l in lines {
            out.push_str(&format!("# {l}\n"));
        }
        out.push_str(&error_answer(seq, e, Some(&Lss::SetNode(0))));
        out
    };
    loop {
        let id = match run(LssCommand::Fastscan {
            step_time: step,
            max_nodes: 1,
        })
        .await
        {
            Ok(LssOutcome::Found(ids)) => match ids.first() {
                Some(id) => *id,
                None => break,
            },
            Ok(_) => break,
            Err(e) => return fail(&lines, e),
        };
        let mut steps = vec![LssCommand::ConfigureNodeId(node)];
        if store {
            steps.push(LssCommand::StoreConfiguration);
        }
        steps.push(LssCommand::SwitchGlobal(LssMode::Waiting));
        for c in steps {
            if let Err(e) = run(c).await {
                // Leave no device in the configuration state.
                let _ = run(LssCommand::SwitchGlobal(LssMode::Waiting)).await;
                return fail(&lines, e);
            }
        }
        found += 1;
        lines.push(format!(
            "Node-ID {node} assigned to: 0x{:08X} 0x{:08X} 0x{:08X} 0x{:08X}",
            id.vendor_id, id.product_code, id.revision, id.serial
        ));
        if node == 127 {
            lines.push("Not all nodes scanned!".into());
            return protocol::format_comment_lines(seq, &lines);
        }
        node += 1;
    }
    lines.push(format!("Found {found} nodes, search finished."));
    protocol::format_comment_lines(seq, &lines)
}
