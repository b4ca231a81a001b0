//! The store target: two tiny stores baked once (Deflate-coded quantized levels, and plain
//! float levels) with the per-node tables a `terrain bake` writes beside them (DSS errors,
//! roughness pyramids, geo-mipmap table, both PVSs); each case replaces one of their files (or
//! a block level and the index entry whose CRC covers it, or a baked tin tile and its index
//! entry's CRC) and goes through the public API: `Store::open`, `read_block` of every block to
//! its finest level, `select_patches`, and each table's decoder as the store-backed methods
//! call it (the tin tiles' through terrain-core's `tile_file`, as the app's reader does).

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use terrain_core::checksum::crc32;
use terrain_core::lod::dss_file::heights_checksum;
use terrain_core::lod::{DssErrorTable, GeomipFor, GeomipTable};
use terrain_core::quadtree::{NodeId, NodeTree, Quadtree, TreeShape};
use terrain_core::synth::FractalConfig;
use terrain_core::tin::grid::{build_tile_at, level_errors};
use terrain_core::tin::tile_file;
use terrain_stream::glam::dvec3;
use terrain_stream::{
    BakeConfig, BakeProgress, Camera, Codec, HeightEncoding, INDEX_FILE, Store, StoreTree, bake,
    select_patches,
};
use terrain_visibility::pvs::{PvsConfig, bake_both, read_pvs, write_pvs};
use terrain_visibility::roughness::file::{self as roughness_file, Expected, TerrainTie};
use terrain_visibility::roughness::{RoughnessConfig, RoughnessTables, quadtree_levels};

use crate::case::{Case, Target};
use crate::mutate::{self, Kind};
use crate::rng::Rng;

/// The store's quadtree leaves (the methods' default `--leaf-cells`).
const LEAF_CELLS: u32 = 16;
const DSS_FILE: &str = "dss_errors.bin";
const ROUGHNESS_FILE: &str = "roughness.bin";
const GEOMIP_FILE: &str = "geomip.bin";
const PVS_FILES: [&str; 2] = ["pvs.bin", "pvs_conservative.bin"];
/// The `tin` method's baked tiles (terrain-app's `tin_scene`), here every tile of the tree
/// meshed from at most 16 cells across by terrain-core's builder.
const TIN_FILE: &str = "tin_tiles.bin";
const TIN_MAX_CELLS: u32 = 16;

/// One pristine store: its folder and its files (relative path, bytes), sorted.
#[derive(Debug)]
pub(crate) struct Pristine {
    pub dir: PathBuf,
    pub files: Vec<(String, Vec<u8>)>,
}

