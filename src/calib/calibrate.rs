//! The calibration methods: consecutive (the thesis), simultaneous (maximum likelihood) and auto.

use std::time::Instant;

use nalgebra::{Isometry3, Unit, Vector3};

use super::backend::CostBackend;
use super::bundle::{Bundle, BundleState, interface_std};
use super::costs::{CostKind, SceneFit, reprojection_residuals};
use super::data::{Candidate, StereoData};
use super::error::CalibError;
use super::lm::{LmOptions, Termination, levenberg_marquardt_observed};
use super::search::{cap_grid, fit_air_distance, refine_axis_observed};
use crate::model::Interface;

/// Which estimator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// The thesis: the axis from the weighted affine-grid invariant (global search over the
    /// tilt cap, then local refinement), then the air layer by linear least squares.
    Consecutive,
    /// Maximum likelihood: Levenberg–Marquardt over axis, air layer and board poses on the
    /// reprojection error, started from the consecutive result.
    Simultaneous,
    /// Consecutive, then maximum likelihood from several starts (the consecutive result, the
    /// minimum of the reprojection profile, the rig's start guess); the lowest cost wins.
    Auto,
}

impl Method {
    /// `consecutive`, `simultaneous` or `auto`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Consecutive => "consecutive",
            Self::Simultaneous => "simultaneous",
            Self::Auto => "auto",
        }
    }
}

/// How to calibrate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibrationOptions {
    /// The estimator.
    pub method: Method,
    /// Largest tilt of the axis from the master camera's z axis that the global search covers, radians.
    pub max_tilt: f64,
    /// Spacing of the global search grid, radians.
    pub grid_spacing: f64,
    /// Huber threshold on each corner's reprojection residual, pixels (`None`: plain least squares).
    pub huber: Option<f64>,
    /// Iteration bound of the maximum-likelihood refinement.
    pub max_iterations: usize,
}

impl Default for CalibrationOptions {
    fn default() -> Self {
        Self { method: Method::Auto, max_tilt: 30f64.to_radians(), grid_spacing: 1.5f64.to_radians(), huber: None, max_iterations: 200 }
    }
}

/// One stage of a calibration, for the report.
#[derive(Debug, Clone, PartialEq)]
pub struct Stage {
    /// What ran (`global search (affine-grid)`, `refine axis`, `air layer (linear)`, `maximum likelihood from …`).
    pub name: String,
    /// The interface it ended at.
    pub candidate: Candidate,
    /// The cost it minimised, at its end.
    pub cost: f64,
    /// The cost's unit.
    pub unit: &'static str,
    /// Iterations (or grid cells).
    pub iterations: usize,
    /// Seconds spent.
    pub seconds: f64,
}

/// Everything a calibration found and how well the data fit it.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationReport {
    /// The estimator that produced the result.
    pub method: Method,
    /// The calibrated axis and air layer.
    pub candidate: Candidate,
    /// Standard deviations of (tilt rad, azimuth rad, air layer m) from JᵀJ; `None` for the
    /// consecutive method or when JᵀJ is singular.
    pub std: Option<[f64; 3]>,
    /// Estimated pixel noise σ̂ from the residuals (maximum likelihood only).
    pub sigma_px: Option<f64>,
    /// RMS reprojection error per camera [left, right], pixels.
    pub rms_px: [f64; 2],
    /// RMS reprojection error per view [left, right], pixels.
    pub rms_px_per_view: Vec<[f64; 2]>,
    /// RMS residual of the rigid board fit to the triangulated corners, metres.
    pub scene_rms_m: f64,
    /// RMS deviation of adjacent triangulated corners' distances from the square, metres.
    pub square_deviation_rms_m: f64,
    /// Board poses X_master = R·X_board + t per view.
    pub poses: Vec<Isometry3<f64>>,
    /// The stages that ran, in order.
    pub stages: Vec<Stage>,
    /// Iterations of the final stage.
    pub iterations: usize,
    /// Why the final stage stopped.
    pub termination: String,
    /// Corners with residuals far above the rest: (view, corner, residual px).
    pub outliers: Vec<(usize, usize, f64)>,
    /// Everything worth a second look.
    pub warnings: Vec<String>,
    /// Wall-clock seconds of the whole calibration.
    pub seconds: f64,
    /// What evaluated the cost batches.
    pub backend: String,
    /// Views and corners used.
    pub views: usize,
    /// Corners seen in both images.
    pub corners: usize,
}

