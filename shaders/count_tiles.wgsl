// prelude: splat_common.wgsl
// Tiles touched by each Gaussian, in depth order (one thread per sorted rank); scanned in place
// afterwards into the offsets at which emit_keys.wgsl writes that Gaussian's tile keys.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> proj: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> sorted_ids: array<u32>;
@group(0) @binding(3) var<storage, read_write> counts: array<u32>;

fn tile_count(g: u32) -> u32 {
    let b = proj[2u * g + 1u];
    if (b.w <= 0.0) {
        return 0u;
    }
    let r = tile_rect(proj[2u * g].xy, b.w);
    return (r.z - r.x) * (r.w - r.y);
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let r = gid.x + gid.y * nwg.x * 256u;
    if (r >= params.n) {
        return;
    }
    counts[r] = tile_count(sorted_ids[r]);
}
