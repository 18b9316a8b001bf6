//! Sources of the runtime as gRPC server streams: the one forwarding loop
//! ([`spawn_forwarding`]: receive, map, send; end when the client goes
//! away, the source ends, the map says so, or the gateway shuts down) over
//! any [`Source`]: a broadcast with its lag counted ([`spawn_forward`]), a
//! bus subscription in batches, a program download's progress.

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

/// How long the shutdown status may wait for room in a stream whose
/// client reads no more: the transport's graceful shutdown waits for the
/// stream.
const SHUTDOWN_SEND: std::time::Duration = std::time::Duration::from_secs(1);

/// Where a forwarded stream's items come from.
pub(crate) trait Source: Send + 'static {
    /// What the source yields.
    type Item: Send + 'static;
    /// The next item, or how many were lost before it; `None` once the
    /// source has ended.
    fn next(&mut self) -> impl std::future::Future<Output = Option<Received<Self::Item>>> + Send;
}

/// A broadcast whose losses are counted in the metrics under the RPC's
/// name (see [`recv_counted`]).
pub(crate) struct Broadcast<T> {
    rpc: &'static str,
    rx: broadcast::Receiver<T>,
}

impl<T: Clone + Send + 'static> Source for Broadcast<T> {
    type Item = T;
    async fn next(&mut self) -> Option<Received<T>> {
        recv_counted(self.rpc, &mut self.rx).await
    }
}

/// A queue of one producer (it loses nothing).
impl<T: Send + 'static> Source for mpsc::Receiver<T> {
    type Item = T;
    async fn next(&mut self) -> Option<Received<T>> {
        self.recv().await.map(Received::Item)
    }
}

/// What the forwarding loop does with what it received.
pub(crate) enum Forward<M> {
    /// Nothing to send.
    Skip,
    /// Send the message and go on.
    Send(M),
    /// Send the message (or end with the status) and end the stream.
    Last(Result<M, Status>),
}

/// Spawns the loop that forwards `source` into `tx`: `initial` first, then
/// each received item or loss mapped by `map`, which also hears of the
/// source's end (`None`; the stream ends after it). The client going away
/// ends the loop at once; the gateway's shutdown ends it with
/// `at_shutdown`, also while a message waits for room, and so does the
/// source's end during the shutdown (its task may end before this one
/// sees the token). Several sources may share one `tx` (one stream over
/// several buses).
pub(crate) fn spawn_forwarding<S, M>(
    mut source: S,
    tx: mpsc::Sender<Result<M, Status>>,
    initial: Vec<M>,
    shutdown: CancellationToken,
    at_shutdown: AtShutdown,
    mut map: impl FnMut(Option<Received<S::Item>>) -> Forward<M> + Send + 'static,
) where
    S: Source,
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
                biased;
                _ = shutdown.cancelled() => break,
                _ = tx.closed() => return,
                r = source.next() => r,
            };
            let ended = received.is_none();
            if ended && shutdown.is_cancelled() {
                break;
            }
            let (message, last) = match map(received) {
                Forward::Skip if ended => return,
                Forward::Skip => continue,
                Forward::Send(m) => (Ok(m), ended),
                Forward::Last(r) => (r, true),
            };
            tokio::select! {
                biased;
                _ = shutdown.cancelled() => break,
                r = tx.send(message) => if r.is_err() || last { return },
            }
        }
        if let AtShutdown::Unavailable = at_shutdown {
            let status = super::error::ApiError::ShuttingDown.into();
            let _ = tokio::time::timeout(SHUTDOWN_SEND, tx.send(Err(status))).await;
        }
    });
}

