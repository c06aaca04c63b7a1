//! The refractive model against independent oracles (tests/oracle_common): forward projection vs
//! bisection over a brute-force tracer and vs Agrawal's one-interface quartic, back-projection vs
//! the tracer, the traced VOP vs eq 4.8 and `RefractiveCamera::vop`, apparent depth, the
//! no-solution cases, and the Newton iteration count of the forward projection.
//!
//! Run with `cargo test --release --test oracle_projection -- --nocapture` to see the measured
//! errors per configuration.

mod oracle_common;

use flatport::model::vop::{real_from_virtual, virtual_from_real};
use flatport::model::{NoSolution, RefractiveCamera};
use nalgebra::{Matrix3, Matrix4, Point2, Point3, Unit, Vector3};
use oracle_common::*;

/// Issue "Done when": forward projection agrees with independent values to 1e-6 px. The bisection
/// oracle resolves the angle of incidence to ~1 ulp (1e-16 rad), i.e. ~1e-13 px at f ≈ 900 px.
const PIXEL_TOL: f64 = 1e-6;
/// Issue "Done when": back-projected rays to 1e-9 (unit direction difference; origin distance in
/// metres). The tracer and the model both work in f64 on paths of ≤ 1 m: rounding is ~1e-15.
const RAY_TOL: f64 = 1e-9;
/// Issue "Done when": VOP relations to 1e-9 m. The traced VOP carries the oracle's angle error
/// (~1e-16 rad) times r/sin²a (≤ ~1e3 m on the grid below), so ≤ 1e-13 m.
const VOP_TOL: f64 = 1e-9;

fn fail_matches(oracle: Fail, model: NoSolution) -> bool {
    matches!(
        (oracle, model),
        (Fail::NotInWater, NoSolution::NotInWater)
            | (Fail::BehindCamera, NoSolution::BehindCamera)
            | (Fail::Tir, NoSolution::TotalInternalReflection)
            | (Fail::Misses, NoSolution::MissesInterface)
            | (Fail::OutsideLens, NoSolution::OutsideLens)
    )
}

#[test]
fn forward_projection_matches_bisection_oracle() {
    println!("forward projection vs bisection oracle (max |Δpixel|):");
    for fixture in all_fixtures() {
        for k in 0..2 {
            let camera = fixture.camera(k);
            let (mut worst_in_image, mut worst, mut compared, mut on_axis): (
                f64,
                f64,
                usize,
                usize,
            ) = (0.0, 0.0, 0, 0);
            for point in grid_points(&fixture, k) {
                match (fixture.project(k, &point), camera.project(&point)) {
                    (Ok(oracle), Ok(model)) => {
                        let error = (oracle - model).norm();
                        // Relative to the pixel's distance from the principal point: far outside
                        // the image (steep rays through a 30° tilted port) pixels reach 1e5 px,
                        // where one ulp is already 1e-11 px.
                        let scale = 1.0
                            + (oracle - Point2::new(fixture.cams[k].cx, fixture.cams[k].cy)).norm()
                                / 1e4;
                        worst = worst.max(error / scale);
                        if fixture.cams[k].in_image(&oracle, 0.0) {
                            worst_in_image = worst_in_image.max(error);
                            compared += 1;
                        }
                        let n = fixture.stack.normal;
                        let offset = point - fixture.cams[k].centre;
                        if (offset - n * n.dot(&offset)).norm() < 1e-12 {
                            on_axis += 1;
                        }
                    }
                    (Err(o), Err(m)) => assert!(
                        fail_matches(o, m),
                        "{}: oracle {o:?}, model {m:?}",
                        fixture.name
                    ),
                    (o, m) => panic!(
                        "{} camera {k} {point:?}: oracle {o:?}, model {m:?}",
                        fixture.name
                    ),
                }
            }
            println!(
                "  {:18} cam {k}: {worst_in_image:.1e} px over {compared} pixels in the image, {worst:.1e} px \
                 (scaled) over all",
                fixture.name
            );
            assert!(
                compared >= 50 && on_axis >= 6,
                "{}: {compared} in image, {on_axis} on axis",
                fixture.name
            );
            assert!(
                worst_in_image <= PIXEL_TOL,
                "{} cam {k}: {worst_in_image} px",
                fixture.name
            );
            assert!(
                worst <= PIXEL_TOL,
                "{} cam {k}: {worst} px (scaled)",
                fixture.name
            );
        }
    }
}

