//! CANopen values, data types, NMT states, EMCY, nodes, node events, SDO
//! transfers, program download steps and outcomes, and object dictionary
//! entries as protobuf messages, and typed values from them.

use super::InvalidArgument;
use crate::canopen::{NodeEvent, NodeEventKind, NodeSnapshot};
use cangate_can::Timestamp;
use cangate_canopen::NodeId;
use cangate_canopen::emcy::Emcy;
use cangate_canopen::nmt::NmtState;
use cangate_canopen::od::{AccessType, ObjectDictionary, Variable};
use cangate_canopen::program_download::{ProgramOutcome, ProgramStep};
use cangate_canopen::value::{DataType, Value};
use cangate_proto::v1 as pb;

/// The protobuf data type for a CiA type (those the API names).
pub(crate) fn data_type_to_pb(t: DataType) -> pb::DataType {
    pb::DataType::try_from(t.code() as i32).unwrap_or(pb::DataType::Unspecified)
}

pub(crate) fn data_type_from_pb(t: i32) -> Result<Option<DataType>, InvalidArgument> {
    if t == 0 {
        return Ok(None);
    }
    u16::try_from(t)
        .ok()
        .and_then(DataType::from_code)
        .map(Some)
        .ok_or_else(|| InvalidArgument(format!("data type {t} is not a CiA 301 type code")))
}

/// A CANopen value to protobuf.
pub(crate) fn value_to_pb(v: &Value) -> pb::Value {
    use pb::value::Value as V;
    let value = match v {
        Value::Boolean(b) => V::BoolValue(*b),
        Value::Real32(f) => V::RealValue(*f as f64),
        Value::Real64(f) => V::RealValue(*f),
        Value::VisibleString(s) | Value::UnicodeString(s) => V::StringValue(s.clone()),
        Value::OctetString(b) | Value::Domain(b) => V::BytesValue(b.clone()),
        other => {
            let i = other.as_i128().unwrap_or(0);
            if other
                .data_type()
                .integer_range()
                .is_some_and(|(min, _)| min < 0)
            {
                V::IntValue(i as i64)
            } else {
                V::UintValue(i as u64)
            }
        }
    };
    pb::Value {
        r#type: data_type_to_pb(v.data_type()) as i32,
        value: Some(value),
    }
}

