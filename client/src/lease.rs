//! Control leases as a guard: renewed in the background, released on drop.

use crate::error::Error;
use crate::{Client, pb};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::watch;
use tokio::task::JoinHandle;
use tonic::Code;

/// Bound of the release a dropped lease sends.
const RELEASE_ON_DROP_TIMEOUT: Duration = Duration::from_secs(2);

/// What the background renewal of a [`ControlLease`] has seen.
#[derive(Debug, Clone, Default)]
pub struct LeaseStatus {
    /// Successful renewals so far.
    pub renewals: u64,
    /// When the latest renewal succeeded (`None`: not yet).
    pub last_renewal: Option<Instant>,
    /// Renewals that failed in a row (0 after a success).
    pub failures: u64,
    /// The latest renewal failure, if the latest renewal failed.
    pub last_error: Option<Arc<Error>>,
    /// The gateway refused a renewal: the lease lapsed, was released or
    /// belongs to another identity. The axes are no longer controlled
    /// (moving ones were stopped) and renewing has ended.
    pub lost: bool,
}

/// Exclusive control of some axes ([`Client::acquire_control`], or a
/// lease taken elsewhere adopted with [`Client::adopt_control`]).
///
/// A task on the current tokio runtime renews the lease every third of
/// its TTL; [`ControlLease::status`] and [`ControlLease::lost`] tell how
/// that goes. Dropping the guard stops renewing and releases the lease
/// (best effort, in a spawned task); [`ControlLease::release`] releases it
/// and reports the result; an adopted lease is not released on drop, and
/// [`ControlLease::keep`] hands a lease on (stops renewing, keeps it). Pass
/// it to commands with
/// [`ControlLease::options`], [`ControlLease::move_options`],
/// [`ControlLease::jog_options`] or the options' `lease` methods.
pub struct ControlLease {
    token: String,
    axes: Vec<String>,
    holder: String,
    ttl: Duration,
    client: Client,
    status: watch::Receiver<LeaseStatus>,
    renewer: Option<JoinHandle<()>>,
    /// Released (or kept, or adopted): nothing to do on drop.
    released: bool,
}

impl std::fmt::Debug for ControlLease {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ControlLease")
            .field("token", &"<redacted>")
            .field("axes", &self.axes)
            .field("holder", &self.holder)
            .field("ttl", &self.ttl)
            .field("status", &*self.status.borrow())
            .finish()
    }
}

impl Client {
    /// Takes control of `axes` (all or none) with a lease of `ttl`
    /// (clamped by the gateway to 0.1..=60 s), renewed in the background
    /// until the guard is dropped or released. Refused with
    /// [`Error::Refused`] (reason `AXIS_CONTROLLED_BY_OTHER`) while
    /// someone else holds one of them.
    pub async fn acquire_control(
        &self,
        axes: &[&str],
        ttl: Duration,
    ) -> Result<ControlLease, Error> {
        self.acquire_control_as(axes, ttl, "").await
    }

    /// [`Client::acquire_control`] with a name others see as the holder
    /// (with this client's address), e.g. "hmi-cell-3".
    pub async fn acquire_control_as(
        &self,
        axes: &[&str],
        ttl: Duration,
        client_name: &str,
    ) -> Result<ControlLease, Error> {
        let req = pb::AcquireControlRequest {
            axes: axes.iter().map(|a| a.to_string()).collect(),
            ttl_ms: crate::canopen::millis(ttl),
            client_name: client_name.to_string(),
        };
        let lease = self
            .call(
                "AcquireControl",
                None,
                self.axes_client().acquire_control(req),
            )
            .await?;
        Ok(self.guard(lease, false))
    }

    /// Renews a lease this client holds as a token (taken by another
    /// program, e.g. `cangate lease acquire`) in the background while the
    /// guard lives. The token is checked by renewing it at once; dropping
    /// the guard stops renewing and does not release it
    /// ([`ControlLease::release`] still does).
    pub async fn adopt_control(&self, token: &str) -> Result<ControlLease, Error> {
        let lease = self.renew_control(token).await?;
        Ok(self.guard(lease, true))
    }

    /// Renews a lease once (no guard): the lease as the gateway now has it.
    /// Refused with FAILED_PRECONDITION when it lapsed or was released.
    pub async fn renew_control(&self, token: &str) -> Result<pb::ControlLease, Error> {
        let req = pb::RenewControlRequest {
            lease: token.to_string(),
        };
        let mut lease = self
            .call("RenewControl", None, self.axes_client().renew_control(req))
            .await?;
        if lease.lease.is_empty() {
            lease.lease = token.to_string();
        }
        Ok(lease)
    }

    /// Releases a lease given as a token (no guard); the axes released.
    pub async fn release_control(&self, token: &str) -> Result<Vec<String>, Error> {
        let req = pb::ReleaseControlRequest {
            lease: token.to_string(),
        };
        let r = self
            .call(
                "ReleaseControl",
                None,
                self.axes_client().release_control(req),
            )
            .await?;
        Ok(r.axes)
    }

