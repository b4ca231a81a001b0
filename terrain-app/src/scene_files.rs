//! A scene folder's precomputed files (from `terrain bake`) for the methods that use them: the
//! PVS files ([`crate::pvs_scene`]) for `pvps-c-pvs` and `pvps-c-cons`, the DSS errors
//! ([`crate::dss_scene`]) for `dss-1`, `dss-2` and `dss-strips`, the roughness pyramids
//! ([`crate::roughness_scene`]) for the PVPS methods. `terrain bench`, `render` and
//! `fly` take it as `--scene`.

use std::path::Path;

use crate::methods::{LodMethod, MethodScene};

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
    if uses(&[LodMethod::Dss1, LodMethod::Dss2, LodMethod::DssStrips]) {
        match crate::dss_scene::load_into(scene, dir) {
            Ok(path) => eprintln!("DSS errors read from {}", path.display()),
            Err(warning) => warnings.push(warning),
        }
    }
    warnings
}
