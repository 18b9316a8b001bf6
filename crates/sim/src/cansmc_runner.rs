//! Runs simulated CANsmc slaves on a pair of virtual buses.
//!
//! [`spawn_cansmc_slaves`] serves every slave of one CANsmc bus pair from a
//! single task: it takes the frames of channel 0 (the command channel) in
//! batches, hands each to the slave it is addressed to (an MST, address
//! 0x3F, to all of them) and sends the replies on channel 1 at once, or
//! after the slave's injected reply delay; replies the slave's drop rate
//! drops are counted by the slave ([`crate::SimCansmcCounters`]). One task rather
//! than one per slave, because every slave would otherwise wake on every
//! frame: a 61-slave bus carries 62 frames per cycle on channel 0.
//!
//! Time is `tokio::time::Instant` since the task started (tests may pause
//! the clock); a batch of frames gets the time it was taken from the port.
//! Injected reply delays wait on a tokio timer, whose resolution is 1 ms:
//! a delay is rounded up to the next millisecond tick (so 500 µs waits
//! up to 1 ms).
//!
//! Each slave lives in a [`CansmcSlaveHandle`] (an `Arc<Mutex<…>>`) shared
//! with the application, to read the state or inject faults while the
//! runner serves the bus:
//!
//! ```no_run
//! # async fn demo() {
//! use cangate_can::{VirtualBus, VirtualBusConfig};
//! use cangate_cansmc::SmcAddress;
//! use cangate_sim::{CansmcSlaveHandle, SimCansmcSlave, SimCansmcSlaveOptions, spawn_cansmc_slaves};
//! use tokio_util::sync::CancellationToken;
//!
//! let ch0 = VirtualBus::new("smc0", VirtualBusConfig::default());
//! let ch1 = VirtualBus::new("smc1", VirtualBusConfig::default());
//! let slaves: Vec<CansmcSlaveHandle> = (1..=4)
//!     .map(|a| {
//!         let options = SimCansmcSlaveOptions::new(SmcAddress::new(a).unwrap());
//!         CansmcSlaveHandle::new(SimCansmcSlave::new(options))
//!     })
//!     .collect();
//! let cancel = CancellationToken::new();
//! let task = spawn_cansmc_slaves(ch0.connect(false), ch1.connect(false), slaves.clone(), cancel.clone());
//! slaves[0].with(|s| s.inject_fault());
//! cancel.cancel();
//! task.await.unwrap();
//! # }
//! ```

use std::collections::BTreeMap;
use std::future::pending;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use cangate_can::{Frame, PortEvent, Timestamp, VirtualPort, VirtualSender};
use cangate_cansmc::telegram::{BROADCAST, SmcAddress};
use tokio::task::JoinHandle;
use tokio::time::{Instant, sleep_until};
use tokio_util::sync::CancellationToken;

use crate::cansmc_slave::SimCansmcSlave;

/// Frames taken from channel 0 per batch.
const BATCH: usize = 128;

/// Number of 6-bit addresses.
const ADDRESSES: usize = 64;

struct Shared {
    slave: SimCansmcSlave,
    /// Replies channel 1 refused (bus-off, interface down).
    send_errors: u64,
}

/// Shared access to a slave run by [`spawn_cansmc_slaves`]. Cheap to clone;
/// all clones are the same slave.
#[derive(Clone)]
pub struct CansmcSlaveHandle {
    shared: Arc<Mutex<Shared>>,
    /// Cached: the runner routes by it without taking the lock.
    address: SmcAddress,
}

impl std::fmt::Debug for CansmcSlaveHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CansmcSlaveHandle")
            .field("address", &self.address)
            .finish_non_exhaustive()
    }
}

impl CansmcSlaveHandle {
    /// Wraps a slave.
    pub fn new(slave: SimCansmcSlave) -> Self {
        CansmcSlaveHandle {
            address: slave.address(),
            shared: Arc::new(Mutex::new(Shared {
                slave,
                send_errors: 0,
            })),
        }
    }

    /// The slave's address.
    pub fn address(&self) -> SmcAddress {
        self.address
    }

