//! Interoperability of the simulated LSS device with an independent LSS
//! master: python-canopen's `LssMaster` (`network.lss`,
//! `tests/python/lss_master.py`), attached to the gateway's virtual can0
//! through the cangate python-can interface, runs its fastscan against a
//! simulated device that has no node-ID, inquires it, configures node-ID
//! 20, stores it and switches back to waiting. The gateway's side is
//! checked over gRPC: the device boots up as node 20, the master's boot
//! procedure (the configuration expects node 20) completes, GetNode shows
//! the identity the fastscan found, and the gateway's own LSS inquire of
//! the device agrees.
//!
//! The interpreter is `CANGATE_PYTHON` (the venv of `scripts/test`), else
//! `python3`; without python-can, python-canopen or the package the test is
//! skipped with the reason, except under `CI=true`.

#[path = "common/python_peer.rs"]
mod python_peer;
#[path = "common/vcan.rs"]
mod vcan;

use anyhow::{Result, anyhow, ensure};
use cangate_client::pb;
use cangate_client::pb::node_event::Event;
use cangate_server::Config;
use python_peer::{Peer, python_or_skip, script};
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
name = "io given its id by python-canopen's LSS master"
eds = "builtin:io"
simulate = true
boot = true
sim_lss = { serial = 0x00C0FFEE }
"#;

const MODULES: &[&str] = &["can", "canopen", "cangate"];
/// Starting python and importing grpc, can and canopen.
const READY_WAIT: Duration = Duration::from_secs(90);
/// python-canopen's fastscan: about 64 silent bits at its response
/// timeout (0.15 s here) plus 10 ms pauses between 133 queries.
const SCAN_WAIT: Duration = Duration::from_secs(120);
const WAIT: Duration = Duration::from_secs(10);

#[test]
fn python_canopen_lss_master_configures_the_simulated_device() {
    let Some(python) = python_or_skip(
        "python_canopen_lss_master_configures_the_simulated_device",
        MODULES,
    ) else {
        return;
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("tokio runtime");
    rt.block_on(async {
        let config = Config::from_toml(CONFIG).expect("config");
        let server = cangate_server::start(&config).await.expect("server starts");
        let r = tokio::time::timeout(Duration::from_secs(240), scenario(&python, &server)).await;
        server.shutdown();
        match r {
            Ok(Ok(())) => {}
            Ok(Err(e)) => panic!("{e:#}"),
            Err(_) => panic!("the scenario took longer than 240 s"),
        }
    });
}

async fn scenario(python: &std::path::Path, server: &cangate_server::RunningServer) -> Result<()> {
    let t0 = Instant::now();
    let step = |name: &str| eprintln!("[{:>6.2} s] {name}", t0.elapsed().as_secs_f64());
    let c = cangate_client::connect(&format!("http://{}", server.addr)).await?;
    let mut events = c
        .canopen_client()
        .stream_node_events(pb::StreamNodeEventsRequest {
            bus: "can0".into(),
            nodes: vec![20],
        })
        .await?
        .into_inner();
    // The device's identity: the builtin:io EDS's vendor, product and
    // revision, with the configured serial.
    let io = cangate_canopen::eds::Eds::parse(cangate_canopen::eds::SIM_IO_EDS)?;
    let node = cangate_canopen::NodeId::new(20)?;
    let eds_u32 = |sub: u8| {
        io.od
            .get(cangate_canopen::ObjectAddress::new(0x1018, sub))
            .and_then(|v| v.default_for_node(node))
            .and_then(|v| v.as_u32())
            .unwrap_or(0)
    };
    let expected = [eds_u32(1), eds_u32(2), eds_u32(3), 0x00C0_FFEE];

    step("starting python-canopen's LSS master, attached through the cangate interface");
    let mut p = Peer::spawn(
        python,
        &script("lss_master.py"),
        &["--channel", "can0", "--node-id", "20"],
        &[("CANGATE_SERVER", format!("http://{}", server.addr))],
    )?;
    p.expect_line("READY", READY_WAIT).await?;

    step("fastscan");
    let found = p
        .expect("FOUND or FAILED", SCAN_WAIT, |l| {
            l.starts_with("FOUND ") || l.starts_with("FAILED ")
        })
        .await?;
    ensure!(found.starts_with("FOUND "), "python: {found}");
    let parts: Vec<u32> = found["FOUND ".len()..]
        .split_whitespace()
        .map(|h| u32::from_str_radix(h, 16))
        .collect::<Result<_, _>>()?;
    ensure!(
        parts == expected,
        "fastscan found {parts:08x?}, the device is {expected:08x?}"
    );

    let inquire = p
        .expect("INQUIRE", WAIT, |l| {
            l.starts_with("INQUIRE ") || l.starts_with("FAILED ")
        })
        .await?;
    ensure!(
        inquire == format!("INQUIRE 255 {:08x} {:08x}", expected[0], expected[3]),
        "python: {inquire}"
    );
    let configured = p
        .expect("CONFIGURED", WAIT, |l| {
            l.starts_with("CONFIGURED ") || l.starts_with("FAILED ")
        })
        .await?;
    ensure!(configured == "CONFIGURED 20", "python: {configured}");

    step("the device boots up as node 20 and the master boots it");
    let deadline = Instant::now() + WAIT;
    let mut booted_up = false;
    loop {
        let ev = tokio::time::timeout_at(deadline.into(), events.message())
            .await
            .map_err(|_| anyhow!("no boot-up / boot completed of node 20 within {WAIT:?}"))??
            .ok_or_else(|| anyhow!("node event stream ended"))?;
        match ev.event {
            Some(Event::BootUp(_)) => booted_up = true,
            Some(Event::BootCompleted(_)) if booted_up => break,
            Some(Event::BootFailed(f)) => return Err(anyhow!("boot failed: {}", f.reason)),
            _ => {}
        }
    }
    let n = c
        .canopen_client()
        .get_node(pb::GetNodeRequest {
            bus: "can0".into(),
            node: 20,
        })
        .await?
        .into_inner();
    let id = n.identity.ok_or_else(|| anyhow!("no identity: {n:?}"))?;
    ensure!(
        [id.vendor_id, id.product_code, id.revision, id.serial] == expected,
        "GetNode identity {id:?}"
    );

    step("the gateway's own LSS inquire agrees");
    let (ident, node_id) = c.lss("can0").inquire(None).await?;
    ensure!(node_id == 20, "node-ID {node_id}");
    ensure!(ident.serial == 0x00C0_FFEE, "{ident:?}");
    // Stored: an unconfigured device is gone from the bus.
    ensure!(!c.lss("can0").identify_non_configured().await?);

    p.say("QUIT")?;
    p.expect_line("BYE", WAIT).await?;
    p.finish(WAIT).await?;
    step("done");
    Ok(())
}
