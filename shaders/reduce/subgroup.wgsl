// Entry point of a cost kernel, subgroup reduction (adapters with SUBGROUP): each subgroup sums
// its terms with subgroupAdd, the subgroup sums meet in workgroup memory, one (sum, count) per
// workgroup and candidate. info.x = correspondences.

var<workgroup> partial: array<vec2r, WORKGROUP_SIZE>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32,
        @builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>,
        @builtin(subgroup_id) subgroup: u32, @builtin(num_subgroups) subgroups: u32,
        @builtin(subgroup_invocation_id) lane: u32) {
    var term = vec2r(0.0);
    if (gid.x < params.info.x) {
        term = cost_term(gid.x, wid.y);
    }
    let sum = subgroupAdd(term);
    if (lane == 0u) {
        partial[subgroup] = sum;
    }
    workgroupBarrier();
    if (li == 0u) {
        var total = vec2r(0.0);
        for (var s = 0u; s < subgroups; s++) {
            total += partial[s];
        }
        let o = 2u * (wid.y * groups.x + wid.x);
        output[o] = total.x;
        output[o + 1u] = total.y;
    }
}
