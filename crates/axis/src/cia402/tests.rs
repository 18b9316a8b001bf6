//! The axis controller in closed loop with the simulated CiA 402 drive
//! (`cangate-sim`), frame by frame in virtual time: 1 ms model steps, SYNC
//! every 10 ms, TPDOs decoded per the standard layout.

use super::*;
use crate::process_data::{FeedbackTrigger, encode_image, feedback_from_values, standard_pdos};
use cangate_can::{CanId, Frame};
use cangate_canopen::NodeId;
use cangate_canopen::pdo::PdoConfig;
use cangate_canopen::value::Value;
use cangate_sim::Device;
use cangate_sim::drive::{SimDrive, SimDriveInputs, SimDriveOptions};

const MS: Duration = Duration::from_millis(1);
const NODE: u8 = 1;

struct Rig {
    axis: Cia402Axis,
    drive: SimDrive,
    now: Duration,
    sync_period: Duration,
    rpdos: Vec<PdoConfig>,
    tpdos: Vec<PdoConfig>,
    /// Every RPDO sent: (time, COB-ID, payload).
    sent: Vec<(Duration, u16, Vec<u8>)>,
    events: Vec<AxisEvent>,
    /// Demand sent at each SYNC (cyclic axes).
    setpoints: Vec<(Duration, i32)>,
    /// Split SYNC handling, as the gateway runs it: the plan the axis
    /// published (as published, and as sampled since), sampled "on the SYNC
    /// thread", each sample handed back; `None` runs [`Cia402Axis::on_sync`].
    split: Option<(Option<CyclicPlan>, Option<CyclicPlan>)>,
    /// Plans published in split mode.
    published: usize,
}

fn frame(id: u16, data: &[u8]) -> Frame {
    Frame::new(CanId::Standard(id), data).unwrap()
}

impl Rig {
    fn new(mode: PositionMode) -> Rig {
        Rig::with_config(Cia402Config::example(1000.0, mode), 35)
    }

    /// A rig whose axis has `cfg` (1000 counts per mm) and whose drive
    /// homes with `homing_method`.
    fn with_config(cfg: Cia402Config, homing_method: u8) -> Rig {
        Rig::build(cfg, homing_method, None)
    }

    /// A rig whose drive has switches and a touch probe input at `inputs`
    /// and whose TPDOs carry the signals ([`with_signal_tpdos`]); EMCYs go
    /// to the axis.
    fn with_inputs(cfg: Cia402Config, inputs: SimDriveInputs) -> Rig {
        Rig::build(cfg, 35, Some(inputs))
    }

    fn build(cfg: Cia402Config, homing_method: u8, inputs: Option<SimDriveInputs>) -> Rig {
        let node = NodeId::new(u32::from(NODE)).unwrap();
        let options = SimDriveOptions {
            inputs: inputs.unwrap_or_default(),
            ..SimDriveOptions::default()
        };
        let drive_axis = cfg.drive_axis;
        // An axis other than the first: a drive with that many axes, the
        // layout moved to the axis (PDOs 4n + 1.., COB-IDs from 0x680).
        let mut drive = if drive_axis == 0 {
            SimDrive::bundled(node, options)
        } else {
            let text = cangate_canopen::eds::sim_drive_eds_with_axes(drive_axis + 1);
            SimDrive::from_eds_text(&text, node, options).unwrap()
        };
        drive.start(Duration::ZERO);
        let (mut rpdos, mut tpdos) = standard_pdos(node, FeedbackTrigger::Sync);
        if inputs.is_some() {
            crate::process_data::with_signal_tpdos(
                &mut tpdos,
                node,
                FeedbackTrigger::Sync,
                |_| true,
                |_| true,
            );
        }
        crate::process_data::relocate_to_axis(&mut rpdos, drive_axis, 0);
        crate::process_data::relocate_to_axis(&mut tpdos, drive_axis, 0);
        let axis = Cia402Axis::new(cfg);
        let mut rig = Rig {
            axis,
            drive,
            now: Duration::ZERO,
            sync_period: 10 * MS,
            rpdos,
            tpdos,
            sent: Vec::new(),
            events: Vec::new(),
            setpoints: Vec::new(),
            split: None,
            published: 0,
        };
        let mut writes = Vec::new();
        for p in rig.rpdos.iter().chain(&rig.tpdos) {
            writes.extend(p.sdo_writes().unwrap());
        }
        writes.extend(rig.axis.boot_writes());
        writes.push((
            cangate_canopen::cia402::on_axis(obj::HOMING_METHOD, drive_axis),
            vec![homing_method],
        ));
        for (addr, data) in writes {
            rig.sdo_write(addr, &data);
        }
        let start = rig.drive.on_frame(&frame(0x000, &[0x01, NODE]), rig.now);
        rig.deliver(start);
        rig.run(30 * MS);
        assert!(rig.axis.snapshot().state.is_some(), "process data flows");
        rig
    }

