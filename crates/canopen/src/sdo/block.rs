//! The two halves of a block transfer, shared by client and server: the
//! sender (client download, server upload) and the receiver (client upload,
//! server download).

use super::{AbortCode, LAST_SEGMENT, SEGMENT_LEN, crc16};

/// A protocol violation found locally: the abort code to send and why.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct Violation {
    pub code: AbortCode,
    pub detail: String,
}

pub(super) fn violation(code: AbortCode, detail: impl Into<String>) -> Violation {
    Violation {
        code,
        detail: detail.into(),
    }
}

/// Valid block sizes (segments per block).
pub(super) fn check_block_size(blksize: u8) -> Result<u8, Violation> {
    if (1..=127).contains(&blksize) {
        Ok(blksize)
    } else {
        Err(violation(
            AbortCode::INVALID_BLOCK_SIZE,
            format!("block size {blksize} is outside 1..=127"),
        ))
    }
}

/// Checks the transferred length against the size indicated at initiation.
pub(super) fn check_final_size(len: usize, size: Option<usize>) -> Result<(), Violation> {
    match size {
        Some(s) if len > s => Err(violation(
            AbortCode::LENGTH_TOO_HIGH,
            format!("{len} bytes transferred but {s} indicated"),
        )),
        Some(s) if len < s => Err(violation(
            AbortCode::LENGTH_TOO_LOW,
            format!("{len} bytes transferred but {s} indicated"),
        )),
        _ => Ok(()),
    }
}

/// Bytes of the last segment that carry no data ("n" of the end frame).
/// An empty transfer still has one (empty) segment, hence 7.
pub(super) fn unused_in_last_segment(len: usize) -> u8 {
    if len == 0 {
        7
    } else {
        ((SEGMENT_LEN - len % SEGMENT_LEN) % SEGMENT_LEN) as u8
    }
}

/// Sends data as blocks of numbered segments and moves forward as acks come.
#[derive(Debug)]
pub(super) struct BlockSender {
    data: Vec<u8>,
    /// Bytes confirmed by acks: the next block starts here.
    acked: usize,
    /// Segments of the block in flight.
    sent: u8,
    blksize: u8,
}

impl BlockSender {
    /// A sender of `data` whose first block has `blksize` segments (the
    /// size the peer asked for at initiation).
    pub(crate) fn new(data: Vec<u8>, blksize: u8) -> Self {
        BlockSender {
            data,
            acked: 0,
            sent: 0,
            blksize,
        }
    }

    /// Size of the whole transfer in bytes.
    pub(crate) fn len(&self) -> usize {
        self.data.len()
    }

    /// Bytes the peer has acknowledged so far, for progress reports.
    pub(crate) fn acked(&self) -> usize {
        self.acked
    }

    /// The segments of the next block, numbered from 1, starting after the
    /// last acknowledged byte; the one holding the final byte has c=1.
    pub(crate) fn next_block(&mut self) -> Vec<[u8; 8]> {
        let rest = &self.data[self.acked..];
        let mut out = Vec::new();
        for seq in 1..=self.blksize {
            let start = usize::from(seq - 1) * SEGMENT_LEN;
            let chunk = &rest[start..(start + SEGMENT_LEN).min(rest.len())];
            let last = start + SEGMENT_LEN >= rest.len();
            let mut p = [0u8; 8];
            p[0] = seq | if last { LAST_SEGMENT } else { 0 };
            p[1..=chunk.len()].copy_from_slice(chunk);
            out.push(p);
            if last {
                break;
            }
        }
        self.sent = out.len() as u8;
        out
    }

    /// Takes a block ack: `ackseq` segments arrived in order (the peer wants
    /// the rest again) and `blksize` applies to the next block. Returns true
    /// once every segment, including the last, is acknowledged.
    pub(crate) fn on_ack(&mut self, ackseq: u8, blksize: u8) -> Result<bool, Violation> {
        if ackseq > self.sent {
            return Err(violation(
                AbortCode::INVALID_SEQUENCE_NUMBER,
                format!("ack of segment {ackseq} but only {} were sent", self.sent),
            ));
        }
        let had_last = self.acked + usize::from(self.sent) * SEGMENT_LEN >= self.data.len();
        self.blksize = check_block_size(blksize)?;
        let done = had_last && ackseq == self.sent;
        self.acked = (self.acked + usize::from(ackseq) * SEGMENT_LEN).min(self.data.len());
        Ok(done)
    }

