// Refractive triangulation of matched pixels already on the device, fused: pixel a (u,v) of
// camera a and pixel b of camera b in the same row → x,y,z,residual, both back-projections and
// the triangulation in one pass (`triangulate_pixels`, shaders/lib/stereo.wgsl), nothing between
// them in memory. The device-resident chain of src/engine/gpu/device.rs (`triangulate_pixels`);
// a row whose pixel has no answer (its status ≠ 0) gets that status here, where the three-kernel
// chain runs `merge_status.wgsl` after its kernels.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> pixels_a: array<real>;
@group(0) @binding(2) var<storage, read_write> output: array<real>;
@group(0) @binding(3) var<storage, read_write> status: array<u32>;
@group(0) @binding(4) var<storage, read> pixels_b: array<real>;
@group(0) @binding(5) var<storage, read> status_a: array<u32>;
@group(0) @binding(6) var<storage, read> status_b: array<u32>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    // The cameras before the first branch (common.wgsl, `View`).
    let a = view(0u);
    let b = view(1u);
    let i = item_index(gid, groups);
    if (i >= params.info.x) {
        return;
    }
    let j = 2u * i;
    let t = triangulate_pixels(a, b, vec2r(pixels_a[j], pixels_a[j + 1u]), status_a[i],
                               vec2r(pixels_b[j], pixels_b[j + 1u]), status_b[i]);
    status[i] = t.status;
    if (t.status == STATUS_OK) {
        let o = 4u * i;
        output[o] = t.point.x;
        output[o + 1u] = t.point.y;
        output[o + 2u] = t.point.z;
        output[o + 3u] = t.residual;
    }
}
