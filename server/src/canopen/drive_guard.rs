//! Which node drives which axis, and whether that axis is active now: the
//! register that keeps commissioning operations (raw SDO writes to the
//! drive's process objects, program download, LSS) off a drive whose axis
//! is enabled or moving.
//!
//! The axes runtime registers each CiA 402 axis's drive when its task
//! starts ([`DriveGuard::register`]) and publishes the axis's state with
//! every status it publishes ([`DriveRegistration::publish`]); the CANopen
//! operations ask [`CanopenBus::check_drive_idle`] before they touch the
//! node. Publishing is one atomic store, so the axis task's hot path pays
//! nothing for it; asking takes a read lock on a small map.

use super::CanopenBus;
use cangate_canopen::cia402::DriveState;
use cangate_canopen::{NodeId, ObjectAddress};
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, RwLock};

/// The CiA 402 objects through which a master commands a drive's motion:
/// controlword, mode of operation, target position, target velocity,
/// target torque. Only the axis writes them while it is enabled.
pub const DRIVE_PROCESS_OBJECTS: [u16; 5] = [0x6040, 0x6060, 0x607A, 0x60FF, 0x6071];

/// The CiA 302-3 program objects (program data, program control): writing
/// them stops, clears or replaces the drive's firmware.
pub const PROGRAM_OBJECTS: [u16; 2] = [0x1F50, 0x1F51];

/// Whether a raw SDO write to `addr` of an axis's drive would command the
/// drive behind the axis's back.
pub fn commands_the_drive(addr: ObjectAddress) -> bool {
    DRIVE_PROCESS_OBJECTS.contains(&addr.index) || PROGRAM_OBJECTS.contains(&addr.index)
}

#[derive(Debug)]
struct Drive {
    axis: String,
    active: AtomicBool,
}

/// The axes' drives of one bus, by node.
#[derive(Debug, Default)]
pub struct DriveGuard {
    drives: RwLock<BTreeMap<NodeId, Arc<Drive>>>,
}

/// One axis's entry in the [`DriveGuard`]; the axis publishes its state
/// through it.
#[derive(Debug, Clone)]
pub struct DriveRegistration(Arc<Drive>);

impl DriveRegistration {
    /// Publishes the axis's state: active while the drive is in operation
    /// enabled, quick stop or fault reaction (its power stage controls the
    /// motor), and while the axis is doing anything but resting (walking
    /// the state machine, homing, moving, stopping).
    pub fn publish(&self, state: Option<DriveState>, at_rest: bool) {
        let powered = matches!(
            state,
            Some(
                DriveState::OperationEnabled
                    | DriveState::QuickStopActive
                    | DriveState::FaultReactionActive
            )
        );
        self.0.active.store(powered || !at_rest, Ordering::Release);
    }
}

impl DriveGuard {
    /// Registers node `node` as the drive of `axis` (inactive until the
    /// axis publishes otherwise).
    pub fn register(&self, node: NodeId, axis: &str) -> DriveRegistration {
        let drive = Arc::new(Drive {
            axis: axis.to_string(),
            active: AtomicBool::new(false),
        });
        self.drives
            .write()
            .expect("drive guard lock")
            .insert(node, drive.clone());
        DriveRegistration(drive)
    }

    /// The axis `node` drives, if it drives one.
    pub fn axis_of(&self, node: NodeId) -> Option<String> {
        self.drives
            .read()
            .expect("drive guard lock")
            .get(&node)
            .map(|d| d.axis.clone())
    }

    /// The axis `node` drives, when that axis is active now.
    pub fn active_axis(&self, node: NodeId) -> Option<String> {
        self.drives
            .read()
            .expect("drive guard lock")
            .get(&node)
            .filter(|d| d.active.load(Ordering::Acquire))
            .map(|d| d.axis.clone())
    }

