// Projection backward, one thread per Gaussian: gradients of the 2-D mean, conic and camera z
// (accumulated by rasterize_bwd.wgsl) -> gradients of the 3-D mean, quaternion and scales.
// Writes 10 floats per Gaussian: mean (3), quaternion (4), scale (3).

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> inputs: array<f32>;
@group(0) @binding(2) var<storage, read> grads: array<f32>;
@group(0) @binding(3) var<storage, read_write> param_grads: array<f32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 256u;
    if (i >= params.n) {
        return;
    }
    let ob = PARAM_GRADS * i;
    let pr = project_gaussian(i);
    if (!pr.valid) {
        for (var k = 0u; k < PARAM_GRADS; k = k + 1u) {
            param_grads[ob + k] = 0.0;
        }
        return;
    }
    let gb = i * params.grad_stride;
    let g_mean2d = vec2<f32>(grads[gb], grads[gb + 1u]);
    let g_conic = vec3<f32>(grads[gb + 2u], grads[gb + 3u], grads[gb + 4u]);
    let g_depth = grads[gb + 6u];
    let p = pr.p;
    let z = p.z;
    let z2 = z * z;
    let fx = params.fx;
    let fy = params.fy;

    // conic = inverse(cov2d): dL/dcov2d = -conic G conic, G the symmetric matrix of dL/dconic.
    let cm = mat2x2<f32>(pr.conic.x, pr.conic.y, pr.conic.y, pr.conic.z);
    let gm = mat2x2<f32>(g_conic.x, 0.5 * g_conic.y, 0.5 * g_conic.y, g_conic.z);
    let g_cov2d = (cm * gm * cm) * -1.0;
    // cov2d = J cov_cam J^T (+ low-pass).
    let g_cov_cam = transpose(pr.jac) * g_cov2d * pr.jac;
    let g_jac = 2.0 * (g_cov2d * pr.jac * pr.cov_cam);

    var gp = vec3<f32>(0.0, 0.0, g_depth);
    // mean2d = (fx x / z + cx, fy y / z + cy)
    gp.x = gp.x + g_mean2d.x * fx / z;
    gp.y = gp.y + g_mean2d.y * fy / z;
    gp.z = gp.z - (g_mean2d.x * fx * p.x + g_mean2d.y * fy * p.y) / z2;
    // J = [[fx/z, 0, -fx u/z], [0, fy/z, -fy v/z]], u = clamp(x/z), v = clamp(y/z)
    let gj00 = g_jac[0][0];
    let gj11 = g_jac[1][1];
    let gj02 = g_jac[2][0];
    let gj12 = g_jac[2][1];
    gp.z = gp.z + (-gj00 * fx + gj02 * fx * pr.u - gj11 * fy + gj12 * fy * pr.v) / z2;
    let gu = -gj02 * fx / z;
    let gv = -gj12 * fy / z;
    if (pr.u_free) {
        gp.x = gp.x + gu / z;
        gp.z = gp.z - gu * p.x / z2;
    }
    if (pr.v_free) {
        gp.y = gp.y + gv / z;
        gp.z = gp.z - gv * p.y / z2;
    }
    let w = view_rot();
    let g_mean = transpose(w) * gp;

    // cov_cam = W (M M^T) W^T with M = R diag(s).
    let g_cov3 = transpose(w) * g_cov_cam * w;
    let mm = mat3x3<f32>(pr.rot[0] * pr.scale.x, pr.rot[1] * pr.scale.y, pr.rot[2] * pr.scale.z);
    let g_m = 2.0 * (g_cov3 * mm);
    let g_scale = vec3<f32>(dot(g_m[0], pr.rot[0]), dot(g_m[1], pr.rot[1]), dot(g_m[2], pr.rot[2]));
    let g_rot = mat3x3<f32>(g_m[0] * pr.scale.x, g_m[1] * pr.scale.y, g_m[2] * pr.scale.z);

    // R(q) for the normalised q = (w, x, y, z); g_rot[c][r] is dL/dR[r][c].
    let qw = pr.qn.x;
    let qx = pr.qn.y;
    let qy = pr.qn.z;
    let qz = pr.qn.w;
    let r00 = g_rot[0][0];
    let r01 = g_rot[1][0];
    let r02 = g_rot[2][0];
    let r10 = g_rot[0][1];
    let r11 = g_rot[1][1];
    let r12 = g_rot[2][1];
    let r20 = g_rot[0][2];
    let r21 = g_rot[1][2];
    let r22 = g_rot[2][2];
    let g_qn = 2.0 * vec4<f32>(
        -qz * r01 + qy * r02 + qz * r10 - qx * r12 - qy * r20 + qx * r21,
        qy * r01 + qz * r02 + qy * r10 - 2.0 * qx * r11 - qw * r12 + qz * r20 + qw * r21 - 2.0 * qx * r22,
        -2.0 * qy * r00 + qx * r01 + qw * r02 + qx * r10 + qz * r12 - qw * r20 + qz * r21 - 2.0 * qy * r22,
        -2.0 * qz * r00 - qw * r01 + qx * r02 + qw * r10 - 2.0 * qz * r11 + qy * r12 + qx * r20 + qy * r21,
    );
    // qn = q / sqrt(max(|q|^2, eps)): below the floor the map is linear.
    let q = pr.qn * pr.qlen;
    var g_q = g_qn / pr.qlen;
    if (dot(q, q) > QUAT_EPS2) {
        g_q = (g_qn - pr.qn * dot(pr.qn, g_qn)) / pr.qlen;
    }
    param_grads[ob] = g_mean.x;
    param_grads[ob + 1u] = g_mean.y;
    param_grads[ob + 2u] = g_mean.z;
    param_grads[ob + 3u] = g_q.x;
    param_grads[ob + 4u] = g_q.y;
    param_grads[ob + 5u] = g_q.z;
    param_grads[ob + 6u] = g_q.w;
    param_grads[ob + 7u] = g_scale.x;
    param_grads[ob + 8u] = g_scale.y;
    param_grads[ob + 9u] = g_scale.z;
}
