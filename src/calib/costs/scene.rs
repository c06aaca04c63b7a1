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

use nalgebra::{Point3, Unit, Vector3};

use super::CostKind;
use super::air_layer::{MIN_GAP_LINE_SIN, air_distance_from_sums, sample_cameras};
use super::lanes::{self, Columns, GapSums, RayColumns};
use crate::calib::problem::board::fit_rigid;
use crate::calib::problem::data::{Candidate, StereoData};

/// The least-squares air layer for the axis `normal`, with the RMS ray gap there (metres).
///
/// `None` when a ray has no answer under this axis (it misses the interface or is totally
/// reflected), when the two rays of a corner are parallel, or when the gaps do not depend on d
/// (Σ a² ≈ 0: both cameras see every corner at the same incidence).
pub fn air_distance_for_axis(data: &StereoData, normal: &Unit<Vector3<f64>>) -> Option<(f64, f64)> {
    AxisRays::new(data, normal)?.air_distance()
}

/// What [`AxisRays`] reads of the data, prepared once per data set, as columns of every corner
/// (in `data.corners` order): its unit air directions and observed pixels in the left and the
/// right camera, and its board point (board frame).
#[derive(Debug, Clone)]
pub struct SceneRows {
    dirs: [Columns<3>; 2],
    pixels: [Columns<2>; 2],
    model: Vec<Point3<f64>>,
}

impl SceneRows {
    /// The rows of `data`.
    pub fn new(data: &StereoData) -> Self {
        Self {
            dirs: [0, 1].map(|k| {
                Columns::from_rows(data.corners.iter().map(|c| c.dirs[k].into_inner().into()))
            }),
            pixels: [0, 1].map(|k| {
                Columns::from_rows(data.corners.iter().map(|c| c.pixels[k].coords.into()))
            }),
            model: data
                .corners
                .iter()
                .map(|c| data.board.point_in_board(c.index))
                .collect(),
        }
    }
}

/// The water rays of every corner of `data` under one axis, for every air layer at once
/// ([`lanes::axis_rays`]' columns per camera: the origin at the air layer d₀, the unit water
/// direction and ∂origin/∂d), with the sums of their gap lines.
/// Holds its buffers for reuse ([`fill`](Self::fill)): a sweep evaluates thousands of axes, and
/// fresh buffers of this size cost page faults each time.
#[derive(Debug, Clone, Default)]
pub struct AxisRays {
    normal: Option<Unit<Vector3<f64>>>,
    /// The air layer at which the origins were computed.
    d0: f64,
    rays: [RayColumns; 2],
    gaps: Option<GapSums>,
    /// Scratch: triangulated points (x, y, z, residual), one view's points, fitted points.
    points: Columns<4>,
    view: Vec<Point3<f64>>,
    fitted: Columns<3>,
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
        let moved = data.ports_moved();
        self.gaps = lanes::axis_rays(
            &near,
            &prepared.dirs,
            d0,
            moved,
            MIN_GAP_LINE_SIN,
            &mut self.rays,
        );
        if self.gaps.is_none() {
            return false;
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

    /// The least-squares air layer of this axis and the RMS ray gap there
    /// ([`least_squares_air_distance`](super::air_layer::least_squares_air_distance) over the
    /// corners' gap lines g(d) = m·(o_l(d) − o_r(d)), m = unit(w_l × w_r)).
    pub fn air_distance(&self) -> Option<(f64, f64)> {
        self.normal?;
        let gaps = self.gaps?;
        if !gaps.usable {
            return None;
        }
        air_distance_from_sums(gaps.aa, gaps.ab, gaps.bb, self.rays[0].len())
    }

    /// The cost `kind` (a triangulating cost: reprojection, scene or ray gap) at the air layer `d`
    /// under this axis, as [`cost`](super::cost) computes it for the candidate (n, d), with the
    /// same fits ([`fit_rigid`] per view); `None` where that is +∞ (a camera outside the air, a
    /// corner that does not triangulate in the water, a view that cannot be fitted, a fitted
    /// corner that does not project).
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
        let shifts = data
            .ports_moved()
            .map(|moved| if moved { d - self.d0 } else { 0.0 });
        if !lanes::triangulate_shifted(&self.rays, shifts, &mut self.points) {
            return None;
        }
        if kind == CostKind::RayGap {
            // ray_gap_rms's sum, in order.
            let sum: f64 = self.points.column(3)[..corners]
                .iter()
                .map(|r| r.powi(2))
                .sum();
            return Some((sum / corners as f64).sqrt());
        }
        self.fitted.resize(corners);
        // SceneFit::scene_rms's and reprojection_residuals's sums, in order.
        let mut sum_squares = 0.0;
        for range in &data.views {
            self.view.clear();
            self.view.extend(range.clone().map(|i| {
                Point3::new(
                    self.points.get(0, i),
                    self.points.get(1, i),
                    self.points.get(2, i),
                )
            }));
            let fit = fit_rigid(&prepared.model[range.clone()], &self.view)?;
            sum_squares += fit.sum_squares;
            if kind == CostKind::Reprojection {
                // fitted_corner's R·P + t, with R as a matrix once per view.
                let rotation = fit.master_from_board.rotation.to_rotation_matrix();
                let t = fit.master_from_board.translation.vector;
                for i in range.clone() {
                    let p = rotation * prepared.model[i].coords + t;
                    for c in 0..3 {
                        self.fitted.set(c, i, p[c]);
                    }
                }
            }
        }
        if kind == CostKind::Scene {
            return Some((sum_squares / corners as f64).sqrt());
        }
        self.fitted.pad();
        let sum =
            lanes::reprojection_squares(&cameras, &self.fitted, &self.rays, &prepared.pixels)?;
        Some((sum / (2 * corners) as f64).sqrt())
    }
}

