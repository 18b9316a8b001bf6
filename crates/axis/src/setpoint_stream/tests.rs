use super::*;

const MS: Duration = Duration::from_millis(1);

fn limits(max: Option<f64>) -> AxisLimits {
    AxisLimits {
        max_jerk: None,
        max_velocity: 100.0,
        max_acceleration: 1000.0,
        stop_deceleration: 1000.0,
        min_position: max.map(|m| -m),
        max_position: max,
    }
}

fn player(axes: usize, depth_ms: u64) -> SetpointPlayer {
    SetpointPlayer::new(
        PlayerConfig::new(MS, Duration::from_millis(depth_ms)),
        vec![limits(Some(500.0)); axes],
        vec![0.0; axes],
    )
}

/// A circle of radius `r` mm at `omega` rad/s on X/Y, starting at rest at
/// the origin (the centre is at (-r, 0)): position at `t` s, with a
/// smooth start (the angle's rate ramps up over the first second).
fn circle(r: f64, omega: f64, t: f64) -> [f64; 2] {
    let phase = if t < 1.0 {
        omega * t * t / 2.0
    } else {
        omega * (t - 0.5)
    };
    [r * phase.cos() - r, r * phase.sin()]
}

#[test]
fn a_circle_at_one_kilohertz_plays_every_point_after_the_buffer() {
    let mut p = player(2, 20);
    // The client's clock starts at 5 s; the network takes 3 ms.
    let client0 = 5_000_000u64;
    let mut played = Vec::new();
    for k in 0..3000u64 {
        let now = MS * (k as u32);
        let t = k as f64 / 1000.0;
        let pos = circle(10.0, 2.0, t);
        if now >= 3 * MS {
            let sent = k - 3;
            let pos = circle(10.0, 2.0, sent as f64 / 1000.0);
            p.push(
                StreamPoint {
                    feed_forward: None,
                    t_us: client0 + sent * 1000,
                    values: pos.to_vec(),
                },
                now,
            )
            .expect("a point inside the limits");
        }
        let out = p.next(now);
        played.push(out.positions.clone());
        let _ = pos;
    }
    let c = p.counters();
    assert_eq!(c.refused, 0);
    assert_eq!(c.late, 0);
    assert_eq!(c.underruns, 0);
    assert_eq!(c.received, 2997);
    // Played 23 ms behind the client (3 ms network, 20 ms buffer).
    let k = 2500usize;
    let expected = circle(10.0, 2.0, (k - 23) as f64 / 1000.0);
    assert!(
        (played[k][0] - expected[0]).abs() < 1e-6,
        "{:?} {expected:?}",
        played[k]
    );
    assert!((played[k][1] - expected[1]).abs() < 1e-6);
    assert_eq!(p.clock_offset_us(), Some(3000 - 5_000_000));
    assert!(
        p.level(MS * 2999) >= Duration::from_millis(19),
        "{:?}",
        p.level(MS * 2999)
    );
}

#[test]
fn points_beyond_the_limits_are_refused_with_the_reason() {
    let mut p = player(1, 10);
    let at = |ms: u64| Duration::from_millis(ms);
    let pt = |t_ms: u64, x: f64| StreamPoint {
        feed_forward: None,
        t_us: t_ms * 1000,
        values: vec![x],
    };
    // Not where the axis stands (0).
    assert!(matches!(
        p.push(pt(0, 5.0), at(0)),
        Err(PointRefused::NotWhereTheAxisStands { .. })
    ));
    p.push(pt(0, 0.0), at(0)).unwrap();
    // 1 mm in 1 ms from rest: 1000 mm/s, beyond 100 mm/s.
    assert!(matches!(
        p.push(pt(1, 1.0), at(1)),
        Err(PointRefused::TooFast { .. })
    ));
    // 0.05 mm in 1 ms from rest: 50 mm/s reached in 1 ms, 50000 mm/s².
    assert!(matches!(
        p.push(pt(1, 0.05), at(1)),
        Err(PointRefused::TooHardAcceleration { .. })
    ));
    // 0.0005 mm in 1 ms: 0.5 mm/s, 500 mm/s²: fine.
    p.push(pt(1, 0.0005), at(1)).unwrap();
    // Same time again; backwards.
    assert!(matches!(
        p.push(pt(1, 0.001), at(2)),
        Err(PointRefused::NotAfterPrevious { .. })
    ));
    assert!(matches!(
        p.push(pt(0, 0.001), at(2)),
        Err(PointRefused::NotAfterPrevious { .. })
    ));
    assert!(matches!(
        p.push(
            StreamPoint {
                feed_forward: None,
                t_us: 2000,
                values: vec![f64::NAN]
            },
            at(2)
        ),
        Err(PointRefused::NotFinite { .. })
    ));
    assert!(matches!(
        p.push(
            StreamPoint {
                feed_forward: None,
                t_us: 2000,
                values: vec![0.0, 0.0]
            },
            at(2)
        ),
        Err(PointRefused::Dimension { got: 2, want: 1 })
    ));
    let c = p.counters();
    assert_eq!((c.received, c.accepted, c.refused), (9, 2, 7));
}

#[test]
fn a_point_that_could_not_stop_inside_the_soft_limits_is_refused() {
    // Soft limit at 500; at 100 mm/s the stop takes 5 mm (1000 mm/s²).
    let mut p = SetpointPlayer::new(
        PlayerConfig::new(MS, Duration::from_millis(10)),
        vec![limits(Some(500.0))],
        vec![490.0],
    );
    p.push(
        StreamPoint {
            feed_forward: None,
            t_us: 0,
            values: vec![490.0],
        },
        Duration::ZERO,
    )
    .unwrap();
    // Accelerate at 1000 mm/s² (within the limit) towards the limit.
    let mut x = 490.0;
    let mut v = 0.0;
    let mut refused = None;
    for k in 1..200u64 {
        v = f64::min(v + 1.0, 100.0);
        x += v / 1000.0;
        if let Err(e) = p.push(
            StreamPoint {
                feed_forward: None,
                t_us: k * 1000,
                values: vec![x],
            },
            MS * k as u32,
        ) {
            refused = Some((x, v, e));
            break;
        }
    }
    let (x, v, e) = refused.expect("refused before the limit");
    assert!(matches!(e, PointRefused::BeyondSoftLimit { .. }), "{e}");
    assert!(x < 500.0 && x + v * v / 2000.0 > 500.0, "{x} at {v}");
}

