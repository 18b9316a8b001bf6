//! The master on a virtual clock against scripted slaves: every frame it
//! sends is checked, every answer is built by hand.

use super::*;
use cangate_can::CanId;

fn addr(a: u8) -> SmcAddress {
    SmcAddress::new(a).unwrap()
}

fn ms(v: u64) -> Duration {
    Duration::from_millis(v)
}

fn us(v: u64) -> Duration {
    Duration::from_micros(v)
}

fn decode(frames: &[Frame]) -> Vec<Telegram> {
    frames
        .iter()
        .map(|f| Telegram::decode(f, Channel::Command).unwrap())
        .collect()
}

fn dct(a: u8) -> Frame {
    Telegram::Slave {
        from: addr(a),
        status: StatusWord {
            ready: true,
            ..StatusWord::default()
        },
        feedback: Feedback::Connect {
            device_type: 0x0402,
            firmware_version: 0x0107,
        },
    }
    .encode()
}

fn dt(a: u8, counter: u8, position: i32) -> Frame {
    Telegram::Slave {
        from: addr(a),
        status: StatusWord {
            ready: true,
            enabled: true,
            counter_echo: CycleCounter::new(counter),
            ..StatusWord::default()
        },
        feedback: Feedback::Position(position),
    }
    .encode()
}

fn param_answer(a: u8, number: u16, value: i32, error: bool) -> Frame {
    Telegram::Slave {
        from: addr(a),
        status: StatusWord {
            ready: true,
            parameter_error: error,
            ..StatusWord::default()
        },
        feedback: Feedback::Parameter { number, value },
    }
    .encode()
}

/// No hand-over grace: a cycle is closed at `T_int` of the next one.
fn config(addresses: &[u8]) -> MasterConfig {
    let mut c = MasterConfig::new(
        ms(2),
        addresses.iter().map(|&a| SlaveSpec::new(addr(a))).collect(),
    );
    c.handover_grace = Duration::ZERO;
    c
}

/// A master in P2 at t = 0 with all `addresses` connected.
fn cyclic(addresses: &[u8]) -> Master {
    let mut m = Master::new(config(addresses)).unwrap();
    m.start(Duration::ZERO);
    for &a in addresses {
        m.on_frame(&dct(a), us(300));
    }
    let p = m.poll(us(300));
    assert_eq!(m.phase(), Phase::Cyclic);
    assert_eq!(decode(&p.frames), vec![Telegram::Mst]);
    assert_eq!(p.cycle_started, Some((0, us(300))));
    m
}

#[test]
fn configuration_errors_are_typed() {
    assert_eq!(
        Master::new(MasterConfig::new(ms(2), vec![])).unwrap_err(),
        ConfigError::NoSlaves
    );
    assert_eq!(
        Master::new(config(&[3, 3])).unwrap_err(),
        ConfigError::DuplicateAddress(3)
    );
    let mut c = config(&[1]);
    c.t_int = ms(2);
    assert!(matches!(
        Master::new(c).unwrap_err(),
        ConfigError::BadTInt { .. }
    ));
    let mut c = config(&[1]);
    c.cycle_time = us(50);
    assert!(matches!(
        Master::new(c).unwrap_err(),
        ConfigError::BadCycleTime(_)
    ));
}

#[test]
fn p0_sends_exact_mcts_and_goes_to_p2_when_all_answer() {
    let mut m = Master::new(config(&[2, 1])).unwrap();
    let frames = m.start(Duration::ZERO);
    // MCT to slave 1: id = 0x01 << 6 | 1 = 0x041; MDTCW 0; cycle time
    // 2000 µs = D0 07 00 00; slave count 2; reserved 0.
    assert_eq!(frames[0].id(), CanId::Standard(0x041));
    assert_eq!(frames[0].data(), &[0, 0, 0xD0, 0x07, 0, 0, 2, 0]);
    assert_eq!(frames[1].id(), CanId::Standard(0x042));
    assert_eq!(m.phase(), Phase::Connecting);
    assert_eq!(m.next_deadline(), Some(ms(50)));

    assert!(m.on_frame(&dct(1), us(200)).is_empty());
    assert_eq!(m.next_deadline(), Some(ms(50)), "still waiting for 2");
    m.on_frame(&dct(2), us(400));
    // Everyone answered: P0 ends at the next poll, without waiting.
    assert_eq!(m.next_deadline(), Some(Duration::ZERO));
    let p = m.poll(us(400));
    assert_eq!(decode(&p.frames), vec![Telegram::Mst]);
    assert_eq!(m.phase(), Phase::Cyclic);
    let s = m.slave(addr(2)).unwrap();
    assert_eq!(s.state, SlaveState::Operational);
    assert_eq!(s.device_type, Some(0x0402));
    assert_eq!(s.firmware_version, Some(0x0107));
    let events = m.take_events();
    assert!(events.contains(&MasterEvent::SlaveConnected {
        address: addr(1),
        device_type: 0x0402,
        firmware_version: 0x0107
    }));
    assert_eq!(events.last(), Some(&MasterEvent::Phase(Phase::Cyclic)));
}

