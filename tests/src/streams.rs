//! Set-point streams as the end-to-end tests drive them: a path sent at
//! its own pace, and the statuses read back.

use cangate_client::{SetpointSender, SetpointStream, pb, setpoint};
use std::time::{Duration, Instant};

/// Bound of every status wait.
const STATUS_WAIT: Duration = Duration::from_secs(60);

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
    tokio::spawn(async move {
        let start = Instant::now();
        for batch in (0..points).collect::<Vec<_>>().chunks(10) {
            let last = *batch.last().unwrap();
            let due = Duration::from_millis(last);
            if let Some(wait) = due.checked_sub(start.elapsed() + lead) {
                tokio::time::sleep(wait).await;
            }
            let pts = batch
                .iter()
                .map(|&k| setpoint(t0_us + k * 1000, path(k as f64 / 1000.0)))
                .collect();
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