/// Bakes the fixture's stores into `work` (deterministic: same bytes every run) and checks
/// that each reads whole.
pub(crate) fn fixture(work: &Path) -> Result<Vec<Pristine>, String> {
    let source = FractalConfig::with_size(97, 81, 10.0);
    let hm = source.to_heightmap().map_err(|e| e.to_string())?;
    let configs = [
        BakeConfig { k: 5, threads: 1, overwrite: true, ..Default::default() },
        BakeConfig {
            k: 5,
            threads: 1,
            overwrite: true,
            codec: Codec::Plain,
            encoding: HeightEncoding::Bounded { max_error_m: 0.01 },
            node_levels: 2,
            // The index without DSS errors (NaN), so the reader's presence check is fuzzed too.
            dss_errors: false,
            geomip_patch_cells: None,
        },
    ];
    let mut out = Vec::new();
    for (n, config) in configs.iter().enumerate() {
        let dir = work.join(format!("store{n}"));
        bake(&source, &dir, config, &mut |_: &BakeProgress| ControlFlow::Continue(()))
            .map_err(|e| format!("baking the fixture store {}: {e}", dir.display()))?;
        let store = Store::open(&dir).map_err(|e| e.to_string())?;
        let qt = Quadtree::new(&hm, LEAF_CELLS);
        std::fs::write(dir.join(DSS_FILE), DssErrorTable::new(&hm, &qt).encode(&hm))
            .map_err(|e| e.to_string())?;
        std::fs::write(dir.join(GEOMIP_FILE), GeomipTable::new(&hm, LEAF_CELLS).encode(&hm))
            .map_err(|e| e.to_string())?;
        let levels = quadtree_levels(hm.width(), hm.height(), LEAF_CELLS as usize);
        let config = RoughnessConfig::default();
        let tables = RoughnessTables::compute(&hm, levels, &config);
        let tie = (store.header().bake_id, index_crc(&dir)?);
        let bytes = roughness_file::encode(
            &tables,
            hm.width(),
            hm.height(),
            heights_checksum(&hm),
            Some(tie),
            &config,
        );
        std::fs::write(dir.join(ROUGHNESS_FILE), bytes).map_err(|e| e.to_string())?;
        let pvs = PvsConfig {
            cells: (4, 4),
            floors: 2,
            patch_level: 3,
            threads: 1,
            ..Default::default()
        };
        let (sampled, conservative, _) = bake_both(&hm, &pvs);
        for (p, name) in [(&sampled, PVS_FILES[0]), (&conservative, PVS_FILES[1])] {
            write_pvs(p, &dir.join(name)).map_err(|e| e.to_string())?;
        }
        let shape = *StoreTree::new(Arc::new(store.clone()), LEAF_CELLS).shape();
        std::fs::write(dir.join(TIN_FILE), tin_file(&hm, &shape, store.header().bake_id)?)
            .map_err(|e| e.to_string())?;
        let summary = run(&dir)?;
        if summary.contains("refused") {
            return Err(format!(
                "the pristine fixture store {} does not read: {summary}",
                dir.display()
            ));
        }
        let mut files = Vec::new();
        list(&dir, &dir, &mut files).map_err(|e| e.to_string())?;
        files.sort();
        out.push(Pristine { dir, files });
    }
    Ok(out)
}

/// A `tin_tiles.bin` of every tile of tree `shape` over `hm` (the file `terrain bake` writes
/// holds the coarse ones of a larger tree; the format is the same).
fn tin_file(
    hm: &terrain_core::Heightmap,
    shape: &TreeShape,
    bake_id: u64,
) -> Result<Vec<u8>, String> {
    let errors = level_errors(shape, 1.0);
    let mut file = vec![0u8; tile_file::HEADER_BYTES];
    let mut index = Vec::new();
    let mut tiles = 0u32;
    for level in 0..=shape.max_level() {
        let (nx, ny) = shape.level_dims(level);
        for j in 0..ny {
            for i in 0..nx {
                let n = NodeId::new(level, i, j);
                let t = build_tile_at(hm, shape, n, errors[level as usize], Some(TIN_MAX_CELLS))
                    .map_err(|e| e.to_string())?;
                let origin = tile_file::tile_origin(shape, n).map_err(|e| e.to_string())?;
                let bytes = tile_file::encode_tile(&t, origin);
                let entry = tile_file::encode_entry(n, t.stride_log2, file.len() as u64, &bytes);
                index.extend_from_slice(&entry);
                file.extend_from_slice(&bytes);
                tiles += 1;
            }
        }
    }
    let key = tile_file::TileFileKey {
        width: shape.width(),
        height: shape.height(),
        root_cells: shape.root_cells(),
        max_level: shape.max_level().into(),
        error_scale: 1.0,
        max_tile_cells: TIN_MAX_CELLS,
        finer_strides: 0,
        min_stride_log2: 0,
        bake_id,
    };
    let head = tile_file::encode_header(&key, tiles, file.len() as u64);
    file[..tile_file::HEADER_BYTES].copy_from_slice(&head);
    file.extend_from_slice(&index);
    Ok(file)
}

fn list(root: &Path, dir: &Path, out: &mut Vec<(String, Vec<u8>)>) -> std::io::Result<()> {
    for e in std::fs::read_dir(dir)? {
        let p = e?.path();
        if p.is_dir() {
            list(root, &p, out)?;
        } else {
            let rel = p.strip_prefix(root).expect("under the root").to_string_lossy().into_owned();
            out.push((rel, std::fs::read(&p)?));
        }
    }
    Ok(())
}

/// CRC-32 of the index content (its bytes before its own CRC): what ties the roughness file
/// to the store.
fn index_crc(dir: &Path) -> Result<u32, String> {
    let bytes = std::fs::read(dir.join(INDEX_FILE)).map_err(|e| e.to_string())?;
    Ok(crc32(&bytes[..bytes.len().saturating_sub(4)]))
}

