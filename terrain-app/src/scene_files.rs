//! A scene folder's precomputed files (from `terrain bake`) for the methods that use them: the
//! PVS files ([`crate::pvs_scene`]) for `pvps-c-pvs` and `pvps-c-cons`, the DSS errors
//! ([`crate::dss_scene`]) for `dss-1`, `dss-2` and `dss-strips`, the roughness pyramids
//! ([`crate::roughness_scene`]) for the PVPS methods. `terrain bench`, `render` and
//! `fly` take it as `--scene`.

use std::path::Path;

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
