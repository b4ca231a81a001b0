//! `terrain mesh`: a view-independent triangle mesh with a guaranteed vertical error, verified
//! against every non-void sample, then written as glTF (.glb / .gltf + .bin) or OBJ.
//!
//! Precision: world coordinates are f64 (UTM eastings and northings are large); files get f32
//! offsets from a *local origin*, the mesh's centre rounded to a multiple of 64 m, which f32
//! holds exactly up to 2^30 m. glTF carries that origin as the node translation (so viewers
//! place the mesh) and, with the CRS, in the asset's `extras` as f64; OBJ in a comment.
//! The f32 offsets quantise positions by at most half an f32 ulp of the mesh's half extent
//! (about 4 mm at 80 km); the verification is of the f64 mesh, before quantisation.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use glam::DVec3;
use gltf::json;
use json::validation::Checked::Valid;
use json::validation::USize64;
use serde::Serialize;
use terrain_core::measure::{MeasureConfig, measure_frame};
use terrain_core::mesh::{self, Algorithm, MeshConfig, TriMesh, verify};
use terrain_core::{Crs, Heightmap};

use terrain_app::method::MethodOptions;
use terrain_app::method::registry::ErrorView;
use terrain_app::methods::{LodMethod, MethodConfig, MethodScene};

use crate::source::SourceArgs;

/// Arguments of `terrain mesh`.
#[derive(Debug, Args)]
pub(crate) struct MeshArgs {
    #[command(flatten)]
    pub source: SourceArgs,
    /// Largest vertical error allowed at any sample, metres (>= 0). Required unless --camera.
    #[arg(long, allow_hyphen_values = true, required_unless_present_any = ["camera", "entropy"])]
    pub max_error: Option<f64>,
    /// The entropy paper's quadtree mesh instead (Chen 2018): split tiles while their largest
    /// local curvature entropy exceeds this threshold E0 (percent of log2(min(M, N))), cracks
    /// removed by the three-pass update, tiles triangulated by constrained Delaunay.
    #[arg(long, allow_hyphen_values = true, conflicts_with_all = ["max_error", "camera"])]
    pub entropy: Option<f64>,
    /// With --entropy: the maximum depth D of the quadtree (capped at the grid's depth).
    #[arg(long, default_value_t = 8, requires = "entropy")]
    pub depth: u32,
    /// With --entropy: build from scattered `x y z` points (text or CSV) instead of the DEM.
    #[arg(long, requires = "entropy")]
    pub points: Option<PathBuf>,
    /// With --entropy --points: the height interpolation at new vertices.
    #[arg(long, value_enum, default_value_t = crate::entropy::InterpolationArg::Natural, requires = "points")]
    pub interpolation: crate::entropy::InterpolationArg,
    /// With --entropy: entropy window and classes.
    #[command(flatten)]
    pub window: crate::entropy::WindowArgs,
    /// Export the LOD surface a method draws from this view instead (every form of `terrain
    /// render --camera`: x,y,z,yaw,pitch, lonlat:..., heights as e.g. 300agl): exactly the
    /// drawn triangles, rebuilt with the tessellator's CPU reference; its error is measured
    /// and reported, not bounded.
    #[arg(long, allow_hyphen_values = true)]
    pub camera: Option<String>,
    /// With --camera: aim at X,Y[,Z] or lonlat:LON,LAT[,Z] (as in `terrain render`).
    #[arg(long, allow_hyphen_values = true, requires = "camera")]
    pub look_at: Option<String>,
    /// With --camera: the LOD method whose surface is exported.
    #[arg(long, value_enum, default_value_t = LodMethod::PvpsC, requires = "camera")]
    pub method: LodMethod,
    /// With --camera: the view's size in pixels, WIDTHxHEIGHT (screen-space errors depend on it).
    #[arg(long, default_value = "1280x720", requires = "camera")]
    pub size: String,
    /// With --camera: the method's quality (`terrain render`'s --error-px, --quality,
    /// --method-param).
    #[command(flatten)]
    pub quality: crate::quality::QualityArgs,
    /// Output file: .glb, .gltf (with a .bin beside it) or .obj. Optional with --stats.
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// rtin: fast right-triangulated irregular network; delaunay: greedy insertion, fewest
    /// triangles.
    #[arg(long, value_enum, default_value_t = AlgorithmArg::Delaunay, conflicts_with_all = ["camera", "entropy"])]
    pub algorithm: AlgorithmArg,
    /// Print the measurement (triangles, errors, timings) as JSON.
    #[arg(long)]
    pub stats: bool,
}

