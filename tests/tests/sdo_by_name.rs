//! Objects by name end to end (issue 17): the demo configuration's
//! simulated drives with the built-in EDS, ReadSdo/WriteSdo with `object`
//! (names resolved by the gateway with the node's EDS), writes without a
//! type (the EDS's), the errors of the API contract (no EDS, unknown and
//! ambiguous names, name and index together), and ListObjects.

use cangate_canopen::eds::{Eds, SIM_DRIVE_EDS};
use cangate_client::{Client, DataType, Error, NodeId, ObjectAddress, SdoValue, pb};
use cangate_server::{Config, RunningServer};
use cangate_tests::*;
use tonic::Code;

/// The demo on an ephemeral port, plus node 20: configured, without an EDS
/// (nothing answers for it; these tests never reach the bus for it).
async fn start() -> (RunningServer, Client) {
    let mut c = Config::demo();
    c.listen = "127.0.0.1:0".parse().unwrap();
    let mut bare = c.canopen[0].nodes[0].clone();
    bare.id = 20;
    bare.name = "no EDS".into();
    bare.eds = None;
    bare.simulate = false;
    bare.heartbeat_timeout_ms = 0;
    c.canopen[0].nodes.push(bare);
    let server = cangate_server::start(&c).await.expect("server starts");
    let client = client(&server).await.with_request_timeout(Some(WAIT));
    (server, client)
}

fn node(id: u32) -> NodeId {
    NodeId::new(id).unwrap()
}

