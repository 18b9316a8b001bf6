//! Connection slots of the text-protocol endpoints (socketcand, CiA 309-3):
//! at most `max` connections and `per_peer` from one address, where idle
//! connections that never authenticate give their slot to a newcomer, so
//! they cannot lock out a client with a token; and where they run: on the
//! bus thread ([`listen_on_bus_thread`]).

use std::sync::Arc;
use tokio_util::sync::CancellationToken;

/// The connections that hold a slot of an endpoint, for the admission of
/// new ones ([`Slots::admit`]).
#[derive(Debug, Default)]
pub struct Slots {
    inner: std::sync::Mutex<SlotList>,
}

#[derive(Debug, Default)]
struct SlotList {
    next_id: u64,
    /// Oldest first.
    slots: Vec<Slot>,
}

#[derive(Debug)]
struct Slot {
    id: u64,
    peer: std::net::IpAddr,
    /// The client authenticated (opened a bus, logged in): never given up
    /// for a newcomer.
    opened: bool,
    /// Fired when the slot is given to a newcomer.
    evict: CancellationToken,
}

/// A connection's slot; freed when dropped.
#[derive(Debug)]
pub struct SlotGuard {
    slots: Arc<Slots>,
    id: u64,
    /// Fires when the connection gave its slot up (see [`Slots::admit`]).
    evicted: CancellationToken,
}

impl SlotGuard {
    /// Fires when the connection gave its slot up to a newcomer.
    pub fn evicted(&self) -> &CancellationToken {
        &self.evicted
    }

    /// The connection authenticated (opened a bus, logged in): it keeps
    /// its slot.
    pub fn opened(&self) {
        let mut list = self.slots.lock();
        if let Some(s) = list.slots.iter_mut().find(|s| s.id == self.id) {
            s.opened = true;
        }
    }
}

impl Drop for SlotGuard {
    fn drop(&mut self) {
        self.slots.lock().slots.retain(|s| s.id != self.id);
    }
}

impl Slots {
    fn lock(&self) -> std::sync::MutexGuard<'_, SlotList> {
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// A slot for a new connection from `peer`, within `max` connections
    /// and `per_peer` from one address. When one of them is reached, the
    /// oldest connection that has not opened a bus (from that address,
    /// for `per_peer`) gives its slot up: idle connections that never
    /// authenticate cannot lock out a client that does. Refused (with the
    /// setting to name) when every counted connection has a bus open.
    pub fn admit(
        self: &Arc<Self>,
        peer: std::net::IpAddr,
        max: usize,
        per_peer: usize,
    ) -> Result<SlotGuard, String> {
        let mut list = self.lock();
        let evict_oldest = |list: &mut SlotList, from: Option<std::net::IpAddr>| {
            let i = list
                .slots
                .iter()
                .position(|s| !s.opened && from.is_none_or(|p| s.peer == p))?;
            let victim = list.slots.remove(i);
            victim.evict.cancel();
            Some(())
        };
        if list.slots.iter().filter(|s| s.peer == peer).count() >= per_peer
            && evict_oldest(&mut list, Some(peer)).is_none()
        {
            return Err(format!(
                "too many connections from {peer} (max_connections_per_peer = {per_peer})"
            ));
        }
        if list.slots.len() >= max && evict_oldest(&mut list, None).is_none() {
            return Err(format!("too many connections (max_connections = {max})"));
        }
        list.next_id += 1;
        let id = list.next_id;
        let evicted = CancellationToken::new();
        list.slots.push(Slot {
            id,
            peer,
            opened: false,
            evict: evicted.clone(),
        });
        Ok(SlotGuard {
            slots: self.clone(),
            id,
            evicted,
        })
    }
}

/// How a text-protocol endpoint's [`accept_connections`] admits clients.
pub struct AcceptPolicy {
    /// The endpoint's name in log lines ("socketcand", "CiA 309-3").
    pub name: &'static str,
    /// `max_connections`.
    pub max: usize,
    /// `max_connections_per_peer`.
    pub per_peer: usize,
    /// Bound of the refusal line's write to a client turned away.
    pub write_timeout: std::time::Duration,
    /// The line (with its end) that tells a client turned away why, in the
    /// endpoint's own protocol.
    pub refusal: fn(&str) -> String,
    /// Counts a client turned away.
    pub on_refused: fn(),
}

