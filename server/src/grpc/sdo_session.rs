//! `Canopen.SdoSession`: ReadSdo/WriteSdo requests and their answers on one
//! bidirectional stream.
//!
//! This module is the session's flow; the Canopen service gives it the
//! function that runs one request as ReadSdo/WriteSdo would (the same
//! code), its error becoming an `SdoSessionError` answer instead of the end
//! of the call. Requests of one (bus, node) run
//! one after the other in the order received, each waiting for the one
//! before it, so their answers keep that order; different nodes run
//! concurrently. At most [`MAX_OUTSTANDING`] requests are outstanding: the
//! reader waits for a free slot before it reads the next request, so a
//! client that sends faster than the bus answers is held back by the
//! transport's flow control. All transfers of a session are tasks of one
//! set that is dropped when the client goes away: their `client_sdo`
//! futures are dropped, and the master aborts what was on the bus.

use super::error::ApiError;
use super::forward::{MessageStream, stream_of};
use crate::security::{Identity, RequestBudget, Role, roles};
use cangate_proto::v1 as pb;
use std::collections::HashMap;
use std::future::Future;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use tokio::sync::{Semaphore, mpsc, oneshot};
use tokio::task::JoinSet;
use tokio_stream::{Stream, StreamExt};
use tokio_util::sync::CancellationToken;
use tonic::Status;

/// Requests of one session outstanding (read, not yet answered) at most.
pub const MAX_OUTSTANDING: usize = 64;

/// Who asks in a session, for each of its requests.
pub(super) struct Caller {
    /// For the master's per-caller bound (see `sdo_caller`).
    pub(super) name: String,
    /// The identity of the stream, for the role of each request and the
    /// audit log; `None` when no security layer ran (then every role).
    pub(super) identity: Option<Identity>,
    /// Writes of this session refused for the role so far: only the first
    /// gets an audit line (refusals cost the gateway nothing else, so a
    /// session could otherwise fill the log as fast as it sends).
    pub(super) refused_writes: AtomicU64,
    /// The client's call rate, taken per request; `None` when no security
    /// layer ran.
    pub(super) budget: Option<RequestBudget>,
}

/// Starts serving one session (`answer`: runs one request): the answers'
/// stream.
pub(super) fn serve<S, F, Fut>(
    shutdown: CancellationToken,
    inbound: S,
    answer: F,
) -> MessageStream<pb::SdoSessionAnswer>
where
    S: Stream<Item = Result<pb::SdoSessionRequest, Status>> + Send + Unpin + 'static,
    F: Fn(pb::SdoSessionRequest) -> Fut + Send + Sync + 'static,
    Fut: Future<Output = pb::SdoSessionAnswer> + Send + 'static,
{
    // Every outstanding request holds a slot until its answer is queued,
    // so this channel never holds more than MAX_OUTSTANDING answers (+ a
    // final error).
    let (tx, rx) = mpsc::channel(MAX_OUTSTANDING + 1);
    tokio::spawn(run(shutdown, Arc::new(answer), inbound, tx));
    stream_of(rx)
}

