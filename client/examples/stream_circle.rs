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

use cangate_client::setpoint_trial::{Circle, ErrorStats, InjectedDelay, send_paced};
use cangate_client::{ConnectOptions, SetpointStreamOptions, pb};
use std::time::Duration;

#[tokio::main]
async fn main() {
    if let Err(e) = run().await {
        eprintln!("stream_circle: {e}");
        std::process::exit(1);
    }
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
    let circle = Circle::starting_at(
        [start[0], start[1]],
        radius,
        turns,
        Duration::from_secs_f64(period),
    );
    let points = circle.duration().as_millis() as u64 + 1;

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
    let delay = if jitter_ms > 0.0 {
        InjectedDelay::exponential(Duration::from_secs_f64(jitter_ms / 1000.0), seed)
    } else {
        InjectedDelay::none()
    };
    let sending = tokio::spawn(async move {
        // A failed send means the call ended: the statuses say why.
        let _ = send_paced(&sender, Duration::from_millis(1), points, delay, |t| {
            circle.point(t.as_secs_f64()).to_vec()
        })
        .await;
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
        commanded.push(circle.radial_error(plane(&s.commanded_positions)));
        if s.actual_positions.iter().all(|p| p.is_finite()) {
            actual.push(circle.radial_error(plane(&s.actual_positions)));
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
    let c_err = ErrorStats::of(commanded.iter().copied());
    let a_err = ErrorStats::of(actual.iter().copied());
    println!(
        "circle r={radius} {turns} turns, depth {depth_ms} ms, jitter p99 {jitter_ms} ms: \
         received {} played {} refused {} late {} dropped {} underruns {} limited {}",
        c.received, c.played, c.refused, c.late, c.dropped, c.underruns, c.limited
    );
    println!(
        "contour error (radial, {} statuses): commanded max {:.4} rms {:.4}; \
         actual max {:.4} rms {:.4}",
        commanded.len(),
        c_err.max,
        c_err.rms,
        a_err.max,
        a_err.rms
    );
    lease.release().await?;
    Ok(())
}

/// The first two positions of a status.
fn plane(p: &[f64]) -> [f64; 2] {
    [
        p.first().copied().unwrap_or(f64::NAN),
        p.get(1).copied().unwrap_or(f64::NAN),
    ]
}
