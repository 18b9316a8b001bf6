//! Pure-maths motion planning for servo axes.
//!
//! Nothing in this crate performs I/O or reads a clock: every time is passed
//! in, either as `f64` seconds measured from the start of a move (profiles)
//! or as a [`std::time::Duration`] (cycle times, jog steps, and the pacer's
//! `now`, which is measured from an arbitrary monotonic origin chosen by the
//! caller). Positions and velocities are in whatever unit the caller uses
//! (counts, mm, degrees…), consistently.
//!
//! * [`TrapezoidProfile`]: time-optimal velocity-limited,
//!   acceleration-limited point-to-point move from any start velocity.
//! * [`SCurveProfile`]: the same with a jerk limit (continuous acceleration).
//! * [`SyncedMove`]: several axes, each with its own limits, arriving at the
//!   same instant (the faster axes are slowed down by time-scaling).
//! * [`Interpolator`]: turns any [`Trajectory`] into the per-cycle setpoint
//!   sequence for cyclic synchronous position mode.
//! * [`JogGenerator`]: online velocity jogging with acceleration limits.
//! * [`JogPacer`]: evens out bursty handwheel units at a bounded rate with a
//!   bounded backlog.
//!
//! Sign conventions: "acceleration" limits speeding up (|v| growing),
//! "deceleration" limits slowing down (|v| shrinking); both are magnitudes.

#![deny(missing_docs, unreachable_pub)]
// A dependency nothing uses fails CI (clippy -D warnings). Test builds are
// left out: their dev-dependencies serve the integration tests.
#![cfg_attr(not(test), warn(unused_crate_dependencies))]

mod interpolator;
mod jog;
mod limits;
mod pacer;
mod scurve;
mod segment;
mod synced;
mod trapezoid;

pub use interpolator::{Interpolator, Trajectory};
pub use jog::JogGenerator;
pub use limits::Limits;
pub use pacer::{JogPacer, PacerStats, PushResult};
pub use scurve::SCurveProfile;
pub use synced::{AxisMove, SyncedMove};
pub use trapezoid::TrapezoidProfile;

/// Errors returned by the validated constructors of this crate.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MotionError {
    /// A limit (velocity, acceleration, jerk, rate, cycle time, backlog…) is
    /// NaN, infinite, zero or negative.
    #[error("{name} must be finite and > 0, got {value}")]
    InvalidLimit {
        /// Which limit.
        name: &'static str,
        /// The rejected value.
        value: f64,
    },
    /// A position or velocity input is NaN or infinite.
    #[error("{name} must be finite, got {value}")]
    NonFinite {
        /// Which input.
        name: &'static str,
        /// The rejected value.
        value: f64,
    },
    /// The start velocity exceeds the velocity limit where the profile type
    /// cannot handle that ([`SCurveProfile`]).
    #[error("start velocity {velocity} exceeds the velocity limit {max_velocity}")]
    StartVelocityTooHigh {
        /// The requested start velocity.
        velocity: f64,
        /// The velocity limit.
        max_velocity: f64,
    },
    /// A [`SyncedMove`] was built with no axes.
    #[error("a synchronised move needs at least one axis")]
    NoAxes,
    /// The inputs are finite but the resulting plan is not (f64 overflow, or
    /// too many interpolation cycles).
    #[error("move is not representable: {0}")]
    Unrepresentable(&'static str),
}

/// `Ok(value)` if finite, else [`MotionError::NonFinite`].
pub(crate) fn check_finite(name: &'static str, value: f64) -> Result<f64, MotionError> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(MotionError::NonFinite { name, value })
    }
}

/// `Ok(value)` if finite and strictly positive, else
/// [`MotionError::InvalidLimit`].
pub(crate) fn check_limit(name: &'static str, value: f64) -> Result<f64, MotionError> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(MotionError::InvalidLimit { name, value })
    }
}
