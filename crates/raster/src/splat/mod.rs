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
/// per-pixel state it left on the GPU and its tile pairs (the room a render again needs). Made
/// only by [`rasterize_forward`], so a backward always matches a real render.
#[derive(Debug)]
pub struct Render {
    n: usize,
    d: usize,
    cam: Camera,
    bands: Vec<(u64, Band, u32)>,
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
                let read = run?;
                bands.push((id, band, read.intersections()));
                reads.push(read);
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

/// A forward render submitted by [`rasterize_submit`] and not read back yet; [`rasterize_finish`]
/// waits for it. The device renders it while the caller does other work. Dropped unread, its
/// buffers are free for later renders again.
#[derive(Debug)]
pub struct PendingForward {
    n: usize,
    d: usize,
    cam: Camera,
    count_work: bool,
    /// The render's band as submitted (render id, band, what was sent), until read back.
    sent: Option<(u64, Band, forward::Submitted)>,
    /// A render that could not be submitted alone (several bands), done already.
    done: Option<ForwardOutput>,
}

/// Start the forward render of `g` from `cam` on the device and return without waiting for it
/// (as [`rasterize_forward`], which it equals once [`rasterize_finish`]ed). An image that needs
/// several bands (see there) is rendered whole here instead.
pub fn rasterize_submit(
    ctx: &GpuContext,
    g: &Gaussians,
    cam: &Camera,
    count_work: bool,
) -> Result<PendingForward, GpuError> {
    g.check()?;
    cam.check()?;
    let mut pending = PendingForward {
        n: g.len(),
        d: g.d,
        cam: *cam,
        count_work,
        sent: None,
        done: None,
    };
    let row_bytes = 4 * cam.width as u64 * (g.d as u64 + 2).max(4);
    let bands = cam.bands((ctx.binding_limit() / row_bytes).min(cam.height as u64) as u32);
    if let [band] = bands[..] {
        let mut pool = state::lock();
        let (id, st) = pool.for_forward(ctx, g.d as u64);
        match forward::submit(ctx, st, g, cam, band, None, count_work, true) {
            Ok(sent) => {
                st.pending = Some(id);
                pending.sent = Some((id, band, sent));
                return Ok(pending);
            }
            Err(GpuError::OverLimit(_)) => {} // rendered in bands below
            Err(e) => return Err(e),
        }
    }
    pending.done = Some(rasterize_forward(ctx, g, cam, None, count_work)?);
    Ok(pending)
}

/// Wait for the render `pending` and read it back. `g` are the inputs it was submitted with,
/// read only when it must be rendered again (its tile pairs overflowed the buffers' capacity).
pub fn rasterize_finish(
    ctx: &GpuContext,
    mut pending: PendingForward,
    g: &Gaussians,
) -> Result<ForwardOutput, GpuError> {
    if let Some(out) = pending.done.take() {
        return Ok(out);
    }
    let (n, d, cam, count_work) = (pending.n, pending.d, pending.cam, pending.count_work);
    g.check()?;
    if g.len() != n || g.d != d {
        return Err(GpuError::Invalid(format!(
            "rasterize finish: inputs of {} Gaussians with {} channels for a render of {n} with {d}",
            g.len(),
            g.d,
        )));
    }
    let Some((id, band, sent)) = pending.sent.take() else {
        return Err(GpuError::Invalid(
            "rasterize finish: the render was read already".into(),
        ));
    };
    let mut pool = state::lock();
    let st = (pool.for_pending(id)).ok_or_else(|| {
        GpuError::Invalid("rasterize finish: the submitted render is gone".into())
    })?;
    st.pending = None;
    let read = match forward::read(ctx, st, sent, band, id) {
        Ok(Some(read)) => read,
        // The tile pairs overflowed: render it again with the grown capacity.
        Ok(None) => match forward::run(ctx, st, g, &cam, band, id, None, count_work, true) {
            Err(GpuError::OverLimit(_)) => {
                drop(pool);
                return rasterize_forward(ctx, g, &cam, None, count_work);
            }
            run => run?,
        },
        // More tile pairs than one binding holds: render it in bands.
        Err(GpuError::OverLimit(_)) => {
            drop(pool);
            return rasterize_forward(ctx, g, &cam, None, count_work);
        }
        Err(e) => return Err(e),
    };
    let render = Render {
        n,
        d,
        cam,
        bands: vec![(id, band, read.intersections())],
    };
    Ok(host::time("unpack", || {
        readback::output(vec![read], count_work, render)
    }))
}

impl Drop for PendingForward {
    fn drop(&mut self) {
        // Never read back: its state may serve other renders (the queue orders their work).
        if let Some((id, _, _)) = self.sent.take() {
            if let Some(st) = state::lock().for_pending(id) {
                st.pending = None;
            }
        }
    }
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
    for &(id, band, pairs) in &render.bands {
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
            (id, band, pairs),
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

impl PendingForward {
    /// Feature channels of the render.
    pub fn channels(&self) -> usize {
        self.d
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` Gaussians in front of the camera (deterministic), `scale` their size in metres.
    fn scene(n: usize, d: usize, scale: f32) -> [Vec<f32>; 6] {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut rand = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let v = |count: usize, f: &mut dyn FnMut(usize) -> f32| (0..count).map(f).collect();
        [
            v(3 * n, &mut |i| match i % 3 {
                2 => 3.0 + rand(),
                _ => 2.0 * rand() - 1.0,
            }),
            v(4 * n, &mut |_| rand() - 0.5),
            v(3 * n, &mut |_| scale * (0.2 + rand())),
            v(n, &mut |_| 0.1 + 0.8 * rand()),
            v(d * n, &mut |_| rand()),
            vec![0.5; d],
        ]
    }

    fn gaussians(s: &[Vec<f32>; 6], d: usize) -> Gaussians<'_> {
        Gaussians {
            means: &s[0],
            quats: &s[1],
            scales: &s[2],
            opacities: &s[3],
            features: &s[4],
            d,
            background: &s[5],
        }
    }

    fn camera(width: u32, height: u32, shift: f32) -> Camera {
        let mut viewmat = [0.0; 16];
        for i in 0..4 {
            viewmat[5 * i] = 1.0;
        }
        viewmat[3] = shift;
        let f = 1.2 * width as f32;
        let k = [
            f,
            0.0,
            width as f32 / 2.0,
            0.0,
            f,
            height as f32 / 2.0,
            0.0,
            0.0,
            1.0,
        ];
        Camera {
            viewmat,
            k,
            width,
            height,
            near: 0.01,
            far: 1e4,
        }
    }

    fn assert_same(a: &ForwardOutput, b: &ForwardOutput) {
        assert_eq!(a.image, b.image);
        assert_eq!(a.depth, b.depth);
        assert_eq!(a.alpha, b.alpha);
        assert_eq!(a.radii, b.radii);
        assert_eq!(a.means2d, b.means2d);
        assert_eq!(a.depths, b.depths);
        assert_eq!(a.intersections, b.intersections);
    }

    #[test]
    fn submitted_renders_read_back_in_any_order_equal_forward_renders() {
        let ctx = GpuContext::global().expect("a Vulkan adapter (lavapipe in CI) is required");
        let (small, wide) = (scene(400, 3, 0.02), scene(300, 5, 0.05));
        let (g1, g2) = (gaussians(&small, 3), gaussians(&wide, 5));
        let (c1, c2) = (camera(64, 48, 0.0), camera(40, 72, 0.1));
        let want1 = rasterize_forward(ctx, &g1, &c1, None, false).unwrap();
        let want2 = rasterize_forward(ctx, &g2, &c2, None, false).unwrap();
        // Two on the device at once, read back last first; a third dropped unread.
        let p1 = rasterize_submit(ctx, &g1, &c1, false).unwrap();
        let p2 = rasterize_submit(ctx, &g2, &c2, false).unwrap();
        drop(rasterize_submit(ctx, &g1, &c2, false).unwrap());
        let got2 = rasterize_finish(ctx, p2, &g2).unwrap();
        let got1 = rasterize_finish(ctx, p1, &g1).unwrap();
        assert_same(&got1, &want1);
        assert_same(&got2, &want2);
        // Their backward passes find their per-pixel state (or render it again) as usual.
        let px = 64 * 48;
        let (gi, gd, ga) = (vec![1.0; 3 * px], vec![0.1; px], vec![0.5; px]);
        let grads = OutputGrads {
            image: &gi,
            depth: &gd,
            alpha: &ga,
        };
        let mode = ctx.default_atomic_mode();
        let a = rasterize_backward(ctx, &got1.render, &g1, &grads, mode, None).unwrap();
        let b = rasterize_backward(ctx, &want1.render, &g1, &grads, mode, None).unwrap();
        let peak = b.means.iter().fold(0f32, |m, v| m.max(v.abs()));
        for (x, y) in a.means.iter().zip(&b.means) {
            assert!((x - y).abs() <= 1e-4 * peak.max(1.0), "{x} vs {y}");
        }
    }

    #[test]
    fn a_submitted_render_whose_tile_pairs_overflow_is_rendered_again_when_read() {
        let ctx = GpuContext::global().expect("a Vulkan adapter (lavapipe in CI) is required");
        // Large Gaussians over the whole image: far more tile pairs than a fresh capacity.
        let big = scene(3000, 3, 0.3);
        let g = gaussians(&big, 3);
        let cam = camera(128, 128, 0.0);
        let pending = rasterize_submit(ctx, &g, &cam, false).unwrap();
        let got = rasterize_finish(ctx, pending, &g).unwrap();
        let want = rasterize_forward(ctx, &g, &cam, None, false).unwrap();
        assert!(got.intersections as u64 > forward::MIN_ISECT_CAP);
        assert_same(&got, &want);
    }

    #[test]
    fn an_image_that_fits_is_one_band_whatever_its_height() {
        // 260 rows are 32 whole tile rows and a partial one: still one band (as two, each render
        // took two of the pool's states, and a training step's views evicted one another).
        let cam = camera(346, 260, 0.0);
        assert_eq!(cam.bands(260), [Band { ty0: 0, rows: 260 }]);
        let rows: Vec<u32> = cam.bands(100).iter().map(|b| b.rows).collect();
        let step = 100 / TILE * TILE;
        assert!(rows[..rows.len() - 1].iter().all(|&r| r == step));
        assert_eq!(rows.iter().sum::<u32>(), 260);
    }

    /// A render's gradients do not depend on the renders made between its forward and its
    /// backward: with its per-pixel state kept, or taken by them and rendered again in a state
    /// whose intersection capacity a render with fewer tile pairs last sized (before 5d81a83 the
    /// re-render dropped the tile pairs past that capacity).
    #[test]
    fn gradients_do_not_depend_on_the_renders_between_forward_and_backward() {
        let ctx = GpuContext::global().expect("a Vulkan adapter (lavapipe in CI) is required");
        let (big, few) = (scene(1500, 1, 0.03), scene(10, 1, 0.03));
        let (g, other) = (gaussians(&big, 1), gaussians(&few, 1));
        // DAVIS346's size (its last tile row partial).
        let cam = camera(346, 260, 0.0);
        let px = 346 * 260;
        let wave = |k: usize, s: f32| -> Vec<f32> {
            (0..px)
                .map(|i| s * (((i * k) % 13) as f32 / 13.0 - 0.5))
                .collect()
        };
        let (gi, gd, ga) = (wave(7919, 1.0), wave(104_729, 0.1), wave(1_299_709, 0.5));
        let grads = OutputGrads {
            image: &gi,
            depth: &gd,
            alpha: &ga,
        };
        let mode = ctx.default_atomic_mode();
        let differentiate = |between: &[Camera]| {
            let a = rasterize_forward(ctx, &g, &cam, None, false).unwrap();
            for c in between {
                rasterize_forward(ctx, &other, c, None, false).unwrap();
            }
            let most = a.render.bands.iter().map(|&(_, _, m)| m).max().unwrap();
            let got = rasterize_backward(ctx, &a.render, &g, &grads, mode, None).unwrap();
            (most, got)
        };
        let (pairs, want) = differentiate(&[]);
        // A band needs more room than a fresh state's (or one a small render shrank).
        assert!(
            pairs as u64 > 2 * forward::MIN_ISECT_CAP,
            "{pairs} tile pairs"
        );
        let small = camera(96, 96, 0.0);
        let cases = [
            ("kept (one small image between)", vec![small]),
            ("kept (one render of its size between)", vec![cam]),
            ("taken (four renders between: rendered again)", vec![cam; 4]),
        ];
        for (case, between) in cases {
            let (_, got) = differentiate(&between);
            let parts = [
                ("means", &got.means, &want.means),
                ("quats", &got.quats, &want.quats),
                ("scales", &got.scales, &want.scales),
                ("opacities", &got.opacities, &want.opacities),
                ("features", &got.features, &want.features),
                ("means2d", &got.means2d, &want.means2d),
            ];
            for (name, a, b) in parts {
                let diff: f64 = (a.iter().zip(b))
                    .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
                    .sum();
                let norm: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
                let err = (diff / norm).sqrt();
                // Float atomics sum in no fixed order: equal up to rounding (~1e-8 measured).
                assert!(err < 1e-5, "{case}: d{name} relative error {err}");
            }
        }
    }
}
