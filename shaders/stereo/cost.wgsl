// Stages 4b–5, `window_zncc` + `combine_views` (twins in src/stereo/cost.rs) for a chunk of
// hypotheses: per reference pixel and hypothesis, the ZNCC of the reference's (2r + 1)² window
// (clipped to the image) against each voter's warped samples, over the samples that have an
// answer, then the voters' costs min(1 − ZNCC, 1) combined (the mean of all for k ≤ 2 votes,
// of the best ⌈k/2⌉ of k > 2) into the cost volume, u32 per (pixel, hypothesis),
// `cost[i·D + h]`. The window sums are direct (no running sums, so no drift in f32), shifted by
// the centre pixel's values against cancellation. Dispatch (⌈W/64⌉, H, chunk).

@group(0) @binding(3) var<storage, read> image: array<f32>;
@group(0) @binding(5) var<storage, read> warped: array<f32>;
@group(0) @binding(6) var<storage, read_write> cost: array<u32>;

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let w = sweep.width;
    let h = sweep.height;
    let k = gid.z;
    if (gid.x >= w || gid.y >= h || sweep.first + k >= sweep.hypotheses) {
        return;
    }
    let x = i32(gid.x);
    let y = i32(gid.y);
    let i = gid.y * w + gid.x;
    let r = i32(sweep.radius);
    let x_lo = max(x - r, 0);
    let x_hi = min(x + r, i32(w) - 1);
    let y_lo = max(y - r, 0);
    let y_hi = min(y + r, i32(h) - 1);
    let n_window = f32((x_hi - x_lo + 1) * (y_hi - y_lo + 1));
    let centre_i = image[i];
    // The reference window's own texture (all of it): `ReferenceWindows::textured`.
    var si = 0.0;
    var sii = 0.0;
    for (var yy = y_lo; yy <= y_hi; yy++) {
        for (var xx = x_lo; xx <= x_hi; xx++) {
            let v = image[u32(yy) * w + u32(xx)] - centre_i;
            si += v;
            sii += v * v;
        }
    }
    let min_spread = sweep.min_texture * sweep.min_texture;
    let textured = sii - si * si / n_window;
    let plane = w * h;
    var costs: array<f32, MAX_VOTERS>;
    var votes = 0u;
    if (textured > 0.0 && textured >= min_spread * n_window) {
        for (var v = 0u; v < sweep.voters; v++) {
            let base = (v * sweep.chunk + k) * plane;
            let centre_w = select(0.5, warped[base + i], warped[base + i] > NO_SAMPLE);
            var n = 0.0;
            var sw = 0.0;
            var sww = 0.0;
            var swi = 0.0;
            var s_i = 0.0;
            var s_ii = 0.0;
            for (var yy = y_lo; yy <= y_hi; yy++) {
                for (var xx = x_lo; xx <= x_hi; xx++) {
                    let at = u32(yy) * w + u32(xx);
                    let raw = warped[base + at];
                    if (raw > NO_SAMPLE) {
                        let s = raw - centre_w;
                        let g = image[at] - centre_i;
                        n += 1.0;
                        sw += s;
                        sww += s * s;
                        swi += s * g;
                        s_i += g;
                        s_ii += g * g;
                    }
                }
            }
            var zncc = NO_ZNCC;
            if (n >= 0.5 * n_window) {
                let spread_w = sww - sw * sw / n;
                let spread_i = s_ii - s_i * s_i / n;
                if (spread_i >= min_spread * n) {
                    zncc = 0.0;
                    if (spread_w > 1e-12 * n) {
                        zncc = (swi - s_i * sw / n) / sqrt(spread_i * spread_w);
                    }
                }
            }
            if (zncc != NO_ZNCC) {
                costs[votes] = clamp(1.0 - zncc, 0.0, 1.0);
                votes += 1u;
            }
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
    cost[i * sweep.hypotheses + sweep.first + k] = out;
}
