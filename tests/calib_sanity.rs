//! Confident wrong answers (issue 14, item 5): repeated views and too few distinct poses are
//! refused, gross corner errors are found and reported by every method (the consecutive one
//! included), and when nothing fits the error or the report says what the data look like (swapped
//! images, a reversed corner order, a wrong square), naming the observations file, with clean
//! numbers; a result whose RMS is above `--max-rms-px` writes the report but not the rig.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use flatport::calib::simulate::rng::Rng;
use flatport::calib::{
    Board, CalibError, Method, Observations, Options, SceneSpec, Target, View, calibrate, simulate,
};
use flatport::io::{rig_from_json_str, write_stereo_observations};
use flatport::model::{Rig, normal_from_tilt_azimuth};
use nalgebra::{Point2, Vector3};
use serde_json::Value;

const EXAMPLE_RIG: &str = include_str!("../data/example_rig.json");

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

fn observations(truth: &Rig, views: usize, noise: f64, seed: u64) -> Observations {
    simulate(
        truth,
        &SceneSpec::pair(Target::Board(board()), views, noise, seed, 0, 1),
    )
    .unwrap()
    .observations
}

/// The corners of the left (0) or the right (1) image of a stereo view.
fn image(view: &mut View, side: usize) -> &mut Vec<Option<Point2<f64>>> {
    &mut view.images[side].corners
}

/// Exchanges the corner lists of a stereo view's two images (the keys stay).
fn swap_images(view: &mut View) {
    let [left, right] = view.images.as_mut_slice() else {
        unreachable!("a stereo view has two images")
    };
    std::mem::swap(&mut left.corners, &mut right.corners);
}

fn run(
    truth: &Rig,
    observations: &Observations,
    method: Method,
) -> Result<flatport::calib::Calibration, CalibError> {
    calibrate(
        &naive(truth),
        observations,
        &Options {
            method,
            ..Default::default()
        },
    )
}

fn flatport(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(args)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .expect("binary runs")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// Writes `observations` and a naive start rig into `dir`; returns (start rig, observations file).
fn files(dir: &Path, observations: &Observations) -> (PathBuf, PathBuf) {
    let start = dir.join("start.json");
    let mut rig: Value = serde_json::from_str(EXAMPLE_RIG).unwrap();
    rig["interface"]["normal"] = serde_json::json!([0, 0, 1]);
    rig["interface"]["distance"] = serde_json::json!(0.01);
    std::fs::write(&start, rig.to_string()).unwrap();
    let path = dir.join("observations.json");
    write_stereo_observations(&path, observations).unwrap();
    (start, path)
}

fn cli_calibrate(start: &Path, observations: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "calibrate",
        "--rig",
        p(start),
        "--observations",
        p(observations),
        "--output",
        p(out),
        "--device",
        "cpu",
    ];
    args.extend_from_slice(extra);
    flatport(&args)
}

#[test]
fn fifteen_copies_of_one_view_are_refused_naming_the_views() {
    // The issue: 15 copies of one view calibrated with exit 0 and an air layer 5.6 σ off.
    let truth = rig(8.0, 45.0);
    let one = observations(&truth, 15, 0.125, 3);
    let mut copies = one.clone();
    copies.views = vec![one.views[0].clone(); 15];
    let error = run(&truth, &copies, Method::Auto).unwrap_err();
    assert!(
        matches!(
            error,
            CalibError::RepeatedView {
                view: 1,
                earlier: 0,
                more: 13,
                ..
            }
        ),
        "{error:?}"
    );

    let dir = tempfile::tempdir().unwrap();
    let (start, path) = files(dir.path(), &copies);
    let out = dir.path().join("out.json");
    let result = cli_calibrate(&start, &path, &out, &[]);
    let stderr = text(&result.stderr);
    assert!(!result.status.success(), "{}", text(&result.stdout));
    assert!(
        stderr.contains(p(&path))
            && stderr.contains("views[1] repeats views[0]")
            && stderr.contains("13 more"),
        "{stderr}"
    );
    assert!(!out.exists());

    // One repeated view among distinct ones is named by both indices.
    let mut repeated = one.clone();
    repeated.views[11] = one.views[4].clone();
    let error = run(&truth, &repeated, Method::Auto).unwrap_err();
    assert!(
        error.to_string().starts_with("views[11] repeats views[4]"),
        "{error}"
    );
    let (start, path) = files(dir.path(), &repeated);
    let stderr = text(&cli_calibrate(&start, &path, &out, &[]).stderr);
    assert!(
        stderr.contains("views[11]: views[11] repeats views[4]"),
        "{stderr}"
    );
}

