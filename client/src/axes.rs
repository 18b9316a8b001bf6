//! The Axes service: state, commands (enable, home, move, jog, stops),
//! live updates.

use crate::canopen::millis;
use crate::error::Error;
use crate::lease::ControlLease;
use crate::streams::{self, EventStream};
use crate::{Client, pb};
use std::time::Duration;

/// The gateway's bound of a wait when none is given.
const DEFAULT_WAIT: Duration = Duration::from_secs(60);
/// The gateway's bound of a coordinated move's wait.
const MOVE_AXES_WAIT: Duration = Duration::from_secs(120);

// The options of a lease live here, beside the options, so the lease
// module needs nothing of the axes (the axes name the lease, not the
// other way round).
impl ControlLease {
    /// Command options carrying this lease.
    pub fn options(&self) -> CommandOptions {
        CommandOptions::default().lease(self)
    }

    /// Move options carrying this lease.
    pub fn move_options(&self) -> MoveOptions {
        MoveOptions::default().lease(self)
    }

    /// Jog options carrying this lease.
    pub fn jog_options(&self) -> JogOptions {
        JogOptions::with_lease(self)
    }
}

/// Lease and wait options of the commands without parameters (enable,
/// disable, home, reset fault).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct CommandOptions {
    /// The control lease token (see [`ControlLease`]); needed to enable,
    /// home or move an axis, not to stop it.
    pub lease: Option<String>,
    /// Return when the command completed, not when the drive accepted it.
    pub wait: bool,
    /// Bound of the wait (`None`: the gateway's 60 s); past it the call
    /// fails with [`Error::Timeout`] (the command itself goes on).
    pub wait_timeout: Option<Duration>,
}

impl CommandOptions {
    /// These options with `lease`.
    pub fn lease(mut self, lease: &ControlLease) -> Self {
        self.lease = Some(lease.token().to_string());
        self
    }

    /// These options waiting (or not) for completion.
    pub fn wait(mut self, wait: bool) -> Self {
        self.wait = wait;
        self
    }

    fn to_pb(&self) -> pb::CommandOptions {
        pb::CommandOptions {
            lease: self.lease.clone().unwrap_or_default(),
            wait: self.wait,
            wait_timeout_ms: self.wait_timeout.map_or(0, millis),
        }
    }

    /// The extra time a call needs beyond the request timeout.
    fn extra(&self) -> Option<Duration> {
        self.wait.then(|| self.wait_timeout.unwrap_or(DEFAULT_WAIT))
    }
}

/// Options of a move ([`Client::move_to`], [`Client::move_by`],
/// [`Client::move_axes`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MoveOptions {
    /// Velocity limit in user units/s (`None`: the axis's default).
    pub velocity: Option<f64>,
    /// Acceleration and deceleration in user units/s² (`None`: the axis's
    /// default).
    pub acceleration: Option<f64>,
    /// Return when the target is reached (or the move failed).
    pub wait: bool,
    /// Bound of the wait (`None`: the gateway's 60 s; 120 s for
    /// [`Client::move_axes`]).
    pub wait_timeout: Option<Duration>,
    /// The control lease token (required).
    pub lease: Option<String>,
}

impl MoveOptions {
    /// These options with a velocity limit.
    pub fn velocity(mut self, velocity: f64) -> Self {
        self.velocity = Some(velocity);
        self
    }

    /// These options with an acceleration.
    pub fn acceleration(mut self, acceleration: f64) -> Self {
        self.acceleration = Some(acceleration);
        self
    }

    /// These options waiting (or not) for the target.
    pub fn wait(mut self, wait: bool) -> Self {
        self.wait = wait;
        self
    }

    /// These options with `lease`.
    pub fn lease(mut self, lease: &ControlLease) -> Self {
        self.lease = Some(lease.token().to_string());
        self
    }

    fn command(&self) -> CommandOptions {
        CommandOptions {
            lease: self.lease.clone(),
            wait: self.wait,
            wait_timeout: self.wait_timeout,
        }
    }
}

/// Options of a jog ([`Client::jog`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct JogOptions {
    /// Acceleration in user units/s² (`None`: the axis's default).
    pub acceleration: Option<f64>,
    /// The control lease token (required).
    pub lease: Option<String>,
}

