//! The SDO client: one transfer at a time with one server node.

use std::time::Duration;

use cangate_can::Frame;

use super::block::{
    BlockReceiver, BlockSender, Violation, check_block_size, check_final_size, violation,
};
use super::*;
use crate::ids::{NodeId, ObjectAddress, cob};

/// Default time the client waits for each server frame.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_millis(500);

/// Default quiet time after the client aborted a transfer itself (timeout,
/// protocol violation, cancel): the server may still answer frames it got
/// before the abort, and those answers must not reach the next transfer.
/// See [`SdoClient::ready_at`].
pub const DEFAULT_SETTLE_TIME: Duration = Duration::from_millis(50);

/// A settle period is extended by each frame that arrives during it (a
/// server still sending a sub-block), but never beyond this many settle
/// times after the abort, so that a chattering server cannot hold the
/// channel.
const MAX_SETTLE_FACTOR: u32 = 10;

/// Abort codes that, in answer to a block initiate, make the client retry
/// the same transfer without block mode (when [`BlockOptions::fallback`]):
/// - 0x05040001 (command specifier not valid or unknown): what a server
///   without block support must answer (CiA 301; CANopenNode does);
/// - 0x06010000 (unsupported access to an object): some servers refuse
///   block access per object this way. If the object really is
///   inaccessible, the retry gets the real abort, so the cost is one round
///   trip.
///
/// Anything else (e.g. 0x06020000) is an answer about the object and ends
/// the transfer.
pub const FALLBACK_CODES: [AbortCode; 2] =
    [AbortCode::INVALID_COMMAND, AbortCode::UNSUPPORTED_ACCESS];

/// Settings of a block transfer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BlockOptions {
    /// Segments per block the client accepts when uploading (1..=127).
    /// In a block download the server chooses the block size.
    pub block_size: u8,
    /// Announce CRC support; the CRC is checked when the server supports it too.
    pub crc: bool,
    /// Upload protocol switch threshold (pst): the server may answer with a
    /// plain expedited/segmented upload if the value has at most this many
    /// bytes. 0 disables switching.
    pub switch_threshold: u8,
    /// Retry without block mode if the server refuses block transfer with
    /// one of [`FALLBACK_CODES`].
    pub fallback: bool,
}

impl Default for BlockOptions {
    fn default() -> Self {
        BlockOptions {
            block_size: 127,
            crc: true,
            switch_threshold: 0,
            fallback: true,
        }
    }
}

/// How a transfer is carried.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Mode {
    /// Expedited for downloads of 1..=4 bytes, segmented otherwise; for
    /// uploads the server decides between expedited and segmented.
    #[default]
    Auto,
    /// Block transfer.
    Block(BlockOptions),
}

/// Per-transfer options.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TransferOptions {
    /// Expedited/segmented or block.
    pub mode: Mode,
    /// Time to wait for each server frame; `None` uses the client default.
    pub timeout: Option<Duration>,
    /// Indicate the size in expedited/segmented download initiates (`23`,
    /// `21`). When false, the client sends `22` (expedited, only for exactly
    /// 4 bytes) or `20` (segmented) as some legacy tools do. Block
    /// downloads always indicate the size.
    pub indicate_size: bool,
}

impl Default for TransferOptions {
    fn default() -> Self {
        TransferOptions {
            mode: Mode::Auto,
            timeout: None,
            indicate_size: true,
        }
    }
}

impl TransferOptions {
    /// Block transfer with default [`BlockOptions`].
    pub fn block() -> Self {
        TransferOptions {
            mode: Mode::Block(BlockOptions::default()),
            ..Self::default()
        }
    }

    /// The same options with another timeout.
    pub fn with_timeout(self, timeout: Duration) -> Self {
        TransferOptions {
            timeout: Some(timeout),
            ..self
        }
    }
}

/// The SDO protocol a transfer uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Protocol {
    /// Data inside the initiate frames.
    Expedited,
    /// Confirmed 7-byte segments.
    Segmented,
    /// Blocks of segments with CRC.
    Block,
}

/// Direction of a transfer, seen from the client.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Read from the server.
    Upload,
    /// Write to the server.
    Download,
}

/// Where a running transfer stands, e.g. for a progress bar.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Progress {
    /// The object being transferred.
    pub addr: ObjectAddress,
    /// Upload or download.
    pub direction: Direction,
    /// The protocol in use; `None` while an upload waits for the server to
    /// choose between expedited and segmented.
    pub protocol: Option<Protocol>,
    /// Bytes confirmed so far.
    pub transferred: usize,
    /// Total bytes, if known (always for downloads; for uploads if the
    /// server indicated the size).
    pub total: Option<usize>,
}

