//! Issue 38 through the binary: `flatport render --calibration-set` draws a rig's ChArUco images
//! (partial boards, lens distortion, image noise) with their truth, `flatport calibrate --images`
//! calibrates a rig from the images alone, and the test compares the written rig with the rendered
//! truth rig itself: extrinsics, every port's axis and air layer, each lens over its image, and
//! points triangulated from exact pixels. The same set as lossless videos must give the same rig,
//! and each kind of bad input must be a clear error that writes nothing.
//!
//! Sizes chosen for CI time (the whole file in about 2–3 minutes on 2 cores): the two-camera rig
//! keeps the example rig's 1280×1024 cameras (30 underwater frames, 15 in-air views each); the
//! three-housing and four-camera rigs use 1024×768 cameras (f = 760 px) with 24 underwater frames
//! and 12 (housings) or 24 (surface) in-air views each. With 12 in-air views the surface rig's
//! camera a came out with fx +0.24 px, cx +0.27 px: its lens 0.649 px off at the image's corner,
//! over the 0.5 px bound; with 24 views 0.470 px.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use flatport::io::{read_rig, write_rig};
use flatport::model::{
    Interface, Layer, PinholeCamera, Ports, Rig, RigCamera, normal_from_tilt_azimuth,
};
use nalgebra::{Matrix3, Point2, Point3, Rotation3, Vector3};

const BOARD: &str = "data/boards/charuco_7x5.json";

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

/// Renders a calibration set of `rig` into `dir` (noise 1 grey level of 255).
fn render(rig: &Path, views: usize, air_views: usize, dir: &Path) {
    let out = flatport(&[
        "render",
        "--rig",
        p(rig),
        "--board",
        BOARD,
        "--calibration-set",
        "--views",
        &views.to_string(),
        "--air-views",
        &air_views.to_string(),
        "--noise",
        "1",
        "--device",
        "cpu",
        "-q",
        "-o",
        p(dir),
    ]);
    assert!(out.status.success(), "render: {}", text(&out.stderr));
}

/// `flatport calibrate --images set ...` with `extra` arguments, writing `rig` and `report`.
fn calibrate(set: &Path, rig: &Path, report: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "calibrate",
        "--images",
        p(set),
        "--board",
        BOARD,
        "--device",
        "cpu",
        "-q",
        "--output",
        p(rig),
        "--report",
        p(report),
    ];
    args.extend_from_slice(extra);
    let started = std::time::Instant::now();
    let out = flatport(&args);
    eprintln!(
        "calibrate {} {}: {:.1} s",
        p(set),
        extra.join(" "),
        started.elapsed().as_secs_f64()
    );
    out
}

/// A camera of `width`×`height` at `centre` (master frame, m), turned by `yaw_deg` about y and
/// `pitch_deg` about x, with lens `distortion`.
fn camera(
    name: &str,
    size: (u32, u32),
    f_px: f64,
    distortion: [f64; 5],
    yaw_deg: f64,
    pitch_deg: f64,
    centre: [f64; 3],
) -> RigCamera {
    let intrinsics = PinholeCamera::new(
        name,
        size.0,
        size.1,
        f_px,
        f_px,
        (size.0 as f64 - 1.0) / 2.0 + 3.0,
        (size.1 as f64 - 1.0) / 2.0 - 2.0,
        distortion,
    )
    .unwrap();
    let r = Rotation3::from_euler_angles(pitch_deg.to_radians(), yaw_deg.to_radians(), 0.0)
        .into_inner();
    RigCamera::new(name, intrinsics, r, -r * Vector3::from(centre)).unwrap()
}

/// The cameras re-expressed relative to the first (the master: its extrinsics the identity).
fn relative_to_first(cameras: Vec<RigCamera>) -> Vec<RigCamera> {
    let master = cameras[0].cam_from_master;
    cameras
        .into_iter()
        .map(|mut c| {
            c.cam_from_master *= master.inverse();
            c
        })
        .collect()
}

const SMALL: (u32, u32) = (1024, 768);
const F_SMALL: f64 = 760.0;

