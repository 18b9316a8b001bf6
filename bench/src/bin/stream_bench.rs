//! `stream_bench`: streamed set-points (`Axes.StreamSetpoints`) on the
//! embedded demo: how closely the simulated drives follow a circle
//! streamed through network jitter, next to the same circle as `MoveAxes`
//! chords; the buffer depth each jitter needs; the gateway's CPU per
//! streamed axis.
//!
//! ```text
//! cargo build -p cangate-server -p cangate-bench --bins
//! target/debug/stream_bench                # full run
//! target/debug/stream_bench --quick        # CI smoke
//! ```
//!
//! The server binary beside this one (the same build) runs the embedded
//! demo as a child process: X and Y are its cyclic (CSP) axes on
//! simulated drives, SYNC every 10 ms. Its heartbeat timeouts are 3 s
//! rather than 300 ms (`--demo-heartbeats`: as in the demo), so that a
//! loaded machine does not lose a simulated drive mid-run. The client here streams as a
//! remote planner would, through `cangate_client::setpoint_trial` (the
//! circle, the injected delays, the contour error), as the example
//! `stream_circle` does.
//!
//! 1. **Contour error of the streamed circle**: radius 10 mm, one turn per
//!    second at full speed (62.8 mm/s), `--turns` turns, a point every
//!    1 ms, each held back by an injected network delay, exponentially
//!    distributed with a p99 of 0, 5 and 20 ms (order kept, as over TCP),
//!    buffer `--depth-ms`. Measured on the drives' actual positions from
//!    the axis state stream, X and Y paired by SYNC (both from the same
//!    SYNC's TPDOs, so each pair is a point the machine was at):
//!    - *to the path*: each pair's distance from the circle;
//!    - *at the same path time*: each pair against the path's point at the
//!      pair's bus time minus one constant latency (client to drive:
//!      buffer, network, the drive's lag), the median over the pairs at
//!      full speed of bus time minus the path time of the pair's angle. A
//!      lag that varies, a jump or a stall shows here, not in the first.
//! 2. **The same circle as `MoveAxes` chords** (`--chords` per turn, one
//!    turn, each move waited for, the axes' default velocity and
//!    acceleration): its contour error against the circle (the chords'
//!    own sagitta, r·(1 − cos(π/N)), included) and its time; ratios
//!    against the streamed circle without jitter.
//! 3. **Buffer depth needed**: per jitter, one turn per depth, depths
//!    rising until two in a row had neither an underrun nor a late point;
//!    the smallest depth from which every deeper one had no underrun, and
//!    no late point either.
//! 4. **Gateway CPU per streamed axis**: the server process's CPU time
//!    (`/proc/<pid>/stat`, every thread) per second, at rest and while a
//!    stream without jitter plays 1, 2 and 3 axes (X; X, Y; X, Y, Z with Z
//!    switched to CSP by `SetMode`): the added CPU, in ms per second, per
//!    stream and per axis.
//!
//! Human-readable results, then one JSON line. Exit 1 if something could
//! not run.

