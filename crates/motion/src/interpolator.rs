//! Cyclic-synchronous-position setpoint generation.

use std::iter::FusedIterator;
use std::time::Duration;

use crate::{MotionError, SCurveProfile, SyncedMove, TrapezoidProfile};

/// Anything with a duration and a position at each instant, ending at rest
/// on a final position.
pub trait Trajectory {
    /// A position: `f64` for one axis, `Vec<f64>` for several.
    type Point;

    /// Duration in seconds.
    fn duration(&self) -> f64;

    /// Position `t` seconds after the start.
    fn position_at(&self, t: f64) -> Self::Point;

    /// The exact final position (the target).
    fn final_position(&self) -> Self::Point;
}

impl<T: Trajectory + ?Sized> Trajectory for &T {
    type Point = T::Point;

    fn duration(&self) -> f64 {
        (**self).duration()
    }

    fn position_at(&self, t: f64) -> Self::Point {
        (**self).position_at(t)
    }

    fn final_position(&self) -> Self::Point {
        (**self).final_position()
    }
}

impl Trajectory for TrapezoidProfile {
    type Point = f64;

    fn duration(&self) -> f64 {
        TrapezoidProfile::duration(self)
    }

    fn position_at(&self, t: f64) -> f64 {
        self.sample(t).0
    }

    fn final_position(&self) -> f64 {
        self.target()
    }
}

impl Trajectory for SCurveProfile {
    type Point = f64;

    fn duration(&self) -> f64 {
        SCurveProfile::duration(self)
    }

    fn position_at(&self, t: f64) -> f64 {
        self.sample(t).0
    }

    fn final_position(&self) -> f64 {
        self.target()
    }
}

impl Trajectory for SyncedMove {
    type Point = Vec<f64>;

    fn duration(&self) -> f64 {
        SyncedMove::duration(self)
    }

    fn position_at(&self, t: f64) -> Vec<f64> {
        self.sample(t)
    }

    fn final_position(&self) -> Vec<f64> {
        self.targets()
    }
}

/// Relative slack when counting cycles, so that a duration that is a whole
/// number of cycles up to rounding does not get an extra, duplicate cycle.
const CYCLE_SLACK: f64 = 1e-9;

/// Largest number of cycles accepted (keeps `k as f64 * cycle` exact).
const MAX_CYCLES: f64 = 9_007_199_254_740_992.0; // 2^53

/// Iterator over the setpoints of a [`Trajectory`] sampled every cycle, for
/// cyclic synchronous position (CSP) mode.
///
/// Setpoint `k` (1-based) is the position at `t = k × cycle`, computed from
/// `k` directly (no accumulated time error). There are
/// `n = max(1, ceil(duration / cycle))` setpoints and the last one is
/// **exactly** [`Trajectory::final_position`]. The start position (`t = 0`)
/// is not yielded: it is where the drive already is. A zero-length move
/// yields exactly one setpoint, the target.
///
/// Since every profile here keeps `|v| <= v_max`, consecutive setpoints
/// (and the start position to the first one) differ by at most
/// `v_max × cycle` (plus rounding).
#[derive(Debug, Clone)]
pub struct Interpolator<T> {
    trajectory: T,
    cycle: Duration,
    cycle_s: f64,
    total: u64,
    next: u64,
}

impl<T: Trajectory> Interpolator<T> {
    /// Sample `trajectory` every `cycle`.
    ///
    /// # Errors
    /// [`MotionError::InvalidLimit`] if `cycle` is zero;
    /// [`MotionError::Unrepresentable`] if the move needs more than 2^53
    /// cycles (or more than `usize::MAX`).
    pub fn new(trajectory: T, cycle: Duration) -> Result<Self, MotionError> {
        let cycle_s = cycle.as_secs_f64();
        if cycle_s <= 0.0 {
            return Err(MotionError::InvalidLimit {
                name: "cycle time",
                value: cycle_s,
            });
        }
        let cycles = (trajectory.duration() / cycle_s - CYCLE_SLACK)
            .ceil()
            .max(1.0);
        if cycles.is_nan() || cycles > MAX_CYCLES {
            return Err(MotionError::Unrepresentable(
                "too many interpolation cycles",
            ));
        }
        Ok(Self {
            trajectory,
            cycle,
            cycle_s,
            total: cycles as u64,
            next: 1,
        })
    }