impl JogOptions {
    /// Jog options with `lease`.
    pub fn with_lease(lease: &ControlLease) -> Self {
        JogOptions {
            acceleration: None,
            lease: Some(lease.token().to_string()),
        }
    }
}

/// Options of stops of several axes ([`Client::stop_axes`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StopOptions {
    /// CiA 402 quick stop instead of the profile deceleration.
    pub quick: bool,
    /// Return when all are at rest.
    pub wait: bool,
}

/// How an axis command ended.
#[derive(Debug, Clone, PartialEq)]
pub struct CommandResult {
    /// ACCEPTED without wait; with wait the final outcome (COMPLETED, or
    /// in a stop of several axes UNSPECIFIED when an axis's wait failed).
    pub outcome: pb::Outcome,
    /// For people ("target reached at 12.500 mm"); may be "".
    pub detail: String,
    /// The axis state right after.
    pub status: Option<pb::AxisStatus>,
}

impl CommandResult {
    /// The proto response it was made from.
    pub fn to_pb(&self) -> pb::AxisCommandResponse {
        pb::AxisCommandResponse {
            outcome: self.outcome as i32,
            detail: self.detail.clone(),
            status: self.status.clone(),
        }
    }

    fn from_pb(r: pb::AxisCommandResponse) -> CommandResult {
        CommandResult {
            outcome: pb::Outcome::try_from(r.outcome).unwrap_or(pb::Outcome::Unspecified),
            detail: r.detail,
            status: r.status,
        }
    }
}

/// One item of [`Client::watch_axes`].
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum AxisUpdate {
    /// The live state of an axis (one per watched axis first, then one
    /// per process data update).
    Status(pb::AxisStatus),
    /// A command ended.
    MotionDone {
        /// Axis name.
        axis: String,
        /// "enable", "move", "jog", "stop", ...
        command: String,
        /// How it ended.
        outcome: pb::Outcome,
        /// For people.
        detail: String,
    },
    /// The axis entered a fault or its node was lost (`active`), or that
    /// cleared.
    Fault {
        /// Axis name.
        axis: String,
        /// The EMCY error code, 0 when none.
        code: u32,
        /// For people.
        text: String,
        /// True: faulted; false: cleared.
        active: bool,
    },
    /// Control of the axis changed hands.
    ControlChange {
        /// Axis name.
        axis: String,
        /// New holder ("" when released or lapsed).
        holder: String,
        /// Previous holder ("" when acquired).
        previous: String,
        /// "acquired", "released", "lapsed: ...".
        reason: String,
    },
    /// The drive's node was lost (`lost`) or came back.
    NodeLink {
        /// Axis name.
        axis: String,
        /// True: lost; false: back.
        lost: bool,
        /// Why, for people.
        reason: String,
    },
    /// Touch probe 1 latched a position.
    TouchProbe {
        /// Axis name.
        axis: String,
        /// RISING or FALLING.
        edge: pb::TouchProbeEdge,
        /// The latched position, user units.
        position: f64,
    },
    /// This stream was too slow: this many updates were dropped here.
    Lost(u64),
}

impl AxisUpdate {
    fn from_pb(u: pb::AxisUpdate) -> Option<AxisUpdate> {
        use pb::axis_event::Kind;
        use pb::axis_update::Update;
        Some(match u.update? {
            Update::Status(s) => AxisUpdate::Status(s),
            Update::Event(e) => {
                let axis = e.axis;
                match e.kind? {
                    Kind::MotionDone(d) => AxisUpdate::MotionDone {
                        axis,
                        command: d.command,
                        outcome: pb::Outcome::try_from(d.outcome)
                            .unwrap_or(pb::Outcome::Unspecified),
                        detail: d.detail,
                    },
                    Kind::Fault(f) => AxisUpdate::Fault {
                        axis,
                        code: f.code,
                        text: f.text,
                        active: f.active,
                    },
                    Kind::Control(c) => AxisUpdate::ControlChange {
                        axis,
                        holder: c.holder,
                        previous: c.previous,
                        reason: c.reason,
                    },
                    Kind::Node(n) => AxisUpdate::NodeLink {
                        axis,
                        lost: n.lost,
                        reason: n.reason,
                    },
                    Kind::Lost(n) => AxisUpdate::Lost(n),
                    Kind::TouchProbe(t) => AxisUpdate::TouchProbe {
                        axis,
                        edge: pb::TouchProbeEdge::try_from(t.edge)
                            .unwrap_or(pb::TouchProbeEdge::Unspecified),
                        position: t.position,
                    },
                }
            }
        })
    }
}

