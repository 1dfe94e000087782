//! Bind groups of the forward and backward passes, built by binding name: each shader's group-0
//! variables (`Kernel::bindings`, reflected from the WGSL) are matched to buffers by name.

use std::cell::OnceCell;

use super::buffers::{Buffers, Grow};
use super::forward::DEPTH_PASSES;
use crate::context::{AtomicMode, GpuContext};
use crate::Kernel;

/// A bind group for `kernel`'s pipeline with `d` channels. Each binding the entry point uses is
/// looked up by its WGSL name, first in `roles` (buffers a kernel names by what it does with
/// them, such as a sort pass's `keys_in`), then among the buffers every kernel names alike.
fn bind(
    ctx: &GpuContext,
    b: &Buffers,
    kernel: Kernel,
    d: u32,
    roles: &[(&str, &wgpu::Buffer)],
) -> wgpu::BindGroup {
    let bindings = kernel.bindings();
    // A role the kernel does not bind is a host/shader mismatch, as is an unknown name below.
    for (role, _) in roles {
        assert!(
            bindings.iter().any(|(_, name)| name == role),
            "{kernel:?} has no binding named {role:?}"
        );
    }
    let entries: Vec<wgpu::BindGroupEntry> = (bindings.iter())
        .map(|&(binding, name)| {
            let buffer = (roles.iter().find(|(role, _)| *role == name))
                .map(|&(_, buffer)| buffer)
                .or_else(|| b.named(name))
                .unwrap_or_else(|| panic!("{kernel:?} binds {name:?}, which no buffer is named"));
            wgpu::BindGroupEntry {
                binding,
                resource: buffer.as_entire_binding(),
            }
        })
        .collect();
    ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &ctx.pipeline(kernel, d).get_bind_group_layout(0),
        entries: &entries,
    })
}

/// Bind groups of the forward passes (rebuilt only after buffers grew).
pub struct Forward {
    pub project: wgpu::BindGroup,
    pub depth_hist: Vec<wgpu::BindGroup>,
    pub depth_scatter: Vec<wgpu::BindGroup>,
    pub count: wgpu::BindGroup,
    pub emit: wgpu::BindGroup,
    pub tile_hist: Vec<wgpu::BindGroup>,
    pub tile_scatter: Vec<wgpu::BindGroup>,
    /// Indexed by which ping-pong buffer holds the tile-sorted lists.
    pub ranges: [wgpu::BindGroup; 2],
    pub raster: [wgpu::BindGroup; 2],
    /// The counting build's, made on the first render that counts.
    raster_count: OnceCell<[wgpu::BindGroup; 2]>,
}

/// The groups of a compositing pass `kernel` (forward or backward), one per ping-pong buffer that
/// may hold the tile-sorted lists.
fn per_sorted(ctx: &GpuContext, b: &Buffers, kernel: Kernel, d: u32) -> [wgpu::BindGroup; 2] {
    [0, 1].map(|k| bind(ctx, b, kernel, d, &[("tile_vals", &b.tile_vals[k].buf)]))
}

/// The histogram and scatter groups of one radix sort, one per pass (`passes` holds each pass's
/// uniform); pass p reads ping-pong buffer p % 2 and writes the other.
fn sort(
    ctx: &GpuContext,
    b: &Buffers,
    passes: &[wgpu::Buffer],
    keys: &[Grow; 2],
    vals: &[Grow; 2],
) -> (Vec<wgpu::BindGroup>, Vec<wgpu::BindGroup>) {
    let (mut hist, mut scatter) = (Vec::new(), Vec::new());
    for (p, uniform) in passes.iter().enumerate() {
        let (src, dst) = (p % 2, 1 - p % 2);
        let read = [("pass_info", uniform), ("keys_in", &keys[src].buf)];
        hist.push(bind(ctx, b, Kernel::SortHistogram, 0, &read));
        let write = [
            ("vals_in", &vals[src].buf),
            ("keys_out", &keys[dst].buf),
            ("vals_out", &vals[dst].buf),
        ];
        scatter.push(bind(
            ctx,
            b,
            Kernel::SortScatter,
            0,
            &[&read[..], &write[..]].concat(),
        ));
    }
    (hist, scatter)
}

