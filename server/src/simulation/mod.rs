//! The gateway's simulated CANopen devices and the fault injection of its
//! virtual buses, at run time (the Simulator service and `cangate sim …`
//! call these; the configuration's `drop_probability`, `drop_ids`,
//! `delay_us` and `fault_seed` set the start values).
//!
//! Bus faults act on the virtual bus itself, so every participant (the
//! gateway, every simulated device, a test's own port) sees the same
//! losses and delays. Device faults act on one simulated device as the
//! real failure would: a power cut silences it and it boots with its
//! power-on defaults; an EMCY or a drive fault goes out on the bus; I/O
//! inputs change the objects its TPDOs carry.
//!
//! [`wiring`] creates the simulated devices of a configuration at start-up
//! and runs them; [`cansmc_slaves`] builds the simulated CANsmc slaves.

pub mod cansmc_slaves;
pub mod wiring;

use cangate_can::{BusState, VirtualBus};
use cangate_canopen::NodeId;
use cangate_canopen::nmt::NmtState;
use cangate_canopen::value::Value;
use cangate_canopen::{ObjectAddress, emcy::ErrorRegister};
use cangate_sim::program::{ProgramFaults, SimProgram};
use cangate_sim::{DeviceHandle, PowerOn, SimDrive, SimHandwheel, SimNode};
use std::collections::BTreeMap;
use std::sync::Mutex;
use std::time::Duration;

use crate::config::MAX_FAULT_DELAY_US;

/// Digital inputs, 8 bits per sub-index (CiA 401).
const DIGITAL_INPUTS: u16 = 0x6000;
/// Analogue inputs, 16 bits per sub-index (CiA 401).
const ANALOGUE_INPUTS: u16 = 0x6401;
/// The longest power cut.
pub const MAX_POWER_CUT: Duration = Duration::from_secs(60);
/// TPDOs triggered after the inputs changed (event-driven ones go out).
const TPDOS: u16 = 4;

/// A simulated CANopen device, by what it is.
#[derive(Clone)]
pub enum SimulatedDevice {
    /// A CiA 301 node from its EDS (e.g. the I/O node).
    Node(DeviceHandle<SimNode>),
    /// A CiA 402 drive.
    Drive(DeviceHandle<SimDrive>),
    /// A handwheel.
    Handwheel(DeviceHandle<SimHandwheel>),
}

/// What a simulated device is, for people.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceKind {
    /// [`SimulatedDevice::Node`].
    Node,
    /// [`SimulatedDevice::Drive`].
    Drive,
    /// [`SimulatedDevice::Handwheel`].
    Handwheel,
}

impl DeviceKind {
    fn name(self) -> &'static str {
        match self {
            DeviceKind::Node => "CANopen node",
            DeviceKind::Drive => "CiA 402 drive",
            DeviceKind::Handwheel => "handwheel",
        }
    }
}

/// A simulated device's state now.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceState {
    /// The bus.
    pub bus: String,
    /// The node id.
    pub node: u8,
    /// What it is.
    pub kind: DeviceKind,
    /// False during a power cut.
    pub powered: bool,
    /// Its NMT state (`None` while unpowered).
    pub nmt: Option<NmtState>,
}

/// The drop and delay faults of a virtual bus.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BusFaults {
    /// Each frame is dropped with this probability (0..=1).
    pub drop_probability: f64,
    /// Frames with these identifiers are dropped.
    pub drop_ids: Vec<u32>,
    /// Every delivery is this late.
    pub delay: Duration,
}

/// A virtual bus's faults now.
#[derive(Debug, Clone, PartialEq)]
pub struct BusFaultState {
    /// The bus.
    pub bus: String,
    /// Drop and delay.
    pub faults: BusFaults,
    /// Forced bus-off.
    pub bus_off: bool,
    /// Frames dropped by fault injection so far.
    pub dropped_by_fault: u64,
}

/// Why a simulation request cannot be carried out.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimulationError {
    /// No bus of that name.
    #[error("no bus {bus:?} (buses: {known})")]
    NoBus {
        /// The name asked for.
        bus: String,
        /// The configured buses.
        known: String,
    },
    /// The bus is not a virtual bus.
    #[error("bus {0:?} is not a virtual bus: faults can be injected only into virtual buses")]
    NotVirtual(String),
    /// No simulated device there.
    #[error("no simulated device at node {node} on bus {bus:?} (simulated: {known})")]
    NoDevice {
        /// The bus.
        bus: String,
        /// The node id asked for.
        node: u32,
        /// The simulated devices.
        known: String,
    },
    /// The device cannot do that.
    #[error("node {node} on bus {bus:?} is a simulated {kind}: {what}")]
    Unsupported {
        /// The bus.
        bus: String,
        /// The node id.
        node: u8,
        /// What the device is.
        kind: &'static str,
        /// What it cannot do, and why.
        what: String,
    },
    /// The device's power is cut, or its NMT state forbids it.
    #[error("node {node} on bus {bus:?}: {why}")]
    NotNow {
        /// The bus.
        bus: String,
        /// The node id.
        node: u8,
        /// Why not now.
        why: String,
    },
    /// A value out of range.
    #[error("{0}")]
    Invalid(String),
}