/// The client stops sending in the middle of the circle: the player goes
/// on along the last segment for its extrapolation time, then brings both
/// axes to rest together, each within its stop deceleration; a stream
/// resumed where they stand plays again.
#[test]
fn an_underrun_ramps_both_axes_to_rest_together_and_the_stream_resumes() {
    let mut p = player(2, 20);
    let mut last = vec![0.0, 0.0];
    let mut prev_v = [0.0f64; 2];
    let mut events = Vec::new();
    let mut stopped_at = None;
    for k in 0..4000u64 {
        let now = MS * (k as u32);
        if k < 2000 {
            let pos = circle(10.0, 2.0, k as f64 / 1000.0);
            p.push(
                StreamPoint {
                    feed_forward: None,
                    t_us: k * 1000,
                    values: pos.to_vec(),
                },
                now,
            )
            .unwrap();
        }
        let out = p.next(now);
        for axis in 0..2 {
            let v = (out.positions[axis] - last[axis]) * 1000.0;
            assert!(
                v.abs() <= 100.0 * 1.002,
                "cycle {k}: axis {axis} at {v} mm/s"
            );
            let a = (v - prev_v[axis]) * 1000.0;
            assert!(
                a.abs() <= 1000.0 * 1.01 + 1e-6,
                "cycle {k}: axis {axis} at {a} mm/s²"
            );
            prev_v[axis] = v;
        }
        last = out.positions.clone();
        if let Some(e) = out.event {
            events.push((k, e));
            if e == PlayerEvent::AtRest {
                stopped_at = Some((k, out.positions.clone()));
            }
        }
    }
    assert_eq!(
        events.iter().map(|e| e.1).collect::<Vec<_>>(),
        [PlayerEvent::Underrun, PlayerEvent::AtRest]
    );
    // The last point plays at 1999 + 20 ms; 20 ms of extrapolation; then
    // the ramp: the circle's speed is 20 mm/s, 20 ms at 1000 mm/s².
    let (underrun, _) = events[0];
    assert!((2038..=2042).contains(&underrun), "underrun at {underrun}");
    let (rest, standing) = stopped_at.unwrap();
    assert!(
        rest - underrun <= 22,
        "at rest {rest} after the underrun at {underrun}"
    );
    assert_eq!(p.state(), PlayerState::Waiting);
    assert_eq!(p.counters().underruns, 1);
    // Resumed from where they stand.
    let t0 = 10_000_000u64;
    p.push(
        StreamPoint {
            feed_forward: None,
            t_us: t0,
            values: standing.clone(),
        },
        MS * 4000,
    )
    .unwrap();
    let mut x = standing[0];
    for k in 1..100u64 {
        x += 0.0001 * k as f64 / 100.0;
        p.push(
            StreamPoint {
                feed_forward: None,
                t_us: t0 + k * 1000,
                values: vec![x, standing[1]],
            },
            MS * (4000 + k as u32),
        )
        .unwrap();
        p.next(MS * (4000 + k as u32));
    }
    assert_eq!(p.state(), PlayerState::Playing);
}

#[test]
fn a_stop_brings_the_axes_to_rest_and_drops_what_is_buffered() {
    let mut p = player(1, 20);
    let mut x = 0.0;
    let mut v: f64 = 0.0;
    for k in 0..500u64 {
        if k > 0 {
            v = (v + 1.0).min(50.0);
            x += v / 1000.0;
        }
        p.push(
            StreamPoint {
                feed_forward: None,
                t_us: k * 1000,
                values: vec![x],
            },
            MS * k as u32,
        )
        .unwrap();
        p.next(MS * k as u32);
    }
    p.stop(MS * 500);
    let mut k = 500;
    let mut out;
    loop {
        k += 1;
        out = p.next(MS * k);
        if out.event == Some(PlayerEvent::AtRest) {
            break;
        }
        assert!(k < 600, "not at rest");
    }
    // 50 mm/s at 1000 mm/s²: 50 ms.
    assert!((548..=553).contains(&k), "at rest at {k}");
    let c = p.counters();
    assert_eq!(c.accepted, c.played + c.late + c.dropped);
    assert!(c.dropped >= 19, "{c:?}");
}

/// A client path whose last point falls between two cycles: the first
/// cycle past it plays the path to that point (and on along its last
/// segment), not on from where the previous cycle was along the last
/// segment's velocity, which would cut short the rest of the path.
#[test]
fn the_first_cycle_past_the_last_point_plays_the_path_to_it() {
    let cycle = 10 * MS;
    let mut p = SetpointPlayer::new(
        PlayerConfig::new(cycle, 20 * MS),
        vec![limits(Some(500.0))],
        vec![0.0],
    );
    // 1 mm in 100 ms at rising then falling speed, a point per ms, each
    // sent at its time; cycles at 3, 13, 23, … ms.
    let path = |k: u64| 0.5 - 0.5 * (std::f64::consts::PI * k as f64 / 100.0).cos();
    let mut last = Vec::new();
    for ms in 0..=130u64 {
        if ms <= 100 {
            p.push(
                StreamPoint {
                    feed_forward: None,
                    t_us: ms * 1000,
                    values: vec![path(ms)],
                },
                MS * ms as u32,
            )
            .unwrap();
        }
        if ms % 10 == 3 {
            last.push(p.next(MS * ms as u32).positions[0]);
        }
    }
    // The playout is 20 ms behind the client: the cycle at 113 ms plays
    // client time 93 ms, the one at 123 ms is 3 ms past the last point.
    let at_93 = last[last.len() - 2];
    assert!((at_93 - path(93)).abs() < 1e-9, "{at_93}");
    let past = last[last.len() - 1];
    assert!((past - 1.0).abs() < 1e-3, "{past}: the path ends at 1");
    assert_eq!(p.counters().played, 101);
}

