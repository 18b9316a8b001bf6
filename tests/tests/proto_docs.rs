//! The `.proto` files are the contract for HMI developers in any language,
//! so every declaration in them carries a comment: each message, enum,
//! service, rpc, oneof, field and enum value needs a comment directly above
//! it (comment lines only, no blank line in between) or a trailing comment
//! on its own line. The test lists every declaration without one as
//! `file:line`.
//!
//! The parser is deliberately small: it strips comments (`//` and `/* */`,
//! not inside string literals), splits the rest into tokens with their line
//! numbers and walks the proto3 grammar far enough to find declarations:
//! nested messages and enums, `oneof`, `map<K, V>`, `optional`,
//! `repeated`, `reserved`, `extensions`, `option` statements (also with
//! aggregate values) and field options in brackets, rpcs over several
//! lines and rpcs with an options body. Anything it does not understand is
//! reported as an error, so the check cannot pass by skipping a construct.

use std::path::{Path, PathBuf};

/// The repository root (`CARGO_MANIFEST_DIR` is `<repo>/tests`).
fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ has a parent")
        .to_path_buf()
}

/// Every `.proto` file below `dir` (recursively), sorted.
fn proto_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let entries = std::fs::read_dir(&d).unwrap_or_else(|e| panic!("{}: {e}", d.display()));
        for entry in entries {
            let path = entry.expect("directory entry").path();
            if path.is_dir() {
                stack.push(path);
            } else if path.extension().is_some_and(|e| e == "proto") {
                out.push(path);
            }
        }
    }
    out.sort();
    out
}

/// What the comment scanner found on one source line.
#[derive(Debug, Clone, Copy, Default)]
struct LineInfo {
    /// The line has code (anything but comments and white space).
    code: bool,
    /// The line has a comment (possibly empty).
    comment: bool,
    /// The line has a comment with text in it (not just `//`).
    comment_text: bool,
}

/// A token with its 1-based line.
#[derive(Debug, Clone, PartialEq)]
struct Token {
    text: String,
    line: usize,
}

/// A declaration that needs a comment.
#[derive(Debug, Clone, PartialEq)]
struct Decl {
    /// "message", "enum", "service", "rpc", "oneof", "field", "enum value".
    kind: &'static str,
    /// Its name.
    name: String,
    /// Line of its first token.
    line: usize,
    /// Line of the token that ends its header (`;` or `{`).
    end_line: usize,
}

/// Records a comment with body `body` on a line: any comment, and whether
/// it says something (more than `//`, `*` and white space).
fn note_comment(info: &mut LineInfo, body: &str) {
    info.comment = true;
    if body
        .chars()
        .any(|c| !c.is_whitespace() && c != '*' && c != '/')
    {
        info.comment_text = true;
    }
}

