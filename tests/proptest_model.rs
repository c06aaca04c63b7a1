//! Property tests of the refractive model over random rigs, against the independent oracles of
//! tests/oracle_common: normals tilted up to 30° in any azimuth; 0–3 layers of 0.1–50 mm with
//! indices 1.0–1.8; index_air 1.0–1.01 and index_water 1.0–1.8 (so total internal reflection
//! occurs, and both sides must agree that there is no solution); air layer 1–100 mm; distortion on
//! or off; a second camera 3–15 cm to the side, turned by up to 10°.
//!
//! Properties: |dir| = 1; Snell at every interface; closed form == traced == oracle tracer;
//! pixel → ray → point → pixel; point → pixel → ray through the point; refractive triangulation;
//! binocular VOPs == each camera's `vop()`; eq 4.7 ∘ eq 4.8 = id; eq 4.8 == traced VOP.

mod oracle_common;

use flatport::model::snell::refract;
use flatport::model::vop::{real_from_virtual, virtual_from_real};
use flatport::model::{NoSolution, binocular_vop, triangulate_rays};
use nalgebra::{Point3, Unit, Vector3};
use oracle_common::random_rig::{RigSpec, build, rig_spec};
use oracle_common::*;
use proptest::prelude::*;
use proptest::test_runner::TestCaseError;

/// Issue "Done when": 1e-6 px forward; the oracle pixels come from exact construction here.
const PIXEL_TOL: f64 = 1e-6;
/// Issue "Done when": back-projection to 1e-9 (unit direction; origin in metres for paths up to
/// 1 m, relative to the path length beyond: rays near grazing inside a thick layer travel far).
const RAY_TOL: f64 = 1e-9;
/// Issue "Done when": triangulation to 1e-7 m.
const TRIANGULATION_TOL: f64 = 1e-7;
/// Issue "Done when": VOP relations to 1e-9 m.
const VOP_TOL: f64 = 1e-9;
/// |dir| = 1: normalisation leaves a few ulp (ε = 2.2e-16).
const UNIT_TOL: f64 = 4e-15;
/// Snell's law between two unit vectors computed by different formulas: a few ulp, amplified by
/// 1/cos θ₂ (≤ 1e3, see [`MIN_COS`]) where the refracted ray is steep.
const SNELL_TOL: f64 = 1e-12;
/// Rays whose cosine to the normal falls below this anywhere in the stack are near grazing: a
/// 1e-15 change of the air direction (one undistortion) moves them by 1e-15/cos², so only
/// agreement on *whether* there is a solution is checked there.
const MIN_COS: f64 = 1e-3;
/// Paths whose TIR test is this close to the critical angle (|ρ² − sin²a|) are left out of the
/// agreement on TIR: both sides round sin²a differently.
const TIR_MARGIN: f64 = 1e-9;

/// Smallest ρ² − sin²a over the media after the air (TIR where ≤ 0) for a unit air direction.
fn tir_margin(fixture: &Fixture, dir: &Vector3<f64>) -> f64 {
    let cos_a = fixture.stack.normal.dot(dir);
    let sin2 = 1.0 - cos_a * cos_a;
    let mu_a = fixture.stack.index_air();
    fixture.stack.indices[1..]
        .iter()
        .map(|mu| (mu / mu_a).powi(2) - sin2)
        .fold(f64::INFINITY, f64::min)
}

/// Smallest cosine to the normal along a traced path.
fn min_cos(fixture: &Fixture, path: &Path) -> f64 {
    path.dirs
        .iter()
        .map(|d| fixture.stack.normal.dot(d))
        .fold(f64::INFINITY, f64::min)
}

fn tangential(v: &Vector3<f64>, n: &Vector3<f64>) -> Vector3<f64> {
    v - n * n.dot(v)
}

/// Samples of undistorted normalised image coordinates over most of the field of view.
fn samples() -> impl Strategy<Value = Vec<(f64, f64, f64)>> {
    prop::collection::vec((-0.7..0.7f64, -0.55..0.55f64, 0.0..1.0f64), 6)
}

/// Air directions at any incidence up to 89.9° and any azimuth about the axis (beyond any image).
fn air_directions() -> impl Strategy<Value = Vec<(f64, f64)>> {
    prop::collection::vec(
        (
            0.0..89.9f64.to_radians(),
            -std::f64::consts::PI..std::f64::consts::PI,
        ),
        6,
    )
}

