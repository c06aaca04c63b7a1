//! A whole rig from board views alone: the cameras calibrated in air (given, or by the in-air
//! intrinsics stage), their extrinsics started from the board co-observations under water
//! ([`extrinsics_start`]), then the one calibration ([`calibrate_unjudged`]) over the
//! ports, the extrinsics and every board pose, under a Huber loss; frames far above the others
//! dropped and the calibration run again; a share of the frames held out and reported; the
//! intrinsics refined with the frames where the held-out frames say it helps
//! ([`RefineIntrinsics`]); and the verdict, from what the held-out frames say of the fit
//! ([`acceptance`](super::acceptance)).
//!
//! What `flatport calibrate --images DIR --board BOARD.json --port …` runs once the boards are
//! detected (no I/O here: frames come as corners).

use nalgebra::{Matrix3, Point3, Vector3};

pub use super::acceptance::Validation;
use super::acceptance::{PLAIN_RMS_PX, Residuals, Verdict, loose_ports, verdict};
use super::bundle::{
    Bundle, Estimate, LensPrior, MIN_START_AIR_M, State, intrinsic_values, shared_distance_floor,
};
use super::extrinsics::{Link, extrinsics_start};
use super::report::add_lens_uncertainty;
use super::turns::agree_turns;
use super::{
    Calibration, Options, Progress, calibrate_unjudged, diagnose_misfit, fit_briefly, poses,
};
use crate::base::Board;
use crate::calib::error::CalibError;
pub use crate::calib::problem::observations::WaterFrame;
use crate::calib::problem::observations::{
    CameraKey, Image, Observations, SeenView, View, unusable_image,
};
use crate::calib::problem::target::Target;
use crate::calib::solvers::lm::LeastSquares;
use crate::model::{Interface, Layer, PinholeCamera, Ports, Rig, RigCamera};

/// The kind of port in front of the cameras (`--port`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PortKind {
    /// One bare water surface in front of every camera (no glass): AquaCal's rig.
    Surface,
    /// One port, with its glass, in front of every camera.
    Shared,
    /// A port per camera (its own housing).
    Housings,
}

impl PortKind {
    /// `surface`, `shared` or `housings`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Surface => "surface",
            Self::Shared => "shared",
            Self::Housings => "housings",
        }
    }

    /// The kind named `name`.
    pub fn from_name(name: &str) -> Option<Self> {
        [Self::Surface, Self::Shared, Self::Housings]
            .into_iter()
            .find(|k| k.name() == name)
    }
}

/// Air distance of the start ports, metres: the naive guess (the port on each camera's z axis,
/// 10 mm of air) that the pipeline's global searches start from.
pub const START_AIR_DISTANCE_M: f64 = 0.01;

/// Share of the frames held out of the fit by default and reported on.
pub const DEFAULT_HOLDOUT: f64 = 0.2;

/// Huber threshold of the fit by default, pixels: a few times the noise of a sub-pixel corner
/// detector (0.05–0.3 px), so that good corners keep least squares' efficiency and a misplaced
/// corner is down-weighted.
pub const DEFAULT_HUBER_PX: f64 = 1.0;

/// A frame whose RMS reprojection error exceeds this many times the median frame's (and
/// [`OUTLIER_FLOOR_PX`]) is dropped and the calibration run again.
pub const OUTLIER_FACTOR: f64 = 4.0;
/// See [`OUTLIER_FACTOR`], pixels.
pub const OUTLIER_FLOOR_PX: f64 = 0.5;

/// Whether the bundle also refines the cameras' in-air intrinsics with the underwater frames
/// ([`BoardsOptions::refine_intrinsics`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RefineIntrinsics {
    /// After the fit with the in-air intrinsics fixed, fit again with every camera's intrinsics
    /// estimated too ([`Estimate::intrinsics`]) and keep them where the held-out frames'
    /// reprojection RMS falls by more than [`REFINE_MARGIN`] (no frames held out: kept fixed).
    /// The default: an in-air calibration is never exact (fx ± 0.1 %, k1 ± 0.003 move corners
    /// at the image's edge by tenths of a pixel, which the port and extrinsics otherwise absorb),
    /// and the held-out frames, not the fitted ones, tell whether the extra parameters explain
    /// the water or only the noise.
    #[default]
    Auto,
    /// Keep the in-air intrinsics fixed.
    Never,
    /// Refine them whenever the refined fit fits, whatever the held-out frames say (they are
    /// still reported).
    Always,
}