    /// Byte 0 bits for the end frame (n << 2) and the CRC of all data.
    pub(crate) fn end_fields(&self) -> (u8, u16) {
        (
            unused_in_last_segment(self.data.len()) << 2,
            crc16(&self.data),
        )
    }
}

/// Collects numbered segments; out-of-order segments are dropped so that
/// the ack makes the sender repeat them.
#[derive(Debug)]
pub(super) struct BlockReceiver {
    /// In-order segments, 7 bytes each (the last one still padded).
    buf: Vec<u8>,
    size: Option<usize>,
    blksize: u8,
    /// Sequence number of the next in-order segment.
    expected: u8,
    /// A segment of this block went missing: the rest of the block is
    /// discarded (even one that seems to carry the expected number, since
    /// it cannot be told apart from a mislabelled one) and resent after
    /// the ack.
    gap: bool,
    /// The segment with c=1 arrived in order.
    got_last: bool,
    /// ... and its block was acknowledged: only the end frame may follow.
    awaiting_end: bool,
}

impl BlockReceiver {
    /// A receiver expecting `size` bytes if the peer indicated it, in blocks
    /// of `blksize` segments (the size this side asked for).
    pub(crate) fn new(size: Option<usize>, blksize: u8) -> Self {
        BlockReceiver {
            // The indicated size comes from the peer: never trust it for a
            // large allocation.
            buf: Vec::with_capacity(size.unwrap_or(0).min(1 << 16)),
            size,
            blksize,
            expected: 1,
            gap: false,
            got_last: false,
            awaiting_end: false,
        }
    }

    /// Segments per block this side asks for in its acks.
    pub(crate) fn blksize(&self) -> u8 {
        self.blksize
    }

    /// The size the peer indicated at initiation, if it did.
    pub(crate) fn size(&self) -> Option<usize> {
        self.size
    }

    /// Whether the last segment arrived and was acknowledged, so only the
    /// end frame may follow.
    pub(crate) fn awaiting_end(&self) -> bool {
        self.awaiting_end
    }

    /// Data bytes received so far (padding of a last segment excluded when
    /// the size is known).
    pub(crate) fn received(&self) -> usize {
        self.size.map_or(self.buf.len(), |s| self.buf.len().min(s))
    }

    /// Takes one segment. Returns `Some(ackseq)` when the block is over
    /// (last sequence number of the block, or c=1), i.e. an ack is due.
    pub(crate) fn on_segment(&mut self, p: &[u8; 8]) -> Result<Option<u8>, Violation> {
        let seq = p[0] & !LAST_SEGMENT;
        let last = p[0] & LAST_SEGMENT != 0;
        if seq == 0 || seq > self.blksize {
            return Err(violation(
                AbortCode::INVALID_SEQUENCE_NUMBER,
                format!("segment number {seq} outside 1..={}", self.blksize),
            ));
        }
        if seq != self.expected {
            self.gap = true;
        }
        if !self.gap && !self.got_last {
            let segments = self.buf.len() / SEGMENT_LEN;
            if let Some(s) = self.size
                && segments >= s.div_ceil(SEGMENT_LEN).max(1)
            {
                return Err(violation(
                    AbortCode::LENGTH_TOO_HIGH,
                    format!("more segments than the {s} indicated bytes need"),
                ));
            }
            self.buf.extend_from_slice(&p[1..]);
            self.expected += 1;
            self.got_last = last;
        }
        if last || seq == self.blksize {
            let ackseq = self.expected - 1;
            self.expected = 1;
            self.gap = false;
            self.awaiting_end = self.got_last;
            Ok(Some(ackseq))
        } else {
            Ok(None)
        }
    }

