use super::*;
use crate::filter::Filter;
use crate::frame::CanId;
use crate::virtual_bus::{VirtualBus, VirtualBusConfig};

fn start(bus: &VirtualBus) -> (BusHandle, CancellationToken) {
    start_with_bitrate(bus, Some(1_000_000))
}

/// `bitrate: None`: no load meter, so the echo follows the subscribers.
fn start_with_bitrate(bus: &VirtualBus, bitrate: Option<u32>) -> (BusHandle, CancellationToken) {
    let cancel = CancellationToken::new();
    let info = BusInfo {
        name: "can0".into(),
        kind: BackendKind::Virtual,
        interface: bus.name().into(),
        fd: true,
        bitrate,
        data_bitrate: None,
        bit_timed: false,
        stuffing: Stuffing::Exact,
    };
    let (h, _) = BusHandle::spawn(info, Backend::Virtual(bus.connect(true)), cancel.clone());
    (h, cancel)
}

fn frame(id: u32) -> Frame {
    Frame::new(CanId::standard(id).unwrap(), &[id as u8]).unwrap()
}

#[tokio::test]
async fn filtered_subscription_sees_matching_rx_and_tx() {
    let vbus = VirtualBus::new("v", VirtualBusConfig::default());
    let (h, _c) = start(&vbus);
    let mut sub = h.subscribe(
        FrameSelector {
            filters: vec![Filter::exact_standard(0x10)],
            error_frames: false,
            transmitted: true,
        },
        16,
    );
    let peer = vbus.connect(false);
    peer.send(&frame(0x11)).unwrap();
    peer.send(&frame(0x10)).unwrap();
    h.send(vec![frame(0x10), frame(0x12)]).await.unwrap();
    let a = sub.recv().await.unwrap();
    let b = sub.recv().await.unwrap();
    assert!(
        matches!(a, BusItem::Frame { direction: Direction::Rx, frame } if frame.raw_id() == 0x10)
    );
    assert!(
        matches!(b, BusItem::Frame { direction: Direction::Tx, frame } if frame.raw_id() == 0x10)
    );
    assert!(sub.try_recv().is_none());
    let st = h.stats();
    assert_eq!((st.rx_frames, st.tx_frames), (2, 2));
}

#[tokio::test]
async fn slow_subscriber_gets_exact_lost_count_in_place() {
    let vbus = VirtualBus::new("v", VirtualBusConfig::default());
    let (h, _c) = start(&vbus);
    let mut slow = h.subscribe(FrameSelector::default(), 4);
    let mut fast = h.subscribe(FrameSelector::default(), 10_000);
    let peer = vbus.connect(false);
    for i in 0..100 {
        peer.send(&frame(i)).unwrap();
    }
    for _ in 0..100 {
        assert!(matches!(fast.recv().await, Some(BusItem::Frame { .. })));
    }
    // The slow one has the first 4 frames queued, then the notice for
    // the other 96.
    for i in 0..4 {
        assert!(
            matches!(slow.recv().await, Some(BusItem::Frame { frame, .. }) if frame.raw_id() == i)
        );
    }
    assert_eq!(slow.recv().await, Some(BusItem::Lost(96)));
    assert_eq!(slow.lost_total(), 96);
    assert_eq!(h.stats().subscriber_drops, 96);
    peer.send(&frame(0x7F)).unwrap();
    assert!(
        matches!(slow.recv().await, Some(BusItem::Frame { frame, .. }) if frame.raw_id() == 0x7F)
    );
}

#[tokio::test]
async fn bus_off_is_reported_and_refuses_sends() {
    let vbus = VirtualBus::new("v", VirtualBusConfig::default());
    let (h, _c) = start(&vbus);
    let mut sub = h.subscribe(FrameSelector::default(), 16);
    vbus.force_bus_off();
    assert!(
        matches!(sub.recv().await, Some(BusItem::State(s)) if s.state == crate::state::BusState::BusOff)
    );
    let err = h.send(vec![frame(1)]).await.unwrap_err();
    assert_eq!(err.sent, 0);
    assert!(matches!(err.error, SendError::BusOff(_)));
    let err = h.try_submit(vec![frame(1)]).unwrap_err();
    assert!(matches!(err.error, SendError::BusOff(_)));
}

