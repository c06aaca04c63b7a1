//! Levenberg–Marquardt over a manifold. The optimiser sees a [`LeastSquares`] problem (its
//! normal equations and a retraction), never cameras or interfaces.

use nalgebra::{DMatrix, DVector};

/// A least-squares problem Σᵢ ρ(|rᵢ(x)|²) over a state that moves by retraction.
pub trait LeastSquares {
    /// The point being optimised.
    type State: Clone;

    /// Number of parameters of a step.
    fn dimension(&self, state: &Self::State) -> usize;

    /// The cost at `state`; `None` where it is undefined (a residual has no answer).
    fn cost(&self, state: &Self::State) -> Option<f64>;

    /// Gauss–Newton normal equations at `state`: (JᵀWJ, JᵀWr, cost) with J = ∂r/∂δ at δ = 0 and
    /// W the robust weights. `None` where a residual has no answer.
    fn normal_equations(&self, state: &Self::State) -> Option<(DMatrix<f64>, DVector<f64>, f64)>;

    /// The state moved by `delta` (a step in the problem's local parameters).
    fn retract(&self, state: &Self::State, delta: &DVector<f64>) -> Self::State;
}

/// When to stop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmOptions {
    /// Largest number of accepted or rejected steps.
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the cost by less than this fraction.
    pub cost_tolerance: f64,
    /// Stop when the gradient's largest component falls below this (cost units per parameter unit).
    pub gradient_tolerance: f64,
    /// Initial damping relative to the largest diagonal of JᵀJ.
    pub initial_damping: f64,
}

impl Default for LmOptions {
    fn default() -> Self {
        Self { max_iterations: 200, cost_tolerance: 1e-10, gradient_tolerance: 1e-18, initial_damping: 1e-4 }
    }
}

/// Why the solver stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Termination {
    /// An accepted step lowered the cost by less than the tolerance.
    CostConverged,
    /// The gradient vanished.
    GradientConverged,
    /// The damping grew without finding a lower cost: the state is a minimum to rounding.
    NoDescent,
    /// The iteration bound was hit.
    MaxIterations,
    /// The cost is undefined at the start.
    InvalidStart,
}

impl Termination {
    /// Short description.
    pub fn describe(self) -> &'static str {
        match self {
            Self::CostConverged => "cost converged",
            Self::GradientConverged => "gradient vanished",
            Self::NoDescent => "no further descent (minimum to rounding)",
            Self::MaxIterations => "iteration limit reached",
            Self::InvalidStart => "cost undefined at the start",
        }
    }

    /// Whether the solver ended at a minimum.
    pub fn converged(self) -> bool {
        matches!(self, Self::CostConverged | Self::GradientConverged | Self::NoDescent)
    }
}

/// What the solver did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmReport {
    /// Steps tried (accepted and rejected).
    pub iterations: usize,
    /// Cost at the start.
    pub initial_cost: f64,
    /// Cost at the end.
    pub final_cost: f64,
    /// Why it stopped.
    pub termination: Termination,
}

/// Minimises `problem` from `start`. Returns the final state, the report, and JᵀWJ at the final
/// state (for covariances).
pub fn levenberg_marquardt<P: LeastSquares>(
    problem: &P,
    start: P::State,
    options: &LmOptions,
) -> (P::State, LmReport, Option<DMatrix<f64>>) {
    let mut state = start;
    let Some((mut jtj, mut jtr, mut cost)) = problem.normal_equations(&state) else {
        let report = LmReport { iterations: 0, initial_cost: f64::INFINITY, final_cost: f64::INFINITY, termination: Termination::InvalidStart };
        return (state, report, None);
    };
    let initial_cost = cost;
    let max_diagonal = jtj.diagonal().max();
    let mut damping = options.initial_damping * max_diagonal.max(1e-300);
    let mut termination = Termination::MaxIterations;
    let mut iterations = 0;
    while iterations < options.max_iterations {
        if jtr.amax() <= options.gradient_tolerance {
            termination = Termination::GradientConverged;
            break;
        }
        iterations += 1;
        // (JᵀJ + λ·diag(JᵀJ)) δ = −Jᵀr, with a floor on the diagonal for parameters that the
        // data barely see.
        let mut a = jtj.clone();
        for i in 0..a.nrows() {
            a[(i, i)] += damping * jtj[(i, i)].max(1e-12 * max_diagonal);
        }
        let Some(cholesky) = a.cholesky() else {
            damping *= 10.0;
            continue;
        };
        let delta = -cholesky.solve(&jtr);
        let candidate = problem.retract(&state, &delta);
        match problem.cost(&candidate) {
            Some(new_cost) if new_cost < cost => {
                let improvement = (cost - new_cost) / cost.max(f64::MIN_POSITIVE);
                state = candidate;
                damping = (damping / 3.0).max(1e-15 * max_diagonal);
                match problem.normal_equations(&state) {
                    Some((j, r, c)) => (jtj, jtr, cost) = (j, r, c),
                    None => {
                        termination = Termination::NoDescent;
                        break;
                    }
                }
                if improvement < options.cost_tolerance {
                    termination = Termination::CostConverged;
                    break;
                }
            }
            _ => {
                damping *= 4.0;
                if damping > 1e16 * max_diagonal.max(1e-300) {
                    termination = Termination::NoDescent;
                    break;
                }
            }
        }
    }
    let report = LmReport { iterations, initial_cost, final_cost: cost, termination };
    (state, report, Some(jtj))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rosenbrock as least squares: r = (10 (y − x²), 1 − x), minimum 0 at (1, 1).
    struct Rosenbrock;

    impl LeastSquares for Rosenbrock {
        type State = DVector<f64>;
        fn dimension(&self, _: &Self::State) -> usize {
            2
        }
        fn cost(&self, s: &Self::State) -> Option<f64> {
            Some((10.0 * (s[1] - s[0] * s[0])).powi(2) + (1.0 - s[0]).powi(2))
        }
        fn normal_equations(&self, s: &Self::State) -> Option<(DMatrix<f64>, DVector<f64>, f64)> {
            let r = DVector::from_vec(vec![10.0 * (s[1] - s[0] * s[0]), 1.0 - s[0]]);
            let j = DMatrix::from_row_slice(2, 2, &[-20.0 * s[0], 10.0, -1.0, 0.0]);
            Some((j.transpose() * &j, j.transpose() * &r, r.norm_squared()))
        }
        fn retract(&self, s: &Self::State, delta: &DVector<f64>) -> Self::State {
            s + delta
        }
    }

    #[test]
    fn solves_rosenbrock_and_says_why_it_stopped() {
        let start = DVector::from_vec(vec![-1.2, 1.0]);
        let (end, report, _) = levenberg_marquardt(&Rosenbrock, start, &LmOptions::default());
        assert!((end[0] - 1.0).abs() < 1e-10 && (end[1] - 1.0).abs() < 1e-10, "{end}");
        assert!(report.termination.converged(), "{report:?}");
        assert!(report.final_cost < 1e-20 && report.initial_cost > 1.0);
    }
}
