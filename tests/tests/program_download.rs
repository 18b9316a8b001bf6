//! Program download (CiA 302-3) end to end: `Canopen.DownloadProgram` of
//! the real server on the virtual bus, driven by the real client, into
//! simulated nodes (which serve 0x1F50/51/56/57 with a flash delay and
//! faults armed through `Simulator.SetProgramFaults`).
//!
//! A 256 KiB image with a monotonic and complete progress stream, the
//! node's boot-up and its new identification (the image's CRC-32); a
//! flash error, an abort at byte N and a start without boot-up, each typed;
//! a cancelled download (the abort on the bus, the program left stopped)
//! followed by a good one; two downloads at once; unknown bus and node; a
//! viewer refused; a request above max_message_bytes accepted.

use cangate_client::{Error, NodeId, ProgramOptions, pb};
use cangate_sim::program::{INITIAL_IDENTIFICATION, crc32, test_image};
use cangate_tests::*;
use futures::StreamExt;
use std::time::{Duration, Instant};
use tonic::Code;

/// Node 5 and 6 on `can0` (fast virtual bus), node 7 on `slow` (1 Mbit/s
/// bit timing: a download takes long enough to be interrupted).
const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[bus]]
name = "slow"
backend = "virtual"
bitrate = 1000000
bit_timing = true

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

[[canopen]]
bus = "slow"

[[canopen.node]]
id = 7
eds = "builtin:io"
simulate = true
heartbeat_timeout_ms = 2000
"#;

type Sim = pb::simulator_client::SimulatorClient<cangate_client::Transport>;

fn node(n: u32) -> NodeId {
    NodeId::new(n).unwrap()
}

async fn read_u32(c: &cangate_client::Client, bus: &str, node: u32, index: u32) -> u32 {
    let r = c
        .canopen_client()
        .read_sdo(pb::ReadSdoRequest {
            bus: bus.into(),
            node,
            index,
            subindex: 1,
            ..Default::default()
        })
        .await
        .expect("ReadSdo")
        .into_inner();
    let mut b = [0u8; 4];
    b[..r.raw.len().min(4)].copy_from_slice(&r.raw[..r.raw.len().min(4)]);
    u32::from_le_bytes(b)
}

async fn faults(sim: &mut Sim, bus: &str, node: u32, f: pb::SetProgramFaultsRequest) {
    sim.set_program_faults(pb::SetProgramFaultsRequest {
        bus: bus.into(),
        node,
        ..f
    })
    .await
    .expect("SetProgramFaults");
}

