//! wgpu compute context and the GPU passes of the Gaussian splatting rasterizer.

pub mod context;
pub mod scan;

pub use context::{dispatch_dims, AdapterChoice, AtomicMode, GpuContext, GpuError};
pub use scan::{exclusive_scan_u32, ScanScratch};

#[cfg(test)]
mod shader_validation {
    /// Every `shaders/*.wgsl` must parse and validate with naga.
    #[test]
    fn all_shaders_validate_with_naga() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shaders");
        let mut checked = 0;
        for entry in std::fs::read_dir(&dir).expect("shaders/ exists") {
            let path = entry.expect("readable dir entry").path();
            if path.extension().and_then(|e| e.to_str()) != Some("wgsl") {
                continue;
            }
            let src = std::fs::read_to_string(&path).expect("readable shader");
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
