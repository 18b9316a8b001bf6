//! CNC handwheels at run time: one task per wheel decodes its feed TPDOs
//! ([`FeedDecoder`], sans-IO), publishes feed events and statistics, resets
//! the counter baseline on heartbeat loss, reboot and mode change, switches
//! the wheel's mode by SDO, and — while the wheel is in manual mode — paces
//! the feed onto the bound axes ([`JogPacer`]: even output, bounded backlog)
//! as relative moves under the wheel's own control lease.

mod ledger;

use crate::axes::{Axes, AxisError, Caller};
use crate::canopen::{CanopenBus, NodeEventKind};
use crate::config::{CounterChoice, HandwheelConfig};
use crate::not_found::NotFound;
use cangate_axis::AxisCommand;
use cangate_can::{BusHandle, BusItem, Filter, FrameSelector, Timestamp};
use cangate_canopen::cia402::DriveState;
use cangate_canopen::handwheel::{
    BaselineReason, CounterLayout, FeedDecoder, FeedEvent, FeedStats, HandwheelAxis,
};
use cangate_canopen::master::SdoRequest;
use cangate_canopen::sdo::{TransferOptions, TransferOutcome};
use cangate_canopen::{NodeId, ObjectAddress};
use cangate_sim::{DeviceHandle, SimHandwheel};
use ledger::{BindingLedger, Executed};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::{broadcast, mpsc};
use tokio_util::sync::CancellationToken;

/// The wheel's operating mode object.
const MODE_OBJECT: ObjectAddress = ObjectAddress::new(0x2000, 0);
/// Lease TTL the wheel holds its bound axes with (renewed at a third).
const LEASE_TTL_MS: u32 = 1000;

/// The wheel's mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// 0x2000 = 0.
    Automatic,
    /// 0x2000 = 1.
    Manual,
}

/// What the bindings did with the feed. Every decoded unit is counted once
/// in `units` and ends in exactly one other counter or in `pending`:
/// [`BindingStats::balance`] is always 0.
#[derive(Debug, Clone, Default)]
pub struct BindingStats {
    /// Feed units decoded (any mode, any wheel axis; compensated ones
    /// included).
    pub units: u64,
    /// Units passed to axes.
    pub executed: u64,
    /// Dropped: the backlog was full, queued units discarded at a
    /// reversal or a mode change, units that would have run late, or a move
    /// the axis refused.
    pub dropped_backlog: u64,
    /// Dropped: the wheel was not in manual mode when they arrived.
    pub dropped_not_manual: u64,
    /// Units queued in the pacers, neither executed nor dropped yet.
    pub pending: u64,
    /// Dropped: axis not enabled.
    pub dropped_not_enabled: u64,
    /// Dropped: the wheel does not hold the axis.
    pub dropped_not_controlled: u64,
    /// Dropped: wheel axis not bound.
    pub dropped_unbound: u64,
    /// Why the binding cannot move now.
    pub blocked: String,
}

impl BindingStats {
    /// `units − executed − dropped − pending`: 0 when every unit is
    /// accounted for.
    pub fn balance(&self) -> i128 {
        i128::from(self.units)
            - i128::from(self.executed)
            - i128::from(self.dropped())
            - i128::from(self.pending)
    }

    /// Every dropped unit, whatever the reason.
    pub fn dropped(&self) -> u64 {
        self.dropped_backlog
            + self.dropped_not_manual
            + self.dropped_not_enabled
            + self.dropped_not_controlled
            + self.dropped_unbound
    }
}

/// A binding resolved to an axis index.
#[derive(Debug, Clone)]
pub struct Binding {
    /// Wheel selector position.
    pub wheel_axis: HandwheelAxis,
    /// Axis index in the [`Axes`].
    pub axis: usize,
    /// Axis name.
    pub axis_name: String,
    /// Distance per unit (axis user unit).
    pub distance_per_unit: f64,
}

