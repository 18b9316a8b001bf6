//! CANsmc phases, slaves, status and events as protobuf messages.

use crate::cansmc::{CansmcEvent, CansmcMaster, CansmcStatus, SlaveView};
use cangate_cansmc::master::{Phase, SlaveState};
use cangate_proto::v1 as pb;

pub(crate) fn phase_pb(p: Phase) -> pb::CansmcPhase {
    match p {
        Phase::Idle => pb::CansmcPhase::Idle,
        Phase::Connecting => pb::CansmcPhase::P0,
        Phase::Parameterising => pb::CansmcPhase::P1,
        Phase::Cyclic => pb::CansmcPhase::P2,
        Phase::Failed => pb::CansmcPhase::Failed,
    }
}

pub(crate) fn slave_state_pb(s: SlaveState) -> pb::CansmcSlaveState {
    match s {
        SlaveState::Connecting => pb::CansmcSlaveState::Connecting,
        SlaveState::Connected => pb::CansmcSlaveState::Connected,
        SlaveState::Missing => pb::CansmcSlaveState::Missing,
        SlaveState::Operational => pb::CansmcSlaveState::Operational,
        SlaveState::Lost => pb::CansmcSlaveState::Lost,
    }
}

/// The DTSW decoded bit by bit (reserved bits are kept in `raw` only).
pub(crate) fn status_word_pb(w: u16) -> pb::CansmcStatusWord {
    let bit = |n: u16| w & (1 << n) != 0;
    pb::CansmcStatusWord {
        raw: u32::from(w),
        ready: bit(0),
        enabled: bit(1),
        fault: bit(2),
        target_reached: bit(3),
        homed: bit(4),
        following_error: bit(5),
        parameter_error: bit(6),
        counter_echo: u32::from(w >> 12),
    }
}

pub(crate) fn slave_pb(s: &SlaveView) -> pb::CansmcSlave {
    let c = &s.counters;
    pb::CansmcSlave {
        address: u32::from(s.address),
        name: s.name.clone(),
        required: s.required,
        state: slave_state_pb(s.state) as i32,
        device_type: s.device_type.map(u32::from),
        firmware_version: s.firmware_version.map(u32::from),
        status_word: s.status_word.map(status_word_pb),
        counters: Some(pb::CansmcSlaveCounters {
            dts: c.dts,
            missed: c.missed,
            late: c.late,
            counter_mismatch: c.counter_mismatch,
            rejects: c.rejects,
            malformed: c.malformed,
            losses: c.losses,
            mdts: c.mdts,
        }),
        consecutive_misses: s.consecutive_misses,
        axis: s.axis.clone().unwrap_or_default(),
    }
}

pub(crate) fn status_pb(m: &CansmcMaster, st: &CansmcStatus) -> pb::CansmcStatus {
    let c = &st.counters;
    let j = &st.jitter;
    pb::CansmcStatus {
        master: m.name().to_string(),
        phase: phase_pb(st.phase) as i32,
        cycle: st.cycle,
        cycle_time_us: m.config().cycle_time_us,
        bitrate: m.bitrate(),
        start_error: st.start_error.clone(),
        starts: st.starts,
        counters: Some(pb::CansmcMasterCounters {
            cycles: c.cycles,
            overruns: c.overruns,
            mdt_slots_missed: c.mdt_slots_missed,
            foreign_frames: c.foreign_frames,
            stray_parameter_answers: c.stray_parameter_answers,
        }),
        slaves: st.slaves.iter().map(slave_pb).collect(),
        jitter: Some(pb::CycleJitter {
            samples: j.samples,
            p50_us: j.p50_us,
            p99_us: j.p99_us,
            p999_us: j.p999_us,
            max_us: j.max_us,
            mean_us: j.mean_us,
            histogram: j.histogram.counts().to_vec(),
            histogram_bucket_us: j.histogram.bucket_us,
        }),
        timestamp_us: now_us(),
    }
}

pub(crate) fn master_info_pb(m: &CansmcMaster) -> pb::CansmcMasterInfo {
    let cfg = m.config();
    let mut slaves: Vec<u32> = cfg.slaves.iter().map(|s| u32::from(s.address)).collect();
    slaves.sort_unstable();
    pb::CansmcMasterInfo {
        name: m.name().to_string(),
        command_bus: cfg.command_bus.clone(),
        status_bus: cfg.status_bus.clone(),
        cycle_time_us: cfg.cycle_time_us,
        phase: phase_pb(m.status().phase) as i32,
        bitrate: m.bitrate(),
        slave_addresses: slaves,
        axes: cfg.axes.iter().map(|a| a.name.clone()).collect(),
    }
}

pub(crate) fn event_pb(e: CansmcEvent) -> pb::CansmcEvent {
    use pb::cansmc_event::Event;
    pb::CansmcEvent {
        timestamp_us: now_us(),
        event: Some(match e {
            CansmcEvent::Phase(p) => Event::Phase(phase_pb(p) as i32),
            CansmcEvent::Slave { address, what } => Event::Slave(pb::CansmcSlaveEvent {
                address: u32::from(address),
                what,
            }),
        }),
    }
}

/// Now, µs since the Unix epoch.
fn now_us() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_word_bits() {
        let w = status_word_pb(0x5000 | 0b101_1011);
        assert_eq!(w.raw, 0x505B);
        assert!(w.ready && w.enabled && !w.fault && w.target_reached && w.homed);
        assert!(!w.following_error && w.parameter_error);
        assert_eq!(w.counter_echo, 5);
        let w = status_word_pb(0x0024);
        assert!(w.fault && w.following_error && !w.ready && !w.enabled);
        assert_eq!(w.counter_echo, 0);
    }

    #[test]
    fn phases_and_states_map_one_to_one() {
        assert_eq!(phase_pb(Phase::Connecting), pb::CansmcPhase::P0);
        assert_eq!(phase_pb(Phase::Parameterising), pb::CansmcPhase::P1);
        assert_eq!(phase_pb(Phase::Cyclic), pb::CansmcPhase::P2);
        assert_eq!(phase_pb(Phase::Failed), pb::CansmcPhase::Failed);
        assert_eq!(phase_pb(Phase::Idle), pb::CansmcPhase::Idle);
        assert_eq!(
            slave_state_pb(SlaveState::Missing),
            pb::CansmcSlaveState::Missing
        );
        assert_eq!(slave_state_pb(SlaveState::Lost), pb::CansmcSlaveState::Lost);
    }
}
