//! A standard gRPC client in another language reads the gateway's errors:
//! the real server in-process on a virtual bus with simulated CANopen
//! nodes, and `tests/python/rich_errors.py` (grpcio, grpcio-status,
//! googleapis-common-protos; stubs generated at run time with grpcio-tools
//! into a temporary directory) calling it.
//!
//! The script decodes each error with `grpc_status.rpc_status.from_call`,
//! finds the `google.rpc.ErrorInfo` (domain `cangate.v1`, reason, metadata)
//! and, for SDO errors, unpacks `cangate.v1.SdoAbortDetails` from its `Any`:
//! a node's abort (NOT_FOUND and FAILED_PRECONDITION), the gateway's abort
//! of an SDO timeout (DEADLINE_EXCEEDED) and an unknown bus.
//!
//! The python interpreter is `CANGATE_PYTHON` (the venv `scripts/test`
//! builds in `target/python` from `tests/python/requirements.txt`), else
//! `python3`. Without the packages the test is skipped, except under
//! `CI=true`, where it fails instead.

mod common;
#[path = "common/python_peer.rs"]
mod python_peer;
#[path = "common/vcan.rs"]
mod vcan;

use common::*;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

const TEST_NAME: &str = "python_client_decodes_rich_errors";
/// Starting python, generating the stubs and four calls (one an SDO
/// timeout of 200 ms) take a few seconds; a loaded CI runner more.
const LIMIT: Duration = Duration::from_secs(150);

const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"
fd = true
[[canopen]]
bus = "can0"
sdo_timeout_ms = 200
[[canopen.node]]
id = 1
name = "drive"
eds = "builtin:drive"
simulate = true
[[canopen.node]]
id = 10
name = "absent"
"#;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn python_client_decodes_rich_errors() {
    let modules = [
        "grpc",
        "grpc_tools",
        "grpc_status",
        "google.rpc.error_details_pb2",
    ];
    let Some(python) = python_peer::python_or_skip(TEST_NAME, &modules) else {
        return;
    };
    let server = start_server(CONFIG).await;
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    let script = here.join("python/rich_errors.py");
    let protos = here.join("../proto/proto");
    let address = server.addr.to_string();
    let run = tokio::task::spawn_blocking(move || {
        Command::new(&python)
            .arg(&script)
            .arg(&protos)
            .arg(&address)
            .env("PYTHONDONTWRITEBYTECODE", "1")
            .stdin(Stdio::null())
            .output()
    });
    let out = tokio::time::timeout(LIMIT, run)
        .await
        .expect("the python client finishes in time")
        .expect("the python client's thread")
        .expect("python starts");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    eprintln!("{stdout}{stderr}");
    assert!(
        out.status.success(),
        "the python client failed ({}):\n{stdout}\n{stderr}",
        out.status
    );
    assert!(
        stdout.contains("rich errors: all checks passed"),
        "{stdout}"
    );
    server.shutdown();
}
