//! The dashboard in a real browser: Debian's headless Chromium, driven by
//! `web/tests/dashboard.mjs` (puppeteer-core from `web/node_modules`),
//! against the real demo server in-process on port 0. The page's clicks
//! are checked on the page by the script and over gRPC here; screenshots
//! go to `target/web-screenshots/`.
//!
//! Needs `/usr/bin/chromium` (or `CANGATE_CHROMIUM`), `node`, and
//! `web/node_modules` (`scripts/web-build`); `scripts/test` installs them.
//! Outside CI a missing one skips the test, saying why; under `CI` it
//! fails.

use cangate_client::{ConnectOptions, pb};
use cangate_server::{Config, RunningServer};
use cangate_tests::*;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn chromium() -> PathBuf {
    std::env::var_os("CANGATE_CHROMIUM").map_or_else(|| "/usr/bin/chromium".into(), PathBuf::from)
}

/// Why the browser test cannot run here, if it cannot.
fn missing() -> Option<String> {
    if !chromium().exists() {
        return Some(format!(
            "{} not found (apt-get install chromium; scripts/test does)",
            chromium().display()
        ));
    }
    if !repo().join("web/node_modules/puppeteer-core").exists() {
        return Some("web/node_modules missing (run scripts/web-build)".into());
    }
    if std::process::Command::new("node")
        .arg("--version")
        .output()
        .is_err()
    {
        return Some("node not found".into());
    }
    None
}

/// Skips (outside CI) or fails (under CI) when something is missing.
fn can_run(test: &str) -> bool {
    match missing() {
        None => true,
        Some(why) if std::env::var_os("CI").is_some() => panic!("{test}: {why}"),
        Some(why) => {
            eprintln!("skipping {test}: {why}");
            false
        }
    }
}

async fn demo_server() -> RunningServer {
    let mut c = Config::demo();
    c.listen = "127.0.0.1:0".parse().unwrap();
    cangate_server::start(&c).await.expect("server starts")
}

