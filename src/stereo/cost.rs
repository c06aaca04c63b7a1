//! Stages 4b–5 of the sweep and the cost volume that runs stages 3–5: the windowed ZNCC cost of
//! the reference against each warped image and the combination of the cameras' costs. The
//! projection and the warp (stages 3 and 4a) are in [`super::project`], exact, or
//! [`super::table`], tabulated; their functions are re-exported here.
//!
//! **Windowed ZNCC.** Over the (2r + 1)² window Ω(p) of reference pixel p, clipped to the image,
//! with n = |Ω|, reference values I and warped values W:
//!
//!   ZNCC = (ΣIW − ΣI·ΣW/n) / √((ΣI² − (ΣI)²/n)·(ΣW² − (ΣW)²/n)),
//!
//! invariant to a gain and an offset of W against I, which is what changes between the
//! viewpoints of an underwater rig: attenuation along paths of different length (a gain) and
//! backscatter (an offset). The sums are box sums, separable: a running sum down the columns
//! (O(1) per pixel whatever r), then each window's 2r + 1 column sums added along the row, in
//! f64 (no drift). The sums run over the
//! window's samples that have an answer (a projection without an answer or outside the other
//! image has none); a camera votes for (p, h) when at least half of the window has one, so a
//! correspondence up to the other image's very border is matched. A reference window whose
//! standard deviation is below `min_texture` has no cost at all (untextured: left to the
//! neighbours, and NaN in the end).
//!
//! **Combination.** Per camera c = min(1 − ZNCC, 1) ∈ [0, 1] (negative correlations are all
//! equally wrong); of the k cameras that vote, the mean of all when k ≤ 2, else the mean of the
//! best ⌈k/2⌉ (a camera that sees an occluder in front of the point does not spoil the others).
//! Stored as u16, c·[`COST_SCALE`], and [`NO_VOTE`] where no camera votes.

use rayon::prelude::*;

pub use super::project::{air_ray_starts, project_hypotheses, warp_bilinear};
use super::rays::{RayGrid, hypothesis_points};
use super::table::{ProjectionTable, TableBand, warp_tabulated};
use crate::base::GreyImage;
use crate::model::RefractiveCamera;

/// A cost of 1 (ZNCC ≤ 0) in the volume's u16 units.
pub const COST_SCALE: u16 = 2047;
/// The cost volume's value where no camera votes: worse than any vote.
pub const NO_VOTE: u16 = 2048;

/// Image rows per task of the cost volume: each task sweeps every hypothesis over its rows (and
/// r rows of halo above and below for the windows).
pub(crate) const BAND_ROWS: usize = 64;

/// Statistics of the reference image's windows.
#[derive(Debug, Clone)]
pub struct ReferenceWindows {
    /// Window radius r.
    pub radius: usize,
    /// n: pixels of each window inside the image.
    pub count: Vec<f32>,
    /// ΣI / n.
    pub mean: Vec<f32>,
    /// 1/√(ΣI² − (ΣI)²/n), 0 where the window is untextured.
    pub inv_spread: Vec<f32>,
}

impl ReferenceWindows {
    /// Whether pixel `i`'s window has texture enough to match.
    #[inline]
    pub fn textured(&self, i: usize) -> bool {
        self.inv_spread[i] > 0.0
    }
}

/// `reference_windows`: the window sums of the reference image (stage 4's fixed half).
pub fn reference_windows(image: &GreyImage, radius: usize, min_texture: f64) -> ReferenceWindows {
    let (w, h) = (image.width as usize, image.height as usize);
    let mut count = vec![0f32; w * h];
    let mut mean = vec![0f32; w * h];
    let mut inv_spread = vec![0f32; w * h];
    count
        .par_chunks_mut(w)
        .zip(mean.par_chunks_mut(w))
        .zip(inv_spread.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, ((count, mean), inv_spread))| {
            let (lo, hi) = (y.saturating_sub(radius), (y + radius).min(h - 1));
            let mut column = vec![[0f64; 2]; w];
            for yy in lo..=hi {
                for (x, c) in column.iter_mut().enumerate() {
                    let v = f64::from(image.pixels[yy * w + x]);
                    c[0] += v;
                    c[1] += v * v;
                }
            }
            let rows = (hi - lo + 1) as f64;
            let mut acc = [0f64; 2];
            for c in &column[..radius.min(w)] {
                acc[0] += c[0];
                acc[1] += c[1];
            }
            for x in 0..w {
                if x + radius < w {
                    acc[0] += column[x + radius][0];
                    acc[1] += column[x + radius][1];
                }
                let cols = ((x + radius).min(w - 1) - x.saturating_sub(radius) + 1) as f64;
                let n = rows * cols;
                let m = acc[0] / n;
                let spread = acc[1] - acc[0] * m;
                count[x] = n as f32;
                mean[x] = m as f32;
                // Standard deviation √(spread/n) ≥ min_texture, else untextured.
                inv_spread[x] = if spread > 0.0 && spread / n >= min_texture * min_texture {
                    (1.0 / spread.sqrt()) as f32
                } else {
                    0.0
                };
                if x >= radius {
                    acc[0] -= column[x - radius][0];
                    acc[1] -= column[x - radius][1];
                }
            }
        });
    ReferenceWindows {
        radius,
        count,
        mean,
        inv_spread,
    }
}

