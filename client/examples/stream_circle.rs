//! Streams a circle on two cyclic axes at 1 kHz (`Axes.StreamSetpoints`),
//! optionally through injected network jitter, and reports the contour
//! error: how far the positions the gateway commanded, and the drives'
//! actual positions, lie from the circle (radial error, max and RMS).
//!
//! ```sh
//! cargo run -p cangate-server &                      # the demo on 127.0.0.1:50051
//! cargo run -p cangate-client --example stream_circle -- --jitter-ms 5
//! ```
//!
//! Options: `--server ADDR`, `--axes X,Y`, `--radius MM` (10),
//! `--turns N` (2), `--period-s S` (time of one turn at full speed, 1),
//! `--depth-ms MS` (jitter buffer, 50), `--jitter-ms MS` (p99 of the
//! delay added to each point, exponentially distributed, order kept; 0),
//! `--seed N`.
//!
//! The angular speed ramps up over half a turn's time and down likewise,
//! so the circle starts and ends at rest where the axes stand (the circle's
//! leftmost point is their start). Each point is generated when its time
//! comes (1 ms apart), held back by its injected delay (never overtaking
//! an earlier one: TCP keeps the order), and sent with the points that are
//! due with it.

use cangate_client::{ConnectOptions, SetpointStreamOptions, pb, setpoint};
use std::f64::consts::PI;
use std::time::{Duration, Instant};

#[tokio::main]
async fn main() {
    if let Err(e) = run().await {
        eprintln!("stream_circle: {e}");
        std::process::exit(1);
    }
}

/// A small PRNG (xorshift64*): reproducible delays without a dependency.
struct Rng(u64);

impl Rng {
    fn unit(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let x = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D);
        (x >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The circle's angle at `s` seconds: ramps up over `period/2` to a turn
/// per `period`, holds, ramps down over `period/2`; `turns` turns in all.
fn angle(s: f64, turns: f64, period: f64) -> f64 {
    let w = 2.0 * PI / period;
    let ramp = period / 2.0;
    let cruise = (turns * period) - ramp;
    if s < ramp {
        w * s * s / (2.0 * ramp)
    } else if s < ramp + cruise {
        w * ramp / 2.0 + w * (s - ramp)
    } else {
        let r = (2.0 * ramp + cruise - s).max(0.0);
        w * (ramp / 2.0 + cruise + ramp / 2.0) - w * r * r / (2.0 * ramp)
    }
}

/// (max, RMS) of `errors`.
fn stats(errors: &[f64]) -> (f64, f64) {
    let max = errors.iter().copied().fold(0.0, f64::max);
    let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len().max(1) as f64).sqrt();
    (max, rms)
}

async fn run() -> Result<(), Box<dyn std::error::Error>> {
    let mut server = std::env::var("CANGATE_SERVER").unwrap_or_else(|_| "127.0.0.1:50051".into());
    let mut axes = "X,Y".to_string();
    let (mut radius, mut turns, mut period) = (10.0, 2.0, 1.0);
    let (mut depth_ms, mut jitter_ms, mut seed) = (50u64, 0.0f64, 1u64);
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().ok_or(format!("{a} needs a value"));
        match a.as_str() {
            "--server" => server = value()?,
            "--axes" => axes = value()?,
            "--radius" => radius = value()?.parse()?,
            "--turns" => turns = value()?.parse()?,
            "--period-s" => period = value()?.parse()?,
            "--depth-ms" => depth_ms = value()?.parse()?,
            "--jitter-ms" => jitter_ms = value()?.parse()?,
            "--seed" => seed = value()?.parse()?,
            other => return Err(format!("unknown argument {other:?}").into()),
        }
    }
    let names: Vec<&str> = axes.split(',').collect();
    if names.len() != 2 {
        return Err("--axes names two axes".into());
    }
    let options = ConnectOptions {
        request_timeout: Some(Duration::from_secs(10)),
        ..Default::default()
    };
    let client = cangate_client::connect_with(&server, &options).await?;
    let lease = client
        .acquire_control_as(&names, Duration::from_secs(2), "stream_circle")
        .await?;
    let mut start = Vec::new();
    for a in &names {
        client.enable(a, &lease.options().wait(true)).await?;
        start.push(
            client
                .axis(a)
                .await?
                .status
                .map_or(0.0, |s| s.demand_position),
        );
    }
    // The circle's centre: `radius` to the right of where the axes stand.
    let centre = [start[0] + radius, start[1]];
    let point = move |s: f64| {
        let a = angle(s, turns, period);
        vec![centre[0] - radius * a.cos(), centre[1] + radius * a.sin()]
    };
    let off = move |p: &[f64]| ((p[0] - centre[0]).hypot(p[1] - centre[1]) - radius).abs();
    let total_ms = ((turns + 0.5) * period * 1000.0).ceil() as u64;

