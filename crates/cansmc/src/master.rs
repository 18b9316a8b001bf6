//! The CANsmc master as a sans-IO state machine: phases P0 (connection),
//! P1 (parameterisation) and P2 (cyclic operation) of
//! `shared/specs/cansmc.md`.
//!
//! The runtime feeds it every frame received on channel 1 ([`Master::on_frame`])
//! and calls [`Master::poll`] whenever [`Master::next_deadline`] has passed;
//! `poll` returns the frames to send on channel 0. Time is a
//! [`Duration`] from an arbitrary monotonic origin chosen by the runtime,
//! so tests run on a virtual clock.
//!
//! # One P2 cycle
//!
//! ```text
//! t_k                    t_k + T_int                          t_k+1 = T_end_m
//! | MST |  application   | MDT a1 | MDT a2 | … | param slot |     | MST …
//!          sets commands     DTs arrive on channel 1 ───────────▶|
//! ```
//!
//! - `poll` at `t_k` sends MST and reports [`Poll::cycle_started`]. The
//!   application then reads the latest feedback ([`Master::slave`]) and
//!   sets cycle k's command values ([`Master::set_command`]) before
//!   `T_int_end`.
//! - `poll` at `t_k + T_int` first closes cycle k-1 (every slave that was
//!   sent a cyclic MDT and did not answer it in time is counted as missed),
//!   then sends one MDT per active slave in address order, with cycle
//!   counter `k mod 16`, then at most one non-cyclic parameter telegram
//!   (the "parameter slot": parameter access keeps working in P2 without
//!   disturbing the cyclic telegrams).
//! - A DT echoing counter `k` that *arrived* before `t_k+1` is valid, even
//!   when the runtime hands it over after `t_k+1`: the arrival time given
//!   to [`Master::on_frame`] (the bus timestamp) decides, not the moment
//!   the runtime got to it. That is why cycle k is closed only at `T_int`
//!   of cycle `k + 1 + g`, `g` being [`MasterConfig::handover_grace`] in
//!   cycles: then every slave sent an MDT in cycle k and not answered in
//!   time is counted as missed. A DT that answers an open MDT but arrived
//!   after the end of its cycle is *late* (counted, not used, and the cycle
//!   is still missed); a duplicate, or an echo of a counter that no open
//!   MDT carried, is a *counter mismatch*.
//!   `lost_after` consecutive misses mark the slave lost
//!   ([`MasterEvent::SlaveLost`]); a valid DT afterwards brings it back
//!   ([`MasterEvent::SlaveRecovered`]).
//!
//! Cycle start times are absolute (`t_k = t_0 + k × cycle`), so they never
//! drift; when the runtime polls more than a whole cycle late, the missed
//! cycles are skipped and counted as overruns.
//!
//! # Fixed here
//!
//! The spec leaves these open:
//! - P0 sends the MCTs of all configured slaves back to back, waits
//!   `connect_timeout` and resends to the silent ones, `connect_attempts`
//!   times in all.
//! - The MCT's cycle counter is 0; MST carries no counter (it has no data).
//! - An initial parameter write that fails stops the start for a required
//!   slave and drops an optional one from the cycle.
//! - In P2 a parameter answer arrives in the same cycle as its request; it
//!   is not a cyclic DT and does not count for misses.

use std::collections::{BTreeMap, VecDeque};
use std::fmt;
use std::time::Duration;

use cangate_can::Frame;

use crate::telegram::{
    Channel, CodecError, Command, ControlWord, CycleCounter, Feedback, Function, ParameterAccess,
    RejectReason, SmcAddress, StatusWord, Telegram,
};

/// One slave the master is configured for.
#[derive(Debug, Clone, PartialEq)]
pub struct SlaveSpec {
    /// Its address, 1..=61.
    pub address: SmcAddress,
    /// Whether the master refuses to start without it.
    pub required: bool,
    /// Parameters written in P1 (number, value), in order.
    pub parameters: Vec<(u16, i32)>,
    /// The cyclic command until the application sets another.
    pub initial_command: Command,
}

impl SlaveSpec {
    /// A required slave without initial parameters, asked for its position
    /// (target 0, not enabled) until the application says otherwise.
    pub fn new(address: SmcAddress) -> Self {
        SlaveSpec {
            address,
            required: true,
            parameters: Vec::new(),
            initial_command: Command::Position(0),
        }
    }
}

/// The master's configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct MasterConfig {
    /// Cycle time of phase P2 (sent to the slaves in the MCT, in µs).
    pub cycle_time: Duration,
    /// Time after MST before the MDTs go out (`T_int`).
    pub t_int: Duration,
    /// How long P0 waits for DCTs before resending MCTs.
    pub connect_timeout: Duration,
    /// MCTs sent to each slave before it is reported missing (≥ 1).
    pub connect_attempts: u32,
    /// Bound of one parameter request.
    pub parameter_timeout: Duration,
    /// Consecutive missed DTs after which a slave is lost (≥ 1).
    pub lost_after: u32,
    /// How long after the end of a cycle a DT that *arrived* in time (by
    /// its bus timestamp) may still be handed over and count: the time
    /// between the wire and the runtime (a receive thread, a bus scheduler
    /// under host load) is not the slave's. A cycle's misses are counted
    /// this much later (rounded up to whole cycles, at most 14).
    pub handover_grace: Duration,
    /// The latest time after a cycle's start at which its MDTs still go
    /// out: a poll later than this could not have the slaves' DTs back
    /// before the cycle ends, so the MDT slot passes unused and counts as
    /// the master's (`mdt_slots_missed`), not as the slaves' misses. A
    /// loaded host that wakes the master late in a cycle must not lose
    /// slaves that did nothing wrong. [`MasterConfig::new`] sets the cycle
    /// time (no bound); [`MasterConfig::mdt_deadline_for`] computes it
    /// from the bus's bit rate.
    pub mdt_deadline: Duration,
    /// The slaves, in any order (MDTs go out in address order).
    pub slaves: Vec<SlaveSpec>,
}