/// A store case: one file of store `n` mutated, or (deep) one level of a block rewritten
/// with its CRC in the index updated so the level's decoder sees the damage.
pub(crate) fn make_case(stores: &[Pristine], rng: &mut Rng, seed: u64, iteration: u64) -> Case {
    let n = rng.below(stores.len());
    let s = &stores[n];
    let index = s.files.iter().position(|(f, _)| f == INDEX_FILE).expect("a store has an index");
    let blocks: Vec<usize> =
        (0..s.files.len()).filter(|&i| s.files[i].0.starts_with("blocks")).collect();
    let pick = if !blocks.is_empty() && rng.chance(0.35) {
        *rng.pick(&blocks)
    } else {
        rng.below(s.files.len())
    };
    let (name, orig) = &s.files[pick];
    let mut bytes = orig.clone();
    let donor = &s.files[rng.below(s.files.len())].1;
    if pick != index
        && name.starts_with("blocks")
        && rng.chance(0.6)
        && let Some((what, new_index)) = deep_block(&s.dir, &mut bytes, &s.files[index].1, rng)
    {
        return Case {
            target: Target::Store(n),
            files: vec![(name.clone(), bytes), (INDEX_FILE.to_string(), new_index)],
            seed,
            iteration,
            what: format!("store{n} {name}: {what}"),
        };
    }
    if name == TIN_FILE
        && rng.chance(0.6)
        && let Some(what) = deep_tin_tile(&mut bytes, rng)
    {
        return Case {
            target: Target::Store(n),
            files: vec![(name.clone(), bytes)],
            seed,
            iteration,
            what: format!("store{n} {name}: {what}"),
        };
    }
    let kind =
        if name.starts_with("blocks") || name == TIN_FILE { Kind::Bytes } else { Kind::Crc32Tail };
    let what = mutate::mutate(&mut bytes, kind, rng, donor);
    Case {
        target: Target::Store(n),
        files: vec![(name.clone(), bytes)],
        seed,
        iteration,
        what: format!("store{n} {name}: {what}"),
    }
}

/// Mutates one level's payload inside block file `bytes` and returns the index with that
/// level's CRC-32 (and the index's own) updated to match.
fn deep_block(
    dir: &Path,
    bytes: &mut [u8],
    index: &[u8],
    rng: &mut Rng,
) -> Option<(String, Vec<u8>)> {
    // The block's row and column are in its header (bytes 20..28).
    let row = u32::from_le_bytes(bytes.get(20..24)?.try_into().ok()?);
    let col = u32::from_le_bytes(bytes.get(24..28)?.try_into().ok()?);
    let store = Store::open(dir).ok()?;
    let id = store.block_ids().find(|id| id.row == row && id.col == col)?;
    let entry = store.entry(id)?;
    let l = rng.below(entry.levels.len());
    let le = entry.levels[l];
    let (start, len) = (le.offset as usize, le.len as usize);
    if len == 0 {
        return None;
    }
    let mut payload = bytes.get(start..start + len)?.to_vec();
    let what = mutate::generic(&mut payload, rng, &[]);
    let grew = payload.len() != len;
    if grew {
        // Lengths live in the index too; keep the level's length so only its content is wrong.
        payload.resize(len, 0);
    }
    bytes[start..start + len].copy_from_slice(&payload);
    let new_crc = crc32(&payload);
    let old = le.crc32.to_le_bytes();
    let mut idx = index.to_vec();
    let body = idx.len().checked_sub(4)?;
    let at = (0..body.saturating_sub(3)).find(|&i| idx[i..i + 4] == old)?;
    idx[at..at + 4].copy_from_slice(&new_crc.to_le_bytes());
    mutate::fix_crc_tail(&mut idx);
    Some((format!("level {l} of block {id} ({what}), its CRC updated in the index"), idx))
}

