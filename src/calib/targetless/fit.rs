//! The maximum-likelihood fit of a targetless calibration: Levenberg–Marquardt over the port
//! parameters `--estimate` names (the bundle's [`Parameter`]s) and every scene point's position
//! (master frame, metres), minimising the reprojection error of every match in every camera that
//! saw it, by exact forward projection (optionally under a Huber loss).
//!
//! Every residual depends on the global parameters and on one point alone, so the normal
//! equations are the bundle's block form with a 3 × 3 block per point instead of a 6 × 6 pose
//! ([`PointNormalEquations`], the bundle's
//! [`BlockNormalEquations`](crate::calib::solvers::block::BlockNormalEquations) with 3 × 3 blocks):
//! the points are eliminated one by one (Schur complement), memory and time are linear in the
//! points. Derivatives are central differences, as in the bundle.

use nalgebra::{DMatrix, DVector, Point2, Point3, Vector2, Vector3};
use rayon::prelude::*;

use crate::calib::pipeline::bundle::{
    Estimate, Parameter, State, difference_step, global_parameters, moved,
};
use crate::calib::solvers::block::{POINT_PARAMETERS, view_share};
pub use crate::calib::solvers::block::{PointBlock, PointNormalEquations};
use crate::calib::solvers::lm::LeastSquares;
use crate::model::{RefractiveCamera, Rig};

/// Central-difference step of a point's coordinates, metres: as the bundle's pose steps, it
/// moves a pixel by ~1e-3 px at a metre (~7 digits kept against rounding, truncation far below).
const POINT_STEP_M: f64 = 1e-6;

/// ∂pixel/∂parameter from the pixels at +h and −h (central), or from one of them and the pixel
/// `at` the state (one-sided) where the other step leaves the valid rigs or points (a point
/// within h of the outer interface or of total reflection); `None` when both do.
fn difference(
    plus: Option<Point2<f64>>,
    minus: Option<Point2<f64>>,
    at: Vector2<f64>,
    h: f64,
) -> Option<Vector2<f64>> {
    match (plus, minus) {
        (Some(p), Some(m)) => Some((p - m) / (2.0 * h)),
        (Some(p), None) => Some((p.coords - at) / h),
        (None, Some(m)) => Some((at - m.coords) / h),
        (None, None) => None,
    }
}

/// One scene point's observations: (rig camera index, pixel) for every camera that saw it.
#[derive(Debug, Clone, PartialEq)]
pub struct Track {
    /// The frame its matches came from (0-based, in the order the frames were given).
    pub frame: usize,
    /// (camera, observed pixel), at least two cameras.
    pub pixels: Vec<(usize, Point2<f64>)>,
}

/// The state of the fit: the rig's refined part (ports, extrinsics; no target poses) and every
/// track's point, master frame.
#[derive(Debug, Clone, PartialEq)]
pub struct PointsState {
    /// Ports and extrinsics (the bundle's state with no poses).
    pub rig: State,
    /// One point per track, master frame, metres.
    pub points: Vec<Point3<f64>>,
}

/// Least air (metres) between a camera and its port at any step of the fit: ten difference
/// steps of a distance (1 µm), so that both sides of every difference are rigs. Below a start's
/// 1 mm ([`crate::calib::pipeline::bundle::MIN_START_AIR_M`]): a fit may pass close to a camera
/// on its way (the far plane of python/tests/test_calibrate_targetless.py does, from a start at
/// 14 mm to 52 mm; bounded at 1 mm it stopped at its start).
pub const MIN_FIT_AIR_M: f64 = 1e-5;

/// The targetless problem: `tracks` seen by the cameras of `base`, estimating `globals`.
pub struct PointsProblem<'a> {
    base: &'a Rig,
    tracks: &'a [Track],
    globals: Vec<Parameter>,
    huber: Option<f64>,
}

impl<'a> PointsProblem<'a> {
    /// The problem of `tracks` under `base` (names, indices, media, what is known), estimating
    /// `estimate` (intrinsics are not estimated here), with an optional Huber threshold (px).
    pub fn new(base: &'a Rig, tracks: &'a [Track], estimate: Estimate, huber: Option<f64>) -> Self {
        let estimate = Estimate {
            intrinsics: false,
            ..estimate
        };
        Self {
            base,
            tracks,
            globals: global_parameters(base, estimate),
            huber,
        }
    }

    /// The global parameters, in step order.
    pub fn globals(&self) -> &[Parameter] {
        &self.globals
    }

