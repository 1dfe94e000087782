//! Encoding of the forward passes: project -> depth sort -> tile lists -> tile sort -> ranges ->
//! rasterize, then the single readback of a render.

use super::buffers::{Buffers, SORT_BLOCK};
use super::inputs::Band;
use super::readback::ForwardRead;
use super::record::{dispatch, dispatch_indirect, Recorder};
use super::state::State;
use super::{binds, readback, Camera, Gaussians, Params, PassTimes, TILE};
use crate::context::{dispatch_dims, GpuContext, GpuError};
use crate::host;
use crate::wgsl::MAX_DIGITS;
use crate::{Kernel, ScanScratch};

/// The depth sort: 4 radix passes of 8-bit digits over the 32-bit keys (an even count: the
/// sorted ids end in the first ping-pong buffer). A stable LSD sort orders the same at any digit
/// width, and on small scenes a pass costs much the same at 4 and 8 bits (its dispatches, not
/// its keys): 4 passes instead of 8 saved ~0.7 ms a render at 96x96 on lavapipe (7ca0e26, 2026-11-26).
pub const DEPTH_PASSES: usize = 4;
pub const DEPTH_BITS: u32 = 8;
/// The tile sort's widest digit (MAX_DIGITS in sort.wgsl) and its most passes (32-bit ids).
const TILE_MAX_BITS: u32 = 8;
pub const TILE_MAX_PASSES: usize = 4;
const _: () =
    assert!(1 << TILE_MAX_BITS <= MAX_DIGITS && TILE_MAX_PASSES as u32 * TILE_MAX_BITS >= 32);
/// Scans per render: one for the tile counts, one per radix pass.
pub const SCANS: usize = 1 + DEPTH_PASSES + TILE_MAX_PASSES;
/// Smallest tile-intersection capacity (16 sort blocks), and the step it grows and shrinks by.
pub const MIN_ISECT_CAP: u64 = 1 << 12;

/// The tile sort's passes and digit width for tile ids below `tiles`: as few passes as digits of
/// up to 8 bits allow, each digit as narrow as that count allows (a pass costs about the same at
/// any width, but its histogram scan grows with the digit count). 8x8 tiles at 512^2 have 12-bit
/// ids: 2 passes of 6 bits; at 96^2 (144 tiles) one pass of 8.
pub fn tile_digits(tiles: u32) -> (usize, u32) {
    let bits = if tiles <= 1 {
        0
    } else {
        32 - (tiles - 1).leading_zeros()
    };
    let passes = bits.div_ceil(TILE_MAX_BITS);
    (
        passes as usize,
        if passes == 0 {
            0
        } else {
            bits.div_ceil(passes)
        },
    )
}

/// The radix passes of one sort. The depth sort runs over all `elements`; the tile sort only
/// over the live tile keys, with the block counts emit_keys.wgsl wrote into `live` (its
/// histogram keeps the capacity's layout, so the blocks not run are cleared to zero counts).
struct Sort<'a> {
    name: &'static str,
    /// Digit width of every pass.
    bits: u32,
    hist_binds: &'a [wgpu::BindGroup],
    scatter_binds: &'a [wgpu::BindGroup],
    elements: u64,
    live: Option<&'a wgpu::Buffer>,
}

impl Sort<'_> {
    fn encode(
        &self,
        ctx: &GpuContext,
        rec: &mut Recorder,
        b: &Buffers,
        scans: &mut [ScanScratch],
    ) -> Result<(), GpuError> {
        let hist = ctx.pipeline(Kernel::SortHistogram, 0);
        let scatter = ctx.pipeline(Kernel::SortScatter, 0);
        let blocks = self.elements.div_ceil(SORT_BLOCK) as u32;
        let digits = 1u32 << self.bits;
        let dims = dispatch_dims(blocks);
        let passes = (self.hist_binds.iter().zip(self.scatter_binds)).zip(scans.iter_mut());
        for ((hb, sb), scan) in passes {
            rec.step(self.name, |enc| {
                match self.live {
                    Some(args) => {
                        enc.clear_buffer(&b.hist.buf, 0, Some(4 * (digits * blocks) as u64));
                        dispatch_indirect(enc, &hist, hb, args);
                    }
                    None => dispatch(enc, &hist, hb, dims),
                }
                scan.encode(ctx, enc, &b.hist.buf, digits * blocks);
                match self.live {
                    Some(args) => dispatch_indirect(enc, &scatter, sb, args),
                    None => dispatch(enc, &scatter, sb, dims),
                }
            })?;
        }
        Ok(())
    }
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
    let State {
        bufs: b,
        binds: cached,
        sort_passes,
        scans,
        isect_cap,
        ..
    } = st;
    let binds = cached.get_or_insert_with(|| binds::Forward::new(ctx, b, sort_passes, p.d));
    let n = p.n;
    let tiles = p.tiles_x * p.tiles_y;
    let (t_passes, t_bits) = tile_digits(tiles);
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
        let depth = Sort {
            name: "sort depth",
            bits: DEPTH_BITS,
            hist_binds: &binds.depth_hist,
            scatter_binds: &binds.depth_scatter,
            elements: n as u64,
            live: None,
        };
        depth.encode(ctx, rec, b, depth_scans)?;
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
        let tile = Sort {
            name: "sort tiles",
            bits: t_bits,
            hist_binds: &binds.tile_hist[..t_passes],
            scatter_binds: &binds.tile_scatter[..t_passes],
            elements: *isect_cap,
            live: Some(&b.live_blocks),
        };
        tile.encode(ctx, rec, b, tile_scans)?;
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
    let kernel = if count_work {
        Kernel::RasterizeFwdCount
    } else {
        Kernel::RasterizeFwd
    };
    let groups = binds.raster(ctx, b, count_work, p.d);
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