impl Client {
    /// Every configured axis with its live state.
    pub async fn list_axes(&mut self) -> Result<Vec<pb::Axis>, Error> {
        let r = self
            .call(
                "ListAxes",
                None,
                self.axes_client().list_axes(pb::ListAxesRequest {}),
            )
            .await?;
        Ok(r.axes)
    }

    /// One axis: configuration and live state.
    pub async fn get_axis(&mut self, axis: &str) -> Result<pb::Axis, Error> {
        self.axis(axis).await
    }

    /// One axis: configuration and live state.
    pub async fn axis(&self, axis: &str) -> Result<pb::Axis, Error> {
        let req = pb::GetAxisRequest {
            axis: axis.to_string(),
        };
        self.call("GetAxis", None, self.axes_client().get_axis(req))
            .await
    }

    /// The live state of one axis.
    pub async fn axis_status(&self, axis: &str) -> Result<pb::AxisStatus, Error> {
        Ok(self.axis(axis).await?.status.unwrap_or_default())
    }

    /// Switches the drive on (to operation enabled). Needs the lease.
    pub async fn enable(
        &self,
        axis: &str,
        options: &CommandOptions,
    ) -> Result<CommandResult, Error> {
        let req = command(axis, options);
        let r = self
            .call("Enable", options.extra(), self.axes_client().enable(req))
            .await?;
        Ok(CommandResult::from_pb(r))
    }

    /// Switches the power stage off. Needs the lease.
    pub async fn disable(
        &self,
        axis: &str,
        options: &CommandOptions,
    ) -> Result<CommandResult, Error> {
        let req = command(axis, options);
        let r = self
            .call("Disable", options.extra(), self.axes_client().disable(req))
            .await?;
        Ok(CommandResult::from_pb(r))
    }

    /// Runs the configured homing method. Needs the lease.
    pub async fn home(&self, axis: &str, options: &CommandOptions) -> Result<CommandResult, Error> {
        let req = command(axis, options);
        let r = self
            .call("Home", options.extra(), self.axes_client().home(req))
            .await?;
        Ok(CommandResult::from_pb(r))
    }

    /// Resets a drive fault (the axis then needs enabling). Needs the
    /// lease.
    pub async fn reset_fault(
        &self,
        axis: &str,
        options: &CommandOptions,
    ) -> Result<CommandResult, Error> {
        let req = command(axis, options);
        let r = self
            .call(
                "ResetFault",
                options.extra(),
                self.axes_client().reset_fault(req),
            )
            .await?;
        Ok(CommandResult::from_pb(r))
    }

    /// Arms touch probe 1 of a CiA 402 axis on `edge` (RISING, FALLING,
    /// BOTH; UNSPECIFIED switches it off), latching the first edge only
    /// or, `continuous`, every one; returns once the drive confirmed it.
    /// Each latch comes as [`AxisUpdate::TouchProbe`]. Needs the lease.
    pub async fn arm_touch_probe(
        &self,
        axis: &str,
        edge: pb::TouchProbeEdge,
        continuous: bool,
        options: &CommandOptions,
    ) -> Result<CommandResult, Error> {
        let req = pb::ArmTouchProbeRequest {
            axis: axis.to_string(),
            edge: edge as i32,
            continuous,
            options: Some(options.to_pb()),
        };
        let r = self
            .call(
                "ArmTouchProbe",
                options.extra(),
                self.axes_client().arm_touch_probe(req),
            )
            .await?;
        Ok(CommandResult::from_pb(r))
    }

