//! Simulated CANsmc servo slave.
//!
//! [`SimCansmcSlave`] is a CANsmc slave as a sans-IO state machine: a
//! [`SlaveProtocol`] (addressing, counter echo, rejects, `T_end_s`) in front
//! of a [`SimCansmcServo`], a servo model stepped at every MST by the time elapsed
//! since the previous one. Feed it the frames of channel 0 with
//! [`SimCansmcSlave::on_frame`] and send what it returns on channel 1; the
//! runner ([`crate::cansmc_runner`]) does that on the virtual bus and also
//! honours the injected reply delay and drop rate
//! ([`SimCansmcSlave::on_frame_with_faults`]).
//!
//! # The model
//!
//! Units inside are encoder counts, counts/s and counts/s². At each MST the
//! servo first moves for the elapsed time under the command in effect, then
//! takes the control word and the command of the previous cycle (they take
//! effect at the MST), then the feedback is sampled.
//!
//! | feature | behaviour |
//! |---|---|
//! | ready / enable | ready after the MCT and while not in fault; enabled while the MDTCW enable bit is set, ready and not in fault; disabled, the motor stands still |
//! | position (0x02) | the target is the cycle's position set-point (the master interpolates); the servo reaches it within the cycle unless that needs more than the velocity limit (parameter 5 × resolution / 60, reduced by the load); following error = target − actual after the move; over parameter 4's limit (0 = no check) → fault, DTSW bits 2 and 5; target reached within [`SimCansmcSlaveOptions::in_position_window`] |
//! | velocity (0x03) | ramps to the target (unit per parameter 2, limited to the velocity limit) with [`SimCansmcSlaveOptions::acceleration`]; target reached at the target velocity |
//! | homing (0x04) | method 1 moves to the reference switch ([`SimCansmcSlaveOptions::home_reference`], a physical position) at the homing speed, then sets the position to 0 there; method 2 sets the position to 0 where the motor stands; both set homed; other methods are rejected (unsupported) |
//! | halt | decelerates with the acceleration limit and holds; the following error is not checked while halted; target reached once stopped |
//! | fault reset | a 0→1 edge of MDTCW bit 2 clears a fault |
//! | io (0x06) | 16 outputs: mask bit i selects output i (output bits 16–31 do not exist and are ignored); inputs = outputs in bits 16–31 (loopback, on by default) OR the settable input word |
//! | encoder (0x07) | the motor position, or a free-running external encoder at [`SimCansmcSlaveOptions::encoder_velocity`] (the source another axis is geared to) |
//! | user (0x08) | echoed |
//!
//! Choices *(fixed here)*: a homing MDT repeated every cycle continues the
//! homing in progress and leaves a finished one alone (the master keeps
//! sending homing MDTs until it sees the homed bit); homing starts again only
//! after another mode was commanded in between. Positions are reported
//! modulo 2³² (as a 32-bit encoder counter wraps). The velocity DT uses the
//! unit of parameter 2, like the velocity MDT. A repeated MCT disables the
//! servo. A load slows the motor down (the velocity limit scales with
//! 100 % − load), so at 100 % it stalls and a moving position set-point ends
//! in a following-error fault.
//!
//! # Parameters
//!
//! | number | access | range | meaning |
//! |---|---|---|---|
//! | 1 | rw | 0..=1 | position feedback: 0 actual position, 1 following error |
//! | 2 | rw | 0..=1 | velocity unit: 0 r/min, 1 0.001 r/min |
//! | 3 | ro | | encoder resolution, counts/rev |
//! | 4 | rw | 0..=i32::MAX | following error limit, counts (0: no check) |
//! | 5 | rw | 1..=60000 | maximum velocity, r/min |
//! | 0x1000 | rw | 0..=1 000 000 | injected reply delay, µs |
//! | 0x1001 | rw | 0..=100 | simulated load, % |
//! | 0x1002 | rw | 0..=1000 | reply drop rate, ‰ |
//! | 0x1003 | rw | any | input word (OR-ed into the inputs) |

use std::time::Duration;

use cangate_can::Frame;
use cangate_cansmc::slave::{ParameterError, Sample, SlaveApplication, SlaveProtocol, SlaveStats};
use cangate_cansmc::telegram::{Command, ControlWord, Function, RejectReason, SmcAddress};

/// Parameter 1: position feedback selection.
pub const PARAM_POSITION_FEEDBACK: u16 = 1;
/// Parameter 2: velocity unit.
pub const PARAM_VELOCITY_UNIT: u16 = 2;
/// Parameter 3: encoder resolution (read-only).
pub const PARAM_ENCODER_RESOLUTION: u16 = 3;
/// Parameter 4: following error limit.
pub const PARAM_FOLLOWING_ERROR_LIMIT: u16 = 4;
/// Parameter 5: maximum velocity.
pub const PARAM_MAX_VELOCITY: u16 = 5;
/// Device-specific parameter: injected reply delay in µs.
pub const PARAM_REPLY_DELAY_US: u16 = 0x1000;
/// Device-specific parameter: simulated load in %.
pub const PARAM_LOAD_PERCENT: u16 = 0x1001;
/// Device-specific parameter: reply drop rate in ‰.
pub const PARAM_DROP_PER_MILLE: u16 = 0x1002;
/// Device-specific parameter: input word.
pub const PARAM_INPUT_WORD: u16 = 0x1003;

/// Largest value of parameter 5 (r/min).
const MAX_RPM_LIMIT: i32 = 60_000;
/// Largest injected reply delay (µs).
const MAX_REPLY_DELAY_US: i32 = 1_000_000;
/// A velocity this close to its target (counts/s) counts as reached; it
/// absorbs the rounding of the ramp.
const VELOCITY_EPSILON: f64 = 1e-6;

