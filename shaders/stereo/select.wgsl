// Stage 7, `winner_take_all` (twin of src/stereo/select.rs): per pixel the hypothesis of least
// aggregated cost (the first of equals), refined by a parabola through the matching costs (the
// aggregated ones where a neighbour has no vote), and the confidence's ingredients. Per pixel
// 3 f32 in `winners`: h* + δ (−1 where rejected: no vote for the winner, or the winner at either
// end), the winner's quality 1 − C/COST_SCALE, and the distinctness (S₂ − S₁)/S₂.

@group(0) @binding(6) var<storage, read> cost: array<u32>;
@group(0) @binding(7) var<storage, read> sum: array<u32>;
@group(0) @binding(8) var<storage, read_write> winners: array<f32>;

fn cost_at(p: u32, k: u32) -> u32 {
    return volume_half(cost[volume_word(p, k)], k);
}

fn sum_at(p: u32, k: u32) -> u32 {
    return volume_half(sum[volume_word(p, k)], k);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= sweep.width || gid.y >= sweep.height) {
        return;
    }
    let p = gid.y * sweep.width + gid.x;
    let d = sweep.hypotheses;
    var best = 0u;
    for (var k = 1u; k < d; k++) {
        if (sum_at(p, k) < sum_at(p, best)) {
            best = k;
        }
    }
    winners[3u * p] = -1.0;
    winners[3u * p + 1u] = 0.0;
    winners[3u * p + 2u] = 0.0;
    if (cost_at(p, best) >= NO_VOTE || best == 0u || best == d - 1u) {
        return;
    }
    let raw = cost_at(p, best - 1u) < NO_VOTE && cost_at(p, best + 1u) < NO_VOTE;
    var minus = f32(sum_at(p, best - 1u));
    var centre = f32(sum_at(p, best));
    var plus = f32(sum_at(p, best + 1u));
    if (raw) {
        minus = f32(cost_at(p, best - 1u));
        centre = f32(cost_at(p, best));
        plus = f32(cost_at(p, best + 1u));
    }
    let curvature = minus - 2.0 * centre + plus;
    var delta = 0.0;
    if (curvature > 0.0) {
        delta = clamp((minus - plus) / (2.0 * curvature), -0.5, 0.5);
    }
    var second = 0xFFFFu;
    for (var k = 0u; k < d; k++) {
        if (k + 2u <= best || k >= best + 2u) {
            second = min(second, sum_at(p, k));
        }
    }
    let s1 = f32(sum_at(p, best));
    winners[3u * p] = f32(best) + delta;
    winners[3u * p + 1u] = 1.0 - f32(cost_at(p, best)) / f32(COST_SCALE);
    winners[3u * p + 2u] = select(0.0, (f32(second) - s1) / f32(second), second > 0u);
}