/// A camera that votes: its projection and its image.
pub struct Voter<'a> {
    /// The camera behind its port.
    pub camera: RefractiveCamera,
    /// Its image (grey 0 … 1).
    pub image: &'a GreyImage,
}

/// Least fraction of a window's pixels (inside the reference image) whose warped samples must
/// have an answer for the camera to vote: a correspondence up to the other image's very border
/// still has more than half of its window inside.
pub const MIN_VALID_FRACTION: f64 = 0.5;

/// Reused buffers of [`window_zncc`]: the column sums of one output row, one array per sum,
/// padded by r zeros each side so that every window's row sum is 2r + 1 plain additions; and,
/// for a radius above 7 only, the window sums of the row.
#[derive(Debug, Clone, Default)]
pub struct ZnccScratch {
    columns: [Vec<f64>; 6],
    sums: [Vec<f64>; 6],
}

/// Stage 4b, `window_zncc`: the ZNCC of the reference against one warped image for the rows
/// `first_row .. first_row + rows` (`zncc`, rows · w values), from the warped samples of the rows
/// `ext_first ..` (`warped`, which must cover every window: r rows above and below, clipped to
/// the image). The sums run over the window's samples that have an answer (Ω′ ⊆ Ω, the
/// reference's sums over Ω′ too); NaN where fewer than [`MIN_VALID_FRACTION`] of the window has
/// one, where the reference window is untextured, or where its part Ω′ is.
///
/// Column sums run down the rows (a window row added, one removed, f64), each window's sum is
/// then the 2r + 1 column sums beside it added afresh (no running sum along the row to drift),
/// every loop over whole rows without branches, so that it vectorises.
///
/// The order of every f64 addition is fixed, so that the result does not depend on how the work
/// is laid out: a column sum adds the window's rows top to bottom, then removes the row that
/// leaves after adding the one that enters; a window's sum adds its 2r + 1 column sums left to
/// right. Within that order the passes are few: the rows that enter and leave are applied in one
/// pass over the columns (the column sums held in registers between the two), and for r ≤ 7 the
/// six window sums are formed in registers in the loop that computes the correlation, rather
/// than by adding whole shifted rows into memory 2r times per sum.
#[allow(clippy::too_many_arguments)]
pub fn window_zncc(
    reference: &GreyImage,
    windows: &ReferenceWindows,
    min_texture: f64,
    warped: &[f32],
    ext_first: usize,
    first_row: usize,
    rows: usize,
    scratch: &mut ZnccScratch,
    zncc: &mut [f32],
) {
    let (w, h) = (reference.width as usize, reference.height as usize);
    let r = windows.radius;
    for c in scratch.columns.iter_mut() {
        c.clear();
        c.resize(w + 2 * r, 0.0);
    }
    // Image row y: its warped samples and the reference's pixels.
    let row = |y: usize| {
        let e = y - ext_first;
        (
            &warped[e * w..(e + 1) * w],
            &reference.pixels[y * w..(y + 1) * w],
        )
    };
    let columns = &mut scratch.columns;
    // The first window's rows, two per pass, top to bottom.
    let (lo, hi) = (first_row.saturating_sub(r), (first_row + r).min(h - 1));
    let mut y = lo;
    while y < hi {
        accumulate_rows(columns, r, row(y), 1.0, row(y + 1), 1.0);
        y += 2;
    }
    if y == hi {
        accumulate_row(columns, r, row(y), 1.0);
    }
    for k in 0..rows {
        let y = first_row + k;
        if k > 0 {
            let entering = (y + r < h).then(|| row(y + r));
            let leaving = (y > r).then(|| row(y - r - 1));
            match (entering, leaving) {
                (Some(new), Some(gone)) => accumulate_rows(columns, r, new, 1.0, gone, -1.0),
                (Some(new), None) => accumulate_row(columns, r, new, 1.0),
                (None, Some(gone)) => accumulate_row(columns, r, gone, -1.0),
                (None, None) => {}
            }
        }
        zncc_row(
            columns,
            r,
            &mut scratch.sums,
            &windows.count[y * w..(y + 1) * w],
            &windows.inv_spread[y * w..(y + 1) * w],
            min_texture * min_texture,
            &mut zncc[k * w..(k + 1) * w],
        );
    }
}