/// Splits `src` into tokens (comments and string contents removed from
/// consideration) and records per line whether it holds code and comments.
fn scan(src: &str) -> (Vec<Token>, Vec<LineInfo>) {
    let lines: Vec<&str> = src.lines().collect();
    let mut info = vec![LineInfo::default(); lines.len()];
    let mut tokens = Vec::new();
    let mut in_block = false;
    for (idx, text) in lines.iter().enumerate() {
        let line = idx + 1;
        let chars: Vec<char> = text.chars().collect();
        let mut i = 0;
        while i < chars.len() {
            if in_block {
                let start = i;
                while i < chars.len() && !(chars[i] == '*' && chars.get(i + 1) == Some(&'/')) {
                    i += 1;
                }
                let body: String = chars[start..i].iter().collect();
                note_comment(&mut info[idx], &body);
                if i < chars.len() {
                    in_block = false;
                    i += 2;
                }
                continue;
            }
            let c = chars[i];
            if c.is_whitespace() {
                i += 1;
            } else if c == '/' && chars.get(i + 1) == Some(&'/') {
                let body: String = chars[i + 2..].iter().collect();
                note_comment(&mut info[idx], &body);
                break;
            } else if c == '/' && chars.get(i + 1) == Some(&'*') {
                in_block = true;
                info[idx].comment = true;
                i += 2;
            } else if c == '"' || c == '\'' {
                // A string literal: one token, `//` inside it is no comment.
                let start = i;
                i += 1;
                while i < chars.len() && chars[i] != c {
                    if chars[i] == '\\' {
                        i += 1;
                    }
                    i += 1;
                }
                i = (i + 1).min(chars.len());
                info[idx].code = true;
                tokens.push(Token {
                    text: chars[start..i].iter().collect(),
                    line,
                });
            } else if c.is_alphanumeric() || c == '_' || c == '.' || c == '-' || c == '+' {
                let start = i;
                while i < chars.len()
                    && (chars[i].is_alphanumeric() || matches!(chars[i], '_' | '.' | '-' | '+'))
                {
                    i += 1;
                }
                info[idx].code = true;
                tokens.push(Token {
                    text: chars[start..i].iter().collect(),
                    line,
                });
            } else {
                info[idx].code = true;
                tokens.push(Token {
                    text: c.to_string(),
                    line,
                });
                i += 1;
            }
        }
    }
    (tokens, info)
}

/// Walks the tokens and collects the declarations.
struct Parser {
    tokens: Vec<Token>,
    pos: usize,
    decls: Vec<Decl>,
    errors: Vec<String>,
}

impl Parser {
    fn peek(&self) -> Option<&str> {
        self.tokens.get(self.pos).map(|t| t.text.as_str())
    }

    fn peek_at(&self, ahead: usize) -> Option<&str> {
        self.tokens.get(self.pos + ahead).map(|t| t.text.as_str())
    }

    fn line(&self) -> usize {
        self.tokens
            .get(self.pos)
            .or(self.tokens.last())
            .map_or(0, |t| t.line)
    }

    fn next(&mut self) -> Option<Token> {
        let t = self.tokens.get(self.pos).cloned();
        self.pos += 1;
        t
    }

    fn error(&mut self, what: &str) {
        let line = self.line();
        self.errors.push(format!("line {line}: {what}"));
    }

    /// Skips to the end of the statement: past the `;` at bracket depth 0
    /// (option values may hold `{ ... }` aggregates). Returns the line of
    /// the `;`.
    fn skip_statement(&mut self) -> usize {
        let mut depth = 0i32;
        while let Some(t) = self.next() {
            match t.text.as_str() {
                "{" | "[" | "(" | "<" => depth += 1,
                "}" | "]" | ")" | ">" => depth -= 1,
                ";" if depth <= 0 => return t.line,
                _ => {}
            }
        }
        self.error("unexpected end of file in a statement");
        self.line()
    }

    /// Skips a balanced `{ ... }` (the `{` is next).
    fn skip_block(&mut self) {
        let mut depth = 0i32;
        while let Some(t) = self.next() {
            match t.text.as_str() {
                "{" => depth += 1,
                "}" => {
                    depth -= 1;
                    if depth == 0 {
                        return;
                    }
                }
                _ => {}
            }
        }
        self.error("unexpected end of file in a block");
    }

    /// `kind Name {`: records the declaration; the `{` is consumed.
    fn block_header(&mut self, kind: &'static str) -> bool {
        let first = self.next().expect("keyword");
        let Some(name) = self.next() else {
            self.error(&format!("{kind} without a name"));
            return false;
        };
        match self.next() {
            Some(t) if t.text == "{" => {
                self.decls.push(Decl {
                    kind,
                    name: name.text,
                    line: first.line,
                    end_line: t.line,
                });
                true
            }
            _ => {
                self.error(&format!("{kind} {}: expected `{{`", name.text));
                false
            }
        }
    }

