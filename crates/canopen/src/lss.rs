//! Layer setting services (LSS, CiA 305), master side: give a device
//! without a node-ID one, change bit timing, and find devices by their
//! 128-bit identity (the CiA 301 identity object 0x1018:01..=04: vendor-ID,
//! product code, revision number, serial number).
//!
//! Every LSS frame is 8 bytes; the master sends on COB-ID 0x7E5, slaves
//! answer on 0x7E4. Byte 0 is the command specifier (cs):
//!
//! | cs | service | answer |
//! |---|---|---|
//! | 0x04 | switch state global `[04 mode]` (0 waiting, 1 configuration) | none |
//! | 0x40..=0x43 | switch state selective: vendor, product, revision, serial (u32 LE in bytes 1..=4) | 0x44 after the serial, from the one slave that matched all four |
//! | 0x11 | configure node-ID `[11 id]` (1..=127, or 255 = none) | `[11 error spec]` |
//! | 0x13 | configure bit timing `[13 table index]` | `[13 error spec]` |
//! | 0x15 | activate bit timing `[15 delay_lo delay_hi]` (switch delay, ms) | none |
//! | 0x17 | store configuration `[17]` | `[17 error spec]` |
//! | 0x5A..=0x5D | inquire vendor, product, revision, serial | same cs, u32 LE |
//! | 0x5E | inquire node-ID | `[5E id]` |
//! | 0x46..=0x4B | identify remote slave: vendor, product, revision low/high, serial low/high | 0x4F from every slave inside the ranges |
//! | 0x4C | identify non-configured remote slave | 0x50 from every slave without a node-ID |
//! | 0x51 | fastscan `[51 IDNumber(u32 LE) BitChecked LSSSub LSSNext]` | 0x4F |
//!
//! Error codes of the confirmed configure services: 0 success, 1 node-ID
//! out of range / bit timing not supported / storing not supported, 2
//! storage media access error (store), 0xFF implementation-specific (the
//! slave's own code in byte 2).
//!
//! Byte vectors here agree with python `canopen`'s `canopen/lss.py`
//! (`LssMaster`: `struct.pack('<BIBBB', CS_FAST_SCAN, id_number,
//! bit_checker, lss_sub, lss_next)`, `message[1:3] = struct.pack('<H',
//! switch_delay_ms)` for 0x15, `[cs, value1, value2]` for the configure
//! services) and CANopenNode's `CO_LSSmaster.c`/`CO_LSSslave.c`.
//!
//! # What this module settles where the spec leaves room
//!
//! - **One operation at a time.** LSS is bus-global (every slave listens to
//!   0x7E5); [`LssMaster`] runs one command at a time and refuses another
//!   ([`LssError::Busy`]) until it ends. The runner serialises per bus.
//! - **Answers** carry the command's cs; 0x7E4 frames with another cs while
//!   a command waits are ignored (another master's traffic, a late answer
//!   to an earlier command), so are all answers while none waits. An
//!   answer with the right cs but shorter than the fields it must carry is
//!   a [`LssError::Protocol`] violation.
//! - **Timeouts**: each confirmed command waits `timeout` for its answer
//!   ([`LssError::Timeout`]). Unconfirmed commands (0x04, 0x15) complete as
//!   soon as they are sent. Identify remote / non-configured complete on
//!   the first answer with `true`, after `timeout` with `false`: silence is
//!   an answer there, not an error.
//! - **Fastscan** (0x51) follows the CiA 305 bit-by-bit search: a reset
//!   query (BitChecked 0x80) asks whether any non-configured slave in the
//!   waiting state is there; then, for LSSSub 0..=3 and each bit from 31
//!   down to 0, a query with that bit 0 (and the bits found above it):
//!   silence means the bit is 1. After bit 0 a confirmation (BitChecked 0,
//!   LSSNext the next part, 0 after the serial) moves the slave to the next
//!   part; the last one puts it in the configuration state. Because several
//!   slaves may answer the same query (on a real bus their identical frames
//!   merge, on a virtual bus they do not), every fastscan step lasts its
//!   full step time and counts any 0x4F in it, as CANopenNode's master
//!   does; a step never ends early. A failed confirmation (a slave lost
//!   mid-scan, or an answer that came after its step and was counted for
//!   the next one, which makes a bit wrong) restarts the search with a
//!   reset query, which also resets the slave being searched (slaves
//!   already found sit in the configuration state and stay out), at most
//!   [`FASTSCAN_RESTARTS`] times per scan; one more is a
//!   [`LssError::Protocol`] error naming the part. Scanning for all slaves
//!   repeats the search: a slave found sits in the configuration state and
//!   no longer answers, so the next reset query finds the next, until
//!   silence. The scan leaves every found slave in the configuration
//!   state; the caller switches them back (0x04 mode 0) when done.
//! - **A slave found twice ends the scan.** CANopenNode's LSS slave
//!   answers fastscan in any LSS state while it has no node-ID, so the
//!   reset query after its find finds it again, for ever. An identity
//!   found a second time is not counted again: the scan ends there with
//!   the identities found once (a slave behind such a one, higher in
//!   identity, is then only found after the first has been given an id:
//!   [`LssCommand::Fastscan`] with `max_nodes` 1, configure, repeat). The
//!   scan is bounded: at most `max_nodes` finds, each with at most
//!   [`FASTSCAN_RESTARTS`] restarts, and one more search at most.
//! - **The step time** must let a request and its answer cross the bus and
//!   the slave turn round ([`min_fastscan_step`]): a shorter step hears
//!   nothing and reports "no slave" while one is there.
//! - Known identity parts (CiA 305 lets a master skip them) are not used:
//!   every scan searches all 128 bits.