/// Three 1024×768 cameras 15 cm apart, the outer ones turned 2° inward, each in its own housing
/// (10 mm of acrylic 1.49; camera c 8 mm of glass 1.52), the ports tilted 4°, 3° and 5° at
/// different azimuths. Names sort in rig order (the layout's folders are read sorted), the middle
/// camera is the master.
fn three_housings() -> Rig {
    let cameras = relative_to_first(vec![
        camera(
            "a",
            SMALL,
            F_SMALL,
            [-0.1, 0.02, 0.0003, -0.0002, 0.0],
            0.0,
            0.0,
            [0.0; 3],
        ),
        camera(
            "b",
            SMALL,
            F_SMALL,
            [-0.09, 0.015, 0.0, 0.0002, 0.0],
            -2.0,
            1.0,
            [-0.15, 0.0, 0.0],
        ),
        camera(
            "c",
            SMALL,
            F_SMALL,
            [-0.11, 0.025, -0.0002, 0.0, 0.0],
            2.0,
            -1.0,
            [0.15, 0.0, 0.0],
        ),
    ]);
    let port = |tilt: f64, azimuth: f64, air: f64, glass: (f64, f64)| {
        let n = normal_from_tilt_azimuth(tilt.to_radians(), azimuth.to_radians());
        Interface::new(
            n.into_inner(),
            air,
            vec![Layer {
                thickness: glass.0,
                index: glass.1,
            }],
            1.0,
            1.333,
        )
        .unwrap()
    };
    Rig::with_ports(
        cameras,
        Ports::PerCamera(vec![
            port(4.0, 30.0, 0.015, (0.01, 1.49)),
            port(3.0, 200.0, 0.02, (0.01, 1.49)),
            port(5.0, 120.0, 0.012, (0.008, 1.52)),
        ]),
    )
    .unwrap()
}

/// Four 1024×768 cameras in a 10 × 8 cm grid, each turned 2° toward the grid's centre, 12 cm above
/// a bare water surface tilted 2° (air 1.0, water 1.333).
fn surface_four() -> Rig {
    let d = [-0.1, 0.02, 0.0, 0.0, 0.0];
    let cameras = vec![
        camera("a", SMALL, F_SMALL, d, 0.0, 0.0, [0.0, 0.0, 0.0]),
        camera("b", SMALL, F_SMALL, d, 2.0, 0.0, [0.1, 0.0, 0.0]),
        camera("c", SMALL, F_SMALL, d, 0.0, -2.0, [0.0, 0.08, 0.0]),
        camera("d", SMALL, F_SMALL, d, 2.0, -2.0, [0.1, 0.08, 0.0]),
    ];
    let n = normal_from_tilt_azimuth(2f64.to_radians(), 0.5);
    let surface = Interface::new(n.into_inner(), 0.12, vec![], 1.0, 1.333).unwrap();
    Rig::new(cameras, surface).unwrap()
}

/// The figures of issue 38's bounds for one calibrated rig against its truth.
#[derive(Debug)]
struct Figures {
    /// Largest rotation error of a non-master camera, degrees.
    rotation_deg: f64,
    /// Largest camera-centre error of a non-master camera, mm.
    translation_mm: f64,
    /// Largest angle between a calibrated port axis and the true one, degrees.
    axis_deg: f64,
    /// Largest error of a port's air layer (camera centre to the first interface), mm.
    air_mm: f64,
    /// Largest displacement, over each camera's image, of the calibrated lens against the true
    /// lens (the pixel the calibrated lens gives to the true lens's ray of a pixel), px.
    lens_px: f64,
    /// Median error of points triangulated through the calibrated rig from their exact pixels
    /// under the truth, percent of their distance from the master camera.
    triangulated_percent: f64,
}

/// The calibrated lens against the true one over a 33 × 25 grid of the image.
fn lens_displacement_px(found: &PinholeCamera, truth: &PinholeCamera) -> f64 {
    let mut worst: f64 = 0.0;
    for i in 0..=32 {
        for j in 0..=24 {
            let pixel = Point2::new(
                (truth.width as f64 - 1.0) * i as f64 / 32.0,
                (truth.height as f64 - 1.0) * j as f64 / 24.0,
            );
            let ray = truth
                .cam_from_img(&pixel)
                .expect("inside the true lens's fold");
            let again = found
                .img_from_cam(&Point3::from(ray.into_inner()))
                .expect("in front of the camera");
            worst = worst.max((again - pixel).norm());
        }
    }
    worst
}