/// A successful transfer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TransferOutcome {
    /// The value read. An expedited upload without size indication yields
    /// all 4 bytes, since the server did not say how many are meaningful.
    Uploaded(Vec<u8>),
    /// The value was written.
    Downloaded,
}

/// Why a transfer failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SdoError {
    /// The server sent an abort.
    #[error("the SDO server aborted the transfer of {addr}: {code}")]
    Aborted {
        /// The object.
        addr: ObjectAddress,
        /// The server's reason.
        code: AbortCode,
    },
    /// The server broke the protocol; the client detected it and sent an
    /// abort with `code`.
    #[error(
        "protocol violation by the SDO server during the transfer of {addr}: {detail}; sent abort {code}"
    )]
    Protocol {
        /// The object.
        addr: ObjectAddress,
        /// The abort code the client sent.
        code: AbortCode,
        /// What was wrong.
        detail: String,
    },
    /// The server did not answer in time; the client sent abort 0x05040000.
    #[error(
        "no answer from the SDO server within {timeout:?} during the transfer of {addr}; sent abort 0x05040000"
    )]
    Timeout {
        /// The object.
        addr: ObjectAddress,
        /// The timeout that expired.
        timeout: Duration,
    },
    /// The application cancelled the transfer; the client sent an abort.
    #[error("the transfer of {addr} was cancelled; sent abort {code}")]
    Cancelled {
        /// The object.
        addr: ObjectAddress,
        /// The abort code sent.
        code: AbortCode,
    },
    /// The interface gave up a request frame of the transfer (its transmit
    /// queue stayed full past the backend's transmit timeout, or the
    /// interface went away): no answer can come, so the transfer ends at
    /// once instead of waiting out its timeout. The client sent abort
    /// 0x08000000 in case the server holds a transfer in progress.
    #[error(
        "the interface could not send the SDO request for {addr} (transmit queue full past its timeout, or the interface went away); sent abort 0x08000000"
    )]
    NotSent {
        /// The object.
        addr: ObjectAddress,
    },
}

impl SdoError {
    /// The abort code on the wire, whoever sent it.
    pub fn abort_code(&self) -> AbortCode {
        match self {
            SdoError::Aborted { code, .. }
            | SdoError::Protocol { code, .. }
            | SdoError::Cancelled { code, .. } => *code,
            SdoError::Timeout { .. } => AbortCode::TIMEOUT,
            SdoError::NotSent { .. } => AbortCode::GENERAL_ERROR,
        }
    }
}

/// Why a transfer could not start.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum StartError {
    /// Another transfer is running; SDO allows one at a time per channel.
    #[error("an SDO transfer with this node is already in progress")]
    Busy,
    /// [`BlockOptions::block_size`] outside 1..=127.
    #[error("block size {0} is outside 1..=127")]
    InvalidBlockSize(u8),
    /// More data than the 32-bit size field of SDO can describe.
    #[error("{0} bytes exceed the SDO size limit of 4 GiB - 1")]
    TooLarge(usize),
}

/// What the client wants done after an input.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
#[must_use]
pub struct Step {
    /// Frames to send, in order.
    pub frames: Vec<Frame>,
    /// Set when the transfer has ended; the client is idle again.
    pub completed: Option<Result<TransferOutcome, SdoError>>,
}

/// Client side of the default SDO channel of one node (requests on
/// 0x600 + node, responses on 0x580 + node). The caller queues transfers:
/// one runs at a time.
#[derive(Debug)]
pub struct SdoClient {
    node: NodeId,
    default_timeout: Duration,
    transfer: Option<Transfer>,
    settle_time: Duration,
    /// After a local abort: until when the channel should stay quiet, and
    /// the latest it may be extended to.
    settling: Option<Settling>,
    /// A local abort happened and no response has since been recognised as
    /// the answer to a new initiate: responses that do not answer the
    /// running transfer's initiate are late answers to the aborted one.
    unsettled: bool,
    /// Responses dropped as stale or unsolicited.
    ignored: u64,
}

#[derive(Debug, Clone, Copy)]
struct Settling {
    until: Duration,
    cap: Duration,
}

#[derive(Debug)]
struct Transfer {
    addr: ObjectAddress,
    opts: TransferOptions,
    timeout: Duration,
    deadline: Duration,
    phase: Phase,
    /// The request payloads of the last step, which the server has not
    /// answered yet: the ones [`SdoClient::on_request_unsent`] matches.
    in_flight: Vec<[u8; 8]>,
}

