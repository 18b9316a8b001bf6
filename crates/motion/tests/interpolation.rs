//! Property tests of the CSP interpolator and the jog generator.

use std::time::Duration;

use cangate_motion::{
    AxisMove, Interpolator, JogGenerator, Limits, SCurveProfile, SyncedMove, TrapezoidProfile,
};
use proptest::prelude::*;

fn limits() -> impl Strategy<Value = Limits> {
    (2.0f64..100.0, 1.0f64..1000.0, 1.0f64..1000.0)
        .prop_map(|(v, a, d)| Limits::new(v, a, d).unwrap())
}

fn cycle() -> impl Strategy<Value = Duration> {
    prop_oneof![
        Just(Duration::from_millis(1)),
        Just(Duration::from_millis(2)),
        (250u64..10_000).prop_map(Duration::from_micros),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    #[test]
    fn setpoints_end_on_target_and_steps_stay_under_vmax_cycle(
        start in -50.0f64..50.0,
        target in -50.0f64..50.0,
        v0_frac in prop_oneof![Just(0.0), -1.0f64..1.0],
        l in limits(),
        cycle in cycle(),
        jerk in prop::option::of(10.0f64..10_000.0),
    ) {
        let v0 = v0_frac * l.max_velocity();
        let c = cycle.as_secs_f64();
        let (points, duration): (Vec<f64>, f64) = match jerk {
            None => {
                let p = TrapezoidProfile::new(start, v0, target, l).unwrap();
                let it = Interpolator::new(&p, cycle).unwrap();
                prop_assert_eq!(it.len() as u64, it.total_cycles());
                (it.collect(), p.duration())
            }
            Some(j) => {
                let p = SCurveProfile::new(start, v0, target, l, j).unwrap();
                (Interpolator::new(&p, cycle).unwrap().collect(), p.duration())
            }
        };
        prop_assert_eq!(*points.last().unwrap(), target);
        let expected = ((duration / c) - 1e-9).ceil().max(1.0) as usize;
        prop_assert_eq!(points.len(), expected);
        let bound = l.max_velocity() * c + 1e-9 * (1.0 + start.abs().max(target.abs()));
        let mut prev = start;
        for (k, &x) in points.iter().enumerate() {
            prop_assert!((x - prev).abs() <= bound, "step {} of {}: {} > {}", k, points.len(), (x - prev).abs(), bound);
            prev = x;
        }
    }

    #[test]
    fn synced_setpoints_end_together(
        axes in prop::collection::vec((-50.0f64..50.0, -50.0f64..50.0, limits()), 1..5),
        cycle in cycle(),
    ) {
        let moves: Vec<AxisMove> = axes.iter().map(|&(s, t, l)| AxisMove::new(s, t, l)).collect();
        let m = SyncedMove::new(moves.clone()).unwrap();
        let c = cycle.as_secs_f64();
        let points: Vec<Vec<f64>> = Interpolator::new(&m, cycle).unwrap().collect();
        prop_assert_eq!(points.last().unwrap(), &m.targets());
        let mut prev: Vec<f64> = moves.iter().map(|a| a.start).collect();
        for p in &points {
            for (i, mv) in moves.iter().enumerate() {
                let bound = mv.limits.max_velocity() * c + 1e-9 * (1.0 + p[i].abs());
                prop_assert!((p[i] - prev[i]).abs() <= bound);
            }
            prev.clone_from(p);
        }
    }

    #[test]
    fn jog_respects_accel_limits_and_is_step_size_independent(
        l in limits(),
        commands in prop::collection::vec((-200.0f64..200.0, 1u64..50, 100u64..5_000), 1..20),
    ) {
        let mut j = JogGenerator::new(0.0, l).unwrap();
        let mut coarse = JogGenerator::new(0.0, l).unwrap();
        for &(v_cmd, steps, step_us) in &commands {
            j.set_target_velocity(v_cmd);
            coarse.set_target_velocity(v_cmd);
            prop_assert!(j.target_velocity().abs() <= l.max_velocity());
            let dt = Duration::from_micros(step_us);
            let h = dt.as_secs_f64();
            for _ in 0..steps {
                let (p0, v0) = (j.position(), j.velocity());
                let (p1, v1) = j.step(dt);
                let eps = 1e-9 * (1.0 + p1.abs());
                prop_assert!(v1.abs() <= l.max_velocity() * (1.0 + 1e-12));
                // Speeding up bounded by acceleration, slowing by deceleration.
                if v0 * v1 >= 0.0 {
                    let dv = v1.abs() - v0.abs();
                    if dv > 0.0 {
                        prop_assert!(dv <= l.acceleration() * h * (1.0 + 1e-9) + 1e-12);
                    } else {
                        prop_assert!(-dv <= l.deceleration() * h * (1.0 + 1e-9) + 1e-12);
                    }
                } else {
                    // Through zero: brake |v0| at dec, then speed up |v1| at acc.
                    let t = v0.abs() / l.deceleration() + v1.abs() / l.acceleration();
                    prop_assert!(t <= h * (1.0 + 1e-9) + 1e-12);
                }
                // Velocity is monotone within a step, so the mean velocity
                // lies between the end velocities.
                let mean = (p1 - p0) / h;
                prop_assert!(mean >= v0.min(v1) - eps / h && mean <= v0.max(v1) + eps / h);
            }
            coarse.step(dt * u32::try_from(steps).unwrap());
            let (pf, vf) = (j.position(), j.velocity());
            prop_assert!((coarse.velocity() - vf).abs() <= 1e-9 * (1.0 + vf.abs()));
            prop_assert!((coarse.position() - pf).abs() <= 1e-7 * (1.0 + pf.abs()));
        }
        // Stop: reaches standstill after |v|/dec having travelled the
        // announced stopping distance.
        let (p, sd, st) = (j.position(), j.stopping_distance(), j.stopping_time());
        j.stop();
        j.step(st + Duration::from_nanos(1));
        prop_assert!(j.is_stopped());
        prop_assert!((j.position() - (p + sd)).abs() <= 1e-7 * (1.0 + p.abs()));
    }
}
