//! DCF (CiA 306) end to end: a node's live values exported as a DCF
//! (ExportDcf), that DCF parsed back with the gateway's own EDS parser,
//! and given to another gateway's node as `dcf`, whose boot procedure
//! writes the configuration values back (rw objects and whole PDOs; a
//! process value like the controlword is not written).

use cangate_canopen::ObjectAddress;
use cangate_canopen::eds::Eds;
use cangate_canopen::value::Value;
use cangate_client::{NodeId, SdoValue};
use cangate_tests::*;
use std::time::Duration;

const SOURCE: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"
bitrate = 500000
[[canopen]]
bus = "can0"
[[canopen.node]]
id = 1
name = "X axis drive"
eds = "builtin:drive"
simulate = true
[[canopen.node]]
id = 9
name = "no eds"
"#;

fn node(n: u32) -> NodeId {
    NodeId::new(n).unwrap()
}

fn addr(index: u16, sub: u8) -> cangate_client::ObjectAddress {
    cangate_client::ObjectAddress::new(index, sub)
}

/// (object, value written on the source node, as the DCF holds it).
fn changes() -> Vec<(u16, u8, SdoValue, Value)> {
    vec![
        (0x1017, 0, SdoValue::U16(77), Value::Unsigned16(77)),
        (0x6081, 0, SdoValue::U32(1234), Value::Unsigned32(1234)),
        (0x6098, 0, SdoValue::I8(17), Value::Integer8(17)),
        (0x607D, 1, SdoValue::I32(-5000), Value::Integer32(-5000)),
        // TPDO1's event timer: applied as the whole TPDO.
        (0x1800, 5, SdoValue::U16(25), Value::Unsigned16(25)),
        // A process value: exported, never written back at boot.
        (0x6040, 0, SdoValue::U16(6), Value::Unsigned16(6)),
    ]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_nodes_values_go_out_as_a_dcf_and_come_back_at_boot() {
    let server = start_server(SOURCE).await;
    let c = client(&server).await;
    let co = c.canopen("can0");
    for (index, sub, v, _) in changes() {
        co.write(node(1), addr(index, sub), v).await.unwrap();
    }
    let r = co.export_dcf(node(1)).await.unwrap();
    assert!(r.objects_read >= 40, "{} objects read", r.objects_read);
    assert!(
        r.skipped
            .iter()
            .any(|s| s.index == 0x2100 && s.reason.contains("DOMAIN")),
        "the firmware DOMAIN is left out: {:?}",
        r.skipped
    );
    let dcf = Eds::parse(&r.dcf).expect("the DCF parses");
    let c1 = dcf.commissioning.as_ref().expect("[DeviceComissioning]");
    assert_eq!(c1.node_id.map(|n| n.get()), Some(1));
    assert_eq!(c1.node_name.as_deref(), Some("X axis drive"));
    assert_eq!(c1.baud_rate, Some(500));
    assert_eq!(c1.network_name.as_deref(), Some("can0"));
    let n1 = cangate_canopen::NodeId::new(1).unwrap();
    let value = |index, sub| {
        dcf.od
            .get(ObjectAddress::new(index, sub))
            .and_then(|v| v.parameter_value.as_ref())
            .map(|p| p.resolve(n1))
    };
    for (index, sub, _, expected) in changes() {
        assert_eq!(value(index, sub), Some(expected), "0x{index:04X}:{sub}");
    }
    // The live identity is in it too.
    assert_eq!(value(0x1018, 1), Some(Value::Unsigned32(0x4D2)));

    // A node without an EDS cannot be exported.
    let e = co.export_dcf(node(9)).await.unwrap_err();
    assert_eq!(e.code(), Some(tonic::Code::FailedPrecondition), "{e:?}");

    // Another gateway's node boots with the DCF.
    let dir = std::env::temp_dir().join(format!("cangate-dcf-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("x-axis.dcf");
    std::fs::write(&path, &r.dcf).unwrap();
    let target = format!(
        r#"
[[bus]]
name = "can0"
backend = "virtual"
[[canopen]]
bus = "can0"
[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true
boot = true
dcf = "{}"
"#,
        path.display()
    );
    let target: &'static str = Box::leak(target.into_boxed_str());
    let server2 = start_server(target).await;
    let c2 = client(&server2).await;
    let co2 = c2.canopen("can0");
    tokio::time::timeout(WAIT, async {
        while get_node(&c2, 1).await.state != cangate_client::pb::NmtState::Operational as i32 {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("booted and started");
    let read = |index, sub, ty| {
        let co2 = co2.clone();
        async move { co2.read(node(1), addr(index, sub), ty).await.unwrap() }
    };
    use cangate_client::DataType as T;
    assert_eq!(read(0x1017, 0, T::Unsigned16).await, SdoValue::U16(77));
    assert_eq!(read(0x6081, 0, T::Unsigned32).await, SdoValue::U32(1234));
    assert_eq!(read(0x6098, 0, T::Integer8).await, SdoValue::I8(17));
    assert_eq!(read(0x607D, 1, T::Integer32).await, SdoValue::I32(-5000));
    assert_eq!(read(0x1800, 5, T::Unsigned16).await, SdoValue::U16(25));
    assert_eq!(
        read(0x6040, 0, T::Unsigned16).await,
        SdoValue::U16(0),
        "the controlword is process data: not written at boot"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_dcf_needs_the_boot_procedure_and_a_readable_file() {
    let config = |extra: &str| {
        format!(
            "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\n[[canopen]]\nbus = \"can0\"\n\
             [[canopen.node]]\nid = 1\neds = \"builtin:drive\"\n{extra}"
        )
    };
    let e = cangate_server::Config::from_toml(&config("dcf = \"x.dcf\"\n")).unwrap_err();
    assert!(e.to_string().contains("set boot = true"), "{e}");
    let e =
        cangate_server::Config::from_toml(&config("boot = true\ndcf = \"/nonexistent/x.dcf\"\n"))
            .unwrap_err();
    assert!(e.to_string().contains("/nonexistent/x.dcf"), "{e}");
}

#[derive(Clone, Default)]
struct Captured(std::sync::Arc<std::sync::Mutex<Vec<u8>>>);

impl std::io::Write for Captured {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// The drive's EDS with the controlword's section turned into what a
/// hand-edited DCF says: `AccessType=rw`, `ParameterValue=0x000F`, and
/// the profile velocity (a real configuration value) given too.
fn dcf_writing_the_controlword() -> String {
    let mut out = String::new();
    let mut section = String::new();
    for line in cangate_canopen::eds::SIM_DRIVE_EDS.lines() {
        if line.starts_with('[') {
            section = line.trim().to_string();
        }
        match (section.as_str(), line.split('=').next()) {
            ("[6040]", Some("AccessType")) => {
                out.push_str("AccessType=rw\nParameterValue=0x000F\n")
            }
            ("[6081]", Some("AccessType")) => out.push_str("AccessType=rw\nParameterValue=777\n"),
            _ => {
                out.push_str(line);
                out.push('\n');
            }
        }
    }
    out
}

/// A DCF that calls the controlword `rw` and gives it 0x000F: the boot
/// takes the access from the node's EDS and never writes the CiA 402
/// command objects, so 0x6040 reads back unchanged, the real configuration
/// value is written, and the skip is logged naming the object.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_dcf_never_writes_the_controlword() {
    let captured = Captured::default();
    let writer = captured.clone();
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::new("cangate_server=warn"))
        .with_writer(move || writer.clone())
        .with_ansi(false)
        .init();
    let dir = std::env::temp_dir().join(format!("cangate-dcf-cw-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("edited.dcf");
    std::fs::write(&path, dcf_writing_the_controlword()).unwrap();
    let config = format!(
        r#"
[[bus]]
name = "can0"
backend = "virtual"
[[canopen]]
bus = "can0"
[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true
boot = true
dcf = "{}"
"#,
        path.display()
    );
    let server = start_server(Box::leak(config.into_boxed_str())).await;
    let c = client(&server).await;
    let co = c.canopen("can0");
    tokio::time::timeout(WAIT, async {
        while get_node(&c, 1).await.state != cangate_client::pb::NmtState::Operational as i32 {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("booted and started");
    use cangate_client::DataType as T;
    assert_eq!(
        co.read(node(1), addr(0x6081, 0), T::Unsigned32)
            .await
            .unwrap(),
        SdoValue::U32(777),
        "the configuration value is written"
    );
    assert_eq!(
        co.read(node(1), addr(0x6040, 0), T::Unsigned16)
            .await
            .unwrap(),
        SdoValue::U16(0),
        "the controlword is never written from a DCF"
    );
    let log = String::from_utf8(captured.0.lock().unwrap().clone()).unwrap();
    let line = log
        .lines()
        .find(|l| l.contains("DCF value not written") && l.contains("0x6040"))
        .unwrap_or_else(|| panic!("no log line for 0x6040 in:\n{log}"));
    assert!(line.contains("CiA 402"), "{line}");
    let _ = std::fs::remove_dir_all(&dir);
}
