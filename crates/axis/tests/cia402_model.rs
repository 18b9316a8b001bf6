//! Model-based random tests of the CiA 402 axis layer: generated command
//! sequences (enable, disable, home, absolute and relative moves, jogs and
//! held jogs, stop, quick stop, reset fault, lease expiry as the runtime
//! handles it, node loss with and without a reboot, drive faults, pauses)
//! against the simulated drive (`cangate-sim`), in profile position and in
//! cyclic synchronous position, in virtual time.
//!
//! Invariants, checked at every step and at every command's end:
//!
//! - never wedged: after stop, reset fault and enable, a reachable move
//!   completes;
//! - every waited command ends with an outcome within its bound, and the
//!   healthy simulated drive never makes a command time out;
//! - the drive never goes beyond the soft limits (or further beyond them
//!   when a reboot put its position reference outside);
//! - completion only at rest (and a move's in the in-position window);
//! - an axis left without a command comes to rest: no command mix leaves
//!   the drive moving without a trajectory the gateway controls;
//! - counters add up: every started command ends exactly once.
//!
//! Every sequence comes from a seed. A failure prints the seed, the mode
//! and the actions up to the failure; replay one with
//! `CIA402_MODEL_SEED=<seed> CIA402_MODEL_MODE=<profile|cyclic> cargo test
//! -p cangate-axis --test cia402_model`.

use std::collections::{HashMap, HashSet};
use std::fmt::Write as _;
use std::time::Duration;

use cangate_axis::PositionMode;
use cangate_axis::cia402::{Cia402Axis, Cia402Config, Output};
use cangate_axis::process_data::{
    FeedbackTrigger, encode_image, feedback_from_values, standard_pdos,
};
use cangate_axis::{Activity, AxisCommand, AxisEvent, CommandError, OpId, Outcome};
use cangate_can::{CanId, Frame};
use cangate_canopen::cia402::{DriveState, objects as obj};
use cangate_canopen::pdo::PdoConfig;
use cangate_canopen::{NodeId, ObjectAddress};
use cangate_sim::Device;
use cangate_sim::drive::{SimDrive, SimDriveOptions};

const MS: Duration = Duration::from_millis(1);
const NODE: u8 = 1;
const SYNC: Duration = Duration::from_millis(10);
/// Counts per mm.
const SCALE: f64 = 1000.0;

/// SplitMix64: small, fast, and the same sequence on every machine.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }

    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }

    fn chance(&mut self, percent: u64) -> bool {
        self.below(100) < percent
    }
}

/// One step of a generated sequence.
#[derive(Debug, Clone, Copy)]
enum Action {
    Enable {
        wait: bool,
    },
    Disable {
        wait: bool,
    },
    ResetFault {
        wait: bool,
    },
    Home {
        wait: bool,
    },
    Move {
        target: f64,
        relative: bool,
        velocity: Option<f64>,
        wait: bool,
    },
    Jog {
        velocity: f64,
    },
    /// A client repeating a jog every 150 ms for `ms`.
    JogHeld {
        velocity: f64,
        ms: u64,
    },
    Stop {
        wait: bool,
    },
    QuickStop {
        wait: bool,
    },
    /// The lease lapsed: the runtime stops a moving axis (halt on cyclic
    /// axes, quick stop on profile axes, as the demo configures them).
    LeaseExpiry,
    /// The link to the node is down for `ms` (no frames either way); then
    /// it is back as it was, or the node was reset and booted again.
    NodeLoss {
        ms: u64,
        reboot: bool,
    },
    DriveFault,
    Pause {
        ms: u64,
    },
}

