// Forward projection under candidate interfaces: candidate (n, d) × point (master frame, one per
// item: the candidate's fitted board corner) → ul, vl, ur, vr (raw pixels in both cameras). Twin
// of the projection in `calib::costs::reprojection_residuals`.

// Bindings: shaders/kernels/candidate_bindings.wgsl (input: x, y, z per item).

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item_index(gid, groups);
    if (i >= params.info.x) {
        return;
    }
    let cameras = candidate_cameras(i);
    if (!cameras.in_air) {
        status[i] = STATUS_MISSES_INTERFACE; // a camera outside the air
        return;
    }
    let a = cameras.a;
    let b = cameras.b;
    let point = vec3r(input[3u * i], input[3u * i + 1u], input[3u * i + 2u]);
    let left = project(a, point);
    if (left.status != STATUS_OK) {
        status[i] = left.status;
        return;
    }
    let right = project(b, point);
    status[i] = right.status;
    if (right.status == STATUS_OK) {
        let o = 4u * i;
        output[o] = left.pixel.x;
        output[o + 1u] = left.pixel.y;
        output[o + 2u] = right.pixel.x;
        output[o + 3u] = right.pixel.y;
    }
}
