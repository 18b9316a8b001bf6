//! The cyclic set-points of a bus's CSP axes, sent by the CANopen master's
//! SYNC thread with every SYNC.
//!
//! The axis task publishes each cyclic axis's [`CyclicPlan`] here whenever
//! it changes (a move, a stop, the drive enabled or lost). At every SYNC
//! the SYNC thread samples each plan, patches the target position into the
//! axis's set-point RPDO and sends it in the SYNC's batch, then leaves the
//! sample for the axis task, which hands it to the axis
//! ([`cangate_axis::cia402::Cia402Axis::on_cyclic_sample`]) at its next
//! wake-up (the drives' TPDOs answering that SYNC).
//!
//! Why: computed by the axis task, each set-point needed that task woken by
//! every SYNC, a thread hand-over per period ("Wake-ups cost more than
//! frames" in docs/design.md). The set-point
//! now also leaves in the same batch as its SYNC, whatever the load on the
//! gateway's bus thread.
//!
//! Set-points are sampled on the SYNC's nominal grid (k·T, not when the
//! thread got to send it), and periods the thread skipped hold each plan
//! back ([`CyclicPlan::hold_back`]): the plan advances one period per SYNC
//! actually sent, so a late or stalled SYNC never becomes a double step.
//!
//! Only the RPDO that maps the target position (0x607A) is sent here; the
//! other RPDOs (the controlword) still go out from the axis task the moment
//! they change. Where a custom mapping puts the controlword into the
//! target-position RPDO, a controlword change rides with the next SYNC.

use crate::canopen::sync_thread::{SyncRider, SyncTick};
use cangate_axis::cia402::{CyclicPlan, CyclicSample};
use cangate_can::{CanId, Frame};
use cangate_canopen::cia402::objects::TARGET_POSITION;
use cangate_canopen::pdo::PdoConfig;
use std::sync::Mutex;
use std::time::Instant;

/// Where the target position sits in an RPDO.
#[derive(Debug, Clone)]
pub struct SetpointLayout {
    /// The RPDO that maps the target position.
    pub rpdo: PdoConfig,
    /// Byte offset of the 32-bit target position in its payload.
    pub offset: usize,
}

impl SetpointLayout {
    /// The layout of the first RPDO in `rpdos` that maps the target
    /// position as 32 bits (PDO mappings here are byte-aligned).
    pub fn find(rpdos: &[PdoConfig]) -> Option<SetpointLayout> {
        for p in rpdos {
            let mut offset = 0;
            for m in &p.mapping {
                if m.addr == TARGET_POSITION && m.bits == 32 {
                    return Some(SetpointLayout {
                        rpdo: p.clone(),
                        offset,
                    });
                }
                offset += usize::from(m.bits) / 8;
            }
        }
        None
    }

    /// `payload` with the target position's bytes cleared: what a change
    /// of the RPDO's other values is compared on.
    pub fn masked(&self, payload: &[u8]) -> Vec<u8> {
        let mut p = payload.to_vec();
        if let Some(target) = p.get_mut(self.offset..self.offset + 4) {
            target.fill(0);
        }
        p
    }
}

/// One axis's entry.
#[derive(Debug, Default)]
struct Entry {
    /// The published plan, as sampled since; `None`: nothing is sent.
    plan: Option<CyclicPlan>,
    /// The set-point RPDO: COB-ID, payload (the target position is patched
    /// in at each SYNC), offset of the target position.
    rpdo: Option<(u16, Vec<u8>, usize)>,
    /// Samples of `plan` not yet taken by the axis task: the latest, after
    /// every sample that ended a trajectory or started a dead-man stop
    /// (the axis must see those even when it wakes only every few SYNCs).
    samples: Vec<CyclicSample>,
    /// The axis's name, for a veto's reason.
    name: String,
}

/// The table shared by one bus's axis task and its master's SYNC thread,
/// indexed by the task's axis index.
#[derive(Debug)]
pub struct CyclicSetpoints {
    /// The axis task's clock: samples are taken in its time.
    origin: Instant,
    entries: Mutex<Vec<Entry>>,
}

impl CyclicSetpoints {
    /// A table for the named axes, all without a plan, on the clock that
    /// starts at `origin`.
    pub fn new(origin: Instant, names: impl IntoIterator<Item = String>) -> CyclicSetpoints {
        CyclicSetpoints {
            origin,
            entries: Mutex::new(
                names
                    .into_iter()
                    .map(|name| Entry {
                        name,
                        ..Entry::default()
                    })
                    .collect(),
            ),
        }
    }

