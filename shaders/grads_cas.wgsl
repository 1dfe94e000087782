// The compare-and-swap build of rasterize_bwd.wgsl's gradient accumulator: float32 bit patterns
// in atomic<u32> words, for adapters without float atomics (grads_float.wgsl otherwise).

// Per Gaussian (grad_stride = GRAD_HEAD + D floats): mean2d x, y, conic a, b, c, opacity, z,
// unused, then the D features.
@group(0) @binding(7) var<storage, read_write> grads: array<atomic<u32>>;

fn grad_add(i: u32, v: f32) {
    var old = atomicLoad(&grads[i]);
    loop {
        let r = atomicCompareExchangeWeak(&grads[i], old, bitcast<u32>(bitcast<f32>(old) + v));
        if (r.exchanged) {
            break;
        }
        old = r.old_value;
    }
}