#[test]
fn views_of_one_pose_do_not_constrain_the_calibration() {
    // Fifteen detections of one board pose, each with its own 0.125 px of noise: not copies, but
    // one pose, from which neither the axis nor the air layer can be calibrated.
    let truth = rig(8.0, 45.0);
    let exact = observations(&truth, 3, 0.0, 4);
    let mut rng = Rng::new(9);
    let mut redetected = exact.clone();
    redetected.views = (0..15)
        .map(|_| {
            let mut view = exact.views[0].clone();
            for c in view
                .images
                .iter_mut()
                .flat_map(|i| i.corners.iter_mut())
                .flatten()
            {
                *c = Point2::new(c.x + 0.125 * rng.normal(), c.y + 0.125 * rng.normal());
            }
            view
        })
        .collect();
    let error = run(&truth, &redetected, Method::Auto).unwrap_err();
    println!("{error}");
    assert!(
        matches!(
            error,
            CalibError::TooFewPoses {
                views: 15,
                distinct: 1,
                needed: 3,
                ..
            }
        ),
        "{error:?}"
    );
    assert!(
        error
            .to_string()
            .contains("only 1 distinct board pose(s) (views 0–14 within"),
        "{error}"
    );

    // Two poses among them: still too few; the CLI names the file and exits non-zero.
    redetected.views[7] = exact.views[1].clone();
    let error = run(&truth, &redetected, Method::Consecutive).unwrap_err();
    assert!(
        matches!(error, CalibError::TooFewPoses { distinct: 2, .. }),
        "{error:?}"
    );
    let dir = tempfile::tempdir().unwrap();
    let (start, path) = files(dir.path(), &redetected);
    let result = cli_calibrate(&start, &path, &dir.path().join("out.json"), &[]);
    let stderr = text(&result.stderr);
    assert!(!result.status.success());
    assert!(
        stderr.contains(p(&path))
            && stderr.contains("only 2 distinct board pose(s) (views 0–6, 8–14 within"),
        "{stderr}"
    );
}

/// Five 50-px detection errors, in both cameras' images.
const GROSS: [(usize, usize, usize); 5] =
    [(0, 3, 0), (2, 17, 1), (5, 40, 0), (9, 8, 1), (12, 50, 0)];

fn with_gross_errors(observations: &Observations) -> Observations {
    let mut spoilt = observations.clone();
    for (k, &(v, i, side)) in GROSS.iter().enumerate() {
        let c = image(&mut spoilt.views[v], side)[i].as_mut().unwrap();
        // 50 px in varied directions.
        let angle = 1.3 * k as f64;
        c.x = (c.x + 50.0 * angle.cos()).clamp(0.0, 1279.0);
        c.y = (c.y + 50.0 * angle.sin()).clamp(0.0, 1023.0);
    }
    spoilt
}

