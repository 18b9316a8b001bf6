//! Trying a set-point stream before a real planner drives it: a circle
//! that starts and ends at rest ([`Circle`]), a sender that plays points
//! out in real time through an injected network delay ([`send_paced`],
//! [`InjectedDelay`]), and the contour error of the drives' actual
//! positions against the path ([`PlanarTrace`], [`Circle::contour_error`],
//! [`Circle::path_time_error`]).
//!
//! The example `stream_circle`, the benchmark `stream_bench` and the
//! end-to-end tests measure with these, so their figures mean the same.

use crate::error::Error;
use crate::pb;
use crate::setpoints::{SetpointSender, setpoint};
use std::f64::consts::PI;
use std::time::{Duration, Instant};

/// A circle in the plane of two axes, traced from its leftmost point: the
/// angular speed ramps up over half a turn's time to one turn per
/// `period`, holds, and ramps down likewise, so the path starts and ends
/// at rest at its leftmost point, `turns` turns later.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Circle {
    /// The centre, user units.
    pub centre: [f64; 2],
    /// The radius, user units.
    pub radius: f64,
    /// Turns in all (at least half a turn: the two ramps).
    pub turns: f64,
    /// The time of one turn at full speed.
    pub period: Duration,
}

impl Circle {
    /// The circle whose leftmost point is `start` (where the axes stand).
    pub fn starting_at(start: [f64; 2], radius: f64, turns: f64, period: Duration) -> Circle {
        Circle {
            centre: [start[0] + radius, start[1]],
            radius,
            turns: turns.max(0.5),
            period,
        }
    }

    /// How long the path takes: `turns` periods and half a period for the
    /// ramps.
    pub fn duration(&self) -> Duration {
        self.period.mul_f64(self.turns + 0.5)
    }

    /// The speed along the path at full speed, user units/s.
    pub fn speed(&self) -> f64 {
        2.0 * PI * self.radius / self.period.as_secs_f64()
    }

    /// The angle travelled at path time `s` (seconds), radians.
    pub fn angle(&self, s: f64) -> f64 {
        let period = self.period.as_secs_f64();
        let w = 2.0 * PI / period;
        let ramp = period / 2.0;
        let cruise = self.turns * period - ramp;
        if s <= 0.0 {
            0.0
        } else if s < ramp {
            w * s * s / (2.0 * ramp)
        } else if s < ramp + cruise {
            w * ramp / 2.0 + w * (s - ramp)
        } else {
            let r = (2.0 * ramp + cruise - s).max(0.0);
            w * (ramp / 2.0 + cruise + ramp / 2.0) - w * r * r / (2.0 * ramp)
        }
    }

    /// The point of the path at path time `s` (seconds).
    pub fn point(&self, s: f64) -> [f64; 2] {
        self.at_angle(self.angle(s))
    }

    /// The circle's point at angle `a` from the leftmost point,
    /// counter-clockwise.
    fn at_angle(&self, a: f64) -> [f64; 2] {
        [
            self.centre[0] - self.radius * a.cos(),
            self.centre[1] + self.radius * a.sin(),
        ]
    }