/// Write `g` into the upload buffer and record its copy into the inputs buffer (first in `rec`).
pub fn upload_inputs(
    ctx: &GpuContext,
    st: &State,
    g: &Gaussians,
    rec: &mut Recorder,
) -> Result<(), GpuError> {
    let b = &st.bufs;
    let bytes = host::time("write inputs", || b.upload.write(ctx, &g.parts()))?;
    rec.enc
        .copy_buffer_to_buffer(&b.upload.buf, 0, &b.inputs.buf, 0, bytes);
    Ok(())
}

/// The intersection capacity for `m` tile pairs: 1.5x headroom in steps of MIN_ISECT_CAP (not a
/// power of two: up to 4x the count, which the histogram scans paid for at every render).
fn isect_capacity(m: u32) -> u64 {
    (m as u64 + m as u64 / 2)
        .next_multiple_of(MIN_ISECT_CAP)
        .max(MIN_ISECT_CAP)
}

/// Grow `st`'s intersection capacity to hold `pairs` tile pairs (at most the binding limit's):
/// after an overflow in `read`, and before a render done again without a readback (the pairs
/// it had when it was read back).
pub fn reserve(ctx: &GpuContext, st: &mut State, pairs: u32) {
    if pairs as u64 > st.isect_cap {
        st.isect_cap = isect_capacity(pairs).min(ctx.binding_limit() / 4);
    }
}

/// A band of a forward render submitted to the device and not yet read back.
#[derive(Debug)]
pub struct Submitted {
    layout: readback::ForwardLayout,
    index: wgpu::SubmissionIndex,
}

/// Encode the render of `band` of `cam`'s image of `g` into `st` as render `id` and submit it
/// without waiting (`read` takes its outputs, with the projected Gaussians when `with_proj`).
/// Errors with `GpuError::OverLimit` when a buffer would exceed the binding limit.
#[allow(clippy::too_many_arguments)]
pub fn submit(
    ctx: &GpuContext,
    st: &mut State,
    g: &Gaussians,
    cam: &Camera,
    band: Band,
    profile: Option<&mut PassTimes>,
    count_work: bool,
    with_proj: bool,
) -> Result<Submitted, GpuError> {
    let (n, d) = (g.len(), g.d);
    // The state's per-pixel buffers are this render's from here on, even if it fails.
    st.current = None;
    st.isect_cap = st.isect_cap.min(ctx.binding_limit() / 4);
    let p = host::time("prepare buffers", || st.prepare(ctx, n, d, cam, band))?;
    let mut rec = Recorder::new(ctx, profile);
    upload_inputs(ctx, st, g, &mut rec)?;
    host::time("encode", || encode(ctx, st, &p, &mut rec, count_work))?;
    let pixels = band.pixels(cam.width).0;
    let layout = readback::copy_forward(&mut rec, &st.bufs, (n, d), pixels, with_proj);
    Ok(Submitted {
        layout,
        index: rec.submit(&st.bufs),
    })
}

/// Wait for the band `s` that `submit` sent as render `id` and read it back; None when its
/// tile pairs overflowed the intersection capacity (grown now: submit it again). Errors with
/// `GpuError::OverLimit` when they exceed the binding limit (then a smaller band may fit).
pub fn read(
    ctx: &GpuContext,
    st: &mut State,
    s: Submitted,
    band: Band,
    id: u64,
) -> Result<Option<ForwardRead>, GpuError> {
    let read = readback::read_forward(ctx, &st.bufs, s.layout, s.index)?;
    let m = read.intersections();
    if read.tiles_disagree() {
        return Err(GpuError::Invalid(
            "rasterize: the tile count and tile key passes disagree on which tiles a \
             Gaussian reaches (a shader compiler broke their shared test); please report it \
             with the adapter's name"
                .into(),
        ));
    }
    let max_cap = ctx.binding_limit() / 4;
    if m as u64 > st.isect_cap {
        if m as u64 > max_cap {
            return Err(GpuError::OverLimit(format!(
                "rasterize: {m} tile pairs in rows {}.. need {} bytes, over the {}-byte \
                 storage binding limit",
                band.ty0 * TILE,
                4 * m as u64,
                4 * max_cap
            )));
        }
        // Render again with room for every intersection (rare: the capacity follows the
        // counts of earlier renders).
        reserve(ctx, st, m);
        return Ok(None);
    }
    // The tile sort's histograms are laid out, cleared and scanned over the whole capacity:
    // size the next render's capacity to this one's count (shrinking only when 4x too large,
    // so renders of different sizes do not alternate between overflow and re-render).
    let want = isect_capacity(m);
    if 4 * want <= st.isect_cap {
        st.isect_cap = want;
    }
    st.current = Some(id);
    Ok(Some(read))
}

/// Render `band` of `cam`'s image of `g` into `st` as render `id` and read its outputs back (the
/// projected Gaussians too when `with_proj`), rendering again when the tile pairs overflowed.
#[allow(clippy::too_many_arguments)]
pub fn run(
    ctx: &GpuContext,
    st: &mut State,
    g: &Gaussians,
    cam: &Camera,
    band: Band,
    id: u64,
    mut profile: Option<&mut PassTimes>,
    count_work: bool,
    with_proj: bool,
) -> Result<ForwardRead, GpuError> {
    loop {
        let sent = submit(
            ctx,
            st,
            g,
            cam,
            band,
            profile.as_deref_mut(),
            count_work,
            with_proj,
        )?;
        if let Some(read) = self::read(ctx, st, sent, band, id)? {
            return Ok(read);
        }
    }
}
