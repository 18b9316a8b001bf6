//! Running a test against a real SocketCAN `vcan0`, wherever `cargo test`
//! happens to run. Include it with
//!
//! ```ignore
//! #[path = "common/vcan.rs"]
//! mod vcan;
//! ```
//!
//! (it is not part of `common/mod.rs`, so the virtual-bus tests do not
//! compile it).
//!
//! Most development hosts and CI containers have no CAN support in their
//! kernel, so [`plan`] picks one of three outcomes:
//!
//! 1. [`Plan::Here`]: the interface exists, run the checks in this process.
//!    This is also what happens inside the VM below.
//! 2. [`Plan::Vm`]: otherwise (and not already inside the VM, where
//!    `CANGATE_VM=1`), [`run_in_vm`] re-runs this very test binary, limited
//!    to the one test, inside a throw-away QEMU guest with vcan0 and vcan1:
//!    the repository's own `scripts/vcan-vm`, or the command prefix in
//!    `CANGATE_VCAN_RUNNER`. It streams the guest's output and requires exit
//!    status 0 and a "1 passed" summary.
//! 3. [`Plan::Unavailable`]: no VM can start here: outside CI, when
//!    `qemu-system-x86_64` is not installed (`scripts/vcan-vm --setup`
//!    installs it; a plain `cargo test` does not install system packages),
//!    or when the runner exits with 125 (the VM itself failed).
//!    [`skip_or_fail`] prints why and passes as skipped - unless `CI=true`,
//!    where `scripts/vcan-vm` installs what it needs and any failure to run
//!    fails the test, so that CI never silently stops exercising real
//!    SocketCAN.

#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The host side of the VM run, including a first-time `apt-get install` of
/// QEMU in CI. The guest itself is bounded by `CANGATE_VM_TIMEOUT` (default
/// below), so this only catches a wedged runner.
pub const VM_RUN_LIMIT: Duration = Duration::from_secs(600);
/// `CANGATE_VM_TIMEOUT` unless the caller's environment sets it.
pub const GUEST_TIMEOUT_SECS: &str = "300";

/// Where the test can run.
pub enum Plan {
    /// The interface is visible to this process.
    Here,
    /// Re-run inside the VM with this command prefix.
    Vm(Vec<String>),
    /// No way to get a real SocketCAN interface here.
    Unavailable(String),
}

/// `CI=true` (or `CI=1`): skipping is not allowed.
pub fn in_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| v.eq_ignore_ascii_case("true") || v == "1")
}

/// This process runs inside the VM (`scripts/vcan-vm` sets `CANGATE_VM=1`).
pub fn inside_vm() -> bool {
    std::env::var("CANGATE_VM").is_ok_and(|v| v == "1")
}

/// The first executable file `name` on PATH.
pub fn find_on_path(name: &str) -> Option<PathBuf> {
    std::env::split_paths(&std::env::var_os("PATH")?)
        .map(|dir| dir.join(name))
        .find(|p| p.is_file())
}

/// The repository's VM runner; this crate is one level below the root.
pub fn repo_runner() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/vcan-vm")
}

/// Decides where a test that needs `iface` runs.
pub fn plan(iface: &str) -> Plan {
    if Path::new("/sys/class/net").join(iface).exists() {
        return Plan::Here;
    }
    if inside_vm() {
        // The VM always creates vcan0; if it is missing, the runner broke and
        // quietly passing would hide that.
        panic!("running inside the VM (CANGATE_VM=1) but {iface} does not exist");
    }
    if let Ok(prefix) = std::env::var("CANGATE_VCAN_RUNNER") {
        let runner: Vec<String> = prefix.split_whitespace().map(str::to_string).collect();
        if runner.is_empty() {
            return Plan::Unavailable("CANGATE_VCAN_RUNNER is set but empty".into());
        }
        // An explicit runner is the user's promise that it works: no probing.
        return Plan::Vm(runner);
    }
    let runner = repo_runner();
    // scripts/vcan-vm installs QEMU itself with apt. That is what CI wants,
    // but a plain `cargo test` on a developer machine should not start
    // installing system packages, so outside CI a missing QEMU means "skip".
    if !in_ci() && find_on_path("qemu-system-x86_64").is_none() {
        return Plan::Unavailable(format!(
            "no {iface} on this host and qemu-system-x86_64 is not installed; \
             run `scripts/vcan-vm --setup` once to install what the VM needs"
        ));
    }
    Plan::Vm(vec![runner.to_string_lossy().into_owned()])
}

