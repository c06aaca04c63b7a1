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
//!
//! Before all of it, with images, each camera's in-air intrinsics ([`intrinsics`]: Zhang's
//! closed form, maximum likelihood over the lens model and the board poses, the lens terms chosen
//! by held-out views).

pub mod acceptance;
pub mod boards;
pub mod bundle;
mod checks;
pub mod consecutive;
pub mod diagnose;
mod estimate;
pub mod extrinsics;
pub mod intrinsics;
pub mod misfit;
pub mod poses;
pub mod report;
pub mod search;
pub mod selection;
pub mod turns;
pub mod water_lenses;

pub(crate) use bundle::fit_briefly;

#[cfg(feature = "gpu")]
use std::sync::Arc;
use std::time::Instant;

use self::bundle::{Bundle, Estimate};
use self::estimate::Stage;
use self::report::Report;
#[cfg(feature = "gpu")]
use crate::calib::backends::gpu::{GpuBackend, GpuResiduals};
use crate::calib::backends::residuals::ResidualBackend;
use crate::calib::backends::{CostBackend, CpuBackend};
use crate::calib::error::CalibError;
use crate::calib::problem::data::StereoData;
use crate::calib::problem::observations::{Observations, SeenView};
use crate::calib::problem::target::Target;
#[cfg(feature = "gpu")]
use crate::engine::GpuEngine;
#[cfg(feature = "gpu")]
use crate::gpu::Precision;
use crate::model::Rig;

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
    /// reprojection profile, the rig's start guess; or the axis search and the rig's start guess); the lowest cost wins.
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

/// Where the cost batches of the consecutive method and the bundle's residual stencils run.
#[derive(Clone, Default)]
pub enum Backend {
    /// The f64 reference on every CPU core.
    #[default]
    Cpu,
    /// The WGSL kernels of a GPU engine (f64 kernels agree with the CPU to ~1e-12; the
    /// refinement's finite differences need them): the pair costs of the consecutive method,
    /// and, with f64 kernels, the bundle's residual stencils (target poses, axis search, maximum
    /// likelihood) of every rig.
    #[cfg(feature = "gpu")]
    Gpu(Arc<GpuEngine>),
}

impl std::fmt::Debug for Backend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Cpu => f.write_str("Cpu"),
            #[cfg(feature = "gpu")]
            Self::Gpu(engine) => write!(f, "Gpu({})", engine.context().adapter().name),
        }
    }
}

impl Backend {
    /// The cost backend over `data` on this device.
    pub fn over<'a>(&'a self, data: &'a StereoData) -> Box<dyn CostBackend + 'a> {
        match self {
            Self::Cpu => Box::new(CpuBackend::new(data)),
            #[cfg(feature = "gpu")]
            Self::Gpu(engine) => Box::new(GpuBackend::new(data, engine.as_ref())),
        }
    }

    /// The backend of `bundle`'s residual stencils on this device: `None` on the CPU (the
    /// bundle's own code) and on an f32 engine (the bundle's central differences need f64
    /// residuals: it stays on the CPU).
    #[cfg_attr(not(feature = "gpu"), allow(unused_variables))]
    pub fn bundle_residuals(&self, bundle: &Bundle) -> Option<Box<dyn ResidualBackend>> {
        match self {
            Self::Cpu => None,
            #[cfg(feature = "gpu")]
            Self::Gpu(engine) => GpuResiduals::new(engine.clone(), &bundle.observed_corners())
                .ok()
                .map(|b| Box::new(b) as Box<dyn ResidualBackend>),
        }
    }

    /// One line saying where each stage of a calibration runs: [`describe`](Self::describe),
    /// then, on a GPU, which stages use it.
    pub fn describe_stages(&self) -> String {
        match self {
            Self::Cpu => self.describe(),
            #[cfg(feature = "gpu")]
            Self::Gpu(engine) if engine.precision() == Precision::F64 => format!(
                "{}; on the GPU: the pair costs of the consecutive method and the bundle's residual stencils (target poses, axis search, maximum likelihood); on the CPU: the normal equations' sums and solves, and the report's residuals",
                self.describe()
            ),
            #[cfg(feature = "gpu")]
            Self::Gpu(_) => format!(
                "{}; on the GPU: the pair costs of the consecutive method; on the CPU: the bundle (target poses, axis search, maximum likelihood), whose central differences need f64 kernels",
                self.describe()
            ),
        }
    }

