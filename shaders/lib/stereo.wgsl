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