#[test]
fn p0_fails_naming_a_missing_required_slave_after_its_retries() {
    let mut m = Master::new(config(&[1, 7])).unwrap();
    assert_eq!(m.start(Duration::ZERO).len(), 2);
    m.on_frame(&dct(1), ms(1));
    // Two more attempts, only to the silent slave.
    let retry = m.poll(ms(50)).frames;
    assert_eq!(decode(&retry).len(), 1);
    assert_eq!(retry[0].id(), CanId::Standard(0x047));
    assert_eq!(m.poll(ms(100)).frames.len(), 1);
    assert!(m.poll(ms(149)).frames.is_empty());
    assert!(m.poll(ms(150)).frames.is_empty());
    assert_eq!(m.phase(), Phase::Failed);
    let events = m.take_events();
    let failed = events
        .iter()
        .find_map(|e| match e {
            MasterEvent::StartFailed { reason } => Some(reason.clone()),
            _ => None,
        })
        .unwrap();
    assert!(failed.contains("required slave(s) 7"), "{failed}");
    assert_eq!(m.next_deadline(), None);
    assert_eq!(m.slave(addr(7)).unwrap().state, SlaveState::Missing);
}

#[test]
fn p0_goes_on_without_a_missing_optional_slave() {
    let mut c = config(&[1, 4]);
    c.slaves[1].required = false;
    let mut m = Master::new(c).unwrap();
    m.start(Duration::ZERO);
    m.on_frame(&dct(1), ms(1));
    m.poll(ms(50));
    m.poll(ms(100));
    let p = m.poll(ms(150));
    assert_eq!(m.phase(), Phase::Cyclic);
    assert_eq!(decode(&p.frames), vec![Telegram::Mst]);
    assert!(m.take_events().contains(&MasterEvent::SlaveMissing {
        address: addr(4),
        required: false,
        reason: "no DCT after 3 MCT(s), 50ms apart".into()
    }));
    // Only slave 1 gets an MDT.
    let mdts = decode(&m.poll(ms(150) + us(100)).frames);
    assert_eq!(mdts.len(), 1);
    assert_eq!(mdts[0].address(), 1);
}

#[test]
fn p1_writes_initial_parameters_one_at_a_time_per_slave() {
    let mut c = config(&[1]);
    c.slaves[0].parameters = vec![(4, 5000), (5, 3000)];
    let mut m = Master::new(c).unwrap();
    m.start(Duration::ZERO);
    m.on_frame(&dct(1), us(100));
    let p = m.poll(us(100));
    assert_eq!(m.phase(), Phase::Parameterising);
    // Parameter write 4 = 5000: id 0x141, MDTCW bit 3, number 04 00,
    // value 88 13 00 00.
    assert_eq!(p.frames.len(), 1, "one request outstanding per slave");
    assert_eq!(p.frames[0].id(), CanId::Standard(0x141));
    assert_eq!(p.frames[0].data(), &[0x08, 0, 4, 0, 0x88, 0x13, 0, 0]);
    let next = m.on_frame(&param_answer(1, 4, 5000, false), us(300));
    assert_eq!(next.len(), 1);
    assert_eq!(next[0].data(), &[0x08, 0, 5, 0, 0xB8, 0x0B, 0, 0]);
    let mst = m.on_frame(&param_answer(1, 5, 3000, false), us(500));
    assert_eq!(decode(&mst), vec![Telegram::Mst], "P2 starts at once");
    assert_eq!(m.phase(), Phase::Cyclic);
}

