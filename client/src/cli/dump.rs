//! `cangate dump`: the frames of one or more buses, like candump, as text
//! (`candump -x` columns), candump's log format (`--log`, what `cangate
//! replay` and canplayer read), pcapng (`--pcap`, for Wireshark) or JSON.

use super::candump_log::log_line;
use super::pcapng::PcapngWriter;
use super::{App, Context, Failure, Result, ctrl_c, hex, label};
use cangate_client::can::Filter;
use cangate_client::pb;
use clap::{Args, ValueEnum};
use futures::StreamExt;
use std::io::Write;
use std::path::PathBuf;

/// `cangate dump BUSES …`
#[derive(Args, Debug)]
pub(crate) struct DumpArgs {
    /// Bus name, several separated by commas (`can0,can1`), or `any` for
    /// every bus of the gateway.
    buses: String,
    /// Filters in candump syntax: <id>:<mask> (match) or <id>~<mask>
    /// (inverted); repeatable, a frame passing any filter is shown.
    #[arg(long = "filter", short = 'f')]
    filters: Vec<Filter>,
    /// Stop after N frames (of all buses together).
    #[arg(short = 'n', value_name = "N")]
    count: Option<u64>,
    /// Also show the frames the gateway's own protocol stacks transmit
    /// (frames other clients send are always shown, marked).
    #[arg(long)]
    tx: bool,
    /// Also show error frames.
    #[arg(long)]
    errors: bool,
    /// Timestamps of the text output, as candump's -t: a absolute
    /// (seconds since the epoch), A absolute with date and time (UTC),
    /// d delta to the previous frame, z since the first frame.
    #[arg(
        short = 't',
        long = "timestamp",
        value_name = "MODE",
        default_value = "a"
    )]
    timestamp: TimestampMode,
    /// Write candump's log format, `(1700000000.123456) can0 123#DEADBEEF`
    /// (what `candump -L` prints, `cangate replay` and canplayer read).
    #[arg(short = 'L', long, conflicts_with_all = ["pcap", "timestamp"])]
    log: bool,
    /// Write pcapng to FILE (`-`: standard output) for Wireshark and
    /// tshark: link type SocketCAN, one interface per bus.
    #[arg(long, value_name = "FILE", conflicts_with = "timestamp")]
    pcap: Option<PathBuf>,
}

/// candump's `-t` modes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum TimestampMode {
    /// Seconds since the Unix epoch: `(1700000000.123456)`.
    #[value(name = "a", alias = "absolute")]
    Absolute,
    /// Date and time, UTC: `(2023-11-14 22:13:20.123456)`.
    #[value(name = "A", alias = "date")]
    Date,
    /// Since the previous frame: `(000.000250)`.
    #[value(name = "d", alias = "delta")]
    Delta,
    /// Since the first frame: `(012.500000)`.
    #[value(name = "z", alias = "zero")]
    Zero,
}

/// Turns frame times into candump's timestamp column.
#[derive(Debug)]
pub(crate) struct Clock {
    mode: TimestampMode,
    first_us: Option<u64>,
    last_us: Option<u64>,
}

impl Clock {
    pub(crate) fn new(mode: TimestampMode) -> Clock {
        Clock {
            mode,
            first_us: None,
            last_us: None,
        }
    }

    /// The column for a frame at `us` (µs since the epoch).
    pub(crate) fn text(&mut self, us: u64) -> String {
        let first = *self.first_us.get_or_insert(us);
        let last = self.last_us.replace(us).unwrap_or(us);
        let relative = |d: u64| format!("({:03}.{:06})", d / 1_000_000, d % 1_000_000);
        match self.mode {
            TimestampMode::Absolute => format!("({}.{:06})", us / 1_000_000, us % 1_000_000),
            TimestampMode::Date => format!("({})", utc_text(us)),
            // Frames of several buses may come a little out of order.
            TimestampMode::Delta => relative(us.saturating_sub(last)),
            TimestampMode::Zero => relative(us.saturating_sub(first)),
        }
    }
}

/// `2023-11-14 22:13:20.123456`, UTC.
fn utc_text(us: u64) -> String {
    let secs = us / 1_000_000;
    let (y, m, d) = civil_from_days((secs / 86_400) as i64);
    let s = secs % 86_400;
    format!(
        "{y:04}-{m:02}-{d:02} {:02}:{:02}:{:02}.{:06}",
        s / 3600,
        s / 60 % 60,
        s % 60,
        us % 1_000_000
    )
}

/// The proleptic Gregorian date of a day count since 1970-01-01 (the
/// "days from civil" inverse in Howard Hinnant's date algorithms).
fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let y = yoe + era * 400 + i64::from(m <= 2);
    (y, m, d)
}