use std::time::Duration;

use cangate_can::{CanId, Frame};

/// COB-ID of LSS requests (master → slaves).
pub const LSS_REQUEST_COB_ID: u16 = 0x7E5;
/// COB-ID of LSS answers (slave → master).
pub const LSS_RESPONSE_COB_ID: u16 = 0x7E4;
/// The node-ID of a device without one (CiA 305 "unconfigured").
pub const UNCONFIGURED_NODE_ID: u8 = 0xFF;

/// Command specifiers (byte 0) of CiA 305.
pub mod cs {
    /// Switch state global.
    pub const SWITCH_GLOBAL: u8 = 0x04;
    /// Configure node-ID.
    pub const CONFIGURE_NODE_ID: u8 = 0x11;
    /// Configure bit timing.
    pub const CONFIGURE_BIT_TIMING: u8 = 0x13;
    /// Activate bit timing.
    pub const ACTIVATE_BIT_TIMING: u8 = 0x15;
    /// Store configuration.
    pub const STORE_CONFIGURATION: u8 = 0x17;
    /// Switch state selective: vendor-ID.
    pub const SWITCH_SELECTIVE_VENDOR: u8 = 0x40;
    /// Switch state selective: product code.
    pub const SWITCH_SELECTIVE_PRODUCT: u8 = 0x41;
    /// Switch state selective: revision number.
    pub const SWITCH_SELECTIVE_REVISION: u8 = 0x42;
    /// Switch state selective: serial number.
    pub const SWITCH_SELECTIVE_SERIAL: u8 = 0x43;
    /// Switch state selective answer.
    pub const SWITCH_SELECTIVE_RESPONSE: u8 = 0x44;
    /// Identify remote slave: vendor-ID.
    pub const IDENTIFY_VENDOR: u8 = 0x46;
    /// Identify remote slave: product code.
    pub const IDENTIFY_PRODUCT: u8 = 0x47;
    /// Identify remote slave: revision number, low bound.
    pub const IDENTIFY_REVISION_LOW: u8 = 0x48;
    /// Identify remote slave: revision number, high bound.
    pub const IDENTIFY_REVISION_HIGH: u8 = 0x49;
    /// Identify remote slave: serial number, low bound.
    pub const IDENTIFY_SERIAL_LOW: u8 = 0x4A;
    /// Identify remote slave: serial number, high bound.
    pub const IDENTIFY_SERIAL_HIGH: u8 = 0x4B;
    /// Identify non-configured remote slave.
    pub const IDENTIFY_NON_CONFIGURED: u8 = 0x4C;
    /// Identify slave (answer to 0x46..=0x4B and to fastscan).
    pub const IDENTIFY_SLAVE: u8 = 0x4F;
    /// Identify non-configured slave (answer to 0x4C).
    pub const IDENTIFY_NON_CONFIGURED_SLAVE: u8 = 0x50;
    /// Fastscan.
    pub const FASTSCAN: u8 = 0x51;
    /// Inquire vendor-ID.
    pub const INQUIRE_VENDOR: u8 = 0x5A;
    /// Inquire product code.
    pub const INQUIRE_PRODUCT: u8 = 0x5B;
    /// Inquire revision number.
    pub const INQUIRE_REVISION: u8 = 0x5C;
    /// Inquire serial number.
    pub const INQUIRE_SERIAL: u8 = 0x5D;
    /// Inquire node-ID.
    pub const INQUIRE_NODE_ID: u8 = 0x5E;
}

