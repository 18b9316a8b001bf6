//! What an axis runner is: the CiA 402 task of a CANopen bus
//! ([`crate::axes::cia402_task`]) and the cycle thread of a CANsmc master
//! ([`crate::cansmc::cycle_thread`]) both run axis controllers for the axis
//! layer ([`crate::axes`]). This module holds what passes between them:
//! the requests the axis layer sends ([`BusRequest`]), the replies and
//! updates it gets back, the waiters of commands, coordinated-move
//! planning, and the one dispatch of a request ([`AxisRunner::dispatch`]).
//! Both runners depend on it; it depends on neither.

use cangate_axis::cansmc::{CansmcAxis, CansmcAxisConfig};
use cangate_axis::cia402::{AxisSnapshot, Cia402Axis};
use cangate_axis::{AxisCommand, AxisEvent, CommandError, CommandKind, MotionSpec, OpId, Outcome};
use cangate_can::Timestamp;
use cangate_motion::{AxisMove, Limits, SyncedMove, TrapezoidProfile};
use std::collections::HashMap;
use std::sync::{Arc, RwLock};
use std::time::Duration;
use tokio::sync::{broadcast, mpsc, oneshot};

struct PendingReply {
    /// Answer at completion (true) or at acceptance.
    wait: bool,
    tx: oneshot::Sender<CommandReply>,
}

/// The callers waiting for the commands of one axis.
#[derive(Default)]
pub(crate) struct Waiters(HashMap<OpId, PendingReply>);

impl Waiters {
    /// Registers a caller of command `op`.
    pub(crate) fn add(&mut self, op: OpId, wait: bool) -> oneshot::Receiver<CommandReply> {
        let (tx, rx) = oneshot::channel();
        self.0.insert(op, PendingReply { wait, tx });
        rx
    }

    /// Answers the waiters `event` concerns, writes the audit and fault
    /// log lines, and publishes it on `updates` as axis `global`.
    pub(crate) fn dispatch(
        &mut self,
        event: AxisEvent,
        name: &str,
        global: usize,
        snapshot: impl Fn() -> AxisSnapshot,
        updates: Option<&broadcast::Sender<AxisUpdate>>,
    ) {
        let publish = |event: AxisEventKind| {
            if let Some(u) = updates {
                let _ = u.send(AxisUpdate::Event {
                    axis: global,
                    at: Timestamp::now(),
                    event,
                });
            }
        };
        match event {
            AxisEvent::Accepted { op } => {
                if self.0.get(&op).is_some_and(|w| !w.wait)
                    && let Some(w) = self.0.remove(&op)
                {
                    let _ = w.tx.send(CommandReply {
                        outcome: None,
                        detail: "accepted by the drive".into(),
                        snapshot: snapshot(),
                    });
                }
            }
            AxisEvent::Done {
                op,
                command,
                outcome,
                detail,
            } => {
                tracing::info!(target: "cangate::audit", axis = %name, command = %command, outcome = outcome.name(), %detail, "axis command ended");
                if let Some(w) = self.0.remove(&op) {
                    let _ = w.tx.send(CommandReply {
                        outcome: Some(outcome),
                        detail: detail.clone(),
                        snapshot: snapshot(),
                    });
                }
                publish(AxisEventKind::MotionDone {
                    command,
                    outcome,
                    detail,
                });
            }
            AxisEvent::Fault { code, text } => {
                if code == 0 && text.is_empty() {
                    tracing::info!(axis = %name, "axis fault cleared");
                } else if code == 0 && text.contains("rebooted") {
                    // Every start-up: the drive boots, the boot procedure
                    // configures it; not worth a warning.
                    tracing::info!(axis = %name, %text, "axis waits for its drive");
                } else {
                    tracing::warn!(axis = %name, code = format!("0x{code:04X}"), %text, "axis fault");
                }
                publish(AxisEventKind::Fault { code, text });
            }
            AxisEvent::TouchProbe { rising, position } => {
                publish(AxisEventKind::TouchProbe { rising, position });
            }
        }
    }
}

/// What planning a coordinated move needs from an axis controller,
/// whatever its drive family.
pub(crate) trait CoordinatedMember {
    /// The axis's defaults and maxima.
    fn motion(&self) -> &MotionSpec;
    /// Where a move starts: the demand position.
    fn demand(&self) -> f64;
    /// Whether the axis can take part in a coordinated move to `target`.
    fn check_coordinated(&self, target: f64) -> Result<(), CommandError>;
}

impl CoordinatedMember for Cia402Axis {
    fn motion(&self) -> &MotionSpec {
        &self.config().motion
    }
    fn demand(&self) -> f64 {
        Cia402Axis::demand(self)
    }
    fn check_coordinated(&self, target: f64) -> Result<(), CommandError> {
        Cia402Axis::check_coordinated(self, target)
    }
}

impl CoordinatedMember for CansmcAxis {
    fn motion(&self) -> &MotionSpec {
        &self.config().motion
    }
    fn demand(&self) -> f64 {
        CansmcAxis::demand(self)
    }
    fn check_coordinated(&self, target: f64) -> Result<(), CommandError> {
        CansmcAxis::check_coordinated(self, target)
    }
}

