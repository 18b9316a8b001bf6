//! Runs simulated devices on the in-process virtual bus.
//!
//! [`spawn_device`] attaches any [`Device`] to a [`VirtualPort`]: it starts
//! the device, feeds it every frame the port receives, ticks it at its
//! [`Device::next_deadline`] and sends whatever it returns, until the
//! cancellation token fires. Time is measured from the moment the task
//! starts (`tokio::time`, so tests may pause the clock).
//!
//! The device lives in a [`DeviceHandle`] (an `Arc<Mutex<…>>`) shared with
//! the application, e.g. a drive model that updates the position while the
//! runner serves the bus:
//!
//! ```no_run
//! # async fn demo() {
//! use cangate_can::{VirtualBus, VirtualBusConfig};
//! use cangate_canopen::{NodeId, ObjectAddress, eds::{Eds, SIM_DRIVE_EDS}, value::Value};
//! use cangate_sim::{DeviceHandle, SimNode, SimNodeOptions, spawn_device};
//! use tokio_util::sync::CancellationToken;
//!
//! let bus = VirtualBus::new("can0", VirtualBusConfig::default());
//! let eds = Eds::parse(SIM_DRIVE_EDS).unwrap();
//! let node = SimNode::new(&eds, NodeId::new(5).unwrap(), SimNodeOptions::default());
//! let handle = DeviceHandle::new(node);
//! let cancel = CancellationToken::new();
//! let task = spawn_device(bus.connect(false), handle.clone(), cancel.clone());
//! handle.with(|n| n.set(ObjectAddress::new(0x6064, 0), Value::Integer32(1000)).unwrap());
//! handle.send_with(|n| n.inject_emcy(0x2310, 0x03, [0; 5]));
//! cancel.cancel();
//! task.await.unwrap();
//! # }
//! ```

use std::future::pending;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use cangate_can::{
    ArrivalClock, BusHandle, BusItem, Direction, Frame, FrameSelector, PortEvent, Timestamp,
    VirtualPort,
};
use tokio::sync::Notify;
use tokio::task::JoinHandle;
use tokio::time::{Instant, sleep_until};
use tokio_util::sync::CancellationToken;

use crate::Device;
use crate::canopen_node::SimNode;

/// Frames taken from the port per batch.
const BATCH: usize = 64;

struct Shared<D> {
    device: D,
    /// Frames queued by the application for the runner to send.
    outbox: Vec<Frame>,
    /// Frames the bus refused (bus-off, interface down).
    send_errors: u64,
    /// A power cut in progress ([`DeviceHandle::power_cycle`]).
    power_cut: Option<PowerCut<D>>,
}

/// The device is off until `until` (set by the runner when it first sees
/// the cut), then `restart` makes it a freshly powered device.
struct PowerCut<D> {
    off_for: Duration,
    until: Option<Duration>,
    restart: Box<dyn FnOnce(&mut D) + Send>,
}

/// Shared access to a device run by [`spawn_device`]. Cheap to clone; all
/// clones are the same device.
///
/// Every access wakes the runner afterwards, so that changes which move the
/// device's next deadline (a TPDO event, a new heartbeat time) take effect
/// at once.
pub struct DeviceHandle<D> {
    shared: Arc<Mutex<Shared<D>>>,
    wake: Arc<Notify>,
}

impl<D> Clone for DeviceHandle<D> {
    fn clone(&self) -> Self {
        DeviceHandle {
            shared: self.shared.clone(),
            wake: self.wake.clone(),
        }
    }
}

impl<D> std::fmt::Debug for DeviceHandle<D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DeviceHandle").finish_non_exhaustive()
    }
}

impl<D: Device> DeviceHandle<D> {
    /// Wraps a device (not started yet: the runner starts it).
    pub fn new(device: D) -> Self {
        DeviceHandle {
            shared: Arc::new(Mutex::new(Shared {
                device,
                outbox: Vec::new(),
                send_errors: 0,
                power_cut: None,
            })),
            wake: Arc::new(Notify::new()),
        }
    }

    /// Runs `f` on the device (under the lock; keep it short and never
    /// await inside) and wakes the runner.
    pub fn with<R>(&self, f: impl FnOnce(&mut D) -> R) -> R {
        let r = f(&mut self.lock().device);
        self.wake.notify_one();
        r
    }

