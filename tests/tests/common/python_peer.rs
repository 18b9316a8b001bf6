//! Python programs as independent peers of the gateway (python-can,
//! python `canopen`, the `cangate` package): finding an interpreter that
//! has the packages, and running a script from `tests/python/` with its
//! output lines on a channel. Include it, with `common/vcan.rs` beside it
//! (its skip rules), as
//!
//! ```ignore
//! #[path = "common/vcan.rs"]
//! mod vcan;
//! #[path = "common/python_peer.rs"]
//! mod python_peer;
//! ```

#![allow(dead_code)]

use anyhow::{Context, Result, bail, ensure};
use std::ffi::OsStr;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::time::{Duration, Instant};
use tokio::sync::mpsc;

/// The interpreter to use (the venv `scripts/test` builds in
/// `target/python`); `python3` when unset.
pub const PYTHON_ENV: &str = "CANGATE_PYTHON";

/// A script of `tests/python/`.
pub fn script(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("python")
        .join(name)
}

/// The interpreter in [`PYTHON_ENV`] (else `python3`) if it imports every
/// one of `modules`, resolved to its real executable; else why not. Inside
/// the VM the host's choice is taken as it is (the host checked it, and an
/// import probe costs seconds under emulation).
pub fn find_python(modules: &[&str]) -> Result<PathBuf, String> {
    let given = std::env::var_os(PYTHON_ENV).map(PathBuf::from);
    if crate::vcan::inside_vm()
        && let Some(p) = given.clone()
    {
        return Ok(p);
    }
    let python = given.unwrap_or_else(|| PathBuf::from("python3"));
    let probe = "import importlib, sys\n\
                 mods = [importlib.import_module(m) for m in sys.argv[1:]]\n\
                 print(sys.executable)\n\
                 print(' '.join(f\"{m.__name__} {getattr(m, '__version__', '?')}\" for m in mods))";
    let out = Command::new(&python)
        .arg("-c")
        .arg(probe)
        .args(modules)
        .stdin(Stdio::null())
        .output()
        .map_err(|e| format!("cannot run {}: {e}", python.display()))?;
    let stdout = String::from_utf8_lossy(&out.stdout);
    let mut lines = stdout.lines();
    match (out.status.success(), lines.next()) {
        (true, Some(exe)) if !exe.is_empty() => {
            eprintln!("python: {exe} with {}", lines.next().unwrap_or("?"));
            Ok(PathBuf::from(exe))
        }
        _ => Err(format!(
            "{} cannot import {} ({}); install them with `python3 -m pip install -r \
             tests/python/requirements.txt ./python` (scripts/test does, into target/python) \
             and set {PYTHON_ENV}",
            python.display(),
            modules.join(", "),
            String::from_utf8_lossy(&out.stderr)
                .lines()
                .last()
                .unwrap_or("no error output")
        )),
    }
}

/// [`find_python`], or `None` after reporting the skip (a failure under
/// `CI=true`).
pub fn python_or_skip(test: &str, modules: &[&str]) -> Option<PathBuf> {
    match find_python(modules) {
        Ok(p) => Some(p),
        Err(reason) => {
            crate::vcan::skip_or_fail(test, &reason);
            None
        }
    }
}

/// A running python script: its stdout lines on a channel (and echoed,
/// labelled with the script's name), its stderr echoed; killed on drop if
/// it is still running.
pub struct Peer {
    name: String,
    child: Child,
    stdin: Option<ChildStdin>,
    lines: mpsc::UnboundedReceiver<String>,
}

