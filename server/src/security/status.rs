//! The status every response ends with, tidied at the edge in one place
//! (response headers of a trailers-only answer, or the trailers):
//!
//! - a request tonic could not decode (bad protobuf, a truncated message,
//!   an unknown compression flag) is the caller's fault: tonic says
//!   INTERNAL, the gateway says INVALID_ARGUMENT;
//! - the message is at most [`MAX_MESSAGE_BYTES`] (percent-encoded), so
//!   that no status, whatever caller string it quotes, comes near a
//!   client's metadata size limit (16 KB by default in most gRPC stacks).

use http::{HeaderMap, HeaderValue};

/// Longest `grpc-message` the gateway sends, in encoded bytes.
pub const MAX_MESSAGE_BYTES: usize = 1024;

/// How tonic's messages for undecodable requests begin (after percent
/// decoding).
const DECODE_FAILURES: &[&str] = &[
    "failed to decode Protobuf message",
    "Unexpected EOF decoding stream",
    "protocol error: received message with invalid compression flag",
    "Message compressed with",
];

/// Decodes the start of a percent-encoded message (enough to compare
/// prefixes; invalid escapes are kept as they are).
fn decoded_prefix(raw: &[u8], n: usize) -> String {
    let mut out = Vec::with_capacity(n);
    let mut i = 0;
    while i < raw.len() && out.len() < n {
        if raw[i] == b'%'
            && let Some(b) = raw
                .get(i + 1..i + 3)
                .and_then(|h| std::str::from_utf8(h).ok())
                .and_then(|h| u8::from_str_radix(h, 16).ok())
        {
            out.push(b);
            i += 3;
            continue;
        }
        out.push(raw[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// `cut` moved back so that the escaped bytes before it end with a whole
/// UTF-8 character (a character is escaped as up to four `%XX`).
fn utf8_boundary(encoded: &[u8], cut: usize) -> usize {
    let escaped = |at: usize| -> Option<u8> {
        (at >= 3 && encoded[at - 3] == b'%')
            .then(|| std::str::from_utf8(&encoded[at - 2..at]).ok())
            .flatten()
            .and_then(|h| u8::from_str_radix(h, 16).ok())
    };
    let mut at = cut;
    for have in 1..=4 {
        let Some(b) = escaped(at) else {
            return cut;
        };
        if b & 0xC0 != 0x80 {
            // The lead byte: how long its character is.
            let need = match b {
                0x00..=0x7F => 1,
                0xC0..=0xDF => 2,
                0xE0..=0xEF => 3,
                _ => 4,
            };
            return if have >= need { cut } else { at - 3 };
        }
        at -= 3;
    }
    cut
}

/// Tidies the `grpc-status`/`grpc-message` pair in `headers` (see the
/// module documentation). Headers without a status are left alone.
pub fn tidy(headers: &mut HeaderMap) {
    let Some(code) = headers
        .get("grpc-status")
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<i32>().ok())
    else {
        return;
    };
    let Some(message) = headers.get("grpc-message").map(|m| m.as_bytes().to_vec()) else {
        return;
    };
    if code == tonic::Code::Internal as i32 {
        let start = decoded_prefix(&message, 80);
        if DECODE_FAILURES.iter().any(|p| start.starts_with(p)) {
            headers.insert(
                "grpc-status",
                HeaderValue::from(tonic::Code::InvalidArgument as i32),
            );
        }
    }
    if message.len() > MAX_MESSAGE_BYTES {
        let mut cut = MAX_MESSAGE_BYTES;
        // Never split a %XX escape.
        if let Some(p) = message[cut - 2..cut].iter().position(|&b| b == b'%') {
            cut = cut - 2 + p;
        }
        cut = utf8_boundary(&message, cut);
        let mut short = message[..cut].to_vec();
        short.extend_from_slice(b"%E2%80%A6%20(message%20cut)");
        if let Ok(v) = HeaderValue::from_bytes(&short) {
            headers.insert("grpc-message", v);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn status(code: tonic::Code, message: &str) -> HeaderMap {
        let mut h = HeaderMap::new();
        tonic::Status::new(code, message)
            .add_header(&mut h)
            .unwrap();
        h
    }

    fn back(h: &HeaderMap) -> tonic::Status {
        tonic::Status::from_header_map(h).unwrap()
    }

    #[test]
    fn decode_failures_become_invalid_argument() {
        let mut h = status(
            tonic::Code::Internal,
            "failed to decode Protobuf message: MoveRequest.target: invalid wire type",
        );
        tidy(&mut h);
        let s = back(&h);
        assert_eq!(s.code(), tonic::Code::InvalidArgument);
        assert!(s.message().contains("invalid wire type"), "{s:?}");
        // Other internal errors stay internal.
        let mut h = status(tonic::Code::Internal, "something broke");
        tidy(&mut h);
        assert_eq!(back(&h).code(), tonic::Code::Internal);
    }

    #[test]
    fn long_messages_are_cut_without_splitting_escapes() {
        for pad in 0..4 {
            let msg = format!("{}{}", "a".repeat(pad), "é\"%<".repeat(2000));
            let mut h = status(tonic::Code::NotFound, &msg);
            tidy(&mut h);
            let raw = h.get("grpc-message").unwrap().as_bytes().len();
            assert!(raw <= MAX_MESSAGE_BYTES + 40, "{raw}");
            let s = back(&h);
            assert_eq!(s.code(), tonic::Code::NotFound);
            assert!(
                s.message().ends_with("… (message cut)"),
                "{:?}",
                s.message()
            );
            assert!(!s.message().contains('\u{FFFD}'), "{:?}", s.message());
        }
    }
}