impl RefineIntrinsics {
    /// The choice named `name` (`auto`, `never`, `always`: `--refine-intrinsics`'s values).
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "auto" => Some(Self::Auto),
            "never" => Some(Self::Never),
            "always" => Some(Self::Always),
            _ => None,
        }
    }
}

impl RefineIntrinsics {
    /// `auto`, `never` or `always`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Never => "never",
            Self::Always => "always",
        }
    }
}

/// Share by which the held-out frames' RMS must fall for [`RefineIntrinsics::Auto`] to keep the
/// refined intrinsics: eight more parameters per camera fitted to thousands of corners raise a
/// held-out RMS by well under 1 % when they explain nothing (the overfit of p parameters over
/// N residuals is ~p/2N), so a 2 % fall is the intrinsics' doing, not the noise's.
pub const REFINE_MARGIN: f64 = 0.02;

/// What [`RefineIntrinsics::Auto`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct IntrinsicsChoice {
    /// Whether the refined intrinsics were kept (the result's rig and report are that fit's).
    pub refined: bool,
    /// The held-out frames' RMS with the in-air intrinsics fixed, pixels.
    pub fixed_rms_px: f64,
    /// The held-out frames' RMS with the intrinsics refined, pixels (+∞ where that fit failed).
    pub refined_rms_px: f64,
    /// Why, in words.
    pub reason: String,
}

/// The rig to calibrate: its cameras (calibrated in air; extrinsics unknown) and its ports.
#[derive(Debug, Clone)]
pub struct RigSetup {
    /// The cameras in rig order, the master first.
    pub cameras: Vec<PinholeCamera>,
    /// The kind of port.
    pub port: PortKind,
    /// Each camera's glass (for `Shared`, the first entry is the port's; for `Surface`, none).
    pub glass: Vec<Vec<Layer>>,
    /// Index of the medium around the cameras.
    pub index_air: f64,
    /// Index of the water.
    pub index_water: f64,
}

/// How to calibrate from boards.
#[derive(Debug, Clone)]
pub struct BoardsOptions {
    /// The calibration's options (its `estimate` is set from the rig: axis and distance of every
    /// port, and the extrinsics where there are several cameras).
    pub calibration: Options,
    /// Share of the frames (seen by two or more cameras) held out of the fit and reported on.
    pub holdout: f64,
    /// Drop frames far above the others ([`OUTLIER_FACTOR`]) and calibrate again.
    pub drop_outliers: bool,
    /// Whether the in-air intrinsics are refined with the frames (default
    /// [`RefineIntrinsics::Auto`]: where the held-out frames say it helps).
    pub refine_intrinsics: RefineIntrinsics,
    /// Per camera, the σ of its lens ([`INTRINSICS`](super::bundle::INTRINSICS) order) from its
    /// in-air calibration; empty when unknown. Where the lenses stay fixed, the ports' and
    /// extrinsics' σ then carry the lenses' uncertainty ([`add_lens_uncertainty`]) instead of
    /// taking the lenses as exact.
    pub lens_std: Vec<[f64; 9]>,
    /// Whether each image's corner order was chosen on its own, so that the cameras of a frame
    /// may number the corners from different ends (a chessboard detected without a rig): the
    /// orders are made to agree ([`agree_turns`]) before the fit.
    pub turnable: bool,
}

impl Default for BoardsOptions {
    fn default() -> Self {
        Self {
            calibration: Options {
                huber: Some(DEFAULT_HUBER_PX),
                ..Options::default()
            },
            holdout: DEFAULT_HOLDOUT,
            drop_outliers: true,
            refine_intrinsics: RefineIntrinsics::Auto,
            lens_std: Vec::new(),
            turnable: false,
        }
    }
}

