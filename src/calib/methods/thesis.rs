//! The thesis' stereo calibration methods: consecutive (the pattern invariants), simultaneous
//! (maximum likelihood) and auto, as named steps. [`calibrate`](super::calibrate) is its public
//! entry, which adds the misfit diagnosis ([`misfit`](super::misfit)); the general calibration
//! ([`rig_calibrate`](super::rig_calibrate)) runs [`run`] for its consecutive start.

use std::time::Instant;

use nalgebra::{Isometry3, Unit, Vector2, Vector3};

use crate::calib::backends::CostBackend;
use crate::calib::costs::{CostKind, SceneFit, reprojection_residuals};
use crate::calib::error::{CalibError, Side, degrees};
use crate::calib::methods::bundle::BlockNormalEquations;
use crate::calib::methods::bundle::{Bundle, BundleState, interface_std};
use crate::calib::methods::diagnose;
use crate::calib::problem::data::{Candidate, StereoData};
use crate::calib::problem::observations::{ViewCorners, compare_views, describe_pose_groups};
use crate::calib::problem::screen::{Screening, screen, without_corners};
use crate::calib::solvers::lm::{LmOptions, LmReport, Termination, levenberg_marquardt_observed};
use crate::calib::solvers::search::{cap_grid, fit_air_distance, refine_axis_observed};
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
    /// Largest RMS reprojection error, pixels, of the corners that are not outliers for the
    /// result to count as a fit ([`CalibrationReport::fits`]); above it the report says what the
    /// data look like ([`CalibrationReport::diagnosis`]).
    pub max_rms_px: f64,
}

/// Default of [`CalibrationOptions::max_rms_px`], pixels.
pub const DEFAULT_MAX_RMS_PX: f64 = 3.0;

impl Default for CalibrationOptions {
    fn default() -> Self {
        Self {
            method: Method::Auto,
            max_tilt: 30f64.to_radians(),
            grid_spacing: 1.5f64.to_radians(),
            huber: None,
            max_iterations: 200,
            max_rms_px: DEFAULT_MAX_RMS_PX,
        }
    }
}

