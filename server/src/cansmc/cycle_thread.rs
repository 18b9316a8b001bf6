//! The cycle thread of one CANsmc master.
//!
//! It owns the sans-IO master and the axes of its slaves, and wakes only at
//! the master's deadlines (MST, `T_int_end`, parameter timeouts). MST
//! timing is what the slaves synchronise on, so the thread sleeps with the
//! OS high-resolution timer until `spin_us` before the cycle start, then
//! waits actively for the exact instant (by default only under
//! `SCHED_FIFO`; see [`spin_ceiling_us`]): tokio timers (1 ms resolution)
//! and a drifting interval are not good enough. Cycle starts are absolute
//! (`t_k = t_0 + k × cycle`) and every MST's lateness goes into the jitter
//! histogram.
//!
//! At each cycle start the thread drains the channel-1 frames received
//! since the last wake (the previous cycle's DTs, all due before this MST),
//! runs the axes on them, sends MST, and at `T_int_end` the MDTs. Commands
//! from the axis API and parameter requests arrive through queues and are
//! served at the next wake (within one cycle).

use super::CansmcError;
use super::jitter::JitterHistogram;
use super::{AxisPort, CansmcEvent, CansmcStatus, Request, SlaveView};
use crate::axis_runner::{
    AxisEventKind, AxisRunner, AxisUpdate, BusRequest, CommandReply, CoordinatedTarget,
    CycleStreams, Waiters, for_axis, prepare_coordinated,
};
use crate::config::{CansmcConfig, CyclicChoice, DEFAULT_FIFO_SPIN_US};
use cangate_axis::cansmc::{CansmcAxis, CycleInput};
use cangate_axis::{AxisCommand, AxisEvent, CansmcDrive, CommandError, JogMode};
use cangate_can::precise_wait::SpinMargin;
use cangate_can::{BusHandle, BusItem, Direction, Frame, FrameSelector, Subscription, Timestamp};
use cangate_cansmc::master::{
    Master, MasterConfig, MasterEvent, Phase, RequestId, SlaveSpec, SlaveState,
};
use cangate_cansmc::{Command, Feedback, SmcAddress};
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::{broadcast, oneshot};
use tokio_util::sync::CancellationToken;

/// The least active wait before an MST, in µs (when `spin_us` is larger).
const SPIN_FLOOR_US: u64 = 20;

/// The longest active wait before an MST: the configured `spin_us`, else
/// [`DEFAULT_FIFO_SPIN_US`] under `SCHED_FIFO` and none without (see
/// [`CansmcConfig::spin_us`]).
fn spin_ceiling_us(configured: Option<u32>, fifo: bool) -> u32 {
    configured.unwrap_or(if fifo { DEFAULT_FIFO_SPIN_US } else { 0 })
}

/// How often the status and the axis states are published.
const PUBLISH_PERIOD: Duration = Duration::from_millis(10);

/// Everything the thread needs.
pub(crate) struct Setup {
    /// The bit rate of the command bus (for the MDT deadline).
    pub bitrate: u32,
    pub config: CansmcConfig,
    pub command_bus: BusHandle,
    pub status_bus: BusHandle,
    pub requests: std::sync::mpsc::Receiver<Request>,
    pub axes: Option<AxisPort>,
    pub status: Arc<Mutex<CansmcStatus>>,
    pub events: broadcast::Sender<CansmcEvent>,
    pub cancel: CancellationToken,
    /// Cleared when the thread ends (see
    /// [`super::CansmcMaster::cycle_thread_running`]).
    pub running: Arc<AtomicBool>,
}

struct Slot {
    global: usize,
    name: String,
    address: SmcAddress,
    axis: CansmcAxis,
    waiters: Waiters,
    /// Activity and fault at the latest publication, to publish changes
    /// at once.
    published: Option<(cangate_axis::Activity, bool)>,
}

