//! Sending many frames to a bus from the command line (`cangate replay`,
//! `cangate gen`): one `Bus.Attach` stream per bus, so the gateway's flow
//! control paces the sender, its per-client raw frame budget counts frames
//! (not calls), and every frame is accounted for: the stream returns each
//! frame of ours once it went out (`receive_own`), and each refused batch
//! as a `SendRefused`. Nothing is lost silently: [`BusWriter::finish`] says
//! how many frames went out, how many were refused and why.

use super::{App, Context, Result};
use cangate_client::can::Frame;
use cangate_client::{AttachEvent, AttachOptions, AttachSender};
use futures::StreamExt;
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::Notify;

/// Most frames in one AttachSend: small messages keep the pacing fine and
/// stay far below the gateway's message size limit.
pub(crate) const BATCH: usize = 256;

/// How long [`BusWriter::finish`] waits, after the last event, for the
/// frames still unaccounted for.
const SETTLE: Duration = Duration::from_secs(3);

/// What happened to the frames a [`BusWriter`] sent.
#[derive(Debug, Default, Clone, PartialEq)]
pub(crate) struct Tally {
    /// Frames handed to the gateway.
    pub(crate) submitted: u64,
    /// Frames seen going out on the bus.
    pub(crate) sent: u64,
    /// Frames the gateway refused, by reason: count and its message.
    pub(crate) refused: BTreeMap<String, (u64, String)>,
    /// Frames of the bus this client did not receive because it read too
    /// slowly: its own frames among them cannot be confirmed.
    pub(crate) lost: u64,
}

impl Tally {
    /// Frames refused, every reason together.
    pub(crate) fn refused_total(&self) -> u64 {
        self.refused.values().map(|(n, _)| n).sum()
    }

    /// Frames neither seen going out nor refused.
    pub(crate) fn unconfirmed(&self) -> u64 {
        self.submitted
            .saturating_sub(self.sent + self.refused_total())
    }

    /// One line for people: `1000 frames sent, 20 refused
    /// (FRAME_RATE_LIMIT: …)`.
    pub(crate) fn summary(&self) -> String {
        let mut text = format!("{} frames sent", self.sent);
        for (reason, (n, message)) in &self.refused {
            text.push_str(&format!(", {n} refused ({reason}: {message})"));
        }
        if self.unconfirmed() > 0 {
            text.push_str(&format!(
                ", {} not confirmed ({} bus frames lost to this client)",
                self.unconfirmed(),
                self.lost
            ));
        }
        text
    }

    /// Every frame went out.
    pub(crate) fn complete(&self) -> bool {
        self.sent >= self.submitted
    }
}

/// One bus's Attach stream, sending.
pub(crate) struct BusWriter {
    bus: String,
    fd: bool,
    sender: AttachSender,
    tally: Arc<Mutex<Tally>>,
    changed: Arc<Notify>,
    events: tokio::task::JoinHandle<()>,
}

impl BusWriter {
    /// Attaches to `bus` (as a CAN FD client when the bus is one).
    pub(crate) async fn open(app: &App, bus: &str) -> Result<BusWriter> {
        let info = app
            .client
            .clone()
            .get_bus(bus)
            .await
            .ctx(format!("bus {bus}"))?;
        let options = AttachOptions {
            receive_own: true,
            fd: info.fd,
            ..AttachOptions::default()
        };
        let attachment = app
            .client
            .attach(bus, &options)
            .await
            .ctx(format!("attaching to {bus}"))?;
        let tally = Arc::new(Mutex::new(Tally::default()));
        let changed = Arc::new(Notify::new());
        let mut stream = attachment.events;
        let (t, c, name) = (tally.clone(), changed.clone(), bus.to_string());
        let events = tokio::spawn(async move {
            while let Some(event) = stream.next().await {
                let Ok(event) = event else { break };
                let mut tally = t.lock().expect("tally");
                match event {
                    AttachEvent::Frame { own: true, .. } => tally.sent += 1,
                    AttachEvent::Refused(r) => {
                        let n = u64::from(r.total.saturating_sub(r.sent));
                        let entry = tally
                            .refused
                            .entry(r.reason.clone())
                            .or_insert((0, r.message.clone()));
                        if entry.0 == 0 {
                            eprintln!("cangate: {name}: frames refused: {}", r.message);
                        }
                        entry.0 += n;
                    }
                    AttachEvent::Lost(n) => tally.lost += n,
                    _ => continue,
                }
                c.notify_waiters();
            }
            c.notify_waiters();
        });
        Ok(BusWriter {
            bus: bus.to_string(),
            fd: info.fd,
            sender: attachment.sender,
            tally,
            changed,
            events,
        })
    }

    /// The bus carries CAN FD.
    pub(crate) fn fd(&self) -> bool {
        self.fd
    }

    /// Sends frames in order (waits while the gateway holds earlier ones
    /// back).
    pub(crate) async fn send(&self, frames: &[Frame]) -> Result<()> {
        for chunk in frames.chunks(BATCH) {
            self.tally.lock().expect("tally").submitted += chunk.len() as u64;
            self.sender
                .send(chunk)
                .await
                .ctx(format!("sending on {}", self.bus))?;
        }
        Ok(())
    }

    /// Frames so far.
    pub(crate) fn tally(&self) -> Tally {
        self.tally.lock().expect("tally").clone()
    }

    /// Waits until every frame sent is accounted for (at most [`SETTLE`]
    /// after the last news), ends the stream, and says what happened.
    pub(crate) async fn finish(self) -> Tally {
        loop {
            let waiting = self.changed.notified();
            let t = self.tally();
            if t.unconfirmed() == 0 || self.events.is_finished() {
                break;
            }
            if tokio::time::timeout(SETTLE, waiting).await.is_err() {
                break;
            }
        }
        self.events.abort();
        self.tally()
    }
}
