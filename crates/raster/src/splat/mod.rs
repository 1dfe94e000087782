//! The differentiable Gaussian splatting rasterizer: forward and backward compute passes.
//!
//! Forward: project -> depth sort (radix) -> count tiles -> scan -> emit tile keys -> stable sort
//! by tile -> tile ranges -> rasterize. Backward: rasterize_bwd -> project_bwd.
//! Buffers, bind groups and pipelines persist in a small per-process pool of render states; each
//! forward is one upload and one download, and so is each backward. A forward returns a
//! [`Render`] handle that its backward takes, with the same inputs.

mod backward;
mod binds;
mod buffers;
mod forward;
mod inputs;
mod readback;
mod record;
mod state;

use crate::context::{AtomicMode, GpuContext, GpuError};
use crate::host;
use crate::wgsl::{self, Params};

use inputs::Band;
pub use inputs::{Camera, Gaussians};
pub use wgsl::TILE;

/// Feature channels a render may have (MAX_D in splat_common.wgsl).
pub const MAX_FEATURES: usize = wgsl::MAX_D as usize;

/// Per-pixel outputs and per-Gaussian metadata of one forward render.
#[derive(Debug)]
pub struct ForwardOutput {
    /// H x W x D, row-major.
    pub image: Vec<f32>,
    pub depth: Vec<f32>,
    pub alpha: Vec<f32>,
    /// 3-sigma radius in pixels, 0 = culled.
    pub radii: Vec<i32>,
    /// N x 2 projected means (x, y) in pixels.
    pub means2d: Vec<f32>,
    /// Camera z of each Gaussian (0 where culled).
    pub depths: Vec<f32>,
    /// Tile intersections rendered.
    pub intersections: u32,
    /// Pixel-Gaussian step counts, when the render was asked to count them.
    pub work: Option<WorkCounts>,
    /// What [`rasterize_backward`] needs of this render.
    pub render: Render,
}

/// One forward render as its backward pass needs it: the camera (to render it again, with the
/// inputs the backward is given, when later renders have taken its buffers) and, per band of rows
/// it was rendered in (one unless its buffers would exceed the binding limit), the id of the
/// per-pixel state it left on the GPU. Made only by [`rasterize_forward`], so a backward always
/// matches a real render.
#[derive(Debug)]
pub struct Render {
    n: usize,
    d: usize,
    cam: Camera,
    bands: Vec<(u64, Band)>,
}

/// What the forward compositing pass did, per render (summed over the image's pixels).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WorkCounts {
    /// (tile, Gaussian) pairs in the tile lists.
    pub pairs: u64,
    /// Pixel-Gaussian steps evaluated (the pixel still open: transmittance above the cut-off).
    pub evaluated: u64,
    /// Evaluated steps that were composited (alpha >= 1/255 inside 3 sigma).
    pub contributed: u64,
    /// Steps of pixels already closed (transmittance below the cut-off) that their invocation
    /// still walked because its other pixels were open.
    pub saturated: u64,
}

/// Gradients of a scalar loss with respect to a render's outputs (H x W x D, H x W, H x W).
#[derive(Debug, Clone, Copy)]
pub struct OutputGrads<'a> {
    pub image: &'a [f32],
    pub depth: &'a [f32],
    pub alpha: &'a [f32],
}

/// Gradients of a scalar loss with respect to every input.
#[derive(Debug, Clone)]
pub struct Gradients {
    pub means: Vec<f32>,
    pub quats: Vec<f32>,
    pub scales: Vec<f32>,
    pub opacities: Vec<f32>,
    pub features: Vec<f32>,
    /// N x 2: dL/dmeans2d, what 3DGS densification accumulates.
    pub means2d: Vec<f32>,
}

