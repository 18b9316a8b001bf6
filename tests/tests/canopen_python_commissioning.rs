//! The gateway's commissioning services against python `canopen` as an
//! independent implementation, attached to the gateway's virtual bus
//! through the cangate python-can interface:
//!
//! - a TPDO remapped with ConfigurePdo is read back by python-canopen's own
//!   PDO reader (its SDO client, its parsing of 0x1800+/0x1A00+) with the
//!   same COB-ID, transmission type, inhibit time, event timer and
//!   mapping;
//! - a TIME python-canopen's TimeProducer sends for a given instant has
//!   exactly the bytes of the gateway's TIME_OF_DAY encoder for it;
//! - a DCF exported by ExportDcf is imported by python-canopen's EDS/DCF
//!   importer with the node id, bitrate and ParameterValues it holds.

#[path = "common/python_peer.rs"]
mod python_peer;
#[path = "common/vcan.rs"]
mod vcan;

use anyhow::{Result, anyhow, ensure};
use cangate_canopen::time_of_day::TimeOfDay;
use cangate_client::{NodeId, SdoValue, pb};
use python_peer::{Peer, python_or_skip, script};
use std::path::{Path, PathBuf};
use std::time::Duration;

const CONFIG: &str = r#"
listen = "127.0.0.1:0"
[[bus]]
name = "can0"
backend = "virtual"
bitrate = 1000000
[[canopen]]
bus = "can0"
[[canopen.node]]
id = 1
name = "drive"
eds = "builtin:drive"
simulate = true
"#;

/// A Unix instant exact in binary floating point (python passes it as a
/// float): 2025-11-24 12:00:00.25 UTC.
const INSTANT_MS: u64 = 1_763_985_600_250;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

#[test]
fn python_canopen_reads_what_the_gateway_commissioned() {
    let test = "python_canopen_reads_what_the_gateway_commissioned";
    let Some(python) = python_or_skip(test, &["can", "canopen", "cangate"]) else {
        return;
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async {
        tokio::time::timeout(Duration::from_secs(180), scenario(&python))
            .await
            .unwrap_or_else(|_| Err(anyhow!("not finished within 180 s")))
    })
    .unwrap_or_else(|e| panic!("{test}: {e:?}"));
}

async fn scenario(python: &Path) -> Result<()> {
    let config = cangate_server::Config::from_toml(CONFIG)?;
    let server = cangate_server::start(&config).await?;
    let mut c = cangate_client::connect(&format!("http://{}", server.addr)).await?;
    let co = c.canopen("can0");
    let node = NodeId::new(1)?;

    // TPDO2 remapped by the gateway.
    co.configure_pdo(
        node,
        pb::PdoConfiguration {
            kind: pb::PdoKind::Tpdo as i32,
            pdo: 2,
            cob_id: 0x2A1,
            enabled: true,
            // Event-driven: python-canopen reads the inhibit time and the
            // event timer only for those.
            transmission_type: 254,
            inhibit_time_100us: 30,
            event_timer_ms: 40,
            mapping: vec![
                pb::PdoMappedObject {
                    index: 0x6041,
                    bits: 16,
                    ..Default::default()
                },
                pb::PdoMappedObject {
                    index: 0x6061,
                    bits: 8,
                    ..Default::default()
                },
            ],
        },
    )
    .await?;

    // Values for the DCF.
    co.write(
        node,
        cangate_client::ObjectAddress::new(0x1017, 0),
        SdoValue::U16(250),
    )
    .await?;
    co.write(
        node,
        cangate_client::ObjectAddress::new(0x6081, 0),
        SdoValue::U32(4321),
    )
    .await?;
    let dcf = co.export_dcf(node).await?;
    let dir = std::env::temp_dir().join(format!("cangate-py-dcf-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let dcf_path = dir.join("drive.dcf");
    std::fs::write(&dcf_path, &dcf.dcf)?;

    // TIME frames on the bus, as the gateway sees them.
    let mut times = c
        .stream_frames(pb::StreamFramesRequest {
            bus: "can0".into(),
            filters: vec![pb::FrameFilter {
                id: 0x100,
                mask: 0x7FF,
                format: pb::IdFormat::Standard as i32,
                invert: false,
            }],
            ..Default::default()
        })
        .await?;

    let eds = repo().join("crates/canopen/eds/cangate-drive.eds");
    let instant = format!("{}.{:03}", INSTANT_MS / 1000, INSTANT_MS % 1000);
    let mut peer = Peer::spawn(
        python,
        &script("commissioning_peer.py"),
        &[
            "--node",
            "1",
            "--eds",
            &eds.to_string_lossy(),
            "--tpdo",
            "2",
            "--time",
            &instant,
            "--dcf",
            &dcf_path.to_string_lossy(),
        ],
        &[("CANGATE_SERVER", format!("http://{}", server.addr))],
    )?;
    let lines = peer.lines_until("BYE", Duration::from_secs(90)).await?;
    peer.finish(Duration::from_secs(10)).await?;

    let tpdo = lines
        .iter()
        .find(|l| l.starts_with("TPDO 2 "))
        .ok_or_else(|| anyhow!("no TPDO line in {lines:?}"))?;
    ensure!(
        tpdo == "TPDO 2 cob=0x2A1 enabled=1 type=254 inhibit=30 event=40 map=6041:00/16,6061:00/8",
        "python-canopen reads TPDO2 differently: {tpdo}"
    );

    // The TIME python sent, against the gateway's encoding of the instant.
    let expected = TimeOfDay::from_unix(Duration::from_millis(INSTANT_MS))?.encode();
    let frame = tokio::time::timeout(Duration::from_secs(10), async {
        loop {
            let m = times
                .message()
                .await?
                .ok_or_else(|| anyhow!("stream ended"))?;
            for ev in m.events {
                if let Some(pb::stream_event::Event::Frame(f)) = ev.event {
                    return Ok::<_, anyhow::Error>(f);
                }
            }
        }
    })
    .await
    .map_err(|_| anyhow!("python's TIME never reached the gateway"))??;
    ensure!(
        frame.data == expected,
        "python-canopen's TIME {:02X?} differs from the gateway's {expected:02X?}",
        frame.data
    );

    let dcf_line = lines
        .iter()
        .find(|l| l.starts_with("DCF "))
        .ok_or_else(|| anyhow!("no DCF line in {lines:?}"))?;
    ensure!(
        dcf_line == "DCF node=1 bitrate=1000000 1017=250 6081=4321 1018:1=1234",
        "python-canopen imports the DCF differently: {dcf_line}"
    );

    let _ = std::fs::remove_dir_all(&dir);
    server.shutdown();
    server
        .wait(Duration::from_secs(5))
        .await
        .map_err(|e| anyhow!("shutdown: {e}"))
}
