// Two cameras: midpoint triangulation of water rays and binocular VOPs (thesis 5.3). Twin of
// src/model/stereo.rs.

struct Triangulation {
    point: vec3r,
    residual: real,
    status: u32,
}

// Midpoint of the closest approach of two rays and their distance there; degenerate for nearly
// parallel rays, not in the water when the approach lies behind either origin.
fn triangulate_rays(a: Ray, b: Ray) -> Triangulation {
    let w0 = a.origin - b.origin;
    let c = dot(a.dir, b.dir);
    let axb = cross3(a.dir, b.dir);
    let sin2 = dot(axb, axb); // not 1 − c², which cancels for nearly parallel rays
    if (!(sin2 >= MIN_RAY_ANGLE_SIN2)) {
        return Triangulation(vec3r(0.0), 0.0, STATUS_DEGENERATE);
    }
    let d = dot(a.dir, w0);
    let e = dot(b.dir, w0);
    let inv_sin2 = 1.0 / sin2;
    let s = (c * e - d) * inv_sin2;
    let t = (e - c * d) * inv_sin2;
    if (s < 0.0 || t < 0.0) {
        return Triangulation(vec3r(0.0), 0.0, STATUS_NOT_IN_WATER);
    }
    let pa = a.origin + a.dir * s;
    let pb = b.origin + b.dir * t;
    return Triangulation(0.5 * (pa + pb), length(pa - pb), STATUS_OK);
}

// A matched pixel pair (raw pixels of cameras a and b) → the triangulated point: each pixel
// back-projected through its own camera and port, then `triangulate_rays`. `carried_a` and
// `carried_b` are the statuses the pixels already hold (STATUS_OK where they hold an answer, as
// device rows carry them; an input out of range). A row answers with the first failure in the
// CPU's order — pixel a's status, pixel b's, a's back-projection, b's back-projection, the
// triangulation — and skips the work after it. Twin of `triangulate_row`
// (src/engine/cpu/lanes/mod.rs) behind the CPU's range check of the whole row.
fn triangulate_pixels(a: View, b: View, pixel_a: vec2r, carried_a: u32, pixel_b: vec2r,
                      carried_b: u32) -> Triangulation {
    if (carried_a != STATUS_OK) {
        return Triangulation(vec3r(0.0), 0.0, carried_a);
    }
    if (carried_b != STATUS_OK) {
        return Triangulation(vec3r(0.0), 0.0, carried_b);
    }
    let ray_a = backproject(a, pixel_a);
    if (ray_a.status != STATUS_OK) {
        return Triangulation(vec3r(0.0), 0.0, ray_a.status);
    }
    let ray_b = backproject(b, pixel_b);
    if (ray_b.status != STATUS_OK) {
        return Triangulation(vec3r(0.0), 0.0, ray_b.status);
    }
    return triangulate_rays(ray_a, ray_b);
}

struct BinocularVop {
    vop_left: vec3r,
    vop_right: vec3r,
    s_left: real,
    s_right: real,
    axis_offset: real,
    conditioning: real,
    status: u32,
}

// Solves [v, n, −v′]·(s, m, s′)ᵀ = C_r − C_l by Cramer's rule; degenerate when |det| is below
// MIN_BINOCULAR_CONDITIONING (the point lies in the plane through the baseline parallel to n).
fn binocular_vop(centre_l: vec3r, v_l: vec3r, centre_r: vec3r, v_r: vec3r, n: vec3r) -> BinocularVop {
    let c2 = -v_r;
    let det = dot(v_l, cross3(n, c2));
    if (!(abs(det) >= MIN_BINOCULAR_CONDITIONING)) {
        return BinocularVop(vec3r(0.0), vec3r(0.0), 0.0, 0.0, 0.0, 0.0, STATUS_DEGENERATE);
    }
    let b = centre_r - centre_l;
    let s_l = dot(b, cross3(n, c2)) / det;
    let m = dot(v_l, cross3(b, c2)) / det;
    let s_r = dot(v_l, cross3(n, b)) / det;
    return BinocularVop(centre_l + v_l * s_l, centre_r + v_r * s_r, s_l, s_r, m, abs(det), STATUS_OK);
}
