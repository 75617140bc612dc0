//! The layers of ARCHITECTURE.md, checked: each crate's normal dependencies on
//! other diffphys crates are exactly among those its layer allows, and its
//! sources name no other diffphys crate.

use std::collections::BTreeSet;
use std::path::Path;

/// Which diffphys crates each crate may depend on (normal dependencies).
const ALLOWED: &[(&str, &[&str])] = &[
    ("hack", &[]),
    ("tape", &[]),
    ("ops", &["diffphys-tape"]),
    ("nn", &["diffphys-tape"]),
    ("learn", &["diffphys-tape", "diffphys-ops", "diffphys-nn"]),
    ("flow", &["diffphys-tape", "diffphys-ops"]),
    ("report", &["diffphys-tape"]),
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
fn sources(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
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
