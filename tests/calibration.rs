//! Calibration of a shared flat refractive stereo system on simulated scenes with known truth:
//! exactness without noise, the issue's accuracy targets from a naive start, the reported
//! standard deviations against the spread over repeated scenes, the simulator against an
//! independent tracer, robustness to outliers.

mod common;

use flatport::calib::costs::scene::air_distance_for_axis;
use flatport::calib::{
    Board, Calibration, Candidate, CostBackend, CostKind, CpuBackend, Method, Options, Scene,
    SceneSpec, StereoData, Target, calibrate, simulate,
};
use flatport::io::rig_from_json_str;
use flatport::model::{Rig, normal_from_tilt_azimuth};
use nalgebra::{Point2, Vector3};

const EXAMPLE_RIG: &str = include_str!("../data/example_rig.json");

/// The example rig (distorted lenses, 6 cm baseline, 14 mm glass) behind an axis of the given tilt
/// and azimuth (degrees) and a 20 mm air layer.
fn rig(tilt_deg: f64, azimuth_deg: f64) -> Rig {
    let base = rig_from_json_str(EXAMPLE_RIG, "example".as_ref()).unwrap();
    let n = normal_from_tilt_azimuth(tilt_deg.to_radians(), azimuth_deg.to_radians());
    base.with_interface(
        base.shared_interface()
            .unwrap()
            .with_pose(n.into_inner(), 0.02)
            .unwrap(),
    )
    .unwrap()
}

/// The issue's naive start: the axis on the camera's z axis, a 10 mm air layer.
fn naive(rig: &Rig) -> Rig {
    rig.with_interface(
        rig.shared_interface()
            .unwrap()
            .with_pose(Vector3::z(), 0.01)
            .unwrap(),
    )
    .unwrap()
}

fn board() -> Board {
    Board {
        rows: 6,
        cols: 9,
        square: 0.04,
    }
}

/// A stereo scene of the board seen whole by cameras 0 and 1, as `flatport simulate` draws it.
fn scene(truth: &Rig, views: usize, noise: f64, seed: u64) -> Scene {
    simulate(
        truth,
        &SceneSpec::pair(Target::Board(board()), views, noise, seed, 0, 1),
    )
    .unwrap()
}

/// Simulates with `truth`, calibrates from the naive start; returns (axis error °, air error m).
fn run(
    truth: &Rig,
    views: usize,
    noise: f64,
    seed: u64,
    method: Method,
) -> (f64, f64, Calibration) {
    let scene = scene(truth, views, noise, seed);
    let start = naive(truth);
    let calibration = calibrate(
        &start,
        &scene.observations,
        &Options {
            method,
            ..Default::default()
        },
    )
    .unwrap();
    let port = calibration.rig.shared_interface().unwrap();
    let axis = port
        .normal()
        .angle(truth.shared_interface().unwrap().normal())
        .to_degrees();
    let air = port.air_distance() - truth.shared_interface().unwrap().air_distance();
    (axis, air, calibration)
}

#[test]
fn noise_free_scenes_come_back_exactly() {
    // The issue: within 1e-5° and 1e-7 m. The maximum-likelihood fit reaches rounding; the
    // consecutive method stops its axis refinement at a 1e-9 rad stencil.
    for (tilt, azimuth, seed) in [
        (8.0, 45.0, 1),
        (15.0, -120.0, 2),
        (0.0, 0.0, 3),
        (25.0, 170.0, 4),
    ] {
        let truth = rig(tilt, azimuth);
        for method in [Method::Auto, Method::Simultaneous, Method::Consecutive] {
            let (axis, air, c) = run(&truth, 10, 0.0, seed, method);
            println!(
                "tilt {tilt}° azimuth {azimuth}° {method:?}: axis {axis:.2e}°, air {air:.2e} m, RMS {:?} px",
                c.report
                    .cameras
                    .iter()
                    .map(|c| c.rms_px)
                    .collect::<Vec<_>>()
            );
            assert!(axis < 1e-5, "{method:?} tilt {tilt}: axis off by {axis}°");
            assert!(
                air.abs() < 1e-7,
                "{method:?} tilt {tilt}: air layer off by {air} m"
            );
            assert!(
                c.report.cameras.iter().all(|c| c.rms_px < 1e-6),
                "{:?}",
                c.report.cameras
            );
        }
    }
}

