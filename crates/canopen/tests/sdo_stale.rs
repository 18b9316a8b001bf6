//! Late answers to an aborted SDO transfer never reach the next transfer,
//! and the gateway's own transfers go before API clients' on a node's SDO
//! channel: scripted peers with exact bytes and virtual time, through the
//! master as the server runs it.

use cangate_can::{CanId, Frame};
use cangate_canopen::master::{Master, MasterEvent, Output, SdoPriority, SdoRequest};
use cangate_canopen::sdo::{DEFAULT_SETTLE_TIME, SdoError, TransferOptions, TransferOutcome};
use cangate_canopen::{NodeId, ObjectAddress};
use std::time::Duration;

const MS: Duration = Duration::from_millis(1);
const TIMEOUT: Duration = Duration::from_millis(200);

fn h(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

fn node() -> NodeId {
    NodeId::new(2).unwrap()
}

fn upload(index: u16) -> SdoRequest {
    SdoRequest::Upload {
        addr: ObjectAddress::new(index, 0),
        opts: TransferOptions::default(),
    }
}

/// The master, and what it sent and reported, with a helper per input.
struct Rig {
    m: Master,
    sent: Vec<Vec<u8>>,
    events: Vec<MasterEvent>,
}

impl Rig {
    fn new() -> Self {
        Rig {
            m: Master::new(TIMEOUT),
            sent: Vec::new(),
            events: Vec::new(),
        }
    }

    fn take(&mut self, out: Output) {
        for f in out.frames {
            assert_eq!(f.id(), CanId::Standard(0x602));
            self.sent.push(f.data().to_vec());
        }
        self.events.extend(out.events);
    }

    fn request(&mut self, id: u64, priority: SdoPriority, req: SdoRequest, now: Duration) {
        let mut out = Output::default();
        self.m.sdo_as(id, node(), priority, req, now, &mut out);
        self.take(out);
    }

    fn answer(&mut self, bytes: &str, now: Duration) {
        let mut out = Output::default();
        let f = Frame::new(CanId::Standard(0x582), &h(bytes)).unwrap();
        self.m.on_frame(&f, now, &mut out);
        self.take(out);
    }

    fn tick(&mut self, now: Duration) {
        let mut out = Output::default();
        self.m.on_tick(now, &mut out);
        self.take(out);
    }

    fn cancel(&mut self, id: u64, now: Duration) {
        let mut out = Output::default();
        self.m.cancel(id, now, &mut out);
        self.take(out);
    }

    /// Ticks at every deadline up to `until`.
    fn run_until(&mut self, until: Duration) {
        while let Some(d) = self.m.next_deadline().filter(|d| *d <= until) {
            self.tick(d);
        }
    }

    fn sent_since(&mut self, mark: usize) -> Vec<Vec<u8>> {
        self.sent[mark..].to_vec()
    }

    fn completed(&self, id: u64) -> Option<&Result<TransferOutcome, SdoError>> {
        self.events.iter().find_map(|e| match e {
            MasterEvent::SdoCompleted { id: i, result, .. } if *i == id => Some(result),
            _ => None,
        })
    }

    fn ignored(&self) -> usize {
        self.events
            .iter()
            .filter(|e| matches!(e, MasterEvent::SdoResponseIgnored { .. }))
            .count()
    }
}

/// Starts a 20-byte segmented download of 0x2000:00 and runs it to its
/// second segment, which is left unanswered.
fn download_in_second_segment(r: &mut Rig) {
    let data: Vec<u8> = (1..=20).collect();
    let req = SdoRequest::Download {
        addr: ObjectAddress::new(0x2000, 0),
        data,
        opts: TransferOptions::default(),
    };
    r.request(1, SdoPriority::Client, req, Duration::ZERO);
    assert_eq!(r.sent, vec![h("21 00 20 00 14 00 00 00")]);
    r.answer("60 00 20 00 00 00 00 00", MS);
    r.answer("20 00 00 00 00 00 00 00", 2 * MS);
    assert_eq!(r.sent.last().unwrap(), &h("10 08 09 0A 0B 0C 0D 0E"));
}

/// The reported case: a cancelled segmented download's last segment is
/// answered (`30`) after the abort went out; the next request, an upload,
/// must get its own answer, not a protocol violation.
#[test]
fn late_segment_answer_after_cancel_is_not_taken_by_the_next_upload() {
    let mut r = Rig::new();
    download_in_second_segment(&mut r);
    r.request(2, SdoPriority::Client, upload(0x1000), 2 * MS);
    let mark = r.sent.len();
    r.cancel(1, 3 * MS);
    // The abort goes out; the next initiate waits for the channel to settle.
    assert_eq!(r.sent_since(mark), vec![h("80 00 20 00 00 00 00 08")]);
    // The server answers the segment it got before the abort.
    r.answer("30 00 00 00 00 00 00 00", 4 * MS);
    assert_eq!(r.ignored(), 1);
    assert_eq!(r.sent.len(), mark + 1, "nothing sent while settling");
    // The late answer extends the quiet time: the server may have more.
    r.run_until(3 * MS + DEFAULT_SETTLE_TIME);
    assert_eq!(r.sent.len(), mark + 1);
    r.run_until(4 * MS + DEFAULT_SETTLE_TIME);
    assert_eq!(r.sent_since(mark + 1), vec![h("40 00 10 00 00 00 00 00")]);
    r.answer("43 00 10 00 92 01 02 00", 60 * MS);
    assert_eq!(
        r.completed(2),
        Some(&Ok(TransferOutcome::Uploaded(vec![0x92, 0x01, 0x02, 0x00])))
    );
}

/// A server slower than the settle time: its late answer comes while the
/// next transfer waits for its initiate response, and is dropped there
/// because it cannot answer that initiate (another command specifier).
#[test]
fn late_answer_after_the_settle_time_is_recognised_by_its_shape() {
    let mut r = Rig::new();
    download_in_second_segment(&mut r);
    r.request(2, SdoPriority::Client, upload(0x1000), 2 * MS);
    r.cancel(1, 3 * MS);
    r.run_until(3 * MS + DEFAULT_SETTLE_TIME);
    assert_eq!(r.sent.last().unwrap(), &h("40 00 10 00 00 00 00 00"));
    r.answer("30 00 00 00 00 00 00 00", 80 * MS);
    assert_eq!(r.completed(2), None, "the late segment answer was taken");
    assert_eq!(r.ignored(), 1);
    r.answer("43 00 10 00 92 01 02 00", 81 * MS);
    assert_eq!(
        r.completed(2),
        Some(&Ok(TransferOutcome::Uploaded(vec![0x92, 0x01, 0x02, 0x00])))
    );
}

/// After a timeout, the late initiate answer names the old object (and a
/// late abort too): neither is the new read's answer nor a violation of it.
#[test]
fn late_answers_naming_the_old_object_are_dropped_after_a_timeout() {
    let mut r = Rig::new();
    r.request(1, SdoPriority::Client, upload(0x2000), Duration::ZERO);
    r.request(2, SdoPriority::Client, upload(0x1000), Duration::ZERO);
    r.run_until(TIMEOUT);
    assert!(matches!(
        r.completed(1),
        Some(Err(SdoError::Timeout { .. }))
    ));
    assert_eq!(r.sent.last().unwrap(), &h("80 00 20 00 00 00 04 05"));
    r.run_until(TIMEOUT + DEFAULT_SETTLE_TIME);
    assert_eq!(r.sent.last().unwrap(), &h("40 00 10 00 00 00 00 00"));
    r.answer(
        "4F 00 20 00 07 00 00 00",
        TIMEOUT + DEFAULT_SETTLE_TIME + MS,
    );
    r.answer(
        "80 00 20 00 00 00 04 05",
        TIMEOUT + DEFAULT_SETTLE_TIME + MS,
    );
    assert_eq!(r.completed(2), None);
    assert_eq!(r.ignored(), 2);
    r.answer(
        "43 00 10 00 92 01 02 00",
        TIMEOUT + DEFAULT_SETTLE_TIME + 2 * MS,
    );
    assert!(matches!(r.completed(2), Some(Ok(_))));
    // Once the new transfer has its answer, the channel is trusted again:
    // a wrong answer to a later request is a protocol violation.
    let t = TIMEOUT + DEFAULT_SETTLE_TIME + 3 * MS;
    r.request(3, SdoPriority::Client, upload(0x1017), t);
    r.answer("4B 00 10 00 00 00 00 00", t + MS);
    assert!(matches!(
        r.completed(3),
        Some(Err(SdoError::Protocol { .. }))
    ));
}

/// A late sub-block of a block upload aborted by timeout keeps the channel
/// settling while it streams in; the next transfer starts after it.
#[test]
fn late_block_segments_extend_the_settle_time() {
    let mut r = Rig::new();
    let block = SdoRequest::Upload {
        addr: ObjectAddress::new(0x2100, 0),
        opts: TransferOptions::block(),
    };
    r.request(1, SdoPriority::Client, block, Duration::ZERO);
    r.answer("C6 00 21 00 00 04 00 00", MS);
    assert_eq!(r.sent.last().unwrap(), &h("A3 00 00 00 00 00 00 00"));
    r.request(2, SdoPriority::Client, upload(0x1000), MS);
    r.run_until(MS + TIMEOUT);
    assert!(matches!(
        r.completed(1),
        Some(Err(SdoError::Timeout { .. }))
    ));
    let aborted = MS + TIMEOUT;
    let mark = r.sent.len();
    // Segments keep coming every 30 ms, each within the settle time of the
    // one before.
    for seq in 1..=5u32 {
        let now = aborted + 30 * MS * seq;
        r.run_until(now);
        r.answer(&format!("{seq:02X} 11 22 33 44 55 66 77"), now);
    }
    assert_eq!(r.sent.len(), mark, "nothing sent while the server streams");
    assert_eq!(r.ignored(), 5);
    r.run_until(aborted + 150 * MS + DEFAULT_SETTLE_TIME);
    assert_eq!(r.sent_since(mark), vec![h("40 00 10 00 00 00 00 00")]);
}

/// The gateway's transfers go before queued client transfers, and a
/// running client transfer with a long timeout to a silent node gives way
/// after the master's default timeout once the gateway needs the channel.
#[test]
fn gateway_transfers_go_first_and_cut_a_silent_client_transfer_short() {
    let mut r = Rig::new();
    let long = SdoRequest::Upload {
        addr: ObjectAddress::new(0x2000, 0),
        opts: TransferOptions::default().with_timeout(Duration::from_secs(3600)),
    };
    r.request(1, SdoPriority::Client, long, Duration::ZERO);
    r.request(2, SdoPriority::Client, upload(0x2001), Duration::ZERO);
    assert_eq!(r.m.next_deadline(), Some(Duration::from_secs(3600)));
    // The boot procedure needs the node 10 ms into the client's read.
    r.request(3, SdoPriority::Gateway, upload(0x1000), 10 * MS);
    assert_eq!(r.m.next_deadline(), Some(TIMEOUT));
    r.run_until(TIMEOUT);
    match r.completed(1) {
        Some(Err(SdoError::Timeout { timeout, .. })) => assert_eq!(*timeout, TIMEOUT),
        other => panic!("{other:?}"),
    }
    r.run_until(TIMEOUT + DEFAULT_SETTLE_TIME);
    // The gateway's read goes before the client's queued one.
    assert_eq!(r.sent.last().unwrap(), &h("40 00 10 00 00 00 00 00"));
    r.answer(
        "43 00 10 00 92 01 02 00",
        TIMEOUT + DEFAULT_SETTLE_TIME + MS,
    );
    assert!(matches!(r.completed(3), Some(Ok(_))));
    assert_eq!(r.sent.last().unwrap(), &h("40 01 20 00 00 00 00 00"));
}

/// A client transfer the node keeps answering is not cut short.
#[test]
fn an_answering_client_transfer_is_not_cut_short() {
    let mut r = Rig::new();
    let long = SdoRequest::Upload {
        addr: ObjectAddress::new(0x1008, 0),
        opts: TransferOptions::default().with_timeout(Duration::from_secs(10)),
    };
    r.request(1, SdoPriority::Client, long, Duration::ZERO);
    r.answer("41 08 10 00 0B 00 00 00", MS);
    r.request(2, SdoPriority::Gateway, upload(0x1000), 2 * MS);
    // Each answer comes within the master's timeout.
    r.answer("00 63 61 6E 67 61 74 65", 150 * MS);
    r.answer("17 20 73 69 6D 00 00 00", 300 * MS);
    assert_eq!(
        r.completed(1),
        Some(&Ok(TransferOutcome::Uploaded(b"cangate sim".to_vec())))
    );
    assert_eq!(r.sent.last().unwrap(), &h("40 00 10 00 00 00 00 00"));
}
