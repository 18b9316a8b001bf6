//! The SDO server of a (simulated) device: serves expedited, segmented and
//! block transfers against an [`ObjectStore`].

use std::time::Duration;

use cangate_can::Frame;

use super::block::{BlockReceiver, BlockSender, Violation, check_block_size, check_final_size};
use super::*;
use crate::ids::{NodeId, ObjectAddress, cob};

/// The object dictionary as the SDO server sees it: whole values in, whole
/// values out. Errors are the abort codes sent to the client.
pub trait ObjectStore {
    /// Reads the value of `addr` (at the start of an upload).
    fn read(&mut self, addr: ObjectAddress) -> Result<Vec<u8>, AbortCode>;
    /// Writes the value of `addr` (once a download has fully arrived).
    fn write(&mut self, addr: ObjectAddress, data: &[u8]) -> Result<(), AbortCode>;
}

/// Server capabilities.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ServerOptions {
    /// Serve block transfers; when false, block initiates get abort
    /// 0x05040001 (command specifier not valid), as CiA 301 servers without
    /// block support answer.
    pub block_transfer: bool,
    /// Segments per block offered for block downloads (clamped to 1..=127).
    pub block_size: u8,
    /// Announce CRC support in block transfers.
    pub crc: bool,
    /// Time to wait for the client's next frame inside a transfer.
    pub timeout: Duration,
}

impl Default for ServerOptions {
    fn default() -> Self {
        ServerOptions {
            block_transfer: true,
            block_size: 127,
            crc: true,
            timeout: Duration::from_secs(1),
        }
    }
}

/// Server side of the default SDO channel of one node (requests on
/// 0x600 + node, responses on 0x580 + node).
#[derive(Debug)]
pub struct SdoServer {
    node: NodeId,
    options: ServerOptions,
    session: Option<Session>,
}

#[derive(Debug)]
struct Session {
    addr: ObjectAddress,
    deadline: Duration,
    phase: ServerPhase,
}

/// What the server waits for.
#[derive(Debug)]
enum ServerPhase {
    /// A download segment with `toggle`.
    Download {
        buf: Vec<u8>,
        size: Option<usize>,
        toggle: bool,
    },
    /// An upload segment request with `toggle`; `offset` bytes were sent.
    Upload {
        data: Vec<u8>,
        offset: usize,
        toggle: bool,
    },
    /// Block download segments, then the end frame.
    BlockDownload { receiver: BlockReceiver, crc: bool },
    /// The client's "start upload".
    BlockUploadStart { sender: BlockSender, crc: bool },
    /// A block ack.
    BlockUpload { sender: BlockSender, crc: bool },
    /// The client's end response.
    BlockUploadEnd,
}

/// Result of handling one request.
enum Reply {
    /// Keep the session in `phase` and send the frames.
    Continue(ServerPhase, Vec<[u8; 8]>),
    /// The transfer is over; send the frames.
    Finished(Vec<[u8; 8]>),
    /// Abort the transfer with this code.
    Abort(AbortCode),
}

impl From<Violation> for Reply {
    fn from(v: Violation) -> Self {
        Reply::Abort(v.code)
    }
}

impl SdoServer {
    /// A server for `node`.
    pub fn new(node: NodeId, mut options: ServerOptions) -> Self {
        options.block_size = options.block_size.clamp(1, 127);
        SdoServer {
            node,
            options,
            session: None,
        }
    }

    /// The options in force.
    pub fn options(&self) -> &ServerOptions {
        &self.options
    }

    /// COB-ID of requests (client → server).
    pub fn request_cob_id(&self) -> u16 {
        cob::SDO_RX + u16::from(self.node.get())
    }

    /// COB-ID of responses (server → client).
    pub fn response_cob_id(&self) -> u16 {
        cob::SDO_TX + u16::from(self.node.get())
    }

    /// The object of the transfer in progress, if any.
    pub fn active_transfer(&self) -> Option<ObjectAddress> {
        self.session.as_ref().map(|s| s.addr)
    }

