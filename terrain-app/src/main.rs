//! The `terrain` command line: composes the engine's crates into user-facing commands.

mod bake;
mod bench_cli;
mod calibrate;
mod demo;
mod draw_args;
mod entropy;
mod fly;
mod info;
mod interrupt;
mod mesh;
mod pvs;
mod quality;
mod render;
mod roughness;
mod shard;
mod source;
mod tiles;
mod tin_tiles;
mod view;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

/// Large-scale terrain: real DEMs in, measured level of detail out.
#[derive(Debug, Parser)]
#[command(name = "terrain", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// The disk cache of stores read from a URL (`s3://`, `gs://`, `az://`, `http(s)://`):
    /// block levels fetched are kept here for the next run. Default `$TERRAIN_CACHE_DIR`, else
    /// `$XDG_CACHE_HOME/terrain`, else `~/.cache/terrain`.
    #[arg(long, global = true, value_name = "DIR")]
    cache_dir: Option<std::path::PathBuf>,
    /// The disk cache's size in MiB (least recently used levels evicted first); 0 keeps
    /// nothing. Default 2048.
    #[arg(long, global = true, value_name = "MIB")]
    disk_cache_mib: Option<u64>,
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
    /// Measure the out-of-core method's p99 pixel error against its tau on a baked store and
    /// write the map --error-px uses for it (STORE/ooc-calibration.txt).
    Calibrate(calibrate::CalibrateArgs),
    /// Build the tin method's coarse tiles (STORE/tin_tiles.bin) into a store baked without
    /// them (before they existed, or with `terrain bake --no-tin`), or again with another
    /// --tin-min-cells.
    TinTiles(tin_tiles::TinTilesArgs),
    /// Draw a DEM (or the embedded synthetic terrain) with the GPU tessellator into a PNG.
    Render(render::RenderArgs),
    /// A triangle mesh within --max-error metres of every sample (RTIN or greedy Delaunay),
    /// verified, then written as .glb, .gltf or .obj.
    Mesh(mesh::MeshArgs),
    /// A Cesium quantized-mesh-1.0 tileset (z/x/y.terrain + layer.json): per level an
    /// error-bounded TIN, verified against every DEM sample of each tile.
    Tiles(tiles::TilesArgs),
    /// Fly a camera flight: numbered PNG frames plus per-frame stats as CSV and JSON.
    Fly(fly::FlyArgs),
    /// Export a view cell's potential visible patch set (PVPS paper) as a PNG, from a scene's
    /// PVS file or baked from a DEM.
    Pvs(pvs::PvsCmdArgs),
    /// Benchmark every LOD method over flights: JSON, Markdown and SVG speed-against-error.
    Bench(bench_cli::BenchArgs),
    /// The embedded terrain end to end: a flight, its frames, a benchmark report and plot.
    Demo(demo::DemoArgs),
    /// An interactive window over a DEM or a baked store, drawn by the engine: fly or orbit,
    /// switch methods, one quality slider, live figures; `--script` drives it without a person.
    View(view::ViewArgs),
}

/// The command line with every option that takes a value accepting a negative number without
/// `=` (`--vertical-scale -0.1`, `--tau -1` reaches its own check), the same for every
/// command and option.
fn command() -> clap::Command {
    fn negatives(cmd: clap::Command) -> clap::Command {
        let subs: Vec<String> = cmd.get_subcommands().map(|c| c.get_name().to_string()).collect();
        let mut cmd = cmd.mut_args(|a| {
            if a.get_action().takes_values() { a.allow_negative_numbers(true) } else { a }
        });
        for name in subs {
            cmd = cmd.mut_subcommand(name, negatives);
        }
        cmd
    }
    negatives(Cli::command())
}

fn main() -> std::process::ExitCode {
    let cli = match Cli::from_arg_matches(&command().get_matches()) {
        Ok(cli) => cli,
        Err(e) => e.exit(),
    };
    // The disk cache options apply to stores read from a URL: refused when no argument is one.
    let given: Vec<&str> = [
        ("--cache-dir", cli.cache_dir.is_some()),
        ("--disk-cache-mib", cli.disk_cache_mib.is_some()),
    ]
    .into_iter()
    .filter_map(|(n, g)| g.then_some(n))
    .collect();
    if !given.is_empty() && !std::env::args().any(|a| terrain_stream::is_url(&a)) {
        eprintln!(
            "error: {} apply to a store read from a URL (s3://, gs://, az://, http(s)://), and no argument is one",
            given.join(", ")
        );
        return std::process::ExitCode::FAILURE;
    }
    terrain_app::ooc::set_disk_cache(cli.cache_dir.clone(), cli.disk_cache_mib);
    let result = match cli.command {
        Command::Info(args) => info::run(&args),
        Command::Entropy(args) => entropy::run(&args),
        Command::Roughness(args) => roughness::run(&args),
        Command::Bake(args) => bake::run(&args),
        Command::Calibrate(args) => calibrate::run(&args),
        Command::TinTiles(args) => tin_tiles::run(&args),
        Command::Render(args) => render::run(&args),
        Command::Mesh(args) => mesh::run(&args),
        Command::Tiles(args) => tiles::run(&args),
        Command::Fly(args) => fly::run(&args),
        Command::Bench(args) => bench_cli::run(&args),
        Command::Pvs(args) => pvs::run(&args),
        Command::Demo(args) => demo::run(&args),
        Command::View(args) => view::run(&args),
    };
    // The store kept open for the session goes: a remote store's side tables read by chunks
    // stop their background fill and remove their incomplete part files.
    terrain_app::ooc::close_store();
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) if e.downcast_ref::<interrupt::Interrupted>().is_some() => {
            eprintln!("{e:#}");
            std::process::ExitCode::from(interrupt::EXIT_CODE)
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every option of every command that takes a value takes `-5` without `=`: the parser
    /// never reads it as an unknown option (the command's own checks may still refuse it).
    #[test]
    fn every_value_option_accepts_a_negative_number() {
        command().debug_assert();
        let cmd = command();
        let mut checked = 0;
        for sub in cmd.get_subcommands() {
            for arg in sub.get_arguments() {
                let Some(long) = arg.get_long() else { continue };
                if !arg.get_action().takes_values() {
                    continue;
                }
                let flag = format!("--{long}");
                let r = command().try_get_matches_from(["terrain", sub.get_name(), &flag, "-5"]);
                if let Err(e) = r {
                    assert_ne!(
                        e.kind(),
                        clap::error::ErrorKind::UnknownArgument,
                        "terrain {} {flag} -5: {e}",
                        sub.get_name()
                    );
                    assert!(!e.to_string().contains("unexpected argument '-5'"), "{e}");
                }
                checked += 1;
            }
        }
        assert!(checked > 50, "only {checked} options checked");
    }

    /// Sizes are options in MiB; the old `-mb` spellings still parse.
    #[test]
    fn mib_options_keep_their_old_spellings() {
        for (sub, new, old) in [
            ("render", "cache_mib", "--cache-mb"),
            ("render", "page_mib", "--page-mb"),
            ("bench", "ooc_cache_mib", "--ooc-cache-mb"),
        ] {
            let mut args = vec!["terrain", sub, old, "64", "-o", "x.png"];
            if sub == "bench" {
                args.extend(["--flight", "f.json"]);
            }
            let m = command().try_get_matches_from(args).unwrap();
            let (_, m) = m.subcommand().unwrap();
            assert_eq!(m.get_one::<u64>(new), Some(&64), "{sub} {old}");
        }
    }
}
