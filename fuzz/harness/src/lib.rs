//! One entry function per decoder that is fed by the network or a file.
//!
//! Each function takes arbitrary bytes, drives the decoder's public API the
//! way the bus or a file does, and panics only when the decoder panics or
//! breaks an invariant checked here. The cargo-fuzz targets (`fuzz/`,
//! nightly) and the stable property test (`tests/tests/decoders_never_panic.rs`)
//! call the same functions, so a crash found by either is reproduced by both.
//!
//! Stateful decoders read their input as a script: a few header bytes set up
//! the decoder (node, options, the transfer to start), then each following
//! record is one event — a frame (mostly on the decoder's COB-ID, sometimes
//! on another id, remote, extended or CAN FD), a step of time, or a control
//! call (cancel, baseline reset, a new transfer). Missing bytes read as zero,
//! so every input is a valid script.

use std::collections::BTreeMap;
use std::sync::OnceLock;
use std::time::Duration;

use cangate_can::frame::FD_LENGTHS;
use cangate_can::{CanId, Frame};
use cangate_canopen::eds::Eds;
use cangate_canopen::emcy::{Emcy, EmcyConsumer, EmcyEvent};
use cangate_canopen::handwheel::{BaselineReason, CounterLayout, FeedDecoder};
use cangate_canopen::lss::{
    IdentifyRange, InquireWhat, LSS_REQUEST_COB_ID, LSS_RESPONSE_COB_ID, LssCommand, LssIdentity,
    LssMaster, LssMode, LssOutcome, UNCONFIGURED_NODE_ID,
};
use cangate_canopen::lss_slave::LssSlave;
use cangate_canopen::od::ObjectDictionary;
use cangate_canopen::pdo::{MappedObject, PdoConfig, PdoKind};
use cangate_canopen::program_download::{
    ProgramAction, ProgramDownload, ProgramPlan, ProgramStep, ProgramTimeouts,
};
use cangate_canopen::sdo::TransferOutcome;
use cangate_canopen::sdo::{
    AbortCode, BlockOptions, Mode, ObjectStore, SdoClient, SdoError, SdoServer, ServerOptions,
    Step, TransferOptions,
};
use cangate_canopen::value::DataType;
use cangate_canopen::{NodeId, ObjectAddress};
use cangate_cansmc::telegram::{Channel, ControlWord, StatusWord, Telegram};
use cangate_sim::{SimNode, SimNodeOptions, SimStore};

/// An entry function: takes any bytes, panics only on a defect.
pub type EntryFn = fn(&[u8]);

/// The names of the entry functions, which are also the fuzz target names
/// and the seed directories under `fuzz/seeds/`.
pub const TARGETS: &[(&str, EntryFn)] = &[
    ("cansend", cansend),
    ("sdo_client", sdo_client),
    ("sdo_server", sdo_server),
    ("pdo", pdo),
    ("emcy", emcy),
    ("lss_master", lss_master),
    ("lss_slave", lss_slave),
    ("eds", eds),
    ("handwheel", handwheel),
    ("cansmc_telegram", cansmc_telegram),
    ("program_download", program_download),
    #[cfg(feature = "config")]
    ("config", config),
    #[cfg(feature = "config")]
    ("socketcand", socketcand),
    #[cfg(feature = "config")]
    ("cia309", cia309),
];

/// A cursor over the input; reads past the end yield zeros.
struct Input<'a> {
    data: &'a [u8],
}

impl<'a> Input<'a> {
    fn new(data: &'a [u8]) -> Self {
        Input { data }
    }

    fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    fn u8(&mut self) -> u8 {
        match self.data.split_first() {
            Some((&b, rest)) => {
                self.data = rest;
                b
            }
            None => 0,
        }
    }

    fn u16(&mut self) -> u16 {
        u16::from_le_bytes([self.u8(), self.u8()])
    }

    fn u32(&mut self) -> u32 {
        u32::from_le_bytes([self.u8(), self.u8(), self.u8(), self.u8()])
    }

    /// Up to `n` bytes (fewer at the end of the input).
    fn take(&mut self, n: usize) -> &'a [u8] {
        let (head, rest) = self.data.split_at(n.min(self.data.len()));
        self.data = rest;
        head
    }
}