/// The SYNC thread's path: sent from a plain thread, no runtime, and
/// published as TX like any other send.
#[tokio::test]
async fn try_submit_sends_without_a_runtime() {
    let vbus = VirtualBus::new("v", VirtualBusConfig::default());
    let mut other = vbus.connect(false);
    let (h, _c) = start(&vbus);
    let mut sub = h.subscribe(
        FrameSelector {
            transmitted: true,
            ..FrameSelector::default()
        },
        16,
    );
    let sender = h.clone();
    let r = std::thread::spawn(move || sender.try_submit(vec![frame(0x80)]))
        .join()
        .unwrap();
    assert!(matches!(r, Ok(None)));
    assert!(
        matches!(other.recv().await, crate::virtual_bus::PortEvent::Frame { frame, .. } if frame.raw_id() == 0x80)
    );
    assert!(
        matches!(sub.recv().await, Some(BusItem::Frame { direction: Direction::Tx, frame }) if frame.raw_id() == 0x80)
    );
    assert_eq!(h.stats().tx_frames, 1);
}

/// A virtual bus whose ports queue a single event: the gateway port's
/// overflows then count the echoes sent to it while the bus task did
/// not run. (A `#[tokio::test]` runs on one thread, so the bus task
/// only runs when the test awaits something pending, and sending on a
/// virtual bus never does.)
fn one_slot_bus() -> VirtualBus {
    VirtualBus::new(
        "v",
        VirtualBusConfig {
            port_queue: 1,
            ..VirtualBusConfig::default()
        },
    )
}

fn tx_selector(filters: Vec<Filter>) -> FrameSelector {
    FrameSelector {
        filters,
        error_frames: false,
        transmitted: true,
    }
}

/// The next item of a subscription; a test fails rather than hangs
/// when it does not come.
async fn next_item(sub: &mut Subscription) -> BusItem {
    tokio::time::timeout(Duration::from_secs(5), sub.recv())
        .await
        .expect("an item within 5 s")
        .expect("bus running")
}

async fn next_frame(sub: &mut Subscription) -> (u32, Direction) {
    loop {
        match next_item(sub).await {
            BusItem::Frame { frame, direction } => return (frame.raw_id(), direction),
            BusItem::State(_) => {}
            BusItem::Lost(n) => panic!("lost {n}"),
        }
    }
}

#[tokio::test]
async fn reselect_changes_what_a_subscription_gets_from_the_next_frame() {
    let vbus = VirtualBus::new("v", VirtualBusConfig::default());
    let (h, _c) = start_with_bitrate(&vbus, None);
    let mut sub = h.subscribe(
        FrameSelector {
            filters: vec![Filter::exact_standard(0x181)],
            ..FrameSelector::default()
        },
        16,
    );
    let peer = vbus.connect(false);
    peer.send(&frame(0x181)).unwrap();
    peer.send(&frame(0x1A0)).unwrap();
    assert_eq!(next_frame(&mut sub).await, (0x181, Direction::Rx));
    assert!(h.reselect(
        &sub.key(),
        FrameSelector {
            filters: vec![Filter::exact_standard(0x1A0)],
            ..FrameSelector::default()
        }
    ));
    peer.send(&frame(0x181)).unwrap();
    peer.send(&frame(0x1A0)).unwrap();
    assert_eq!(next_frame(&mut sub).await, (0x1A0, Direction::Rx));
    assert!(sub.try_recv().is_none(), "0x181 no longer passes");
    let key = sub.key();
    drop(sub);
    peer.send(&frame(0x1A0)).unwrap();
    // The bus task drops an ended subscriber at its next fan-out.
    for _ in 0..100 {
        if !h.reselect(&key, FrameSelector::default()) {
            return;
        }
        tokio::time::sleep(std::time::Duration::from_millis(5)).await;
    }
    panic!("an ended subscription is still reselectable");
}