/// Grid of undistorted normalised coordinates over (and a little beyond) the field of view.
fn normalized_grid() -> Vec<(f64, f64)> {
    let mut grid = Vec::new();
    for i in 0..=16 {
        for j in 0..=12 {
            grid.push((-0.8 + 1.6 * i as f64 / 16.0, -0.65 + 1.3 * j as f64 / 12.0));
        }
    }
    grid
}

fn ray_errors(
    ray: Result<flatport::model::Ray, NoSolution>,
    oracle: &Result<Path, Fail>,
    what: &str,
) -> (f64, f64) {
    match (ray, oracle) {
        (Ok(ray), Ok(path)) => (
            (ray.dir.into_inner() - path.dir_in_water()).norm(),
            (ray.origin - path.origin()).norm(),
        ),
        (Err(m), Err(o)) => {
            assert!(fail_matches(*o, m), "{what}: oracle {o:?}, model {m:?}");
            (0.0, 0.0)
        }
        (m, o) => panic!("{what}: oracle {o:?}, model {m:?}"),
    }
}

#[test]
fn backprojection_matches_the_tracer() {
    println!("back-projection vs tracer (max |Δdir|, max |Δorigin| m):");
    let mut tir = 0;
    for fixture in all_fixtures() {
        for k in 0..2 {
            let camera = fixture.camera(k);
            let params = &fixture.cams[k];
            let (mut dir_err, mut origin_err, mut pixels): (f64, f64, usize) = (0.0, 0.0, 0);
            for (x, y) in normalized_grid() {
                let dir = params.dir_from_normalized(x, y);
                let oracle = fixture.trace(k, &dir);
                if oracle == Err(Fail::Tir) {
                    tir += 1;
                }
                let unit = Unit::new_normalize(dir);
                let what = format!("{} cam {k} ({x}, {y})", fixture.name);
                // The air direction given directly: closed form and traced.
                for ray in [camera.ray_in_water(&unit), camera.trace_ray_in_water(&unit)] {
                    let (d, o) = ray_errors(ray, &oracle, &what);
                    dir_err = dir_err.max(d);
                    origin_err = origin_err.max(o);
                }
                // Through the pixel (crate undistortion) where the lens model is meaningful.
                let pixel = pixel_from_normalized(params, x, y);
                if !params.has_distortion() || params.in_image(&pixel, 0.0) {
                    pixels += 1;
                    for ray in [
                        camera.backproject(&pixel),
                        camera.backproject_traced(&pixel),
                    ] {
                        let (d, o) = ray_errors(ray, &oracle, &what);
                        dir_err = dir_err.max(d);
                        origin_err = origin_err.max(o);
                    }
                }
            }
            println!(
                "  {:18} cam {k}: {dir_err:.1e}, {origin_err:.1e} m ({pixels} pixels)",
                fixture.name
            );
            assert!(pixels > 100, "{}", fixture.name);
            assert!(
                dir_err <= RAY_TOL && origin_err <= RAY_TOL,
                "{} cam {k}",
                fixture.name
            );
        }
    }
    // The immersed rig (μa = 1.333 → μw = 1.0) must have exercised total internal reflection.
    assert!(tir > 20, "only {tir} TIR directions");
}

#[test]
fn projected_pixel_backprojects_through_the_point() {
    let mut worst: f64 = 0.0;
    let mut checked = 0;
    for fixture in all_fixtures() {
        for k in 0..2 {
            let camera = fixture.camera(k);
            for point in grid_points(&fixture, k) {
                let Ok(pixel) = camera.project(&point) else {
                    continue;
                };
                if fixture.cams[k].has_distortion() && !fixture.cams[k].in_image(&pixel, 0.0) {
                    continue; // undistortion is only defined inside the image
                }
                let ray = camera
                    .backproject(&pixel)
                    .expect("a projected pixel back-projects");
                let miss = point_line_distance(&point, &ray.origin, &ray.dir);
                worst = worst.max(miss);
                checked += 1;
                // Issue: back-projection to 1e-9; here the point lies ≤ 5 m along the ray.
                assert!(
                    miss <= RAY_TOL,
                    "{} cam {k} {point:?}: misses by {miss} m",
                    fixture.name
                );
            }
        }
    }
    println!(
        "project → backproject: max distance of the point from its ray {worst:.1e} m over {checked} points"
    );
    assert!(checked > 1000);
}

