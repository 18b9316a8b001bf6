//! The CiA 309-3 ASCII gateway protocol without I/O: splitting the byte
//! stream into lines ([`LineBuffer`]), reading a command line
//! ([`Session::on_line`], with the session's defaults: network, node, SDO
//! timeout and block mode), the values of each data type in both
//! directions ([`DataType`]) and every line the gateway writes.
//!
//! Source of truth: CANopenNode's `309/CO_gateway_ascii.h` (the command
//! syntax of its help text, the error codes of `CO_GTWA_respErrorCode_t`)
//! and `CO_gateway_ascii.c` / `301/CO_fifo.c` (commit 9b8beed) for the
//! bytes: what `canopend` and `cocomm` (CANopenLinux) speak. Lely's
//! `src/co/gw_txt.c` (lely-core) for the event lines, which canopend does
//! not send. What this module settles:
//!
//! - **Lines.** A command ends with `\n`, a `\r` before it is optional;
//!   every answer ends with `\r\n`. `#` starts a comment (outside a quoted
//!   string); an empty or comment-only line is answered with an empty line,
//!   as canopend does.
//! - **Prefix.** `[<sequence>]` (a number, as `strtoul(…, 0)` reads it:
//!   decimal, `0x` hex, leading-zero octal), then for the node commands
//!   (`read`, `write`, NMT) up to two numbers, `[[<net>] <node>]`, and for
//!   the network commands (`set`, `lss_*`) one, `[<net>]` (the help text's
//!   syntax; canopend itself reads a single number as the node there and
//!   ignores it). A line without `[…]` is read as sequence 0, as canopend
//!   does on its standard input (on its sockets it answers 101).
//! - **Answers.** `[seq] OK`, `[seq] <value>`, `[seq] ERROR:<code> #<text>`
//!   (no space after the colon), SDO aborts as `[seq] ERROR:0x%08X #<text>`.
//!   The gateway's own refusals (roles, an enabled axis's drive) are error
//!   102 with the reason after the standard text.
//! - **Values** ([`DataType`]): integers as `%u`/`%d`, `x…` as `0x%0NX`,
//!   reals as `%g`, `vs` in double quotes with `"` doubled, `os`/`us`/`d`
//!   as base64, `hex` as upper-case bytes separated by spaces. A numeric
//!   value whose answer has another size is printed as `hex`, as canopend
//!   does; `read` without a type prints `hex`.
//! - **Networks.** Network *n* is the *n*-th CANopen bus of `[cia309]`; the
//!   default network is 1 (canopend starts without one and does not check
//!   it), the default node is unset (error 105 until `set node`).
//! - **NMT to every node**: node 0 (`[1] 0 start`), as canopend's node
//!   check allows 0 for NMT only.
//! - **Event lines** (opt-in with `set events 1`, a cangate extension: a
//!   client that reads one line per command would otherwise take an event
//!   for its answer): `<net> <node> BOOT_UP`,
//!   `<net> <node> EMCY <code %04X> <register %02X> <5 bytes %u>`,
//!   `<net> <node> ERROR <code> (<text>)` for a heartbeat (203) or node
//!   guarding (200) loss and a heartbeat back (202), as lely-core's
//!   `gw_txt.c` prints them.
//! - **PDO data** (lely-core's `coctl`, `gw_txt.c`; canopend has none):
//!   `[<net>] r[ead] p[do] <n>` and `[<net>] w[rite] p[do] <n> <count>
//!   <value>…`, network commands (a single number before them is the
//!   network). The values are those of the PDO's mapped objects in
//!   mapping order, as unsigned numbers of their bits; read answers
//!   `[seq] <net> pdo <count> 0x<value>…` (`%x`, as lely prints them).
//!   Lely numbers the gateway's own PDOs; cangate has the nodes' PDOs, so
//!   PDO *n* (1..=512) is PDO `(n-1) % 4 + 1` of node `(n-1) / 4 + 1`
//!   ([`pdo_target`]): `read pdo` reads that TPDO of the node (the last
//!   one received), `write pdo` sends that RPDO of the node.

use std::fmt::Write as _;

/// A CiA 309-3 error code of an `ERROR:` answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ErrorCode(pub u16);

impl ErrorCode {
    /// 100: the command is not supported.
    pub const NOT_SUPPORTED: ErrorCode = ErrorCode(100);
    /// 101: the command cannot be read.
    pub const SYNTAX: ErrorCode = ErrorCode(101);
    /// 102: the gateway cannot carry the command out now.
    pub const INTERNAL_STATE: ErrorCode = ErrorCode(102);
    /// 103: no answer in time.
    pub const TIMEOUT: ErrorCode = ErrorCode(103);
    /// 104: no default network.
    pub const NO_DEFAULT_NET: ErrorCode = ErrorCode(104);
    /// 105: no default node.
    pub const NO_DEFAULT_NODE: ErrorCode = ErrorCode(105);
    /// 106: no such network.
    pub const UNSUPPORTED_NET: ErrorCode = ErrorCode(106);
    /// 107: no such node.
    pub const UNSUPPORTED_NODE: ErrorCode = ErrorCode(107);
    /// 200: node guarding lost the node.
    pub const LOST_GUARDING: ErrorCode = ErrorCode(200);
    /// 202: heartbeat started (again).
    pub const HEARTBEAT_STARTED: ErrorCode = ErrorCode(202);
    /// 203: heartbeat lost.
    pub const HEARTBEAT_LOST: ErrorCode = ErrorCode(203);
    /// 301: the bus is off.
    pub const BUS_OFF: ErrorCode = ErrorCode(301);
    /// 501: an LSS device refused with a manufacturer-specific error.
    pub const LSS_MANUFACTURER: ErrorCode = ErrorCode(501);
    /// 502: the LSS device does not take this node-ID.
    pub const LSS_NODE_ID: ErrorCode = ErrorCode(502);
    /// 503: the LSS device does not take this bit rate.
    pub const LSS_BIT_RATE: ErrorCode = ErrorCode(503);
    /// 504: the LSS device could not store its configuration.
    pub const LSS_STORE: ErrorCode = ErrorCode(504);

    /// The standard text of the code (CiA 309-3, as canopend prints it).
    pub fn text(self) -> &'static str {
        match self.0 {
            100 => "Request not supported.",
            101 => "Syntax error.",
            102 => "Request not processed due to internal state.",
            103 => "Time-out.",
            104 => "No default net set.",
            105 => "No default node set.",
            106 => "Unsupported net.",
            107 => "Unsupported node.",
            200 => "Lost guarding message.",
            201 => "Lost connection.",
            202 => "Heartbeat started.",
            203 => "Heartbeat lost.",
            204 => "Wrong NMT state.",
            205 => "Boot-up.",
            300 => "Error passive.",
            301 => "Bus off.",
            303 => "CAN buffer overflow.",
            304 => "CAN init.",
            305 => "CAN active (at init or start-up).",
            400 => "PDO already used.",
            401 => "PDO length exceeded.",
            501 => "LSS implementation- / manufacturer-specific error.",
            502 => "LSS node-ID not supported.",
            503 => "LSS bit-rate not supported.",
            504 => "LSS parameter storing failed.",
            505 => "LSS command failed because of media error.",
            600 => "Running out of memory.",
            _ => "-",
        }
    }
}

/// `[seq] OK`.
pub fn format_ok(seq: u32) -> String {
    format!("[{seq}] OK\r\n")
}

/// `[seq] ERROR:<code> #<text>`, the gateway's reason after the standard
/// text when there is one.
pub fn format_error(seq: u32, code: ErrorCode, detail: Option<&str>) -> String {
    match detail {
        Some(d) => format!(
            "[{seq}] ERROR:{} #{} {}\r\n",
            code.0,
            code.text(),
            one_line(d)
        ),
        None => format!("[{seq}] ERROR:{} #{}\r\n", code.0, code.text()),
    }
}

