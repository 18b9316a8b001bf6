//! A client that stops reading never slows the bus or other clients; when
//! it resumes it is told exactly how many frames it missed.

use cangate_client::can::{CanId, Frame};
use cangate_client::pb::stream_event::Event;
use cangate_tests::*;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

const N: u64 = 200_000;
const MARKER_ID: u32 = 0x7FF;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stalled_consumer_gets_exact_lost_count_and_does_not_delay_others() {
    let server = start_server(ONE_BUS).await;
    let vbus = server.gateway().network().get("can0").unwrap();
    let device = vbus.connect(false);

    // The stalled client: small buffer, opens the stream and stops reading.
    let mut stalled_client = client(&server).await;
    let mut req = stream_request("can0", vec![]);
    req.queue_length = 64;
    let (mut stalled, mut stalled_pending) = open_stream(&mut stalled_client, req).await;

    // The fast client reads everything with a large buffer.
    let mut fast_client = client(&server).await;
    let mut req = stream_request("can0", vec![]);
    req.queue_length = 1_000_000;
    let (mut fast, fast_pending) = open_stream(&mut fast_client, req).await;
    assert!(fast_pending.is_empty());
    let fast_count = Arc::new(AtomicU64::new(0));
    let counter = fast_count.clone();
    let fast_reader = tokio::spawn(async move {
        let mut next = 0u64;
        loop {
            let msg = tokio::time::timeout(WAIT, fast.message()).await;
            let Ok(Ok(Some(msg))) = msg else {
                panic!("fast stream broke: {msg:?}")
            };
            for ev in msg.events {
                match ev.event {
                    Some(Event::Frame(f)) if f.id == MARKER_ID => return next,
                    Some(Event::Frame(f)) => {
                        let seq = u64::from_le_bytes(f.data[..8].try_into().unwrap());
                        assert_eq!(seq, next, "fast client sees every frame in order");
                        next += 1;
                        counter.store(next, Ordering::Relaxed);
                    }
                    Some(Event::Lost(l)) => panic!("fast client lost {} frames", l.count),
                    _ => {}
                }
            }
        }
    });

    // The device sends N frames, paced only by the fast client (so the
    // gateway's own receive queue never overflows), never by the stalled one.
    let id = CanId::standard(0x100).unwrap();
    for seq in 0..N {
        while seq > fast_count.load(Ordering::Relaxed) + 8_000 {
            tokio::task::yield_now().await;
        }
        device
            .send(&Frame::new(id, &seq.to_le_bytes()).unwrap())
            .unwrap();
    }
    device
        .send(&Frame::new(CanId::standard(MARKER_ID).unwrap(), &[]).unwrap())
        .unwrap();
    let fast_total = tokio::time::timeout(WAIT, fast_reader)
        .await
        .unwrap()
        .unwrap();
    assert_eq!(fast_total, N);

    // The stalled client resumes: frames it got plus frames it was told it
    // lost add up to exactly N (the marker itself was lost too while the
    // client's buffer was full, so it is counted out).
    let mut received = 0u64;
    let mut lost = 0u64;
    let mut notices = 0;
    while received + lost < N + 1 {
        for ev in stalled_pending.drain(..) {
            match ev.event {
                Some(Event::Frame(_)) => received += 1,
                Some(Event::Lost(l)) => {
                    lost += l.count;
                    notices += 1;
                }
                _ => {}
            }
        }
        if received + lost > N {
            break;
        }
        let msg = tokio::time::timeout(WAIT, stalled.message())
            .await
            .unwrap_or_else(|_| panic!("stalled client stuck at received {received} + lost {lost}"))
            .unwrap()
            .expect("stream open");
        stalled_pending.extend(msg.events);
    }
    assert!(notices >= 1, "the stalled client was told it lost frames");
    assert!(lost > 0);
    assert_eq!(
        received + lost,
        N + 1,
        "received {received} + lost {lost} must be N + marker"
    );
    // Now that it reads again, the next frame reaches it normally.
    device
        .send(&Frame::new(CanId::standard(0x555).unwrap(), &[]).unwrap())
        .unwrap();
    let next = read_frames(&mut stalled, &mut stalled_pending, 1).await;
    assert_eq!(next[0].id, 0x555);
    let stats = server.gateway().bus("can0").unwrap().stats();
    assert_eq!(stats.subscriber_drops, lost);
    assert_eq!(stats.rx_overflows, 0);
    server.shutdown();
}

