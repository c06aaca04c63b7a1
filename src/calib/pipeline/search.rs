//! The start of the ports when no camera pair shares a port over a board (one camera, a port per
//! camera, a 3-D target): a global search over each port's axis in which every cell fits the air
//! distance and the target poses by a few Levenberg–Marquardt steps.

use nalgebra::{Isometry3, Vector3};

use super::Options;
use super::bundle::{Bundle, Estimate, Parameter, State, fit_briefly, rms};
use super::extrinsics::MIN_LINK_CORNERS;
use super::poses::{POSE_ITERATIONS, bent_into_water, pinhole_pose, place_undefined_views};
use crate::calib::error::CalibError;
use crate::calib::problem::observations::SeenView;
use crate::calib::problem::target::Target;
use crate::calib::solvers::lm::LeastSquares;
use crate::calib::solvers::search::cap_grid;
use crate::model::{Ports, Rig};

/// Spacing of the global axis search, radians.
const SEARCH_SPACING_DEG: f64 = 4.0;
/// Levenberg–Marquardt steps of a search cell.
const CELL_ITERATIONS: usize = 30;
/// Levenberg–Marquardt steps of a port per camera refined from its best cell, with its own
/// images alone (axis, air distance and board poses).
const REFINE_ITERATIONS: usize = 100;
/// Air layers (metres) a port per camera is also refined from, at its cell's axis: the span of
/// real housings (2–40 mm), a factor of about three apart.
const REFINE_AIR_M: [f64; 3] = [0.003, 0.01, 0.03];
/// How many of the search's best cells a port per camera is refined from.
const REFINE_CELLS: usize = 3;

/// A board pose cam_from_target per view, where one was found.
pub(super) type ViewPoses = Vec<Option<Isometry3<f64>>>;

