//! What a calibration that does not fit looks like: each common mistake in the inputs is undone
//! in turn, the rig calibrated again, and a mistake whose undoing brings the reprojection RMS far
//! down is named.
//!
//! The mistakes are the ones new users make (each gave 2–21 px RMS in a test made as one would):
//! a wrong square size or a target in other units, corners detected in half-resolution (or
//! double-resolution) images, corners that were undistorted before they were given (so that the
//! calibration undistorts them twice), a baseline written in millimetres, and in-air extrinsics
//! off by as much as an in-air stereo calibration leaves them (fixed by estimating them). Each hypothesis
//! calibrates from scratch the same way, and so does the data as given, so the RMS values
//! compared are alike.

use nalgebra::{Point2, Point3, Vector2};

use rayon::prelude::*;

use super::bundle::Estimate;
use super::{Options, calibrate_views};
use crate::base::Board;
use crate::calib::problem::observations::SeenView;
use crate::calib::problem::target::Target;
use crate::model::Rig;

/// A hypothesis counts when undoing it brings the RMS below this share of the RMS as given.
const EXPLAINS: f64 = 0.3;
/// Most iterations of each hypothesis' maximum-likelihood refinement.
const FIT_ITERATIONS: usize = 60;

/// One common mistake: what it changes in the inputs to undo it, and how the finding reads.
enum Undo {
    /// Target points multiplied by the factor.
    ScaleTarget(f64),
    /// Every observed pixel multiplied by the factor.
    ScalePixels(f64),
    /// Observed pixels read as undistorted pixels and distorted again.
    Redistort,
    /// Every camera's translation from the master multiplied by the factor.
    ScaleBaseline(f64),
    /// The extrinsics estimated with the port (an in-air calibration's error in R, t).
    EstimateExtrinsics,
}

/// The hypotheses tried, in the order findings are listed.
const HYPOTHESES: [(Undo, &str); 10] = [
    (
        Undo::ScaleTarget(0.1),
        "the target's size is ten times too large (a square in millimetres read as centimetres?)",
    ),
    (
        Undo::ScaleTarget(10.0),
        "the target's size is ten times too small",
    ),
    (
        Undo::ScaleTarget(0.5),
        "the square size is twice the true one",
    ),
    (
        Undo::ScaleTarget(2.0),
        "the square size is half the true one",
    ),
    (
        Undo::ScaleTarget(0.001),
        "the target is in millimetres, not metres",
    ),
    (
        Undo::ScalePixels(2.0),
        "the corners are in half-resolution pixels (detected in images downscaled by 2?): give them at the rig's resolution",
    ),
    (
        Undo::ScalePixels(0.5),
        "the corners are at twice the rig's resolution: give them at the resolution the intrinsics were calibrated at",
    ),
    (
        Undo::Redistort,
        "the corners look undistorted already (and so were undistorted twice): give raw, distorted pixels",
    ),
    (
        Undo::ScaleBaseline(0.001),
        "the rig's baseline looks like millimetres: extrinsic translations are metres (`flatport rig from-opencv --unit mm` converts)",
    ),
    (
        Undo::EstimateExtrinsics,
        "the in-air extrinsics look off (an in-air stereo calibration's error in R and T is enough): estimate them with the port, adding `extrinsics` to --estimate",
    ),
];

