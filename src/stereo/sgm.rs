//! Stage 7, semi-global matching (Hirschmüller, PAMI 2008) over the hypotheses.
//!
//! Along each path direction r the cost of hypothesis h at pixel p is
//!
//!   L_r(p, h) = C(p, h) + min(L_r(p − r, h), L_r(p − r, h ± 1) + P1, min_k L_r(p − r, k) + P2(p, r))
//!               − min_k L_r(p − r, k),
//!
//! and S(p, h) = Σ_r L_r(p, h). P1 charges a step of one hypothesis (a slanted surface), P2 any
//! larger jump; P2 is lowered where the reference image changes along the path, where depth edges
//! are likely: P2(p, r) = max(P1 + 1, P2 / (1 + |I(p) − I(p − r)| / g)). Eight paths (the four
//! axes and the four diagonals) or four (the axes). L ≤ C + P2, so with C ≤ [`NO_VOTE`] and P2 ≤
//! 2048 every L fits 12 bits and S over 8 paths fits u16.
//!
//! Loop shape (the GPU twin's): the horizontal paths row by row (each row a sequence), the
//! vertical and diagonal paths as sweeps down and up the image, every pixel of a row
//! independent given the previous row.

use rayon::prelude::*;

use super::cost::NO_VOTE;
#[cfg(doc)]
use super::select::winner_take_all;
use super::select::{Winners, select_pixels};

/// Padding of a path's previous costs at both ends of the hypotheses: large, and far from overflow
/// when P1 is added.
const PAD: u16 = 0x7FFF;

/// SGM's parameters in cost units (the volume's u16).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SgmParams {
    /// P1: a step of one hypothesis.
    pub p1: u16,
    /// P2: a larger jump, before the image's gradient lowers it.
    pub p2: u16,
    /// g: the grey-level change (0 … 1) along a path at which P2 is halved.
    pub gradient: f32,
    /// 8 or 4 paths.
    pub paths: usize,
}

impl SgmParams {
    #[inline]
    fn p2_at(&self, a: f32, b: f32) -> u16 {
        let p2 = f32::from(self.p2) / (1.0 + (a - b).abs() / self.gradient);
        // floor(p2 + ½), p2 ≥ 0: as the GPU rounds (and no libm call).
        ((p2 + 0.5) as u16).max(self.p1 + 1)
    }
}

/// One step of a path: L(p, ·) from L(p − r, ·) (`previous`, padded with [`PAD`] at both ends,
/// D + 2 values, whose least value is `minimum`) and C(p, ·); written into `current` (padded
/// likewise), added to `sum` (`ADD`) or written there (the first path to reach `sum`). Returns
/// the least L(p, ·), the next step's `minimum`.
#[inline(always)]
fn path_step<const ADD: bool>(
    previous: &[u16],
    minimum: u16,
    cost: &[u16],
    p1: u16,
    p2: u16,
    current: &mut [u16],
    sum: &mut [u16],
) -> u16 {
    let d = cost.len();
    assert!(previous.len() == d + 2 && current.len() == d + 2 && sum.len() == d);
    let cap = minimum + p2;
    let (below, same, above) = (&previous[..d], &previous[1..d + 1], &previous[2..]);
    let out = &mut current[1..d + 1];
    // Without branches over slices of one length, so that it vectorises (u16 lanes).
    let mut least = u16::MAX;
    for i in 0..d {
        let v = same[i].min(below[i] + p1).min(above[i] + p1).min(cap);
        let l = cost[i] + v - minimum;
        out[i] = l;
        sum[i] = if ADD { sum[i].saturating_add(l) } else { l };
        least = least.min(l);
    }
    current[0] = PAD;
    current[d + 1] = PAD;
    least
}

/// The first pixel of a path: L = C, added to `sum` (`ADD`) or written there. Returns the least L.
#[inline(always)]
fn path_start<const ADD: bool>(cost: &[u16], current: &mut [u16], sum: &mut [u16]) -> u16 {
    let d = cost.len();
    current[0] = PAD;
    current[d + 1] = PAD;
    current[1..=d].copy_from_slice(cost);
    let mut least = u16::MAX;
    for (s, &c) in sum.iter_mut().zip(cost) {
        *s = if ADD { s.saturating_add(c) } else { c };
        least = least.min(c);
    }
    least
}

/// `sgm_aggregate`: S = Σ_r L_r over the cost volume `cost` (`[(y·w + x)·D + h]`), with the
/// reference image (grey, row-major) for P2.
pub fn sgm_aggregate(
    cost: &[u16],
    width: usize,
    height: usize,
    depth_count: usize,
    image: &[f32],
    params: &SgmParams,
) -> Vec<u16> {
    let mut sum = Vec::new();
    sgm_aggregate_into(cost, width, height, depth_count, image, params, &mut sum);
    sum
}

