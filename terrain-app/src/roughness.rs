//! `terrain roughness`: export the roughness pyramids of the PVPS paper's methods as PNGs, one
//! image per quadtree level, north up (the paper's Figure 8 and Figure 10 images).

use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, ValueEnum};
use terrain_visibility::roughness::{
    NodePyramid, RoughnessConfig, d2_pyramid, level_to_grey, range_pyramid, roughness_pyramid,
};

use crate::source::SourceArgs;

/// Arguments of `terrain roughness`.
#[derive(Debug, Args)]
pub(crate) struct RoughnessArgs {
    #[command(flatten)]
    pub source: SourceArgs,
    /// Which roughness: c = the PVPS paper's Eq. 5 (normalised 0-255), b = Dong's height range,
    /// a = Röttger's d2 (our stand-in for Zhai 2016).
    #[arg(long, value_enum, default_value_t = Method::C)]
    pub method: Method,
    /// Pyramid levels; 7 gives the paper's 64 x 64 patch grid at the finest level.
    #[arg(long, default_value_t = 7)]
    pub levels: usize,
    /// Output folder; receives `<method>_level<N>.png` for every level.
    #[arg(short, long)]
    pub output: PathBuf,
}

/// The roughness measure to export.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub(crate) enum Method {
    /// PVPS method A (Zhai): Röttger's d2.
    A,
    /// PVPS method B (Dong): max - min height, metres.
    B,
    /// PVPS method C (Zhang 2021): Eq. 5 roughness normalised to 0-255.
    C,
}

/// Runs `terrain roughness`.
pub(crate) fn run(args: &RoughnessArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        (1..=12).contains(&args.levels),
        "--levels must be 1..=12, got {}",
        args.levels
    );
    let hm = match args.source.load()? {
        Some(dem) => dem.heightmap,
        None => terrain_core::synth::default_terrain(),
    };
    let (name, pyramid): (&str, NodePyramid) = match args.method {
        Method::A => ("a", d2_pyramid(&hm, args.levels)),
        Method::B => ("b", range_pyramid(&hm, args.levels)),
        Method::C => ("c", roughness_pyramid(&hm, args.levels, &RoughnessConfig::default())),
    };
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("could not create {}", args.output.display()))?;
    // Methods A and B are not on a 0-255 scale: stretch each pyramid by its largest value.
    let scale = match args.method {
        Method::C => 1.0,
        _ => {
            let max = (0..pyramid.levels())
                .flat_map(|l| pyramid.level(l).iter().copied())
                .fold(0.0f32, f32::max);
            if max > 0.0 { 255.0 / max } else { 1.0 }
        }
    };
    for level in 0..pyramid.levels() {
        let (side, px) = level_to_grey(&pyramid, level, scale);
        let path = args.output.join(format!("{name}_level{level}.png"));
        let img = image::GrayImage::from_raw(side as u32, side as u32, px)
            .context("pyramid level size")?;
        img.save(&path).with_context(|| format!("could not write {}", path.display()))?;
    }
    println!(
        "wrote {} levels of method {name} roughness ({} x {} at the finest, root covers {} cells) to {}",
        pyramid.levels(),
        pyramid.side(pyramid.levels() - 1),
        pyramid.side(pyramid.levels() - 1),
        pyramid.root_cells(),
        args.output.display()
    );
    Ok(())
}