/// Runs a download to its end, checking the stream's shape; the outcome
/// or the error, and every message.
async fn download(
    c: &cangate_client::Client,
    bus: &str,
    n: u32,
    img: Vec<u8>,
    opts: &ProgramOptions,
) -> (
    Result<pb::DownloadProgramOutcome, Error>,
    Vec<pb::DownloadProgramProgress>,
) {
    let mut seen = Vec::new();
    let r = tokio::time::timeout(
        WAIT * 3,
        c.canopen(bus)
            .download_program_with(node(n), img, opts, |m| seen.push(*m)),
    )
    .await
    .expect("the download ends in time");
    (r, seen)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_256_kib_image_is_downloaded_and_the_node_boots_with_it() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut events = node_events(&c, vec![5]).await;
    let img = test_image(256 * 1024, 7);
    let want = crc32(&img);
    assert_eq!(
        read_u32(&c, "can0", 5, 0x1F56).await,
        INITIAL_IDENTIFICATION
    );
    let opts = ProgramOptions {
        expected_identification: Some(want),
        ..Default::default()
    };
    let t0 = Instant::now();
    let (r, seen) = download(&c, "can0", 5, img.clone(), &opts).await;
    let o = r.expect("the download succeeds");
    let took = t0.elapsed();
    assert_eq!(o.old_identification, Some(INITIAL_IDENTIFICATION));
    assert_eq!(o.new_identification, want);
    assert_eq!(o.bytes, img.len() as u64);
    assert!(o.data_bytes_per_second > 0.0);
    assert!(o.duration_ms >= o.data_duration_ms);
    assert!(o.duration_ms as u128 <= took.as_millis() + 1);

    // The stream: steps in order, bytes never decreasing, complete.
    use pb::ProgramStep as S;
    let steps: Vec<i32> = seen.iter().map(|m| m.step).collect();
    assert!(steps.windows(2).all(|w| w[0] <= w[1]), "{steps:?}");
    let mut distinct = steps.clone();
    distinct.dedup();
    assert_eq!(
        distinct,
        [
            S::ReadIdentificationBefore,
            S::StopProgram,
            S::DownloadData,
            S::WaitFlash,
            S::StartProgram,
            S::WaitBootUp,
            S::ReadIdentificationAfter
        ]
        .map(|s| s as i32)
    );
    let bytes: Vec<u64> = seen.iter().map(|m| m.bytes_done).collect();
    assert!(bytes.windows(2).all(|w| w[0] <= w[1]), "{bytes:?}");
    assert!(seen.iter().all(|m| m.bytes_total == img.len() as u64));
    let last = seen.last().unwrap();
    assert_eq!(last.bytes_done, img.len() as u64);
    assert!(last.outcome.is_some());
    assert_eq!(seen.iter().filter(|m| m.outcome.is_some()).count(), 1);

    // The node booted, and reports the new program, running.
    let t0 = Instant::now();
    loop {
        let ev = tokio::time::timeout(WAIT.saturating_sub(t0.elapsed()), events.message())
            .await
            .expect("the boot-up event")
            .unwrap()
            .unwrap();
        if matches!(ev.event, Some(pb::node_event::Event::BootUp(_))) {
            break;
        }
    }
    assert_eq!(read_u32(&c, "can0", 5, 0x1F56).await, want);
    assert_eq!(read_u32(&c, "can0", 5, 0x1F51).await, 1);
    assert_eq!(read_u32(&c, "can0", 5, 0x1F57).await, 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn failures_are_typed_and_name_their_step() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut sim = pb::simulator_client::SimulatorClient::new(c.channel());
    let img = test_image(20_000, 3);

    // A flash error: ABORTED, PROGRAM_FLASH_ERROR, the CiA 302-3 name.
    faults(
        &mut sim,
        "can0",
        5,
        pb::SetProgramFaultsRequest {
            flash_error: 5,
            ..Default::default()
        },
    )
    .await;
    let (r, _) = download(&c, "can0", 5, img.clone(), &Default::default()).await;
    let e = r.unwrap_err();
    assert_eq!(e.code(), Some(Code::Aborted), "{e}");
    assert_eq!(e.reason().as_deref(), Some("PROGRAM_FLASH_ERROR"), "{e}");
    assert!(e.to_string().contains("flash write error"), "{e}");
    let meta = cangate_client::error_metadata(&e);
    assert_eq!(meta["flash_error"], "5");
    assert_eq!(meta["step"], "wait-flash");
    // The program is not valid: 0x1F51 reads 3 (stopped, no program).
    assert_eq!(read_u32(&c, "can0", 5, 0x1F51).await, 3);

    // An abort by the node at byte 10 000: the SDO abort, typed.
    faults(
        &mut sim,
        "can0",
        5,
        pb::SetProgramFaultsRequest {
            abort_at_byte: Some(10_000),
            abort_code: 0x0606_0000,
            ..Default::default()
        },
    )
    .await;
    let (r, seen) = download(&c, "can0", 5, img.clone(), &Default::default()).await;
    let e = r.unwrap_err();
    match &e {
        Error::SdoAbort {
            node,
            index,
            subindex,
            code,
            by_node,
            ..
        } => {
            assert_eq!((*node, *index, *subindex), (5, 0x1F50, 1));
            assert_eq!(*code, 0x0606_0000);
            assert!(by_node);
        }
        other => panic!("not an SDO abort: {other:?}"),
    }
    // The gateway's message names the step (the client's line is its own).
    let message = e.status().unwrap().message();
    assert!(
        message.contains("downloading the program data"),
        "{message}"
    );
    assert_eq!(cangate_client::error_metadata(&e)["step"], "download-data");
    assert!(seen.iter().all(|m| m.bytes_done < img.len() as u64));

    // A start without boot-up: DEADLINE_EXCEEDED, PROGRAM_NO_BOOT_UP.
    faults(
        &mut sim,
        "can0",
        5,
        pb::SetProgramFaultsRequest {
            no_boot: true,
            ..Default::default()
        },
    )
    .await;
    let opts = ProgramOptions {
        boot_timeout: Some(Duration::from_millis(500)),
        ..Default::default()
    };
    let (r, _) = download(&c, "can0", 5, img.clone(), &opts).await;
    let e = r.unwrap_err();
    assert!(matches!(e, Error::Timeout { .. }), "{e:?}");
    assert_eq!(e.reason().as_deref(), Some("PROGRAM_NO_BOOT_UP"), "{e}");

    // The expected identification differs.
    let opts = ProgramOptions {
        expected_identification: Some(0x1234_5678),
        ..Default::default()
    };
    let (r, _) = download(&c, "can0", 5, img.clone(), &opts).await;
    let e = r.unwrap_err();
    assert_eq!(
        e.reason().as_deref(),
        Some("PROGRAM_IDENTIFICATION_MISMATCH"),
        "{e}"
    );
    assert_eq!(
        cangate_client::error_metadata(&e)["found"],
        format!("0x{:08X}", crc32(&img))
    );

    // After all of these, a good download.
    let (r, _) = download(&c, "can0", 5, img.clone(), &Default::default()).await;
    assert_eq!(r.unwrap().new_identification, crc32(&img));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cancelled_download_stops_on_the_bus_and_a_new_one_works() {
    let server = start_server(CONFIG).await;
    let mut c = client(&server).await;
    let (mut frames, mut pending) = open_stream(
        &mut c,
        pb::StreamFramesRequest {
            include_transmitted: true,
            ..stream_request(
                "slow",
                vec![pb::FrameFilter {
                    id: 0x607,
                    mask: 0x7FF,
                    ..Default::default()
                }],
            )
        },
    )
    .await;
    // 64 KiB at 1 Mbit/s: over a second of data.
    let img = test_image(64 * 1024, 11);
    let mut s = c
        .canopen("slow")
        .download_program(node(7), img.clone(), &Default::default())
        .await
        .expect("the download starts");
    // A second download to the same node meanwhile is refused.
    let e = c
        .canopen("slow")
        .download_program_with(node(7), vec![1, 2, 3], &Default::default(), |_| {})
        .await
        .unwrap_err();
    assert_eq!(e.code(), Some(Code::FailedPrecondition), "{e}");
    assert_eq!(e.reason().as_deref(), Some("PROGRAM_DOWNLOAD_RUNNING"));
    assert!(e.to_string().contains("already running"), "{e}");
    // Cancel once the node confirmed some data.
    let t0 = Instant::now();
    loop {
        let m = tokio::time::timeout(WAIT, s.next())
            .await
            .expect("progress in time")
            .expect("stream open")
            .expect("no error");
        if m.step == pb::ProgramStep::DownloadData as i32 && m.bytes_done > 0 {
            assert!(m.bytes_done < img.len() as u64, "cancel before the end");
            break;
        }
        assert!(t0.elapsed() < WAIT);
    }
    drop(s);
    // The gateway aborts the block download on the bus (0x80 0x50 0x1F 01).
    let t0 = Instant::now();
    'abort: loop {
        let got = read_frames(&mut frames, &mut pending, 1).await;
        for f in got {
            if f.data.len() == 8 && f.data[..4] == [0x80, 0x50, 0x1F, 0x01] {
                break 'abort;
            }
        }
        assert!(t0.elapsed() < WAIT, "no abort of 0x1F50 on the bus");
    }
    // No transfer left, the program stopped (not running a half image).
    let transfers = c
        .canopen_client()
        .list_sdo_transfers(pb::ListSdoTransfersRequest { bus: "slow".into() })
        .await
        .unwrap()
        .into_inner();
    assert!(transfers.transfers.is_empty(), "{transfers:?}");
    assert_eq!(read_u32(&c, "slow", 7, 0x1F51).await, 0);
    assert_eq!(
        read_u32(&c, "slow", 7, 0x1F56).await,
        INITIAL_IDENTIFICATION
    );
    // A new download goes through.
    let small = test_image(4096, 5);
    let (r, _) = download(&c, "slow", 7, small.clone(), &Default::default()).await;
    let o = r.expect("the download after the cancel succeeds");
    assert_eq!(o.new_identification, crc32(&small));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn downloads_to_two_nodes_run_side_by_side() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let (a, b) = (test_image(30_000, 1), test_image(30_000, 2));
    let opts = ProgramOptions::default();
    let ((ra, _), (rb, _)) = tokio::join!(
        download(&c, "can0", 5, a.clone(), &opts),
        download(&c, "can0", 6, b.clone(), &opts),
    );
    assert_eq!(ra.unwrap().new_identification, crc32(&a));
    assert_eq!(rb.unwrap().new_identification, crc32(&b));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unknown_bus_or_node_and_bad_requests_are_refused() {
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let e = c
        .canopen("nope")
        .download_program(node(5), vec![1], &Default::default())
        .await
        .err()
        .expect("refused");
    assert!(
        matches!(&e, Error::NotFound { kind, .. } if kind == "bus"),
        "{e:?}"
    );
    let e = c
        .canopen("can0")
        .download_program(node(99), vec![1], &Default::default())
        .await
        .err()
        .expect("refused");
    assert!(
        matches!(&e, Error::NotFound { kind, .. } if kind == "node"),
        "{e:?}"
    );
    let e = c
        .canopen("can0")
        .download_program(node(5), Vec::new(), &Default::default())
        .await
        .err()
        .expect("refused");
    assert_eq!(e.code(), Some(Code::InvalidArgument), "{e:?}");
    // A request above max_message_bytes (4 MiB by default) still reaches
    // the service: the image plus the other fields.
    let e = c
        .canopen("can0")
        .download_program(node(99), vec![0; 4 * 1024 * 1024], &Default::default())
        .await
        .err()
        .expect("refused");
    assert!(
        matches!(&e, Error::NotFound { kind, .. } if kind == "node"),
        "{e:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_viewer_may_not_download_a_program() {
    let tokens: String = [("wall", "viewer", "v-token"), ("pc", "engineer", "e-token")]
        .iter()
        .map(|(name, role, token)| {
            format!(
                "[[security.tokens]]\nname = \"{name}\"\nrole = \"{role}\"\nsha256 = \"{}\"\n",
                cangate_client::hash_token(token)
            )
        })
        .collect();
    let server = start_server(&format!("{tokens}{CONFIG}")).await;
    let with = |token: &'static str| {
        let addr = server.addr;
        async move {
            cangate_client::connect_with(
                &format!("http://{addr}"),
                &cangate_client::ConnectOptions {
                    token: Some(token.into()),
                    ..Default::default()
                },
            )
            .await
            .unwrap()
        }
    };
    let viewer = with("v-token").await;
    let e = viewer
        .canopen("can0")
        .download_program(node(5), vec![1, 2, 3], &Default::default())
        .await
        .err()
        .expect("refused");
    assert_eq!(e.code(), Some(Code::PermissionDenied), "{e:?}");
    assert!(e.to_string().contains("engineer"), "{e}");
    let engineer = with("e-token").await;
    let img = test_image(2000, 9);
    let o = engineer
        .canopen("can0")
        .download_program_with(node(5), img.clone(), &Default::default(), |_| {})
        .await
        .expect("an engineer may");
    assert_eq!(o.new_identification, crc32(&img));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn after_an_abort_by_the_node_the_next_download_works_at_once() {
    // On the timed bus the rest of the sub-block is still on its way when
    // the node aborts; the node answers those segments as new requests.
    // Those answers must not fail the next download.
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let mut sim = pb::simulator_client::SimulatorClient::new(c.channel());
    let img = test_image(20_000, 21);
    for _ in 0..2 {
        faults(
            &mut sim,
            "slow",
            7,
            pb::SetProgramFaultsRequest {
                abort_at_byte: Some(2_000),
                ..Default::default()
            },
        )
        .await;
        let (r, _) = download(&c, "slow", 7, img.clone(), &Default::default()).await;
        assert!(
            matches!(
                r,
                Err(Error::SdoAbort {
                    code: 0x0606_0000,
                    ..
                })
            ),
            "{r:?}"
        );
        let (r, _) = download(&c, "slow", 7, img.clone(), &Default::default()).await;
        assert_eq!(
            r.expect("the next download").new_identification,
            crc32(&img)
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_4_mib_image_passes_the_message_limit_and_is_downloaded() {
    // 4 MiB of image plus the request's other fields is above the default
    // max_message_bytes (4 MiB): DownloadProgram may carry it.
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    let img = test_image(4 * 1024 * 1024, 44);
    let (r, seen) = download(&c, "can0", 6, img.clone(), &Default::default()).await;
    let o = r.expect("the 4 MiB download succeeds");
    assert_eq!(o.bytes, img.len() as u64);
    assert_eq!(o.new_identification, crc32(&img));
    assert_eq!(seen.last().unwrap().bytes_done, img.len() as u64);
}

/// Node 3 drives axis X.
const AXIS_CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"
sdo_timeout_ms = 200

[[canopen.node]]
id = 3
eds = "builtin:drive"
simulate = true

[[axis]]
name = "X"
bus = "can0"
node = 3
counts_per_unit = 1000.0
max_velocity = 50.0
max_acceleration = 500.0
process_data = "sdo"
sdo_poll_ms = 5
"#;

/// A program download to the drive of an enabled axis is refused before
/// anything is sent (FAILED_PRECONDITION, AXIS_ACTIVE, naming the axis),
/// and so is program control by SDO (stop, start, clear: 0x1F51); once
/// the axis is disabled the download runs.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_download_to_an_enabled_axis_drive_is_refused() {
    use cangate_tests::axes::*;
    let server = start_server(AXIS_CONFIG).await;
    let c = client(&server).await;
    let mut axes = c.axes_client();
    wait_status(&mut axes, "X", |s| s.state != 0 && !s.node_lost).await;
    let lease = acquire(&mut axes, &["X"], 10_000, "test").await;
    enable(&mut axes, "X", &lease).await;
    let mut control = c.canopen_client();

    let img = test_image(4_000, 1);
    let (r, seen) = download(&c, "can0", 3, img.clone(), &ProgramOptions::default()).await;
    match r {
        Err(Error::Refused {
            code,
            reason,
            message,
            ..
        }) => {
            assert_eq!(code, Code::FailedPrecondition);
            assert_eq!(reason, "AXIS_ACTIVE");
            assert!(message.contains("axis X"), "{message}");
        }
        other => panic!("not refused: {other:?}"),
    }
    assert!(seen.is_empty(), "{seen:?}");
    for control_value in [0u8, 1, 3] {
        let e = control
            .write_sdo(pb::WriteSdoRequest {
                bus: "can0".into(),
                node: 3,
                index: 0x1F51,
                subindex: 1,
                data: Some(pb::write_sdo_request::Data::Raw(vec![control_value])),
                ..Default::default()
            })
            .await
            .unwrap_err();
        assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
        assert!(e.message().contains("axis X"), "{}", e.message());
    }
    // The drive's program still runs.
    assert_eq!(read_u32(&c, "can0", 3, 0x1F51).await, 1);
    let s = wait_status(&mut axes, "X", |_| true).await;
    assert_eq!(s.state, pb::DriveState::OperationEnabled as i32, "{s:?}");

    let r = axes
        .disable(cmd("X", &lease, true))
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    let (r, _) = download(&c, "can0", 3, img, &ProgramOptions::default()).await;
    r.expect("a disabled axis's drive takes a program");
}
