// The projection maths shared by project.wgsl (forward) and project_bwd.wgsl (backward), so the
// backward pass recomputes exactly what the forward pass computed. Needs `params` and `inputs`.

// Everything the projection computes, with the intermediates its backward pass needs.
struct Projected {
    valid: bool,
    p: vec3<f32>, // camera-space mean
    mean2d: vec2<f32>,
    conic: vec3<f32>, // inverse 2-D covariance (a, b, c) of [[a, b], [b, c]]
    radius: f32,
    qn: vec4<f32>, // normalised quaternion (w, x, y, z)
    qlen: f32, // sqrt(max(|q|^2, QUAT_EPS2))
    rot: mat3x3<f32>,
    scale: vec3<f32>,
    cov_cam: mat3x3<f32>,
    jac: mat3x2<f32>, // 2x3 EWA Jacobian (3 columns, 2 rows)
    u: f32, // x/z clamped to the guard band
    v: f32,
    u_free: bool, // x/z was inside the guard band (the clamp passes gradients)
    v_free: bool,
}

fn view_rot() -> mat3x3<f32> {
    let v = params.view;
    return mat3x3<f32>(v[0].xyz, v[1].xyz, v[2].xyz);
}

fn quat_to_rot(q: vec4<f32>) -> mat3x3<f32> {
    let w = q.x;
    let x = q.y;
    let y = q.z;
    let z = q.w;
    return mat3x3<f32>(
        vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        vec3<f32>(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        vec3<f32>(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)),
    );
}

fn project_gaussian(i: u32) -> Projected {
    var o: Projected;
    o.valid = false;
    let m = vec3<f32>(inputs[3u * i], inputs[3u * i + 1u], inputs[3u * i + 2u]);
    let p = (params.view * vec4<f32>(m, 1.0)).xyz;
    o.p = p;
    // Near/far culling; `!(...)` also culls NaN.
    if (!(p.z >= params.near && p.z <= params.far)) {
        return o;
    }
    // Too faint to draw anywhere (alpha <= opacity < ALPHA_MIN): culled here, so it costs no
    // tile work. With time-local opacity most Gaussians of a fast object are, at any one time.
    if (!(inputs[params.off_opac + i] >= ALPHA_MIN)) {
        return o;
    }
    let qb = params.off_quats + 4u * i;
    let q = vec4<f32>(inputs[qb], inputs[qb + 1u], inputs[qb + 2u], inputs[qb + 3u]);
    o.qlen = sqrt(max(dot(q, q), QUAT_EPS2));
    o.qn = q / o.qlen;
    o.rot = quat_to_rot(o.qn);
    let sb = params.off_scales + 3u * i;
    o.scale = vec3<f32>(inputs[sb], inputs[sb + 1u], inputs[sb + 2u]);
    let mm = mat3x3<f32>(o.rot[0] * o.scale.x, o.rot[1] * o.scale.y, o.rot[2] * o.scale.z);
    let w = view_rot();
    o.cov_cam = w * (mm * transpose(mm)) * transpose(w);
    let z = p.z;
    let xz = p.x / z;
    let yz = p.y / z;
    o.u = clamp(xz, -params.lim_x_neg, params.lim_x_pos);
    o.v = clamp(yz, -params.lim_y_neg, params.lim_y_pos);
    o.u_free = xz >= -params.lim_x_neg && xz <= params.lim_x_pos;
    o.v_free = yz >= -params.lim_y_neg && yz <= params.lim_y_pos;
    o.jac = mat3x2<f32>(
        vec2<f32>(params.fx / z, 0.0),
        vec2<f32>(0.0, params.fy / z),
        vec2<f32>(-params.fx * o.u / z, -params.fy * o.v / z),
    );
    let cov = o.jac * o.cov_cam * transpose(o.jac);
    let a = cov[0][0] + LOW_PASS;
    let b = cov[1][0];
    let c = cov[1][1] + LOW_PASS;
    if (!(a <= MAX_VAR_PX && c <= MAX_VAR_PX)) {
        return o;
    }
    let det = a * c - b * b;
    if (!(det > 0.0)) {
        return o;
    }
    o.conic = vec3<f32>(c / det, -b / det, a / det);
    o.mean2d = vec2<f32>(params.fx * xz + params.cx, params.fy * yz + params.cy);
    let mid = 0.5 * (a + c);
    let lambda = mid + sqrt(max(0.1, mid * mid - det));
    o.radius = ceil(3.0 * sqrt(lambda));
    let r = tile_rect(o.mean2d, o.radius, 0u, params.image_tiles_y); // the image's, not the band's
    if (r.z <= r.x || r.w <= r.y) {
        return o;
    }
    o.valid = true;
    return o;
}