/// `[seq] ERROR:0x%08X #<text>` for an SDO abort code; `name` is the
/// code's CiA 301 text.
pub fn format_abort(seq: u32, code: u32, name: &str) -> String {
    let mut text = String::with_capacity(name.len() + 1);
    let mut chars = name.chars();
    if let Some(c) = chars.next() {
        text.extend(c.to_uppercase());
        text.push_str(chars.as_str());
    }
    if !text.ends_with('.') {
        text.push('.');
    }
    format!("[{seq}] ERROR:0x{code:08X} #{text}\r\n")
}

/// `[seq] <value>`: the answer of a read.
pub fn format_value(seq: u32, ty: Option<DataType>, data: &[u8]) -> String {
    let mut out = format!("[{seq}] ");
    ty.unwrap_or(DataType::Hex).format_into(&mut out, data);
    out.push_str("\r\n");
    out
}

/// `[seq] 0x%08X 0x%08X 0x%08X 0x%08X`: an LSS address (vendor-ID,
/// product code, revision, serial number).
pub fn format_lss_address(seq: u32, id: [u32; 4]) -> String {
    format!(
        "[{seq}] 0x{:08X} 0x{:08X} 0x{:08X} 0x{:08X}\r\n",
        id[0], id[1], id[2], id[3]
    )
}

/// `[seq] 0x%08X`: one inquired LSS value.
pub fn format_lss_value(seq: u32, v: u32) -> String {
    format!("[{seq}] 0x{v:08X}\r\n")
}

/// `[seq] 0x%02X`: an inquired node-ID.
pub fn format_lss_node_id(seq: u32, id: u8) -> String {
    format!("[{seq}] 0x{id:02X}\r\n")
}

/// Comment lines (`# …`) and then `[seq] OK`, for answers of several
/// lines (as canopend's `lss_allnodes` reports).
pub fn format_comment_lines(seq: u32, lines: &[String]) -> String {
    let mut out = String::new();
    for l in lines {
        let _ = writeln!(out, "# {}", one_line(l));
    }
    out.push_str(&format_ok(seq));
    out
}

/// Newlines in a reason would end the answer early.
fn one_line(s: &str) -> String {
    s.replace(['\r', '\n'], " ")
}

/// What happened to a node, for an event line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Event {
    /// A boot-up message.
    BootUp,
    /// An EMCY message.
    Emcy {
        /// Error code.
        code: u16,
        /// Error register.
        register: u8,
        /// Manufacturer-specific error field.
        manufacturer: [u8; 5],
    },
    /// The heartbeat (or, with `guarding`, node guarding) lost the node.
    Lost {
        /// Detected by node guarding.
        guarding: bool,
    },
    /// The heartbeat is back.
    HeartbeatStarted,
}

/// The event line of `event` of `node` on network `net`.
pub fn format_event(net: u16, node: u8, event: &Event) -> String {
    let error = |code: ErrorCode| format!("{net} {node} ERROR {} ({})\r\n", code.0, code.text());
    match event {
        Event::BootUp => format!("{net} {node} BOOT_UP\r\n"),
        Event::Emcy {
            code,
            register,
            manufacturer: m,
        } => format!(
            "{net} {node} EMCY {code:04X} {register:02X} {} {} {} {} {}\r\n",
            m[0], m[1], m[2], m[3], m[4]
        ),
        Event::Lost { guarding: false } => error(ErrorCode::HEARTBEAT_LOST),
        Event::Lost { guarding: true } => error(ErrorCode::LOST_GUARDING),
        Event::HeartbeatStarted => error(ErrorCode::HEARTBEAT_STARTED),
    }
}

/// The help texts (`help`, `help datatype`, `help lss`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HelpTopic {
    /// The commands.
    Commands,
    /// The data types.
    Datatypes,
    /// The LSS commands.
    Lss,
}

/// The help text of `topic`, lines separated by `\n`, the last one ending
/// with `\r\n` (canopend's layout).
pub fn help_text(topic: HelpTopic) -> &'static str {
    match topic {
        HelpTopic::Commands => HELP_COMMANDS,
        HelpTopic::Datatypes => HELP_DATATYPES,
        HelpTopic::Lss => HELP_LSS,
    }
}

const HELP_COMMANDS: &str = "\n\
cangate CiA 309-3 ASCII gateway. Every command starts with [<sequence>].\n\
[[<net>] <node>] r[ead] <index> <subindex> [<datatype>]   SDO upload\n\
[[<net>] <node>] w[rite] <index> <subindex> <datatype> <value>   SDO download\n\
[<net>] r[ead] p[do] <n>   the last TPDO (n-1)%4+1 received from node (n-1)/4+1\n\
[<net>] w[rite] p[do] <n> <count> <value>...   send RPDO (n-1)%4+1 of node (n-1)/4+1\n\
[[<net>] <node>] start | stop | preop[erational]   NMT (node 0: every node)\n\
[[<net>] <node>] reset node | reset comm[unication]   NMT reset\n\
[<net>] set network <net>   default network (1: the first CANopen bus)\n\
[<net>] set node <node>   default node\n\
[<net>] set sdo_timeout <ms>   SDO timeout of this connection\n\
[<net>] set sdo_block <0|1>   SDO block transfers on or off\n\
set events <0|1>   event lines (BOOT_UP, EMCY, ERROR) on this connection\n\
login <token>   authenticate (when the gateway has tokens)\n\
info   the networks and who you are\n\
help [datatype|lss]   this text, the data types, the LSS commands\n\
Answers: [<sequence>] OK | <value> | ERROR:<code> #<text>\n\
Lines end with \\n (\\r optional); # starts a comment.\r\n";

const HELP_DATATYPES: &str = "\n\
b   boolean\n\
i8 i16 i32 i64   signed integers\n\
u8 u16 u32 u64   unsigned integers\n\
x8 x16 x32 x64   unsigned integers shown in hexadecimal\n\
r32 r64   reals\n\
vs   visible string (in double quotes when it has spaces; \"\" is one quote)\n\
os us   octet and unicode strings, base64\n\
d   domain, base64\n\
hex   bytes in hexadecimal, spaces between them optional\r\n";

const HELP_LSS: &str = "\n\
[<net>] lss_switch_glob <0|1>   every device to waiting (0) or configuration (1)\n\
[<net>] lss_switch_sel <vendor> <product> <revision> <serial>   one device to configuration\n\
[<net>] lss_set_node <node>   node-ID of the device in configuration\n\
[<net>] lss_conf_bitrate 0 <index>   bit rate (0=1000 1=800 2=500 3=250 4=125 6=50 7=20 8=10 kbit/s)\n\
[<net>] lss_activate_bitrate <switch delay ms>\n\
[<net>] lss_store   store the configuration\n\
[<net>] lss_inquire_addr [<0..3>]   vendor, product, revision, serial (all four without a number)\n\
[<net>] lss_get_node   node-ID of the device in configuration\n\
[<net>] _lss_fastscan [<step ms>]   find one unconfigured device (left in configuration)\n\
[<net>] lss_allnodes [<step ms> [<first node> <store 0|1>]]   number every unconfigured device\r\n";

/// A CiA 309-3 data type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DataType {
    /// `b`.
    Bool,
    /// `i8`.
    I8,
    /// `i16`.
    I16,
    /// `i32`.
    I32,
    /// `i64`.
    I64,
    /// `u8`.
    U8,
    /// `u16`.
    U16,
    /// `u32`.
    U32,
    /// `u64`.
    U64,
    /// `x8`.
    X8,
    /// `x16`.
    X16,
    /// `x32`.
    X32,
    /// `x64`.
    X64,
    /// `r32`.
    R32,
    /// `r64`.
    R64,
    /// `vs`.
    VisibleString,
    /// `os`.
    OctetString,
    /// `us`.
    UnicodeString,
    /// `d`.
    Domain,
    /// `hex` (canopend's, not in CiA 309-3).
    Hex,
}

impl DataType {
    /// The type of a name (lower case).
    pub fn from_name(name: &str) -> Option<DataType> {
        use DataType::*;
        Some(match name {
            "b" => Bool,
            "i8" => I8,
            "i16" => I16,
            "i32" => I32,
            "i64" => I64,
            "u8" => U8,
            "u16" => U16,
            "u32" => U32,
            "u64" => U64,
            "x8" => X8,
            "x16" => X16,
            "x32" => X32,
            "x64" => X64,
            "r32" => R32,
            "r64" => R64,
            "vs" => VisibleString,
            "os" => OctetString,
            "us" => UnicodeString,
            "d" => Domain,
            "hex" => Hex,
            _ => return None,
        })
    }

