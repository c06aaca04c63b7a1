//! Board detection on rendered images against the exact corners (the board's corners projected
//! through the port by the model's forward projection, which the oracle suites check against
//! ray tracing; the images come from back-projection, a different path), corner 0 in both
//! orientations of a board, and the ways a set of images can fail, through the binary.

mod gpu_harness;

use std::path::Path;
use std::process::{Command, Output};

use flatport::calib::{Board, SceneSpec, Target, simulate};
use flatport::detect::{Found, detect_board, resolve_view};
use flatport::engine::{Device, Engine, EngineOptions};
use flatport::model::Rig;
use flatport::render::{RenderOptions, render_board};
use nalgebra::{Isometry3, Point2, Translation3, UnitQuaternion, Vector3};

fn example_rig() -> Rig {
    flatport::io::read_rig(&Path::new(env!("CARGO_MANIFEST_DIR")).join("data/example_rig.json"))
        .expect("example rig")
}

fn cpu() -> Engine {
    Engine::new(&EngineOptions {
        device: Device::Cpu,
        precision: None,
        adapter: None,
        threads: None,
    })
    .unwrap()
}

fn grey(image: &flatport::render::GreyImage) -> image::GrayImage {
    image::GrayImage::from_raw(image.width, image.height, image.to_u8()).unwrap()
}

/// The exact corners of `board` at `pose` in rig camera `camera`.
fn exact(rig: &Rig, camera: usize, board: &Board, pose: &Isometry3<f64>) -> Vec<Point2<f64>> {
    let camera = rig.refractive_camera(camera);
    (0..board.corners())
        .map(|c| {
            camera
                .project(&(pose * board.point_in_board(c)))
                .expect("corner projects")
        })
        .collect()
}

fn rms_and_max(found: &[Point2<f64>], exact: &[Point2<f64>]) -> (f64, f64) {
    let errors: Vec<f64> = found
        .iter()
        .zip(exact)
        .map(|(a, b)| (a - b).norm())
        .collect();
    let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
    (rms, errors.iter().copied().fold(0.0, f64::max))
}

/// Poses that both cameras of the example rig see whole, corners 40 px inside the images.
fn poses(board: &Board, views: usize, seed: u64) -> Vec<Isometry3<f64>> {
    let mut spec = SceneSpec::pair(Target::Board(*board), views, 0.0, seed, 0, 1);
    spec.margin_px = 40.0;
    simulate(&example_rig(), &spec).unwrap().master_from_target
}

/// The same pose with the board turned by 180° in its plane about the centre of its corners.
fn turned(board: &Board, pose: &Isometry3<f64>) -> Isometry3<f64> {
    let centre = board.centre_in_board().coords;
    let half_turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI);
    pose * Translation3::from(centre)
        * Isometry3::from_parts(Translation3::identity(), half_turn)
        * Translation3::from(-centre)
}

/// Detects the board in both cameras' images of `pose` and resolves corner 0.
fn detect_view(
    rig: &Rig,
    board: &Board,
    pose: &Isometry3<f64>,
    options: &RenderOptions,
    with_rig: bool,
) -> Result<[Vec<Point2<f64>>; 2], String> {
    let engine = cpu();
    let found: Vec<Option<Found>> = (0..2)
        .map(|k| {
            let image = grey(
                &render_board(&engine, &rig.refractive_camera(k), board, pose, options).unwrap(),
            );
            Some(Found::new(
                &image,
                board,
                detect_board(&image, board).expect("the whole board is found"),
            ))
        })
        .collect();
    let names = ["left".to_string(), "right".to_string()];
    let indices = [0, 1];
    let chosen = resolve_view(
        board,
        &names,
        with_rig.then_some((rig, &indices[..])),
        &found,
    )?;
    let corners =
        |k: usize| found[k].as_ref().unwrap().detection.orderings[chosen[k].unwrap().0].clone();
    Ok([corners(0), corners(1)])
}