/// Random streams: random client periods, network delays with jitter,
/// stalls and bursts, paths that sometimes break the limits, stops.
/// Whatever comes, no played step is faster than the maximum velocity,
/// none accelerates beyond what the accepted points allow, no position
/// leaves the soft limits, every underrun ends at rest, and the counters
/// add up.
#[test]
fn random_streams_never_jump_nor_leave_the_limits() {
    for seed in 1..=random_cases() {
        random_stream(seed);
    }
}

/// Runs of each random stream test: `SETPOINT_STREAM_CASES`, else 60 (a
/// debug build plays about ten runs a second; thousands are a release
/// build's or a night's run, e.g. `SETPOINT_STREAM_CASES=3000 cargo test
/// --release -p cangate-axis --lib random_`).
fn random_cases() -> u64 {
    std::env::var("SETPOINT_STREAM_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(60)
}

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn f64(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: u64, hi: u64) -> u64 {
        lo + self.next() % (hi - lo)
    }
}

fn random_stream(seed: u64) {
    let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
    let cycle = MS;
    let depth = Duration::from_millis(rng.range(2, 30));
    let lim = AxisLimits {
        max_jerk: None,
        max_velocity: 50.0,
        max_acceleration: 500.0,
        stop_deceleration: 800.0,
        min_position: Some(-20.0),
        max_position: Some(20.0),
    };
    let mut p = SetpointPlayer::new(PlayerConfig::new(cycle, depth), vec![lim; 2], vec![0.0; 2]);
    let period_us = rng.range(500, 10_000);
    // The client's path: a target velocity that changes now and then,
    // followed within the acceleration limit (sometimes beyond it, or
    // beyond the velocity limit, on purpose).
    let mut pos = [0.0f64; 2];
    let mut vel = [0.0f64; 2];
    let mut target = [0.0f64; 2];
    let mut client_t = rng.range(0, 1_000_000_000);
    let mut next_send = Duration::ZERO;
    // Points in flight: (arrival, point).
    let mut flight: Vec<(Duration, StreamPoint)> = Vec::new();
    let mut stalled_until = Duration::ZERO;
    let mut last = vec![0.0; 2];
    let mut prev_v = [0.0f64; 2];
    let mut first = true;
    let mut stopping_ms = None;
    let end = 20_000u32;
    for k in 0..end {
        let now = cycle * k;
        // The client.
        while next_send <= now && stopping_ms.is_none() {
            if rng.f64() < 0.01 {
                target = [(rng.f64() - 0.5) * 80.0, (rng.f64() - 0.5) * 80.0];
            }
            let dt = period_us as f64 / 1e6;
            let wild = rng.f64() < 0.002;
            for a in 0..2 {
                // Head back from the soft limits early enough.
                if pos[a].abs() > 12.0 && vel[a] * pos[a] > 0.0 {
                    target[a] = -pos[a].signum() * 10.0;
                }
                let dv = (target[a] - vel[a]).clamp(-450.0 * dt, 450.0 * dt);
                vel[a] += if wild { dv * 20.0 } else { dv };
                pos[a] += vel[a] * dt;
            }
            client_t += period_us;
            // The network: 1-3 ms, jitter up to 25 ms now and then, and
            // stalls of up to 200 ms that release a burst.
            let mut delay = Duration::from_micros(rng.range(1000, 3000));
            if rng.f64() < 0.05 {
                delay += Duration::from_micros(rng.range(0, 25_000));
            }
            if rng.f64() < 0.001 {
                stalled_until = now + Duration::from_millis(rng.range(10, 200));
            }
            let arrive = (now + delay).max(stalled_until);
            flight.push((
                arrive,
                StreamPoint {
                    feed_forward: None,
                    t_us: client_t,
                    values: pos.to_vec(),
                },
            ));
            next_send += Duration::from_micros(period_us);
        }
        // Deliveries in arrival order (a stall releases a burst in order).
        flight.sort_by_key(|(at, _)| *at);
        while flight.first().is_some_and(|(at, _)| *at <= now) {
            let (_, pt) = flight.remove(0);
            let r = p.push(pt.clone(), now);
            if first {
                if r.is_ok() {
                    first = false;
                }
            } else if let Err(PointRefused::NotWhereTheAxisStands { .. }) = r {
                // The client resumes where the player stands after an
                // underrun: its path restarts from there, at rest.
                pos = [p.position()[0], p.position()[1]];
                vel = [0.0; 2];
            }
        }
        if k == end - 2000 {
            p.stop(now);
            stopping_ms = Some(k);
        }
        let out = p.next(now);
        for a in 0..2 {
            let x = out.positions[a];
            assert!(
                (-20.0 - 1e-6..=20.0 + 1e-6).contains(&x),
                "seed {seed} cycle {k}: axis {a} at {x}"
            );
            let v = (x - last[a]) / cycle.as_secs_f64();
            assert!(
                v.abs() <= 50.0 * 1.002 + 1e-6,
                "seed {seed} cycle {k}: axis {a} at {v} mm/s"
            );
            // The velocity changes by at most the acceleration over a
            // cycle (the stop deceleration on the ramp to rest).
            let dv_max = 800.0 * cycle.as_secs_f64();
            let dv = v - prev_v[a];
            assert!(
                dv.abs() <= dv_max * (1.0 + 1e-6) + 1e-9,
                "seed {seed} cycle {k}: axis {a} velocity {} -> {v} (period {period_us} µs)",
                prev_v[a]
            );
            prev_v[a] = v;
        }
        last = out.positions.clone();
    }
    assert_eq!(
        p.state(),
        PlayerState::Waiting,
        "seed {seed}: at rest at the end"
    );
    let c = p.counters();
    assert_eq!(c.received, c.accepted + c.refused, "seed {seed}: {c:?}");
    assert_eq!(
        c.accepted,
        c.played + c.late + c.dropped,
        "seed {seed}: {c:?}"
    );
}

/// A velocity player (cyclic synchronous velocity) of `axes` axes with
/// [`limits`], standing at 0.
fn velocity_player(axes: usize, depth_ms: u64) -> SetpointPlayer {
    let mut cfg = PlayerConfig::new(MS, Duration::from_millis(depth_ms));
    cfg.kind = SetpointKind::Velocity;
    SetpointPlayer::new(cfg, vec![limits(Some(500.0)); axes], vec![0.0; axes])
}