#[test]
fn apparent_depth_at_normal_incidence() {
    let mut worst: f64 = 0.0;
    for fixture in all_fixtures() {
        for k in 0..2 {
            let camera = fixture.camera(k);
            let n = fixture.stack.normal;
            let outer = fixture.d_k(k) + fixture.stack.layers_thickness();
            for &depth in &[1e-4, 0.01, 0.3, 1.0, 5.0] {
                let point = fixture.cams[k].centre + n * (outer + depth);
                let x = fixture.stack.depth(&fixture.cams[k].centre, &point);
                let expected = apparent_depth(x, &fixture.stack);
                let vop = camera.vop(&point).expect("on-axis point has a VOP");
                let formula = virtual_from_real(
                    x,
                    0.0,
                    &fixture.stack.layers(),
                    fixture.stack.index_air(),
                    fixture.stack.index_water(),
                )
                .unwrap();
                for got in [vop.vop_distance, formula] {
                    worst = worst.max((got - expected).abs());
                    // Issue: VOP relations to 1e-9 m.
                    assert!(
                        (got - expected).abs() <= VOP_TOL,
                        "{}: {got} vs {expected}",
                        fixture.name
                    );
                }
                // The pixel is that of the axis direction n.
                if let Some(oracle) = pixel_from_dir(&fixture.cams[k], &n) {
                    let model = camera.project(&point).unwrap();
                    assert!((model - oracle).norm() <= PIXEL_TOL, "{}", fixture.name);
                }
            }
        }
    }
    println!("apparent depth at a = 0: max |x̌ − ((μa/μw)x − Σtᵢ(1 − μa/μᵢ))| = {worst:.1e} m");
}

/// Cosine of the water ray's angle below which the VOP test moves a point to
/// [`vop_where_the_water_ray_grazes`]: there eq 4.8 has condition number ~1/cos²θw in a.
const GRAZING_COS: f64 = 0.01;

#[test]
fn vop_matches_the_traced_vop() {
    println!("VOP vs traced VOP (max |Δx̌| m, max |ΔǑ| m):");
    let (mut in_glass, mut grazing) = (0, 0);
    for fixture in all_fixtures() {
        let layers = fixture.stack.layers();
        let (mu_a, mu_w) = (fixture.stack.index_air(), fixture.stack.index_water());
        let n = fixture.stack.normal;
        for k in 0..2 {
            let camera = fixture.camera(k);
            let (mut worst_distance, mut worst_point): (f64, f64) = (0.0, 0.0);
            let mut worst_at = String::new();
            for point in grid_points(&fixture, k) {
                let Some((traced, traced_vop)) = fixture.traced_vop(k, &point) else {
                    continue;
                };
                let (dir, a) = fixture.air_dir(k, &point).unwrap();
                if n.dot(&fixture.trace(k, &dir).unwrap().dir_in_water()) < GRAZING_COS {
                    grazing += 1;
                    continue;
                }
                let x = fixture.stack.depth(&fixture.cams[k].centre, &point);
                let vop = camera.vop(&point).expect("point in the water has a VOP");
                let formula =
                    virtual_from_real(x, a, &layers, mu_a, mu_w).expect("no TIR on a real path");
                for got in [vop.vop_distance, formula] {
                    if (got - traced).abs() > worst_distance {
                        worst_distance = (got - traced).abs();
                        worst_at = format!("x = {x:.1e} m, a = {a:.3} rad, x̌ = {traced:.3e} m");
                    }
                }
                worst_point = worst_point.max((vop.vop - traced_vop).norm());
                assert!((vop.depth - x).abs() <= 1e-12, "{}", fixture.name);
                // eq 4.7 inverts the traced x̌.
                let back = real_from_virtual(traced, a, &layers, mu_a, mu_w).unwrap();
                assert!(
                    (back - x).abs() <= VOP_TOL,
                    "{}: eq 4.7 gives {back}, traced {x}",
                    fixture.name
                );
                if traced < 0.0 {
                    in_glass += 1;
                }
            }
            println!(
                "  {:18} cam {k}: {worst_distance:.1e}, {worst_point:.1e} (at {worst_at})",
                fixture.name
            );
            assert!(
                worst_distance <= VOP_TOL && worst_point <= VOP_TOL,
                "{} cam {k}",
                fixture.name
            );
        }
    }
    println!(
        "  ({grazing} points with a grazing water ray, cos θw < {GRAZING_COS}, left to the next test)"
    );
    // The 0.1 mm points behind glass have their VOP inside the glass (x̌ < 0).
    assert!(in_glass > 100, "only {in_glass} VOPs inside the layers");
}

