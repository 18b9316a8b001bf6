//! The CANsmc axis in closed loop with a minimal ideal servo: the slave
//! applies the previous cycle's command at each MST (the spec's pipeline),
//! follows position set-points exactly, homes in a few cycles and faults
//! on request. Virtual time only.

use super::*;

const CYCLE: Duration = Duration::from_millis(2);

/// An ideal CANsmc servo: state after the MST of each cycle.
#[derive(Debug, Default)]
struct Servo {
    enabled: bool,
    fault: bool,
    following_error: bool,
    homed: bool,
    homing_cycles: u32,
    position: i32,
    /// Command received in the previous cycle, applied at the next MST.
    pending: Option<CycleOutput>,
    last_reset: bool,
    encoder: i32,
    /// Stop answering (a lost slave).
    silent: bool,
    /// Velocity mode: counts/s.
    velocity: f64,
    /// The function of the command applied last: the DT carries its
    /// feedback.
    last: Option<Command>,
    /// The MDTCW cycle counter of the command applied last, echoed in
    /// the DTSW's bits 12-15.
    counter: u8,
}

impl Servo {
    /// The MST: apply last cycle's command, then sample.
    fn mst(&mut self) {
        if let Some(cmd) = self.pending.take() {
            let c = cmd.control;
            self.counter = self.counter.wrapping_add(1);
            if c.fault_reset && !self.last_reset {
                self.fault = false;
                self.following_error = false;
            }
            self.last_reset = c.fault_reset;
            self.enabled = c.enable && !self.fault;
            if self.enabled && !c.halt {
                self.last = Some(cmd.command);
                match cmd.command {
                    Command::Position(p) => {
                        self.velocity = 0.0;
                        self.position = p;
                    }
                    // 0.001 r/min at 10 000 counts/rev; no ramp.
                    Command::Velocity(v) => {
                        self.velocity = f64::from(v) * 10_000.0 / 60_000.0;
                        self.position += (self.velocity * CYCLE.as_secs_f64()).round() as i32;
                    }
                    Command::Homing { .. } => {
                        self.homing_cycles += 1;
                        self.position -= self.position.signum() * 100.min(self.position.abs());
                        if self.position == 0 && self.homing_cycles > 3 {
                            self.homed = true;
                        }
                    }
                    _ => {}
                }
            }
        }
    }

    fn input(&self) -> CycleInput {
        if self.silent {
            return CycleInput::default();
        }
        let (position, velocity, encoder) = match self.last {
            Some(Command::Velocity(_)) => (None, Some((self.velocity * 6.0) as i32), None),
            Some(Command::Encoder) => (None, None, Some(self.position)),
            _ => (Some(self.position), None, None),
        };
        CycleInput {
            velocity,
            encoder,
            status: Some(StatusWord {
                ready: true,
                enabled: self.enabled,
                fault: self.fault,
                target_reached: true,
                homed: self.homed,
                following_error: self.following_error,
                counter_echo: CycleCounter::new(self.counter),
                ..StatusWord::default()
            }),
            position,
            source_count: Some(self.encoder),
        }
    }
}

struct Rig {
    axis: CansmcAxis,
    servo: Servo,
    now: Duration,
    events: Vec<AxisEvent>,
}

impl Rig {
    fn new(cfg: CansmcAxisConfig) -> Self {
        let mut rig = Rig {
            axis: CansmcAxis::new(cfg),
            servo: Servo::default(),
            now: Duration::ZERO,
            events: Vec::new(),
        };
        rig.cycles(1);
        rig
    }

    /// Runs `n` cycles: MST at the slave, then the axis computes the MDT.
    fn cycles(&mut self, n: usize) {
        for _ in 0..n {
            self.servo.mst();
            let input = self.servo.input();
            let out = self.axis.on_cycle(self.now, input, &mut self.events);
            if !self.servo.silent {
                self.servo.pending = Some(out);
            }
            self.now += CYCLE;
        }
    }

    fn command(&mut self, cmd: AxisCommand) -> Result<OpId, CommandError> {
        self.axis.command(cmd, self.now, &mut self.events)
    }