/// A received frame chosen by `sel`: mostly a classic data frame of
/// `sel & 0x0F` (clamped to 8) bytes on `cob`, else a frame on another
/// standard id, a remote, extended, error or CAN FD frame.
fn frame(r: &mut Input, cob: u16, sel: u8) -> Frame {
    let len = usize::from(sel & 0x0F);
    let classic = len.min(8);
    let own = CanId::Standard(cob & 0x7FF);
    let built = match sel >> 4 {
        0..=10 => Frame::new(own, r.take(classic)),
        11 | 12 => Frame::new(CanId::Standard(r.u16() & 0x7FF), r.take(classic)),
        13 => Frame::new_remote(own, classic as u8),
        14 if len & 1 == 0 => Frame::new(CanId::Extended(r.u32() & 0x1FFF_FFFF), r.take(classic)),
        14 => {
            let mut d = [0u8; 8];
            let src = r.take(8);
            d[..src.len()].copy_from_slice(src);
            Ok(Frame::new_error(u32::from(cob), d))
        }
        _ => {
            let mut d = r.take(FD_LENGTHS[len]).to_vec();
            d.resize(FD_LENGTHS[len], 0);
            Frame::new_fd(own, &d, len & 1 != 0, len & 2 != 0)
        }
    };
    built.expect("the harness builds only valid frames")
}

/// A node id 1..=127 from any byte.
fn node_id(b: u8) -> NodeId {
    NodeId::new(u32::from(b % 127) + 1).expect("1..=127")
}

/// The simulated drive's EDS, as the demo's `builtin:drive`.
fn drive_eds() -> &'static Eds {
    static EDS: OnceLock<Eds> = OnceLock::new();
    EDS.get_or_init(|| {
        Eds::parse(include_str!(
            "../../../crates/canopen/eds/cangate-drive.eds"
        ))
        .expect("the drive EDS parses")
    })
}

/// `cansend` syntax (`cangate send`, text frame files). A parsed frame
/// prints back to text that parses to the same frame.
pub fn cansend(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    let Ok(frame) = text.parse::<Frame>() else {
        return;
    };
    let printed = frame.to_string();
    let again: Frame = printed
        .parse()
        .unwrap_or_else(|e| panic!("{frame:?} prints as {printed:?}, which does not parse: {e}"));
    assert_eq!(again, frame, "{printed:?} does not parse back to itself");
}

/// Every frame a client or server sends is a classic 8-byte data frame on
/// its COB-ID.
fn assert_sdo_frames(frames: &[Frame], cob: u16) {
    for f in frames {
        assert_eq!(
            f.id(),
            CanId::Standard(cob),
            "SDO frame on the wrong id: {f:?}"
        );
        assert!(
            !f.is_fd() && !f.is_remote() && !f.is_error() && f.data().len() == 8,
            "not an 8-byte SDO frame: {f:?}"
        );
    }
}

/// Starts the transfer the next header bytes describe, if the client is
/// idle: upload or download (of up to 1 KiB), expedited/segmented or block;
/// at once or (as the gateway does) once the client is ready again.
fn start_sdo_transfer(client: &mut SdoClient, r: &mut Input, now: &mut Duration) {
    if client.is_busy() {
        return;
    }
    let h = r.u8();
    if h & 0x40 != 0 {
        *now = client.ready_at().map_or(*now, |at| at.max(*now));
    }
    let now = *now;
    let addr = ObjectAddress::new(r.u16(), r.u8());
    let mode = if h & 1 != 0 {
        Mode::Block(BlockOptions {
            block_size: r.u8(),
            crc: h & 2 != 0,
            switch_threshold: r.u8(),
            fallback: h & 4 != 0,
        })
    } else {
        Mode::Auto
    };
    let opts = TransferOptions {
        mode,
        timeout: (h & 0x10 != 0).then(|| Duration::from_millis(u64::from(r.u8()))),
        indicate_size: h & 8 != 0,
    };
    let frames = if h & 0x20 == 0 {
        client.start_upload(addr, opts, now)
    } else {
        let len = usize::from(r.u16() % 1024);
        let data = (0..len).map(|i| (i * 7) as u8).collect();
        client.start_download(addr, data, opts, now)
    };
    match frames {
        Ok(frames) => {
            assert!(client.is_busy(), "started, yet idle");
            assert_sdo_frames(&frames, client.request_cob_id());
        }
        Err(_) => assert!(!client.is_busy(), "refused to start, yet busy"),
    }
}

