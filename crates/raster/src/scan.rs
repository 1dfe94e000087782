//! GPU exclusive prefix sum over u32, used to turn per-Gaussian tile counts into offsets.

use crate::context::{dispatch_dims, GpuContext, GpuError};

const SOURCE: &str = include_str!(concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../shaders/scan.wgsl"
));
const BLOCK: u32 = 256;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    n: u32,
    num_blocks: u32,
    _pad: [u32; 2],
}

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
}

impl ScanScratch {
    fn level(&mut self, ctx: &GpuContext, index: usize, sums_needed: u32) -> &Level {
        while self.levels.len() <= index {
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
        let scan = ctx.pipeline("scan", SOURCE, "scan_blocks");
        let add = ctx.pipeline("scan", SOURCE, "add_offsets");
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
                _pad: [0; 2],
            };
            ctx.queue
                .write_buffer(&level.params, 0, bytemuck::bytes_of(&params));
            groups.push(blocks);
            if blocks == 1 {
                break;
            }
            sizes.push(blocks);
        }
        let buffer_at = |scratch: &ScanScratch, i: usize| -> wgpu::Buffer {
            if i == 0 {
                data.clone()
            } else {
                scratch.levels[i - 1].sums.clone()
            }
        };
        let mut binds = Vec::new();
        for (i, &blocks) in groups.iter().enumerate() {
            let input = buffer_at(self, i);
            let level = &self.levels[i];
            let (bs, ps) = (&level.sums, &level.params);
            let bind_scan = ctx.bind_buffers(&scan, &[&input, bs, ps]);
            let bind_add = ctx.bind_buffers(&add, &[&input, bs, ps]);
            binds.push((bind_scan, bind_add, blocks));
        }
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("scan"),
            timestamp_writes: None,
        });
        pass.set_pipeline(&scan);
        for (bind_scan, _, blocks) in &binds {
            let (x, y) = dispatch_dims(*blocks);
            pass.set_bind_group(0, bind_scan, &[]);
            pass.dispatch_workgroups(x, y, 1);
        }
        // Up-sweep: add each level's scanned block totals back into the level below.
        pass.set_pipeline(&add);
        for (_, bind_add, blocks) in binds.iter().rev().skip(1) {
            let (x, y) = dispatch_dims(*blocks);
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
    fn gpu_scan_wraps_like_cpu_on_overflow() {
        let ctx = GpuContext::global().expect("a Vulkan adapter (lavapipe in CI) is required");
        let v = vec![u32::MAX / 2; 600];
        assert_eq!(exclusive_scan_u32(ctx, &v).unwrap(), cpu_scan(&v));
    }
}