    /// Runs until op `id` is done (at most `max` cycles); its outcome.
    fn until_done(&mut self, id: OpId, max: usize) -> (Outcome, String) {
        for _ in 0..max {
            if let Some(done) = self.events.iter().find_map(|e| match e {
                AxisEvent::Done {
                    op,
                    outcome,
                    detail,
                    ..
                } if *op == id => Some((*outcome, detail.clone())),
                _ => None,
            }) {
                return done;
            }
            self.cycles(1);
        }
        panic!("op {id} not done after {max} cycles: {:?}", self.events);
    }

    fn enabled(cfg: CansmcAxisConfig) -> Self {
        let mut rig = Rig::new(cfg);
        let id = rig.command(AxisCommand::Enable).unwrap();
        assert_eq!(rig.until_done(id, 10).0, Outcome::Completed);
        rig
    }
}

fn cfg() -> CansmcAxisConfig {
    CansmcAxisConfig::example(1000.0, CYCLE)
}

fn mv(target: f64) -> AxisCommand {
    AxisCommand::Move {
        target,
        relative: false,
        velocity: None,
        acceleration: None,
    }
}

#[test]
fn commands_before_feedback_or_when_disabled_are_refused_clearly() {
    let mut axis = CansmcAxis::new(cfg());
    let mut ev = Vec::new();
    let e = axis.command(mv(1.0), Duration::ZERO, &mut ev).unwrap_err();
    assert!(e.to_string().contains("no drive telegram"), "{e}");
    let mut rig = Rig::new(cfg());
    let e = rig.command(mv(1.0)).unwrap_err();
    assert!(e.to_string().contains("not enabled"), "{e}");
    let mut rig = Rig::enabled(cfg());
    assert!(matches!(
        rig.command(mv(5000.0)),
        Err(CommandError::BeyondSoftLimit(_))
    ));
    assert!(matches!(
        rig.command(AxisCommand::Move {
            target: 1.0,
            relative: false,
            velocity: Some(-1.0),
            acceleration: None
        }),
        Err(CommandError::BadValue(_))
    ));
}

#[test]
fn enable_sets_the_mdtcw_bit_and_holds_the_actual_position() {
    let mut rig = Rig::new(cfg());
    rig.servo.position = 12_345;
    rig.cycles(1);
    let id = rig.command(AxisCommand::Enable).unwrap();
    let (outcome, _) = rig.until_done(id, 10);
    assert_eq!(outcome, Outcome::Completed);
    assert_eq!(rig.servo.position, 12_345, "enabling must not jump");
    let out = rig
        .axis
        .on_cycle(rig.now, rig.servo.input(), &mut rig.events);
    assert!(out.control.enable && !out.control.halt);
    assert_eq!(out.command, Command::Position(12_345));
    let snap = rig.axis.snapshot();
    assert_eq!(snap.state, Some(DriveState::OperationEnabled));
    assert_eq!(snap.mode, MODE_CYCLIC_POSITION);
    assert!((snap.position - 12.345).abs() < 1e-9);
}

#[test]
fn a_move_interpolates_a_trapezoid_every_cycle_and_completes_in_position() {
    let mut rig = Rig::enabled(cfg());
    let id = rig.command(mv(10.0)).unwrap();
    let mut positions = Vec::new();
    for _ in 0..400 {
        rig.cycles(1);
        positions.push(rig.servo.position);
        if rig
            .events
            .iter()
            .any(|e| matches!(e, AxisEvent::Done { op, .. } if *op == id))
        {
            break;
        }
    }
    let (outcome, detail) = rig.until_done(id, 1);
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    assert_eq!(rig.servo.position, 10_000);
    // 50 mm/s default velocity: at most 0.1 mm (100 counts) per 2 ms.
    let steps: Vec<i32> = positions.windows(2).map(|w| w[1] - w[0]).collect();
    assert!(steps.iter().all(|s| (0..=100).contains(s)), "{steps:?}");
    assert!(steps.contains(&100), "reaches cruise velocity");
}

