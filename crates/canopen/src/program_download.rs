//! Program download (CiA 302-3): replacing a node's application program
//! over SDO, as a sans-IO state machine over SDO results, boot-ups and
//! time.
//!
//! The objects (program number `p`, the sub-index, 1..=254; 1 is the
//! application program of most devices):
//!
//! | object | type | meaning |
//! |---|---|---|
//! | 0x1F50:p program data | DOMAIN, wo | the program image, written with SDO block download |
//! | 0x1F51:p program control | UNSIGNED8, rw | write 0 stop, 1 start, 2 reset, 3 clear; read: 0 stopped, 1 running, 2 stopped (no program), 3 cleared |
//! | 0x1F56:p application software identification | UNSIGNED32, ro | what the device reports about the program (often a CRC or a date); compared before and after |
//! | 0x1F57:p flash status identification | UNSIGNED32, ro | bit 0: 1 = in progress (busy), 0 = finished; bits 1..=7: error code (below); bits 8..=15 reserved, 16..=31 manufacturer-specific |
//!
//! Flash status error codes (bits 1..=7 of 0x1F57, CiA 302-3 as device
//! manuals reproduce it): 0 no error, 1 no valid program, 2 data format
//! unknown, 3 data format error or data format does not match, 4 flash not
//! cleared before write, 5 flash write error, 6 general address error,
//! 7 flash secured (write access currently forbidden), 63 unspecified
//! error; others are reserved.
//!
//! The sequence [`ProgramDownload`] runs, one SDO transfer at a time:
//!
//! 1. read 0x1F56:p (identification before; an SDO abort here is no
//!    failure — a node without a valid program may have none — it only
//!    leaves the old identification unknown);
//! 2. write 0x1F51:p = 0 (stop the program);
//! 3. optionally write 0x1F51:p = 3 (clear the program);
//! 4. write 0x1F50:p with the image by SDO block download (falling back to
//!    segmented if the node refuses block transfer); the runner reports the
//!    bytes confirmed meanwhile;
//! 5. read 0x1F57:p until bit 0 is clear, every poll interval, at most the
//!    flash timeout from the end of the download; an error code fails the
//!    download;
//! 6. write 0x1F51:p = 1 (start the program): the node resets and boots.
//!    A node may reset before it confirms the write, so an SDO timeout
//!    here is no failure by itself: only no boot-up within the boot
//!    timeout is;
//! 7. wait for the node's boot-up (at most the boot timeout from the
//!    start request);
//! 8. read 0x1F56:p (identification after) and compare it with the
//!    expected one when the caller gave it.
//!
//! Every wait has a deadline: each SDO transfer its SDO timeout (the
//! runner's), the flash status and the boot-up theirs here. What is left
//! undone when the download fails or is cancelled is the caller's to
//! settle; after step 2 the node's program is stopped, so a failed or
//! cancelled download leaves it stopped, never running a half-written
//! image.

use std::fmt;
use std::time::Duration;

use crate::ids::{NodeId, ObjectAddress};
use crate::master::SdoRequest;
use crate::sdo::{AbortCode, SdoError, TransferOptions, TransferOutcome};

/// Program data (DOMAIN).
pub const PROGRAM_DATA: u16 = 0x1F50;
/// Program control (UNSIGNED8).
pub const PROGRAM_CONTROL: u16 = 0x1F51;
/// Application software identification (UNSIGNED32).
pub const SOFTWARE_IDENTIFICATION: u16 = 0x1F56;
/// Flash status identification (UNSIGNED32).
pub const FLASH_STATUS: u16 = 0x1F57;

/// Values written to program control (0x1F51).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum ProgramControl {
    /// Stop the program.
    Stop = 0,
    /// Start the program (the node resets and boots).
    Start = 1,
    /// Reset the program.
    Reset = 2,
    /// Clear (erase) the program.
    Clear = 3,
}

impl ProgramControl {
    /// The command from its byte.
    pub fn from_byte(b: u8) -> Option<ProgramControl> {
        match b {
            0 => Some(ProgramControl::Stop),
            1 => Some(ProgramControl::Start),
            2 => Some(ProgramControl::Reset),
            3 => Some(ProgramControl::Clear),
            _ => None,
        }
    }
}

/// A flash status identification (0x1F57) value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct FlashStatus(pub u32);

impl FlashStatus {
    /// Finished, no error.
    pub const OK: FlashStatus = FlashStatus(0);
    /// Bit 0: programming in progress.
    pub fn in_progress(self) -> bool {
        self.0 & 1 != 0
    }

    /// The error code (bits 1..=7), 0 for none.
    pub fn error_code(self) -> u8 {
        ((self.0 >> 1) & 0x7F) as u8
    }

