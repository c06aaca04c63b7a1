//! The maximum-likelihood refinement: Levenberg–Marquardt over the system axis, the air layer and
//! every board pose, minimising the reprojection error of the board corners in both cameras
//! (optionally under a Huber loss).
//!
//! Step parameters, in order: (δ₁, δ₂) the axis moved in its tangent plane
//! ([`tangent_step`]), δd the air layer (m), then for each view ω (rotation vector, rad) and τ
//! (translation, m) with master_from_board ← (τ, exp(ω)) · master_from_board.

use nalgebra::{
    Cholesky, DMatrix, DVector, Dyn, Isometry3, Matrix6, OMatrix, Translation3, U6, Unit,
    UnitQuaternion, Vector2, Vector3, Vector6,
};
use rayon::prelude::*;

use crate::calib::problem::data::{Candidate, StereoData};
use crate::calib::solvers::lm::{LeastSquares, NormalEquations};
use crate::calib::solvers::search::tangent_step;
use crate::engine::cpu::lanes;
use crate::model::RefractiveCamera;

/// The interface and board poses being refined.
#[derive(Debug, Clone, PartialEq)]
pub struct BundleState {
    /// System axis and air layer.
    pub candidate: Candidate,
    /// X_master = R·X_board + t per view.
    pub poses: Vec<Isometry3<f64>>,
}

/// Parameters of the interface in a step: δ₁, δ₂, δd. These are the bundle's global parameters
/// (shared by every residual); [`BlockNormalEquations`] takes their number as a value, so more
/// can join them (extrinsics, layer thicknesses).
pub const INTERFACE_PARAMETERS: usize = 3;
/// Parameters of one board pose in a step: ω (rad), τ (m).
pub const POSE_PARAMETERS: usize = 6;

/// One view's share of the normal equations: its pose block, its coupling to the global
/// parameters and its pose gradient.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseBlock {
    /// J_vᵀWJ_v over the view's six pose parameters.
    pub pose: Matrix6<f64>,
    /// J_gᵀWJ_v: global parameters (rows) × the view's pose parameters.
    pub coupling: OMatrix<f64, Dyn, U6>,
    /// J_vᵀWr over the view's pose parameters.
    pub gradient: Vector6<f64>,
}

/// Normal equations of a bundle with G global parameters g and V poses p_v:
///
/// ```text
/// ⎡ U    W₁  …  W_V ⎤ ⎡δg ⎤     ⎡b_g⎤
/// ⎢ W₁ᵀ  V₁         ⎥ ⎢δp₁⎥ = − ⎢b₁ ⎥
/// ⎢ ⋮        ⋱      ⎥ ⎢ ⋮ ⎥     ⎢ ⋮ ⎥
/// ⎣ W_Vᵀ        V_V ⎦ ⎣δp_V⎦     ⎣b_V⎦
/// ```
///
/// No residual depends on two poses, so the pose part is block diagonal and is eliminated view by
/// view (Schur complement on the poses): S = U − Σ W_v V_v⁻¹ W_vᵀ, S δg = −(b_g − Σ W_v V_v⁻¹ b_v),
/// then δp_v = −V_v⁻¹ (b_v + W_vᵀ δg). Memory and time are linear in V (a dense solve is cubic).
/// The step's order is δg, then δp₁ … δp_V.
#[derive(Debug, Clone, PartialEq)]
pub struct BlockNormalEquations {
    /// U = J_gᵀWJ_g (G × G, symmetric).
    pub global: DMatrix<f64>,
    /// b_g = J_gᵀWr.
    pub global_gradient: DVector<f64>,
    /// The poses' blocks, in view order.
    pub views: Vec<PoseBlock>,
    /// Σ ρ(|r|²).
    pub cost: f64,
}

/// The reduced system: (S, its right-hand side, the factors of the damped pose blocks).
type Reduced = (DMatrix<f64>, DVector<f64>, Vec<Cholesky<f64, U6>>);

impl BlockNormalEquations {
    /// Number of global parameters G.
    pub fn globals(&self) -> usize {
        self.global.nrows()
    }

    /// Parameters of a step: G + 6V.
    pub fn dimension(&self) -> usize {
        self.globals() + POSE_PARAMETERS * self.views.len()
    }

