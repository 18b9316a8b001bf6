//! Program download (CiA 302-3) at run time: one task per download drives
//! the sans-IO [`ProgramDownload`] with the master's SDO transfers, the
//! node's boot-up events and time, and reports steps and the bytes of the
//! data download the node confirmed.
//!
//! One download per node at a time ([`ProgramStartError::Busy`]). A
//! download whose receiver is dropped (the API client went away) stops at
//! once: the transfer running is dropped, which the master turns into an
//! SDO abort (0x08000000) within its sweep, and nothing further is sent.
//! Once the stop step is done the node's program stays stopped, so it never
//! runs a half-written image; a later download starts again from the
//! beginning.

use super::drive_guard::AxisActive;
use super::{CanopenBus, CanopenError, NodeEventKind};
use cangate_canopen::NodeId;
use cangate_canopen::master::SdoRequest;
use cangate_canopen::program_download::{
    PROGRAM_DATA, ProgramAction, ProgramDownload, ProgramError, ProgramOutcome, ProgramPlan,
    ProgramStep,
};
use cangate_canopen::sdo::TransferOutcome;
use std::collections::HashSet;
use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::{broadcast, mpsc};
use tracing::Instrument as _;

/// How often the bytes confirmed are looked up during the data download.
const PROGRESS_PERIOD: Duration = Duration::from_millis(50);

/// What a running download reports.
#[derive(Debug)]
pub enum ProgramEvent {
    /// Where it stands: the step, and the data bytes the node confirmed.
    Progress {
        /// The step running.
        step: ProgramStep,
        /// Data bytes confirmed so far.
        bytes_done: usize,
        /// The image's size.
        total: usize,
    },
    /// The end.
    Finished(Result<ProgramOutcome, ProgramFailure>),
}

/// Why a download failed.
#[derive(Debug, thiserror::Error)]
pub enum ProgramFailure {
    /// A step failed (SDO abort, flash status, no boot-up, identification).
    #[error(transparent)]
    Program(#[from] ProgramError),
    /// The node's axis became active during the download; nothing more
    /// was sent to the node.
    #[error("{1}: {0}")]
    AxisActive(AxisActive, ProgramStep),
    /// The gateway could not carry a transfer out (master stopped, ...).
    #[error("{step}: {error}")]
    Gateway {
        /// The step.
        step: ProgramStep,
        /// Why.
        error: CanopenError,
    },
}

/// Why a download could not start.
#[derive(Debug, thiserror::Error)]
pub enum ProgramStartError {
    /// Another download to the node runs.
    #[error(
        "a program download to node {node} on bus {bus} is already running; wait for it to end"
    )]
    Busy {
        /// The bus.
        bus: String,
        /// The node.
        node: u8,
    },
    /// The node drives an enabled or moving axis.
    #[error(transparent)]
    AxisActive(#[from] AxisActive),
}

/// Nodes with a download running.
#[derive(Debug, Default, Clone)]
pub(super) struct Downloads(Arc<Mutex<HashSet<NodeId>>>);

struct Claim {
    downloads: Downloads,
    node: NodeId,
}

impl Drop for Claim {
    fn drop(&mut self) {
        self.downloads
            .0
            .lock()
            .expect("downloads lock")
            .remove(&self.node);
    }
}

type SdoFuture = Pin<Box<dyn Future<Output = Result<TransferOutcome, CanopenError>> + Send>>;

impl CanopenBus {
    /// Starts a program download of `plan` on behalf of `caller`; its
    /// events come on the receiver. Dropping the receiver cancels it.
    pub fn download_program(
        &self,
        plan: ProgramPlan,
        caller: &str,
    ) -> Result<mpsc::Receiver<ProgramEvent>, ProgramStartError> {
        let node = plan.node;
        self.check_drive_idle(node, "a program download")?;
        {
            let mut running = self.programs.0.lock().expect("downloads lock");
            if !running.insert(node) {
                return Err(ProgramStartError::Busy {
                    bus: self.bus.clone(),
                    node: node.get(),
                });
            }
        }
        let claim = Claim {
            downloads: self.programs.clone(),
            node,
        };
        let (tx, rx) = mpsc::channel(64);
        // Subscribed before the start: the boot-up cannot be missed.
        let events = self.events();
        // The download logs inside its bus's and node's spans.
        let bus_span = tracing::info_span!("bus", bus = %self.bus);
        let span = tracing::info_span!(parent: &bus_span, "node", node = node.get());
        tracing::info!(parent: &span, bytes = plan.image.len(), program = plan.program, %caller, "program download started");
        tokio::spawn(
            run_download(
                self.clone(),
                ProgramDownload::new(plan),
                events,
                tx,
                caller.to_string(),
                claim,
            )
            .instrument(span),
        );
        Ok(rx)
    }
}