    /// Finished with an error.
    pub fn is_error(self) -> bool {
        !self.in_progress() && self.error_code() != 0
    }

    /// The status with error `code` (busy clear).
    pub fn with_error(code: u8) -> FlashStatus {
        FlashStatus(u32::from(code & 0x7F) << 1)
    }

    /// The CiA 302-3 name of the error code.
    pub fn error_name(self) -> &'static str {
        match self.error_code() {
            0 => "no error",
            1 => "no valid program",
            2 => "data format unknown",
            3 => "data format error or data format does not match",
            4 => "flash not cleared before write",
            5 => "flash write error",
            6 => "general address error",
            7 => "flash secured (write access currently forbidden)",
            63 => "unspecified error",
            _ => "reserved error code",
        }
    }
}

impl fmt::Display for FlashStatus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "0x{:08X} ({}{}: {})",
            self.0,
            if self.in_progress() { "busy, " } else { "" },
            format_args!("error {}", self.error_code()),
            self.error_name()
        )
    }
}

/// The steps of a program download, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum ProgramStep {
    /// Reading 0x1F56 before.
    ReadIdentificationBefore,
    /// Writing 0x1F51 = 0.
    StopProgram,
    /// Writing 0x1F51 = 3.
    ClearProgram,
    /// Writing 0x1F50 by block download.
    DownloadData,
    /// Polling 0x1F57.
    WaitFlash,
    /// Writing 0x1F51 = 1.
    StartProgram,
    /// Waiting for the boot-up.
    WaitBootUp,
    /// Reading 0x1F56 after.
    ReadIdentificationAfter,
}

impl ProgramStep {
    /// Every step in order.
    pub const ALL: [ProgramStep; 8] = [
        ProgramStep::ReadIdentificationBefore,
        ProgramStep::StopProgram,
        ProgramStep::ClearProgram,
        ProgramStep::DownloadData,
        ProgramStep::WaitFlash,
        ProgramStep::StartProgram,
        ProgramStep::WaitBootUp,
        ProgramStep::ReadIdentificationAfter,
    ];

    /// A short stable name ("download-data").
    pub fn name(self) -> &'static str {
        match self {
            ProgramStep::ReadIdentificationBefore => "read-identification-before",
            ProgramStep::StopProgram => "stop-program",
            ProgramStep::ClearProgram => "clear-program",
            ProgramStep::DownloadData => "download-data",
            ProgramStep::WaitFlash => "wait-flash",
            ProgramStep::StartProgram => "start-program",
            ProgramStep::WaitBootUp => "wait-boot-up",
            ProgramStep::ReadIdentificationAfter => "read-identification-after",
        }
    }
}

impl fmt::Display for ProgramStep {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let what = match self {
            ProgramStep::ReadIdentificationBefore => {
                "reading the software identification 0x1F56 before"
            }
            ProgramStep::StopProgram => "stopping the program (0x1F51 = 0)",
            ProgramStep::ClearProgram => "clearing the program (0x1F51 = 3)",
            ProgramStep::DownloadData => "downloading the program data 0x1F50",
            ProgramStep::WaitFlash => "waiting for the flash status 0x1F57",
            ProgramStep::StartProgram => "starting the program (0x1F51 = 1)",
            ProgramStep::WaitBootUp => "waiting for the node's boot-up",
            ProgramStep::ReadIdentificationAfter => {
                "reading the software identification 0x1F56 after"
            }
        };
        f.write_str(what)
    }
}

/// Why a program download failed. Every variant names its step.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ProgramError {
    /// An SDO transfer of a step failed (abort by the node, timeout,
    /// protocol violation, cancel).
    #[error("{step}: {error}")]
    Sdo {
        /// The step.
        step: ProgramStep,
        /// The SDO failure (its abort code and CiA name).
        error: SdoError,
    },
    /// The node reported a flash error in 0x1F57.
    #[error("{}: the node reports flash status {status}", ProgramStep::WaitFlash)]
    Flash {
        /// The status read.
        status: FlashStatus,
    },
    /// 0x1F57 still said "in progress" after the flash timeout.
    #[error(
        "{}: still busy after {waited:?} (last status {last})",
        ProgramStep::WaitFlash
    )]
    FlashTimeout {
        /// How long it was polled.
        waited: Duration,
        /// The last status read.
        last: FlashStatus,
    },
    /// No boot-up within the boot timeout after the start request.
    #[error("{}: no boot-up within {waited:?} after the start request{}", ProgramStep::WaitBootUp, .start_error.as_ref().map(|e| format!(" (the start request itself: {e})")).unwrap_or_default())]
    NoBootUp {
        /// The boot timeout.
        waited: Duration,
        /// The start request's own failure when it had one (a timeout).
        start_error: Option<SdoError>,
    },
    /// A value read had the wrong size.
    #[error("{step}: the node answered {len} bytes, expected 1..=4")]
    BadValue {
        /// The step.
        step: ProgramStep,
        /// Bytes received.
        len: usize,
    },
    /// The identification after the download is not the expected one.
    #[error(
        "{}: the node reports 0x{found:08X}, expected 0x{expected:08X}",
        ProgramStep::ReadIdentificationAfter
    )]
    IdentificationMismatch {
        /// What the caller expected.
        expected: u32,
        /// What the node reports.
        found: u32,
    },
}