/// A calibrated interface and its report.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// The rig's interface with the calibrated axis and air layer.
    pub interface: Interface,
    /// How it was found and how well it fits.
    pub report: CalibrationReport,
}

/// Fewest views accepted; below [`FEW_VIEWS`] a warning says the result is weak.
pub const MIN_VIEWS: usize = 3;
/// Views below which a calibration is flagged as weakly determined.
pub const FEW_VIEWS: usize = 8;

/// Where a running calibration is, for progress displays ([`calibrate_with_progress`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibrationProgress<'a> {
    /// The stage running, named as its [`Stage`] will be (without the result).
    pub stage: &'a str,
    /// Steps done in the stage: grid axes evaluated, or iterations.
    pub done: usize,
    /// The stage's number of steps when known in advance (grid axes), `None` for iterations.
    pub total: Option<usize>,
    /// The stage's lowest cost so far, in the stage's unit (`unit`).
    pub cost: f64,
    /// The cost's unit.
    pub unit: &'static str,
}

/// Calibrates the axis and air layer of `backend.data()` (whose rig's interface is the start
/// guess). `warnings` (from validating the observations) are carried into the report.
pub fn calibrate(backend: &dyn CostBackend, options: &CalibrationOptions, warnings: Vec<String>) -> Result<Calibration, CalibError> {
    calibrate_with_progress(backend, options, warnings, &mut |_| {})
}

