//! Model-based random tests of the CiA 402 modes: generated sequences of
//! mode changes (CSP, CSV, CST, profile torque), moves, jogs, torques,
//! stops and pauses against the simulated drive (`cangate-sim`, its torque
//! model for the torque modes), in virtual time.
//!
//! Invariants, checked at every SYNC and at every command's end:
//!
//! - never a jump: in CSP each set-point differs from the previous one by
//!   at most the maximum velocity over a SYNC period, in CSV each velocity
//!   set-point from the previous one by at most the maximum acceleration
//!   over a period, and the first set-point of a mode starts where the
//!   drive stands (CSP) or at rest (CSV);
//! - the drive never runs faster than the maximum velocity (under torque:
//!   plus what its torque adds in one feedback period before the guard's
//!   halt), nor beyond the soft limits;
//! - stops are never refused and end at rest within their bound; a mode
//!   change is accepted only at rest, and refused while the axis moves;
//! - counters add up: every started command ends exactly once.
//!
//! A failure prints the seed and the actions; replay one with
//! `CIA402_MODES_SEED=<seed> cargo test -p cangate-axis --test
//! cia402_modes_model`.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::time::Duration;

use cangate_axis::cia402::{Cia402Axis, Cia402Config, Output};
use cangate_axis::process_data::{
    FeedbackTrigger, encode_image, feedback_from_values, standard_pdos, torque_rpdo,
};
use cangate_axis::{AxisCommand, AxisEvent, CommandError, DriveMode, OpId, Outcome};
use cangate_can::{CanId, Frame};
use cangate_canopen::cia402::ModeOfOperation;
use cangate_canopen::{NodeId, ObjectAddress};
use cangate_sim::Device;
use cangate_sim::drive::{SimDrive, SimDriveOptions};

const MS: Duration = Duration::from_millis(1);
const NODE: u8 = 1;
const SYNC: Duration = Duration::from_millis(10);
/// Counts per mm.
const SCALE: f64 = 1000.0;
const VMAX: f64 = 50.0;
const AMAX: f64 = 500.0;
const LIMIT: f64 = 300.0;
const TMAX: f64 = 200.0;

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
}

#[derive(Debug, Clone, Copy)]
enum Action {
    Mode(DriveMode),
    Move(f64),
    /// Jog at this velocity, repeated for this long.
    Jog(f64, Duration),
    Torque(f64),
    Stop,
    Pause(Duration),
}

const MODES: [DriveMode; 4] = [
    DriveMode::CyclicPosition,
    DriveMode::CyclicVelocity,
    DriveMode::CyclicTorque,
    DriveMode::ProfileTorque,
];

fn generate(rng: &mut Rng) -> Vec<Action> {
    (0..16)
        .map(|_| match rng.below(10) {
            0 | 1 => Action::Mode(MODES[rng.below(4) as usize]),
            2 => Action::Move(rng.range(-LIMIT, LIMIT)),
            3 | 4 => Action::Jog(
                rng.range(-VMAX, VMAX),
                Duration::from_millis(50 + rng.below(600)),
            ),
            5 | 6 => Action::Torque(rng.range(-TMAX, TMAX)),
            7 => Action::Stop,
            _ => Action::Pause(Duration::from_millis(rng.below(400))),
        })
        .collect()
}

fn frame(id: u16, data: &[u8]) -> Frame {
    Frame::new(CanId::Standard(id), data).unwrap()
}

struct Rig {
    axis: Cia402Axis,
    drive: SimDrive,
    now: Duration,
    next_sync: Duration,
    rpdos: Vec<cangate_canopen::pdo::PdoConfig>,
    tpdos: Vec<cangate_canopen::pdo::PdoConfig>,
    started: HashMap<OpId, AxisCommand>,
    ended: HashMap<OpId, Outcome>,
    /// The previous RPDO2 and the drive's mode when it went out.
    last_rpdo2: Option<(Option<ModeOfOperation>, i32, i32)>,
    failures: Vec<String>,
}

