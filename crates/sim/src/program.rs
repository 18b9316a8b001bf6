//! Program download (CiA 302-3) in a simulated node: program number 1 of
//! 0x1F50 (program data), 0x1F51 (program control), 0x1F56 (application
//! software identification) and 0x1F57 (flash status identification),
//! with a simulated flash delay and injectable faults. [`SimNode`] serves
//! these objects whatever its EDS says.
//!
//! | object | behaviour |
//! |---|---|
//! | 0x1F50:01 | write only (read: 0x06010001). Refused with 0x08000022 (present device state) at the initiate while the program runs or the flash is busy. A completed download starts "flashing": 0x1F57 busy for [`ProgramOptions::flash_time_per_kib`] per started KiB, then OK (the image becomes the program) or the injected flash error (the program is invalid) |
//! | 0x1F51:01 | read: 0 stopped, 1 running, 3 cleared (no valid program). Write 0 stop, 3 clear (stopped, identification 0), 1 start (or 2 reset): refused with 0x08000022 without a valid program or while flashing; otherwise the write is confirmed, then the node resets (NMT reset node: boot-up, pre-operational) running the program |
//! | 0x1F56:01 | read only: the CRC-32 (IEEE) of the program image; [`INITIAL_IDENTIFICATION`] for the program the node starts with, 0 when cleared |
//! | 0x1F57:01 | read only: bit 0 busy while flashing; bits 1..=7 the error code of the last download (5 flash write error, …) |
//! | sub 0 | 1 (one program) |
//!
//! Faults ([`ProgramFaults`]) each act once, on the next download or
//! start, then clear themselves: a flash error code; an abort of the data
//! download after N bytes (counted in whole 7-byte segments received, so
//! the abort comes with the first segment that reaches N); a start that
//! is confirmed but never boots. The program survives resets and power
//! cycles (it is in "flash").
//!
//! [`SimNode`]: crate::SimNode

use std::time::Duration;

use cangate_canopen::ObjectAddress;
use cangate_canopen::program_download::{
    FLASH_STATUS, FlashStatus, PROGRAM_CONTROL, PROGRAM_DATA, SOFTWARE_IDENTIFICATION,
};
use cangate_canopen::sdo::AbortCode;

/// 0x1F56 of the program a simulated node starts with.
pub const INITIAL_IDENTIFICATION: u32 = 0x0001_0000;

/// How the simulated flash behaves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ProgramOptions {
    /// Flash time per started KiB of image (0x1F57 busy meanwhile).
    pub flash_time_per_kib: Duration,
}

impl Default for ProgramOptions {
    fn default() -> Self {
        ProgramOptions {
            flash_time_per_kib: Duration::from_millis(1),
        }
    }
}

/// Faults of the next program download; each clears itself once used.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ProgramFaults {
    /// The next flashing ends with this error code (1..=127) in 0x1F57.
    pub flash_error: Option<u8>,
    /// The next data download is aborted by the node with this code once
    /// this many bytes arrived.
    pub abort_at: Option<(usize, AbortCode)>,
    /// The next start is confirmed, but the node never boots.
    pub no_boot: bool,
}

/// The program state of a simulated node. See the [module
/// documentation](self).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SimProgram {
    options: ProgramOptions,
    faults: ProgramFaults,
    running: bool,
    valid: bool,
    identification: u32,
    /// Flashing until then; the status and the identification it ends with.
    flashing: Option<(Duration, FlashStatus, Option<u32>)>,
    status: FlashStatus,
    /// Bytes of the running 0x1F50 download received so far.
    received: usize,
    downloads: u64,
}

impl Default for SimProgram {
    fn default() -> Self {
        Self::new(ProgramOptions::default())
    }
}

/// What a program object write asks of the node beyond the answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProgramEffect {
    /// Nothing more.
    None,
    /// Reset the node (NMT reset node) after the answer.
    Reset,
}

impl SimProgram {
    /// A node running its initial program.
    pub fn new(options: ProgramOptions) -> Self {
        SimProgram {
            options,
            faults: ProgramFaults::default(),
            running: true,
            valid: true,
            identification: INITIAL_IDENTIFICATION,
            flashing: None,
            status: FlashStatus::OK,
            received: 0,
            downloads: 0,
        }
    }

    /// True for the objects served here (0x1F50, 0x1F51, 0x1F56, 0x1F57).
    pub fn serves(addr: ObjectAddress) -> bool {
        matches!(
            addr.index,
            PROGRAM_DATA | PROGRAM_CONTROL | SOFTWARE_IDENTIFICATION | FLASH_STATUS
        )
    }

    /// Sets the faults of the next download (replacing the previous ones).
    pub fn set_faults(&mut self, faults: ProgramFaults) {
        self.faults = faults;
    }

    /// The faults still armed.
    pub fn faults(&self) -> ProgramFaults {
        self.faults
    }