    /// One line saying what evaluates the cost batches.
    pub fn describe(&self) -> String {
        match self {
            Self::Cpu => format!(
                "cpu (f64 reference, {} threads)",
                rayon::current_num_threads()
            ),
            #[cfg(feature = "gpu")]
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
    /// A Gaussian prior on the intrinsics where they are estimated (the lenses calibrated in
    /// air, refined under water: [`boards`]); `None`: none.
    pub lens_prior: Option<bundle::LensPrior>,
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
            lens_prior: None,
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

/// Fewest distinct poses of a planar target accepted; below [`FEW_VIEWS`] a warning says the
/// result is weak.
pub const MIN_VIEWS: usize = 3;
/// Fewest views of a 3-D (non-planar) target accepted: one fixes its pose and the port.
pub const MIN_VIEWS_3D: usize = 1;
/// Views of a planar target below which a calibration is flagged as weakly determined.
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
/// image and corner); fewer than [`MIN_VIEWS`] distinct poses of a planar target (of a 3-D one,
/// [`MIN_VIEWS_3D`]); repeated views; no axis
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
    // A chessboard's corners numbered alike in every camera of a view (a detector that numbers
    // each image on its own may start a colour-symmetric board at either end).
    let (agreed, turned) = match turns::agree_observation_turns(rig, observations) {
        Some((agreed, turned)) => (Some(agreed), turned),
        None => (None, Vec::new()),
    };
    let observations = agreed.as_ref().unwrap_or(observations);
    let mut calibration = calibrate_unjudged(rig, observations, options, progress)?;
    let report = &mut calibration.report;
    for (name, t) in &turned {
        report.warnings.push(format!(
            "camera '{name}': the corner order of {} of its {} images was turned to agree with the other cameras of their views (the board looks alike turned; the observations number its corners from another end)",
            t.turned, t.images
        ));
    }
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
        diagnose_misfit(rig, observations, report, options)?;
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

/// [`calibrate_with_progress`] without its judgement: [`Report::fits`] holds the RMS to
/// [`Options::rms_bound`] alone, whatever the noise, and no diagnosis runs. For callers that
/// judge the fit by other data (held-out frames: [`acceptance`]).
pub fn calibrate_unjudged(
    rig: &Rig,
    observations: &Observations,
    options: &Options,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Calibration, CalibError> {
    let started = Instant::now();
    checks::check_options(rig, &observations.target, options)?;
    let (observations, left_out) = &observations.without_unusable_images();
    let seen = observations.resolve(rig)?;
    let mut warnings = left_out.clone();
    warnings.extend(observations.check(&seen)?);
    checks::check_views(&observations.target, &seen, &mut warnings)?;
    let mut calibration = calibrate_views(
        rig,
        &observations.target,
        &seen,
        options,
        warnings,
        progress,
    )?;
    calibration.report.seconds = started.elapsed().as_secs_f64();
    Ok(calibration)
}

/// Fills `report.diagnosis` (a calibration of `rig` from `observations` that does not fit): what
/// the data look like, each cause checked by calibrating again ([`diagnose::diagnosis`]).
pub fn diagnose_misfit(
    rig: &Rig,
    observations: &Observations,
    report: &mut Report,
    options: &Options,
) -> Result<(), CalibError> {
    let (observations, _) = &observations.without_unusable_images();
    let seen = observations.resolve(rig)?;
    report.diagnosis = diagnose::diagnosis(rig, &observations.target, &seen, report, options);
    Ok(())
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
    checks::warn_unobservable(rig, target, seen, options, &mut warnings);
    let screening = target
        .board()
        .map(|board| checks::screen_gross_errors(rig, board, seen, &mut warnings));
    let clean_views = screening.as_ref().and_then(|s| s.without_suspects(seen));
    let clean = clean_views.as_deref().unwrap_or(seen);
    let pairs = estimate::shared_board_pairs(rig, target, clean)?;
    for data in &pairs {
        warnings.extend(diagnose::pairing_findings(data));
    }
    let mut stages = Vec::new();
    // The bundle's residual stencils over these views on the options' device (None: the CPU).
    let residuals =
        options
            .backend
            .bundle_residuals(&Bundle::new(rig, target, clean, Estimate::NOTHING, None));
    let mut steps = estimate::Steps {
        rig,
        target,
        views: clean,
        residuals: residuals.as_deref(),
        options,
        stages: &mut stages,
        warnings: &mut warnings,
        progress,
    };
    let estimated = estimate::estimate(&mut steps, &pairs).map_err(|error| {
        match (error, pairs.first()) {
            // What the data look like, where nothing explains them.
            (CalibError::NoSolution { reason, bound_deg }, Some(data)) => {
                let noise = screening.as_ref().and_then(|s| s.noise_px);
                CalibError::NoSolution {
                    bound_deg,
                    reason: format!(
                        "{reason}. What the data look like: {}",
                        diagnose::explain(data, None, noise).join("; ")
                    ),
                }
            }
            (other, _) => other,
        }
    })?;
    if let Some(reason) = residuals.as_ref().and_then(|r| r.failure()) {
        warnings.push(format!(
            "the GPU failed in the bundle ({reason}): its residuals ran on the CPU from then on"
        ));
    }
    let input = report::Input {
        rig,
        target,
        seen,
        screening: screening.as_ref(),
        pairs: &pairs,
        options,
    };
    let (mut report, calibrated) = report::make_report(&input, estimated, stages, warnings)?;
    report.seconds = started.elapsed().as_secs_f64();
    Ok(Calibration {
        rig: calibrated,
        report,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::Board;
    use crate::calib::simulate::{SceneSpec, simulate};
    use crate::model::{Interface, Layer, PinholeCamera, RigCamera, normal_from_tilt_azimuth};
    use nalgebra::{Matrix3, Vector3};

    const BOARD: Board = Board {
        rows: 5,
        cols: 7,
        square: 0.03,
    };

    /// One 800×600 camera behind a port tilted 6° with 10 mm of glass and 20 mm of air.
    fn one_camera(tilt_deg: f64) -> Rig {
        let intrinsics =
            PinholeCamera::new("cam", 800, 600, 700.0, 700.0, 400.0, 300.0, [0.0; 5]).unwrap();
        let camera =
            RigCamera::new("cam", intrinsics, Matrix3::identity(), Vector3::zeros()).unwrap();
        let n = normal_from_tilt_azimuth(tilt_deg.to_radians(), 0.7);
        let glass = vec![Layer {
            thickness: 0.01,
            index: 1.49,
        }];
        let port = Interface::new(n.into_inner(), 0.02, glass, 1.0, 1.333).unwrap();
        Rig::new(vec![camera], port).unwrap()
    }

    fn naive(rig: &Rig) -> Rig {
        let port = rig.shared_interface().unwrap();
        rig.with_interface(port.with_pose(Vector3::z(), 0.01).unwrap())
            .unwrap()
    }

    #[test]
    fn methods_are_named_and_defaults_hold() {
        for m in [Method::Consecutive, Method::Simultaneous, Method::Auto] {
            assert_eq!(Method::from_name(m.name()), Some(m));
        }
        assert_eq!(Method::from_name("thesis"), None);
        let options = Options::default();
        assert_eq!(options.method, Method::Auto);
        assert_eq!(options.rms_bound(), DEFAULT_MAX_RMS_PX);
        assert!((options.grid_spacing() - 1.5f64.to_radians()).abs() < 1e-15);
        // A tilt bound below the default spacing takes the spacing with it.
        let narrow = Options {
            max_tilt: 0.5f64.to_radians(),
            ..Options::default()
        };
        assert_eq!(narrow.grid_spacing(), narrow.max_tilt);
        assert_eq!(Backend::default().describe().split(' ').next(), Some("cpu"));
    }

    #[test]
    fn options_that_do_not_apply_are_refused_before_any_work() {
        let rig = one_camera(6.0);
        let board = Target::Board(BOARD);
        let refused = |options: Options, words: &str| {
            let error = checks::check_options(&rig, &board, &options).unwrap_err();
            assert!(error.to_string().contains(words), "{error}");
        };
        refused(
            Options {
                max_tilt: 85f64.to_radians(),
                ..Options::default()
            },
            "(0°, 80°)",
        );
        refused(
            Options {
                grid_spacing: Some(2.0f64.to_radians()),
                max_tilt: 1f64.to_radians(),
                ..Options::default()
            },
            "grid spacing",
        );
        refused(
            Options {
                max_rms_px: Some(0.0),
                ..Options::default()
            },
            "positive number of pixels",
        );
        refused(
            Options {
                method: Method::Consecutive,
                ..Options::default()
            },
            "two or more cameras behind one shared port",
        );
        refused(
            Options {
                estimate: Estimate::NOTHING,
                ..Options::default()
            },
            "names nothing",
        );
        refused(
            Options {
                estimate: Estimate::parse("axis,layer:3").unwrap(),
                ..Options::default()
            },
            "layer:0 to layer:0",
        );
        refused(
            Options {
                estimate: Estimate::parse("axis,extrinsics").unwrap(),
                ..Options::default()
            },
            "two or more cameras",
        );
        assert!(checks::check_options(&rig, &board, &Options::default()).is_ok());
    }

    #[test]
    fn one_camera_comes_back_exactly_from_noise_free_views() {
        // The axis search (no pair shares a port), then maximum likelihood: the truth, to
        // rounding, with every stage reported and no warning of a misfit.
        let truth = one_camera(6.0);
        let scene = simulate(&truth, &SceneSpec::new(Target::Board(BOARD), 8, 0.0, 4)).unwrap();
        let calibration =
            calibrate(&naive(&truth), &scene.observations, &Options::default()).unwrap();
        let (found, want) = (
            calibration.rig.shared_interface().unwrap(),
            truth.shared_interface().unwrap(),
        );
        let axis = found.normal().angle(want.normal()).to_degrees();
        let air = (found.air_distance() - want.air_distance()).abs();
        assert!(axis < 1e-6 && air < 1e-8, "axis {axis}°, air {air} m");
        let report = &calibration.report;
        assert!(report.fits && report.rms_px < 1e-6, "{report:?}");
        assert!(
            report.strategy.contains("global search"),
            "{}",
            report.strategy
        );
        assert_eq!(report.views, 8);
        assert_eq!(report.observations, 8 * BOARD.corners());
        assert!(report.scene.is_none(), "one camera has no pair");
        assert!(report.diagnosis.is_empty());
        let names: Vec<&str> = report.stages.iter().map(|s| s.name.as_str()).collect();
        assert!(
            names[0].starts_with("target poses")
                && names.last().unwrap().starts_with("maximum likelihood"),
            "{names:?}"
        );
    }
}