    fn file(&mut self) {
        while let Some(t) = self.peek() {
            match t {
                "syntax" | "edition" | "package" | "import" | "option" => {
                    self.skip_statement();
                }
                ";" => self.pos += 1,
                "message" => self.message(),
                "enum" => self.enumeration(),
                "service" => self.service(),
                other => {
                    let msg = format!("unexpected `{other}` at file level");
                    self.error(&msg);
                    self.skip_statement();
                }
            }
        }
    }

    fn message(&mut self) {
        if !self.block_header("message") {
            return;
        }
        self.message_body(false);
    }

    /// The body of a message (or of a oneof with `oneof`), after its `{`.
    fn message_body(&mut self, oneof: bool) {
        loop {
            let Some(t) = self.peek() else {
                self.error("unexpected end of file in a message");
                return;
            };
            match t {
                "}" => {
                    self.pos += 1;
                    return;
                }
                ";" => self.pos += 1,
                "option" => {
                    self.skip_statement();
                }
                "reserved" | "extensions" if !oneof => {
                    self.skip_statement();
                }
                "message" if !oneof => self.message(),
                "enum" if !oneof => self.enumeration(),
                "oneof" if !oneof => {
                    if self.block_header("oneof") {
                        self.message_body(true);
                    }
                }
                "extend" | "group" => {
                    let msg = format!("`{t}` is not supported by this check");
                    self.error(&msg);
                    self.skip_block();
                }
                _ => self.field(),
            }
        }
    }

    /// `[optional|repeated|required] Type name = N [opts];` or
    /// `map<K, V> name = N [opts];`.
    fn field(&mut self) {
        let line = self.line();
        let start = self.pos;
        if matches!(self.peek(), Some("optional" | "repeated" | "required")) {
            self.pos += 1;
        }
        let name = if self.peek() == Some("map") && self.peek_at(1) == Some("<") {
            // map < K , V > name
            self.pos += 2;
            let ok = self.peek_at(1) == Some(",") && self.peek_at(3) == Some(">");
            self.pos += 4;
            if !ok {
                self.error("malformed map field");
            }
            self.next()
        } else {
            // Type name
            self.pos += 1;
            self.next()
        };
        let Some(name) = name else {
            self.error("unexpected end of file in a field");
            return;
        };
        if self.peek() != Some("=") || !is_ident(&name.text) {
            self.pos = start;
            let msg = format!(
                "cannot parse a field starting with `{}`",
                self.peek().unwrap_or("")
            );
            self.error(&msg);
            self.skip_statement();
            return;
        }
        let end_line = self.skip_statement();
        self.decls.push(Decl {
            kind: "field",
            name: name.text,
            line,
            end_line,
        });
    }

    fn enumeration(&mut self) {
        if !self.block_header("enum") {
            return;
        }
        loop {
            let Some(t) = self.peek() else {
                self.error("unexpected end of file in an enum");
                return;
            };
            match t {
                "}" => {
                    self.pos += 1;
                    return;
                }
                ";" => self.pos += 1,
                "option" | "reserved" => {
                    self.skip_statement();
                }
                _ => {
                    let line = self.line();
                    let name = self.next().expect("peeked").text;
                    if self.peek() != Some("=") || !is_ident(&name) {
                        let msg = format!("cannot parse an enum value starting with `{name}`");
                        self.error(&msg);
                        self.skip_statement();
                        continue;
                    }
                    let end_line = self.skip_statement();
                    self.decls.push(Decl {
                        kind: "enum value",
                        name,
                        line,
                        end_line,
                    });
                }
            }
        }
    }

    fn service(&mut self) {
        if !self.block_header("service") {
            return;
        }
        loop {
            let Some(t) = self.peek() else {
                self.error("unexpected end of file in a service");
                return;
            };
            match t {
                "}" => {
                    self.pos += 1;
                    return;
                }
                ";" => self.pos += 1,
                "option" => {
                    self.skip_statement();
                }
                "rpc" => self.rpc(),
                other => {
                    let msg = format!("unexpected `{other}` in a service");
                    self.error(&msg);
                    self.skip_statement();
                }
            }
        }
    }

