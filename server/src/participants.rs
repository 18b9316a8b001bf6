//! The register of bus participants: who each client sender on a bus is.
//!
//! Clients send on a bus as participants: each one is a [`ClientId`] whose
//! frames the bus delivers to everyone else as received, and the streams
//! that show those frames name their sender. Every edge that lets clients
//! send (the gRPC `Bus` service, the socketcand endpoint) registers its
//! senders here, in one register the server shares between them, so a
//! frame sent through one edge is named in the streams of another.

use cangate_can::ClientId;
use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, Mutex};

/// Names of senders that ended, kept for the frames of theirs still on
/// their way to slow streams (see [`SenderNames`]).
pub const ENDED_SENDER_NAMES: usize = 4096;

/// Who each sender of client frames is (`FrameSender.client`): the caller
/// of every `SendFrames` call and `Attach` stream in progress, and of the
/// last [`ENDED_SENDER_NAMES`] that ended, whose frames may still wait in
/// the queue of a slow stream. Bounded: an older sender's frames are shown
/// with its number only.
#[derive(Debug, Default)]
pub struct SenderNames {
    inner: Mutex<SenderNamesInner>,
}

#[derive(Debug, Default)]
struct SenderNamesInner {
    names: HashMap<ClientId, Arc<str>>,
    ended: VecDeque<ClientId>,
}

impl SenderNames {
    /// Registers a sender while the returned guard lives (a gRPC call, a
    /// socketcand session).
    pub fn register(self: &Arc<Self>, id: ClientId, name: String) -> SenderGuard {
        self.lock().names.insert(id, Arc::from(name));
        SenderGuard {
            names: self.clone(),
            id,
        }
    }

    /// The name of a sender, if it is still known.
    pub fn name(&self, id: ClientId) -> Option<Arc<str>> {
        self.lock().names.get(&id).cloned()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, SenderNamesInner> {
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// A name lookup for one stream's conversions: it remembers the last
    /// sender, so a run of one client's frames takes the lock once.
    pub fn lookup(self: &Arc<Self>) -> impl FnMut(ClientId) -> String + Send + 'static {
        let names = self.clone();
        let mut last: Option<(ClientId, String)> = None;
        move |id| {
            if let Some((l, name)) = &last
                && *l == id
            {
                return name.clone();
            }
            let name = names.name(id).map(|n| n.to_string()).unwrap_or_default();
            last = Some((id, name.clone()));
            name
        }
    }
}

/// A registered sender; ends its registration when dropped.
#[derive(Debug)]
pub struct SenderGuard {
    names: Arc<SenderNames>,
    id: ClientId,
}

impl Drop for SenderGuard {
    fn drop(&mut self) {
        let mut inner = self.names.lock();
        inner.ended.push_back(self.id);
        while inner.ended.len() > ENDED_SENDER_NAMES {
            if let Some(old) = inner.ended.pop_front() {
                inner.names.remove(&old);
            }
        }
    }
}
