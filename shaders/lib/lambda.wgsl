// The λ relations (thesis eqs 4.2, 4.6) and the virtual-from-real relation (eq 4.8) for N layers,
// in terms of sin²a and cos a of the angle of incidence in air. Twin of src/model/vop.rs.

// λ1 = √(ρ_w² − sin²a) / cos a (eq 4.2); not ok on total internal reflection.
fn lambda1(cam: View, sin2_a: real, cos_a: real) -> Maybe {
    let radicand = cam.rho_water * cam.rho_water - sin2_a;
    return Maybe(sqrt(max(radicand, 0.0)) / cos_a, radicand > 0.0 && cos_a > 0.0);
}

// λ2 = cos a / √(ρ² − sin²a) (eq 4.6) for a layer of index ratio ρ; not ok on total internal
// reflection.
fn lambda2(rho: real, sin2_a: real, cos_a: real) -> Maybe {
    let radicand = rho * rho - sin2_a;
    return Maybe(cos_a / sqrt(max(radicand, 0.0)), radicand > 0.0 && cos_a > 0.0);
}

// x̌ = x / λ1 − Σ tᵢ (1 − λ2,ᵢ) (eq 4.8): VOP distance of a point at depth x.
fn virtual_from_real(cam: View, depth: real, sin2_a: real, cos_a: real) -> Maybe {
    let l1 = lambda1(cam, sin2_a, cos_a);
    // The first layer (the View's), then the later ones to RIG_LAYERS (common.wgsl), each where
    // the camera has it.
    let has_layer = cam.layers > 0u;
    let first = lambda2(cam.first_layer.y, sin2_a, cos_a);
    var ok = l1.ok && (first.ok || !has_layer);
    var value = depth / l1.value - select(0.0, cam.first_layer.x * (1.0 - first.value), has_layer);
    for (var l = 1u; l < RIG_LAYERS; l++) {
        let present = l < cam.layers;
        let layer = later_layer(cam, l);
        let l2 = lambda2(layer.y, sin2_a, cos_a);
        ok = ok && (l2.ok || !present);
        value -= select(0.0, layer.x * (1.0 - l2.value), present);
    }
    return Maybe(value, ok);
}
