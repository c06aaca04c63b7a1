//! The lanes' side of [`crate::model::camera`]: the OpenCV distortion and its Jacobian (the
//! model's own generic function) and the undistortion Newton iteration, for
//! [`LANES`](super::f64s::LANES) normalised points at once.

use super::f64s::{F64s, Mask};
use crate::model::PinholeCamera;
use crate::model::camera::UNDISTORT_MAX_ITERATIONS;

/// The distortion coefficients with the constant products the scalar expressions form, so that
/// each lane rounds exactly as [`PinholeCamera::distort_normalized`] does.
#[derive(Debug, Clone, Copy)]
pub struct Distortion {
    k1: f64,
    k2: f64,
    p1: f64,
    p2: f64,
    k3: f64,
}

/// Distorted coordinates and their Jacobian, a block of lanes.
pub type Distorted = crate::model::camera::Distorted<F64s>;

impl Distortion {
    /// The coefficients of `intrinsics`.
    pub fn new(intrinsics: &PinholeCamera) -> Self {
        let [k1, k2, p1, p2, k3] = intrinsics.distortion;
        Self { k1, k2, p1, p2, k3 }
    }

    /// [`PinholeCamera::distort_normalized`] and its Jacobian: the model's own
    /// [`distort_with_jacobian`](crate::model::camera::distort_with_jacobian) over lanes.
    #[inline(always)]
    pub fn distort_with_jacobian(&self, x: F64s, y: F64s) -> Distorted {
        let Self { k1, k2, p1, p2, k3 } = *self;
        crate::model::camera::distort_with_jacobian([k1, k2, p1, p2, k3], x, y)
    }

    /// [`PinholeCamera::undistort_normalized_in_fold`]'s first run for every lane: Newton from the
    /// inverse radial series, x ≈ x′(1 − r′²(k1 + r′²(k2 − 3k1²))), until |distort(p) − x′|² ≤
    /// tol², tol = 1e-14(1 + |x′|), at most [`UNDISTORT_MAX_ITERATIONS`] steps, all lanes until
    /// the slowest is done.
    ///
    /// Returns (x, y, ok, steps): `ok` where that run ended with a positive Jacobian determinant
    /// inside the fold, which is where the scalar function returns the same point (a lane without
    /// `ok` needs the scalar function: its second run, or its `None`); `steps` the Newton steps
    /// the block took (one ÷ each).
    #[inline(always)]
    pub fn undistort_in_fold(
        &self,
        xd: F64s,
        yd: F64s,
        fold_radius2: f64,
    ) -> (F64s, F64s, Mask, u32) {
        let (k1, k2) = (self.k1, self.k2);
        let r2 = xd * xd + yd * yd;
        let tolerance = 1e-14 * (1.0 + r2.sqrt());
        let tolerance2 = tolerance * tolerance;
        let shrink = 1.0 - r2 * (k1 + r2 * (k2 - 3.0 * k1 * k1));
        let (mut x, mut y) = (xd * shrink, yd * shrink);
        let mut active = Mask::splat(true);
        let mut ok = Mask::splat(false);
        let mut steps = 0;
        for _ in 0..UNDISTORT_MAX_ITERATIONS {
            let d = self.distort_with_jacobian(x, y);
            let (rx, ry) = (d.x - xd, d.y - yd);
            let det = d.dxx * d.dyy - d.dxy * d.dxy;
            let converged = (rx * rx + ry * ry).le(tolerance2);
            // Done: converged (accepted when the determinant is positive), or a fold.
            ok = ok | (active & converged & det.gt(F64s::splat(0.0)));
            active = active.and_not(converged) & det.gt(F64s::splat(0.0));
            if !active.any() {
                break;
            }
            steps += 1;
            let inv_det = 1.0 / det;
            let step_x = (d.dyy * rx - d.dxy * ry) * inv_det;
            let step_y = (d.dxx * ry - d.dxy * rx) * inv_det;
            x = active.select(x - step_x, x);
            y = active.select(y - step_y, y);
            active = active & x.is_finite() & y.is_finite();
        }
        if active.any() {
            // The bound was reached: the scalar code tests the residual once more.
            let d = self.distort_with_jacobian(x, y);
            let (rx, ry) = (d.x - xd, d.y - yd);
            let det = d.dxx * d.dyy - d.dxy * d.dxy;
            ok = ok | (active & (rx * rx + ry * ry).le(tolerance2) & det.gt(F64s::splat(0.0)));
        }
        ok = ok & (x * x + y * y).lt(F64s::splat(fold_radius2));
        (x, y, ok, steps)
    }
}
