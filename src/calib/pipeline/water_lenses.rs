//! Lenses from the underwater frames alone: `calibrate --images` without `air/` and without
//! `--rig`, for footage where no in-air views exist.
//!
//! 1. **Each camera's start lens** from its own views of the board under water: a pinhole with
//!    k1, k2 fitted as if there were no port ([`calibrate_intrinsics`]). Near the axis the water
//!    magnifies by n_water / n_air (a ray at angle θ in water leaves the port at n·θ), so that fit's
//!    focal length divided by the ratio starts the lens's; its principal point starts the lens's;
//!    its k1, k2 (mostly the refraction's pincushion) are dropped. Views that do not determine
//!    a focal length fail here, named by camera: boards that all face the camera (within
//!    [`MIN_START_TILT_DEG`]), or a focal length σ above [`MAX_START_FOCAL_STD`].
//! 2. **The one calibration** of [`calibrate_from_boards`] with every lens estimated together
//!    with the ports, the extrinsics and the board poses (fx, fy, cx, cy and the lens terms of the
//!    candidate), once per candidate of [`TERM_CANDIDATES`]; the richest whose held-out frames'
//!    RMS is within [`TERM_MARGIN`] of the lowest is kept (without held-out frames, k1 alone):
//!    [`choose_terms`] says why the richest.
//! 3. **Determined?** A lens whose focal length σ exceeds [`MAX_FOCAL_STD`] of it, or whose
//!    principal point σ exceeds [`MAX_PRINCIPAL_STD`] of the image width, is refused by name:
//!    the views do not pin it (too few tilts of the board, too narrow a range of distances).

use super::boards::{
    BoardsCalibration, BoardsOptions, RefineIntrinsics, RigSetup, WaterFrame, calibrate_from_boards,
};
use super::intrinsics::{AirView, IntrinsicsOptions, LensTerms, ModelChoice, calibrate_intrinsics};
use super::{Progress, bundle::Estimate};
use crate::base::Board;
use crate::calib::error::CalibError;
use crate::model::PinholeCamera;

/// The lens terms compared, simplest first: none, k1, k1 and k2, k1 k2 p1 p2. A lens's small
/// decentring (p1, p2 ~ 4e-4) moves corners by half a pixel at the image's edge; left out, the
/// principal point takes it up (1 px in a rendered pair) and the extrinsics with it (0.09°).
pub const TERM_CANDIDATES: [LensTerms; 4] = [
    LensTerms::NONE,
    LensTerms {
        free: [true, false, false, false, false],
    },
    LensTerms {
        free: [true, true, false, false, false],
    },
    LensTerms::K1_K2_TANGENTIAL,
];

/// How far (relative) above the lowest held-out RMS a candidate may be and still be kept (0.02: 2 %).
pub const TERM_MARGIN: f64 = 0.02;

/// Views whose boards all stay within this tilt (degrees) from facing the camera do not start a
/// lens: a fit to fronto-parallel boards through a port tilted 8° finds them 4° tilted and a
/// focal length 16 % off.
pub const MIN_START_TILT_DEG: f64 = 10.0;

/// Largest σ of a start's focal length, as a share of it (the start fit has no port, so looser
/// than [`MAX_FOCAL_STD`]): above it the views are named as not determining the lens.
pub const MAX_START_FOCAL_STD: f64 = 0.05;

/// Largest σ of a focal length, as a share of it, for a lens to count as determined.
pub const MAX_FOCAL_STD: f64 = 0.01;

/// Largest σ of a principal point coordinate, as a share of the image width.
pub const MAX_PRINCIPAL_STD: f64 = 0.01;

/// The start value of a lens term the fit estimates (the bundle estimates the terms that are not
/// exactly 0 in its start camera).
const TERM_START: f64 = 1e-9;

/// One candidate's outcome.
#[derive(Debug, Clone, PartialEq)]
pub struct TermTrial {
    /// The lens terms estimated.
    pub terms: LensTerms,
    /// The held-out frames' RMS, pixels (NaN without held-out frames; +∞ where the fit failed).
    pub held_out_rms_px: f64,
    /// Why it failed, where it did.
    pub failed: Option<String>,
}

