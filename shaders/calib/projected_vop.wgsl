// Binocular VOPs under candidate axes, projected along n into the plane ⟂ n, with their Jacobian
// for pixel noise: candidate axis n (w unused) × corner → q₁, q₂, then J = ∂q/∂(u_l, v_l, u_r, v_r)
// column by column (8 reals). The host forms the covariance J Jᵀ in f64
// (`ProjectedVop::from_jacobian`): near the degenerate plane it is too ill-conditioned for f32.
// Twin of `calib::invariants::{plane_basis, projected_vop}`; degenerate where the binocular VOP
// is undetermined (the host leaves those corners out).

// Bindings: shaders/calib/candidate_bindings.wgsl (input per corner, 18 reals: v_l xyz, v_r xyz,
// ∂v_l/∂u xyz, ∂v_l/∂v xyz, ∂v_r/∂u xyz, ∂v_r/∂v xyz, master frame).

// e₁ = unit(x − (n·x) n), e₂ = n × e₁: an orthonormal basis of the plane ⟂ n, continuous around
// n = z (tilts below 90°).
fn plane_basis_e1(n: vec3r) -> vec3r {
    return normalize(vec3r(1.0, 0.0, 0.0) - n * n.x);
}

fn corner_dir(k: u32) -> vec3r {
    return vec3r(input[k], input[k + 1u], input[k + 2u]);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    // The cameras before the first branch (common.wgsl, `View`).
    let left = view(0u);
    let right = view(1u);
    let i = item_index(gid, groups);
    if (i >= params.info.x) {
        return;
    }
    let item = candidate_item(i);
    let n = candidates[item.candidate].xyz;
    let k = 18u * item.corner;
    let v_l = corner_dir(k);
    let v_r = corner_dir(k + 3u);
    let bv = binocular_vop(left.centre, v_l, right.centre, v_r, n);
    status[i] = bv.status;
    if (bv.status != STATUS_OK) {
        return;
    }
    let e1 = plane_basis_e1(n);
    let e2 = cross3(n, e1);
    // M = [v, n, −v′]: row 0 of M⁻¹ is (n × −v′)ᵀ / det M. A change dv of the left ray moves
    // s by −(M⁻¹ dv)₀·s, a change dv′ of the right one by (M⁻¹ dv′)₀·s′; the projected point
    // E·(C_l + s v) moves by E·(v ds + s dv).
    let row0 = cross3(n, -v_r) / dot(v_l, cross3(n, -v_r));
    var jacobian = array<vec2r, 4>(); // ∂q/∂(u_l, v_l, u_r, v_r)
    for (var col = 0u; col < 2u; col++) {
        let dv_l = corner_dir(k + 6u + 3u * col);
        let dv_r = corner_dir(k + 12u + 3u * col);
        let dp_l = v_l * (-dot(row0, dv_l) * bv.s_left) + dv_l * bv.s_left;
        let dp_r = v_l * (dot(row0, dv_r) * bv.s_right);
        jacobian[col] = vec2r(dot(e1, dp_l), dot(e2, dp_l));
        jacobian[col + 2u] = vec2r(dot(e1, dp_r), dot(e2, dp_r));
    }
    let o = 10u * i;
    output[o] = dot(e1, bv.vop_left);
    output[o + 1u] = dot(e2, bv.vop_left);
    for (var col = 0u; col < 4u; col++) {
        output[o + 2u + 2u * col] = jacobian[col].x;
        output[o + 3u + 2u * col] = jacobian[col].y;
    }
}
