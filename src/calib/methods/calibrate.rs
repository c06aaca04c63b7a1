//! The public entries of calibration, each with the diagnosis of a misfit that names the usual
//! input mistake ([`misfit`]): [`calibrate`], a stereo rig by the thesis' methods
//! ([`thesis`]: consecutive, simultaneous, auto), and [`calibrate_rig`], any rig
//! ([`rig_calibrate`](super::rig_calibrate)).

pub use super::thesis::{
    Calibration, CalibrationOptions, CalibrationProgress, CalibrationReport, DEFAULT_MAX_RMS_PX,
    FEW_VIEWS, MIN_VIEWS, Method, NOISE_FACTOR, NOISE_MARGIN_PX, Outlier, Stage, WEAK_AIR_STD_M,
    WEAK_TILT_STD_DEG,
};
use std::time::Instant;

use super::misfit::{self, explain_misfit};
use super::rig_calibrate::{RigCalibration, RigCalibrationOptions, calibrate_views};
use super::thesis;
use crate::calib::backends::CostBackend;
use crate::calib::error::CalibError;
use crate::calib::problem::rig_observations::RigObservations;
use crate::model::Rig;

/// Calibrates the axis and air layer of `backend.data()` (whose rig's interface is the start
/// guess). `warnings` (from validating the observations) are carried into the report.
///
/// Before any fit: views that repeat another are an error ([`CalibError::RepeatedView`]), so
/// are fewer than [`MIN_VIEWS`] distinct board poses ([`CalibError::TooFewPoses`]); views whose
/// images look swapped or whose corner order looks reversed are warned about
/// ([`diagnose::pairing_findings`](super::diagnose::pairing_findings)); corners off the board's
/// shape in their image by far more than the noise ([`screen`](crate::calib::problem::screen))
/// are left out of the estimate, whatever the method. Every method reports the corner images
/// whose residuals under the result are far above the rest. When no axis explains the data the
/// error says what the data look like ([`diagnose::explain`](super::diagnose::explain)); so does
/// [`CalibrationReport::diagnosis`] when the RMS of the result is far above the noise or above
/// [`CalibrationOptions::max_rms_px`], and it names the usual input mistake the misfit looks
/// like ([`misfit::explain_stereo_misfit`]).
pub fn calibrate(
    backend: &dyn CostBackend,
    options: &CalibrationOptions,
    warnings: Vec<String>,
) -> Result<Calibration, CalibError> {
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
    thesis::run(
        backend,
        options,
        warnings,
        progress,
        &misfit::explain_stereo_misfit,
    )
}

/// Calibrates `rig` (its ports and extrinsics the start, the rest known) from `observations`.
/// When the result does not fit, the report's diagnosis says which common input mistake the data
/// look like ([`explain_misfit`]).
pub fn calibrate_rig(
    rig: &Rig,
    observations: &RigObservations,
    options: &RigCalibrationOptions,
) -> Result<RigCalibration, CalibError> {
    let started = Instant::now();
    let views = observations.resolve(rig)?;
    let target = &observations.target;
    let mut calibration = calibrate_views(rig, target, &views, options)?;
    let report = &mut calibration.report;
    let worst = report.worst_rms_px();
    let noise_bound = report
        .corner_noise_px
        .map(|s| NOISE_FACTOR * s + NOISE_MARGIN_PX);
    if !report.fits || noise_bound.is_some_and(|b| worst > b) {
        report.diagnosis = explain_misfit(rig, target, &views, options);
        if let (true, Some(s)) = (report.fits, report.corner_noise_px) {
            report.warnings.push(format!(
                "the reprojection RMS ({worst:.2} px in the worst camera) is far above the corner noise seen in the images (σ ≈ {s:.3} px): the model does not explain the data. What the data look like: {}",
                report.diagnosis.join("; ")
            ));
        }
    }
    report.seconds = started.elapsed().as_secs_f64();
    Ok(calibration)
}
