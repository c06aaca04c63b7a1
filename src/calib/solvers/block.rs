//! The normal equations of a bundle adjustment: G global parameters shared by every residual and
//! N local parameters per block, which only that block's residuals depend on, solved by the Schur
//! complement on the blocks ([`BlockNormalEquations`]): one pose of six parameters per view in the
//! bundle ([`PoseBlock`]), one scene point of three coordinates per track in the targetless fit
//! ([`PointNormalEquations`]); each block's share from its residuals and their Jacobian
//! ([`view_share`]), under an optional Huber loss ([`robust`]).
//!
//! Pose step parameters: ω (rotation vector, rad) and τ (translation, m), with
//! target pose ← (τ, exp(ω)) · pose ([`move_pose`]).

use nalgebra::{
    Cholesky, Const, DMatrix, DVector, Dyn, Isometry3, OMatrix, SMatrix, SVector, Translation3,
    UnitQuaternion, Vector2, Vector3,
};

use crate::calib::solvers::lm::NormalEquations;

/// Parameters of one target pose in a step: ω (rad), τ (m).
pub const POSE_PARAMETERS: usize = 6;

/// Parameters of one scene point in a step: x, y, z (m).
pub const POINT_PARAMETERS: usize = 3;

/// One block's share of the normal equations (a view's pose, a track's point): its N × N block,
/// its coupling to the global parameters and its gradient.
#[derive(Debug, Clone, PartialEq)]
pub struct LocalBlock<const N: usize> {
    /// J_vᵀWJ_v over the block's N local parameters.
    pub local: SMatrix<f64, N, N>,
    /// J_gᵀWJ_v: global parameters (rows) × the block's local parameters.
    pub coupling: OMatrix<f64, Dyn, Const<N>>,
    /// J_vᵀWr over the block's local parameters.
    pub gradient: SVector<f64, N>,
}

/// One view's share of the bundle's normal equations: its pose block (6 × 6).
pub type PoseBlock = LocalBlock<POSE_PARAMETERS>;

/// One scene point's share of the targetless fit's normal equations: its point block (3 × 3).
pub type PointBlock = LocalBlock<POINT_PARAMETERS>;

/// Normal equations of a bundle with G global parameters g and V blocks p_v of N local
/// parameters each (poses by default):
///
/// ```text
/// ⎡ U    W₁  …  W_V ⎤ ⎡δg ⎤     ⎡b_g⎤
/// ⎢ W₁ᵀ  V₁         ⎥ ⎢δp₁⎥ = − ⎢b₁ ⎥
/// ⎢ ⋮        ⋱      ⎥ ⎢ ⋮ ⎥     ⎢ ⋮ ⎥
/// ⎣ W_Vᵀ        V_V ⎦ ⎣δp_V⎦     ⎣b_V⎦
/// ```
///
/// No residual depends on two blocks (two poses, two points), so the local part is block diagonal
/// and is eliminated block by block (Schur complement on the blocks):
/// S = U − Σ W_v V_v⁻¹ W_vᵀ, S δg = −(b_g − Σ W_v V_v⁻¹ b_v), then δp_v = −V_v⁻¹ (b_v + W_vᵀ δg).
/// Memory and time are linear in V (a dense solve is cubic). The step's order is δg, then
/// δp₁ … δp_V.
#[derive(Debug, Clone, PartialEq)]
pub struct BlockNormalEquations<const N: usize = POSE_PARAMETERS> {
    /// U = J_gᵀWJ_g (G × G, symmetric).
    pub global: DMatrix<f64>,
    /// b_g = J_gᵀWr.
    pub global_gradient: DVector<f64>,
    /// The local blocks, in step order (views for poses, tracks for points).
    pub blocks: Vec<LocalBlock<N>>,
    /// Σ ρ(|r|²).
    pub cost: f64,
}