impl Forward {
    pub fn new(ctx: &GpuContext, b: &Buffers, sort_passes: &[wgpu::Buffer], d: u32) -> Self {
        let project = bind(
            ctx,
            b,
            Kernel::Project,
            d,
            &[
                ("depth_keys", &b.depth_keys[0].buf),
                ("depth_vals", &b.depth_vals[0].buf),
            ],
        );
        let (depth_passes, tile_passes) = sort_passes.split_at(DEPTH_PASSES);
        let (depth_hist, depth_scatter) = sort(ctx, b, depth_passes, &b.depth_keys, &b.depth_vals);
        let (tile_hist, tile_scatter) = sort(ctx, b, tile_passes, &b.tile_keys, &b.tile_vals);
        // DEPTH_PASSES is even: the depth-sorted ids end in depth_vals[0].
        let sorted_ids = ("sorted_ids", &b.depth_vals[0].buf);
        let count = bind(
            ctx,
            b,
            Kernel::CountTiles,
            d,
            &[sorted_ids, ("counts", &b.offsets.buf)],
        );
        let emit = bind(
            ctx,
            b,
            Kernel::EmitKeys,
            d,
            &[
                sorted_ids,
                ("tile_keys", &b.tile_keys[0].buf),
                ("tile_vals", &b.tile_vals[0].buf),
            ],
        );
        let ranges = [0, 1].map(|k| {
            bind(
                ctx,
                b,
                Kernel::TileRanges,
                d,
                &[("tile_keys", &b.tile_keys[k].buf)],
            )
        });
        Self {
            project,
            depth_hist,
            depth_scatter,
            count,
            emit,
            tile_hist,
            tile_scatter,
            ranges,
            raster: per_sorted(ctx, b, Kernel::RasterizeFwd, d),
            raster_count: OnceCell::new(),
        }
    }

    /// The compositing pass's groups for its counting build (`count_work`) or the plain one.
    pub fn raster(
        &self,
        ctx: &GpuContext,
        b: &Buffers,
        count_work: bool,
        d: u32,
    ) -> &[wgpu::BindGroup; 2] {
        if count_work {
            (self.raster_count).get_or_init(|| per_sorted(ctx, b, Kernel::RasterizeFwdCount, d))
        } else {
            &self.raster
        }
    }
}

/// The backward compositing kernel for an atomics mode, summing across subgroups first or not.
pub fn raster_bwd_kernel(mode: AtomicMode, subgroups: bool) -> Kernel {
    match (mode, subgroups) {
        (AtomicMode::Float, true) => Kernel::RasterizeBwd,
        (AtomicMode::Cas, true) => Kernel::RasterizeBwdCas,
        (AtomicMode::Float, false) => Kernel::RasterizeBwdSolo,
        (AtomicMode::Cas, false) => Kernel::RasterizeBwdCasSolo,
    }
}

/// Bind groups of the backward passes for one backward compositing kernel.
pub struct Backward {
    pub raster: [wgpu::BindGroup; 2],
    pub project: wgpu::BindGroup,
}

impl Backward {
    pub fn new(ctx: &GpuContext, b: &Buffers, raster: Kernel, d: u32) -> Self {
        Self {
            raster: per_sorted(ctx, b, raster, d),
            project: bind(ctx, b, Kernel::ProjectBwd, d, &[]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::buffers::Sizes;
    use super::*;
    use crate::wgsl::{Params, SortPass};

    /// Every binding of every splat kernel resolves to a buffer by its WGSL name (a mismatch
    /// panics in `bind`), and wgpu accepts the groups.
    #[test]
    fn every_splat_binding_resolves_by_name() {
        let ctx = GpuContext::global().expect("a Vulkan adapter (lavapipe in CI) is required");
        let mut b = Buffers::new(ctx, std::mem::size_of::<Params>() as u64);
        let sizes = Sizes {
            n: 1,
            d: 1,
            pixels: 1,
            tiles: 1,
            isect: super::super::forward::MIN_ISECT_CAP,
        };
        b.ensure(ctx, sizes).expect("room for one Gaussian");
        let passes: Vec<wgpu::Buffer> = (0..DEPTH_PASSES + super::super::forward::TILE_MAX_PASSES)
            .map(|_| {
                ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: None,
                    size: std::mem::size_of::<SortPass>() as u64,
                    usage: wgpu::BufferUsages::UNIFORM,
                    mapped_at_creation: false,
                })
            })
            .collect();
        Forward::new(ctx, &b, &passes, 1).raster(ctx, &b, true, 1);
        for mode in [AtomicMode::Float, AtomicMode::Cas] {
            for subgroups in [true, false] {
                let kernel = raster_bwd_kernel(mode, subgroups);
                if ctx.runs(kernel) {
                    Backward::new(ctx, &b, kernel, 1);
                }
            }
        }
        ctx.wait().expect("the device survives");
    }
}
