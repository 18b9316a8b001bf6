//! The running gateway: its buses, the gRPC server, and one cancellation
//! tree from the signal handler through the server, the streams and the bus
//! tasks.

use crate::axes::Axes;
use crate::canopen::{BootPlan, CanopenBus, NodeFacts};
use crate::cansmc::CansmcMaster;
use crate::config::{
    BackendChoice, BusConfig, CanopenConfig, Config, NodeConfig, StuffingChoice, parse_object,
};
use crate::handwheel::Handwheels;
use crate::not_found::NotFound;
use crate::simulation::SimulatedDevice;
use cangate_axis::{AxisSpec, DriveSpec, ProcessDataPath};
use cangate_can::bus::{Backend, BackendKind, BusHandle, BusInfo};
use cangate_can::socketcan_bus::SocketCanBus;
use cangate_can::{BitTiming, Stuffing, VirtualBusConfig, VirtualNetwork};
use cangate_canopen::NodeId;
use cangate_canopen::ObjectAddress;
use cangate_canopen::eds::Eds;
use cangate_canopen::pdo::{PdoConfig, PdoKind};
use cangate_canopen::value::{DataType, Value};
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

/// Why the gateway could not start, by what failed.
#[derive(Debug, thiserror::Error)]
pub enum BootError {
    /// A bus could not be opened or set up (its backend, its client
    /// share, its simulated faults).
    #[error("bus {bus:?}: {message}")]
    Bus {
        /// Bus name.
        bus: String,
        /// What went wrong.
        message: String,
    },
    /// A CANopen node's description (EDS, DCF, PDOs, boot writes, its
    /// simulation) cannot be used.
    #[error("bus {bus:?}: node {node}: {message}")]
    Node {
        /// Bus name.
        bus: String,
        /// Node-ID as configured.
        node: u32,
        /// What went wrong.
        message: String,
    },
    /// The master's own heartbeat producer cannot be set up.
    #[error("bus {bus:?}: master_node_id: {message}")]
    MasterHeartbeat {
        /// Bus name.
        bus: String,
        /// What went wrong.
        message: String,
    },
    /// The axis layer could not start.
    #[error("axes: {0}")]
    Axes(String),
    /// A CANsmc master (or its simulated slaves) could not start.
    #[error("bus {bus:?}: cansmc {master}: {message}")]
    Cansmc {
        /// Master name.
        master: String,
        /// Its command bus.
        bus: String,
        /// What went wrong.
        message: String,
    },
    /// The handwheels could not start.
    #[error("handwheels: {0}")]
    Handwheels(String),
    /// The thread of the bus runtime could not be started.
    #[error("cannot start the bus runtime thread: {0}")]
    Runtime(std::io::Error),
}

/// The runtime the bus side runs on: the bus owner tasks, the CANopen and
/// CANsmc masters, the axis tasks and simulated devices (what
/// [`Gateway::start`] spawns, except the handwheel tasks, which feed the
/// gRPC side), one current-thread tokio runtime on its own thread
/// `gateway-bus`. The gRPC services stay on the caller's runtime.
///
/// Why: the process data path (a frame arrives, the bus task fans it out,
/// the axis task steps and sends) is a chain of task wake-ups, and
/// wake-ups, not frames, cost the CPU ("Wake-ups cost more than frames" in
/// docs/design.md). On one thread the chain runs back to back, and the bus
/// side's order of events no longer depends on work stealing.
struct BusRuntime {
    handle: tokio::runtime::Handle,
    /// Ends the thread (and drops whatever still runs on it).
    stop: CancellationToken,
}

impl BusRuntime {
    /// `io`: a backend (SocketCAN) or an endpoint served on the bus thread
    /// (socketcand, CiA 309-3) needs the I/O driver. Without it the
    /// thread parks on a futex instead of in `epoll_wait`, a cheaper sleep
    /// and wake-up, and virtual buses need nothing else.
    /// `rt_priority`: `SCHED_FIFO` for the thread (0: the default policy).
    fn start(io: bool, rt_priority: u8) -> Result<BusRuntime, BootError> {
        let mut builder = tokio::runtime::Builder::new_current_thread();
        builder.enable_time();
        if io {
            builder.enable_io();
        }
        let rt = builder.build().map_err(BootError::Runtime)?;
        let handle = rt.handle().clone();
        let stop = CancellationToken::new();
        let until = stop.clone();
        std::thread::Builder::new()
            .name("gateway-bus".into())
            .spawn(move || {
                crate::realtime::enter(rt_priority, "gateway-bus");
                rt.block_on(until.cancelled())
            })
            .map_err(BootError::Runtime)?;
        Ok(BusRuntime { handle, stop })
    }
}

impl Drop for BusRuntime {
    fn drop(&mut self) {
        // Not joined: the last reference to the gateway may be dropped on
        // that very thread. The tasks have ended by now in an orderly
        // shutdown (they follow the shutdown token and are awaited by
        // `RunningServer::wait`).
        self.stop.cancel();
    }
}

/// The buses and shared state every service uses.
pub struct Gateway {
    buses: BTreeMap<String, BusHandle>,
    canopen: BTreeMap<String, CanopenBus>,
    cansmc: BTreeMap<String, CansmcMaster>,
    /// Simulated CANsmc slaves per master (tests and the Simulator reach
    /// them here).
    sim_smc: BTreeMap<String, Vec<cangate_sim::cansmc_runner::CansmcSlaveHandle>>,
    /// The cycle threads, joined at shutdown.
    cansmc_threads: std::sync::Mutex<Vec<std::thread::JoinHandle<()>>>,
    axes: Arc<Axes>,
    handwheels: Arc<Handwheels>,
    network: VirtualNetwork,
    /// Simulated devices and virtual-bus faults (the Simulator service).
    simulation: crate::simulation::Simulation,
    shutdown: CancellationToken,
    /// Declared last so it is dropped last: the bus side runs on it.
    bus_runtime: BusRuntime,
}