struct Thread {
    master: Master,
    cfg: CansmcConfig,
    origin: Instant,
    command_bus: BusHandle,
    rt: tokio::runtime::Runtime,
    subscription: Subscription,
    slots: Vec<Slot>,
    by_address: HashMap<u8, usize>,
    /// Gear sources per axis slot.
    gear_source: Vec<Option<SmcAddress>>,
    axis_requests: Option<tokio::sync::mpsc::Receiver<BusRequest>>,
    updates: Option<broadcast::Sender<AxisUpdate>>,
    latest: Option<crate::axis_runner::LatestStates>,
    /// The set-point streams over the axes, played at each cycle start.
    streams: Option<Arc<dyn CycleStreams>>,
    /// The cycle the streams played last (a gap: cycles skipped).
    streams_cycle: Option<u64>,
    requests: std::sync::mpsc::Receiver<Request>,
    parameter_waiters: HashMap<RequestId, oneshot::Sender<Result<i32, CansmcError>>>,
    status: Arc<Mutex<CansmcStatus>>,
    events: broadcast::Sender<CansmcEvent>,
    jitter: JitterHistogram,
    /// How long before each MST the thread stops sleeping (up to
    /// `spin_us`, learnt from its wake-ups).
    spin: SpinMargin,
    start_error: Option<String>,
    starts: u64,
    /// When the status and the axis states are published next.
    next_publish: Duration,
    send_errors: u64,
    rx_lost: u64,
}

/// Starts the thread.
pub(crate) fn spawn(setup: Setup) -> Result<std::thread::JoinHandle<()>, String> {
    let name = format!("cansmc-{}", setup.config.name);
    let drives: Vec<&CansmcDrive> = (setup.axes.iter())
        .flat_map(|port| &port.axes)
        .map(|a| &a.controller.drive)
        .collect();
    let master_config = master_config(&setup.config, &drives, setup.bitrate);
    let master =
        Master::new(master_config).map_err(|e| format!("cansmc {}: {e}", setup.config.name))?;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| format!("cansmc {}: {e}", setup.config.name))?;
    // Subscribe before the first MCT, so that no DCT is missed.
    let subscription = setup
        .status_bus
        .subscribe(FrameSelector::all(), 4 * 64 + 1024);
    let (mut slots, mut gear_source, mut axis_requests, mut updates, mut latest, mut streams) =
        (Vec::new(), Vec::new(), None, None, None, None);
    if let Some(port) = setup.axes {
        for a in port.axes {
            let drive = &a.controller.drive;
            gear_source.push(drive.gear.and_then(|g| SmcAddress::new(g.source).ok()));
            slots.push(Slot {
                global: a.global,
                name: a.name,
                address: drive.address,
                axis: CansmcAxis::new(a.controller),
                waiters: Waiters::default(),
                published: None,
            });
        }
        axis_requests = Some(port.requests);
        updates = Some(port.updates);
        latest = Some(port.latest);
        streams = Some(port.streams);
    }
    let by_address = slots
        .iter()
        .enumerate()
        .map(|(i, s)| (s.address.get(), i))
        .collect();
    // Set when the thread starts: the default depends on whether it gets
    // SCHED_FIFO.
    let spin = SpinMargin::new(Duration::ZERO, Duration::ZERO);
    let mut t = Thread {
        master,
        cfg: setup.config,
        origin: Instant::now(),
        command_bus: setup.command_bus,
        rt,
        subscription,
        slots,
        by_address,
        gear_source,
        axis_requests,
        updates,
        latest,
        streams,
        streams_cycle: None,
        requests: setup.requests,
        parameter_waiters: HashMap::new(),
        status: setup.status,
        events: setup.events,
        jitter: JitterHistogram::default(),
        spin,
        start_error: None,
        starts: 0,
        next_publish: Duration::ZERO,
        send_errors: 0,
        rx_lost: 0,
    };
    let cancel = setup.cancel;
    let running = setup.running;
    // Everything the thread logs is in its master's span (a CANsmc master
    // has a command and a status bus).
    let span = tracing::info_span!("cansmc", master = %t.cfg.name);
    std::thread::Builder::new()
        .name(name)
        .spawn(move || {
            // Cleared last, even if the thread panics: after the final
            // status and with the thread's bus handles gone.
            let _running = ClearOnExit(running);
            let _in_master = span.entered();
            t.run(&cancel);
            drop(t);
        })
        .map_err(|e| format!("cannot start the CANsmc cycle thread: {e}"))
}

/// Clears its flag when dropped.
struct ClearOnExit(Arc<AtomicBool>);

impl Drop for ClearOnExit {
    fn drop(&mut self) {
        self.0.store(false, Ordering::Release);
    }
}

