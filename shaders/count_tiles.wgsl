// Tiles each Gaussian reaches (tile_hit), in depth order (one thread per sorted rank), plus a 0
// after the last rank; scanned in place afterwards into the offsets at which emit_keys.wgsl
// writes that Gaussian's tile keys (offsets[n] is the total).

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> proj: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> sorted_ids: array<u32>;
@group(0) @binding(3) var<storage, read_write> counts: array<u32>;

fn tile_count(g: u32) -> u32 {
    let mo = proj[2u * g];
    let co = proj[2u * g + 1u];
    if (co.w <= 0.0) {
        return 0u;
    }
    let q_max = cull_q_max(mo.z);
    let r = cull_rect(mo.xy, co.w, q_max);
    var count = 0u;
    for (var ty = r.y; ty < r.w; ty = ty + 1u) {
        for (var tx = r.x; tx < r.z; tx = tx + 1u) {
            if (tile_hit(mo.xy, co.xyz, q_max, tx, ty)) {
                count = count + 1u;
            }
        }
    }
    return count;
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let r = gid.x + gid.y * nwg.x * 256u;
    if (r > params.n) {
        return;
    }
    if (r == params.n) {
        counts[r] = 0u;
        return;
    }
    counts[r] = tile_count(sorted_ids[r]);
}