fn velocity_point(t_us: u64, v: f64) -> StreamPoint {
    StreamPoint {
        feed_forward: None,
        t_us,
        values: vec![v],
    }
}

/// Velocities played: each cycle's velocity is the client's (after the
/// buffer), the path is their integral, and the end of the points holds
/// the last velocity for the extrapolation, then ramps it to 0 at the
/// stop deceleration.
#[test]
fn a_velocity_stream_plays_the_velocities_and_ramps_them_to_zero() {
    let mut p = velocity_player(1, 10);
    // 0 -> 50 mm/s at 500 mm/s² (0.1 s), then held to 0.3 s.
    let v = |s: f64| (500.0 * s).min(50.0);
    for k in 0..=300u64 {
        p.push(
            velocity_point(k * 1000, v(k as f64 / 1000.0)),
            MS * k as u32,
        )
        .unwrap();
        p.next(MS * k as u32);
    }
    // Played 10 ms behind: client time 0.29 s, 50 mm/s.
    assert!((p.velocity()[0] - 50.0).abs() < 1e-6, "{:?}", p.velocity());
    // Its integral: 2.5 mm over the ramp, 50 mm/s for 0.19 s.
    let x = p.position()[0];
    assert!((x - 12.0).abs() < 0.01, "{x}");
    let mut underrun = None;
    let mut rest = None;
    let mut last_v = p.velocity()[0];
    for k in 301..500u32 {
        let out = p.next(MS * k);
        let dv = p.velocity()[0] - last_v;
        assert!((-1.0 - 1e-9..=1e-9).contains(&dv), "cycle {k}: {dv}");
        last_v = p.velocity()[0];
        match out.event {
            Some(PlayerEvent::Underrun) => underrun = Some(k),
            Some(PlayerEvent::AtRest) => rest = Some(k),
            None => {}
        }
    }
    // The last point plays at 310 ms; 10 ms of extrapolation at 50 mm/s;
    // then 50 ms of ramp at 1000 mm/s².
    let (u, r) = (underrun.unwrap(), rest.unwrap());
    assert!((319..=322).contains(&u), "underrun at {u}");
    assert!((r - u) <= 51, "at rest {r} after the underrun at {u}");
    assert_eq!(p.velocity()[0], 0.0);
    assert_eq!(p.counters().underruns, 1);
}

/// A velocity point is refused when not from rest at the start, above
/// the maximum velocity, changing faster than the acceleration, or
/// predicting a position the axis could not stop before its soft limit.
#[test]
fn velocity_points_beyond_the_limits_are_refused() {
    let mut p = velocity_player(1, 10);
    assert!(matches!(
        p.push(velocity_point(0, 5.0), Duration::ZERO),
        Err(PointRefused::NotFromRest { axis: 0, .. })
    ));
    p.push(velocity_point(0, 0.0), Duration::ZERO).unwrap();
    assert!(matches!(
        p.push(velocity_point(1000, 101.0), MS),
        Err(PointRefused::TooFast { .. })
    ));
    // 1000 mm/s² allows 1 mm/s per ms.
    assert!(matches!(
        p.push(velocity_point(1000, 1.5), MS),
        Err(PointRefused::TooHardAcceleration { .. })
    ));
    p.push(velocity_point(1000, 1.0), MS).unwrap();
    assert_eq!(p.counters().refused, 3);
    // Accelerate at the limit towards +500 mm: at 100 mm/s the stop takes
    // 5 mm; cruise to where that still fits, then one more point too far.
    let mut t = 1000u64;
    let mut v = 1.0;
    let mut x = 0.0005;
    loop {
        t += 1000;
        let next_v = (v + 1.0f64).min(100.0);
        let next_x = x + (v + next_v) / 2.0 * 0.001;
        let r = p.push(velocity_point(t, next_v), MS * (t / 1000) as u32);
        if next_x + next_v * next_v / 2000.0 > 500.0 + 1e-6 {
            assert!(
                matches!(r, Err(PointRefused::BeyondSoftLimit { .. })),
                "{r:?} at {next_x}"
            );
            break;
        }
        r.unwrap();
        v = next_v;
        x = next_x;
    }
}

/// Random velocity streams (cyclic synchronous velocity): random client
/// periods and bus cycles, network delays with jitter, stalls and bursts,
/// velocity profiles that sometimes break the limits, cycles the sender
/// skips, stops. Whatever comes, no cycle's velocity exceeds the maximum,
/// none changes by more than the acceleration (the stop deceleration on
/// the ramp to rest) allows but to brake harder after skipped cycles, no
/// position leaves the soft limits but by the travel of skipped cycles,
/// the position is the integral of the velocities sent, every underrun
/// ends at rest within the ramp's bound, and the counters add up:
/// received = played + late + refused + dropped.
#[test]
fn random_velocity_streams_never_jump_nor_leave_the_limits() {
    for seed in 1..=random_cases() {
        random_velocity_stream(seed);
    }
}

/// The first seed of the random velocity streams above 60 that breaks the
/// acceleration bound: axis 0 goes from 7.64 to -11.63 mm/s in one 10 ms
/// cycle (at most 8 mm/s allowed), at cycle 1324, client period 5523 µs.
/// Found by `SETPOINT_STREAM_CASES=1000`; kept here until the player is
/// fixed (docs/safety.md, "Open").
#[test]
#[ignore = "open defect: a velocity stream steps beyond the acceleration bound (seed 375)"]
fn random_velocity_stream_seed_375_never_jumps() {
    random_velocity_stream(375);
}