#[test]
fn a_jog_runs_while_renewed_and_the_dead_man_stops_it() {
    let mut rig = Rig::enabled(cfg());
    let mut id = rig
        .command(AxisCommand::Jog {
            velocity: 20.0,
            acceleration: None,
        })
        .unwrap();
    for _ in 0..5 {
        rig.cycles(100); // 200 ms
        let previous = id;
        id = rig
            .command(AxisCommand::Jog {
                velocity: 20.0,
                acceleration: None,
            })
            .unwrap();
        // A repetition is a command of its own, acknowledged at once (a
        // caller without wait gets its answer); the previous one ends.
        assert!(rig.events.contains(&AxisEvent::Accepted { op: id }));
        assert_eq!(rig.until_done(previous, 1).0, Outcome::Superseded);
    }
    assert_eq!(rig.axis.activity(), Activity::Jogging);
    let moving_at = rig.servo.position;
    assert!(moving_at > 15_000, "about 1 s at 20 mm/s: {moving_at}");
    let (outcome, detail) = rig.until_done(id, 1000);
    assert_eq!(outcome, Outcome::Stopped);
    assert!(detail.contains("dead-man"), "{detail}");
    let rest = rig.servo.position;
    rig.cycles(10);
    assert_eq!(rig.servo.position, rest, "at rest after the dead-man");
}

#[test]
fn stop_ramps_a_move_down_without_a_jump() {
    let mut rig = Rig::enabled(cfg());
    let id = rig.command(mv(100.0)).unwrap();
    rig.cycles(200);
    let stop = rig.command(AxisCommand::Stop).unwrap();
    let (outcome, _) = rig.until_done(id, 1);
    assert_eq!(outcome, Outcome::Stopped);
    let mut last = rig.servo.position;
    let mut max_step = 0;
    for _ in 0..500 {
        rig.cycles(1);
        max_step = max_step.max(rig.servo.position - last);
        last = rig.servo.position;
    }
    assert_eq!(rig.until_done(stop, 1).0, Outcome::Completed);
    assert!(max_step <= 100, "no faster than the move: {max_step}");
    assert!(rig.servo.position < 100_000, "stopped before the target");
    assert_eq!(rig.axis.activity(), Activity::Idle);
}

#[test]
fn homing_hands_over_to_the_slave_and_returns_to_position_mode() {
    let mut rig = Rig::enabled(cfg());
    rig.servo.position = 550;
    rig.cycles(1);
    let id = rig.command(AxisCommand::Home).unwrap();
    rig.cycles(2);
    assert_eq!(rig.axis.snapshot().mode, MODE_HOMING);
    assert_eq!(
        rig.servo.pending.unwrap().command,
        Command::Homing { method: 1 }
    );
    let (outcome, detail) = rig.until_done(id, 50);
    assert_eq!(outcome, Outcome::Completed, "{detail}");
    assert!(rig.axis.snapshot().homed);
    rig.cycles(2);
    assert_eq!(rig.servo.pending.unwrap().command, Command::Position(0));
}

#[test]
fn a_fault_ends_the_move_and_a_reset_pulses_the_edge() {
    let mut rig = Rig::enabled(cfg());
    let id = rig.command(mv(50.0)).unwrap();
    rig.cycles(50);
    rig.servo.fault = true;
    rig.servo.following_error = true;
    rig.cycles(2);
    let (outcome, detail) = rig.until_done(id, 1);
    assert_eq!(outcome, Outcome::Fault);
    assert!(detail.contains("following error"), "{detail}");
    assert!(rig.events.contains(&AxisEvent::Fault {
        code: 0x8611,
        text: "following error over limit (DTSW bit 5)".into()
    }));
    assert!(rig.command(mv(1.0)).is_err());
    let reset = rig.command(AxisCommand::ResetFault).unwrap();
    // The reset bit is set for exactly one cycle.
    rig.cycles(1);
    assert!(rig.servo.pending.unwrap().control.fault_reset);
    rig.cycles(1);
    assert!(!rig.servo.pending.unwrap().control.fault_reset);
    assert_eq!(rig.until_done(reset, 10).0, Outcome::Completed);
    assert!(rig.events.contains(&AxisEvent::Fault {
        code: 0,
        text: String::new()
    }));
}

