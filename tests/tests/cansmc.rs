//! The Cansmc service end to end: the real server in-process with the
//! embedded demo's CANsmc master (`smc` on the virtual buses smc0/smc1,
//! simulated slaves 1 and 2 behind axes A and B, 3 a free-running encoder,
//! 4 behind axis C geared to slave 3 at 0.5), driven by the real client.
//!
//! The machine running this may be a busy 2-core box with a debug build:
//! every wait polls until its condition holds, bounded by [`WAIT`], and
//! rates are checked with wide tolerances.

use cangate_client::pb;
use cangate_client::pb::axis_update::Update;
use cangate_client::pb::cansmc_event::Event;
use cangate_server::{Config, RunningServer};
use cangate_tests::*;
use std::time::{Duration, Instant};
use tonic::Code;

type Smc = pb::cansmc_client::CansmcClient<cangate_client::Transport>;
type Axes = pb::axes_client::AxesClient<cangate_client::Transport>;

/// The demo configuration with only its CANsmc part (the CANopen devices
/// would only load the machine), on an ephemeral port.
fn demo_smc_config() -> Config {
    let mut c = Config::demo();
    c.listen = "127.0.0.1:0".parse().unwrap();
    c.canopen.clear();
    c.axes.clear();
    c.handwheels.clear();
    c.buses.retain(|b| b.name == "smc0" || b.name == "smc1");
    assert_eq!(c.cansmc.len(), 1, "the demo has one CANsmc master");
    assert_eq!(c.cansmc[0].name, "smc");
    // A debug build on a busy machine can miss three DTs in a row (6 ms)
    // now and then: the demo's lost_after would then fault the axes under
    // test. 50 cycles (100 ms) keeps the tests about what they test.
    c.cansmc[0].lost_after = 50;
    c
}

struct Bed {
    server: RunningServer,
    smc: Smc,
    axes: Axes,
}

async fn start(config: &Config) -> Bed {
    let server = cangate_server::start(config).await.expect("server starts");
    let c = client(&server).await;
    Bed {
        smc: c.cansmc_client(),
        axes: c.axes_client(),
        server,
    }
}

/// The demo master, in P2 with every slave operational.
async fn demo() -> Bed {
    let mut bed = start(&demo_smc_config()).await;
    wait_status(
        &mut bed.smc,
        "smc",
        "P2 with four operational slaves",
        |s| {
            s.phase == pb::CansmcPhase::P2 as i32
                && s.slaves.len() == 4
                && s.slaves.iter().all(|x| x.state == operational())
        },
    )
    .await;
    bed
}

fn operational() -> i32 {
    pb::CansmcSlaveState::Operational as i32
}

async fn status(smc: &mut Smc, master: &str) -> pb::CansmcStatus {
    smc.get_status(pb::GetCansmcStatusRequest {
        master: master.into(),
    })
    .await
    .expect("GetStatus")
    .into_inner()
}