#[tokio::test]
async fn own_frames_are_echoed_only_for_subscribers_to_transmitted() {
    let vbus = one_slot_bus();
    let (h, _c) = start_with_bitrate(&vbus, None);
    // Set at spawn: no subscriber, so no echo.
    assert_eq!(h.echo_filters(), Some(Vec::new()));
    let mut rx_only = h.subscribe(FrameSelector::default(), 16);
    assert_eq!(h.echo_filters(), Some(Vec::new()));

    // Sent from this task, the bus task not running in between: with
    // an echo, the second and third frame would overflow the port.
    h.send(vec![frame(0x080)]).await.unwrap();
    h.send(vec![frame(0x181)]).await.unwrap();
    h.try_submit(vec![frame(0x080)]).unwrap();
    assert_eq!(vbus.stats().port_overflows, 0, "nothing was echoed");
    assert_eq!(h.stats().tx_frames, 3, "counted at send time");

    // A subscriber to transmitted 0x080: 0x080 is echoed, 0x181 not.
    let mut tx = h.subscribe(tx_selector(vec![Filter::exact_standard(0x080)]), 16);
    assert_eq!(h.echo_filters(), Some(vec![Filter::exact_standard(0x080)]));
    h.send(vec![frame(0x181), frame(0x080), frame(0x181)])
        .await
        .unwrap();
    assert_eq!(vbus.stats().port_overflows, 0, "only 0x080 was echoed");
    assert_eq!(next_frame(&mut tx).await, (0x080, Direction::Tx));
    h.submit(vec![frame(0x080), frame(0x181)]).await.unwrap();
    assert_eq!(next_frame(&mut tx).await, (0x080, Direction::Tx));
    assert!(tx.try_recv().is_none());
    assert!(rx_only.try_recv().is_none(), "no Tx for an Rx subscriber");

    // Gone: the next fan-out (a peer's frame) narrows the echo again.
    drop(tx);
    let peer = vbus.connect(false);
    peer.send(&frame(0x700)).unwrap();
    assert_eq!(next_frame(&mut rx_only).await, (0x700, Direction::Rx));
    assert_eq!(h.echo_filters(), Some(Vec::new()));
    drop(peer); // Its one-slot queue would overflow, not ours.
    h.send(vec![frame(0x080), frame(0x080)]).await.unwrap();
    assert_eq!(vbus.stats().port_overflows, 0, "nothing was echoed");
}