/// The master configuration: the slaves of `axes` start with a position
/// MDT, gear sources and `cyclic = "encoder"` slaves with an encoder
/// request.
fn master_config(cfg: &CansmcConfig, axes: &[&CansmcDrive], bitrate: u32) -> MasterConfig {
    let gear_sources: Vec<u8> = axes
        .iter()
        .filter_map(|a| a.gear.map(|g| g.source))
        .collect();
    let velocity_jogs: Vec<u8> = (axes.iter())
        .filter(|a| a.jog_mode == JogMode::SlaveVelocity)
        .map(|a| a.address.get())
        .collect();
    let axis_slaves: Vec<u8> = axes.iter().map(|a| a.address.get()).collect();
    let slaves = cfg
        .slaves
        .iter()
        .filter_map(|s| {
            let address = SmcAddress::new(s.address).ok()?;
            let initial_command = if axis_slaves.contains(&s.address) {
                Command::Position(0)
            } else if gear_sources.contains(&s.address) || s.cyclic == CyclicChoice::Encoder {
                Command::Encoder
            } else if s.cyclic == CyclicChoice::Io {
                Command::Io {
                    outputs: 0,
                    mask: 0,
                }
            } else {
                Command::Position(0)
            };
            Some(SlaveSpec {
                address,
                required: s.required,
                parameters: {
                    let mut p: Vec<(u16, i32)> =
                        s.parameters.iter().map(|p| (p.number, p.value)).collect();
                    // Velocity-mode jogs send 0.001 r/min (parameter 2 = 1)
                    // unless the configuration sets the unit itself.
                    if velocity_jogs.contains(&s.address) && !p.iter().any(|(n, _)| *n == 2) {
                        p.insert(0, (2, 1));
                    }
                    p
                },
                initial_command,
            })
        })
        .collect();
    let mut m = MasterConfig::new(cfg.cycle_time(), slaves);
    m.t_int = Duration::from_micros(u64::from(cfg.t_int_us));
    m.connect_timeout = Duration::from_millis(cfg.connect_timeout_ms);
    m.connect_attempts = cfg.connect_attempts;
    m.parameter_timeout = Duration::from_millis(cfg.parameter_timeout_ms);
    m.lost_after = cfg.lost_after;
    m.handover_grace = Duration::from_millis(u64::from(cfg.handover_grace_ms));
    m.mdt_deadline = m.mdt_deadline_for(bitrate);
    m
}

impl Thread {
    fn now(&self) -> Duration {
        self.origin.elapsed()
    }

    fn run(&mut self, cancel: &CancellationToken) {
        let mut fifo = false;
        if self.cfg.rt_priority > 0 {
            match crate::realtime::set_fifo(self.cfg.rt_priority) {
                Ok(()) => {
                    fifo = true;
                    tracing::info!(
                        priority = self.cfg.rt_priority,
                        "CANsmc cycle thread runs with SCHED_FIFO"
                    )
                }
                Err(e) => {
                    tracing::warn!(priority = self.cfg.rt_priority, error = %e, "CANsmc cycle thread could not get real-time priority (needs root or CAP_SYS_NICE); MST timing depends on the host's load")
                }
            }
        }
        let spin_us = u64::from(spin_ceiling_us(self.cfg.spin_us, fifo));
        self.spin = SpinMargin::new(
            Duration::from_micros(spin_us.min(SPIN_FLOOR_US)),
            Duration::from_micros(spin_us),
        );
        tracing::debug!(
            spin_us,
            "CANsmc cycle thread: active wait before each MST at most this long"
        );
        // Timed sleeps end within a µs of the deadline, not the default
        // 50 µs: the active wait before each MST then only covers the
        // wake-up latency.
        cangate_can::precise_wait::fine_timer_slack();
        self.start();
        while !cancel.is_cancelled() {
            let next = self.master.next_deadline();
            // Idle phases and P0/P1 wake often enough to serve answers and
            // requests promptly; P2 wakes at its deadlines.
            let cap = match self.master.phase() {
                Phase::Connecting | Phase::Parameterising => Duration::from_millis(1),
                Phase::Cyclic => Duration::from_millis(50),
                Phase::Idle | Phase::Failed => Duration::from_millis(20),
            };
            let now = self.now();
            let deadline = next.map_or(now + cap, |d| d.min(now + cap));
            let is_mst = self.master.phase() == Phase::Cyclic
                && next == Some(self.master.cycle_start(self.master.cycle() + 1));
            self.wait_until(deadline, is_mst);
            self.step(is_mst && Some(deadline) == next);
        }
        self.master.stop();
        self.publish_status();
    }