/// `--algorithm` values.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub(crate) enum AlgorithmArg {
    /// Right-triangulated irregular network.
    Rtin,
    /// Greedy Delaunay refinement (Garland & Heckbert 1995).
    Delaunay,
}

/// Output formats, from the file extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Format {
    Glb,
    Gltf,
    Obj,
}

fn format_of(path: &Path) -> anyhow::Result<Format> {
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("glb") => Ok(Format::Glb),
        Some("gltf") => Ok(Format::Gltf),
        Some("obj") => Ok(Format::Obj),
        _ => bail!("{}: the output must end in .glb, .gltf or .obj", path.display()),
    }
}

/// What `--stats` prints.
#[derive(Debug, Serialize)]
struct Stats {
    algorithm: &'static str,
    width: usize,
    height: usize,
    /// The bound asked for; `None` for a view's LOD surface (`--camera`), which has none.
    max_error_bound_m: Option<f64>,
    measured_max_error_m: f64,
    rms_error_m: f64,
    vertices: usize,
    triangles: usize,
    build_ms: f64,
    verify_ms: f64,
}

/// Runs `terrain mesh`.
pub(crate) fn run(args: &MeshArgs) -> anyhow::Result<()> {
    let format = match &args.output {
        Some(p) => Some(format_of(p)?),
        None if args.stats => None,
        None => bail!("give an output file with -o (.glb, .gltf or .obj), or --stats"),
    };
    let q = &args.quality;
    if args.camera.is_none()
        && (q.error_px.is_some() || q.quality.is_some() || q.method_param.is_some())
    {
        bail!(
            "--error-px, --quality and --method-param apply with --camera (a view's LOD surface)"
        );
    }
    if let Some(e0) = args.entropy {
        return entropy_mesh(args, e0, format);
    }
    let hm = match args.source.load_surface()? {
        Some(dem) => dem.heightmap,
        None => terrain_core::synth::default_terrain(),
    };
    if let Some(camera) = &args.camera {
        return view_mesh(args, camera, hm, format);
    }
    let bound = args.max_error.expect("clap requires --max-error without --camera");
    if bound.is_nan() || bound < 0.0 {
        bail!("--max-error must be a non-negative number of metres, got {bound}");
    }
    let (algorithm, name) = match args.algorithm {
        AlgorithmArg::Rtin => (Algorithm::Rtin, "rtin"),
        AlgorithmArg::Delaunay => (Algorithm::Delaunay, "delaunay"),
    };
    let t0 = Instant::now();
    let mesh = mesh::build(&hm, &MeshConfig { max_error: bound, algorithm })?;
    let build_ms = t0.elapsed().as_secs_f64() * 1e3;
    let t1 = Instant::now();
    let measured = verify::check(&hm, &mesh, bound)
        .context("refusing to export a mesh that fails its check")?;
    let verify_ms = t1.elapsed().as_secs_f64() * 1e3;
    let stats = Stats {
        algorithm: name,
        width: hm.width(),
        height: hm.height(),
        max_error_bound_m: Some(bound),
        measured_max_error_m: measured.max_error,
        rms_error_m: measured.rms_error,
        vertices: mesh.positions.len(),
        triangles: mesh.triangles.len(),
        build_ms,
        verify_ms,
    };
    let meta = Metadata::new(&hm, &mesh, &stats);
    if let (Some(path), Some(format)) = (&args.output, format) {
        match format {
            Format::Glb | Format::Gltf => write_gltf(path, format, &mesh, &meta)?,
            Format::Obj => write_obj(path, &mesh, &meta)?,
        }
    }
    if args.stats {
        println!("{}", serde_json::to_string(&stats)?);
    } else {
        println!(
            "{name}: {} triangles, {} vertices; max error {:.3} m (bound {bound} m), RMS {:.3} m \
             over {} samples; built in {build_ms:.1} ms{}",
            stats.triangles,
            stats.vertices,
            stats.measured_max_error_m,
            stats.rms_error_m,
            measured.samples,
            args.output
                .as_ref()
                .map(|p| format!(", written to {}", p.display()))
                .unwrap_or_default()
        );
    }
    Ok(())
}

