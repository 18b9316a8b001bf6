//! Feasibility arithmetic against the spec and the paper's table.

use cangate_cansmc::{
    CycleConfig, FeasibilityError, Infeasibility, frame_bits_worst_case, max_slaves,
};

const MBIT: u32 = 1_000_000;

/// The paper's published table at 1 Mbit/s: (cycle µs, maximum slaves).
const PAPER: [(u32, u32); 4] = [(2_000, 10), (4_000, 20), (8_000, 40), (16_000, 61)];

#[test]
fn frame_lengths_match_spec() {
    assert_eq!(frame_bits_worst_case(8), 135);
    assert_eq!(frame_bits_worst_case(0), 55);
}

#[test]
fn report_arithmetic() {
    let r = CycleConfig::new(MBIT, 10, 2_000).check().unwrap();
    assert_eq!(r.mst_ns, 55_000);
    assert_eq!(r.telegram_ns, 135_000);
    assert_eq!(r.t_int_end_ns, 155_000);
    assert_eq!(r.mdts_end_ns, 155_000 + 10 * 135_000);
    // (10 + 1) DTs after T_int_end, plus 20 µs response latency.
    assert_eq!(r.last_dt_end_ns, 155_000 + 11 * 135_000 + 20_000);
    assert_eq!(r.required_ns, r.last_dt_end_ns + 100_000);
    assert!(r.is_feasible());
    assert_eq!(r.slack_ns(), 2_000_000 - 1_760_000);
    let text = r.to_string();
    assert!(text.contains("135 bits"), "{text}");
    assert!(text.contains("feasible"), "{text}");
}

#[test]
fn paper_table_rows_are_feasible() {
    for (cycle, slaves) in PAPER {
        let r = CycleConfig::new(MBIT, slaves, cycle).check().unwrap();
        assert!(r.is_feasible(), "{r}");
    }
}

#[test]
fn computed_maximum_is_tight() {
    let expected = [11, 26, 56, 61];
    for ((cycle, paper), want) in PAPER.into_iter().zip(expected) {
        let max = max_slaves(CycleConfig::new(MBIT, 0, cycle)).unwrap();
        assert_eq!(max, want, "cycle {cycle} µs");
        assert!(max >= paper);
        assert!(
            CycleConfig::new(MBIT, max, cycle)
                .check()
                .unwrap()
                .is_feasible()
        );
        let over = CycleConfig::new(MBIT, max + 1, cycle).check().unwrap();
        assert!(!over.is_feasible(), "{over}");
        let why = if max == 61 {
            Infeasibility::TooManySlaves
        } else {
            Infeasibility::BusTime
        };
        assert!(over.problems.contains(&why), "{over}");
        assert!(over.to_string().contains("NOT feasible"));
    }
}

#[test]
fn lower_bitrate_and_parameters() {
    // 500 kbit/s doubles every frame time.
    let r = CycleConfig::new(500_000, 1, 2_000).check().unwrap();
    assert_eq!(r.telegram_ns, 270_000);
    // No T_int / guard / latency: pure bus bound at 2 ms is (2000-55)/135 - 1 = 13.
    let bare = CycleConfig {
        t_int_us: 0,
        response_us: 0,
        guard_us: 0,
        ..CycleConfig::new(MBIT, 0, 2_000)
    };
    assert_eq!(max_slaves(bare).unwrap(), 13);
    // A cycle too short for any slave.
    assert_eq!(max_slaves(CycleConfig::new(MBIT, 0, 300)).unwrap(), 0);
}

#[test]
fn invalid_inputs() {
    assert_eq!(
        CycleConfig::new(0, 1, 2_000).check(),
        Err(FeasibilityError::ZeroBitrate)
    );
    assert_eq!(
        max_slaves(CycleConfig::new(MBIT, 1, 0)),
        Err(FeasibilityError::ZeroCycleTime)
    );
}
