//! A node's PDOs, the SYNC and the TIME changed while the gateway runs,
//! end to end on the virtual bus with the real client:
//!
//! - ReadPdoConfig shows what the boot procedure wrote; ConfigurePdo
//!   remaps TPDO1 to another COB-ID and other objects (one by EDS name),
//!   and StreamPdo decodes the new layout at once while the old COB-ID
//!   goes quiet; a disabled TPDO stops; a remapped RPDO changes what
//!   WritePdo accepts; a node's refusal names the parameter object; bad
//!   requests are refused before anything is written; an axis's drive is
//!   refused.
//! - SetSync starts a stopped SYNC with a counter (the frames carry
//!   1..=N), drops the counter, stops; a moving cyclic axis vetoes a stop
//!   and a new period, and a still one does not; without a SYNC a cyclic
//!   axis refuses moves but takes stops.
//! - SetTime sends the host's time as a TIME_OF_DAY on 0x100 (decoded
//!   and compared with the clock), periodically, and stops.

use cangate_client::pb;
use cangate_client::{Error, NodeId};
use cangate_tests::axes::{acquire, cmd, enable, opts, wait_ready, wait_status};
use cangate_tests::*;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

const PDO_CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"
[[canopen]]
bus = "can0"
[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true
boot = true
[[canopen.node.tpdo]]
num = 1
transmission_type = 255
event_timer_ms = 20
mapping = ["6041:0:16", "6064:0:32"]
[[canopen.node.rpdo]]
num = 1
mapping = ["6040:0:16", "607A:0:32"]
[[canopen.node]]
id = 2
eds = "builtin:drive"
simulate = true
heartbeat_timeout_ms = 2000
[[axis]]
name = "A"
bus = "can0"
node = 2
counts_per_unit = 1000.0
max_velocity = 10.0
max_acceleration = 100.0
"#;

/// The status of a refused call.
#[track_caller]
fn refusal<T: std::fmt::Debug>(r: Result<T, Error>) -> tonic::Status {
    match r {
        Err(e) => e
            .status()
            .cloned()
            .unwrap_or_else(|| panic!("no status: {e:?}")),
        Ok(v) => panic!("expected a refusal, got {v:?}"),
    }
}

fn node(n: u32) -> NodeId {
    NodeId::new(n).unwrap()
}

fn mapped(index: u32, subindex: u32, bits: u32) -> pb::PdoMappedObject {
    pb::PdoMappedObject {
        index,
        subindex,
        bits,
        ..Default::default()
    }
}

fn layout(p: &pb::PdoConfiguration) -> Vec<(u32, u32, u32)> {
    p.mapping
        .iter()
        .map(|m| (m.index, m.subindex, m.bits))
        .collect()
}

/// The next decoded TPDO of node 1 on `cob_id`, skipping others.
async fn next_pdo(s: &mut tonic::Streaming<pb::PdoMessage>, cob_id: u32) -> pb::PdoMessage {
    tokio::time::timeout(WAIT, async {
        loop {
            let m = s.message().await.unwrap().expect("stream open");
            if m.cob_id == cob_id {
                return m;
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("no TPDO on 0x{cob_id:X} in time"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pdos_are_remapped_at_run_time_and_decoded_at_once() {
    let server = start_server(PDO_CONFIG).await;
    let c = client(&server).await;
    let co = c.canopen("can0");
    let mut pdos = c
        .canopen_client()
        .stream_pdo(pb::StreamPdoRequest {
            bus: "can0".into(),
            nodes: vec![1],
        })
        .await
        .unwrap()
        .into_inner();
    // Booted: the configured TPDO1 flows.
    let first = next_pdo(&mut pdos, 0x181).await;
    assert_eq!(first.values.len(), 2);

    // What the boot procedure wrote, read back from the node.
    let tpdo1 = co
        .pdo_config(node(1), Some(pb::PdoKind::Tpdo), 1)
        .await
        .unwrap();
    assert_eq!(tpdo1.len(), 1);
    let t = &tpdo1[0];
    assert_eq!(
        (t.cob_id, t.enabled, t.transmission_type, t.event_timer_ms),
        (0x181, true, 255, 20)
    );
    assert_eq!(layout(t), vec![(0x6041, 0, 16), (0x6064, 0, 32)]);
    assert_eq!(t.mapping[0].name, "Statusword");
    // Without a number: every PDO of the EDS, RPDOs first.
    let all = co.pdo_config(node(1), None, 0).await.unwrap();
    let kinds: Vec<(i32, u32)> = all.iter().map(|p| (p.kind, p.pdo)).collect();
    assert_eq!(
        kinds,
        vec![
            (pb::PdoKind::Rpdo as i32, 1),
            (pb::PdoKind::Rpdo as i32, 2),
            // The target torque's, not valid until a torque axis maps it.
            (pb::PdoKind::Rpdo as i32, 3),
            (pb::PdoKind::Tpdo as i32, 1),
            (pb::PdoKind::Tpdo as i32, 2),
            // Free for the drive's signals (not valid by default).
            (pb::PdoKind::Tpdo as i32, 3),
            (pb::PdoKind::Tpdo as i32, 4)
        ]
    );

    // Remapped: another COB-ID, the statusword (length from the EDS) and
    // an object given by its EDS name.
    let r = co
        .configure_pdo(
            node(1),
            pb::PdoConfiguration {
                kind: pb::PdoKind::Tpdo as i32,
                pdo: 1,
                cob_id: 0x1A1,
                enabled: true,
                transmission_type: 255,
                event_timer_ms: 10,
                mapping: vec![
                    mapped(0x6041, 0, 0),
                    pb::PdoMappedObject {
                        object: "Modes of operation display".into(),
                        ..Default::default()
                    },
                ],
                ..Default::default()
            },
        )
        .await
        .unwrap();
    let applied = r.pdo.unwrap();
    assert_eq!(layout(&applied), vec![(0x6041, 0, 16), (0x6061, 0, 8)]);
    assert_eq!(
        r.writes.first().map(String::as_str),
        Some("0x1800:01 = A1 01 00 80"),
        "first the PDO is made invalid: {:?}",
        r.writes
    );
    assert_eq!(
        r.writes.last().map(String::as_str),
        Some("0x1800:01 = A1 01 00 00")
    );
    // Decoded with the new layout at once; the old COB-ID is gone.
    let m = next_pdo(&mut pdos, 0x1A1).await;
    let names: Vec<&str> = m.values.iter().map(|v| v.name.as_str()).collect();
    assert_eq!(names, ["Statusword", "Modes of operation display"]);
    assert_eq!(m.pdo, 1);
    for _ in 0..10 {
        let m = next_pdo(&mut pdos, 0x1A1).await;
        assert_eq!(m.values.len(), 2);
    }
    let read = co
        .pdo_config(node(1), Some(pb::PdoKind::Tpdo), 1)
        .await
        .unwrap();
    assert_eq!(
        (read[0].cob_id, read[0].event_timer_ms, layout(&read[0])),
        (0x1A1, 10, vec![(0x6041, 0, 16), (0x6061, 0, 8)])
    );

    // Disabled: nothing more is decoded.
    let mut off = read[0].clone();
    off.enabled = false;
    co.configure_pdo(node(1), off).await.unwrap();
    let quiet = tokio::time::timeout(Duration::from_millis(300), async {
        loop {
            let m = pdos.message().await.unwrap().unwrap();
            // PDOs already queued before the change may still come.
            if m.cob_id == 0x1A1 {
                continue;
            }
            return m;
        }
    })
    .await;
    assert!(
        quiet.is_err(),
        "a disabled TPDO is still decoded: {quiet:?}"
    );
    let read = co
        .pdo_config(node(1), Some(pb::PdoKind::Tpdo), 1)
        .await
        .unwrap();
    assert!(!read[0].enabled);

    // RPDO1 remapped to the controlword alone: WritePdo follows.
    co.configure_pdo(
        node(1),
        pb::PdoConfiguration {
            kind: pb::PdoKind::Rpdo as i32,
            pdo: 1,
            enabled: true,
            transmission_type: 255,
            mapping: vec![mapped(0x6040, 0, 16)],
            ..Default::default()
        },
    )
    .await
    .unwrap();
    let write = |values: Vec<(u32, pb::DataType, pb::value::Value)>| {
        let mut pdo = c.canopen_client();
        async move {
            pdo.write_pdo(pb::WritePdoRequest {
                bus: "can0".into(),
                node: 1,
                pdo: 1,
                values: values
                    .into_iter()
                    .map(|(index, ty, v)| pb::PdoValue {
                        index,
                        subindex: 0,
                        name: String::new(),
                        value: Some(pb::Value {
                            r#type: ty as i32,
                            value: Some(v),
                        }),
                    })
                    .collect(),
            })
            .await
        }
    };
    let controlword = (
        0x6040,
        pb::DataType::Unsigned16,
        pb::value::Value::UintValue(6),
    );
    let sent = write(vec![controlword.clone()]).await.unwrap().into_inner();
    assert_eq!(sent.data, vec![6, 0]);
    let refused = write(vec![
        controlword,
        (
            0x607A,
            pb::DataType::Integer32,
            pb::value::Value::IntValue(1),
        ),
    ])
    .await
    .unwrap_err();
    assert_eq!(refused.code(), tonic::Code::InvalidArgument);
    assert!(
        refused.message().contains("does not map 0x607A"),
        "{refused:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_pdo_configurations_are_refused_with_the_object_that_failed() {
    let server = start_server(PDO_CONFIG).await;
    let c = client(&server).await;
    let co = c.canopen("can0");
    let tpdo = |mapping: Vec<pb::PdoMappedObject>| pb::PdoConfiguration {
        kind: pb::PdoKind::Tpdo as i32,
        pdo: 2,
        enabled: true,
        transmission_type: 1,
        mapping,
        ..Default::default()
    };
    let refused = |r: Result<pb::ConfigurePdoResponse, Error>| refusal(r);

    // Refused by the gateway before anything is written.
    let s = refused(
        co.configure_pdo(node(1), tpdo(vec![mapped(0x6064, 0, 32); 3]))
            .await,
    );
    assert_eq!(s.code(), tonic::Code::InvalidArgument);
    assert!(s.message().contains("96 bits"), "{s:?}");
    let s = refused(
        co.configure_pdo(node(1), tpdo(vec![mapped(0x1000, 0, 0)]))
            .await,
    );
    assert_eq!(s.code(), tonic::Code::InvalidArgument);
    assert!(s.message().contains("not PDO-mappable"), "{s:?}");
    let s = refused(
        co.configure_pdo(
            node(1),
            tpdo(vec![pb::PdoMappedObject {
                object: "No such object".into(),
                ..Default::default()
            }]),
        )
        .await,
    );
    assert_eq!(s.code(), tonic::Code::InvalidArgument);
    let mut reserved = tpdo(vec![]);
    reserved.transmission_type = 245;
    let s = refused(co.configure_pdo(node(1), reserved).await);
    assert!(s.message().contains("reserved"), "{s:?}");
    let mut no_cob = tpdo(vec![]);
    no_cob.pdo = 9;
    let s = refused(co.configure_pdo(node(1), no_cob).await);
    assert!(s.message().contains("no predefined COB-ID"), "{s:?}");
    let mut wide = tpdo(vec![]);
    wide.cob_id = 0x800;
    let s = refused(co.configure_pdo(node(1), wide).await);
    assert!(s.message().contains("11-bit"), "{s:?}");
    let s = refused(
        co.configure_pdo(node(1), pb::PdoConfiguration::default())
            .await,
    );
    assert_eq!(s.code(), tonic::Code::InvalidArgument);

    // Refused by the node: the object named, the SDO abort's details
    // kept, and the PDO left invalid (its first write went through).
    let s = refused(
        co.configure_pdo(node(1), tpdo(vec![mapped(0x2FFF, 0, 16)]))
            .await,
    );
    assert!(
        s.message().contains("0x1A01:01 (mapping entry 1)"),
        "the failing object is named: {s:?}"
    );
    let e = co
        .configure_pdo(node(1), tpdo(vec![mapped(0x2FFF, 0, 16)]))
        .await
        .unwrap_err();
    assert!(
        matches!(
            e,
            Error::SdoAbort {
                node: 1,
                index: 0x1A01,
                subindex: 1,
                by_node: true,
                ..
            }
        ),
        "the client decodes the abort: {e:?}"
    );
    let read = co
        .pdo_config(node(1), Some(pb::PdoKind::Tpdo), 2)
        .await
        .unwrap();
    assert!(!read[0].enabled, "left invalid after the failure");

    // An axis's drive: its PDOs are the axis's.
    let s = refused(
        co.configure_pdo(node(2), tpdo(vec![mapped(0x6041, 0, 16)]))
            .await,
    );
    assert_eq!(s.code(), tonic::Code::FailedPrecondition);
    assert!(s.message().contains("axis"), "{s:?}");
    // A node nobody knows.
    let s = refused(co.configure_pdo(node(99), tpdo(vec![])).await);
    assert_eq!(s.code(), tonic::Code::NotFound);
}

const SYNC_CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"
[[canopen]]
bus = "can0"
"#;

fn frames_of(id: u32) -> pb::StreamFramesRequest {
    let mut r = stream_request(
        "can0",
        vec![pb::FrameFilter {
            id,
            mask: 0x7FF,
            format: pb::IdFormat::Standard as i32,
            invert: false,
        }],
    );
    r.include_transmitted = true;
    r
}

/// The data of the next `n` frames of a stream.
async fn next_data(
    s: &mut tonic::Streaming<pb::StreamFramesResponse>,
    pending: &mut Vec<pb::StreamEvent>,
    n: usize,
) -> Vec<Vec<u8>> {
    read_frames(s, pending, n)
        .await
        .into_iter()
        .take(n)
        .map(|f| f.data)
        .collect()
}

/// Frames that arrive within `d` (for the tail after a change).
async fn drain(s: &mut tonic::Streaming<pb::StreamFramesResponse>, d: Duration) {
    let _ = tokio::time::timeout(d, async {
        while let Some(Ok(Some(_))) = Some(s.message().await) {}
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_sync_is_started_with_a_counter_changed_and_stopped() {
    let server = start_server(SYNC_CONFIG).await;
    let mut c = client(&server).await;
    let co = c.canopen("can0");
    let s = co.sync_status().await.unwrap();
    assert!(!s.running, "no sync_period_us: stopped");
    assert_eq!((s.period_us, s.counter_overflow, s.sent), (10_000, 0, 0));
    let (mut syncs, mut pending) = open_stream(&mut c, frames_of(0x080)).await;
    assert_quiet(&mut syncs).await;

    let s = co
        .set_sync(Some(true), Some(Duration::from_millis(2)), Some(4))
        .await
        .unwrap();
    assert!(s.running);
    assert_eq!((s.period_us, s.counter_overflow), (2000, 4));
    // The counter runs 1..=4 and wraps to 1 (CiA 301 0x1019).
    let data = next_data(&mut syncs, &mut pending, 10).await;
    assert_eq!(data[0], vec![1], "the counter starts at 1: {data:?}");
    for pair in data.windows(2) {
        let (a, b) = (pair[0][0], pair[1][0]);
        assert_eq!(b, if a == 4 { 1 } else { a + 1 }, "{data:?}");
    }

    // Without a counter: SYNCs without data.
    co.set_sync(None, None, Some(0)).await.unwrap();
    tokio::time::timeout(WAIT, async {
        loop {
            if next_data(&mut syncs, &mut pending, 1).await[0].is_empty() {
                return;
            }
        }
    })
    .await
    .expect("SYNCs without data");

    // Stopped: the count stands still, the bus is quiet.
    let s = co.set_sync(Some(false), None, None).await.unwrap();
    assert!(!s.running);
    pending.clear();
    drain(&mut syncs, Duration::from_millis(100)).await;
    let sent = co.sync_status().await.unwrap().sent;
    assert_quiet(&mut syncs).await;
    assert_eq!(co.sync_status().await.unwrap().sent, sent);

    // Out of range.
    for (period, counter) in [
        (Some(Duration::from_micros(50)), None),
        (None, Some(1)),
        (None, Some(241)),
    ] {
        let status = refusal(co.set_sync(None, period, counter).await);
        assert_eq!(status.code(), tonic::Code::InvalidArgument, "{status:?}");
    }
}

const CYCLIC_CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"
[[canopen]]
bus = "can0"
sync_period_us = 2000
[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true
heartbeat_timeout_ms = 2000
[[axis]]
name = "X"
bus = "can0"
node = 1
counts_per_unit = 1000.0
position_mode = "cyclic"
min_position = -500.0
max_position = 500.0
max_velocity = 20.0
max_acceleration = 100.0
"#;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_enabled_cyclic_axis_vetoes_a_sync_stop_and_a_new_period() {
    let server = start_server(CYCLIC_CONFIG).await;
    let c = client(&server).await;
    let co = c.canopen("can0");
    let mut axes = c.axes_client();
    wait_ready(&mut axes, &["X"]).await;
    let lease = acquire(&mut axes, &["X"], 10_000, "sync-test").await;
    enable(&mut axes, "X", &lease).await;
    // A long move: 200 mm at 20 mm/s.
    axes.r#move(pb::MoveRequest {
        axis: "X".into(),
        target: 200.0,
        options: opts(&lease, false),
        ..Default::default()
    })
    .await
    .expect("move starts");
    wait_status(&mut axes, "X", |a| a.velocity.abs() > 1.0).await;
    for (running, period) in [(Some(false), None), (None, Some(Duration::from_millis(4)))] {
        let status = refusal(co.set_sync(running, period, None).await);
        assert_eq!(status.code(), tonic::Code::FailedPrecondition);
        assert!(
            status.message().contains("cyclic axis X is moving"),
            "{status:?}"
        );
    }
    // A counter change does not interrupt the set-points: allowed.
    co.set_sync(None, None, Some(10)).await.unwrap();
    assert!(co.sync_status().await.unwrap().running);

    // Stopped but enabled, it still vetoes: its drive takes a set-point
    // with every SYNC.
    axes.stop(cmd("X", &lease, true)).await.expect("stop");
    wait_status(&mut axes, "X", |a| a.velocity == 0.0).await;
    let status = refusal(
        co.set_sync(None, Some(Duration::from_millis(4)), None)
            .await,
    );
    assert_eq!(status.code(), tonic::Code::FailedPrecondition);
    assert!(
        status.message().contains("cyclic axis X is enabled"),
        "{status:?}"
    );
    // Disabled, it no longer vetoes.
    let r = axes
        .disable(cmd("X", &lease, true))
        .await
        .expect("disable")
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    let s = co
        .set_sync(None, Some(Duration::from_millis(4)), None)
        .await
        .unwrap();
    assert_eq!(s.period_us, 4000);
    let s = co.set_sync(Some(false), None, None).await.unwrap();
    assert!(!s.running);

    // Without a SYNC the cyclic axis cannot be enabled (it would wait for
    // set-points for ever); a stop is never refused.
    let refused = axes.enable(cmd("X", &lease, true)).await.unwrap_err();
    assert_eq!(refused.code(), tonic::Code::FailedPrecondition);
    assert!(
        refused.message().contains("SYNC of bus can0 is stopped"),
        "{refused:?}"
    );
    axes.stop(cmd("X", &lease, false))
        .await
        .expect("a stop is taken");
    // Started again: it is enabled and moves.
    co.set_sync(Some(true), None, None).await.unwrap();
    enable(&mut axes, "X", &lease).await;
    let r = axes
        .r#move(pb::MoveRequest {
            axis: "X".into(),
            target: 1.0,
            options: opts(&lease, true),
            ..Default::default()
        })
        .await
        .expect("moves with the SYNC back")
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn time_of_day_is_sent_now_and_periodically() {
    let server = start_server(SYNC_CONFIG).await;
    let mut c = client(&server).await;
    let co = c.canopen("can0");
    let (mut times, mut pending) = open_stream(&mut c, frames_of(0x100)).await;
    let before = SystemTime::now().duration_since(UNIX_EPOCH).unwrap();
    let r = co.set_time(true, None).await.unwrap();
    let after = SystemTime::now().duration_since(UNIX_EPOCH).unwrap();
    let sent = r.sent.expect("the TIME sent");
    assert_eq!(r.time_period_ms, 0);
    let unix = Duration::from_millis(sent.unix_ms);
    assert!(
        unix + Duration::from_millis(1) >= before && unix <= after,
        "{unix:?} not within {before:?}..{after:?}"
    );
    let frame = read_frames(&mut times, &mut pending, 1).await.remove(0);
    assert_eq!(frame.data.len(), 6);
    let ms = u32::from_le_bytes(frame.data[..4].try_into().unwrap()) & 0x0FFF_FFFF;
    let days = u16::from_le_bytes(frame.data[4..].try_into().unwrap());
    assert_eq!(
        (ms, u32::from(days)),
        (sent.ms_after_midnight, sent.days_since_1984)
    );
    // 1984-01-01 + days + ms is the Unix time of the response.
    assert_eq!(
        441_763_200_000 + u64::from(days) * 86_400_000 + u64::from(ms),
        sent.unix_ms
    );

    // Every 100 ms (the shortest period), then off.
    let r = co
        .set_time(false, Some(Duration::from_millis(100)))
        .await
        .unwrap();
    assert!(r.sent.is_none());
    assert_eq!(r.time_period_ms, 100);
    assert_eq!(co.sync_status().await.unwrap().time_period_ms, 100);
    let frames = read_frames(&mut times, &mut pending, 4).await;
    let unix_ms = |d: &[u8]| {
        let ms = u32::from_le_bytes(d[..4].try_into().unwrap()) & 0x0FFF_FFFF;
        let days = u16::from_le_bytes(d[4..].try_into().unwrap());
        u64::from(days) * 86_400_000 + u64::from(ms)
    };
    for pair in frames.windows(2) {
        assert!(
            unix_ms(&pair[1].data) > unix_ms(&pair[0].data),
            "time advances"
        );
    }
    co.set_time(false, Some(Duration::ZERO)).await.unwrap();
    pending.clear();
    drain(&mut times, Duration::from_millis(100)).await;
    assert_quiet(&mut times).await;
    let status = refusal(co.set_time(false, Some(Duration::from_secs(86_401))).await);
    assert_eq!(status.code(), tonic::Code::InvalidArgument);
    // A 1 ms period would put 1,000 TIME frames a second on 0x100: refused,
    // and the producer stays off.
    let status = refusal(co.set_time(false, Some(Duration::from_millis(1))).await);
    assert_eq!(status.code(), tonic::Code::InvalidArgument);
    assert!(
        status.message().contains("at least 100 ms"),
        "{}",
        status.message()
    );
    assert_eq!(co.sync_status().await.unwrap().time_period_ms, 0);
    assert_quiet(&mut times).await;
}