/// Passes as skipped with the reason on stderr, or fails under CI.
pub fn skip_or_fail(test_name: &str, reason: &str) {
    if in_ci() {
        panic!("CI=true, so {test_name} must run, but it cannot: {reason}");
    }
    // Straight to the process's stderr, past libtest's output capture: a
    // skip reported as "ok" must still be visible without --nocapture.
    use std::io::Write as _;
    let _ = writeln!(std::io::stderr(), "SKIPPED {test_name}: {reason}");
}

/// Re-runs `test_name` of this test binary under `runner` (`scripts/vcan-vm`),
/// with `extra_env` added to the environment (the runner passes the host
/// environment into the guest). Panics unless it passed there; an exit 125
/// (the VM could not run) goes through [`skip_or_fail`].
pub fn run_in_vm(runner: &[String], test_name: &str, extra_env: &[(&str, &str)]) {
    let exe = std::env::current_exe().expect("the path of this test binary");
    let mut cmd = Command::new(&runner[0]);
    cmd.args(&runner[1..])
        .arg(&exe)
        .args(["--exact", test_name, "--nocapture", "--test-threads=1"])
        .envs(extra_env.iter().copied())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    // The guest gets its own limit, so a wedged guest ends with the runner's
    // exit status 124 and a message rather than our watchdog's kill.
    if std::env::var_os("CANGATE_VM_TIMEOUT").is_none() {
        cmd.env("CANGATE_VM_TIMEOUT", GUEST_TIMEOUT_SECS);
    }
    // Outside CI the runner may use what is installed but must not install
    // packages (it exits 125 and names `scripts/vcan-vm --setup` instead).
    if !in_ci() && std::env::var_os("CANGATE_VM_INSTALL").is_none() {
        cmd.env("CANGATE_VM_INSTALL", "0");
    }
    eprintln!(
        "no vcan here; re-running {test_name} in {}",
        runner.join(" ")
    );
    let started = Instant::now();
    let mut child = cmd
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {}: {e}", runner[0]));

    // Forward through println!/eprintln! rather than inheriting the file
    // descriptors, so libtest's output capture applies to the guest's output
    // just like to ours (shown with --nocapture or when the test fails).
    let out = child.stdout.take().expect("piped stdout");
    let err = child.stderr.take().expect("piped stderr");
    let stdout_thread = std::thread::spawn(move || {
        let mut summary_ok = false;
        for line in BufReader::new(out).lines().map_while(Result::ok) {
            summary_ok |= line.contains("test result: ok. 1 passed");
            println!("[vm] {line}");
        }
        summary_ok
    });
    let stderr_thread = std::thread::spawn(move || {
        // The runner's first own message says why it could not run a VM;
        // it goes into the skip reason, which stays visible.
        let mut first_note = None;
        for line in BufReader::new(err).lines().map_while(Result::ok) {
            if first_note.is_none() && line.starts_with("vcan-vm: ") {
                first_note = Some(line.clone());
            }
            eprintln!("[vm] {line}");
        }
        first_note
    });

    let status = loop {
        if let Some(status) = child.try_wait().expect("wait for the VM runner") {
            break status;
        }
        if started.elapsed() > VM_RUN_LIMIT {
            // SIGTERM first: scripts/vcan-vm traps it and takes its QEMU
            // down with it; a SIGKILL would orphan the guest.
            let _ = Command::new("kill")
                .args(["-TERM", &child.id().to_string()])
                .status();
            let grace = Instant::now() + Duration::from_secs(5);
            while Instant::now() < grace && matches!(child.try_wait(), Ok(None)) {
                std::thread::sleep(Duration::from_millis(50));
            }
            let _ = child.kill();
            let _ = child.wait();
            panic!("the VM run did not finish within {VM_RUN_LIMIT:?}; killed it");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let summary_ok = stdout_thread.join().expect("stdout forwarder");
    let runner_note = stderr_thread.join().expect("stderr forwarder");
    eprintln!(
        "VM run finished in {:.1} s with {status}",
        started.elapsed().as_secs_f64()
    );

    match status.code() {
        // scripts/vcan-vm: "the VM failed" (QEMU missing and not
        // installable, no boot, ...): an environment problem, not a gateway
        // bug.
        Some(125) => skip_or_fail(
            test_name,
            &format!(
                "{} could not run a VM (exit 125): {}",
                runner[0],
                runner_note.as_deref().unwrap_or("see its output above")
            ),
        ),
        Some(0) => assert!(
            summary_ok,
            "the VM run exited 0 but did not report `1 passed`: \
             the test name {test_name:?} probably does not match the function"
        ),
        Some(124) => panic!("the guest hit CANGATE_VM_TIMEOUT (exit 124)"),
        _ => panic!("{test_name} failed inside the VM ({status})"),
    }
}