/// The closed form and the model's tracer against the oracle tracer for air directions at any
/// incidence: the same answer, or the same reason for none (TIR; never a miss here).
fn steep_rays(fixture: &Fixture, directions: &[(f64, f64)]) -> Result<(), TestCaseError> {
    let n = fixture.stack.normal;
    let (u, v) = lateral_basis(&n);
    for k in 0..2 {
        let camera = fixture.camera(k);
        for &(a, phi) in directions {
            let dir = n * a.cos() + (u * phi.cos() + v * phi.sin()) * a.sin();
            if tir_margin(fixture, &dir).abs() <= TIR_MARGIN {
                continue;
            }
            let unit_dir = Unit::new_normalize(dir);
            let rays = [
                camera.ray_in_water(&unit_dir),
                camera.trace_ray_in_water(&unit_dir),
            ];
            match fixture.trace(k, &dir) {
                Err(Fail::Tir) => {
                    for ray in &rays {
                        prop_assert_eq!(
                            ray.map(|r| r.origin),
                            Err(NoSolution::TotalInternalReflection)
                        );
                    }
                }
                Err(e) => return Err(TestCaseError::fail(format!("oracle {e:?}"))),
                Ok(path) => {
                    let path_length = (path.origin() - fixture.cams[k].centre).norm();
                    for ray in &rays {
                        let ray = ray.map_err(|e| {
                            TestCaseError::fail(format!("model {e:?}, oracle traced"))
                        })?;
                        prop_assert!((ray.dir.norm() - 1.0).abs() <= UNIT_TOL);
                        if min_cos(fixture, &path) < MIN_COS {
                            continue;
                        }
                        let dir_error = (ray.dir.into_inner() - path.dir_in_water()).norm();
                        let origin_error = (ray.origin - path.origin()).norm();
                        prop_assert!(dir_error <= RAY_TOL, "direction off by {:e}", dir_error);
                        prop_assert!(
                            origin_error <= RAY_TOL * path_length.max(1.0),
                            "origin off by {:e}",
                            origin_error
                        );
                    }
                }
            }
        }
    }
    Ok(())
}

/// The pixel and master-frame air direction of a normalised sample for camera k, when the pixel lies
/// inside the image (where a lens model means something; always with no distortion).
fn sample_ray(
    fixture: &Fixture,
    k: usize,
    x: f64,
    y: f64,
) -> Option<(nalgebra::Point2<f64>, Vector3<f64>)> {
    let cam = &fixture.cams[k];
    if x * x + y * y >= fold_radius2(&cam.distortion) {
        return None;
    }
    let pixel = pixel_from_normalized(cam, x, y);
    (!cam.has_distortion() || cam.in_image(&pixel, 0.0))
        .then(|| (pixel, cam.dir_from_normalized(x, y)))
}

