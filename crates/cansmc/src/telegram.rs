//! CANsmc telegrams and their wire encoding.
//!
//! A telegram's head is the standard 11-bit CAN identifier:
//! `ID[10:6]` = function code (5 bits), `ID[5:0]` = address (6 bits).
//! Every telegram except MST carries 8 data bytes: a 16-bit control word
//! (master → slave, [`ControlWord`]) or status word (slave → master,
//! [`StatusWord`]) in bytes 0–1, then 6 function-specific bytes. All
//! multi-byte values are little-endian.
//!
//! Decoding is strict: anything the spec does not define (extended id, RTR,
//! CAN FD, wrong DLC, unknown function, reserved address, a telegram on the
//! wrong channel, non-zero reserved bits or bytes) is a [`CodecError`], so a
//! frame that decodes re-encodes to exactly the same bytes.

use std::fmt;

use cangate_can::{CanId, Frame};

/// The broadcast address (`0x3F`), used only by MST in this implementation.
pub const BROADCAST: u8 = 0x3F;

/// Length of every telegram except MST.
pub const TELEGRAM_LEN: usize = 8;

/// Why a frame is not a valid CANsmc telegram.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum CodecError {
    /// CANsmc uses standard 11-bit identifiers only.
    #[error("extended identifier 0x{0:08X}: CANsmc uses 11-bit identifiers only")]
    ExtendedId(u32),
    /// CANsmc uses data frames only.
    #[error("remote frame on id 0x{0:03X}: CANsmc uses data frames only")]
    Remote(u32),
    /// An error frame is not a telegram.
    #[error("error frame is not a CANsmc telegram")]
    ErrorFrame,
    /// CANsmc is classic CAN 2.0.
    #[error("CAN FD frame on id 0x{0:03X}: CANsmc uses classic CAN frames only")]
    Fd(u32),
    /// A function code the spec does not define.
    #[error("unknown function code 0x{0:02X}")]
    UnknownFunction(u8),
    /// The function is not sent on this channel (e.g. MST on channel 1,
    /// reject on channel 0).
    #[error("function {function} is not sent on channel {channel}")]
    WrongChannel {
        /// The telegram's function.
        function: Function,
        /// The channel it arrived on.
        channel: Channel,
    },
    /// The data length does not match the function.
    #[error("function {function}: {got} data bytes, expected {expected}")]
    WrongLength {
        /// The telegram's function.
        function: Function,
        /// The length the spec requires.
        expected: usize,
        /// The length received.
        got: usize,
    },
    /// The address is not valid for this function (MST must be broadcast;
    /// all others must be a slave address `1..=61`).
    #[error("function {function}: address 0x{address:02X} is not allowed")]
    BadAddress {
        /// The telegram's function.
        function: Function,
        /// The received address.
        address: u8,
    },
    /// A slave address outside `1..=61` (0, 0x3E and 0x3F are not slaves).
    #[error("slave address {0} is outside 1..=61")]
    BadSlaveAddress(u8),
    /// Reserved bits of the control or status word are set.
    #[error("reserved bits 0x{bits:04X} set in the {word}")]
    ReservedBits {
        /// "control word" or "status word".
        word: &'static str,
        /// The offending bits.
        bits: u16,
    },
    /// The parameter-write bit (MDTCW bit 3) on a function other than 0x05.
    #[error("parameter-write bit set on function {0}")]
    WriteBitOutsideParameter(Function),
    /// A reserved data byte is not zero.
    #[error("function {function}: reserved byte {index} is 0x{value:02X}, must be 0")]
    ReservedByte {
        /// The telegram's function.
        function: Function,
        /// Byte index within the 8 data bytes.
        index: usize,
        /// The received value.
        value: u8,
    },
    /// A reject telegram naming a function that cannot be rejected.
    #[error("reject telegram names function 0x{0:02X}, which cannot be rejected")]
    BadRejectedFunction(u8),
    /// A reject reason other than 1, 2 or 3.
    #[error("unknown reject reason {0}")]
    BadRejectReason(u8),
}

