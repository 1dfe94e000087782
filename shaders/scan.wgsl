// Exclusive prefix sum over u32 (wrapping on overflow), in place.
// scan_blocks: each 256-wide block is scanned in workgroup memory and its total written to
// block_sums; the host scans block_sums recursively, then add_offsets adds them back.

struct ScanParams {
    n: u32,          // elements in `data`
    num_blocks: u32, // blocks that really exist (the 2-D dispatch may launch more)
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<storage, read_write> data: array<u32>;
@group(0) @binding(1) var<storage, read_write> block_sums: array<u32>;
@group(0) @binding(2) var<uniform> params: ScanParams;

const SCAN_BLOCK: u32 = 256u;
var<workgroup> tile: array<u32, SCAN_BLOCK>;

@compute @workgroup_size(SCAN_BLOCK)
fn scan_blocks(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let block = wid.x + wid.y * nwg.x;
    let i = block * SCAN_BLOCK + lid;
    var v = 0u;
    if (i < params.n) {
        v = data[i];
    }
    tile[lid] = v;
    workgroupBarrier();
    // Hillis-Steele inclusive scan: log2(256) = 8 steps, two barriers each.
    for (var off = 1u; off < SCAN_BLOCK; off = off * 2u) {
        var add = 0u;
        if (lid >= off) {
            add = tile[lid - off];
        }
        workgroupBarrier();
        tile[lid] = tile[lid] + add;
        workgroupBarrier();
    }
    if (i < params.n) {
        data[i] = tile[lid] - v;
    }
    if (lid == SCAN_BLOCK - 1u && block < params.num_blocks) {
        block_sums[block] = tile[lid];
    }
}

@compute @workgroup_size(SCAN_BLOCK)
fn add_offsets(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let block = wid.x + wid.y * nwg.x;
    let i = block * SCAN_BLOCK + lid;
    if (i < params.n && block < params.num_blocks) {
        data[i] = data[i] + block_sums[block];
    }
}