impl Gateway {
    /// Opens every configured bus and starts its owner task, then what
    /// runs on the buses: the CANopen masters (with their simulated
    /// devices), the axis layer, the CANsmc masters and the handwheels.
    pub fn start(
        config: &Config,
        shutdown: CancellationToken,
    ) -> Result<(Gateway, Vec<JoinHandle<()>>), BootError> {
        let bus_runtime = BusRuntime::start(
            config
                .buses
                .iter()
                .any(|b| b.backend == crate::config::BackendChoice::Socketcan)
                // The text-protocol endpoints serve their connections on
                // the bus thread (`security::slots::listen_on_bus_thread`).
                || config.socketcand.is_some()
                || config.cia309.is_some(),
            config.rt_priority,
        )?;
        // Everything spawned from here on (tokio::spawn in the bus, master,
        // axis and handwheel constructors) runs on the bus runtime.
        // The caller's runtime (the gRPC side), if there is one.
        let caller = tokio::runtime::Handle::try_current().ok();
        let bus_side = bus_runtime.handle.clone();
        let _bus_side_guard = bus_side.enter();
        let network = VirtualNetwork::new();
        let (buses, mut tasks) = start_buses(config, &network, &shutdown)?;
        let simulation = crate::simulation::wiring::bus_faults(&config.buses, &network)
            .map_err(|(bus, message)| BootError::Bus { bus, message })?;
        let mut booting = CanopenBoot {
            simulation,
            simulated: Vec::new(),
            sim_wheels: std::collections::HashMap::new(),
            canopen: BTreeMap::new(),
        };
        // One SYNC thread for every CANopen bus (started with the first).
        let sync_thread = crate::canopen::sync_thread::SyncThread::new(
            config.rt_priority,
            shutdown.child_token(),
        );
        for cc in &config.canopen {
            tasks.extend(booting.start_master(
                config,
                cc,
                &buses,
                &network,
                &sync_thread,
                &shutdown,
            )?);
        }
        let CanopenBoot {
            simulation,
            simulated,
            sim_wheels,
            canopen,
        } = booting;
        let (axes, axis_tasks, mut axis_ports) = config
            .axis_specs()
            .and_then(|specs| Axes::start(&specs, &canopen, shutdown.child_token()))
            .map_err(BootError::Axes)?;
        tasks.extend(axis_tasks);
        let mut cansmc = BTreeMap::new();
        let mut sim_smc = BTreeMap::new();
        let mut cansmc_threads = Vec::new();
        for mc in &config.cansmc {
            let StartedCansmc {
                master,
                thread,
                sims,
            } = start_cansmc_master(
                config,
                mc,
                &buses,
                &network,
                axis_ports.remove(&mc.name),
                &shutdown,
            )?;
            if !sims.is_empty() {
                sim_smc.insert(mc.name.clone(), sims);
            }
            cansmc.insert(mc.name.clone(), master);
            cansmc_threads.push(thread);
        }
        // The handwheel tasks run with the gRPC side: each feed event is
        // broadcast to every StreamFeed subscriber, and from the bus
        // thread each of those wake-ups would be a cross-runtime schedule
        // (100 subscribers at 7 000 frames/s: 700 000 a second from one
        // thread). Their input from the bus is one wake-up per batch.
        let (handwheels, wheel_tasks) = {
            let _caller_side = caller.as_ref().map(|h| h.enter());
            Handwheels::start(
                &config.handwheels,
                &canopen,
                &buses,
                &axes,
                &sim_wheels,
                shutdown.child_token(),
            )
        }
        .map_err(BootError::Handwheels)?;
        tasks.extend(wheel_tasks);
        // Simulated devices start after their master listens, so that the
        // master sees their boot-up.
        for (port, device) in simulated {
            tasks.push(crate::simulation::wiring::spawn(
                port,
                device,
                shutdown.child_token(),
            ));
        }
        Ok((
            Gateway {
                buses,
                canopen,
                cansmc,
                sim_smc,
                cansmc_threads: std::sync::Mutex::new(cansmc_threads),
                axes,
                handwheels,
                network,
                simulation,
                shutdown,
                bus_runtime,
            },
            tasks,
        ))
    }

    /// A bus by name.
    pub fn bus(&self, name: &str) -> Result<&BusHandle, NotFound> {
        self.buses.get(name).ok_or_else(|| {
            NotFound::among("bus", "buses", name, self.buses.keys().map(String::as_str))
        })
    }

    /// The CANopen master of a bus, if it has one.
    pub fn canopen(&self, bus: &str) -> Option<&CanopenBus> {
        self.canopen.get(bus)
    }

    /// A CANsmc master by name.
    pub fn cansmc(&self, name: &str) -> Result<&CansmcMaster, NotFound> {
        self.cansmc.get(name).ok_or_else(|| {
            NotFound::among(
                "CANsmc master",
                "masters",
                name,
                self.cansmc.keys().map(String::as_str),
            )
        })
    }

    /// Every CANsmc master, by name.
    pub fn cansmc_masters(&self) -> impl Iterator<Item = &CansmcMaster> {
        self.cansmc.values()
    }

    /// The simulated slaves of a CANsmc master (empty when none).
    pub fn simulated_cansmc_slaves(
        &self,
        master: &str,
    ) -> &[cangate_sim::cansmc_runner::CansmcSlaveHandle] {
        self.sim_smc.get(master).map_or(&[], Vec::as_slice)
    }

    /// Waits for the CANsmc cycle threads to end (after the shutdown
    /// token fired): each ends within one wake-up of the token, its last
    /// frames submitted and its last status published. The threads are
    /// joined off the async runtime.
    pub async fn join_cansmc_threads(&self) {
        let threads = std::mem::take(&mut *self.cansmc_threads.lock().expect("threads lock"));
        if threads.is_empty() {
            return;
        }
        let _ = tokio::task::spawn_blocking(move || {
            for t in threads {
                let _ = t.join();
            }
        })
        .await;
    }

