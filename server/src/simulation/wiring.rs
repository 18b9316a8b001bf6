//! Start-up wiring of the simulated devices a configuration asks for
//! (`simulate = true` on a CANopen node or a CANsmc slave): which model
//! each node gets, and where each runs.

use super::SimulatedDevice;
use crate::config::{
    BackendChoice, BusConfig, CansmcConfig, CounterChoice, NodeConfig, SimDeviceConfig, SimStart,
};
use cangate_can::{VirtualBus, VirtualNetwork, VirtualPort};
use cangate_canopen::cia402::ModeOfOperation;
use cangate_canopen::eds::Eds;
use cangate_canopen::handwheel::CounterLayout;
use cangate_canopen::lss::LssIdentity;
use cangate_canopen::nmt::NmtState;
use cangate_canopen::{NodeId, ObjectAddress};
use cangate_sim::cansmc_runner::CansmcSlaveHandle;
use cangate_sim::{
    DeviceHandle, SimDrive, SimDriveOptions, SimHandwheel, SimHandwheelOptions, SimNode,
    SimNodeOptions,
};
use std::sync::Arc;
use std::time::Duration;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

/// The simulated device of configured node `nc` from its EDS: a handwheel
/// for the built-in handwheel EDS (its feed counter laid out as the
/// `[[handwheel]]` on it says), a CiA 402 drive for a device profile 402
/// (0x1000 low word 0x0192), else a plain CiA 301 node.
pub fn canopen_device(
    nc: &NodeConfig,
    node: NodeId,
    eds: Arc<Eds>,
    wheel_counter: Option<CounterChoice>,
) -> SimulatedDevice {
    // The device's heartbeat comes at a third of the consumer timeout
    // (100 ms when none is configured), so one late frame is not a loss. A
    // guarded node produces none: it answers the master's guarding
    // requests instead (CiA 301: heartbeat or node guarding). `sim`
    // overrides it.
    let sim = nc.sim.clone().unwrap_or(SimDeviceConfig {
        start: SimStart::Boot,
        heartbeat_ms: None,
        node_guarding: true,
        refuses_nmt_start: false,
        mode: 8,
        position: 0,
        negative_limit_switch: None,
        positive_limit_switch: None,
        home_switch: None,
        touch_probe: None,
    });
    let heartbeat_ms = match nc.heartbeat_timeout_ms {
        _ if sim.heartbeat_ms.is_some() => sim.heartbeat_ms.unwrap_or_default(),
        _ if nc.guarding().is_some() => 0,
        0 => 100,
        t => (t / 3).clamp(1, u16::MAX as u64) as u16,
    };
    let eds_u32 = |sub: u8| {
        eds.od
            .get(ObjectAddress::new(0x1018, sub))
            .and_then(|v| v.default_for_node(node))
            .and_then(|v| v.as_u32())
            .unwrap_or(0)
    };
    let lss = nc.sim_lss.as_ref().map(|l| LssIdentity {
        vendor_id: l.vendor_id.unwrap_or_else(|| eds_u32(1)),
        product_code: l.product_code.unwrap_or_else(|| eds_u32(2)),
        revision: l.revision.unwrap_or_else(|| eds_u32(3)),
        serial: l.serial,
    });
    let options = SimNodeOptions {
        heartbeat_ms: Some(heartbeat_ms),
        lss,
        lss_unconfigured: nc.sim_lss.as_ref().is_some_and(|l| !l.configured),
        lss_fastscan_until_configured: nc
            .sim_lss
            .as_ref()
            .is_some_and(|l| l.fastscan_until_configured),
        running_at_start: match sim.start {
            SimStart::Boot => None,
            SimStart::PreOperational => Some(NmtState::PreOperational),
            SimStart::Operational | SimStart::OperationEnabled => Some(NmtState::Operational),
        },
        refuses_nmt_start: sim.refuses_nmt_start,
        node_guarding: sim.node_guarding,
        ..SimNodeOptions::default()
    };
    if nc.eds.as_deref() == Some("builtin:handwheel") {
        let layout = match wheel_counter.unwrap_or_default() {
            CounterChoice::Nibble => CounterLayout::Nibble,
            CounterChoice::Bits67 => CounterLayout::Bits6_7,
        };
        return SimulatedDevice::Handwheel(DeviceHandle::new(SimHandwheel::new(
            &eds,
            node,
            SimHandwheelOptions {
                node: options,
                layout,
                ..Default::default()
            },
        )));
    }
    let device_type = eds
        .od
        .get(ObjectAddress::new(0x1000, 0))
        .and_then(|v| v.default_for_node(node))
        .and_then(|v| v.as_u32())
        .unwrap_or(0);
    if device_type & 0xFFFF == 402 {
        SimulatedDevice::Drive(DeviceHandle::new(SimDrive::new(
            &eds,
            node,
            SimDriveOptions {
                node: options,
                enabled_at_start: (sim.start == SimStart::OperationEnabled)
                    .then(|| ModeOfOperation::from_code(sim.mode))
                    .flatten()
                    .map(|mode| (mode, sim.position)),
                inputs: cangate_sim::SimDriveInputs {
                    negative_limit_switch: sim.negative_limit_switch,
                    positive_limit_switch: sim.positive_limit_switch,
                    home_switch: sim.home_switch,
                    touch_probe: sim.touch_probe,
                },
                ..SimDriveOptions::default()
            },
        )))
    } else {
        SimulatedDevice::Node(DeviceHandle::new(SimNode::new(&eds, node, options)))
    }
}

