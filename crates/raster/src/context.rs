//! One wgpu instance/adapter/device/queue per process, with cached compute pipelines.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

use thiserror::Error;

use crate::kernels::Kernel;

#[derive(Debug, Error)]
pub enum GpuError {
    #[error(
        "no Vulkan adapter found ({0}); install the software driver with \
         `apt-get install -y mesa-vulkan-drivers libvulkan1` or a GPU driver"
    )]
    NoAdapter(String),
    #[error("EVSPLAT_ADAPTER={0:?} is not one of auto, cpu, gpu")]
    BadAdapterChoice(String),
    #[error("could not open the GPU device on {adapter}: {reason}")]
    Device { adapter: String, reason: String },
    #[error("GPU readback failed: {0}")]
    Readback(String),
    #[error("{0}")]
    Invalid(String),
    /// A buffer would exceed the storage-binding limit (`GpuContext::binding_limit`).
    #[error("{0}")]
    OverLimit(String),
}

/// Which kind of adapter to use, from `EVSPLAT_ADAPTER`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AdapterChoice {
    /// Prefer a real GPU, fall back to a CPU (lavapipe) adapter.
    Auto,
    /// Only a CPU adapter (lavapipe / fallback).
    Cpu,
    /// Only a real GPU.
    Gpu,
}

impl AdapterChoice {
    pub fn from_env() -> Result<Self, GpuError> {
        match std::env::var("EVSPLAT_ADAPTER") {
            Err(_) => Ok(Self::Auto),
            Ok(v) => match v.trim().to_ascii_lowercase().as_str() {
                "" | "auto" => Ok(Self::Auto),
                "cpu" | "lavapipe" => Ok(Self::Cpu),
                "gpu" => Ok(Self::Gpu),
                _ => Err(GpuError::BadAdapterChoice(v)),
            },
        }
    }
}

/// How float gradients are accumulated in shaders.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AtomicMode {
    /// Native `atomicAdd` on `atomic<f32>` (SHADER_FLOAT32_ATOMIC).
    Float,
    /// Compare-and-swap loop on `atomic<u32>` bit patterns; works everywhere.
    Cas,
}

pub struct GpuContext {
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pub limits: wgpu::Limits,
    /// The adapter offers (and the device enabled) float32 atomic add on storage buffers.
    pub float_atomics: bool,
    /// The adapter offers (and the device enabled) subgroup operations in compute shaders.
    pub subgroups: bool,
    /// By kernel and channel count (0 for kernels without per-channel loops).
    pipelines: Mutex<HashMap<(Kernel, u32), Arc<wgpu::ComputePipeline>>>,
}

static GLOBAL: OnceLock<Result<GpuContext, String>> = OnceLock::new();

fn is_cpu(info: &wgpu::AdapterInfo) -> bool {
    info.device_type == wgpu::DeviceType::Cpu
}