/// How often one fastscan restarts its search after a failed
/// confirmation before it gives up.
pub const FASTSCAN_RESTARTS: u8 = 3;

/// Fastscan BitChecked value of the reset query.
pub const FASTSCAN_RESET: u8 = 0x80;

/// How long a slave may take to turn a fastscan query round into its
/// answer, beyond the frames' own time on the bus: one wake-up of a device
/// stack's task on a loaded host.
pub const FASTSCAN_SLAVE_TURNAROUND: Duration = Duration::from_millis(2);

/// The shortest fastscan step on a bus of `bitrate` bit/s (`None`: no bit
/// timing, frames take no time): the request and the answer, each an
/// 8-byte standard frame at its longest (135 bits with worst-case stuff
/// bits and the interframe space), plus [`FASTSCAN_SLAVE_TURNAROUND`],
/// rounded up to whole milliseconds.
pub fn min_fastscan_step(bitrate: Option<u32>) -> Duration {
    const FRAME_BITS: u64 = 135;
    let frames_us = bitrate
        .filter(|b| *b > 0)
        .map_or(0, |b| (2 * FRAME_BITS * 1_000_000).div_ceil(u64::from(b)));
    let us = frames_us + FASTSCAN_SLAVE_TURNAROUND.as_micros() as u64;
    Duration::from_millis(us.div_ceil(1000))
}

/// A device's LSS address: the identity object 0x1018:01..=04.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct LssIdentity {
    /// 0x1018:01.
    pub vendor_id: u32,
    /// 0x1018:02.
    pub product_code: u32,
    /// 0x1018:03.
    pub revision: u32,
    /// 0x1018:04.
    pub serial: u32,
}

impl LssIdentity {
    /// The four parts in LSSSub order (0 vendor .. 3 serial).
    pub fn parts(&self) -> [u32; 4] {
        [
            self.vendor_id,
            self.product_code,
            self.revision,
            self.serial,
        ]
    }
    /// From the four parts in LSSSub order.
    pub fn from_parts(p: [u32; 4]) -> Self {
        LssIdentity {
            vendor_id: p[0],
            product_code: p[1],
            revision: p[2],
            serial: p[3],
        }
    }
}

impl std::fmt::Display for LssIdentity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "vendor 0x{:08X} product 0x{:08X} revision 0x{:08X} serial 0x{:08X}",
            self.vendor_id, self.product_code, self.revision, self.serial
        )
    }
}

/// The LSS state of a slave.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LssMode {
    /// Waiting state (mode 0): the slave only listens for switch and
    /// identify commands and fastscan.
    Waiting,
    /// Configuration state (mode 1).
    Configuration,
}

impl LssMode {
    /// The mode byte of switch state global.
    pub fn to_byte(self) -> u8 {
        match self {
            LssMode::Waiting => 0,
            LssMode::Configuration => 1,
        }
    }
}

/// Which identity part (or the node-ID) an inquire command asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InquireWhat {
    /// 0x5A.
    VendorId,
    /// 0x5B.
    ProductCode,
    /// 0x5C.
    Revision,
    /// 0x5D.
    Serial,
    /// 0x5E: the active node-ID (255: none).
    NodeId,
}