/// [`calibrate`], telling `progress` where it is: after every batch of the global grid and every
/// iteration of the local refinements and of the maximum-likelihood fit.
pub fn calibrate_with_progress(
    backend: &dyn CostBackend,
    options: &CalibrationOptions,
    warnings: Vec<String>,
    progress: &mut dyn FnMut(&CalibrationProgress),
) -> Result<Calibration, CalibError> {
    let started = Instant::now();
    let data = backend.data();
    let mut warnings = warnings;
    if data.views.len() < MIN_VIEWS {
        return Err(CalibError::TooFewViews { usable: data.views.len(), needed: MIN_VIEWS });
    }
    if data.views.len() < FEW_VIEWS {
        warnings.push(format!(
            "only {} views: the axis and air layer are weakly determined (15-20 views at varied depths and angles are recommended)",
            data.views.len()
        ));
    }
    if !(options.max_tilt > 0.0 && options.max_tilt < 80f64.to_radians()) {
        return Err(CalibError::Options(format!("the tilt bound must lie in (0°, 80°), got {}°", options.max_tilt.to_degrees())));
    }
    if !(options.grid_spacing > 0.0 && options.grid_spacing <= options.max_tilt) {
        return Err(CalibError::Options(format!("the grid spacing must lie in (0°, tilt bound], got {}°", options.grid_spacing.to_degrees())));
    }
    if super::search::cap_grid_size(options.max_tilt, options.grid_spacing) > super::search::MAX_CAP_GRID_AXES as f64 {
        return Err(CalibError::Options(format!(
            "a grid spacing of {}° over a {}° tilt bound gives {:.3e} axes; the global search takes at most {} (each costs an evaluation over every corner): use a spacing ≥ {}°",
            options.grid_spacing.to_degrees(),
            options.max_tilt.to_degrees(),
            super::search::cap_grid_size(options.max_tilt, options.grid_spacing),
            super::search::MAX_CAP_GRID_AXES,
            super::search::min_cap_grid_spacing_deg_text(options.max_tilt)
        )));
    }
    let mut stages = Vec::new();

    // 1. Consecutive: axis from the weighted affine-grid invariant, global then local.
    let consecutive = axis_search(backend, CostKind::AffineGrid, options, &mut stages, progress)?;
    let linear_started = Instant::now();
    let (air_distance, gap) = super::air_layer::air_distance_for_axis(data, &consecutive.normal).ok_or_else(|| CalibError::NoSolution {
        bound_deg: options.max_tilt.to_degrees(),
        reason: "the air layer has no least-squares solution under the invariant's axis".into(),
    })?;
    let mut consecutive = Candidate { normal: consecutive.normal, air_distance };
    stages.push(stage("air layer (linear least squares on the ray gaps)", consecutive, gap, "m", 1, linear_started));
    if !triangulates(data, &consecutive) {
        // The ray gaps hardly depend on d when both cameras see a corner at similar incidence,
        // so noise can throw the linear solve far off: take the air layer that best explains
        // the images along the same axis instead.
        let t = Instant::now();
        let (d, cost) = fit_air_distance(backend, CostKind::Reprojection, &consecutive.normal)?
            .ok_or_else(|| no_solution(options, "no air layer lets both cameras triangulate every corner under the invariant's axis"))?;
        warnings.push(format!(
            "the linear air layer ({:.2} mm) leaves corners without a triangulation: took the air layer with the least reprojection error along the same axis ({:.2} mm)",
            air_distance * 1e3,
            d * 1e3
        ));
        consecutive.air_distance = d;
        stages.push(stage("air layer (1-D search on the reprojection error)", consecutive, cost, "px", 1, t));
    }

    let (final_candidate, poses, ml) = match options.method {
        Method::Consecutive => {
            let cameras = data.cameras_behind(&consecutive).ok_or_else(|| no_solution(options, "the consecutive result puts a camera outside the air"))?;
            let fit = SceneFit::new(data, &cameras).ok_or_else(|| no_solution(options, "the consecutive result cannot triangulate every corner"))?;
            (consecutive, fit.poses(), None)
        }
        Method::Simultaneous | Method::Auto => {
            let mut starts = vec![("the consecutive result".to_string(), consecutive)];
            if options.method == Method::Auto {
                let profile = axis_search(backend, CostKind::Reprojection, options, &mut stages, progress)?;
                starts.push(("the reprojection profile's minimum".into(), profile));
                starts.push(("the rig's start guess".into(), Candidate::of(data.rig.interface())));
            }
            let mut best: Option<(BundleState, super::lm::LmReport, Option<super::bundle::BlockNormalEquations>)> = None;
            let mut finals = Vec::new();
            for (name, start) in &starts {
                let t = Instant::now();
                let Some(poses) = data.cameras_behind(start).and_then(|c| SceneFit::new(data, &c)).map(|f| f.poses()) else {
                    warnings.push(format!(
                        "{name} (tilt {:.2}°, air layer {:.1} mm) cannot triangulate every corner (a board behind the interface, or a camera outside the air): not used as a start",
                        start.tilt().to_degrees(),
                        start.air_distance * 1e3
                    ));
                    continue;
                };
                let bundle = Bundle::new(data, options.huber);
                let lm_options = LmOptions { max_iterations: options.max_iterations, ..LmOptions::default() };
                let stage_name = format!("maximum likelihood from {name}");
                // The cost in the report's unit: RMS over the 4 coordinates of each corner.
                let rms = |cost: f64| (cost / (4 * data.corners.len()) as f64).sqrt();
                let (state, report, jtj) = levenberg_marquardt_observed(&bundle, BundleState { candidate: *start, poses }, &lm_options, &mut |i| {
                    progress(&CalibrationProgress { stage: &stage_name, done: i.iteration, total: None, cost: rms(i.cost), unit: "px" })
                });
                stages.push(Stage {
                    name: format!("maximum likelihood from {name} ({})", report.termination.describe()),
                    candidate: state.candidate,
                    cost: (report.final_cost / (4 * data.corners.len()) as f64).sqrt(),
                    unit: "px",
                    iterations: report.iterations,
                    seconds: t.elapsed().as_secs_f64(),
                });
                finals.push((name.clone(), state.candidate, report.final_cost));
                if best.as_ref().is_none_or(|(_, r, _)| report.final_cost < r.final_cost) {
                    best = Some((state, report, jtj));
                }
            }
            let (state, report, jtj) = best.ok_or_else(|| no_solution(options, "no start lets both cameras triangulate every corner"))?;
            let best_cost = report.final_cost;
            for (name, candidate, cost) in &finals {
                let apart = candidate.normal.angle(&state.candidate.normal).to_degrees();
                // A start that ends in a clearly worse minimum only shows the cost has several; one
                // that ends nearly as low elsewhere makes the answer ambiguous.
                if *cost < best_cost * 1.5 && apart > 0.5 {
                    warnings.push(format!(
                        "the refinement from {name} ended {apart:.2}° away at a cost only ×{:.2} higher: the data hardly tell the two axes apart",
                        cost / best_cost.max(f64::MIN_POSITIVE)
                    ));
                }
            }
            if !report.termination.converged() {
                warnings.push(format!("the maximum-likelihood refinement stopped early: {}", report.termination.describe()));
            }
            (state.candidate, state.poses, Some((report, jtj)))
        }
    };

    // The report: residuals under the final interface and poses.
    let cameras = data.cameras_behind(&final_candidate).ok_or_else(|| no_solution(options, "the result puts a camera outside the air"))?;
    let residuals = reprojection_residuals(data, &cameras, &poses).ok_or_else(|| no_solution(options, "a fitted corner does not project"))?;
    let scene = SceneFit::new(data, &cameras);
    let mut per_view = Vec::with_capacity(data.views.len());
    let mut total = [0.0; 2];
    for range in &data.views {
        let mut sums = [0.0; 2];
        for r in &residuals[range.clone()] {
            for k in 0..2 {
                sums[k] += r[k].norm_squared();
            }
        }
        for k in 0..2 {
            total[k] += sums[k];
        }
        per_view.push(sums.map(|s| (s / range.len() as f64).sqrt()));
    }
    let rms_px = total.map(|s| (s / data.corners.len() as f64).sqrt());
    let outliers = find_outliers(data, &residuals);
    if !outliers.is_empty() {
        warnings.push(format!(
            "{} corner(s) have residuals far above the rest (largest {:.2} px at view {} corner {}): check the detections{}",
            outliers.len(),
            outliers[0].2,
            outliers[0].0,
            outliers[0].1,
            if options.huber.is_none() { ", or use the Huber loss" } else { "" }
        ));
    }
    let (std, sigma_px, iterations, termination) = match &ml {
        Some((report, jtj)) => {
            let std = jtj.as_ref().and_then(|j| interface_std(&final_candidate, j, report.final_cost, 4 * data.corners.len()));
            (std.map(|s| s.0), std.map(|s| s.1), report.iterations, report.termination.describe().to_string())
        }
        None => (None, None, stages.iter().rev().find(|s| s.name.starts_with("refine")).map_or(0, |s| s.iterations), "converged".into()),
    };
    if let Some([tilt_std, _, _]) = std {
        if final_candidate.tilt() < 3.0 * tilt_std {
            warnings.push(format!(
                "the tilt ({:.3}°) is within 3 standard deviations of zero: the azimuth is undetermined",
                final_candidate.tilt().to_degrees()
            ));
        }
    }
    if let Some(Termination::MaxIterations) = ml.as_ref().map(|(r, _)| r.termination) {
        warnings.push("raise --max-iterations".into());
    }
    let interface = data
        .rig
        .interface()
        .with_pose(final_candidate.normal.into_inner(), final_candidate.air_distance)
        .map_err(|e| no_solution(options, &format!("the result is not a valid interface: {e}")))?;
    let report = CalibrationReport {
        method: options.method,
        candidate: final_candidate,
        std,
        sigma_px,
        rms_px,
        rms_px_per_view: per_view,
        scene_rms_m: scene.as_ref().map_or(f64::NAN, |s| s.scene_rms()),
        square_deviation_rms_m: scene.as_ref().map_or(f64::NAN, |s| s.square_deviation_rms(data)),
        poses,
        stages,
        iterations,
        termination,
        outliers,
        warnings,
        seconds: started.elapsed().as_secs_f64(),
        backend: backend.describe(),
        views: data.views.len(),
        corners: data.corners.len(),
    };
    Ok(Calibration { interface, report })
}