/// A coordinated move's target for one axis: the axis's index in its
/// runtime, the target, and the requested velocity and acceleration
/// (`None`: the axis's defaults).
pub(crate) type CoordinatedTarget = (usize, f64, Option<f64>, Option<f64>);

/// Plans a coordinated move ([`plan_coordinated`]) and checks every axis
/// before any starts, so that it is all or none. `axis(i)` gives the name
/// and controller of the runtime's axis `i`.
pub(crate) fn prepare_coordinated<'a, A: CoordinatedMember + 'a>(
    targets: &[CoordinatedTarget],
    axis: impl Fn(usize) -> (&'a str, &'a A),
) -> Result<Vec<(TrapezoidProfile, f64)>, CommandError> {
    let axes: Vec<CoordinatedAxis<'_>> = targets
        .iter()
        .map(|&(i, target, velocity, acceleration)| {
            let (name, a) = axis(i);
            let m = a.motion();
            CoordinatedAxis {
                name,
                from: a.demand(),
                target,
                velocity,
                acceleration,
                default_velocity: m.default_velocity,
                default_acceleration: m.default_acceleration,
                max_velocity: m.max_velocity,
                max_acceleration: m.max_acceleration,
            }
        })
        .collect();
    let plan = plan_coordinated(&axes)?;
    for &(i, target, ..) in targets {
        let (name, a) = axis(i);
        a.check_coordinated(target).map_err(|e| for_axis(name, e))?;
    }
    Ok(plan)
}

/// One axis of a coordinated move, as the runtime knows it.
pub(crate) struct CoordinatedAxis<'a> {
    /// For messages.
    pub name: &'a str,
    /// Where it starts (its demand position).
    pub from: f64,
    /// Where it goes.
    pub target: f64,
    /// The requested velocity and acceleration (`None`: the defaults).
    pub velocity: Option<f64>,
    /// See `velocity`.
    pub acceleration: Option<f64>,
    /// The axis's defaults and maxima.
    pub default_velocity: f64,
    /// See `default_velocity`.
    pub default_acceleration: f64,
    /// See `default_velocity`.
    pub max_velocity: f64,
    /// See `default_velocity`.
    pub max_acceleration: f64,
}

