//! Client A streams with filters, client B sends: A sees exactly the
//! matching frames, in order, with timestamps, as received frames of a
//! client (B) marked with its sender; extended ids, remote frames and CAN
//! FD round-trip unchanged.

use cangate_client::can::{Filter, Frame};
use cangate_client::pb;
use cangate_tests::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn filtered_stream_sees_exactly_the_matching_frames_in_order() {
    let server = start_server(ONE_BUS).await;
    let mut a = client(&server).await;
    let mut b = client(&server).await;
    let filters: Vec<Filter> = vec![
        "100:700".parse().unwrap(),
        "1F334455:1FFFFFFF".parse().unwrap(),
    ];
    let mut req = stream_request(
        "can0",
        filters.iter().map(cangate_client::filter_to_pb).collect(),
    );
    req.include_transmitted = true;
    let (mut stream, mut pending) = open_stream(&mut a, req).await;

    let texts = [
        "100#01",                         // matches 100:700
        "200#02",                         // no
        "1F334455#DEADBEEF",              // matches the extended filter
        "00000455#03",                    // extended, other id: no
        "1AB#R4",                         // remote, matches 100:700
        "17F##1AABBCCDDEEFF001122334455", // FD with BRS, matches
        "7FF#",                           // no
        "155##0",                         // FD, empty payload, matches
        "00000100#04", // extended 0x100: the std filter matches both formats (candump semantics)
    ];
    let frames: Vec<Frame> = texts.iter().map(|t| t.parse().unwrap()).collect();
    let before = cangate_client::can::Timestamp::now().as_nanos();
    b.send("can0", &frames).await.expect("send accepted");
    let expected: Vec<&Frame> = frames
        .iter()
        .filter(|f| filters.iter().any(|flt| flt.matches(f)))
        .collect();
    assert_eq!(expected.len(), 6);

    let got = read_frames(&mut stream, &mut pending, expected.len()).await;
    let mut last_ts = 0;
    for (g, want) in got.iter().zip(&expected) {
        let back = cangate_client::frame_from_pb(g).expect("valid frame");
        assert_eq!(back.to_string(), want.to_string());
        assert_eq!(
            (g.direction, g.origin),
            (pb::Direction::Rx as i32, pb::FrameOrigin::Client as i32),
            "B's frames are received from a client, as a socket receives another's"
        );
        let sender = g.sender.as_ref().expect("B is named");
        assert!(
            sender.id > 0 && sender.client.starts_with("127.0.0.1:"),
            "{sender:?}"
        );
        assert_eq!(
            sender.id,
            got[0].sender.as_ref().unwrap().id,
            "one call, one sender"
        );
        assert!(g.timestamp_ns >= before, "timestamp is set and recent");
        assert!(g.timestamp_ns >= last_ts, "timestamps are monotonic");
        last_ts = g.timestamp_ns;
    }
    assert_eq!(got.len(), expected.len());
    assert_quiet(&mut stream).await;
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_from_a_device_arrive_as_rx() {
    let server = start_server(ONE_BUS).await;
    let vbus = server.gateway().network().get("can0").unwrap();
    let device = vbus.connect(false);
    let mut a = client(&server).await;
    let (mut stream, mut pending) = open_stream(&mut a, stream_request("can0", vec![])).await;
    let f: Frame = "1F334455#0102030405060708".parse().unwrap();
    device.send(&f).unwrap();
    let got = read_frames(&mut stream, &mut pending, 1).await;
    assert_eq!(got[0].direction, pb::Direction::Rx as i32);
    assert_eq!(got[0].origin, pb::FrameOrigin::Bus as i32);
    assert_eq!(got[0].sender, None);
    assert!(got[0].extended);
    assert_eq!(got[0].id, 0x1F33_4455);
    assert_eq!(got[0].data, vec![1, 2, 3, 4, 5, 6, 7, 8]);
    assert!(got[0].timestamp_ns > 0);
    // Without include_transmitted, the gateway's own frames are not shown;
    // a client's are (they are received frames, as on a SocketCAN host).
    let own: Frame = "080#".parse().unwrap();
    server
        .gateway()
        .bus("can0")
        .unwrap()
        .send(vec![own])
        .await
        .unwrap();
    let mut b = client(&server).await;
    b.send("can0", &["123#00".parse().unwrap()]).await.unwrap();
    let got = read_frames(&mut stream, &mut pending, 1).await;
    assert_eq!(
        (got[0].id, got[0].direction),
        (0x123, pb::Direction::Rx as i32)
    );
    assert_eq!(got[0].origin, pb::FrameOrigin::Client as i32);
    assert_quiet(&mut stream).await;
    let info = b.get_bus("can0").await.unwrap();
    let stats = info.statistics.unwrap();
    assert_eq!((stats.rx_frames, stats.tx_frames), (1, 2));
    server.shutdown();
}
