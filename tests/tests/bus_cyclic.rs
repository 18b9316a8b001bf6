//! Cyclic transmission run by the gateway for an attached client
//! (`AttachCyclic`, python-can's `send_periodic`): a job's frames arrive at
//! its period as the client's frames, a change of its data takes effect
//! without stopping it, a stop ends it, and so do its duration, a refused
//! frame (the client's raw frame budget) and the client going away.
//!
//! Timing is asserted only where it cannot flake: a job never sends faster
//! than its period (no burst), so n frames take at least n periods; upper
//! bounds are the generous [`WAIT`].

use cangate_client::can::Frame;
use cangate_client::pb;
use cangate_client::{AttachEvent, AttachOptions, Attachment};
use cangate_tests::*;
use futures::StreamExt;
use std::time::{Duration, Instant};
use tonic::Code;

fn frame(text: &str) -> Frame {
    text.parse().expect("valid frame text")
}

/// A watcher's stream of one identifier's frames, one at a time.
struct Watch {
    stream: tonic::Streaming<pb::StreamFramesResponse>,
    pending: Vec<pb::StreamEvent>,
    frames: std::collections::VecDeque<pb::Frame>,
}

impl Watch {
    async fn open(c: &mut cangate_client::Client, id: u32) -> Watch {
        let (stream, pending) = open_stream(c, frames_on("can0", id)).await;
        Watch {
            stream,
            pending,
            frames: Default::default(),
        }
    }

    async fn next(&mut self) -> pb::Frame {
        if self.frames.is_empty() {
            let got = read_frames(&mut self.stream, &mut self.pending, 1).await;
            self.frames.extend(got);
        }
        self.frames.pop_front().expect("a frame")
    }

    /// Waits until no frame comes for `quiet`, at most [`WAIT`] (a job
    /// still running would keep it busy past that); the frames that came.
    async fn until_quiet(&mut self, quiet: Duration) -> usize {
        let deadline = Instant::now() + WAIT;
        let mut frames = self.frames.drain(..).count();
        loop {
            match tokio::time::timeout(quiet, self.stream.message()).await {
                Err(_) => return frames,
                Ok(m) => {
                    let m = m.expect("stream ok").expect("stream not ended");
                    frames += m.events.len();
                    assert!(
                        Instant::now() < deadline,
                        "frames still coming {} s on",
                        WAIT.as_secs()
                    );
                }
            }
        }
    }
}