fn backprojection_properties(
    fixture: &Fixture,
    samples: &[(f64, f64, f64)],
) -> Result<(), TestCaseError> {
    let n = fixture.stack.normal;
    let unit_n = Unit::new_normalize(n);
    for k in 0..2 {
        let camera = fixture.camera(k);
        for &(x, y, _) in samples {
            let Some((pixel, dir)) = sample_ray(fixture, k, x, y) else {
                continue;
            };
            let oracle = fixture.trace(k, &dir);
            let unit_dir = Unit::new_normalize(dir);
            let rays = [
                camera.ray_in_water(&unit_dir),
                camera.trace_ray_in_water(&unit_dir),
                camera.backproject(&pixel),
                camera.backproject_traced(&pixel),
            ];
            let path = match oracle {
                Err(Fail::Tir) => {
                    if tir_margin(fixture, &dir).abs() > TIR_MARGIN {
                        for ray in &rays {
                            prop_assert_eq!(
                                ray.map(|r| r.origin),
                                Err(NoSolution::TotalInternalReflection)
                            );
                        }
                    }
                    continue;
                }
                Err(e) => {
                    return Err(TestCaseError::fail(format!(
                        "oracle {e:?} for an in-view ray"
                    )));
                }
                Ok(path) => path,
            };
            if tir_margin(fixture, &dir).abs() <= TIR_MARGIN {
                continue;
            }
            let grazing = min_cos(fixture, &path) < MIN_COS;
            let path_length = (path.origin() - fixture.cams[k].centre).norm();
            for (i, ray) in rays.iter().enumerate() {
                let ray = ray.map_err(|e| {
                    TestCaseError::fail(format!("ray {i}: model {e:?}, oracle traced"))
                })?;
                prop_assert!(
                    (ray.dir.norm() - 1.0).abs() <= UNIT_TOL,
                    "|dir| = {}",
                    ray.dir.norm()
                );
                if grazing {
                    continue;
                }
                let dir_error = (ray.dir.into_inner() - path.dir_in_water()).norm();
                let origin_error = (ray.origin - path.origin()).norm();
                prop_assert!(
                    dir_error <= RAY_TOL,
                    "ray {}: direction off by {:e}",
                    i,
                    dir_error
                );
                prop_assert!(
                    origin_error <= RAY_TOL * path_length.max(1.0),
                    "ray {}: origin off by {:e}",
                    i,
                    origin_error
                );
                // The origin lies on the outer interface.
                let outer = fixture.d_k(k) + fixture.stack.layers_thickness();
                let plane_error = (n.dot(&(ray.origin - fixture.cams[k].centre)) - outer).abs();
                prop_assert!(plane_error <= RAY_TOL * path_length.max(1.0));
            }
            if grazing {
                continue;
            }
            // Snell across the whole stack on the model's own rays: μa·v_t = μw·w_t (magnitude,
            // plane of refraction and side at once).
            let air = camera
                .dir_in_air_from_img(&pixel)
                .map_err(|e| TestCaseError::fail(format!("{e:?}")))?;
            let water = camera.backproject(&pixel).unwrap().dir;
            let (mu_a, mu_w) = (fixture.stack.index_air(), fixture.stack.index_water());
            let snell = (tangential(&air, &n) * mu_a - tangential(&water, &n) * mu_w).norm();
            prop_assert!(snell <= SNELL_TOL, "μ sin θ not conserved: {:e}", snell);
            // Snell at every interface of the oracle's path, through the crate's vector formula,
            // and μ sin θ conserved along the oracle's path (from its tangential components).
            for (i, pair) in path.dirs.windows(2).enumerate() {
                let (mu1, mu2) = (fixture.stack.indices[i], fixture.stack.indices[i + 1]);
                let refracted = refract(&Unit::new_normalize(pair[0]), &unit_n, mu1 / mu2)
                    .ok_or_else(|| {
                        TestCaseError::fail(format!("refract gave TIR at interface {i}"))
                    })?;
                prop_assert!(
                    (refracted.into_inner() - pair[1]).norm() <= SNELL_TOL,
                    "interface {}",
                    i
                );
                let conserved =
                    (tangential(&pair[0], &n) * mu1 - tangential(&pair[1], &n) * mu2).norm();
                prop_assert!(conserved <= SNELL_TOL);
            }
        }
    }
    Ok(())
}

fn round_trips(fixture: &Fixture, samples: &[(f64, f64, f64)]) -> Result<(), TestCaseError> {
    for k in 0..2 {
        let camera = fixture.camera(k);
        let centre = fixture.cams[k].centre;
        for &(x, y, t) in samples {
            let Some((pixel, dir)) = sample_ray(fixture, k, x, y) else {
                continue;
            };
            let Ok(path) = fixture.trace(k, &dir) else {
                continue;
            };
            if min_cos(fixture, &path) < MIN_COS || tir_margin(fixture, &dir).abs() <= TIR_MARGIN {
                continue;
            }
            // A point 1 mm – 5 m along the oracle's water ray: its pixel is known exactly.
            let s = 1e-3 * 5000f64.powf(t);
            let point = path.origin() + path.dir_in_water() * s;

            // pixel → ray → point → pixel.
            let ray = camera
                .backproject(&pixel)
                .map_err(|e| TestCaseError::fail(format!("{e:?}")))?;
            let back = camera
                .project(&ray.point_at(s))
                .map_err(|e| TestCaseError::fail(format!("{e:?}")))?;
            prop_assert!(
                (back - pixel).norm() <= PIXEL_TOL,
                "pixel → ray → pixel off by {:e}",
                (back - pixel).norm()
            );

            // point → pixel (== the oracle's pixel) → ray through the point.
            let projected = camera
                .project(&point)
                .map_err(|e| TestCaseError::fail(format!("{e:?}")))?;
            prop_assert!(
                (projected - pixel).norm() <= PIXEL_TOL,
                "project off by {:e}",
                (projected - pixel).norm()
            );
            let ray = camera
                .backproject(&projected)
                .map_err(|e| TestCaseError::fail(format!("{e:?}")))?;
            let miss = point_line_distance(&point, &ray.origin, &ray.dir);
            prop_assert!(
                miss <= RAY_TOL * (point - centre).norm(),
                "ray misses the point by {:e} m",
                miss
            );

            // The model's VOP == the traced VOP (where eq 4.8 is well conditioned, see
            // oracle_projection::GRAZING_COS), and eq 4.7 undoes eq 4.8.
            let x_depth = fixture.stack.depth(&centre, &point);
            let a = fixture.stack.normal.dot(&dir).clamp(-1.0, 1.0).acos();
            if fixture.stack.normal.dot(&path.dir_in_water()) >= 0.01 && a > 1e-6 {
                let (traced, traced_vop) =
                    vop_by_tracing(&centre, &dir, &point, &fixture.stack.normal, x_depth);
                let vop = camera
                    .vop(&point)
                    .map_err(|e| TestCaseError::fail(format!("{e:?}")))?;
                prop_assert!(
                    (vop.vop_distance - traced).abs() <= VOP_TOL,
                    "vop() {} vs traced {}",
                    vop.vop_distance,
                    traced
                );
                prop_assert!((vop.vop - traced_vop).norm() <= VOP_TOL);
                let layers = fixture.stack.layers();
                let (mu_a, mu_w) = (fixture.stack.index_air(), fixture.stack.index_water());
                let formula = virtual_from_real(x_depth, a, &layers, mu_a, mu_w).unwrap();
                prop_assert!(
                    (formula - traced).abs() <= VOP_TOL,
                    "eq 4.8 {} vs traced {}",
                    formula,
                    traced
                );
                let back = real_from_virtual(formula, a, &layers, mu_a, mu_w).unwrap();
                prop_assert!(
                    (back - x_depth).abs() <= VOP_TOL,
                    "eq 4.7 ∘ 4.8: {} vs {}",
                    back,
                    x_depth
                );
            }
        }
    }
    Ok(())
}

