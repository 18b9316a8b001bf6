//! CANsmc slave protocol state machine (sans-IO).
//!
//! [`SlaveProtocol`] is the protocol half of a CANsmc slave: it takes the
//! frames seen on channel 0 (the command channel) with the time they
//! arrived and returns the telegram to send on channel 1, if any. The drive
//! behind it is a [`SlaveApplication`]: the protocol tells it when a cycle
//! starts (MST) and which command takes effect then, asks it for feedback,
//! parameters and whether a command can be taken, and does everything else
//! — addressing, counter echo, reject telegrams, the slave's cycle end —
//! itself. Nothing here touches a socket, sleeps or needs an async runtime;
//! time is a [`Duration`] from an arbitrary monotonic origin chosen by the
//! caller.
//!
//! # Behaviour
//!
//! | telegram | answer |
//! |---|---|
//! | MST (`0x03F`) | none; the command received in the previous cycle takes effect ([`SlaveApplication::on_mst`]) and the feedback is sampled and cached ([`SlaveApplication::sample`]) |
//! | MCT (0x01) | DCT at once: device type, firmware version, status word from a fresh sample, MCT counter echoed |
//! | parameter (0x05) | parameter telegram at once with the same number and the value read (or written); on error DTSW bit 6 set and value 0 |
//! | MDT 0x02..=0x04, 0x06..=0x08 | the DT of the same function at once, carrying the feedback cached at the last MST and the MDT's counter; or a reject telegram (0x1F) |
//! | anything for another slave | nothing (not counted) |
//! | a frame that does not decode | nothing; counted in [`SlaveStats::malformed`] |
//!
//! DT data by function: position → [`Sample::position_feedback`] (actual
//! position or following error per parameter 1: the application fills it),
//! velocity → [`Sample::velocity`], homing → [`Sample::position`], io →
//! [`Sample::inputs`], encoder → [`Sample::encoder`], user → the MDT's six
//! bytes echoed (see [`SlaveApplication::user_reply`]).
//!
//! # Choices where the spec is silent *(fixed here)*
//!
//! - **Before the first MCT** the slave is not connected: MST and MDTs are
//!   ignored (counted in [`SlaveStats::unconnected`]); a slave without a
//!   cycle time has no time base. Parameter telegrams are answered at any
//!   time, before the MCT too (the spec allows parameter access "any time").
//! - **A repeated MCT** re-connects: the new cycle time and slave count
//!   replace the old ones, the pending command is discarded, the control
//!   word in effect returns to all zeros (not enabled) and the slave waits
//!   for a new first MST (its previous cycle no longer exists).
//! - **Cycle time 0** in the MCT is accepted but disables the `T_end_s`
//!   check (there is no cycle end to miss).
//! - **MDT before the first MST** (after the MCT): answered with the
//!   feedback sampled at the MCT, and its command takes effect at the first
//!   MST. It cannot be late (no cycle has started).
//! - **`T_end_s`**: an MDT that arrives later than last MST + cycle time
//!   (strictly later) is neither answered nor applied, and is counted in
//!   [`SlaveStats::late`]. Not applying it keeps the slave consistent with
//!   the master, which counts the cycle's DT as missing anyway; the slave
//!   keeps its last command as if no MDT had come.
//! - **Several MDTs in one cycle**: the last one received before the MST
//!   takes effect (one pending command per slave).
//! - **Parameter 0x05 is always supported** (the standard parameters are
//!   mandatory); [`SlaveApplication::supports`] is asked only for
//!   0x02..=0x04 and 0x06..=0x08. A parameter telegram's control word is
//!   only read for bit 3 and the counter: its enable, halt and fault reset
//!   bits do not change the pending control word, and it is never late.
//! - **Rejected MDTs**: the reject telegram carries the status word of the
//!   last sample and the MDT's counter echo. The rejected command does not
//!   become pending, but its control word does, so that enable, halt and
//!   fault reset always reach the drive (a master may reset a fault with the
//!   same MDT that carries a command the fault refuses).
//! - **Which commands are refused** is the application's business
//!   ([`SlaveApplication::check`]); the convention this crate documents and
//!   the simulated slave follows: position, velocity, io, encoder and user
//!   MDTs are always answered (even when not enabled or in fault — the
//!   master sends them every cycle and the MDTCW enable bit decides motion;
//!   the status word shows enabled and fault); homing is rejected with
//!   [`RejectReason::Fault`] in fault and [`RejectReason::NotEnabled`] when
//!   the MDT's enable bit is 0.
//! - **Status flags in non-cyclic answers** (DCT, parameter) come from a
//!   fresh [`SlaveApplication::sample`] call, not the cached cyclic sample.
//! - **Malformed frames** are counted only when the identifier's address
//!   field (its low 6 bits) is this slave's or broadcast: frames meant for
//!   other slaves are their business.

use std::time::Duration;

use cangate_can::Frame;

use crate::telegram::{
    BROADCAST, Channel, Command, ControlWord, CycleCounter, Feedback, Function, ParameterAccess,
    RejectReason, SmcAddress, StatusWord, Telegram,
};