    /// Waits until `deadline`: for an MST (`exact`) by sleeping until a
    /// learnt margin before it, then actively (see [`SpinMargin`]: the
    /// margin follows this host's wake-up latency, within `spin_us`);
    /// otherwise by sleeping.
    fn wait_until(&mut self, deadline: Duration, exact: bool) {
        let target = self.origin + deadline;
        if exact && !self.spin.margin().is_zero() {
            self.spin.wait_until(target);
            return;
        }
        let now = Instant::now();
        if now < target {
            std::thread::sleep(target - now);
        }
    }

    fn start(&mut self) {
        self.starts += 1;
        self.start_error = None;
        let now = self.now();
        let frames = self.master.start(now);
        self.send(frames);
        self.after_master();
    }

    fn step(&mut self, mst_due: bool) {
        // Answers first: the previous cycle's DTs belong before this MST.
        self.drain_status_channel();
        let now = self.now();
        let poll = self.master.poll(now);
        let mut frames = poll.frames;
        if let Some((k, scheduled)) = poll.cycle_started {
            if mst_due || k > 0 {
                self.jitter
                    .record(now.saturating_sub(scheduled).as_nanos() as u64);
            }
            // MST first, then the axes compute this cycle's set-points.
            self.send(std::mem::take(&mut frames));
            self.play_streams(k, scheduled);
            self.run_axes(now, k);
        }
        self.send(frames);
        self.serve_requests(now);
        self.after_master();
        if poll.cycle_started.is_some() && now >= self.next_publish {
            // About every 10 ms, by time: cycle numbers skipped by an
            // overrun must not delay it.
            self.next_publish = now + PUBLISH_PERIOD;
            self.publish_status();
            for i in 0..self.slots.len() {
                self.publish_axis(i);
            }
        }
    }

    fn drain_status_channel(&mut self) {
        let mut answers = Vec::new();
        let now = self.now();
        // The wall-clock time of the origin, to put bus timestamps on the
        // master's clock (taken at each drain: no drift between the two).
        let origin_wall = i128::from(Timestamp::now().as_nanos()) - now.as_nanos() as i128;
        while let Some(item) = self.subscription.try_recv() {
            match item {
                BusItem::Frame {
                    frame,
                    direction: Direction::Rx,
                } => {
                    let at = arrival(frame.timestamp(), origin_wall, now);
                    answers.extend(self.master.on_frame(&frame, at));
                }
                BusItem::Frame { .. } | BusItem::State(_) => {}
                BusItem::Lost(n) => {
                    self.rx_lost += n;
                    tracing::warn!(
                        lost = n,
                        "CANsmc master lost channel-1 frames (queue overflow)"
                    );
                }
            }
        }
        self.send(answers);
    }

    fn send(&mut self, frames: Vec<Frame>) {
        if frames.is_empty() {
            return;
        }
        let bus = self.command_bus.clone();
        if let Err(e) = self.rt.block_on(bus.submit(frames)) {
            self.send_errors += 1;
            if self.send_errors.is_power_of_two() {
                tracing::warn!(error = %e, failures = self.send_errors, "CANsmc telegrams not sent");
            }
        }
    }

    /// Plays the set-point streams for cycle `k`, scheduled at `scheduled`
    /// (on the nominal grid): each streamed axis gets this cycle's
    /// set-point before it runs.
    fn play_streams(&mut self, k: u64, scheduled: Duration) {
        let Some(streams) = &self.streams else {
            return;
        };
        let skipped = self
            .streams_cycle
            .filter(|&last| k > last)
            .map_or(0, |last| k - last - 1);
        self.streams_cycle = Some(k);
        let cycle = self.cfg.cycle_time();
        let missed = cycle.saturating_mul(u32::try_from(skipped).unwrap_or(u32::MAX));
        let mut axes: Vec<&mut CansmcAxis> = self.slots.iter_mut().map(|s| &mut s.axis).collect();
        streams.play(self.origin + scheduled, missed, &mut axes);
    }