fn stereo(fixture: &Fixture, samples: &[(f64, f64, f64)]) -> Result<(), TestCaseError> {
    let (left, right) = (fixture.camera(0), fixture.camera(1));
    let n = Unit::new_normalize(fixture.stack.normal);
    for &(x, y, t) in samples {
        let Some((pixel_l, dir_l)) = sample_ray(fixture, 0, 0.6 * x, 0.6 * y) else {
            continue;
        };
        let Ok(path) = fixture.trace(0, &dir_l) else {
            continue;
        };
        if min_cos(fixture, &path) < MIN_COS {
            continue;
        }
        // 0.3–5 m along the water ray.
        let point = path.origin() + path.dir_in_water() * (0.3 * (5.0f64 / 0.3).powf(t));
        let Ok(pixel_r) = right.project(&point) else {
            continue;
        };
        if fixture.cams[1].has_distortion() && !fixture.cams[1].in_image(&pixel_r, 0.0) {
            continue;
        }
        let (Ok(ray_l), Ok(ray_r)) = (left.backproject(&pixel_l), right.backproject(&pixel_r))
        else {
            return Err(TestCaseError::fail("projected pixels must back-project"));
        };
        let tri =
            triangulate_rays(&ray_l, &ray_r).map_err(|e| TestCaseError::fail(format!("{e:?}")))?;
        prop_assert!(
            (tri.point - point).norm() <= TRIANGULATION_TOL,
            "triangulated {:e} m off",
            (tri.point - point).norm()
        );
        // The rays meet: residual < 1e-9 m (issue).
        prop_assert!(tri.residual < 1e-9, "residual {:e}", tri.residual);

        // Binocular VOPs from the two air rays and the axis only == each camera's own VOP.
        let (Ok(air_l), Ok(air_r)) = (
            left.dir_in_air_from_img(&pixel_l),
            right.dir_in_air_from_img(&pixel_r),
        ) else {
            return Err(TestCaseError::fail("in-image pixels have air rays"));
        };
        let Ok(bino) = binocular_vop(left.centre(), &air_l, right.centre(), &air_r, &n) else {
            continue;
        };
        if bino.conditioning <= 1e-3 {
            continue;
        }
        let grazing = |k: usize, dir: &Vector3<f64>| {
            fixture
                .trace(k, dir)
                .map_or(true, |p| fixture.stack.normal.dot(&p.dir_in_water()) < 0.01)
        };
        if grazing(0, &air_l) || grazing(1, &air_r) {
            continue;
        }
        let (vop_l, vop_r) = (left.vop(&point).unwrap(), right.vop(&point).unwrap());
        prop_assert!(
            (bino.vop_left - vop_l.vop).norm() <= VOP_TOL,
            "left VOP {:e} m off",
            (bino.vop_left - vop_l.vop).norm()
        );
        prop_assert!(
            (bino.vop_right - vop_r.vop).norm() <= VOP_TOL,
            "right VOP {:e} m off",
            (bino.vop_right - vop_r.vop).norm()
        );
        // And both lie on the point's object axis, m·n apart.
        prop_assert!(point_line_distance(&bino.vop_left, &point, &n).abs() <= VOP_TOL);
    }
    Ok(())
}

