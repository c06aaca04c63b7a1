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
    /// J_gᵀWr over the block's residuals: its share of b_g (for the covariance from the blocks'
    /// scatter, [`BlockNormalEquations::clustered_covariance`]).
    pub global_gradient: DVector<f64>,
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
    /// The diagonal a prior on the globals added to U (zeros without one): the information that
    /// comes from no block.
    pub prior_information: DVector<f64>,
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

    /// The same normal equations over the globals `keep` only (in that order), the others held
    /// where they are.
    pub fn restricted(&self, keep: &[usize]) -> Self {
        Self {
            global: self.global.select_rows(keep).select_columns(keep),
            global_gradient: self.global_gradient.select_rows(keep),
            blocks: self
                .blocks
                .iter()
                .map(|b| LocalBlock {
                    local: b.local,
                    coupling: b.coupling.select_rows(keep),
                    gradient: b.gradient,
                    global_gradient: b.global_gradient.select_rows(keep),
                })
                .collect(),
            cost: self.cost,
            prior_information: self.prior_information.select_rows(keep),
        }
    }

    /// Covariance of the global parameters from how the blocks scatter, not from a residual
    /// variance (the cluster-robust "sandwich" over blocks, with views as the clusters):
    /// S⁻¹ M S⁻¹ with S the undamped Schur complement, M = B/(B−1) Σ_b s_b s_bᵀ + σ² P, where
    /// s_b = g_b − W_b V_b⁻¹ b_b is block b's score on the globals with its own local parameters
    /// eliminated, B the number of blocks and P [`prior_information`](Self::prior_information)
    /// at the residual variance `sigma2` (a prior is not data: its terms keep their model
    /// variance). Where the errors are independent with one variance this agrees with
    /// `sigma2` × [`global_covariance`](Self::global_covariance) on average, each variance
    /// within a relative standard error of about √(2/(B_i − 1)); where a view's corners err
    /// together (blur, a lens or board a little off) or some views are noisier than others, it
    /// is larger, and that one is right. Evaluated at the result, where Σ s_b = 0 without a
    /// prior. Also returns B_i per global: the blocks whose score on it is not zero (a camera's
    /// extrinsics are informed by the views that camera saw only). `None` with fewer than two
    /// blocks or a singular system.
    pub fn clustered_covariance(&self, sigma2: f64) -> Option<(DMatrix<f64>, Vec<usize>)> {
        let blocks = self.blocks.len();
        if blocks < 2 {
            return None;
        }
        let mut meat = DMatrix::from_diagonal(&(&self.prior_information * sigma2));
        let mut informing = vec![0; self.globals()];
        let scale = blocks as f64 / (blocks - 1) as f64;
        for block in &self.blocks {
            let factor = block.local.cholesky()?;
            let score = &block.global_gradient - &block.coupling * factor.solve(&block.gradient);
            for (count, s) in informing.iter_mut().zip(score.iter()) {
                *count += usize::from(*s != 0.0);
            }
            meat.ger(scale, &score, &score, 1.0);
        }
        let inverse = self.global_covariance()?;
        Some((&inverse * meat * &inverse, informing))
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
                global_gradient: jtr.rows(0, globals).into_owned(),
            });
        }
        Self {
            global,
            global_gradient,
            blocks,
            cost,
            prior_information: DVector::zeros(globals),
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
        let (j, r) = random_jacobian(globals, views, rows_per_view, seed);
        let dense = DenseNormalEquations {
            jtj: j.transpose() * &j,
            jtr: j.transpose() * &r,
            cost: r.norm_squared(),
        };
        (block_normal(&j, &r, globals, rows_per_view), dense)
    }

    /// The J and r of [`random_problem`].
    fn random_jacobian(
        globals: usize,
        views: usize,
        rows_per_view: usize,
        seed: u64,
    ) -> (DMatrix<f64>, DVector<f64>) {
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
        (j, r)
    }

    /// The block normal equations of a J whose rows are views of `rows_per_view` rows each.
    fn block_normal(
        j: &DMatrix<f64>,
        r: &DVector<f64>,
        globals: usize,
        rows_per_view: usize,
    ) -> BlockNormalEquations {
        let views = j.nrows() / rows_per_view;
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
                    global_gradient: jg.transpose() * rv,
                }
            })
            .collect();
        BlockNormalEquations {
            global: jg.transpose() * jg,
            global_gradient: jg.transpose() * r,
            blocks,
            cost: r.norm_squared(),
            prior_information: DVector::zeros(globals),
        }
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
            global_gradient: DVector::zeros(3),
        };
        assert!(block.solve_damped(0.0, 0.0).is_none());
        assert!(block.global_covariance().is_none());
        // Damping with a positive floor makes it definite again.
        assert!(block.solve_damped(1e-3, 1.0).is_some());
    }

    /// Monte Carlo of a linear bundle (G globals, a pose per view): the least-squares result's
    /// error is −(JᵀJ)⁻¹Jᵀe exactly, so the covariance of the globals over many draws of the
    /// errors e is the truth the estimates are held to. Each view's errors are e_v = s_v·z
    /// (z standard normal) plus, with `correlated`, J_g,v·u_v (u_v ~ N(0, 0.5²) per view: its
    /// corners err together as a shift of the globals would move them) and scales s_v from 0.3
    /// to 3 (some views noisier than others); otherwise s_v = 1. Returns, per global, the Monte Carlo
    /// variance, the mean of the clustered estimate over the draws and the mean of the
    /// classical σ̂²(JᵀJ)⁻¹.
    fn covariances_over_draws(correlated: bool, seed: u64) -> Vec<(f64, f64, f64)> {
        let (globals, views, rows_per_view, draws) = (3, 30, 16, 1500);
        let (j, _) = random_jacobian(globals, views, rows_per_view, seed);
        let mut rng = Rng::new(seed + 100);
        let rows = views * rows_per_view;
        let n = j.ncols();
        let jtj = j.transpose() * &j;
        let inverse = jtj.cholesky().unwrap().inverse();
        let projection = &inverse * j.transpose();
        let scales: Vec<f64> = (0..views)
            .map(|_| {
                if correlated {
                    0.3 * 10f64.powf(rng.uniform())
                } else {
                    1.0
                }
            })
            .collect();
        let mut sum_sq = vec![0.0; globals];
        let mut clustered = vec![0.0; globals];
        let mut classical = vec![0.0; globals];
        for _ in 0..draws {
            let mut e = DVector::zeros(rows);
            for (v, scale) in scales.iter().enumerate() {
                let mut ev = DVector::from_fn(rows_per_view, |_, _| rng.normal() * scale);
                if correlated {
                    // The view's corners err together, as a shift of the globals would move them.
                    let shift = DVector::from_fn(globals, |_, _| 0.5 * rng.normal());
                    ev += j.view((v * rows_per_view, 0), (rows_per_view, globals)) * shift;
                }
                e.rows_mut(v * rows_per_view, rows_per_view).copy_from(&ev);
            }
            let delta = -(&projection * &e);
            for g in 0..globals {
                sum_sq[g] += delta[g] * delta[g];
            }
            // The residuals at the result and the normal equations there.
            let r = &e + &j * &delta;
            let normal = block_normal(&j, &r, globals, rows_per_view);
            let sigma2 = r.norm_squared() / (rows - n) as f64;
            let (c, _) = normal.clustered_covariance(sigma2).unwrap();
            let a = normal.global_covariance().unwrap() * sigma2;
            for g in 0..globals {
                clustered[g] += c[(g, g)] / draws as f64;
                classical[g] += a[(g, g)] / draws as f64;
            }
        }
        (0..globals)
            .map(|g| (sum_sq[g] / draws as f64, clustered[g], classical[g]))
            .collect()
    }

    #[test]
    fn the_clustered_covariance_is_the_spread_of_results_when_a_views_errors_go_together() {
        for seed in [11, 12] {
            for (g, (truth, clustered, classical)) in
                covariances_over_draws(true, seed).into_iter().enumerate()
            {
                let ratio = clustered / truth;
                assert!(
                    (0.8..1.2).contains(&ratio),
                    "seed {seed}, global {g}: clustered variance {clustered:e} against the Monte Carlo's {truth:e} (×{ratio:.3})"
                );
                // The classical one misses it: this case tells the two apart.
                assert!(
                    classical / truth < 0.7 || classical / truth > 1.4,
                    "seed {seed}, global {g}: σ̂²(JᵀJ)⁻¹ {classical:e} against {truth:e}: no case"
                );
            }
        }
    }

    #[test]
    fn with_independent_errors_the_clustered_covariance_is_the_classical_one() {
        for (g, (truth, clustered, classical)) in
            covariances_over_draws(false, 13).into_iter().enumerate()
        {
            for (name, estimate) in [("clustered", clustered), ("classical", classical)] {
                let ratio = estimate / truth;
                assert!(
                    (0.85..1.15).contains(&ratio),
                    "global {g}: {name} variance {estimate:e} against the Monte Carlo's {truth:e} (×{ratio:.3})"
                );
            }
        }
    }

    #[test]
    fn a_prior_keeps_its_model_variance_in_the_clustered_covariance() {
        // No data scatter at all (every block's score zero): what is left is the prior's term,
        // S⁻¹ σ² P S⁻¹.
        let (mut normal, _) = random_problem(3, 5, 20, 14);
        for block in &mut normal.blocks {
            block.gradient = Vector6::zeros();
            block.global_gradient = DVector::zeros(3);
        }
        normal.prior_information = DVector::from_vec(vec![4e6, 0.0, 9e6]);
        for g in 0..3 {
            normal.global[(g, g)] += normal.prior_information[g];
        }
        let inverse = normal.global_covariance().unwrap();
        let expected =
            &inverse * DMatrix::from_diagonal(&(&normal.prior_information * 0.25)) * &inverse;
        let (clustered, informing) = normal.clustered_covariance(0.25).unwrap();
        assert_eq!(informing, vec![0; 3], "no block's score is anything");
        assert!(relative(&clustered, &expected) < 1e-9);
    }
}