use anyhow::{Context, Result, anyhow, bail};
use cangate_bench::axes::{self, AxesClient};
use cangate_bench::child::{ServerChild, default_server_binary};
use cangate_bench::host::{self, process_cpu_seconds};
use cangate_bench::report;
use cangate_client::setpoint_trial::{
    Circle, ErrorStats, InjectedDelay, PacedSend, PathTimeError, PlanarTrace, send_paced,
};
use cangate_client::{Client, ConnectOptions, ControlLease, SetpointStreamOptions, pb};
use clap::Parser;
use futures::StreamExt;
use serde_json::{Value, json};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Streamed set-points on the embedded demo: contour error, buffer depth,
/// CPU per axis.
#[derive(Parser, Debug, Clone)]
#[command(about)]
struct Args {
    /// Tiny runs, for CI smoke runs.
    #[arg(long)]
    quick: bool,
    /// Server binary [default: cangate-server next to this executable].
    #[arg(long)]
    server_bin: Option<PathBuf>,
    /// Turns of the circle in part 1.
    #[arg(long, default_value_t = 3.0)]
    turns: f64,
    /// Buffer depth of part 1, ms.
    #[arg(long, default_value_t = 50)]
    depth_ms: u64,
    /// Injected jitter (p99 of the delay), ms, comma-separated.
    #[arg(long, default_value = "0,5,20", value_delimiter = ',')]
    jitter_ms: Vec<f64>,
    /// Chords per turn of part 2.
    #[arg(long, default_value_t = 36)]
    chords: u32,
    /// Depths swept in part 3, ms, rising.
    #[arg(
        long,
        default_value = "1,2,5,10,15,20,30,40,50,75,100,150,200",
        value_delimiter = ','
    )]
    depths_ms: Vec<u64>,
    /// Seconds of each CPU window in part 4.
    #[arg(long, default_value_t = 10.0)]
    cpu_seconds: f64,
    /// Seed of the injected delays.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Run the demo with its own heartbeat timeouts (300 ms) rather than
    /// 3 s (see [`demo_config`]).
    #[arg(long)]
    demo_heartbeats: bool,
}

/// The embedded demo, as the server runs it without `--config`, with its
/// heartbeat timeouts (300 ms: the gateway's of the nodes, the drives' of
/// the master) at 3 s unless `demo_heartbeats`: on a loaded machine a
/// simulated drive's heartbeat may come late, the axis is lost and the
/// stream ends; the timeouts take no part in the figures.
fn demo_config(demo_heartbeats: bool) -> String {
    let demo = cangate_server::config::DEMO_CONFIG;
    if demo_heartbeats {
        return demo.to_string();
    }
    demo.replace("heartbeat_timeout_ms = 300", "heartbeat_timeout_ms = 3000")
        .replace(
            "sync_period_us = 10000\n",
            "sync_period_us = 10000\ndrive_heartbeat_timeout_ms = 3000\n",
        )
}

/// The circle's radius, mm.
const RADIUS: f64 = 10.0;
/// One turn per second at full speed.
const PERIOD: Duration = Duration::from_secs(1);
/// The client's point period: 1 kHz.
const POINT_PERIOD: Duration = Duration::from_millis(1);
/// How long the server may take to answer its first call.
const READY_TIMEOUT: Duration = Duration::from_secs(30);

fn main() -> ExitCode {
    let args = Args::parse();
    let rt = match tokio::runtime::Runtime::new() {
        Ok(rt) => rt,
        Err(e) => return host::exit_code("stream_bench", false, Err(e.into())),
    };
    host::exit_code("stream_bench", false, rt.block_on(run(args)))
}

/// The demo's SYNC period (the one CANopen master's).
fn demo_sync_period() -> Duration {
    let config = cangate_server::Config::demo();
    Duration::from_micros(config.canopen.first().map_or(10_000, |c| c.sync_period_us))
}

/// The client, the lease over X, Y and Z, where X and Y stood at the
/// start.
struct Bed {
    client: Client,
    lease: ControlLease,
    home: [f64; 2],
    sync: Duration,
    /// The axes in use (Z from part 4).
    axes: Mutex<Vec<&'static str>>,
    /// Runs repeated after a drive left operation enabled.
    repeated: Mutex<Vec<String>>,
}

impl Bed {
    /// Runs `run` again (twice at the most) when it fails, after bringing
    /// back the drives: on a loaded machine a simulated drive may miss
    /// the master's heartbeat (300 ms in the demo) and fault, which ends a
    /// stream; such runs are said, not hidden.
    async fn retrying<T, F, Fut>(&self, what: &str, mut run: F) -> Result<T>
    where
        F: FnMut() -> Fut,
        Fut: std::future::Future<Output = Result<T>>,
    {
        let mut attempt = 1;
        loop {
            match run().await {
                Ok(v) => return Ok(v),
                Err(e) if attempt < 3 => {
                    println!("   ({what}: {e:#}; the drives brought back, run again)");
                    self.repeated
                        .lock()
                        .expect("lock")
                        .push(format!("{what}: {e:#}"));
                    self.recover().await?;
                    attempt += 1;
                }
                Err(e) => return Err(e),
            }
        }
    }