    /// Drives an axis in a torque mode (CST, profile torque) with a torque
    /// in per mille of its drive's rated torque, until a stop or another
    /// command; the gateway stops it when its velocity exceeds its
    /// maximum. Needs the lease.
    pub async fn set_torque(
        &self,
        axis: &str,
        per_mille: f64,
        options: &CommandOptions,
    ) -> Result<CommandResult, Error> {
        let req = pb::SetTorqueRequest {
            axis: axis.to_string(),
            torque_per_mille: per_mille,
            options: Some(options.to_pb()),
        };
        let r = self
            .call(
                "SetTorque",
                options.extra(),
                self.axes_client().set_torque(req),
            )
            .await?;
        Ok(CommandResult::from_pb(r))
    }

    /// Changes an axis's CiA 402 mode of operation, at rest only. Needs
    /// the lease.
    pub async fn set_mode(
        &self,
        axis: &str,
        mode: pb::DriveMode,
        options: &CommandOptions,
    ) -> Result<CommandResult, Error> {
        let req = pb::SetAxisModeRequest {
            axis: axis.to_string(),
            mode: mode as i32,
            options: Some(options.to_pb()),
        };
        let r = self
            .call("SetMode", options.extra(), self.axes_client().set_mode(req))
            .await?;
        Ok(CommandResult::from_pb(r))
    }

    /// Moves to an absolute position (user units). Needs the lease.
    pub async fn move_to(
        &self,
        axis: &str,
        position: f64,
        options: &MoveOptions,
    ) -> Result<CommandResult, Error> {
        self.move_axis(axis, position, false, options).await
    }

    /// Moves by a distance from where the axis is heading (user units).
    /// Needs the lease.
    pub async fn move_by(
        &self,
        axis: &str,
        distance: f64,
        options: &MoveOptions,
    ) -> Result<CommandResult, Error> {
        self.move_axis(axis, distance, true, options).await
    }

