//! candump's log format, written by `cangate dump --log` and read by
//! `cangate replay`: one frame a line,
//!
//! ```text
//! (1700000000.123456) can0 123#DEADBEEF
//! (1700000000.123789) can1 1F334455##1AABBCC
//! ```
//!
//! as `candump -l`/`-L` writes it and `canplayer` reads it (can-utils'
//! `lib.c`, `sprint_canframe`): the time in seconds since the Unix epoch
//! with six decimals, the interface, then the frame in cansend syntax.
//! Standard identifiers have 3 hex digits, extended 8; CAN FD frames `##`
//! and a flags nibble (BRS 1, ESI 2; newer can-utils also set 4, FDF); a
//! remote request `#R` and its length when not 0; an error frame the 8
//! digits of CAN_ERR_FLAG (0x20000000) and its class, with 8 data bytes.
//! Newer candump versions may end a line with a direction word (`R`/`T`);
//! it is accepted and ignored, as canplayer does.

use super::hex;
use cangate_client::can::Frame;
use cangate_client::pb;

/// SocketCAN's CAN_ERR_FLAG: marks an error frame's identifier.
pub(crate) const CAN_ERR_FLAG: u32 = 0x2000_0000;

/// The frame in cansend syntax, as a log line has it: `123#DEADBEEF`.
pub(crate) fn frame_text(f: &pb::Frame) -> String {
    if f.error {
        return format!(
            "{:08X}#{}",
            CAN_ERR_FLAG | (f.id & 0x1FFF_FFFF),
            hex(&f.data, "")
        );
    }
    let id = if f.extended {
        format!("{:08X}", f.id)
    } else {
        format!("{:03X}", f.id)
    };
    if f.remote {
        return match f.remote_dlc {
            0 => format!("{id}#R"),
            n => format!("{id}#R{n}"),
        };
    }
    if f.fd {
        let flags = u8::from(f.brs) | (u8::from(f.esi) << 1);
        return format!("{id}##{flags:X}{}", hex(&f.data, ""));
    }
    format!("{id}#{}", hex(&f.data, ""))
}

/// One log line: `(1700000000.123456) can0 123#DEADBEEF`. `us` is the
/// frame's time, µs since the Unix epoch.
pub(crate) fn log_line(us: u64, bus: &str, f: &pb::Frame) -> String {
    format!(
        "({}.{:06}) {bus} {}",
        us / 1_000_000,
        us % 1_000_000,
        frame_text(f)
    )
}

/// A frame read from a log.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct LogRecord {
    /// The frame's time, ns since the Unix epoch (µs precision in logs
    /// candump wrote).
    pub(crate) time_ns: u64,
    /// The interface the log names.
    pub(crate) bus: String,
    /// The frame.
    pub(crate) frame: Frame,
}

/// What one line of a log holds.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum LogLine {
    /// A frame.
    Frame(LogRecord),
    /// An error frame: received, never sent, so a replay passes over it.
    ErrorFrame,
    /// An empty line or a `#` comment.
    Blank,
}

/// Parses one line of a candump log. The error says what is wrong, for
/// `file:line: …`.
pub(crate) fn parse_line(line: &str) -> Result<LogLine, String> {
    let line = line.trim();
    if line.is_empty() || line.starts_with('#') {
        return Ok(LogLine::Blank);
    }
    let mut words = line.split_ascii_whitespace();
    let (Some(time), Some(bus), Some(frame)) = (words.next(), words.next(), words.next()) else {
        return Err("expected \"(SECONDS.MICROS) BUS FRAME\"".into());
    };
    // An optional direction word, nothing after it.
    if let Some(extra) = words.next()
        && (!matches!(extra, "R" | "T") || words.next().is_some())
    {
        return Err(format!("unexpected {extra:?} after the frame"));
    }
    let time_ns = parse_time(time)?;
    if bus.is_empty() || bus.len() > 64 {
        return Err(format!("{bus:?} is not an interface name"));
    }
    let id_digits = frame.split('#').next().unwrap_or("");
    if id_digits.len() == 8
        && u32::from_str_radix(id_digits, 16).is_ok_and(|id| id & CAN_ERR_FLAG != 0)
    {
        return Ok(LogLine::ErrorFrame);
    }
    let frame: Frame = frame.parse().map_err(|e| format!("{e}"))?;
    Ok(LogLine::Frame(LogRecord {
        time_ns,
        bus: bus.to_string(),
        frame,
    }))
}

