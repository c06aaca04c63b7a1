// The λ relations (thesis eqs 4.2, 4.6) and the virtual-from-real relation (eq 4.8) for N layers,
// in terms of sin²a and cos a of the angle of incidence in air. Twin of src/model/vop.rs.

// λ1 = √(ρ_w² − sin²a) / cos a (eq 4.2); not ok on total internal reflection.
fn lambda1(cam: View, sin2_a: real, cos_a: real) -> Maybe {
    let radicand = params.cams[cam.k].extra.z * params.cams[cam.k].extra.z - sin2_a;
    return Maybe(sqrt(max(radicand, 0.0)) / cos_a, radicand > 0.0 && cos_a > 0.0);
}

// λ2,ᵢ = cos a / √(ρᵢ² − sin²a) (eq 4.6) for layer i; not ok on total internal reflection.
fn lambda2(cam: View, layer: u32, sin2_a: real, cos_a: real) -> Maybe {
    let rho = params.cams[cam.k].layers[layer].y;
    let radicand = rho * rho - sin2_a;
    return Maybe(cos_a / sqrt(max(radicand, 0.0)), radicand > 0.0 && cos_a > 0.0);
}

// x̌ = x / λ1 − Σ tᵢ (1 − λ2,ᵢ) (eq 4.8): VOP distance of a point at depth x.
fn virtual_from_real(cam: View, depth: real, sin2_a: real, cos_a: real) -> Maybe {
    let l1 = lambda1(cam, sin2_a, cos_a);
    var ok = l1.ok;
    var value = depth / l1.value;
    for (var l = 0u; l < min(params.cams[cam.k].counts.x, MAX_LAYERS); l++) {
        let l2 = lambda2(cam, l, sin2_a, cos_a);
        ok = ok && l2.ok;
        value -= params.cams[cam.k].layers[l].x * (1.0 - l2.value);
    }
    return Maybe(value, ok);
}
