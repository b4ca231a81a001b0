//! The options `render`, `fly` and `view` share, one clap struct per group flattened into
//! each command (one definition, one help text, one check): the LOD method and its quality
//! ([`MethodArgs`]), a store's streaming options ([`StoreArgs`]), and the camera
//! ([`CameraArgs`]: `render` and `view`; `fly` takes its cameras from the flight). The input
//! is [`crate::source::SourceArgs`]; the image size stays per command (its default differs:
//! `fly` writes many frames, at 640x360).

use anyhow::bail;
use clap::Args;
use terrain_app::methods::LodMethod;
use terrain_app::ooc::OocConfig;

use crate::quality::QualityArgs;

/// The LOD method and its quality.
#[derive(Debug, Clone, Args)]
pub(crate) struct MethodArgs {
    /// LOD method: which patches to draw with which tessellation factors. Default: pvps-c for
    /// a DEM, ooc (the out-of-core paper's) for a baked store; from a store every method
    /// `terrain render <store> --method` takes.
    #[arg(long, value_enum)]
    pub method: Option<LodMethod>,
    /// Cells per side of the finest patch (the PVPS paper: a 64 x 64 patch grid).
    #[arg(long, default_value_t = 16)]
    pub leaf_cells: u32,
    #[command(flatten)]
    pub quality: QualityArgs,
}

impl MethodArgs {
    /// The method asked for, or the default for a DEM (`pvps-c`) or a store (`ooc`).
    pub(crate) fn kind(&self, store: bool) -> LodMethod {
        self.method.unwrap_or(if store { LodMethod::OutOfCore } else { LodMethod::PvpsC })
    }

    /// Refuses a leaf size of 0.
    pub(crate) fn check(&self) -> anyhow::Result<()> {
        if self.leaf_cells == 0 {
            bail!("--leaf-cells must be at least 1");
        }
        Ok(())
    }
}

/// The stream cache's budget when `--cache-mib` is not given, MiB.
pub(crate) const CACHE_MIB: u64 = 1024;
/// Full-resolution pages when `--page-capacity` is not given.
pub(crate) const PAGE_CAPACITY: u32 = 1024;
/// The page atlas when `--page-mib` is not given, MiB.
pub(crate) const PAGE_MIB: u64 = 256;

/// A store's streaming options (refused with a DEM file by the commands that take both).
#[derive(Debug, Clone, Args)]
pub(crate) struct StoreArgs {
    /// A store: the screen-error threshold tau of Eq. 7 (out-of-core paper), pixels
    /// [default: the balanced preset's 2 px through ooc's measured p99 per pixel of tau, i.e.
    /// tau 3.33 under the default refinement, Eq. 7 with segments of at most 16 cells; README:
    /// "One quality knob"].
    #[arg(long)]
    pub tau: Option<f64>,
    /// A store: the memory budget of the store's data, MiB (2^20 bytes): the stream cache's
    /// blocks and the index entries the view needs [default: 1024].
    #[arg(long, alias = "cache-mb")]
    pub cache_mib: Option<u64>,
    /// A store: full-resolution pages the renderer holds at most (slots of (2^k + 1)^2 f32
    /// each); blocks beyond them are drawn from coarser slot classes [default: 1024].
    #[arg(long)]
    pub page_capacity: Option<u32>,
    /// A store: MiB of page atlas on the device, shared by the slot classes of every level
    /// (a block drawn at level L takes a (2^L + 1)^2 slot) [default: 256].
    #[arg(long, alias = "page-mb")]
    pub page_mib: Option<u64>,
}

impl StoreArgs {
    /// The options given, by name (for the refusals of options a mode would ignore).
    pub(crate) fn given(&self) -> [(&'static str, bool); 4] {
        [
            ("--tau", self.tau.is_some()),
            ("--cache-mib", self.cache_mib.is_some()),
            ("--page-capacity", self.page_capacity.is_some()),
            ("--page-mib", self.page_mib.is_some()),
        ]
    }

    /// The cache budget, MiB.
    pub(crate) fn cache_mib(&self) -> u64 {
        self.cache_mib.unwrap_or(CACHE_MIB)
    }

    /// The stream configuration with threshold `tau` (the quality options' mapping or
    /// `--tau`), checked.
    pub(crate) fn config(&self, tau: f64) -> anyhow::Result<OocConfig> {
        if !(tau.is_finite() && tau > 0.0) {
            bail!("--tau must be a positive number of pixels, got {tau}");
        }
        let page_capacity = self.page_capacity.unwrap_or(PAGE_CAPACITY);
        if page_capacity == 0 {
            bail!("--page-capacity must be at least 1");
        }
        Ok(OocConfig {
            tau,
            budget_bytes: self.cache_mib() << 20,
            page_capacity,
            page_budget_bytes: self.page_mib.unwrap_or(PAGE_MIB) << 20,
            ..OocConfig::default()
        })
    }
}

/// Where the camera is and how wide it sees.
#[derive(Debug, Clone, Args)]
pub(crate) struct CameraArgs {
    /// Camera as x,y,z,yaw,pitch: position in the DEM's world coordinates (metres; the CRS's
    /// coordinates for projected DEMs), compass yaw in degrees (0 north, 90 east), pitch in
    /// degrees (negative looks down). Default: a view that fills the image with the terrain,
    /// looking across its longer side.
    /// Also `lonlat:LON,LAT,Z,yaw,pitch` (WGS84 degrees, converted to the DEM's CRS), and Z as
    /// metres above the ground with an `agl` suffix (`300agl`). An eye under the ground is
    /// lifted above it (with a warning); a camera that sees no terrain is a warning.
    #[arg(long, allow_hyphen_values = true)]
    pub camera: Option<String>,
    /// Aim the camera at X,Y[,Z] or lonlat:LON,LAT[,Z] (Z default: the ground there; `agl`
    /// suffix as in --camera) instead of giving yaw and pitch: --camera is then X,Y,Z.
    #[arg(long, allow_hyphen_values = true, requires = "camera")]
    pub look_at: Option<String>,
    /// Vertical field of view, degrees.
    #[arg(long, default_value_t = 60.0)]
    pub fov: f64,
}

impl CameraArgs {
    /// The camera as given (`None`: the default framing), parsed.
    pub(crate) fn spec(&self) -> anyhow::Result<Option<terrain_app::camera::CameraSpec>> {
        if !(self.fov.is_finite() && self.fov > 0.0 && self.fov < 180.0) {
            bail!("--fov must be between 0 and 180 degrees, got {}", self.fov);
        }
        self.camera
            .as_deref()
            .map(|c| terrain_app::camera::parse(c, self.look_at.as_deref()))
            .transpose()
    }
}