/// Mutates one tile's bytes inside a `tin_tiles.bin` (same length) and updates its index
/// entry's CRC-32 to match, so the tile's decoder sees the damage.
fn deep_tin_tile(file: &mut [u8], rng: &mut Rng) -> Option<String> {
    let len = file.len() as u64;
    let header = tile_file::parse_header(file.get(..tile_file::HEADER_BYTES)?, len).ok()?;
    let tiles = header.tiles as usize;
    if tiles == 0 {
        return None;
    }
    let k = rng.below(tiles);
    let e_at = header.index_offset as usize + k * tile_file::ENTRY_BYTES;
    let entry = file.get(e_at..e_at + tile_file::ENTRY_BYTES)?;
    let offset = u64::from_le_bytes(entry[16..24].try_into().ok()?) as usize;
    let n = u32::from_le_bytes(entry[24..28].try_into().ok()?) as usize;
    let mut payload = file.get(offset..offset + n)?.to_vec();
    let what = mutate::generic(&mut payload, rng, &[]);
    payload.resize(n, 0);
    file[offset..offset + n].copy_from_slice(&payload);
    let crc = crc32(&payload);
    file[e_at + 28..e_at + 32].copy_from_slice(&crc.to_le_bytes());
    Some(format!("tile {k} ({what}), its CRC updated in the index"))
}