    /// The size of a value in bytes, for the fixed-size types.
    pub fn size(self) -> Option<usize> {
        use DataType::*;
        match self {
            Bool | I8 | U8 | X8 => Some(1),
            I16 | U16 | X16 => Some(2),
            I32 | U32 | X32 | R32 => Some(4),
            I64 | U64 | X64 | R64 => Some(8),
            VisibleString | OctetString | UnicodeString | Domain | Hex => None,
        }
    }

    /// Appends the text of `data` as this type (see the module
    /// documentation).
    pub fn format_into(self, out: &mut String, data: &[u8]) {
        use DataType::*;
        if let Some(size) = self.size()
            && data.len() != size
        {
            return Hex.format_into(out, data);
        }
        let le = |n: usize| -> u64 {
            let mut b = [0u8; 8];
            b[..n].copy_from_slice(&data[..n]);
            u64::from_le_bytes(b)
        };
        let _ = match self {
            Bool | U8 | U16 | U32 | U64 => write!(out, "{}", le(data.len())),
            I8 => write!(out, "{}", data[0] as i8),
            I16 => write!(out, "{}", le(2) as u16 as i16),
            I32 => write!(out, "{}", le(4) as u32 as i32),
            I64 => write!(out, "{}", le(8) as i64),
            X8 => write!(out, "0x{:02X}", data[0]),
            X16 => write!(out, "0x{:04X}", le(2)),
            X32 => write!(out, "0x{:08X}", le(4)),
            X64 => write!(out, "0x{:016X}", le(8)),
            R32 => {
                out.push_str(&format_g(f64::from(f32::from_bits(le(4) as u32))));
                Ok(())
            }
            R64 => {
                out.push_str(&format_g(f64::from_bits(le(8))));
                Ok(())
            }
            VisibleString => {
                out.push('"');
                for &b in data {
                    // canopend leaves NUL and CR out.
                    match b {
                        0 | b'\r' => {}
                        b'"' => out.push_str("\"\""),
                        _ => out.push(char::from(b)),
                    }
                }
                out.push('"');
                Ok(())
            }
            OctetString | UnicodeString | Domain => {
                base64_encode_into(out, data);
                Ok(())
            }
            Hex => {
                for (i, b) in data.iter().enumerate() {
                    if i > 0 {
                        out.push(' ');
                    }
                    let _ = write!(out, "{b:02X}");
                }
                Ok(())
            }
        };
    }
}

/// C's `printf("%g")`: six significant digits, the exponent form below
/// 1e-4 and from 1e6 on, trailing zeros removed.
pub fn format_g(x: f64) -> String {
    if x.is_nan() {
        return if x.is_sign_negative() { "-nan" } else { "nan" }.into();
    }
    if x.is_infinite() {
        return if x < 0.0 { "-inf" } else { "inf" }.into();
    }
    if x == 0.0 {
        return if x.is_sign_negative() { "-0" } else { "0" }.into();
    }
    // The exponent after rounding to six significant digits.
    let sci = format!("{x:.5e}");
    let (mantissa, exp) = sci.split_once('e').expect("{:e} has an exponent");
    let exp: i32 = exp.parse().expect("an integer exponent");
    let trim = |s: &str| -> String {
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s.to_string()
        }
    };
    if !(-4..6).contains(&exp) {
        let sign = if exp < 0 { '-' } else { '+' };
        format!("{}e{sign}{:02}", trim(mantissa), exp.abs())
    } else {
        trim(&format!("{:.*}", (5 - exp) as usize, x))
    }
}

const BASE64: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

/// RFC 2045 base64 with padding, on one line.
fn base64_encode_into(out: &mut String, data: &[u8]) {
    for chunk in data.chunks(3) {
        let b = [
            chunk[0],
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for i in 0..4 {
            if i <= chunk.len() {
                out.push(char::from(BASE64[((n >> (18 - 6 * i)) & 0x3F) as usize]));
            } else {
                out.push('=');
            }
        }
    }
}

/// Base64 with or without padding; `None` for anything else.
fn base64_decode(text: &str) -> Option<Vec<u8>> {
    let body = text.trim_end_matches('=');
    if text.len() - body.len() > 2 {
        return None;
    }
    let mut out = Vec::with_capacity(body.len() * 3 / 4);
    let mut acc = 0u32;
    let mut bits = 0;
    for c in body.bytes() {
        let v = BASE64.iter().position(|&b| b == c)? as u32;
        acc = (acc << 6) | v;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    // A single character left over cannot hold a byte.
    (bits < 6).then_some(out)
}

/// A number as `strtoul(s, &end, 0)` reads it, the whole token: decimal,
/// `0x` hexadecimal, or octal with a leading zero.
fn parse_c_unsigned(s: &str) -> Option<u64> {
    let (digits, radix) = if let Some(h) = s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        (h, 16)
    } else if s.len() > 1 && s.starts_with('0') {
        (&s[1..], 8)
    } else {
        (s, 10)
    };
    if digits.is_empty() || !digits.chars().all(|c| c.is_digit(radix)) {
        return None;
    }
    u64::from_str_radix(digits, radix).ok()
}

/// A signed number as `strtoll(s, &end, 0)` reads it.
fn parse_c_signed(s: &str) -> Option<i64> {
    let (neg, rest) = match s.as_bytes().first() {
        Some(b'-') => (true, &s[1..]),
        Some(b'+') => (false, &s[1..]),
        _ => (false, s),
    };
    let m = parse_c_unsigned(rest)?;
    if neg {
        if m == 1 << 63 {
            Some(i64::MIN)
        } else {
            i64::try_from(m).ok().map(|v| -v)
        }
    } else {
        i64::try_from(m).ok()
    }
}

/// Reads one command line word by word.
struct Lexer<'a> {
    s: &'a str,
    pos: usize,
}

impl<'a> Lexer<'a> {
    fn skip_space(&mut self) {
        let rest = &self.s[self.pos..];
        self.pos += rest.len() - rest.trim_start_matches([' ', '\t', '\r']).len();
    }

    /// At the end of the command (the line's end or a comment).
    fn at_end(&mut self) -> bool {
        self.skip_space();
        self.s[self.pos..].is_empty() || self.s[self.pos..].starts_with('#')
    }

    /// The next word; `None` at the end.
    fn word(&mut self) -> Option<&'a str> {
        if self.at_end() {
            return None;
        }
        let rest = &self.s[self.pos..];
        let n = rest.find([' ', '\t', '\r', '#']).unwrap_or(rest.len());
        self.pos += n;
        Some(&rest[..n])
    }

    /// A visible string: in double quotes (`""` is one quote inside) or
    /// one word without them.
    fn visible_string(&mut self) -> Option<String> {
        if self.at_end() {
            return None;
        }
        let rest = &self.s[self.pos..];
        let mut out = String::new();
        if let Some(quoted) = rest.strip_prefix('"') {
            let mut chars = quoted.char_indices().peekable();
            while let Some((i, c)) = chars.next() {
                if c != '"' {
                    out.push(c);
                } else if chars.peek().map(|&(_, c)| c) == Some('"') {
                    out.push('"');
                    chars.next();
                } else {
                    // The closing quote: a word boundary must follow.
                    let after = &quoted[i + 1..];
                    if !(after.is_empty() || after.starts_with([' ', '\t', '\r', '#'])) {
                        return None;
                    }
                    self.pos += 1 + i + 1;
                    return Some(out);
                }
            }
            // No closing quote.
            None
        } else {
            let w = self.word()?;
            // A quote inside a bare word only doubled.
            let mut chars = w.chars().peekable();
            while let Some(c) = chars.next() {
                if c == '"' && chars.next() != Some('"') {
                    return None;
                }
                out.push(c);
            }
            Some(out)
        }
    }
}

