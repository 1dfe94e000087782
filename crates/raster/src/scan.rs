//! GPU exclusive prefix sum over u32, used to turn per-Gaussian tile counts into offsets.

use crate::context::{dispatch_dims, GpuContext, GpuError};
use crate::kernels::Kernel;
use crate::wgsl::{ScanParams as Params, SCAN_BLOCK as BLOCK};

/// One level of the recursive scan: its block-sum buffer and uniform.
struct Level {
    sums: wgpu::Buffer,
    sums_cap: u32,
    params: wgpu::Buffer,
}

/// Scratch buffers for in-place scans; grows geometrically and is reused across calls.
/// Encode at most one scan per scratch per queue submission (the uniforms are shared).
#[derive(Default)]
pub struct ScanScratch {
    levels: Vec<Level>,
    /// (scan, add) bind groups per level, valid for `bound_to` until a level buffer changes.
    binds: Vec<(wgpu::BindGroup, wgpu::BindGroup)>,
    bound_to: Option<wgpu::Buffer>,
}

impl ScanScratch {
    fn level(&mut self, ctx: &GpuContext, index: usize, sums_needed: u32) -> &Level {
        while self.levels.len() <= index {
            self.binds.truncate(self.levels.len());
            self.levels.push(Level {
                sums: ctx.storage_buffer("scan sums", 4),
                sums_cap: 1,
                params: ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("scan params"),
                    size: std::mem::size_of::<Params>() as u64,
                    usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                }),
            });
        }
        let level = &mut self.levels[index];
        if level.sums_cap < sums_needed {
            let cap = sums_needed.next_power_of_two();
            level.sums = ctx.storage_buffer("scan sums", cap as u64 * 4);
            level.sums_cap = cap;
            // Levels `index` (output) and `index + 1` (input) bind this buffer.
            self.binds.truncate(index);
        }
        &self.levels[index]
    }

    /// Encode an in-place exclusive scan of the first `n` u32 of `data`.
    pub fn encode(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        data: &wgpu::Buffer,
        n: u32,
    ) {
        if n == 0 {
            return;
        }
        let scan = ctx.pipeline(Kernel::ScanBlocks, 0);
        let add = ctx.pipeline(Kernel::AddOffsets, 0);
        // Down-sweep: scan each level's blocks, collecting block totals into the next level.
        let mut sizes = vec![n];
        let mut groups = Vec::new();
        loop {
            let count = *sizes.last().unwrap_or(&0);
            let blocks = count.div_ceil(BLOCK);
            let level = self.level(ctx, groups.len(), blocks);
            let params = Params {
                n: count,
                num_blocks: blocks,
                _pad0: 0,
                _pad1: 0,
            };
            ctx.queue
                .write_buffer(&level.params, 0, bytemuck::bytes_of(&params));
            groups.push(blocks);
            if blocks == 1 {
                break;
            }
            sizes.push(blocks);
        }
        // Bind groups are built only when the data buffer or a level buffer changed.
        if self.bound_to.as_ref() != Some(data) {
            self.binds.clear();
            self.bound_to = Some(data.clone());
        }
        while self.binds.len() < groups.len() {
            let i = self.binds.len();
            let input = if i == 0 {
                data
            } else {
                &self.levels[i - 1].sums
            };
            let level = &self.levels[i];
            let (bs, ps) = (&level.sums, &level.params);
            let bind_scan = ctx.bind_buffers(&scan, &[input, bs, ps]);
            let bind_add = ctx.bind_buffers(&add, &[input, bs, ps]);
            self.binds.push((bind_scan, bind_add));
        }
        let binds: Vec<_> = self
            .binds
            .iter()
            .zip(&groups)
            .map(|((s, a), &g)| (s, a, g))
            .collect();
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("scan"),
            timestamp_writes: None,
        });
        pass.set_pipeline(&scan);
        for &(bind_scan, _, blocks) in &binds {
            let (x, y) = dispatch_dims(blocks);
            pass.set_bind_group(0, bind_scan, &[]);
            pass.dispatch_workgroups(x, y, 1);
        }
        // Up-sweep: add each level's scanned block totals back into the level below.
        pass.set_pipeline(&add);
        for &(_, bind_add, blocks) in binds.iter().rev().skip(1) {
            let (x, y) = dispatch_dims(blocks);
            pass.set_bind_group(0, bind_add, &[]);
            pass.dispatch_workgroups(x, y, 1);
        }
    }
}

