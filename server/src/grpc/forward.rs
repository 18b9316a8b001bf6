//! Broadcasts of the runtime as gRPC server streams: the one forwarding
//! loop (receive, count lag, map, send; end when the client goes away, the
//! source closes or the gateway shuts down).

use std::pin::Pin;
use tokio::sync::{broadcast, mpsc};
use tokio_stream::Stream;
use tokio_util::sync::CancellationToken;
use tonic::Status;

/// A server stream of `M`.
pub(crate) type MessageStream<M> = Pin<Box<dyn Stream<Item = Result<M, Status>> + Send>>;

/// What a subscriber got from a broadcast.
pub(crate) enum Received<T> {
    /// The next item.
    Item(T),
    /// This many items were lost because the subscriber fell behind.
    Lost(u64),
}

/// The next item of `rx`, or how many were lost to lag (counted in the
/// metrics under the RPC's name `rpc`); `None` once the sender is gone.
pub(crate) async fn recv_counted<T: Clone>(
    rpc: &'static str,
    rx: &mut broadcast::Receiver<T>,
) -> Option<Received<T>> {
    match rx.recv().await {
        Ok(item) => Some(Received::Item(item)),
        Err(broadcast::error::RecvError::Lagged(n)) => {
            crate::metrics::stream_lag(rpc, n);
            Some(Received::Lost(n))
        }
        Err(broadcast::error::RecvError::Closed) => None,
    }
}

/// How a forwarded stream ends when the gateway shuts down.
#[derive(Clone, Copy)]
pub(crate) enum AtShutdown {
    /// The stream ends with UNAVAILABLE "the gateway is shutting down".
    Unavailable,
    /// The stream just ends (OK).
    End,
}

/// Spawns the loop that forwards `rx` into `tx`: `initial` first, then
/// each received item or loss mapped by `map` (`None`: nothing to send).
/// Several sources may share one `tx` (one stream over several buses).
pub(crate) fn spawn_forward<T, M>(
    rpc: &'static str,
    mut rx: broadcast::Receiver<T>,
    tx: mpsc::Sender<Result<M, Status>>,
    initial: Vec<M>,
    shutdown: CancellationToken,
    at_shutdown: AtShutdown,
    mut map: impl FnMut(Received<T>) -> Option<M> + Send + 'static,
) where
    T: Clone + Send + 'static,
    M: Send + 'static,
{
    tokio::spawn(async move {
        for m in initial {
            if tx.send(Ok(m)).await.is_err() {
                return;
            }
        }
        loop {
            let received = tokio::select! {
                _ = shutdown.cancelled() => {
                    if let AtShutdown::Unavailable = at_shutdown {
                        let _ = tx.send(Err(super::error::ApiError::ShuttingDown.into())).await;
                    }
                    return;
                }
                _ = tx.closed() => return,
                r = recv_counted(rpc, &mut rx) => r,
            };
            let Some(received) = received else { return };
            if let Some(m) = map(received)
                && tx.send(Ok(m)).await.is_err()
            {
                return;
            }
        }
    });
}

/// The receiving end of `tx` as a server stream.
pub(crate) fn stream_of<M: Send + 'static>(
    rx: mpsc::Receiver<Result<M, Status>>,
) -> MessageStream<M> {
    Box::pin(tokio_stream::wrappers::ReceiverStream::new(rx))
}
