//! The calibration costs of one candidate interface, in f64 on the CPU (the reference that the
//! GPU backend is checked against).
//!
//! - [`CostKind::Reprojection`]: triangulate every corner, fit the rigid board to each view
//!   (Kabsch), project the fitted board into both cameras: RMS pixel error.
//! - [`CostKind::Scene`]: the same fit's RMS 3-D residual, metres (the 3-D scene error).
//! - [`CostKind::RayGap`]: RMS distance between the two water rays of each corner, metres.
//! - [`CostKind::AffineGrid`]: the weighted affine-grid invariant, fused per view
//!   ([`affine_grid`]); [`CostKind::PlaneFitting`], [`CostKind::PlaneAngles`]: the thesis'
//!   plane errors ([`invariants`]). These ignore the air layer.
//!
//! [`lanes`] is the triangulating costs' vector twin (every corner under one axis at a time, for
//! the sweeps), on the lanes of [`crate::engine::cpu::lanes`].
//!
//! A candidate under which some corner has no answer (a camera outside the air, a ray that is
//! totally reflected, a point that triangulates behind the port) costs +∞.

pub mod affine_grid;
pub mod air_layer;
pub mod invariants;
pub mod lanes;
pub mod scene;

use nalgebra::{Isometry3, Point2, Point3, Vector2};

use crate::calib::costs::invariants::{ProjectedVop, plane_angles, plane_fitting, projected_vops};
use crate::calib::problem::board::{RigidFit, fit_rigid};
use crate::calib::problem::data::{Candidate, Corner, StereoData};
use crate::engine::cpu::lanes::project_all;
use crate::model::{RefractiveCamera, Triangulation, triangulate_rays};

/// Which cost to evaluate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CostKind {
    /// RMS reprojection error of the rigidly fitted boards in both cameras, pixels.
    Reprojection,
    /// RMS residual of the rigid board fit to the triangulated corners, metres.
    Scene,
    /// RMS distance between the two water rays of each corner, metres.
    RayGap,
    /// Weighted affine-grid invariant: χ² per degree of freedom (≈ σ² in px² at the true axis).
    AffineGrid,
    /// Plane fitting error: RMS distance of the projected corners to their row and column lines, metres.
    PlaneFitting,
    /// Plane angles error: RMS angle between parallel rows (columns) of the projected grid, radians.
    PlaneAngles,
}

impl CostKind {
    /// Every cost.
    pub const ALL: [CostKind; 6] = [
        Self::Reprojection,
        Self::Scene,
        Self::RayGap,
        Self::AffineGrid,
        Self::PlaneFitting,
        Self::PlaneAngles,
    ];

    /// Whether the cost depends on the axis only (not on the air layer).
    pub fn axis_only(self) -> bool {
        matches!(
            self,
            Self::AffineGrid | Self::PlaneFitting | Self::PlaneAngles
        )
    }

    /// Short name (`reprojection`, `scene`, `ray-gap`, `affine-grid`, `plane-fitting`, `plane-angles`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Reprojection => "reprojection",
            Self::Scene => "scene",
            Self::RayGap => "ray-gap",
            Self::AffineGrid => "affine-grid",
            Self::PlaneFitting => "plane-fitting",
            Self::PlaneAngles => "plane-angles",
        }
    }

    /// The cost named `name` ([`name`](Self::name)'s inverse).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }

    /// Unit of the cost's value.
    pub fn unit(self) -> &'static str {
        match self {
            Self::Reprojection => "px",
            Self::Scene | Self::RayGap | Self::PlaneFitting => "m",
            Self::AffineGrid => "px²",
            Self::PlaneAngles => "rad",
        }
    }
}

/// The triangulated corners and the rigid board fits under one candidate.
#[derive(Debug, Clone)]
pub struct SceneFit {
    /// Triangulated corner (midpoint), master frame, in `data.corners` order.
    pub points: Vec<Point3<f64>>,
    /// Distance between the two water rays of each corner, metres.
    pub gaps: Vec<f64>,
    /// Rigid fit of each view.
    pub fits: Vec<RigidFit>,
}

impl SceneFit {
    /// Triangulates every corner behind `cameras` and fits the board to each view. `None` when a
    /// corner has no answer or a view cannot be fitted.
    pub fn new(data: &StereoData, cameras: &[RefractiveCamera; 2]) -> Option<Self> {
        let mut points = Vec::with_capacity(data.corners.len());
        let mut gaps = Vec::with_capacity(data.corners.len());
        for corner in &data.corners {
            let t = triangulate_corner(cameras, corner)?;
            points.push(t.point);
            gaps.push(t.residual);
        }
        Self::from_triangulated(data, points, gaps)
    }

