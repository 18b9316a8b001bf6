//! Property tests of the single-axis profiles and synchronised moves.

use cangate_motion::{AxisMove, Limits, SCurveProfile, SyncedMove, TrapezoidProfile};
use proptest::prelude::*;

/// Samples per profile in the property checks.
const N: u32 = 2000;
/// Relative tolerance on limits.
const REL: f64 = 1e-9;

fn tol(scale: f64) -> f64 {
    1e-9 * (1.0 + scale.abs())
}

fn limits() -> impl Strategy<Value = Limits> {
    (0.1f64..100.0, 0.1f64..1000.0, 0.1f64..1000.0)
        .prop_map(|(v, a, d)| Limits::new(v, a, d).unwrap())
}

/// Positions, sometimes equal (zero-length moves).
fn endpoints() -> impl Strategy<Value = (f64, f64)> {
    prop_oneof![
        4 => (-1000.0f64..1000.0, -1000.0f64..1000.0),
        1 => (-1000.0f64..1000.0).prop_map(|x| (x, x)),
    ]
}

/// Check a sampled profile: ends exactly at rest on target, respects the
/// speed bound and the accel/decel limits, and is continuous (velocity is
/// the derivative of position, acceleration bounded between samples).
fn check_profile(
    sample: impl Fn(f64) -> (f64, f64, f64),
    duration: f64,
    target: f64,
    speed_bound: f64,
    acc: f64,
    dec: f64,
) -> Result<(), TestCaseError> {
    prop_assert!(duration.is_finite() && duration >= 0.0);
    prop_assert_eq!(sample(duration), (target, 0.0, 0.0));
    prop_assert_eq!(sample(duration * 2.0 + 1.0), (target, 0.0, 0.0));
    let amax = acc.max(dec);
    let dt = duration / f64::from(N);
    let mut prev = sample(0.0);
    for i in 1..=N {
        let t = if i == N { duration } else { f64::from(i) * dt };
        let (p, v, a) = sample(t);
        let scale = p.abs().max(target.abs());
        prop_assert!(
            v.abs() <= speed_bound * (1.0 + REL) + tol(0.0),
            "t={} v={}",
            t,
            v
        );
        prop_assert!(a.abs() <= amax * (1.0 + REL), "t={} a={}", t, a);
        if a * v > 0.0 {
            prop_assert!(
                a.abs() <= acc * (1.0 + REL),
                "speeding up too hard: t={} a={}",
                t,
                a
            );
        }
        if a * v < 0.0 {
            prop_assert!(
                a.abs() <= dec * (1.0 + REL),
                "braking too hard: t={} a={}",
                t,
                a
            );
        }
        let (p0, v0, _) = prev;
        // Position continuity and consistency with velocity (trapezoid rule
        // is exact on constant-acceleration pieces; error only where an
        // acceleration step falls inside the interval).
        prop_assert!(
            (p - p0).abs() <= speed_bound * dt * (1.0 + REL) + tol(scale),
            "jump at t={}",
            t
        );
        prop_assert!(
            (p - p0 - (v + v0) / 2.0 * dt).abs() <= 2.0 * amax * dt * dt + tol(scale),
            "position/velocity inconsistent at t={}: dp={} v0={} v={}",
            t,
            p - p0,
            v0,
            v
        );
        prop_assert!(
            (v - v0).abs() <= amax * dt * (1.0 + REL) + tol(speed_bound),
            "v jump at t={}",
            t
        );
        prev = (p, v, a);
    }
    Ok(())
}

/// Analytic minimum duration of a rest-to-rest trapezoid.
fn rest_to_rest_duration(dist: f64, l: Limits) -> f64 {
    let (v, a, d) = (l.max_velocity(), l.acceleration(), l.deceleration());
    if dist >= v * v / 2.0 * (1.0 / a + 1.0 / d) {
        dist / v + v / (2.0 * a) + v / (2.0 * d)
    } else {
        (2.0 * dist * (1.0 / a + 1.0 / d)).sqrt()
    }
}