    /// The path time (seconds) at which the path has travelled angle `a`
    /// (clamped to the path's ends).
    pub fn time_at_angle(&self, a: f64) -> f64 {
        let (mut lo, mut hi) = (0.0, self.duration().as_secs_f64());
        if a <= 0.0 {
            return lo;
        }
        if a >= self.angle(hi) {
            return hi;
        }
        for _ in 0..60 {
            let mid = (lo + hi) / 2.0;
            if self.angle(mid) < a {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        (lo + hi) / 2.0
    }

    /// The distance of `p` from the circle: the contour error of a point,
    /// measured to the nearest point of the path.
    pub fn radial_error(&self, p: [f64; 2]) -> f64 {
        ((p[0] - self.centre[0]).hypot(p[1] - self.centre[1]) - self.radius).abs()
    }

    /// The contour error of `samples` ((time, position), as
    /// [`PlanarTrace::pairs`] gives them): each position's distance from
    /// the circle.
    pub fn contour_error(&self, samples: &[(u64, [f64; 2])]) -> ErrorStats {
        ErrorStats::of(samples.iter().map(|(_, p)| self.radial_error(*p)))
    }

    /// The error of `samples` ((time µs, position)) against the path at
    /// the same path time. The samples' clock and the path's differ by
    /// the latency from the client to the drive (buffer, network, the
    /// drive's own lag): taken as one constant, the median over the
    /// samples at full speed of the sample's time minus the path time of
    /// its angle. Each sample is then compared with the path's point at
    /// its time minus that latency: a drive that lags behind or runs
    /// ahead of the rest of the path, a jump or a stall shows, where the
    /// distance to the path ([`Circle::contour_error`]) sees only what
    /// leaves the circle. `None` without samples at full speed.
    pub fn path_time_error(&self, samples: &[(u64, [f64; 2])]) -> Option<PathTimeError> {
        let period = self.period.as_secs_f64();
        let total = self.duration().as_secs_f64();
        let mut previous = 0.0;
        let mut offsets = Vec::new();
        for (t, p) in samples {
            let a = unwrap_angle(
                (p[1] - self.centre[1]).atan2(self.centre[0] - p[0]),
                previous,
            );
            previous = a;
            let s = self.time_at_angle(a);
            if s > period / 2.0 && s < total - period / 2.0 {
                offsets.push(*t as f64 / 1e6 - s);
            }
        }
        if offsets.is_empty() {
            return None;
        }
        offsets.sort_by(f64::total_cmp);
        let latency = offsets[offsets.len() / 2];
        let errors = samples.iter().filter_map(|(t, p)| {
            let s = *t as f64 / 1e6 - latency;
            (0.0..=total).contains(&s).then(|| {
                let q = self.point(s);
                (p[0] - q[0]).hypot(p[1] - q[1])
            })
        });
        Some(PathTimeError {
            error: ErrorStats::of(errors),
            latency_s: latency,
        })
    }
}

/// `a` (in (-π, π]) plus the whole turns that bring it nearest `previous`.
fn unwrap_angle(a: f64, previous: f64) -> f64 {
    a + 2.0 * PI * ((previous - a) / (2.0 * PI)).round()
}

/// Max, RMS, median and 90th percentile of a set of errors (user units).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ErrorStats {
    /// How many errors.
    pub samples: usize,
    /// The largest.
    pub max: f64,
    /// The root mean square.
    pub rms: f64,
    /// The median.
    pub median: f64,
    /// The 90th percentile.
    pub p90: f64,
}

impl ErrorStats {
    /// The statistics of `errors` (all zero when there are none).
    pub fn of(errors: impl IntoIterator<Item = f64>) -> ErrorStats {
        let mut e: Vec<f64> = errors.into_iter().collect();
        if e.is_empty() {
            return ErrorStats::default();
        }
        e.sort_by(f64::total_cmp);
        ErrorStats {
            samples: e.len(),
            max: e[e.len() - 1],
            rms: (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt(),
            median: e[e.len() / 2],
            p90: e[e.len() * 9 / 10],
        }
    }
}

/// The error against the path at the same path time
/// ([`Circle::path_time_error`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathTimeError {
    /// The errors.
    pub error: ErrorStats,
    /// The samples' clock minus the path time, seconds: the latency from
    /// the path to the drives (in the samples' clock, e.g. Unix time, plus
    /// the path's origin).
    pub latency_s: f64,
}

/// The drives' actual positions of two axes as the axis state stream
/// reports them ([`crate::Client::watch_axes`]), paired by SYNC: one
/// sample per axis and SYNC (the first status of each SYNC's process
/// data, which carries the position), each X sample with the Y sample
/// nearest in time. Both positions of a pair are then from the same SYNC,
/// so the pair is a point the machine was at (the stream status's
/// `actual_positions` are each axis's latest, and may be a SYNC apart).
#[derive(Debug, Clone)]
pub struct PlanarTrace {
    axes: [String; 2],
    samples: [Vec<(u64, f64)>; 2],
    sync_period_us: u64,
}

impl PlanarTrace {
    /// A trace of axes `x` and `y` on a bus with SYNC every `sync_period`.
    pub fn new(x: &str, y: &str, sync_period: Duration) -> PlanarTrace {
        PlanarTrace {
            axes: [x.to_string(), y.to_string()],
            samples: [Vec::new(), Vec::new()],
            sync_period_us: u64::try_from(sync_period.as_micros()).unwrap_or(u64::MAX),
        }
    }

    /// Takes one status (of another axis, or without process data yet:
    /// ignored).
    pub fn record(&mut self, status: &pb::AxisStatus) {
        let Some(i) = self.axes.iter().position(|a| *a == status.axis) else {
            return;
        };
        if status.timestamp_us == 0 {
            return;
        }
        let samples = &mut self.samples[i];
        // The other process data of the same SYNC (and command replies)
        // come within half a period of its first.
        if samples
            .last()
            .is_some_and(|(t, _)| status.timestamp_us < t + self.sync_period_us / 2)
        {
            return;
        }
        samples.push((status.timestamp_us, status.position));
    }