/// Findings on what the misfit of `rig` (ports and extrinsics: the start) to `views` of `target`
/// looks like: `Ok` with one line per mistake whose undoing explains it (the calibration then
/// fits within the options' RMS bound, far below the RMS as given), the best first, or `Err` with
/// one line saying that none does and what to check. Each hypothesis is a whole calibration (`calibrate_views` with
/// `options`, from `rig`'s start), since a start fitted to the wrong data can be far from where
/// the right data lead; the hypotheses run in parallel.
pub fn explain_misfit(
    rig: &Rig,
    target: &Target,
    views: &[SeenView],
    options: &Options,
) -> Result<Vec<String>, String> {
    let options = Options {
        max_iterations: options.max_iterations.min(FIT_ITERATIONS),
        ..options.clone()
    };
    let refit = |rig: &Rig, target: &Target, views: &[SeenView]| {
        rms_after_calibration(rig, target, views, &options)
    };
    let Some(now) = refit(rig, target, views) else {
        return Err(
            "no calibration of the data as given finishes (are the corners in target order?)"
                .into(),
        );
    };
    let has_distortion = rig.cameras().iter().any(|c| c.intrinsics.has_distortion());
    let undone: Vec<Option<f64>> = HYPOTHESES
        .par_iter()
        .map(|(undo, _)| match undo {
            Undo::ScaleTarget(s) => refit(rig, &scaled_target(target, *s), views),
            Undo::ScalePixels(s) => refit(
                rig,
                target,
                &map_pixels(views, |_, p| Point2::from(p.coords * *s)),
            ),
            Undo::Redistort if has_distortion => {
                let redistorted = map_pixels(views, |k, p| {
                    let intrinsics = &rig.cameras()[k].intrinsics;
                    let normalised = Vector2::new(
                        (p.x - intrinsics.cx) / intrinsics.fx,
                        (p.y - intrinsics.cy) / intrinsics.fy,
                    );
                    intrinsics.img_from_normalized(&normalised)
                });
                refit(rig, target, &redistorted)
            }
            Undo::ScaleBaseline(s) if rig.cameras().len() >= 2 => {
                scaled_baseline(rig, *s).and_then(|moved| refit(&moved, target, views))
            }
            Undo::EstimateExtrinsics
                if rig.cameras().len() >= 2 && !options.estimate.extrinsics =>
            {
                let freed = Options {
                    estimate: Estimate {
                        extrinsics: true,
                        ..options.estimate
                    },
                    ..options.clone()
                };
                rms_after_calibration(rig, target, views, &freed)
            }
            Undo::Redistort | Undo::ScaleBaseline(_) | Undo::EstimateExtrinsics => None,
        })
        .collect();
    // A mistake explains the misfit when its undoing fits (within the accepted RMS) and far
    // better than the data as given; the best explanation first.
    let mut explained: Vec<(f64, &str)> = HYPOTHESES
        .iter()
        .zip(undone)
        .filter_map(|((_, what), r)| Some((r?, *what)))
        .filter(|(r, _)| *r < EXPLAINS * now && *r <= options.rms_bound())
        .collect();
    explained.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Estimating the extrinsics undoes every mistake in them (a baseline in millimetres too, now
    // that the housings' extrinsics are linked again through their ports): where a specific
    // mistake explains the misfit, it is the finding, not the general remedy.
    let general = HYPOTHESES
        .iter()
        .find(|(undo, _)| matches!(undo, Undo::EstimateExtrinsics))
        .map(|(_, what)| *what);
    if explained.iter().any(|(_, what)| Some(*what) != general) {
        explained.retain(|(_, what)| Some(*what) != general);
    }
    if explained.is_empty() {
        return Err(format!(
            "the RMS of {now:.2} px is not explained by a scaled target, half- or double-resolution pixels, corners undistorted twice, a baseline in millimetres or in-air extrinsics off; check that the corners are raw (distorted) pixels in target order in every camera, and the rig's intrinsics and extrinsics"
        ));
    }
    Ok(explained
        .into_iter()
        .map(|(r, what)| {
            format!("{what} (with that fixed, the RMS falls from {now:.2} px to {r:.2} px)")
        })
        .collect())
}

/// Whether a finding of [`explain_misfit`] names a mistake of scale (the target's size, or the
/// baseline's unit), which a triangulated board of the wrong scale shows too.
pub fn is_about_scale(finding: &str) -> bool {
    HYPOTHESES.iter().any(|(undo, what)| {
        matches!(undo, Undo::ScaleTarget(_) | Undo::ScaleBaseline(_)) && finding.starts_with(what)
    })
}

/// The RMS reprojection error of a whole calibration of `views` from `rig`'s start; `None` when
/// it fails or leaves no finite cost.
fn rms_after_calibration(
    rig: &Rig,
    target: &Target,
    views: &[SeenView],
    options: &Options,
) -> Option<f64> {
    calibrate_views(rig, target, views, options, Vec::new(), &mut |_| {})
        .ok()
        .map(|c| c.report.rms_px)
        .filter(|r| r.is_finite())
}

/// The views with every observed pixel of camera k mapped by `f(k, pixel)`.
fn map_pixels(views: &[SeenView], f: impl Fn(usize, &Point2<f64>) -> Point2<f64>) -> Vec<SeenView> {
    views
        .iter()
        .map(|view| SeenView {
            cameras: view
                .cameras
                .iter()
                .map(|(k, corners)| (*k, corners.iter().map(|(i, p)| (*i, f(*k, p))).collect()))
                .collect(),
            keys: view.keys.clone(),
        })
        .collect()
}

/// The rig with every camera's translation from the master scaled; `None` when that leaves a
/// camera outside the air.
fn scaled_baseline(rig: &Rig, scale: f64) -> Option<Rig> {
    let mut moved = rig.clone();
    for k in 1..rig.cameras().len() {
        let mut pose = rig.cameras()[k].cam_from_master;
        pose.translation.vector *= scale;
        moved = moved.with_extrinsics(k, pose).ok()?;
    }
    Some(moved)
}

fn scaled_target(target: &Target, scale: f64) -> Target {
    match target {
        Target::Board(board) => Target::Board(Board {
            square: board.square * scale,
            ..*board
        }),
        Target::Points(points) => Target::Points(
            points
                .iter()
                .map(|p| Point3::from(p.coords * scale))
                .collect(),
        ),
    }
}