/// What [`calibrate_lenses_under_water`] found.
#[derive(Debug, Clone)]
pub struct WaterLenses {
    /// The calibration kept.
    pub calibration: BoardsCalibration,
    /// Each camera's start lens (from its underwater views, the magnification divided out).
    pub starts: Vec<PinholeCamera>,
    /// Every candidate tried, in order.
    pub trials: Vec<TermTrial>,
    /// The terms kept.
    pub terms: LensTerms,
    /// Why, in words.
    pub reason: String,
}

/// Camera `k`'s start lens (named `name`, `width` × `height` pixels) from its views of `board` in
/// `frames`: see the [module](self) documentation, step 1.
pub fn water_lens_start(
    name: &str,
    size: (u32, u32),
    board: &Board,
    frames: &[WaterFrame],
    k: usize,
    index_air: f64,
    index_water: f64,
) -> Result<PinholeCamera, CalibError> {
    let views: Vec<AirView> = frames
        .iter()
        .filter(|f| f.corners.get(k).is_some_and(|c| !c.is_empty()))
        .map(|f| AirView {
            label: f.label.clone(),
            corners: f.corners[k].clone(),
        })
        .collect();
    let options = IntrinsicsOptions {
        model: ModelChoice::Fixed(TERM_CANDIDATES[2]),
        ..IntrinsicsOptions::default()
    };
    let fit = calibrate_intrinsics(name, size.0, size.1, board, &views, &options).map_err(|e| {
        CalibError::NotDetermined(format!(
            "camera '{name}': no start for its lens from its {} underwater views of the board ({e}); without in-air views (air/{name}/) or a rig file (--rig), the board must be filmed under water tilted by 20–40° in several directions",
            views.len()
        ))
    })?;
    // A focal length needs boards seen at a slant (Zhang's condition): boards that face the
    // camera in every view leave it free along a valley, and the fit's end is arbitrary.
    let largest_tilt = fit
        .cam_from_board
        .iter()
        .flatten()
        .map(|pose| {
            (pose.rotation * nalgebra::Vector3::z())
                .z
                .abs()
                .min(1.0)
                .acos()
                .to_degrees()
        })
        .fold(0.0, f64::max);
    // The σ of the views' geometry (OpenCV's formula), not the one raised by how the views
    // scatter: this pinhole fit of refracted corners misfits by design, and its scatter says so,
    // not whether slanted boards pin a focal length (zoo seed 6's cam1, boards tilted up to
    // 53°, was refused at 1550 ± 111 px with the raised σ).
    let focal_std =
        fit.std_classical[0].max(fit.std_classical[1]) / fit.camera.fx.min(fit.camera.fy);
    if largest_tilt < MIN_START_TILT_DEG || !(focal_std <= MAX_START_FOCAL_STD) {
        return Err(CalibError::NotDetermined(format!(
            "camera '{name}': its {} underwater views of the board do not determine its lens (the board is tilted by at most {largest_tilt:.1}° from facing the camera; the focal length comes out {:.0} ± {:.0} px); without in-air views (air/{name}/) or a rig file (--rig), the board must be filmed under water tilted by 20–40° in several directions",
            views.len(),
            fit.camera.fx,
            fit.std_classical[0]
        )));
    }
    let ratio = index_water / index_air;
    let c = fit.camera;
    PinholeCamera::new(
        name,
        size.0,
        size.1,
        c.fx / ratio,
        c.fy / ratio,
        c.cx,
        c.cy,
        [0.0; 5],
    )
    .map_err(|e| CalibError::Options(e.to_string()))
}