impl ProgramError {
    /// The step that failed.
    pub fn step(&self) -> ProgramStep {
        match self {
            ProgramError::Sdo { step, .. } | ProgramError::BadValue { step, .. } => *step,
            ProgramError::Flash { .. } | ProgramError::FlashTimeout { .. } => {
                ProgramStep::WaitFlash
            }
            ProgramError::NoBootUp { .. } => ProgramStep::WaitBootUp,
            ProgramError::IdentificationMismatch { .. } => ProgramStep::ReadIdentificationAfter,
        }
    }

    /// The SDO abort code on the wire, when an SDO transfer failed.
    pub fn abort_code(&self) -> Option<AbortCode> {
        match self {
            ProgramError::Sdo { error, .. } => Some(error.abort_code()),
            _ => None,
        }
    }
}

/// Waits of a program download.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ProgramTimeouts {
    /// Longest wait for the flash status to leave "in progress", from the
    /// end of the data download.
    pub flash: Duration,
    /// Time between two reads of the flash status.
    pub poll_interval: Duration,
    /// Longest wait for the boot-up, from the start request.
    pub boot: Duration,
}

impl Default for ProgramTimeouts {
    fn default() -> Self {
        ProgramTimeouts {
            flash: Duration::from_secs(60),
            poll_interval: Duration::from_millis(50),
            boot: Duration::from_secs(10),
        }
    }
}

/// What to download where.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProgramPlan {
    /// The node.
    pub node: NodeId,
    /// Program number: the sub-index of 0x1F50/51/56/57 (1..=254).
    pub program: u8,
    /// The image.
    pub image: Vec<u8>,
    /// The identification 0x1F56 must report afterwards, if known.
    pub expected_identification: Option<u32>,
    /// Clear the program (0x1F51 = 3) before downloading.
    pub clear: bool,
    /// The waits.
    pub timeouts: ProgramTimeouts,
}

/// A finished download.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProgramOutcome {
    /// 0x1F56 before (`None` when the node refused the read).
    pub old_identification: Option<u32>,
    /// 0x1F56 after.
    pub new_identification: u32,
    /// Bytes downloaded.
    pub bytes: usize,
    /// From the start to the end.
    pub duration: Duration,
    /// The data download step alone (for its throughput).
    pub download_duration: Duration,
}

/// What the runner must do.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ProgramAction {
    /// Run this SDO transfer with the node and feed its result to
    /// [`ProgramDownload::on_sdo_result`].
    Sdo(SdoRequest),
    /// A new step began.
    Step(ProgramStep),
    /// The download ended.
    Finished(Result<ProgramOutcome, ProgramError>),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Idle,
    /// An SDO transfer of the step runs.
    Transfer(ProgramStep),
    /// Waiting until the next flash status poll.
    FlashPause {
        until: Duration,
    },
    /// Start requested: waiting for its result and for the boot-up.
    Starting,
    /// The start request ended (or timed out): waiting for the boot-up.
    Booting,
    Done,
}

/// One program download. See the [module documentation](self).
#[derive(Debug)]
pub struct ProgramDownload {
    plan: ProgramPlan,
    state: State,
    started_at: Duration,
    download_started: Duration,
    download_ended: Duration,
    flash_deadline: Duration,
    boot_deadline: Duration,
    booted: bool,
    start_error: Option<SdoError>,
    last_flash: FlashStatus,
    old_identification: Option<u32>,
}

fn u32_of(bytes: &[u8]) -> Option<u32> {
    if bytes.is_empty() || bytes.len() > 4 {
        return None;
    }
    let mut b = [0u8; 4];
    b[..bytes.len()].copy_from_slice(bytes);
    Some(u32::from_le_bytes(b))
}

impl ProgramDownload {
    /// A download of `plan`, not yet started.
    pub fn new(plan: ProgramPlan) -> Self {
        ProgramDownload {
            plan,
            state: State::Idle,
            started_at: Duration::ZERO,
            download_started: Duration::ZERO,
            download_ended: Duration::ZERO,
            flash_deadline: Duration::ZERO,
            boot_deadline: Duration::ZERO,
            booted: false,
            start_error: None,
            last_flash: FlashStatus::OK,
            old_identification: None,
        }
    }

