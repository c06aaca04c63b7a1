//! The maximum-likelihood refinement: Levenberg–Marquardt over the system axis, the air layer and
//! every board pose, minimising the reprojection error of the board corners in both cameras
//! (optionally under a Huber loss).
//!
//! Step parameters, in order: (δ₁, δ₂) the axis moved in its tangent plane
//! ([`tangent_step`]), δd the air layer (m), then for each view ω (rotation vector, rad) and τ
//! (translation, m) with master_from_board ← (τ, exp(ω)) · master_from_board.

use nalgebra::{DMatrix, DVector, Isometry3, Translation3, Unit, UnitQuaternion, Vector2, Vector3};
use rayon::prelude::*;

use super::data::{Candidate, StereoData};
use super::lm::LeastSquares;
use super::search::tangent_step;
use crate::model::RefractiveCamera;

/// The interface and board poses being refined.
#[derive(Debug, Clone, PartialEq)]
pub struct BundleState {
    /// System axis and air layer.
    pub candidate: Candidate,
    /// X_master = R·X_board + t per view.
    pub poses: Vec<Isometry3<f64>>,
}

/// Parameters of the interface in a step: δ₁, δ₂, δd.
pub const INTERFACE_PARAMETERS: usize = 3;
const POSE_PARAMETERS: usize = 6;
/// Parameters one residual depends on: the interface's and its view's pose.
const BLOCK: usize = INTERFACE_PARAMETERS + POSE_PARAMETERS;

/// One view's share of the normal equations over its 9 parameters (upper triangle).
struct ViewBlock {
    jtj: [[f64; BLOCK]; BLOCK],
    jtr: [f64; BLOCK],
    cost: f64,
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
    /// `data.corners` order; `None` when one does not project.
    fn view_residuals(&self, cameras: &[RefractiveCamera; 2], view: usize, pose: &Isometry3<f64>, out: &mut Vec<Vector2<f64>>) -> Option<()> {
        for corner in &self.data.corners[self.data.views[view].clone()] {
            let point = pose * self.data.board.point_in_board(corner.index);
            for (camera, pixel) in cameras.iter().zip(&corner.pixels) {
                out.push(camera.project(&point).ok()? - pixel);
            }
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
                self.view_residuals(&cameras, v, pose, &mut out).map(|()| out)
            })
            .collect();
        Some(per_view?.concat())
    }

    /// (cost contribution, weight) of a residual of length² `r2`: r² and 1 inside the Huber
    /// threshold k, 2k|r| − k² and k/|r| outside.
    fn robust(&self, r2: f64) -> (f64, f64) {
        match self.huber {
            Some(k) if r2 > k * k => {
                let r = r2.sqrt();
                (2.0 * k * r - k * k, k / r)
            }
            _ => (r2, 1.0),
        }
    }
}