#[test]
fn the_consecutive_method_withstands_gross_outliers_and_reports_them() {
    // The issue: `--method consecutive` with five 50-px outliers ended 37° off and reported none.
    for (tilt, azimuth, seed) in [(8.0, 45.0, 11), (15.0, -120.0, 12), (3.0, 100.0, 13)] {
        let truth = rig(tilt, azimuth);
        let clean = observations(&truth, 15, 0.125, seed);
        let reference = run(&truth, &clean, Method::Consecutive).unwrap();
        let calibration = run(&truth, &with_gross_errors(&clean), Method::Consecutive).unwrap();
        let port = calibration.rig.shared_interface().unwrap();
        let reference_port = reference.rig.shared_interface().unwrap();
        let axis = port
            .normal()
            .angle(truth.shared_interface().unwrap().normal())
            .to_degrees();
        let from_clean = port.normal().angle(reference_port.normal()).to_degrees();
        let air = port.air_distance() - 0.02;
        println!(
            "tilt {tilt}°: axis {axis:.4}° off (clean data {:.4}°, the two {from_clean:.5}° apart), air {:.3} mm",
            reference_port
                .normal()
                .angle(truth.shared_interface().unwrap().normal())
                .to_degrees(),
            air * 1e3
        );
        // The consecutive method's own error on such scenes reaches 0.19° (tilt 15°, clean
        // data); its result moves by less than 0.02° when the gross errors are added (measured
        // 0.001-0.005°). Before the screening it ended 8-37° off.
        assert!(
            axis < 0.3 && from_clean < 0.02 && air.abs() < 3e-3,
            "tilt {tilt}: {axis}° ({from_clean}° from clean), {air} m"
        );
        let report = &calibration.report;
        for &(v, i, side) in &GROSS {
            let side = ["left", "right"][side];
            let found = report
                .outliers
                .iter()
                .find(|o| o.view == v && o.corner == i && o.image == side);
            let found =
                found.unwrap_or_else(|| panic!("({v}, {i}, {side}) not in {:?}", report.outliers));
            assert!(
                (found.residual_px - 50.0).abs() < 5.0 && found.screened,
                "{found:?}"
            );
            assert_eq!(found.camera, side);
        }
        assert_eq!(report.outliers.len(), 5, "{:?}", report.outliers);
        assert!(
            report
                .warnings
                .iter()
                .any(|w| w.starts_with("5 corner(s) have residuals far above the rest")),
            "{:?}",
            report.warnings
        );
        // Not a fit of the images: the consecutive result leaves 0.1-0.45 px (measured) at 0.125 px
        // of noise.
        assert!(
            report.fits && report.cameras.iter().all(|c| c.inlier_rms_px < 1.0),
            "{:?}",
            report.cameras
        );
    }
}

#[test]
fn the_cli_lists_the_outliers_of_the_consecutive_method() {
    let truth = rig(8.0, 45.0);
    let spoilt = with_gross_errors(&observations(&truth, 15, 0.125, 11));
    let dir = tempfile::tempdir().unwrap();
    let (start, path) = files(dir.path(), &spoilt);
    let (out, report) = (dir.path().join("out.json"), dir.path().join("report.json"));
    let result = cli_calibrate(
        &start,
        &path,
        &out,
        &["--method", "consecutive", "--report", p(&report)],
    );
    let stdout = text(&result.stdout);
    assert!(result.status.success(), "{}", text(&result.stderr));
    assert!(
        stdout.contains("5 outlier corner(s)")
            && stdout.contains("view 2, right image (right), corner 17:"),
        "{stdout}"
    );
    let report: Value = serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    let outliers = report["outliers"].as_array().unwrap();
    assert_eq!(outliers.len(), 5, "{outliers:?}");
    assert!(
        outliers.iter().any(|o| o["view"] == 9
            && o["corner"] == 8
            && o["image"] == "right"
            && o["camera"] == "right"),
        "{outliers:?}"
    );
    assert_eq!(report["fits"], true);
    assert!(out.exists());
}