    /// The program runs.
    pub fn running(&self) -> bool {
        self.running
    }

    /// 0x1F56 now.
    pub fn identification(&self) -> u32 {
        self.identification
    }

    /// Completed data downloads.
    pub fn downloads(&self) -> u64 {
        self.downloads
    }

    fn settle(&mut self, now: Duration) {
        if let Some((until, status, id)) = self.flashing
            && now >= until
        {
            self.flashing = None;
            self.status = status;
            match id {
                Some(id) => {
                    self.valid = true;
                    self.identification = id;
                }
                None => self.valid = false,
            }
        }
    }

    /// 0x1F57 at `now`.
    pub fn flash_status(&mut self, now: Duration) -> FlashStatus {
        self.settle(now);
        match self.flashing {
            Some(_) => FlashStatus(self.status.0 | 1),
            None => self.status,
        }
    }

    /// When the flashing ends, if it runs.
    pub fn next_deadline(&self) -> Option<Duration> {
        self.flashing.map(|(until, _, _)| until)
    }

    /// Whether a download of 0x1F50:`sub` may start now; the abort code if
    /// not.
    pub fn check_download_start(&mut self, sub: u8, now: Duration) -> Result<(), AbortCode> {
        self.settle(now);
        if sub != 1 {
            return Err(AbortCode::SUB_INDEX_DOES_NOT_EXIST);
        }
        if self.running || self.flashing.is_some() {
            return Err(AbortCode::CANNOT_TRANSFER_DEVICE_STATE);
        }
        self.received = 0;
        Ok(())
    }

    /// Counts `bytes` more of the running data download; the abort code
    /// when the injected abort is due.
    pub fn on_data(&mut self, bytes: usize) -> Option<AbortCode> {
        self.received += bytes;
        match self.faults.abort_at {
            Some((at, code)) if self.received >= at => {
                self.faults.abort_at = None;
                Some(code)
            }
            _ => None,
        }
    }

    /// Reads a program object.
    pub fn read(&mut self, addr: ObjectAddress, now: Duration) -> Result<Vec<u8>, AbortCode> {
        self.settle(now);
        if addr.sub == 0 {
            return Ok(vec![1]);
        }
        if addr.sub != 1 {
            return Err(AbortCode::SUB_INDEX_DOES_NOT_EXIST);
        }
        match addr.index {
            PROGRAM_DATA => Err(AbortCode::READ_OF_WRITE_ONLY),
            PROGRAM_CONTROL => Ok(vec![if self.running {
                1
            } else if self.valid {
                0
            } else {
                3
            }]),
            SOFTWARE_IDENTIFICATION => Ok(self.identification.to_le_bytes().to_vec()),
            FLASH_STATUS => Ok(self.flash_status(now).0.to_le_bytes().to_vec()),
            _ => Err(AbortCode::OBJECT_DOES_NOT_EXIST),
        }
    }

    /// Writes a program object.
    pub fn write(
        &mut self,
        addr: ObjectAddress,
        data: &[u8],
        now: Duration,
    ) -> Result<ProgramEffect, AbortCode> {
        self.settle(now);
        if addr.sub == 0 {
            return Err(AbortCode::WRITE_OF_READ_ONLY);
        }
        if addr.sub != 1 {
            return Err(AbortCode::SUB_INDEX_DOES_NOT_EXIST);
        }
        match addr.index {
            PROGRAM_DATA => {
                if self.running || self.flashing.is_some() {
                    return Err(AbortCode::CANNOT_TRANSFER_DEVICE_STATE);
                }
                let kib = data.len().div_ceil(1024).max(1) as u32;
                let until = now + self.options.flash_time_per_kib * kib;
                let outcome = match self.faults.flash_error.take() {
                    Some(code) => (FlashStatus::with_error(code.max(1)), None),
                    None => (FlashStatus::OK, Some(crc32(data))),
                };
                self.valid = false;
                self.flashing = Some((until, outcome.0, outcome.1));
                self.downloads += 1;
                Ok(ProgramEffect::None)
            }
            PROGRAM_CONTROL => {
                let [cmd] = data else {
                    return Err(if data.len() > 1 {
                        AbortCode::LENGTH_TOO_HIGH
                    } else {
                        AbortCode::LENGTH_TOO_LOW
                    });
                };
                match cmd {
                    0 => {
                        self.running = false;
                        Ok(ProgramEffect::None)
                    }
                    1 | 2 => {
                        if !self.valid || self.flashing.is_some() {
                            return Err(AbortCode::CANNOT_TRANSFER_DEVICE_STATE);
                        }
                        self.running = true;
                        if std::mem::take(&mut self.faults.no_boot) {
                            Ok(ProgramEffect::None)
                        } else {
                            Ok(ProgramEffect::Reset)
                        }
                    }
                    3 => {
                        if self.flashing.is_some() {
                            return Err(AbortCode::CANNOT_TRANSFER_DEVICE_STATE);
                        }
                        self.running = false;
                        self.valid = false;
                        self.identification = 0;
                        self.status = FlashStatus::OK;
                        Ok(ProgramEffect::None)
                    }
                    _ => Err(AbortCode::INVALID_VALUE),
                }
            }
            SOFTWARE_IDENTIFICATION | FLASH_STATUS => Err(AbortCode::WRITE_OF_READ_ONLY),
            _ => Err(AbortCode::OBJECT_DOES_NOT_EXIST),
        }
    }
}