/// What the client waits for.
#[derive(Debug)]
enum Phase {
    DownloadInitiate {
        data: Vec<u8>,
        expedited: bool,
    },
    /// The segment starting at `done` is in flight with `toggle`.
    DownloadSegment {
        data: Vec<u8>,
        done: usize,
        toggle: bool,
    },
    UploadInitiate,
    /// A segment with `toggle` was requested.
    UploadSegment {
        buf: Vec<u8>,
        size: Option<usize>,
        toggle: bool,
    },
    BlockDownloadInitiate {
        data: Vec<u8>,
        crc: bool,
    },
    BlockDownload {
        sender: BlockSender,
        crc: bool,
    },
    BlockDownloadEnd {
        len: usize,
    },
    BlockUploadInitiate {
        opts: BlockOptions,
    },
    BlockUpload {
        receiver: BlockReceiver,
        crc: bool,
    },
}

enum Flow {
    Continue(Vec<[u8; 8]>),
    Done(Vec<[u8; 8]>, TransferOutcome),
}

impl SdoClient {
    /// A client for `node` with [`DEFAULT_TIMEOUT`].
    pub fn new(node: NodeId) -> Self {
        SdoClient {
            node,
            default_timeout: DEFAULT_TIMEOUT,
            transfer: None,
            settle_time: DEFAULT_SETTLE_TIME,
            settling: None,
            unsettled: false,
            ignored: 0,
        }
    }

    /// The same client with another default timeout.
    pub fn with_default_timeout(mut self, timeout: Duration) -> Self {
        self.default_timeout = timeout;
        self
    }

    /// The same client with another settle time (see [`Self::ready_at`]);
    /// zero turns the quiet period off (stale responses are then only
    /// recognised by their shape).
    pub fn with_settle_time(mut self, settle: Duration) -> Self {
        self.settle_time = settle;
        self
    }

    /// When a new transfer should start at the earliest: `Some` for a
    /// while after the client aborted a transfer itself, so that late
    /// answers of the server to the aborted transfer arrive while the
    /// client is idle and are dropped. A transfer started earlier still
    /// works, but then only responses whose shape cannot answer its
    /// initiate (another command specifier or object) are recognised as
    /// stale. `None` when the channel is quiet.
    pub fn ready_at(&self) -> Option<Duration> {
        self.settling.map(|s| s.until)
    }

    /// Responses dropped because they answered an aborted transfer, or
    /// arrived while no transfer ran.
    pub fn ignored_responses(&self) -> u64 {
        self.ignored
    }

    /// Makes the running transfer wait at most `max` for each server frame
    /// from now on, counting from the last frame exchanged (the owner of
    /// the channel needs it for something more urgent). Nothing happens
    /// when idle or when the transfer's timeout is already shorter.
    pub fn limit_timeout(&mut self, max: Duration) {
        if let Some(t) = self.transfer.as_mut()
            && t.timeout > max
        {
            let since = t.deadline.saturating_sub(t.timeout);
            t.timeout = max;
            t.deadline = since + max;
        }
    }

    /// The transfer ended with an abort the client sent (or the server's
    /// abort of a block download with segments in flight): the server may
    /// still answer what it received before the abort.
    fn begin_settling(&mut self, now: Duration) {
        self.unsettled = true;
        if !self.settle_time.is_zero() {
            self.settling = Some(Settling {
                until: now + self.settle_time,
                cap: now + self.settle_time * MAX_SETTLE_FACTOR,
            });
        }
    }

    /// The server node.
    pub fn node(&self) -> NodeId {
        self.node
    }

    /// COB-ID of requests (client → server).
    pub fn request_cob_id(&self) -> u16 {
        cob::SDO_RX + u16::from(self.node.get())
    }

    /// COB-ID of responses (server → client).
    pub fn response_cob_id(&self) -> u16 {
        cob::SDO_TX + u16::from(self.node.get())
    }

    /// True while a transfer runs.
    pub fn is_busy(&self) -> bool {
        self.transfer.is_some()
    }