proptest! {
    #[test]
    fn trapezoid_respects_limits_and_ends_on_target(
        (start, target) in endpoints(),
        v0 in prop_oneof![1 => Just(0.0), 3 => -50.0f64..50.0],
        l in limits(),
    ) {
        let p = TrapezoidProfile::new(start, v0, target, l).unwrap();
        let bound = l.max_velocity().max(v0.abs());
        check_profile(|t| p.sample(t), p.duration(), target, bound, l.acceleration(), l.deceleration())?;
        prop_assert!(p.peak_velocity() <= bound * (1.0 + REL));
        let (x, v, _) = p.sample(0.0);
        prop_assert_eq!((x, v), (start, v0));
    }

    #[test]
    fn rest_to_rest_trapezoid_is_time_optimal_and_triangular_when_short(
        (start, target) in endpoints(),
        l in limits(),
    ) {
        let p = TrapezoidProfile::rest_to_rest(start, target, l).unwrap();
        let dist = (target - start).abs();
        let expect = rest_to_rest_duration(dist, l);
        prop_assert!((p.duration() - expect).abs() <= 1e-9 * (1.0 + expect), "{} vs {}", p.duration(), expect);
        let v = l.max_velocity();
        let needs_cruise = dist > v * v / 2.0 * (1.0 / l.acceleration() + 1.0 / l.deceleration()) * (1.0 + 1e-9);
        if needs_cruise {
            prop_assert!(p.has_cruise());
            prop_assert!((p.peak_velocity() - v).abs() <= tol(v));
        } else if dist < v * v / 2.0 * (1.0 / l.acceleration() + 1.0 / l.deceleration()) * (1.0 - 1e-9) {
            prop_assert!(!p.has_cruise());
            prop_assert!(p.peak_velocity() < v);
        }
        // Monotone towards the target: never moves backwards.
        let s = (target - start).signum();
        let mut last = start;
        for i in 0..=200 {
            let (x, _, _) = p.sample(p.duration() * f64::from(i) / 200.0);
            prop_assert!((x - last) * s >= -tol(x));
            last = x;
        }
    }

    #[test]
    fn reversal_goes_to_the_stopping_point_then_back(
        (start, dist) in (-100.0f64..100.0, 0.01f64..100.0),
        speed in 0.01f64..20.0,
        l in limits(),
    ) {
        // Moving at -speed away from a target at +dist.
        let target = start + dist;
        let p = TrapezoidProfile::new(start, -speed, target, l).unwrap();
        let t_stop = speed / l.deceleration();
        let (x, v, a) = p.sample(t_stop);
        let turn = start - speed * speed / (2.0 * l.deceleration());
        prop_assert!((x - turn).abs() <= tol(turn) + 1e-9 * speed * t_stop, "turn at {} not {}", x, turn);
        prop_assert!(v.abs() <= tol(speed));
        prop_assert!(a >= 0.0);
        // Never goes below the turning point.
        for i in 0..=400 {
            let (x, _, _) = p.sample(p.duration() * f64::from(i) / 400.0);
            prop_assert!(x >= turn - tol(turn) - 1e-9 * speed * t_stop);
        }
        let expect = t_stop + rest_to_rest_duration(target - turn, l);
        prop_assert!((p.duration() - expect).abs() <= 1e-9 * (1.0 + expect));
    }

    #[test]
    fn scurve_respects_jerk_accel_and_velocity(
        (start, target) in endpoints(),
        l in limits(),
        v0_frac in prop_oneof![1 => Just(0.0), 3 => -1.0f64..1.0],
        jerk in 0.5f64..10_000.0,
    ) {
        let v0 = v0_frac * l.max_velocity();
        let p = SCurveProfile::new(start, v0, target, l, jerk).unwrap();
        check_profile(|t| p.sample(t), p.duration(), target, l.max_velocity(), l.acceleration(), l.deceleration())?;
        // Acceleration is continuous with bounded jerk.
        let n = 2000;
        let dt = p.duration() / f64::from(n);
        let mut prev_a = p.sample(0.0).2;
        prop_assert!(prev_a.abs() <= tol(0.0));
        for i in 1..=n {
            let a = p.sample(f64::from(i) * dt).2;
            prop_assert!((a - prev_a).abs() <= jerk * dt * (1.0 + REL) + tol(l.acceleration().max(l.deceleration())));
            prev_a = a;
        }
        // Near the end the profile is already essentially at the target.
        let (x, v, _) = p.sample(p.duration() * (1.0 - 1e-12));
        prop_assert!((x - target).abs() <= 1e-6 * (1.0 + target.abs()));
        prop_assert!(v.abs() <= 1e-6 * (1.0 + l.max_velocity()));
    }

    #[test]
    fn synced_move_ends_together_within_each_axis_limits(
        axes in prop::collection::vec((endpoints(), limits()), 1..6),
    ) {
        let moves: Vec<AxisMove> = axes.iter().map(|&((s, t), l)| AxisMove::new(s, t, l)).collect();
        let m = SyncedMove::new(moves.clone()).unwrap();
        let targets: Vec<f64> = moves.iter().map(|a| a.target).collect();
        prop_assert_eq!(m.sample(m.duration()), targets.clone());
        prop_assert_eq!(m.targets(), targets);
        let mins: Vec<f64> = (0..m.axis_count()).map(|i| m.profile(i).unwrap().duration()).collect();
        let longest = mins.iter().copied().fold(0.0, f64::max);
        prop_assert_eq!(m.duration(), longest);
        let starts: Vec<f64> = moves.iter().map(|a| a.start).collect();
        prop_assert_eq!(m.sample(0.0), starts);
        for (i, mv) in moves.iter().enumerate() {
            let l = mv.limits;
            check_profile(
                |t| m.sample_states(t)[i],
                m.duration(),
                mv.target,
                l.max_velocity(),
                l.acceleration(),
                l.deceleration(),
            )?;
            // Every axis still moving until (nearly) the common end: not
            // arrived early unless it has nothing to do.
            if mv.start != mv.target && m.duration() > 0.0 {
                let (x, _, _) = m.sample_states(m.duration() * 0.99)[i];
                prop_assert!(x != mv.target);
            }
        }
    }
}
