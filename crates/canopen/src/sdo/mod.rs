//! SDO (service data object, CiA 301 §7.2.4): confirmed read ("upload") and
//! write ("download") of object dictionary entries, as sans-IO state
//! machines: [`SdoClient`] for a tool talking to one node and [`SdoServer`]
//! for a simulated device serving an [`ObjectStore`].
//!
//! Every SDO frame has 8 bytes; byte 0 is the command specifier (ccs from
//! the client on 0x600+node, scs from the server on 0x580+node). Initiate
//! frames carry the object address in bytes 1..4 (index little-endian,
//! sub-index) and the server echoes it.
//!
//! | protocol | shape |
//! |---|---|
//! | expedited | 1..=4 bytes inside the initiate frame (`2x`/`4x`); one round trip |
//! | segmented | initiate (`21`/`41`, size in bytes 4..8), then 7-byte segments, each confirmed, with a toggle bit alternating from 0 |
//! | block | initiate with block size and CRC capability, sub-blocks of up to 127 segments numbered 1..=blksize confirmed by one ack (`ackseq` = last in-order segment), then an end frame with the unused byte count of the last segment and a CRC-16 |
//! | abort | `80`, address, abort code little-endian; either side, any time |
//!
//! Conventions shared by client and server:
//! - Zero bytes cannot be expedited (the `n` field only expresses 1..=4 bytes
//!   with size indicated), so an empty value goes segmented: initiate with
//!   size 0, then one last segment carrying no data (`0F`: n=7, c=1).
//! - Frames shorter than 8 bytes are zero-padded rather than rejected: some
//!   devices send unpadded expedited responses. Empty, remote, CAN FD and
//!   extended-id frames are not SDO frames and are ignored.
//! - An indicated size is checked against the data actually transferred;
//!   a difference is aborted with 0x06070012 (more) or 0x06070013 (less).
//! - CRC-16 ([`crc16`]) is used in block transfers only when both sides
//!   announce support.
//! - SDO frames carry no transaction number, so after the client aborts a
//!   transfer itself (timeout, protocol violation, cancel) the server may
//!   still answer requests it received before the abort. Such late answers
//!   must not be taken as the next transfer's: the client stays quiet for a
//!   settle time ([`SdoClient::ready_at`], extended while late frames keep
//!   coming), and until a response answers the next transfer's initiate
//!   (right command specifier and object), responses that cannot are
//!   dropped and counted ([`SdoClient::ignored_responses`]). A late answer
//!   of the very same shape arriving after the settle time cannot be told
//!   apart by any SDO client. The same holds after the server aborts a
//!   block download: the rest of the sub-block is already on its way, and
//!   a server idle again answers those segments as if they were requests
//!   (a segment's sequence number reads as a command specifier).

mod abort;
mod block;
mod client;
mod crc;
mod server;
#[cfg(test)]
mod tests;

pub use abort::AbortCode;
pub use client::{
    BlockOptions, DEFAULT_SETTLE_TIME, DEFAULT_TIMEOUT, Direction, FALLBACK_CODES, Mode, Progress,
    Protocol, SdoClient, SdoError, StartError, Step, TransferOptions, TransferOutcome,
};
pub use crc::{crc16, crc16_update};
pub use server::{ObjectStore, SdoServer, ServerOptions};

use crate::ids::ObjectAddress;
use cangate_can::{CanId, Frame};

/// Data bytes per segment (segmented and block transfers).
const SEGMENT_LEN: usize = 7;
/// Mask of the command specifier (bits 7..5 of byte 0).
const CS_MASK: u8 = 0xE0;

// Client command specifiers (ccs << 5).
const CCS_DOWNLOAD_SEGMENT: u8 = 0x00;
const CCS_INITIATE_DOWNLOAD: u8 = 0x20;
const CCS_INITIATE_UPLOAD: u8 = 0x40;
const CCS_UPLOAD_SEGMENT: u8 = 0x60;
const CCS_BLOCK_UPLOAD: u8 = 0xA0;
const CCS_BLOCK_DOWNLOAD: u8 = 0xC0;
// Server command specifiers (scs << 5).
const SCS_UPLOAD_SEGMENT: u8 = 0x00;
const SCS_DOWNLOAD_SEGMENT: u8 = 0x20;
const SCS_INITIATE_UPLOAD: u8 = 0x40;
const SCS_INITIATE_DOWNLOAD: u8 = 0x60;
const SCS_BLOCK_DOWNLOAD: u8 = 0xA0;
const SCS_BLOCK_UPLOAD: u8 = 0xC0;
/// Abort transfer, both directions.
const CS_ABORT: u8 = 0x80;

// Sub-commands of block transfers (cs/ss in the low bits of byte 0).
const BLOCK_INITIATE: u8 = 0;
const BLOCK_END: u8 = 1;
const BLOCK_ACK: u8 = 2;
const BLOCK_START: u8 = 3;

/// Toggle bit of segmented transfers.
const TOGGLE: u8 = 0x10;
/// Expedited flag (e) of initiate frames.
const EXPEDITED: u8 = 0x02;
/// Size-indicated flag (s) of initiate frames.
const SIZE_INDICATED: u8 = 0x01;
/// Size-indicated flag (s) of block initiate frames.
const BLOCK_SIZE_INDICATED: u8 = 0x02;
/// CRC support flag (cc/sc) of block initiate frames.
const CRC_SUPPORTED: u8 = 0x04;
/// "Last segment" flag (c) of a block segment; the rest is the sequence number.
const LAST_SEGMENT: u8 = 0x80;

/// The 8 data bytes of a frame on SDO COB-ID `cob_id`, zero-padded, or
/// `None` if the frame is not an SDO frame for that COB-ID.
fn sdo_payload(frame: &Frame, cob_id: u16) -> Option<[u8; 8]> {
    let data = frame.data();
    if frame.id() != CanId::Standard(cob_id)
        || frame.is_remote()
        || frame.is_error()
        || frame.is_fd()
        || data.is_empty()
    {
        return None;
    }
    let mut p = [0u8; 8];
    let n = data.len().min(8);
    p[..n].copy_from_slice(&data[..n]);
    Some(p)
}

/// An SDO frame. COB-IDs here are at most 0x600 + 127, which always fits in
/// 11 bits, and 8 bytes always fit a classic frame, so this cannot fail.
fn sdo_frame(cob_id: u16, payload: [u8; 8]) -> Frame {
    Frame::new(CanId::Standard(cob_id & 0x7FF), &payload).expect("8 bytes on an 11-bit id")
}

/// The object address in bytes 1..4 of an initiate or abort frame.
fn address_of(p: &[u8; 8]) -> ObjectAddress {
    ObjectAddress::new(u16::from_le_bytes([p[1], p[2]]), p[3])
}

/// An initiate-style payload: command, address, four data bytes.
fn with_address(command: u8, addr: ObjectAddress, tail: [u8; 4]) -> [u8; 8] {
    let [lo, hi] = addr.index.to_le_bytes();
    [
        command, lo, hi, addr.sub, tail[0], tail[1], tail[2], tail[3],
    ]
}

/// An abort frame payload.
fn abort_payload(addr: ObjectAddress, code: AbortCode) -> [u8; 8] {
    with_address(CS_ABORT, addr, code.get().to_le_bytes())
}

/// A command with all other bytes zero.
fn command_only(command: u8) -> [u8; 8] {
    [command, 0, 0, 0, 0, 0, 0, 0]
}

/// Bytes 4..8 as a little-endian u32 (size or abort code).
fn u32_at(p: &[u8; 8]) -> u32 {
    u32::from_le_bytes([p[4], p[5], p[6], p[7]])
}