/// Why a parameter access failed (answered with DTSW bit 6 set, value 0).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ParameterError {
    /// The slave has no parameter with this number.
    #[error("parameter {0} does not exist")]
    Unknown(u16),
    /// The parameter cannot be written.
    #[error("parameter {0} is read-only")]
    ReadOnly(u16),
    /// The value is outside the parameter's range.
    #[error("value {value} is out of range for parameter {number}")]
    OutOfRange {
        /// The parameter.
        number: u16,
        /// The refused value.
        value: i32,
    },
}

/// The drive's feedback at one instant, as a DT reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Sample {
    /// DTSW bit 0: ready.
    pub ready: bool,
    /// DTSW bit 1: enabled (servo on).
    pub enabled: bool,
    /// DTSW bit 2: fault.
    pub fault: bool,
    /// DTSW bit 3: target reached / in position.
    pub target_reached: bool,
    /// DTSW bit 4: homed.
    pub homed: bool,
    /// DTSW bit 5: following error over limit.
    pub following_error: bool,
    /// Actual position in encoder counts (the homing DT reports it).
    pub position: i32,
    /// What the position DT reports: the actual position, or the following
    /// error if parameter 1 = 1 (the application decides).
    pub position_feedback: i32,
    /// Actual velocity, unit per parameter 2.
    pub velocity: i32,
    /// Encoder count (the encoder DT reports it).
    pub encoder: i32,
    /// Digital input bits (the io DT reports them).
    pub inputs: u32,
}

impl Sample {
    /// The status word with these flags, the given parameter-error bit and
    /// counter echo.
    pub fn status_word(&self, counter_echo: CycleCounter, parameter_error: bool) -> StatusWord {
        StatusWord {
            ready: self.ready,
            enabled: self.enabled,
            fault: self.fault,
            target_reached: self.target_reached,
            homed: self.homed,
            following_error: self.following_error,
            parameter_error,
            counter_echo,
        }
    }
}

/// The drive behind a [`SlaveProtocol`].
pub trait SlaveApplication {
    /// Device type reported in the DCT.
    fn device_type(&self) -> u16;

    /// Firmware version reported in the DCT.
    fn firmware_version(&self) -> u16;

    /// Whether the drive implements this function (asked for 0x02..=0x04
    /// and 0x06..=0x08; parameters 0x05 are always supported).
    fn supports(&self, function: Function) -> bool;

    /// An MCT arrived at `now` (phase P0): the cycle time and slave count
    /// the master configured. A drive typically becomes ready here. Called
    /// for every MCT, a repeated one too.
    fn on_connect(&mut self, now: Duration, cycle_time: Duration, slave_count: u8) {
        let _ = (now, cycle_time, slave_count);
    }

    /// MST at `now`: the control word and command received in the previous
    /// cycle take effect now (`command` is `None` if no MDT was taken last
    /// cycle: keep the last command; `control` is then the last control
    /// word again). Feedback is sampled right after this call.
    fn on_mst(&mut self, now: Duration, control: ControlWord, command: Option<Command>);

    /// The feedback as of the last [`SlaveApplication::on_mst`] (or the
    /// current state before the first one). The protocol calls this right
    /// after `on_mst` and caches the result for the cycle's DT.
    fn sample(&self) -> Sample;

    /// Reads a parameter.
    fn read_parameter(&self, number: u16) -> Result<i32, ParameterError>;

    /// Writes a parameter (at once, not at the next MST: parameter access
    /// is not cyclic).
    fn write_parameter(&mut self, number: u16, value: i32) -> Result<(), ParameterError>;

    /// Why a command cannot be taken now (`None` accepts it). `control` is
    /// the MDT's control word, so that e.g. a homing request with the enable
    /// bit set is accepted by a drive that enables at the next MST.
    fn check(&self, control: ControlWord, command: &Command) -> Option<RejectReason>;

    /// The six data bytes of the DT answering a user MDT (0x08) carrying
    /// `data`. Echoes them by default.
    fn user_reply(&mut self, data: [u8; 6]) -> [u8; 6] {
        data
    }
}

/// Where a slave is in the start-up sequence.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SlavePhase {
    /// No MCT received yet (P0): only parameter telegrams are answered.
    Unconnected,
    /// MCT answered, no MST yet (P0 done, P1).
    Connected,
    /// At least one MST received since the last MCT (P2).
    Cyclic,
}

/// Counters of a [`SlaveProtocol`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SlaveStats {
    /// MSTs that started a cycle.
    pub msts: u64,
    /// MCTs answered.
    pub connects: u64,
    /// MDTs (0x02..=0x04, 0x06..=0x08) addressed to this slave while
    /// connected, including rejected and late ones.
    pub mdts: u64,
    /// Parameter telegrams answered.
    pub parameters: u64,
    /// Parameter telegrams answered with the parameter-error bit.
    pub parameter_errors: u64,
    /// Telegrams returned for sending (DCT, DT, parameter, reject).
    pub replies: u64,
    /// Reject telegrams among the replies.
    pub rejects: u64,
    /// MDTs that arrived after this slave's cycle end (`T_end_s`): not
    /// answered, not applied.
    pub late: u64,
    /// Frames with this slave's or the broadcast address that are not valid
    /// CANsmc telegrams (ignored).
    pub malformed: u64,
    /// MST or MDTs received before the first MCT (ignored).
    pub unconnected: u64,
}