/// Median error of points triangulated through `found` (least squares over every camera whose
/// image holds the point) from their exact pixels under `truth`, percent of the point's distance
/// from the master camera. The points: 8 depths over `depth` m along the master's axis, ±30 % and
/// ±25 % of the depth sideways (where the rendered boards are).
fn triangulation_error_percent(found: &Rig, truth: &Rig, depth: (f64, f64)) -> f64 {
    let mut errors = Vec::new();
    for iz in 0..8 {
        let z = depth.0 + (depth.1 - depth.0) * iz as f64 / 7.0;
        for ix in -6..=6 {
            for iy in -5..=5 {
                let point = Point3::new(0.05 * ix as f64 * z, 0.05 * iy as f64 * z, z);
                let mut normal = Matrix3::zeros();
                let mut right = Vector3::zeros();
                let mut rays = 0;
                for (k, camera) in truth.cameras().iter().enumerate() {
                    let intrinsics = &camera.intrinsics;
                    let Ok(pixel) = truth.refractive_camera(k).project(&point) else {
                        continue;
                    };
                    let inside = |p: f64, size: u32| (0.0..size as f64 - 1.0).contains(&p);
                    if !inside(pixel.x, intrinsics.width) || !inside(pixel.y, intrinsics.height) {
                        continue;
                    }
                    let f = found.camera_index(&camera.name).expect("same cameras");
                    let ray = found
                        .refractive_camera(f)
                        .backproject(&pixel)
                        .expect("a pixel inside the image back-projects");
                    let d = ray.dir.into_inner();
                    let m = Matrix3::identity() - d * d.transpose();
                    normal += m;
                    right += m * ray.origin.coords;
                    rays += 1;
                }
                if rays < 2 {
                    continue;
                }
                let inverse = normal.try_inverse().expect("two rays apart");
                let error = (inverse * right - point.coords).norm();
                errors.push(100.0 * error / point.coords.norm());
            }
        }
    }
    assert!(
        errors.len() > 100,
        "only {} points seen by two cameras",
        errors.len()
    );
    errors.sort_by(f64::total_cmp);
    errors[errors.len() / 2]
}

/// The depths `flatport render --calibration-set` draws its boards at (its `depth_range`, written
/// out again: the board's outer size at 0.9 to 0.35 of the master's image width under water).
fn board_depths(truth: &Rig) -> (f64, f64) {
    let camera = &truth.cameras()[0].intrinsics;
    let outer = 7.0 * 0.04; // charuco_7x5: 7 squares of 40 mm across
    let span = camera.fx * outer / camera.width as f64 * 1.333;
    (span / 0.9, span / 0.35)
}

fn figures(found: &Rig, truth: &Rig) -> Figures {
    assert_eq!(found.cameras().len(), truth.cameras().len());
    let mut f = Figures {
        rotation_deg: 0.0,
        translation_mm: 0.0,
        axis_deg: 0.0,
        air_mm: 0.0,
        lens_px: 0.0,
        triangulated_percent: 0.0,
    };
    for (k, t) in truth.cameras().iter().enumerate() {
        let c = &found.cameras()[found.camera_index(&t.name).expect("every camera")];
        let rotation = (c.cam_from_master.rotation * t.cam_from_master.rotation.inverse()).angle();
        f.rotation_deg = f.rotation_deg.max(rotation.to_degrees());
        f.translation_mm = f
            .translation_mm
            .max((c.centre_in_master() - t.centre_in_master()).norm() * 1e3);
        let lens_px = lens_displacement_px(&c.intrinsics, &t.intrinsics);
        eprintln!(
            "camera {}: lens off by up to {lens_px:.3} px over the image (found {:?}, true {:?})",
            t.name, c.intrinsics, t.intrinsics
        );
        f.lens_px = f.lens_px.max(lens_px);
        let axis = found
            .port_in_master(found.camera_index(&t.name).unwrap())
            .normal()
            .angle(&**truth.port_in_master(k).normal());
        f.axis_deg = f.axis_deg.max(axis.to_degrees());
    }
    f.air_mm = match (found.ports(), truth.ports()) {
        (Ports::Shared(a), Ports::Shared(b)) => (a.air_distance() - b.air_distance()).abs() * 1e3,
        (Ports::PerCamera(a), Ports::PerCamera(b)) => a
            .iter()
            .zip(b)
            .map(|(a, b)| (a.air_distance() - b.air_distance()).abs() * 1e3)
            .fold(0.0, f64::max),
        _ => panic!("the calibrated rig has other ports than the truth"),
    };
    f.triangulated_percent = triangulation_error_percent(found, truth, board_depths(truth));
    f
}