/// Adds (`sign` +1) or removes (−1) one sample, warped `s` over reference `i`, to the six sums
/// (count, ΣW, ΣW², ΣIW, ΣI, ΣI²) when it has an answer.
#[inline(always)]
fn add_sample(sums: &mut [f64; 6], s: f32, i: f32, sign: f64) {
    let answered = s.is_finite();
    let m = if answered { sign } else { 0.0 };
    let s = if answered { f64::from(s) } else { 0.0 };
    let i = f64::from(i);
    let ms = sign * s;
    sums[0] += m;
    sums[1] += ms;
    sums[2] += ms * s;
    sums[3] += ms * i;
    sums[4] += m * i;
    sums[5] += m * i * i;
}

crate::engine::cpu::lanes::dispatched! {
    /// Adds (`sign` +1) or removes (−1) one image row, its warped samples and the reference's
    /// pixels, to the padded column sums over the samples with an answer: (count, ΣW, ΣW², ΣIW,
    /// ΣI, ΣI²).
    fn accumulate_row(columns: &mut [Vec<f64>; 6], r: usize, (warped, image): (&[f32], &[f32]), sign: f64) {
        let w = warped.len();
        let image = &image[..w];
        let [c0, c1, c2, c3, c4, c5] = columns;
        let (c0, c1, c2) = (&mut c0[r..r + w], &mut c1[r..r + w], &mut c2[r..r + w]);
        let (c3, c4, c5) = (&mut c3[r..r + w], &mut c4[r..r + w], &mut c5[r..r + w]);
        for x in 0..w {
            let mut sums = [c0[x], c1[x], c2[x], c3[x], c4[x], c5[x]];
            add_sample(&mut sums, warped[x], image[x], sign);
            [c0[x], c1[x], c2[x], c3[x], c4[x], c5[x]] = sums;
        }
    }

    /// [`accumulate_row`] of row a then row b in one pass, the column sums held in registers
    /// between the two (the six arrays are read and written once, not twice).
    fn accumulate_rows(columns: &mut [Vec<f64>; 6], r: usize, (warped, image): (&[f32], &[f32]), sign: f64, (warped_b, image_b): (&[f32], &[f32]), sign_b: f64) {
        let w = warped.len();
        let (image, warped_b, image_b) = (&image[..w], &warped_b[..w], &image_b[..w]);
        let [c0, c1, c2, c3, c4, c5] = columns;
        let (c0, c1, c2) = (&mut c0[r..r + w], &mut c1[r..r + w], &mut c2[r..r + w]);
        let (c3, c4, c5) = (&mut c3[r..r + w], &mut c4[r..r + w], &mut c5[r..r + w]);
        for x in 0..w {
            let mut sums = [c0[x], c1[x], c2[x], c3[x], c4[x], c5[x]];
            add_sample(&mut sums, warped[x], image[x], sign);
            add_sample(&mut sums, warped_b[x], image_b[x], sign_b);
            [c0[x], c1[x], c2[x], c3[x], c4[x], c5[x]] = sums;
        }
    }

    /// The ZNCC of one output row from the padded column sums (see [`window_zncc`]). For r ≤ 7,
    /// one loop along the row forms each window's six sums and its correlation
    /// ([`zncc_row_unrolled`]); above, each sum is formed in `sums` by 2r passes along the row
    /// that add a shifted column row, then a second loop correlates ([`zncc_row_shifted`]).
    fn zncc_row(columns: &[Vec<f64>; 6], r: usize, sums: &mut [Vec<f64>; 6], count: &[f32], inv_spread: &[f32], min_spread_per_sample: f64, out: &mut [f32]) {
        let row = (count, inv_spread, min_spread_per_sample, out);
        match r {
            0 => zncc_row_unrolled::<1>(columns, row),
            1 => zncc_row_unrolled::<3>(columns, row),
            2 => zncc_row_unrolled::<5>(columns, row),
            3 => zncc_row_unrolled::<7>(columns, row),
            4 => zncc_row_unrolled::<9>(columns, row),
            5 => zncc_row_unrolled::<11>(columns, row),
            6 => zncc_row_unrolled::<13>(columns, row),
            7 => zncc_row_unrolled::<15>(columns, row),
            _ => zncc_row_shifted(columns, r, sums, row),
        }
    }
}

/// [`zncc_row`] for any r: each window sum formed in `sums` by adding the shifted column rows
/// `column[k .. k + w]`, k = 1 … 2r, to `column[.. w]` in turn, then the correlations.
#[inline(always)]
fn zncc_row_shifted(
    columns: &[Vec<f64>; 6],
    r: usize,
    sums: &mut [Vec<f64>; 6],
    (count, inv_spread, min_spread_per_sample, out): (&[f32], &[f32], f64, &mut [f32]),
) {
    let w = out.len();
    for (column, sum) in columns.iter().zip(sums.iter_mut()) {
        sum.clear();
        sum.extend_from_slice(&column[..w]);
        for k in 1..=2 * r {
            for (s, c) in sum.iter_mut().zip(&column[k..k + w]) {
                *s += c;
            }
        }
    }
    let [n, sw, sww, siw, si, sii] = sums;
    let (n, sw, sww) = (&n[..w], &sw[..w], &sww[..w]);
    let (siw, si, sii) = (&siw[..w], &si[..w], &sii[..w]);
    let (count, inv_spread) = (&count[..w], &inv_spread[..w]);
    for x in 0..w {
        let sums = [n[x], sw[x], sww[x], siw[x], si[x], sii[x]];
        out[x] = correlation(sums, count[x], inv_spread[x], min_spread_per_sample);
    }
}

