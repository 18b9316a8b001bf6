//! Buses: `cangate bus list|show`, `send`.

use super::{App, Context, Result, label, print_json};
use cangate_client::can::Frame;
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