/// Accepts connections on `listener` until `shutdown`, each within a slot
/// of [`Slots`] (a client turned away gets the policy's refusal line), and
/// runs `serve` for each as a task; waits for them all at the end. Accept
/// errors (out of descriptors and the like) are retried shortly.
pub async fn accept_connections<F, Fut>(
    listener: tokio::net::TcpListener,
    policy: AcceptPolicy,
    shutdown: CancellationToken,
    mut serve: F,
) where
    F: FnMut(tokio::net::TcpStream, std::net::SocketAddr, SlotGuard) -> Fut,
    Fut: std::future::Future<Output = ()> + Send + 'static,
{
    use tokio::io::AsyncWriteExt;
    let mut connections = tokio::task::JoinSet::new();
    let slots = Arc::new(Slots::default());
    loop {
        while connections.try_join_next().is_some() {}
        let accepted = tokio::select! {
            biased;
            _ = shutdown.cancelled() => break,
            a = listener.accept() => a,
        };
        let (mut stream, peer) = match accepted {
            Ok(a) => a,
            Err(e) => {
                tracing::warn!("{} accept: {e}", policy.name);
                tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                continue;
            }
        };
        match slots.admit(peer.ip(), policy.max, policy.per_peer) {
            Ok(slot) => {
                connections.spawn(serve(stream, peer, slot));
            }
            Err(message) => {
                (policy.on_refused)();
                let line = (policy.refusal)(&message);
                let write_timeout = policy.write_timeout;
                connections.spawn(async move {
                    let _ = tokio::time::timeout(write_timeout, stream.write_all(line.as_bytes()))
                        .await;
                });
            }
        }
    }
    drop(listener);
    while connections.join_next().await.is_some() {}
}

/// Binds `addr` and runs `serve` on the listener as a task of `bus_side`,
/// the runtime of the bus thread (`gateway-bus`), so that every connection
/// of the endpoint is served there. Returns the bound address and the
/// task.
///
/// Why: a text-protocol command is a short exchange with the bus side (an
/// SDO read, a frame out and one back). Served on the gRPC side's runtime,
/// each exchange crossed threads twice, a sleep and a wake-up each way,
/// and those, not the protocol's work, were most of its latency and CPU
/// ("Wake-ups cost more than frames" in docs/design.md). On the bus
/// thread the request reaches the CANopen master or the bus task, and
/// the answer the connection, as a task wake-up on the same thread, as in
/// the single-threaded peers (canopend, socketcand). What a connection may
/// cost that thread is bounded: one command at a time, lines of at most
/// `max_line_bytes`, `max_connections`, and tokio's cooperative budget on
/// every socket operation.
///
/// # Errors
/// The address cannot be bound.
pub fn listen_on_bus_thread<F, Fut>(
    bus_side: &tokio::runtime::Handle,
    addr: std::net::SocketAddr,
    serve: F,
) -> std::io::Result<(std::net::SocketAddr, tokio::task::JoinHandle<()>)>
where
    F: FnOnce(tokio::net::TcpListener) -> Fut + Send + 'static,
    Fut: std::future::Future<Output = ()> + Send + 'static,
{
    let listener = std::net::TcpListener::bind(addr)?;
    listener.set_nonblocking(true)?;
    let bound = listener.local_addr()?;
    // Registered with the bus runtime's reactor, from a task on it: its
    // connections' sockets are then polled by the bus thread.
    let task = bus_side.spawn(async move {
        match tokio::net::TcpListener::from_std(listener) {
            Ok(l) => serve(l).await,
            Err(e) => tracing::error!(%bound, "cannot listen on the bus thread: {e}"),
        }
    });
    Ok((bound, task))
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    /// A current-thread runtime on a thread of its own, as the gateway's
    /// bus runtime is.
    fn bus_like_runtime(name: &str) -> (tokio::runtime::Handle, CancellationToken) {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("runtime");
        let handle = rt.handle().clone();
        let stop = CancellationToken::new();
        let until = stop.clone();
        std::thread::Builder::new()
            .name(name.into())
            .spawn(move || rt.block_on(until.cancelled()))
            .expect("thread");
        (handle, stop)
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn connections_are_served_on_the_bus_thread() {
        let (bus_side, stop) = bus_like_runtime("test-bus-thread");
        let (addr, task) = listen_on_bus_thread(
            &bus_side,
            "127.0.0.1:0".parse().expect("address"),
            |listener| async move {
                let (mut stream, _) = listener.accept().await.expect("accept");
                let name = std::thread::current().name().unwrap_or("").to_owned();
                stream.write_all(name.as_bytes()).await.expect("write");
            },
        )
        .expect("bind");
        let mut client = tokio::net::TcpStream::connect(addr).await.expect("connect");
        let mut served_on = String::new();
        client.read_to_string(&mut served_on).await.expect("read");
        assert_eq!(served_on, "test-bus-thread");
        task.await.expect("the listener's task");
        stop.cancel();
    }

    #[test]
    fn an_address_in_use_is_an_error_not_a_task() {
        let (bus_side, stop) = bus_like_runtime("test-bus-thread-2");
        let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
        let addr = taken.local_addr().expect("address");
        let r = listen_on_bus_thread(&bus_side, addr, |_| async {});
        assert!(r.is_err(), "a second listener on {addr}");
        stop.cancel();
    }
}