/// One output row of [`zncc_row`] for the window width `D` = 2r + 1: each window's six sums
/// added in registers, column x + 0 first, and its correlation, in one loop along the row. With
/// `D` a constant the additions unroll and the loop vectorises over x.
#[inline(always)]
fn zncc_row_unrolled<const D: usize>(
    columns: &[Vec<f64>; 6],
    (count, inv_spread, min_spread_per_sample, out): (&[f32], &[f32], f64, &mut [f32]),
) {
    let w = out.len();
    let [n, sw, sww, siw, si, sii] = columns;
    let (n, sw, sww) = (
        shifted::<D>(n, w),
        shifted::<D>(sw, w),
        shifted::<D>(sww, w),
    );
    let (siw, si, sii) = (
        shifted::<D>(siw, w),
        shifted::<D>(si, w),
        shifted::<D>(sii, w),
    );
    let (count, inv_spread) = (&count[..w], &inv_spread[..w]);
    for x in 0..w {
        let sums = [
            window_sum(&n, x),
            window_sum(&sw, x),
            window_sum(&sww, x),
            window_sum(&siw, x),
            window_sum(&si, x),
            window_sum(&sii, x),
        ];
        out[x] = correlation(sums, count[x], inv_spread[x], min_spread_per_sample);
    }
}

/// The `D` rows `column[k .. k + w]`, k = 0 … D − 1: each of length w, so that indexing them with
/// x < w needs no bounds check in the loop.
#[inline(always)]
fn shifted<const D: usize>(column: &[f64], w: usize) -> [&[f64]; D] {
    let mut rows: [&[f64]; D] = [&[]; D];
    for (k, row) in rows.iter_mut().enumerate() {
        *row = &column[k..k + w];
    }
    rows
}

/// The window sum at x of [`shifted`] rows: their values at x added in order, k = 0 first.
#[inline(always)]
fn window_sum<const D: usize>(rows: &[&[f64]; D], x: usize) -> f64 {
    let mut sum = rows[0][x];
    for row in &rows[1..] {
        sum += row[x];
    }
    sum
}

/// One window's ZNCC from its six sums (count, ΣW, ΣW², ΣIW, ΣI, ΣI²), NaN where it does not
/// vote (see [`window_zncc`]). Without branches (`&` on the conditions, selects), so that the
/// loops that call it vectorise; the spreads are differences of f64 sums, their ratio is taken
/// in f32 (the result's type).
#[inline(always)]
fn correlation(
    [n, sw, sww, siw, si, sii]: [f64; 6],
    count: f32,
    inv_spread: f32,
    min_spread_per_sample: f64,
) -> f32 {
    let voted = (inv_spread > 0.0) & (n >= MIN_VALID_FRACTION * f64::from(count));
    let n_safe = if voted { n } else { 1.0 };
    let inv_n = 1.0 / n_safe;
    let spread_w = sww - sw * sw * inv_n;
    let spread_i = sii - si * si * inv_n;
    let covariance = (siw - si * sw * inv_n) as f32;
    let product = (spread_i * spread_w) as f32;
    let flat = !(spread_w > 1e-12 * n_safe);
    let product = if (product > 0.0) & !flat {
        product
    } else {
        1.0
    };
    let correlation = if flat {
        0.0
    } else {
        covariance / product.sqrt()
    };
    if voted & (spread_i >= min_spread_per_sample * n_safe) {
        correlation
    } else {
        f32::NAN
    }
}

/// Stage 5, `combine_views`: the cost of one hypothesis for every pixel of a band from the
/// cameras' ZNCC (see the module docs), u16, written at `costs[i]`.
pub fn combine_views(zncc: &[Vec<f32>], costs: &mut [u16]) {
    match zncc {
        [one] => combine_one(one, costs),
        _ => {
            let mut votes = Vec::with_capacity(zncc.len());
            for (i, cost) in costs.iter_mut().enumerate() {
                votes.clear();
                votes.extend(
                    zncc.iter()
                        .map(|z| z[i])
                        .filter(|z| z.is_finite())
                        .map(|z| (1.0 - z).clamp(0.0, 1.0)),
                );
                *cost = match votes.len() {
                    0 => NO_VOTE,
                    k => {
                        let used = if k <= 2 {
                            k
                        } else {
                            votes.sort_by(f32::total_cmp);
                            k.div_ceil(2)
                        };
                        let mean = votes[..used].iter().sum::<f32>() / used as f32;
                        to_units(mean)
                    }
                };
            }
        }
    }
}