/// A corner whose reprojection residual in one image is far above the rest, or that the
/// screening found off the board's shape in that image.
#[derive(Debug, Clone, PartialEq)]
pub struct Outlier {
    /// 0-based view.
    pub view: usize,
    /// The image.
    pub side: Side,
    /// The rig camera that took that image.
    pub camera: String,
    /// Corner index on the board (row-major).
    pub corner: usize,
    /// Its reprojection residual in that image under the result, pixels.
    pub residual_px: f64,
    /// Whether the screening of the images ([`screen`](crate::calib::problem::screen)) found it before any fit; such
    /// corners are left out of the estimate.
    pub screened: bool,
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
    /// Corners with residuals far above the rest: (view, corner, larger residual of its two
    /// images px), worst first; [`Self::outlier_images`] says which image.
    pub outliers: Vec<(usize, usize, f64)>,
    /// Every image of an outlier corner whose residual is far above the rest (or that the
    /// screening found), worst first.
    pub outlier_images: Vec<Outlier>,
    /// RMS reprojection error per camera [left, right] over the images that are not outliers, pixels.
    pub inlier_rms_px: [f64; 2],
    /// The corner noise σ per coordinate seen in the images themselves (the scatter about the
    /// board's smooth shape, [`screen`](crate::calib::problem::screen)), pixels: what the reprojection RMS should come
    /// close to. `None` for boards under 3 × 3.
    pub noise_px: Option<f64>,
    /// Whether the result fits: the larger of [`Self::inlier_rms_px`] is at most the
    /// [`CalibrationOptions::max_rms_px`]. The CLI writes no rig otherwise.
    pub fits: bool,
    /// What the data look like, when the RMS is far above the noise or above the bound
    /// ([`crate::calib::methods::diagnose::explain`]); empty otherwise.
    pub diagnosis: Vec<String>,
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

/// Where a running calibration is, for progress displays ([`calibrate_with_progress`](super::calibrate::calibrate_with_progress)).
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

/// Runs the method of `options` on `backend.data()` (see [`calibrate`](super::calibrate::calibrate)),
/// telling `progress` where it is. When the result does not fit, `explain_more(data, max_rms_px)`
/// adds to the diagnosis (the public entry passes the misfit hypotheses; the general
/// calibration's consecutive start, which bounds nothing, passes none).
pub fn run(
    backend: &dyn CostBackend,
    options: &CalibrationOptions,
    warnings: Vec<String>,
    progress: &mut dyn FnMut(&CalibrationProgress),
    explain_more: &dyn Fn(&StereoData, f64) -> Vec<String>,
) -> Result<Calibration, CalibError> {
    let data = backend.data();
    let mut screening = None;
    calibrate_screened(
        backend,
        options,
        warnings,
        &mut screening,
        progress,
        explain_more,
    )
    .map_err(|error| match error {
        CalibError::NoSolution { reason, .. } => {
            let noise = screening.as_ref().and_then(|s: &Screening| s.noise_px);
            // The local refinement does not know the search bound (it reports NaN): every
            // NoSolution here is under the options' bound.
            CalibError::NoSolution {
                bound_deg: options.max_tilt.to_degrees(),
                reason: format!(
                    "{reason}. What the data look like: {}",
                    diagnose::explain(data, None, noise).join("; ")
                ),
            }
        }
        other => other,
    })
}

/// The corners of every view of `data` for [`compare_views`].
fn view_corners(data: &StereoData) -> Vec<ViewCorners> {
    data.views
        .iter()
        .map(|range| {
            data.corners[range.clone()]
                .iter()
                .map(|c| (c.index, c.pixels))
                .collect()
        })
        .collect()
}

/// RMS reprojection error, pixels, at or below which the noise explains a maximum-likelihood
/// result: this many times the corner noise seen in the images, plus [`NOISE_MARGIN_PX`] for the
/// model error of that estimate.
pub const NOISE_FACTOR: f64 = 3.0;
/// See [`NOISE_FACTOR`], pixels.
pub const NOISE_MARGIN_PX: f64 = 0.2;

/// The maximum-likelihood fit a method ended with: the LM report and the normal equations at the
/// result (for the covariance).
type MlFit = (LmReport, Option<BlockNormalEquations>);

/// The thesis' pipeline as named steps: check the options and the views, screen the corners,
/// the consecutive estimate, the maximum-likelihood fit (simultaneous, auto), then the report of
/// how the result fits. `screening_out` receives the screening (the error path needs its noise).
fn calibrate_screened(
    backend: &dyn CostBackend,
    options: &CalibrationOptions,
    warnings: Vec<String>,
    screening_out: &mut Option<Screening>,
    progress: &mut dyn FnMut(&CalibrationProgress),
    explain_more: &dyn Fn(&StereoData, f64) -> Vec<String>,
) -> Result<Calibration, CalibError> {
    let started = Instant::now();
    let data = backend.data();
    let mut warnings = warnings;
    check_options(options)?;
    check_views(data, &mut warnings)?;
    let (screening, reduced) = screen_gross_errors(data, &mut warnings);
    *screening_out = Some(screening.clone());
    let reduced_backend = reduced.as_ref().map(|r| backend.over(r));
    let clean: &dyn CostBackend = reduced_backend.as_deref().unwrap_or(backend);
    let clean_data = clean.data();
    let mut stages = Vec::new();

    let (final_candidate, poses, ml) = estimate(
        clean,
        Candidate::of(data.port()),
        options,
        &mut stages,
        &mut warnings,
        progress,
    )?;

    // The report: residuals under the final interface and poses, over every corner.
    let cameras = data
        .cameras_behind(&final_candidate)
        .ok_or_else(|| no_solution(options, "the result puts a camera outside the air"))?;
    let residuals = reprojection_residuals(data, &cameras, &poses)
        .ok_or_else(|| no_solution(options, "a fitted corner does not project"))?;
    // The 3-D errors over every corner, else (an outlier that does not triangulate) over the kept ones.
    let (scene, scene_data) = match SceneFit::new(data, &cameras) {
        Some(fit) => (Some(fit), data),
        None => (
            clean_data
                .cameras_behind(&final_candidate)
                .and_then(|c| SceneFit::new(clean_data, &c)),
            clean_data,
        ),
    };
    let (rms_px, per_view) = rms_per_view(data, &residuals);
    let (outliers, outlier_images) = find_outliers(data, &residuals, &screening);
    if let Some(worst) = outlier_images.first() {
        warnings.push(format!(
            "{} corner(s) have residuals far above the rest (largest {:.2} px at view {} corner {}, {} image): check the detections{}",
            outliers.len(),
            worst.residual_px,
            worst.view,
            worst.corner,
            worst.side.name(),
            // The screened ones are already left out of the fit.
            if options.huber.is_none() && ml.is_some() && outlier_images.iter().any(|o| !o.screened) { ", or use the Huber loss" } else { "" }
        ));
    }
    let inlier_rms_px = inlier_rms(data, &residuals, &outlier_images);
    let (std, sigma_px, iterations, termination) =
        uncertainty(&final_candidate, ml.as_ref(), clean_data, &stages);
    warnings.extend(uncertainty_warnings(&final_candidate, ml.as_ref(), std));
    let (fits, diagnosis) = check_fit(
        data,
        &final_candidate,
        inlier_rms_px,
        screening.noise_px.filter(|_| ml.is_some()),
        screening.noise_px,
        options,
        explain_more,
        &mut warnings,
    );
    let interface = data
        .port()
        .with_pose(
            final_candidate.normal.into_inner(),
            final_candidate.air_distance,
        )
        .map_err(|e| {
            no_solution(
                options,
                &format!("the result is not a valid interface: {e}"),
            )
        })?;
    let report = CalibrationReport {
        method: options.method,
        candidate: final_candidate,
        std,
        sigma_px,
        rms_px,
        rms_px_per_view: per_view,
        scene_rms_m: scene.as_ref().map_or(f64::NAN, |s| s.scene_rms()),
        square_deviation_rms_m: scene
            .as_ref()
            .map_or(f64::NAN, |s| s.square_deviation_rms(scene_data)),
        poses,
        stages,
        iterations,
        termination,
        outliers,
        outlier_images,
        inlier_rms_px,
        noise_px: screening.noise_px,
        fits,
        diagnosis,
        warnings,
        seconds: started.elapsed().as_secs_f64(),
        backend: backend.describe(),
        views: data.views.len(),
        corners: data.corners.len(),
    };
    Ok(Calibration { interface, report })
}

/// The estimate of the chosen method over `clean` (the screened data): the consecutive result
/// alone, or maximum likelihood from it (and, for auto, from the reprojection profile's minimum
/// and `rig_start`). Returns the interface, the board poses and the fit, if any.
fn estimate(
    clean: &dyn CostBackend,
    rig_start: Candidate,
    options: &CalibrationOptions,
    stages: &mut Vec<Stage>,
    warnings: &mut Vec<String>,
    progress: &mut dyn FnMut(&CalibrationProgress),
) -> Result<(Candidate, Vec<Isometry3<f64>>, Option<MlFit>), CalibError> {
    let clean_data = clean.data();
    let consecutive = consecutive_estimate(clean, options, stages, warnings, progress)?;
    Ok(match options.method {
        Method::Consecutive => {
            clean_data.cameras_behind(&consecutive).ok_or_else(|| {
                no_solution(
                    options,
                    "the consecutive result puts a camera outside the air",
                )
            })?;
            let poses = start_poses(clean_data, &consecutive).ok_or_else(|| {
                no_solution(
                    options,
                    "the consecutive result cannot triangulate every corner",
                )
            })?;
            (consecutive, poses, None)
        }
        Method::Simultaneous | Method::Auto => {
            let mut starts = vec![("the consecutive result".to_string(), consecutive)];
            if options.method == Method::Auto {
                let profile =
                    axis_search(clean, CostKind::Reprojection, options, stages, progress)?;
                starts.push(("the reprojection profile's minimum".into(), profile));
                starts.push(("the rig's start guess".into(), rig_start));
            }
            let (state, report, jtj) =
                maximum_likelihood(clean_data, &starts, options, stages, warnings, progress)?;
            (state.candidate, state.poses, Some((report, jtj)))
        }
    })
}

/// The options' bounds: the tilt cap, the grid spacing and size, the accepted RMS.
fn check_options(options: &CalibrationOptions) -> Result<(), CalibError> {
    use crate::calib::solvers::search::{
        MAX_CAP_GRID_AXES, cap_grid_size, min_cap_grid_spacing_deg_text,
    };
    if !(options.max_tilt > 0.0 && options.max_tilt < 80f64.to_radians()) {
        return Err(CalibError::Options(format!(
            "the tilt bound must lie in (0°, 80°), got {}°",
            degrees(options.max_tilt.to_degrees())
        )));
    }
    if !(options.grid_spacing > 0.0 && options.grid_spacing <= options.max_tilt) {
        return Err(CalibError::Options(format!(
            "the grid spacing must lie in (0°, tilt bound], got {}°",
            degrees(options.grid_spacing.to_degrees())
        )));
    }
    let axes = cap_grid_size(options.max_tilt, options.grid_spacing);
    if axes > MAX_CAP_GRID_AXES as f64 {
        return Err(CalibError::Options(format!(
            "a grid spacing of {}° over a {}° tilt bound gives {axes:.3e} axes; the global search takes at most {MAX_CAP_GRID_AXES} (each costs an evaluation over every corner): use a spacing ≥ {}°",
            degrees(options.grid_spacing.to_degrees()),
            degrees(options.max_tilt.to_degrees()),
            min_cap_grid_spacing_deg_text(options.max_tilt)
        )));
    }
    if !(options.max_rms_px > 0.0) {
        return Err(CalibError::Options(format!(
            "the largest accepted RMS must be a positive number of pixels, got {}",
            options.max_rms_px
        )));
    }
    Ok(())
}

/// Enough views, none repeating another, enough distinct poses (an error otherwise: the answer
/// would look confident and be wrong, the copies shrinking the standard deviations by √copies);
/// few poses and views whose images look swapped or reversed are warnings.
fn check_views(data: &StereoData, warnings: &mut Vec<String>) -> Result<(), CalibError> {
    if data.views.len() < MIN_VIEWS {
        return Err(CalibError::TooFewViews {
            usable: data.views.len(),
            needed: MIN_VIEWS,
        });
    }
    let groups = compare_views(&view_corners(data));
    groups.check_repeats()?;
    if groups.distinct < MIN_VIEWS {
        return Err(CalibError::TooFewPoses {
            views: data.views.len(),
            distinct: groups.distinct,
            groups: describe_pose_groups(&groups),
            needed: MIN_VIEWS,
        });
    }
    if groups.distinct < FEW_VIEWS {
        let poses = if groups.distinct == data.views.len() {
            format!("only {} views", data.views.len())
        } else {
            format!(
                "only {} distinct board poses among {} views",
                groups.distinct,
                data.views.len()
            )
        };
        warnings.push(format!("{poses}: the axis and air layer are weakly determined (15-20 views at varied depths and angles are recommended)"));
    }
    warnings.extend(diagnose::pairing_findings(data));
    Ok(())
}

/// Gross corner errors, found from each image alone: the screening, and the data without them
/// (`None` when there are none, or when leaving them out would empty a view), which every
/// estimate uses (the report lists them with their residuals under the result).
fn screen_gross_errors(
    data: &StereoData,
    warnings: &mut Vec<String>,
) -> (Screening, Option<StereoData>) {
    let screening = screen(data);
    let reduced = if screening.suspects.is_empty() {
        None
    } else {
        without_corners(data, &screening.mask(data.corners.len()))
    };
    if let Some(worst) = screening.suspects.first() {
        warnings.push(format!(
            "{} corner(s) lie off the board's shape in their image by more than {:.2} px (largest {:.1} px: view {} corner {}, {} image){}",
            screening.suspects.len(),
            screening.threshold_px,
            worst.deviation_px,
            worst.view,
            worst.corner,
            worst.side.name(),
            if reduced.is_some() { ": left out of the estimate (listed below when the result confirms them)" } else { "" }
        ));
    }
    (screening, reduced)
}

/// The consecutive method: the axis from the weighted affine-grid invariant (global search, then
/// local refinement), then the air layer by linear least squares on the ray gaps, or, when that
/// leaves corners without a triangulation, the air layer that best explains the images.
fn consecutive_estimate(
    backend: &dyn CostBackend,
    options: &CalibrationOptions,
    stages: &mut Vec<Stage>,
    warnings: &mut Vec<String>,
    progress: &mut dyn FnMut(&CalibrationProgress),
) -> Result<Candidate, CalibError> {
    let data = backend.data();
    let axis = axis_search(backend, CostKind::AffineGrid, options, stages, progress)?;
    let linear_started = Instant::now();
    let (air_distance, gap) = crate::calib::costs::scene::air_distance_for_axis(data, &axis.normal)
        .ok_or_else(|| CalibError::NoSolution {
            bound_deg: options.max_tilt.to_degrees(),
            reason: "the air layer has no least-squares solution under the invariant's axis".into(),
        })?;
    let mut consecutive = Candidate {
        normal: axis.normal,
        air_distance,
    };
    stages.push(stage(
        "air layer (linear least squares on the ray gaps)",
        consecutive,
        gap,
        "m",
        1,
        linear_started,
    ));
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
        stages.push(stage(
            "air layer (1-D search on the reprojection error)",
            consecutive,
            cost,
            "px",
            1,
            t,
        ));
    }
    Ok(consecutive)
}

