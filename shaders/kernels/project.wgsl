// Forward projection: x,y,z (master frame) → u,v (raw pixel).

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> input: array<real>;        // 3 per item
@group(0) @binding(2) var<storage, read_write> output: array<real>; // 2 per item
@group(0) @binding(3) var<storage, read_write> status: array<u32>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item_index(gid, groups);
    if (i >= params.info.x) {
        return;
    }
    let p = project(params.a, vec3r(input[3u * i], input[3u * i + 1u], input[3u * i + 2u]));
    status[i] = p.status;
    if (p.status == STATUS_OK) {
        output[2u * i] = p.pixel.x;
        output[2u * i + 1u] = p.pixel.y;
    }
}
