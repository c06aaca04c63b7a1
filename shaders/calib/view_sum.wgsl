// The sum over views of the per-(candidate, view) kernels' items (calib_affine_grid,
// calib_scene_*), on the device, so that one row per candidate leaves it instead of one per
// (candidate, view). One invocation per candidate of a chunk: it adds the M reals of the items of
// views 0, 1, 2, … in that order, as the host did (the same f64 sums, bit for bit), and combines
// their statuses: STATUS_RETRY where any view has it (the candidate runs again, every view), else
// the first non-zero status in view order, else STATUS_OK. Composed in front of this file: the
// items' type `item_real` and COMPENSATED. f64 items, and f32 items where the adapter has
// SHADER_F64, are added plainly in f64 (real = f64), the host's f64 sums bit for bit; on an
// adapter without f64 the f32 items are added in f32 with Neumaier's compensation.
//
// Items (bindings 1 and 2) are view-major, as the per-view kernels write them within one
// submission's batch of views: item = view · info.y + candidate, view counted within the batch.
// A call whose views need several batches runs this once per batch, the later ones adding to
// the sums and combining with the statuses already there.

// params.info: x the chunk's candidates (padded: also the items per view), y the views of the
// batch, z 1 to add to the sums already there (a later batch) or 0 to start them, w the reals per
// item (M ≤ 4). The cameras of Params are not read.
@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> items: array<item_real>;
@group(0) @binding(2) var<storage, read> item_status: array<u32>;
@group(0) @binding(3) var<storage, read_write> sums: array<real>; // M reals per candidate
@group(0) @binding(4) var<storage, read_write> codes: array<u32>; // per candidate

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let c = item_index(gid, groups);
    let per_view = params.info.x;
    if (c >= per_view) {
        return;
    }
    let m = params.info.w;
    var sum = vec4r(0.0);
    var compensation = vec4r(0.0);
    var code = STATUS_OK;
    var retry = false;
    if (params.info.z != 0u) {
        for (var k = 0u; k < m; k++) {
            sum[k] = sums[c * m + k];
        }
        code = codes[c];
        retry = code == STATUS_RETRY;
    }
    for (var v = 0u; v < params.info.y; v++) {
        let item = v * per_view + c;
        let s = item_status[item];
        if (s == STATUS_RETRY) {
            retry = true;
        } else if (code == STATUS_OK) {
            code = s;
        }
        for (var k = 0u; k < m; k++) {
            let x = real(items[item * m + k]);
            if (COMPENSATED) {
                // Neumaier: the rounding error of each addition, kept aside.
                let t = sum[k] + x;
                compensation[k] += select((x - t) + sum[k], (sum[k] - t) + x, abs(sum[k]) >= abs(x));
                sum[k] = t;
            } else {
                sum[k] = sum[k] + x;
            }
        }
    }
    for (var k = 0u; k < m; k++) {
        sums[c * m + k] = sum[k] + compensation[k];
    }
    codes[c] = select(code, STATUS_RETRY, retry);
}
