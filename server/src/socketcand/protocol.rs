//! The socketcand protocol without I/O: splitting the byte stream into
//! `< … >` elements ([`Deframer`]), reading the commands a client sends
//! ([`parse`]), the session's modes ([`Session`]) and the lines the gateway
//! writes ([`format_frame`], [`format_error`]).
//!
//! Source of truth: `doc/protocol.md` of linux-can/socketcand, and its
//! implementation (`src/socketcand.c`, `state_nobus.c`, `state_bcm.c`,
//! `state_raw.c`) where the two differ. What this module settles:
//!
//! - **Framing.** A command is everything from a `<` to the next `>`;
//!   bytes outside elements are dropped (as `receive_command` in
//!   socketcand.c does), so `< a >< b >` and `< a >\n< b >` are two
//!   commands. One `<` … `>` per command: an element with a `<` inside
//!   (`< < send 1A2 1 00 >`, `< open ca< echo >`) is malformed, answered
//!   with `< error … >` and not executed (socketcand would read
//!   `open ca< echo`), so that a command cut off or nested by a broken
//!   client never acts. Words are separated by any run of ASCII whitespace
//!   (socketcand's `sscanf` does the same). An element longer than the
//!   limit is an error that ends the connection.
//! - **`< open bus [token] >`.** socketcand reads the bus with `sscanf("%s")`
//!   and ignores further words; the gateway reads a second word as the
//!   client's token (python-can passes `channel` verbatim, so
//!   `channel="can0 TOKEN"` gives `< open can0 TOKEN >`). More words are an
//!   error.
//! - **`< send id len data… >`.** As socketcand: the id in hex, extended
//!   when it is written with exactly 8 digits, standard otherwise; `len`
//!   in decimal (python-can writes it in hex, the same for 0..=8); exactly
//!   `len` data bytes of one or two hex digits. Classic frames only, as in
//!   socketcand (remote frames cannot be sent: the protocol has no way to
//!   say so). socketcand ignores a malformed `send` silently; the gateway
//!   answers `< error … >`.
//! - **CAN FD.** Not in socketcand's master branch; its `rawmode-canfd`
//!   branch (commit 7f894ba, linux-can/socketcand#12) adds
//!   `< sendfd id len data… >` (len a CAN FD length, 0..=64) and reports FD
//!   frames as `< fdframe id secs.usecs data >`. The gateway speaks those,
//!   without BRS/ESI (the branch carries no flags either).
//! - **Frames out** (raw mode): `< frame 123 23.424242 1A220344 >`: the id
//!   as `%03X` or `%08X`, the timestamp as seconds and six digits of
//!   microseconds, the data as upper-case hex without spaces (socketcand's
//!   `state_raw.c`). Remote frames are not reported (socketcand's
//!   `state_raw.c` leaves them out too).
//! - **Modes.** `< hi >` greets; after `open` the session is in BCM mode,
//!   where `send` and `echo` work; `< rawmode >` starts the frame feed,
//!   `< bcmmode >` stops it; both answer `< ok >` (also when already in
//!   that mode, where socketcand says "unknown command"). In BCM mode the
//!   jobs `add`, `update`, `delete`, `filter`, `subscribe` and
//!   `unsubscribe` run as [`super::bcm`] describes (silent on success, as
//!   socketcand; `< error … >` when malformed or refused); in raw mode
//!   they are answered with `< error … >` naming `< bcmmode >`.
//!   `muxfilter`, `< controlmode >`, `< isotpmode >` and the bus
//!   configuration commands (`< can0 B … >`, `< can0 C … >`) are answered
//!   with `< error … >` naming them as not supported. `< echo >` is
//!   answered with itself in every mode.

use cangate_can::{CanId, Frame};
use std::fmt::Write as _;

/// Default longest element (`<` to `>`), in bytes: an `sendfd` with 64
/// data bytes written with spaces, an extended id and a long token fit.
pub const DEFAULT_MAX_ELEMENT: usize = 1024;

