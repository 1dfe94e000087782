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
// The block is scanned by raking: RAKERS invocations each scan RAKE consecutive values serially,
// one scans the RAKERS totals, and every value adds its rake's offset. Three barriers instead of
// the 17 of a Hillis-Steele scan: on lavapipe each barrier switches between all of the
// workgroup's SIMD batches, and the scans of the sorts' histograms are dominated by them.
const RAKE: u32 = 8u;
const RAKERS: u32 = 32u; // SCAN_BLOCK / RAKE
var<workgroup> tile: array<u32, SCAN_BLOCK>;
var<workgroup> rake_sums: array<u32, RAKERS>;

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
    // Inclusive scan of each rake in place; its total to rake_sums.
    if (lid < RAKERS) {
        var acc = 0u;
        for (var k = 0u; k < RAKE; k = k + 1u) {
            acc = acc + tile[lid * RAKE + k];
            tile[lid * RAKE + k] = acc;
        }
        rake_sums[lid] = acc;
    }
    workgroupBarrier();
    // Exclusive scan of the rake totals; the block total to block_sums.
    if (lid == 0u) {
        var acc = 0u;
        for (var r = 0u; r < RAKERS; r = r + 1u) {
            let total = rake_sums[r];
            rake_sums[r] = acc;
            acc = acc + total;
        }
        if (block < params.num_blocks) {
            block_sums[block] = acc;
        }
    }
    workgroupBarrier();
    if (i < params.n) {
        data[i] = rake_sums[lid / RAKE] + tile[lid] - v;
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