/// Opens the store in `dir` and reads everything a store-backed method reads. `Ok` with a
/// summary (each part read or refused), or the opener's refusal.
pub(crate) fn run(dir: &Path) -> Result<String, String> {
    let store = Store::open(dir).map_err(|e| e.to_string())?;
    let k = store.header().k;
    let mut parts = Vec::new();
    let ids: Vec<_> = store.block_ids().collect();
    let mut bad_blocks = 0;
    for &id in &ids {
        let _ = store.block_rect(id);
        match store.read_block(id, k) {
            Ok(b) => {
                let _ = b.grid(k);
            }
            Err(_) => bad_blocks += 1,
        }
    }
    parts.push(if bad_blocks == 0 {
        format!("{} blocks read", ids.len())
    } else {
        format!("{bad_blocks} of {} blocks refused", ids.len())
    });
    let (bake_id, header) = (store.header().bake_id, store.header().clone());
    let store = Arc::new(store);
    let tree = StoreTree::new(store.clone(), LEAF_CELLS);
    let shape = *tree.shape();

    // A view from above the middle of the first block, looking north, every block resident.
    if let Some((lo, hi)) = store.block_rect(ids[0]) {
        let c = (lo + hi) * 0.5;
        let eye =
            dvec3(c.x, c.y - (hi.y - lo.y), f64::from(header.georef.spacing_m.x as f32) * 50.0);
        if eye.is_finite() {
            let camera = Camera::from_yaw_pitch(eye, 0.0, -30.0).with_clip(1.0, 1e6);
            let sel = select_patches(&tree, &camera, 2.0, |_| Some(k));
            parts.push(format!("{} patches", sel.patches.len()));
        }
    }

    let read = |name: &str| std::fs::read(dir.join(name)).map_err(|e| e.to_string());
    let outcome = |name: &str, r: Result<(), String>| match r {
        Ok(()) => format!("{name} read"),
        Err(e) => format!("{name} refused ({e})"),
    };
    let dss = read(DSS_FILE).and_then(|b| {
        DssErrorTable::decode_for(&b, &shape, None).map(|_| ()).map_err(|e| e.to_string())
    });
    parts.push(outcome(DSS_FILE, dss));
    // Read by pages (what a large store's table gets): opened from the header and tail, then
    // every node of every level asked (each page read and checked once, in order).
    let paged = read(DSS_FILE).and_then(|b| {
        let len = b.len() as u64;
        let paging = terrain_core::lod::DssPaging::default();
        let t = DssErrorTable::open_paged(DSS_FILE, Arc::new(b), len, &shape, None, &paging)
            .map_err(|e| e.to_string())?;
        for level in 0..=shape.max_level() {
            let (nx, ny) = shape.level_dims(level);
            for j in 0..ny {
                for i in 0..nx {
                    std::hint::black_box(t.get(terrain_core::quadtree::NodeId { level, i, j }));
                }
            }
        }
        t.take_error().map_or(Ok(()), |e| Err(e.to_string()))
    });
    parts.push(outcome("dss_errors.bin by pages", paged));
    let want = GeomipFor {
        width: shape.width(),
        height: shape.height(),
        patch_cells: shape.leaf_cells(),
        heights_crc: None,
    };
    let geomip = read(GEOMIP_FILE)
        .and_then(|b| GeomipTable::decode(&b, &want).map(|_| ()).map_err(|e| e.to_string()));
    parts.push(outcome(GEOMIP_FILE, geomip));
    let expected = Expected {
        width: header.width as usize,
        height: header.height as usize,
        levels: quadtree_levels(header.width as usize, header.height as usize, LEAF_CELLS as usize),
        config: RoughnessConfig::default(),
        tie: TerrainTie::Store { bake_id, index_crc: index_crc(dir)? },
    };
    let rough = read(ROUGHNESS_FILE).and_then(|b| {
        roughness_file::decode_for(&b, &expected).map(|_| ()).map_err(|e| e.to_string())
    });
    parts.push(outcome(ROUGHNESS_FILE, rough));
    let tin = read(TIN_FILE).and_then(|b| {
        let head = b.get(..tile_file::HEADER_BYTES).ok_or("shorter than its header")?;
        let header = tile_file::parse_header(head, b.len() as u64).map_err(|e| e.to_string())?;
        let index = &b[header.index_offset as usize..];
        let slots = tile_file::parse_index(index, &header, &shape).map_err(|e| e.to_string())?;
        let mut refused = 0;
        for (node, slot) in &slots {
            let bytes = &b[slot.offset as usize..][..slot.len as usize];
            match tile_file::read_tile(*node, slot, bytes, &shape) {
                Ok(t) => {
                    // What the method does with a tile: its sides and heights by vertex.
                    std::hint::black_box(t.side(terrain_core::quadtree::Direction::North).count());
                    std::hint::black_box(
                        t.triangles.iter().flatten().map(|&v| t.heights[v as usize]).sum::<f32>(),
                    );
                }
                Err(_) => refused += 1,
            }
        }
        if refused > 0 {
            Err(format!("{refused} of {} tiles refused", slots.len()))
        } else {
            Ok(())
        }
    });
    parts.push(outcome(TIN_FILE, tin));
    for name in PVS_FILES {
        let pvs = read_pvs(&dir.join(name)).map_err(|e| e.to_string()).and_then(|p| {
            if !p.matches(&shape) {
                return Err("made for another grid".to_string());
            }
            // Every cell's bits at every level of the pyramid, as the culling reads them.
            let lmax = p.layout.patch_level;
            let mut visible = 0usize;
            for c in 0..p.layout.cell_count() {
                let cell = p.layout.cell_at_index(c);
                for l in 0..=lmax.min(6) {
                    let side = 1u32 << l;
                    for j in 0..side {
                        for i in 0..side {
                            visible += usize::from(p.visible(cell, NodeId::new(l, i, j)));
                        }
                    }
                }
            }
            let _ = p.culled_fraction();
            let _ = visible;
            Ok(())
        });
        parts.push(outcome(name, pvs));
    }
    Ok(parts.join(", "))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fixture's tin tiles read whole, and a tile damaged behind a matching CRC (the deep
    /// mutation) is refused by its decoder or read as a valid tile, never a panic; some of
    /// the seeded cases are refused, so the decoder is reached.
    #[test]
    fn the_tin_tiles_read_and_their_deep_damage_reaches_the_decoder() {
        let work = std::env::temp_dir().join(format!("terrain-fuzz-tin-{}", std::process::id()));
        let stores = fixture(&work).unwrap();
        let s = &stores[0];
        assert!(run(&s.dir).unwrap().contains("tin_tiles.bin read"));
        let orig = &s.files.iter().find(|(n, _)| n == TIN_FILE).expect("the tin tiles").1;
        let case_dir = work.join("case");
        let mut refused = 0;
        for i in 0..40 {
            let mut bytes = orig.clone();
            let what = deep_tin_tile(&mut bytes, &mut Rng::for_case(7, i)).expect("a tile");
            crate::materialise(s, &[(TIN_FILE.to_string(), bytes)], &case_dir).unwrap();
            let summary = run(&case_dir).unwrap();
            refused += usize::from(summary.contains("tin_tiles.bin refused"));
            println!("{what}: {summary}");
        }
        assert!(refused > 0, "no deep mutation was refused");
        std::fs::remove_dir_all(&work).unwrap();
    }
}