/// `RefractiveCamera::vop` where the water ray grazes the interface (immersed rig, μa > μw, points
/// 0.1 mm behind the port seen near the critical angle). The VOP is well conditioned in the point
/// (x̌ = r / tan a − d_k − Σtᵢ by its definition), but `vop()` evaluates eq 4.8 at its τ, whose
/// condition number in a is ~1/cos²θw: measured error up to 2.1e-8 m over 148 points at
/// x = 0.1 mm, a within ~1e-4 rad of the critical angle 0.848 rad, x̌ ≈ 1 m.
#[test]
fn vop_where_the_water_ray_grazes() {
    let mut worst: f64 = 0.0;
    let mut checked = 0;
    for fixture in all_fixtures() {
        let n = fixture.stack.normal;
        for k in 0..2 {
            let camera = fixture.camera(k);
            for point in grid_points(&fixture, k) {
                let Some((traced, _)) = fixture.traced_vop(k, &point) else {
                    continue;
                };
                let (dir, _) = fixture.air_dir(k, &point).unwrap();
                if n.dot(&fixture.trace(k, &dir).unwrap().dir_in_water()) >= GRAZING_COS {
                    continue;
                }
                checked += 1;
                worst = worst.max((camera.vop(&point).unwrap().vop_distance - traced).abs());
            }
        }
    }
    println!("vop() where the water ray grazes: max |Δx̌| = {worst:.1e} m over {checked} points");
    assert!(checked > 0);
    // Issue: VOP relations to 1e-9 m.
    assert!(worst <= VOP_TOL, "{worst} m");
}

#[test]
fn no_solution_cases() {
    let glass = fixture(Kind::OneGlass, false);
    let camera = glass.camera(0);
    let n = glass.stack.normal;
    let (u, _) = lateral_basis(&n);
    let d = glass.stack.air_distance;
    // Inside the glass (d < n·O < d + t), in the air, behind the camera.
    for point in [
        n * (d + 0.007),
        n * (d + 0.007) + u * 0.3,
        n * (0.5 * d),
        n * (-1.0) + u,
    ] {
        let point = Point3::from(point);
        assert_eq!(glass.project(0, &point), Err(Fail::NotInWater));
        assert_eq!(camera.project(&point), Err(NoSolution::NotInWater));
        assert_eq!(
            camera.air_path_to(&point).map(|p| p.depth),
            Err(NoSolution::NotInWater)
        );
        assert_eq!(
            camera.vop(&point).map(|v| v.depth),
            Err(NoSolution::NotInWater)
        );
    }
    // Just beyond the outer interface is in the water.
    assert!(
        camera
            .project(&Point3::from(n * (d + 0.014 + 1e-9)))
            .is_ok()
    );

    // A reversed tank: camera in water (μa = 1.333) behind glass, an air gap, glass, water. Light
    // cannot enter the air gap beyond asin(1/1.333) ≈ 48.6°.
    let stack = Stack {
        normal: normal_from_angles(0.2, 0.5),
        air_distance: 0.05,
        thicknesses: vec![0.01, 0.3, 0.01],
        indices: vec![1.333, 1.5, 1.0, 1.5, 1.333],
    };
    let centre = Point3::origin();
    let cam = CamParams {
        rotation: Matrix3::identity(),
        centre,
        width: 1280,
        height: 1024,
        fx: 500.0,
        fy: 500.0,
        cx: 639.5,
        cy: 511.5,
        distortion: [0.0; 5],
    };
    let tank = Fixture::build("reversed tank", stack, vec![cam]);
    let camera = tank.camera(0);
    let (mut tir, mut through) = (0, 0);
    for i in 0..=20 {
        let pixel = Point2::new(i as f64 * 1279.0 / 20.0, 100.0);
        let dir =
            tank.cams[0].dir_from_normalized((pixel.x - 639.5) / 500.0, (100.0 - 511.5) / 500.0);
        match tank.trace(0, &dir) {
            Err(Fail::Tir) => {
                tir += 1;
                assert_eq!(
                    camera.backproject(&pixel),
                    Err(NoSolution::TotalInternalReflection)
                );
                assert_eq!(
                    camera.backproject_traced(&pixel),
                    Err(NoSolution::TotalInternalReflection)
                );
            }
            Ok(path) => {
                through += 1;
                let ray = camera.backproject(&pixel).unwrap();
                assert!((ray.dir.into_inner() - path.dir_in_water()).norm() <= RAY_TOL);
                assert!((ray.origin - path.origin()).norm() <= RAY_TOL);
            }
            Err(e) => panic!("{e:?}"),
        }
    }
    assert!(tir >= 3 && through >= 3, "tir {tir}, through {through}");

    // Air rays parallel to or away from the interface miss it.
    let flat = Fixture::build(
        "45° port",
        Stack {
            normal: Vector3::new(1.0, 0.0, 1.0).normalize(),
            air_distance: 0.03,
            thicknesses: vec![0.01],
            indices: vec![1.0, 1.5, 1.333],
        },
        vec![CamParams {
            rotation: Matrix3::identity(),
            ..tank.cams[0].clone()
        }],
    );
    let camera = flat.camera(0);
    // Normalised x = −1 looks along (−1, 0, 1)/√2, exactly perpendicular to n = (1, 0, 1)/√2.
    let parallel = Point2::new(639.5 - 500.0, 511.5);
    let dir = flat.cams[0].dir_from_normalized(-1.0, 0.0);
    assert_eq!(flat.stack.normal.dot(&dir), 0.0);
    assert_eq!(flat.trace(0, &dir).map(|p| p.origin()), Err(Fail::Misses));
    for pixel in [parallel, Point2::new(0.0, 300.0)] {
        assert_eq!(
            camera.backproject(&pixel),
            Err(NoSolution::MissesInterface),
            "{pixel:?}"
        );
        assert_eq!(
            camera.backproject_traced(&pixel),
            Err(NoSolution::MissesInterface),
            "{pixel:?}"
        );
    }
    let along = Unit::new_normalize(Vector3::new(0.0, 1.0, 0.0));
    assert_eq!(
        camera.ray_in_water(&along),
        Err(NoSolution::MissesInterface)
    );
    assert_eq!(
        camera.trace_ray_in_water(&along),
        Err(NoSolution::MissesInterface)
    );
}