/// SDO client: starts a transfer, then takes arbitrary responses, timer
/// ticks and cancellations; when a transfer ends it starts the next one, so
/// late responses of the previous transfer reach the new one.
pub fn sdo_client(data: &[u8]) {
    let mut r = Input::new(data);
    let mut client = SdoClient::new(node_id(r.u8()));
    let (req, resp) = (client.request_cob_id(), client.response_cob_id());
    let mut now = Duration::ZERO;
    start_sdo_transfer(&mut client, &mut r, &mut now);
    while !r.is_empty() {
        let op = r.u8();
        let was_busy = client.is_busy();
        let step: Step = match op % 8 {
            0..=4 => {
                let sel = r.u8();
                let f = frame(&mut r, resp, sel);
                client.on_frame(&f, now)
            }
            5 => {
                now += Duration::from_millis(u64::from(op >> 3) * 50);
                let deadline = client.next_deadline();
                let step = client.on_tick(now);
                if let Some(d) = deadline {
                    let expired = now >= d;
                    assert_eq!(
                        matches!(step.completed, Some(Err(SdoError::Timeout { .. }))),
                        expired,
                        "deadline {d:?} at {now:?} gave {step:?}"
                    );
                }
                step
            }
            6 if op & 0x80 != 0 => {
                client.limit_timeout(Duration::from_millis(u64::from(op & 0x78)));
                continue;
            }
            6 => client.cancel(AbortCode(r.u32()), now),
            _ => {
                start_sdo_transfer(&mut client, &mut r, &mut now);
                continue;
            }
        };
        assert_sdo_frames(&step.frames, req);
        if !was_busy {
            assert_eq!(step, Step::default(), "an idle client acted");
        }
        assert_eq!(
            step.completed.is_some(),
            was_busy && !client.is_busy(),
            "completion and busy state disagree: {step:?}"
        );
        if let Some(p) = client.progress()
            && let Some(total) = p.total
        {
            assert!(p.transferred <= total, "progress past the total: {p:?}");
        }
        if let Some(Err(e)) = &step.completed {
            let _ = (e.to_string(), e.abort_code());
        }
        if step.completed.is_some() {
            start_sdo_transfer(&mut client, &mut r, &mut now);
        }
    }
}

/// SDO server of a simulated drive (the drive EDS as its object
/// dictionary): takes arbitrary requests and timer ticks.
pub fn sdo_server(data: &[u8]) {
    static STORE: OnceLock<SimStore> = OnceLock::new();
    let mut r = Input::new(data);
    let h = r.u8();
    let node = NodeId::new(5).expect("valid");
    let mut store = STORE
        .get_or_init(|| SimStore::new(drive_eds().od.clone(), node))
        .clone();
    let options = ServerOptions {
        block_transfer: h & 1 == 0,
        block_size: r.u8(),
        crc: h & 2 == 0,
        timeout: Duration::from_millis(100),
    };
    let mut server = SdoServer::new(node, options);
    let (req, resp) = (server.request_cob_id(), server.response_cob_id());
    let mut now = Duration::ZERO;
    while !r.is_empty() {
        let op = r.u8();
        let frames = if op % 8 == 7 {
            now += Duration::from_millis(u64::from(op >> 3) * 10);
            let deadline = server.next_deadline();
            let frames = server.on_tick(now);
            if let Some(d) = deadline {
                assert_eq!(now >= d, !frames.is_empty(), "deadline {d:?} at {now:?}");
                assert_eq!(now >= d, server.active_transfer().is_none());
            }
            frames
        } else {
            let f = frame(&mut r, req, op);
            server.on_frame(&f, now, &mut store)
        };
        assert_sdo_frames(&frames, resp);
        // Reads of what was written go through the store's own checks.
        if let Some(addr) = server.active_transfer() {
            let _ = store.read(addr);
        }
    }
}

/// PDO decoding (and re-encoding) with a mapping taken from the input:
/// arbitrary entries or objects of the drive's dictionary.
pub fn pdo(data: &[u8]) {
    static VARIABLES: OnceLock<Vec<(ObjectAddress, Option<usize>)>> = OnceLock::new();
    let vars = VARIABLES.get_or_init(|| {
        drive_eds()
            .od
            .variables()
            .map(|v| (v.address, v.data_type.fixed_size()))
            .collect()
    });
    let mut r = Input::new(data);
    let h = r.u8();
    let mapping = (0..h & 0x0F)
        .map(|_| {
            let e = r.u8();
            if e & 1 == 0 {
                let (addr, size) = vars[usize::from(r.u16()) % vars.len()];
                let bits = size.map_or(e, |n| (n * 8) as u8);
                MappedObject { addr, bits }
            } else {
                MappedObject::from_entry(r.u32())
            }
        })
        .collect();
    let cfg = PdoConfig {
        kind: if h & 0x20 == 0 {
            PdoKind::Rpdo
        } else {
            PdoKind::Tpdo
        },
        num: r.u16() % 520,
        cob_id: r.u16() & 0x7FF,
        transmission_type: r.u8(),
        inhibit_time: r.u16(),
        event_timer_ms: r.u16(),
        mapping,
    };
    let valid = cfg.validate().is_ok();
    let _ = cfg.sdo_writes();
    let od: Option<&ObjectDictionary> = (h & 0x10 != 0).then(|| &drive_eds().od);
    while !r.is_empty() {
        let n = usize::from(r.u8() % 10);
        let payload = r.take(n);
        let Ok(values) = cfg.decode(od, payload) else {
            continue;
        };
        assert_eq!(values.len(), cfg.mapping.len());
        if !valid {
            continue;
        }
        let pairs: Vec<_> = values.iter().map(|(m, v)| (m.addr, v.clone())).collect();
        let encoded = cfg
            .encode(&pairs)
            .unwrap_or_else(|e| panic!("decoded values do not encode: {e}"));
        assert_eq!(encoded.len(), cfg.len());
        let mut seen = BTreeMap::new();
        let unique = cfg
            .mapping
            .iter()
            .all(|m| seen.insert(m.addr, ()).is_none());
        let canonical = values
            .iter()
            .all(|(_, v)| v.data_type() != DataType::Boolean);
        if unique && canonical {
            assert_eq!(encoded, payload[..cfg.len()], "decode/encode differ");
        }
    }
}

