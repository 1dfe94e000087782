//! The compute kernels, as crates/raster/build/main.rs assembled, validated and reflected them from
//! shaders/*.wgsl; `GpuContext::pipeline` builds their pipelines.

include!(concat!(env!("OUT_DIR"), "/kernels.rs"));

impl Kernel {
    /// Workgroups (folded into 2-D, see `dispatch_dims`) covering `items` invocations along x.
    pub fn groups_for(self, items: u32) -> (u32, u32) {
        crate::dispatch_dims(items.div_ceil(self.workgroup_size()[0]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::GpuContext;

    /// The build script validated each source with naga; wgpu also builds every pipeline the
    /// device can run (overrides applied) for the extreme channel counts, and an invalid one
    /// panics the device.
    #[test]
    fn every_kernel_builds_a_pipeline_for_one_and_max_channels() {
        let ctx = GpuContext::global().expect("a Vulkan adapter (lavapipe in CI) is required");
        for k in Kernel::ALL {
            if !ctx.runs(k) {
                continue;
            }
            for d in [1, crate::wgsl::MAX_D] {
                ctx.pipeline(k, d);
            }
        }
        ctx.wait().expect("the device survives");
    }
}
