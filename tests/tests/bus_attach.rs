//! Remote clients are bus participants (`Bus.Attach`, and `SendFrames`
//! with the same loopback semantics): an attached client is a CANopen node
//! for the gateway's own master on the demo's can0, with the default
//! limits on; other clients see its frames marked with its sender; its own
//! frames come back only when it asks; a slow attached reader loses frames
//! (told exactly how many) without slowing the bus or anyone else; a flood
//! beyond the raw frame budget is refused with RESOURCE_EXHAUSTED and
//! FRAME_RATE_LIMIT, batch by batch; protocol errors end the stream with
//! their reason; a cancelled attachment leaves no subscription behind.

use cangate_client::can::{CanId, Frame};
use cangate_client::pb;
use cangate_client::{AttachEvent, AttachOptions, Attachment, Client, ConnectOptions, Error};
use cangate_server::Config;
use cangate_tests::*;
use futures::StreamExt;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};
use tonic::Code;

/// The node id the attached client takes on the demo's can0 (the demo's
/// own nodes are 1-4 and 10).
const NODE: u8 = 42;

/// The next event of an attachment, bounded by [`WAIT`].
async fn next_event(a: &mut Attachment) -> AttachEvent {
    tokio::time::timeout(WAIT, a.events.next())
        .await
        .expect("an event in time")
        .expect("the stream goes on")
        .expect("no stream error")
}

/// The next frame of an attachment (state events are skipped; a loss or a
/// refusal fails the test).
async fn next_frame(a: &mut Attachment) -> (Frame, bool, pb::FrameOrigin, Option<pb::FrameSender>) {
    loop {
        match next_event(a).await {
            AttachEvent::Frame {
                frame,
                own,
                origin,
                sender,
            } => return (frame, own, origin, sender),
            AttachEvent::State(_) => {}
            other => panic!("unexpected {other:?}"),
        }
    }
}

/// Asserts that no frame arrives within a short while.
async fn assert_no_frame(a: &mut Attachment) {
    let quiet = tokio::time::timeout(Duration::from_millis(300), async {
        loop {
            match a.events.next().await {
                Some(Ok(AttachEvent::State(_))) => {}
                other => return other,
            }
        }
    })
    .await;
    if let Ok(e) = quiet {
        panic!("unexpected event {e:?}");
    }
}

fn frame(text: &str) -> Frame {
    text.parse().expect("valid frame text")
}

/// A tiny CiA 301 SDO server, enough for the gateway's master: expedited
/// and segmented uploads and downloads of a few objects, aborts for the
/// rest. Answers one request frame with one response frame.
struct SdoServer {
    objects: std::collections::HashMap<(u16, u8), Vec<u8>>,
    /// The transfer in progress: object, data, offset, toggle.
    upload: Option<(Vec<u8>, usize, u8)>,
    download: Option<((u16, u8), Vec<u8>, u8)>,
}

impl SdoServer {
    fn new() -> Self {
        let mut objects = std::collections::HashMap::new();
        objects.insert((0x1000, 0), 0x000F_0191u32.to_le_bytes().to_vec());
        objects.insert((0x1008, 0), b"attached node".to_vec());
        objects.insert((0x1018, 1), 0x0000_0ABCu32.to_le_bytes().to_vec());
        objects.insert((0x2000, 0), 0u32.to_le_bytes().to_vec());
        objects.insert((0x2100, 0), Vec::new());
        SdoServer {
            objects,
            upload: None,
            download: None,
        }
    }

    fn abort(index: u16, sub: u8, code: u32) -> [u8; 8] {
        let mut r = [0x80, index as u8, (index >> 8) as u8, sub, 0, 0, 0, 0];
        r[4..].copy_from_slice(&code.to_le_bytes());
        r
    }