/// The two CANsmc channels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Channel {
    /// Channel 0: master → slaves (MST, MCT, MDT).
    Command,
    /// Channel 1: slaves → master (DCT, DT, reject).
    Status,
}

impl Channel {
    /// The channel number (0 or 1).
    pub fn index(self) -> u8 {
        match self {
            Channel::Command => 0,
            Channel::Status => 1,
        }
    }
}

impl fmt::Display for Channel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.index())
    }
}

/// A CANsmc function code (`ID[10:6]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Function {
    /// 0x00: master synchronisation telegram (channel 0, DLC 0, broadcast).
    Mst,
    /// 0x01: connection telegrams MCT / DCT (phase P0).
    Connection,
    /// 0x02: position control.
    Position,
    /// 0x03: velocity control.
    Velocity,
    /// 0x04: return to reference point.
    Homing,
    /// 0x05: parameter read/write.
    Parameter,
    /// 0x06: digital I/O.
    Io,
    /// 0x07: read encoder count.
    Encoder,
    /// 0x08: user-defined.
    User,
    /// 0x1F: the slave cannot do what was asked (channel 1 only).
    Reject,
}

impl Function {
    /// The 5-bit function code.
    pub fn code(self) -> u8 {
        match self {
            Function::Mst => 0x00,
            Function::Connection => 0x01,
            Function::Position => 0x02,
            Function::Velocity => 0x03,
            Function::Homing => 0x04,
            Function::Parameter => 0x05,
            Function::Io => 0x06,
            Function::Encoder => 0x07,
            Function::User => 0x08,
            Function::Reject => 0x1F,
        }
    }

    /// The function for a code, if the spec defines it.
    pub fn from_code(code: u8) -> Option<Self> {
        Some(match code {
            0x00 => Function::Mst,
            0x01 => Function::Connection,
            0x02 => Function::Position,
            0x03 => Function::Velocity,
            0x04 => Function::Homing,
            0x05 => Function::Parameter,
            0x06 => Function::Io,
            0x07 => Function::Encoder,
            0x08 => Function::User,
            0x1F => Function::Reject,
            _ => return None,
        })
    }

    /// The CAN identifier of this function addressed to/from `address`.
    pub fn can_id(self, address: u8) -> u16 {
        (u16::from(self.code()) << 6) | u16::from(address & 0x3F)
    }
}

impl fmt::Display for Function {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let name = match self {
            Function::Mst => "MST",
            Function::Connection => "connection",
            Function::Position => "position",
            Function::Velocity => "velocity",
            Function::Homing => "homing",
            Function::Parameter => "parameter",
            Function::Io => "io",
            Function::Encoder => "encoder",
            Function::User => "user",
            Function::Reject => "reject",
        };
        write!(f, "0x{:02X} ({name})", self.code())
    }
}

/// A slave address, `1..=61` (0 and 0x3E are reserved, 0x3F is broadcast).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct SmcAddress(u8);

impl SmcAddress {
    /// Lowest slave address.
    pub const MIN: u8 = 1;
    /// Highest slave address.
    pub const MAX: u8 = 61;

    /// A slave address, rejecting anything outside `1..=61`.
    pub fn new(address: u8) -> Result<Self, CodecError> {
        if (Self::MIN..=Self::MAX).contains(&address) {
            Ok(SmcAddress(address))
        } else {
            Err(CodecError::BadSlaveAddress(address))
        }
    }

    /// The address value.
    pub fn get(self) -> u8 {
        self.0
    }
}

impl fmt::Display for SmcAddress {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// The 4-bit cycle counter in MDTCW bits 12–15 (echoed in DTSW bits 12–15).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct CycleCounter(u8);

impl CycleCounter {
    /// A counter value; only the low 4 bits are kept (the counter is mod 16).
    pub fn new(value: u8) -> Self {
        CycleCounter(value & 0x0F)
    }