impl MasterConfig {
    /// A configuration with the given cycle and slaves and defaults for the
    /// rest: `T_int` 100 µs, 3 connection attempts 50 ms apart, parameter
    /// timeout 100 ms, lost after 3 misses, 10 ms hand-over grace.
    pub fn new(cycle_time: Duration, slaves: Vec<SlaveSpec>) -> Self {
        MasterConfig {
            cycle_time,
            t_int: Duration::from_micros(u64::from(crate::feasibility::DEFAULT_T_INT_US)),
            connect_timeout: Duration::from_millis(50),
            connect_attempts: 3,
            parameter_timeout: Duration::from_millis(100),
            lost_after: 3,
            handover_grace: Duration::from_millis(10),
            mdt_deadline: cycle_time,
            slaves,
        }
    }

    /// The [`MasterConfig::mdt_deadline`] of this cycle at `bitrate`: the
    /// cycle time less the worst-case time of every slave's MDT, one more
    /// telegram for the last DT, and the slaves' response latency
    /// ([`crate::feasibility`]); never before `T_int`.
    pub fn mdt_deadline_for(&self, bitrate: u32) -> Duration {
        let bitrate = u64::from(bitrate.max(1));
        let telegram_bits = u64::from(crate::feasibility::frame_bits_worst_case(8));
        let telegram_ns = (telegram_bits * 1_000_000_000).div_ceil(bitrate);
        let slaves = self.slaves.len() as u64;
        let answer = Duration::from_nanos(
            (slaves + 1) * telegram_ns + u64::from(crate::feasibility::DEFAULT_RESPONSE_US) * 1_000,
        );
        self.cycle_time.saturating_sub(answer).max(self.t_int)
    }

    /// [`MasterConfig::handover_grace`] in whole cycles (the counter's 16
    /// values must tell the open cycles apart).
    pub fn handover_grace_cycles(&self) -> u64 {
        let cycle = self.cycle_time.as_nanos().max(1);
        let n = self.handover_grace.as_nanos().div_ceil(cycle);
        u64::try_from(n).unwrap_or(u64::MAX).min(14)
    }
}

/// Why a configuration cannot run.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ConfigError {
    /// No slave configured.
    #[error("a CANsmc master needs at least one slave")]
    NoSlaves,
    /// An address configured twice.
    #[error("slave address {0} is configured twice")]
    DuplicateAddress(u8),
    /// A cycle time outside what the MCT can carry or the runtime can keep.
    #[error("cycle time {0:?} must be between 100 µs and 4294 s")]
    BadCycleTime(Duration),
    /// `T_int` not shorter than the cycle.
    #[error("T_int {t_int:?} must be shorter than the cycle time {cycle:?}")]
    BadTInt {
        /// `T_int`.
        t_int: Duration,
        /// The cycle time.
        cycle: Duration,
    },
    /// A zero count or timeout.
    #[error("{0} must be positive")]
    NotPositive(&'static str),
}

/// The master's phase.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Phase {
    /// Not started (or stopped).
    Idle,
    /// P0: connecting (MCT/DCT).
    Connecting,
    /// P1: writing the initial parameters.
    Parameterising,
    /// P2: cyclic operation.
    Cyclic,
    /// Start-up failed (a required slave is missing or refused its
    /// parameters); [`Master::restart`] tries again.
    Failed,
}

impl Phase {
    /// Short name: `idle`, `P0`, `P1`, `P2`, `failed`.
    pub const fn name(self) -> &'static str {
        match self {
            Phase::Idle => "idle",
            Phase::Connecting => "P0",
            Phase::Parameterising => "P1",
            Phase::Cyclic => "P2",
            Phase::Failed => "failed",
        }
    }
}

impl fmt::Display for Phase {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Where a slave stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SlaveState {
    /// No DCT yet.
    Connecting,
    /// Answered its MCT.
    Connected,
    /// Did not answer in P0 (optional slaves only: the master runs without
    /// it) or refused its initial parameters.
    Missing,
    /// In the cycle, answering.
    Operational,
    /// `lost_after` consecutive DTs missed; still sent MDTs so that it can
    /// come back.
    Lost,
}

impl SlaveState {
    /// Lower-case name.
    pub const fn name(self) -> &'static str {
        match self {
            SlaveState::Connecting => "connecting",
            SlaveState::Connected => "connected",
            SlaveState::Missing => "missing",
            SlaveState::Operational => "operational",
            SlaveState::Lost => "lost",
        }
    }
}

