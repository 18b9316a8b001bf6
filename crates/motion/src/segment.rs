//! Piecewise constant-jerk trajectories (shared by the profile types).
//!
//! A plan is a list of contiguous segments; each stores both its start and
//! its end state and is evaluated from whichever end is nearer, so that
//! boundary states are reproduced exactly (continuity up to rounding inside
//! a segment) and the last segment lands exactly on the target.

/// Kinematic state at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct State {
    pub p: f64,
    pub v: f64,
    pub a: f64,
}

impl State {
    /// Advance by `tau` seconds under constant `jerk`.
    fn advance(self, tau: f64, jerk: f64) -> State {
        State {
            p: self.p + self.v * tau + self.a * tau * tau / 2.0 + jerk * tau * tau * tau / 6.0,
            v: self.v + self.a * tau + jerk * tau * tau / 2.0,
            a: self.a + jerk * tau,
        }
    }

    /// Go back by `sigma` seconds under constant `jerk`.
    fn retreat(self, sigma: f64, jerk: f64) -> State {
        State {
            p: self.p - self.v * sigma + self.a * sigma * sigma / 2.0
                - jerk * sigma * sigma * sigma / 6.0,
            v: self.v - self.a * sigma + jerk * sigma * sigma / 2.0,
            a: self.a - jerk * sigma,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Segment {
    t0: f64,
    t1: f64,
    start: State,
    end: State,
    jerk: f64,
}

impl Segment {
    fn eval(&self, t: f64) -> State {
        let tau = t - self.t0;
        let sigma = self.t1 - t;
        if tau <= sigma {
            self.start.advance(tau, self.jerk)
        } else {
            self.end.retreat(sigma, self.jerk)
        }
    }
}

/// A finished plan: contiguous segments from `t = 0` to `duration()`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Piecewise {
    segments: Vec<Segment>,
    start: State,
    target: f64,
}

impl Piecewise {
    /// Seconds from the start of the plan to rest on the target (0 for a
    /// plan with no segments: already there).
    pub(crate) fn duration(&self) -> f64 {
        self.segments.last().map_or(0.0, |s| s.t1)
    }

    /// `(pos, vel, acc)` at `t`: clamped to the start state for `t <= 0`
    /// (or NaN) and to `(target, 0, 0)` for `t >= duration()`.
    pub(crate) fn sample(&self, t: f64) -> (f64, f64, f64) {
        let Some(first) = self.segments.first() else {
            return (self.target, 0.0, 0.0);
        };
        if t >= self.duration() {
            return (self.target, 0.0, 0.0);
        }
        if t.is_nan() || t <= 0.0 {
            return (self.start.p, self.start.v, first.start.a);
        }
        let i = self.segments.partition_point(|s| s.t1 <= t);
        let s = self.segments[i.min(self.segments.len() - 1)].eval(t);
        (s.p, s.v, s.a)
    }

    /// Largest speed reached (velocity extrema are at segment boundaries for
    /// every plan built here, since acceleration changes sign only there).
    pub(crate) fn peak_speed(&self) -> f64 {
        self.segments
            .iter()
            .map(|s| s.start.v.abs().max(s.end.v.abs()))
            .fold(self.start.v.abs(), f64::max)
    }

    /// Whether every boundary state is finite.
    pub(crate) fn is_finite(&self) -> bool {
        self.duration().is_finite()
            && self.segments.iter().all(|s| {
                [s.start.p, s.start.v, s.start.a, s.end.p, s.end.v, s.end.a]
                    .iter()
                    .all(|x| x.is_finite())
            })
    }
}

/// Appends segments forward from a start state.
#[derive(Debug)]
pub(crate) struct Builder {
    t: f64,
    start: State,
    state: State,
    segments: Vec<Segment>,
}

impl Builder {
    /// A builder at position `p` moving at `v` with no acceleration, at
    /// `t = 0`; segments are appended from there.
    pub(crate) fn new(p: f64, v: f64) -> Self {
        let start = State { p, v, a: 0.0 };
        Self {
            t: 0.0,
            start,
            state: start,
            segments: Vec::with_capacity(8),
        }
    }

    /// Position at the end of the segments appended so far.
    pub(crate) fn position(&self) -> f64 {
        self.state.p
    }

    /// Velocity at the end of the segments appended so far.
    pub(crate) fn velocity(&self) -> f64 {
        self.state.v
    }

    /// Append a segment of `duration` starting with acceleration `a0` and
    /// constant `jerk`. Non-positive (or NaN) durations are skipped.
    pub(crate) fn push(&mut self, duration: f64, a0: f64, jerk: f64) {
        if duration.is_nan() || duration <= 0.0 {
            return;
        }
        let start = State {
            a: a0,
            ..self.state
        };
        let end = start.advance(duration, jerk);
        let t1 = self.t + duration;
        self.segments.push(Segment {
            t0: self.t,
            t1,
            start,
            end,
            jerk,
        });
        self.t = t1;
        self.state = end;
    }

    /// Overwrite the current velocity (removes rounding at phase ends).
    pub(crate) fn snap_velocity(&mut self, v: f64) {
        self.state.v = v;
        if let Some(last) = self.segments.last_mut() {
            last.end.v = v;
        }
    }

    /// Overwrite the current acceleration (removes rounding at phase ends).
    pub(crate) fn snap_acceleration(&mut self, a: f64) {
        self.state.a = a;
        if let Some(last) = self.segments.last_mut() {
            last.end.a = a;
        }
    }

    /// Finish at rest exactly on `target` (the last segment's end
    /// acceleration is kept: a trapezoid's final segment ends braking).
    pub(crate) fn finish(mut self, target: f64) -> Piecewise {
        if let Some(last) = self.segments.last_mut() {
            last.end.p = target;
            last.end.v = 0.0;
        }
        Piecewise {
            segments: self.segments,
            start: self.start,
            target,
        }
    }
}