/// Splits received bytes into `< … >` elements.
#[derive(Debug)]
pub struct Deframer {
    buf: Vec<u8>,
    max: usize,
}

/// An element that did not end within the limit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("a command longer than {0} bytes")]
pub struct TooLong(pub usize);

impl Deframer {
    /// A deframer for elements of at most `max` bytes (both brackets
    /// included).
    pub fn new(max: usize) -> Self {
        Deframer {
            buf: Vec::new(),
            max: max.max(2),
        }
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// The next complete element, brackets included; `Ok(None)` when more
    /// bytes are needed.
    ///
    /// # Errors
    /// When an element has gone on for more than the limit without `>`.
    pub fn next_element(&mut self) -> Result<Option<Vec<u8>>, TooLong> {
        // Nothing before a '<' can ever be a command.
        match self.buf.iter().position(|&b| b == b'<') {
            Some(start) => {
                self.buf.drain(..start);
            }
            None => {
                self.buf.clear();
                return Ok(None);
            }
        }
        match self.buf.iter().position(|&b| b == b'>') {
            Some(end) => {
                // A '<' inside stays in the element, which [`parse`] then
                // refuses as malformed: one '<' … '>' per command.
                if end >= self.max {
                    return Err(TooLong(self.max));
                }
                let element: Vec<u8> = self.buf.drain(..=end).collect();
                Ok(Some(element))
            }
            None if self.buf.len() > self.max => Err(TooLong(self.max)),
            None => Ok(None),
        }
    }

    /// Bytes buffered (for tests).
    pub fn buffered(&self) -> usize {
        self.buf.len()
    }
}

/// A command from the client.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Command {
    /// `< open bus [token] >`.
    Open {
        /// The bus name.
        bus: String,
        /// The client's token, if it gave one.
        token: Option<String>,
    },
    /// `< rawmode >`.
    RawMode,
    /// `< bcmmode >`.
    BcmMode,
    /// `< echo >`.
    Echo,
    /// `< send … >` or `< sendfd … >`.
    Send(Frame),
    /// A BCM job or receive operation.
    Bcm(BcmCommand),
    /// A socketcand command the gateway does not implement (`muxfilter`,
    /// control and ISO-TP modes, bus configuration).
    NotSupported(&'static str),
}

/// A BCM mode command (see [`super::bcm`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum BcmCommand {
    /// `< add secs usecs id dlc data… >`.
    Add {
        /// The interval.
        interval: std::time::Duration,
        /// The frame.
        frame: Frame,
    },
    /// `< update id dlc data… >`.
    Update(Frame),
    /// `< delete id >`.
    Delete(CanId),
    /// `< subscribe secs usecs id >` (`mask` `None`) or
    /// `< filter secs usecs id dlc mask… >`.
    Receive {
        /// The identifier.
        id: CanId,
        /// The content mask of a filter.
        mask: Option<Vec<u8>>,
        /// The throttle interval (zero: none).
        throttle: std::time::Duration,
    },
    /// `< unsubscribe id >`.
    Unsubscribe(CanId),
}

/// Why a command was not understood; the text goes into `< error … >`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ParseError {
    /// Not a socketcand command at all.
    #[error("unknown command")]
    Unknown,
    /// A known command with bad arguments.
    #[error("{0}")]
    Syntax(String),
}

/// The BCM mode commands of socketcand the gateway does not implement.
const BCM_COMMANDS: &[&str] = &["muxfilter"];