/// Runs `device` on `port` (a task on the current runtime) until `cancel`.
pub fn spawn(
    port: VirtualPort,
    device: SimulatedDevice,
    cancel: CancellationToken,
) -> JoinHandle<()> {
    match device {
        SimulatedDevice::Node(h) => cangate_sim::spawn_device(port, h, cancel),
        SimulatedDevice::Drive(h) => cangate_sim::spawn_device(port, h, cancel),
        SimulatedDevice::Handwheel(h) => cangate_sim::spawn_device(port, h, cancel),
    }
}

/// Starts the simulated slaves of CANsmc master `mc` (none: nothing
/// starts) on the virtual buses `virtual_bus` finds by bus name. They
/// stand for other hardware, so they get a thread of their own and
/// neither load nor wait for the gateway's bus thread. They attach before
/// the master's first MCT.
pub fn start_cansmc_slaves(
    mc: &CansmcConfig,
    virtual_bus: impl Fn(&str) -> Option<VirtualBus>,
    cancel: CancellationToken,
) -> Result<Vec<CansmcSlaveHandle>, String> {
    let slaves: Vec<CansmcSlaveHandle> = mc
        .slaves
        .iter()
        .filter(|s| s.simulate)
        .map(super::cansmc_slaves::slave_for)
        .collect::<Result<_, _>>()?;
    if slaves.is_empty() {
        return Ok(slaves);
    }
    let port = |name: &str| {
        virtual_bus(name)
            .map(|b| b.connect(false))
            .ok_or_else(|| "simulated slaves need virtual buses".to_string())
    };
    let ch0 = port(&mc.command_bus)?;
    let ch1 = port(&mc.status_bus)?;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .map_err(|e| format!("simulated slaves: {e}"))?;
    let runner_slaves = slaves.clone();
    std::thread::Builder::new()
        .name(format!("sim-{}", mc.name))
        .spawn(move || {
            rt.block_on(async move {
                let runner = cangate_sim::cansmc_runner::spawn_cansmc_slaves(
                    ch0,
                    ch1,
                    runner_slaves,
                    cancel,
                );
                let _ = runner.await;
            });
        })
        .map_err(|e| format!("simulated slaves: {e}"))?;
    Ok(slaves)
}

/// The run-time simulation of `buses`: every bus known (with its virtual
/// bus, if it is one) and the configured faults (`drop_probability`,
/// `drop_ids`, `delay_us`) applied. An error names the bus.
pub fn bus_faults(
    buses: &[BusConfig],
    network: &VirtualNetwork,
) -> Result<super::Simulation, (String, String)> {
    let mut simulation = super::Simulation::new();
    for bc in buses {
        let vbus = (bc.backend == BackendChoice::Virtual)
            .then(|| network.get(bc.interface()))
            .flatten();
        simulation.add_bus(&bc.name, vbus);
        if bc.has_faults() {
            simulation
                .set_faults(
                    &bc.name,
                    super::BusFaults {
                        drop_probability: bc.drop_probability.unwrap_or(0.0),
                        drop_ids: bc.drop_ids.clone(),
                        delay: Duration::from_micros(bc.delay_us.unwrap_or(0)),
                    },
                )
                .map_err(|e| (bc.name.clone(), e.to_string()))?;
        }
    }
    Ok(simulation)
}