/// The EMCY consumer: arbitrary frames around 0x080..=0x0FF.
pub fn emcy(data: &[u8]) {
    let mut r = Input::new(data);
    let limit = usize::from(r.u8() % 5);
    let mut consumer = EmcyConsumer::new(limit);
    let mut now = Duration::ZERO;
    while !r.is_empty() {
        now += Duration::from_millis(1);
        let cob = 0x80 | u16::from(r.u8() & 0x7F);
        let sel = r.u8();
        let f = frame(&mut r, cob, sel);
        let _ = Emcy::decode(&f).map(|e| (e.to_string(), e.code_name(), e.error_register()));
        let Some(event) = consumer.on_frame(&f, now) else {
            continue;
        };
        let _ = format!("{event:?}");
        match event {
            EmcyEvent::Error(e) => {
                assert_eq!(consumer.active(e.node), Some(&e));
                let _ = (e.to_string(), e.error_register().names().count());
            }
            EmcyEvent::Reset { emcy, .. } => assert_eq!(consumer.active(emcy.node), None),
            EmcyEvent::Malformed { node, .. } => assert!(consumer.node(node).is_some()),
        }
        let total = consumer.active_errors().count();
        assert!(total <= 127);
        for e in consumer.active_errors() {
            assert!(consumer.history(e.node).count() <= limit);
        }
    }
}

/// An LSS command chosen by the input.
fn lss_command(r: &mut Input) -> LssCommand {
    match r.u8() % 11 {
        0 => LssCommand::SwitchGlobal(if r.u8() & 1 == 0 {
            LssMode::Waiting
        } else {
            LssMode::Configuration
        }),
        1 => LssCommand::SwitchSelective(LssIdentity::from_parts([
            r.u32(),
            r.u32(),
            r.u32(),
            r.u32(),
        ])),
        2 => LssCommand::ConfigureNodeId(r.u8()),
        3 => LssCommand::ConfigureBitTiming {
            table: r.u8(),
            index: r.u8(),
        },
        4 => LssCommand::ActivateBitTiming {
            switch_delay_ms: r.u16(),
        },
        5 => LssCommand::StoreConfiguration,
        6 => LssCommand::Inquire(match r.u8() % 5 {
            0 => InquireWhat::VendorId,
            1 => InquireWhat::ProductCode,
            2 => InquireWhat::Revision,
            3 => InquireWhat::Serial,
            _ => InquireWhat::NodeId,
        }),
        7 => LssCommand::IdentifyRemote(IdentifyRange {
            vendor_id: r.u32(),
            product_code: r.u32(),
            revision_low: r.u32(),
            revision_high: r.u32(),
            serial_low: r.u32(),
            serial_high: r.u32(),
        }),
        8 => LssCommand::IdentifyNonConfigured,
        _ => LssCommand::Fastscan {
            step_time: Duration::from_millis(u64::from(r.u8() % 4)),
            max_nodes: usize::from(r.u8() % 3),
        },
    }
}

/// Every frame an LSS peer sends: 8 bytes on its COB-ID.
fn assert_lss_frames(frames: &[Frame], cob: u16) {
    for f in frames {
        assert_eq!(
            f.raw_id(),
            u32::from(cob),
            "LSS frame on the wrong id: {f:?}"
        );
        assert_eq!(f.data().len(), 8, "LSS frames are 8 bytes: {f:?}");
        assert!(!f.is_extended() && !f.is_remote() && !f.is_fd());
    }
}