    fn on_request(&mut self, req: &[u8]) -> [u8; 8] {
        let index = u16::from_le_bytes([req[1], req[2]]);
        let sub = req[3];
        let mux = |cmd: u8| [cmd, req[1], req[2], req[3], 0, 0, 0, 0];
        match req[0] >> 5 {
            // Initiate upload.
            2 => {
                let Some(data) = self.objects.get(&(index, sub)).cloned() else {
                    return Self::abort(index, sub, 0x0602_0000);
                };
                if data.len() <= 4 {
                    let mut r = mux(0x43 | (((4 - data.len()) as u8) << 2));
                    r[4..4 + data.len()].copy_from_slice(&data);
                    r
                } else {
                    let mut r = mux(0x41);
                    r[4..].copy_from_slice(&(data.len() as u32).to_le_bytes());
                    self.upload = Some((data, 0, 0));
                    r
                }
            }
            // Upload segment.
            3 => {
                let Some((data, offset, toggle)) = self.upload.as_mut() else {
                    return Self::abort(0, 0, 0x0504_0001);
                };
                let n = (data.len() - *offset).min(7);
                let last = *offset + n == data.len();
                let mut r = [0u8; 8];
                r[0] = (*toggle << 4) | (((7 - n) as u8) << 1) | u8::from(last);
                r[1..1 + n].copy_from_slice(&data[*offset..*offset + n]);
                *offset += n;
                *toggle ^= 1;
                if last {
                    self.upload = None;
                }
                r
            }
            // Initiate download.
            1 => {
                if !self.objects.contains_key(&(index, sub)) {
                    return Self::abort(index, sub, 0x0602_0000);
                }
                if req[0] & 0x02 != 0 {
                    let unused = if req[0] & 0x01 != 0 {
                        usize::from((req[0] >> 2) & 0x03)
                    } else {
                        0
                    };
                    self.objects
                        .insert((index, sub), req[4..8 - unused].to_vec());
                } else {
                    self.download = Some(((index, sub), Vec::new(), 0));
                }
                mux(0x60)
            }
            // Download segment.
            0 => {
                let Some((_, data, toggle)) = self.download.as_mut() else {
                    return Self::abort(0, 0, 0x0504_0001);
                };
                let n = 7 - usize::from((req[0] >> 1) & 0x07);
                data.extend_from_slice(&req[1..1 + n]);
                let r = [0x20 | (*toggle << 4), 0, 0, 0, 0, 0, 0, 0];
                *toggle ^= 1;
                if req[0] & 0x01 != 0 {
                    let (key, data, _) = self.download.take().expect("in progress");
                    self.objects.insert(key, data);
                }
                r
            }
            // Abort from the client: forget the transfer.
            4 => {
                self.upload = None;
                self.download = None;
                [0; 8]
            }
            _ => Self::abort(index, sub, 0x0504_0001),
        }
    }
}

/// Runs the SDO server of node [`NODE`] on an attachment until the events
/// end; counts the requests answered.
fn spawn_sdo_node(mut node: Attachment, answered: Arc<AtomicU64>) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let mut server = SdoServer::new();
        let request_id = 0x600 + u32::from(NODE);
        let response_id = CanId::Standard(0x580 + u16::from(NODE));
        while let Some(ev) = node.events.next().await {
            let Ok(AttachEvent::Frame { frame, own, .. }) = ev else {
                continue;
            };
            if own || frame.raw_id() != request_id || frame.data().len() != 8 {
                continue;
            }
            let answer = server.on_request(frame.data());
            if answer == [0; 8] {
                continue;
            }
            let reply = Frame::new(response_id, &answer).expect("valid frame");
            if node.sender.send(&[reply]).await.is_err() {
                return;
            }
            answered.fetch_add(1, Ordering::Relaxed);
        }
    })
}

