// prelude: splat_common.wgsl
// Forward compositing, one 16x4 workgroup per 16x16 tile, PX pixels per invocation: each pixel
// blends the tile's depth-sorted Gaussians front to back.
// Per pixel it also stores what the backward pass replays from: final transmittance, the number
// of list entries walked up to the last contributor, and sum(w z).

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> inputs: array<f32>;
@group(0) @binding(2) var<storage, read> proj: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> tile_vals: array<u32>;
@group(0) @binding(4) var<storage, read> ranges: array<vec2<u32>>;
@group(0) @binding(5) var<storage, read_write> out_image: array<f32>;
@group(0) @binding(6) var<storage, read_write> out_depth: array<f32>;
@group(0) @binding(7) var<storage, read_write> out_alpha: array<f32>;
// (final T, bitcast entries walked to the last contributor, sum of w z, 0) per pixel.
@group(0) @binding(8) var<storage, read_write> aux: array<vec4<f32>>;
// Words 2..8: the work counters, (low, high) pairs, of the counting build.
@group(0) @binding(9) var<storage, read_write> counters: array<atomic<u32>>;

// True only in the counting build (crates/raster/src/splat/mod.rs), which tallies pixel steps
// evaluated, composited and walked after the pixel closed; false compiles the tallies away.
const COUNT_WORK: bool = false;

// Adds v to 64-bit counter k, carrying into its high word when the low word wraps.
fn count_add(k: u32, v: u32) {
    let old = atomicAdd(&counters[2u + 2u * k], v);
    if (old > 0xffffffffu - v) {
        atomicAdd(&counters[3u + 2u * k], 1u);
    }
}

@compute @workgroup_size(16, 4)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
) {
    let tile = wid.x + wid.y * params.tiles_x;
    let px = wid.x * TILE + lid.x;
    let range = ranges[tile];
    var acc: array<array<f32, D>, PX>;
    var t: array<f32, PX>;
    var wz: array<f32, PX>;
    var last: array<u32, PX>;
    var live: array<bool, PX>;
    var inside: array<bool, PX>;
    var n_live = 0u;
    var n_eval = 0u;
    var n_used = 0u;
    var n_closed = 0u;
    for (var j = 0u; j < PX; j = j + 1u) {
        let py = tile_row(wid.y, lid.y, j);
        t[j] = 1.0;
        inside[j] = px < params.width && py < params.height;
        live[j] = inside[j];
        if (live[j]) {
            n_live = n_live + 1u;
        }
    }
    var walked = 0u;
    for (var idx = range.x; idx < range.y && n_live > 0u; idx = idx + 1u) {
        walked = walked + 1u;
        let g = tile_vals[idx];
        let mo = proj[2u * g];
        let co = proj[2u * g + 1u];
        let fb = params.off_feat + g * D;
        for (var j = 0u; j < PX; j = j + 1u) {
            if (!live[j]) {
                if (COUNT_WORK && inside[j]) {
                    n_closed = n_closed + 1u;
                }
                continue;
            }
            if (COUNT_WORK) {
                n_eval = n_eval + 1u;
            }
            let py = tile_row(wid.y, lid.y, j);
            let dd = mo.xy - vec2<f32>(f32(px) + 0.5, f32(py) + 0.5);
            let power = splat_power(co, dd);
            if (power < POWER_CUT) {
                continue;
            }
            let alpha = min(ALPHA_MAX, mo.z * exp(power));
            if (alpha < ALPHA_MIN) {
                continue;
            }
            let next_t = t[j] * (1.0 - alpha);
            if (next_t < T_MIN) {
                live[j] = false;
                n_live = n_live - 1u;
                continue;
            }
            let w = alpha * t[j];
            for (var c = 0u; c < D; c = c + 1u) {
                acc[j][c] = acc[j][c] + inputs[fb + c] * w;
            }
            wz[j] = wz[j] + mo.w * w;
            t[j] = next_t;
            last[j] = walked;
            if (COUNT_WORK) {
                n_used = n_used + 1u;
            }
        }
    }
    if (COUNT_WORK) {
        count_add(0u, n_eval);
        count_add(1u, n_used);
        count_add(2u, n_closed);
    }
    for (var j = 0u; j < PX; j = j + 1u) {
        let py = tile_row(wid.y, lid.y, j);
        if (px >= params.width || py >= params.height) {
            continue;
        }
        let pi = py * params.width + px;
        for (var c = 0u; c < D; c = c + 1u) {
            out_image[pi * D + c] = acc[j][c] + t[j] * inputs[params.off_bg + c];
        }
        let a = 1.0 - t[j];
        var depth = 0.0;
        if (a > ALPHA_EPS) {
            depth = wz[j] / a;
        }
        out_depth[pi] = depth;
        out_alpha[pi] = a;
        aux[pi] = vec4<f32>(t[j], bitcast<f32>(last[j]), wz[j], 0.0);
    }
}