    /// The plan.
    pub fn plan(&self) -> &ProgramPlan {
        &self.plan
    }

    /// The node.
    pub fn node(&self) -> NodeId {
        self.plan.node
    }

    /// The step running now (`None` before the start and after the end).
    pub fn step(&self) -> Option<ProgramStep> {
        match self.state {
            State::Idle | State::Done => None,
            State::Transfer(s) => Some(s),
            State::FlashPause { .. } => Some(ProgramStep::WaitFlash),
            State::Starting => Some(ProgramStep::StartProgram),
            State::Booting => Some(ProgramStep::WaitBootUp),
        }
    }

    /// True once [`ProgramAction::Finished`] was given.
    pub fn is_finished(&self) -> bool {
        self.state == State::Done
    }

    fn addr(&self, index: u16) -> ObjectAddress {
        ObjectAddress::new(index, self.plan.program)
    }

    fn upload(&self, index: u16) -> SdoRequest {
        SdoRequest::Upload {
            addr: self.addr(index),
            opts: TransferOptions::default(),
        }
    }

    fn control(&self, c: ProgramControl) -> SdoRequest {
        SdoRequest::Download {
            addr: self.addr(PROGRAM_CONTROL),
            data: vec![c as u8],
            opts: TransferOptions::default(),
        }
    }

    fn transfer(&mut self, step: ProgramStep, now: Duration, out: &mut Vec<ProgramAction>) {
        let req = match step {
            ProgramStep::ReadIdentificationBefore | ProgramStep::ReadIdentificationAfter => {
                self.upload(SOFTWARE_IDENTIFICATION)
            }
            ProgramStep::StopProgram => self.control(ProgramControl::Stop),
            ProgramStep::ClearProgram => self.control(ProgramControl::Clear),
            ProgramStep::DownloadData => {
                self.download_started = now;
                SdoRequest::Download {
                    addr: self.addr(PROGRAM_DATA),
                    data: self.plan.image.clone(),
                    opts: TransferOptions::block(),
                }
            }
            ProgramStep::WaitFlash => self.upload(FLASH_STATUS),
            ProgramStep::StartProgram => {
                self.boot_deadline = now + self.plan.timeouts.boot;
                self.booted = false;
                self.state = State::Starting;
                out.push(ProgramAction::Step(step));
                out.push(ProgramAction::Sdo(self.control(ProgramControl::Start)));
                return;
            }
            ProgramStep::WaitBootUp => unreachable!("no transfer"),
        };
        let announce = !matches!(
            self.state,
            State::FlashPause { .. } | State::Transfer(ProgramStep::WaitFlash)
        );
        if announce || step != ProgramStep::WaitFlash {
            out.push(ProgramAction::Step(step));
        }
        self.state = State::Transfer(step);
        out.push(ProgramAction::Sdo(req));
    }

    fn finish(&mut self, r: Result<ProgramOutcome, ProgramError>, out: &mut Vec<ProgramAction>) {
        self.state = State::Done;
        out.push(ProgramAction::Finished(r));
    }

    fn fail(&mut self, e: ProgramError, out: &mut Vec<ProgramAction>) {
        self.finish(Err(e), out);
    }

    /// Starts the download at `now`.
    pub fn start(&mut self, now: Duration) -> Vec<ProgramAction> {
        let mut out = Vec::new();
        if self.state == State::Idle {
            self.started_at = now;
            self.transfer(ProgramStep::ReadIdentificationBefore, now, &mut out);
        }
        out
    }

    /// The result of the SDO transfer last asked for.
    pub fn on_sdo_result(
        &mut self,
        result: Result<TransferOutcome, SdoError>,
        now: Duration,
    ) -> Vec<ProgramAction> {
        let mut out = Vec::new();
        match self.state {
            State::Transfer(step) => self.transfer_done(step, result, now, &mut out),
            State::Starting => match result {
                Ok(_) => self.wait_boot(now, &mut out),
                // The node may reset before it answers.
                Err(e @ SdoError::Timeout { .. }) => {
                    self.start_error = Some(e);
                    self.wait_boot(now, &mut out)
                }
                Err(error) if !self.booted => self.fail(
                    ProgramError::Sdo {
                        step: ProgramStep::StartProgram,
                        error,
                    },
                    &mut out,
                ),
                Err(e) => {
                    self.start_error = Some(e);
                    self.wait_boot(now, &mut out)
                }
            },
            _ => {}
        }
        out
    }

