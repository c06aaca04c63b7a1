//! The triangulating costs ([`CostKind::Reprojection`], [`CostKind::Scene`], [`CostKind::RayGap`])
//! of every air layer under one axis, from the water rays of that axis computed once.
//!
//! Under a fixed axis n the water direction w_k of a corner does not depend on the air layer, and
//! its origin on the outer interface moves along the air ray: raising the first interface by δ
//! moves the point where the air ray meets it by v_k·δ/(n·v_k), and the rest of the path (parallel
//! planes, unchanged angles) translates with it. So o_k(d) = o_k(d₀) + (d − d₀)·v_k/(n·v_k) exactly
//! (DESIGN.md §2, "Back-projection": the water ray is linear in the air layer), and one
//! [`ray_in_water`](crate::model::RefractiveCamera::ray_in_water) per camera and corner serves the
//! air layer's least-squares solve ([`AxisRays::air_distance`]) and the triangulation at any d
//! ([`AxisRays::cost`]). The results are those of [`cost`](super::cost) up to rounding.

use std::cell::RefCell;

use nalgebra::{Point2, Point3, Unit, Vector3};

use super::air_layer::{GapLine, least_squares_air_distance, sample_cameras};
use super::{CostKind, pixel_residuals};
use crate::calib::problem::board::fit_rigid;
use crate::calib::problem::data::{Candidate, StereoData};
use crate::engine::simd;

/// The least-squares air layer for the axis `normal`, with the RMS ray gap there (metres).
///
/// `None` when a ray has no answer under this axis (it misses the interface or is totally
/// reflected), when the two rays of a corner are parallel, or when the gaps do not depend on d
/// (Σ a² ≈ 0: both cameras see every corner at the same incidence).
pub fn air_distance_for_axis(data: &StereoData, normal: &Unit<Vector3<f64>>) -> Option<(f64, f64)> {
    AxisRays::new(data, normal)?.air_distance()
}

/// What [`AxisRays`] reads of the data, prepared once per data set: the unit air directions of
/// every corner (left, right) and its board point (board frame).
#[derive(Debug, Clone)]
pub struct SceneRows {
    dirs: [Vec<[f64; 3]>; 2],
    model: Vec<Point3<f64>>,
}

impl SceneRows {
    /// The rows of `data`.
    pub fn new(data: &StereoData) -> Self {
        Self {
            dirs: [0, 1].map(|k| {
                data.corners
                    .iter()
                    .map(|c| <[f64; 3]>::from(c.dirs[k].into_inner()))
                    .collect()
            }),
            model: data
                .corners
                .iter()
                .map(|c| data.board.point_in_board(c.index))
                .collect(),
        }
    }
}

/// The water rays of every corner of `data` under one axis, for every air layer at once: per
/// camera and corner the origin at the air layer d₀, the unit water direction and ∂origin/∂d
/// ([`simd::rays_in_water`]'s rows). Holds its buffers for reuse ([`fill`](Self::fill)): a sweep
/// evaluates thousands of axes, and fresh buffers of this size cost page faults each time.
#[derive(Debug, Clone, Default)]
pub struct AxisRays {
    normal: Option<Unit<Vector3<f64>>>,
    /// The air layer at which the origins were computed.
    d0: f64,
    /// Rows of the left, then the right camera, in `data.corners` order.
    rays: [Vec<[f64; 9]>; 2],
    /// Scratch: statuses, triangulated rows, points, pixels.
    status: Vec<u32>,
    rows: Vec<[f64; 4]>,
    points: Vec<Point3<f64>>,
    fitted: Vec<[f64; 3]>,
    pixels: [Vec<[f64; 2]>; 2],
}

impl AxisRays {
    /// The rays of every corner under `normal` (on the CPU engine's vector path). `None` when the
    /// axis is not an interface normal or some corner's ray misses the interface or is totally
    /// reflected under it (then no air layer explains every corner: each cost is +∞).
    pub fn new(data: &StereoData, normal: &Unit<Vector3<f64>>) -> Option<Self> {
        let mut rays = Self::default();
        rays.fill(data, &SceneRows::new(data), normal)
            .then_some(rays)
    }

