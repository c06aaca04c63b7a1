//! The λ relations and the Virtual Object Point (VOP) relations of Dolereit's thesis.
//!
//! All angles are the angle of incidence a in the medium around the cameras (μa), measured from the
//! system axis. In the plane of refraction μa sin a = μᵢ sin θᵢ = μw sin θw.

use super::interface::Layer;

/// λ1 (thesis eq 4.2): λ1 = √((μw/μa)² − sin²a) / cos a = tan a / tan θw.
///
/// Returns `None` on total internal reflection ((μw/μa)² ≤ sin²a) or a ≥ 90°.
pub fn lambda1(incidence: f64, index_air: f64, index_water: f64) -> Option<f64> {
    let (sin_a, cos_a) = incidence.sin_cos();
    lambda_ratio(sin_a * sin_a, cos_a, index_water / index_air).map(|root| root / cos_a)
}

/// λ2 (thesis eq 4.6): λ2 = cos a / √((μg/μa)² − sin²a) = tan θg / tan a.
///
/// Returns `None` on total internal reflection or a ≥ 90°.
pub fn lambda2(incidence: f64, index_air: f64, index_glass: f64) -> Option<f64> {
    let (sin_a, cos_a) = incidence.sin_cos();
    lambda_ratio(sin_a * sin_a, cos_a, index_glass / index_air).map(|root| cos_a / root)
}

/// √(ρ² − sin²a) when positive and cos a > 0.
#[inline]
fn lambda_ratio(sin2_a: f64, cos_a: f64, rho: f64) -> Option<f64> {
    let radicand = rho * rho - sin2_a;
    (radicand > 0.0 && cos_a > 0.0).then(|| radicand.sqrt())
}

/// The thickness term T = Σ tᵢ (1 − λ2(a, μa, μᵢ)) of the N-layer VOP relations.
#[inline]
fn layer_shift(sin2_a: f64, cos_a: f64, index_air: f64, layers: &[Layer]) -> Option<f64> {
    let mut shift = 0.0;
    for layer in layers {
        let root = lambda_ratio(sin2_a, cos_a, layer.index / index_air)?;
        shift += layer.thickness * (1.0 - cos_a / root);
    }
    Some(shift)
}

/// Virtual-from-real (thesis eq 4.8, generalised to N layers):
/// x̌ = x / λ1 − Σ tᵢ (1 − λ2(a, μa, μᵢ)).
///
/// `depth` is x, the distance of the real point O from the outer interface along the axis (> 0);
/// the result is x̌, the signed distance from A1 (where O's object axis meets the outer interface)
/// to the VOP, positive toward the water, negative when the VOP lies inside the layers. Metres.
/// Returns `None` on total internal reflection at any layer or in the water.
pub fn virtual_from_real(
    depth: f64,
    incidence: f64,
    layers: &[Layer],
    index_air: f64,
    index_water: f64,
) -> Option<f64> {
    let (lambda1, shift) = lambda1_and_shift(incidence, layers, index_air, index_water)?;
    Some(depth / lambda1 - shift)
}

/// Real-from-virtual (thesis eq 4.7, generalised to N layers):
/// x = λ1 · (x̌ + Σ tᵢ (1 − λ2(a, μa, μᵢ))).
///
/// Inverse of [`virtual_from_real`]; same units and `None` cases.
pub fn real_from_virtual(
    vop_distance: f64,
    incidence: f64,
    layers: &[Layer],
    index_air: f64,
    index_water: f64,
) -> Option<f64> {
    let (lambda1, shift) = lambda1_and_shift(incidence, layers, index_air, index_water)?;
    Some(lambda1 * (vop_distance + shift))
}

/// λ1 and T = Σ tᵢ (1 − λ2,ᵢ) at angle of incidence a: the two quantities of eqs 4.7 and 4.8.
fn lambda1_and_shift(
    incidence: f64,
    layers: &[Layer],
    index_air: f64,
    index_water: f64,
) -> Option<(f64, f64)> {
    let (sin_a, cos_a) = incidence.sin_cos();
    let sin2_a = sin_a * sin_a;
    let lambda1 = lambda_ratio(sin2_a, cos_a, index_water / index_air)? / cos_a;
    Some((lambda1, layer_shift(sin2_a, cos_a, index_air, layers)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    const GLASS: [Layer; 1] = [Layer {
        thickness: 0.014,
        index: 1.473,
    }];

    #[test]
    fn lambdas_are_tangent_ratios() {
        let a: f64 = 0.5;
        let (ma, mg, mw) = (1.003, 1.473, 1.333);
        let theta_w = (ma * a.sin() / mw).asin();
        let theta_g = (ma * a.sin() / mg).asin();
        assert!((lambda1(a, ma, mw).unwrap() - a.tan() / theta_w.tan()).abs() < 1e-14);
        assert!((lambda2(a, ma, mg).unwrap() - theta_g.tan() / a.tan()).abs() < 1e-14);
    }

    #[test]
    fn normal_incidence_is_apparent_depth() {
        // x̌ = (μa/μw)·x − t_g(1 − μa/μg) at a = 0.
        let x = 1.2;
        let v = virtual_from_real(x, 0.0, &GLASS, 1.0, 1.333).unwrap();
        let expected = x / 1.333 - 0.014 * (1.0 - 1.0 / 1.473);
        assert!((v - expected).abs() < 1e-15);
    }

    #[test]
    fn relations_invert_each_other_including_vops_in_the_glass() {
        for &x in &[1e-4, 0.001, 0.3, 5.0] {
            for &a in &[0.0, 0.2, 0.6, 0.9] {
                let v = virtual_from_real(x, a, &GLASS, 1.0, 1.333).unwrap();
                let back = real_from_virtual(v, a, &GLASS, 1.0, 1.333).unwrap();
                assert!((back - x).abs() < 1e-15 * (1.0 + x), "x={x} a={a}");
            }
        }
        // A point 0.1 mm into the water has its VOP inside the glass.
        assert!(virtual_from_real(1e-4, 0.3, &GLASS, 1.0, 1.333).unwrap() < 0.0);
    }

    #[test]
    fn total_internal_reflection_is_none() {
        // From water (1.333) into "air" 1.0 past the critical angle.
        assert!(lambda1(1.0, 1.333, 1.0).is_none());
        assert!(lambda2(1.0, 1.333, 1.0).is_none());
        assert!(virtual_from_real(1.0, 1.0, &GLASS, 1.333, 1.0).is_none());
    }
}