/// `terrain mesh --entropy E0`: the entropy quadtree's watertight mesh, measured against every
/// non-void sample of the DEM (or of the scattered points' raster).
fn entropy_mesh(args: &MeshArgs, e0: f64, format: Option<Format>) -> anyhow::Result<()> {
    let r = crate::entropy::build_mesh(
        &args.source,
        args.points.as_deref(),
        &args.window,
        e0,
        args.depth,
        args.interpolation,
    )?;
    let t1 = Instant::now();
    // Scattered points deeper than the raster (D > 10) put vertices between raster samples:
    // such a mesh is not measured against the raster (reported as 0 samples).
    let measured = match verify::measure(&r.hm, &r.mesh) {
        Ok(m) => m,
        Err(verify::VerifyError::VertexOffGrid { .. }) if args.points.is_some() => {
            verify::ErrorStats { max_error: f64::NAN, rms_error: f64::NAN, samples: 0, worst: None }
        }
        Err(e) => return Err(e).context("measuring the entropy mesh"),
    };
    let verify_ms = t1.elapsed().as_secs_f64() * 1e3;
    let stats = Stats {
        algorithm: "entropy",
        width: r.hm.width(),
        height: r.hm.height(),
        max_error_bound_m: None,
        measured_max_error_m: measured.max_error,
        rms_error_m: measured.rms_error,
        vertices: r.mesh.positions.len(),
        triangles: r.mesh.triangles.len(),
        build_ms: r.build_ms,
        verify_ms,
    };
    let meta = Metadata::new(&r.hm, &r.mesh, &stats);
    if let (Some(path), Some(format)) = (&args.output, format) {
        match format {
            Format::Glb | Format::Gltf => write_gltf(path, format, &r.mesh, &meta)?,
            Format::Obj => write_obj(path, &r.mesh, &meta)?,
        }
    }
    if args.stats {
        let mut v = serde_json::to_value(&stats)?;
        v["tiles"] = r.tiles.into();
        v["crack_elimination_ms"] = r.crack_ms.into();
        v["simplification_percent"] =
            (100.0 * (1.0 - r.mesh.triangles.len() as f64 / r.full_triangles as f64)).into();
        println!("{v}");
    } else {
        println!(
            "entropy E0 = {e0}: {} tiles, {} triangles ({:.2} % fewer than the full depth), {} \
             vertices; max error {:.3} m, RMS {:.3} m over {} samples; built in {:.1} ms, cracks \
             removed in {:.2} ms{}",
            r.tiles,
            stats.triangles,
            100.0 * (1.0 - r.mesh.triangles.len() as f64 / r.full_triangles as f64),
            stats.vertices,
            measured.max_error,
            measured.rms_error,
            measured.samples,
            r.build_ms,
            r.crack_ms,
            args.output
                .as_ref()
                .map(|p| format!(", written to {}", p.display()))
                .unwrap_or_default()
        );
    }
    Ok(())
}

