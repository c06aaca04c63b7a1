//! Searches over the system axis: a global grid over a spherical cap of tilts, and a local
//! refinement from finite-difference stencils. Both hand whole batches to the backend.

use nalgebra::{Matrix2, Unit, Vector2, Vector3};

use crate::calib::backends::CostBackend;
use crate::calib::costs::CostKind;
use crate::calib::costs::invariants::plane_basis;
use crate::calib::error::CalibError;
use crate::calib::problem::data::Candidate;

/// Most axes of a global search grid ([`cap_grid`]): every axis costs one evaluation over all
/// corners in each global search (two in the auto method), so 10⁵ axes already take minutes on a
/// thousand views. The default 1.5° over a 30° cap is 1 229 axes.
pub const MAX_CAP_GRID_AXES: usize = 100_000;

/// Axes [`cap_grid`] spreads over a cap of tilt `bound` at `spacing` (radians), as a float so that
/// tiny spacings do not overflow (+∞ for a zero spacing).
pub fn cap_grid_size(bound: f64, spacing: f64) -> f64 {
    let area = std::f64::consts::TAU * (1.0 - bound.cos());
    (area / (spacing * spacing)).ceil().max(1.0) + 1.0
}

/// The smallest spacing (radians) whose [`cap_grid`] over `bound` holds at most
/// [`MAX_CAP_GRID_AXES`] axes.
pub fn min_cap_grid_spacing(bound: f64) -> f64 {
    let area = std::f64::consts::TAU * (1.0 - bound.cos());
    (area / (MAX_CAP_GRID_AXES - 1) as f64).sqrt()
}

/// [`min_cap_grid_spacing`] in degrees, rounded up to 4 decimals (so that the value printed is
/// accepted).
pub fn min_cap_grid_spacing_deg_text(bound: f64) -> String {
    format!(
        "{:.4}",
        (min_cap_grid_spacing(bound).to_degrees() * 1e4).ceil() / 1e4
    )
}

/// Axes with a tilt from the master z axis of at most `bound` (radians), spread evenly over that
/// spherical cap (a Fibonacci spiral) about `spacing` radians apart; the first is z itself. At most
/// [`MAX_CAP_GRID_AXES`] axes: a smaller spacing is widened to [`min_cap_grid_spacing`] (callers
/// refuse it first with a message, see [`cap_grid_size`]).
pub fn cap_grid(bound: f64, spacing: f64) -> Vec<Unit<Vector3<f64>>> {
    let area = std::f64::consts::TAU * (1.0 - bound.cos());
    let count = (area / (spacing * spacing))
        .ceil()
        .clamp(1.0, (MAX_CAP_GRID_AXES - 1) as f64) as usize;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let mut normals = vec![Unit::new_unchecked(Vector3::z())];
    for i in 0..count {
        // z uniform in [cos bound, 1): equal areas.
        let z = 1.0 - (1.0 - bound.cos()) * (i as f64 + 0.5) / count as f64;
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = golden * i as f64;
        normals.push(Unit::new_normalize(Vector3::new(
            r * phi.cos(),
            r * phi.sin(),
            z,
        )));
    }
    normals
}

/// The axis `normal` moved by `offset` in its tangent plane (basis [`plane_basis`]).
pub fn tangent_step(normal: &Unit<Vector3<f64>>, offset: &Vector2<f64>) -> Unit<Vector3<f64>> {
    let [e1, e2] = plane_basis(normal);
    Unit::new_normalize(normal.into_inner() + e1 * offset.x + e2 * offset.y)
}

/// The result of a local axis refinement.
#[derive(Debug, Clone, Copy)]
pub struct Refined {
    /// The best candidate found (air layer from the profile, NaN for axis-only costs).
    pub candidate: Candidate,
    /// Its cost.
    pub cost: f64,
    /// Stencil iterations.
    pub iterations: usize,
    /// Candidates evaluated.
    pub evaluations: usize,
}

/// Refines an axis by minimising the profile of `kind` (see [`CostBackend::profile`]) from `start`.
///
/// Each iteration evaluates a 3×3 stencil of spacing h in the tangent plane in one batch, takes
/// the gradient and Hessian from its central differences, and tries the Newton step (clipped to
/// 2h) in a second batch. It moves to the best point seen; when neither the step nor the stencil
/// improves, h shrinks fourfold. Stops when h < `min_step` (radians) or after `max_iterations`.
pub fn refine_axis(
    backend: &dyn CostBackend,
    kind: CostKind,
    start: Unit<Vector3<f64>>,
    step: f64,
    min_step: f64,
    max_iterations: usize,
) -> Result<Refined, CalibError> {
    refine_axis_observed(
        backend,
        kind,
        start,
        step,
        min_step,
        max_iterations,
        &mut |_, _| {},
    )
}