/// The demo configuration on an ephemeral port, with its CANopen part on
/// can0 (master, simulated drives, handwheel, I/O node, axes) and its
/// default limits; the CANsmc master on smc0/smc1 is left out, as it has
/// nothing to do with can0 and only loads a debug build.
fn demo_can0() -> Config {
    let mut c = Config::demo();
    c.listen = "127.0.0.1:0".parse().unwrap();
    c.cansmc.clear();
    c.buses.retain(|b| b.name == "can0");
    c
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_attached_client_is_a_canopen_node_for_the_gateways_master() {
    let server = cangate_server::start(&demo_can0())
        .await
        .expect("server starts");
    let c = client(&server).await;
    let mut observer = client(&server).await;

    // Another client watches node 42's SDO traffic both ways.
    let watch = vec![
        cangate_client::filter_to_pb(&cangate_client::can::Filter::exact_standard(
            0x580 + u16::from(NODE),
        )),
        cangate_client::filter_to_pb(&cangate_client::can::Filter::exact_standard(
            0x600 + u16::from(NODE),
        )),
    ];
    let mut req = stream_request("can0", watch);
    req.include_transmitted = true;
    req.queue_length = 4096;
    let (mut watched, mut pending) = open_stream(&mut observer, req).await;

    // The node: receives its SDO requests and the NMT commands.
    let options = AttachOptions {
        filters: vec![
            cangate_client::can::Filter::exact_standard(0x600 + u16::from(NODE)),
            cangate_client::can::Filter::exact_standard(0x000),
        ],
        ..AttachOptions::default()
    };
    let node = c.attach("can0", &options).await.expect("attached");
    assert_eq!(node.bus.name, "can0");
    assert!(node.bus.fd && node.sender_id > 0, "{node:?}");
    let node_sender = node.sender.clone();
    let node_id = node.sender_id;
    let answered = Arc::new(AtomicU64::new(0));
    let task = spawn_sdo_node(node, answered.clone());

    // Its boot-up reaches the gateway's master (loopback to the stacks).
    node_sender
        .send(&[Frame::new(CanId::Standard(0x700 + u16::from(NODE)), &[0]).unwrap()])
        .await
        .unwrap();
    let t0 = Instant::now();
    loop {
        let n = c
            .canopen_client()
            .get_node(pb::GetNodeRequest {
                bus: "can0".into(),
                node: NODE.into(),
            })
            .await;
        if n.is_ok() {
            break;
        }
        assert!(
            t0.elapsed() < WAIT,
            "the master never heard of node {NODE}: {n:?}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }

    // The gateway's own SDO client reads and writes it through the
    // attached client: expedited, segmented, and a 4 KiB segmented write.
    let canopen = c.canopen("can0");
    let node_id_typed: cangate_client::NodeId = NODE.to_string().parse().unwrap();
    use cangate_client::{DataType, ObjectAddress, SdoValue};
    let v = canopen
        .read(
            node_id_typed,
            ObjectAddress::new(0x1000, 0),
            DataType::Unsigned32,
        )
        .await
        .expect("expedited read through the attached node");
    assert_eq!(v, SdoValue::U32(0x000F_0191));
    let v = canopen
        .read(
            node_id_typed,
            ObjectAddress::new(0x1008, 0),
            DataType::VisibleString,
        )
        .await
        .expect("segmented read");
    assert_eq!(v, SdoValue::VisibleString("attached node".into()));
    canopen
        .write(
            node_id_typed,
            ObjectAddress::new(0x2000, 0),
            SdoValue::U32(0xC0FFEE),
        )
        .await
        .expect("expedited write");
    let v = canopen
        .read(
            node_id_typed,
            ObjectAddress::new(0x2000, 0),
            DataType::Unsigned32,
        )
        .await
        .unwrap();
    assert_eq!(v, SdoValue::U32(0xC0FFEE));
    let image: Vec<u8> = (0..4096u32).map(|i| (i * 7 + 3) as u8).collect();
    let started = Instant::now();
    canopen
        .write(
            node_id_typed,
            ObjectAddress::new(0x2100, 0),
            SdoValue::Domain(image.clone()),
        )
        .await
        .expect("4 KiB segmented write with the default limits");
    let write_time = started.elapsed();
    let back = canopen
        .read(
            node_id_typed,
            ObjectAddress::new(0x2100, 0),
            DataType::Domain,
        )
        .await
        .unwrap();
    assert_eq!(back, SdoValue::Domain(image));
    let e = canopen
        .read(
            node_id_typed,
            ObjectAddress::new(0x3000, 0),
            DataType::Unsigned8,
        )
        .await
        .unwrap_err();
    assert!(
        matches!(
            e,
            Error::SdoAbort {
                code: 0x0602_0000,
                by_node: true,
                ..
            }
        ),
        "the node's abort reaches the caller: {e:?}"
    );
    eprintln!(
        "4 KiB segmented write through the attached node: {write_time:?}; {} requests answered",
        answered.load(Ordering::Relaxed)
    );

    // The observer saw the master's requests as the gateway's and the
    // node's answers as a client's, named.
    let frames = read_frames(&mut watched, &mut pending, 4).await;
    let request = frames
        .iter()
        .find(|f| f.id == 0x600 + u32::from(NODE))
        .expect("a request");
    assert_eq!(
        (request.direction, request.origin, request.sender.clone()),
        (
            pb::Direction::Tx as i32,
            pb::FrameOrigin::Gateway as i32,
            None
        )
    );
    let answer = frames
        .iter()
        .find(|f| f.id == 0x580 + u32::from(NODE))
        .expect("an answer");
    assert_eq!(answer.direction, pb::Direction::Rx as i32);
    assert_eq!(answer.origin, pb::FrameOrigin::Client as i32);
    let sender = answer.sender.as_ref().expect("named");
    assert_eq!(sender.id, node_id);
    assert!(sender.client.starts_with("127.0.0.1:"), "{sender:?}");

    drop(node_sender);
    task.abort();
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn own_frames_come_back_only_when_asked() {
    let server = start_server(ONE_BUS).await;
    let c = client(&server).await;
    let mut a = c
        .attach(
            "can0",
            &AttachOptions {
                receive_own: true,
                ..AttachOptions::default()
            },
        )
        .await
        .unwrap();
    let mut b = c.attach("can0", &AttachOptions::default()).await.unwrap();
    assert_ne!(a.sender_id, b.sender_id, "one sender per stream");
    for x in [&mut a, &mut b] {
        assert!(matches!(next_event(x).await, AttachEvent::State(_)));
    }

    a.sender.send(&[frame("111#AA")]).await.unwrap();
    let (f, own, origin, sender) = next_frame(&mut a).await;
    assert_eq!(
        (f.raw_id(), own, origin),
        (0x111, true, pb::FrameOrigin::Client)
    );
    assert_eq!(sender.unwrap().id, a.sender_id);
    let (f, own, origin, sender) = next_frame(&mut b).await;
    assert_eq!(
        (f.raw_id(), own, origin),
        (0x111, false, pb::FrameOrigin::Client)
    );
    assert_eq!(sender.unwrap().id, a.sender_id);
    assert!(f.timestamp().as_nanos() > 0);

    b.sender.send(&[frame("222#BB")]).await.unwrap();
    let (f, own, _, sender) = next_frame(&mut a).await;
    assert_eq!((f.raw_id(), own), (0x222, false));
    assert_eq!(sender.unwrap().id, b.sender_id);
    assert_no_frame(&mut b).await;

    // The gateway's own frames and other nodes' reach both, as received.
    let vbus = server.gateway().network().get("can0").unwrap();
    vbus.connect(false).send(&frame("333#CC")).unwrap();
    server
        .gateway()
        .bus("can0")
        .unwrap()
        .send(vec![frame("080#")])
        .await
        .unwrap();
    for x in [&mut a, &mut b] {
        let (f, own, origin, sender) = next_frame(x).await;
        assert_eq!(
            (f.raw_id(), own, origin, sender),
            (0x333, false, pb::FrameOrigin::Bus, None)
        );
        let (f, own, origin, _) = next_frame(x).await;
        assert_eq!(
            (f.raw_id(), own, origin),
            (0x080, false, pb::FrameOrigin::Gateway)
        );
    }

    // A SendFrames call is a sender of its own: both receive its frames.
    let mut s = client(&server).await;
    s.send("can0", &[frame("444#DD")]).await.unwrap();
    let ids = [a.sender_id, b.sender_id];
    for x in [&mut a, &mut b] {
        let (f, own, origin, sender) = next_frame(x).await;
        assert_eq!(
            (f.raw_id(), own, origin),
            (0x444, false, pb::FrameOrigin::Client)
        );
        let sender = sender.unwrap();
        assert!(!ids.contains(&sender.id), "{sender:?}");
    }
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slow_attached_reader_loses_frames_and_nobody_else_does() {
    const N: u64 = 30_000;
    let server = start_server(ONE_BUS).await;
    let vbus = server.gateway().network().get("can0").unwrap();
    let device = vbus.connect(false);
    let c = client(&server).await;

    // The slow one: a small queue, and it does not read for now.
    let mut slow = c
        .attach(
            "can0",
            &AttachOptions {
                queue_length: Some(64),
                ..AttachOptions::default()
            },
        )
        .await
        .unwrap();

    // A fast reader on another connection reads everything.
    let mut fast_client = client(&server).await;
    let mut req = stream_request("can0", vec![]);
    req.queue_length = 100_000;
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
                    // The slow client's frame, sent after the device's.
                    Some(pb::stream_event::Event::Frame(f)) if f.id == 0x555 => {
                        assert_eq!(f.origin, pb::FrameOrigin::Client as i32);
                        return next;
                    }
                    Some(pb::stream_event::Event::Frame(f)) => {
                        let seq = u64::from_le_bytes(f.data[..8].try_into().unwrap());
                        assert_eq!(seq, next, "the fast reader sees every frame in order");
                        next += 1;
                        counter.store(next, Ordering::Relaxed);
                    }
                    Some(pb::stream_event::Event::Lost(l)) => {
                        panic!("the fast reader lost {} frames", l.count)
                    }
                    _ => {}
                }
            }
        }
    });

    // The device sends, paced by the fast reader only.
    let id = CanId::Standard(0x100);
    for seq in 0..N {
        while seq > fast_count.load(Ordering::Relaxed) + 8_000 {
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        device
            .send(&Frame::new(id, &seq.to_le_bytes()).unwrap())
            .unwrap();
    }
    // The slow client still sends, and is heard, while it does not read.
    slow.sender.send(&[frame("555#01")]).await.unwrap();
    let seen = tokio::time::timeout(WAIT, fast_reader)
        .await
        .expect("the fast reader finished in time")
        .unwrap();
    assert_eq!(
        seen, N,
        "the fast reader saw every frame, then the slow one's"
    );

    // Now the slow one reads: frames in order with the exact losses in
    // place, until every frame is accounted for.
    let (mut next, mut received, mut lost) = (0u64, 0u64, 0u64);
    while received + lost < N {
        match next_event(&mut slow).await {
            AttachEvent::Frame { frame, .. } if frame.raw_id() == 0x100 => {
                let seq = u64::from_le_bytes(frame.data()[..8].try_into().unwrap());
                assert_eq!(seq, next, "frames in order, losses where they happened");
                next += 1;
                received += 1;
            }
            AttachEvent::Lost(n) => {
                next += n;
                lost += n;
            }
            AttachEvent::Frame { .. } | AttachEvent::State(_) => {}
            other => panic!("unexpected {other:?}"),
        }
    }
    assert_eq!(received + lost, N, "every frame received or counted");
    assert!(
        lost > 0,
        "the slow reader lost frames ({received} received)"
    );
    // Reading again, it gets the next frame as usual.
    device.send(&frame("7FF#")).unwrap();
    let (f, ..) = next_frame(&mut slow).await;
    assert_eq!(f.raw_id(), 0x7FF);
    let stats = c.clone().get_bus("can0").await.unwrap().statistics.unwrap();
    assert!(stats.subscriber_drops >= lost, "{stats:?}");
    server.shutdown();
}

/// Clients with their own identities, so that each has its own budget.
fn tokens(names: &[(&str, &str)]) -> String {
    names
        .iter()
        .map(|(name, role)| {
            format!(
                "[[security.tokens]]\nname = \"{name}\"\nrole = \"{role}\"\nsha256 = \"{}\"\n",
                cangate_client::hash_token(name)
            )
        })
        .collect()
}

async fn as_token(server: &cangate_server::RunningServer, token: &str) -> Client {
    cangate_client::connect_with(
        &format!("http://{}", server.addr),
        &ConnectOptions {
            token: Some(token.into()),
            ..Default::default()
        },
    )
    .await
    .expect("client connects")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_flood_beyond_the_frame_budget_is_refused_batch_by_batch() {
    // The default limits (5,000 frames/s, 10,000 at once) on a bus that
    // takes frames as fast as they come.
    let config = format!(
        "{ONE_BUS}{}",
        tokens(&[
            ("flood", "engineer"),
            ("calm", "engineer"),
            ("calls", "engineer"),
            ("look", "viewer")
        ])
    );
    let server = start_server(&config).await;
    let mut calm = as_token(&server, "calm").await;
    let mut look = as_token(&server, "look").await;
    let flood = as_token(&server, "flood").await;

    // A viewer may stream but not attach (it would send raw frames).
    let e = look
        .attach("can0", &AttachOptions::default())
        .await
        .unwrap_err();
    assert_eq!(e.code(), Some(Code::PermissionDenied), "{e}");

    let mut req = stream_request("can0", vec![]);
    req.queue_length = 65_536;
    let (mut watch, mut pending) = open_stream(&mut look, req).await;

    // Through Attach: batches of 1,000 until the budget refuses one; the
    // stream goes on, and a refused batch sends nothing.
    let mut a = flood
        .attach("can0", &AttachOptions::default())
        .await
        .unwrap();
    let batch: Vec<Frame> = (0..1000u16)
        .map(|i| Frame::new(CanId::Standard(0x100), &i.to_le_bytes()).unwrap())
        .collect();
    let mut sequences = Vec::new();
    for _ in 0..30 {
        sequences.push(a.sender.send(&batch).await.unwrap());
    }
    let mut refused = Vec::new();
    let deadline = tokio::time::Instant::now() + WAIT;
    // Every batch either arrives (its frames on the watcher's stream) or is
    // refused; count both until all 30 are accounted for.
    assert!(pending.is_empty());
    let mut delivered = 0u64;
    while (delivered / 1000) + (refused.len() as u64) < 30 {
        tokio::select! {
            _ = tokio::time::sleep_until(deadline) => {
                panic!("{delivered} frames delivered, {} batches refused", refused.len())
            }
            ev = a.events.next() => match ev.expect("stream on").expect("no error") {
                AttachEvent::Refused(r) => refused.push(r),
                AttachEvent::State(_) => {}
                other => panic!("unexpected {other:?}"),
            },
            m = watch.message() => {
                for ev in m.expect("watch ok").expect("watch on").events {
                    match ev.event {
                        Some(pb::stream_event::Event::Frame(f)) => {
                            assert_eq!(f.origin, pb::FrameOrigin::Client as i32);
                            delivered += 1;
                        }
                        Some(pb::stream_event::Event::Lost(l)) => panic!("watcher lost {}", l.count),
                        _ => {}
                    }
                }
            }
        }
    }
    assert!(
        !refused.is_empty(),
        "30,000 frames at once exceed the budget"
    );
    assert!(refused.len() < 30, "the burst passed");
    assert_eq!(
        delivered,
        1000 * (30 - refused.len() as u64),
        "refused batches send nothing"
    );
    for r in &refused {
        assert_eq!(r.code, Code::ResourceExhausted as i32, "{r:?}");
        assert_eq!(r.reason, "FRAME_RATE_LIMIT");
        assert_eq!(r.metadata.get("frames").map(String::as_str), Some("1000"));
        assert_eq!((r.sent, r.total), (0, 1000));
        assert!(sequences.contains(&r.sequence), "{r:?}");
        assert!(
            r.message
                .contains("raw_frames_per_second_per_client = 5000"),
            "{r:?}"
        );
    }

    // Through SendFrames: the burst at once, then a second one is refused
    // as a call (its frames are counted, not the call), nothing of it sent.
    let mut calls = as_token(&server, "calls").await;
    let big: Vec<Frame> = (0..10_000u32)
        .map(|i| Frame::new(CanId::Standard(0x200), &i.to_le_bytes()).unwrap())
        .collect();
    let before = calls
        .get_bus("can0")
        .await
        .unwrap()
        .statistics
        .unwrap()
        .tx_frames;
    assert_eq!(calls.send("can0", &big).await.unwrap(), 10_000);
    let e = calls.send("can0", &big).await.unwrap_err();
    assert_eq!(e.code(), Some(Code::ResourceExhausted), "{e}");
    assert_eq!(e.reason().as_deref(), Some("FRAME_RATE_LIMIT"), "{e:?}");
    let after = calls
        .get_bus("can0")
        .await
        .unwrap()
        .statistics
        .unwrap()
        .tx_frames;
    assert_eq!(after - before, 10_000, "the refused call sent nothing");

    // Other identities have their own budgets, and the flood's recovers.
    assert_eq!(calm.send("can0", &batch).await.unwrap(), 1000);
    tokio::time::sleep(Duration::from_millis(500)).await;
    a.sender.send(&[frame("7FF#01")]).await.unwrap();
    loop {
        let got = read_frames(&mut watch, &mut pending, 1).await;
        if got.iter().any(|f| f.id == 0x7FF) {
            break;
        }
    }
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn protocol_errors_end_the_stream_with_their_reason() {
    let server = start_server(
        "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\nfd = true\n\
         [[bus]]\nname = \"classic\"\nbackend = \"virtual\"\n",
    )
    .await;
    let c = client(&server).await;
    let open = |bus: &str, fd: bool| pb::AttachRequest {
        message: Some(pb::attach_request::Message::Open(pb::AttachOpen {
            bus: bus.into(),
            fd,
            ..Default::default()
        })),
    };
    let send = |frames: Vec<pb::Frame>, sequence| pb::AttachRequest {
        message: Some(pb::attach_request::Message::Send(pb::AttachSend {
            frames,
            sequence,
        })),
    };
    let attach = |messages: Vec<pb::AttachRequest>| {
        let mut bus = c.bus_client();
        async move {
            let outbound = futures::stream::iter(messages).chain(futures::stream::pending());
            tokio::time::timeout(WAIT, bus.attach(outbound))
                .await
                .expect("answered in time")
        }
    };
    let reason = |s: &tonic::Status| {
        cangate_client::error_info(s)
            .map(|i| i.reason)
            .unwrap_or_default()
    };

    // A first message that is not an open.
    let s = attach(vec![send(vec![], 1)]).await.unwrap_err();
    assert_eq!(
        (s.code(), reason(&s).as_str()),
        (Code::InvalidArgument, "ATTACH_PROTOCOL")
    );
    // An unknown bus; CAN FD on a classic bus.
    let s = attach(vec![open("nope", false)]).await.unwrap_err();
    assert_eq!(
        (s.code(), reason(&s).as_str()),
        (Code::NotFound, "BUS_NOT_FOUND")
    );
    let s = attach(vec![open("classic", true)]).await.unwrap_err();
    assert_eq!(
        (s.code(), reason(&s).as_str()),
        (Code::InvalidArgument, "CAN_FD_NOT_SUPPORTED")
    );

    // Open without fd: an FD frame is refused in the stream (INVALID_FRAME,
    // the stream goes on), a malformed one too; a second open ends it.
    let fd_frame = cangate_client::frame_to_pb(&frame("123##1AABB"));
    let mut bad = cangate_client::frame_to_pb(&frame("123#00"));
    bad.id = 0x800;
    let mut stream = attach(vec![
        open("can0", false),
        send(vec![fd_frame], 7),
        send(vec![cangate_client::frame_to_pb(&frame("123#00")), bad], 8),
        send(vec![], 9),
        open("can0", false),
    ])
    .await
    .expect("opened")
    .into_inner();
    let mut refusals = Vec::new();
    let end = loop {
        match tokio::time::timeout(WAIT, stream.message())
            .await
            .expect("in time")
        {
            Ok(Some(m)) => {
                for e in m.events {
                    if let Some(pb::attach_event::Event::Refused(r)) = e.event {
                        refusals.push(r);
                    }
                }
            }
            Ok(None) => panic!("ended without a status"),
            Err(s) => break s,
        }
    };
    assert_eq!(
        (end.code(), reason(&end).as_str()),
        (Code::InvalidArgument, "ATTACH_PROTOCOL")
    );
    let summary: Vec<(u64, String, Option<String>)> = refusals
        .iter()
        .map(|r| {
            (
                r.sequence,
                r.reason.clone(),
                r.metadata.get("frame").cloned(),
            )
        })
        .collect();
    assert_eq!(
        summary,
        vec![
            (7, "INVALID_FRAME".into(), Some("0".into())),
            (8, "INVALID_FRAME".into(), Some("1".into())),
            (9, "INVALID_ARGUMENT".into(), None),
        ]
    );
    assert!(
        refusals
            .iter()
            .all(|r| r.code == Code::InvalidArgument as i32 && r.sent == 0)
    );
    let stats = c.clone().get_bus("can0").await.unwrap().statistics.unwrap();
    assert_eq!(stats.tx_frames, 0, "nothing of a refused batch was sent");
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_message_too_large_ends_the_stream_with_its_reason() {
    let server = start_server(&format!(
        "{ONE_BUS}[security.limits]\nmax_message_bytes = 1024\n"
    ))
    .await;
    let c = client(&server).await;
    let mut a = c.attach("can0", &AttachOptions::default()).await.unwrap();
    let big: Vec<Frame> = (0..100u32)
        .map(|i| Frame::new(CanId::Standard(0x100), &i.to_le_bytes()).unwrap())
        .collect();
    a.sender.send(&big).await.unwrap();
    let e = loop {
        match tokio::time::timeout(WAIT, a.events.next())
            .await
            .expect("in time")
            .expect("an end with a status")
        {
            Ok(AttachEvent::State(_)) => {}
            Ok(other) => panic!("unexpected {other:?}"),
            Err(e) => break e,
        }
    };
    assert_eq!(e.code(), Some(Code::ResourceExhausted), "{e}");
    assert_eq!(e.reason().as_deref(), Some("MESSAGE_SIZE_LIMIT"), "{e:?}");
    server.shutdown();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cancelled_attachment_leaves_nothing_behind() {
    // Two open streams at most: a leaked stream slot would refuse the
    // attachments after the first two.
    let server = start_server(&format!(
        "{ONE_BUS}[security.limits]\nmax_streams_per_client = 2\n"
    ))
    .await;
    let mut c = client(&server).await;
    let subscribers = |info: pb::BusInfo| info.statistics.unwrap().subscribers;
    let baseline = subscribers(c.get_bus("can0").await.unwrap());
    let mut watcher = client(&server).await;
    let (mut watch, mut pending) = open_stream(&mut watcher, stream_request("can0", vec![])).await;
    let with_watcher = baseline + 1;
    let vbus = server.gateway().network().get("can0").unwrap();
    let device = vbus.connect(false);

    for round in 0..5u8 {
        let mut a = c.attach("can0", &AttachOptions::default()).await.unwrap();
        assert_eq!(
            subscribers(c.get_bus("can0").await.unwrap()),
            with_watcher + 1
        );
        // Mid-way: frames both ways, some unread, a batch sent.
        for i in 0..100u8 {
            device
                .send(&Frame::new(CanId::Standard(0x300), &[round, i]).unwrap())
                .unwrap();
        }
        a.sender
            .send(&[Frame::new(CanId::Standard(0x400), &[round]).unwrap()])
            .await
            .unwrap();
        let _ = next_event(&mut a).await;
        // The watcher saw the batch, marked.
        loop {
            let got = read_frames(&mut watch, &mut pending, 1).await;
            if let Some(f) = got.iter().find(|f| f.id == 0x400) {
                assert_eq!(f.origin, pb::FrameOrigin::Client as i32);
                break;
            }
        }
        // More on their way when the client drops the attachment.
        let more: Vec<Frame> = (0..1000u16)
            .map(|i| Frame::new(CanId::Standard(0x401), &i.to_le_bytes()).unwrap())
            .collect();
        a.sender.send(&more).await.unwrap();
        drop(a);
        let t0 = Instant::now();
        loop {
            let n = subscribers(c.get_bus("can0").await.unwrap());
            if n == with_watcher {
                break;
            }
            assert!(t0.elapsed() < WAIT, "round {round}: {n} subscribers stay");
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    }
    drop((watch, pending));
    let t0 = Instant::now();
    while subscribers(c.get_bus("can0").await.unwrap()) != baseline {
        assert!(t0.elapsed() < WAIT, "the watcher's subscription stays");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    server.shutdown();
}

/// The batch of an Attach stream that is cancelled while the bus's client
/// share holds it back is withdrawn: the frames not yet sent never reach
/// the bus, and the bus counts them. (At 1 % of a bit-timed 1 Mbit/s bus,
/// 1,000 frames would go on for about 11 s after the client left.)
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cancelled_attachment_withdraws_the_frames_it_queued() {
    let server = start_server(
        "metrics_listen = \"127.0.0.1:0\"\n\
         [[bus]]\nname = \"can0\"\nbackend = \"virtual\"\nbitrate = 1000000\n\
         bit_timing = true\nclient_share_percent = 1\n",
    )
    .await;
    let c = client(&server).await;
    let bus = server.gateway().bus("can0").unwrap().clone();
    let mut device = server
        .gateway()
        .network()
        .get("can0")
        .unwrap()
        .connect(false);
    let a = c.attach("can0", &AttachOptions::default()).await.unwrap();
    let batch: Vec<Frame> = (0..1000u16)
        .map(|i| Frame::new(CanId::Standard(0x401), &i.to_le_bytes()).unwrap())
        .collect();
    a.sender.send(&batch).await.unwrap();
    // The first frames are on the bus: the batch is being paced.
    loop {
        match tokio::time::timeout(WAIT, device.recv())
            .await
            .expect("a frame")
        {
            cangate_can::PortEvent::Frame { frame, .. } if frame.raw_id() == 0x401 => break,
            _ => {}
        }
    }
    drop(a);
    // What it had queued and what it had not queued yet are counted.
    let t0 = Instant::now();
    let withdrawn = loop {
        let n = bus.stats().client_frames_withdrawn;
        if n >= 900 || t0.elapsed() > WAIT {
            break n;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    };
    assert!(withdrawn >= 900, "{withdrawn} withdrawn");
    // A marker queued now goes behind whatever the share had let out of
    // the batch (client frames keep their order): when it arrives, every
    // frame of the batch that will ever go out has.
    let marker = c.attach("can0", &AttachOptions::default()).await.unwrap();
    marker
        .sender
        .send(&[Frame::new(CanId::Standard(0x7FE), &[]).unwrap()])
        .await
        .unwrap();
    let mut sent = 1u64;
    loop {
        match tokio::time::timeout(WAIT, device.recv())
            .await
            .expect("the marker")
        {
            cangate_can::PortEvent::Frame { frame, .. } if frame.raw_id() == 0x401 => sent += 1,
            cangate_can::PortEvent::Frame { frame, .. } if frame.raw_id() == 0x7FE => break,
            _ => {}
        }
    }
    assert_eq!(sent + withdrawn, 1000, "{sent} sent, {withdrawn} withdrawn");
    assert_eq!(bus.stats().budget_queued, 0);
    // Reported on the metrics endpoint.
    let text = scrape_metrics(server.metrics_addr.expect("metrics listen")).await;
    assert!(
        text.contains(&format!(
            "cangate_client_frames_withdrawn_total{{bus=\"can0\"}} {withdrawn}"
        )),
        "{text}"
    );
    server.shutdown();
}
