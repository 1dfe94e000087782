//! Encoding of the backward passes: rasterize_bwd (atomics) then project_bwd, one readback.

use super::binds::{self, raster_bwd_kernel};
use super::buffers::GRAD_HEAD;
use super::inputs::Band;
use super::record::{dispatch, Recorder};
use super::state::State;
use super::{forward, readback, Gaussians, Gradients, OutputGrads, PassTimes, Render};
use crate::context::{AtomicMode, GpuContext, GpuError};
use crate::host;
use crate::Kernel;

/// Differentiate band `band` of `render` (of inputs `g`), rendered as `id` with `pairs` tile
/// pairs, in `st` (`grads`: the band's rows), rendering it again first when another render
/// replaced its per-pixel state there.
pub fn run(
    ctx: &GpuContext,
    st: &mut State,
    (render, g): (&Render, &Gaussians),
    (id, band, pairs): (u64, Band, u32),
    grads: &OutputGrads,
    mode: AtomicMode,
    profile: Option<&mut PassTimes>,
) -> Result<Gradients, GpuError> {
    let rerender = st.current != Some(id);
    if rerender {
        // The state may last have held a render with fewer tile pairs: without room for all of
        // this band's, emit_keys would drop the excess and the lists would differ from the
        // forward's (a re-render reads no counters back to notice).
        forward::reserve(ctx, st, pairs);
    }
    let p = host::time("prepare buffers", || {
        st.prepare(ctx, render.n, render.d, &render.cam, band)
    })?;
    let mut rec = Recorder::new(ctx, profile);
    // One upload: the inputs when the render must be redone, then the three output gradients,
    // back to back as they lie in `grad_in`.
    let mut parts = Vec::with_capacity(9);
    if rerender {
        parts.extend(g.parts());
    }
    parts.extend([grads.image, grads.depth, grads.alpha]);
    let b = &st.bufs;
    let bytes = host::time("write output gradients", || b.upload.write(ctx, &parts))?;
    let out_bytes = 4 * (grads.image.len() + grads.depth.len() + grads.alpha.len()) as u64;
    let input_bytes = bytes - out_bytes;
    if input_bytes > 0 {
        (rec.enc).copy_buffer_to_buffer(&b.upload.buf, 0, &b.inputs.buf, 0, input_bytes);
    }
    (rec.enc).copy_buffer_to_buffer(&b.upload.buf, input_bytes, &b.grad_in.buf, 0, out_bytes);
    if rerender {
        // Render it again (no readback).
        host::time("encode", || forward::encode(ctx, st, &p, &mut rec, false))?;
        st.current = Some(id);
    }
    let b = &st.bufs;
    let kernel = raster_bwd_kernel(mode, ctx.subgroup_reduce());
    let binds = (st.bwd_binds)
        .entry(kernel)
        .or_insert_with(|| binds::Backward::new(ctx, b, kernel, p.d));
    let n = render.n as u64;
    let grad_bytes = 4 * n * (GRAD_HEAD + render.d as u64);
    let sorted = forward::tile_digits(p.tiles_x * p.tiles_y).0 % 2;
    rec.step("backward rasterize", |enc| {
        if grad_bytes > 0 {
            enc.clear_buffer(&b.grads.buf, 0, Some(grad_bytes));
        }
        dispatch(
            enc,
            &ctx.pipeline(kernel, p.d),
            &binds.raster[sorted],
            (p.tiles_x, p.tiles_y),
        );
    })?;
    if n > 0 {
        rec.step("backward project", |enc| {
            dispatch(
                enc,
                &ctx.pipeline(Kernel::ProjectBwd, p.d),
                &binds.project,
                Kernel::ProjectBwd.groups_for(n as u32),
            )
        })?;
    }
    readback::gradients(rec, b, render.n, render.d)
}