/// How a [`SimCansmcSlave`] is built.
#[derive(Debug, Clone, PartialEq)]
pub struct SimCansmcSlaveOptions {
    /// The slave address.
    pub address: SmcAddress,
    /// Device type reported in the DCT.
    pub device_type: u16,
    /// Firmware version reported in the DCT.
    pub firmware_version: u16,
    /// Encoder counts per revolution (parameter 3; 10 000 by default, at
    /// least 1).
    pub encoder_resolution: u32,
    /// Initial maximum velocity in r/min (parameter 5; 3000 by default).
    pub max_velocity_rpm: u32,
    /// Initial following error limit in counts (parameter 4; 20 000 by
    /// default, two revolutions).
    pub following_error_limit: u32,
    /// Acceleration limit of velocity mode and halt, counts/s² (5 000 000
    /// by default: 3000 r/min in 100 ms at 10 000 counts/rev).
    pub acceleration: f64,
    /// Position mode reports target reached within this many counts (10 by
    /// default).
    pub in_position_window: u32,
    /// Physical position of the reference switch homing method 1 moves to,
    /// counts.
    pub home_reference: i32,
    /// Homing speed, counts/s (50 000 by default; never above the velocity
    /// limit).
    pub homing_speed: f64,
    /// Physical position at power-up (also the reported position until
    /// homed), counts.
    pub initial_position: i32,
    /// `None`: the encoder DT reports the motor position. `Some(v)`: a
    /// free-running external encoder counting at `v` counts/s.
    pub encoder_velocity: Option<f64>,
    /// Inputs 16–31 mirror outputs 0–15 (on by default).
    pub io_loopback: bool,
    /// Reply delay the runner applies.
    pub reply_delay: Duration,
    /// Fraction of replies the runner drops (0.0..=1.0).
    pub drop_rate: f64,
    /// Seed of the drop decisions.
    pub seed: u64,
    /// Whether homing (0x04) is implemented (on by default).
    pub supports_homing: bool,
    /// Whether user telegrams (0x08) are implemented (on by default).
    pub supports_user: bool,
}

impl SimCansmcSlaveOptions {
    /// Default options for the slave at `address`.
    pub fn new(address: SmcAddress) -> Self {
        SimCansmcSlaveOptions {
            address,
            ..Self::default()
        }
    }
}

impl Default for SimCansmcSlaveOptions {
    /// Slave 1, 10 000 counts/rev, 3000 r/min.
    fn default() -> Self {
        SimCansmcSlaveOptions {
            address: SmcAddress::new(1).unwrap_or_else(|_| unreachable!("1 is a slave address")),
            device_type: 0x0402,
            firmware_version: 0x0100,
            encoder_resolution: 10_000,
            max_velocity_rpm: 3000,
            following_error_limit: 20_000,
            acceleration: 5_000_000.0,
            in_position_window: 10,
            home_reference: 0,
            homing_speed: 50_000.0,
            initial_position: 0,
            encoder_velocity: None,
            io_loopback: true,
            reply_delay: Duration::ZERO,
            drop_rate: 0.0,
            seed: 0x5EED,
            supports_homing: true,
            supports_user: true,
        }
    }
}

/// Why a simulated servo is in fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SimCansmcFault {
    /// Injected with [`SimCansmcServo::inject_fault`] (an over-current-like
    /// fault).
    Injected,
    /// The following error exceeded parameter 4.
    FollowingError,
}

/// What the servo is doing, for tests and the demo.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SimCansmcMode {
    /// No motion command yet: stands still.
    Idle,
    /// Following position set-points; the current one, counts.
    Position(f64),
    /// Ramping to / running at a velocity, counts/s.
    Velocity(f64),
    /// Homing with this method, not finished.
    Homing(u8),
    /// Homing finished: holds position 0 until another mode is commanded.
    Homed,
}

/// Counters of a [`SimCansmcSlave`] beyond the protocol's.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SimCansmcCounters {
    /// Model steps (one per MST and MCT).
    pub steps: u64,
    /// Replies dropped by the injected drop rate.
    pub replies_dropped: u64,
    /// Replies sent with an injected delay.
    pub replies_delayed: u64,
    /// Faults raised (injected or following error).
    pub faults: u64,
}

/// A tiny xorshift64 generator: reproducible drop decisions without a
/// dependency.
#[derive(Debug, Clone)]
struct XorShift(u64);

impl XorShift {
    fn new(seed: u64) -> Self {
        // The all-zero state is a fixed point; mix the seed so that 0 works.
        let s = seed ^ 0x9E37_79B9_7F4A_7C15;
        XorShift(if s == 0 { 0x9E37_79B9_7F4A_7C15 } else { s })
    }

    fn next_u64(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.0 = x;
        x
    }

    /// Uniform in `[0, 1)`.
    fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Reports a position modulo 2³², as a 32-bit counter wraps.
fn wrap(x: f64) -> i32 {
    // `as i64` saturates (and maps NaN to 0); the truncation to i32 wraps.
    x.round() as i64 as i32
}

/// Moves `from` toward `to` by at most `step` (≥ 0).
fn approach(from: f64, to: f64, step: f64) -> f64 {
    if (to - from).abs() <= step {
        to
    } else if to > from {
        from + step
    } else {
        from - step
    }
}

/// The servo model behind a [`SimCansmcSlave`]: the [`SlaveApplication`].
#[derive(Debug, Clone)]
pub struct SimCansmcServo {
    options: SimCansmcSlaveOptions,
    // Parameters.
    feedback_is_following_error: bool,
    velocity_unit_milli: bool,
    following_error_limit: i32,
    max_velocity_rpm: i32,
    load_percent: i32,
    input_word: u32,
    reply_delay: Duration,
    drop_rate: f64,
    // State.
    ready: bool,
    enabled: bool,
    halt: bool,
    fault: Option<SimCansmcFault>,
    following_error_flag: bool,
    homed: bool,
    target_reached: bool,
    last_control: ControlWord,
    last_step: Option<Duration>,
    /// Physical motor position, counts.
    physical: f64,
    /// Physical position of reported position 0 (moved by homing).
    zero: f64,
    /// Counts/s.
    velocity: f64,
    following_error: f64,
    mode: SimCansmcMode,
    outputs: u32,
    external_encoder: f64,
    encoder_velocity: Option<f64>,
    rng: XorShift,
    counters: SimCansmcCounters,
}

impl SimCansmcServo {
    /// A servo at power-up (not ready until the MCT).
    pub fn new(options: SimCansmcSlaveOptions) -> Self {
        let mut options = options;
        options.encoder_resolution = options.encoder_resolution.max(1);
        SimCansmcServo {
            feedback_is_following_error: false,
            velocity_unit_milli: false,
            following_error_limit: i32::try_from(options.following_error_limit).unwrap_or(i32::MAX),
            max_velocity_rpm: i32::try_from(options.max_velocity_rpm)
                .unwrap_or(MAX_RPM_LIMIT)
                .clamp(1, MAX_RPM_LIMIT),
            load_percent: 0,
            input_word: 0,
            reply_delay: options.reply_delay,
            drop_rate: options.drop_rate.clamp(0.0, 1.0),
            ready: false,
            enabled: false,
            halt: false,
            fault: None,
            following_error_flag: false,
            homed: false,
            target_reached: false,
            last_control: ControlWord::default(),
            last_step: None,
            physical: f64::from(options.initial_position),
            zero: 0.0,
            velocity: 0.0,
            following_error: 0.0,
            mode: SimCansmcMode::Idle,
            outputs: 0,
            external_encoder: 0.0,
            encoder_velocity: options.encoder_velocity,
            rng: XorShift::new(options.seed),
            counters: SimCansmcCounters::default(),
            options,
        }
    }