/// A global search over port `p`'s axis (within the tilt cap about its frame's z axis): each cell
/// fits the air distance and the poses by a few LM steps; the best cell (and the start, if
/// better) is kept.
/// With a port per camera only that camera's images take part (the other ports are still at
/// their start and would pull the search their way), and the port kept is refined from its cell
/// (axis, air distance and poses) by those images alone, from the [`REFINE_CELLS`] best cells,
/// each also at the air layers of [`REFINE_AIR_M`], and from the start's port; the lowest kept.
///
/// Returns the state with port `p` replaced and, with a port per camera, camera `p`'s board pose
/// cam_from_target in every view where it saw [`MIN_LINK_CORNERS`] or more corners, fitted to its
/// images alone through the port found (`None` elsewhere, and for a shared port): poses through
/// the real port, from which the extrinsics can be linked again ([`link_poses`]).
///
/// [`link_poses`]: super::extrinsics::link_poses
pub fn search_axis(
    rig: &Rig,
    target: &Target,
    views: &[SeenView],
    state: State,
    p: usize,
    options: &Options,
) -> Result<(State, ViewPoses), CalibError> {
    let mut own_poses_found = vec![None; views.len()];
    let distance_only = Estimate {
        distance: options.estimate.distance,
        ..Estimate::NOTHING
    };
    let per_camera = matches!(rig.ports(), Ports::PerCamera(_));
    // The views of these images, by their index in `views`.
    let mut own_index = Vec::new();
    let (own_views, own_poses): (Vec<SeenView>, Vec<Isometry3<f64>>) = match rig.ports() {
        Ports::Shared(_) => (views.to_vec(), state.poses.clone()),
        Ports::PerCamera(_) => views
            .iter()
            .zip(&state.poses)
            .enumerate()
            .filter_map(|(v, (view, pose))| {
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
                if own.is_empty() {
                    return None;
                }
                own_index.push(v);
                let own = SeenView { cameras: own, keys };
                let pose = own_start_pose(rig, target, &own, &state, p).unwrap_or(*pose);
                Some((own, pose))
            })
            .unzip(),
    };
    if own_views.is_empty() {
        return Ok((state, own_poses_found));
    }
    let whole = state;
    let views = &own_views[..];
    // The poses refitted to these images alone under the start port, for every cell to start from.
    let pose_only = Bundle::new(rig, target, views, Estimate::NOTHING, options.huber);
    // These images' residual stencils on the options' device (a device error falls back to the
    // CPU, as in the rest of the pipeline).
    let residuals = options.backend.bundle_residuals(&pose_only);
    let pose_only = pose_only.on(residuals.as_deref());
    let state = fit_briefly(
        &pose_only,
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
    let start_fit = fit_briefly(&bundle, state.clone(), CELL_ITERATIONS);
    let start_cost = rms(&bundle, &start_fit);
    let cells: Vec<(f64, State)> = axes
        .iter()
        .map(|axis| {
            let mut cell = state.clone();
            cell.ports[p].normal = *axis;
            // A tilted shared port may reach a camera set off across the start's axis (a wide
            // baseline): the port moves out past it, so that the cell starts where its cost is
            // defined.
            let (cell, _) = cell.feasible();
            // A view whose apparent-board pose this cell's port cannot project (a wide lens:
            // zoo seed 75, k1 = −0.26, every cell and the start undefined) is placed again by
            // its corners' directions bent into the water at the cell's port.
            let (cell, _) = place_undefined_views(&pose_only, rig, target, views, cell);
            let cell = fit_briefly(&bundle, cell, CELL_ITERATIONS);
            (rms(&bundle, &cell), cell)
        })
        .collect();
    // Lowest cost first (an undefined cell last).
    let mut cells = cells;
    cells.sort_by(|a, b| a.0.total_cmp(&b.0));
    let cost = cells.first().map_or(f64::INFINITY, |(c, _)| *c);
    if cost.is_finite() || start_cost.is_finite() {
        // The port found; the poses are refitted over every camera afterwards.
        let start_port = whole.ports[p].clone();
        let mut result = whole;
        let mut found = if cost <= start_cost
            && let Some((_, best)) = cells.first()
        {
            best.clone()
        } else {
            start_fit.clone()
        };
        if per_camera && options.estimate.axis {
            // A cell is up to half a spacing (2°) off, its air distance fitted at that axis
            // tens of millimetres off: six housings' ports each so far off, and the extrinsics
            // linked through them, start the joint fit where it stops at a wrong minimum (zoo
            // seed 70: 0.65 px against a noise of 0.011). The port fitted to its own camera's
            // images alone, as for one camera, comes to the truth from a cell near it.
            let own = Estimate {
                axis: true,
                ..distance_only
            };
            let refine = Bundle::new(rig, target, views, own, options.huber)
                .keeping(|g| matches!(g, Parameter::Axis(q, _) | Parameter::Distance(q) if q == p))
                .on(residuals.as_deref());
            // From the best few cells, each also at several air layers, and from the start's
            // port: a cell's air fitted at an axis degrees off may have collapsed to nothing, a
            // bound the fit does not leave again, and the truth may lie between two cells (zoo
            // seed 70's 2.5 mm housing: the best cell 1.6° off with 4e-7 m of air, the second
            // 2° off the other way with 68 mm).
            let mut starts = Vec::new();
            for (_, cell) in cells
                .iter()
                .take(REFINE_CELLS)
                .filter(|(c, _)| c.is_finite())
            {
                starts.push(cell.clone());
                for air in REFINE_AIR_M {
                    let mut start = cell.clone();
                    start.ports[p].distance = air;
                    starts.push(start);
                }
            }
            // The start's port as given, not as `start_fit` left it: its air, fitted at the start's
            // axis, may have collapsed as a cell's does.
            let mut start = start_fit;
            start.ports[p] = start_port;
            starts.push(start);
            let mut best_cost = rms(&refine, &found);
            for start in starts {
                let refined = fit_briefly(&refine, start, REFINE_ITERATIONS);
                let cost = rms(&refine, &refined);
                if cost < best_cost {
                    best_cost = cost;
                    found = refined;
                }
            }
        }
        result.ports[p] = found.ports[p].clone();
        if per_camera {
            // Camera p's own board poses (master_from_target through its start extrinsics).
            let cam_from_master = found.extrinsics[p];
            for ((&v, pose), view) in own_index.iter().zip(&found.poses).zip(views) {
                if view
                    .cameras
                    .iter()
                    .all(|(_, c)| c.len() >= MIN_LINK_CORNERS)
                {
                    own_poses_found[v] = Some(cam_from_master * pose);
                }
            }
        }
        Ok((result, own_poses_found))
    } else {
        Err(CalibError::Options(format!(
            "no axis within a tilt of {:.1}° explains the corners of port {p}",
            options.max_tilt.to_degrees()
        )))
    }
}

/// The start of the target pose (master frame) of camera `p`'s image `own` (a view of that
/// camera alone) for its port's search: the pinhole pose of its corners' directions in the
/// water, else of their directions in air, whichever camera `p`'s start port first projects
/// every corner of.
///
/// The view's pose otherwise comes from the camera that saw most of it, carried over by the
/// start's extrinsics, which behind housings can be centimetres off and leave the board where
/// camera p's port cannot see it. The pinhole pose of the pixels is that of the *apparent*
/// board: a corner a wide lens sees 45° off its axis lies, so placed, 45° off in the water,
/// where only a ray 70° off in air would reach it, outside the lens (or beyond 90°). Each
/// corner's direction bent into the water instead ([`bent_into_water`], at a port across the
/// camera's z axis) places the board where the port's rays go, up to their offset of a few
/// millimetres.
fn own_start_pose(
    rig: &Rig,
    target: &Target,
    own: &SeenView,
    state: &State,
    p: usize,
) -> Option<Isometry3<f64>> {
    let (_, corners) = own.cameras.first()?;
    let intrinsics = &rig.cameras()[p].intrinsics;
    let port = match rig.ports() {
        Ports::PerCamera(ports) => ports.get(p)?,
        Ports::Shared(port) => port,
    };
    let ratio = port.index_air() / port.index_water();
    let (object, in_air): (Vec<_>, Vec<_>) = corners
        .iter()
        .filter_map(|(i, pixel)| Some((target.point(*i), intrinsics.normalized_from_img(pixel)?)))
        .unzip();
    let in_water: Vec<_> = in_air
        .iter()
        .map(|x| bent_into_water(x, &Vector3::z(), ratio).unwrap_or(*x))
        .collect();
    let views = std::slice::from_ref(own);
    let bundle = Bundle::new(rig, target, views, Estimate::NOTHING, None);
    [in_water, in_air]
        .iter()
        .filter_map(|image| pinhole_pose(&object, image))
        .filter(|pose| {
            object.iter().all(|x| (pose * x).z > 0.0)
                && pose.translation.vector.iter().all(|x| x.is_finite())
        })
        .map(|cam_from_target| state.extrinsics[p].inverse() * cam_from_target)
        .find(|pose| {
            let one = State {
                poses: vec![*pose],
                ..state.clone()
            };
            bundle.cost(&one).is_some_and(f64::is_finite)
        })
}
