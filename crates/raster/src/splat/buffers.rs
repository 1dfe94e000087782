//! Persistent GPU buffers of the splatting passes: grown geometrically, never shrunk, with the
//! bind groups rebuilt only after a buffer grew.

use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::Arc;

use crate::context::{GpuContext, GpuError};
use crate::wgsl;

/// A storage buffer that only ever grows (to the next power of two of the request).
pub struct Grow {
    label: &'static str,
    pub buf: wgpu::Buffer,
    cap: u64,
}

impl Grow {
    fn new(ctx: &GpuContext, label: &'static str) -> Self {
        Self {
            label,
            buf: ctx.storage_buffer(label, 16),
            cap: 16,
        }
    }

    /// Make room for `bytes`; true when the buffer was replaced. Errors past the binding limit.
    fn ensure(&mut self, ctx: &GpuContext, bytes: u64) -> Result<bool, GpuError> {
        let max = ctx.binding_limit();
        if bytes > max {
            return Err(GpuError::OverLimit(format!(
                "rasterize: the {} buffer needs {bytes} bytes, over the {max}-byte storage binding \
                 limit; render fewer Gaussians or fewer feature channels per call",
                self.label
            )));
        }
        if bytes <= self.cap {
            return Ok(false);
        }
        let cap = bytes
            .next_power_of_two()
            .min(max.next_multiple_of(4))
            .max(16);
        self.buf = ctx.storage_buffer(self.label, cap);
        self.cap = cap;
        Ok(true)
    }
}

/// The host-visible buffer a call's inputs are written into and copied from into the storage
/// buffers. It stays mapped between calls (mapped again in each call's own wait), so a call
/// writes its inputs straight into it: no packed host copy, and no staging buffer allocated per
/// call as `Queue::write_buffer` does (a fresh host-visible allocation the size of the inputs).
pub struct Upload {
    pub buf: wgpu::Buffer,
    cap: u64,
    /// UNMAPPED, PENDING (asked for, not yet mapped) or MAPPED: wgpu 30 has no map state query.
    state: Arc<AtomicU8>,
}

const UNMAPPED: u8 = 0;
const PENDING: u8 = 1;
const MAPPED: u8 = 2;

impl Upload {
    fn new(ctx: &GpuContext, bytes: u64) -> Self {
        let buf = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("splat upload"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_WRITE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: true,
        });
        Self {
            buf,
            cap: bytes,
            state: Arc::new(AtomicU8::new(MAPPED)),
        }
    }

    /// Write `parts` back to back from the start of the buffer and unmap it for the copies out of
    /// it; returns the bytes written. Maps it first when an earlier call left it unmapped (one that
    /// failed before its wait): the device is idle then, so the wait only runs the callback.
    pub fn write(&self, ctx: &GpuContext, parts: &[&[f32]]) -> Result<u64, GpuError> {
        let bytes = 4 * parts.iter().map(|p| p.len() as u64).sum::<u64>();
        if bytes > self.cap {
            return Err(GpuError::Invalid(format!(
                "rasterize: {bytes} bytes of inputs for a {}-byte upload buffer",
                self.cap
            )));
        }
        if bytes == 0 {
            return Ok(0);
        }
        if self.state.load(Ordering::Acquire) != MAPPED {
            self.remap();
            ctx.wait()?;
            if self.state.load(Ordering::Acquire) != MAPPED {
                return Err(GpuError::Readback(
                    "the upload buffer could not be mapped".into(),
                ));
            }
        }
        {
            let mut view = self
                .buf
                .slice(..bytes)
                .get_mapped_range_mut()
                .map_err(|e| GpuError::Readback(format!("upload buffer: {e}")))?;
            let mut at = 0;
            for part in parts {
                let src: &[u8] = bytemuck::cast_slice(part);
                view.slice(at..at + src.len()).copy_from_slice(src);
                at += src.len();
            }
        }
        self.state.store(UNMAPPED, Ordering::Release);
        self.buf.unmap();
        Ok(bytes)
    }

    /// Ask for the buffer to be mapped again once the work submitted so far is done.
    pub fn remap(&self) {
        if self.state.load(Ordering::Acquire) == UNMAPPED {
            self.state.store(PENDING, Ordering::Release);
            let state = self.state.clone();
            self.buf
                .slice(..)
                .map_async(wgpu::MapMode::Write, move |r| {
                    state.store(if r.is_ok() { MAPPED } else { UNMAPPED }, Ordering::Release);
                });
        }
    }
}

/// What one render needs room for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sizes {
    pub n: u64,
    pub d: u64,
    pub pixels: u64,
    pub tiles: u64,
    /// Capacity of the tile-intersection lists.
    pub isect: u64,
}

pub struct Buffers {
    pub inputs: Grow,
    pub counters: Grow,
    pub proj: Grow,
    pub depth_keys: [Grow; 2],
    pub depth_vals: [Grow; 2],
    pub offsets: Grow,
    pub tile_keys: [Grow; 2],
    pub tile_vals: [Grow; 2],
    pub hist: Grow,
    pub ranges: Grow,
    pub image: Grow,
    pub depth: Grow,
    pub alpha: Grow,
    pub aux: Grow,
    pub grad_in: Grow,
    pub grads: Grow,
    pub param_grads: Grow,
    pub params: wgpu::Buffer,
    /// Workgroup counts (x, y, z) of the passes over the live tile keys, written by emit_keys.
    pub live_blocks: wgpu::Buffer,
    pub staging: wgpu::Buffer,
    staging_cap: u64,
    pub upload: Upload,
}