    let mut stream = client
        .stream_setpoints(
            &lease,
            &names,
            SetpointStreamOptions {
                depth: Duration::from_millis(depth_ms),
                extrapolate: None,
                point_period: Some(Duration::from_millis(1)),
                status_period: Some(Duration::from_millis(10)),
            },
        )
        .await?;
    let sender = stream.sender().ok_or("no sender")?;
    // Exponential delays with the given p99: mean = p99 / ln(100).
    let mean_us = jitter_ms * 1000.0 / 100f64.ln();
    let sending = tokio::spawn(async move {
        let mut rng = Rng(seed.max(1));
        let t0 = Instant::now();
        let mut pending: Vec<(Duration, pb::Setpoint)> = Vec::new();
        let mut release = Duration::ZERO;
        let mut k = 0u64;
        let mut tick = tokio::time::interval(Duration::from_millis(1));
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
        loop {
            tick.tick().await;
            let now = t0.elapsed();
            // Every point whose time has come is generated now.
            while k <= total_ms && Duration::from_millis(k) <= now {
                let delay = if mean_us > 0.0 {
                    -mean_us * (1.0 - rng.unit()).ln()
                } else {
                    0.0
                };
                release =
                    release.max(Duration::from_millis(k) + Duration::from_micros(delay as u64));
                pending.push((release, setpoint(k * 1000, point(k as f64 / 1000.0))));
                k += 1;
            }
            let due = pending.iter().take_while(|(r, _)| *r <= now).count();
            if due > 0 {
                let batch = pending.drain(..due).map(|(_, p)| p).collect();
                if sender.send(batch).await.is_err() {
                    return;
                }
            }
            if k > total_ms && pending.is_empty() {
                return;
            }
        }
    });
    let mut commanded = Vec::new();
    let mut actual = Vec::new();
    let mut last = None;
    let mut sending = Some(sending);
    loop {
        // (Reading a status is cancel-safe: the call keeps its state.)
        let status = tokio::select! {
            s = stream.status() => s?,
            _ = async { sending.as_mut().expect("guarded").await }, if sending.is_some() => {
                // Every point sent: the gateway plays the rest, then ends.
                sending = None;
                stream.finish();
                continue;
            }
        };
        let Some(s) = status else { break };
        commanded.push(off(&s.commanded_positions));
        if s.actual_positions.iter().all(|p| p.is_finite()) {
            actual.push(off(&s.actual_positions));
        }
        for e in &s.events {
            if e.kind != pb::SetpointEventKind::SetpointEventAtRest as i32 {
                println!("event: {} {} {}", e.reason, e.axis, e.detail);
            }
        }
        last = Some(s);
    }
    let last = last.ok_or("no status")?;
    let c = last.counters.unwrap_or_default();
    let (cmax, crms) = stats(&commanded);
    let (amax, arms) = stats(&actual);
    println!(
        "circle r={radius} {turns} turns, depth {depth_ms} ms, jitter p99 {jitter_ms} ms: \
         received {} played {} refused {} late {} dropped {} underruns {} limited {}",
        c.received, c.played, c.refused, c.late, c.dropped, c.underruns, c.limited
    );
    println!(
        "contour error (radial, {} statuses): commanded max {cmax:.4} rms {crms:.4}; \
         actual max {amax:.4} rms {arms:.4}",
        commanded.len()
    );
    lease.release().await?;
    Ok(())
}
