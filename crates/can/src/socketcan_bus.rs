//! The Linux SocketCAN backend (via the `socketcan` crate, tokio flavour).
//!
//! One raw CAN FD-capable socket per interface, kernel timestamps
//! (`SO_TIMESTAMPNS`), error frames enabled and decoded into [`BusStatus`].
//! When the interface goes down or disappears, the backend reports
//! [`BusState::Down`] and reconnects with exponential backoff (100 ms up to
//! 5 s) once the interface is up again; it never gives up.

use crate::frame::{CanId, Frame, FrameKind, Timestamp};
use crate::state::{BusState, BusStatus, status_from_error_frame};
use crate::virtual_bus::SendError;
use socketcan::id::FdFlags;
use socketcan::{
    CanAnyFrame, CanDataFrame, CanFdFrame, CanRemoteFrame, EmbeddedFrame, ExtendedId, Id,
    SocketOptions, StandardId,
};
use std::time::{Duration, UNIX_EPOCH};

/// Events from the SocketCAN backend.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SocketCanEvent {
    /// A frame (data, remote or error) with its kernel timestamp.
    Frame(Frame),
    /// The interface state changed (down, up, error states from error frames).
    State(BusStatus),
}

/// A SocketCAN interface that survives the interface going away.
pub struct SocketCanBus {
    interface: String,
    socket: Option<socketcan::tokio::CanFdSocket>,
    status: BusStatus,
    backoff: Duration,
    /// A state change to report before the next frame.
    pending_state: Option<BusStatus>,
    /// Deadlines kept across calls: `recv` is cancelled whenever the bus
    /// task's select! picks another branch (every 20 ms tick).
    next_link_check: Option<tokio::time::Instant>,
    next_reconnect: Option<tokio::time::Instant>,
}

impl std::fmt::Debug for SocketCanBus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SocketCanBus")
            .field("interface", &self.interface)
            .field("status", &self.status)
            .finish()
    }
}

const MIN_BACKOFF: Duration = Duration::from_millis(100);
const MAX_BACKOFF: Duration = Duration::from_secs(5);
/// How often a connected bus checks the interface's IFF_UP flag, so that
/// `ip link set dev X down` is noticed even when the bus is silent.
const LINK_POLL: Duration = Duration::from_millis(250);

/// Whether the interface exists (`Some`) and is administratively up.
pub fn interface_is_up(interface: &str) -> Option<bool> {
    let flags = std::fs::read_to_string(format!("/sys/class/net/{interface}/flags")).ok()?;
    let flags = u32::from_str_radix(flags.trim().trim_start_matches("0x"), 16).ok()?;
    Some(flags & 0x1 != 0)
}

impl SocketCanBus {
    /// Opens the interface. Fails if the interface does not exist, so a
    /// configuration error is caught at start-up; later disappearances are
    /// handled by reconnecting.
    pub fn open(interface: &str) -> std::io::Result<Self> {
        if interface_is_up(interface).is_none() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::NotFound,
                format!("CAN interface {interface} does not exist"),
            ));
        }
        let mut bus = SocketCanBus {
            interface: interface.to_string(),
            socket: None,
            status: BusStatus::DOWN,
            backoff: MIN_BACKOFF,
            pending_state: None,
            next_link_check: None,
            next_reconnect: None,
        };
        if interface_is_up(interface) == Some(true) {
            bus.connect()?;
        }
        Ok(bus)
    }

    fn connect(&mut self) -> std::io::Result<()> {
        let sock = socketcan::tokio::CanFdSocket::open(&self.interface)?;
        sock.set_error_filter_accept_all()?;
        sock.set_recv_timestamp(true)?;
        self.socket = Some(sock);
        self.backoff = MIN_BACKOFF;
        self.set_status(BusStatus::UP);
        Ok(())
    }

    fn disconnect(&mut self, why: &std::io::Error) {
        if self.socket.take().is_some() {
            tracing::warn!(interface = %self.interface, error = %why, "CAN interface lost; reconnecting");
        }
        self.set_status(BusStatus::DOWN);
    }

    fn set_status(&mut self, status: BusStatus) {
        if status != self.status {
            self.status = status;
            self.pending_state = Some(status);
        }
    }

    /// Interface name.
    pub fn interface(&self) -> &str {
        &self.interface
    }

    /// Current status.
    pub fn status(&self) -> BusStatus {
        self.status
    }

    /// Waits for the next frame or state change. Never returns an error:
    /// failures become [`BusState::Down`] and reconnection attempts.
    pub async fn recv(&mut self) -> SocketCanEvent {
        loop {
            if let Some(s) = self.pending_state.take() {
                return SocketCanEvent::State(s);
            }
            if self.socket.is_none() {
                let at = *self
                    .next_reconnect
                    .get_or_insert_with(|| tokio::time::Instant::now() + self.backoff);
                tokio::time::sleep_until(at).await;
                self.next_reconnect = None;
                self.backoff = (self.backoff * 2).min(MAX_BACKOFF);
                if interface_is_up(&self.interface) == Some(true)
                    && let Err(e) = self.connect()
                {
                    tracing::debug!(interface = %self.interface, error = %e, "reconnect failed");
                }
                continue;
            }
            let check_at = *self
                .next_link_check
                .get_or_insert_with(|| tokio::time::Instant::now() + LINK_POLL);
            let sock = self.socket.as_ref().expect("connected");
            let result = tokio::select! {
                r = sock.read_frame_with_timestamps() => Some(r),
                _ = tokio::time::sleep_until(check_at) => None,
            };
            match result {
                None => {
                    self.next_link_check = None;
                    if interface_is_up(&self.interface) != Some(true) {
                        self.disconnect(&std::io::Error::other("interface is down"));
                    }
                }
                Some(Err(e)) => self.disconnect(&e),
                Some(Ok((any, ts))) => {
                    let stamp = ts
                        .socket
                        .and_then(|t| t.duration_since(UNIX_EPOCH).ok())
                        .map(|d| Timestamp(d.as_nanos() as u64))
                        .unwrap_or_else(Timestamp::now);
                    let Some(frame) = from_socketcan(&any) else {
                        continue;
                    };
                    let frame = frame.with_timestamp(stamp);
                    if let Some(s) = status_from_error_frame(&frame, self.status) {
                        self.set_status(s);
                    }
                    return SocketCanEvent::Frame(frame);
                }
            }
        }
    }

    /// Sends one frame.
    pub async fn send(&mut self, frame: &Frame) -> Result<(), SendError> {
        let Some(sock) = self.socket.as_ref() else {
            return Err(SendError::Down(self.interface.clone()));
        };
        if self.status.state == BusState::BusOff {
            return Err(SendError::BusOff(self.interface.clone()));
        }
        let any = to_socketcan(frame).ok_or_else(|| SendError::Io {
            bus: self.interface.clone(),
            message: format!("frame {frame} cannot be represented"),
        })?;
        let result = match any {
            CanAnyFrame::Fd(f) => sock.write_frame(&f).await,
            CanAnyFrame::Normal(f) => sock.write_frame(&f).await,
            CanAnyFrame::Remote(f) => sock.write_frame(&f).await,
            CanAnyFrame::Error(_) => return Ok(()),
        };
        match result {
            Ok(()) => Ok(()),
            Err(e) if e.raw_os_error() == Some(libc::EINVAL) && frame.is_fd() => {
                Err(SendError::FdNotSupported(self.interface.clone()))
            }
            Err(e) => {
                if matches!(e.raw_os_error(), Some(libc::ENETDOWN) | Some(libc::ENODEV)) {
                    self.disconnect(&e);
                }
                Err(SendError::Io {
                    bus: self.interface.clone(),
                    message: e.to_string(),
                })
            }
        }
    }
}