    fn resolution(&self) -> f64 {
        f64::from(self.options.encoder_resolution)
    }

    /// The velocity limit now, counts/s (parameter 5 reduced by the load).
    fn velocity_limit(&self) -> f64 {
        let free = f64::from(100 - self.load_percent) / 100.0;
        f64::from(self.max_velocity_rpm) * self.resolution() / 60.0 * free
    }

    /// Counts/s per unit of a velocity telegram (parameter 2).
    fn counts_per_unit(&self) -> f64 {
        let per_rpm = self.resolution() / 60.0;
        if self.velocity_unit_milli {
            per_rpm / 1000.0
        } else {
            per_rpm
        }
    }

    fn raise(&mut self, fault: SimCansmcFault) {
        if self.fault.is_none() {
            self.counters.faults += 1;
        }
        self.fault = Some(fault);
        if fault == SimCansmcFault::FollowingError {
            self.following_error_flag = true;
        }
        // The power stage switches off: the motor stops (modelled as at
        // once; a real one would coast or brake).
        self.enabled = false;
        self.ready = false;
        self.velocity = 0.0;
        self.target_reached = false;
    }

    /// Moves the model forward to `now` under the command in effect.
    fn step(&mut self, now: Duration) {
        let dt = self
            .last_step
            .map_or(Duration::ZERO, |last| now.saturating_sub(last));
        self.last_step = Some(now);
        self.counters.steps += 1;
        let secs = dt.as_secs_f64();
        if let Some(v) = self.encoder_velocity {
            self.external_encoder += v * secs;
        }
        if !self.enabled {
            self.velocity = 0.0;
            self.following_error = 0.0;
            return;
        }
        let limit = self.velocity_limit();
        let accel_step = self.options.acceleration.max(0.0) * secs;
        if self.halt {
            let v0 = self.velocity;
            self.velocity = approach(v0, 0.0, accel_step);
            self.physical += (v0 + self.velocity) / 2.0 * secs;
            self.following_error = 0.0;
            return;
        }
        match self.mode {
            SimCansmcMode::Idle | SimCansmcMode::Homed => self.velocity = 0.0,
            SimCansmcMode::Position(target) => {
                let actual = self.physical - self.zero;
                let moved = approach(actual, target, limit * secs) - actual;
                self.physical += moved;
                self.velocity = if secs > 0.0 { moved / secs } else { 0.0 };
                self.following_error = target - (self.physical - self.zero);
                let limit = self.following_error_limit;
                if limit > 0 && self.following_error.abs() > f64::from(limit) {
                    self.raise(SimCansmcFault::FollowingError);
                }
            }
            SimCansmcMode::Velocity(target) => {
                let target = target.clamp(-limit, limit);
                let v0 = self.velocity;
                self.velocity = approach(v0, target, accel_step);
                self.physical += (v0 + self.velocity) / 2.0 * secs;
            }
            SimCansmcMode::Homing(_) => {
                let reference = f64::from(self.options.home_reference);
                let speed = self.options.homing_speed.abs().min(limit);
                let before = self.physical;
                self.physical = approach(before, reference, speed * secs);
                self.velocity = if secs > 0.0 {
                    (self.physical - before) / secs
                } else {
                    0.0
                };
                if self.physical == reference {
                    self.finish_homing();
                }
            }
        }
    }

    fn finish_homing(&mut self) {
        self.zero = self.physical;
        self.homed = true;
        self.velocity = 0.0;
        self.mode = SimCansmcMode::Homed;
    }

    fn apply_control(&mut self, control: ControlWord) {
        if control.fault_reset && !self.last_control.fault_reset && self.fault.is_some() {
            self.fault = None;
            self.following_error_flag = false;
            self.ready = true;
        }
        self.last_control = control;
        self.halt = control.halt;
        self.enabled = control.enable && self.ready && self.fault.is_none();
        if !self.enabled {
            self.velocity = 0.0;
        }
    }

    fn apply_command(&mut self, command: Command) {
        match command {
            Command::Position(target) => self.mode = SimCansmcMode::Position(f64::from(target)),
            Command::Velocity(v) => {
                self.mode = SimCansmcMode::Velocity(f64::from(v) * self.counts_per_unit());
            }
            // Continuing or already finished: see the module doc.
            Command::Homing { .. }
                if matches!(self.mode, SimCansmcMode::Homing(_) | SimCansmcMode::Homed) => {}
            Command::Homing { method: 2 } => self.finish_homing(),
            Command::Homing { method } => {
                self.homed = false;
                self.mode = SimCansmcMode::Homing(method);
            }
            Command::Io { outputs, mask } => {
                let mask = u32::from(mask);
                self.outputs = (self.outputs & !mask) | (outputs & mask);
            }
            Command::Encoder | Command::User(_) => {}
            // Never passed to on_mst by the protocol.
            Command::Connect { .. } | Command::Parameter { .. } => {}
        }
    }

    fn update_target_reached(&mut self) {
        self.target_reached = self.enabled
            && if self.halt {
                self.velocity.abs() < VELOCITY_EPSILON
            } else {
                match self.mode {
                    SimCansmcMode::Idle | SimCansmcMode::Homed => true,
                    SimCansmcMode::Position(target) => {
                        (target - self.position_f64()).abs()
                            <= f64::from(self.options.in_position_window)
                    }
                    SimCansmcMode::Velocity(target) => {
                        let limit = self.velocity_limit();
                        (target.clamp(-limit, limit) - self.velocity).abs() < VELOCITY_EPSILON
                    }
                    SimCansmcMode::Homing(_) => false,
                }
            };
    }

    fn position_f64(&self) -> f64 {
        self.physical - self.zero
    }

    // ---- state for tests and the demo ----

    /// The options it was built with.
    pub fn options(&self) -> &SimCansmcSlaveOptions {
        &self.options
    }

    /// Reported position, counts (relative to the homing zero).
    pub fn position(&self) -> i32 {
        wrap(self.position_f64())
    }