    /// The Schur complement on the poses of the damped system (each diagonal entry a grown by
    /// `damping`·max(a, `floor`)): (S, its right-hand side b_g − Σ W_v V_v⁻¹ b_v, the factors of
    /// the damped V_v). `None` when a pose block is not positive definite.
    fn reduce(&self, damping: f64, floor: f64) -> Option<Reduced> {
        let mut schur = self.global.clone();
        for i in 0..self.globals() {
            schur[(i, i)] += damping * self.global[(i, i)].max(floor);
        }
        let mut rhs = self.global_gradient.clone();
        let mut factors = Vec::with_capacity(self.views.len());
        for block in &self.views {
            let mut pose = block.pose;
            for i in 0..POSE_PARAMETERS {
                pose[(i, i)] += damping * block.pose[(i, i)].max(floor);
            }
            let factor = pose.cholesky()?;
            // V⁻¹ W_vᵀ (6 × G) and V⁻¹ b_v.
            let solved = factor.solve(&block.coupling.transpose());
            schur -= &block.coupling * &solved;
            rhs -= &block.coupling * factor.solve(&block.gradient);
            factors.push(factor);
        }
        Some((schur, rhs, factors))
    }

    /// Covariance of the global parameters, the G × G block of (JᵀWJ)⁻¹: the inverse of the Schur
    /// complement of the undamped system. `None` when the system is singular.
    pub fn global_covariance(&self) -> Option<DMatrix<f64>> {
        let (schur, _, _) = self.reduce(0.0, 0.0)?;
        Some(schur.cholesky()?.inverse())
    }
}

impl NormalEquations for BlockNormalEquations {
    fn cost(&self) -> f64 {
        self.cost
    }

    fn gradient_amax(&self) -> f64 {
        self.views
            .iter()
            .map(|b| b.gradient.amax())
            .fold(self.global_gradient.amax(), f64::max)
    }

    fn max_diagonal(&self) -> f64 {
        self.views
            .iter()
            .map(|b| b.pose.diagonal().max())
            .fold(self.global.diagonal().max(), f64::max)
    }

    fn solve_damped(&self, damping: f64, floor: f64) -> Option<DVector<f64>> {
        let (schur, rhs, factors) = self.reduce(damping, floor)?;
        let global_step = -schur.cholesky()?.solve(&rhs);
        let g = self.globals();
        let mut step = DVector::zeros(self.dimension());
        step.rows_mut(0, g).copy_from(&global_step);
        for (v, (block, factor)) in self.views.iter().zip(&factors).enumerate() {
            let pose_step =
                -factor.solve(&(block.gradient + block.coupling.transpose() * &global_step));
            step.fixed_rows_mut::<POSE_PARAMETERS>(g + POSE_PARAMETERS * v)
                .copy_from(&pose_step);
        }
        Some(step)
    }
}

/// Central-difference step for every parameter (rad or m): pixels are exact to ~1e-10 px, so the
/// derivatives keep ~8 digits, and the truncation error (h²) is far below that.
const DIFFERENCE_STEP: f64 = 1e-6;

/// The reprojection problem of [`StereoData`].
pub struct Bundle<'a> {
    data: &'a StereoData,
    /// Huber threshold in pixels on each corner's residual length; `None` for plain least squares.
    huber: Option<f64>,
}

impl<'a> Bundle<'a> {
    /// The problem over `data`, with an optional Huber threshold (pixels).
    pub fn new(data: &'a StereoData, huber: Option<f64>) -> Self {
        Self { data, huber }
    }

    /// Residuals (projected − observed, px) of the corners of `view`, left and right, in
    /// `data.corners` order; `None` when one does not project. The view's corners are projected
    /// together, in the lanes of the CPU engine's vector path.
    fn view_residuals(
        &self,
        cameras: &[RefractiveCamera; 2],
        view: usize,
        pose: &Isometry3<f64>,
        out: &mut Vec<Vector2<f64>>,
    ) -> Option<()> {
        let corners = &self.data.corners[self.data.views[view].clone()];
        let points: Vec<[f64; 3]> = corners
            .iter()
            .map(|c| {
                (pose * self.data.board.point_in_board(c.index))
                    .coords
                    .into()
            })
            .collect();
        let [left, right] =
            [&cameras[0], &cameras[1]].map(|camera| lanes::project_all(camera, &points));
        let (left, right) = (left?, right?);
        for ((corner, l), r) in corners.iter().zip(&left).zip(&right) {
            out.push(Vector2::new(l[0], l[1]) - corner.pixels[0].coords);
            out.push(Vector2::new(r[0], r[1]) - corner.pixels[1].coords);
        }
        Some(())
    }

