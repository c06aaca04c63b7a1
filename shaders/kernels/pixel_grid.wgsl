// Pixels of a grid generated on the device, row-major: row g = info.z + i of a grid `info.y`
// columns wide is the pixel (u, v) = step · (g mod width, g div width), `info.w` the step in
// pixels (`info.z` the chunk's first row). Every row has an answer.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(2) var<storage, read_write> output: array<real>;
@group(0) @binding(3) var<storage, read_write> status: array<u32>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item_index(gid, groups);
    if (i >= params.info.x) {
        return;
    }
    let width = params.info.y;
    let step = real(params.info.w);
    let g = params.info.z + i;
    output[2u * i] = step * real(g % width);
    output[2u * i + 1u] = step * real(g / width);
    status[i] = STATUS_OK;
}