    /// The guard of `lease`, renewing it; `adopted`: not released on drop.
    fn guard(&self, lease: pb::ControlLease, adopted: bool) -> ControlLease {
        let ttl = Duration::from_millis(u64::from(lease.ttl_ms.max(1)));
        let (tx, rx) = watch::channel(LeaseStatus::default());
        let renewer = tokio::spawn(renew(self.clone(), lease.lease.clone(), ttl, tx));
        ControlLease {
            token: lease.lease,
            axes: lease.axes,
            holder: lease.holder,
            ttl,
            client: self.clone(),
            status: rx,
            renewer: Some(renewer),
            released: adopted,
        }
    }
}

/// Renews every third of the TTL until the gateway refuses (or the task
/// is aborted).
async fn renew(client: Client, token: String, mut ttl: Duration, tx: watch::Sender<LeaseStatus>) {
    loop {
        let period = ttl / 3;
        tokio::time::sleep(period).await;
        // One renewal never runs into the next one's slot.
        let bound = client
            .request_timeout()
            .map_or(period, |t| t.min(period))
            .max(Duration::from_millis(10));
        let c = client.with_request_timeout(Some(bound));
        let req = pb::RenewControlRequest {
            lease: token.clone(),
        };
        match c
            .call("RenewControl", None, c.axes_client().renew_control(req))
            .await
        {
            Ok(l) => {
                if l.ttl_ms > 0 {
                    ttl = Duration::from_millis(u64::from(l.ttl_ms));
                }
                tx.send_modify(|s| {
                    s.renewals += 1;
                    s.last_renewal = Some(Instant::now());
                    s.failures = 0;
                    s.last_error = None;
                });
            }
            Err(e) => {
                let lost = matches!(
                    e.code(),
                    Some(Code::FailedPrecondition | Code::PermissionDenied | Code::NotFound)
                );
                tx.send_modify(|s| {
                    s.failures += 1;
                    s.last_error = Some(Arc::new(e));
                    s.lost = lost;
                });
                if lost {
                    return;
                }
            }
        }
    }
}

impl ControlLease {
    /// The lease token to pass in commands (secret: it is the control).
    pub fn token(&self) -> &str {
        &self.token
    }

    /// The axes it covers.
    pub fn axes(&self) -> &[String] {
        &self.axes
    }

    /// The holder as others see it ("hmi-cell-3 (10.0.0.7:51234)").
    pub fn holder(&self) -> &str {
        &self.holder
    }

    /// The TTL the gateway granted.
    pub fn ttl(&self) -> Duration {
        self.ttl
    }

    /// What the background renewal has seen so far.
    pub fn status(&self) -> LeaseStatus {
        self.status.borrow().clone()
    }

    /// A receiver of every change of [`ControlLease::status`].
    pub fn subscribe(&self) -> watch::Receiver<LeaseStatus> {
        self.status.clone()
    }

    /// Resolves when the lease is lost (a renewal refused by the gateway),
    /// with the status then; never while the lease is held.
    pub async fn lost(&self) -> LeaseStatus {
        let mut rx = self.status.clone();
        match rx.wait_for(|s| s.lost).await {
            Ok(s) => s.clone(),
            // The renewer ended without a loss: only when it was stopped.
            Err(_) => std::future::pending().await,
        }
    }

    /// Renews now (also done in the background).
    pub async fn renew(&self) -> Result<(), Error> {
        let req = pb::RenewControlRequest {
            lease: self.token.clone(),
        };
        self.client
            .call(
                "RenewControl",
                None,
                self.client.axes_client().renew_control(req),
            )
            .await?;
        Ok(())
    }

    /// Stops renewing and keeps the lease: the gateway's lease as granted
    /// (token, axes, holder, TTL), for another program to use and renew
    /// within its TTL. Nothing is sent.
    pub fn keep(mut self) -> pb::ControlLease {
        if let Some(r) = self.renewer.take() {
            r.abort();
        }
        self.released = true;
        pb::ControlLease {
            lease: std::mem::take(&mut self.token),
            axes: std::mem::take(&mut self.axes),
            holder: std::mem::take(&mut self.holder),
            ttl_ms: u32::try_from(self.ttl.as_millis()).unwrap_or(u32::MAX),
        }
    }

    /// Stops renewing and gives control back; the axes released. The axes
    /// keep their state (a moving axis keeps moving unless stopped).
    pub async fn release(mut self) -> Result<Vec<String>, Error> {
        if let Some(r) = self.renewer.take() {
            r.abort();
        }
        self.released = true;
        self.client.release_control(&self.token).await
    }
}

impl Drop for ControlLease {
    fn drop(&mut self) {
        if let Some(r) = self.renewer.take() {
            r.abort();
        }
        if self.released || self.status.borrow().lost {
            return;
        }
        // Best effort: without a runtime (dropped outside tokio) the lease
        // lapses at its TTL instead.
        let Ok(runtime) = tokio::runtime::Handle::try_current() else {
            return;
        };
        let client = self
            .client
            .with_request_timeout(Some(RELEASE_ON_DROP_TIMEOUT));
        let req = pb::ReleaseControlRequest {
            lease: std::mem::take(&mut self.token),
        };
        runtime.spawn(async move {
            let _ = client
                .call(
                    "ReleaseControl",
                    None,
                    client.axes_client().release_control(req),
                )
                .await;
        });
    }
}
