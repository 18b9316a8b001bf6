//! Byte vectors of the LSS master, checked against python `canopen`'s
//! `LssMaster` framing (canopen 2.4.1, `canopen/lss.py`) and CiA 305's
//! command table, and the master against [`LssSlave`]s.

use super::*;
use crate::lss_slave::{LssSlave, LssSlaveEvent};
use proptest::prelude::*;

const MS: Duration = Duration::from_millis(1);

fn h(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

fn wire(frames: &[Frame]) -> Vec<(u32, Vec<u8>)> {
    frames
        .iter()
        .map(|f| (f.raw_id(), f.data().to_vec()))
        .collect()
}

fn answer(hex: &str) -> Frame {
    Frame::new(CanId::Standard(0x7E4), &h(hex)).unwrap()
}

const ID: LssIdentity = LssIdentity {
    vendor_id: 0x0000_0360,
    product_code: 0x1234_5678,
    revision: 0x0001_0002,
    serial: 0xDEAD_BEEF,
};

#[test]
fn switch_global_is_unconfirmed() {
    let mut m = LssMaster::new();
    let s = m.start(
        LssCommand::SwitchGlobal(LssMode::Configuration),
        100 * MS,
        Duration::ZERO,
    );
    assert_eq!(wire(&s.frames), vec![(0x7E5, h("04 01 00 00 00 00 00 00"))]);
    assert_eq!(s.completed, Some(Ok(LssOutcome::Sent)));
    assert_eq!(m.next_deadline(), None);
    let s = m.start(
        LssCommand::SwitchGlobal(LssMode::Waiting),
        100 * MS,
        Duration::ZERO,
    );
    assert_eq!(wire(&s.frames), vec![(0x7E5, h("04 00 00 00 00 00 00 00"))]);
}

#[test]
fn switch_selective_sends_four_parts_and_waits_for_0x44() {
    let mut m = LssMaster::new();
    let s = m.start(LssCommand::SwitchSelective(ID), 100 * MS, Duration::ZERO);
    assert_eq!(
        wire(&s.frames),
        vec![
            (0x7E5, h("40 60 03 00 00 00 00 00")),
            (0x7E5, h("41 78 56 34 12 00 00 00")),
            (0x7E5, h("42 02 00 01 00 00 00 00")),
            (0x7E5, h("43 EF BE AD DE 00 00 00")),
        ]
    );
    assert_eq!(s.completed, None);
    // Another cs is not the answer.
    assert_eq!(
        m.on_frame(&answer("4F 00 00 00 00 00 00 00"), MS).completed,
        None
    );
    let s = m.on_frame(&answer("44 00 00 00 00 00 00 00"), MS);
    assert_eq!(s.completed, Some(Ok(LssOutcome::Confirmed)));
}

#[test]
fn configure_node_id_confirmed_refused_and_invalid() {
    let mut m = LssMaster::new();
    let s = m.start(LssCommand::ConfigureNodeId(20), 100 * MS, Duration::ZERO);
    assert_eq!(wire(&s.frames), vec![(0x7E5, h("11 14 00 00 00 00 00 00"))]);
    let s = m.on_frame(&answer("11 00 00 00 00 00 00 00"), MS);
    assert_eq!(s.completed, Some(Ok(LssOutcome::Confirmed)));

    m.start(LssCommand::ConfigureNodeId(20), 100 * MS, Duration::ZERO);
    let s = m.on_frame(&answer("11 FF 07 00 00 00 00 00"), MS);
    let err = s.completed.unwrap().unwrap_err();
    assert_eq!(
        err,
        LssError::Refused {
            command: "configure node-ID",
            error: 0xFF,
            spec_error: 7
        }
    );
    assert!(err.to_string().contains("implementation-specific error 7"));

    for bad in [0u8, 128, 200] {
        let s = m.start(LssCommand::ConfigureNodeId(bad), 100 * MS, Duration::ZERO);
        assert!(s.frames.is_empty());
        assert!(matches!(s.completed, Some(Err(LssError::Invalid { .. }))));
    }
    // 255 takes the node-ID away: allowed.
    let s = m.start(LssCommand::ConfigureNodeId(255), 100 * MS, Duration::ZERO);
    assert_eq!(wire(&s.frames), vec![(0x7E5, h("11 FF 00 00 00 00 00 00"))]);
}

#[test]
fn bit_timing_store_and_activate() {
    let mut m = LssMaster::new();
    let s = m.start(
        LssCommand::ConfigureBitTiming { table: 0, index: 3 },
        100 * MS,
        Duration::ZERO,
    );
    assert_eq!(wire(&s.frames), vec![(0x7E5, h("13 00 03 00 00 00 00 00"))]);
    let s = m.on_frame(&answer("13 01 00 00 00 00 00 00"), MS);
    assert!(matches!(
        s.completed,
        Some(Err(LssError::Refused { error: 1, .. }))
    ));
    let s = m.start(LssCommand::StoreConfiguration, 100 * MS, Duration::ZERO);
    assert_eq!(wire(&s.frames), vec![(0x7E5, h("17 00 00 00 00 00 00 00"))]);
    let s = m.on_frame(&answer("17 02 00 00 00 00 00 00"), MS);
    assert!(matches!(
        s.completed,
        Some(Err(LssError::Refused { error: 2, .. }))
    ));
    // python canopen: message[1:3] = struct.pack('<H', switch_delay_ms)
    let s = m.start(
        LssCommand::ActivateBitTiming {
            switch_delay_ms: 1000,
        },
        100 * MS,
        Duration::ZERO,
    );
    assert_eq!(wire(&s.frames), vec![(0x7E5, h("15 E8 03 00 00 00 00 00"))]);
    assert_eq!(s.completed, Some(Ok(LssOutcome::Sent)));
}

#[test]
fn inquire_values_and_short_answers() {
    let mut m = LssMaster::new();
    let s = m.start(
        LssCommand::Inquire(InquireWhat::Serial),
        100 * MS,
        Duration::ZERO,
    );
    assert_eq!(wire(&s.frames), vec![(0x7E5, h("5D 00 00 00 00 00 00 00"))]);
    let s = m.on_frame(&answer("5D EF BE AD DE 00 00 00"), MS);
    assert_eq!(s.completed, Some(Ok(LssOutcome::Value(0xDEAD_BEEF))));
    m.start(
        LssCommand::Inquire(InquireWhat::NodeId),
        100 * MS,
        Duration::ZERO,
    );
    let s = m.on_frame(&answer("5E 14 00 00 00 00 00 00"), MS);
    assert_eq!(s.completed, Some(Ok(LssOutcome::Value(20))));
    m.start(
        LssCommand::Inquire(InquireWhat::VendorId),
        100 * MS,
        Duration::ZERO,
    );
    let s = m.on_frame(&answer("5A 60 03"), MS);
    assert!(matches!(s.completed, Some(Err(LssError::Protocol { .. }))));
}

#[test]
fn timeouts_busy_and_identify() {
    let mut m = LssMaster::new();
    m.start(LssCommand::StoreConfiguration, 100 * MS, Duration::ZERO);
    assert_eq!(m.next_deadline(), Some(100 * MS));
    let s = m.start(LssCommand::StoreConfiguration, 100 * MS, Duration::ZERO);
    assert_eq!(
        s.completed,
        Some(Err(LssError::Busy {
            running: "store configuration"
        }))
    );
    assert_eq!(m.on_tick(99 * MS).completed, None);
    assert_eq!(
        m.on_tick(100 * MS).completed,
        Some(Err(LssError::Timeout {
            command: "store configuration",
            after: 100 * MS
        }))
    );
    // Late answers with nothing running are ignored.
    assert_eq!(
        m.on_frame(&answer("17 00 00 00 00 00 00 00"), MS),
        LssStep::default()
    );

    let s = m.start(LssCommand::IdentifyNonConfigured, 50 * MS, Duration::ZERO);
    assert_eq!(wire(&s.frames), vec![(0x7E5, h("4C 00 00 00 00 00 00 00"))]);
    assert_eq!(
        m.on_tick(50 * MS).completed,
        Some(Ok(LssOutcome::Present(false)))
    );
    m.start(LssCommand::IdentifyNonConfigured, 50 * MS, Duration::ZERO);
    assert_eq!(
        m.on_frame(&answer("50 00 00 00 00 00 00 00"), MS).completed,
        Some(Ok(LssOutcome::Present(true)))
    );

    let range = IdentifyRange {
        vendor_id: 0x360,
        product_code: 0x12345678,
        revision_low: 0,
        revision_high: 0xFFFF_FFFF,
        serial_low: 1,
        serial_high: 2,
    };
    let s = m.start(LssCommand::IdentifyRemote(range), 50 * MS, Duration::ZERO);
    let cs: Vec<u8> = s.frames.iter().map(|f| f.data()[0]).collect();
    assert_eq!(cs, vec![0x46, 0x47, 0x48, 0x49, 0x4A, 0x4B]);
    assert_eq!(s.frames[3].data(), &h("49 FF FF FF FF 00 00 00")[..]);
}

#[test]
fn fastscan_query_bytes() {
    // python canopen: struct.pack('<BIBBB', CS_FAST_SCAN, id_number,
    // bit_checker, lss_sub, lss_next)
    assert_eq!(
        fastscan_frame(0x1234_5678, 31, 0, 0).data(),
        &h("51 78 56 34 12 1F 00 00")[..]
    );
    assert_eq!(
        fastscan_frame(0, 0x80, 0, 0).data(),
        &h("51 00 00 00 00 80 00 00")[..]
    );
    // The confirmation of the serial number: LSSNext wraps to 0.
    assert_eq!(
        fastscan_frame(0xDEAD_BEEF, 0, 3, 0).data(),
        &h("51 EF BE AD DE 00 03 00")[..]
    );
}

/// Runs the master against `slaves` with instant delivery; every step is
/// ticked at its deadline. Returns the outcome and the frames sent.
fn run(
    m: &mut LssMaster,
    slaves: &mut [LssSlave],
    command: LssCommand,
) -> (Result<LssOutcome, LssError>, usize) {
    let mut now = Duration::ZERO;
    let mut step = m.start(command, 100 * MS, now);
    let mut sent = 0;
    loop {
        let mut answers = Vec::new();
        for f in &step.frames {
            sent += 1;
            for s in slaves.iter_mut() {
                let (a, _) = s.on_frame(f);
                answers.extend(a);
            }
        }
        if let Some(r) = step.completed {
            return (r, sent);
        }
        let mut done = None;
        for a in &answers {
            let s = m.on_frame(a, now);
            assert!(s.frames.is_empty());
            done = done.or(s.completed);
        }
        if let Some(r) = done {
            return (r, sent);
        }
        now = m.next_deadline().expect("a running command has a deadline");
        step = m.on_tick(now);
    }
}

fn fastscan_all() -> LssCommand {
    LssCommand::Fastscan {
        step_time: 10 * MS,
        max_nodes: 16,
    }
}

#[test]
fn fastscan_finds_one_slave_in_133_steps() {
    let mut m = LssMaster::new();
    let mut slaves = [LssSlave::new(ID, UNCONFIGURED_NODE_ID)];
    let (r, sent) = run(&mut m, &mut slaves, fastscan_all());
    assert_eq!(r, Ok(LssOutcome::Found(vec![ID])));
    // Reset, 4 × (32 bits + confirmation), and the final reset query.
    assert_eq!(sent, 1 + 4 * 33 + 1);
    assert_eq!(slaves[0].mode(), LssMode::Configuration);
}

#[test]
fn fastscan_ignores_configured_slaves_and_reports_silence() {
    let mut m = LssMaster::new();
    let mut slaves = [LssSlave::new(ID, 5)];
    let (r, sent) = run(&mut m, &mut slaves, fastscan_all());
    assert_eq!(r, Ok(LssOutcome::Found(vec![])));
    assert_eq!(sent, 1);
}

#[test]
fn fastscan_restarts_after_a_failed_confirmation() {
    // The slave's answer to one bit query is lost (as if it came after
    // the step): the bit reads 1, the confirmation fails, the search
    // restarts and then finds the slave.
    let mut m = LssMaster::new();
    let mut slave = LssSlave::new(ID, UNCONFIGURED_NODE_ID);
    let mut now = Duration::ZERO;
    let mut step = m.start(fastscan_all(), 100 * MS, now);
    let (mut n, mut resets) = (0, 0);
    loop {
        for f in &step.frames {
            n += 1;
            resets += usize::from(f.data()[5] == FASTSCAN_RESET);
            // Query 3 asks whether vendor bit 30 is 0, which it is.
            if let (Some(a), _) = slave.on_frame(f)
                && n != 3
            {
                m.on_frame(&a, now);
            }
        }
        if let Some(r) = step.completed {
            assert_eq!(r, Ok(LssOutcome::Found(vec![ID])));
            // The first search, its restart, and the final silent query.
            assert_eq!(resets, 3);
            return;
        }
        now = m.next_deadline().unwrap();
        step = m.on_tick(now);
    }
}

#[test]
fn fastscan_gives_up_after_its_restarts() {
    // Something answers the reset queries and nothing else.
    let mut m = LssMaster::new();
    let mut now = Duration::ZERO;
    let mut step = m.start(fastscan_all(), 100 * MS, now);
    let mut resets = 0;
    loop {
        for f in &step.frames {
            if f.data()[5] == FASTSCAN_RESET {
                resets += 1;
                m.on_frame(&answer("4F 00 00 00 00 00 00 00"), now);
            }
        }
        if let Some(r) = step.completed {
            let e = r.unwrap_err();
            assert!(matches!(e, LssError::Protocol { .. }), "{e}");
            assert!(e.to_string().contains("vendor-ID 0xFFFFFFFF"), "{e}");
            assert_eq!(resets, 1 + usize::from(FASTSCAN_RESTARTS));
            return;
        }
        now = m.next_deadline().unwrap();
        step = m.on_tick(now);
    }
}

#[test]
fn configure_store_and_apply_through_the_slave() {
    let mut m = LssMaster::new();
    let mut slaves = [LssSlave::new(ID, UNCONFIGURED_NODE_ID)];
    let (r, _) = run(&mut m, &mut slaves, LssCommand::SwitchSelective(ID));
    assert_eq!(r, Ok(LssOutcome::Confirmed));
    let (r, _) = run(
        &mut m,
        &mut slaves,
        LssCommand::Inquire(InquireWhat::NodeId),
    );
    assert_eq!(r, Ok(LssOutcome::Value(255)));
    let (r, _) = run(&mut m, &mut slaves, LssCommand::ConfigureNodeId(20));
    assert_eq!(r, Ok(LssOutcome::Confirmed));
    let (r, _) = run(&mut m, &mut slaves, LssCommand::StoreConfiguration);
    assert_eq!(r, Ok(LssOutcome::Confirmed));
    assert_eq!(slaves[0].stored_node_id(), 20);
    // Back to waiting: the unconfigured slave takes its new id at once.
    let (_, events) = slaves[0].on_frame(&request_frame(cs::SWITCH_GLOBAL, &[0]));
    assert_eq!(
        events,
        vec![
            LssSlaveEvent::ModeChanged(LssMode::Waiting),
            LssSlaveEvent::ApplyNodeId(20)
        ]
    );
    // Configured now: no longer found.
    let (r, _) = run(&mut m, &mut slaves, fastscan_all());
    assert_eq!(r, Ok(LssOutcome::Found(vec![])));
    // Power cycle: the stored id.
    slaves[0].power_on();
    assert_eq!(slaves[0].active_node_id(), 20);
}

#[test]
fn a_slave_refuses_bad_ids_and_bit_timings() {
    let mut s = LssSlave::new(ID, UNCONFIGURED_NODE_ID).without_store();
    s.on_frame(&request_frame(cs::SWITCH_GLOBAL, &[1]));
    let (a, _) = s.on_frame(&request_frame(cs::CONFIGURE_NODE_ID, &[0]));
    assert_eq!(a.unwrap().data(), &h("11 01 00 00 00 00 00 00")[..]);
    let (a, _) = s.on_frame(&request_frame(cs::CONFIGURE_BIT_TIMING, &[0, 5]));
    assert_eq!(a.unwrap().data(), &h("13 01 00 00 00 00 00 00")[..]);
    let (a, _) = s.on_frame(&request_frame(cs::STORE_CONFIGURATION, &[]));
    assert_eq!(a.unwrap().data(), &h("17 01 00 00 00 00 00 00")[..]);
    let (a, _) = s.on_frame(&request_frame(cs::INQUIRE_PRODUCT, &[]));
    assert_eq!(a.unwrap().data(), &h("5B 78 56 34 12 00 00 00")[..]);
}

/// Frames as (COB-ID, bytes).
type Wire = Vec<(u32, Vec<u8>)>;

/// Like [`run`], also returning every frame sent.
fn run_wire(
    m: &mut LssMaster,
    slaves: &mut [LssSlave],
    command: LssCommand,
) -> (Result<LssOutcome, LssError>, Wire) {
    let mut now = Duration::ZERO;
    let mut step = m.start(command, 100 * MS, now);
    let mut sent = Vec::new();
    loop {
        let mut answers = Vec::new();
        for f in &step.frames {
            sent.push((f.raw_id(), f.data().to_vec()));
            for s in slaves.iter_mut() {
                answers.extend(s.on_frame(f).0);
            }
        }
        if let Some(r) = step.completed {
            return (r, sent);
        }
        let mut done = None;
        for a in &answers {
            done = done.or(m.on_frame(a, now).completed);
        }
        if let Some(r) = done {
            return (r, sent);
        }
        now = m.next_deadline().unwrap();
        step = m.on_tick(now);
    }
}

/// A slave like CANopenNode's answers fastscan in the configuration state
/// while it has no node-ID: the reset query after its find finds it again.
/// The scan reports it once and ends after the second search instead of
/// finding it `max_nodes` times (or for ever).
#[test]
fn a_slave_answering_until_configured_is_found_once() {
    let mut m = LssMaster::new();
    let mut slaves =
        [LssSlave::new(ID, UNCONFIGURED_NODE_ID).answering_fastscan_until_configured()];
    let (r, sent) = run_wire(&mut m, &mut slaves, fastscan_all());
    assert_eq!(r, Ok(LssOutcome::Found(vec![ID])));
    // Two whole searches: reset, 4 × (32 bits + confirmation), twice.
    assert_eq!(sent.len(), 2 * (1 + 4 * 33));
    let reset = (0x7E5, h("51 00 00 00 00 80 00 00"));
    assert_eq!(sent[0], reset);
    assert_eq!(sent[133], reset, "the second search");
    // Each search ends with the serial's confirmation (LSSNext 0).
    let confirm_serial = (0x7E5, h("51 EF BE AD DE 00 03 00"));
    assert_eq!(sent[132], confirm_serial);
    assert_eq!(sent[265], confirm_serial);
    assert_eq!(slaves[0].mode(), LssMode::Configuration);
    // A CiA 305 slave in the same place is found once, by one search and
    // one silent reset query.
    let mut m = LssMaster::new();
    let mut slaves = [LssSlave::new(ID, UNCONFIGURED_NODE_ID)];
    let (r, sent) = run_wire(&mut m, &mut slaves, fastscan_all());
    assert_eq!(r, Ok(LssOutcome::Found(vec![ID])));
    assert_eq!(sent.len(), 1 + 4 * 33 + 1);
}

/// Two such slaves: a scan for all finds only the lower (it hides the
/// other); finding one at a time and giving each its id before the next
/// search finds both. The frames between the finds: configure node-ID
/// (the found slave is in the configuration state), switch global waiting
/// (it takes the id and stops answering).
#[test]
fn slaves_answering_until_configured_are_found_one_at_a_time() {
    let id2 = LssIdentity {
        serial: ID.serial + 1,
        ..ID
    };
    let mut slaves = [
        LssSlave::new(id2, UNCONFIGURED_NODE_ID).answering_fastscan_until_configured(),
        LssSlave::new(ID, UNCONFIGURED_NODE_ID).answering_fastscan_until_configured(),
    ];
    let mut m = LssMaster::new();
    let (r, _) = run_wire(&mut m, &mut slaves, fastscan_all());
    assert_eq!(r, Ok(LssOutcome::Found(vec![ID])));
    run_wire(
        &mut m,
        &mut slaves,
        LssCommand::SwitchGlobal(LssMode::Waiting),
    )
    .0
    .unwrap();

    let one = LssCommand::Fastscan {
        step_time: 10 * MS,
        max_nodes: 1,
    };
    for (want, node) in [(ID, 10u8), (id2, 11)] {
        let (r, sent) = run_wire(&mut m, &mut slaves, one.clone());
        assert_eq!(r, Ok(LssOutcome::Found(vec![want])));
        assert_eq!(sent.len(), 1 + 4 * 33, "no reset query after the one find");
        let (r, sent) = run_wire(&mut m, &mut slaves, LssCommand::ConfigureNodeId(node));
        assert_eq!(r, Ok(LssOutcome::Confirmed));
        let mut configure = h("11 00 00 00 00 00 00 00");
        configure[1] = node;
        assert_eq!(sent, vec![(0x7E5, configure)]);
        let (_, sent) = run_wire(
            &mut m,
            &mut slaves,
            LssCommand::SwitchGlobal(LssMode::Waiting),
        );
        assert_eq!(sent, vec![(0x7E5, h("04 00 00 00 00 00 00 00"))]);
    }
    assert_eq!(slaves[1].active_node_id(), 10);
    assert_eq!(slaves[0].active_node_id(), 11);
    let (r, sent) = run_wire(&mut m, &mut slaves, one);
    assert_eq!(r, Ok(LssOutcome::Found(vec![])));
    assert_eq!(sent.len(), 1);
}

#[test]
fn the_shortest_fastscan_step_follows_the_bitrate() {
    // Two 135-bit frames and 2 ms, rounded up to whole ms.
    assert_eq!(min_fastscan_step(None), 2 * MS);
    assert_eq!(min_fastscan_step(Some(1_000_000)), 3 * MS);
    assert_eq!(min_fastscan_step(Some(500_000)), 3 * MS);
    assert_eq!(min_fastscan_step(Some(125_000)), 5 * MS);
    assert_eq!(min_fastscan_step(Some(10_000)), 29 * MS);
}

proptest! {
    /// Master against slaves: fastscan finds every non-configured slave,
    /// lowest identity first (the search takes the 0 branch whenever some
    /// slave answers), none of the configured ones; identify
    /// non-configured agrees.
    #[test]
    fn master_and_slaves_agree(
        ids in proptest::collection::btree_set(
            (0u32..4, any::<u32>(), 0u32..3, any::<u32>()), 0..4),
        configured in proptest::collection::vec(any::<bool>(), 4),
    ) {
        let ids: Vec<LssIdentity> = ids
            .into_iter()
            .map(|(v, p, r, s)| LssIdentity::from_parts([v, p, r, s]))
            .collect();
        let mut slaves: Vec<LssSlave> = ids
            .iter()
            .zip(&configured)
            .map(|(id, &c)| LssSlave::new(*id, if c { 9 } else { UNCONFIGURED_NODE_ID }))
            .collect();
        let expect: Vec<LssIdentity> = ids
            .iter()
            .zip(&configured)
            .filter(|(_, c)| !**c)
            .map(|(id, _)| *id)
            .collect();
        let mut m = LssMaster::new();
        let (present, _) = run(&mut m, &mut slaves, LssCommand::IdentifyNonConfigured);
        prop_assert_eq!(present, Ok(LssOutcome::Present(!expect.is_empty())));
        let (r, _) = run(&mut m, &mut slaves, fastscan_all());
        prop_assert_eq!(r, Ok(LssOutcome::Found(expect.clone())));
        // Each found slave can be selected by its identity.
        for id in &expect {
            let _ = run(&mut m, &mut slaves, LssCommand::SwitchGlobal(LssMode::Waiting));
            let (r, _) = run(&mut m, &mut slaves, LssCommand::SwitchSelective(*id));
            prop_assert_eq!(r, Ok(LssOutcome::Confirmed));
            let (r, _) = run(&mut m, &mut slaves, LssCommand::Inquire(InquireWhat::Serial));
            prop_assert_eq!(r, Ok(LssOutcome::Value(id.serial)));
        }
    }
}
