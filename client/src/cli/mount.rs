//! `cangate mount BUS IFNAME`: a bus of the gateway as a local SocketCAN
//! interface, both ways through one `Bus.Attach` stream, so that any
//! SocketCAN program here (candump, SavvyCAN, a ROS driver, python-can's
//! `socketcan` interface) works on the gateway's bus unchanged.
//!
//! - **The interface.** An existing one is used as it is (brought up if
//!   it is down and that is allowed); a missing one is created as a
//!   virtual CAN interface (`ip link add IFNAME type vcan`, with the CAN FD
//!   MTU when the gateway's bus is CAN FD), which needs `CAP_NET_ADMIN`:
//!   without it the command says what to run. One it created is deleted at
//!   the end.
//! - **No echo.** Frames of the gateway's bus are written to the
//!   interface by this program's socket, which does not receive its own
//!   frames (SocketCAN's default), so they never go back to the gateway;
//!   frames read from the interface are sent as this attachment's, which
//!   the gateway does not send back to it (`receive_own` off).
//! - **Loss** is counted each way: frames the gateway dropped because
//!   this program read too slowly, frames the interface did not take (its
//!   transmit queue full), frames the kernel dropped before this program
//!   read them, frames the gateway refused (its frame budget, bus-off).
//!   The counters are printed at the end, on SIGUSR1, and every
//!   `--stats-every` seconds.

use super::{App, Context, Failure, Result, ctrl_c};
use cangate_can::socketcan_bus::{SocketCanBus, SocketCanEvent, interface_is_up};
use cangate_client::can::Filter;
use cangate_client::{AttachEvent, AttachOptions};
use clap::Args;
use futures::{FutureExt, StreamExt};
use std::process::Command;
use std::time::Duration;

/// At most this many frames of the gateway go to the interface in one
/// write.
const WRITE_BATCH: usize = 256;

/// `CANFD_MTU`: an interface with this MTU carries CAN FD frames.
const CANFD_MTU: u32 = 72;

/// `cangate mount BUS IFNAME`
#[derive(Args, Debug)]
pub(crate) struct MountArgs {
    /// The gateway's bus.
    bus: String,
    /// The local SocketCAN interface (a vcan is created when it does not
    /// exist and this program may).
    ifname: String,
    /// Also print the counters every SECONDS (they are printed at the end
    /// and on SIGUSR1 anyway).
    #[arg(long, value_name = "SECONDS")]
    stats_every: Option<f64>,
    /// Only the gateway's frames that pass these filters go to the
    /// interface, in candump syntax: <id>:<mask> (match) or <id>~<mask>
    /// (inverted); repeatable, a frame passing any filter goes. The gateway
    /// applies them, so what is filtered out never crosses the network.
    /// Frames of the interface all go to the gateway.
    #[arg(long = "filter", short = 'f')]
    filters: Vec<Filter>,
}

/// Frames each way, and the ones lost.
#[derive(Debug, Default)]
struct Counters {
    /// Frames of the gateway's bus written to the interface.
    to_local: u64,
    /// Frames of the interface sent to the gateway.
    to_gateway: u64,
    /// Frames the gateway dropped for this program (it read too slowly).
    lost_gateway_queue: u64,
    /// Frames the interface did not take (its transmit queue full).
    lost_local_tx: u64,
    /// Frames the kernel dropped before this program read them.
    lost_local_rx: u64,
    /// Frames the gateway refused (frame budget, bus-off, malformed).
    refused_by_gateway: u64,
}

impl Counters {
    /// The frames of a send the gateway refused: not sent after all.
    fn refused(&mut self, r: &cangate_client::pb::SendRefused) {
        let refused = u64::from(r.total.saturating_sub(r.sent));
        self.refused_by_gateway += refused;
        self.to_gateway = self.to_gateway.saturating_sub(refused);
    }

    fn line(&self, bus: &str, ifname: &str) -> String {
        format!(
            "cangate mount {bus} {ifname}: {} frames to {ifname}, {} to {bus}; lost: {} dropped by \
             the gateway (read too slowly), {} not taken by {ifname} (transmit queue full), {} \
             dropped by the kernel before they were read, {} refused by the gateway",
            self.to_local,
            self.to_gateway,
            self.lost_gateway_queue,
            self.lost_local_tx,
            self.lost_local_rx,
            self.refused_by_gateway
        )
    }
}

/// The interface's MTU, if it exists.
fn mtu(ifname: &str) -> Option<u32> {
    std::fs::read_to_string(format!("/sys/class/net/{ifname}/mtu"))
        .ok()?
        .trim()
        .parse()
        .ok()
}