/// Per-slave counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SlaveCounters {
    /// Cyclic MDTs sent.
    pub mdts: u64,
    /// Valid DTs received (in time, right counter).
    pub dts: u64,
    /// Cycles whose DT never came in time.
    pub missed: u64,
    /// DTs that came after the end of their cycle (counted, not used).
    pub late: u64,
    /// DTs echoing a counter that was never sent for them.
    pub counter_mismatch: u64,
    /// Reject telegrams.
    pub rejects: u64,
    /// Telegrams from this address that do not decode.
    pub malformed: u64,
    /// Times the slave was declared lost.
    pub losses: u64,
}

/// A cyclic MDT waiting for its DT.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct OpenMdt {
    /// The cycle it was sent in.
    cycle: u64,
    /// A late answer came (counted as late; the cycle is still missed).
    late: bool,
    /// Counted as missed; kept until the counter comes round again, so a
    /// late answer is still recognised as one.
    closed: bool,
}

/// What the master knows of one slave.
#[derive(Debug, Clone, PartialEq)]
pub struct SlaveStatus {
    /// The configuration.
    pub spec: SlaveSpec,
    /// State.
    pub state: SlaveState,
    /// Device type from the DCT.
    pub device_type: Option<u16>,
    /// Firmware version from the DCT.
    pub firmware_version: Option<u16>,
    /// Latest valid cyclic DT: status word, feedback and the cycle it
    /// answered.
    pub last: Option<(StatusWord, Feedback, u64)>,
    /// Consecutive cycles without a valid DT.
    pub consecutive_misses: u32,
    /// Counters.
    pub counters: SlaveCounters,
    /// The control word and command of the next MDT.
    pub control: ControlWord,
    /// See `control`.
    pub command: Command,
    /// Per counter value: the cyclic MDT that carried it and is not
    /// closed yet (answered in time, or closed as missed). An echo is
    /// valid when it answers an open MDT and arrived before the end of
    /// that MDT's cycle; *late* when it answers an open MDT after that;
    /// anything else (a duplicate, a counter that no open MDT carried, a
    /// corrupted one) is a counter mismatch.
    open: [Option<OpenMdt>; 16],
}

impl SlaveStatus {
    /// Whether the slave takes part in the cycle.
    pub fn active(&self) -> bool {
        matches!(
            self.state,
            SlaveState::Connected | SlaveState::Operational | SlaveState::Lost
        )
    }
}

/// Identifies a parameter request.
pub type RequestId = u64;

/// Why a parameter request failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ParameterError {
    /// DTSW bit 6: unknown number, read-only or out of range.
    #[error("slave {address} refused parameter {number} (unknown, read-only or out of range)")]
    Refused {
        /// The slave.
        address: u8,
        /// The parameter.
        number: u16,
    },
    /// A reject telegram.
    #[error("slave {address} rejected the parameter telegram: {reason:?}")]
    Rejected {
        /// The slave.
        address: u8,
        /// Why.
        reason: RejectReason,
    },
    /// No answer in time.
    #[error("slave {address} did not answer parameter {number} within {timeout:?}")]
    Timeout {
        /// The slave.
        address: u8,
        /// The parameter.
        number: u16,
        /// The bound.
        timeout: Duration,
    },
    /// The address is not configured.
    #[error("slave {0} is not configured on this master")]
    UnknownSlave(u8),
    /// The slave is missing or the master is not running.
    #[error("slave {address} cannot take parameter requests: {why}")]
    Unavailable {
        /// The slave.
        address: u8,
        /// Why.
        why: String,
    },
    /// The master restarted or stopped before the answer.
    #[error("the master restarted before the answer")]
    Cancelled,
}

/// What the master reports.
#[derive(Debug, Clone, PartialEq)]
pub enum MasterEvent {
    /// The phase changed.
    Phase(Phase),
    /// A slave answered its MCT.
    SlaveConnected {
        /// The slave.
        address: SmcAddress,
        /// From the DCT.
        device_type: u16,
        /// From the DCT.
        firmware_version: u16,
    },
    /// A slave did not answer in P0 or refused its initial parameters.
    SlaveMissing {
        /// The slave.
        address: SmcAddress,
        /// Whether the start fails because of it.
        required: bool,
        /// Why, for people.
        reason: String,
    },
    /// Start-up failed; the master is in [`Phase::Failed`].
    StartFailed {
        /// For people: which slaves and why.
        reason: String,
    },
    /// `lost_after` consecutive DTs missed.
    SlaveLost {
        /// The slave.
        address: SmcAddress,
        /// Consecutive misses.
        misses: u32,
    },
    /// A lost slave answers again.
    SlaveRecovered {
        /// The slave.
        address: SmcAddress,
    },
    /// A slave rejected its cyclic command.
    Rejected {
        /// The slave.
        address: SmcAddress,
        /// The rejected function.
        function: Function,
        /// Why.
        reason: RejectReason,
    },
    /// A parameter request ended.
    ParameterDone {
        /// The request.
        id: RequestId,
        /// The slave.
        address: SmcAddress,
        /// The parameter.
        number: u16,
        /// The value read or written, or why not.
        result: Result<i32, ParameterError>,
    },
}

