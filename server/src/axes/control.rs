//! Who may command an axis: every caller (the gRPC edge, the handwheel
//! binding, an embedding program) presents a [`Caller`] and gets the same
//! rules from [`Axes`]:
//!
//! - a command that needs control (everything but a stop) needs the lease
//!   that holds the axis, presented by the identity that acquired it;
//! - a stop needs no lease and is never refused by one; a lease that comes
//!   along with it is renewed when its identity may present it, and
//!   otherwise ignored;
//! - every command, granted or refused, reaches the audit log
//!   (`cangate::audit`) with the caller's name and the lease's holder.

use super::{Axes, AxisError, CommandResult};
use crate::axis_runner::CoordinatedTarget;
use cangate_axis::{AxisCommand, Outcome, StopKind};
use std::time::Duration;

/// Who asks for an axis operation.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Caller {
    /// How the audit log names the caller: a peer address, `handwheel
    /// hw1`, the name an embedding program gives itself.
    pub name: String,
    /// The authenticated identity a lease is bound to (`token operator-1`,
    /// `certificate hmi-2`); `None` without authentication.
    pub identity: Option<String>,
    /// The control lease token presented; empty for none.
    pub lease: String,
}

impl Caller {
    /// A caller named `name` without identity or lease.
    pub fn new(name: impl Into<String>) -> Self {
        Caller {
            name: name.into(),
            identity: None,
            lease: String::new(),
        }
    }

    /// The same caller presenting lease `token`.
    #[must_use]
    pub fn with_lease(mut self, token: impl Into<String>) -> Self {
        self.lease = token.into();
        self
    }

    /// The same caller as the authenticated `identity`.
    #[must_use]
    pub fn with_identity(mut self, identity: Option<String>) -> Self {
        self.identity = identity;
        self
    }
}

impl Axes {
    /// Whether `caller` may run `cmd` on axis `i` (renewing its lease); the
    /// lease holder's name for the audit log (empty for a stop).
    fn admit(&self, i: usize, cmd: &AxisCommand, caller: &Caller) -> Result<String, AxisError> {
        // A lease serves the identity that acquired it only; a stop needs
        // none, so another identity's lease on a stop is ignored (never
        // renewed) and the stop goes ahead.
        let owner_check = if caller.lease.is_empty() {
            Ok(())
        } else {
            self.check_lease_owner(&caller.lease, caller.identity.as_deref())
        };
        if cmd.needs_control() {
            owner_check?;
            self.authorize(i, &caller.lease)
        } else {
            if !caller.lease.is_empty() && owner_check.is_ok() {
                let _ = self.renew_token(&caller.lease);
            }
            Ok(String::new())
        }
    }

    /// Runs a command of `caller` on axis `i` under the control rules (see
    /// the module's documentation); returns when the drive accepted it, or
    /// with `wait` when it ended (bounded by `wait_timeout`).
    ///
    /// # Errors
    /// [`AxisError::Lease`] when the caller does not control the axis (never
    /// for a stop), and every reason the axis refuses or does not answer.
    pub async fn command(
        &self,
        i: usize,
        cmd: AxisCommand,
        caller: &Caller,
        wait: bool,
        wait_timeout: Duration,
    ) -> Result<CommandResult, AxisError> {
        let axis = self.name(i);
        let holder = match self.admit(i, &cmd, caller) {
            Ok(h) => h,
            Err(e) => {
                audit(caller, "", axis, &cmd, &format!("refused: {e}"));
                return Err(e);
            }
        };
        let r = self.dispatch(i, cmd, wait, wait_timeout).await;
        let result = match &r {
            Ok(res) => format!(
                "{}: {}",
                res.outcome.map_or("accepted", Outcome::name),
                res.detail
            ),
            Err(e) => format!("refused: {e}"),
        };
        audit(caller, &holder, axis, &cmd, &result);
        r
    }

    /// Queues a command of `caller` on axis `i` under the control rules,
    /// without waiting for its acceptance (commands of one caller keep
    /// their order). For the handwheel binding, which must never stall on a
    /// drive; not audited (a wheel sends many small moves).
    ///
    /// # Errors
    /// [`AxisError::Lease`] when the caller does not control the axis (never
    /// for a stop); [`AxisError::Unavailable`] when the axis task's queue is
    /// full or closed.
    pub fn submit(&self, i: usize, cmd: AxisCommand, caller: &Caller) -> Result<(), AxisError> {
        self.admit(i, &cmd, caller)?;
        self.enqueue(i, cmd)
    }

    /// Stops several axes at once (per bus in one batch of frames). A stop
    /// needs no lease and is never refused by one.
    ///
    /// # Errors
    /// [`AxisError::ShuttingDown`] when the axis tasks are gone; each
    /// axis's own result is in the list.
    pub async fn stop_many(
        &self,
        axes: &[usize],
        kind: StopKind,
        wait: bool,
        caller: &Caller,
    ) -> Result<Vec<Result<CommandResult, AxisError>>, AxisError> {
        let names: Vec<&str> = axes.iter().map(|&i| self.name(i)).collect();
        let quick = kind == StopKind::QuickStop;
        tracing::info!(target: "cangate::audit", peer = %caller.name, axes = ?names, quick, "stop axes");
        self.stop_batch(axes, kind, wait).await
    }

    /// Starts a coordinated cyclic move of `caller`: (axis, target,
    /// velocity, acceleration) per axis, all on one bus, each controlled by
    /// the caller's lease.
    ///
    /// # Errors
    /// [`AxisError::Lease`] naming the first axis the caller does not
    /// control, [`AxisError::NotCoordinable`], and every reason the axes
    /// refuse.
    pub async fn move_coordinated(
        &self,
        targets: Vec<CoordinatedTarget>,
        caller: &Caller,
        wait: bool,
    ) -> Result<Vec<Result<CommandResult, AxisError>>, AxisError> {
        self.check_lease_owner(&caller.lease, caller.identity.as_deref())?;
        for (i, ..) in &targets {
            self.authorize(*i, &caller.lease)?;
        }
        let audited: Vec<(&str, f64)> = targets
            .iter()
            .map(|(i, t, ..)| (self.name(*i), *t))
            .collect();
        tracing::info!(target: "cangate::audit", peer = %caller.name, targets = ?audited, "coordinated move");
        self.dispatch_coordinated(targets, wait).await
    }

    /// Extends the caller's lease, if its identity may present it.
    ///
    /// # Errors
    /// [`AxisError::Lease`]: unknown, lapsed, or another identity's.
    pub fn renew(&self, caller: &Caller) -> Result<cangate_axis::lease::Lease, AxisError> {
        self.check_lease_owner(&caller.lease, caller.identity.as_deref())?;
        self.renew_token(&caller.lease)
    }

    /// Ends the caller's lease, if its identity may present it.
    ///
    /// # Errors
    /// [`AxisError::Lease`]: unknown, lapsed, or another identity's.
    pub fn release(&self, caller: &Caller) -> Result<cangate_axis::lease::Lease, AxisError> {
        self.check_lease_owner(&caller.lease, caller.identity.as_deref())?;
        self.release_token(&caller.lease)
    }
}

fn audit(caller: &Caller, holder: &str, axis: &str, cmd: &AxisCommand, result: &str) {
    tracing::info!(
        target: "cangate::audit",
        peer = %caller.name,
        %holder,
        %axis,
        command = ?cmd,
        %result,
        "axis command"
    );
}
