//! Every conversion between the runtime's types and the protobuf messages,
//! one file per service.

pub mod axes;
pub mod bus;
pub mod canopen;
pub mod cansmc;
pub mod handwheel;
pub mod simulation;