fn generate(rng: &mut Rng, mode: PositionMode) -> Vec<Action> {
    let limit = limit(mode);
    let vmax = cfg(mode).motion.max_velocity;
    let n = 4 + rng.below(10);
    let mut actions = vec![Action::Enable {
        wait: rng.chance(70),
    }];
    for _ in 0..n {
        let wait = rng.chance(40);
        let a = match rng.below(100) {
            0..=5 => Action::Enable { wait },
            6..=8 => Action::Disable { wait },
            9..=11 => Action::ResetFault { wait },
            12..=18 => Action::Home { wait },
            19..=40 => {
                let relative = rng.chance(30);
                let target = if relative {
                    rng.range(-40.0, 40.0)
                } else if rng.chance(10) {
                    // Beyond the limits: refused.
                    rng.range(1.0, 1.2) * limit * if rng.chance(50) { 1.0 } else { -1.0 }
                } else {
                    rng.range(-limit, limit)
                };
                // Mostly fast: the virtual time of a run is what costs.
                let velocity = rng.chance(80).then(|| rng.range(0.5, 1.0) * vmax);
                Action::Move {
                    target,
                    relative,
                    velocity,
                    wait,
                }
            }
            41..=52 => Action::Jog {
                velocity: rng.range(-1.0, 1.0) * vmax,
            },
            53..=58 => Action::JogHeld {
                velocity: rng.range(-1.0, 1.0) * vmax,
                ms: 200 + rng.below(800),
            },
            59..=68 => Action::Stop { wait },
            69..=72 => Action::QuickStop { wait },
            73..=76 => Action::LeaseExpiry,
            77..=79 => Action::NodeLoss {
                ms: 20 + rng.below(400),
                reboot: rng.chance(50),
            },
            80..=82 => Action::DriveFault,
            _ => Action::Pause { ms: rng.below(400) },
        };
        actions.push(a);
    }
    actions
}

fn limit(mode: PositionMode) -> f64 {
    match mode {
        PositionMode::Cyclic => 200.0,
        PositionMode::Profile => 100.0,
    }
}

/// The demo's axes: X (cyclic) and Z (profile).
fn cfg(mode: PositionMode) -> Cia402Config {
    let mut c = Cia402Config::example(SCALE, mode);
    let (vmax, amax) = match mode {
        PositionMode::Cyclic => (100.0, 1000.0),
        PositionMode::Profile => (50.0, 500.0),
    };
    c.motion.min_position = Some(-limit(mode));
    c.motion.max_position = Some(limit(mode));
    c.motion.max_velocity = vmax;
    c.motion.max_acceleration = amax;
    c.motion.default_velocity = vmax / 4.0;
    c.motion.default_acceleration = amax / 4.0;
    c.motion.stop_deceleration = amax;
    c.motion.quick_stop_deceleration = amax;
    c.motion.in_position_window = 10.0 / SCALE;
    c
}

fn frame(id: u16, data: &[u8]) -> Frame {
    Frame::new(CanId::Standard(id), data).unwrap()
}

/// The axis and its simulated drive, coupled frame by frame.
struct Rig {
    mode: PositionMode,
    /// Wall time since the rig was made (the cost of a run).
    started_at: std::time::Instant,
    axis: Cia402Axis,
    drive: SimDrive,
    now: Duration,
    next_sync: Duration,
    rpdos: Vec<PdoConfig>,
    tpdos: Vec<PdoConfig>,
    /// The link to the node is down: frames are lost both ways.
    link_down: bool,
    /// Ops started and ended, with their commands.
    started: HashMap<OpId, AxisCommand>,
    ended: HashMap<OpId, (Outcome, String)>,
    /// Absolute targets of the move ops (mm).
    targets: HashMap<OpId, f64>,
    /// Since when the axis has had no command while its link was up.
    idle_since: Option<Duration>,
    /// The position the drive had at the previous check (counts).
    last_position: f64,
    /// Invariant violations.
    failures: Vec<String>,
}

impl Rig {
    fn new(mode: PositionMode) -> Rig {
        let node = NodeId::new(u32::from(NODE)).unwrap();
        // A 2 ms model step: half the cost of the default 1 ms in a debug
        // build, still five steps per SYNC.
        let options = SimDriveOptions {
            step: 2 * MS,
            ..SimDriveOptions::default()
        };
        let mut drive = SimDrive::bundled(node, options);
        drive.start(Duration::ZERO);
        let (rpdos, tpdos) = standard_pdos(node, FeedbackTrigger::Sync);
        let mut rig = Rig {
            mode,
            started_at: std::time::Instant::now(),
            axis: Cia402Axis::new(cfg(mode)),
            drive,
            now: Duration::ZERO,
            next_sync: SYNC,
            rpdos,
            tpdos,
            link_down: false,
            started: HashMap::new(),
            ended: HashMap::new(),
            targets: HashMap::new(),
            idle_since: None,
            last_position: 0.0,
            failures: Vec::new(),
        };
        rig.boot();
        rig.run(30 * MS);
        rig
    }

