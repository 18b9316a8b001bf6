//! The access table: every RPC the gateway serves, by full gRPC path, with
//! the least role it needs. One table for the whole API, so that a review
//! sees every decision at once; a test checks it against the compiled
//! `.proto` files (every method listed exactly once, nothing stale).
//!
//! An RPC missing here is refused (fail closed).

use super::Role;

/// Who may call an RPC.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Anyone, without credentials (health checks, reflection).
    Public,
    /// Callers holding at least this role.
    Role(Role),
}

/// One RPC's entry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rule {
    /// Full gRPC path, `/package.Service/Method`.
    pub path: &'static str,
    /// Who may call it.
    pub access: Access,
    /// It returns a stream (counts against `max_streams_per_client` while
    /// open).
    pub streaming: bool,
}

const fn rule(path: &'static str, access: Access, streaming: bool) -> Rule {
    Rule {
        path,
        access,
        streaming,
    }
}

use Access::Public;
const V: Access = Access::Role(Role::Viewer);
const O: Access = Access::Role(Role::Operator);
const E: Access = Access::Role(Role::Engineer);

/// Every RPC and who may call it.
pub const TABLE: &[Rule] = &[
    // Bus: reading and streaming frames is viewing; sending raw frames
    // bypasses every protocol check, so it is engineering.
    rule("/cangate.v1.Bus/ListBuses", V, false),
    rule("/cangate.v1.Bus/GetBus", V, false),
    rule("/cangate.v1.Bus/SendFrames", E, false),
    rule("/cangate.v1.Bus/StreamFrames", V, true),
    rule("/cangate.v1.Bus/Attach", E, true),
    // CANopen: reads (SDO reads and scans change nothing on the devices)
    // are viewing; NMT and SDO/PDO writes change devices: engineering.
    rule("/cangate.v1.Canopen/ListNodes", V, false),
    rule("/cangate.v1.Canopen/GetNode", V, false),
    rule("/cangate.v1.Canopen/SendNmt", E, false),
    rule("/cangate.v1.Canopen/ReadSdo", V, false),
    rule("/cangate.v1.Canopen/WriteSdo", E, false),
    // Each request of a session needs the role of ReadSdo or WriteSdo (see
    // [`session_request_role`]); opening one is viewing.
    rule("/cangate.v1.Canopen/SdoSession", V, true),
    rule("/cangate.v1.Canopen/ListObjects", V, false),
    rule("/cangate.v1.Canopen/ListSdoTransfers", V, false),
    rule("/cangate.v1.Canopen/ScanNetwork", V, false),
    rule("/cangate.v1.Canopen/StreamNodeEvents", V, true),
    rule("/cangate.v1.Canopen/StreamPdo", V, true),
    rule("/cangate.v1.Canopen/WritePdo", E, false),
    rule("/cangate.v1.Canopen/ReadPdoConfig", V, false),
    rule("/cangate.v1.Canopen/ConfigurePdo", E, false),
    rule("/cangate.v1.Canopen/GetSync", V, false),
    rule("/cangate.v1.Canopen/SetSync", E, false),
    rule("/cangate.v1.Canopen/SetTime", E, false),
    rule("/cangate.v1.Canopen/ExportDcf", V, false),
    rule("/cangate.v1.Canopen/DownloadProgram", E, true),
    // Axes: state is viewing; leases and every command (stops included:
    // a viewer is read-only) are operating.
    rule("/cangate.v1.Axes/ListAxes", V, false),
    rule("/cangate.v1.Axes/GetAxis", V, false),
    rule("/cangate.v1.Axes/AcquireControl", O, false),
    rule("/cangate.v1.Axes/RenewControl", O, false),
    rule("/cangate.v1.Axes/ReleaseControl", O, false),
    rule("/cangate.v1.Axes/Enable", O, false),
    rule("/cangate.v1.Axes/Disable", O, false),
    rule("/cangate.v1.Axes/Home", O, false),
    rule("/cangate.v1.Axes/Move", O, false),
    rule("/cangate.v1.Axes/Jog", O, false),
    rule("/cangate.v1.Axes/Stop", O, false),
    rule("/cangate.v1.Axes/QuickStop", O, false),
    rule("/cangate.v1.Axes/ResetFault", O, false),
    rule("/cangate.v1.Axes/ArmTouchProbe", O, false),
    rule("/cangate.v1.Axes/SetTorque", O, false),
    rule("/cangate.v1.Axes/SetMode", O, false),
    rule("/cangate.v1.Axes/StopAxes", O, false),
    rule("/cangate.v1.Axes/MoveAxes", O, false),
    rule("/cangate.v1.Axes/StreamAxisState", V, true),
    rule("/cangate.v1.Axes/StreamSetpoints", O, true),
    // Handwheels: switching manual/automatic mode is operating.
    rule("/cangate.v1.Handwheels/ListHandwheels", V, false),
    rule("/cangate.v1.Handwheels/GetHandwheel", V, false),
    rule("/cangate.v1.Handwheels/SetMode", O, false),
    rule("/cangate.v1.Handwheels/StreamFeed", V, true),
    rule("/cangate.v1.Handwheels/StreamFeedBatches", V, true),
    // The simulator injects frames as a device would: engineering.
    rule("/cangate.v1.Simulator/TurnHandwheel", E, false),
    rule("/cangate.v1.Simulator/ListSimulatedDevices", V, false),
    rule("/cangate.v1.Simulator/SetBusFaults", E, false),
    rule("/cangate.v1.Simulator/GetBusFaults", V, false),
    rule("/cangate.v1.Simulator/SetBusOff", E, false),
    rule("/cangate.v1.Simulator/PowerCycleDevice", E, false),
    rule("/cangate.v1.Simulator/SendEmcy", E, false),
    rule("/cangate.v1.Simulator/RaiseDriveFault", E, false),
    rule("/cangate.v1.Simulator/SetIoInputs", E, false),
    rule("/cangate.v1.Simulator/SetProgramFaults", E, false),
    // Session: the caller's own identity, for any valid credentials.
    rule("/cangate.v1.Session/GetCaller", V, false),
    // CANsmc: reading parameters is viewing; writing them and restarting
    // the master (its axes drop out of the cycle) is engineering.
    rule("/cangate.v1.Cansmc/ListMasters", V, false),
    rule("/cangate.v1.Cansmc/GetStatus", V, false),
    rule("/cangate.v1.Cansmc/ReadParameter", V, false),
    rule("/cangate.v1.Cansmc/WriteParameter", E, false),
    rule("/cangate.v1.Cansmc/StreamCycleStats", V, true),
    rule("/cangate.v1.Cansmc/Restart", E, false),
    // LSS (CiA 305) is bus-global. Finding and inquiring devices moves
    // them between LSS states and back but configures nothing: operating.
    // Configuring node-IDs and bit timings, storing, and switching devices
    // explicitly: engineering.
    rule("/cangate.v1.Lss/Fastscan", O, false),
    rule("/cangate.v1.Lss/Inquire", O, false),
    rule("/cangate.v1.Lss/IdentifyRemote", O, false),
    rule("/cangate.v1.Lss/IdentifyNonConfigured", O, false),
    rule("/cangate.v1.Lss/SwitchGlobal", E, false),
    rule("/cangate.v1.Lss/SwitchSelective", E, false),
    rule("/cangate.v1.Lss/ConfigureNodeId", E, false),
    rule("/cangate.v1.Lss/ConfigureBitTiming", E, false),
    rule("/cangate.v1.Lss/ActivateBitTiming", E, false),
    rule("/cangate.v1.Lss/StoreConfiguration", E, false),
    rule("/cangate.v1.Lss/AssignNodeId", E, false),
    // Standard services for probes and tools.
    rule("/grpc.health.v1.Health/Check", Public, false),
    rule("/grpc.health.v1.Health/Watch", Public, true),
    rule(
        "/grpc.reflection.v1.ServerReflection/ServerReflectionInfo",
        Public,
        true,
    ),
    // The same service under its older name, which many tools still speak.
    rule(
        "/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo",
        Public,
        true,
    ),
];