    /// Takes any received frame and returns the frames to send. Frames
    /// other than SDO requests to this node are ignored.
    pub fn on_frame<S: ObjectStore + ?Sized>(
        &mut self,
        frame: &Frame,
        now: Duration,
        store: &mut S,
    ) -> Vec<Frame> {
        let Some(p) = sdo_payload(frame, self.request_cob_id()) else {
            return Vec::new();
        };
        let session = self.session.take();
        let session_addr = session
            .as_ref()
            .map_or(ObjectAddress::new(0, 0), |s| s.addr);
        let (addr, reply) = match session.map(|s| s.phase) {
            // Inside a block download everything but an abort is a segment
            // (its byte 0 is a sequence number, not a command).
            Some(ServerPhase::BlockDownload { mut receiver, crc })
                if !receiver.awaiting_end() && p[0] != CS_ABORT =>
            {
                let reply = match receiver.on_segment(&p) {
                    Ok(ack) => {
                        let frames = ack.map_or_else(Vec::new, |ackseq| {
                            let command = SCS_BLOCK_DOWNLOAD | BLOCK_ACK;
                            vec![[command, ackseq, receiver.blksize(), 0, 0, 0, 0, 0]]
                        });
                        Reply::Continue(ServerPhase::BlockDownload { receiver, crc }, frames)
                    }
                    Err(v) => v.into(),
                };
                (session_addr, reply)
            }
            phase => self.dispatch(&p, phase, session_addr, store),
        };
        let payloads = match reply {
            Reply::Continue(phase, frames) => {
                self.session = Some(Session {
                    addr,
                    deadline: now + self.options.timeout,
                    phase,
                });
                frames
            }
            Reply::Finished(frames) => frames,
            Reply::Abort(code) => vec![abort_payload(addr, code)],
        };
        payloads.into_iter().map(|p| self.frame(p)).collect()
    }

    /// Aborts a transfer whose client went silent (abort 0x05040000).
    pub fn on_tick(&mut self, now: Duration) -> Vec<Frame> {
        match self.session.take() {
            Some(s) if now >= s.deadline => {
                vec![self.frame(abort_payload(s.addr, AbortCode::TIMEOUT))]
            }
            s => {
                self.session = s;
                Vec::new()
            }
        }
    }

    /// When [`Self::on_tick`] must run next, if a transfer is running.
    pub fn next_deadline(&self) -> Option<Duration> {
        self.session.as_ref().map(|s| s.deadline)
    }

    fn frame(&self, payload: [u8; 8]) -> Frame {
        sdo_frame(self.response_cob_id(), payload)
    }

    /// Handles a command frame; returns the address for the reply.
    fn dispatch<S: ObjectStore + ?Sized>(
        &self,
        p: &[u8; 8],
        phase: Option<ServerPhase>,
        session_addr: ObjectAddress,
        store: &mut S,
    ) -> (ObjectAddress, Reply) {
        let command = p[0];
        let addr = address_of(p);
        // An initiate starts a new transfer whatever was going on.
        match (command & CS_MASK, phase) {
            // The client aborted: end silently.
            (CS_ABORT, _) => (session_addr, Reply::Finished(Vec::new())),
            (CCS_INITIATE_DOWNLOAD, _) => (addr, initiate_download(addr, p, store)),
            (CCS_INITIATE_UPLOAD, _) => (addr, initiate_upload(addr, store)),
            (CCS_BLOCK_DOWNLOAD, _) if command & 1 == BLOCK_INITIATE => {
                (addr, self.initiate_block_download(addr, p))
            }
            (CCS_BLOCK_UPLOAD, _) if command & 3 == BLOCK_INITIATE => {
                (addr, self.initiate_block_upload(addr, p, store))
            }
            (CCS_DOWNLOAD_SEGMENT, Some(ServerPhase::Download { buf, size, toggle })) => (
                session_addr,
                download_segment(session_addr, p, buf, size, toggle, store),
            ),
            (
                CCS_UPLOAD_SEGMENT,
                Some(ServerPhase::Upload {
                    data,
                    offset,
                    toggle,
                }),
            ) => (session_addr, upload_segment(command, data, offset, toggle)),
            (CCS_BLOCK_DOWNLOAD, Some(ServerPhase::BlockDownload { receiver, crc })) => {
                let reply = block_download_end(session_addr, p, receiver, crc, store)
                    .unwrap_or_else(Reply::from);
                (session_addr, reply)
            }
            (CCS_BLOCK_UPLOAD, Some(ServerPhase::BlockUploadStart { mut sender, crc }))
                if command & 3 == BLOCK_START =>
            {
                let frames = sender.next_block();
                (
                    session_addr,
                    Reply::Continue(ServerPhase::BlockUpload { sender, crc }, frames),
                )
            }
            (CCS_BLOCK_UPLOAD, Some(ServerPhase::BlockUpload { sender, crc }))
                if command & 3 == BLOCK_ACK =>
            {
                (
                    session_addr,
                    block_upload_ack(p, sender, crc).unwrap_or_else(Reply::from),
                )
            }
            (CCS_BLOCK_UPLOAD, Some(ServerPhase::BlockUploadEnd)) if command & 3 == BLOCK_END => {
                (session_addr, Reply::Finished(Vec::new()))
            }
            _ => (session_addr, Reply::Abort(AbortCode::INVALID_COMMAND)),
        }
    }