    /// `rpc Name(Req) returns (Resp);` or `... { option ...; }`.
    fn rpc(&mut self) {
        let line = self.line();
        self.pos += 1;
        let Some(name) = self.next() else {
            self.error("rpc without a name");
            return;
        };
        // Up to the `;` or the options body.
        let mut depth = 0i32;
        loop {
            let Some(t) = self.peek().map(str::to_string) else {
                self.error("unexpected end of file in an rpc");
                return;
            };
            match t.as_str() {
                "(" => depth += 1,
                ")" => depth -= 1,
                ";" if depth == 0 => {
                    let end_line = self.line();
                    self.pos += 1;
                    self.decls.push(Decl {
                        kind: "rpc",
                        name: name.text,
                        line,
                        end_line,
                    });
                    return;
                }
                "{" if depth == 0 => {
                    let end_line = self.line();
                    self.skip_block();
                    if self.peek() == Some(";") {
                        self.pos += 1;
                    }
                    self.decls.push(Decl {
                        kind: "rpc",
                        name: name.text,
                        line,
                        end_line,
                    });
                    return;
                }
                _ => {}
            }
            self.pos += 1;
        }
    }
}

fn is_ident(s: &str) -> bool {
    s.chars()
        .next()
        .is_some_and(|c| c.is_alphabetic() || c == '_')
        && s.chars().all(|c| c.is_alphanumeric() || c == '_')
}

/// Whether the declaration has a comment with text directly above it
/// (comment-only lines, no blank line in between) or on its header's
/// first or last line.
fn documented(d: &Decl, info: &[LineInfo]) -> bool {
    let at = |line: usize| info.get(line - 1).copied().unwrap_or_default();
    if at(d.line).comment_text || at(d.end_line).comment_text {
        return true;
    }
    let mut line = d.line;
    while line > 1 {
        line -= 1;
        let l = at(line);
        if l.code || !l.comment {
            // Code, or a blank line: the comment block (if any) ended.
            return false;
        }
        if l.comment_text {
            return true;
        }
    }
    false
}

/// The declarations of a `.proto` source without a comment, and what the
/// parser could not understand, each as `line: ...`.
fn check(src: &str) -> (Vec<Decl>, Vec<String>, Vec<String>) {
    let (tokens, info) = scan(src);
    let mut p = Parser {
        tokens,
        pos: 0,
        decls: Vec::new(),
        errors: Vec::new(),
    };
    p.file();
    let undocumented = p
        .decls
        .iter()
        .filter(|d| !documented(d, &info))
        .map(|d| format!("{}: {} `{}` has no comment", d.line, d.kind, d.name))
        .collect();
    (p.decls, undocumented, p.errors)
}

#[test]
fn every_proto_declaration_is_documented() {
    let root = repo();
    let files = proto_files(&root.join("proto"));
    assert!(
        files.len() >= 5,
        "expected the .proto files under proto/, found {files:?}"
    );
    let mut problems = Vec::new();
    let mut total = 0;
    for path in &files {
        let rel = path
            .strip_prefix(&root)
            .unwrap_or(path)
            .display()
            .to_string();
        let src = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{rel}: {e}"));
        let (decls, undocumented, errors) = check(&src);
        assert!(
            decls.iter().any(|d| d.kind == "field"),
            "{rel}: the parser found no fields; is it still a proto file?"
        );
        total += decls.len();
        for e in errors {
            problems.push(format!("{rel}:{e} (proto_docs parser)"));
        }
        for u in undocumented {
            problems.push(format!("{rel}:{u}"));
        }
    }
    assert!(
        problems.is_empty(),
        "{} of {total} declarations in the .proto files need attention; every message, enum, \
         service, rpc, oneof, field and enum value needs a comment directly above it (no blank \
         line in between) or a trailing comment on its line:\n{}",
        problems.len(),
        problems.join("\n")
    );
}

