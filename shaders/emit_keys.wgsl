// prelude: splat_common.wgsl
// One (tile, Gaussian) pair per tile a Gaussian touches, written at its scanned offset. Ranks are
// in depth order, so a stable sort by tile alone leaves every tile's list front to back.
// The last rank also records the total count; pairs beyond the capacity are dropped and the host
// grows the buffers and renders again.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> proj: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> sorted_ids: array<u32>;
@group(0) @binding(3) var<storage, read> offsets: array<u32>;
@group(0) @binding(4) var<storage, read_write> tile_keys: array<u32>;
@group(0) @binding(5) var<storage, read_write> tile_vals: array<u32>;
@group(0) @binding(6) var<storage, read_write> counters: array<u32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let rank = gid.x + gid.y * nwg.x * 256u;
    if (rank >= params.n) {
        return;
    }
    let g = sorted_ids[rank];
    let b = proj[2u * g + 1u];
    var at = offsets[rank];
    if (b.w > 0.0) {
        let r = tile_rect(proj[2u * g].xy, b.w);
        for (var ty = r.y; ty < r.w; ty = ty + 1u) {
            for (var tx = r.x; tx < r.z; tx = tx + 1u) {
                if (at < params.cap) {
                    tile_keys[at] = ty * params.tiles_x + tx;
                    tile_vals[at] = g;
                }
                at = at + 1u;
            }
        }
    }
    if (rank == params.n - 1u) {
        counters[0] = at;
    }
}