    /// Starts reading `addr`; returns the frames to send.
    pub fn start_upload(
        &mut self,
        addr: ObjectAddress,
        opts: TransferOptions,
        now: Duration,
    ) -> Result<Vec<Frame>, StartError> {
        self.check_start(&opts)?;
        let (payload, phase) = match opts.mode {
            Mode::Auto => (upload_initiate(addr), Phase::UploadInitiate),
            Mode::Block(b) => {
                let cc = if b.crc { CRC_SUPPORTED } else { 0 };
                let tail = [b.block_size, b.switch_threshold, 0, 0];
                let command = CCS_BLOCK_UPLOAD | cc | BLOCK_INITIATE;
                (
                    with_address(command, addr, tail),
                    Phase::BlockUploadInitiate { opts: b },
                )
            }
        };
        Ok(self.begin(addr, opts, phase, payload, now))
    }

    /// Starts writing `data` to `addr`; returns the frames to send.
    pub fn start_download(
        &mut self,
        addr: ObjectAddress,
        data: Vec<u8>,
        opts: TransferOptions,
        now: Duration,
    ) -> Result<Vec<Frame>, StartError> {
        self.check_start(&opts)?;
        let Ok(len) = u32::try_from(data.len()) else {
            return Err(StartError::TooLarge(data.len()));
        };
        let (payload, phase) = match opts.mode {
            Mode::Auto => download_initiate(addr, data, opts.indicate_size),
            Mode::Block(b) => {
                let cc = if b.crc { CRC_SUPPORTED } else { 0 };
                let command = CCS_BLOCK_DOWNLOAD | cc | BLOCK_SIZE_INDICATED | BLOCK_INITIATE;
                let payload = with_address(command, addr, len.to_le_bytes());
                (payload, Phase::BlockDownloadInitiate { data, crc: b.crc })
            }
        };
        Ok(self.begin(addr, opts, phase, payload, now))
    }

    /// Takes any received frame; frames other than SDO responses from this
    /// node, and frames while idle, are ignored.
    pub fn on_frame(&mut self, frame: &Frame, now: Duration) -> Step {
        let Some(p) = sdo_payload(frame, self.response_cob_id()) else {
            return Step::default();
        };
        let Some(mut t) = self.transfer.take() else {
            self.ignored += 1;
            if let Some(s) = self.settling.as_mut()
                && now < s.until
            {
                s.until = (now + self.settle_time).min(s.cap).max(s.until);
            }
            return Step::default();
        };
        if self.unsettled {
            if !t.answers_initiate(&p) {
                // A late answer to the aborted transfer: not ours.
                self.ignored += 1;
                self.transfer = Some(t);
                return Step::default();
            }
            self.unsettled = false;
        }
        // Inside a block upload, 0x81..=0xFF are last segments: only 0x80
        // (sequence number 0, which segments never use) is an abort there.
        let in_segments =
            matches!(&t.phase, Phase::BlockUpload { receiver, .. } if !receiver.awaiting_end());
        let is_abort = if in_segments {
            p[0] == CS_ABORT
        } else {
            p[0] & CS_MASK == CS_ABORT
        };
        if is_abort {
            let code = AbortCode(u32_at(&p));
            if let Some(payload) = t.fall_back(code) {
                t.deadline = now + t.timeout;
                t.in_flight = vec![payload];
                self.transfer = Some(t);
                return Step {
                    frames: vec![self.frame(payload)],
                    completed: None,
                };
            }
            // A server that aborts a block download mid sub-block still
            // gets the segments already on their way, and a server that is
            // idle again takes them for new requests and answers them:
            // those answers must not reach the next transfer.
            if matches!(t.phase, Phase::BlockDownload { .. }) {
                self.begin_settling(now);
            }
            let error = SdoError::Aborted { addr: t.addr, code };
            return self.step(Vec::new(), Some(Err(error)));
        }
        match t.handle(&p) {
            Ok(Flow::Continue(out)) => {
                t.deadline = now + t.timeout;
                t.in_flight.clone_from(&out);
                self.transfer = Some(t);
                self.step(out, None)
            }
            Ok(Flow::Done(out, outcome)) => self.step(out, Some(Ok(outcome))),
            Err(Violation { code, detail }) => {
                let error = SdoError::Protocol {
                    addr: t.addr,
                    code,
                    detail,
                };
                self.begin_settling(now);
                self.step(vec![abort_payload(t.addr, code)], Some(Err(error)))
            }
        }
    }

    /// Checks the timeout; call at [`Self::next_deadline`] (or any time).
    pub fn on_tick(&mut self, now: Duration) -> Step {
        if self.settling.is_some_and(|s| now >= s.until) {
            self.settling = None;
        }
        match self.transfer.take() {
            Some(t) if now >= t.deadline => {
                let error = SdoError::Timeout {
                    addr: t.addr,
                    timeout: t.timeout,
                };
                let abort = abort_payload(t.addr, AbortCode::TIMEOUT);
                self.begin_settling(now);
                self.step(vec![abort], Some(Err(error)))
            }
            t => {
                self.transfer = t;
                Step::default()
            }
        }
    }

