//! The PVS files of a scene (the folder `terrain bake` writes): their names, and loading them
//! into a [`MethodScene`] so that a bad file turns occlusion culling off with a warning
//! instead of failing the run.

use std::path::{Path, PathBuf};

use terrain_visibility::pvs::{PvsMode, read_pvs};

use crate::methods::MethodScene;

/// The sampled (the PVPS paper's) PVS in a scene folder.
pub const SAMPLED_FILE: &str = "pvs.bin";
/// The conservative PVS in a scene folder.
pub const CONSERVATIVE_FILE: &str = "pvs_conservative.bin";

/// The file name of `mode`'s PVS.
pub fn pvs_file(mode: PvsMode) -> &'static str {
    match mode {
        PvsMode::Sampled => SAMPLED_FILE,
        PvsMode::Conservative => CONSERVATIVE_FILE,
    }
}

/// The file of `mode` in scene folder `dir`.
pub fn pvs_path(dir: &Path, mode: PvsMode) -> PathBuf {
    dir.join(pvs_file(mode))
}

/// Loads both PVS files of scene folder `dir` into `scene`. Returns one warning per file that
/// could not be used (missing, corrupt, truncated, another grid); for those, the matching
/// method draws without occlusion culling.
pub fn load_into(scene: &MethodScene, dir: &Path) -> Vec<String> {
    let mut warnings = Vec::new();
    for mode in [PvsMode::Sampled, PvsMode::Conservative] {
        let path = pvs_path(dir, mode);
        let result = read_pvs(&path).map_err(|e| e.to_string()).and_then(|p| {
            if p.mode != mode {
                return Err(format!("{}: holds a {} PVS", path.display(), p.mode.name()));
            }
            scene.set_pvs(mode, Some(p)).map_err(|e| format!("{}: {e}", path.display()))
        });
        if let Err(e) = result {
            let _ = scene.set_pvs(mode, None);
            warnings.push(format!("{e}; drawing without {} occlusion culling", mode.name()));
        }
    }
    warnings
}