impl Rig {
    fn new() -> Rig {
        let node = NodeId::new(u32::from(NODE)).unwrap();
        let options = SimDriveOptions {
            step: 2 * MS,
            ..SimDriveOptions::default()
        };
        let mut drive = SimDrive::bundled(node, options);
        drive.start(Duration::ZERO);
        let (mut rpdos, tpdos) = standard_pdos(node, FeedbackTrigger::Sync);
        rpdos.push(torque_rpdo(node));
        let mut cfg = Cia402Config::example_in(SCALE, DriveMode::CyclicPosition);
        cfg.motion.min_position = Some(-LIMIT);
        cfg.motion.max_position = Some(LIMIT);
        cfg.motion.max_velocity = VMAX;
        cfg.motion.max_acceleration = AMAX;
        cfg.motion.default_velocity = VMAX / 2.0;
        cfg.motion.default_acceleration = AMAX / 2.0;
        cfg.motion.stop_deceleration = AMAX;
        cfg.motion.quick_stop_deceleration = AMAX;
        cfg.torque.max_torque = TMAX;
        let mut rig = Rig {
            axis: Cia402Axis::new(cfg),
            drive,
            now: Duration::ZERO,
            next_sync: SYNC,
            rpdos,
            tpdos,
            started: HashMap::new(),
            ended: HashMap::new(),
            last_rpdo2: None,
            failures: Vec::new(),
        };
        let mut writes = Vec::new();
        for p in rig.rpdos.iter().chain(&rig.tpdos) {
            writes.extend(p.sdo_writes().unwrap());
        }
        writes.extend(rig.axis.boot_writes());
        for (addr, data) in writes {
            rig.sdo_write(addr, &data);
        }
        let start = rig.drive.on_frame(&frame(0x000, &[0x01, NODE]), rig.now);
        rig.deliver(start);
        rig.run(30 * MS);
        rig
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
                    for (cob, data) in encode_image(&image, &self.rpdos).unwrap() {
                        let replies = self.drive.on_frame(&frame(cob, &data), self.now);
                        if cob == 0x300 + u16::from(NODE) {
                            self.check_set_point(&data);
                        }
                        self.deliver(replies);
                    }
                }
                Output::SdoWrites(writes) => {
                    for (addr, data) in writes {
                        self.sdo_write(addr, &data);
                    }
                    let mut out = Vec::new();
                    self.axis.on_sdo_done(Ok(()), self.now, &mut out);
                    self.handle(out);
                }
                Output::Event(AxisEvent::Done { op, outcome, .. }) => {
                    if !self.started.contains_key(&op) {
                        self.fail(format!("done for an op never started: {op}"));
                    }
                    if self.ended.insert(op, outcome).is_some() {
                        self.fail(format!("op {op} ended twice"));
                    }
                    if outcome == Outcome::Timeout {
                        self.fail(format!("op {op} timed out"));
                    }
                }
                Output::Event(_) => {}
            }
        }
    }

    /// Never a jump: each RPDO2 against the previous one, in the object
    /// the drive's mode uses.
    fn check_set_point(&mut self, data: &[u8]) {
        let position = i32::from_le_bytes(data[..4].try_into().unwrap());
        let velocity = i32::from_le_bytes(data[4..8].try_into().unwrap());
        let mode = self.drive.mode();
        let step_p = VMAX * SCALE * SYNC.as_secs_f64() * 1.01 + 2.0;
        let step_v = AMAX * SCALE * SYNC.as_secs_f64() * 1.01 + 2.0;
        match (self.last_rpdo2, mode) {
            (Some((was, p, _)), Some(ModeOfOperation::CyclicSynchronousPosition))
                if was == mode && f64::from((position - p).abs()) > step_p =>
            {
                self.fail(format!("a position step {p} -> {position} counts"));
            }
            (Some((was, _, v)), Some(ModeOfOperation::CyclicSynchronousVelocity))
                if was == mode && f64::from((velocity - v).abs()) > step_v =>
            {
                self.fail(format!("a velocity step {v} -> {velocity} counts/s"));
            }
            (Some((was, _, _)), Some(ModeOfOperation::CyclicSynchronousVelocity))
                if was != mode && velocity.abs() as f64 > step_v =>
            {
                self.fail(format!("CSV started at {velocity} counts/s"));
            }
            _ => {}
        }
        self.last_rpdo2 = Some((mode, position, velocity));
    }

    fn fail(&mut self, what: String) {
        if self.failures.len() < 5 {
            self.failures
                .push(format!("at {} ms: {what}", self.now.as_millis()));
        }
    }

    fn command(&mut self, cmd: AxisCommand) -> Result<OpId, CommandError> {
        let mut out = Vec::new();
        let r = self.axis.command(cmd, self.now, &mut out);
        if let Ok(op) = r {
            self.started.entry(op).or_insert(cmd);
        }
        self.handle(out);
        r
    }

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
                self.axis.on_sync(self.now, &mut out);
                self.handle(out);
                self.deliver(frames);
                self.check();
            }
            let mut out = Vec::new();
            self.axis.on_tick(self.now, &mut out);
            self.handle(out);
        }
    }

    /// At every SYNC: the velocity bound and the soft limits.
    fn check(&mut self) {
        let v = self.drive.velocity().abs() / SCALE;
        // Under torque the guard halts at the first feedback beyond VMAX:
        // the torque (at most TMAX per mille, 1000 counts/s² each) adds
        // at most a SYNC period of acceleration before the halt.
        let bound = VMAX + TMAX * SYNC.as_secs_f64() + 0.5;
        if v > bound {
            self.fail(format!("{v:.3} mm/s, beyond {bound:.3}"));
        }
        let p = self.drive.position() / SCALE;
        if p.abs() > LIMIT + 0.01 {
            self.fail(format!("at {p:.3} mm, beyond the soft limits"));
        }
    }

    fn at_rest(&self) -> bool {
        self.drive.velocity().abs() / SCALE < 0.1
    }

    /// Waits for `op` to end, bounded.
    fn wait(&mut self, op: OpId, bound: Duration) -> Option<Outcome> {
        let end = self.now + bound;
        while self.now < end {
            if let Some(o) = self.ended.get(&op) {
                return Some(*o);
            }
            self.run(SYNC);
        }
        self.ended.get(&op).copied()
    }
}