    /// [`new`](Self::new) in place, reusing the buffers, with `data`'s rows prepared; false where
    /// `new` is `None`.
    pub fn fill(
        &mut self,
        data: &StereoData,
        prepared: &SceneRows,
        normal: &Unit<Vector3<f64>>,
    ) -> bool {
        self.normal = None;
        let Some((d0, near, _)) = sample_cameras(data, normal) else {
            return false;
        };
        let corners = data.corners.len();
        self.status.resize(corners, 0);
        for k in 0..2 {
            self.rays[k].resize(corners, [0.0; 9]);
            simd::rays_in_water(
                &near[k],
                &prepared.dirs[k],
                &mut self.rays[k],
                &mut self.status,
            );
            if self.status.iter().any(|&s| s != 0) {
                return false;
            }
        }
        // The axis as the rig normalises it.
        self.normal = Some(*near[0].normal());
        self.d0 = d0;
        true
    }

    /// The axis (unit, as the rig normalises it); `None` after a [`fill`](Self::fill) that failed.
    pub fn normal(&self) -> Option<&Unit<Vector3<f64>>> {
        self.normal.as_ref()
    }

    /// The gap line of every corner ([`GapLine`]: g(d) = m·(o_l(d) − o_r(d)) = a·d + b with
    /// m = unit(w_l × w_r), a = m·(∂o_l/∂d − ∂o_r/∂d)).
    pub fn gap_lines(&self) -> impl Iterator<Item = GapLine> + '_ {
        let vector = |row: &[f64; 9], k: usize| Vector3::new(row[k], row[k + 1], row[k + 2]);
        let d0 = self.d0;
        self.rays[0].iter().zip(&self.rays[1]).map(move |(l, r)| {
            let cross = vector(l, 3).cross(&vector(r, 3));
            let norm = cross.norm();
            let m = cross / norm;
            let g0 = m.dot(&(vector(l, 0) - vector(r, 0)));
            let a = m.dot(&(vector(l, 6) - vector(r, 6)));
            GapLine {
                a,
                b: g0 - a * d0,
                sin_angle: norm,
            }
        })
    }

    /// The least-squares air layer of this axis and the RMS ray gap there
    /// ([`least_squares_air_distance`] over [`gap_lines`](Self::gap_lines)).
    pub fn air_distance(&self) -> Option<(f64, f64)> {
        self.normal?;
        let lines: Vec<Option<GapLine>> = self.gap_lines().map(Some).collect();
        least_squares_air_distance(&lines)
    }

    /// The cost `kind` (a triangulating cost: reprojection, scene or ray gap) at the air layer `d`
    /// under this axis, as [`cost`](super::cost) computes it for the candidate (n, d), with the
    /// same fits ([`fit_rigid`] per view) and sums; `None` where that is +∞ (a camera outside the
    /// air, a corner that does not triangulate in the water, a view that cannot be fitted, a
    /// fitted corner that does not project).
    pub fn cost(
        &mut self,
        data: &StereoData,
        prepared: &SceneRows,
        kind: CostKind,
        d: f64,
    ) -> Option<f64> {
        debug_assert!(!kind.axis_only(), "AxisRays::cost of {}", kind.name());
        let cameras = data.cameras_behind(&Candidate {
            normal: self.normal?,
            air_distance: d,
        })?;
        let corners = data.corners.len();
        self.rows.resize(corners, [0.0; 4]);
        self.status.resize(corners, 0);
        simd::triangulate_shifted(
            &self.rays[0],
            &self.rays[1],
            d - self.d0,
            &mut self.rows,
            &mut self.status,
        );
        if self.status.iter().any(|&s| s != 0) {
            return None;
        }
        if kind == CostKind::RayGap {
            // ray_gap_rms's sum, in order.
            let sum: f64 = self.rows.iter().map(|r| r[3].powi(2)).sum();
            return Some((sum / corners as f64).sqrt());
        }
        self.points.clear();
        self.points
            .extend(self.rows.iter().map(|r| Point3::new(r[0], r[1], r[2])));
        self.fitted.clear();
        // SceneFit::scene_rms's and reprojection_residuals's sums, in order.
        let mut sum_squares = 0.0;
        for range in &data.views {
            let fit = fit_rigid(&prepared.model[range.clone()], &self.points[range.clone()])?;
            sum_squares += fit.sum_squares;
            if kind == CostKind::Reprojection {
                // fitted_corner's R·P + t, with R as a matrix once per view.
                let rotation = fit.master_from_board.rotation.to_rotation_matrix();
                let t = fit.master_from_board.translation.vector;
                self.fitted.extend(
                    prepared.model[range.clone()]
                        .iter()
                        .map(|p| <[f64; 3]>::from(rotation * p.coords + t)),
                );
            }
        }
        if kind == CostKind::Scene {
            return Some((sum_squares / corners as f64).sqrt());
        }
        for k in 0..2 {
            self.pixels[k].resize(corners, [0.0; 2]);
            simd::project(
                &cameras[k],
                &self.fitted,
                &mut self.pixels[k],
                &mut self.status,
            );
            if self.status.iter().any(|&s| s != 0) {
                return None;
            }
        }
        let pixel = |p: &[f64; 2]| Point2::new(p[0], p[1]);
        let sum: f64 = data
            .corners
            .iter()
            .zip(self.pixels[0].iter().zip(&self.pixels[1]))
            .map(|(c, (l, r))| {
                let [l, r] = pixel_residuals(c, [pixel(l), pixel(r)]);
                l.norm_squared() + r.norm_squared()
            })
            .sum();
        Some((sum / (2 * corners) as f64).sqrt())
    }
}

