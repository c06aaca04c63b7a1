// Stage 6, `sgm_aggregate` (twin of src/stereo/sgm.rs) along every path direction at once: the
// workgroups of row y of the dispatch run direction SGM_DIRECTIONS[y] (the first `sweep.paths`),
// one workgroup per path line (every line starts where the pixel before it, (x − dx, y − dy), is
// outside the image), its invocations over the hypotheses; L of the previous pixel is kept in
// workgroup memory (two rows, padded with PAD at both ends), its minimum by a two-level
// reduction. Adds L to `sum` (u32 per (pixel, hypothesis)) atomically: the directions run side by
// side, and integer sums do not depend on their order, so the result is the CPU's. Dispatch
// (most lines of a direction, paths, 1); a workgroup past its direction's lines returns at once.
//
// One dispatch for all directions fills a large GPU (a 1280 × 1024 image has 1 024 to 2 303
// lines a direction: one direction alone is a quarter of an H200's resident threads), and the
// minimum reads 2 × 8 values per invocation and step instead of 64.

@group(0) @binding(3) var<storage, read> image: array<f32>;
@group(0) @binding(6) var<storage, read> cost: array<u32>;
@group(0) @binding(7) var<storage, read_write> sum: array<atomic<u32>>;

const PAD: u32 = 0x7FFFu;
const MAX_HYPOTHESES: u32 = 1024u;
const ROW: u32 = 1026u; // MAX_HYPOTHESES + 2
// The order of src/stereo/gpu/mod.rs: the four axis directions, then the diagonals.
const SGM_DIRECTIONS = array<vec2<i32>, 8>(
    vec2<i32>(1, 0), vec2<i32>(-1, 0), vec2<i32>(0, 1), vec2<i32>(0, -1),
    vec2<i32>(1, 1), vec2<i32>(-1, 1), vec2<i32>(1, -1), vec2<i32>(-1, -1),
);
// Invocations whose partial minima one invocation of the first level combines.
const FAN: u32 = 8u;
var<workgroup> previous: array<u32, 2052>; // two rows of ROW
var<workgroup> partial: array<u32, WORKGROUP_SIZE>;
var<workgroup> partial_fan: array<u32, WORKGROUP_SIZE>;

// P2 lowered by the image's change along the path: `SgmParams::p2_at`.
fn p2_at(a: f32, b: f32) -> u32 {
    let p2 = f32(sweep.p2) / (1.0 + abs(a - b) / sweep.gradient);
    return max(u32(floor(p2 + 0.5)), sweep.p1 + 1u);
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let w = i32(sweep.width);
    let h = i32(sweep.height);
    let d = sweep.hypotheses;
    if (wid.y >= sweep.paths) {
        return;
    }
    let dir = SGM_DIRECTIONS[wid.y];
    let dx = dir.x;
    let dy = dir.y;
    let line = i32(wid.x);
    var lines = w + h - 1;
    if (dy == 0) {
        lines = h;
    } else if (dx == 0) {
        lines = w;
    }
    if (line >= lines) {
        return;
    }
    var x: i32;
    var y: i32;
    if (dy == 0) {
        x = select(w - 1, 0, dx > 0);
        y = line;
    } else if (dx == 0) {
        x = line;
        y = select(h - 1, 0, dy > 0);
    } else if (line < w) {
        x = line;
        y = select(h - 1, 0, dy > 0);
    } else {
        x = select(w - 1, 0, dx > 0);
        let row = line - w + 1;
        y = select(h - 1 - row, row, dy > 0);
    }
    for (var j = t; j < 2u * ROW; j += WORKGROUP_SIZE) {
        previous[j] = PAD;
    }
    workgroupBarrier();
    let fans = (WORKGROUP_SIZE + FAN - 1u) / FAN;
    var parity = 0u;
    var first = true;
    var before = 0u;
    loop {
        if (x < 0 || x >= w || y < 0 || y >= h) {
            break;
        }
        let p = u32(y) * sweep.width + u32(x);
        let prev = parity * ROW;
        let cur = (1u - parity) * ROW;
        if (first) {
            for (var k = t; k < d; k += WORKGROUP_SIZE) {
                let l = cost[p * d + k];
                previous[cur + k + 1u] = l;
                atomicAdd(&sum[p * d + k], l);
            }
        } else {
            var m = PAD;
            for (var k = t; k < d; k += WORKGROUP_SIZE) {
                m = min(m, previous[prev + k + 1u]);
            }
            partial[t] = m;
            workgroupBarrier();
            if (t < fans) {
                var f = PAD;
                for (var j = t * FAN; j < min(t * FAN + FAN, WORKGROUP_SIZE); j++) {
                    f = min(f, partial[j]);
                }
                partial_fan[t] = f;
            }
            workgroupBarrier();
            var minimum = PAD;
            for (var j = 0u; j < fans; j++) {
                minimum = min(minimum, partial_fan[j]);
            }
            let p1 = sweep.p1;
            let cap = minimum + p2_at(image[p], image[before]);
            for (var k = t; k < d; k += WORKGROUP_SIZE) {
                let v = min(min(previous[prev + k + 1u], previous[prev + k] + p1), min(previous[prev + k + 2u] + p1, cap));
                let l = cost[p * d + k] + v - minimum;
                previous[cur + k + 1u] = l;
                atomicAdd(&sum[p * d + k], l);
            }
        }
        workgroupBarrier();
        first = false;
        before = p;
        parity = 1u - parity;
        x += dx;
        y += dy;
    }
}