impl InquireWhat {
    /// The command specifier.
    pub fn cs(self) -> u8 {
        match self {
            InquireWhat::VendorId => cs::INQUIRE_VENDOR,
            InquireWhat::ProductCode => cs::INQUIRE_PRODUCT,
            InquireWhat::Revision => cs::INQUIRE_REVISION,
            InquireWhat::Serial => cs::INQUIRE_SERIAL,
            InquireWhat::NodeId => cs::INQUIRE_NODE_ID,
        }
    }
}

/// Ranges of identify remote slave (0x46..=0x4B): vendor and product
/// exact, revision and serial inclusive ranges.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct IdentifyRange {
    /// Vendor-ID.
    pub vendor_id: u32,
    /// Product code.
    pub product_code: u32,
    /// Lowest revision number.
    pub revision_low: u32,
    /// Highest revision number.
    pub revision_high: u32,
    /// Lowest serial number.
    pub serial_low: u32,
    /// Highest serial number.
    pub serial_high: u32,
}

/// One LSS command.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LssCommand {
    /// 0x04: every slave to `mode`. Unconfirmed.
    SwitchGlobal(LssMode),
    /// 0x40..=0x43: the slave with this identity to the configuration
    /// state; confirmed by 0x44.
    SwitchSelective(LssIdentity),
    /// 0x11: the configured slave's pending node-ID (1..=127, or 255 to
    /// take it away).
    ConfigureNodeId(u8),
    /// 0x13: bit timing table selector (0 = CiA 301 table) and index.
    ConfigureBitTiming {
        /// Table selector.
        table: u8,
        /// Index in the table.
        index: u8,
    },
    /// 0x15: activate the configured bit timing after the switch delay.
    /// Unconfirmed.
    ActivateBitTiming {
        /// Switch delay in ms.
        switch_delay_ms: u16,
    },
    /// 0x17: store the pending node-ID and bit timing.
    StoreConfiguration,
    /// 0x5A..=0x5E.
    Inquire(InquireWhat),
    /// 0x46..=0x4B: is any slave inside the ranges there?
    IdentifyRemote(IdentifyRange),
    /// 0x4C: is any slave without a node-ID there?
    IdentifyNonConfigured,
    /// 0x51 repeated: the identities of up to `max_nodes` non-configured
    /// slaves in the waiting state (each left in the configuration state).
    Fastscan {
        /// How long each step listens for answers.
        step_time: Duration,
        /// Stop after this many slaves (at least 1).
        max_nodes: usize,
    },
}

impl LssCommand {
    /// The command's name in CiA 305 terms, for messages.
    pub fn name(&self) -> &'static str {
        match self {
            LssCommand::SwitchGlobal(_) => "switch state global",
            LssCommand::SwitchSelective(_) => "switch state selective",
            LssCommand::ConfigureNodeId(_) => "configure node-ID",
            LssCommand::ConfigureBitTiming { .. } => "configure bit timing",
            LssCommand::ActivateBitTiming { .. } => "activate bit timing",
            LssCommand::StoreConfiguration => "store configuration",
            LssCommand::Inquire(_) => "inquire",
            LssCommand::IdentifyRemote(_) => "identify remote slave",
            LssCommand::IdentifyNonConfigured => "identify non-configured remote slave",
            LssCommand::Fastscan { .. } => "fastscan",
        }
    }
}

/// How a command ended well.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LssOutcome {
    /// An unconfirmed command was sent.
    Sent,
    /// A confirmed command was confirmed (0x44, or error code 0).
    Confirmed,
    /// An inquired value (node-ID: 1..=127 or 255).
    Value(u32),
    /// Identify: whether any slave answered.
    Present(bool),
    /// Fastscan: the identities found, in the order found.
    Found(Vec<LssIdentity>),
}

