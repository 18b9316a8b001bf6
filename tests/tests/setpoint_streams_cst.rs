//! Set-point streams of torques on a simulated drive in cyclic
//! synchronous torque (T, node 2): each SYNC's torque goes to 0x6071 in
//! the axis's torque RPDO (0x402, two bytes), every torque and every step
//! inside T's max_torque and torque slope, and every end of the stream
//! ramps the torque to 0 and halts the drive (controlword bit 8 in RPDO1,
//! 0x202). The bus's frames are read by a port of the test on the
//! virtual bus.

use cangate_can::virtual_bus::PortEvent;
use cangate_client::pb;
use cangate_client::{SetpointSender, setpoint, torque_setpoint};
use cangate_tests::axes::*;
use cangate_tests::streams::{events, read_until, refusals, send_points, stream_options};
use cangate_tests::*;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tonic::Code;

/// T: CST, at most 300 per mille changing at most 2000 per mille/s, its
/// guard at 30 mm/s (the unloaded simulated motor settles near 20 mm/s
/// at 30 per mille); P: CSP. SYNC every 5 ms.
const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"
sync_period_us = 5000

[[canopen.node]]
id = 2
eds = "builtin:drive"
simulate = true

[[canopen.node]]
id = 3
eds = "builtin:drive"
simulate = true

[[axis]]
name = "T"
bus = "can0"
node = 2
counts_per_unit = 1000.0
mode = "cst"
min_position = -5000.0
max_position = 5000.0
max_velocity = 30.0
max_acceleration = 1000.0
max_torque = 300.0
torque_slope = 2000.0

[[axis]]
name = "P"
bus = "can0"
node = 3
counts_per_unit = 1000.0
mode = "csp"
min_position = -200.0
max_position = 200.0
max_velocity = 100.0
max_acceleration = 1000.0
"#;

/// The torque slope of T, per mille/s, and the SYNC period.
const SLOPE: f64 = 2000.0;
const SYNC: f64 = 0.005;

/// The payloads of T's RPDO1 (0x202) and torque RPDO (0x402) on the bus,
/// in order, as a port of the test read them.
#[derive(Clone, Default)]
struct Spy(Arc<Mutex<Seen>>);

/// The payloads of RPDO1 and of the torque RPDO.
type Seen = (Vec<Vec<u8>>, Vec<Vec<u8>>);

impl Spy {
    /// The torque RPDO's payloads so far.
    fn rpdo3(&self) -> Vec<Vec<u8>> {
        self.0.lock().unwrap().1.clone()
    }

    /// Forgets the frames so far.
    fn clear(&self) {
        let mut g = self.0.lock().unwrap();
        g.0.clear();
        g.1.clear();
    }

    /// Whether the last controlword T's RPDO1 carried has halt (bit 8)
    /// set.
    fn halted(&self) -> bool {
        let g = self.0.lock().unwrap();
        let last = g.0.last().expect("controlwords sent");
        u16::from_le_bytes([last[0], last[1]]) & 0x0100 != 0
    }
}

/// The server, a client, T enabled under the client's lease, and the spy
/// on T's RPDOs.
async fn setup() -> (
    cangate_server::RunningServer,
    cangate_client::Client,
    Axes,
    cangate_client::ControlLease,
    Spy,
) {
    let server = start_server(CONFIG).await;
    let mut port = server
        .gateway()
        .network()
        .get("can0")
        .expect("virtual can0")
        .connect(false);
    let spy = Spy::default();
    let frames = spy.clone();
    tokio::spawn(async move {
        loop {
            if let PortEvent::Frame { frame, .. } = port.recv().await {
                let mut g = frames.0.lock().unwrap();
                match frame.id().raw() {
                    0x202 => g.0.push(frame.data().to_vec()),
                    0x402 => g.1.push(frame.data().to_vec()),
                    _ => {}
                }
            }
        }
    });
    let c = client(&server).await;
    let mut axes = c.axes_client();
    wait_ready(&mut axes, &["T", "P"]).await;
    let lease = c
        .acquire_control_as(&["T", "P"], Duration::from_secs(5), "torque")
        .await
        .unwrap();
    enable(&mut axes, "T", lease.token()).await;
    (server, c, axes, lease, spy)
}

/// T's torque profile (per mille) at `s` seconds: up at 1000 per mille/s
/// to 30, held, down from 0.47 s: 0 from 0.5 s on.
fn push(s: f64) -> f64 {
    (1000.0 * s).min(30.0).min((1000.0 * (0.5 - s)).max(0.0))
}