/// Board poses of a start, fitted to the corners of `data`; `None` when a corner does not
/// triangulate under it.
fn start_poses(data: &StereoData, start: &Candidate) -> Option<Vec<Isometry3<f64>>> {
    data.cameras_behind(start)
        .and_then(|c| SceneFit::new(data, &c))
        .map(|f| f.poses())
}

/// Maximum likelihood (Levenberg–Marquardt over the axis, the air layer and every board pose on
/// the reprojection error) from each named start; the lowest cost wins. A start that ends nearly
/// as low far away, and a fit that stops early, are warnings.
fn maximum_likelihood(
    data: &StereoData,
    starts: &[(String, Candidate)],
    options: &CalibrationOptions,
    stages: &mut Vec<Stage>,
    warnings: &mut Vec<String>,
    progress: &mut dyn FnMut(&CalibrationProgress),
) -> Result<(BundleState, LmReport, Option<BlockNormalEquations>), CalibError> {
    let mut best: Option<(BundleState, LmReport, Option<BlockNormalEquations>)> = None;
    let mut finals = Vec::new();
    // The cost in the report's unit: RMS over the 4 coordinates of each corner.
    let rms = |cost: f64| (cost / (4 * data.corners.len()) as f64).sqrt();
    for (name, start) in starts {
        let t = Instant::now();
        let Some(poses) = start_poses(data, start) else {
            warnings.push(format!(
                "{name} (tilt {:.2}°, air layer {:.1} mm) cannot triangulate every corner (a board behind the interface, or a camera outside the air): not used as a start",
                start.tilt().to_degrees(),
                start.air_distance * 1e3
            ));
            continue;
        };
        let bundle = Bundle::new(data, options.huber);
        let lm_options = LmOptions {
            max_iterations: options.max_iterations,
            ..LmOptions::default()
        };
        let stage_name = format!("maximum likelihood from {name}");
        let (state, report, jtj) = levenberg_marquardt_observed(
            &bundle,
            BundleState {
                candidate: *start,
                poses,
            },
            &lm_options,
            &mut |i| {
                progress(&CalibrationProgress {
                    stage: &stage_name,
                    done: i.iteration,
                    total: None,
                    cost: rms(i.cost),
                    unit: "px",
                })
            },
        );
        stages.push(Stage {
            name: format!(
                "maximum likelihood from {name} ({})",
                report.termination.describe()
            ),
            candidate: state.candidate,
            cost: rms(report.final_cost),
            unit: "px",
            iterations: report.iterations,
            seconds: t.elapsed().as_secs_f64(),
        });
        finals.push((name.clone(), state.candidate, report.final_cost));
        if best
            .as_ref()
            .is_none_or(|(_, r, _)| report.final_cost < r.final_cost)
        {
            best = Some((state, report, jtj));
        }
    }
    let (state, report, jtj) = best.ok_or_else(|| {
        no_solution(
            options,
            "no start lets both cameras triangulate every corner",
        )
    })?;
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
        warnings.push(format!(
            "the maximum-likelihood refinement stopped early: {}",
            report.termination.describe()
        ));
    }
    Ok((state, report, jtj))
}

