//! The cangate gRPC contract: generated prost messages and tonic client and
//! server stubs for every service in `proto/cangate/v1/*.proto`.
//!
//! The `.proto` files are the API reference; every field is documented there
//! and the documentation is carried into the generated Rust types.

#![deny(missing_docs, unreachable_pub)]
// A dependency nothing uses fails CI (clippy -D warnings). Test builds are
// left out: their dev-dependencies serve the integration tests.
#![cfg_attr(not(test), warn(unused_crate_dependencies))]

/// Package `cangate.v1`: the code prost and tonic generate from the
/// `.proto` files. Their comments become the doc comments here, so the
/// crate's `missing_docs` holds for this module too (an undocumented field
/// or message fails the build); only clippy's style lints are off, the
/// style being the generators'.
#[allow(clippy::all)]
pub mod v1 {
    tonic::include_proto!("cangate.v1");
}

pub mod frames;

/// Encoded `FileDescriptorSet` of every cangate proto, for gRPC reflection.
pub const FILE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/cangate_descriptor.bin"));
