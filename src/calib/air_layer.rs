//! The air layer from the axis by linear least squares (DESIGN.md §2, "Air layer from the axis").
//!
//! Both water rays of a correspondence must meet. With n fixed, each water ray is o_k(d) + λ·w_k:
//! its direction w_k does not depend on d and its origin on the outer interface moves linearly
//! with d (thesis 5.2.2). So with m = (w_l × w_r)/|w_l × w_r|, the signed distance between the two
//! lines, g(d) = m·(o_l(d) − o_r(d)) = a·d + b, is exactly linear in d, and
//! d = −Σ aⱼbⱼ / Σ aⱼ² minimises the summed squared ray gaps.

use nalgebra::{Unit, Vector3};

use super::data::{Candidate, StereoData};
use crate::model::RefractiveCamera;

/// The least-squares air layer for the axis `normal`, with the RMS ray gap there (metres).
///
/// `None` when a ray has no answer under this axis (it misses the interface or is totally
/// reflected), when the two rays of a corner are parallel, or when the gaps do not depend on d
/// (Σ a² ≈ 0: both cameras see every corner at the same incidence).
pub fn air_distance_for_axis(data: &StereoData, normal: &Unit<Vector3<f64>>) -> Option<(f64, f64)> {
    // Any two air layers that keep the cameras in the air: the rays are exactly linear in d.
    let d0 = data.min_air_distance(normal) + 0.01;
    let d1 = d0 + 1.0;
    let near = data.cameras_behind(&Candidate { normal: *normal, air_distance: d0 })?;
    let far = data.cameras_behind(&Candidate { normal: *normal, air_distance: d1 })?;
    let (mut aa, mut ab, mut bb) = (0.0, 0.0, 0.0);
    for corner in &data.corners {
        let (a, b) = gap_line(&near, &far, corner, d0)?;
        aa += a * a;
        ab += a * b;
        bb += b * b;
    }
    if !(aa > 1e-18 * data.corners.len() as f64) {
        return None;
    }
    let d = -ab / aa;
    let sum_squares = (bb - ab * ab / aa).max(0.0);
    Some((d, (sum_squares / data.corners.len() as f64).sqrt()))
}

/// (a, b) of the corner's signed ray gap g(d) = a·d + b.
fn gap_line(near: &[RefractiveCamera; 2], far: &[RefractiveCamera; 2], corner: &super::data::Corner, d0: f64) -> Option<(f64, f64)> {
    let ray = |cams: &[RefractiveCamera; 2], k: usize| cams[k].ray_in_water(&corner.dirs[k]).ok();
    let (l0, r0, l1, r1) = (ray(near, 0)?, ray(near, 1)?, ray(far, 0)?, ray(far, 1)?);
    let cross = l0.dir.cross(&r0.dir);
    let norm = cross.norm();
    if !(norm > 1e-9) {
        return None;
    }
    let m = cross / norm;
    let g0 = m.dot(&(l0.origin - r0.origin));
    let g1 = m.dot(&(l1.origin - r1.origin));
    let a = g1 - g0; // per metre of d (d1 − d0 = 1)
    Some((a, g0 - a * d0))
}
