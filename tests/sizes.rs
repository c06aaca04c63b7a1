//! Sizes: the bundle's block (Schur) normal equations against a dense solve built here from a
//! finite-difference Jacobian; sizes from user input refused before anything is allocated; a sweep
//! streamed in batches writes the same cost.npy as an independent evaluation of every cell.

use std::path::Path;
use std::process::Command;

use flatport::calib::costs::scene::{SceneRows, axis_costs, profile_cost};
use flatport::calib::pipeline::bundle::{Bundle, State};
use flatport::calib::solvers::lm::{DenseNormalEquations, LeastSquares, NormalEquations};
use flatport::calib::{
    Board, Candidate, CostKind, Estimate, SceneSpec, StereoData, Target, costs::SceneFit, simulate,
};
use flatport::io::rig_from_json_str;
use flatport::model::Rig;
use nalgebra::{DMatrix, DVector};

const EXAMPLE_RIG: &str = include_str!("../data/example_rig.json");

fn example_rig() -> Rig {
    rig_from_json_str(EXAMPLE_RIG, "example".as_ref()).unwrap()
}

fn flatport(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_flatport"))
        .args(args)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .expect("binary runs")
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// Runs flatport and expects a clean failure (exit 1, or 2 for a usage error that clap reports;
/// no panic, no abort) whose message names every one of `words`.
fn refused(args: &[&str], words: &[&str]) -> String {
    let out = flatport(args);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(
        matches!(out.status.code(), Some(1 | 2)),
        "flatport {args:?} should fail cleanly, got {:?}: {stderr}",
        out.status
    );
    assert!(
        !stderr.contains("panicked") && !stderr.contains("memory allocation"),
        "{args:?}: {stderr}"
    );
    for w in words {
        assert!(
            stderr.contains(w),
            "flatport {args:?}: the message should name '{w}': {stderr}"
        );
    }
    stderr
}

/// The dense normal equations of `bundle` at `state`: J by central differences of the bundle's
/// residuals under its retraction (one column per step parameter, step 1e-6), Huber weights
/// k/|r| per corner residual outside the threshold.
fn dense_normal_equations(
    bundle: &Bundle,
    state: &State,
    huber: Option<f64>,
) -> DenseNormalEquations {
    let n = bundle.dimension(state);
    let residuals = |state: &State| -> Vec<nalgebra::Vector2<f64>> {
        bundle.all_residuals(state).unwrap().concat()
    };
    let base = residuals(state);
    let rows = 2 * base.len();
    let h = 1e-6;
    let mut j = DMatrix::zeros(rows, n);
    for k in 0..n {
        let mut delta = DVector::zeros(n);
        delta[k] = h;
        let plus = residuals(&bundle.retract(state, &delta));
        delta[k] = -h;
        let minus = residuals(&bundle.retract(state, &delta));
        for i in 0..base.len() {
            let d = (plus[i] - minus[i]) / (2.0 * h);
            j[(2 * i, k)] = d.x;
            j[(2 * i + 1, k)] = d.y;
        }
    }
    let mut weights = DVector::zeros(rows);
    let mut r = DVector::zeros(rows);
    let mut cost = 0.0;
    for (i, e) in base.iter().enumerate() {
        let length = e.norm();
        let (c, w) = match huber {
            Some(k) if length > k => (2.0 * k * length - k * k, k / length),
            _ => (length * length, 1.0),
        };
        cost += c;
        for (a, value) in [e.x, e.y].into_iter().enumerate() {
            r[2 * i + a] = value;
            weights[2 * i + a] = w;
        }
    }
    let wj = DMatrix::from_fn(rows, n, |a, b| weights[a] * j[(a, b)]);
    DenseNormalEquations {
        jtj: j.transpose() * &wj,
        jtr: wj.transpose() * &r,
        cost,
    }
}

#[test]
fn bundle_schur_step_and_covariance_equal_a_dense_solve() {
    let rig = example_rig();
    let board = Board {
        rows: 4,
        cols: 5,
        square: 0.05,
    };
    let scene = simulate(
        &rig,
        &SceneSpec::pair(Target::Board(board), 5, 0.3, 7, 0, 1),
    )
    .unwrap();
    let data = StereoData::from_observations(&rig, [0, 1], &scene.observations).unwrap();
    let seen = scene.observations.resolve(&rig).unwrap();
    // A state off the truth so the residuals and the gradient are far from zero.
    let truth = Candidate::of(rig.shared_interface().unwrap());
    let start = Candidate {
        normal: flatport::calib::solvers::search::tangent_step(
            &truth.normal,
            &nalgebra::Vector2::new(0.01, -0.004),
        ),
        air_distance: 0.023,
    };
    let cameras = data.cameras_behind(&start).unwrap();
    let poses = SceneFit::new(&data, &cameras).unwrap().poses();
    let mut state = State::of(&rig, poses);
    state.ports[0].normal = start.normal;
    state.ports[0].distance = start.air_distance;
    // The axis (two tangent steps) and the air distance: three global parameters.
    let globals = 3;
    for huber in [None, Some(0.5)] {
        let bundle = Bundle::new(
            &rig,
            &Target::Board(board),
            &seen,
            Estimate::default(),
            huber,
        );
        assert_eq!(bundle.globals().len(), globals);
        let block = bundle.normal_equations(&state).unwrap();
        let dense = dense_normal_equations(&bundle, &state, huber);
        assert_eq!(block.dimension(), dense.jtj.nrows());
        assert!(
            (block.cost - dense.cost).abs() <= 1e-12 * dense.cost,
            "{} vs {}",
            block.cost,
            dense.cost
        );
        let floor = 1e-12 * dense.max_diagonal();
        for damping in [0.0, 1e-4, 1.0] {
            let step = block.solve_damped(damping, floor).unwrap();
            let reference = dense.solve_damped(damping, floor).unwrap();
            let error = (&step - &reference).norm() / reference.norm();
            println!("huber {huber:?}, damping {damping}: step relative error {error:.2e}");
            assert!(
                error < 1e-9,
                "huber {huber:?}, damping {damping}: step relative error {error:e}"
            );
        }
        let inverse = dense.jtj.clone().cholesky().unwrap().inverse();
        let reference = inverse.view((0, 0), (globals, globals)).into_owned();
        let covariance = block.global_covariance().unwrap();
        let error = (&covariance - &reference).norm() / reference.norm();
        println!("huber {huber:?}: covariance relative error {error:.2e}");
        assert!(
            error < 1e-9,
            "huber {huber:?}: covariance relative error {error:e}"
        );
    }
}

/// A small simulated scene in `dir`: (rig, observations).
fn scene(dir: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let out = flatport(&[
        "simulate",
        "--rig",
        "data/example_rig.json",
        "--views",
        "6",
        "--seed",
        "5",
        "--output",
        p(&dir.join("scene")),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    (
        dir.join("scene/rig.json"),
        dir.join("scene/observations.json"),
    )
}

#[test]
fn huge_sizes_from_the_command_line_are_refused_before_allocating() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let o = p(&out);
    let rig = "data/example_rig.json";
    // simulate: views and board size.
    for views in ["18446744073709551615", "10000000000", "185186", "0"] {
        refused(
            &["simulate", "--rig", rig, "--views", views, "--output", o],
            &["--views", views, "1..=185185"],
        );
    }
    refused(
        &[
            "simulate",
            "--rig",
            rig,
            "--board",
            "100000x100000@0.01",
            "--output",
            o,
        ],
        &["--board", "at most 10000"],
    );
    refused(
        &[
            "simulate",
            "--rig",
            rig,
            "--board",
            "4294967296x4294967296@0.01",
            "--output",
            o,
        ],
        &["--board", "at most 10000"],
    );
    assert!(!out.exists(), "nothing is written");
    let (rig, obs) = scene(dir.path());
    let (rig, obs) = (p(&rig), p(&obs));
    // sweep: grid counts (each alone, their product, with a distance grid) and the batch size.
    let sweep = |extra: &[&str], words: &[&str]| {
        let mut args = vec![
            "sweep",
            "--rig",
            rig,
            "--observations",
            obs,
            "--output",
            o,
            "--device",
            "cpu",
            "--quiet",
        ];
        args.extend_from_slice(extra);
        refused(&args, words)
    };
    sweep(
        &[
            "--tilt-deg",
            "0:20:100000",
            "--azimuth-deg",
            "-180:180:100000",
        ],
        &["--tilt-deg", "100000 × 100000", "at most 1000000000 cells"],
    );
    sweep(
        &[
            "--tilt-deg",
            "0:20:18446744073709551615",
            "--azimuth-deg",
            "-180:180:18446744073709551615",
        ],
        &["--tilt-deg", "at most 1000000000 cells"],
    );
    sweep(
        &[
            "--tilt-deg",
            "0:20:10",
            "--azimuth-deg",
            "-180:180:10",
            "--distance",
            "0.01:0.03:18446744073709551615",
        ],
        &["--distance", "at most 1000000000 cells"],
    );
    for chunk in ["0", "18446744073709551615", "1048577"] {
        sweep(
            &[
                "--tilt-deg",
                "0:20:4",
                "--azimuth-deg",
                "-180:180:4",
                "--chunk",
                chunk,
            ],
            &["--chunk", chunk, "1..=1048576"],
        );
    }
    assert!(!out.exists(), "nothing is written");
    // calibrate: the global search grid.
    let rig_out = dir.path().join("calibrated.json");
    for step in ["0.001", "0.01"] {
        refused(
            &[
                "calibrate",
                "--rig",
                rig,
                "--observations",
                obs,
                "--output",
                p(&rig_out),
                "--grid-step-deg",
                step,
                "--device",
                "cpu",
            ],
            &[
                "--grid-step-deg",
                step,
                "at most 100000",
                "--grid-step-deg 0.1",
            ],
        );
    }
    assert!(!rig_out.exists());
    // bench: batch size, sweep cells, repetitions.
    refused(
        &["bench", "--no-gpu", "--items", "10000000000"],
        &["--items", "10000000000", "1..=16777216"],
    );
    refused(
        &["bench", "--no-gpu", "--items", "18446744073709551615"],
        &["--items", "1..=16777216"],
    );
    refused(
        &["bench", "--no-gpu", "--sweep-cells", "18446744073709551615"],
        &["--sweep-cells", "1..=1048576"],
    );
    refused(
        &["bench", "--no-gpu", "--repeats", "18446744073709551615"],
        &["--repeats", "1..=1000"],
    );
}

/// The bytes of a little-endian float64 .npy of `shape` holding `values`, written here from the
/// format's definition (version 1.0, header padded with spaces to a multiple of 64 bytes).
fn npy_bytes(shape: &[usize], values: &[f64]) -> Vec<u8> {
    let dims = shape.iter().map(|d| d.to_string()).collect::<Vec<_>>();
    let shape_text = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut header = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': {shape_text}, }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    for v in values {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    bytes
}

/// `value`, after checking that it is +∞ where `reference` is and within 1e-12 of it elsewhere.
fn within_rounding(cost_name: &str, value: f64, reference: f64) -> f64 {
    assert_eq!(
        value.is_finite(),
        reference.is_finite(),
        "{cost_name}: finiteness"
    );
    if reference.is_finite() {
        assert!(
            (value - reference).abs() <= 1e-12 * reference.abs(),
            "{cost_name}: {value} against the reference {reference}"
        );
    }
    value
}

#[test]
fn a_sweep_in_small_batches_writes_every_cell_as_an_independent_evaluation() {
    use flatport::calib::costs::cost;
    use flatport::calib::costs::scene::air_distance_for_axis;
    use flatport::model::normal_from_tilt_azimuth;

    let dir = tempfile::tempdir().unwrap();
    let (rig_path, obs_path) = scene(dir.path());
    let rig = flatport::io::read_rig(&rig_path).unwrap();
    let observations = flatport::io::read_observations(&obs_path).unwrap();
    let data = StereoData::from_observations(&rig, [0, 1], &observations).unwrap();
    let (tilts, azimuths, distances) = ((2.0, 14.0, 5), (-180.0, 150.0, 7), (0.012, 0.03, 3));
    let value = |(start, stop, count): (f64, f64, usize), i: usize| {
        start + (stop - start) * i as f64 / (count - 1) as f64
    };
    let normal = |t: usize, a: usize| {
        normal_from_tilt_azimuth(
            value(tilts, t).to_radians(),
            value(azimuths, a).to_radians(),
        )
    };
    // --chunk 3 on a 7-wide azimuth grid: batches end inside tilt rows.
    for (cost_name, kind, with_distance) in [
        ("3d", CostKind::Scene, true),
        ("3d", CostKind::Scene, false),
        ("invariant", CostKind::AffineGrid, true),
        ("reprojection", CostKind::Reprojection, false),
    ] {
        let out = dir
            .path()
            .join(format!("sweep-{cost_name}-{with_distance}"));
        let (t, a, d) = (
            format!("{}:{}:{}", tilts.0, tilts.1, tilts.2),
            format!("{}:{}:{}", azimuths.0, azimuths.1, azimuths.2),
            format!("{}:{}:{}", distances.0, distances.1, distances.2),
        );
        let mut args = vec![
            "sweep",
            "--rig",
            p(&rig_path),
            "--observations",
            p(&obs_path),
            "--cost",
            cost_name,
            "--tilt-deg",
            &t,
            "--azimuth-deg",
            &a,
        ];
        args.extend_from_slice(&[
            "--output",
            p(&out),
            "--device",
            "cpu",
            "--quiet",
            "--chunk",
            "3",
        ]);
        if with_distance {
            args.extend_from_slice(&["--distance", &d]);
        }
        let run = flatport(&args);
        assert!(
            run.status.success(),
            "{}",
            String::from_utf8_lossy(&run.stderr)
        );
        let mut expected = Vec::new();
        let mut shape = vec![tilts.2, azimuths.2];
        for ti in 0..tilts.2 {
            for ai in 0..azimuths.2 {
                let n = normal(ti, ai);
                if with_distance {
                    for di in 0..distances.2 {
                        let air = if kind.axis_only() {
                            f64::NAN
                        } else {
                            value(distances, di)
                        };
                        let candidate = Candidate {
                            normal: n,
                            air_distance: air,
                        };
                        let reference = cost(&data, kind, &candidate);
                        if kind.axis_only() {
                            expected.push(reference);
                            continue;
                        }
                        // The CPU backend evaluates the air layers of one axis from its water
                        // rays computed once (calib::costs::scene::axis_costs): the sweep must
                        // equal that evaluation bit for bit, and it must equal the reference to
                        // rounding.
                        let axis = axis_costs(&data, &SceneRows::new(&data), kind, &[candidate])[0];
                        expected.push(within_rounding(cost_name, axis, reference));
                    }
                } else {
                    // The profile: the least-squares air layer, +∞ where there is none or it puts a camera outside the air.
                    let reference = match air_distance_for_axis(&data, &n) {
                        Some((air, _)) if air > data.min_air_distance(&n) => cost(
                            &data,
                            kind,
                            &Candidate {
                                normal: n,
                                air_distance: air,
                            },
                        ),
                        _ => f64::INFINITY,
                    };
                    if kind.axis_only() {
                        expected.push(reference);
                    } else {
                        // The CPU backend's profile computes each axis's water rays once
                        // (calib::costs::scene), which rounds differently from `cost` at the
                        // same air layer: the sweep must equal that evaluation bit for bit, and
                        // it must equal the reference to rounding (measured ≤ 2.5e-14 relative).
                        let (_, profiled) = profile_cost(&data, &SceneRows::new(&data), kind, &n);
                        expected.push(within_rounding(cost_name, profiled, reference));
                    }
                }
            }
        }
        if with_distance {
            shape.push(distances.2);
        }
        let written = std::fs::read(out.join("cost.npy")).unwrap();
        assert!(
            expected.iter().any(|c| c.is_finite()),
            "{cost_name}: the test grid has finite cells"
        );
        assert!(
            written == npy_bytes(&shape, &expected),
            "{cost_name} (distance grid {with_distance}): cost.npy differs from the cell-by-cell evaluation"
        );
        let csv = std::fs::read_to_string(out.join("cost.csv")).unwrap();
        assert_eq!(
            csv.lines().count(),
            1 + expected.len(),
            "{cost_name}: one CSV row per cell"
        );
    }
}

#[test]
fn a_calibration_reports_its_stages_iterations_and_costs_as_it_goes() {
    use flatport::calib::{Options, calibrate_with_progress};
    let rig = example_rig();
    let board = Board {
        rows: 6,
        cols: 9,
        square: 0.04,
    };
    let scene = simulate(
        &rig,
        &SceneSpec::pair(Target::Board(board), 8, 0.1, 2, 0, 1),
    )
    .unwrap();
    let mut events: Vec<(String, usize, Option<usize>, f64)> = Vec::new();
    let calibration =
        calibrate_with_progress(&rig, &scene.observations, &Options::default(), &mut |p| {
            events.push((p.stage.to_string(), p.done, p.total, p.cost))
        })
        .unwrap();
    // Every stage of the report that iterates was announced, in order, with its last cost: the
    // events fall into runs of one stage each.
    let mut runs: Vec<&(String, usize, Option<usize>, f64)> = Vec::new();
    for (k, e) in events.iter().enumerate() {
        if events
            .get(k + 1)
            .is_none_or(|next| next.0 != e.0 || next.1 <= e.1)
        {
            runs.push(e);
        }
    }
    // The stages that iterate (not the poses' fit, nor the linear air layer).
    let stages: Vec<_> = calibration
        .report
        .stages
        .iter()
        .filter(|s| !s.name.starts_with("air layer") && !s.name.starts_with("target poses"))
        .collect();
    assert_eq!(runs.len(), stages.len(), "{runs:?}");
    for (stage, last) in stages.iter().zip(&runs) {
        assert!(
            stage.name.starts_with(&last.0),
            "{} announced as {}",
            stage.name,
            last.0
        );
        if let Some(total) = last.2 {
            assert_eq!(
                last.1, total,
                "{}: the global grid is reported to its end",
                stage.name
            );
        }
        let relative = (last.3 - stage.cost).abs() / stage.cost;
        assert!(
            relative < 1e-12,
            "{}: {} vs {}",
            stage.name,
            last.3,
            stage.cost
        );
    }
    let global: Vec<_> = events
        .iter()
        .filter(|e| e.0.starts_with("global search (affine-grid"))
        .collect();
    assert!(
        global.windows(2).all(|w| w[0].1 < w[1].1),
        "the grid's progress grows"
    );
    let ml = events
        .iter()
        .filter(|e| e.0.starts_with("maximum likelihood"))
        .count();
    assert!(
        ml >= calibration.report.iterations,
        "every iteration of the fit is reported"
    );
}