/// Calibrates the rig of `setup` (its cameras' lenses the starts of [`water_lens_start`]) with
/// every lens estimated: see the [module](self) documentation, steps 2 and 3. `options` as for
/// [`calibrate_from_boards`] (its intrinsics refinement is this function's).
pub fn calibrate_lenses_under_water(
    names: &[String],
    setup: &RigSetup,
    board: &Board,
    frames: &[WaterFrame],
    options: &BoardsOptions,
    progress: &mut dyn FnMut(&Progress),
) -> Result<WaterLenses, CalibError> {
    let mut options = options.clone();
    options.refine_intrinsics = RefineIntrinsics::Never;
    options.calibration.estimate = Estimate {
        intrinsics: true,
        ..options.calibration.estimate
    };
    let mut trials = Vec::new();
    // Every candidate's calibration (None where it failed or was refused), in TERM_CANDIDATES order.
    let mut results: Vec<Option<BoardsCalibration>> = Vec::new();
    let mut last_error = None;
    for terms in TERM_CANDIDATES {
        let mut candidate = setup.clone();
        for camera in &mut candidate.cameras {
            for (d, free) in camera.distortion.iter_mut().zip(terms.free) {
                *d = if free { TERM_START } else { 0.0 };
            }
        }
        let result = calibrate_from_boards(names, &candidate, board, frames, &options, progress);
        let (held_out_rms_px, failed) = match &result {
            Ok(c) if c.verdict.accepted() => {
                (c.validation.as_ref().map_or(f64::NAN, |v| v.rms_px), None)
            }
            Ok(c) => (f64::INFINITY, Some(c.verdict.why.join("; "))),
            Err(e) => (f64::INFINITY, Some(e.to_string())),
        };
        trials.push(TermTrial {
            terms,
            held_out_rms_px,
            failed,
        });
        match result {
            Ok(c) => results.push(Some(c)),
            Err(e) => {
                last_error = Some(e);
                results.push(None);
            }
        }
    }
    // Without an accepted candidate, the first that ran is kept: its report says why it is poor.
    let chosen = choose_terms(&trials).or_else(|| results.iter().position(Option::is_some));
    let Some((terms, calibration)) =
        chosen.and_then(|i| Some((TERM_CANDIDATES[i], results.swap_remove(i)?)))
    else {
        return Err(
            last_error.unwrap_or_else(|| CalibError::Options("no lens candidate was tried".into()))
        );
    };
    let reason = format!(
        "lens terms {} chosen by the held-out frames' RMS ({}; the richest set within {:.0} % of the lowest is kept)",
        terms.describe(),
        trials
            .iter()
            .map(|t| format!(
                "{}: {}",
                t.terms.describe(),
                match &t.failed {
                    Some(why) => format!("failed ({why})"),
                    None if t.held_out_rms_px.is_nan() => "no frames held out".into(),
                    None => format!("{:.4} px", t.held_out_rms_px),
                }
            ))
            .collect::<Vec<_>>()
            .join(", "),
        100.0 * TERM_MARGIN
    );
    if calibration.verdict.accepted() {
        undetermined_lenses(&calibration)?;
    }
    Ok(WaterLenses {
        calibration,
        starts: setup.cameras.clone(),
        trials,
        terms,
        reason,
    })
}

/// The candidate of `trials` (in [`TERM_CANDIDATES`] order) to keep: among the accepted ones,
/// the richest whose held-out RMS is within [`TERM_MARGIN`] of the lowest; without held-out
/// frames, k1 alone where it was accepted. `None` when none was accepted.
///
/// Richest, not simplest: a term the fit leaves out is not harmless where the frames barely see
/// it. A lens's decentring (p1, p2 ~ 3e-4) left out is taken up by the principal point and the
/// port's tilt, which then come out many σ off while the held-out RMS hardly moves (zoo seed 5,
/// two housings with the board 1.5–3 m away: 0.4 % lower RMS with p1, p2, but without them cx
/// 1.3 px and the axes 0.07° off, 8σ); with them, the ambiguity is in the σ. A richer set that
/// over-fits shows as a higher held-out RMS and is not kept.
fn choose_terms(trials: &[TermTrial]) -> Option<usize> {
    let accepted = |t: &TermTrial| t.failed.is_none();
    let lowest = trials
        .iter()
        .filter(|t| accepted(t))
        .map(|t| t.held_out_rms_px)
        .filter(|r| r.is_finite())
        .fold(f64::INFINITY, f64::min);
    if !lowest.is_finite() {
        // No held-out frames: k1, the term every lens under water needs, else the first accepted.
        return trials
            .iter()
            .position(|t| accepted(t) && t.terms == TERM_CANDIDATES[1])
            .or_else(|| trials.iter().position(accepted));
    }
    trials
        .iter()
        .rposition(|t| accepted(t) && t.held_out_rms_px <= (1.0 + TERM_MARGIN) * lowest)
}