/// The protocol state of one CANsmc slave; see the [module
/// documentation](self).
#[derive(Debug, Clone)]
pub struct SlaveProtocol {
    address: SmcAddress,
    /// Cycle time from the last MCT; `None` before the first MCT.
    cycle_time: Option<Duration>,
    slave_count: u8,
    /// Arrival of the last MST since the last MCT.
    last_mst: Option<Duration>,
    /// The control word in effect (applied at the last MST).
    control: ControlWord,
    /// Received this cycle, takes effect at the next MST.
    pending_control: Option<ControlWord>,
    pending_command: Option<Command>,
    /// Feedback sampled at the last MST (or at the MCT).
    sample: Sample,
    stats: SlaveStats,
}

impl SlaveProtocol {
    /// A slave at `address`, waiting for its MCT.
    pub fn new(address: SmcAddress) -> Self {
        SlaveProtocol {
            address,
            cycle_time: None,
            slave_count: 0,
            last_mst: None,
            control: ControlWord::default(),
            pending_control: None,
            pending_command: None,
            sample: Sample::default(),
            stats: SlaveStats::default(),
        }
    }

    /// The slave's address.
    pub fn address(&self) -> SmcAddress {
        self.address
    }

    /// Where the slave is in the start-up sequence.
    pub fn phase(&self) -> SlavePhase {
        match (self.cycle_time, self.last_mst) {
            (None, _) => SlavePhase::Unconnected,
            (Some(_), None) => SlavePhase::Connected,
            (Some(_), Some(_)) => SlavePhase::Cyclic,
        }
    }

    /// The cycle time of the last MCT.
    pub fn cycle_time(&self) -> Option<Duration> {
        self.cycle_time
    }

    /// The slave count of the last MCT (0 before the first).
    pub fn slave_count(&self) -> u8 {
        self.slave_count
    }

    /// This slave's cycle end `T_end_s` (last MST + cycle time), after
    /// which it sends no DT; `None` before the first MST or with cycle
    /// time 0.
    pub fn cycle_end(&self) -> Option<Duration> {
        match (self.last_mst, self.cycle_time) {
            (Some(mst), Some(cycle)) if !cycle.is_zero() => Some(mst + cycle),
            _ => None,
        }
    }

    /// The control word in effect since the last MST.
    pub fn control(&self) -> ControlWord {
        self.control
    }

    /// The feedback cached at the last MST (what this cycle's DTs carry).
    pub fn last_sample(&self) -> Sample {
        self.sample
    }

    /// Counters.
    pub fn stats(&self) -> SlaveStats {
        self.stats
    }

    /// A frame seen on channel 0 at `now`; returns the telegram to send on
    /// channel 1 (at most one).
    pub fn on_frame(
        &mut self,
        frame: &Frame,
        now: Duration,
        app: &mut impl SlaveApplication,
    ) -> Option<Frame> {
        let telegram = match Telegram::decode(frame, Channel::Command) {
            Ok(t) => t,
            Err(_) => {
                // The address field of whatever identifier it had (error
                // frames have none worth looking at; count them too only if
                // the bits happen to match).
                let address = (frame.raw_id() & 0x3F) as u8;
                if address == self.address.get() || address == BROADCAST {
                    self.stats.malformed += 1;
                }
                return None;
            }
        };
        let reply = self.on_telegram(telegram, now, app)?;
        self.stats.replies += 1;
        Some(reply.encode())
    }

    /// A decoded channel-0 telegram at `now`; returns the telegram to send
    /// on channel 1 (at most one). [`SlaveProtocol::on_frame`] without the
    /// codec.
    pub fn on_telegram(
        &mut self,
        telegram: Telegram,
        now: Duration,
        app: &mut impl SlaveApplication,
    ) -> Option<Telegram> {
        match telegram {
            Telegram::Mst => {
                self.on_mst(now, app);
                None
            }
            Telegram::Master {
                to,
                control,
                command,
            } if to == self.address => self.on_master(control, command, now, app),
            // Another slave's telegram, or a slave telegram (which never
            // decodes on channel 0 anyway).
            Telegram::Master { .. } | Telegram::Slave { .. } => None,
        }
    }

    fn on_mst(&mut self, now: Duration, app: &mut impl SlaveApplication) {
        if self.cycle_time.is_none() {
            self.stats.unconnected += 1;
            return;
        }
        self.stats.msts += 1;
        self.last_mst = Some(now);
        if let Some(control) = self.pending_control.take() {
            self.control = control;
        }
        app.on_mst(now, self.control, self.pending_command.take());
        self.sample = app.sample();
    }

