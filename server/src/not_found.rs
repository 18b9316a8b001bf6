//! The runtime's "no such thing" error: a bus, axis, handwheel, CANsmc
//! master or slave named by a caller that does not exist. Its message
//! quotes only the start of the caller's name, so no message grows with
//! the caller's input, and lists the names that do exist.

/// At most this many bytes of a caller-chosen string go into a message.
pub const QUOTE_BYTES: usize = 64;

/// A caller-chosen string quoted for a message: in full when short, else
/// its start and its length.
pub fn quote_prefix(s: &str) -> String {
    if s.len() <= QUOTE_BYTES {
        return format!("{s:?}");
    }
    let mut end = QUOTE_BYTES;
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    format!("{:?}… ({} bytes)", &s[..end], s.len())
}

/// A named thing that does not exist.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{kind} {} not found{hint}", quote_prefix(.name))]
pub struct NotFound {
    /// What kind of thing ("bus", "axis", …).
    pub kind: &'static str,
    /// The name asked for.
    pub name: String,
    /// Extra help, e.g. the names that do exist: " (axes: X, Z)".
    pub hint: String,
}

impl NotFound {
    /// `kind` `name` is not one of `existing` (listed in the message under
    /// `plural`).
    pub fn among<'a>(
        kind: &'static str,
        plural: &str,
        name: &str,
        existing: impl IntoIterator<Item = &'a str>,
    ) -> NotFound {
        let names: Vec<&str> = existing.into_iter().collect();
        NotFound {
            kind,
            name: name.to_string(),
            hint: format!(" ({plural}: {})", names.join(", ")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn caller_names_are_quoted_by_their_start_only() {
        let e = NotFound::among("axis", "axes", &"x".repeat(20_000), ["X"]);
        let m = e.to_string();
        assert!(m.len() < 200, "{m}");
        assert!(
            m.contains("(20000 bytes)") && m.ends_with("(axes: X)"),
            "{m}"
        );
        // Multi-byte characters are cut at a boundary.
        assert!(quote_prefix(&"é".repeat(100)).contains("(200 bytes)"));
        assert_eq!(quote_prefix("X"), "\"X\"");
    }
}
