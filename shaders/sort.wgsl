// One pass of a stable LSD radix sort of (key, value) u32 pairs, on a digit of 1 to 8 bits (the
// depth sort's are 8 bits; the tile sort's as wide as needed to take the fewest passes).
// histogram: per-workgroup digit counts, stored digit-major (hist[digit * blocks + block]) so
// that one exclusive scan (scan.wgsl) turns them into global destinations.
// scatter: each element goes to its digit's destination plus its stable rank in the block.

struct SortPass {
    shift: u32, // the digit's lowest bit
    bits: u32, // the digit's width, at most log2(MAX_DIGITS)
    which: u32, // 0: sort the params.n depth keys; 1: sort the tile keys (count in counters[0])
    _pad: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> pass_info: SortPass;
@group(0) @binding(2) var<storage, read> counters: array<u32>;
@group(0) @binding(3) var<storage, read> keys_in: array<u32>;
@group(0) @binding(4) var<storage, read_write> hist: array<u32>;
@group(0) @binding(5) var<storage, read> vals_in: array<u32>;
@group(0) @binding(6) var<storage, read_write> keys_out: array<u32>;
@group(0) @binding(7) var<storage, read_write> vals_out: array<u32>;

const MAX_DIGITS: u32 = 256u; // of 8 bits
var<workgroup> local_hist: array<atomic<u32>, MAX_DIGITS>;
// Each block element's digit (MAX_DIGITS: none), then also its rank among its walker's run of
// the same digit in the upper 16 bits (scatter).
var<workgroup> block_digits: array<u32, SORT_BLOCK>;
// Stable ranks come from WALKERS serial walks over consecutive runs of the block: walker w counts
// the digits of its run in walk_counts[digit * WALKERS + w], which a scan over walkers then turns
// into each run's offset within its digit.
const WALKERS: u32 = 8u;
const RUN: u32 = SORT_BLOCK / WALKERS;
var<workgroup> walk_counts: array<u32, MAX_DIGITS * WALKERS>;

fn live_count() -> u32 {
    if (pass_info.which == 0u) {
        return params.n;
    }
    return min(counters[0], params.cap);
}

// Blocks in the histogram layout: fixed by the buffer capacity, not by the live count.
fn num_blocks() -> u32 {
    if (pass_info.which == 0u) {
        return (params.n + SORT_BLOCK - 1u) / SORT_BLOCK;
    }
    return (params.cap + SORT_BLOCK - 1u) / SORT_BLOCK;
}

fn digits() -> u32 {
    return 1u << pass_info.bits;
}

fn digit(key: u32) -> u32 {
    return (key >> pass_info.shift) & (digits() - 1u);
}

@compute @workgroup_size(SORT_THREADS)
fn histogram(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let block = wid.x + wid.y * nwg.x;
    let nb = num_blocks();
    // The tile keys' histogram layout follows the buffer's capacity, but only the live blocks
    // run (an indirect dispatch; the host clears the rest). A block with no live element (no
    // keys at all) only writes its zero counts (whole workgroup, so the barriers below stay in
    // uniform control flow).
    if (block * SORT_BLOCK >= live_count()) {
        if (lid < digits() && block < nb) {
            hist[lid * nb + block] = 0u;
        }
        return;
    }
    if (lid < digits()) {
        atomicStore(&local_hist[lid], 0u);
    }
    workgroupBarrier();
    for (var k = 0u; k < SORT_KEYS; k = k + 1u) {
        let i = block * SORT_BLOCK + k * SORT_THREADS + lid;
        if (i < live_count()) {
            atomicAdd(&local_hist[digit(keys_in[i])], 1u);
        }
    }
    workgroupBarrier();
    if (lid < digits() && block < nb) {
        hist[lid * nb + block] = atomicLoad(&local_hist[lid]);
    }
}

@compute @workgroup_size(SORT_THREADS)
fn scatter(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let block = wid.x + wid.y * nwg.x;
    if (block * SORT_BLOCK >= live_count()) {
        return; // nothing live in this block (see histogram)
    }
    // This invocation's keys: block positions lid, lid + SORT_THREADS, ...
    for (var k = 0u; k < SORT_KEYS; k = k + 1u) {
        let j = k * SORT_THREADS + lid;
        let i = block * SORT_BLOCK + j;
        var d = MAX_DIGITS; // no digit: not a live element
        if (i < live_count()) {
            d = digit(keys_in[i]);
        }
        block_digits[j] = d;
    }
    for (var k = lid; k < MAX_DIGITS * WALKERS; k = k + SORT_THREADS) {
        walk_counts[k] = 0u;
    }
    workgroupBarrier();
    // Stable ranks within each walker's run: a serial walk per walker, the walkers side by side
    // (one SIMD batch on lavapipe; a single walker over the whole block cost 8x the time).
    if (lid < WALKERS) {
        for (var r = 0u; r < RUN; r = r + 1u) {
            let j = lid * RUN + r;
            let dj = block_digits[j];
            if (dj < MAX_DIGITS) {
                let c = dj * WALKERS + lid;
                let rank = walk_counts[c];
                block_digits[j] = dj | (rank << 16u);
                walk_counts[c] = rank + 1u;
            }
        }
    }
    workgroupBarrier();
    // Each digit's runs in walker order: exclusive offsets of the runs within the digit.
    for (var dg = lid; dg < digits(); dg = dg + SORT_THREADS) {
        var sum = 0u;
        for (var w = 0u; w < WALKERS; w = w + 1u) {
            let c = walk_counts[dg * WALKERS + w];
            walk_counts[dg * WALKERS + w] = sum;
            sum = sum + c;
        }
    }
    workgroupBarrier();
    let nb = num_blocks();
    for (var k = 0u; k < SORT_KEYS; k = k + 1u) {
        let j = k * SORT_THREADS + lid;
        let i = block * SORT_BLOCK + j;
        if (i < live_count()) {
            let dj = block_digits[j] & 0xffffu;
            let rank = block_digits[j] >> 16u;
            let dst = hist[dj * nb + block] + walk_counts[dj * WALKERS + j / RUN] + rank;
            keys_out[dst] = keys_in[i];
            vals_out[dst] = vals_in[i];
        }
    }
}