    /// Runs `f` on the device and has the runner send the frames it
    /// returns, e.g. `handle.send_with(|n| n.inject_emcy(0x2310, 3, [0; 5]))`.
    pub fn send_with<I: IntoIterator<Item = Frame>>(&self, f: impl FnOnce(&mut D) -> I) {
        {
            let mut s = self.lock();
            let frames: Vec<Frame> = f(&mut s.device).into_iter().collect();
            s.outbox.extend(frames);
        }
        self.wake.notify_one();
    }

    /// Cuts the device's power for `off`: it receives and sends nothing
    /// (frames the application queued are lost, as in a real outage), then
    /// `restart` turns it into a freshly powered device (e.g.
    /// [`crate::PowerOn::powered_on`]) and the runner starts it (a CANopen
    /// node boots up). A new cut during one replaces it.
    pub fn power_cycle(&self, off: Duration, restart: impl FnOnce(&mut D) + Send + 'static) {
        {
            let mut s = self.lock();
            s.outbox.clear();
            s.power_cut = Some(PowerCut {
                off_for: off,
                until: None,
                restart: Box::new(restart),
            });
        }
        self.wake.notify_one();
    }

    /// False while a power cut is in progress.
    pub fn is_powered(&self) -> bool {
        self.lock().power_cut.is_none()
    }

    /// Frames the bus refused so far.
    pub fn send_errors(&self) -> u64 {
        self.lock().send_errors
    }

    fn lock(&self) -> MutexGuard<'_, Shared<D>> {
        self.shared.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// Runs `device` on `port` until `cancel` fires; see the [module
/// documentation](self). The port should not echo its own frames (they are
/// ignored if it does).
pub fn spawn_device<D: Device + Send + 'static>(
    port: VirtualPort,
    device: DeviceHandle<D>,
    cancel: CancellationToken,
) -> JoinHandle<()> {
    tokio::spawn(run(port, device, cancel))
}

/// Runs `device` on any bus the gateway's bus layer owns (e.g. a SocketCAN
/// `vcan0` shared with a gateway in another process) until `cancel` fires:
/// the same loop as [`spawn_device`] over a [`BusHandle`] (it receives
/// every frame, ignores its own, and sends through the bus's queue). Power
/// cuts are not modelled here.
pub fn spawn_device_on_bus<D: Device + Send + 'static>(
    bus: BusHandle,
    device: DeviceHandle<D>,
    cancel: CancellationToken,
) -> JoinHandle<()> {
    tokio::spawn(async move {
        let mut sub = bus.subscribe(FrameSelector::default(), 4096);
        let origin = Instant::now();
        let started = device.lock().device.start(origin.elapsed());
        let _ = bus.send(started).await;
        let mut items = Vec::with_capacity(BATCH);
        let mut clock = ArrivalClock::default();
        loop {
            let (queued, deadline) = {
                let mut s = device.lock();
                (std::mem::take(&mut s.outbox), s.device.next_deadline())
            };
            if !queued.is_empty() {
                let _ = bus.send(queued).await;
            }
            let timer = async {
                match deadline {
                    Some(d) => sleep_until(origin + d).await,
                    None => pending::<()>().await,
                }
            };
            let mut out = Vec::new();
            tokio::select! {
                biased;
                _ = cancel.cancelled() => break,
                _ = device.wake.notified() => {}
                n = sub.recv_many(&mut items, BATCH) => {
                    if n == 0 {
                        break;
                    }
                }
                _ = timer => {}
            }
            // As in `run`: what arrived first, at its arrival time.
            while items.len() < BATCH {
                match sub.try_recv() {
                    Some(item) => items.push(item),
                    None => break,
                }
            }
            let now = origin.elapsed();
            {
                let mut s = device.lock();
                for item in items.drain(..) {
                    if let BusItem::Frame {
                        frame,
                        direction: Direction::Rx,
                    } = item
                    {
                        let at = clock.frame_time(now, &frame, Timestamp::now());
                        out.extend(s.device.on_frame(&frame, at));
                    }
                }
            }
            out.extend(device.lock().device.on_tick(clock.time(origin.elapsed())));
            if !out.is_empty() {
                let _ = bus.send(out).await;
            }
        }
    })
}

