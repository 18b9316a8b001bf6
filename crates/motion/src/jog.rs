//! Online velocity jogging.

use std::time::Duration;

use crate::{Limits, MotionError, check_finite};

/// Online velocity-mode jog: the commanded velocity can change at any time
/// and the output ramps towards it within the limits.
///
/// * Speeding up (|v| growing towards the target velocity) uses the
///   acceleration limit; slowing down, including braking through zero for a
///   direction change, uses the deceleration limit.
/// * The target velocity is clamped to `±max_velocity`.
/// * [`JogGenerator::step`] integrates exactly (piecewise-constant
///   acceleration is split at the instants the velocity reaches zero or the
///   target), so the result does not depend on how `dt` is chopped up,
///   beyond rounding.
#[derive(Debug, Clone, PartialEq)]
pub struct JogGenerator {
    position: f64,
    velocity: f64,
    target_velocity: f64,
    limits: Limits,
}

impl JogGenerator {
    /// A generator at rest at `position`.
    ///
    /// # Errors
    /// [`MotionError::NonFinite`] if `position` is not finite.
    pub fn new(position: f64, limits: Limits) -> Result<Self, MotionError> {
        Ok(Self {
            position: check_finite("position", position)?,
            velocity: 0.0,
            target_velocity: 0.0,
            limits,
        })
    }

    /// Command a velocity. It is clamped to `±max_velocity`; NaN is treated
    /// as a stop (fail-safe). Returns the velocity actually targeted.
    pub fn set_target_velocity(&mut self, v: f64) -> f64 {
        let vmax = self.limits.max_velocity();
        self.target_velocity = if v.is_nan() {
            0.0
        } else {
            v.clamp(-vmax, vmax)
        };
        self.target_velocity
    }

    /// Decelerate to standstill (target velocity 0).
    pub fn stop(&mut self) {
        self.target_velocity = 0.0;
    }

    /// Replace the limits; the target velocity is re-clamped. A current
    /// speed above the new velocity limit is brought down with the new
    /// deceleration.
    pub fn set_limits(&mut self, limits: Limits) {
        self.limits = limits;
        self.set_target_velocity(self.target_velocity);
    }

    /// Advance by `dt`; returns the new `(position, velocity)`.
    pub fn step(&mut self, dt: Duration) -> (f64, f64) {
        let mut rem = dt.as_secs_f64();
        // At most: brake to zero, speed up to target, cruise.
        for _ in 0..4 {
            if rem <= 0.0 {
                break;
            }
            let (v, vt) = (self.velocity, self.target_velocity);
            if v == vt {
                self.position += v * rem;
                break;
            }
            let slowing = v != 0.0 && (vt * v <= 0.0 || vt.abs() < v.abs());
            let (accel, goal) = if slowing {
                let goal = if vt * v > 0.0 { vt } else { 0.0 };
                (-v.signum() * self.limits.deceleration(), goal)
            } else {
                ((vt - v).signum() * self.limits.acceleration(), vt)
            };
            let needed = (goal - v) / accel;
            if needed <= rem {
                self.position += (v + goal) / 2.0 * needed;
                self.velocity = goal;
                rem -= needed;
            } else {
                self.position += v * rem + accel * rem * rem / 2.0;
                self.velocity = v + accel * rem;
                rem = 0.0;
            }
        }
        (self.position, self.velocity)
    }

    /// Current position.
    pub fn position(&self) -> f64 {
        self.position
    }

    /// Current velocity.
    pub fn velocity(&self) -> f64 {
        self.velocity
    }

    /// Commanded (clamped) target velocity.
    pub fn target_velocity(&self) -> f64 {
        self.target_velocity
    }

    /// Current limits.
    pub fn limits(&self) -> Limits {
        self.limits
    }

    /// True when at rest and commanded to stay at rest.
    pub fn is_stopped(&self) -> bool {
        self.velocity == 0.0 && self.target_velocity == 0.0
    }

    /// Signed distance still travelled if [`JogGenerator::stop`] were called
    /// now: `v·|v| / (2·deceleration)`.
    pub fn stopping_distance(&self) -> f64 {
        self.velocity * self.velocity.abs() / (2.0 * self.limits.deceleration())
    }

    /// Time to standstill if stopped now: `|v| / deceleration` (saturating
    /// at [`Duration::MAX`]).
    pub fn stopping_time(&self) -> Duration {
        Duration::try_from_secs_f64(self.velocity.abs() / self.limits.deceleration())
            .unwrap_or(Duration::MAX)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn ramps_up_cruises_and_stops() {
        let mut j = JogGenerator::new(0.0, Limits::new(2.0, 1.0, 4.0).unwrap()).unwrap();
        assert_eq!(j.set_target_velocity(5.0), 2.0);
        // 2 s to reach 2 (distance 2), then 1 s cruise (2).
        j.step(Duration::from_secs(3));
        assert!((j.position() - 4.0).abs() < 1e-12);
        assert_eq!(j.velocity(), 2.0);
        let sd = j.stopping_distance();
        assert!((sd - 0.5).abs() < 1e-12);
        j.stop();
        for _ in 0..600 {
            j.step(MS);
        }
        assert!(j.is_stopped());
        assert!((j.position() - 4.5).abs() < 1e-9, "{}", j.position());
    }

    #[test]
    fn reversal_brakes_with_deceleration_then_accelerates() {
        let mut j = JogGenerator::new(0.0, Limits::new(2.0, 1.0, 4.0).unwrap()).unwrap();
        j.set_target_velocity(2.0);
        j.step(Duration::from_secs(2));
        j.set_target_velocity(-2.0);
        // Braking from 2 at 4 takes 0.5 s, then 0.5 s at accel 1 -> -0.5.
        let (_, v) = j.step(Duration::from_secs(1));
        assert!((v + 0.5).abs() < 1e-12);
    }

    #[test]
    fn nan_target_stops() {
        let mut j = JogGenerator::new(0.0, Limits::symmetric(1.0, 1.0).unwrap()).unwrap();
        j.set_target_velocity(1.0);
        assert_eq!(j.set_target_velocity(f64::NAN), 0.0);
    }
}
