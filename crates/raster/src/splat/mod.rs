//! The differentiable Gaussian splatting rasterizer: forward and backward compute passes.
//!
//! Forward: project -> depth sort (radix) -> count tiles -> scan -> emit tile keys -> stable sort
//! by tile -> tile ranges -> rasterize. Backward: rasterize_bwd -> project_bwd.
//! Buffers, bind groups and pipelines persist in one per-process [`State`]; each forward is one
//! upload and one download, and so is each backward.

mod backward;
mod buffers;
mod forward;

use std::collections::HashMap;
use std::sync::{Mutex, OnceLock};

use crate::context::{AtomicMode, GpuContext, GpuError};
use crate::wgsl::{self, Params};
use buffers::{Buffers, Sizes, INPUT_FLOATS};

/// Feature channels a render may have (MAX_D in splat_common.wgsl).
pub const MAX_FEATURES: usize = wgsl::MAX_D as usize;
pub use wgsl::TILE;

/// Pinhole camera: world->camera `viewmat` (row-major 4x4), intrinsics `k` (row-major 3x3).
#[derive(Clone, Copy, Debug)]
pub struct Camera {
    pub viewmat: [f32; 16],
    pub k: [f32; 9],
    pub width: u32,
    pub height: u32,
    pub near: f32,
    pub far: f32,
}

/// The Gaussians to render, as flat row-major arrays.
#[derive(Clone, Copy, Debug)]
pub struct Gaussians<'a> {
    pub means: &'a [f32],
    pub quats: &'a [f32],
    pub scales: &'a [f32],
    pub opacities: &'a [f32],
    pub features: &'a [f32],
    pub d: usize,
    pub background: &'a [f32],
}

impl Gaussians<'_> {
    pub fn len(&self) -> usize {
        self.opacities.len()
    }

    pub fn is_empty(&self) -> bool {
        self.opacities.is_empty()
    }

    fn check(&self) -> Result<(), GpuError> {
        let n = self.len();
        let bad = |what: &str, got: usize, want: usize| {
            GpuError::Invalid(format!(
                "rasterize: {what} has {got} values, expected {want} for {n} Gaussians with {} features",
                self.d
            ))
        };
        if self.d == 0 || self.d > MAX_FEATURES {
            return Err(GpuError::Invalid(format!(
                "rasterize: features have {} channels; 1 to {MAX_FEATURES} are supported",
                self.d
            )));
        }
        for (what, got, want) in [
            ("means", self.means.len(), 3 * n),
            ("quats", self.quats.len(), 4 * n),
            ("scales", self.scales.len(), 3 * n),
            ("features", self.features.len(), self.d * n),
            ("background", self.background.len(), self.d),
        ] {
            if got != want {
                return Err(bad(what, got, want));
            }
        }
        if n >= (u32::MAX / 16) as usize {
            return Err(GpuError::Invalid(format!(
                "rasterize: {n} Gaussians are too many"
            )));
        }
        Ok(())
    }

    /// All inputs in one array (the single upload): means, quats, scales, opacities, features,
    /// background, at the offsets recorded in `Params`.
    fn pack(&self) -> Vec<f32> {
        let mut v = Vec::with_capacity(self.len() * (INPUT_FLOATS as usize + self.d) + self.d);
        for part in [
            self.means,
            self.quats,
            self.scales,
            self.opacities,
            self.features,
            self.background,
        ] {
            v.extend_from_slice(part);
        }
        v
    }
}

impl Camera {
    fn check(&self) -> Result<(), GpuError> {
        if self.width == 0 || self.height == 0 || self.width > 16384 || self.height > 16384 {
            return Err(GpuError::Invalid(format!(
                "rasterize: image size {}x{} must be 1..16384 on each side",
                self.width, self.height
            )));
        }
        if !(self.near > 0.0 && self.far > self.near) {
            return Err(GpuError::Invalid(format!(
                "rasterize: need 0 < near < far, got near={} far={}",
                self.near, self.far
            )));
        }
        let (fx, fy) = (self.k[0], self.k[4]);
        if !(fx > 0.0 && fy > 0.0) {
            return Err(GpuError::Invalid(format!(
                "rasterize: K must have positive focal lengths, got fx={fx} fy={fy}"
            )));
        }
        Ok(())
    }

    pub fn tiles(&self) -> (u32, u32) {
        (self.width.div_ceil(TILE), self.height.div_ceil(TILE))
    }
}