/// Runs a [`SimNode`] on `port` until `cancel` fires. Use [`DeviceHandle`]
/// and [`spawn_device`] to keep access to the node while it runs.
pub fn spawn_node(port: VirtualPort, node: SimNode, cancel: CancellationToken) -> JoinHandle<()> {
    spawn_device(port, DeviceHandle::new(node), cancel)
}

async fn run<D: Device>(mut port: VirtualPort, handle: DeviceHandle<D>, cancel: CancellationToken) {
    let origin = Instant::now();
    let mut filters = Filters::default();
    let started = handle.lock().device.start(origin.elapsed());
    filters.refresh(&port, &handle);
    send_all(&port, &handle, &started);
    let mut events = Vec::with_capacity(BATCH);
    let mut clock = ArrivalClock::default();
    loop {
        let (queued, deadline, off) = {
            let mut s = handle.lock();
            match power_state(&mut s, origin.elapsed()) {
                Some(until) => (Vec::new(), Some(until), true),
                None => (
                    std::mem::take(&mut s.outbox),
                    s.device.next_deadline(),
                    false,
                ),
            }
        };
        if off {
            // Unpowered: the port takes nothing; after power-on the fresh
            // device's filters are set whatever its generation.
            if filters.set.as_deref() != Some(&[]) {
                port.set_filters(Some(Vec::new()));
                filters = Filters {
                    set: Some(Vec::new()),
                    generation: None,
                };
            }
        } else {
            // The application may have changed the device through the handle.
            filters.refresh(&port, &handle);
        }
        send_all(&port, &handle, &queued);
        let timer = async {
            match deadline {
                Some(d) => sleep_until(origin + d).await,
                None => pending::<()>().await,
            }
        };
        tokio::select! {
            biased;
            _ = cancel.cancelled() => break,
            _ = handle.wake.notified() => {}
            _ = port.recv_many(&mut events, BATCH) => {}
            _ = timer => {}
        }
        if off {
            events.clear();
            continue;
        }
        // Whatever woke the runner, the frames that arrived meanwhile are
        // the device's before its timers: a runner held up by a loaded
        // host must not judge a heartbeat lost that waits in its port.
        while events.len() < BATCH {
            match port.try_recv() {
                Some(event) => events.push(event),
                None => break,
            }
        }
        if !events.is_empty() {
            let now = origin.elapsed();
            let mut out = Vec::new();
            {
                let mut s = handle.lock();
                for event in events.drain(..) {
                    if let PortEvent::Frame { frame, own: false } = event {
                        let at = clock.frame_time(now, &frame, Timestamp::now());
                        out.extend(s.device.on_frame(&frame, at));
                    }
                }
            }
            // Before the answers: one may confirm a new PDO COB-ID.
            filters.refresh(&port, &handle);
            send_all(&port, &handle, &out);
        }
        let due = handle.lock().device.on_tick(clock.time(origin.elapsed()));
        send_all(&port, &handle, &due);
    }
}

/// Advances a power cut at `now`: `Some(until)` while the device is off;
/// at the end, restarts the device and queues its start-up frames.
fn power_state<D: Device>(s: &mut Shared<D>, now: Duration) -> Option<Duration> {
    let cut = s.power_cut.as_mut()?;
    let until = *cut.until.get_or_insert(now + cut.off_for);
    if now < until {
        s.outbox.clear();
        return Some(until);
    }
    let cut = s.power_cut.take()?;
    (cut.restart)(&mut s.device);
    let boot = s.device.start(now);
    s.outbox = boot;
    None
}

/// The acceptance filters last set on the device's port, and the device's
/// filter generation they were built at.
#[derive(Default)]
struct Filters {
    set: Option<Vec<cangate_can::Filter>>,
    generation: Option<u64>,
}

impl Filters {
    /// Gives the port the device's current filters if they may have
    /// changed and did.
    fn refresh<D: Device>(&mut self, port: &VirtualPort, handle: &DeviceHandle<D>) {
        let now = {
            let s = handle.lock();
            let generation = s.device.filter_generation();
            if self.generation == Some(generation) {
                return;
            }
            self.generation = Some(generation);
            s.device.receive_filters()
        };
        if now != self.set {
            port.set_filters(now.clone());
            self.set = now;
        }
    }
}

