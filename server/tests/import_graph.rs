//! Modules depend on each other one way. For the server: the edges on the
//! runtime, the runtime on the configuration, and no edge on another edge.
//! This test reads the sources and fails on a module that names one of a
//! layer above it, on an edge that names another edge, on a module that
//! names one it must not skip to ([`SKIPS_FORBIDDEN`]), on `ApiError`
//! outside `grpc/`, and on a circle between sibling modules (anywhere in
//! the server, in `cangate-can` and in `cangate-client`); see "Layers" in
//! docs/design.md.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Layer of each top-level module of the server: 0 configuration, 1
/// runtime, 2 what the edges share (security, metrics), 3 the edges, 4 the
/// server that puts the edges together.
const LAYERS: &[(&str, u8)] = &[
    ("config", 0),
    ("realtime", 1),
    ("not_found", 1),
    ("participants", 1),
    ("cyclic", 1),
    ("axis_runner", 1),
    ("canopen", 1),
    ("axes", 1),
    ("cansmc", 1),
    ("handwheel", 1),
    ("simulation", 1),
    ("gateway", 1),
    ("traffic_log", 1),
    ("metrics", 2),
    ("convert", 2),
    ("security", 2),
    ("grpc", EDGE),
    ("socketcand", EDGE),
    ("cia309", EDGE),
    ("bridge", EDGE),
    ("web", EDGE),
    ("serve", 4),
];

/// The layer of the edges: each speaks its protocol to clients over the
/// runtime; none names another (what two edges share belongs to the
/// runtime, or to layer 2).
const EDGE: u8 = 3;