    /// The gateway's boot procedure: PDOs, soft limits, homing, start.
    fn boot(&mut self) {
        let mut writes = Vec::new();
        for p in self.rpdos.iter().chain(&self.tpdos) {
            writes.extend(p.sdo_writes().unwrap());
        }
        writes.extend(self.axis.boot_writes());
        let method: u8 = match self.mode {
            PositionMode::Cyclic => 35,
            PositionMode::Profile => 19,
        };
        writes.push((obj::HOMING_METHOD, vec![method]));
        // A homing run at 20 mm/s, 100 mm/s².
        writes.push((
            ObjectAddress::new(0x6099, 1),
            20_000u32.to_le_bytes().to_vec(),
        ));
        writes.push((
            ObjectAddress::new(0x609A, 0),
            100_000u32.to_le_bytes().to_vec(),
        ));
        for (addr, data) in writes {
            self.sdo_write(addr, &data);
        }
        let start = self.drive.on_frame(&frame(0x000, &[0x01, NODE]), self.now);
        self.deliver(start);
    }

    fn sdo_write(&mut self, addr: ObjectAddress, data: &[u8]) {
        let n = 4 - data.len() as u8;
        let mut f = vec![
            0x23 | (n << 2),
            addr.index as u8,
            (addr.index >> 8) as u8,
            addr.sub,
        ];
        f.extend_from_slice(data);
        f.resize(8, 0);
        let reply = self
            .drive
            .on_frame(&frame(0x600 + u16::from(NODE), &f), self.now);
        assert!(
            reply
                .iter()
                .any(|r| r.raw_id() == 0x580 + u32::from(NODE) && r.data()[0] == 0x60),
            "SDO write {addr} accepted"
        );
    }

    fn deliver(&mut self, frames: Vec<Frame>) {
        if self.link_down {
            return;
        }
        let mut out = Vec::new();
        for f in frames {
            let id = f.raw_id() as u16;
            if let Some(p) = self.tpdos.iter().find(|p| p.cob_id == id) {
                let values = p.decode(None, f.data()).unwrap();
                let fb = feedback_from_values(values.iter().map(|(m, v)| (m.addr, v)));
                self.axis.on_feedback(fb, self.now, &mut out);
            }
        }
        self.handle(out);
    }

    fn handle(&mut self, outputs: Vec<Output>) {
        for o in outputs {
            match o {
                Output::Image(image) => {
                    if self.link_down {
                        continue;
                    }
                    for (cob, data) in encode_image(&image, &self.rpdos).unwrap() {
                        let replies = self.drive.on_frame(&frame(cob, &data), self.now);
                        self.deliver(replies);
                    }
                }
                Output::SdoWrites(writes) => {
                    let result = if self.link_down {
                        Err("SDO timeout".to_string())
                    } else {
                        for (addr, data) in writes {
                            self.sdo_write(addr, &data);
                        }
                        Ok(())
                    };
                    let mut out = Vec::new();
                    self.axis.on_sdo_done(result, self.now, &mut out);
                    self.handle(out);
                }
                Output::Event(e) => self.on_event(e),
            }
        }
    }

