//! The real `cangate` binary against a real gateway (in this process, on a
//! virtual bus with a simulated CiA 402 drive as axis X): the grammar
//! (negative values without `--`), connecting (host:port, a silent
//! listener within the connect timeout), --json of typed SDO values, SDO
//! aborts and unknown names with their messages and exit statuses, a lease
//! acquired, used and released from the shell, completions.

mod common;

use common::{assert_status, command, run, stderr, stdout};
use std::net::SocketAddr;
use std::process::Output;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// One bus, one simulated drive (node 1) as axis X; generous heartbeat
/// timeout for loaded test machines.
const CONFIG: &str = r#"
listen = "127.0.0.1:0"

[[bus]]
name = "can0"
backend = "virtual"
fd = true
bitrate = 1000000

[[canopen]]
bus = "can0"
sdo_timeout_ms = 500
sync_period_us = 10000

[[canopen.node]]
id = 1
name = "X axis drive"
eds = "builtin:drive"
heartbeat_timeout_ms = 2000
simulate = true

[[axis]]
name = "X"
bus = "can0"
node = 1
unit = "mm"
counts_per_unit = 1000.0
position_mode = "cyclic"
min_position = -200.0
max_position = 200.0
max_velocity = 100.0
max_acceleration = 1000.0
homing_method = 35
stop_on_loss = "halt"
jog_deadman_ms = 500
"#;

/// The gateway all tests share: started once, running until the test
/// process ends.
fn gateway() -> SocketAddr {
    static ADDR: OnceLock<SocketAddr> = OnceLock::new();
    *ADDR.get_or_init(|| common::start_gateway(CONFIG))
}

/// Runs `cangate --server HOST:PORT ARGS…` (no `CANGATE_*` from the
/// environment).
fn cangate(args: &[&str]) -> Output {
    let addr = gateway().to_string();
    run(&["--server", &addr], args)
}

/// Every error is one line `cangate: …`, no raw tonic text, no repeats.
#[track_caller]
fn assert_one_clean_error(o: &Output) {
    let err = stderr(o);
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(lines[0].starts_with("cangate: "), "{err}");
    for raw in ["status:", "Status {", "code:", "details:", "metadata:"] {
        assert!(!err.contains(raw), "raw tonic text in {err}");
    }
    assert!(!err.contains("transport error: transport error"), "{err}");
}

#[test]
fn negative_values_need_no_double_dash_and_json_keeps_the_type() {
    // Home offset: an INTEGER32 nobody else in these tests touches.
    let o = cangate(&["sdo", "write", "can0", "1", "0x607C", "i32", "-5000"]);
    assert_status(&o, 0);
    let o = cangate(&["sdo", "read", "can0", "1", "0x607C"]);
    assert_status(&o, 0);
    assert_eq!(stdout(&o).trim(), "-5000");
    let o = cangate(&[
        "sdo", "read", "can0", "1", "0x607C", "--type", "i32", "--json",
    ]);
    assert_status(&o, 0);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON");
    assert_eq!(v["value"]["type"], "DATA_TYPE_INTEGER32", "{v}");
    // Canonical proto3 JSON: 64-bit integers are strings.
    assert_eq!(v["value"]["intValue"], "-5000", "{v}");
    // The bytes as they are, base64: -5000 little-endian is 78 EC FF FF.
    assert_eq!(v["raw"], "eOz//w==", "{v}");
}

#[test]
fn unsigned_and_string_values_keep_their_type_too() {
    let o = cangate(&[
        "sdo", "read", "can0", "1", "0x1008", "--type", "vs", "--json",
    ]);
    assert_status(&o, 0);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON");
    assert_eq!(v["value"]["type"], "DATA_TYPE_VISIBLE_STRING", "{v}");
    assert_eq!(v["value"]["stringValue"], "cangate sim drive", "{v}");
    let o = cangate(&["sdo", "read", "can0", "1", "0x1000", "--type", "u32"]);
    assert_status(&o, 0);
    assert_eq!(stdout(&o).trim(), "131474 (0x20192)");
}

