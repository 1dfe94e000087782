// Backward compositing, one workgroup of TILE invocations per tile, a column of two quads of four
// pixels per invocation (vec4 lanes, see splat_common.wgsl): each pixel replays its list back to
// front from the stored final transmittance and last contributor (as 3DGS); an invocation sums
// its pixels' gradients of the 2-D mean, conic, opacity, camera z and features per Gaussian,
// group_sum sums them over its group (the invocations with a fragment of that Gaussian) and the
// group's leader adds each sum to the accumulator with one atomic.
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

// Four pixels' replay state.
struct Quad {
    lanes: Lanes,
    last: vec4<u32>,
    t_final: vec4<f32>,
    t: vec4<f32>, // transmittance in front of the current fragment
    g_z: vec4<f32>,
    g_tfinal: vec4<f32>,
    g_img: array<vec4<f32>, D>,
    // Sums over the fragments behind the current one: sum_j f_j w_j and sum_j z_j w_j.
    after: array<vec4<f32>, D>,
    after_z: vec4<f32>,
}

// One Gaussian's gradient terms, summed over an invocation's pixels.
struct Terms {
    mean: vec2<f32>,
    conic: vec3<f32>,
    opacity: f32,
    depth: f32,
    feat: array<f32, D>,
}

fn quad_init(lanes: Lanes) -> Quad {
    let hw = params.width * params.height;
    var q: Quad;
    q.lanes = lanes;
    q.last = vec4<u32>(0u);
    q.t_final = vec4<f32>(1.0);
    q.g_z = vec4<f32>(0.0);
    q.g_tfinal = vec4<f32>(0.0);
    q.after_z = vec4<f32>(0.0);
    for (var c = 0u; c < D; c = c + 1u) {
        q.g_img[c] = vec4<f32>(0.0);
        q.after[c] = vec4<f32>(0.0);
    }
    for (var j = 0u; j < 4u; j = j + 1u) {
        if (!lanes.inside[j]) {
            continue;
        }
        let pi = lanes.py[j] * params.width + lanes.px;
        let a4 = aux[pi];
        q.t_final[j] = a4.x;
        q.last[j] = bitcast<u32>(a4.y);
        let a = 1.0 - a4.x;
        let gd = grad_in[hw * D + pi];
        let ga = grad_in[hw * (D + 1u) + pi];
        // L depends on T_final through the background, alpha = 1 - T_final and
        // depth = sum(w z) / alpha.
        var gt = -ga;
        if (a > ALPHA_EPS) {
            q.g_z[j] = gd / a;
            gt = gt + gd * (a4.z / a) / a;
        }
        for (var c = 0u; c < D; c = c + 1u) {
            let gi = grad_in[pi * D + c];
            q.g_img[c][j] = gi;
            gt = gt + gi * inputs[params.off_bg + c];
        }
        q.g_tfinal[j] = gt;
    }
    q.t = q.t_final;
    return q;
}

// Step `q` over fragment k (Gaussian g, projected mo / co) and add its terms to `s`; false when
// none of its pixels has a fragment of g.
fn quad_step(
    q: ptr<function, Quad>,
    s: ptr<function, Terms>,
    k: u32,
    g: u32,
    mo: vec4<f32>,
    co: vec4<f32>,
) -> bool {
    let dx = mo.x - (*q).lanes.centre_x;
    let dy = vec4<f32>(mo.y) - (*q).lanes.centre_y;
    let power = splat_powers(co, dx, dy);
    let near = (vec4<u32>(k) < (*q).last) & (power >= vec4<f32>(POWER_CUT));
    if (!any(near)) {
        return false; // beyond 3 sigma of the quad's four pixels: no exp, no feature loads
    }
    let gauss = exp(power);
    let raw = mo.z * gauss;
    let alpha = min(vec4<f32>(ALPHA_MAX), raw);
    let hit = near & (alpha >= vec4<f32>(ALPHA_MIN));
    if (!any(hit)) {
        return false;
    }
    let one_minus = 1.0 - alpha;
    let t = select((*q).t, (*q).t / one_minus, hit);
    (*q).t = t;
    let w = select(vec4<f32>(0.0), alpha * t, hit);
    var g_alpha = vec4<f32>(0.0);
    let fb = params.off_feat + g * D;
    for (var c = 0u; c < D; c = c + 1u) {
        let f = inputs[fb + c];
        let gi = (*q).g_img[c];
        g_alpha = g_alpha + gi * (f * t - (*q).after[c] / one_minus);
        (*s).feat[c] = (*s).feat[c] + dot(gi, w);
        (*q).after[c] = (*q).after[c] + f * w;
    }
    g_alpha = g_alpha + (*q).g_z * (mo.w * t - (*q).after_z / one_minus);
    g_alpha = g_alpha - (*q).g_tfinal * (*q).t_final / one_minus;
    (*q).after_z = (*q).after_z + mo.w * w;
    // alpha = min(ALPHA_MAX, opacity * gauss): the clamp passes no gradient.
    let ga = select(vec4<f32>(0.0), g_alpha, hit & (raw <= vec4<f32>(ALPHA_MAX)));
    let gp = ga * raw;
    // power = -0.5 (a dx^2 + c dy^2) - b dx dy with (dx, dy) = mean2d - pixel.
    let g_mean = vec2<f32>(dot(gp, co.x * dx + co.y * dy), dot(gp, co.z * dy + co.y * dx));
    (*s).mean = (*s).mean - g_mean;
    (*s).conic = (*s).conic - vec3<f32>(
        0.5 * dx * dx * dot(gp, vec4<f32>(1.0)),
        dot(gp, dx * dy),
        dot(gp, 0.5 * dy * dy),
    );
    (*s).opacity = (*s).opacity + dot(ga, gauss);
    (*s).depth = (*s).depth + dot((*q).g_z, w);
    return true;
}

@compute @workgroup_size(TILE, TILE / (4u * QUADS))
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
) {
    var q0 = quad_init(pixel_lanes(wid, lid, 0u));
    var q1 = quad_init(pixel_lanes(wid, lid, 1u));
    let range = ranges[q0.lanes.tile];
    let lasts = max(q0.last, q1.last);
    let n_walk = group_max(max(max(lasts.x, lasts.y), max(lasts.z, lasts.w)));

    for (var kk = 0u; kk < n_walk; kk = kk + 1u) {
        let k = n_walk - 1u - kk;
        let g = tile_vals[range.x + k];
        let mo = proj[2u * g];
        let co = proj[2u * g + 1u];
        var s: Terms;
        s.mean = vec2<f32>(0.0);
        s.conic = vec3<f32>(0.0);
        s.opacity = 0.0;
        s.depth = 0.0;
        for (var c = 0u; c < D; c = c + 1u) {
            s.feat[c] = 0.0;
        }
        let hit0 = quad_step(&q0, &s, k, g, mo, co);
        let hit1 = quad_step(&q1, &s, k, g, mo, co);
        if (!(hit0 || hit1)) {
            continue;
        }
        let g_mean = vec2<f32>(group_sum(s.mean.x), group_sum(s.mean.y));
        let g_conic = vec3<f32>(group_sum(s.conic.x), group_sum(s.conic.y), group_sum(s.conic.z));
        let g_opacity = group_sum(s.opacity);
        let g_depth = group_sum(s.depth);
        var g_feat: array<f32, D>;
        for (var c = 0u; c < D; c = c + 1u) {
            g_feat[c] = group_sum(s.feat[c]);
        }
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