/// `terrain mesh --camera`: the LOD surface `args.method` draws from that view, rebuilt with its
/// renderer's CPU reference (`Method::surface`: the triangles the GPU draws, the entropy
/// method's mesh as built; zero-area ones dropped), its error
/// against the DEM measured over the view (`terrain_core::measure`) and reported.
fn view_mesh(
    args: &MeshArgs,
    camera: &str,
    hm: Heightmap,
    format: Option<Format>,
) -> anyhow::Result<()> {
    let (width, height) = crate::render::parse_size(&args.size)?;
    let spec = terrain_app::camera::parse(camera, args.look_at.as_deref())?;
    let camera = crate::render::place_camera(Some(&spec), &hm, (width, height), 60.0)?;
    let position = camera.position;
    let t0 = Instant::now();
    let mut config = MethodConfig::default();
    let view = ErrorView { height_px: f64::from(height), fov_y_deg: camera.fov_y.to_degrees() };
    args.quality.apply(&mut config, args.method, view, &[])?;
    let scene = MethodScene::new(hm, config);
    // The method's frame and its drawn surface, through the one method interface.
    let mut method = terrain_app::method::build(
        args.method,
        &scene,
        &MethodOptions { morph: true, ..MethodOptions::default() },
    )?;
    let mut frame = method.frame(&camera);
    let surface = method.surface(&mut frame)?.mesh;
    let selection = &frame.selection;
    let build_ms = t0.elapsed().as_secs_f64() * 1e3;
    let t1 = Instant::now();
    let errors = measure_frame(
        &scene.hm,
        &scene.qt,
        &camera,
        selection,
        &surface,
        &MeasureConfig::default(),
    );
    let verify_ms = t1.elapsed().as_secs_f64() * 1e3;
    // Border patches reach past the grid and collapse there: keep triangles with plan area.
    let triangles: Vec<[u32; 3]> = surface
        .triangles
        .iter()
        .copied()
        .filter(|t| {
            let [a, b, c] = t.map(|k| surface.grid[k as usize]);
            (b - a).perp_dot(c - a).abs() > 1e-12
        })
        .collect();
    anyhow::ensure!(
        !triangles.is_empty(),
        "the view at {camera} sees no terrain: nothing to export",
        camera = position
    );
    let normals = mesh::vertex_normals(&surface.positions, &triangles);
    let tri_mesh = TriMesh { positions: surface.positions, normals, triangles };
    let stats = Stats {
        algorithm: args.method.name(),
        width: scene.hm.width(),
        height: scene.hm.height(),
        max_error_bound_m: None,
        measured_max_error_m: errors.max_abs_m,
        rms_error_m: errors.rmse_m,
        vertices: tri_mesh.positions.len(),
        triangles: tri_mesh.triangles.len(),
        build_ms,
        verify_ms,
    };
    let meta = Metadata::new(&scene.hm, &tri_mesh, &stats);
    if let (Some(path), Some(format)) = (&args.output, format) {
        match format {
            Format::Glb | Format::Gltf => write_gltf(path, format, &tri_mesh, &meta)?,
            Format::Obj => write_obj(path, &tri_mesh, &meta)?,
        }
    }
    if args.stats {
        println!("{}", serde_json::to_string(&stats)?);
    } else {
        println!(
            "{} view surface: {} patches, {} triangles, {} vertices; over the {} samples in view: \
             max error {:.3} m, RMS {:.3} m, p99 {:.2} px{}",
            args.method.name(),
            selection.patches.len(),
            stats.triangles,
            stats.vertices,
            errors.samples,
            errors.max_abs_m,
            errors.rmse_m,
            errors.p99_px,
            args.output
                .as_ref()
                .map(|p| format!(", written to {}", p.display()))
                .unwrap_or_default()
        );
    }
    Ok(())
}

/// Where the mesh sits: stored beside the geometry so the f32 offsets can be placed exactly.
#[derive(Debug, Serialize)]
struct Metadata<'a> {
    /// The CRS as text ("EPSG:26915").
    crs: String,
    /// The EPSG code, when known.
    epsg: Option<u32>,
    /// World-frame position (x east, y north, z up, metres, f64) that every position is
    /// relative to.
    origin: [f64; 3],
    /// How world x/y relate to the CRS.
    world_frame: &'static str,
    /// CRS coordinates of the south-west sample, and the spacing in CRS units.
    native_origin: [f64; 2],
    native_spacing: [f64; 2],
    /// The measurement.
    #[serde(flatten)]
    stats: &'a Stats,
}

