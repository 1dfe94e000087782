//! Encoding of the forward passes and the single readback of a render.

use std::time::Instant;

use std::cell::OnceCell;

use super::buffers::{Buffers, COUNTER_WORDS, SORT_BLOCK};
use super::{Camera, ForwardOutput, Gaussians, Params, PassTimes, State, WorkCounts};
use crate::context::{dispatch_dims, GpuContext, GpuError};
use crate::wgsl::DIGITS;
use crate::{Kernel, ScanScratch};

/// Scans per render: one for the tile counts, up to 8 per radix sort (depth, tile).
pub const SCANS: usize = 17;
/// 4-bit radix passes over the 32-bit depth keys.
const DEPTH_PASSES: usize = 8;
/// Smallest tile-intersection capacity (16 sort blocks); the capacity follows the counts.
pub const MIN_ISECT_CAP: u64 = 1 << 12;

/// A bind group for `pipeline` with the given (binding, buffer) pairs.
pub fn bind(
    ctx: &GpuContext,
    pipeline: &wgpu::ComputePipeline,
    entries: &[(u32, &wgpu::Buffer)],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = entries
        .iter()
        .map(|(i, b)| wgpu::BindGroupEntry {
            binding: *i,
            resource: b.as_entire_binding(),
        })
        .collect();
    ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(0),
        entries: &entries,
    })
}

/// Encodes passes into one command encoder, or (profiling) submits and times each on its own.
pub struct Recorder<'a> {
    ctx: &'a GpuContext,
    pub enc: wgpu::CommandEncoder,
    profile: Option<&'a mut PassTimes>,
}

impl<'a> Recorder<'a> {
    pub fn new(ctx: &'a GpuContext, profile: Option<&'a mut PassTimes>) -> Self {
        Self {
            ctx,
            enc: ctx.device.create_command_encoder(&Default::default()),
            profile,
        }
    }

    pub fn step(
        &mut self,
        name: &'static str,
        f: impl FnOnce(&mut wgpu::CommandEncoder),
    ) -> Result<(), GpuError> {
        let start = Instant::now();
        f(&mut self.enc);
        if let Some(times) = self.profile.as_deref_mut() {
            let enc = std::mem::replace(
                &mut self.enc,
                self.ctx.device.create_command_encoder(&Default::default()),
            );
            self.ctx.queue.submit([enc.finish()]);
            self.ctx.wait()?;
            let dt = start.elapsed().as_secs_f64();
            match times.iter_mut().find(|(n, _)| *n == name) {
                Some((_, t)) => *t += dt,
                None => times.push((name, dt)),
            }
        }
        Ok(())
    }

    /// Submit the remaining work (and copies), wait, and map `bytes` of `staging`.
    pub fn finish(self, staging: &wgpu::Buffer, bytes: u64) -> Result<Vec<u8>, GpuError> {
        self.ctx.queue.submit([self.enc.finish()]);
        self.ctx.map_read(staging, bytes)
    }
}

pub fn dispatch(
    enc: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    group: &wgpu::BindGroup,
    dims: (u32, u32),
) {
    let mut pass = enc.begin_compute_pass(&Default::default());
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, group, &[]);
    pass.dispatch_workgroups(dims.0, dims.1, 1);
}

/// A dispatch whose workgroup counts a previous pass wrote into `args` (x, y, z).
fn dispatch_indirect(
    enc: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    group: &wgpu::BindGroup,
    args: &wgpu::Buffer,
) {
    let mut pass = enc.begin_compute_pass(&Default::default());
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, group, &[]);
    pass.dispatch_workgroups_indirect(args, 0);
}

/// Bind groups of the forward passes (rebuilt only after buffers grew).
pub struct Binds {
    project: wgpu::BindGroup,
    depth_hist: Vec<wgpu::BindGroup>,
    depth_scatter: Vec<wgpu::BindGroup>,
    count: wgpu::BindGroup,
    emit: wgpu::BindGroup,
    tile_hist: Vec<wgpu::BindGroup>,
    tile_scatter: Vec<wgpu::BindGroup>,
    /// Indexed by which ping-pong buffer holds the tile-sorted lists.
    ranges: [wgpu::BindGroup; 2],
    raster: [wgpu::BindGroup; 2],
    /// The counting build's, made on the first render that counts.
    raster_count: OnceCell<[wgpu::BindGroup; 2]>,
}