impl GpuContext {
    /// The process-wide context, created on first use and printed once to stderr.
    pub fn global() -> Result<&'static GpuContext, GpuError> {
        GLOBAL
            .get_or_init(|| {
                let ctx = GpuContext::new(AdapterChoice::from_env().map_err(|e| e.to_string())?)
                    .map_err(|e| e.to_string())?;
                if std::env::var_os("EVSPLAT_QUIET").is_none() {
                    eprintln!(
                        "evsplat: using adapter \"{}\" ({:?}, {:?}, float32 atomics: {}, \
                         subgroups: {})",
                        ctx.info.name,
                        ctx.info.device_type,
                        ctx.info.backend,
                        ctx.float_atomics,
                        ctx.subgroups
                    );
                }
                Ok(ctx)
            })
            .as_ref()
            .map_err(|e| GpuError::Invalid(e.clone()))
    }

    pub fn new(choice: AdapterChoice) -> Result<Self, GpuError> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends: wgpu::Backends::VULKAN,
            ..wgpu::InstanceDescriptor::new_without_display_handle_from_env()
        });
        let adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::VULKAN));
        let seen: Vec<String> = adapters.iter().map(|a| a.get_info().name).collect();
        let pick = |want_cpu: bool| {
            adapters
                .iter()
                .find(|a| is_cpu(&a.get_info()) == want_cpu)
                .cloned()
        };
        let adapter = match choice {
            AdapterChoice::Cpu => pick(true),
            AdapterChoice::Gpu => pick(false),
            AdapterChoice::Auto => pick(false).or_else(|| pick(true)),
        }
        .ok_or_else(|| {
            GpuError::NoAdapter(if seen.is_empty() {
                "none visible".to_string()
            } else {
                format!("EVSPLAT_ADAPTER={choice:?} but only {seen:?}")
            })
        })?;
        let info = adapter.get_info();
        // Every optional feature some kernel uses, where the adapter has it.
        let wanted = (Kernel::ALL.iter().flat_map(|k| k.features()))
            .fold(wgpu::Features::empty(), |all, f| all | *f);
        let features = adapter.features() & wanted;
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("evsplat"),
            required_features: features,
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| GpuError::Device {
            adapter: info.name.clone(),
            reason: e.to_string(),
        })?;
        Ok(Self {
            adapter,
            device,
            queue,
            info,
            limits,
            float_atomics: features.contains(wgpu::Features::SHADER_FLOAT32_ATOMIC),
            subgroups: features.contains(wgpu::Features::SUBGROUP),
            pipelines: Mutex::new(HashMap::new()),
        })
    }

    /// The atomic mode shaders should use: float atomics when present unless
    /// `EVSPLAT_ATOMICS=cas` forces the compare-and-swap path.
    pub fn default_atomic_mode(&self) -> AtomicMode {
        let forced_cas = std::env::var("EVSPLAT_ATOMICS")
            .map(|v| v.eq_ignore_ascii_case("cas"))
            .unwrap_or(false);
        if self.float_atomics && !forced_cas {
            AtomicMode::Float
        } else {
            AtomicMode::Cas
        }
    }

    /// Whether the backward pass sums gradients across subgroups before its atomics: where the
    /// device has subgroup operations, unless `EVSPLAT_SUBGROUPS=off` forces one atomic per
    /// invocation.
    pub fn subgroup_reduce(&self) -> bool {
        let off = std::env::var("EVSPLAT_SUBGROUPS")
            .map(|v| v.eq_ignore_ascii_case("off"))
            .unwrap_or(false);
        self.subgroups && !off
    }

    /// The storage-binding size the rasterizer plans with: the device's limit, or less where
    /// `EVSPLAT_MAX_BINDING` (bytes) says so (tests force the chunking of large renders with it).
    pub fn binding_limit(&self) -> u64 {
        let device = self.limits.max_storage_buffer_binding_size;
        (std::env::var("EVSPLAT_MAX_BINDING").ok())
            .and_then(|v| v.trim().parse::<u64>().ok())
            .map_or(device, |forced| forced.min(device))
    }

    /// Whether the device enabled every optional feature `kernel` uses.
    pub fn runs(&self, kernel: Kernel) -> bool {
        let enabled = self.device.features();
        kernel.features().iter().all(|f| enabled.contains(*f))
    }

    /// The compute pipeline of `kernel` for `d` feature channels (ignored by kernels without
    /// per-channel loops), built once and cached.
    pub fn pipeline(&self, kernel: Kernel, d: u32) -> Arc<wgpu::ComputePipeline> {
        let d = if kernel.per_channel() { d } else { 0 };
        let mut cache = self.pipelines.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(p) = cache.get(&(kernel, d)) {
            return p.clone();
        }
        let label = format!("{kernel:?} d={d}");
        let module = self
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(&label),
                source: wgpu::ShaderSource::Wgsl(kernel.source(d)),
            });
        let pipeline = Arc::new(self.device.create_compute_pipeline(
            &wgpu::ComputePipelineDescriptor {
                label: Some(&label),
                layout: None,
                module: &module,
                entry_point: Some(kernel.entry()),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants: kernel.constants(),
                    ..Default::default()
                },
                cache: None,
            },
        ));
        cache.insert((kernel, d), pipeline.clone());
        pipeline
    }

    /// A bind group for group 0 of `pipeline` with `buffers` bound at 0, 1, 2, ...
    pub fn bind_buffers(
        &self,
        pipeline: &wgpu::ComputePipeline,
        buffers: &[&wgpu::Buffer],
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: b.as_entire_binding(),
            })
            .collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        })
    }

    /// A storage buffer of at least `bytes` (never zero-sized), usable as copy source and target.
    pub fn storage_buffer(&self, label: &str, bytes: u64) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes.max(16).next_multiple_of(4),
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// Block until the queue is idle.
    pub fn wait(&self) -> Result<(), GpuError> {
        self.wait_for(None)
    }

    /// Block until `submission` (None: every submission so far) has completed.
    pub fn wait_for(&self, submission: Option<wgpu::SubmissionIndex>) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::Wait {
                submission_index: submission,
                timeout: None,
            })
            .map(|_| ())
            .map_err(|e| GpuError::Readback(e.to_string()))
    }

    /// Copy `bytes` bytes from the start of `src` back to the host (one staging copy).
    pub fn read_buffer(&self, src: &wgpu::Buffer, bytes: u64) -> Result<Vec<u8>, GpuError> {
        if bytes == 0 {
            return Ok(Vec::new());
        }
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: bytes.next_multiple_of(4),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = self.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(src, 0, &staging, 0, bytes.next_multiple_of(4));
        self.queue.submit([enc.finish()]);
        self.map_read(&staging, bytes, <[u8]>::to_vec)
    }

    /// Map an already-filled MAP_READ buffer and hand its first `bytes` bytes to `read` (which
    /// copies what it needs out of the mapping: nothing else does).
    pub fn map_read<T>(
        &self,
        staging: &wgpu::Buffer,
        bytes: u64,
        read: impl FnOnce(&[u8]) -> T,
    ) -> Result<T, GpuError> {
        self.map_read_after(staging, bytes, None, read)
    }

    /// `map_read` once `submission` (the one that fills `staging`; None: every submission so
    /// far) has completed: later submissions may still be running.
    pub fn map_read_after<T>(
        &self,
        staging: &wgpu::Buffer,
        bytes: u64,
        submission: Option<wgpu::SubmissionIndex>,
        read: impl FnOnce(&[u8]) -> T,
    ) -> Result<T, GpuError> {
        let slice = staging.slice(..bytes.next_multiple_of(4));
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        crate::host::time("wait", || self.wait_for(submission))?;
        rx.recv()
            .map_err(|e| GpuError::Readback(e.to_string()))?
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        let out = crate::host::time("copy out of staging", || {
            let view = slice
                .get_mapped_range()
                .map_err(|e| GpuError::Readback(e.to_string()))?;
            Ok::<_, GpuError>(read(&view[..bytes as usize]))
        })?;
        staging.unmap();
        Ok(out)
    }
}

/// Workgroup counts for `groups` workgroups, folded into 2-D when over the 65535 per-dimension limit.
pub fn dispatch_dims(groups: u32) -> (u32, u32) {
    const MAX: u32 = 65535;
    if groups <= MAX {
        (groups.max(1), 1)
    } else {
        (MAX, groups.div_ceil(MAX))
    }
}