fn move_pose(pose: &Isometry3<f64>, delta: &[f64]) -> Isometry3<f64> {
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

    fn dimension(&self, state: &BundleState) -> usize {
        INTERFACE_PARAMETERS + POSE_PARAMETERS * state.poses.len()
    }

    fn cost(&self, state: &BundleState) -> Option<f64> {
        Some(self.residuals(state)?.iter().map(|r| self.robust(r.norm_squared()).0).sum())
    }

    fn normal_equations(&self, state: &BundleState) -> Option<(DMatrix<f64>, DVector<f64>, f64)> {
        let data = self.data;
        let dimension = self.dimension(state);
        let cameras = data.cameras_behind(&state.candidate)?;
        let base = self.residuals(state)?;
        let rows = base.len();
        // ∂r/∂(interface parameters): every residual, central differences.
        let mut interface_jacobian = vec![[Vector2::zeros(); INTERFACE_PARAMETERS]; rows];
        for p in 0..INTERFACE_PARAMETERS {
            let mut delta = [0.0; INTERFACE_PARAMETERS];
            delta[p] = DIFFERENCE_STEP;
            let plus = self.residuals(&BundleState { candidate: move_interface(&state.candidate, &delta), poses: state.poses.clone() })?;
            delta[p] = -DIFFERENCE_STEP;
            let minus = self.residuals(&BundleState { candidate: move_interface(&state.candidate, &delta), poses: state.poses.clone() })?;
            for i in 0..rows {
                interface_jacobian[i][p] = (plus[i] - minus[i]) / (2.0 * DIFFERENCE_STEP);
            }
        }
        // Per view, in parallel: ∂r/∂(pose v) (only this view's residuals move), then the view's
        // share of JᵀWJ and JᵀWr over its columns (3 interface + 6 pose parameters).
        let blocks: Option<Vec<ViewBlock>> = state
            .poses
            .par_iter()
            .enumerate()
            .map(|(v, pose)| {
                let range = data.views[v].clone();
                let first_row = 2 * range.start;
                let count = 2 * range.len();
                let mut pose_jacobian = vec![[Vector2::zeros(); POSE_PARAMETERS]; count];
                let (mut plus, mut minus) = (Vec::with_capacity(count), Vec::with_capacity(count));
                for p in 0..POSE_PARAMETERS {
                    let mut delta = [0.0; POSE_PARAMETERS];
                    delta[p] = DIFFERENCE_STEP;
                    plus.clear();
                    self.view_residuals(&cameras, v, &move_pose(pose, &delta), &mut plus)?;
                    delta[p] = -DIFFERENCE_STEP;
                    minus.clear();
                    self.view_residuals(&cameras, v, &move_pose(pose, &delta), &mut minus)?;
                    for ((row, plus), minus) in pose_jacobian.iter_mut().zip(&plus).zip(&minus) {
                        row[p] = (plus - minus) / (2.0 * DIFFERENCE_STEP);
                    }
                }
                let mut block = ViewBlock { jtj: [[0.0; BLOCK]; BLOCK], jtr: [0.0; BLOCK], cost: 0.0 };
                for (i, pose_row) in pose_jacobian.iter().enumerate() {
                    let row = first_row + i;
                    let r = base[row];
                    let (contribution, weight) = self.robust(r.norm_squared());
                    block.cost += contribution;
                    let mut gradient = [Vector2::zeros(); BLOCK];
                    gradient[..INTERFACE_PARAMETERS].copy_from_slice(&interface_jacobian[row]);
                    gradient[INTERFACE_PARAMETERS..].copy_from_slice(pose_row);
                    for a in 0..BLOCK {
                        block.jtr[a] += weight * gradient[a].dot(&r);
                        for b in a..BLOCK {
                            block.jtj[a][b] += weight * gradient[a].dot(&gradient[b]);
                        }
                    }
                }
                Some(block)
            })
            .collect();
        let mut jtj = DMatrix::zeros(dimension, dimension);
        let mut jtr = DVector::zeros(dimension);
        let mut cost = 0.0;
        for (v, block) in blocks?.iter().enumerate() {
            let offset = INTERFACE_PARAMETERS + POSE_PARAMETERS * v;
            let column = |a: usize| if a < INTERFACE_PARAMETERS { a } else { offset + a - INTERFACE_PARAMETERS };
            cost += block.cost;
            for a in 0..BLOCK {
                jtr[column(a)] += block.jtr[a];
                for b in a..BLOCK {
                    jtj[(column(a), column(b))] += block.jtj[a][b];
                    if a != b {
                        jtj[(column(b), column(a))] += block.jtj[a][b];
                    }
                }
            }
        }
        Some((jtj, jtr, cost))
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

/// Standard deviations of (tilt, azimuth, air layer) from the inverse of JᵀJ scaled by the
/// residual variance σ̂² = cost / (residuals − parameters), with the tangent-plane axis
/// parameters carried to tilt and azimuth by their derivatives at `candidate`. Also returns σ̂.
pub fn interface_std(candidate: &Candidate, jtj: &DMatrix<f64>, cost: f64, residuals: usize) -> Option<([f64; 3], f64)> {
    let parameters = jtj.nrows();
    let dof = residuals.checked_sub(parameters).filter(|&d| d > 0)?;
    let sigma2 = cost / dof as f64;
    let inverse = jtj.clone().cholesky()?.inverse();
    let covariance = inverse.fixed_view::<3, 3>(0, 0).into_owned() * sigma2;
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
        d_azimuth = (d_azimuth + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
        jacobian[(1, p)] = d_azimuth / (2.0 * h);
    }
    let propagated = jacobian * covariance * jacobian.transpose();
    Some(([propagated[(0, 0)].sqrt(), propagated[(1, 1)].sqrt(), propagated[(2, 2)].sqrt()], sigma2.sqrt()))
}
