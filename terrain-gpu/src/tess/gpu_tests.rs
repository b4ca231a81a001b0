//! GPU tessellation against the CPU reference, on Vulkan (lavapipe here) and GL (llvmpipe),
//! plus the `TERRAIN_GPU_BACKEND` override. Where no adapter exists the tests print why and
//! pass, unless `TERRAIN_REQUIRE_GPU` is set (CI sets it): then they fail.

use super::tests::factor_corpus;
use super::{GpuTessellator, PatchFactors, tessellate};
use crate::device::{BACKEND_ENV, BackendChoice, GpuContext, GpuError, REQUIRE_ENV};
use crate::test_support::context;

fn required() -> bool {
    std::env::var_os(REQUIRE_ENV).is_some()
}

fn gpu_matches_reference(backend: BackendChoice, expected: wgpu::Backend) {
    let Some(ctx) = context(backend) else { return };
    assert_eq!(ctx.adapter_info().backend, expected, "{}", ctx.describe());
    check_known_software_features(&ctx);
    let mut factors = factor_corpus(80);
    // A culled patch in the middle of the batch: it must take no room.
    factors.insert(5, PatchFactors { inner: [4.0, 4.0], outer: [4.0, 0.0, 4.0, 4.0] });
    let tess = GpuTessellator::new(&ctx.device);
    let out = tess.tessellate(&ctx, &factors).unwrap();
    let back = out.read_back(&ctx).unwrap();

    let mut total_indices = 0;
    let mut worst = 0.0f32;
    for (p, f) in factors.iter().enumerate() {
        let cpu = tessellate(f);
        let r = back.ranges[p];
        assert_eq!(r.point_count as usize, cpu.points.len(), "patch {p} {f:?}");
        assert_eq!(r.index_count as usize, cpu.indices.len(), "patch {p} {f:?}");
        for (k, want) in cpu.points.iter().enumerate() {
            let got = back.points[r.point_offset as usize + k];
            assert_eq!(got.patch_index, p as u32);
            for c in 0..2 {
                let d = (got.uv[c] - want[c]).abs();
                worst = worst.max(d);
                assert!(d <= 1e-6, "patch {p} {f:?} point {k}: gpu {:?} cpu {want:?}", got.uv);
            }
        }
        let gpu_indices = &back.indices[r.index_offset as usize..][..cpu.indices.len()];
        for (k, (&g, &c)) in gpu_indices.iter().zip(&cpu.indices).enumerate() {
            assert_eq!(g, r.point_offset + c, "patch {p} {f:?} index {k}");
        }
        total_indices += r.index_count;
    }
    assert_eq!(back.draw_args.index_count, total_indices);
    assert_eq!(back.draw_args.instance_count, 1);
    println!(
        "{} patches, {} points, {} triangles: identical topology, max |gpu - cpu| = {worst:e}",
        factors.len(),
        out.point_capacity,
        total_indices / 3
    );
}

/// The feature flags on Mesa's software drivers are known (shared/notes): check them there.
fn check_known_software_features(ctx: &GpuContext) {
    let info = ctx.adapter_info();
    let f = ctx.features;
    println!("features: {f:?}");
    if !info.name.contains("llvmpipe") {
        return;
    }
    if info.backend == wgpu::Backend::Vulkan {
        assert!(f.timestamp_query && !f.compute_timestamps_trustworthy, "lavapipe: {f:?}");
        assert!(f.float32_filterable && f.multi_draw_indirect_count, "lavapipe: {f:?}");
    } else {
        assert!(f.compute_timestamps_trustworthy == f.timestamp_query, "llvmpipe GL: {f:?}");
        assert!(!f.float32_filterable && !f.multi_draw_indirect_count, "llvmpipe GL: {f:?}");
    }
}

#[test]
fn gpu_tessellation_matches_reference_on_vulkan() {
    gpu_matches_reference(BackendChoice::Vulkan, wgpu::Backend::Vulkan);
}

#[test]
fn gpu_tessellation_matches_reference_on_gl() {
    gpu_matches_reference(BackendChoice::Gl, wgpu::Backend::Gl);
}

/// Set by the parent test in the child process it starts.
const CHILD_ENV: &str = "TERRAIN_GPU_TEST_CHILD";

/// In a child process with `TERRAIN_GPU_BACKEND=vulkan`, asks for GL in the config: the
/// variable must win, and the adapter must really be Vulkan (no silent fallback to GL).
#[test]
fn backend_env_override_child() {
    let config = crate::DeviceConfig { backend: BackendChoice::Gl, require: false };
    let wanted = config.effective_backend().unwrap();
    match std::env::var(BACKEND_ENV) {
        Ok(v) => assert_eq!(Some(wanted), BackendChoice::parse(&v)),
        Err(_) => assert_eq!(wanted, BackendChoice::Gl),
    }
    if std::env::var_os(CHILD_ENV).is_none() {
        return;
    }
    match GpuContext::new(&config) {
        Ok(ctx) => {
            println!("CHILD-BACKEND={:?} ADAPTER={}", ctx.adapter_info().backend, ctx.describe())
        }
        Err(GpuError::NoAdapter { tried }) => println!("CHILD-NO-ADAPTER tried={tried:?}"),
        Err(e) => panic!("{e}"),
    }
}