/// The LSS master (CiA 305): commands chosen by the input, arbitrary
/// answers around 0x7E4, timer ticks and cancels. A command completes once,
/// a busy master refuses another, deadlines are kept.
pub fn lss_master(data: &[u8]) {
    let mut r = Input::new(data);
    let mut m = LssMaster::new();
    let mut now = Duration::ZERO;
    while !r.is_empty() {
        let op = r.u8();
        let was_running = m.running().is_some();
        let step = match op % 8 {
            0 => {
                let cmd = lss_command(&mut r);
                let timeout = Duration::from_millis(u64::from(r.u8()));
                let step = m.start(cmd, timeout, now);
                if was_running {
                    assert!(
                        matches!(
                            step.completed,
                            Some(Err(cangate_canopen::lss::LssError::Busy { .. }))
                        ),
                        "a busy master started another command: {step:?}"
                    );
                    assert!(step.frames.is_empty());
                    assert!(m.running().is_some(), "the running command was dropped");
                } else {
                    assert_eq!(
                        step.completed.is_none(),
                        m.running().is_some(),
                        "completion and running state disagree: {step:?}"
                    );
                }
                step
            }
            1..=4 => {
                let sel = r.u8();
                let cob = if op & 0x80 == 0 {
                    LSS_RESPONSE_COB_ID
                } else {
                    LSS_REQUEST_COB_ID
                };
                let f = frame(&mut r, cob, sel);
                let step = m.on_frame(&f, now);
                assert!(step.frames.is_empty(), "answers never make the master send");
                step
            }
            5 | 6 => {
                now += Duration::from_millis(u64::from(op >> 3));
                let deadline = m.next_deadline();
                let step = m.on_tick(now);
                if deadline.is_none_or(|d| now < d) {
                    assert_eq!(step, Default::default(), "acted before its deadline");
                }
                step
            }
            _ => {
                m.cancel();
                assert!(m.running().is_none());
                continue;
            }
        };
        assert_lss_frames(&step.frames, LSS_REQUEST_COB_ID);
        if op % 8 != 0 {
            assert_eq!(
                step.completed.is_some(),
                was_running && m.running().is_none(),
                "completion and running state disagree: {step:?}"
            );
        }
        if let Some(done) = &step.completed {
            match done {
                Ok(LssOutcome::Value(v)) => {
                    let _ = v;
                }
                Ok(LssOutcome::Found(ids)) => assert!(ids.len() <= 2),
                Ok(_) => {}
                Err(e) => {
                    let _ = e.to_string();
                }
            }
        }
        assert_eq!(m.next_deadline().is_some(), m.running().is_some());
    }
}

/// The LSS slave: an identity and a stored node-ID from the header, then
/// arbitrary requests around 0x7E5 and resets. Answers are 8 bytes on
/// 0x7E4; node-IDs stay 1..=127 or 255.
pub fn lss_slave(data: &[u8]) {
    let mut r = Input::new(data);
    let identity = LssIdentity::from_parts([
        u32::from(r.u8() & 3),
        u32::from(r.u8()),
        u32::from(r.u8() & 1),
        r.u32(),
    ]);
    let stored = match r.u8() {
        b @ 1..=127 => b,
        _ => UNCONFIGURED_NODE_ID,
    };
    let mut s = LssSlave::new(identity, stored);
    let valid = |id: u8| (1..=127).contains(&id) || id == UNCONFIGURED_NODE_ID;
    while !r.is_empty() {
        let op = r.u8();
        match op % 8 {
            0 => {
                let _ = s.on_reset(op & 0x80 != 0);
            }
            1 => s.power_on(),
            _ => {
                let sel = r.u8();
                let f = frame(&mut r, LSS_REQUEST_COB_ID, sel);
                let (answer, events) = s.on_frame(&f);
                assert_lss_frames(answer.as_slice(), LSS_RESPONSE_COB_ID);
                let _ = format!("{events:?}");
            }
        }
        assert!(valid(s.active_node_id()), "{:?}", s.active_node_id());
        assert!(valid(s.pending_node_id()));
        assert!(valid(s.stored_node_id()));
        assert_eq!(s.identity(), identity);
    }
}