/// [`sgm_aggregate`] into `sum`, whose memory is reused where it has room.
pub fn sgm_aggregate_into(
    cost: &[u16],
    width: usize,
    height: usize,
    depth_count: usize,
    image: &[f32],
    params: &SgmParams,
    sum: &mut Vec<u16>,
) {
    aggregate(cost, width, height, depth_count, image, params, sum, None);
}

/// [`sgm_aggregate_into`] and then [`winner_take_all`] of `sum` and `cost`, the same winners,
/// with each row's winners selected as soon as its last path has been added: its sums and
/// costs are then still in the cache, where a pass of its own read both volumes (640 MiB at
/// 1280 × 1024 × 128) once more.
pub fn sgm_winners(
    cost: &[u16],
    width: usize,
    height: usize,
    depth_count: usize,
    image: &[f32],
    params: &SgmParams,
    sum: &mut Vec<u16>,
) -> Winners {
    let mut winners = Winners {
        index: vec![f32::NAN; width * height],
        quality: vec![0.0; width * height],
        distinctness: vec![0.0; width * height],
    };
    aggregate(
        cost,
        width,
        height,
        depth_count,
        image,
        params,
        sum,
        Some(&mut winners),
    );
    winners
}

/// The aggregation, and with `winners` the selection of every row after its last path.
#[allow(clippy::too_many_arguments)]
fn aggregate(
    cost: &[u16],
    width: usize,
    height: usize,
    depth_count: usize,
    image: &[f32],
    params: &SgmParams,
    sum: &mut Vec<u16>,
    mut winners: Option<&mut Winners>,
) {
    let (w, d) = (width, depth_count);
    debug_assert!(cost.iter().all(|&c| c <= NO_VOTE));
    // No fill: the first path along each row writes its sums.
    super::volume::resize_for_writing(sum, w * height * d);
    let row_len = w * d;
    // Left to right and right to left along row y: the first writes the row's sums, the
    // second adds to them.
    let horizontal = |y: usize, sum_row: &mut [u16]| {
        let mut buffers = [vec![PAD; d + 2], vec![PAD; d + 2]];
        let cost_row = &cost[y * row_len..(y + 1) * row_len];
        horizontal_paths(
            cost_row,
            sum_row,
            &image[y * w..(y + 1) * w],
            params,
            &mut buffers,
        );
    };
    // Down and up the image: the vertical path and, with 8 paths, the two diagonals. On the way
    // down each row's horizontal paths run beside the vertical ones of the row above, so that
    // the sweep finds the row's costs and sums still in the cache (a separate pass over the
    // rows read 320 MiB of costs and 640 MiB of sums more at 1280 × 1024 × 128). The sums are
    // saturating additions of costs ≥ 0, the same in any order.
    let columns: &[isize] = if params.paths >= 8 { &[0, 1, -1] } else { &[0] };
    let n = columns.len();
    // Pixels per task along a row.
    const CHUNK: usize = 64;
    if height > 0 {
        horizontal(0, &mut sum[..row_len]);
    }
    for down in [true, false] {
        let mut previous = vec![PAD; w * n * (d + 2)];
        let mut current = vec![PAD; w * n * (d + 2)];
        let mut previous_least = vec![0u16; w * n];
        let mut current_least = vec![0u16; w * n];
        for k in 0..height {
            let y = if down { k } else { height - 1 - k };
            let before_row = if down { y.wrapping_sub(1) } else { y + 1 };
            let cost_row = &cost[y * row_len..(y + 1) * row_len];
            let (sum_row, below) = sum[y * row_len..].split_at_mut(row_len);
            // The next row's horizontal paths, on the way down.
            let next = (down && y + 1 < height).then(|| &mut below[..row_len]);
            let line = Line {
                row: &image[y * w..(y + 1) * w],
                before: (k > 0).then(|| &image[before_row * w..(before_row + 1) * w]),
                cost: cost_row,
                previous: &previous,
                previous_least: &previous_least,
                columns,
                depth_count: d,
            };
            rayon::join(
                || {
                    if let Some(next) = next {
                        horizontal(y + 1, next);
                    }
                },
                || {
                    sum_row
                        .par_chunks_mut(CHUNK * d)
                        .zip(current.par_chunks_mut(CHUNK * n * (d + 2)))
                        .zip(current_least.par_chunks_mut(CHUNK * n))
                        .enumerate()
                        .for_each(|(chunk, ((sum, current), least))| {
                            vertical_paths(&line, chunk * CHUNK, params, sum, current, least);
                        });
                },
            );
            // On the way up a row's sums are complete once its own paths are added.
            if let (false, Some(winners)) = (down, winners.as_deref_mut()) {
                let pixels = y * w..(y + 1) * w;
                winners.index[pixels.clone()]
                    .par_chunks_mut(CHUNK)
                    .zip(winners.quality[pixels.clone()].par_chunks_mut(CHUNK))
                    .zip(winners.distinctness[pixels].par_chunks_mut(CHUNK))
                    .enumerate()
                    .for_each(|(chunk, ((index, quality), distinctness))| {
                        let at = chunk * CHUNK * d..(chunk * CHUNK + index.len()) * d;
                        select_pixels(
                            &sum[y * row_len..(y + 1) * row_len][at.clone()],
                            &cost_row[at],
                            d,
                            index,
                            quality,
                            distinctness,
                        );
                    });
            }
            std::mem::swap(&mut previous, &mut current);
            std::mem::swap(&mut previous_least, &mut current_least);
        }
    }
}

