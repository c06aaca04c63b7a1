//! Issue 47: the report's advice is right. A one-camera housing is filmed on purpose badly (every
//! view of the board facing the camera, at one distance); the advice, from the fit's information
//! matrix, must name the parameter that is poorly determined and a view; that view rendered
//! (its corners projected through the true rig, with the same noise) and added must lower the
//! named parameter's σ by at least 2×, as the advice predicted.
//!
//! Measured (seed 47; seeds 1 and 2 alike): σ of the air distance 2.72 mm with 12 frontal views
//! at 0.9 m; advised: the board 0.54 m away, tilted 35°, in the image's centre, predicted
//! 1.089 mm; rendered, added and calibrated again: 1.087 mm (2.5× lower). At 0.7 m the same
//! design step gives only 2.0–2.4×, too close to the bound to test on.

use flatport::calib::pipeline::report::Report;
use flatport::calib::problem::board::Board;
use flatport::calib::simulate::rng::Rng;
use flatport::calib::{CameraKey, Image, Observations, Options, Target, View, calibrate};
use flatport::model::{Ports, Rig};
use flatport::report::{Input, advice::Advice, write_report};
use nalgebra::{Isometry3, Point2, Point3, Translation3, UnitQuaternion, Vector3};

const NOISE_PX: f64 = 0.125;

fn truth() -> Rig {
    flatport::io::read_rig(std::path::Path::new("data/rigs/single_housing.json")).unwrap()
}

/// The truth's cameras behind the naive port (axis on the camera's z, 10 mm of air).
fn start(truth: &Rig) -> Rig {
    let port = truth.port_in_master(0);
    let naive = port.with_pose(Vector3::z(), 0.010).unwrap();
    let ports = match truth.ports() {
        Ports::Shared(_) => Ports::Shared(naive),
        Ports::PerCamera(_) => Ports::PerCamera(vec![naive]),
    };
    truth.with_new_ports(ports).unwrap()
}

/// The board's corners at `pose` through the true rig with Gaussian noise, as one view; `None`
/// when a corner leaves the image.
fn render_view(truth: &Rig, target: &Target, pose: &Isometry3<f64>, rng: &mut Rng) -> Option<View> {
    let camera = truth.refractive_camera(0);
    let intrinsics = &truth.cameras()[0].intrinsics;
    let corners = (0..target.len())
        .map(|i| {
            let p = camera.project(&(pose * target.point(i))).ok()?;
            let inside = p.x > 5.0
                && p.y > 5.0
                && p.x < f64::from(intrinsics.width) - 5.0
                && p.y < f64::from(intrinsics.height) - 5.0;
            inside.then(|| {
                Some(Point2::new(
                    p.x + NOISE_PX * rng.normal(),
                    p.y + NOISE_PX * rng.normal(),
                ))
            })
        })
        .collect::<Option<Vec<_>>>()?;
    Some(View {
        images: vec![Image {
            camera: CameraKey::Name(truth.cameras()[0].name.clone()),
            key: truth.cameras()[0].name.clone(),
            corners,
        }],
    })
}

/// Views of the board facing the camera at `distance` m, its centre moved over the image.
fn frontal_views(truth: &Rig, target: &Target, distance: f64, rng: &mut Rng) -> Vec<View> {
    let centre = Point3::new(0.5 * 8.0 * 0.04, 0.5 * 5.0 * 0.04, 0.0);
    let mut views = Vec::new();
    for (x, y) in [
        (0.0, 0.0),
        (-0.25, -0.2),
        (0.25, -0.2),
        (-0.25, 0.2),
        (0.25, 0.2),
        (0.0, -0.22),
        (0.0, 0.22),
        (-0.3, 0.0),
        (0.3, 0.0),
        (0.12, 0.1),
        (-0.12, -0.1),
        (0.15, -0.12),
    ] {
        // A small in-plane turn so no two views are alike.
        let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.3 * x);
        let at = Vector3::new(0.45 * x * distance, 0.45 * y * distance, distance);
        let pose = Isometry3::from_parts(Translation3::from(at - turn * centre.coords), turn);
        if let Some(view) = render_view(truth, target, &pose, rng) {
            views.push(view);
        }
    }
    views
}

