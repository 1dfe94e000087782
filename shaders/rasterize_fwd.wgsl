// Forward compositing, one TILE x TILE/4 workgroup per tile, four pixels per invocation (vec4 lanes,
// see splat_common.wgsl): each pixel blends the tile's depth-sorted Gaussians front to back until
// its transmittance would fall below T_MIN; the invocation stops when all four have.
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

// True only in the counting build (its own kernel, crates/raster/build/main.rs), which tallies
// pixel steps evaluated, composited and walked after the pixel closed; false compiles them away.
override COUNT_WORK: bool = false;

// Adds the four lanes of `lanes` to 64-bit counter k, carrying into its high word when the low
// word wraps.
fn count_add(k: u32, lanes: vec4<u32>) {
    let v = dot(lanes, vec4<u32>(1u));
    let old = atomicAdd(&counters[2u + 2u * k], v);
    if (old > 0xffffffffu - v) {
        atomicAdd(&counters[3u + 2u * k], 1u);
    }
}

@compute @workgroup_size(TILE, TILE / 4u)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
) {
    let lanes = pixel_lanes(wid, lid);
    let range = ranges[lanes.tile];
    var acc: array<vec4<f32>, D>;
    for (var c = 0u; c < D; c = c + 1u) {
        acc[c] = vec4<f32>(0.0);
    }
    var t = vec4<f32>(1.0);
    var wz = vec4<f32>(0.0);
    var last = vec4<u32>(0u);
    var open = lanes.inside; // transmittance still above T_MIN
    var walked = 0u;
    var n_eval = vec4<u32>(0u);
    var n_used = vec4<u32>(0u);
    var n_closed = vec4<u32>(0u);
    for (var idx = range.x; idx < range.y && any(open); idx = idx + 1u) {
        walked = walked + 1u;
        let g = tile_vals[idx];
        let mo = proj[2u * g];
        let co = proj[2u * g + 1u];
        let power = splat_powers(co, mo.x - lanes.centre_x, vec4<f32>(mo.y) - lanes.centre_y);
        let near = open & (power >= vec4<f32>(POWER_CUT));
        if (COUNT_WORK) {
            n_eval = n_eval + select(vec4<u32>(0u), vec4<u32>(1u), open);
            n_closed = n_closed + select(vec4<u32>(0u), vec4<u32>(1u), lanes.inside & !open);
        }
        if (!any(near)) {
            continue; // beyond 3 sigma of all four pixels: no exp, no feature loads
        }
        let alpha = min(vec4<f32>(ALPHA_MAX), mo.z * exp(power));
        let hit = near & (alpha >= vec4<f32>(ALPHA_MIN));
        let next_t = t * (1.0 - alpha);
        let closes = hit & (next_t < vec4<f32>(T_MIN));
        let used = hit & !closes;
        if (COUNT_WORK) {
            n_used = n_used + select(vec4<u32>(0u), vec4<u32>(1u), used);
        }
        open = open & !closes;
        if (!any(used)) {
            continue;
        }
        let w = select(vec4<f32>(0.0), alpha * t, used);
        let fb = params.off_feat + g * D;
        for (var c = 0u; c < D; c = c + 1u) {
            acc[c] = acc[c] + inputs[fb + c] * w;
        }
        wz = wz + mo.w * w;
        t = select(t, next_t, used);
        last = select(last, vec4<u32>(walked), used);
    }
    if (COUNT_WORK) {
        count_add(0u, n_eval);
        count_add(1u, n_used);
        count_add(2u, n_closed);
    }
    let a = 1.0 - t;
    let depth = select(vec4<f32>(0.0), wz / a, a > vec4<f32>(ALPHA_EPS));
    for (var j = 0u; j < 4u; j = j + 1u) {
        if (!lanes.inside[j]) {
            continue;
        }
        let pi = lanes.py[j] * params.width + lanes.px;
        for (var c = 0u; c < D; c = c + 1u) {
            out_image[pi * D + c] = acc[c][j] + t[j] * inputs[params.off_bg + c];
        }
        out_depth[pi] = depth[j];
        out_alpha[pi] = a[j];
        aux[pi] = vec4<f32>(t[j], bitcast<f32>(last[j]), wz[j], 0.0);
    }
}