/// A rig calibrated from boards.
#[derive(Debug, Clone)]
pub struct BoardsCalibration {
    /// The calibrated rig and its report (views numbered as in [`BoardsCalibration::fitted`]).
    pub calibration: Calibration,
    /// The rig the calibration started from (extrinsics from the co-observations, naive ports).
    pub start: Rig,
    /// How each camera's start was linked to the master.
    pub links: Vec<Link>,
    /// The labels of the frames fitted, in the report's view order.
    pub fitted: Vec<String>,
    /// Frames dropped as outliers, with why.
    pub dropped: Vec<(String, String)>,
    /// Corners left out after the first fit for residuals far above the rest (the first fit's
    /// outliers: misplaced detections), named.
    pub dropped_corners: Vec<String>,
    /// Images left out before the fit (too few corners, corners on a line), with why.
    pub left_out: Vec<String>,
    /// Cameras whose images' corner order was turned to agree with the other cameras of their
    /// frames ([`BoardsOptions::turnable`]), a line each.
    pub turned: Vec<String>,
    /// The held-out frames' verdict (`None` when there were too few frames to hold any out).
    pub validation: Option<Validation>,
    /// Whether the intrinsics were refined and the held-out RMS of both fits (`None` with
    /// [`RefineIntrinsics::Never`], with intrinsics estimated in
    /// [`BoardsOptions::calibration`] already, or without held-out frames).
    pub intrinsics: Option<IntrinsicsChoice>,
    /// Good, usable or poor, and why ([`acceptance`](super::acceptance)); the report's
    /// [`fits`](super::report::Report::fits) is whether it is accepted.
    pub verdict: Verdict,
    /// The median error of the fitted frames' squares triangulated through the rig, percent of
    /// the square (`None` when no corner pair was seen by two cameras).
    pub fitted_squares_percent: Option<f64>,
}

/// The start rig: `setup`'s cameras at the identity (their extrinsics come from the frames) and
/// the naive ports.
pub fn start_rig(names: &[String], setup: &RigSetup) -> Result<Rig, CalibError> {
    let options = |e: crate::model::ModelError| CalibError::Options(e.to_string());
    let cameras = names
        .iter()
        .zip(&setup.cameras)
        .map(|(name, intrinsics)| {
            RigCamera::new(name, *intrinsics, Matrix3::identity(), Vector3::zeros())
        })
        .collect::<Result<Vec<_>, _>>()
        .map_err(options)?;
    let port = |layers: &[Layer]| {
        Interface::new(
            Vector3::z(),
            START_AIR_DISTANCE_M,
            layers.to_vec(),
            setup.index_air,
            setup.index_water,
        )
        .map_err(options)
    };
    let none: &[Layer] = &[];
    let glass = |k: usize| setup.glass.get(k).map_or(none, Vec::as_slice);
    let ports = match setup.port {
        PortKind::Surface => Ports::Shared(port(none)?),
        PortKind::Shared => Ports::Shared(port(glass(0))?),
        PortKind::Housings => Ports::PerCamera(
            (0..cameras.len())
                .map(|k| port(glass(k)))
                .collect::<Result<_, _>>()?,
        ),
    };
    Rig::with_ports(cameras, ports).map_err(options)
}

