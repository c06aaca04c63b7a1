// The status of an input row carried to the output row computed from it: a row whose input has no
// answer (status ≠ 0) gets the input's status, whatever the kernel wrote. Runs after a kernel over
// device-resident rows (src/engine/gpu/device.rs), once per input.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(3) var<storage, read_write> status: array<u32>;
@group(0) @binding(4) var<storage, read> input_status: array<u32>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = item_index(gid, groups);
    if (i >= params.info.x) {
        return;
    }
    let carried = input_status[i];
    if (carried != STATUS_OK) {
        status[i] = carried;
    }
}