thread_local! {
    /// Each thread's buffers of [`profile_cost`] and [`axis_costs`].
    static RAYS: RefCell<AxisRays> = RefCell::new(AxisRays::default());
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

/// The triangulating cost `kind` of `candidates` that share one axis (a sweep's air layers under
/// one axis), from the water rays of that axis computed once ([`AxisRays`]): each is
/// [`cost`](super::cost) of its candidate up to rounding, +∞ where that is +∞ (a ray with no
/// answer under the axis, a camera outside the air, a corner that does not triangulate in the
/// water, a view that cannot be fitted, a fitted corner that does not project).
///
/// Panics if the candidates do not share one axis.
pub fn axis_costs(
    data: &StereoData,
    prepared: &SceneRows,
    kind: CostKind,
    candidates: &[Candidate],
) -> Vec<f64> {
    let Some(first) = candidates.first() else {
        return Vec::new();
    };
    assert!(
        candidates.iter().all(|c| c.normal == first.normal),
        "axis_costs of candidates under different axes"
    );
    RAYS.with_borrow_mut(|rays| {
        if !rays.fill(data, prepared, &first.normal) {
            // A ray without an answer under this axis has none at any air layer.
            return vec![f64::INFINITY; candidates.len()];
        }
        candidates
            .iter()
            .map(|c| {
                rays.cost(data, prepared, kind, c.air_distance)
                    .unwrap_or(f64::INFINITY)
            })
            .collect()
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::Board;
    use crate::calib::costs::cost;
    use crate::calib::simulate::{SceneSpec, simulate};
    use crate::model::normal_from_tilt_azimuth;

    /// The profile's costs (rays once per axis, origins moved to the air layer, the fitted corners
    /// projected from their observed rays) equal the reference [`cost`] (the scalar model per
    /// candidate, the safeguarded projection) at the profile's air layer: on the example rig,
    /// whose fitted corners the unsafeguarded iteration settles, and with its glass made less
    /// dense than the air (index 1.0 behind air of 1.003), which sends every one of them to the
    /// safeguarded lanes.
    #[test]
    fn profile_costs_equal_the_reference_at_their_air_layer() {
        let path = std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/data/example_rig.json"
        ));
        let text = std::fs::read_to_string(path).unwrap();
        let mut json: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(json["interface"]["index_air"], 1.003);
        json["interface"]["layers"][0]["index"] = 1.0.into();
        for text in [text, json.to_string()] {
            let rig = crate::io::rig_from_json_str(&text, path).unwrap();
            let compared = compare_profiles(&rig);
            assert!(compared >= 9, "only {compared} finite profiles");
        }
    }

    /// The costs of candidates sharing an axis, from its rays computed once, equal the reference
    /// at every air layer (including ones that put a camera outside the air: +∞ on both sides).
    #[test]
    fn axis_costs_equal_the_reference_at_every_air_layer() {
        let rig = crate::io::read_rig(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/data/example_rig.json"
        )))
        .unwrap();
        let (data, prepared) = simulated(&rig);
        let truth = *rig.shared_interface().unwrap().normal();
        let (mut finite, mut infinite) = (0, 0);
        for normal in [truth, normal_from_tilt_azimuth(0.1, 0.7)] {
            let candidates: Vec<Candidate> = [-0.5, 0.001, 0.012, 0.02, 0.031, 0.2]
                .iter()
                .map(|&air_distance| Candidate {
                    normal,
                    air_distance,
                })
                .collect();
            for kind in [CostKind::Reprojection, CostKind::Scene, CostKind::RayGap] {
                let costs = axis_costs(&data, &prepared, kind, &candidates);
                for (candidate, axis) in candidates.iter().zip(costs) {
                    let reference = cost(&data, kind, candidate);
                    if reference.is_finite() {
                        finite += 1;
                        let relative = (axis - reference).abs() / reference;
                        assert!(
                            relative <= 1e-12,
                            "{} at {}: {axis} against {reference}",
                            kind.name(),
                            candidate.air_distance
                        );
                    } else {
                        infinite += 1;
                        assert_eq!(
                            axis,
                            reference,
                            "{} at {}",
                            kind.name(),
                            candidate.air_distance
                        );
                    }
                }
            }
        }
        assert!(
            finite >= 20 && infinite >= 3,
            "{finite} finite, {infinite} infinite"
        );
    }

    /// Six simulated views of a 9×6 board behind `rig` (cameras 0 and 1), with their rows.
    fn simulated(rig: &crate::model::Rig) -> (StereoData, SceneRows) {
        let board = crate::calib::Target::Board(Board {
            rows: 6,
            cols: 9,
            square: 0.04,
        });
        let scene = simulate(rig, &SceneSpec::pair(board, 6, 0.1, 5, 0, 1)).unwrap();
        let data = StereoData::from_observations(rig, [0, 1], &scene.observations).unwrap();
        let prepared = SceneRows::new(&data);
        (data, prepared)
    }

    /// How many finite profiles of `rig`'s simulated scene equal the reference (panics where one
    /// does not).
    fn compare_profiles(rig: &crate::model::Rig) -> usize {
        let (data, prepared) = simulated(rig);
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
        compared
    }
}