/// Calibrates the rig of `setup` (camera `names` in rig order) from `frames` of `board` under
/// water, by the steps of the module documentation.
///
/// Errors: fewer than three usable frames; a camera that never shares a frame with the others
/// (directly or through a chain); whatever [`calibrate_unjudged`] refuses. A fit that is plainly
/// wrong is not an error: its [`BoardsCalibration::verdict`] is poor and the report's `fits` false.
pub fn calibrate_from_boards(
    names: &[String],
    setup: &RigSetup,
    board: &Board,
    frames: &[WaterFrame],
    options: &BoardsOptions,
    progress: &mut dyn FnMut(&Progress),
) -> Result<BoardsCalibration, CalibError> {
    let target = Target::Board(*board);
    let base = start_rig(names, setup)?;
    // A chessboard's corners numbered alike in every camera of a frame.
    let mut turned = Vec::new();
    let frames = if options.turnable && names.len() > 1 {
        let mut frames = frames.to_vec();
        for t in agree_turns(&base, board, &mut frames) {
            turned.push(format!(
                "camera '{}': the corner order of {} of its {} images turned to agree with the other cameras of their frames (the board looks alike turned)",
                names[t.camera], t.turned, t.images
            ));
        }
        std::borrow::Cow::Owned(frames)
    } else {
        std::borrow::Cow::Borrowed(frames)
    };
    // Every image with enough corners off one line; frames with none left out.
    let mut left_out = Vec::new();
    let mut usable: Vec<(String, View)> = Vec::new();
    for frame in frames.iter() {
        let mut images = Vec::new();
        for (k, corners) in frame.corners.iter().enumerate() {
            if corners.is_empty() {
                continue;
            }
            let indices: Vec<usize> = corners.iter().map(|(i, _)| *i).collect();
            if let Some(why) = unusable_image(&target, &indices) {
                left_out.push(format!(
                    "frame {}, camera '{}': left out ({why}: no pose of the board from it)",
                    frame.label, names[k]
                ));
                continue;
            }
            let mut full = vec![None; board.corners()];
            for (i, p) in corners {
                if let Some(slot) = full.get_mut(*i) {
                    *slot = Some(*p);
                }
            }
            images.push(Image {
                camera: CameraKey::Name(names[k].clone()),
                key: names[k].clone(),
                corners: full,
            });
        }
        if !images.is_empty() {
            usable.push((frame.label.clone(), View { images }));
        }
    }
    // Hold out every m-th frame seen by two or more cameras (spread over the sequence; with one
    // camera, every m-th frame).
    let needed = names.len().min(2);
    let several = |view: &View| view.images.len() >= needed;
    let candidates = usable.iter().filter(|(_, v)| several(v)).count();
    let held = (options.holdout.clamp(0.0, 0.5) * candidates as f64).floor() as usize;
    let mut held_out = Vec::new();
    let mut fitted = Vec::new();
    if held > 0 && candidates - held >= super::MIN_VIEWS {
        let step = candidates as f64 / held as f64;
        let mut next = step / 2.0;
        let mut index = 0.0;
        for (label, view) in usable {
            if several(&view) {
                if index >= next.floor() && held_out.len() < held {
                    held_out.push((label, view));
                    next += step;
                } else {
                    fitted.push((label, view));
                }
                index += 1.0;
            } else {
                fitted.push((label, view));
            }
        }
    } else {
        fitted = usable;
    }
    if fitted.len() < super::MIN_VIEWS {
        return Err(CalibError::TooFewViews {
            usable: fitted.len(),
            needed: super::MIN_VIEWS,
        });
    }
    let observations = |views: &[(String, View)]| Observations {
        target: target.clone(),
        views: views.iter().map(|(_, v)| v.clone()).collect(),
        stereo_form: false,
    };
    // The extrinsics' start from the fitted frames.
    let seen = observations(&fitted).resolve(&base)?;
    let (cam_from_master, links) = extrinsics_start(&base, &target, &seen)?;
    let mut cameras = base.cameras().to_vec();
    for (camera, pose) in cameras.iter_mut().zip(&cam_from_master) {
        camera.cam_from_master = *pose;
    }
    // The naive port on the master's axis 10 mm away may leave a lower camera under the water
    // (cameras at different heights above a surface): the port moves out past the lowest one.
    let ports = match base.ports() {
        Ports::Shared(port) => {
            let floor = shared_distance_floor(port.normal(), &cam_from_master) - MIN_START_AIR_M
                + START_AIR_DISTANCE_M;
            Ports::Shared(
                port.with_pose(port.normal().into_inner(), floor)
                    .map_err(|e| CalibError::Options(e.to_string()))?,
            )
        }
        per_camera => per_camera.clone(),
    };
    let start = Rig::with_ports(cameras, ports).map_err(|e| CalibError::Options(e.to_string()))?;
    let mut calibration_options = options.calibration.clone();
    calibration_options.estimate = Estimate {
        extrinsics: names.len() > 1,
        ..calibration_options.estimate
    };
    // The fits are held to the plain bound only: the held-out frames judge them below.
    let rms_bound = options.calibration.max_rms_px.unwrap_or(PLAIN_RMS_PX);
    calibration_options.max_rms_px = Some(rms_bound);
    let mut calibration = calibrate_unjudged(
        &start,
        &observations(&fitted),
        &calibration_options,
        progress,
    )?;
    // Corners far above the rest (the report's outliers: a misplaced detection), and frames far
    // above the others: left out, and the calibration run again once.
    let mut dropped = Vec::new();
    let mut dropped_corners = Vec::new();
    let mut again = false;
    if options.drop_outliers {
        // The frames first (their RMS leaves the outlier corners out), then the corners.
        let frame_rms = frame_rms(&calibration, &fitted);
        let mut sorted: Vec<f64> = frame_rms
            .iter()
            .copied()
            .filter(|r| r.is_finite())
            .collect();
        sorted.sort_by(f64::total_cmp);
        let median = sorted.get(sorted.len() / 2).copied().unwrap_or(f64::NAN);
        let bound = (OUTLIER_FACTOR * median).max(OUTLIER_FLOOR_PX);
        let keep: Vec<bool> = frame_rms.iter().map(|r| !(*r > bound)).collect();
        let kept = keep.iter().filter(|k| **k).count();
        let drop_frames = kept < fitted.len() && kept >= super::MIN_VIEWS;
        // Corners dropped per (frame, image).
        let mut outliers_in = std::collections::HashMap::<(String, String), usize>::new();
        for outlier in &calibration.report.outliers {
            if drop_frames && !keep[outlier.view] {
                continue;
            }
            let (label, view) = &mut fitted[outlier.view];
            let image = view.images.iter_mut().find(|i| i.key == outlier.image);
            if let Some(corner) = image.and_then(|i| i.corners.get_mut(outlier.corner))
                && corner.take().is_some()
            {
                again = true;
                *outliers_in
                    .entry((label.clone(), outlier.image.clone()))
                    .or_insert(0) += 1;
                dropped_corners.push(format!(
                    "frame {label}, camera '{}', corner {}: residual {:.2} px",
                    outlier.camera, outlier.corner, outlier.residual_px
                ));
            }
        }
        if drop_frames {
            let mut next = Vec::new();
            for ((label, view), (keep, rms)) in fitted.into_iter().zip(keep.iter().zip(&frame_rms))
            {
                if *keep {
                    next.push((label, view));
                } else {
                    dropped.push((
                        label,
                        format!(
                            "RMS {rms:.2} px, above {OUTLIER_FACTOR} × the median frame's {median:.3} px"
                        ),
                    ));
                }
            }
            fitted = next;
            again = true;
        }
        // An image whose outliers leave it without a pose of the board (too few corners, or all
        // on one line), or whose corners are mostly outliers (a misread board), is left out whole,
        // and a frame left without images with it.
        for (label, view) in &mut fitted {
            view.images.retain(|image| {
                let kept = image.seen_corners();
                let outliers = outliers_in
                    .get(&(label.clone(), image.key.clone()))
                    .copied()
                    .unwrap_or(0);
                let why = unusable_image(&target, &kept).or_else(|| {
                    (2 * outliers > kept.len() + outliers).then(|| {
                        format!(
                            "{outliers} of its {} corners are outliers",
                            kept.len() + outliers
                        )
                    })
                });
                match why {
                    None => true,
                    Some(why) => {
                        dropped_corners.push(format!(
                            "frame {label}, camera '{}': the whole image left out ({why})",
                            image.key
                        ));
                        false
                    }
                }
            });
        }
        fitted.retain(|(_, view)| !view.images.is_empty());
    }
    if again {
        // From the first fit: its extrinsics are far nearer than the co-observations' start, so
        // the consecutive method (which takes them as given) can run.
        let first = calibration.rig.clone();
        calibration = calibrate_unjudged(
            &first,
            &observations(&fitted),
            &calibration_options,
            progress,
        )?;
    }
    let mut validation = if held_out.is_empty() {
        None
    } else {
        Some(validate(
            &calibration.rig,
            board,
            &observations(&held_out),
            &held_out,
        )?)
    };
    let mut intrinsics = None;
    let refine = match options.refine_intrinsics {
        RefineIntrinsics::Auto => validation.is_some(),
        RefineIntrinsics::Always => true,
        RefineIntrinsics::Never => false,
    };
    if refine && !calibration_options.estimate.intrinsics {
        // The same frames again, the intrinsics estimated too, from the fixed fit's rig.
        // The lenses calibrated in air stay in the fit as a prior with their σ: under water a
        // principal point and a port's tilt move the corners nearly alike, and without the
        // prior the pair drifts together (zoo seeds 62 and 70 on degraded footage: cx and cy 3-5
        // px off where the in-air σ is 0.4 px, the ports' axes 0.3-0.5° off).
        let lens_prior = calibration
            .report
            .sigma_px
            .filter(|_| options.lens_std.len() == names.len())
            .map(|corner_sigma_px| LensPrior {
                means: calibration
                    .rig
                    .cameras()
                    .iter()
                    .map(|c| intrinsic_values(&c.intrinsics))
                    .collect(),
                std: options.lens_std.clone(),
                corner_sigma_px,
            });
        let with_prior = lens_prior.is_some();
        let refined_options = Options {
            estimate: Estimate {
                intrinsics: true,
                ..calibration_options.estimate
            },
            lens_prior,
            ..calibration_options.clone()
        };
        let refined = calibrate_unjudged(
            &calibration.rig,
            &observations(&fitted),
            &refined_options,
            progress,
        );
        let refined = match refined {
            Ok(c) if c.report.fits => Ok(c),
            Ok(c) => Err(format!(
                "its RMS is {:.2} px in the worst camera",
                c.report.worst_inlier_rms_px()
            )),
            Err(e) => Err(e.to_string()),
        };
        let checked = refined.and_then(|c| {
            if held_out.is_empty() {
                return Ok((c, None));
            }
            validate(&c.rig, board, &observations(&held_out), &held_out)
                .map(|v| (c, Some(v)))
                .map_err(|e| format!("its held-out frames do not fit: {e}"))
        });
        let fixed_rms_px = validation.as_ref().map_or(f64::NAN, |v| v.rms_px);
        let refined_rms_px = match &checked {
            Ok((_, Some(v))) => v.rms_px,
            _ => f64::INFINITY,
        };
        let (keep, reason) = match (&checked, options.refine_intrinsics) {
            (Err(why), _) => (
                false,
                format!("kept fixed: the fit with the intrinsics refined failed ({why})"),
            ),
            (Ok(_), RefineIntrinsics::Always) => (
                true,
                format!(
                    "refined (--refine-intrinsics always; held-out RMS {fixed_rms_px:.4} px fixed, {refined_rms_px:.4} px refined)"
                ),
            ),
            (Ok(_), _) => {
                let better = refined_rms_px < (1.0 - REFINE_MARGIN) * fixed_rms_px;
                (
                    better,
                    format!(
                        "held-out RMS {fixed_rms_px:.4} px with the in-air intrinsics fixed, {refined_rms_px:.4} px refined: {}",
                        if better {
                            format!("refined (more than {:.0} % lower)", 100.0 * REFINE_MARGIN)
                        } else {
                            format!(
                                "kept fixed (refinement lowers it by no more than {:.0} %)",
                                100.0 * REFINE_MARGIN
                            )
                        }
                    ),
                )
            }
        };
        let reason = if with_prior {
            format!("{reason}; refined with the in-air lenses as a prior (their σ)")
        } else {
            reason
        };
        intrinsics = Some(IntrinsicsChoice {
            refined: keep,
            fixed_rms_px,
            refined_rms_px,
            reason,
        });
        if keep && let Ok((c, v)) = checked {
            calibration = c;
            validation = v;
        }
    }
    // Lenses held fixed: their in-air uncertainty into the ports' and extrinsics' σ.
    let lenses_fixed =
        !calibration_options.estimate.intrinsics && intrinsics.as_ref().is_none_or(|c| !c.refined);
    if lenses_fixed && options.lens_std.len() == names.len() {
        let (fitted_observations, _) = observations(&fitted).without_unusable_images();
        let seen = fitted_observations.resolve(&calibration.rig)?;
        add_lens_uncertainty(
            &mut calibration.report,
            &calibration.rig,
            &target,
            &seen,
            calibration_options.estimate,
            calibration_options.huber,
            &options.lens_std,
        );
    }
    // The verdict: the fit's residuals against what the held-out frames say.
    let fitted_squares_percent = {
        let seen = observations(&fitted).resolve(&calibration.rig)?;
        let mut errors: Vec<f64> = seen
            .iter()
            .flat_map(|view| square_errors(&calibration.rig, board, view))
            .map(f64::abs)
            .collect();
        median(&mut errors).map(|m| 100.0 * m / board.square)
    };
    let mut verdict = verdict(
        Residuals::of(&calibration.report),
        fitted_squares_percent,
        validation.as_ref(),
        rms_bound,
    );
    loose_ports(
        &mut verdict,
        &calibration.report,
        setup.port == PortKind::Surface,
    );
    let report = &mut calibration.report;
    report.fits = verdict.accepted();
    if !report.fits {
        diagnose_misfit(&start, &observations(&fitted), report, &calibration_options)?;
        report.warnings.push(format!(
            "the calibration is plainly wrong ({}). What the data look like: {}",
            verdict.why.join("; "),
            report.diagnosis.join("; ")
        ));
    }
    Ok(BoardsCalibration {
        calibration,
        start,
        links,
        fitted: fitted.into_iter().map(|(label, _)| label).collect(),
        dropped,
        dropped_corners,
        left_out,
        turned,
        validation,
        intrinsics,
        verdict,
        fitted_squares_percent,
    })
}

