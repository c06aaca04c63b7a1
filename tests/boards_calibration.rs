//! A whole rig from partial board views under water (`calib::pipeline::boards`): the extrinsics
//! started from the co-observations, then the ports, the extrinsics and the board poses by
//! maximum likelihood, on the three rig kinds of issue 38 (a bare water surface over four
//! cameras, a stereo pair behind one port with glass, three cameras in their own housings), with
//! the cameras' in-air calibration exact. The frames are the exact forward projections of a board
//! placed at random in front of the rig (corners outside an image dropped: partial boards, and
//! frames only one camera sees), plus Gaussian noise: the truth is independent of the fit.

#[path = "common/rigs.rs"]
mod rigs;

use flatport::calib::Board;
use flatport::calib::pipeline::boards::{
    BoardsOptions, PortKind, RigSetup, WaterFrame, calibrate_from_boards,
};
use flatport::model::{Interface, Layer, Ports, Rig, normal_from_tilt_azimuth};
use nalgebra::{Isometry3, Matrix3, Point2, Point3, Translation3, UnitQuaternion, Vector3};

const BOARD: Board = Board {
    rows: 6,
    cols: 8,
    square: 0.04,
};

/// xorshift64* with Box–Muller: the frames' poses and noise (no dependency on the crate's RNG).
struct Rng(u64);

impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.uniform()
    }
    fn gauss(&mut self) -> f64 {
        let (u, v) = (self.uniform().max(1e-300), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// `count` frames of `BOARD` in front of `rig` at `depth` metres (a range), turned up to 40°,
/// each corner the exact projection into every camera that sees it inside its image (5 px
/// margin), plus `noise_px` of Gaussian noise per coordinate.
fn frames(rig: &Rig, count: usize, depth: (f64, f64), noise_px: f64, seed: u64) -> Vec<WaterFrame> {
    frames_of(&BOARD, rig, count, depth, noise_px, seed, 5.0)
}

/// [`frames`] of `board`, the corners kept `margin_px` inside each image.
fn frames_of(
    board: &Board,
    rig: &Rig,
    count: usize,
    depth: (f64, f64),
    noise_px: f64,
    seed: u64,
    margin_px: f64,
) -> Vec<WaterFrame> {
    let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
    let cameras: Vec<_> = (0..rig.cameras().len())
        .map(|k| rig.refractive_camera(k))
        .collect();
    let centre = board.centre_in_board();
    let mut out = Vec::new();
    while out.len() < count {
        let z = rng.range(depth.0, depth.1);
        let position = Vector3::new(rng.range(-0.35, 0.35) * z, rng.range(-0.3, 0.3) * z, z);
        let tilt = rng.range(0.0, 40f64.to_radians());
        let towards = rng.range(0.0, std::f64::consts::TAU);
        let axis = Vector3::new(towards.cos(), towards.sin(), 0.0);
        let rotation = UnitQuaternion::from_scaled_axis(axis * tilt)
            * UnitQuaternion::from_scaled_axis(Vector3::z() * rng.range(-0.6, 0.6));
        let master_from_board = Isometry3::from_parts(Translation3::from(position), rotation)
            * Translation3::from(-centre.coords);
        let mut corners = vec![Vec::new(); cameras.len()];
        for (k, camera) in cameras.iter().enumerate() {
            let intrinsics = &rig.cameras()[k].intrinsics;
            for i in 0..board.corners() {
                let point = master_from_board * board.point_in_board(i);
                let Ok(pixel) = camera.project(&point) else {
                    continue;
                };
                let noisy = Point2::new(
                    pixel.x + noise_px * rng.gauss(),
                    pixel.y + noise_px * rng.gauss(),
                );
                let inside =
                    |p: f64, size: u32| (margin_px..size as f64 - 1.0 - margin_px).contains(&p);
                if inside(noisy.x, intrinsics.width) && inside(noisy.y, intrinsics.height) {
                    corners[k].push((i, noisy));
                }
            }
        }
        if corners.iter().any(|c| c.len() >= 6) {
            out.push(WaterFrame {
                label: format!("{:04}", out.len()),
                corners,
            });
        }
    }
    out
}

fn setup(rig: &Rig, port: PortKind) -> (Vec<String>, RigSetup) {
    let ports = rigs::ports(rig);
    let first = &ports[0];
    let glass = match rig.ports() {
        Ports::Shared(p) => vec![p.layers().to_vec()],
        Ports::PerCamera(ports) => ports.iter().map(|p| p.layers().to_vec()).collect(),
    };
    (
        rig.cameras().iter().map(|c| c.name.clone()).collect(),
        RigSetup {
            cameras: rig.cameras().iter().map(|c| c.intrinsics).collect(),
            port,
            glass,
            index_air: first.index_air(),
            index_water: first.index_water(),
        },
    )
}

/// The worst errors of `found` against `truth`: extrinsics (°, mm), axes (°), air layers (mm).
fn errors(found: &Rig, truth: &Rig) -> (f64, f64, f64, f64) {
    let mut rotation: f64 = 0.0;
    let mut translation: f64 = 0.0;
    for (f, t) in found.cameras().iter().zip(truth.cameras()) {
        let e = f.cam_from_master.inverse() * t.cam_from_master;
        rotation = rotation.max(e.rotation.angle().to_degrees());
        translation = translation.max((f.centre_in_master() - t.centre_in_master()).norm() * 1e3);
    }
    let mut axis: f64 = 0.0;
    let mut air: f64 = 0.0;
    for (f, t) in rigs::ports(found).iter().zip(rigs::ports(truth)) {
        axis = axis.max(f.normal().angle(t.normal()).to_degrees());
        air = air.max((f.air_distance() - t.air_distance()).abs() * 1e3);
    }
    (rotation, translation, axis, air)
}

fn calibrate(truth: &Rig, port: PortKind, depth: (f64, f64), noise: f64, seed: u64) -> (Rig, f64) {
    let (names, setup) = setup(truth, port);
    let frames = frames(truth, 40, depth, noise, seed);
    let result = calibrate_from_boards(
        &names,
        &setup,
        &BOARD,
        &frames,
        &BoardsOptions::default(),
        &mut |_| {},
    )
    .unwrap();
    let report = &result.calibration.report;
    assert!(report.fits, "{:?}\n{:?}", report.warnings, report.diagnosis);
    let validation = result.validation.expect("frames held out");
    eprintln!(
        "{port:?}: RMS {:.3} px, held out {} frames: {:.3} px, corner distances median {:.4} % ({} pairs); links {:?}; dropped {:?}",
        report.rms_px,
        validation.frames.len(),
        validation.rms_px,
        validation.median_error_percent,
        validation.distances,
        result.links,
        result.dropped
    );
    (result.calibration.rig, validation.median_error_percent)
}

/// Four cameras above one bare water surface (tilted 2°, 250 mm of air), boards 0.6–1.4 m away.
fn surface_rig() -> Rig {
    let four = rigs::four_cameras();
    let n = normal_from_tilt_azimuth(2f64.to_radians(), 0.5);
    let surface = Interface::new(n.into_inner(), 0.25, vec![], 1.0, 1.333).unwrap();
    Rig::new(four.cameras().to_vec(), surface).unwrap()
}

/// Three cameras 15 cm apart in their own housings (8 mm of acrylic, each port tilted its own way).
fn three_housings() -> Rig {
    let cameras = vec![
        rigs::camera("a", 2.0, 0.0, [-0.15, 0.0, 0.0]),
        rigs::camera("b", 0.0, 1.0, [0.0, 0.0, 0.0]),
        rigs::camera("c", -2.0, 0.0, [0.15, 0.0, 0.0]),
    ];
    let port = |tilt: f64, azimuth: f64, air: f64| {
        let n = normal_from_tilt_azimuth(tilt.to_radians(), azimuth.to_radians());
        Interface::new(
            n.into_inner(),
            air,
            vec![Layer {
                thickness: 0.008,
                index: 1.49,
            }],
            1.0,
            1.333,
        )
        .unwrap()
    };
    let ports = Ports::PerCamera(vec![
        port(4.0, 30.0, 0.015),
        port(3.0, 200.0, 0.02),
        port(5.0, 120.0, 0.012),
    ]);
    // The master is "a": express the others relative to it.
    let master = cameras[0].cam_from_master;
    let cameras = cameras
        .into_iter()
        .map(|mut c| {
            c.cam_from_master *= master.inverse();
            c
        })
        .collect();
    Rig::with_ports(cameras, ports).unwrap()
}

/// The median error of points triangulated through `found` from their exact pixels under
/// `truth` (every camera that sees a point inside its image), as a share of the point's distance
/// from the master camera, percent: the calibration's error in 3-D, without the corners' noise.
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
                for k in 0..truth.cameras().len() {
                    let intrinsics = &truth.cameras()[k].intrinsics;
                    let Ok(pixel) = truth.refractive_camera(k).project(&point) else {
                        continue;
                    };
                    let inside = |p: f64, size: u32| (0.0..size as f64 - 1.0).contains(&p);
                    if !inside(pixel.x, intrinsics.width) || !inside(pixel.y, intrinsics.height) {
                        continue;
                    }
                    let Ok(ray) = found.refractive_camera(k).backproject(&pixel) else {
                        continue;
                    };
                    let d = ray.dir.into_inner();
                    let m = Matrix3::identity() - d * d.transpose();
                    normal += m;
                    right += m * ray.origin.coords;
                    rays += 1;
                }
                if rays < 2 {
                    continue;
                }
                if let Some(inverse) = normal.try_inverse() {
                    let error = (inverse * right - point.coords).norm();
                    errors.push(100.0 * error / point.coords.norm());
                }
            }
        }
    }
    assert!(
        errors.len() > 100,
        "{} points seen by two cameras",
        errors.len()
    );
    errors.sort_by(f64::total_cmp);
    errors[errors.len() / 2]
}

