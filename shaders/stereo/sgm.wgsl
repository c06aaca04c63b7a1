// Stage 6, `sgm_aggregate` (twin of src/stereo/sgm.rs) along every path direction at once: the
// workgroups of row y of the dispatch run direction SGM_DIRECTIONS[y] (the first `sweep.paths`),
// each `sweep.group_lines` consecutive path lines (every line starts where the pixel before it,
// (x − dx, y − dy), is outside the image), WORKGROUP_SIZE / group_lines invocations a line over
// its hypotheses, a word of two at a time; L of each line's previous pixel is kept in workgroup
// memory (two rows of D + 2, padded with PAD at both ends), its minimum by a two-level reduction.
// Reads `cost` and adds L to `sum`, both packed two u16 a u32 (`volume_word`), a word atomically: the directions run side by side, and integer sums do not
// depend on their order, so the result is the CPU's. The lines of a workgroup step together, as
// long as its longest. Dispatch (⌈most lines of a direction / group_lines⌉, paths, 1).
//
// One dispatch for all directions fills a large GPU (a 1280 × 1024 image has 1 024 to 2 303
// lines a direction), and the lines a workgroup shares split the cost of its barriers, which a
// software adapter pays for every invocation.

@group(0) @binding(3) var<storage, read> image: array<f32>;
@group(0) @binding(6) var<storage, read> cost: array<u32>;
@group(0) @binding(7) var<storage, read_write> sum: array<atomic<u32>>;

const PAD: u32 = 0x7FFFu;
// Workgroup memory for the lines' rows of L: group_lines · 2 · (D + 2) ≤ PREVIOUS (with the two
// arrays of partial minima, 16 KiB: WebGPU's least workgroup storage), one line of the host's
// most hypotheses (`MAX_HYPOTHESES`) included. `SGM_PREVIOUS` on the host.
const PREVIOUS: u32 = 3968u;
// The order of src/stereo/gpu/mod.rs: the four axis directions, then the diagonals.
const SGM_DIRECTIONS = array<vec2<i32>, 8>(
    vec2<i32>(1, 0), vec2<i32>(-1, 0), vec2<i32>(0, 1), vec2<i32>(0, -1),
    vec2<i32>(1, 1), vec2<i32>(-1, 1), vec2<i32>(1, -1), vec2<i32>(-1, -1),
);
// Invocations whose partial minima one invocation of the first level combines.
const FAN: u32 = 8u;
var<workgroup> previous: array<u32, PREVIOUS>;
var<workgroup> partial: array<u32, WORKGROUP_SIZE>;
var<workgroup> partial_fan: array<u32, WORKGROUP_SIZE>;

// Path lines of direction (dx, dy) in a w × h image.
fn line_count(dx: i32, dy: i32, w: i32, h: i32) -> i32 {
    if (dy == 0) {
        return h;
    } else if (dx == 0) {
        return w;
    }
    return w + h - 1;
}

// The first pixel of path line `line` of direction (dx, dy).
fn line_start(dx: i32, dy: i32, line: i32, w: i32, h: i32) -> vec2<i32> {
    if (dy == 0) {
        return vec2<i32>(select(w - 1, 0, dx > 0), line);
    } else if (dx == 0 || line < w) {
        return vec2<i32>(line, select(h - 1, 0, dy > 0));
    }
    let row = line - w + 1;
    return vec2<i32>(select(w - 1, 0, dx > 0), select(h - 1 - row, row, dy > 0));
}