    fn on_event(&mut self, e: AxisEvent) {
        let AxisEvent::Done {
            op,
            command,
            outcome,
            detail,
        } = e
        else {
            return;
        };
        let Some(cmd) = self.started.get(&op).copied() else {
            self.fail(format!(
                "done for an op never started: {op} {command} {outcome:?}"
            ));
            return;
        };
        if self.ended.contains_key(&op) {
            self.fail(format!("op {op} ({command}) ended twice"));
        }
        self.ended.insert(op, (outcome, detail.clone()));
        // The healthy simulated drive never makes a command time out.
        if outcome == Outcome::Timeout {
            self.fail(format!("{command} timed out: {detail}"));
        }
        if outcome != Outcome::Completed {
            return;
        }
        let v = self.drive.velocity().abs();
        let p = self.drive.position();
        let window = 10.0;
        match cmd {
            AxisCommand::Move { .. } => {
                if v > 10.0 * window {
                    self.fail(format!(
                        "move completed while moving at {v} counts/s: {detail}"
                    ));
                }
                let target = self.target_of(op);
                if let Some(t) = target
                    && (p - t * SCALE).abs() > 2.0 * window
                {
                    self.fail(format!(
                        "move completed at {p} counts, target {t} mm: {detail}"
                    ));
                }
            }
            AxisCommand::Stop | AxisCommand::Home if v > 10.0 * window => {
                self.fail(format!(
                    "{command} completed while moving at {v} counts/s: {detail}"
                ));
            }
            AxisCommand::QuickStop if v > 10.0 * window => {
                self.fail(format!("quick stop completed while moving at {v} counts/s"));
            }
            AxisCommand::Enable if self.drive.state() != DriveState::OperationEnabled => {
                self.fail(format!("enable completed in {:?}", self.drive.state()));
            }
            _ => {}
        }
    }

    /// The absolute target of a move op, recorded when it started.
    fn target_of(&self, op: OpId) -> Option<f64> {
        self.targets.get(&op).copied()
    }

    fn fail(&mut self, what: String) {
        if self.failures.len() >= 5 {
            return;
        }
        self.failures
            .push(format!("at {} ms: {what}", self.now.as_millis()));
    }

    fn command(&mut self, cmd: AxisCommand) -> Result<OpId, CommandError> {
        let mut out = Vec::new();
        let r = self.axis.command(cmd, self.now, &mut out);
        if let Ok(op) = r {
            self.started.entry(op).or_insert(cmd);
            // The absolute target: the command's, or for a relative move
            // of a profile axis its latest target (a cyclic axis's
            // relative target is not kept apart from its demand).
            match cmd {
                AxisCommand::Move {
                    target,
                    relative: false,
                    ..
                } => {
                    self.targets.insert(op, target);
                }
                AxisCommand::Move { .. } if self.mode == PositionMode::Profile => {
                    self.targets
                        .insert(op, self.axis.snapshot().demand_position);
                }
                _ => {}
            }
        }
        self.handle(out);
        r
    }

    /// Runs the rig to `now + d`: the drive's model, a SYNC every 10 ms
    /// (the drive answers with its TPDOs), the axis's deadlines.
    fn run(&mut self, d: Duration) {
        let end = self.now + d;
        while self.now < end {
            let mut next = self.next_sync.min(end);
            if let Some(t) = self.axis.next_deadline()
                && t > self.now
            {
                next = next.min(t);
            }
            if next <= self.now {
                next = self.now + MS;
            }
            self.now = next;
            let frames = self.drive.on_tick(self.now);
            self.deliver(frames);
            if self.now >= self.next_sync {
                self.next_sync += SYNC;
                let frames = self.drive.on_frame(&frame(0x080, &[]), self.now);
                let mut out = Vec::new();
                if !self.link_down {
                    self.axis.on_sync(self.now, &mut out);
                }
                self.handle(out);
                self.deliver(frames);
                self.check();
            }
            let mut out = Vec::new();
            self.axis.on_tick(self.now, &mut out);
            self.handle(out);
        }
    }

