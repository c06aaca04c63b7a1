//! The calibration accuracy study of docs/accuracy.md: axis and air-layer errors against pixel noise
//! and against the number of views, over random simulated scenes, for each method.
//!
//! Scene: the example rig (data/example_rig.json: two 1280×1024 cameras, f = 864.91 px, mild
//! distortion, 6 cm baseline, right camera turned 1°), a 14 mm glass port (n = 1.473) at
//! 20 mm air, water 1.333, the axis tilted 8° at a random azimuth per trial; a 9×6 board of
//! 40 mm squares at random poses seen whole by both cameras. Every calibration starts from the
//! naive rig: axis on the camera's z axis, 10 mm air layer.
//!
//! The `rigs` tables: the calibration (`calibrate`, method `auto`) of the rigs of
//! issue 10 (`tests/common/rigs.rs`, shared with the tests: one camera in a housing, four cameras
//! behind one window, two housings, a stereo pair behind one port), each from the naive start
//! (every axis on its camera's z axis, 10 mm of air), 0.125 px of noise, a 9×6 board of 40 mm
//! squares at random poses from the library's simulator (`simulate`: seen whole by the
//! master, by the other cameras when they see it whole). The stereo pair's in-air extrinsics are
//! off by the size OpenCV's `stereoCalibrate` gave (0.15° in R, 3 mm in T), calibrated with them
//! held fixed and with `extrinsics` estimated. Errors: the angle between the found and the true
//! axis of each port and |found − true| air distance (in the port's own frame).
//!
//! Run: `cargo run --release --example accuracy_study [TRIALS] [SECTIONS]` (default 50 trials,
//! every section; SECTIONS is a comma-separated subset of `stereo` (the noise and views tables of
//! the stereo methods) and `rigs`); prints Markdown.

#[path = "../tests/common/rigs.rs"]
mod rigs;

use flatport::calib::simulate::rng::Rng;
use flatport::calib::{Board, Estimate, Method, Options, SceneSpec, Target, calibrate, simulate};
use flatport::io::rig_from_json_str;
use flatport::model::{Rig, normal_from_tilt_azimuth};
use nalgebra::Vector3;
use rayon::prelude::*;

const METHODS: [Method; 3] = [Method::Consecutive, Method::Simultaneous, Method::Auto];

/// (axis error °, |air error| mm, seconds) per method for one random scene.
fn trial(views: usize, noise: f64, seed: u64) -> Trial {
    let base =
        rig_from_json_str(include_str!("../data/example_rig.json"), "example".as_ref()).unwrap();
    let azimuth = Rng::new(seed ^ 0xA5A5).range(-180.0, 180.0);
    let n = normal_from_tilt_azimuth(8f64.to_radians(), azimuth.to_radians());
    let truth = base
        .with_interface(
            base.shared_interface()
                .unwrap()
                .with_pose(n.into_inner(), 0.02)
                .unwrap(),
        )
        .unwrap();
    let start = truth
        .with_interface(
            truth
                .shared_interface()
                .unwrap()
                .with_pose(Vector3::z(), 0.01)
                .unwrap(),
        )
        .unwrap();
    let board = Target::Board(Board {
        rows: 6,
        cols: 9,
        square: 0.04,
    });
    let scene = simulate(&truth, &SceneSpec::pair(board, views, noise, seed, 0, 1)).unwrap();
    METHODS
        .iter()
        .map(|&method| {
            let options = Options {
                method,
                ..Default::default()
            };
            match calibrate(&start, &scene.observations, &options) {
                Ok(c) => {
                    let port = c.rig.shared_interface().expect("a shared port");
                    (
                        port.normal().angle(&n).to_degrees(),
                        (port.air_distance() - 0.02).abs() * 1e3,
                        c.report.seconds,
                    )
                }
                Err(_) => (f64::INFINITY, f64::INFINITY, f64::NAN),
            }
        })
        .collect()
}

