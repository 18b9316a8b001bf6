//! Time-optimal trapezoidal (acceleration-limited) point-to-point profile.

use crate::segment::{Builder, Piecewise};
use crate::{Limits, MotionError, check_finite};

/// A time-optimal move from `(start, start_velocity)` to rest at `target`,
/// respecting a velocity limit, an acceleration limit (speeding up) and a
/// deceleration limit (slowing down).
///
/// Shape, in the order the phases occur (each phase may be absent):
///
/// 1. **Brake to standstill** with the deceleration limit, if the axis is
///    moving away from the target, or moving towards it too fast to stop in
///    time (the move then overshoots and comes back: "decelerate, reverse").
/// 2. **Accelerate** towards the target up to the peak speed; or, if the
///    start speed exceeds the velocity limit, **decelerate** down to it.
/// 3. **Cruise** at the velocity limit (absent for a short, *triangular*
///    move whose peak speed stays below the limit).
/// 4. **Decelerate** to rest exactly on the target.
///
/// Velocity never exceeds `max(|start_velocity|, max_velocity)`; acceleration
/// is `±acceleration` while speeding up, `±deceleration` while slowing down,
/// or zero. `sample(t)` for `t >= duration()` returns exactly
/// `(target, 0.0, 0.0)`.
#[derive(Debug, Clone, PartialEq)]
pub struct TrapezoidProfile {
    start: f64,
    start_velocity: f64,
    target: f64,
    limits: Limits,
    cruise: bool,
    path: Piecewise,
}

impl TrapezoidProfile {
    /// Plan a move.
    ///
    /// # Errors
    /// [`MotionError::NonFinite`] if `start`, `start_velocity`, `target` or
    /// `target - start` is not finite; [`MotionError::Unrepresentable`] if
    /// the plan overflows `f64`. (Invalid limits are rejected earlier, by
    /// [`Limits::new`].)
    pub fn new(
        start: f64,
        start_velocity: f64,
        target: f64,
        limits: Limits,
    ) -> Result<Self, MotionError> {
        check_finite("start position", start)?;
        check_finite("start velocity", start_velocity)?;
        check_finite("target position", target)?;
        let d = check_finite("target - start", target - start)?;
        let vmax = limits.max_velocity();
        let acc = limits.acceleration();
        let dec = limits.deceleration();
        let v0 = start_velocity;

        let mut b = Builder::new(start, v0);
        let mut cruise = false;

        // Phase 1: brake to standstill if we cannot reach the target
        // without overshooting (moving away, or stopping distance too long).
        if v0 != 0.0 {
            let stopping = v0 * v0 / (2.0 * dec);
            if d * v0 <= 0.0 || stopping > d.abs() {
                let s = v0.signum();
                b.push(v0.abs() / dec, -s * dec, 0.0);
                b.snap_velocity(0.0);
            }
        }

        // From here the axis is at rest, or moving towards the target with
        // a stopping distance that fits.
        let rem = target - b.position();
        if rem != 0.0 {
            let s = rem.signum();
            let dist = rem.abs();
            let u0 = (b.velocity() * s).max(0.0);
            if u0 > vmax {
                // Slow down to the limit, cruise, stop.
                b.push((u0 - vmax) / dec, -s * dec, 0.0);
                b.snap_velocity(s * vmax);
                let cruise_dist = (dist - u0 * u0 / (2.0 * dec)).max(0.0);
                b.push(cruise_dist / vmax, 0.0, 0.0);
                cruise = cruise_dist > 0.0;
                b.push(vmax / dec, -s * dec, 0.0);
            } else {
                // Peak speed of the triangular profile: accelerate from u0
                // to vp then decelerate to 0 covers exactly `dist`.
                let vp_tri = ((2.0 * acc * dec * dist + dec * u0 * u0) / (acc + dec)).sqrt();
                let vp = vp_tri.min(vmax).max(u0);
                b.push((vp - u0) / acc, s * acc, 0.0);
                b.snap_velocity(s * vp);
                if vp_tri > vmax {
                    let cruise_dist =
                        (dist - (vmax * vmax - u0 * u0) / (2.0 * acc) - vmax * vmax / (2.0 * dec))
                            .max(0.0);
                    b.push(cruise_dist / vmax, 0.0, 0.0);
                    cruise = cruise_dist > 0.0;
                }
                b.push(vp / dec, -s * dec, 0.0);
            }
        }

        let path = b.finish(target);
        if !path.is_finite() {
            return Err(MotionError::Unrepresentable(
                "trapezoid profile overflows f64",
            ));
        }
        Ok(Self {
            start,
            start_velocity,
            target,
            limits,
            cruise,
            path,
        })
    }

    /// A move that starts at rest.
    ///
    /// # Errors
    /// As [`TrapezoidProfile::new`].
    pub fn rest_to_rest(start: f64, target: f64, limits: Limits) -> Result<Self, MotionError> {
        Self::new(start, 0.0, target, limits)
    }