    /// The cycle time.
    pub fn cycle(&self) -> Duration {
        self.cycle
    }

    /// Total number of setpoints the iterator yields from the start.
    pub fn total_cycles(&self) -> u64 {
        self.total
    }

    /// Number of setpoints not yet yielded.
    pub fn remaining(&self) -> u64 {
        (self.total + 1).saturating_sub(self.next)
    }

    /// The trajectory being sampled.
    pub fn trajectory(&self) -> &T {
        &self.trajectory
    }
}

impl<T: Trajectory> Iterator for Interpolator<T> {
    type Item = T::Point;

    fn next(&mut self) -> Option<T::Point> {
        let k = self.next;
        if k > self.total {
            return None;
        }
        self.next += 1;
        Some(if k == self.total {
            self.trajectory.final_position()
        } else {
            self.trajectory.position_at(k as f64 * self.cycle_s)
        })
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        // `total` fits in usize (checked in `new`).
        let n = usize::try_from(self.remaining()).unwrap_or(usize::MAX);
        (n, Some(n))
    }
}

impl<T: Trajectory> ExactSizeIterator for Interpolator<T> {}

impl<T: Trajectory> FusedIterator for Interpolator<T> {}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{AxisMove, Limits};

    #[test]
    fn whole_number_of_cycles() {
        // 7 s move at 1 ms: exactly 7000 setpoints, last = target.
        let l = Limits::symmetric(2.0, 1.0).unwrap();
        let p = TrapezoidProfile::rest_to_rest(0.0, 10.0, l).unwrap();
        let it = Interpolator::new(&p, Duration::from_millis(1)).unwrap();
        assert_eq!(it.total_cycles(), 7000);
        assert_eq!(it.len(), 7000);
        let v: Vec<f64> = it.collect();
        assert_eq!(*v.last().unwrap(), 10.0);
        assert!((v[999] - 0.5).abs() < 1e-9);
    }

    #[test]
    fn zero_move_yields_the_target_once() {
        let l = Limits::symmetric(2.0, 1.0).unwrap();
        let p = TrapezoidProfile::rest_to_rest(4.0, 4.0, l).unwrap();
        let v: Vec<f64> = Interpolator::new(p, Duration::from_millis(2))
            .unwrap()
            .collect();
        assert_eq!(v, vec![4.0]);
    }

    #[test]
    fn zero_cycle_is_rejected() {
        let l = Limits::symmetric(2.0, 1.0).unwrap();
        let p = TrapezoidProfile::rest_to_rest(0.0, 1.0, l).unwrap();
        assert!(matches!(
            Interpolator::new(p, Duration::ZERO),
            Err(MotionError::InvalidLimit {
                name: "cycle time",
                ..
            })
        ));
    }

    #[test]
    fn synced_move_setpoints_end_on_all_targets() {
        let a = Limits::symmetric(3.0, 5.0).unwrap();
        let b = Limits::symmetric(1.0, 2.0).unwrap();
        let m = SyncedMove::new([AxisMove::new(0.0, 7.0, a), AxisMove::new(1.0, -2.0, b)]).unwrap();
        let mut it = Interpolator::new(&m, Duration::from_millis(2)).unwrap();
        let n = it.len();
        let last = it.by_ref().last().unwrap();
        assert_eq!(last, vec![7.0, -2.0]);
        assert!(n >= 1);
        assert_eq!(it.next(), None);
    }
}