/// [`spawn_forwarding`] of a broadcast: each received item or loss mapped
/// by `map` (`None`: nothing to send); losses are counted in the metrics
/// under `rpc`.
pub(crate) fn spawn_forward<T, M>(
    rpc: &'static str,
    rx: broadcast::Receiver<T>,
    tx: mpsc::Sender<Result<M, Status>>,
    initial: Vec<M>,
    shutdown: CancellationToken,
    at_shutdown: AtShutdown,
    mut map: impl FnMut(Received<T>) -> Option<M> + Send + 'static,
) where
    T: Clone + Send + 'static,
    M: Send + 'static,
{
    spawn_forwarding(
        Broadcast { rpc, rx },
        tx,
        initial,
        shutdown,
        at_shutdown,
        move |received| match received.and_then(&mut map) {
            Some(m) => Forward::Send(m),
            None => Forward::Skip,
        },
    );
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

/// A server stream of batches read straight from a broadcast by the
/// transport's own task, with no forwarding task between them: each
/// message takes every item ready when the transport asks for the next one
/// (at least one mapped item, at most `max`), items and losses mapped by
/// `map` (`None`: nothing to send). With many subscribers to one source
/// this halves the task wake-ups per item (the forwarding task of
/// [`spawn_forward`] is woken for each item, then wakes the transport's),
/// which is most of a fan-out's cost. Losses are counted in the metrics
/// under `rpc`; the stream ends when the source closes, or with
/// UNAVAILABLE when the gateway shuts down. A paused reader leaves its
/// items in the broadcast until it lags, then is told how many it lost.
pub(crate) fn broadcast_batches<T, M, B>(
    rpc: &'static str,
    rx: broadcast::Receiver<T>,
    shutdown: CancellationToken,
    max: usize,
    map: impl FnMut(Received<T>) -> Option<M> + Send + 'static,
    batch: fn(Vec<M>) -> B,
) -> MessageStream<B>
where
    T: Clone + Send + 'static,
    M: Send + 'static,
    B: Send + 'static,
{
    /// What one subscriber carries from message to message.
    struct Subscriber<T, F> {
        rx: broadcast::Receiver<T>,
        map: F,
        /// Registered once: a fresh `cancelled()` per message would take
        /// the token's lock on every item for every subscriber.
        shutdown: Pin<Box<tokio_util::sync::WaitForCancellationFutureOwned>>,
        ended: bool,
    }
    let max = max.max(1);
    let first = Subscriber {
        rx,
        map,
        shutdown: Box::pin(shutdown.cancelled_owned()),
        ended: false,
    };
    Box::pin(futures::stream::unfold(first, move |mut sub| async move {
        if sub.ended {
            return None;
        }
        loop {
            // The source first: the shutdown is only polled (and its waker
            // refreshed) when nothing is ready.
            let received = tokio::select! {
                biased;
                r = recv_counted(rpc, &mut sub.rx) => r,
                _ = sub.shutdown.as_mut() => {
                    sub.ended = true;
                    return Some((Err(super::error::ApiError::ShuttingDown.into()), sub));
                }
            };
            let received = received?;
            let mut items: Vec<M> = (sub.map)(received).into_iter().collect();
            while items.len() < max {
                let next = match sub.rx.try_recv() {
                    Ok(item) => Received::Item(item),
                    Err(broadcast::error::TryRecvError::Lagged(n)) => {
                        crate::metrics::stream_lag(rpc, n);
                        Received::Lost(n)
                    }
                    Err(broadcast::error::TryRecvError::Empty) => break,
                    Err(broadcast::error::TryRecvError::Closed) => {
                        sub.ended = true;
                        break;
                    }
                };
                items.extend((sub.map)(next));
            }
            if !items.is_empty() {
                return Some((Ok(batch(items)), sub));
            }
            if sub.ended {
                return None;
            }
        }
    }))
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

    /// The map sees every item and the source's end; a last message ends
    /// the stream (what follows in the source is not sent).
    #[tokio::test]
    async fn a_last_message_ends_the_stream_and_the_map_hears_of_the_end() {
        let (items, source) = mpsc::channel(8);
        for i in [1, 2, 3] {
            items.send(i).await.unwrap();
        }
        let (tx, mut rx) = mpsc::channel(8);
        spawn_forwarding(
            source,
            tx,
            vec![0],
            CancellationToken::new(),
            AtShutdown::Unavailable,
            |r| match r {
                Some(Received::Item(2)) => Forward::Last(Ok(20)),
                Some(Received::Item(i)) => Forward::Send(i * 10),
                Some(Received::Lost(_)) => Forward::Skip,
                None => Forward::Last(Err(Status::unavailable("ended"))),
            },
        );
        let mut got = Vec::new();
        while let Some(m) = rx.recv().await {
            got.push(m.unwrap());
        }
        assert_eq!(got, vec![0, 10, 20]);

        // The source's end, mapped.
        let (items, source) = mpsc::channel::<i32>(8);
        drop(items);
        let (tx, mut rx) = mpsc::channel::<Result<i32, Status>>(8);
        spawn_forwarding(
            source,
            tx,
            Vec::new(),
            CancellationToken::new(),
            AtShutdown::Unavailable,
            |r| match r {
                Some(_) => Forward::Skip,
                None => Forward::Last(Err(Status::unavailable("ended"))),
            },
        );
        assert_eq!(rx.recv().await.unwrap().unwrap_err().message(), "ended");
        assert!(rx.recv().await.is_none());
    }

    /// At shutdown a message still waiting for room in a stream whose
    /// reader stopped is given up: the stream ends with UNAVAILABLE after
    /// what the reader already had, nothing after it.
    #[tokio::test]
    async fn at_shutdown_a_message_waiting_for_room_is_given_up() {
        let (items, source) = mpsc::channel(8);
        items.send(2).await.unwrap();
        let (tx, mut rx) = mpsc::channel(1);
        let shutdown = CancellationToken::new();
        spawn_forwarding(
            source,
            tx,
            vec![1],
            shutdown.clone(),
            AtShutdown::Unavailable,
            |r| match r {
                Some(Received::Item(i)) => Forward::Send(i),
                _ => Forward::Skip,
            },
        );
        // One thread: the forwarding task runs at these yields until it
        // waits for room for 2 (1 fills the stream).
        for _ in 0..8 {
            tokio::task::yield_now().await;
        }
        shutdown.cancel();
        assert_eq!(rx.recv().await.unwrap().unwrap(), 1);
        let e = rx.recv().await.unwrap().unwrap_err();
        assert_eq!(e.code(), tonic::Code::Unavailable);
        assert!(rx.recv().await.is_none(), "nothing after the shutdown");
    }

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
    async fn broadcast_batches_take_what_is_ready_map_losses_and_end_with_the_source() {
        let (tx, rx) = broadcast::channel(4);
        let shutdown = CancellationToken::new();
        // Odd items only; a loss becomes -n.
        let map = |r: Received<i32>| match r {
            Received::Item(i) => (i % 2 == 1).then_some(i),
            Received::Lost(n) => Some(-(n as i32)),
        };
        let mut s = broadcast_batches("test", rx, shutdown, 2, map, |v: Vec<i32>| v);
        for i in 0..4 {
            tx.send(i).unwrap();
        }
        // 0 is dropped by the map; at most 2 items per message.
        assert_eq!(s.next().await.unwrap().unwrap(), vec![1, 3]);
        // Six more into a capacity of 4: the two oldest are lost.
        for i in 4..10 {
            tx.send(i).unwrap();
        }
        assert_eq!(s.next().await.unwrap().unwrap(), vec![-2, 7]);
        assert_eq!(s.next().await.unwrap().unwrap(), vec![9]);
        // Nothing ready: the next message waits for the next mapped item.
        let next = tokio::spawn(async move { (s.next().await, s) });
        tokio::task::yield_now().await;
        tx.send(10).unwrap();
        tx.send(11).unwrap();
        drop(tx);
        let (m, mut s) = next.await.unwrap();
        assert_eq!(m.unwrap().unwrap(), vec![11]);
        assert!(s.next().await.is_none(), "the source closed");
    }

    #[tokio::test]
    async fn broadcast_batches_end_with_unavailable_at_shutdown() {
        let (tx, rx) = broadcast::channel::<i32>(4);
        let shutdown = CancellationToken::new();
        let mut s = broadcast_batches(
            "test",
            rx,
            shutdown.clone(),
            8,
            |r| match r {
                Received::Item(i) => Some(i),
                Received::Lost(_) => None,
            },
            |v: Vec<i32>| v,
        );
        tx.send(1).unwrap();
        assert_eq!(s.next().await.unwrap().unwrap(), vec![1]);
        shutdown.cancel();
        let e = s.next().await.unwrap().unwrap_err();
        assert_eq!(e.code(), tonic::Code::Unavailable);
        assert!(s.next().await.is_none());
        drop(tx);
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