fn params(g: &Gaussians, cam: &Camera, cap: u64) -> Params {
    let n = g.len() as u32;
    let d = g.d as u32;
    let (tiles_x, tiles_y) = cam.tiles();
    let mut view = [0f32; 16];
    // Row-major 4x4 in, column-major mat4x4 out.
    for r in 0..4 {
        for c in 0..4 {
            view[4 * c + r] = cam.viewmat[4 * r + c];
        }
    }
    let (fx, fy, cx, cy) = (cam.k[0], cam.k[4], cam.k[2], cam.k[5]);
    let (w, h) = (cam.width as f32, cam.height as f32);
    // gsplat's guard band: 30% of the half field of view beyond each image edge.
    let (tan_x, tan_y) = (0.5 * w / fx, 0.5 * h / fy);
    Params {
        view,
        fx,
        fy,
        cx,
        cy,
        near: cam.near,
        far: cam.far,
        lim_x_pos: (w - cx) / fx + 0.3 * tan_x,
        lim_x_neg: cx / fx + 0.3 * tan_x,
        lim_y_pos: (h - cy) / fy + 0.3 * tan_y,
        lim_y_neg: cy / fy + 0.3 * tan_y,
        width: cam.width,
        height: cam.height,
        n,
        d,
        tiles_x,
        tiles_y,
        cap: cap as u32,
        off_quats: 3 * n,
        off_scales: 7 * n,
        off_opac: 10 * n,
        off_feat: 11 * n,
        off_bg: (11 + d) * n,
        grad_stride: buffers::GRAD_HEAD as u32 + d,
        _pad: 0,
    }
}

/// Per-pixel outputs and per-Gaussian metadata of one forward render.
#[derive(Debug, Clone)]
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
    /// Identifies this render to [`rasterize_backward`].
    pub id: u64,
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

struct State {
    bufs: Buffers,
    /// Intersection capacity (grows when a render overflows it, shrinks when far too large).
    isect_cap: u64,
    sizes: Option<Sizes>,
    binds: Option<forward::Binds>,
    bwd_binds: HashMap<bool, backward::Binds>,
    sort_passes: Vec<wgpu::Buffer>,
    scans: Vec<crate::ScanScratch>,
    /// The render whose per-pixel state is in the buffers.
    current: Option<u64>,
    /// Pool clock of the last use, for least-recently-used reuse.
    used: u64,
    /// The render here was differentiated already: its state is not needed again.
    spent: bool,
}

/// Renders whose per-pixel state a backward pass may still need each keep their own buffers,
/// up to this many: a training step renders two or three views and differentiates them in
/// reverse order, which with one set of buffers would re-render every view but the last.
const STATES: usize = 3;

/// The per-process states and the render-id counter.
struct Pool {
    states: Vec<State>,
    next_id: u64,
    clock: u64,
}

impl Pool {
    /// The state for a new render with `d` channels: a spent one of the same width first, then
    /// any spent one, a new one while the pool has room, else the least recently used.
    fn for_forward(&mut self, ctx: &GpuContext, d: u64) -> &mut State {
        let same_d = |s: &State| s.sizes.is_some_and(|z| z.d == d);
        let pick = (self.states.iter().position(|s| s.spent && same_d(s)))
            .or_else(|| self.states.iter().position(|s| s.spent));
        let i = match pick {
            Some(i) => i,
            None if self.states.len() < STATES => {
                self.states.push(State::new(ctx));
                self.states.len() - 1
            }
            None => (0..self.states.len())
                .min_by_key(|&i| self.states[i].used)
                .unwrap_or(0),
        };
        self.touch(i)
    }

    /// The state holding render `id`, else (it was evicted) the least recently used one.
    fn for_backward(&mut self, ctx: &GpuContext, id: u64) -> &mut State {
        if self.states.is_empty() {
            self.states.push(State::new(ctx));
        }
        let i = (self.states.iter().position(|s| s.current == Some(id)))
            .or_else(|| (0..self.states.len()).min_by_key(|&i| self.states[i].used))
            .unwrap_or(0);
        self.touch(i)
    }

    fn touch(&mut self, i: usize) -> &mut State {
        self.clock += 1;
        let st = &mut self.states[i];
        st.used = self.clock;
        st
    }
}

fn pool() -> &'static Mutex<Pool> {
    static POOL: OnceLock<Mutex<Pool>> = OnceLock::new();
    POOL.get_or_init(|| {
        Mutex::new(Pool {
            states: Vec::new(),
            next_id: 1,
            clock: 0,
        })
    })
}

