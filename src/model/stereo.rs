//! Two cameras: binocular Virtual Object Points (thesis 5.3) and refractive triangulation.

use nalgebra::{Matrix3, Point3, Unit, Vector3};

use super::NoSolution;
use super::refractive_camera::Ray;

/// Smallest |det [v, n, −v′]| (all columns unit) accepted by [`binocular_vop`]. Below it the point
/// lies (within ~1e-9 rad) in the plane through the baseline parallel to the axis.
pub const MIN_BINOCULAR_CONDITIONING: f64 = 1e-9;

/// Smallest sin² of the angle between two water rays accepted by [`triangulate_rays`] (1e-6 rad).
pub const MIN_RAY_ANGLE_SIN2: f64 = 1e-12;

/// The two VOPs of one point seen by two cameras, from the system axis alone.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BinocularVop {
    /// Ǒ = C_l + s·v, on the left air ray.
    pub vop_left: Point3<f64>,
    /// Ǒ′ = C_r + s′·v′ = Ǒ + m·n, on the right air ray.
    pub vop_right: Point3<f64>,
    /// Parameter s along the left air ray.
    pub s_left: f64,
    /// Parameter s′ along the right air ray.
    pub s_right: f64,
    /// m: offset Ǒ → Ǒ′ along the axis.
    pub axis_offset: f64,
    /// |det [v, n, −v′]| ∈ [0, 1]: 0 when the point lies in the plane through the baseline parallel
    /// to the axis, where the VOPs are undetermined. Use it to weight or reject.
    pub conditioning: f64,
}

/// Binocular VOPs (thesis 5.3): solves [v, n, −v′]·(s, m, s′)ᵀ = C_r − C_l for two corresponding
/// air rays v (from `centre_left`) and v′ (from `centre_right`) and the system axis n, master frame.
///
/// Needs the axis only: no air layer, thicknesses or indices. Returns
/// [`NoSolution::Degenerate`] when the conditioning |det| < [`MIN_BINOCULAR_CONDITIONING`].
pub fn binocular_vop(
    centre_left: &Point3<f64>,
    dir_left: &Unit<Vector3<f64>>,
    centre_right: &Point3<f64>,
    dir_right: &Unit<Vector3<f64>>,
    normal: &Unit<Vector3<f64>>,
) -> Result<BinocularVop, NoSolution> {
    let m = Matrix3::from_columns(&[
        dir_left.into_inner(),
        normal.into_inner(),
        -dir_right.into_inner(),
    ]);
    let det = m.determinant();
    if !(det.abs() >= MIN_BINOCULAR_CONDITIONING) {
        return Err(NoSolution::Degenerate);
    }
    let b = centre_right - centre_left;
    // Cramer's rule: each unknown is det with its column replaced by b, over det.
    let solve = |col: usize| {
        let mut mc = m;
        mc.set_column(col, &b);
        mc.determinant() / det
    };
    let (s_left, axis_offset, s_right) = (solve(0), solve(1), solve(2));
    Ok(BinocularVop {
        vop_left: centre_left + dir_left.into_inner() * s_left,
        vop_right: centre_right + dir_right.into_inner() * s_right,
        s_left,
        s_right,
        axis_offset,
        conditioning: det.abs(),
    })
}

/// A triangulated point and how well the two rays met.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Triangulation {
    /// Midpoint of the closest approach of the two rays, master frame.
    pub point: Point3<f64>,
    /// Distance between the rays at their closest approach, metres.
    pub residual: f64,
}