    /// Resets a fault and enables again every axis in use that is not
    /// operation enabled.
    async fn recover(&self) -> Result<()> {
        let axes = self.axes.lock().expect("lock").clone();
        for a in axes {
            let s = self.client.axis_status(a).await?;
            if s.state == pb::DriveState::OperationEnabled as i32 && !s.node_lost {
                continue;
            }
            let wait = self.lease.options().wait(true);
            if s.state == pb::DriveState::Fault as i32 {
                self.client.reset_fault(a, &wait).await?;
            }
            self.client.enable(a, &wait).await?;
        }
        Ok(())
    }

    /// Moves X and Y back to where they stood at the start, so that every
    /// circle starts at the same place (a circle cut short by an underrun
    /// ends elsewhere).
    async fn go_home(&self) -> Result<()> {
        self.client
            .move_axes(
                &[("X", self.home[0]), ("Y", self.home[1])],
                &self.lease.move_options().wait(true),
            )
            .await?;
        Ok(())
    }
}

/// What one streamed circle measured.
#[derive(Debug, Clone)]
struct CircleRun {
    counters: pb::SetpointCounters,
    /// The drives' pairs' distance from the circle.
    contour: ErrorStats,
    /// The drives' pairs against the path at the same path time.
    path_time: Option<PathTimeError>,
    /// The commanded positions (each status's) distance from the circle.
    commanded: ErrorStats,
    sent: PacedSend,
    /// Why the stream ended.
    ended: String,
    /// From the path's time to the drives' (buffer, network, SYNC, the
    /// drive's lag): the latency taken out at the same path time.
    latency: Option<Duration>,
}

impl CircleRun {
    fn json(&self) -> Value {
        let c = &self.counters;
        json!({
            "received": c.received, "played": c.played, "refused": c.refused,
            "late": c.late, "dropped": c.dropped, "underruns": c.underruns,
            "limited": c.limited,
            "contour_mm": stats_json(&self.contour),
            "path_time_mm": self.path_time.map(|p| stats_json(&p.error)),
            "commanded_mm": stats_json(&self.commanded),
            "delay_p99_ms": ms(self.sent.delay_p99),
            "delay_max_ms": ms(self.sent.delay_max),
            "ended": self.ended,
        })
    }
}

