// Back-projection of a pixel buffer: u,v → ox,oy,oz,dx,dy,dz (ray in the water, master frame).

// Bindings: shaders/kernels/map_bindings.wgsl (input and output rows, status).

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    // The cameras before the first branch (common.wgsl, `View`).
    let cam = view(0u);
    let i = item_index(gid, groups);
    if (i >= params.info.x) {
        return;
    }
    let ray = backproject(cam, vec2r(input[2u * i], input[2u * i + 1u]));
    status[i] = ray.status;
    if (ray.status == STATUS_OK) {
        let o = 6u * i;
        output[o] = ray.origin.x;
        output[o + 1u] = ray.origin.y;
        output[o + 2u] = ray.origin.z;
        output[o + 3u] = ray.dir.x;
        output[o + 4u] = ray.dir.y;
        output[o + 5u] = ray.dir.z;
    }
}