/// Midpoint triangulation of two rays (in the water, origins on the outer interface).
///
/// Errors: [`NoSolution::Degenerate`] for nearly parallel rays (sin² of their angle below
/// [`MIN_RAY_ANGLE_SIN2`]); [`NoSolution::NotInWater`] when the closest approach lies behind either
/// origin, i.e. not in the water.
pub fn triangulate_rays(a: &Ray, b: &Ray) -> Result<Triangulation, NoSolution> {
    let (da, db) = (a.dir.into_inner(), b.dir.into_inner());
    let w0 = a.origin - b.origin;
    let cos = da.dot(&db);
    // |da × db|² rather than 1 − cos²: exact to rounding for nearly parallel rays, where 1 − cos²
    // cancels (the f32 kernel lost 1e-3 relative there).
    let sin2 = da.cross(&db).norm_squared();
    if !(sin2 >= MIN_RAY_ANGLE_SIN2) {
        return Err(NoSolution::Degenerate);
    }
    let (d, e) = (da.dot(&w0), db.dot(&w0));
    let s = (cos * e - d) / sin2;
    let t = (e - cos * d) / sin2;
    if s < 0.0 || t < 0.0 {
        return Err(NoSolution::NotInWater);
    }
    let (pa, pb) = (a.point_at(s), b.point_at(t));
    Ok(Triangulation {
        point: nalgebra::center(&pa, &pb),
        residual: (pa - pb).norm(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(x: f64, y: f64, z: f64) -> Unit<Vector3<f64>> {
        Unit::new_normalize(Vector3::new(x, y, z))
    }

    #[test]
    fn crossing_rays_meet_at_their_intersection() {
        let target = Point3::new(0.1, -0.2, 1.5);
        let a = Ray {
            origin: Point3::new(0.0, 0.0, 0.03),
            dir: Unit::new_normalize(target - Point3::new(0.0, 0.0, 0.03)),
        };
        let b = Ray {
            origin: Point3::new(0.1, 0.0, 0.03),
            dir: Unit::new_normalize(target - Point3::new(0.1, 0.0, 0.03)),
        };
        let t = triangulate_rays(&a, &b).unwrap();
        // Rounding is amplified by 1/sin²(angle between rays) ≈ 230 here: ε·1.5·230 ≈ 8e-14.
        assert!(
            (t.point - target).norm() < 2e-13,
            "{}",
            (t.point - target).norm()
        );
        assert!(t.residual < 2e-13);
    }

    #[test]
    fn skew_rays_give_midpoint_and_distance() {
        // x axis at z = 0 and y axis shifted to z = 0.2: closest points (0,0,0) and (0,0,0.2).
        let a = Ray {
            origin: Point3::new(-1.0, 0.0, 0.0),
            dir: unit(1.0, 0.0, 0.0),
        };
        let b = Ray {
            origin: Point3::new(0.0, -1.0, 0.2),
            dir: unit(0.0, 1.0, 0.0),
        };
        let t = triangulate_rays(&a, &b).unwrap();
        assert!((t.point - Point3::new(0.0, 0.0, 0.1)).norm() < 1e-15);
        assert!((t.residual - 0.2).abs() < 1e-15);
    }

    #[test]
    fn parallel_and_diverging_rays_are_refused() {
        let a = Ray {
            origin: Point3::new(0.0, 0.0, 0.0),
            dir: unit(0.0, 0.0, 1.0),
        };
        let b = Ray {
            origin: Point3::new(0.1, 0.0, 0.0),
            dir: unit(0.0, 0.0, 1.0),
        };
        assert_eq!(triangulate_rays(&a, &b), Err(NoSolution::Degenerate));
        let c = Ray {
            origin: Point3::new(0.1, 0.0, 0.0),
            dir: unit(0.1, 0.0, 1.0),
        };
        assert_eq!(triangulate_rays(&a, &c), Err(NoSolution::NotInWater));
    }

    #[test]
    fn binocular_vops_lie_on_both_rays_and_one_axis_line() {
        let n = unit(0.05, -0.03, 1.0);
        let (cl, cr) = (Point3::origin(), Point3::new(0.06, 0.01, 0.0));
        let (vl, vr) = (unit(0.2, 0.1, 1.0), unit(0.1, 0.12, 1.0));
        let b = binocular_vop(&cl, &vl, &cr, &vr, &n).unwrap();
        let offset = b.vop_right - b.vop_left;
        assert!((offset - n.into_inner() * b.axis_offset).norm() < 1e-14);
        assert!(b.conditioning > 0.0 && b.conditioning <= 1.0);
    }

    #[test]
    fn point_in_the_baseline_plane_is_degenerate() {
        // Baseline along x, axis along z: rays in the x-z plane make [v, n, −v′] singular.
        let n = unit(0.0, 0.0, 1.0);
        let (cl, cr) = (Point3::origin(), Point3::new(0.06, 0.0, 0.0));
        let r = binocular_vop(&cl, &unit(0.1, 0.0, 1.0), &cr, &unit(0.05, 0.0, 1.0), &n);
        assert_eq!(r, Err(NoSolution::Degenerate));
    }
}
