//! Compiles the .proto contract with protox (pure Rust, no system protoc) and
//! generates the prost messages and tonic stubs. The encoded descriptor set is
//! kept for gRPC reflection.

use prost::Message;
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let files = [
        "proto/cangate/v1/bus.proto",
        "proto/cangate/v1/canopen.proto",
        "proto/cangate/v1/axes.proto",
        "proto/cangate/v1/handwheel.proto",
        "proto/cangate/v1/cansmc.proto",
    ];
    for f in &files {
        println!("cargo:rerun-if-changed={f}");
    }
    let fds = protox::Compiler::new(["proto"])?
        .include_source_info(true)
        .include_imports(true)
        .open_files(files)?
        .file_descriptor_set();
    let out = PathBuf::from(std::env::var("OUT_DIR")?);
    std::fs::write(out.join("cangate_descriptor.bin"), fds.encode_to_vec())?;
    tonic_prost_build::configure()
        .build_server(true)
        .build_client(true)
        .emit_rerun_if_changed(false)
        .compile_fds(fds)?;
    Ok(())
}