/// Issue 38's bounds. The lens bound: 0.5 px over the whole image, corners included, where the
/// in-air views hold few corners; a lens error of that size moves a ray by 0.5/f ≈ 0.04° at the
/// image's edge, below the extrinsics' bound, and the triangulation bound checks its effect in
/// 3-D where the boards are.
fn check_bounds(what: &str, f: &Figures, surface: bool) {
    eprintln!(
        "{what}: extrinsics {:.4}° {:.3} mm, axes {:.4}°, air {:.3} mm, lens {:.3} px, triangulated points {:.4} % of their distance",
        f.rotation_deg, f.translation_mm, f.axis_deg, f.air_mm, f.lens_px, f.triangulated_percent
    );
    assert!(
        f.rotation_deg < 0.05 && f.translation_mm < 1.0,
        "{what}: extrinsics {f:?}"
    );
    assert!(f.axis_deg < 0.1, "{what}: axis {f:?}");
    let air_bound = if surface { 0.3 } else { 1.5 };
    assert!(f.air_mm < air_bound, "{what}: air layer {f:?}");
    assert!(f.lens_px < 0.5, "{what}: lens {f:?}");
    assert!(
        f.triangulated_percent <= 0.06,
        "{what}: triangulated points {f:?}"
    );
}

/// A rendered set and its calibration, kept for the tests that reuse them.
struct Calibrated {
    _dir: tempfile::TempDir,
    set: PathBuf,
    rig: PathBuf,
}

/// The example rig (2 cameras behind one shared port with 14 mm of glass) rendered and calibrated
/// once for the tests that need it.
fn shared_pair() -> &'static Calibrated {
    static SET: OnceLock<Calibrated> = OnceLock::new();
    SET.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let set = dir.path().join("set");
        render(Path::new("data/example_rig.json"), 30, 15, &set);
        let rig = dir.path().join("rig.json");
        let report = dir.path().join("report.json");
        let out = calibrate(
            &set,
            &rig,
            &report,
            &[
                "--port",
                "shared",
                "--glass",
                "0.014:1.473",
                "--index-air",
                "1.003",
            ],
        );
        assert!(
            out.status.success(),
            "{}\n{}",
            text(&out.stdout),
            text(&out.stderr)
        );
        assert!(report.is_file());
        Calibrated {
            _dir: dir,
            set,
            rig,
        }
    })
}

#[test]
fn two_cameras_behind_one_shared_port() {
    let calibrated = shared_pair();
    let truth = read_rig(&calibrated.set.join("water/rig.json")).unwrap();
    let found = read_rig(&calibrated.rig).unwrap();
    check_bounds("shared port", &figures(&found, &truth), false);
}