    /// Fits the board to each view of corners already triangulated (`points`, `gaps` in
    /// `data.corners` order, from [`triangulate_corner`] or its GPU twin). `None` when a view
    /// cannot be fitted.
    pub fn from_triangulated(
        data: &StereoData,
        points: Vec<Point3<f64>>,
        gaps: Vec<f64>,
    ) -> Option<Self> {
        let fits = data
            .views
            .iter()
            .map(|range| {
                let model: Vec<_> = data.corners[range.clone()]
                    .iter()
                    .map(|c| data.board.point_in_board(c.index))
                    .collect();
                fit_rigid(&model, &points[range.clone()])
            })
            .collect::<Option<Vec<_>>>()?;
        Some(Self { points, gaps, fits })
    }

    /// X_master = R·X_board + t of each view.
    pub fn poses(&self) -> Vec<Isometry3<f64>> {
        self.fits.iter().map(|f| f.master_from_board).collect()
    }

    /// Every corner of the fitted boards, master frame, in `data.corners` order: what
    /// [`reprojection_residuals`] projects.
    pub fn fitted_points(&self, data: &StereoData) -> Vec<Point3<f64>> {
        data.corners
            .iter()
            .map(|c| fitted_corner(data, &self.fits[c.view].master_from_board, c))
            .collect()
    }

    /// RMS of the rigid-fit residuals over all corners, metres.
    pub fn scene_rms(&self) -> f64 {
        (self.fits.iter().map(|f| f.sum_squares).sum::<f64>() / self.points.len() as f64).sqrt()
    }

    /// RMS deviation of the distances between adjacent triangulated corners (along rows and
    /// columns) from the board's square, metres.
    pub fn square_deviation_rms(&self, data: &StereoData) -> f64 {
        let (mut sum, mut count) = (0.0, 0usize);
        for range in &data.views {
            let corners = &data.corners[range.clone()];
            let lookup: std::collections::HashMap<usize, usize> = corners
                .iter()
                .enumerate()
                .map(|(j, c)| (c.index, range.start + j))
                .collect();
            for c in corners {
                let (r, col) = data.board.grid_position(c.index);
                let here = lookup[&c.index];
                let neighbours = [
                    (col + 1 < data.board.cols).then(|| c.index + 1),
                    (r + 1 < data.board.rows).then(|| c.index + data.board.cols),
                ];
                for next in neighbours
                    .into_iter()
                    .flatten()
                    .filter_map(|i| lookup.get(&i))
                {
                    let distance = (self.points[here] - self.points[*next]).norm();
                    sum += (distance - data.board.square).powi(2);
                    count += 1;
                }
            }
        }
        if count == 0 {
            0.0
        } else {
            (sum / count as f64).sqrt()
        }
    }
}

/// The corner triangulated behind `cameras`: both air rays into the water, midpoint of their
/// closest approach and the gap there. `None` when a ray or the triangulation has no answer. CPU
/// twin of the `calib_triangulate` kernel.
pub fn triangulate_corner(
    cameras: &[RefractiveCamera; 2],
    corner: &Corner,
) -> Option<Triangulation> {
    let left = cameras[0].ray_in_water(&corner.dirs[0]).ok()?;
    let right = cameras[1].ray_in_water(&corner.dirs[1]).ok()?;
    triangulate_rays(&left, &right).ok()
}

/// Corner `corner` of the board at pose `master_from_board`, master frame.
pub fn fitted_corner(
    data: &StereoData,
    master_from_board: &Isometry3<f64>,
    corner: &Corner,
) -> Point3<f64> {
    master_from_board * data.board.point_in_board(corner.index)
}

/// Observed − projected pixel of a corner in both images, `[left, right]`.
pub fn pixel_residuals(corner: &Corner, projected: [Point2<f64>; 2]) -> [Vector2<f64>; 2] {
    [
        corner.pixels[0] - projected[0],
        corner.pixels[1] - projected[1],
    ]
}

