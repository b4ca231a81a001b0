//! The `terrain` command line: composes the engine's crates into user-facing commands.

mod bake;
mod bench_cli;
mod demo;
mod entropy;
mod fly;
mod info;
mod mesh;
mod pvs;
mod render;
mod roughness;
mod source;

use clap::{Parser, Subcommand};

/// Large-scale terrain: real DEMs in, measured level of detail out.
#[derive(Debug, Parser)]
#[command(name = "terrain", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Describe a DEM (or the embedded synthetic terrain when no file is given): size, sample
    /// type, georeference, spacing in metres, height range and voids.
    Info(info::InfoArgs),
    /// Export the local curvature entropy map (entropy paper, Eq. 1-3) and the profile
    /// curvature map as PNG images; `--compare` prints curvature against entropy (Fig. 3).
    Entropy(entropy::EntropyArgs),
    /// Export the roughness pyramids of the PVPS paper's methods A, B and C as PNG images.
    Roughness(roughness::RoughnessArgs),
    /// Bake a DEM (or `--synthetic SIZE`) into an out-of-core block store.
    Bake(bake::BakeArgs),
    /// Draw a DEM (or the embedded synthetic terrain) with the GPU tessellator into a PNG.
    Render(render::RenderArgs),
    /// A triangle mesh within --max-error metres of every sample (RTIN or greedy Delaunay),
    /// verified, then written as .glb, .gltf or .obj.
    Mesh(mesh::MeshArgs),
    /// Fly a camera flight: numbered PNG frames plus per-frame stats as CSV and JSON.
    Fly(fly::FlyArgs),
    /// Export a view cell's potential visible patch set (PVPS paper) as a PNG, from a scene's
    /// PVS file or baked from a DEM.
    Pvs(pvs::PvsCmdArgs),
    /// Benchmark every LOD method over flights: JSON, Markdown and SVG speed-against-error.
    Bench(bench_cli::BenchArgs),
    /// The embedded terrain end to end: a flight, its frames, a benchmark report and plot.
    Demo(demo::DemoArgs),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Info(args) => info::run(&args),
        Command::Entropy(args) => entropy::run(&args),
        Command::Roughness(args) => roughness::run(&args),
        Command::Bake(args) => bake::run(&args),
        Command::Render(args) => render::run(&args),
        Command::Mesh(args) => mesh::run(&args),
        Command::Fly(args) => fly::run(&args),
        Command::Bench(args) => bench_cli::run(&args),
        Command::Pvs(args) => pvs::run(&args),
        Command::Demo(args) => demo::run(&args),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
