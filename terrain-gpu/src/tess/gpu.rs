//! The compute-shader tessellator (`tessellate.wgsl`): buffers, pipelines, dispatch and
//! read-back. The design (count, scan, emit; one indexed indirect draw) is explained in
//! [`super`].

use std::mem::size_of;

use bytemuck::{Pod, Zeroable};

use super::{PatchFactors, QuadLayout};
use crate::device::{GpuContext, GpuError};

/// Factors of one patch as the shader reads them (`Factors` in WGSL).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuPatchFactors {
    /// Outer factors, [`PatchFactors::outer`]'s order.
    pub outer: [f32; 4],
    /// Inner factors `[u, v]`.
    pub inner: [f32; 2],
    /// Padding to 16-byte alignment.
    pub pad: [f32; 2],
}

impl From<&PatchFactors> for GpuPatchFactors {
    fn from(f: &PatchFactors) -> Self {
        Self { outer: f.outer, inner: f.inner, pad: [0.0; 2] }
    }
}

/// Where a patch's output lies in the point and index buffers.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct PatchRange {
    /// First point.
    pub point_offset: u32,
    /// Number of points.
    pub point_count: u32,
    /// First index.
    pub index_offset: u32,
    /// Number of indices (three per triangle). Indices are global point indices.
    pub index_count: u32,
}

/// One emitted point: domain position and the patch it belongs to (for vertex pulling).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuDomainPoint {
    /// `(u, v)` in `[0, 1]^2`.
    pub uv: [f32; 2],
    /// Index of the patch in the input.
    pub patch_index: u32,
    /// Padding.
    pub pad: u32,
}

/// `draw_indexed_indirect` arguments, as wgpu reads them.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct DrawIndexedArgs {
    /// Indices to draw.
    pub index_count: u32,
    /// Instances (1).
    pub instance_count: u32,
    /// First index (0).
    pub first_index: u32,
    /// Added to every index (0).
    pub base_vertex: i32,
    /// First instance (0).
    pub first_instance: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct Params {
    patch_count: u32,
    point_capacity: u32,
    index_capacity: u32,
    pad: u32,
}

const _: () = {
    assert!(size_of::<GpuPatchFactors>() == 32);
    assert!(size_of::<PatchRange>() == 16);
    assert!(size_of::<GpuDomainPoint>() == 16);
    assert!(size_of::<DrawIndexedArgs>() == 20);
    assert!(size_of::<Params>() == 16);
};

/// The shader source.
pub const SHADER: &str = include_str!("tessellate.wgsl");

/// Workgroup size of the `count` and `emit` entry points.
const WORKGROUP: u32 = 64;

/// Pipelines of the three passes and their shared bind group layout.
#[derive(Debug)]
pub struct GpuTessellator {
    layout: wgpu::BindGroupLayout,
    count: wgpu::ComputePipeline,
    scan: wgpu::ComputePipeline,
    emit: wgpu::ComputePipeline,
}

/// Buffers holding one tessellation on the device.
#[derive(Debug)]
pub struct GpuTessOutput {
    /// [`GpuDomainPoint`]s (`STORAGE | VERTEX | COPY_SRC`).
    pub points: wgpu::Buffer,
    /// `u32` triangle-list indices into `points` (`STORAGE | INDEX | COPY_SRC`).
    pub indices: wgpu::Buffer,
    /// One [`PatchRange`] per patch.
    pub ranges: wgpu::Buffer,
    /// [`DrawIndexedArgs`] for `draw_indexed_indirect` (`STORAGE | INDIRECT | COPY_SRC`).
    pub draw_args: wgpu::Buffer,
    /// Patches.
    pub patch_count: u32,
    /// Room for points.
    pub point_capacity: u32,
    /// Room for indices.
    pub index_capacity: u32,
    bind_group: wgpu::BindGroup,
}

/// A tessellation read back to the host.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TessReadBack {
    /// Points, `point_capacity` of them.
    pub points: Vec<GpuDomainPoint>,
    /// Indices, `index_capacity` of them.
    pub indices: Vec<u32>,
    /// One range per patch.
    pub ranges: Vec<PatchRange>,
    /// The indirect draw arguments.
    pub draw_args: DrawIndexedArgs,
}

fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