#[test]
fn issue_targets_from_the_naive_start() {
    // The issue's held-out settings: 15 views, 9×6, 0.125 px, 8° tilt, 20 mm air, 14 mm glass →
    // within 0.06° and 1.5 mm; 15° tilt, 20 views, 0.25 px → within 0.12° and 3 mm. Azimuths and
    // seeds vary; the reported σ of the maximum-likelihood fit is about 0.02° and 0.3 mm here.
    let mut worst = [0.0f64; 4];
    for seed in 1..=5 {
        let (axis, air, c) = run(
            &rig(8.0, 45.0 + 60.0 * seed as f64),
            15,
            0.125,
            100 + seed,
            Method::Auto,
        );
        println!(
            "8°, seed {seed}: axis {axis:.4}°, air {:.3} mm, {:.2} s",
            air * 1e3,
            c.report.seconds
        );
        worst[0] = worst[0].max(axis);
        worst[1] = worst[1].max(air.abs());
        let (axis, air, c) = run(
            &rig(15.0, -30.0 - 50.0 * seed as f64),
            20,
            0.25,
            200 + seed,
            Method::Auto,
        );
        println!(
            "15°, seed {seed}: axis {axis:.4}°, air {:.3} mm, {:.2} s",
            air * 1e3,
            c.report.seconds
        );
        worst[2] = worst[2].max(axis);
        worst[3] = worst[3].max(air.abs());
    }
    assert!(worst[0] < 0.06 && worst[1] < 1.5e-3, "8° scenes: {worst:?}");
    assert!(worst[2] < 0.12 && worst[3] < 3e-3, "15° scenes: {worst:?}");
}

#[test]
fn reported_standard_deviations_match_the_spread_over_scenes() {
    // 24 scenes of one geometry (the poses vary with the seed): the RMS error of each parameter
    // against the mean reported σ. For 24 Gaussian errors the ratio lies in [0.7, 1.3] with
    // probability > 0.95; the poses differ per seed, so allow [0.5, 2].
    let truth = rig(10.0, 30.0);
    let (mut sq, mut std) = ([0.0; 3], [0.0; 3]);
    let trials = 24;
    for seed in 0..trials {
        // Auto: maximum likelihood from several starts. From the consecutive start alone none of
        // these 24 scenes ends in a local minimum (σ̂ 0.244–0.259 px; before the LM damping was
        // put in plain units, 2 stopped early at σ̂ 0.35–0.38 px).
        let (_, air, c) = run(&truth, 12, 0.25, 300 + seed, Method::Auto);
        let port = c.report.port();
        let s = [port.tilt.std, port.azimuth.std, port.distance.std]
            .map(|s| s.expect("maximum likelihood gives standard deviations"));
        let found = Candidate::of(c.rig.shared_interface().unwrap());
        let t = Candidate::of(truth.shared_interface().unwrap());
        let d_azimuth = (found.azimuth() - t.azimuth() + std::f64::consts::PI)
            .rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        for (k, e) in [found.tilt() - t.tilt(), d_azimuth, air]
            .into_iter()
            .enumerate()
        {
            sq[k] += e * e;
            std[k] += s[k];
        }
    }
    for k in 0..3 {
        let ratio = (sq[k] / trials as f64).sqrt() / (std[k] / trials as f64);
        println!("parameter {k}: RMS error / mean σ = {ratio:.3}");
        assert!((0.5..2.0).contains(&ratio), "parameter {k}: ratio {ratio}");
    }
}