/// eq 4.8 against a VOP traced from the angle itself (no root finding on either side), and eq 4.7
/// ∘ eq 4.8 = id.
fn vop_relations(fixture: &Fixture, a: f64, log_depth: f64) -> Result<(), TestCaseError> {
    let n = fixture.stack.normal;
    let (u, _) = lateral_basis(&n);
    let dir = n * a.cos() + u * a.sin();
    let depth = 10f64.powf(log_depth);
    let layers = fixture.stack.layers();
    let (mu_a, mu_w) = (fixture.stack.index_air(), fixture.stack.index_water());
    let formula = virtual_from_real(depth, a, &layers, mu_a, mu_w);
    let path = match fixture.trace(0, &dir) {
        Err(_) => {
            if tir_margin(fixture, &dir).abs() > TIR_MARGIN {
                prop_assert_eq!(formula, None, "TIR by tracing, not by eq 4.8");
            }
            return Ok(());
        }
        Ok(path) => path,
    };
    if tir_margin(fixture, &dir).abs() <= TIR_MARGIN {
        return Ok(());
    }
    let formula = formula.ok_or_else(|| TestCaseError::fail("eq 4.8 gave TIR on a traced path"))?;
    let back = real_from_virtual(formula, a, &layers, mu_a, mu_w).unwrap();
    prop_assert!(
        (back - depth).abs() <= VOP_TOL,
        "eq 4.7 ∘ 4.8: {} vs {}",
        back,
        depth
    );
    let w = path.dir_in_water();
    if n.dot(&w) < 0.01 || a < 1e-6 {
        return Ok(()); // eq 4.8 is ill-conditioned where the water ray grazes
    }
    let point = path.origin() + w * (depth / n.dot(&w));
    let (traced, _) = vop_by_tracing(&Point3::origin(), &dir, &point, &n, depth);
    prop_assert!(
        (formula - traced).abs() <= VOP_TOL,
        "eq 4.8 {} vs traced {}",
        formula,
        traced
    );
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(1024))]

    #[test]
    fn backprojection_agrees_with_the_tracer_and_snell(spec in rig_spec(), samples in samples()) {
        backprojection_properties(&build(&spec), &samples)?;
    }

    #[test]
    fn steep_rays_agree_with_the_tracer_including_tir(spec in rig_spec(), directions in air_directions()) {
        steep_rays(&build(&spec), &directions)?;
    }

    #[test]
    fn round_trips_and_vops(spec in rig_spec(), samples in samples()) {
        round_trips(&build(&spec), &samples)?;
    }

    #[test]
    fn stereo_triangulation_and_binocular_vops(spec in rig_spec(), samples in samples()) {
        stereo(&build(&spec), &samples)?;
    }

    #[test]
    fn vop_relations_match_tracing(spec in rig_spec(), a in prop_oneof![0.0..1.565f64, 1.3..1.57f64], log_depth in -4.0..1.0f64) {
        vop_relations(&build(&spec), a, log_depth)?;
    }
}

/// The binocular VOPs are undetermined in the plane through the baseline parallel to the axis.
#[test]
fn binocular_vop_in_the_baseline_plane_is_degenerate() {
    let fixture = build(&RigSpec {
        tilt: 0.0,
        azimuth: 0.0,
        air_distance: 0.03,
        layers: vec![(0.01, 1.5)],
        index_air: 1.0,
        index_water: 1.333,
        distortion: None,
        focal: 900.0,
        turn: (0.0, 0.0, 0.0),
        baseline: (0.1, 0.0, 0.0),
    });
    let (left, right) = (fixture.camera(0), fixture.camera(1));
    // The point (0.05, 0, 2): both air rays lie in the x–z plane, which contains n = z.
    let point = Point3::new(0.05, 0.0, 2.0);
    let (dl, dr) = (
        left.air_path_to(&point).unwrap().dir_in_air,
        right.air_path_to(&point).unwrap().dir_in_air,
    );
    let n = Unit::new_normalize(fixture.stack.normal);
    assert_eq!(
        binocular_vop(left.centre(), &dl, right.centre(), &dr, &n).map(|b| b.s_left),
        Err(NoSolution::Degenerate)
    );
}