/// Simulated devices and virtual buses of a gateway. See the [module
/// documentation](self).
#[derive(Default)]
pub struct Simulation {
    /// Every bus by name; `None` for buses that are not virtual.
    buses: BTreeMap<String, Option<SimBus>>,
    devices: BTreeMap<(String, u8), SimulatedDevice>,
}

struct SimBus {
    bus: VirtualBus,
    faults: Mutex<BusFaults>,
}

impl Simulation {
    /// Nothing simulated yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Registers a bus (`None`: not virtual).
    pub fn add_bus(&mut self, name: &str, bus: Option<VirtualBus>) {
        self.buses.insert(
            name.to_string(),
            bus.map(|bus| SimBus {
                bus,
                faults: Mutex::new(BusFaults::default()),
            }),
        );
    }

    /// Registers a simulated device.
    pub fn add_device(&mut self, bus: &str, node: NodeId, device: SimulatedDevice) {
        self.devices.insert((bus.to_string(), node.get()), device);
    }

    /// Whether there is anything to simulate (a virtual bus or a device).
    pub fn is_empty(&self) -> bool {
        self.devices.is_empty() && self.buses.values().all(Option::is_none)
    }

    /// Every simulated device, by bus and node.
    pub fn devices(&self) -> Vec<DeviceState> {
        self.devices
            .iter()
            .map(|((bus, node), d)| state(bus, *node, d))
            .collect()
    }

    fn virtual_bus(&self, bus: &str) -> Result<&SimBus, SimulationError> {
        match self.buses.get(bus) {
            Some(Some(b)) => Ok(b),
            Some(None) => Err(SimulationError::NotVirtual(bus.to_string())),
            None => Err(SimulationError::NoBus {
                bus: bus.to_string(),
                known: list(self.buses.keys().cloned()),
            }),
        }
    }

    fn device(&self, bus: &str, node: u32) -> Result<(u8, &SimulatedDevice), SimulationError> {
        if !self.buses.contains_key(bus) {
            return Err(SimulationError::NoBus {
                bus: bus.to_string(),
                known: list(self.buses.keys().cloned()),
            });
        }
        let found = u8::try_from(node)
            .ok()
            .and_then(|n| self.devices.get(&(bus.to_string(), n)).map(|d| (n, d)));
        found.ok_or_else(|| SimulationError::NoDevice {
            bus: bus.to_string(),
            node,
            known: list(self.devices.keys().map(|(b, n)| format!("{b} node {n}"))),
        })
    }

    /// Replaces the drop and delay faults of a virtual bus.
    pub fn set_faults(
        &self,
        bus: &str,
        faults: BusFaults,
    ) -> Result<BusFaultState, SimulationError> {
        let b = self.virtual_bus(bus)?;
        check_faults(&faults)?;
        b.bus.set_drop_probability(faults.drop_probability);
        b.bus.set_drop_ids(faults.drop_ids.iter().copied());
        b.bus.set_delay(faults.delay);
        *b.faults.lock().expect("faults lock") = faults;
        self.faults(bus)
    }

    /// The faults of a virtual bus now.
    pub fn faults(&self, bus: &str) -> Result<BusFaultState, SimulationError> {
        let b = self.virtual_bus(bus)?;
        Ok(BusFaultState {
            bus: bus.to_string(),
            faults: b.faults.lock().expect("faults lock").clone(),
            bus_off: b.bus.status().state == BusState::BusOff,
            dropped_by_fault: b.bus.stats().dropped_by_fault,
        })
    }

    /// Forces a virtual bus off, or recovers it.
    pub fn set_bus_off(&self, bus: &str, off: bool) -> Result<BusFaultState, SimulationError> {
        let b = self.virtual_bus(bus)?;
        if off {
            b.bus.force_bus_off();
        } else {
            b.bus.recover();
        }
        self.faults(bus)
    }