    /// The value, `0..=15`.
    pub fn get(self) -> u8 {
        self.0
    }

    /// The next cycle's counter (+1 mod 16).
    #[must_use]
    pub fn next(self) -> Self {
        CycleCounter((self.0 + 1) & 0x0F)
    }
}

/// The master's control word (MDTCW), bytes 0–1 of every master telegram
/// except MST. Bit 3 (parameter write) is carried by
/// [`Command::Parameter`]'s [`ParameterAccess`], since it only exists for
/// function 0x05.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct ControlWord {
    /// Bit 0: enable (servo on).
    pub enable: bool,
    /// Bit 1: halt — decelerate and hold position.
    pub halt: bool,
    /// Bit 2: fault reset (the slave acts on a 0→1 edge).
    pub fault_reset: bool,
    /// Bits 12–15: cycle counter.
    pub counter: CycleCounter,
}

impl ControlWord {
    const ENABLE: u16 = 1 << 0;
    const HALT: u16 = 1 << 1;
    const FAULT_RESET: u16 = 1 << 2;
    const PARAM_WRITE: u16 = 1 << 3;
    const RESERVED: u16 = 0x0FF0;

    /// The 16-bit value, with the parameter-write bit as given.
    pub fn to_bits(self, parameter_write: bool) -> u16 {
        let mut w = u16::from(self.counter.get()) << 12;
        if self.enable {
            w |= Self::ENABLE;
        }
        if self.halt {
            w |= Self::HALT;
        }
        if self.fault_reset {
            w |= Self::FAULT_RESET;
        }
        if parameter_write {
            w |= Self::PARAM_WRITE;
        }
        w
    }

    /// Parses a control word; returns it and the parameter-write bit.
    /// Reserved bits 4–11 must be zero.
    pub fn from_bits(w: u16) -> Result<(Self, bool), CodecError> {
        if w & Self::RESERVED != 0 {
            return Err(CodecError::ReservedBits {
                word: "control word",
                bits: w & Self::RESERVED,
            });
        }
        Ok((
            ControlWord {
                enable: w & Self::ENABLE != 0,
                halt: w & Self::HALT != 0,
                fault_reset: w & Self::FAULT_RESET != 0,
                counter: CycleCounter::new((w >> 12) as u8),
            },
            w & Self::PARAM_WRITE != 0,
        ))
    }
}

/// The slave's status word (DTSW), bytes 0–1 of every slave telegram.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct StatusWord {
    /// Bit 0: ready.
    pub ready: bool,
    /// Bit 1: enabled.
    pub enabled: bool,
    /// Bit 2: fault.
    pub fault: bool,
    /// Bit 3: target reached / in position.
    pub target_reached: bool,
    /// Bit 4: homed (reference point found).
    pub homed: bool,
    /// Bit 5: following error over limit.
    pub following_error: bool,
    /// Bit 6: parameter error (unknown number, read-only, or out of range).
    pub parameter_error: bool,
    /// Bits 12–15: echo of the MDTCW cycle counter this telegram answers.
    pub counter_echo: CycleCounter,
}

impl StatusWord {
    const RESERVED: u16 = 0x0F80;

    /// The 16-bit value.
    pub fn to_bits(self) -> u16 {
        let flags = [
            self.ready,
            self.enabled,
            self.fault,
            self.target_reached,
            self.homed,
            self.following_error,
            self.parameter_error,
        ];
        let mut w = u16::from(self.counter_echo.get()) << 12;
        for (bit, set) in flags.into_iter().enumerate() {
            if set {
                w |= 1 << bit;
            }
        }
        w
    }

    /// Parses a status word; reserved bits 7–11 must be zero.
    pub fn from_bits(w: u16) -> Result<Self, CodecError> {
        if w & Self::RESERVED != 0 {
            return Err(CodecError::ReservedBits {
                word: "status word",
                bits: w & Self::RESERVED,
            });
        }
        let bit = |n: u16| w & (1 << n) != 0;
        Ok(StatusWord {
            ready: bit(0),
            enabled: bit(1),
            fault: bit(2),
            target_reached: bit(3),
            homed: bit(4),
            following_error: bit(5),
            parameter_error: bit(6),
            counter_echo: CycleCounter::new((w >> 12) as u8),
        })
    }
}