    /// Applies the end frame: drops the `unused` padding bytes, checks the
    /// size and, if `crc` is given, the CRC; returns the data.
    pub(crate) fn finish(mut self, unused: u8, crc: Option<u16>) -> Result<Vec<u8>, Violation> {
        // The last segment contributed 7 bytes, so this cannot underflow.
        let len = self.buf.len().saturating_sub(usize::from(unused));
        self.buf.truncate(len);
        check_final_size(len, self.size)?;
        if let Some(expected) = crc {
            let actual = crc16(&self.buf);
            if actual != expected {
                return Err(violation(
                    AbortCode::CRC_ERROR,
                    format!("CRC 0x{actual:04X} computed but 0x{expected:04X} received"),
                ));
            }
        }
        Ok(self.buf)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unused_bytes() {
        assert_eq!(unused_in_last_segment(0), 7);
        assert_eq!(unused_in_last_segment(1), 6);
        assert_eq!(unused_in_last_segment(7), 0);
        assert_eq!(unused_in_last_segment(26), 2);
        assert_eq!(unused_in_last_segment(30), 5);
    }

    #[test]
    fn sender_splits_and_retransmits_from_ack() {
        let mut s = BlockSender::new((0..20).collect(), 2);
        let b = s.next_block();
        assert_eq!(b.len(), 2);
        assert_eq!(b[0], [1, 0, 1, 2, 3, 4, 5, 6]);
        assert_eq!(b[1], [2, 7, 8, 9, 10, 11, 12, 13]);
        // Only segment 1 arrived: the next block starts with bytes 7..
        assert_eq!(s.on_ack(1, 127), Ok(false));
        let b = s.next_block();
        assert_eq!(
            b,
            vec![
                [1, 7, 8, 9, 10, 11, 12, 13],
                [0x82, 14, 15, 16, 17, 18, 19, 0]
            ]
        );
        assert_eq!(
            s.on_ack(3, 127).unwrap_err().code,
            AbortCode::INVALID_SEQUENCE_NUMBER
        );
        assert_eq!(
            s.on_ack(2, 0).unwrap_err().code,
            AbortCode::INVALID_BLOCK_SIZE
        );
    }

    #[test]
    fn empty_data_is_one_empty_last_segment() {
        let mut s = BlockSender::new(Vec::new(), 127);
        assert_eq!(s.next_block(), vec![[0x81, 0, 0, 0, 0, 0, 0, 0]]);
        assert_eq!(s.on_ack(1, 127), Ok(true));
        assert_eq!(s.end_fields(), (7 << 2, 0));
    }

    #[test]
    fn receiver_ignores_out_of_order_and_acks_last_good() {
        let mut r = BlockReceiver::new(Some(10), 3);
        assert_eq!(r.on_segment(&[1, 1, 2, 3, 4, 5, 6, 7]), Ok(None));
        assert_eq!(r.on_segment(&[0x83, 0, 0, 0, 0, 0, 0, 0]), Ok(Some(1)));
        assert!(!r.awaiting_end());
        assert_eq!(r.on_segment(&[0x81, 8, 9, 10, 0, 0, 0, 0]), Ok(Some(1)));
        assert!(r.awaiting_end());
        assert_eq!(
            r.finish(4, Some(crc16(&[1, 2, 3, 4, 5, 6, 7, 8, 9, 10])))
                .unwrap()
                .len(),
            10
        );
        // After a gap the rest of the block is discarded, even a segment
        // carrying the number that was expected.
        let mut r = BlockReceiver::new(None, 4);
        assert_eq!(r.on_segment(&[2, 0, 0, 0, 0, 0, 0, 0]), Ok(None));
        assert_eq!(r.on_segment(&[1, 0, 0, 0, 0, 0, 0, 0]), Ok(None));
        assert_eq!(r.on_segment(&[4, 0, 0, 0, 0, 0, 0, 0]), Ok(Some(0)));
        assert_eq!(r.received(), 0);
        let mut r = BlockReceiver::new(None, 3);
        assert_eq!(
            r.on_segment(&[4, 0, 0, 0, 0, 0, 0, 0]).unwrap_err().code,
            AbortCode::INVALID_SEQUENCE_NUMBER
        );
    }
}