/// A frame like `candump -x`: `(secs.micros)  can0  RX - -       123   [4]
/// DE AD BE EF`. The column after the bus says where the frame came from as
/// candump's does on the gateway's host: `RX` from another node on the
/// wire, `TX` sent from the host (the gateway's own stacks, or a client of
/// the gateway, whose frames end with `< sender N NAME`); then BRS and ESI
/// (`B`/`E` or `-`).
fn frame_line(time: &str, bus: &str, f: &pb::Frame) -> String {
    let id = if f.extended {
        format!("{:08X}", f.id)
    } else {
        format!("{:03X}", f.id)
    };
    let dir = format!(
        "{} {} {}",
        if sent_from_host(f) { "TX" } else { "RX" },
        if f.brs { "B" } else { "-" },
        if f.esi { "E" } else { "-" }
    );
    let from = match &f.sender {
        Some(s) if s.client.is_empty() => format!("  < sender {}", s.id),
        Some(s) => format!("  < sender {} {}", s.id, s.client),
        None => String::new(),
    };
    let body = if f.remote {
        format!("[{}]  remote request", f.remote_dlc)
    } else if f.fd {
        format!("[{:02}]  {}", f.data.len(), hex(&f.data, " "))
    } else {
        format!("[{}]  {}", f.data.len(), hex(&f.data, " "))
    };
    let kind = if f.error {
        " ERROR"
    } else if f.fd {
        " FD"
    } else {
        ""
    };
    format!("{time}  {bus}  {dir}  {id:>8}{kind}   {body}{from}")
}

/// Sent from the gateway's host: by its own stacks or by one of its
/// clients (candump's TX, pcapng's outbound).
fn sent_from_host(f: &pb::Frame) -> bool {
    f.direction == pb::Direction::Tx as i32
        || f.origin == pb::FrameOrigin::Client as i32
        || f.origin == pb::FrameOrigin::Gateway as i32
}

/// A frame's time in µs since the epoch; the local clock when the gateway
/// gave none.
fn frame_us(f: &pb::Frame) -> u64 {
    match f.timestamp_ns / 1000 {
        0 => super::now_us(),
        us => us,
    }
}

/// Where the frames go.
enum Output {
    Text(Clock),
    Log,
    Json { with_bus: bool },
    Pcap(PcapngWriter<Box<dyn Write + Send>>),
}

impl Output {
    /// One frame event of `bus`.
    fn frame(&mut self, app: &App, bus: &str, ev: &pb::StreamEvent, f: &pb::Frame) -> Result<()> {
        match self {
            Output::Text(clock) => app.line(frame_line(&clock.text(frame_us(f)), bus, f)),
            Output::Log => app.line(log_line(frame_us(f), bus, f)),
            Output::Json { with_bus } => json_line(ev, bus, *with_bus),
            Output::Pcap(w) => {
                let interface = w.interface(bus).unwrap_or(0);
                Ok(w.frame(interface, frame_us(f) * 1000, f, sent_from_host(f))?)
            }
        }
    }

    /// The end of a message of events: what was written is flushed.
    fn flush(&mut self) -> Result<()> {
        if let Output::Pcap(w) = self {
            w.flush()?;
        }
        Ok(())
    }
}

/// A stream event as one JSON line; with several buses, the event's bus
/// as an extra `bus` member.
fn json_line(ev: &pb::StreamEvent, bus: &str, with_bus: bool) -> Result<()> {
    if !with_bus {
        return super::print_json_line(ev);
    }
    let mut v = serde_json::to_value(ev)?;
    if let serde_json::Value::Object(map) = &mut v {
        map.insert("bus".into(), bus.into());
    }
    super::print_json_line(&v)
}

/// The buses named on the command line (`any`: every bus).
async fn bus_names(app: &App, spec: &str) -> Result<Vec<String>> {
    if spec == "any" {
        let buses = app
            .client
            .clone()
            .list_buses()
            .await
            .ctx("listing the buses")?;
        return Ok(buses.into_iter().map(|b| b.name).collect());
    }
    let mut names: Vec<String> = Vec::new();
    for name in spec.split(',') {
        if name.is_empty() {
            return Err(Failure::usage(
                "dump",
                format!("{spec:?}: expected BUS, BUS,BUS… or any"),
            ));
        }
        if !names.iter().any(|n| n == name) {
            names.push(name.to_string());
        }
    }
    Ok(names)
}

