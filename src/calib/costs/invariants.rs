//! The pattern invariants of thesis 5.4.1 (DESIGN.md §2), which need the system axis only.
//!
//! For a corner seen by both cameras the binocular VOPs Ǒ, Ǒ′ ([`binocular_vop`]) lie on the
//! corner's object axis, the line through the real point parallel to n. Projected along n onto a
//! plane ⟂ n they all fall on the projection of the real point. The board is planar, so under the
//! true axis the projected corners of a view form an exact affine image of the corner grid: rows
//! and columns are straight (plane fitting error, PFE), parallel rows stay parallel (plane angles
//! error, PAE), and the whole grid fits one affine map (affine-grid residual).
//!
//! The projected position is ill-conditioned near the plane through the baseline parallel to n,
//! where [v, n, −v′] is singular: there one direction of it moves by metres per pixel of noise.
//! The affine-grid residual therefore weights each corner by the inverse of its covariance,
//! propagated from isotropic 1-pixel noise in both images (a χ² per degree of freedom, ≈ σ² in px²
//! at the true axis). [`affine_grid`] is its explicit per-view form, the reference the batch path
//! [`affine_grid`](crate::calib::costs::affine_grid) (which adds a taper near the degenerate plane) is tested against; PFE
//! and PAE are the thesis' plain forms.

use nalgebra::{Matrix2, Matrix2x4, Matrix3, Matrix6, Point3, Unit, Vector2, Vector3, Vector6};

use crate::calib::problem::data::{Corner, StereoData};
use crate::model::binocular_vop;

/// A corner's binocular VOP projected along n into a plane ⟂ n, with its covariance for 1 px of
/// noise in each image coordinate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProjectedVop {
    /// Corner index on the board.
    pub index: usize,
    /// Position in the plane ⟂ n (basis [`plane_basis`]), metres.
    pub position: Vector2<f64>,
    /// Covariance of `position` for unit pixel noise, m²/px².
    pub covariance: Matrix2<f64>,
}

/// An orthonormal basis (e₁, e₂) of the plane ⟂ n, continuous around n = z.
pub fn plane_basis(normal: &Unit<Vector3<f64>>) -> [Vector3<f64>; 2] {
    let n = normal.into_inner();
    // e₁ = unit(x − (n·x) n), e₂ = n × e₁: well defined while |n_x| < 1 (tilts below 90°).
    let e1 = (Vector3::x() - n * n.x).normalize();
    [e1, n.cross(&e1)]
}

impl ProjectedVop {
    /// From the position and its Jacobian J = ∂q/∂(u_l, v_l, u_r, v_r) (metres per pixel):
    /// Σ = J Jᵀ for unit pixel noise. Formed here in f64 whatever precision J was computed in, so
    /// that Σ is positive semi-definite even for corners near the degenerate plane, whose Σ has a
    /// condition number up to ~1e12 (f32 entries of Σ itself can give it a negative determinant).
    pub fn from_jacobian(index: usize, position: Vector2<f64>, jacobian: &Matrix2x4<f64>) -> Self {
        Self {
            index,
            position,
            covariance: jacobian * jacobian.transpose(),
        }
    }

    /// From a packed row (q₁, q₂, then J column by column), as the `calib_projected_vop` kernel
    /// writes it.
    pub fn from_packed(index: usize, row: &[f64; 10]) -> Self {
        Self::from_jacobian(
            index,
            Vector2::new(row[0], row[1]),
            &Matrix2x4::from_column_slice(&row[2..]),
        )
    }
}

/// The projected VOPs of one view's corners under `normal`. Corners in the degenerate plane
/// (binocular VOP undetermined) carry no position and are left out.
pub fn projected_vops(
    data: &StereoData,
    corners: &[Corner],
    normal: &Unit<Vector3<f64>>,
) -> Vec<ProjectedVop> {
    let centres = data.centres();
    let basis = plane_basis(normal);
    corners
        .iter()
        .filter_map(|c| projected_vop(&centres, &basis, normal, c))
        .collect()
}