#[tokio::test]
async fn echo_filter_is_the_union_of_the_transmitted_selectors() {
    let vbus = VirtualBus::new("v", VirtualBusConfig::default());
    let (h, _c) = start_with_bitrate(&vbus, None);
    let a = Filter::exact_standard(0x080);
    let b = Filter::exact_standard(0x181);
    let _rx_only = h.subscribe(
        FrameSelector {
            filters: vec![Filter::exact_standard(0x700)],
            ..FrameSelector::default()
        },
        16,
    );
    let sub_a = h.subscribe(tx_selector(vec![a]), 16);
    let _sub_ab = h.subscribe(tx_selector(vec![a, b]), 16);
    assert_eq!(h.echo_filters(), Some(vec![a, b]), "deduplicated union");
    // No filters: every frame, so the whole echo.
    let all = h.subscribe(tx_selector(Vec::new()), 16);
    assert_eq!(h.echo_filters(), None);
    drop((all, sub_a));
    // A state change fans out too, and drops the closed subscribers.
    vbus.force_bus_off();
    tokio::time::timeout(Duration::from_secs(5), async {
        while h.echo_filters().is_none() {
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
    })
    .await
    .expect("echo filter narrowed");
    assert_eq!(h.echo_filters(), Some(vec![a, b]));
}

/// Transmitted frames from every send path and thread reach a
/// subscriber in order with the echo narrowed to its filter.
#[tokio::test]
async fn filtered_echo_keeps_every_wanted_tx_frame_in_order() {
    let vbus = VirtualBus::new("v", VirtualBusConfig::default());
    let (h, _c) = start_with_bitrate(&vbus, None);
    let mut sub = h.subscribe(tx_selector(vec![Filter::exact_standard(0x080)]), 4096);
    let sender = h.clone();
    let thread = std::thread::spawn(move || {
        for i in 0..500u16 {
            let f = Frame::new(CanId::Standard(0x080), &i.to_le_bytes()).unwrap();
            assert!(sender.try_submit(vec![f, frame(0x181)]).unwrap().is_none());
        }
    });
    for i in 0..500u16 {
        let f = Frame::new(CanId::Standard(0x200), &i.to_le_bytes()).unwrap();
        h.send(vec![f, frame(0x080)]).await.unwrap();
    }
    thread.join().unwrap();
    let (mut from_thread, mut from_task) = (0u16, 0);
    while from_thread < 500 || from_task < 500 {
        match next_item(&mut sub).await {
            BusItem::Frame { frame, direction } => {
                assert_eq!((frame.raw_id(), direction), (0x080, Direction::Tx));
                if frame.data().len() == 2 {
                    let i = u16::from_le_bytes([frame.data()[0], frame.data()[1]]);
                    assert_eq!(i, from_thread, "in order");
                    from_thread += 1;
                } else {
                    from_task += 1;
                }
            }
            other => panic!("{other:?}"),
        }
    }
    assert!(sub.try_recv().is_none());
    assert_eq!(h.stats().tx_frames, 2000);
}

/// With a bitrate the load meter needs every frame: the echo stays on
/// whatever the subscribers want.
#[tokio::test]
async fn bus_with_bitrate_keeps_echoing_everything() {
    let vbus = one_slot_bus();
    let (h, _c) = start_with_bitrate(&vbus, Some(1_000_000));
    assert_eq!(h.echo_filters(), None);
    let tx = h.subscribe(tx_selector(vec![Filter::exact_standard(0x080)]), 16);
    assert_eq!(h.echo_filters(), None);
    h.send(vec![frame(0x181), frame(0x181), frame(0x181)])
        .await
        .unwrap();
    assert_eq!(vbus.stats().port_overflows, 2, "all three echoed");
    drop(tx);
    tokio::time::sleep(Duration::from_millis(60)).await;
    assert_eq!(h.echo_filters(), None);
    assert!(h.stats().load_percent > 0.0, "own frames metered");
}

/// A bit-timed 1 Mbit/s virtual bus and its gateway handle (paced).
fn start_bit_timed() -> (VirtualBus, BusHandle, CancellationToken) {
    let vbus = VirtualBus::new(
        "timed",
        VirtualBusConfig {
            bit_timing: Some(BitTiming::new(1_000_000)),
            ..VirtualBusConfig::default()
        },
    );
    let cancel = CancellationToken::new();
    let info = BusInfo {
        name: "can0".into(),
        kind: BackendKind::Virtual,
        interface: vbus.name().into(),
        fd: false,
        bitrate: Some(1_000_000),
        data_bitrate: None,
        bit_timed: true,
        stuffing: Stuffing::Exact,
    };
    let (h, _) = BusHandle::spawn(info, Backend::Virtual(vbus.connect(true)), cancel.clone());
    (vbus, h, cancel)
}

/// [`start_bit_timed`] with client frames paced to 1 % of the bus.
fn start_client_share_1() -> (VirtualBus, BusHandle, CancellationToken) {
    let (vbus, h, c) = start_bit_timed();
    h.set_tx_shares(TxShares {
        client_percent: 1,
        bulk_percent: 50,
    })
    .unwrap();
    (vbus, h, c)
}

/// Client frames on the highest-priority identifier, paced to 1 % of
/// the bus: the gateway's own frame, sent after them, reaches the other
/// node long before the last of them, and the client's call lasts at
/// least as long as its share allows.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn client_frames_are_paced_behind_own_frames() {
    let (vbus, h, _c) = start_client_share_1();
    let mut peer = vbus.connect(false);
    let flood: Vec<Frame> = (0..100u8)
        .map(|i| Frame::new(CanId::Standard(0x001), &[i; 8]).unwrap())
        .collect();
    let started = std::time::Instant::now();
    let client = h.clone();
    let flood_task = tokio::spawn(async move { client.send_as(TxClass::Client, flood).await });
    // Let the first chunk go out, then send an own frame.
    loop {
        if let PortEvent::Frame { frame, .. } = peer.recv().await {
            assert_eq!(frame.raw_id(), 0x001);
            break;
        }
    }
    h.send(vec![frame(0x080)]).await.unwrap();
    let mut position = None;
    let mut seen = 1;
    while seen < 101 {
        let PortEvent::Frame { frame, .. } =
            tokio::time::timeout(Duration::from_secs(10), peer.recv())
                .await
                .expect("frames keep coming")
        else {
            continue;
        };
        if frame.raw_id() == 0x080 {
            position = Some(seen);
        }
        seen += 1;
    }
    tokio::time::timeout(Duration::from_secs(10), flood_task)
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    let position = position.expect("own frame sent");
    assert!(
        position <= 50,
        "own frame only after {position} client frames"
    );
    // 100 frames of about 111 us at 1 %: about 11 ms of wall time per
    // frame after the first burst.
    assert!(
        started.elapsed() >= Duration::from_millis(500),
        "{:?}",
        started.elapsed()
    );
    let st = h.stats();
    assert!(st.client_frames_delayed >= 90, "{st:?}");
    assert_eq!(st.budget_queued, 0);
    assert_eq!(st.tx_frames, 101);
}