#[test]
fn backend_env_vulkan_gives_a_vulkan_adapter() {
    let exe = std::env::current_exe().unwrap();
    let output = std::process::Command::new(exe)
        .args(["--exact", "tess::gpu_tests::backend_env_override_child", "--nocapture"])
        .env(BACKEND_ENV, "vulkan")
        .env(CHILD_ENV, "1")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "child failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    if let Some(line) = stdout.lines().find(|l| l.starts_with("CHILD-BACKEND=")) {
        println!("{line}");
        assert!(line.starts_with("CHILD-BACKEND=Vulkan "), "{line}");
    } else {
        let line = stdout.lines().find(|l| l.starts_with("CHILD-NO-ADAPTER"));
        let line = line.unwrap_or_else(|| panic!("child printed no result:\n{stdout}"));
        // No Vulkan adapter: it must say it tried Vulkan only, not fall back to GL.
        assert_eq!(line, "CHILD-NO-ADAPTER tried=[Vulkan]");
        assert!(!required(), "{REQUIRE_ENV} is set but there is no Vulkan adapter");
        println!("SKIPPED: no Vulkan adapter, and none was required");
    }
}

#[test]
fn bad_backend_names_are_rejected() {
    assert_eq!(BackendChoice::parse("Vulkan"), Some(BackendChoice::Vulkan));
    assert_eq!(BackendChoice::parse(" gl "), Some(BackendChoice::Gl));
    assert_eq!(BackendChoice::parse("metal"), None);
}

/// Tessellates a 2 x 2 grid of patches whose shared edges agree on their factors (inner
/// factors all different), draws it with the indirect arguments into an offscreen target and
/// checks that every pixel is covered: the draw arguments, indices and points are usable as
/// they are, and the shared edges leave no gap at any pixel centre.
fn patch_grid_covers_the_viewport(backend: BackendChoice) {
    let Some(ctx) = context(backend) else { return };
    // Edge factors: [u = 0, v = 0, u = 1, v = 1]; cells (0,0), (1,0), (0,1), (1,1).
    // Shared edges at x = 1/2: a (bottom row), b (top row); at y = 1/2: c (left), d (right).
    let (a, b, c, d) = (3.7, 17.25, 63.9, 1.0);
    let factors = [
        PatchFactors { inner: [5.5, 2.0], outer: [9.0, 6.3, a, c] },
        PatchFactors { inner: [64.0, 3.1], outer: [a, 2.0, 40.0, d] },
        PatchFactors { inner: [12.7, 30.2], outer: [4.4, c, b, 7.0] },
        PatchFactors { inner: [2.0, 2.0], outer: [b, d, 11.0, 64.0] },
    ];
    let tess = GpuTessellator::new(&ctx.device);
    let out = tess.tessellate(&ctx, &factors).unwrap();
    let target = crate::OffscreenTarget::new(&ctx.device, 203, 157);
    let module = ctx.device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("draw_test.wgsl"),
        source: wgpu::ShaderSource::Wgsl(include_str!("draw_test.wgsl").into()),
    });
    let attributes = wgpu::vertex_attr_array![0 => Float32x2, 1 => Uint32];
    let pipeline = ctx.device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("draw_test"),
        layout: None,
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some("vs"),
            compilation_options: Default::default(),
            buffers: &[Some(wgpu::VertexBufferLayout {
                array_stride: std::mem::size_of::<super::GpuDomainPoint>() as u64,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &attributes,
            })],
        },
        primitive: wgpu::PrimitiveState::default(),
        depth_stencil: Some(crate::OffscreenTarget::depth_state()),
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some("fs"),
            compilation_options: Default::default(),
            targets: &[Some(crate::target::COLOR_FORMAT.into())],
        }),
        multiview_mask: None,
        cache: None,
    });
    let mut encoder = ctx.device.create_command_encoder(&Default::default());
    {
        let mut pass = target.begin_pass(&mut encoder, wgpu::Color::BLACK);
        pass.set_pipeline(&pipeline);
        pass.set_vertex_buffer(0, out.points.slice(..));
        pass.set_index_buffer(out.indices.slice(..), wgpu::IndexFormat::Uint32);
        pass.draw_indexed_indirect(&out.draw_args, 0);
    }
    ctx.queue.submit([encoder.finish()]);
    let image = target.read_color(&ctx).unwrap();
    let holes: Vec<_> = (0..image.height)
        .flat_map(|y| (0..image.width).map(move |x| (x, y)))
        .filter(|&(x, y)| image.get(x, y) != [255, 0, 0, 255])
        .collect();
    assert!(
        holes.is_empty(),
        "{} uncovered pixels, first {:?}",
        holes.len(),
        &holes[..holes.len().min(10)]
    );
    println!("{} x {} pixels, all covered", image.width, image.height);
}

#[test]
fn patch_grid_covers_the_viewport_on_vulkan() {
    patch_grid_covers_the_viewport(BackendChoice::Vulkan);
}

#[test]
fn patch_grid_covers_the_viewport_on_gl() {
    patch_grid_covers_the_viewport(BackendChoice::Gl);
}
