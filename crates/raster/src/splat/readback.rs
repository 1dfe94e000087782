//! The one download of each pass: what is copied into the staging buffer, in which order, and
//! how it is taken apart on the host.

use super::buffers::{Buffers, COUNTER_WORDS, GRAD_HEAD, PARAM_GRADS};
use super::record::Recorder;
use super::{ForwardOutput, Gradients, Render, WorkCounts};
use crate::context::GpuError;
use crate::host;

/// A forward render as read back: image, depth, alpha, the projected Gaussians (8 floats each)
/// and the counters.
pub struct ForwardRead {
    floats: Vec<f32>,
    counters: Vec<u32>,
    pixels: usize,
    n: usize,
    d: usize,
}

/// Copy a forward render's outputs to the host (submitting what `rec` recorded).
pub fn forward(
    mut rec: Recorder,
    b: &Buffers,
    n: usize,
    d: usize,
    pixels: usize,
) -> Result<ForwardRead, GpuError> {
    let (n64, d64, px) = (n as u64, d as u64, pixels as u64);
    let parts: [(&wgpu::Buffer, u64); 5] = [
        (&b.image.buf, 4 * px * d64),
        (&b.depth.buf, 4 * px),
        (&b.alpha.buf, 4 * px),
        (&b.proj.buf, 4 * 8 * n64),
        (&b.counters.buf, 4 * COUNTER_WORDS),
    ];
    let mut at = 0;
    for (src, bytes) in parts {
        if bytes > 0 {
            rec.enc.copy_buffer_to_buffer(src, 0, &b.staging, at, bytes);
        }
        at += bytes;
    }
    let raw = rec.finish(&b.staging, at)?;
    let (floats, counters) = raw.split_at(raw.len() - 4 * COUNTER_WORDS as usize);
    Ok(host::time("unpack", || ForwardRead {
        floats: bytemuck::pod_collect_to_vec(floats),
        counters: bytemuck::pod_collect_to_vec(counters),
        pixels,
        n,
        d,
    }))
}

impl ForwardRead {
    /// Tile intersections the render produced (more than the capacity when it overflowed).
    pub fn intersections(&self) -> u32 {
        self.counters[0]
    }

    /// Whether the tile count and tile key passes flagged a disagreement.
    pub fn tiles_disagree(&self) -> bool {
        self.counters[1] != 0
    }

    /// (image, depth, alpha) of the band, and the projected Gaussians.
    fn parts(&self) -> (&[f32], &[f32], &[f32], &[f32]) {
        let (image, rest) = self.floats.split_at(self.pixels * self.d);
        let (depth, rest) = rest.split_at(self.pixels);
        let (alpha, rest) = rest.split_at(self.pixels);
        (image, depth, alpha, &rest[..8 * self.n])
    }

    /// Work counter k (64 bits from two words).
    fn work(&self, k: usize) -> u64 {
        let c = &self.counters;
        c[2 + 2 * k] as u64 | (c[3 + 2 * k] as u64) << 32
    }
}

/// The render of `render`'s bands, read back in order (top to bottom): their rows stacked, their
/// counts summed; every band projected the same Gaussians, so the first one's are taken.
pub fn output(bands: &[ForwardRead], count_work: bool, render: Render) -> ForwardOutput {
    let (mut image, mut depth, mut alpha) = (Vec::new(), Vec::new(), Vec::new());
    for band in bands {
        let (i, d, a, _) = band.parts();
        image.extend_from_slice(i);
        depth.extend_from_slice(d);
        alpha.extend_from_slice(a);
    }
    let proj = bands.first().map_or(&[][..], |b| b.parts().3);
    let sum = |f: &dyn Fn(&ForwardRead) -> u64| bands.iter().map(f).sum::<u64>();
    let pairs = sum(&|b| b.intersections() as u64);
    ForwardOutput {
        image,
        depth,
        alpha,
        radii: proj.chunks_exact(8).map(|q| q[7] as i32).collect(),
        means2d: proj.chunks_exact(8).flat_map(|q| [q[0], q[1]]).collect(),
        depths: proj.chunks_exact(8).map(|q| q[3]).collect(),
        intersections: pairs.min(u32::MAX as u64) as u32,
        work: count_work.then(|| WorkCounts {
            pairs,
            evaluated: sum(&|b| b.work(0)),
            contributed: sum(&|b| b.work(1)),
            saturated: sum(&|b| b.work(2)),
        }),
        render,
    }
}

/// Copy the gradient accumulator and the parameter gradients of `n` Gaussians with `d` channels
/// to the host (submitting what `rec` recorded) and split them per input.
pub fn gradients(
    mut rec: Recorder,
    b: &Buffers,
    n: usize,
    d: usize,
) -> Result<Gradients, GpuError> {
    let stride = GRAD_HEAD as usize + d;
    let grad_bytes = 4 * (n * stride) as u64;
    let param_bytes = 4 * n as u64 * PARAM_GRADS;
    if n > 0 {
        rec.enc
            .copy_buffer_to_buffer(&b.grads.buf, 0, &b.staging, 0, grad_bytes);
        rec.enc
            .copy_buffer_to_buffer(&b.param_grads.buf, 0, &b.staging, grad_bytes, param_bytes);
    }
    let raw = rec.finish(&b.staging, grad_bytes + param_bytes)?;
    Ok(host::time("unpack", || split_gradients(&raw, n, d)))
}

/// The gradients of each input, from the accumulator and the parameter gradients as read back.
fn split_gradients(raw: &[u8], n: usize, d: usize) -> Gradients {
    let stride = GRAD_HEAD as usize + d;
    let all: Vec<f32> = bytemuck::pod_collect_to_vec(raw);
    let (acc, params) = all.split_at(n * stride);
    let mut out = Gradients {
        means: Vec::with_capacity(3 * n),
        quats: Vec::with_capacity(4 * n),
        scales: Vec::with_capacity(3 * n),
        opacities: Vec::with_capacity(n),
        features: Vec::with_capacity(d * n),
        means2d: Vec::with_capacity(2 * n),
    };
    for (a, q) in acc
        .chunks_exact(stride)
        .zip(params.chunks_exact(PARAM_GRADS as usize))
    {
        out.means2d.extend_from_slice(&a[..2]);
        out.opacities.push(a[5]);
        out.features.extend_from_slice(&a[GRAD_HEAD as usize..]);
        out.means.extend_from_slice(&q[..3]);
        out.quats.extend_from_slice(&q[3..7]);
        out.scales.extend_from_slice(&q[7..10]);
    }
    out
}