/// Issue 45's real photographs: lenses from a rig file known to about 0.5 px (not the ones the
/// images were taken with). Kept fixed, they leave an RMS far above the corner noise that the
/// held-out frames confirm: written, the verdict usable with that reason. Refined under water
/// (the default, where the held-out frames say it helps), the lenses come back to the truth and
/// the verdict is good.
#[test]
fn lenses_from_a_rig_file_half_a_pixel_off_are_judged_by_the_held_out_frames() {
    let calibrated = shared_pair();
    let truth = read_rig(&calibrated.set.join("water/rig.json")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    // Each lens moved as a real calibration's error would: fx, fy ±0.2 %, the principal point
    // by 0.4–0.6 px, k1 by 0.003.
    let cameras: Vec<RigCamera> = truth
        .cameras()
        .iter()
        .zip([1.0, -1.0])
        .map(|(c, sign)| {
            let mut lens = c.intrinsics.clone();
            lens.fx *= 1.0 + 0.002 * sign;
            lens.fy *= 1.0 + 0.0015 * sign;
            lens.cx += 0.5 * sign;
            lens.cy -= 0.4;
            lens.distortion[0] += 0.003 * sign;
            let mut camera = c.clone();
            camera.intrinsics = lens;
            camera
        })
        .collect();
    let lenses = dir.path().join("lenses.json");
    write_rig(
        &lenses,
        &Rig::with_ports(cameras, truth.ports().clone()).unwrap(),
    )
    .unwrap();
    let run = |when: &str| {
        let (rig, report) = (
            dir.path().join(format!("rig_{when}.json")),
            dir.path().join(format!("report_{when}.json")),
        );
        let out = calibrate(
            &calibrated.set,
            &rig,
            &report,
            &[
                "--port",
                "shared",
                "--glass",
                "0.014:1.473",
                "--index-air",
                "1.003",
                "--rig",
                p(&lenses),
                "--refine-intrinsics",
                when,
            ],
        );
        let stdout = text(&out.stdout);
        assert!(out.status.success(), "{stdout}\n{}", text(&out.stderr));
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
        (stdout, report, read_rig(&rig).unwrap())
    };
    let (stdout, report, found) = run("never");
    assert_eq!(report["verdict"]["grade"], "usable", "{stdout}");
    assert!(
        stdout.contains("verdict: usable: RMS") && stdout.contains("above the corner noise"),
        "{stdout}"
    );
    // The rig still measures: the held-out squares (the issue's bound for real photographs is
    // 0.35 %) and points triangulated from exact pixels.
    let squares = report["held_out"]["median_distance_error_percent_of_square"]
        .as_f64()
        .unwrap();
    assert!(squares < 0.35, "held-out squares {squares} %");
    let f = figures(&found, &truth);
    assert!(f.triangulated_percent < 0.35, "{f:?}");
    let (stdout, report, found) = run("auto");
    assert_eq!(report["verdict"]["grade"], "good", "{stdout}");
    assert!(stdout.contains("refined (more than 2 % lower)"), "{stdout}");
    check_bounds(
        "lenses refined under water",
        &figures(&found, &truth),
        false,
    );
}

/// Renders `truth` and calibrates it with `extra` arguments; the figures.
fn render_and_calibrate(truth: &Rig, views: usize, air_views: usize, extra: &[&str]) -> Figures {
    let dir = tempfile::tempdir().unwrap();
    let truth_path = dir.path().join("truth_rig.json");
    write_rig(&truth_path, truth).unwrap();
    let set = dir.path().join("set");
    render(&truth_path, views, air_views, &set);
    let rig = dir.path().join("rig.json");
    let report = dir.path().join("report.json");
    let out = calibrate(&set, &rig, &report, extra);
    assert!(
        out.status.success(),
        "{}\n{}",
        text(&out.stdout),
        text(&out.stderr)
    );
    eprintln!("{}", text(&out.stdout));
    let found = read_rig(&rig).unwrap();
    // The truth the images were rendered from (the rig above, as render wrote it back).
    let rendered = read_rig(&set.join("water/rig.json")).unwrap();
    assert_eq!(rendered.cameras().len(), truth.cameras().len());
    figures(&found, &rendered)
}

#[test]
fn three_cameras_in_their_own_housings() {
    let f = render_and_calibrate(
        &three_housings(),
        24,
        12,
        &[
            "--port",
            "housings",
            "--glass",
            "0.01:1.49",
            "--glass",
            "c=0.008:1.52",
        ],
    );
    check_bounds("three housings", &f, false);
}

#[test]
fn four_cameras_above_a_bare_water_surface() {
    let f = render_and_calibrate(&surface_four(), 24, 24, &["--port", "surface"]);
    check_bounds("water surface", &f, true);
}

/// Issue 45's route without lenses: no air/ folder and no --rig. Every lens (fx, fy, cx, cy and
/// the terms the held-out frames choose) comes from the underwater frames with the port and the
/// extrinsics, and the rig meets issue 38's bounds against the truth (the left camera's lens has
/// a small decentring, p1 4e-4, p2 -3e-4: left out, its principal point moved by 1 px and the
/// right camera's rotation by 0.09°).
#[test]
fn lenses_from_the_underwater_frames_alone() {
    let calibrated = shared_pair();
    let dir = tempfile::tempdir().unwrap();
    let set = dir.path().join("set");
    copy_tree(&calibrated.set, &set, &|p| {
        p.ends_with("air") || p.ends_with("air-truth")
    });
    assert!(!set.join("air").exists() && set.join("water").is_dir());
    let (rig, report) = (dir.path().join("rig.json"), dir.path().join("report.json"));
    let out = calibrate(
        &set,
        &rig,
        &report,
        &[
            "--port",
            "shared",
            "--glass",
            "0.014:1.473",
            "--index-air",
            "1.003",
        ],
    );
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", text(&out.stderr));
    assert!(
        stdout.contains("lenses: lens terms k1, k2, p1, p2 chosen by the held-out frames"),
        "{stdout}"
    );
    assert!(stdout.contains("verdict: good"), "{stdout}");
    let truth = read_rig(&calibrated.set.join("water/rig.json")).unwrap();
    check_bounds(
        "lenses from the underwater frames",
        &figures(&read_rig(&rig).unwrap(), &truth),
        false,
    );
}

/// Every file under `from` hard-linked (or copied) to `to`, except those `skip` names.
fn copy_tree(from: &Path, to: &Path, skip: &dyn Fn(&Path) -> bool) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let path = entry.unwrap().path();
        if skip(&path) {
            continue;
        }
        let target = to.join(path.file_name().unwrap());
        if path.is_dir() {
            copy_tree(&path, &target, skip);
        } else if std::fs::hard_link(&path, &target).is_err() {
            std::fs::copy(&path, &target).unwrap();
        }
    }
}