/// A reader that pauses while frames trickle in one by one (each its own
/// small stream message, as on a bus at a few thousand frames/s) keeps
/// its stream: when it reads again it gets the frames that were buffered
/// and `FramesLost` for the rest, never a transport error. (HTTP/2 peers
/// limit how many small DATA frames may wait unread; the gateway and the
/// client keep below that limit.)
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn paused_reader_of_a_trickle_gets_lost_notices_not_a_transport_error() {
    let server = start_server(ONE_BUS).await;
    let vbus = server.gateway().network().get("can0").unwrap();
    let device = vbus.connect(false);
    let mut c = client(&server).await;
    let (mut paused, mut pending) = open_stream(&mut c, stream_request("can0", vec![])).await;

    // One frame at a time with a pause in between, so that the gateway's
    // stream task wakes for nearly every frame; the reader does not read
    // meanwhile.
    const TRICKLE: u64 = 40_000;
    let sender = std::thread::spawn(move || {
        let id = CanId::standard(0x100).unwrap();
        for seq in 0..TRICKLE {
            device
                .send(&Frame::new(id, &seq.to_le_bytes()).unwrap())
                .unwrap();
            std::thread::sleep(std::time::Duration::from_micros(50));
        }
        device
    });
    let device = tokio::task::spawn_blocking(move || sender.join().unwrap())
        .await
        .unwrap();

    // Resume: every frame is either received in order or counted lost.
    let mut received = 0u64;
    let mut lost = 0u64;
    let mut next_seq = 0u64;
    while received + lost < TRICKLE {
        for ev in pending.drain(..) {
            match ev.event {
                Some(Event::Frame(f)) => {
                    let seq = u64::from_le_bytes(f.data[..8].try_into().unwrap());
                    assert!(seq >= next_seq, "in order");
                    // Frames are missing only where a notice before
                    // this frame covered them.
                    assert!(
                        seq - received <= lost,
                        "frames before {seq} missing without a FramesLost notice"
                    );
                    next_seq = seq + 1;
                    received += 1;
                }
                Some(Event::Lost(l)) => lost += l.count,
                _ => {}
            }
        }
        if received + lost >= TRICKLE {
            break;
        }
        let msg = tokio::time::timeout(WAIT, paused.message())
            .await
            .unwrap_or_else(|_| panic!("stuck at received {received} + lost {lost}"));
        match msg {
            Ok(Some(msg)) => pending.extend(msg.events),
            Ok(None) => panic!("stream ended after {received} received + {lost} lost"),
            Err(status) => {
                panic!("transport error after {received} received + {lost} lost: {status:?}")
            }
        }
    }
    assert_eq!(received + lost, TRICKLE);
    // The stream is still alive.
    device
        .send(&Frame::new(CanId::standard(MARKER_ID).unwrap(), &[]).unwrap())
        .unwrap();
    let next = read_frames(&mut paused, &mut pending, 1).await;
    assert_eq!(next[0].id, MARKER_ID);
    let stats = server.gateway().bus("can0").unwrap().stats();
    assert_eq!(
        stats.subscriber_drops, lost,
        "every loss counted on the bus"
    );
    server.shutdown();
}

/// Two buses, the metrics endpoint: which stream messages waited for more
/// events shows per bus (`cangate_stream_messages_held_total`).
const TWO_BUSES_WITH_METRICS: &str = r#"
metrics_listen = "127.0.0.1:0"

[[bus]]
name = "quick0"
backend = "virtual"

[[bus]]
name = "paced0"
backend = "virtual"
"#;

/// Frames one at a time, each read before the next is sent (a
/// request/response exchange over the stream), past the small-message
/// burst: a `low_latency` stream sends every one at once; a default one
/// makes some wait for company (and counts them), which is what keeps a
/// paused reader's HTTP/2 connection alive.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_low_latency_stream_never_holds_a_frame_back_a_default_one_does_past_its_burst() {
    let server = start_server(TWO_BUSES_WITH_METRICS).await;
    let metrics = server.metrics_addr.expect("metrics configured");
    let mut c = client(&server).await;
    let held = |text: &str, bus: &str| -> u64 {
        let prefix = format!("cangate_stream_messages_held_total{{bus=\"{bus}\"}} ");
        text.lines()
            .find_map(|l| l.strip_prefix(&prefix))
            .map_or(0, |v| v.trim().parse().unwrap())
    };
    // The default stream first, until it holds one back: past the burst of
    // 1,000 plus what refilled meanwhile (more on a slow host).
    let mut needed = 0;
    let (mut paced, mut paced_pending) =
        open_stream(&mut c, stream_request("paced0", vec![])).await;
    let paced_device = server
        .gateway()
        .network()
        .get("paced0")
        .unwrap()
        .connect(false);
    while held(&scrape_metrics(metrics).await, "paced0") == 0 {
        assert!(
            needed < 50_000,
            "the default stream never paced its small messages"
        );
        exchange(&paced_device, &mut paced, &mut paced_pending, needed, 100).await;
        needed += 100;
    }
    // The low-latency one, as many and more: nothing held back.
    let mut req = stream_request("quick0", vec![]);
    req.low_latency = true;
    let (mut quick, mut quick_pending) = open_stream(&mut c, req).await;
    let quick_device = server
        .gateway()
        .network()
        .get("quick0")
        .unwrap()
        .connect(false);
    exchange(
        &quick_device,
        &mut quick,
        &mut quick_pending,
        0,
        needed + 500,
    )
    .await;
    let text = scrape_metrics(metrics).await;
    assert_eq!(held(&text, "quick0"), 0, "{text}");
    server.shutdown();
}

/// `count` frames numbered from `first`, each sent once the previous one
/// came back on `stream`.
async fn exchange(
    device: &cangate_can::virtual_bus::VirtualPort,
    stream: &mut tonic::Streaming<cangate_client::pb::StreamFramesResponse>,
    pending: &mut Vec<cangate_client::pb::StreamEvent>,
    first: u64,
    count: u64,
) {
    let id = CanId::standard(0x181).unwrap();
    for seq in first..first + count {
        device
            .send(&Frame::new(id, &seq.to_le_bytes()).unwrap())
            .unwrap();
        let got = read_frames(stream, pending, 1).await;
        assert_eq!(got[0].data, seq.to_le_bytes(), "in order, none lost");
    }
}