/// Why an LSS command failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LssError {
    /// Nobody answered in time.
    #[error("LSS {command}: no answer within {after:?}")]
    Timeout {
        /// The command.
        command: &'static str,
        /// The time waited.
        after: Duration,
    },
    /// The slave answered with an error code.
    #[error("LSS {command}: the slave refused with error {error}{}", spec_text(*.error, *.spec_error))]
    Refused {
        /// The command.
        command: &'static str,
        /// The CiA 305 error code (1, 2, or 0xFF).
        error: u8,
        /// The implementation-specific error (with error 0xFF).
        spec_error: u8,
    },
    /// An answer that breaks the protocol.
    #[error("LSS {command}: protocol violation: {reason}")]
    Protocol {
        /// The command.
        command: &'static str,
        /// What was wrong.
        reason: String,
    },
    /// Another LSS command is running.
    #[error("another LSS command ({running}) is running on this bus")]
    Busy {
        /// The running command.
        running: &'static str,
    },
    /// The command's arguments are invalid (e.g. a node-ID outside
    /// 1..=127 and 255).
    #[error("LSS {command}: {reason}")]
    Invalid {
        /// The command.
        command: &'static str,
        /// Why.
        reason: String,
    },
}

fn spec_text(error: u8, spec: u8) -> String {
    let meaning = match error {
        1 => " (out of range / not supported)",
        2 => " (storage media access error)",
        0xFF => return format!(" (implementation-specific error {spec})"),
        _ => "",
    };
    meaning.to_string()
}

/// An LSS request frame: `cs` then `payload` (at most 7 bytes), zero
/// padded to 8 bytes, on 0x7E5.
pub fn request_frame(cs: u8, payload: &[u8]) -> Frame {
    lss_frame(LSS_REQUEST_COB_ID, cs, payload)
}

/// An LSS answer frame on 0x7E4.
pub fn response_frame(cs: u8, payload: &[u8]) -> Frame {
    lss_frame(LSS_RESPONSE_COB_ID, cs, payload)
}

fn lss_frame(cob: u16, cs: u8, payload: &[u8]) -> Frame {
    let mut data = [0u8; 8];
    data[0] = cs;
    let n = payload.len().min(7);
    data[1..1 + n].copy_from_slice(&payload[..n]);
    Frame::new(CanId::Standard(cob), &data).expect("an 8-byte standard frame")
}

/// A fastscan query.
pub fn fastscan_frame(id_number: u32, bit_checked: u8, sub: u8, next: u8) -> Frame {
    let v = id_number.to_le_bytes();
    request_frame(
        cs::FASTSCAN,
        &[v[0], v[1], v[2], v[3], bit_checked, sub, next],
    )
}

/// An LSS answer as a master reads it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LssAnswer {
    /// Command specifier.
    pub cs: u8,
    /// Bytes 1..=7 (zero where the frame was shorter).
    pub payload: [u8; 7],
    /// The frame's length.
    pub len: usize,
}

impl LssAnswer {
    /// Bytes 1..=4 as a u32 (little-endian).
    pub fn u32(&self) -> u32 {
        u32::from_le_bytes([
            self.payload[0],
            self.payload[1],
            self.payload[2],
            self.payload[3],
        ])
    }
}

/// Decodes a frame on `cob` (0x7E4 answers, 0x7E5 requests): `None` for
/// other ids, remote, extended, FD or empty frames. Never panics.
pub fn decode(frame: &Frame, cob: u16) -> Option<LssAnswer> {
    if frame.is_extended()
        || frame.is_remote()
        || frame.is_fd()
        || frame.is_error()
        || frame.raw_id() != u32::from(cob)
    {
        return None;
    }
    let d = frame.data();
    let (&cs, rest) = d.split_first()?;
    let mut payload = [0u8; 7];
    let n = rest.len().min(7);
    payload[..n].copy_from_slice(&rest[..n]);
    Some(LssAnswer {
        cs,
        payload,
        len: d.len(),
    })
}

/// What a command is waiting for.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Wait {
    /// A confirmed answer with this cs; `min_len` bytes needed.
    Answer { cs: u8, min_len: usize },
    /// Any answer with this cs before the deadline (identify).
    Presence { cs: u8 },
    /// A fastscan step.
    Fastscan(Fastscan),
}