    fn initiate_block_download(&self, addr: ObjectAddress, p: &[u8; 8]) -> Reply {
        if !self.options.block_transfer {
            return Reply::Abort(AbortCode::INVALID_COMMAND);
        }
        let size = (p[0] & BLOCK_SIZE_INDICATED != 0).then(|| u32_at(p) as usize);
        let sc = if self.options.crc { CRC_SUPPORTED } else { 0 };
        let crc = self.options.crc && p[0] & CRC_SUPPORTED != 0;
        let blksize = self.options.block_size;
        let command = SCS_BLOCK_DOWNLOAD | sc | BLOCK_INITIATE;
        let response = with_address(command, addr, [blksize, 0, 0, 0]);
        let receiver = BlockReceiver::new(size, blksize);
        Reply::Continue(ServerPhase::BlockDownload { receiver, crc }, vec![response])
    }

    fn initiate_block_upload<S: ObjectStore + ?Sized>(
        &self,
        addr: ObjectAddress,
        p: &[u8; 8],
        store: &mut S,
    ) -> Reply {
        if !self.options.block_transfer {
            return Reply::Abort(AbortCode::INVALID_COMMAND);
        }
        let blksize = match check_block_size(p[4]) {
            Ok(b) => b,
            Err(v) => return v.into(),
        };
        let switch_threshold = usize::from(p[5]);
        let data = match store.read(addr) {
            Ok(d) => d,
            Err(code) => return Reply::Abort(code),
        };
        if switch_threshold > 0 && data.len() <= switch_threshold {
            // Protocol switch: small enough for a plain upload.
            return upload_response(addr, data);
        }
        let Ok(len) = u32::try_from(data.len()) else {
            return Reply::Abort(AbortCode::OUT_OF_MEMORY);
        };
        let sc = if self.options.crc { CRC_SUPPORTED } else { 0 };
        let crc = self.options.crc && p[0] & CRC_SUPPORTED != 0;
        let command = SCS_BLOCK_UPLOAD | sc | BLOCK_SIZE_INDICATED | BLOCK_INITIATE;
        let response = with_address(command, addr, len.to_le_bytes());
        let sender = BlockSender::new(data, blksize);
        Reply::Continue(
            ServerPhase::BlockUploadStart { sender, crc },
            vec![response],
        )
    }
}

fn initiate_download<S: ObjectStore + ?Sized>(
    addr: ObjectAddress,
    p: &[u8; 8],
    store: &mut S,
) -> Reply {
    let command = p[0];
    let size_indicated = command & SIZE_INDICATED != 0;
    let response = with_address(SCS_INITIATE_DOWNLOAD, addr, [0; 4]);
    if command & EXPEDITED != 0 {
        // Without size indication all 4 bytes are the value.
        let len = if size_indicated {
            4 - usize::from((command >> 2) & 3)
        } else {
            4
        };
        return match store.write(addr, &p[4..4 + len]) {
            Ok(()) => Reply::Finished(vec![response]),
            Err(code) => Reply::Abort(code),
        };
    }
    let size = size_indicated.then(|| u32_at(p) as usize);
    let phase = ServerPhase::Download {
        buf: Vec::with_capacity(size.unwrap_or(0).min(1 << 16)),
        size,
        toggle: false,
    };
    Reply::Continue(phase, vec![response])
}