    /// The axes.
    pub fn axes(&self) -> &Arc<Axes> {
        &self.axes
    }

    /// The handwheels.
    pub fn handwheels(&self) -> &Arc<Handwheels> {
        &self.handwheels
    }

    /// Every CANopen master, by bus name.
    pub fn canopen_buses(&self) -> impl Iterator<Item = &CanopenBus> {
        self.canopen.values()
    }

    /// All buses, by name.
    pub fn buses(&self) -> impl Iterator<Item = &BusHandle> {
        self.buses.values()
    }

    /// The runtime of the bus side (the `gateway-bus` thread), for code
    /// embedding the gateway that talks to the buses at the lowest latency
    /// (a local control loop): a task spawned here calls
    /// [`CanopenBus::sdo`] or [`BusHandle::send`] without a hand-over to
    /// another thread and back, each of which costs a thread wake-up
    /// (5-20 µs on a virtual machine). The price: such a task shares the
    /// thread with every protocol stack, so it must never block or run
    /// long between awaits, or the buses stall with it.
    pub fn bus_runtime(&self) -> &tokio::runtime::Handle {
        &self.bus_runtime.handle
    }

    /// The simulated devices and the virtual buses' fault injection.
    pub fn simulation(&self) -> &crate::simulation::Simulation {
        &self.simulation
    }

    /// The in-process virtual buses (simulated devices and tests attach here).
    pub fn network(&self) -> &VirtualNetwork {
        &self.network
    }

    /// Fires when the gateway shuts down; long-lived streams end on it.
    pub fn shutdown_token(&self) -> CancellationToken {
        self.shutdown.clone()
    }
}

type NodePlan = (Vec<PdoConfig>, Vec<PdoConfig>, Option<Arc<BootPlan>>);

/// The buses by name.
type Buses = BTreeMap<String, BusHandle>;

/// Opens every configured bus and starts its owner task, with its client
/// share.
fn start_buses(
    config: &Config,
    network: &VirtualNetwork,
    shutdown: &CancellationToken,
) -> Result<(Buses, Vec<JoinHandle<()>>), BootError> {
    let mut buses = BTreeMap::new();
    let mut tasks = Vec::new();
    for bc in &config.buses {
        let (info, backend) = open_bus(bc, network)?;
        let (handle, task) = BusHandle::spawn(info, backend, shutdown.child_token());
        bc.tx_shares()
            .and_then(|shares| handle.set_tx_shares(shares))
            .map_err(|message| BootError::Bus {
                bus: bc.name.clone(),
                message,
            })?;
        tasks.extend(crate::traffic_log::spawn(
            &bc.name,
            &handle,
            bc.decode,
            shutdown.child_token(),
        ));
        buses.insert(bc.name.clone(), handle);
        tasks.push(task);
    }
    Ok((buses, tasks))
}

/// The CANopen side while it starts: the masters so far, and the
/// simulated devices that start once everything listens.
struct CanopenBoot {
    simulation: crate::simulation::Simulation,
    /// Simulated devices with their ports, spawned last.
    simulated: Vec<(cangate_can::VirtualPort, SimulatedDevice)>,
    /// Simulated handwheels by bus and node, for the handwheel tasks.
    sim_wheels: std::collections::HashMap<
        (String, u32),
        cangate_sim::DeviceHandle<cangate_sim::SimHandwheel>,
    >,
    canopen: BTreeMap<String, CanopenBus>,
}

impl CanopenBoot {
    /// Starts the master of one `[[canopen]]` section: the facts of its
    /// nodes (wiring up the simulated ones), the master task on the SYNC
    /// thread, and the master's own heartbeat.
    fn start_master(
        &mut self,
        config: &Config,
        cc: &CanopenConfig,
        buses: &BTreeMap<String, BusHandle>,
        network: &VirtualNetwork,
        sync_thread: &crate::canopen::sync_thread::SyncThread,
        shutdown: &CancellationToken,
    ) -> Result<Vec<JoinHandle<()>>, BootError> {
        let bus = buses[&cc.bus].clone();
        let mut facts = BTreeMap::new();
        for nc in &cc.nodes {
            let err = |message: String| BootError::Node {
                bus: cc.bus.clone(),
                node: nc.id,
                message,
            };
            let node = NodeId::new(nc.id).map_err(|e| err(e.to_string()))?;
            let (eds, eds_text) = match nc.load_eds().map_err(err)? {
                Some((eds, text)) => (Some(Arc::new(eds)), Some(text)),
                None => (None, None),
            };
            if nc.simulate {
                let eds = eds
                    .as_ref()
                    .ok_or_else(|| err("a simulated node needs an eds".into()))?;
                let vbus = network
                    .get(bus.info().interface.as_str())
                    .ok_or_else(|| err("simulated nodes need a virtual bus".into()))?;
                self.simulate(config, cc, nc, node, eds.clone(), vbus);
            }
            facts.insert(
                node,
                node_facts(config, cc, nc, node, eds, eds_text).map_err(err)?,
            );
        }
        let mut tasks = Vec::new();
        let (master, task) = CanopenBus::spawn(
            bus.clone(),
            Duration::from_millis(cc.sdo_timeout_ms),
            crate::canopen::sync_thread::SyncSettings {
                running: cc.sync_period_us > 0,
                // A stopped SYNC started at run time without a period runs
                // at 10 ms until one is given.
                period: Duration::from_micros(if cc.sync_period_us > 0 {
                    cc.sync_period_us
                } else {
                    10_000
                }),
                counter_overflow: cc.sync_counter_overflow,
            },
            (cc.time_period_ms > 0).then(|| Duration::from_millis(cc.time_period_ms)),
            sync_thread,
            facts,
            shutdown.child_token(),
        );
        let master = master.with_client_sdo_limit(
            config.security.limits.sdo_requests_per_client_and_node as usize,
        );
        master.set_handover_spin(Duration::from_micros(config.handover_spin_us));
        self.canopen.insert(cc.bus.clone(), master);
        tasks.push(task);
        // The master's own heartbeat, which the axis drives consume.
        if let Some((id, ms)) = cc.master_heartbeat() {
            let id = NodeId::new(u32::from(id)).map_err(|e| BootError::MasterHeartbeat {
                bus: cc.bus.clone(),
                message: e.to_string(),
            })?;
            tasks.push(crate::canopen::master_heartbeat::spawn(
                bus,
                id,
                Duration::from_millis(u64::from(ms)),
                shutdown.child_token(),
            ));
        }
        Ok(tasks)
    }