fn percentile(values: &mut [f64], q: f64) -> f64 {
    values.sort_by(f64::total_cmp);
    values[((values.len() - 1) as f64 * q).round() as usize]
}

/// (axis error °, |air error| mm, seconds) of each method in one scene.
type Trial = Vec<(f64, f64, f64)>;

fn table(label: &str, rows: &[(String, Vec<Trial>)]) {
    println!(
        "| {label} | method | axis median (°) | axis 95 % (°) | air median (mm) | air 95 % (mm) | time median (s) |"
    );
    println!("|---|---|---|---|---|---|---|");
    for (name, trials) in rows {
        for (m, method) in METHODS.iter().enumerate() {
            let mut axis: Vec<f64> = trials.iter().map(|t| t[m].0).collect();
            let mut air: Vec<f64> = trials.iter().map(|t| t[m].1).collect();
            let mut time: Vec<f64> = trials
                .iter()
                .map(|t| t[m].2)
                .filter(|t| t.is_finite())
                .collect();
            println!(
                "| {name} | {} | {:.4} | {:.4} | {:.3} | {:.3} | {:.2} |",
                method.name(),
                percentile(&mut axis, 0.5),
                percentile(&mut axis, 0.95),
                percentile(&mut air, 0.5),
                percentile(&mut air, 0.95),
                percentile(&mut time, 0.5)
            );
        }
    }
    println!();
}

/// One row of the `rigs` tables: a true rig, the rig the calibration starts from, the views per
/// scene, what is estimated, and issue 10's bound (axis °, air mm) where it sets one.
struct RigCase {
    name: &'static str,
    truth: Rig,
    start: Rig,
    views: usize,
    estimate: Estimate,
    target: Option<(f64, f64)>,
}

fn rig_cases() -> Vec<RigCase> {
    let case = |name, truth: Rig, views, target| RigCase {
        name,
        start: rigs::naive(&truth),
        truth,
        views,
        estimate: Estimate::default(),
        target,
    };
    let stereo = rigs::stereo();
    let off = rigs::naive(&stereo)
        .with_extrinsics(
            1,
            rigs::opencv_error() * stereo.cameras()[1].cam_from_master,
        )
        .unwrap();
    vec![
        case(
            "one camera, 10 views",
            rigs::one_camera(),
            10,
            Some((0.2, 3.2)),
        ),
        case(
            "four cameras behind one port, 12 views",
            rigs::four_cameras(),
            12,
            Some((0.04, 1.0)),
        ),
        case(
            "two housings, 12 views",
            rigs::two_housings(),
            12,
            Some((0.07, 1.0)),
        ),
        RigCase {
            name: "stereo, extrinsics 0.15°/3 mm off, 15 views",
            truth: stereo.clone(),
            start: off.clone(),
            views: 15,
            estimate: Estimate::default(),
            target: None,
        },
        RigCase {
            name: "stereo, extrinsics 0.15°/3 mm off, 15 views",
            truth: stereo,
            start: off,
            views: 15,
            estimate: Estimate::parse("axis,distance,extrinsics").unwrap(),
            target: Some((0.15, 3.0)),
        },
    ]
}

/// (axis error °, |air error| mm) of every port, seconds and RMS reprojection error (px) of one
/// scene of `case` at `noise` px; infinite errors when the calibration fails or does not fit.
fn rig_trial(case: &RigCase, noise: f64, seed: u64) -> (Vec<(f64, f64)>, f64, f64) {
    let ports = rigs::ports(&case.truth);
    let failed = (
        vec![(f64::INFINITY, f64::INFINITY); ports.len()],
        f64::NAN,
        f64::INFINITY,
    );
    let scene = simulate(
        &case.truth,
        &SceneSpec::new(rigs::board(), case.views, noise, seed),
    )
    .unwrap();
    let options = Options {
        estimate: case.estimate,
        ..Options::default()
    };
    match calibrate(&case.start, &scene.observations, &options) {
        Ok(c) if c.report.fits => (
            ports
                .iter()
                .zip(rigs::ports(&c.rig))
                .map(|(truth, found)| {
                    (
                        truth.normal().angle(found.normal()).to_degrees(),
                        (truth.air_distance() - found.air_distance()).abs() * 1e3,
                    )
                })
                .collect(),
            c.report.seconds,
            c.report.rms_px,
        ),
        _ => failed,
    }
}

