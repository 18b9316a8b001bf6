//! Simulated devices and bus faults as protobuf messages.

use crate::simulation::{BusFaultState, DeviceKind, DeviceState};
use cangate_proto::v1 as pb;

pub(crate) fn device_pb(d: DeviceState) -> pb::SimulatedDevice {
    pb::SimulatedDevice {
        bus: d.bus,
        node: u32::from(d.node),
        kind: match d.kind {
            DeviceKind::Node => pb::SimulatedDeviceKind::Node,
            DeviceKind::Drive => pb::SimulatedDeviceKind::Drive,
            DeviceKind::Handwheel => pb::SimulatedDeviceKind::Handwheel,
        } as i32,
        powered: d.powered,
        nmt_state: d.nmt.map_or("off", |s| s.name()).to_string(),
    }
}

pub(crate) fn faults_pb(f: BusFaultState) -> pb::BusFaults {
    pb::BusFaults {
        bus: f.bus,
        drop_probability: f.faults.drop_probability,
        drop_ids: f.faults.drop_ids,
        delay_us: u64::try_from(f.faults.delay.as_micros()).unwrap_or(u64::MAX),
        bus_off: f.bus_off,
        dropped_by_fault: f.dropped_by_fault,
    }
}