/// A protobuf value to a CANopen value, range-checked against its type.
pub(crate) fn value_from_pb(v: &pb::Value) -> Result<Value, InvalidArgument> {
    use pb::value::Value as V;
    let ty = data_type_from_pb(v.r#type)?
        .ok_or_else(|| InvalidArgument("the value has no data type".into()))?;
    let bad =
        |what: &str| InvalidArgument(format!("a {what} value does not fit the data type {ty}"));
    let value = match (v.value.as_ref(), ty) {
        (Some(V::BoolValue(b)), DataType::Boolean) => Value::Boolean(*b),
        (Some(V::IntValue(i)), t) if t.is_integer() => {
            Value::from_integer(t, *i as i128).map_err(|e| InvalidArgument(e.to_string()))?
        }
        (Some(V::UintValue(u)), t) if t.is_integer() => {
            Value::from_integer(t, *u as i128).map_err(|e| InvalidArgument(e.to_string()))?
        }
        (Some(V::RealValue(f)), DataType::Real32) => Value::Real32(*f as f32),
        (Some(V::RealValue(f)), DataType::Real64) => Value::Real64(*f),
        (Some(V::StringValue(s)), DataType::VisibleString) => {
            let v = Value::VisibleString(s.clone());
            Value::decode(DataType::VisibleString, &v.encode())
                .map_err(|e| InvalidArgument(e.to_string()))?;
            v
        }
        (Some(V::StringValue(s)), DataType::UnicodeString) => Value::UnicodeString(s.clone()),
        (Some(V::BytesValue(b)), DataType::OctetString) => Value::OctetString(b.clone()),
        (Some(V::BytesValue(b)), DataType::Domain) => Value::Domain(b.clone()),
        (Some(V::BoolValue(_)), _) => return Err(bad("boolean")),
        (Some(V::IntValue(_)), _) | (Some(V::UintValue(_)), _) => return Err(bad("integer")),
        (Some(V::RealValue(_)), _) => return Err(bad("real")),
        (Some(V::StringValue(_)), _) => return Err(bad("string")),
        (Some(V::BytesValue(_)), _) => return Err(bad("bytes")),
        (None, _) => return Err(InvalidArgument("the value is empty".into())),
    };
    Ok(value)
}

pub(crate) fn nmt_state_to_pb(s: Option<NmtState>) -> pb::NmtState {
    match s {
        None => pb::NmtState::Unknown,
        Some(NmtState::Initialising) => pb::NmtState::Initialising,
        Some(NmtState::Stopped) => pb::NmtState::Stopped,
        Some(NmtState::Operational) => pb::NmtState::Operational,
        Some(NmtState::PreOperational) => pb::NmtState::PreOperational,
    }
}

pub(crate) fn emcy_to_pb(e: &Emcy, at: Timestamp) -> pb::Emcy {
    pb::Emcy {
        node: e.node.get() as u32,
        code: e.code as u32,
        code_name: e.code_name().to_string(),
        register: e.register as u32,
        register_bits: e.error_register().names().map(str::to_string).collect(),
        manufacturer: e.manufacturer.to_vec(),
        timestamp_ns: at.as_nanos(),
    }
}

/// The mechanism of a loss or recovery event: node guarding or heartbeat.
pub(crate) fn monitoring_to_pb(guarding: bool) -> pb::LifeMonitoring {
    if guarding {
        pb::LifeMonitoring::NodeGuarding
    } else {
        pb::LifeMonitoring::Heartbeat
    }
}

pub(crate) fn node_to_pb(bus: &str, n: &NodeSnapshot) -> pb::Node {
    pb::Node {
        bus: bus.to_string(),
        id: n.id.get() as u32,
        name: n.facts.name.clone(),
        state: nmt_state_to_pb(n.state) as i32,
        heartbeat_age_ms: n.heartbeat_age.map(|a| a.as_millis() as u64),
        heartbeat_lost: n.heartbeat_lost,
        heartbeat_timeout_ms: n
            .facts
            .heartbeat_timeout
            .map(|t| t.as_millis() as u32)
            .unwrap_or(0),
        device_type: n.facts.device_type,
        device_name: n.facts.device_name.clone().unwrap_or_default(),
        identity: n.facts.identity.map(|i| pb::Identity {
            vendor_id: i[0],
            product_code: i[1],
            revision: i[2],
            serial: i[3],
        }),
        active_error: n.active_error.as_ref().map(|(e, t)| emcy_to_pb(e, *t)),
        emcy_history: n
            .emcy_history
            .iter()
            .map(|(e, t)| emcy_to_pb(e, *t))
            .collect(),
        boot_ups: n.boot_ups,
        monitoring: match (n.facts.guarding, n.facts.heartbeat_timeout) {
            (Some(_), _) => pb::LifeMonitoring::NodeGuarding,
            (None, Some(_)) => pb::LifeMonitoring::Heartbeat,
            (None, None) => pb::LifeMonitoring::None,
        } as i32,
        guard_time_ms: n.facts.guarding.map_or(0, |(t, _)| t.as_millis() as u32),
        life_time_factor: n.facts.guarding.map_or(0, |(_, f)| u32::from(f)),
        guarding_toggle_errors: n.guarding_toggle_errors,
        configured: n.facts.configured,
    }
}

/// A value given without a type (`Value.type` unspecified) as the EDS type
/// `ty`: numbers, booleans and bytes converted (range-checked), a string
/// for a non-string type parsed as a person types it.
pub(crate) fn value_from_pb_as(v: &pb::Value, ty: DataType) -> Result<Value, InvalidArgument> {
    use pb::value::Value as V;
    let string_type = matches!(ty, DataType::VisibleString | DataType::UnicodeString);
    if let Some(V::StringValue(text)) = &v.value
        && !string_type
    {
        return Value::parse(ty, text).map_err(|e| InvalidArgument(e.to_string()));
    }
    let typed = pb::Value {
        r#type: ty.code() as i32,
        value: v.value.clone(),
    };
    value_from_pb(&typed)
}

/// The protobuf access rights.
pub(crate) fn access_to_pb(a: AccessType) -> pb::ObjectAccess {
    match a {
        AccessType::Ro => pb::ObjectAccess::Ro,
        AccessType::Wo => pb::ObjectAccess::Wo,
        AccessType::Rw => pb::ObjectAccess::Rw,
        AccessType::Rwr => pb::ObjectAccess::Rwr,
        AccessType::Rww => pb::ObjectAccess::Rww,
        AccessType::Const => pb::ObjectAccess::Const,
    }
}

/// A value for a field of ObjectInfo: only for types the API names.
fn known_value_to_pb(v: &Value) -> Option<pb::Value> {
    (data_type_to_pb(v.data_type()) != pb::DataType::Unspecified).then(|| value_to_pb(v))
}

/// One sub-object of a node's dictionary (`var` must be in `od`).
pub(crate) fn object_info_to_pb(
    od: &ObjectDictionary,
    var: &Variable,
    node: NodeId,
) -> pb::ObjectInfo {
    let object = od.object(var.address.index);
    pb::ObjectInfo {
        index: var.address.index.into(),
        subindex: var.address.sub.into(),
        name: od
            .full_name(var.address)
            .unwrap_or_else(|| var.name.clone()),
        object_name: object.map(|o| o.name.clone()).unwrap_or_default(),
        sub_name: var.name.clone(),
        object_type: object
            .map(|o| o.object_type.to_string())
            .unwrap_or_default(),
        r#type: data_type_to_pb(var.data_type) as i32,
        type_code: var.data_type.code().into(),
        access: access_to_pb(var.access) as i32,
        pdo_mappable: var.pdo_mappable,
        default_value: var
            .default_for_node(node)
            .as_ref()
            .and_then(known_value_to_pb),
        default_text: var
            .parameter_value
            .as_ref()
            .or(var.default.as_ref())
            .map(ToString::to_string)
            .unwrap_or_default(),
        low_limit: var.low_limit.as_ref().and_then(known_value_to_pb),
        high_limit: var.high_limit.as_ref().and_then(known_value_to_pb),
    }
}

/// A node's PDO as a message, its mapped objects named from `od`.
pub(crate) fn pdo_to_pb(
    pdo: &crate::canopen::pdo_config::NodePdo,
    od: Option<&ObjectDictionary>,
) -> pb::PdoConfiguration {
    use cangate_canopen::pdo::PdoKind;
    let c = &pdo.config;
    pb::PdoConfiguration {
        kind: match c.kind {
            PdoKind::Rpdo => pb::PdoKind::Rpdo,
            PdoKind::Tpdo => pb::PdoKind::Tpdo,
        } as i32,
        pdo: u32::from(c.num),
        cob_id: u32::from(c.cob_id),
        enabled: pdo.enabled,
        transmission_type: u32::from(c.transmission_type),
        inhibit_time_100us: u32::from(c.inhibit_time),
        event_timer_ms: u32::from(c.event_timer_ms),
        mapping: c
            .mapping
            .iter()
            .map(|m| pb::PdoMappedObject {
                index: u32::from(m.addr.index),
                subindex: u32::from(m.addr.sub),
                bits: u32::from(m.bits),
                name: od.and_then(|od| od.full_name(m.addr)).unwrap_or_default(),
                object: String::new(),
            })
            .collect(),
    }
}

/// The PDO kind of a request (UNSPECIFIED: `None`).
pub(crate) fn pdo_kind_from_pb(
    kind: i32,
) -> Result<Option<cangate_canopen::pdo::PdoKind>, InvalidArgument> {
    use cangate_canopen::pdo::PdoKind;
    match pb::PdoKind::try_from(kind) {
        Ok(pb::PdoKind::Unspecified) => Ok(None),
        Ok(pb::PdoKind::Rpdo) => Ok(Some(PdoKind::Rpdo)),
        Ok(pb::PdoKind::Tpdo) => Ok(Some(PdoKind::Tpdo)),
        Err(_) => Err(InvalidArgument(format!(
            "PDO kind {kind} is not RPDO (1) or TPDO (2)"
        ))),
    }
}

/// A ConfigurePdo request's PDO for `node`: objects named by `object` are
/// resolved in `od`, a missing bit length is the EDS type's, a COB-ID of
/// 0 is the predefined one. Every field is range-checked here, so that
/// nothing reaches the node that CiA 301 would refuse for its form.
pub(crate) fn pdo_from_pb(
    p: &pb::PdoConfiguration,
    node: NodeId,
    od: Option<&ObjectDictionary>,
) -> Result<crate::canopen::pdo_config::NodePdo, InvalidArgument> {
    use cangate_canopen::ObjectAddress;
    use cangate_canopen::pdo::{MappedObject, PdoConfig};
    let bad = |m: String| InvalidArgument(m);
    let kind =
        pdo_kind_from_pb(p.kind)?.ok_or_else(|| bad("pdo.kind: give RPDO or TPDO".into()))?;
    let num = u16::try_from(p.pdo)
        .ok()
        .filter(|n| (1..=512).contains(n))
        .ok_or_else(|| bad(format!("PDO number {} is out of range (1..=512)", p.pdo)))?;
    let cob_id = match p.cob_id {
        0 => kind.default_cob_id(num, node).ok_or_else(|| {
            bad(format!(
                "PDO {num} has no predefined COB-ID (only 1..=4 do): give cob_id"
            ))
        })?,
        c @ 0x001..=0x7FF => c as u16,
        c => return Err(bad(format!("COB-ID 0x{c:X} is not an 11-bit identifier"))),
    };
    let field = |v: u32, max: u32, what: &str| {
        if v > max {
            Err(bad(format!("{what} {v} is above its maximum {max}")))
        } else {
            Ok(v)
        }
    };
    let transmission_type = field(p.transmission_type, 255, "transmission_type")? as u8;
    if (241..=251).contains(&transmission_type) {
        return Err(bad(format!(
            "transmission type {transmission_type} is reserved (CiA 301: 241..=251)"
        )));
    }
    let inhibit_time = field(p.inhibit_time_100us, 0xFFFF, "inhibit_time_100us")? as u16;
    let event_timer_ms = field(p.event_timer_ms, 0xFFFF, "event_timer_ms")? as u16;
    let mut mapping = Vec::with_capacity(p.mapping.len());
    for (i, m) in p.mapping.iter().enumerate() {
        let at = |e: String| bad(format!("mapping entry {}: {e}", i + 1));
        let addr = if m.object.is_empty() {
            let index = u16::try_from(m.index)
                .map_err(|_| at(format!("index 0x{:X} does not fit 16 bits", m.index)))?;
            let sub = u8::try_from(m.subindex)
                .map_err(|_| at(format!("sub-index {} does not fit 8 bits", m.subindex)))?;
            ObjectAddress::new(index, sub)
        } else {
            let od = od.ok_or_else(|| {
                at(format!(
                    "the node has no EDS, so {:?} cannot be resolved; give index and subindex",
                    m.object
                ))
            })?;
            od.resolve(&m.object).map_err(|e| at(e.to_string()))?
        };
        let bits = if m.bits != 0 {
            u8::try_from(m.bits).map_err(|_| at(format!("{} bits is not a length", m.bits)))?
        } else {
            let var = od.and_then(|od| od.get(addr)).ok_or_else(|| {
                at(format!(
                    "{addr} is not in the node's EDS: give its length in bits"
                ))
            })?;
            var.data_type
                .bit_len()
                .and_then(|b| u8::try_from(b).ok())
                .ok_or_else(|| at(format!("{addr} has no fixed size and cannot be mapped")))?
        };
        if let Some(var) = od.and_then(|od| od.get(addr))
            && !var.pdo_mappable
        {
            return Err(at(format!(
                "{addr} ({}) is not PDO-mappable according to the node's EDS",
                var.name
            )));
        }
        mapping.push(MappedObject { addr, bits });
    }
    let config = PdoConfig {
        kind,
        num,
        cob_id,
        transmission_type,
        inhibit_time,
        event_timer_ms,
        mapping,
    };
    config.validate().map_err(|e| bad(e.to_string()))?;
    Ok(crate::canopen::pdo_config::NodePdo {
        config,
        enabled: p.enabled,
    })
}

/// A node event of bus `bus` as its protobuf message.
pub(crate) fn node_event_to_pb(bus: &str, ev: &NodeEvent) -> pb::NodeEvent {
    use pb::node_event::Event as E;
    let event = match &ev.kind {
        NodeEventKind::BootUp => E::BootUp(pb::BootUp {}),
        NodeEventKind::StateChanged { from, to } => E::StateChanged(pb::StateChange {
            from: nmt_state_to_pb(*from) as i32,
            to: nmt_state_to_pb(Some(*to)) as i32,
        }),
        NodeEventKind::HeartbeatLost { timeout, guarding } => E::HeartbeatLost(pb::HeartbeatLost {
            timeout_ms: timeout.as_millis() as u32,
            monitoring: monitoring_to_pb(*guarding) as i32,
        }),
        NodeEventKind::HeartbeatRecovered {
            state,
            after,
            guarding,
        } => E::HeartbeatRecovered(pb::HeartbeatRecovered {
            state: nmt_state_to_pb(Some(*state)) as i32,
            silent_ms: after.as_millis() as u64,
            monitoring: monitoring_to_pb(*guarding) as i32,
        }),
        NodeEventKind::GuardingToggleError {
            data,
            expected,
            count,
        } => E::GuardingToggleError(pb::GuardingToggleError {
            data: u32::from(*data),
            expected_toggle: *expected,
            count: *count,
        }),
        NodeEventKind::Emcy(e) => E::Emcy(emcy_to_pb(e, ev.at)),
        NodeEventKind::BootCompleted { .. } => E::BootCompleted(pb::BootCompleted {}),
        NodeEventKind::BootFailed { reason } => E::BootFailed(pb::BootFailed {
            reason: reason.clone(),
        }),
    };
    pb::NodeEvent {
        bus: bus.to_string(),
        node: ev.node.get() as u32,
        timestamp_ns: ev.at.as_nanos(),
        event: Some(event),
    }
}

/// The node events of bus `bus` a subscriber missed, as a node event.
pub(crate) fn node_events_lost_to_pb(bus: &str, count: u64) -> pb::NodeEvent {
    pb::NodeEvent {
        bus: bus.to_string(),
        node: 0,
        timestamp_ns: Timestamp::now().as_nanos(),
        event: Some(pb::node_event::Event::Lost(pb::EventsLost { count })),
    }
}

/// An SDO transfer in progress with `node`.
pub(crate) fn sdo_transfer_to_pb(
    node: NodeId,
    p: &cangate_canopen::sdo::Progress,
) -> pb::SdoTransfer {
    use cangate_canopen::sdo::{Direction, Protocol};
    pb::SdoTransfer {
        node: node.get() as u32,
        index: p.addr.index as u32,
        subindex: p.addr.sub as u32,
        upload: p.direction == Direction::Upload,
        protocol: match p.protocol {
            Some(Protocol::Expedited) => "expedited",
            Some(Protocol::Segmented) => "segmented",
            Some(Protocol::Block) => "block",
            None => "",
        }
        .to_string(),
        transferred: p.transferred as u64,
        total: p.total.map(|t| t as u64),
    }
}

/// A program download step.
pub(crate) fn program_step_to_pb(step: ProgramStep) -> pb::ProgramStep {
    match step {
        ProgramStep::ReadIdentificationBefore => pb::ProgramStep::ReadIdentificationBefore,
        ProgramStep::StopProgram => pb::ProgramStep::StopProgram,
        ProgramStep::ClearProgram => pb::ProgramStep::ClearProgram,
        ProgramStep::DownloadData => pb::ProgramStep::DownloadData,
        ProgramStep::WaitFlash => pb::ProgramStep::WaitFlash,
        ProgramStep::StartProgram => pb::ProgramStep::StartProgram,
        ProgramStep::WaitBootUp => pb::ProgramStep::WaitBootUp,
        ProgramStep::ReadIdentificationAfter => pb::ProgramStep::ReadIdentificationAfter,
    }
}

/// A completed program download.
pub(crate) fn program_outcome_to_pb(o: &ProgramOutcome) -> pb::DownloadProgramOutcome {
    let secs = o.download_duration.as_secs_f64();
    pb::DownloadProgramOutcome {
        old_identification: o.old_identification,
        new_identification: o.new_identification,
        bytes: o.bytes as u64,
        duration_ms: o.duration.as_millis() as u64,
        data_duration_ms: o.download_duration.as_millis() as u64,
        data_bytes_per_second: if secs > 0.0 {
            o.bytes as f64 / secs
        } else {
            0.0
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cangate_canopen::ObjectAddress;
    use cangate_canopen::eds::{Eds, SIM_DRIVE_EDS};

    fn untyped(value: pb::value::Value) -> pb::Value {
        pb::Value {
            r#type: 0,
            value: Some(value),
        }
    }

    #[test]
    fn untyped_values_take_the_eds_type() {
        use pb::value::Value as V;
        let as_ = |v, ty| value_from_pb_as(&untyped(v), ty);
        assert_eq!(
            as_(V::UintValue(100), DataType::Unsigned16).unwrap(),
            Value::Unsigned16(100)
        );
        assert_eq!(
            as_(V::StringValue("0x64".into()), DataType::Unsigned16).unwrap(),
            Value::Unsigned16(100)
        );
        assert_eq!(
            as_(V::StringValue("-5".into()), DataType::Integer32).unwrap(),
            Value::Integer32(-5)
        );
        assert_eq!(
            as_(V::StringValue("0x64".into()), DataType::VisibleString).unwrap(),
            Value::VisibleString("0x64".into())
        );
        assert_eq!(
            as_(V::StringValue("true".into()), DataType::Boolean).unwrap(),
            Value::Boolean(true)
        );
        assert!(as_(V::StringValue("70000".into()), DataType::Unsigned16).is_err());
        assert!(as_(V::UintValue(70000), DataType::Unsigned16).is_err());
        assert!(as_(V::RealValue(1.0), DataType::Unsigned16).is_err());
    }

    #[test]
    fn object_infos_of_the_drive() {
        let od = Eds::parse(SIM_DRIVE_EDS).unwrap().od;
        let node = NodeId::new(5).unwrap();
        let info = |index, sub| {
            object_info_to_pb(&od, od.get(ObjectAddress::new(index, sub)).unwrap(), node)
        };
        let name = info(0x1008, 0);
        assert_eq!(name.name, "Manufacturer device name");
        assert_eq!(name.r#type, pb::DataType::VisibleString as i32);
        assert_eq!(name.access, pb::ObjectAccess::Const as i32);
        assert_eq!(name.object_type, "VAR");
        let vendor = info(0x1018, 1);
        assert_eq!(
            (vendor.name.as_str(), vendor.object_name.as_str()),
            ("Identity object.Vendor-ID", "Identity object")
        );
        assert_eq!(vendor.sub_name, "Vendor-ID");
        let cw = info(0x6040, 0);
        assert!(cw.pdo_mappable);
        assert_eq!(cw.access, pb::ObjectAccess::Rww as i32);
        assert_eq!(cw.type_code, 6);
        // $NODEID defaults are resolved for the node; the text keeps them.
        let cob = info(0x1800, 1);
        assert!(cob.default_text.contains("$NODEID"), "{}", cob.default_text);
        let Some(pb::value::Value::UintValue(v)) = cob.default_value.unwrap().value else {
            panic!()
        };
        assert_eq!(v & 0x7FF, 0x185);
    }
}
