//! The `cangate-server` binary itself: `--print-config`, configuration
//! errors with exit code 2, start-up errors, and a real SIGTERM (with a
//! plain-text log when standard error is not a terminal).

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_cangate-server");

fn write_config(name: &str, text: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("cangate-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn print_config_shows_the_effective_demo_with_overrides() {
    let out = Command::new(BIN)
        .arg("--print-config")
        .env("CANGATE_LOG__FORMAT", "json")
        .env("CANGATE_SERVER", "http://ignored-by-the-server:1")
        .env("CANGATE_SOMETHING_ELSE", "belongs to another tool")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    let cfg = cangate_server::Config::from_toml(&text).expect("printed config parses back");
    assert_eq!(cfg.log.format, cangate_server::config::LogFormat::Json);
    assert_eq!(cfg.buses.len(), 3);
}

#[test]
fn unknown_key_is_named_and_exits_2() {
    let path = write_config(
        "bad.toml",
        "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\nbitrat = 1\n",
    );
    let out = Command::new(BIN)
        .arg("--config")
        .arg(&path)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bitrat"), "{err}");
}

#[test]
fn missing_interface_is_a_clear_start_up_error() {
    let path = write_config(
        "missing.toml",
        "listen = \"127.0.0.1:0\"\n[[bus]]\nname = \"can0\"\nbackend = \"socketcan\"\ninterface = \"nosuchcan7\"\n",
    );
    let out = Command::new(BIN)
        .arg("--config")
        .arg(&path)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("bus \"can0\"") && err.contains("nosuchcan7 does not exist"),
        "{err}"
    );
}

#[test]
fn sigterm_shuts_down_gracefully() {
    let mut child = Command::new(BIN)
        .args(["--listen", "127.0.0.1:0"])
        .env("RUST_LOG", "info")
        .env_remove("NO_COLOR")
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    // Wait for the "listening" log line (bounded).
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let started = Instant::now();
    let mut first = Vec::new();
    loop {
        let line = rx
            .recv_timeout(Duration::from_secs(20))
            .expect("server logs that it listens");
        first.push(line);
        if first.last().is_some_and(|l| l.contains("listening")) {
            break;
        }
        assert!(started.elapsed() < Duration::from_secs(20));
    }
    // Standard error is a pipe, not a terminal: no colour codes.
    let coloured = first.iter().find(|l| l.contains('\x1b'));
    assert!(
        coloured.is_none(),
        "ANSI escapes in a redirected log: {coloured:?}"
    );
    let pid = child.id().to_string();
    assert!(
        Command::new("kill")
            .args(["-TERM", &pid])
            .status()
            .unwrap()
            .success()
    );
    let t0 = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "no exit within 10 s of SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(status.success(), "graceful exit code 0, got {status:?}");
    let rest: Vec<String> = rx.try_iter().collect();
    assert!(rest.iter().any(|l| l.contains("shutting down")), "{rest:?}");
}

#[test]
fn network_listen_without_insecure_is_refused() {
    let out = Command::new(BIN)
        .args(["--listen", "0.0.0.0:0"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("insecure = true"), "{err}");
}