    fn on_master(
        &mut self,
        control: ControlWord,
        command: Command,
        now: Duration,
        app: &mut impl SlaveApplication,
    ) -> Option<Telegram> {
        let counter = control.counter;
        match command {
            Command::Connect {
                cycle_time_us,
                slave_count,
            } => {
                let cycle_time = Duration::from_micros(cycle_time_us.into());
                self.cycle_time = Some(cycle_time);
                self.slave_count = slave_count;
                self.last_mst = None;
                self.control = ControlWord::default();
                self.pending_control = None;
                self.pending_command = None;
                self.stats.connects += 1;
                app.on_connect(now, cycle_time, slave_count);
                self.sample = app.sample();
                Some(self.reply(
                    self.sample.status_word(counter, false),
                    Feedback::Connect {
                        device_type: app.device_type(),
                        firmware_version: app.firmware_version(),
                    },
                ))
            }
            Command::Parameter {
                access,
                number,
                value,
            } => {
                self.stats.parameters += 1;
                let result = match access {
                    ParameterAccess::Read => app.read_parameter(number),
                    // Answer with the value as stored, which is the value
                    // written unless the application normalises it.
                    ParameterAccess::Write => app
                        .write_parameter(number, value)
                        .and_then(|()| app.read_parameter(number).or(Ok(value))),
                };
                let (value, error) = match result {
                    Ok(v) => (v, false),
                    Err(_) => {
                        self.stats.parameter_errors += 1;
                        (0, true)
                    }
                };
                Some(self.reply(
                    app.sample().status_word(counter, error),
                    Feedback::Parameter { number, value },
                ))
            }
            _ => self.on_mdt(control, command, now, app),
        }
    }

    fn on_mdt(
        &mut self,
        control: ControlWord,
        command: Command,
        now: Duration,
        app: &mut impl SlaveApplication,
    ) -> Option<Telegram> {
        if self.cycle_time.is_none() {
            self.stats.unconnected += 1;
            return None;
        }
        self.stats.mdts += 1;
        if self.cycle_end().is_some_and(|end| now > end) {
            self.stats.late += 1;
            return None;
        }
        let function = command.function();
        let refusal = if app.supports(function) {
            app.check(control, &command)
        } else {
            Some(RejectReason::Unsupported)
        };
        self.pending_control = Some(control);
        let status = self.sample.status_word(control.counter, false);
        if let Some(reason) = refusal {
            self.stats.rejects += 1;
            return Some(self.reply(status, Feedback::Reject { function, reason }));
        }
        self.pending_command = Some(command);
        let s = &self.sample;
        let feedback = match command {
            Command::Position(_) => Feedback::Position(s.position_feedback),
            Command::Velocity(_) => Feedback::Velocity(s.velocity),
            Command::Homing { .. } => Feedback::Homing(s.position),
            Command::Io { .. } => Feedback::Io { inputs: s.inputs },
            Command::Encoder => Feedback::Encoder(s.encoder),
            Command::User(data) => Feedback::User(app.user_reply(data)),
            // Handled by on_master; never reaches here.
            Command::Connect { .. } | Command::Parameter { .. } => return None,
        };
        Some(self.reply(status, feedback))
    }

    fn reply(&self, status: StatusWord, feedback: Feedback) -> Telegram {
        Telegram::Slave {
            from: self.address,
            status,
            feedback,
        }
    }
}

#[cfg(test)]
mod tests {
    use cangate_can::CanId;

    use super::*;

    /// A minimal drive that records what the protocol tells it.
    #[derive(Debug, Default)]
    struct App {
        connected: Option<(Duration, u8)>,
        msts: Vec<(Duration, ControlWord, Option<Command>)>,
        /// Position applied at the last MST (feedback = this + 1000).
        target: i32,
        enabled: bool,
        fault: bool,
        params: [i32; 3],
        no_homing: bool,
    }

    impl SlaveApplication for App {
        fn device_type(&self) -> u16 {
            0x0102
        }
        fn firmware_version(&self) -> u16 {
            0x0304
        }
        fn supports(&self, function: Function) -> bool {
            !(self.no_homing && function == Function::Homing) && function != Function::User
        }
        fn on_connect(&mut self, _now: Duration, cycle_time: Duration, slave_count: u8) {
            self.connected = Some((cycle_time, slave_count));
        }
        fn on_mst(&mut self, now: Duration, control: ControlWord, command: Option<Command>) {
            self.msts.push((now, control, command));
            self.enabled = control.enable && !self.fault;
            if let Some(Command::Position(p)) = command {
                self.target = p;
            }
        }
        fn sample(&self) -> Sample {
            Sample {
                ready: self.connected.is_some(),
                enabled: self.enabled,
                fault: self.fault,
                position: self.target + 1000,
                position_feedback: self.target + 1000,
                velocity: -5,
                encoder: 0x1234_5678,
                inputs: 0xA5A5_0001,
                ..Sample::default()
            }
        }
        fn read_parameter(&self, number: u16) -> Result<i32, ParameterError> {
            match number {
                1..=3 => Ok(self.params[usize::from(number - 1)]),
                _ => Err(ParameterError::Unknown(number)),
            }
        }
        fn write_parameter(&mut self, number: u16, value: i32) -> Result<(), ParameterError> {
            match number {
                3 => Err(ParameterError::ReadOnly(3)),
                1 if !(0..=1).contains(&value) => Err(ParameterError::OutOfRange { number, value }),
                1 | 2 => {
                    self.params[usize::from(number - 1)] = value;
                    Ok(())
                }
                _ => Err(ParameterError::Unknown(number)),
            }
        }
        fn check(&self, control: ControlWord, command: &Command) -> Option<RejectReason> {
            match command {
                Command::Homing { .. } if self.fault => Some(RejectReason::Fault),
                Command::Homing { .. } if !control.enable => Some(RejectReason::NotEnabled),
                _ => None,
            }
        }
    }

