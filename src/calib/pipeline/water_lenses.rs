//! Lenses from the underwater frames alone: `calibrate --images` without `air/` and without
//! `--rig`, for footage where no in-air views exist.
//!
//! 1. **Each camera's start lens** from its own views of the board under water: a pinhole with
//!    k1, k2 fitted as if there were no port ([`calibrate_intrinsics`]). Near the axis the water
//!    magnifies by n_water / n_air (a ray at angle θ in water leaves the port at n·θ), so that fit's
//!    focal length divided by the ratio starts the lens's; its principal point starts the lens's;
//!    its k1, k2 (mostly the refraction's pincushion) are dropped. Views that do not determine
//!    a focal length (fronto-parallel boards only) fail here, named by camera.
//! 2. **The one calibration** of [`calibrate_from_boards`] with every lens estimated together
//!    with the ports, the extrinsics and the board poses (fx, fy, cx, cy and the lens terms of the
//!    candidate), once per candidate of [`TERM_CANDIDATES`], simplest first; a richer candidate
//!    is kept where the held-out frames' RMS falls by more than [`TERM_MARGIN`] (without held-out
//!    frames, k1 alone).
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

/// Relative fall of the held-out RMS a richer candidate must bring to be kept (0.02: 2 %).
pub const TERM_MARGIN: f64 = 0.02;

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
    let mut best: Option<(BoardsCalibration, LensTerms, f64)> = None;
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
            failed: failed.clone(),
        });
        let Ok(result) = result else {
            last_error = result.err();
            continue;
        };
        if failed.is_some() {
            // A poor fit is kept only while nothing better exists: its report says why.
            if best.is_none() {
                best = Some((result, terms, f64::INFINITY));
            }
            continue;
        }
        let better = match &best {
            None => true,
            Some((_, _, rms)) if !rms.is_finite() => true,
            // Without held-out frames, k1 alone: the term every lens under water needs.
            Some(_) if held_out_rms_px.is_nan() => terms == TERM_CANDIDATES[1],
            Some((_, _, rms)) => held_out_rms_px < (1.0 - TERM_MARGIN) * rms,
        };
        if better {
            best = Some((result, terms, held_out_rms_px));
        } else if best
            .as_ref()
            .is_some_and(|(_, t, _)| *t != TERM_CANDIDATES[0])
        {
            // A richer candidate that does not help after one that did: stop.
            break;
        }
    }
    let Some((calibration, terms, _)) = best else {
        return Err(
            last_error.unwrap_or_else(|| CalibError::Options("no lens candidate was tried".into()))
        );
    };
    let reason = format!(
        "lens terms {} chosen by the held-out frames' RMS ({}; a richer set is kept where it falls by more than {:.0} %)",
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
