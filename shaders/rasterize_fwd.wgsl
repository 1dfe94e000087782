// Forward compositing, one workgroup of TILE invocations per tile, a column of two quads of four
// pixels per invocation (vec4 lanes, see splat_common.wgsl): each pixel blends the tile's
// depth-sorted Gaussians front to back until its transmittance would fall below T_MIN; the
// invocation stops when all eight have.
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

// Four pixels' compositing state.
struct Quad {
    lanes: Lanes,
    acc: array<vec4<f32>, D>,
    t: vec4<f32>,
    wz: vec4<f32>,
    last: vec4<u32>,
    open: vec4<bool>, // transmittance still above T_MIN
    n_eval: vec4<u32>,
    n_used: vec4<u32>,
    n_closed: vec4<u32>,
}

fn quad_init(lanes: Lanes) -> Quad {
    var q: Quad;
    q.lanes = lanes;
    for (var c = 0u; c < D; c = c + 1u) {
        q.acc[c] = vec4<f32>(0.0);
    }
    q.t = vec4<f32>(1.0);
    q.wz = vec4<f32>(0.0);
    q.last = vec4<u32>(0u);
    q.open = lanes.inside;
    q.n_eval = vec4<u32>(0u);
    q.n_used = vec4<u32>(0u);
    q.n_closed = vec4<u32>(0u);
    return q;
}

// Blend list entry `walked` (Gaussian g, projected mo / co) into `q`.
fn quad_blend(q: ptr<function, Quad>, walked: u32, g: u32, mo: vec4<f32>, co: vec4<f32>) {
    let open = (*q).open;
    let power = splat_powers(co, mo.x - (*q).lanes.centre_x, vec4<f32>(mo.y) - (*q).lanes.centre_y);
    let near = open & (power >= vec4<f32>(POWER_CUT));
    if (COUNT_WORK) {
        (*q).n_eval = (*q).n_eval + select(vec4<u32>(0u), vec4<u32>(1u), open);
        let closed = (*q).lanes.inside & !open;
        (*q).n_closed = (*q).n_closed + select(vec4<u32>(0u), vec4<u32>(1u), closed);
    }
    if (!any(near)) {
        return; // beyond 3 sigma of the quad's four pixels: no exp, no feature loads
    }
    let alpha = min(vec4<f32>(ALPHA_MAX), mo.z * exp(power));
    let hit = near & (alpha >= vec4<f32>(ALPHA_MIN));
    let t = (*q).t;
    let next_t = t * (1.0 - alpha);
    let closes = hit & (next_t < vec4<f32>(T_MIN));
    let used = hit & !closes;
    if (COUNT_WORK) {
        (*q).n_used = (*q).n_used + select(vec4<u32>(0u), vec4<u32>(1u), used);
    }
    (*q).open = open & !closes;
    if (!any(used)) {
        return;
    }
    let w = select(vec4<f32>(0.0), alpha * t, used);
    let fb = params.off_feat + g * D;
    for (var c = 0u; c < D; c = c + 1u) {
        (*q).acc[c] = (*q).acc[c] + inputs[fb + c] * w;
    }
    (*q).wz = (*q).wz + mo.w * w;
    (*q).t = select(t, next_t, used);
    (*q).last = select((*q).last, vec4<u32>(walked), used);
}

fn quad_write(q: Quad) {
    if (COUNT_WORK) {
        count_add(0u, q.n_eval);
        count_add(1u, q.n_used);
        count_add(2u, q.n_closed);
    }
    let t = q.t;
    let a = 1.0 - t;
    let depth = select(vec4<f32>(0.0), q.wz / a, a > vec4<f32>(ALPHA_EPS));
    for (var j = 0u; j < 4u; j = j + 1u) {
        if (!q.lanes.inside[j]) {
            continue;
        }
        let pi = q.lanes.py[j] * params.width + q.lanes.px;
        for (var c = 0u; c < D; c = c + 1u) {
            out_image[pi * D + c] = q.acc[c][j] + t[j] * inputs[params.off_bg + c];
        }
        out_depth[pi] = depth[j];
        out_alpha[pi] = a[j];
        aux[pi] = vec4<f32>(t[j], bitcast<f32>(q.last[j]), q.wz[j], 0.0);
    }
}

@compute @workgroup_size(TILE, TILE / (4u * QUADS))
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
) {
    var q0 = quad_init(pixel_lanes(wid, lid, 0u));
    var q1 = quad_init(pixel_lanes(wid, lid, 1u));
    let range = ranges[q0.lanes.tile];
    var walked = 0u;
    for (var idx = range.x; idx < range.y && any(q0.open | q1.open); idx = idx + 1u) {
        walked = walked + 1u;
        let g = tile_vals[idx];
        let mo = proj[2u * g];
        let co = proj[2u * g + 1u];
        quad_blend(&q0, walked, g, mo, co);
        quad_blend(&q1, walked, g, mo, co);
    }
    quad_write(q0);
    quad_write(q1);
}
