// Refractive triangulation of water rays already on the device: ray a (ox,oy,oz,dx,dy,dz) and ray
// b of the same row → x,y,z,residual. The rows of the device-resident chain back-project →
// triangulate (src/engine/gpu/device.rs); rows whose rays have no answer get their status from
// `merge_status.wgsl` after this kernel.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> rays_a: array<real>;
@group(0) @binding(2) var<storage, read_write> output: array<real>;
@group(0) @binding(3) var<storage, read_write> status: array<u32>;
@group(0) @binding(4) var<storage, read> rays_b: array<real>;

fn ray_a(i: u32) -> Ray {
    let o = 6u * i;
    return Ray(vec3r(rays_a[o], rays_a[o + 1u], rays_a[o + 2u]),
               vec3r(rays_a[o + 3u], rays_a[o + 4u], rays_a[o + 5u]), STATUS_OK);
}

fn ray_b(i: u32) -> Ray {
    let o = 6u * i;
    return Ray(vec3r(rays_b[o], rays_b[o + 1u], rays_b[o + 2u]),
               vec3r(rays_b[o + 3u], rays_b[o + 4u], rays_b[o + 5u]), STATUS_OK);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item_index(gid, groups);
    if (i >= params.info.x) {
        return;
    }
    let t = triangulate_rays(ray_a(i), ray_b(i));
    status[i] = t.status;
    if (t.status == STATUS_OK) {
        let o = 4u * i;
        output[o] = t.point.x;
        output[o + 1u] = t.point.y;
        output[o + 2u] = t.point.z;
        output[o + 3u] = t.residual;
    }
}
