// One (tile, Gaussian) pair per tile a Gaussian reaches, written at its scanned offset. Ranks are
// in depth order, so a stable sort by tile alone leaves every tile's list front to back.
// Rank 0 records the total count and the live keys' workgroup counts; pairs beyond the capacity are dropped and the host grows the
// buffers and renders again. count_tiles.wgsl ran the same tile_hit on the same values; should a
// compiler ever make the two disagree, no write leaves this Gaussian's slots and counters[1]
// tells the host.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> proj: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> sorted_ids: array<u32>;
@group(0) @binding(3) var<storage, read> offsets: array<u32>;
@group(0) @binding(4) var<storage, read_write> tile_keys: array<u32>;
@group(0) @binding(5) var<storage, read_write> tile_vals: array<u32>;
@group(0) @binding(6) var<storage, read_write> counters: array<u32>;
// Workgroups (x, y, z), one per SORT_BLOCK live keys, of the passes over them (tile sort, tile
// ranges), folded
// into 2-D over 65535 as dispatch_dims (crates/raster/src/context.rs) does.
@group(0) @binding(7) var<storage, read_write> live_blocks: array<u32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let rank = gid.x + gid.y * nwg.x * 256u;
    if (rank >= params.n) {
        return;
    }
    if (rank == 0u) {
        let total = offsets[params.n];
        counters[0] = total;
        let blocks = max((min(total, params.cap) + SORT_BLOCK - 1u) / SORT_BLOCK, 1u);
        let x = min(blocks, 65535u);
        live_blocks[0] = x;
        live_blocks[1] = (blocks + x - 1u) / x;
        live_blocks[2] = 1u;
    }
    let g = sorted_ids[rank];
    let mo = proj[2u * g];
    let co = proj[2u * g + 1u];
    var at = offsets[rank];
    let end = offsets[rank + 1u];
    if (co.w > 0.0) {
        let q_max = cull_q_max(mo.z);
        let r = cull_rect(mo.xy, co.w, q_max);
        for (var ty = r.y; ty < r.w; ty = ty + 1u) {
            for (var tx = r.x; tx < r.z; tx = tx + 1u) {
                if (!tile_hit(mo.xy, co.xyz, q_max, tx, ty)) {
                    continue;
                }
                if (at < end && at < params.cap) {
                    tile_keys[at] = (ty - params.band_ty0) * params.tiles_x + tx;
                    tile_vals[at] = g;
                }
                at = at + 1u;
            }
        }
    }
    if (at != end) {
        counters[1] = 1u;
    }
}