    /// Every active axis's drive: (node, axis).
    pub fn active_drives(&self) -> Vec<(NodeId, String)> {
        self.drives
            .read()
            .expect("drive guard lock")
            .iter()
            .filter(|(_, d)| d.active.load(Ordering::Acquire))
            .map(|(n, d)| (*n, d.axis.clone()))
            .collect()
    }
}

/// An operation refused because the node drives an active axis.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "node {node} on bus {bus} is the drive of axis {axis}, which is enabled or moving: \
     {operation} would disturb it; disable the axis first"
)]
pub struct AxisActive {
    /// The bus.
    pub bus: String,
    /// The drive's node.
    pub node: NodeId,
    /// The axis.
    pub axis: String,
    /// What was refused ("writing 0x6040:00", "a program download").
    pub operation: String,
}

impl CanopenBus {
    /// The register of this bus's axis drives.
    pub fn drive_guard(&self) -> &DriveGuard {
        &self.drive_guard
    }

    /// Refuses `operation` on `node` while the node drives an active axis.
    pub fn check_drive_idle(&self, node: NodeId, operation: &str) -> Result<(), AxisActive> {
        match self.drive_guard.active_axis(node) {
            Some(axis) => Err(AxisActive {
                bus: self.bus.clone(),
                node,
                axis,
                operation: operation.to_string(),
            }),
            None => Ok(()),
        }
    }

    /// Refuses a raw SDO write to `addr` of `node` when the node drives an
    /// active axis and the object commands the drive
    /// ([`commands_the_drive`]).
    pub fn check_sdo_write(&self, node: NodeId, addr: ObjectAddress) -> Result<(), AxisActive> {
        if !commands_the_drive(addr) {
            return Ok(());
        }
        self.check_drive_idle(node, &format!("writing {addr}"))
    }

    /// Refuses sending an RPDO of `node` that maps an object which
    /// commands the drive ([`commands_the_drive`]) while the node drives
    /// an active axis: the same rule as a raw SDO write of that object.
    pub fn check_rpdo_write(
        &self,
        node: NodeId,
        cfg: &cangate_canopen::pdo::PdoConfig,
    ) -> Result<(), AxisActive> {
        match cfg.mapping.iter().find(|m| commands_the_drive(m.addr)) {
            Some(m) => self.check_drive_idle(
                node,
                &format!("sending RPDO {} (it maps {})", cfg.num, m.addr),
            ),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_axis_is_active_while_powered_or_busy() {
        let g = DriveGuard::default();
        let n = NodeId::new(3).unwrap();
        let r = g.register(n, "X");
        assert_eq!(g.axis_of(n).as_deref(), Some("X"));
        assert_eq!(g.active_axis(n), None, "inactive until published");
        r.publish(Some(DriveState::OperationEnabled), true);
        assert_eq!(g.active_axis(n).as_deref(), Some("X"));
        r.publish(Some(DriveState::SwitchedOn), true);
        assert_eq!(g.active_axis(n), None);
        // Walking the state machine towards enabled.
        r.publish(Some(DriveState::ReadyToSwitchOn), false);
        assert_eq!(g.active_axis(n).as_deref(), Some("X"));
        r.publish(Some(DriveState::QuickStopActive), true);
        assert_eq!(g.active_drives(), vec![(n, "X".to_string())]);
        r.publish(Some(DriveState::Fault), true);
        assert!(g.active_drives().is_empty());
        assert_eq!(g.active_axis(NodeId::new(4).unwrap()), None);
    }

    #[test]
    fn process_and_program_objects_command_the_drive() {
        for i in [0x6040, 0x6060, 0x607A, 0x60FF, 0x6071, 0x1F50, 0x1F51] {
            assert!(commands_the_drive(ObjectAddress::new(i, 0)), "{i:04X}");
        }
        for i in [0x6041, 0x6081, 0x1017, 0x1F56] {
            assert!(!commands_the_drive(ObjectAddress::new(i, 0)), "{i:04X}");
        }
    }
}
