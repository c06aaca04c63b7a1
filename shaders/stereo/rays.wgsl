// Stage 1, `reference_rays` (twin of src/stereo/rays.rs): every reference pixel back-projected to
// its water ray, from the pixel grid generated here. Per pixel 8 f32: o.xyz, z₀, w.xyz, ż, with
// ż = −1 where the pixel has no ray or the ray does not go deeper (z₀ = r₃·(o − C), ż = r₃·w).

@group(0) @binding(2) var<storage, read_write> rays: array<f32>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let cam = view(0u);
    if (gid.x >= sweep.width || gid.y >= sweep.height) {
        return;
    }
    let i = gid.y * sweep.width + gid.x;
    let ray = backproject(cam, vec2r(real(gid.x), real(gid.y)));
    let z0 = cam_from_master(cam, ray.origin - cam.centre).z;
    let dz = cam_from_master(cam, ray.dir).z;
    let ok = ray.status == STATUS_OK && dz > 0.0;
    let o = 8u * i;
    rays[o] = f32(ray.origin.x);
    rays[o + 1u] = f32(ray.origin.y);
    rays[o + 2u] = f32(ray.origin.z);
    rays[o + 3u] = f32(z0);
    rays[o + 4u] = f32(ray.dir.x);
    rays[o + 5u] = f32(ray.dir.y);
    rays[o + 6u] = f32(ray.dir.z);
    rays[o + 7u] = select(-1.0, f32(dz), ok);
}
