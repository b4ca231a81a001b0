//! End-to-end test of an interrupted `terrain bake`: SIGINT or SIGTERM once the bake has
//! started writing blocks exits with status 130, leaves no `.NAME.part` folder and leaves the
//! existing store it was to replace as it was.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use terrain_stream::Store;

use common::terrain;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Every file under `dir` with its bytes, sorted by path.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                todo.push(p);
            } else {
                out.push((p.clone(), std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

fn interrupted_bake(signal: &str) {
    let dir = common::scratch("interrupt-cli", signal);
    let out = dir.join("store");
    // The store the interrupted bake is to replace.
    let small = terrain(&[
        "bake",
        "--synthetic",
        "65",
        "-o",
        s(&out),
        "--block-k",
        "5",
        "--no-pvs",
        "--no-dss",
    ]);
    assert!(small.status.success(), "{}", String::from_utf8_lossy(&small.stderr));
    let before = snapshot(&out);
    assert!(!before.is_empty());

    // Large enough that it is still writing blocks when the signal comes (many rows of small
    // blocks, each row a point where the bake checks the flag).
    let mut child = Command::new(env!("CARGO_BIN_EXE_terrain"))
        .args(["bake", "--synthetic", "16385", "-o", s(&out), "--overwrite", "--block-k", "5"])
        .args(["--threads", "1", "--no-dss", "--no-pvs", "--no-roughness", "--no-geomip"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let part = dir.join(".store.part");
    let blocks = part.join("blocks");
    let start = Instant::now();
    let writing = || std::fs::read_dir(&blocks).is_ok_and(|mut d| d.next().is_some());
    while !writing() {
        if start.elapsed() > Duration::from_secs(300) || child.try_wait().unwrap().is_some() {
            let _ = child.kill();
            panic!("the bake never started writing blocks into {}", blocks.display());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let sent = Command::new("kill").args([signal, &child.id().to_string()]).status().unwrap();
    assert!(sent.success());
    let output = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(130), "{signal}: {:?} {err}", output.status);
    assert!(err.contains("interrupted") && !err.contains("panicked"), "{err}");
    assert!(!part.exists(), "{signal}: {} left behind", part.display());
    let names: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(names, ["store"], "{signal}: only the store is left in {}", dir.display());
    // The old store, byte for byte, and it still opens as the 65 x 65 store.
    assert!(snapshot(&out) == before, "{signal}: the existing store was changed");
    assert_eq!(Store::open(&out).unwrap().header().width, 65);
}

#[test]
fn sigint_during_a_bake_removes_its_part_folder_and_keeps_the_old_store() {
    interrupted_bake("-INT");
}

#[test]
fn sigterm_during_a_bake_removes_its_part_folder_and_keeps_the_old_store() {
    interrupted_bake("-TERM");
}