/// Pixel residuals (observed − projected) of the fitted boards in both cameras, `[left, right]`
/// per corner in `data.corners` order. `None` when a fitted corner does not project.
pub fn reprojection_residuals(
    data: &StereoData,
    cameras: &[RefractiveCamera; 2],
    poses: &[Isometry3<f64>],
) -> Option<Vec<[Vector2<f64>; 2]>> {
    // Every corner at once, in the lanes of the CPU engine's vector path.
    let points: Vec<[f64; 3]> = data
        .corners
        .iter()
        .map(|c| fitted_corner(data, &poses[c.view], c).coords.into())
        .collect();
    let left = project_all(&cameras[0], &points)?;
    let right = project_all(&cameras[1], &points)?;
    let pixel = |p: &[f64; 2]| Point2::new(p[0], p[1]);
    Some(
        data.corners
            .iter()
            .zip(left.iter().zip(&right))
            .map(|(c, (l, r))| pixel_residuals(c, [pixel(l), pixel(r)]))
            .collect(),
    )
}

/// [`CostKind::Reprojection`] from the residuals of every corner: √(Σ |r_l|² + |r_r|² / 2N), pixels.
pub fn reprojection_rms(residuals: &[[Vector2<f64>; 2]]) -> f64 {
    let sum: f64 = residuals
        .iter()
        .map(|[l, r]| l.norm_squared() + r.norm_squared())
        .sum();
    (sum / (2 * residuals.len()) as f64).sqrt()
}

/// [`CostKind::RayGap`] from the gap of every corner: √(Σ gap² / N), metres.
pub fn ray_gap_rms(gaps: &[f64]) -> f64 {
    let sum: f64 = gaps.iter().map(|g| g.powi(2)).sum();
    (sum / gaps.len() as f64).sqrt()
}

/// The cost `kind` of one candidate, +∞ where the candidate explains no corner. The affine-grid
/// invariant's per-corner rows are prepared by each call here; the backends prepare them once
/// ([`cost_prepared`]).
pub fn cost(data: &StereoData, kind: CostKind, candidate: &Candidate) -> f64 {
    let rows = if kind == CostKind::AffineGrid {
        affine_grid::affine_rows(data)
    } else {
        Vec::new()
    };
    cost_prepared(data, &rows, kind, candidate)
}

/// [`cost`] with the affine-grid rows ([`affine_grid::affine_rows`]) prepared by the caller (only
/// read for [`CostKind::AffineGrid`]).
pub fn cost_prepared(
    data: &StereoData,
    affine_rows: &[[f64; affine_grid::ROW]],
    kind: CostKind,
    candidate: &Candidate,
) -> f64 {
    evaluate(data, affine_rows, kind, candidate).unwrap_or(f64::INFINITY)
}

fn evaluate(
    data: &StereoData,
    affine_rows: &[[f64; affine_grid::ROW]],
    kind: CostKind,
    candidate: &Candidate,
) -> Option<f64> {
    if kind == CostKind::AffineGrid {
        let n = candidate.normal;
        return affine_grid::affine_grid_cost(data, affine_rows, &[n.x, n.y, n.z]);
    }
    if kind.axis_only() {
        return plane_cost(
            data,
            kind,
            data.views
                .iter()
                .map(|range| projected_vops(data, &data.corners[range.clone()], &candidate.normal)),
        );
    }
    let cameras = data.cameras_behind(candidate)?;
    if kind == CostKind::RayGap {
        let gaps = data
            .corners
            .iter()
            .map(|c| triangulate_corner(&cameras, c).map(|t| t.residual))
            .collect::<Option<Vec<_>>>()?;
        return Some(ray_gap_rms(&gaps));
    }
    let fit = SceneFit::new(data, &cameras)?;
    match kind {
        CostKind::Scene => Some(fit.scene_rms()),
        _ => Some(reprojection_rms(&reprojection_residuals(
            data,
            &cameras,
            &fit.poses(),
        )?)),
    }
}

/// A plane error ([`CostKind::PlaneFitting`] or [`CostKind::PlaneAngles`]) from the projected VOPs
/// of each view in turn (corners whose VOP is undetermined left out): √(Σ/dof). `None` when no
/// degree of freedom is left. ([`CostKind::AffineGrid`] is [`affine_grid`]'s.)
pub fn plane_cost(
    data: &StereoData,
    kind: CostKind,
    views: impl IntoIterator<Item = Vec<ProjectedVop>>,
) -> Option<f64> {
    debug_assert!(
        matches!(kind, CostKind::PlaneFitting | CostKind::PlaneAngles),
        "plane_cost of {}",
        kind.name()
    );
    let (mut sum, mut dof) = (0.0, 0usize);
    for vops in views {
        let (s, d) = if kind == CostKind::PlaneFitting {
            plane_fitting(data, &vops)
        } else {
            plane_angles(data, &vops)
        };
        sum += s;
        dof += d;
    }
    (dof > 0).then(|| (sum / dof as f64).sqrt())
}