impl<'a> Metadata<'a> {
    fn new(hm: &Heightmap, mesh: &TriMesh, stats: &'a Stats) -> Self {
        let g = hm.georef();
        Self {
            crs: g.crs.to_string(),
            epsg: match g.crs {
                Crs::Epsg(c) => Some(c),
                _ => None,
            },
            origin: local_origin(mesh).to_array(),
            world_frame: match g.units {
                terrain_core::georef::AngularOrLinear::Metres => "the CRS's projected metres",
                terrain_core::georef::AngularOrLinear::Degrees => {
                    "equirectangular metres at the grid's centre latitude (WGS84 degree lengths)"
                }
            },
            native_origin: g.native_origin.to_array(),
            native_spacing: g.native_spacing.to_array(),
            stats,
        }
    }
}

/// The mesh's bounding-box centre rounded to a multiple of 64 m: exact in f32 and f64.
fn local_origin(mesh: &TriMesh) -> DVec3 {
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for &p in &mesh.positions {
        lo = lo.min(p);
        hi = hi.max(p);
    }
    if mesh.positions.is_empty() {
        return DVec3::ZERO;
    }
    ((lo + hi) * 0.5 / 64.0).round() * 64.0
}

/// World (z up) to glTF (y up, right-handed): (x, y, z) -> (x, z, -y), a rotation, so
/// counter-clockwise-from-above triangles stay front-facing from above.
fn to_gltf(v: DVec3) -> [f64; 3] {
    [v.x, v.z, -v.y]
}

fn write_gltf(
    path: &Path,
    format: Format,
    mesh: &TriMesh,
    meta: &Metadata<'_>,
) -> anyhow::Result<()> {
    let origin = DVec3::from_array(meta.origin);
    // Buffer: positions (f32 vec3), normals (f32 vec3), indices (u32), little-endian.
    let mut bin = Vec::with_capacity(mesh.positions.len() * 24 + mesh.triangles.len() * 12);
    let (mut min, mut max) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for &p in &mesh.positions {
        let q = to_gltf(p - origin).map(|c| c as f32);
        for k in 0..3 {
            min[k] = min[k].min(q[k]);
            max[k] = max[k].max(q[k]);
            bin.extend_from_slice(&q[k].to_le_bytes());
        }
    }
    let positions_len = bin.len();
    for n in &mesh.normals {
        for c in to_gltf(n.as_dvec3()) {
            bin.extend_from_slice(&(c as f32).to_le_bytes());
        }
    }
    let normals_len = bin.len() - positions_len;
    for t in &mesh.triangles {
        for k in t {
            bin.extend_from_slice(&k.to_le_bytes());
        }
    }
    let indices_len = bin.len() - positions_len - normals_len;
    let bin_name = path.with_extension("bin");
    let uri = match format {
        Format::Gltf => Some(
            bin_name
                .file_name()
                .and_then(|n| n.to_str())
                .context("non-UTF-8 file name")?
                .to_owned(),
        ),
        _ => None,
    };
    let extras = Some(serde_json::value::to_raw_value(meta)?);

    let mut root = json::Root::default();
    let buffer = root.push(json::Buffer {
        byte_length: USize64::from(bin.len()),
        extensions: None,
        extras: None,
        name: None,
        uri,
    });
    let view = |root: &mut json::Root, offset: usize, len: usize, target| {
        root.push(json::buffer::View {
            buffer,
            byte_length: USize64::from(len),
            byte_offset: Some(USize64::from(offset)),
            byte_stride: None,
            extensions: None,
            extras: None,
            name: None,
            target: Some(Valid(target)),
        })
    };
    use json::buffer::Target::{ArrayBuffer, ElementArrayBuffer};
    let pos_view = view(&mut root, 0, positions_len, ArrayBuffer);
    let nrm_view = view(&mut root, positions_len, normals_len, ArrayBuffer);
    let idx_view = view(&mut root, positions_len + normals_len, indices_len, ElementArrayBuffer);
    let accessor = |view, count: usize, component, type_, bounds: Option<([f32; 3], [f32; 3])>| {
        json::Accessor {
            buffer_view: Some(view),
            byte_offset: None,
            count: USize64::from(count),
            component_type: Valid(json::accessor::GenericComponentType(component)),
            extensions: None,
            extras: None,
            type_: Valid(type_),
            min: bounds.map(|b| json::Value::from(b.0.to_vec())),
            max: bounds.map(|b| json::Value::from(b.1.to_vec())),
            name: None,
            normalized: false,
            sparse: None,
        }
    };
    use json::accessor::{ComponentType, Type};
    let n = mesh.positions.len();
    let positions =
        root.push(accessor(pos_view, n, ComponentType::F32, Type::Vec3, Some((min, max))));
    let normals = root.push(accessor(nrm_view, n, ComponentType::F32, Type::Vec3, None));
    let indices = root.push(accessor(
        idx_view,
        mesh.triangles.len() * 3,
        ComponentType::U32,
        Type::Scalar,
        None,
    ));
    let primitive = json::mesh::Primitive {
        attributes: [
            (Valid(json::mesh::Semantic::Positions), positions),
            (Valid(json::mesh::Semantic::Normals), normals),
        ]
        .into_iter()
        .collect(),
        extensions: None,
        extras: None,
        indices: Some(indices),
        material: None,
        mode: Valid(json::mesh::Mode::Triangles),
        targets: None,
    };
    let gmesh = root.push(json::Mesh {
        extensions: None,
        extras: None,
        name: Some("terrain".into()),
        primitives: vec![primitive],
        weights: None,
    });
    // The local origin is a multiple of 64 m: exact as f32.
    let translation = to_gltf(origin).map(|c| c as f32);
    let node = root.push(json::Node {
        mesh: Some(gmesh),
        translation: Some(translation),
        name: Some("terrain".into()),
        extras: extras.clone(),
        ..Default::default()
    });
    let scene =
        root.push(json::Scene { extensions: None, extras: None, name: None, nodes: vec![node] });
    root.scene = Some(scene);
    root.asset.generator = Some(format!("terrain mesh {}", env!("CARGO_PKG_VERSION")));
    root.asset.extras = extras;

    let write = |p: &Path, bytes: &[u8]| {
        std::fs::write(p, bytes).with_context(|| format!("could not write {}", p.display()))
    };
    match format {
        Format::Glb => {
            let json = json::serialize::to_vec(&root)?;
            let glb = gltf::binary::Glb {
                header: gltf::binary::Header { magic: *b"glTF", version: 2, length: 0 },
                json: json.into(),
                bin: Some(bin.into()),
            };
            let bytes = glb.to_vec().context("the mesh is too large for a .glb (4 GiB)")?;
            write(path, &bytes)
        }
        _ => {
            write(&bin_name, &bin)?;
            write(path, &json::serialize::to_vec_pretty(&root)?)
        }
    }
}