    /// Feeds every axis its slave's latest answer; sets the MDT content.
    fn run_axes(&mut self, now: Duration, cycle: u64) {
        for i in 0..self.slots.len() {
            let fresh = |fb: Option<&(cangate_cansmc::StatusWord, Feedback, u64)>| {
                fb.filter(|(_, _, c)| c + 1 == cycle).copied()
            };
            let own = self
                .master
                .slave(self.slots[i].address)
                .and_then(|s| s.last.as_ref());
            // Only the DT answering the previous cycle: a stale status
            // must not pass for the effect of a command sent since.
            let status = fresh(own).map(|(s, _, _)| s);
            let (position, velocity, encoder) = match fresh(own).map(|(_, fb, _)| fb) {
                Some(Feedback::Position(p) | Feedback::Homing(p)) => (Some(p), None, None),
                Some(Feedback::Velocity(v)) => (None, Some(v), None),
                Some(Feedback::Encoder(c)) => (None, None, Some(c)),
                _ => (None, None, None),
            };
            let source_count = self.gear_source[i].and_then(|src| {
                fresh(self.master.slave(src).and_then(|s| s.last.as_ref())).and_then(
                    |(_, fb, _)| match fb {
                        Feedback::Encoder(c) | Feedback::Position(c) | Feedback::Homing(c) => {
                            Some(c)
                        }
                        _ => None,
                    },
                )
            });
            let mut events = Vec::new();
            let out = self.slots[i].axis.on_cycle(
                now,
                CycleInput {
                    status,
                    position,
                    source_count,
                    velocity,
                    encoder,
                },
                &mut events,
            );
            let _ = self
                .master
                .set_command(self.slots[i].address, out.control, out.command);
            // Events publish the axis themselves (on_axis_events).
            self.on_axis_events(i, events);
            let activity = self.slots[i].axis.activity();
            let fault = self.slots[i].axis.has_fault();
            if self.slots[i].published != Some((activity, fault)) {
                self.publish_axis(i);
            }
        }
    }

    fn serve_requests(&mut self, now: Duration) {
        while let Ok(r) = self.requests.try_recv() {
            match r {
                Request::Parameter {
                    address,
                    number,
                    write,
                    reply,
                } => {
                    let id = match write {
                        Some(v) => self.master.write_parameter(address, number, v),
                        None => self.master.read_parameter(address, number),
                    };
                    match id {
                        Ok(id) => {
                            self.parameter_waiters.insert(id, reply);
                        }
                        Err(e) => {
                            let _ = reply.send(Err(CansmcError::Parameter(e)));
                        }
                    }
                }
                Request::Restart { reply } => {
                    tracing::info!("CANsmc master restarts through P0/P1");
                    for i in 0..self.slots.len() {
                        let mut ev = Vec::new();
                        self.slots[i]
                            .axis
                            .on_slave_lost("the master restarts (P0/P1)", &mut ev);
                        self.on_axis_events(i, ev);
                        self.node_event(i, true, "the master restarts (P0/P1)".into());
                        self.publish_axis(i);
                    }
                    self.jitter.clear();
                    self.starts += 1;
                    self.start_error = None;
                    let frames = self.master.restart(now);
                    self.send(frames);
                    let _ = reply.send(());
                }
            }
        }
        let Some(mut rx) = self.axis_requests.take() else {
            return;
        };
        while let Ok(r) = rx.try_recv() {
            self.on_axis_request(r, now);
        }
        self.axis_requests = Some(rx);
    }

