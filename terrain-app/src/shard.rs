//! `terrain bake --shard K/N` and `terrain bake --merge PART...`: the blocks of a bake split
//! across processes or machines by block rows (`terrain_stream::bake_shard`), then joined
//! (`terrain_stream::merge`) into the store a single `terrain bake` writes, byte for byte.
//!
//! The shards bake the blocks and their index entries (per-node min/max/StaticE, the DSS
//! paper's 32 errors per block) and geomorph's table of their rows (joined by the merge). The
//! other scene tables (roughness pyramids, DSS errors per node, PVS) are baked by the merge, from the DEM given to it again, by the very
//! code a single bake runs: they are computed from the source's heights (not the stored,
//! quantized ones), and the roughness, DSS and PVS tables need the whole grid's quadtree.
//!
//! Each part records the source's identity ([`source_id`]: every DEM file's name, length and
//! CRC-32, or the synthetic terrain's size; how it is read) and the bake options; the merge
//! computes both from its own arguments and refuses any part whose differ, by name.

use std::io::Read;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use anyhow::Context;
use terrain_core::checksum::crc32_update;
use terrain_stream::{
    BakeConfig, BakeError, BakeProgress, BakeReport, HeightSource, MergeConfig, Shard,
};

use crate::bake::BakeArgs;

/// What a part records of the source: the synthetic terrain's size, or every DEM file's name,
/// length and CRC-32 (the whole file read once; a path may differ between machines, the
/// bytes may not), with the reading options that change the heights and whether the grid is
/// read by rows (which fills voids differently).
pub(crate) fn source_id(args: &BakeArgs, by_rows: bool) -> anyhow::Result<String> {
    if let Some(n) = args.synthetic {
        return Ok(format!("synthetic fractal {n} x {n} at 10 m"));
    }
    let mut files = Vec::new();
    for path in &args.source.dem {
        let mut f = std::fs::File::open(path).with_context(|| format!("{}", path.display()))?;
        let (mut crc, mut len) = (0u32, 0u64);
        let mut buf = vec![0u8; 1 << 20];
        loop {
            let n = f.read(&mut buf).with_context(|| format!("reading {}", path.display()))?;
            if n == 0 {
                break;
            }
            crc = crc32_update(crc, &buf[..n]);
            len += n as u64;
        }
        let name = path.file_name().map(|n| n.to_string_lossy()).unwrap_or_default();
        files.push(format!("{name} ({len} bytes, CRC-32 {crc:08x})"));
    }
    let s = &args.source;
    Ok(format!(
        "{}; format {:?}, nodata {:?}, vertical scale {} offset {}, spacing {:?}, band {}, raw {:?}, {}",
        files.join(", "),
        s.format,
        s.nodata,
        s.vertical_scale,
        s.vertical_offset,
        s.spacing,
        s.band,
        s.raw,
        if by_rows { "read by rows" } else { "read whole" }
    ))
}

/// `--shard K/N`: bakes the shard's blocks into the part folder `-o`, and no table.
pub(crate) fn run_shard(
    args: &BakeArgs,
    source: &dyn HeightSource,
    config: &BakeConfig,
    shard: Shard,
    by_rows: bool,
    progress: &mut (dyn FnMut(&BakeProgress) -> ControlFlow<()> + Send),
) -> anyhow::Result<()> {
    let id = source_id(args, by_rows)?;
    let out = &args.output;
    let r = match terrain_stream::bake_shard(source, out, config, shard, &id, progress) {
        Err(BakeError::Cancelled) => {
            return Err(crate::interrupt::Interrupted(format!(
                "no part written, {} is as it was",
                out.display()
            ))
            .into());
        }
        r => r.with_context(|| format!("baking shard {shard} into {}", out.display()))?,
    };
    println!(
        "{}: shard {} (block rows {}..{}): {} blocks, {:.1} MiB, {:.1} s",
        out.display(),
        r.shard,
        r.rows.start,
        r.rows.end,
        r.blocks,
        r.bytes as f64 / terrain_app::MIB,
        r.elapsed.as_secs_f64()
    );
    Ok(())
}

/// The store's blocks and index, into the local folder `out` (never `args.output`, which may
/// be a URL): baked, or with `--merge`, joined from the parts (each
/// argument a part folder or a folder of parts), which must be of this source and options.
/// The outer error: the parts or the source could not be read; the inner: the bake's or merge's.
pub(crate) fn bake_or_merge(
    args: &BakeArgs,
    out: &Path,
    source: &dyn HeightSource,
    config: &BakeConfig,
    by_rows: bool,
    progress: &mut (dyn FnMut(&BakeProgress) -> ControlFlow<()> + Send),
) -> anyhow::Result<Result<BakeReport, BakeError>> {
    if args.merge.is_empty() {
        return Ok(terrain_stream::bake(source, out, config, progress));
    }
    let mut parts: Vec<PathBuf> = Vec::new();
    for p in &args.merge {
        parts.extend(terrain_stream::find_parts(p)?);
    }
    let merge = MergeConfig {
        overwrite: config.overwrite,
        threads: config.threads,
        source_id: Some(source_id(args, by_rows)?),
        bake: Some(config.clone()),
    };
    Ok(terrain_stream::merge(&parts, out, &merge, progress))
}
