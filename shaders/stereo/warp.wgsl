// Stages 2–4a, `hypothesis_points` + `project_hypotheses` + `warp_bilinear` (twins in
// src/stereo/rays.rs and src/stereo/cost.rs) for one voting camera (camera 1 of `params`) and a
// chunk of hypotheses: the point X = o + ((z − z₀)/ż)·w of depth z = 1/q_h on each reference
// pixel's ray, projected exactly through the voter's port (`project_near_pair`, two hypotheses per
// invocation; `project` with every safeguard where it does not settle), and the voter's image
// sampled bilinearly there. Dispatch (⌈W/64⌉, H, ⌈chunk/2⌉).

@group(0) @binding(2) var<storage, read> rays: array<f32>;
@group(0) @binding(4) var<storage, read> other: array<f32>;
@group(0) @binding(5) var<storage, read_write> warped: array<f32>;

// The point of depth 1/q on pixel i's ray; w = 0 where it is not in the water.
fn hypothesis_point(i: u32, q: f32) -> vec4<f32> {
    let o = 8u * i;
    let dz = rays[o + 7u];
    let s = (1.0 / q - rays[o + 3u]) / dz;
    let ok = dz > 0.0 && s >= 0.0;
    let p = vec3<f32>(rays[o], rays[o + 1u], rays[o + 2u]) + s * vec3<f32>(rays[o + 4u], rays[o + 5u], rays[o + 6u]);
    return vec4<f32>(p, select(0.0, 1.0, ok));
}

fn warp_bilinear(pixel: Pixel) -> f32 {
    let w = sweep.voter_width;
    let h = sweep.voter_height;
    let u = f32(pixel.pixel.x);
    let v = f32(pixel.pixel.y);
    if (pixel.status != STATUS_OK || !(u >= 0.0 && u <= f32(w - 1u) && v >= 0.0 && v <= f32(h - 1u))) {
        return NO_SAMPLE;
    }
    let x0 = min(u32(floor(u)), max(w, 2u) - 2u);
    let y0 = min(u32(floor(v)), max(h, 2u) - 2u);
    let fx = u - f32(x0);
    let fy = v - f32(y0);
    let x1 = min(x0 + 1u, w - 1u);
    let y1 = min(y0 + 1u, h - 1u);
    let a = other[y0 * w + x0];
    let b = other[y0 * w + x1];
    let c = other[y1 * w + x0];
    let d = other[y1 * w + x1];
    let top = a + fx * (b - a);
    let bottom = c + fx * (d - c);
    return top + fy * (bottom - top);
}

fn store(i: u32, k: u32, value: f32) {
    warped[(sweep.voter * sweep.chunk + k) * sweep.width * sweep.height + i] = value;
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let cam = view(1u);
    let count = min(sweep.chunk, sweep.hypotheses - sweep.first);
    let k = 2u * gid.z;
    if (gid.x >= sweep.width || gid.y >= sweep.height || k >= count) {
        return;
    }
    let i = gid.y * sweep.width + gid.x;
    let second = min(k + 1u, count - 1u);
    let a = hypothesis_point(i, sweep.q0 + f32(sweep.first + k) * sweep.dq);
    let b = hypothesis_point(i, sweep.q0 + f32(sweep.first + second) * sweep.dq);
    let pair = project_near_pair(cam, vec3r(a.xyz), cam, vec3r(b.xyz), vec2r(0.0));
    var pa = pair.a.pixel;
    var pb = pair.b.pixel;
    if (!pair.a.converged) {
        pa = project(cam, vec3r(a.xyz));
    }
    if (!pair.b.converged) {
        pb = project(cam, vec3r(b.xyz));
    }
    store(i, k, select(NO_SAMPLE, warp_bilinear(pa), a.w > 0.0));
    if (second != k) {
        store(i, second, select(NO_SAMPLE, warp_bilinear(pb), b.w > 0.0));
    }
}
