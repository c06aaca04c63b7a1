// Back-projection of every pixel of an image, generated in the shader (no input buffer): the
// dispatch is (⌈width / WORKGROUP_SIZE⌉, rows); pixel (column, first row + row) → ray, row-major.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(2) var<storage, read_write> output: array<real>; // 6 per pixel
@group(0) @binding(3) var<storage, read_write> status: array<u32>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    // The camera before the first branch (common.wgsl, `View`).
    let cam = view(0u);
    let width = params.info.y;
    if (gid.x >= width) {
        return;
    }
    let i = gid.y * width + gid.x;
    let pixel = vec2r(real(gid.x), real(gid.y + params.info.z));
    let ray = backproject(cam, pixel);
    status[i] = ray.status;
    if (ray.status == STATUS_OK) {
        let o = 6u * i;
        output[o] = ray.origin.x;
        output[o + 1u] = ray.origin.y;
        output[o + 2u] = ray.origin.z;
        output[o + 3u] = ray.dir.x;
        output[o + 4u] = ray.dir.y;
        output[o + 5u] = ray.dir.z;
    }
}
