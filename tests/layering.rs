//! The layers of ARCHITECTURE.md, checked: each crate's normal dependencies on
//! other diffphys crates are exactly among those its layer allows, and its
//! sources name no other diffphys crate. Inside each library crate the
//! modules import each other without a circle (an import that runs back up),
//! and no file under crates/ is longer than 700 lines.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Which diffphys crates each crate may depend on (normal dependencies).
const ALLOWED: &[(&str, &[&str])] = &[
    ("hack", &[]),
    ("tape", &[]),
    ("ops", &["diffphys-tape"]),
    ("nn", &["diffphys-tape"]),
    (
        "learn",
        &[
            "diffphys-tape",
            "diffphys-ops",
            "diffphys-nn",
            "diffphys-report",
        ],
    ),
    ("flow", &["diffphys-tape", "diffphys-ops"]),
    ("report", &["diffphys-tape"]),
    (
        "hybrid",
        &[
            "diffphys-tape",
            "diffphys-nn",
            "diffphys-learn",
            "diffphys-flow",
            "diffphys-report",
        ],
    ),
    (
        "compare",
        &["diffphys-tape", "diffphys-ops", "diffphys-report"],
    ),
    ("candle", &["diffphys-tape", "diffphys-ops"]),
    (
        "python",
        &[
            "diffphys-tape",
            "diffphys-ops",
            "diffphys-flow",
            "diffphys-nn",
        ],
    ),
];

/// The `diffphys-*` names under `[dependencies]` of a manifest (dev- and
/// build-dependencies may reach wider: tests see more than the library),
/// less `diffphys-hack`, which every crate depends on and which holds no code
/// (it only unifies the features of third-party dependencies).
fn diffphys_dependencies(manifest: &str) -> BTreeSet<String> {
    let mut in_deps = false;
    let mut found = BTreeSet::new();
    for line in manifest.lines() {
        let line = line.trim();
        if line.starts_with('[') {
            in_deps = line == "[dependencies]";
            continue;
        }
        if in_deps {
            let name = line.split(['=', '.', ' ']).next().unwrap_or("");
            if name.starts_with("diffphys") && name != "diffphys-hack" {
                found.insert(name.to_string());
            }
        }
    }
    found
}

/// Every `.rs` file under `dir`.
fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("readable source folder") {
        let path = entry.expect("readable entry").path();
        if path.is_dir() {
            sources(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

#[test]
fn every_crate_imports_only_the_layers_below_it() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("crates");
    let mut checked = 0;
    for entry in std::fs::read_dir(&root).expect("crates/ exists") {
        let dir = entry.expect("readable entry").path();
        let name = dir.file_name().unwrap().to_string_lossy().to_string();
        let Ok(manifest) = std::fs::read_to_string(dir.join("Cargo.toml")) else {
            continue;
        };
        let allowed: BTreeSet<String> = ALLOWED
            .iter()
            .find(|(n, _)| *n == name)
            .unwrap_or_else(|| panic!("crates/{name} is not in ARCHITECTURE.md's layers"))
            .1
            .iter()
            .map(|s| s.to_string())
            .collect();
        let deps = diffphys_dependencies(&manifest);
        let extra: Vec<_> = deps.difference(&allowed).collect();
        assert!(
            extra.is_empty(),
            "crates/{name} depends on {extra:?}; its layer allows only {allowed:?}"
        );

        // The sources name no diffphys crate the manifest could not provide
        // (a path dependency sneaked in some other way, say).
        let mut files = Vec::new();
        sources(&dir.join("src"), &mut files);
        for file in files {
            let text = std::fs::read_to_string(&file).unwrap();
            for other in [
                "tape", "ops", "nn", "learn", "flow", "compare", "candle", "report",
            ] {
                let crate_name = format!("diffphys-{other}");
                let ident = format!("diffphys_{other}::");
                if other != name && !allowed.contains(&crate_name) {
                    assert!(
                        !text.contains(&ident),
                        "{} names {ident} but crates/{name} may not depend on it",
                        file.display()
                    );
                }
            }
        }
        checked += 1;
    }
    assert!(checked >= 5, "only {checked} crates found under crates/");
}

/// The longest a source file under crates/ may be.
const MAX_LINES: usize = 700;

fn crates_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("crates")
}

#[test]
fn no_file_under_crates_is_longer_than_700_lines() {
    let mut files = Vec::new();
    sources(&crates_dir(), &mut files);
    assert!(files.len() > 50, "only {} sources found", files.len());
    let long: Vec<String> = files
        .iter()
        .filter(|f| !f.components().any(|c| c.as_os_str() == "target"))
        .filter_map(|f| {
            let n = std::fs::read_to_string(f).unwrap().lines().count();
            (n > MAX_LINES).then(|| format!("{} ({n} lines)", f.display()))
        })
        .collect();
    assert!(long.is_empty(), "past {MAX_LINES} lines: {long:?}");
}

/// The first path segment of each item of a use tree (`a::B`, `{a::B, c}`,
/// `a::{B, C}` give `a`, `a` and `c`, `a`).
fn use_heads(tree: &str) -> Vec<String> {
    let tree = tree.trim();
    let Some(inner) = tree.strip_prefix('{') else {
        return vec![tree.split("::").next().unwrap_or("").trim().to_string()];
    };
    let inner = inner.strip_suffix('}').unwrap_or(inner);
    let (mut depth, mut part, mut heads) = (0, String::new(), Vec::new());
    for ch in inner.chars().chain([',']) {
        match ch {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                if !part.trim().is_empty() {
                    heads.extend(use_heads(&part));
                }
                part.clear();
                continue;
            }
            _ => {}
        }
        part.push(ch);
    }
    heads
}