    /// The pairs (time µs, [x, y]) in time order: each X sample with the Y
    /// sample nearest in time, if within half a SYNC period.
    pub fn pairs(&self) -> Vec<(u64, [f64; 2])> {
        let ys = &self.samples[1];
        let mut out = Vec::new();
        for &(tx, x) in &self.samples[0] {
            let at = ys.partition_point(|(t, _)| *t < tx);
            let nearest = [at.checked_sub(1), Some(at)]
                .into_iter()
                .flatten()
                .filter_map(|j| ys.get(j))
                .min_by_key(|(t, _)| t.abs_diff(tx));
            if let Some(&(ty, y)) = nearest
                && ty.abs_diff(tx) < self.sync_period_us / 2
            {
                out.push((tx.min(ty), [x, y]));
            }
        }
        out
    }
}

/// Delays injected into a set-point stream as a network would add them:
/// none, or exponentially distributed with a given 99th percentile (most
/// points fast, a few late), from a reproducible generator.
#[derive(Debug, Clone)]
pub struct InjectedDelay {
    mean_us: f64,
    state: u64,
}

impl InjectedDelay {
    /// No delay.
    pub fn none() -> InjectedDelay {
        InjectedDelay {
            mean_us: 0.0,
            state: 1,
        }
    }

    /// Exponentially distributed delays whose 99th percentile is `p99`
    /// (mean `p99 / ln 100`); the same `seed`, the same delays.
    pub fn exponential(p99: Duration, seed: u64) -> InjectedDelay {
        InjectedDelay {
            mean_us: p99.as_secs_f64() * 1e6 / 100f64.ln(),
            state: seed.max(1),
        }
    }

    /// The next delay.
    pub fn next_delay(&mut self) -> Duration {
        if self.mean_us <= 0.0 {
            return Duration::ZERO;
        }
        Duration::from_micros((-self.mean_us * (1.0 - self.unit()).ln()) as u64)
    }