#[test]
fn a_lost_slave_faults_the_axis_and_refuses_commands_until_back() {
    let mut rig = Rig::enabled(cfg());
    let id = rig
        .command(AxisCommand::Jog {
            velocity: 5.0,
            acceleration: None,
        })
        .unwrap();
    rig.cycles(5);
    rig.axis.on_slave_lost("3 DTs missed", &mut rig.events);
    assert_eq!(rig.until_done(id, 1).0, Outcome::Fault);
    let e = rig.command(AxisCommand::Enable).unwrap_err();
    assert!(e.to_string().contains("slave is lost"), "{e}");
    assert!(
        rig.command(AxisCommand::Stop).is_ok(),
        "stops are never refused"
    );
    assert_eq!(
        rig.axis.snapshot().fault,
        Some((0, "slave lost: 3 DTs missed".into()))
    );
    rig.axis.on_slave_back(&mut rig.events);
    rig.cycles(2);
    // Back, but disabled by the loss: the axis says why until the enable.
    let (_, text) = rig
        .axis
        .snapshot()
        .fault
        .expect("the reason it is disabled");
    assert!(
        text.contains("disabled because the slave was lost (3 DTs missed)"),
        "{text}"
    );
    assert!(matches!(
        rig.events.last(),
        Some(AxisEvent::Fault { text, .. }) if text.contains("disabled because")
    ));
    let enable = rig.command(AxisCommand::Enable).unwrap();
    assert!(rig.events.contains(&AxisEvent::Fault {
        code: 0,
        text: String::new()
    }));
    assert_eq!(rig.until_done(enable, 10).0, Outcome::Completed);
    assert!(rig.axis.snapshot().fault.is_none());
}

#[test]
fn a_geared_axis_follows_its_source_with_one_cycle_of_lag() {
    let mut c = cfg();
    c.drive.gear = Some(Gear {
        source: 3,
        ratio: 0.5,
    });
    let mut rig = Rig::new(c);
    rig.servo.position = 1_000;
    rig.servo.encoder = 40_000;
    rig.cycles(1);
    let id = rig.command(AxisCommand::Enable).unwrap();
    rig.until_done(id, 10);
    assert_eq!(rig.axis.activity(), Activity::Moving);
    rig.cycles(2);
    assert_eq!(rig.servo.position, 1_000, "engaging does not jump");
    // The source turns 20 counts per cycle.
    for _ in 0..100 {
        rig.servo.encoder += 20;
        rig.cycles(1);
        // The command of this cycle used the count sampled at this MST;
        // the servo applies it at the next MST.
        let commanded = match rig.servo.pending.unwrap().command {
            Command::Position(p) => p,
            other => panic!("{other:?}"),
        };
        assert_eq!(commanded, 1_000 + (rig.servo.encoder - 40_000) / 2);
    }
    assert!(rig.command(mv(1.0)).is_err(), "a geared axis refuses moves");
    let stop = rig.command(AxisCommand::Stop).unwrap();
    assert_eq!(rig.until_done(stop, 100).0, Outcome::Completed);
    assert!(!rig.axis.is_geared());
    let before = rig.servo.position;
    rig.servo.encoder += 10_000;
    rig.cycles(3);
    assert_eq!(rig.servo.position, before, "disengaged after the stop");
}

#[test]
fn a_jog_stops_at_the_soft_limit() {
    let mut c = cfg();
    c.motion.max_position = Some(2.0);
    let mut rig = Rig::enabled(c);
    rig.command(AxisCommand::Jog {
        velocity: 50.0,
        acceleration: None,
    })
    .unwrap();
    for _ in 0..10 {
        rig.cycles(20);
        rig.command(AxisCommand::Jog {
            velocity: 50.0,
            acceleration: None,
        })
        .unwrap();
    }
    assert!(rig.servo.position <= 2_000, "{}", rig.servo.position);
    assert!(rig.servo.position > 1_900, "{}", rig.servo.position);
}

