// prelude: splat_common.wgsl
// Forward compositing, one 16x16 workgroup per tile, one thread per pixel: the tile's Gaussians
// are loaded 256 at a time into workgroup memory and blended front to back.
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

const BATCH: u32 = 256u;
var<workgroup> b_mean: array<vec4<f32>, 256>; // (x, y, opacity, z)
var<workgroup> b_conic: array<vec4<f32>, 256>;
var<workgroup> b_id: array<u32, 256>;
var<workgroup> w_range: vec2<u32>;
var<workgroup> n_done: atomic<u32>;
var<workgroup> w_all_done: bool;

@compute @workgroup_size(16, 16)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let tile = wid.x + wid.y * params.tiles_x;
    let px = wid.x * TILE + lid.x;
    let py = wid.y * TILE + lid.y;
    let inside = px < params.width && py < params.height;
    let pix = vec2<f32>(f32(px) + 0.5, f32(py) + 0.5);
    if (li == 0u) {
        w_range = ranges[tile];
    }
    let range = workgroupUniformLoad(&w_range);
    var acc: array<f32, D>;
    var t = 1.0;
    var wz = 0.0;
    var walked = 0u;
    var last = 0u;
    var done = !inside;
    let batches = (range.y - range.x + BATCH - 1u) / BATCH;
    for (var b = 0u; b < batches; b = b + 1u) {
        // The whole tile stops once every pixel is saturated.
        if (li == 0u) {
            atomicStore(&n_done, 0u);
        }
        workgroupBarrier();
        if (done) {
            atomicAdd(&n_done, 1u);
        }
        workgroupBarrier();
        if (li == 0u) {
            w_all_done = atomicLoad(&n_done) == BATCH;
        }
        if (workgroupUniformLoad(&w_all_done)) {
            break;
        }
        let start = range.x + b * BATCH;
        let idx = start + li;
        if (idx < range.y) {
            let g = tile_vals[idx];
            b_id[li] = g;
            b_mean[li] = proj[2u * g];
            b_conic[li] = proj[2u * g + 1u];
        }
        workgroupBarrier();
        let count = min(BATCH, range.y - start);
        for (var k = 0u; k < count && !done; k = k + 1u) {
            walked = walked + 1u;
            let mo = b_mean[k];
            let co = b_conic[k];
            let dd = mo.xy - pix;
            let power = -0.5 * (co.x * dd.x * dd.x + co.z * dd.y * dd.y) - co.y * dd.x * dd.y;
            if (power < POWER_CUT) {
                continue;
            }
            let alpha = min(ALPHA_MAX, mo.z * exp(power));
            if (alpha < ALPHA_MIN) {
                continue;
            }
            let next_t = t * (1.0 - alpha);
            if (next_t < T_MIN) {
                done = true;
                break;
            }
            let w = alpha * t;
            let fb = params.off_feat + b_id[k] * D;
            for (var c = 0u; c < D; c = c + 1u) {
                acc[c] = acc[c] + inputs[fb + c] * w;
            }
            wz = wz + mo.w * w;
            t = next_t;
            last = walked;
        }
        workgroupBarrier();
    }
    if (!inside) {
        return;
    }
    let pi = py * params.width + px;
    for (var c = 0u; c < D; c = c + 1u) {
        out_image[pi * D + c] = acc[c] + t * inputs[params.off_bg + c];
    }
    let a = 1.0 - t;
    var depth = 0.0;
    if (a > ALPHA_EPS) {
        depth = wz / a;
    }
    out_depth[pi] = depth;
    out_alpha[pi] = a;
    aux[pi] = vec4<f32>(t, bitcast<f32>(last), wz, 0.0);
}