    /// Cuts a device's power for `off` (see [`DeviceHandle::power_cycle`]).
    pub fn power_cycle(
        &self,
        bus: &str,
        node: u32,
        off: Duration,
    ) -> Result<DeviceState, SimulationError> {
        if off > MAX_POWER_CUT {
            return Err(SimulationError::Invalid(format!(
                "a power cut of {} ms is longer than the {} ms allowed",
                off.as_millis(),
                MAX_POWER_CUT.as_millis()
            )));
        }
        let (n, device) = self.device(bus, node)?;
        match device {
            SimulatedDevice::Node(h) => h.power_cycle(off, |d| *d = d.powered_on()),
            SimulatedDevice::Drive(h) => h.power_cycle(off, |d| *d = d.powered_on()),
            SimulatedDevice::Handwheel(h) => h.power_cycle(off, |d| *d = d.powered_on()),
        }
        Ok(state(bus, n, device))
    }

    /// Makes a device send an EMCY with `code`, setting its error register.
    pub fn send_emcy(
        &self,
        bus: &str,
        node: u32,
        code: u16,
        register: u8,
        manufacturer: [u8; 5],
    ) -> Result<DeviceState, SimulationError> {
        let (n, device) = self.device(bus, node)?;
        powered(bus, n, device)?;
        let register = if code != 0 && register == 0 {
            ErrorRegister::GENERIC
        } else {
            register
        };
        let sent = match device {
            SimulatedDevice::Node(h) => emit(h, |d| d.inject_emcy(code, register, manufacturer)),
            SimulatedDevice::Drive(h) => emit(h, |d| {
                d.node_mut().inject_emcy(code, register, manufacturer)
            }),
            SimulatedDevice::Handwheel(h) => emit(h, |d| {
                d.node_mut().inject_emcy(code, register, manufacturer)
            }),
        };
        if !sent {
            return Err(SimulationError::NotNow {
                bus: bus.to_string(),
                node: n,
                why: "it may not send an EMCY now (stopped, or its EMCY COB-ID is invalid)".into(),
            });
        }
        Ok(state(bus, n, device))
    }

    /// Arms the program download faults of a device (replacing those
    /// armed); returns its program state after.
    pub fn set_program_faults(
        &self,
        bus: &str,
        node: u32,
        faults: ProgramFaults,
    ) -> Result<SimProgram, SimulationError> {
        let (_, device) = self.device(bus, node)?;
        Ok(match device {
            SimulatedDevice::Node(h) => h.with(|d| {
                d.set_program_faults(faults);
                d.program().clone()
            }),
            SimulatedDevice::Drive(h) => h.with(|d| {
                d.node_mut().set_program_faults(faults);
                d.node().program().clone()
            }),
            SimulatedDevice::Handwheel(h) => h.with(|d| {
                d.node_mut().set_program_faults(faults);
                d.node().program().clone()
            }),
        })
    }

    /// Raises a fault with `code` in a simulated drive.
    pub fn raise_drive_fault(
        &self,
        bus: &str,
        node: u32,
        code: u16,
    ) -> Result<DeviceState, SimulationError> {
        let (n, device) = self.device(bus, node)?;
        if code < 0x1000 {
            return Err(SimulationError::Invalid(format!(
                "{code:#06x} is no fault code (0x1000..=0xFFFF; 0x0000 is \"error reset\")"
            )));
        }
        let SimulatedDevice::Drive(h) = device else {
            return Err(unsupported(
                bus,
                n,
                device,
                "only a CiA 402 drive has drive faults",
            ));
        };
        powered(bus, n, device)?;
        h.send_with(|d| d.inject_fault(code));
        Ok(state(bus, n, device))
    }