/// The session's reader: reads requests while a slot is free, starts each
/// after the one before it for the same node, and ends when the client
/// has sent everything and every answer is out, or at once (cancelling
/// what runs) when the client goes away or the gateway shuts down.
async fn run<S, F, Fut>(
    shutdown: CancellationToken,
    answer: Arc<F>,
    mut inbound: S,
    tx: mpsc::Sender<Result<pb::SdoSessionAnswer, Status>>,
) where
    S: Stream<Item = Result<pb::SdoSessionRequest, Status>> + Send + Unpin + 'static,
    F: Fn(pb::SdoSessionRequest) -> Fut + Send + Sync + 'static,
    Fut: Future<Output = pb::SdoSessionAnswer> + Send + 'static,
{
    let slots = Arc::new(Semaphore::new(MAX_OUTSTANDING));
    let mut tasks = JoinSet::new();
    // The completion of the last request started per (bus, node): the
    // next one for it waits for that. Closed entries are pruned.
    let mut last: HashMap<(String, u32), oneshot::Receiver<()>> = HashMap::new();
    let mut reading = true;
    loop {
        if !reading && tasks.is_empty() {
            return;
        }
        tokio::select! {
            biased;
            () = shutdown.cancelled() => {
                let _ = tx.send(Err(ApiError::ShuttingDown.into())).await;
                return;
            }
            () = tx.closed() => return,
            Some(_) = tasks.join_next(), if !tasks.is_empty() => {}
            permit = slots.clone().acquire_owned(), if reading => {
                let permit = permit.expect("the slots are never closed");
                tokio::select! {
                    biased;
                    () = shutdown.cancelled() => {
                        let _ = tx.send(Err(ApiError::ShuttingDown.into())).await;
                        return;
                    }
                    () = tx.closed() => return,
                    msg = inbound.next() => match msg.transpose() {
                        Ok(Some(request)) => {
                            let key = node_key(&request);
                            if last.len() >= MAX_OUTSTANDING {
                                last.retain(|_, done| {
                                    !matches!(
                                        done.try_recv(),
                                        Err(oneshot::error::TryRecvError::Closed)
                                    )
                                });
                            }
                            let (done, done_rx) = oneshot::channel::<()>();
                            let before = last.insert(key, done_rx);
                            let answer = answer.clone();
                            let tx = tx.clone();
                            tasks.spawn(async move {
                                if let Some(before) = before {
                                    // Closed when the one before is answered.
                                    let _ = before.await;
                                }
                                let answer = answer(request).await;
                                let _ = tx.send(Ok(answer)).await;
                                drop(permit);
                                drop(done);
                            });
                        }
                        // The client sent everything: answer what is
                        // outstanding, then end.
                        Ok(None) => reading = false,
                        // The client went away (cancelled, reset): drop
                        // everything outstanding.
                        Err(_) => return,
                    },
                }
            }
        }
    }
}

/// The order key of a request: its bus and node as sent (a request that is
/// neither read nor write has its own empty key).
fn node_key(r: &pb::SdoSessionRequest) -> (String, u32) {
    match &r.request {
        Some(pb::sdo_session_request::Request::Read(q)) => (q.bus.clone(), q.node),
        Some(pb::sdo_session_request::Request::Write(q)) => (q.bus.clone(), q.node),
        None => (String::new(), 0),
    }
}

/// The caller's role is enough for the unary RPC a request stands for,
/// and its call rate has room for one more call.
pub(super) fn check_role(caller: &Caller, rpc: &str) -> Result<(), ApiError> {
    if let Some(budget) = &caller.budget {
        budget.take().map_err(|e| {
            ApiError::refused(
                tonic::Code::ResourceExhausted,
                crate::security::limit_reason(&e.0),
                e.0,
                Vec::new(),
            )
        })?;
    }
    let Some(id) = &caller.identity else {
        return Ok(());
    };
    let needed = roles::session_request_role(&format!("/cangate.v1.Canopen/{rpc}"))
        .unwrap_or(Role::Engineer);
    if id.role < needed {
        return Err(ApiError::PermissionDenied(format!(
            "an SdoSession {} needs role {needed} (as {rpc}); {} holds role {}",
            if rpc == "WriteSdo" { "write" } else { "read" },
            id.name,
            id.role
        )));
    }
    Ok(())
}