/// A cost 0 … 1 in the volume's units: floor(x·[`COST_SCALE`] + ½) for x ≥ 0, as the GPU rounds
/// (and no libm call).
#[inline(always)]
fn to_units(cost: f32) -> u16 {
    // max/min first (a NaN becomes 0.5; the callers' costs are within 0 … 1 already, so no
    // value changes): the conversion below is then sound for any input.
    #[allow(clippy::manual_clamp)]
    let units = (cost * f32::from(COST_SCALE) + 0.5).max(0.5).min(2047.5);
    // SAFETY: `units` is a number within 0.5 … 2047.5, which i32 holds. The unchecked
    // conversion is one vector instruction; `as` adds NaN and range fix-ups that LLVM left
    // scalar (6 % of a 1280 × 1024 pair's samples).
    unsafe { units.to_int_unchecked::<i32>() as u16 }
}

crate::engine::cpu::lanes::dispatched! {
    /// [`combine_views`] for one voting camera: its own cost, or [`NO_VOTE`].
    fn combine_one(zncc: &[f32], costs: &mut [u16]) {
        for (cost, &z) in costs.iter_mut().zip(zncc) {
            // A NaN fails the comparison: no vote. max/min rather than `clamp`, whose NaN
            // handling kept the loop scalar; they agree on every number.
            #[allow(clippy::manual_clamp)]
            let units = to_units((1.0 - z).max(0.0).min(1.0));
            *cost = if z >= -f32::MAX { units } else { NO_VOTE };
        }
    }
}

/// Hypotheses of a band whose costs are kept in rows (`[h][pixel]`) before they are written,
/// transposed, into the volume's `[pixel][h]` layout: a pixel's 16 costs are 32 contiguous bytes
/// there, where one hypothesis at a time wrote 2 bytes every D·2 bytes.
const HYPOTHESIS_BLOCK: usize = 16;

