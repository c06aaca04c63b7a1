// Virtual Object Points: x,y,z → depth, vop_distance, vop_x, vop_y, vop_z, tan a (the host turns
// tan a into the angle: WGSL has no f64 arctangent).

// Bindings: shaders/kernels/map_bindings.wgsl (input and output rows, status).

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    // The cameras before the first branch (common.wgsl, `View`).
    let cam = view(0u);
    let i = item_index(gid, groups);
    if (i >= params.info.x) {
        return;
    }
    let v = vop(cam, vec3r(input[3u * i], input[3u * i + 1u], input[3u * i + 2u]));
    status[i] = v.status;
    if (v.status == STATUS_OK) {
        let o = 6u * i;
        output[o] = v.depth;
        output[o + 1u] = v.vop_distance;
        output[o + 2u] = v.vop.x;
        output[o + 3u] = v.vop.y;
        output[o + 4u] = v.vop.z;
        output[o + 5u] = v.tan_a;
    }
}