/// Read or write, MDTCW bit 3 of a parameter telegram.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ParameterAccess {
    /// Bit 3 = 0: read (the value field is 0).
    Read,
    /// Bit 3 = 1: write the value.
    Write,
}

/// The 6 command bytes (MDTCD) of a master telegram, by function.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Command {
    /// MCT (0x01): cycle time in µs, slave count.
    Connect {
        /// Cycle time in µs (bytes 2–5).
        cycle_time_us: u32,
        /// Number of slaves (byte 6).
        slave_count: u8,
    },
    /// 0x02: target position in encoder counts.
    Position(i32),
    /// 0x03: target velocity, unit per parameter 2.
    Velocity(i32),
    /// 0x04: return to reference point with this homing method.
    Homing {
        /// Homing method (byte 2).
        method: u8,
    },
    /// 0x05: parameter read or write. A read carries value 0.
    Parameter {
        /// Read or write (MDTCW bit 3).
        access: ParameterAccess,
        /// Parameter number (bytes 2–3).
        number: u16,
        /// Value (bytes 4–7); 0 in a read request.
        value: i32,
    },
    /// 0x06: set the outputs selected by `mask`.
    Io {
        /// Output bits (bytes 2–5).
        outputs: u32,
        /// Output mask (bytes 6–7).
        mask: u16,
    },
    /// 0x07: request the encoder count (no data).
    Encoder,
    /// 0x08: user-defined bytes 2–7.
    User([u8; 6]),
}

impl Command {
    /// The function code this command is sent with.
    pub fn function(&self) -> Function {
        match self {
            Command::Connect { .. } => Function::Connection,
            Command::Position(_) => Function::Position,
            Command::Velocity(_) => Function::Velocity,
            Command::Homing { .. } => Function::Homing,
            Command::Parameter { .. } => Function::Parameter,
            Command::Io { .. } => Function::Io,
            Command::Encoder => Function::Encoder,
            Command::User(_) => Function::User,
        }
    }
}

/// Why a slave rejected a request (reject telegram byte 3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RejectReason {
    /// 1: the function is not supported.
    Unsupported,
    /// 2: the drive is not enabled.
    NotEnabled,
    /// 3: the drive is in fault.
    Fault,
}

impl RejectReason {
    /// The wire code.
    pub fn code(self) -> u8 {
        match self {
            RejectReason::Unsupported => 1,
            RejectReason::NotEnabled => 2,
            RejectReason::Fault => 3,
        }
    }

    /// The reason for a wire code.
    pub fn from_code(code: u8) -> Result<Self, CodecError> {
        match code {
            1 => Ok(RejectReason::Unsupported),
            2 => Ok(RejectReason::NotEnabled),
            3 => Ok(RejectReason::Fault),
            other => Err(CodecError::BadRejectReason(other)),
        }
    }
}

/// The 6 data bytes (DTSD) of a slave telegram, by function.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Feedback {
    /// DCT (0x01): device type and firmware version.
    Connect {
        /// Device type (bytes 2–3).
        device_type: u16,
        /// Firmware version (bytes 4–5).
        firmware_version: u16,
    },
    /// 0x02: actual position, or following error if parameter 1 = 1.
    Position(i32),
    /// 0x03: actual velocity.
    Velocity(i32),
    /// 0x04: actual position during homing.
    Homing(i32),
    /// 0x05: parameter answer.
    Parameter {
        /// Parameter number (bytes 2–3).
        number: u16,
        /// Value (bytes 4–7).
        value: i32,
    },
    /// 0x06: input bits.
    Io {
        /// Input bits (bytes 2–5).
        inputs: u32,
    },
    /// 0x07: encoder count.
    Encoder(i32),
    /// 0x08: user-defined bytes 2–7.
    User([u8; 6]),
    /// 0x1F: the slave cannot do what was asked.
    Reject {
        /// The rejected function (never MST or reject).
        function: Function,
        /// Why.
        reason: RejectReason,
    },
}

