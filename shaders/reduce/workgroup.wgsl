// Entry point of a cost kernel, portable reduction: workgroup (WORKGROUP_SIZE correspondences) ×
// candidate; the terms are summed by a tree in workgroup memory (WORKGROUP_SIZE a power of two),
// one (sum, count) per workgroup and candidate. info.x = correspondences.

var<workgroup> partial: array<vec2r, WORKGROUP_SIZE>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) li: u32,
        @builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    var term = vec2r(0.0);
    if (gid.x < params.info.x) {
        term = cost_term(gid.x, wid.y);
    }
    partial[li] = term;
    for (var stride = WORKGROUP_SIZE / 2u; stride > 0u; stride >>= 1u) {
        workgroupBarrier();
        if (li < stride) {
            partial[li] += partial[li + stride];
        }
    }
    if (li == 0u) {
        let o = 2u * (wid.y * groups.x + wid.x);
        output[o] = partial[0].x;
        output[o + 1u] = partial[0].y;
    }
}