    /// When [`Self::on_tick`] must run next, if a transfer is running.
    pub fn next_deadline(&self) -> Option<Duration> {
        self.transfer.as_ref().map(|t| t.deadline)
    }

    /// Cancels the running transfer, sending an abort with `code`
    /// (e.g. 0x08000000 general error). Does nothing when idle.
    pub fn cancel(&mut self, code: AbortCode, now: Duration) -> Step {
        match self.transfer.take() {
            Some(t) => {
                self.begin_settling(now);
                let error = SdoError::Cancelled { addr: t.addr, code };
                self.step(vec![abort_payload(t.addr, code)], Some(Err(error)))
            }
            None => Step::default(),
        }
    }

    /// The interface gave up the request frame with payload `data` (see
    /// [`SdoError::NotSent`]). Ends the running transfer when `data` is
    /// one of the requests it is waiting to have answered; anything else
    /// (a frame of a transfer that already ended, another channel's) does
    /// nothing.
    pub fn on_request_unsent(&mut self, data: &[u8], now: Duration) -> Step {
        match self.transfer.take() {
            Some(t) if t.in_flight.iter().any(|p| p[..] == *data) => {
                self.begin_settling(now);
                let abort = abort_payload(t.addr, AbortCode::GENERAL_ERROR);
                let error = SdoError::NotSent { addr: t.addr };
                self.step(vec![abort], Some(Err(error)))
            }
            t => {
                self.transfer = t;
                Step::default()
            }
        }
    }

    /// Progress of the running transfer.
    pub fn progress(&self) -> Option<Progress> {
        let t = self.transfer.as_ref()?;
        let (direction, protocol, transferred, total) = match &t.phase {
            Phase::DownloadInitiate { data, expedited } => {
                let p = if *expedited {
                    Protocol::Expedited
                } else {
                    Protocol::Segmented
                };
                (Direction::Download, Some(p), 0, Some(data.len()))
            }
            Phase::DownloadSegment { data, done, .. } => (
                Direction::Download,
                Some(Protocol::Segmented),
                *done,
                Some(data.len()),
            ),
            Phase::BlockDownloadInitiate { data, .. } => (
                Direction::Download,
                Some(Protocol::Block),
                0,
                Some(data.len()),
            ),
            Phase::BlockDownload { sender, .. } => (
                Direction::Download,
                Some(Protocol::Block),
                sender.acked(),
                Some(sender.len()),
            ),
            Phase::BlockDownloadEnd { len } => {
                (Direction::Download, Some(Protocol::Block), *len, Some(*len))
            }
            Phase::UploadInitiate => (Direction::Upload, None, 0, None),
            Phase::UploadSegment { buf, size, .. } => (
                Direction::Upload,
                Some(Protocol::Segmented),
                buf.len(),
                *size,
            ),
            Phase::BlockUploadInitiate { .. } => {
                (Direction::Upload, Some(Protocol::Block), 0, None)
            }
            Phase::BlockUpload { receiver, .. } => (
                Direction::Upload,
                Some(Protocol::Block),
                receiver.received(),
                receiver.size(),
            ),
        };
        Some(Progress {
            addr: t.addr,
            direction,
            protocol,
            transferred,
            total,
        })
    }

    fn check_start(&self, opts: &TransferOptions) -> Result<(), StartError> {
        if self.transfer.is_some() {
            return Err(StartError::Busy);
        }
        if let Mode::Block(b) = opts.mode
            && !(1..=127).contains(&b.block_size)
        {
            return Err(StartError::InvalidBlockSize(b.block_size));
        }
        Ok(())
    }

    fn begin(
        &mut self,
        addr: ObjectAddress,
        opts: TransferOptions,
        phase: Phase,
        payload: [u8; 8],
        now: Duration,
    ) -> Vec<Frame> {
        let timeout = opts.timeout.unwrap_or(self.default_timeout);
        self.settling = None;
        self.transfer = Some(Transfer {
            addr,
            opts,
            timeout,
            deadline: now + timeout,
            phase,
            in_flight: vec![payload],
        });
        vec![self.frame(payload)]
    }

    fn frame(&self, payload: [u8; 8]) -> Frame {
        sdo_frame(self.request_cob_id(), payload)
    }