#[test]
fn corners_on_rendered_images_match_the_exact_projections() {
    // Measured (this test's scenes): RMS 0.02 px, largest 0.075 px, with and without blur. The
    // issue's goal is RMS ≤ 0.1 px and largest ≤ 0.5 px; the bounds here sit between the two so
    // that a regression shows before the goal is missed.
    let rig = example_rig();
    let board = Board {
        rows: 6,
        cols: 9,
        square: 0.04,
    };
    let sharp = RenderOptions {
        noise: 2.0,
        ..RenderOptions::default()
    };
    let blurred = RenderOptions {
        noise: 2.0,
        blur_px: 0.8,
        seed: 5,
        ..RenderOptions::default()
    };
    let (mut sum, mut count, mut max) = (0.0, 0usize, 0.0f64);
    for (v, pose) in poses(&board, 4, 11).iter().enumerate() {
        let options = if v % 2 == 0 { &sharp } else { &blurred };
        let found = detect_view(&rig, &board, pose, options, false)
            .expect("the colours decide on a 9×6 board");
        for (k, corners) in found.iter().enumerate() {
            let truth = exact(&rig, k, &board, pose);
            let (rms, largest) = rms_and_max(corners, &truth);
            assert!(
                rms < 1.0,
                "view {v} camera {k}: RMS {rms} px: corner 0 at the wrong end?"
            );
            sum += rms * rms * truth.len() as f64;
            count += truth.len();
            max = max.max(largest);
        }
    }
    let rms = (sum / count as f64).sqrt();
    assert!(
        rms <= 0.05 && max <= 0.25,
        "corner RMS {rms:.4} px, largest {max:.4} px"
    );
}

#[test]
fn the_colours_put_corner_0_at_the_same_physical_corner_however_the_board_is_turned() {
    // 9×6: 10 × 7 squares, the two ends differ in colour. Turned by 180°, the image shows the
    // same grid the other way round; corner 0 must follow the board, not the image.
    let rig = example_rig();
    let board = Board {
        rows: 6,
        cols: 9,
        square: 0.04,
    };
    let options = RenderOptions {
        noise: 1.0,
        ..RenderOptions::default()
    };
    for pose in poses(&board, 2, 3) {
        for pose in [pose, turned(&board, &pose)] {
            let found = detect_view(&rig, &board, &pose, &options, false).unwrap();
            for (k, corners) in found.iter().enumerate() {
                let (rms, _) = rms_and_max(corners, &exact(&rig, k, &board, &pose));
                assert!(
                    rms < 0.1,
                    "camera {k}: corner 0 is not the board's corner 0 (RMS {rms} px against the exact order)"
                );
            }
        }
    }
}

#[test]
fn on_a_symmetric_board_both_cameras_of_a_view_agree_on_corner_0() {
    // 8×6: 9 × 7 squares, the board looks the same turned by 180°, colours included. Either end
    // may be corner 0, but the same one in both images: with the rig by the rays, without it by
    // the image rule.
    let rig = example_rig();
    let board = Board {
        rows: 6,
        cols: 8,
        square: 0.04,
    };
    let options = RenderOptions {
        noise: 1.0,
        ..RenderOptions::default()
    };
    for (v, pose) in poses(&board, 2, 9).into_iter().enumerate() {
        for pose in [pose, turned(&board, &pose)] {
            for with_rig in [true, false] {
                let found = detect_view(&rig, &board, &pose, &options, with_rig).unwrap();
                let ends: Vec<bool> = (0..2)
                    .map(|k| {
                        let straight = exact(&rig, k, &board, &pose);
                        let reversed: Vec<_> = straight.iter().rev().copied().collect();
                        let (a, _) = rms_and_max(&found[k], &straight);
                        let (b, _) = rms_and_max(&found[k], &reversed);
                        assert!(
                            a.min(b) < 0.1,
                            "view {v} camera {k}: neither order of the board ({a}, {b} px)"
                        );
                        a < b
                    })
                    .collect();
                assert_eq!(
                    ends[0], ends[1],
                    "view {v} (rig: {with_rig}): the cameras put corner 0 at different ends"
                );
            }
        }
    }
}