#[test]
fn p1_refused_initial_parameter_fails_a_required_slave() {
    let mut c = config(&[3]);
    c.slaves[0].parameters = vec![(3, 1)];
    let mut m = Master::new(c).unwrap();
    m.start(Duration::ZERO);
    m.on_frame(&dct(3), us(100));
    m.poll(us(100));
    m.on_frame(&param_answer(3, 3, 0, true), us(300));
    assert_eq!(m.phase(), Phase::Failed);
    let reason = m
        .take_events()
        .into_iter()
        .find_map(|e| match e {
            MasterEvent::StartFailed { reason } => Some(reason),
            _ => None,
        })
        .unwrap();
    assert!(
        reason.contains("parameter 3") && reason.contains("unknown, read-only or out of range"),
        "{reason}"
    );
}

#[test]
fn p2_sends_mdts_in_address_order_with_the_cycle_counter() {
    let mut m = cyclic(&[9, 2, 5]);
    assert_eq!(m.next_deadline(), Some(us(400)), "T_int_end = t0 + 100 µs");
    m.set_command(
        addr(5),
        ControlWord {
            enable: true,
            ..ControlWord::default()
        },
        Command::Position(-2),
    )
    .unwrap();
    assert!(m.poll(us(399)).frames.is_empty());
    let p = m.poll(us(400));
    let t = decode(&p.frames);
    assert_eq!(
        t.iter().map(Telegram::address).collect::<Vec<_>>(),
        vec![2, 5, 9]
    );
    // Slave 5: id 0x085, MDTCW enable, counter 0; target -2.
    assert_eq!(p.frames[1].id(), CanId::Standard(0x085));
    assert_eq!(
        p.frames[1].data(),
        &[0x01, 0x00, 0xFE, 0xFF, 0xFF, 0xFF, 0, 0]
    );
    assert_eq!(m.next_deadline(), Some(us(2300)));

    // Cycle 17 carries counter 1 in bits 12-15.
    for k in 1..=17u64 {
        let p = m.poll(us(300) + ms(2) * k as u32);
        assert_eq!(p.cycle_started.map(|c| c.0), Some(k));
        let p = m.poll(us(400) + ms(2) * k as u32);
        assert_eq!(p.frames.len(), 3);
        if k == 17 {
            assert_eq!(p.frames[1].data()[1], 0x10);
        }
    }
    assert_eq!(m.counters().cycles, 18);
}

#[test]
fn p2_counts_valid_late_and_mismatched_dts_and_loses_silent_slaves() {
    let mut m = cyclic(&[1, 2]);
    m.poll(us(400));
    // Cycle 0: slave 1 answers in time, slave 2 answers with a wrong
    // counter (that is not an answer).
    m.on_frame(&dt(1, 0, 100), us(700));
    m.on_frame(&dt(2, 9, 200), us(800));
    let s1 = m.slave(addr(1)).unwrap();
    assert_eq!(s1.last, Some((dt_status(0), Feedback::Position(100), 0)));
    // Cycle 1 starts; slave 2's cycle-0 answer comes after MST: late.
    m.poll(us(2300));
    m.on_frame(&dt(2, 0, 200), us(2310));
    m.poll(us(2400));
    m.on_frame(&dt(1, 1, 101), us(2600));
    m.poll(us(4300));
    m.poll(us(4400));
    m.on_frame(&dt(1, 2, 102), us(4600));
    m.poll(us(6300));
    // Cycle 2 is closed at T_int_end of cycle 3.
    assert_eq!(m.slave(addr(2)).unwrap().counters.missed, 2);
    let p = m.poll(us(6400));
    assert_eq!(p.frames.len(), 2, "still sent MDTs");
    let s2 = m.slave(addr(2)).unwrap();
    assert_eq!(s2.counters.counter_mismatch, 1);
    assert_eq!(s2.counters.late, 1);
    assert_eq!(s2.counters.missed, 3);
    assert_eq!(s2.counters.dts, 0);
    assert_eq!(s2.state, SlaveState::Lost, "3 consecutive misses");
    let s1 = m.slave(addr(1)).unwrap();
    assert_eq!((s1.counters.dts, s1.counters.missed), (3, 0));
    assert!(m.take_events().contains(&MasterEvent::SlaveLost {
        address: addr(2),
        misses: 3
    }));
    // A valid DT brings it back.
    m.on_frame(&dt(2, 3, 205), us(6600));
    assert_eq!(m.slave(addr(2)).unwrap().state, SlaveState::Operational);
    assert!(
        m.take_events()
            .contains(&MasterEvent::SlaveRecovered { address: addr(2) })
    );
}

fn dt_status(counter: u8) -> StatusWord {
    StatusWord {
        ready: true,
        enabled: true,
        counter_echo: CycleCounter::new(counter),
        ..StatusWord::default()
    }
}

