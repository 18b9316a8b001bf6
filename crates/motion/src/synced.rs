//! Coordinated multi-axis moves that end at the same instant.

use crate::{Limits, MotionError, TrapezoidProfile};

/// One axis of a [`SyncedMove`]: a rest-to-rest move with its own limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisMove {
    /// Start position (the axis is at rest there).
    pub start: f64,
    /// Target position.
    pub target: f64,
    /// This axis's limits.
    pub limits: Limits,
}

impl AxisMove {
    /// Convenience constructor.
    pub fn new(start: f64, target: f64, limits: Limits) -> Self {
        Self {
            start,
            target,
            limits,
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
struct SyncedAxis {
    /// The axis's own minimum-time profile.
    profile: TrapezoidProfile,
    /// `profile.duration() / move duration`, in `[0, 1]`.
    ratio: f64,
}

/// Several rest-to-rest axis moves stretched to a common duration.
///
/// Each axis first gets its own time-optimal [`TrapezoidProfile`]; the move
/// lasts as long as the slowest one, `T = max(T_i)`. Every other axis is
/// **time-scaled** by `λ_i = T / T_i >= 1`: it follows `p_i(t / λ_i)`, which
/// is exactly the trapezoid planned with limits `v/λ`, `a/λ²`, `d/λ²` — same
/// shape, velocity divided by `λ_i`, acceleration by `λ_i²`. Hence every
/// axis stays within its own limits, starts and ends at rest, and all axes
/// reach their targets together at `t = T`: `sample(t)` for `t >= T`
/// returns exactly the targets. Axes with a zero-length move stay put.
#[derive(Debug, Clone, PartialEq)]
pub struct SyncedMove {
    axes: Vec<SyncedAxis>,
    duration: f64,
}

impl SyncedMove {
    /// Plan a coordinated move.
    ///
    /// # Errors
    /// [`MotionError::NoAxes`] if `axes` is empty; otherwise the errors of
    /// [`TrapezoidProfile::new`] for the first offending axis.
    pub fn new<I: IntoIterator<Item = AxisMove>>(axes: I) -> Result<Self, MotionError> {
        let profiles = axes
            .into_iter()
            .map(|a| TrapezoidProfile::rest_to_rest(a.start, a.target, a.limits))
            .collect::<Result<Vec<_>, _>>()?;
        if profiles.is_empty() {
            return Err(MotionError::NoAxes);
        }
        let duration = profiles
            .iter()
            .map(TrapezoidProfile::duration)
            .fold(0.0, f64::max);
        let axes = profiles
            .into_iter()
            .map(|profile| {
                let ratio = if duration > 0.0 {
                    profile.duration() / duration
                } else {
                    0.0
                };
                SyncedAxis { profile, ratio }
            })
            .collect();
        Ok(Self { axes, duration })
    }

    /// Common duration in seconds (that of the slowest axis).
    pub fn duration(&self) -> f64 {
        self.duration
    }

    /// Number of axes.
    pub fn axis_count(&self) -> usize {
        self.axes.len()
    }

    /// The minimum-time (unstretched) profile of axis `i`.
    pub fn profile(&self, i: usize) -> Option<&TrapezoidProfile> {
        self.axes.get(i).map(|a| &a.profile)
    }

    /// The time-scale factor `λ_i = duration() / T_i >= 1` of axis `i`
    /// (infinite for a zero-length axis move).
    pub fn time_scale(&self, i: usize) -> Option<f64> {
        self.axes.get(i).map(|a| 1.0 / a.ratio)
    }

    /// Target positions, one per axis.
    pub fn targets(&self) -> Vec<f64> {
        self.axes.iter().map(|a| a.profile.target()).collect()
    }

    /// Positions of all axes at `t` seconds after the start.
    pub fn sample(&self, t: f64) -> Vec<f64> {
        self.sample_states(t)
            .into_iter()
            .map(|(p, _, _)| p)
            .collect()
    }

    /// Positions written into `out` without allocating (for cyclic loops).
    /// Only the first `min(out.len(), axis_count())` entries are written.
    pub fn sample_into(&self, t: f64, out: &mut [f64]) {
        for (o, a) in out.iter_mut().zip(&self.axes) {
            *o = Self::axis_state(a, t, self.duration).0;
        }
    }

    /// `(position, velocity, acceleration)` of every axis at `t`.
    pub fn sample_states(&self, t: f64) -> Vec<(f64, f64, f64)> {
        self.axes
            .iter()
            .map(|a| Self::axis_state(a, t, self.duration))
            .collect()
    }

    fn axis_state(a: &SyncedAxis, t: f64, duration: f64) -> (f64, f64, f64) {
        if t >= duration || a.ratio == 0.0 {
            return (a.profile.target(), 0.0, 0.0);
        }
        let r = a.ratio;
        let (p, v, acc) = a.profile.sample(t * r);
        (p, v * r, acc * r * r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slower_axis_sets_the_duration_and_all_end_together() {
        let fast = Limits::symmetric(10.0, 10.0).unwrap();
        let slow = Limits::symmetric(1.0, 1.0).unwrap();
        let m = SyncedMove::new([
            AxisMove::new(0.0, 10.0, fast),
            AxisMove::new(0.0, -10.0, slow),
            AxisMove::new(5.0, 5.0, slow),
        ])
        .unwrap();
        let t_slow = TrapezoidProfile::rest_to_rest(0.0, -10.0, slow)
            .unwrap()
            .duration();
        assert_eq!(m.duration(), t_slow);
        assert_eq!(m.sample(m.duration()), vec![10.0, -10.0, 5.0]);
        assert_eq!(m.time_scale(1), Some(1.0));
        assert!(m.time_scale(0).unwrap() > 1.0);
        // Halfway: the symmetric profiles are at their midpoints.
        let mid = m.sample(m.duration() / 2.0);
        assert!((mid[0] - 5.0).abs() < 1e-9 && (mid[1] + 5.0).abs() < 1e-9 && mid[2] == 5.0);
        let mut out = [0.0; 3];
        m.sample_into(m.duration() / 2.0, &mut out);
        assert_eq!(out.to_vec(), mid);
    }

    #[test]
    fn empty_is_an_error() {
        assert_eq!(SyncedMove::new([]), Err(MotionError::NoAxes));
    }

    #[test]
    fn all_zero_moves() {
        let l = Limits::symmetric(1.0, 1.0).unwrap();
        let m = SyncedMove::new([AxisMove::new(1.0, 1.0, l), AxisMove::new(2.0, 2.0, l)]).unwrap();
        assert_eq!(m.duration(), 0.0);
        assert_eq!(m.sample(0.0), vec![1.0, 2.0]);
    }
}