fn stats_json(s: &ErrorStats) -> Value {
    json!({"max": s.max, "rms": s.rms, "median": s.median, "samples": s.samples})
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Watches X and Y into a trace until dropped.
struct Watch {
    trace: Arc<Mutex<PlanarTrace>>,
    task: tokio::task::JoinHandle<()>,
}

impl Watch {
    async fn start(bed: &Bed) -> Result<Watch> {
        let mut updates = bed.client.watch_axes(&["X", "Y"], false).await?;
        let trace = Arc::new(Mutex::new(PlanarTrace::new("X", "Y", bed.sync)));
        let into = trace.clone();
        let task = tokio::spawn(async move {
            while let Some(Ok(u)) = updates.next().await {
                if let cangate_client::AxisUpdate::Status(s) = u {
                    into.lock().expect("trace lock").record(&s);
                }
            }
        });
        Ok(Watch { trace, task })
    }

    fn finish(self) -> Vec<(u64, [f64; 2])> {
        self.task.abort();
        self.trace.lock().expect("trace lock").pairs()
    }
}

/// The positions X and Y are commanded to now.
async fn demand(client: &Client, axes: &[&str]) -> Result<Vec<f64>> {
    let mut out = Vec::new();
    for a in axes {
        out.push(client.axis_status(a).await?.demand_position);
    }
    Ok(out)
}

/// What [`stream_path`] saw.
struct Streamed {
    /// The last status.
    last: pb::SetpointStreamStatus,
    sent: PacedSend,
    /// Every status's commanded positions.
    commanded: Vec<Vec<f64>>,
    /// Unix time (s) of the path's start (the first point's time), as the
    /// client started sending: within a millisecond.
    origin_unix_s: f64,
}

/// Streams `path` (positions per path time, one per axis) over `axes` for
/// `duration`, a point every ms, through `delay`.
async fn stream_path(
    bed: &Bed,
    axes: &[&str],
    depth: Duration,
    duration: Duration,
    delay: InjectedDelay,
    path: impl FnMut(Duration) -> Vec<f64> + Send + 'static,
) -> Result<Streamed> {
    let mut stream = bed
        .client
        .stream_setpoints(
            &bed.lease,
            axes,
            SetpointStreamOptions {
                depth,
                extrapolate: None,
                point_period: Some(POINT_PERIOD),
                status_period: Some(Duration::from_millis(10)),
            },
        )
        .await?;
    let sender = stream.sender().context("a new stream has a sender")?;
    let points = (duration.as_micros() / POINT_PERIOD.as_micros()) as u64 + 1;
    let origin_unix_s = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)?
        .as_secs_f64();
    let mut sending = Some(tokio::spawn(async move {
        send_paced(&sender, POINT_PERIOD, points, delay, path).await
    }));
    let mut sent = None;
    let mut commanded = Vec::new();
    let mut last = None;
    loop {
        // (Reading a status is cancel-safe: the call keeps its state.)
        let status = tokio::select! {
            s = stream.status() => s?,
            r = async { sending.as_mut().expect("guarded").await }, if sending.is_some() => {
                // Every point sent: the gateway plays the rest, then ends.
                sending = None;
                sent = Some(r??);
                stream.finish();
                continue;
            }
        };
        let Some(s) = status else { break };
        commanded.push(s.commanded_positions.clone());
        last = Some(s);
    }
    let sent = match (sent, sending) {
        (Some(s), _) => s,
        // The call ended before every point went out.
        (None, Some(task)) => task.await??,
        (None, None) => bail!("the sender ended without a result"),
    };
    Ok(Streamed {
        last: last.context("the stream sent no status")?,
        sent,
        commanded,
        origin_unix_s,
    })
}

/// Streams the circle from home with `depth` and `jitter` (p99), watching
/// the drives.
async fn stream_circle(
    bed: &Bed,
    turns: f64,
    depth: Duration,
    jitter: Duration,
    seed: u64,
) -> Result<CircleRun> {
    bed.go_home().await?;
    let start = demand(&bed.client, &["X", "Y"]).await?;
    let circle = Circle::starting_at([start[0], start[1]], RADIUS, turns, PERIOD);
    let delay = if jitter.is_zero() {
        InjectedDelay::none()
    } else {
        InjectedDelay::exponential(jitter, seed)
    };
    let watch = Watch::start(bed).await?;
    let Streamed {
        last,
        sent,
        commanded,
        origin_unix_s,
    } = stream_path(
        bed,
        &["X", "Y"],
        depth,
        circle.duration(),
        delay,
        move |t| circle.point(t.as_secs_f64()).to_vec(),
    )
    .await?;
    let pairs = watch.finish();
    let path_time = circle.path_time_error(&pairs);
    Ok(CircleRun {
        latency: path_time.map(|p| Duration::from_secs_f64((p.latency_s - origin_unix_s).max(0.0))),
        counters: last.counters.unwrap_or_default(),
        contour: circle.contour_error(&pairs),
        path_time,
        commanded: ErrorStats::of(
            commanded
                .iter()
                .filter(|p| p.len() == 2)
                .map(|p| circle.radial_error([p[0], p[1]])),
        ),
        sent,
        ended: last.ended,
    })
}