fn random_velocity_stream(seed: u64) {
    let mut rng = Rng(seed.wrapping_mul(0xD1B5_4A32_D192_ED03) | 1);
    let cycle = Duration::from_micros([1000, 2000, 4000, 10_000][rng.range(0, 4) as usize]);
    let depth = Duration::from_millis(rng.range(5, 60));
    let lim = AxisLimits {
        max_jerk: None,
        max_velocity: 50.0,
        max_acceleration: 500.0,
        stop_deceleration: 800.0,
        min_position: Some(-20.0),
        max_position: Some(20.0),
    };
    let mut cfg = PlayerConfig::new(cycle, depth);
    cfg.kind = SetpointKind::Velocity;
    cfg.extrapolate = Duration::from_millis(rng.range(0, 50));
    let mut p = SetpointPlayer::new(cfg, vec![lim; 2], vec![0.0; 2]);
    let period_us = rng.range(500, 20_000);
    let c = cycle.as_secs_f64();
    // The client: a velocity that follows a target now and then changed,
    // within the acceleration (sometimes beyond it, or beyond the maximum
    // velocity, on purpose), heading back from the soft limits by its own
    // integral.
    let mut pos = [0.0f64; 2];
    let mut vel = [0.0f64; 2];
    let mut target = [0.0f64; 2];
    let mut client_t = rng.range(0, 1_000_000_000);
    let mut next_send = Duration::ZERO;
    let mut flight: Vec<(Duration, StreamPoint)> = Vec::new();
    let mut stalled_until = Duration::ZERO;
    let mut last = vec![0.0; 2];
    let mut prev_v = [0.0f64; 2];
    let mut stopping = false;
    let mut underrun_at: Option<u32> = None;
    let mut sent = 0u64;
    // Where the client turns back from the soft limits: some press hard
    // into them (and are told off).
    let turn = 10.0 + rng.f64() * 10.0;
    let mut accepted_vel = [0.0f64; 2];
    let steps = (20.0 / c) as u32;
    // The longest ramp to rest: the maximum velocity at the stop
    // deceleration, plus a cycle of rounding.
    let ramp_cycles = (50.0 / 800.0 / c).ceil() as u32 + 1;
    // Cycles the sender skips now and then (a stalled host): the player's
    // clock is held back by them, and the drive went on at its velocity.
    let mut held_back = Duration::ZERO;
    let mut skipping = 0u32;
    let mut missed = Duration::ZERO;
    // Player cycles played (the ramp's bound counts those).
    let mut played = 0u32;
    let mut since_stall = u32::MAX;
    for k in 0..steps {
        let wall = cycle * k;
        let now = wall.saturating_sub(held_back);
        while next_send <= now && !stopping {
            if rng.f64() < 0.01 {
                target = [(rng.f64() - 0.5) * 104.0, (rng.f64() - 0.5) * 104.0];
            }
            let dt = period_us as f64 / 1e6;
            let wild = rng.f64() < 0.002;
            for a in 0..2 {
                if pos[a].abs() > turn && vel[a] * pos[a] > 0.0 {
                    target[a] = -pos[a].signum() * 10.0;
                }
                let dv = (target[a] - vel[a]).clamp(-450.0 * dt, 450.0 * dt);
                let v0 = vel[a];
                vel[a] += if wild { dv * 20.0 } else { dv };
                pos[a] += (v0 + vel[a]) / 2.0 * dt;
            }
            client_t += period_us;
            let mut delay = Duration::from_micros(rng.range(1000, 3000));
            if rng.f64() < 0.05 {
                delay += Duration::from_micros(rng.range(0, 40_000));
            }
            if rng.f64() < 0.001 {
                stalled_until = now + Duration::from_millis(rng.range(10, 300));
            }
            let arrive = (now + delay).max(stalled_until);
            flight.push((
                arrive,
                StreamPoint {
                    feed_forward: None,
                    t_us: client_t,
                    values: vel.to_vec(),
                },
            ));
            sent += 1;
            next_send += Duration::from_micros(period_us);
        }
        flight.sort_by_key(|(at, _)| *at);
        while flight.first().is_some_and(|(at, _)| *at <= now) {
            let (_, pt) = flight.remove(0);
            let v = [pt.values[0], pt.values[1]];
            match p.push(pt, now) {
                Ok(()) => accepted_vel = v,
                Err(PointRefused::TooFast { .. } | PointRefused::TooHardAcceleration { .. }) => {
                    // Told off: it goes on from its last accepted
                    // velocity.
                    vel = accepted_vel;
                }
                Err(PointRefused::NotFromRest { .. }) => {
                    // The client restarts from rest, from where the
                    // gateway says the axes stand.
                    pos = [p.position()[0], p.position()[1]];
                    vel = [0.0; 2];
                    accepted_vel = vel;
                }
                Err(PointRefused::BeyondSoftLimit { .. }) => {
                    // Told off: it brakes.
                    target = [0.0; 2];
                }
                _ => {}
            }
        }
        if k == steps - (2.0 / c) as u32 {
            p.stop(now);
            stopping = true;
        }
        if skipping == 0 && rng.f64() < 0.002 {
            skipping = rng.range(1, 6) as u32;
        }
        if skipping > 0 {
            skipping -= 1;
            missed += cycle;
            continue;
        }
        held_back += missed;
        let now = wall.saturating_sub(held_back);
        p.skipped(missed);
        let skipped_s = missed.as_secs_f64();
        since_stall = if missed.is_zero() {
            since_stall.saturating_add(1)
        } else {
            0
        };
        missed = Duration::ZERO;
        played += 1;
        let out = p.next(now);
        match out.event {
            Some(PlayerEvent::Underrun) => {
                assert!(underrun_at.is_none(), "seed {seed}: underrun during a ramp");
                underrun_at = Some(played);
            }
            Some(PlayerEvent::AtRest) => underrun_at = None,
            None => {}
        }
        if out.state == PlayerState::Waiting {
            // At rest (an underrun of axes that stood still is at rest at
            // once, without an AtRest of its own).
            underrun_at = None;
        }
        if let Some(u) = underrun_at {
            assert!(
                played - u <= ramp_cycles,
                "seed {seed} cycle {k}: the underrun at {u} is not at rest after {ramp_cycles} \
                 cycles"
            );
        }
        for a in 0..2 {
            let x = out.positions[a];
            // Inside the soft limits but for the travel of skipped cycles
            // (nothing the gateway sends holds a drive that it cannot
            // reach).
            let beyond = 50.0 * skipped_s;
            assert!(
                (-20.0 - beyond - 1e-6..=20.0 + beyond + 1e-6).contains(&x),
                "seed {seed} cycle {k}: axis {a} at {x}"
            );
            // The drive's set-point: the cycle's velocity, whose integral
            // the position is.
            let v = p.velocity()[a];
            let coasted = prev_v[a] * skipped_s;
            assert!(
                ((x - last[a] - coasted) / c - v).abs() < 1e-6 * 50.0,
                "seed {seed} cycle {k}: axis {a} position and velocity disagree"
            );
            assert!(
                v.abs() <= 50.0 * (1.0 + 1e-9),
                "seed {seed} cycle {k}: axis {a} at {v} mm/s"
            );
            let dv_max = 800.0 * c;
            let dv = v - prev_v[a];
            // A stall that carried the drive closer to a soft limit than
            // its braking curve allows is braked harder (never sped up).
            let braking_after_a_stall = since_stall < ramp_cycles && v.abs() < prev_v[a].abs();
            assert!(
                braking_after_a_stall || dv.abs() <= dv_max * (1.0 + 1e-6) + 1e-9,
                "seed {seed} cycle {k}: axis {a} velocity {} -> {v} (cycle {cycle:?}, period \
                 {period_us} µs)",
                prev_v[a]
            );
            prev_v[a] = v;
        }
        last = out.positions.clone();
    }
    assert_eq!(
        p.state(),
        PlayerState::Waiting,
        "seed {seed}: at rest at the end"
    );
    assert_eq!(p.velocity(), [0.0, 0.0], "seed {seed}");
    let n = p.counters();
    assert_eq!(n.received + flight.len() as u64, sent, "seed {seed}: {n:?}");
    assert_eq!(n.received, n.accepted + n.refused, "seed {seed}: {n:?}");
    assert_eq!(
        n.received,
        n.played + n.late + n.refused + n.dropped,
        "seed {seed}: {n:?}"
    );
}