/// An error naming every lens of `calibration` whose focal length or principal point the frames
/// do not pin ([`MAX_FOCAL_STD`], [`MAX_PRINCIPAL_STD`]).
fn undetermined_lenses(calibration: &BoardsCalibration) -> Result<(), CalibError> {
    let mut weak = Vec::new();
    for (camera, report) in calibration
        .calibration
        .rig
        .cameras()
        .iter()
        .zip(&calibration.calibration.report.cameras)
    {
        let lens = &camera.intrinsics;
        let Some(std) = report.intrinsics_std else {
            continue;
        };
        let std = |j: usize| std[j].unwrap_or(f64::INFINITY);
        let focal = std(0).max(std(1)) / lens.fx.min(lens.fy);
        let principal = std(2).max(std(3)) / lens.width as f64;
        if !(focal <= MAX_FOCAL_STD) || !(principal <= MAX_PRINCIPAL_STD) {
            weak.push(format!(
                "camera '{}': fx {:.1} ± {:.1} px, cx {:.1} ± {:.1} px, cy {:.1} ± {:.1} px",
                camera.name,
                lens.fx,
                std(0),
                lens.cx,
                std(2),
                lens.cy,
                std(3)
            ));
        }
    }
    if weak.is_empty() {
        Ok(())
    } else {
        Err(CalibError::NotDetermined(format!(
            "the underwater frames do not determine the lens of {} (a focal length needs σ below {:.0} % of it, a principal point below {:.0} % of the width): film the board tilted by 20–40° in several directions and over a range of distances, give the in-air views (air/<camera>/), or give the lenses (--rig)",
            weak.join("; "),
            100.0 * MAX_FOCAL_STD,
            100.0 * MAX_PRINCIPAL_STD
        )))
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Isometry3, Point2, Translation3, UnitQuaternion, Vector3};

    use super::*;
    use crate::base::Rng;

    /// Frames of the example rig's left camera (through its tilted port, glass and water) seeing
    /// a 9 × 6 board at `poses` (camera frame), corners with 0.1 px of noise.
    fn frames(poses: &[Isometry3<f64>]) -> (Vec<WaterFrame>, crate::model::Rig, Board) {
        let rig = crate::io::read_rig(std::path::Path::new("data/example_rig.json")).unwrap();
        let camera = rig.refractive_camera(0);
        let board = Board {
            rows: 6,
            cols: 9,
            square: 0.04,
        };
        let mut rng = Rng::new(5);
        let frames = poses
            .iter()
            .enumerate()
            .map(|(v, pose)| {
                let corners: Vec<(usize, Point2<f64>)> = (0..board.corners())
                    .filter_map(|i| {
                        let pixel = camera.project(&(pose * board.point_in_board(i))).ok()?;
                        Some((
                            i,
                            pixel + 0.1 * nalgebra::Vector2::new(rng.normal(), rng.normal()),
                        ))
                    })
                    .collect();
                WaterFrame {
                    label: format!("view {v}"),
                    corners: vec![corners, Vec::new()],
                }
            })
            .collect();
        (frames, rig, board)
    }

    /// The board's centre at `(x, y, z)` in the camera, turned by `about_x` and `about_y` (°).
    fn pose(x: f64, y: f64, z: f64, about_x: f64, about_y: f64) -> Isometry3<f64> {
        let rotation = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), about_x.to_radians())
            * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), about_y.to_radians());
        let centre = Vector3::new(0.16, 0.1, 0.0);
        Isometry3::from_parts(
            Translation3::from(Vector3::new(x, y, z) - rotation * centre),
            rotation,
        )
    }

    /// Issue 45: boards that only ever face the camera do not determine a focal length (Zhang's
    /// degenerate case: every view's homography is a scaled similarity); the start is refused
    /// naming the camera and what to film. The same number of views tilted 20–35° in several
    /// directions starts the lens within 3 % of the truth (the water's magnification divided
    /// out; the port's refraction is not modelled in the start, so not closer).
    #[test]
    fn fronto_parallel_boards_are_refused_and_tilted_ones_start_the_lens() {
        let facing: Vec<Isometry3<f64>> = (0..10)
            .map(|v| {
                let t = f64::from(v);
                pose(
                    0.08 * (t * 1.3).sin(),
                    0.06 * (t * 0.7).cos(),
                    0.6 + 0.05 * t,
                    0.0,
                    0.0,
                )
            })
            .collect();
        let (frames_facing, rig, board) = frames(&facing);
        let size = (
            rig.cameras()[0].intrinsics.width,
            rig.cameras()[0].intrinsics.height,
        );
        let port = rig.port_in_master(0);
        let n = (port.index_air(), port.index_water());
        let refused =
            water_lens_start("left", size, &board, &frames_facing, 0, n.0, n.1).unwrap_err();
        let message = refused.to_string();
        assert!(
            matches!(refused, CalibError::NotDetermined(_)),
            "{refused:?}"
        );
        assert!(
            message.contains("camera 'left'") && message.contains("tilted"),
            "{message}"
        );

        let tilted: Vec<Isometry3<f64>> = (0..10)
            .map(|v| {
                let t = f64::from(v);
                let angle = 20.0 + 15.0 * (t * 0.9).sin().abs();
                let (about_x, about_y) = match v % 4 {
                    0 => (angle, 0.0),
                    1 => (-angle, 0.0),
                    2 => (0.0, angle),
                    _ => (0.0, -angle),
                };
                pose(
                    0.06 * (t * 1.3).sin(),
                    0.05 * (t * 0.7).cos(),
                    0.6 + 0.05 * t,
                    about_x,
                    about_y,
                )
            })
            .collect();
        let (frames_tilted, _, _) = frames(&tilted);
        let start = water_lens_start("left", size, &board, &frames_tilted, 0, n.0, n.1).unwrap();
        let truth = &rig.cameras()[0].intrinsics;
        let off = (start.fx / truth.fx - 1.0).abs();
        assert!(off < 0.03, "fx {} against {}: {off}", start.fx, truth.fx);
    }

    /// The richest accepted candidate within the margin of the lowest held-out RMS: zoo seed 5's
    /// figures (p1, p2 bring 0.4 %, and are kept), a richer set that over-fits, a richer set
    /// that failed, and no held-out frames.
    #[test]
    fn the_richest_set_within_the_margin_is_kept() {
        let trials = |rms: [f64; 4], failed: [bool; 4]| -> Vec<TermTrial> {
            TERM_CANDIDATES
                .iter()
                .zip(rms.iter().zip(failed))
                .map(|(&terms, (&rms, failed))| TermTrial {
                    terms,
                    held_out_rms_px: if failed { f64::INFINITY } else { rms },
                    failed: failed.then(|| "refused".to_string()),
                })
                .collect()
        };
        let ok = [false; 4];
        assert_eq!(
            choose_terms(&trials([0.1493, 0.0654, 0.0229, 0.0228], ok)),
            Some(3)
        );
        // Within 2 % of the lowest, the richer set: p1, p2 costing 1 % more are kept.
        assert_eq!(
            choose_terms(&trials([0.1493, 0.0654, 0.0229, 0.0231], ok)),
            Some(3)
        );
        // Over-fitting: the richest is 10 % above the lowest.
        assert_eq!(
            choose_terms(&trials([0.1493, 0.0654, 0.0229, 0.0252], ok)),
            Some(2)
        );
        assert_eq!(
            choose_terms(&trials(
                [0.1493, 0.0654, 0.0229, 0.0],
                [false, false, false, true]
            )),
            Some(2)
        );
        assert_eq!(
            choose_terms(&trials([0.2, 0.1, 0.0, 0.0], [false, false, true, true])),
            Some(1)
        );
        assert_eq!(choose_terms(&trials([f64::NAN; 4], ok)), Some(1));
        assert_eq!(
            choose_terms(&trials([f64::NAN; 4], [false, true, true, true])),
            Some(0)
        );
        assert_eq!(choose_terms(&trials([0.0; 4], [true; 4])), None);
    }
}