    /// The invariants that hold at every SYNC.
    fn check(&mut self) {
        let p = self.drive.position();
        if std::env::var_os("CIA402_MODEL_TRACE").is_some() {
            let s = self.axis.snapshot();
            eprintln!(
                "{:>6} ms drive {:?} mode {:?} p {:.0} v {:.0} | axis {:?} demand {:.3} image {:?}",
                self.now.as_millis(),
                self.drive.state(),
                self.drive.mode(),
                p,
                self.drive.velocity(),
                s.activity,
                s.demand_position,
                self.axis.image()
            );
        }
        let lim = limit(self.mode) * SCALE;
        // The in-position window: what a drive settling after its own
        // ramp may still move.
        let tol = 10.0;
        // A quick stop and a fault reaction are the drive's own ramps, at
        // its quick stop deceleration: what they overrun is the drive's
        // configuration, not a trajectory of the gateway.
        let own_ramp = matches!(
            self.drive.state(),
            DriveState::QuickStopActive | DriveState::FaultReactionActive
        );
        if own_ramp {
            self.last_position = p;
        } else if p > lim + tol && p > self.last_position + tol {
            self.fail(format!(
                "beyond the max soft limit and moving out: {p} counts"
            ));
        }
        if p < -lim - tol && p < self.last_position - tol {
            self.fail(format!(
                "beyond the min soft limit and moving out: {p} counts"
            ));
        }
        self.last_position = p;
        // An axis without a command comes to rest within 3 s (any stop
        // ramp is shorter), unless its link is down.
        let idle = self.axis.current_op().is_none() && !self.link_down;
        match (idle, self.idle_since) {
            (true, None) => self.idle_since = Some(self.now),
            (false, _) => self.idle_since = None,
            _ => {}
        }
        if let Some(since) = self.idle_since
            && self.now - since > Duration::from_secs(3)
            && self.drive.velocity().abs() > 100.0
        {
            self.fail(format!(
                "no command for {} ms, yet the drive moves at {} counts/s (state {:?})",
                (self.now - since).as_millis(),
                self.drive.velocity(),
                self.drive.state()
            ));
            self.idle_since = None;
        }
    }

    /// Runs until `op` ended; false when it did not within `bound`.
    fn wait(&mut self, op: OpId, bound: Duration) -> bool {
        let end = self.now + bound;
        while self.now < end {
            if self.ended.contains_key(&op) {
                return true;
            }
            self.run(SYNC);
        }
        self.ended.contains_key(&op)
    }

    fn link_down(&mut self, reason: &str) {
        let mut out = Vec::new();
        self.axis.on_node_lost(reason, &mut out);
        self.handle(out);
        self.link_down = true;
    }

    fn link_up(&mut self, reboot: bool) {
        self.link_down = false;
        if reboot {
            let frames = self.drive.on_frame(&frame(0x000, &[0x81, NODE]), self.now);
            self.deliver(frames);
            self.boot();
            // The reboot moved the position reference.
            self.last_position = self.drive.position();
        }
        let mut out = Vec::new();
        self.axis.on_node_back(reboot, &mut out);
        self.handle(out);
    }
}

/// A generous bound for a waited command from where the axis stands.
fn bound(rig: &Rig, cmd: &AxisCommand) -> Duration {
    let c = rig.axis.config();
    let base = 3 * c.motion.state_timeout + c.motion.settle_timeout * 3;
    match *cmd {
        AxisCommand::Move { velocity, .. } => {
            let v = velocity.unwrap_or(c.motion.default_velocity);
            let dist = 2.0 * limit(rig.mode) + 20.0;
            base + Duration::from_secs_f64(
                dist / v + 4.0 * c.motion.max_velocity / c.motion.default_acceleration,
            )
        }
        AxisCommand::Home => c.motion.homing_timeout + base,
        _ => base + Duration::from_secs(2),
    }
}

/// Runs one sequence; the failures found (empty: all invariants held).
fn run_sequence(mode: PositionMode, actions: &[Action], log: &mut String) -> Vec<String> {
    let mut rig = Rig::new(mode);
    for (i, &action) in actions.iter().enumerate() {
        let _ = writeln!(log, "  {i}: {action:?}");
        perform(&mut rig, action);
        if !rig.failures.is_empty() {
            return rig.failures;
        }
    }
    recover(&mut rig, log);
    if std::env::var_os("CIA402_MODEL_TIMING").is_some() {
        eprintln!(
            "{} ms virtual in {:?}",
            rig.now.as_millis(),
            rig.started_at.elapsed()
        );
    }
    let started: HashSet<_> = rig.started.keys().copied().collect();
    let running = rig.axis.current_op();
    for op in &started {
        if !rig.ended.contains_key(op) && Some(*op) != running {
            rig.fail(format!("op {op} ({:?}) never ended", rig.started[op]));
        }
    }
    rig.failures
}