/// A queued client batch comes back at once; its outcome is known
/// without waiting once it is on the bus, and a batch the bus could
/// not send reports why (and leaves no echo outstanding).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn queued_client_frames_report_their_outcome_later() {
    let (vbus, h, _c) = start_client_share_1();
    let mut peer = vbus.connect(false);
    let client = ClientId::next();
    let mut one = h.queue_as_client(client, vec![frame(0x123)]).await;
    let got = tokio::time::timeout(Duration::from_secs(5), peer.recv())
        .await
        .expect("the queued frame arrives");
    assert!(matches!(got, PortEvent::Frame { frame, .. } if frame.raw_id() == 0x123));
    let outcome = loop {
        if let Some(o) = one.try_outcome() {
            break o;
        }
        tokio::time::sleep(Duration::from_millis(1)).await;
    };
    assert_eq!(outcome, Ok(()));
    // At 1 % of 1 Mbit/s, 200 frames take about 2 s: bus-off comes
    // first and the rest are not sent.
    let many = h.queue_as_client(client, vec![frame(0x124); 200]).await;
    vbus.force_bus_off();
    let err = tokio::time::timeout(Duration::from_secs(10), many.outcome())
        .await
        .expect("an outcome, not a hang")
        .unwrap_err();
    assert!(err.sent < 200, "{err}");
    assert_eq!(h.shared.counters.client_echo.load(Ordering::Relaxed), 0);
    // Refused before the queue: known at once.
    let mut refused = h.queue_as_client(client, vec![frame(0x125)]).await;
    for _ in 0..2 {
        // The same answer however often it is asked.
        assert!(matches!(
            refused.try_outcome(),
            Some(Err(SendFailure {
                error: SendError::BusOff(_),
                ..
            }))
        ));
    }
    assert_eq!(h.shared.counters.client_echo.load(Ordering::Relaxed), 0);
}

/// A client batch given up before its outcome (the [`PendingSend`]
/// dropped: a cancelled call, a closed stream) is withdrawn: what the
/// share had not let out yet is never sent, and counted; the frames
/// of the client's next batch follow the ones that did go out.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_dropped_client_batch_is_withdrawn() {
    let (vbus, h, _c) = start_client_share_1();
    let mut peer = vbus.connect(false);
    let client = ClientId::next();
    // About 11 s at 1 % of the bus.
    let pending = h.queue_as_client(client, vec![frame(0x001); 1000]).await;
    // The first frames go out, then the client goes away.
    loop {
        if let PortEvent::Frame { frame, .. } = peer.recv().await {
            assert_eq!(frame.raw_id(), 0x001);
            break;
        }
    }
    drop(pending);
    let t0 = std::time::Instant::now();
    let withdrawn = loop {
        let st = h.stats();
        if st.client_frames_withdrawn > 0 {
            break st.client_frames_withdrawn;
        }
        assert!(t0.elapsed() < Duration::from_secs(10), "{st:?}");
        tokio::time::sleep(Duration::from_millis(1)).await;
    };
    assert!(withdrawn >= 900, "{withdrawn} withdrawn");
    let st = h.stats();
    assert_eq!(st.budget_queued, 0, "{st:?}");
    // A marker behind the sent ones in the client's FIFO: when it
    // arrives, everything that went out before it has too.
    h.send_as_client(client, vec![frame(0x7FE)]).await.unwrap();
    let mut sent = 1u64;
    loop {
        match tokio::time::timeout(Duration::from_secs(10), peer.recv())
            .await
            .expect("the marker arrives")
        {
            PortEvent::Frame { frame, .. } if frame.raw_id() == 0x001 => sent += 1,
            PortEvent::Frame { frame, .. } if frame.raw_id() == 0x7FE => break,
            _ => {}
        }
    }
    assert_eq!(sent + withdrawn, 1000, "{sent} sent, {withdrawn} withdrawn");
    // The echo count is back to zero: nothing is waited for.
    let t0 = std::time::Instant::now();
    while h.shared.counters.client_echo.load(Ordering::Relaxed) != 0 {
        assert!(t0.elapsed() < Duration::from_secs(10));
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
}