/// Whether every corner triangulates and every view can be fitted under `candidate`.
fn triangulates(data: &StereoData, candidate: &Candidate) -> bool {
    data.cameras_behind(candidate).and_then(|c| SceneFit::new(data, &c)).is_some()
}

fn no_solution(options: &CalibrationOptions, reason: &str) -> CalibError {
    CalibError::NoSolution { bound_deg: options.max_tilt.to_degrees(), reason: reason.into() }
}

fn stage(name: &str, candidate: Candidate, cost: f64, unit: &'static str, iterations: usize, since: Instant) -> Stage {
    Stage { name: name.into(), candidate, cost, unit, iterations, seconds: since.elapsed().as_secs_f64() }
}

/// Axes of the global grid per backend call (progress is reported after each).
const GLOBAL_BATCH: usize = 2048;

/// How many of the global grid's best cells (at least this many degrees apart) are refined.
const LOCAL_STARTS: usize = 3;
const DISTINCT_DEG: f64 = 4.0;

/// Global search of `kind`'s profile over the tilt cap, then local refinement of the best few
/// distinct cells; the best refined axis (with the profile's air layer) wins.
fn axis_search(
    backend: &dyn CostBackend,
    kind: CostKind,
    options: &CalibrationOptions,
    stages: &mut Vec<Stage>,
    progress: &mut dyn FnMut(&CalibrationProgress),
) -> Result<Candidate, CalibError> {
    let t = Instant::now();
    let grid = cap_grid(options.max_tilt, options.grid_spacing);
    // In batches, to report progress (each axis is evaluated alone, so the costs do not depend on
    // the batching).
    let global_name = format!("global search ({}, {} axes)", kind.name(), grid.len());
    let (mut candidates, mut costs) = (Vec::with_capacity(grid.len()), Vec::with_capacity(grid.len()));
    for batch in grid.chunks(GLOBAL_BATCH) {
        let (c, v) = backend.profile(kind, batch)?;
        candidates.extend(c);
        costs.extend(v);
        let best = costs.iter().copied().filter(|c| c.is_finite()).fold(f64::INFINITY, f64::min);
        progress(&CalibrationProgress { stage: &global_name, done: costs.len(), total: Some(grid.len()), cost: best, unit: kind.unit() });
    }
    let mut order: Vec<usize> = (0..grid.len()).filter(|&i| costs[i].is_finite()).collect();
    if order.is_empty() {
        return Err(CalibError::NoSolution {
            bound_deg: options.max_tilt.to_degrees(),
            reason: format!("the {} cost is undefined on every one of {} grid axes", kind.name(), grid.len()),
        });
    }
    order.sort_by(|&a, &b| costs[a].total_cmp(&costs[b]));
    let mut starts: Vec<Unit<Vector3<f64>>> = Vec::new();
    for &i in &order {
        if starts.iter().all(|s| s.angle(&grid[i]).to_degrees() > DISTINCT_DEG) {
            starts.push(grid[i]);
            if starts.len() == LOCAL_STARTS {
                break;
            }
        }
    }
    stages.push(stage(&global_name, candidates[order[0]], costs[order[0]], kind.unit(), grid.len(), t));
    let mut best: Option<super::search::Refined> = None;
    for start in starts {
        let t = Instant::now();
        let refine_name = format!("refine axis ({})", kind.name());
        let refined = refine_axis_observed(backend, kind, start, options.grid_spacing, 1e-9, 300, &mut |i, cost| {
            progress(&CalibrationProgress { stage: &refine_name, done: i, total: None, cost, unit: kind.unit() })
        })?;
        stages.push(stage(&format!("refine axis ({})", kind.name()), refined.candidate, refined.cost, kind.unit(), refined.iterations, t));
        if best.is_none_or(|b| refined.cost < b.cost) {
            best = Some(refined);
        }
    }
    Ok(best.expect("at least one start").candidate)
}

/// Corners whose larger residual exceeds max(1 px, 5 × the robust σ (1.4826 × median residual)),
/// worst first.
fn find_outliers(data: &StereoData, residuals: &[[nalgebra::Vector2<f64>; 2]]) -> Vec<(usize, usize, f64)> {
    let lengths: Vec<f64> = residuals.iter().map(|[l, r]| l.norm().max(r.norm())).collect();
    let mut sorted = lengths.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    let threshold = (5.0 * 1.4826 * median).max(1.0);
    let mut outliers: Vec<(usize, usize, f64)> = lengths
        .iter()
        .enumerate()
        .filter(|&(_, &l)| l > threshold)
        .map(|(j, &l)| (data.corners[j].view, data.corners[j].index, l))
        .collect();
    outliers.sort_by(|a, b| b.2.total_cmp(&a.2));
    outliers
}