/// The compositing pass's bind groups (one per ping-pong buffer) for `raster_p`.
fn raster_binds(
    ctx: &GpuContext,
    b: &Buffers,
    raster_p: &wgpu::ComputePipeline,
) -> [wgpu::BindGroup; 2] {
    [0, 1].map(|k| {
        bind(
            ctx,
            raster_p,
            &[
                (0, &b.params),
                (1, &b.inputs.buf),
                (2, &b.proj.buf),
                (3, &b.tile_vals[k].buf),
                (4, &b.ranges.buf),
                (5, &b.image.buf),
                (6, &b.depth.buf),
                (7, &b.alpha.buf),
                (8, &b.aux.buf),
                (9, &b.counters.buf),
            ],
        )
    })
}

fn sort_binds(
    ctx: &GpuContext,
    b: &Buffers,
    passes: &[wgpu::Buffer],
    keys: &[super::buffers::Grow; 2],
    vals: &[super::buffers::Grow; 2],
) -> (Vec<wgpu::BindGroup>, Vec<wgpu::BindGroup>) {
    let hist = ctx.pipeline(Kernel::SortHistogram, 0);
    let scatter = ctx.pipeline(Kernel::SortScatter, 0);
    let mut hs = Vec::new();
    let mut ss = Vec::new();
    for (p, uniform) in passes.iter().enumerate() {
        let (src, dst) = (p % 2, 1 - p % 2);
        hs.push(bind(
            ctx,
            &hist,
            &[
                (0, &b.params),
                (1, uniform),
                (2, &b.counters.buf),
                (3, &keys[src].buf),
                (4, &b.hist.buf),
            ],
        ));
        ss.push(bind(
            ctx,
            &scatter,
            &[
                (0, &b.params),
                (1, uniform),
                (2, &b.counters.buf),
                (3, &keys[src].buf),
                (4, &b.hist.buf),
                (5, &vals[src].buf),
                (6, &keys[dst].buf),
                (7, &vals[dst].buf),
            ],
        ));
    }
    (hs, ss)
}

impl Binds {
    fn new(ctx: &GpuContext, b: &Buffers, sort_passes: &[wgpu::Buffer], d: u32) -> Self {
        let project = bind(
            ctx,
            &ctx.pipeline(Kernel::Project, d),
            &[
                (0, &b.params),
                (1, &b.inputs.buf),
                (2, &b.proj.buf),
                (3, &b.depth_keys[0].buf),
                (4, &b.depth_vals[0].buf),
            ],
        );
        let (depth_hist, depth_scatter) =
            sort_binds(ctx, b, &sort_passes[..8], &b.depth_keys, &b.depth_vals);
        let (tile_hist, tile_scatter) =
            sort_binds(ctx, b, &sort_passes[8..], &b.tile_keys, &b.tile_vals);
        // DEPTH_PASSES is even: the depth-sorted ids end in depth_vals[0].
        let count = bind(
            ctx,
            &ctx.pipeline(Kernel::CountTiles, d),
            &[
                (0, &b.params),
                (1, &b.proj.buf),
                (2, &b.depth_vals[0].buf),
                (3, &b.offsets.buf),
            ],
        );
        let emit = bind(
            ctx,
            &ctx.pipeline(Kernel::EmitKeys, d),
            &[
                (0, &b.params),
                (1, &b.proj.buf),
                (2, &b.depth_vals[0].buf),
                (3, &b.offsets.buf),
                (4, &b.tile_keys[0].buf),
                (5, &b.tile_vals[0].buf),
                (6, &b.counters.buf),
                (7, &b.live_blocks),
            ],
        );
        let ranges_p = ctx.pipeline(Kernel::TileRanges, d);
        let raster_p = ctx.pipeline(Kernel::RasterizeFwd, d);
        let ranges = [0, 1].map(|k| {
            bind(
                ctx,
                &ranges_p,
                &[
                    (0, &b.params),
                    (1, &b.counters.buf),
                    (2, &b.tile_keys[k].buf),
                    (3, &b.ranges.buf),
                ],
            )
        });
        let raster = raster_binds(ctx, b, &raster_p);
        Self {
            project,
            depth_hist,
            depth_scatter,
            count,
            emit,
            tile_hist,
            tile_scatter,
            ranges,
            raster,
            raster_count: OnceCell::new(),
        }
    }
}