    fn step(
        &self,
        payloads: Vec<[u8; 8]>,
        completed: Option<Result<TransferOutcome, SdoError>>,
    ) -> Step {
        Step {
            frames: payloads.into_iter().map(|p| self.frame(p)).collect(),
            completed,
        }
    }
}

fn upload_initiate(addr: ObjectAddress) -> [u8; 8] {
    with_address(CCS_INITIATE_UPLOAD, addr, [0; 4])
}

/// The initiate frame of an expedited or segmented download.
fn download_initiate(addr: ObjectAddress, data: Vec<u8>, indicate_size: bool) -> ([u8; 8], Phase) {
    let len = data.len();
    if (1..=4).contains(&len) && (indicate_size || len == 4) {
        let mut tail = [0u8; 4];
        tail[..len].copy_from_slice(&data);
        let size_bits = if indicate_size {
            ((4 - len as u8) << 2) | SIZE_INDICATED
        } else {
            0
        };
        let command = CCS_INITIATE_DOWNLOAD | EXPEDITED | size_bits;
        let phase = Phase::DownloadInitiate {
            data,
            expedited: true,
        };
        (with_address(command, addr, tail), phase)
    } else {
        let (command, tail) = if indicate_size {
            (
                CCS_INITIATE_DOWNLOAD | SIZE_INDICATED,
                (len as u32).to_le_bytes(),
            )
        } else {
            (CCS_INITIATE_DOWNLOAD, [0; 4])
        };
        let phase = Phase::DownloadInitiate {
            data,
            expedited: false,
        };
        (with_address(command, addr, tail), phase)
    }
}

/// Fails unless the command specifier of `command` is `expected`.
fn expect_command(command: u8, expected: u8, what: &str) -> Result<(), Violation> {
    if command & CS_MASK == expected {
        Ok(())
    } else {
        Err(violation(
            AbortCode::INVALID_COMMAND,
            format!("expected {what}, got command byte 0x{command:02X}"),
        ))
    }
}

/// Fails unless a block command has the sub-command `expected` (under `mask`).
fn expect_block(command: u8, scs: u8, mask: u8, sub: u8, what: &str) -> Result<(), Violation> {
    expect_command(command, scs, what)?;
    if command & mask == sub {
        Ok(())
    } else {
        Err(violation(
            AbortCode::INVALID_COMMAND,
            format!("expected {what}, got command byte 0x{command:02X}"),
        ))
    }
}

fn check_toggle(command: u8, toggle: bool) -> Result<(), Violation> {
    if (command & TOGGLE != 0) == toggle {
        Ok(())
    } else {
        Err(violation(
            AbortCode::TOGGLE_BIT_NOT_ALTERNATED,
            format!(
                "segment with toggle {} where {} was due",
                u8::from(!toggle),
                u8::from(toggle)
            ),
        ))
    }
}

impl Transfer {
    /// Whether `p` can be the server's answer to this transfer's initiate:
    /// the right command specifier naming our object, or an abort naming
    /// it. Past the initiate phases everything is taken (the server has
    /// answered this transfer, and answers in order).
    fn answers_initiate(&self, p: &[u8; 8]) -> bool {
        let command = p[0];
        let names_us = address_of(p) == self.addr;
        let cs = command & CS_MASK;
        let initiating = matches!(
            self.phase,
            Phase::UploadInitiate
                | Phase::DownloadInitiate { .. }
                | Phase::BlockDownloadInitiate { .. }
                | Phase::BlockUploadInitiate { .. }
        );
        if initiating && cs == CS_ABORT {
            return names_us;
        }
        match &self.phase {
            Phase::UploadInitiate => cs == SCS_INITIATE_UPLOAD && names_us,
            Phase::DownloadInitiate { .. } => cs == SCS_INITIATE_DOWNLOAD && names_us,
            Phase::BlockDownloadInitiate { .. } => {
                cs == SCS_BLOCK_DOWNLOAD && command & 0x03 == BLOCK_INITIATE && names_us
            }
            Phase::BlockUploadInitiate { .. } => {
                ((cs == SCS_BLOCK_UPLOAD && command & 0x01 == BLOCK_INITIATE)
                    || cs == SCS_INITIATE_UPLOAD)
                    && names_us
            }
            _ => true,
        }
    }

    /// The server's reply must name our object; a mismatch means it is
    /// answering something else. No CiA 301 code fits exactly; 0x06040043
    /// (general parameter incompatibility) says "the parameters disagree".
    fn check_echo(&self, p: &[u8; 8]) -> Result<(), Violation> {
        let echoed = address_of(p);
        if echoed == self.addr {
            Ok(())
        } else {
            Err(violation(
                AbortCode::PARAMETER_INCOMPATIBILITY,
                format!("response names object {echoed} instead of {}", self.addr),
            ))
        }
    }