/// The RMS reprojection error of each camera over every corner, and per view, pixels.
fn rms_per_view(data: &StereoData, residuals: &[[Vector2<f64>; 2]]) -> ([f64; 2], Vec<[f64; 2]>) {
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
    (
        total.map(|s| (s / data.corners.len() as f64).sqrt()),
        per_view,
    )
}

/// The standard deviations of (tilt, azimuth, air layer) and σ̂ of a maximum-likelihood fit,
/// with its iterations and how it ended; the consecutive result has no standard deviations and
/// reports its last refinement's iterations.
fn uncertainty(
    result: &Candidate,
    ml: Option<&MlFit>,
    data: &StereoData,
    stages: &[Stage],
) -> (Option<[f64; 3]>, Option<f64>, usize, String) {
    match ml {
        Some((report, jtj)) => {
            let std = jtj
                .as_ref()
                .and_then(|j| interface_std(result, j, report.final_cost, 4 * data.corners.len()));
            (
                std.map(|s| s.0),
                std.map(|s| s.1),
                report.iterations,
                report.termination.describe().to_string(),
            )
        }
        None => (
            None,
            None,
            stages
                .iter()
                .rev()
                .find(|s| s.name.starts_with("refine"))
                .map_or(0, |s| s.iterations),
            "converged".into(),
        ),
    }
}

