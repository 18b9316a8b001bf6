//! Buses: `cangate bus list|show`, `dump`, `send`.

use super::{App, Context, Result, ctrl_c, hex, label, print_json};
use cangate_client::can::{Filter, Frame};
use cangate_client::pb;
use clap::{Args, Subcommand};

/// `cangate bus …`
#[derive(Args, Debug)]
pub(crate) struct BusArgs {
    #[command(subcommand)]
    verb: BusVerb,
}

#[derive(Subcommand, Debug)]
enum BusVerb {
    /// Table of buses: state, error counters, frames, load.
    List,
    /// One bus in detail.
    Show {
        /// Bus name.
        bus: String,
    },
}

/// `cangate dump BUS …`
#[derive(Args, Debug)]
pub(crate) struct DumpArgs {
    /// Bus name.
    bus: String,
    /// Filters in candump syntax: <id>:<mask> (match) or <id>~<mask>
    /// (inverted); repeatable, a frame passing any filter is shown.
    #[arg(long = "filter", short = 'f')]
    filters: Vec<Filter>,
    /// Stop after N frames.
    #[arg(short = 'n', value_name = "N")]
    count: Option<u64>,
    /// Also show the frames the gateway's own protocol stacks transmit
    /// (frames other clients send are always shown, marked).
    #[arg(long)]
    tx: bool,
    /// Also show error frames.
    #[arg(long)]
    errors: bool,
}

/// `cangate send BUS FRAME…`
#[derive(Args, Debug)]
pub(crate) struct SendArgs {
    /// Bus name.
    bus: String,
    /// One or more frames, sent in order (all or none).
    #[arg(required = true, value_parser = frame)]
    frames: Vec<Frame>,
}

fn frame(text: &str) -> Result<Frame, String> {
    text.parse::<Frame>().map_err(|e| e.to_string())
}

fn bus_line(b: &pb::BusInfo) -> String {
    let st = b.status.unwrap_or_default();
    let s = b.statistics.unwrap_or_default();
    let bitrate = if b.bitrate > 0 {
        format!("{}k{}", b.bitrate / 1000, if b.fd { "/FD" } else { "" })
    } else {
        "-".into()
    };
    format!(
        "{:<8} {:<9} {:<10} {:<14} {:>9} {:>10} {:>10} {:>7} {:>6.1}",
        b.name,
        label::<pb::BackendKind>(b.backend),
        b.interface,
        format!(
            "{} ({}/{})",
            label::<pb::BusState>(st.state),
            st.tx_errors,
            st.rx_errors
        ),
        bitrate,
        s.rx_frames,
        s.tx_frames,
        s.error_frames + s.tx_failed,
        s.load_percent
    )
}

const BUS_HEADER: &str =
    "BUS      BACKEND   INTERFACE  STATE            BITRATE         RX         TX  ERRORS  LOAD%";

/// `cangate bus list` (and `cangate buses`)
pub(crate) async fn list(app: &App) -> Result<()> {
    let buses = app
        .client
        .clone()
        .list_buses()
        .await
        .ctx("listing the buses")?;
    if app.json {
        return print_json(&pb::ListBusesResponse { buses });
    }
    let mut text = BUS_HEADER.to_string();
    for b in &buses {
        text.push('\n');
        text.push_str(&bus_line(b));
    }
    app.line(text)
}

/// `cangate bus …`
pub(crate) async fn run(app: &App, args: BusArgs) -> Result<()> {
    match args.verb {
        BusVerb::List => list(app).await,
        BusVerb::Show { bus } => {
            let b = app
                .client
                .clone()
                .get_bus(&bus)
                .await
                .ctx(format!("bus {bus}"))?;
            let s = b.statistics.unwrap_or_default();
            let text = format!(
                "{BUS_HEADER}\n{}\nerror frames {}  tx failed {}  rx overflows {}  subscriber drops {}  subscribers {}  data bitrate {}  bit timing {}",
                bus_line(&b),
                s.error_frames,
                s.tx_failed,
                s.rx_overflows,
                s.subscriber_drops,
                s.subscribers,
                b.data_bitrate,
                if b.bit_timed { "simulated" } else { "off" },
            );
            app.show(text, &b)
        }
    }
}

/// `cangate send BUS FRAME…`
pub(crate) async fn send(app: &App, a: SendArgs) -> Result<()> {
    let sent = app
        .client
        .clone()
        .send(&a.bus, &a.frames)
        .await
        .ctx(format!("sending on {}", a.bus))?;
    if app.json {
        print_json(&pb::SendFramesResponse { sent })?;
    }
    Ok(())
}