impl Peer {
    /// Starts `python -u SCRIPT ARGS…` (`script` a path, `args` its
    /// arguments) with `env` added.
    pub fn spawn<A: AsRef<OsStr>>(
        python: &Path,
        script: &Path,
        args: &[A],
        env: &[(&str, String)],
    ) -> Result<Peer> {
        let name = script
            .file_stem()
            .map_or_else(|| "python".into(), |s| s.to_string_lossy().into_owned());
        let mut child = Command::new(python)
            .arg("-u")
            .arg(script)
            .args(args)
            .env("PYTHONDONTWRITEBYTECODE", "1")
            .envs(env.iter().map(|(k, v)| (k, v)))
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .with_context(|| format!("starting {} {}", python.display(), script.display()))?;
        let out = child.stdout.take().expect("piped stdout");
        let err = child.stderr.take().expect("piped stderr");
        let (tx, lines) = mpsc::unbounded_channel();
        let label = name.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                if line.len() > 200 {
                    eprintln!("  [{label}] {}... ({} chars)", &line[..120], line.len());
                } else {
                    eprintln!("  [{label}] {line}");
                }
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        let label = name.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(err).lines().map_while(Result::ok) {
                eprintln!("  [{label} stderr] {line}");
            }
        });
        Ok(Peer {
            name,
            stdin: child.stdin.take(),
            child,
            lines,
        })
    }

    /// The next stdout line matching `pred` (others skipped: they were
    /// echoed); fails early when the script exits.
    pub async fn expect(
        &mut self,
        what: &str,
        limit: Duration,
        pred: impl Fn(&str) -> bool,
    ) -> Result<String> {
        let deadline = Instant::now() + limit;
        loop {
            match tokio::time::timeout_at(deadline.into(), self.lines.recv()).await {
                Err(_) => bail!("{} did not print {what} within {limit:?}", self.name),
                Ok(None) => {
                    let status = self.child.wait().ok();
                    bail!(
                        "{} exited ({status:?}) before printing {what}; see its stderr above",
                        self.name
                    )
                }
                Ok(Some(line)) if pred(&line) => return Ok(line),
                Ok(Some(_)) => {}
            }
        }
    }

    /// The next stdout line, whatever it is.
    pub async fn next_line(&mut self, limit: Duration) -> Result<String> {
        self.expect("a line", limit, |_| true).await
    }

    /// Waits for exactly `line`.
    pub async fn expect_line(&mut self, line: &str, limit: Duration) -> Result<()> {
        self.expect(line, limit, |l| l == line).await.map(|_| ())
    }

    /// The lines before `end` (which must come, each within `limit`).
    pub async fn lines_until(&mut self, end: &str, limit: Duration) -> Result<Vec<String>> {
        let mut out = Vec::new();
        loop {
            let line = self.next_line(limit).await?;
            if line == end {
                return Ok(out);
            }
            out.push(line);
        }
    }

    /// `tests/python/local_node.py` stored exactly `data` at `index:sub`
    /// (its `WRITE IIII:SS hex` line).
    pub async fn expect_stored(
        &mut self,
        index: u16,
        sub: u8,
        data: &[u8],
        limit: Duration,
    ) -> Result<()> {
        let prefix = format!("WRITE {index:04X}:{sub:02X} ");
        let line = self
            .expect(&prefix, limit, |l| l.starts_with(&prefix))
            .await?;
        let hex: String = data.iter().map(|b| format!("{b:02x}")).collect();
        ensure!(
            line[prefix.len()..] == hex,
            "the device stored {} at {index:04X}:{sub:02X}, expected {hex}",
            &line[prefix.len()..]
        );
        Ok(())
    }

    /// Writes a line to the script's stdin.
    pub fn say(&mut self, line: &str) -> Result<()> {
        let stdin = self.stdin.as_mut().context("stdin already closed")?;
        writeln!(stdin, "{line}").context("writing to the python script")?;
        stdin.flush().context("writing to the python script")
    }

    /// Closes stdin and requires a clean exit within `limit`.
    pub async fn finish(&mut self, limit: Duration) -> Result<()> {
        self.stdin.take();
        let deadline = Instant::now() + limit;
        loop {
            if let Some(status) = self.child.try_wait()? {
                ensure!(status.success(), "{} exited with {status}", self.name);
                return Ok(());
            }
            ensure!(
                Instant::now() < deadline,
                "{} did not exit within {limit:?}",
                self.name
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }
}

impl Drop for Peer {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}
