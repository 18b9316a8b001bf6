//! What the `cangate` binary's tests share: a real gateway started in this
//! process on its own runtime thread, and running the binary against it.

#![allow(dead_code)]

use std::net::SocketAddr;
use std::process::{Command, Output};
use std::time::Duration;

/// Starts a gateway with `config` (TOML) on a runtime thread of its own,
/// running until the test process ends; returns its gRPC address.
pub fn start_gateway(config: &'static str) -> SocketAddr {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .expect("runtime");
        rt.block_on(async move {
            let config = cangate_server::Config::from_toml(config).expect("config");
            let server = cangate_server::start(&config).await.expect("server starts");
            tx.send(server.addr).expect("test waits");
            std::future::pending::<()>().await;
        });
    });
    rx.recv_timeout(Duration::from_secs(30))
        .expect("the gateway starts")
}

/// The `cangate` binary, without any `CANGATE_*` of the environment.
pub fn command() -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_cangate"));
    for (k, _) in std::env::vars() {
        if k.starts_with("CANGATE_") {
            cmd.env_remove(k);
        }
    }
    cmd
}

/// Runs `cangate FIRST… ARGS…` to its end.
pub fn run(first: &[&str], args: &[&str]) -> Output {
    command()
        .args(first)
        .args(args)
        .output()
        .expect("cangate runs")
}

pub fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Asserts the exit status, showing the output when it differs.
#[track_caller]
pub fn assert_status(o: &Output, code: i32) {
    assert_eq!(
        o.status.code(),
        Some(code),
        "stdout: {}\nstderr: {}",
        stdout(o),
        stderr(o)
    );
}