    async fn move_axis(
        &self,
        axis: &str,
        target: f64,
        relative: bool,
        options: &MoveOptions,
    ) -> Result<CommandResult, Error> {
        let cmd = options.command();
        let req = pb::MoveRequest {
            axis: axis.to_string(),
            target,
            relative,
            velocity: options.velocity.unwrap_or(0.0),
            acceleration: options.acceleration.unwrap_or(0.0),
            options: Some(cmd.to_pb()),
        };
        let r = self
            .call("Move", cmd.extra(), self.axes_client().r#move(req))
            .await?;
        Ok(CommandResult::from_pb(r))
    }

    /// Jogs at a signed velocity (user units/s; 0 stops). A dead-man:
    /// the axis stops `Axis.jog_deadman_ms` after the latest call, so call
    /// it again while the jog should go on. Needs the lease.
    pub async fn jog(
        &self,
        axis: &str,
        velocity: f64,
        options: &JogOptions,
    ) -> Result<CommandResult, Error> {
        let req = pb::JogRequest {
            axis: axis.to_string(),
            velocity,
            acceleration: options.acceleration.unwrap_or(0.0),
            options: Some(pb::CommandOptions {
                lease: options.lease.clone().unwrap_or_default(),
                wait: false,
                wait_timeout_ms: 0,
            }),
        };
        let r = self.call("Jog", None, self.axes_client().jog(req)).await?;
        Ok(CommandResult::from_pb(r))
    }

    /// Decelerates to rest with the profile deceleration. No lease needed.
    pub async fn stop(&self, axis: &str, wait: bool) -> Result<CommandResult, Error> {
        let options = CommandOptions::default().wait(wait);
        let req = command(axis, &options);
        let r = self
            .call("Stop", options.extra(), self.axes_client().stop(req))
            .await?;
        Ok(CommandResult::from_pb(r))
    }

    /// CiA 402 quick stop. No lease needed.
    pub async fn quick_stop(&self, axis: &str, wait: bool) -> Result<CommandResult, Error> {
        let options = CommandOptions::default().wait(wait);
        let req = command(axis, &options);
        let r = self
            .call(
                "QuickStop",
                options.extra(),
                self.axes_client().quick_stop(req),
            )
            .await?;
        Ok(CommandResult::from_pb(r))
    }

    /// Stops several axes at once (their stop frames leave together); one
    /// result per axis, in order. No lease needed.
    pub async fn stop_axes(
        &self,
        axes: &[&str],
        options: StopOptions,
    ) -> Result<Vec<CommandResult>, Error> {
        let req = pb::StopAxesRequest {
            axes: axes.iter().map(|a| a.to_string()).collect(),
            quick: options.quick,
            wait: options.wait,
        };
        let extra = options.wait.then_some(DEFAULT_WAIT);
        let r = self
            .call("StopAxes", extra, self.axes_client().stop_axes(req))
            .await?;
        Ok(r.results.into_iter().map(CommandResult::from_pb).collect())
    }

    /// A coordinated move of cyclic axes to absolute targets: they start
    /// and arrive together. `options.velocity`/`acceleration` limit every
    /// axis. Needs a lease covering all.
    pub async fn move_axes(
        &self,
        targets: &[(&str, f64)],
        options: &MoveOptions,
    ) -> Result<Vec<CommandResult>, Error> {
        let req = pb::MoveAxesRequest {
            targets: targets
                .iter()
                .map(|(axis, target)| pb::AxisTarget {
                    axis: axis.to_string(),
                    target: *target,
                    velocity: options.velocity.unwrap_or(0.0),
                    acceleration: options.acceleration.unwrap_or(0.0),
                })
                .collect(),
            lease: options.lease.clone().unwrap_or_default(),
            wait: options.wait,
        };
        let extra = options
            .wait
            .then(|| options.wait_timeout.unwrap_or(MOVE_AXES_WAIT));
        let r = self
            .call("MoveAxes", extra, self.axes_client().move_axes(req))
            .await?;
        Ok(r.results.into_iter().map(CommandResult::from_pb).collect())
    }

    /// Live state and events of `axes` (empty: all). With `changes_only`,
    /// a status identical to the axis's previous one is skipped.
    pub async fn watch_axes(
        &self,
        axes: &[&str],
        changes_only: bool,
    ) -> Result<EventStream<AxisUpdate>, Error> {
        let req = pb::StreamAxisStateRequest {
            axes: axes.iter().map(|a| a.to_string()).collect(),
            changes_only,
        };
        let s = self
            .call(
                "StreamAxisState",
                None,
                self.axes_client().stream_axis_state(req),
            )
            .await?;
        Ok(streams::flat_map(s, AxisUpdate::from_pb))
    }
}

fn command(axis: &str, options: &CommandOptions) -> pb::AxisCommandRequest {
    pb::AxisCommandRequest {
        axis: axis.to_string(),
        options: Some(options.to_pb()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn options_become_the_proto() {
        let o = CommandOptions {
            lease: Some("t".into()),
            wait: true,
            wait_timeout: Some(Duration::from_secs(3)),
        };
        let p = o.to_pb();
        assert_eq!(
            (p.lease.as_str(), p.wait, p.wait_timeout_ms),
            ("t", true, 3000)
        );
        assert_eq!(o.extra(), Some(Duration::from_secs(3)));
        assert_eq!(
            CommandOptions::default().wait(true).extra(),
            Some(DEFAULT_WAIT)
        );
        assert_eq!(CommandOptions::default().extra(), None);
        let m = MoveOptions::default()
            .velocity(20.0)
            .acceleration(100.0)
            .wait(true);
        assert_eq!(
            (m.velocity, m.acceleration, m.wait),
            (Some(20.0), Some(100.0), true)
        );
    }

    #[test]
    fn updates_are_typed() {
        use pb::axis_event::Kind;
        let ev = |kind| pb::AxisUpdate {
            update: Some(pb::axis_update::Update::Event(pb::AxisEvent {
                axis: "X".into(),
                timestamp_us: 1,
                kind: Some(kind),
            })),
        };
        assert_eq!(
            AxisUpdate::from_pb(ev(Kind::MotionDone(pb::MotionDone {
                command: "move".into(),
                outcome: pb::Outcome::Completed as i32,
                detail: "d".into(),
            }))),
            Some(AxisUpdate::MotionDone {
                axis: "X".into(),
                command: "move".into(),
                outcome: pb::Outcome::Completed,
                detail: "d".into()
            })
        );
        assert_eq!(
            AxisUpdate::from_pb(ev(Kind::Lost(4))),
            Some(AxisUpdate::Lost(4))
        );
        assert_eq!(AxisUpdate::from_pb(pb::AxisUpdate { update: None }), None);
    }
}