#[test]
fn a_symmetric_board_with_vertical_rows_and_no_rig_is_reported_not_guessed() {
    // Rows running down the image: the image rule cannot tell the ends apart, the colours cannot
    // either; without a rig the view must be refused by name, with the rig it resolves.
    let rig = example_rig();
    let board = Board {
        rows: 6,
        cols: 8,
        square: 0.04,
    };
    let options = RenderOptions::default();
    let quarter = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2);
    let centre = board.centre_in_board().coords;
    let pose = Isometry3::from_parts(Translation3::new(0.03, 0.0, 0.8), quarter)
        * Translation3::from(-centre);
    let error = detect_view(&rig, &board, &pose, &options, false).unwrap_err();
    assert!(
        error.contains("camera left") && error.contains("--rig"),
        "{error}"
    );
    let found = detect_view(&rig, &board, &pose, &options, true).unwrap();
    let straight = exact(&rig, 1, &board, &pose);
    let reversed: Vec<_> = straight.iter().rev().copied().collect();
    let left_straight = rms_and_max(&found[0], &exact(&rig, 0, &board, &pose)).0 < 0.1;
    let right = if left_straight { straight } else { reversed };
    assert!(
        rms_and_max(&found[1], &right).0 < 0.1,
        "the rays paired the right camera the wrong way round"
    );
}

#[test]
fn the_gpu_renders_what_the_cpu_renders() {
    // The GPU makes the pixel grid in the shader and back-projects in f32 (directions within
    // 2e-6 of the f64 reference: about 2 µm on a board 1 m away, 0.002 px). Only sub-samples
    // within that of an edge can differ, each by 1/64 of the contrast.
    let Some(gpu) = gpu_harness::engine(flatport::gpu::Precision::F32) else {
        return;
    };
    let gpu = Engine::Gpu(gpu);
    let rig = example_rig();
    let board = Board {
        rows: 6,
        cols: 9,
        square: 0.04,
    };
    let pose = poses(&board, 1, 2)[0];
    let options = RenderOptions::default();
    let camera = rig.refractive_camera(1);
    let on_cpu = render_board(&cpu(), &camera, &board, &pose, &options).unwrap();
    let on_gpu = render_board(&gpu, &camera, &board, &pose, &options).unwrap();
    let differences: Vec<f32> = on_cpu
        .pixels
        .iter()
        .zip(&on_gpu.pixels)
        .map(|(a, b)| (a - b).abs())
        .collect();
    let mean = differences.iter().sum::<f32>() / differences.len() as f32;
    let max = differences.iter().copied().fold(0.0, f32::max);
    let contrast = (options.shades.white - options.shades.black) as f32;
    assert!(
        mean < 1e-4 && max <= 2.0 * contrast / 64.0 + 1e-6,
        "mean {mean}, largest {max}"
    );
}

#[test]
fn png_jpeg_tiff_grey_and_colour_8_and_16_bit_give_the_same_corners() {
    let rig = example_rig();
    let board = Board {
        rows: 6,
        cols: 9,
        square: 0.04,
    };
    let pose = poses(&board, 1, 6)[0];
    let rendered = render_board(
        &cpu(),
        &rig.refractive_camera(0),
        &board,
        &pose,
        &RenderOptions {
            noise: 1.0,
            ..RenderOptions::default()
        },
    )
    .unwrap();
    let truth = exact(&rig, 0, &board, &pose);
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (rendered.width, rendered.height);
    let grey8 = grey(&rendered);
    let grey16 =
        image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, rendered.to_u16()).unwrap();
    let colour = image::DynamicImage::ImageLuma8(grey8.clone()).to_rgb8();
    let files = [
        ("grey8.png", image::DynamicImage::ImageLuma8(grey8.clone())),
        (
            "grey16.png",
            image::DynamicImage::ImageLuma16(grey16.clone()),
        ),
        ("grey16.tif", image::DynamicImage::ImageLuma16(grey16)),
        ("colour.png", image::DynamicImage::ImageRgb8(colour.clone())),
        ("colour.jpg", image::DynamicImage::ImageRgb8(colour)),
    ];
    for (name, picture) in files {
        let path = dir.path().join(name);
        picture.save(&path).unwrap();
        let read = flatport::io::read_grey_image(&path).unwrap();
        let detection = detect_board(&read, &board).unwrap_or_else(|m| panic!("{name}: {m}"));
        let found = Found::new(&read, &board, detection);
        let chosen = resolve_view(&board, &["left".to_string()], None, &[Some(found.clone())])
            .unwrap()[0]
            .unwrap()
            .0;
        let (rms, max) = rms_and_max(&found.detection.orderings[chosen], &truth);
        // JPEG's blocks cost a little; the lossless files are the 8-bit image (16-bit rounds to it).
        let bound = if name.ends_with(".jpg") { 0.1 } else { 0.05 };
        assert!(
            rms <= bound && max <= 5.0 * bound,
            "{name}: RMS {rms} px, largest {max} px"
        );
    }
}