/// `(1700000000.123456)` to ns since the epoch: 1 to 9 decimals.
fn parse_time(text: &str) -> Result<u64, String> {
    let bad = || format!("{text:?} is not a time like (1700000000.123456)");
    let inner = text
        .strip_prefix('(')
        .and_then(|t| t.strip_suffix(')'))
        .ok_or_else(bad)?;
    let (secs, frac) = inner.split_once('.').ok_or_else(bad)?;
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    if !digits(secs) || !digits(frac) || frac.len() > 9 {
        return Err(bad());
    }
    let secs: u64 = secs.parse().map_err(|_| bad())?;
    let frac_ns: u64 = format!("{frac:0<9}").parse().map_err(|_| bad())?;
    secs.checked_mul(1_000_000_000)
        .and_then(|ns| ns.checked_add(frac_ns))
        .ok_or_else(bad)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pb(text: &str) -> pb::Frame {
        cangate_client::frame_to_pb(&text.parse().unwrap())
    }

    /// The lines candump -l writes for each kind of frame (can-utils
    /// lib.c): 3 or 8 id digits, `##flags` for FD, `#R` with a length,
    /// error frames with CAN_ERR_FLAG.
    #[test]
    fn lines_are_written_as_candump_writes_them() {
        let t = 1_700_000_000_123_456;
        assert_eq!(
            log_line(t, "can0", &pb("123#DEADBEEF")),
            "(1700000000.123456) can0 123#DEADBEEF"
        );
        assert_eq!(
            log_line(t, "can1", &pb("1F334455#")),
            "(1700000000.123456) can1 1F334455#"
        );
        assert_eq!(log_line(5, "c", &pb("7FF#R")), "(0.000005) c 7FF#R");
        assert_eq!(log_line(5, "c", &pb("7FF#R3")), "(0.000005) c 7FF#R3");
        assert_eq!(
            log_line(5, "c", &pb("123##3AABBCCDDEEFF0011")),
            "(0.000005) c 123##3AABBCCDDEEFF0011"
        );
        assert_eq!(log_line(5, "c", &pb("123##0")), "(0.000005) c 123##0");
        let mut error = pb("123#0000000000000000");
        error.error = true;
        error.id = 0x004;
        error.data = vec![0, 4, 0, 0, 0, 0, 0, 0];
        assert_eq!(
            log_line(5, "c", &error),
            "(0.000005) c 20000004#0004000000000000"
        );
    }

    #[test]
    fn lines_read_back_to_the_same_frames() {
        for text in [
            "123#DEADBEEF",
            "1F334455#",
            "7FF#R",
            "000#R8",
            "123##1AABB",
            "12345678##2",
        ] {
            let line = log_line(1_700_000_000_000_001, "vcan0", &pb(text));
            let LogLine::Frame(r) = parse_line(&line).unwrap() else {
                panic!("{line}")
            };
            assert_eq!(r.frame, text.parse::<Frame>().unwrap(), "{line}");
            assert_eq!(r.bus, "vcan0");
            assert_eq!(r.time_ns, 1_700_000_000_000_001_000);
        }
    }

    #[test]
    fn other_writers_lines_are_read_too() {
        // A direction word (newer candump), the FDF bit in the flags,
        // separators in the data, fewer or more decimals, spaces.
        let LogLine::Frame(r) = parse_line("  (1.5) can0 123##5AA.BB  T ").unwrap() else {
            panic!()
        };
        assert_eq!(r.time_ns, 1_500_000_000);
        assert_eq!(r.frame, "123##1AABB".parse::<Frame>().unwrap());
        let LogLine::Frame(r) = parse_line("(2.123456789) x 001#").unwrap() else {
            panic!()
        };
        assert_eq!(r.time_ns, 2_123_456_789);
        assert_eq!(
            parse_line("(1.0) can0 20000080#0000000000000000"),
            Ok(LogLine::ErrorFrame)
        );
        assert_eq!(parse_line(""), Ok(LogLine::Blank));
        assert_eq!(parse_line("# a comment"), Ok(LogLine::Blank));
    }

    #[test]
    fn malformed_lines_say_what_is_wrong() {
        for (line, says) in [
            ("can0 123#00", "expected"),
            ("(1.0) can0", "expected"),
            ("1.0 can0 123#00", "not a time"),
            ("(1) can0 123#00", "not a time"),
            ("(-1.0) can0 123#00", "not a time"),
            ("(1.0000000001) can0 123#00", "not a time"),
            ("(99999999999999999999.0) can0 123#00", "not a time"),
            ("(1.0) can0 12#00", "identifier"),
            ("(1.0) can0 123#0", "hex"),
            ("(1.0) can0 123#00 X", "unexpected"),
            ("(1.0) can0 123#00 T T", "unexpected"),
            ("(1.0) can0 123#112233445566778899", "8"),
        ] {
            let e = parse_line(line).expect_err(line);
            assert!(e.contains(says), "{line}: {e}");
        }
    }
}