async fn run_download(
    bus: CanopenBus,
    mut pd: ProgramDownload,
    mut events: broadcast::Receiver<super::NodeEvent>,
    tx: mpsc::Sender<ProgramEvent>,
    caller: String,
    _claim: Claim,
) {
    let node = pd.node();
    let total = pd.plan().image.len();
    let origin = Instant::now();
    let mut sdo: Option<SdoFuture> = None;
    let mut current: Option<SdoRequest> = None;
    let mut step = ProgramStep::ReadIdentificationBefore;
    let mut done_bytes = 0usize;
    let mut progress = tokio::time::interval(PROGRESS_PERIOD);
    progress.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut actions = pd.start(Duration::ZERO);
    loop {
        for a in actions.drain(..) {
            match a {
                ProgramAction::Step(s) => {
                    step = s;
                    if s > ProgramStep::DownloadData {
                        done_bytes = total;
                    }
                    let _ = tx
                        .send(ProgramEvent::Progress {
                            step: s,
                            bytes_done: done_bytes,
                            total,
                        })
                        .await;
                }
                ProgramAction::Sdo(req) => {
                    // An axis enabled while the download runs: its drive's
                    // program is not stopped, replaced or started under it.
                    if let Err(e) = bus.check_drive_idle(node, "a program download") {
                        tracing::warn!(error = %e, "program download stopped");
                        let _ = tx
                            .send(ProgramEvent::Finished(Err(ProgramFailure::AxisActive(
                                e, step,
                            ))))
                            .await;
                        return;
                    }
                    let b = bus.clone();
                    let c = caller.clone();
                    let r = req.clone();
                    current = Some(req);
                    sdo = Some(Box::pin(async move { b.client_sdo(node, r, &c).await }));
                }
                ProgramAction::Finished(r) => {
                    match &r {
                        Ok(o) => {
                            tracing::info!(
                                bytes = o.bytes,
                                new = format!("0x{:08X}", o.new_identification),
                                "program download done"
                            )
                        }
                        Err(e) => {
                            tracing::warn!(error = %e, "program download failed")
                        }
                    }
                    let _ = tx
                        .send(ProgramEvent::Finished(r.map_err(ProgramFailure::from)))
                        .await;
                    return;
                }
            }
        }
        let deadline = pd
            .next_deadline()
            .map(|d| origin + d)
            .unwrap_or_else(|| Instant::now() + Duration::from_secs(3600));
        tokio::select! {
            biased;
            _ = tx.closed() => {
                tracing::warn!(step = step.name(), "program download cancelled by the client");
                // Dropping `sdo` makes the master abort the transfer.
                return;
            }
            r = async { sdo.as_mut().expect("guarded").await }, if sdo.is_some() => {
                sdo = None;
                current = None;
                let r = match r {
                    Ok(o) => Ok(o),
                    Err(CanopenError::Sdo(e)) => Err(e),
                    Err(error) => {
                        let _ = tx.send(ProgramEvent::Finished(Err(ProgramFailure::Gateway { step, error }))).await;
                        return;
                    }
                };
                actions = pd.on_sdo_result(r, origin.elapsed());
            }
            ev = events.recv() => {
                match ev {
                    Ok(ev) if ev.node == node && matches!(ev.kind, NodeEventKind::BootUp) => {
                        actions = pd.on_boot_up(origin.elapsed());
                    }
                    Ok(_) | Err(broadcast::error::RecvError::Lagged(_)) => {}
                    Err(broadcast::error::RecvError::Closed) => {
                        let _ = tx.send(ProgramEvent::Finished(Err(ProgramFailure::Gateway { step, error: CanopenError::Stopped }))).await;
                        return;
                    }
                }
            }
            _ = tokio::time::sleep_until(deadline.into()) => {
                actions = pd.on_tick(origin.elapsed());
            }
            _ = progress.tick(), if step == ProgramStep::DownloadData => {
                let data = matches!(&current, Some(SdoRequest::Download { addr, .. }) if addr.index == PROGRAM_DATA);
                if data
                    && let Ok(transfers) = bus.transfers().await
                    && let Some((_, p)) = transfers.iter().find(|(n, p)| *n == node && p.addr.index == PROGRAM_DATA)
                    && p.transferred != done_bytes
                {
                    done_bytes = p.transferred;
                    let _ = tx.try_send(ProgramEvent::Progress { step, bytes_done: done_bytes, total });
                }
            }
        }
    }
}
