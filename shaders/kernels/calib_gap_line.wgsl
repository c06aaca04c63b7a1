// The signed gap between the two water rays of a corner as a line in the air layer, under
// candidate axes: candidate axis n (w unused) × corner (its two air rays) → a, b, |w_l × w_r| with
// g(d) = m·(o_l(d) − o_r(d)) = a·d + b, m = unit(w_l × w_r). Twin of `calib::air_layer::gap_line`:
// the water directions do not depend on d and the origins move linearly with it, so the rays at
// d = 0 and d = 1 m give the line exactly (d_k may be negative here: only the line is wanted).

// Bindings: shaders/kernels/candidate_bindings.wgsl (input: v_l xyz, v_r xyz per corner).

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item_index(gid, groups);
    if (i >= params.info.x) {
        return;
    }
    let item = candidate_item(i);
    let n = candidates[item.candidate].xyz;
    let k = 6u * item.corner;
    let v_l = vec3r(input[k], input[k + 1u], input[k + 2u]);
    let v_r = vec3r(input[k + 3u], input[k + 4u], input[k + 5u]);
    let l0 = ray_in_water(with_interface(0u, vec4r(n, 0.0)), v_l);
    let r0 = ray_in_water(with_interface(1u, vec4r(n, 0.0)), v_r);
    if (l0.status != STATUS_OK) {
        status[i] = l0.status;
        return;
    }
    if (r0.status != STATUS_OK) {
        status[i] = r0.status;
        return;
    }
    let w = cross3(l0.dir, r0.dir);
    let sin_angle = length(w);
    if (!(sin_angle > 0.0)) {
        status[i] = STATUS_DEGENERATE; // parallel rays: no sign for the gap
        return;
    }
    status[i] = STATUS_OK;
    // Same directions and statuses at any air layer: only the origins move.
    let l1 = ray_in_water(with_interface(0u, vec4r(n, 1.0)), v_l);
    let r1 = ray_in_water(with_interface(1u, vec4r(n, 1.0)), v_r);
    let m = w / sin_angle;
    let g0 = dot(m, l0.origin - r0.origin);
    let g1 = dot(m, l1.origin - r1.origin);
    let o = 3u * i;
    output[o] = g1 - g0;
    output[o + 1u] = g0;
    output[o + 2u] = sin_angle;
}