    /// Exact model position, counts.
    pub fn position_exact(&self) -> f64 {
        self.position_f64()
    }

    /// Physical position (ignores homing), counts.
    pub fn physical_position(&self) -> f64 {
        self.physical
    }

    /// Velocity, counts/s.
    pub fn velocity(&self) -> f64 {
        self.velocity
    }

    /// Following error of the last step, counts.
    pub fn following_error(&self) -> f64 {
        self.following_error
    }

    /// Ready (MCT received, no fault).
    pub fn ready(&self) -> bool {
        self.ready
    }

    /// Enabled (servo on).
    pub fn enabled(&self) -> bool {
        self.enabled
    }

    /// Halted by the MDTCW.
    pub fn halted(&self) -> bool {
        self.halt
    }

    /// The fault, if any.
    pub fn fault(&self) -> Option<SimCansmcFault> {
        self.fault
    }

    /// Homed.
    pub fn homed(&self) -> bool {
        self.homed
    }

    /// What the servo is doing.
    pub fn mode(&self) -> SimCansmcMode {
        self.mode
    }

    /// Output bits.
    pub fn outputs(&self) -> u32 {
        self.outputs
    }

    /// Input bits as the io DT reports them.
    pub fn inputs(&self) -> u32 {
        let loopback = if self.options.io_loopback {
            self.outputs.rotate_left(16)
        } else {
            0
        };
        loopback | self.input_word
    }

    /// Encoder count as the encoder DT reports it.
    pub fn encoder(&self) -> i32 {
        if self.encoder_velocity.is_some() {
            wrap(self.external_encoder)
        } else {
            self.position()
        }
    }

    /// Counters.
    pub fn counters(&self) -> SimCansmcCounters {
        self.counters
    }

    /// Injected reply delay.
    pub fn reply_delay(&self) -> Duration {
        self.reply_delay
    }

    /// Injected drop rate.
    pub fn drop_rate(&self) -> f64 {
        self.drop_rate
    }

    // ---- fault injection and settings ----

    /// Raises an over-current-like fault at once (visible from the next
    /// MST's sample); a fault reset edge clears it.
    pub fn inject_fault(&mut self) {
        self.raise(SimCansmcFault::Injected);
    }

    /// Sets the simulated load, % (clamped to 0..=100).
    pub fn set_load(&mut self, percent: u8) {
        self.load_percent = i32::from(percent.min(100));
    }

    /// Sets the input word OR-ed into the inputs.
    pub fn set_input_word(&mut self, word: u32) {
        self.input_word = word;
    }

    /// Switches the encoder DT to a free-running external encoder at `v`
    /// counts/s (it keeps its count), or back to the motor position.
    pub fn set_encoder_velocity(&mut self, v: Option<f64>) {
        self.encoder_velocity = v;
    }

    /// Sets the reply delay the runner applies (it waits on a tokio timer,
    /// so the delay is rounded up to a 1 ms tick).
    pub fn set_reply_delay(&mut self, delay: Duration) {
        self.reply_delay = delay;
    }

    /// Sets the fraction of replies the runner drops (clamped to 0..=1).
    pub fn set_drop_rate(&mut self, rate: f64) {
        self.drop_rate = if rate.is_nan() {
            0.0
        } else {
            rate.clamp(0.0, 1.0)
        };
    }

    /// Decides whether the next reply is dropped (draws from the seeded
    /// generator only when the rate is strictly between 0 and 1).
    fn drop_next(&mut self) -> bool {
        if self.drop_rate <= 0.0 {
            false
        } else if self.drop_rate >= 1.0 {
            true
        } else {
            self.rng.next_f64() < self.drop_rate
        }
    }
}

fn in_range(
    number: u16,
    value: i32,
    range: std::ops::RangeInclusive<i32>,
) -> Result<(), ParameterError> {
    if range.contains(&value) {
        Ok(())
    } else {
        Err(ParameterError::OutOfRange { number, value })
    }
}

impl SlaveApplication for SimCansmcServo {
    fn device_type(&self) -> u16 {
        self.options.device_type
    }

    fn firmware_version(&self) -> u16 {
        self.options.firmware_version
    }

    fn supports(&self, function: Function) -> bool {
        match function {
            Function::Homing => self.options.supports_homing,
            Function::User => self.options.supports_user,
            _ => true,
        }
    }

    fn on_connect(&mut self, now: Duration, _cycle_time: Duration, _slave_count: u8) {
        self.step(now);
        self.ready = self.fault.is_none();
        self.enabled = false;
        self.velocity = 0.0;
        self.last_control = ControlWord::default();
        self.update_target_reached();
    }

    fn on_mst(&mut self, now: Duration, control: ControlWord, command: Option<Command>) {
        self.step(now);
        // Target reached describes the motion just finished (the set-point
        // followed during the last cycle), not the command that starts now:
        // a drive following per-cycle set-points is "in position".
        self.update_target_reached();
        self.apply_control(control);
        if !self.enabled {
            self.target_reached = false;
        }
        if let Some(command) = command {
            self.apply_command(command);
        }
    }

    fn sample(&self) -> Sample {
        let position = self.position();
        Sample {
            ready: self.ready,
            enabled: self.enabled,
            fault: self.fault.is_some(),
            target_reached: self.target_reached,
            homed: self.homed,
            following_error: self.following_error_flag,
            position,
            position_feedback: if self.feedback_is_following_error {
                wrap(self.following_error)
            } else {
                position
            },
            velocity: wrap(self.velocity / self.counts_per_unit()),
            encoder: self.encoder(),
            inputs: self.inputs(),
        }
    }

    fn read_parameter(&self, number: u16) -> Result<i32, ParameterError> {
        Ok(match number {
            PARAM_POSITION_FEEDBACK => i32::from(self.feedback_is_following_error),
            PARAM_VELOCITY_UNIT => i32::from(self.velocity_unit_milli),
            PARAM_ENCODER_RESOLUTION => {
                i32::try_from(self.options.encoder_resolution).unwrap_or(i32::MAX)
            }
            PARAM_FOLLOWING_ERROR_LIMIT => self.following_error_limit,
            PARAM_MAX_VELOCITY => self.max_velocity_rpm,
            PARAM_REPLY_DELAY_US => i32::try_from(self.reply_delay.as_micros()).unwrap_or(i32::MAX),
            PARAM_LOAD_PERCENT => self.load_percent,
            PARAM_DROP_PER_MILLE => (self.drop_rate * 1000.0).round() as i32,
            PARAM_INPUT_WORD => self.input_word as i32,
            _ => return Err(ParameterError::Unknown(number)),
        })
    }