/// The targetless fit's normal equations: G global parameters and P points, a 3 × 3 block per
/// point; the step's order is δg, then δp₁ … δp_P.
pub type PointNormalEquations = BlockNormalEquations<POINT_PARAMETERS>;

/// The reduced system: (S, its right-hand side, the factors of the damped local blocks).
type Reduced<const N: usize> = (DMatrix<f64>, DVector<f64>, Vec<Cholesky<f64, Const<N>>>);

impl<const N: usize> BlockNormalEquations<N> {
    /// Number of global parameters G.
    pub fn globals(&self) -> usize {
        self.global.nrows()
    }

    /// Parameters of a step: G + N·V.
    pub fn dimension(&self) -> usize {
        self.globals() + N * self.blocks.len()
    }

    /// The Schur complement on the blocks of the damped system (each diagonal entry a grown by
    /// `damping`·max(a, `floor`)): (S, its right-hand side b_g − Σ W_v V_v⁻¹ b_v, the factors of
    /// the damped V_v). `None` when a local block is not positive definite.
    fn reduce(&self, damping: f64, floor: f64) -> Option<Reduced<N>> {
        let mut schur = self.global.clone();
        for i in 0..self.globals() {
            schur[(i, i)] += damping * self.global[(i, i)].max(floor);
        }
        let mut rhs = self.global_gradient.clone();
        let mut factors = Vec::with_capacity(self.blocks.len());
        for block in &self.blocks {
            let mut local = block.local;
            for i in 0..N {
                local[(i, i)] += damping * block.local[(i, i)].max(floor);
            }
            let factor = local.cholesky()?;
            // V⁻¹ W_vᵀ (N × G) and V⁻¹ b_v.
            let solved = factor.solve(&block.coupling.transpose());
            schur -= &block.coupling * &solved;
            rhs -= &block.coupling * factor.solve(&block.gradient);
            factors.push(factor);
        }
        Some((schur, rhs, factors))
    }

    /// Information of the global parameters (unit residual variance): the Schur complement of
    /// the undamped system, whose inverse is [`global_covariance`](Self::global_covariance).
    /// `None` when a local block is singular.
    pub fn global_information(&self) -> Option<DMatrix<f64>> {
        Some(self.reduce(0.0, 0.0)?.0)
    }

    /// Covariance of the global parameters (unit residual variance), the G × G block of
    /// (JᵀWJ)⁻¹: the inverse of the Schur complement of the undamped system. `None` when the
    /// system is singular.
    pub fn global_covariance(&self) -> Option<DMatrix<f64>> {
        let (schur, _, _) = self.reduce(0.0, 0.0)?;
        Some(schur.cholesky()?.inverse())
    }
}

impl<const N: usize> NormalEquations for BlockNormalEquations<N> {
    fn cost(&self) -> f64 {
        self.cost
    }

    fn gradient_amax(&self) -> f64 {
        self.blocks
            .iter()
            .map(|b| b.gradient.amax())
            .fold(self.global_gradient.amax(), f64::max)
    }

    fn max_diagonal(&self) -> f64 {
        self.blocks
            .iter()
            .map(|b| b.local.diagonal().max())
            .fold(self.global.diagonal().max(), f64::max)
    }

    fn solve_damped(&self, damping: f64, floor: f64) -> Option<DVector<f64>> {
        let (schur, rhs, factors) = self.reduce(damping, floor)?;
        let global_step = -schur.cholesky()?.solve(&rhs);
        let g = self.globals();
        let mut step = DVector::zeros(self.dimension());
        step.rows_mut(0, g).copy_from(&global_step);
        for (v, (block, factor)) in self.blocks.iter().zip(&factors).enumerate() {
            let local_step =
                -factor.solve(&(block.gradient + block.coupling.transpose() * &global_step));
            step.fixed_rows_mut::<N>(g + N * v).copy_from(&local_step);
        }
        Some(step)
    }
}

