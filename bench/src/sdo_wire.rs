//! SDO transfers as the wire sees them, for the benchmarks that compare a
//! transfer's time with the bus's: the frames' bus time, and test images
//! with realistic bit stuffing.

use cangate_can::{BitTiming, CanId, Frame};

/// A classic frame of an SDO transfer.
pub fn frame(id: u16, data: &[u8]) -> Frame {
    Frame::new(CanId::Standard(id), data).expect("classic SDO frame")
}

/// Bus time of the frames of an SDO transfer of `data` with node `node`,
/// protocol by protocol
/// (the data frames and their confirmations; the initiate and end frames
/// are included as plain 8-byte frames).
pub fn transfer_bus_ns(t: &BitTiming, node: u8, data: &[u8], block: bool, upload: bool) -> u64 {
    let node = u16::from(node);
    let (data_id, confirm_id) = if upload {
        (0x580 + node, 0x600 + node)
    } else {
        (0x600 + node, 0x580 + node)
    };
    let d = |f: &Frame| t.frame_duration_ns(f);
    let plain = |id: u16, cmd: u8| d(&frame(id, &[cmd, 0, 0x21, 0, 0, 0, 0, 0]));
    let chunks: Vec<&[u8]> = data.chunks(7).collect();
    let mut total = 0;
    if block {
        // Initiate (2), start (upload only), segments, one ack per
        // sub-block of 127, end (2).
        total += plain(confirm_id, 0xA0) + plain(data_id, 0xC0);
        if upload {
            total += plain(confirm_id, 0xA3);
        }
        for (k, c) in chunks.iter().enumerate() {
            let seq = (k % 127) as u8 + 1;
            let last = if k + 1 == chunks.len() { 0x80 } else { 0 };
            let mut p = [0u8; 8];
            p[0] = seq | last;
            p[1..1 + c.len()].copy_from_slice(c);
            total += d(&frame(data_id, &p));
            if seq == 127 || last != 0 {
                total += d(&frame(confirm_id, &[0xA2, seq, 127, 0, 0, 0, 0, 0]));
            }
        }
        total += plain(data_id, 0xC1) + plain(confirm_id, 0xA1);
    } else {
        total += plain(confirm_id, 0x40) + plain(data_id, 0x41);
        for (k, c) in chunks.iter().enumerate() {
            let toggle = if k % 2 == 1 { 0x10 } else { 0 };
            let last = u8::from(k + 1 == chunks.len());
            let unused = ((7 - c.len()) as u8) << 1;
            let mut p = [0u8; 8];
            p[0] = toggle | unused | last;
            p[1..1 + c.len()].copy_from_slice(c);
            total += d(&frame(data_id, &p));
            let ack = if upload { 0x60 | toggle } else { 0x20 | toggle };
            total += d(&frame(confirm_id, &[ack, 0, 0, 0, 0, 0, 0, 0]));
        }
    }
    total
}

/// Deterministic pseudo-random bytes (realistic bit stuffing): the
/// simulated node's test image.
pub fn firmware(len: usize) -> Vec<u8> {
    cangate_sim::program::test_image(len, 0x2545_F491)
}
