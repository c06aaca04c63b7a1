//! Lane twin of [`crate::model::camera`]: OpenCV distortion, its Jacobian, and the undistortion
//! Newton iteration, for [`LANES`](super::f64s::LANES) normalised points at once.

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

/// Distorted coordinates and the Jacobian ∂(x′, y′)/∂(x, y) = [[dxx, dxy], [dxy, dyy]].
#[derive(Debug, Clone, Copy)]
pub struct Distorted {
    /// x′.
    pub x: F64s,
    /// y′.
    pub y: F64s,
    /// ∂x′/∂x.
    pub dxx: F64s,
    /// ∂x′/∂y = ∂y′/∂x.
    pub dxy: F64s,
    /// ∂y′/∂y.
    pub dyy: F64s,
}

impl Distortion {
    /// The coefficients of `intrinsics`.
    pub fn new(intrinsics: &PinholeCamera) -> Self {
        let [k1, k2, p1, p2, k3] = intrinsics.distortion;
        Self { k1, k2, p1, p2, k3 }
    }

    /// [`PinholeCamera::distort_normalized`] and its Jacobian, the same expressions in the same
    /// order (R = (1 + k1 r²) + r⁴(k2 + k3 r²), dR/d(r²) = k1 + r²(2k2 + 3k3 r²)).
    #[inline(always)]
    pub fn distort_with_jacobian(&self, x: F64s, y: F64s) -> Distorted {
        let Self { k1, k2, p1, p2, k3 } = *self;
        let r2 = x * x + y * y;
        let r4 = r2 * r2;
        let radial = (1.0 + k1 * r2) + r4 * (k2 + k3 * r2);
        let radial_d = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
        let two_x = 2.0 * x;
        let two_y = 2.0 * y;
        Distorted {
            x: x * radial + 2.0 * p1 * x * y + p2 * (r2 + two_x * x),
            y: y * radial + p1 * (r2 + two_y * y) + 2.0 * p2 * x * y,
            dxx: radial + two_x * x * radial_d + 2.0 * p1 * y + 6.0 * p2 * x,
            dxy: two_x * y * radial_d + 2.0 * p1 * x + 2.0 * p2 * y,
            dyy: radial + two_y * y * radial_d + 6.0 * p1 * y + 2.0 * p2 * x,
        }
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