    fn wait_boot(&mut self, now: Duration, out: &mut Vec<ProgramAction>) {
        out.push(ProgramAction::Step(ProgramStep::WaitBootUp));
        self.state = State::Booting;
        if self.booted {
            self.transfer(ProgramStep::ReadIdentificationAfter, now, out);
        }
    }

    fn transfer_done(
        &mut self,
        step: ProgramStep,
        result: Result<TransferOutcome, SdoError>,
        now: Duration,
        out: &mut Vec<ProgramAction>,
    ) {
        let value = match result {
            Ok(TransferOutcome::Uploaded(b)) => Some(b),
            Ok(TransferOutcome::Downloaded) => None,
            Err(SdoError::Aborted { .. }) if step == ProgramStep::ReadIdentificationBefore => {
                self.old_identification = None;
                self.transfer(ProgramStep::StopProgram, now, out);
                return;
            }
            Err(error) => return self.fail(ProgramError::Sdo { step, error }, out),
        };
        let read = |value: Option<Vec<u8>>| -> Result<u32, ProgramError> {
            let b = value.unwrap_or_default();
            u32_of(&b).ok_or(ProgramError::BadValue { step, len: b.len() })
        };
        match step {
            ProgramStep::ReadIdentificationBefore => match read(value) {
                Ok(v) => {
                    self.old_identification = Some(v);
                    self.transfer(ProgramStep::StopProgram, now, out);
                }
                Err(e) => self.fail(e, out),
            },
            ProgramStep::StopProgram => {
                let next = if self.plan.clear {
                    ProgramStep::ClearProgram
                } else {
                    ProgramStep::DownloadData
                };
                self.transfer(next, now, out);
            }
            ProgramStep::ClearProgram => self.transfer(ProgramStep::DownloadData, now, out),
            ProgramStep::DownloadData => {
                self.download_ended = now;
                self.flash_deadline = now + self.plan.timeouts.flash;
                self.transfer(ProgramStep::WaitFlash, now, out);
            }
            ProgramStep::WaitFlash => match read(value) {
                Ok(v) => {
                    let status = FlashStatus(v);
                    self.last_flash = status;
                    if status.in_progress() {
                        if now >= self.flash_deadline {
                            self.fail(
                                ProgramError::FlashTimeout {
                                    waited: self.plan.timeouts.flash,
                                    last: status,
                                },
                                out,
                            );
                        } else {
                            let until =
                                (now + self.plan.timeouts.poll_interval).min(self.flash_deadline);
                            self.state = State::FlashPause { until };
                        }
                    } else if status.error_code() != 0 {
                        self.fail(ProgramError::Flash { status }, out);
                    } else {
                        self.transfer(ProgramStep::StartProgram, now, out);
                    }
                }
                Err(e) => self.fail(e, out),
            },
            ProgramStep::ReadIdentificationAfter => match read(value) {
                Ok(found) => match self.plan.expected_identification {
                    Some(expected) if expected != found => self.fail(
                        ProgramError::IdentificationMismatch { expected, found },
                        out,
                    ),
                    _ => {
                        let outcome = ProgramOutcome {
                            old_identification: self.old_identification,
                            new_identification: found,
                            bytes: self.plan.image.len(),
                            duration: now.saturating_sub(self.started_at),
                            download_duration: self
                                .download_ended
                                .saturating_sub(self.download_started),
                        };
                        self.finish(Ok(outcome), out);
                    }
                },
                Err(e) => self.fail(e, out),
            },
            ProgramStep::StartProgram | ProgramStep::WaitBootUp => {}
        }
    }

    /// The node sent its boot-up at `now`.
    pub fn on_boot_up(&mut self, now: Duration) -> Vec<ProgramAction> {
        let mut out = Vec::new();
        match self.state {
            State::Starting => self.booted = true,
            State::Booting => {
                self.booted = true;
                self.transfer(ProgramStep::ReadIdentificationAfter, now, &mut out);
            }
            _ => {}
        }
        out
    }

    /// Advances time: the next flash status poll, the flash and boot
    /// deadlines.
    pub fn on_tick(&mut self, now: Duration) -> Vec<ProgramAction> {
        let mut out = Vec::new();
        match self.state {
            State::FlashPause { until } if now >= until => {
                self.transfer(ProgramStep::WaitFlash, now, &mut out);
            }
            State::Starting | State::Booting if now >= self.boot_deadline => {
                let start_error = self.start_error.take();
                self.fail(
                    ProgramError::NoBootUp {
                        waited: self.plan.timeouts.boot,
                        start_error,
                    },
                    &mut out,
                );
            }
            _ => {}
        }
        out
    }

