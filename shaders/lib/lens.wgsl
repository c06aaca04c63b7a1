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

// Normalised undistorted coordinates of a raw pixel, as `RefractiveCamera::dir_in_air_from_img`
// undistorts (`PinholeCamera::undistort_normalized_in_fold`): Newton with the analytic Jacobian,
// first from the inverse radial series x′(1 − r′²(k1 + r′²(k2 − 3k1²))); where that run meets a
// fold (determinant ≤ 0), does not converge, or converges beyond the fold or at a non-positive
// determinant, once more from the distorted point. Each run tests the residual after each of at
// most UNDISTORT_MAX_ITERATIONS steps, as the CPU does. `ok` is false when neither run converges
// or the result lies beyond the fold of the radial distortion.
//
// One loop with a restart rather than two loops: llvmpipe runs every loop body at least once,
// masked or not, so a second loop would cost a pass of `distort` for every pixel.
struct Undistorted {
    point: vec2r,
    ok: bool,
}

fn normalized_from_img(cam: View, pixel: vec2r) -> Undistorted {
    let distorted = (pixel - cam.intrinsics.zw) / cam.intrinsics.xy;
    var p = distorted;
    var ok = true;
    if (cam.distorted) {
        let k1 = cam.distortion.x;
        let k2 = cam.distortion.y;
        let r2 = dot(distorted, distorted);
        let tolerance = UNDISTORT_TOLERANCE * (1.0 + sqrt(r2));
        p = distorted * (1.0 - r2 * (k1 + r2 * (k2 - 3.0 * k1 * k1)));
        ok = false;
        var second = false;
        var steps = 0u;
        loop {
            let dj = distort(cam, p);
            let residual = dj.point - distorted;
            let det = dj.dx.x * dj.dy.y - dj.dy.x * dj.dx.y;
            var failed = false;
            if (length(residual) <= tolerance) {
                if (second || (det > 0.0 && dot(p, p) < cam.fold2)) {
                    ok = true;
                    break;
                }
                failed = true;
            } else if (steps == UNDISTORT_MAX_ITERATIONS || !(det > 0.0)) {
                failed = true;
            }
            if (failed) {
                if (second) {
                    break;
                }
                second = true;
                steps = 0u;
                p = distorted;
                continue;
            }
            p -= vec2r(dj.dy.y * residual.x - dj.dy.x * residual.y,
                       dj.dx.x * residual.y - dj.dx.y * residual.x) / det;
            steps++;
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
