//! `cangate replay FILE`: plays a candump log onto the gateway's buses, as
//! canplayer plays one onto local interfaces: the log's timing kept (or as
//! fast as the gateway takes frames), buses renamed with canplayer's
//! `TARGET=SOURCE` assignments, repeated with `--loop`. The file is read as
//! it plays, so a log of any size needs little memory.

use super::bus_writer::{BATCH, BusWriter, Tally};
use super::candump_log::{LogLine, LogRecord, parse_line};
use super::{App, Context, Failure, Result, ctrl_c};
use clap::Args;
use std::collections::BTreeMap;
use std::io::BufRead;
use std::path::PathBuf;
use tokio::time::{Duration, Instant};

/// `cangate replay FILE [TARGET=SOURCE…]`
#[derive(Args, Debug)]
pub(crate) struct ReplayArgs {
    /// The candump log (`candump -l`/`-L`, `cangate dump --log`); `-`:
    /// standard input.
    file: PathBuf,
    /// Play the frames the log has for bus SOURCE onto bus TARGET (as
    /// canplayer's `can1=can0`); with assignments, frames of other buses
    /// are skipped; without, each frame goes to the bus the log names.
    #[arg(value_name = "TARGET=SOURCE", value_parser = assignment)]
    assign: Vec<(String, String)>,
    /// Ignore the log's timing: send as fast as the gateway takes frames.
    #[arg(long)]
    fast: bool,
    /// Play the log N times.
    #[arg(long = "loop", value_name = "N", default_value_t = 1,
          value_parser = clap::value_parser!(u32).range(1..))]
    loops: u32,
}

fn assignment(text: &str) -> Result<(String, String), String> {
    match text.split_once('=') {
        Some((t, s)) if !t.is_empty() && !s.is_empty() => Ok((t.to_string(), s.to_string())),
        _ => Err(format!("{text:?} is not TARGET=SOURCE (e.g. can1=can0)")),
    }
}

impl ReplayArgs {
    /// Refused before connecting: a file that cannot be opened.
    pub(crate) fn check(&self) -> Result<()> {
        if self.file.as_os_str() != "-" {
            std::fs::File::open(&self.file).ctx(format!("opening {}", self.file.display()))?;
        }
        if self.loops > 1 && self.file.as_os_str() == "-" {
            return Err(Failure::usage(
                "replay",
                "--loop needs a file: standard input can be read once",
            ));
        }
        Ok(())
    }

    /// The bus a log frame goes to, if any.
    fn target(&self, source: &str) -> Option<String> {
        if self.assign.is_empty() {
            return Some(source.to_string());
        }
        self.assign
            .iter()
            .find(|(_, s)| s == source)
            .map(|(t, _)| t.clone())
    }
}

/// Reads the log on a thread of its own (file reads block; standard input
/// may stall for as long as its writer likes, and Ctrl-C must still end
/// the replay), `loops` times, handing the lines over through a bounded
/// queue: `(line number, line)`, `None` at the end of each pass.
fn read_lines(
    file: PathBuf,
    loops: u32,
) -> tokio::sync::mpsc::Receiver<std::io::Result<Option<(usize, String)>>> {
    let (tx, rx) = tokio::sync::mpsc::channel(1024);
    std::thread::spawn(move || {
        for _ in 0..loops {
            let reader: Box<dyn BufRead> = if file.as_os_str() == "-" {
                Box::new(std::io::BufReader::new(std::io::stdin()))
            } else {
                match std::fs::File::open(&file) {
                    Ok(f) => Box::new(std::io::BufReader::new(f)),
                    Err(e) => {
                        let _ = tx.blocking_send(Err(e));
                        return;
                    }
                }
            };
            for (i, line) in reader.lines().enumerate() {
                let stop = line.is_err();
                if tx.blocking_send(line.map(|l| Some((i + 1, l)))).is_err() || stop {
                    return;
                }
            }
            if tx.blocking_send(Ok(None)).is_err() {
                return;
            }
        }
    });
    rx
}

/// The writers, one per target bus, opened as the log first names it.
struct Writers<'a> {
    app: &'a App,
    open: BTreeMap<String, BusWriter>,
    pending: BTreeMap<String, Vec<cangate_client::can::Frame>>,
    /// CAN FD frames of the log left out, by classic bus: the gateway
    /// would refuse the whole batch they are in.
    skipped_fd: BTreeMap<String, u64>,
}