/// Live state shared between a wheel's task and the API.
pub struct WheelState {
    /// Configuration.
    pub config: HandwheelConfig,
    /// Node id.
    pub node: NodeId,
    /// Where the feed counter sits in the feed byte.
    pub layout: CounterLayout,
    /// Resolved bindings.
    pub bindings: Vec<Binding>,
    /// Mode last set or read.
    pub mode: Mutex<Option<Mode>>,
    /// Heartbeat lost.
    pub node_lost: Mutex<bool>,
    /// Decoder statistics.
    pub stats: Mutex<FeedStats>,
    /// Binding statistics.
    pub binding: Mutex<BindingStats>,
    /// The simulated device, if the gateway runs it.
    pub sim: Option<DeviceHandle<SimHandwheel>>,
    control: mpsc::Sender<Control>,
}

enum Control {
    ModeChanged(Mode),
}

/// A feed event of wheel `wheel` (index), with its bus timestamp.
#[derive(Debug, Clone)]
pub struct WheelFeed {
    /// Wheel index.
    pub wheel: usize,
    /// Bus time.
    pub at: Timestamp,
    /// The decoded event.
    pub event: FeedEvent,
}

/// Every handwheel of the gateway.
pub struct Handwheels {
    wheels: Vec<Arc<WheelState>>,
    masters: Vec<CanopenBus>,
    feed: broadcast::Sender<WheelFeed>,
}

impl Handwheels {
    /// Starts one task per configured wheel.
    pub fn start(
        configs: &[HandwheelConfig],
        masters: &std::collections::BTreeMap<String, CanopenBus>,
        buses: &std::collections::BTreeMap<String, BusHandle>,
        axes: &Arc<Axes>,
        sims: &HashMap<(String, u32), DeviceHandle<SimHandwheel>>,
        cancel: CancellationToken,
    ) -> Result<(Arc<Handwheels>, Vec<tokio::task::JoinHandle<()>>), String> {
        let (feed, _) = broadcast::channel(65_536);
        let mut wheels = Vec::new();
        let mut wheel_masters = Vec::new();
        let mut tasks = Vec::new();
        for (i, c) in configs.iter().enumerate() {
            let node = NodeId::new(c.node).map_err(|e| format!("handwheel {}: {e}", c.name))?;
            let master = masters
                .get(&c.bus)
                .ok_or_else(|| format!("handwheel {}: no CANopen master", c.name))?
                .clone();
            let bus = buses
                .get(&c.bus)
                .ok_or_else(|| format!("handwheel {}: no bus", c.name))?
                .clone();
            let mut bindings = Vec::new();
            for b in &c.bind {
                let axis = axes
                    .index(&b.axis)
                    .map_err(|e| format!("handwheel {}: {e}", c.name))?;
                bindings.push(Binding {
                    wheel_axis: b.wheel_axis()?,
                    axis,
                    axis_name: b.axis.clone(),
                    distance_per_unit: b.distance_per_unit,
                });
            }
            let (control, control_rx) = mpsc::channel(16);
            let layout = match c.counter {
                CounterChoice::Nibble => CounterLayout::Nibble,
                CounterChoice::Bits67 => CounterLayout::Bits6_7,
            };
            let state = Arc::new(WheelState {
                config: c.clone(),
                node,
                layout,
                bindings,
                mode: Mutex::new(None),
                node_lost: Mutex::new(false),
                stats: Mutex::new(FeedStats::default()),
                binding: Mutex::new(BindingStats::default()),
                sim: sims.get(&(c.bus.clone(), c.node)).cloned(),
                control,
            });
            let decoder = FeedDecoder::new(node, layout);
            // Subscribe now, so the first frames after start-up are seen.
            let sub = bus.subscribe(
                FrameSelector {
                    filters: vec![Filter::exact_standard(decoder.cob_id())],
                    error_frames: false,
                    transmitted: false,
                },
                65_536,
            );
            // The wheel's task logs inside its bus's, node's and own spans.
            let span = tracing::info_span!("bus", bus = %master.bus());
            let span = tracing::info_span!(parent: &span, "node", node = node.get());
            let span =
                tracing::info_span!(parent: &span, "handwheel", handwheel = %state.config.name);
            tasks.push(tokio::spawn(tracing::Instrument::instrument(
                run_wheel(WheelTask {
                    index: i,
                    state: state.clone(),
                    decoder,
                    sub,
                    events: master.events(),
                    control: control_rx,
                    feed: feed.clone(),
                    axes: axes.clone(),
                    cancel: cancel.child_token(),
                }),
                span,
            )));
            wheels.push(state);
            wheel_masters.push(master);
        }
        Ok((
            Arc::new(Handwheels {
                wheels,
                masters: wheel_masters,
                feed,
            }),
            tasks,
        ))
    }