/// The next notice of a cyclic job of an attachment (frames, states and
/// the refusals its calls returned already are skipped).
async fn next_notice(a: &mut Attachment) -> AttachEvent {
    tokio::time::timeout(WAIT, async {
        loop {
            match a.events.next().await {
                Some(Ok(
                    AttachEvent::Frame { .. } | AttachEvent::State(_) | AttachEvent::Refused(_),
                )) => {}
                Some(Ok(e)) => return e,
                other => panic!("the stream ended: {other:?}"),
            }
        }
    })
    .await
    .expect("a notice in time")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cyclic_job_sends_at_its_period_changes_its_data_and_stops() {
    let server = start_server(ONE_BUS).await;
    let mut look = client(&server).await;
    let mut watch = Watch::open(&mut look, 0x321).await;
    let c = client(&server).await;
    let a = c.attach("can0", &AttachOptions::default()).await.unwrap();

    let period = Duration::from_millis(20);
    let started = Instant::now();
    a.sender
        .start_cyclic(1, &[frame("321#01")], period, None)
        .await
        .unwrap();
    let mut first = None;
    for _ in 0..10 {
        let f = watch.next().await;
        assert_eq!(f.data, [1]);
        assert_eq!(f.origin(), pb::FrameOrigin::Client);
        assert_eq!(
            f.sender.as_ref().unwrap().id,
            a.sender_id,
            "the client's frames"
        );
        first.get_or_insert(f.timestamp_ns);
    }
    // No burst: ten frames, the first one period after the start, take at
    // least ten periods.
    assert!(started.elapsed() >= 10 * period, "{:?}", started.elapsed());

    // New data, same job: the frames change, the job goes on.
    a.sender.modify_cyclic(1, &[frame("321#02")]).await.unwrap();
    loop {
        if watch.next().await.data == [2] {
            break;
        }
    }
    for _ in 0..3 {
        assert_eq!(watch.next().await.data, [2]);
    }

    // Stopped: after the stop is answered nothing of the job is sent. The
    // client's next frame comes after every frame it sent before (one
    // sender's frames arrive in order), so nothing of the job follows it.
    a.sender.stop_cyclic(1).await.unwrap();
    a.sender.send_confirmed(&[frame("321#FF")]).await.unwrap();
    loop {
        if watch.next().await.data == [0xFF] {
            break;
        }
    }
    assert_eq!(watch.until_quiet(Duration::from_millis(300)).await, 0);
    // Stopping it again is no error.
    a.sender.stop_cyclic(1).await.unwrap();
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_goes_away_takes_its_cyclic_jobs_along() {
    let server = start_server(ONE_BUS).await;
    let mut look = client(&server).await;
    let mut watch = Watch::open(&mut look, 0x322).await;
    let c = client(&server).await;
    let a = c.attach("can0", &AttachOptions::default()).await.unwrap();
    a.sender
        .start_cyclic(
            1,
            &[frame("322#01"), frame("322#02")],
            Duration::from_millis(10),
            None,
        )
        .await
        .unwrap();
    // Two frames in turn.
    let mut seen = Vec::new();
    for _ in 0..4 {
        seen.push(watch.next().await.data[0]);
    }
    assert!(seen.windows(2).all(|w| w[0] != w[1]), "{seen:?}");
    drop(a);
    drop(c);
    watch.until_quiet(Duration::from_millis(500)).await;
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_ends_with_its_duration_or_its_budget_and_bad_jobs_are_refused() {
    let server = start_server(&format!(
        "{ONE_BUS}[security.limits]\nraw_frames_per_second_per_client = 10\nraw_frame_burst = 5\n"
    ))
    .await;
    let c = client(&server).await;
    let mut a = c.attach("can0", &AttachOptions::default()).await.unwrap();

    let e = a
        .sender
        .start_cyclic(1, &[frame("123#")], Duration::from_micros(500), None)
        .await
        .unwrap_err();
    assert_eq!(e.code(), Some(Code::InvalidArgument), "{e}");
    let e = a
        .sender
        .modify_cyclic(9, &[frame("123#")])
        .await
        .unwrap_err();
    assert_eq!(e.code(), Some(Code::InvalidArgument), "{e}");
    assert!(e.to_string().contains("does not run"), "{e}");

    // 1 ms against 10 frames/s, 5 at once: the budget ends the job.
    a.sender
        .start_cyclic(2, &[frame("124#")], Duration::from_millis(1), None)
        .await
        .unwrap();
    match next_notice(&mut a).await {
        AttachEvent::CyclicStopped(s) => {
            assert_eq!(s.job, 2);
            assert_eq!(s.code, Code::ResourceExhausted as i32, "{s:?}");
            assert_eq!(s.reason, "FRAME_RATE_LIMIT", "{s:?}");
        }
        other => panic!("unexpected {other:?}"),
    }

    // A job with a duration ends by itself (the budget refills at 10/s,
    // the job sends 1 per 200 ms).
    a.sender
        .start_cyclic(
            3,
            &[frame("125#")],
            Duration::from_millis(200),
            Some(Duration::from_millis(300)),
        )
        .await
        .unwrap();
    match next_notice(&mut a).await {
        AttachEvent::CyclicStopped(s) => {
            assert_eq!((s.job, s.code, s.reason.as_str()), (3, 0, ""), "{s:?}");
        }
        other => panic!("unexpected {other:?}"),
    }
    server.shutdown();
}
