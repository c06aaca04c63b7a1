// Back-projection, f32: pixel → ray in the water (origin on the outer interface, unit direction).
// Twin of `RefractiveCamera::backproject` (src/model/refractive_camera.rs), same closed form.

@group(0) @binding(0) var<uniform> camera: Camera;
@group(0) @binding(1) var<storage, read> pixels: array<vec2<f32>>;
@group(0) @binding(2) var<storage, read_write> rays: array<f32>;      // 6 per item
@group(0) @binding(3) var<storage, read_write> status: array<u32>;

// OpenCV distortion of normalised coordinates and its Jacobian (columns).
fn distort(p: vec2<f32>) -> array<vec2<f32>, 3> {
    let k1 = camera.distortion.x; let k2 = camera.distortion.y;
    let p1 = camera.distortion.z; let p2 = camera.distortion.w; let k3 = camera.extra.x;
    let x = p.x; let y = p.y;
    let r2 = x * x + y * y;
    let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
    let radial_d = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
    let d = vec2<f32>(x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                      y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y);
    let dxx = radial + 2.0 * x * x * radial_d + 2.0 * p1 * y + 6.0 * p2 * x;
    let dxy = 2.0 * x * y * radial_d + 2.0 * p1 * x + 2.0 * p2 * y;
    let dyy = radial + 2.0 * y * y * radial_d + 6.0 * p1 * y + 2.0 * p2 * x;
    return array<vec2<f32>, 3>(d, vec2<f32>(dxx, dxy), vec2<f32>(dxy, dyy));
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item_index(gid, groups);
    if (i >= camera.counts.y) {
        return;
    }
    let pixel = pixels[i];
    let distorted = vec2<f32>((pixel.x - camera.intrinsics.z) / camera.intrinsics.x,
                              (pixel.y - camera.intrinsics.w) / camera.intrinsics.y);
    var p = distorted;
    var ok = true;
    if (camera.counts.z != 0u) {
        // Newton with the analytic Jacobian, as PinholeCamera::undistort_normalized.
        let tolerance = 4e-7 * (1.0 + length(distorted));
        ok = false;
        for (var it = 0u; it < UNDISTORT_MAX_ITERATIONS; it++) {
            let dj = distort(p);
            let residual = dj[0] - distorted;
            if (length(residual) <= tolerance) {
                ok = true;
                break;
            }
            let det = dj[1].x * dj[2].y - dj[2].x * dj[1].y;
            if (!(det > 0.0)) {
                break;
            }
            p -= vec2<f32>(dj[2].y * residual.x - dj[2].x * residual.y,
                           dj[1].x * residual.y - dj[1].y * residual.x) / det;
        }
    }
    if (!ok || !(dot(p, p) < camera.extra.y)) {
        status[i] = STATUS_OUTSIDE_LENS;
        return;
    }
    let dir_cam = normalize(vec3<f32>(p, 1.0));
    let v = vec3<f32>(dot(camera.master_from_cam0.xyz, dir_cam),
                      dot(camera.master_from_cam1.xyz, dir_cam),
                      dot(camera.master_from_cam2.xyz, dir_cam));
    let n = camera.normal.xyz;
    let cos_a = dot(n, v);
    if (!(cos_a > 0.0)) {
        status[i] = STATUS_MISSES_INTERFACE;
        return;
    }
    let sin2_a = max(1.0 - cos_a * cos_a, 0.0);
    let rho_w = camera.extra.z;
    let water_radicand = rho_w * rho_w - sin2_a;
    if (!(water_radicand > 0.0)) {
        status[i] = STATUS_TOTAL_INTERNAL_REFLECTION;
        return;
    }
    let d_k = camera.extra.w;
    let lambda1 = sqrt(water_radicand) / cos_a;
    var axis_shift = d_k * (1.0 - lambda1);
    var lateral_length = d_k;
    for (var l = 0u; l < min(camera.counts.x, MAX_LAYERS); l++) {
        let layer = camera.layers[l];
        let radicand = layer.y * layer.y - sin2_a;
        if (!(radicand > 0.0)) {
            status[i] = STATUS_TOTAL_INTERNAL_REFLECTION;
            return;
        }
        let lambda2 = cos_a / sqrt(radicand);
        axis_shift += layer.x * (1.0 - lambda1 * lambda2);
        lateral_length += layer.x * lambda2;
    }
    let bent = v + n * (cos_a * (lambda1 - 1.0));
    let origin = camera.centre.xyz + n * axis_shift + bent * (lateral_length / cos_a);
    let dir = normalize(bent);
    let o = 6u * i;
    rays[o] = origin.x; rays[o + 1u] = origin.y; rays[o + 2u] = origin.z;
    rays[o + 3u] = dir.x; rays[o + 4u] = dir.y; rays[o + 5u] = dir.z;
    status[i] = STATUS_OK;
}