/// The RMS reprojection error of every view of `views` (over all its cameras) under
/// `calibration`, without the corners its report names as outliers (one misplaced corner is the
/// corner's fault, not the frame's; the Huber loss has already down-weighted it).
fn frame_rms(calibration: &Calibration, views: &[(String, View)]) -> Vec<f64> {
    let report = &calibration.report;
    views
        .iter()
        .enumerate()
        .map(|(v, (_, view))| {
            let (mut sum, mut count) = (0.0, 0usize);
            for camera in &report.cameras {
                let Some(rms) = camera.rms_px_per_view.get(v).filter(|r| r.is_finite()) else {
                    continue;
                };
                let Some(image) = view.images.iter().find(|i| i.key == camera.name) else {
                    continue;
                };
                let n = image.corners.iter().filter(|c| c.is_some()).count();
                let outliers: Vec<f64> = report
                    .outliers
                    .iter()
                    .filter(|o| o.view == v && o.camera == camera.name)
                    .map(|o| o.residual_px)
                    .collect();
                if n > outliers.len() {
                    let squares =
                        rms * rms * n as f64 - outliers.iter().map(|r| r * r).sum::<f64>();
                    sum += squares.max(0.0);
                    count += n - outliers.len();
                }
            }
            if count > 0 {
                (sum / count as f64).sqrt()
            } else {
                f64::NAN
            }
        })
        .collect()
}

