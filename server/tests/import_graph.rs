//! The server's modules depend on each other one way: the API edge on the
//! runtime, the runtime on the configuration. This test reads the sources
//! and fails on a circle between top-level modules, on a module that names
//! one of a layer above it, on a module that names one it must not skip
//! to ([`SKIPS_FORBIDDEN`]), and on `ApiError` outside `grpc/`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Layer of each top-level module: 0 configuration, 1 runtime, 2 API edge.
const LAYERS: &[(&str, u8)] = &[
    ("config", 0),
    ("realtime", 1),
    ("not_found", 1),
    ("axis_runner", 1),
    ("canopen", 1),
    ("axes", 1),
    ("cansmc", 1),
    ("handwheel", 1),
    ("simulation", 1),
    ("gateway", 1),
    ("traffic_log", 1),
    ("metrics", 2),
    ("security", 2),
    ("grpc", 2),
    ("serve", 2),
    ("socketcand", 2),
    ("web", 2),
];

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

/// Top-level module names used after `crate::` (also inside `crate::{…}`).
fn used_modules(code: &str, known: &BTreeSet<&str>) -> BTreeSet<String> {
    let mut used = BTreeSet::new();
    for (i, _) in code.match_indices("crate::") {
        let rest = &code[i + "crate::".len()..];
        let names: Vec<&str> = match rest.strip_prefix('{') {
            Some(group) => group[..group.find('}').unwrap_or(group.len())]
                .split(',')
                .map(|p| p.trim().split("::").next().unwrap_or("").trim())
                .collect(),
            None => vec![
                rest.split(|c: char| !c.is_alphanumeric() && c != '_')
                    .next()
                    .unwrap_or(""),
            ],
        };
        used.extend(
            names
                .into_iter()
                .filter(|n| known.contains(n))
                .map(str::to_string),
        );
    }
    used
}

#[test]
fn server_modules_depend_one_way() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let layers: BTreeMap<&str, u8> = LAYERS.iter().copied().collect();
    let known: BTreeSet<&str> = layers.keys().copied().collect();
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut edges: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    let mut problems = Vec::new();
    for file in &files {
        let rel = file.strip_prefix(&src).unwrap();
        let first = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        let module = first.trim_end_matches(".rs").to_string();
        if module == "lib" || module == "main" {
            continue;
        }
        let Some(&layer) = layers.get(module.as_str()) else {
            problems.push(format!(
                "{module} (src/{}) has no layer in LAYERS",
                rel.display()
            ));
            continue;
        };
        let code = code_of(file);
        if code.contains("ApiError") && module != "grpc" {
            problems.push(format!(
                "src/{} names ApiError outside grpc/",
                rel.display()
            ));
        }
        for used in used_modules(&code, &known) {
            if used == module {
                continue;
            }
            if let Some((_, _, why)) = SKIPS_FORBIDDEN
                .iter()
                .find(|(from, to, _)| *from == module && *to == used)
            {
                problems.push(format!("src/{} names {used}: {why}", rel.display()));
            }
            if layers[used.as_str()] > layer {
                problems.push(format!(
                    "src/{} (layer {layer}) names {used} (layer {})",
                    rel.display(),
                    layers[used.as_str()]
                ));
            }
            edges.entry(module.clone()).or_default().insert(used);
        }
    }
    // A circle: some module reaches itself.
    for start in edges.keys() {
        let mut stack: Vec<(String, Vec<String>)> = vec![(start.clone(), vec![start.clone()])];
        let mut seen = BTreeSet::new();
        while let Some((m, path)) = stack.pop() {
            for next in edges.get(&m).into_iter().flatten() {
                if next == start {
                    problems.push(format!("circle: {} -> {start}", path.join(" -> ")));
                } else if seen.insert(next.clone()) {
                    let mut p = path.clone();
                    p.push(next.clone());
                    stack.push((next.clone(), p));
                }
            }
        }
    }
    problems.sort();
    problems.dedup();
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