    const A: u8 = 5;

    fn addr(a: u8) -> SmcAddress {
        SmcAddress::new(a).unwrap()
    }

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    fn us(n: u64) -> Duration {
        Duration::from_micros(n)
    }

    fn cw(enable: bool, counter: u8) -> ControlWord {
        ControlWord {
            enable,
            counter: CycleCounter::new(counter),
            ..ControlWord::default()
        }
    }

    fn master(to: u8, control: ControlWord, command: Command) -> Frame {
        Telegram::Master {
            to: addr(to),
            control,
            command,
        }
        .encode()
    }

    fn mst() -> Frame {
        Telegram::Mst.encode()
    }

    fn raw(id: u16, data: &[u8]) -> Frame {
        Frame::new(CanId::Standard(id), data).unwrap()
    }

    fn id_of(frame: &Frame) -> u32 {
        frame.raw_id()
    }

    fn decode(frame: &Frame) -> Telegram {
        Telegram::decode(frame, Channel::Status).unwrap()
    }

    /// A slave at address 5 connected with a 4 ms cycle at t = 0.
    fn connected() -> (SlaveProtocol, App) {
        let mut slave = SlaveProtocol::new(addr(A));
        let mut app = App::default();
        let mct = master(
            A,
            cw(false, 0),
            Command::Connect {
                cycle_time_us: 4000,
                slave_count: 3,
            },
        );
        slave.on_frame(&mct, Duration::ZERO, &mut app).unwrap();
        (slave, app)
    }

    #[test]
    fn mct_is_answered_with_dct_bytes() {
        let mut slave = SlaveProtocol::new(addr(A));
        let mut app = App::default();
        // MCT by hand: id = 0x01 << 6 | 5 = 0x045; MDTCW counter 3 = 0x3000;
        // cycle time 4000 µs = 0x00000FA0; slave count 3.
        let mct = raw(0x045, &[0x00, 0x30, 0xA0, 0x0F, 0x00, 0x00, 0x03, 0x00]);
        assert_eq!(
            mct,
            master(
                A,
                cw(false, 3),
                Command::Connect {
                    cycle_time_us: 4000,
                    slave_count: 3
                }
            )
        );
        assert_eq!(slave.phase(), SlavePhase::Unconnected);
        let dct = slave.on_frame(&mct, ms(1), &mut app).unwrap();
        // DCT: same id on channel 1; DTSW ready (bit 0) + echo 3 = 0x3001;
        // device type 0x0102, firmware 0x0304, reserved 0.
        assert_eq!(id_of(&dct), 0x045);
        assert_eq!(dct.data(), [0x01, 0x30, 0x02, 0x01, 0x04, 0x03, 0x00, 0x00]);
        assert_eq!(app.connected, Some((us(4000), 3)));
        assert_eq!(slave.phase(), SlavePhase::Connected);
        assert_eq!(slave.cycle_time(), Some(us(4000)));
        assert_eq!(slave.slave_count(), 3);
        assert_eq!(slave.stats().connects, 1);
        assert_eq!(slave.stats().replies, 1);
    }

    #[test]
    fn parameter_read_write_and_errors() {
        let mut slave = SlaveProtocol::new(addr(A));
        let mut app = App::default();
        let param = |access, number, value, counter| {
            master(
                A,
                cw(false, counter),
                Command::Parameter {
                    access,
                    number,
                    value,
                },
            )
        };
        // Parameter access works before the MCT. Write parameter 2 = 0x11223344
        // by hand: id 0x05 << 6 | 5 = 0x145; MDTCW bit 3 (write) + counter 1.
        let write = raw(0x145, &[0x08, 0x10, 0x02, 0x00, 0x44, 0x33, 0x22, 0x11]);
        assert_eq!(
            write,
            param(ParameterAccess::Write, 2, 0x1122_3344, 1),
            "hand-built bytes match the codec"
        );
        let answer = slave.on_frame(&write, ms(0), &mut app).unwrap();
        assert_eq!(id_of(&answer), 0x145);
        // Not ready (no MCT), echo 1, number 2, value as written.
        assert_eq!(
            answer.data(),
            [0x00, 0x10, 0x02, 0x00, 0x44, 0x33, 0x22, 0x11]
        );
        assert_eq!(app.params[1], 0x1122_3344);

        // Read it back.
        let answer = slave
            .on_frame(&param(ParameterAccess::Read, 2, 0, 2), ms(1), &mut app)
            .unwrap();
        assert_eq!(
            answer.data(),
            [0x00, 0x20, 0x02, 0x00, 0x44, 0x33, 0x22, 0x11]
        );

        // Unknown, read-only and out of range: bit 6 (0x40), value 0.
        for (access, number, value) in [
            (ParameterAccess::Read, 0x0999, 0),
            (ParameterAccess::Write, 3, 7),
            (ParameterAccess::Write, 1, 2),
        ] {
            let answer = slave
                .on_frame(&param(access, number, value, 4), ms(2), &mut app)
                .unwrap();
            let n = number.to_le_bytes();
            assert_eq!(answer.data(), [0x40, 0x40, n[0], n[1], 0, 0, 0, 0]);
        }
        assert_eq!(app.params[0], 0, "refused write left the value alone");
        let stats = slave.stats();
        assert_eq!((stats.parameters, stats.parameter_errors), (5, 3));

        // And during cyclic operation, with the status of the drive.
        let (mut slave, mut app) = connected();
        slave.on_frame(&mst(), ms(4), &mut app);
        let answer = slave
            .on_frame(&param(ParameterAccess::Read, 1, 0, 9), ms(5), &mut app)
            .unwrap();
        assert_eq!(answer.data(), [0x01, 0x90, 0x01, 0x00, 0, 0, 0, 0]);
    }

