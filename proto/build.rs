//! Compiles the .proto contract with protox (pure Rust, no system protoc) and
//! generates the prost messages and tonic stubs. The encoded descriptor set is
//! kept for gRPC reflection.
//!
//! With the `serde` feature, pbjson generates Serialize/Deserialize (the
//! canonical proto3 JSON mapping) for every message and enum; the impls are
//! included at the end of the generated module (`cangate.v1.rs`), so
//! `src/lib.rs` stays as it is.

use prost::Message;
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let files = [
        "proto/cangate/v1/bus.proto",
        "proto/cangate/v1/canopen.proto",
        "proto/cangate/v1/axes.proto",
        "proto/cangate/v1/handwheel.proto",
        "proto/cangate/v1/cansmc.proto",
        "proto/cangate/v1/session.proto",
        "proto/cangate/v1/lss.proto",
        "proto/cangate/v1/bridge.proto",
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
    #[cfg(feature = "serde")]
    let encoded = fds.encode_to_vec();
    tonic_prost_build::configure()
        .build_server(true)
        .build_client(true)
        .emit_rerun_if_changed(false)
        .compile_fds(fds)?;
    #[cfg(feature = "serde")]
    serde_impls(&out, &encoded)?;
    Ok(())
}

/// Writes `cangate.v1.serde.rs` (pbjson) and includes it from the module
/// prost generated.
#[cfg(feature = "serde")]
fn serde_impls(
    out: &std::path::Path,
    descriptors: &[u8],
) -> Result<(), Box<dyn std::error::Error>> {
    pbjson_build::Builder::new()
        .register_descriptors(descriptors)?
        .out_dir(out)
        // Every field, also at its default value: a reader of the CLI's
        // --json sees `"homed": false` rather than nothing.
        .emit_fields()
        .build(&[".cangate.v1"])?;
    let module = out.join("cangate.v1.rs");
    let mut text = std::fs::read_to_string(&module)?;
    text.push_str(
        "\n// Canonical proto3 JSON (pbjson), feature `serde`.\n\
         include!(concat!(env!(\"OUT_DIR\"), \"/cangate.v1.serde.rs\"));\n",
    );
    std::fs::write(module, text)?;
    Ok(())
}