#[test]
fn raw_reads_show_the_bytes_not_the_eds_type() {
    // 0x1000 is UNSIGNED32 0x00020192 in the EDS; raw is its bytes.
    let o = cangate(&["sdo", "read", "can0", "1", "0x1000", "--type", "raw"]);
    assert_status(&o, 0);
    assert_eq!(stdout(&o).trim(), "92 01 02 00");
    let o = cangate(&[
        "sdo", "read", "can0", "1", "0x1000", "--type", "raw", "--json",
    ]);
    assert_status(&o, 0);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON");
    assert!(v.get("value").is_none(), "{v}");
    assert_eq!(v["raw"], "kgECAA==", "{v}");
    // Without a type the EDS's decodes it.
    let o = cangate(&["sdo", "read", "can0", "1", "0x1000"]);
    assert_eq!(stdout(&o).trim(), "131474 (0x20192)");
}

#[test]
fn objects_by_name_from_the_eds() {
    // A read by ParameterName is the read by address.
    let o = cangate(&["sdo", "read", "can0", "1", "Manufacturer device name"]);
    assert_status(&o, 0);
    assert_eq!(stdout(&o).trim(), "\"cangate sim drive\"");
    let o = cangate(&["sdo", "read", "can0", "1", "identity object.vendor-id"]);
    assert_status(&o, 0);
    let by_address = cangate(&["sdo", "read", "can0", "1", "0x1018:01"]);
    assert_eq!(stdout(&o), stdout(&by_address));

    // A write by name needs no type: the gateway takes the EDS's
    // (UNSIGNED16); then back to the EDS default.
    let o = cangate(&[
        "sdo",
        "write",
        "can0",
        "1",
        "Producer heartbeat time",
        "100",
    ]);
    assert_status(&o, 0);
    let o = cangate(&["sdo", "read", "can0", "1", "0x1017", "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON");
    assert_eq!(v["value"]["type"], "DATA_TYPE_UNSIGNED16", "{v}");
    assert_eq!(v["value"]["uintValue"], "100", "{v}");
    let o = cangate(&[
        "sdo",
        "write",
        "can0",
        "1",
        "Producer heartbeat time",
        "1000",
    ]);
    assert_status(&o, 0);

    // An unknown name: NOT_FOUND, exit 3, one line naming it.
    let o = cangate(&["sdo", "read", "can0", "1", "Flux capacitor"]);
    assert_status(&o, 3);
    assert_one_clean_error(&o);
    assert!(stderr(&o).contains("Flux capacitor"), "{}", stderr(&o));
    // A value that does not fit the EDS type: INVALID_ARGUMENT.
    let o = cangate(&["sdo", "write", "can0", "1", "Producer heartbeat time", "-1"]);
    assert_status(&o, 1);
    assert_one_clean_error(&o);
}

#[test]
fn node_objects_lists_the_dictionary() {
    let o = cangate(&["node", "objects", "can0", "1"]);
    assert_status(&o, 0);
    let out = stdout(&o);
    let line = |start: &str| {
        out.lines()
            .find(|l| l.starts_with(start))
            .unwrap_or_else(|| panic!("{start} in\n{out}"))
            .to_string()
    };
    let name = line("0x1008:00 Manufacturer device name");
    assert!(
        name.contains("visible-string") && name.contains("const"),
        "{name}"
    );
    let cw = line("0x6040:00 Controlword");
    assert!(
        cw.contains("unsigned16") && cw.contains("rww") && cw.contains("yes"),
        "{cw}"
    );
    assert!(line("0x1018:04").contains("Identity object.Serial number"));
    // --filter and --json.
    let o = cangate(&[
        "--json", "node", "objects", "can0", "1", "--filter", "identity",
    ]);
    assert_status(&o, 0);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON");
    let objects = v["objects"].as_array().expect("objects");
    assert_eq!(objects.len(), 5, "{v}");
    assert_eq!(objects[1]["name"], "Identity object.Vendor-ID", "{v}");
    assert_eq!(objects[1]["access"], "OBJECT_ACCESS_RO", "{v}");
}

#[test]
fn host_port_and_urls_both_work() {
    let addr = gateway().to_string();
    for server in [addr.clone(), format!("http://{addr}")] {
        let o = run(&["--server", &server], &["bus", "list", "--json"]);
        assert_status(&o, 0);
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON");
        assert_eq!(v["buses"][0]["name"], "can0", "{v}");
        assert_eq!(v["buses"][0]["status"]["state"], "BUS_STATE_UP", "{v}");
    }
    // The environment variable is the same flag.
    let mut cmd = command();
    let o = cmd
        .env("CANGATE_SERVER", &addr)
        .args(["node", "list"])
        .output()
        .unwrap();
    assert_status(&o, 0);
    assert!(stdout(&o).contains("X axis drive"), "{}", stdout(&o));
}

#[test]
fn a_silent_listener_times_out_within_the_connect_bound() {
    // Accepts connections (the kernel does) and never answers.
    let silent = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = silent.local_addr().unwrap().to_string();
    let started = Instant::now();
    let o = run(
        &["--server", &addr, "--connect-timeout-ms", "300"],
        &["bus", "list"],
    );
    let took = started.elapsed();
    assert_status(&o, 4);
    assert!(took < Duration::from_secs(5), "took {took:?}");
    assert_one_clean_error(&o);
    let err = stderr(&o);
    assert!(
        err.contains(&format!("connecting to {addr}")) && err.contains("within 300 ms"),
        "{err}"
    );
    drop(silent);
}

#[test]
fn a_refused_connection_says_so_once() {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let o = run(
        &["--server", &format!("127.0.0.1:{port}")],
        &["bus", "list"],
    );
    assert_status(&o, 5);
    assert_one_clean_error(&o);
    assert!(
        stderr(&o).contains("cannot connect to http://127.0.0.1:"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn an_sdo_abort_shows_code_and_name_and_exits_6() {
    let o = cangate(&["sdo", "read", "can0", "1", "0x5555"]);
    assert_status(&o, 6);
    assert_one_clean_error(&o);
    let err = stderr(&o);
    assert!(
        err.contains("SDO abort 0x06020000 object does not exist in the object dictionary"),
        "{err}"
    );
    assert!(
        err.starts_with("cangate: sdo read on can0: node 1, object 0x5555:00"),
        "{err}"
    );
    assert_eq!(err.matches("0x06020000").count(), 1, "{err}");
}

#[test]
fn unknown_names_are_not_found_with_exit_3() {
    for args in [
        &["axis", "show", "Q"][..],
        &["axis", "move", "Q", "1"],
        &["bus", "show", "nope"],
    ] {
        let o = cangate(args);
        assert_status(&o, 3);
        assert_one_clean_error(&o);
        assert!(stderr(&o).contains("not found"), "{args:?}: {}", stderr(&o));
    }
}

#[test]
fn usage_errors_exit_2_before_connecting() {
    for args in [
        &["axis", "move", "X"][..],
        &["sdo", "read", "can0", "0", "0x1000"],
        &["sdo", "write", "can0", "1", "0x607C", "u8", "300"],
        // A type without its value.
        &["sdo", "write", "can0", "1", "0x607C", "u8"],
        &["nmt", "can0", "jump", "1"],
    ] {
        // A server nobody listens on: a usage error never gets that far.
        let o = run(&["--server", "127.0.0.1:1"], args);
        assert_status(&o, 2);
    }
}

#[test]
fn a_lease_from_the_shell_drives_an_axis_and_is_released() {
    let o = cangate(&["lease", "acquire", "X", "--ttl-ms", "20000"]);
    assert_status(&o, 0);
    let token = stdout(&o).trim().to_string();
    assert!(token.len() >= 16 && !token.contains(' '), "{token:?}");

    // Someone without the lease is refused while it is held.
    let o = cangate(&["axis", "enable", "X"]);
    assert_status(&o, 1);
    assert!(
        stderr(&o).contains("AXIS_CONTROLLED_BY_OTHER"),
        "{}",
        stderr(&o)
    );

    // With it: a drive that faulted on a loaded machine is reset first.
    let _ = cangate(&["axis", "reset-fault", "X", "--wait", "--lease", &token]);
    let o = cangate(&["axis", "enable", "X", "--wait", "--lease", &token]);
    assert_status(&o, 0);
    let o = cangate(&["axis", "move", "X", "-1.5", "--wait", "--lease", &token]);
    assert_status(&o, 0);
    assert!(stdout(&o).contains("X: move completed"), "{}", stdout(&o));
    let o = cangate(&[
        "axis", "move", "X", "0.5", "--rel", "--wait", "--json", "--lease", &token,
    ]);
    assert_status(&o, 0);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON");
    assert_eq!(v["outcome"], "OUTCOME_COMPLETED", "{v}");
    assert_eq!(v["status"]["axis"], "X", "{v}");

    // The lease was kept by the commands: renew and release it.
    let o = cangate(&["lease", "renew", &token, "--json"]);
    assert_status(&o, 0);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON");
    assert_eq!(v["axes"][0], "X", "{v}");
    let o = cangate(&["lease", "release", &token]);
    assert_status(&o, 0);
    assert_eq!(stdout(&o).trim(), "released: X");
    let o = cangate(&["lease", "release", &token]);
    assert_status(&o, 1);
    assert_one_clean_error(&o);

    // Free again: a command takes (and gives back) its own lease.
    let o = cangate(&["axis", "move", "X", "0", "--wait"]);
    assert_status(&o, 0);
    let o = cangate(&["axis", "list", "X", "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON");
    assert_eq!(v["axes"][0]["status"]["controlledBy"], "", "{v}");
}

#[test]
fn streams_print_one_json_object_per_line() {
    let o = cangate(&["dump", "can0", "-n", "3", "--json"]);
    assert_status(&o, 0);
    let out = stdout(&o);
    let frames = out
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).expect("one object per line"))
        .filter(|v| v.get("frame").is_some())
        .count();
    assert_eq!(frames, 3, "{out}");
}

#[test]
fn whoami_says_who_the_client_is() {
    let o = cangate(&["whoami"]);
    assert_status(&o, 0);
    assert_eq!(
        stdout(&o).trim(),
        "anonymous: engineer (none, the gateway has authentication off)"
    );
}

#[test]
fn completions_are_generated() {
    for shell in ["bash", "zsh", "fish"] {
        let o = run(&[], &["completions", shell]);
        assert_status(&o, 0);
        let out = stdout(&o);
        assert!(
            out.contains("cangate") && out.contains("move-all"),
            "{shell}: {out}"
        );
    }
}

#[test]
fn a_reader_that_stops_reading_ends_a_stream_quietly() {
    use std::io::{BufRead, BufReader};
    let addr = gateway().to_string();
    let mut child = command()
        .args(["--server", &addr, "dump", "can0", "--json"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("cangate runs");
    let mut lines = BufReader::new(child.stdout.take().expect("piped"));
    let mut first = String::new();
    lines.read_line(&mut first).expect("a line");
    assert!(first.starts_with('{'), "{first}");
    // `| head -1`: the reader goes away; the next write fails.
    drop(lines);
    let started = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().expect("wait") {
            break s;
        }
        assert!(started.elapsed() < Duration::from_secs(10), "still running");
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut err = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
    assert_eq!(status.code(), Some(0), "{err}");
    assert!(err.is_empty(), "{err}");
}

#[test]
fn completions_to_a_reader_that_closes_early_end_quietly() {
    // `cangate completions bash | head -1`, the reader gone before the
    // script is written: the write fails (broken pipe) and the command ends
    // with status 0 and nothing on standard error.
    let mut child = command()
        .args(["completions", "bash"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("cangate runs");
    drop(child.stdout.take());
    let out = child.wait_with_output().expect("cangate ends");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{err}");
    assert!(err.is_empty(), "{err}");
}

#[test]
fn sdo_write_options_may_follow_the_type() {
    // The README's order: TYPE, then --file and --block.
    let dir = std::env::temp_dir().join(format!("cangate-cli-sdo-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("name.bin");
    std::fs::write(&file, b"cli order").unwrap();
    // 0x2100 of the built-in drive: the firmware image, a DOMAIN.
    let o = cangate(&[
        "sdo",
        "write",
        "can0",
        "1",
        "0x2100",
        "domain",
        "--file",
        file.to_str().unwrap(),
        "--block",
    ]);
    assert_status(&o, 0);
    let back = dir.join("back.bin");
    let o = cangate(&[
        "sdo",
        "read",
        "can0",
        "1",
        "0x2100",
        "--output",
        back.to_str().unwrap(),
    ]);
    assert_status(&o, 0);
    assert_eq!(std::fs::read(&back).unwrap(), b"cli order");
    let _ = std::fs::remove_dir_all(&dir);
}
