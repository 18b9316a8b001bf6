//! `cangate lss` against a real gateway (in this process) on a virtual bus
//! with one simulated device that starts without a node-ID: `lss scan`
//! prints its identity, `lss set-id --serial` gives it node-ID 20, after
//! which `lss inquire` and `node show` see node 20; a second scan finds
//! nothing; bad ids are usage errors.

mod common;

use common::{assert_status, run, stderr, stdout};
use std::net::SocketAddr;
use std::process::Output;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

const CONFIG: &str = r#"
listen = "127.0.0.1:0"

[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"

[[canopen.node]]
id = 20
name = "io given its id by LSS"
eds = "builtin:io"
simulate = true
boot = true
sim_lss = { serial = 0xCAFE }
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
fn scan_set_id_and_inquire_from_the_shell() {
    let o = cangate(&["lss", "scan", "can0"]);
    assert_status(&o, 0);
    let out = stdout(&o);
    assert_eq!(out.lines().count(), 1, "{out}");
    assert!(out.contains("serial 0x0000CAFE"), "{out}");
    let o = cangate(&["lss", "scan", "can0", "--json"]);
    assert_status(&o, 0);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON");
    assert_eq!(v["devices"][0]["serial"], 0xCAFE, "{v}");

    let o = cangate(&["lss", "set-id", "can0", "--serial", "0xCAFE", "20"]);
    assert_status(&o, 0);
    assert!(
        stdout(&o).starts_with("node-ID 20 set and stored (was none)"),
        "{}",
        stdout(&o)
    );
    // The node boots up as 20 and the master boots it.
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let o = cangate(&["node", "show", "can0", "20", "--json"]);
        if o.status.success() {
            let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON");
            if v["state"] == "NMT_STATE_OPERATIONAL" {
                break;
            }
        }
        assert!(Instant::now() < deadline, "node 20 never operational");
        std::thread::sleep(Duration::from_millis(50));
    }
    let o = cangate(&["lss", "inquire", "can0"]);
    assert_status(&o, 0);
    assert!(stdout(&o).contains("node-ID 20"), "{}", stdout(&o));
    let o = cangate(&["lss", "scan", "can0"]);
    assert_status(&o, 0);
    assert_eq!(stdout(&o).trim(), "no unconfigured device answered");
}

#[test]
fn bad_ids_are_usage_errors() {
    for id in ["0", "128", "x"] {
        let o = run(
            &["--server", "127.0.0.1:1"],
            &["lss", "set-id", "can0", "--serial", "1", id],
        );
        assert_status(&o, 2);
        assert!(!stderr(&o).is_empty());
    }
    // A partial identity is refused by the grammar.
    let o = run(
        &["--server", "127.0.0.1:1"],
        &[
            "lss", "set-id", "can0", "--serial", "1", "--vendor", "2", "20",
        ],
    );
    assert_status(&o, 2);
}
