//! The per-process render states: each holds the buffers, bind groups and sort scratch of one
//! render whose per-pixel state a backward pass may still need.

use std::collections::HashMap;
use std::sync::{Mutex, MutexGuard, OnceLock};

use super::buffers::{Buffers, Sizes};
use super::inputs::{params, Band, Camera};
use super::{binds, forward};
use crate::context::{GpuContext, GpuError};
use crate::wgsl::{self, Params};
use crate::Kernel;
use crate::ScanScratch;

pub struct State {
    pub bufs: Buffers,
    /// Intersection capacity (grows when a render overflows it, shrinks when far too large).
    pub isect_cap: u64,
    sizes: Option<Sizes>,
    pub binds: Option<binds::Forward>,
    /// Keyed by the backward compositing kernel (atomics mode, subgroup sums or not).
    pub bwd_binds: HashMap<Kernel, binds::Backward>,
    pub sort_passes: Vec<wgpu::Buffer>,
    pub scans: Vec<ScanScratch>,
    /// The render whose per-pixel state is in the buffers.
    pub current: Option<u64>,
    /// Pool clock of the last use, for least-recently-used reuse.
    used: u64,
    /// The render here was differentiated already: its state is not needed again.
    pub spent: bool,
    /// A render submitted here and not read back yet (`rasterize_submit`): no other render may
    /// take these buffers until it is.
    pub pending: Option<u64>,
}

/// Renders whose per-pixel state a backward pass may still need each keep their own buffers,
/// up to this many: a training step renders two or three views and differentiates them in
/// reverse order, which with one set of buffers would re-render every view but the last. (More
/// only while more renders are submitted and not read back at once.)
const STATES: usize = 3;

/// The per-process states and the render-id counter.
pub struct Pool {
    states: Vec<State>,
    next_id: u64,
    clock: u64,
}

impl Pool {
    /// A fresh render id and the state for that render with `d` channels: a spent one of the same
    /// width first, then any spent one, a new one while the pool has room, else the least
    /// recently used; never one with a render waiting to be read back (a new one instead).
    pub fn for_forward(&mut self, ctx: &GpuContext, d: u64) -> (u64, &mut State) {
        let id = self.next_id;
        self.next_id += 1;
        let same_d = |s: &State| s.sizes.is_some_and(|z| z.d == d);
        let free = |s: &State| s.pending.is_none();
        let pick = (self.states.iter())
            .position(|s| free(s) && s.spent && same_d(s))
            .or_else(|| self.states.iter().position(|s| free(s) && s.spent));
        let i = match pick {
            Some(i) => i,
            None if self.states.len() < STATES => self.add(ctx),
            None => self.least_recent().unwrap_or_else(|| self.add(ctx)),
        };
        let st = self.touch(i);
        st.spent = false;
        (id, st)
    }

    /// The state holding render `id`, else (it was evicted) the least recently used one that no
    /// submitted render is waiting in.
    pub fn for_backward(&mut self, ctx: &GpuContext, id: u64) -> &mut State {
        let i = (self.states.iter().position(|s| s.current == Some(id)))
            .or_else(|| self.least_recent())
            .unwrap_or_else(|| self.add(ctx));
        let st = self.touch(i);
        st.spent = true;
        st
    }

    /// The state render `id` was submitted to and not read back from yet.
    pub fn for_pending(&mut self, id: u64) -> Option<&mut State> {
        let i = self.states.iter().position(|s| s.pending == Some(id))?;
        Some(self.touch(i))
    }

    fn least_recent(&self) -> Option<usize> {
        (0..self.states.len())
            .filter(|&i| self.states[i].pending.is_none())
            .min_by_key(|&i| self.states[i].used)
    }

    fn add(&mut self, ctx: &GpuContext) -> usize {
        self.states.push(State::new(ctx));
        self.states.len() - 1
    }

    fn touch(&mut self, i: usize) -> &mut State {
        self.clock += 1;
        let st = &mut self.states[i];
        st.used = self.clock;
        st
    }
}

/// The pool, locked (a panic in an earlier holder does not stop later renders).
pub fn lock() -> MutexGuard<'static, Pool> {
    static POOL: OnceLock<Mutex<Pool>> = OnceLock::new();
    let pool = POOL.get_or_init(|| {
        Mutex::new(Pool {
            states: Vec::new(),
            next_id: 1,
            clock: 0,
        })
    });
    pool.lock().unwrap_or_else(|p| p.into_inner())
}

impl State {
    fn new(ctx: &GpuContext) -> Self {
        // The depth sort's passes are fixed; the tile sort's are written by `prepare`, as its
        // digits depend on the tile count.
        let sort_passes = (0..forward::DEPTH_PASSES + forward::TILE_MAX_PASSES)
            .map(|p| {
                let b = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("sort pass"),
                    size: std::mem::size_of::<wgsl::SortPass>() as u64,
                    usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                });
                if p < forward::DEPTH_PASSES {
                    let pass = sort_pass(p, forward::DEPTH_BITS, 0);
                    ctx.queue.write_buffer(&b, 0, bytemuck::bytes_of(&pass));
                }
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
                .map(|_| ScanScratch::default())
                .collect(),
            current: None,
            used: 0,
            spent: false,
            pending: None,
        }
    }

    /// Grow buffers for a render of `n` Gaussians with `d` channels and drop bind groups that
    /// point at replaced buffers; writes and returns the uniforms of the render of `band`.
    pub fn prepare(
        &mut self,
        ctx: &GpuContext,
        n: usize,
        d: usize,
        cam: &Camera,
        band: Band,
    ) -> Result<Params, GpuError> {
        let p = params(n, d, cam, band, self.isect_cap);
        let tiles = p.tiles_x * p.tiles_y;
        let sizes = Sizes {
            n: n as u64,
            d: d as u64,
            pixels: p.width as u64 * p.height as u64,
            tiles: tiles as u64,
            isect: self.isect_cap,
        };
        let d_changed = self.sizes.is_some_and(|old| old.d != sizes.d);
        // Over the binding limit, some buffers may have been replaced before the error.
        let grown = self.bufs.ensure(ctx, sizes);
        if !matches!(grown, Ok(false)) || d_changed {
            self.binds = None;
            self.bwd_binds.clear();
        }
        grown?;
        if self.sizes.is_none_or(|old| old.tiles != sizes.tiles) {
            let (passes, bits) = forward::tile_digits(tiles);
            for p in 0..passes {
                let pass = sort_pass(p, bits, 1);
                let buf = &self.sort_passes[forward::DEPTH_PASSES + p];
                ctx.queue.write_buffer(buf, 0, bytemuck::bytes_of(&pass));
            }
        }
        self.sizes = Some(sizes);
        ctx.queue
            .write_buffer(&self.bufs.params, 0, bytemuck::bytes_of(&p));
        Ok(p)
    }
}

/// Radix pass `p` over digits of `bits` bits of the depth keys (`which` 0) or tile keys (1).
fn sort_pass(p: usize, bits: u32, which: u32) -> wgsl::SortPass {
    wgsl::SortPass {
        shift: p as u32 * bits,
        bits,
        which,
        _pad: 0,
    }
}