/// The held-out frames through the calibrated rig: their board poses fitted (nothing else moves),
/// the RMS reprojection error, and every pair of neighbouring corners triangulated from all the
/// cameras that saw both, against the square.
pub fn validate(
    rig: &Rig,
    board: &Board,
    observations: &Observations,
    frames: &[(String, View)],
) -> Result<Validation, CalibError> {
    let target = Target::Board(*board);
    let seen = observations.resolve(rig)?;
    // The corners the fit would leave out (far off the board's smooth shape in their image: a
    // misdetection) are left out here too, or one of them decides the held-out RMS.
    let mut notes = Vec::new();
    let screening = super::checks::screen_gross_errors(rig, board, &seen, &mut notes);
    let clean = screening.without_suspects(&seen).unwrap_or(seen);
    // Each frame's board pose alone (the pinhole pose of its corners' directions in the water,
    // else of the pixels', then fitted through the rig); a frame whose corners do not all
    // project from either start is left out, not an infinite RMS.
    let (mut squares, mut corners, mut views_left_out) = (0.0, 0usize, 0usize);
    let mut used = Vec::new();
    for view in &clean {
        let one = std::slice::from_ref(view);
        let pose_only = Bundle::new(rig, &target, one, Estimate::NOTHING, None);
        let start = [poses::water_poses, poses::initial_poses]
            .iter()
            .filter_map(|poses| poses(rig, &target, one).ok())
            .map(|poses| State::of(rig, poses))
            .find(|start| pose_only.cost(start).is_some_and(f64::is_finite));
        let Some(start) = start else {
            views_left_out += 1;
            continue;
        };
        let fitted = fit_briefly(&pose_only, start, 50);
        match pose_only.cost(&fitted) {
            Some(cost) if cost.is_finite() => {
                squares += 2.0 * cost;
                corners += pose_only.residuals();
                used.push(view.clone());
            }
            _ => views_left_out += 1,
        }
    }
    let rms_px = if corners > 0 {
        (squares / corners as f64).sqrt()
    } else {
        f64::INFINITY
    };
    let errors: Vec<f64> = used
        .iter()
        .flat_map(|view| square_errors(rig, board, view))
        .collect();
    let mut absolute: Vec<f64> = errors.iter().map(|e| e.abs()).collect();
    let median = median(&mut absolute).unwrap_or(f64::NAN);
    let rms_error = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len().max(1) as f64).sqrt();
    Ok(Validation {
        frames: frames.iter().map(|(label, _)| label.clone()).collect(),
        rms_px,
        distances: errors.len(),
        median_error_m: median,
        median_error_percent: 100.0 * median / board.square,
        rms_error_m: rms_error,
        views_left_out,
        corners_left_out: screening.suspects.len(),
    })
}

