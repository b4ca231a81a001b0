//! Every shader module parses and validates with naga, so a shader error fails `cargo test`
//! even on machines without any GPU adapter: each module made of several `.wgsl` files
//! (`terrain_gpu::SHADER_MODULES`: a renderer's shader with the shared paged lookup after it)
//! as the renderer creates it, and every other `.wgsl` file under `src/` on its own.

use std::path::{Path, PathBuf};

fn wgsl_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect();
    entries.sort();
    for path in entries {
        if path.is_dir() {
            wgsl_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "wgsl") {
            out.push(path);
        }
    }
}

/// naga's complaint about `source`, if any.
fn validate(name: &str, source: &str) -> Option<String> {
    let module = match naga::front::wgsl::parse_str(source) {
        Ok(m) => m,
        Err(e) => return Some(e.emit_to_string_with_path(source, name)),
    };
    let mut validator = naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::default(),
    );
    validator.validate(&module).err().map(|e| format!("{name}: {}", e.emit_to_string(source)))
}

#[test]
fn every_shader_parses_and_validates() {
    let mut files = Vec::new();
    wgsl_files(&Path::new(env!("CARGO_MANIFEST_DIR")).join("src"), &mut files);
    assert!(!files.is_empty(), "no .wgsl file found under src/");
    let mut failures = Vec::new();
    for (name, source) in terrain_gpu::SHADER_MODULES {
        failures.extend(validate(name, source));
        println!("validated module {name}");
    }
    for path in &files {
        let source = std::fs::read_to_string(path).unwrap();
        // A file that is part of a module is validated there (a snippet alone is not a module).
        if terrain_gpu::SHADER_MODULES.iter().any(|(_, m)| m.contains(&source)) {
            continue;
        }
        failures.extend(validate(&path.display().to_string(), &source));
        println!("validated {}", path.display());
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The paged lookup exists once: one `.wgsl` file defines it, and both renderers' modules
/// include that file.
#[test]
fn the_paged_lookup_is_one_snippet_shared_by_both_renderers() {
    let mut files = Vec::new();
    wgsl_files(&Path::new(env!("CARGO_MANIFEST_DIR")).join("src"), &mut files);
    let defining: Vec<&PathBuf> = files
        .iter()
        .filter(|p| std::fs::read_to_string(p).unwrap().contains("fn lookup("))
        .collect();
    assert_eq!(defining.len(), 1, "{defining:?}");
    assert!(defining[0].ends_with("paged_lookup.wgsl"), "{defining:?}");
    let snippet = std::fs::read_to_string(defining[0]).unwrap();
    let users: Vec<&str> = terrain_gpu::SHADER_MODULES
        .iter()
        .filter(|(_, m)| m.contains(&snippet))
        .map(|(n, _)| *n)
        .collect();
    assert_eq!(users, ["render/terrain.wgsl", "geomorph/geomorph.wgsl"]);
}