#[derive(Debug, Clone, PartialEq, Eq)]
struct Fastscan {
    step_time: Duration,
    max_nodes: usize,
    found: Vec<LssIdentity>,
    id: [u32; 4],
    step: ScanStep,
    /// A 0x4F arrived during the current step.
    answered: bool,
    /// Restarts after failed confirmations so far.
    restarts: u8,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ScanStep {
    /// The reset query.
    Reset,
    /// Bit `bit` of part `sub`.
    Bit { sub: u8, bit: u8 },
    /// The confirmation of part `sub`.
    Confirm { sub: u8 },
}

impl Fastscan {
    fn query(&self) -> Frame {
        match self.step {
            ScanStep::Reset => fastscan_frame(0, FASTSCAN_RESET, 0, 0),
            ScanStep::Bit { sub, bit } => fastscan_frame(self.id[usize::from(sub)], bit, sub, sub),
            ScanStep::Confirm { sub } => {
                fastscan_frame(self.id[usize::from(sub)], 0, sub, (sub + 1) & 3)
            }
        }
    }
}

#[derive(Debug)]
struct Running {
    name: &'static str,
    wait: Wait,
    deadline: Duration,
    timeout: Duration,
}

/// The result of one input to [`LssMaster`].
#[derive(Debug, Default, PartialEq, Eq)]
pub struct LssStep {
    /// Frames to send, in order.
    pub frames: Vec<Frame>,
    /// The command ended.
    pub completed: Option<Result<LssOutcome, LssError>>,
}

/// The LSS master of one bus: one command at a time. See the
/// [module documentation](self).
#[derive(Debug, Default)]
pub struct LssMaster {
    running: Option<Running>,
}

impl LssMaster {
    /// An idle master.
    pub fn new() -> Self {
        Self::default()
    }

    /// The running command, if any.
    pub fn running(&self) -> Option<&'static str> {
        self.running.as_ref().map(|r| r.name)
    }