/// Radix passes needed for tile ids below `tiles`.
pub fn tile_passes(tiles: u32) -> usize {
    let bits = if tiles <= 1 {
        0
    } else {
        32 - (tiles - 1).leading_zeros()
    };
    bits.div_ceil(4) as usize
}

/// The radix passes of one sort. The depth sort runs over all `elements`; the tile sort only
/// over the live tile keys, with the block counts emit_keys.wgsl wrote into `live` (its
/// histogram keeps the capacity's layout, so the blocks not run are cleared to zero counts).
#[allow(clippy::too_many_arguments)]
fn encode_sort(
    ctx: &GpuContext,
    rec: &mut Recorder,
    name: &'static str,
    b: &Buffers,
    hist_binds: &[wgpu::BindGroup],
    scatter_binds: &[wgpu::BindGroup],
    scans: &mut [ScanScratch],
    elements: u64,
    live: Option<&wgpu::Buffer>,
) -> Result<(), GpuError> {
    let hist = ctx.pipeline(Kernel::SortHistogram, 0);
    let scatter = ctx.pipeline(Kernel::SortScatter, 0);
    let blocks = elements.div_ceil(SORT_BLOCK) as u32;
    let dims = dispatch_dims(blocks);
    for ((hb, sb), scan) in hist_binds.iter().zip(scatter_binds).zip(scans.iter_mut()) {
        rec.step(name, |enc| {
            match live {
                Some(args) => {
                    enc.clear_buffer(&b.hist.buf, 0, Some(4 * DIGITS as u64 * blocks as u64));
                    dispatch_indirect(enc, &hist, hb, args);
                }
                None => dispatch(enc, &hist, hb, dims),
            }
            scan.encode(ctx, enc, &b.hist.buf, DIGITS * blocks);
            match live {
                Some(args) => dispatch_indirect(enc, &scatter, sb, args),
                None => dispatch(enc, &scatter, sb, dims),
            }
        })?;
    }
    Ok(())
}

/// Encode the whole forward render (no readback); `count_work` picks the counting build of the
/// compositing pass.
pub fn encode(
    ctx: &GpuContext,
    st: &mut State,
    p: &Params,
    rec: &mut Recorder,
    count_work: bool,
) -> Result<(), GpuError> {
    if st.binds.is_none() {
        st.binds = Some(Binds::new(ctx, &st.bufs, &st.sort_passes, p.d));
    }
    let State {
        bufs: b,
        binds,
        scans,
        isect_cap,
        ..
    } = st;
    let Some(binds) = binds.as_ref() else {
        return Err(GpuError::Invalid("rasterize: bind groups missing".into()));
    };
    let n = p.n;
    let tiles = p.tiles_x * p.tiles_y;
    let t_passes = tile_passes(tiles);
    rec.step("clear", |enc| {
        enc.clear_buffer(&b.counters.buf, 0, None);
        enc.clear_buffer(&b.ranges.buf, 0, Some(8 * tiles as u64));
    })?;
    if n > 0 {
        rec.step("project", |enc| {
            dispatch(
                enc,
                &ctx.pipeline(Kernel::Project, p.d),
                &binds.project,
                Kernel::Project.groups_for(n),
            )
        })?;
        let (depth_scans, rest) = scans.split_at_mut(DEPTH_PASSES);
        encode_sort(
            ctx,
            rec,
            "sort depth",
            b,
            &binds.depth_hist,
            &binds.depth_scatter,
            depth_scans,
            n as u64,
            None,
        )?;
        let (count_scan, tile_scans) = rest.split_at_mut(1);
        rec.step("tiles: count, scan, emit", |enc| {
            // n + 1 counts (the last is 0), so the scan leaves every Gaussian's end and the total.
            dispatch(
                enc,
                &ctx.pipeline(Kernel::CountTiles, p.d),
                &binds.count,
                Kernel::CountTiles.groups_for(n + 1),
            );
            count_scan[0].encode(ctx, enc, &b.offsets.buf, n + 1);
            dispatch(
                enc,
                &ctx.pipeline(Kernel::EmitKeys, p.d),
                &binds.emit,
                Kernel::EmitKeys.groups_for(n),
            );
        })?;
        encode_sort(
            ctx,
            rec,
            "sort tiles",
            b,
            &binds.tile_hist[..t_passes],
            &binds.tile_scatter[..t_passes],
            tile_scans,
            *isect_cap,
            Some(&b.live_blocks),
        )?;
        let sorted = t_passes % 2;
        rec.step("tile ranges", |enc| {
            dispatch_indirect(
                enc,
                &ctx.pipeline(Kernel::TileRanges, p.d),
                &binds.ranges[sorted],
                &b.live_blocks,
            )
        })?;
    }
    let sorted = t_passes % 2;
    let (kernel, groups) = if count_work {
        let counting = ctx.pipeline(Kernel::RasterizeFwdCount, p.d);
        let groups = binds
            .raster_count
            .get_or_init(|| raster_binds(ctx, b, &counting));
        (Kernel::RasterizeFwdCount, groups)
    } else {
        (Kernel::RasterizeFwd, &binds.raster)
    };
    rec.step("rasterize", |enc| {
        dispatch(
            enc,
            &ctx.pipeline(kernel, p.d),
            &groups[sorted],
            (p.tiles_x, p.tiles_y),
        )
    })?;
    Ok(())
}