impl Feedback {
    /// The function code this feedback is sent with.
    pub fn function(&self) -> Function {
        match self {
            Feedback::Connect { .. } => Function::Connection,
            Feedback::Position(_) => Function::Position,
            Feedback::Velocity(_) => Function::Velocity,
            Feedback::Homing(_) => Function::Homing,
            Feedback::Parameter { .. } => Function::Parameter,
            Feedback::Io { .. } => Function::Io,
            Feedback::Encoder(_) => Function::Encoder,
            Feedback::User(_) => Function::User,
            Feedback::Reject { .. } => Function::Reject,
        }
    }
}

/// One CANsmc telegram.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Telegram {
    /// MST: master synchronisation, id 0x03F, no data, channel 0.
    Mst,
    /// A master telegram on channel 0: MCT ([`Command::Connect`]) or MDT.
    Master {
        /// The target slave.
        to: SmcAddress,
        /// MDTCW (bit 3 comes from the command).
        control: ControlWord,
        /// MDTCD.
        command: Command,
    },
    /// A slave telegram on channel 1: DCT ([`Feedback::Connect`]), DT or
    /// reject.
    Slave {
        /// The sending slave.
        from: SmcAddress,
        /// DTSW.
        status: StatusWord,
        /// DTSD.
        feedback: Feedback,
    },
}

fn put_i32(d: &mut [u8; 8], v: i32) {
    d[2..6].copy_from_slice(&v.to_le_bytes());
}

fn put_u32(d: &mut [u8; 8], v: u32) {
    d[2..6].copy_from_slice(&v.to_le_bytes());
}

fn u16_at(d: &[u8], i: usize) -> u16 {
    u16::from_le_bytes([d[i], d[i + 1]])
}

fn u32_at(d: &[u8], i: usize) -> u32 {
    u32::from_le_bytes([d[i], d[i + 1], d[i + 2], d[i + 3]])
}

fn i32_at(d: &[u8], i: usize) -> i32 {
    u32_at(d, i) as i32
}

/// Checks that `d[from..]` is all zero.
fn reserved(d: &[u8], function: Function, from: usize) -> Result<(), CodecError> {
    match d.iter().enumerate().skip(from).find(|(_, b)| **b != 0) {
        Some((index, &value)) => Err(CodecError::ReservedByte {
            function,
            index,
            value,
        }),
        None => Ok(()),
    }
}

impl Telegram {
    /// The function code.
    pub fn function(&self) -> Function {
        match self {
            Telegram::Mst => Function::Mst,
            Telegram::Master { command, .. } => command.function(),
            Telegram::Slave { feedback, .. } => feedback.function(),
        }
    }

    /// The channel this telegram travels on.
    pub fn channel(&self) -> Channel {
        match self {
            Telegram::Mst | Telegram::Master { .. } => Channel::Command,
            Telegram::Slave { .. } => Channel::Status,
        }
    }

    /// The 6-bit address of the identifier.
    pub fn address(&self) -> u8 {
        match self {
            Telegram::Mst => BROADCAST,
            Telegram::Master { to, .. } => to.get(),
            Telegram::Slave { from, .. } => from.get(),
        }
    }

    /// The 11-bit CAN identifier.
    pub fn can_id(&self) -> u16 {
        self.function().can_id(self.address())
    }

