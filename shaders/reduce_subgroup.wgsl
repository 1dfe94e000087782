// The subgroup build of rasterize_bwd.wgsl's gradient reduction (adapters with wgpu's SUBGROUP:
// most GPUs, and lavapipe, whose subgroup is its 8 SIMD lanes). A subgroup walks its tile's list
// in lock-step from its deepest last contributor, so its invocations hold the same Gaussian at
// each step; those with a fragment of it sum their terms across the subgroup and one of them adds
// each sum with one atomic, instead of each adding its own: up to subgroup-size times fewer
// atomics, which contend on a GPU and cost a compare-and-swap loop each on the CAS path.
// Invocations with nothing at a step skip it on their own (`continue`): the sums and the leader
// are over the invocations still active, which are exactly those with terms to add. A
// subgroup-uniform skip (subgroupAny) was slower on lavapipe, where it is a loop over the lanes
// and a per-invocation skip is one mask test.
// reduce_invocation.wgsl is the same interface for every other adapter.

// The loop bound shared by the subgroup: its largest per-invocation bound.
fn group_max(x: u32) -> u32 {
    return subgroupMax(x);
}

// The sum of `v` over the active invocations of the subgroup, in each of them.
fn group_sum(v: f32) -> f32 {
    return subgroupAdd(v);
}

// True in one active invocation of the subgroup: the one that adds the sums (WGSL has no
// subgroupElect; this is the first active one).
fn group_leader() -> bool {
    return subgroupExclusiveAdd(1u) == 0u;
}