fn issue(rig: &mut Rig, cmd: AxisCommand, wait: bool) {
    let before_state = rig.axis.snapshot().state;
    match rig.command(cmd) {
        Ok(op) => {
            if wait {
                let b = bound(rig, &cmd);
                if !rig.wait(op, b) {
                    rig.fail(format!(
                        "waited {cmd:?} did not end within {} ms (activity {:?})",
                        b.as_millis(),
                        rig.axis.activity()
                    ));
                }
            }
        }
        Err(CommandError::NotEnabled(m))
            if m.contains("not enabled")
                && before_state == Some(DriveState::OperationEnabled)
                && !rig.link_down =>
        {
            rig.fail(format!(
                "{cmd:?} refused as not enabled in operation enabled: {m}"
            ));
        }
        Err(_) => {}
    }
}

fn perform(rig: &mut Rig, action: Action) {
    match action {
        Action::Enable { wait } => issue(rig, AxisCommand::Enable, wait),
        Action::Disable { wait } => issue(rig, AxisCommand::Disable, wait),
        Action::ResetFault { wait } => issue(rig, AxisCommand::ResetFault, wait),
        Action::Home { wait } => issue(rig, AxisCommand::Home, wait),
        Action::Move {
            target,
            relative,
            velocity,
            wait,
        } => issue(
            rig,
            AxisCommand::Move {
                target,
                relative,
                velocity,
                acceleration: None,
            },
            wait,
        ),
        Action::Jog { velocity } => issue(
            rig,
            AxisCommand::Jog {
                velocity,
                acceleration: None,
            },
            false,
        ),
        Action::JogHeld { velocity, ms } => {
            let jog = AxisCommand::Jog {
                velocity,
                acceleration: None,
            };
            let mut first = None;
            let end = rig.now + Duration::from_millis(ms);
            while rig.now < end {
                match rig.command(jog) {
                    Ok(op) => {
                        // A held jog is one jog, never stopped by its
                        // dead-man while repeated.
                        if let Some(f) = first
                            && f != op
                            && !rig
                                .ended
                                .get(&f)
                                .is_some_and(|(o, _)| *o != Outcome::Stopped)
                        {
                            rig.fail(format!("a held jog became a new one: {f} then {op}"));
                        }
                        if let Some((Outcome::Stopped, d)) = rig.ended.get(&op)
                            && d.contains("dead-man")
                        {
                            rig.fail(format!("a held jog was stopped by its dead-man: {d}"));
                        }
                        first = Some(op);
                    }
                    Err(_) => break,
                }
                rig.run(Duration::from_millis(150));
            }
        }
        Action::Stop { wait } => issue(rig, AxisCommand::Stop, wait),
        Action::QuickStop { wait } => issue(rig, AxisCommand::QuickStop, wait),
        Action::LeaseExpiry => {
            if matches!(
                rig.axis.activity(),
                Activity::Moving | Activity::Jogging | Activity::Homing
            ) {
                let cmd = match rig.mode {
                    PositionMode::Cyclic => AxisCommand::Stop,
                    PositionMode::Profile => AxisCommand::QuickStop,
                };
                issue(rig, cmd, false);
            }
        }
        Action::NodeLoss { ms, reboot } => {
            rig.link_down("no heartbeat for 300 ms");
            rig.run(Duration::from_millis(ms));
            rig.link_up(reboot);
        }
        Action::DriveFault => {
            let frames = rig.drive.inject_fault(0x2310);
            if !rig.link_down {
                rig.deliver(frames);
                let mut out = Vec::new();
                rig.axis
                    .on_emcy(0x2310, "continuous over-current", &mut out);
                rig.handle(out);
            }
        }
        Action::Pause { ms } => rig.run(Duration::from_millis(ms)),
    }
    rig.run(SYNC);
}