/// A torque stream over `axes` axes of at most 500 per mille changing at
/// most 10 000 per mille/s, 1 ms cycle.
fn torque_player(axes: usize, depth_ms: u64) -> SetpointPlayer {
    let mut cfg = PlayerConfig::new(MS, Duration::from_millis(depth_ms));
    cfg.kind = SetpointKind::Torque;
    SetpointPlayer::new(
        cfg,
        vec![AxisLimits::torque(500.0, 10_000.0); axes],
        vec![0.0; axes],
    )
}

fn torque_point(t_us: u64, t: f64) -> StreamPoint {
    StreamPoint {
        feed_forward: None,
        t_us,
        values: vec![t],
    }
}

/// The torques play interpolated after the buffer, the last one is held
/// for the extrapolation time, then the torque ramps to exactly 0 at the
/// slope (an underrun), and the next playout starts from 0 again.
#[test]
fn a_torque_stream_plays_holds_and_ramps_the_torque_to_zero() {
    let mut p = torque_player(1, 15);
    // Each point arrives at its own time (no delay).
    let mut played = Vec::new();
    for k in 0..=70u32 {
        if k % 10 == 0 && k <= 20 {
            let t_us = u64::from(k) * 1000;
            p.push(torque_point(t_us, 5.0 * f64::from(k)), MS * k)
                .unwrap();
        }
        played.push(p.next(MS * k).positions[0]);
    }
    // Client time is 15 ms behind: 0 up to 15 ms, then 5 per mille per
    // ms up to 100 at 35 ms.
    assert_eq!(played[15], 0.0);
    for (k, want) in [(20, 25.0), (25, 50.0), (35, 100.0)] {
        assert!((played[k] - want).abs() < 1e-9, "{k}: {played:?}");
    }
    // Held at 100 for the extrapolation (15 ms, the depth).
    assert!(played[35..50].iter().all(|&t| t == 100.0), "{played:?}");
    // Then an underrun: 100 per mille to 0 at 10 000 per mille/s, 10 ms.
    for (k, want) in [(50, 90.0), (54, 50.0), (58, 10.0)] {
        assert!((played[k] - want).abs() < 1e-9, "{k}: {played:?}");
    }
    assert!(played[59..].iter().all(|&t| t == 0.0), "{played:?}");
    assert_eq!(p.state(), PlayerState::Waiting);
    let c = p.counters();
    assert_eq!((c.received, c.played, c.underruns), (3, 3, 1), "{c:?}");
    // A new playout starts from 0 torque.
    assert!(matches!(
        p.push(torque_point(100_000, 50.0), MS * 71),
        Err(PointRefused::TorqueNotFromZero { axis: 0, .. })
    ));
    p.push(torque_point(100_000, 5.0), MS * 71).unwrap();
}

/// Torques beyond the maximum, changes beyond the slope, a start away
/// from 0, a wrong count and a value that is not finite are refused.
#[test]
fn torque_points_beyond_the_limits_are_refused() {
    let mut p = torque_player(1, 5);
    assert_eq!(
        p.push(torque_point(0, 20.0), Duration::ZERO),
        Err(PointRefused::TorqueNotFromZero {
            axis: 0,
            torque: 20.0,
            tolerance: 10.0,
        })
    );
    p.push(torque_point(0, 10.0), Duration::ZERO).unwrap();
    assert_eq!(
        p.push(torque_point(1000, 600.0), Duration::ZERO),
        Err(PointRefused::TorqueAboveMax {
            axis: 0,
            torque: 600.0,
            max: 500.0,
        })
    );
    // 10 -> 30 in 1 ms: 20 000 per mille/s.
    assert_eq!(
        p.push(torque_point(1000, 30.0), Duration::ZERO),
        Err(PointRefused::TorqueTooSteep {
            axis: 0,
            slope: 20_000.0,
            max: 10_000.0,
        })
    );
    assert!(matches!(
        p.push(torque_point(1000, f64::NAN), Duration::ZERO),
        Err(PointRefused::NotFinite { axis: 0, .. })
    ));
    assert!(matches!(
        p.push(
            StreamPoint {
                feed_forward: None,
                t_us: 1000,
                values: vec![1.0, 2.0]
            },
            Duration::ZERO
        ),
        Err(PointRefused::Dimension { got: 2, want: 1 })
    ));
    p.push(torque_point(1000, 20.0), Duration::ZERO).unwrap();
    let c = p.counters();
    assert_eq!((c.received, c.accepted, c.refused), (7, 2, 5), "{c:?}");
}