#[test]
fn simulated_corners_agree_with_an_independent_tracer() {
    // Trace each simulated pixel through the planes (Snell in angle form, tests/common) and check
    // that the ray in the water passes through the true corner.
    let truth = rig(12.0, 80.0);
    let scene = scene(&truth, 6, 0.0, 9);
    let mut worst: f64 = 0.0;
    for (v, view) in scene.observations.views.iter().enumerate() {
        for (k, corners) in view.images.iter().map(|i| &i.corners).enumerate() {
            let stack = common::Stack::of(&truth, k);
            for (i, pixel) in corners.iter().enumerate() {
                let pixel: Point2<f64> = pixel.unwrap();
                let corner = scene.master_from_target[v] * board().point_in_board(i);
                let (origin, dir, _) =
                    common::trace(&stack, common::dir_of_pixel(&stack, pixel)).unwrap();
                let miss = (corner.coords - origin).cross(&dir).norm();
                worst = worst.max(miss);
                assert!(
                    common::in_image(&stack, &pixel, 0.0),
                    "view {v} camera {k} corner {i}: {pixel}"
                );
            }
        }
    }
    println!("largest distance of a true corner from its traced ray: {worst:.2e} m");
    assert!(worst < 1e-9, "{worst}");
}

#[test]
fn costs_vanish_at_the_truth_and_the_linear_air_layer_is_exact() {
    let truth = rig(8.0, 45.0);
    let scene = scene(&truth, 8, 0.0, 5);
    let data = StereoData::from_observations(&naive(&truth), [0, 1], &scene.observations).unwrap();
    let backend = CpuBackend::new(&data);
    let at_truth = Candidate::of(truth.shared_interface().unwrap());
    let off = Candidate {
        normal: normal_from_tilt_azimuth(9f64.to_radians(), 45f64.to_radians()),
        air_distance: 0.02,
    };
    for kind in CostKind::ALL {
        let costs = backend.costs(kind, &[at_truth, off]).unwrap();
        println!(
            "{}: {:.2e} at the truth, {:.2e} 1° off ({})",
            kind.name(),
            costs[0],
            costs[1],
            kind.unit()
        );
        assert!(
            costs[1] > 1e3 * costs[0].max(1e-16),
            "{}: {costs:?}",
            kind.name()
        );
    }
    let (d, gap) =
        air_distance_for_axis(&data, truth.shared_interface().unwrap().normal()).unwrap();
    assert!((d - 0.02).abs() < 1e-10 && gap < 1e-10, "{d} {gap}");
}

#[test]
fn huber_loss_withstands_outlier_corners_and_they_are_reported() {
    let truth = rig(8.0, 45.0);
    let mut scene = scene(&truth, 15, 0.125, 11);
    // Five gross detection errors of 15–25 px.
    for (k, (v, i)) in [(0, 3), (2, 17), (5, 40), (9, 8), (12, 50)]
        .into_iter()
        .enumerate()
    {
        let p = scene.observations.views[v].images[0].corners[i]
            .as_mut()
            .unwrap();
        p.x += 15.0 + 2.5 * k as f64;
        p.y -= 10.0;
    }
    let options = Options {
        huber: Some(0.5),
        ..Default::default()
    };
    let c = calibrate(&naive(&truth), &scene.observations, &options).unwrap();
    let port = c.rig.shared_interface().unwrap();
    let axis = port
        .normal()
        .angle(truth.shared_interface().unwrap().normal())
        .to_degrees();
    let air = port.air_distance() - 0.02;
    println!(
        "with Huber: axis {axis:.4}°, air {:.3} mm; outliers {:?}",
        air * 1e3,
        c.report.outliers
    );
    assert!(axis < 0.1 && air.abs() < 2e-3, "{axis} {air}");
    let flagged: Vec<(usize, usize)> = c
        .report
        .outliers
        .iter()
        .map(|o| (o.view, o.corner))
        .collect();
    for expected in [(0, 3), (2, 17), (5, 40), (9, 8), (12, 50)] {
        assert!(
            flagged.contains(&expected),
            "{expected:?} not in {flagged:?}"
        );
    }
    assert!(
        c.report.warnings.iter().any(|w| w.contains("5 corner(s)")),
        "{:?}",
        c.report.warnings
    );
}