/// Reads one element (brackets included) as a command.
///
/// # Errors
/// Unknown commands and bad arguments, with a message for the client.
pub fn parse(element: &[u8]) -> Result<Command, ParseError> {
    let text = std::str::from_utf8(element)
        .ok()
        .filter(|t| t.is_ascii())
        .ok_or_else(|| ParseError::Syntax("a command must be ASCII text".into()))?;
    let inner = text
        .strip_prefix('<')
        .and_then(|t| t.strip_suffix('>'))
        .ok_or(ParseError::Unknown)?;
    if inner.contains('<') {
        return Err(ParseError::Syntax(
            "malformed command: a second opening bracket before the closing one \
             (one bracket pair per command, nothing nested)"
                .into(),
        ));
    }
    let words: Vec<&str> = inner.split_ascii_whitespace().collect();
    let Some((&name, args)) = words.split_first() else {
        return Err(ParseError::Unknown);
    };
    let no_args = |c: Command| {
        if args.is_empty() {
            Ok(c)
        } else {
            Err(ParseError::Syntax(format!("{name} takes no arguments")))
        }
    };
    match name {
        "open" => match args {
            [bus] => Ok(Command::Open {
                bus: (*bus).to_string(),
                token: None,
            }),
            [bus, token] => Ok(Command::Open {
                bus: (*bus).to_string(),
                token: Some((*token).to_string()),
            }),
            [] => Err(ParseError::Syntax("open needs a bus name".into())),
            _ => Err(ParseError::Syntax(
                "open takes a bus name and optionally a token".into(),
            )),
        },
        "rawmode" => no_args(Command::RawMode),
        "bcmmode" => no_args(Command::BcmMode),
        "echo" => no_args(Command::Echo),
        "controlmode" => no_args(Command::NotSupported("controlmode")),
        "isotpmode" => no_args(Command::NotSupported("isotpmode")),
        "send" => parse_send("send", args, false).map(Command::Send),
        "sendfd" => parse_send("sendfd", args, true).map(Command::Send),
        "add" => match args {
            [secs, usecs, frame @ ..] => Ok(Command::Bcm(BcmCommand::Add {
                interval: interval("add", secs, usecs)?,
                frame: parse_send("add", frame, false)?,
            })),
            _ => Err(syntax("add needs secs usecs id dlc data…")),
        },
        "update" => parse_send("update", args, false).map(|f| Command::Bcm(BcmCommand::Update(f))),
        "delete" => match args {
            [id] => Ok(Command::Bcm(BcmCommand::Delete(parse_id("delete", id)?))),
            _ => Err(syntax("delete needs an id")),
        },
        "unsubscribe" => match args {
            [id] => Ok(Command::Bcm(BcmCommand::Unsubscribe(parse_id(
                "unsubscribe",
                id,
            )?))),
            _ => Err(syntax("unsubscribe needs an id")),
        },
        "subscribe" => match args {
            [secs, usecs, id] => Ok(Command::Bcm(BcmCommand::Receive {
                id: parse_id("subscribe", id)?,
                mask: None,
                throttle: interval("subscribe", secs, usecs)?,
            })),
            _ => Err(syntax("subscribe needs secs usecs id")),
        },
        "filter" => match args {
            [secs, usecs, frame @ ..] => {
                let mask = parse_send("filter", frame, false)?;
                Ok(Command::Bcm(BcmCommand::Receive {
                    id: mask.id(),
                    mask: Some(mask.data().to_vec()),
                    throttle: interval("filter", secs, usecs)?,
                }))
            }
            _ => Err(syntax("filter needs secs usecs id dlc mask…")),
        },
        "statistics" => Ok(Command::NotSupported("statistics")),
        "isotpconf" => Ok(Command::NotSupported("isotpconf")),
        "sendpdu" => Ok(Command::NotSupported("sendpdu")),
        _ => {
            if let Some(c) = BCM_COMMANDS.iter().find(|c| **c == name) {
                return Ok(Command::NotSupported(c));
            }
            // `< can0 B … >` / `< can0 C … >`: bus configuration.
            match args.first() {
                Some(&"B") => Ok(Command::NotSupported("bittiming (B)")),
                Some(&"C") => Ok(Command::NotSupported("controlmode (C)")),
                _ => Err(ParseError::Unknown),
            }
        }
    }
}

fn syntax(message: impl Into<String>) -> ParseError {
    ParseError::Syntax(message.into())
}