/// EDS/DCF files, and what the gateway derives from them: the default
/// PDO configurations and a simulated node's store.
pub fn eds(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    let eds = match Eds::parse(&text) {
        Ok(eds) => eds,
        Err(e) => {
            let _ = (e.to_string(), e.line(), e.kind());
            return;
        }
    };
    let node = eds.node_id().unwrap_or_else(|| node_id(0));
    for kind in [PdoKind::Rpdo, PdoKind::Tpdo] {
        for num in 1..=4 {
            if let Some(cfg) = PdoConfig::from_od(&eds.od, kind, num, node)
                && cfg.validate().is_ok()
            {
                let _ = cfg.sdo_writes();
            }
        }
    }
    let _ = eds.od.defaults_for_node(node).count();
    let addresses: Vec<_> = eds.od.variables().map(|v| v.address).collect();
    let mut store = SimStore::new(eds.od, node);
    for addr in addresses {
        if let Ok(value) = store.read(addr) {
            let _ = store.write(addr, &value);
        }
    }
}

/// The handwheel feed decoder: feed frames, boot-ups, other frames,
/// baseline resets. The units it reports add up to its statistics.
pub fn handwheel(data: &[u8]) {
    let mut r = Input::new(data);
    let h = r.u8();
    let layout = if h & 0x80 == 0 {
        CounterLayout::Nibble
    } else {
        CounterLayout::Bits6_7
    };
    let node = node_id(h);
    let mut decoder = FeedDecoder::new(node, layout);
    let cob = decoder.cob_id();
    let mut now = Duration::ZERO;
    let mut units = 0u64;
    let mut feed_frames = 0u64;
    while !r.is_empty() {
        let op = r.u8();
        now += Duration::from_millis(u64::from(op & 0x0F));
        let event = match op >> 4 {
            0..=9 => {
                let sel = if op & 0x10 == 0 { 0x01 } else { r.u8() };
                let f = frame(&mut r, cob, sel);
                let on_feed = f.raw_id() == u32::from(cob) && !f.is_extended() && !f.is_error();
                let event = decoder.on_frame(&f, now);
                assert_eq!(event.is_some(), on_feed, "{f:?} gave {event:?}");
                feed_frames += u64::from(on_feed);
                event
            }
            10 => {
                let boot = Frame::new(CanId::Standard(0x700 + u16::from(node.get())), &[0])
                    .expect("valid");
                assert_eq!(decoder.on_frame(&boot, now), None);
                assert!(decoder.awaiting_baseline());
                None
            }
            11 => {
                let reason = [
                    BaselineReason::HeartbeatLost,
                    BaselineReason::ModeChange,
                    BaselineReason::Other,
                ][usize::from(op % 3)];
                decoder.reset_baseline(reason);
                None
            }
            _ => Some(decoder.on_byte(r.u8(), now)),
        };
        if let Some(e) = event {
            if e.error.is_some() {
                assert_eq!(e.units, 0, "a bad frame moved: {e:?}");
            }
            assert!(e.compensated < 16);
            units += u64::from(e.units);
            let _ = e.signed_units();
        }
        assert_eq!(decoder.stats().total_units(), units, "units do not add up");
        assert_eq!(decoder.stats().frames, feed_frames, "frames do not add up");
    }
}

/// CANsmc telegrams on either channel. A decoded telegram encodes back to
/// the same frame; control and status words round-trip.
pub fn cansmc_telegram(data: &[u8]) {
    let mut r = Input::new(data);
    while !r.is_empty() {
        let sel = r.u8();
        let channel = if sel & 0x80 == 0 {
            Channel::Command
        } else {
            Channel::Status
        };
        let id = r.u16() & 0x7FF;
        let kind = r.u8();
        let f = frame(&mut r, id, kind);
        if let Ok(t) = Telegram::decode(&f, channel) {
            let _ = (format!("{t:?}"), t.function().to_string());
            let again = t.encode();
            assert_eq!(again.id(), f.id(), "{t:?}");
            assert_eq!(again.data(), f.data(), "{t:?}");
            assert_eq!(t.channel(), channel, "{t:?}");
        }
        let w = r.u16();
        if let Ok((cw, parameter_write)) = ControlWord::from_bits(w) {
            assert_eq!(cw.to_bits(parameter_write), w, "control word {w:#06X}");
        }
        if let Ok(sw) = StatusWord::from_bits(w) {
            assert_eq!(sw.to_bits(), w, "status word {w:#06X}");
        }
    }
}

#[cfg(feature = "config")]
/// The server configuration from TOML text. A valid configuration prints
/// (`--print-config`) as TOML that loads again.
pub fn config(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(cfg) = cangate_server::config::Config::from_toml(text) else {
        return;
    };
    let printed = cfg.to_toml();
    if let Err(e) = cangate_server::config::Config::from_toml(&printed) {
        panic!("the printed configuration does not load: {e}\n{printed}");
    }
}

