// Refractive triangulation: ul,vl,ur,vr (raw pixels in cameras a and b) → x,y,z,residual.

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
    // Host rows carry no status of their own (the engine marks rows beyond the precision as it
    // reads the answers back).
    let t = triangulate_pixels(left, right, vec2r(input[j], input[j + 1u]), STATUS_OK,
                               vec2r(input[j + 2u], input[j + 3u]), STATUS_OK);
    status[i] = t.status;
    if (t.status == STATUS_OK) {
        output[j] = t.point.x;
        output[j + 1u] = t.point.y;
        output[j + 2u] = t.point.z;
        output[j + 3u] = t.residual;
    }
}