/// `secs usecs` of a BCM command (decimal, as socketcand's `%llu`).
fn interval(cmd: &str, secs: &str, usecs: &str) -> Result<std::time::Duration, ParseError> {
    let number = |w: &str| {
        (!w.is_empty() && w.len() <= 12 && w.bytes().all(|b| b.is_ascii_digit()))
            .then(|| w.parse::<u64>().ok())
            .flatten()
    };
    match (number(secs), number(usecs)) {
        (Some(s), Some(u)) => {
            Ok(std::time::Duration::from_secs(s) + std::time::Duration::from_micros(u))
        }
        _ => Err(syntax(format!(
            "{cmd}: the interval must be decimal seconds and microseconds"
        ))),
    }
}

/// A hexadecimal identifier, extended when written with 8 digits (as
/// socketcand reads it).
fn parse_id(cmd: &str, id: &str) -> Result<CanId, ParseError> {
    if id.is_empty() || id.len() > 8 || !id.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(syntax(format!("{cmd}: bad identifier {}", clip(id))));
    }
    let raw = u32::from_str_radix(id, 16).map_err(|_| syntax(format!("{cmd}: bad identifier")))?;
    CanId::new(raw, id.len() == 8).map_err(|e| syntax(format!("{cmd}: {e}")))
}

/// `id len data…` of `send` (classic) or `sendfd` (CAN FD), and of the
/// BCM commands that carry a frame (`cmd` names the command).
fn parse_send(cmd: &str, args: &[&str], fd: bool) -> Result<Frame, ParseError> {
    let [id, len, data @ ..] = args else {
        return Err(syntax(format!("{cmd} needs an id and a length")));
    };
    let can_id = parse_id(cmd, id)?;
    let len: usize = if len.len() <= 2 && len.bytes().all(|b| b.is_ascii_digit()) {
        len.parse().unwrap_or(usize::MAX)
    } else {
        usize::MAX
    };
    let max = if fd { 64 } else { 8 };
    if len > max {
        return Err(syntax(format!(
            "{cmd}: the length must be a decimal number 0..={max}{}",
            if fd { "" } else { " (sendfd for CAN FD)" }
        )));
    }
    if data.len() != len {
        return Err(syntax(format!(
            "{cmd}: length {len} but {} data bytes",
            data.len()
        )));
    }
    let mut bytes = Vec::with_capacity(len);
    for d in data {
        if d.is_empty() || d.len() > 2 || !d.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(syntax(format!("{cmd}: bad data byte {}", clip(d))));
        }
        bytes.push(u8::from_str_radix(d, 16).unwrap_or(0));
    }
    let frame = if fd {
        Frame::new_fd(can_id, &bytes, false, false)
    } else {
        Frame::new(can_id, &bytes)
    };
    frame.map_err(|e| syntax(format!("{cmd}: {e}")))
}

/// At most 16 characters of a client's word, for an error message.
fn clip(s: &str) -> String {
    let mut out: String = s.chars().take(16).collect();
    if s.len() > out.len() {
        out.push('…');
    }
    out
}

/// The line for a frame in raw mode: `< frame … >`, `< fdframe … >` for a
/// CAN FD frame; none for remote and error frames.
pub fn format_frame(frame: &Frame) -> Option<String> {
    if frame.is_remote() || frame.is_error() {
        return None;
    }
    let ns = frame.timestamp().as_nanos();
    let (secs, usecs) = (ns / 1_000_000_000, (ns % 1_000_000_000) / 1000);
    let kind = if frame.is_fd() { "fdframe" } else { "frame" };
    let mut line = String::with_capacity(40 + 2 * frame.data().len());
    let _ = if frame.is_extended() {
        write!(line, "< {kind} {:08X} {secs}.{usecs:06} ", frame.raw_id())
    } else {
        write!(line, "< {kind} {:03X} {secs}.{usecs:06} ", frame.raw_id())
    };
    for b in frame.data() {
        let _ = write!(line, "{b:02X}");
    }
    line.push_str(" >");
    Some(line)
}

/// `< error message >`; the message's brackets (which would end the
/// element early) and control characters become spaces.
pub fn format_error(message: &str) -> String {
    let clean: String = message
        .chars()
        .map(|c| {
            if c == '<' || c == '>' || c.is_control() {
                ' '
            } else {
                c
            }
        })
        .collect();
    format!("< error {} >", clean.trim())
}

