//! `dashboard_bench`: the browser dashboard's live frame view with can0 at
//! full load, in the system's headless Chromium.
//!
//! ```text
//! scripts/web-build                                           # web/node_modules
//! cargo run --release -p cangate-bench --bin dashboard_bench
//! ```
//!
//! The gateway runs the demo configuration (can0 bit-timed at 1 Mbit/s with
//! its simulated devices). The benchmark, as another node on the wire,
//! keeps can0 at full load with 8-byte frames (identifiers 0x700-0x77F,
//! about 8,300 frames/s with the demo's own traffic) and, from a second
//! node, every 50 ms puts a marker frame on the bus (identifier 0x010, so
//! it wins arbitration; its data the time it was queued, µs since the
//! epoch). `web/tests/frame_view_perf.mjs` opens the
//! dashboard's live view of can0 and records when each marker's line is
//! first on the screen.
//!
//! Reports, for an idle phase and a loaded one of `--seconds` each: the
//! browser's CPU (every Chromium process, from /proc, in % of one core;
//! in the idle phase for every page of the dashboard in turn),
//! and under load the delay from the marker entering the bus queue to its
//! line on the screen (p50/p99; it includes the bus's arbitration under
//! full load, the gateway, gRPC-Web, the page's coalescing to animation
//! frames and the rendering), the rate the page shows, and frames it
//! reports lost.
//!
//! Needs node, `web/node_modules` (`scripts/web-build`) and Chromium
//! (`/usr/bin/chromium` or `CANGATE_CHROMIUM`); says so and exits 1
//! without them. Human-readable results, then one JSON line.

use anyhow::{Context, Result, bail};
use cangate_bench::{gateway, host, report};
use cangate_can::{CanId, Frame};
use clap::Parser;
use serde_json::json;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, ExitCode, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// The dashboard under load.
#[derive(Parser, Debug)]
#[command(about)]
struct Args {
    /// Seconds of each phase (idle, loaded).
    #[arg(long, default_value_t = 10.0)]
    seconds: f64,
    /// Short phases (2 s), for a smoke run.
    #[arg(long)]
    quick: bool,
    /// Profile the page's main thread during the loaded phase and print the
    /// functions with the most self time.
    #[arg(long)]
    profile: bool,
}

/// The marker's identifier: above the load in priority, so that it waits
/// for the frame on the wire, not for the whole load queue.
const MARKER_ID: u16 = 0x010;
/// Load frames queued per millisecond: a little more than 1 Mbit/s carries
/// (8-byte frames are ~125 bit times), so the bus stays saturated.
const LOAD_PER_MS: usize = 9;
/// The dashboard's pages measured at demo traffic besides the buses page
/// (the frame view, measured first and under load).
const OTHER_PAGES: [&str; 5] = ["axes", "canopen", "cansmc", "handwheel", "alarms"];