fn hal_id(id: CanId) -> Option<Id> {
    Some(match id {
        CanId::Standard(i) => Id::Standard(StandardId::new(i)?),
        CanId::Extended(i) => Id::Extended(ExtendedId::new(i)?),
    })
}

/// Converts our frame to the socketcan crate's.
pub fn to_socketcan(frame: &Frame) -> Option<CanAnyFrame> {
    let id = hal_id(frame.id())?;
    Some(match frame.kind() {
        FrameKind::Data if frame.is_fd() => {
            let mut flags = FdFlags::empty();
            if frame.brs() {
                flags |= FdFlags::BRS;
            }
            if frame.esi() {
                flags |= FdFlags::ESI;
            }
            CanAnyFrame::Fd(CanFdFrame::with_flags(id, frame.data(), flags)?)
        }
        FrameKind::Data => CanAnyFrame::Normal(CanDataFrame::new(id, frame.data())?),
        FrameKind::Remote => {
            CanAnyFrame::Remote(CanRemoteFrame::new_remote(id, frame.dlc() as usize)?)
        }
        FrameKind::Error => return None,
    })
}

/// Converts the socketcan crate's frame to ours.
pub fn from_socketcan(any: &CanAnyFrame) -> Option<Frame> {
    use socketcan::Frame as _;
    let cid = |ext: bool, raw: u32| CanId::new(raw, ext).ok();
    match any {
        CanAnyFrame::Normal(f) => Frame::new(cid(f.is_extended(), f.raw_id())?, f.data()).ok(),
        CanAnyFrame::Remote(f) => {
            Frame::new_remote(cid(f.is_extended(), f.raw_id())?, f.dlc() as u8).ok()
        }
        CanAnyFrame::Fd(f) => Frame::new_fd(
            cid(f.is_extended(), f.raw_id())?,
            f.data(),
            f.is_brs(),
            f.flags().contains(FdFlags::ESI),
        )
        .ok(),
        CanAnyFrame::Error(f) => {
            let mut data = [0u8; 8];
            let d = f.data();
            data[..d.len().min(8)].copy_from_slice(&d[..d.len().min(8)]);
            Some(Frame::new_error(f.id_word() & 0x1FFF_FFFF, data))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conversion_round_trips() {
        let frames: Vec<Frame> = [
            "123#DEADBEEF",
            "1F334455#0102",
            "123#R4",
            "7FF#",
            "00000001##3AABBCCDDEEFF001122334455",
        ]
        .iter()
        .map(|s| s.parse().unwrap())
        .collect();
        for f in frames {
            let back = from_socketcan(&to_socketcan(&f).unwrap()).unwrap();
            assert_eq!(back, f, "{f}");
        }
    }
}
