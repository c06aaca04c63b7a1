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
    let rho_water = params.cams[cam.k].extra.z;
    let water_radicand = rho_water * rho_water - sin2_a;
    if (!(water_radicand > 0.0)) {
        return Ray(vec3r(0.0), vec3r(0.0), STATUS_TOTAL_INTERNAL_REFLECTION);
    }
    let inv_cos_a = 1.0 / cos_a;
    // cos a·λ1 = √(ρ_w² − sin²a) = ρ_w cos θ_w.
    let cos_lambda1 = sqrt(water_radicand);
    let l1 = cos_lambda1 * inv_cos_a;
    let d_k = cam.d_k;
    var axis_shift = d_k * (1.0 - l1);
    var lateral_length = d_k;
    var reflected = false;
    for (var l = 0u; l < min(params.cams[cam.k].counts.x, MAX_LAYERS); l++) {
        let layer = params.cams[cam.k].layers[l].xy;
        let radicand = layer.y * layer.y - sin2_a;
        reflected = reflected || !(radicand > 0.0);
        let l2 = cos_a / sqrt(radicand);
        axis_shift += layer.x * (1.0 - l1 * l2);
        lateral_length += layer.x * l2;
    }
    if (reflected) {
        return Ray(vec3r(0.0), vec3r(0.0), STATUS_TOTAL_INTERNAL_REFLECTION);
    }
    let bent = v + n * (cos_lambda1 - cos_a);
    let origin = params.cams[cam.k].centre.xyz + n * axis_shift + bent * (lateral_length * inv_cos_a);
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