#[test]
fn a_velocity_mode_jog_runs_in_the_slave_and_resumes_position_control_where_it_stopped() {
    let mut c = cfg();
    c.drive.jog_mode = JogMode::SlaveVelocity;
    let mut rig = Rig::enabled(c);
    let start = rig.servo.position;
    // 10 mm/s = 10 000 counts/s = 1 rev/s = 60 r/min = 60 000 × 0.001 r/min.
    let id = rig
        .command(AxisCommand::Jog {
            velocity: 10.0,
            acceleration: None,
        })
        .unwrap();
    rig.cycles(2);
    assert_eq!(
        rig.servo.pending.unwrap().command,
        Command::Velocity(60_000)
    );
    rig.cycles(100);
    let moved = rig.servo.position - start;
    assert!(
        (1_900..=2_100).contains(&moved),
        "about 200 ms at 10 mm/s: {moved}"
    );
    // The position is estimated from the velocity feedback meanwhile.
    let est = rig.axis.snapshot().position;
    let real = f64::from(rig.servo.position) / 1000.0;
    assert!((est - real).abs() < 0.05, "estimate {est} vs {real}");
    // The dead-man brakes (velocity 0), reads the encoder, then holds
    // exactly there with a position set-point.
    let (outcome, detail) = rig.until_done(id, 1000);
    assert_eq!(outcome, Outcome::Stopped, "{detail}");
    assert!(detail.contains("dead-man"), "{detail}");
    rig.cycles(2);
    assert_eq!(
        rig.servo.pending.unwrap().command,
        Command::Position(rig.servo.position)
    );
    assert_eq!(rig.axis.activity(), Activity::Idle);
    let at = rig.servo.position;
    rig.cycles(10);
    assert_eq!(rig.servo.position, at, "holding");
    // A move afterwards starts from the true position.
    let id = rig.command(mv(f64::from(at) / 1000.0 + 1.0)).unwrap();
    assert_eq!(rig.until_done(id, 500).0, Outcome::Completed);
    assert_eq!(rig.servo.position, at + 1000);
}

/// Issue 26, item 1: a stop brakes at the axis's stop deceleration (the
/// maximum acceleration by default), not at the interrupted motion's: a
/// gentle move (20 mm/s, 10 mm/s²) stopped after 3 s comes to rest within
/// v²/(2·a_stop) plus one cycle's travel, for Stop, QuickStop and a jog's
/// dead-man. At the motion's own 10 mm/s² it would be 20 mm.
#[test]
fn every_stop_brakes_at_least_at_the_stop_deceleration() {
    let cycles_of = |d: Duration| (d.as_micros() / CYCLE.as_micros()) as usize;
    for by in ["stop", "quick stop", "dead-man"] {
        let cfg = cfg();
        let a_stop = if by == "quick stop" {
            cfg.motion.quick_stop_deceleration
        } else {
            cfg.motion.stop_deceleration
        };
        let mut rig = Rig::enabled(cfg);
        let op = if by == "dead-man" {
            let jog = AxisCommand::Jog {
                velocity: 20.0,
                acceleration: Some(10.0),
            };
            let mut op = rig.command(jog).unwrap();
            for _ in 0..15 {
                rig.cycles(cycles_of(Duration::from_millis(200)));
                op = rig.command(jog).unwrap();
            }
            rig.cycles(cycles_of(Duration::from_millis(500)));
            op
        } else {
            rig.command(AxisCommand::Move {
                target: 500.0,
                relative: false,
                velocity: Some(20.0),
                acceleration: Some(10.0),
            })
            .unwrap();
            rig.cycles(cycles_of(Duration::from_secs(3)));
            rig.command(if by == "stop" {
                AxisCommand::Stop
            } else {
                AxisCommand::QuickStop
            })
            .unwrap()
        };
        let p0 = f64::from(rig.servo.position) / 1000.0;
        let v = rig.axis.snapshot().velocity;
        assert!((v - 20.0).abs() < 0.5, "{by}: at speed ({v})");
        rig.until_done(op, 2000);
        rig.cycles(10);
        let d = (f64::from(rig.servo.position) / 1000.0 - p0).abs();
        let bound = v * v / (2.0 * a_stop) + v * CYCLE.as_secs_f64() + 0.01;
        assert!(
            d <= bound,
            "{by}: stopped in {d:.3} mm, more than {bound:.3} mm"
        );
    }
}

// ------------------------------------------------------ set-point streams

use crate::setpoint_stream::{AxisLimits, PlayerConfig, PlayerState, SetpointPlayer, StreamPoint};