    fn after_master(&mut self) {
        for e in self.master.take_events() {
            match e {
                MasterEvent::Phase(p) => {
                    tracing::info!(phase = %p, "CANsmc phase");
                    if p == Phase::Cyclic {
                        self.jitter.clear();
                        for i in 0..self.slots.len() {
                            let back = self
                                .master
                                .slave(self.slots[i].address)
                                .is_some_and(|s| s.state == SlaveState::Operational);
                            if back {
                                let mut ev = Vec::new();
                                self.slots[i].axis.on_slave_back(&mut ev);
                                self.on_axis_events(i, ev);
                                self.node_event(i, false, "the master is in P2".into());
                            }
                        }
                    }
                    let _ = self.events.send(CansmcEvent::Phase(p));
                    self.publish_status();
                }
                MasterEvent::StartFailed { reason } => {
                    tracing::error!(%reason, "CANsmc start-up failed");
                    self.start_error = Some(reason);
                }
                MasterEvent::SlaveConnected {
                    address,
                    device_type,
                    firmware_version,
                } => {
                    tracing::info!(
                        slave = address.get(),
                        device_type = format!("0x{device_type:04X}"),
                        firmware = format!("0x{firmware_version:04X}"),
                        "CANsmc slave connected"
                    );
                    self.slave_event(
                        address,
                        format!(
                            "connected (device type 0x{device_type:04X}, firmware 0x{firmware_version:04X})"
                        ),
                    );
                }
                MasterEvent::SlaveMissing {
                    address,
                    required,
                    reason,
                } => {
                    tracing::warn!(slave = address.get(), required, %reason, "CANsmc slave missing");
                    self.slave_event(address, format!("missing: {reason}"));
                    self.axis_lost(address, &format!("missing: {reason}"));
                }
                MasterEvent::SlaveLost { address, misses } => {
                    let reason = format!("{misses} consecutive DTs missed");
                    let c = self
                        .master
                        .slave(address)
                        .map(|s| s.counters)
                        .unwrap_or_default();
                    tracing::warn!(
                        slave = address.get(),
                        misses,
                        dts = c.dts,
                        missed = c.missed,
                        late = c.late,
                        mismatch = c.counter_mismatch,
                        overruns = self.master.counters().overruns,
                        slots_missed = self.master.counters().mdt_slots_missed,
                        "CANsmc slave lost"
                    );
                    self.slave_event(address, format!("lost: {reason}"));
                    self.axis_lost(address, &reason);
                }
                MasterEvent::SlaveRecovered { address } => {
                    tracing::info!(slave = address.get(), "CANsmc slave answers again");
                    self.slave_event(address, "recovered".into());
                    if let Some(&i) = self.by_address.get(&address.get()) {
                        let mut ev = Vec::new();
                        self.slots[i].axis.on_slave_back(&mut ev);
                        self.on_axis_events(i, ev);
                        self.node_event(
                            i,
                            false,
                            "the slave answers again (the axis was disabled when it was lost: enable it again)".into(),
                        );
                    }
                }
                MasterEvent::Rejected {
                    address,
                    function,
                    reason,
                } => {
                    tracing::warn!(slave = address.get(), %function, ?reason, "CANsmc slave rejected its command");
                    self.slave_event(address, format!("rejected {function}: {reason:?}"));
                }
                MasterEvent::ParameterDone { id, result, .. } => {
                    if let Some(w) = self.parameter_waiters.remove(&id) {
                        let _ = w.send(result.map_err(CansmcError::Parameter));
                    }
                }
            }
        }
    }

    fn slave_event(&self, address: SmcAddress, what: String) {
        let _ = self.events.send(CansmcEvent::Slave {
            address: address.get(),
            what,
        });
    }

    fn axis_lost(&mut self, address: SmcAddress, reason: &str) {
        if let Some(&i) = self.by_address.get(&address.get()) {
            let mut ev = Vec::new();
            self.slots[i].axis.on_slave_lost(reason, &mut ev);
            self.on_axis_events(i, ev);
            self.node_event(i, true, reason.to_string());
            self.publish_axis(i);
        }
    }

    fn node_event(&self, i: usize, lost: bool, reason: String) {
        if let Some(u) = &self.updates {
            let _ = u.send(AxisUpdate::Event {
                axis: self.slots[i].global,
                at: Timestamp::now(),
                event: AxisEventKind::Node { lost, reason },
            });
        }
    }

    fn publish_status(&self) {
        let slaves = self
            .master
            .slaves()
            .map(|s| {
                let a = s.spec.address.get();
                let cfg = self.cfg.slaves.iter().find(|c| c.address == a);
                SlaveView {
                    address: a,
                    name: cfg.map(|c| c.name.clone()).unwrap_or_default(),
                    required: s.spec.required,
                    state: s.state,
                    device_type: s.device_type,
                    firmware_version: s.firmware_version,
                    status_word: s.last.map(|(w, _, _)| w.to_bits()),
                    counters: s.counters,
                    consecutive_misses: s.consecutive_misses,
                    axis: self.by_address.get(&a).map(|&i| self.slots[i].name.clone()),
                }
            })
            .collect();
        let mut st = self.status.lock().expect("status lock");
        *st = CansmcStatus {
            phase: self.master.phase(),
            cycle: self.master.cycle(),
            counters: self.master.counters(),
            slaves,
            jitter: self.jitter.stats(),
            start_error: self.start_error.clone(),
            starts: self.starts,
        };
    }

