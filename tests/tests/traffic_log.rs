//! A bus's `decode = "decoded"` puts its CANopen traffic in the log in
//! words: an SDO read of a simulated node shows as its request and its
//! answer on the target `cangate::frames`.

use cangate_client::pb;
use cangate_tests::*;
use std::io::Write;
use std::sync::{Arc, Mutex};

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
"#;

/// Everything written to the log in this process.
#[derive(Clone, Default)]
struct Captured(Arc<Mutex<Vec<u8>>>);

impl Captured {
    fn text(&self) -> String {
        String::from_utf8_lossy(&self.0.lock().unwrap_or_else(|p| p.into_inner())).to_string()
    }
}

impl Write for Captured {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_decoded_bus_logs_an_sdo_read_in_words() {
    let captured = Captured::default();
    let writer = captured.clone();
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::new(
            "cangate_server=info,cangate::frames=info",
        ))
        .with_writer(move || writer.clone())
        .with_ansi(false)
        .init();
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
    server.shutdown();
}