impl Writers<'_> {
    async fn queue(&mut self, bus: String, record: LogRecord) -> Result<()> {
        let writer = match self.open.entry(bus.clone()) {
            std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::btree_map::Entry::Vacant(e) => {
                e.insert(BusWriter::open(self.app, &bus).await?)
            }
        };
        if record.frame.is_fd() && !writer.fd() {
            *self.skipped_fd.entry(bus).or_default() += 1;
            return Ok(());
        }
        let batch = self.pending.entry(bus.clone()).or_default();
        batch.push(record.frame);
        if batch.len() >= BATCH {
            self.flush_bus(&bus).await?;
        }
        Ok(())
    }

    async fn flush_bus(&mut self, bus: &str) -> Result<()> {
        let Some(frames) = self.pending.remove(bus) else {
            return Ok(());
        };
        if let Some(w) = self.open.get(bus) {
            w.send(&frames).await?;
        }
        Ok(())
    }

    async fn flush(&mut self) -> Result<()> {
        let buses: Vec<String> = self.pending.keys().cloned().collect();
        for bus in buses {
            self.flush_bus(&bus).await?;
        }
        Ok(())
    }

    async fn finish(self) -> BTreeMap<String, Tally> {
        let mut out = BTreeMap::new();
        for (bus, w) in self.open {
            out.insert(bus, w.finish().await);
        }
        out
    }
}

/// `cangate replay FILE …`
pub(crate) async fn replay(app: &App, a: ReplayArgs) -> Result<()> {
    let mut writers = Writers {
        app,
        open: BTreeMap::new(),
        pending: BTreeMap::new(),
        skipped_fd: BTreeMap::new(),
    };
    let mut skipped_errors = 0u64;
    let played = tokio::select! {
        r = play(&a, &mut writers, &mut skipped_errors) => r.map(|()| true),
        _ = ctrl_c() => Ok(false),
    };
    // Whatever happened, what was queued goes and is accounted for.
    let flushed = writers.flush().await;
    let skipped_fd = std::mem::take(&mut writers.skipped_fd);
    let tallies = writers.finish().await;
    for (bus, t) in &tallies {
        eprintln!("cangate: replay on {bus}: {}", t.summary());
    }
    for (bus, n) in &skipped_fd {
        eprintln!(
            "cangate: replay on {bus}: {n} CAN FD frames of the log skipped (the bus is classic CAN)"
        );
    }
    if skipped_errors > 0 {
        eprintln!(
            "cangate: replay: {skipped_errors} error frames of the log skipped (they are received, never sent)"
        );
    }
    let played = played?;
    flushed?;
    if !played {
        return Err(Failure::interrupted("replay"));
    }
    let incomplete: Vec<String> = tallies
        .iter()
        .filter(|(_, t)| !t.complete())
        .map(|(bus, t)| format!("{bus}: {}", t.summary()))
        .collect();
    if !incomplete.is_empty() {
        return Err(Failure::failed(
            format!("replay of {}", a.file.display()),
            format!("not every frame went out ({})", incomplete.join("; ")),
        ));
    }
    Ok(())
}

/// Reads the log (`loops` times) and sends each frame at its time.
async fn play(a: &ReplayArgs, writers: &mut Writers<'_>, skipped_errors: &mut u64) -> Result<()> {
    let mut lines = read_lines(a.file.clone(), a.loops);
    let mut first_ns: Option<u64> = None;
    let mut start = Instant::now();
    while let Some(item) = lines.recv().await {
        let Some((number, line)) = item.ctx(format!("reading {}", a.file.display()))? else {
            // The end of a pass: the next one starts its own clock.
            writers.flush().await?;
            first_ns = None;
            start = Instant::now();
            continue;
        };
        let record = match parse_line(&line) {
            Ok(LogLine::Frame(r)) => r,
            Ok(LogLine::ErrorFrame) => {
                *skipped_errors += 1;
                continue;
            }
            Ok(LogLine::Blank) => continue,
            Err(why) => {
                return Err(Failure::usage(
                    "replay",
                    format!("{}:{number}: {why}", a.file.display()),
                ));
            }
        };
        let Some(bus) = a.target(&record.bus) else {
            continue;
        };
        if !a.fast {
            let t0 = *first_ns.get_or_insert(record.time_ns);
            let due = start + Duration::from_nanos(record.time_ns.saturating_sub(t0));
            // Frames due later: what is queued goes first, then wait.
            if due > Instant::now() {
                writers.flush().await?;
                tokio::time::sleep_until(due).await;
            }
        }
        writers.queue(bus, record).await?;
    }
    writers.flush().await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn assignments_rename_buses_like_canplayer() {
        assert_eq!(assignment("can1=can0"), Ok(("can1".into(), "can0".into())));
        assert!(assignment("can1").is_err());
        assert!(assignment("=can0").is_err());
        let mut a = ReplayArgs {
            file: "-".into(),
            assign: vec![],
            fast: false,
            loops: 1,
        };
        assert_eq!(a.target("can0"), Some("can0".into()));
        a.assign = vec![("smc0".into(), "can0".into())];
        assert_eq!(a.target("can0"), Some("smc0".into()));
        assert_eq!(a.target("can1"), None);
    }
}
