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
/// drive behind the axis's back: a process object of any axis of the
/// drive (each further axis's at + 0x800), or a program object.
pub fn commands_the_drive(addr: ObjectAddress) -> bool {
    let first = cangate_canopen::cia402::first_axis(addr);
    DRIVE_PROCESS_OBJECTS.contains(&first.index) || PROGRAM_OBJECTS.contains(&addr.index)
}

#[derive(Debug)]
struct Drive {
    axis: String,
    active: AtomicBool,
}

/// The axes' drives of one bus, by node: every axis of a multi-axis
/// drive (they share the node, and what is done to the node is done to
/// all of them).
#[derive(Debug, Default)]
pub struct DriveGuard {
    drives: RwLock<BTreeMap<NodeId, Vec<Arc<Drive>>>>,
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
    /// axis publishes otherwise); a multi-axis drive's node is registered
    /// once per axis.
    pub fn register(&self, node: NodeId, axis: &str) -> DriveRegistration {
        let drive = Arc::new(Drive {
            axis: axis.to_string(),
            active: AtomicBool::new(false),
        });
        let mut drives = self.drives.write().expect("drive guard lock");
        let axes = drives.entry(node).or_default();
        // A re-registration of the same axis (its task restarted) replaces
        // the old entry.
        axes.retain(|d| d.axis != axis);
        axes.push(drive.clone());
        DriveRegistration(drive)
    }

    /// The axes `node` drives (one, or each axis of a multi-axis drive),
    /// joined with ", "; `None` when it drives none.
    pub fn axis_of(&self, node: NodeId) -> Option<String> {
        let drives = self.drives.read().expect("drive guard lock");
        let axes = drives.get(&node).filter(|a| !a.is_empty())?;
        Some(
            axes.iter()
                .map(|d| d.axis.as_str())
                .collect::<Vec<_>>()
                .join(", "),
        )
    }

    /// The active axes `node` drives, joined with ", ", when any is
    /// active now.
    pub fn active_axis(&self, node: NodeId) -> Option<String> {
        let drives = self.drives.read().expect("drive guard lock");
        let active: Vec<&str> = drives
            .get(&node)?
            .iter()
            .filter(|d| d.active.load(Ordering::Acquire))
            .map(|d| d.axis.as_str())
            .collect();
        (!active.is_empty()).then(|| active.join(", "))
    }

    /// Every active axis's drive: (node, axis).
    pub fn active_drives(&self) -> Vec<(NodeId, String)> {
        self.drives
            .read()
            .expect("drive guard lock")
            .iter()
            .flat_map(|(n, axes)| axes.iter().map(move |d| (*n, d)))
            .filter(|(_, d)| d.active.load(Ordering::Acquire))
            .map(|(n, d)| (n, d.axis.clone()))
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

    /// The axes of a multi-axis drive share its node: an operation on
    /// the node is refused while any of them is active, whichever was
    /// registered last.
    #[test]
    fn a_node_with_any_active_axis_is_active() {
        let n = NodeId::new(3).unwrap();
        for active_first in [true, false] {
            let g = DriveGuard::default();
            let a = g.register(n, "A");
            let b = g.register(n, "B");
            let (on, off, name) = if active_first {
                (&a, &b, "A")
            } else {
                (&b, &a, "B")
            };
            on.publish(Some(DriveState::OperationEnabled), true);
            off.publish(Some(DriveState::SwitchOnDisabled), true);
            assert_eq!(g.active_axis(n).as_deref(), Some(name));
            assert_eq!(g.active_drives(), vec![(n, name.to_string())]);
            on.publish(Some(DriveState::SwitchedOn), true);
            assert_eq!(g.active_axis(n), None);
        }
    }

    #[test]
    fn process_and_program_objects_command_the_drive() {
        // Those of every axis of a multi-axis drive (+ 0x800 each).
        for i in [0x6840, 0x6860, 0x687A, 0x68FF, 0x6871, 0x7040, 0x9871] {
            assert!(commands_the_drive(ObjectAddress::new(i, 0)), "{i:04X}");
        }
        assert!(!commands_the_drive(ObjectAddress::new(0x6841, 0)));
        for i in [0x6040, 0x6060, 0x607A, 0x60FF, 0x6071, 0x1F50, 0x1F51] {
            assert!(commands_the_drive(ObjectAddress::new(i, 0)), "{i:04X}");
        }
        for i in [0x6041, 0x6081, 0x1017, 0x1F56] {
            assert!(!commands_the_drive(ObjectAddress::new(i, 0)), "{i:04X}");
        }
    }
}
