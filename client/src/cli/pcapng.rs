//! pcapng output of `cangate dump --pcap`, for Wireshark and tshark.
//!
//! One section (Section Header Block), one interface per bus (Interface
//! Description Block: link type LINKTYPE_CAN_SOCKETCAN, the bus's name as
//! `if_name`, nanosecond timestamps through `if_tsresol` = 9), then one
//! Enhanced Packet Block per frame with its direction in `epb_flags`
//! (pcapng, draft-ietf-opsawg-pcapng, sections 4.1-4.3; all integers of
//! the blocks little-endian, as the byte-order magic says).
//!
//! The packet is what a capture on a Linux CAN interface holds
//! (tcpdump.org, LINKTYPE_CAN_SOCKETCAN = 227): the identifier and its
//! flags big-endian (EFF 0x80000000, RTR 0x40000000, ERR 0x20000000), the
//! payload length (a remote request's: the length it asks for), the FD
//! flags (BRS 0x01, ESI 0x02, FDF 0x04), two reserved bytes, then the
//! payload padded
//! to the kernel's frame size: 16 bytes in all for a classic frame, 72
//! for CAN FD. With both FDF and the 72-byte size, readers that predate
//! the FDF flag decode FD frames too.

use super::candump_log::CAN_ERR_FLAG;
use cangate_client::pb;
use std::io::{self, Write};

/// LINKTYPE_CAN_SOCKETCAN.
pub(crate) const LINKTYPE_CAN_SOCKETCAN: u16 = 227;
/// `struct can_frame`: header and 8 data bytes.
const CAN_MTU: usize = 16;
/// `struct canfd_frame`: header and 64 data bytes.
const CANFD_MTU: usize = 72;

const SHB: u32 = 0x0A0D_0D0A;
const IDB: u32 = 0x0000_0001;
const EPB: u32 = 0x0000_0006;
const BYTE_ORDER_MAGIC: u32 = 0x1A2B_3C4D;
const OPT_END: u16 = 0;
const SHB_USERAPPL: u16 = 4;
const IF_NAME: u16 = 2;
const IF_TSRESOL: u16 = 9;
const EPB_FLAGS: u16 = 2;
/// `epb_flags` bits 0-1: the direction.
const INBOUND: u32 = 1;
const OUTBOUND: u32 = 2;

/// Writes one pcapng section, an interface per bus.
pub(crate) struct PcapngWriter<W: Write> {
    out: W,
    buses: Vec<String>,
}

impl<W: Write> PcapngWriter<W> {
    /// Writes the section header and one interface per bus (their order
    /// gives the interface numbers [`PcapngWriter::frame`] takes).
    pub(crate) fn new(mut out: W, buses: &[String]) -> io::Result<Self> {
        let mut body = Vec::new();
        body.extend_from_slice(&BYTE_ORDER_MAGIC.to_le_bytes());
        body.extend_from_slice(&1u16.to_le_bytes()); // major version
        body.extend_from_slice(&0u16.to_le_bytes()); // minor version
        body.extend_from_slice(&(-1i64).to_le_bytes()); // section length: unknown
        let userappl = format!("cangate {}", env!("CARGO_PKG_VERSION"));
        option(&mut body, SHB_USERAPPL, userappl.as_bytes());
        option(&mut body, OPT_END, &[]);
        block(&mut out, SHB, &body)?;
        for bus in buses {
            let mut body = Vec::new();
            body.extend_from_slice(&LINKTYPE_CAN_SOCKETCAN.to_le_bytes());
            body.extend_from_slice(&0u16.to_le_bytes()); // reserved
            body.extend_from_slice(&0u32.to_le_bytes()); // snap length: none
            option(&mut body, IF_NAME, bus.as_bytes());
            option(&mut body, IF_TSRESOL, &[9]); // 10^-9 s
            option(&mut body, OPT_END, &[]);
            block(&mut out, IDB, &body)?;
        }
        out.flush()?;
        Ok(PcapngWriter {
            out,
            buses: buses.to_vec(),
        })
    }

