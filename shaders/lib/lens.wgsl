// The OpenCV lens model [k1 k2 p1 p2 k3] on normalised coordinates. Twin of `PinholeCamera`
// (src/model/camera.rs).

// A distorted point and the columns of the distortion's Jacobian.
struct Distortion {
    point: vec2r,
    dx: vec2r,
    dy: vec2r,
}

fn distort(cam: View, p: vec2r) -> Distortion {
    let k1 = cam.distortion.x;
    let k2 = cam.distortion.y;
    let p1 = cam.distortion.z;
    let p2 = cam.distortion.w;
    let k3 = cam.k3;
    let x = p.x;
    let y = p.y;
    let r2 = x * x + y * y;
    let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
    let radial_d = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
    let d = vec2r(x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                  y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y);
    let dxx = radial + 2.0 * x * x * radial_d + 2.0 * p1 * y + 6.0 * p2 * x;
    let dxy = 2.0 * x * y * radial_d + 2.0 * p1 * x + 2.0 * p2 * y;
    let dyy = radial + 2.0 * y * y * radial_d + 6.0 * p1 * y + 2.0 * p2 * x;
    return Distortion(d, vec2r(dxx, dxy), vec2r(dxy, dyy));
}

// Normalised undistorted coordinates of a raw pixel, as `PinholeCamera::normalized_from_img`:
// Newton with the analytic Jacobian; `ok` is false when it does not converge or when the result
// lies beyond the fold of the radial distortion.
struct Undistorted {
    point: vec2r,
    ok: bool,
}

fn normalized_from_img(cam: View, pixel: vec2r) -> Undistorted {
    let distorted = (pixel - cam.intrinsics.zw) / cam.intrinsics.xy;
    var p = distorted;
    var ok = true;
    if (cam.distorted) {
        let tolerance = UNDISTORT_TOLERANCE * (1.0 + length(distorted));
        ok = false;
        for (var it = 0u; it < UNDISTORT_MAX_ITERATIONS; it++) {
            let dj = distort(cam, p);
            let residual = dj.point - distorted;
            if (length(residual) <= tolerance) {
                ok = true;
                break;
            }
            let det = dj.dx.x * dj.dy.y - dj.dy.x * dj.dx.y;
            if (!(det > 0.0)) {
                break;
            }
            p -= vec2r(dj.dy.y * residual.x - dj.dy.x * residual.y,
                       dj.dx.x * residual.y - dj.dx.y * residual.x) / det;
        }
    }
    return Undistorted(p, ok && dot(p, p) < cam.fold2);
}

// Raw pixel of normalised undistorted coordinates.
fn img_from_normalized(cam: View, p: vec2r) -> vec2r {
    var q = p;
    if (cam.distorted) {
        q = distort(cam, p).point;
    }
    return q * cam.intrinsics.xy + cam.intrinsics.zw;
}
