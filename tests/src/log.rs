//! The log of this test process, captured: a test that checks what the
//! gateway logs (the audit lines, the decoded traffic) installs the
//! process's subscriber once with [`capture_log`] and reads the text.

use std::io::Write;
use std::sync::{Arc, Mutex};

/// Everything the process logged since [`capture_log`].
#[derive(Clone, Default)]
pub struct CapturedLog(Arc<Mutex<Vec<u8>>>);

impl CapturedLog {
    /// The log so far, as text.
    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.0.lock().unwrap_or_else(|p| p.into_inner())).to_string()
    }
}

impl Write for CapturedLog {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// Installs the process's log subscriber with `filter` (an `EnvFilter`
/// directive such as `cangate::audit=info`), writing plain text into the
/// returned log. Once per test process: a second call panics.
pub fn capture_log(filter: &str) -> CapturedLog {
    let captured = CapturedLog::default();
    let writer = captured.clone();
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::new(filter))
        .with_writer(move || writer.clone())
        .with_ansi(false)
        .init();
    captured
}