/// A write of a session changes a device as WriteSdo does: the audit log
/// gets a line for it (the session itself, opened by a viewer's role, is
/// not audited as a state-changing call); of the writes refused for the
/// role, the session's first.
pub(super) fn audit_write(
    caller: &Caller,
    bus: &str,
    node: u32,
    index: u32,
    sub: u32,
    object: &str,
    result: &Result<pb::WriteSdoResponse, ApiError>,
) {
    let who = caller
        .identity
        .as_ref()
        .map_or(caller.name.as_str(), |i| i.name.as_str());
    if matches!(result, Err(ApiError::PermissionDenied(_)))
        && caller.refused_writes.fetch_add(1, Ordering::Relaxed) > 0
    {
        return;
    }
    let object = crate::not_found::quote_prefix(object);
    match result {
        Ok(_) => tracing::info!(
            target: crate::security::auth::AUDIT_TARGET,
            %who,
            method = "/cangate.v1.Canopen/SdoSession write",
            %bus,
            node,
            index = %format_args!("0x{index:04X}"),
            sub,
            %object,
            code = "OK",
            "rpc"
        ),
        Err(e) => tracing::warn!(
            target: crate::security::auth::AUDIT_TARGET,
            %who,
            method = "/cangate.v1.Canopen/SdoSession write",
            %bus,
            node,
            index = %format_args!("0x{index:04X}"),
            sub,
            %object,
            code = crate::metrics::code_name(e.code()),
            message = %e,
            "rpc"
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicUsize;
    use tokio::sync::Notify;

    /// A request to its own node (no order between them).
    fn request(id: u64) -> Result<pb::SdoSessionRequest, Status> {
        Ok(pb::SdoSessionRequest {
            id,
            request: Some(pb::sdo_session_request::Request::Read(pb::ReadSdoRequest {
                bus: "b".into(),
                node: id as u32,
                ..Default::default()
            })),
        })
    }

    /// Lets every task of this single-threaded runtime run until all
    /// wait: each yield runs every task that is ready once (far more
    /// rounds than the session's few steps per request need; no clock).
    async fn settle() {
        for _ in 0..10_000 {
            tokio::task::yield_now().await;
        }
    }

    /// Beyond MAX_OUTSTANDING unanswered requests the session reads no
    /// more; each answer lets one more in; answers carry their ids.
    #[tokio::test]
    async fn the_session_stops_reading_at_the_outstanding_bound() {
        let (tx, rx) = mpsc::channel(200);
        for id in 1..=100 {
            tx.send(request(id)).await.unwrap();
        }
        let started = Arc::new(AtomicUsize::new(0));
        let release = Arc::new(Notify::new());
        let (s, r) = (started.clone(), release.clone());
        let mut answers = serve(
            CancellationToken::new(),
            tokio_stream::wrappers::ReceiverStream::new(rx),
            move |req: pb::SdoSessionRequest| {
                let (s, r) = (s.clone(), r.clone());
                async move {
                    s.fetch_add(1, Ordering::SeqCst);
                    r.notified().await;
                    pb::SdoSessionAnswer {
                        id: req.id,
                        result: None,
                    }
                }
            },
        );
        settle().await;
        assert_eq!(started.load(Ordering::SeqCst), MAX_OUTSTANDING);
        // The rest is still in the client's queue.
        assert_eq!(tx.capacity(), 200 - (100 - MAX_OUTSTANDING));
        release.notify_one();
        let a = answers.next().await.unwrap().unwrap();
        assert!((1..=64).contains(&a.id), "{a:?}");
        settle().await;
        assert_eq!(started.load(Ordering::SeqCst), MAX_OUTSTANDING + 1);
    }

    /// Counts its drops.
    struct DropCount(Arc<AtomicUsize>);
    impl Drop for DropCount {
        fn drop(&mut self) {
            self.0.fetch_add(1, Ordering::SeqCst);
        }
    }

    /// A client that goes away (drops the answers) drops every
    /// outstanding request's future: the transfers' callers are gone.
    #[tokio::test]
    async fn a_client_that_goes_away_drops_what_is_outstanding() {
        let (tx, rx) = mpsc::channel(10);
        for id in 1..=5 {
            tx.send(request(id)).await.unwrap();
        }
        let dropped = Arc::new(AtomicUsize::new(0));
        let d = dropped.clone();
        let answers = serve(
            CancellationToken::new(),
            tokio_stream::wrappers::ReceiverStream::new(rx),
            move |_req: pb::SdoSessionRequest| {
                let guard = DropCount(d.clone());
                async move {
                    let _guard = guard;
                    std::future::pending::<pb::SdoSessionAnswer>().await
                }
            },
        );
        settle().await;
        assert_eq!(dropped.load(Ordering::SeqCst), 0);
        drop(answers);
        settle().await;
        assert_eq!(dropped.load(Ordering::SeqCst), 5);
    }

    /// The client's end of sending: what is outstanding is answered, in
    /// order per node, then the answers end.
    #[tokio::test]
    async fn the_end_of_requests_ends_the_answers_after_the_last() {
        let (tx, rx) = mpsc::channel(10);
        for id in 1..=6 {
            let mut r = request(id).unwrap();
            if let Some(pb::sdo_session_request::Request::Read(q)) = &mut r.request {
                q.node = 7;
            }
            tx.send(Ok(r)).await.unwrap();
        }
        drop(tx);
        let mut answers = serve(
            CancellationToken::new(),
            tokio_stream::wrappers::ReceiverStream::new(rx),
            |req: pb::SdoSessionRequest| async move {
                // Later requests finish sooner, if nothing kept the order.
                for _ in 0..(10 - req.id) * 10 {
                    tokio::task::yield_now().await;
                }
                pb::SdoSessionAnswer {
                    id: req.id,
                    result: None,
                }
            },
        );
        let mut ids = Vec::new();
        while let Some(a) = answers.next().await {
            ids.push(a.unwrap().id);
        }
        assert_eq!(ids, vec![1, 2, 3, 4, 5, 6]);
    }
}