fn screenshots() -> PathBuf {
    let dir = repo().join("target/web-screenshots");
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// One browser at a time: three Chromiums at once on a 2-core CI host
/// starved each other's pages for seconds (a page then lost its 3 s axis
/// lease between two renewals).
static ONE_BROWSER: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// Runs the browser script; `on_need` answers its requests (with the line
/// to send back). Returns the steps it reported.
async fn drive<F, Fut>(args: &[String], mut on_need: F) -> Vec<String>
where
    F: FnMut(String) -> Fut,
    Fut: std::future::Future<Output = String>,
{
    let _one = ONE_BROWSER.lock().await;
    let mut child = tokio::process::Command::new("node")
        .arg(repo().join("web/tests/dashboard.mjs"))
        .args(args)
        .env("CANGATE_CHROMIUM", chromium())
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .expect("node starts");
    let mut stdin = child.stdin.take().unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let mut stderr = child.stderr.take().unwrap();
    let mut steps = Vec::new();
    let run = async {
        while let Some(line) = lines.next_line().await.unwrap() {
            eprintln!("browser: {line}");
            if let Some(need) = line.strip_prefix("need ") {
                let answer = on_need(need.to_string()).await;
                stdin
                    .write_all(format!("{answer}\n").as_bytes())
                    .await
                    .unwrap();
            } else if let Some(step) = line.strip_prefix("step ") {
                steps.push(step.to_string());
            }
        }
    };
    tokio::time::timeout(Duration::from_secs(120), run)
        .await
        .expect("the browser script finished in time");
    let status = child.wait().await.unwrap();
    let mut err = String::new();
    tokio::io::AsyncReadExt::read_to_string(&mut stderr, &mut err)
        .await
        .unwrap();
    assert!(status.success(), "browser script failed: {err}");
    steps
}

fn unexpected(need: String) -> String {
    panic!("unexpected request {need}")
}

/// Turns the simulated wheel hw1 (in manual mode, set by the page) 40
/// detents on X with 30 % frame loss, waits until its statistics settle
/// and returns them as the page shows them (JSON by the page's keys).
async fn turn_wheel(c: &cangate_client::Client) -> String {
    c.simulator_client()
        .turn_handwheel(pb::TurnHandwheelRequest {
            handwheel: "hw1".into(),
            detents: 40,
            axis: pb::WheelAxis::X as i32,
            multiplier: 1,
            loss: 0.3,
            max_consecutive_loss: 3,
        })
        .await
        .expect("TurnHandwheel");
    let mut hw = c.handwheels_client();
    let mut last = None;
    loop {
        tokio::time::sleep(Duration::from_millis(300)).await;
        let w = hw
            .get_handwheel(pb::GetHandwheelRequest {
                handwheel: "hw1".into(),
            })
            .await
            .expect("GetHandwheel")
            .into_inner();
        let s = w.stats.expect("stats");
        let b = w.binding.expect("binding stats");
        let now = format!(
            r#"{{"frames":{},"gaps":{},"compensated":{},"duplicates":{},"units":{}}}"#,
            s.frames, s.gaps, s.compensated_units, s.duplicates, b.units
        );
        if last.as_ref() == Some(&now) && b.pending_units == 0 {
            assert!(s.frames > 0 && s.gaps > 0, "{now}");
            return now;
        }
        last = Some(now);
    }
}

/// The `cangate` binary of this build: `cargo test --workspace` builds it
/// (the client's own tests need it) before any test runs.
fn cangate_binary() -> Option<PathBuf> {
    let dir = std::env::current_exe()
        .ok()?
        .parent()?
        .parent()?
        .to_path_buf();
    Some(dir.join("cangate")).filter(|p| p.is_file())
}

/// Sends can0 7E5#C0FFEE as a user would, with `cangate send`; without the
/// binary (this crate's tests built alone), over gRPC, saying so, except
/// under CI.
async fn send_with_the_cli(c: &cangate_client::Client, server: &str) {
    match cangate_binary() {
        Some(bin) => {
            let out = tokio::process::Command::new(&bin)
                .args(["--server", server, "send", "can0", "7E5#C0FFEE"])
                .output()
                .await
                .expect("cangate runs");
            assert!(
                out.status.success(),
                "cangate send failed: {}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        None => {
            assert!(
                std::env::var_os("CI").is_none(),
                "CI=true: the cangate binary must be built beside this test"
            );
            eprintln!(
                "no cangate binary beside this test (build the workspace): sending over gRPC"
            );
            c.bus_client()
                .send_frames(pb::SendFramesRequest {
                    bus: "can0".into(),
                    frames: vec![pb::Frame {
                        id: 0x7E5,
                        data: vec![0xC0, 0xFF, 0xEE],
                        ..Default::default()
                    }],
                })
                .await
                .expect("frame sent over gRPC");
        }
    }
}

/// An axis's live status over gRPC.
async fn axis_status(c: &cangate_client::Client, axis: &str) -> pb::AxisStatus {
    c.axes_client()
        .get_axis(pb::GetAxisRequest { axis: axis.into() })
        .await
        .expect("GetAxis")
        .into_inner()
        .status
        .expect("status")
}

/// X is free well before its lease (3 s, renewed every second) could have
/// lapsed: the page gave it back as it went away.
async fn released_at_once(c: &cangate_client::Client) {
    let started = std::time::Instant::now();
    loop {
        let holder = axis_status(c, "X").await.controlled_by;
        if holder.is_empty() {
            return;
        }
        assert!(
            started.elapsed() < std::time::Duration::from_millis(1500),
            "X still controlled by {holder} after the page was left"
        );
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_dashboard_moves_jogs_stops_and_shows_frames() {
    if !can_run("the_dashboard_moves_jogs_stops_and_shows_frames") {
        return;
    }
    let server = demo_server().await;
    let c = client(&server).await;
    let url = format!("http://{}/", server.addr);
    let shots = screenshots();
    let steps = drive(&["demo".into(), url, shots.display().to_string()], |need| {
        let c = c.clone();
        let server_addr = server.addr.to_string();
        async move {
            match need.as_str() {
                "send-frame" => send_with_the_cli(&c, &server_addr).await,
                "emcy" => {
                    c.simulator_client()
                        .send_emcy(pb::SendEmcyRequest {
                            bus: "can0".into(),
                            node: 4,
                            code: 0x2310,
                            error_register: 0x03,
                            manufacturer: vec![],
                        })
                        .await
                        .expect("EMCY sent by the simulated node 4");
                }
                "turn" => return turn_wheel(&c).await,
                "lease-released" => released_at_once(&c).await,
                "x-at-12.5" => {
                    let st = axis_status(&c, "X").await;
                    assert!(
                        (st.position - 12.5).abs() < 0.002,
                        "X over gRPC at {} after the page's move to 12.5",
                        st.position
                    );
                    assert_eq!(st.activity, pb::AxisActivity::Idle as i32, "X idle");
                    assert_eq!(st.state, pb::DriveState::OperationEnabled as i32);
                }
                other => panic!("unexpected request {other}"),
            }
            "ok".to_string()
        }
    })
    .await;
    let names: Vec<&str> = steps.iter().map(|s| s.split(' ').next().unwrap()).collect();
    assert_eq!(
        names,
        [
            "axes-listed",
            "switches",
            "x-moved",
            "x-traced",
            "y-jog",
            "home-move",
            "stop-all",
            "frame-shown",
            "filters",
            "load-chart",
            "canopen-nodes",
            "nmt",
            "emcy-shown",
            "alarm-emcy",
            "hidden-pages-still",
            "sdo-read",
            "sdo-abort",
            "sdo-read-by-name",
            "canopen-scan",
            "handwheel",
            "handwheel-automatic",
            "cansmc",
            "cansmc-histogram",
            "cansmc-restart",
            "cansmc-parameters",
            "streams",
            "lease-released",
            "no-console-errors"
        ]
    );
    let step = |name: &str| {
        steps
            .iter()
            .find_map(|s| s.strip_prefix(name)?.strip_prefix(' '))
            .unwrap_or_else(|| panic!("step {name}"))
            .to_string()
    };
    assert_eq!(
        step("switches"),
        "home=true positive=false negative=false",
        "the demo's Y switch icons"
    );
    // What the page did, seen over gRPC: Y came to rest after the jog,
    // and X was stopped by STOP ALL on its way from 12.5 to -150 (the move
    // to 12.5 was checked on the page; the stop moved X on since).
    for name in ["X", "Y"] {
        let st = axis_status(&c, name).await;
        assert_eq!(st.velocity, 0.0, "{name} at rest");
        assert_eq!(st.activity, pb::AxisActivity::Idle as i32, "{name} idle");
        assert_eq!(st.state, pb::DriveState::OperationEnabled as i32);
    }
    let x = axis_status(&c, "X").await.position;
    let on_page: f64 = step("stop-all")
        .strip_prefix("x=")
        .and_then(|v| v.parse().ok())
        .expect("the page reports where X stopped");
    assert!((x - on_page).abs() < 1e-3, "page {on_page}, gRPC {x}");
    assert!(x < 12.5 && x > -140.0, "{x}");
    // The move after Home ran at the velocity given on the page (20, not
    // the axis's 100: the drive's actual velocity, which overshoots the
    // profile's a little) and X is homed.
    let home_move = step("home-move");
    let vmax: f64 = home_move
        .rsplit_once("vmax=")
        .and_then(|(_, v)| v.parse().ok())
        .expect("vmax");
    // The page samples the velocity as it polls: a loaded machine may miss
    // the plateau, so only the bound the velocity input sets is checked
    // (the axis's maximum is 100).
    assert!(vmax > 1.0 && vmax < 25.0, "{home_move}");
    let x_status = axis_status(&c, "X").await;
    assert!(x_status.homed, "X homed by the page");

    // can0 carries the demo's SYNC and process data: its charted load
    // is above zero, as GetBus says.
    let can0_load: f64 = step("load-chart")
        .strip_prefix("can0=")
        .and_then(|v| v.parse().ok())
        .expect("can0 load");
    let grpc_load = c
        .bus_client()
        .get_bus(pb::GetBusRequest { bus: "can0".into() })
        .await
        .expect("GetBus")
        .into_inner()
        .statistics
        .expect("statistics")
        .load_percent;
    assert!(
        can0_load > 0.0 && grpc_load > 0.0,
        "page {can0_load}, gRPC {grpc_load}"
    );

    // The CANopen page, against the gateway's own answers: node 1's
    // identity and device name, the EMCY of node 4 as the master decoded
    // it, and the abort of a write to the read-only 0x1000.
    let mut co = c.canopen_client();
    let node1 = co
        .get_node(pb::GetNodeRequest {
            bus: "can0".into(),
            node: 1,
        })
        .await
        .expect("GetNode")
        .into_inner();
    let id = node1.identity.expect("node 1 identity read at boot");
    assert_eq!(
        step("canopen-nodes"),
        format!(
            "identity=\"vendor 0x{:08X} product 0x{:08X} rev 0x{:08X} serial {}\"",
            id.vendor_id, id.product_code, id.revision, id.serial
        )
    );
    let name = co
        .read_sdo(pb::ReadSdoRequest {
            bus: "can0".into(),
            node: 1,
            index: 0x1008,
            subindex: 0,
            ..Default::default()
        })
        .await
        .expect("ReadSdo 0x1008")
        .into_inner();
    let Some(pb::value::Value::StringValue(device_name)) = name.value.and_then(|v| v.value) else {
        panic!("0x1008 of node 1 is a string")
    };
    assert!(!device_name.is_empty());
    assert_eq!(
        step("sdo-read"),
        format!(
            "read can0 node 1 0x1008:0: VISIBLE_STRING {device_name:?}; raw [{}] {}",
            name.raw.len(),
            name.raw
                .iter()
                .map(|b| format!("{b:02X}"))
                .collect::<Vec<_>>()
                .join(" ")
        )
    );
    // The picker read 0x1008 by its EDS name: the same value, typed by the
    // EDS (its type preselected), the object's facts from ListObjects.
    let raw_hex = name
        .raw
        .iter()
        .map(|b| format!("{b:02X}"))
        .collect::<Vec<_>>()
        .join(" ");
    assert_eq!(
        step("sdo-read-by-name"),
        format!(
            "read can0 node 1 \"Manufacturer device name\": VISIBLE_STRING {device_name:?}; raw [{}] {raw_hex} \
             | 0x1008:00 Manufacturer device name: VISIBLE_STRING, const, default {device_name:?} \
             | Producer heartbeat time",
            name.raw.len(),
        )
    );
    let node4 = co
        .get_node(pb::GetNodeRequest {
            bus: "can0".into(),
            node: 4,
        })
        .await
        .expect("GetNode")
        .into_inner();
    let emcy = node4
        .active_error
        .expect("node 4's EMCY is its active error");
    assert_eq!(emcy.code, 0x2310);
    assert!(
        step("emcy-shown").contains(&format!("0x2310 {}", emcy.code_name)),
        "{} / {}",
        step("emcy-shown"),
        emcy.code_name
    );
    let refused = co
        .write_sdo(pb::WriteSdoRequest {
            bus: "can0".into(),
            node: 1,
            index: 0x1000,
            subindex: 0,
            data: Some(pb::write_sdo_request::Data::Value(pb::Value {
                r#type: pb::DataType::Unsigned32 as i32,
                value: Some(pb::value::Value::UintValue(1)),
            })),
            options: None,
            object: String::new(),
            force: false,
        })
        .await
        .expect_err("0x1000 is read-only");
    let abort = cangate_client::sdo_abort_details(&refused).expect("SdoAbortDetails");
    assert_eq!(abort.code, 0x0601_0002);
    assert_eq!(
        step("sdo-abort"),
        format!("SDO abort 0x{:08X} {}", abort.code, abort.name)
    );
    // Node 3 is operational again after the page's NMT pre-operational,
    // stop and start.
    let node3 = co
        .get_node(pb::GetNodeRequest {
            bus: "can0".into(),
            node: 3,
        })
        .await
        .expect("GetNode")
        .into_inner();
    assert_eq!(node3.state, pb::NmtState::Operational as i32);
    // The handwheel: every gap the gateway counted is a line of the page's
    // feed, and the wheel is back in automatic mode.
    let hw = c
        .handwheels_client()
        .get_handwheel(pb::GetHandwheelRequest {
            handwheel: "hw1".into(),
        })
        .await
        .expect("GetHandwheel")
        .into_inner();
    assert_eq!(hw.mode, pb::HandwheelMode::Automatic as i32);
    let gaps = hw.stats.expect("stats").gaps;
    assert!(
        step("handwheel").ends_with(&format!("compensated_lines={gaps}")),
        "{} / {gaps} gaps",
        step("handwheel")
    );
    // The CANsmc slaves the page lists are the master's.
    let st = c
        .cansmc_client()
        .get_status(pb::GetCansmcStatusRequest {
            master: String::new(),
        })
        .await
        .expect("GetStatus")
        .into_inner();
    assert_eq!(st.phase, pb::CansmcPhase::P2 as i32);
    let slaves: Vec<String> = st
        .slaves
        .iter()
        .map(|s| {
            let opt = if s.required { "" } else { " (optional)" };
            format!("{}:{}{opt}", s.address, s.name)
        })
        .collect();
    // (The names are plain ASCII: Debug quotes them as JSON does.)
    assert_eq!(
        step("cansmc"),
        format!(
            "[{}]",
            slaves
                .iter()
                .map(|s| format!("{s:?}"))
                .collect::<Vec<_>>()
                .join(",")
        )
    );
    cansmc_page_against_grpc(&c, &step).await;
    // The page's scan of can0 found the nodes ScanNetwork finds.
    let scanned: Vec<String> = co
        .scan_network(pb::ScanNetworkRequest {
            bus: "can0".into(),
            timeout_ms: 0,
        })
        .await
        .expect("ScanNetwork")
        .into_inner()
        .nodes
        .iter()
        .map(|n| n.id.to_string())
        .collect();
    assert_eq!(step("canopen-scan"), format!("[{}]", scanned.join(",")));
    for f in [
        "axes.png",
        "axes-x-moved.png",
        "buses.png",
        "canopen.png",
        "handwheel.png",
        "cansmc.png",
        "cansmc-parameters.png",
    ] {
        assert!(shots.join(f).exists(), "{f}");
    }
    server.shutdown();
}

/// The CANsmc page's histogram, Restart and parameter panel, against the
/// gateway's answers: the histogram the page drew summed to its samples,
/// as GetStatus's does; the master went through P0 once more (starts 2,
/// P2); parameter 4 of slave 1 reads back what the page wrote, and the
/// page read the encoder resolution GetStatus's slave reads.
async fn cansmc_page_against_grpc(c: &cangate_client::Client, step: &impl Fn(&str) -> String) {
    let hist = step("cansmc-histogram");
    let field = |name: &str| -> u64 {
        hist.split(' ')
            .find_map(|kv| kv.strip_prefix(name)?.strip_prefix('='))
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("{name} in {hist}"))
    };
    assert_eq!(field("samples"), field("total"), "{hist}");
    assert!(field("samples") > 0 && field("drawn") > 0, "{hist}");
    assert!(
        field("buckets") <= 100 && field("drawn") <= field("buckets"),
        "{hist}"
    );
    let mut smc = c.cansmc_client();
    let st = smc
        .get_status(pb::GetCansmcStatusRequest {
            master: String::new(),
        })
        .await
        .expect("GetStatus")
        .into_inner();
    assert_eq!(st.phase, pb::CansmcPhase::P2 as i32);
    assert_eq!(st.starts, 2, "restarted once by the page");
    assert_eq!(step("cansmc-restart"), "starts=2");
    let j = st.jitter.expect("jitter");
    assert_eq!(j.histogram.iter().sum::<u64>(), j.samples);
    let read = |number: u32| {
        let mut smc = smc.clone();
        async move {
            smc.read_parameter(pb::ReadParameterRequest {
                master: String::new(),
                address: 1,
                number,
            })
            .await
            .expect("ReadParameter")
            .into_inner()
            .value
        }
    };
    let resolution = read(3).await;
    assert_eq!(read(4).await, 23456, "the page's write of parameter 4");
    let params = step("cansmc-parameters");
    assert!(
        params.starts_with(&format!("resolution={resolution} refused="))
            && params.ends_with(" written=23456"),
        "{params}"
    );
    assert!(params.contains("read-only"), "{params}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_gateway_with_tokens_asks_for_one_and_honours_the_role() {
    if !can_run("a_gateway_with_tokens_asks_for_one_and_honours_the_role") {
        return;
    }
    let tokens = format!(
        "[[security.tokens]]\nname = \"wall-screen\"\nrole = \"viewer\"\nsha256 = \"{}\"\n\
         [[security.tokens]]\nname = \"hmi\"\nrole = \"operator\"\nsha256 = \"{}\"\n",
        cangate_client::hash_token("viewer-secret"),
        cangate_client::hash_token("operator-secret")
    );
    // The token tables go after the demo's own [security] keys.
    let server = {
        let mut c = Config::demo();
        let extra = Config::from_toml(&format!(
            "{tokens}[[bus]]\nname = \"x\"\nbackend = \"virtual\"\n"
        ))
        .expect("token configuration is valid");
        c.security.tokens = extra.security.tokens;
        c.listen = "127.0.0.1:0".parse().unwrap();
        cangate_server::start(&c).await.expect("server starts")
    };
    let url = format!("http://{}/", server.addr);
    let steps = drive(
        &[
            "tokens".into(),
            url,
            screenshots().display().to_string(),
            "viewer-secret".into(),
            "operator-secret".into(),
        ],
        |need| async move { unexpected(need) },
    )
    .await;
    // The roles the page shows and the buttons it disables, as the access
    // table (server/src/security/roles.rs) gives them.
    let viewer = r#"{"acquire":"AcquireControl needs role operator; this token has role viewer","enable":"Enable needs role operator; this token has role viewer","stopAll":"StopAxes needs role operator; this token has role viewer","nmt":"SendNmt needs role engineer; this token has role viewer","sdoRead":"enabled","sdoWrite":"WriteSdo needs role engineer; this token has role viewer","scan":"enabled","smcRestart":"Restart needs role engineer; this token has role viewer","paramRead":"enabled","paramWrite":"WriteParameter needs role engineer; this token has role viewer"}"#;
    let operator = r#"{"acquire":"enabled","enable":"enabled","stopAll":"enabled","nmt":"SendNmt needs role engineer; this token has role operator","sdoRead":"enabled","sdoWrite":"WriteSdo needs role engineer; this token has role operator","scan":"enabled","smcRestart":"Restart needs role engineer; this token has role operator","paramRead":"enabled","paramWrite":"WriteParameter needs role engineer; this token has role operator"}"#;
    assert_eq!(
        steps,
        [
            "refused-without-token".to_string(),
            "accepted-with-token".into(),
            "role role: viewer (wall-screen)".into(),
            format!("viewer-buttons {viewer}"),
            "role role: operator (hmi)".into(),
            format!("operator-buttons {operator}"),
            "no-console-errors".into(),
        ]
    );
    // Nobody took control of X through the page.
    let c = cangate_client::connect_with(
        &format!("http://{}", server.addr),
        &ConnectOptions {
            token: Some("viewer-secret".into()),
            ..Default::default()
        },
    )
    .await
    .unwrap();
    assert_eq!(axis_status(&c, "X").await.controlled_by, "");
    server.shutdown();
}

/// The page when the gateway goes away, and the Control column: the
/// handwheel taking X (manual mode) and releasing it shows in X's Control
/// cell; QUICK STOP ALL stops every axis; then the gateway shuts down
/// while the page is open: the connection line turns (driven by the
/// streams' errors, not a timer), every axis row is marked stale with its
/// age, and a STOP ALL click that fails stays shown until the operator
/// acknowledges it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_shows_a_gateway_that_went_away_and_a_failed_stop() {
    if !can_run("the_page_shows_a_gateway_that_went_away_and_a_failed_stop") {
        return;
    }
    let server = demo_server().await;
    let url = format!("http://{}/", server.addr);
    let server = &server;
    let steps = drive(
        &["gone".into(), url, screenshots().display().to_string()],
        |need| async move {
            assert_eq!(need, "shutdown", "unexpected request {need}");
            server.shutdown();
            "done".to_string()
        },
    )
    .await;
    let step = |name: &str| -> String {
        steps
            .iter()
            .find_map(|s| s.strip_prefix(name).map(|r| r.trim().to_string()))
            .unwrap_or_else(|| panic!("no step {name} in {steps:?}"))
    };
    assert!(step("control-taken").contains("handwheel hw1"), "{steps:?}");
    step("control-released");
    step("quick-stop-all");
    // Turned at once (the streams end with the gateway's shutdown); the
    // bound is generous for a loaded machine.
    let lost = step("link-lost");
    let ms: u64 = lost
        .strip_prefix("ms=")
        .and_then(|r| r.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{lost}"));
    assert!(
        ms < 5_000,
        "the connection line turned after {ms} ms: {lost}"
    );
    assert!(lost.contains("gateway lost"), "{lost}");
    assert!(step("rows-stale").starts_with("stale "), "{steps:?}");
    step("stop-failed-shown");
    step("stop-failed-acknowledged");
    assert_eq!(steps.last().map(String::as_str), Some("no-console-errors"));
    assert!(screenshots().join("gone.png").exists());
}

/// Every page at a panel PC's 1024×768 and at 1920×1080, and the axes view
/// on an upright tablet (768×1024): no command button outside the
/// viewport, no sideways scrolling, no number cut, STOP ALL and QUICK STOP
/// ALL in view; a screenshot of each in `target/web-screenshots/`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_page_fits_a_panel_pc_and_a_full_hd_screen() {
    if !can_run("every_page_fits_a_panel_pc_and_a_full_hd_screen") {
        return;
    }
    let server = demo_server().await;
    let url = format!("http://{}/", server.addr);
    let steps = drive(
        &["layout".into(), url, screenshots().display().to_string()],
        |need| async move { unexpected(need) },
    )
    .await;
    let pages = ["axes", "buses", "canopen", "handwheel", "cansmc", "alarms"];
    for (size, pages) in [
        ("1024x768", &pages[..]),
        ("1920x1080", &pages[..]),
        ("768x1024", &pages[..1]),
    ] {
        for page in pages {
            let step = format!("layout {page} {size}");
            assert!(steps.contains(&step), "no step {step:?} in {steps:?}");
            assert!(screenshots().join(format!("{page}-{size}.png")).exists());
        }
    }
    assert_eq!(steps.last().map(String::as_str), Some("no-console-errors"));
}

/// Hold-to-run on a touch panel: the jog button jogs Y while a finger
/// holds it (past the dead-man time) and stops Y when the finger lifts or
/// the touch is cancelled; checked over gRPC that Y is at rest after.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_touch_jog_runs_while_held_and_stops_when_the_touch_ends_or_is_lost() {
    if !can_run("a_touch_jog_runs_while_held_and_stops_when_the_touch_ends_or_is_lost") {
        return;
    }
    let server = demo_server().await;
    let url = format!("http://{}/", server.addr);
    let steps = drive(
        &["touch".into(), url, screenshots().display().to_string()],
        |need| async move { unexpected(need) },
    )
    .await;
    for end in ["touchEnd", "touchCancel"] {
        let step = steps
            .iter()
            .find(|s| s.starts_with(&format!("touch {end} ")))
            .unwrap_or_else(|| panic!("no touch step for {end} in {steps:?}"));
        let moved: f64 = step
            .split_whitespace()
            .find_map(|w| w.strip_prefix("moved="))
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("{step}"));
        assert!(moved > 1.0, "{step}");
    }
    let c = client(&server).await;
    let y = axis_status(&c, "Y").await;
    assert_eq!(y.activity, pb::AxisActivity::Idle as i32, "{y:?}");
    assert_eq!(steps.last().map(String::as_str), Some("no-console-errors"));
}

/// Alarms the page raises from polled states (not from events): a bus that
/// went off and a CANsmc slave no axis reports for, both marked cleared
/// when they come back.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bus_off_and_a_lost_cansmc_slave_are_alarms_until_they_recover() {
    if !can_run("a_bus_off_and_a_lost_cansmc_slave_are_alarms_until_they_recover") {
        return;
    }
    let server = demo_server().await;
    let smc1 = server
        .gateway()
        .network()
        .get("smc1")
        .expect("the demo's smc1");
    let url = format!("http://{}/", server.addr);
    let steps = drive(
        &["health".into(), url, screenshots().display().to_string()],
        |need| {
            let smc1 = smc1.clone();
            async move {
                match need.as_str() {
                    "smc1-bus-off" => smc1.force_bus_off(),
                    "smc1-recover" => smc1.recover(),
                    other => panic!("unexpected request {other}"),
                }
                "ok".to_string()
            }
        },
    )
    .await;
    assert_eq!(
        steps,
        ["health-raised", "health-cleared", "no-console-errors"],
        "{steps:?}"
    );
}

