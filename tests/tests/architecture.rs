//! Architecture invariants that code review alone would not keep: the direction of the
//! dependencies between our crates (read from `cargo metadata`), wgpu only where it belongs,
//! a `//!` line atop every Rust file, and no ignored tests.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;
use terrain_tests::workspace_root;

const OURS: [&str; 8] = [
    "terrain-core",
    "terrain-visibility",
    "terrain-stream",
    "terrain-gpu",
    "terrain-app",
    "xtask",
    "terrain-tests",
    "terrain-fuzz",
];

fn host_triple(cargo: &str) -> String {
    // `cargo` lives beside `rustc`; fall back to the one on PATH.
    let rustc = std::path::Path::new(cargo).with_file_name("rustc");
    let rustc = if rustc.exists() { rustc.into_os_string() } else { "rustc".into() };
    let out = Command::new(rustc).arg("-vV").output().expect("rustc -vV runs");
    let text = String::from_utf8(out.stdout).expect("rustc prints UTF-8");
    text.lines()
        .find_map(|l| l.strip_prefix("host: "))
        .expect("rustc -vV names the host")
        .trim()
        .to_string()
}

/// Normal (non-dev, non-build) dependency graph of the resolved workspace: package name -> names.
fn dependency_graph() -> BTreeMap<String, BTreeSet<String>> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    // Resolve for the host only: other platforms' crates (android, windows) need not be on disk,
    // and the invariant is about our crates' edges, which are the same on every platform.
    let host = host_triple(&cargo);
    let out = Command::new(&cargo)
        .args(["metadata", "--format-version", "1", "--offline", "--filter-platform", &host])
        .current_dir(workspace_root())
        .output()
        .expect("cargo metadata runs");
    assert!(
        out.status.success(),
        "cargo metadata failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta: Value = serde_json::from_slice(&out.stdout).expect("cargo metadata prints JSON");
    let names: BTreeMap<&str, &str> = meta["packages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| (p["id"].as_str().unwrap(), p["name"].as_str().unwrap()))
        .collect();
    let mut graph = BTreeMap::new();
    for node in meta["resolve"]["nodes"].as_array().unwrap() {
        let name = names[node["id"].as_str().unwrap()].to_string();
        let deps = node["deps"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|d| d["dep_kinds"].as_array().unwrap().iter().any(|k| k["kind"].is_null()))
            .map(|d| names[d["pkg"].as_str().unwrap()].to_string())
            .collect::<BTreeSet<_>>();
        graph.entry(name).or_insert_with(BTreeSet::new).extend(deps);
    }
    graph
}

fn closure(graph: &BTreeMap<String, BTreeSet<String>>, root: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut stack = vec![root.to_string()];
    while let Some(n) = stack.pop() {
        for d in graph.get(&n).into_iter().flatten() {
            if seen.insert(d.clone()) {
                stack.push(d.clone());
            }
        }
    }
    seen
}

fn ours_in(deps: &BTreeSet<String>) -> BTreeSet<&'static str> {
    OURS.iter().copied().filter(|o| deps.contains(*o)).collect()
}

#[test]
fn dependencies_flow_one_way() {
    let g = dependency_graph();
    let direct = |c: &str| ours_in(&g[c]);
    assert_eq!(
        direct("terrain-core"),
        BTreeSet::new(),
        "terrain-core must depend on no crate of ours"
    );
    for mid in ["terrain-visibility", "terrain-stream", "terrain-gpu"] {
        assert_eq!(
            direct(mid),
            BTreeSet::from(["terrain-core"]),
            "{mid} must depend on terrain-core only"
        );
    }
    assert_eq!(
        direct("terrain-app"),
        BTreeSet::from(["terrain-core", "terrain-visibility", "terrain-stream", "terrain-gpu"]),
        "terrain-app composes the four library crates"
    );
    // The fuzzing harness drives the library crates' public APIs, never the app's.
    assert_eq!(
        direct("terrain-fuzz"),
        BTreeSet::from(["terrain-core", "terrain-visibility", "terrain-stream"]),
        "terrain-fuzz drives the readers and the store opener"
    );
    // Nothing depends on xtask, the tests crate or the harness; only the tests crate (and
    // xtask) may use the app's composition library.
    for (pkg, deps) in &g {
        for top in ["xtask", "terrain-tests", "terrain-fuzz"] {
            assert!(!deps.contains(top), "{pkg} depends on {top}");
        }
        if deps.contains("terrain-app") {
            assert!(
                ["terrain-tests", "xtask"].contains(&pkg.as_str()),
                "{pkg} depends on terrain-app"
            );
        }
    }
}

#[test]
fn only_gpu_and_app_reach_wgpu() {
    let g = dependency_graph();
    for c in ["terrain-core", "terrain-visibility", "terrain-stream"] {
        let all = closure(&g, c);
        let gpu: Vec<_> = all.iter().filter(|d| d.starts_with("wgpu") || *d == "naga").collect();
        assert!(
            gpu.is_empty(),
            "{c} must not depend on wgpu, even transitively; it reaches {gpu:?}"
        );
    }
    assert!(closure(&g, "terrain-gpu").contains("wgpu"), "terrain-gpu is the wgpu renderer");
}

fn rust_and_wgsl_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        if path.is_dir() {
            if !(name.starts_with('.') || name == "target") {
                rust_and_wgsl_files(&path, out);
            }
        } else if name.ends_with(".rs") || name.ends_with(".wgsl") {
            out.push(path);
        }
    }
}

#[test]
fn every_source_file_opens_with_a_doc_line() {
    let mut files = Vec::new();
    rust_and_wgsl_files(&workspace_root(), &mut files);
    assert!(
        files.len() > 10,
        "found only {} source files: is the workspace root right?",
        files.len()
    );
    let missing: Vec<_> = files
        .iter()
        .filter(|p| {
            let text = std::fs::read_to_string(p).unwrap();
            let first = text.lines().next().unwrap_or("");
            let is_rs = p.extension().is_some_and(|e| e == "rs");
            // Rust files open with an inner doc comment; shaders with a `//` comment saying what they do.
            if is_rs { !first.starts_with("//!") } else { !first.starts_with("//") }
        })
        .collect();
    assert!(missing.is_empty(), "files without an opening doc line: {missing:#?}");
}

#[test]
fn no_ignored_or_should_panic_tests() {
    let mut files = Vec::new();
    rust_and_wgsl_files(&workspace_root(), &mut files);
    // Built with concat! so this file does not match itself.
    let banned = [concat!("#[", "ignore"), concat!("#[", "should_panic")];
    let offenders: Vec<_> = files
        .iter()
        .filter(|p| {
            let text = std::fs::read_to_string(p).unwrap();
            banned.iter().any(|b| text.contains(b))
        })
        .collect();
    assert!(
        offenders.is_empty(),
        "ignored or should_panic tests (assert today's behaviour instead): {offenders:#?}"
    );
}
