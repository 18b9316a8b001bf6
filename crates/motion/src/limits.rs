//! Kinematic limits of one axis.

use crate::{MotionError, check_limit};

/// Validated kinematic limits of one axis: all three are finite and > 0.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    max_velocity: f64,
    acceleration: f64,
    deceleration: f64,
}

impl Limits {
    /// Limits with separate acceleration (speeding up) and deceleration
    /// (slowing down) magnitudes.
    ///
    /// # Errors
    /// [`MotionError::InvalidLimit`] if any value is NaN, infinite, zero or
    /// negative.
    pub fn new(
        max_velocity: f64,
        acceleration: f64,
        deceleration: f64,
    ) -> Result<Self, MotionError> {
        Ok(Self {
            max_velocity: check_limit("max velocity", max_velocity)?,
            acceleration: check_limit("acceleration", acceleration)?,
            deceleration: check_limit("deceleration", deceleration)?,
        })
    }

    /// Limits with the same magnitude for acceleration and deceleration.
    ///
    /// # Errors
    /// As [`Limits::new`].
    pub fn symmetric(max_velocity: f64, acceleration: f64) -> Result<Self, MotionError> {
        Self::new(max_velocity, acceleration, acceleration)
    }

    /// Maximum speed (magnitude).
    pub fn max_velocity(&self) -> f64 {
        self.max_velocity
    }

    /// Maximum acceleration magnitude while speeding up.
    pub fn acceleration(&self) -> f64 {
        self.acceleration
    }

    /// Maximum deceleration magnitude while slowing down (including braking
    /// before a reversal).
    pub fn deceleration(&self) -> f64 {
        self.deceleration
    }
}