    /// Number of wheels.
    pub fn len(&self) -> usize {
        self.wheels.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.wheels.is_empty()
    }

    /// Whether any wheel is simulated by the gateway.
    pub fn any_simulated(&self) -> bool {
        self.wheels.iter().any(|w| w.sim.is_some())
    }

    /// Wheel `i`.
    pub fn wheel(&self, i: usize) -> &Arc<WheelState> {
        &self.wheels[i]
    }

    /// The index of a named wheel.
    pub fn index(&self, name: &str) -> Result<usize, HandwheelError> {
        self.wheels
            .iter()
            .position(|w| w.config.name == name)
            .ok_or_else(|| {
                HandwheelError::NotFound(NotFound::among(
                    "handwheel",
                    "handwheels",
                    name,
                    self.wheels.iter().map(|w| w.config.name.as_str()),
                ))
            })
    }

    /// Subscribes to every wheel's feed.
    pub fn subscribe(&self) -> broadcast::Receiver<WheelFeed> {
        self.feed.subscribe()
    }

    /// Reads the mode from the wheel (0x2000).
    pub async fn read_mode(&self, i: usize) -> Result<Mode, HandwheelError> {
        let w = &self.wheels[i];
        let r = self.masters[i]
            .sdo(
                w.node,
                SdoRequest::Upload {
                    addr: MODE_OBJECT,
                    opts: TransferOptions::default(),
                },
            )
            .await;
        let data = match r {
            Ok(TransferOutcome::Uploaded(d)) => d,
            Ok(_) => {
                return Err(HandwheelError::Device("unexpected SDO outcome".into()));
            }
            Err(crate::canopen::CanopenError::Sdo(error)) => {
                return Err(HandwheelError::Sdo {
                    node: w.config.node as u8,
                    error,
                });
            }
            Err(e) => return Err(HandwheelError::Unavailable(e.to_string())),
        };
        let mode = match data.first() {
            Some(0) => Mode::Automatic,
            Some(1) => Mode::Manual,
            other => {
                return Err(HandwheelError::Device(format!(
                    "handwheel {}: 0x2000 reads {other:?}, neither 0 (automatic) nor 1 (manual)",
                    w.config.name
                )));
            }
        };
        *w.mode.lock().expect("mode lock") = Some(mode);
        Ok(mode)
    }

    /// Writes the mode (0x2000) and confirms it by reading it back.
    pub async fn set_mode(&self, i: usize, mode: Mode) -> Result<Mode, HandwheelError> {
        let w = &self.wheels[i];
        let value = match mode {
            Mode::Automatic => 0u8,
            Mode::Manual => 1u8,
        };
        let r = self.masters[i]
            .sdo(
                w.node,
                SdoRequest::Download {
                    addr: MODE_OBJECT,
                    data: vec![value],
                    opts: TransferOptions::default(),
                },
            )
            .await;
        match r {
            Ok(_) => {}
            Err(crate::canopen::CanopenError::Sdo(error)) => {
                return Err(HandwheelError::Sdo {
                    node: w.config.node as u8,
                    error,
                });
            }
            Err(e) => return Err(HandwheelError::Unavailable(e.to_string())),
        }
        let read = self.read_mode(i).await?;
        if read != mode {
            return Err(HandwheelError::Device(format!(
                "handwheel {}: wrote mode {mode:?} but it reads back {read:?}",
                w.config.name
            )));
        }
        let _ = w.control.send(Control::ModeChanged(mode)).await;
        Ok(read)
    }
}

struct WheelTask {
    index: usize,
    state: Arc<WheelState>,
    decoder: FeedDecoder,
    sub: cangate_can::Subscription,
    events: broadcast::Receiver<crate::canopen::NodeEvent>,
    control: mpsc::Receiver<Control>,
    feed: broadcast::Sender<WheelFeed>,
    axes: Arc<Axes>,
    cancel: CancellationToken,
}

/// The wheel's hold on its bound axes.
struct Hold {
    lease: Option<String>,
    renewed: Instant,
    retry_at: Instant,
}

