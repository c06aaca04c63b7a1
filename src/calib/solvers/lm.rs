//! Levenberg–Marquardt over a manifold. The optimiser sees a [`LeastSquares`] problem (its
//! normal equations and a retraction), never cameras or interfaces.

use nalgebra::{DMatrix, DVector};

/// Gauss–Newton normal equations JᵀWJ δ = −JᵀWr at one state, in whatever layout the problem
/// keeps them (dense, or blocks that a solver reduces): the optimiser only asks for the gradient,
/// the diagonal and damped solves.
pub trait NormalEquations {
    /// The cost Σᵢ ρ(|rᵢ|²) at the state they were built at.
    fn cost(&self) -> f64;

    /// max |JᵀWr|ᵢ, the largest gradient component.
    fn gradient_amax(&self) -> f64;

    /// max (JᵀWJ)ᵢᵢ, the largest diagonal entry.
    fn max_diagonal(&self) -> f64;

    /// The step δ solving (JᵀWJ + λ·D) δ = −JᵀWr with D = diag(max((JᵀWJ)ᵢᵢ, `floor`)), or `None`
    /// where that matrix is not numerically positive definite.
    fn solve_damped(&self, damping: f64, floor: f64) -> Option<DVector<f64>>;
}

/// Normal equations held as one dense matrix: for small problems and as the reference the block
/// solvers are tested against.
#[derive(Debug, Clone, PartialEq)]
pub struct DenseNormalEquations {
    /// JᵀWJ.
    pub jtj: DMatrix<f64>,
    /// JᵀWr.
    pub jtr: DVector<f64>,
    /// The cost.
    pub cost: f64,
}

impl NormalEquations for DenseNormalEquations {
    fn cost(&self) -> f64 {
        self.cost
    }

    fn gradient_amax(&self) -> f64 {
        self.jtr.amax()
    }

    fn max_diagonal(&self) -> f64 {
        self.jtj.diagonal().max()
    }

    fn solve_damped(&self, damping: f64, floor: f64) -> Option<DVector<f64>> {
        let mut a = self.jtj.clone();
        for i in 0..a.nrows() {
            a[(i, i)] += damping * self.jtj[(i, i)].max(floor);
        }
        Some(-a.cholesky()?.solve(&self.jtr))
    }
}

/// A least-squares problem Σᵢ ρ(|rᵢ(x)|²) over a state that moves by retraction.
pub trait LeastSquares {
    /// The point being optimised.
    type State: Clone;
    /// How the problem holds its normal equations.
    type Normal: NormalEquations;

    /// Number of parameters of a step.
    fn dimension(&self, state: &Self::State) -> usize;

    /// The cost at `state`; `None` where it is undefined (a residual has no answer).
    fn cost(&self, state: &Self::State) -> Option<f64>;

    /// Gauss–Newton normal equations at `state`: JᵀWJ, JᵀWr and the cost, with J = ∂r/∂δ at
    /// δ = 0 and W the robust weights. `None` where a residual has no answer.
    fn normal_equations(&self, state: &Self::State) -> Option<Self::Normal>;

    /// The state moved by `delta` (a step in the problem's local parameters).
    fn retract(&self, state: &Self::State, delta: &DVector<f64>) -> Self::State;
}

/// What the solver reports after each step it tries, for progress displays.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmIteration {
    /// Steps tried so far (accepted and rejected).
    pub iteration: usize,
    /// The cost at the current state.
    pub cost: f64,
    /// Whether this step was accepted.
    pub accepted: bool,
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
    /// Initial damping λ (dimensionless: it scales each parameter's own diagonal entry of JᵀWJ,
    /// Marquardt's form, so the steps do not depend on the parameters' units).
    pub initial_damping: f64,
}

