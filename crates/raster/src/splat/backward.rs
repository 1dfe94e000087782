//! Encoding of the backward passes: rasterize_bwd (atomics) then project_bwd, one readback.

use super::buffers::{Buffers, GRAD_HEAD, PARAM_GRADS};
use super::forward::{bind, dispatch, Recorder};
use super::{forward, Camera, Gaussians, Gradients, PassTimes, State};
use crate::context::{AtomicMode, GpuContext, GpuError};
use crate::Kernel;

pub struct Binds {
    raster: [wgpu::BindGroup; 2],
    project: wgpu::BindGroup,
}

fn raster_kernel(mode: AtomicMode) -> Kernel {
    match mode {
        AtomicMode::Float => Kernel::RasterizeBwd,
        AtomicMode::Cas => Kernel::RasterizeBwdCas,
    }
}

impl Binds {
    fn new(ctx: &GpuContext, b: &Buffers, mode: AtomicMode, d: u32) -> Self {
        let raster_p = ctx.pipeline(raster_kernel(mode), d);
        let raster = [0, 1].map(|k| {
            bind(
                ctx,
                &raster_p,
                &[
                    (0, &b.params),
                    (1, &b.inputs.buf),
                    (2, &b.proj.buf),
                    (3, &b.tile_vals[k].buf),
                    (4, &b.ranges.buf),
                    (5, &b.aux.buf),
                    (6, &b.grad_in.buf),
                    (7, &b.grads.buf),
                ],
            )
        });
        let project = bind(
            ctx,
            &ctx.pipeline(Kernel::ProjectBwd, d),
            &[
                (0, &b.params),
                (1, &b.inputs.buf),
                (2, &b.grads.buf),
                (3, &b.param_grads.buf),
            ],
        );
        Self { raster, project }
    }
}

#[allow(clippy::too_many_arguments)]
pub fn run(
    ctx: &GpuContext,
    st: &mut State,
    g: &Gaussians,
    cam: &Camera,
    id: u64,
    grad_out: [&[f32]; 3],
    mode: AtomicMode,
    profile: Option<&mut PassTimes>,
) -> Result<Gradients, GpuError> {
    let p = st.prepare(ctx, g, cam)?;
    let mut rec = Recorder::new(ctx, profile);
    if st.current != Some(id) {
        // Another render replaced this one's per-pixel state: render it again (no readback).
        ctx.queue
            .write_buffer(&st.bufs.inputs.buf, 0, bytemuck::cast_slice(&g.pack()));
        forward::encode(ctx, st, &p, &mut rec, false)?;
        st.current = Some(id);
    }
    let mut packed = Vec::with_capacity(grad_out.iter().map(|s| s.len()).sum());
    for part in grad_out {
        packed.extend_from_slice(part);
    }
    ctx.queue
        .write_buffer(&st.bufs.grad_in.buf, 0, bytemuck::cast_slice(&packed));
    let fp = matches!(mode, AtomicMode::Float);
    if !st.bwd_binds.contains_key(&fp) {
        st.bwd_binds
            .insert(fp, Binds::new(ctx, &st.bufs, mode, p.d));
    }
    let b = &st.bufs;
    let binds = st
        .bwd_binds
        .get(&fp)
        .ok_or_else(|| GpuError::Invalid("rasterize: backward bind groups missing".into()))?;
    let (n, d) = (g.len() as u64, g.d as u64);
    let grad_bytes = 4 * n * (GRAD_HEAD + d);
    let sorted = forward::tile_passes(p.tiles_x * p.tiles_y) % 2;
    rec.step("backward rasterize", |enc| {
        if grad_bytes > 0 {
            enc.clear_buffer(&b.grads.buf, 0, Some(grad_bytes));
        }
        dispatch(
            enc,
            &ctx.pipeline(raster_kernel(mode), p.d),
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
    let param_bytes = 4 * n * PARAM_GRADS;
    if n > 0 {
        rec.enc
            .copy_buffer_to_buffer(&b.grads.buf, 0, &b.staging, 0, grad_bytes);
        rec.enc
            .copy_buffer_to_buffer(&b.param_grads.buf, 0, &b.staging, grad_bytes, param_bytes);
    }
    let raw = rec.finish(&b.staging, grad_bytes + param_bytes)?;
    let all: Vec<f32> = bytemuck::pod_collect_to_vec(&raw);
    let (n, d) = (n as usize, d as usize);
    let stride = GRAD_HEAD as usize + d;
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
    Ok(out)
}
