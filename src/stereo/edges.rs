//! Stage 10, `depth_edges`: the pixels next to a depth discontinuity.
//!
//! A matching window that straddles a depth edge sees both surfaces and its ZNCC follows the
//! nearer, more textured one: the foreground grows by up to the window radius into the background
//! (foreground fattening), and in a region only the reference sees (occluded from the others) the
//! fattened depth is even confirmed by the other camera, which sees the foreground there. A pixel
//! whose depth z differs from another depth within `radius` pixels by more than `jump`·z is
//! therefore returned as NaN: with m and M the least and greatest depths of the
//! (2·radius + 1)² window (separable running minimum and maximum),
//! near an edge ⇔ M − z > jump·z or z − m > jump·z.

use rayon::prelude::*;

/// `depth_edges`: whether each pixel of `depth` (row-major, NaN where none) lies within `radius`
/// pixels of a relative depth jump larger than `jump`.
pub fn depth_edges(
    depth: &[f32],
    width: usize,
    height: usize,
    radius: usize,
    jump: f32,
) -> Vec<bool> {
    let (w, h) = (width, height);
    // Least and greatest finite depth along each row's window, then down each column's.
    let mut row_min = vec![f32::INFINITY; w * h];
    let mut row_max = vec![f32::NEG_INFINITY; w * h];
    row_min
        .par_chunks_mut(w)
        .zip(row_max.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (lo, hi))| {
            let row = &depth[y * w..(y + 1) * w];
            for x in 0..w {
                let (a, b) = (x.saturating_sub(radius), (x + radius).min(w - 1));
                for &z in &row[a..=b] {
                    if z.is_finite() {
                        lo[x] = lo[x].min(z);
                        hi[x] = hi[x].max(z);
                    }
                }
            }
        });
    let mut near = vec![false; w * h];
    near.par_chunks_mut(w).enumerate().for_each(|(y, near)| {
        let (a, b) = (y.saturating_sub(radius), (y + radius).min(h - 1));
        for x in 0..w {
            let z = depth[y * w + x];
            if !z.is_finite() {
                continue;
            }
            let (mut lo, mut hi) = (z, z);
            for yy in a..=b {
                lo = lo.min(row_min[yy * w + x]);
                hi = hi.max(row_max[yy * w + x]);
            }
            near[x] = hi - z > jump * z || z - lo > jump * z;
        }
    });
    near
}

/// `near_mask`: whether each pixel lies within `radius` pixels (a (2·radius + 1)² window) of a
/// pixel where `mask` is set (separable running maximum).
pub fn near_mask(mask: &[bool], width: usize, height: usize, radius: usize) -> Vec<bool> {
    let (w, h) = (width, height);
    let mut rows = vec![false; w * h];
    rows.par_chunks_mut(w).enumerate().for_each(|(y, out)| {
        let row = &mask[y * w..(y + 1) * w];
        for (x, out) in out.iter_mut().enumerate() {
            let (a, b) = (x.saturating_sub(radius), (x + radius).min(w - 1));
            *out = row[a..=b].iter().any(|&m| m);
        }
    });
    let mut near = vec![false; w * h];
    near.par_chunks_mut(w).enumerate().for_each(|(y, out)| {
        let (a, b) = (y.saturating_sub(radius), (y + radius).min(h - 1));
        for (x, out) in out.iter_mut().enumerate() {
            *out = (a..=b).any(|yy| rows[yy * w + x]);
        }
    });
    near
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_marks_a_band_on_both_sides_and_a_slope_nothing() {
        let (w, h) = (20, 5);
        let depth: Vec<f32> = (0..w * h)
            .map(|i| if i % w < 10 { 1.0 } else { 1.5 })
            .collect();
        let near = depth_edges(&depth, w, h, 2, 0.03);
        for x in 0..w {
            assert_eq!(near[2 * w + x], (8..12).contains(&x), "column {x}");
        }
        // A gentle slope (0.2 % a pixel) and a hole: no edge.
        let mut slope: Vec<f32> = (0..w * h).map(|i| 1.0 + 0.002 * (i % w) as f32).collect();
        slope[2 * w + 5] = f32::NAN;
        assert!(depth_edges(&slope, w, h, 3, 0.03).iter().all(|n| !n));
    }
}