    /// Restarts without block mode if the abort is a refusal of block
    /// transfer (see [`FALLBACK_CODES`]); returns the new initiate frame.
    fn fall_back(&mut self, code: AbortCode) -> Option<[u8; 8]> {
        let Mode::Block(b) = self.opts.mode else {
            return None;
        };
        if !b.fallback || !FALLBACK_CODES.contains(&code) {
            return None;
        }
        match std::mem::replace(&mut self.phase, Phase::UploadInitiate) {
            Phase::BlockDownloadInitiate { data, .. } => {
                let (payload, phase) = download_initiate(self.addr, data, self.opts.indicate_size);
                self.phase = phase;
                Some(payload)
            }
            Phase::BlockUploadInitiate { .. } => Some(upload_initiate(self.addr)),
            other => {
                self.phase = other;
                None
            }
        }
    }

    fn handle(&mut self, p: &[u8; 8]) -> Result<Flow, Violation> {
        let command = p[0];
        // Every arm that continues stores the next phase.
        match std::mem::replace(&mut self.phase, Phase::UploadInitiate) {
            Phase::DownloadInitiate { data, expedited } => {
                expect_command(
                    command,
                    SCS_INITIATE_DOWNLOAD,
                    "a download initiate response",
                )?;
                self.check_echo(p)?;
                // Bytes 4..8 are reserved. Some drives echo the written
                // value there (`60 34 20 00 E8 03 00 00`): not checked.
                if expedited {
                    return Ok(Flow::Done(Vec::new(), TransferOutcome::Downloaded));
                }
                Ok(self.send_segment(data, 0, false))
            }
            Phase::DownloadSegment { data, done, toggle } => {
                expect_command(command, SCS_DOWNLOAD_SEGMENT, "a download segment response")?;
                check_toggle(command, toggle)?;
                let done = (done + SEGMENT_LEN).min(data.len());
                if done == data.len() {
                    return Ok(Flow::Done(Vec::new(), TransferOutcome::Downloaded));
                }
                Ok(self.send_segment(data, done, !toggle))
            }
            Phase::UploadInitiate => self.upload_initiate_response(p),
            Phase::UploadSegment {
                mut buf,
                size,
                toggle,
            } => {
                expect_command(command, SCS_UPLOAD_SEGMENT, "an upload segment")?;
                check_toggle(command, toggle)?;
                let unused = usize::from((command >> 1) & 7);
                buf.extend_from_slice(&p[1..8 - unused]);
                if let Some(s) = size
                    && buf.len() > s
                {
                    check_final_size(buf.len(), size)?;
                }
                if command & 1 != 0 {
                    check_final_size(buf.len(), size)?;
                    return Ok(Flow::Done(Vec::new(), TransferOutcome::Uploaded(buf)));
                }
                self.phase = Phase::UploadSegment {
                    buf,
                    size,
                    toggle: !toggle,
                };
                let request = CCS_UPLOAD_SEGMENT | if toggle { 0 } else { TOGGLE };
                Ok(Flow::Continue(vec![command_only(request)]))
            }
            Phase::BlockDownloadInitiate { data, crc } => {
                let what = "a block download initiate response";
                expect_block(command, SCS_BLOCK_DOWNLOAD, 0x03, BLOCK_INITIATE, what)?;
                self.check_echo(p)?;
                let blksize = check_block_size(p[4])?;
                let crc = crc && command & CRC_SUPPORTED != 0;
                let mut sender = BlockSender::new(data, blksize);
                let frames = sender.next_block();
                self.phase = Phase::BlockDownload { sender, crc };
                Ok(Flow::Continue(frames))
            }
            Phase::BlockDownload { mut sender, crc } => {
                expect_block(command, SCS_BLOCK_DOWNLOAD, 0x03, BLOCK_ACK, "a block ack")?;
                if sender.on_ack(p[1], p[2])? {
                    let (unused_bits, crc_value) = sender.end_fields();
                    let crc_value = if crc { crc_value } else { 0 };
                    let [lo, hi] = crc_value.to_le_bytes();
                    let end = [
                        CCS_BLOCK_DOWNLOAD | unused_bits | BLOCK_END,
                        lo,
                        hi,
                        0,
                        0,
                        0,
                        0,
                        0,
                    ];
                    self.phase = Phase::BlockDownloadEnd { len: sender.len() };
                    Ok(Flow::Continue(vec![end]))
                } else {
                    let frames = sender.next_block();
                    self.phase = Phase::BlockDownload { sender, crc };
                    Ok(Flow::Continue(frames))
                }
            }
            Phase::BlockDownloadEnd { .. } => {
                let what = "a block download end response";
                expect_block(command, SCS_BLOCK_DOWNLOAD, 0x03, BLOCK_END, what)?;
                Ok(Flow::Done(Vec::new(), TransferOutcome::Downloaded))
            }
            Phase::BlockUploadInitiate { opts } => {
                // Protocol switch: the value is small enough for the server to
                // answer as a plain upload. Some servers (python-canopen's
                // LocalNode, for one) also answer a block upload initiate
                // that offered no switch with a plain upload response; with
                // `fallback` on we accept that too, as the server refusing
                // block transfer, rather than failing the read.
                if command & CS_MASK == SCS_INITIATE_UPLOAD
                    && (opts.switch_threshold > 0 || opts.fallback)
                {
                    return self.upload_initiate_response(p);
                }
                let what = "a block upload initiate response";
                expect_block(command, SCS_BLOCK_UPLOAD, 0x01, BLOCK_INITIATE, what)?;
                self.check_echo(p)?;
                let size = (command & BLOCK_SIZE_INDICATED != 0).then(|| u32_at(p) as usize);
                let crc = opts.crc && command & CRC_SUPPORTED != 0;
                let receiver = BlockReceiver::new(size, opts.block_size);
                self.phase = Phase::BlockUpload { receiver, crc };
                Ok(Flow::Continue(vec![command_only(
                    CCS_BLOCK_UPLOAD | BLOCK_START,
                )]))
            }
            Phase::BlockUpload { mut receiver, crc } => {
                if receiver.awaiting_end() {
                    let what = "a block upload end";
                    expect_block(command, SCS_BLOCK_UPLOAD, 0x01, BLOCK_END, what)?;
                    let crc_value = u16::from_le_bytes([p[1], p[2]]);
                    let data = receiver.finish((command >> 2) & 7, crc.then_some(crc_value))?;
                    let end = command_only(CCS_BLOCK_UPLOAD | BLOCK_END);
                    return Ok(Flow::Done(vec![end], TransferOutcome::Uploaded(data)));
                }
                let ack = receiver.on_segment(p)?;
                let blksize = receiver.blksize();
                self.phase = Phase::BlockUpload { receiver, crc };
                Ok(Flow::Continue(match ack {
                    Some(ackseq) => {
                        let command = CCS_BLOCK_UPLOAD | BLOCK_ACK;
                        vec![[command, ackseq, blksize, 0, 0, 0, 0, 0]]
                    }
                    None => Vec::new(),
                }))
            }
        }
    }

