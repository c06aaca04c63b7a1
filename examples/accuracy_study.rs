//! The calibration accuracy study of the README: axis and air-layer errors against pixel noise
//! and against the number of views, over random simulated scenes, for each method.
//!
//! Scene: the example rig (data/example_rig.json: two 1280×1024 cameras, f = 864.91 px, mild
//! distortion, 6 cm baseline, right camera turned 1°), a 14 mm glass port (n = 1.473) at
//! 20 mm air, water 1.333, the axis tilted 8° at a random azimuth per trial; a 9×6 board of
//! 40 mm squares at random poses seen whole by both cameras. Every calibration starts from the
//! naive rig: axis on the camera's z axis, 10 mm air layer.
//!
//! Run: `cargo run --release --example accuracy_study [TRIALS]` (default 50); prints Markdown.

use flatport::calib::simulate::rng::Rng;
use flatport::calib::{
    Board, CalibrationOptions, CpuBackend, Method, SceneSpec, StereoData, calibrate, simulate,
};
use flatport::io::rig_from_json_str;
use flatport::model::normal_from_tilt_azimuth;
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
    let scene = simulate(
        &truth,
        0,
        1,
        &SceneSpec::new(
            Board {
                rows: 6,
                cols: 9,
                square: 0.04,
            },
            views,
            noise,
            seed,
        ),
    )
    .unwrap();
    let data = StereoData::new(&start, [0, 1], &scene.observations).unwrap();
    METHODS
        .iter()
        .map(|&method| {
            match calibrate(
                &CpuBackend::new(&data),
                &CalibrationOptions {
                    method,
                    ..Default::default()
                },
                vec![],
            ) {
                Ok(c) => (
                    c.interface.normal().angle(&n).to_degrees(),
                    (c.interface.air_distance() - 0.02).abs() * 1e3,
                    c.report.seconds,
                ),
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

fn main() {
    let trials: u64 = std::env::args()
        .nth(1)
        .map_or(50, |t| t.parse().expect("TRIALS is a number"));
    println!(
        "{trials} random scenes per row; errors are the angle between the found and the true axis and |found − true| air layer.\n"
    );
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
