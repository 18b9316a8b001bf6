//! The SDO fallback of a CiA 402 axis's process data (`process_data =
//! "sdo"`): for drives whose PDOs cannot be mapped, or buses without room
//! for them.
//!
//! One task per such axis, beside the bus's axis task: it reads the
//! feedback objects ([`sdo_feedback_objects`]) every poll period and writes
//! each process image the axis asks for, only the objects that changed,
//! the controlword last ([`sdo_image_writes`]). Images are written in the
//! order they were produced and before the next poll, so a handshake edge
//! (new set-point, fault reset) is never merged away and the poll after it
//! sees its effect. The master queues the SDO transfers per node, so these
//! share the drive's SDO server with the boot procedure and with clients'
//! ReadSdo/WriteSdo; every transfer has the master's timeout.
//!
//! Only profile position axes can use it (the config refuses cyclic ones):
//! a set-point every SYNC does not fit SDO round trips.

use crate::canopen::CanopenBus;
use cangate_axis::cia402::{Feedback, ProcessImage};
use cangate_axis::process_data::{feedback_from_sdo, sdo_feedback_objects, sdo_image_writes};
use cangate_canopen::master::SdoRequest;
use cangate_canopen::sdo::{TransferOptions, TransferOutcome};
use cangate_canopen::{NodeId, ObjectAddress};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

/// The axis task's handle on its worker.
pub struct SdoWorker {
    /// Process images to write (the changed objects), in order.
    pub images: mpsc::Sender<ProcessImage>,
    /// Set when the drive rebooted: what it holds is unknown, so the next
    /// image goes out in full. A flag, not a queued message, so that it
    /// cannot be lost to a full queue.
    pub forget: Arc<AtomicBool>,
}

/// What the worker reports to the axis task.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SdoReport {
    /// One poll's feedback.
    Feedback(Feedback),
    /// A poll or a write failed; for people.
    Failed(String),
}

/// Images an axis may have queued: a command produces a handful, so a
/// full queue means the drive stopped answering and the axis's own
/// timeouts are already running out.
const IMAGE_QUEUE: usize = 64;

/// Starts the worker of the axis in slot `slot` of its bus task (node
/// `node`, the objects of its axis `drive_axis`), polling every `poll`.
/// Reports go to `reports`, tagged with `slot`. Ends when the returned
/// sender is dropped or `cancel` fires.
pub fn spawn(
    master: CanopenBus,
    node: NodeId,
    drive_axis: u8,
    slot: usize,
    poll: Duration,
    reports: mpsc::Sender<(usize, SdoReport)>,
    cancel: CancellationToken,
) -> SdoWorker {
    let (images, rx) = mpsc::channel(IMAGE_QUEUE);
    let forget = Arc::new(AtomicBool::new(false));
    tokio::spawn(run(
        Link {
            master,
            node,
            drive_axis,
            slot,
            forget: forget.clone(),
        },
        poll,
        rx,
        reports,
        cancel,
    ));
    SdoWorker { images, forget }
}

/// What the worker talks to.
struct Link {
    master: CanopenBus,
    node: NodeId,
    drive_axis: u8,
    slot: usize,
    forget: Arc<AtomicBool>,
}

async fn run(
    link: Link,
    poll: Duration,
    mut images: mpsc::Receiver<ProcessImage>,
    reports: mpsc::Sender<(usize, SdoReport)>,
    cancel: CancellationToken,
) {
    let Link {
        master,
        node,
        drive_axis,
        slot,
        forget,
    } = link;
    let mut written: Option<ProcessImage> = None;
    let mut ticks = tokio::time::interval(poll);
    // A slow drive (or a lost one, each upload waiting for its timeout)
    // stretches the period rather than queueing a burst of polls.
    ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        let report = tokio::select! {
            biased;
            _ = cancel.cancelled() => break,
            image = images.recv() => match image {
                None => break,
                Some(image) => {
                    if forget.swap(false, Ordering::AcqRel) {
                        written = None;
                    }
                    match download_all(&master, node, sdo_image_writes(drive_axis, written.as_ref(), &image)).await {
                        Ok(()) => {
                            written = Some(image);
                            continue;
                        }
                        Err(e) => {
                            // Part of it may have been written: the next
                            // image goes out in full.
                            written = None;
                            SdoReport::Failed(e)
                        }
                    }
                }
            },
            _ = ticks.tick() => match read_feedback(&master, node, drive_axis).await {
                Ok(fb) => SdoReport::Feedback(fb),
                Err(e) => SdoReport::Failed(e),
            },
        };
        if reports.send((slot, report)).await.is_err() {
            break;
        }
    }
}

/// Writes `writes` to `node` by SDO one after the other; the first failure
/// ends it, naming the object. (Also the axes' parameter writes.)
pub(super) async fn download_all(
    master: &CanopenBus,
    node: NodeId,
    writes: Vec<(ObjectAddress, Vec<u8>)>,
) -> Result<(), String> {
    for (addr, data) in writes {
        master
            .sdo(
                node,
                SdoRequest::Download {
                    addr,
                    data,
                    opts: TransferOptions::default(),
                },
            )
            .await
            .map_err(|e| format!("writing {addr}: {e}"))?;
    }
    Ok(())
}

async fn read_feedback(
    master: &CanopenBus,
    node: NodeId,
    drive_axis: u8,
) -> Result<Feedback, String> {
    let mut uploads: [Vec<u8>; 4] = Default::default();
    for (addr, slot) in sdo_feedback_objects(drive_axis)
        .iter()
        .zip(uploads.iter_mut())
    {
        let r = master
            .sdo(
                node,
                SdoRequest::Upload {
                    addr: *addr,
                    opts: TransferOptions::default(),
                },
            )
            .await
            .map_err(|e| format!("reading {addr} by SDO: {e}"))?;
        match r {
            TransferOutcome::Uploaded(data) => *slot = data,
            TransferOutcome::Downloaded => {
                return Err(format!("reading {addr} by SDO: no value came back"));
            }
        }
    }
    feedback_from_sdo(&uploads).map_err(|e| e.to_string())
}
