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

// A bound on the sum of the magnitudes of the distortion's terms at p: the scale of its rounding
// (UNDISTORT_FLOOR times it bounds the residual's rounding on any adapter). Far outside the image
// (8e5 px through a lens with k2 > 0) the f32 residual's rounding comes within a factor two of the
// tolerance, and an adapter that rounds differently (NVIDIA) ran out of steps where lavapipe
// converged. Not used in f64 (UNDISTORT_FLOOR = 0).
fn distortion_magnitude(cam: View, p: vec2r) -> real {
    if (UNDISTORT_FLOOR == 0.0) {
        return 0.0;
    }
    let r2 = dot(p, p);
    let radial = 1.0 + r2 * (abs(cam.distortion.x) + r2 * (abs(cam.distortion.y) + r2 * abs(cam.k3)));
    let tangential = 3.0 * (abs(cam.distortion.z) + abs(cam.distortion.w)) * r2;
    return (abs(p.x) + abs(p.y)) * radial + tangential;
}

// Normalised undistorted coordinates of a raw pixel, as `RefractiveCamera::dir_in_air_from_img`
// undistorts (`PinholeCamera::undistort_normalized_in_fold`): Newton with the analytic Jacobian,
// first from the inverse radial series x′(1 − r′²(k1 + r′²(k2 − 3k1²))); where that run meets a
// fold (determinant ≤ 0), does not converge, or converges beyond the fold or at a non-positive
// determinant, once more from the distorted point. Each run tests the residual after each of at
// most UNDISTORT_MAX_ITERATIONS steps, as the CPU does (in f32, after the last step, a residual
// within the evaluation's rounding floor also passes: distortion_magnitude). `ok` is false when neither run converges
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
            // At the last step, a residual within the evaluation's rounding floor is as converged
            // as the precision allows (f32 only: distortion_magnitude).
            let converged = length(residual) <= tolerance
                || (steps == UNDISTORT_MAX_ITERATIONS
                    && length(residual) <= UNDISTORT_FLOOR * distortion_magnitude(cam, p));
            if (converged) {
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