    /// The interface number of a bus.
    pub(crate) fn interface(&self, bus: &str) -> Option<u32> {
        self.buses
            .iter()
            .position(|b| b == bus)
            .and_then(|i| u32::try_from(i).ok())
    }

    /// Writes one frame of interface `interface` (from
    /// [`PcapngWriter::interface`]): its time in ns since the Unix epoch,
    /// and whether it was sent from the gateway's host (outbound) or
    /// received.
    pub(crate) fn frame(
        &mut self,
        interface: u32,
        time_ns: u64,
        f: &pb::Frame,
        outbound: bool,
    ) -> io::Result<()> {
        let packet = socketcan_packet(f);
        let mut body = Vec::with_capacity(32 + packet.len());
        body.extend_from_slice(&interface.to_le_bytes());
        body.extend_from_slice(&((time_ns >> 32) as u32).to_le_bytes());
        body.extend_from_slice(&(time_ns as u32).to_le_bytes());
        let len = packet.len() as u32;
        body.extend_from_slice(&len.to_le_bytes()); // captured
        body.extend_from_slice(&len.to_le_bytes()); // on the wire
        body.extend_from_slice(&packet);
        pad(&mut body);
        let direction = if outbound { OUTBOUND } else { INBOUND };
        option(&mut body, EPB_FLAGS, &direction.to_le_bytes());
        option(&mut body, OPT_END, &[]);
        block(&mut self.out, EPB, &body)
    }

    /// Flushes what was written (after each batch, so a reader of `-`
    /// sees frames as they come).
    pub(crate) fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }
}

/// The frame as a Linux capture holds it (see the module docs).
pub(crate) fn socketcan_packet(f: &pb::Frame) -> Vec<u8> {
    let mut id = f.id & 0x1FFF_FFFF;
    if f.extended {
        id |= 0x8000_0000;
    }
    if f.remote {
        id |= 0x4000_0000;
    }
    if f.error {
        id |= CAN_ERR_FLAG;
    }
    let data = &f.data[..f.data.len().min(64)];
    let (size, fd_flags) = if f.fd {
        (CANFD_MTU, 0x04 | u8::from(f.brs) | (u8::from(f.esi) << 1))
    } else {
        (CAN_MTU, 0)
    };
    let len = if f.remote {
        f.remote_dlc.min(8) as u8
    } else {
        data.len() as u8
    };
    let mut p = Vec::with_capacity(size);
    p.extend_from_slice(&id.to_be_bytes());
    p.extend_from_slice(&[len, fd_flags, 0, 0]);
    p.extend_from_slice(data);
    p.resize(size.max(8 + data.len()), 0);
    p
}

/// A block: type, total length, body (already padded), total length.
fn block(out: &mut impl Write, kind: u32, body: &[u8]) -> io::Result<()> {
    let total = (12 + body.len()) as u32;
    out.write_all(&kind.to_le_bytes())?;
    out.write_all(&total.to_le_bytes())?;
    out.write_all(body)?;
    out.write_all(&total.to_le_bytes())
}

/// An option: code, length, value padded to 32 bits.
fn option(body: &mut Vec<u8>, code: u16, value: &[u8]) {
    body.extend_from_slice(&code.to_le_bytes());
    body.extend_from_slice(&(value.len() as u16).to_le_bytes());
    body.extend_from_slice(value);
    pad(body);
}