    /// Runs `f` on the slave (under the lock; keep it short and never await
    /// inside), e.g. `handle.with(|s| s.inject_fault())`.
    pub fn with<R>(&self, f: impl FnOnce(&mut SimCansmcSlave) -> R) -> R {
        f(&mut self.lock().slave)
    }

    /// Replies channel 1 refused so far.
    pub fn send_errors(&self) -> u64 {
        self.lock().send_errors
    }

    fn lock(&self) -> MutexGuard<'_, Shared> {
        // A panic under the lock (in a test closure) must not take the bus
        // down with it: the slave's state is still consistent.
        self.shared.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// Serves `slaves` on the CANsmc bus pair (`channel0` receives the master's
/// telegrams, `channel1` sends the answers) from one task until `cancel`
/// fires; see the [module documentation](self).
///
/// Nothing is read from `channel1`: the port is detached from its bus at
/// once (only its sender is kept), so it does not queue the other slaves'
/// telegrams. Two slaves with the same address both answer, as on a real
/// bus.
pub fn spawn_cansmc_slaves(
    channel0: VirtualPort,
    channel1: VirtualPort,
    slaves: Vec<CansmcSlaveHandle>,
    cancel: CancellationToken,
) -> JoinHandle<()> {
    let sender = channel1.sender();
    drop(channel1);
    tokio::spawn(run(channel0, sender, slaves, cancel))
}

/// When a frame stamped `ts` reached the slave, on the runner's clock: the
/// bus timestamp (a bit-timed bus stamps the modelled end of frame), so the
/// slave's time base (MST) and its cycle end (`T_end_s`) do not include the
/// host's scheduling delay. Unstamped frames, and stamps more than 50 ms
/// from now (a wall-clock step), use `now`. Used on bit-timed buses only
/// (see `run`).
fn frame_time(ts: Timestamp, origin_wall: i128, now: Duration) -> Duration {
    if ts.as_nanos() == 0 {
        return now;
    }
    let at = i128::from(ts.as_nanos()) - origin_wall;
    let now_ns = now.as_nanos() as i128;
    if at > now_ns || at < now_ns - 50_000_000 {
        return now;
    }
    Duration::from_nanos(at as u64)
}

async fn run(
    mut channel0: VirtualPort,
    channel1: VirtualSender,
    slaves: Vec<CansmcSlaveHandle>,
    cancel: CancellationToken,
) {
    let origin = Instant::now();
    // On a bit-timed bus a frame's timestamp is the modelled end of its
    // transmission: the slave's time base. Elsewhere (instant delivery,
    // and tests on a paused tokio clock, which runs apart from the wall
    // clock of the stamps) the moment of processing is used.
    let timed = channel0.bus().config().bit_timing.is_some();
    let mut routes: Vec<Vec<usize>> = vec![Vec::new(); ADDRESSES];
    for (i, slave) in slaves.iter().enumerate() {
        routes[usize::from(slave.address.get())].push(i);
    }
    routes[usize::from(BROADCAST)] = (0..slaves.len()).collect();

    // Delayed replies by due time; the sequence number keeps equal times in
    // arrival order.
    let mut delayed: BTreeMap<(Instant, u64), (usize, Frame)> = BTreeMap::new();
    let mut sequence = 0u64;
    let mut events = Vec::with_capacity(BATCH);
    // Replies to send: slave, frame, and the model time it became ready
    // (see `send`).
    let mut out: Vec<(usize, Frame, Option<Timestamp>)> = Vec::new();
    loop {
        let next_due = delayed.first_key_value().map(|(&(due, _), _)| due);
        let timer = async {
            match next_due {
                Some(due) => sleep_until(due).await,
                None => pending::<()>().await,
            }
        };
        tokio::select! {
            biased;
            _ = cancel.cancelled() => break,
            _ = channel0.recv_many(&mut events, BATCH) => {
                let arrival = Instant::now();
                let now = arrival.duration_since(origin);
                let origin_wall =
                    i128::from(Timestamp::now().as_nanos()) - now.as_nanos() as i128;
                for event in events.drain(..) {
                    let PortEvent::Frame { frame, own: false } = event else {
                        continue;
                    };
                    let now = if timed {
                        frame_time(frame.timestamp(), origin_wall, now)
                    } else {
                        now
                    };
                    // The identifier's address field; a frame that does not
                    // decode still goes to the slave it names, which counts it.
                    let address = (frame.raw_id() & 0x3F) as usize;
                    for &i in &routes[address] {
                        let reply = slaves[i].lock().slave.on_frame_with_faults(&frame, now);
                        let Some(reply) = reply else { continue };
                        if reply.delay.is_zero() {
                            // On a bit-timed bus the answer is ready when
                            // the telegram it answers ended, on the model's
                            // clock: how late this task ran does not move
                            // it (a loaded host must not make the
                            // simulated slaves miss their cycle).
                            let ready = (timed && frame.timestamp().as_nanos() != 0)
                                .then(|| frame.timestamp());
                            out.push((i, reply.frame, ready));
                        } else {
                            delayed.insert((arrival + reply.delay, sequence), (i, reply.frame));
                            sequence += 1;
                        }
                    }
                }
            }
            _ = timer => {}
        }
        let now = Instant::now();
        while let Some(entry) = delayed.first_entry() {
            if entry.key().0 > now {
                break;
            }
            let (i, frame) = entry.remove();
            out.push((i, frame, None));
        }
        send(&channel1, &slaves, &mut out);
    }
}

/// Sends the replies. Those with a ready time (answers on a bit-timed bus)
/// are queued at that model time, each on its own, so that a reply is
/// stamped as if sent the moment its telegram ended however late this task
/// ran (they share one transmit queue, in the order they became ready).
/// The others go in one batch, queued now.
fn send(
    channel1: &VirtualSender,
    slaves: &[CansmcSlaveHandle],
    out: &mut Vec<(usize, Frame, Option<Timestamp>)>,
) {
    if out.is_empty() {
        return;
    }
    let mut now_batch: Vec<(usize, Frame)> = Vec::new();
    for (i, frame, ready) in out.drain(..) {
        match ready {
            Some(at) => {
                if channel1.send_batch_ready_at(&[frame], at).is_err() {
                    slaves[i].lock().send_errors += 1;
                }
            }
            None => now_batch.push((i, frame)),
        }
    }
    if now_batch.is_empty() {
        return;
    }
    let frames: Vec<Frame> = now_batch.iter().map(|(_, frame)| *frame).collect();
    if channel1.send_batch(&frames).is_err() {
        // All or nothing: every slave of the batch lost its reply.
        for (i, _) in &now_batch {
            slaves[*i].lock().send_errors += 1;
        }
    }
}

#[cfg(test)]
mod tests {