/// Polls GetStatus until `f` holds (bounded by [`WAIT`]).
async fn wait_status(
    smc: &mut Smc,
    master: &str,
    what: &str,
    mut f: impl FnMut(&pb::CansmcStatus) -> bool,
) -> pb::CansmcStatus {
    let t0 = Instant::now();
    loop {
        let s = status(smc, master).await;
        if f(&s) {
            return s;
        }
        assert!(t0.elapsed() < WAIT, "not {what} within {WAIT:?}: {s:#?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

async fn read(smc: &mut Smc, address: u32, number: u32) -> Result<i32, tonic::Status> {
    smc.read_parameter(pb::ReadParameterRequest {
        master: "smc".into(),
        address,
        number,
    })
    .await
    .map(|r| r.into_inner().value)
}

async fn write(smc: &mut Smc, address: u32, number: u32, value: i32) -> Result<i32, tonic::Status> {
    smc.write_parameter(pb::WriteParameterRequest {
        master: "smc".into(),
        address,
        number,
        value,
    })
    .await
    .map(|r| r.into_inner().value)
}

async fn acquire(axes: &mut Axes, names: &[&str]) -> String {
    axes.acquire_control(pb::AcquireControlRequest {
        axes: names.iter().map(|s| s.to_string()).collect(),
        ttl_ms: 10_000,
        client_name: "cansmc-test".into(),
    })
    .await
    .expect("AcquireControl")
    .into_inner()
    .lease
}

fn cmd(axis: &str, lease: &str) -> pb::AxisCommandRequest {
    pb::AxisCommandRequest {
        axis: axis.into(),
        options: Some(pb::CommandOptions {
            lease: lease.into(),
            wait: true,
            wait_timeout_ms: 10_000,
        }),
    }
}

async fn enable(axes: &mut Axes, axis: &str, lease: &str) {
    let r = axes
        .enable(cmd(axis, lease))
        .await
        .unwrap_or_else(|e| panic!("enable {axis}: {e}"))
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{axis}: {r:?}");
}

async fn move_to(axes: &mut Axes, axis: &str, lease: &str, target: f64) -> pb::AxisCommandResponse {
    axes.r#move(pb::MoveRequest {
        axis: axis.into(),
        target,
        relative: false,
        velocity: 10.0,
        acceleration: 100.0,
        options: cmd(axis, lease).options,
    })
    .await
    .unwrap_or_else(|e| panic!("move {axis}: {e}"))
    .into_inner()
}

async fn axis_status(axes: &mut Axes, axis: &str) -> pb::AxisStatus {
    axes.get_axis(pb::GetAxisRequest { axis: axis.into() })
        .await
        .expect("GetAxis")
        .into_inner()
        .status
        .expect("axis status")
}

fn total_dts(s: &pb::CansmcStatus) -> u64 {
    s.slaves
        .iter()
        .map(|x| x.counters.unwrap_or_default().dts)
        .sum()
}

/// The demo master reaches P2; its four slaves are operational with the
/// device type and firmware version of their DCT (simulated: 0x0402,
/// 0x0100); the cycle is timed (jitter samples) and DTs keep coming. The
/// service is listed, healthy and reflected.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn demo_master_runs_p2_with_four_operational_slaves() {
    let mut bed = demo().await;
    let list = bed
        .smc
        .list_masters(pb::ListMastersRequest {})
        .await
        .unwrap()
        .into_inner()
        .masters;
    assert_eq!(list.len(), 1);
    let m = &list[0];
    assert_eq!(
        (
            m.name.as_str(),
            m.command_bus.as_str(),
            m.status_bus.as_str()
        ),
        ("smc", "smc0", "smc1")
    );
    assert_eq!(m.cycle_time_us, 4000);
    assert_eq!(m.bitrate, 1_000_000);
    assert_eq!(m.phase, pb::CansmcPhase::P2 as i32);
    assert_eq!(m.slave_addresses, vec![1, 2, 3, 4]);
    assert_eq!(m.axes, vec!["A", "B", "C"]);

    // P2 may have just begun: wait for the first DT of every slave (the
    // status shows a slave's status word once one arrived).
    let s1 = wait_status(&mut bed.smc, "smc", "a DT from every slave", |s| {
        s.slaves.iter().all(|x| x.status_word.is_some())
    })
    .await;
    assert_eq!(s1.master, "smc");
    assert_eq!(s1.cycle_time_us, 4000);
    assert_eq!(s1.bitrate, 1_000_000);
    assert_eq!(s1.starts, 1);
    assert_eq!(s1.start_error, None);
    let axes: Vec<&str> = s1.slaves.iter().map(|x| x.axis.as_str()).collect();
    assert_eq!(axes, ["A", "B", "", "C"]);
    for x in &s1.slaves {
        assert!(x.required, "{x:?}");
        assert_eq!(x.device_type, Some(0x0402), "{x:?}");
        assert_eq!(x.firmware_version, Some(0x0100), "{x:?}");
        let w = x.status_word.expect("a DT arrived");
        assert!(w.ready && !w.fault, "{x:?}");
        assert_eq!(w.raw & 0x0FFF, w.raw & 0x007F, "reserved bits are 0");
    }
    assert_eq!(s1.slaves[0].name, "A servo");
    assert_eq!(s1.slaves[2].name, "Spindle encoder");
    // The empty name is the only master.
    let s2 = wait_status(&mut bed.smc, "", "moving on", |s| {
        total_dts(s) > total_dts(&s1) + 40 && s.cycle > s1.cycle
    })
    .await;
    assert_eq!(s2.master, "smc");
    let j = s2.jitter.unwrap();
    assert!(j.samples > 0, "{j:?}");
    assert!(j.p50_us <= j.p99_us && j.p99_us <= j.max_us, "{j:?}");
    // The histogram: every cycle counted once, in at most 100 buckets of
    // a listed width reaching the worst MST, the last one not empty.
    assert_eq!(j.histogram.iter().sum::<u64>(), j.samples, "{j:?}");
    assert!(
        [1, 2, 5, 10, 20, 50, 100].contains(&j.histogram_bucket_us),
        "{j:?}"
    );
    assert!(!j.histogram.is_empty() && j.histogram.len() <= 100, "{j:?}");
    assert!(j.histogram.last() > Some(&0), "{j:?}");
    let width = f64::from(j.histogram_bucket_us);
    assert!(j.max_us < width * j.histogram.len() as f64 || j.histogram.len() == 100);
    assert!(j.max_us >= width * (j.histogram.len() - 1) as f64, "{j:?}");
    let c = s2.counters.unwrap();
    assert!(c.cycles > 0, "{c:?}");
    for (a, b) in s1.slaves.iter().zip(&s2.slaves) {
        let (a, b) = (a.counters.unwrap(), b.counters.unwrap());
        assert!(b.dts > a.dts && b.mdts > a.mdts, "{a:?} -> {b:?}");
    }

    let err = bed
        .smc
        .get_status(pb::GetCansmcStatusRequest {
            master: "nope".into(),
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::NotFound, "{err:?}");
    assert!(err.message().contains("smc"), "lists the masters: {err:?}");

    // Health and reflection know the service.
    let c = client(&bed.server).await;
    let r = tonic_health::pb::health_client::HealthClient::new(c.channel())
        .check(tonic_health::pb::HealthCheckRequest {
            service: "cangate.v1.Cansmc".into(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(
        r.status,
        tonic_health::pb::health_check_response::ServingStatus::Serving as i32
    );
    bed.server.shutdown();
}

/// Parameters through the cycle's parameter slot: read the encoder
/// resolution, write and read back the following error limit; a read-only
/// parameter is refused by the slave (FAILED_PRECONDITION), unknown slaves
/// and masters are NOT_FOUND, bad addresses and numbers INVALID_ARGUMENT.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn parameters_read_write_and_refusals() {
    let mut bed = demo().await;
    let smc = &mut bed.smc;
    assert_eq!(read(smc, 1, 3).await.unwrap(), 10_000);
    assert_eq!(write(smc, 1, 4, 30_000).await.unwrap(), 30_000);
    assert_eq!(read(smc, 1, 4).await.unwrap(), 30_000);
    // Other slaves keep theirs.
    assert_eq!(read(smc, 2, 4).await.unwrap(), 20_000);

    let e = write(smc, 1, 3, 5).await.unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    assert!(
        e.message().contains("refused parameter 3") && e.message().contains("read-only"),
        "{e:?}"
    );
    // Unchanged, and the refusal did not stop the slave.
    assert_eq!(read(smc, 1, 3).await.unwrap(), 10_000);
    let e = read(smc, 9, 3).await.unwrap_err();
    assert_eq!(e.code(), Code::NotFound, "{e:?}");
    assert!(
        e.message().contains("1, 2, 3, 4"),
        "lists the slaves: {e:?}"
    );
    for (address, number) in [(0, 3), (62, 3), (1, 70_000)] {
        let e = read(smc, address, number).await.unwrap_err();
        assert_eq!(e.code(), Code::InvalidArgument, "{address}/{number}: {e:?}");
    }
    let e = smc
        .read_parameter(pb::ReadParameterRequest {
            master: "other".into(),
            address: 1,
            number: 3,
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::NotFound, "{e:?}");
    let s = status(smc, "smc").await;
    assert!(s.slaves.iter().all(|x| x.state == operational()), "{s:#?}");
    bed.server.shutdown();
}

/// CANsmc axes through the Axes service: A is enabled and moved to 2.0 mm
/// (completed, within its in-position window of 10 counts); B homes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn axis_moves_and_homes_through_the_axis_api() {
    let mut bed = demo().await;
    let a = bed
        .axes
        .get_axis(pb::GetAxisRequest { axis: "A".into() })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(a.backend, pb::AxisBackend::Cansmc as i32);
    assert_eq!(a.node, 1);
    let lease = acquire(&mut bed.axes, &["A", "B"]).await;
    enable(&mut bed.axes, "A", &lease).await;
    let r = move_to(&mut bed.axes, "A", &lease, 2.0).await;
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    let window = 10.0 / 10_000.0;
    let st = r.status.unwrap();
    assert!(
        (st.position - 2.0).abs() <= window + 1e-9,
        "at {} ({})",
        st.position,
        r.detail
    );
    let st = axis_status(&mut bed.axes, "A").await;
    assert!((st.position - 2.0).abs() <= window + 1e-9, "{st:?}");
    // The slave's status word says so too.
    let s = status(&mut bed.smc, "smc").await;
    let w = s.slaves[0].status_word.unwrap();
    assert!(w.enabled && !w.fault, "{w:?}");

    enable(&mut bed.axes, "B", &lease).await;
    let r = bed
        .axes
        .home(cmd("B", &lease))
        .await
        .expect("home B")
        .into_inner();
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    assert!(r.status.unwrap().homed);
    // The status is published every ~10 ms: poll.
    wait_status(&mut bed.smc, "smc", "slave 2 homed", |s| {
        s.slaves[1].status_word.is_some_and(|w| w.homed)
    })
    .await;
    assert!(axis_status(&mut bed.axes, "B").await.homed);
    bed.server.shutdown();
}

/// A coordinated move of two CANsmc axes (the planning the CiA 402 task
/// shares): both complete at their targets, and the call is all or none:
/// a target beyond a soft limit starts neither axis.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn coordinated_move_of_cansmc_axes_arrives_together() {
    let mut bed = demo().await;
    let lease = acquire(&mut bed.axes, &["A", "B"]).await;
    enable(&mut bed.axes, "A", &lease).await;
    enable(&mut bed.axes, "B", &lease).await;
    let target = |axis: &str, target: f64| pb::AxisTarget {
        axis: axis.into(),
        target,
        velocity: 0.0,
        acceleration: 0.0,
    };
    let r = bed
        .axes
        .move_axes(pb::MoveAxesRequest {
            targets: vec![target("A", 3.0), target("B", -1.5)],
            lease: lease.clone(),
            wait: true,
        })
        .await
        .expect("coordinated move")
        .into_inner();
    let window = 10.0 / 10_000.0;
    for (res, want) in r.results.iter().zip([3.0, -1.5]) {
        assert_eq!(res.outcome, pb::Outcome::Completed as i32, "{res:?}");
        let st = res.status.clone().unwrap();
        assert!((st.position - want).abs() <= window + 1e-9, "{st:?}");
    }
    let e = bed
        .axes
        .move_axes(pb::MoveAxesRequest {
            targets: vec![target("A", 0.0), target("B", 1.0e9)],
            lease,
            wait: false,
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::OutOfRange, "{e:?}");
    assert!(e.message().contains("axis B"), "{}", e.message());
    // A did not start: it is still at 3.
    tokio::time::sleep(Duration::from_millis(100)).await;
    let a = axis_status(&mut bed.axes, "A").await;
    assert!((a.position - 3.0).abs() <= window + 1e-9, "{a:?}");
    bed.server.shutdown();
}

/// Axis C follows slave 3's free-running encoder (5000 counts/s) at ratio
/// 0.5 once enabled: 2500 counts/s at 27.78 counts/deg ≈ 90 deg/s, with a
/// small following error; after Stop it no longer follows.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn geared_axis_follows_the_encoder_until_stopped() {
    let mut bed = demo().await;
    let lease = acquire(&mut bed.axes, &["C"]).await;
    enable(&mut bed.axes, "C", &lease).await;
    // Let the gear engage and settle.
    tokio::time::sleep(Duration::from_millis(200)).await;
    let expected = 0.5 * 5000.0 / (1000.0 / 36.0);
    let p0 = axis_status(&mut bed.axes, "C").await;
    let t0 = Instant::now();
    let mut worst_fe: f64 = 0.0;
    while t0.elapsed() < Duration::from_secs(1) {
        tokio::time::sleep(Duration::from_millis(100)).await;
        let st = axis_status(&mut bed.axes, "C").await;
        worst_fe = worst_fe.max(st.following_error.abs());
        assert_eq!(st.fault_code, 0, "{st:?}");
    }
    let p1 = axis_status(&mut bed.axes, "C").await;
    // Status timestamps are those of the DTs the positions come from.
    let dt = if p0.timestamp_us > 0 && p1.timestamp_us > p0.timestamp_us {
        (p1.timestamp_us - p0.timestamp_us) as f64 / 1e6
    } else {
        t0.elapsed().as_secs_f64()
    };
    let v = (p1.position - p0.position) / dt;
    assert!(
        (v - expected).abs() <= 0.2 * expected,
        "C moves at {v:.1} deg/s, expected {expected:.1} ({p0:?} -> {p1:?})"
    );
    // One cycle of lag at 90 deg/s is 0.18 deg; allow for the servo model.
    assert!(worst_fe < 5.0, "following error up to {worst_fe} deg");

    let r = bed
        .axes
        .stop(cmd("C", &lease))
        .await
        .expect("stop C")
        .into_inner();
    assert!(
        r.outcome == pb::Outcome::Completed as i32 || r.outcome == pb::Outcome::Stopped as i32,
        "{r:?}"
    );
    tokio::time::sleep(Duration::from_millis(100)).await;
    let a = axis_status(&mut bed.axes, "C").await;
    tokio::time::sleep(Duration::from_millis(500)).await;
    let b = axis_status(&mut bed.axes, "C").await;
    assert!(
        (b.position - a.position).abs() < 0.5,
        "C still moves after Stop: {a:?} -> {b:?}"
    );
    bed.server.shutdown();
}

/// Restart goes back through P0 and P1 to P2 (seen as phase events on the
/// stats stream); the axes report their node lost meanwhile and are
/// commandable again afterwards.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn restart_goes_through_p0_and_p1_back_to_p2() {
    let mut bed = demo().await;
    let mut stats = bed
        .smc
        .stream_cycle_stats(pb::StreamCycleStatsRequest {
            master: "smc".into(),
            interval_ms: 50,
        })
        .await
        .unwrap()
        .into_inner();
    // The first update comes at once: the stream is in place.
    let first = tokio::time::timeout(WAIT, stats.message())
        .await
        .expect("first update in time")
        .unwrap()
        .expect("stream open");
    assert_eq!(first.status.unwrap().phase, pb::CansmcPhase::P2 as i32);
    let mut axis_stream = bed
        .axes
        .stream_axis_state(pb::StreamAxisStateRequest {
            axes: vec!["A".into()],
            changes_only: false,
        })
        .await
        .unwrap()
        .into_inner();

    let r = bed
        .smc
        .restart(pb::RestartRequest {
            master: "smc".into(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.master, "smc");

    let mut phases = Vec::new();
    tokio::time::timeout(WAIT, async {
        while phases.last() != Some(&pb::CansmcPhase::P2) {
            let u = stats.message().await.unwrap().expect("stream open");
            assert_eq!(u.events_lost, 0);
            for e in u.events {
                if let Some(Event::Phase(p)) = e.event {
                    phases.push(pb::CansmcPhase::try_from(p).unwrap());
                }
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("back in P2 within {WAIT:?}; phases seen: {phases:?}"));
    assert_eq!(
        phases,
        [
            pb::CansmcPhase::P0,
            pb::CansmcPhase::P1,
            pb::CansmcPhase::P2
        ]
    );
    let s = wait_status(&mut bed.smc, "smc", "restarted", |s| {
        s.phase == pb::CansmcPhase::P2 as i32 && s.slaves.iter().all(|x| x.state == operational())
    })
    .await;
    assert_eq!(s.starts, 2);
    assert_eq!(s.start_error, None);

    // The axis saw its node lost, then back.
    let (mut lost, mut back) = (false, false);
    tokio::time::timeout(WAIT, async {
        while !(lost && back) {
            let u = axis_stream.message().await.unwrap().expect("stream open");
            match u.update {
                Some(Update::Status(st)) if st.node_lost => lost = true,
                Some(Update::Status(st)) if lost && !st.node_lost => back = true,
                _ => {}
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("node lost {lost}, back {back}"));

    let lease = acquire(&mut bed.axes, &["A"]).await;
    enable(&mut bed.axes, "A", &lease).await;
    let r = move_to(&mut bed.axes, "A", &lease, -1.0).await;
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    bed.server.shutdown();
}

/// StreamCycleStats: bounds of the interval, updates with a growing cycle,
/// and the end at shutdown with UNAVAILABLE.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cycle_stats_stream_bounds_updates_and_shutdown() {
    let mut bed = demo().await;
    for bad in [10, 49, 60_001] {
        let e = bed
            .smc
            .stream_cycle_stats(pb::StreamCycleStatsRequest {
                master: "smc".into(),
                interval_ms: bad,
            })
            .await
            .unwrap_err();
        assert_eq!(e.code(), Code::InvalidArgument, "{bad}: {e:?}");
    }
    let e = bed
        .smc
        .stream_cycle_stats(pb::StreamCycleStatsRequest {
            master: "nope".into(),
            interval_ms: 0,
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::NotFound, "{e:?}");

    let mut s = bed
        .smc
        .stream_cycle_stats(pb::StreamCycleStatsRequest {
            master: String::new(),
            interval_ms: 100,
        })
        .await
        .unwrap()
        .into_inner();
    let mut cycles = Vec::new();
    for _ in 0..3 {
        let u = tokio::time::timeout(WAIT, s.message())
            .await
            .expect("update in time")
            .unwrap()
            .expect("stream open");
        let st = u.status.unwrap();
        assert_eq!(st.master, "smc");
        assert_eq!(st.slaves.len(), 4);
        cycles.push(st.cycle);
    }
    assert!(cycles[0] < cycles[2], "{cycles:?}");

    bed.server.shutdown();
    let end = tokio::time::timeout(WAIT, async {
        loop {
            match s.message().await {
                Ok(Some(_)) => continue,
                other => return other,
            }
        }
    })
    .await
    .expect("the stream ends at shutdown");
    match end {
        Err(e) => {
            assert_eq!(e.code(), Code::Unavailable, "{e:?}");
            assert!(e.message().contains("shutting down"), "{e:?}");
        }
        Ok(None) => {} // the connection closed before the status got out
        Ok(Some(_)) => unreachable!(),
    }
}

/// Shutdown waits for the CANsmc cycle threads: once it has returned, no
/// cycle thread runs any more (so none sends an MDT after it), and each
/// master's status is the one its thread published on the way out (idle).
/// A long cycle keeps the thread asleep for up to 50 ms at a time, longer
/// than the rest of the shutdown takes: without the wait it would still
/// run when shutdown returns.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_waits_for_the_cycle_threads() {
    let mut config = demo_smc_config();
    config.cansmc[0].cycle_time_us = 100_000;
    config.cansmc[0].lost_after = 3;
    let mut bed = start(&config).await;
    wait_status(&mut bed.smc, "smc", "P2", |s| {
        s.phase == pb::CansmcPhase::P2 as i32
    })
    .await;
    let gateway = bed.server.gateway().clone();
    let master = gateway.cansmc("smc").expect("the demo master").clone();
    assert!(master.cycle_thread_running(), "the cycle thread runs in P2");
    bed.server.shutdown();
    bed.server
        .wait(Duration::from_secs(10))
        .await
        .expect("the server stops");
    assert!(
        !master.cycle_thread_running(),
        "the cycle thread still runs after shutdown returned"
    );
    assert_eq!(
        format!("{:?}", master.status().phase),
        "Idle",
        "the cycle thread's last status (idle) is published before shutdown returns"
    );
}

/// A master with slave 1 simulated and slave 7 absent.
fn missing_slave_config(required: bool) -> Config {
    let text = format!(
        r#"
listen = "127.0.0.1:0"

[[bus]]
name = "smc0"
backend = "virtual"
bitrate = 1000000
bit_timing = true

[[bus]]
name = "smc1"
backend = "virtual"
bitrate = 1000000
bit_timing = true

[[cansmc]]
name = "m"
command_bus = "smc0"
status_bus = "smc1"
cycle_time_us = 2000
connect_timeout_ms = 20
connect_attempts = 2

[[cansmc.slave]]
address = 1
name = "present"
simulate = true

[[cansmc.slave]]
address = 7
name = "absent"
required = {required}
"#
    );
    Config::from_toml(&text).expect("test configuration is valid")
}

/// A required slave that does not answer in P0 fails the start, naming its
/// address; an optional one is reported MISSING and the master runs P2
/// without it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_missing_slave_fails_the_start_only_when_required() {
    let mut bed = start(&missing_slave_config(true)).await;
    let s = wait_status(&mut bed.smc, "m", "failed", |s| {
        s.phase == pb::CansmcPhase::Failed as i32
    })
    .await;
    let err = s.start_error.clone().expect("a start error");
    assert!(err.contains('7'), "{err}");
    assert!(!err.contains('1'), "names only the missing slave: {err}");
    let seven = s.slaves.iter().find(|x| x.address == 7).unwrap();
    assert_eq!(seven.state, pb::CansmcSlaveState::Missing as i32, "{s:#?}");
    assert_eq!(seven.device_type, None);
    // Parameters need P2.
    let e = bed
        .smc
        .read_parameter(pb::ReadParameterRequest {
            master: "m".into(),
            address: 1,
            number: 3,
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::Unavailable, "{e:?}");
    bed.server.shutdown();

    let mut bed = start(&missing_slave_config(false)).await;
    let s = wait_status(&mut bed.smc, "m", "P2 without slave 7", |s| {
        s.phase == pb::CansmcPhase::P2 as i32
    })
    .await;
    assert_eq!(s.start_error, None);
    let by = |a: u32| s.slaves.iter().find(|x| x.address == a).unwrap();
    assert_eq!(by(7).state, pb::CansmcSlaveState::Missing as i32, "{s:#?}");
    assert!(!by(7).required);
    assert_eq!(by(1).state, operational(), "{s:#?}");
    assert_eq!(by(1).device_type, Some(0x0402));
    let e = bed
        .smc
        .read_parameter(pb::ReadParameterRequest {
            master: "m".into(),
            address: 7,
            number: 3,
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::Unavailable, "{e:?}");
    bed.server.shutdown();
}

/// A slave that stops answering (the simulator drops all its replies) is
/// declared lost after `lost_after` cycles: its axis faults with the reason
/// and refuses commands; when it answers again the axis must be enabled
/// again. Meanwhile a StopAxes on A and B (one step of the cycle thread)
/// stops both, and stops need no lease.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_slave_is_lost_and_faults_its_axis() {
    let mut config = demo_smc_config();
    config.cansmc[0].lost_after = 20;
    let mut bed = start(&config).await;
    wait_status(&mut bed.smc, "smc", "P2", |s| {
        s.phase == pb::CansmcPhase::P2 as i32 && s.slaves.iter().all(|x| x.state == operational())
    })
    .await;
    let lease = acquire(&mut bed.axes, &["A", "B"]).await;
    enable(&mut bed.axes, "A", &lease).await;
    enable(&mut bed.axes, "B", &lease).await;
    // Both jog; one StopAxes stops both (no lease needed for stops).
    for axis in ["A", "B"] {
        bed.axes
            .jog(pb::JogRequest {
                axis: axis.into(),
                velocity: 2.0,
                acceleration: 0.0,
                options: Some(pb::CommandOptions {
                    lease: lease.clone(),
                    wait: false,
                    wait_timeout_ms: 0,
                }),
            })
            .await
            .unwrap_or_else(|e| panic!("jog {axis}: {e}"));
    }
    let stopped = bed
        .axes
        .stop_axes(pb::StopAxesRequest {
            axes: vec!["A".into(), "B".into()],
            quick: false,
            wait: true,
        })
        .await
        .expect("StopAxes")
        .into_inner();
    assert_eq!(stopped.results.len(), 2, "{stopped:?}");
    for r in &stopped.results {
        assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    }

    let sims = bed.server.gateway().simulated_cansmc_slaves("smc").to_vec();
    let a = sims
        .iter()
        .find(|s| s.address().get() == 1)
        .expect("simulated slave 1");
    a.with(|s| s.set_drop_rate(1.0));
    let s = wait_status(&mut bed.smc, "smc", "slave 1 lost", |s| {
        s.slaves[0].state == pb::CansmcSlaveState::Lost as i32
    })
    .await;
    assert!(s.slaves[0].counters.unwrap().losses >= 1);
    let t0 = Instant::now();
    let st = loop {
        let st = axis_status(&mut bed.axes, "A").await;
        if st.node_lost {
            break st;
        }
        assert!(t0.elapsed() < WAIT, "axis A not faulted: {st:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    assert!(st.fault_text.contains("slave lost"), "{st:?}");
    let e = bed.axes.enable(cmd("A", &lease)).await.unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e}");
    assert!(e.message().contains("slave is lost"), "{e}");
    // B is unaffected.
    assert!(!axis_status(&mut bed.axes, "B").await.node_lost);

    a.with(|s| s.set_drop_rate(0.0));
    wait_status(&mut bed.smc, "smc", "slave 1 back", |s| {
        s.slaves[0].state == operational()
    })
    .await;
    let t0 = Instant::now();
    while axis_status(&mut bed.axes, "A").await.node_lost {
        assert!(t0.elapsed() < WAIT, "axis A still lost");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    enable(&mut bed.axes, "A", &lease).await;
    bed.server.shutdown();
}

/// Axis B jogs in the slave's velocity mode (demo: `jog_mode =
/// "velocity"`): the slave moves, the dead-man brakes it, the gateway reads
/// the encoder back and position control resumes exactly there (a move
/// afterwards lands on its target).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_velocity_mode_jog_moves_the_slave_and_hands_back_to_position_control() {
    let mut bed = demo().await;
    let lease = acquire(&mut bed.axes, &["B"]).await;
    enable(&mut bed.axes, "B", &lease).await;
    let start = axis_status(&mut bed.axes, "B").await.position;
    // One jog, waited for: it runs until the dead-man (500 ms) stops it;
    // a waited command that was stopped ends ABORTED, saying why.
    let e = bed
        .axes
        .jog(pb::JogRequest {
            axis: "B".into(),
            velocity: 5.0,
            acceleration: 0.0,
            options: cmd("B", &lease).options,
        })
        .await
        .expect_err("a dead-man stop");
    assert_eq!(e.code(), Code::Aborted, "{e}");
    assert!(e.message().contains("dead-man"), "{e}");
    let after = axis_status(&mut bed.axes, "B").await.position;
    assert!(after - start > 1.0, "moved {start} -> {after}");
    // The slave's parameter 2 was set to 0.001 r/min in P1.
    assert_eq!(read(&mut bed.smc, 2, 2).await.unwrap(), 1);
    let target = (after + 1.0).min(90.0);
    let r = move_to(&mut bed.axes, "B", &lease, target).await;
    assert_eq!(r.outcome, pb::Outcome::Completed as i32, "{r:?}");
    let st = axis_status(&mut bed.axes, "B").await;
    assert!((st.position - target).abs() < 0.002, "{st:?}");
    bed.server.shutdown();
}