/// Sends `torque` sampled every ms for client times 0..`points` ms, in
/// batches of 10, never more than 300 ms ahead of real time.
fn send_torques(
    sender: SetpointSender,
    points: u64,
    torque: impl Fn(f64) -> f64 + Send + 'static,
) -> tokio::task::JoinHandle<()> {
    send_points(sender, points, Duration::from_millis(300), move |k| {
        torque_setpoint(k * 1000, vec![torque(k as f64 / 1000.0)])
    })
}

/// The torque RPDO's payloads: 0x6071 alone, i16 little endian; every
/// torque within ±300 and each step within the slope over a SYNC (a SYNC
/// the loaded host skipped carries at most one period's step too).
fn torques(frames: &[Vec<u8>]) -> Vec<i16> {
    let t: Vec<i16> = frames
        .iter()
        .map(|d| {
            assert_eq!(d.len(), 2, "{d:?}");
            i16::from_le_bytes([d[0], d[1]])
        })
        .collect();
    for w in t.windows(2) {
        assert!(
            f64::from((w[1] - w[0]).abs()) <= SLOPE * SYNC + 1.0,
            "{w:?}"
        );
    }
    assert!(t.iter().all(|x| x.abs() <= 300), "{t:?}");
    t
}

/// Waits until T is idle and stands still; its status.
async fn wait_halted(axes: &mut Axes) -> pb::AxisStatus {
    wait_status(axes, "T", |s| {
        s.activity == pb::AxisActivity::Idle as i32 && s.velocity.abs() < 0.1
    })
    .await
}

/// Torques streamed to T play through to the drive (it turns), each
/// SYNC's torque leaves in the torque RPDO with exact bytes, points beyond
/// the limits are refused, and the stream's end ramps the torque to 0 and
/// halts the drive.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn torques_stream_to_the_cst_axis_and_its_end_halts_the_drive() {
    let (server, c, mut axes, lease, spy) = setup().await;
    let mut stream = c
        .stream_setpoints(&lease, &["T"], stream_options())
        .await
        .unwrap();
    // Not from 0, above the maximum, too steep: refused.
    stream
        .send(vec![torque_setpoint(0, vec![50.0])])
        .await
        .unwrap();
    let mut seen = Vec::new();
    read_until(&mut stream, &mut seen, |s| {
        s.counters.as_ref().is_some_and(|c| c.refused == 1)
    })
    .await
    .unwrap()
    .unwrap();
    assert!(!spy.halted(), "the stream released the halt");
    let sending = send_torques(stream.sender().unwrap(), 700, push);
    let turning = read_until(&mut stream, &mut seen, |s| {
        s.signals[0].velocity_actual.is_some_and(|v| v > 5.0)
    })
    .await
    .unwrap()
    .expect("T turns under 30 per mille");
    assert_eq!(turning.ended, "");
    sending.await.unwrap();
    // Above the maximum, then a jump of 200 per mille in 0.1 ms: refused.
    stream
        .send(vec![
            torque_setpoint(699_500, vec![400.0]),
            torque_setpoint(699_600, vec![200.0]),
        ])
        .await
        .unwrap();
    stream.finish();
    read_until(&mut stream, &mut seen, |_| false)
        .await
        .expect("the stream ends normally");
    let last = seen.last().unwrap();
    assert_eq!(last.ended, "CLIENT_ENDED", "{last:?}");
    assert_eq!(last.commanded_torques, [0.0], "{last:?}");
    assert!(last.commanded_positions.is_empty(), "{last:?}");
    let r = refusals(&seen);
    assert_eq!(r, ["NOT_FROM_REST", "TORQUE_ABOVE_MAX", "TORQUE_TOO_STEEP"]);
    let n = last.counters.unwrap();
    assert_eq!(n.received, n.accepted + n.refused, "{n:?}");
    assert_eq!(n.accepted, n.played + n.late + n.dropped, "{n:?}");
    let s = wait_halted(&mut axes).await;
    assert!(spy.halted(), "T halted: {s:?}");
    // The torque RPDO: 30 per mille (0x001E) held, back to exactly 0.
    let rpdo3 = spy.rpdo3();
    let t = torques(&rpdo3);
    assert!(rpdo3.contains(&vec![0x1E, 0x00]), "{t:?}");
    assert_eq!(rpdo3.last().unwrap(), &vec![0, 0], "{t:?}");
    assert_eq!(t.iter().max(), Some(&30), "{t:?}");
    server.shutdown();
}

