// The float32 atomicAdd build of rasterize_bwd.wgsl's gradient accumulator (adapters with
// SHADER_FLOAT32_ATOMIC). grads_cas.wgsl is the same binding for every other adapter.

// Per Gaussian (grad_stride = GRAD_HEAD + D floats): mean2d x, y, conic a, b, c, opacity, z,
// unused, then the D features.
@group(0) @binding(7) var<storage, read_write> grads: array<atomic<f32>>;

fn grad_add(i: u32, v: f32) {
    atomicAdd(&grads[i], v);
}
