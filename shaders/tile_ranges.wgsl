// [start, end) of each tile's run in the tile-sorted intersection list (ranges cleared to 0 first).

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> counters: array<u32>;
@group(0) @binding(2) var<storage, read> tile_keys: array<u32>;
// Flat (start, end) pairs: scalar stores, because start and end of one tile are written by
// different threads and a vector-component store may be a read-modify-write of both.
@group(0) @binding(3) var<storage, read_write> ranges: array<u32>;

// One workgroup per SORT_BLOCK keys (the tile sort's dispatch), SORT_KEYS keys per invocation.
@compute @workgroup_size(SORT_THREADS)
fn main(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let m = min(counters[0], params.cap);
    let first = (wid.x + wid.y * nwg.x) * SORT_BLOCK + lid;
    for (var k = 0u; k < SORT_KEYS; k = k + 1u) {
        let i = first + k * SORT_THREADS;
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
}