    #[test]
    fn mst_applies_the_previous_cycles_command() {
        let (mut slave, mut app) = connected();
        // Cycle 1: MST, then MDT with target 100.
        assert_eq!(slave.on_frame(&mst(), ms(4), &mut app), None);
        assert_eq!(app.msts.len(), 1);
        assert_eq!(app.msts[0].2, None, "nothing received before the first MST");
        let dt = slave
            .on_frame(
                &master(A, cw(true, 1), Command::Position(100)),
                ms(5),
                &mut app,
            )
            .unwrap();
        // The DT carries the sample of this cycle's MST (target 0 + 1000),
        // not the MDT's target.
        assert_eq!(
            decode(&dt),
            Telegram::Slave {
                from: addr(A),
                status: StatusWord {
                    ready: true,
                    counter_echo: CycleCounter::new(1),
                    ..StatusWord::default()
                },
                feedback: Feedback::Position(1000),
            }
        );
        // By hand: id 0x02 << 6 | 5 = 0x085; DTSW ready + echo 1 = 0x1001;
        // position 1000 = 0x000003E8.
        assert_eq!(id_of(&dt), 0x085);
        assert_eq!(dt.data(), [0x01, 0x10, 0xE8, 0x03, 0x00, 0x00, 0x00, 0x00]);
        assert_eq!(app.target, 0, "the MDT does not act before the next MST");

        // Cycle 2: the MST applies target 100 with the enable bit.
        slave.on_frame(&mst(), ms(8), &mut app);
        assert_eq!(
            app.msts[1],
            (ms(8), cw(true, 1), Some(Command::Position(100)))
        );
        let dt = slave
            .on_frame(
                &master(A, cw(true, 2), Command::Position(200)),
                ms(9),
                &mut app,
            )
            .unwrap();
        // enabled (bit 1) + ready, echo 2, position 1100 = 0x44C.
        assert_eq!(dt.data(), [0x03, 0x20, 0x4C, 0x04, 0x00, 0x00, 0x00, 0x00]);

        // Cycle 3 without an MDT: cycle 4's MST keeps the last control word
        // and passes no command.
        slave.on_frame(&mst(), ms(12), &mut app);
        slave.on_frame(&mst(), ms(16), &mut app);
        assert_eq!(app.msts[2].2, Some(Command::Position(200)));
        assert_eq!(app.msts[3], (ms(16), cw(true, 2), None));
        assert_eq!(app.target, 200);
        let stats = slave.stats();
        assert_eq!((stats.msts, stats.mdts, stats.replies), (4, 2, 3));
    }

    #[test]
    fn every_function_echoes_the_counter_with_its_feedback() {
        let (mut slave, mut app) = connected();
        slave.on_frame(&mst(), ms(4), &mut app);
        let cases = [
            (Command::Velocity(7), Feedback::Velocity(-5)),
            (
                Command::Homing { method: 1 },
                Feedback::Homing(1000), // enable bit set below
            ),
            (
                Command::Io {
                    outputs: 3,
                    mask: 0xFFFF,
                },
                Feedback::Io {
                    inputs: 0xA5A5_0001,
                },
            ),
            (Command::Encoder, Feedback::Encoder(0x1234_5678)),
        ];
        for (k, (command, feedback)) in cases.into_iter().enumerate() {
            let counter = (k as u8 + 13) & 0x0F; // wraps past 15
            let dt = slave
                .on_frame(&master(A, cw(true, counter), command), ms(5), &mut app)
                .unwrap();
            let Telegram::Slave {
                status,
                feedback: f,
                ..
            } = decode(&dt)
            else {
                panic!("not a slave telegram");
            };
            assert_eq!(status.counter_echo.get(), counter);
            assert_eq!(f, feedback);
            assert_eq!(dt.data()[1] >> 4, counter, "echo in DTSW bits 12-15");
        }
        // Encoder DT by hand: id 0x07 << 6 | 5 = 0x1C5, echo 0 (13 + 3 = 16).
        let dt = slave
            .on_frame(&master(A, cw(true, 0), Command::Encoder), ms(5), &mut app)
            .unwrap();
        assert_eq!(id_of(&dt), 0x1C5);
        assert_eq!(dt.data(), [0x01, 0x00, 0x78, 0x56, 0x34, 0x12, 0x00, 0x00]);
    }

