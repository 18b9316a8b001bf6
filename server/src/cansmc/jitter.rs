//! Cycle start-time jitter: a histogram of how late each MST left against
//! its schedule, in 1 µs buckets (constant memory for any run length),
//! and a coarse copy of it for clients to chart (`CoarseHistogram`).

/// Buckets of 1 µs; later samples go into the last one (and `max`).
const BUCKETS: usize = 10_000;

/// At most this many buckets in the coarse histogram.
pub const COARSE_BUCKETS: usize = 100;

/// Widths of the coarse buckets, µs: the smallest with which
/// `COARSE_BUCKETS` reach the worst lateness is used. The last,
/// `COARSE_BUCKETS` × 100 µs, covers the whole fine histogram.
const COARSE_WIDTHS_US: [u32; 7] = [1, 2, 5, 10, 20, 50, 100];

/// The MST lateness histogram in at most `COARSE_BUCKETS` buckets of
/// `bucket_us` µs: `counts[i]` counts the MSTs late by
/// `[i × bucket_us, (i + 1) × bucket_us)` µs, the last one also every
/// later MST. Empty buckets after the last sample are left out. The counts
/// sum to the samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoarseHistogram {
    /// Width of a bucket, µs (1, 2, 5, 10, 20, 50 or 100).
    pub bucket_us: u32,
    /// Buckets used (`counts[..len]`).
    pub len: usize,
    /// The counts; those from `len` on are 0.
    pub counts: [u64; COARSE_BUCKETS],
}

impl Default for CoarseHistogram {
    fn default() -> Self {
        CoarseHistogram {
            bucket_us: 1,
            len: 0,
            counts: [0; COARSE_BUCKETS],
        }
    }
}

impl CoarseHistogram {
    /// The buckets used.
    pub fn counts(&self) -> &[u64] {
        &self.counts[..self.len]
    }
}

/// Percentiles of the MST lateness, µs, and its coarse histogram.
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
    /// The histogram, coarsened.
    pub histogram: CoarseHistogram,
}

/// The histogram.
#[derive(Debug, Clone)]
pub struct JitterHistogram {
    buckets: Vec<u64>,
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
        self.buckets[i] += 1;
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
            seen += n;
            if seen >= rank {
                // The bucket's upper edge: a conservative figure.
                return ((i + 1) as f64).min(self.max_ns as f64 / 1_000.0);
            }
        }
        self.max_ns as f64 / 1_000.0
    }

    /// The histogram in at most `COARSE_BUCKETS` buckets, as wide as
    /// needed for the worst lateness (see `CoarseHistogram`).
    pub fn coarse(&self) -> CoarseHistogram {
        let mut h = CoarseHistogram::default();
        if self.samples == 0 {
            return h;
        }
        // The fine bucket of the worst sample (the last one beyond it).
        let last = ((self.max_ns / 1_000) as usize).min(BUCKETS - 1);
        let width = COARSE_WIDTHS_US
            .into_iter()
            .find(|&w| last < COARSE_BUCKETS * w as usize)
            .unwrap_or(COARSE_WIDTHS_US[COARSE_WIDTHS_US.len() - 1]);
        h.bucket_us = width;
        for (i, &n) in self.buckets[..=last].iter().enumerate() {
            let j = (i / width as usize).min(COARSE_BUCKETS - 1);
            h.counts[j] += n;
        }
        h.len = (last / width as usize).min(COARSE_BUCKETS - 1) + 1;
        h
    }

    /// The percentiles and the coarse histogram.
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
            histogram: self.coarse(),
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
        // Beyond the fine histogram: 100 µs buckets, the last one "and
        // above" holding the 20 ms MST.
        let c = s.histogram;
        assert_eq!((c.bucket_us, c.len), (100, 100));
        assert_eq!(c.counts()[0], 99);
        assert_eq!(c.counts()[99], 1);
        assert_eq!(c.counts().iter().sum::<u64>(), 100);
    }

    #[test]
    fn the_coarse_histogram_is_as_wide_as_the_worst_lateness_needs() {
        let mut h = JitterHistogram::default();
        assert_eq!(h.coarse().counts(), &[] as &[u64]);
        // Within 100 µs: the 1 µs buckets themselves, up to the worst.
        for ns in [0, 999, 1_000, 2_500, 2_999, 99_999] {
            h.record(ns);
        }
        let c = h.coarse();
        assert_eq!((c.bucket_us, c.len), (1, 100));
        assert_eq!(&c.counts()[..4], &[2, 1, 2, 0]);
        assert_eq!(c.counts()[99], 1);
        // 100 µs late: 2 µs buckets (50 is 100..102 µs).
        h.record(100_000);
        let c = h.coarse();
        assert_eq!((c.bucket_us, c.len), (2, 51));
        assert_eq!(&c.counts()[..2], &[3, 2]);
        assert_eq!(c.counts()[49], 1); // 99.999 µs
        assert_eq!(c.counts()[50], 1);
        // 1234 µs late: 20 µs buckets (100 × 10 µs reach 999 µs only);
        // 1234 µs is in bucket 61 (1220..1240 µs).
        h.record(1_234_000);
        let c = h.coarse();
        assert_eq!((c.bucket_us, c.len), (20, 62));
        assert_eq!(c.counts()[0], 5);
        assert_eq!(c.counts()[4], 1); // 99.999 µs in 80..100
        assert_eq!(c.counts()[5], 1); // 100 µs in 100..120
        assert_eq!(c.counts()[61], 1);
        assert_eq!(c.counts().iter().sum::<u64>(), 8);
        // Exactly the last fine bucket (9.999 ms): 100 µs, all 100 used.
        h.record(9_999_000);
        let c = h.coarse();
        assert_eq!((c.bucket_us, c.len), (100, 100));
        assert_eq!(c.counts()[99], 1);
        assert_eq!(c.counts().iter().sum::<u64>(), 9);
        h.clear();
        assert_eq!(h.coarse(), CoarseHistogram::default());
    }
}