/// The bytes of a value written as `ty` (the rest of the command line);
/// `None` when it cannot be read.
fn parse_value(ty: DataType, lx: &mut Lexer<'_>) -> Option<Vec<u8>> {
    use DataType::*;
    let unsigned = |lx: &mut Lexer<'_>, max: u64, n: usize| -> Option<Vec<u8>> {
        let v = parse_c_unsigned(lx.word()?).filter(|v| *v <= max)?;
        Some(v.to_le_bytes()[..n].to_vec())
    };
    let signed = |lx: &mut Lexer<'_>, min: i64, max: i64, n: usize| -> Option<Vec<u8>> {
        let v = parse_c_signed(lx.word()?).filter(|v| (min..=max).contains(v))?;
        Some(v.to_le_bytes()[..n].to_vec())
    };
    let data = match ty {
        Bool | U8 | X8 => unsigned(lx, u8::MAX.into(), 1)?,
        U16 | X16 => unsigned(lx, u16::MAX.into(), 2)?,
        U32 | X32 => unsigned(lx, u32::MAX.into(), 4)?,
        U64 | X64 => unsigned(lx, u64::MAX, 8)?,
        I8 => signed(lx, i8::MIN.into(), i8::MAX.into(), 1)?,
        I16 => signed(lx, i16::MIN.into(), i16::MAX.into(), 2)?,
        I32 => signed(lx, i32::MIN.into(), i32::MAX.into(), 4)?,
        I64 => signed(lx, i64::MIN, i64::MAX, 8)?,
        R32 => lx.word()?.parse::<f32>().ok()?.to_le_bytes().to_vec(),
        R64 => lx.word()?.parse::<f64>().ok()?.to_le_bytes().to_vec(),
        VisibleString => lx.visible_string()?.into_bytes(),
        OctetString | UnicodeString | Domain => base64_decode(lx.word()?)?,
        Hex => {
            let mut out = Vec::new();
            while let Some(w) = lx.word() {
                let bytes = w.as_bytes();
                if bytes.len() == 1 {
                    out.push(u8::from_str_radix(w, 16).ok()?);
                    continue;
                }
                if bytes.len() % 2 != 0 {
                    return None;
                }
                for pair in bytes.chunks(2) {
                    out.push(u8::from_str_radix(std::str::from_utf8(pair).ok()?, 16).ok()?);
                }
            }
            out
        }
    };
    // canopend refuses an empty value.
    (!data.is_empty() && lx.at_end()).then_some(data)
}

/// An NMT command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Nmt {
    /// `start`.
    Start,
    /// `stop`.
    Stop,
    /// `preop[erational]`.
    PreOperational,
    /// `reset node`.
    ResetNode,
    /// `reset comm[unication]`.
    ResetCommunication,
}

/// An LSS command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lss {
    /// `lss_switch_glob <0|1>`: to configuration (`true`) or waiting.
    SwitchGlobal(bool),
    /// `lss_switch_sel <vendor> <product> <revision> <serial>`.
    SwitchSelective([u32; 4]),
    /// `lss_set_node <node>` (1..=127, or 255).
    SetNode(u8),
    /// `lss_conf_bitrate <table> <index>`.
    ConfigureBitRate {
        /// Table selector (0).
        table: u8,
        /// Index in the CiA 301 table.
        index: u8,
    },
    /// `lss_activate_bitrate <switch delay ms>`.
    ActivateBitRate(u16),
    /// `lss_store`.
    Store,
    /// `lss_inquire_addr [<0..3>]`: one part of the address, or all four.
    InquireAddress(Option<u8>),
    /// `lss_get_node`.
    GetNode,
    /// `_lss_fastscan [<ms>]`.
    Fastscan(Option<u16>),
    /// `lss_allnodes [<ms> [<first node> <store>]]`: every unconfigured
    /// device found by fastscan gets the next node-ID.
    AllNodes {
        /// Fastscan step time (`None`: the default).
        step_ms: Option<u16>,
        /// The first node-ID given (canopend: 2).
        first: u8,
        /// Store each configuration (canopend: yes).
        store: bool,
    },
}

/// What the gateway has to do for a line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Action {
    /// Write this answer (the session handled the command itself).
    Reply(String),
    /// SDO upload.
    Read {
        /// Sequence.
        seq: u32,
        /// Network (1-based).
        net: u16,
        /// Node.
        node: u8,
        /// Index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// How to print the value (`None`: `hex`).
        ty: Option<DataType>,
    },
    /// SDO download.
    Write {
        /// Sequence.
        seq: u32,
        /// Network.
        net: u16,
        /// Node.
        node: u8,
        /// Index.
        index: u16,
        /// Sub-index.
        sub: u8,
        /// The value's bytes.
        data: Vec<u8>,
    },
    /// NMT to `node` (0: every node).
    Nmt {
        /// Sequence.
        seq: u32,
        /// Network.
        net: u16,
        /// Node, 0 for all.
        node: u8,
        /// The command.
        command: Nmt,
    },
    /// An LSS command on network `net`.
    Lss {
        /// Sequence.
        seq: u32,
        /// Network.
        net: u16,
        /// The command.
        command: Lss,
    },
    /// `set events <0|1>`: answered by the gateway, which subscribes.
    Events {
        /// Sequence.
        seq: u32,
        /// On or off.
        on: bool,
    },
    /// `login <token>`.
    Login {
        /// Sequence.
        seq: u32,
        /// The token.
        token: String,
    },
    /// `info`.
    Info {
        /// Sequence.
        seq: u32,
    },
    /// `read pdo <n>`: the last TPDO received (see [`pdo_target`]).
    ReadPdo {
        /// Sequence.
        seq: u32,
        /// Network.
        net: u16,
        /// Node.
        node: u8,
        /// The node's TPDO number.
        pdo: u16,
    },
    /// `write pdo <n> <count> <value>…`: an RPDO sent (see
    /// [`pdo_target`]).
    WritePdo {
        /// Sequence.
        seq: u32,
        /// Network.
        net: u16,
        /// Node.
        node: u8,
        /// The node's RPDO number.
        pdo: u16,
        /// The mapped objects' values, in mapping order.
        values: Vec<u64>,
    },
}

/// The node and its PDO number that the gateway's PDO `n` (1..=512) of
/// `read pdo`/`write pdo` stands for: four per node, as the predefined
/// connection set has (PDO 1 is node 1's first, 9 node 3's first); `None`
/// beyond node 127.
pub fn pdo_target(n: u16) -> Option<(u8, u16)> {
    let node = (n.checked_sub(1)? / 4 + 1) as u8;
    (node <= 127).then_some((node, (n - 1) % 4 + 1))
}

/// `[seq] <net> pdo <count> 0x<value>…`: a PDO's mapped values as lely's
/// `gw_txt.c` prints a read.
pub fn format_pdo(seq: u32, net: u16, values: &[u64]) -> String {
    let mut line = format!("[{seq}] {net} pdo {}", values.len());
    for v in values {
        let _ = write!(line, " 0x{v:x}");
    }
    line.push_str("\r\n");
    line
}

impl Action {
    /// The command's name for metrics and refusals.
    pub fn name(&self) -> &'static str {
        match self {
            Action::Reply(_) => "local",
            Action::Read { .. } => "read",
            Action::Write { .. } => "write",
            Action::Nmt { .. } => "nmt",
            Action::Lss { .. } => "lss",
            Action::Events { .. } => "events",
            Action::Login { .. } => "login",
            Action::Info { .. } => "info",
            Action::ReadPdo { .. } => "read_pdo",
            Action::WritePdo { .. } => "write_pdo",
        }
    }
}

/// One connection's defaults and its reading of command lines.
#[derive(Debug, Clone)]
pub struct Session {
    nets: u16,
    default_net: u16,
    default_node: Option<u8>,
    /// SDO timeout, ms.
    pub sdo_timeout_ms: u16,
    /// SDO block transfers.
    pub sdo_block: bool,
}

/// Why a line was refused before anything was done.
struct Refused(ErrorCode);

impl From<ErrorCode> for Refused {
    fn from(c: ErrorCode) -> Self {
        Refused(c)
    }
}