async fn run_wheel(mut t: WheelTask) {
    let origin = Instant::now();
    let mut items = Vec::with_capacity(256);
    let c = &t.state.config;
    let mut ledger = BindingLedger::new(
        t.state.bindings.len(),
        c.max_units_per_s,
        Duration::from_millis(u64::from(c.stop_within_ms)),
    );
    let mut manual = false;
    let mut hold = Hold {
        lease: None,
        renewed: Instant::now(),
        retry_at: Instant::now(),
    };
    // Paced output is polled at most every 2 ms (the axes take a set-point
    // per SYNC anyway), and the lease is renewed at a third of its TTL.
    let mut tick = tokio::time::interval(Duration::from_millis(2));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    loop {
        // Biased: a mode change confirmed before feed frames were read is
        // applied first, so those frames count in the new mode.
        tokio::select! {
            biased;
            _ = t.cancel.cancelled() => break,
            Some(ctl) = t.control.recv() => match ctl {
                Control::ModeChanged(mode) => {
                    t.decoder.reset_baseline(BaselineReason::ModeChange);
                    manual = mode == Mode::Manual;
                    ledger.clear();
                    if !manual {
                        release(&t.state, &mut ledger, &t.axes, &mut hold);
                    }
                    publish(&t.state, &ledger);
                }
            },
            n = t.sub.recv_many(&mut items, 256) => {
                if n == 0 {
                    break;
                }
                let now = origin.elapsed();
                for item in items.drain(..) {
                    match item {
                        BusItem::Frame { frame, .. } => {
                            if let Some(ev) = t.decoder.on_frame(&frame, now) {
                                if let Some(axis) = ev.axis {
                                    ledger.feed(&t.state.bindings, axis, ev.signed_units(), manual, now);
                                }
                                let _ = t.feed.send(WheelFeed {
                                    wheel: t.index,
                                    at: frame.timestamp(),
                                    event: ev,
                                });
                            }
                        }
                        BusItem::Lost(n) => {
                            // The gateway itself fell behind: the counter
                            // can no longer be trusted across the hole.
                            tracing::warn!(lost = n, "handwheel task missed feed frames (overloaded)");
                            t.decoder.reset_baseline(BaselineReason::Other);
                        }
                        BusItem::State(_) => {}
                    }
                }
                *t.state.stats.lock().expect("stats lock") = t.decoder.stats().clone();
                publish(&t.state, &ledger);
            }
            e = t.events.recv() => match e {
                Ok(e) if e.node == t.state.node => match e.kind {
                    NodeEventKind::HeartbeatLost { .. } => {
                        *t.state.node_lost.lock().expect("lock") = true;
                        t.decoder.reset_baseline(BaselineReason::HeartbeatLost);
                    }
                    NodeEventKind::HeartbeatRecovered { .. } => {
                        *t.state.node_lost.lock().expect("lock") = false;
                    }
                    NodeEventKind::BootUp => {
                        // A rebooted wheel starts in its default mode; its
                        // boot-up message says it is there again.
                        *t.state.node_lost.lock().expect("lock") = false;
                        t.decoder.reset_baseline(BaselineReason::DeviceRestart);
                        *t.state.mode.lock().expect("lock") = None;
                        manual = false;
                        ledger.clear();
                        release(&t.state, &mut ledger, &t.axes, &mut hold);
                        publish(&t.state, &ledger);
                    }
                    _ => {}
                },
                Ok(_) => {}
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    // A missed heartbeat loss or reboot would leave a stale
                    // counter baseline: start a new one.
                    tracing::warn!(missed = n, "handwheel task missed node events (overloaded)");
                    t.decoder.reset_baseline(BaselineReason::Other);
                }
                Err(broadcast::error::RecvError::Closed) => break,
            },
            // Only a wheel in manual mode with bindings has work to pace.
            _ = tick.tick(), if manual && !t.state.bindings.is_empty() => {
                keep_hold(&t.state, &mut ledger, &t.axes, &mut hold);
                let now = origin.elapsed();
                execute(&t.state, &t.axes, &mut ledger, &hold, now);
                publish(&t.state, &ledger);
            }
        }
    }
    release(&t.state, &mut ledger, &t.axes, &mut hold);
    publish(&t.state, &ledger);
}