    /// Sets the inputs of a simulated I/O node: `digital` into 0x6000 sub
    /// 1, 2, … and `analogue` into 0x6401 sub 1, 2, …, then triggers its
    /// event-driven TPDOs. Returns the inputs now.
    pub fn set_io_inputs(
        &self,
        bus: &str,
        node: u32,
        digital: &[u8],
        analogue: &[i16],
    ) -> Result<(DeviceState, Vec<u8>, Vec<i16>), SimulationError> {
        let (n, device) = self.device(bus, node)?;
        let SimulatedDevice::Node(h) = device else {
            return Err(unsupported(
                bus,
                n,
                device,
                "inputs are set on a simulated I/O node (CiA 401 objects 0x6000/0x6401)",
            ));
        };
        powered(bus, n, device)?;
        let result = h.with(|d| {
            let subs = |d: &SimNode, index: u16| -> usize {
                (1..=u8::MAX)
                    .take_while(|&s| d.get(ObjectAddress::new(index, s)).is_some())
                    .count()
            };
            let (nd, na) = (subs(d, DIGITAL_INPUTS), subs(d, ANALOGUE_INPUTS));
            if digital.len() > nd || analogue.len() > na {
                return Err(format!(
                    "it has {nd} digital input bytes (0x6000) and {na} analogue inputs \
                     (0x6401); got {} and {}",
                    digital.len(),
                    analogue.len()
                ));
            }
            for (i, &v) in digital.iter().enumerate() {
                let addr = ObjectAddress::new(DIGITAL_INPUTS, i as u8 + 1);
                d.set(addr, Value::Unsigned8(v))
                    .map_err(|e| e.to_string())?;
            }
            for (i, &v) in analogue.iter().enumerate() {
                let addr = ObjectAddress::new(ANALOGUE_INPUTS, i as u8 + 1);
                d.set(addr, Value::Integer16(v))
                    .map_err(|e| e.to_string())?;
            }
            for pdo in 1..=TPDOS {
                d.trigger_tpdo(pdo);
            }
            let now_digital = (1..=nd as u8)
                .filter_map(|s| match d.get(ObjectAddress::new(DIGITAL_INPUTS, s)) {
                    Some(Value::Unsigned8(v)) => Some(*v),
                    _ => None,
                })
                .collect();
            let now_analogue = (1..=na as u8)
                .filter_map(|s| match d.get(ObjectAddress::new(ANALOGUE_INPUTS, s)) {
                    Some(Value::Integer16(v)) => Some(*v),
                    _ => None,
                })
                .collect();
            Ok((now_digital, now_analogue))
        });
        let (digital, analogue) = result.map_err(|what| SimulationError::Unsupported {
            bus: bus.to_string(),
            node: n,
            kind: DeviceKind::Node.name(),
            what,
        })?;
        Ok((state(bus, n, device), digital, analogue))
    }
}

fn check_faults(f: &BusFaults) -> Result<(), SimulationError> {
    if !(0.0..=1.0).contains(&f.drop_probability) {
        return Err(SimulationError::Invalid(format!(
            "drop_probability {} is not a probability (0..=1)",
            f.drop_probability
        )));
    }
    if let Some(id) = f.drop_ids.iter().find(|&&id| id > 0x1FFF_FFFF) {
        return Err(SimulationError::Invalid(format!(
            "drop id {id:#x} is no CAN identifier (at most 0x1FFFFFFF)"
        )));
    }
    if f.delay > Duration::from_micros(MAX_FAULT_DELAY_US) {
        return Err(SimulationError::Invalid(format!(
            "a delay of {} µs exceeds {MAX_FAULT_DELAY_US} µs (10 s)",
            f.delay.as_micros()
        )));
    }
    Ok(())
}

/// Runs `f` and sends the frame it returns; false when it returned none.
fn emit<D: cangate_sim::Device>(
    h: &DeviceHandle<D>,
    f: impl FnOnce(&mut D) -> Option<cangate_can::Frame>,
) -> bool {
    let mut sent = false;
    h.send_with(|d| {
        let frame = f(d);
        sent = frame.is_some();
        frame
    });
    sent
}

fn kind(d: &SimulatedDevice) -> DeviceKind {
    match d {
        SimulatedDevice::Node(_) => DeviceKind::Node,
        SimulatedDevice::Drive(_) => DeviceKind::Drive,
        SimulatedDevice::Handwheel(_) => DeviceKind::Handwheel,
    }
}

fn state(bus: &str, node: u8, d: &SimulatedDevice) -> DeviceState {
    let (powered, nmt) = match d {
        SimulatedDevice::Node(h) => (h.is_powered(), h.with(|d| d.nmt_state())),
        SimulatedDevice::Drive(h) => (h.is_powered(), h.with(|d| d.node().nmt_state())),
        SimulatedDevice::Handwheel(h) => (h.is_powered(), h.with(|d| d.node().nmt_state())),
    };
    DeviceState {
        bus: bus.to_string(),
        node,
        kind: kind(d),
        powered,
        nmt: powered.then_some(nmt),
    }
}

fn powered(bus: &str, node: u8, d: &SimulatedDevice) -> Result<(), SimulationError> {
    let on = match d {
        SimulatedDevice::Node(h) => h.is_powered(),
        SimulatedDevice::Drive(h) => h.is_powered(),
        SimulatedDevice::Handwheel(h) => h.is_powered(),
    };
    if on {
        Ok(())
    } else {
        Err(SimulationError::NotNow {
            bus: bus.to_string(),
            node,
            why: "its power is cut (power cycle in progress)".into(),
        })
    }
}

fn unsupported(bus: &str, node: u8, d: &SimulatedDevice, what: &str) -> SimulationError {
    SimulationError::Unsupported {
        bus: bus.to_string(),
        node,
        kind: kind(d).name(),
        what: what.to_string(),
    }
}

fn list(items: impl Iterator<Item = String>) -> String {
    let v: Vec<String> = items.collect();
    if v.is_empty() {
        "none".into()
    } else {
        v.join(", ")
    }
}