    /// Total duration in seconds (0 for a zero-length move from rest).
    pub fn duration(&self) -> f64 {
        self.path.duration()
    }

    /// `(position, velocity, acceleration)` at `t` seconds after the start.
    /// `t <= 0` (or NaN) gives the start state; `t >= duration()` gives
    /// exactly `(target, 0.0, 0.0)`.
    pub fn sample(&self, t: f64) -> (f64, f64, f64) {
        self.path.sample(t)
    }

    /// Start position.
    pub fn start(&self) -> f64 {
        self.start
    }

    /// Start velocity.
    pub fn start_velocity(&self) -> f64 {
        self.start_velocity
    }

    /// Target position.
    pub fn target(&self) -> f64 {
        self.target
    }

    /// The limits the profile was planned with.
    pub fn limits(&self) -> Limits {
        self.limits
    }

    /// Whether the profile has a constant-velocity phase (false for a
    /// triangular profile, a pure stop, or a zero-length move).
    pub fn has_cruise(&self) -> bool {
        self.cruise
    }

    /// Largest speed reached during the move (including the start speed).
    pub fn peak_velocity(&self) -> f64 {
        self.path.peak_speed()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lim(v: f64, a: f64, d: f64) -> Limits {
        Limits::new(v, a, d).unwrap()
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-9 * (1.0 + a.abs().max(b.abs()))
    }

    #[test]
    fn symmetric_trapezoid_has_textbook_duration() {
        // 10 units at v=2, a=1: 2 s accel (2 units), 2 s decel (2 units),
        // 6 units cruise = 3 s. Total 7 s.
        let p = TrapezoidProfile::rest_to_rest(0.0, 10.0, lim(2.0, 1.0, 1.0)).unwrap();
        assert!(close(p.duration(), 7.0), "{}", p.duration());
        assert!(p.has_cruise());
        assert_eq!(p.sample(7.0), (10.0, 0.0, 0.0));
        let (x, v, a) = p.sample(1.0);
        assert!(close(x, 0.5) && close(v, 1.0) && close(a, 1.0));
        let (x, v, a) = p.sample(3.5);
        assert!(close(x, 5.0) && close(v, 2.0) && a == 0.0);
        let (x, v, a) = p.sample(6.0);
        assert!(close(x, 9.5) && close(v, 1.0) && close(a, -1.0));
    }

    #[test]
    fn long_asymmetric_braking_is_continuous_in_its_second_half() {
        // Final segment 10 s long: sampled from its end in the second half.
        let p = TrapezoidProfile::rest_to_rest(0.0, 50.0, lim(10.0, 100.0, 1.0)).unwrap();
        let t_end = p.duration();
        let (x, v, a) = p.sample(t_end - 2.0);
        assert!(
            close(x, 48.0) && close(v, 2.0) && close(a, -1.0),
            "{x} {v} {a}"
        );
        let (x, v, _) = p.sample(t_end - 8.0);
        assert!(close(x, 18.0) && close(v, 8.0), "{x} {v}");
    }

    #[test]
    fn triangular_profile_never_cruises() {
        // 1 unit at a=d=1: peak 1 at t=1, total 2 s; limit 5 never reached.
        let p = TrapezoidProfile::rest_to_rest(0.0, 1.0, lim(5.0, 1.0, 1.0)).unwrap();
        assert!(!p.has_cruise());
        assert!(close(p.duration(), 2.0));
        assert!(close(p.peak_velocity(), 1.0));
    }

    #[test]
    fn asymmetric_triangular() {
        // a=2, d=1, dist 3: vp^2 = 2*2*1*3/3 = 4 -> vp=2, t_acc=1, t_dec=2.
        let p = TrapezoidProfile::rest_to_rest(0.0, 3.0, lim(10.0, 2.0, 1.0)).unwrap();
        assert!(close(p.duration(), 3.0));
        assert!(close(p.peak_velocity(), 2.0));
        let (x, v, _) = p.sample(1.0);
        assert!(close(x, 1.0) && close(v, 2.0));
    }

    #[test]
    fn negative_direction_mirrors_positive() {
        let l = lim(2.0, 1.0, 3.0);
        let p = TrapezoidProfile::rest_to_rest(5.0, 15.0, l).unwrap();
        let n = TrapezoidProfile::rest_to_rest(5.0, -5.0, l).unwrap();
        assert!(close(p.duration(), n.duration()));
        for i in 0..=100 {
            let t = p.duration() * f64::from(i) / 100.0;
            let (xp, vp, ap) = p.sample(t);
            let (xn, vn, an) = n.sample(t);
            assert!(
                close(xp - 5.0, 5.0 - xn) && close(vp, -vn) && close(ap, -an),
                "t={t}"
            );
        }
    }

    #[test]
    fn zero_length_move() {
        let p = TrapezoidProfile::rest_to_rest(3.0, 3.0, lim(1.0, 1.0, 1.0)).unwrap();
        assert_eq!(p.duration(), 0.0);
        assert_eq!(p.sample(0.0), (3.0, 0.0, 0.0));
        assert_eq!(p.sample(1.0), (3.0, 0.0, 0.0));
    }

    #[test]
    fn moving_away_from_target_brakes_and_reverses() {
        // At 0 moving at -2 (away from +10), decel 1: stops after 2 s at -2,
        // then goes back 12 units.
        let p = TrapezoidProfile::new(0.0, -2.0, 10.0, lim(3.0, 1.0, 1.0)).unwrap();
        let (x, v, a) = p.sample(1.0);
        assert!(close(x, -1.5) && close(v, -1.0) && close(a, 1.0));
        let (x, v, _) = p.sample(2.0);
        assert!(close(x, -2.0) && v.abs() < 1e-12);
        // Rest-to-rest 12 units at v=3,a=d=1: 3+3 s ramps (9 units) + 1 s cruise.
        assert!(close(p.duration(), 2.0 + 7.0), "{}", p.duration());
        assert_eq!(p.sample(p.duration()), (10.0, 0.0, 0.0));
    }

    #[test]
    fn moving_at_target_stops_and_returns() {
        let p = TrapezoidProfile::new(0.0, 1.0, 0.0, lim(1.0, 1.0, 1.0)).unwrap();
        // Stops at 0.5 after 1 s, then returns 0.5 (triangular, 2*sqrt(0.5)).
        assert!(close(p.duration(), 1.0 + 2.0 * 0.5f64.sqrt()));
        let (x, v, _) = p.sample(1.0);
        assert!(close(x, 0.5) && v.abs() < 1e-12);
    }

    #[test]
    fn overshoot_when_too_fast_to_stop() {
        // Towards target 1 at v=2, decel 1: stopping distance 2 > 1.
        let p = TrapezoidProfile::new(0.0, 2.0, 1.0, lim(2.0, 1.0, 1.0)).unwrap();
        let (x, v, _) = p.sample(2.0);
        assert!(close(x, 2.0) && v.abs() < 1e-12);
        assert_eq!(p.sample(p.duration()).0, 1.0);
    }

    #[test]
    fn start_above_velocity_limit_slows_to_limit() {
        let p = TrapezoidProfile::new(0.0, 4.0, 100.0, lim(2.0, 1.0, 1.0)).unwrap();
        let (_, v, a) = p.sample(1.0);
        assert!(close(v, 3.0) && close(a, -1.0));
        let (_, v, _) = p.sample(10.0);
        assert!(close(v, 2.0));
        assert!(close(p.peak_velocity(), 4.0));
    }

    #[test]
    fn exact_stop_on_target_from_moving_start() {
        // Stopping distance exactly equals the remaining distance.
        let p = TrapezoidProfile::new(0.0, 2.0, 2.0, lim(2.0, 1.0, 1.0)).unwrap();
        assert!(close(p.duration(), 2.0));
        assert!(!p.has_cruise());
    }

    #[test]
    fn invalid_inputs_are_typed_errors() {
        assert!(matches!(
            Limits::new(0.0, 1.0, 1.0),
            Err(MotionError::InvalidLimit {
                name: "max velocity",
                ..
            })
        ));
        assert!(matches!(
            Limits::new(1.0, -1.0, 1.0),
            Err(MotionError::InvalidLimit {
                name: "acceleration",
                ..
            })
        ));
        assert!(matches!(
            Limits::new(1.0, 1.0, f64::NAN),
            Err(MotionError::InvalidLimit {
                name: "deceleration",
                ..
            })
        ));
        assert!(matches!(
            Limits::symmetric(f64::INFINITY, 1.0),
            Err(MotionError::InvalidLimit { .. })
        ));
        let l = lim(1.0, 1.0, 1.0);
        assert!(matches!(
            TrapezoidProfile::new(f64::NAN, 0.0, 1.0, l),
            Err(MotionError::NonFinite { .. })
        ));
        assert!(matches!(
            TrapezoidProfile::new(0.0, f64::INFINITY, 1.0, l),
            Err(MotionError::NonFinite { .. })
        ));
        assert!(matches!(
            TrapezoidProfile::new(-f64::MAX, 0.0, f64::MAX, l),
            Err(MotionError::NonFinite { .. })
        ));
    }

    #[test]
    fn sample_clamps_outside_the_move() {
        let p = TrapezoidProfile::new(1.0, 0.5, 4.0, lim(1.0, 1.0, 1.0)).unwrap();
        assert_eq!(p.sample(-1.0).0, 1.0);
        assert_eq!(p.sample(-1.0).1, 0.5);
        assert_eq!(p.sample(f64::NAN).0, 1.0);
        assert_eq!(p.sample(1e9), (4.0, 0.0, 0.0));
    }
}