/// Client frames take only time nobody else needs: a client's frames
/// on the highest-priority identifier, queued while another node has
/// a backlog, go out after the whole backlog, although each of them
/// would have won its arbitration.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn client_frames_wait_while_other_frames_wait_for_the_wire() {
    let (vbus, h, _c) = start_bit_timed();
    let mut watcher = vbus.connect(false);
    let device = vbus.connect(false);
    // About 20 ms of the device's frames, queued at once.
    device.send_batch(&vec![frame(0x701); 200]).unwrap();
    h.send_as_client(ClientId::next(), vec![frame(0x001); 5])
        .await
        .unwrap();
    let mut order = Vec::new();
    while order.len() < 205 {
        if let PortEvent::Frame { frame, .. } =
            tokio::time::timeout(Duration::from_secs(10), watcher.recv())
                .await
                .expect("frames keep coming")
        {
            order.push(frame.raw_id());
        }
    }
    let first_client = order.iter().position(|&id| id == 0x001).unwrap();
    assert_eq!(first_client, 200, "a client frame overtook the backlog");
    assert!(h.stats().client_frames_delayed >= 5);
}

/// A long client batch waits in front of the wire a chunk of
/// [`CLIENT_CHUNK_BUS_TIME_NS`] at a time (back-pressure), never as a
/// whole: the client's backlog there is bounded in bus time.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_long_client_batch_waits_a_chunk_at_a_time() {
    let (vbus, h, _c) = start_client_share_1();
    let mut peer = vbus.connect(false);
    let client = h.clone();
    let batch = vec![frame(0x001); 1000];
    let one = BitTiming::new(1_000_000).frame_duration_ns(&batch[0]);
    let chunk = CLIENT_CHUNK_BUS_TIME_NS / one;
    let sending = tokio::spawn(async move { client.send_as_client(ClientId::next(), batch).await });
    let mut most = 0;
    let mut seen = 0;
    while seen < 40 {
        most = most.max(h.stats().budget_queued);
        if let Ok(PortEvent::Frame { .. }) =
            tokio::time::timeout(Duration::from_millis(1), peer.recv()).await
        {
            seen += 1;
        }
    }
    assert!(most > 0 && most <= chunk, "{most} queued, chunk {chunk}");
    // Given up: the rest of its chunk is withdrawn, the later chunks
    // are never queued; all of them count as withdrawn.
    sending.abort();
    let _ = sending.await;
    let t0 = std::time::Instant::now();
    let st = loop {
        let st = h.stats();
        if st.client_frames_withdrawn + st.tx_frames == 1000 {
            break st;
        }
        assert!(t0.elapsed() < Duration::from_secs(10), "{st:?}");
        tokio::time::sleep(Duration::from_millis(1)).await;
    };
    // About 40 sent at 1 %: nearly all the rest withdrawn.
    assert!(st.client_frames_withdrawn >= 500, "{st:?}");
    assert_eq!(st.budget_queued, 0, "{st:?}");
}

/// A client that keeps queueing while its share is used up is refused
/// beyond [`MAX_BUDGET_QUEUED`] frames, with a reason; nothing of the
/// refused batch is sent, and it is counted.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn client_backlog_is_bounded() {
    let (_vbus, h, _c) = start_client_share_1();
    let batch = |n: usize| vec![frame(0x100); n];
    h.submit_as(TxClass::Client, batch(40_000)).await.unwrap();
    let err = h.send_as(TxClass::Client, batch(20_000)).await.unwrap_err();
    assert_eq!(err.sent, 0);
    assert!(
        matches!(err.error, SendError::BudgetExhausted { percent: 1, .. }),
        "{err}"
    );
    assert!(err.to_string().contains("client_share_percent"), "{err}");
    let st = h.stats();
    assert_eq!(st.client_frames_refused, 20_000);
    assert!(st.budget_queued > 30_000, "{st:?}");
    // Bulk data is not refused: its transfers pace themselves.
    h.submit_as(TxClass::Bulk, batch(20_000)).await.unwrap();
    assert!(
        h.set_tx_shares(TxShares {
            client_percent: 0,
            bulk_percent: 50
        })
        .is_err()
    );
}

/// Where frames take no bus time, client frames go out at once.
#[tokio::test]
async fn untimed_bus_does_not_pace() {
    let vbus = VirtualBus::new("v", VirtualBusConfig::default());
    let (h, _c) = start(&vbus);
    let mut peer = vbus.connect(false);
    h.send_as(TxClass::Client, vec![frame(0x001); 1000])
        .await
        .unwrap();
    for _ in 0..1000 {
        assert!(matches!(peer.recv().await, PortEvent::Frame { .. }));
    }
    assert_eq!(h.stats().client_frames_delayed, 0);
}