    use cangate_can::{BitTiming, VirtualBus, VirtualBusConfig};
    use cangate_cansmc::telegram::{
        Channel, Command, ControlWord, CycleCounter, Feedback, StatusWord, Telegram,
    };
    use tokio::time::timeout;

    use super::*;
    use crate::cansmc_slave::SimCansmcSlaveOptions;

    fn addr(a: u8) -> SmcAddress {
        SmcAddress::new(a).unwrap()
    }

    fn slave(a: u8) -> CansmcSlaveHandle {
        CansmcSlaveHandle::new(SimCansmcSlave::new(SimCansmcSlaveOptions {
            device_type: 0x0402,
            firmware_version: 0x0107,
            ..SimCansmcSlaveOptions::new(addr(a))
        }))
    }

    fn mct(to: u8, cycle_time_us: u32, slave_count: u8) -> Frame {
        Telegram::Master {
            to: addr(to),
            control: ControlWord::default(),
            command: Command::Connect {
                cycle_time_us,
                slave_count,
            },
        }
        .encode()
    }

    fn mdt(to: u8, counter: u8, command: Command) -> Frame {
        Telegram::Master {
            to: addr(to),
            control: ControlWord {
                enable: true,
                counter: CycleCounter::new(counter),
                ..ControlWord::default()
            },
            command,
        }
        .encode()
    }

    async fn next_frame(port: &mut VirtualPort) -> Frame {
        let wait = async {
            loop {
                if let PortEvent::Frame { frame, .. } = port.recv().await {
                    return frame;
                }
            }
        };
        timeout(Duration::from_secs(5), wait)
            .await
            .expect("no frame on channel 1")
    }

