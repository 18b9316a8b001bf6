//! Handwheel pacer: evenness, overflow accounting and the drain bound.

use std::time::Duration;

use cangate_motion::{JogPacer, PushResult};
use proptest::prelude::*;

fn us(x: u64) -> Duration {
    Duration::from_micros(x)
}

/// A burst of 500 units arriving within 10 ms at 1000 units/s comes out at
/// most 1 unit per ms, evenly, all of it, within the drain bound.
#[test]
fn burst_of_500_in_10ms_is_spread_at_one_per_ms() {
    let mut p = JogPacer::new(1000.0, 500).unwrap();
    let mut out_times = Vec::new();
    let mut t = 0;
    while t <= 1_000_000 {
        if t < 10_000 && t % 1000 == 0 {
            let r = p.push(50, us(t));
            assert_eq!(
                r,
                PushResult {
                    accepted: 50,
                    dropped: 0,
                    flushed: 0
                },
                "at {t} µs"
            );
        }
        let n = p.poll(us(t));
        assert!(n == 0 || n == 1, "poll at {t} µs returned {n}");
        if n == 1 {
            out_times.push(t);
        }
        t += 100; // poll every 100 µs
    }
    assert_eq!(out_times.len(), 500);
    for w in out_times.windows(2) {
        assert!(w[1] - w[0] >= 1000, "units {} µs apart", w[1] - w[0]);
    }
    // Output is even: exactly one unit per ms from the first push on.
    assert_eq!(out_times[0], 0);
    assert_eq!(*out_times.last().unwrap(), 499_000);
    // Drain bound: last push at 9 ms, bound 500 ms.
    assert_eq!(p.drain_bound(), Duration::from_millis(500));
    assert!(*out_times.last().unwrap() <= 9_000 + 500_000);
    assert_eq!(p.backlog(), 0);
    let s = p.stats();
    assert_eq!(
        (s.accepted, s.emitted, s.dropped, s.expired, s.flushed),
        (500, 500, 0, 0, 0)
    );
}

#[test]
fn backlog_overflow_is_counted_exactly() {
    let mut p = JogPacer::new(1000.0, 100).unwrap();
    assert_eq!(
        p.push(150, us(0)),
        PushResult {
            accepted: 100,
            dropped: 50,
            flushed: 0
        }
    );
    let mut emitted = 0;
    for ms in 0..10 {
        emitted += p.poll(us(ms * 1000));
    }
    assert_eq!(emitted, 10);
    assert_eq!(p.backlog(), 90);
    assert_eq!(
        p.push(30, us(9_500)),
        PushResult {
            accepted: 10,
            dropped: 20,
            flushed: 0
        }
    );
    assert_eq!(
        p.push(1, us(9_600)),
        PushResult {
            accepted: 0,
            dropped: 1,
            flushed: 0
        }
    );
    assert_eq!(p.stats().dropped, 71);
    assert_eq!(p.stats().accepted, 110);
    // Dropped units are never executed: exactly 110 come out in total.
    let mut total = emitted;
    for ms in 10..1000 {
        total += p.poll(us(ms * 1000));
    }
    assert_eq!(total, 110);
    // Negative units are counted with their sign.
    let mut q = JogPacer::new(10.0, 5).unwrap();
    assert_eq!(
        q.push(-8, us(0)),
        PushResult {
            accepted: -5,
            dropped: -3,
            flushed: 0
        }
    );
    assert_eq!(q.backlog(), -5);
}

#[test]
fn full_backlog_drains_within_the_bound() {
    let mut p = JogPacer::new(250.0, 50).unwrap();
    assert_eq!(p.drain_bound(), Duration::from_millis(200));
    // Keep the backlog topped up, then stop pushing at 1 s.
    let mut last_out = 0;
    let mut t = 0;
    while t <= 2_000_000 {
        if t <= 1_000_000 && t % 10_000 == 0 {
            p.push(100, us(t));
        }
        if p.poll(us(t)) != 0 {
            last_out = t;
        }
        t += 1000;
    }
    assert!(
        last_out <= 1_000_000 + 200_000,
        "last unit at {last_out} µs"
    );
    assert!(
        last_out >= 1_000_000 + 190_000,
        "backlog was full, drain takes the full bound"
    );
    assert_eq!(p.backlog(), 0);
    assert_eq!(p.stats().expired, 0);
}

