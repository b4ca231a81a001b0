//! Device selection: any adapter that exists, Vulkan first, then GL; software adapters
//! (lavapipe, llvmpipe: `DeviceType::Cpu`) are accepted like any other. Also the feature
//! flags the renderer branches on, and buffer read-back.

use std::fmt;

/// Environment variable that overrides [`DeviceConfig::backend`]: `vulkan`, `gl` or `auto`.
pub const BACKEND_ENV: &str = "TERRAIN_GPU_BACKEND";
/// Environment variable that, when set (to anything), makes a missing adapter an error.
pub const REQUIRE_ENV: &str = "TERRAIN_REQUIRE_GPU";

/// Which graphics API to use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BackendChoice {
    /// Vulkan if an adapter exists, else GL.
    #[default]
    Auto,
    /// Vulkan only: never falls back to GL.
    Vulkan,
    /// GL (EGL, GL 4.5 core on llvmpipe) only.
    Gl,
}

impl BackendChoice {
    /// The backends to try, in order.
    pub fn candidates(self) -> &'static [wgpu::Backend] {
        match self {
            Self::Auto => &[wgpu::Backend::Vulkan, wgpu::Backend::Gl],
            Self::Vulkan => &[wgpu::Backend::Vulkan],
            Self::Gl => &[wgpu::Backend::Gl],
        }
    }

    /// Parses `vulkan`, `gl` or `auto` (any case, surrounding blanks ignored).
    pub fn parse(s: &str) -> Option<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" | "" => Some(Self::Auto),
            "vulkan" | "vk" => Some(Self::Vulkan),
            "gl" | "gles" | "opengl" => Some(Self::Gl),
            _ => None,
        }
    }
}

/// How to pick the device. `Default` is `Auto` and not required.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DeviceConfig {
    /// The backend; `TERRAIN_GPU_BACKEND` overrides it.
    pub backend: BackendChoice,
    /// Whether the caller cannot do without a device: [`GpuContext::try_new`] then returns
    /// [`GpuError::NoAdapter`] instead of `Ok(None)`.
    pub require: bool,
}

impl DeviceConfig {
    /// `backend` as given, `require` from `TERRAIN_REQUIRE_GPU` (set: required).
    pub fn from_env(backend: BackendChoice) -> Self {
        Self { backend, require: std::env::var_os(REQUIRE_ENV).is_some() }
    }

    /// The backend after the `TERRAIN_GPU_BACKEND` override.
    pub fn effective_backend(&self) -> Result<BackendChoice, GpuError> {
        match std::env::var(BACKEND_ENV) {
            Ok(value) => BackendChoice::parse(&value).ok_or(GpuError::BadBackendEnv { value }),
            Err(_) => Ok(self.backend),
        }
    }
}

/// Why a device could not be created or used.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GpuError {
    /// No adapter on any backend tried.
    #[error("no GPU adapter found (tried {})", BackendList(tried))]
    NoAdapter {
        /// Backends tried, in order.
        tried: Vec<wgpu::Backend>,
    },
    /// `TERRAIN_GPU_BACKEND` holds something other than `vulkan`, `gl` or `auto`.
    #[error("{BACKEND_ENV}={value:?} is not one of vulkan, gl, auto")]
    BadBackendEnv {
        /// The value found.
        value: String,
    },
    /// The adapter refused to create a device.
    #[error("adapter {adapter:?} could not create a device")]
    RequestDevice {
        /// Adapter name.
        adapter: String,
        /// wgpu's reason.
        #[source]
        source: wgpu::RequestDeviceError,
    },
    /// A buffer would exceed a device limit.
    #[error("{what} needs {requested} bytes, the device allows {maximum}")]
    LimitExceeded {
        /// Which buffer.
        what: &'static str,
        /// Bytes needed.
        requested: u64,
        /// The device's limit.
        maximum: u64,
    },
    /// Mapping a buffer for read-back failed.
    #[error("mapping a buffer for read-back failed")]
    Map(#[from] wgpu::BufferAsyncError),
    /// Waiting for the device failed (device lost or timeout).
    #[error("waiting for the device failed")]
    Poll(#[from] wgpu::PollError),
}

struct BackendList<'a>(&'a [wgpu::Backend]);