/// Plans a move where all axes start and arrive together: per axis its
/// profile and the time scale (profile time per wall time) to play it at.
pub(crate) fn plan_coordinated(
    axes: &[CoordinatedAxis<'_>],
) -> Result<Vec<(TrapezoidProfile, f64)>, CommandError> {
    let mut moves = Vec::new();
    for a in axes {
        let v = a.velocity.unwrap_or(a.default_velocity);
        let acc = a.acceleration.unwrap_or(a.default_acceleration);
        if v > a.max_velocity || acc > a.max_acceleration {
            return Err(CommandError::AboveMaximum(format!(
                "axis {}: velocity {v} / acceleration {acc} exceed the maxima {} / {}",
                a.name, a.max_velocity, a.max_acceleration
            )));
        }
        let limits = Limits::symmetric(v, acc)
            .map_err(|e| CommandError::BadValue(format!("axis {}: {e}", a.name)))?;
        moves.push(AxisMove::new(a.from, a.target, limits));
    }
    let plan = SyncedMove::new(moves).map_err(|e| CommandError::BadValue(e.to_string()))?;
    (0..axes.len())
        .map(|k| {
            let profile = plan.profile(k).cloned().ok_or_else(|| {
                CommandError::BadValue("the coordinated plan lost an axis".into())
            })?;
            let ratio = plan
                .time_scale(k)
                .map_or(0.0, |l| if l.is_finite() { 1.0 / l } else { 0.0 });
            Ok((profile, ratio))
        })
        .collect()
}

/// `e` with the axis named in its message.
pub(crate) fn for_axis(axis: &str, e: CommandError) -> CommandError {
    e.prefixed(&format!("axis {axis}: "))
}

/// How a command ended, for its caller.
#[derive(Debug)]
pub struct CommandReply {
    /// `None`: accepted (not waited for).
    pub outcome: Option<Outcome>,
    /// For people.
    pub detail: String,
    /// The axis right after.
    pub snapshot: AxisSnapshot,
}

/// The receiving end of a command: its [`CommandReply`].
pub type Waiter = oneshot::Receiver<CommandReply>;

/// Requests to a bus task.
pub enum BusRequest {
    /// One command.
    Command {
        /// Axis index in this task.
        local: usize,
        /// The command.
        cmd: AxisCommand,
        /// Reply at completion instead of acceptance.
        wait: bool,
        /// The waiter, or why the command was refused.
        reply: oneshot::Sender<Result<Waiter, CommandError>>,
    },
    /// Several commands applied in one step.
    Many {
        /// (axis, command).
        cmds: Vec<(usize, AxisCommand)>,
        /// As above.
        wait: bool,
        /// One result per command.
        reply: oneshot::Sender<Vec<Result<Waiter, CommandError>>>,
    },
    /// A coordinated cyclic move: (axis, target, velocity, acceleration).
    Coordinated {
        /// Targets.
        targets: Vec<CoordinatedTarget>,
        /// As above.
        wait: bool,
        /// The waiters (all or none).
        reply: oneshot::Sender<Result<Vec<Waiter>, CommandError>>,
    },
}

/// Something that happened to an axis, for StreamAxisState.
#[derive(Debug, Clone)]
pub enum AxisUpdate {
    /// New live state (after each process data update or command).
    Status {
        /// Axis index.
        axis: usize,
        /// The state.
        snapshot: Arc<AxisSnapshot>,
        /// Bus time of the process data.
        at: Timestamp,
    },
    /// An event.
    Event {
        /// Axis index.
        axis: usize,
        /// Wall time.
        at: Timestamp,
        /// What.
        event: AxisEventKind,
    },
}

/// The events of an axis.
#[derive(Debug, Clone)]
pub enum AxisEventKind {
    /// A command ended.
    MotionDone {
        /// Which command.
        command: CommandKind,
        /// How.
        outcome: Outcome,
        /// For people.
        detail: String,
    },
    /// Fault entered (code, text) or cleared (0, "").
    Fault {
        /// Error code.
        code: u16,
        /// Its name.
        text: String,
    },
    /// Touch probe 1 latched a position.
    TouchProbe {
        /// At the rising edge (else the falling one).
        rising: bool,
        /// User units.
        position: f64,
    },
    /// Control changed hands.
    Control {
        /// New holder ("" none).
        holder: String,
        /// Previous holder ("" none).
        previous: String,
        /// Why.
        reason: String,
    },
    /// The drive's node was lost or is back.
    Node {
        /// Lost (true) or back.
        lost: bool,
        /// Why.
        reason: String,
    },
}

/// Latest state of every axis, by axis index.
pub type LatestStates = Arc<RwLock<Vec<Option<(Arc<AxisSnapshot>, Timestamp)>>>>;

/// A CANsmc axis as the axis layer hands it over: its index among all
/// axes, its name, its controller's configuration.
pub struct CansmcPortAxis {
    /// Index among all axes of the gateway.
    pub global: usize,
    /// The axis's name.
    pub name: String,
    /// The controller's configuration (with its slave).
    pub controller: CansmcAxisConfig,
}

/// The axes of one master, as the axis layer hands them over.
pub struct AxisPort {
    /// Commands from the axis API.
    pub requests: mpsc::Receiver<BusRequest>,
    /// The master's axes in configuration order of `[[cansmc.axis]]`.
    pub axes: Vec<CansmcPortAxis>,
    /// Where updates go.
    pub updates: broadcast::Sender<AxisUpdate>,
    /// Latest state of every axis.
    pub latest: LatestStates,
    /// The set-point streams over these axes, played by the cycle thread.
    pub streams: Arc<dyn CycleStreams>,
}

/// The set-point streams over a CANsmc master's axes, as its cycle thread
/// plays them: at every cycle, before the axes compute their set-points,
/// so the streams need no thread hand-over per cycle.
pub trait CycleStreams: Send + Sync {
    /// Plays the cycle scheduled at `at`; `missed`: the cycles the thread
    /// skipped since the previous one, as time (the playout holds back by
    /// them: a late cycle never carries a double step). `axes`: the
    /// master's axes in [`AxisPort::axes`] order.
    fn play(&self, at: std::time::Instant, missed: Duration, axes: &mut [&mut CansmcAxis]);
}

/// A runner of axis controllers, as the axis layer drives it. Axes are
/// numbered within the runner (`local`).
pub(crate) trait AxisRunner {
    /// Starts `cmd` on axis `local`. The waiter answers at acceptance, or
    /// at completion with `wait`; a refused command changes nothing.
    fn start_command(
        &mut self,
        local: usize,
        cmd: AxisCommand,
        wait: bool,
        now: Duration,
    ) -> Result<Waiter, CommandError>;

    /// Starts a coordinated move of several axes: all or none.
    fn start_coordinated(
        &mut self,
        targets: Vec<CoordinatedTarget>,
        wait: bool,
        now: Duration,
    ) -> Result<Vec<Waiter>, CommandError>;

    /// Serves one request of the axis layer: the one dispatch both
    /// runners share.
    fn dispatch(&mut self, request: BusRequest, now: Duration) {
        match request {
            BusRequest::Command {
                local,
                cmd,
                wait,
                reply,
            } => {
                let r = self.start_command(local, cmd, wait, now);
                let _ = reply.send(r);
            }
            BusRequest::Many { cmds, wait, reply } => {
                let r = cmds
                    .into_iter()
                    .map(|(local, cmd)| self.start_command(local, cmd, wait, now))
                    .collect();
                let _ = reply.send(r);
            }
            BusRequest::Coordinated {
                targets,
                wait,
                reply,
            } => {
                let _ = reply.send(self.start_coordinated(targets, wait, now));
            }
        }
    }
}