    fn write_parameter(&mut self, number: u16, value: i32) -> Result<(), ParameterError> {
        match number {
            PARAM_POSITION_FEEDBACK => {
                in_range(number, value, 0..=1)?;
                self.feedback_is_following_error = value == 1;
            }
            PARAM_VELOCITY_UNIT => {
                in_range(number, value, 0..=1)?;
                self.velocity_unit_milli = value == 1;
            }
            PARAM_ENCODER_RESOLUTION => return Err(ParameterError::ReadOnly(number)),
            PARAM_FOLLOWING_ERROR_LIMIT => {
                in_range(number, value, 0..=i32::MAX)?;
                self.following_error_limit = value;
            }
            PARAM_MAX_VELOCITY => {
                in_range(number, value, 1..=MAX_RPM_LIMIT)?;
                self.max_velocity_rpm = value;
            }
            PARAM_REPLY_DELAY_US => {
                in_range(number, value, 0..=MAX_REPLY_DELAY_US)?;
                self.reply_delay = Duration::from_micros(value.unsigned_abs().into());
            }
            PARAM_LOAD_PERCENT => {
                in_range(number, value, 0..=100)?;
                self.load_percent = value;
            }
            PARAM_DROP_PER_MILLE => {
                in_range(number, value, 0..=1000)?;
                self.drop_rate = f64::from(value) / 1000.0;
            }
            PARAM_INPUT_WORD => self.input_word = value as u32,
            _ => return Err(ParameterError::Unknown(number)),
        }
        Ok(())
    }

    fn check(&self, control: ControlWord, command: &Command) -> Option<RejectReason> {
        match command {
            Command::Homing { method } => {
                if !self.options.supports_homing || !matches!(method, 1 | 2) {
                    Some(RejectReason::Unsupported)
                } else if self.fault.is_some() {
                    Some(RejectReason::Fault)
                } else if !control.enable {
                    Some(RejectReason::NotEnabled)
                } else {
                    None
                }
            }
            // Motion and data commands are always answered: the enable bit
            // decides motion, the status word shows enabled and fault.
            _ => None,
        }
    }
}

/// A reply with the delay the runner must wait before sending it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimCansmcReply {
    /// The telegram to send on channel 1.
    pub frame: Frame,
    /// Injected delay (zero: send at once).
    pub delay: Duration,
}

/// A simulated CANsmc servo slave: [`SlaveProtocol`] + [`SimCansmcServo`]. See the
/// [module documentation](self).
#[derive(Debug, Clone)]
pub struct SimCansmcSlave {
    protocol: SlaveProtocol,
    servo: SimCansmcServo,
}

impl SimCansmcSlave {
    /// A slave at power-up, waiting for its MCT.
    pub fn new(options: SimCansmcSlaveOptions) -> Self {
        SimCansmcSlave {
            protocol: SlaveProtocol::new(options.address),
            servo: SimCansmcServo::new(options),
        }
    }

    /// The slave address.
    pub fn address(&self) -> SmcAddress {
        self.protocol.address()
    }

    /// A frame seen on channel 0 at `now`; returns the reply for channel 1.
    /// No injected drop or delay: see [`SimCansmcSlave::on_frame_with_faults`].
    pub fn on_frame(&mut self, frame: &Frame, now: Duration) -> Option<Frame> {
        self.protocol.on_frame(frame, now, &mut self.servo)
    }

    /// As [`SimCansmcSlave::on_frame`], then applies the injected faults:
    /// the reply is dropped (and counted) with the drop rate, or carries the
    /// reply delay. A delayed reply may arrive after the cycle end: it models
    /// a slave too slow for its cycle, for testing the master's `T_end_m`.
    pub fn on_frame_with_faults(&mut self, frame: &Frame, now: Duration) -> Option<SimCansmcReply> {
        let frame = self.on_frame(frame, now)?;
        if self.servo.drop_next() {
            self.servo.counters.replies_dropped += 1;
            return None;
        }
        let delay = self.servo.reply_delay;
        if !delay.is_zero() {
            self.servo.counters.replies_delayed += 1;
        }
        Some(SimCansmcReply { frame, delay })
    }

    /// The protocol state.
    pub fn protocol(&self) -> &SlaveProtocol {
        &self.protocol
    }

    /// Protocol counters.
    pub fn stats(&self) -> SlaveStats {
        self.protocol.stats()
    }

    /// The servo model.
    pub fn servo(&self) -> &SimCansmcServo {
        &self.servo
    }

    /// The servo model, for fault injection and settings.
    pub fn servo_mut(&mut self) -> &mut SimCansmcServo {
        &mut self.servo
    }

    /// Reported position, counts.
    pub fn position(&self) -> i32 {
        self.servo.position()
    }

    /// Velocity, counts/s.
    pub fn velocity(&self) -> f64 {
        self.servo.velocity()
    }

    /// Enabled (servo on).
    pub fn enabled(&self) -> bool {
        self.servo.enabled()
    }

    /// The fault, if any.
    pub fn fault(&self) -> Option<SimCansmcFault> {
        self.servo.fault()
    }

    /// Homed.
    pub fn homed(&self) -> bool {
        self.servo.homed()
    }

    /// Output bits.
    pub fn outputs(&self) -> u32 {
        self.servo.outputs()
    }

    /// Encoder count.
    pub fn encoder(&self) -> i32 {
        self.servo.encoder()
    }

    /// Model counters.
    pub fn counters(&self) -> SimCansmcCounters {
        self.servo.counters()
    }

    /// See [`SimCansmcServo::inject_fault`].
    pub fn inject_fault(&mut self) {
        self.servo.inject_fault();
    }

    /// See [`SimCansmcServo::set_load`].
    pub fn set_load(&mut self, percent: u8) {
        self.servo.set_load(percent);
    }

    /// See [`SimCansmcServo::set_reply_delay`].
    pub fn set_reply_delay(&mut self, delay: Duration) {
        self.servo.set_reply_delay(delay);
    }

    /// See [`SimCansmcServo::set_drop_rate`].
    pub fn set_drop_rate(&mut self, rate: f64) {
        self.servo.set_drop_rate(rate);
    }

    /// See [`SimCansmcServo::set_encoder_velocity`].
    pub fn set_encoder_velocity(&mut self, v: Option<f64>) {
        self.servo.set_encoder_velocity(v);
    }