    /// Starts `command`; confirmed commands wait `timeout` for their
    /// answer (fastscan uses its own step time). Unconfirmed commands and
    /// refusals complete in the returned step.
    pub fn start(&mut self, command: LssCommand, timeout: Duration, now: Duration) -> LssStep {
        let name = command.name();
        if let Some(r) = &self.running {
            return LssStep {
                frames: Vec::new(),
                completed: Some(Err(LssError::Busy { running: r.name })),
            };
        }
        let u32_payload = |v: u32| v.to_le_bytes();
        let (frames, wait) = match command {
            LssCommand::SwitchGlobal(mode) => {
                return LssStep {
                    frames: vec![request_frame(cs::SWITCH_GLOBAL, &[mode.to_byte()])],
                    completed: Some(Ok(LssOutcome::Sent)),
                };
            }
            LssCommand::ActivateBitTiming { switch_delay_ms } => {
                return LssStep {
                    frames: vec![request_frame(
                        cs::ACTIVATE_BIT_TIMING,
                        &switch_delay_ms.to_le_bytes(),
                    )],
                    completed: Some(Ok(LssOutcome::Sent)),
                };
            }
            LssCommand::SwitchSelective(id) => (
                [
                    cs::SWITCH_SELECTIVE_VENDOR,
                    cs::SWITCH_SELECTIVE_PRODUCT,
                    cs::SWITCH_SELECTIVE_REVISION,
                    cs::SWITCH_SELECTIVE_SERIAL,
                ]
                .into_iter()
                .zip(id.parts())
                .map(|(c, v)| request_frame(c, &u32_payload(v)))
                .collect(),
                Wait::Answer {
                    cs: cs::SWITCH_SELECTIVE_RESPONSE,
                    min_len: 1,
                },
            ),
            LssCommand::ConfigureNodeId(id) => {
                if !(1..=127).contains(&id) && id != UNCONFIGURED_NODE_ID {
                    return LssStep {
                        frames: Vec::new(),
                        completed: Some(Err(LssError::Invalid {
                            command: name,
                            reason: format!(
                                "node-ID {id} is out of range (1..=127, or 255 for none)"
                            ),
                        })),
                    };
                }
                (
                    vec![request_frame(cs::CONFIGURE_NODE_ID, &[id])],
                    Wait::Answer {
                        cs: cs::CONFIGURE_NODE_ID,
                        min_len: 3,
                    },
                )
            }
            LssCommand::ConfigureBitTiming { table, index } => (
                vec![request_frame(cs::CONFIGURE_BIT_TIMING, &[table, index])],
                Wait::Answer {
                    cs: cs::CONFIGURE_BIT_TIMING,
                    min_len: 3,
                },
            ),
            LssCommand::StoreConfiguration => (
                vec![request_frame(cs::STORE_CONFIGURATION, &[])],
                Wait::Answer {
                    cs: cs::STORE_CONFIGURATION,
                    min_len: 3,
                },
            ),
            LssCommand::Inquire(what) => (
                vec![request_frame(what.cs(), &[])],
                Wait::Answer {
                    cs: what.cs(),
                    min_len: if what == InquireWhat::NodeId { 2 } else { 5 },
                },
            ),
            LssCommand::IdentifyRemote(r) => (
                [
                    (cs::IDENTIFY_VENDOR, r.vendor_id),
                    (cs::IDENTIFY_PRODUCT, r.product_code),
                    (cs::IDENTIFY_REVISION_LOW, r.revision_low),
                    (cs::IDENTIFY_REVISION_HIGH, r.revision_high),
                    (cs::IDENTIFY_SERIAL_LOW, r.serial_low),
                    (cs::IDENTIFY_SERIAL_HIGH, r.serial_high),
                ]
                .into_iter()
                .map(|(c, v)| request_frame(c, &u32_payload(v)))
                .collect(),
                Wait::Presence {
                    cs: cs::IDENTIFY_SLAVE,
                },
            ),
            LssCommand::IdentifyNonConfigured => (
                vec![request_frame(cs::IDENTIFY_NON_CONFIGURED, &[])],
                Wait::Presence {
                    cs: cs::IDENTIFY_NON_CONFIGURED_SLAVE,
                },
            ),
            LssCommand::Fastscan {
                step_time,
                max_nodes,
            } => {
                if step_time.is_zero() || max_nodes == 0 {
                    return LssStep {
                        frames: Vec::new(),
                        completed: Some(Err(LssError::Invalid {
                            command: name,
                            reason: "the step time and the node count must be positive".into(),
                        })),
                    };
                }
                let scan = Fastscan {
                    step_time,
                    max_nodes,
                    found: Vec::new(),
                    id: [0; 4],
                    step: ScanStep::Reset,
                    answered: false,
                    restarts: 0,
                };
                let frames = vec![scan.query()];
                self.running = Some(Running {
                    name,
                    wait: Wait::Fastscan(scan),
                    deadline: now + step_time,
                    timeout: step_time,
                });
                return LssStep {
                    frames,
                    completed: None,
                };
            }
        };
        self.running = Some(Running {
            name,
            wait,
            deadline: now + timeout,
            timeout,
        });
        LssStep {
            frames,
            completed: None,
        }
    }

    /// Drops the running command (the caller gave up). Nothing is sent:
    /// LSS has no abort.
    pub fn cancel(&mut self) {
        self.running = None;
    }

    /// Feeds a received frame (anything; only 0x7E4 answers matter).
    pub fn on_frame(&mut self, frame: &Frame, _now: Duration) -> LssStep {
        let mut step = LssStep::default();
        let Some(a) = decode(frame, LSS_RESPONSE_COB_ID) else {
            return step;
        };
        let Some(r) = self.running.as_mut() else {
            return step;
        };
        let name = r.name;
        match &mut r.wait {
            Wait::Answer { cs: want, min_len } => {
                if a.cs != *want {
                    return step;
                }
                let result = if a.len < *min_len {
                    Err(LssError::Protocol {
                        command: name,
                        reason: format!(
                            "answer 0x{:02X} has {} bytes, {} needed",
                            a.cs, a.len, min_len
                        ),
                    })
                } else {
                    match a.cs {
                        cs::SWITCH_SELECTIVE_RESPONSE => Ok(LssOutcome::Confirmed),
                        cs::CONFIGURE_NODE_ID
                        | cs::CONFIGURE_BIT_TIMING
                        | cs::STORE_CONFIGURATION => match a.payload[0] {
                            0 => Ok(LssOutcome::Confirmed),
                            error => Err(LssError::Refused {
                                command: name,
                                error,
                                spec_error: a.payload[1],
                            }),
                        },
                        cs::INQUIRE_NODE_ID => Ok(LssOutcome::Value(u32::from(a.payload[0]))),
                        _ => Ok(LssOutcome::Value(a.u32())),
                    }
                };
                self.running = None;
                step.completed = Some(result);
            }
            Wait::Presence { cs: want } => {
                if a.cs == *want {
                    self.running = None;
                    step.completed = Some(Ok(LssOutcome::Present(true)));
                }
            }
            Wait::Fastscan(scan) => {
                if a.cs == cs::IDENTIFY_SLAVE {
                    scan.answered = true;
                }
            }
        }
        step
    }