/// Agrawal et al. (CVPR 2012), one interface, in the plane of refraction: camera at the origin,
/// interface at distance d along the axis, the point at depth x beyond it and lateral distance r.
/// The ray meets the interface at lateral q, so
///   sin a = q / √(d² + q²),  sin θw = (r − q) / √(x² + (r − q)²),  μa sin a = μw sin θw.
/// Squared and multiplied out:  μa² q² (x² + (r − q)²) = μw² (r − q)² (d² + q²).
/// With A = μa² − μw², B = μa² x², D = μw² d², and q²(r − q)² = q⁴ − 2r q³ + r² q²:
///   A q⁴ − 2A r q³ + (A r² + B − D) q² + 2D r q − D r² = 0.
/// Returned in units of r (q̃ = q/r), lowest degree first.
fn agrawal_quartic(d: f64, x: f64, r: f64, mu_a: f64, mu_w: f64) -> [f64; 5] {
    let a = mu_a * mu_a - mu_w * mu_w;
    let b = mu_a * mu_a * (x / r) * (x / r);
    let dd = mu_w * mu_w * (d / r) * (d / r);
    [-dd, 2.0 * dd, a + b - dd, -2.0 * a, a]
}

fn polynomial(c: &[f64; 5], q: f64) -> (f64, f64) {
    let value = c.iter().rev().fold(0.0, |acc, &k| acc * q + k);
    let slope = c[1] + q * (2.0 * c[2] + q * (3.0 * c[3] + q * 4.0 * c[4]));
    (value, slope)
}

