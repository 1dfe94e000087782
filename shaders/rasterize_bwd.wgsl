// prelude: splat_common.wgsl
// Backward compositing, one 16x4 workgroup per 16x16 tile, PX pixels per invocation: each pixel
// replays its list back to front from the stored final transmittance and last contributor (as
// 3DGS); an invocation sums its pixels' gradients of the 2-D mean, conic, opacity, camera z and
// features per Gaussian, then adds them with one atomic each.
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

@compute @workgroup_size(16, 4)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
) {
    let tile = wid.x + wid.y * params.tiles_x;
    let px = wid.x * TILE + lid.x;
    let hw = params.width * params.height;
    let range = ranges[tile];

    var last: array<u32, PX>;
    var t: array<f32, PX>;
    var t_final: array<f32, PX>;
    var g_img: array<array<f32, D>, PX>;
    var g_z: array<f32, PX>;
    var g_tfinal: array<f32, PX>;
    // Sums over the fragments behind the current one: sum_j f_j w_j and sum_j z_j w_j.
    var after: array<array<f32, D>, PX>;
    var after_z: array<f32, PX>;
    var n_walk = 0u;
    for (var j = 0u; j < PX; j = j + 1u) {
        let py = tile_row(wid.y, lid.y, j);
        t[j] = 1.0;
        t_final[j] = 1.0;
        if (px >= params.width || py >= params.height) {
            continue;
        }
        let pi = py * params.width + px;
        let a4 = aux[pi];
        t_final[j] = a4.x;
        t[j] = a4.x;
        last[j] = bitcast<u32>(a4.y);
        n_walk = max(n_walk, last[j]);
        let a = 1.0 - a4.x;
        let gd = grad_in[hw * D + pi];
        let ga = grad_in[hw * (D + 1u) + pi];
        // L depends on T_final through the background, alpha = 1 - T_final and
        // depth = sum(w z) / alpha.
        var gt = -ga;
        if (a > ALPHA_EPS) {
            g_z[j] = gd / a;
            gt = gt + gd * (a4.z / a) / a;
        }
        for (var c = 0u; c < D; c = c + 1u) {
            g_img[j][c] = grad_in[pi * D + c];
            gt = gt + g_img[j][c] * inputs[params.off_bg + c];
        }
        g_tfinal[j] = gt;
    }

    for (var kk = 0u; kk < n_walk; kk = kk + 1u) {
        let k = n_walk - 1u - kk;
        let g = tile_vals[range.x + k];
        let mo = proj[2u * g];
        let co = proj[2u * g + 1u];
        let fb = params.off_feat + g * D;
        // This Gaussian's gradient summed over the invocation's pixels: one atomic per value.
        var s_feat: array<f32, D>;
        var s_mean = vec2<f32>(0.0);
        var s_conic = vec3<f32>(0.0);
        var s_opac = 0.0;
        var s_z = 0.0;
        var hit = false;
        for (var j = 0u; j < PX; j = j + 1u) {
            if (k >= last[j]) {
                continue;
            }
            let py = tile_row(wid.y, lid.y, j);
            let dd = mo.xy - vec2<f32>(f32(px) + 0.5, f32(py) + 0.5);
            let power = splat_power(co, dd);
            if (power < POWER_CUT) {
                continue;
            }
            let gauss = exp(power);
            let raw = mo.z * gauss;
            let alpha = min(ALPHA_MAX, raw);
            if (alpha < ALPHA_MIN) {
                continue;
            }
            hit = true;
            let one_minus = 1.0 - alpha;
            t[j] = t[j] / one_minus; // transmittance in front of this fragment
            let w = alpha * t[j];
            var g_alpha = 0.0;
            for (var c = 0u; c < D; c = c + 1u) {
                let f = inputs[fb + c];
                g_alpha = g_alpha + g_img[j][c] * (f * t[j] - after[j][c] / one_minus);
                s_feat[c] = s_feat[c] + g_img[j][c] * w;
                after[j][c] = after[j][c] + f * w;
            }
            g_alpha = g_alpha + g_z[j] * (mo.w * t[j] - after_z[j] / one_minus);
            g_alpha = g_alpha - g_tfinal[j] * t_final[j] / one_minus;
            s_z = s_z + g_z[j] * w;
            after_z[j] = after_z[j] + mo.w * w;
            // alpha = min(ALPHA_MAX, opacity * gauss): the clamp passes no gradient.
            if (raw <= ALPHA_MAX) {
                s_opac = s_opac + g_alpha * gauss;
                let gp = g_alpha * raw;
                // power = -0.5 (a dx^2 + c dy^2) - b dx dy with (dx, dy) = mean2d - pixel.
                s_mean = s_mean - gp * vec2<f32>(co.x * dd.x + co.y * dd.y, co.z * dd.y + co.y * dd.x);
                s_conic = s_conic - gp * vec3<f32>(0.5 * dd.x * dd.x, dd.x * dd.y, 0.5 * dd.y * dd.y);
            }
        }
        if (!hit) {
            continue;
        }
        let gb = g * params.grad_stride;
        for (var c = 0u; c < D; c = c + 1u) {
            grad_add(gb + 8u + c, s_feat[c]);
        }
        grad_add(gb + 0u, s_mean.x);
        grad_add(gb + 1u, s_mean.y);
        grad_add(gb + 2u, s_conic.x);
        grad_add(gb + 3u, s_conic.y);
        grad_add(gb + 4u, s_conic.z);
        grad_add(gb + 5u, s_opac);
        grad_add(gb + 6u, s_z);
    }
}
