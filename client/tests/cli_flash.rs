//! `cangate flash` (program download, CiA 302-3) as a shell user runs it:
//! the real binary against a real gateway in this process with simulated
//! CANopen nodes; the outcome line, plain progress lines when standard
//! error is not a terminal, --json lines, and failures (a flash error armed
//! with `cangate sim program-faults`, an SDO abort, an unknown node) with
//! one clean error line and their exit statuses.

mod common;

use common::{assert_status, run, stderr, stdout};
use std::net::SocketAddr;
use std::process::Output;
use std::sync::OnceLock;

const CONFIG: &str = r#"
listen = "127.0.0.1:0"

[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"

[[canopen.node]]
id = 5
eds = "builtin:io"
simulate = true
heartbeat_timeout_ms = 2000

[[canopen.node]]
id = 6
eds = "builtin:io"
simulate = true
heartbeat_timeout_ms = 2000

[[canopen.node]]
id = 7
eds = "builtin:io"
simulate = true
heartbeat_timeout_ms = 2000
"#;

fn gateway() -> SocketAddr {
    static ADDR: OnceLock<SocketAddr> = OnceLock::new();
    *ADDR.get_or_init(|| common::start_gateway(CONFIG))
}

fn cangate(args: &[&str]) -> Output {
    let addr = gateway().to_string();
    run(&["--server", &addr], args)
}

/// A firmware file of `len` bytes in the target directory.
fn firmware(name: &str, len: usize) -> (std::path::PathBuf, Vec<u8>) {
    let data: Vec<u8> = (0..len).map(|i| (i * 31 % 253) as u8).collect();
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"));
    let path = dir.join(name);
    std::fs::write(&path, &data).unwrap();
    (path, data)
}

/// CRC-32 (IEEE): what the simulated node reports as the identification.
fn crc32(data: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in data {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xEDB8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

#[test]
fn flash_downloads_and_prints_the_outcome() {
    let (path, data) = firmware("cli_flash_ok.bin", 50_000);
    let id = format!("0x{:08X}", crc32(&data));
    let o = cangate(&[
        "flash",
        "can0",
        "5",
        path.to_str().unwrap(),
        "--expect-id",
        &id,
    ]);
    assert_status(&o, 0);
    let out = stdout(&o);
    assert!(
        out.starts_with(&format!(
            "node 5 program 1: 0x00010000 -> {id}, 50000 bytes in "
        )),
        "{out}"
    );
    assert!(out.contains("KiB/s"), "{out}");
    // Not a terminal: plain lines, one per step, the data in tenths.
    let err = stderr(&o);
    for step in [
        "read-identification-before",
        "stop-program",
        "download-data",
        "wait-flash",
        "start-program",
        "wait-boot-up",
        "read-identification-after",
    ] {
        assert!(
            err.contains(&format!("{step}: ")),
            "{step} missing in {err}"
        );
    }
    assert!(!err.contains('\r'), "no bar redraws off a terminal: {err}");
    assert!(
        err.contains("download-data: 50000/50000 bytes (100%)")
            || err.contains("wait-flash: 50000/50000 bytes (100%)"),
        "{err}"
    );

    // --json: one progress message per line, the last with the outcome.
    let o = cangate(&[
        "--json",
        "flash",
        "can0",
        "6",
        path.to_str().unwrap(),
        "--clear",
    ]);
    assert_status(&o, 0);
    let out = stdout(&o);
    let last = out.lines().last().unwrap();
    assert!(last.contains("\"outcome\""), "{out}");
    assert!(
        last.contains(&format!("\"newIdentification\":{}", crc32(&data))),
        "{last}"
    );
    assert!(out.contains("PROGRAM_STEP_CLEAR_PROGRAM"), "{out}");
}

#[test]
fn flash_failures_exit_with_their_status_and_one_line() {
    let (path, _) = firmware("cli_flash_fail.bin", 20_000);
    let file = path.to_str().unwrap();
    // A flash error armed in the simulated node: exit 1, the CiA name.
    let o = cangate(&["sim", "program-faults", "can0", "7", "--flash-error", "5"]);
    assert_status(&o, 0);
    assert!(
        stdout(&o).contains("next download faults: flash error 5"),
        "{}",
        stdout(&o)
    );
    let o = cangate(&["flash", "can0", "7", file]);
    assert_status(&o, 1);
    let err = stderr(&o);
    let last = err.lines().last().unwrap();
    assert!(last.starts_with("cangate: flash node 7 on can0: "), "{err}");
    assert!(last.contains("flash write error"), "{err}");
    // An abort at byte 7000: exit 6 with the code and its name.
    let o = cangate(&["sim", "program-faults", "can0", "7", "--abort-at", "7000"]);
    assert_status(&o, 0);
    let o = cangate(&["flash", "can0", "7", file]);
    assert_status(&o, 6);
    let err = stderr(&o);
    let last = err.lines().last().unwrap();
    assert!(
        last.starts_with("cangate: flash node 7 on can0, step download-data: node 7, object 0x1F50:01: SDO abort 0x06060000"),
        "{err}"
    );
    assert_eq!(err.matches("cangate: ").count(), 1, "{err}");
    assert!(err.contains("hardware error"), "{err}");
    // An unknown node: exit 3; a missing file: exit 1 before connecting.
    let o = cangate(&["flash", "can0", "99", file]);
    assert_status(&o, 3);
    let o = cangate(&["flash", "can0", "7", "/nonexistent/fw.bin"]);
    assert_status(&o, 1);
    assert!(
        stderr(&o).contains("reading /nonexistent/fw.bin"),
        "{}",
        stderr(&o)
    );
    // Afterwards a good download.
    let o = cangate(&["flash", "can0", "7", file]);
    assert_status(&o, 0);
}