    /// The residual count: two per observation.
    pub fn residuals(&self) -> usize {
        2 * self.tracks.iter().map(|t| t.pixels.len()).sum::<usize>()
    }

    /// Residuals (projected − observed, px) of track `t` at `point`, in its camera order.
    fn track_residuals(
        &self,
        cameras: &[RefractiveCamera],
        t: usize,
        point: &Point3<f64>,
    ) -> Option<Vec<Vector2<f64>>> {
        self.tracks[t]
            .pixels
            .iter()
            .map(|(k, observed)| Some(cameras[*k].project(point).ok()? - observed))
            .collect()
    }

    /// Every track's residuals at `state`.
    pub fn all_residuals(&self, state: &PointsState) -> Option<Vec<Vec<Vector2<f64>>>> {
        let cameras = state.rig.cameras(self.base)?;
        state
            .points
            .par_iter()
            .enumerate()
            .map(|(t, point)| self.track_residuals(&cameras, t, point))
            .collect()
    }

    /// The cameras at `state` and at `state` with each global moved by ± its difference step.
    #[allow(clippy::type_complexity)] // (cameras, per global [+h, −h] cameras), used once below
    fn cameras_and_shifted(
        &self,
        state: &PointsState,
    ) -> Option<(Vec<RefractiveCamera>, Vec<[Vec<RefractiveCamera>; 2]>)> {
        let cameras = state.rig.cameras(self.base)?;
        let shifted = self
            .globals
            .iter()
            .map(|&p| {
                let h = difference_step(p);
                Some([
                    moved(&state.rig, p, h).cameras(self.base)?,
                    moved(&state.rig, p, -h).cameras(self.base)?,
                ])
            })
            .collect::<Option<_>>()?;
        Some((cameras, shifted))
    }

    /// Track `t`'s share of the normal equations at `point`: `None` where its point does not
    /// project into one of its cameras, at the state or a difference step away.
    fn track_share(
        &self,
        cameras: &[RefractiveCamera],
        shifted: &[[Vec<RefractiveCamera>; 2]],
        t: usize,
        point: &Point3<f64>,
    ) -> Option<(DMatrix<f64>, DVector<f64>, f64)> {
        let globals = self.globals.len();
        let columns = globals + POINT_PARAMETERS;
        let base = self.track_residuals(cameras, t, point)?;
        let count = base.len();
        let mut jacobian = vec![Vector2::zeros(); columns * count];
        for (c, &parameter) in self.globals.iter().enumerate() {
            let h = difference_step(parameter);
            let only = parameter.camera(self.base);
            for (i, (k, _)) in self.tracks[t].pixels.iter().enumerate() {
                if only.is_some_and(|o| o != *k) {
                    continue;
                }
                jacobian[c * count + i] = difference(
                    shifted[c][0][*k].project(point).ok(),
                    shifted[c][1][*k].project(point).ok(),
                    base[i] + self.tracks[t].pixels[i].1.coords,
                    h,
                )?;
            }
        }
        for axis in 0..3 {
            let mut step = Vector3::zeros();
            step[axis] = POINT_STEP_M;
            for (i, (k, _)) in self.tracks[t].pixels.iter().enumerate() {
                jacobian[(globals + axis) * count + i] = difference(
                    cameras[*k].project(&(point + step)).ok(),
                    cameras[*k].project(&(point - step)).ok(),
                    base[i] + self.tracks[t].pixels[i].1.coords,
                    POINT_STEP_M,
                )?;
            }
        }
        Some(view_share(&base, &jacobian, columns, self.huber))
    }

    /// The tracks whose residuals or derivatives are undefined at `state` (a point that does not
    /// project into one of its cameras, there or a difference step away), or `None` where the
    /// state's cameras themselves are not. Such a track makes the cost or the normal equations
    /// undefined: the fit leaves it out rather than start where it cannot step.
    pub fn undefined_tracks(&self, state: &PointsState) -> Option<Vec<usize>> {
        let (cameras, shifted) = self.cameras_and_shifted(state)?;
        Some(
            state
                .points
                .par_iter()
                .enumerate()
                .filter(|(t, point)| self.track_share(&cameras, &shifted, *t, point).is_none())
                .map(|(t, _)| t)
                .collect(),
        )
    }
}

