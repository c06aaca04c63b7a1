//! Steps 1 and 2 of the pipeline ([`super`]): the options' bounds and whether the method
//! applies, the views as a whole (enough distinct target poses, no copies), what the data cannot
//! determine, and the screening of each image of a board for gross corner errors.

use super::bundle::{Estimate, distance_unobservable};
use super::report::port_names;
use super::{FEW_VIEWS, MIN_VIEWS, MIN_VIEWS_3D, Method, Options};
use crate::base::Board;
use crate::calib::error::{CalibError, degrees};
use crate::calib::problem::observations::{
    SeenView, compare_views, describe_pose_groups, view_corners,
};
use crate::calib::problem::screen::{Screening, screen};
use crate::calib::problem::target::Target;
use crate::model::{Ports, Rig};

/// The options' bounds, and whether the method and the estimate apply to the rig.
pub(super) fn check_options(
    rig: &Rig,
    target: &Target,
    options: &Options,
) -> Result<(), CalibError> {
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
        if estimate.layers != 0 || estimate.extrinsics || estimate.intrinsics {
            return Err(CalibError::Options(
                "the consecutive method estimates the axis and the air distance only; --estimate layers, extrinsics or intrinsics needs --method simultaneous or auto".into(),
            ));
        }
    }
    if !(estimate.axis
        || estimate.distance
        || estimate.layers != 0
        || estimate.extrinsics
        || estimate.intrinsics)
    {
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
/// warning. A planar target needs [`MIN_VIEWS`] distinct poses (within one view its pose and the
/// port trade off); a 3-D (non-planar) target fixes its pose, and with it the port, from one
/// view ([`MIN_VIEWS_3D`]; Agrawal et al.'s tank: one image of a 3-D target).
pub(super) fn check_views(
    target: &Target,
    seen: &[SeenView],
    warnings: &mut Vec<String>,
) -> Result<(), CalibError> {
    let planar = target.is_planar();
    let needed = if planar { MIN_VIEWS } else { MIN_VIEWS_3D };
    if seen.len() < needed {
        return Err(CalibError::TooFewViews {
            usable: seen.len(),
            needed,
        });
    }
    let groups = compare_views(&view_corners(seen));
    groups.check_repeats()?;
    if groups.distinct < needed {
        return Err(CalibError::TooFewPoses {
            views: seen.len(),
            distinct: groups.distinct,
            groups: describe_pose_groups(&groups),
            needed,
        });
    }
    if planar && groups.distinct < FEW_VIEWS {
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
pub(super) fn warn_unobservable(
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
pub(super) fn screen_gross_errors(
    rig: &Rig,
    board: &Board,
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