impl fmt::Display for BackendList<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (k, b) in self.0.iter().enumerate() {
            write!(f, "{}{b:?}", if k > 0 { ", " } else { "" })?;
        }
        Ok(())
    }
}

/// Optional capabilities the renderer adapts to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GpuFeatures {
    /// Linear filtering of `R32Float` textures; absent on GL: filter by hand in shaders.
    pub float32_filterable: bool,
    /// Timestamp queries.
    pub timestamp_query: bool,
    /// Whether compute-pass timestamps measure the pass: false on lavapipe, whose
    /// compute-pass timestamps are wrong (0.1 ms reported for a 60 ms pass).
    pub compute_timestamps_trustworthy: bool,
    /// `multi_draw_indexed_indirect_count` (not on GL).
    pub multi_draw_indirect_count: bool,
}

/// An adapter, its device and queue, and the features enabled on it.
#[derive(Debug)]
pub struct GpuContext {
    /// Kept alive for the adapter's sake.
    pub instance: wgpu::Instance,
    /// The adapter chosen.
    pub adapter: wgpu::Adapter,
    /// The device, with every feature of [`GpuFeatures`] the adapter has enabled.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// What is available.
    pub features: GpuFeatures,
}

/// Ranks device types: real GPUs first, software last, but every type is acceptable.
fn preference(t: wgpu::DeviceType) -> u8 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    }
}

impl GpuContext {
    /// Creates a device on the first backend (in [`BackendChoice::candidates`] order) that
    /// has an adapter. Fails with [`GpuError::NoAdapter`] when none has.
    pub fn new(config: &DeviceConfig) -> Result<Self, GpuError> {
        Self::on_backend(config.effective_backend()?)
    }

    /// Like [`GpuContext::new`] on `backend`, ignoring `TERRAIN_GPU_BACKEND`: for tests that
    /// must run on one backend whatever the environment says.
    pub fn on_backend(backend: BackendChoice) -> Result<Self, GpuError> {
        let mut tried = Vec::new();
        for &b in backend.candidates() {
            tried.push(b);
            let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
            desc.backends = wgpu::Backends::from(b);
            let instance = wgpu::Instance::new(desc);
            let mut adapters = pollster::block_on(instance.enumerate_adapters(desc_backends(b)));
            adapters.retain(|a| a.get_info().backend == b);
            adapters.sort_by_key(|a| preference(a.get_info().device_type));
            if let Some(adapter) = adapters.into_iter().next() {
                return Self::with_adapter(instance, adapter);
            }
        }
        Err(GpuError::NoAdapter { tried })
    }

    /// Like [`GpuContext::new`], but a missing adapter is `Ok(None)` unless
    /// [`DeviceConfig::require`] is set: for tests that skip where no GPU exists.
    pub fn try_new(config: &DeviceConfig) -> Result<Option<Self>, GpuError> {
        match Self::new(config) {
            Err(GpuError::NoAdapter { .. }) if !config.require => Ok(None),
            other => other.map(Some),
        }
    }