/// [`refine_axis`], calling `progress(iteration, best cost)` after every iteration.
pub fn refine_axis_observed(
    backend: &dyn CostBackend,
    kind: CostKind,
    start: Unit<Vector3<f64>>,
    step: f64,
    min_step: f64,
    max_iterations: usize,
    progress: &mut dyn FnMut(usize, f64),
) -> Result<Refined, CalibError> {
    let (candidates, costs) = backend.profile(kind, &[start])?;
    let (mut best, mut best_cost) = (candidates[0], costs[0]);
    let mut h = step;
    let mut evaluations = 1;
    let mut iterations = 0;
    while h >= min_step && iterations < max_iterations {
        iterations += 1;
        let centre = best.normal;
        let offsets: Vec<Vector2<f64>> = (-1..=1)
            .flat_map(|i| (-1..=1).map(move |j| Vector2::new(i as f64, j as f64) * h))
            .filter(|o| o.norm() > 0.0)
            .collect();
        let normals: Vec<_> = offsets.iter().map(|o| tangent_step(&centre, o)).collect();
        let (stencil, values) = backend.profile(kind, &normals)?;
        evaluations += normals.len();
        let at = |i: i32, j: i32| -> f64 {
            if i == 0 && j == 0 {
                return best_cost;
            }
            let k = offsets
                .iter()
                .position(|o| o.x == i as f64 * h && o.y == j as f64 * h)
                .expect("stencil point");
            values[k]
        };
        let mut moved = false;
        let mut step_length = 0.0;
        let f0 = best_cost;
        let g = Vector2::new(at(1, 0) - at(-1, 0), at(0, 1) - at(0, -1)) / (2.0 * h);
        let hxx = (at(1, 0) - 2.0 * f0 + at(-1, 0)) / (h * h);
        let hyy = (at(0, 1) - 2.0 * f0 + at(0, -1)) / (h * h);
        let hxy = (at(1, 1) - at(1, -1) - at(-1, 1) + at(-1, -1)) / (4.0 * h * h);
        let hessian = Matrix2::new(hxx, hxy, hxy, hyy);
        if g.iter().chain(hessian.iter()).all(|v| v.is_finite())
            && let Some(cholesky) = hessian.cholesky()
        {
            let mut newton = -cholesky.solve(&g);
            if newton.norm() > 2.0 * h {
                newton *= 2.0 * h / newton.norm();
            }
            let (c, v) = backend.profile(kind, &[tangent_step(&centre, &newton)])?;
            evaluations += 1;
            if v[0] < best_cost {
                best = c[0];
                best_cost = v[0];
                moved = true;
                step_length = newton.norm();
            }
        }
        // The stencil's best point, when it beats the Newton step.
        if let Some(k) = (0..values.len())
            .filter(|&k| values[k] < best_cost)
            .min_by(|&a, &b| values[a].total_cmp(&values[b]))
        {
            best = stencil[k];
            best_cost = values[k];
            moved = true;
            step_length = offsets[k].norm();
        }
        if moved {
            // Keep the stencil about as wide as the last step so the differences stay accurate.
            h = h.min(step_length.max(min_step)).max(step_length * 0.5);
        } else {
            h /= 4.0;
        }
        progress(iterations, best_cost);
    }
    if !best_cost.is_finite() {
        return Err(CalibError::NoSolution {
            bound_deg: f64::NAN,
            reason: format!(
                "the {} cost is infinite at and around the start axis",
                kind.name()
            ),
        });
    }
    Ok(Refined {
        candidate: best,
        cost: best_cost,
        iterations,
        evaluations,
    })
}

/// Largest air layer [`fit_air_distance`] considers, metres.
pub const MAX_AIR_DISTANCE: f64 = 0.5;

/// The air layer that minimises `kind` along a fixed axis: a batch of 64 air layers spaced
/// geometrically from just outside the cameras to [`MAX_AIR_DISTANCE`], then batches of 8 ever
/// closer around the best (golden-section-like shrinking) until the bracket is below 1e-9 m.
/// `None` when every air layer costs +∞.
pub fn fit_air_distance(
    backend: &dyn CostBackend,
    kind: CostKind,
    normal: &Unit<Vector3<f64>>,
) -> Result<Option<(f64, f64)>, CalibError> {
    let low = backend.data().min_air_distance(normal) + 1e-4;
    if !(low < MAX_AIR_DISTANCE) {
        return Ok(None);
    }
    let count = 64;
    let ratio = (MAX_AIR_DISTANCE / low).powf(1.0 / (count - 1) as f64);
    let mut distances: Vec<f64> = (0..count).map(|i| low * ratio.powi(i)).collect();
    let (mut best_d, mut best_cost) = (f64::NAN, f64::INFINITY);
    let mut bracket;
    loop {
        let candidates: Vec<Candidate> = distances
            .iter()
            .map(|&d| Candidate {
                normal: *normal,
                air_distance: d,
            })
            .collect();
        let costs = backend.costs(kind, &candidates)?;
        let Some(k) = (0..costs.len())
            .filter(|&k| costs[k].is_finite())
            .min_by(|&a, &b| costs[a].total_cmp(&costs[b]))
        else {
            return Ok(best_cost.is_finite().then_some((best_d, best_cost)));
        };
        if costs[k] < best_cost {
            (best_d, best_cost) = (distances[k], costs[k]);
        }
        let below = if k > 0 {
            distances[k - 1]
        } else {
            (best_d - (distances[1] - distances[0])).max(low)
        };
        let above = if k + 1 < distances.len() {
            distances[k + 1]
        } else {
            best_d + (distances[k] - distances[k - 1])
        };
        bracket = above - below;
        if bracket < 1e-9 {
            break;
        }
        distances = (0..=8)
            .map(|i| below + bracket * i as f64 / 8.0)
            .filter(|&d| d >= low)
            .collect();
    }
    Ok(Some((best_d, best_cost)))
}