fn attach_options(filters: Vec<Filter>, receive_own: bool, fd: bool) -> AttachOptions {
    AttachOptions {
        selector: FrameSelector {
            filters,
            ..FrameSelector::default()
        },
        receive_own,
        fd,
        queue: 64,
    }
}

/// The next frame of a subscription with its direction and sender.
async fn next_marked(sub: &mut Subscription) -> (u32, Direction, Option<ClientId>) {
    loop {
        match next_item(sub).await {
            BusItem::Frame { frame, direction } => {
                return (frame.raw_id(), direction, frame.sender());
            }
            BusItem::State(_) => {}
            BusItem::Lost(n) => panic!("lost {n}"),
        }
    }
}

/// Loopback: a client's frame reaches the wire, every other subscriber
/// as received (also one that did not ask for transmitted frames, as
/// the gateway's stacks do not), marked with its sender, and its own
/// subscription only when asked, as transmitted.
#[tokio::test]
async fn client_frames_reach_the_other_subscribers_as_received() {
    let vbus = VirtualBus::new("v", VirtualBusConfig::default());
    let (h, _c) = start(&vbus);
    let mut wire = vbus.connect(false);
    let mut stack = h.subscribe(FrameSelector::default(), 16);
    let mut monitor = h.subscribe(tx_selector(Vec::new()), 16);
    let (a, b) = (ClientId::next(), ClientId::next());
    assert_ne!(a, b);
    let mut own = h.attach(a, attach_options(Vec::new(), true, true));
    let mut quiet = h.attach(a, attach_options(Vec::new(), false, true));
    let mut other = h.attach(b, attach_options(Vec::new(), false, true));

    h.send_as_client(a, vec![frame(0x123)]).await.unwrap();
    assert!(matches!(wire.recv().await, PortEvent::Frame { frame, .. } if frame.raw_id() == 0x123));
    let rx = (0x123, Direction::Rx, Some(a));
    assert_eq!(next_marked(&mut stack).await, rx);
    assert_eq!(next_marked(&mut monitor).await, rx);
    assert_eq!(next_marked(&mut other).await, rx);
    assert_eq!(
        next_marked(&mut own).await,
        (0x123, Direction::Tx, Some(a)),
        "its own frame, asked for"
    );

    // The gateway's own frame: transmitted, to the monitor and to the
    // attached clients (nodes on the bus), not to the plain subscriber.
    h.send(vec![frame(0x080)]).await.unwrap();
    let tx = (0x080, Direction::Tx, None);
    assert_eq!(next_marked(&mut monitor).await, tx);
    assert_eq!(next_marked(&mut own).await, tx);
    assert_eq!(next_marked(&mut quiet).await, tx, "not its own frame");
    assert_eq!(next_marked(&mut other).await, tx);
    assert!(stack.try_recv().is_none());

    // A device's frame: received by everyone, unmarked.
    vbus.connect(false).send(&frame(0x701)).unwrap();
    for sub in [&mut stack, &mut monitor, &mut own, &mut quiet, &mut other] {
        assert_eq!(next_marked(sub).await, (0x701, Direction::Rx, None));
    }
    for sub in [&mut stack, &mut monitor, &mut own, &mut quiet, &mut other] {
        assert!(sub.try_recv().is_none());
    }
    let st = h.stats();
    assert_eq!((st.tx_frames, st.rx_frames), (2, 1));
}

/// An attached client's filters apply to what it receives, and without
/// `fd` it gets no CAN FD frames (as a SocketCAN socket without
/// `CAN_RAW_FD_FRAMES`); the others still get its FD frames.
#[tokio::test]
async fn attached_client_filters_and_fd() {
    let vbus = VirtualBus::new("v", VirtualBusConfig::default());
    let (h, _c) = start(&vbus);
    let (a, b) = (ClientId::next(), ClientId::next());
    let mut classic = h.attach(
        a,
        attach_options(vec![Filter::exact_standard(0x100)], true, false),
    );
    let mut all = h.attach(b, attach_options(Vec::new(), false, true));
    let fd = Frame::new_fd(CanId::Standard(0x100), &[1; 12], true, false).unwrap();
    h.send_as_client(b, vec![fd, frame(0x200), frame(0x100)])
        .await
        .unwrap();
    assert_eq!(
        next_marked(&mut classic).await,
        (0x100, Direction::Rx, Some(b))
    );
    assert!(classic.try_recv().is_none(), "no FD frame, nothing else");
    assert!(all.try_recv().is_none(), "its own frames, not asked for");
    h.send_as_client(a, vec![fd]).await.unwrap();
    let (id, direction, sender) = next_marked(&mut all).await;
    assert_eq!((id, direction, sender), (0x100, Direction::Rx, Some(a)));
    h.send(vec![frame(0x100)]).await.unwrap();
    assert_eq!(
        next_marked(&mut classic).await,
        (0x100, Direction::Tx, None),
        "not its own FD frame, but the gateway's next one"
    );
}

