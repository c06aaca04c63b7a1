//! Stage 9, `consistency`: a reference pixel's point must be seen at the same place by another
//! camera's own depth map.
//!
//! For reference pixel p with point X: q = π_c(X) (exact forward projection into camera c);
//! X′ = camera c's point at q (its own depth map, computed with c as the reference: bilinear
//! between the four pixels around q when all four have points on one surface, within 1 % of each
//! other's distance from c, else the nearest pixel's); p′ = π_ref(X′). The pixel is
//! [`Check::Confirmed`] when ‖p′ − p‖ ≤ τ (≈ 1 px) for at least one camera c,
//! [`Check::Contradicted`] when some camera had a point there but none agreed (an occlusion, or a
//! mismatch in either map), [`Check::Unchecked`] when no camera had (outside every other image,
//! or no depth there).

use rayon::prelude::*;

use super::rays::TASK_PIXELS;
use crate::engine::cpu::lanes;
use crate::model::RefractiveCamera;

/// What the other cameras say about a reference pixel's point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Check {
    /// No camera had a point where it projects (or the pixel has no point).
    Unchecked,
    /// Some camera had a point there, none within the tolerance.
    Contradicted,
    /// A camera's point there reprojects within the tolerance.
    Confirmed,
}

/// Another camera's depth map, as points.
pub struct CheckView<'a> {
    /// The camera.
    pub camera: &'a RefractiveCamera,
    /// Its image width.
    pub width: usize,
    /// Its image height.
    pub height: usize,
    /// Its point per pixel (master frame), NaN where it has none.
    pub points: &'a [[f64; 3]],
}

impl CheckView<'_> {
    /// X′ at pixel position (u, v) (see the module docs), `None` where the map has no point.
    fn point_at(&self, u: f64, v: f64) -> Option<[f64; 3]> {
        let (w, h) = (self.width, self.height);
        if !(u >= 0.0 && v >= 0.0 && u <= (w - 1) as f64 && v <= (h - 1) as f64) {
            return None;
        }
        let nearest = self.points[v.round() as usize * w + u.round() as usize];
        let (x0, y0) = (
            (u.floor() as usize).min(w.saturating_sub(2)),
            (v.floor() as usize).min(h.saturating_sub(2)),
        );
        let (fx, fy) = (u - x0 as f64, v - y0 as f64);
        let corners = [
            self.points[y0 * w + x0],
            self.points[y0 * w + x0 + 1],
            self.points[(y0 + 1) * w + x0],
            self.points[(y0 + 1) * w + x0 + 1],
        ];
        let centre = self.camera.centre();
        let distance = |p: &[f64; 3]| {
            ((p[0] - centre.x).powi(2) + (p[1] - centre.y).powi(2) + (p[2] - centre.z).powi(2))
                .sqrt()
        };
        let distances = corners.map(|p| distance(&p));
        let (near, far) = distances
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &d| {
                (a.min(d), b.max(d))
            });
        if near.is_finite() && far.is_finite() && far - near <= 0.01 * near {
            let weights = [
                (1.0 - fx) * (1.0 - fy),
                fx * (1.0 - fy),
                (1.0 - fx) * fy,
                fx * fy,
            ];
            let mut x = [0.0; 3];
            for (c, wgt) in corners.iter().zip(weights) {
                for k in 0..3 {
                    x[k] += wgt * c[k];
                }
            }
            return Some(x);
        }
        nearest[0].is_finite().then_some(nearest)
    }
}

/// `consistency`: what `checks` say about each reference pixel's point (`points`, NaN where
/// none; pixel (i mod w, i div w)) with the tolerance `tolerance_px`.
pub fn consistency(
    reference: &RefractiveCamera,
    width: usize,
    points: &[[f64; 3]],
    checks: &[CheckView],
    tolerance_px: f64,
) -> Vec<Check> {
    let mut confirmed = vec![Check::Unchecked; points.len()];
    let reference_centre: [f64; 3] = reference.centre().coords.into();
    confirmed
        .par_chunks_mut(TASK_PIXELS)
        .zip(points.par_chunks(TASK_PIXELS))
        .enumerate()
        .for_each(|(task, (confirmed, points))| {
            let n = points.len();
            let mut there = vec![[0.0; 2]; n];
            let mut back = vec![[0.0; 3]; n];
            let mut again = vec![[0.0; 2]; n];
            let mut status = vec![0u32; n];
            let mut status_back = vec![0u32; n];
            let has_point: Vec<bool> = points.iter().map(|p| p[0].is_finite()).collect();
            for check in checks {
                let placeholder: [f64; 3] = check.camera.centre().coords.into();
                let queried: Vec<[f64; 3]> = points
                    .iter()
                    .zip(&has_point)
                    .map(|(p, &ok)| if ok { *p } else { placeholder })
                    .collect();
                lanes::project(check.camera, &queried, &mut there, &mut status);
                let mut found = vec![false; n];
                for j in 0..n {
                    back[j] = reference_centre;
                    if !has_point[j] || confirmed[j] == Check::Confirmed || status[j] != 0 {
                        continue;
                    }
                    if let Some(x) = check.point_at(there[j][0], there[j][1]) {
                        back[j] = x;
                        found[j] = true;
                    }
                }
                lanes::project(reference, &back, &mut again, &mut status_back);
                for j in 0..n {
                    if found[j] && status_back[j] == 0 {
                        let i = task * TASK_PIXELS + j;
                        let (du, dv) = (
                            again[j][0] - (i % width) as f64,
                            again[j][1] - (i / width) as f64,
                        );
                        confirmed[j] = if du * du + dv * dv <= tolerance_px * tolerance_px {
                            Check::Confirmed
                        } else {
                            Check::Contradicted
                        };
                    }
                }
            }
        });
    confirmed
}