/// The calibration of `views` from the naive start, its report and the advice on it.
fn calibrate_and_advise(truth: &Rig, target: &Target, views: &[View]) -> (Report, Advice) {
    let observations = Observations {
        target: target.clone(),
        views: views.to_vec(),
        stereo_form: false,
    };
    let calibration = calibrate(&start(truth), &observations, &Options::default()).unwrap();
    let input = Input::from_observations(
        "test",
        &calibration.rig,
        &calibration.report,
        &observations,
        None,
    );
    let dir = tempfile::tempdir().unwrap();
    let written = write_report(dir.path(), &input).unwrap();
    let index = std::fs::read_to_string(&written.index).unwrap();
    let advice = written.advice.expect("an observations route gives advice");
    for line in &advice.text {
        assert!(
            index.contains(
                &line
                    .replace('&', "&amp;")
                    .replace('<', "&lt;")
                    .replace('>', "&gt;")
            ),
            "the page shows the advice: {line}"
        );
    }
    (calibration.report, advice)
}

fn sigma_of(advice: &Advice, name: &str) -> f64 {
    advice
        .parameters
        .iter()
        .find(|p| p.name == name)
        .unwrap_or_else(|| panic!("{name} in {:?}", advice.parameters))
        .sigma
}

#[test]
fn the_advised_view_halves_the_sigma_of_the_parameter_it_names() {
    let truth = truth();
    let target = Target::Board(Board {
        rows: 6,
        cols: 9,
        square: 0.04,
    });
    let mut rng = Rng::new(47);
    // Every view facing the camera at 0.9 m: nothing separates the air layer from the board's
    // distance.
    let mut views = frontal_views(&truth, &target, 0.9, &mut rng);
    assert!(views.len() >= 10, "{} views", views.len());
    let (report, advice) = calibrate_and_advise(&truth, &target, &views);
    for line in &advice.text {
        eprintln!("advice: {line}");
    }
    let worst = &advice.parameters[advice.worst.expect("a worst parameter")];
    eprintln!(
        "worst: {} σ {:.4} {} (tolerance {:.4}); report: air σ {:?} m, tilt σ {:?} rad",
        worst.name,
        worst.sigma * worst.scale,
        worst.unit,
        worst.tolerance * worst.scale,
        report.ports[0].distance.std,
        report.ports[0].tilt.std
    );
    // The poorly determined parameter is the air distance, and the advice says so.
    assert!(worst.name.contains("air distance"), "{}", worst.name);
    assert!(
        advice.text[0].contains("air distance"),
        "the advice names it: {}",
        advice.text[0]
    );
    let (view, predicted, _) = advice.best.clone().expect("a view advised");
    assert!(
        advice.text[1].contains(" m from camera cam"),
        "{}",
        advice.text[1]
    );
    assert!(advice.text[1].contains(&view.place()), "{}", advice.text[1]);
    eprintln!(
        "advised: {:.2} m, {}, {} (predicted σ after one view {:.4} mm)",
        view.distance_m,
        view.tilt_words(),
        view.place(),
        predicted * 1e3
    );
    // The report's own σ agrees with the advice's (the same information matrix).
    let reported = report.ports[0].distance.std.expect("a σ of the air layer");
    assert!(
        (reported / worst.sigma - 1.0).abs() < 0.05,
        "report {reported}, advice {}",
        worst.sigma
    );
    // The advised view, rendered through the true rig, added.
    let rendered = render_view(&truth, &target, &view.master_from_target, &mut rng)
        .expect("the advised view fits the image");
    views.push(rendered);
    let (after_report, after) = calibrate_and_advise(&truth, &target, &views);
    let sigma_after = sigma_of(&after, &worst.name);
    let reported_after = after_report.ports[0].distance.std.unwrap();
    eprintln!(
        "σ of the {}: {:.4} → {:.4} mm (predicted {:.4}); the report's {:.4} → {:.4} mm",
        worst.name,
        worst.sigma * 1e3,
        sigma_after * 1e3,
        predicted * 1e3,
        reported * 1e3,
        reported_after * 1e3
    );
    assert!(
        sigma_after <= 0.5 * worst.sigma,
        "σ {} → {}",
        worst.sigma,
        sigma_after
    );
    assert!(
        reported_after <= 0.5 * reported,
        "report σ {reported} → {reported_after}"
    );
    // The prediction from the fit's information matrix holds to within 10 % (the re-fit moves
    // the rig and σ̂ a little; 0.2 % at this seed, 1 % at seeds 1 and 2).
    assert!(
        (sigma_after / predicted - 1.0).abs() < 0.1,
        "predicted {predicted}, got {sigma_after}"
    );
}