/// (module, module it must not name, why): lower layers it may not reach
/// past the one in between.
const SKIPS_FORBIDDEN: &[(&str, &str, &str)] = &[(
    "grpc",
    "config",
    "the API edge translates the runtime's domain types (an axis's \
     cangate_axis::AxisSpec, …); what it needs of the configuration, the \
     runtime hands over in those",
)];

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The source without comments and without its unit tests.
fn code_of(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap();
    let text = match text.find("#[cfg(test)]\nmod tests") {
        Some(i) => &text[..i],
        None => &text,
    };
    text.lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The module path of a source file under `src` (`a/b.rs`, `a/b/mod.rs`:
/// `["a", "b"]`; the crate root: `[]`).
fn module_path(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).unwrap();
    let mut parts: Vec<String> = rel
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    let last = parts.pop().unwrap();
    let stem = last.trim_end_matches(".rs");
    if !matches!(stem, "mod" | "lib" | "main") {
        parts.push(stem.to_string());
    }
    parts
}

/// The paths a `use` tree (or a path in code) names, from the text right
/// after its first `::`: `a::{b, c::{d, e}}` gives `a::b`, `a::c::d`,
/// `a::c::e`.
fn paths_of(text: &str) -> Vec<Vec<String>> {
    fn tree(s: &[u8], i: &mut usize, prefix: &[String], out: &mut Vec<Vec<String>>) {
        let mut path = prefix.to_vec();
        loop {
            while *i < s.len() && (s[*i] as char).is_whitespace() {
                *i += 1;
            }
            if *i < s.len() && s[*i] == b'{' {
                *i += 1;
                loop {
                    tree(s, i, &path, out);
                    while *i < s.len() && (s[*i] as char).is_whitespace() {
                        *i += 1;
                    }
                    match s.get(*i) {
                        Some(b',') => *i += 1,
                        Some(b'}') => {
                            *i += 1;
                            return;
                        }
                        _ => return,
                    }
                    while *i < s.len() && (s[*i] as char).is_whitespace() {
                        *i += 1;
                    }
                    if s.get(*i) == Some(&b'}') {
                        *i += 1;
                        return;
                    }
                }
            }
            let start = *i;
            while *i < s.len() && ((s[*i] as char).is_alphanumeric() || s[*i] == b'_') {
                *i += 1;
            }
            let name = std::str::from_utf8(&s[start..*i]).unwrap();
            if !name.is_empty() && name != "self" {
                path.push(name.to_string());
            }
            if s[*i..].starts_with(b"::") {
                *i += 2;
            } else {
                out.push(path);
                return;
            }
        }
    }
    let mut out = Vec::new();
    tree(text.as_bytes(), &mut 0, &[], &mut out);
    out
}

/// Every module path that `code` (in module `here`) names with `crate::`,
/// `super::` or `self::`, resolved against `modules` to the longest known
/// module; `reexports` maps names the crate root re-exports to their
/// module.
fn used_modules(
    code: &str,
    here: &[String],
    modules: &BTreeSet<Vec<String>>,
    reexports: &BTreeMap<String, Vec<String>>,
) -> BTreeSet<Vec<String>> {
    let mut used = BTreeSet::new();
    let bytes = code.as_bytes();
    for (i, _) in code.match_indices("crate::") {
        if i > 0 && ((bytes[i - 1] as char).is_alphanumeric() || bytes[i - 1] == b'_') {
            continue; // e.g. `cangate_crate::`
        }
        for p in paths_of(&code[i + "crate::".len()..]) {
            used.insert(resolve(p, modules, reexports));
        }
    }
    for (i, _) in code.match_indices("super::") {
        if i > 0 && ((bytes[i - 1] as char).is_alphanumeric() || bytes[i - 1] == b':') {
            continue; // `super::super::` counts once
        }
        let mut rest = &code[i..];
        let mut base = here.to_vec();
        while let Some(r) = rest.strip_prefix("super::") {
            base.pop();
            rest = r;
        }
        for p in paths_of(rest) {
            let mut full = base.clone();
            full.extend(p);
            used.insert(resolve(full, modules, reexports));
        }
    }
    used
}

fn resolve(
    path: Vec<String>,
    modules: &BTreeSet<Vec<String>>,
    reexports: &BTreeMap<String, Vec<String>>,
) -> Vec<String> {
    if let [name] = path.as_slice()
        && let Some(m) = reexports.get(name)
    {
        return m.clone();
    }
    let mut p = path;
    while !p.is_empty() && !modules.contains(&p) {
        p.pop();
    }
    p
}

/// Names the crate root re-exports (`pub use m::{A, B};`) and their module.
fn root_reexports(root: &str, modules: &BTreeSet<Vec<String>>) -> BTreeMap<String, Vec<String>> {
    let mut out = BTreeMap::new();
    for (i, _) in root.match_indices("pub use ") {
        let rest = &root[i + "pub use ".len()..];
        let stmt = &rest[..rest.find(';').unwrap_or(rest.len())];
        for p in paths_of(stmt) {
            if let Some((name, module)) = p.split_last()
                && modules.contains(module)
            {
                out.insert(name.clone(), module.to_vec());
            }
        }
    }
    out
}

/// A crate's module graph: for each file module, the modules it names
/// (parents and children left out: a module and its own submodules are
/// one unit to the rest of the crate).
struct ModuleGraph {
    uses: BTreeMap<Vec<String>, BTreeSet<Vec<String>>>,
}

impl ModuleGraph {
    /// The modules of the files under `src` that `keep` accepts (by module
    /// path), with `root` the crate root's file.
    fn read(src: &Path, root: &str, keep: impl Fn(&[String]) -> bool) -> ModuleGraph {
        let mut files = Vec::new();
        rust_files(src, &mut files);
        let files: Vec<(Vec<String>, PathBuf)> = files
            .into_iter()
            .filter(|f| {
                let name = f.file_name().unwrap().to_string_lossy();
                let is_root = f.parent() == Some(src) && (name == "lib.rs" || name == "main.rs");
                if is_root {
                    name == root
                } else {
                    keep(&module_path(src, f))
                }
            })
            .map(|f| (module_path(src, &f), f))
            .collect();
        let modules: BTreeSet<Vec<String>> = files.iter().map(|(m, _)| m.clone()).collect();
        let root_code = code_of(&src.join(root));
        let reexports = root_reexports(&root_code, &modules);
        let mut uses = BTreeMap::new();
        for (module, file) in &files {
            let code = code_of(file);
            uses.insert(
                module.clone(),
                used_modules(&code, module, &modules, &reexports),
            );
        }
        ModuleGraph { uses }
    }

    /// Circles between sibling modules: at each level of the tree, a
    /// module that reaches itself through its siblings.
    fn circles(&self) -> Vec<String> {
        // Edges between siblings: from `a::x::…` to `a::y::…` is `a::x`
        // to `a::y`.
        let mut edges: BTreeMap<Vec<String>, BTreeSet<Vec<String>>> = BTreeMap::new();
        for (from, tos) in &self.uses {
            for to in tos {
                let common = from.iter().zip(to).take_while(|(a, b)| a == b).count();
                if common == from.len() || common == to.len() {
                    continue; // the same module, a parent or a child
                }
                edges
                    .entry(from[..=common].to_vec())
                    .or_default()
                    .insert(to[..=common].to_vec());
            }
        }
        let mut problems = Vec::new();
        for start in edges.keys() {
            let mut stack = vec![(start.clone(), vec![start.join("::")])];
            let mut seen = BTreeSet::new();
            while let Some((m, path)) = stack.pop() {
                for next in edges.get(&m).into_iter().flatten() {
                    if next == start {
                        let mut circle = path.clone();
                        circle.push(start.join("::"));
                        problems.push(format!("circle: {}", circle.join(" -> ")));
                    } else if seen.insert(next.clone()) {
                        let mut p = path.clone();
                        p.push(next.join("::"));
                        stack.push((next.clone(), p));
                    }
                }
            }
        }
        problems
    }
}

fn report(mut problems: Vec<String>) {
    problems.sort();
    problems.dedup();
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn server_modules_depend_one_way() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let layers: BTreeMap<&str, u8> = LAYERS.iter().copied().collect();
    // The library only: the binary (main.rs) puts everything together.
    let graph = ModuleGraph::read(&src, "lib.rs", |_| true);
    let mut problems = Vec::new();
    for (module, uses) in &graph.uses {
        let Some(top) = module.first() else { continue };
        let file = module.join("/");
        let Some(&layer) = layers.get(top.as_str()) else {
            problems.push(format!("{top} (src/{file}) has no layer in LAYERS"));
            continue;
        };
        let code = code_of(&if src.join(format!("{file}.rs")).exists() {
            src.join(format!("{file}.rs"))
        } else {
            src.join(&file).join("mod.rs")
        });
        if code.contains("ApiError") && top != "grpc" {
            problems.push(format!("src/{file} names ApiError outside grpc/"));
        }
        for used in uses {
            let Some(used_top) = used.first() else {
                continue;
            };
            if used_top == top {
                continue;
            }
            if let Some((_, _, why)) = SKIPS_FORBIDDEN
                .iter()
                .find(|(from, to, _)| *from == top && *to == used_top)
            {
                problems.push(format!("src/{file} names {used_top}: {why}"));
            }
            let Some(&used_layer) = layers.get(used_top.as_str()) else {
                continue;
            };
            if used_layer > layer {
                problems.push(format!(
                    "src/{file} (layer {layer}) names {used_top} (layer {used_layer})"
                ));
            } else if layer == EDGE && used_layer == EDGE {
                problems.push(format!(
                    "src/{file} (an edge) names {used_top}, another edge"
                ));
            }
        }
    }
    problems.extend(graph.circles());
    report(problems);
}

#[test]
fn can_modules_have_no_circles() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("../crates/can/src");
    report(ModuleGraph::read(&src, "lib.rs", |_| true).circles());
}

