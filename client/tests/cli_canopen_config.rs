//! The real `cangate` binary changing a CANopen bus at run time: `pdo
//! show|map|disable`, `sync`, `time`, `node dcf`, against a gateway of its
//! own (one simulated drive, no axis, the SYNC stopped), with the exit
//! statuses of refusals.

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
id = 1
name = "drive"
eds = "builtin:drive"
simulate = true
boot = true
"#;

fn gateway() -> SocketAddr {
    static ADDR: OnceLock<SocketAddr> = OnceLock::new();
    *ADDR.get_or_init(|| common::start_gateway(CONFIG))
}

fn cangate(args: &[&str]) -> Output {
    let addr = gateway().to_string();
    run(&["--server", &addr], args)
}

#[test]
fn pdos_are_shown_mapped_and_disabled() {
    let o = cangate(&["pdo", "show", "can0", "1", "tpdo2"]);
    assert_status(&o, 0);
    let text = stdout(&o);
    assert!(text.starts_with("TPDO2   0x281  enabled"), "{text}");
    assert!(
        text.contains("0x606C:00/32  Velocity actual value"),
        "{text}"
    );

    let o = cangate(&[
        "pdo",
        "map",
        "can0",
        "1",
        "tpdo2",
        "0x6041:0",
        "Modes of operation display",
        "0x6064:0/32",
        "--sync",
        "2",
    ]);
    assert_status(&o, 0);
    let text = stdout(&o);
    assert!(text.contains("type 2 (every 2th SYNC)"), "{text}");
    assert!(
        text.contains("0x6061:00/8   Modes of operation display"),
        "{text}"
    );
    // Read back from the node.
    let o = cangate(&["pdo", "show", "can0", "1", "tpdo2", "--json"]);
    assert_status(&o, 0);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON");
    assert_eq!(v[0]["transmissionType"], 2, "{v}");
    assert_eq!(v[0]["mapping"].as_array().map(Vec::len), Some(3), "{v}");

    let o = cangate(&["pdo", "disable", "can0", "1", "tpdo2"]);
    assert_status(&o, 0);
    assert!(stdout(&o).contains("disabled"), "{}", stdout(&o));

    // Refusals: a bad object on this side, a non-mappable one by the
    // gateway, the node's abort with the object named.
    let o = cangate(&["pdo", "map", "can0", "1", "tpdo2", "0x6041"]);
    assert_status(&o, 2);
    let o = cangate(&["pdo", "map", "can0", "1", "tpdo2", "0x1000:0"]);
    assert_status(&o, 1);
    assert!(stderr(&o).contains("not PDO-mappable"), "{}", stderr(&o));
    let o = cangate(&["pdo", "map", "can0", "1", "tpdo2", "0x2FFF:0/16"]);
    assert_status(&o, 6);
    assert!(
        stderr(&o).contains("object 0x1A01:01: SDO abort 0x06040041"),
        "{}",
        stderr(&o)
    );
    let o = cangate(&["pdo", "show", "can0", "1", "xpdo1"]);
    assert_status(&o, 2);
}

#[test]
fn sync_and_time_from_the_shell() {
    let o = cangate(&["sync", "can0"]);
    assert_status(&o, 0);
    assert!(stdout(&o).contains("SYNC stopped"), "{}", stdout(&o));
    let o = cangate(&["sync", "can0", "start", "--period-us", "5000"]);
    assert_status(&o, 0);
    assert!(
        stdout(&o).contains("SYNC running  period 5000 µs"),
        "{}",
        stdout(&o)
    );
    let o = cangate(&["sync", "can0", "set", "--counter", "8"]);
    assert_status(&o, 0);
    assert!(stdout(&o).contains("counter 1..=8"), "{}", stdout(&o));
    let o = cangate(&["sync", "can0", "set", "--counter", "1"]);
    assert_status(&o, 1);
    assert!(stderr(&o).contains("reserved"), "{}", stderr(&o));
    let o = cangate(&["sync", "can0", "stop"]);
    assert_status(&o, 0);
    assert!(stdout(&o).contains("SYNC stopped"), "{}", stdout(&o));
    let o = cangate(&["sync", "can9"]);
    assert_status(&o, 3);

    let o = cangate(&["time", "can0", "send"]);
    assert_status(&o, 0);
    assert!(stdout(&o).contains("TIME sent: day"), "{}", stdout(&o));
    let o = cangate(&["time", "can0", "every", "1000"]);
    assert_status(&o, 0);
    assert!(stdout(&o).contains("TIME every 1000 ms"), "{}", stdout(&o));
    let o = cangate(&["time", "can0", "off"]);
    assert_status(&o, 0);
    assert!(
        stdout(&o).contains("TIME only on request"),
        "{}",
        stdout(&o)
    );
}

#[test]
fn a_dcf_is_written_to_a_file() {
    let dir = std::env::temp_dir().join(format!("cangate-cli-dcf-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("drive.dcf");
    let o = cangate(&["node", "dcf", "can0", "1", "-o", path.to_str().unwrap()]);
    assert_status(&o, 0);
    assert!(stderr(&o).contains("written to"), "{}", stderr(&o));
    assert!(stderr(&o).contains("0x2100:00 left out"), "{}", stderr(&o));
    let text = std::fs::read_to_string(&path).unwrap();
    // (The DCF's content is checked with the EDS parser in the server's
    // tests; here, that the file is the DCF.)
    assert!(
        text.contains("\n[DeviceComissioning]\nNodeID=1\nNodeName=drive\n"),
        "{text}"
    );
    assert!(text.contains("[1018sub1]"), "{text}");
    assert!(text.contains("ParameterValue=0x4D2"), "{text}");
    // To standard output without -o.
    let o = cangate(&["node", "dcf", "can0", "1"]);
    assert_status(&o, 0);
    assert!(stdout(&o).contains("[DeviceComissioning]"));
    let _ = std::fs::remove_dir_all(&dir);
}
