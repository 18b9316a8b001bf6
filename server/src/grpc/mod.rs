//! gRPC services and the conversions to and from the protobuf types.

pub mod axes_service;
pub mod bus_service;
pub mod canopen_service;
pub mod cansmc_service;
pub mod convert;
pub mod handwheel_service;
