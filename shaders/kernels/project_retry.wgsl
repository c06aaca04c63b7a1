// The safeguarded forward projection (`project_safeguarded.wgsl`) of the rows `project.wgsl` left
// with STATUS_RETRY, in place: for rows that stay on the device, where the host cannot gather them.
// Every other row keeps what `project.wgsl` wrote.

// Bindings: shaders/kernels/map_bindings.wgsl (input and output rows, status).

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    // The cameras before the first branch (common.wgsl, `View`).
    let cam = view(0u);
    let i = item_index(gid, groups);
    if (i >= params.info.x || status[i] != STATUS_RETRY) {
        return;
    }
    let p = project(cam, vec3r(input[3u * i], input[3u * i + 1u], input[3u * i + 2u]));
    status[i] = p.status;
    if (p.status == STATUS_OK) {
        output[2u * i] = p.pixel.x;
        output[2u * i + 1u] = p.pixel.y;
    }
}
