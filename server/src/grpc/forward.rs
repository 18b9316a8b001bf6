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

/// The receiving end of `tx` as a server stream of batches: each message
/// takes every item ready when the transport asks for the next one (at
/// least one, at most `max`), so a reader that falls behind catches up
/// with fewer, larger messages. An error ends the stream after the items
/// before it.
pub(crate) fn batches_of<M: Send + 'static, B: Send + 'static>(
    rx: mpsc::Receiver<Result<M, Status>>,
    max: usize,
    batch: fn(Vec<M>) -> B,
) -> MessageStream<B> {
    /// The receiver, and an error to send after the batch before it.
    type State<M> = (mpsc::Receiver<Result<M, Status>>, Option<Status>);
    let max = max.max(1);
    Box::pin(futures::stream::unfold(
        (rx, None),
        move |(mut rx, error): State<M>| async move {
            if let Some(e) = error {
                // The last message; the stream ends after it.
                rx.close();
                return Some((Err(e), (rx, None)));
            }
            let mut ready = Vec::new();
            if rx.recv_many(&mut ready, max).await == 0 {
                return None;
            }
            let mut items = Vec::with_capacity(ready.len());
            let mut error = None;
            for r in ready {
                match r {
                    Ok(m) => items.push(m),
                    Err(e) => {
                        error = Some(e);
                        break;
                    }
                }
            }
            if items.is_empty() {
                return error.map(|e| {
                    rx.close();
                    (Err(e), (rx, None))
                });
            }
            Some((Ok(batch(items)), (rx, error)))
        },
    ))
}

/// The receiving end of `tx` as a server stream.
pub(crate) fn stream_of<M: Send + 'static>(
    rx: mpsc::Receiver<Result<M, Status>>,
) -> MessageStream<M> {
    Box::pin(tokio_stream::wrappers::ReceiverStream::new(rx))
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio_stream::StreamExt;

    #[tokio::test]
    async fn batches_take_what_is_ready_in_order_and_end_at_an_error() {
        let (tx, rx) = mpsc::channel(16);
        for i in 0..5 {
            tx.send(Ok(i)).await.unwrap();
        }
        let mut s = batches_of(rx, 3, |v: Vec<i32>| v);
        assert_eq!(s.next().await.unwrap().unwrap(), vec![0, 1, 2]);
        assert_eq!(s.next().await.unwrap().unwrap(), vec![3, 4]);
        // Nothing ready: the next batch waits for the next item.
        tx.send(Ok(5)).await.unwrap();
        tx.send(Err(Status::unavailable("gone"))).await.unwrap();
        tx.send(Ok(6)).await.unwrap();
        assert_eq!(s.next().await.unwrap().unwrap(), vec![5]);
        let e = s.next().await.unwrap().unwrap_err();
        assert_eq!(e.code(), tonic::Code::Unavailable);
        assert!(s.next().await.is_none(), "nothing after the error");
    }

    #[tokio::test]
    async fn an_error_first_is_sent_alone_and_a_closed_source_ends_the_stream() {
        let (tx, rx) = mpsc::channel(4);
        tx.send(Err(Status::internal("x"))).await.unwrap();
        let mut s = batches_of(rx, 8, |v: Vec<i32>| v);
        assert!(s.next().await.unwrap().is_err());
        assert!(s.next().await.is_none());
        let (tx, rx) = mpsc::channel::<Result<i32, Status>>(4);
        drop(tx);
        let mut s = batches_of(rx, 8, |v: Vec<i32>| v);
        assert!(s.next().await.is_none());
    }
}