/// Host-side timings of the passes, filled when profiling (each pass submitted separately).
pub type PassTimes = Vec<(&'static str, f64)>;

/// Render `g` from `cam`. With `profile`, each pass is submitted and timed on its own; with
/// `count_work`, the compositing pass is the (slower) build that fills [`ForwardOutput::work`].
/// An image whose per-pixel or tile-pair buffers would exceed the storage-binding limit
/// (`GpuContext::binding_limit`) is rendered in bands of whole tile rows, each as an image of its
/// own rows, and its rows stacked: the same pixels, bit for bit.
pub fn rasterize_forward(
    ctx: &GpuContext,
    g: &Gaussians,
    cam: &Camera,
    mut profile: Option<&mut PassTimes>,
    count_work: bool,
) -> Result<ForwardOutput, GpuError> {
    g.check()?;
    cam.check()?;
    // The widest per-pixel buffer: the output gradients (d + 2 floats) or the pixel state (4).
    let row_bytes = 4 * cam.width as u64 * (g.d as u64 + 2).max(4);
    let max_rows = (ctx.binding_limit() / row_bytes).min(cam.height as u64) as u32;
    let mut todo = cam.bands(max_rows); // one band when the image fits
    todo.reverse(); // a stack: the top band is popped first
    let (mut bands, mut reads) = (Vec::new(), Vec::new());
    while let Some(band) = todo.pop() {
        let mut pool = state::lock();
        let (id, st) = pool.for_forward(ctx, g.d as u64);
        let run = forward::run(
            ctx,
            st,
            g,
            cam,
            band,
            id,
            profile.as_deref_mut(),
            count_work,
            reads.is_empty(), // every band projects the same Gaussians: read them once
        );
        match (run, band.split()) {
            // Too many tile pairs (or pixels) for one band: render its halves instead.
            (Err(GpuError::OverLimit(_)), Some([top, bottom])) => {
                todo.push(bottom);
                todo.push(top);
            }
            (run, _) => {
                reads.push(run?);
                bands.push((id, band));
            }
        }
    }
    let render = Render {
        n: g.len(),
        d: g.d,
        cam: *cam,
        bands,
    };
    Ok(host::time("unpack", || {
        readback::output(reads, count_work, render)
    }))
}

/// Gradients of a loss given its gradients with respect to the outputs of `render`, whose inputs
/// `g` were (it is rendered again first when later renders have replaced it in the buffers).
pub fn rasterize_backward(
    ctx: &GpuContext,
    render: &Render,
    g: &Gaussians,
    grads: &OutputGrads,
    mode: AtomicMode,
    profile: Option<&mut PassTimes>,
) -> Result<Gradients, GpuError> {
    g.check()?;
    if g.len() != render.n || g.d != render.d {
        return Err(GpuError::Invalid(format!(
            "rasterize backward: inputs of {} Gaussians with {} channels for a render of {} with {}",
            g.len(),
            g.d,
            render.n,
            render.d
        )));
    }
    let pixels = render.cam.width as usize * render.cam.height as usize;
    let d = render.d;
    if grads.image.len() != pixels * d || grads.depth.len() != pixels || grads.alpha.len() != pixels
    {
        return Err(GpuError::Invalid(format!(
            "rasterize backward: output gradients have {}/{}/{} values, expected {}/{pixels}/{pixels}",
            grads.image.len(),
            grads.depth.len(),
            grads.alpha.len(),
            pixels * d
        )));
    }
    if mode == AtomicMode::Float && !ctx.float_atomics {
        return Err(GpuError::Invalid(
            "rasterize: float32 atomics requested but the adapter lacks SHADER_FLOAT32_ATOMIC; \
             use EVSPLAT_ATOMICS=cas"
                .into(),
        ));
    }
    let mut total: Option<Gradients> = None;
    let mut profile = profile;
    for &(id, band) in &render.bands {
        // The band's rows of each output gradient.
        let (px, first) = band.pixels(render.cam.width);
        let part = OutputGrads {
            image: &grads.image[first * d..(first + px) * d],
            depth: &grads.depth[first..first + px],
            alpha: &grads.alpha[first..first + px],
        };
        let mut pool = state::lock();
        let st = pool.for_backward(ctx, id);
        let band_grads = backward::run(
            ctx,
            st,
            (render, g),
            (id, band),
            &part,
            mode,
            profile.as_deref_mut(),
        )?;
        match total.as_mut() {
            Some(t) => t.add(&band_grads),
            None => total = Some(band_grads),
        }
    }
    total.ok_or_else(|| GpuError::Invalid("rasterize backward: a render without bands".into()))
}

impl Render {
    /// Feature channels of the render.
    pub fn channels(&self) -> usize {
        self.d
    }
}

impl Gradients {
    /// Add `other`'s gradients (of another band of the same render) to these.
    fn add(&mut self, other: &Gradients) {
        let pairs = [
            (&mut self.means, &other.means),
            (&mut self.quats, &other.quats),
            (&mut self.scales, &other.scales),
            (&mut self.opacities, &other.opacities),
            (&mut self.features, &other.features),
            (&mut self.means2d, &other.means2d),
        ];
        for (mine, theirs) in pairs {
            for (a, b) in mine.iter_mut().zip(theirs) {
                *a += b;
            }
        }
    }
}