impl Default for LmOptions {
    fn default() -> Self {
        Self {
            max_iterations: 200,
            cost_tolerance: 1e-10,
            gradient_tolerance: 1e-18,
            initial_damping: 1e-4,
        }
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
        matches!(
            self,
            Self::CostConverged | Self::GradientConverged | Self::NoDescent
        )
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

/// Minimises `problem` from `start`. Returns the final state, the report, and the normal
/// equations at the final state (for covariances).
pub fn levenberg_marquardt<P: LeastSquares>(
    problem: &P,
    start: P::State,
    options: &LmOptions,
) -> (P::State, LmReport, Option<P::Normal>) {
    levenberg_marquardt_observed(problem, start, options, &mut |_| {})
}

/// [`levenberg_marquardt`], calling `observer` after every step tried.
pub fn levenberg_marquardt_observed<P: LeastSquares>(
    problem: &P,
    start: P::State,
    options: &LmOptions,
    observer: &mut dyn FnMut(&LmIteration),
) -> (P::State, LmReport, Option<P::Normal>) {
    let mut state = start;
    let Some(mut normal) = problem.normal_equations(&state) else {
        let report = LmReport {
            iterations: 0,
            initial_cost: f64::INFINITY,
            final_cost: f64::INFINITY,
            termination: Termination::InvalidStart,
        };
        return (state, report, None);
    };
    let mut cost = normal.cost();
    let initial_cost = cost;
    let max_diagonal = normal.max_diagonal();
    // λ multiplies diag(JᵀWJ), which carries the units: λ itself is a pure number. (Scaling it by
    // the largest diagonal entry too made it depend on the units of the parameters — ~1e4 for a
    // target pose in metres seen at 0.6 m — so a start near the optimum took a few steps shrunk
    // ten-thousandfold, whose tiny gains stopped the solver by the cost tolerance there.)
    let mut damping = options.initial_damping;
    let mut termination = Termination::MaxIterations;
    let mut iterations = 0;
    while iterations < options.max_iterations {
        if normal.gradient_amax() <= options.gradient_tolerance {
            termination = Termination::GradientConverged;
            break;
        }
        iterations += 1;
        // (JᵀJ + λ·diag(JᵀJ)) δ = −Jᵀr, with a floor on the diagonal for parameters that the
        // data barely see.
        let Some(delta) = normal.solve_damped(damping, 1e-12 * max_diagonal) else {
            damping *= 10.0;
            observer(&LmIteration {
                iteration: iterations,
                cost,
                accepted: false,
            });
            continue;
        };
        let candidate = problem.retract(&state, &delta);
        match problem.cost(&candidate) {
            Some(new_cost) if new_cost < cost => {
                let improvement = (cost - new_cost) / cost.max(f64::MIN_POSITIVE);
                state = candidate;
                damping = (damping / 3.0).max(1e-15);
                match problem.normal_equations(&state) {
                    Some(n) => {
                        cost = n.cost();
                        normal = n;
                    }
                    None => {
                        termination = Termination::NoDescent;
                        break;
                    }
                }
                observer(&LmIteration {
                    iteration: iterations,
                    cost,
                    accepted: true,
                });
                if improvement < options.cost_tolerance {
                    termination = Termination::CostConverged;
                    break;
                }
            }
            _ => {
                observer(&LmIteration {
                    iteration: iterations,
                    cost,
                    accepted: false,
                });
                damping *= 4.0;
                if damping > 1e16 {
                    termination = Termination::NoDescent;
                    break;
                }
            }
        }
    }
    let report = LmReport {
        iterations,
        initial_cost,
        final_cost: cost,
        termination,
    };
    (state, report, Some(normal))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rosenbrock as least squares: r = (10 (y − x²), 1 − x), minimum 0 at (1, 1).
    struct Rosenbrock;

    impl LeastSquares for Rosenbrock {
        type State = DVector<f64>;
        type Normal = DenseNormalEquations;
        fn dimension(&self, _: &Self::State) -> usize {
            2
        }
        fn cost(&self, s: &Self::State) -> Option<f64> {
            Some((10.0 * (s[1] - s[0] * s[0])).powi(2) + (1.0 - s[0]).powi(2))
        }
        fn normal_equations(&self, s: &Self::State) -> Option<DenseNormalEquations> {
            let r = DVector::from_vec(vec![10.0 * (s[1] - s[0] * s[0]), 1.0 - s[0]]);
            let j = DMatrix::from_row_slice(2, 2, &[-20.0 * s[0], 10.0, -1.0, 0.0]);
            Some(DenseNormalEquations {
                jtj: j.transpose() * &j,
                jtr: j.transpose() * &r,
                cost: r.norm_squared(),
            })
        }
        fn retract(&self, s: &Self::State, delta: &DVector<f64>) -> Self::State {
            s + delta
        }
    }

    /// Linear least squares r = A x − b whose two parameters have units 10⁴ apart (as a pose in
    /// metres beside an axis in radians), with noise: the optimum keeps a cost of order 1.
    struct Scaled {
        a: DMatrix<f64>,
        b: DVector<f64>,
    }

    impl LeastSquares for Scaled {
        type State = DVector<f64>;
        type Normal = DenseNormalEquations;
        fn dimension(&self, _: &Self::State) -> usize {
            2
        }
        fn cost(&self, s: &Self::State) -> Option<f64> {
            Some((&self.a * s - &self.b).norm_squared())
        }
        fn normal_equations(&self, s: &Self::State) -> Option<DenseNormalEquations> {
            let r = &self.a * s - &self.b;
            Some(DenseNormalEquations {
                jtj: self.a.transpose() * &self.a,
                jtr: self.a.transpose() * &r,
                cost: r.norm_squared(),
            })
        }
        fn retract(&self, s: &Self::State, delta: &DVector<f64>) -> Self::State {
            s + delta
        }
    }

    #[test]
    fn a_start_near_the_optimum_reaches_it_whatever_the_units() {
        let a = DMatrix::from_row_slice(4, 2, &[1e4, 1.0, 2e4, -1.0, 0.0, 2.0, -1e4, 0.5]);
        let b = DVector::from_vec(vec![1.0, -0.7, 0.4, 0.9]);
        let optimum = (a.transpose() * &a)
            .cholesky()
            .unwrap()
            .solve(&(a.transpose() * &b));
        let problem = Scaled { a, b };
        let best = problem.cost(&optimum).unwrap();
        // A start whose cost exceeds the optimum's by 1e-7 of it, off along the small-scale
        // parameter: the excess is the ML estimate's whole move from a start at the truth.
        let column = problem.a.column(1).norm();
        let offset = (1e-7 * best).sqrt() / column;
        let start = &optimum + DVector::from_vec(vec![0.0, offset]);
        let (end, report, _) = levenberg_marquardt(&problem, start, &LmOptions::default());
        assert!(report.termination.converged(), "{report:?}");
        // With λ scaled by the largest diagonal (≈ 6e8) as well, the first steps were shrunk
        // ~1e5-fold, gained less than the cost tolerance, and the solver stopped at the start.
        assert!(
            (end[1] - optimum[1]).abs() < 1e-3 * offset,
            "ended {:e} from the optimum, started {offset:e} from it",
            (end[1] - optimum[1]).abs()
        );
    }

    #[test]
    fn solves_rosenbrock_and_says_why_it_stopped() {
        let start = DVector::from_vec(vec![-1.2, 1.0]);
        let (end, report, _) = levenberg_marquardt(&Rosenbrock, start, &LmOptions::default());
        assert!(
            (end[0] - 1.0).abs() < 1e-10 && (end[1] - 1.0).abs() < 1e-10,
            "{end}"
        );
        assert!(report.termination.converged(), "{report:?}");
        assert!(report.final_cost < 1e-20 && report.initial_cost > 1.0);
    }
}
