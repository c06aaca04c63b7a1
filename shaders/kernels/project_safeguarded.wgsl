// Forward projection with every safeguard (`project`: reference-medium switching, bracket,
// bisection, critical angles, overflow): x,y,z (master frame) → u,v (raw pixel). The host runs it
// on the rows `project.wgsl` leaves (status STATUS_RETRY).

// Bindings: shaders/kernels/map_bindings.wgsl (input and output rows, status).

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    // The cameras before the first branch (common.wgsl, `View`).
    let cam = view(0u);
    let i = item_index(gid, groups);
    if (i >= params.info.x) {
        return;
    }
    let p = project(cam, vec3r(input[3u * i], input[3u * i + 1u], input[3u * i + 2u]));
    status[i] = p.status;
    if (p.status == STATUS_OK) {
        output[2u * i] = p.pixel.x;
        output[2u * i + 1u] = p.pixel.y;
    }
}