    #[test]
    fn user_mdt_is_echoed_by_default() {
        struct Echo(App);
        impl SlaveApplication for Echo {
            fn device_type(&self) -> u16 {
                1
            }
            fn firmware_version(&self) -> u16 {
                1
            }
            fn supports(&self, _: Function) -> bool {
                true
            }
            fn on_mst(&mut self, now: Duration, control: ControlWord, command: Option<Command>) {
                self.0.on_mst(now, control, command);
            }
            fn sample(&self) -> Sample {
                self.0.sample()
            }
            fn read_parameter(&self, number: u16) -> Result<i32, ParameterError> {
                self.0.read_parameter(number)
            }
            fn write_parameter(&mut self, number: u16, value: i32) -> Result<(), ParameterError> {
                self.0.write_parameter(number, value)
            }
            fn check(&self, _: ControlWord, _: &Command) -> Option<RejectReason> {
                None
            }
        }
        let (mut slave, app) = connected();
        let mut app = Echo(app);
        slave.on_frame(&mst(), ms(4), &mut app);
        let dt = slave
            .on_frame(
                &master(A, cw(false, 6), Command::User([1, 2, 3, 4, 5, 6])),
                ms(5),
                &mut app,
            )
            .unwrap();
        assert_eq!(id_of(&dt), 0x205);
        assert_eq!(dt.data(), [0x01, 0x60, 1, 2, 3, 4, 5, 6]);
        slave.on_frame(&mst(), ms(8), &mut app);
        assert_eq!(app.0.msts[1].2, Some(Command::User([1, 2, 3, 4, 5, 6])));
    }

    #[test]
    fn rejects_name_function_and_reason() {
        let (mut slave, mut app) = connected();
        slave.on_frame(&mst(), ms(4), &mut app);

        // Homing without the enable bit: reason 2. By hand: id 0x1F << 6 | 5
        // = 0x7C5; DTSW ready + echo 7; function 0x04, reason 2.
        let reject = slave
            .on_frame(
                &master(A, cw(false, 7), Command::Homing { method: 1 }),
                ms(5),
                &mut app,
            )
            .unwrap();
        assert_eq!(id_of(&reject), 0x7C5);
        assert_eq!(reject.data(), [0x01, 0x70, 0x04, 0x02, 0, 0, 0, 0]);

        // User not supported: reason 1.
        let reject = slave
            .on_frame(
                &master(A, cw(true, 7), Command::User([0; 6])),
                ms(5),
                &mut app,
            )
            .unwrap();
        assert_eq!(reject.data(), [0x01, 0x70, 0x08, 0x01, 0, 0, 0, 0]);

        // In fault: homing reason 3, but position is answered.
        app.fault = true;
        let reject = slave
            .on_frame(
                &master(A, cw(true, 8), Command::Homing { method: 1 }),
                ms(5),
                &mut app,
            )
            .unwrap();
        assert_eq!(
            decode(&reject),
            Telegram::Slave {
                from: addr(A),
                status: StatusWord {
                    ready: true,
                    counter_echo: CycleCounter::new(8),
                    ..StatusWord::default()
                },
                feedback: Feedback::Reject {
                    function: Function::Homing,
                    reason: RejectReason::Fault,
                },
            }
        );
        let stats = slave.stats();
        // The DCT and three rejects.
        assert_eq!((stats.rejects, stats.replies), (3, 4));

        // The rejected command is not applied, but its control word is.
        slave.on_frame(&mst(), ms(8), &mut app);
        assert_eq!(app.msts[1], (ms(8), cw(true, 8), None));

        app.no_homing = true;
        app.fault = false;
        let reject = slave
            .on_frame(
                &master(A, cw(true, 9), Command::Homing { method: 1 }),
                ms(9),
                &mut app,
            )
            .unwrap();
        assert_eq!(reject.data()[2..4], [0x04, 0x01]);
    }

    #[test]
    fn late_mdt_is_suppressed_and_not_applied() {
        let (mut slave, mut app) = connected();
        slave.on_frame(&mst(), ms(4), &mut app);
        assert_eq!(slave.cycle_end(), Some(ms(8)));
        // Exactly at the cycle end is still in time.
        assert!(
            slave
                .on_frame(
                    &master(A, cw(true, 1), Command::Position(5)),
                    ms(8),
                    &mut app
                )
                .is_some()
        );
        // 1 µs later is not.
        let late = master(A, cw(true, 2), Command::Position(9));
        assert_eq!(slave.on_frame(&late, ms(8) + us(1), &mut app), None);
        assert_eq!(slave.stats().late, 1);
        slave.on_frame(&mst(), ms(9), &mut app);
        assert_eq!(
            app.msts[1],
            (ms(9), cw(true, 1), Some(Command::Position(5))),
            "the late MDT was not applied"
        );
        // Parameter telegrams are never late.
        let read = master(
            A,
            cw(false, 0),
            Command::Parameter {
                access: ParameterAccess::Read,
                number: 1,
                value: 0,
            },
        );
        assert!(slave.on_frame(&read, ms(100), &mut app).is_some());
    }

