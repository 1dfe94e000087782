//! Encoding of the backward passes: rasterize_bwd (atomics) then project_bwd, one readback.

use super::binds::{self, raster_bwd_kernel};
use super::buffers::GRAD_HEAD;
use super::inputs::Band;
use super::record::{dispatch, Recorder};
use super::state::State;
use super::{forward, readback, Gradients, OutputGrads, PassTimes, Render};
use crate::context::{AtomicMode, GpuContext, GpuError};
use crate::host;
use crate::Kernel;

/// Differentiate band `band` of `render`, rendered as `id`, in `st` (`grads`: the band's rows),
/// rendering it again first when another render replaced its per-pixel state there.
pub fn run(
    ctx: &GpuContext,
    st: &mut State,
    render: &Render,
    (id, band): (u64, Band),
    grads: &OutputGrads,
    mode: AtomicMode,
    profile: Option<&mut PassTimes>,
) -> Result<Gradients, GpuError> {
    let p = host::time("prepare buffers", || {
        st.prepare(ctx, render.n, render.d, &render.cam, band)
    })?;
    let mut rec = Recorder::new(ctx, profile);
    if st.current != Some(id) {
        // Render it again (no readback).
        host::time("write inputs", || {
            let bytes = bytemuck::cast_slice(&render.inputs);
            ctx.queue.write_buffer(&st.bufs.inputs.buf, 0, bytes)
        });
        host::time("encode", || forward::encode(ctx, st, &p, &mut rec, false))?;
        st.current = Some(id);
    }
    // The three output gradients lie back to back in `grad_in`: each is written at its offset
    // (no host-side copy into one packed vector).
    host::time("write output gradients", || {
        let mut offset = 0;
        for part in [grads.image, grads.depth, grads.alpha] {
            let bytes: &[u8] = bytemuck::cast_slice(part);
            ctx.queue.write_buffer(&st.bufs.grad_in.buf, offset, bytes);
            offset += bytes.len() as u64;
        }
    });
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