/// The binocular VOP of one corner under `normal`, projected along n with `basis` =
/// [`plane_basis`]`(normal)`, and its covariance; `centres` = C_l, C_r. `None` where the VOP is
/// undetermined. CPU twin of the `calib_projected_vop` kernel.
pub fn projected_vop(
    centres: &[Point3<f64>; 2],
    basis: &[Vector3<f64>; 2],
    normal: &Unit<Vector3<f64>>,
    c: &Corner,
) -> Option<ProjectedVop> {
    let [centre_l, centre_r] = centres;
    let [e1, e2] = basis;
    let [v_l, v_r] = c.dirs;
    let bv = binocular_vop(centre_l, &v_l, centre_r, &v_r, normal).ok()?;
    let point: Point3<f64> = bv.vop_left;
    let position = Vector2::new(e1.dot(&point.coords), e2.dot(&point.coords));
    // Propagation: M x = C_r − C_l with M = [v, n, −v′], x = (s, m, s′). A change dv moves
    // column 0, so ds = −(M⁻¹ dv)₀·s; dv′ moves column 2 (−v′), so ds = (M⁻¹ dv′)₀·s′.
    // The projected point is E·(C_l + s v): dq = E·(v ds + s dv).
    let m = Matrix3::from_columns(&[v_l.into_inner(), normal.into_inner(), -v_r.into_inner()]);
    let m_inv = m.try_inverse()?;
    let row0 = m_inv.row(0);
    let ds_l = -(row0 * c.dir_jacobians[0]) * bv.s_left; // 1×2
    let ds_r = (row0 * c.dir_jacobians[1]) * bv.s_right; // 1×2
    let dp_l = v_l.into_inner() * ds_l + c.dir_jacobians[0] * bv.s_left; // 3×2
    let dp_r = v_l.into_inner() * ds_r; // 3×2
    let mut jacobian = Matrix2x4::zeros();
    for col in 0..2 {
        jacobian[(0, col)] = e1.dot(&dp_l.column(col));
        jacobian[(1, col)] = e2.dot(&dp_l.column(col));
        jacobian[(0, col + 2)] = e1.dot(&dp_r.column(col));
        jacobian[(1, col + 2)] = e2.dot(&dp_r.column(col));
    }
    Some(ProjectedVop::from_jacobian(c.index, position, &jacobian))
}

/// Weighted affine-grid residual of one view: fits q ≈ A·g + b (A 2×2, b 2-vector, g the corner's
/// grid position in metres) by generalised least squares with weights Σᵢ⁻¹, and returns
/// (χ² = Σ rᵢᵀ Σᵢ⁻¹ rᵢ, degrees of freedom 2N − 6). `None` with fewer than 4 corners or a singular
/// system.
pub fn affine_grid(data: &StereoData, vops: &[ProjectedVop]) -> Option<(f64, usize)> {
    if vops.len() < 4 {
        return None;
    }
    let square = data.board.square;
    let mut normal = Matrix6::zeros();
    let mut rhs = Vector6::zeros();
    let mut weights = Vec::with_capacity(vops.len());
    for vop in vops {
        let (r, c) = data.board.grid_position(vop.index);
        let g = Vector2::new(c as f64 * square, r as f64 * square);
        // A tiny ridge keeps Σ invertible where one direction is exactly unconstrained.
        let ridge = 1e-12 * vop.covariance.trace() + 1e-30;
        let w = (vop.covariance + Matrix2::identity() * ridge).try_inverse()?;
        let design = design_rows(&g);
        normal += design.transpose() * w * design;
        rhs += design.transpose() * w * vop.position;
        weights.push((design, w));
    }
    let theta = normal.cholesky()?.solve(&rhs);
    let chi2 = vops
        .iter()
        .zip(&weights)
        .map(|(vop, (design, w))| {
            let r = vop.position - design * theta;
            (r.transpose() * w * r)[(0, 0)]
        })
        .sum();
    Some((chi2, 2 * vops.len() - 6))
}