/// What the circle as chords measured.
struct ChordRun {
    chords: u32,
    contour: ErrorStats,
    /// The drives' distance from the polygon of chords (the commanded
    /// path).
    to_chords: ErrorStats,
    sagitta: f64,
    time: Duration,
}

/// Distance of `p` from the segment `a`–`b`.
fn segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let f = if len2 > 0.0 {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p[0] - a[0] - f * dx).hypot(p[1] - a[1] - f * dy)
}

/// One turn of the circle as `chords` coordinated moves, each waited for.
async fn move_chords(bed: &Bed, chords: u32) -> Result<ChordRun> {
    bed.go_home().await?;
    let start = demand(&bed.client, &["X", "Y"]).await?;
    let circle = Circle::starting_at([start[0], start[1]], RADIUS, 1.0, PERIOD);
    let vertex = |i: u32| {
        let a = 2.0 * std::f64::consts::PI * f64::from(i) / f64::from(chords);
        [
            circle.centre[0] - RADIUS * a.cos(),
            circle.centre[1] + RADIUS * a.sin(),
        ]
    };
    let watch = Watch::start(bed).await?;
    let t0 = Instant::now();
    for i in 1..=chords {
        let v = vertex(i);
        bed.client
            .move_axes(
                &[("X", v[0]), ("Y", v[1])],
                &bed.lease.move_options().wait(true),
            )
            .await?;
    }
    let time = t0.elapsed();
    let pairs = watch.finish();
    let to_chords = ErrorStats::of(pairs.iter().map(|(_, p)| {
        (0..chords)
            .map(|i| segment_distance(*p, vertex(i), vertex(i + 1)))
            .fold(f64::INFINITY, f64::min)
    }));
    Ok(ChordRun {
        chords,
        contour: circle.contour_error(&pairs),
        to_chords,
        sagitta: RADIUS * (1.0 - (std::f64::consts::PI / f64::from(chords)).cos()),
        time,
    })
}

/// One row of the depth sweep.
#[derive(Debug, Clone)]
struct DepthRow {
    depth_ms: u64,
    late: u64,
    underruns: u64,
}

/// The server's CPU seconds per second over `window` with nothing
/// streaming.
async fn idle_cpu(pid: u32, window: Duration) -> Result<f64> {
    let c0 = process_cpu_seconds(pid)?;
    let t0 = Instant::now();
    tokio::time::sleep(window).await;
    Ok((process_cpu_seconds(pid)? - c0) / t0.elapsed().as_secs_f64())
}

/// The server's CPU seconds per second while a stream without jitter plays
/// the circle (X, Y) and Z following Y, on the first `n` of X, Y, Z, for
/// about `window`.
async fn streaming_cpu(bed: &Bed, pid: u32, n: usize, window: Duration) -> Result<(f64, u64)> {
    bed.go_home().await?;
    let names = ["X", "Y", "Z"];
    let start = demand(&bed.client, &names).await?;
    let turns = (window.as_secs_f64() / PERIOD.as_secs_f64() - 0.5).max(0.5);
    let circle = Circle::starting_at([start[0], start[1]], RADIUS, turns, PERIOD);
    let z0 = start[2];
    let c0 = process_cpu_seconds(pid)?;
    let t0 = Instant::now();
    let streamed = stream_path(
        bed,
        &names[..n],
        Duration::from_millis(50),
        circle.duration(),
        InjectedDelay::none(),
        move |t| {
            let p = circle.point(t.as_secs_f64());
            let mut v = vec![p[0], p[1], z0 + (p[1] - circle.centre[1]) / 2.0];
            v.truncate(n);
            v
        },
    )
    .await?;
    let cpu = (process_cpu_seconds(pid)? - c0) / t0.elapsed().as_secs_f64();
    Ok((cpu, streamed.last.counters.unwrap_or_default().played))
}

