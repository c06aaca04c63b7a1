//! Snell's law in vector form.

use nalgebra::{Unit, Vector2, Vector3};

/// Refracts the unit direction `dir` at a surface with unit normal `normal`, going from a medium of
/// index μ1 into one of index μ2, with `ratio` r = μ1/μ2.
///
/// With c = n·d and s² = r²(1 − c²), the refracted direction is
/// t = r·d + (√(1 − s²) − r·c)·n, a unit vector on the same side of the surface as n.
///
/// Returns `None` on total internal reflection (s² > 1) and when `dir` does not travel through the
/// surface along `normal` (c ≤ 0).
#[inline]
pub fn refract(
    dir: &Unit<Vector3<f64>>,
    normal: &Unit<Vector3<f64>>,
    ratio: f64,
) -> Option<Unit<Vector3<f64>>> {
    let c = normal.dot(dir);
    if c <= 0.0 {
        return None;
    }
    let s2 = ratio * ratio * (1.0 - c * c);
    if s2 > 1.0 {
        return None;
    }
    let t = dir.into_inner() * ratio + normal.into_inner() * ((1.0 - s2).sqrt() - ratio * c);
    // |t| = 1 analytically; renormalising only removes rounding.
    Some(Unit::new_normalize(t))
}

/// The direction in the water of a ray that leaves the camera at undistorted normalised
/// coordinates `x` (through (x, y, 1)) and crosses a flat port with unit axis `normal` (camera
/// frame, pointing into the water), as normalised coordinates again: Snell's law with
/// sin θ_water = `ratio` · sin θ_air (`ratio` = n_air / n_water; the layers between change no
/// direction), the azimuth about the axis kept. `None` for a ray that does not reach the port or
/// that leaves it backwards.
///
/// The pinhole pose of these directions places a board where the port's rays go (up to their
/// offset of a few millimetres); that of the pixels themselves places the *apparent* board,
/// nearer by about n_water / n_air and off by more the farther a corner is from the axis.
pub fn bent_into_water(
    x: &Vector2<f64>,
    normal: &Vector3<f64>,
    ratio: f64,
) -> Option<Vector2<f64>> {
    let d = Vector3::new(x.x, x.y, 1.0).normalize();
    let cos_air = d.dot(normal);
    if !(cos_air > 0.0) {
        return None;
    }
    let across = d - normal * cos_air;
    let sin_air = across.norm();
    let sin_water = ratio * sin_air;
    if !(sin_water < 1.0) {
        return None;
    }
    let water = if sin_air > 0.0 {
        normal * (1.0 - sin_water * sin_water).sqrt() + across * (sin_water / sin_air)
    } else {
        d
    };
    (water.z > 0.0).then(|| Vector2::new(water.x / water.z, water.y / water.z))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(x: f64, y: f64, z: f64) -> Unit<Vector3<f64>> {
        Unit::new_normalize(Vector3::new(x, y, z))
    }

    #[test]
    fn normal_incidence_does_not_bend() {
        let n = unit(0.0, 0.0, 1.0);
        let t = refract(&n, &n, 1.0 / 1.333).unwrap();
        assert!((t.into_inner() - n.into_inner()).norm() < 1e-15);
    }

    #[test]
    fn equal_indices_do_not_bend() {
        let n = unit(0.1, -0.2, 1.0);
        let d = unit(0.4, 0.3, 1.0);
        let t = refract(&d, &n, 1.0).unwrap();
        assert!((t.into_inner() - d.into_inner()).norm() < 1e-15);
    }

    #[test]
    fn snell_law_holds_and_stays_in_plane() {
        let n = unit(0.0, 0.0, 1.0);
        let a: f64 = 0.7;
        let d = unit(a.sin(), 0.0, a.cos());
        let (m1, m2) = (1.0, 1.473);
        let t = refract(&d, &n, m1 / m2).unwrap();
        // sin of the refracted angle is the x component (the plane of refraction is x-z).
        assert!((m1 * a.sin() - m2 * t.x).abs() < 1e-15);
        assert!(t.y.abs() < 1e-15);
        assert!(t.z > 0.0);
    }

    #[test]
    fn total_internal_reflection_is_none() {
        let n = unit(0.0, 0.0, 1.0);
        // Water to air beyond the critical angle asin(1/1.333) ≈ 48.6°.
        let a: f64 = 50f64.to_radians();
        let d = unit(a.sin(), 0.0, a.cos());
        assert!(refract(&d, &n, 1.333).is_none());
        let a: f64 = 47f64.to_radians();
        let d = unit(a.sin(), 0.0, a.cos());
        assert!(refract(&d, &n, 1.333).is_some());
    }

    #[test]
    fn direction_away_from_surface_is_none() {
        let n = unit(0.0, 0.0, 1.0);
        assert!(refract(&unit(0.0, 1.0, -0.1), &n, 0.75).is_none());
        assert!(refract(&unit(1.0, 0.0, 0.0), &n, 0.75).is_none());
    }
}
