//! Lane twin of [`triangulate_rays`](crate::model::triangulate_rays): midpoint triangulation of
//! [`LANES`](super::f64s::LANES) pairs of rays at once.

use super::f64s::{F64s, Mask, Vec3s};
use super::refractive_camera::{Rays, Status};
use crate::model::NoSolution;
use crate::model::stereo::MIN_RAY_ANGLE_SIN2;

/// Points and residuals for a block of ray pairs.
#[derive(Debug, Clone, Copy)]
pub struct Triangulated {
    /// Midpoints of closest approach, master frame.
    pub point: Vec3s,
    /// Distances between the rays there, metres.
    pub residual: F64s,
    /// The reason per lane (0: an answer): `a`'s first, then `b`'s, then the triangulation's.
    pub status: Status,
}

/// [`triangulate_rays`](crate::model::triangulate_rays) for lanes of rays `a` and `b`, the same
/// expressions in the same order: s = (cos·e − d)/sin², t = (e − cos·d)/sin², sin² = |a × b|².
/// `in_range`: lanes whose four input numbers are within ±[`MAX_INPUT`](crate::model::MAX_INPUT)
/// (a row beyond is [`NoSolution::OutOfRange`] before anything else).
#[inline(always)]
pub fn triangulate(a: &Rays, b: &Rays, in_range: Mask) -> Triangulated {
    let mut status = Status::ok();
    status.fail(!in_range, NoSolution::OutOfRange);
    for (s, &reason) in status.0.iter_mut().zip(&a.status.0) {
        if *s == 0 {
            *s = reason;
        }
    }
    for (s, &reason) in status.0.iter_mut().zip(&b.status.0) {
        if *s == 0 {
            *s = reason;
        }
    }
    let (da, db) = (a.dir, b.dir);
    let w0 = a.origin - b.origin;
    let cos = da.dot(db);
    let sin2 = da.cross(db).norm_squared();
    status.fail(
        !sin2.ge(F64s::splat(MIN_RAY_ANGLE_SIN2)),
        NoSolution::Degenerate,
    );
    let (d, e) = (da.dot(w0), db.dot(w0));
    let s = (cos * e - d) / sin2;
    let t = (e - cos * d) / sin2;
    let zero = F64s::splat(0.0);
    status.fail(s.lt(zero) | t.lt(zero), NoSolution::NotInWater);
    let pa = a.origin + da.scale(s);
    let pb = b.origin + db.scale(t);
    let half = F64s::splat(0.5);
    let point = (pa + pb).scale(half);
    let residual = (pa - pb).norm_squared().sqrt();
    status.fail(
        !(point.is_finite() & residual.is_finite()),
        NoSolution::OutOfRange,
    );
    Triangulated {
        point,
        residual,
        status,
    }
}