    fn sdo_write(&mut self, addr: ObjectAddress, data: &[u8]) {
        assert!((1..=4).contains(&data.len()));
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
        let ok = reply
            .iter()
            .any(|r| r.raw_id() == 0x580 + u32::from(NODE) && r.data()[0] == 0x60);
        assert!(ok, "SDO write {addr} accepted: {reply:?}");
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
            if id == 0x80 + u16::from(NODE) && f.data().len() == 8 {
                let code = u16::from_le_bytes([f.data()[0], f.data()[1]]);
                self.axis.on_emcy(code, "EMCY", &mut out);
            }
        }
        self.handle(out);
    }

    fn handle(&mut self, outputs: Vec<Output>) {
        for o in outputs {
            match o {
                Output::Image(image) => {
                    for (cob, data) in encode_image(&image, &self.rpdos).unwrap() {
                        self.sent.push((self.now, cob, data.clone()));
                        let replies = self.drive.on_frame(&frame(cob, &data), self.now);
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
                Output::Event(e) => self.events.push(e),
            }
        }
    }

    fn command(&mut self, cmd: AxisCommand) -> Result<OpId, CommandError> {
        let mut out = Vec::new();
        let r = self.axis.command(cmd, self.now, &mut out);
        self.handle(out);
        r
    }

    fn step(&mut self) {
        self.now += MS;
        let frames = self.drive.on_tick(self.now);
        self.deliver(frames);
        if self
            .now
            .as_millis()
            .is_multiple_of(self.sync_period.as_millis())
        {
            let frames = self.drive.on_frame(&frame(0x080, &[]), self.now);
            if self.split.is_some() {
                self.split_sync();
                self.deliver(frames);
                let mut out = Vec::new();
                self.axis.on_tick(self.now, &mut out);
                self.handle(out);
                return;
            }
            let mut out = Vec::new();
            self.axis.on_sync(self.now, &mut out);
            if self.axis.config().position_mode() == PositionMode::Cyclic
                && out.iter().any(|o| matches!(o, Output::Image(_)))
            {
                self.setpoints
                    .push((self.now, self.axis.image().target_position));
            }
            self.handle(out);
            self.deliver(frames);
        }
        let mut out = Vec::new();
        self.axis.on_tick(self.now, &mut out);
        self.handle(out);
    }

    /// One SYNC the way the gateway splits it: the plan is republished when
    /// the axis's differs from the one published (the task's side), sampled
    /// (the SYNC thread's side; the target-position RPDO leaves with the
    /// SYNC), and the sample handed back to the axis.
    fn split_sync(&mut self) {
        let (published, sampled) = self.split.as_mut().expect("split");
        let wanted = self.axis.cyclic_plan();
        if wanted != *published {
            published.clone_from(&wanted);
            *sampled = wanted;
            self.published += 1;
        }
        let Some(plan) = sampled.as_mut() else {
            return;
        };
        let sample = plan.sample(self.now);
        self.setpoints.push((self.now, sample.counts));
        let mut image = self.axis.image();
        image.target_position = sample.counts;
        let target = self
            .rpdos
            .iter()
            .find(|p| p.mapping.iter().any(|m| m.addr == obj::TARGET_POSITION))
            .cloned()
            .expect("target RPDO");
        for (cob, data) in encode_image(&image, &[target]).unwrap() {
            self.sent.push((self.now, cob, data.clone()));
            let replies = self.drive.on_frame(&frame(cob, &data), self.now);
            self.deliver(replies);
        }
        let mut out = Vec::new();
        self.axis.on_cyclic_sample(&sample, self.now, &mut out);
        self.handle(out);
    }

    fn run(&mut self, d: Duration) {
        let end = self.now + d;
        while self.now < end {
            self.step();
        }
    }

    /// Runs until command `op` is done (bounded), returning its outcome.
    fn run_until_done(&mut self, op: OpId, limit: Duration) -> (Outcome, String) {
        let end = self.now + limit;
        while self.now < end {
            if let Some(r) = self.done(op) {
                return r;
            }
            self.step();
        }
        panic!(
            "op {op} not done within {limit:?}; events {:?}",
            self.events
        );
    }

    fn done(&self, op: OpId) -> Option<(Outcome, String)> {
        self.events.iter().find_map(|e| match e {
            AxisEvent::Done {
                op: o,
                outcome,
                detail,
                ..
            } if *o == op => Some((*outcome, detail.clone())),
            _ => None,
        })
    }

    fn accepted(&self, op: OpId) -> bool {
        self.events
            .iter()
            .any(|e| matches!(e, AxisEvent::Accepted { op: o } if *o == op))
    }

    fn enable(&mut self) {
        let op = self.command(AxisCommand::Enable).unwrap();
        let (outcome, detail) = self.run_until_done(op, Duration::from_secs(2));
        assert_eq!(outcome, Outcome::Completed, "{detail}");
        let drive_axis = self.axis.config().drive_axis;
        assert_eq!(
            self.drive.axis_state(drive_axis),
            DriveState::OperationEnabled
        );
    }

    /// A move at 100 mm/s and 1000 mm/s², or the axis's maxima when lower.
    fn mv(&mut self, target: f64) -> OpId {
        let cfg = self.axis.config();
        let (velocity, acceleration) = (
            cfg.motion.max_velocity.min(100.0),
            cfg.motion.max_acceleration.min(1000.0),
        );
        self.command(AxisCommand::Move {
            target,
            relative: false,
            velocity: Some(velocity),
            acceleration: Some(acceleration),
        })
        .unwrap()
    }
}

#[test]
fn commands_before_process_data_are_refused_clearly() {
    let mut axis = Cia402Axis::new(Cia402Config::example(1000.0, PositionMode::Profile));
    let err = axis
        .command(AxisCommand::Enable, Duration::ZERO, &mut Vec::new())
        .unwrap_err();
    assert!(matches!(err, CommandError::DriveUnavailable(m) if m.contains("no process data")));
}

#[test]
fn enable_walks_the_state_machine_and_moves_need_it() {
    let mut rig = Rig::new(PositionMode::Profile);
    let refused = rig
        .command(AxisCommand::Move {
            target: 1.0,
            relative: false,
            velocity: None,
            acceleration: None,
        })
        .unwrap_err();
    assert!(
        matches!(&refused, CommandError::NotEnabled(m)
            if m.contains("not enabled") && m.contains("switch on disabled")),
        "{refused:?}"
    );
    rig.enable();
    // shutdown 0x06, switch on 0x07, enable operation 0x0F on RPDO1.
    let cws: Vec<u16> = rig
        .sent
        .iter()
        .filter(|(_, cob, _)| *cob == 0x201)
        .map(|(_, _, d)| u16::from_le_bytes([d[0], d[1]]))
        .collect();
    assert!(cws.ends_with(&[0x0006, 0x0007, 0x000F]), "{cws:04X?}");
}

#[test]
fn profile_move_handshake_frames_are_exact() {
    let mut rig = Rig::new(PositionMode::Profile);
    rig.enable();
    rig.sent.clear();
    let op = rig.mv(12.5);
    let (outcome, detail) = rig.run_until_done(op, Duration::from_secs(3));
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    assert!(rig.accepted(op));
    assert_eq!(rig.drive.position(), 12_500.0);
    // 1) target 12 500 counts (RPDO2 first), then controlword 0x003F:
    //    enable operation + new set-point (bit 4) + change set
    //    immediately (bit 5), mode 1;
    // 2) after the set-point acknowledge: 0x002F (bit 4 cleared).
    let frames: Vec<(u16, Vec<u8>)> = rig.sent.iter().map(|(_, c, d)| (*c, d.clone())).collect();
    assert_eq!(
        frames,
        vec![
            (0x301, vec![0xD4, 0x30, 0, 0, 0, 0, 0, 0]),
            (0x201, vec![0x3F, 0x00, 0x01]),
            (0x301, vec![0xD4, 0x30, 0, 0, 0, 0, 0, 0]),
            (0x201, vec![0x2F, 0x00, 0x01]),
        ]
    );
    assert!(detail.contains("12.500"), "{detail}");
    // The profile parameters went by SDO first (100 mm/s = 100 000
    // counts/s).
    assert_eq!(
        rig.drive
            .node()
            .get(obj::PROFILE_VELOCITY)
            .and_then(Value::as_u32),
        Some(100_000)
    );
}

/// The second axis of a two-axis drive (objects at index + 0x800): the
/// profile move's RPDOs are its own (RPDO6 and RPDO5 on COB-IDs 0x681 and
/// 0x680, mapping 0x687A and 0x6840), its profile parameters go to
/// 0x6881..0x6884 by SDO, and the drive's first axis is not touched.
#[test]
fn a_second_drive_axis_moves_on_its_own_objects_and_pdos() {
    let mut cfg = Cia402Config::example(1000.0, PositionMode::Profile);
    cfg.drive_axis = 1;
    cfg.motion.min_position = Some(-100.0);
    cfg.motion.max_position = Some(100.0);
    let mut rig = Rig::with_config(cfg, 35);
    assert_eq!(
        (
            rig.rpdos[0].num,
            rig.rpdos[0].cob_id,
            rig.rpdos[0].mapping[0].addr
        ),
        (5, 0x680, ObjectAddress::new(0x6840, 0))
    );
    rig.enable();
    rig.sent.clear();
    let op = rig.mv(12.5);
    let (outcome, detail) = rig.run_until_done(op, Duration::from_secs(3));
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    assert_eq!(rig.drive.axis_position(1), 12_500.0);
    let frames: Vec<(u16, Vec<u8>)> = rig.sent.iter().map(|(_, c, d)| (*c, d.clone())).collect();
    assert_eq!(
        frames,
        vec![
            (0x681, vec![0xD4, 0x30, 0, 0, 0, 0, 0, 0]),
            (0x680, vec![0x3F, 0x00, 0x01]),
            (0x681, vec![0xD4, 0x30, 0, 0, 0, 0, 0, 0]),
            (0x680, vec![0x2F, 0x00, 0x01]),
        ]
    );
    let value = |index| {
        rig.drive
            .node()
            .get(ObjectAddress::new(index, 0))
            .and_then(Value::as_u32)
    };
    assert_eq!(value(0x6881), Some(100_000), "profile velocity of axis 1");
    assert_ne!(value(0x6081), Some(100_000), "axis 0's is not written");
    // The soft limits went to 0x687D at boot.
    let boot = rig.axis.boot_writes();
    assert_eq!(
        boot[..2],
        [
            (
                ObjectAddress::new(0x687D, 1),
                (-100_000i32).to_le_bytes().to_vec()
            ),
            (
                ObjectAddress::new(0x687D, 2),
                100_000i32.to_le_bytes().to_vec()
            ),
        ]
    );
    assert!(
        boot.iter()
            .all(|(a, _)| a.index >= 0x6800 && a.index < 0x7000),
        "{boot:?}"
    );
    assert_eq!(rig.drive.axis_state(0), DriveState::SwitchOnDisabled);
    assert_eq!(rig.drive.axis_position(0), 0.0);
}

#[test]
fn relative_moves_add_to_the_latest_target() {
    let mut rig = Rig::new(PositionMode::Profile);
    rig.enable();
    let op = rig.mv(5.0);
    rig.run_until_done(op, Duration::from_secs(3));
    let op = rig
        .command(AxisCommand::Move {
            target: -2.0,
            relative: true,
            velocity: Some(100.0),
            acceleration: Some(1000.0),
        })
        .unwrap();
    assert_eq!(
        rig.run_until_done(op, Duration::from_secs(3)).0,
        Outcome::Completed
    );
    assert_eq!(rig.drive.position(), 3_000.0);
}

#[test]
fn soft_limits_and_maxima_are_enforced_before_anything_is_sent() {
    let mut rig = Rig::new(PositionMode::Profile);
    rig.enable();
    rig.sent.clear();
    let err = rig
        .command(AxisCommand::Move {
            target: 600.0,
            relative: false,
            velocity: None,
            acceleration: None,
        })
        .unwrap_err();
    assert!(
        matches!(&err, CommandError::BeyondSoftLimit(m) if m.contains("max_position = 500 mm")),
        "{err:?}"
    );
    let err = rig
        .command(AxisCommand::Move {
            target: 1.0,
            relative: false,
            velocity: Some(1e6),
            acceleration: None,
        })
        .unwrap_err();
    assert!(matches!(err, CommandError::AboveMaximum(_)), "{err:?}");
    let err = rig
        .command(AxisCommand::Move {
            target: f64::NAN,
            relative: false,
            velocity: None,
            acceleration: None,
        })
        .unwrap_err();
    assert!(matches!(err, CommandError::BadValue(_)), "{err:?}");
    let err = rig
        .command(AxisCommand::Jog {
            velocity: -300.0,
            acceleration: None,
        })
        .unwrap_err();
    assert!(matches!(err, CommandError::AboveMaximum(_)), "{err:?}");
    assert!(rig.sent.is_empty());
}

#[test]
fn cyclic_move_samples_a_trapezoid_within_the_limits_every_sync() {
    let mut rig = Rig::new(PositionMode::Cyclic);
    rig.enable();
    rig.setpoints.clear();
    let op = rig.mv(20.0);
    let (outcome, detail) = rig.run_until_done(op, Duration::from_secs(3));
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    assert!((rig.drive.position() - 20_000.0).abs() <= 10.0);
    // Every SYNC carried a set-point; steps respect v ≤ 100 mm/s (1000
    // counts per 10 ms cycle) and a ≤ 1000 mm/s² (Δv ≤ 100 counts per
    // cycle per cycle), plus rounding.
    let p: Vec<f64> = rig.setpoints.iter().map(|(_, c)| f64::from(*c)).collect();
    assert!(p.len() > 20);
    let syncs: Vec<u128> = rig.setpoints.iter().map(|(t, _)| t.as_millis()).collect();
    assert!(syncs.windows(2).all(|w| w[1] - w[0] == 10), "one per SYNC");
    let v: Vec<f64> = p.windows(2).map(|w| w[1] - w[0]).collect();
    assert!(v.iter().all(|dv| dv.abs() <= 1000.0 + 1.0), "{v:?}");
    let a: Vec<f64> = v.windows(2).map(|w| w[1] - w[0]).collect();
    assert!(a.iter().all(|da| da.abs() <= 100.0 + 2.0), "{a:?}");
    assert_eq!(*p.last().unwrap(), 20_000.0);
    assert!(p.windows(2).all(|w| w[1] >= w[0]), "monotonic");
}

#[test]
fn cyclic_enable_holds_the_current_position() {
    let mut rig = Rig::new(PositionMode::Cyclic);
    rig.enable();
    rig.run(100 * MS);
    assert_eq!(rig.drive.position(), 0.0);
    assert!(!rig.setpoints.is_empty());
    assert!(rig.setpoints.iter().all(|(_, c)| *c == 0));
    assert_eq!(
        rig.drive.mode(),
        Some(ModeOfOperation::CyclicSynchronousPosition)
    );
}

#[test]
fn stop_decelerates_a_cyclic_move_to_rest_short_of_the_target() {
    let mut rig = Rig::new(PositionMode::Cyclic);
    rig.enable();
    let mv = rig.mv(100.0);
    rig.run(300 * MS);
    let stop = rig.command(AxisCommand::Stop).unwrap();
    assert_eq!(rig.done(mv).unwrap().0, Outcome::Stopped);
    assert_eq!(
        rig.run_until_done(stop, Duration::from_secs(2)).0,
        Outcome::Completed
    );
    rig.run(100 * MS);
    let p = rig.drive.position();
    assert!(p > 15_000.0 && p < 100_000.0, "{p}");
    assert!(rig.drive.velocity().abs() < 1.0);
}

/// The gateway samples cyclic set-points on its SYNC thread
/// ([`Cia402Axis::cyclic_plan`] there, [`Cia402Axis::on_cyclic_sample`]
/// back): enable, a move, a re-targeted move, a stop, a jog to its
/// dead-man and a coordinated move send exactly the set-points that
/// [`Cia402Axis::on_sync`] sends, and end the same way.
#[test]
fn set_points_sampled_from_the_published_plan_equal_on_sync() {
    fn scenario(split: bool) -> (Vec<(Duration, i32)>, Vec<Outcome>, f64, usize) {
        let mut rig = Rig::new(PositionMode::Cyclic);
        if split {
            rig.split = Some((None, None));
        }
        rig.enable();
        let mut outcomes = Vec::new();
        let mv = rig.mv(20.0);
        outcomes.push(rig.run_until_done(mv, Duration::from_secs(3)).0);
        let mv = rig.mv(60.0);
        rig.run(150 * MS);
        // Re-targeted while moving.
        let mv2 = rig.mv(-10.0);
        outcomes.push(rig.done(mv).unwrap().0);
        rig.run(200 * MS);
        let stop = rig.command(AxisCommand::Stop).unwrap();
        outcomes.push(rig.done(mv2).unwrap().0);
        outcomes.push(rig.run_until_done(stop, Duration::from_secs(2)).0);
        let jog = rig
            .command(AxisCommand::Jog {
                velocity: 5.0,
                acceleration: None,
            })
            .unwrap();
        outcomes.push(rig.run_until_done(jog, Duration::from_secs(3)).0);
        let from = rig.axis.demand();
        let limits = Limits::symmetric(100.0, 1000.0).unwrap();
        let plan = cangate_motion::SyncedMove::new([
            cangate_motion::AxisMove::new(from, from + 30.0, limits),
            cangate_motion::AxisMove::new(0.0, 5.0, limits),
        ])
        .unwrap();
        let ratio = 1.0 / plan.time_scale(1).unwrap();
        let mut out = Vec::new();
        let op = rig
            .axis
            .start_coordinated(plan.profile(1).unwrap().clone(), ratio, rig.now, &mut out)
            .unwrap();
        rig.handle(out);
        outcomes.push(rig.run_until_done(op, Duration::from_secs(3)).0);
        rig.run(50 * MS);
        (rig.setpoints, outcomes, rig.drive.position(), rig.published)
    }
    let (on_sync, outcomes, position, _) = scenario(false);
    let (split, split_outcomes, split_position, published) = scenario(true);
    // A plan is published when a command changes it (and once more when
    // its first sample fixes the start, once when it ends), not per SYNC.
    assert!(
        published <= 20,
        "{published} plans for {} SYNCs",
        split.len()
    );
    assert!(on_sync.len() > 100, "{}", on_sync.len());
    assert_eq!(split_outcomes, outcomes);
    assert_eq!(split.len(), on_sync.len());
    for (a, b) in split.iter().zip(&on_sync) {
        assert_eq!(a, b);
    }
    assert_eq!(split_position, position);
    use Outcome::*;
    assert_eq!(
        outcomes,
        [
            Completed, Superseded, Stopped, Completed, Stopped, Completed
        ]
    );
}

#[test]
fn profile_stop_halts_and_the_next_move_runs() {
    let mut rig = Rig::new(PositionMode::Profile);
    rig.enable();
    let mv = rig.mv(100.0);
    rig.run(300 * MS);
    let stop = rig.command(AxisCommand::Stop).unwrap();
    assert_eq!(
        rig.run_until_done(stop, Duration::from_secs(2)).0,
        Outcome::Completed
    );
    assert_eq!(rig.done(mv).unwrap().0, Outcome::Stopped);
    let halted_at = rig.drive.position();
    assert!(halted_at < 100_000.0);
    rig.run(200 * MS);
    assert_eq!(rig.drive.position(), halted_at, "stays halted");
    let op = rig.mv(10.0);
    assert_eq!(
        rig.run_until_done(op, Duration::from_secs(3)).0,
        Outcome::Completed
    );
    assert_eq!(rig.drive.position(), 10_000.0);
}

#[test]
fn jog_runs_while_repeated_and_stops_at_the_dead_man() {
    for mode in [PositionMode::Profile, PositionMode::Cyclic] {
        let mut rig = Rig::new(mode);
        rig.enable();
        let jog = AxisCommand::Jog {
            velocity: 20.0,
            acceleration: Some(1000.0),
        };
        let op = rig.command(jog).unwrap();
        for _ in 0..5 {
            rig.run(200 * MS);
            assert_eq!(rig.command(jog).unwrap(), op, "{mode:?}: same jog");
        }
        assert!(rig.done(op).is_none(), "{mode:?}: still jogging");
        // ~1 s at 20 mm/s.
        let p = rig.drive.position();
        assert!(p > 15_000.0, "{mode:?}: {p}");
        // No renewal: the dead-man (500 ms) stops it.
        let (outcome, detail) = rig.run_until_done(op, Duration::from_secs(2));
        assert_eq!(outcome, Outcome::Stopped, "{mode:?}: {detail}");
        assert!(detail.contains("dead-man"), "{detail}");
        rig.run(100 * MS);
        assert!(rig.drive.velocity().abs() < 1.0, "{mode:?}");
        let stopped_at = rig.drive.position();
        assert!(stopped_at < 40_000.0, "{mode:?}: {stopped_at}");
    }
}

/// The set-points of a cyclic jog are sampled where the SYNC is sent, so
/// the dead-man must hold there too: with the axis's own thread stalled
/// (no samples handed back, no ticks), the plan alone stops the jog at the
/// first SYNC past the deadline, at the jog's deceleration; once the axis
/// runs again its jog ends "stopped" where the drive stands.
#[test]
fn a_cyclic_jog_stops_at_its_dead_man_even_while_the_axis_is_stalled() {
    let mut rig = Rig::new(PositionMode::Cyclic);
    rig.split = Some((None, None));
    rig.enable();
    let op = rig
        .command(AxisCommand::Jog {
            velocity: 20.0,
            acceleration: Some(1000.0),
        })
        .unwrap();
    let jog_start = rig.now;
    rig.run(200 * MS);
    assert!(rig.done(op).is_none());
    // The axis stalls: only the published plan is sampled from here on.
    let (_, sampled) = rig.split.take().unwrap();
    let mut plan = sampled.expect("a published plan");
    let deadline = jog_start + Duration::from_millis(500);
    let mut stops = Vec::new();
    let mut last = None;
    while rig.now < jog_start + Duration::from_secs(3) {
        rig.now += MS;
        let _ = rig.drive.on_tick(rig.now);
        if rig
            .now
            .as_millis()
            .is_multiple_of(rig.sync_period.as_millis())
        {
            let _ = rig.drive.on_frame(&frame(0x080, &[]), rig.now);
            let sample = plan.sample(rig.now);
            if sample.deadman_stop {
                stops.push(rig.now);
            }
            let mut image = rig.axis.image();
            image.target_position = sample.counts;
            for (cob, data) in encode_image(&image, &rig.rpdos[1..]).unwrap() {
                let _ = rig.drive.on_frame(&frame(cob, &data), rig.now);
            }
            last = Some(sample);
        }
    }
    assert_eq!(stops.len(), 1, "{stops:?}");
    assert!(stops[0] >= deadline && stops[0] < deadline + rig.sync_period);
    // 20 mm/s for ~0.5 s, then 0.2 mm of ramp at 1000 mm/s²: not 3 s worth.
    let p = rig.drive.position();
    assert!(p > 9_000.0 && p < 11_500.0, "{p}");
    assert!(rig.drive.velocity().abs() < 1.0);
    // The axis runs again: it takes the latest sample and ends the jog.
    let mut out = Vec::new();
    rig.axis.on_cyclic_sample(&last.unwrap(), rig.now, &mut out);
    rig.handle(out);
    rig.split = Some((None, None));
    let (outcome, detail) = rig.run_until_done(op, Duration::from_secs(3));
    assert_eq!(outcome, Outcome::Stopped, "{detail}");
    rig.run(100 * MS);
    assert!(
        (rig.drive.position() - p).abs() < 5.0,
        "stays where it stopped"
    );
}

#[test]
fn quick_stop_leaves_operation_enabled_and_enable_recovers() {
    let mut rig = Rig::new(PositionMode::Profile);
    rig.enable();
    let mv = rig.mv(100.0);
    rig.run(200 * MS);
    let qs = rig.command(AxisCommand::QuickStop).unwrap();
    assert_eq!(rig.done(mv).unwrap().0, Outcome::Stopped);
    assert_eq!(
        rig.run_until_done(qs, Duration::from_secs(2)).0,
        Outcome::Completed
    );
    assert_ne!(rig.drive.state(), DriveState::OperationEnabled);
    rig.enable();
}

#[test]
fn homing_runs_the_method_and_returns_to_the_position_mode() {
    for mode in [PositionMode::Profile, PositionMode::Cyclic] {
        let mut rig = Rig::new(mode);
        rig.enable();
        let op = rig.mv(7.0);
        rig.run_until_done(op, Duration::from_secs(3));
        assert!(!rig.axis.snapshot().homed);
        let home = rig.command(AxisCommand::Home).unwrap();
        let (outcome, detail) = rig.run_until_done(home, Duration::from_secs(3));
        assert_eq!(outcome, Outcome::Completed, "{mode:?}: {detail}");
        let s = rig.axis.snapshot();
        assert!(s.homed);
        // Method 35: the current position becomes the home offset (0).
        assert!(rig.drive.position().abs() < 1.0, "{mode:?}");
        assert!(s.position.abs() <= 0.001, "{mode:?}");
        // And the next move runs in the position mode.
        let op = rig.mv(1.0);
        assert_eq!(
            rig.run_until_done(op, Duration::from_secs(3)).0,
            Outcome::Completed,
            "{mode:?}"
        );
        assert!((rig.drive.position() - 1000.0).abs() <= 10.0, "{mode:?}");
    }
}

#[test]
fn fault_ends_the_move_reports_the_emcy_and_reset_enable_recovers() {
    let mut rig = Rig::new(PositionMode::Cyclic);
    rig.enable();
    let mv = rig.mv(100.0);
    rig.run(100 * MS);
    let frames = rig.drive.inject_fault(0x2310);
    assert!(frames.iter().any(|f| f.raw_id() == 0x081));
    let mut out = Vec::new();
    rig.axis
        .on_emcy(0x2310, "continuous over-current", &mut out);
    rig.handle(out);
    rig.run(100 * MS);
    assert_eq!(rig.done(mv).unwrap().0, Outcome::Fault);
    assert!(rig.events.iter().any(|e| matches!(e,
        AxisEvent::Fault { code: 0x2310, text } if text == "continuous over-current")));
    let s = rig.axis.snapshot();
    assert_eq!(s.fault, Some((0x2310, "continuous over-current".into())));
    let err = rig.command(AxisCommand::Enable).unwrap_err();
    assert!(
        matches!(&err, CommandError::InFault(m) if m.contains("ResetFault")),
        "{err:?}"
    );
    let reset = rig.command(AxisCommand::ResetFault).unwrap();
    assert_eq!(
        rig.run_until_done(reset, Duration::from_secs(2)).0,
        Outcome::Completed
    );
    let mut out = Vec::new();
    rig.axis.on_emcy(0, "", &mut out);
    assert_eq!(rig.axis.snapshot().fault, None);
    rig.enable();
    // Holds where it stopped (no jump back to the old demand).
    let p = rig.drive.position();
    rig.run(100 * MS);
    assert!((rig.drive.position() - p).abs() < 1.0);
}

#[test]
fn node_loss_ends_commands_and_refuses_new_ones_until_back() {
    let mut rig = Rig::new(PositionMode::Profile);
    rig.enable();
    let mv = rig.mv(100.0);
    let mut out = Vec::new();
    rig.axis.on_node_lost("heartbeat timeout", &mut out);
    rig.handle(out);
    assert_eq!(
        rig.done(mv).unwrap(),
        (Outcome::Fault, "node lost: heartbeat timeout".into())
    );
    assert_eq!(
        rig.axis.snapshot().fault.unwrap().1,
        "node lost: heartbeat timeout"
    );
    let err = rig.command(AxisCommand::Enable).unwrap_err();
    assert!(matches!(&err, CommandError::DriveUnavailable(m) if m.contains("node is lost")));
    let mut out = Vec::new();
    rig.axis.on_node_back(false, &mut out);
    rig.handle(out);
    assert!(rig.axis.snapshot().fault.is_none());
    rig.run(20 * MS);
    rig.command(AxisCommand::Stop).unwrap();
}

#[test]
fn a_drive_fault_that_outlasts_a_node_loss_is_reported_again_when_the_node_is_back() {
    let mut rig = Rig::new(PositionMode::Profile);
    rig.enable();
    let frames = rig.drive.inject_fault(0x2310);
    rig.deliver(frames);
    let mut out = Vec::new();
    rig.axis
        .on_emcy(0x2310, "continuous over-current", &mut out);
    rig.handle(out);
    rig.run(30 * MS);
    assert_eq!(rig.axis.snapshot().fault.unwrap().0, 0x2310);
    let mut out = Vec::new();
    rig.axis.on_node_lost("heartbeat timeout", &mut out);
    rig.handle(out);
    rig.events.clear();
    let mut out = Vec::new();
    rig.axis.on_node_back(false, &mut out);
    rig.handle(out);
    // "The loss is over", then "the drive is still faulted": the last
    // fault event agrees with the status.
    assert_eq!(
        rig.events,
        vec![
            AxisEvent::Fault {
                code: 0,
                text: String::new()
            },
            AxisEvent::Fault {
                code: 0x2310,
                text: "continuous over-current".into()
            },
        ]
    );
    assert_eq!(rig.axis.snapshot().fault.unwrap().0, 0x2310);
}

#[test]
fn coordinated_moves_start_and_arrive_together() {
    use cangate_motion::{AxisMove, SyncedMove};
    let mut a = Rig::new(PositionMode::Cyclic);
    let mut b = Rig::new(PositionMode::Cyclic);
    a.enable();
    b.enable();
    a.setpoints.clear();
    b.setpoints.clear();
    let limits = Limits::symmetric(100.0, 1000.0).unwrap();
    let plan = SyncedMove::new([
        AxisMove::new(0.0, 30.0, limits),
        AxisMove::new(0.0, 5.0, limits),
    ])
    .unwrap();
    let mut ops = Vec::new();
    for (i, rig) in [&mut a, &mut b].into_iter().enumerate() {
        let ratio = 1.0 / plan.time_scale(i).unwrap();
        let mut out = Vec::new();
        let profile = plan.profile(i).unwrap().clone();
        ops.push(
            rig.axis
                .start_coordinated(profile, ratio, rig.now, &mut out)
                .unwrap(),
        );
        rig.handle(out);
    }
    // Both rigs run in lock-step; note the SYNC each demand arrives.
    let mut arrived = [None, None];
    for _ in 0..2000 {
        for (i, rig) in [&mut a, &mut b].into_iter().enumerate() {
            rig.step();
            let target = [30_000, 5_000][i];
            if arrived[i].is_none() && rig.setpoints.last().map(|s| s.1) == Some(target) {
                arrived[i] = Some(rig.now);
            }
        }
    }
    assert!(arrived[0].is_some());
    assert_eq!(
        arrived[0], arrived[1],
        "both demands arrive in the same SYNC"
    );
    // And they started in the same SYNC.
    let first_move = |r: &Rig| r.setpoints.iter().find(|s| s.1 != 0).map(|s| s.0);
    assert_eq!(first_move(&a), first_move(&b));
    assert_eq!(a.done(ops[0]).unwrap().0, Outcome::Completed);
    assert_eq!(b.done(ops[1]).unwrap().0, Outcome::Completed);
}

#[test]
fn relative_moves_faster_than_sync_keep_advancing_and_add_up_exactly() {
    // A handwheel binding re-plans every 2 ms; SYNC is every 10 ms. Each
    // new trajectory starts from the state of the latest SYNC sample, so
    // the demand keeps moving at the commanded pace instead of restarting
    // from rest at every SYNC.
    let mut rig = Rig::new(PositionMode::Cyclic);
    rig.enable();
    rig.setpoints.clear();
    for _ in 0..100 {
        rig.command(AxisCommand::Move {
            target: 0.002,
            relative: true,
            velocity: Some(1.0),
            acceleration: Some(1000.0),
        })
        .unwrap();
        rig.run(2 * MS);
    }
    // 0.2 mm commanded over 200 ms at 1 mm/s: nearly all of it is done.
    let done = rig.setpoints.last().unwrap().1;
    assert!(done >= 180, "{:?}", rig.setpoints);
    rig.run(100 * MS);
    assert_eq!(rig.setpoints.last().unwrap().1, 200);
}

/// The demo's axes: X cyclic with ±200 mm and 100 mm/s, Z profile with
/// ±100 mm, 50 mm/s and a homing run to a reference switch.
fn demo_config(mode: PositionMode) -> Cia402Config {
    let mut cfg = Cia402Config::example(1000.0, mode);
    let (limit, vmax, amax) = match mode {
        PositionMode::Cyclic => (200.0, 100.0, 1000.0),
        PositionMode::Profile => (100.0, 50.0, 500.0),
    };
    cfg.motion.min_position = Some(-limit);
    cfg.motion.max_position = Some(limit);
    cfg.motion.max_velocity = vmax;
    cfg.motion.max_acceleration = amax;
    cfg.motion.default_velocity = vmax / 4.0;
    cfg.motion.default_acceleration = amax / 4.0;
    cfg.motion.stop_deceleration = amax;
    cfg.motion.quick_stop_deceleration = amax;
    cfg
}

/// Issue 14, item 1: move, home (to a switch, slow), stop during the
/// homing run, move: the axis stays commandable, and the interrupted
/// homing says so.
#[test]
fn a_stop_during_homing_leaves_a_profile_axis_commandable() {
    let mut rig = Rig::with_config(demo_config(PositionMode::Profile), 19);
    rig.enable();
    let mv = rig.mv(10.0);
    assert_eq!(
        rig.run_until_done(mv, Duration::from_secs(3)).0,
        Outcome::Completed
    );
    let home = rig.command(AxisCommand::Home).unwrap();
    rig.run(300 * MS);
    assert!(rig.done(home).is_none(), "homing runs");
    let stop = rig.command(AxisCommand::Stop).unwrap();
    let (outcome, detail) = rig.done(home).expect("the homing ended");
    assert_eq!(outcome, Outcome::Stopped);
    assert!(detail.contains("not homed"), "{detail}");
    assert_eq!(
        rig.run_until_done(stop, Duration::from_secs(3)).0,
        Outcome::Completed
    );
    for target in [5.0, -3.0] {
        let mv = rig.mv(target);
        let (outcome, detail) = rig.run_until_done(mv, Duration::from_secs(5));
        assert_eq!(outcome, Outcome::Completed, "{detail}");
        assert!((rig.drive.position() - target * 1000.0).abs() < 1.0);
    }
    assert!(!rig.axis.snapshot().homed);
}

/// Issue 14, item 1: a move sent during homing supersedes it cleanly (the
/// homing ends saying it was interrupted) and runs.
#[test]
fn a_move_during_homing_supersedes_it_and_runs() {
    let mut rig = Rig::with_config(demo_config(PositionMode::Profile), 19);
    rig.enable();
    let mv = rig.mv(10.0);
    rig.run_until_done(mv, Duration::from_secs(3));
    let home = rig.command(AxisCommand::Home).unwrap();
    rig.run(300 * MS);
    let mv = rig.mv(5.0);
    let (outcome, detail) = rig.done(home).expect("the homing ended");
    assert_eq!(outcome, Outcome::Superseded);
    assert!(detail.contains("not homed"), "{detail}");
    let (outcome, detail) = rig.run_until_done(mv, Duration::from_secs(5));
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    assert!((rig.drive.position() - 5000.0).abs() < 1.0);
}

/// Issue 14, item 1a: a cyclic axis jogging at nearly full speed is told
/// to home. It must come to rest under the gateway's trajectory before the
/// drive switches to homing (whose deceleration is far lower), never pass
/// its soft limits, and a stop must stop it.
#[test]
fn home_while_jogging_does_not_run_a_cyclic_axis_away() {
    let mut rig = Rig::with_config(demo_config(PositionMode::Cyclic), 35);
    rig.enable();
    let jog = AxisCommand::Jog {
        velocity: -99.0,
        acceleration: None,
    };
    rig.command(jog).unwrap();
    rig.run(200 * MS);
    rig.command(jog).unwrap();
    rig.run(300 * MS);
    let home = rig.command(AxisCommand::Home).unwrap();
    let end = rig.now + Duration::from_secs(5);
    let mut lowest = f64::MAX;
    while rig.now < end && rig.done(home).is_none() {
        rig.step();
        lowest = lowest.min(rig.drive.position());
    }
    let (outcome, detail) = rig.done(home).expect("homing ends");
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    assert!(lowest >= -200_000.0, "passed the soft limit: {lowest}");
    assert!(rig.drive.velocity().abs() < 1.0);
    // A jog, then a stop with wait: the stop completes at rest.
    rig.command(jog).unwrap();
    rig.run(300 * MS);
    let stop = rig.command(AxisCommand::Stop).unwrap();
    let (outcome, detail) = rig.run_until_done(stop, Duration::from_secs(3));
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    // At rest: what is left moves less than the in-position window.
    let at = rig.drive.position();
    rig.run(200 * MS);
    assert!((rig.drive.position() - at).abs() <= 10.0);
}

/// How a gentle motion is stopped in [`stopping_distance`].
#[derive(Debug, Clone, Copy, PartialEq)]
enum StopBy {
    Stop,
    QuickStop,
    /// The jog's dead-man (no renewal).
    DeadMan,
}

/// A gentle motion (20 mm/s, 10 mm/s²) at full speed after 3 s, then
/// stopped `by`: the distance the drive travels from the stop on (mm), and
/// its velocity then (mm/s).
fn stopping_distance(mode: PositionMode, split: bool, by: StopBy) -> (f64, f64) {
    let mut rig = Rig::with_config(demo_config(mode), 35);
    if split {
        rig.split = Some((None, None));
    }
    rig.enable();
    let gentle = Some(10.0);
    let op = if by == StopBy::DeadMan {
        let jog = AxisCommand::Jog {
            velocity: 20.0,
            acceleration: gentle,
        };
        let op = rig.command(jog).unwrap();
        for _ in 0..15 {
            rig.run(200 * MS);
            rig.command(jog).unwrap();
        }
        // The dead-man expires 500 ms after the last renewal.
        rig.run(500 * MS);
        op
    } else {
        rig.command(AxisCommand::Move {
            target: 90.0,
            relative: false,
            velocity: Some(20.0),
            acceleration: gentle,
        })
        .unwrap();
        rig.run(Duration::from_secs(3));
        let cmd = if by == StopBy::Stop {
            AxisCommand::Stop
        } else {
            AxisCommand::QuickStop
        };
        rig.command(cmd).unwrap()
    };
    let (p0, v0) = (rig.drive.position() / 1000.0, rig.drive.velocity() / 1000.0);
    rig.run_until_done(op, Duration::from_secs(5));
    rig.run(200 * MS);
    assert!(rig.drive.velocity().abs() < 1.0, "{mode:?} {by:?}: at rest");
    ((rig.drive.position() / 1000.0 - p0).abs(), v0)
}

/// Issue 26, item 1: a stop brakes at the axis's stop deceleration (the
/// maximum acceleration by default), not at the interrupted motion's: the
/// stopping distance of a gentle motion is within v²/(2·a_stop) plus the
/// travel of the set-points already sent, for Stop, QuickStop and the jog's dead-man, on
/// cyclic (the gateway's ramp, sampled by the axis or as the SYNC thread
/// does) and profile axes (the drive's halt ramp, 0x6084). At the motion's
/// own 10 mm/s² it would be 20 mm.
#[test]
fn every_stop_brakes_at_least_at_the_stop_deceleration() {
    for (mode, split) in [
        (PositionMode::Cyclic, false),
        (PositionMode::Cyclic, true),
        (PositionMode::Profile, false),
    ] {
        for by in [StopBy::Stop, StopBy::QuickStop, StopBy::DeadMan] {
            let cfg = demo_config(mode);
            let a_stop = if by == StopBy::QuickStop {
                cfg.motion.quick_stop_deceleration
            } else {
                cfg.motion.stop_deceleration
            };
            let (d, v) = stopping_distance(mode, split, by);
            assert!((v - 20.0).abs() < 0.5, "{mode:?} {by:?}: at speed ({v})");
            // The set-points already sent, and for a cyclic axis the
            // drive's one SYNC period of interpolation behind them: a
            // cycle's travel each.
            let cycles = if mode == PositionMode::Cyclic {
                2.0
            } else {
                1.0
            };
            let bound = v * v / (2.0 * a_stop) + cycles * v * 0.010 + 0.01;
            assert!(
                d <= bound,
                "{mode:?} split {split} {by:?}: stopped in {d:.3} mm, more than {bound:.3} mm"
            );
        }
    }
}

/// Issue 26, item 5: a drive taken out of operation enabled behind the
/// axis's back (here 0 written to its controlword by SDO) ends the move
/// running on it at the first statusword that shows it, saying why, not
/// at the move's deadline; the axis takes commands again.
#[test]
fn a_drive_that_leaves_operation_enabled_ends_the_move_at_once() {
    for mode in [PositionMode::Cyclic, PositionMode::Profile] {
        let mut rig = Rig::with_config(demo_config(mode), 35);
        rig.enable();
        let op = rig
            .command(AxisCommand::Move {
                target: 90.0,
                relative: false,
                velocity: Some(20.0),
                acceleration: Some(100.0),
            })
            .unwrap();
        rig.run(Duration::from_secs(1));
        assert!(rig.done(op).is_none(), "{mode:?}: still moving");
        rig.sdo_write(obj::CONTROLWORD, &[0, 0]);
        let at = rig.now;
        let (outcome, detail) = rig.run_until_done(op, Duration::from_secs(5));
        assert!(
            rig.now - at <= 3 * rig.sync_period,
            "{mode:?}: ended {:?} after the drive left",
            rig.now - at
        );
        assert_eq!(outcome, Outcome::Fault, "{mode:?}: {detail}");
        assert!(
            detail.contains("left operation enabled (now switch on disabled)"),
            "{mode:?}: {detail}"
        );
        rig.enable();
        let op = rig.mv(0.0);
        let (outcome, detail) = rig.run_until_done(op, Duration::from_secs(10));
        assert_eq!(outcome, Outcome::Completed, "{mode:?}: {detail}");
    }
}

/// Issue 26, item 5: a motion command while a disable is under way is
/// refused (it would race the drive's way out of operation enabled and
/// time out); the disable goes on.
#[test]
fn a_move_is_refused_while_a_disable_is_under_way() {
    for mode in [PositionMode::Cyclic, PositionMode::Profile] {
        let mut rig = Rig::with_config(demo_config(mode), 35);
        rig.enable();
        let disable = rig.command(AxisCommand::Disable).unwrap();
        for cmd in [
            AxisCommand::Move {
                target: 5.0,
                relative: false,
                velocity: None,
                acceleration: None,
            },
            AxisCommand::Jog {
                velocity: 5.0,
                acceleration: None,
            },
            AxisCommand::Home,
        ] {
            match rig.command(cmd) {
                Err(CommandError::Busy(m)) => {
                    assert!(m.contains("being disabled"), "{mode:?}: {m}")
                }
                other => panic!("{mode:?} {cmd:?}: {other:?}"),
            }
        }
        let (outcome, detail) = rig.run_until_done(disable, Duration::from_secs(2));
        assert_eq!(outcome, Outcome::Completed, "{mode:?}: {detail}");
    }
}

impl Rig {
    /// A rig whose drive was enabled before the axis existed (a gateway
    /// restarted next to a running machine): operational, operation
    /// enabled in `mode` at `position` counts, already configured.
    fn adopting(position_mode: PositionMode, mode: ModeOfOperation, position: i32) -> Rig {
        let node = NodeId::new(u32::from(NODE)).unwrap();
        let mut options = SimDriveOptions {
            enabled_at_start: Some((mode, position)),
            ..SimDriveOptions::default()
        };
        options.node.running_at_start = Some(cangate_canopen::nmt::NmtState::Operational);
        let mut drive = SimDrive::bundled(node, options);
        assert!(drive.start(Duration::ZERO).is_empty(), "no boot-up");
        assert_eq!(drive.state(), DriveState::OperationEnabled);
        let (rpdos, tpdos) = standard_pdos(node, FeedbackTrigger::Sync);
        let mut rig = Rig {
            axis: Cia402Axis::new(Cia402Config::example(1000.0, position_mode)),
            drive,
            now: Duration::ZERO,
            sync_period: 10 * MS,
            rpdos,
            tpdos,
            sent: Vec::new(),
            events: Vec::new(),
            setpoints: Vec::new(),
            split: None,
            published: 0,
        };
        let mut writes = Vec::new();
        for p in rig.rpdos.iter().chain(&rig.tpdos) {
            writes.extend(p.sdo_writes().unwrap());
        }
        for (addr, data) in writes {
            rig.sdo_write(addr, &data);
        }
        rig
    }
}

/// A drive found in operation enabled is adopted as it is: the axis shows
/// operation enabled at the drive's position, no RPDO it sends takes the
/// drive out of operation enabled, the drive holds, and the axis moves it
/// without an Enable.
#[test]
fn a_drive_found_enabled_keeps_its_state_and_position() {
    for (position_mode, mode) in [
        (
            PositionMode::Cyclic,
            ModeOfOperation::CyclicSynchronousPosition,
        ),
        (PositionMode::Profile, ModeOfOperation::ProfilePosition),
    ] {
        let mut rig = Rig::adopting(position_mode, mode, 12_345);
        rig.run(100 * MS);
        let s = rig.axis.snapshot();
        assert_eq!(
            s.state,
            Some(DriveState::OperationEnabled),
            "{position_mode:?}"
        );
        assert!((s.position - 12.345).abs() < 1e-9, "{s:?}");
        assert!((s.demand_position - 12.345).abs() < 1e-9, "{s:?}");
        assert_eq!(rig.drive.state(), DriveState::OperationEnabled);
        assert!((rig.drive.position() - 12_345.0).abs() < 1.0);
        let mv = rig
            .command(AxisCommand::Move {
                target: 13.0,
                relative: false,
                velocity: Some(10.0),
                acceleration: Some(100.0),
            })
            .unwrap();
        let (outcome, detail) = rig.run_until_done(mv, Duration::from_secs(3));
        assert_eq!(outcome, Outcome::Completed, "{position_mode:?}: {detail}");
        assert!((rig.drive.position() - 13_000.0).abs() <= 10.0);
        assert_eq!(rig.drive.state(), DriveState::OperationEnabled);
        let controlword = 0x200 + u16::from(NODE);
        for (at, _, data) in rig.sent.iter().filter(|(_, c, _)| *c == controlword) {
            let cw = u16::from_le_bytes([data[0], data[1]]);
            assert_eq!(
                cw & 0x0F,
                0x0F,
                "{position_mode:?}: controlword {cw:#06x} at {at:?}"
            );
        }
    }
}

/// The demo's cyclic axis X with a positive limit switch at 50 mm.
fn switch_rig(mode: PositionMode) -> Rig {
    let mut rig = Rig::with_inputs(
        demo_config(mode),
        SimDriveInputs {
            negative_limit_switch: Some(-50_000),
            positive_limit_switch: Some(50_000),
            home_switch: Some(0),
            touch_probe: Some(20_000),
        },
    );
    rig.enable();
    rig
}

fn faults(rig: &Rig) -> Vec<(u16, String)> {
    rig.events
        .iter()
        .filter_map(|e| match e {
            AxisEvent::Fault { code, text } => Some((*code, text.clone())),
            _ => None,
        })
        .collect()
}

#[test]
fn signals_come_with_the_process_data() {
    let mut rig = switch_rig(PositionMode::Cyclic);
    let s = rig.axis.snapshot();
    // At 0: on the home switch (physical 0 and above), no limit switch.
    assert_eq!(s.signals.digital_inputs, Some(0x4));
    assert_eq!(s.signals.torque, Some(0));
    assert_eq!(s.signals.following_error, Some(0.0));
    assert_eq!(s.signals.touch_probe_status, Some(0));
    assert_eq!(s.fault, None);
    let op = rig.mv(-10.0);
    let mut torque_seen = false;
    for _ in 0..50 {
        rig.step();
        torque_seen |= rig.axis.snapshot().signals.torque.is_some_and(|t| t != 0);
    }
    assert!(torque_seen, "torque while accelerating");
    rig.run_until_done(op, Duration::from_secs(2));
    assert_eq!(rig.axis.snapshot().signals.digital_inputs, Some(0));
    // Without the signal TPDOs they stay absent.
    let plain = Rig::new(PositionMode::Cyclic);
    assert_eq!(plain.axis.snapshot().signals, DriveSignals::default());
}

#[test]
fn limit_switch_stops_a_cyclic_move_says_why_and_lets_the_axis_back_off() {
    let mut rig = switch_rig(PositionMode::Cyclic);
    let op = rig.mv(100.0);
    let (outcome, detail) = rig.run_until_done(op, Duration::from_secs(3));
    assert_eq!(outcome, Outcome::Fault);
    assert!(
        detail.starts_with("positive limit switch reached at 5"),
        "{detail}"
    );
    rig.run(500 * MS);
    let s = rig.axis.snapshot();
    // Braked by the drive at its quick stop deceleration (0x6084 of the
    // simulated drive: 100 mm/s²) as far as the gateway's ramp went on.
    assert!(
        (50.0..56.0).contains(&s.position),
        "stopped at the switch: {s:?}"
    );
    assert_eq!(s.fault, Some((0, "positive limit switch reached".into())));
    assert_eq!(s.signals.digital_inputs, Some(0x6));
    assert_eq!(s.state, Some(DriveState::OperationEnabled));
    // The demand is where the drive stands: no jump, no following error.
    assert!((s.demand_position - s.position).abs() < 0.01, "{s:?}");
    assert_eq!(
        faults(&rig),
        [(0, "positive limit switch reached".to_string())]
    );
    // Further into it: refused. Away: runs, and the fault clears.
    let e = rig
        .command(AxisCommand::Move {
            target: 60.0,
            relative: false,
            velocity: None,
            acceleration: None,
        })
        .unwrap_err();
    assert!(
        e.to_string()
            .starts_with("the positive limit switch is active"),
        "{e}"
    );
    let e = rig
        .command(AxisCommand::Jog {
            velocity: 5.0,
            acceleration: None,
        })
        .unwrap_err();
    assert!(matches!(e, CommandError::BeyondSoftLimit(_)), "{e}");
    let back = rig.mv(10.0);
    let (outcome, detail) = rig.run_until_done(back, Duration::from_secs(3));
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    assert_eq!(rig.axis.snapshot().fault, None);
    assert_eq!(faults(&rig).last(), Some(&(0, String::new())));
}

#[test]
fn limit_switch_halts_a_profile_jog_and_lets_it_back_off() {
    let mut rig = switch_rig(PositionMode::Profile);
    let jog = rig
        .command(AxisCommand::Jog {
            velocity: -20.0,
            acceleration: None,
        })
        .unwrap();
    // The dead-man: repeated.
    let mut outcome = None;
    for _ in 0..40 {
        rig.run(100 * MS);
        if let Some(r) = rig.done(jog) {
            outcome = Some(r);
            break;
        }
        rig.command(AxisCommand::Jog {
            velocity: -20.0,
            acceleration: None,
        })
        .unwrap();
    }
    let (outcome, detail) = outcome.expect("the jog ended");
    assert_eq!(outcome, Outcome::Fault);
    assert!(
        detail.starts_with("negative limit switch reached"),
        "{detail}"
    );
    rig.run(300 * MS);
    let s = rig.axis.snapshot();
    assert!((-51.0..=-50.0).contains(&s.position), "{s:?}");
    assert_eq!(s.fault, Some((0, "negative limit switch reached".into())));
    let back = rig.mv(-40.0);
    let (outcome, detail) = rig.run_until_done(back, Duration::from_secs(3));
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    assert_eq!(rig.axis.snapshot().fault, None);
}

#[test]
fn touch_probe_latch_is_an_event_in_user_units() {
    let mut rig = switch_rig(PositionMode::Cyclic);
    rig.sdo_write(
        obj::TOUCH_PROBE_FUNCTION,
        &crate::signals::touch_probe_function(crate::signals::ProbeEdges::Both, false)
            .to_le_bytes(),
    );
    let op = rig.mv(30.0);
    rig.run_until_done(op, Duration::from_secs(3));
    let op = rig.mv(0.0);
    rig.run_until_done(op, Duration::from_secs(3));
    let latches: Vec<_> = rig
        .events
        .iter()
        .filter_map(|e| match e {
            AxisEvent::TouchProbe { rising, position } => Some((*rising, *position)),
            _ => None,
        })
        .collect();
    assert_eq!(latches, [(true, 20.0), (false, 20.0)]);
    assert_eq!(rig.axis.snapshot().signals.touch_probe_status, Some(0x7));
}

#[test]
fn following_error_fault_names_the_error_and_the_window() {
    let mut cfg = demo_config(PositionMode::Cyclic);
    cfg.supervision.following_error_window = Some(0.1);
    cfg.supervision.following_error_timeout = Some(20 * MS);
    let mut rig = Rig::with_inputs(cfg, SimDriveInputs::default());
    rig.enable();
    let op = rig.mv(50.0);
    let (outcome, detail) = rig.run_until_done(op, Duration::from_secs(3));
    assert_eq!(outcome, Outcome::Fault, "{detail}");
    rig.run(300 * MS);
    let (code, text) = rig.axis.snapshot().fault.expect("in fault");
    assert_eq!(code, 0x8611);
    assert!(
        text.starts_with("following error beyond the window (")
            && text.ends_with(" mm > 0.100 mm)"),
        "{text}"
    );
    assert_eq!(faults(&rig).last(), Some(&(0x8611, text)));
}

/// A drive fault on the limit switch, then reset: the events end on the
/// limit switch the status still shows, not on "cleared".
#[test]
fn a_fault_cleared_on_an_active_limit_switch_reports_the_switch_again() {
    let mut rig = switch_rig(PositionMode::Cyclic);
    let op = rig.mv(100.0);
    rig.run_until_done(op, Duration::from_secs(3));
    rig.run(300 * MS);
    let frames = rig.drive.inject_fault(0x2310);
    rig.deliver(frames);
    rig.run(100 * MS);
    assert_eq!(rig.axis.snapshot().fault.map(|f| f.0), Some(0x2310));
    let reset = rig.command(AxisCommand::ResetFault).unwrap();
    rig.run_until_done(reset, Duration::from_secs(2));
    let reached = (0, "positive limit switch reached".to_string());
    assert_eq!(rig.axis.snapshot().fault, Some(reached.clone()));
    assert_eq!(faults(&rig).last(), Some(&reached), "{:?}", faults(&rig));
}
mod modes;
