//! `cangate flash`: program download (CiA 302-3) of a file into a node,
//! with a progress bar on a terminal (plain progress lines otherwise) and
//! an outcome line.

use super::{App, Context, Failure, Result, ctrl_c, int_arg, label, node_id, print_json_line};
use cangate_client::{Error, NodeId, ProgramOptions, pb};
use clap::Args;
use futures::StreamExt;
use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// `cangate flash BUS NODE FILE`.
#[derive(Args, Debug)]
pub(crate) struct FlashArgs {
    /// The bus.
    bus: String,
    /// The node id (1..=127).
    #[arg(value_parser = node_id)]
    node: NodeId,
    /// The program image file.
    file: PathBuf,
    /// Program number: the sub-index of 0x1F50/0x1F51/0x1F56/0x1F57.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=254))]
    program: u8,
    /// The software identification (0x1F56) the node must report after
    /// the download (decimal or 0x hex).
    #[arg(long, value_parser = int_arg, value_name = "ID")]
    expect_id: Option<u32>,
    /// Clear the program (0x1F51 = 3) before writing it.
    #[arg(long)]
    clear: bool,
    /// Longest wait for the flash status after the data, in ms (0: the
    /// gateway's default, 60 s).
    #[arg(long, default_value_t = 0, value_name = "MS")]
    flash_timeout_ms: u64,
    /// Longest wait for the boot-up after the start, in ms (0: the
    /// gateway's default, 10 s).
    #[arg(long, default_value_t = 0, value_name = "MS")]
    boot_timeout_ms: u64,
}

/// Progress on standard error: a bar redrawn in place on a terminal, one
/// line per step and per 10 % otherwise.
struct Progress {
    tty: bool,
    step: i32,
    tenth: u64,
    started: Instant,
}

impl Progress {
    fn show(&mut self, m: &pb::DownloadProgramProgress) {
        let mut err = std::io::stderr().lock();
        let step = label::<pb::ProgramStep>(m.step);
        let total = m.bytes_total.max(1);
        if self.tty {
            const WIDTH: u64 = 30;
            let filled = (m.bytes_done * WIDTH / total) as usize;
            let secs = self.started.elapsed().as_secs_f64().max(1e-3);
            let _ = write!(
                err,
                "\r[{}{}] {:>3}% {}/{} bytes {:.1} KiB/s {:<26}",
                "#".repeat(filled),
                "-".repeat(WIDTH as usize - filled),
                m.bytes_done * 100 / total,
                m.bytes_done,
                m.bytes_total,
                m.bytes_done as f64 / 1024.0 / secs,
                step
            );
        } else {
            let tenth = m.bytes_done * 10 / total;
            if m.step != self.step || tenth != self.tenth {
                let _ = writeln!(
                    err,
                    "{step}: {}/{} bytes ({}%)",
                    m.bytes_done,
                    m.bytes_total,
                    m.bytes_done * 100 / total
                );
            }
            self.tenth = tenth;
        }
        self.step = m.step;
        let _ = err.flush();
    }

    fn end(&self) {
        if self.tty {
            let _ = writeln!(std::io::stderr());
        }
    }
}

fn id(v: Option<u32>) -> String {
    v.map_or_else(|| "unknown".to_string(), |v| format!("0x{v:08X}"))
}

/// Runs `cangate flash`.
pub(crate) async fn run(app: &App, a: FlashArgs) -> Result<()> {
    let what = format!("flash node {} on {}", a.node, a.bus);
    let image = std::fs::read(&a.file).ctx(format!("reading {}", a.file.display()))?;
    if image.is_empty() {
        return Err(Failure::usage(
            what,
            format!("{} is empty", a.file.display()),
        ));
    }
    let ms = |v: u64| (v > 0).then(|| Duration::from_millis(v));
    let opts = ProgramOptions {
        program: Some(a.program),
        expected_identification: a.expect_id,
        clear: a.clear,
        flash_timeout: ms(a.flash_timeout_ms),
        boot_timeout: ms(a.boot_timeout_ms),
    };
    let canopen = app.client.canopen(&a.bus);
    let mut stream = canopen
        .download_program(a.node, image, &opts)
        .await
        .ctx(what.clone())?;
    let mut progress = Progress {
        tty: !app.json && std::io::stderr().is_terminal(),
        step: -1,
        tenth: u64::MAX,
        started: Instant::now(),
    };
    loop {
        let m = tokio::select! {
            m = stream.next() => m,
            _ = ctrl_c() => {
                progress.end();
                // Dropping the stream cancels the download on the gateway.
                return Err(Failure::interrupted(what));
            }
        };
        let m = match m {
            None => {
                return Err(Failure::failed(
                    what,
                    "the gateway ended the download without an outcome",
                ));
            }
            Some(Err(e)) => {
                progress.end();
                // An SDO abort's line is the client's own (node, object,
                // code): say which step it broke.
                let step = cangate_client::error_metadata(&e).remove("step");
                let what = match step {
                    Some(step) if matches!(e, Error::SdoAbort { .. }) => {
                        format!("{what}, step {step}")
                    }
                    _ => what,
                };
                return Err(e).ctx(what);
            }
            Some(Ok(m)) => m,
        };
        if app.json {
            print_json_line(&m)?;
        } else {
            progress.show(&m);
        }
        if let Some(o) = &m.outcome {
            progress.end();
            if !app.json {
                app.line(format!(
                    "node {} program {}: {} -> {}, {} bytes in {:.2} s ({:.1} KiB/s data, {:.2} s in all)",
                    a.node,
                    a.program,
                    id(o.old_identification),
                    id(Some(o.new_identification)),
                    o.bytes,
                    o.data_duration_ms as f64 / 1000.0,
                    o.data_bytes_per_second / 1024.0,
                    o.duration_ms as f64 / 1000.0,
                ))?;
            }
            return Ok(());
        }
    }
}
