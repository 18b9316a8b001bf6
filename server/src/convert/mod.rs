//! Every conversion between the runtime's types and the protobuf messages,
//! one file per service. The edges that speak protobuf share them (the
//! gRPC services and the plant bridge carry the same messages), so they
//! live beside the edges, not in one of them.

pub mod axes;
pub mod bus;
pub mod canopen;
pub mod cansmc;
pub mod handwheel;
pub mod simulation;

/// A request message that does not say something the runtime can do: the
/// edge answers it as an invalid argument, with this text.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InvalidArgument(pub String);

impl std::fmt::Display for InvalidArgument {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