#[test]
fn p2_parameter_access_uses_the_slot_after_the_mdts() {
    let mut m = cyclic(&[1, 2]);
    let read = m.read_parameter(addr(2), 3).unwrap();
    let write = m.write_parameter(addr(2), 77, 1).unwrap();
    let p = m.poll(us(400));
    let t = decode(&p.frames);
    assert_eq!(t.len(), 3, "two MDTs and one parameter telegram");
    assert_eq!(p.frames[2].id(), CanId::Standard(0x142));
    assert_eq!(p.frames[2].data(), &[0x00, 0x00, 3, 0, 0, 0, 0, 0]);
    m.on_frame(&param_answer(2, 3, 10_000, false), us(700));
    // The write waits for the next cycle's slot and is refused.
    m.poll(us(2300));
    let p = m.poll(us(2400));
    assert_eq!(p.frames.len(), 3);
    assert_eq!(p.frames[2].data()[0], 0x08);
    m.on_frame(&param_answer(2, 77, 0, true), us(2700));
    let events = m.take_events();
    assert!(events.contains(&MasterEvent::ParameterDone {
        id: read,
        address: addr(2),
        number: 3,
        result: Ok(10_000)
    }));
    assert!(events.contains(&MasterEvent::ParameterDone {
        id: write,
        address: addr(2),
        number: 77,
        result: Err(ParameterError::Refused {
            address: 2,
            number: 77
        })
    }));
    // Parameter answers are not cyclic DTs: both cycles missed for 2.
    m.poll(us(4300));
    m.poll(us(4400));
    assert_eq!(m.slave(addr(2)).unwrap().counters.missed, 2);
}

#[test]
fn parameter_requests_time_out_and_unknown_slaves_are_refused() {
    let mut m = cyclic(&[1]);
    let id = m.read_parameter(addr(1), 5).unwrap();
    m.poll(us(400));
    assert_eq!(m.next_deadline(), Some(us(2300)));
    let mut t = us(2300);
    while t <= us(400) + ms(100) {
        m.poll(t);
        m.poll(t + us(100));
        t += ms(2);
    }
    let done = m.take_events().into_iter().find_map(|e| match e {
        MasterEvent::ParameterDone { id: i, result, .. } if i == id => Some(result),
        _ => None,
    });
    assert!(matches!(done, Some(Err(ParameterError::Timeout { .. }))));
    assert_eq!(
        m.read_parameter(addr(9), 1),
        Err(ParameterError::UnknownSlave(9))
    );
    // A late answer after the timeout is only counted.
    m.on_frame(&param_answer(1, 5, 1, false), t);
    assert_eq!(m.counters().stray_parameter_answers, 1);
}

#[test]
fn a_late_poll_skips_whole_cycles_and_keeps_mst_on_the_grid() {
    let mut m = cyclic(&[1]);
    m.poll(us(400));
    // Next poll 3.5 cycles late.
    let p = m.poll(us(300) + ms(7));
    assert_eq!(p.cycle_started, Some((3, us(300) + ms(6))));
    assert_eq!(m.counters().overruns, 2);
    assert_eq!(m.next_deadline(), Some(us(300) + ms(6) + us(100)));
    // The MDT slot of cycle 3 is already late but inside the cycle: sent.
    assert_eq!(m.poll(us(300) + ms(7)).frames.len(), 1);
}

#[test]
fn polls_too_late_for_an_answer_send_no_mdt_and_do_not_lose_the_slaves() {
    // lost_after 3; the MDT deadline 1.5 ms into a 2 ms cycle.
    let mut c = config(&[1]);
    c.mdt_deadline = us(1500);
    let mut m = Master::new(c).unwrap();
    m.start(Duration::ZERO);
    m.on_frame(&dct(1), us(300));
    m.poll(us(300));
    // Five cycles whose MDT poll comes 1.8 ms after their MST (a loaded
    // host): the DTs could not be back before the next MST.
    for k in 0..5u64 {
        let start = 300 + k * 2000;
        if k > 0 {
            m.poll(us(start));
        }
        let p = m.poll(us(start + 1800));
        assert!(p.frames.is_empty(), "cycle {k}: no MDT after the deadline");
    }
    assert_eq!(m.counters().mdt_slots_missed, 5);
    let s = m.slave(addr(1)).unwrap();
    assert_eq!((s.counters.mdts, s.counters.missed), (0, 0));
    assert_eq!(s.state, SlaveState::Operational);
    // On time again: the MDT goes out.
    m.poll(us(300 + 5 * 2000));
    let p = m.poll(us(300 + 5 * 2000 + 1500));
    assert_eq!(p.frames.len(), 1, "at the deadline the MDT still goes");
}