#[test]
fn client_modules_have_no_circles() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("../client/src");
    let is_cli = |m: &[String]| m.first().is_some_and(|t| t == "cli");
    report(ModuleGraph::read(&src, "lib.rs", |m| !is_cli(m)).circles());
    report(ModuleGraph::read(&src, "main.rs", is_cli).circles());
}

/// The checks find what they are for: a circle, a root re-export standing
/// for its module, an edge naming an edge.
#[test]
fn the_checks_see_circles_and_reexports() {
    let modules: BTreeSet<Vec<String>> = [vec![], vec!["a".into()], vec!["b".into()]]
        .into_iter()
        .collect();
    let reexports = root_reexports("pub use b::{X,\n    Y};", &modules);
    let a_uses = used_modules(
        "use crate::{Y, z};",
        &["a".to_string()],
        &modules,
        &reexports,
    );
    assert!(a_uses.contains(&vec!["b".to_string()]), "{a_uses:?}");
    let b_uses = used_modules(
        "use super::a::{self, Q};",
        &["b".to_string()],
        &modules,
        &reexports,
    );
    assert!(b_uses.contains(&vec!["a".to_string()]), "{b_uses:?}");
    let graph = ModuleGraph {
        uses: [
            (vec!["a".to_string()], a_uses),
            (vec!["b".to_string()], b_uses),
        ]
        .into_iter()
        .collect(),
    };
    assert_eq!(graph.circles().len(), 2, "{:?}", graph.circles());
}