/// On a bus whose echo follows the subscribers (no load meter), client
/// frames still reach the subscribers that did not ask for transmitted
/// frames: the echo opens for them and narrows again once they are
/// back.
#[tokio::test]
async fn client_frames_open_a_narrowed_echo_until_they_are_back() {
    let vbus = VirtualBus::new("v", VirtualBusConfig::default());
    let (h, _c) = start_with_bitrate(&vbus, None);
    let mut stack = h.subscribe(
        FrameSelector {
            filters: vec![Filter::exact_standard(0x581)],
            ..FrameSelector::default()
        },
        16,
    );
    assert_eq!(h.echo_filters(), Some(Vec::new()));
    let client = ClientId::next();
    for round in 0..3u8 {
        h.send_as_client(client, vec![frame(0x581), frame(0x582)])
            .await
            .unwrap();
        assert_eq!(
            next_marked(&mut stack).await,
            (0x581, Direction::Rx, Some(client)),
            "round {round}"
        );
        // Both echoes are back once the bus task handled the second.
        tokio::time::timeout(Duration::from_secs(5), async {
            while h.echo_filters() != Some(Vec::new()) {
                tokio::time::sleep(Duration::from_millis(1)).await;
            }
        })
        .await
        .expect("echo narrowed again");
    }
    // A refused batch does not leave the echo open either.
    vbus.force_bus_off();
    assert!(h.send_as_client(client, vec![frame(0x581)]).await.is_err());
    assert_eq!(h.echo_filters(), Some(Vec::new()));
    assert!(stack.try_recv().is_none());
}

/// A frame of another node that carries a client mark (another gateway
/// on the same virtual bus) is received like any other frame: unmarked.
#[tokio::test]
async fn marks_of_other_nodes_are_dropped() {
    let vbus = VirtualBus::new("v", VirtualBusConfig::default());
    let (h, _c) = start(&vbus);
    let mut sub = h.subscribe(FrameSelector::default(), 16);
    let marked = frame(0x321).with_sender(Some(ClientId::next()));
    vbus.connect(false).send(&marked).unwrap();
    assert_eq!(next_marked(&mut sub).await, (0x321, Direction::Rx, None));
}

/// Paced client frames on a bit-timed bus reach the other subscribers
/// with their bus time, in order; a dropped attachment leaves no
/// subscriber behind.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn paced_client_frames_are_delivered_with_their_bus_time() {
    let (_vbus, h, _c) = start_bit_timed();
    let mut stack = h.subscribe(FrameSelector::default(), 256);
    let client = ClientId::next();
    let own = h.attach(client, attach_options(Vec::new(), true, false));
    assert_eq!(h.stats().subscribers, 2);
    let before = Timestamp::now();
    let batch: Vec<Frame> = (0..100u8)
        .map(|i| Frame::new(CanId::Standard(0x123), &[i; 8]).unwrap())
        .collect();
    h.send_as_client(client, batch).await.unwrap();
    let mut last = before;
    for i in 0..100u8 {
        let BusItem::Frame { frame, direction } = next_item(&mut stack).await else {
            panic!("a frame");
        };
        assert_eq!((direction, frame.sender()), (Direction::Rx, Some(client)));
        assert_eq!(frame.data(), [i; 8], "in order");
        assert!(frame.timestamp() > last, "bus time");
        last = frame.timestamp();
    }
    drop(own);
    tokio::time::timeout(Duration::from_secs(5), async {
        while h.stats().subscribers != 1 {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    })
    .await
    .expect("the attachment's subscription is gone");
}

#[tokio::test]
async fn cancel_ends_subscriptions() {
    let vbus = VirtualBus::new("v", VirtualBusConfig::default());
    let (h, c) = start(&vbus);
    let mut sub = h.subscribe(FrameSelector::default(), 16);
    c.cancel();
    assert_eq!(sub.recv().await, None);
}