/// The code of a file without its comments (from `//` to the end of each
/// line: doc links name modules without importing them) and its
/// `#[cfg(test)]` module.
fn code(text: &str) -> String {
    let text = text.split("#[cfg(test)]").next().unwrap_or("");
    text.lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Every `use crate::…;` tree of `code` and every inline `crate::name` path:
/// the names they start with.
fn crate_names(code: &str) -> BTreeSet<String> {
    let mut names = BTreeSet::new();
    let mut rest = code;
    while let Some(at) = rest.find("crate::") {
        let after = &rest[at + "crate::".len()..];
        let is_use = rest[..at].trim_end().ends_with("use");
        if is_use {
            let end = after.find(';').unwrap_or(after.len());
            names.extend(use_heads(&after[..end]));
        } else {
            let name: String = after
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            names.insert(name);
        }
        rest = after;
    }
    names
}

/// The top-level modules of the library crate in `src` and, for each, the
/// other top-level modules it imports (names re-exported by `lib.rs` count as
/// their module's; a module's own submodules are part of it).
fn module_graph(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let lib = code(&std::fs::read_to_string(src.join("lib.rs")).unwrap());
    let mut reexported = BTreeMap::new();
    for stmt in lib.split(';') {
        let Some(tree) = stmt.trim().strip_prefix("pub use ") else {
            continue;
        };
        let Some((module, items)) = tree.split_once("::") else {
            continue;
        };
        let items = items.trim();
        let names: Vec<&str> = if let Some(inner) = items.strip_prefix('{') {
            inner.trim_end_matches('}').split(',').collect()
        } else {
            vec![items]
        };
        for name in names {
            let name = name.rsplit(" as ").next().unwrap_or("").trim();
            let name = name.rsplit("::").next().unwrap_or("").trim();
            reexported.insert(name.to_string(), module.trim().to_string());
        }
    }
    let mut files = Vec::new();
    sources(src, &mut files);
    let top = |f: &Path| -> String {
        let rel = f.strip_prefix(src).unwrap();
        let first = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        first.trim_end_matches(".rs").to_string()
    };
    let modules: BTreeSet<String> = files
        .iter()
        .map(|f| top(f))
        .filter(|m| m != "lib")
        .collect();
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for f in &files {
        let m = top(f);
        if m == "lib" {
            continue;
        }
        let names = crate_names(&code(&std::fs::read_to_string(f).unwrap()));
        let deps = graph.entry(m.clone()).or_default();
        for name in names {
            let target = if modules.contains(&name) {
                Some(name)
            } else {
                reexported.get(&name).cloned()
            };
            if let Some(t) = target.filter(|t| *t != m) {
                deps.insert(t);
            }
        }
    }
    graph
}

/// A circle of `graph`, if there is one.
fn circle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        m: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(at) = path.iter().position(|p| p == m) {
            let mut found = path[at..].to_vec();
            found.push(m.to_string());
            return Some(found);
        }
        if done.contains(m) {
            return None;
        }
        path.push(m.to_string());
        for d in graph.get(m).into_iter().flatten() {
            if let Some(c) = visit(d, graph, path, done) {
                return Some(c);
            }
        }
        path.pop();
        done.insert(m.to_string());
        None
    }
    let mut done = BTreeSet::new();
    graph
        .keys()
        .find_map(|m| visit(m, graph, &mut Vec::new(), &mut done))
}

#[test]
fn the_modules_of_each_library_crate_import_each_other_without_a_circle() {
    let mut checked = 0;
    for name in [
        "flow", "ops", "learn", "nn", "tape", "report", "compare", "python",
    ] {
        let graph = module_graph(&crates_dir().join(name).join("src"));
        assert!(graph.len() > 3, "crates/{name}: only {graph:?}");
        if let Some(c) = circle(&graph) {
            panic!(
                "crates/{name}: the imports run in a circle: {}",
                c.join(" -> ")
            );
        }
        checked += 1;
    }
    assert_eq!(checked, 8);
}

#[test]
fn the_circle_finder_finds_a_circle_and_reads_nested_use_trees() {
    let graph: BTreeMap<String, BTreeSet<String>> = [
        ("a", vec!["b"]),
        ("b", vec!["c"]),
        ("c", vec!["a"]),
        ("d", vec![]),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v.into_iter().map(String::from).collect()))
    .collect();
    assert_eq!(circle(&graph).unwrap(), ["a", "b", "c", "a"]);
    let mut open = graph.clone();
    open.get_mut("c").unwrap().clear();
    assert_eq!(circle(&open), None);
    assert_eq!(
        use_heads("{grid::{FlowGrid, Lattice}, sides::Side, Result}"),
        ["grid", "sides", "Result"]
    );
    let names = crate_names("use crate::{a::X, b};\nlet y = crate::c::f();\n// crate::d\n");
    assert_eq!(names, ["a", "b", "c", "d"].map(String::from).into());
    assert!(!crate_names(&code("let y = 1; // crate::d\n")).contains("d"));
}
