//! End-to-end tests of `terrain bake --shard K/N` and `--merge`: a real DEM with voids (Crater
//! Lake, its voids given by --nodata) baked in N = 1..4 shards and merged is the single bake's
//! store, every file (blocks, index and every scene table) byte for byte, with a negative
//! control; the merge refuses parts of another DEM, of other options, and missing shards,
//! naming them; a bad `--shard` is refused before any work.

mod common;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Output;

use common::{data, terrain};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn ok(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "terrain bake failed: {err}");
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn failed(out: &Output) -> String {
    assert!(!out.status.success(), "expected a failure: {}", String::from_utf8_lossy(&out.stdout));
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Every file of a folder (relative path -> bytes).
fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    common::files_under(dir)
        .into_iter()
        .map(|p| {
            let rel = p.strip_prefix(dir).unwrap().to_string_lossy().into_owned();
            (rel, std::fs::read(&p).unwrap())
        })
        .collect()
}

/// The first file that differs (or the file names), `None` when the folders are identical.
fn first_difference(a: &Path, b: &Path) -> Option<String> {
    let (fa, fb) = (files(a), files(b));
    if fa.keys().ne(fb.keys()) {
        return Some(format!("file names differ: {:?} vs {:?}", fa.keys(), fb.keys()));
    }
    fa.iter().find(|(name, bytes)| fb[*name] != **bytes).map(|(name, _)| name.clone())
}

/// Crater Lake's options: its voids (-32767, no tag), blocks of 64 cells (7 x 5 blocks), every
/// table, the PVS at a small size.
const OPTIONS: [&str; 8] =
    ["--nodata", "-32767", "--block-k", "6", "--pvs-cells", "4", "--pvs-floors", "1"];

fn bake(dem: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["bake", s(dem)];
    args.extend(OPTIONS);
    args.extend(extra);
    terrain(&args)
}

#[test]
fn a_sharded_bake_of_a_dem_with_voids_merges_into_the_single_bakes_bytes() {
    let dem = data("crater_lake/craterlake-elev-16bit-30m.tif");
    let dir = common::scratch("shard-cli", "bytes");
    let single = dir.join("single");
    ok(&bake(&dem, &["-o", s(&single)]));
    let tables = files(&single);
    for t in ["index.tsi", "roughness.bin", "geomip.bin", "dss_errors.bin", "pvs.bin"] {
        assert!(tables.contains_key(t), "{t} in {:?}", tables.keys());
    }
    for n in 1..=4u32 {
        let parts = dir.join(format!("parts{n}"));
        for k in 0..n {
            let part = parts.join(format!("p{k}"));
            let stdout = ok(&bake(&dem, &["--shard", &format!("{k}/{n}"), "-o", s(&part)]));
            assert!(stdout.contains(&format!("shard {k}/{n}")), "{stdout}");
            assert!(!part.join("roughness.bin").exists(), "a shard bakes no table");
        }
        let merged = dir.join(format!("merged{n}"));
        ok(&bake(&dem, &["--merge", s(&parts), "-o", s(&merged)]));
        assert_eq!(first_difference(&single, &merged), None, "{n} shards");
    }
    // Negative control: one byte of the merged roughness table changed shows.
    let merged = dir.join("merged4");
    let table = merged.join("roughness.bin");
    let mut bytes = std::fs::read(&table).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 1;
    std::fs::write(&table, bytes).unwrap();
    assert_eq!(first_difference(&single, &merged).as_deref(), Some("roughness.bin"));

    // Refusals, by name: parts of another DEM (Crater Lake read without --nodata: other
    // heights), of other options (--block-k 5), and a missing shard.
    let parts = dir.join("parts2");
    let out = dir.join("refused");
    let mut other = vec!["bake", s(&dem), "--block-k", "6", "--merge", s(&parts), "-o", s(&out)];
    let e = failed(&terrain(&other));
    assert!(e.contains("p0") && e.contains("another source"), "{e}");
    other[3] = "5";
    other.splice(2..2, ["--nodata", "-32767"]);
    let e = failed(&terrain(&other));
    assert!(e.contains("p0") && e.contains("other options"), "{e}");
    let p0 = parts.join("p0");
    let e = failed(&bake(&dem, &["--merge", s(&p0), "-o", s(&out)]));
    assert!(e.contains("shard 1/2 missing"), "{e}");
    assert!(!out.exists(), "a refused merge writes nothing");
    let e = failed(&bake(&dem, &["--shard", "2/2", "-o", s(&out)]));
    assert!(e.contains("K in 0..N"), "{e}");
}