fn have_ffmpeg() -> bool {
    Command::new("ffmpeg")
        .arg("-version")
        .output()
        .is_ok_and(|o| o.status.success())
        && Command::new("ffprobe")
            .arg("-version")
            .output()
            .is_ok_and(|o| o.status.success())
}

#[test]
fn the_set_as_lossless_videos_gives_the_same_rig() {
    if !have_ffmpeg() {
        eprintln!("skipped: ffmpeg/ffprobe not on PATH (the videos are encoded with ffmpeg)");
        return;
    }
    let calibrated = shared_pair();
    let dir = tempfile::tempdir().unwrap();
    let videos = dir.path().join("videos");
    for part in ["air", "water"] {
        for camera in ["left", "right"] {
            let folder = videos.join(part).join(camera);
            std::fs::create_dir_all(&folder).unwrap();
            let out = Command::new("ffmpeg")
                .args(["-loglevel", "error", "-framerate", "10", "-i"])
                .arg(calibrated.set.join(part).join(camera).join("view_%03d.png"))
                .args(["-c:v", "ffv1"])
                .arg(folder.join(format!("{camera}.mkv")))
                .output()
                .unwrap();
            assert!(out.status.success(), "ffmpeg: {}", text(&out.stderr));
        }
    }
    let rig = dir.path().join("rig.json");
    let report = dir.path().join("report.json");
    let out = calibrate(
        &videos,
        &rig,
        &report,
        &[
            "--port",
            "shared",
            "--glass",
            "0.014:1.473",
            "--index-air",
            "1.003",
        ],
    );
    assert!(
        out.status.success(),
        "{}\n{}",
        text(&out.stdout),
        text(&out.stderr)
    );
    let from_videos = read_rig(&rig).unwrap();
    let from_images = read_rig(&calibrated.rig).unwrap();
    let mut worst: f64 = 0.0;
    for (a, b) in from_videos.cameras().iter().zip(from_images.cameras()) {
        assert_eq!(a.name, b.name);
        let (i, j) = (&a.intrinsics, &b.intrinsics);
        for (x, y) in [(i.fx, j.fx), (i.fy, j.fy), (i.cx, j.cx), (i.cy, j.cy)]
            .into_iter()
            .chain(i.distortion.iter().copied().zip(j.distortion))
        {
            worst = worst.max((x - y).abs());
        }
        worst =
            worst.max((a.cam_from_master.rotation * b.cam_from_master.rotation.inverse()).angle());
        worst = worst.max(
            (a.cam_from_master.translation.vector - b.cam_from_master.translation.vector).norm(),
        );
    }
    let (pa, pb) = (from_videos.port_in_master(0), from_images.port_in_master(0));
    worst = worst.max(pa.normal().angle(&**pb.normal()));
    worst = worst.max((pa.air_distance() - pb.air_distance()).abs());
    eprintln!("videos against images: largest difference {worst:e}");
    assert!(worst < 1e-9, "the videos' rig differs by {worst:e}");
}

