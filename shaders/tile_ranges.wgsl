// [start, end) of each tile's run in the tile-sorted intersection list (ranges cleared to 0 first).

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> counters: array<u32>;
@group(0) @binding(2) var<storage, read> tile_keys: array<u32>;
// Flat (start, end) pairs: scalar stores, because start and end of one tile are written by
// different threads and a vector-component store may be a read-modify-write of both.
@group(0) @binding(3) var<storage, read_write> ranges: array<u32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 256u;
    let m = min(counters[0], params.cap);
    if (i >= m) {
        return;
    }
    let t = tile_keys[i];
    if (i == 0u || tile_keys[i - 1u] != t) {
        ranges[2u * t] = i;
    }
    if (i == m - 1u || tile_keys[i + 1u] != t) {
        ranges[2u * t + 1u] = i + 1u;
    }
}