async fn run(args: Args) -> Result<bool> {
    println!("{}", report::banner("stream_bench", args.quick));
    let binary = match &args.server_bin {
        Some(b) => b.clone(),
        None => default_server_binary()?,
    };
    if !binary.is_file() {
        bail!(
            "{} not found: build it (cargo build -p cangate-server) or pass --server-bin",
            binary.display()
        );
    }
    let (turns, sweep_turns, chords, cpu_window) = if args.quick {
        (1.0, 0.5, 6, Duration::from_millis(1000))
    } else {
        (
            args.turns,
            1.0,
            args.chords,
            Duration::from_secs_f64(args.cpu_seconds),
        )
    };
    let jitters: Vec<Duration> = args
        .jitter_ms
        .iter()
        .map(|j| Duration::from_secs_f64(j.max(0.0) / 1e3))
        .collect();
    let depths: Vec<u64> = if args.quick {
        vec![5, 50]
    } else {
        args.depths_ms.clone()
    };
    let config_path =
        std::env::temp_dir().join(format!("stream_bench-{}.toml", std::process::id()));
    std::fs::write(&config_path, demo_config(args.demo_heartbeats))
        .with_context(|| format!("writing {}", config_path.display()))?;
    let config_arg = config_path.display().to_string();
    let started = ServerChild::start(&binary, &["--config", &config_arg], READY_TIMEOUT).await;
    let _ = std::fs::remove_file(&config_path);
    let server = started?;
    let pid = server.pid();
    println!(
        "server: {} --config <the embedded demo{}> (pid {pid}), ready after {} ms",
        binary.display(),
        if args.demo_heartbeats {
            ""
        } else {
            ", heartbeat timeouts 3 s"
        },
        server.ready_after.as_millis()
    );
    let client = cangate_client::connect_with(
        &server.url,
        &ConnectOptions {
            request_timeout: Some(Duration::from_secs(30)),
            ..Default::default()
        },
    )
    .await?;
    let mut axes_client: AxesClient = client.axes_client();
    axes::wait_up(&mut axes_client, &["X", "Y", "Z"], READY_TIMEOUT).await?;
    let lease = client
        .acquire_control_as(&["X", "Y", "Z"], Duration::from_secs(5), "stream_bench")
        .await?;
    for a in ["X", "Y"] {
        client.enable(a, &lease.options().wait(true)).await?;
    }
    let home = demand(&client, &["X", "Y"]).await?;
    let bed = Bed {
        client,
        lease,
        home: [home[0], home[1]],
        sync: demo_sync_period(),
        axes: Mutex::new(vec!["X", "Y"]),
        repeated: Mutex::new(Vec::new()),
    };
    let depth = Duration::from_millis(args.depth_ms);

    // 1. The streamed circle through each jitter.
    println!(
        "1. circle r {RADIUS} mm, {turns} turns at one turn per {} s (full speed {:.1} mm/s), a point every {} ms, buffer {} ms, SYNC {} ms;",
        PERIOD.as_secs_f64(),
        Circle::starting_at([0.0; 2], RADIUS, 1.0, PERIOD).speed(),
        POINT_PERIOD.as_millis(),
        args.depth_ms,
        bed.sync.as_millis()
    );
    println!(
        "   drives' actual positions (axis state stream, X and Y paired by SYNC) to the path (distance from the circle) and at the same path time (against the path's point at the pair's bus time minus the median latency):"
    );
    println!(
        "   jitter p99 | injected p99 / max | late | underruns | to the path max / RMS | same path time max / RMS | latency | commanded max"
    );
    let mut streamed = Vec::new();
    for &j in &jitters {
        let r = bed
            .retrying("circle", || stream_circle(&bed, turns, depth, j, args.seed))
            .await?;
        let c = &r.counters;
        let (pt_max, pt_rms) = r
            .path_time
            .map_or((f64::NAN, f64::NAN), |p| (p.error.max, p.error.rms));
        println!(
            "   {:>7.0} ms | {:>6.1} / {:>5.1} ms | {:>4} | {:>9} | {:>6.3} / {:.3} mm | {:>8.3} / {:.3} mm | {} | {:.4} mm{}",
            ms(j),
            ms(r.sent.delay_p99),
            ms(r.sent.delay_max),
            c.late,
            c.underruns,
            r.contour.max,
            r.contour.rms,
            pt_max,
            pt_rms,
            r.latency
                .map_or("-".to_string(), |l| format!("{:.0} ms", ms(l))),
            r.commanded.max,
            if r.ended == "CLIENT_ENDED" {
                String::new()
            } else {
                format!(" (ended {})", r.ended)
            }
        );
        streamed.push((j, r));
    }

    // 2. The circle as MoveAxes chords.
    let chord = bed.retrying("chords", || move_chords(&bed, chords)).await?;
    let reference = streamed.first().map(|(_, r)| r);
    println!(
        "2. the same circle as {} MoveAxes chords (each waited for, default velocity and acceleration): {:.1} s for one turn; to the circle max {:.3} / RMS {:.3} mm (sagitta {:.3} mm), to the chords max {:.3} / RMS {:.3} mm",
        chord.chords,
        chord.time.as_secs_f64(),
        chord.contour.max,
        chord.contour.rms,
        chord.sagitta,
        chord.to_chords.max,
        chord.to_chords.rms
    );
    if let Some(r) = reference {
        println!(
            "   streamed ({} ms jitter) / chords: contour error max {:.2}, RMS {:.2}; time per turn {:.2}",
            ms(streamed[0].0),
            r.contour.max / chord.contour.max,
            r.contour.rms / chord.contour.rms,
            PERIOD.as_secs_f64() / chord.time.as_secs_f64()
        );
    }

    // 3. The buffer depth each jitter needs.
    println!(
        "3. buffer depth for no underrun ({sweep_turns} turn per depth, depths {depths:?} ms):"
    );
    let mut sweeps = Vec::new();
    for &j in &jitters {
        let mut rows = Vec::new();
        for &d in &depths {
            let r =
                stream_circle(&bed, sweep_turns, Duration::from_millis(d), j, args.seed).await?;
            rows.push(DepthRow {
                depth_ms: d,
                late: r.counters.late,
                underruns: r.counters.underruns,
            });
            // Two clean depths in a row end the sweep (one, quick): a
            // single clean run may be luck on a loaded machine.
            let clean = rows
                .iter()
                .rev()
                .take_while(|r| r.underruns == 0 && r.late == 0)
                .count();
            if clean >= if args.quick { 1 } else { 2 } {
                break;
            }
        }
        // The smallest depth from which every deeper one swept was clean.
        let clean_from = |clean: fn(&DepthRow) -> bool| {
            let after = rows.iter().rposition(|r| !clean(r)).map_or(0, |i| i + 1);
            rows.get(after).map(|r| r.depth_ms)
        };
        let no_underrun = clean_from(|r| r.underruns == 0);
        let no_late = clean_from(|r| r.underruns == 0 && r.late == 0);
        let shown: Vec<String> = rows
            .iter()
            .map(|r| {
                format!(
                    "{} ms: {} late, {} underruns",
                    r.depth_ms, r.late, r.underruns
                )
            })
            .collect();
        println!(
            "   jitter p99 {:>2.0} ms: no underrun from {}, nor a late point from {} ({})",
            ms(j),
            depth_text(no_underrun),
            depth_text(no_late),
            shown.join("; ")
        );
        sweeps.push(json!({
            "jitter_ms": ms(j),
            "no_underrun_depth_ms": no_underrun,
            "no_late_depth_ms": no_late,
            "rows": rows.iter().map(|r| json!({"depth_ms": r.depth_ms, "late": r.late, "underruns": r.underruns})).collect::<Vec<_>>(),
        }));
    }

    // 4. CPU per streamed axis.
    bed.axes.lock().expect("lock").push("Z");
    bed.client
        .enable("Z", &bed.lease.options().wait(true))
        .await?;
    bed.client
        .set_mode("Z", pb::DriveMode::Csp, &bed.lease.options().wait(true))
        .await
        .map_err(|e| anyhow!("switching Z to CSP: {e}"))?;
    println!(
        "4. server CPU (all its threads, /proc/{pid}/stat), {:.1} s windows, 1 kHz points sent as they come (one message each), 50 ms buffer:",
        cpu_window.as_secs_f64()
    );
    let idle = idle_cpu(pid, cpu_window).await?;
    println!("   at rest: {:.1} ms/s", idle * 1e3);
    let mut cpu_rows = Vec::new();
    for n in 1..=3usize {
        let (cpu, played) = bed
            .retrying("cpu", || streaming_cpu(&bed, pid, n, cpu_window))
            .await?;
        let added = (cpu - idle) * 1e3;
        println!(
            "   {n} axis stream ({}): {:.1} ms/s, {:+.1} ms/s over rest, {:.1} ms/s per axis ({played} points played)",
            ["X", "X, Y", "X, Y, Z"][n - 1],
            cpu * 1e3,
            added,
            added / n as f64
        );
        cpu_rows.push(json!({"axes": n, "cpu_ms_per_s": cpu * 1e3, "added_ms_per_s": added, "per_axis_ms_per_s": added / n as f64}));
    }
    if let (Some(one), Some(three)) = (cpu_rows.first(), cpu_rows.get(2)) {
        let added = |v: &Value| v["added_ms_per_s"].as_f64().unwrap_or(f64::NAN);
        println!(
            "   each axis beyond the first: {:+.1} ms/s ((3 axes - 1 axis) / 2); the rest is the stream's (a gRPC message per point)",
            (added(three) - added(one)) / 2.0
        );
    }
    let idle_after = idle_cpu(pid, cpu_window).await?;
    println!(
        "   at rest again: {:.1} ms/s (the spread of the rest figure is the measurement's noise)",
        idle_after * 1e3
    );
    let repeated = bed.repeated.lock().expect("lock").clone();
    if !repeated.is_empty() {
        println!(
            "{} run(s) repeated after a drive left operation enabled (a loaded machine)",
            repeated.len()
        );
    }
    let _ = bed.lease.release().await;
    let mut server = server;
    let _ = server.terminate();

    println!(
        "{}",
        json!({
            "bench": "stream",
            "quick": args.quick,
            "build": if cfg!(debug_assertions) { "debug" } else { "release" },
            "radius_mm": RADIUS,
            "turns": turns,
            "depth_ms": args.depth_ms,
            "sync_ms": ms(bed.sync),
            "streamed": streamed.iter().map(|(j, r)| {
                let mut v = r.json();
                v["jitter_ms"] = json!(ms(*j));
                v["latency_ms"] = json!(r.latency.map(ms));
                v
            }).collect::<Vec<_>>(),
            "chords": {
                "chords": chord.chords, "time_s": chord.time.as_secs_f64(),
                "contour_mm": stats_json(&chord.contour), "to_chords_mm": stats_json(&chord.to_chords),
                "sagitta_mm": chord.sagitta,
            },
            "depth_sweep": sweeps,
            "repeated_runs": repeated,
            "cpu": {"idle_ms_per_s": idle * 1e3, "idle_after_ms_per_s": idle_after * 1e3, "streams": cpu_rows},
        })
    );
    Ok(true)
}

fn depth_text(d: Option<u64>) -> String {
    d.map_or("beyond the sweep".to_string(), |d| format!("{d} ms"))
}