/// Exclusive scan of `values` on the GPU (upload, scan, download). Wraps on u32 overflow.
pub fn exclusive_scan_u32(ctx: &GpuContext, values: &[u32]) -> Result<Vec<u32>, GpuError> {
    if values.is_empty() {
        return Ok(Vec::new());
    }
    let n = u32::try_from(values.len())
        .map_err(|_| GpuError::Invalid(format!("scan of {} values exceeds u32", values.len())))?;
    let bytes = values.len() as u64 * 4;
    let max = ctx.limits.max_storage_buffer_binding_size;
    if bytes > max {
        return Err(GpuError::Invalid(format!(
            "scan of {} values ({bytes} bytes) exceeds the adapter's storage binding limit of {max} bytes",
            values.len()
        )));
    }
    let data = ctx.storage_buffer("scan data", bytes);
    ctx.queue
        .write_buffer(&data, 0, bytemuck::cast_slice(values));
    let mut scratch = ScanScratch::default();
    let mut enc = ctx.device.create_command_encoder(&Default::default());
    scratch.encode(ctx, &mut enc, &data, n);
    ctx.queue.submit([enc.finish()]);
    let out = ctx.read_buffer(&data, bytes)?;
    Ok(bytemuck::cast_slice(&out).to_vec())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cpu_scan(v: &[u32]) -> Vec<u32> {
        let mut acc = 0u32;
        v.iter()
            .map(|&x| {
                let out = acc;
                acc = acc.wrapping_add(x);
                out
            })
            .collect()
    }

    #[test]
    fn gpu_scan_matches_cpu_scan_for_edge_sizes() {
        let ctx = GpuContext::global().expect("a Vulkan adapter (lavapipe in CI) is required");
        let mut state = 0x2545_f491_4f6c_dd1du64;
        for &n in &[0usize, 1, 255, 256, 257, 65_537, 1_000_003] {
            let v: Vec<u32> = (0..n)
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    (state % 1000) as u32
                })
                .collect();
            assert_eq!(
                exclusive_scan_u32(ctx, &v).unwrap(),
                cpu_scan(&v),
                "n = {n}"
            );
        }
    }

    #[test]
    fn one_scratch_reused_across_sizes_and_buffers_matches_cpu_scan() {
        let ctx = GpuContext::global().expect("a Vulkan adapter (lavapipe in CI) is required");
        let mut scratch = ScanScratch::default();
        let small = ctx.storage_buffer("a", 4 * 1_000_003);
        let other = ctx.storage_buffer("b", 4 * 1_000_003);
        // Growing levels, switching buffers and repeating a buffer all reuse or rebuild binds.
        for (n, buf) in [
            (300, &small),
            (70_000, &small),
            (10, &other),
            (1_000_003, &other),
            (300, &small),
        ] {
            let v: Vec<u32> = (0..n as u32)
                .map(|i| i.wrapping_mul(2_654_435_761) % 977)
                .collect();
            ctx.queue.write_buffer(buf, 0, bytemuck::cast_slice(&v));
            let mut enc = ctx.device.create_command_encoder(&Default::default());
            scratch.encode(ctx, &mut enc, buf, n as u32);
            ctx.queue.submit([enc.finish()]);
            let out = ctx.read_buffer(buf, n as u64 * 4).unwrap();
            assert_eq!(
                bytemuck::cast_slice::<u8, u32>(&out),
                &cpu_scan(&v)[..],
                "n = {n}"
            );
        }
    }

    #[test]
    fn gpu_scan_wraps_like_cpu_on_overflow() {
        let ctx = GpuContext::global().expect("a Vulkan adapter (lavapipe in CI) is required");
        let v = vec![u32::MAX / 2; 600];
        assert_eq!(exclusive_scan_u32(ctx, &v).unwrap(), cpu_scan(&v));
    }
}
