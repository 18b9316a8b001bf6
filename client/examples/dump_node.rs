//! Reads a CANopen node's identity and standard objects over SDO, typed,
//! and prints them; an object the node does not have shows its abort.
//!
//! ```sh
//! cargo run -p cangate-server &                      # the demo on 127.0.0.1:50051
//! cargo run -p cangate-client --example dump_node -- can0 1
//! cargo run -p cangate-client --example dump_node -- --server gw:50051 can0 0x05
//! ```
//!
//! Arguments: `[--server ADDR] [BUS] [NODE]` (defaults can0, 1).

use cangate_client::{ConnectOptions, DataType, Error, NodeId, ObjectAddress};
use std::time::Duration;

/// Objects of every CiA 301 device (and of CiA 402 drives).
const OBJECTS: &[(u16, u8, DataType, &str)] = &[
    (0x1000, 0, DataType::Unsigned32, "device type"),
    (0x1001, 0, DataType::Unsigned8, "error register"),
    (0x1008, 0, DataType::VisibleString, "device name"),
    (0x1009, 0, DataType::VisibleString, "hardware version"),
    (0x100A, 0, DataType::VisibleString, "software version"),
    (
        0x1017,
        0,
        DataType::Unsigned16,
        "producer heartbeat time (ms)",
    ),
    (0x1018, 1, DataType::Unsigned32, "vendor id"),
    (0x1018, 2, DataType::Unsigned32, "product code"),
    (0x1018, 3, DataType::Unsigned32, "revision"),
    (0x1018, 4, DataType::Unsigned32, "serial number"),
];

const DRIVE_OBJECTS: &[(u16, u8, DataType, &str)] = &[
    (0x6041, 0, DataType::Unsigned16, "statusword"),
    (0x6061, 0, DataType::Integer8, "modes of operation display"),
    (0x6064, 0, DataType::Integer32, "position actual value"),
    (0x606C, 0, DataType::Integer32, "velocity actual value"),
];

#[tokio::main]
async fn main() {
    if let Err(e) = run().await {
        eprintln!("dump_node: {e}");
        std::process::exit(1);
    }
}

async fn run() -> Result<(), Box<dyn std::error::Error>> {
    let mut server = std::env::var("CANGATE_SERVER").unwrap_or_else(|_| "127.0.0.1:50051".into());
    let mut positional = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--server" => server = args.next().ok_or("--server needs an address")?,
            _ => positional.push(a),
        }
    }
    let bus = positional.first().map_or("can0", String::as_str);
    let node: NodeId = positional.get(1).map_or("1", String::as_str).parse()?;
    let options = ConnectOptions {
        request_timeout: Some(Duration::from_secs(10)),
        ..Default::default()
    };
    let client = cangate_client::connect_with(&server, &options).await?;
    let canopen = client.canopen(bus);

    match canopen.node(node).await {
        Ok(n) => {
            println!(
                "node {node} on {bus}: {}",
                if n.name.is_empty() {
                    "(no configured name)"
                } else {
                    &n.name
                }
            );
            let state = cangate_client::pb::NmtState::try_from(n.state)
                .map_or("?", |s| s.as_str_name().trim_start_matches("NMT_STATE_"));
            println!("  NMT state          {state}");
            match n.heartbeat_age_ms {
                Some(age) => println!(
                    "  last heartbeat     {age} ms ago{}",
                    if n.heartbeat_lost { " (LOST)" } else { "" }
                ),
                None => println!("  last heartbeat     never"),
            }
            if let Some(e) = n.active_error {
                println!("  active error       0x{:04X} {}", e.code, e.code_name);
            }
        }
        Err(Error::NotFound { message, .. }) => println!("node {node} on {bus}: {message}"),
        Err(e) => return Err(e.into()),
    }

    let mut is_drive = false;
    println!("objects:");
    for &(index, sub, ty, what) in OBJECTS {
        let addr = ObjectAddress::new(index, sub);
        let value = canopen.read(node, addr, ty).await;
        if index == 0x1000 {
            is_drive = matches!(&value, Ok(v) if v.as_u64().is_some_and(|t| t & 0xFFFF == 402));
        }
        show(addr, what, value)?;
    }
    if is_drive {
        println!("CiA 402 drive:");
        for &(index, sub, ty, what) in DRIVE_OBJECTS {
            let addr = ObjectAddress::new(index, sub);
            show(addr, what, canopen.read(node, addr, ty).await)?;
        }
    }
    Ok(())
}

/// One line per object; an SDO abort is an answer too, anything else ends
/// the dump.
fn show(
    addr: ObjectAddress,
    what: &str,
    value: Result<cangate_client::SdoValue, Error>,
) -> Result<(), Error> {
    match value {
        Ok(v) => println!("  {addr}  {what:<30} {v}"),
        Err(Error::SdoAbort { code, name, .. }) => {
            println!("  {addr}  {what:<30} (abort 0x{code:08X} {name})")
        }
        Err(e @ Error::Timeout { .. }) => println!("  {addr}  {what:<30} ({e})"),
        Err(e) => return Err(e),
    }
    Ok(())
}