/// A stop ramps every torque to 0 together (each within its slope) and
/// drops the buffered points.
#[test]
fn a_stop_ramps_the_torques_to_zero_together() {
    let mut p = torque_player(2, 1);
    for k in 0..=21u32 {
        let t = f64::from(k);
        let pt = StreamPoint {
            feed_forward: None,
            t_us: u64::from(k) * 1000,
            values: vec![5.0 * t, -2.5 * t],
        };
        p.push(pt, MS * k).unwrap();
        p.next(MS * k);
    }
    // Client time 20 ms: 100 and -50.
    assert_eq!(p.position(), [100.0, -50.0]);
    p.stop(MS * 21);
    let mut k = 22;
    let mut last = p.position().to_vec();
    loop {
        let out = p.next(MS * k);
        for (t, t0) in out.positions.iter().zip(&last) {
            assert!((t - t0).abs() <= 10.0 + 1e-9, "{out:?}");
        }
        last = out.positions.clone();
        if out.event == Some(PlayerEvent::AtRest) {
            break;
        }
        k += 1;
    }
    // 100 per mille at 10 000 per mille/s: 10 ms; y reaches 0 with x.
    assert_eq!(k, 31);
    assert_eq!(last, [0.0, 0.0]);
    let c = p.counters();
    assert_eq!(c.received, c.played + c.dropped, "{c:?}");
}

#[test]
fn random_torque_streams_never_exceed_the_maximum_nor_the_slope() {
    for seed in 1..=random_cases() {
        random_torque_stream(seed);
    }
}

/// Random torque profiles (some beyond the maximum or the slope on
/// purpose) with random network delay, stalls, stalled senders and a
/// stop at the end, in virtual time: no torque beyond the maximum, no
/// change beyond the slope, every underrun and stop ends at exactly 0
/// within the slope's ramp, the counters add up.
fn random_torque_stream(seed: u64) {
    let mut rng = Rng(seed.wrapping_mul(0xA24B_AED4_963E_E407) | 1);
    let cycle = Duration::from_micros([1000, 2000, 4000, 10_000][rng.range(0, 4) as usize]);
    let depth = Duration::from_millis(rng.range(5, 60));
    let (max, slope) = (400.0, 2000.0);
    let mut cfg = PlayerConfig::new(cycle, depth);
    cfg.kind = SetpointKind::Torque;
    cfg.extrapolate = Duration::from_millis(rng.range(0, 50));
    let mut p = SetpointPlayer::new(cfg, vec![AxisLimits::torque(max, slope); 2], vec![0.0; 2]);
    let period_us = rng.range(500, 20_000);
    let c = cycle.as_secs_f64();
    let mut torque = [0.0f64; 2];
    let mut accepted = [0.0f64; 2];
    let mut target = [0.0f64; 2];
    let mut client_t = rng.range(0, 1_000_000_000);
    let mut next_send = Duration::ZERO;
    let mut flight: Vec<(Duration, StreamPoint)> = Vec::new();
    let mut stalled_until = Duration::ZERO;
    let mut last = [0.0f64; 2];
    let mut stopping = false;
    let mut stop_at: Option<u32> = None;
    let mut sent = 0u64;
    let steps = (20.0 / c) as u32;
    // The longest ramp to 0: the maximum at the slope, plus a cycle.
    let ramp_cycles = (max / slope / c).ceil() as u32 + 1;
    for k in 0..steps {
        let now = cycle * k;
        while next_send <= now && !stopping {
            if rng.f64() < 0.01 {
                target = [(rng.f64() - 0.5) * 900.0, (rng.f64() - 0.5) * 900.0];
            }
            let dt = period_us as f64 / 1e6;
            let wild = rng.f64() < 0.002;
            for a in 0..2 {
                let dt_max = 0.9 * slope * dt;
                let d = (target[a] - torque[a]).clamp(-dt_max, dt_max);
                torque[a] += if wild { d * 20.0 } else { d };
            }
            client_t += period_us;
            let mut delay = Duration::from_micros(rng.range(1000, 3000));
            if rng.f64() < 0.05 {
                delay += Duration::from_micros(rng.range(0, 40_000));
            }
            if rng.f64() < 0.001 {
                stalled_until = now + Duration::from_millis(rng.range(10, 300));
            }
            flight.push((
                (now + delay).max(stalled_until),
                StreamPoint {
                    feed_forward: None,
                    t_us: client_t,
                    values: torque.to_vec(),
                },
            ));
            sent += 1;
            next_send += Duration::from_micros(period_us);
        }
        flight.sort_by_key(|(at, _)| *at);
        while flight.first().is_some_and(|(at, _)| *at <= now) {
            let (_, pt) = flight.remove(0);
            let t = [pt.values[0], pt.values[1]];
            match p.push(pt, now) {
                Ok(()) => accepted = t,
                Err(PointRefused::TorqueTooSteep { .. } | PointRefused::TorqueAboveMax { .. }) => {
                    torque = accepted;
                }
                Err(PointRefused::TorqueNotFromZero { .. }) => {
                    torque = [0.0; 2];
                    accepted = torque;
                }
                Err(_) => {}
            }
        }
        if k == steps - (2.0 / c) as u32 {
            p.stop(now);
            stopping = true;
        }
        let out = p.next(now);
        match out.event {
            Some(PlayerEvent::Underrun) if stop_at.is_none() => stop_at = Some(k),
            _ => {}
        }
        if stopping && stop_at.is_none() {
            stop_at = Some(k);
        }
        if out.state == PlayerState::Waiting {
            // Every ramp ends at exactly 0.
            assert_eq!(out.positions, [0.0, 0.0], "seed {seed} cycle {k}");
            if !stopping {
                stop_at = None;
            }
        }
        if let Some(s) = stop_at
            && out.state != PlayerState::Waiting
        {
            assert!(
                k - s <= ramp_cycles,
                "seed {seed} cycle {k}: the ramp from {s} is not at 0 after {ramp_cycles} cycles"
            );
        }
        for (a, (&t, t0)) in out.positions.iter().zip(last.iter_mut()).enumerate() {
            assert!(t.abs() <= max + 1e-9, "seed {seed} cycle {k}: {t}");
            assert!(
                (t - *t0).abs() <= slope * c * (1.0 + 1e-9) + 1e-9,
                "seed {seed} cycle {k}: axis {a} {t0} -> {t}"
            );
            *t0 = t;
        }
    }
    assert_eq!(p.state(), PlayerState::Waiting, "seed {seed}");
    assert_eq!(p.position(), [0.0, 0.0], "seed {seed}");
    let n = p.counters();
    assert_eq!(n.received + flight.len() as u64, sent, "seed {seed}: {n:?}");
    assert_eq!(n.received, n.accepted + n.refused, "seed {seed}: {n:?}");
    assert_eq!(
        n.received,
        n.played + n.late + n.refused + n.dropped,
        "seed {seed}: {n:?}"
    );
}