fn check(kind: PortKind, truth: &Rig, depth: (f64, f64)) {
    let (found, _) = calibrate(truth, kind, depth, 0.08, 3);
    let (rotation, translation, axis, air) = errors(&found, truth);
    let median_percent = triangulation_error_percent(&found, truth, depth);
    eprintln!(
        "{kind:?}: extrinsics {rotation:.4}° {translation:.3} mm, axes {axis:.4}°, air {air:.3} mm, triangulated points {median_percent:.4} % of their distance"
    );
    // Issue 38's bounds for the one command with default options.
    assert!(
        rotation < 0.05 && translation < 1.0,
        "extrinsics {rotation}° {translation} mm"
    );
    assert!(axis < 0.1, "axis {axis}°");
    let air_bound = if kind == PortKind::Surface { 0.3 } else { 1.5 };
    assert!(air < air_bound, "air {air} mm");
    assert!(
        median_percent < 0.06,
        "triangulated points {median_percent} %"
    );
}

#[test]
fn four_cameras_above_a_water_surface() {
    check(PortKind::Surface, &surface_rig(), (0.6, 1.4));
}

#[test]
fn a_stereo_pair_behind_one_port() {
    check(PortKind::Shared, &rigs::stereo(), (0.5, 1.3));
}

#[test]
fn three_cameras_in_their_own_housings() {
    check(PortKind::Housings, &three_housings(), (0.6, 1.4));
}

/// Zoo seed 7's rig: eight cameras in their own housings, 0.24 m apart and turned up to 30° from
/// each other, wide lenses (k1 ≈ −0.2), a 9x4-corner board of 36 mm squares 0.39–0.78 m away.
/// Two starts failed here: each port's search started its camera's board poses from another
/// camera's pinhole pose carried over by the start's extrinsics, and from pinhole poses, which
/// place a wide lens's edge corners where no ray through the port reaches (these frames: "no
/// axis within a tilt of 30.0° explains the corners of port 5"); and the extrinsics' start from
/// the pinhole poses of the apparent boards was 2–6° and 2–9 cm off (each housing compresses its
/// camera's apparent board along its own axis), the fit from it stopping at 13 px on the
/// rendered set (refused: "the square size is twice the true one"). Each camera's poses started
/// from its own corners bent into the water, and the extrinsics linked again through the ports
/// found, it fits within issue 38's bounds.
#[test]
fn eight_housings_turned_from_each_other() {
    let zoo = flatport::calib::simulate::zoo::zoo_rig(7).unwrap();
    let board = flatport::io::board_from_json_str(&zoo.board.json(), "zoo_7.json".as_ref())
        .unwrap()
        .corner_grid();
    let truth = &zoo.rig;
    let depth = zoo.water_distance();
    let (names, setup) = setup(truth, PortKind::Housings);
    // The corners 60 px inside the images (the render's margin is 40 px).
    let frames = frames_of(&board, truth, 30, depth, 0.08, 7, 60.0);
    let result = calibrate_from_boards(
        &names,
        &setup,
        &board,
        &frames,
        &BoardsOptions::default(),
        &mut |_| {},
    )
    .unwrap();
    let report = &result.calibration.report;
    let (rotation, translation, axis, air) = errors(&result.calibration.rig, truth);
    eprintln!(
        "zoo seed 7 rig: RMS {:.3} px, extrinsics {rotation:.4}° {translation:.3} mm, axes {axis:.4}°, air {air:.3} mm; {}; stages {:?}",
        report.rms_px,
        report.strategy,
        report
            .stages
            .iter()
            .map(|s| format!("{}: {:.3} {}", s.name, s.cost, s.unit))
            .collect::<Vec<_>>()
    );
    assert!(report.fits, "{:?}\n{:?}", report.warnings, report.diagnosis);
    assert!(
        rotation < 0.05 && translation < 1.0,
        "extrinsics {rotation}° {translation} mm"
    );
    assert!(axis < 0.1 && air < 1.5, "axis {axis}°, air {air} mm");
}

