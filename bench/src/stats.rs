//! Latency statistics: HDR histograms of nanoseconds and the percentiles
//! the benchmarks report, in microseconds.

use hdrhistogram::Histogram;
use serde_json::{Value, json};
use std::time::Duration;

/// The largest latency a [`histogram`] tells apart: two minutes, far above
/// any timeout of a benchmark (a larger sample is clamped to it).
const MAX_NS: u64 = 120_000_000_000;

/// An empty histogram of latencies in nanoseconds, 3 significant digits,
/// from 1 ns to two minutes. Every benchmark uses the same one so that
/// their histograms can be added and their percentiles compared.
pub fn histogram() -> Histogram<u64> {
    Histogram::new_with_bounds(1, MAX_NS, 3).expect("valid histogram bounds")
}

/// Records a latency of `ns` nanoseconds: 0 counts as 1 ns (the
/// histogram's resolution), beyond two minutes as two minutes, so recording
/// never fails in the middle of a run.
pub fn record_ns(h: &mut Histogram<u64>, ns: u64) {
    h.saturating_record(ns.max(1));
}

/// Records a measured duration (see [`record_ns`]).
pub fn record(h: &mut Histogram<u64>, d: Duration) {
    record_ns(h, u64::try_from(d.as_nanos()).unwrap_or(u64::MAX));
}

/// The value at quantile `q` (0 to 1) of a histogram of nanoseconds, in µs.
pub fn quantile_us(h: &Histogram<u64>, q: f64) -> f64 {
    h.value_at_quantile(q) as f64 / 1000.0
}

/// The percentiles of a histogram of nanoseconds, in µs: what the
/// benchmarks print and put in their JSON.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Percentiles {
    /// Samples recorded.
    pub samples: u64,
    /// Smallest sample.
    pub min_us: f64,
    /// Median.
    pub p50_us: f64,
    /// 90th percentile.
    pub p90_us: f64,
    /// 99th percentile: the figure most targets are set on.
    pub p99_us: f64,
    /// 99.9th percentile.
    pub p999_us: f64,
    /// Largest sample.
    pub max_us: f64,
    /// Arithmetic mean.
    pub mean_us: f64,
}

impl Percentiles {
    /// The percentiles of `h` (nanoseconds).
    pub fn of(h: &Histogram<u64>) -> Percentiles {
        Percentiles {
            samples: h.len(),
            min_us: h.min() as f64 / 1000.0,
            p50_us: quantile_us(h, 0.50),
            p90_us: quantile_us(h, 0.90),
            p99_us: quantile_us(h, 0.99),
            p999_us: quantile_us(h, 0.999),
            max_us: h.max() as f64 / 1000.0,
            mean_us: h.mean() / 1000.0,
        }
    }

    /// Every figure as a JSON object (`p50_us`, …, `samples`).
    pub fn to_json(&self) -> Value {
        json!({
            "p50_us": self.p50_us,
            "p90_us": self.p90_us,
            "p99_us": self.p99_us,
            "p999_us": self.p999_us,
            "max_us": self.max_us,
            "min_us": self.min_us,
            "mean_us": self.mean_us,
            "samples": self.samples,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_in_microseconds() {
        let mut h = histogram();
        for us in 1..=100u64 {
            record(&mut h, Duration::from_micros(us));
        }
        let p = Percentiles::of(&h);
        assert_eq!(p.samples, 100);
        assert!((p.p50_us - 50.0).abs() < 0.1, "{p:?}");
        assert!((p.p99_us - 99.0).abs() < 0.1, "{p:?}");
        assert!((p.max_us - 100.0).abs() < 0.1, "{p:?}");
        assert!((p.min_us - 1.0).abs() < 0.01, "{p:?}");
        assert_eq!(p.to_json()["samples"], 100);
    }

    #[test]
    fn recording_never_fails() {
        let mut h = histogram();
        record_ns(&mut h, 0);
        record(&mut h, Duration::from_secs(3600));
        assert_eq!(h.len(), 2);
        assert_eq!(h.min(), 1);
        assert!(h.max() >= MAX_NS);
    }
}