    fn decode(frame: &Frame) -> (SmcAddress, StatusWord, Feedback) {
        match Telegram::decode(frame, Channel::Status).unwrap() {
            Telegram::Slave {
                from,
                status,
                feedback,
            } => (from, status, feedback),
            other => panic!("not a slave telegram: {other:?}"),
        }
    }

    #[tokio::test(start_paused = true)]
    async fn slaves_answer_on_channel_1() {
        let ch0 = VirtualBus::new("smc-run-0", VirtualBusConfig::default());
        let ch1 = VirtualBus::new("smc-run-1", VirtualBusConfig::default());
        let master0 = ch0.connect(false);
        let mut master1 = ch1.connect(false);
        let slaves = vec![slave(1), slave(2), slave(3)];
        let cancel = CancellationToken::new();
        let task = spawn_cansmc_slaves(
            ch0.connect(false),
            ch1.connect(false),
            slaves.clone(),
            cancel.clone(),
        );

        // MCT to slave 2: DCT id 0x042, ready, device 0x0402, firmware 0x0107.
        master0.send(&mct(2, 4000, 3)).unwrap();
        let dct = next_frame(&mut master1).await;
        assert_eq!(dct.raw_id(), 0x042);
        assert_eq!(dct.data(), [0x01, 0x00, 0x02, 0x04, 0x07, 0x01, 0x00, 0x00]);
        master0.send(&mct(1, 4000, 3)).unwrap();
        assert_eq!(next_frame(&mut master1).await.raw_id(), 0x041);

        // One cycle: MST then MDTs to 1 and 2 (slave 3 was never connected
        // and ignores its MDT).
        master0.send(&Telegram::Mst.encode()).unwrap();
        master0
            .send_batch(&[
                mdt(1, 1, Command::Position(0)),
                mdt(2, 1, Command::Encoder),
                mdt(3, 1, Command::Position(0)),
            ])
            .unwrap();
        let dt = next_frame(&mut master1).await;
        assert_eq!(dt.raw_id(), 0x081);
        assert_eq!(dt.data(), [0x01, 0x10, 0, 0, 0, 0, 0, 0]);
        let dt = next_frame(&mut master1).await;
        assert_eq!(dt.raw_id(), 0x1C2);
        assert_eq!(dt.data(), [0x01, 0x10, 0, 0, 0, 0, 0, 0]);

        // Next cycle: the enable bit took effect at the MST.
        master0.send(&Telegram::Mst.encode()).unwrap();
        master0.send(&mdt(1, 2, Command::Position(0))).unwrap();
        let (from, status, feedback) = decode(&next_frame(&mut master1).await);
        assert_eq!(from, addr(1));
        assert!(status.enabled && status.ready);
        assert_eq!(status.counter_echo, CycleCounter::new(2));
        assert_eq!(feedback, Feedback::Position(0));
        assert!(slaves[0].with(|s| s.enabled()));

        // Injected delay: the DT leaves 500 µs after its MDT.
        slaves[1].with(|s| s.set_reply_delay(Duration::from_micros(500)));
        let sent = Instant::now();
        master0.send(&mdt(2, 2, Command::Encoder)).unwrap();
        let dt = next_frame(&mut master1).await;
        assert_eq!(dt.raw_id(), 0x1C2);
        // Tokio's timers tick in whole milliseconds: 500 µs becomes 1 ms.
        let waited = sent.elapsed();
        assert!(
            (Duration::from_micros(500)..=Duration::from_millis(1)).contains(&waited),
            "{waited:?}"
        );

        // Dropped replies are counted, nothing is sent.
        slaves[0].with(|s| s.set_drop_rate(1.0));
        master0.send(&mdt(1, 2, Command::Position(0))).unwrap();
        slaves[1].with(|s| s.set_reply_delay(Duration::ZERO));
        master0.send(&mdt(2, 2, Command::Encoder)).unwrap();
        assert_eq!(next_frame(&mut master1).await.raw_id(), 0x1C2);
        assert_eq!(slaves[0].with(|s| s.counters().replies_dropped), 1);

        // An MDT after the slave's cycle end (MST + 4 ms) is not answered.
        slaves[0].with(|s| s.set_drop_rate(0.0));
        tokio::time::sleep(Duration::from_millis(5)).await;
        master0.send(&mdt(1, 2, Command::Position(0))).unwrap();
        master0.send(&mdt(2, 2, Command::Encoder)).unwrap();
        assert!(
            timeout(Duration::from_millis(50), next_frame(&mut master1))
                .await
                .is_err()
        );
        assert_eq!(slaves[0].with(|s| s.stats().late), 1);
        assert_eq!(slaves[1].with(|s| s.stats().late), 1);
        // Two MSTs and one MDT before any MCT.
        assert_eq!(slaves[2].with(|s| s.stats().unconnected), 3);
        assert!(slaves.iter().all(|s| s.send_errors() == 0));

        cancel.cancel();
        task.await.unwrap();
    }