    #[test]
    fn zero_cycle_time_disables_the_late_check() {
        let mut slave = SlaveProtocol::new(addr(A));
        let mut app = App::default();
        let mct = master(
            A,
            cw(false, 0),
            Command::Connect {
                cycle_time_us: 0,
                slave_count: 1,
            },
        );
        slave.on_frame(&mct, ms(0), &mut app).unwrap();
        slave.on_frame(&mst(), ms(1), &mut app);
        assert_eq!(slave.cycle_end(), None);
        let mdt = master(A, cw(true, 1), Command::Position(5));
        assert!(slave.on_frame(&mdt, ms(1000), &mut app).is_some());
    }

    #[test]
    fn unconnected_slave_ignores_cyclic_telegrams() {
        let mut slave = SlaveProtocol::new(addr(A));
        let mut app = App::default();
        assert_eq!(slave.on_frame(&mst(), ms(0), &mut app), None);
        let mdt = master(A, cw(true, 1), Command::Position(5));
        assert_eq!(slave.on_frame(&mdt, ms(1), &mut app), None);
        assert!(app.msts.is_empty());
        assert_eq!(slave.stats().unconnected, 2);
        assert_eq!(slave.stats().replies, 0);
    }

    #[test]
    fn mdt_before_first_mst_waits_for_it() {
        let (mut slave, mut app) = connected();
        let mdt = master(A, cw(true, 1), Command::Position(5));
        // Answered with the sample taken at the MCT; never late.
        let dt = slave.on_frame(&mdt, ms(500), &mut app).unwrap();
        assert_eq!(dt.data(), [0x01, 0x10, 0xE8, 0x03, 0, 0, 0, 0]);
        slave.on_frame(&mst(), ms(501), &mut app);
        assert_eq!(app.msts[0].2, Some(Command::Position(5)));
    }

    #[test]
    fn repeated_mct_reconnects() {
        let (mut slave, mut app) = connected();
        slave.on_frame(&mst(), ms(4), &mut app);
        slave.on_frame(
            &master(A, cw(true, 1), Command::Position(5)),
            ms(5),
            &mut app,
        );
        let mct = master(
            A,
            cw(false, 0),
            Command::Connect {
                cycle_time_us: 2000,
                slave_count: 9,
            },
        );
        assert!(slave.on_frame(&mct, ms(6), &mut app).is_some());
        assert_eq!(slave.phase(), SlavePhase::Connected);
        assert_eq!(slave.cycle_time(), Some(ms(2)));
        slave.on_frame(&mst(), ms(7), &mut app);
        assert_eq!(app.msts[1].2, None, "pending command discarded");
    }

    #[test]
    fn other_slaves_and_malformed_frames_are_ignored() {
        let (mut slave, mut app) = connected();
        slave.on_frame(&mst(), ms(4), &mut app);
        let before = slave.stats();
        // Another slave's MDT and MCT: no answer, not counted.
        assert_eq!(
            slave.on_frame(
                &master(6, cw(true, 1), Command::Position(1)),
                ms(5),
                &mut app
            ),
            None
        );
        assert_eq!(slave.stats(), before);

        let bad = [
            // MST with data.
            raw(0x03F, &[0]),
            // MST addressed to a slave.
            raw(0x005, &[]),
            // Position MDT, 7 bytes.
            raw(0x085, &[1, 0, 0, 0, 0, 0, 0]),
            // Reserved control-word bits.
            raw(0x085, &[0x10, 0, 0, 0, 0, 0, 0, 0]),
            // Non-zero reserved byte.
            raw(0x085, &[0, 0, 0, 0, 0, 0, 1, 0]),
            // Unknown function 0x09.
            raw(0x245, &[0; 8]),
            // Reject on channel 0.
            raw(0x7C5, &[0, 0, 2, 1, 0, 0, 0, 0]),
            // Extended identifier, remote frame, error frame.
            Frame::new(CanId::Extended(0x85), &[0; 8]).unwrap(),
            Frame::new_remote(CanId::Standard(0x085), 8).unwrap(),
            Frame::new_error(0x3F, [0; 8]),
        ];
        for frame in &bad {
            assert_eq!(slave.on_frame(frame, ms(5), &mut app), None, "{frame:?}");
        }
        // Malformed frames for other slaves are not counted.
        assert_eq!(slave.on_frame(&raw(0x086, &[1]), ms(5), &mut app), None);
        let stats = slave.stats();
        assert_eq!(stats.malformed, bad.len() as u64);
        assert_eq!(stats.replies, before.replies);
        assert_eq!(app.msts.len(), 1);
    }
}
