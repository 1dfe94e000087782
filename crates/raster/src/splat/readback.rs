//! The one download of each pass: what is copied into the staging buffer, in which order, and
//! how it is taken apart on the host: straight out of the mapped staging buffer into the vectors
//! handed to numpy, one copy of each value.

use std::borrow::Cow;

use super::buffers::{Buffers, COUNTER_WORDS, GRAD_HEAD, PARAM_GRADS};
use super::record::Recorder;
use super::{ForwardOutput, Gradients, Render, WorkCounts};
use crate::context::{GpuContext, GpuError};

/// What the projection leaves per Gaussian that the caller gets.
#[derive(Default)]
struct Projected {
    radii: Vec<i32>,
    means2d: Vec<f32>,
    depths: Vec<f32>,
}

/// A band of a forward render as read back: its image, depth and alpha rows, the projected
/// Gaussians (read with the first band only: every band projects the same) and the counters.
pub struct ForwardRead {
    image: Vec<f32>,
    depth: Vec<f32>,
    alpha: Vec<f32>,
    proj: Option<Projected>,
    counters: [u32; COUNTER_WORDS as usize],
}

/// `bytes` as floats: borrowed (mapped memory is aligned), copied only if it were not.
fn floats(bytes: &[u8]) -> Cow<'_, [f32]> {
    match bytemuck::try_cast_slice(bytes) {
        Ok(f) => Cow::Borrowed(f),
        Err(_) => Cow::Owned(bytemuck::pod_collect_to_vec(bytes)),
    }
}

/// What a forward render copied into its staging buffer, in order: image, depth and alpha rows,
/// (with `proj`) the projected Gaussians, the counters.
#[derive(Clone, Copy, Debug)]
pub struct ForwardLayout {
    n: usize,
    d: usize,
    pixels: usize,
    with_proj: bool,
    bytes: u64,
}

/// Record the copies of a forward render's outputs (and, with `with_proj`, its projected
/// Gaussians) into the staging buffer, last in `rec`.
pub fn copy_forward(
    rec: &mut Recorder,
    b: &Buffers,
    (n, d): (usize, usize),
    pixels: usize,
    with_proj: bool,
) -> ForwardLayout {
    let (d64, px) = (d as u64, pixels as u64);
    let proj_floats = if with_proj { 8 * n } else { 0 };
    let parts: [(&wgpu::Buffer, u64); 5] = [
        (&b.image.buf, 4 * px * d64),
        (&b.depth.buf, 4 * px),
        (&b.alpha.buf, 4 * px),
        (&b.proj.buf, 4 * proj_floats as u64),
        (&b.counters.buf, 4 * COUNTER_WORDS),
    ];
    let mut at = 0;
    for (src, bytes) in parts {
        if bytes > 0 {
            rec.enc.copy_buffer_to_buffer(src, 0, &b.staging, at, bytes);
        }
        at += bytes;
    }
    ForwardLayout {
        n,
        d,
        pixels,
        with_proj,
        bytes: at,
    }
}

/// Take a forward render's outputs out of the staging buffer once `submission` (the one that
/// copied them there, as `layout` says) has completed.
pub fn read_forward(
    ctx: &GpuContext,
    b: &Buffers,
    layout: ForwardLayout,
    submission: wgpu::SubmissionIndex,
) -> Result<ForwardRead, GpuError> {
    let ForwardLayout {
        n,
        d,
        pixels,
        with_proj,
        bytes,
    } = layout;
    let proj_floats = if with_proj { 8 * n } else { 0 };
    ctx.map_read_after(&b.staging, bytes, Some(submission), |raw| {
        let all = floats(raw);
        let (image, rest) = all.split_at(pixels * d);
        let (depth, rest) = rest.split_at(pixels);
        let (alpha, rest) = rest.split_at(pixels);
        let (proj, words) = rest.split_at(proj_floats);
        let mut counters = [0; COUNTER_WORDS as usize];
        for (c, w) in counters.iter_mut().zip(words) {
            *c = w.to_bits();
        }
        ForwardRead {
            image: image.to_vec(),
            depth: depth.to_vec(),
            alpha: alpha.to_vec(),
            proj: with_proj.then(|| Projected {
                radii: proj.chunks_exact(8).map(|q| q[7] as i32).collect(),
                means2d: proj.chunks_exact(8).flat_map(|q| [q[0], q[1]]).collect(),
                depths: proj.chunks_exact(8).map(|q| q[3]).collect(),
            }),
            counters,
        }
    })
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

    /// Work counter k (64 bits from two words).
    fn work(&self, k: usize) -> u64 {
        let c = &self.counters;
        c[2 + 2 * k] as u64 | (c[3 + 2 * k] as u64) << 32
    }
}

/// The render of `render`'s bands, read back in order (top to bottom): their rows stacked (the
/// usual single band's vectors moved, not copied), their counts summed, the first band's
/// projected Gaussians.
pub fn output(bands: Vec<ForwardRead>, count_work: bool, render: Render) -> ForwardOutput {
    let sum = |f: &dyn Fn(&ForwardRead) -> u64| bands.iter().map(f).sum::<u64>();
    let pairs = sum(&|b| b.intersections() as u64);
    let work = count_work.then(|| WorkCounts {
        pairs,
        evaluated: sum(&|b| b.work(0)),
        contributed: sum(&|b| b.work(1)),
        saturated: sum(&|b| b.work(2)),
    });
    let mut bands = bands.into_iter();
    let (mut image, mut depth, mut alpha, proj) = match bands.next() {
        Some(b) => (b.image, b.depth, b.alpha, b.proj.unwrap_or_default()),
        None => Default::default(),
    };
    for band in bands {
        image.extend_from_slice(&band.image);
        depth.extend_from_slice(&band.depth);
        alpha.extend_from_slice(&band.alpha);
    }
    ForwardOutput {
        image,
        depth,
        alpha,
        radii: proj.radii,
        means2d: proj.means2d,
        depths: proj.depths,
        intersections: pairs.min(u32::MAX as u64) as u32,
        work,
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
    rec.finish(b, grad_bytes + param_bytes, |raw| {
        split_gradients(raw, n, d)
    })
}

/// The gradients of each input, from the accumulator and the parameter gradients as read back.
fn split_gradients(raw: &[u8], n: usize, d: usize) -> Gradients {
    let stride = GRAD_HEAD as usize + d;
    let all = floats(raw);
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
