// Triangulation under candidate interfaces: candidate (n, d) × corner (its two air rays v_l, v_r,
// master frame) → x, y, z, gap (midpoint of the closest approach of the two water rays and their
// distance there). Twin of `calib::costs::triangulate_corner`.

// Bindings: shaders/calib/candidate_bindings.wgsl (input: v_l xyz, v_r xyz per corner).

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
    let item = cameras.item;
    let a = cameras.a;
    let b = cameras.b;
    let k = 6u * item.corner;
    let ray_a = ray_in_water(a, vec3r(input[k], input[k + 1u], input[k + 2u]));
    if (ray_a.status != STATUS_OK) {
        status[i] = ray_a.status;
        return;
    }
    let ray_b = ray_in_water(b, vec3r(input[k + 3u], input[k + 4u], input[k + 5u]));
    if (ray_b.status != STATUS_OK) {
        status[i] = ray_b.status;
        return;
    }
    let t = triangulate_rays(ray_a, ray_b);
    status[i] = t.status;
    if (t.status == STATUS_OK) {
        let o = 4u * i;
        output[o] = t.point.x;
        output[o + 1u] = t.point.y;
        output[o + 2u] = t.point.z;
        output[o + 3u] = t.residual;
    }
}