    /// See [`SimCansmcServo::set_input_word`].
    pub fn set_input_word(&mut self, word: u32) {
        self.servo.set_input_word(word);
    }
}

#[cfg(test)]
mod tests {
    use cangate_cansmc::telegram::{
        Channel, CycleCounter, Feedback, ParameterAccess, StatusWord, Telegram,
    };

    use super::*;

    const CYCLE_US: u32 = 4000;

    fn addr(a: u8) -> SmcAddress {
        SmcAddress::new(a).unwrap()
    }

    fn us(n: u64) -> Duration {
        Duration::from_micros(n)
    }

    /// A tiny master: one MST per cycle, one MDT 100 µs later.
    struct Master {
        slave: SimCansmcSlave,
        cycle: u64,
        counter: CycleCounter,
    }

    impl Master {
        fn new(options: SimCansmcSlaveOptions) -> Self {
            let mut slave = SimCansmcSlave::new(options);
            let mct = Telegram::Master {
                to: slave.address(),
                control: ControlWord::default(),
                command: Command::Connect {
                    cycle_time_us: CYCLE_US,
                    slave_count: 1,
                },
            };
            let dct = slave.on_frame(&mct.encode(), Duration::ZERO).unwrap();
            assert!(matches!(
                Telegram::decode(&dct, Channel::Status).unwrap(),
                Telegram::Slave {
                    feedback: Feedback::Connect { .. },
                    ..
                }
            ));
            Master {
                slave,
                cycle: 0,
                counter: CycleCounter::default(),
            }
        }

        fn mst_time(&self) -> Duration {
            us(self.cycle * u64::from(CYCLE_US))
        }

        fn control(&self, enable: bool) -> ControlWord {
            ControlWord {
                enable,
                counter: self.counter,
                ..ControlWord::default()
            }
        }

        /// One cycle: MST, then the MDT; returns the decoded answer.
        fn cycle_with(&mut self, control: ControlWord, command: Command) -> (StatusWord, Feedback) {
            self.cycle += 1;
            self.counter = self.counter.next();
            let control = ControlWord {
                counter: self.counter,
                ..control
            };
            let t = self.mst_time();
            assert_eq!(self.slave.on_frame(&Telegram::Mst.encode(), t), None);
            let mdt = Telegram::Master {
                to: self.slave.address(),
                control,
                command,
            };
            let reply = self.slave.on_frame(&mdt.encode(), t + us(100)).unwrap();
            match Telegram::decode(&reply, Channel::Status).unwrap() {
                Telegram::Slave {
                    status, feedback, ..
                } => {
                    assert_eq!(status.counter_echo, self.counter);
                    (status, feedback)
                }
                other => panic!("unexpected {other:?}"),
            }
        }

        fn cycle(&mut self, enable: bool, command: Command) -> (StatusWord, Feedback) {
            let control = self.control(enable);
            self.cycle_with(control, command)
        }

        fn parameter(&mut self, access: ParameterAccess, number: u16, value: i32) -> (bool, i32) {
            let t = self.mst_time() + us(200);
            let telegram = Telegram::Master {
                to: self.slave.address(),
                control: ControlWord::default(),
                command: Command::Parameter {
                    access,
                    number,
                    value,
                },
            };
            let reply = self.slave.on_frame(&telegram.encode(), t).unwrap();
            match Telegram::decode(&reply, Channel::Status).unwrap() {
                Telegram::Slave {
                    status,
                    feedback: Feedback::Parameter { number: n, value },
                    ..
                } => {
                    assert_eq!(n, number);
                    (status.parameter_error, value)
                }
                other => panic!("unexpected {other:?}"),
            }
        }
    }

    #[test]
    fn position_setpoints_are_followed() {
        let mut m = Master::new(SimCansmcSlaveOptions::default());
        // 10 counts per µs... 1000 counts per 4 ms cycle = 250 000 counts/s
        // (1500 r/min), below the 3000 r/min limit.
        let setpoints: Vec<i32> = (0..20).map(|k| k * 1000).collect();
        let mut reported = Vec::new();
        for &p in &setpoints {
            let (status, feedback) = m.cycle(true, Command::Position(p));
            reported.push((status, feedback));
        }
        // The set-point of cycle k takes effect at MST k+1 and is reached at
        // MST k+2, where it is sampled: the DT of cycle k+2 reports it.
        for k in 2..setpoints.len() {
            assert_eq!(
                reported[k].1,
                Feedback::Position(setpoints[k - 2]),
                "cycle {k}"
            );
            assert!(reported[k].0.enabled && reported[k].0.ready);
            assert!(reported[k].0.target_reached);
        }
        // The last DT (cycle 20) reported set-point 17 (the 18th).
        assert_eq!(m.slave.position(), 17_000);
        assert!((m.slave.velocity() - 250_000.0).abs() < 1e-6);
        assert_eq!(m.slave.fault(), None);

        // Parameter 1 = 1: the position DT reports the following error (0
        // when the set-points are reachable).
        assert_eq!(m.parameter(ParameterAccess::Write, 1, 1), (false, 1));
        let (_, feedback) = m.cycle(true, Command::Position(20_000));
        assert_eq!(feedback, Feedback::Position(0));
    }

    #[test]
    fn position_jump_is_velocity_limited() {
        let mut m = Master::new(SimCansmcSlaveOptions::default());
        // 3000 r/min × 10 000 / 60 = 500 000 counts/s: 2000 counts per cycle.
        // Cycle 1's MDT takes effect at MST 2; MST 3 samples the first move.
        for _ in 0..3 {
            m.cycle(true, Command::Position(10_000));
        }
        assert_eq!(m.slave.position(), 2000);
        assert_eq!(m.slave.servo().following_error(), 8000.0);
        let (status, _) = m.cycle(true, Command::Position(10_000));
        assert!(!status.target_reached && !status.fault);
        for _ in 0..5 {
            m.cycle(true, Command::Position(10_000));
        }
        assert_eq!(m.slave.position(), 10_000);
    }

