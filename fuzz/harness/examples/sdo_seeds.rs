//! Writes the SDO seed scripts (`fuzz/seeds/sdo_client`, `fuzz/seeds/sdo_server`)
//! from real exchanges between our SDO client and the simulated drive's SDO
//! server, one per protocol, in the script format of the harness: the
//! client scripts replay the server's responses, the server scripts replay
//! the client's requests.
//!
//! Run from `fuzz/`: `cargo run -p cangate-fuzz-harness --no-default-features --example sdo_seeds`

use std::time::Duration;

use cangate_can::Frame;
use cangate_canopen::eds::Eds;
use cangate_canopen::sdo::{
    BlockOptions, Mode, SdoClient, SdoServer, ServerOptions, TransferOptions,
};
use cangate_canopen::{NodeId, ObjectAddress};
use cangate_sim::SimStore;

/// The node the harness's server target uses; the client script's first
/// byte selects node `byte % 127 + 1`.
const NODE: u8 = 5;

struct Case {
    name: &'static str,
    addr: ObjectAddress,
    block: Option<(u8, bool)>,
    /// Download length (the harness writes bytes `i * 7`), or an upload.
    download: Option<u16>,
    server_block_size: u8,
}

fn main() {
    let text = include_str!("../../../crates/canopen/eds/cangate-drive.eds");
    let eds = Eds::parse(text).expect("drive EDS");
    let node = NodeId::new(u32::from(NODE)).expect("node");
    let device_name = ObjectAddress::new(0x1008, 0);
    let device_type = ObjectAddress::new(0x1000, 0);
    let firmware = ObjectAddress::new(0x2100, 0);
    let cases = [
        Case {
            name: "expedited_upload",
            addr: device_type,
            block: None,
            download: None,
            server_block_size: 127,
        },
        Case {
            name: "segmented_upload",
            addr: device_name,
            block: None,
            download: None,
            server_block_size: 127,
        },
        Case {
            name: "block_upload_crc",
            addr: device_name,
            block: Some((4, true)),
            download: None,
            server_block_size: 127,
        },
        Case {
            name: "block_upload_no_crc",
            addr: device_name,
            block: Some((2, false)),
            download: None,
            server_block_size: 127,
        },
        Case {
            name: "expedited_download",
            addr: firmware,
            block: None,
            download: Some(3),
            server_block_size: 127,
        },
        Case {
            name: "segmented_download",
            addr: firmware,
            block: None,
            download: Some(40),
            server_block_size: 127,
        },
        Case {
            name: "empty_download",
            addr: firmware,
            block: None,
            download: Some(0),
            server_block_size: 127,
        },
        Case {
            name: "block_download_crc",
            addr: firmware,
            block: Some((127, true)),
            download: Some(60),
            server_block_size: 3,
        },
        Case {
            name: "abort_unknown_object",
            addr: ObjectAddress::new(0x5FFF, 1),
            block: None,
            download: None,
            server_block_size: 127,
        },
    ];
    let out = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../seeds");
    for case in cases {
        let mut store = SimStore::new(eds.od.clone(), node);
        let server_options = ServerOptions {
            block_size: case.server_block_size,
            ..ServerOptions::default()
        };
        let mut server = SdoServer::new(node, server_options);
        let mut client = SdoClient::new(node);
        let mut client_script = vec![NODE - 1];
        let mut header = 0u8;
        let mode = match case.block {
            Some((block_size, crc)) => {
                header |= 1 | if crc { 2 } else { 0 };
                Mode::Block(BlockOptions {
                    block_size,
                    crc,
                    switch_threshold: 0,
                    fallback: false,
                })
            }
            None => Mode::Auto,
        };
        header |= 8; // indicate size
        if case.download.is_some() {
            header |= 0x20;
        }
        client_script.push(header);
        client_script.extend(case.addr.index.to_le_bytes());
        client_script.push(case.addr.sub);
        if let Some((block_size, _)) = case.block {
            client_script.extend([block_size, 0]);
        }
        let opts = TransferOptions {
            mode,
            timeout: None,
            indicate_size: true,
        };
        let now = Duration::ZERO;
        let mut to_server: Vec<Frame> = match case.download {
            Some(len) => {
                client_script.extend(len.to_le_bytes());
                let data = (0..usize::from(len)).map(|i| (i * 7) as u8).collect();
                client
                    .start_download(case.addr, data, opts, now)
                    .expect("start")
            }
            None => client.start_upload(case.addr, opts, now).expect("start"),
        };
        let mut server_script = vec![0u8, case.server_block_size];
        let mut done = false;
        for _ in 0..1000 {
            let mut to_client = Vec::new();
            for f in to_server.drain(..) {
                server_script.push(0x08);
                server_script.extend(f.data());
                to_client.extend(server.on_frame(&f, now, &mut store));
            }
            for f in &to_client {
                client_script.extend([0x00, 0x08]);
                client_script.extend(f.data());
                let step = client.on_frame(f, now);
                to_server.extend(step.frames);
                if let Some(result) = step.completed {
                    println!("{}: {:?}", case.name, result.map(|_| "ok"));
                    done = true;
                }
            }
            if to_server.is_empty() {
                break;
            }
        }
        assert!(done, "{} did not complete", case.name);
        for (dir, script) in [("sdo_client", client_script), ("sdo_server", server_script)] {
            let path = out.join(dir);
            std::fs::create_dir_all(&path).expect("seed directory");
            std::fs::write(path.join(case.name), script).expect("seed file");
        }
    }
}