/// Warnings about what the standard deviations say: an undetermined azimuth, a singular or weak
/// fit, and a fit that ran out of iterations.
fn uncertainty_warnings(
    result: &Candidate,
    ml: Option<&MlFit>,
    std: Option<[f64; 3]>,
) -> Vec<String> {
    let mut warnings = Vec::new();
    if let Some([tilt_std, _, _]) = std
        && result.tilt() < 3.0 * tilt_std
    {
        warnings.push(format!(
            "the tilt ({:.3}°) is within 3 standard deviations of zero: the azimuth is undetermined",
            result.tilt().to_degrees()
        ));
    }
    match (ml, std) {
        (Some(_), None) => warnings.push("JᵀJ is singular at the result: the views do not determine the axis and air layer (vary the board's angle and distance)".into()),
        (_, Some([tilt_std, _, air_std])) if tilt_std > WEAK_TILT_STD_DEG.to_radians() || air_std > WEAK_AIR_STD_M => warnings.push(format!(
            "the views hardly constrain the result (σ tilt {:.2}°, σ air layer {:.1} mm): vary the board's angle and distance between views",
            tilt_std.to_degrees(),
            air_std * 1e3
        )),
        _ => {}
    }
    if let Some(Termination::MaxIterations) = ml.map(|(r, _)| r.termination) {
        warnings.push("raise --max-iterations".into());
    }
    warnings
}