/// Rows of q = A g + b in θ = (a₁₁, a₁₂, a₂₁, a₂₂, b₁, b₂).
fn design_rows(g: &Vector2<f64>) -> nalgebra::Matrix2x6<f64> {
    nalgebra::Matrix2x6::new(g.x, g.y, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, g.x, g.y, 0.0, 1.0)
}

/// Total-least-squares line through 2-D points: (Σ squared perpendicular distances, unit
/// direction). `None` with fewer than 3 points.
fn fit_line(points: &[Vector2<f64>]) -> Option<(f64, Vector2<f64>)> {
    if points.len() < 3 {
        return None;
    }
    let mean = points.iter().sum::<Vector2<f64>>() / points.len() as f64;
    let scatter = points.iter().fold(Matrix2::zeros(), |s, p| {
        s + (p - mean) * (p - mean).transpose()
    });
    let eigen = scatter.symmetric_eigen();
    let (small, large) = if eigen.eigenvalues[0] <= eigen.eigenvalues[1] {
        (0, 1)
    } else {
        (1, 0)
    };
    Some((
        eigen.eigenvalues[small].max(0.0),
        eigen.eigenvectors.column(large).into_owned(),
    ))
}

/// The lines of one view: every board row and column with at least 3 projected corners, as
/// (is_row, points).
fn grid_lines(data: &StereoData, vops: &[ProjectedVop]) -> Vec<(bool, Vec<Vector2<f64>>)> {
    let board = &data.board;
    let mut rows = vec![Vec::new(); board.rows];
    let mut cols = vec![Vec::new(); board.cols];
    for vop in vops {
        let (r, c) = board.grid_position(vop.index);
        rows[r].push(vop.position);
        cols[c].push(vop.position);
    }
    rows.into_iter()
        .map(|p| (true, p))
        .chain(cols.into_iter().map(|p| (false, p)))
        .filter(|(_, p)| p.len() >= 3)
        .collect()
}

/// Plane fitting error of one view: (Σ squared distances of the projected corners to their row's
/// and column's fitted line, degrees of freedom Σ (points − 2)), metres².
pub fn plane_fitting(data: &StereoData, vops: &[ProjectedVop]) -> (f64, usize) {
    grid_lines(data, vops)
        .iter()
        .filter_map(|(_, points)| fit_line(points).map(|(ss, _)| (ss, points.len() - 2)))
        .fold((0.0, 0), |(s, n), (ss, dof)| (s + ss, n + dof))
}

/// Plane angles error of one view: (Σ squared angles between each row's line and the view's mean
/// row direction, and likewise for columns, number of lines − 2), radians².
pub fn plane_angles(data: &StereoData, vops: &[ProjectedVop]) -> (f64, usize) {
    let lines = grid_lines(data, vops);
    let mut sum = 0.0;
    let mut count = 0;
    for family in [true, false] {
        let dirs: Vec<Vector2<f64>> = lines
            .iter()
            .filter(|(row, _)| *row == family)
            .filter_map(|(_, p)| fit_line(p).map(|(_, d)| d))
            .collect();
        if dirs.len() < 2 {
            continue;
        }
        // Mean of an axial direction: average the doubled angles.
        let doubled = dirs.iter().fold(Vector2::zeros(), |a, d| {
            a + Vector2::new(d.x * d.x - d.y * d.y, 2.0 * d.x * d.y)
        });
        let mean_angle = 0.5 * doubled.y.atan2(doubled.x);
        for d in &dirs {
            let mut delta = d.y.atan2(d.x) - mean_angle;
            // Lines have no sign: fold into (−π/2, π/2].
            delta = (delta + std::f64::consts::FRAC_PI_2).rem_euclid(std::f64::consts::PI)
                - std::f64::consts::FRAC_PI_2;
            sum += delta * delta;
        }
        count += dirs.len() - 1;
    }
    (sum, count)
}
