//! The SYNC and TIME producers of a CANopen bus: `cangate sync`,
//! `cangate time`.

use super::{App, Context, Result};
use cangate_client::pb;
use clap::{Args, Subcommand};
use std::time::Duration;

/// `cangate sync BUS [start|stop|set …]`
#[derive(Args, Debug)]
pub(crate) struct SyncArgs {
    /// Bus.
    bus: String,
    #[command(subcommand)]
    verb: Option<SyncVerb>,
}

#[derive(Subcommand, Debug)]
enum SyncVerb {
    /// The producer's state (the default).
    Status,
    /// Starts producing SYNCs (with the current or the given period).
    Start {
        /// Period in µs.
        #[arg(long, value_name = "US")]
        period_us: Option<u32>,
    },
    /// Stops producing SYNCs (refused while a cyclic axis moves).
    Stop,
    /// Changes the period and/or the counter (0x1019) without starting or
    /// stopping.
    Set {
        /// Period in µs.
        #[arg(long, value_name = "US")]
        period_us: Option<u32>,
        /// Counter overflow value: 0 (no counter) or 2..=240.
        #[arg(long, value_name = "N")]
        counter: Option<u8>,
    },
}

/// `cangate time BUS [send|every MS|off]`
#[derive(Args, Debug)]
pub(crate) struct TimeArgs {
    /// Bus.
    bus: String,
    #[command(subcommand)]
    verb: TimeVerb,
}

#[derive(Subcommand, Debug)]
enum TimeVerb {
    /// Sends the host's time now (CiA 301 TIME_OF_DAY on 0x100).
    Send,
    /// Sends the time every MS milliseconds.
    Every {
        /// Period in ms.
        ms: u32,
    },
    /// Stops the periodic TIME.
    Off,
}

fn status_text(s: &pb::SyncStatus) -> String {
    format!(
        "{}  SYNC {}  period {} µs  counter {}  sent {}  skipped {}  TIME {}",
        s.bus,
        if s.running { "running" } else { "stopped" },
        s.period_us,
        if s.counter_overflow == 0 {
            "off".to_string()
        } else {
            format!("1..={}", s.counter_overflow)
        },
        s.sent,
        s.skipped,
        if s.time_period_ms == 0 {
            "on request".to_string()
        } else {
            format!("every {} ms", s.time_period_ms)
        }
    )
}

/// `cangate sync …`
pub(crate) async fn sync(app: &App, a: SyncArgs) -> Result<()> {
    let co = app.client.canopen(&a.bus);
    let us = |p: Option<u32>| p.map(|us| Duration::from_micros(u64::from(us)));
    let (what, status) = match a.verb.unwrap_or(SyncVerb::Status) {
        SyncVerb::Status => ("reading the SYNC producer", co.sync_status().await),
        SyncVerb::Start { period_us } => (
            "starting the SYNC",
            co.set_sync(Some(true), us(period_us), None).await,
        ),
        SyncVerb::Stop => (
            "stopping the SYNC",
            co.set_sync(Some(false), None, None).await,
        ),
        SyncVerb::Set { period_us, counter } => (
            "changing the SYNC",
            co.set_sync(None, us(period_us), counter).await,
        ),
    };
    let status = status.ctx(format!("{what} of {}", a.bus))?;
    app.item(status_text(&status), &status)
}

/// `cangate time …`
pub(crate) async fn time(app: &App, a: TimeArgs) -> Result<()> {
    let co = app.client.canopen(&a.bus);
    let r = match a.verb {
        TimeVerb::Send => co.set_time(true, None).await,
        TimeVerb::Every { ms } => {
            co.set_time(false, Some(Duration::from_millis(u64::from(ms))))
                .await
        }
        TimeVerb::Off => co.set_time(false, Some(Duration::ZERO)).await,
    }
    .ctx(format!("TIME on {}", a.bus))?;
    let text = match &r.sent {
        Some(t) => format!(
            "{}  TIME sent: day {} since 1984, {} ms after midnight (UTC)",
            a.bus, t.days_since_1984, t.ms_after_midnight
        ),
        None if r.time_period_ms == 0 => format!("{}  TIME only on request", a.bus),
        None => format!("{}  TIME every {} ms", a.bus, r.time_period_ms),
    };
    app.item(text, &r)
}