/// Does the result fit? The worse camera's RMS over the images that are not outliers, against
/// the accepted bound and (for a maximum-likelihood fit, `fit_noise_px`) the noise seen in the
/// images. Returns whether it is within the bound and, when either is exceeded, what the data
/// look like (also in a warning).
fn check_fit(
    data: &StereoData,
    result: &Candidate,
    inlier_rms_px: [f64; 2],
    fit_noise_px: Option<f64>,
    noise_px: Option<f64>,
    options: &CalibrationOptions,
    explain_more: &dyn Fn(&StereoData, f64) -> Vec<String>,
    warnings: &mut Vec<String>,
) -> (bool, Vec<String>) {
    let worst_rms = inlier_rms_px[0].max(inlier_rms_px[1]);
    let fits = worst_rms <= options.max_rms_px;
    // Only a maximum-likelihood fit is expected to come down to the noise; the consecutive
    // result (no fit of the images) is held to the bound alone.
    let noise_bound = fit_noise_px.map(|s| NOISE_FACTOR * s + NOISE_MARGIN_PX);
    if fits && !noise_bound.is_some_and(|b| worst_rms > b) {
        return (fits, Vec::new());
    }
    let mut diagnosis = diagnose::explain(data, Some(result), noise_px);
    diagnosis.extend(explain_more(data, options.max_rms_px));
    warnings.push(format!(
        "the reprojection RMS ({worst_rms:.2} px without the outliers) is {}: the model does not explain the data. What the data look like: {}",
        match (noise_px, fits) {
            (Some(s), true) => format!("far above the corner noise seen in the images (σ ≈ {s:.3} px)"),
            (Some(s), false) => format!("above the accepted {} px (the corner noise seen in the images is σ ≈ {s:.3} px)", options.max_rms_px),
            (None, _) => format!("above the accepted {} px", options.max_rms_px),
        },
        diagnosis.join("; ")
    ));
    (fits, diagnosis)
}