/// One image row of a sweep down or up the image and what its paths come from.
struct Line<'a> {
    /// The reference image's row.
    row: &'a [f32],
    /// The image's row the paths come from; `None` on the sweep's first row.
    before: Option<&'a [f32]>,
    /// The row's costs.
    cost: &'a [u16],
    /// L of the row before, `[(x·n + m)·(D + 2) + 1 + h]` for the n path directions.
    previous: &'a [u16],
    /// The least L of each of those.
    previous_least: &'a [u16],
    /// The directions' column offsets.
    columns: &'a [isize],
    depth_count: usize,
}

crate::engine::cpu::lanes::dispatched! {
    /// Both horizontal paths of one row: `cost` and `sum` the row's `[x·D + h]`, `row` its image
    /// row, `buffers` two padded path buffers of D + 2.
    fn horizontal_paths(cost: &[u16], sum: &mut [u16], row: &[f32], params: &SgmParams, buffers: &mut [Vec<u16>; 2]) {
        let w = row.len();
        let d = cost.len() / w;
        let [previous, current] = buffers;
        for forward in [true, false] {
            let mut least = 0;
            for k in 0..w {
                let x = if forward { k } else { w - 1 - k };
                let (c, s) = (&cost[x * d..(x + 1) * d], &mut sum[x * d..(x + 1) * d]);
                // Left to right is the first path to reach the row's sums: it writes them.
                least = match (k, forward) {
                    (0, true) => path_start::<false>(c, current, s),
                    (0, false) => path_start::<true>(c, current, s),
                    _ => {
                        let before = if forward { x - 1 } else { x + 1 };
                        let p2 = params.p2_at(row[x], row[before]);
                        if forward {
                            path_step::<false>(previous, least, c, params.p1, p2, current, s)
                        } else {
                            path_step::<true>(previous, least, c, params.p1, p2, current, s)
                        }
                    }
                };
                std::mem::swap(previous, current);
            }
        }
    }

    /// The vertical and diagonal paths of the pixels `first ..` of one line (`sum`, `current`
    /// and `least` those pixels' parts of the line's sums, paths and least values).
    fn vertical_paths(line: &Line, first: usize, params: &SgmParams, sum: &mut [u16], current: &mut [u16], least: &mut [u16]) {
        let d = line.depth_count;
        let (w, n) = (line.row.len(), line.columns.len());
        for j in 0..sum.len() / d {
            let x = first + j;
            let c = &line.cost[x * d..(x + 1) * d];
            let s = &mut sum[j * d..(j + 1) * d];
            for (m, &dx) in line.columns.iter().enumerate() {
                let out = &mut current[(j * n + m) * (d + 2)..(j * n + m + 1) * (d + 2)];
                // The path comes from (x − dx, y ∓ 1).
                let from = x as isize - dx;
                least[j * n + m] = match line.before {
                    Some(before) if from >= 0 && from < w as isize => {
                        let from = from as usize;
                        let p2 = params.p2_at(line.row[x], before[from]);
                        let k = from * n + m;
                        let previous = &line.previous[k * (d + 2)..(k + 1) * (d + 2)];
                        path_step::<true>(previous, line.previous_least[k], c, params.p1, p2, out, s)
                    }
                    _ => path_start::<true>(c, out, s),
                };
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_path_step_follows_the_recursion() {
        let previous = [PAD, 10, 4, 9, 30, PAD];
        let cost = [5, 5, 5, 5];
        let mut current = [0u16; 6];
        let mut sum = [1u16; 4];
        let least = path_step::<true>(&previous, 4, &cost, 2, 7, &mut current, &mut sum);
        // min = 4; h0: min(10, 4+2, 11) = 6 → 5 + 6 − 4 = 7; h1: 4 → 5; h2: min(9, 6) = 6 → 7;
        // h3: min(30, 9+2, 11) = 11 → 12.
        assert_eq!(current, [PAD, 7, 5, 7, 12, PAD]);
        assert_eq!(sum, [8, 6, 8, 13]);
        assert_eq!(least, 5);
    }

    #[test]
    fn aggregation_fills_a_gap_from_its_neighbours() {
        // 9 × 7 pixels, 6 hypotheses: every pixel prefers hypothesis 2 except the centre, which
        // has no vote; the aggregated minimum there is hypothesis 2 too, on 8 and on 4 paths.
        let (w, h, d) = (9, 7, 6);
        let mut cost = vec![0u16; w * h * d];
        for p in 0..w * h {
            for k in 0..d {
                cost[p * d + k] = if k == 2 { 100 } else { 900 };
            }
        }
        let centre = 3 * w + 4;
        cost[centre * d..(centre + 1) * d].fill(NO_VOTE);
        let image = vec![0.5f32; w * h];
        for paths in [8, 4] {
            let params = SgmParams {
                p1: 50,
                p2: 400,
                gradient: 0.05,
                paths,
            };
            let sum = sgm_aggregate(&cost, w, h, d, &image, &params);
            let s = &sum[centre * d..(centre + 1) * d];
            let best = (0..d).min_by_key(|&k| s[k]).unwrap();
            assert_eq!(best, 2, "{paths} paths: {s:?}");
        }
    }

    #[test]
    fn aggregation_matches_the_recursion_path_by_path() {
        // An independent oracle: every path direction r walked on its own over a full array of
        // L_r, in an order that visits p − r before p, then S = Σ_r L_r (saturating).
        let (w, h, d) = (11usize, 9usize, 7usize);
        let mut seed = 12345u64;
        let mut next = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 33) as u32
        };
        let cost: Vec<u16> = (0..w * h * d)
            .map(|_| match next() % 10 {
                0 => NO_VOTE,
                _ => (next() % 2048) as u16,
            })
            .collect();
        let image: Vec<f32> = (0..w * h)
            .map(|_| (next() % 1000) as f32 / 1000.0)
            .collect();
        for paths in [8, 4] {
            let params = SgmParams {
                p1: 60,
                p2: 500,
                gradient: 0.1,
                paths,
            };
            let mut directions: Vec<(isize, isize)> = vec![(1, 0), (-1, 0), (0, 1), (0, -1)];
            if paths == 8 {
                directions.extend([(1, 1), (-1, 1), (1, -1), (-1, -1)]);
            }
            let mut expected = vec![0u16; w * h * d];
            for &(dx, dy) in &directions {
                let mut l = vec![0u16; w * h * d];
                let ys: Vec<usize> = if dy >= 0 {
                    (0..h).collect()
                } else {
                    (0..h).rev().collect()
                };
                let xs: Vec<usize> = if dx >= 0 {
                    (0..w).collect()
                } else {
                    (0..w).rev().collect()
                };
                for &y in &ys {
                    for &x in &xs {
                        let p = y * w + x;
                        let (fx, fy) = (x as isize - dx, y as isize - dy);
                        let inside = fx >= 0 && fy >= 0 && fx < w as isize && fy < h as isize;
                        for k in 0..d {
                            l[p * d + k] = if !inside {
                                cost[p * d + k]
                            } else {
                                let q = fy as usize * w + fx as usize;
                                let before = &l[q * d..(q + 1) * d];
                                let least = *before.iter().min().unwrap();
                                let p2 = params.p2_at(image[p], image[q]);
                                let mut best = u32::from(before[k]);
                                if k > 0 {
                                    best =
                                        best.min(u32::from(before[k - 1]) + u32::from(params.p1));
                                }
                                if k + 1 < d {
                                    best =
                                        best.min(u32::from(before[k + 1]) + u32::from(params.p1));
                                }
                                best = best.min(u32::from(least) + u32::from(p2));
                                (u32::from(cost[p * d + k]) + best - u32::from(least)) as u16
                            };
                        }
                    }
                }
                for (s, v) in expected.iter_mut().zip(&l) {
                    *s = s.saturating_add(*v);
                }
            }
            assert_eq!(
                sgm_aggregate(&cost, w, h, d, &image, &params),
                expected,
                "{paths} paths"
            );
            // Into a reused volume holding anything: every sum is written before it is read.
            let mut reused = vec![54321u16; w * h * d + 5];
            sgm_aggregate_into(&cost, w, h, d, &image, &params, &mut reused);
            assert_eq!(reused, expected, "{paths} paths, reused");
            // The fused selection picks what the selection of the whole volume picks.
            let mut sum = vec![7u16; 3];
            let fused = sgm_winners(&cost, w, h, d, &image, &params, &mut sum);
            let apart = crate::stereo::select::winner_take_all(&expected, &cost, d);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&fused.index), bits(&apart.index), "{paths} paths");
            assert_eq!(bits(&fused.quality), bits(&apart.quality));
            assert_eq!(bits(&fused.distinctness), bits(&apart.distinctness));
            assert!(apart.index.iter().any(|i| i.is_finite()));
        }
    }
}