// ---- through the binary ----

fn flatport(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(args)
        .output()
        .expect("binary runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn run_ok(args: &[&str]) -> Output {
    let o = flatport(args);
    assert!(
        o.status.success(),
        "flatport {args:?} failed: {}",
        stderr(&o)
    );
    o
}

fn run_err(args: &[&str]) -> String {
    let o = flatport(args);
    assert!(!o.status.success(), "flatport {args:?} should fail");
    stderr(&o)
}

/// Renders `views` views of the example rig into `dir` (left/, right/, corners.json, rig.json).
fn render(dir: &Path, views: usize, extra: &[&str]) {
    let rig = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/example_rig.json");
    let views = views.to_string();
    let mut args = vec![
        "render",
        "--rig",
        rig.to_str().unwrap(),
        "--views",
        &views,
        "--seed",
        "4",
        "--noise",
        "1.5",
        "--device",
        "cpu",
        "-q",
    ];
    args.extend_from_slice(extra);
    args.extend_from_slice(&["--output", dir.to_str().unwrap()]);
    run_ok(&args);
}

fn images_arg(dir: &Path, camera: &str) -> String {
    format!(
        "{camera}={}/{camera}/*.png",
        glob::Pattern::escape(dir.to_str().unwrap())
    )
}

fn detect(dir: &Path, output: &Path, extra: &[&str]) -> Output {
    let (left, right) = (images_arg(dir, "left"), images_arg(dir, "right"));
    let mut args = vec![
        "detect",
        "--board",
        "9x6@0.04",
        "--images",
        &left,
        "--images",
        &right,
        "-q",
        "--output",
        output.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    flatport(&args)
}

fn read(path: &Path) -> flatport::calib::Observations {
    flatport::io::read_observations(path).unwrap()
}

#[test]
fn detect_writes_the_exact_corners_of_rendered_16_bit_images_and_draws_overlays() {
    let dir = tempfile::tempdir().unwrap();
    let shots = dir.path().join("shots");
    render(&shots, 3, &["--bits", "16"]);
    let output = dir.path().join("obs.json");
    let overlays = dir.path().join("overlays");
    let rig = shots.join("rig.json");
    let o = detect(
        &shots,
        &output,
        &[
            "--rig",
            rig.to_str().unwrap(),
            "--overlay",
            overlays.to_str().unwrap(),
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let (found, truth) = (read(&output), read(&shots.join("corners.json")));
    assert_eq!(found.views.len(), 3);
    for (a, b) in found.views.iter().zip(&truth.views) {
        let flat = |v: &[Option<Point2<f64>>]| v.iter().map(|p| p.unwrap()).collect::<Vec<_>>();
        for (p, q) in a
            .images
            .iter()
            .zip(&b.images)
            .map(|(a, b)| (&a.corners, &b.corners))
        {
            let (rms, max) = rms_and_max(&flat(p), &flat(q));
            assert!(rms <= 0.05 && max <= 0.25, "RMS {rms} px, largest {max} px");
        }
    }
    for camera in ["left", "right"] {
        for v in 0..3 {
            let path = overlays.join(camera).join(format!("view_{v:03}.jpg"));
            let image = image::open(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert_eq!((image.width(), image.height()), (1280, 1024));
        }
    }
}

#[test]
fn images_of_the_wrong_size_truncated_files_and_unequal_counts_are_errors_naming_them() {
    let dir = tempfile::tempdir().unwrap();
    let shots = dir.path().join("shots");
    render(&shots, 2, &[]);
    let output = dir.path().join("obs.json");
    let rig = shots.join("rig.json");

    // Wrong size against the rig.
    let small = shots.join("left/view_001.png");
    image::GrayImage::from_pixel(640, 480, image::Luma([128]))
        .save(&small)
        .unwrap();
    let o = detect(&shots, &output, &["--rig", rig.to_str().unwrap()]);
    assert!(!o.status.success());
    let error = stderr(&o);
    assert!(
        error.contains("view_001.png") && error.contains("640×480") && error.contains("1280×1024"),
        "{error}"
    );
    // Without the rig, against the camera's other image.
    let error = stderr(&detect(&shots, &output, &[]));
    assert!(
        error.contains("view_001.png") && error.contains("640×480"),
        "{error}"
    );
    assert!(!output.exists(), "nothing is written on an error");

    // A truncated PNG.
    let bytes = std::fs::read(shots.join("left/view_000.png")).unwrap();
    std::fs::write(&small, &bytes[..bytes.len() / 2]).unwrap();
    let error = stderr(&detect(&shots, &output, &[]));
    assert!(error.contains("view_001.png"), "{error}");
    assert!(!output.exists());

    // Unequal counts.
    std::fs::remove_file(&small).unwrap();
    let error = stderr(&detect(&shots, &output, &[]));
    assert!(
        error.contains("'left' has 1 images") && error.contains("'right' has 2"),
        "{error}"
    );

    // A camera the rig does not have, a glob that matches nothing.
    let error = run_err(&[
        "detect",
        "--board",
        "9x6@0.04",
        "--images",
        &images_arg(&shots, "port"),
        "--rig",
        rig.to_str().unwrap(),
        "-o",
        "x.json",
    ]);
    assert!(
        error.contains("'port'") && error.contains("left, right"),
        "{error}"
    );
    let error = run_err(&[
        "detect",
        "--board",
        "9x6@0.04",
        "--images",
        "left=/nonexistent/*.png",
        "-o",
        "x.json",
    ]);
    assert!(
        error.contains("/nonexistent/*.png") && error.contains("no file matches"),
        "{error}"
    );
}

#[test]
fn a_view_no_camera_found_is_dropped_and_one_camera_alone_is_left_out_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let shots = dir.path().join("shots");
    render(&shots, 3, &[]);
    let blank = image::GrayImage::from_pixel(1280, 1024, image::Luma([100]));
    blank.save(shots.join("left/view_001.png")).unwrap();
    blank.save(shots.join("right/view_001.png")).unwrap();
    blank.save(shots.join("right/view_002.png")).unwrap();
    let output = dir.path().join("obs.json");
    let o = detect(&shots, &output, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let error = stderr(&o);
    assert!(
        error.contains("view 1") && error.contains("no camera found the board"),
        "{error}"
    );
    assert!(
        error.contains("view 2") && error.contains("only left found the board"),
        "{error}"
    );
    let (found, truth) = (read(&output), read(&shots.join("corners.json")));
    assert_eq!(found.views.len(), 1, "only view 0 holds both cameras");
    let first = |o: &flatport::calib::Observations| o.views[0].images[0].corners[0].unwrap();
    assert!((first(&found) - first(&truth)).norm() < 0.25);

    // No view at all: an error, not an empty file passed on.
    blank.save(shots.join("left/view_000.png")).unwrap();
    blank.save(shots.join("right/view_000.png")).unwrap();
    let o = detect(&shots, &output, &[]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("no view"), "{}", stderr(&o));
}

#[test]
fn the_demo_calibrates_from_detected_corners_as_well_as_simulated_corners_allow() {
    // tests/calibration.rs holds simulated corners of this scene kind (8° tilt, 15 views,
    // 0.125 px of noise) to 0.06° of axis and 1.5 mm of air layer; the demo's detected corners
    // (0.02 px RMS) must do at least as well.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    run_ok(&["demo", "--device", "cpu", "--output", out.to_str().unwrap()]);
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let truth = flatport::io::read_truth(&out.join("truth.json")).unwrap();
    let n = &report["normal"];
    let normal = Vector3::new(
        n[0].as_f64().unwrap(),
        n[1].as_f64().unwrap(),
        n[2].as_f64().unwrap(),
    )
    .normalize();
    let axis_error = normal.angle(truth.interface.normal()).to_degrees();
    let air_error =
        (report["air_distance"].as_f64().unwrap() - truth.interface.air_distance()).abs();
    assert!(
        axis_error <= 0.06 && air_error <= 1.5e-3,
        "axis off by {axis_error}°, air layer by {air_error} m"
    );
    for camera in ["left", "right"] {
        assert!(
            out.join("overlays")
                .join(camera)
                .join("view_014.jpg")
                .exists()
        );
        assert!(
            out.join("images")
                .join(camera)
                .join("view_014.png")
                .exists()
        );
    }
}