    /// Every residual at `state`, two per corner (left, right); views in parallel.
    pub fn residuals(&self, state: &BundleState) -> Option<Vec<Vector2<f64>>> {
        let cameras = self.data.cameras_behind(&state.candidate)?;
        let per_view: Option<Vec<Vec<Vector2<f64>>>> = state
            .poses
            .par_iter()
            .enumerate()
            .map(|(v, pose)| {
                let mut out = Vec::with_capacity(2 * self.data.views[v].len());
                self.view_residuals(&cameras, v, pose, &mut out)
                    .map(|()| out)
            })
            .collect();
        Some(per_view?.concat())
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

impl BlockNormalEquations {
    /// The normal equations of `globals` global parameters from every view's share
    /// ([`view_share`]): the globals' blocks summed, each view's pose block kept.
    pub fn from_shares(globals: usize, shares: Vec<(DMatrix<f64>, DVector<f64>, f64)>) -> Self {
        let mut global = DMatrix::zeros(globals, globals);
        let mut global_gradient = DVector::zeros(globals);
        let mut cost = 0.0;
        let mut views = Vec::with_capacity(shares.len());
        for (jtj, jtr, share_cost) in shares {
            global += jtj.view((0, 0), (globals, globals));
            global_gradient += jtr.rows(0, globals);
            cost += share_cost;
            views.push(PoseBlock {
                pose: jtj
                    .fixed_view::<POSE_PARAMETERS, POSE_PARAMETERS>(globals, globals)
                    .into_owned(),
                coupling: jtj
                    .generic_view((0, globals), (Dyn(globals), U6))
                    .into_owned(),
                gradient: jtr.fixed_rows::<POSE_PARAMETERS>(globals).into_owned(),
            });
        }
        Self {
            global,
            global_gradient,
            views,
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

fn move_interface(candidate: &Candidate, delta: &[f64]) -> Candidate {
    Candidate {
        normal: tangent_step(&candidate.normal, &Vector2::new(delta[0], delta[1])),
        air_distance: candidate.air_distance + delta[2],
    }
}

impl LeastSquares for Bundle<'_> {
    type State = BundleState;
    type Normal = BlockNormalEquations;

    fn dimension(&self, state: &BundleState) -> usize {
        INTERFACE_PARAMETERS + POSE_PARAMETERS * state.poses.len()
    }

    fn cost(&self, state: &BundleState) -> Option<f64> {
        Some(
            self.residuals(state)?
                .iter()
                .map(|r| robust(self.huber, r.norm_squared()).0)
                .sum(),
        )
    }

    fn normal_equations(&self, state: &BundleState) -> Option<BlockNormalEquations> {
        let data = self.data;
        let globals = INTERFACE_PARAMETERS;
        let cameras = data.cameras_behind(&state.candidate)?;
        // The cameras behind the interface moved by ±h along each global parameter.
        let shifted: Vec<[[RefractiveCamera; 2]; 2]> = (0..globals)
            .map(|p| {
                let mut delta = [0.0; INTERFACE_PARAMETERS];
                delta[p] = DIFFERENCE_STEP;
                let plus = data.cameras_behind(&move_interface(&state.candidate, &delta))?;
                delta[p] = -DIFFERENCE_STEP;
                let minus = data.cameras_behind(&move_interface(&state.candidate, &delta))?;
                Some([plus, minus])
            })
            .collect::<Option<_>>()?;
        // Per view, in parallel: ∂r/∂(globals) and ∂r/∂(pose v) by central differences (only
        // this view's residuals depend on its pose), then its share of JᵀWJ and JᵀWr.
        let shares: Vec<(DMatrix<f64>, DVector<f64>, f64)> = state
            .poses
            .par_iter()
            .enumerate()
            .map(|(v, pose)| {
                let mut base = Vec::with_capacity(2 * data.views[v].len());
                self.view_residuals(&cameras, v, pose, &mut base)?;
                let count = base.len();
                let columns = globals + POSE_PARAMETERS;
                // jacobian[p * count + i] = ∂r_i/∂(parameter p), globals first.
                let mut jacobian = vec![Vector2::zeros(); columns * count];
                let (mut plus, mut minus) = (Vec::with_capacity(count), Vec::with_capacity(count));
                for p in 0..columns {
                    plus.clear();
                    minus.clear();
                    if p < globals {
                        self.view_residuals(&shifted[p][0], v, pose, &mut plus)?;
                        self.view_residuals(&shifted[p][1], v, pose, &mut minus)?;
                    } else {
                        let mut delta = [0.0; POSE_PARAMETERS];
                        delta[p - globals] = DIFFERENCE_STEP;
                        self.view_residuals(&cameras, v, &move_pose(pose, &delta), &mut plus)?;
                        delta[p - globals] = -DIFFERENCE_STEP;
                        self.view_residuals(&cameras, v, &move_pose(pose, &delta), &mut minus)?;
                    }
                    for (i, (plus, minus)) in plus.iter().zip(&minus).enumerate() {
                        jacobian[p * count + i] = (plus - minus) / (2.0 * DIFFERENCE_STEP);
                    }
                }
                Some(view_share(&base, &jacobian, columns, self.huber))
            })
            .collect::<Option<_>>()?;
        Some(BlockNormalEquations::from_shares(globals, shares))
    }

    fn retract(&self, state: &BundleState, delta: &DVector<f64>) -> BundleState {
        let d = delta.as_slice();
        BundleState {
            candidate: move_interface(&state.candidate, &d[..INTERFACE_PARAMETERS]),
            poses: state
                .poses
                .iter()
                .enumerate()
                .map(|(v, pose)| {
                    let offset = INTERFACE_PARAMETERS + POSE_PARAMETERS * v;
                    move_pose(pose, &d[offset..offset + POSE_PARAMETERS])
                })
                .collect(),
        }
    }
}

/// Standard deviations of (tilt, azimuth, air layer) from the global block of (JᵀJ)⁻¹ (the
/// inverse of the Schur complement, [`BlockNormalEquations::global_covariance`]) scaled by the
/// residual variance σ̂² = cost / (residuals − parameters), with the tangent-plane axis
/// parameters carried to tilt and azimuth by their derivatives at `candidate`. Also returns σ̂.
pub fn interface_std(
    candidate: &Candidate,
    normal: &BlockNormalEquations,
    cost: f64,
    residuals: usize,
) -> Option<([f64; 3], f64)> {
    let parameters = normal.dimension();
    let dof = residuals.checked_sub(parameters).filter(|&d| d > 0)?;
    let sigma2 = cost / dof as f64;
    let covariance = normal
        .global_covariance()?
        .fixed_view::<3, 3>(0, 0)
        .into_owned()
        * sigma2;
    // ∂(tilt, azimuth)/∂(δ₁, δ₂) by central differences on the unit sphere.
    let h = 1e-7;
    let angles = |n: &Unit<Vector3<f64>>| (n.z.clamp(-1.0, 1.0).acos(), n.y.atan2(n.x));
    let mut jacobian = nalgebra::Matrix3::identity();
    for p in 0..2 {
        let mut offset = Vector2::zeros();
        offset[p] = h;
        let plus = angles(&tangent_step(&candidate.normal, &offset));
        offset[p] = -h;
        let minus = angles(&tangent_step(&candidate.normal, &offset));
        jacobian[(0, p)] = (plus.0 - minus.0) / (2.0 * h);
        let mut d_azimuth = plus.1 - minus.1;
        d_azimuth = (d_azimuth + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        jacobian[(1, p)] = d_azimuth / (2.0 * h);
    }
    let propagated = jacobian * covariance * jacobian.transpose();
    Some((
        [
            propagated[(0, 0)].sqrt(),
            propagated[(1, 1)].sqrt(),
            propagated[(2, 2)].sqrt(),
        ],
        sigma2.sqrt(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::simulate::rng::Rng;
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
                    pose: jp.transpose() * jp,
                    coupling: jg.transpose() * jp,
                    gradient: jp.transpose() * rv,
                }
            })
            .collect();
        let block = BlockNormalEquations {
            global: jg.transpose() * jg,
            global_gradient: jg.transpose() * &r,
            views: blocks,
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
        block.views[1] = PoseBlock {
            pose: Matrix6::zeros(),
            coupling: OMatrix::<f64, Dyn, U6>::zeros(3),
            gradient: Vector6::zeros(),
        };
        assert!(block.solve_damped(0.0, 0.0).is_none());
        assert!(block.global_covariance().is_none());
        // Damping with a positive floor makes it definite again.
        assert!(block.solve_damped(1e-3, 1.0).is_some());
    }
}
