//! Sizes: the bundle's block (Schur) normal equations against a dense solve built here from a
//! finite-difference Jacobian; sizes from user input refused before anything is allocated; a sweep
//! streamed in batches writes the same cost.npy as an independent evaluation of every cell.

use std::path::Path;
use std::process::Command;

use flatport::calib::bundle::{Bundle, BundleState, INTERFACE_PARAMETERS};
use flatport::calib::lm::{DenseNormalEquations, LeastSquares, NormalEquations};
use flatport::calib::{Board, Candidate, CostBackend, CostKind, CpuBackend, SceneSpec, StereoData, costs::SceneFit, simulate};
use flatport::io::rig_from_json_str;
use flatport::model::Rig;
use nalgebra::{DMatrix, DVector};

const EXAMPLE_RIG: &str = include_str!("../data/example_rig.json");

fn example_rig() -> Rig {
    rig_from_json_str(EXAMPLE_RIG, "example".as_ref()).unwrap()
}

fn flatport(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_flatport")).args(args).env("XDG_RUNTIME_DIR", std::env::temp_dir()).output().expect("binary runs")
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// Runs flatport and expects a clean failure (exit 1, no panic, no abort) whose message names
/// every one of `words`.
fn refused(args: &[&str], words: &[&str]) -> String {
    let out = flatport(args);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "flatport {args:?} should fail cleanly, got {:?}: {stderr}", out.status);
    assert!(!stderr.contains("panicked") && !stderr.contains("memory allocation"), "{args:?}: {stderr}");
    for w in words {
        assert!(stderr.contains(w), "flatport {args:?}: the message should name '{w}': {stderr}");
    }
    stderr
}

/// The dense normal equations of `bundle` at `state`: J by central differences of the bundle's
/// residuals under its retraction (one column per step parameter, step 1e-6), Huber weights
/// k/|r| per corner residual outside the threshold.
fn dense_normal_equations(bundle: &Bundle, state: &BundleState, huber: Option<f64>) -> DenseNormalEquations {
    let n = bundle.dimension(state);
    let base = bundle.residuals(state).unwrap();
    let rows = 2 * base.len();
    let h = 1e-6;
    let mut j = DMatrix::zeros(rows, n);
    for k in 0..n {
        let mut delta = DVector::zeros(n);
        delta[k] = h;
        let plus = bundle.residuals(&bundle.retract(state, &delta)).unwrap();
        delta[k] = -h;
        let minus = bundle.residuals(&bundle.retract(state, &delta)).unwrap();
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
    DenseNormalEquations { jtj: j.transpose() * &wj, jtr: wj.transpose() * &r, cost }
}

#[test]
fn bundle_schur_step_and_covariance_equal_a_dense_solve() {
    let rig = example_rig();
    let scene = simulate(&rig, 0, 1, &SceneSpec::new(Board { rows: 4, cols: 5, square: 0.05 }, 5, 0.3, 7)).unwrap();
    let data = StereoData::new(&rig, [0, 1], &scene.observations).unwrap();
    // A state off the truth so the residuals and the gradient are far from zero.
    let truth = Candidate::of(rig.interface());
    let start = Candidate { normal: flatport::calib::search::tangent_step(&truth.normal, &nalgebra::Vector2::new(0.01, -0.004)), air_distance: 0.023 };
    let cameras = data.cameras_behind(&start).unwrap();
    let poses = SceneFit::new(&data, &cameras).unwrap().poses();
    let state = BundleState { candidate: start, poses };
    for huber in [None, Some(0.5)] {
        let bundle = Bundle::new(&data, huber);
        let block = bundle.normal_equations(&state).unwrap();
        let dense = dense_normal_equations(&bundle, &state, huber);
        assert_eq!(block.dimension(), dense.jtj.nrows());
        assert!((block.cost - dense.cost).abs() <= 1e-12 * dense.cost, "{} vs {}", block.cost, dense.cost);
        let floor = 1e-12 * dense.max_diagonal();
        for damping in [0.0, 1e-4, 1.0] {
            let step = block.solve_damped(damping, floor).unwrap();
            let reference = dense.solve_damped(damping, floor).unwrap();
            let error = (&step - &reference).norm() / reference.norm();
            println!("huber {huber:?}, damping {damping}: step relative error {error:.2e}");
            assert!(error < 1e-9, "huber {huber:?}, damping {damping}: step relative error {error:e}");
        }
        let inverse = dense.jtj.clone().cholesky().unwrap().inverse();
        let reference = inverse.view((0, 0), (INTERFACE_PARAMETERS, INTERFACE_PARAMETERS)).into_owned();
        let covariance = block.global_covariance().unwrap();
        let error = (&covariance - &reference).norm() / reference.norm();
        println!("huber {huber:?}: covariance relative error {error:.2e}");
        assert!(error < 1e-9, "huber {huber:?}: covariance relative error {error:e}");
    }
}
