// Per-correspondence cost over a batch of candidate interfaces: for candidate c = (n, d) and
// correspondence j (the two air rays, master frame), the squared distance between the two water
// rays at their closest approach (the triangulation residual²). The reduction files
// (shaders/reduce/) provide the entry point that sums the terms of a workgroup.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> input: array<real>;        // v_a xyz, v_b xyz per correspondence
@group(0) @binding(2) var<storage, read_write> output: array<real>; // (sum, count) per candidate × workgroup
@group(0) @binding(4) var<storage, read> candidates: array<vec4r>;  // n xyz (unit), d

// (residual², 1) for correspondence j under candidate c, (0, 0) when it has no answer.
fn cost_term(j: u32, c: u32) -> vec2r {
    let candidate = candidates[c];
    let a = with_interface(view(0u), candidate);
    let b = with_interface(view(1u), candidate);
    if (!(a.d_k > 0.0 && b.d_k > 0.0)) {
        return vec2r(0.0); // a camera outside the air
    }
    let k = 6u * j;
    let ray_a = ray_in_water(a, vec3r(input[k], input[k + 1u], input[k + 2u]));
    let ray_b = ray_in_water(b, vec3r(input[k + 3u], input[k + 4u], input[k + 5u]));
    if (ray_a.status != STATUS_OK || ray_b.status != STATUS_OK) {
        return vec2r(0.0);
    }
    let t = triangulate_rays(ray_a, ray_b);
    if (t.status != STATUS_OK) {
        return vec2r(0.0);
    }
    return vec2r(t.residual * t.residual, 1.0);
}