#[test]
fn the_mdt_deadline_leaves_room_for_every_mdt_and_the_last_dt() {
    // Four slaves at 1 Mbit/s, 4 ms: 5 worst-case 8-byte telegrams
    // (135 bits, 135 µs each) and 20 µs response latency before the end.
    let c = MasterConfig::new(ms(4), (1..=4).map(|a| SlaveSpec::new(addr(a))).collect());
    assert_eq!(c.mdt_deadline_for(1_000_000), us(4000 - 5 * 135 - 20));
    // A cycle too short for its slaves still sends at T_int.
    assert_eq!(c.mdt_deadline_for(10_000), c.t_int);
    assert_eq!(c.mdt_deadline, ms(4), "no bound unless asked");
}

#[test]
fn malformed_and_foreign_frames_are_counted_not_used() {
    let mut m = cyclic(&[1]);
    m.poll(us(400));
    // DT from slave 1 with a reserved status bit set.
    let bad = Frame::new(CanId::Standard(0x081), &[0x80, 0, 0, 0, 0, 0, 0, 0]).unwrap();
    m.on_frame(&bad, us(500));
    m.on_frame(&dt(33, 0, 1), us(600));
    assert_eq!(m.slave(addr(1)).unwrap().counters.malformed, 1);
    assert_eq!(m.counters().foreign_frames, 1);
    assert_eq!(m.slave(addr(1)).unwrap().counters.dts, 0);
}

#[test]
fn restart_goes_back_through_p0_and_cancels_requests() {
    let mut m = cyclic(&[1]);
    let id = m.read_parameter(addr(1), 1).unwrap();
    let frames = m.restart(ms(1));
    assert_eq!(m.phase(), Phase::Connecting);
    assert_eq!(frames.len(), 1);
    assert!(m.take_events().contains(&MasterEvent::ParameterDone {
        id,
        address: addr(1),
        number: 1,
        result: Err(ParameterError::Cancelled)
    }));
    m.stop();
    assert_eq!(m.next_deadline(), None);
    assert!(m.read_parameter(addr(1), 1).is_err());
}

#[test]
fn a_dt_that_arrived_in_time_counts_even_when_processed_after_the_next_mst() {
    let mut m = cyclic(&[1]);
    m.poll(us(400));
    // Cycle 1 starts at 2300; the cycle-0 DT stamped 2250 is handed over
    // at 2350 (host scheduling delay): valid for cycle 0.
    m.poll(us(2300));
    m.on_frame(&dt(1, 0, 42), us(2250));
    m.poll(us(2400));
    let s = m.slave(addr(1)).unwrap();
    assert_eq!(
        (s.counters.dts, s.counters.missed, s.counters.late),
        (1, 0, 0)
    );
    assert_eq!(s.last.unwrap().1, Feedback::Position(42));
    assert_eq!(s.last.unwrap().2, 0);
    // One stamped after the MST of its next cycle is late.
    m.poll(us(4300));
    m.on_frame(&dt(1, 1, 43), us(4310));
    m.poll(us(4400));
    let s = m.slave(addr(1)).unwrap();
    assert_eq!(
        (s.counters.dts, s.counters.missed, s.counters.late),
        (1, 1, 1)
    );
}

/// Runs cycle `k` of a master from `cyclic` (MST at 300 µs + k × 2 ms,
/// MDTs 100 µs later); every slave in `answering` answers in time.
fn run_cycle(m: &mut Master, k: u64, answering: &[u8]) {
    let start = 300 + k * 2000;
    m.poll(us(start));
    m.poll(us(start + 100));
    for &a in answering {
        m.on_frame(&dt(a, (k % 16) as u8, 0), us(start + 300));
    }
}

