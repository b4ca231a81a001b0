//! A scene folder's precomputed files (from `terrain bake`) for the methods that use them: the
//! PVS files ([`crate::pvs_scene`]) for `pvps-c-pvs` and `pvps-c-cons`, the DSS errors
//! ([`crate::dss_scene`]) for `dss-1`, `dss-2` and `dss-strips`, the roughness pyramids
//! ([`crate::roughness_scene`]) for the PVPS methods. `terrain bench`, `render` and
//! `fly` take it as `--scene`. A baked store's per-node tables are read for its methods by
//! [`read_store_table`] (whole, or by pages when large).

use std::path::Path;
use std::sync::Arc;

use anyhow::Context;
use terrain_core::checksum::TableFileError;
use terrain_core::lod::TableReader;
use terrain_stream::Store;

use crate::methods::{LodMethod, MethodScene};

/// The methods that read a scene folder's files ([`load`]): the PVPS methods (roughness
/// pyramids; `pvps-c-pvs` and `pvps-c-cons` also the PVS) and the DSS methods (their errors).
pub const READ_BY: [LodMethod; 9] = [
    LodMethod::PvpsA,
    LodMethod::PvpsB,
    LodMethod::PvpsC,
    LodMethod::PvpsCPvs,
    LodMethod::PvpsCConservative,
    LodMethod::Dss1,
    LodMethod::Dss2,
    LodMethod::DssStrips,
    LodMethod::DssStripsPow2,
];

/// Refuses `--scene` for `methods` none of which reads a scene folder (it would be ignored).
pub fn check_used(methods: &[LodMethod]) -> Result<(), String> {
    if methods.iter().any(|m| READ_BY.contains(m)) {
        return Ok(());
    }
    let names: Vec<&str> = methods.iter().map(|m| m.name()).collect();
    let readers: Vec<&str> = READ_BY.iter().map(|m| m.name()).collect();
    Err(format!(
        "--scene is read by {} only, and {} reads nothing from it",
        readers.join(", "),
        names.join(", ")
    ))
}

/// Reads what `methods` use from scene folder `dir` into `scene`, saying on stderr what was
/// read. Returns the warnings (one per file that could not be used; the method then bakes or
/// computes in memory, or, for a PVS, draws without occlusion culling).
pub fn load(scene: &MethodScene, dir: &Path, methods: &[LodMethod]) -> Vec<String> {
    let uses = |m: &[LodMethod]| methods.iter().any(|x| m.contains(x));
    let mut warnings = Vec::new();
    if uses(&[
        LodMethod::PvpsA,
        LodMethod::PvpsB,
        LodMethod::PvpsC,
        LodMethod::PvpsCPvs,
        LodMethod::PvpsCConservative,
    ]) {
        match crate::roughness_scene::load_into(scene, dir) {
            Ok(path) => eprintln!("roughness pyramids read from {}", path.display()),
            Err(warning) => warnings.push(warning),
        }
    }
    if uses(&[LodMethod::PvpsCPvs, LodMethod::PvpsCConservative]) {
        warnings.extend(crate::pvs_scene::load_into(scene, dir));
    }
    if uses(&[LodMethod::Dss1, LodMethod::Dss2, LodMethod::DssStrips, LodMethod::DssStripsPow2]) {
        match crate::dss_scene::load_into(scene, dir) {
            Ok(path) => eprintln!("DSS errors read from {}", path.display()),
            Err(warning) => warnings.push(warning),
        }
    }
    warnings
}

/// The page cache of a side table read by pages (geomorph's `geomip.bin`, the DSS paper's
/// `dss_errors.bin`) for a store method whose memory budget
/// ([`crate::ooc::OocConfig::budget_bytes`]) is `budget_bytes`: a quarter of it, at least
/// 32 MiB (the tables' own default). The method's scene takes what the cache holds from the
/// blocks' share of the budget each frame ([`crate::ooc::OocScene::set_reserved`]), so the
/// one budget bounds both. At 1 px on the 32769^2 store's `fast_pass`, geomorph's frames
/// touch nearly every patch of its 169 MB table (3.8 M patches drawn at the start): 32 MiB of
/// least recently used pages were read again every frame (5.1 GB over 30 frames, selection
/// 1.13 s a frame, 0.28-0.31 s with the quarter). `dss-2`'s table (1.43 GB there) is walked
/// far less per frame; its selection did not change measurably (bench/ooc/README.md,
/// "Geomorph's table cache from the budget").
pub fn table_cache_bytes(budget_bytes: u64) -> u64 {
    (budget_bytes / 4).max(32 << 20)
}

/// What [`read_store_table`] reads.
pub(crate) struct StoreTable<'a, T> {
    /// The side table's file name in the store (`geomip.bin`, `dss_errors.bin`).
    pub file: &'a str,
    /// Read whole up to this many bytes, by pages above.
    pub read_whole_max: u64,
    /// What to do when the store has no such table, given where it was looked for.
    pub missing: &'a dyn Fn(&str) -> String,
    /// Added to "LOCATION cannot be used" when the table is refused.
    pub unusable_hint: &'a str,
    /// Decodes the whole file.
    pub decode: &'a dyn Fn(&[u8]) -> Result<T, TableFileError>,
    /// Opens it by pages: its location (in errors), the reader, its length.
    pub open_paged: &'a OpenPaged<'a, T>,
}

/// [`StoreTable::open_paged`].
pub(crate) type OpenPaged<'a, T> =
    dyn Fn(&str, Arc<dyn TableReader>, u64) -> Result<T, TableFileError> + 'a;

/// A store's per-node table read for a method (geomorph's `geomip.bin`, the DSS errors):
/// whole when it is at most `read_whole_max` bytes (a remote store's fetched into its mirror
/// first, one GET), else opened by pages through `open_paged` (the table where it lies: the
/// file, a remote store's mirror copy, or the remote object by chunks when the store reads its
/// tables so: [`Store::side_table`]; never fetched whole to open it), or read whole, with a
/// warning, when it is a version-1 file (baked before the tables' page checksums). Fails
/// saying what to bake when the store has none.
pub(crate) fn read_store_table<T>(store: &Store, t: &StoreTable<'_, T>) -> anyhow::Result<T> {
    let expected = if store.is_remote() {
        format!("{}/{}", store.location(), t.file)
    } else {
        store.dir().join(t.file).display().to_string()
    };
    let missing = || (t.missing)(&expected);
    let table = store.side_table(t.file).with_context(missing)?.with_context(missing)?;
    let len = table.len();
    // What is read: the file (a remote store's mirror copy), or the remote object.
    let location = table.location().to_string();
    let unusable = || format!("{location} cannot be used{}", t.unusable_hint);
    let whole = || -> anyhow::Result<T> {
        let path = store.side_file(t.file).with_context(missing)?.with_context(missing)?;
        let bytes = std::fs::read(&path).with_context(missing)?;
        (t.decode)(&bytes).with_context(unusable)
    };
    if len <= t.read_whole_max {
        return whole();
    }
    match (t.open_paged)(&location, Arc::new(table), len) {
        Err(TableFileError::Version { found: 1, .. }) => {
            eprintln!(
                "warning: {location} is version 1, read whole ({:.0} MiB); bake the store again \
                 to read it by pages",
                len as f64 / crate::MIB
            );
            whole()
        }
        other => other.with_context(unusable),
    }
}