fn main() -> ExitCode {
    let args = Args::parse();
    host::exit_code("dashboard_bench", false, run(&args).map(|()| true))
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn run(args: &Args) -> Result<()> {
    let seconds = if args.quick { 2.0 } else { args.seconds };
    let web = repo().join("web");
    if !web.join("node_modules/puppeteer-core").exists() {
        bail!("web/node_modules is missing: run scripts/web-build first");
    }
    let chromium = std::env::var("CANGATE_CHROMIUM").unwrap_or_else(|_| "/usr/bin/chromium".into());
    if !Path::new(&chromium).exists() {
        bail!(
            "no Chromium at {chromium} (Debian: apt-get install chromium; or set CANGATE_CHROMIUM)"
        );
    }
    println!("{}", report::banner("dashboard_bench", args.quick));
    let rt = gateway::runtime("gateway", gateway::gateway_workers())?;
    let mut config = cangate_server::Config::demo();
    config.listen = "127.0.0.1:0".parse().expect("address");
    gateway::lift_client_limits(&mut config);
    let server = gateway::start_on(&rt, &config)?;
    let url = gateway::url(&server);
    let bus = gateway::virtual_bus(&server, "can0")?;

    let mut page = Page::start(&web, &url, args.profile)?;
    page.wait_for("ready", Duration::from_secs(60))?;

    // Idle: the demo's own traffic only.
    let idle = browser_cpu_over(page.pid(), seconds)?;
    println!("idle page: browser {:.1} % of one core", idle * 100.0);

    // The other pages at demo traffic: what a panel PC showing one of them
    // all shift spends on the browser.
    let mut pages = serde_json::Map::new();
    pages.insert("buses".into(), json!(idle));
    for name in OTHER_PAGES {
        page.show(name)?;
        let cpu = browser_cpu_over(page.pid(), seconds)?;
        println!("{name} page: browser {:.1} % of one core", cpu * 100.0);
        pages.insert(name.into(), json!(cpu));
    }
    page.show("buses")?;

    // Loaded: the bench saturates can0 and sends markers.
    // Two nodes: the load's transmit queue stays full (a node sends its
    // queue in order), so the markers come from a node of their own and
    // win arbitration by their identifier, as a high-priority message on a
    // real bus does.
    let (load_port, marker_port) = (bus.connect(false), bus.connect(false));
    let stop = Arc::new(AtomicBool::new(false));
    let loader = {
        let stop = stop.clone();
        std::thread::Builder::new()
            .name("bench-load".into())
            .spawn(move || load(&load_port, &marker_port, &stop))
            .context("starting the load thread")?
    };
    // Let the page settle into the load before measuring.
    std::thread::sleep(Duration::from_secs(1));
    if args.profile {
        page.say("profile-start")?;
    }
    let own_before = host::thread_cpu()?;
    let loaded = browser_cpu_over(page.pid(), seconds)?;
    let own = own_cpu_since(&own_before, seconds)?;
    let report = page.report()?;
    let stats = server
        .gateway()
        .buses()
        .find(|b| b.name() == "can0")
        .map(|b| b.stats());
    stop.store(true, Ordering::Relaxed);
    let sent = loader
        .join()
        .map_err(|_| anyhow::anyhow!("the load thread panicked"))??;
    page.quit();

    rt.block_on(gateway::stop(server));

    let mut delays: Vec<i64> = report["delays_us"]
        .as_array()
        .map(|a| a.iter().filter_map(serde_json::Value::as_i64).collect())
        .unwrap_or_default();
    if delays.is_empty() {
        bail!("no marker reached the screen");
    }
    // In the order they were shown: a delay that grows through the run is
    // a backlog (the page falls behind), a steady one is latency.
    let median = |d: &[i64]| {
        let mut d = d.to_vec();
        d.sort_unstable();
        d[d.len() / 2] as f64 / 1000.0
    };
    let tenth = delays.len().div_ceil(10);
    let (first, last) = (
        median(&delays[..tenth]),
        median(&delays[delays.len() - tenth..]),
    );
    delays.sort_unstable();
    let q = |p: f64| delays[((delays.len() - 1) as f64 * p).round() as usize] as f64 / 1000.0;
    let (p50, p99) = (q(0.50), q(0.99));
    if let Some(top) = report["profile_top"].as_array() {
        println!("page main thread, self time during the loaded phase:");
        for f in top {
            println!("  {:>6} ms  {}", f[1], f[0].as_str().unwrap_or("?"));
        }
    }
    let rate = report["rate_text"].as_str().unwrap_or("");
    let lost = report["lost_text"].as_str().unwrap_or("");
    println!(
        "loaded page: browser {:.1} % of one core; the page shows {rate}{}",
        loaded * 100.0,
        if lost.is_empty() {
            String::new()
        } else {
            format!(", {lost}")
        }
    );
    println!(
        "this process meanwhile (the gateway, the bus model, the load): {:.0} % of one core; {}",
        own.iter().map(|(_, c)| c).sum::<f64>() * 100.0,
        own.iter()
            .take(6)
            .map(|(n, c)| format!("{n} {:.0} %", c * 100.0))
            .collect::<Vec<_>>()
            .join(", ")
    );
    println!(
        "bus to screen: p50 {p50:.1} ms, p99 {p99:.1} ms over {} markers (median of the first \
         tenth {first:.1} ms, of the last {last:.1} ms; {} load frames queued{})",
        delays.len(),
        sent.0,
        stats.map_or(String::new(), |s| format!(
            ", bus load {:.0} %",
            s.load_percent
        )),
    );
    println!(
        "{}",
        json!({
            "bench": "dashboard",
            "idle_browser_cpu": idle,
            "page_browser_cpu": pages,
            "loaded_browser_cpu": loaded,
            "delay_ms_p50": p50,
            "delay_ms_p99": p99,
            "delay_ms_first_tenth": first,
            "delay_ms_last_tenth": last,
            "markers": delays.len(),
            "rate_text": rate,
            "lost_text": lost,
        })
    );
    Ok(())
}

/// Keeps the bus saturated from `port` and sends a marker from `markers`
/// every 50 ms until `stop`; returns (load frames, markers) queued.
fn load(
    port: &cangate_can::VirtualPort,
    markers_port: &cangate_can::VirtualPort,
    stop: &AtomicBool,
) -> Result<(u64, u64)> {
    let mut counter = 0u64;
    let mut markers = 0u64;
    let mut next_marker = Instant::now();
    while !stop.load(Ordering::Relaxed) {
        let batch: Vec<Frame> = (0..LOAD_PER_MS)
            .map(|_| {
                counter += 1;
                let id = CanId::standard(0x700 + (counter % 0x80) as u32).expect("id");
                Frame::new(id, &counter.to_le_bytes()).expect("frame")
            })
            .collect();
        // A full queue (the bus is saturated) is what we want: drop the rest.
        let _ = port.send_batch(&batch);
        if Instant::now() >= next_marker {
            let us = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_micros() as u64);
            let marker = Frame::new(
                CanId::standard(u32::from(MARKER_ID)).expect("id"),
                &us.to_le_bytes(),
            )
            .expect("frame");
            if markers_port.send(&marker).is_ok() {
                markers += 1;
            }
            next_marker += Duration::from_millis(50);
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    Ok((counter, markers))
}

/// This process's CPU since `before`, per thread name, as shares of one
/// core over `seconds`, most first.
fn own_cpu_since(before: &[(String, f64)], seconds: f64) -> Result<Vec<(String, f64)>> {
    let mut by_name: std::collections::BTreeMap<String, f64> = Default::default();
    for (name, secs) in host::thread_cpu()? {
        *by_name.entry(name).or_default() += secs;
    }
    for (name, secs) in before {
        *by_name.entry(name.clone()).or_default() -= secs;
    }
    let mut out: Vec<(String, f64)> = by_name
        .into_iter()
        .map(|(n, s)| (n, s.max(0.0) / seconds))
        .collect();
    out.sort_by(|a, b| b.1.total_cmp(&a.1));
    Ok(out)
}

/// CPU of every descendant process of `root` (Chromium's processes under
/// node), not `root` itself, as a share of one core over `seconds`.
fn browser_cpu_over(root: u32, seconds: f64) -> Result<f64> {
    let before = descendants_cpu(root);
    let started = Instant::now();
    std::thread::sleep(Duration::from_secs_f64(seconds));
    let after = descendants_cpu(root);
    Ok((after - before).max(0.0) / started.elapsed().as_secs_f64())
}

fn descendants_cpu(root: u32) -> f64 {
    let mut parent_of = Vec::new();
    for entry in std::fs::read_dir("/proc").into_iter().flatten().flatten() {
        let Some(pid) = entry
            .file_name()
            .to_str()
            .and_then(|p| p.parse::<u32>().ok())
        else {
            continue;
        };
        let stat = std::fs::read_to_string(entry.path().join("stat")).unwrap_or_default();
        let Some((_, rest)) = stat.rsplit_once(')') else {
            continue;
        };
        let ppid = rest
            .split_whitespace()
            .nth(1)
            .and_then(|p| p.parse::<u32>().ok());
        if let Some(ppid) = ppid {
            parent_of.push((pid, ppid));
        }
    }
    let mut family = vec![root];
    let mut i = 0;
    while i < family.len() {
        let p = family[i];
        family.extend(parent_of.iter().filter(|(_, pp)| *pp == p).map(|(c, _)| *c));
        i += 1;
    }
    family[1..]
        .iter()
        .filter_map(|pid| host::process_thread_cpu(*pid).ok())
        .map(|threads| threads.iter().map(|t| t.2).sum::<f64>())
        .sum()
}

/// The node script driving Chromium.
struct Page {
    child: Child,
    stdin: Option<ChildStdin>,
    lines: std::sync::mpsc::Receiver<String>,
}

impl Page {
    fn start(web: &Path, url: &str, profile: bool) -> Result<Page> {
        let marker = format!("{MARKER_ID:03X}");
        let mut child = Command::new("node")
            .arg(web.join("tests/frame_view_perf.mjs"))
            .args([url, marker.as_str()])
            .args(profile.then_some("profile"))
            .current_dir(web)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .context("starting node (needed for the browser)")?;
        let out = child.stdout.take().expect("piped");
        let (tx, lines) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Ok(Page {
            stdin: child.stdin.take(),
            child,
            lines,
        })
    }

    fn pid(&self) -> u32 {
        self.child.id()
    }

    fn wait_for(&mut self, want: &str, limit: Duration) -> Result<String> {
        let deadline = Instant::now() + limit;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(l) if l.starts_with(want) => return Ok(l),
                Ok(_) => {}
                Err(_) => bail!("the browser script did not say {want} within {limit:?}"),
            }
        }
    }

    fn say(&mut self, line: &str) -> Result<()> {
        let stdin = self.stdin.as_mut().context("stdin closed")?;
        writeln!(stdin, "{line}")?;
        Ok(())
    }

    /// Shows the dashboard's page `name` and waits until it is drawn.
    fn show(&mut self, name: &str) -> Result<()> {
        self.say(&format!("show {name}"))?;
        self.wait_for(&format!("shown {name}"), Duration::from_secs(60))?;
        Ok(())
    }

    fn report(&mut self) -> Result<serde_json::Value> {
        self.say("report")?;
        let line = self.wait_for("{", Duration::from_secs(30))?;
        serde_json::from_str(&line).context("the browser script's report")
    }

    fn quit(&mut self) {
        if let Some(mut stdin) = self.stdin.take() {
            let _ = writeln!(stdin, "quit");
        }
        let deadline = Instant::now() + Duration::from_secs(10);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Page {
    fn drop(&mut self) {
        self.quit();
    }
}
