//! Set-point streams as the end-to-end tests drive them: a path sent at
//! its own pace, and the statuses read back.

use cangate_client::{SetpointSender, SetpointStream, SetpointStreamOptions, pb, setpoint};
use std::time::{Duration, Instant};

/// Bound of every status wait.
const STATUS_WAIT: Duration = Duration::from_secs(60);

/// The stream options of the end-to-end tests: a 50 ms buffer, 50 ms of
/// extrapolation, 1 ms points, a status every 10 ms.
pub fn stream_options() -> SetpointStreamOptions {
    SetpointStreamOptions {
        depth: Duration::from_millis(50),
        extrapolate: Some(Duration::from_millis(50)),
        point_period: Some(Duration::from_millis(1)),
        status_period: Some(Duration::from_millis(10)),
    }
}

/// Sends `path` sampled every ms for client times 0..`points` ms (client
/// time `t0_us` on), in batches of 10, never more than `lead` ahead of
/// real time.
pub fn send_path(
    sender: SetpointSender,
    t0_us: u64,
    points: u64,
    lead: Duration,
    path: impl Fn(f64) -> Vec<f64> + Send + 'static,
) -> tokio::task::JoinHandle<()> {
    send_points(sender, points, lead, move |k| {
        setpoint(t0_us + k * 1000, path(k as f64 / 1000.0))
    })
}

/// Sends `point(k)` for k = 0..`points` (one per ms of client time), in
/// batches of 10, never more than `lead` ahead of real time: any kind of
/// set-point (`setpoint`, `velocity_setpoint`, `torque_setpoint`).
pub fn send_points(
    sender: SetpointSender,
    points: u64,
    lead: Duration,
    point: impl Fn(u64) -> pb::Setpoint + Send + 'static,
) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let start = Instant::now();
        for batch in (0..points).collect::<Vec<_>>().chunks(10) {
            let last = *batch.last().unwrap();
            let due = Duration::from_millis(last);
            if let Some(wait) = due.checked_sub(start.elapsed() + lead) {
                tokio::time::sleep(wait).await;
            }
            let pts = batch.iter().map(|&k| point(k)).collect();
            if sender.send(pts).await.is_err() {
                return;
            }
        }
    })
}

/// Reads statuses into `seen` until `done` says so (or the call ends:
/// `None`); panics after a minute without.
pub async fn read_until(
    stream: &mut SetpointStream,
    seen: &mut Vec<pb::SetpointStreamStatus>,
    mut done: impl FnMut(&pb::SetpointStreamStatus) -> bool,
) -> Result<Option<pb::SetpointStreamStatus>, cangate_client::Error> {
    tokio::time::timeout(STATUS_WAIT, async {
        loop {
            match stream.status().await? {
                Some(s) => {
                    seen.push(s.clone());
                    if done(&s) {
                        return Ok(Some(s));
                    }
                }
                None => return Ok(None),
            }
        }
    })
    .await
    .expect("the stream answers")
}

/// Every event of the statuses, in order.
pub fn events(seen: &[pb::SetpointStreamStatus]) -> Vec<pb::SetpointStreamEvent> {
    seen.iter().flat_map(|s| s.events.clone()).collect()
}

/// The reasons of the refused points among the statuses' events, in order.
pub fn refusals(seen: &[pb::SetpointStreamStatus]) -> Vec<String> {
    events(seen)
        .iter()
        .filter(|e| e.kind == pb::SetpointEventKind::SetpointEventPointRefused as i32)
        .map(|e| e.reason.clone())
        .collect()
}