    /// The 0 or 8 data bytes.
    pub fn payload(&self) -> ([u8; 8], usize) {
        let mut d = [0u8; 8];
        match *self {
            Telegram::Mst => return (d, 0),
            Telegram::Master {
                control, command, ..
            } => {
                let write = matches!(
                    command,
                    Command::Parameter {
                        access: ParameterAccess::Write,
                        ..
                    }
                );
                d[0..2].copy_from_slice(&control.to_bits(write).to_le_bytes());
                match command {
                    Command::Connect {
                        cycle_time_us,
                        slave_count,
                    } => {
                        put_u32(&mut d, cycle_time_us);
                        d[6] = slave_count;
                    }
                    Command::Position(v) | Command::Velocity(v) => put_i32(&mut d, v),
                    Command::Homing { method } => d[2] = method,
                    Command::Parameter { number, value, .. } => {
                        d[2..4].copy_from_slice(&number.to_le_bytes());
                        d[4..8].copy_from_slice(&value.to_le_bytes());
                    }
                    Command::Io { outputs, mask } => {
                        put_u32(&mut d, outputs);
                        d[6..8].copy_from_slice(&mask.to_le_bytes());
                    }
                    Command::Encoder => {}
                    Command::User(bytes) => d[2..8].copy_from_slice(&bytes),
                }
            }
            Telegram::Slave {
                status, feedback, ..
            } => {
                d[0..2].copy_from_slice(&status.to_bits().to_le_bytes());
                match feedback {
                    Feedback::Connect {
                        device_type,
                        firmware_version,
                    } => {
                        d[2..4].copy_from_slice(&device_type.to_le_bytes());
                        d[4..6].copy_from_slice(&firmware_version.to_le_bytes());
                    }
                    Feedback::Position(v)
                    | Feedback::Velocity(v)
                    | Feedback::Homing(v)
                    | Feedback::Encoder(v) => put_i32(&mut d, v),
                    Feedback::Parameter { number, value } => {
                        d[2..4].copy_from_slice(&number.to_le_bytes());
                        d[4..8].copy_from_slice(&value.to_le_bytes());
                    }
                    Feedback::Io { inputs } => put_u32(&mut d, inputs),
                    Feedback::User(bytes) => d[2..8].copy_from_slice(&bytes),
                    Feedback::Reject { function, reason } => {
                        d[2] = function.code();
                        d[3] = reason.code();
                    }
                }
            }
        }
        (d, TELEGRAM_LEN)
    }

    /// Encodes the telegram as a classic standard-id data frame. Send it on
    /// [`Telegram::channel`].
    pub fn encode(&self) -> Frame {
        let (d, len) = self.payload();
        match Frame::new(CanId::Standard(self.can_id()), &d[..len]) {
            Ok(frame) => frame,
            // The id is at most 11 bits and the payload at most 8 bytes.
            Err(e) => unreachable!("CANsmc telegram always fits a classic frame: {e}"),
        }
    }

    /// Decodes a frame received on `channel`, rejecting anything the spec
    /// does not define.
    pub fn decode(frame: &Frame, channel: Channel) -> Result<Telegram, CodecError> {
        if frame.is_error() {
            return Err(CodecError::ErrorFrame);
        }
        let id = match frame.id() {
            CanId::Extended(id) => return Err(CodecError::ExtendedId(id)),
            CanId::Standard(id) => id,
        };
        if frame.is_remote() {
            return Err(CodecError::Remote(id.into()));
        }
        if frame.is_fd() {
            return Err(CodecError::Fd(id.into()));
        }
        let code = (id >> 6) as u8;
        let address = (id & 0x3F) as u8;
        let function = Function::from_code(code).ok_or(CodecError::UnknownFunction(code))?;
        let on_channel = match function {
            Function::Mst => channel == Channel::Command,
            Function::Reject => channel == Channel::Status,
            _ => true,
        };
        if !on_channel {
            return Err(CodecError::WrongChannel { function, channel });
        }
        let d = frame.data();
        let expected = if function == Function::Mst {
            0
        } else {
            TELEGRAM_LEN
        };
        if d.len() != expected {
            return Err(CodecError::WrongLength {
                function,
                expected,
                got: d.len(),
            });
        }
        if function == Function::Mst {
            return if address == BROADCAST {
                Ok(Telegram::Mst)
            } else {
                Err(CodecError::BadAddress { function, address })
            };
        }
        let addr =
            SmcAddress::new(address).map_err(|_| CodecError::BadAddress { function, address })?;
        match channel {
            Channel::Command => decode_master(function, addr, d),
            Channel::Status => decode_slave(function, addr, d),
        }
    }
}