impl State {
    fn new(ctx: &GpuContext) -> Self {
        let sort_passes = (0..2u32)
            .flat_map(|which| {
                (0..8u32).map(move |p| wgsl::SortPass {
                    shift: 4 * p,
                    which,
                    _pad0: 0,
                    _pad1: 0,
                })
            })
            .map(|pass| {
                let b = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("sort pass"),
                    size: 16,
                    usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                });
                ctx.queue.write_buffer(&b, 0, bytemuck::bytes_of(&pass));
                b
            })
            .collect();
        Self {
            bufs: Buffers::new(ctx, std::mem::size_of::<Params>() as u64),
            isect_cap: forward::MIN_ISECT_CAP,
            sizes: None,
            binds: None,
            bwd_binds: HashMap::new(),
            sort_passes,
            scans: (0..forward::SCANS)
                .map(|_| crate::ScanScratch::default())
                .collect(),
            current: None,
            used: 0,
            spent: false,
        }
    }

    /// Grow buffers for this render and drop bind groups that point at replaced buffers.
    fn prepare(
        &mut self,
        ctx: &GpuContext,
        g: &Gaussians,
        cam: &Camera,
    ) -> Result<Params, GpuError> {
        let (tx, ty) = cam.tiles();
        let sizes = Sizes {
            n: g.len() as u64,
            d: g.d as u64,
            pixels: cam.width as u64 * cam.height as u64,
            tiles: tx as u64 * ty as u64,
            isect: self.isect_cap,
        };
        let d_changed = self.sizes.is_some_and(|old| old.d != sizes.d);
        if self.bufs.ensure(ctx, sizes)? || d_changed {
            self.binds = None;
            self.bwd_binds.clear();
        }
        self.sizes = Some(sizes);
        let p = params(g, cam, self.isect_cap);
        ctx.queue
            .write_buffer(&self.bufs.params, 0, bytemuck::bytes_of(&p));
        Ok(p)
    }
}

fn lock() -> std::sync::MutexGuard<'static, Pool> {
    pool().lock().unwrap_or_else(|p| p.into_inner())
}

/// Render `g` from `cam`. With `profile`, each pass is submitted and timed on its own; with
/// `count_work`, the compositing pass is the (slower) build that fills [`ForwardOutput::work`].
pub fn rasterize_forward(
    ctx: &GpuContext,
    g: &Gaussians,
    cam: &Camera,
    profile: Option<&mut PassTimes>,
    count_work: bool,
) -> Result<ForwardOutput, GpuError> {
    g.check()?;
    cam.check()?;
    let mut pool = lock();
    let id = pool.next_id;
    pool.next_id += 1;
    let st = pool.for_forward(ctx, g.d as u64);
    st.spent = false;
    forward::run(ctx, st, g, cam, id, profile, count_work)
}

/// Gradients of a loss given its gradients with respect to the outputs of render `id` (which is
/// re-rendered first when another render has replaced it in the buffers).
#[allow(clippy::too_many_arguments)]
pub fn rasterize_backward(
    ctx: &GpuContext,
    g: &Gaussians,
    cam: &Camera,
    id: u64,
    grad_image: &[f32],
    grad_depth: &[f32],
    grad_alpha: &[f32],
    mode: AtomicMode,
    profile: Option<&mut PassTimes>,
) -> Result<Gradients, GpuError> {
    g.check()?;
    cam.check()?;
    let pixels = cam.width as usize * cam.height as usize;
    if grad_image.len() != pixels * g.d || grad_depth.len() != pixels || grad_alpha.len() != pixels
    {
        return Err(GpuError::Invalid(format!(
            "rasterize backward: output gradients have {}/{}/{} values, expected {}/{pixels}/{pixels}",
            grad_image.len(),
            grad_depth.len(),
            grad_alpha.len(),
            pixels * g.d
        )));
    }
    if mode == AtomicMode::Float && !ctx.float_atomics {
        return Err(GpuError::Invalid(
            "rasterize: float32 atomics requested but the adapter lacks SHADER_FLOAT32_ATOMIC; \
             use EVSPLAT_ATOMICS=cas"
                .into(),
        ));
    }
    let mut pool = lock();
    let st = pool.for_backward(ctx, id);
    st.spent = true;
    backward::run(
        ctx,
        st,
        g,
        cam,
        id,
        [grad_image, grad_depth, grad_alpha],
        mode,
        profile,
    )
}