/// The entry of an RPC path, if it is classified.
pub fn lookup(path: &str) -> Option<&'static Rule> {
    TABLE.iter().find(|r| r.path == path)
}

/// The role one request inside a session needs: that of the unary RPC at
/// `path` it stands for (an SdoSession read needs ReadSdo's, a write
/// WriteSdo's), so that a session grants nothing the unary calls do not.
/// None for an unclassified path (refuse).
pub fn session_request_role(path: &str) -> Option<Role> {
    lookup(path).map(|r| match r.access {
        Access::Public => Role::Viewer,
        Access::Role(role) => role,
    })
}

/// True for the stops, which the limits give a budget of their own (see
/// [`super::limits`]): a machine must be stoppable by a client that is at
/// its limits for everything else.
pub fn is_stop(rule: &Rule) -> bool {
    matches!(
        rule.path,
        "/cangate.v1.Axes/Stop" | "/cangate.v1.Axes/QuickStop" | "/cangate.v1.Axes/StopAxes"
    )
}

/// True for the RPCs that send raw frames: the limits count their frames
/// (see [`super::limits::FrameBudget`]); `SendFrames` is not counted as a
/// call against the call rate.
pub fn sends_raw_frames(rule: &Rule) -> bool {
    matches!(
        rule.path,
        "/cangate.v1.Bus/SendFrames" | "/cangate.v1.Bus/Attach"
    )
}

