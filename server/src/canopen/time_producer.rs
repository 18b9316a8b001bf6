//! The TIME producer of a CANopen bus: sends the host's UTC time as a
//! TIME_OF_DAY ([`cangate_canopen::time_of_day`]) every period, when a
//! period is set (`time_period_ms`, `Canopen.SetTime`; at least
//! [`super::MIN_TIME_PERIOD`]), and on request.
//!
//! A task rather than a thread like the SYNC's: a TIME frame tells the time
//! to the millisecond whenever it leaves, so a late wake-up costs nothing.

use cangate_can::BusHandle;
use cangate_canopen::time_of_day::{TimeOfDay, TimeOfDayError};
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use tokio::sync::watch;
use tokio_util::sync::CancellationToken;

/// The TIME_OF_DAY of the host's clock now.
pub(super) fn now() -> Result<TimeOfDay, TimeOfDayError> {
    let since_epoch = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_err(|_| TimeOfDayError::Before1984)?;
    TimeOfDay::from_unix(since_epoch)
}

/// Sends a TIME frame every period `period` holds, until `cancel` fires.
pub(super) async fn run(
    bus: BusHandle,
    mut period: watch::Receiver<Option<Duration>>,
    cancel: CancellationToken,
) {
    loop {
        let current = *period.borrow_and_update();
        let wait = async {
            match current {
                Some(p) => tokio::time::sleep(p).await,
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            biased;
            _ = cancel.cancelled() => return,
            changed = period.changed() => {
                if changed.is_err() {
                    return;
                }
                // A new period starts counting now.
                continue;
            }
            _ = wait => {}
        }
        match now() {
            Ok(t) => {
                if let Err(e) = bus.submit(vec![t.frame()]).await {
                    tracing::warn!(error = %e, "TIME not sent");
                }
            }
            Err(e) => tracing::warn!(error = %e, "TIME not sent"),
        }
    }
}
