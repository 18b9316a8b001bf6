//! The real server binary as a child process: found beside the benchmark
//! (the same target profile), started on a free loopback port, ready once
//! it answers a gRPC call, stopped on every path out of the benchmark. Its
//! CPU time and memory are then the server's alone, read from
//! `/proc/<pid>` ([`crate::host`]).

use anyhow::{Context, Result, bail};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

/// The server binary next to this executable.
pub fn default_server_binary() -> Result<PathBuf> {
    let exe = std::env::current_exe().context("locating this executable")?;
    let dir = exe
        .parent()
        .context("this executable has no parent directory")?;
    Ok(dir.join(format!("cangate-server{}", std::env::consts::EXE_SUFFIX)))
}

/// A free TCP port on loopback (free when asked: another process may take
/// it before the server binds it, which the start then reports).
pub fn free_port() -> Result<u16> {
    let l = std::net::TcpListener::bind("127.0.0.1:0").context("finding a free port")?;
    Ok(l.local_addr()?.port())
}

/// A running server binary; killed when dropped, if still running.
pub struct ServerChild {
    child: Child,
    /// The URL its clients connect to.
    pub url: String,
    /// From the start to its first answer.
    pub ready_after: Duration,
    /// How many buses it answered with.
    pub buses: usize,
}

impl ServerChild {
    /// Starts `binary --listen 127.0.0.1:<free port>` with `args` (none:
    /// the embedded demo), its output discarded, and waits until it
    /// answers ListBuses, `timeout` at the most.
    pub async fn start(binary: &Path, args: &[&str], timeout: Duration) -> Result<ServerChild> {
        let addr = format!("127.0.0.1:{}", free_port()?);
        let child = Command::new(binary)
            .args(["--listen", &addr])
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .with_context(|| format!("starting {}", binary.display()))?;
        let mut server = ServerChild {
            child,
            url: format!("http://{addr}"),
            ready_after: Duration::ZERO,
            buses: 0,
        };
        let started = Instant::now();
        server.buses = loop {
            if let Some(status) = server.child.try_wait()? {
                bail!("the server exited before answering: {status}");
            }
            if started.elapsed() > timeout {
                bail!("the server did not answer ListBuses within {timeout:?}");
            }
            if let Ok(mut client) = cangate_client::connect(&server.url).await
                && let Ok(buses) = client.list_buses().await
            {
                break buses.len();
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        };
        server.ready_after = started.elapsed();
        Ok(server)
    }

    /// Its process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// SIGTERM (graceful shutdown), then SIGKILL if it does not exit
    /// within 10 s; its exit status if it exited on its own.
    pub fn terminate(&mut self) -> Result<Option<ExitStatus>> {
        if let Some(status) = self.child.try_wait()? {
            return Ok(Some(status));
        }
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .stderr(Stdio::null())
            .status();
        let deadline = Instant::now() + Duration::from_secs(10);
        while Instant::now() < deadline {
            if let Some(status) = self.child.try_wait()? {
                return Ok(Some(status));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        self.child.kill()?;
        self.child.wait()?;
        Ok(None)
    }
}

impl Drop for ServerChild {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}