    /// Sends the download segment starting at `done`.
    fn send_segment(&mut self, data: Vec<u8>, done: usize, toggle: bool) -> Flow {
        let chunk = &data[done..(done + SEGMENT_LEN).min(data.len())];
        let last = done + SEGMENT_LEN >= data.len();
        let mut p = [0u8; 8];
        p[0] = CCS_DOWNLOAD_SEGMENT
            | if toggle { TOGGLE } else { 0 }
            | (((SEGMENT_LEN - chunk.len()) as u8) << 1)
            | u8::from(last);
        p[1..=chunk.len()].copy_from_slice(chunk);
        self.phase = Phase::DownloadSegment { data, done, toggle };
        Flow::Continue(vec![p])
    }

    fn upload_initiate_response(&mut self, p: &[u8; 8]) -> Result<Flow, Violation> {
        let command = p[0];
        expect_command(command, SCS_INITIATE_UPLOAD, "an upload initiate response")?;
        self.check_echo(p)?;
        let size_indicated = command & SIZE_INDICATED != 0;
        if command & EXPEDITED != 0 {
            let len = if size_indicated {
                4 - usize::from((command >> 2) & 3)
            } else {
                4
            };
            let data = p[4..4 + len].to_vec();
            return Ok(Flow::Done(Vec::new(), TransferOutcome::Uploaded(data)));
        }
        let size = size_indicated.then(|| u32_at(p) as usize);
        self.phase = Phase::UploadSegment {
            buf: Vec::with_capacity(size.unwrap_or(0).min(1 << 16)),
            size,
            toggle: false,
        };
        Ok(Flow::Continue(vec![command_only(CCS_UPLOAD_SEGMENT)]))
    }
}