#[test]
fn stop_within_sizes_the_backlog() {
    let mut p = JogPacer::stop_within(1000.0, Duration::from_millis(100)).unwrap();
    assert_eq!(p.max_backlog(), 100);
    p.push(1_000_000, us(0));
    let mut last = 0;
    for t in (0..=1_000_000).step_by(500) {
        if p.poll(us(t)) != 0 {
            last = t;
        }
    }
    assert!(last <= 100_000);
    assert_eq!(p.stats().dropped, 1_000_000 - 100);
}

#[derive(Debug, Clone)]
enum Ev {
    Push { at_us: u64, units: i64 },
}

proptest! {
    /// Random bursts, random rate/backlog/poll cycle: exact accounting,
    /// bounded backlog, output lagging its slot by less than one poll cycle
    /// (so any `m + 1` consecutive units span more than `m / rate - cycle`),
    /// nothing expires when polled every cycle, and everything is out within
    /// `drain_bound + cycle` of the last push.
    #[test]
    fn pacer_invariants(
        rate in 10.0f64..5000.0,
        max_backlog in 1u32..400,
        cycle_us in 50u64..5000,
        bursts in prop::collection::vec((0u64..20_000, -300i64..300), 1..30),
    ) {
        let mut p = JogPacer::new(rate, max_backlog).unwrap();
        let mut events: Vec<Ev> = Vec::new();
        let mut at = 0;
        for &(gap, units) in &bursts {
            at += gap;
            events.push(Ev::Push { at_us: at, units });
        }
        let last_push = at;
        let period = 1.0 / rate;
        let cycle = cycle_us as f64 * 1e-6;
        let end = last_push + (p.drain_bound().as_micros() as u64) + 3 * cycle_us;

        let mut outs: Vec<(f64, i64)> = Vec::new(); // (time s, sign) per unit
        let mut accepted_total: i64 = 0;
        let mut emitted_total: i64 = 0;
        let mut flushed_total: i64 = 0;
        let mut ev = events.iter().peekable();
        let mut t = 0;
        while t <= end {
            // Pushes at or before this poll instant (at their own times).
            while let Some(Ev::Push { at_us, units }) = ev.peek().copied() {
                if *at_us > t { break; }
                let before = p.backlog();
                let r = p.push(*units, us(*at_us));
                prop_assert_eq!(r.accepted + r.dropped, *units);
                let reversed = before != 0 && units.signum() != before.signum() && *units != 0;
                let room = i64::from(max_backlog) - if reversed { 0 } else { before.abs() };
                prop_assert_eq!(r.accepted.abs(), units.abs().min(room));
                prop_assert_eq!(r.flushed, if reversed { before } else { 0 });
                prop_assert!(p.backlog().abs() <= i64::from(max_backlog));
                accepted_total += r.accepted.abs();
                flushed_total += r.flushed.abs();
                ev.next();
            }
            let n = p.poll(us(t));
            for _ in 0..n.abs() {
                outs.push((t as f64 * 1e-6, n.signum()));
            }
            emitted_total += n.abs();
            prop_assert_eq!(
                accepted_total,
                emitted_total + flushed_total + p.backlog().abs()
            );
            t += cycle_us;
        }
        let s = p.stats();
        prop_assert_eq!(s.expired, 0);
        prop_assert_eq!(p.backlog(), 0);
        prop_assert_eq!(s.emitted as i64, emitted_total);
        // Evenness.
        for m in 1..=8usize {
            for w in outs.windows(m + 1) {
                let span = w[m].0 - w[0].0;
                prop_assert!(
                    span > m as f64 * period - cycle - 1e-9,
                    "{} units within {} s (period {}, cycle {})", m + 1, span, period, cycle
                );
            }
        }
        // Drain bound.
        if let Some(&(t_last, _)) = outs.last() {
            let bound = last_push as f64 * 1e-6 + p.drain_bound().as_secs_f64() + cycle;
            prop_assert!(t_last <= bound + 1e-9, "last unit at {} > {}", t_last, bound);
        }
    }
}
