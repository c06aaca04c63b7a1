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
fn ray_in_water(cam: View, v: vec3r) -> Ray {
    let n = cam.n;
    let cos_a = dot(n, v);
    if (!(cos_a > 0.0)) {
        return Ray(vec3r(0.0), vec3r(0.0), STATUS_MISSES_INTERFACE);
    }
    let sin2_a = max(1.0 - cos_a * cos_a, 0.0);
    let l1 = lambda1(cam, sin2_a, cos_a);
    if (!l1.ok) {
        return Ray(vec3r(0.0), vec3r(0.0), STATUS_TOTAL_INTERNAL_REFLECTION);
    }
    let d_k = cam.d_k;
    var axis_shift = d_k * (1.0 - l1.value);
    var lateral_length = d_k;
    for (var l = 0u; l < min(params.cams[cam.k].counts.x, MAX_LAYERS); l++) {
        let l2 = lambda2(cam, l, sin2_a, cos_a);
        if (!l2.ok) {
            return Ray(vec3r(0.0), vec3r(0.0), STATUS_TOTAL_INTERNAL_REFLECTION);
        }
        let t = params.cams[cam.k].layers[l].x;
        axis_shift += t * (1.0 - l1.value * l2.value);
        lateral_length += t * l2.value;
    }
    let bent = v + n * (cos_a * (l1.value - 1.0));
    let origin = params.cams[cam.k].centre.xyz + n * axis_shift + bent * (lateral_length / cos_a);
    return Ray(origin, normalize(bent), STATUS_OK);
}

// Back-projection of a raw pixel.
fn backproject(cam: View, pixel: vec2r) -> Ray {
    let v = dir_in_air_from_img(cam, pixel);
    if (v.status != STATUS_OK) {
        return Ray(vec3r(0.0), vec3r(0.0), v.status);
    }
    return ray_in_water(cam, v.dir);
}
