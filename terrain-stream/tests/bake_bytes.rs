//! The bake's output does not depend on how its rows arrive: a grid baked from rows generated
//! band by band (the synthetic source), from the same grid in memory, and from a raw f32 file
//! read by bands of rows (heights and void flags in one read), with one thread or several, gives
//! the same store, every file byte for byte. A negative control (one sample changed) shows the
//! comparison sees a difference.

use std::collections::BTreeMap;
use std::io::Write;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use terrain_core::dem::{Format, LoadOptions, RawSampleType, RawSpec, RowReader};
use terrain_core::heightmap::Heightmap;
use terrain_core::synth::FractalConfig;
use terrain_stream::{BakeConfig, HeightSource, bake};

fn scratch(name: &str) -> PathBuf {
    let d =
        std::env::temp_dir().join(format!("terrain-stream-bytes-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Every file of a store folder (relative path -> bytes).
fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(dir).unwrap().to_string_lossy().into_owned();
                out.insert(rel, std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

fn bake_dir(source: &dyn HeightSource, name: &str, threads: usize) -> PathBuf {
    let out = scratch(name);
    let cfg = BakeConfig { k: 6, threads, ..BakeConfig::default() };
    bake(source, &out, &cfg, &mut |_| ControlFlow::Continue(())).unwrap();
    out
}

/// The first file that differs, or `None`.
fn first_difference(a: &Path, b: &Path) -> Option<String> {
    let (fa, fb) = (files(a), files(b));
    if fa.keys().ne(fb.keys()) {
        return Some(format!("file names differ: {:?} vs {:?}", fa.keys(), fb.keys()));
    }
    fa.iter().find(|(name, bytes)| fb[*name] != **bytes).map(|(name, _)| name.clone())
}

/// The grid's rows into a headerless f32 file, north row first (the raw layout).
fn write_raw(hm: &Heightmap, path: &Path) {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let w = hm.width();
    for j in (0..hm.height()).rev() {
        for z in &hm.data()[j * w..(j + 1) * w] {
            f.write_all(&z.to_le_bytes()).unwrap();
        }
    }
    f.flush().unwrap();
}

#[test]
fn a_bake_is_the_same_bytes_whatever_way_its_rows_arrive() {
    // Not a multiple of the 64-cell blocks either way: padded east and north blocks.
    let synth = FractalConfig::with_size(301, 203, 10.0);
    let hm = synth.to_heightmap().unwrap();
    let generated = bake_dir(&synth, "generated", 2);
    assert!(files(&generated).len() > 10, "a store of several block files");

    let in_memory = bake_dir(&hm, "memory", 1);
    assert_eq!(first_difference(&generated, &in_memory), None, "generated vs in memory");

    let raw = scratch("raw-file");
    std::fs::create_dir_all(&raw).unwrap();
    let raw = raw.join("grid.f32");
    write_raw(&hm, &raw);
    let options = LoadOptions {
        format: Some(Format::Raw),
        raw: Some(RawSpec { width: 301, height: 203, sample: RawSampleType::F32 }),
        spacing_m: 10.0,
        ..LoadOptions::default()
    };
    let rows = RowReader::open(&raw, &options).unwrap();
    let from_file = bake_dir(&rows, "file", 3);
    assert_eq!(first_difference(&generated, &from_file), None, "generated vs raw file");

    // Negative control: one sample 5 m higher changes a block file.
    let mut data = hm.data().to_vec();
    data[150 * 301 + 77] += 5.0;
    let changed = Heightmap::new(301, 203, data, hm.voids().clone(), hm.georef().clone()).unwrap();
    let other = bake_dir(&changed, "changed", 2);
    let diff = first_difference(&generated, &other).expect("a changed sample changes the store");
    assert!(diff.contains("blocks") || diff.contains("index"), "{diff}");

    for d in [generated, in_memory, from_file, other, raw.parent().unwrap().to_path_buf()] {
        let _ = std::fs::remove_dir_all(d);
    }
}