fn player_for(rig: &Rig) -> SetpointPlayer {
    let m = &rig.axis.config().motion;
    let limits = AxisLimits {
        max_jerk: None,
        max_velocity: m.max_velocity,
        max_acceleration: m.max_acceleration,
        stop_deceleration: m.stop_deceleration,
        min_position: m.min_position,
        max_position: m.max_position,
    };
    let mut cfg = PlayerConfig::new(CYCLE, Duration::from_millis(10));
    cfg.extrapolate = Duration::from_millis(10);
    SetpointPlayer::new(cfg, vec![limits], vec![rig.axis.demand()])
}

/// One cycle of a streamed axis: the player's set-point, then the cycle.
fn stream_cycle(rig: &mut Rig, player: &mut SetpointPlayer) -> PlayerState {
    let c = player.next(rig.now);
    rig.axis
        .stream_setpoint(c.positions[0], player.velocity()[0]);
    rig.cycles(1);
    c.state
}

/// Pushes the points of `path` every 1 ms of client time up to `until_ms`,
/// each arrived on time (client time 0 at `start`).
fn feed(player: &mut SetpointPlayer, start: Duration, until_ms: u64) {
    for k in 0..=until_ms {
        player
            .push(
                StreamPoint {
                    feed_forward: None,
                    t_us: k * 1000,
                    values: vec![path(k as f64 / 1000.0)],
                },
                start + Duration::from_millis(k),
            )
            .unwrap();
    }
}

/// A smooth path from 0: 5 mm along a cosine blend over 1 s.
fn path(t: f64) -> f64 {
    let s = t.clamp(0.0, 1.0);
    2.5 * (1.0 - (std::f64::consts::PI * s).cos())
}

#[test]
fn a_streamed_axis_follows_the_players_set_points_and_takes_no_other_command() {
    let mut rig = Rig::enabled(cfg());
    let mut player = player_for(&rig);
    rig.axis.start_stream(rig.axis.demand()).unwrap();
    assert!(rig.axis.is_streamed());
    assert_eq!(rig.axis.activity(), Activity::Moving);
    let e = rig.command(mv(1.0)).unwrap_err();
    assert!(e.to_string().contains("set-point stream"), "{e}");
    for refused in [
        AxisCommand::Jog {
            velocity: 1.0,
            acceleration: None,
        },
        AxisCommand::Home,
        AxisCommand::Enable,
        AxisCommand::Disable,
    ] {
        assert!(matches!(rig.command(refused), Err(CommandError::Busy(_))));
    }
    feed(&mut player, rig.now, 1000);
    let mut max_error: f64 = 0.0;
    for _ in 0..700 {
        stream_cycle(&mut rig, &mut player);
        // The axis sends the player's set-point of the cycle.
        max_error = max_error.max((rig.axis.demand() - player.position()[0]).abs());
    }
    assert!(max_error < 1e-3, "demand off the player: {max_error}");
    let played = player.position()[0];
    assert!(played > 1.0, "the path advanced: {played}");
    // The servo follows a cycle behind.
    let actual = f64::from(rig.servo.position) / 1000.0;
    assert!((actual - played).abs() < 0.1, "{actual} vs {played}");
}

#[test]
fn a_stop_ends_the_streamed_motion_at_once_and_ramps_to_rest() {
    let mut rig = Rig::enabled(cfg());
    let mut player = player_for(&rig);
    rig.axis.start_stream(rig.axis.demand()).unwrap();
    feed(&mut player, rig.now, 400);
    for _ in 0..200 {
        stream_cycle(&mut rig, &mut player);
    }
    let v = rig.axis.snapshot().velocity;
    assert!(v > 1.0, "moving: {v}");
    let id = rig.command(AxisCommand::Stop).unwrap();
    assert!(!rig.axis.is_streamed(), "a stop ends the streamed motion");
    // Set-points from a stream that has not heard of it yet are ignored.
    let dt = CYCLE.as_secs_f64();
    let decel = rig.axis.config().motion.stop_deceleration;
    let mut previous = rig.axis.demand();
    let mut previous_v = player.velocity()[0];
    let mut worst_dv: f64 = 0.0;
    for _ in 0..100 {
        rig.axis.stream_setpoint(100.0, 0.0);
        rig.cycles(1);
        let d = rig.axis.demand();
        let step = (d - previous) / dt;
        worst_dv = worst_dv.max((step - previous_v).abs() / dt);
        previous_v = step;
        previous = d;
    }
    assert_eq!(rig.until_done(id, 100).0, Outcome::Completed);
    assert!(
        rig.axis.demand() < 10.0,
        "never jumped to the stale set-point"
    );
    assert!(
        worst_dv <= decel * 1.05,
        "braking at {worst_dv} over the stop deceleration {decel}"
    );
    assert_eq!(rig.axis.activity(), Activity::Idle);
}

