//! Stage 8, `winner_take_all`: the hypothesis of least aggregated cost per pixel, refined between
//! hypotheses, with what the confidence is made of.
//!
//! Sub-hypothesis refinement: the winner h* is the least aggregated cost S; a parabola through
//! the matching costs C₋, C₀, C₊ at h* and its neighbours (the aggregated ones where a neighbour
//! has no vote) puts the vertex at h* + δ, δ = (C₋ − C₊) / (2(C₋ − 2C₀ + C₊)) ∈ [−½, ½]. The
//! matching costs, not the aggregated ones: SGM's penalties flatten S toward the hypotheses and
//! pulled the vertex by a third of a step on a noise-free plane (0.33 against 0.06 of a step,
//! `tests/stereo.rs`). The hypotheses are uniform in inverse depth, so this is a parabola in 1/z:
//! 1/z = q₀ + (h* + δ)·Δq.
//!
//! Rejected (NaN): no camera voted for the winner; the winner is the first or last hypothesis
//! (the surface may lie outside the depth range).

use rayon::prelude::*;

use super::cost::{COST_SCALE, NO_VOTE};

/// Per pixel: the refined hypothesis index and the confidence's ingredients.
#[derive(Debug, Clone)]
pub struct Winners {
    /// h* + δ, NaN where rejected.
    pub index: Vec<f32>,
    /// 1 − C(p, h*) / [`COST_SCALE`]: the winner's (combined, clipped) ZNCC, 0 … 1.
    pub quality: Vec<f32>,
    /// (S₂ − S₁) / S₂ with S₁ the winner's aggregated cost and S₂ the least aggregated cost two or
    /// more hypotheses away from it: 0 for an ambiguous pixel, toward 1 for a distinct one.
    pub distinctness: Vec<f32>,
}

/// `winner_take_all` over the aggregated costs `sum` with the raw costs `cost` (both
/// `[(y·w + x)·D + h]`).
pub fn winner_take_all(sum: &[u16], cost: &[u16], depth_count: usize) -> Winners {
    let d = depth_count;
    let pixels = sum.len() / d;
    let mut index = vec![f32::NAN; pixels];
    let mut quality = vec![0f32; pixels];
    let mut distinctness = vec![0f32; pixels];
    index
        .par_chunks_mut(TASK_PIXELS)
        .zip(quality.par_chunks_mut(TASK_PIXELS))
        .zip(distinctness.par_chunks_mut(TASK_PIXELS))
        .enumerate()
        .for_each(|(task, ((index, quality), distinctness))| {
            let pixels = task * TASK_PIXELS * d..(task * TASK_PIXELS + index.len()) * d;
            select_pixels(
                &sum[pixels.clone()],
                &cost[pixels],
                d,
                index,
                quality,
                distinctness,
            );
        });
    Winners {
        index,
        quality,
        distinctness,
    }
}

/// Pixels per task of [`winner_take_all`].
const TASK_PIXELS: usize = 1024;

/// The least of `values` (`u16::MAX` for none), a loop that vectorises.
#[inline(always)]
fn least(values: &[u16]) -> u16 {
    values.iter().fold(u16::MAX, |m, &v| m.min(v))
}

crate::engine::cpu::lanes::dispatched! {
    /// [`winner_take_all`] for the pixels of `index` (their `sum` and `cost`, D a pixel).
    pub(crate) fn select_pixels(sum: &[u16], cost: &[u16], d: usize, index: &mut [f32], quality: &mut [f32], distinctness: &mut [f32]) {
        for j in 0..index.len() {
            let s = &sum[j * d..(j + 1) * d];
            let c = &cost[j * d..(j + 1) * d];
            // The first hypothesis of the least aggregated cost.
            let lowest = least(s);
            let best = s.iter().position(|&v| v == lowest).unwrap_or(0);
            if c[best] >= NO_VOTE || best == 0 || best == d - 1 {
                continue;
            }
            // The parabola through the matching costs where both neighbours have votes (the
            // aggregated costs carry SGM's penalties, which pull the vertex toward the
            // hypotheses: 0.33 of a step on a noise-free plane against 0.06), else through
            // the aggregated costs.
            let raw = c[best - 1] < NO_VOTE && c[best + 1] < NO_VOTE;
            let through = if raw { c } else { s };
            let (minus, centre, plus) = (
                f32::from(through[best - 1]),
                f32::from(through[best]),
                f32::from(through[best + 1]),
            );
            let curvature = minus - 2.0 * centre + plus;
            let delta = if curvature > 0.0 {
                ((minus - plus) / (2.0 * curvature)).clamp(-0.5, 0.5)
            } else {
                0.0
            };
            index[j] = best as f32 + delta;
            quality[j] = 1.0 - f32::from(c[best]) / f32::from(COST_SCALE);
            // The least aggregated cost two or more hypotheses from the winner.
            let second = least(&s[..best - 1]).min(least(&s[best + 2..]));
            distinctness[j] = if second > 0 {
                (f32::from(second) - f32::from(s[best])) / f32::from(second)
            } else {
                0.0
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_parabola_finds_the_vertex_between_hypotheses() {
        // C(h) = 10·(h − 3.3)² + 50, sampled: the vertex at 3.3; the aggregated costs choose the
        // winner, the matching costs place the vertex.
        let d = 8;
        let parabola = |at: f64| -> Vec<u16> {
            (0..d)
                .map(|h| (10.0 * (h as f64 - at).powi(2) + 50.0).round() as u16)
                .collect()
        };
        let (sum, cost) = (parabola(3.1), parabola(3.3));
        let w = winner_take_all(&sum, &cost, d);
        assert!((w.index[0] - 3.3).abs() < 0.05, "{}", w.index[0]);
        assert!(w.distinctness[0] > 0.3);
        // A neighbour without a vote: the aggregated costs place the vertex.
        let mut holed = cost.clone();
        holed[2] = NO_VOTE;
        let w = winner_take_all(&sum, &holed, d);
        assert!((w.index[0] - 3.1).abs() < 0.05, "{}", w.index[0]);
        // A winner at the end of the range, or without a vote, is rejected.
        let mut edge = sum.clone();
        edge[0] = 0;
        assert!(winner_take_all(&edge, &cost, d).index[0].is_nan());
        let mut unvoted = cost.clone();
        unvoted[3] = NO_VOTE;
        assert!(winner_take_all(&sum, &unvoted, d).index[0].is_nan());
    }
}
