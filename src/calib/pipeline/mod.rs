//! One calibration pipeline for every rig: one camera or many, a shared port or a port per
//! camera, a board or a 3-D target ([`calibrate`]). The steps, in order:
//!
//! 1. **Check** the options and the observations ([`Observations::resolve`],
//!    [`Observations::check`]): enough distinct target poses, no repeated views.
//! 2. **Screen** each image of a board for gross corner errors from the board's own shape
//!    ([`screen`](crate::calib::problem::screen)); they are left out of every estimate.
//! 3. **Poses**: each view's target pose by the pinhole model ([`poses`]), then fitted through the
//!    start port.
//! 4. **Start** of the ports. Where two or more cameras share the port and see a board together,
//!    the thesis' consecutive method ([`consecutive`]: the axis from the affine-grid invariant, the
//!    air layer by linear least squares) on every such pair, the pair whose result explains every
//!    corner best winning; its cost batches run on the CPU or the GPU ([`Backend`]). Otherwise a
//!    global search over each port's axis ([`search`]).
//! 5. **Maximum likelihood** ([`bundle`]) over everything estimated and every target pose, from
//!    the start (`simultaneous`), or from several starts with the lowest cost winning (`auto`:
//!    the consecutive result, the reprojection profile's minimum, the rig's own start); the
//!    `consecutive` method stops before it.
//! 6. **Report** ([`report`]): every port and camera with standard deviations from the
//!    covariance, residuals per camera and view, outlier images, and, when the result does not
//!    fit, what the data look like ([`diagnose`], and [`misfit`]: the usual input mistakes, each
//!    undone and calibrated again).

pub mod bundle;
pub mod consecutive;
pub mod diagnose;
pub mod misfit;
pub mod poses;
pub mod report;
pub mod search;

use std::sync::Arc;
use std::time::Instant;

use self::bundle::{Bundle, Estimate, State, distance_unobservable};
use self::report::{
    Report, SceneErrors, Stage, camera_reports, camera_rms, find_outliers, label_residuals,
    port_names, port_reports,
};
use crate::calib::backends::gpu::GpuBackend;
use crate::calib::backends::{CostBackend, CpuBackend};
use crate::calib::costs::SceneFit;
use crate::calib::error::{CalibError, degrees};
use crate::calib::problem::data::{Candidate, StereoData};
use crate::calib::problem::observations::{
    Observations, SeenView, compare_views, describe_pose_groups, view_corners,
};
use crate::calib::problem::screen::{Screening, screen};
use crate::calib::problem::target::Target;
use crate::calib::solvers::block::BlockNormalEquations;
use crate::calib::solvers::lm::{LmOptions, LmReport, Termination, levenberg_marquardt_observed};
use crate::gpu::GpuEngine;
use crate::model::{Ports, Rig};

/// Which estimator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// The thesis: the axis from the weighted affine-grid invariant (global search over the tilt
    /// cap, then local refinement), then the air layer by linear least squares, on a camera pair
    /// behind a shared port; no refinement of the port by the reprojection error.
    Consecutive,
    /// Maximum likelihood: Levenberg–Marquardt over everything estimated and every target pose
    /// on the reprojection error, from the consecutive result (or the axis search where no pair
    /// shares a port).
    Simultaneous,
    /// Maximum likelihood from several starts (the consecutive result, the minimum of the
    /// reprojection profile, the rig's start guess; or the axis search); the lowest cost wins.
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

    /// The method named `name`.
    pub fn from_name(name: &str) -> Option<Self> {
        [Self::Consecutive, Self::Simultaneous, Self::Auto]
            .into_iter()
            .find(|m| m.name() == name)
    }
}

/// Where the cost batches of the consecutive method run.
#[derive(Clone, Default)]
pub enum Backend {
    /// The f64 reference on every CPU core.
    #[default]
    Cpu,
    /// The WGSL kernels of a GPU engine (f64 kernels agree with the CPU to ~1e-12; the
    /// refinement's finite differences need them).
    Gpu(Arc<GpuEngine>),
}

impl std::fmt::Debug for Backend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Cpu => f.write_str("Cpu"),
            Self::Gpu(engine) => write!(f, "Gpu({})", engine.context().adapter().name),
        }
    }
}

impl Backend {
    /// The cost backend over `data` on this device.
    pub fn over<'a>(&'a self, data: &'a StereoData) -> Box<dyn CostBackend + 'a> {
        match self {
            Self::Cpu => Box::new(CpuBackend::new(data)),
            Self::Gpu(engine) => Box::new(GpuBackend::new(data, engine.as_ref())),
        }
    }

    /// One line saying what evaluates the cost batches.
    pub fn describe(&self) -> String {
        match self {
            Self::Cpu => format!(
                "cpu (f64 reference, {} threads)",
                rayon::current_num_threads()
            ),
            Self::Gpu(engine) => {
                let a = engine.context().adapter();
                format!("gpu: {} ({}), {}", a.name, a.driver, engine.precision())
            }
        }
    }
}