/// Shows the ledger's counters to the API (one consistent snapshot).
fn publish(state: &WheelState, ledger: &BindingLedger) {
    *state.binding.lock().expect("binding lock") = ledger.stats();
}

/// Takes (and keeps renewing) control of the bound axes.
fn keep_hold(state: &WheelState, ledger: &mut BindingLedger, axes: &Axes, hold: &mut Hold) {
    let now = Instant::now();
    match &hold.lease {
        Some(token) => {
            if now.duration_since(hold.renewed)
                >= Duration::from_millis(u64::from(LEASE_TTL_MS / 3))
            {
                if axes.renew(&wheel_caller(state, token)).is_ok() {
                    hold.renewed = now;
                } else {
                    hold.lease = None;
                }
            }
        }
        None => {
            if now < hold.retry_at {
                return;
            }
            let names: Vec<String> = state.bindings.iter().map(|b| b.axis_name.clone()).collect();
            match axes.acquire(
                &names,
                Some(Duration::from_millis(u64::from(LEASE_TTL_MS))),
                wheel_caller(state, "").name,
                None,
            ) {
                Ok(l) => {
                    hold.lease = Some(l.token);
                    hold.renewed = now;
                    ledger.set_blocked(String::new());
                }
                Err(e) => {
                    hold.retry_at = now + Duration::from_millis(500);
                    ledger.set_blocked(e.to_string());
                }
            }
        }
    }
}

/// Gives the bound axes back (the wheel left manual mode, rebooted or
/// stopped); a refusal to take them no longer applies either.
fn release(state: &WheelState, ledger: &mut BindingLedger, axes: &Axes, hold: &mut Hold) {
    if let Some(token) = hold.lease.take() {
        let _ = axes.release(&wheel_caller(state, &token));
    }
    hold.retry_at = Instant::now();
    ledger.set_blocked(String::new());
}

/// Sends the units now due as relative moves.
fn execute(
    state: &WheelState,
    axes: &Axes,
    ledger: &mut BindingLedger,
    hold: &Hold,
    now: Duration,
) {
    ledger.poll(now, |k, units| {
        let b = &state.bindings[k];
        let Some(token) = &hold.lease else {
            return Executed::NotControlled;
        };
        let enabled = axes.latest(b.axis).is_some_and(|(s, _)| {
            s.state == Some(DriveState::OperationEnabled) && s.node_lost.is_none()
        });
        if !enabled {
            return Executed::NotEnabled;
        }
        let cfg = &axes.spec(b.axis).motion;
        // The paced rate as the move's velocity, so consecutive small moves
        // blend into an even motion.
        let velocity = (state.config.max_units_per_s * b.distance_per_unit).min(cfg.max_velocity);
        let cmd = AxisCommand::Move {
            target: units as f64 * b.distance_per_unit,
            relative: true,
            velocity: Some(velocity),
            acceleration: Some(cfg.max_acceleration),
        };
        match axes.submit(b.axis, cmd, &wheel_caller(state, token)) {
            Ok(()) => Executed::Done,
            Err(AxisError::Lease(_)) => Executed::NotControlled,
            Err(_) => Executed::Refused,
        }
    });
}

/// The wheel as the axes see it: named after it, presenting `token`.
fn wheel_caller(state: &WheelState, token: &str) -> Caller {
    Caller::new(format!("handwheel {}", state.config.name)).with_lease(token)
}

/// Why a handwheel request failed, by reason.
#[derive(Debug, thiserror::Error)]
pub enum HandwheelError {
    /// No such handwheel.
    #[error(transparent)]
    NotFound(#[from] NotFound),
    /// The wheel answered something it should not (a mode that is neither
    /// automatic nor manual, a write that does not read back).
    #[error("{0}")]
    Device(String),
    /// An SDO transfer to the wheel failed.
    #[error("node {node}: {error}")]
    Sdo {
        /// The wheel's node id.
        node: u8,
        /// The failure (abort code, timeout).
        error: cangate_canopen::sdo::SdoError,
    },
    /// The wheel's bus or master cannot carry the request.
    #[error("{0}")]
    Unavailable(String),
}