#[test]
fn swapped_images_are_named_with_the_file_and_clean_numbers() {
    // The issue: swapped left/right images ended in "no candidate axis within a tilt of
    // 29.999999999999996° …" naming neither the file nor the likely swap.
    let truth = rig(8.0, 45.0);
    let mut swapped = observations(&truth, 12, 0.125, 21);
    for view in &mut swapped.views {
        swap_images(view);
    }
    let dir = tempfile::tempdir().unwrap();
    let (start, path) = files(dir.path(), &swapped);
    let out = dir.path().join("out.json");
    let result = cli_calibrate(&start, &path, &out, &[]);
    let stderr = text(&result.stderr);
    assert!(!result.status.success());
    assert!(stderr.contains(p(&path)), "{stderr}");
    assert!(
        stderr.contains("the left and right images look swapped (views 0–11)"),
        "{stderr}"
    );
    assert!(
        stderr.contains("within a tilt of 30°") && !stderr.contains("29.99"),
        "{stderr}"
    );
    assert!(!out.exists());

    // One view swapped, another with one image's corner order reversed: the reversed order is
    // the board turned by 180° (the same points), numbered again to agree with the other camera
    // (calib::pipeline::turns) before the fit; the swap is named.
    let mut mixed = observations(&truth, 12, 0.125, 22);
    swap_images(&mut mixed.views[3]);
    image(&mut mixed.views[8], 1).reverse();
    let error = run(&truth, &mixed, Method::Auto).unwrap_err().to_string();
    println!("{error}");
    assert!(
        error.contains("look swapped (views 3)") && !error.contains("reversed"),
        "{error}"
    );
    // The reversed order alone: the calibration fits, as with the order given right, and a
    // warning names the camera renumbered.
    let clean = observations(&truth, 12, 0.125, 22);
    let mut reversed = clean.clone();
    image(&mut reversed.views[8], 1).reverse();
    let fixed = run(&truth, &reversed, Method::Auto).unwrap();
    let right = run(&truth, &clean, Method::Auto).unwrap();
    assert!(fixed.report.fits);
    assert_eq!(fixed.rig, right.rig);
    assert!(
        fixed.report.warnings.iter().any(
            |w| w.contains("camera 'right': the corner order of 1 of its 12 images was turned")
        ),
        "{:?}",
        fixed.report.warnings
    );
}

#[test]
fn a_result_above_the_rms_bound_writes_the_report_not_the_rig() {
    // A board whose square is given as 30 mm instead of 40 mm: the fit cannot explain the
    // images; the report says what that looks like and the rig is not written.
    let truth = rig(8.0, 45.0);
    let mut wrong = observations(&truth, 12, 0.125, 31);
    wrong.target = Target::Board(Board {
        square: 0.03,
        ..board()
    });
    let dir = tempfile::tempdir().unwrap();
    let (start, path) = files(dir.path(), &wrong);
    let (out, report) = (dir.path().join("out.json"), dir.path().join("report.json"));
    let result = cli_calibrate(&start, &path, &out, &["--report", p(&report)]);
    let stderr = text(&result.stderr);
    assert!(!result.status.success(), "{}", text(&result.stdout));
    assert!(
        stderr.contains(p(&path))
            && stderr.contains("above --max-rms-px 3")
            && stderr.contains("not written"),
        "{stderr}"
    );
    assert!(
        stderr.contains("the observations give 30.00 mm"),
        "{stderr}"
    );
    assert!(!out.exists());
    let written: Value = serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(written["fits"], false);
    let diagnosis: Vec<&str> = written["diagnosis"]
        .as_array()
        .unwrap()
        .iter()
        .map(|d| d.as_str().unwrap())
        .collect();
    // The triangulated squares measure the true 40 mm.
    assert!(
        diagnosis[0].contains("measure 39.") || diagnosis[0].contains("measure 40."),
        "{diagnosis:?}"
    );

    // A bound the user raises is a bound: the rig is written, the warning stays.
    let result = cli_calibrate(&start, &path, &out, &["--max-rms-px", "1000"]);
    assert!(result.status.success(), "{}", text(&result.stderr));
    assert!(
        text(&result.stdout).contains("the model does not explain the data"),
        "{}",
        text(&result.stdout)
    );
    assert!(out.exists());
    let bad = cli_calibrate(&start, &path, &out, &["--max-rms-px", "0"]);
    assert!(
        !bad.status.success() && text(&bad.stderr).contains("--max-rms-px"),
        "{}",
        text(&bad.stderr)
    );
}