/// A frame like `candump -x`: `(secs.micros)  can0  RX - -       123   [4]
/// DE AD BE EF`. The column after the bus says where the frame came from as
/// candump's does on the gateway's host: `RX` from another node on the
/// wire, `TX` sent from the host (the gateway's own stacks, or a client of
/// the gateway, whose frames end with `< sender N NAME`); then BRS and ESI
/// (`B`/`E` or `-`).
fn frame_line(bus: &str, f: &pb::Frame) -> String {
    let id = if f.extended {
        format!("{:08X}", f.id)
    } else {
        format!("{:03X}", f.id)
    };
    let local = f.direction == pb::Direction::Tx as i32
        || f.origin == pb::FrameOrigin::Client as i32
        || f.origin == pb::FrameOrigin::Gateway as i32;
    let dir = format!(
        "{} {} {}",
        if local { "TX" } else { "RX" },
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
    format!(
        "{}  {bus}  {dir}  {id:>8}{kind}   {body}{from}",
        super::time_text(f.timestamp_ns / 1000)
    )
}

/// `cangate dump BUS …`: each `StreamEvent` (frame, lost, state) as a line;
/// with --json one JSON object per event.
pub(crate) async fn dump(app: &App, a: DumpArgs) -> Result<()> {
    let req = pb::StreamFramesRequest {
        bus: a.bus.clone(),
        filters: a.filters.iter().map(cangate_client::filter_to_pb).collect(),
        include_transmitted: a.tx,
        include_error_frames: a.errors,
        max_batch: 0,
        queue_length: 0,
    };
    let what = format!("dump of {}", a.bus);
    let mut stream = app
        .client
        .clone()
        .stream_frames(req)
        .await
        .ctx(what.clone())?;
    let bus = a.bus.as_str();
    let mut seen = 0u64;
    loop {
        let msg = tokio::select! {
            m = stream.message() => m.map_err(cangate_client::Error::from).ctx(what.clone())?,
            _ = ctrl_c() => return Ok(()),
        };
        let Some(msg) = msg else { break };
        for ev in msg.events {
            use pb::stream_event::Event;
            match &ev.event {
                Some(Event::Frame(f)) => {
                    app.item(frame_line(bus, f), &ev)?;
                    seen += 1;
                    if a.count.is_some_and(|n| seen >= n) {
                        return Ok(());
                    }
                }
                Some(Event::Lost(l)) if app.json => super::print_json_line(&ev)?,
                Some(Event::Lost(l)) => eprintln!(
                    "cangate: {bus}: {} frames lost (this client read too slowly)",
                    l.count
                ),
                Some(Event::State(_)) if app.json => super::print_json_line(&ev)?,
                Some(Event::State(s)) => eprintln!(
                    "cangate: {bus}: state {} (tx errors {}, rx errors {})",
                    label::<pb::BusState>(s.state),
                    s.tx_errors,
                    s.rx_errors
                ),
                None => {}
            }
        }
    }
    match a.count {
        Some(n) if seen < n => Err(super::Failure::failed(
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
        let f: Frame = text.parse().unwrap();
        let mut p = cangate_client::proto::frames::frame_to_pb(&f, direction);
        p.origin = origin as i32;
        p
    }

    /// The candump -x columns: RX for other nodes, TX for what the
    /// gateway's host sent (its stacks, its clients, who are named).
    #[test]
    fn frame_lines_mark_where_frames_came_from() {
        let wire = pb_frame("123#DEADBEEF", pb::Direction::Rx, pb::FrameOrigin::Bus);
        let line = frame_line("can0", &wire);
        assert!(
            line.contains("  can0  RX - -       123   [4]  DE AD BE EF"),
            "{line}"
        );
        assert!(!line.contains('<'), "{line}");
        let own = pb_frame("080#", pb::Direction::Tx, pb::FrameOrigin::Gateway);
        assert!(frame_line("can0", &own).contains("  can0  TX - -       080   [0]"));
        let mut client = pb_frame("7FF##3AA", pb::Direction::Rx, pb::FrameOrigin::Client);
        client.sender = Some(pb::FrameSender {
            id: 7,
            client: "hmi-1@10.0.0.5:41234".into(),
        });
        let line = frame_line("can0", &client);
        assert!(
            line.contains(
                "  can0  TX B E       7FF FD   [01]  AA  < sender 7 hmi-1@10.0.0.5:41234"
            ),
            "{line}"
        );
        client.sender.as_mut().unwrap().client.clear();
        assert!(frame_line("can0", &client).ends_with("  < sender 7"));
    }
}