pub const SORT_BLOCK: u64 = wgsl::SORT_BLOCK as u64;
/// u32 words of `counters`: the tile-pair count, the tile passes' disagreement flag, then three
/// 64-bit work counters as (low, high) words (rasterize_fwd.wgsl's counting build).
pub const COUNTER_WORDS: u64 = 8;
/// Floats per Gaussian in `inputs`: mean 3, quaternion 4, scale 3, opacity 1 (features follow).
pub const INPUT_FLOATS: u64 = 11;
/// Floats per Gaussian in the gradient accumulator before the features (see rasterize_bwd.wgsl).
pub const GRAD_HEAD: u64 = wgsl::GRAD_HEAD as u64;
/// Floats per Gaussian written by project_bwd.wgsl: mean 3, quaternion 4, scale 3.
pub const PARAM_GRADS: u64 = wgsl::PARAM_GRADS as u64;

impl Buffers {
    pub fn new(ctx: &GpuContext, params_bytes: u64) -> Self {
        let g = |label| Grow::new(ctx, label);
        Self {
            inputs: g("inputs"),
            counters: g("counters"),
            proj: g("projected"),
            depth_keys: [g("depth keys"), g("depth keys")],
            depth_vals: [g("depth ids"), g("depth ids")],
            offsets: g("tile offsets"),
            tile_keys: [g("tile keys"), g("tile keys")],
            tile_vals: [g("tile ids"), g("tile ids")],
            hist: g("sort histogram"),
            ranges: g("tile ranges"),
            image: g("image"),
            depth: g("depth"),
            alpha: g("alpha"),
            aux: g("pixel state"),
            grad_in: g("output gradients"),
            grads: g("gradient accumulator"),
            param_grads: g("parameter gradients"),
            params: ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("splat params"),
                size: params_bytes,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            live_blocks: ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("live tile-key blocks"),
                size: 16,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::INDIRECT,
                mapped_at_creation: false,
            }),
            staging: Self::staging_buffer(ctx, 16),
            staging_cap: 16,
            upload: Upload::new(ctx, 16),
        }
    }

    /// The buffer that every kernel binding it names `name` (the ping-pong buffers and those
    /// named by their role in one kernel are given to the bind group by that role instead).
    pub fn named(&self, name: &str) -> Option<&wgpu::Buffer> {
        Some(match name {
            "params" => &self.params,
            "live_blocks" => &self.live_blocks,
            "inputs" => &self.inputs.buf,
            "counters" => &self.counters.buf,
            "proj" => &self.proj.buf,
            "offsets" => &self.offsets.buf,
            "hist" => &self.hist.buf,
            "ranges" => &self.ranges.buf,
            "out_image" => &self.image.buf,
            "out_depth" => &self.depth.buf,
            "out_alpha" => &self.alpha.buf,
            "aux" => &self.aux.buf,
            "grad_in" => &self.grad_in.buf,
            "grads" => &self.grads.buf,
            "param_grads" => &self.param_grads.buf,
            _ => return None,
        })
    }

    fn staging_buffer(ctx: &GpuContext, bytes: u64) -> wgpu::Buffer {
        ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("splat readback"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// Grow every buffer to fit `s`; true when any bind group must be rebuilt.
    pub fn ensure(&mut self, ctx: &GpuContext, s: Sizes) -> Result<bool, GpuError> {
        let f = 4u64;
        let input_bytes = f * (s.n * (INPUT_FLOATS + s.d) + s.d);
        let blocks = s.n.div_ceil(SORT_BLOCK).max(s.isect.div_ceil(SORT_BLOCK));
        let mut grown = false;
        grown |= self.inputs.ensure(ctx, input_bytes)?;
        grown |= self.counters.ensure(ctx, 4 * COUNTER_WORDS)?;
        grown |= self.proj.ensure(ctx, f * 8 * s.n)?;
        for b in self.depth_keys.iter_mut().chain(self.depth_vals.iter_mut()) {
            grown |= b.ensure(ctx, f * s.n)?;
        }
        grown |= self.offsets.ensure(ctx, f * (s.n + 1))?;
        for b in self.tile_keys.iter_mut().chain(self.tile_vals.iter_mut()) {
            grown |= b.ensure(ctx, f * s.isect)?;
        }
        grown |= self
            .hist
            .ensure(ctx, f * wgsl::MAX_DIGITS as u64 * blocks)?;
        grown |= self.ranges.ensure(ctx, f * 2 * s.tiles)?;
        grown |= self.image.ensure(ctx, f * s.pixels * s.d)?;
        grown |= self.depth.ensure(ctx, f * s.pixels)?;
        grown |= self.alpha.ensure(ctx, f * s.pixels)?;
        grown |= self.aux.ensure(ctx, f * 4 * s.pixels)?;
        grown |= self.grad_in.ensure(ctx, f * s.pixels * (s.d + 2))?;
        grown |= self.grads.ensure(ctx, f * s.n * (GRAD_HEAD + s.d))?;
        grown |= self.param_grads.ensure(ctx, f * s.n * PARAM_GRADS)?;
        let download = (f * (s.pixels * (s.d + 2) + 8 * s.n) + 4 * COUNTER_WORDS)
            .max(f * s.n * (GRAD_HEAD + s.d + PARAM_GRADS));
        if download > self.staging_cap {
            let cap = download.next_power_of_two();
            self.staging = Self::staging_buffer(ctx, cap);
            self.staging_cap = cap;
        }
        // A backward that renders again uploads the inputs and the output gradients together.
        let upload = input_bytes + f * s.pixels * (s.d + 2);
        if upload > self.upload.cap {
            self.upload = Upload::new(ctx, upload.next_power_of_two());
        }
        Ok(grown)
    }
}