/// σ of the tilt, degrees, above which the views are said to hardly constrain the axis.
pub const WEAK_TILT_STD_DEG: f64 = 1.0;
/// σ of the air layer, metres, above which the views are said to hardly constrain it.
pub const WEAK_AIR_STD_M: f64 = 5e-3;

/// Whether every corner triangulates and every view can be fitted under `candidate`.
fn triangulates(data: &StereoData, candidate: &Candidate) -> bool {
    data.cameras_behind(candidate)
        .and_then(|c| SceneFit::new(data, &c))
        .is_some()
}

fn no_solution(options: &CalibrationOptions, reason: &str) -> CalibError {
    CalibError::NoSolution {
        bound_deg: options.max_tilt.to_degrees(),
        reason: reason.into(),
    }
}

fn stage(
    name: &str,
    candidate: Candidate,
    cost: f64,
    unit: &'static str,
    iterations: usize,
    since: Instant,
) -> Stage {
    Stage {
        name: name.into(),
        candidate,
        cost,
        unit,
        iterations,
        seconds: since.elapsed().as_secs_f64(),
    }
}

/// Axes of the global grid per backend call (progress is reported after each).
const GLOBAL_BATCH: usize = 256;

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
    let (mut candidates, mut costs) = (
        Vec::with_capacity(grid.len()),
        Vec::with_capacity(grid.len()),
    );
    for batch in grid.chunks(GLOBAL_BATCH) {
        let (c, v) = backend.profile(kind, batch)?;
        candidates.extend(c);
        costs.extend(v);
        let best = costs
            .iter()
            .copied()
            .filter(|c| c.is_finite())
            .fold(f64::INFINITY, f64::min);
        progress(&CalibrationProgress {
            stage: &global_name,
            done: costs.len(),
            total: Some(grid.len()),
            cost: best,
            unit: kind.unit(),
        });
    }
    let mut order: Vec<usize> = (0..grid.len()).filter(|&i| costs[i].is_finite()).collect();
    if order.is_empty() {
        return Err(CalibError::NoSolution {
            bound_deg: options.max_tilt.to_degrees(),
            reason: format!(
                "the {} cost is undefined on every one of {} grid axes",
                kind.name(),
                grid.len()
            ),
        });
    }
    order.sort_by(|&a, &b| costs[a].total_cmp(&costs[b]));
    let mut starts: Vec<Unit<Vector3<f64>>> = Vec::new();
    for &i in &order {
        if starts
            .iter()
            .all(|s| s.angle(&grid[i]).to_degrees() > DISTINCT_DEG)
        {
            starts.push(grid[i]);
            if starts.len() == LOCAL_STARTS {
                break;
            }
        }
    }
    stages.push(stage(
        &global_name,
        candidates[order[0]],
        costs[order[0]],
        kind.unit(),
        grid.len(),
        t,
    ));
    let mut best: Option<crate::calib::solvers::search::Refined> = None;
    for start in starts {
        let t = Instant::now();
        let refine_name = format!("refine axis ({})", kind.name());
        let refined = refine_axis_observed(
            backend,
            kind,
            start,
            options.grid_spacing,
            1e-9,
            300,
            &mut |i, cost| {
                progress(&CalibrationProgress {
                    stage: &refine_name,
                    done: i,
                    total: None,
                    cost,
                    unit: kind.unit(),
                })
            },
        )?;
        stages.push(stage(
            &format!("refine axis ({})", kind.name()),
            refined.candidate,
            refined.cost,
            kind.unit(),
            refined.iterations,
            t,
        ));
        if best.is_none_or(|b| refined.cost < b.cost) {
            best = Some(refined);
        }
    }
    Ok(best.expect("at least one start").candidate)
}