/// (cost contribution, weight) of a residual of length² `r2` under an optional Huber threshold
/// `huber`: r² and 1 inside the threshold k, 2k|r| − k² and k/|r| outside.
pub fn robust(huber: Option<f64>, r2: f64) -> (f64, f64) {
    match huber {
        Some(k) if r2 > k * k => {
            let r = r2.sqrt();
            (2.0 * k * r - k * k, k / r)
        }
        _ => (r2, 1.0),
    }
}

/// One view's share of the normal equations (JᵀWJ, JᵀWr, Σρ) from its residuals `base` and its
/// Jacobian, `jacobian[p * base.len() + i] = ∂r_i/∂(parameter p)` over `columns` parameters
/// (globals first, then the view's pose). Columns that are zero in a row add nothing and are
/// skipped (a global that moves another camera).
pub fn view_share(
    base: &[Vector2<f64>],
    jacobian: &[Vector2<f64>],
    columns: usize,
    huber: Option<f64>,
) -> (DMatrix<f64>, DVector<f64>, f64) {
    let count = base.len();
    let mut jtj = DMatrix::zeros(columns, columns);
    let mut jtr = DVector::zeros(columns);
    let mut cost = 0.0;
    for (i, r) in base.iter().enumerate() {
        let (contribution, weight) = robust(huber, r.norm_squared());
        cost += contribution;
        for a in 0..columns {
            let ja = jacobian[a * count + i];
            if ja == Vector2::zeros() {
                continue;
            }
            jtr[a] += weight * ja.dot(r);
            for b in a..columns {
                jtj[(a, b)] += weight * ja.dot(&jacobian[b * count + i]);
            }
        }
    }
    jtj.fill_lower_triangle_with_upper_triangle();
    (jtj, jtr, cost)
}

impl<const N: usize> BlockNormalEquations<N> {
    /// The normal equations of `globals` global parameters from every block's share
    /// ([`view_share`] over the globals, then the block's N local parameters): the globals'
    /// blocks summed, each view's pose block (each track's point block) kept.
    pub fn from_shares(globals: usize, shares: Vec<(DMatrix<f64>, DVector<f64>, f64)>) -> Self {
        let mut global = DMatrix::zeros(globals, globals);
        let mut global_gradient = DVector::zeros(globals);
        let mut cost = 0.0;
        let mut blocks = Vec::with_capacity(shares.len());
        for (jtj, jtr, share_cost) in shares {
            global += jtj.view((0, 0), (globals, globals));
            global_gradient += jtr.rows(0, globals);
            cost += share_cost;
            blocks.push(LocalBlock {
                local: jtj.fixed_view::<N, N>(globals, globals).into_owned(),
                coupling: jtj
                    .generic_view((0, globals), (Dyn(globals), Const::<N>))
                    .into_owned(),
                gradient: jtr.fixed_rows::<N>(globals).into_owned(),
            });
        }
        Self {
            global,
            global_gradient,
            blocks,
            cost,
        }
    }
}

/// A target pose moved by a step (ω rotation vector, τ translation): (τ, exp ω) · pose.
pub fn move_pose(pose: &Isometry3<f64>, delta: &[f64]) -> Isometry3<f64> {
    let rotation = UnitQuaternion::from_scaled_axis(Vector3::new(delta[0], delta[1], delta[2]));
    let translation = Translation3::new(delta[3], delta[4], delta[5]);
    Isometry3::from_parts(translation, rotation) * pose
}

#[cfg(test)]
mod tests {
    use nalgebra::{Matrix6, U6, Vector6};

    use super::*;
    use crate::base::Rng;
    use crate::calib::solvers::lm::DenseNormalEquations;