#[cfg(feature = "config")]
/// The socketcand endpoint's protocol (server/src/socketcand/protocol.rs):
/// the bytes a client sends, in chunks cut where the first byte says, through
/// the deframer and the session. Every element is within the limit, every
/// line the gateway would write is one element (`< ` … ` >`, no other
/// bracket), and every frame a `send` yields is reported as one too.
pub fn socketcand(data: &[u8]) {
    use cangate_server::socketcand::protocol::{Action, Deframer, Session, format_frame};
    const MAX: usize = 128;
    let one_element = |line: &str| {
        assert!(
            line.starts_with("< ")
                && line.ends_with(" >")
                && line.matches('<').count() == 1
                && line.matches('>').count() == 1,
            "not one element: {line:?}"
        );
    };
    let (chunk, rest) = match data.split_first() {
        Some((c, rest)) => (usize::from(*c % 32) + 1, rest),
        None => return,
    };
    let mut deframer = Deframer::new(MAX);
    let mut session = Session::new();
    for piece in rest.chunks(chunk) {
        deframer.push(piece);
        loop {
            let element = match deframer.next_element() {
                Ok(Some(e)) => e,
                Ok(None) => break,
                Err(_) => return,
            };
            assert!(element.len() <= MAX, "{} bytes", element.len());
            match session.on_element(&element) {
                Action::Reply(line) | Action::Close(line) => one_element(&line),
                Action::Open { bus, token } => {
                    assert!(!bus.is_empty() && !bus.contains(['<', '>', ' ']));
                    assert!(token.is_none_or(|t| !t.is_empty()));
                    session.opened();
                }
                Action::Send(frame) => {
                    assert!(!frame.is_remote() && !frame.is_error());
                    let line = format_frame(&frame).expect("a data frame is reported");
                    one_element(&line);
                }
                Action::Feed(_) => {}
                Action::Bcm(command) => {
                    use cangate_server::socketcand::bcm::format_bcm_frame;
                    use cangate_server::socketcand::protocol::BcmCommand;
                    if let BcmCommand::Add { frame, .. } | BcmCommand::Update(frame) = command {
                        assert!(!frame.is_fd() && !frame.is_remote());
                        one_element(&format_bcm_frame(&frame));
                    }
                }
            }
        }
    }
}

/// The CiA 309-3 gateway's reading of command lines: a chunk size, then
/// the bytes a client sends. Every line within the limit; every answer the
/// session gives itself ends with `\r\n` and holds no other line break
/// but the `\n` of a help text; a write's data is never empty; a read's
/// value printed as its type (and as every other) is one line.
pub fn cia309(data: &[u8]) {
    use cangate_server::cia309::protocol::{Action, DataType, LineBuffer, Session, format_value};
    const MAX: usize = 256;
    let (chunk, rest) = match data.split_first() {
        Some((c, rest)) => (usize::from(*c % 32) + 1, rest),
        None => return,
    };
    let mut lines = LineBuffer::new(MAX);
    let mut session = Session::new(2, 500);
    let types = [
        "b", "i8", "i16", "i32", "i64", "u8", "u16", "u32", "u64", "x8", "x16", "x32", "x64",
        "r32", "r64", "vs", "os", "us", "d", "hex",
    ];
    for piece in rest.chunks(chunk) {
        lines.push(piece);
        loop {
            let line = match lines.next_line() {
                Ok(Some(l)) => l,
                Ok(None) => break,
                Err(_) => return,
            };
            assert!(line.len() <= MAX, "{} bytes", line.len());
            match session.on_line(&line) {
                Action::Reply(text) => {
                    assert!(text.ends_with("\r\n"), "{text:?}");
                    if !text.starts_with('\n') {
                        assert_eq!(text.matches('\n').count(), 1, "{text:?}");
                    }
                }
                Action::Write { data, .. } => {
                    assert!(!data.is_empty());
                    for t in types {
                        let ty = DataType::from_name(t).expect("a type");
                        let text = format_value(1, Some(ty), &data);
                        assert_eq!(text.matches('\n').count(), 1, "{t}: {text:?}");
                    }
                }
                Action::WritePdo {
                    node, pdo, values, ..
                } => {
                    assert!((1..=127).contains(&node) && (1..=4).contains(&pdo));
                    assert!(values.len() <= 64);
                    let text = cangate_server::cia309::protocol::format_pdo(1, 1, &values);
                    assert_eq!(text.matches('\n').count(), 1, "{text:?}");
                }
                Action::ReadPdo { node, pdo, .. } => {
                    assert!((1..=127).contains(&node) && (1..=4).contains(&pdo));
                }
                Action::Read { .. }
                | Action::Nmt { .. }
                | Action::Lss { .. }
                | Action::Events { .. }
                | Action::Login { .. }
                | Action::Info { .. } => {}
            }
        }
    }
}

