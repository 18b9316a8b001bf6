//! The bit-timed virtual bus: frames take their modelled time on the wire
//! (checked on the bus timestamps, not on wall time), arbitration picks the
//! lowest identifier among queued senders, and the load figure matches.

use cangate_client::can::{CanId, Frame};
use cangate_client::pb;
use cangate_tests::*;

/// A standard 8-byte frame with worst-case stuffing: 111 + 24 stuff bits.
const FRAME_NS: u64 = 135_000;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_take_modelled_bus_time_in_arbitration_order() {
    // The train is a client's (SendFrames): without a client share (100 %)
    // it goes to the wire at once, back to back (bus_budget.rs tests the
    // share).
    let server = start_server(
        "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\nbitrate = 1000000\n\
         bit_timing = true\nstuffing = \"worst-case\"\nclient_share_percent = 100\n",
    )
    .await;
    let vbus = server.gateway().network().get("can0").unwrap();
    let mut c = client(&server).await;
    let mut req = stream_request("can0", vec![]);
    req.include_transmitted = true;
    req.queue_length = 10_000;
    let (mut stream, mut pending) = open_stream(&mut c, req).await;

    // A train of 1,000 8-byte frames with the highest priority id, sent by
    // a client; it occupies the bus for 135 ms of bus time.
    let train: Vec<Frame> = (0..1000u64)
        .map(|i| Frame::new(CanId::Standard(0x000), &i.to_le_bytes()).unwrap())
        .collect();
    c.send("can0", &train).await.unwrap();
    // While it runs, four other nodes queue one frame each, in an order
    // unrelated to their priority.
    let ports: Vec<_> = (0..4).map(|_| vbus.connect(false)).collect();
    for (port, id) in ports.iter().zip([0x300u16, 0x100, 0x200, 0x050]) {
        port.send(&Frame::new(CanId::Standard(id), &[0xAA; 8]).unwrap())
            .unwrap();
    }

    let got = read_frames(&mut stream, &mut pending, 1004).await;
    for (i, f) in got[..1000].iter().enumerate() {
        assert_eq!(f.id, 0);
        assert_eq!(
            f.data,
            (i as u64).to_le_bytes(),
            "the train keeps its order"
        );
        assert_eq!(f.origin, pb::FrameOrigin::Client as i32);
    }
    // Back to back: each frame ends exactly one frame time after the last.
    for w in got.windows(2) {
        assert_eq!(w[1].timestamp_ns - w[0].timestamp_ns, FRAME_NS);
    }
    assert_eq!(
        got[999].timestamp_ns - got[0].timestamp_ns,
        999 * FRAME_NS,
        "1,000 frames take 1,000 x 135 us of bus time"
    );
    // Then the queued nodes, lowest identifier first.
    let ids: Vec<u32> = got[1000..].iter().map(|f| f.id).collect();
    assert_eq!(ids, vec![0x050, 0x100, 0x200, 0x300]);
    assert!(
        got[1000..]
            .iter()
            .all(|f| f.direction == pb::Direction::Rx as i32)
    );

    // Load: 1,004 x 135 us busy within the last second's window (nine
    // complete 100 ms buckets plus the current one): 13.5 % to 15.1 %. The
    // figure is refreshed every 20 ms, so the last frames may not be in it
    // yet: poll (bounded) until they are, then check it is not above.
    let mut load = 0.0;
    for _ in 0..20 {
        load = c
            .get_bus("can0")
            .await
            .unwrap()
            .statistics
            .unwrap()
            .load_percent;
        if load >= 13.0 {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
    }
    assert!((13.0..=15.6).contains(&load), "load {load}");
    server.shutdown();
}