    /// A random block-sparse Jacobian (each residual row depends on the G globals and one view's
    /// pose), its block normal equations, and the dense JᵀJ, Jᵀr of the same J built directly.
    fn random_problem(
        globals: usize,
        views: usize,
        rows_per_view: usize,
        seed: u64,
    ) -> (BlockNormalEquations, DenseNormalEquations) {
        let mut rng = Rng::new(seed);
        let n = globals + POSE_PARAMETERS * views;
        let rows = views * rows_per_view;
        let mut j = DMatrix::zeros(rows, n);
        let mut r = DVector::zeros(rows);
        for v in 0..views {
            for i in 0..rows_per_view {
                let row = v * rows_per_view + i;
                for c in 0..globals {
                    j[(row, c)] = rng.normal();
                }
                for c in 0..POSE_PARAMETERS {
                    // Pose columns of a different scale, as in the bundle (radians vs metres).
                    j[(row, globals + POSE_PARAMETERS * v + c)] =
                        rng.normal() * if c < 3 { 300.0 } else { 2000.0 };
                }
                r[row] = rng.normal();
            }
        }
        let dense = DenseNormalEquations {
            jtj: j.transpose() * &j,
            jtr: j.transpose() * &r,
            cost: r.norm_squared(),
        };
        let jg = j.columns(0, globals);
        let blocks = (0..views)
            .map(|v| {
                let rows = j.rows(v * rows_per_view, rows_per_view);
                let jg = rows.columns(0, globals);
                let jp = rows.fixed_columns::<POSE_PARAMETERS>(globals + POSE_PARAMETERS * v);
                let rv = r.rows(v * rows_per_view, rows_per_view);
                PoseBlock {
                    local: jp.transpose() * jp,
                    coupling: jg.transpose() * jp,
                    gradient: jp.transpose() * rv,
                }
            })
            .collect();
        let block = BlockNormalEquations {
            global: jg.transpose() * jg,
            global_gradient: jg.transpose() * &r,
            blocks,
            cost: r.norm_squared(),
        };
        (block, dense)
    }

    fn relative(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
        (a - b).norm() / b.norm()
    }

    #[test]
    fn schur_step_and_covariance_equal_the_dense_solve() {
        // G = 3 (axis, air layer) as today and G = 5 (more globals, as extrinsics will add).
        for (globals, views, seed) in [(3, 7, 1), (5, 4, 2), (3, 1, 3)] {
            let (block, dense) = random_problem(globals, views, 20, seed);
            assert_eq!(block.dimension(), dense.jtj.nrows());
            assert_eq!(block.max_diagonal(), dense.max_diagonal());
            assert!(
                (block.gradient_amax() - dense.gradient_amax()).abs()
                    <= 1e-12 * dense.gradient_amax()
            );
            for (damping, floor) in [(0.0, 0.0), (1e-4, 1e-12), (10.0, 1e3)] {
                let step = block.solve_damped(damping, floor).unwrap();
                let reference = dense.solve_damped(damping, floor).unwrap();
                let error = (&step - &reference).norm() / reference.norm();
                assert!(
                    error < 1e-9,
                    "G {globals}, damping {damping}: step relative error {error:e}"
                );
            }
            // The global block of the inverse of the full JᵀJ.
            let inverse = dense.jtj.clone().cholesky().unwrap().inverse();
            let reference = inverse.view((0, 0), (globals, globals)).into_owned();
            let covariance = block.global_covariance().unwrap();
            let error = relative(&covariance, &reference);
            assert!(
                error < 1e-9,
                "G {globals}: covariance relative error {error:e}"
            );
        }
    }

    #[test]
    fn a_singular_pose_block_is_refused() {
        let (mut block, _) = random_problem(3, 3, 20, 4);
        block.blocks[1] = PoseBlock {
            local: Matrix6::zeros(),
            coupling: OMatrix::<f64, Dyn, U6>::zeros(3),
            gradient: Vector6::zeros(),
        };
        assert!(block.solve_damped(0.0, 0.0).is_none());
        assert!(block.global_covariance().is_none());
        // Damping with a positive floor makes it definite again.
        assert!(block.solve_damped(1e-3, 1.0).is_some());
    }
}