/// The status's code and ErrorInfo reason.
fn code_reason(e: &Error) -> (Option<Code>, String) {
    let reason = e
        .status()
        .and_then(cangate_client::error_info)
        .map(|i| i.reason)
        .unwrap_or_default();
    (e.code(), reason)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reads_and_writes_by_name() {
    let (_server, c) = start().await;
    let can0 = c.canopen("can0");

    // A VAR by its ParameterName is the same object as by address.
    let by_name = can0
        .read_object(node(1), "Manufacturer device name", DataType::Unspecified)
        .await
        .unwrap();
    let by_address = can0
        .read(
            node(1),
            ObjectAddress::new(0x1008, 0),
            DataType::VisibleString,
        )
        .await
        .unwrap();
    assert_eq!(by_name, by_address);
    assert_eq!(by_name, SdoValue::VisibleString("cangate sim drive".into()));
    // Case and separators do not matter.
    assert_eq!(
        can0.read_object(node(1), "manufacturer_device_NAME", DataType::Unspecified)
            .await
            .unwrap(),
        by_address
    );

    // A sub-object as "object.sub", alone, and an address as text.
    let vendor = can0
        .read_object(node(1), "Identity object.Vendor-ID", DataType::Unspecified)
        .await
        .unwrap();
    assert!(matches!(vendor, SdoValue::U32(_)), "{vendor:?}");
    assert_eq!(
        can0.read_object(node(1), ObjectAddress::new(0x1018, 1), DataType::Unsigned32)
            .await
            .unwrap(),
        vendor
    );
    let mut raw = c.clone();
    let r = raw
        .read_sdo(pb::ReadSdoRequest {
            bus: "can0".into(),
            node: 1,
            object: "0x1018:01".into(),
            ..Default::default()
        })
        .await
        .unwrap();
    assert_eq!(
        r.value.map(|v| SdoValue::from_pb(&v).unwrap()),
        Some(vendor.clone())
    );
    assert_eq!(
        can0.read_object(node(1), "Vendor-ID", DataType::Unspecified)
            .await
            .unwrap(),
        vendor
    );

    // A write by name without a type takes the EDS type (UNSIGNED16),
    // from text and from a typed value alike.
    assert_eq!(
        can0.write_text(node(2), "Producer heartbeat time", "100")
            .await
            .unwrap(),
        2
    );
    assert_eq!(
        can0.read(
            node(2),
            ObjectAddress::new(0x1017, 0),
            DataType::Unspecified
        )
        .await
        .unwrap(),
        SdoValue::U16(100)
    );
    let untyped = pb::WriteSdoRequest {
        bus: "can0".into(),
        node: 2,
        object: "producer heartbeat time".into(),
        data: Some(pb::write_sdo_request::Data::Value(pb::Value {
            r#type: 0,
            value: Some(pb::value::Value::UintValue(250)),
        })),
        ..Default::default()
    };
    assert_eq!(raw.write_sdo(untyped).await.unwrap().bytes, 2);
    assert_eq!(
        can0.read_object(node(2), "Producer heartbeat time", DataType::Unspecified)
            .await
            .unwrap(),
        SdoValue::U16(250)
    );
    // A typed value by name is checked against the EDS as by address.
    let e = can0
        .write_object(node(2), "Producer heartbeat time", SdoValue::U32(5))
        .await
        .unwrap_err();
    assert_eq!(code_reason(&e).0, Some(Code::InvalidArgument), "{e}");
    // Text that does not fit the EDS type is refused before the bus.
    let e = can0
        .write_text(node(2), "Producer heartbeat time", "70000")
        .await
        .unwrap_err();
    assert_eq!(code_reason(&e).0, Some(Code::InvalidArgument), "{e}");
    assert!(e.to_string().contains("UNSIGNED16"), "{e}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn names_that_do_not_name_one_object_are_refused() {
    let (_server, c) = start().await;
    let can0 = c.canopen("can0");
    let read = |n: u32, name: &'static str| {
        let can0 = can0.clone();
        async move {
            can0.read_object(node(n), name, DataType::Unspecified)
                .await
                .unwrap_err()
        }
    };

    // Unknown: NOT_FOUND, OBJECT_NOT_FOUND.
    let e = read(1, "Flux capacitor").await;
    assert_eq!(
        code_reason(&e),
        (Some(Code::NotFound), "OBJECT_NOT_FOUND".into()),
        "{e}"
    );
    assert!(e.to_string().contains("Flux capacitor"), "{e}");

    // Ambiguous: INVALID_ARGUMENT listing the candidates with full names.
    let e = read(1, "Highest sub-index supported").await;
    assert_eq!(code_reason(&e).0, Some(Code::InvalidArgument), "{e}");
    let text = e.to_string();
    assert!(text.contains("ambiguous"), "{text}");
    assert!(
        text.contains("0x1018:00 (Identity object.Highest sub-index supported)"),
        "{text}"
    );

    // A node without EDS: FAILED_PRECONDITION saying so.
    let e = read(20, "Manufacturer device name").await;
    assert_eq!(code_reason(&e).0, Some(Code::FailedPrecondition), "{e}");
    assert!(e.to_string().contains("has no EDS"), "{e}");

    // A write without a type to an object the gateway has no EDS type for.
    let e = can0
        .write_text(node(20), ObjectAddress::new(0x1017, 0), "100")
        .await
        .unwrap_err();
    assert_eq!(code_reason(&e).0, Some(Code::InvalidArgument), "{e}");
    assert!(e.to_string().contains("give the type"), "{e}");

    // A name and an index together.
    let mut raw = c.clone();
    let e = raw
        .read_sdo(pb::ReadSdoRequest {
            bus: "can0".into(),
            node: 1,
            index: 0x1008,
            object: "Manufacturer device name".into(),
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(code_reason(&e).0, Some(Code::InvalidArgument), "{e}");
    assert!(e.to_string().contains("not both"), "{e}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn list_objects_shows_the_dictionary_of_the_eds() {
    let (_server, c) = start().await;
    let can0 = c.canopen("can0");
    let objects = can0.objects(node(1)).await.unwrap();
    let eds = Eds::parse(SIM_DRIVE_EDS).unwrap();
    assert_eq!(objects.len(), eds.od.variables().count());
    assert!(
        objects
            .windows(2)
            .all(|w| (w[0].index, w[0].subindex) < (w[1].index, w[1].subindex))
    );
    let find = |index, sub| {
        objects
            .iter()
            .find(|o| o.index == index && o.subindex == sub)
            .unwrap_or_else(|| panic!("0x{index:04X}:{sub} listed"))
    };
    let name = find(0x1008, 0);
    assert_eq!(name.name, "Manufacturer device name");
    assert_eq!(name.r#type, pb::DataType::VisibleString as i32);
    assert_eq!(name.access, pb::ObjectAccess::Const as i32);
    assert_eq!(name.default_text, "cangate sim drive");
    let cw = find(0x6040, 0);
    assert_eq!(cw.name, "Controlword");
    assert_eq!(cw.r#type, pb::DataType::Unsigned16 as i32);
    assert_eq!(cw.access, pb::ObjectAccess::Rww as i32);
    assert!(cw.pdo_mappable);
    let serial = find(0x1018, 4);
    assert_eq!(serial.name, "Identity object.Serial number");
    assert_eq!(
        (serial.object_name.as_str(), serial.sub_name.as_str()),
        ("Identity object", "Serial number")
    );
    assert_eq!(serial.object_type, "RECORD");
    let hb = find(0x1017, 0);
    assert_eq!(
        hb.default_value,
        Some(SdoValue::U16(1000).to_pb()),
        "{hb:?}"
    );
    // Every listed name reads back as its object.
    for o in objects.iter().filter(|o| o.index == 0x1018) {
        let by_name = can0
            .read_object(node(1), o.name.as_str(), DataType::Unspecified)
            .await
            .unwrap();
        let by_address = can0
            .read(
                node(1),
                ObjectAddress::new(o.index as u16, o.subindex as u8),
                DataType::Unspecified,
            )
            .await
            .unwrap();
        assert_eq!(by_name, by_address, "{}", o.name);
    }

    // Unknown bus and node: NOT_FOUND; a node without EDS:
    // FAILED_PRECONDITION.
    let e = c.canopen("can9").objects(node(1)).await.unwrap_err();
    assert_eq!(
        code_reason(&e),
        (Some(Code::NotFound), "BUS_NOT_FOUND".into())
    );
    let e = can0.objects(node(99)).await.unwrap_err();
    assert_eq!(
        code_reason(&e),
        (Some(Code::NotFound), "NODE_NOT_FOUND".into())
    );
    let e = can0.objects(node(20)).await.unwrap_err();
    assert_eq!(code_reason(&e).0, Some(Code::FailedPrecondition), "{e}");
    assert!(e.to_string().contains("has no EDS"), "{e}");
}