/// 200 per mille would run the unloaded motor far beyond its 30 mm/s: the
/// axis's guard stops it, the stream ends TORQUE_GUARD naming T, the
/// torque ramps to 0 and the drive is halted at rest.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_velocity_guard_ends_a_torque_stream_and_halts_the_drive() {
    let (server, c, mut axes, lease, spy) = setup().await;
    let mut stream = c
        .stream_setpoints(&lease, &["T"], stream_options())
        .await
        .unwrap();
    let sending = send_torques(stream.sender().unwrap(), 5000, |s| (1000.0 * s).min(200.0));
    let mut seen = Vec::new();
    let e = read_until(&mut stream, &mut seen, |_| false)
        .await
        .expect_err("the guard ends the stream");
    assert_eq!(e.code(), Some(Code::Aborted), "{e:?}");
    sending.abort();
    let last = seen.last().unwrap();
    assert_eq!(last.ended, "TORQUE_GUARD", "{last:?}");
    let ended = events(&seen)
        .into_iter()
        .find(|e| e.kind == pb::SetpointEventKind::SetpointEventEnded as i32)
        .unwrap();
    assert_eq!(ended.axis, "T");
    assert!(ended.detail.contains("max_velocity"), "{ended:?}");
    wait_halted(&mut axes).await;
    assert!(spy.halted());
    let rpdo3 = spy.rpdo3();
    torques(&rpdo3);
    assert_eq!(rpdo3.last().unwrap(), &vec![0, 0]);
    server.shutdown();
}

/// A torque stream that runs out of points ends (UNDERRUN) with the
/// torque at 0 and the drive halted; one whose lease is released ends
/// LEASE_LOST the same way; csp and cst axes do not mix in a stream, and
/// a position point on a torque stream is a protocol error.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_underrun_or_a_lost_lease_halts_the_drive_and_kinds_do_not_mix() {
    let (server, c, mut axes, lease, spy) = setup().await;
    let mut stream = c
        .stream_setpoints(&lease, &["T"], stream_options())
        .await
        .unwrap();
    // Up to 30 per mille and no further point.
    let sending = send_torques(stream.sender().unwrap(), 100, |s| (1000.0 * s).min(30.0));
    let mut seen = Vec::new();
    let e = read_until(&mut stream, &mut seen, |_| false)
        .await
        .expect_err("an underrun ends a torque stream");
    assert_eq!(e.code(), Some(Code::Aborted), "{e:?}");
    sending.await.unwrap();
    assert_eq!(seen.last().unwrap().ended, "UNDERRUN");
    assert!(
        events(&seen)
            .iter()
            .any(|e| e.kind == pb::SetpointEventKind::SetpointEventUnderrun as i32)
    );
    wait_halted(&mut axes).await;
    assert!(spy.halted());
    let rpdo3 = spy.rpdo3();
    torques(&rpdo3);
    assert_eq!(rpdo3.last().unwrap(), &vec![0, 0]);

    // Kinds do not mix; positions are no torques.
    enable(&mut axes, "P", lease.token()).await;
    let e = c
        .stream_setpoints(&lease, &["P", "T"], stream_options())
        .await
        .err()
        .expect("refused");
    assert_eq!(e.code(), Some(Code::FailedPrecondition), "{e:?}");
    assert!(e.to_string().contains("not both"), "{e}");
    let mut stream = c
        .stream_setpoints(&lease, &["T"], stream_options())
        .await
        .unwrap();
    stream.send(vec![setpoint(0, vec![0.0])]).await.unwrap();
    let e = read_until(&mut stream, &mut seen, |_| false)
        .await
        .expect_err("positions on a cst stream");
    assert_eq!(e.code(), Some(Code::InvalidArgument), "{e:?}");
    wait_halted(&mut axes).await;

    // A released lease.
    spy.clear();
    let mut stream = c
        .stream_setpoints(&lease, &["T"], stream_options())
        .await
        .unwrap();
    let sending = send_torques(stream.sender().unwrap(), 5000, |s| (1000.0 * s).min(30.0));
    read_until(&mut stream, &mut seen, |s| {
        s.signals[0].velocity_actual.is_some_and(|v| v > 5.0)
    })
    .await
    .unwrap()
    .expect("T turns");
    lease.release().await.unwrap();
    let e = read_until(&mut stream, &mut seen, |_| false)
        .await
        .expect_err("a stream whose lease is gone ends with an error");
    assert_eq!(e.code(), Some(Code::Aborted), "{e:?}");
    assert_eq!(seen.last().unwrap().ended, "LEASE_LOST");
    sending.abort();
    wait_halted(&mut axes).await;
    assert!(spy.halted());
    let rpdo3 = spy.rpdo3();
    torques(&rpdo3);
    assert_eq!(rpdo3.last().unwrap(), &vec![0, 0]);
    server.shutdown();
}
