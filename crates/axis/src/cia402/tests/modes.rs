//! The modes beyond profile and cyclic position against the simulated
//! drive: cyclic synchronous velocity and torque, profile torque,
//! interpolated position, and the mode change at rest, with the exact
//! RPDOs that carry them.

use super::*;
use crate::process_data::torque_rpdo;
use cangate_sim::drive::TorqueModel;

/// A rig in `mode` (1000 counts per mm, ±500 mm, 200 mm/s, stop at
/// 2000 mm/s²) whose drive has `options`; the torque RPDO (RPDO3, 0x6071)
/// is mapped besides the standard layout.
fn rig_in(mode: DriveMode, options: SimDriveOptions, edit: impl FnOnce(&mut Cia402Config)) -> Rig {
    let node = NodeId::new(u32::from(NODE)).unwrap();
    let mut drive = SimDrive::bundled(node, options);
    drive.start(Duration::ZERO);
    let (mut rpdos, tpdos) = standard_pdos(node, FeedbackTrigger::Sync);
    rpdos.push(torque_rpdo(node));
    let mut cfg = Cia402Config::example_in(1000.0, mode);
    edit(&mut cfg);
    let mut rig = Rig {
        axis: Cia402Axis::new(cfg),
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
    for (addr, data) in writes {
        rig.sdo_write(addr, &data);
    }
    let start = rig.drive.on_frame(&frame(0x000, &[0x01, NODE]), rig.now);
    rig.deliver(start);
    rig.run(30 * MS);
    rig
}

impl Rig {
    /// RPDOs with `cob` sent since the `from`th one of all (time,
    /// payload).
    fn sent_on(&self, cob: u16, from: usize) -> Vec<(Duration, Vec<u8>)> {
        self.sent[from..]
            .iter()
            .filter(|(_, c, _)| *c == cob)
            .map(|(t, _, d)| (*t, d.clone()))
            .collect()
    }

    /// How many RPDOs were sent so far.
    fn mark(&self) -> usize {
        self.sent.len()
    }

    /// The drive's velocity (counts/s).
    fn drive_velocity(&self) -> f64 {
        self.drive.velocity()
    }

    /// Holds a jog at `velocity` for `d`, repeating it within the dead-man.
    fn hold_jog(&mut self, velocity: f64, acceleration: f64, d: Duration) -> OpId {
        let jog = AxisCommand::Jog {
            velocity,
            acceleration: Some(acceleration),
        };
        let op = self.command(jog).unwrap();
        let end = self.now + d;
        while self.now < end {
            self.run(100 * MS);
            assert_eq!(self.command(jog).unwrap(), op, "the jog is re-armed");
        }
        op
    }
}

const RPDO1: u16 = 0x200 + NODE as u16;
const RPDO2: u16 = 0x300 + NODE as u16;
const RPDO3: u16 = 0x400 + NODE as u16;

fn velocity_of(rpdo2: &[u8]) -> i32 {
    i32::from_le_bytes(rpdo2[4..8].try_into().unwrap())
}

#[test]
fn csv_jogs_with_velocity_set_points_in_rpdo2_within_the_acceleration() {
    let mut rig = rig_in(
        DriveMode::CyclicVelocity,
        SimDriveOptions::default(),
        |_| {},
    );
    rig.enable();
    // Enabled in mode 9: RPDO1 carries controlword 0x000F and 0x09.
    assert!(
        rig.sent_on(RPDO1, 0)
            .iter()
            .any(|(_, d)| d == &[0x0F, 0x00, 0x09]),
        "{:?}",
        rig.sent_on(RPDO1, 0)
    );
    assert_eq!(
        rig.drive.mode(),
        Some(ModeOfOperation::CyclicSynchronousVelocity)
    );
    let from = rig.mark();
    let start = rig.axis.snapshot().position;
    rig.hold_jog(50.0, 500.0, Duration::from_millis(400));
    let sent = rig.sent_on(RPDO2, from);
    // Every SYNC a velocity; 500 mm/s² over 10 ms: at most 5 mm/s
    // (5000 counts/s) more per SYNC, up to 50 mm/s, never a jump.
    let mut previous = 0;
    for (t, d) in &sent {
        let v = velocity_of(d);
        assert!((v - previous).abs() <= 5001, "{t:?}: {previous} -> {v}");
        assert!((0..=50_000).contains(&v), "{t:?}: {v}");
        previous = v;
    }
    // At speed: exactly 50 000 counts/s in bytes 4..8 of RPDO2.
    assert_eq!(&sent.last().unwrap().1[4..8], &[0x50, 0xC3, 0x00, 0x00]);
    assert!((rig.drive_velocity() - 50_000.0).abs() < 100.0);
    assert!(rig.axis.snapshot().position > start + 10.0);
    // Stop: the gateway ramps the velocity to 0 at the stop deceleration
    // (2000 mm/s²: at most 20 000 counts/s less per SYNC).
    let from = rig.mark();
    let stop = rig.command(AxisCommand::Stop).unwrap();
    let (outcome, detail) = rig.run_until_done(stop, Duration::from_secs(2));
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    let mut previous = 50_000;
    for (t, d) in rig.sent_on(RPDO2, from) {
        let v = velocity_of(&d);
        assert!((previous - v).abs() <= 20_001, "{t:?}: {previous} -> {v}");
        assert!(v >= 0, "{t:?}: {v}: a stop never reverses");
        previous = v;
    }
    assert_eq!(previous, 0);
    // At rest as the axis counts it (below the in-position window per
    // 100 ms); the drive's lag settles the rest.
    assert!(
        rig.drive_velocity().abs() < 100.0,
        "{}",
        rig.drive_velocity()
    );
    assert_eq!(rig.axis.activity(), Activity::Idle);
    // A move has no meaning in CSV: refused, nothing sent.
    let before = rig.sent.len();
    let e = rig.command(AxisCommand::Move {
        target: 1.0,
        relative: false,
        velocity: None,
        acceleration: None,
    });
    assert!(matches!(e, Err(CommandError::WrongMode(_))), "{e:?}");
    assert_eq!(rig.sent.len(), before);
}

#[test]
fn csv_jog_dead_man_ramps_the_velocity_down() {
    let mut rig = rig_in(
        DriveMode::CyclicVelocity,
        SimDriveOptions::default(),
        |_| {},
    );
    rig.enable();
    let op = rig.hold_jog(-40.0, 1000.0, Duration::from_millis(300));
    // Released: the dead-man (500 ms) stops it on the stop ramp.
    let (outcome, detail) = rig.run_until_done(op, Duration::from_secs(2));
    assert_eq!(outcome, Outcome::Stopped, "{detail}");
    assert!(
        rig.drive_velocity().abs() < 100.0,
        "{}",
        rig.drive_velocity()
    );
    let last = rig.sent_on(RPDO2, 0).last().unwrap().1.clone();
    assert_eq!(velocity_of(&last), 0);
}

/// A CST axis with max_velocity 30 mm/s (30 000 counts/s).
fn cst_rig() -> Rig {
    rig_in(DriveMode::CyclicTorque, SimDriveOptions::default(), |c| {
        c.motion.max_velocity = 30.0;
        c.torque.max_torque = 500.0;
    })
}

#[test]
fn cst_sends_the_torque_in_rpdo3_and_a_stop_halts_on_the_drive_ramp() {
    let mut rig = cst_rig();
    rig.enable();
    assert!(
        rig.sent_on(RPDO1, 0)
            .iter()
            .any(|(_, d)| d == &[0x0F, 0x00, 0x0A])
    );
    let from = rig.mark();
    // 30 per mille against 10 of Coulomb and 1 per 1000 counts/s viscous
    // friction: the unloaded motor settles at 20 000 counts/s, below the
    // guard.
    let op = rig
        .command(AxisCommand::SetTorque { per_mille: 30.0 })
        .unwrap();
    assert!(rig.accepted(op));
    assert_eq!(rig.sent_on(RPDO3, from)[0].1, vec![0x1E, 0x00]);
    // The inertia over the viscous friction: a time constant of 1 s.
    rig.run(Duration::from_secs(5));
    assert!(
        rig.done(op).is_none(),
        "a torque command runs until stopped"
    );
    assert_eq!(rig.axis.activity(), Activity::Moving);
    let v = rig.drive_velocity();
    assert!((v - 20_000.0).abs() < 500.0, "{v}");
    // Stop: halt (bit 8) on the drive's own ramp, torque set-point 0.
    let from = rig.mark();
    let stop = rig.command(AxisCommand::Stop).unwrap();
    assert_eq!(rig.done(op).unwrap().0, Outcome::Stopped);
    assert!(
        rig.sent_on(RPDO1, from)
            .iter()
            .any(|(_, d)| d == &[0x0F, 0x01, 0x0A])
    );
    assert_eq!(rig.sent_on(RPDO3, from)[0].1, vec![0x00, 0x00]);
    let (outcome, detail) = rig.run_until_done(stop, Duration::from_secs(2));
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    assert_eq!(rig.drive_velocity(), 0.0);
}

#[test]
fn cst_velocity_guard_stops_an_unloaded_axis_that_runs_away() {
    let mut rig = cst_rig();
    rig.enable();
    // 200 per mille would take the unloaded motor to 190 000 counts/s.
    let op = rig
        .command(AxisCommand::SetTorque { per_mille: 200.0 })
        .unwrap();
    let mut fastest: f64 = 0.0;
    let end = rig.now + Duration::from_secs(2);
    while rig.done(op).is_none() && rig.now < end {
        rig.step();
        fastest = fastest.max(rig.drive_velocity().abs());
    }
    let (outcome, detail) = rig.done(op).expect("the guard ended the torque command");
    assert_eq!(outcome, Outcome::Stopped, "{detail}");
    assert!(detail.contains("exceeded max_velocity 30"), "{detail}");
    assert_eq!(rig.drive_velocity(), 0.0);
    // Beyond 30 000 counts/s for at most a feedback period (10 ms at
    // 190 000 counts/s²) before the halt brakes.
    assert!(fastest < 33_000.0, "{fastest}");
    assert_eq!(rig.axis.image().target_torque, 0);
    // Above the axis's maximum torque: refused, nothing sent.
    let e = rig.command(AxisCommand::SetTorque { per_mille: 600.0 });
    assert!(matches!(e, Err(CommandError::AboveMaximum(_))), "{e:?}");
}

#[test]
fn profile_torque_ramps_at_the_torque_slope_written_at_boot() {
    let mut rig = rig_in(DriveMode::ProfileTorque, SimDriveOptions::default(), |c| {
        c.torque.torque_slope = 100.0;
    });
    rig.enable();
    assert!(
        rig.sent_on(RPDO1, 0)
            .iter()
            .any(|(_, d)| d == &[0x0F, 0x00, 0x04])
    );
    let slope = rig.drive.node().get(obj::TORQUE_SLOPE).cloned();
    assert_eq!(slope, Some(Value::Unsigned32(100)));
    let op = rig
        .command(AxisCommand::SetTorque { per_mille: 50.0 })
        .unwrap();
    rig.run(Duration::from_millis(250));
    let torque = |rig: &Rig| match rig.drive.node().get(obj::TORQUE_ACTUAL) {
        Some(Value::Integer16(t)) => *t,
        other => panic!("{other:?}"),
    };
    // 100 per mille/s: half way after 250 ms.
    assert!((23..=27).contains(&torque(&rig)), "{}", torque(&rig));
    rig.run(Duration::from_millis(400));
    assert_eq!(torque(&rig), 50);
    let stop = rig.command(AxisCommand::Stop).unwrap();
    assert_eq!(rig.done(op).unwrap().0, Outcome::Stopped);
    let (outcome, detail) = rig.run_until_done(stop, Duration::from_secs(2));
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    assert_eq!(rig.drive_velocity(), 0.0);
}

#[test]
fn the_mode_changes_at_rest_and_is_refused_while_moving() {
    let mut rig = rig_in(
        DriveMode::CyclicPosition,
        SimDriveOptions::default(),
        |_| {},
    );
    rig.enable();
    // A torque in CSP: refused.
    let e = rig.command(AxisCommand::SetTorque { per_mille: 10.0 });
    assert!(matches!(e, Err(CommandError::WrongMode(_))), "{e:?}");
    // At rest: 0x6060 = 9 in RPDO1, done when the drive shows it.
    let from = rig.mark();
    let op = rig
        .command(AxisCommand::SetMode {
            mode: DriveMode::CyclicVelocity,
        })
        .unwrap();
    assert_eq!(rig.sent_on(RPDO1, from)[0].1, vec![0x0F, 0x00, 0x09]);
    let (outcome, detail) = rig.run_until_done(op, Duration::from_secs(1));
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    assert_eq!(rig.axis.mode(), DriveMode::CyclicVelocity);
    assert_eq!(
        rig.drive.mode(),
        Some(ModeOfOperation::CyclicSynchronousVelocity)
    );
    // Moving: refused, and the jog runs on.
    let jog = AxisCommand::Jog {
        velocity: 20.0,
        acceleration: None,
    };
    let j = rig.command(jog).unwrap();
    rig.run(100 * MS);
    let before = rig.sent.len();
    let e = rig.command(AxisCommand::SetMode {
        mode: DriveMode::CyclicPosition,
    });
    match e {
        Err(CommandError::Busy(m)) => assert!(m.contains("only at rest"), "{m}"),
        other => panic!("{other:?}"),
    }
    assert_eq!(
        rig.sent.len(),
        before,
        "a refused mode change sends nothing"
    );
    assert!(rig.done(j).is_none());
    let stop = rig.command(AxisCommand::Stop).unwrap();
    rig.run_until_done(stop, Duration::from_secs(2));
    // At rest again: back to CSP, holding where the drive stands.
    let from = rig.mark();
    let op = rig
        .command(AxisCommand::SetMode {
            mode: DriveMode::CyclicPosition,
        })
        .unwrap();
    assert_eq!(rig.sent_on(RPDO1, from)[0].1, vec![0x0F, 0x00, 0x08]);
    let (outcome, detail) = rig.run_until_done(op, Duration::from_secs(1));
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    let at = rig.axis.snapshot().position;
    let mv = rig.mv(at + 5.0);
    let (outcome, detail) = rig.run_until_done(mv, Duration::from_secs(2));
    assert_eq!(outcome, Outcome::Completed, "{detail}");
}

#[test]
fn a_mode_the_drive_does_not_support_is_refused() {
    let mut rig = rig_in(
        DriveMode::CyclicPosition,
        SimDriveOptions::default(),
        |_| {},
    );
    // PP, PV, HM, CSP, CSV: no torque modes.
    rig.axis.set_supported_modes(0x1A5);
    let e = rig.command(AxisCommand::SetMode {
        mode: DriveMode::CyclicTorque,
    });
    match e {
        Err(CommandError::WrongMode(m)) => {
            assert!(m.contains("does not support cst"), "{m}");
        }
        other => panic!("{other:?}"),
    }
    // An axis whose process data has no 0x6071 has no torque modes.
    let mut rig = rig_in(DriveMode::CyclicPosition, SimDriveOptions::default(), |c| {
        c.torque.in_process_data = false;
    });
    let e = rig.command(AxisCommand::SetMode {
        mode: DriveMode::ProfileTorque,
    });
    assert!(matches!(e, Err(CommandError::WrongMode(_))), "{e:?}");
}

#[test]
fn the_torque_model_has_inertia_and_friction() {
    let m = TorqueModel::default();
    // At rest, a torque within the Coulomb friction does not start it.
    assert_eq!(m.step(0.0, 10.0, 0.001), 0.0);
    // 30 - 10 per mille: 20 000 counts/s² for 1 ms.
    assert_eq!(m.step(0.0, 30.0, 0.001), 20.0);
    // Coasting: friction brakes, and never reverses the motion.
    let mut v = 1000.0;
    for _ in 0..1000 {
        let next = m.step(v, 0.0, 0.001);
        assert!(next >= 0.0 && next < v);
        v = next;
        if v == 0.0 {
            break;
        }
    }
    assert_eq!(v, 0.0);
}

/// A drive without CSP (PP, PV, HM, IP, CSV: 0x6502 = 0x165) and its axis
/// in interpolated position: RPDO2 carries 0x60C1:01 and 0x60FF, the
/// interpolation period is the SYNC period.
fn ip_rig() -> Rig {
    let options = SimDriveOptions {
        supported_modes: Some(0x165),
        ..SimDriveOptions::default()
    };
    let mut rig = rig_in(DriveMode::InterpolatedPosition, options, |_| {});
    let node = NodeId::new(u32::from(NODE)).unwrap();
    rig.rpdos[1] = crate::process_data::interpolated_rpdo(node);
    let mut writes = rig.rpdos[1].sdo_writes().unwrap();
    let (value, index) = crate::process_data::interpolation_period(rig.sync_period);
    assert_eq!((value, index), (10, -3));
    writes.push((obj::INTERPOLATION_PERIOD_VALUE, vec![value]));
    writes.push((obj::INTERPOLATION_PERIOD_INDEX, vec![index as u8]));
    for (addr, data) in writes {
        rig.sdo_write(addr, &data);
    }
    rig
}

#[test]
fn interpolated_position_moves_a_drive_without_csp() {
    let mut rig = ip_rig();
    // CSP is refused by this drive: it keeps the mode in effect.
    rig.axis.set_supported_modes(0x165);
    let e = rig.command(AxisCommand::SetMode {
        mode: DriveMode::CyclicPosition,
    });
    assert!(matches!(e, Err(CommandError::WrongMode(_))), "{e:?}");
    rig.enable();
    // Enabled in mode 7 with bit 4 (enable ip mode): controlword 0x001F.
    assert!(
        rig.sent_on(RPDO1, 0)
            .iter()
            .any(|(_, d)| d == &[0x1F, 0x00, 0x07]),
        "{:?}",
        rig.sent_on(RPDO1, 0)
    );
    assert_eq!(
        rig.drive.mode(),
        Some(ModeOfOperation::InterpolatedPosition)
    );
    let from = rig.mark();
    let op = rig.mv(20.0);
    let (outcome, detail) = rig.run_until_done(op, Duration::from_secs(3));
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    assert!((rig.axis.snapshot().position - 20.0).abs() <= 0.01);
    // The set-points went to 0x60C1:01 (bytes 0..4 of RPDO2), one per
    // SYNC, never a step beyond 100 mm/s over 10 ms (1000 counts).
    let sent = rig.sent_on(RPDO2, from);
    let mut previous = 0;
    for (t, d) in &sent {
        let p = i32::from_le_bytes(d[..4].try_into().unwrap());
        assert!((p - previous).abs() <= 1001, "{t:?}: {previous} -> {p}");
        previous = p;
    }
    assert_eq!(&sent.last().unwrap().1[..4], &20_000i32.to_le_bytes());
    // A stop mid-move ramps down as in CSP, bit 4 kept.
    let op = rig.mv(-20.0);
    rig.run(200 * MS);
    let stop = rig.command(AxisCommand::Stop).unwrap();
    assert_eq!(rig.done(op).unwrap().0, Outcome::Stopped);
    let (outcome, detail) = rig.run_until_done(stop, Duration::from_secs(2));
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    assert_eq!(rig.axis.image().controlword & 0x0010, 0x0010);
}

#[test]
fn no_torque_outlives_its_command() {
    let mut rig = cst_rig();
    rig.enable();
    // 5 per mille: within the Coulomb friction, the axis stays at rest.
    let op = rig
        .command(AxisCommand::SetTorque { per_mille: 5.0 })
        .unwrap();
    rig.run(100 * MS);
    assert_eq!(rig.drive_velocity(), 0.0);
    // A homing at rest supersedes it: the torque set-point goes to 0 at
    // once, and the axis comes back to CST without it.
    let from = rig.mark();
    let home = rig.command(AxisCommand::Home).unwrap();
    assert_eq!(rig.done(op).unwrap().0, Outcome::Superseded);
    assert_eq!(rig.sent_on(RPDO3, from)[0].1, vec![0x00, 0x00]);
    let (outcome, detail) = rig.run_until_done(home, Duration::from_secs(2));
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    assert_eq!(
        rig.drive.mode(),
        Some(ModeOfOperation::CyclicSynchronousTorque)
    );
    assert_eq!(rig.axis.image().target_torque, 0);
    assert!(
        rig.sent_on(RPDO3, from)
            .iter()
            .all(|(_, d)| d == &[0x00, 0x00])
    );
}

#[test]
fn a_torque_stops_before_the_soft_limit() {
    let mut rig = rig_in(DriveMode::CyclicTorque, SimDriveOptions::default(), |c| {
        c.motion.min_position = Some(-20.0);
        c.motion.max_position = Some(20.0);
        c.motion.max_velocity = 100.0;
    });
    rig.enable();
    // 60 per mille: 50 000 counts/s² at first, towards +20 mm.
    let op = rig
        .command(AxisCommand::SetTorque { per_mille: 60.0 })
        .unwrap();
    let mut furthest: f64 = 0.0;
    let end = rig.now + Duration::from_secs(3);
    while rig.now < end {
        rig.step();
        furthest = furthest.max(rig.drive.position());
    }
    let (outcome, detail) = rig.done(op).expect("the guard ended the torque command");
    assert_eq!(outcome, Outcome::Stopped, "{detail}");
    assert!(detail.contains("soft limit max_position = 20"), "{detail}");
    // Stopped by the gateway inside the limit, not clamped there by the
    // drive's own 0x607D.
    assert!(furthest < 20_000.0, "{furthest}");
    assert_eq!(rig.drive_velocity(), 0.0);
}
