//! Jerk-limited ("S-curve") point-to-point profile.

use crate::segment::{Builder, Piecewise};
use crate::{Limits, MotionError, check_finite, check_limit};

/// A jerk-limited move from `(start, start_velocity)` (with zero start
/// acceleration) to rest at `target`.
///
/// Every velocity change (speed up, slow down, brake) is a jerk-limited
/// phase: jerk `±jerk` until the acceleration limit is reached, constant
/// acceleration, jerk back to zero acceleration (the constant part is absent
/// for small velocity changes). Acceleration is therefore continuous and
/// bounded by `acceleration` while speeding up and `deceleration` while
/// slowing down; the velocity never exceeds `max_velocity`.
///
/// Phases: optional brake-to-standstill (moving away from the target, or
/// too fast to stop in time: the move overshoots and comes back), speed-up
/// to the peak speed, optional cruise, stop exactly on the target. The peak
/// speed of short moves is found by bisection (the covered distance is
/// monotonic in it), so the plan is near-time-optimal within this shape.
///
/// Unlike [`crate::TrapezoidProfile`], a start speed above `max_velocity`
/// is rejected ([`MotionError::StartVelocityTooHigh`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SCurveProfile {
    start: f64,
    start_velocity: f64,
    target: f64,
    limits: Limits,
    jerk: f64,
    cruise: bool,
    path: Piecewise,
}

/// Timing of one jerk-limited velocity change of magnitude `dv`:
/// `(jerk ramp time, constant-acceleration time, peak acceleration)`.
fn phase_times(dv: f64, amax: f64, jerk: f64) -> (f64, f64, f64) {
    if dv * jerk >= amax * amax {
        (amax / jerk, dv / amax - amax / jerk, amax)
    } else {
        let ap = (dv * jerk).sqrt();
        (ap / jerk, 0.0, ap)
    }
}

fn phase_duration(dv: f64, amax: f64, jerk: f64) -> f64 {
    let (tj, th, _) = phase_times(dv, amax, jerk);
    2.0 * tj + th
}

/// Distance covered while changing speed from `u` to `w` (same sign, both
/// magnitudes): the phase is point-symmetric so the mean speed is the
/// average of the end speeds.
fn phase_distance(u: f64, w: f64, amax: f64, jerk: f64) -> f64 {
    (u + w) / 2.0 * phase_duration((w - u).abs(), amax, jerk)
}

/// Append a jerk-limited phase from the builder's current velocity to
/// `v_to`, using `amax` as the acceleration bound.
fn push_phase(b: &mut Builder, v_to: f64, amax: f64, jerk: f64) {
    let dv = v_to - b.velocity();
    if dv == 0.0 {
        return;
    }
    let s = dv.signum();
    let (tj, th, ap) = phase_times(dv.abs(), amax, jerk);
    b.push(tj, 0.0, s * jerk);
    b.snap_acceleration(s * ap);
    b.push(th, s * ap, 0.0);
    b.push(tj, s * ap, -s * jerk);
    b.snap_acceleration(0.0);
    b.snap_velocity(v_to);
}

