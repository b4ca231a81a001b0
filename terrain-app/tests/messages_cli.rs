//! Messages in the user's words: `--help` names options, never library items (no rustdoc
//! links), errors name the CLI option that fixes them (not a library field), an OS error
//! appears once, and numbers are printed as numbers (no `DVec3(...)`).

mod common;

use std::path::Path;
use std::process::Output;

use common::{data, scratch, terrain};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Library names a user cannot act on.
fn assert_no_internals(text: &str) {
    for bad in ["LoadOptions", "::", "[`", "`]", "DVec", "BakeConfig", "set overwrite"] {
        assert!(!text.contains(bad), "`{bad}` in:\n{text}");
    }
}

#[test]
fn every_commands_help_is_free_of_rustdoc_links() {
    let top = String::from_utf8(terrain(&["--help"]).stdout).unwrap();
    let commands: Vec<&str> = top
        .lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.split_whitespace().next())
        .filter(|c| *c != "help")
        .collect();
    assert!(commands.len() >= 10, "{top}");
    assert_no_internals(&top);
    for c in commands {
        let out = terrain(&[c, "--help"]);
        assert!(out.status.success(), "{c} --help");
        assert_no_internals(&String::from_utf8(out.stdout).unwrap());
    }
}

#[test]
fn an_os_error_is_printed_once() {
    let dir = scratch("messages", "os");
    let missing = dir.join("missing.json");
    let err = stderr(&terrain(&["fly", "--flight", s(&missing), "-o", s(&dir.join("f"))]));
    assert_eq!(err.matches("(os error 2)").count(), 1, "{err}");
    assert_eq!(err.matches(s(&missing)).count(), 1, "{err}");
    // A bake into a folder under a regular file: the OS error once.
    let file = dir.join("a-file");
    std::fs::write(&file, b"x").unwrap();
    let out = terrain(&["bake", "--synthetic", "65", "-o", s(&file.join("x.scene")), "--no-pvs"]);
    let err = stderr(&out);
    assert!(!out.status.success());
    assert_eq!(err.matches("(os error").count(), 1, "{err}");
}

#[test]
fn errors_name_the_option_that_fixes_them() {
    let dir = scratch("messages", "options");
    // An existing store: --overwrite.
    let store = dir.join("s.scene");
    let bake = |extra: &[&str]| {
        let mut a = vec!["bake", "--synthetic", "65", "--block-k", "5", "-o", s(&store)];
        a.extend(["--no-pvs", "--no-dss", "--no-roughness", "--no-geomip"]);
        a.extend(extra);
        terrain(&a)
    };
    assert!(bake(&[]).status.success());
    let err = stderr(&bake(&[]));
    assert!(err.contains("--overwrite"), "{err}");
    assert_no_internals(&err);
    // A raw file without its size: --raw.
    let raw = dir.join("grid.bin");
    std::fs::write(&raw, [0x5Au8; 64]).unwrap();
    let err = stderr(&terrain(&["info", s(&raw)]));
    assert!(err.contains("--raw WIDTHxHEIGHT:TYPE"), "{err}");
    assert_no_internals(&err);
    // A colour PNG: --format.
    let err = stderr(&terrain(&["info", s(&data("puget_sound/ps_texture_1k.png"))]));
    assert!(err.contains("--format terrain-rgb"), "{err}");
    assert_no_internals(&err);
    // Two tiles far apart: not adjacent (not a size limit).
    let err =
        stderr(&terrain(&["info", s(&data("srtm/N41E001.hgt")), s(&data("srtm/N52E008.hgt"))]));
    assert!(err.contains("is not adjacent to any other tile"), "{err}");
    assert!(!err.contains("max_samples") && !err.contains("exceeds"), "{err}");
}

/// Every option, help text and message gives sizes in MiB (the code computes with 2^20).
#[test]
fn sizes_are_in_mib_everywhere() {
    let is_mb = |t: &str| {
        t.split(|c: char| !c.is_ascii_alphanumeric() && c != '-')
            .any(|w| w == "MB" || w.ends_with("-mb"))
    };
    for c in ["render", "bench", "bake", "info", "fly", "mesh"] {
        let help = String::from_utf8(terrain(&[c, "--help"]).stdout).unwrap();
        assert!(!is_mb(&help), "{c} --help:\n{help}");
    }
    let render = String::from_utf8(terrain(&["render", "--help"]).stdout).unwrap();
    assert!(render.contains("--cache-mib") && render.contains("--page-mib"), "{render}");
    let dir = scratch("messages", "mib");
    let store = dir.join("s.scene");
    let out =
        terrain(&["bake", "--synthetic", "65", "--block-k", "5", "-o", s(&store), "--no-pvs"]);
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), stderr(&out));
    assert!(out.status.success() && text.contains("MiB") && !is_mb(&text), "{text}");
    let info = terrain(&["info", s(&store)]);
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(text.contains("MiB") && !is_mb(&text), "{text}");
}