/// What one [`Master::poll`] produced.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Poll {
    /// Frames to send on channel 0, in order.
    pub frames: Vec<Frame>,
    /// Cycle `k` started with the MST in `frames`: the application sets its
    /// command values now. Carries the scheduled start time of the cycle.
    pub cycle_started: Option<(u64, Duration)>,
}

#[derive(Debug, Clone)]
struct ParamRequest {
    id: RequestId,
    access: ParameterAccess,
    number: u16,
    value: i32,
    /// Part of P1's initial writes.
    initial: bool,
}

#[derive(Debug, Clone)]
struct Outstanding {
    request: ParamRequest,
    deadline: Duration,
}

/// Counters of the whole master.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MasterCounters {
    /// Cycles started (MSTs sent).
    pub cycles: u64,
    /// Cycles skipped because `poll` came more than a cycle late.
    pub overruns: u64,
    /// Cycles whose MDTs were not sent because `poll` came too late.
    pub mdt_slots_missed: u64,
    /// Frames on channel 1 that do not decode or come from unknown
    /// addresses.
    pub foreign_frames: u64,
    /// Parameter answers nobody waited for (after a timeout).
    pub stray_parameter_answers: u64,
}

/// The CANsmc master.
#[derive(Debug)]
pub struct Master {
    config: MasterConfig,
    phase: Phase,
    slaves: BTreeMap<u8, SlaveStatus>,
    /// P0: attempts made and when the current one times out.
    attempts: u32,
    connect_deadline: Duration,
    /// P2: start of cycle 0 and the current cycle.
    origin: Duration,
    cycle: u64,
    mdts_sent: bool,
    /// The previous cycle's DTs are not evaluated yet (see
    /// [`Master::on_frame`]).
    /// Parameter requests per slave; one outstanding each.
    queues: BTreeMap<u8, VecDeque<ParamRequest>>,
    outstanding: BTreeMap<u8, Outstanding>,
    /// Round-robin position of the P2 parameter slot.
    slot_cursor: u8,
    next_id: RequestId,
    events: Vec<MasterEvent>,
    counters: MasterCounters,
}