#[test]
fn an_underrun_ramps_the_streamed_axis_to_rest_within_the_stop_deceleration() {
    let mut rig = Rig::enabled(cfg());
    let mut player = player_for(&rig);
    rig.axis.start_stream(rig.axis.demand()).unwrap();
    // Points for 0.3 s only: then the player runs dry.
    feed(&mut player, rig.now, 300);
    let decel = rig.axis.config().motion.stop_deceleration;
    let dt = CYCLE.as_secs_f64();
    let mut previous = rig.axis.demand();
    let mut previous_v = 0.0;
    let mut worst_dv: f64 = 0.0;
    let mut underrun = false;
    let mut at_rest = false;
    for _ in 0..600 {
        let c = player.next(rig.now);
        underrun |= c.event == Some(crate::setpoint_stream::PlayerEvent::Underrun);
        at_rest |= c.event == Some(crate::setpoint_stream::PlayerEvent::AtRest);
        rig.axis
            .stream_setpoint(c.positions[0], player.velocity()[0]);
        rig.cycles(1);
        let d = rig.axis.demand();
        let v = (d - previous) / dt;
        if underrun {
            worst_dv = worst_dv.max((v - previous_v).abs() / dt);
        }
        previous_v = v;
        previous = d;
    }
    assert!(
        underrun && at_rest,
        "underrun {underrun}, at rest {at_rest}"
    );
    assert!(
        worst_dv <= decel * 1.05,
        "braking at {worst_dv} over the stop deceleration {decel}"
    );
    assert_eq!(previous_v, 0.0, "at rest");
    rig.axis.end_stream();
    assert!(!rig.axis.is_streamed());
    assert_eq!(rig.axis.activity(), Activity::Idle);
    // Commands are taken again.
    let id = rig.command(mv(0.0)).unwrap();
    assert_eq!(rig.until_done(id, 2000).0, Outcome::Completed);
}

#[test]
fn a_fault_or_a_lost_slave_ends_the_streamed_motion() {
    let mut rig = Rig::enabled(cfg());
    rig.axis.start_stream(rig.axis.demand()).unwrap();
    rig.servo.fault = true;
    rig.cycles(2);
    assert!(!rig.axis.is_streamed());
    let mut rig = Rig::enabled(cfg());
    rig.axis.start_stream(rig.axis.demand()).unwrap();
    let mut ev = Vec::new();
    rig.axis.on_slave_lost("test", &mut ev);
    assert!(!rig.axis.is_streamed());
    // A stream starts only where the axis stands.
    let mut rig = Rig::enabled(cfg());
    let e = rig.axis.start_stream(rig.axis.demand() + 1.0).unwrap_err();
    assert!(e.to_string().contains("moved since"), "{e}");
}

/// An axis at rest has the same state in every cycle although each DT
/// echoes a new cycle counter (DTSW bits 12-15): the echo says the
/// telegram is fresh, not how the drive is, so a watcher of changes
/// (StreamAxisState with changes_only) hears nothing from an axis at rest.
#[test]
fn an_axis_at_rest_has_the_same_state_in_every_cycle_whatever_the_counter_echo() {
    let mut rig = Rig::enabled(cfg());
    rig.cycles(3);
    let first = rig.axis.snapshot();
    assert_eq!(
        first.statusword & 0x000F,
        0b1011,
        "ready, enabled, in position"
    );
    for _ in 0..20 {
        rig.cycles(1);
        assert_eq!(rig.axis.snapshot(), first);
    }
}
