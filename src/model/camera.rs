//! OpenCV pinhole camera with Brown–Conrady distortion `[k1, k2, p1, p2, k3]`.
//!
//! Camera frame: x right, y down, z forward. Pixel (0, 0) is the centre of the top-left pixel.
//! Lens distortion is independent of refraction: pixels are undistorted before back-projection and
//! distorted after projection.

use std::ops::{Add, Mul};

use nalgebra::{Matrix2, Point2, Point3, Unit, Vector2, Vector3};

use super::error::{ModelError, check_finite};

/// Largest number of Newton steps [`PinholeCamera::undistort_normalized`] takes.
pub const UNDISTORT_MAX_ITERATIONS: usize = 30;

/// Intrinsics of an OpenCV pinhole camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PinholeCamera {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length in x, pixels.
    pub fx: f64,
    /// Focal length in y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// OpenCV distortion `[k1, k2, p1, p2, k3]`.
    pub distortion: [f64; 5],
}

impl PinholeCamera {
    /// Builds and validates intrinsics (`name` only labels errors).
    #[allow(clippy::too_many_arguments)] // OpenCV's own parameter list: size, fx, fy, cx, cy, distortion Focal lengths must be > 0 and
    /// every value finite.
    pub fn new(
        name: &str,
        width: u32,
        height: u32,
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        distortion: [f64; 5],
    ) -> Result<Self, ModelError> {
        for (field, value) in [("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)] {
            check_finite(&format!("camera '{name}' {field}"), value)?;
        }
        for (i, k) in distortion.iter().enumerate() {
            check_finite(&format!("camera '{name}' distortion[{i}]"), *k)?;
        }
        for (field, value) in [("fx", fx), ("fy", fy)] {
            if value <= 0.0 {
                return Err(ModelError::BadIntrinsics {
                    camera: name.to_string(),
                    field,
                    requirement: "> 0",
                    value,
                });
            }
        }
        for (field, value) in [("width", width), ("height", height)] {
            if value == 0 {
                return Err(ModelError::BadIntrinsics {
                    camera: name.to_string(),
                    field,
                    requirement: "> 0",
                    value: 0.0,
                });
            }
        }
        Ok(Self {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            distortion,
        })
    }

    /// True when any distortion coefficient is non-zero.
    #[inline]
    pub fn has_distortion(&self) -> bool {
        self.distortion.iter().any(|&k| k != 0.0)
    }

    /// Applies the OpenCV distortion to normalised coordinates (x, y) = (X/Z, Y/Z):
    ///
    /// R = 1 + k1 r² + k2 r⁴ + k3 r⁶, r² = x² + y²,
    /// x′ = x R + 2 p1 x y + p2 (r² + 2x²), y′ = y R + p1 (r² + 2y²) + 2 p2 x y.
    #[inline]
    pub fn distort_normalized(&self, p: &Vector2<f64>) -> Vector2<f64> {
        self.distort_with_jacobian(p).0
    }

    /// Distortion and its 2×2 Jacobian ∂(x′, y′)/∂(x, y) ([`distort_with_jacobian`]).
    #[inline]
    fn distort_with_jacobian(&self, p: &Vector2<f64>) -> (Vector2<f64>, Matrix2<f64>) {
        let d = distort_with_jacobian(self.distortion, p.x, p.y);
        (
            Vector2::new(d.x, d.y),
            Matrix2::new(d.dxx, d.dxy, d.dxy, d.dyy),
        )
    }

    /// Inverts [`distort_normalized`](Self::distort_normalized) by Newton's method with the analytic
    /// Jacobian, started at the distorted point.
    ///
    /// Returns `None` when the iteration does not reach a residual of 1e-14 (normalised units, about
    /// 1e-11 px) within [`UNDISTORT_MAX_ITERATIONS`] steps, or meets a fold of the distortion map
    /// (Jacobian determinant ≤ 0): the pixel lies outside the region where the lens model is
    /// invertible.
    pub fn undistort_normalized(&self, distorted: &Vector2<f64>) -> Option<Vector2<f64>> {
        if !self.has_distortion() {
            return Some(*distorted);
        }
        self.undistort_from(distorted, *distorted, undistort_tolerance(distorted))
            .map(|(p, _)| p)
    }

    /// [`undistort_normalized`](Self::undistort_normalized) for a caller that only accepts answers
    /// inside the fold, |x|² < `fold_radius2` ([`fold_radius2`](Self::fold_radius2)), in fewer
    /// steps: Newton starts from the inverse radial series to second order,
    /// x ≈ x′·(1 − k1 r′² + (3k1² − k2) r′⁴), r′ = |x′|. Where that run fails, or ends beyond the
    /// fold or where the Jacobian determinant is not positive, it runs again from the distorted
    /// point as `undistort_normalized` does. Same convergence test and `None` cases; an answer
    /// beyond the fold can only come from that second run.
    pub fn undistort_normalized_in_fold(
        &self,
        distorted: &Vector2<f64>,
        fold_radius2: f64,
    ) -> Option<Vector2<f64>> {
        if !self.has_distortion() {
            return Some(*distorted);
        }
        let [k1, k2, ..] = self.distortion;
        let r2 = distorted.norm_squared();
        let tolerance = undistort_tolerance(distorted);
        let start = distorted * (1.0 - r2 * (k1 + r2 * (k2 - 3.0 * k1 * k1)));
        match self.undistort_from(distorted, start, tolerance) {
            Some((p, det)) if det > 0.0 && p.norm_squared() < fold_radius2 => Some(p),
            _ => self
                .undistort_from(distorted, *distorted, tolerance)
                .map(|(p, _)| p),
        }
    }

    /// The Newton iteration of [`undistort_normalized`](Self::undistort_normalized) from `p`: the
    /// point where the residual |distort(p) − distorted| is ≤ `tolerance`, and the Jacobian
    /// determinant there.
    #[inline]
    fn undistort_from(
        &self,
        distorted: &Vector2<f64>,
        mut p: Vector2<f64>,
        tolerance: f64,
    ) -> Option<(Vector2<f64>, f64)> {
        let tolerance2 = tolerance * tolerance;
        for _ in 0..UNDISTORT_MAX_ITERATIONS {
            let (d, jac) = self.distort_with_jacobian(&p);
            let residual = d - distorted;
            let det = jac.determinant();
            if residual.norm_squared() <= tolerance2 {
                return Some((p, det));
            }
            if !(det > 0.0) {
                return None;
            }
            // 2×2 inverse written out: cheaper than a general solve.
            let inv_det = 1.0 / det;
            let step = Vector2::new(
                (jac.m22 * residual.x - jac.m12 * residual.y) * inv_det,
                (jac.m11 * residual.y - jac.m21 * residual.x) * inv_det,
            );
            p -= step;
            if !p.x.is_finite() || !p.y.is_finite() {
                return None;
            }
        }
        let (d, jac) = self.distort_with_jacobian(&p);
        ((d - distorted).norm_squared() <= tolerance2).then_some((p, jac.determinant()))
    }

    /// r²_fold: the squared normalised radius at which the radial distortion r·(1 + k1 r² + k2 r⁴ +
    /// k3 r⁶) stops increasing, i.e. the smallest s > 0 with 1 + 3k1 s + 5k2 s² + 7k3 s³ = 0
    /// (∞ when there is none below s = 100, i.e. 84° off axis). Beyond it the lens model is not
    /// one-to-one: a pixel there has several preimages, so neither direction is trustworthy.
    pub fn fold_radius2(&self) -> f64 {
        let [k1, k2, _, _, k3] = self.distortion;
        let slope = |s: f64| 1.0 + s * (3.0 * k1 + s * (5.0 * k2 + s * 7.0 * k3));
        // March on a fine geometric grid to the first sign change, then bisect.
        let mut lo = 0.0;
        let mut hi = 1e-4;
        while hi <= 100.0 {
            if slope(hi) <= 0.0 {
                for _ in 0..100 {
                    let mid = 0.5 * (lo + hi);
                    if slope(mid) > 0.0 { lo = mid } else { hi = mid }
                }
                return lo;
            }
            lo = hi;
            hi *= 1.05;
        }
        f64::INFINITY
    }

    /// Pixel of a point in the camera frame: pinhole, then distortion. `None` when z ≤ 0.
    #[inline]
    pub fn img_from_cam(&self, point_in_cam: &Point3<f64>) -> Option<Point2<f64>> {
        if !(point_in_cam.z > 0.0) {
            return None;
        }
        let normalized = Vector2::new(
            point_in_cam.x / point_in_cam.z,
            point_in_cam.y / point_in_cam.z,
        );
        Some(self.img_from_normalized(&normalized))
    }

    /// Pixel of normalised (undistorted) coordinates: distortion, then the intrinsic matrix.
    #[inline]
    pub fn img_from_normalized(&self, normalized: &Vector2<f64>) -> Point2<f64> {
        let d = if self.has_distortion() {
            self.distort_normalized(normalized)
        } else {
            *normalized
        };
        Point2::new(self.fx * d.x + self.cx, self.fy * d.y + self.cy)
    }

    /// Undistorted normalised coordinates of a pixel. `None` when undistortion fails.
    #[inline]
    pub fn normalized_from_img(&self, pixel: &Point2<f64>) -> Option<Vector2<f64>> {
        let distorted = Vector2::new((pixel.x - self.cx) / self.fx, (pixel.y - self.cy) / self.fy);
        self.undistort_normalized(&distorted)
    }

    /// Unit viewing direction (camera frame) of a pixel. `None` when undistortion fails.
    #[inline]
    pub fn cam_from_img(&self, pixel: &Point2<f64>) -> Option<Unit<Vector3<f64>>> {
        let n = self.normalized_from_img(pixel)?;
        Some(Unit::new_normalize(Vector3::new(n.x, n.y, 1.0)))
    }
}

/// Distorted normalised coordinates (x′, y′) and the Jacobian ∂(x′, y′)/∂(x, y) =
/// [[dxx, dxy], [dxy, dyy]], of one point (`T = f64`) or of a block of lanes.
#[derive(Debug, Clone, Copy)]
pub struct Distorted<T> {
    /// x′.
    pub x: T,
    /// y′.
    pub y: T,
    /// ∂x′/∂x.
    pub dxx: T,
    /// ∂x′/∂y = ∂y′/∂x.
    pub dxy: T,
    /// ∂y′/∂y.
    pub dyy: T,
}

/// The OpenCV lens model (`coefficients` = [k1, k2, p1, p2, k3]) at normalised (x, y), with its
/// Jacobian: R = 1 + k1 r² + k2 r⁴ + k3 r⁶, x′ = x R + 2 p1 x y + p2 (r² + 2x²),
/// y′ = y R + p1 (r² + 2y²) + 2 p2 x y.
///
/// The one Rust definition of the model: [`PinholeCamera`] calls it with `f64`, the CPU's vector
/// path with its lanes (`engine::cpu::lanes`), so every lane rounds exactly as the scalar code
/// (the same expressions in the same order; Rust never fuses a multiply-add on its own). The
/// kernels' twin is `shaders/lib/lens.wgsl`.
#[inline(always)]
pub fn distort_with_jacobian<T>(coefficients: [f64; 5], x: T, y: T) -> Distorted<T>
where
    T: Copy + Add<Output = T> + Mul<Output = T>,
    f64: Add<T, Output = T> + Mul<T, Output = T>,
{
    let [k1, k2, p1, p2, k3] = coefficients;
    // The coefficients' constant multiples, formed in f64 as the expressions below would form
    // them left to right (2·p1·x·y = ((2·p1)·x)·y): the same roundings.
    let [k2_2, k3_3, p1_2, p2_2, p1_6, p2_6] = scaled_coefficients(coefficients);
    let r2 = x * x + y * y;
    // Estrin's split, (1 + k1 r²) + r⁴(k2 + k3 r²): a shorter chain than Horner's.
    let r4 = r2 * r2;
    let radial = (1.0 + k1 * r2) + r4 * (k2 + k3 * r2);
    // dR/d(r²)
    let radial_d = k1 + r2 * (k2_2 + k3_3 * r2);
    let (two_x, two_y) = (2.0 * x, 2.0 * y);
    Distorted {
        x: x * radial + p1_2 * x * y + p2 * (r2 + two_x * x),
        y: y * radial + p1 * (r2 + two_y * y) + p2_2 * x * y,
        dxx: radial + two_x * x * radial_d + p1_2 * y + p2_6 * x,
        dxy: two_x * y * radial_d + p1_2 * x + p2_2 * y,
        dyy: radial + two_y * y * radial_d + p1_6 * y + p2_2 * x,
    }
}

/// 2 k2, 3 k3, 2 p1, 2 p2, 6 p1, 6 p2 (outside the generic function, whose bounds would make
/// `2.0 * k2` mean `f64 · T`).
#[inline(always)]
fn scaled_coefficients([_, k2, p1, p2, k3]: [f64; 5]) -> [f64; 6] {
    [2.0 * k2, 3.0 * k3, 2.0 * p1, 2.0 * p2, 6.0 * p1, 6.0 * p2]
}

/// Residual at which undistortion stops: 1e-14·(1 + |x′|), normalised units.
#[inline]
fn undistort_tolerance(distorted: &Vector2<f64>) -> f64 {
    1e-14 * (1.0 + distorted.norm())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(distortion: [f64; 5]) -> PinholeCamera {
        PinholeCamera::new("test", 1280, 1024, 864.91, 870.0, 640.0, 512.0, distortion).unwrap()
    }

    #[test]
    fn principal_point_looks_down_the_axis() {
        let c = camera([0.0; 5]);
        let d = c.cam_from_img(&Point2::new(640.0, 512.0)).unwrap();
        assert!((d.into_inner() - Vector3::z()).norm() < 1e-15);
        let px = c.img_from_cam(&Point3::new(0.0, 0.0, 2.0)).unwrap();
        assert_eq!(px, Point2::new(640.0, 512.0));
    }

    #[test]
    fn pinhole_matches_hand_values() {
        let c = camera([0.0; 5]);
        // X/Z = 0.1, Y/Z = -0.05 → u = 864.91·0.1 + 640, v = 870·(−0.05) + 512.
        let px = c.img_from_cam(&Point3::new(0.2, -0.1, 2.0)).unwrap();
        assert!((px.x - 726.491).abs() < 1e-12);
        assert!((px.y - 468.5).abs() < 1e-12);
        assert!(c.img_from_cam(&Point3::new(0.2, -0.1, -2.0)).is_none());
    }

    #[test]
    fn distortion_matches_hand_values() {
        let c = camera([0.1, 0.01, 0.001, 0.002, 0.0005]);
        let (x, y) = (0.3f64, -0.2f64);
        let r2: f64 = 0.13;
        let radial = 1.0 + 0.1 * r2 + 0.01 * r2 * r2 + 0.0005 * r2 * r2 * r2;
        let xd = x * radial + 2.0 * 0.001 * x * y + 0.002 * (r2 + 2.0 * x * x);
        let yd = y * radial + 0.001 * (r2 + 2.0 * y * y) + 2.0 * 0.002 * x * y;
        let d = c.distort_normalized(&Vector2::new(x, y));
        assert!((d.x - xd).abs() < 1e-15 && (d.y - yd).abs() < 1e-15);
    }

    #[test]
    fn undistort_inverts_distort_over_the_image() {
        // Strong barrel distortion, typical of wide-angle underwater housings.
        let c = camera([-0.28, 0.09, 0.0012, -0.0007, -0.012]);
        for i in 0..=16 {
            for j in 0..=16 {
                let px = Point2::new(i as f64 * 1279.0 / 16.0, j as f64 * 1023.0 / 16.0);
                let n = c
                    .normalized_from_img(&px)
                    .expect("inside the image the lens model inverts");
                let back = c.img_from_normalized(&n);
                assert!(
                    (back - px).norm() < 1e-9,
                    "pixel {px:?} came back as {back:?}"
                );
            }
        }
    }

    #[test]
    fn undistort_reports_failure_beyond_the_fold() {
        // k1 < 0 folds the radial map at r² = −1/(3 k1): distorted radii beyond its maximum have no preimage.
        let c = camera([-0.5, 0.0, 0.0, 0.0, 0.0]);
        // Maximum distorted radius is r(1 + k1 r²) at r² = 2/3: ≈ 0.544. Ask for 0.8.
        assert!(c.undistort_normalized(&Vector2::new(0.8, 0.0)).is_none());
        assert!(c.undistort_normalized(&Vector2::new(0.3, 0.0)).is_some());
        assert!(
            c.undistort_normalized_in_fold(&Vector2::new(0.8, 0.0), c.fold_radius2())
                .is_none()
        );
        assert!(
            c.undistort_normalized_in_fold(&Vector2::new(0.3, 0.0), c.fold_radius2())
                .is_some()
        );
    }

    #[test]
    fn undistort_in_fold_agrees_with_the_plain_start() {
        // Barrel, pincushion with a fold, and the pure-k1 fold of the test above, over normalised
        // points out to the fold and beyond it.
        let lenses = [
            [-0.28, 0.09, 0.0012, -0.0007, -0.012],
            [0.3, -0.1, 0.002, 0.001, 0.02],
            [-0.5, 0.0, 0.0, 0.0, 0.0],
        ];
        let mut worst: f64 = 0.0;
        for distortion in lenses {
            let c = camera(distortion);
            let fold = c.fold_radius2();
            for i in 0..=40 {
                for j in 0..=40 {
                    let d =
                        Vector2::new((i as f64 / 40.0 - 0.5) * 2.4, (j as f64 / 40.0 - 0.5) * 2.0);
                    let inside = |p: &Vector2<f64>| p.norm_squared() < fold;
                    let plain = c.undistort_normalized(&d).filter(inside);
                    let fast = c.undistort_normalized_in_fold(&d, fold).filter(inside);
                    match (plain, fast) {
                        (Some(a), Some(b)) => worst = worst.max((a - b).norm()),
                        (Some(a), None) => panic!("{distortion:?} {d:?}: lost the answer {a:?}"),
                        // The series start may reach an in-fold preimage the plain start misses.
                        (None, _) => {}
                    }
                }
            }
        }
        // Both stop at a residual of 1e-14(1 + |x′|), which the inverse Jacobian amplifies where
        // the map flattens toward the fold.
        assert!(worst < 1e-12, "{worst:e}");
    }

    #[test]
    fn fold_radius_is_where_the_radial_map_turns() {
        // k1 < 0 only: 1 + 3 k1 s = 0 at s = −1/(3 k1).
        let c = camera([-0.5, 0.0, 0.0, 0.0, 0.0]);
        assert!((c.fold_radius2() - 2.0 / 3.0).abs() < 1e-12);
        assert_eq!(
            camera([0.1, 0.01, 0.0, 0.0, 0.0]).fold_radius2(),
            f64::INFINITY
        );
        assert_eq!(camera([0.0; 5]).fold_radius2(), f64::INFINITY);
        // The radial map really is one-to-one up to the fold and turns back after it.
        let c = camera([-0.28, 0.09, 0.0, 0.0, -0.012]);
        let s = c.fold_radius2();
        let radial = |r: f64| c.distort_normalized(&Vector2::new(r, 0.0)).x;
        let r = s.sqrt();
        assert!(radial(r * 0.999) < radial(r) && radial(r * 1.001) < radial(r));
    }

    #[test]
    fn bad_intrinsics_are_rejected() {
        assert!(PinholeCamera::new("c", 10, 10, 0.0, 1.0, 0.0, 0.0, [0.0; 5]).is_err());
        assert!(PinholeCamera::new("c", 0, 10, 1.0, 1.0, 0.0, 0.0, [0.0; 5]).is_err());
        assert!(PinholeCamera::new("c", 10, 10, 1.0, 1.0, f64::NAN, 0.0, [0.0; 5]).is_err());
    }
}