    /// Wires up the simulated device of node `nc` on `vbus`; it starts
    /// with the others, after every master listens.
    fn simulate(
        &mut self,
        config: &Config,
        cc: &CanopenConfig,
        nc: &NodeConfig,
        node: NodeId,
        eds: Arc<Eds>,
        vbus: cangate_can::VirtualBus,
    ) {
        let wheel_counter = config
            .handwheels
            .iter()
            .find(|h| h.bus == cc.bus && h.node == nc.id)
            .map(|h| h.counter);
        let device = crate::simulation::wiring::canopen_device(nc, node, eds, wheel_counter);
        if let SimulatedDevice::Handwheel(handle) = &device {
            self.sim_wheels
                .insert((cc.bus.clone(), nc.id), handle.clone());
        }
        self.simulation.add_device(&cc.bus, node, device.clone());
        self.simulated.push((vbus.connect(false), device));
    }
}

/// Starts one CANsmc master: its simulated slaves first (they attach to
/// the virtual buses before the master's first MCT), then its cycle
/// thread.
fn start_cansmc_master(
    config: &Config,
    mc: &crate::config::CansmcConfig,
    buses: &BTreeMap<String, BusHandle>,
    network: &VirtualNetwork,
    axis_port: Option<crate::axis_runner::AxisPort>,
    shutdown: &CancellationToken,
) -> Result<StartedCansmc, BootError> {
    let err = |message: String| BootError::Cansmc {
        master: mc.name.clone(),
        bus: mc.command_bus.clone(),
        message,
    };
    let sims = crate::simulation::wiring::start_cansmc_slaves(
        mc,
        |name| network.get(buses[name].info().interface.as_str()),
        shutdown.child_token(),
    )
    .map_err(err)?;
    let (master, thread) = CansmcMaster::start(
        mc,
        mc.effective_bitrate(&config.buses),
        buses[&mc.command_bus].clone(),
        buses[&mc.status_bus].clone(),
        axis_port,
        shutdown.child_token(),
    )
    .map_err(err)?;
    Ok(StartedCansmc {
        master,
        thread,
        sims,
    })
}

/// A started CANsmc master.
struct StartedCansmc {
    master: CansmcMaster,
    /// Its cycle thread.
    thread: std::thread::JoinHandle<()>,
    /// Its simulated slaves.
    sims: Vec<cangate_sim::cansmc_runner::CansmcSlaveHandle>,
}

/// What the master knows of configured node `nc` before it is heard of:
/// its PDOs and boot procedure (from `node_plan`), EDS and heartbeat.
fn node_facts(
    config: &Config,
    cc: &CanopenConfig,
    nc: &NodeConfig,
    node: NodeId,
    eds: Option<Arc<Eds>>,
    eds_text: Option<Arc<str>>,
) -> Result<NodeFacts, String> {
    let axes = (config.axes.iter())
        .filter(|a| a.bus == cc.bus && a.node == nc.id)
        .map(|a| Ok((AxisSpec::try_from(a)?, further_axis_block(config, cc, a))))
        .collect::<Result<Vec<_>, String>>()?;
    let sync = (cc.sync_period_us > 0).then(|| Duration::from_micros(cc.sync_period_us));
    let master_heartbeat = cc
        .master_heartbeat()
        .zip(cc.drive_heartbeat_timeout_ms())
        .map(|((id, _), timeout)| (id, timeout));
    let (tpdos, rpdos, mut boot) =
        node_plan(nc, node, eds.as_deref(), &axes, sync, master_heartbeat)?;
    // A handwheel sends feed only when operational: it is started at every
    // boot-up like the configured nodes.
    if boot.is_none()
        && config
            .handwheels
            .iter()
            .any(|h| h.bus == cc.bus && h.node == nc.id)
    {
        boot = Some(Arc::new(BootPlan::default()));
    }
    Ok(NodeFacts {
        name: nc.name.clone(),
        configured: true,
        tpdos,
        rpdos,
        boot,
        eds,
        eds_text,
        heartbeat_timeout: (nc.heartbeat_timeout_ms > 0)
            .then(|| Duration::from_millis(nc.heartbeat_timeout_ms)),
        guarding: nc.guarding(),
        // The CiA 402 axis task of the bus reads its drive's TPDOs from
        // the bus itself.
        tpdos_read_by_axis: !axes.is_empty(),
        ..Default::default()
    })
}

/// The further-axis block (COB-IDs 0x680 + 8 × block, see
/// [`cangate_axis::process_data::FURTHER_AXIS_COB_BASE`]) of axis `a` on
/// `cc`'s bus: its place among the bus's axes with a `drive_axis` above 0,
/// by node and drive axis (0 for a first axis, which has the predefined
/// COB-IDs).
fn further_axis_block(config: &Config, cc: &CanopenConfig, a: &crate::config::AxisConfig) -> u16 {
    if a.drive_axis == 0 {
        return 0;
    }
    config
        .axes
        .iter()
        .filter(|b| {
            b.bus == cc.bus && b.drive_axis > 0 && (b.node, b.drive_axis) < (a.node, a.drive_axis)
        })
        .count() as u16
}