/// How to calibrate.
#[derive(Debug, Clone)]
pub struct Options {
    /// The estimator.
    pub method: Method,
    /// What is estimated (default: every port's axis and air distance).
    pub estimate: Estimate,
    /// Largest tilt of an axis from its frame's z axis that the global searches cover, radians.
    pub max_tilt: f64,
    /// Spacing of the consecutive method's global search grid, radians (`None`: 1.5°, or the
    /// tilt bound where that is smaller).
    pub grid_spacing: Option<f64>,
    /// Huber threshold on each corner's reprojection residual, pixels (`None`: plain least squares).
    pub huber: Option<f64>,
    /// Iteration bound of the maximum-likelihood refinement.
    pub max_iterations: usize,
    /// Largest RMS reprojection error of any camera, pixels, over the images that are not
    /// outliers, for the result to count as a fit ([`Report::fits`]); above it the report says
    /// what the data look like ([`Report::diagnosis`]). `None` (the default): at most
    /// [`DEFAULT_MAX_RMS_PX`], and a maximum-likelihood fit at most [`NOISE_FACTOR`] times the
    /// corner noise seen in the images plus [`NOISE_MARGIN_PX`] (a result far above the noise is
    /// plainly wrong); a bound given here is the bound, whatever the noise.
    pub max_rms_px: Option<f64>,
    /// Where the consecutive method's cost batches run.
    pub backend: Backend,
}

/// Default of [`Options::max_rms_px`], pixels.
pub const DEFAULT_MAX_RMS_PX: f64 = 3.0;

/// Default spacing of the consecutive method's global search grid, degrees.
pub const DEFAULT_GRID_SPACING_DEG: f64 = 1.5;

impl Options {
    /// The bound on the RMS that [`Options::max_rms_px`] gives, or [`DEFAULT_MAX_RMS_PX`].
    pub fn rms_bound(&self) -> f64 {
        self.max_rms_px.unwrap_or(DEFAULT_MAX_RMS_PX)
    }

    /// The spacing of the consecutive method's global search grid, radians:
    /// [`Options::grid_spacing`], else [`DEFAULT_GRID_SPACING_DEG`] or the tilt bound where
    /// that is smaller.
    pub fn grid_spacing(&self) -> f64 {
        self.grid_spacing
            .unwrap_or_else(|| DEFAULT_GRID_SPACING_DEG.to_radians().min(self.max_tilt))
    }
}

impl Default for Options {
    fn default() -> Self {
        Self {
            method: Method::Auto,
            estimate: Estimate::default(),
            max_tilt: 30f64.to_radians(),
            grid_spacing: None,
            huber: None,
            max_iterations: 200,
            max_rms_px: None,
            backend: Backend::Cpu,
        }
    }
}

/// Where a running calibration is, for progress displays ([`calibrate_with_progress`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Progress<'a> {
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

/// A calibrated rig and its report.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// The input rig with everything estimated replaced by its estimate.
    pub rig: Rig,
    /// How it was found and how well it fits.
    pub report: Report,
}

/// Fewest views accepted; below [`FEW_VIEWS`] a warning says the result is weak.
pub const MIN_VIEWS: usize = 3;
/// Views below which a calibration is flagged as weakly determined.
pub const FEW_VIEWS: usize = 8;
/// RMS reprojection error, pixels, at or below which the noise explains a maximum-likelihood
/// result: this many times the corner noise seen in the images, plus [`NOISE_MARGIN_PX`] for the
/// model error of that estimate.
pub const NOISE_FACTOR: f64 = 3.0;
/// See [`NOISE_FACTOR`], pixels.
pub const NOISE_MARGIN_PX: f64 = 0.2;
/// σ of the tilt, degrees, above which the views are said to hardly constrain the axis.
pub const WEAK_TILT_STD_DEG: f64 = 1.0;
/// σ of the air distance, metres, above which the views are said to hardly constrain it.
pub const WEAK_AIR_STD_M: f64 = 5e-3;

/// Calibrates `rig` (its ports and extrinsics the start guess, everything else known) from
/// `observations`, by the steps of the module documentation.
///
/// Errors: options out of range or a method that does not apply to the rig
/// ([`CalibError::Options`]); observations that do not fit the rig or its target (named by view,
/// image and corner); fewer than [`MIN_VIEWS`] distinct target poses; repeated views; no axis
/// within the tilt bound that explains the corners ([`CalibError::NoSolution`], which says what
/// the data look like). A result that does not fit is not an error: [`Report::fits`] is false and
/// [`Report::diagnosis`] names the usual input mistake the misfit looks like.
///
/// ```
/// use flatport::calib::{Options, SceneSpec, Target, Board, calibrate, simulate};
/// let truth = flatport::io::read_rig("data/example_rig.json".as_ref())?;
/// let board = Target::Board(Board { rows: 6, cols: 9, square: 0.04 });
/// let scene = simulate(&truth, &SceneSpec::pair(board, 12, 0.1, 1, 0, 1))?;
/// // Start from the port on the camera's z axis, 10 mm of air.
/// let start = truth.with_interface(truth.shared_interface().unwrap().with_pose(nalgebra::Vector3::z(), 0.01)?)?;
/// let calibration = calibrate(&start, &scene.observations, &Options::default())?;
/// let port = calibration.report.port();
/// assert!(calibration.report.fits);
/// assert!((port.tilt.value.to_degrees() - 8.0).abs() < 0.1);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn calibrate(
    rig: &Rig,
    observations: &Observations,
    options: &Options,
) -> Result<Calibration, CalibError> {
    calibrate_with_progress(rig, observations, options, &mut |_| {})
}