/// The physical root of the quartic: eigenvalues of the companion matrix, the real ones polished by
/// Newton on the polynomial, kept if in [0, 1] (units of r) and satisfying the unsquared equation.
fn agrawal_root(d: f64, x: f64, r: f64, mu_a: f64, mu_w: f64) -> f64 {
    let c = agrawal_quartic(d, x, r, mu_a, mu_w);
    let b: Vec<f64> = c.iter().map(|k| k / c[4]).collect();
    #[rustfmt::skip]
    let companion = Matrix4::new(
        0.0, 0.0, 0.0, -b[0],
        1.0, 0.0, 0.0, -b[1],
        0.0, 1.0, 0.0, -b[2],
        0.0, 0.0, 1.0, -b[3],
    );
    let (xt, dt) = (x / r, d / r);
    let unsquared = |q: f64| {
        mu_a * q * (xt * xt + (1.0 - q) * (1.0 - q)).sqrt()
            - mu_w * (1.0 - q) * (dt * dt + q * q).sqrt()
    };
    let mut roots = Vec::new();
    for z in companion.complex_eigenvalues().iter() {
        if z.im.abs() > 1e-6 * (1.0 + z.re.abs()) {
            continue;
        }
        let mut q = z.re;
        for _ in 0..8 {
            let (value, slope) = polynomial(&c, q);
            if slope == 0.0 {
                break;
            }
            q -= value / slope;
        }
        let scale = mu_a * q.abs() * (xt * xt + 1.0).sqrt() + mu_w * (dt * dt + 1.0).sqrt();
        if (-1e-12..=1.0 + 1e-12).contains(&q) && unsquared(q).abs() <= 1e-9 * scale {
            roots.push(q);
        }
    }
    assert_eq!(
        roots.len(),
        1,
        "d={d} x={x} r={r}: physical roots {roots:?}"
    );
    roots[0] * r
}

#[test]
fn single_interface_matches_agrawal_quartic() {
    let mut summary = Vec::new();
    for fixture in [fixture(Kind::Single, false), fixture(Kind::Single, true)] {
        let (mu_a, mu_w) = (fixture.stack.index_air(), fixture.stack.index_water());
        let n = fixture.stack.normal;
        for k in 0..2 {
            let camera = fixture.camera(k);
            let centre = fixture.cams[k].centre;
            let d = fixture.d_k(k);
            let (mut worst, mut worst_oracles, mut compared): (f64, f64, usize) = (0.0, 0.0, 0);
            for point in grid_points(&fixture, k) {
                let offset = point - centre;
                let z = n.dot(&offset);
                let lateral = offset - n * z;
                let r = lateral.norm();
                if r < 1e-9 {
                    continue; // on the axis line: a = 0, checked elsewhere
                }
                let q = agrawal_root(d, z - d, r, mu_a, mu_w);
                let dir = n * d + lateral * (q / r);
                let Some(oracle) = pixel_from_dir(&fixture.cams[k], &dir) else {
                    continue;
                };
                if !fixture.cams[k].in_image(&oracle, 0.0) {
                    continue;
                }
                let model = camera.project(&point).expect("in front of the camera");
                worst = worst.max((model - oracle).norm());
                // The two oracles agree with each other too.
                worst_oracles =
                    worst_oracles.max((fixture.project(k, &point).unwrap() - oracle).norm());
                compared += 1;
            }
            summary.push(format!("  {:18} cam {k}: {worst:.1e} px (oracles differ by {worst_oracles:.1e} px) over {compared}", fixture.name));
            assert!(compared >= 50, "{compared}");
            assert!(
                worst <= PIXEL_TOL && worst_oracles <= PIXEL_TOL,
                "{} cam {k}: {worst}, {worst_oracles}",
                fixture.name
            );
        }
    }
    println!(
        "forward projection vs Agrawal's quartic (max |Δpixel|):\n{}",
        summary.join("\n")
    );
}

/// f(τ) = d_k τ + Σ tᵢ tan θᵢ + x tan θw − r with sin θₘ = (μa/μₘ) sin a, tan a = τ (DESIGN.md's
/// equation written in τ), and f′(τ), evaluated here from scratch.
fn design_equation(tau: f64, d_k: f64, depth: f64, r: f64, stack: &Stack) -> (f64, f64) {
    let sin_a = tau / (1.0 + tau * tau).sqrt();
    let dsin_dtau = 1.0 / (1.0 + tau * tau).powf(1.5);
    let mut f = d_k * tau - r;
    let mut df = d_k;
    let lengths = stack
        .thicknesses
        .iter()
        .copied()
        .chain(std::iter::once(depth));
    for (length, mu) in lengths.zip(&stack.indices[1..]) {
        let s = stack.index_air() / mu * sin_a;
        let c = (1.0 - s * s).sqrt();
        f += length * s / c;
        // d tan θ / d sin a = (μa/μ) / cos³ θ.
        df += length * stack.index_air() / mu / (c * c * c) * dsin_dtau;
    }
    (f, df)
}