fn perform(rig: &mut Rig, action: Action) {
    match action {
        Action::Mode(mode) => {
            let resting = rig.at_rest() && rig.axis.activity() == cangate_axis::Activity::Idle;
            match rig.command(AxisCommand::SetMode { mode }) {
                Ok(op) => {
                    if !rig.at_rest() {
                        rig.fail(format!("a mode change to {mode} accepted while moving"));
                    }
                    match rig.wait(op, Duration::from_secs(2)) {
                        Some(Outcome::Completed) => {}
                        other => rig.fail(format!("mode change to {mode}: {other:?}")),
                    }
                }
                Err(CommandError::Busy(_)) if !resting => {}
                Err(e) => rig.fail(format!("mode change to {mode} refused at rest: {e}")),
            }
        }
        Action::Move(target) => {
            let _ = rig.command(AxisCommand::Move {
                target,
                relative: false,
                velocity: None,
                acceleration: None,
            });
            rig.run(Duration::from_millis(300));
        }
        Action::Jog(velocity, hold) => {
            let jog = AxisCommand::Jog {
                velocity,
                acceleration: None,
            };
            let end = rig.now + hold;
            while rig.now < end {
                let _ = rig.command(jog);
                rig.run(100 * MS);
            }
        }
        Action::Torque(per_mille) => {
            let _ = rig.command(AxisCommand::SetTorque { per_mille });
            rig.run(Duration::from_millis(400));
        }
        Action::Stop => {
            let op = match rig.command(AxisCommand::Stop) {
                Ok(op) => op,
                Err(e) => {
                    rig.fail(format!("a stop was refused: {e}"));
                    return;
                }
            };
            // From at most VMAX at AMAX, plus the settle time.
            let bound = Duration::from_secs_f64(VMAX / AMAX) + Duration::from_secs(3);
            match rig.wait(op, bound) {
                Some(Outcome::Completed) if rig.at_rest() => {}
                other => rig.fail(format!(
                    "stop: {other:?} at {:.3} mm/s",
                    rig.drive.velocity() / SCALE
                )),
            }
        }
        Action::Pause(d) => rig.run(d),
    }
}

fn run_sequence(actions: &[Action], log: &mut String) -> Vec<String> {
    let mut rig = Rig::new();
    let enable = rig.command(AxisCommand::Enable).unwrap();
    if rig.wait(enable, Duration::from_secs(2)) != Some(Outcome::Completed) {
        return vec!["enable failed".into()];
    }
    for &a in actions {
        let _ = writeln!(
            log,
            "  {:>6} ms {:?} ({}, {:.3} mm/s): {a:?}",
            rig.now.as_millis(),
            rig.axis.mode(),
            rig.drive.mode().map_or("-".to_string(), |m| m.to_string()),
            rig.drive.velocity() / SCALE
        );
        perform(&mut rig, a);
        if !rig.failures.is_empty() {
            break;
        }
    }
    // The end: a stop brings it to rest in any mode.
    if rig.failures.is_empty() {
        perform(&mut rig, Action::Stop);
        rig.run(Duration::from_secs(1));
        let open: Vec<_> = rig
            .started
            .keys()
            .filter(|op| !rig.ended.contains_key(op))
            .copied()
            .collect();
        if !open.is_empty() {
            rig.fail(format!("commands never ended: {open:?}"));
        }
    }
    rig.failures
}

#[test]
fn mode_changes_and_stops_hold_the_limits_under_random_commands() {
    let seeds: Vec<u64> = match std::env::var("CIA402_MODES_SEED") {
        Ok(s) => vec![s.parse().expect("a seed")],
        Err(_) => (0..40).collect(),
    };
    for seed in seeds {
        let actions = generate(&mut Rng(seed));
        let mut log = String::new();
        let failures = run_sequence(&actions, &mut log);
        assert!(
            failures.is_empty(),
            "seed {seed} failed:\n{}\nsequence:\n{log}replay: CIA402_MODES_SEED={seed} cargo test -p cangate-axis --test cia402_modes_model\n",
            failures.join("\n")
        );
    }
}