/// [`calibrate`], telling `progress` where it is: after every batch of a global grid and every
/// iteration of the local refinements and of the maximum-likelihood fit.
pub fn calibrate_with_progress(
    rig: &Rig,
    observations: &Observations,
    options: &Options,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Calibration, CalibError> {
    let started = Instant::now();
    check_options(rig, &observations.target, options)?;
    let seen = observations.resolve(rig)?;
    let mut warnings = observations.check(&seen)?;
    check_views(&seen, &mut warnings)?;
    let mut calibration = calibrate_views(
        rig,
        &observations.target,
        &seen,
        options,
        warnings,
        progress,
    )?;
    let report = &mut calibration.report;
    let worst = report.worst_inlier_rms_px();
    // Only a maximum-likelihood fit is expected to come down to the noise; the consecutive result
    // (no fit of the images) is held to the bound alone.
    let noise_bound = report
        .noise_px
        .filter(|_| report.sigma_px.is_some())
        .map(|s| NOISE_FACTOR * s + NOISE_MARGIN_PX);
    let above_noise = noise_bound.is_some_and(|b| worst > b);
    if above_noise && options.max_rms_px.is_none() {
        report.fits = false;
    }
    if !report.fits || above_noise {
        report.diagnosis = diagnosis(rig, &observations.target, &seen, report, options);
        report.warnings.push(format!(
            "the reprojection RMS ({worst:.2} px in the worst camera, without the outliers) is {}: the model does not explain the data. What the data look like: {}",
            match (report.noise_px, above_noise) {
                (Some(s), true) => format!("far above the corner noise seen in the images (σ ≈ {s:.3} px; a fit comes within {NOISE_FACTOR} σ + {NOISE_MARGIN_PX} px)"),
                (Some(s), false) => format!("above the accepted {} px (the corner noise seen in the images is σ ≈ {s:.3} px)", options.rms_bound()),
                (None, _) => format!("above the accepted {} px", options.rms_bound()),
            },
            report.diagnosis.join("; ")
        ));
    }
    report.seconds = started.elapsed().as_secs_f64();
    Ok(calibration)
}

/// What the data look like when the result does not fit. First what a camera pair's rays show
/// (swapped images, a reversed corner order, a triangulated board of the wrong scale); then the
/// usual input mistakes, each undone in turn and calibrated again ([`misfit`]), those whose
/// undoing explains the misfit (a scale finding that one of them names already is left out); or,
/// when none does, a summary of the data and the line that says so.
fn diagnosis(
    rig: &Rig,
    target: &Target,
    seen: &[SeenView],
    report: &Report,
    options: &Options,
) -> Vec<String> {
    // The pair the 3-D errors are about, else the first that saw three views of a board together.
    let named =
        report
            .scene
            .as_ref()
            .and_then(|s| match s.cameras.clone().map(|n| rig.camera_index(&n)) {
                [Some(a), Some(b)] => Some([a, b]),
                _ => None,
            });
    let n = rig.cameras().len();
    let pair = target.board().and_then(|board| {
        named
            .into_iter()
            .chain((0..n).flat_map(|a| (a + 1..n).map(move |b| [a, b])))
            .filter_map(|pair| StereoData::new(rig, pair, board, seen).ok())
            .find(|d| d.views.len() >= MIN_VIEWS)
    });
    let mut findings = Vec::new();
    let mut scale = None;
    if let Some(data) = &pair {
        findings = diagnose::pairing_findings(data);
        // The fitted port where it is the pair's (a shared one), else the pair's start.
        let candidate = matches!(rig.ports(), Ports::Shared(_)).then(|| Candidate {
            normal: nalgebra::Unit::new_normalize(nalgebra::Vector3::from(report.port().normal)),
            air_distance: report.port().distance.value,
        });
        scale = diagnose::scale_finding(data, candidate.as_ref(), !findings.is_empty());
    }
    match misfit::explain_misfit(rig, target, seen, options) {
        Ok(verified) => {
            let named_scale = verified.iter().any(|v| misfit::is_about_scale(v));
            if !named_scale {
                findings.extend(scale);
            }
            findings.extend(verified);
        }
        Err(unexplained) => {
            findings.extend(scale);
            if let Some(data) = &pair {
                findings.push(diagnose::summary(data, report.noise_px));
            }
            findings.push(unexplained);
        }
    }
    findings
}

/// The pipeline on views already resolved and checked, without the diagnosis of a misfit (which
/// calibrates again through this function: [`misfit`]).
pub(crate) fn calibrate_views(
    rig: &Rig,
    target: &Target,
    seen: &[SeenView],
    options: &Options,
    mut warnings: Vec<String>,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Calibration, CalibError> {
    let started = Instant::now();
    warn_unobservable(rig, target, seen, options, &mut warnings);
    let screening = target
        .board()
        .map(|board| screen_gross_errors(rig, board, seen, &mut warnings));
    let clean_views = screening.as_ref().and_then(|s| s.without_suspects(seen));
    let clean = clean_views.as_deref().unwrap_or(seen);
    let pairs = shared_board_pairs(rig, target, clean)?;
    for data in &pairs {
        warnings.extend(diagnose::pairing_findings(data));
    }
    let mut stages = Vec::new();
    let estimate = estimate(
        rig,
        target,
        clean,
        &pairs,
        options,
        &mut stages,
        &mut warnings,
        progress,
    )
    .map_err(|error| match (error, pairs.first()) {
        (CalibError::NoSolution { reason, bound_deg }, Some(data)) => CalibError::NoSolution {
            bound_deg,
            reason: format!(
                "{reason}. What the data look like: {}",
                diagnose::explain(data, None, screening.as_ref().and_then(|s| s.noise_px))
                    .join("; ")
            ),
        },
        (other, _) => other,
    })?;
    let report = make_report(
        rig,
        target,
        seen,
        screening.as_ref(),
        &pairs,
        estimate,
        stages,
        warnings,
        options,
    )?;
    let calibrated = report.1;
    let mut report = report.0;
    report.seconds = started.elapsed().as_secs_f64();
    Ok(Calibration {
        rig: calibrated,
        report,
    })
}

/// The options' bounds, and whether the method and the estimate apply to the rig.
fn check_options(rig: &Rig, target: &Target, options: &Options) -> Result<(), CalibError> {
    use crate::calib::solvers::search::{
        MAX_CAP_GRID_AXES, cap_grid_size, min_cap_grid_spacing_deg_text,
    };
    if !(options.max_tilt > 0.0 && options.max_tilt < 80f64.to_radians()) {
        return Err(CalibError::Options(format!(
            "the tilt bound must lie in (0°, 80°), got {}°",
            degrees(options.max_tilt.to_degrees())
        )));
    }
    let spacing = options.grid_spacing();
    if !(spacing > 0.0 && spacing <= options.max_tilt) {
        return Err(CalibError::Options(format!(
            "the grid spacing must lie in (0°, tilt bound], got {}°",
            degrees(spacing.to_degrees())
        )));
    }
    let axes = cap_grid_size(options.max_tilt, spacing);
    if axes > MAX_CAP_GRID_AXES as f64 {
        return Err(CalibError::Options(format!(
            "a grid spacing of {}° over a {}° tilt bound gives {axes:.3e} axes; the global search takes at most {MAX_CAP_GRID_AXES} (each costs an evaluation over every corner): use a spacing ≥ {}°",
            degrees(spacing.to_degrees()),
            degrees(options.max_tilt.to_degrees()),
            min_cap_grid_spacing_deg_text(options.max_tilt)
        )));
    }
    if let Some(bound) = options.max_rms_px
        && !(bound > 0.0)
    {
        return Err(CalibError::Options(format!(
            "the largest accepted RMS must be a positive number of pixels, got {bound}"
        )));
    }
    if options.huber.is_some_and(|k| !(k > 0.0)) {
        return Err(CalibError::Options(
            "the Huber threshold must be a positive number of pixels".into(),
        ));
    }
    let estimate = &options.estimate;
    if options.method == Method::Consecutive {
        let shared = matches!(rig.ports(), Ports::Shared(_)) && rig.cameras().len() >= 2;
        if !shared || target.board().is_none() {
            return Err(CalibError::Options(
                "the consecutive method (the thesis' invariants) needs two or more cameras behind one shared port and a board; use --method simultaneous or auto".into(),
            ));
        }
        if estimate.layers != 0 || estimate.extrinsics {
            return Err(CalibError::Options(
                "the consecutive method estimates the axis and the air distance only; --estimate layers or extrinsics needs --method simultaneous or auto".into(),
            ));
        }
    }
    if !(estimate.axis || estimate.distance || estimate.layers != 0 || estimate.extrinsics) {
        return Err(CalibError::Options(
            "--estimate names nothing to estimate".into(),
        ));
    }
    let layers = match rig.ports() {
        Ports::Shared(port) => port.layers().len(),
        Ports::PerCamera(ports) => ports.iter().map(|p| p.layers().len()).min().unwrap_or(0),
    };
    if estimate.layers != Estimate::ALL_LAYERS
        && let Some(k) = (layers..32).find(|&k| estimate.layer(k))
    {
        return Err(CalibError::Options(format!(
            "--estimate layer:{k}: the rig's port(s) have {layers} layer(s), layer:0 to layer:{}",
            layers.saturating_sub(1)
        )));
    }
    if estimate.extrinsics && rig.cameras().len() < 2 {
        return Err(CalibError::Options("--estimate extrinsics needs two or more cameras (the master's extrinsics define the frame)".into()));
    }
    Ok(())
}

/// Enough views and enough distinct target poses (an error otherwise: the answer would look
/// confident and be wrong, copies shrinking the standard deviations by √copies); few poses are a
/// warning.
fn check_views(seen: &[SeenView], warnings: &mut Vec<String>) -> Result<(), CalibError> {
    if seen.len() < MIN_VIEWS {
        return Err(CalibError::TooFewViews {
            usable: seen.len(),
            needed: MIN_VIEWS,
        });
    }
    let groups = compare_views(&view_corners(seen));
    groups.check_repeats()?;
    if groups.distinct < MIN_VIEWS {
        return Err(CalibError::TooFewPoses {
            views: seen.len(),
            distinct: groups.distinct,
            groups: describe_pose_groups(&groups),
            needed: MIN_VIEWS,
        });
    }
    if groups.distinct < FEW_VIEWS {
        let poses = if groups.distinct == seen.len() {
            format!("only {} views", seen.len())
        } else {
            format!(
                "only {} distinct target poses among {} views",
                groups.distinct,
                seen.len()
            )
        };
        warnings.push(format!("{poses}: the port is weakly determined (15-20 views at varied depths and angles are recommended)"));
    }
    Ok(())
}

/// Warnings for what the data cannot determine: an air distance that changes no ray, and a
/// planar target seen in fewer than three views.
fn warn_unobservable(
    rig: &Rig,
    target: &Target,
    seen: &[SeenView],
    options: &Options,
    warnings: &mut Vec<String>,
) {
    if options.estimate.distance {
        for (name, port) in port_names(rig) {
            if distance_unobservable(&port) {
                warnings.push(format!(
                    "port {name}: the same medium (index {}) on both sides of the port, so where it sits changes no ray: its air distance is not observable and stays at its start ({:.1} mm)",
                    port.index_air(),
                    port.air_distance() * 1e3
                ));
            }
        }
    }
    if target.is_planar() && seen.len() < 3 {
        warnings.push(format!("{} view(s) of a planar target: the port is weakly determined below 3 (a 3-D target fixes it from one)", seen.len()));
    }
}

/// Gross corner errors, found from each image of a board alone (left out of every estimate; the
/// report lists them with their residuals under the result).
fn screen_gross_errors(
    rig: &Rig,
    board: &crate::calib::problem::board::Board,
    seen: &[SeenView],
    warnings: &mut Vec<String>,
) -> Screening {
    let screening = screen(rig, board, seen);
    if let Some(worst) = screening.suspects.first() {
        let kept = screening.without_suspects(seen).is_some();
        warnings.push(format!(
            "{} corner(s) lie off the board's shape in their image by more than {:.2} px (largest {:.1} px: view {} corner {}, camera {}){}",
            screening.suspects.len(),
            screening.threshold_px,
            worst.deviation_px,
            worst.view,
            worst.corner,
            rig.cameras()[worst.camera].name,
            if kept { ": left out of the estimate (listed below when the result confirms them)" } else { "" }
        ));
    }
    screening
}

/// The camera pairs behind the shared port that saw the board together in [`MIN_VIEWS`] or more
/// views, prepared for the pair costs: none for a 3-D target or a port per camera.
fn shared_board_pairs(
    rig: &Rig,
    target: &Target,
    seen: &[SeenView],
) -> Result<Vec<StereoData>, CalibError> {
    let (Ports::Shared(_), Some(board)) = (rig.ports(), target.board()) else {
        return Ok(Vec::new());
    };
    let n = rig.cameras().len();
    let mut pairs = Vec::new();
    for a in 0..n {
        for b in a + 1..n {
            let data = StereoData::new(rig, [a, b], board, seen)?;
            if data.views.len() >= MIN_VIEWS {
                pairs.push(data);
            }
        }
    }
    Ok(pairs)
}

/// Levenberg–Marquardt for at most `iterations` steps: the short fits of the poses and the search.
pub(crate) fn fit_briefly(bundle: &Bundle, state: State, iterations: usize) -> State {
    let options = LmOptions {
        max_iterations: iterations,
        ..LmOptions::default()
    };
    crate::calib::solvers::lm::levenberg_marquardt(bundle, state, &options).0
}

/// RMS reprojection error of `state` under `bundle`, pixels (+∞ when it has none).
pub(crate) fn rms(bundle: &Bundle, state: &State) -> f64 {
    bundle
        .cost(state)
        .map_or(f64::INFINITY, |c| (c / bundle.residuals() as f64).sqrt())
}

use crate::calib::solvers::lm::LeastSquares;

/// The estimate: the state reached, the maximum-likelihood fit if one ran, what ran in words,
/// and the camera pair whose consecutive result started it.
struct Estimated {
    state: State,
    fit: Option<(
        LmReport,
        Option<BlockNormalEquations>,
        Vec<bundle::Parameter>,
    )>,
    strategy: String,
    pair: Option<[usize; 2]>,
}

/// The start and the refinement of the method (steps 3 to 5 of the module documentation).
#[allow(clippy::too_many_arguments)]
fn estimate(
    rig: &Rig,
    target: &Target,
    views: &[SeenView],
    pairs: &[StereoData],
    options: &Options,
    stages: &mut Vec<Stage>,
    warnings: &mut Vec<String>,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Estimated, CalibError> {
    // 3. Poses, pinhole first, then through the start port.
    let clock = Instant::now();
    let pinhole = State::of(rig, poses::initial_poses(rig, target, views)?);
    let pose_only = Bundle::new(rig, target, views, Estimate::NOTHING, options.huber);
    let rig_start = fit_briefly(&pose_only, pinhole.clone(), search::POSE_ITERATIONS);
    stages.push(Stage {
        name: "target poses (pinhole, then through the start port)".into(),
        port: None,
        cost: rms(&pose_only, &rig_start),
        unit: "px",
        iterations: search::POSE_ITERATIONS,
        seconds: clock.elapsed().as_secs_f64(),
    });
    let mut strategy = format!("{}: ", options.method.name());
    let moves_ports = options.estimate.axis || options.estimate.distance;
    // 4. The start of the ports.
    let use_pairs = !pairs.is_empty() && moves_ports;
    let mut starts: Vec<(String, State)> = Vec::new();
    let mut best_pair = None;
    if use_pairs {
        match consecutive_start(
            rig, target, views, &pinhole, pairs, options, stages, warnings, progress,
        ) {
            Ok((state, pair, profile)) => {
                best_pair = Some(pair);
                let names = pair.map(|k| rig.cameras()[k].name.as_str());
                strategy += &format!(
                    "consecutive (thesis) over {} camera pair(s), best pair {}–{}",
                    pairs.len(),
                    names[0],
                    names[1]
                );
                starts.push(("the consecutive result".into(), state));
                if let Some(profile) = profile {
                    starts.push(("the reprojection profile's minimum".into(), profile));
                }
            }
            // The consecutive method takes the in-air extrinsics as given: a few mm off can leave
            // its linear air layer without a solution. Where they are estimated too, its failure
            // is no verdict on the data, and `auto` goes on from the axis search instead.
            Err(e)
                if options.method == Method::Auto
                    && options.estimate.axis
                    && options.estimate.extrinsics =>
            {
                warnings.push(format!(
                    "the consecutive start failed ({e}); the global axis search replaced it"
                ));
            }
            Err(e) => return Err(e),
        }
    }
    if starts.is_empty() {
        if options.estimate.axis {
            let clock = Instant::now();
            let mut state = rig_start.clone();
            for p in 0..state.ports.len() {
                state = search::search_axis(rig, target, views, state, p, options)?;
            }
            let state = fit_briefly(&pose_only, state, search::POSE_ITERATIONS);
            strategy += "pose per view, global search over each port's axis";
            stages.push(Stage {
                name: "global axis search".into(),
                port: Some(first_port(&state)),
                cost: rms(&pose_only, &state),
                unit: "px",
                iterations: 0,
                seconds: clock.elapsed().as_secs_f64(),
            });
            starts.push(("the axis search's result".into(), state));
        } else {
            strategy += "pose per view";
        }
    }
    if options.method == Method::Auto && use_pairs {
        starts.push(("the rig's start guess".into(), rig_start.clone()));
    }
    if starts.is_empty() {
        starts.push(("the rig's start guess".into(), rig_start));
    }
    // The consecutive method ends with its start.
    if options.method == Method::Consecutive {
        let (_, state) = starts.swap_remove(0);
        return Ok(Estimated {
            state,
            fit: None,
            strategy,
            pair: best_pair,
        });
    }
    // 5. Maximum likelihood from each start; the lowest cost wins.
    let full = Bundle::new(rig, target, views, options.estimate, options.huber);
    let lm = LmOptions {
        max_iterations: options.max_iterations,
        ..LmOptions::default()
    };
    let residuals = full.residuals();
    let report_rms = |cost: f64| (cost / residuals as f64).sqrt();
    let mut best: Option<(State, LmReport, Option<BlockNormalEquations>)> = None;
    let mut finals = Vec::new();
    for (name, start) in &starts {
        if full.cost(start).is_none_or(|c| !c.is_finite()) {
            let port = first_port(start);
            warnings.push(format!(
                "{name} (tilt {:.2}°, air layer {:.1} mm) does not explain every corner (a target behind the port, or a camera outside the air): not used as a start",
                port.tilt().to_degrees(),
                port.air_distance * 1e3
            ));
            continue;
        }
        let clock = Instant::now();
        let stage_name = format!("maximum likelihood from {name}");
        let (state, report, normal) =
            levenberg_marquardt_observed(&full, start.clone(), &lm, &mut |i| {
                progress(&Progress {
                    stage: &stage_name,
                    done: i.iteration,
                    total: None,
                    cost: report_rms(i.cost),
                    unit: "px",
                })
            });
        stages.push(Stage {
            name: format!("{stage_name} ({})", report.termination.describe()),
            port: Some(first_port(&state)),
            cost: report_rms(report.final_cost),
            unit: "px",
            iterations: report.iterations,
            seconds: clock.elapsed().as_secs_f64(),
        });
        finals.push((name.clone(), first_port(&state), report.final_cost));
        if best
            .as_ref()
            .is_none_or(|(_, r, _)| report.final_cost < r.final_cost)
        {
            best = Some((state, report, normal));
        }
    }
    let (state, report, normal) = best.ok_or_else(|| CalibError::NoSolution {
        bound_deg: options.max_tilt.to_degrees(),
        reason: "no start explains every corner".into(),
    })?;
    let best_port = first_port(&state);
    for (name, port, cost) in &finals {
        let apart = port.normal.angle(&best_port.normal).to_degrees();
        // A start that ends in a clearly worse minimum only shows the cost has several; one
        // that ends nearly as low elsewhere makes the answer ambiguous.
        if *cost < report.final_cost * 1.5 && apart > 0.5 {
            warnings.push(format!(
                "the refinement from {name} ended {apart:.2}° away at a cost only ×{:.2} higher: the data hardly tell the two axes apart",
                cost / report.final_cost.max(f64::MIN_POSITIVE)
            ));
        }
    }
    if !report.termination.converged() {
        warnings.push(format!(
            "the maximum-likelihood refinement stopped early: {}",
            report.termination.describe()
        ));
    }
    strategy += &if starts.len() > 1 {
        format!(", maximum likelihood from {} starts", starts.len())
    } else {
        ", maximum likelihood".to_string()
    };
    Ok(Estimated {
        state,
        fit: Some((report, normal, full.globals().to_vec())),
        strategy,
        pair: best_pair,
    })
}

/// The first port's axis and air distance in `state`.
fn first_port(state: &State) -> Candidate {
    Candidate {
        normal: state.ports[0].normal,
        air_distance: state.ports[0].distance,
    }
}

/// The thesis' consecutive method on every pair (its cost batches on the options' backend); each
/// pair's axis and air distance is tried as the start of the whole rig (poses refitted) and the
/// one that explains every corner best wins. Returns that state, its pair and, for `auto`, the
/// state at the minimum of that pair's reprojection profile.
#[allow(clippy::too_many_arguments)]
fn consecutive_start(
    rig: &Rig,
    target: &Target,
    views: &[SeenView],
    pinhole: &State,
    pairs: &[StereoData],
    options: &Options,
    stages: &mut Vec<Stage>,
    warnings: &mut Vec<String>,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(State, [usize; 2], Option<State>), CalibError> {
    let pose_only = Bundle::new(rig, target, views, Estimate::NOTHING, options.huber);
    // The rig behind a pair's candidate port, its target poses from the pair's corners
    // triangulated under it and fitted rigidly (the views the pair did not see keep the pinhole
    // poses), then fitted through the port over every camera.
    let at = |candidate: &Candidate, data: &StereoData| {
        let mut state = pinhole.clone();
        state.ports[0].normal = candidate.normal;
        state.ports[0].distance = candidate.air_distance;
        if let Some(fit) = data
            .cameras_behind(candidate)
            .and_then(|cameras| SceneFit::new(data, &cameras))
        {
            for (pose, &v) in fit.poses().into_iter().zip(&data.view_numbers) {
                state.poses[v] = pose;
            }
        }
        fit_briefly(&pose_only, state, search::POSE_ITERATIONS)
    };
    let mut best: Option<(f64, State, usize)> = None;
    let mut last_error = None;
    let several = pairs.len() > 1;
    for (p, data) in pairs.iter().enumerate() {
        let backend = options.backend.over(data);
        let mut pair_stages = Vec::new();
        let mut pair_warnings = Vec::new();
        let candidate = match consecutive::consecutive_estimate(
            backend.as_ref(),
            options,
            &mut pair_stages,
            &mut pair_warnings,
            progress,
        ) {
            Ok(c) => c,
            Err(e) => {
                last_error = Some(e);
                continue;
            }
        };
        let name = data
            .cameras
            .map(|k| rig.cameras()[k].name.clone())
            .join("–");
        for stage in &mut pair_stages {
            if several {
                stage.name = format!("{} [{name}]", stage.name);
            }
        }
        stages.extend(pair_stages);
        warnings.extend(pair_warnings);
        let state = at(&candidate, data);
        let cost = rms(&pose_only, &state);
        if best.as_ref().is_none_or(|(c, _, _)| cost < *c) {
            best = Some((cost, state, p));
        }
    }
    let Some((_, state, p)) = best else {
        return Err(last_error.unwrap_or_else(|| {
            CalibError::Options(
                "no pair of cameras shares enough views of the board for the consecutive method"
                    .into(),
            )
        }));
    };
    let profile = if options.method == Method::Auto {
        let backend = options.backend.over(&pairs[p]);
        let candidate = consecutive::profile_minimum(backend.as_ref(), options, stages, progress)?;
        Some(at(&candidate, &pairs[p]))
    } else {
        None
    };
    Ok((state, pairs[p].cameras, profile))
}

/// The report of `estimate` over every corner of `seen` (the screened ones included), and the
/// calibrated rig.
#[allow(clippy::too_many_arguments)]
fn make_report(
    rig: &Rig,
    target: &Target,
    seen: &[SeenView],
    screening: Option<&Screening>,
    pairs: &[StereoData],
    estimate: Estimated,
    stages: Vec<Stage>,
    mut warnings: Vec<String>,
    options: &Options,
) -> Result<(Report, Rig), CalibError> {
    let Estimated {
        state,
        fit,
        strategy,
        pair,
    } = estimate;
    let calibrated = state.rig(rig).ok_or_else(|| {
        consecutive::no_solution(options, "the result puts a camera outside the air")
    })?;
    // The poses under the result over every corner (the screened ones too) for the residuals.
    let every = Bundle::new(rig, target, seen, Estimate::NOTHING, options.huber);
    let residuals = every.all_residuals(&state).ok_or_else(|| {
        consecutive::no_solution(options, "a fitted corner does not project under the result")
    })?;
    let labelled = label_residuals(seen, &residuals);
    let outliers = find_outliers(rig, seen, &labelled, screening);
    if let Some(worst) = outliers.first() {
        let count: std::collections::BTreeSet<(usize, usize)> =
            outliers.iter().map(|o| (o.view, o.corner)).collect();
        warnings.push(format!(
            "{} corner(s) have residuals far above the rest (largest {:.2} px at view {} corner {}, {} image): check the detections{}",
            count.len(),
            worst.residual_px,
            worst.view,
            worst.corner,
            worst.image,
            if options.huber.is_none() && fit.is_some() && outliers.iter().any(|o| !o.screened) { ", or use the Huber loss" } else { "" }
        ));
    }
    let observations: usize = seen.iter().map(SeenView::observations).sum();
    let all_residuals: Vec<f64> = residuals
        .iter()
        .flatten()
        .map(|r| r.norm_squared())
        .collect();
    let rms_px = (all_residuals.iter().sum::<f64>() / all_residuals.len().max(1) as f64).sqrt();
    // Standard deviations and σ̂ of a maximum-likelihood fit.
    let (covariance, sigma_px, iterations, termination, globals) = match &fit {
        Some((report, normal, globals)) => {
            let dimension =
                globals.len() + crate::calib::solvers::block::POSE_PARAMETERS * state.poses.len();
            // The fit ran on the views without the screened corner images.
            let residual_count = fitted_residuals(seen, screening);
            let dof = residual_count.saturating_sub(dimension);
            let sigma2 = if dof > 0 {
                report.final_cost / dof as f64
            } else {
                f64::NAN
            };
            let covariance = normal
                .as_ref()
                .and_then(BlockNormalEquations::global_covariance)
                .map(|c| c * sigma2);
            (
                covariance,
                Some(sigma2.sqrt()),
                report.iterations,
                report.termination.describe().to_string(),
                globals.clone(),
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
            "converged".to_string(),
            Vec::new(),
        ),
    };
    let ports = port_reports(rig, &state, &globals, covariance.as_ref());
    warnings.extend(uncertainty_warnings(
        &ports,
        fit.as_ref().map(|f| &f.0),
        &covariance,
    ));
    let cameras = camera_reports(
        rig,
        seen,
        camera_rms(rig, &labelled, &outliers),
        &globals,
        covariance.as_ref(),
        &state.extrinsics,
    );
    let fits = cameras
        .iter()
        .all(|c| c.inlier_rms_px.is_nan() || c.inlier_rms_px <= options.rms_bound());
    let scene = scene_errors(&calibrated, target, seen, pairs, pair);
    let corners: usize = seen
        .iter()
        .map(|v| {
            let set: std::collections::BTreeSet<usize> = v
                .cameras
                .iter()
                .flat_map(|(_, c)| c.iter().map(|(i, _)| *i))
                .collect();
            set.len()
        })
        .sum();
    let report = Report {
        method: options.method,
        strategy,
        estimate: options.estimate,
        ports,
        cameras,
        sigma_px,
        noise_px: screening.and_then(|s| s.noise_px),
        rms_px,
        scene,
        poses: state.poses.clone(),
        board: target.board().is_some(),
        stages,
        iterations,
        termination,
        outliers,
        fits,
        diagnosis: Vec::new(),
        warnings,
        seconds: 0.0,
        backend: options.backend.describe(),
        views: seen.len(),
        corners,
        observations,
    };
    Ok((report, calibrated))
}

/// Scalar residuals the maximum-likelihood fit ran on: two per corner image of the views without
/// the screened images.
fn fitted_residuals(seen: &[SeenView], screening: Option<&Screening>) -> usize {
    let clean = screening.and_then(|s| s.without_suspects(seen));
    let views = clean.as_deref().unwrap_or(seen);
    2 * views.iter().map(SeenView::observations).sum::<usize>()
}

/// Warnings about what the standard deviations say: an undetermined azimuth, a singular or weak
/// fit, a fit that ran out of iterations.
fn uncertainty_warnings(
    ports: &[report::PortReport],
    fit: Option<&LmReport>,
    covariance: &Option<nalgebra::DMatrix<f64>>,
) -> Vec<String> {
    let mut warnings = Vec::new();
    let port = &ports[0];
    if let Some(tilt_std) = port.tilt.std
        && port.tilt.value < 3.0 * tilt_std
    {
        warnings.push(format!(
            "the tilt ({:.3}°) is within 3 standard deviations of zero: the azimuth is undetermined",
            port.tilt.value.to_degrees()
        ));
    }
    match (fit, covariance) {
        (Some(_), None) => warnings.push("JᵀJ is singular at the result: the views do not determine what is estimated (vary the target's angle and distance)".into()),
        (Some(_), Some(_)) => {
            let weak_tilt = port.tilt.std.is_some_and(|s| s > WEAK_TILT_STD_DEG.to_radians());
            let weak_air = port.distance.std.is_some_and(|s| s > WEAK_AIR_STD_M);
            if weak_tilt || weak_air {
                warnings.push(format!(
                    "the views hardly constrain the result (σ tilt {:.2}°, σ air layer {:.1} mm): vary the target's angle and distance between views",
                    port.tilt.std.unwrap_or(f64::NAN).to_degrees(),
                    port.distance.std.unwrap_or(f64::NAN) * 1e3
                ));
            }
        }
        _ => {}
    }
    if fit.is_some_and(|r| r.termination == Termination::MaxIterations) {
        warnings.push("raise --max-iterations".into());
    }
    warnings
}

/// The 3-D errors of the triangulated corners of one camera pair under the calibrated rig: the
/// pair the consecutive start ran on, else the first pair that saw the board in three views.
fn scene_errors(
    calibrated: &Rig,
    target: &Target,
    seen: &[SeenView],
    pairs: &[StereoData],
    pair: Option<[usize; 2]>,
) -> Option<SceneErrors> {
    let board = target.board()?;
    let pair = pair
        .or_else(|| pairs.first().map(|d| d.cameras))
        .or_else(|| {
            let n = calibrated.cameras().len();
            (0..n)
                .flat_map(|a| (a + 1..n).map(move |b| [a, b]))
                .find(|&[a, b]| {
                    StereoData::new(calibrated, [a, b], board, seen)
                        .is_ok_and(|d| d.views.len() >= MIN_VIEWS)
                })
        })?;
    let cameras = pair.map(|k| calibrated.refractive_camera(k));
    // Over every corner, else (a screened corner that does not triangulate) over the kept ones.
    let every = StereoData::new(calibrated, pair, board, seen).ok()?;
    let (data, fit) = match SceneFit::new(&every, &cameras) {
        Some(fit) => (every, fit),
        None => {
            let kept = pairs.iter().find(|d| d.cameras == pair)?.clone();
            let fit = SceneFit::new(&kept, &cameras)?;
            (kept, fit)
        }
    };
    Some(SceneErrors {
        cameras: pair.map(|k| calibrated.cameras()[k].name.clone()),
        rms_m: fit.scene_rms(),
        square_deviation_rms_m: fit.square_deviation_rms(&data),
    })
}