    /// When [`ProgramDownload::on_tick`] next has something to do.
    pub fn next_deadline(&self) -> Option<Duration> {
        match self.state {
            State::FlashPause { until } => Some(until),
            State::Starting | State::Booting => Some(self.boot_deadline),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::master::{Master, MasterEvent, Output};
    use cangate_can::{CanId, Frame};

    const MS: Duration = Duration::from_millis(1);

    fn node() -> NodeId {
        NodeId::new(5).unwrap()
    }

    fn plan(clear: bool, expected: Option<u32>) -> ProgramPlan {
        ProgramPlan {
            node: node(),
            program: 1,
            image: (0..1000u32).map(|i| i as u8).collect(),
            expected_identification: expected,
            clear,
            timeouts: ProgramTimeouts {
                flash: 500 * MS,
                poll_interval: 100 * MS,
                boot: 1000 * MS,
            },
        }
    }

    /// The core driven through a real [`Master`]: the non-block steps are
    /// checked frame by frame against a scripted node; the block download
    /// of 0x1F50 is checked as a request and answered directly.
    struct Harness {
        pd: ProgramDownload,
        master: Master,
        now: Duration,
        steps: Vec<ProgramStep>,
        finished: Option<Result<ProgramOutcome, ProgramError>>,
        /// The frames the master sent for the SDO request in flight.
        sent: Vec<Vec<u8>>,
        next_id: u64,
    }

    impl Harness {
        fn new(plan: ProgramPlan) -> Self {
            Harness {
                pd: ProgramDownload::new(plan),
                master: Master::new(500 * MS),
                now: Duration::ZERO,
                steps: Vec::new(),
                finished: None,
                sent: Vec::new(),
                next_id: 1,
            }
        }

        fn apply(&mut self, actions: Vec<ProgramAction>) {
            for a in actions {
                match a {
                    ProgramAction::Step(s) => self.steps.push(s),
                    ProgramAction::Finished(r) => self.finished = Some(r),
                    ProgramAction::Sdo(SdoRequest::Download { addr, data, opts })
                        if addr.index == PROGRAM_DATA =>
                    {
                        assert_eq!(addr.sub, 1);
                        assert_eq!(data, self.pd.plan().image);
                        assert_eq!(opts, TransferOptions::block());
                        self.sent.push(b"block".to_vec());
                    }
                    ProgramAction::Sdo(req) => {
                        let mut out = Output::default();
                        self.master
                            .sdo(self.next_id, node(), req, self.now, &mut out);
                        self.next_id += 1;
                        for f in &out.frames {
                            assert_eq!(f.raw_id(), 0x605);
                            self.sent.push(f.data().to_vec());
                        }
                    }
                }
            }
        }

        fn start(&mut self) {
            let a = self.pd.start(self.now);
            self.apply(a);
        }

        /// Expects exactly `request` was sent; answers `response` (hex).
        fn exchange(&mut self, request: &str, response: &str) {
            assert_eq!(self.sent, vec![h(request)], "at {:?}", self.now);
            self.sent.clear();
            let mut out = Output::default();
            let f = Frame::new(CanId::Standard(0x585), &h(response)).unwrap();
            self.master.on_frame(&f, self.now, &mut out);
            self.feed(out);
        }

        fn feed(&mut self, out: Output) {
            for f in &out.frames {
                self.sent.push(f.data().to_vec());
            }
            for ev in out.events {
                if let MasterEvent::SdoCompleted { result, .. } = ev {
                    let a = self.pd.on_sdo_result(result, self.now);
                    self.apply(a);
                }
            }
        }

        fn block_done(&mut self, result: Result<TransferOutcome, SdoError>) {
            assert_eq!(self.sent, vec![b"block".to_vec()]);
            self.sent.clear();
            let a = self.pd.on_sdo_result(result, self.now);
            self.apply(a);
        }

        fn advance_to(&mut self, t: Duration) {
            self.now = t;
            let mut out = Output::default();
            self.master.on_tick(t, &mut out);
            self.feed(out);
            let a = self.pd.on_tick(t);
            self.apply(a);
        }

        fn boot_up(&mut self) {
            let a = self.pd.on_boot_up(self.now);
            self.apply(a);
        }
    }

    fn h(s: &str) -> Vec<u8> {
        s.split_whitespace()
            .map(|b| u8::from_str_radix(b, 16).unwrap())
            .collect()
    }

    #[test]
    fn the_whole_sequence_with_exact_bytes() {
        let mut t = Harness::new(plan(true, Some(0xCAFE_0002)));
        t.start();
        // 1. Read 0x1F56:01.
        t.exchange("40 56 1F 01 00 00 00 00", "43 56 1F 01 01 00 FE CA");
        // 2. Stop: 0x1F51:01 = 0 (expedited, 1 byte).
        t.exchange("2F 51 1F 01 00 00 00 00", "60 51 1F 01 00 00 00 00");
        // 3. Clear: 0x1F51:01 = 3.
        t.exchange("2F 51 1F 01 03 00 00 00", "60 51 1F 01 00 00 00 00");
        // 4. The block download of 0x1F50:01.
        t.now = 40 * MS;
        t.block_done(Ok(TransferOutcome::Downloaded));
        // 5. Flash status: busy, then (after the poll interval) done.
        t.exchange("40 57 1F 01 00 00 00 00", "43 57 1F 01 01 00 00 00");
        assert_eq!(t.pd.next_deadline(), Some(140 * MS));
        t.advance_to(139 * MS);
        assert!(t.sent.is_empty());
        t.advance_to(140 * MS);
        t.exchange("40 57 1F 01 00 00 00 00", "43 57 1F 01 00 00 00 00");
        // 6. Start: 0x1F51:01 = 1.
        t.exchange("2F 51 1F 01 01 00 00 00", "60 51 1F 01 00 00 00 00");
        assert_eq!(t.pd.step(), Some(ProgramStep::WaitBootUp));
        assert!(t.sent.is_empty());
        // 7. Boot-up, then 8. read 0x1F56:01 again.
        t.now = 300 * MS;
        t.boot_up();
        t.exchange("40 56 1F 01 00 00 00 00", "43 56 1F 01 02 00 FE CA");
        assert_eq!(
            t.finished,
            Some(Ok(ProgramOutcome {
                old_identification: Some(0xCAFE_0001),
                new_identification: 0xCAFE_0002,
                bytes: 1000,
                duration: 300 * MS,
                download_duration: 40 * MS,
            }))
        );
        assert_eq!(t.steps, ProgramStep::ALL.to_vec());
        assert!(t.pd.is_finished());
        assert_eq!(t.pd.next_deadline(), None);
    }

    #[test]
    fn without_clear_the_download_follows_the_stop() {
        let mut t = Harness::new(plan(false, None));
        t.start();
        t.exchange("40 56 1F 01 00 00 00 00", "43 56 1F 01 01 00 00 00");
        t.exchange("2F 51 1F 01 00 00 00 00", "60 51 1F 01 00 00 00 00");
        t.block_done(Ok(TransferOutcome::Downloaded));
        assert!(!t.steps.contains(&ProgramStep::ClearProgram));
    }

    #[test]
    fn an_abort_of_the_first_read_is_no_failure() {
        let mut t = Harness::new(plan(false, None));
        t.start();
        // 0x08000024 no data available.
        t.exchange("40 56 1F 01 00 00 00 00", "80 56 1F 01 24 00 00 08");
        t.exchange("2F 51 1F 01 00 00 00 00", "60 51 1F 01 00 00 00 00");
        t.block_done(Ok(TransferOutcome::Downloaded));
        t.exchange("40 57 1F 01 00 00 00 00", "43 57 1F 01 00 00 00 00");
        t.exchange("2F 51 1F 01 01 00 00 00", "60 51 1F 01 00 00 00 00");
        t.boot_up();
        t.exchange("40 56 1F 01 00 00 00 00", "43 56 1F 01 07 00 00 00");
        let out = t.finished.unwrap().unwrap();
        assert_eq!(out.old_identification, None);
        assert_eq!(out.new_identification, 7);
    }

    #[test]
    fn a_refused_stop_names_the_step_and_the_abort() {
        let mut t = Harness::new(plan(false, None));
        t.start();
        t.exchange("40 56 1F 01 00 00 00 00", "43 56 1F 01 01 00 00 00");
        t.exchange("2F 51 1F 01 00 00 00 00", "80 51 1F 01 22 00 00 08");
        let e = t.finished.unwrap().unwrap_err();
        assert_eq!(e.step(), ProgramStep::StopProgram);
        assert_eq!(
            e.abort_code(),
            Some(AbortCode::CANNOT_TRANSFER_DEVICE_STATE)
        );
        let text = e.to_string();
        assert!(text.contains("stopping the program"), "{text}");
        assert!(text.contains("present device state"), "{text}");
    }

    #[test]
    fn an_abort_during_the_block_download_fails_that_step() {
        let mut t = Harness::new(plan(false, None));
        t.start();
        t.exchange("40 56 1F 01 00 00 00 00", "43 56 1F 01 01 00 00 00");
        t.exchange("2F 51 1F 01 00 00 00 00", "60 51 1F 01 00 00 00 00");
        t.block_done(Err(SdoError::Aborted {
            addr: ObjectAddress::new(0x1F50, 1),
            code: AbortCode::HARDWARE_ERROR,
        }));
        let e = t.finished.unwrap().unwrap_err();
        assert_eq!(e.step(), ProgramStep::DownloadData);
        assert_eq!(e.abort_code(), Some(AbortCode::HARDWARE_ERROR));
    }

    #[test]
    fn a_flash_error_is_reported_with_its_cia_name() {
        let mut t = Harness::new(plan(false, None));
        t.start();
        t.exchange("40 56 1F 01 00 00 00 00", "43 56 1F 01 01 00 00 00");
        t.exchange("2F 51 1F 01 00 00 00 00", "60 51 1F 01 00 00 00 00");
        t.block_done(Ok(TransferOutcome::Downloaded));
        // Error 5 (flash write error) = 0x0A.
        t.exchange("40 57 1F 01 00 00 00 00", "43 57 1F 01 0A 00 00 00");
        let e = t.finished.unwrap().unwrap_err();
        assert_eq!(
            e,
            ProgramError::Flash {
                status: FlashStatus(0x0A)
            }
        );
        assert!(e.to_string().contains("flash write error"), "{e}");
    }

    #[test]
    fn a_flash_that_stays_busy_times_out() {
        let mut t = Harness::new(plan(false, None));
        t.start();
        t.exchange("40 56 1F 01 00 00 00 00", "43 56 1F 01 01 00 00 00");
        t.exchange("2F 51 1F 01 00 00 00 00", "60 51 1F 01 00 00 00 00");
        t.block_done(Ok(TransferOutcome::Downloaded));
        for k in 1..=5u32 {
            t.exchange("40 57 1F 01 00 00 00 00", "43 57 1F 01 01 00 00 00");
            t.advance_to(k * 100 * MS);
        }
        // The deadline (500 ms) reached: the poll at 500 ms is the last.
        t.exchange("40 57 1F 01 00 00 00 00", "43 57 1F 01 01 00 00 00");
        assert!(matches!(
            t.finished,
            Some(Err(ProgramError::FlashTimeout { .. }))
        ));
    }

    fn to_start(t: &mut Harness) {
        t.start();
        t.exchange("40 56 1F 01 00 00 00 00", "43 56 1F 01 01 00 00 00");
        t.exchange("2F 51 1F 01 00 00 00 00", "60 51 1F 01 00 00 00 00");
        t.block_done(Ok(TransferOutcome::Downloaded));
        t.exchange("40 57 1F 01 00 00 00 00", "43 57 1F 01 00 00 00 00");
    }

    #[test]
    fn no_boot_up_within_the_boot_timeout() {
        let mut t = Harness::new(plan(false, None));
        to_start(&mut t);
        t.exchange("2F 51 1F 01 01 00 00 00", "60 51 1F 01 00 00 00 00");
        assert_eq!(t.pd.next_deadline(), Some(1000 * MS));
        t.advance_to(999 * MS);
        assert!(t.finished.is_none());
        t.advance_to(1000 * MS);
        let e = t.finished.unwrap().unwrap_err();
        assert_eq!(e.step(), ProgramStep::WaitBootUp);
        assert!(e.to_string().contains("no boot-up"), "{e}");
    }

    #[test]
    fn a_node_that_resets_before_answering_the_start_is_fine() {
        let mut t = Harness::new(plan(false, Some(9)));
        to_start(&mut t);
        assert_eq!(t.sent, vec![h("2F 51 1F 01 01 00 00 00")]);
        t.sent.clear();
        // Boot-up instead of the answer; the SDO then times out.
        t.now = 10 * MS;
        t.boot_up();
        t.advance_to(500 * MS);
        assert_eq!(t.sent[0], h("80 51 1F 01 00 00 04 05"));
        t.sent.remove(0);
        // The channel settles, then 0x1F56 is read.
        t.advance_to(550 * MS);
        t.exchange("40 56 1F 01 00 00 00 00", "43 56 1F 01 08 00 00 00");
        assert_eq!(
            t.finished,
            Some(Err(ProgramError::IdentificationMismatch {
                expected: 9,
                found: 8
            }))
        );
    }

    #[test]
    fn flash_status_decoding() {
        assert!(FlashStatus(1).in_progress());
        assert!(!FlashStatus(1).is_error());
        assert_eq!(FlashStatus::with_error(5), FlashStatus(0x0A));
        assert_eq!(FlashStatus(0x0A).error_name(), "flash write error");
        assert_eq!(
            FlashStatus::with_error(63).error_name(),
            "unspecified error"
        );
        assert_eq!(FlashStatus(0xFFFF_0000).error_code(), 0);
    }
}