#[test]
fn weakly_constrained_results_say_so() {
    // Three views at 0.5 px: the air layer's σ is about 15 mm (measured), which the warnings say;
    // fifteen views of the same geometry constrain it to about 1 mm and say nothing.
    let truth = rig(8.0, 45.0);
    let weak = run(&truth, &observations(&truth, 3, 0.5, 1), Method::Auto).unwrap();
    let port = weak.report.port();
    let (tilt_std, air_std) = (port.tilt.std.unwrap(), port.distance.std.unwrap());
    println!(
        "3 views: σ tilt {:.3}°, σ air {:.2} mm",
        tilt_std.to_degrees(),
        air_std * 1e3
    );
    assert!(
        weak.report
            .warnings
            .iter()
            .any(|w| w.starts_with("the views hardly constrain the result")),
        "{:?}",
        weak.report.warnings
    );
    let strong = run(&truth, &observations(&truth, 15, 0.5, 1), Method::Auto).unwrap();
    assert!(
        !strong
            .report
            .warnings
            .iter()
            .any(|w| w.contains("hardly constrain")),
        "{:?}",
        strong.report.warnings
    );
}

/// `observations` with every corner pixel of image `side` (0 left, 1 right) mapped by `f`.
fn map_corners(
    observations: &Observations,
    f: impl Fn(usize, Point2<f64>) -> Point2<f64>,
) -> Observations {
    let mut mapped = observations.clone();
    for view in &mut mapped.views {
        for (side, image) in view.images.iter_mut().enumerate() {
            for corner in image.corners.iter_mut().flatten() {
                *corner = f(side, *corner);
            }
        }
    }
    mapped
}

#[test]
fn the_usual_input_mistakes_are_named_and_not_written() {
    // Each mistake a new user makes, on the stereo rig: corners detected in half-resolution
    // images, corners given undistorted (so undistorted twice), a square of the wrong size. Each
    // fails above --max-rms-px with a diagnosis that names it, and no rig is written.
    let truth = rig(8.0, 45.0);
    let good = observations(&truth, 12, 0.125, 41);
    let intrinsics: Vec<_> = truth.cameras().iter().map(|c| c.intrinsics).collect();
    let half = map_corners(&good, |_, p| Point2::new(p.x / 2.0, p.y / 2.0));
    let undistorted = map_corners(&good, |side, p| {
        let k = &intrinsics[side];
        let n = k.normalized_from_img(&p).unwrap();
        Point2::new(k.fx * n.x + k.cx, k.fy * n.y + k.cy)
    });
    let mut square = good.clone();
    square.target = Target::Board(Board {
        square: 0.02,
        ..board()
    });
    for (observations, named) in [
        (&half, "half-resolution pixels"),
        (&undistorted, "undistorted twice"),
        (&square, "the square size is half the true one"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let (start, path) = files(dir.path(), observations);
        let (out, report) = (dir.path().join("out.json"), dir.path().join("report.json"));
        let result = cli_calibrate(&start, &path, &out, &["--report", p(&report)]);
        let stderr = text(&result.stderr);
        assert!(
            !result.status.success(),
            "{named}: {}",
            text(&result.stdout)
        );
        // Above the 3 px bound, or within it but far above the corner noise: not a fit either way.
        assert!(
            (stderr.contains("above --max-rms-px 3")
                || stderr.contains("far above the corner noise seen in the images"))
                && stderr.contains(named),
            "{named}: {stderr}"
        );
        assert!(!out.exists(), "{named}");
        let written: Value =
            serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
        let diagnosis = written["diagnosis"].to_string();
        assert!(diagnosis.contains(named), "{named}: {diagnosis} {stderr}");
        // Only the mistake made is named.
        for other in [
            "half-resolution",
            "undistorted twice",
            "square size",
            "millimetres",
        ] {
            assert!(
                named.contains(other) || !diagnosis.contains(other),
                "{named}: {other} named too: {diagnosis}"
            );
        }
    }
    // The correct data fit and name nothing.
    let dir = tempfile::tempdir().unwrap();
    let (start, path) = files(dir.path(), &good);
    let out = dir.path().join("out.json");
    let result = cli_calibrate(&start, &path, &out, &[]);
    assert!(result.status.success(), "{}", text(&result.stderr));
}