impl Master {
    /// A master for `config`, in [`Phase::Idle`].
    pub fn new(config: MasterConfig) -> Result<Self, ConfigError> {
        if config.slaves.is_empty() {
            return Err(ConfigError::NoSlaves);
        }
        if config.cycle_time < Duration::from_micros(100)
            || config.cycle_time.as_micros() > u128::from(u32::MAX)
        {
            return Err(ConfigError::BadCycleTime(config.cycle_time));
        }
        if config.t_int >= config.cycle_time {
            return Err(ConfigError::BadTInt {
                t_int: config.t_int,
                cycle: config.cycle_time,
            });
        }
        if config.connect_attempts == 0 {
            return Err(ConfigError::NotPositive("connect_attempts"));
        }
        if config.lost_after == 0 {
            return Err(ConfigError::NotPositive("lost_after"));
        }
        if config.connect_timeout.is_zero() {
            return Err(ConfigError::NotPositive("connect_timeout"));
        }
        if config.parameter_timeout.is_zero() {
            return Err(ConfigError::NotPositive("parameter_timeout"));
        }
        let mut slaves = BTreeMap::new();
        for s in &config.slaves {
            let a = s.address.get();
            let status = SlaveStatus {
                spec: s.clone(),
                state: SlaveState::Connecting,
                device_type: None,
                firmware_version: None,
                last: None,
                consecutive_misses: 0,
                counters: SlaveCounters::default(),
                control: ControlWord::default(),
                command: s.initial_command,
                open: [None; 16],
            };
            if slaves.insert(a, status).is_some() {
                return Err(ConfigError::DuplicateAddress(a));
            }
        }
        Ok(Master {
            config,
            phase: Phase::Idle,
            slaves,
            attempts: 0,
            connect_deadline: Duration::ZERO,
            origin: Duration::ZERO,
            cycle: 0,
            mdts_sent: false,
            queues: BTreeMap::new(),
            outstanding: BTreeMap::new(),
            slot_cursor: 0,
            next_id: 1,
            events: Vec::new(),
            counters: MasterCounters::default(),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &MasterConfig {
        &self.config
    }

    /// The phase.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// The current (latest started) cycle of P2.
    pub fn cycle(&self) -> u64 {
        self.cycle
    }

    /// Scheduled start of cycle `k`.
    pub fn cycle_start(&self, k: u64) -> Duration {
        let ns = self
            .config
            .cycle_time
            .as_nanos()
            .saturating_mul(u128::from(k));
        self.origin + Duration::from_nanos(u64::try_from(ns).unwrap_or(u64::MAX))
    }

    /// Master counters.
    pub fn counters(&self) -> MasterCounters {
        self.counters
    }

    /// One slave.
    pub fn slave(&self, address: SmcAddress) -> Option<&SlaveStatus> {
        self.slaves.get(&address.get())
    }

    /// Every slave in address order.
    pub fn slaves(&self) -> impl Iterator<Item = &SlaveStatus> {
        self.slaves.values()
    }

    /// Takes the events since the last call.
    pub fn take_events(&mut self) -> Vec<MasterEvent> {
        std::mem::take(&mut self.events)
    }

    fn set_phase(&mut self, phase: Phase) {
        if self.phase != phase {
            self.phase = phase;
            self.events.push(MasterEvent::Phase(phase));
        }
    }

    /// Starts P0 at `now`: the MCTs to send on channel 0.
    pub fn start(&mut self, now: Duration) -> Vec<Frame> {
        self.cancel_requests();
        for s in self.slaves.values_mut() {
            s.state = SlaveState::Connecting;
            s.device_type = None;
            s.firmware_version = None;
            s.last = None;
            s.consecutive_misses = 0;
            s.control = ControlWord::default();
            s.command = s.spec.initial_command;
            s.open = [None; 16];
        }
        self.set_phase(Phase::Connecting);
        self.attempts = 0;
        self.send_mcts(now)
    }

    /// Back through P0 and P1 (pending parameter requests are cancelled).
    pub fn restart(&mut self, now: Duration) -> Vec<Frame> {
        self.start(now)
    }

    /// Stops: no more frames until [`Master::start`].
    pub fn stop(&mut self) {
        self.cancel_requests();
        self.set_phase(Phase::Idle);
    }

    fn cancel_requests(&mut self) {
        let mut cancelled = Vec::new();
        for (a, o) in std::mem::take(&mut self.outstanding) {
            cancelled.push((a, o.request));
        }
        for (a, q) in std::mem::take(&mut self.queues) {
            cancelled.extend(q.into_iter().map(|r| (a, r)));
        }
        for (a, r) in cancelled {
            if r.initial {
                continue;
            }
            if let Ok(address) = SmcAddress::new(a) {
                self.events.push(MasterEvent::ParameterDone {
                    id: r.id,
                    address,
                    number: r.number,
                    result: Err(ParameterError::Cancelled),
                });
            }
        }
    }

    fn send_mcts(&mut self, now: Duration) -> Vec<Frame> {
        self.attempts += 1;
        self.connect_deadline = now + self.config.connect_timeout;
        let cycle_time_us = u32::try_from(self.config.cycle_time.as_micros()).unwrap_or(u32::MAX);
        let slave_count = u8::try_from(self.slaves.len()).unwrap_or(u8::MAX);
        self.slaves
            .values()
            .filter(|s| s.state == SlaveState::Connecting)
            .map(|s| {
                Telegram::Master {
                    to: s.spec.address,
                    control: ControlWord::default(),
                    command: Command::Connect {
                        cycle_time_us,
                        slave_count,
                    },
                }
                .encode()
            })
            .collect()
    }

    /// Queues a parameter read; the answer comes as
    /// [`MasterEvent::ParameterDone`].
    pub fn read_parameter(
        &mut self,
        address: SmcAddress,
        number: u16,
    ) -> Result<RequestId, ParameterError> {
        self.queue_parameter(address, ParameterAccess::Read, number, 0, false)
    }

    /// Queues a parameter write; the answer comes as
    /// [`MasterEvent::ParameterDone`].
    pub fn write_parameter(
        &mut self,
        address: SmcAddress,
        number: u16,
        value: i32,
    ) -> Result<RequestId, ParameterError> {
        self.queue_parameter(address, ParameterAccess::Write, number, value, false)
    }

    fn queue_parameter(
        &mut self,
        address: SmcAddress,
        access: ParameterAccess,
        number: u16,
        value: i32,
        initial: bool,
    ) -> Result<RequestId, ParameterError> {
        let a = address.get();
        let Some(s) = self.slaves.get(&a) else {
            return Err(ParameterError::UnknownSlave(a));
        };
        let why = match (self.phase, s.state) {
            (Phase::Idle, _) => Some("the master is not running".to_string()),
            (Phase::Failed, _) => Some("the master's start-up failed".to_string()),
            (_, SlaveState::Missing) => Some("it is missing".to_string()),
            (Phase::Connecting, _) if !initial => {
                Some("the master is still connecting (P0)".to_string())
            }
            _ => None,
        };
        if let Some(why) = why {
            return Err(ParameterError::Unavailable { address: a, why });
        }
        let id = self.next_id;
        self.next_id += 1;
        self.queues.entry(a).or_default().push_back(ParamRequest {
            id,
            access,
            number,
            value,
            initial,
        });
        Ok(id)
    }

    /// Sets the control word and command of `address`'s next MDTs (the
    /// counter is the master's). Call it after [`Poll::cycle_started`] and
    /// before `T_int_end`; the values stay until changed.
    pub fn set_command(
        &mut self,
        address: SmcAddress,
        control: ControlWord,
        command: Command,
    ) -> Result<(), ParameterError> {
        if matches!(command, Command::Connect { .. } | Command::Parameter { .. }) {
            return Err(ParameterError::Unavailable {
                address: address.get(),
                why: "connection and parameter telegrams are not cyclic commands".into(),
            });
        }
        let s = self
            .slaves
            .get_mut(&address.get())
            .ok_or(ParameterError::UnknownSlave(address.get()))?;
        s.control = ControlWord {
            counter: CycleCounter::default(),
            ..control
        };
        s.command = command;
        Ok(())
    }

    /// When [`Master::poll`] must run next.
    pub fn next_deadline(&self) -> Option<Duration> {
        let param = self.outstanding.values().map(|o| o.deadline).min();
        let phase = match self.phase {
            Phase::Idle | Phase::Failed => None,
            Phase::Connecting => Some(self.connect_deadline),
            // P1 sends requests as soon as a slave is free; `poll` right
            // after each answer does that, so only timeouts are deadlines.
            Phase::Parameterising => None,
            Phase::Cyclic => Some(if self.mdts_sent {
                self.cycle_start(self.cycle + 1)
            } else {
                self.cycle_start(self.cycle) + self.config.t_int
            }),
        };
        match (param, phase) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Runs everything due at `now`: the frames to send on channel 0.
    pub fn poll(&mut self, now: Duration) -> Poll {
        let mut out = Poll::default();
        self.expire_parameters(now);
        match self.phase {
            Phase::Idle | Phase::Failed => {}
            Phase::Connecting => {
                if now >= self.connect_deadline {
                    if self.attempts < self.config.connect_attempts {
                        out.frames = self.send_mcts(now);
                    } else {
                        self.finish_connecting(now, &mut out);
                    }
                }
            }
            Phase::Parameterising => self.run_parameterising(now, &mut out),
            Phase::Cyclic => self.run_cyclic(now, &mut out),
        }
        out
    }

    fn finish_connecting(&mut self, now: Duration, out: &mut Poll) {
        let mut missing_required = Vec::new();
        for s in self.slaves.values_mut() {
            if s.state == SlaveState::Connecting {
                s.state = SlaveState::Missing;
                let reason = format!(
                    "no DCT after {} MCT(s), {:?} apart",
                    self.config.connect_attempts, self.config.connect_timeout
                );
                if s.spec.required {
                    missing_required.push(s.spec.address.get());
                }
                self.events.push(MasterEvent::SlaveMissing {
                    address: s.spec.address,
                    required: s.spec.required,
                    reason,
                });
            }
        }
        if !missing_required.is_empty() {
            self.fail(format!(
                "required slave(s) {} did not answer the connection telegram (P0)",
                join(&missing_required)
            ));
            return;
        }
        self.set_phase(Phase::Parameterising);
        let initial: Vec<(SmcAddress, Vec<(u16, i32)>)> = self
            .slaves
            .values()
            .filter(|s| s.state == SlaveState::Connected)
            .map(|s| (s.spec.address, s.spec.parameters.clone()))
            .collect();
        for (address, params) in initial {
            for (number, value) in params {
                // Cannot fail: the slave is configured and connected.
                let _ = self.queue_parameter(address, ParameterAccess::Write, number, value, true);
            }
        }
        self.run_parameterising(now, out);
    }

    fn fail(&mut self, reason: String) {
        self.cancel_requests();
        self.events.push(MasterEvent::StartFailed { reason });
        self.set_phase(Phase::Failed);
    }

    fn run_parameterising(&mut self, now: Duration, out: &mut Poll) {
        let addresses: Vec<u8> = self.queues.keys().copied().collect();
        for a in addresses {
            if let Some(frame) = self.next_parameter_telegram(a, now) {
                out.frames.push(frame);
            }
        }
        let initial_pending = self.queues.values().flatten().any(|r| r.initial)
            || self.outstanding.values().any(|o| o.request.initial);
        if !initial_pending && self.phase == Phase::Parameterising {
            self.enter_cyclic(now, out);
        }
    }

    fn next_parameter_telegram(&mut self, a: u8, now: Duration) -> Option<Frame> {
        if self.outstanding.contains_key(&a) {
            return None;
        }
        let request = self.queues.get_mut(&a)?.pop_front()?;
        let address = self.slaves.get(&a)?.spec.address;
        let frame = Telegram::Master {
            to: address,
            control: ControlWord {
                counter: CycleCounter::new(self.cycle as u8),
                ..self.slaves.get(&a)?.control
            },
            command: Command::Parameter {
                access: request.access,
                number: request.number,
                value: match request.access {
                    ParameterAccess::Read => 0,
                    ParameterAccess::Write => request.value,
                },
            },
        }
        .encode();
        self.outstanding.insert(
            a,
            Outstanding {
                request,
                deadline: now + self.config.parameter_timeout,
            },
        );
        Some(frame)
    }

    fn enter_cyclic(&mut self, now: Duration, out: &mut Poll) {
        for s in self.slaves.values_mut() {
            if s.state == SlaveState::Connected {
                s.state = SlaveState::Operational;
            }
        }
        self.set_phase(Phase::Cyclic);
        self.origin = now;
        self.cycle = 0;
        self.start_cycle(out);
    }

    fn start_cycle(&mut self, out: &mut Poll) {
        self.mdts_sent = false;
        self.counters.cycles += 1;
        out.frames.push(Telegram::Mst.encode());
        out.cycle_started = Some((self.cycle, self.cycle_start(self.cycle)));
    }

    fn run_cyclic(&mut self, now: Duration, out: &mut Poll) {
        let next = self.cycle_start(self.cycle + 1);
        if !self.mdts_sent {
            let start = self.cycle_start(self.cycle);
            if now < next && now <= start + self.config.mdt_deadline {
                if now >= start + self.config.t_int {
                    self.send_mdts(now, out);
                }
                return;
            }
            // The MDT slot of this cycle passed unused.
            self.mdts_sent = true;
            self.counters.mdt_slots_missed += 1;
        }
        if now < next {
            return;
        }
        // Skip whole cycles that passed without a poll: start the latest
        // cycle that is due, so MST stays on the grid.
        let elapsed = now.saturating_sub(self.origin);
        let due = (elapsed.as_nanos() / self.config.cycle_time.as_nanos()) as u64;
        if due > self.cycle + 1 {
            self.counters.overruns += due - self.cycle - 1;
        }
        self.cycle = due.max(self.cycle + 1);
        self.start_cycle(out);
    }

    fn send_mdts(&mut self, now: Duration, out: &mut Poll) {
        self.mdts_sent = true;
        self.close_open_cycles();
        let counter = CycleCounter::new(self.cycle as u8);
        for s in self.slaves.values_mut() {
            if !s.active() {
                continue;
            }
            s.counters.mdts += 1;
            s.open[usize::from(counter.get())] = Some(OpenMdt {
                cycle: self.cycle,
                late: false,
                closed: false,
            });
            out.frames.push(
                Telegram::Master {
                    to: s.spec.address,
                    control: ControlWord {
                        counter,
                        ..s.control
                    },
                    command: s.command,
                }
                .encode(),
            );
        }
        // The parameter slot: one request per cycle, round robin.
        let candidates: Vec<u8> = self
            .queues
            .iter()
            .filter(|(a, q)| !q.is_empty() && !self.outstanding.contains_key(a))
            .map(|(a, _)| *a)
            .collect();
        if let Some(&a) = candidates
            .iter()
            .find(|&&a| a > self.slot_cursor)
            .or_else(|| candidates.first())
        {
            self.slot_cursor = a;
            if let Some(frame) = self.next_parameter_telegram(a, now) {
                out.frames.push(frame);
            }
        }
    }

    /// Closes the cycles whose DTs have had their hand-over time: each
    /// open MDT of cycle `k` is closed at `T_int` of cycle `k + 1 + grace`
    /// and counted as missed; `lost_after` consecutive misses lose the
    /// slave.
    fn close_open_cycles(&mut self) {
        let grace = self.config.handover_grace_cycles();
        let Some(last) = self.cycle.checked_sub(1 + grace) else {
            return;
        };
        let lost_after = self.config.lost_after;
        for s in self.slaves.values_mut() {
            let mut due: Vec<u64> = s
                .open
                .iter()
                .flatten()
                .filter(|o| !o.closed && o.cycle <= last)
                .map(|o| o.cycle)
                .collect();
            due.sort_unstable();
            for k in due {
                if let Some(o) = &mut s.open[(k % 16) as usize] {
                    o.closed = true;
                }
                s.counters.missed += 1;
                s.consecutive_misses += 1;
                if s.consecutive_misses >= lost_after && s.state == SlaveState::Operational {
                    s.state = SlaveState::Lost;
                    s.counters.losses += 1;
                    self.events.push(MasterEvent::SlaveLost {
                        address: s.spec.address,
                        misses: s.consecutive_misses,
                    });
                }
            }
        }
    }

    fn expire_parameters(&mut self, now: Duration) {
        let expired: Vec<u8> = self
            .outstanding
            .iter()
            .filter(|(_, o)| now >= o.deadline)
            .map(|(a, _)| *a)
            .collect();
        for a in expired {
            if let Some(o) = self.outstanding.remove(&a) {
                let error = ParameterError::Timeout {
                    address: a,
                    number: o.request.number,
                    timeout: self.config.parameter_timeout,
                };
                self.parameter_done(a, o.request, Err(error));
            }
        }
    }

    fn parameter_done(
        &mut self,
        a: u8,
        request: ParamRequest,
        result: Result<i32, ParameterError>,
    ) {
        let Some(address) = self.slaves.get(&a).map(|s| s.spec.address) else {
            return;
        };
        if request.initial {
            if let Err(e) = &result {
                self.initial_write_failed(a, request.number, e.to_string());
            }
            return;
        }
        self.events.push(MasterEvent::ParameterDone {
            id: request.id,
            address,
            number: request.number,
            result,
        });
    }

    fn initial_write_failed(&mut self, a: u8, number: u16, why: String) {
        let Some(s) = self.slaves.get_mut(&a) else {
            return;
        };
        let reason = format!("initial write of parameter {number} failed: {why}");
        s.state = SlaveState::Missing;
        let required = s.spec.required;
        self.events.push(MasterEvent::SlaveMissing {
            address: s.spec.address,
            required,
            reason: reason.clone(),
        });
        self.queues.remove(&a);
        if required {
            self.fail(format!("required slave {a}: {reason} (P1)"));
        }
    }

    /// A frame received on channel 1; `now` is when it arrived (its bus
    /// timestamp on the master's clock, if the runtime has one). Returns
    /// frames to send at once on channel 0 (P1: the next parameter request
    /// of that slave).
    pub fn on_frame(&mut self, frame: &Frame, now: Duration) -> Vec<Frame> {
        let telegram = match Telegram::decode(frame, Channel::Status) {
            Ok(t) => t,
            Err(e) => {
                self.malformed(frame, e);
                return Vec::new();
            }
        };
        let Telegram::Slave {
            from,
            status,
            feedback,
        } = telegram
        else {
            self.counters.foreign_frames += 1;
            return Vec::new();
        };
        let a = from.get();
        if !self.slaves.contains_key(&a) {
            self.counters.foreign_frames += 1;
            return Vec::new();
        }
        match feedback {
            Feedback::Connect {
                device_type,
                firmware_version,
            } => self.on_dct(from, device_type, firmware_version),
            Feedback::Parameter { number, value } => {
                self.on_parameter_answer(a, status, number, value);
            }
            Feedback::Reject {
                function: Function::Parameter,
                reason,
            } => {
                if let Some(o) = self.outstanding.remove(&a) {
                    self.parameter_done(
                        a,
                        o.request,
                        Err(ParameterError::Rejected { address: a, reason }),
                    );
                }
                if let Some(s) = self.slaves.get_mut(&a) {
                    s.counters.rejects += 1;
                }
            }
            Feedback::Reject { function, reason } => {
                if let Some(cycle) = self.cyclic_answer(a, status, now) {
                    // The reject carries the slave's status word: the
                    // application must see it (a slave in fault answers a
                    // homing MDT with a reject every cycle, and its fault
                    // shows only here).
                    if let Some(s) = self.slaves.get_mut(&a)
                        && s.last.is_none_or(|(_, _, c)| c <= cycle)
                    {
                        s.last = Some((status, feedback, cycle));
                    }
                    self.events.push(MasterEvent::Rejected {
                        address: from,
                        function,
                        reason,
                    });
                }
                if let Some(s) = self.slaves.get_mut(&a) {
                    s.counters.rejects += 1;
                }
            }
            other => {
                if let Some(cycle) = self.cyclic_answer(a, status, now)
                    && let Some(s) = self.slaves.get_mut(&a)
                    && s.last.is_none_or(|(_, _, c)| c <= cycle)
                {
                    s.last = Some((status, other, cycle));
                }
            }
        }
        let mut frames = Vec::new();
        if self.phase == Phase::Parameterising {
            let mut out = Poll::default();
            self.run_parameterising(now, &mut out);
            frames = out.frames;
        }
        frames
    }

    fn malformed(&mut self, frame: &Frame, _error: CodecError) {
        // Attribute it to a slave when the identifier names one.
        let address = (frame.raw_id() & 0x3F) as u8;
        match self.slaves.get_mut(&address) {
            Some(s) if !frame.is_extended() => s.counters.malformed += 1,
            _ => self.counters.foreign_frames += 1,
        }
    }

    fn on_dct(&mut self, from: SmcAddress, device_type: u16, firmware_version: u16) {
        let Some(s) = self.slaves.get_mut(&from.get()) else {
            return;
        };
        s.device_type = Some(device_type);
        s.firmware_version = Some(firmware_version);
        if s.state == SlaveState::Connecting && self.phase == Phase::Connecting {
            s.state = SlaveState::Connected;
            self.events.push(MasterEvent::SlaveConnected {
                address: from,
                device_type,
                firmware_version,
            });
        }
        if self.phase == Phase::Connecting
            && self
                .slaves
                .values()
                .all(|s| s.state != SlaveState::Connecting)
        {
            // Everyone answered: no need to wait for the timeout.
            self.connect_deadline = Duration::ZERO;
            self.attempts = self.config.connect_attempts;
        }
    }

    fn on_parameter_answer(&mut self, a: u8, status: StatusWord, number: u16, value: i32) {
        let matches = self
            .outstanding
            .get(&a)
            .is_some_and(|o| o.request.number == number);
        if !matches {
            self.counters.stray_parameter_answers += 1;
            return;
        }
        let Some(o) = self.outstanding.remove(&a) else {
            return;
        };
        let result = if status.parameter_error {
            Err(ParameterError::Refused { address: a, number })
        } else {
            Ok(value)
        };
        self.parameter_done(a, o.request, result);
    }

    /// Classifies a cyclic answer that arrived at `at`: the cycle it is
    /// valid for, or `None` (late or mismatched, counted).
    fn cyclic_answer(&mut self, a: u8, status: StatusWord, at: Duration) -> Option<u64> {
        if self.phase != Phase::Cyclic {
            return None;
        }
        let echo = usize::from(status.counter_echo.get());
        let open = self.slaves.get(&a)?.open[echo];
        let valid = match open {
            Some(o) if !o.late && !o.closed && at < self.cycle_start(o.cycle + 1) => Some(o.cycle),
            _ => None,
        };
        let s = self.slaves.get_mut(&a)?;
        match (open, valid) {
            (_, Some(_)) => {
                s.open[echo] = None;
                s.counters.dts += 1;
                s.consecutive_misses = 0;
                if s.state == SlaveState::Lost {
                    s.state = SlaveState::Operational;
                    self.events.push(MasterEvent::SlaveRecovered {
                        address: s.spec.address,
                    });
                }
            }
            // After the end of its cycle: late, once.
            (Some(o), None) if !o.late => {
                s.open[echo] = Some(OpenMdt { late: true, ..o });
                s.counters.late += 1;
            }
            _ => s.counters.counter_mismatch += 1,
        }
        valid
    }
}

fn join(addresses: &[u8]) -> String {
    addresses
        .iter()
        .map(u8::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(test)]
mod tests;
