// Backward compositing, one TILE x TILE/4 workgroup per tile, four pixels per invocation (vec4 lanes,
// see splat_common.wgsl): each pixel replays its list back to front from the stored final
// transmittance and last contributor (as 3DGS); an invocation sums its pixels' gradients of the
// 2-D mean, conic, opacity, camera z and features per Gaussian, group_sum sums them over its
// group (the invocations with a fragment of that Gaussian) and the group's leader adds each sum
// to the accumulator with one atomic.
// Four kernels share this source (crates/raster/build/main.rs): `grads` and grad_add come from
// grads_float.wgsl (float32 atomicAdd) or grads_cas.wgsl (compare-and-swap), and the group_*
// functions from reduce_subgroup.wgsl (the group is a subgroup: one atomic per subgroup) or
// reduce_invocation.wgsl (the group is the invocation: one atomic per invocation).

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> inputs: array<f32>;
@group(0) @binding(2) var<storage, read> proj: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> tile_vals: array<u32>;
@group(0) @binding(4) var<storage, read> ranges: array<vec2<u32>>;
@group(0) @binding(5) var<storage, read> aux: array<vec4<f32>>;
// dL/dimage (H*W*D), then dL/ddepth (H*W), then dL/dalpha (H*W).
@group(0) @binding(6) var<storage, read> grad_in: array<f32>;

@compute @workgroup_size(TILE, TILE / 4u)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
) {
    let lanes = pixel_lanes(wid, lid);
    let hw = params.width * params.height;
    let range = ranges[lanes.tile];

    var last = vec4<u32>(0u);
    var t_final = vec4<f32>(1.0);
    var g_z = vec4<f32>(0.0);
    var g_tfinal = vec4<f32>(0.0);
    var g_img: array<vec4<f32>, D>;
    // Sums over the fragments behind the current one: sum_j f_j w_j and sum_j z_j w_j.
    var after: array<vec4<f32>, D>;
    var after_z = vec4<f32>(0.0);
    for (var c = 0u; c < D; c = c + 1u) {
        g_img[c] = vec4<f32>(0.0);
        after[c] = vec4<f32>(0.0);
    }
    for (var j = 0u; j < 4u; j = j + 1u) {
        if (!lanes.inside[j]) {
            continue;
        }
        let pi = lanes.py[j] * params.width + lanes.px;
        let a4 = aux[pi];
        t_final[j] = a4.x;
        last[j] = bitcast<u32>(a4.y);
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
            let gi = grad_in[pi * D + c];
            g_img[c][j] = gi;
            gt = gt + gi * inputs[params.off_bg + c];
        }
        g_tfinal[j] = gt;
    }
    let n_walk = group_max(max(max(last.x, last.y), max(last.z, last.w)));
    var t = t_final;

    for (var kk = 0u; kk < n_walk; kk = kk + 1u) {
        let k = n_walk - 1u - kk;
        let g = tile_vals[range.x + k];
        let mo = proj[2u * g];
        let co = proj[2u * g + 1u];
        let dx = mo.x - lanes.centre_x;
        let dy = vec4<f32>(mo.y) - lanes.centre_y;
        let power = splat_powers(co, dx, dy);
        let near = (vec4<u32>(k) < last) & (power >= vec4<f32>(POWER_CUT));
        if (!any(near)) {
            continue; // beyond 3 sigma of all four pixels: no exp, no feature loads
        }
        let gauss = exp(power);
        let raw = mo.z * gauss;
        let alpha = min(vec4<f32>(ALPHA_MAX), raw);
        let hit = near & (alpha >= vec4<f32>(ALPHA_MIN));
        if (!any(hit)) {
            continue;
        }
        let one_minus = 1.0 - alpha;
        t = select(t, t / one_minus, hit); // transmittance in front of this fragment
        let w = select(vec4<f32>(0.0), alpha * t, hit);
        var g_alpha = vec4<f32>(0.0);
        // This Gaussian's feature gradients summed over the group: each element written below
        // before it is read.
        var g_feat: array<f32, D>;
        let fb = params.off_feat + g * D;
        for (var c = 0u; c < D; c = c + 1u) {
            let f = inputs[fb + c];
            g_alpha = g_alpha + g_img[c] * (f * t - after[c] / one_minus);
            g_feat[c] = group_sum(dot(g_img[c], w));
            after[c] = after[c] + f * w;
        }
        g_alpha = g_alpha + g_z * (mo.w * t - after_z / one_minus);
        g_alpha = g_alpha - g_tfinal * t_final / one_minus;
        after_z = after_z + mo.w * w;
        // alpha = min(ALPHA_MAX, opacity * gauss): the clamp passes no gradient.
        let ga = select(vec4<f32>(0.0), g_alpha, hit & (raw <= vec4<f32>(ALPHA_MAX)));
        let gp = ga * raw;
        // power = -0.5 (a dx^2 + c dy^2) - b dx dy with (dx, dy) = mean2d - pixel.
        let g_mean = vec2<f32>(
            group_sum(-dot(gp, co.x * dx + co.y * dy)),
            group_sum(-dot(gp, co.z * dy + co.y * dx)),
        );
        let g_conic = vec3<f32>(
            group_sum(-0.5 * dx * dx * dot(gp, vec4<f32>(1.0))),
            group_sum(-dot(gp, dx * dy)),
            group_sum(-dot(gp, 0.5 * dy * dy)),
        );
        let g_opacity = group_sum(dot(ga, gauss));
        let g_depth = group_sum(dot(g_z, w));
        if (group_leader()) { // after the sums, in the same active invocations
            let gb = g * params.grad_stride;
            grad_add(gb + 0u, g_mean.x);
            grad_add(gb + 1u, g_mean.y);
            grad_add(gb + 2u, g_conic.x);
            grad_add(gb + 3u, g_conic.y);
            grad_add(gb + 4u, g_conic.z);
            grad_add(gb + 5u, g_opacity);
            grad_add(gb + 6u, g_depth);
            for (var c = 0u; c < D; c = c + 1u) {
                grad_add(gb + GRAD_HEAD + c, g_feat[c]);
            }
        }
    }
}