/// The session's mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Connected, no bus open yet.
    NoBus,
    /// A bus is open; no frame feed (socketcand's default after `open`).
    Bcm,
    /// A bus is open and every frame is reported.
    Raw,
}

/// What the connection has to do for one element.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Action {
    /// Write this line.
    Reply(String),
    /// Authorise and open the bus; then call [`Session::opened`] (and
    /// write `< ok >`) or write the refusal and close.
    Open {
        /// The bus.
        bus: String,
        /// The token given.
        token: Option<String>,
    },
    /// Send the frame as this client (role, budget), then nothing, or an
    /// `< error … >` line when refused.
    Send(Frame),
    /// Start (true) or stop the frame feed, then write `< ok >`.
    Feed(bool),
    /// A BCM job or receive operation for the session's [`super::bcm::Bcm`].
    Bcm(BcmCommand),
    /// Write this line and close the connection.
    Close(String),
}

/// The mode machine of one connection.
#[derive(Debug)]
pub struct Session {
    mode: Mode,
}

impl Default for Session {
    fn default() -> Self {
        Self::new()
    }
}

impl Session {
    /// A new connection (after `< hi >`).
    pub fn new() -> Self {
        Session { mode: Mode::NoBus }
    }

    /// The current mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// The bus was opened: BCM mode.
    pub fn opened(&mut self) {
        self.mode = Mode::Bcm;
    }