impl LeastSquares for PointsProblem<'_> {
    type State = PointsState;
    type Normal = PointNormalEquations;

    fn dimension(&self, state: &PointsState) -> usize {
        self.globals.len() + POINT_PARAMETERS * state.points.len()
    }

    /// Undefined, besides where a point does not project, where a camera comes within
    /// [`MIN_FIT_AIR_M`] of its port: on degraded footage the likelihood can fall toward a
    /// camera's air layer of zero (a shared port tilted 8° slid from 80 mm to 1 µm of one
    /// camera of a pair), where the difference steps leave the air and the fit stops with no
    /// σ. The bound keeps every step a rig whose derivatives exist; a fit that ends on it says
    /// so through its σ.
    fn cost(&self, state: &PointsState) -> Option<f64> {
        let cameras = state.rig.cameras(self.base)?;
        if cameras.iter().any(|c| c.air_distance() < MIN_FIT_AIR_M) {
            return None;
        }
        let residuals = self.all_residuals(state)?;
        Some(
            residuals
                .iter()
                .flatten()
                .map(|r| crate::calib::solvers::block::robust(self.huber, r.norm_squared()).0)
                .sum(),
        )
    }

    fn normal_equations(&self, state: &PointsState) -> Option<PointNormalEquations> {
        let (cameras, shifted) = self.cameras_and_shifted(state)?;
        let shares: Vec<(DMatrix<f64>, DVector<f64>, f64)> = state
            .points
            .par_iter()
            .enumerate()
            .map(|(t, point)| self.track_share(&cameras, &shifted, t, point))
            .collect::<Option<_>>()?;
        Some(PointNormalEquations::from_shares(
            self.globals.len(),
            shares,
        ))
    }

    fn retract(&self, state: &PointsState, delta: &DVector<f64>) -> PointsState {
        let mut rig = state.rig.clone();
        for (c, &parameter) in self.globals.iter().enumerate() {
            rig = moved(&rig, parameter, delta[c]);
        }
        let g = self.globals.len();
        let points = state
            .points
            .iter()
            .enumerate()
            .map(|(p, x)| {
                x + delta
                    .fixed_rows::<POINT_PARAMETERS>(g + POINT_PARAMETERS * p)
                    .into_owned()
            })
            .collect();
        PointsState { rig, points }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::Rng;
    use crate::calib::solvers::lm::{DenseNormalEquations, NormalEquations};

    #[test]
    fn the_point_schur_step_and_covariance_equal_the_dense_solve() {
        // A random Jacobian with the block pattern: every row on the globals and one point.
        let (globals, points, rows) = (4, 9, 6);
        let mut rng = Rng::new(11);
        let n = globals + 3 * points;
        let mut j = DMatrix::zeros(points * rows, n);
        let mut r = DVector::zeros(points * rows);
        for p in 0..points {
            for i in 0..rows {
                let row = p * rows + i;
                for c in 0..globals {
                    j[(row, c)] = rng.normal();
                }
                for c in 0..3 {
                    j[(row, globals + 3 * p + c)] = 500.0 * rng.normal();
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
        let blocks = (0..points)
            .map(|p| {
                let rows_p = j.rows(p * rows, rows);
                let jg = rows_p.columns(0, globals);
                let jp = rows_p.fixed_columns::<3>(globals + 3 * p);
                let rp = r.rows(p * rows, rows);
                PointBlock {
                    local: jp.transpose() * jp,
                    coupling: jg.transpose() * jp,
                    gradient: jp.transpose() * rp,
                    global_gradient: jg.transpose() * rp,
                }
            })
            .collect();
        let block = PointNormalEquations {
            global: jg.transpose() * jg,
            global_gradient: jg.transpose() * &r,
            blocks,
            cost: r.norm_squared(),
            prior_information: DVector::zeros(globals),
        };
        for (damping, floor) in [(0.0, 0.0), (1e-3, 1e-9), (5.0, 1.0)] {
            let step = block.solve_damped(damping, floor).unwrap();
            let reference = dense.solve_damped(damping, floor).unwrap();
            let error = (&step - &reference).norm() / reference.norm();
            assert!(error < 1e-9, "damping {damping}: step error {error:e}");
        }
        let inverse = dense.jtj.clone().cholesky().unwrap().inverse();
        let reference = inverse.view((0, 0), (globals, globals)).into_owned();
        let covariance = block.global_covariance().unwrap();
        let error = (&covariance - &reference).norm() / reference.norm();
        assert!(error < 1e-9, "covariance error {error:e}");
    }
}