    #[test]
    fn velocity_ramps_with_the_acceleration_limit() {
        let mut m = Master::new(SimCansmcSlaveOptions::default());
        // 600 r/min = 100 000 counts/s; at 5 000 000 counts/s² that takes
        // 20 ms = 5 cycles.
        m.cycle(true, Command::Velocity(600));
        let mut velocities = Vec::new();
        for _ in 0..8 {
            let (status, feedback) = m.cycle(true, Command::Velocity(600));
            velocities.push((m.slave.velocity(), status.target_reached, feedback));
        }
        // First sample: the command just took effect, no time has passed.
        assert_eq!(velocities[0].0, 0.0);
        assert_eq!(velocities[1].0, 20_000.0);
        assert_eq!(velocities[2].0, 40_000.0);
        assert_eq!(velocities[5].0, 100_000.0);
        assert!(!velocities[4].1 && velocities[5].1);
        assert_eq!(velocities[7].2, Feedback::Velocity(600));
        // Position: the ramp's area (0.5 × 100 000 × 0.02 = 1000) plus
        // 2 cycles at full speed (800 counts).
        assert_eq!(m.slave.position(), 1000 + 800);

        // In 0.001 r/min the same speed reads 600 000.
        assert_eq!(m.parameter(ParameterAccess::Write, 2, 1), (false, 1));
        let (_, feedback) = m.cycle(true, Command::Velocity(600_000));
        assert_eq!(feedback, Feedback::Velocity(600_000));

        // Halt: decelerates to 0 and holds.
        let halt = ControlWord {
            halt: true,
            ..m.control(true)
        };
        for _ in 0..8 {
            m.cycle_with(halt, Command::Velocity(600_000));
        }
        let (status, feedback) = m.cycle_with(halt, Command::Velocity(600_000));
        assert_eq!(feedback, Feedback::Velocity(0));
        assert!(status.target_reached && status.enabled);
    }

    #[test]
    fn homing_sets_homed_and_the_zero() {
        let options = SimCansmcSlaveOptions {
            initial_position: 5000,
            home_reference: 1000,
            homing_speed: 100_000.0,
            ..SimCansmcSlaveOptions::default()
        };
        let mut m = Master::new(options);
        // Not enabled yet: rejected with reason 2.
        let (_, feedback) = m.cycle(false, Command::Homing { method: 1 });
        assert_eq!(
            feedback,
            Feedback::Reject {
                function: Function::Homing,
                reason: RejectReason::NotEnabled
            }
        );
        // Unknown method: unsupported.
        let (_, feedback) = m.cycle(true, Command::Homing { method: 9 });
        assert_eq!(
            feedback,
            Feedback::Reject {
                function: Function::Homing,
                reason: RejectReason::Unsupported
            }
        );
        // 4000 counts at 100 000 counts/s = 40 ms = 10 cycles; the master
        // repeats the homing MDT until it sees the homed bit.
        let mut cycles = 0;
        let homed_at = loop {
            let (status, feedback) = m.cycle(true, Command::Homing { method: 1 });
            cycles += 1;
            assert!(cycles < 30, "never homed");
            if status.homed {
                break feedback;
            }
        };
        assert_eq!(homed_at, Feedback::Homing(0));
        assert_eq!(m.slave.position(), 0);
        assert_eq!(m.slave.servo().physical_position(), 1000.0);
        assert_eq!(m.slave.servo().mode(), SimCansmcMode::Homed);
        // Repeated homing MDTs leave it homed.
        let (status, _) = m.cycle(true, Command::Homing { method: 1 });
        assert!(status.homed && status.target_reached);

        // Method 2 zeroes where the motor stands.
        m.cycle(true, Command::Position(300));
        m.cycle(true, Command::Position(300));
        m.cycle(true, Command::Homing { method: 2 });
        let (status, feedback) = m.cycle(true, Command::Homing { method: 2 });
        assert!(status.homed);
        assert_eq!(feedback, Feedback::Homing(0));
        assert_eq!(m.slave.servo().physical_position(), 1300.0);

        // Homing not supported at all.
        let mut m = Master::new(SimCansmcSlaveOptions {
            supports_homing: false,
            ..SimCansmcSlaveOptions::default()
        });
        let (_, feedback) = m.cycle(true, Command::Homing { method: 1 });
        assert_eq!(
            feedback,
            Feedback::Reject {
                function: Function::Homing,
                reason: RejectReason::Unsupported
            }
        );
    }

    #[test]
    fn following_error_fault_and_reset() {
        let mut m = Master::new(SimCansmcSlaveOptions::default());
        m.cycle(true, Command::Position(0));
        // Full load: the motor stalls while the set-point runs away.
        m.slave.set_load(100);
        let mut fault_status = None;
        for k in 1..20 {
            let (status, _) = m.cycle(true, Command::Position(k * 2000));
            if status.fault {
                fault_status = Some(status);
                break;
            }
        }
        let status = fault_status.expect("following error fault");
        // Bits 2 and 5, not enabled, not ready.
        assert!(status.following_error && !status.enabled && !status.ready);
        assert_eq!(m.slave.fault(), Some(SimCansmcFault::FollowingError));

        // Motion MDTs are still answered in fault; homing is rejected.
        let (status, feedback) = m.cycle(true, Command::Position(0));
        assert!(status.fault && matches!(feedback, Feedback::Position(_)));
        let (_, feedback) = m.cycle(true, Command::Homing { method: 1 });
        assert_eq!(
            feedback,
            Feedback::Reject {
                function: Function::Homing,
                reason: RejectReason::Fault
            }
        );

        // Fault reset (edge) with the load removed, target at the position.
        m.slave.set_load(0);
        let here = m.slave.position();
        let reset = ControlWord {
            fault_reset: true,
            ..m.control(true)
        };
        m.cycle_with(reset, Command::Position(here));
        let (status, _) = m.cycle_with(reset, Command::Position(here));
        assert!(!status.fault && !status.following_error);
        assert!(status.ready && status.enabled);
        assert_eq!(m.slave.counters().faults, 1);
    }

    #[test]
    fn injected_fault_needs_a_reset_edge() {
        let mut m = Master::new(SimCansmcSlaveOptions::default());
        let reset = ControlWord {
            fault_reset: true,
            ..m.control(true)
        };
        for _ in 0..3 {
            m.cycle(true, Command::Velocity(100));
        }
        assert!(m.slave.velocity() > 0.0);
        m.slave.inject_fault();
        // The next sample shows the fault; this MDT carries the reset edge.
        let (status, _) = m.cycle_with(reset, Command::Velocity(100));
        assert!(status.fault && !status.enabled && !status.following_error);
        assert_eq!(m.slave.velocity(), 0.0);
        assert_eq!(m.slave.fault(), Some(SimCansmcFault::Injected));
        // The reset takes effect at the next MST and the drive re-enables.
        let (status, _) = m.cycle(true, Command::Velocity(100));
        assert!(!status.fault && status.enabled, "{status:?}");

        // A reset bit held high acts once, on its rising edge.
        m.cycle_with(reset, Command::Velocity(100));
        m.cycle_with(reset, Command::Velocity(100));
        m.slave.inject_fault();
        let (status, _) = m.cycle_with(reset, Command::Velocity(100));
        assert!(status.fault);
        let (status, _) = m.cycle(true, Command::Velocity(100));
        assert!(status.fault, "held-high reset bit has no edge");
        m.cycle_with(reset, Command::Velocity(100));
        let (status, _) = m.cycle(true, Command::Velocity(100));
        assert!(!status.fault, "a new edge resets");
        assert_eq!(m.slave.counters().faults, 2);
    }