fn floats(bytes: &[u8]) -> Vec<f32> {
    bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

pub fn run(
    ctx: &GpuContext,
    st: &mut State,
    g: &Gaussians,
    cam: &Camera,
    id: u64,
    mut profile: Option<&mut PassTimes>,
    count_work: bool,
) -> Result<ForwardOutput, GpuError> {
    let packed = g.pack();
    loop {
        let p = st.prepare(ctx, g, cam)?;
        ctx.queue
            .write_buffer(&st.bufs.inputs.buf, 0, bytemuck::cast_slice(&packed));
        let mut rec = Recorder::new(ctx, profile.as_deref_mut());
        encode(ctx, st, &p, &mut rec, count_work)?;
        let (n, d) = (g.len() as u64, g.d as u64);
        let pixels = cam.width as u64 * cam.height as u64;
        let b = &st.bufs;
        let parts: [(&wgpu::Buffer, u64); 5] = [
            (&b.image.buf, 4 * pixels * d),
            (&b.depth.buf, 4 * pixels),
            (&b.alpha.buf, 4 * pixels),
            (&b.proj.buf, 4 * 8 * n),
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
        let all = floats(&raw);
        let (pixels, n, d) = (pixels as usize, n as usize, d as usize);
        let counters: Vec<u32> =
            bytemuck::pod_collect_to_vec(&raw[raw.len() - 4 * COUNTER_WORDS as usize..]);
        let m = counters[0];
        if counters[1] != 0 {
            return Err(GpuError::Invalid(
                "rasterize: the tile count and tile key passes disagree on which tiles a \
                 Gaussian reaches (a shader compiler broke their shared test); please report it \
                 with the adapter's name"
                    .into(),
            ));
        }
        if m as u64 > st.isect_cap {
            // Render again with room for every intersection (rare: the capacity follows the
            // counts of earlier renders).
            st.isect_cap = (m as u64 + m as u64 / 2).next_power_of_two();
            continue;
        }
        // The tile sort and ranges dispatch over the whole capacity, and on lavapipe every
        // workgroup costs ~13 µs even with nothing live in it: size the next render's capacity
        // to this one's count (2x headroom, shrinking only when 8x too large, so renders of
        // different sizes do not alternate between overflow and re-render).
        let want = (2 * m as u64).next_power_of_two().max(MIN_ISECT_CAP);
        if 4 * want <= st.isect_cap {
            st.isect_cap = want;
        }
        let (image, rest) = all.split_at(pixels * d);
        let (depth, rest) = rest.split_at(pixels);
        let (alpha, rest) = rest.split_at(pixels);
        let proj = &rest[..8 * n];
        st.current = Some(id);
        return Ok(ForwardOutput {
            image: image.to_vec(),
            depth: depth.to_vec(),
            alpha: alpha.to_vec(),
            radii: proj.chunks_exact(8).map(|q| q[7] as i32).collect(),
            means2d: proj.chunks_exact(8).flat_map(|q| [q[0], q[1]]).collect(),
            depths: proj.chunks_exact(8).map(|q| q[3]).collect(),
            intersections: m,
            work: count_work.then(|| {
                let wide =
                    |k: usize| counters[2 + 2 * k] as u64 | (counters[3 + 2 * k] as u64) << 32;
                WorkCounts {
                    pairs: m as u64,
                    evaluated: wide(0),
                    contributed: wide(1),
                    saturated: wide(2),
                }
            }),
            id,
        });
    }
}