/// The PDO layouts the master uses for a node, and its boot procedure. A
/// node that backs axes (one, or several of a multi-axis drive, each with
/// its further-axis block) gets the axis process data layout of each
/// ([`cangate_axis::process_data`]) and always a boot procedure.
fn node_plan(
    nc: &NodeConfig,
    node: NodeId,
    eds: Option<&Eds>,
    axes: &[(AxisSpec, u16)],
    sync: Option<Duration>,
    master_heartbeat: Option<(u8, u16)>,
) -> Result<NodePlan, String> {
    // The CiA 402 axes of the drive (a CANsmc axis is no CANopen node).
    let drives: Vec<(&AxisSpec, &cangate_axis::Cia402Drive, u16)> = axes
        .iter()
        .filter_map(|(a, block)| match &a.drive {
            DriveSpec::Cia402(d) => Some((a, d, *block)),
            DriveSpec::Cansmc(_) => None,
        })
        .collect();
    let (tpdos, rpdos) = if drives.is_empty() {
        (
            pdo_layouts(PdoKind::Tpdo, &nc.tpdo, eds, node)?,
            pdo_layouts(PdoKind::Rpdo, &nc.rpdo, eds, node)?,
        )
    } else {
        let (mut tpdos, mut rpdos) = (Vec::new(), Vec::new());
        for &(axis, d, block) in &drives {
            let (t, r) = axis_pdos(nc, node, axis, d, sync.is_some(), eds, block)?;
            tpdos.extend(t);
            rpdos.extend(r);
        }
        (tpdos, rpdos)
    };
    if drives.is_empty() && !nc.boot {
        return Ok((tpdos, rpdos, None));
    }
    let mut writes = dcf_writes(nc, node, eds)?;
    if let Some(ms) = nc.heartbeat_producer_ms {
        writes.push((ObjectAddress::new(0x1017, 0), ms.to_le_bytes().to_vec()));
    }
    writes.extend(life_guarding_writes(nc, eds));
    if let Some(&(first, _, _)) = drives.first() {
        // The node watches the master's heartbeat once, for all its axes.
        writes.extend(master_heartbeat_consumer(eds, master_heartbeat, first));
        for p in tpdos.iter().chain(&rpdos) {
            writes.extend(p.sdo_writes().map_err(|e| e.to_string())?);
        }
        for &(axis, d, _) in &drives {
            use cangate_canopen::cia402::{objects as obj, on_axis};
            let controller = d.controller(axis.motion.clone());
            writes.extend(cangate_axis::cia402::Cia402Axis::new(controller).boot_writes());
            if let (cangate_axis::DriveMode::InterpolatedPosition, Some(period)) = (d.mode, sync) {
                // The drive interpolates each 0x60C1 set-point over one
                // SYNC period.
                let (value, index) = cangate_axis::process_data::interpolation_period(period);
                writes.push((
                    on_axis(obj::INTERPOLATION_PERIOD_VALUE, d.drive_axis),
                    vec![value],
                ));
                writes.push((
                    on_axis(obj::INTERPOLATION_PERIOD_INDEX, d.drive_axis),
                    index.to_le_bytes().to_vec(),
                ));
            }
            writes.push((
                on_axis(obj::HOMING_METHOD, d.drive_axis),
                vec![d.homing_method as u8],
            ));
        }
    } else {
        // Only PDOs configured explicitly are written; EDS defaults are
        // the node's own.
        for (entries, list) in [(&nc.tpdo, &tpdos), (&nc.rpdo, &rpdos)] {
            if !entries.is_empty() {
                for p in list {
                    writes.extend(p.sdo_writes().map_err(|e| e.to_string())?);
                }
            }
        }
    }
    writes.extend(configured_writes(nc)?);
    let plan = BootPlan {
        device_type: nc.device_type,
        vendor_id: nc.vendor_id,
        product_code: nc.product_code,
        writes,
        identify_only: false,
        required_modes: drives
            .iter()
            .map(|(_, d, _)| (d.drive_axis, d.mode.operation().supported_mask()))
            .collect(),
    };
    Ok((tpdos, rpdos, Some(Arc::new(plan))))
}

