//! Helpers the CLI's command modules share: gRPC results as user-facing
//! errors, Ctrl-C, optional sleeps, number parsing and timestamps.

use anyhow::Result;
use std::time::Duration;

/// A gRPC status as the user should see it: the server's message and
/// code, and the SDO abort when the server attached one the message does
/// not already name.
pub fn status_error(s: tonic::Status) -> anyhow::Error {
    let abort = s
        .metadata()
        .get("cangate-sdo-abort")
        .and_then(|v| v.to_str().ok())
        .map(str::to_string);
    let shown = s.message().to_string();
    let e = anyhow::Error::from(cangate_client::Error::from(s));
    match abort {
        Some(a) if !shown.contains(&a) => e.context(format!("SDO abort {a}")),
        _ => e,
    }
}

/// A gRPC call's result as the inner message or a user-facing error.
pub trait Rpc<T> {
    /// See the trait.
    fn rpc(self) -> Result<T>;
}

impl<T> Rpc<T> for Result<tonic::Response<T>, tonic::Status> {
    fn rpc(self) -> Result<T> {
        self.map(tonic::Response::into_inner).map_err(status_error)
    }
}

/// Ctrl-C; never resolves if the handler cannot be installed.
pub async fn ctrl_c() {
    if tokio::signal::ctrl_c().await.is_err() {
        std::future::pending::<()>().await;
    }
}

/// Sleeps `secs`, or forever when `None`.
pub async fn sleep_opt(secs: Option<f64>) {
    match secs {
        Some(s) => tokio::time::sleep(Duration::from_secs_f64(s)).await,
        None => std::future::pending().await,
    }
}

/// A clap value parser: a finite number above 0.
pub fn positive(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("{text:?} is not a positive number")),
    }
}

/// Now, µs since the Unix epoch.
pub fn now_us() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64)
}

/// `(1712345678.123456)`, like the other streams of the CLI; the local
/// clock when the gateway gave no time.
pub fn time_text(us: u64) -> String {
    let us = if us == 0 { now_us() } else { us };
    format!("({}.{:06})", us / 1_000_000, us % 1_000_000)
}