    fn with_adapter(instance: wgpu::Instance, adapter: wgpu::Adapter) -> Result<Self, GpuError> {
        let info = adapter.get_info();
        let available = adapter.features();
        let wanted = wgpu::Features::FLOAT32_FILTERABLE
            | wgpu::Features::TIMESTAMP_QUERY
            | wgpu::Features::MULTI_DRAW_INDIRECT_COUNT;
        let enabled = available & wanted;
        let desc = wgpu::DeviceDescriptor {
            label: Some("terrain-gpu"),
            required_features: enabled,
            required_limits: adapter.limits(),
            ..Default::default()
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&desc))
            .map_err(|source| GpuError::RequestDevice { adapter: info.name.clone(), source })?;
        let lavapipe = info.backend == wgpu::Backend::Vulkan && is_llvmpipe(&info);
        let timestamp_query = enabled.contains(wgpu::Features::TIMESTAMP_QUERY);
        let features = GpuFeatures {
            float32_filterable: enabled.contains(wgpu::Features::FLOAT32_FILTERABLE),
            timestamp_query,
            compute_timestamps_trustworthy: timestamp_query && !lavapipe,
            multi_draw_indirect_count: enabled.contains(wgpu::Features::MULTI_DRAW_INDIRECT_COUNT),
        };
        Ok(Self { instance, adapter, device, queue, features })
    }

    /// The adapter's name, backend, type and driver.
    pub fn adapter_info(&self) -> wgpu::AdapterInfo {
        self.adapter.get_info()
    }

    /// One line naming adapter, backend, device type and driver, for logs and test output.
    pub fn describe(&self) -> String {
        let i = self.adapter_info();
        format!(
            "{} ({:?}, {:?}, driver {} {})",
            i.name, i.backend, i.device_type, i.driver, i.driver_info
        )
    }

    /// Copies `size` bytes from the start of `buffer` (which needs `COPY_SRC`) to the host,
    /// waiting for all submitted work.
    pub fn read_buffer(&self, buffer: &wgpu::Buffer, size: u64) -> Result<Vec<u8>, GpuError> {
        read_buffer(&self.device, &self.queue, buffer, size)
    }
}

/// [`GpuContext::read_buffer`] for holders of a device and queue (wgpu's are cheap clones).
pub fn read_buffer(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    buffer: &wgpu::Buffer,
    size: u64,
) -> Result<Vec<u8>, GpuError> {
    if size == 0 {
        return Ok(Vec::new());
    }
    let padded = size.next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT);
    let staging = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("read-back staging"),
        size: padded,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = device.create_command_encoder(&Default::default());
    encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, padded);
    queue.submit([encoder.finish()]);
    let (tx, rx) = std::sync::mpsc::channel();
    staging.map_async(wgpu::MapMode::Read, .., move |r| {
        // The receiver waits below; a send error means it is gone, nothing to do.
        let _ = tx.send(r);
    });
    device.poll(wgpu::PollType::wait_indefinitely())?;
    rx.recv().unwrap_or(Err(wgpu::BufferAsyncError))?;
    let bytes = staging.get_mapped_range(..).map(|v| v[..size as usize].to_vec());
    staging.unmap();
    bytes.map_err(|_| GpuError::Map(wgpu::BufferAsyncError))
}

fn desc_backends(b: wgpu::Backend) -> wgpu::Backends {
    wgpu::Backends::from(b)
}

/// Mesa's software rasterisers call themselves llvmpipe on both APIs (lavapipe on Vulkan).
fn is_llvmpipe(info: &wgpu::AdapterInfo) -> bool {
    let hay = format!("{} {} {}", info.name, info.driver, info.driver_info).to_ascii_lowercase();
    hay.contains("llvmpipe") || hay.contains("lavapipe")
}

/// A `size[0]` x `size[1]` texture of `format` holding `bytes` (`texel` bytes each).
pub(crate) fn upload_texture(
    ctx: &GpuContext,
    label: &str,
    size: [u32; 2],
    format: wgpu::TextureFormat,
    bytes: &[u8],
    texel: u32,
) -> wgpu::TextureView {
    let extent = wgpu::Extent3d { width: size[0], height: size[1], depth_or_array_layers: 1 };
    let tex = ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: extent,
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    ctx.queue.write_texture(
        tex.as_image_copy(),
        bytes,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(size[0] * texel),
            rows_per_image: Some(size[1]),
        },
        extent,
    );
    tex.create_view(&Default::default())
}
