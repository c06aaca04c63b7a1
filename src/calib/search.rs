//! Searches over the system axis: a global grid over a spherical cap of tilts, and a local
//! refinement from finite-difference stencils. Both hand whole batches to the backend.

use nalgebra::{Matrix2, Unit, Vector2, Vector3};

use super::backend::CostBackend;
use super::costs::CostKind;
use super::data::Candidate;
use super::error::CalibError;
use super::invariants::plane_basis;

/// Axes with a tilt from the master z axis of at most `bound` (radians), spread evenly over that
/// spherical cap (a Fibonacci spiral) about `spacing` radians apart; the first is z itself.
pub fn cap_grid(bound: f64, spacing: f64) -> Vec<Unit<Vector3<f64>>> {
    let area = std::f64::consts::TAU * (1.0 - bound.cos());
    let count = ((area / (spacing * spacing)).ceil() as usize).max(1);
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let mut normals = vec![Unit::new_unchecked(Vector3::z())];
    for i in 0..count {
        // z uniform in [cos bound, 1): equal areas.
        let z = 1.0 - (1.0 - bound.cos()) * (i as f64 + 0.5) / count as f64;
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = golden * i as f64;
        normals.push(Unit::new_normalize(Vector3::new(r * phi.cos(), r * phi.sin(), z)));
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
    let (candidates, costs) = backend.profile(kind, &[start])?;
    let (mut best, mut best_cost) = (candidates[0], costs[0]);
    let mut h = step;
    let mut evaluations = 1;
    let mut iterations = 0;
    while h >= min_step && iterations < max_iterations {
        iterations += 1;
        let centre = best.normal;
        let offsets: Vec<Vector2<f64>> =
            (-1..=1).flat_map(|i| (-1..=1).map(move |j| Vector2::new(i as f64, j as f64) * h)).filter(|o| o.norm() > 0.0).collect();
        let normals: Vec<_> = offsets.iter().map(|o| tangent_step(&centre, o)).collect();
        let (stencil, values) = backend.profile(kind, &normals)?;
        evaluations += normals.len();
        let at = |i: i32, j: i32| -> f64 {
            if i == 0 && j == 0 {
                return best_cost;
            }
            let k = offsets.iter().position(|o| o.x == i as f64 * h && o.y == j as f64 * h).expect("stencil point");
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
        if g.iter().chain(hessian.iter()).all(|v| v.is_finite()) {
            if let Some(cholesky) = hessian.cholesky() {
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
        }
        // The stencil's best point, when it beats the Newton step.
        if let Some(k) = (0..values.len()).filter(|&k| values[k] < best_cost).min_by(|&a, &b| values[a].total_cmp(&values[b])) {
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
    }
    if !best_cost.is_finite() {
        return Err(CalibError::NoSolution {
            bound_deg: f64::NAN,
            reason: format!("the {} cost is infinite at and around the start axis", kind.name()),
        });
    }
    Ok(Refined { candidate: best, cost: best_cost, iterations, evaluations })
}