/// The dashboard over HTTPS: the demo gateway with `[security.tls]` (a
/// throwaway self-signed certificate for 127.0.0.1, made here with rcgen),
/// Chromium trusting exactly that certificate's public key
/// (`--ignore-certificate-errors-spki-list`): the page loads from
/// `https://127.0.0.1:PORT/` and lists the axes over gRPC-Web on TLS (over
/// HTTP/2: the gateway's ALPN offers h2 only).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_dashboard_works_over_tls() {
    if !can_run("the_dashboard_works_over_tls") {
        return;
    }
    let dir = std::env::temp_dir().join(format!("cangate-dashboard-tls-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let key = rcgen::KeyPair::generate().unwrap();
    let mut params =
        rcgen::CertificateParams::new(vec!["127.0.0.1".to_string(), "localhost".to_string()])
            .unwrap();
    params
        .distinguished_name
        .push(rcgen::DnType::CommonName, "cangate dashboard test");
    let cert = params.self_signed(&key).unwrap();
    let (cert_file, key_file) = (dir.join("server.pem"), dir.join("server.key"));
    std::fs::write(&cert_file, cert.pem()).unwrap();
    std::fs::write(&key_file, key.serialize_pem()).unwrap();
    let server = {
        let mut c = Config::demo();
        c.security.tls = Config::from_toml(&format!(
            "[security.tls]\ncert = \"{}\"\nkey = \"{}\"\n[[bus]]\nname = \"x\"\nbackend = \"virtual\"\n",
            cert_file.display(),
            key_file.display()
        ))
        .expect("TLS configuration is valid")
        .security
        .tls;
        c.listen = "127.0.0.1:0".parse().unwrap();
        cangate_server::start(&c).await.expect("server starts")
    };
    let url = format!("https://127.0.0.1:{}/", server.addr.port());
    let steps = drive(
        &[
            "tls".into(),
            url,
            screenshots().display().to_string(),
            cert_file.display().to_string(),
        ],
        |need| async move { unexpected(need) },
    )
    .await;
    // The axes the page lists are the gateway's, in its order.
    let c = cangate_client::connect_with(
        &format!("https://127.0.0.1:{}", server.addr.port()),
        &ConnectOptions {
            ca: Some(cert_file.clone()),
            tls_domain: Some("localhost".into()),
            ..Default::default()
        },
    )
    .await
    .expect("a TLS client trusting the certificate connects");
    let axes: Vec<String> = c
        .axes_client()
        .list_axes(pb::ListAxesRequest {})
        .await
        .expect("ListAxes")
        .into_inner()
        .axes
        .iter()
        .map(|a| format!("{:?}", a.name))
        .collect();
    assert_eq!(
        steps,
        [
            format!("tls-axes [{}] protocol=h2", axes.join(",")),
            "no-console-errors".into(),
        ]
    );
    assert!(screenshots().join("tls.png").exists());
    server.shutdown();
    let _ = std::fs::remove_dir_all(&dir);
}

/// The page stays light: one script and one style sheet, no framework, a
/// bound on their size that a new dependency would break (today about
/// 200 KB of script, 63 KB gzipped, most of it the protobuf runtime and
/// the generated messages; the charts are the page's own canvas drawing).
#[test]
fn the_page_stays_light() {
    let dist = repo().join("web/dist");
    let size = |f: &str| std::fs::metadata(dist.join(f)).map(|m| m.len()).unwrap();
    let (js, css) = (size("app.js"), size("app.css"));
    assert!(js < 220_000, "web/dist/app.js is {js} bytes");
    assert!(css < 20_000, "web/dist/app.css is {css} bytes");
}