// Pixels of the path line from `start` in direction (dx, dy) before it leaves the image.
fn line_length(dx: i32, dy: i32, start: vec2<i32>, w: i32, h: i32) -> i32 {
    var n = max(w, h);
    if (dx != 0) {
        n = min(n, select(start.x + 1, w - start.x, dx > 0));
    }
    if (dy != 0) {
        n = min(n, select(start.y + 1, h - start.y, dy > 0));
    }
    return n;
}

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
    let lines = line_count(dx, dy, w, h);
    let group = sweep.group_lines;
    let lanes = WORKGROUP_SIZE / group;
    let slot = t / lanes;
    let lane = t % lanes;
    let first_line = i32(wid.x * group);
    // The workgroup's walk: as long as its longest line (the same value in every invocation).
    var steps = 0;
    for (var g = 0u; g < group; g++) {
        let l = first_line + i32(g);
        if (l < lines) {
            steps = max(steps, line_length(dx, dy, line_start(dx, dy, l, w, h), w, h));
        }
    }
    if (steps == 0) {
        return;
    }
    let line = first_line + i32(slot);
    let start = line_start(dx, dy, line, w, h);
    let length = select(0, line_length(dx, dy, start, w, h), line < lines);
    let row = d + 2u;
    // Words of the packed volumes a pixel (`volume_word`): two hypotheses each.
    let pairs = (d + 1u) / 2u;
    let mine = slot * 2u * row;
    for (var j = t; j < group * 2u * row; j += WORKGROUP_SIZE) {
        previous[j] = PAD;
    }
    workgroupBarrier();
    // Partial minima of this line: partial[slot·lanes + lane], then FAN of them at a time.
    let fans = (lanes + FAN - 1u) / FAN;
    let at = slot * lanes;
    var parity = 0u;
    for (var step = 0; step < steps; step++) {
        let on = step < length;
        let x = start.x + step * dx;
        let y = start.y + step * dy;
        let p = u32(max(y, 0)) * sweep.width + u32(max(x, 0));
        let prev = mine + parity * row;
        let cur = mine + (1u - parity) * row;
        if (step == 0) {
            // L = C: a word (two hypotheses) at a time; the high half of the last word of an odd
            // D is no hypothesis (its cost 0, its L never read: that slot is the PAD end).
            if (on) {
                for (var j = lane; j < pairs; j += lanes) {
                    let k = 2u * j;
                    let word = cost[p * pairs + j];
                    previous[cur + k + 1u] = word & 0xFFFFu;
                    if (k + 1u < d) {
                        previous[cur + k + 2u] = word >> 16u;
                    }
                    atomicAdd(&sum[p * pairs + j], word);
                }
            }
        } else {
            var m = PAD;
            if (on) {
                for (var k = lane; k < d; k += lanes) {
                    m = min(m, previous[prev + k + 1u]);
                }
            }
            partial[t] = m;
            workgroupBarrier();
            if (lane < fans) {
                var f = PAD;
                for (var j = lane * FAN; j < min(lane * FAN + FAN, lanes); j++) {
                    f = min(f, partial[at + j]);
                }
                partial_fan[at + lane] = f;
            }
            workgroupBarrier();
            if (on) {
                var minimum = PAD;
                for (var j = 0u; j < fans; j++) {
                    minimum = min(minimum, partial_fan[at + j]);
                }
                let before = u32(y - dy) * sweep.width + u32(x - dx);
                let p1 = sweep.p1;
                let cap = minimum + p2_at(image[p], image[before]);
                for (var j = lane; j < pairs; j += lanes) {
                    let k = 2u * j;
                    let word = cost[p * pairs + j];
                    let v0 = min(min(previous[prev + k + 1u], previous[prev + k] + p1), min(previous[prev + k + 2u] + p1, cap));
                    let l0 = (word & 0xFFFFu) + v0 - minimum;
                    var l1 = 0u;
                    if (k + 1u < d) {
                        let v1 = min(min(previous[prev + k + 2u], previous[prev + k + 1u] + p1), min(previous[prev + k + 3u] + p1, cap));
                        l1 = (word >> 16u) + v1 - minimum;
                        previous[cur + k + 2u] = l1;
                    }
                    previous[cur + k + 1u] = l0;
                    atomicAdd(&sum[p * pairs + j], l0 | (l1 << 16u));
                }
            }
        }
        workgroupBarrier();
        parity = 1u - parity;
    }
}