    #[test]
    fn parameters_check_access_and_range() {
        let mut m = Master::new(SimCansmcSlaveOptions::default());
        use ParameterAccess::{Read, Write};
        assert_eq!(m.parameter(Read, 3, 0), (false, 10_000));
        assert_eq!(m.parameter(Write, 3, 5), (true, 0));
        assert_eq!(m.parameter(Read, 4, 0), (false, 20_000));
        assert_eq!(m.parameter(Write, 4, -1), (true, 0));
        assert_eq!(m.parameter(Write, 5, 0), (true, 0));
        assert_eq!(m.parameter(Write, 5, 1500), (false, 1500));
        assert_eq!(m.parameter(Write, 1, 2), (true, 0));
        assert_eq!(m.parameter(Read, 6, 0), (true, 0));
        assert_eq!(m.parameter(Write, 0x1000, 250), (false, 250));
        assert_eq!(m.slave.servo().reply_delay(), us(250));
        assert_eq!(m.parameter(Write, 0x1001, 101), (true, 0));
        assert_eq!(m.parameter(Write, 0x1001, 50), (false, 50));
        assert_eq!(m.parameter(Write, 0x1002, 125), (false, 125));
        assert_eq!(m.slave.servo().drop_rate(), 0.125);
        assert_eq!(m.parameter(Write, 0x1003, -1), (false, -1));
        // Max velocity 1500 r/min at 50 % load: 125 000 counts/s limit.
        m.slave.set_drop_rate(0.0);
        m.cycle(true, Command::Velocity(3000));
        for _ in 0..20 {
            m.cycle(true, Command::Velocity(3000));
        }
        assert_eq!(m.slave.velocity(), 125_000.0);
    }

    #[test]
    fn io_outputs_masked_and_inputs_looped_back() {
        let mut m = Master::new(SimCansmcSlaveOptions::default());
        m.slave.set_input_word(0x0000_00F0);
        let io = |outputs, mask| Command::Io { outputs, mask };
        m.cycle(false, io(0xFFFF_00FF, 0x000F));
        let (_, feedback) = m.cycle(false, io(0x0000_0000, 0x0003));
        // Outputs 0–3 set by the first MDT (bits 16–31 ignored); the DT
        // samples before the second takes effect.
        assert_eq!(
            feedback,
            Feedback::Io {
                inputs: 0x000F_00F0
            }
        );
        let (_, feedback) = m.cycle(false, Command::Encoder);
        assert_eq!(m.slave.outputs(), 0x000C);
        assert_eq!(feedback, Feedback::Encoder(0));
        let (_, feedback) = m.cycle(false, io(0, 0));
        assert_eq!(
            feedback,
            Feedback::Io {
                inputs: 0x000C_00F0
            }
        );
        // User telegrams are echoed.
        let (_, feedback) = m.cycle(false, Command::User([9, 8, 7, 6, 5, 4]));
        assert_eq!(feedback, Feedback::User([9, 8, 7, 6, 5, 4]));
    }

    #[test]
    fn external_encoder_runs_free() {
        let mut m = Master::new(SimCansmcSlaveOptions {
            encoder_velocity: Some(-2500.0),
            ..SimCansmcSlaveOptions::default()
        });
        let mut counts = Vec::new();
        for _ in 0..4 {
            let (_, feedback) = m.cycle(false, Command::Encoder);
            counts.push(feedback);
        }
        // -2500 counts/s × 4 ms = -10 counts per cycle from the MCT at t = 0.
        assert_eq!(counts, [-10, -20, -30, -40].map(Feedback::Encoder).to_vec());
        m.slave.set_encoder_velocity(None);
        assert_eq!(m.slave.encoder(), m.slave.position());
    }

    #[test]
    fn drop_and_delay_are_reproducible() {
        let run = |seed| {
            let mut slave = SimCansmcSlave::new(SimCansmcSlaveOptions {
                drop_rate: 0.3,
                reply_delay: us(150),
                seed,
                ..SimCansmcSlaveOptions::default()
            });
            let read = Telegram::Master {
                to: addr(1),
                control: ControlWord::default(),
                command: Command::Parameter {
                    access: ParameterAccess::Read,
                    number: 3,
                    value: 0,
                },
            }
            .encode();
            let fates: Vec<Option<Duration>> = (0..200)
                .map(|k| {
                    slave
                        .on_frame_with_faults(&read, us(k))
                        .map(|reply| reply.delay)
                })
                .collect();
            (fates, slave.counters())
        };
        let (a, counters) = run(7);
        let (b, _) = run(7);
        let (c, _) = run(8);
        assert_eq!(a, b, "same seed, same decisions");
        assert_ne!(a, c, "another seed, other decisions");
        let dropped = a.iter().filter(|f| f.is_none()).count() as u64;
        assert_eq!(counters.replies_dropped, dropped);
        assert_eq!(counters.replies_delayed, 200 - dropped);
        assert!((40..=80).contains(&dropped), "about 30 %: {dropped}");
        assert!(a.iter().flatten().all(|d| *d == us(150)));

        // Rate 0 and 1 draw nothing and decide alike for every seed.
        let mut slave = SimCansmcSlave::new(SimCansmcSlaveOptions::default());
        let mct = Telegram::Master {
            to: addr(1),
            control: ControlWord::default(),
            command: Command::Connect {
                cycle_time_us: 1000,
                slave_count: 1,
            },
        }
        .encode();
        let reply = slave.on_frame_with_faults(&mct, us(0)).unwrap();
        assert_eq!(reply.delay, Duration::ZERO);
        slave.set_drop_rate(1.0);
        assert_eq!(slave.on_frame_with_faults(&mct, us(1)), None);
        assert_eq!(slave.counters().replies_dropped, 1);
    }
}
