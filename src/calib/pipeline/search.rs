//! The start of the ports when no camera pair shares a port over a board (one camera, a port per
//! camera, a 3-D target): a global search over each port's axis in which every cell fits the air
//! distance and the target poses by a few Levenberg–Marquardt steps.

use nalgebra::Isometry3;

use super::bundle::{Bundle, Estimate, Parameter, State};
use super::{Options, fit_briefly, rms};
use crate::calib::error::CalibError;
use crate::calib::problem::observations::SeenView;
use crate::calib::problem::target::Target;
use crate::calib::solvers::search::cap_grid;
use crate::model::{Ports, Rig};

/// Spacing of the global axis search, radians.
const SEARCH_SPACING_DEG: f64 = 4.0;
/// Levenberg–Marquardt steps of a search cell, and of the poses alone.
const CELL_ITERATIONS: usize = 30;
pub(super) const POSE_ITERATIONS: usize = 30;

/// A global search over port `p`'s axis (within the tilt cap about its frame's z axis): each cell
/// fits the air distance and the poses by a few LM steps; the best cell (and the start, if
/// better) is kept.
/// With a port per camera only that camera's images take part (the other ports are still at
/// their start and would pull the search their way).
pub fn search_axis(
    rig: &Rig,
    target: &Target,
    views: &[SeenView],
    state: State,
    p: usize,
    options: &Options,
) -> Result<State, CalibError> {
    let distance_only = Estimate {
        distance: options.estimate.distance,
        ..Estimate::NOTHING
    };
    let (own_views, own_poses): (Vec<SeenView>, Vec<Isometry3<f64>>) = match rig.ports() {
        Ports::Shared(_) => (views.to_vec(), state.poses.clone()),
        Ports::PerCamera(_) => views
            .iter()
            .zip(&state.poses)
            .filter_map(|(view, pose)| {
                let own: Vec<_> = view
                    .cameras
                    .iter()
                    .filter(|(k, _)| *k == p)
                    .cloned()
                    .collect();
                let keys = view
                    .cameras
                    .iter()
                    .zip(&view.keys)
                    .filter(|((k, _), _)| *k == p)
                    .map(|(_, key)| key.clone())
                    .collect();
                (!own.is_empty()).then_some((SeenView { cameras: own, keys }, *pose))
            })
            .unzip(),
    };
    if own_views.is_empty() {
        return Ok(state);
    }
    let whole = state;
    let views = &own_views[..];
    // The poses refitted to these images alone under the start port, for every cell to start from.
    let pose_only = Bundle::new(rig, target, views, Estimate::NOTHING, options.huber);
    // These images' residual stencils on the options' device (a device error falls back to the
    // CPU, as in the rest of the pipeline).
    let residuals = options.backend.bundle_residuals(&pose_only);
    let state = fit_briefly(
        &pose_only.on(residuals.as_deref()),
        State {
            poses: own_poses,
            ..whole.clone()
        },
        POSE_ITERATIONS,
    );
    let bundle = Bundle::new(rig, target, views, distance_only, options.huber)
        .keeping(|g| g == Parameter::Distance(p))
        .on(residuals.as_deref());
    let axes = cap_grid(options.max_tilt, SEARCH_SPACING_DEG.to_radians());
    let start_cost = rms(
        &bundle,
        &fit_briefly(&bundle, state.clone(), CELL_ITERATIONS),
    );
    let cells: Vec<(f64, State)> = axes
        .iter()
        .map(|axis| {
            let mut cell = state.clone();
            cell.ports[p].normal = *axis;
            let cell = fit_briefly(&bundle, cell, CELL_ITERATIONS);
            (rms(&bundle, &cell), cell)
        })
        .collect();
    let (cost, best) = cells
        .into_iter()
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .expect("the cap grid holds the z axis");
    if cost.is_finite() || start_cost.is_finite() {
        // The port found; the poses are refitted over every camera afterwards.
        let mut result = whole;
        if cost <= start_cost {
            result.ports[p] = best.ports[p].clone();
        }
        Ok(result)
    } else {
        Err(CalibError::Options(format!(
            "no axis within a tilt of {:.1}° explains the corners of port {p}",
            options.max_tilt.to_degrees()
        )))
    }
}