/// Never wedged: stop, reset fault, enable, then a reachable move
/// completes.
fn recover(rig: &mut Rig, log: &mut String) {
    let _ = writeln!(log, "  recovery: stop, reset fault, enable, move");
    if rig.link_down {
        rig.link_up(false);
    }
    rig.run(Duration::from_millis(50));
    for cmd in [
        AxisCommand::Stop,
        AxisCommand::ResetFault,
        AxisCommand::Enable,
    ] {
        match rig.command(cmd) {
            Ok(op) => {
                let b = bound(rig, &cmd);
                if !rig.wait(op, b) {
                    rig.fail(format!("recovery: {cmd:?} did not end within {b:?}"));
                    return;
                }
            }
            Err(e) => {
                if cmd != AxisCommand::Stop {
                    rig.fail(format!("recovery: {cmd:?} refused: {e}"));
                    return;
                }
            }
        }
    }
    let here = rig.axis.snapshot().position;
    let target = if here > 0.0 { here - 5.0 } else { here + 5.0 };
    let target = target.clamp(-limit(rig.mode) + 1.0, limit(rig.mode) - 1.0);
    let cmd = AxisCommand::Move {
        target,
        relative: false,
        velocity: None,
        acceleration: None,
    };
    match rig.command(cmd) {
        Ok(op) => {
            let b = bound(rig, &cmd);
            if !rig.wait(op, b) {
                rig.fail(format!("recovery: the move did not end within {b:?}"));
            } else if rig.ended[&op].0 != Outcome::Completed {
                let (o, d) = rig.ended[&op].clone();
                rig.fail(format!("recovery: the move ended {o:?}: {d}"));
            }
        }
        Err(e) => rig.fail(format!("recovery: the move was refused: {e}")),
    }
}

fn mode_name(mode: PositionMode) -> &'static str {
    match mode {
        PositionMode::Cyclic => "cyclic",
        PositionMode::Profile => "profile",
    }
}

/// Runs `count` sequences from `first_seed` on (or the one seed of
/// `CIA402_MODEL_SEED` when set, for the mode of `CIA402_MODEL_MODE`).
fn campaign(mode: PositionMode, first_seed: u64, count: u64) {
    let replay = std::env::var("CIA402_MODEL_SEED")
        .ok()
        .and_then(|s| s.parse::<u64>().ok());
    let replay_mode = std::env::var("CIA402_MODEL_MODE").ok();
    let seeds: Vec<u64> = match replay {
        Some(seed) => {
            if replay_mode.is_some_and(|m| m != mode_name(mode)) {
                return;
            }
            vec![seed]
        }
        None => {
            let count = std::env::var("CIA402_MODEL_COUNT")
                .ok()
                .and_then(|s| s.parse::<u64>().ok())
                .unwrap_or(count);
            (first_seed..first_seed + count).collect()
        }
    };
    let mut report = String::new();
    let mut failed = 0;
    for seed in seeds {
        let actions = generate(&mut Rng(seed), mode);
        let mut log = String::new();
        let failures = run_sequence(mode, &actions, &mut log);
        if !failures.is_empty() {
            failed += 1;
            if failed <= 3 {
                let _ = writeln!(
                    report,
                    "seed {seed} ({}) failed:\n{}\nsequence:\n{log}replay: CIA402_MODEL_SEED={seed} CIA402_MODEL_MODE={} cargo test -p cangate-axis --test cia402_model\n",
                    mode_name(mode),
                    failures.join("\n"),
                    mode_name(mode)
                );
            }
        }
    }
    assert!(failed == 0, "{failed} sequences failed\n{report}");
}

#[test]
fn profile_position_axis_holds_its_invariants_under_random_commands() {
    campaign(PositionMode::Profile, 1, 1000);
}

#[test]
fn cyclic_axis_holds_its_invariants_under_random_commands() {
    campaign(PositionMode::Cyclic, 1_000_001, 1000);
}