/// Runs `calibrate --images set` with `extra`, expects a failure whose message holds every one of
/// `expected`, and that neither the rig nor the report was written.
fn fails(set: &Path, extra: &[&str], expected: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let rig = dir.path().join("out_rig.json");
    let report = dir.path().join("out_report.json");
    let out = calibrate(set, &rig, &report, extra);
    let stderr = text(&out.stderr);
    assert!(!out.status.success(), "succeeded: {}", text(&out.stdout));
    for e in expected {
        assert!(stderr.contains(e), "'{e}' not in: {stderr}");
    }
    assert!(!rig.exists(), "{} written on failure", rig.display());
    assert!(!report.exists(), "{} written on failure", report.display());
    eprintln!("{}", stderr.trim_end());
}

const SHARED: [&str; 6] = [
    "--port",
    "shared",
    "--glass",
    "0.014:1.473",
    "--index-air",
    "1.003",
];

#[test]
fn a_camera_folder_missing_from_air_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let set = dir.path().join("set");
    copy_tree(&shared_pair().set, &set, &|path| {
        path.ends_with("air/right")
    });
    fails(&set, &SHARED, &["air", "right"]);
}

#[test]
fn water_cameras_with_different_frame_counts_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let set = dir.path().join("set");
    copy_tree(&shared_pair().set, &set, &|path| {
        path.ends_with("water/right/view_029.png")
    });
    fails(&set, &SHARED, &["water", "right", "29", "30"]);
}

#[test]
fn an_unknown_dictionary_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let board = dir.path().join("board.json");
    std::fs::write(
        &board,
        r#"{"type": "charuco", "squares_x": 7, "squares_y": 5, "square_size": 0.04, "marker_size": 0.03, "dictionary": "DICT_9X9_7", "legacy_pattern": false}"#,
    )
    .unwrap();
    let set = &shared_pair().set;
    let rig = dir.path().join("out_rig.json");
    let report = dir.path().join("out_report.json");
    let out = flatport(&[
        "calibrate",
        "--images",
        p(set),
        "--board",
        p(&board),
        "--port",
        "shared",
        "-q",
        "--output",
        p(&rig),
        "--report",
        p(&report),
    ]);
    let stderr = text(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("board.json") && stderr.contains("DICT_9X9_7"),
        "{stderr}"
    );
    assert!(!rig.exists() && !report.exists());
    eprintln!("{}", stderr.trim_end());
}

#[test]
fn a_video_that_cannot_be_decoded_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let set = dir.path().join("set");
    copy_tree(&shared_pair().set, &set, &|path| {
        path.parent().is_some_and(|d| d.ends_with("water/right"))
    });
    std::fs::write(
        set.join("water/right/right.mp4"),
        b"this is not a video, only some text in a file named .mp4",
    )
    .unwrap();
    fails(&set, &SHARED, &["right.mp4"]);
}

#[test]
fn no_frame_that_two_cameras_see_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let set = dir.path().join("set");
    copy_tree(&shared_pair().set, &set, &|_| false);
    // The left camera sees the board only in even frames, the right one only in odd frames.
    let blank = image::GrayImage::from_pixel(1280, 1024, image::Luma([128]));
    for v in 0..30 {
        let camera = if v % 2 == 0 { "right" } else { "left" };
        let path = set
            .join("water")
            .join(camera)
            .join(format!("view_{v:03}.png"));
        std::fs::remove_file(&path).unwrap();
        blank.save(&path).unwrap();
    }
    fails(
        &set,
        &SHARED,
        &["right", "never sees the board in a frame together with"],
    );
}

#[test]
fn images_without_port_are_refused() {
    fails(&shared_pair().set, &["--glass", "0.014:1.473"], &["--port"]);
}

#[test]
fn glass_for_an_unknown_camera_is_named() {
    fails(
        &shared_pair().set,
        &["--port", "housings", "--glass", "middle=0.01:1.49"],
        &["middle", "left, right"],
    );
}