/// Writes the rows `costs[k·n .. (k + 1)·n]` of hypotheses `first .. first + k_count` into
/// `volume[i·D + first + k]`: a transposition, 8 pixels × 16 hypotheses at a time through SSE2
/// shuffles where a whole block of 16 is written (one value at a time, strided, it was 8 % of a
/// 1280 × 1024 pair's time).
fn store_block(costs: &[u16], pixels: usize, first: usize, depth_count: usize, volume: &mut [u16]) {
    let count = costs.len() / pixels;
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if count == HYPOTHESIS_BLOCK {
        // SAFETY: SSE2 is part of every x86-64 processor.
        done = unsafe { transpose_sse2::store_tiles(costs, pixels, first, depth_count, volume) };
    }
    for (i, out) in volume.chunks_exact_mut(depth_count).enumerate().skip(done) {
        for (k, slot) in out[first..first + count].iter_mut().enumerate() {
            *slot = costs[k * pixels + i];
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod transpose_sse2 {
    use super::HYPOTHESIS_BLOCK;
    use std::arch::x86_64::*;

    /// [`super::store_block`] of 16 hypotheses for the first multiple of 8 pixels; returns how
    /// many pixels it wrote. SSE2 is part of x86-64, so there is nothing to detect.
    #[target_feature(enable = "sse2")]
    pub(super) fn store_tiles(
        costs: &[u16],
        pixels: usize,
        first: usize,
        depth_count: usize,
        volume: &mut [u16],
    ) -> usize {
        assert!(
            costs.len() == HYPOTHESIS_BLOCK * pixels && first + HYPOTHESIS_BLOCK <= depth_count
        );
        assert!(volume.len() >= pixels * depth_count);
        let tiles = pixels / 8;
        for tile in 0..tiles {
            let i = tile * 8;
            for half in 0..2 {
                // Rows: hypotheses 8·half … 8·half + 7, pixels i … i + 7.
                // SAFETY: (8·half + k)·pixels + i + 8 ≤ 16·pixels = costs.len().
                let r: [__m128i; 8] = std::array::from_fn(|k| unsafe {
                    _mm_loadu_si128(costs.as_ptr().add((8 * half + k) * pixels + i).cast())
                });
                let columns = transpose(r);
                for (j, column) in columns.into_iter().enumerate() {
                    let at = (i + j) * depth_count + first + 8 * half;
                    // SAFETY: at + 8 ≤ (i + j)·D + first + 16 ≤ pixels·D ≤ volume.len().
                    unsafe { _mm_storeu_si128(volume.as_mut_ptr().add(at).cast(), column) };
                }
            }
        }
        tiles * 8
    }

    /// The 8 × 8 transpose of u16 rows: column j of the result holds element j of every row.
    #[inline]
    #[target_feature(enable = "sse2")]
    fn transpose(r: [__m128i; 8]) -> [__m128i; 8] {
        let t0 = _mm_unpacklo_epi16(r[0], r[1]);
        let t1 = _mm_unpackhi_epi16(r[0], r[1]);
        let t2 = _mm_unpacklo_epi16(r[2], r[3]);
        let t3 = _mm_unpackhi_epi16(r[2], r[3]);
        let t4 = _mm_unpacklo_epi16(r[4], r[5]);
        let t5 = _mm_unpackhi_epi16(r[4], r[5]);
        let t6 = _mm_unpacklo_epi16(r[6], r[7]);
        let t7 = _mm_unpackhi_epi16(r[6], r[7]);
        let u0 = _mm_unpacklo_epi32(t0, t2);
        let u1 = _mm_unpackhi_epi32(t0, t2);
        let u2 = _mm_unpacklo_epi32(t1, t3);
        let u3 = _mm_unpackhi_epi32(t1, t3);
        let u4 = _mm_unpacklo_epi32(t4, t6);
        let u5 = _mm_unpackhi_epi32(t4, t6);
        let u6 = _mm_unpacklo_epi32(t5, t7);
        let u7 = _mm_unpackhi_epi32(t5, t7);
        [
            _mm_unpacklo_epi64(u0, u4),
            _mm_unpackhi_epi64(u0, u4),
            _mm_unpacklo_epi64(u1, u5),
            _mm_unpackhi_epi64(u1, u5),
            _mm_unpacklo_epi64(u2, u6),
            _mm_unpackhi_epi64(u2, u6),
            _mm_unpacklo_epi64(u3, u7),
            _mm_unpackhi_epi64(u3, u7),
        ]
    }
}

/// The cost volume (stages 2–5 for every hypothesis): `volume[(y·w + x)·D + h]` for the D
/// inverse depths, in bands of `BAND_ROWS` (64) rows in parallel, every hypothesis of a band in
/// turn. The projections are exact with `table` `None`, else tabulated through it and sampled
/// as they are interpolated ([`warp_tabulated`]; the table of the reference camera whose rays
/// `rays` are).
/// `progress` is called once per band and hypothesis.
#[allow(clippy::too_many_arguments)]
pub fn cost_volume(
    rays: &RayGrid,
    reference: &GreyImage,
    windows: &ReferenceWindows,
    min_texture: f64,
    voters: &[Voter],
    inverse_depths: &[f64],
    table: Option<&ProjectionTable>,
    progress: &(dyn Fn() + Sync),
) -> Vec<u16> {
    let mut volume = Vec::new();
    cost_volume_into(
        rays,
        reference,
        windows,
        min_texture,
        voters,
        inverse_depths,
        table,
        progress,
        &mut volume,
    );
    volume
}

/// [`cost_volume`] into `volume`, whose memory is reused where it has room.
#[allow(clippy::too_many_arguments)]
pub fn cost_volume_into(
    rays: &RayGrid,
    reference: &GreyImage,
    windows: &ReferenceWindows,
    min_texture: f64,
    voters: &[Voter],
    inverse_depths: &[f64],
    table: Option<&ProjectionTable>,
    progress: &(dyn Fn() + Sync),
    volume: &mut Vec<u16>,
) {
    let (w, h) = (rays.width, rays.height);
    let d = inverse_depths.len();
    let r = windows.radius;
    // No fill: a band writes every hypothesis of every pixel, or fills itself when untextured.
    super::volume::resize_for_writing(volume, w * h * d);
    volume
        .par_chunks_mut(BAND_ROWS * w * d)
        .enumerate()
        .for_each(|(band, volume)| {
            let first = band * BAND_ROWS;
            let rows = volume.len() / (w * d);
            let (ext_first, ext_end) = (first.saturating_sub(r), (first + rows + r).min(h));
            let ext = (ext_end - ext_first) * w;
            // The exact path's buffers (the tabulated one samples as it projects).
            let exact = if table.is_none() { ext } else { 0 };
            let mut points = vec![[0.0; 3]; exact];
            let mut pixels = vec![[0.0; 2]; exact];
            let mut status = vec![0u32; exact];
            let mut warped = vec![0f32; ext];
            let mut scratch = ZnccScratch::default();
            let mut zncc = vec![vec![0f32; rows * w]; voters.len()];
            let mut costs = vec![NO_VOTE; HYPOTHESIS_BLOCK.min(d) * rows * w];
            let any_textured = (first * w..(first + rows) * w).any(|i| windows.textured(i));
            if !any_textured {
                volume.fill(NO_VOTE);
            }
            let starts: Vec<Vec<f64>> = voters
                .iter()
                .map(|voter| {
                    let mut starts = vec![0.0; ext];
                    air_ray_starts(rays, ext_first, &voter.camera, &mut starts);
                    starts
                })
                .collect();
            let mut bands: Vec<Option<TableBand>> = voters
                .iter()
                .map(|voter| {
                    table.map(|table| {
                        TableBand::new(table, rays, ext_first, ext_end - ext_first, &voter.camera)
                    })
                })
                .collect();
            for (hypothesis, &q) in inverse_depths.iter().enumerate() {
                if any_textured {
                    for (((voter, zncc), starts), band) in voters
                        .iter()
                        .zip(zncc.iter_mut())
                        .zip(&starts)
                        .zip(bands.iter_mut())
                    {
                        match (table, band) {
                            (Some(table), Some(band)) => {
                                warp_tabulated(
                                    table,
                                    band,
                                    rays,
                                    &voter.camera,
                                    starts,
                                    q,
                                    voter.image,
                                    &mut warped,
                                );
                            }
                            _ => {
                                let placeholder = voter.camera.centre().coords.into();
                                hypothesis_points(rays, ext_first, q, placeholder, &mut points);
                                project_hypotheses(
                                    &voter.camera,
                                    &points,
                                    starts,
                                    &mut pixels,
                                    &mut status,
                                );
                                warp_bilinear(voter.image, &pixels, &status, &mut warped);
                            }
                        }
                        window_zncc(
                            reference,
                            windows,
                            min_texture,
                            &warped,
                            ext_first,
                            first,
                            rows,
                            &mut scratch,
                            zncc,
                        );
                    }
                    let k = hypothesis % HYPOTHESIS_BLOCK;
                    combine_views(&zncc, &mut costs[k * rows * w..(k + 1) * rows * w]);
                    if k + 1 == HYPOTHESIS_BLOCK || hypothesis + 1 == d {
                        let first = hypothesis - k;
                        store_block(&costs[..(k + 1) * rows * w], rows * w, first, d, volume);
                    }
                }
                progress();
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(w: u32, h: u32, f: impl Fn(usize, usize) -> f32) -> GreyImage {
        GreyImage {
            width: w,
            height: h,
            pixels: (0..(w * h) as usize)
                .map(|i| f(i % w as usize, i / w as usize))
                .collect(),
        }
    }

    #[test]
    fn zncc_is_one_under_gain_and_offset_and_the_sums_match_brute_force() {
        let (w, h, r) = (23usize, 17usize, 2usize);
        let texture = |x: usize, y: usize| {
            ((x * 7 + y * 13) % 11) as f32 / 11.0 + (x as f32 * 0.3).sin() * 0.2
        };
        let reference = image(w as u32, h as u32, texture);
        let windows = reference_windows(&reference, r, 0.01);
        // A warped image 0.6·I + 0.2 with one sample missing.
        let mut warped: Vec<f32> = reference.pixels.iter().map(|v| 0.6 * v + 0.2).collect();
        warped[5 * w + 9] = f32::NAN;
        let mut zncc = vec![0f32; w * h];
        window_zncc(
            &reference,
            &windows,
            0.01,
            &warped,
            0,
            0,
            h,
            &mut ZnccScratch::default(),
            &mut zncc,
        );
        // The window around the missing sample is matched over the samples it has.
        for (i, z) in zncc.iter().enumerate() {
            assert!((z - 1.0).abs() < 1e-5, "({}, {}): {z}", i % w, i / w);
        }
        // Less than half a window: no vote.
        let mut sparse = warped.clone();
        for y in 3..8 {
            for x in 7..12 {
                if (x + y) % 4 != 0 {
                    sparse[y * w + x] = f32::NAN;
                }
            }
        }
        window_zncc(
            &reference,
            &windows,
            0.01,
            &sparse,
            0,
            0,
            h,
            &mut ZnccScratch::default(),
            &mut zncc,
        );
        assert!(zncc[5 * w + 9].is_nan(), "{}", zncc[5 * w + 9]);
        assert!((zncc[12 * w + 3] - 1.0).abs() < 1e-5);
        // Against a brute-force ZNCC with another warped image, on a band with a halo.
        let other = image(w as u32, h as u32, |x, y| {
            ((x * 3 + y * 5) % 7) as f32 / 7.0
        });
        let (first, rows) = (6, 5);
        let (ext_first, ext_end) = (first - r, first + rows + r);
        let mut band = vec![0f32; rows * w];
        window_zncc(
            &reference,
            &windows,
            0.01,
            &other.pixels[ext_first * w..ext_end * w],
            ext_first,
            first,
            rows,
            &mut ZnccScratch::default(),
            &mut band,
        );
        for k in 0..rows {
            for x in 0..w {
                let y = first + k;
                let (mut si, mut sw, mut sii, mut sww, mut siw, mut n) =
                    (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
                for yy in y.saturating_sub(r)..=(y + r).min(h - 1) {
                    for xx in x.saturating_sub(r)..=(x + r).min(w - 1) {
                        let (i, v) = (
                            f64::from(reference.pixels[yy * w + xx]),
                            f64::from(other.pixels[yy * w + xx]),
                        );
                        si += i;
                        sw += v;
                        sii += i * i;
                        sww += v * v;
                        siw += i * v;
                        n += 1.0;
                    }
                }
                let expected =
                    (siw - si * sw / n) / ((sii - si * si / n) * (sww - sw * sw / n)).sqrt();
                assert!(
                    (f64::from(band[k * w + x]) - expected).abs() < 1e-5,
                    "({x}, {y}): {} against {expected}",
                    band[k * w + x]
                );
            }
        }
    }

    #[test]
    fn unrolled_window_sums_equal_the_shifted_rows_bit_for_bit() {
        // Column sums of 2r + 1 rows of pseudo-random samples, about one in eight without an
        // answer; the unrolled sums must round as the shifted rows' sums do, for every radius.
        let w = 41;
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        for r in 0..=9 {
            let mut columns: [Vec<f64>; 6] = Default::default();
            for c in columns.iter_mut() {
                c.resize(w + 2 * r, 0.0);
            }
            for _ in 0..=2 * r {
                let warped: Vec<f32> = (0..w)
                    .map(|_| if next() < 0.125 { f32::NAN } else { next() })
                    .collect();
                let image: Vec<f32> = (0..w).map(|_| next()).collect();
                accumulate_row(&mut columns, r, (&warped, &image), 1.0);
            }
            let count = vec![((2 * r + 1) * (2 * r + 1)) as f32; w];
            let inv_spread: Vec<f32> = (0..w)
                .map(|_| if next() < 0.1 { 0.0 } else { 1.0 })
                .collect();
            let mut unrolled = vec![0f32; w];
            let mut shifted = vec![0f32; w];
            let mut sums = Default::default();
            zncc_row(
                &columns,
                r,
                &mut sums,
                &count,
                &inv_spread,
                1e-4,
                &mut unrolled,
            );
            let row = (&count[..], &inv_spread[..], 1e-4, &mut shifted[..]);
            zncc_row_shifted(&columns, r, &mut sums, row);
            let bits = |z: &[f32]| z.iter().map(|z| z.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&unrolled), bits(&shifted), "r = {r}");
            if r > 0 {
                let matched = unrolled.iter().filter(|z| z.is_finite()).count();
                assert!(matched > w / 2, "r = {r}: {matched} of {w} matched");
            }
        }
    }

    #[test]
    fn bilinear_samples_and_rejects_outside() {
        let img = image(4, 3, |x, y| (x + 10 * y) as f32);
        let pixels = [
            [1.5, 1.25],
            [3.0, 2.0],
            [-0.01, 1.0],
            [0.0, 2.01],
            [1.0, 1.0],
        ];
        let status = [0, 0, 0, 0, 4];
        let mut out = [0f32; 5];
        warp_bilinear(&img, &pixels, &status, &mut out);
        assert!((out[0] - 14.0).abs() < 1e-5, "{}", out[0]);
        assert_eq!(out[1], 23.0);
        assert!(out[2].is_nan() && out[3].is_nan() && out[4].is_nan());
    }

    #[test]
    fn views_combine_as_the_mean_of_the_best_half() {
        let mut costs = vec![0u16; 3];
        // Pixel 0: two votes; pixel 1: three votes (best two of three: ⌈3/2⌉ = 2); pixel 2: none.
        let zncc = vec![
            vec![0.9, 0.9, f32::NAN],
            vec![0.5, 0.7, f32::NAN],
            vec![f32::NAN, -0.4, f32::NAN],
        ];
        combine_views(&zncc, &mut costs);
        let cost = |c: f32| (c * f32::from(COST_SCALE)).round() as u16;
        assert_eq!(
            costs,
            [cost((0.1 + 0.5) / 2.0), cost((0.1 + 0.3) / 2.0), NO_VOTE]
        );
        // One camera: its own cost, clamped to 0 … 1, or no vote.
        combine_views(&[vec![0.9, -0.4, f32::NAN]], &mut costs);
        assert_eq!(costs, [cost(0.1), COST_SCALE, NO_VOTE]);
        // Into the volume's [pixel][hypothesis] layout, hypotheses 1 and 2 of 4.
        let mut volume = vec![7u16; 3 * 4];
        store_block(&[1, 2, 3, 4, 5, 6], 3, 1, 4, &mut volume);
        assert_eq!(volume, [7, 1, 4, 7, 7, 2, 5, 7, 7, 3, 6, 7]);
        // A whole block of 16 over 21 pixels (two tiles of 8 and a rest), hypotheses 16 … 31
        // of 40: every value where the definition puts it, the others untouched.
        let (pixels, d, first) = (21, 40, 16);
        let block: Vec<u16> = (0..HYPOTHESIS_BLOCK * pixels).map(|j| j as u16).collect();
        let mut volume = vec![u16::MAX; pixels * d];
        store_block(&block, pixels, first, d, &mut volume);
        for i in 0..pixels {
            for h in 0..d {
                let expected = if (first..first + HYPOTHESIS_BLOCK).contains(&h) {
                    block[(h - first) * pixels + i]
                } else {
                    u16::MAX
                };
                assert_eq!(volume[i * d + h], expected, "pixel {i}, hypothesis {h}");
            }
        }
    }
}