    /// 20 slaves on a 1 Mbit/s bit-timed pair (the paper's 4 ms row): every
    /// MDT of a cycle is answered, DTs serialised on channel 1. Real time
    /// (the bus scheduler runs on the wall clock); the MCT's cycle time is
    /// generous so that a slow debug build on a busy machine does not make
    /// the slaves' `T_end_s` suppress answers.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn twenty_slaves_answer_one_cycle_on_a_bit_timed_bus() {
        const N: u8 = 20;
        let config = VirtualBusConfig {
            bit_timing: Some(BitTiming::new(1_000_000)),
            ..VirtualBusConfig::default()
        };
        let ch0 = VirtualBus::new("smc-timed-0", config.clone());
        let ch1 = VirtualBus::new("smc-timed-1", config);
        let master0 = ch0.connect(false);
        let mut master1 = ch1.connect(false);
        let slaves: Vec<CansmcSlaveHandle> = (1..=N).map(slave).collect();
        let cancel = CancellationToken::new();
        let task = spawn_cansmc_slaves(
            ch0.connect(false),
            ch1.connect(false),
            slaves.clone(),
            cancel.clone(),
        );

        let mcts: Vec<Frame> = (1..=N).map(|a| mct(a, 200_000, N)).collect();
        master0.send_batch(&mcts).unwrap();
        let mut connected = Vec::new();
        for _ in 0..N {
            let (from, status, feedback) = decode(&next_frame(&mut master1).await);
            assert!(status.ready);
            assert!(matches!(feedback, Feedback::Connect { .. }));
            connected.push(from.get());
        }
        connected.sort_unstable();
        assert_eq!(connected, (1..=N).collect::<Vec<_>>());

        for counter in 1..=3u8 {
            master0.send(&Telegram::Mst.encode()).unwrap();
            let mdts: Vec<Frame> = (1..=N)
                .map(|a| mdt(a, counter, Command::Position(i32::from(a) * 10)))
                .collect();
            master0.send_batch(&mdts).unwrap();
            let mut answered = Vec::new();
            let mut stamps = Vec::new();
            for _ in 0..N {
                let frame = next_frame(&mut master1).await;
                stamps.push(frame.timestamp().as_nanos());
                let (from, status, feedback) = decode(&frame);
                assert_eq!(status.counter_echo, CycleCounter::new(counter));
                assert!(matches!(feedback, Feedback::Position(_)));
                answered.push(from.get());
            }
            // MDTs win arbitration in address order and each is answered at
            // once: the DTs come in address order, one frame time apart at
            // least (an 8-byte frame is over 100 bits).
            assert_eq!(answered, (1..=N).collect::<Vec<_>>(), "cycle {counter}");
            for pair in stamps.windows(2) {
                assert!(pair[1] - pair[0] >= 100_000, "{stamps:?}");
            }
        }
        // The position set-points of cycle 1 took effect at MST 2 and were
        // reached by MST 3.
        for (k, s) in slaves.iter().enumerate() {
            assert_eq!(s.with(|s| s.position()), (k as i32 + 1) * 10);
            assert_eq!(s.with(|s| s.stats().replies), 4);
            assert_eq!(s.send_errors(), 0);
        }

        cancel.cancel();
        task.await.unwrap();
    }
}