    /// A uniform number in [0, 1) (xorshift64*: reproducible without a
    /// dependency).
    fn unit(&mut self) -> f64 {
        self.state ^= self.state >> 12;
        self.state ^= self.state << 25;
        self.state ^= self.state >> 27;
        let x = self.state.wrapping_mul(0x2545_F491_4F6C_DD1D);
        (x >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// What [`send_paced`] sent.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PacedSend {
    /// Points sent.
    pub points: u64,
    /// The 99th percentile of the delay the points were held back by
    /// (the injected delay, or more where an earlier point held it).
    pub delay_p99: Duration,
    /// The largest such delay.
    pub delay_max: Duration,
}

/// Sends `count` points `period` apart (point `k` at client time
/// `k · period`, positions `positions(k · period)`), each when its time
/// comes in real time, held back by `delay` and never overtaking an
/// earlier point (as over TCP); the points due together go in one batch.
///
/// # Errors
/// As [`SetpointSender::send`] (the call has ended: read the statuses for
/// why).
pub async fn send_paced(
    sender: &SetpointSender,
    period: Duration,
    count: u64,
    mut delay: InjectedDelay,
    mut positions: impl FnMut(Duration) -> Vec<f64>,
) -> Result<PacedSend, Error> {
    let t0 = Instant::now();
    let mut pending: Vec<(Duration, pb::Setpoint)> = Vec::new();
    let mut delays = Vec::new();
    let mut release = Duration::ZERO;
    let mut k = 0u64;
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
    let period_us = u64::try_from(period.as_micros()).unwrap_or(u64::MAX);
    while k < count || !pending.is_empty() {
        tick.tick().await;
        let now = t0.elapsed();
        // Every point whose time has come is generated now.
        while k < count && period * u32::try_from(k).unwrap_or(u32::MAX) <= now {
            let due = period * u32::try_from(k).unwrap_or(u32::MAX);
            release = release.max(due + delay.next_delay());
            delays.push(release - due);
            pending.push((release, setpoint(k * period_us, positions(due))));
            k += 1;
        }
        let ready = pending.iter().take_while(|(r, _)| *r <= now).count();
        if ready > 0 {
            let batch = pending.drain(..ready).map(|(_, p)| p).collect();
            sender.send(batch).await?;
        }
    }
    delays.sort();
    let pick = |q: f64| {
        delays
            .get(((delays.len() as f64 * q) as usize).min(delays.len().saturating_sub(1)))
            .copied()
            .unwrap_or_default()
    };
    Ok(PacedSend {
        points: k,
        delay_p99: pick(0.99),
        delay_max: delays.last().copied().unwrap_or_default(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn circle() -> Circle {
        Circle::starting_at([1.0, 2.0], 10.0, 2.0, Duration::from_secs(1))
    }

    #[test]
    fn the_circle_starts_and_ends_at_rest_at_its_leftmost_point() {
        let c = circle();
        assert_eq!(c.centre, [11.0, 2.0]);
        assert_eq!(c.duration(), Duration::from_millis(2500));
        let end = c.duration().as_secs_f64();
        for s in [0.0, end] {
            let p = c.point(s);
            assert!(
                (p[0] - 1.0).abs() < 1e-9 && (p[1] - 2.0).abs() < 1e-9,
                "{p:?}"
            );
        }
        // At rest at both ends: the angle hardly moves in the first and
        // the last millisecond; at full speed a turn per period.
        assert!(c.angle(0.001) < 1e-4);
        assert!(c.angle(end) - c.angle(end - 0.001) < 1e-4);
        assert!((c.angle(1.3) - c.angle(1.2) - 2.0 * PI * 0.1).abs() < 1e-9);
        assert!((c.angle(end) - 4.0 * PI).abs() < 1e-9);
        for s in [0.1, 0.7, 1.9, 2.45] {
            assert!(c.radial_error(c.point(s)) < 1e-9);
            assert!((c.time_at_angle(c.angle(s)) - s).abs() < 1e-6);
        }
    }

    #[test]
    fn path_time_error_takes_out_a_constant_latency_and_sees_a_lag() {
        let c = circle();
        let latency = 1_700_000_000.25;
        let at = |s: f64| ((s + latency) * 1e6).round() as u64;
        // The path sampled every 10 ms, exactly: no error, the latency
        // found.
        let exact: Vec<(u64, [f64; 2])> = (0..250)
            .map(|k| k as f64 * 0.01)
            .map(|s| (at(s), c.point(s)))
            .collect();
        let e = c.path_time_error(&exact).expect("samples at full speed");
        assert!((e.latency_s - latency).abs() < 1e-5, "{}", e.latency_s);
        assert!(e.error.max < 1e-3, "{:?}", e.error);
        assert!(c.contour_error(&exact).max < 1e-9);
        // The path jumps 20 ms ahead in the middle of the second turn: on
        // the circle, so no contour error, but 20 ms along the path at
        // full speed (1.26 mm) off at the same path time.
        let jumped: Vec<(u64, [f64; 2])> = (0..250)
            .map(|k| k as f64 * 0.01)
            .map(|s| (at(s), c.point(if s > 1.5 { s + 0.02 } else { s })))
            .collect();
        assert!(c.contour_error(&jumped).max < 1e-9);
        let e = c.path_time_error(&jumped).expect("samples");
        assert!(e.error.max > 1.2 && e.error.max < 1.3, "{:?}", e.error);
    }

    #[test]
    fn a_trace_pairs_the_axes_by_sync() {
        let status = |axis: &str, t: u64, position: f64| pb::AxisStatus {
            axis: axis.into(),
            timestamp_us: t,
            position,
            ..Default::default()
        };
        let mut trace = PlanarTrace::new("X", "Y", Duration::from_millis(10));
        for s in [
            status("X", 10_000, 1.0),
            status("X", 10_300, 1.0), // TPDO2 of the same SYNC
            status("Y", 10_150, 2.0),
            status("Z", 10_200, 9.0),
            status("X", 20_000, 1.5),
            status("Y", 20_100, 2.5),
            status("X", 30_000, 2.0), // Y's of this SYNC missing
            status("Y", 0, 7.0),      // no process data yet
            status("Y", 40_050, 3.5),
            status("X", 40_000, 3.0),
        ] {
            trace.record(&s);
        }
        assert_eq!(
            trace.pairs(),
            vec![
                (10_000, [1.0, 2.0]),
                (20_000, [1.5, 2.5]),
                (40_000, [3.0, 3.5])
            ]
        );
    }

    #[test]
    fn injected_delays_have_the_asked_p99_and_repeat_with_the_seed() {
        let mut d = InjectedDelay::exponential(Duration::from_millis(20), 7);
        let mut v: Vec<Duration> = (0..20_000).map(|_| d.next_delay()).collect();
        let mut again = InjectedDelay::exponential(Duration::from_millis(20), 7);
        assert_eq!(again.next_delay(), v[0]);
        v.sort();
        let p99 = v[v.len() * 99 / 100].as_secs_f64() * 1e3;
        assert!((18.0..22.0).contains(&p99), "{p99} ms");
        assert_eq!(InjectedDelay::none().next_delay(), Duration::ZERO);
    }
}
