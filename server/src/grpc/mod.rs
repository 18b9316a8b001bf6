//! gRPC services and the conversions to and from the protobuf types.

pub mod axes_service;
pub mod bus_service;
pub mod canopen_service;
pub mod cansmc_service;
pub mod error;
mod forward;
pub mod handwheel_service;
pub mod lss_service;
mod runtime_errors;
pub mod sdo_session;
pub mod session_service;
pub mod setpoint_streams;
pub mod simulator_service;

/// Who made a call, for audit lines and lease holders: the authenticated
/// identity and the peer address (`operator-1@10.0.0.5:41234`), or only
/// the address when authentication is off.
pub(crate) fn caller<T>(req: &tonic::Request<T>) -> String {
    let addr = req
        .remote_addr()
        .map_or_else(|| "unknown".to_string(), |a| a.to_string());
    match req.extensions().get::<crate::security::Identity>() {
        // Names come from the configuration or a verified certificate;
        // still, a certificate's CN is not ours to size.
        Some(id) if id.method != "none" => format!("{}@{addr}", clip(&id.name, 64)),
        _ => addr,
    }
}

/// `s` cut to at most `bytes` bytes at a character boundary.
fn clip(s: &str, bytes: usize) -> &str {
    if s.len() <= bytes {
        return s;
    }
    let mut end = bytes;
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    &s[..end]
}