/// Program download (CiA 302-3): the master's state machine fed arbitrary
/// SDO results (values of any length read from the node, aborts with any
/// code, timeouts), boot-ups and time; then a simulated node's program
/// objects (0x1F50..0x1F57, the block download gate and its faults) fed
/// arbitrary frames on its SDO COB-ID. Steps only move forward, the end
/// comes once, and nothing is asked after it.
pub fn program_download(data: &[u8]) {
    let mut r = Input::new(data);
    let ms = |v: u64| Duration::from_millis(v);
    let node = node_id(r.u8());
    let program = r.u8().max(1);
    let len = usize::from(r.u8());
    let image = r.take(len).to_vec();
    let expected = (r.u8() & 1 == 1).then(|| r.u32());
    let clear = r.u8() & 1 == 1;
    let timeouts = ProgramTimeouts {
        flash: ms(u64::from(r.u16())),
        poll_interval: ms(u64::from(r.u8())),
        boot: ms(u64::from(r.u16())),
    };
    let plan = ProgramPlan {
        node,
        program,
        image,
        expected_identification: expected,
        clear,
        timeouts,
    };
    let mut pd = ProgramDownload::new(plan);
    let mut now = Duration::ZERO;
    let mut last: Option<ProgramStep> = None;
    let mut finished = false;
    let mut check = |actions: Vec<ProgramAction>, finished: &mut bool| {
        for a in actions {
            assert!(!*finished, "an action after the end: {a:?}");
            match a {
                ProgramAction::Step(s) => {
                    assert!(last.is_none_or(|l| l <= s), "{last:?} then {s:?}");
                    last = Some(s);
                }
                ProgramAction::Sdo(req) => {
                    let _ = format!("{req:?}");
                }
                ProgramAction::Finished(r) => {
                    if let Err(e) = &r {
                        let _ = (e.to_string(), e.step(), e.abort_code());
                    }
                    *finished = true;
                }
            }
        }
    };
    check(pd.start(now), &mut finished);
    let addr = ObjectAddress::new(0x1F50, program);
    let mut frames_left = 0;
    while !r.is_empty() && frames_left == 0 {
        let op = r.u8();
        let actions = match op % 9 {
            0..=2 => {
                let n = usize::from(r.u8() % 9);
                let value = r.take(n).to_vec();
                pd.on_sdo_result(Ok(TransferOutcome::Uploaded(value)), now)
            }
            3 => pd.on_sdo_result(Ok(TransferOutcome::Downloaded), now),
            4 => pd.on_sdo_result(
                Err(SdoError::Aborted {
                    addr,
                    code: AbortCode(r.u32()),
                }),
                now,
            ),
            5 => pd.on_sdo_result(
                Err(SdoError::Timeout {
                    addr,
                    timeout: ms(500),
                }),
                now,
            ),
            6 => pd.on_boot_up(now),
            7 => {
                now += ms(u64::from(r.u16()));
                pd.on_tick(now)
            }
            _ => {
                frames_left = 1;
                Vec::new()
            }
        };
        check(actions, &mut finished);
        if finished {
            assert_eq!(pd.step(), None);
            assert_eq!(pd.next_deadline(), None);
            assert!(pd.is_finished());
        }
        if let Some(d) = pd.next_deadline() {
            assert!(d <= now + ms(70_000) + ms(u64::from(u16::MAX)) * 2);
        }
    }
    // The rest of the input: frames to a simulated node's SDO server.
    let mut sim = SimNode::new(drive_eds(), node, SimNodeOptions::default());
    let _ = sim.start(now);
    let cob = 0x600 + u16::from(node.get());
    let rx = 0x580 + u16::from(node.get());
    while !r.is_empty() {
        let sel = r.u8();
        if sel == 0xFF {
            now += ms(u64::from(r.u8()));
            let _ = sim.on_tick(now);
            continue;
        }
        let f = frame(&mut r, cob, sel);
        now += Duration::from_micros(100);
        for out in sim.on_frame(&f, now) {
            assert!(!out.is_fd() && !out.is_extended());
            if out.raw_id() == u32::from(rx) {
                assert_eq!(out.data().len(), 8);
            }
        }
        if let Some(d) = sim.next_deadline() {
            let _ = sim.on_tick(d.max(now));
        }
        let p = sim.program();
        let _ = (p.running(), p.identification(), p.downloads());
    }
}