fn pad(body: &mut Vec<u8>) {
    while !body.len().is_multiple_of(4) {
        body.push(0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pb(text: &str) -> pb::Frame {
        cangate_client::frame_to_pb(&text.parse().unwrap())
    }

    /// The kernel's layout: big-endian id with flags, length, FD flags,
    /// payload padded to 16 (classic) or 72 (FD) bytes.
    #[test]
    fn packets_are_laid_out_as_linux_captures_them() {
        assert_eq!(
            socketcan_packet(&pb("123#DEADBEEF")),
            [
                0x00, 0x00, 0x01, 0x23, 4, 0, 0, 0, 0xDE, 0xAD, 0xBE, 0xEF, 0, 0, 0, 0
            ]
        );
        let ext = socketcan_packet(&pb("1F334455#11"));
        assert_eq!(&ext[..9], [0x9F, 0x33, 0x44, 0x55, 1, 0, 0, 0, 0x11]);
        assert_eq!(ext.len(), 16);
        let remote = socketcan_packet(&pb("7FF#R3"));
        assert_eq!(&remote[..8], [0x40, 0x00, 0x07, 0xFF, 3, 0, 0, 0]);
        assert_eq!(remote.len(), 16);
        let fd = socketcan_packet(&pb("123##3AABBCCDDEEFF001122334455"));
        assert_eq!(&fd[..8], [0x00, 0x00, 0x01, 0x23, 12, 0x07, 0, 0]);
        assert_eq!(fd[8], 0xAA);
        assert_eq!(fd.len(), 72);
        let mut error = pb("000#0000000000000000");
        error.error = true;
        error.id = 0x40;
        assert_eq!(&socketcan_packet(&error)[..4], [0x20, 0x00, 0x00, 0x40]);
    }

    /// Exact bytes of a whole file: section, one interface, one packet.
    #[test]
    fn a_file_has_its_blocks_in_pcapng_layout() {
        let mut out = Vec::new();
        let mut w = PcapngWriter::new(&mut out, &["can0".to_string()]).unwrap();
        assert_eq!(w.interface("can0"), Some(0));
        assert_eq!(w.interface("can1"), None);
        w.frame(0, 0x0000_0001_0000_0002, &pb("123#AA"), true)
            .unwrap();
        drop(w);
        let u32_at = |i: usize| u32::from_le_bytes(out[i..i + 4].try_into().unwrap());
        // Section header block.
        assert_eq!(u32_at(0), SHB);
        let shb_len = u32_at(4) as usize;
        assert_eq!(u32_at(8), BYTE_ORDER_MAGIC);
        assert_eq!(u32_at(shb_len - 4) as usize, shb_len);
        assert_eq!(shb_len % 4, 0);
        // Interface description block.
        let idb = shb_len;
        let idb_len = u32_at(idb + 4) as usize;
        assert_eq!(u32_at(idb), IDB);
        assert_eq!(&out[idb + 8..idb + 10], 227u16.to_le_bytes());
        // if_name "can0", then if_tsresol 9.
        assert_eq!(
            &out[idb + 16..idb + 32],
            [2, 0, 4, 0, b'c', b'a', b'n', b'0', 9, 0, 1, 0, 9, 0, 0, 0]
        );
        assert_eq!(u32_at(idb + idb_len - 4) as usize, idb_len);
        // Enhanced packet block.
        let epb = idb + idb_len;
        assert_eq!(u32_at(epb), EPB);
        let epb_len = u32_at(epb + 4) as usize;
        assert_eq!(epb_len, 12 + 20 + 16 + 8 + 4);
        assert_eq!(u32_at(epb + 8), 0); // interface
        assert_eq!(u32_at(epb + 12), 1); // time, high
        assert_eq!(u32_at(epb + 16), 2); // time, low
        assert_eq!(u32_at(epb + 20), 16); // captured
        assert_eq!(u32_at(epb + 24), 16); // original
        assert_eq!(&out[epb + 28..epb + 33], [0, 0, 1, 0x23, 1]);
        // epb_flags: outbound.
        assert_eq!(&out[epb + 44..epb + 52], [2, 0, 4, 0, 2, 0, 0, 0]);
        assert_eq!(out.len(), epb + epb_len);
    }
}
