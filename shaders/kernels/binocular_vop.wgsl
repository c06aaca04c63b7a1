// Binocular VOPs from the system axis alone: ul,vl,ur,vr (raw pixels in cameras a and b) →
// left VOP xyz, right VOP xyz, axis offset m, conditioning |det|.

// Bindings: shaders/kernels/map_bindings.wgsl (input and output rows, status).

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    // The cameras before the first branch (common.wgsl, `View`).
    let left = view(0u);
    let right = view(1u);
    let i = item_index(gid, groups);
    if (i >= params.info.x) {
        return;
    }
    let j = 4u * i;
    let v_l = dir_in_air_from_img(left, vec2r(input[j], input[j + 1u]));
    if (v_l.status != STATUS_OK) {
        status[i] = v_l.status;
        return;
    }
    let v_r = dir_in_air_from_img(right, vec2r(input[j + 2u], input[j + 3u]));
    if (v_r.status != STATUS_OK) {
        status[i] = v_r.status;
        return;
    }
    let b = binocular_vop(left.centre, v_l.dir, right.centre, v_r.dir, left.n);
    status[i] = b.status;
    if (b.status == STATUS_OK) {
        let o = 8u * i;
        output[o] = b.vop_left.x;
        output[o + 1u] = b.vop_left.y;
        output[o + 2u] = b.vop_left.z;
        output[o + 3u] = b.vop_right.x;
        output[o + 4u] = b.vop_right.y;
        output[o + 5u] = b.vop_right.z;
        output[o + 6u] = b.axis_offset;
        output[o + 7u] = b.conditioning;
    }
}
