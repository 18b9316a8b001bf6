//! Cycle start-time jitter: a histogram of how late each MST left against
//! its schedule, in 1 µs buckets (constant memory for any run length).

/// Buckets of 1 µs; later samples go into the last one (and `max`).
const BUCKETS: usize = 10_000;

/// Percentiles of the MST lateness, µs.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct JitterStats {
    /// Cycles measured.
    pub samples: u64,
    /// Median lateness.
    pub p50_us: f64,
    /// 99th percentile.
    pub p99_us: f64,
    /// 99.9th percentile.
    pub p999_us: f64,
    /// Worst.
    pub max_us: f64,
    /// Mean.
    pub mean_us: f64,
}

/// The histogram.
#[derive(Debug, Clone)]
pub struct JitterHistogram {
    buckets: Vec<u32>,
    samples: u64,
    sum_ns: u128,
    max_ns: u64,
}

impl Default for JitterHistogram {
    fn default() -> Self {
        JitterHistogram {
            buckets: vec![0; BUCKETS],
            samples: 0,
            sum_ns: 0,
            max_ns: 0,
        }
    }
}

impl JitterHistogram {
    /// Records one lateness.
    pub fn record(&mut self, late_ns: u64) {
        let i = ((late_ns / 1_000) as usize).min(BUCKETS - 1);
        self.buckets[i] = self.buckets[i].saturating_add(1);
        self.samples += 1;
        self.sum_ns += u128::from(late_ns);
        self.max_ns = self.max_ns.max(late_ns);
    }

    /// Forgets everything.
    pub fn clear(&mut self) {
        *self = JitterHistogram::default();
    }

    fn percentile(&self, q: f64) -> f64 {
        if self.samples == 0 {
            return 0.0;
        }
        let rank = ((self.samples as f64) * q).ceil().max(1.0) as u64;
        let mut seen = 0u64;
        for (i, &n) in self.buckets.iter().enumerate() {
            seen += u64::from(n);
            if seen >= rank {
                // The bucket's upper edge: a conservative figure.
                return ((i + 1) as f64).min(self.max_ns as f64 / 1_000.0);
            }
        }
        self.max_ns as f64 / 1_000.0
    }

    /// The percentiles.
    pub fn stats(&self) -> JitterStats {
        JitterStats {
            samples: self.samples,
            p50_us: self.percentile(0.50),
            p99_us: self.percentile(0.99),
            p999_us: self.percentile(0.999),
            max_us: self.max_ns as f64 / 1_000.0,
            mean_us: if self.samples == 0 {
                0.0
            } else {
                (self.sum_ns / u128::from(self.samples)) as f64 / 1_000.0
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_are_bucket_upper_edges_capped_by_the_max() {
        let mut h = JitterHistogram::default();
        assert_eq!(h.stats(), JitterStats::default());
        for _ in 0..98 {
            h.record(3_500); // 3.5 µs -> bucket 3
        }
        h.record(50_000);
        h.record(20_000_000); // beyond the last bucket
        let s = h.stats();
        assert_eq!(s.samples, 100);
        assert_eq!(s.p50_us, 4.0);
        assert_eq!(s.p99_us, 51.0);
        assert_eq!(s.max_us, 20_000.0);
        assert_eq!(s.p999_us, 10_000.0);
        assert!((s.mean_us - (98.0 * 3.5 + 50.0 + 20_000.0) / 100.0).abs() < 0.01);
    }
}