/// The profile of a triangulating cost at one axis: the least-squares air layer (NaN where the
/// axis has none) and the cost there (+∞ where the axis has no air layer, the air layer does not
/// keep both cameras in the air, or the cost is +∞), as [`CostBackend::profile`]'s default
/// computes them.
///
/// [`CostBackend::profile`]: crate::calib::backends::CostBackend::profile
pub fn profile_cost(
    data: &StereoData,
    prepared: &SceneRows,
    kind: CostKind,
    normal: &Unit<Vector3<f64>>,
) -> (f64, f64) {
    thread_local! {
        static RAYS: RefCell<AxisRays> = RefCell::new(AxisRays::default());
    }
    RAYS.with_borrow_mut(|rays| {
        if !rays.fill(data, prepared, normal) {
            // Some corner has no ray: its gap line is missing and the air layer undetermined.
            return (f64::NAN, f64::INFINITY);
        }
        let Some((d, _)) = rays.air_distance() else {
            return (f64::NAN, f64::INFINITY);
        };
        if !(d > data.min_air_distance(normal)) {
            return (d, f64::INFINITY);
        }
        (
            d,
            rays.cost(data, prepared, kind, d).unwrap_or(f64::INFINITY),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::costs::cost;
    use crate::calib::problem::board::Board;
    use crate::calib::simulate::{SceneSpec, simulate};
    use crate::model::normal_from_tilt_azimuth;

    /// The profile's costs (rays once per axis on the vector path, origins moved to the air
    /// layer, the vector path's projections) equal the reference [`cost`] (the scalar model per
    /// candidate) at the profile's air layer.
    #[test]
    fn profile_costs_equal_the_reference_at_their_air_layer() {
        let rig = crate::io::read_rig(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/data/example_rig.json"
        )))
        .unwrap();
        let board = Board {
            rows: 6,
            cols: 9,
            square: 0.04,
        };
        let scene = simulate(&rig, 0, 1, &SceneSpec::new(board, 6, 0.1, 5)).unwrap();
        let data = StereoData::new(&rig, [0, 1], &scene.observations).unwrap();
        let prepared = SceneRows::new(&data);
        let truth = *rig.shared_interface().unwrap().normal();
        let mut compared = 0;
        let axes = [(0.0, 0.0), (6.0, 40.0), (10.0, 50.0), (9.0, 30.0)]
            .map(|(t, a): (f64, f64)| normal_from_tilt_azimuth(t.to_radians(), a.to_radians()));
        for normal in std::iter::once(truth).chain(axes) {
            for kind in [CostKind::Reprojection, CostKind::Scene, CostKind::RayGap] {
                let (d, profiled) = profile_cost(&data, &prepared, kind, &normal);
                if !profiled.is_finite() {
                    continue;
                }
                let candidate = Candidate {
                    normal,
                    air_distance: d,
                };
                let reference = cost(&data, kind, &candidate);
                let relative = (profiled - reference).abs() / reference;
                assert!(
                    relative <= 1e-12,
                    "{}: {profiled} against {reference} ({relative:e})",
                    kind.name()
                );
                compared += 1;
            }
        }
        assert!(compared >= 9, "only {compared} finite profiles");
    }
}