/// Outlier images: a corner image whose residual exceeds max(1 px, 5 × the robust σ
/// (1.4826 × the median of every corner's larger residual)); those the screening found are
/// marked (a screened image that the result explains is not an outlier).
/// Returns the corners (view, corner, larger residual), worst first, and the images, worst first.
fn find_outliers(
    data: &StereoData,
    residuals: &[[nalgebra::Vector2<f64>; 2]],
    screening: &Screening,
) -> (Vec<(usize, usize, f64)>, Vec<Outlier>) {
    let lengths: Vec<[f64; 2]> = residuals
        .iter()
        .map(|[l, r]| [l.norm(), r.norm()])
        .collect();
    let mut sorted: Vec<f64> = lengths.iter().map(|[l, r]| l.max(*r)).collect();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    let threshold = (5.0 * 1.4826 * median).max(1.0);
    let screened: std::collections::HashSet<(usize, Side)> = screening
        .suspects
        .iter()
        .map(|s| (s.position, s.side))
        .collect();
    let mut images = Vec::new();
    let mut corners = Vec::new();
    for (j, pair) in lengths.iter().enumerate() {
        let corner = &data.corners[j];
        let mut flagged = false;
        for (k, side) in [Side::Left, Side::Right].into_iter().enumerate() {
            let was_screened = screened.contains(&(j, side));
            if pair[k] > threshold {
                flagged = true;
                images.push(Outlier {
                    view: corner.view,
                    side,
                    camera: data.rig.cameras()[data.cameras[k]].name.clone(),
                    corner: corner.index,
                    residual_px: pair[k],
                    screened: was_screened,
                });
            }
        }
        if flagged {
            corners.push((corner.view, corner.index, pair[0].max(pair[1])));
        }
    }
    corners.sort_by(|a, b| b.2.total_cmp(&a.2));
    images.sort_by(|a, b| b.residual_px.total_cmp(&a.residual_px));
    (corners, images)
}

/// RMS reprojection error per camera over the images that are not in `outliers`, pixels.
fn inlier_rms(
    data: &StereoData,
    residuals: &[[nalgebra::Vector2<f64>; 2]],
    outliers: &[Outlier],
) -> [f64; 2] {
    let flagged: std::collections::HashSet<(usize, usize, Side)> = outliers
        .iter()
        .map(|o| (o.view, o.corner, o.side))
        .collect();
    let (mut sums, mut counts) = ([0.0; 2], [0usize; 2]);
    for (j, pair) in residuals.iter().enumerate() {
        let c = &data.corners[j];
        for (k, side) in [Side::Left, Side::Right].into_iter().enumerate() {
            if !flagged.contains(&(c.view, c.index, side)) {
                sums[k] += pair[k].norm_squared();
                counts[k] += 1;
            }
        }
    }
    [0, 1].map(|k| {
        if counts[k] == 0 {
            f64::NAN
        } else {
            (sums[k] / counts[k] as f64).sqrt()
        }
    })
}