fn download_segment<S: ObjectStore + ?Sized>(
    addr: ObjectAddress,
    p: &[u8; 8],
    mut buf: Vec<u8>,
    size: Option<usize>,
    toggle: bool,
    store: &mut S,
) -> Reply {
    let command = p[0];
    if (command & TOGGLE != 0) != toggle {
        return Reply::Abort(AbortCode::TOGGLE_BIT_NOT_ALTERNATED);
    }
    let unused = usize::from((command >> 1) & 7);
    buf.extend_from_slice(&p[1..8 - unused]);
    if let Some(s) = size
        && buf.len() > s
    {
        return Reply::Abort(AbortCode::LENGTH_TOO_HIGH);
    }
    let response = command_only(SCS_DOWNLOAD_SEGMENT | (command & TOGGLE));
    if command & 1 == 0 {
        let phase = ServerPhase::Download {
            buf,
            size,
            toggle: !toggle,
        };
        return Reply::Continue(phase, vec![response]);
    }
    if let Err(v) = check_final_size(buf.len(), size) {
        return v.into();
    }
    match store.write(addr, &buf) {
        Ok(()) => Reply::Finished(vec![response]),
        Err(code) => Reply::Abort(code),
    }
}

fn initiate_upload<S: ObjectStore + ?Sized>(addr: ObjectAddress, store: &mut S) -> Reply {
    match store.read(addr) {
        Ok(data) => upload_response(addr, data),
        Err(code) => Reply::Abort(code),
    }
}

/// Expedited for 1..=4 bytes, else the start of a segmented upload (an empty
/// value is a segmented upload of size 0).
fn upload_response(addr: ObjectAddress, data: Vec<u8>) -> Reply {
    let len = data.len();
    if (1..=4).contains(&len) {
        let mut tail = [0u8; 4];
        tail[..len].copy_from_slice(&data);
        let command = SCS_INITIATE_UPLOAD | (((4 - len) as u8) << 2) | EXPEDITED | SIZE_INDICATED;
        return Reply::Finished(vec![with_address(command, addr, tail)]);
    }
    let Ok(size) = u32::try_from(len) else {
        return Reply::Abort(AbortCode::OUT_OF_MEMORY);
    };
    let response = with_address(
        SCS_INITIATE_UPLOAD | SIZE_INDICATED,
        addr,
        size.to_le_bytes(),
    );
    let phase = ServerPhase::Upload {
        data,
        offset: 0,
        toggle: false,
    };
    Reply::Continue(phase, vec![response])
}

fn upload_segment(command: u8, data: Vec<u8>, offset: usize, toggle: bool) -> Reply {
    if (command & TOGGLE != 0) != toggle {
        return Reply::Abort(AbortCode::TOGGLE_BIT_NOT_ALTERNATED);
    }
    let end = (offset + SEGMENT_LEN).min(data.len());
    let chunk = &data[offset..end];
    let last = end == data.len();
    let mut p = [0u8; 8];
    p[0] = SCS_UPLOAD_SEGMENT
        | (command & TOGGLE)
        | (((SEGMENT_LEN - chunk.len()) as u8) << 1)
        | u8::from(last);
    p[1..=chunk.len()].copy_from_slice(chunk);
    if last {
        return Reply::Finished(vec![p]);
    }
    let phase = ServerPhase::Upload {
        data,
        offset: end,
        toggle: !toggle,
    };
    Reply::Continue(phase, vec![p])
}

fn block_download_end<S: ObjectStore + ?Sized>(
    addr: ObjectAddress,
    p: &[u8; 8],
    receiver: BlockReceiver,
    crc: bool,
    store: &mut S,
) -> Result<Reply, Violation> {
    if !receiver.awaiting_end() || p[0] & 1 != BLOCK_END {
        return Ok(Reply::Abort(AbortCode::INVALID_COMMAND));
    }
    let crc_value = u16::from_le_bytes([p[1], p[2]]);
    let data = receiver.finish((p[0] >> 2) & 7, crc.then_some(crc_value))?;
    Ok(match store.write(addr, &data) {
        Ok(()) => Reply::Finished(vec![command_only(SCS_BLOCK_DOWNLOAD | BLOCK_END)]),
        Err(code) => Reply::Abort(code),
    })
}

fn block_upload_ack(p: &[u8; 8], mut sender: BlockSender, crc: bool) -> Result<Reply, Violation> {
    if sender.on_ack(p[1], p[2])? {
        let (unused_bits, crc_value) = sender.end_fields();
        let [lo, hi] = if crc { crc_value } else { 0 }.to_le_bytes();
        let end = [
            SCS_BLOCK_UPLOAD | unused_bits | BLOCK_END,
            lo,
            hi,
            0,
            0,
            0,
            0,
            0,
        ];
        return Ok(Reply::Continue(ServerPhase::BlockUploadEnd, vec![end]));
    }
    let frames = sender.next_block();
    Ok(Reply::Continue(
        ServerPhase::BlockUpload { sender, crc },
        frames,
    ))
}