/// The PDOs of a drive that backs `axis`: the axis layer's standard
/// mapping (none for an axis whose process data goes by SDO).
fn axis_pdos(
    nc: &NodeConfig,
    node: NodeId,
    axis: &AxisSpec,
    drive: &cangate_axis::Cia402Drive,
    sync: bool,
    eds: Option<&Eds>,
    block: u16,
) -> Result<(Vec<PdoConfig>, Vec<PdoConfig>), String> {
    use cangate_axis::process_data::{FeedbackTrigger, PDOS_PER_AXIS, standard_pdos};
    use cangate_canopen::cia402::on_axis;
    if !nc.tpdo.is_empty() || !nc.rpdo.is_empty() {
        return Err(format!(
            "backs axis {}: its PDOs are set by the axis layer; remove the tpdo/rpdo entries",
            axis.name
        ));
    }
    let trigger = if sync {
        FeedbackTrigger::Sync
    } else {
        FeedbackTrigger::Event { event_timer_ms: 10 }
    };
    // The SDO fallback maps no PDO: whatever the drive's own PDOs carry is
    // left alone and not used.
    let (mut rpdos, mut tpdos) = match drive.process_data {
        ProcessDataPath::Pdo => {
            let (mut rpdos, tpdos) = standard_pdos(node, trigger);
            if drive.mode == cangate_axis::DriveMode::InterpolatedPosition {
                // A drive without CSP: the position set-point in 0x60C1:01.
                rpdos[1] = cangate_axis::process_data::interpolated_rpdo(node);
            }
            if drive.torque.in_process_data {
                // A torque axis: the target torque in RPDO3.
                rpdos.push(cangate_axis::process_data::torque_rpdo(node));
            } else if let Some(eds) = eds {
                // A position stream's feed-forward in RPDO3, where the
                // drive has a velocity offset (and the torque offset with
                // it, where it has one) and a third RPDO.
                let mappable = |addr| {
                    eds.od
                        .get(on_axis(addr, drive.drive_axis))
                        .is_some_and(|v| v.pdo_mappable)
                };
                let k = 2 + PDOS_PER_AXIS * u16::from(drive.drive_axis);
                let has_rpdo3 = eds.od.get(ObjectAddress::new(0x1400 + k, 1)).is_some()
                    && eds.od.get(ObjectAddress::new(0x1600 + k, 0)).is_some();
                if has_rpdo3 && mappable(cangate_canopen::cia402::objects::VELOCITY_OFFSET) {
                    rpdos.push(cangate_axis::process_data::feed_forward_rpdo(
                        node,
                        mappable(cangate_canopen::cia402::objects::TORQUE_OFFSET),
                    ));
                }
            }
            (rpdos, tpdos)
        }
        ProcessDataPath::Sdo { .. } => (Vec::new(), Vec::new()),
    };
    // The signals (torque, following error, switches, touch probe) where
    // the drive's EDS says it has them and PDOs to carry them: a mapping
    // write the drive aborts would fail its boot, so without an EDS there
    // are none.
    if let (ProcessDataPath::Pdo, Some(eds), true) = (drive.process_data, eds, drive.signal_pdos) {
        cangate_axis::process_data::with_signal_tpdos(
            &mut tpdos,
            node,
            trigger,
            |addr| {
                eds.od
                    .get(on_axis(addr, drive.drive_axis))
                    .is_some_and(|v| v.pdo_mappable)
            },
            |n| {
                // PDO n of the axis: 4 × drive_axis + n of the drive.
                let k = n - 1 + PDOS_PER_AXIS * u16::from(drive.drive_axis);
                eds.od.get(ObjectAddress::new(0x1800 + k, 1)).is_some()
                    && eds.od.get(ObjectAddress::new(0x1A00 + k, 0)).is_some()
            },
        );
    }
    // A further axis of a multi-axis drive: its own PDO numbers, objects
    // and COB-IDs.
    cangate_axis::process_data::relocate_to_axis(&mut tpdos, drive.drive_axis, block);
    cangate_axis::process_data::relocate_to_axis(&mut rpdos, drive.drive_axis, block);
    Ok((tpdos, rpdos))
}

/// The layouts of a node's PDOs of one kind: as configured, else (not
/// configured) the EDS defaults, which describe what the node sends.
fn pdo_layouts(
    kind: PdoKind,
    entries: &[crate::config::PdoConfigEntry],
    eds: Option<&Eds>,
    node: NodeId,
) -> Result<Vec<PdoConfig>, String> {
    if entries.is_empty() {
        return Ok(eds
            .map(|e| {
                (1..=4)
                    .filter_map(|n| PdoConfig::from_od(&e.od, kind, n, node))
                    .filter(|p| !p.is_empty())
                    .collect()
            })
            .unwrap_or_default());
    }
    entries.iter().map(|p| p.to_pdo(kind, node)).collect()
}

/// The node's configured boot writes (`[[canopen.node.write]]`), encoded.
fn configured_writes(nc: &NodeConfig) -> Result<Vec<(ObjectAddress, Vec<u8>)>, String> {
    nc.writes
        .iter()
        .map(|w| {
            let addr = parse_object(&w.object)?;
            let ty: DataType =
                w.ty.parse()
                    .map_err(|e| format!("write {}: {e}", w.object))?;
            let v = Value::parse(ty, &w.value).map_err(|e| format!("write {}: {e}", w.object))?;
            Ok((addr, v.encode()))
        })
        .collect()
}

/// The boot writes that let a guarded node watch the master's guarding
/// (life guarding): its guard time (0x100C, ms) and life time factor
/// (0x100D) as configured. Left out when the node's EDS does not have
/// both (a write the node aborts would fail its boot).
fn life_guarding_writes(nc: &NodeConfig, eds: Option<&Eds>) -> Vec<(ObjectAddress, Vec<u8>)> {
    let guard = ObjectAddress::new(0x100C, 0);
    let factor = ObjectAddress::new(0x100D, 0);
    let Some((guard_time, life_time_factor)) = nc.guarding() else {
        return Vec::new();
    };
    if !eds.is_some_and(|e| e.od.get(guard).is_some() && e.od.get(factor).is_some()) {
        tracing::info!(
            node = nc.id,
            "guarded node without 0x100C/0x100D in its EDS: its life guarding is not configured"
        );
        return Vec::new();
    }
    let ms = u16::try_from(guard_time.as_millis()).unwrap_or(u16::MAX);
    vec![
        (guard, ms.to_le_bytes().to_vec()),
        (factor, vec![life_time_factor]),
    ]
}

/// The boot writes of the node's `dcf` (its `ParameterValue`s, see
/// [`cangate_canopen::dcf::configuration_writes`]), first of the boot
/// procedure so that the configuration's own writes win.
fn dcf_writes(
    nc: &NodeConfig,
    node: NodeId,
    eds: Option<&Eds>,
) -> Result<Vec<(ObjectAddress, Vec<u8>)>, String> {
    let Some(dcf) = nc.load_dcf()? else {
        return Ok(Vec::new());
    };
    let path = nc.dcf.as_deref().unwrap_or_default();
    // The node's own EDS says what is configuration (without one, the
    // EDS was loaded from the DCF itself).
    let eds = eds.filter(|_| nc.eds.is_some()).map(|e| &e.od);
    let out = cangate_canopen::dcf::configuration_writes(&dcf.od, eds, node)
        .map_err(|e| format!("dcf {path:?}: {e}"))?;
    for (addr, why) in &out.skipped {
        tracing::warn!(node = node.get(), dcf = %path, object = %addr, "DCF value not written at boot: {why}");
    }
    Ok(out.writes)
}