fn write_obj(path: &Path, mesh: &TriMesh, meta: &Metadata<'_>) -> anyhow::Result<()> {
    let file =
        File::create(path).with_context(|| format!("could not create {}", path.display()))?;
    let mut w = BufWriter::new(file);
    let origin = DVec3::from_array(meta.origin);
    let s = meta.stats;
    writeln!(
        w,
        "# terrain mesh ({}): {} triangles, {} vertices",
        s.algorithm, s.triangles, s.vertices
    )?;
    let bound =
        s.max_error_bound_m.map_or("none (a view's LOD surface)".into(), |b| format!("{b} m"));
    writeln!(
        w,
        "# max error bound {bound}; measured max {} m, RMS {} m",
        s.measured_max_error_m, s.rms_error_m
    )?;
    writeln!(w, "# crs {} ({})", meta.crs, meta.world_frame)?;
    writeln!(w, "# axes: x east, y north, z up, metres; positions are relative to the origin")?;
    writeln!(w, "# origin {:.6} {:.6} {:.6}", origin.x, origin.y, origin.z)?;
    for &p in &mesh.positions {
        let q = p - origin;
        writeln!(w, "v {:.4} {:.4} {:.4}", q.x, q.y, q.z)?;
    }
    for n in &mesh.normals {
        writeln!(w, "vn {:.6} {:.6} {:.6}", n.x, n.y, n.z)?;
    }
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|k| k + 1);
        writeln!(w, "f {a}//{a} {b}//{b} {c}//{c}")?;
    }
    w.flush().with_context(|| format!("could not write {}", path.display()))
}
