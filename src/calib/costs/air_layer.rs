//! The air layer from the axis by linear least squares (DESIGN.md §2, "Air layer from the axis").
//!
//! Both water rays of a correspondence must meet. With n fixed, each water ray is o_k(d) + λ·w_k:
//! its direction w_k does not depend on d and its origin on the outer interface moves linearly
//! with d (thesis 5.2.2). So with m = (w_l × w_r)/|w_l × w_r|, the signed distance between the two
//! lines, g(d) = m·(o_l(d) − o_r(d)) = a·d + b, is exactly linear in d, and
//! d = −Σ aⱼbⱼ / Σ aⱼ² minimises the summed squared ray gaps. These are the pieces;
//! [`air_distance_for_axis`](super::scene::air_distance_for_axis) solves it for the corners of a
//! data set, from their water rays prepared once ([`AxisRays`](super::scene::AxisRays)).

use nalgebra::{Unit, Vector3};

use crate::calib::problem::data::{Candidate, StereoData};
use crate::model::RefractiveCamera;

/// The cameras behind `normal` at two air layers d0 and d0 + 1 m that keep them in the air (any
/// two do: the rays are exactly linear in d), as (d0, near, far). `None` when `normal` is not an
/// interface axis (zero or pointing backward).
pub fn sample_cameras(
    data: &StereoData,
    normal: &Unit<Vector3<f64>>,
) -> Option<(f64, [RefractiveCamera; 2], [RefractiveCamera; 2])> {
    let d0 = data.min_air_distance(normal) + 0.01;
    let d1 = d0 + 1.0;
    let near = data.cameras_behind(&Candidate {
        normal: *normal,
        air_distance: d0,
    })?;
    let far = data.cameras_behind(&Candidate {
        normal: *normal,
        air_distance: d1,
    })?;
    Some((d0, near, far))
}

/// Smallest |w_l × w_r| (sine of the angle between the two water rays) of a usable gap line.
pub const MIN_GAP_LINE_SIN: f64 = 1e-9;

/// The signed ray gap of one corner as a line in the air layer, g(d) = a·d + b, and the sine of
/// the angle between the two water rays that fixes its sign convention m = (w_l × w_r)/|w_l × w_r|.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GapLine {
    /// Slope a, metres of gap per metre of air layer.
    pub a: f64,
    /// Intercept b = g(0), metres.
    pub b: f64,
    /// |w_l × w_r|: the line is usable where it is at least [`MIN_GAP_LINE_SIN`].
    pub sin_angle: f64,
}

/// d = −Σ aⱼbⱼ / Σ aⱼ² over the gap lines of every corner, with the RMS gap there (metres).
/// `None` when a corner has no line or an unusable one, or when Σ a² ≈ 0.
pub fn least_squares_air_distance(lines: &[Option<GapLine>]) -> Option<(f64, f64)> {
    let (mut aa, mut ab, mut bb) = (0.0, 0.0, 0.0);
    for line in lines {
        let GapLine { a, b, sin_angle } = (*line)?;
        if !(sin_angle > MIN_GAP_LINE_SIN) {
            return None;
        }
        aa += a * a;
        ab += a * b;
        bb += b * b;
    }
    air_distance_from_sums(aa, ab, bb, lines.len())
}

/// [`least_squares_air_distance`] from the sums Σa², Σab, Σb² over `lines` usable gap lines.
pub fn air_distance_from_sums(aa: f64, ab: f64, bb: f64, lines: usize) -> Option<(f64, f64)> {
    if !(aa > 1e-18 * lines as f64) {
        return None;
    }
    let d = -ab / aa;
    let sum_squares = (bb - ab * ab / aa).max(0.0);
    Some((d, (sum_squares / lines as f64).sqrt()))
}