/// Runs `ip ARGS`, or says why it failed.
fn ip(args: &[&str]) -> std::result::Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| format!("cannot run `ip`: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "`ip {}` failed: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

/// Makes sure the interface exists and is up; true when it was created
/// here.
fn ensure_interface(ifname: &str, fd: bool) -> Result<bool> {
    let what = format!("mounting on {ifname}");
    let created = match interface_is_up(ifname) {
        Some(_) => false,
        None => {
            let mut add = vec!["link", "add", "dev", ifname, "type", "vcan"];
            let mtu = CANFD_MTU.to_string();
            if fd {
                add.extend(["mtu", mtu.as_str()]);
            }
            ip(&add).map_err(|e| {
                Failure::failed(
                    &what,
                    format!(
                        "{ifname} does not exist and cannot be created here ({e}); create it \
                         first: sudo ip link add dev {ifname} type vcan{} && sudo ip link set \
                         up {ifname}",
                        if fd { " mtu 72" } else { "" }
                    ),
                )
            })?;
            true
        }
    };
    if interface_is_up(ifname) == Some(false) {
        ip(&["link", "set", "up", ifname]).map_err(|e| {
            Failure::failed(
                &what,
                format!("{ifname} is down and cannot be brought up here ({e}): sudo ip link set up {ifname}"),
            )
        })?;
    }
    Ok(created)
}

/// Deletes an interface this program created.
struct CreatedInterface(Option<String>);

impl Drop for CreatedInterface {
    fn drop(&mut self) {
        if let Some(ifname) = self.0.take()
            && let Err(e) = ip(&["link", "delete", "dev", &ifname])
        {
            eprintln!("cangate: {e}");
        }
    }
}

/// SIGUSR1, or never where it cannot be listened to.
async fn sigusr1(signal: &mut Option<tokio::signal::unix::Signal>) {
    match signal {
        Some(s) => {
            if s.recv().await.is_none() {
                std::future::pending::<()>().await;
            }
        }
        None => std::future::pending().await,
    }
}

pub(crate) async fn mount(app: &App, a: MountArgs) -> Result<()> {
    let mut client = app.client.clone();
    let info = client
        .get_bus(&a.bus)
        .await
        .ctx(format!("mounting {}", a.bus))?;
    let created = ensure_interface(&a.ifname, info.fd)?;
    let _created = CreatedInterface(created.then(|| a.ifname.clone()));
    // CAN FD both ways only when both sides carry it.
    let fd = info.fd && mtu(&a.ifname) == Some(CANFD_MTU);
    let mut local = SocketCanBus::open(&a.ifname)
        .map_err(|e| Failure::failed(format!("opening {}", a.ifname), e.to_string()))?;
    let options = AttachOptions {
        filters: a.filters.clone(),
        fd,
        low_latency: true,
        ..AttachOptions::default()
    };
    let attachment = app
        .client
        .attach(&a.bus, &options)
        .await
        .ctx(format!("attaching to {}", a.bus))?;
    let sender = attachment.sender;
    let mut events = attachment.events;
    eprintln!(
        "cangate: {} mounted on {}{} (Ctrl-C ends it; SIGUSR1 prints the counters)",
        a.bus,
        a.ifname,
        if created { ", created" } else { "" }
    );
    let mut usr1 =
        tokio::signal::unix::signal(tokio::signal::unix::SignalKind::user_defined1()).ok();
    let every = a
        .stats_every
        .filter(|s| s.is_finite() && *s > 0.0)
        .map(Duration::from_secs_f64);
    let mut tick = every.map(tokio::time::interval);
    if let Some(t) = &mut tick {
        t.tick().await;
    }
    let mut n = Counters::default();
    let end = loop {
        tokio::select! {
            _ = ctrl_c() => break Ok(()),
            _ = sigusr1(&mut usr1) => eprintln!("{}", n.line(&a.bus, &a.ifname)),
            _ = async { match &mut tick { Some(t) => { t.tick().await; } None => std::future::pending().await } } => {
                eprintln!("{}", n.line(&a.bus, &a.ifname));
            }
            event = events.next() => {
                // The events that arrived with it are handled in the same
                // turn, and their frames go to the interface in one write:
                // one wake-up and one queue entry per batch, not per frame,
                // so the mount keeps up with a busy bus.
                let mut frames = Vec::new();
                let mut next = Some(event);
                let mut end = None;
                while let Some(event) = next.take() {
                    match event {
                        Some(Ok(AttachEvent::Frame { frame, own: false, .. })) => frames.push(frame),
                        Some(Ok(AttachEvent::Lost(k))) => n.lost_gateway_queue += k,
                        Some(Ok(AttachEvent::Refused(r))) => n.refused(&r),
                        Some(Ok(_)) => {}
                        Some(Err(e)) => {
                            end = Some(Err::<(), _>(e).ctx(format!("the attachment to {}", a.bus)));
                            break;
                        }
                        None => {
                            end = Some(Err(Failure::failed(format!("the attachment to {}", a.bus), "the gateway ended it")));
                            break;
                        }
                    }
                    if frames.len() < WRITE_BATCH {
                        next = events.next().now_or_never();
                    }
                }
                if !frames.is_empty() {
                    local.queue(frames, None);
                }
                if let Some(end) = end {
                    break end;
                }
            }
            event = local.recv() => match event {
                // Error frames stay here: a SocketCAN error frame is not a
                // frame of the gateway's bus.
                SocketCanEvent::Frame(frame) if !frame.is_error() => {
                    if frame.is_fd() && !fd {
                        n.refused_by_gateway += 1;
                        continue;
                    }
                    if let Err(e) = sender.send(&[frame]).await {
                        break Err::<(), _>(e).ctx(format!("sending to {}", a.bus));
                    }
                    n.to_gateway += 1;
                }
                SocketCanEvent::Frame(_) => {}
                SocketCanEvent::Sent(_) => n.to_local += 1,
                SocketCanEvent::Unsent(_) => n.lost_local_tx += 1,
                SocketCanEvent::Lost(k) => n.lost_local_rx += k,
                SocketCanEvent::State(s) => eprintln!("cangate: {}: {s:?}", a.ifname),
            },
        }
    };
    // What was read from the interface reaches the gateway before the end
    // (bounded by the client's request timeout); the events are no longer
    // read, so they must not hold the answers back.
    drop(events);
    if let Err(e) = sender.flush().await {
        eprintln!("cangate: {}: {e}", a.bus);
    }
    eprintln!("{}", n.line(&a.bus, &a.ifname));
    end
}