fn send_all<D>(port: &VirtualPort, handle: &DeviceHandle<D>, frames: &[Frame]) {
    let failed = frames.iter().filter(|f| port.send(f).is_err()).count();
    if failed > 0 {
        let mut s = handle.shared.lock().unwrap_or_else(PoisonError::into_inner);
        s.send_errors += failed as u64;
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use cangate_can::{CanId, VirtualBus, VirtualBusConfig};
    use cangate_canopen::eds::{Eds, SIM_DRIVE_EDS};
    use cangate_canopen::value::Value;
    use cangate_canopen::{NodeId, ObjectAddress};
    use tokio::time::timeout;

    use super::*;
    use crate::SimNodeOptions;

    fn drive(options: SimNodeOptions) -> SimNode {
        let eds = Eds::parse(SIM_DRIVE_EDS).unwrap();
        SimNode::new(&eds, NodeId::new(5).unwrap(), options)
    }

    fn frame(id: u16, data: &[u8]) -> Frame {
        Frame::new(CanId::Standard(id), data).unwrap()
    }

    /// The next frame with `id` the port receives (others are skipped).
    async fn next_with_id(port: &mut VirtualPort, id: u16) -> Frame {
        let wait = async {
            loop {
                if let PortEvent::Frame { frame, .. } = port.recv().await
                    && frame.id() == CanId::Standard(id)
                {
                    return frame;
                }
            }
        };
        timeout(Duration::from_secs(5), wait)
            .await
            .unwrap_or_else(|_| panic!("no frame {id:03X}"))
    }

    /// One try of the held-up runner below: `Some(error register)` after
    /// the runner's thread was blocked for 500 ms while a producer kept
    /// sending its heartbeat every 10 ms, or `None` when the producer's own
    /// thread was held up for 150 ms or more (a host too loaded for the
    /// premise).
    async fn heartbeats_through_a_held_up_runner() -> Option<Value> {
        use std::sync::atomic::{AtomicBool, Ordering};
        let bus = VirtualBus::new("sim-late", VirtualBusConfig::default());
        let mut tester = bus.connect(false);
        let cancel = CancellationToken::new();
        let handle = DeviceHandle::new(drive(SimNodeOptions::default()));
        let task = spawn_device(bus.connect(false), handle.clone(), cancel.clone());
        next_with_id(&mut tester, 0x705).await;
        // 0x1016:01 = node 0x7F, 300 ms.
        tester
            .send(&frame(
                0x605,
                &[0x23, 0x16, 0x10, 0x01, 0x2C, 0x01, 0x7F, 0x00],
            ))
            .unwrap();
        assert_eq!(next_with_id(&mut tester, 0x585).await.data()[0], 0x60);
        let stop = Arc::new(AtomicBool::new(false));
        let producer = {
            let port = bus.connect(false);
            let stop = stop.clone();
            std::thread::spawn(move || {
                let mut longest = Duration::ZERO;
                let mut last = std::time::Instant::now();
                while !stop.load(Ordering::Relaxed) {
                    port.send(&frame(0x77F, &[0x05])).unwrap();
                    longest = longest.max(last.elapsed());
                    last = std::time::Instant::now();
                    std::thread::sleep(Duration::from_millis(10));
                }
                longest
            })
        };
        tokio::time::sleep(Duration::from_millis(100)).await;
        // The runner shares this thread: it cannot run while it sleeps.
        std::thread::sleep(Duration::from_millis(500));
        tokio::time::sleep(Duration::from_millis(100)).await;
        stop.store(true, Ordering::Relaxed);
        let longest = producer.join().unwrap();
        let register = handle.with(|n| n.get(ObjectAddress::new(0x1001, 0)).cloned());
        cancel.cancel();
        task.await.unwrap();
        (longest < Duration::from_millis(150)).then(|| register.unwrap())
    }

    /// A device held up (a loaded host) while the heartbeats it consumes
    /// waited in its port judges each by the time it arrived, as a
    /// device's receive interrupt would: its own lateness is no loss of the
    /// producer.
    #[tokio::test]
    async fn a_held_up_runner_judges_heartbeats_by_their_arrival() {
        for _ in 0..3 {
            if let Some(register) = heartbeats_through_a_held_up_runner().await {
                assert_eq!(register, Value::Unsigned8(0), "heartbeat judged lost");
                return;
            }
        }
        panic!("the heartbeat producer's thread was held up in every try");
    }

    #[tokio::test]
    async fn sdo_read_over_the_virtual_bus() {
        let bus = VirtualBus::new("sim-sdo", VirtualBusConfig::default());
        let mut tester = bus.connect(false);
        let cancel = CancellationToken::new();
        let task = spawn_node(
            bus.connect(false),
            drive(SimNodeOptions::default()),
            cancel.clone(),
        );
        assert_eq!(next_with_id(&mut tester, 0x705).await.data(), [0x00]);
        tester
            .send(&frame(0x605, &[0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]))
            .unwrap();
        let reply = next_with_id(&mut tester, 0x585).await;
        assert_eq!(
            reply.data(),
            [0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00]
        );
        cancel.cancel();
        task.await.unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn heartbeats_follow_the_clock() {
        let bus = VirtualBus::new("sim-hb", VirtualBusConfig::default());
        let mut tester = bus.connect(false);
        let cancel = CancellationToken::new();
        let options = SimNodeOptions {
            heartbeat_ms: Some(100),
            ..SimNodeOptions::default()
        };
        let task = spawn_node(bus.connect(false), drive(options), cancel.clone());
        assert_eq!(next_with_id(&mut tester, 0x705).await.data(), [0x00]);
        let boot = Instant::now();
        for k in 1..=3u32 {
            assert_eq!(next_with_id(&mut tester, 0x705).await.data(), [0x7F]);
            assert_eq!(boot.elapsed(), Duration::from_millis(100) * k);
        }
        cancel.cancel();
        task.await.unwrap();
    }

    /// The runner gives the port the node's filters, and the new ones
    /// before the SDO answer that confirms a PDO's new COB-ID: an RPDO sent
    /// right after that answer reaches the node.
    #[tokio::test]
    async fn port_filters_follow_the_node() {
        let bus = VirtualBus::new("sim-filters", VirtualBusConfig::default());
        let mut tester = bus.connect(false);
        let cancel = CancellationToken::new();
        let handle = DeviceHandle::new(drive(SimNodeOptions::default()));
        let task = spawn_device(bus.connect(false), handle.clone(), cancel.clone());
        next_with_id(&mut tester, 0x705).await;
        tester.send(&frame(0x000, &[0x01, 0x05])).unwrap();
        for (request, reply) in [
            ([0x23, 0x00, 0x14, 0x01, 0x05, 0x02, 0x00, 0x80], 0x60),
            ([0x23, 0x00, 0x14, 0x01, 0xAB, 0x02, 0x00, 0x00], 0x60),
        ] {
            tester.send(&frame(0x605, &request)).unwrap();
            assert_eq!(next_with_id(&mut tester, 0x585).await.data()[0], reply);
        }
        // RPDO1 (controlword, target position) on its new COB-ID at once;
        // another drive's RPDO is not even queued to this one.
        tester
            .send(&frame(0x2AB, &[0x0F, 0x00, 0x40, 0xE2, 0x01, 0x00]))
            .unwrap();
        tester
            .send(&frame(0x206, &[0x06, 0x00, 0x00, 0x00, 0x00, 0x00]))
            .unwrap();
        tester
            .send(&frame(0x605, &[0x40, 0x7A, 0x60, 0x00, 0, 0, 0, 0]))
            .unwrap();
        let reply = next_with_id(&mut tester, 0x585).await;
        assert_eq!(
            reply.data(),
            [0x43, 0x7A, 0x60, 0x00, 0x40, 0xE2, 0x01, 0x00]
        );
        assert_eq!(
            handle.with(|n| n.get(ObjectAddress::new(0x6040, 0)).cloned()),
            Some(Value::Unsigned16(0x000F))
        );
        cancel.cancel();
        task.await.unwrap();
    }

    #[tokio::test]
    async fn handle_shares_the_node_with_the_application() {
        let bus = VirtualBus::new("sim-handle", VirtualBusConfig::default());
        let mut tester = bus.connect(false);
        let cancel = CancellationToken::new();
        let handle = DeviceHandle::new(drive(SimNodeOptions::default()));
        let task = spawn_device(bus.connect(false), handle.clone(), cancel.clone());
        next_with_id(&mut tester, 0x705).await;

        // A process value set by the application is read by the master.
        handle.with(|n| {
            n.set(ObjectAddress::new(0x6041, 0), Value::Unsigned16(0x0237))
                .unwrap()
        });
        tester
            .send(&frame(0x605, &[0x40, 0x41, 0x60, 0x00, 0, 0, 0, 0]))
            .unwrap();
        let reply = next_with_id(&mut tester, 0x585).await;
        assert_eq!(
            reply.data(),
            [0x4B, 0x41, 0x60, 0x00, 0x37, 0x02, 0x00, 0x00]
        );

        // Frames produced outside on_frame/on_tick go out through the runner.
        handle.send_with(|n| n.inject_emcy(0x2310, 0x03, [1, 2, 3, 4, 5]));
        let emcy = next_with_id(&mut tester, 0x085).await;
        assert_eq!(emcy.data(), [0x10, 0x23, 0x03, 1, 2, 3, 4, 5]);

        // An NMT start makes the runner send TPDO1 at once, then per timer.
        tester.send(&frame(0x000, &[0x01, 0x05])).unwrap();
        let tpdo = next_with_id(&mut tester, 0x185).await;
        assert_eq!(tpdo.data(), [0x37, 0x02, 0, 0, 0, 0]);
        next_with_id(&mut tester, 0x185).await;
        assert_eq!(
            handle.with(|n| n.nmt_state()),
            cangate_canopen::nmt::NmtState::Operational
        );
        assert_eq!(handle.send_errors(), 0);

        cancel.cancel();
        task.await.unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn a_power_cycle_silences_the_node_then_boots_it_with_its_defaults() {
        use crate::PowerOn;
        let bus = VirtualBus::new("sim-power", VirtualBusConfig::default());
        let mut tester = bus.connect(false);
        let cancel = CancellationToken::new();
        let handle = DeviceHandle::new(drive(SimNodeOptions::default()));
        let task = spawn_device(bus.connect(false), handle.clone(), cancel.clone());
        assert_eq!(next_with_id(&mut tester, 0x705).await.data(), [0x00]);
        // Heartbeat 0x1017 = 50 ms over SDO.
        tester
            .send(&frame(0x605, &[0x2B, 0x17, 0x10, 0x00, 50, 0, 0, 0]))
            .unwrap();
        assert_eq!(next_with_id(&mut tester, 0x585).await.data()[0], 0x60);
        handle.power_cycle(Duration::from_millis(500), |n| *n = n.powered_on());
        tokio::task::yield_now().await;
        assert!(!handle.is_powered());
        // Off: no heartbeat, no SDO answer, nothing at all.
        tester
            .send(&frame(0x605, &[0x40, 0x17, 0x10, 0x00, 0, 0, 0, 0]))
            .unwrap();
        let silent = timeout(Duration::from_millis(400), async {
            loop {
                if let PortEvent::Frame { frame, .. } = tester.recv().await {
                    return frame;
                }
            }
        })
        .await;
        // The heartbeat already on the bus before the cut may still arrive.
        if let Ok(f) = silent {
            assert_eq!(f.raw_id(), 0x705, "{f:?}");
        }
        // Power returns: boot-up, and the dictionary's defaults (0x1017 = 1000).
        let boot = next_with_id(&mut tester, 0x705).await;
        assert_eq!(boot.data(), [0x00]);
        assert!(handle.is_powered());
        tester
            .send(&frame(0x605, &[0x40, 0x17, 0x10, 0x00, 0, 0, 0, 0]))
            .unwrap();
        let reply = next_with_id(&mut tester, 0x585).await;
        assert_eq!(reply.data()[4..6], 1000u16.to_le_bytes());
        cancel.cancel();
        task.await.unwrap();
    }
}