/// The boot write that makes an axis drive watch the master's heartbeat:
/// 0x1016:01 = master node << 16 | consumer time in ms. Left out when the
/// drive's EDS is unknown or has no 0x1016:01 (a write it might abort would
/// fail its boot; warned).
fn master_heartbeat_consumer(
    eds: Option<&Eds>,
    master: Option<(u8, u16)>,
    axis: &AxisSpec,
) -> Option<(ObjectAddress, Vec<u8>)> {
    let (id, timeout_ms) = master?;
    let addr = ObjectAddress::new(0x1016, 1);
    if eds.is_none_or(|e| e.od.get(addr).is_none()) {
        tracing::warn!(
            axis = %axis.name,
            "no 0x1016:01 in the drive's EDS (or no EDS): it is not told to watch the \
             master's heartbeat and will not stop on its own if the gateway dies"
        );
        return None;
    }
    let value = (u32::from(id) << 16) | u32::from(timeout_ms);
    Some((addr, value.to_le_bytes().to_vec()))
}

fn open_bus(bc: &BusConfig, network: &VirtualNetwork) -> Result<(BusInfo, Backend), BootError> {
    let err = |message: String| BootError::Bus {
        bus: bc.name.clone(),
        message,
    };
    match bc.backend {
        BackendChoice::Socketcan => {
            let options = cangate_can::socketcan_bus::SocketCanOptions {
                receive_buffer: bc.receive_buffer,
                transmit_queue: bc
                    .transmit_queue
                    .unwrap_or(cangate_can::socketcan_bus::DEFAULT_TRANSMIT_QUEUE),
                transmit_timeout: bc
                    .transmit_timeout_ms
                    .map_or(cangate_can::socketcan_bus::DEFAULT_TRANSMIT_TIMEOUT, |ms| {
                        std::time::Duration::from_millis(ms.into())
                    }),
            };
            let bus =
                SocketCanBus::open_with(bc.interface(), options).map_err(|e| err(e.to_string()))?;
            let info = BusInfo {
                name: bc.name.clone(),
                kind: BackendKind::SocketCan,
                interface: bc.interface().to_string(),
                fd: bc.fd,
                bitrate: bc.bitrate,
                data_bitrate: bc.data_bitrate,
                bit_timed: false,
                stuffing: Stuffing::Exact,
            };
            Ok((info, Backend::SocketCan(bus)))
        }
        BackendChoice::Virtual => {
            let stuffing = match bc.stuffing {
                StuffingChoice::Exact => Stuffing::Exact,
                StuffingChoice::WorstCase => Stuffing::WorstCase,
            };
            let timing = bc.bit_timing.then(|| BitTiming {
                bitrate: bc.bitrate.unwrap_or(1_000_000),
                data_bitrate: bc.data_bitrate.or(bc.bitrate).unwrap_or(1_000_000),
                stuffing,
            });
            let vcfg = VirtualBusConfig {
                bit_timing: timing,
                fd: bc.fd,
                port_queue: bc.queue.unwrap_or(VirtualBusConfig::default().port_queue),
                seed: bc.fault_seed.unwrap_or(VirtualBusConfig::default().seed),
                rx_coalesce: std::time::Duration::from_micros(u64::from(bc.rx_coalesce_us)),
            };
            let vbus = network.bus(bc.interface(), vcfg);
            let info = BusInfo {
                name: bc.name.clone(),
                kind: BackendKind::Virtual,
                interface: bc.interface().to_string(),
                fd: bc.fd,
                bitrate: bc.bitrate,
                data_bitrate: bc.data_bitrate,
                bit_timed: bc.bit_timing,
                stuffing,
            };
            Ok((info, Backend::Virtual(vbus.connect(true))))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A start-up failure says by its variant what failed: here a bus
    /// whose interface does not exist.
    #[test]
    fn a_missing_interface_is_a_bus_boot_error() {
        let config = Config::from_toml(
            "[[bus]]\nname = \"can0\"\nbackend = \"socketcan\"\ninterface = \"nosuchcan7\"\n",
        )
        .expect("valid configuration");
        let Err(e) = Gateway::start(&config, CancellationToken::new()) else {
            panic!("a missing interface starts");
        };
        assert!(
            matches!(&e, BootError::Bus { bus, .. } if bus == "can0"),
            "{e:?}"
        );
        assert!(e.to_string().starts_with("bus \"can0\": "), "{e}");
    }

    /// The boot plan of an axis's drive: the signal TPDOs where the EDS
    /// has them (unless switched off), the supervision objects with their
    /// exact bytes.
    #[test]
    fn axis_drive_boot_plan_maps_the_signals_and_writes_the_supervision() {
        let plan = |axis_extra: &str, eds: bool| {
            let text = format!(
                "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\n[[canopen]]\nbus = \"can0\"\n\
                 sync_period_us = 10000\n[[canopen.node]]\nid = 1\n{}\
                 [[axis]]\nname = \"X\"\nbus = \"can0\"\nnode = 1\ncounts_per_unit = 1000.0\n\
                 max_velocity = 100.0\nmax_acceleration = 1000.0\n{axis_extra}",
                if eds {
                    "eds = \"builtin:drive\"\nsimulate = true\n"
                } else {
                    ""
                }
            );
            let config = Config::from_toml(&text).expect("valid configuration");
            let cc = &config.canopen[0];
            let nc = &cc.nodes[0];
            let eds = eds.then(|| {
                cangate_canopen::eds::Eds::parse(cangate_canopen::eds::SIM_DRIVE_EDS).unwrap()
            });
            let axis = AxisSpec::try_from(&config.axes[0]).unwrap();
            let node = NodeId::new(1).unwrap();
            node_plan(
                nc,
                node,
                eds.as_ref(),
                &[(axis, 0)],
                Some(std::time::Duration::from_millis(10)),
                None,
            )
            .unwrap()
        };
        let (tpdos, _, boot) = plan(
            "following_error_window = 0.5\nfollowing_error_timeout_ms = 20\nmax_torque = 1500\n\
             signal_pdos = true\n",
            true,
        );
        let cobs: Vec<u16> = tpdos.iter().map(|p| p.cob_id).collect();
        assert_eq!(cobs, [0x181, 0x281, 0x381, 0x481]);
        let writes = &boot.expect("a boot plan").writes;
        for (addr, bytes) in [
            (ObjectAddress::new(0x6065, 0), vec![0xF4, 0x01, 0x00, 0x00]),
            (ObjectAddress::new(0x6066, 0), vec![0x14, 0x00]),
            (ObjectAddress::new(0x6072, 0), vec![0xDC, 0x05]),
            (ObjectAddress::new(0x1A02, 2), vec![0x20, 0x00, 0xFD, 0x60]),
        ] {
            assert!(
                writes.contains(&(addr, bytes.clone())),
                "{addr} {bytes:02X?} in {writes:?}"
            );
        }
        for off in ["signal_pdos = false\n", ""] {
            let (tpdos, _, _) = plan(off, true);
            assert_eq!(tpdos.len(), 2, "{off:?}: no signals (off by default)");
            assert_eq!(tpdos[1].mapping.len(), 1);
        }
        let (tpdos, _, _) = plan("signal_pdos = true\n", false);
        assert_eq!(tpdos.len(), 2, "no EDS: no signals");
    }

    /// Two axes of one drive node (CiA 402 multi-axis): the first keeps
    /// PDOs 1..=4 on the predefined COB-IDs, the second gets PDOs 5..=8
    /// on the first further-axis block (0x680..0x687) mapping its objects
    /// at + 0x800; its boot writes and its mode check are its own.
    #[test]
    fn a_two_axis_drive_gets_distinct_pdos_and_objects_per_axis() {
        let text = "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\n[[canopen]]\nbus = \"can0\"\n\
             sync_period_us = 10000\n[[canopen.node]]\nid = 3\neds = \"builtin:drive2\"\n\
             simulate = true\n\
             [[axis]]\nname = \"A\"\nbus = \"can0\"\nnode = 3\ncounts_per_unit = 1000.0\n\
             max_velocity = 100.0\nmax_acceleration = 1000.0\nsignal_pdos = true\n\
             [[axis]]\nname = \"B\"\nbus = \"can0\"\nnode = 3\ndrive_axis = 1\n\
             counts_per_unit = 1000.0\nmax_velocity = 100.0\nmax_acceleration = 1000.0\n\
             min_position = -10.0\nmax_position = 10.0\nsignal_pdos = true\nmode = \"csp\"\n";
        let config = Config::from_toml(text).expect("valid configuration");
        let cc = &config.canopen[0];
        let nc = &cc.nodes[0];
        let (eds, _) = nc.load_eds().unwrap().unwrap();
        let axes: Vec<(AxisSpec, u16)> = config
            .axes
            .iter()
            .map(|a| {
                (
                    AxisSpec::try_from(a).unwrap(),
                    further_axis_block(&config, cc, a),
                )
            })
            .collect();
        assert_eq!(axes[1].1, 0, "the bus's first further axis");
        let node = NodeId::new(3).unwrap();
        let (tpdos, rpdos, boot) = node_plan(
            nc,
            node,
            Some(&eds),
            &axes,
            Some(std::time::Duration::from_millis(10)),
            None,
        )
        .unwrap();
        let ids = |l: &[PdoConfig]| l.iter().map(|p| (p.num, p.cob_id)).collect::<Vec<_>>();
        assert_eq!(
            ids(&tpdos),
            [
                (1, 0x183),
                (2, 0x283),
                (3, 0x383),
                (4, 0x483),
                (5, 0x684),
                (6, 0x685),
                (7, 0x686),
                (8, 0x687)
            ]
        );
        // RPDO3 and RPDO7 carry each axis's feed-forward (0x60B1/0x60B2
        // and 0x68B1/0x68B2): the drive's EDS has them.
        assert_eq!(
            ids(&rpdos),
            [
                (1, 0x203),
                (2, 0x303),
                (3, 0x403),
                (5, 0x680),
                (6, 0x681),
                (7, 0x682)
            ]
        );
        let boot = boot.expect("a boot plan");
        for (addr, bytes) in [
            // RPDO5 maps axis 1's controlword, TPDO7 its digital inputs.
            (ObjectAddress::new(0x1604, 1), vec![0x10, 0x00, 0x40, 0x68]),
            // RPDO7 maps axis 1's velocity offset first.
            (ObjectAddress::new(0x1606, 1), vec![0x20, 0x00, 0xB1, 0x68]),
            (ObjectAddress::new(0x1A06, 2), vec![0x20, 0x00, 0xFD, 0x68]),
            (ObjectAddress::new(0x1804, 1), vec![0x84, 0x06, 0x00, 0x00]),
            // Its soft limits and homing method.
            (
                ObjectAddress::new(0x687D, 2),
                10_000i32.to_le_bytes().to_vec(),
            ),
            (ObjectAddress::new(0x6898, 0), vec![35]),
            (ObjectAddress::new(0x6098, 0), vec![35]),
        ] {
            assert!(
                boot.writes.contains(&(addr, bytes.clone())),
                "{addr} {bytes:02X?} in {:?}",
                boot.writes
            );
        }
        assert!(
            !boot.writes.iter().any(|(a, _)| a.index == 0x607D),
            "axis A has no soft limits: only B's went out"
        );
        assert_eq!(boot.required_modes.len(), 2);
        assert_eq!(boot.required_modes[1].0, 1);
    }
}