    /// Advances time: timeouts and fastscan steps.
    pub fn on_tick(&mut self, now: Duration) -> LssStep {
        let mut step = LssStep::default();
        let Some(r) = self.running.as_mut() else {
            return step;
        };
        if now < r.deadline {
            return step;
        }
        let name = r.name;
        match &mut r.wait {
            Wait::Answer { .. } => {
                step.completed = Some(Err(LssError::Timeout {
                    command: name,
                    after: r.timeout,
                }));
                self.running = None;
            }
            Wait::Presence { .. } => {
                step.completed = Some(Ok(LssOutcome::Present(false)));
                self.running = None;
            }
            Wait::Fastscan(scan) => match advance(scan) {
                Ok(true) => {
                    step.frames.push(scan.query());
                    r.deadline = now + scan.step_time;
                }
                Ok(false) => {
                    step.completed = Some(Ok(LssOutcome::Found(std::mem::take(&mut scan.found))));
                    self.running = None;
                }
                Err(reason) => {
                    step.completed = Some(Err(LssError::Protocol {
                        command: name,
                        reason,
                    }));
                    self.running = None;
                }
            },
        }
        step
    }

    /// When [`LssMaster::on_tick`] must run next.
    pub fn next_deadline(&self) -> Option<Duration> {
        self.running.as_ref().map(|r| r.deadline)
    }
}

/// Ends a fastscan step: `Ok(true)` with the next query to send, `Ok(false)`
/// when the scan is over.
fn advance(scan: &mut Fastscan) -> Result<bool, String> {
    let answered = std::mem::take(&mut scan.answered);
    match scan.step {
        ScanStep::Reset => {
            if !answered {
                return Ok(false);
            }
            scan.id = [0; 4];
            scan.step = ScanStep::Bit { sub: 0, bit: 31 };
        }
        ScanStep::Bit { sub, bit } => {
            if !answered {
                scan.id[usize::from(sub)] |= 1 << bit;
            }
            scan.step = if bit == 0 {
                ScanStep::Confirm { sub }
            } else {
                ScanStep::Bit { sub, bit: bit - 1 }
            };
        }
        ScanStep::Confirm { sub } => {
            if !answered {
                const PART: [&str; 4] = [
                    "vendor-ID",
                    "product code",
                    "revision number",
                    "serial number",
                ];
                if scan.restarts >= FASTSCAN_RESTARTS {
                    return Err(format!(
                        "no slave confirmed the {} 0x{:08X} found, after {} restarts (a slave left mid-scan, or answers too late for the step time)",
                        PART[usize::from(sub)],
                        scan.id[usize::from(sub)],
                        scan.restarts
                    ));
                }
                scan.restarts += 1;
                scan.step = ScanStep::Reset;
                return Ok(true);
            }
            if sub < 3 {
                scan.step = ScanStep::Bit {
                    sub: sub + 1,
                    bit: 31,
                };
            } else {
                let identity = LssIdentity::from_parts(scan.id);
                if scan.found.contains(&identity) {
                    // A slave that answers until it has a node-ID.
                    return Ok(false);
                }
                scan.found.push(identity);
                if scan.found.len() >= scan.max_nodes {
                    return Ok(false);
                }
                scan.step = ScanStep::Reset;
            }
        }
    }
    Ok(true)
}

#[cfg(test)]
mod tests;
