// Stage 5, `combine_views` (twin in src/stereo/cost.rs) for a chunk of hypotheses: per reference
// pixel and hypothesis, the voters' costs min(1 − ZNCC, 1) from `zncc` (stage 4b,
// shaders/stereo/zncc.wgsl) combined (the mean of all for k ≤ 2 votes, of the best ⌈k/2⌉ of
// k > 2) into the cost volume, u16 per (pixel, hypothesis), packed (`volume_word`): OR-ed into
// its half of a word cleared before the sweep. Dispatch (⌈W/64⌉, H, chunk).

@group(0) @binding(6) var<storage, read_write> cost: array<atomic<u32>>;
@group(0) @binding(9) var<storage, read> zncc: array<f32>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let w = sweep.width;
    let h = sweep.height;
    let k = gid.z;
    if (gid.x >= w || gid.y >= h || sweep.first + k >= sweep.hypotheses) {
        return;
    }
    let i = gid.y * w + gid.x;
    let plane = w * h;
    var costs: array<f32, MAX_VOTERS>;
    var votes = 0u;
    for (var v = 0u; v < sweep.voters; v++) {
        let z = zncc[(v * sweep.chunk + k) * plane + i];
        if (z != NO_ZNCC) {
            costs[votes] = clamp(1.0 - z, 0.0, 1.0);
            votes += 1u;
        }
    }
    var out = NO_VOTE;
    if (votes > 0u) {
        // The best ⌈k/2⌉ of k > 2 votes (all of one or two), by selection.
        let used = select(votes, (votes + 1u) / 2u, votes > 2u);
        var total = 0.0;
        for (var m = 0u; m < used; m++) {
            var best = m;
            for (var j = m + 1u; j < votes; j++) {
                if (costs[j] < costs[best]) {
                    best = j;
                }
            }
            let c = costs[best];
            costs[best] = costs[m];
            costs[m] = c;
            total += c;
        }
        out = u32(floor(total / f32(used) * f32(COST_SCALE) + 0.5));
    }
    let h_index = sweep.first + k;
    atomicOr(&cost[volume_word(i, h_index)], out << ((h_index & 1u) * 16u));
}