#[test]
fn a_wrong_counter_echo_is_a_mismatch_not_late_once_the_counter_wrapped() {
    let mut m = cyclic(&[1, 2]);
    m.poll(us(400));
    m.on_frame(&dt(1, 0, 0), us(700));
    m.on_frame(&dt(2, 0, 0), us(700));
    for k in 1..40 {
        run_cycle(&mut m, k, &[1, 2]);
    }
    // Cycle 40 (counter 8): slave 2 echoes counters it was sent and
    // answered long ago, as a slave with a broken counter would: none of
    // them answers an MDT, so every one is a mismatch, none is late.
    run_cycle(&mut m, 40, &[1]);
    for wrong in [3u8, 7, 13] {
        m.on_frame(&dt(2, wrong, 0), us(300 + 40 * 2000 + 400));
    }
    let s2 = m.slave(addr(2)).unwrap().counters;
    assert_eq!((s2.counter_mismatch, s2.late), (3, 0), "{s2:?}");
    // A real late answer: cycle 41's DT is missed, its answer comes in
    // cycle 42 — late once; the same echo again is a mismatch.
    run_cycle(&mut m, 41, &[1]);
    run_cycle(&mut m, 42, &[1, 2]);
    m.on_frame(&dt(2, 41 % 16, 0), us(300 + 42 * 2000 + 500));
    m.on_frame(&dt(2, 41 % 16, 0), us(300 + 42 * 2000 + 600));
    run_cycle(&mut m, 43, &[1, 2]);
    let s2 = m.slave(addr(2)).unwrap().counters;
    assert_eq!((s2.counter_mismatch, s2.late), (4, 1), "{s2:?}");
    // Every MDT is accounted for: answered in time or missed.
    assert_eq!(s2.dts + s2.missed, s2.mdts, "{s2:?}");
}

#[test]
fn a_rejected_mdt_still_delivers_the_slave_status_word() {
    let mut m = cyclic(&[1]);
    m.poll(us(400));
    m.on_frame(&dt(1, 0, 7), us(700));
    run_cycle(&mut m, 1, &[]);
    // Cycle 1: the slave is in fault and rejects its homing MDT; the reject
    // carries the fault in its status word.
    let reject = Telegram::Slave {
        from: addr(1),
        status: StatusWord {
            ready: true,
            fault: true,
            counter_echo: CycleCounter::new(1),
            ..StatusWord::default()
        },
        feedback: Feedback::Reject {
            function: Function::Homing,
            reason: RejectReason::Fault,
        },
    }
    .encode();
    m.on_frame(&reject, us(2300 + 400));
    let s = m.slave(addr(1)).unwrap();
    let (status, feedback, cycle) = s.last.unwrap();
    assert!(status.fault, "the application must see the fault");
    assert_eq!(cycle, 1);
    assert!(matches!(feedback, Feedback::Reject { .. }));
    assert_eq!((s.counters.dts, s.counters.rejects), (2, 1));
    assert!(m.take_events().iter().any(|e| matches!(
        e,
        MasterEvent::Rejected {
            reason: RejectReason::Fault,
            ..
        }
    )));
}

#[test]
fn a_dt_stamped_in_time_counts_when_handed_over_within_the_grace() {
    let mut c = config(&[1]);
    c.handover_grace = ms(5); // 3 cycles of 2 ms
    let mut m = Master::new(c).unwrap();
    m.start(Duration::ZERO);
    m.on_frame(&dct(1), us(300));
    m.poll(us(300));
    assert_eq!(m.phase(), Phase::Cyclic);
    m.poll(us(400));
    // Cycles 1..=3 pass without the DT of cycle 0 (the host delayed its
    // delivery); it was stamped 700 µs into cycle 0.
    for k in 1..=3 {
        run_cycle(&mut m, k, &[1]);
    }
    assert_eq!(m.slave(addr(1)).unwrap().counters.missed, 0);
    m.on_frame(&dt(1, 0, 5), us(700));
    let s = m.slave(addr(1)).unwrap().counters;
    assert_eq!((s.dts, s.missed, s.late), (4, 0, 0), "{s:?}");
    // Cycle 4's DT never comes: missed at T_int of cycle 8, not before.
    run_cycle(&mut m, 4, &[]);
    for k in 5..=7 {
        run_cycle(&mut m, k, &[1]);
    }
    assert_eq!(m.slave(addr(1)).unwrap().counters.missed, 0);
    run_cycle(&mut m, 8, &[1]);
    let s = m.slave(addr(1)).unwrap().counters;
    assert_eq!((s.dts, s.missed), (8, 1), "{s:?}");
    // Stamped after the end of its cycle: late, whenever it is handed over.
    run_cycle(&mut m, 9, &[]);
    m.on_frame(&dt(1, 9, 0), us(300 + 10 * 2000 + 10));
    let s = m.slave(addr(1)).unwrap().counters;
    assert_eq!((s.late, s.counter_mismatch), (1, 0), "{s:?}");
}
