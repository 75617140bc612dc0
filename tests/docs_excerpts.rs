//! Tutorials cannot drift from the code. Every ```` ```rust ```` block in
//! `docs/*.md` is one of two kinds:
//!
//! - a whole program (it has `fn main` or starts with `use`): rustdoc compiles
//!   and runs it, because the facade includes each page as a doctest
//!   (`src/docs.rs`);
//! - an excerpt (` ```rust,ignore `): its lines must stand, in order and
//!   contiguous, in the source of an example the page names
//!   (`--example NAME`), which CI builds and runs at `--small`.
//!
//! This test checks the excerpts; it fails on a block that is in neither form.

use std::path::{Path, PathBuf};

/// The fenced blocks of a markdown page: (info string, lines).
fn blocks(page: &str) -> Vec<(String, Vec<String>)> {
    let mut out = Vec::new();
    let mut current: Option<(String, Vec<String>)> = None;
    for line in page.lines() {
        let trimmed = line.trim_start();
        if let Some(info) = trimmed.strip_prefix("```") {
            match current.take() {
                Some(block) => out.push(block),
                None => current = Some((info.trim().to_string(), Vec::new())),
            }
        } else if let Some((_, lines)) = current.as_mut() {
            lines.push(line.to_string());
        }
    }
    out
}

/// The examples a page names with `--example NAME`.
fn named_examples(page: &str) -> Vec<String> {
    let mut names: Vec<String> = page
        .split("--example ")
        .skip(1)
        .filter_map(|rest| {
            let name: String = rest
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            (!name.is_empty()).then_some(name)
        })
        .collect();
    names.sort();
    names.dedup();
    names
}

/// The modules an example declares (`mod burgers_scene;`): folders or files
/// beside it whose lines count as the example's.
fn declared_modules(source: &str) -> Vec<String> {
    source
        .lines()
        .filter_map(|l| l.trim().strip_prefix("mod ")?.strip_suffix(';'))
        .map(|m| m.trim().to_string())
        .collect()
}

/// The source lines of an example: its file, its scene folder and the
/// modules it declares, if any.
fn example_lines(root: &Path, name: &str) -> Vec<String> {
    let main = root.join("examples").join(format!("{name}.rs"));
    let mut files: Vec<PathBuf> = vec![main.clone()];
    let mut dirs = vec![
        root.join("examples").join(format!("{name}_scene")),
        root.join("examples").join(name),
        root.join("examples").join("common"),
    ];
    for module in declared_modules(&std::fs::read_to_string(&main).unwrap_or_default()) {
        files.push(root.join("examples").join(format!("{module}.rs")));
        dirs.push(root.join("examples").join(module));
    }
    dirs.sort();
    dirs.dedup();
    for dir in dirs {
        if let Ok(entries) = std::fs::read_dir(&dir) {
            files.extend(entries.filter_map(|e| e.ok().map(|e| e.path())));
        }
    }
    files
        .iter()
        .filter_map(|f| std::fs::read_to_string(f).ok())
        .flat_map(|s| s.lines().map(|l| l.trim().to_string()).collect::<Vec<_>>())
        .collect()
}

fn contains_run(haystack: &[String], needle: &[String]) -> bool {
    needle.is_empty() || haystack.windows(needle.len()).any(|w| w == needle)
}

#[test]
fn every_rust_block_in_docs_is_compiled_or_an_excerpt_of_a_run_example() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut pages: Vec<PathBuf> = std::fs::read_dir(root.join("docs"))
        .expect("docs/ exists")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    pages.sort();
    let mut excerpts = 0;
    let mut failures = Vec::new();
    for page_path in &pages {
        let page = std::fs::read_to_string(page_path).unwrap();
        let sources: Vec<String> = named_examples(&page)
            .iter()
            .flat_map(|n| example_lines(root, n))
            .collect();
        for (info, lines) in blocks(&page) {
            let langs: Vec<&str> = info.split(',').map(str::trim).collect();
            if langs.first() != Some(&"rust") {
                continue;
            }
            if !langs.contains(&"ignore") {
                // A whole program: the doctest of src/docs.rs compiles it.
                continue;
            }
            let needle: Vec<String> = lines
                .iter()
                .map(|l| l.trim().to_string())
                .filter(|l| !l.is_empty())
                .collect();
            let haystack: Vec<String> = sources.iter().filter(|l| !l.is_empty()).cloned().collect();
            excerpts += 1;
            if !contains_run(&haystack, &needle) {
                failures.push(format!(
                    "{}: an excerpt starting {:?} is not in the examples the page names",
                    page_path.display(),
                    needle.first()
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert!(excerpts > 10, "only {excerpts} excerpts found in docs/");
}
