// Forward projection: x,y,z (master frame) → u,v (raw pixel), by `project_near_pair` from tan a = 0
// (its first step lands on the paraxial root): the unbracketed Newton iteration where no medium is
// less dense than air. Rows it does not settle get STATUS_RETRY, and the host runs them through
// `project_safeguarded.wgsl` (every safeguard of `project`). On lavapipe, which runs every branch
// of a shader masked, the safeguards cost every row every step: this kernel runs ~3× as many rows
// per second.
//
// Two rows per invocation (`Kernel::rows_per_invocation`), rows 2j and 2j + 1, iterated in one
// loop (`project_near_pair`): on a CPU driver the two chains of dependent divisions overlap. The
// last invocation of an odd count projects its one row twice and writes it once.

// Bindings: shaders/kernels/map_bindings.wgsl (input and output rows, status).

fn point_row(i: u32) -> vec3r {
    return vec3r(input[3u * i], input[3u * i + 1u], input[3u * i + 2u]);
}

fn write_row(i: u32, p: NearPixel) {
    status[i] = select(STATUS_RETRY, p.pixel.status, p.converged);
    if (p.converged && p.pixel.status == STATUS_OK) {
        output[2u * i] = p.pixel.pixel.x;
        output[2u * i + 1u] = p.pixel.pixel.y;
    }
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    // The cameras before the first branch (common.wgsl, `View`).
    let cam = view(0u);
    let i = 2u * item_index(gid, groups);
    if (i >= params.info.x) {
        return;
    }
    let second = min(i + 1u, params.info.x - 1u);
    let p = project_near_pair(cam, point_row(i), cam, point_row(second), vec2r(0.0));
    write_row(i, p.a);
    if (second != i) {
        write_row(second, p.b);
    }
}
