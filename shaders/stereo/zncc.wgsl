// Stage 4b, `window_zncc` (twin in src/stereo/cost.rs) for a chunk of hypotheses and every voter:
// per reference pixel, the ZNCC of the reference's (2r + 1)² window (clipped to the image) against
// the voter's warped samples, over the samples that have an answer; NO_ZNCC where fewer than half
// the window has one, where the reference window is untextured (all of it) or where its part is.
// Written to `zncc[(v·chunk + k)·W·H + i]`. Dispatch (⌈W/64⌉, ⌈H/strip⌉, voters·chunk).
//
// Separable box sums, as on the CPU: an invocation walks one column down a strip of
// `sweep.strip` rows, adding the window row that enters and removing the one that leaves (each
// row's sum over its 2r + 1 columns, recomputed from the samples, so what is removed is what was
// added). Per pixel that reads about 4(2r + 1) samples instead of 2(2r + 1)², and the running
// sums' rounding stays that of a direct sum: the walk is at most strip + 2r steps, and every
// sample is shifted by this column's values at the strip's middle row, within strip/2 + r rows of
// every window it enters (sums of local differences, not of raw grey levels, against
// cancellation).

@group(0) @binding(3) var<storage, read> image: array<f32>;
@group(0) @binding(5) var<storage, read> warped: array<f32>;
@group(0) @binding(9) var<storage, read_write> zncc: array<f32>;

// Window sums over the samples with an answer: n, ΣW, ΣW², ΣWI, ΣI, ΣI² (W, I shifted); and the
// reference's own over every sample of the window (its texture, `ReferenceWindows::textured`).
struct Sums {
    n: f32,
    sw: f32,
    sww: f32,
    swi: f32,
    si: f32,
    sii: f32,
    ti: f32,
    tii: f32,
}

fn zero_sums() -> Sums {
    return Sums(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
}

// The sums of image row y over the columns x_lo ..= x_hi.
fn row_sums(base: u32, y: u32, x_lo: u32, x_hi: u32, cw: f32, ci: f32) -> Sums {
    var s = zero_sums();
    let row = y * sweep.width;
    for (var x = x_lo; x <= x_hi; x++) {
        let g = image[row + x] - ci;
        s.ti += g;
        s.tii += g * g;
        let raw = warped[base + row + x];
        if (raw > NO_SAMPLE) {
            let a = raw - cw;
            s.n += 1.0;
            s.sw += a;
            s.sww += a * a;
            s.swi += a * g;
            s.si += g;
            s.sii += g * g;
        }
    }
    return s;
}

// a + sign·b.
fn accumulate(a: Sums, b: Sums, sign: f32) -> Sums {
    return Sums(
        a.n + sign * b.n,
        a.sw + sign * b.sw,
        a.sww + sign * b.sww,
        a.swi + sign * b.swi,
        a.si + sign * b.si,
        a.sii + sign * b.sii,
        a.ti + sign * b.ti,
        a.tii + sign * b.tii,
    );
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let w = sweep.width;
    let h = sweep.height;
    let v = gid.z / sweep.chunk;
    let k = gid.z % sweep.chunk;
    let y0 = gid.y * sweep.strip;
    if (gid.x >= w || y0 >= h || v >= sweep.voters || sweep.first + k >= sweep.hypotheses) {
        return;
    }
    let x = gid.x;
    let r = sweep.radius;
    let y_end = min(y0 + sweep.strip, h);
    let x_lo = select(0u, x - r, x >= r);
    let x_hi = min(x + r, w - 1u);
    let columns = f32(x_hi - x_lo + 1u);
    let base = (v * sweep.chunk + k) * w * h;
    // The shift: this column's values at the strip's middle row.
    let middle = (y0 + y_end - 1u) / 2u * w + x;
    let ci = image[middle];
    let cw = select(0.5, warped[base + middle], warped[base + middle] > NO_SAMPLE);

    var s = zero_sums();
    for (var y = select(0u, y0 - r, y0 >= r); y <= min(y0 + r, h - 1u); y++) {
        s = accumulate(s, row_sums(base, y, x_lo, x_hi, cw, ci), 1.0);
    }
    let min_spread = sweep.min_texture * sweep.min_texture;
    for (var y = y0; y < y_end; y++) {
        if (y > y0) {
            if (y + r < h) {
                s = accumulate(s, row_sums(base, y + r, x_lo, x_hi, cw, ci), 1.0);
            }
            if (y > r) {
                s = accumulate(s, row_sums(base, y - r - 1u, x_lo, x_hi, cw, ci), -1.0);
            }
        }
        let rows = f32(min(y + r, h - 1u) - select(0u, y - r, y >= r) + 1u);
        let n_window = columns * rows;
        let textured = s.tii - s.ti * s.ti / n_window;
        var z = NO_ZNCC;
        if (textured > 0.0 && textured >= min_spread * n_window && s.n >= 0.5 * n_window) {
            let spread_w = s.sww - s.sw * s.sw / s.n;
            let spread_i = s.sii - s.si * s.si / s.n;
            if (spread_i >= min_spread * s.n) {
                z = 0.0;
                // A warped window flat to within the sums' rounding has no correlation to give.
                if (spread_w > max(1e-12 * s.n, ZNCC_FLAT * s.sww)) {
                    z = (s.swi - s.si * s.sw / s.n) / sqrt(spread_i * spread_w);
                }
            }
        }
        zncc[base + y * w + x] = z;
    }
}