#[test]
fn a_camera_that_never_meets_the_others_is_named() {
    let truth = rigs::stereo();
    let (names, setup) = setup(&truth, PortKind::Shared);
    let mut frames = frames(&truth, 12, (0.5, 1.3), 0.0, 5);
    for (f, frame) in frames.iter_mut().enumerate() {
        // The right camera's images only in frames the left one did not see.
        frame.corners[f % 2].clear();
    }
    let error = calibrate_from_boards(
        &names,
        &setup,
        &BOARD,
        &frames,
        &BoardsOptions::default(),
        &mut |_| {},
    )
    .unwrap_err()
    .to_string();
    assert!(
        error.contains("camera 'right' never sees the board"),
        "{error}"
    );
}

/// Issue 38's defect: three cameras in their own housings (ports tilted up to 10°, a 0.5 m
/// spread), extrinsics estimated, started at the true extrinsics and the naive ports, must fit
/// down to the noise (it stopped at 1.95 px and was refused).
#[test]
fn housings_with_extrinsics_from_the_naive_ports() {
    let cameras = vec![
        rigs::camera("a", 6.0, 0.0, [-0.25, 0.0, 0.0]),
        rigs::camera("b", 0.0, 2.0, [0.0, 0.02, 0.0]),
        rigs::camera("c", -6.0, 0.0, [0.25, 0.0, 0.0]),
    ];
    let port = |tilt: f64, azimuth: f64, air: f64| {
        let n = normal_from_tilt_azimuth(tilt.to_radians(), azimuth.to_radians());
        Interface::new(
            n.into_inner(),
            air,
            vec![Layer {
                thickness: 0.01,
                index: 1.49,
            }],
            1.0,
            1.333,
        )
        .unwrap()
    };
    let master = cameras[0].cam_from_master;
    let cameras: Vec<_> = cameras
        .into_iter()
        .map(|mut c| {
            c.cam_from_master *= master.inverse();
            c
        })
        .collect();
    let truth = Rig::with_ports(
        cameras,
        Ports::PerCamera(vec![
            port(8.0, 30.0, 0.02),
            port(6.0, 200.0, 0.025),
            port(10.0, 120.0, 0.015),
        ]),
    )
    .unwrap();
    let (names, setup) = setup(&truth, PortKind::Housings);
    let frames = frames(&truth, 30, (0.7, 1.6), 0.08, 11);
    let observations = flatport::calib::Observations {
        target: flatport::calib::Target::Board(BOARD),
        views: frames
            .iter()
            .filter_map(|f| {
                let images: Vec<_> = f
                    .corners
                    .iter()
                    .enumerate()
                    .filter(|(_, c)| c.len() >= 6)
                    .map(|(k, c)| {
                        let mut full = vec![None; BOARD.corners()];
                        for (i, p) in c {
                            full[*i] = Some(*p);
                        }
                        flatport::calib::Image {
                            camera: flatport::calib::CameraKey::Name(names[k].clone()),
                            key: names[k].clone(),
                            corners: full,
                        }
                    })
                    .collect();
                (!images.is_empty()).then_some(flatport::calib::View { images })
            })
            .collect(),
        stereo_form: false,
    };
    let _ = setup;
    let options = flatport::calib::Options {
        estimate: flatport::calib::Estimate::parse("axis,distance,extrinsics").unwrap(),
        ..Default::default()
    };
    let calibration =
        flatport::calib::calibrate(&rigs::naive(&truth), &observations, &options).unwrap();
    let report = &calibration.report;
    let (rotation, translation, axis, air) = errors(&calibration.rig, &truth);
    eprintln!(
        "housings from the naive ports: RMS {:.3} px, extrinsics {rotation:.4}° {translation:.3} mm, axes {axis:.4}°, air {air:.3} mm; {}; {:?}",
        report.rms_px, report.strategy, report.warnings
    );
    assert!(report.fits, "{:?} {:?}", report.warnings, report.diagnosis);
    assert!(axis < 0.1 && air < 1.5, "axis {axis}°, air {air} mm");
}

