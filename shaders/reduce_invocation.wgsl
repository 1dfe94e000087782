// The build of rasterize_bwd.wgsl's gradient reduction for adapters without subgroup operations
// (reduce_subgroup.wgsl otherwise): every invocation walks its own list and adds its own terms,
// one atomic per value per Gaussian it touches.

fn group_max(x: u32) -> u32 {
    return x;
}

fn group_sum(v: f32) -> f32 {
    return v;
}

fn group_leader() -> bool {
    return true;
}