fn decode_master(function: Function, to: SmcAddress, d: &[u8]) -> Result<Telegram, CodecError> {
    let (control, write) = ControlWord::from_bits(u16_at(d, 0))?;
    if write && function != Function::Parameter {
        return Err(CodecError::WriteBitOutsideParameter(function));
    }
    let command = match function {
        Function::Connection => {
            reserved(d, function, 7)?;
            Command::Connect {
                cycle_time_us: u32_at(d, 2),
                slave_count: d[6],
            }
        }
        Function::Position => {
            reserved(d, function, 6)?;
            Command::Position(i32_at(d, 2))
        }
        Function::Velocity => {
            reserved(d, function, 6)?;
            Command::Velocity(i32_at(d, 2))
        }
        Function::Homing => {
            reserved(d, function, 3)?;
            Command::Homing { method: d[2] }
        }
        Function::Parameter => Command::Parameter {
            access: if write {
                ParameterAccess::Write
            } else {
                ParameterAccess::Read
            },
            number: u16_at(d, 2),
            value: i32_at(d, 4),
        },
        Function::Io => Command::Io {
            outputs: u32_at(d, 2),
            mask: u16_at(d, 6),
        },
        Function::Encoder => {
            reserved(d, function, 2)?;
            Command::Encoder
        }
        Function::User => {
            let mut b = [0u8; 6];
            b.copy_from_slice(&d[2..8]);
            Command::User(b)
        }
        // MST is handled by the caller; reject never reaches here (channel check).
        Function::Mst | Function::Reject => {
            return Err(CodecError::WrongChannel {
                function,
                channel: Channel::Command,
            });
        }
    };
    Ok(Telegram::Master {
        to,
        control,
        command,
    })
}

fn decode_slave(function: Function, from: SmcAddress, d: &[u8]) -> Result<Telegram, CodecError> {
    let status = StatusWord::from_bits(u16_at(d, 0))?;
    let feedback = match function {
        Function::Connection => {
            reserved(d, function, 6)?;
            Feedback::Connect {
                device_type: u16_at(d, 2),
                firmware_version: u16_at(d, 4),
            }
        }
        Function::Position => {
            reserved(d, function, 6)?;
            Feedback::Position(i32_at(d, 2))
        }
        Function::Velocity => {
            reserved(d, function, 6)?;
            Feedback::Velocity(i32_at(d, 2))
        }
        Function::Homing => {
            reserved(d, function, 6)?;
            Feedback::Homing(i32_at(d, 2))
        }
        Function::Parameter => Feedback::Parameter {
            number: u16_at(d, 2),
            value: i32_at(d, 4),
        },
        Function::Io => {
            reserved(d, function, 6)?;
            Feedback::Io {
                inputs: u32_at(d, 2),
            }
        }
        Function::Encoder => {
            reserved(d, function, 6)?;
            Feedback::Encoder(i32_at(d, 2))
        }
        Function::User => {
            let mut b = [0u8; 6];
            b.copy_from_slice(&d[2..8]);
            Feedback::User(b)
        }
        Function::Reject => {
            reserved(d, function, 4)?;
            let rejected = match Function::from_code(d[2]) {
                Some(f) if f != Function::Mst && f != Function::Reject => f,
                _ => return Err(CodecError::BadRejectedFunction(d[2])),
            };
            Feedback::Reject {
                function: rejected,
                reason: RejectReason::from_code(d[3])?,
            }
        }
        Function::Mst => {
            return Err(CodecError::WrongChannel {
                function,
                channel: Channel::Status,
            });
        }
    };
    Ok(Telegram::Slave {
        from,
        status,
        feedback,
    })
}