/// The parser itself: what it finds, what it flags, what it accepts.
#[test]
fn parser_finds_and_flags_declarations() {
    let src = r#"// File comment.
syntax = "proto3";
package demo.v1;
import "google/protobuf/empty.proto";
option go_package = "example.com/demo//v1";
option (my.opt) = { a: 1; b: "x" };

// A service.
service S {
  option deprecated = true;
  // Documented rpc.
  rpc A(Req) returns (Resp);
  rpc B(Req)
      returns (stream Resp); // trailing on the last line
  // With options.
  rpc C(stream Req) returns (Resp) {
    option idempotency_level = NO_SIDE_EFFECTS;
  }
  rpc Undoc(Req) returns (Resp);
}

message Undocumented {
  // Doc.
  int32 a = 1;
  int32 group_member = 2;

  int32 after_blank = 3;
  // Doc.

  int32 blank_between = 4;
  optional double o = 5; // trailing
  // Doc.
  repeated string r = 6 [packed = false];
  // Doc.
  map<string, int64> m = 7;
  map<string, int64> m_undoc = 8;
  reserved 9, 10 to 12;
  reserved "old";
  // Doc.
  oneof kind {
    // Doc.
    Msg x = 13;
    uint64 y = 14;
  }
  oneof bare {
    /* Block doc. */
    bool z = 15;
  }
  //
  int32 empty_comment = 16;
  /*
   * Block doc over lines.
   */
  int32 block_above = 17;
  // Doc.
  string with_slashes = 18 [default = "a // b"];
  // Nested message.
  message Inner {
    int32 i = 1;
  }
  // Doc.
  int32 multi_line = 19 [
    deprecated = true
  ];
}

// Doc.
enum E {
  option allow_alias = true;
  // Doc.
  E_UNSPECIFIED = 0;
  E_ONE = 1; // trailing
  // Doc.
  E_TWO = 2 [deprecated = true];
  reserved 3;
}
"#;
    let (decls, undocumented, errors) = check(src);
    assert!(errors.is_empty(), "{errors:?}");
    let names: Vec<&str> = decls.iter().map(|d| d.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "S",
            "A",
            "B",
            "C",
            "Undoc",
            "Undocumented",
            "a",
            "group_member",
            "after_blank",
            "blank_between",
            "o",
            "r",
            "m",
            "m_undoc",
            "kind",
            "x",
            "y",
            "bare",
            "z",
            "empty_comment",
            "block_above",
            "with_slashes",
            "Inner",
            "i",
            "multi_line",
            "E",
            "E_UNSPECIFIED",
            "E_ONE",
            "E_TWO",
        ]
    );
    assert_eq!(
        undocumented,
        [
            "19: rpc `Undoc` has no comment",
            "22: message `Undocumented` has no comment",
            "25: field `group_member` has no comment",
            "27: field `after_blank` has no comment",
            "30: field `blank_between` has no comment",
            "36: field `m_undoc` has no comment",
            "43: field `y` has no comment",
            "45: oneof `bare` has no comment",
            "50: field `empty_comment` has no comment",
            "59: field `i` has no comment",
        ]
    );
}

#[test]
fn parser_reports_what_it_does_not_understand() {
    let (_, _, errors) = check("// M.\nmessage M {\n  // F.\n  int32 = 1;\n}\n");
    assert_eq!(errors.len(), 1, "{errors:?}");
    assert!(errors[0].starts_with("line 4:"), "{errors:?}");
    let (_, _, errors) = check("// E.\nenum E {\n  // V.\n  V 0;\n}\n");
    assert_eq!(errors.len(), 1, "{errors:?}");
    let (_, _, errors) = check("// M.\nmessage M {\n  // F.\n  int32 a = 1;\n");
    assert!(!errors.is_empty());
}