/// The next word, which must be there.
fn word<'a>(lx: &mut Lexer<'a>) -> Result<&'a str, Refused> {
    lx.word().ok_or(Refused(ErrorCode::SYNTAX))
}

/// Which prefix numbers a command takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Level {
    /// `[[net] node]`.
    Node,
    /// `[net]`.
    Network,
    /// None.
    Global,
}

impl Session {
    /// A session on `nets` networks with the SDO timeout `sdo_timeout_ms`.
    pub fn new(nets: u16, sdo_timeout_ms: u16) -> Session {
        Session {
            nets,
            default_net: 1,
            default_node: None,
            sdo_timeout_ms,
            sdo_block: false,
        }
    }

    /// Reads one line (without its `\n`).
    pub fn on_line(&mut self, line: &str) -> Action {
        let mut lx = Lexer { s: line, pos: 0 };
        if lx.at_end() {
            return Action::Reply("\r\n".into());
        }
        let mut seq = 0;
        let save = lx.pos;
        let first = lx.word().unwrap_or_default();
        if let Some(inner) = first.strip_prefix('[') {
            match inner.strip_suffix(']').and_then(parse_c_unsigned) {
                Some(s) if s <= u64::from(u32::MAX) => seq = s as u32,
                _ => return Action::Reply(format_error(0, ErrorCode::SYNTAX, None)),
            }
        } else {
            lx.pos = save;
        }
        match self.command(seq, &mut lx) {
            Ok(a) => a,
            Err(Refused(code)) => Action::Reply(format_error(seq, code, None)),
        }
    }

    fn command(&mut self, seq: u32, lx: &mut Lexer<'_>) -> Result<Action, Refused> {
        let mut numbers: Vec<u64> = Vec::new();
        let name = loop {
            let w = lx.word().ok_or(ErrorCode::SYNTAX)?;
            if !w.starts_with(|c: char| c.is_ascii_digit()) {
                break w.to_ascii_lowercase();
            }
            if numbers.len() == 2 {
                return Err(ErrorCode::SYNTAX.into());
            }
            numbers.push(parse_c_unsigned(w).ok_or(ErrorCode::SYNTAX)?);
        };
        // `r[ead] p[do]`, `w[rite] p[do]`: network commands.
        let pdo = matches!(name.as_str(), "r" | "read" | "w" | "write") && {
            let save = lx.pos;
            let next = lx.word().map(str::to_ascii_lowercase);
            let pdo = matches!(next.as_deref(), Some("p" | "pdo"));
            if !pdo {
                lx.pos = save;
            }
            pdo
        };
        let level = match name.as_str() {
            _ if pdo => Level::Network,
            "r" | "read" | "w" | "write" | "start" | "stop" | "preop" | "preoperational"
            | "reset" => Level::Node,
            "set" => Level::Network,
            n if n.starts_with("lss_") || n.starts_with("_lss_") => Level::Network,
            "help" | "info" | "login" => Level::Global,
            // Not a command: answered 100 whatever came before it.
            _ => Level::Node,
        };
        let (net, node) = match (level, numbers.as_slice()) {
            (_, []) => (None, None),
            (Level::Node, [node]) => (None, Some(*node)),
            (Level::Node, [net, node]) => (Some(*net), Some(*node)),
            (Level::Network, [net]) => (Some(*net), None),
            _ => return Err(ErrorCode::SYNTAX.into()),
        };
        if node.is_some_and(|n| n > 127) {
            return Err(ErrorCode::UNSUPPORTED_NODE.into());
        }
        if net.is_some_and(|n| n > 0xFFFF) {
            return Err(ErrorCode::UNSUPPORTED_NET.into());
        }
        let net = net.map(|n| n as u16);
        let node = node.map(|n| n as u8);
        let number = |lx: &mut Lexer<'_>, max: u64| -> Result<u64, Refused> {
            parse_c_unsigned(word(lx)?)
                .filter(|v| *v <= max)
                .ok_or(Refused(ErrorCode::SYNTAX))
        };
        let end = |lx: &mut Lexer<'_>| -> Result<(), Refused> {
            if lx.at_end() {
                Ok(())
            } else {
                Err(ErrorCode::SYNTAX.into())
            }
        };
        let action = match name.as_str() {
            _ if pdo => {
                let net = self.network(net)?;
                let n = number(lx, 512)? as u16;
                if n == 0 {
                    return Err(ErrorCode::SYNTAX.into());
                }
                let (node, pdo) = pdo_target(n).ok_or(ErrorCode::UNSUPPORTED_NODE)?;
                if name.starts_with('r') {
                    end(lx)?;
                    Action::ReadPdo {
                        seq,
                        net,
                        node,
                        pdo,
                    }
                } else {
                    // A classic PDO maps at most 64 objects (of one bit);
                    // the gateway maps whole bytes, at most 8.
                    let count = number(lx, 0x40)?;
                    let values = (0..count)
                        .map(|_| number(lx, u64::MAX))
                        .collect::<Result<Vec<_>, _>>()?;
                    end(lx)?;
                    Action::WritePdo {
                        seq,
                        net,
                        node,
                        pdo,
                        values,
                    }
                }
            }
            "r" | "read" => {
                let (net, node) = self.target(net, node, 1)?;
                let index = number(lx, 0xFFFF)? as u16;
                let sub = number(lx, 0xFF)? as u8;
                let ty = match lx.word() {
                    Some(t) => Some(
                        DataType::from_name(&t.to_ascii_lowercase()).ok_or(ErrorCode::SYNTAX)?,
                    ),
                    None => None,
                };
                end(lx)?;
                Action::Read {
                    seq,
                    net,
                    node,
                    index,
                    sub,
                    ty,
                }
            }
            "w" | "write" => {
                let (net, node) = self.target(net, node, 1)?;
                let index = number(lx, 0xFFFF)? as u16;
                let sub = number(lx, 0xFF)? as u8;
                let ty = DataType::from_name(&word(lx)?.to_ascii_lowercase())
                    .ok_or(ErrorCode::SYNTAX)?;
                let data = parse_value(ty, lx).ok_or(ErrorCode::SYNTAX)?;
                Action::Write {
                    seq,
                    net,
                    node,
                    index,
                    sub,
                    data,
                }
            }
            "start" | "stop" | "preop" | "preoperational" | "reset" => {
                let (net, node) = self.target(net, node, 0)?;
                let command = match name.as_str() {
                    "start" => Nmt::Start,
                    "stop" => Nmt::Stop,
                    "preop" | "preoperational" => Nmt::PreOperational,
                    _ => match word(lx)?.to_ascii_lowercase().as_str() {
                        "node" => Nmt::ResetNode,
                        "comm" | "communication" => Nmt::ResetCommunication,
                        _ => return Err(ErrorCode::SYNTAX.into()),
                    },
                };
                end(lx)?;
                Action::Nmt {
                    seq,
                    net,
                    node,
                    command,
                }
            }
            "set" => {
                let what = word(lx)?.to_ascii_lowercase();
                if what == "network" {
                    if net.is_some() {
                        return Err(ErrorCode::SYNTAX.into());
                    }
                    let n = number(lx, 0xFFFF)? as u16;
                    end(lx)?;
                    if n == 0 || n > self.nets {
                        return Err(ErrorCode::UNSUPPORTED_NET.into());
                    }
                    self.default_net = n;
                    return Ok(Action::Reply(format_ok(seq)));
                }
                self.network(net)?;
                match what.as_str() {
                    "node" => {
                        let n = number(lx, 127)?;
                        end(lx)?;
                        if n == 0 {
                            return Err(ErrorCode::SYNTAX.into());
                        }
                        self.default_node = Some(n as u8);
                    }
                    "sdo_timeout" => {
                        let ms = number(lx, 0xFFFF)?;
                        end(lx)?;
                        if ms == 0 {
                            return Err(ErrorCode::SYNTAX.into());
                        }
                        self.sdo_timeout_ms = ms as u16;
                    }
                    "sdo_block" => {
                        let on = number(lx, 1)?;
                        end(lx)?;
                        self.sdo_block = on == 1;
                    }
                    "events" => {
                        let on = number(lx, 1)?;
                        end(lx)?;
                        return Ok(Action::Events { seq, on: on == 1 });
                    }
                    _ => return Err(ErrorCode::NOT_SUPPORTED.into()),
                }
                Action::Reply(format_ok(seq))
            }
            "help" => {
                let topic = match lx.word().map(|w| w.to_ascii_lowercase()) {
                    None => HelpTopic::Commands,
                    Some(w) if w == "datatype" => HelpTopic::Datatypes,
                    Some(w) if w == "lss" => HelpTopic::Lss,
                    Some(_) => return Err(ErrorCode::SYNTAX.into()),
                };
                end(lx)?;
                Action::Reply(help_text(topic).into())
            }
            "info" => {
                end(lx)?;
                Action::Info { seq }
            }
            "login" => {
                let token = word(lx)?.to_string();
                end(lx)?;
                Action::Login { seq, token }
            }
            n if n.starts_with("lss_") || n == "_lss_fastscan" => {
                let net = self.network(net)?;
                let command = match n {
                    "lss_switch_glob" => Lss::SwitchGlobal(number(lx, 1)? == 1),
                    "lss_switch_sel" => {
                        let mut id = [0u32; 4];
                        for part in &mut id {
                            *part = number(lx, u32::MAX.into())? as u32;
                        }
                        Lss::SwitchSelective(id)
                    }
                    "lss_set_node" => {
                        let id = number(lx, 0xFF)? as u8;
                        if (128..255).contains(&id) || id == 0 {
                            return Err(ErrorCode::SYNTAX.into());
                        }
                        Lss::SetNode(id)
                    }
                    "lss_conf_bitrate" => {
                        let table = number(lx, 0)? as u8;
                        let index = number(lx, 9)? as u8;
                        if index == 5 {
                            return Err(ErrorCode::SYNTAX.into());
                        }
                        Lss::ConfigureBitRate { table, index }
                    }
                    "lss_activate_bitrate" => Lss::ActivateBitRate(number(lx, 0xFFFF)? as u16),
                    "lss_store" => Lss::Store,
                    "lss_inquire_addr" => Lss::InquireAddress(if lx.at_end() {
                        None
                    } else {
                        Some(number(lx, 3)? as u8)
                    }),
                    "lss_get_node" => Lss::GetNode,
                    "_lss_fastscan" => Lss::Fastscan(if lx.at_end() {
                        None
                    } else {
                        Some(number(lx, 0xFFFF)? as u16)
                    }),
                    "lss_allnodes" => {
                        let step_ms = if lx.at_end() {
                            None
                        } else {
                            Some(number(lx, 0xFFFF)? as u16)
                        };
                        let (first, store) = if lx.at_end() {
                            (2, true)
                        } else {
                            let first = number(lx, 127)? as u8;
                            let store = number(lx, 1)? == 1;
                            if first == 0 {
                                return Err(ErrorCode::SYNTAX.into());
                            }
                            (first, store)
                        };
                        if !lx.at_end() {
                            // The scan-type and identity matches.
                            return Err(ErrorCode::NOT_SUPPORTED.into());
                        }
                        Lss::AllNodes {
                            step_ms,
                            first,
                            store,
                        }
                    }
                    _ => return Err(ErrorCode::NOT_SUPPORTED.into()),
                };
                end(lx)?;
                Action::Lss { seq, net, command }
            }
            _ => return Err(ErrorCode::NOT_SUPPORTED.into()),
        };
        Ok(action)
    }

    /// The network of a command: given or the default, one that exists.
    fn network(&self, net: Option<u16>) -> Result<u16, Refused> {
        let net = net.unwrap_or(self.default_net);
        if net == 0 || net > self.nets {
            return Err(ErrorCode::UNSUPPORTED_NET.into());
        }
        Ok(net)
    }

    /// The network and node of a node command, the node at least
    /// `node_min`.
    fn target(
        &self,
        net: Option<u16>,
        node: Option<u8>,
        node_min: u8,
    ) -> Result<(u16, u8), Refused> {
        let node = node
            .or(self.default_node)
            .ok_or(ErrorCode::NO_DEFAULT_NODE)?;
        if node < node_min {
            return Err(ErrorCode::UNSUPPORTED_NODE.into());
        }
        Ok((self.network(net)?, node))
    }
}