fn rig_table(trials: u64, noise: f64) {
    println!(
        "| rig ({noise} px, naive start) | estimate | port | axis median (°) | axis 90 % (°) | air median (mm) | air 90 % (mm) | issue target (°, mm) | RMS median (px) | failed | time median (s) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for case in rig_cases() {
        let results: Vec<_> = (0..trials)
            .into_par_iter()
            .map(|s| rig_trial(&case, noise, 7000 + s))
            .collect();
        let failed = results.iter().filter(|(_, t, _)| t.is_nan()).count();
        let rms = percentile(&mut results.iter().map(|r| r.2).collect::<Vec<_>>(), 0.5);
        let mut time: Vec<f64> = results
            .iter()
            .map(|(_, t, _)| *t)
            .filter(|t| t.is_finite())
            .collect();
        let time = if time.is_empty() {
            f64::NAN
        } else {
            percentile(&mut time, 0.5)
        };
        let names: Vec<String> = match case.truth.ports() {
            flatport::model::Ports::Shared(_) => vec!["shared".into()],
            flatport::model::Ports::PerCamera(_) => case
                .truth
                .cameras()
                .iter()
                .map(|c| c.name.clone())
                .collect(),
        };
        for (p, port) in names.iter().enumerate() {
            let mut axis: Vec<f64> = results.iter().map(|(e, _, _)| e[p].0).collect();
            let mut air: Vec<f64> = results.iter().map(|(e, _, _)| e[p].1).collect();
            let target = case
                .target
                .map_or("—".to_string(), |(a, d)| format!("{a}, {d}"));
            println!(
                "| {} | {} | {port} | {:.4} | {:.4} | {:.3} | {:.3} | {target} | {rms:.3} | {failed} | {time:.2} |",
                case.name,
                case.estimate.name(),
                percentile(&mut axis, 0.5),
                percentile(&mut axis, 0.9),
                percentile(&mut air, 0.5),
                percentile(&mut air, 0.9),
            );
        }
    }
    println!();
}

fn main() {
    let trials: u64 = std::env::args()
        .nth(1)
        .map_or(50, |t| t.parse().expect("TRIALS is a number"));
    let sections = std::env::args().nth(2).unwrap_or("stereo,rigs".into());
    let sections: Vec<&str> = sections.split(',').map(str::trim).collect();
    if let Some(s) = sections.iter().find(|s| !["stereo", "rigs"].contains(s)) {
        panic!("unknown section '{s}': SECTIONS is a comma-separated subset of stereo, rigs");
    }
    println!(
        "{trials} random scenes per row; errors are the angle between the found and the true axis and |found − true| air layer.\n"
    );
    if sections.contains(&"stereo") {
        stereo_tables(trials);
    }
    if sections.contains(&"rigs") {
        rig_table(trials, 0.125);
    }
}

/// The noise and views tables of the stereo methods.
fn stereo_tables(trials: u64) {
    let noise_rows: Vec<(String, Vec<_>)> = [0.0, 0.1, 0.25, 0.5, 1.0]
        .iter()
        .map(|&noise| {
            let results = (0..trials)
                .into_par_iter()
                .map(|s| trial(15, noise, 1000 + s))
                .collect();
            (format!("{noise} px"), results)
        })
        .collect();
    table("noise (15 views)", &noise_rows);
    let view_rows: Vec<(String, Vec<_>)> = [5, 10, 15, 20, 30]
        .iter()
        .map(|&views| {
            let results = (0..trials)
                .into_par_iter()
                .map(|s| trial(views, 0.25, 5000 + s))
                .collect();
            (format!("{views} views"), results)
        })
        .collect();
    table("views (0.25 px)", &view_rows);
}
