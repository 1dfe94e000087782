// Pass 1, one thread per Gaussian: 3-D mean, scale, rotation -> 2-D mean, conic, depth, 3-sigma
// radius (0 = culled), and the depth sort key (float bits of camera z; culled ones sort last).

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> inputs: array<f32>;
// Two vec4 per Gaussian: (mean2d.x, mean2d.y, opacity, z), (conic.a, conic.b, conic.c, radius).
@group(0) @binding(2) var<storage, read_write> proj: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> depth_keys: array<u32>;
@group(0) @binding(4) var<storage, read_write> depth_vals: array<u32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 256u;
    if (i >= params.n) {
        return;
    }
    let pr = project_gaussian(i);
    if (pr.valid) {
        proj[2u * i] = vec4<f32>(pr.mean2d, inputs[params.off_opac + i], pr.p.z);
        proj[2u * i + 1u] = vec4<f32>(pr.conic, pr.radius);
        // z >= near > 0, and the bits of a positive float sort like the float.
        depth_keys[i] = bitcast<u32>(pr.p.z);
    } else {
        proj[2u * i] = vec4<f32>(0.0);
        proj[2u * i + 1u] = vec4<f32>(0.0);
        depth_keys[i] = CULLED_KEY;
    }
    depth_vals[i] = i;
}