/// Splits received bytes into lines.
#[derive(Debug)]
pub struct LineBuffer {
    buf: Vec<u8>,
    max: usize,
}

/// A line that did not end within the limit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("a command line longer than {0} bytes")]
pub struct TooLong(pub usize);

impl LineBuffer {
    /// Lines of at most `max` bytes.
    pub fn new(max: usize) -> LineBuffer {
        LineBuffer {
            buf: Vec::new(),
            max,
        }
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// The next complete line without `\n` (and `\r`), `Ok(None)` when
    /// more bytes are needed; a line that is not ASCII comes back as an
    /// empty `Err`-free `Some` of its lossy text, which the parser refuses.
    ///
    /// # Errors
    /// A line longer than the limit.
    pub fn next_line(&mut self) -> Result<Option<String>, TooLong> {
        match self.buf.iter().position(|&b| b == b'\n') {
            Some(end) if end > self.max => Err(TooLong(self.max)),
            Some(end) => {
                let mut line: Vec<u8> = self.buf.drain(..=end).collect();
                line.pop();
                if line.last() == Some(&b'\r') {
                    line.pop();
                }
                Ok(Some(String::from_utf8_lossy(&line).into_owned()))
            }
            None if self.buf.len() > self.max => Err(TooLong(self.max)),
            None => Ok(None),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn session() -> Session {
        let mut s = Session::new(2, 500);
        s.default_node = None;
        s
    }

    fn reply(s: &mut Session, line: &str) -> String {
        match s.on_line(line) {
            Action::Reply(r) => r,
            other => panic!("{line:?}: {other:?}"),
        }
    }

    #[test]
    fn pdo_commands_are_lelys_network_commands() {
        let mut s = session();
        // PDO n is PDO (n-1)%4+1 of node (n-1)/4+1.
        assert_eq!(pdo_target(1), Some((1, 1)));
        assert_eq!(pdo_target(9), Some((3, 1)));
        assert_eq!(pdo_target(12), Some((3, 4)));
        assert_eq!(pdo_target(508), Some((127, 4)));
        assert_eq!(pdo_target(509), None);
        assert_eq!(pdo_target(0), None);
        assert_eq!(
            s.on_line("[1] read pdo 9"),
            Action::ReadPdo {
                seq: 1,
                net: 1,
                node: 3,
                pdo: 1
            }
        );
        // A single number before it is the network; short forms.
        assert_eq!(
            s.on_line("[2] 2 r p 0x0A"),
            Action::ReadPdo {
                seq: 2,
                net: 2,
                node: 3,
                pdo: 2
            }
        );
        assert_eq!(
            s.on_line("[3] w pdo 9 2 0x5A 300"),
            Action::WritePdo {
                seq: 3,
                net: 1,
                node: 3,
                pdo: 1,
                values: vec![0x5A, 300]
            }
        );
        assert_eq!(
            s.on_line("[4] 1 write PDO 12 0"),
            Action::WritePdo {
                seq: 4,
                net: 1,
                node: 3,
                pdo: 4,
                values: vec![]
            }
        );
        // A node before a network command, a missing or extra value, a
        // number out of range, a network that does not exist.
        for (line, code) in [
            ("[5] 1 3 read pdo 9", "101"),
            ("[5] write pdo 9 2 1", "101"),
            ("[5] write pdo 9 1 1 2", "101"),
            ("[5] write pdo 9 65", "101"),
            ("[5] read pdo 0", "101"),
            ("[5] read pdo 513", "101"),
            ("[5] read pdo 9 1", "101"),
            ("[5] read pdo 509", "107"),
            ("[5] 3 read pdo 9", "106"),
        ] {
            assert!(
                reply(&mut s, line).starts_with(&format!("[5] ERROR:{code} #")),
                "{line}: {}",
                reply(&mut s, line)
            );
        }
        // An SDO read is still one.
        assert!(matches!(
            s.on_line("[6] 3 read 0x1000 0 u32"),
            Action::Read { node: 3, .. }
        ));
        assert_eq!(format_pdo(7, 1, &[]), "[7] 1 pdo 0\r\n");
        assert_eq!(
            format_pdo(7, 1, &[0x5A, 0x12C, u64::MAX]),
            "[7] 1 pdo 3 0x5a 0x12c 0xffffffffffffffff\r\n"
        );
    }

    #[test]
    fn reads_the_help_texts_examples() {
        // `[1] 4 read 0x1017 0 i16` (CO_gateway_ascii.h).
        let mut s = session();
        assert_eq!(
            s.on_line("[1] 4 read 0x1017 0 i16"),
            Action::Read {
                seq: 1,
                net: 1,
                node: 4,
                index: 0x1017,
                sub: 0,
                ty: Some(DataType::I16)
            }
        );
        // cocomm's README: `1 write 0x1017 0 u16 1000`, sequence added.
        assert_eq!(
            s.on_line("[2] 1 write 0x1017 0 u16 1000\r"),
            Action::Write {
                seq: 2,
                net: 1,
                node: 1,
                index: 0x1017,
                sub: 0,
                data: vec![0xE8, 0x03]
            }
        );
        assert_eq!(
            s.on_line("[3] 1 w 0x1010 1 vs save"),
            Action::Write {
                seq: 3,
                net: 1,
                node: 1,
                index: 0x1010,
                sub: 1,
                data: b"save".to_vec()
            }
        );
        assert_eq!(
            s.on_line("[4] 2 1 reset node"),
            Action::Nmt {
                seq: 4,
                net: 2,
                node: 1,
                command: Nmt::ResetNode
            }
        );
        // `r` without a type prints hex; case does not matter.
        assert_eq!(
            s.on_line("[5] 3 R 0x1018 1 # vendor"),
            Action::Read {
                seq: 5,
                net: 1,
                node: 3,
                index: 0x1018,
                sub: 1,
                ty: None
            }
        );
    }

    #[test]
    fn error_answers_are_canopends_bytes() {
        let mut s = session();
        // No default node (canopend: 105), then one.
        assert_eq!(
            reply(&mut s, "[7] read 0x1000 0 u32"),
            "[7] ERROR:105 #No default node set.\r\n"
        );
        assert_eq!(reply(&mut s, "[8] set node 3"), "[8] OK\r\n");
        assert!(matches!(
            s.on_line("[9] read 0x1000 0 u32"),
            Action::Read {
                node: 3,
                net: 1,
                ..
            }
        ));
        assert_eq!(
            reply(&mut s, "[10] 1 bogus"),
            "[10] ERROR:100 #Request not supported.\r\n"
        );
        assert_eq!(
            reply(&mut s, "[11] 3 read 0x1000"),
            "[11] ERROR:101 #Syntax error.\r\n"
        );
        assert_eq!(
            reply(&mut s, "[12] 128 start"),
            "[12] ERROR:107 #Unsupported node.\r\n"
        );
        assert_eq!(
            reply(&mut s, "[13] 3 1 2 start"),
            "[13] ERROR:101 #Syntax error.\r\n"
        );
        assert_eq!(
            reply(&mut s, "[14] 3 3 start"),
            "[14] ERROR:106 #Unsupported net.\r\n"
        );
        assert_eq!(
            reply(&mut s, "[15] 3 write 0x2000 0 u8 256"),
            "[15] ERROR:101 #Syntax error.\r\n"
        );
        assert_eq!(
            reply(&mut s, "[16] 3 write 0x2000 0 u8 1 2"),
            "[16] ERROR:101 #Syntax error.\r\n"
        );
        assert_eq!(
            reply(&mut s, "[17] set bogus 1"),
            "[17] ERROR:100 #Request not supported.\r\n"
        );
        assert_eq!(
            reply(&mut s, "[x] help"),
            "[0] ERROR:101 #Syntax error.\r\n"
        );
        // Reads need a node of 1..=127; NMT takes 0 (every node).
        assert_eq!(
            reply(&mut s, "[18] 0 read 0x1000 0"),
            "[18] ERROR:107 #Unsupported node.\r\n"
        );
        assert!(matches!(
            s.on_line("[19] 0 preop"),
            Action::Nmt {
                node: 0,
                command: Nmt::PreOperational,
                ..
            }
        ));
        // Empty and comment lines: an empty answer.
        assert_eq!(reply(&mut s, ""), "\r\n");
        assert_eq!(reply(&mut s, "  # nothing"), "\r\n");
        assert_eq!(
            format_error(3, ErrorCode::INTERNAL_STATE, Some("needs role\nengineer")),
            "[3] ERROR:102 #Request not processed due to internal state. needs role engineer\r\n"
        );
    }

    #[test]
    fn sdo_aborts_print_the_code_in_hex() {
        assert_eq!(
            format_abort(
                4,
                0x0602_0000,
                "object does not exist in the object dictionary"
            ),
            "[4] ERROR:0x06020000 #Object does not exist in the object dictionary.\r\n"
        );
    }

    #[test]
    fn the_prefix_and_the_network_commands() {
        let mut s = session();
        // A line without a sequence is sequence 0 (canopend's stdio).
        assert!(matches!(
            s.on_line("4 start"),
            Action::Nmt {
                seq: 0,
                node: 4,
                ..
            }
        ));
        assert!(matches!(
            s.on_line("[0x10] 4 stop"),
            Action::Nmt {
                seq: 16,
                command: Nmt::Stop,
                ..
            }
        ));
        assert_eq!(reply(&mut s, "[1] set network 2"), "[1] OK\r\n");
        assert!(matches!(
            s.on_line("[2] 5 reset comm"),
            Action::Nmt {
                net: 2,
                node: 5,
                command: Nmt::ResetCommunication,
                ..
            }
        ));
        assert_eq!(
            reply(&mut s, "[3] set network 3"),
            "[3] ERROR:106 #Unsupported net.\r\n"
        );
        assert_eq!(reply(&mut s, "[4] 1 set sdo_timeout 1000"), "[4] OK\r\n");
        assert_eq!(s.sdo_timeout_ms, 1000);
        assert_eq!(reply(&mut s, "[5] set sdo_block 1"), "[5] OK\r\n");
        assert!(s.sdo_block);
        assert_eq!(
            reply(&mut s, "[6] set sdo_block 2"),
            "[6] ERROR:101 #Syntax error.\r\n"
        );
        assert_eq!(
            s.on_line("[7] 1 lss_switch_sel 0x360 2 3 0x10"),
            Action::Lss {
                seq: 7,
                net: 1,
                command: Lss::SwitchSelective([0x360, 2, 3, 16])
            }
        );
        assert_eq!(
            s.on_line("[8] lss_inquire_addr"),
            Action::Lss {
                seq: 8,
                net: 2,
                command: Lss::InquireAddress(None)
            }
        );
        assert_eq!(
            reply(&mut s, "[9] lss_set_node 128"),
            "[9] ERROR:101 #Syntax error.\r\n"
        );
        assert_eq!(
            reply(&mut s, "[10] lss_conf_bitrate 0 5"),
            "[10] ERROR:101 #Syntax error.\r\n"
        );
        assert_eq!(
            s.on_line("[11] lss_allnodes"),
            Action::Lss {
                seq: 11,
                net: 2,
                command: Lss::AllNodes {
                    step_ms: None,
                    first: 2,
                    store: true
                }
            }
        );
        assert_eq!(
            s.on_line("[11] lss_allnodes 50 10 0"),
            Action::Lss {
                seq: 11,
                net: 2,
                command: Lss::AllNodes {
                    step_ms: Some(50),
                    first: 10,
                    store: false
                }
            }
        );
        assert_eq!(
            reply(&mut s, "[11] lss_allnodes 50 10 0 0 0x360 1 0 1 0 1 0"),
            "[11] ERROR:100 #Request not supported.\r\n"
        );
        assert_eq!(
            s.on_line("[12] set events 1"),
            Action::Events { seq: 12, on: true }
        );
        assert_eq!(
            s.on_line("[13] login s3cret"),
            Action::Login {
                seq: 13,
                token: "s3cret".into()
            }
        );
        assert_eq!(
            reply(&mut s, "[14] 1 login s3cret"),
            "[14] ERROR:101 #Syntax error.\r\n"
        );
        assert!(reply(&mut s, "[15] help lss").starts_with("\n"));
        assert!(reply(&mut s, "[15] help").ends_with("\r\n"));
    }

    fn write_data(s: &mut Session, ty: &str, value: &str) -> Option<Vec<u8>> {
        match s.on_line(&format!("[1] 3 w 0x2000 0 {ty} {value}")) {
            Action::Write { data, .. } => Some(data),
            _ => None,
        }
    }

    #[test]
    fn values_are_read_as_canopend_reads_them() {
        let mut s = session();
        let w = |s: &mut Session, ty, v| write_data(s, ty, v);
        assert_eq!(w(&mut s, "b", "1"), Some(vec![1]));
        assert_eq!(w(&mut s, "i8", "-128"), Some(vec![0x80]));
        assert_eq!(w(&mut s, "i8", "128"), None);
        assert_eq!(w(&mut s, "i16", "-0x10"), Some(vec![0xF0, 0xFF]));
        assert_eq!(w(&mut s, "i32", "-2"), Some(vec![0xFE, 0xFF, 0xFF, 0xFF]));
        assert_eq!(w(&mut s, "i64", "-1"), Some(vec![0xFF; 8]));
        assert_eq!(w(&mut s, "u8", "010"), Some(vec![8]), "octal, as strtoul");
        assert_eq!(w(&mut s, "u16", "0xBEEF"), Some(vec![0xEF, 0xBE]));
        assert_eq!(w(&mut s, "u32", "-1"), None);
        assert_eq!(
            w(&mut s, "x32", "0x12345678"),
            Some(vec![0x78, 0x56, 0x34, 0x12])
        );
        assert_eq!(
            w(&mut s, "u64", "18446744073709551615"),
            Some(vec![0xFF; 8])
        );
        assert_eq!(w(&mut s, "r32", "1.5"), Some(vec![0, 0, 0xC0, 0x3F]));
        assert_eq!(w(&mut s, "r64", "-2"), Some((-2f64).to_le_bytes().to_vec()));
        assert_eq!(
            w(&mut s, "vs", "\"a \"\"b\"\" #c\""),
            Some(b"a \"b\" #c".to_vec())
        );
        assert_eq!(w(&mut s, "vs", "\"open"), None);
        assert_eq!(w(&mut s, "vs", "\"\""), None, "empty, as canopend");
        assert_eq!(w(&mut s, "os", "AAEC/w=="), Some(vec![0, 1, 2, 0xFF]));
        assert_eq!(w(&mut s, "d", "AAEC/w"), Some(vec![0, 1, 2, 0xFF]));
        assert_eq!(w(&mut s, "d", "A"), None);
        assert_eq!(w(&mut s, "hex", "01 0203 a"), Some(vec![1, 2, 3, 0xA]));
        assert_eq!(w(&mut s, "hex", "012"), None);
        assert_eq!(w(&mut s, "t", "1"), None, "time types are not supported");
    }

    fn text(ty: DataType, data: &[u8]) -> String {
        format_value(1, Some(ty), data)
    }

    #[test]
    fn values_are_printed_as_canopend_prints_them() {
        use DataType::*;
        assert_eq!(text(U16, &[0xE8, 0x03]), "[1] 1000\r\n");
        assert_eq!(text(Bool, &[1]), "[1] 1\r\n");
        assert_eq!(text(I8, &[0xFF]), "[1] -1\r\n");
        assert_eq!(text(I16, &[0x00, 0x80]), "[1] -32768\r\n");
        assert_eq!(text(I32, &[0xFE, 0xFF, 0xFF, 0xFF]), "[1] -2\r\n");
        assert_eq!(text(I64, &[0xFF; 8]), "[1] -1\r\n");
        assert_eq!(text(U32, &[0x78, 0x56, 0x34, 0x12]), "[1] 305419896\r\n");
        assert_eq!(text(U64, &[0xFF; 8]), "[1] 18446744073709551615\r\n");
        assert_eq!(text(X8, &[0x0A]), "[1] 0x0A\r\n");
        assert_eq!(text(X16, &[0x34, 0x12]), "[1] 0x1234\r\n");
        assert_eq!(text(X32, &[0x92, 0x01, 0x02, 0x00]), "[1] 0x00020192\r\n");
        assert_eq!(
            text(X64, &[1, 0, 0, 0, 0, 0, 0, 0]),
            "[1] 0x0000000000000001\r\n"
        );
        assert_eq!(text(R32, &1.5f32.to_le_bytes()), "[1] 1.5\r\n");
        assert_eq!(text(R64, &0.1f64.to_le_bytes()), "[1] 0.1\r\n");
        assert_eq!(text(VisibleString, b"a\"b\0\r"), "[1] \"a\"\"b\"\r\n");
        assert_eq!(text(OctetString, &[0, 1, 2, 0xFF]), "[1] AAEC/w==\r\n");
        assert_eq!(text(Domain, b"abc"), "[1] YWJj\r\n");
        assert_eq!(text(UnicodeString, b"ab"), "[1] YWI=\r\n");
        assert_eq!(text(Hex, &[0x12, 0xAB]), "[1] 12 AB\r\n");
        // Another size than the type's: hex, as canopend.
        assert_eq!(text(U32, &[0x12, 0xAB]), "[1] 12 AB\r\n");
        assert_eq!(format_value(2, None, &[1, 2, 3]), "[2] 01 02 03\r\n");
        assert_eq!(format_value(2, None, &[]), "[2] \r\n");
    }

    #[test]
    fn reals_print_as_printf_g() {
        for (x, g) in [
            (0.0, "0"),
            (1.0, "1"),
            (100000.0, "100000"),
            (1_000_000.0, "1e+06"),
            (123456789.0, "1.23457e+08"),
            (0.0001, "0.0001"),
            (0.00001234, "1.234e-05"),
            (-3.25, "-3.25"),
            (999999.5, "1e+06"),
            (2.5e-300, "2.5e-300"),
            (f64::INFINITY, "inf"),
        ] {
            assert_eq!(format_g(x), g, "{x}");
        }
        // An r32 prints its float as a double, as canopend's %g does.
        assert_eq!(format_g(f64::from(0.1f32)), "0.1");
    }

    #[test]
    fn event_lines_as_lely_prints_them() {
        assert_eq!(format_event(1, 5, &Event::BootUp), "1 5 BOOT_UP\r\n");
        assert_eq!(
            format_event(
                1,
                3,
                &Event::Emcy {
                    code: 0x8110,
                    register: 0x11,
                    manufacturer: [0, 1, 2, 3, 255]
                }
            ),
            "1 3 EMCY 8110 11 0 1 2 3 255\r\n"
        );
        assert_eq!(
            format_event(2, 4, &Event::Lost { guarding: false }),
            "2 4 ERROR 203 (Heartbeat lost.)\r\n"
        );
        assert_eq!(
            format_event(2, 4, &Event::HeartbeatStarted),
            "2 4 ERROR 202 (Heartbeat started.)\r\n"
        );
    }

    #[test]
    fn lss_answers() {
        assert_eq!(
            format_lss_address(3, [0x360, 1, 2, 0xDEADBEEF]),
            "[3] 0x00000360 0x00000001 0x00000002 0xDEADBEEF\r\n"
        );
        assert_eq!(format_lss_node_id(4, 5), "[4] 0x05\r\n");
        assert_eq!(format_lss_value(4, 0x360), "[4] 0x00000360\r\n");
    }

    #[test]
    fn lines_split_at_newlines_within_the_limit() {
        let mut b = LineBuffer::new(16);
        b.push(b"[1] help\r\n[2] 3 st");
        assert_eq!(b.next_line(), Ok(Some("[1] help".into())));
        assert_eq!(b.next_line(), Ok(None));
        b.push(b"art\n");
        assert_eq!(b.next_line(), Ok(Some("[2] 3 start".into())));
        b.push(&[b'x'; 17]);
        assert_eq!(b.next_line(), Err(TooLong(16)));
    }
}