    /// Replaces the plans of several axes at once, so that a multi-axis
    /// command starts in one SYNC: (axis, plan or `None` to stop sending,
    /// COB-ID and current payload of its set-point RPDO, target offset).
    /// Drops the samples of the replaced plans. A plan that is the one
    /// sampled here as published earlier (the axis took up a sample's
    /// start) keeps the copy sampled here, which may have been held back
    /// since.
    pub fn publish(
        &self,
        plans: impl IntoIterator<Item = (usize, Option<CyclicPlan>, u16, Vec<u8>, usize)>,
    ) {
        let mut entries = self.entries.lock().expect("set-point table lock");
        for (i, plan, cob, payload, offset) in plans {
            let Some(e) = entries.get_mut(i) else {
                continue;
            };
            e.rpdo = plan.is_some().then_some((cob, payload, offset));
            if let (Some(old), Some(new)) = (&e.plan, &plan)
                && old.same_motion(new)
            {
                continue;
            }
            e.plan = plan;
            e.samples.clear();
        }
    }

    /// The set-point RPDO's other values changed (a custom mapping with
    /// the controlword): the next SYNC carries `payload`.
    pub fn set_payload(&self, i: usize, payload: Vec<u8>) {
        let mut entries = self.entries.lock().expect("set-point table lock");
        if let Some((_, p, _)) = entries.get_mut(i).and_then(|e| e.rpdo.as_mut()) {
            *p = payload;
        }
    }

    /// Moves the samples taken since the last call into `out`.
    pub fn take_samples(&self, out: &mut Vec<(usize, CyclicSample)>) {
        let mut entries = self.entries.lock().expect("set-point table lock");
        for (i, e) in entries.iter_mut().enumerate() {
            out.extend(e.samples.drain(..).map(|s| (i, s)));
        }
    }
}

impl SyncRider for CyclicSetpoints {
    fn sync_change_veto(&self) -> Option<String> {
        // Every enabled cyclic axis, moving or not: its drive interpolates
        // the set-points of each SYNC over the period it was enabled with
        // and (on most drives) faults when the SYNC stops or its period
        // changes under it.
        let entries = self.entries.lock().expect("set-point table lock");
        let enabled: Vec<&str> = entries
            .iter()
            .filter(|e| e.plan.is_some())
            .map(|e| e.name.as_str())
            .collect();
        let moving = entries
            .iter()
            .any(|e| e.plan.as_ref().is_some_and(CyclicPlan::is_moving));
        (!enabled.is_empty()).then(|| {
            format!(
                "cyclic axis {} is {} on this SYNC; {} it first (its drive takes a set-point \
                 with every SYNC)",
                enabled.join(", "),
                if moving { "moving" } else { "enabled" },
                if moving {
                    "stop and disable"
                } else {
                    "disable"
                },
            )
        })
    }