impl SCurveProfile {
    /// Plan a jerk-limited move.
    ///
    /// # Errors
    /// [`MotionError::InvalidLimit`] for a non-finite or non-positive
    /// `jerk`; [`MotionError::NonFinite`] for non-finite positions/velocity;
    /// [`MotionError::StartVelocityTooHigh`] if `|start_velocity|` exceeds
    /// the velocity limit; [`MotionError::Unrepresentable`] on overflow.
    pub fn new(
        start: f64,
        start_velocity: f64,
        target: f64,
        limits: Limits,
        jerk: f64,
    ) -> Result<Self, MotionError> {
        check_finite("start position", start)?;
        check_finite("start velocity", start_velocity)?;
        check_finite("target position", target)?;
        let jerk = check_limit("jerk", jerk)?;
        let d = check_finite("target - start", target - start)?;
        let vmax = limits.max_velocity();
        let acc = limits.acceleration();
        let dec = limits.deceleration();
        let v0 = start_velocity;
        if v0.abs() > vmax {
            return Err(MotionError::StartVelocityTooHigh {
                velocity: v0,
                max_velocity: vmax,
            });
        }

        let mut b = Builder::new(start, v0);
        let mut cruise = false;

        if v0 != 0.0 {
            let stopping = phase_distance(0.0, v0.abs(), dec, jerk);
            if d * v0 <= 0.0 || stopping > d.abs() {
                push_phase(&mut b, 0.0, dec, jerk);
            }
        }

        let rem = target - b.position();
        if rem != 0.0 {
            let s = rem.signum();
            let dist = rem.abs();
            let u0 = (b.velocity() * s).max(0.0);
            let covered =
                |vp: f64| phase_distance(u0, vp, acc, jerk) + phase_distance(0.0, vp, dec, jerk);
            let vp = if covered(vmax) <= dist {
                vmax
            } else {
                // covered(u0) <= dist (the stop fits), covered(vmax) > dist.
                let (mut lo, mut hi) = (u0, vmax);
                for _ in 0..200 {
                    let mid = 0.5 * (lo + hi);
                    if mid <= lo || mid >= hi {
                        break;
                    }
                    if covered(mid) <= dist {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                lo
            };
            push_phase(&mut b, s * vp, acc, jerk);
            if vp > 0.0 {
                let cruise_dist = (dist - covered(vp)).max(0.0);
                b.push(cruise_dist / vp, 0.0, 0.0);
                cruise = vp == vmax && cruise_dist > 0.0;
            }
            push_phase(&mut b, 0.0, dec, jerk);
        }

        let path = b.finish(target);
        if !path.is_finite() {
            return Err(MotionError::Unrepresentable(
                "s-curve profile overflows f64",
            ));
        }
        Ok(Self {
            start,
            start_velocity,
            target,
            limits,
            jerk,
            cruise,
            path,
        })
    }

    /// Total duration in seconds.
    pub fn duration(&self) -> f64 {
        self.path.duration()
    }

    /// `(position, velocity, acceleration)` at `t` seconds after the start;
    /// clamped like [`crate::TrapezoidProfile::sample`].
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

    /// The jerk limit.
    pub fn jerk(&self) -> f64 {
        self.jerk
    }

    /// Whether the profile cruises at the velocity limit.
    pub fn has_cruise(&self) -> bool {
        self.cruise
    }

    /// Largest speed reached during the move.
    pub fn peak_velocity(&self) -> f64 {
        self.path.peak_speed()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-9 * (1.0 + a.abs().max(b.abs()))
    }

    #[test]
    fn long_move_has_seven_phases_and_textbook_duration() {
        // v=1, a=1, j=10: each ramp 0.1 s, speed-up takes 1.1 s, covers
        // 0.55. Two ramps cover 1.1; 10 units leave 8.9 at v=1.
        let l = Limits::symmetric(1.0, 1.0).unwrap();
        let p = SCurveProfile::new(0.0, 0.0, 10.0, l, 10.0).unwrap();
        assert!(close(p.duration(), 1.1 + 8.9 + 1.1), "{}", p.duration());
        assert!(p.has_cruise());
        let (_, _, a) = p.sample(0.05);
        assert!(close(a, 0.5));
        assert_eq!(p.sample(p.duration()), (10.0, 0.0, 0.0));
    }

    #[test]
    fn short_move_is_found_by_bisection() {
        let l = Limits::symmetric(10.0, 1.0).unwrap();
        let p = SCurveProfile::new(0.0, 0.0, 0.5, l, 5.0).unwrap();
        assert!(!p.has_cruise());
        assert!(p.peak_velocity() < 10.0);
        let (x, v, _) = p.sample(p.duration() * 0.999_999);
        assert!((x - 0.5).abs() < 1e-9 && v.abs() < 1e-6);
    }

    #[test]
    fn rejects_bad_jerk_and_fast_start() {
        let l = Limits::symmetric(1.0, 1.0).unwrap();
        assert!(matches!(
            SCurveProfile::new(0.0, 0.0, 1.0, l, 0.0),
            Err(MotionError::InvalidLimit { name: "jerk", .. })
        ));
        assert!(matches!(
            SCurveProfile::new(0.0, 2.0, 1.0, l, 1.0),
            Err(MotionError::StartVelocityTooHigh { .. })
        ));
    }

    #[test]
    fn reversal_brakes_first() {
        let l = Limits::symmetric(2.0, 1.0).unwrap();
        let p = SCurveProfile::new(0.0, 1.0, -3.0, l, 4.0).unwrap();
        let (_, v, a) = p.sample(0.1);
        assert!(v > 0.0 && v < 1.0 && a < 0.0);
        assert_eq!(p.sample(p.duration()), (-3.0, 0.0, 0.0));
    }
}
