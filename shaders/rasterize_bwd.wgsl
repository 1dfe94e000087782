// prelude: splat_common.wgsl
// Backward compositing, one 16x16 workgroup per tile: each pixel replays its list back to front
// from the stored final transmittance and last contributor (as 3DGS), and accumulates per-Gaussian
// gradients of the 2-D mean, conic, opacity, camera z and features with atomics.
// grad_add is the float32 atomicAdd; the compare-and-swap build replaces its body (see
// crates/raster/src/splat/mod.rs), so both paths come from this one source.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> inputs: array<f32>;
@group(0) @binding(2) var<storage, read> proj: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> tile_vals: array<u32>;
@group(0) @binding(4) var<storage, read> ranges: array<vec2<u32>>;
@group(0) @binding(5) var<storage, read> aux: array<vec4<f32>>;
// dL/dimage (H*W*D), then dL/ddepth (H*W), then dL/dalpha (H*W).
@group(0) @binding(6) var<storage, read> grad_in: array<f32>;
// Per Gaussian (grad_stride = 8 + D floats): mean2d x, y, conic a, b, c, opacity, z, unused,
// then the D features.
@group(0) @binding(7) var<storage, read_write> grads: array<atomic<f32>>;

fn grad_add(i: u32, v: f32) {
    atomicAdd(&grads[i], v);
}

const BATCH: u32 = 256u;
var<workgroup> b_mean: array<vec4<f32>, 256>;
var<workgroup> b_conic: array<vec4<f32>, 256>;
var<workgroup> b_id: array<u32, 256>;
var<workgroup> w_range: vec2<u32>;
var<workgroup> max_last: atomic<u32>;
var<workgroup> w_max_last: u32;

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
    let hw = params.width * params.height;
    let pi = py * params.width + px;

    var last = 0u;
    var t = 1.0;
    var g_img: array<f32, D>;
    var g_z = 0.0;
    var g_tfinal = 0.0;
    var t_final = 1.0;
    if (inside) {
        let a4 = aux[pi];
        t_final = a4.x;
        t = t_final;
        last = bitcast<u32>(a4.y);
        let a = 1.0 - t_final;
        let gd = grad_in[hw * D + pi];
        let ga = grad_in[hw * (D + 1u) + pi];
        // L depends on T_final through the background, alpha = 1 - T_final and
        // depth = sum(w z) / alpha.
        g_tfinal = -ga;
        if (a > ALPHA_EPS) {
            let depth = a4.z / a;
            g_z = gd / a;
            g_tfinal = g_tfinal + gd * depth / a;
        }
        for (var c = 0u; c < D; c = c + 1u) {
            g_img[c] = grad_in[pi * D + c];
            g_tfinal = g_tfinal + g_img[c] * inputs[params.off_bg + c];
        }
    }
    if (li == 0u) {
        w_range = ranges[tile];
        atomicStore(&max_last, 0u);
    }
    workgroupBarrier();
    atomicMax(&max_last, last);
    workgroupBarrier();
    if (li == 0u) {
        w_max_last = atomicLoad(&max_last);
    }
    let n_walk = workgroupUniformLoad(&w_max_last);
    let range = workgroupUniformLoad(&w_range);

    // Sums over the fragments behind the current one: sum_j f_j w_j and sum_j z_j w_j.
    var after: array<f32, D>;
    var after_z = 0.0;
    let batches = (n_walk + BATCH - 1u) / BATCH;
    for (var bb = 0u; bb < batches; bb = bb + 1u) {
        let b = batches - 1u - bb;
        let start = b * BATCH; // relative to range.x
        let idx = range.x + start + li;
        workgroupBarrier();
        if (start + li < n_walk) {
            let g = tile_vals[idx];
            b_id[li] = g;
            b_mean[li] = proj[2u * g];
            b_conic[li] = proj[2u * g + 1u];
        }
        workgroupBarrier();
        let count = min(BATCH, n_walk - start);
        for (var kk = 0u; kk < count; kk = kk + 1u) {
            let k = count - 1u - kk;
            if (start + k >= last) {
                continue;
            }
            let mo = b_mean[k];
            let co = b_conic[k];
            let dd = mo.xy - pix;
            let power = -0.5 * (co.x * dd.x * dd.x + co.z * dd.y * dd.y) - co.y * dd.x * dd.y;
            if (power < POWER_CUT) {
                continue;
            }
            let gauss = exp(power);
            let raw = mo.z * gauss;
            let alpha = min(ALPHA_MAX, raw);
            if (alpha < ALPHA_MIN) {
                continue;
            }
            let one_minus = 1.0 - alpha;
            t = t / one_minus; // transmittance in front of this fragment
            let w = alpha * t;
            let g = b_id[k];
            let gb = g * params.grad_stride;
            let fb = params.off_feat + g * D;
            var g_alpha = 0.0;
            for (var c = 0u; c < D; c = c + 1u) {
                let f = inputs[fb + c];
                g_alpha = g_alpha + g_img[c] * (f * t - after[c] / one_minus);
                grad_add(gb + 8u + c, g_img[c] * w);
                after[c] = after[c] + f * w;
            }
            g_alpha = g_alpha + g_z * (mo.w * t - after_z / one_minus);
            g_alpha = g_alpha - g_tfinal * t_final / one_minus;
            grad_add(gb + 6u, g_z * w);
            after_z = after_z + mo.w * w;
            // alpha = min(ALPHA_MAX, opacity * gauss): the clamp passes no gradient.
            if (raw <= ALPHA_MAX) {
                grad_add(gb + 5u, g_alpha * gauss);
                let gp = g_alpha * raw;
                // power = -0.5 (a dx^2 + c dy^2) - b dx dy with (dx, dy) = mean2d - pixel.
                grad_add(gb + 0u, -gp * (co.x * dd.x + co.y * dd.y));
                grad_add(gb + 1u, -gp * (co.z * dd.y + co.y * dd.x));
                grad_add(gb + 2u, -0.5 * gp * dd.x * dd.x);
                grad_add(gb + 3u, -gp * dd.x * dd.y);
                grad_add(gb + 4u, -0.5 * gp * dd.y * dd.y);
            }
        }
    }
}