/// A position stream's feed-forward plays interpolated between points like
/// the position; without one (or once the points run out) the
/// feed-forward is the commanded velocity. A feed-forward beyond the
/// limits refuses its point.
#[test]
fn the_feed_forward_of_a_position_stream_is_interpolated_and_checked() {
    let mut p = player(1, 15).with_feed_forward_torque_limits(vec![300.0]);
    let point = |k: u32, x: f64, v: f64, t: f64| StreamPoint {
        t_us: u64::from(k) * 1000,
        values: vec![x],
        feed_forward: Some(FeedForward {
            velocities: vec![v],
            torques: vec![t],
        }),
    };
    let mut ff = Vec::new();
    for k in 0..=35u32 {
        if k % 10 == 0 && k <= 20 {
            // 0 to 0.1 to 0.3 mm: 10 then 20 mm/s, torque 0, 40, 80.
            let (x, v, t) =
                [(0.0, 0.0, 0.0), (0.1, 10.0, 40.0), (0.3, 20.0, 80.0)][k as usize / 10];
            p.push(point(k, x, v, t), MS * k).unwrap();
        }
        p.next(MS * k);
        ff.push(p.feed_forward());
    }
    // Client time 15 ms behind: at 20 ms half way to the second point.
    assert_eq!(ff[20].velocities, [5.0]);
    assert_eq!(ff[20].torques, [20.0]);
    assert_eq!(ff[25].velocities, [10.0]);
    assert!((ff[30].velocities[0] - 15.0).abs() < 1e-9, "{:?}", ff[30]);
    assert!((ff[30].torques[0] - 60.0).abs() < 1e-9, "{:?}", ff[30]);
    // Beyond the maximum velocity, the maximum torque, not finite, the
    // wrong count: refused.
    assert!(matches!(
        p.push(point(36, 0.31, 150.0, 0.0), MS * 36),
        Err(PointRefused::TooFast { axis: 0, .. })
    ));
    assert!(matches!(
        p.push(point(36, 0.31, 10.0, 400.0), MS * 36),
        Err(PointRefused::TorqueAboveMax { axis: 0, .. })
    ));
    assert!(matches!(
        p.push(point(36, 0.31, f64::NAN, 0.0), MS * 36),
        Err(PointRefused::NotFinite { axis: 0, .. })
    ));
    let mut two = point(36, 0.31, 10.0, 0.0);
    two.feed_forward.as_mut().unwrap().torques = vec![1.0, 2.0];
    assert!(matches!(
        p.push(two, MS * 36),
        Err(PointRefused::Dimension { got: 2, want: 1 })
    ));
    // No point ahead: the commanded velocity, no torque.
    for k in 36..=40u32 {
        p.next(MS * k);
    }
    let f = p.feed_forward();
    assert!(f.torques.is_empty(), "{f:?}");
    assert_eq!(f.velocities, p.velocity());
    // A stream whose client gives none: 0 (a drive that derives its own
    // feed-forward does not get it twice).
    let mut p = player(1, 5);
    for k in 0..=10u32 {
        let pt = StreamPoint {
            feed_forward: None,
            t_us: u64::from(k) * 1000,
            values: vec![0.0005 * f64::from(k * k)],
        };
        p.push(pt, MS * k).unwrap();
        p.next(MS * k);
    }
    assert!(p.velocity()[0] > 0.0);
    assert_eq!(p.feed_forward().velocities, [0.0]);
}

/// With a maximum jerk, a point whose segment's acceleration changes from
/// the previous one's faster than the jerk allows over the segment is
/// refused (exactly at the bound it is taken); without one nothing is
/// checked.
#[test]
fn a_point_beyond_the_maximum_jerk_is_refused() {
    let lim = AxisLimits {
        max_jerk: Some(10_000.0),
        ..limits(Some(500.0))
    };
    let mut p = SetpointPlayer::new(PlayerConfig::new(MS, MS * 5), vec![lim], vec![0.0]);
    let at = |t_ms: u64, x: f64| StreamPoint {
        feed_forward: None,
        t_us: t_ms * 1000,
        values: vec![x],
    };
    p.push(at(0, 0.0), Duration::ZERO).unwrap();
    // Segments of 10 ms: 0.05 mm is 5 mm/s, 500 mm/s² from rest: a
    // change of 500 mm/s² in 10 ms, 50 000 mm/s³.
    assert_eq!(
        p.push(at(10, 0.05), Duration::ZERO),
        Err(PointRefused::TooHardJerk {
            axis: 0,
            jerk: 50_000.0,
            max: 10_000.0,
        })
    );
    // 0.01 mm: 1 mm/s, 100 mm/s², 10 000 mm/s³: at the bound.
    p.push(at(10, 0.01), Duration::ZERO).unwrap();
    // Then 0.03 mm (2 mm/s, 100 mm/s² again): no change of acceleration.
    p.push(at(20, 0.03), Duration::ZERO).unwrap();
    // Then a stop of the acceleration to -100 mm/s²: 20 000 mm/s³.
    assert!(matches!(
        p.push(at(30, 0.04), Duration::ZERO),
        Err(PointRefused::TooHardJerk { axis: 0, .. })
    ));
    // Without a maximum jerk the same points pass.
    let mut p = player(1, 5);
    for (t, x) in [(0, 0.0), (10, 0.05), (20, 0.15)] {
        p.push(at(t, x), Duration::ZERO).unwrap();
    }
}