impl GpuTessellator {
    /// Compiles the shader and builds the pipelines.
    pub fn new(device: &wgpu::Device) -> Self {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("tessellate.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let uniform = wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("tessellate"),
            entries: &[
                uniform,
                storage_entry(1, true),
                storage_entry(2, false),
                storage_entry(3, false),
                storage_entry(4, false),
                storage_entry(5, false),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("tessellate"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = |entry: &str| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        Self { count: pipeline("count"), scan: pipeline("scan"), emit: pipeline("emit"), layout }
    }

    /// Allocates output buffers sized exactly for `factors` (the CPU computes the counts in
    /// closed form) and uploads the factors; nothing runs until [`GpuTessellator::encode`].
    pub fn prepare(
        &self,
        ctx: &GpuContext,
        factors: &[PatchFactors],
    ) -> Result<GpuTessOutput, GpuError> {
        self.prepare_on(&ctx.device, &ctx.queue, factors)
    }

    /// [`GpuTessellator::prepare`] for holders of a device and queue.
    pub fn prepare_on(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        factors: &[PatchFactors],
    ) -> Result<GpuTessOutput, GpuError> {
        let (mut points, mut indices) = (0u64, 0u64);
        for f in factors {
            let l = QuadLayout::new(f);
            points += u64::from(l.point_count());
            indices += 3 * u64::from(l.triangle_count());
        }
        let limit = device.limits().max_storage_buffer_binding_size;
        let check = |what, count: u64, stride: usize| {
            let requested = count.max(1) * stride as u64;
            if requested > limit {
                Err(GpuError::LimitExceeded { what, requested, maximum: limit })
            } else {
                Ok(requested)
            }
        };
        let points_size = check("tessellated points", points, size_of::<GpuDomainPoint>())?;
        let indices_size = check("tessellated indices", indices, size_of::<u32>())?;
        let n = factors.len() as u64;
        let factors_size = check("patch factors", n, size_of::<GpuPatchFactors>())?;
        let ranges_size = check("patch ranges", n, size_of::<PatchRange>())?;

        let buffer = |label, size, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        use wgpu::BufferUsages as U;
        let points_buf = buffer("tess points", points_size, U::STORAGE | U::VERTEX | U::COPY_SRC);
        let indices_buf = buffer("tess indices", indices_size, U::STORAGE | U::INDEX | U::COPY_SRC);
        let ranges_buf = buffer("tess ranges", ranges_size, U::STORAGE | U::COPY_SRC);
        let draw_buf = buffer(
            "tess draw args",
            size_of::<DrawIndexedArgs>() as u64,
            U::STORAGE | U::INDIRECT | U::COPY_SRC,
        );
        let factors_buf = buffer("tess factors", factors_size, U::STORAGE | U::COPY_DST);
        let gpu_factors: Vec<GpuPatchFactors> = factors.iter().map(Into::into).collect();
        queue.write_buffer(&factors_buf, 0, bytemuck::cast_slice(&gpu_factors));
        let params = Params {
            patch_count: factors.len() as u32,
            point_capacity: points as u32,
            index_capacity: indices as u32,
            pad: 0,
        };
        let params_buf =
            buffer("tess params", size_of::<Params>() as u64, U::UNIFORM | U::COPY_DST);
        queue.write_buffer(&params_buf, 0, bytemuck::bytes_of(&params));
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("tessellate"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: params_buf.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: factors_buf.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 2, resource: ranges_buf.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 3, resource: points_buf.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 4, resource: indices_buf.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 5, resource: draw_buf.as_entire_binding() },
            ],
        });
        Ok(GpuTessOutput {
            points: points_buf,
            indices: indices_buf,
            ranges: ranges_buf,
            draw_args: draw_buf,
            patch_count: params.patch_count,
            point_capacity: params.point_capacity,
            index_capacity: params.index_capacity,
            bind_group,
        })
    }

    /// Records the three passes into `encoder`.
    pub fn encode(&self, encoder: &mut wgpu::CommandEncoder, out: &GpuTessOutput) {
        self.encode_timed(encoder, out, None);
    }

    /// Like [`GpuTessellator::encode`], writing timestamps at the pass's start and end.
    pub fn encode_timed(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        out: &GpuTessOutput,
        timestamp_writes: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let groups = out.patch_count.div_ceil(WORKGROUP);
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("tessellate"),
            timestamp_writes,
        });
        pass.set_bind_group(0, &out.bind_group, &[]);
        if groups > 0 {
            pass.set_pipeline(&self.count);
            pass.dispatch_workgroups(groups, 1, 1);
        }
        // The scan runs even for no patches: it writes the draw arguments.
        pass.set_pipeline(&self.scan);
        pass.dispatch_workgroups(1, 1, 1);
        if groups > 0 {
            pass.set_pipeline(&self.emit);
            pass.dispatch_workgroups(groups, 1, 1);
        }
    }

    /// Prepares, encodes and submits: the tessellation of `factors` on the device.
    pub fn tessellate(
        &self,
        ctx: &GpuContext,
        factors: &[PatchFactors],
    ) -> Result<GpuTessOutput, GpuError> {
        let out = self.prepare(ctx, factors)?;
        let mut encoder = ctx.device.create_command_encoder(&Default::default());
        self.encode(&mut encoder, &out);
        ctx.queue.submit([encoder.finish()]);
        Ok(out)
    }
}

impl GpuTessOutput {
    /// Reads every buffer back (waits for the device).
    pub fn read_back(&self, ctx: &GpuContext) -> Result<TessReadBack, GpuError> {
        let read = |buf: &wgpu::Buffer, count: u32, stride: usize| {
            ctx.read_buffer(buf, u64::from(count) * stride as u64)
        };
        let points = read(&self.points, self.point_capacity, size_of::<GpuDomainPoint>())?;
        let indices = read(&self.indices, self.index_capacity, 4)?;
        let ranges = read(&self.ranges, self.patch_count, size_of::<PatchRange>())?;
        let draw = read(&self.draw_args, 1, size_of::<DrawIndexedArgs>())?;
        Ok(TessReadBack {
            points: bytemuck::pod_collect_to_vec(&points),
            indices: bytemuck::pod_collect_to_vec(&indices),
            ranges: bytemuck::pod_collect_to_vec(&ranges),
            draw_args: bytemuck::pod_read_unaligned(&draw),
        })
    }
}