/// True for the RPCs whose stream carries requests that each count as a
/// call against the client's call rate (see
/// [`super::limits::RequestBudget`]).
pub fn carries_requests(rule: &Rule) -> bool {
    rule.path == "/cangate.v1.Canopen/SdoSession"
}

/// True for calls that change state (role operator or above): these are
/// written to the audit log.
pub fn state_changing(rule: &Rule) -> bool {
    matches!(rule.access, Access::Role(r) if r >= Role::Operator)
}

#[cfg(test)]
mod tests {
    use super::*;
    use prost::Message;
    use std::collections::BTreeMap;

    /// Every method of every served service, from the compiled descriptor
    /// sets, with whether it streams responses.
    fn served_methods() -> BTreeMap<String, bool> {
        let mut out = BTreeMap::new();
        for set in [
            cangate_proto::FILE_DESCRIPTOR_SET,
            tonic_health::pb::FILE_DESCRIPTOR_SET,
            tonic_reflection::pb::v1::FILE_DESCRIPTOR_SET,
            tonic_reflection::pb::v1alpha::FILE_DESCRIPTOR_SET,
        ] {
            let fds = prost_types::FileDescriptorSet::decode(set).expect("descriptor set decodes");
            for file in fds.file {
                let package = file.package();
                for service in &file.service {
                    for m in &service.method {
                        out.insert(
                            format!("/{package}.{}/{}", service.name(), m.name()),
                            m.server_streaming(),
                        );
                    }
                }
            }
        }
        out
    }

    #[test]
    fn table_covers_every_rpc_exactly_once_and_nothing_stale() {
        let served = served_methods();
        assert!(served.contains_key("/cangate.v1.Bus/SendFrames"));
        for (path, streaming) in &served {
            let n = TABLE.iter().filter(|r| r.path == path).count();
            assert_eq!(n, 1, "{path} must have exactly one access table entry");
            assert_eq!(
                lookup(path).map(|r| r.streaming),
                Some(*streaming),
                "{path}: the table's streaming flag disagrees with the proto"
            );
        }
        for r in TABLE {
            assert!(
                served.contains_key(r.path),
                "stale access table entry {} (no such RPC in the protos)",
                r.path
            );
        }
    }

    #[test]
    fn roles_are_ordered_and_writes_need_engineer() {
        assert!(Role::Engineer > Role::Operator && Role::Operator > Role::Viewer);
        for p in [
            "/cangate.v1.Canopen/WriteSdo",
            "/cangate.v1.Canopen/SendNmt",
            "/cangate.v1.Canopen/WritePdo",
            "/cangate.v1.Canopen/ConfigurePdo",
            "/cangate.v1.Canopen/SetSync",
            "/cangate.v1.Canopen/SetTime",
            "/cangate.v1.Bus/SendFrames",
            "/cangate.v1.Bus/Attach",
            "/cangate.v1.Simulator/TurnHandwheel",
            "/cangate.v1.Cansmc/WriteParameter",
            "/cangate.v1.Cansmc/Restart",
            "/cangate.v1.Lss/AssignNodeId",
            "/cangate.v1.Lss/ConfigureNodeId",
            "/cangate.v1.Lss/StoreConfiguration",
        ] {
            assert_eq!(lookup(p).map(|r| r.access), Some(E), "{p}");
        }
        assert_eq!(lookup("/cangate.v1.Axes/Move").map(|r| r.access), Some(O));
        assert!(lookup("/cangate.v1.Axes/Nope").is_none());
        assert!(!state_changing(
            lookup("/cangate.v1.Bus/ListBuses").unwrap()
        ));
        assert!(state_changing(
            lookup("/cangate.v1.Axes/AcquireControl").unwrap()
        ));
        let stops: Vec<&str> = TABLE
            .iter()
            .filter(|r| is_stop(r))
            .map(|r| r.path)
            .collect();
        assert_eq!(stops.len(), 3, "{stops:?}");
        let raw: Vec<&str> = TABLE
            .iter()
            .filter(|r| sends_raw_frames(r))
            .map(|r| r.path)
            .collect();
        assert_eq!(
            raw,
            ["/cangate.v1.Bus/SendFrames", "/cangate.v1.Bus/Attach"],
            "the RPCs whose frames the limits count"
        );
    }
}