/// `cangate dump BUSES …`: each `StreamEvent` (frame, lost, state) of each
/// bus; frames to standard output (or the pcap file), the rest to standard
/// error, except with --json, where every event is a JSON line.
pub(crate) async fn dump(app: &App, a: DumpArgs) -> Result<()> {
    let buses = bus_names(app, &a.buses).await?;
    let what = format!("dump of {}", buses.join(","));
    let mut streams = Vec::new();
    for bus in &buses {
        let req = pb::StreamFramesRequest {
            bus: bus.clone(),
            filters: a.filters.iter().map(cangate_client::filter_to_pb).collect(),
            include_transmitted: a.tx,
            include_error_frames: a.errors,
            max_batch: 0,
            queue_length: 0,
            // dump's reader pauses (`| less`) on many buses at once: the
            // gateway's small-message budget keeps the connection.
            low_latency: false,
        };
        let stream = app
            .client
            .clone()
            .stream_frames(req)
            .await
            .ctx(format!("dump of {bus}"))?;
        let bus = bus.clone();
        streams.push(stream.map(move |m| (bus.clone(), m)).boxed());
    }
    let mut out = if let Some(path) = &a.pcap {
        let file: Box<dyn Write + Send> = if path.as_os_str() == "-" {
            Box::new(std::io::stdout())
        } else {
            Box::new(std::io::BufWriter::new(
                std::fs::File::create(path).ctx(format!("creating {}", path.display()))?,
            ))
        };
        Output::Pcap(PcapngWriter::new(file, &buses)?)
    } else if app.json {
        Output::Json {
            with_bus: buses.len() > 1,
        }
    } else if a.log {
        Output::Log
    } else {
        Output::Text(Clock::new(a.timestamp))
    };
    let mut merged = futures::stream::select_all(streams);
    let mut seen = 0u64;
    loop {
        let next = tokio::select! {
            m = merged.next() => m,
            _ = ctrl_c() => break,
        };
        let Some((bus, msg)) = next else { break };
        let msg = msg
            .map_err(cangate_client::Error::from)
            .ctx(format!("dump of {bus}"))?;
        for ev in &msg.events {
            use pb::stream_event::Event;
            match &ev.event {
                Some(Event::Frame(f)) => {
                    out.frame(app, &bus, ev, f)?;
                    seen += 1;
                    if a.count.is_some_and(|n| seen >= n) {
                        out.flush()?;
                        return Ok(());
                    }
                }
                Some(_) if matches!(out, Output::Json { .. }) => {
                    json_line(ev, &bus, buses.len() > 1)?
                }
                Some(Event::Lost(l)) => eprintln!(
                    "cangate: {bus}: {} frames lost (this client read too slowly)",
                    l.count
                ),
                Some(Event::State(s)) => eprintln!(
                    "cangate: {bus}: state {} (tx errors {}, rx errors {})",
                    label::<pb::BusState>(s.state),
                    s.tx_errors,
                    s.rx_errors
                ),
                None => {}
            }
        }
        out.flush()?;
    }
    out.flush()?;
    match a.count {
        Some(n) if seen < n => Err(Failure::failed(
            what,
            format!("the stream ended after {seen} of {n} frames"),
        )),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pb_frame(text: &str, direction: pb::Direction, origin: pb::FrameOrigin) -> pb::Frame {
        let f: cangate_client::can::Frame = text.parse().unwrap();
        let mut p = cangate_client::proto::frames::frame_to_pb(&f, direction);
        p.origin = origin as i32;
        p
    }

    /// The candump -x columns: RX for other nodes, TX for what the
    /// gateway's host sent (its stacks, its clients, who are named).
    #[test]
    fn frame_lines_mark_where_frames_came_from() {
        let t = "(1.000000)";
        let wire = pb_frame("123#DEADBEEF", pb::Direction::Rx, pb::FrameOrigin::Bus);
        let line = frame_line(t, "can0", &wire);
        assert_eq!(
            line,
            "(1.000000)  can0  RX - -       123   [4]  DE AD BE EF"
        );
        let own = pb_frame("080#", pb::Direction::Tx, pb::FrameOrigin::Gateway);
        assert!(frame_line(t, "can0", &own).contains("  can0  TX - -       080   [0]"));
        let mut client = pb_frame("7FF##3AA", pb::Direction::Rx, pb::FrameOrigin::Client);
        client.sender = Some(pb::FrameSender {
            id: 7,
            client: "hmi-1@10.0.0.5:41234".into(),
        });
        let line = frame_line(t, "can0", &client);
        assert!(
            line.contains(
                "  can0  TX B E       7FF FD   [01]  AA  < sender 7 hmi-1@10.0.0.5:41234"
            ),
            "{line}"
        );
        client.sender.as_mut().unwrap().client.clear();
        assert!(frame_line(t, "can0", &client).ends_with("  < sender 7"));
    }

    /// candump's -t a, A, d, z.
    #[test]
    fn timestamp_modes_are_candumps() {
        let t0 = 1_700_000_000_123_456;
        let mut a = Clock::new(TimestampMode::Absolute);
        assert_eq!(a.text(t0), "(1700000000.123456)");
        let mut date = Clock::new(TimestampMode::Date);
        assert_eq!(date.text(t0), "(2023-11-14 22:13:20.123456)");
        assert_eq!(
            date.text(951_782_400_000_001),
            "(2000-02-29 00:00:00.000001)"
        );
        assert_eq!(date.text(0), "(1970-01-01 00:00:00.000000)");
        let mut d = Clock::new(TimestampMode::Delta);
        assert_eq!(d.text(t0), "(000.000000)");
        assert_eq!(d.text(t0 + 250), "(000.000250)");
        assert_eq!(d.text(t0 + 1_500_250), "(001.500000)");
        // A frame of another bus a little earlier: no wrap-around.
        assert_eq!(d.text(t0 + 1_500_000), "(000.000000)");
        let mut z = Clock::new(TimestampMode::Zero);
        assert_eq!(z.text(t0), "(000.000000)");
        assert_eq!(z.text(t0 + 12_500_000), "(012.500000)");
        assert_eq!(z.text(t0 + 1_000_000_000), "(1000.000000)");
    }
}