/// Iteration counts of the forward projection over random points: depth 0.2–5 m beyond the outer
/// interface (one in eight only 0.1 mm beyond it), lateral offset ≤ 1 m from the camera's axis line,
/// every configuration and camera. Returns (all counts, counts of points whose pixel is in the image),
/// and checks on the way that the converged τ solves DESIGN.md's equation (see below).
fn newton_statistics(kinds: &[Kind]) -> (Vec<u32>, Vec<u32>) {
    let mut rng = Rng::new(2012);
    let (mut all, mut in_image) = (Vec::new(), Vec::new());
    let (mut worst_backward, mut worst_relative_r): (f64, f64) = (0.0, 0.0);
    let fixtures = kinds
        .iter()
        .flat_map(|&kind| [fixture(kind, false), fixture(kind, true)]);
    for fixture in fixtures {
        let n = fixture.stack.normal;
        let (u, v) = lateral_basis(&n);
        for k in 0..2 {
            let camera: RefractiveCamera = fixture.camera(k);
            let centre = fixture.cams[k].centre;
            let outer = fixture.d_k(k) + fixture.stack.layers_thickness();
            for sample in 0..160 {
                let depth = if sample % 8 == 0 {
                    1e-4
                } else {
                    rng.uniform(0.2, 5.0)
                };
                let (radius, phi) = (
                    rng.uniform(0.0, 1.0),
                    rng.uniform(0.0, std::f64::consts::TAU),
                );
                let point = centre + n * (outer + depth) + (u * phi.cos() + v * phi.sin()) * radius;
                let path = camera.air_path_to(&point).expect("point in the water");
                all.push(path.iterations);
                let pixel = pixel_from_dir(&fixture.cams[k], &path.dir_in_air.into_inner());
                if pixel.is_some_and(|p| fixture.cams[k].in_image(&p, 0.0)) {
                    in_image.push(path.iterations);
                }
                let offset = point - centre;
                let r = (offset - n * n.dot(&offset)).norm();
                let x = fixture.stack.depth(&centre, &point);
                let (f, df) =
                    design_equation(path.tan_incidence, fixture.d_k(k), x, r, &fixture.stack);
                // Backward error: the relative change of τ that cancels f, |f| / (τ f′(τ)). (|f|/r
                // itself is ill-conditioned where the water ray grazes and f′ → ∞.)
                worst_backward = worst_backward.max((f / (path.tan_incidence * df)).abs());
                worst_relative_r = worst_relative_r.max((f / r).abs());
            }
        }
    }
    println!(
        "converged τ: max |f|/(τ f′) = {worst_backward:.1e}, max |f|/r = {worst_relative_r:.1e}"
    );
    // Issue: the converged τ satisfies the equation to 1e-12 relative.
    assert!(worst_backward <= 1e-12, "{worst_backward}");
    (all, in_image)
}

fn median_max(mut counts: Vec<u32>, what: &str) -> (u32, u32) {
    counts.sort_unstable();
    let (median, max) = (counts[counts.len() / 2], *counts.last().unwrap());
    let p99 = counts[counts.len() * 99 / 100];
    println!(
        "Newton iterations, {what} ({} points): median {median}, 99th percentile {p99}, max {max}",
        counts.len()
    );
    (median, max)
}

/// The configurations of the issue (single interface, one to three layers, the tank), points whose
/// pixel lies inside the image.
#[test]
fn newton_iterations_in_view() {
    let kinds = [
        Kind::Single,
        Kind::OneGlass,
        Kind::TwoLayers,
        Kind::ThreeLayers,
        Kind::Tank,
    ];
    let (all, in_image) = newton_statistics(&kinds);
    median_max(all, "issue's configurations, all points");
    let (median, max) = median_max(in_image, "issue's configurations, pixel inside the image");
    // Issue: max ≤ 8, median ≤ 5 (stopping at relative step 1e-13).
    assert!(median <= 5 && max <= 8, "median {median}, max {max}");
}

/// Over the whole random domain, including air rays at 70–86° incidence (outside any image here)
/// and points 0.1 mm behind the port of the immersed rig, where the water ray grazes the interface
/// near the critical angle. Measured: median 3, 99th percentile 7, max 9 (was 12 before the solver
/// re-parametrised in the slowest medium when a step left through its critical angle).
#[test]
fn newton_iterations_everywhere() {
    let (all, in_image) = newton_statistics(&Kind::ALL);
    median_max(in_image, "every configuration, pixel inside the image");
    let (median, max) = median_max(all, "every configuration, all points");
    assert!(median <= 4 && max <= 10, "median {median}, max {max}");
}
