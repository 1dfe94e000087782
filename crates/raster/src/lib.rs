//! wgpu compute context and the GPU passes of the Gaussian splatting rasterizer.

pub mod context;
pub mod scan;
pub mod splat;

pub use context::{dispatch_dims, AdapterChoice, AtomicMode, GpuContext, GpuError};
pub use scan::{exclusive_scan_u32, ScanScratch};
pub use splat::{
    rasterize_backward, rasterize_forward, Camera, ForwardOutput, Gaussians, Gradients, PassTimes,
    WorkCounts,
};

#[cfg(test)]
mod shader_validation {
    /// Every `shaders/*.wgsl` must parse and validate with naga (with the preludes it names).
    #[test]
    fn all_shaders_validate_with_naga() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shaders");
        let mut checked = 0;
        for entry in std::fs::read_dir(&dir).expect("shaders/ exists") {
            let path = entry.expect("readable dir entry").path();
            if path.extension().and_then(|e| e.to_str()) != Some("wgsl") {
                continue;
            }
            let name = path
                .file_name()
                .and_then(|n| n.to_str())
                .unwrap_or_default();
            if name.starts_with("splat_") {
                continue; // preludes: validated inside the passes that name them
            }
            let raw = std::fs::read_to_string(&path).expect("readable shader");
            let src =
                crate::splat::with_preludes(&raw, |n| std::fs::read_to_string(dir.join(n)).ok())
                    .expect("preludes resolve");
            let module = naga::front::wgsl::parse_str(&src)
                .unwrap_or_else(|e| panic!("{}: {}", path.display(), e.emit_to_string(&src)));
            naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::all(),
            )
            .validate(&module)
            .unwrap_or_else(|e| panic!("{}: {e:?}", path.display()));
            checked += 1;
        }
        assert!(checked > 0, "no shaders found in {}", dir.display());
    }
}
