//! The thesis' consecutive method on one camera pair behind a shared port (DESIGN.md §3): the
//! axis from the weighted affine-grid invariant (a global search over the tilt cap, then a local
//! refinement of the best few cells), then the air layer by linear least squares on the ray gaps.
//! Every cost is evaluated in batches by a [`CostBackend`] (the CPU reference or the GPU). The
//! pipeline ([`super`]) runs it as the start of every rig with such a pair; the reprojection
//! profile's minimum ([`profile_minimum`]) is a second start of the `auto` method.

use std::time::Instant;

use nalgebra::{Unit, Vector3};

use super::{Options, Progress, Stage};
use crate::calib::backends::CostBackend;
use crate::calib::costs::{CostKind, SceneFit};
use crate::calib::error::CalibError;
use crate::calib::problem::data::{Candidate, StereoData};
use crate::calib::solvers::search::{Refined, cap_grid, fit_air_distance, refine_axis_observed};

/// The consecutive estimate of the pair of `backend`: the axis from the affine-grid invariant,
/// then the air layer by linear least squares on the ray gaps, or, when that leaves corners
/// without a triangulation, the air layer that best explains the images along the same axis.
pub fn consecutive_estimate(
    backend: &dyn CostBackend,
    options: &Options,
    stages: &mut Vec<Stage>,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Candidate, CalibError> {
    let data = backend.data();
    let axis = axis_search(backend, CostKind::AffineGrid, options, stages, progress)?;
    let linear_started = Instant::now();
    let (air_distance, gap) = crate::calib::costs::scene::air_distance_for_axis(data, &axis.normal)
        .ok_or_else(|| {
            no_solution(
                options,
                "the air layer has no least-squares solution under the invariant's axis",
            )
        })?;
    let mut consecutive = Candidate {
        normal: axis.normal,
        air_distance,
    };
    stages.push(Stage::at(
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
        // A fallback with its reason, not a finding: a stage, not a warning.
        consecutive.air_distance = d;
        stages.push(Stage::at(
            &format!(
                "air layer (1-D search on the reprojection error: the linear one, {:.2} mm, left corners without a triangulation)",
                air_distance * 1e3
            ),
            consecutive,
            cost,
            "px",
            1,
            t,
        ));
    }
    Ok(consecutive)
}

/// The minimum of the reprojection error's profile over the axis (each axis with its
/// least-squares air layer): the `auto` method's second start.
pub fn profile_minimum(
    backend: &dyn CostBackend,
    options: &Options,
    stages: &mut Vec<Stage>,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Candidate, CalibError> {
    axis_search(backend, CostKind::Reprojection, options, stages, progress)
}

/// Whether every corner triangulates and every view can be fitted under `candidate`.
pub fn triangulates(data: &StereoData, candidate: &Candidate) -> bool {
    data.cameras_behind(candidate)
        .and_then(|c| SceneFit::new(data, &c))
        .is_some()
}

/// A [`CalibError::NoSolution`] under the options' tilt bound.
pub fn no_solution(options: &Options, reason: &str) -> CalibError {
    CalibError::NoSolution {
        bound_deg: options.max_tilt.to_degrees(),
        reason: reason.into(),
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
    options: &Options,
    stages: &mut Vec<Stage>,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Candidate, CalibError> {
    let t = Instant::now();
    let grid = cap_grid(options.max_tilt, options.grid_spacing());
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
        progress(&Progress {
            stage: &global_name,
            done: costs.len(),
            total: Some(grid.len()),
            cost: best,
            unit: kind.unit(),
        });
    }
    let mut order: Vec<usize> = (0..grid.len()).filter(|&i| costs[i].is_finite()).collect();
    if order.is_empty() {
        return Err(no_solution(
            options,
            &format!(
                "the {} cost is undefined on every one of {} grid axes",
                kind.name(),
                grid.len()
            ),
        ));
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
    stages.push(Stage::at(
        &global_name,
        candidates[order[0]],
        costs[order[0]],
        kind.unit(),
        grid.len(),
        t,
    ));
    let mut best: Option<Refined> = None;
    for start in starts {
        let t = Instant::now();
        let refine_name = format!("refine axis ({})", kind.name());
        let refined = refine_axis_observed(
            backend,
            kind,
            start,
            options.grid_spacing(),
            1e-9,
            300,
            &mut |i, cost| {
                progress(&Progress {
                    stage: &refine_name,
                    done: i,
                    total: None,
                    cost,
                    unit: kind.unit(),
                })
            },
        )?;
        stages.push(Stage::at(
            &refine_name,
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
