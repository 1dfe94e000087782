//! Recording passes: one command encoder per render, or (profiling) one timed submission per pass.

use std::time::Instant;

use super::buffers::Buffers;
use super::PassTimes;
use crate::context::{GpuContext, GpuError};
use crate::host;

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

    /// Submit the remaining work (and copies) without waiting, and ask for `b`'s upload buffer
    /// to be mapped again for the next call once the copies out of it are done.
    pub fn submit(self, b: &Buffers) -> wgpu::SubmissionIndex {
        let ctx = self.ctx;
        let index = host::time("submit", || ctx.queue.submit([self.enc.finish()]));
        b.upload.remap();
        index
    }

    /// `submit`, wait, and hand the first `bytes` of `b`'s staging buffer to `read`.
    pub fn finish<T>(
        self,
        b: &Buffers,
        bytes: u64,
        read: impl FnOnce(&[u8]) -> T,
    ) -> Result<T, GpuError> {
        let ctx = self.ctx;
        let index = self.submit(b);
        ctx.map_read_after(&b.staging, bytes, Some(index), read)
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
pub fn dispatch_indirect(
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