    fn publish_axis(&mut self, i: usize) {
        let (Some(updates), Some(latest)) = (&self.updates, &self.latest) else {
            return;
        };
        let slot = &mut self.slots[i];
        let snapshot = Arc::new(slot.axis.snapshot());
        slot.published = Some((snapshot.activity, snapshot.fault.is_some()));
        let at = Timestamp::now();
        latest.write().expect("latest lock")[slot.global] = Some((snapshot.clone(), at));
        let _ = updates.send(AxisUpdate::Status {
            axis: slot.global,
            snapshot,
            at,
        });
    }

    // ------------------------------------------------------------ axis API

    fn on_axis_request(&mut self, r: BusRequest, now: Duration) {
        self.dispatch(r, now);
    }

    fn on_axis_events(&mut self, i: usize, events: Vec<AxisEvent>) {
        if events.is_empty() {
            return;
        }
        // GetAxis and the status stream show the state that ended a
        // command before the command's caller hears of it.
        self.publish_axis(i);
        let slot = &mut self.slots[i];
        let axis = &slot.axis;
        for e in events {
            slot.waiters.dispatch(
                e,
                &slot.name,
                slot.global,
                || axis.snapshot(),
                self.updates.as_ref(),
            );
        }
    }
}

/// When a frame stamped `ts` arrived, on the master's clock: the bus
/// timestamp (the bit-timed virtual bus stamps the modelled end of frame,
/// SocketCAN the kernel's receive time), so that host scheduling delays
/// between the wire and this thread do not count against the slave. An
/// unstamped frame, or a stamp outside the last 100 ms (a clock step),
/// counts as arriving now.
fn arrival(ts: Timestamp, origin_wall: i128, now: Duration) -> Duration {
    if ts.as_nanos() == 0 {
        return now;
    }
    let at = i128::from(ts.as_nanos()) - origin_wall;
    let now_ns = now.as_nanos() as i128;
    if at > now_ns || at < now_ns - 100_000_000 {
        return now;
    }
    Duration::from_nanos(at as u64)
}

impl AxisRunner for Thread {
    fn start_command(
        &mut self,
        i: usize,
        cmd: AxisCommand,
        wait: bool,
        now: Duration,
    ) -> Result<oneshot::Receiver<CommandReply>, CommandError> {
        let mut events = Vec::new();
        let op = self.slots[i].axis.command(cmd, now, &mut events)?;
        let rx = self.slots[i].waiters.add(op, wait);
        self.on_axis_events(i, events);
        self.publish_axis(i);
        Ok(rx)
    }

    fn start_coordinated(
        &mut self,
        targets: Vec<CoordinatedTarget>,
        wait: bool,
        now: Duration,
    ) -> Result<Vec<oneshot::Receiver<CommandReply>>, CommandError> {
        let slots = &self.slots;
        let plan = prepare_coordinated(&targets, |i| (slots[i].name.as_str(), &slots[i].axis))?;
        let mut waiters = Vec::new();
        for ((profile, ratio), &(i, ..)) in plan.into_iter().zip(&targets) {
            let mut events = Vec::new();
            let op = self.slots[i]
                .axis
                .start_coordinated(profile, ratio, now, &mut events)
                .map_err(|e| for_axis(&self.slots[i].name, e))?;
            waiters.push(self.slots[i].waiters.add(op, wait));
            self.on_axis_events(i, events);
            self.publish_axis(i);
        }
        Ok(waiters)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_configured_hand_over_grace_reaches_the_master() {
        let config = crate::config::Config::from_toml(crate::config::DEMO_CONFIG).unwrap();
        let m = master_config(&config.cansmc[0], &[], 1_000_000);
        assert_eq!(m.handover_grace, Duration::from_millis(56));
        assert_eq!(m.handover_grace_cycles(), 14);
    }

    #[test]
    fn the_cycle_thread_spins_by_default_only_under_sched_fifo() {
        assert_eq!(spin_ceiling_us(None, true), DEFAULT_FIFO_SPIN_US);
        assert_eq!(spin_ceiling_us(None, false), 0);
        // A configured value holds either way.
        assert_eq!(spin_ceiling_us(Some(150), false), 150);
        assert_eq!(spin_ceiling_us(Some(0), true), 0);
    }
}
