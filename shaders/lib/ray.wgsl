// Back-projection: raw pixel → air ray → ray in the water. Twin of
// `RefractiveCamera::{dir_in_air_from_img, ray_in_water}` (src/model/refractive_camera.rs).

struct AirDir {
    dir: vec3r,
    status: u32,
}

// Unit viewing direction of a raw pixel, master frame.
fn dir_in_air_from_img(cam: View, pixel: vec2r) -> AirDir {
    let p = normalized_from_img(cam, pixel);
    if (!p.ok) {
        return AirDir(vec3r(0.0), STATUS_OUTSIDE_LENS);
    }
    return AirDir(master_from_cam(cam, normalize(vec3r(p.point, 1.0))), STATUS_OK);
}

struct Ray {
    origin: vec3r,
    dir: vec3r,
    status: u32,
}

// A layer (t, ρ)'s terms of the water ray's axis crossing: (t (1 − λ1 λ2), t λ2, ρ² − sin²a), with
// λ2 = cos a / √(ρ² − sin²a); light enters the layer where the last is positive.
fn layer_shift(layer: vec2r, sin2_a: real, cos_a: real, l1: real) -> vec3r {
    let radicand = layer.y * layer.y - sin2_a;
    let l2 = cos_a / sqrt(radicand);
    return vec3r(layer.x * (1.0 - l1 * l2), layer.x * l2, radicand);
}

// Closed form (thesis 5.2.2): with c = n·v, λ1 and λ2,ᵢ at a, the water ray is
// C_k + [d_k (1 − λ1) + Σ tᵢ (1 − λ1 λ2,ᵢ)]·n + λ·(v + c (λ1 − 1)·n), started on the outer interface.
// The same operations as `RefractiveCamera::ray_in_water`: one division by cos a, and the bent
// direction normalised from 1/ρ_w (|v + c (λ1 − 1)·n|² = ρ_w² for a unit v) with one Newton step
// of 1/√, not a square root and a division.
fn ray_in_water(cam: View, v: vec3r) -> Ray {
    let n = cam.n;
    let cos_a = dot(n, v);
    if (!(cos_a > 0.0)) {
        return Ray(vec3r(0.0), vec3r(0.0), STATUS_MISSES_INTERFACE);
    }
    let sin2_a = max(1.0 - cos_a * cos_a, 0.0);
    let rho_water = cam.rho_water;
    let water_radicand = rho_water * rho_water - sin2_a;
    if (!(water_radicand > 0.0)) {
        return Ray(vec3r(0.0), vec3r(0.0), STATUS_TOTAL_INTERNAL_REFLECTION);
    }
    let inv_cos_a = 1.0 / cos_a;
    let cos_lambda1 = sqrt(water_radicand);
    let l1 = cos_lambda1 * inv_cos_a;
    let d_k = cam.d_k;
    // The first layer (the View's), then the later ones to RIG_LAYERS (common.wgsl), each where
    // the camera has it.
    let first = layer_shift(cam.first_layer.xy, sin2_a, cos_a, l1);
    let has_layer = cam.layers > 0u;
    var axis_shift = d_k * (1.0 - l1) + select(0.0, first.x, has_layer);
    var lateral_length = d_k + select(0.0, first.y, has_layer);
    var reflected = has_layer && !(first.z > 0.0);
    for (var l = 1u; l < RIG_LAYERS; l++) {
        let present = l < cam.layers;
        let next = layer_shift(later_layer(cam, l).xy, sin2_a, cos_a, l1);
        reflected = reflected || (present && !(next.z > 0.0));
        axis_shift += select(0.0, next.x, present);
        lateral_length += select(0.0, next.y, present);
    }
    if (reflected) {
        return Ray(vec3r(0.0), vec3r(0.0), STATUS_TOTAL_INTERNAL_REFLECTION);
    }
    let bent = v + n * (cos_lambda1 - cos_a);
    let origin = cam.centre + n * axis_shift + bent * (lateral_length * inv_cos_a);
    let y = 1.0 / rho_water;
    let scale = y * (1.5 - 0.5 * dot(bent, bent) * y * y);
    return Ray(origin, bent * scale, STATUS_OK);
}

// Back-projection of a raw pixel.
fn backproject(cam: View, pixel: vec2r) -> Ray {
    let v = dir_in_air_from_img(cam, pixel);
    if (v.status != STATUS_OK) {
        return Ray(vec3r(0.0), vec3r(0.0), v.status);
    }
    return ray_in_water(cam, v.dir);
}
