// Forward projection: x,y,z (master frame) → u,v (raw pixel), by `project_near` from tan a = 0
// (its first step lands on the paraxial root): the unbracketed Newton iteration where no medium is
// less dense than air. Rows it does not settle get STATUS_RETRY, and the host runs them through
// `project_safeguarded.wgsl` (every safeguard of `project`). On lavapipe, which runs every branch
// of a shader masked, the safeguards cost every row every step: this kernel runs ~3× as many rows
// per second.

// Bindings: shaders/kernels/map_bindings.wgsl (input and output rows, status).

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    // The cameras before the first branch (common.wgsl, `View`).
    let cam = view(0u);
    let i = item_index(gid, groups);
    if (i >= params.info.x) {
        return;
    }
    let point = vec3r(input[3u * i], input[3u * i + 1u], input[3u * i + 2u]);
    let p = project_near(cam, point, 0.0);
    status[i] = select(STATUS_RETRY, p.pixel.status, p.converged);
    if (p.converged && p.pixel.status == STATUS_OK) {
        output[2u * i] = p.pixel.pixel.x;
        output[2u * i + 1u] = p.pixel.pixel.y;
    }
}
