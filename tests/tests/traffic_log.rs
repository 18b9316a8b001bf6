//! What the log says and where: a bus's `decode = "decoded"` puts its
//! CANopen traffic in words (an SDO read of a simulated node shows as its
//! request and its answer on the target `cangate::frames`, in the bus's
//! span), and a line logged while serving a call is in the call's
//! `request` span (method and peer).

use cangate_client::pb;
use cangate_tests::*;

const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"
decode = "decoded"

[[canopen]]
bus = "can0"

[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true

[[axis]]
name = "X"
bus = "can0"
node = 1
counts_per_unit = 1000.0
min_position = -100.0
max_position = 100.0
max_velocity = 50.0
max_acceleration = 500.0
"#;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_decoded_bus_logs_an_sdo_read_in_words() {
    let captured = cangate_tests::log::capture_log(
        "cangate_server=info,cangate::frames=info,cangate::audit=info",
    );
    let server = start_server(CONFIG).await;
    let c = client(&server).await;
    c.canopen_client()
        .read_sdo(pb::ReadSdoRequest {
            bus: "can0".into(),
            node: 1,
            index: 0x1000,
            subindex: 0,
            r#type: pb::DataType::Unspecified as i32,
            options: None,
            object: String::new(),
        })
        .await
        .expect("the simulated drive answers");
    // The log task writes the lines as it reads the frames: wait for them
    // (bounded), not for a time.
    let wanted = [
        "tx 601 [8] 40 00 10 00",
        "SDO upload request 0x1000:00 to node 1",
        "SDO upload response 0x1000:00 from node 1 (expedited)",
    ];
    let t0 = std::time::Instant::now();
    let text = loop {
        let text = captured.text();
        if wanted.iter().all(|w| text.contains(w)) {
            break text;
        }
        assert!(t0.elapsed() < WAIT, "missing {wanted:?} in:\n{text}");
        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
    };
    let request = text
        .lines()
        .find(|l| l.contains("SDO upload request 0x1000:00 to node 1"))
        .unwrap();
    // The bus's span names the bus once; the target says what the line is.
    assert!(
        request.contains("bus{bus=can0}") && request.contains("cangate::frames"),
        "{request}"
    );

    // The audit line of a call is in the call's span.
    pb::axes_client::AxesClient::new(c.channel())
        .acquire_control(pb::AcquireControlRequest {
            axes: vec!["X".into()],
            ttl_ms: 1000,
            client_name: "log test".into(),
        })
        .await
        .unwrap();
    let text = captured.text();
    let granted = text
        .lines()
        .find(|l| l.contains("acquire control"))
        .unwrap_or_else(|| panic!("no audit line for AcquireControl in:\n{text}"));
    assert!(
        granted.contains("request{method=/cangate.v1.Axes/AcquireControl peer=127.0.0.1:"),
        "{granted}"
    );
    server.shutdown();
}