/// Every pair of neighbouring corners of `view` that two or more cameras saw, triangulated
/// through `rig` ([`triangulate_view`]): their distance minus the board's square, metres.
pub fn square_errors(rig: &Rig, board: &Board, view: &SeenView) -> Vec<f64> {
    let points = triangulate_view(rig, board, view);
    let mut errors = Vec::new();
    for (i, p) in points.iter().enumerate() {
        let Some(p) = p else { continue };
        let (r, c) = board.grid_position(i);
        let right = (c + 1 < board.cols).then(|| i + 1);
        let below = (r + 1 < board.rows).then(|| i + board.cols);
        for j in [right, below].into_iter().flatten() {
            if let Some(q) = points[j] {
                errors.push((p - q).norm() - board.square);
            }
        }
    }
    errors
}

/// The median of `values` (sorted in place), `None` when empty.
fn median(values: &mut [f64]) -> Option<f64> {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied()
}

/// Each corner of `view` seen by two or more cameras, triangulated as the point nearest all their
/// water rays (least squares); `None` for the others.
pub fn triangulate_view(rig: &Rig, board: &Board, view: &SeenView) -> Vec<Option<Point3<f64>>> {
    let cameras: Vec<_> = view
        .cameras
        .iter()
        .map(|(k, _)| rig.refractive_camera(*k))
        .collect();
    let mut normal = vec![Matrix3::zeros(); board.corners()];
    let mut right = vec![Vector3::zeros(); board.corners()];
    let mut rays = vec![0usize; board.corners()];
    for (camera, (_, corners)) in cameras.iter().zip(&view.cameras) {
        for (i, pixel) in corners {
            let Ok(ray) = camera.backproject(pixel) else {
                continue;
            };
            let d = ray.dir.into_inner();
            let m = Matrix3::identity() - d * d.transpose();
            normal[*i] += m;
            right[*i] += m * ray.origin.coords;
            rays[*i] += 1;
        }
    }
    (0..board.corners())
        .map(|i| {
            (rays[i] >= 2)
                .then(|| {
                    normal[i]
                        .try_inverse()
                        .map(|inv| Point3::from(inv * right[i]))
                })
                .flatten()
        })
        .collect()
}