/// CRC-32 (IEEE 802.3, reflected, as zip and Ethernet): what the simulated
/// node reports as the identification of an image.
pub fn crc32(data: &[u8]) -> u32 {
    const TABLE: [u32; 256] = {
        let mut t = [0u32; 256];
        let mut i = 0;
        while i < 256 {
            let mut c = i as u32;
            let mut k = 0;
            while k < 8 {
                c = if c & 1 != 0 {
                    0xEDB8_8320 ^ (c >> 1)
                } else {
                    c >> 1
                };
                k += 1;
            }
            t[i] = c;
            i += 1;
        }
        t
    };
    let mut c = !0u32;
    for &b in data {
        c = TABLE[((c ^ u32::from(b)) & 0xFF) as usize] ^ (c >> 8);
    }
    !c
}

/// A deterministic pseudo-random program image of `len` bytes (xorshift32
/// from `seed`): realistic bit stuffing on the wire, reproducible
/// identification (0x1F56), for tests and benchmarks of program download.
pub fn test_image(len: usize, seed: u32) -> Vec<u8> {
    let mut x = seed | 1;
    (0..len)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            (x >> 24) as u8
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    fn at(index: u16) -> ObjectAddress {
        ObjectAddress::new(index, 1)
    }

    #[test]
    fn crc32_check_value() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn download_flash_start() {
        let mut p = SimProgram::default();
        assert_eq!(
            p.check_download_start(1, Duration::ZERO),
            Err(AbortCode::CANNOT_TRANSFER_DEVICE_STATE)
        );
        assert_eq!(
            p.write(at(PROGRAM_CONTROL), &[0], Duration::ZERO),
            Ok(ProgramEffect::None)
        );
        assert_eq!(p.check_download_start(1, Duration::ZERO), Ok(()));
        let image = vec![0x5A; 2048];
        p.write(at(PROGRAM_DATA), &image, Duration::ZERO).unwrap();
        assert!(p.flash_status(MS).in_progress());
        assert_eq!(
            p.write(at(PROGRAM_CONTROL), &[1], MS),
            Err(AbortCode::CANNOT_TRANSFER_DEVICE_STATE)
        );
        assert_eq!(p.next_deadline(), Some(2 * MS));
        assert_eq!(p.flash_status(2 * MS), FlashStatus::OK);
        assert_eq!(p.identification(), crc32(&image));
        assert_eq!(
            p.write(at(PROGRAM_CONTROL), &[1], 2 * MS),
            Ok(ProgramEffect::Reset)
        );
        assert!(p.running());
    }

    #[test]
    fn faults_act_once() {
        let mut p = SimProgram::default();
        p.set_faults(ProgramFaults {
            flash_error: Some(5),
            abort_at: Some((100, AbortCode::HARDWARE_ERROR)),
            no_boot: true,
        });
        p.write(at(PROGRAM_CONTROL), &[0], Duration::ZERO).unwrap();
        p.check_download_start(1, Duration::ZERO).unwrap();
        assert_eq!(p.on_data(98), None);
        assert_eq!(p.on_data(7), Some(AbortCode::HARDWARE_ERROR));
        assert_eq!(p.on_data(7), None);
        p.write(at(PROGRAM_DATA), &[1, 2, 3], Duration::ZERO)
            .unwrap();
        let s = p.flash_status(10 * MS);
        assert_eq!(s.error_code(), 5);
        // No valid program: no start.
        assert_eq!(
            p.write(at(PROGRAM_CONTROL), &[1], 10 * MS),
            Err(AbortCode::CANNOT_TRANSFER_DEVICE_STATE)
        );
        p.write(at(PROGRAM_DATA), &[1, 2, 3], 10 * MS).unwrap();
        assert_eq!(p.flash_status(20 * MS), FlashStatus::OK);
        assert_eq!(
            p.write(at(PROGRAM_CONTROL), &[1], 20 * MS),
            Ok(ProgramEffect::None)
        );
        p.write(at(PROGRAM_CONTROL), &[0], 20 * MS).unwrap();
        assert_eq!(
            p.write(at(PROGRAM_CONTROL), &[1], 20 * MS),
            Ok(ProgramEffect::Reset)
        );
    }
}