    /// What to do with one element.
    pub fn on_element(&mut self, element: &[u8]) -> Action {
        let command = match parse(element) {
            Ok(c) => c,
            // As socketcand: an unknown command is answered and the
            // connection goes on.
            Err(e) => return Action::Reply(format_error(&e.to_string())),
        };
        match (self.mode, command) {
            (_, Command::Echo) => Action::Reply("< echo >".into()),
            (Mode::NoBus, Command::Open { bus, token }) => Action::Open { bus, token },
            (_, Command::Open { .. }) => Action::Reply(format_error(
                "a bus is open already: one bus per connection",
            )),
            (_, Command::NotSupported(what @ ("bittiming (B)" | "controlmode (C)"))) => {
                // socketcand closes after a failed bus configuration.
                Action::Close(format_error(&format!(
                    "{what} is not supported: the gateway configures its buses itself"
                )))
            }
            (Mode::NoBus, _) => Action::Reply(format_error("open a bus first (open BUS)")),
            (_, Command::RawMode) => {
                self.mode = Mode::Raw;
                Action::Feed(true)
            }
            (_, Command::BcmMode) => {
                self.mode = Mode::Bcm;
                Action::Feed(false)
            }
            (_, Command::Send(frame)) => Action::Send(frame),
            (Mode::Bcm, Command::Bcm(c)) => Action::Bcm(c),
            (_, Command::Bcm(_)) => Action::Reply(format_error(
                "BCM jobs and subscriptions work in BCM mode (send bcmmode first)",
            )),
            (_, Command::NotSupported(what)) => {
                Action::Reply(format_error(&format!("{what} is not supported by cangate")))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cangate_can::Timestamp;

    fn id(raw: u32, ext: bool) -> CanId {
        CanId::new(raw, ext).unwrap()
    }

    fn elements(input: &[u8]) -> Vec<String> {
        let mut d = Deframer::new(DEFAULT_MAX_ELEMENT);
        d.push(input);
        let mut out = Vec::new();
        while let Some(e) = d.next_element().unwrap() {
            out.push(String::from_utf8(e).unwrap());
        }
        out
    }

    #[test]
    fn deframer_splits_elements_and_drops_what_is_between() {
        assert_eq!(
            elements(b"< open can0 >< rawmode >"),
            ["< open can0 >", "< rawmode >"]
        );
        assert_eq!(
            elements(b"junk< echo >\r\n  < send 123 0 >trailing"),
            ["< echo >", "< send 123 0 >"]
        );
        // A '<' inside stays in the element (parse refuses it).
        assert_eq!(elements(b"< open ca< echo >"), ["< open ca< echo >"]);
        assert_eq!(
            elements(b"< < < send 1A2 1 00 > > >"),
            ["< < < send 1A2 1 00 >"]
        );
        // Split across reads.
        let mut d = Deframer::new(64);
        d.push(b"< sen");
        assert_eq!(d.next_element(), Ok(None));
        d.push(b"d 1 0 >");
        assert_eq!(d.next_element(), Ok(Some(b"< send 1 0 >".to_vec())));
        assert_eq!(d.buffered(), 0);
        // Bytes without '<' are dropped at once, not kept.
        d.push(b"xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx");
        assert_eq!(d.next_element(), Ok(None));
        assert_eq!(d.buffered(), 0);
    }

    #[test]
    fn deframer_refuses_an_endless_element() {
        let mut d = Deframer::new(16);
        d.push(b"< 0123456789abcdef");
        assert_eq!(d.next_element(), Err(TooLong(16)));
        let mut d = Deframer::new(16);
        d.push(b"< 0123456789abcdef >");
        assert_eq!(d.next_element(), Err(TooLong(16)));
        let mut d = Deframer::new(16);
        d.push(b"< 0123456789ab >");
        assert!(d.next_element().unwrap().is_some());
    }

    #[test]
    fn protocol_md_send_examples() {
        // doc/protocol.md: "< send 123 0 >" (ID 123, no data) and
        // "< send 1AAAAAAA 2 1 f1 >" (extended, 0x01 0xF1).
        assert_eq!(
            parse(b"< send 123 0 >"),
            Ok(Command::Send(Frame::new(id(0x123, false), &[]).unwrap()))
        );
        assert_eq!(
            parse(b"< send 1AAAAAAA 2 1 f1 >"),
            Ok(Command::Send(
                Frame::new(id(0x1AAA_AAAA, true), &[0x01, 0xF1]).unwrap()
            ))
        );
    }

    #[test]
    fn python_can_send_lines() {
        // python-can 4.6.1 writes "< send {id:03X|08X} {len:X} {b:x} ... >":
        // two spaces before '>' without data; lower-case unpadded bytes.
        assert_eq!(
            parse(b"< send 7FF 0  >"),
            Ok(Command::Send(Frame::new(id(0x7FF, false), &[]).unwrap()))
        );
        assert_eq!(
            parse(b"< send 00000001 8 0 1 a 1f ff 10 2 3 >"),
            Ok(Command::Send(
                Frame::new(id(1, true), &[0, 1, 0xa, 0x1f, 0xff, 0x10, 2, 3]).unwrap()
            ))
        );
        assert_eq!(
            parse(b"< send 601 8 40 8 10 0 0 0 0 0 >"),
            Ok(Command::Send(
                Frame::new(id(0x601, false), &[0x40, 8, 0x10, 0, 0, 0, 0, 0]).unwrap()
            ))
        );
    }

    #[test]
    fn sendfd_as_in_the_rawmode_canfd_branch() {
        let data: Vec<u8> = (0..12).collect();
        let line = format!(
            "< sendfd 123 12 {} >",
            data.iter()
                .map(|b| format!("{b:x}"))
                .collect::<Vec<_>>()
                .join(" ")
        );
        assert_eq!(
            parse(line.as_bytes()),
            Ok(Command::Send(
                Frame::new_fd(id(0x123, false), &data, false, false).unwrap()
            ))
        );
        // 9 is no CAN FD length.
        assert!(matches!(
            parse(b"< sendfd 123 9 1 2 3 4 5 6 7 8 9 >"),
            Err(ParseError::Syntax(m)) if m.contains("not a valid CAN FD length")
        ));
    }

    /// Nested or cut-off elements never act: a `send` inside another `<`
    /// sends nothing.
    #[test]
    fn nested_elements_are_refused_and_never_executed() {
        for input in [
            &b"< < < send 1A2 1 00 > > >"[..],
            b"< < send 1A2 1 00 >",
            b"< open ca< send 1A2 1 00 >",
            b"<< echo >",
        ] {
            let mut session = Session::new();
            session.opened();
            let mut d = Deframer::new(DEFAULT_MAX_ELEMENT);
            d.push(input);
            let mut actions = Vec::new();
            while let Some(e) = d.next_element().unwrap() {
                actions.push(session.on_element(&e));
            }
            assert_eq!(actions.len(), 1, "{}", String::from_utf8_lossy(input));
            match &actions[0] {
                Action::Reply(line) => assert!(
                    line.starts_with("< error") && line.contains("one"),
                    "{line}"
                ),
                other => panic!("{}: {other:?}", String::from_utf8_lossy(input)),
            }
        }
    }

    #[test]
    fn malformed_sends_are_errors_with_a_reason() {
        for (line, needle) in [
            (&b"< send >"[..], "needs an id"),
            (b"< send 123 >", "needs an id"),
            (b"< send 800 0 >", "11 bits"),
            (b"< send 20000000 0 >", "29 bits"),
            (b"< send 123456789 0 >", "bad identifier"),
            (b"< send xyz 0 >", "bad identifier"),
            (b"< send 123 9 1 2 3 4 5 6 7 8 9 >", "0..=8"),
            (b"< send 123 2 1 >", "length 2 but 1"),
            (b"< send 123 1 100 >", "bad data byte"),
            (b"< send 123 1 g >", "bad data byte"),
            (b"< send 123 -1 >", "decimal"),
        ] {
            match parse(line) {
                Err(ParseError::Syntax(m)) => {
                    assert!(m.contains(needle), "{}: {m}", String::from_utf8_lossy(line))
                }
                other => panic!("{}: {other:?}", String::from_utf8_lossy(line)),
            }
        }
        assert_eq!(parse(b"< >"), Err(ParseError::Unknown));
        assert_eq!(parse(b"< hello >"), Err(ParseError::Unknown));
        assert!(matches!(
            parse(b"< echo \xff >"),
            Err(ParseError::Syntax(_))
        ));
    }

    #[test]
    fn open_with_and_without_token() {
        assert_eq!(
            parse(b"< open can0 >"),
            Ok(Command::Open {
                bus: "can0".into(),
                token: None
            })
        );
        assert_eq!(
            parse(b"< open can0 s3cret >"),
            Ok(Command::Open {
                bus: "can0".into(),
                token: Some("s3cret".into())
            })
        );
        assert!(matches!(
            parse(b"< open can0 a b >"),
            Err(ParseError::Syntax(_))
        ));
        assert!(matches!(parse(b"< open >"), Err(ParseError::Syntax(_))));
    }

    #[test]
    fn protocol_md_frame_example() {
        // doc/protocol.md: "< frame 123 23.424242 1A220344 >".
        let f = Frame::new(id(0x123, false), &[0x1A, 0x22, 0x03, 0x44])
            .unwrap()
            .with_timestamp(Timestamp(23_424_242_000));
        assert_eq!(
            format_frame(&f).unwrap(),
            "< frame 123 23.424242 1A220344 >"
        );
        // Extended ids with 8 digits; no data: a space before '>' as
        // state_raw.c writes it.
        let f = Frame::new(id(0x1AB, true), &[])
            .unwrap()
            .with_timestamp(Timestamp(1_700_000_000_000_001_999));
        assert_eq!(
            format_frame(&f).unwrap(),
            "< frame 000001AB 1700000000.000001  >"
        );
        let f = Frame::new_fd(id(0x3B, false), &[0xAA; 12], true, false)
            .unwrap()
            .with_timestamp(Timestamp(1_589_476_062_377_071_000));
        assert_eq!(
            format_frame(&f).unwrap(),
            "< fdframe 03B 1589476062.377071 AAAAAAAAAAAAAAAAAAAAAAAA >"
        );
        assert_eq!(
            format_frame(&Frame::new_remote(id(1, false), 0).unwrap()),
            None
        );
        assert_eq!(format_frame(&Frame::new_error(4, [0; 8])), None);
    }

    #[test]
    fn errors_cannot_break_the_framing() {
        assert_eq!(format_error("unknown command"), "< error unknown command >");
        assert_eq!(format_error("a <b> c\n"), "< error a  b  c >");
    }

    #[test]
    fn session_modes() {
        let mut s = Session::new();
        assert_eq!(
            s.on_element(b"< send 123 0 >"),
            Action::Reply("< error open a bus first (open BUS) >".into())
        );
        assert_eq!(s.on_element(b"< echo >"), Action::Reply("< echo >".into()));
        assert_eq!(
            s.on_element(b"< open can0 >"),
            Action::Open {
                bus: "can0".into(),
                token: None
            }
        );
        s.opened();
        assert_eq!(s.mode(), Mode::Bcm);
        assert_eq!(
            s.on_element(b"< send 123 1 ff >"),
            Action::Send(Frame::new(id(0x123, false), &[0xff]).unwrap())
        );
        assert_eq!(
            s.on_element(b"< subscribe 0 0 123 >"),
            Action::Bcm(BcmCommand::Receive {
                id: id(0x123, false),
                mask: None,
                throttle: std::time::Duration::ZERO
            })
        );
        assert_eq!(
            s.on_element(b"< add 1 500000 12345678 2 11 22 >"),
            Action::Bcm(BcmCommand::Add {
                interval: std::time::Duration::from_millis(1500),
                frame: Frame::new(id(0x1234_5678, true), &[0x11, 0x22]).unwrap()
            })
        );
        assert_eq!(
            s.on_element(b"< filter 0 20000 123 2 FF 00 >"),
            Action::Bcm(BcmCommand::Receive {
                id: id(0x123, false),
                mask: Some(vec![0xFF, 0]),
                throttle: std::time::Duration::from_millis(20)
            })
        );
        assert_eq!(
            s.on_element(b"< update 123 1 42 >"),
            Action::Bcm(BcmCommand::Update(
                Frame::new(id(0x123, false), &[0x42]).unwrap()
            ))
        );
        assert_eq!(
            s.on_element(b"< delete 123 >"),
            Action::Bcm(BcmCommand::Delete(id(0x123, false)))
        );
        assert_eq!(
            s.on_element(b"< unsubscribe 123 >"),
            Action::Bcm(BcmCommand::Unsubscribe(id(0x123, false)))
        );
        assert_eq!(
            s.on_element(b"< add 0 x 123 0 >"),
            Action::Reply(
                "< error add: the interval must be decimal seconds and microseconds >".into()
            )
        );
        assert_eq!(
            s.on_element(b"< muxfilter 0 0 123 2 FF >"),
            Action::Reply("< error muxfilter is not supported by cangate >".into())
        );
        assert_eq!(s.on_element(b"< rawmode >"), Action::Feed(true));
        assert_eq!(s.mode(), Mode::Raw);
        assert_eq!(s.on_element(b"< rawmode >"), Action::Feed(true));
        assert!(
            matches!(s.on_element(b"< controlmode >"), Action::Reply(r) if r.starts_with("< error controlmode"))
        );
        assert!(
            matches!(s.on_element(b"< isotpmode >"), Action::Reply(r) if r.starts_with("< error isotpmode"))
        );
        assert_eq!(s.mode(), Mode::Raw);
        assert_eq!(
            s.on_element(b"< frobnicate >"),
            Action::Reply("< error unknown command >".into())
        );
        assert!(
            matches!(s.on_element(b"< open can1 >"), Action::Reply(r) if r.starts_with("< error"))
        );
        assert_eq!(s.on_element(b"< bcmmode >"), Action::Feed(false));
        assert_eq!(s.mode(), Mode::Bcm);
        assert!(
            matches!(s.on_element(b"< can0 B 500000 0 0 0 0 0 0 0 >"), Action::Close(r) if r.starts_with("< error bittiming"))
        );
    }
}