/// The in-air intrinsics slightly off, as an in-air calibration leaves them (fx +0.1 % and
/// −0.1 %, k1 +0.003 and −0.003 in the two cameras of the stereo pair): the calibration with
/// them fixed, and the default, which refines them where the held-out frames' RMS falls by more
/// than the margin. Prints both held-out RMS values, the port's and the triangulation's errors of
/// each; the choice follows the margin rule and, where refined, the result is no worse in 3-D.
#[test]
fn in_air_intrinsics_slightly_off_are_refined_where_the_held_out_frames_say_so() {
    use flatport::calib::pipeline::boards::{REFINE_MARGIN, RefineIntrinsics};
    let truth = rigs::stereo();
    let depth = (0.5, 1.3);
    let (names, mut setup) = setup(&truth, PortKind::Shared);
    for (camera, sign) in setup.cameras.iter_mut().zip([1.0, -1.0]) {
        camera.fx *= 1.0 + sign * 1e-3;
        camera.distortion[0] += sign * 3e-3;
    }
    let frames = frames(&truth, 40, depth, 0.08, 5);
    let run = |refine: RefineIntrinsics| {
        let options = BoardsOptions {
            refine_intrinsics: refine,
            ..BoardsOptions::default()
        };
        calibrate_from_boards(&names, &setup, &BOARD, &frames, &options, &mut |_| {}).unwrap()
    };
    let fixed = run(RefineIntrinsics::Never);
    assert!(fixed.intrinsics.is_none());
    let auto = run(RefineIntrinsics::Auto);
    let choice = auto.intrinsics.clone().expect("frames held out: a choice");
    let fixed_held_out = fixed.validation.as_ref().unwrap().rms_px;
    assert!((choice.fixed_rms_px - fixed_held_out).abs() < 1e-12);
    assert_eq!(
        choice.refined,
        choice.refined_rms_px < (1.0 - REFINE_MARGIN) * choice.fixed_rms_px
    );
    let describe = |result: &flatport::calib::pipeline::boards::BoardsCalibration| {
        let rig = &result.calibration.rig;
        let (rotation, translation, axis, air) = errors(rig, &truth);
        let median = triangulation_error_percent(rig, &truth, depth);
        let c: Vec<String> = rig
            .cameras()
            .iter()
            .zip(truth.cameras())
            .map(|(f, t)| {
                format!(
                    "fx {:+.3} px, cx {:+.3} px, k1 {:+.5}",
                    f.intrinsics.fx - t.intrinsics.fx,
                    f.intrinsics.cx - t.intrinsics.cx,
                    f.intrinsics.distortion[0] - t.intrinsics.distortion[0]
                )
            })
            .collect();
        eprintln!(
            "extrinsics {rotation:.4}° {translation:.3} mm, axis {axis:.4}°, air {air:.3} mm, triangulated points {median:.4} %; intrinsics off by {c:?}"
        );
        median
    };
    eprint!("in-air intrinsics fixed: ");
    let fixed_error = describe(&fixed);
    eprint!("default (refined: {}): ", choice.refined);
    let auto_error = describe(&auto);
    eprintln!("{}", choice.reason);
    if choice.refined {
        assert!(
            auto_error <= fixed_error,
            "refined {auto_error} % against fixed {fixed_error} %"
        );
    }
}