    fn on_sync(&self, tick: SyncTick, frames: &mut Vec<Frame>) {
        let t = tick.at.saturating_duration_since(self.origin);
        let mut entries = self.entries.lock().expect("set-point table lock");
        for e in entries.iter_mut() {
            let (Some(plan), Some((cob, payload, offset))) = (&mut e.plan, &mut e.rpdo) else {
                continue;
            };
            plan.hold_back(tick.missed);
            let sample = plan.sample(t);
            if let Some(target) = payload.get_mut(*offset..*offset + 4) {
                target.copy_from_slice(&sample.counts.to_le_bytes());
            }
            match Frame::new(CanId::Standard(*cob), payload) {
                Ok(f) => frames.push(f),
                Err(e) => tracing::error!(cob_id = *cob, error = %e, "set-point RPDO not sent"),
            }
            // A plain sample replaces the previous plain one: only the
            // latest demand matters then.
            if e.samples.last().is_some_and(|s| !s.ends_a_motion()) {
                e.samples.pop();
            }
            e.samples.push(sample);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cangate_axis::process_data::{FeedbackTrigger, standard_pdos};
    use cangate_canopen::NodeId;

    #[test]
    fn the_standard_layout_puts_the_target_position_first_in_rpdo2() {
        let (rpdos, _) = standard_pdos(NodeId::new(5).unwrap(), FeedbackTrigger::Sync);
        let l = SetpointLayout::find(&rpdos).expect("target position mapped");
        assert_eq!(l.rpdo.cob_id, 0x305);
        assert_eq!(l.offset, 0);
        assert_eq!(
            l.masked(&[1, 2, 3, 4, 5, 6, 7, 8]),
            vec![0, 0, 0, 0, 5, 6, 7, 8]
        );
        assert!(SetpointLayout::find(&rpdos[..1]).is_none());
    }

    #[test]
    fn each_sync_sends_the_sampled_set_point_and_leaves_the_sample() {
        let origin = Instant::now();
        let table = CyclicSetpoints::new(origin, ["a", "b", "c"].map(String::from));
        let units = cangate_axis::Units {
            counts_per_unit: 1000.0,
        };
        // Axis 1 holds 1.5 mm; its RPDO also maps a target velocity.
        table.publish([(
            1,
            Some(CyclicPlan::holding(1.5, units)),
            0x302,
            vec![0, 0, 0, 0, 9, 8, 7, 6],
            0,
        )]);
        let mut frames = vec![Frame::new(CanId::Standard(0x080), &[]).unwrap()];
        let at = origin + std::time::Duration::from_millis(3);
        table.on_sync(SyncTick::on_time(at), &mut frames);
        assert_eq!(frames.len(), 2, "the SYNC first, then the set-point");
        assert_eq!(frames[1].raw_id(), 0x302);
        assert_eq!(frames[1].data(), &[0xDC, 0x05, 0, 0, 9, 8, 7, 6]);
        let mut samples = Vec::new();
        table.take_samples(&mut samples);
        assert_eq!(samples.len(), 1);
        assert_eq!(samples[0].0, 1);
        assert_eq!(samples[0].1.counts, 1500);
        assert_eq!(samples[0].1.at, std::time::Duration::from_millis(3));
        // Taken once.
        samples.clear();
        table.take_samples(&mut samples);
        assert!(samples.is_empty());
        // A new payload rides with the next SYNC.
        table.set_payload(1, vec![0, 0, 0, 0, 1, 1, 1, 1]);
        let mut frames = Vec::new();
        table.on_sync(SyncTick::on_time(at), &mut frames);
        assert_eq!(frames[0].data(), &[0xDC, 0x05, 0, 0, 1, 1, 1, 1]);
        // Withdrawn: nothing is sent, and the pending sample of the old
        // plan is dropped.
        table.publish([(1, None, 0x302, Vec::new(), 0)]);
        let mut frames = Vec::new();
        table.on_sync(SyncTick::on_time(at), &mut frames);
        assert!(frames.is_empty());
        table.take_samples(&mut samples);
        assert!(samples.is_empty());
    }

    /// Issue 26, item 4: a SYNC thread that stalls (5.5 periods without a
    /// SYNC), or wakes late (0.4 periods), or finds the bus queue full
    /// (a SYNC built, not sent) never sends a set-point further than one
    /// period's travel at the maximum velocity from the previous one sent:
    /// the plan is sampled on the SYNC grid and held back by the periods
    /// without a SYNC. The move still ends at its target.
    /// An enabled cyclic-position axis (1000 counts per unit) at 0,
    /// commanded to move to `target` at its maximum velocity and
    /// acceleration, at time 0.
    fn moving_cyclic_axis(
        target: f64,
    ) -> (
        cangate_axis::cia402::Cia402Axis,
        cangate_axis::cia402::Cia402Config,
    ) {
        use cangate_axis::cia402::{Cia402Axis, Cia402Config, Feedback};
        use cangate_axis::{AxisCommand, PositionMode};
        use std::time::Duration;

        let cfg = Cia402Config::example(1000.0, PositionMode::Cyclic);
        let mut axis = Cia402Axis::new(cfg.clone());
        let mut out = Vec::new();
        let enabled = Feedback {
            statusword: Some(0x0237),
            position: Some(0),
            velocity: Some(0),
            mode_display: Some(8),
            following_error: None,
        };
        axis.on_feedback(enabled, Duration::ZERO, &mut out);
        axis.command(
            AxisCommand::Move {
                target,
                relative: false,
                velocity: Some(cfg.motion.max_velocity),
                acceleration: Some(cfg.motion.max_acceleration),
            },
            Duration::ZERO,
            &mut out,
        )
        .expect("move");
        (axis, cfg)
    }

    #[test]
    fn a_stalled_sync_thread_never_sends_a_double_step() {
        use crate::canopen::sync_thread::due_sync;
        use cangate_canopen::sync::SyncProducer;
        use std::time::Duration;

        let period = Duration::from_millis(1);
        let (mut axis, cfg) = moving_cyclic_axis(300.0);
        let max_step = cfg.motion.max_velocity * period.as_secs_f64() * 1000.0 + 1.0;
        let mut out = Vec::new();
        let origin = Instant::now();
        let table = CyclicSetpoints::new(origin, ["x".to_string()]);
        let mut published = None;
        let mut producer = SyncProducer::new(period, 0).expect("period");
        producer.start(Duration::ZERO);
        let mut sent: Vec<i32> = Vec::new();
        let mut samples = Vec::new();
        let mut unsent = 0;
        let mut now = Duration::ZERO;
        for k in 1..=3000u32 {
            now = period * k;
            match k % 200 {
                // Stalled for 5.5 periods.
                100..=104 => continue,
                105 => now += period / 2,
                // Late by 0.4 periods.
                150 => now += period * 2 / 5,
                _ => {}
            }
            // The axis task: samples back to the axis, its plan published
            // when it changed.
            table.take_samples(&mut samples);
            for (_, s) in samples.drain(..) {
                axis.on_cyclic_sample(&s, now, &mut out);
            }
            let plan = axis.cyclic_plan();
            if plan != published {
                table.publish([(0, plan.clone(), 0x301, vec![0; 8], 0)]);
                published = plan;
            }
            // The SYNC thread.
            let Some((sync, due, missed)) = due_sync(&mut producer, now, unsent) else {
                continue;
            };
            let mut frames = vec![sync];
            table.on_sync(
                SyncTick {
                    at: origin + due,
                    missed,
                },
                &mut frames,
            );
            if k % 200 == 170 {
                // The bus's queue was full: built, not sent.
                unsent += 1;
                continue;
            }
            unsent = 0;
            let counts = i32::from_le_bytes(frames[1].data()[..4].try_into().unwrap());
            if let Some(&last) = sent.last() {
                let step = f64::from(counts - last).abs();
                assert!(
                    step <= max_step,
                    "SYNC {k} at {now:?}: a step of {step} counts (at most {max_step})"
                );
            }
            sent.push(counts);
        }
        assert_eq!(sent.last(), Some(&300_000), "the move ends at its target");
        assert!(now > Duration::from_secs(2));
    }

    /// An axis task that wakes only every few SYNCs (a loaded host) still
    /// hears of the sample that finished the trajectory, although later
    /// SYNCs sampled the plan again: the move completes with the SYNC that
    /// ends it, not at the axis's deadline.
    #[test]
    fn a_slow_axis_task_still_sees_the_sample_that_ends_the_move() {
        use std::time::Duration;

        let period = Duration::from_millis(1);
        for wake_every in 2..=5u32 {
            for phase in 0..wake_every {
                let (mut axis, _) = moving_cyclic_axis(10.0);
                let mut out = Vec::new();
                let origin = Instant::now();
                let table = CyclicSetpoints::new(origin, ["x".to_string()]);
                let plan = axis.cyclic_plan();
                table.publish([(0, plan.clone(), 0x301, vec![0; 8], 0)]);
                let mut published = plan;
                let mut samples = Vec::new();
                let mut ended_at = None;
                for k in 1..=5000u32 {
                    let now = period * k;
                    if k % wake_every == phase {
                        table.take_samples(&mut samples);
                        for (_, s) in samples.drain(..) {
                            axis.on_cyclic_sample(&s, now, &mut out);
                        }
                        let plan = axis.cyclic_plan();
                        if plan != published {
                            table.publish([(0, plan.clone(), 0x301, vec![0; 8], 0)]);
                            published = plan;
                        }
                        if let Some(end) = ended_at
                            && k > end + wake_every
                        {
                            assert!(
                                !axis.cyclic_plan().is_some_and(|p| p.is_moving()),
                                "waking every {wake_every} SYNCs (phase {phase}): the trajectory \
                                 ended at SYNC {end}, the axis still moves at {k}"
                            );
                            break;
                        }
                    }
                    let mut frames = Vec::new();
                    table.on_sync(SyncTick::on_time(origin + now), &mut frames);
                    let counts = i32::from_le_bytes(frames[0].data()[..4].try_into().unwrap());
                    if counts == 10_000 && ended_at.is_none() {
                        ended_at = Some(k);
                    }
                }
                assert!(ended_at.is_some(), "the move reached its target");
            }
        }
    }

    #[test]
    fn a_sync_without_plans_adds_nothing_and_leaves_no_sample() {
        let table = CyclicSetpoints::new(Instant::now(), ["a", "b"].map(String::from));
        let mut frames = Vec::new();
        table.on_sync(SyncTick::on_time(Instant::now()), &mut frames);
        assert!(frames.is_empty());
        let mut samples = Vec::new();
        table.take_samples(&mut samples);
        assert!(samples.is_empty());
    }
}
