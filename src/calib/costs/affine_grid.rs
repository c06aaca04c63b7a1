//! The weighted affine-grid invariant fused per (candidate axis, view): the batch path of
//! [`CostKind::AffineGrid`](super::CostKind::AffineGrid). CPU twin of
//! `shaders/calib/affine_grid.wgsl` (same names, same loop).
//!
//! **Formulation.** For the axis n write t = n / n_z. The binocular VOP of a corner lies at
//! s along its left air ray, s = (t·p)/(t·m) with p = b × v_r, m = v_l × v_r, b = C_r − C_l
//! (Cramer's rule on [v_l, n, −v_r]·(s, μ, s′) = b, thesis 5.3). Projecting along n onto the plane
//! z = 0, Π(w) = (w_x − w_z t_x, w_y − w_z t_y), is an affine image of the projection onto the
//! plane ⟂ n, and Π(C_l) is the same for every corner of a view; the weighted affine fit is
//! invariant under both, so the position q = s·Π(v_l) gives exactly the χ² of
//! [`invariants::affine_grid`](crate::calib::costs::invariants::affine_grid). Its Jacobian for pixel noise is
//! made of dot products of t with per-corner vectors computed once ([`affine_rows`]):
//! ∂s/∂u_l = −s (t·a)/(t·m) with a = ∂v_l/∂u × v_r, ∂s/∂u_r = (t·c − s t·e)/(t·m) with
//! c = b × ∂v_r/∂u, e = v_l × ∂v_r/∂u; ∂q = ∂s Π(v_l) + s Π(∂v_l). Σ = J Jᵀ for 1 px of noise,
//! det Σ by Cauchy–Binet (a sum of squares), W = (Σ + ρI)⁻¹ with the ridge ρ of the explicit
//! fit.
//!
//! **Taper.** Where t·m is comparable to its own change under a pixel of noise the position is
//! not linear in the noise (s changes sign), so the propagated covariance understates the error
//! and single corners would throw spikes into the cost surface along lines of axes. Each corner's
//! weight is multiplied by w = D² / (D² + κ² σ_D²), D = t·m, σ_D² = Σ (∂D/∂pixel)² for 1 px,
//! κ = [`TAPER`]; the degrees of freedom are 2 Σ w − 6 per view.
//!
//! **Fit.** Per view, with g the corner's grid position (centred on the view's mean) and
//! g̃ = (g_x, g_y, 1): the normal matrix Σ Wᵢ ⊗ g̃ᵢg̃ᵢᵀ, the right-hand side Σ (Wᵢqᵢ) ⊗ g̃ᵢ and
//! Σ qᵢᵀWᵢqᵢ are summed in one pass; χ² = Σ qᵀWq − |L⁻¹ rhs|² (L the Cholesky factor). The
//! subtraction cancels up to ~1e7-fold at the minimum, so this runs in f64 on every backend.

// Indexed loops over the small fixed-size sums and the 6×6 factor mirror the kernel's.
#![allow(clippy::needless_range_loop)]

use crate::calib::problem::data::{Corner, StereoData};

/// Reals per corner row: v_l, p, m, ∂v_l/∂u, ∂v_l/∂v, a_u, a_v, c_u, c_v, e_u, e_v (3 each),
/// g_x, g_y (centred), padding.
pub const ROW: usize = 36;

/// κ of the taper: corners within κ pixel-noise standard deviations of the degenerate plane lose
/// their weight smoothly. Mirrored in `shaders/calib/affine_grid.wgsl` (a test checks).
pub const TAPER: f64 = 2.0;

/// |t·m| at or below which a corner carries no weight at all (its VOP is undetermined).
pub const MIN_DENOMINATOR: f64 = 1e-12;

/// Fewest corners with weight for a view to be fitted.
const MIN_CORNERS: u32 = 4;

fn cross(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: &[f64; 3], b: &[f64]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The per-corner rows of `data`, view by view as `data.corners`, grid positions centred on each
/// view's mean.
pub fn affine_rows(data: &StereoData) -> Vec<[f64; ROW]> {
    let [centre_l, centre_r] = data.centres();
    let b = (centre_r - centre_l).into();
    let mut rows = Vec::with_capacity(data.corners.len());
    for range in &data.views {
        let corners = &data.corners[range.clone()];
        let grid = |c: &Corner| {
            let (r, col) = data.board.grid_position(c.index);
            [col as f64 * data.board.square, r as f64 * data.board.square]
        };
        let mean = corners
            .iter()
            .map(grid)
            .fold([0.0; 2], |a, g| [a[0] + g[0], a[1] + g[1]])
            .map(|s| s / corners.len().max(1) as f64);
        for corner in corners {
            let v_l: [f64; 3] = corner.dirs[0].into_inner().into();
            let v_r: [f64; 3] = corner.dirs[1].into_inner().into();
            let column = |k: usize, axis: usize| -> [f64; 3] {
                corner.dir_jacobians[k].column(axis).into_owned().into()
            };
            let (dl_u, dl_v, dr_u, dr_v) = (column(0, 0), column(0, 1), column(1, 0), column(1, 1));
            let parts = [
                v_l,
                cross(&b, &v_r),
                cross(&v_l, &v_r),
                dl_u,
                dl_v,
                cross(&dl_u, &v_r),
                cross(&dl_v, &v_r),
                cross(&b, &dr_u),
                cross(&b, &dr_v),
                cross(&v_l, &dr_u),
                cross(&v_l, &dr_v),
            ];
            let mut row = [0.0; ROW];
            for (k, part) in parts.iter().enumerate() {
                row[3 * k..3 * k + 3].copy_from_slice(part);
            }
            let g = grid(corner);
            row[33] = g[0] - mean[0];
            row[34] = g[1] - mean[1];
            rows.push(row);
        }
    }
    rows
}

/// Below this ratio χ²/Σ qᵀWq the one-pass χ² has lost more than half its digits to the
/// subtraction, and the view is summed again from its residuals (noise-free data near the truth;
/// at 0.1 px of noise the ratio stays above ~2e-4).
pub const CANCELLATION: f64 = 1e-6;

/// One corner's terms under an axis: its position q = q′/d, its weight W = scale·adj, its taper.
#[derive(Debug, Clone, Copy)]
struct CornerTerms {
    /// q′ = d·q (no division).
    q_prime: [f64; 2],
    /// d = t·m.
    d: f64,
    /// Adjugate of d⁴(Σ + ρI): (a₁₁, a₁₂, a₂₂).
    adj: [f64; 3],
    /// d⁴ / ((d² + κ²σ_D²)·det(d⁴(Σ + ρI))): W = d²·d4_inverse·adj.
    d4_inverse: f64,
    /// The taper w.
    taper: f64,
    /// Grid position (centred).
    g: [f64; 2],
}

/// The terms of one corner under the axis t = n/n_z with the taper's κ; `None` in the
/// degenerate plane (|t·m| ≤ [`MIN_DENOMINATOR`]).
#[inline(always)]
fn corner_terms(row: &[f64; ROW], t: &[f64; 3], kappa: f64) -> Option<CornerTerms> {
    let d = dot(t, &row[6..9]);
    if !(d.abs() > MIN_DENOMINATOR) {
        return None;
    }
    let numerator = dot(t, &row[3..6]); // s = numerator / d
    let project = |w: &[f64]| [w[0] - w[2] * t[0], w[1] - w[2] * t[1]];
    let pv = project(&row[0..3]);
    // ∂D/∂pixel: left (t·a_u, t·a_v), right (t·e_u, t·e_v).
    let (ta_u, ta_v) = (dot(t, &row[15..18]), dot(t, &row[18..21]));
    let (te_u, te_v) = (dot(t, &row[27..30]), dot(t, &row[30..33]));
    let (tc_u, tc_v) = (dot(t, &row[21..24]), dot(t, &row[24..27]));
    // Columns of d²·J, J = ∂q/∂(u_l, v_l, u_r, v_r): no division until the weight. The two right
    // columns are cₖ·Π(v_l): only ρ = c₁² + c₂² enters Σ and its determinant.
    let left = |ta: f64, dv: &[f64]| {
        let p = project(dv);
        [
            numerator * (d * p[0] - ta * pv[0]),
            numerator * (d * p[1] - ta * pv[1]),
        ]
    };
    let (j0, j1) = (left(ta_u, &row[9..12]), left(ta_v, &row[12..15]));
    let (c1, c2) = (tc_u * d - numerator * te_u, tc_v * d - numerator * te_v);
    let rho = c1 * c1 + c2 * c2;
    let sxx = j0[0] * j0[0] + j1[0] * j1[0] + rho * pv[0] * pv[0];
    let sxy = j0[0] * j0[1] + j1[0] * j1[1] + rho * pv[0] * pv[1];
    let syy = j0[1] * j0[1] + j1[1] * j1[1] + rho * pv[1] * pv[1];
    // det(d⁴Σ) = Σ_{k<l} minors² (Cauchy–Binet, never negative).
    let minor = |a: &[f64; 2], b: &[f64; 2]| a[0] * b[1] - a[1] * b[0];
    let (m01, m0v, m1v) = (minor(&j0, &j1), minor(&j0, &pv), minor(&j1, &pv));
    let det = m01 * m01 + rho * (m0v * m0v + m1v * m1v);
    let trace = sxx + syy;
    let d2 = d * d;
    // The ridge 1e-12·tr Σ + 1e-30 of the explicit fit, in d⁴Σ's units.
    let ridge = 1e-12 * trace + 1e-30 * d2 * d2;
    let det_ridged = det + ridge * trace + ridge * ridge;
    let sigma_d2 = ta_u * ta_u + ta_v * ta_v + te_u * te_u + te_v * te_v;
    // taper = d²/(d² + κ²σ_D²); W = taper·d⁴·adj/det_ridged; one division per corner.
    let inverse = 1.0 / ((d2 + kappa * kappa * sigma_d2) * det_ridged);
    Some(CornerTerms {
        q_prime: [numerator * pv[0], numerator * pv[1]],
        d,
        adj: [syy + ridge, -sxy, sxx + ridge],
        d4_inverse: d2 * d2 * inverse,
        taper: d2 * det_ridged * inverse,
        g: [row[33], row[34]],
    })
}

/// The sums of one view's weighted affine fit under one axis.
#[derive(Debug, Clone, Copy, Default)]
struct ViewSums {
    /// W₁₁, W₁₂, W₂₂ times (g_x², g_x g_y, g_x) and (g_y², g_y, 1).
    s11: [f64; 6],
    s12: [f64; 6],
    s22: [f64; 6],
    /// (Wq)₁ g̃ and (Wq)₂ g̃.
    r1: [f64; 3],
    r2: [f64; 3],
    /// Σ qᵀWq.
    qwq: f64,
    /// Σ w (the tapers).
    weight: f64,
    /// Corners with weight.
    used: u32,
}

/// Adds one corner's terms.
#[inline(always)]
fn accumulate(sums: &mut ViewSums, c: &CornerTerms) {
    let scale = c.d * c.d * c.d4_inverse;
    let (w11, w12, w22) = (c.adj[0] * scale, c.adj[1] * scale, c.adj[2] * scale);
    let [gx, gy] = c.g;
    let g6 = [gx * gx, gx * gy, gx, gy * gy, gy, 1.0];
    for k in 0..6 {
        sums.s11[k] += w11 * g6[k];
        sums.s12[k] += w12 * g6[k];
        sums.s22[k] += w22 * g6[k];
    }
    // Wq = d⁵·inverse·adj·q′ = d·d4_inverse·adj·q′, qᵀWq = d4_inverse·q′ᵀ adj q′.
    let q = c.q_prime;
    let adj_q = [
        c.adj[0] * q[0] + c.adj[1] * q[1],
        c.adj[1] * q[0] + c.adj[2] * q[1],
    ];
    let wq_scale = c.d * c.d4_inverse;
    let g3 = [gx, gy, 1.0];
    for k in 0..3 {
        sums.r1[k] += wq_scale * adj_q[0] * g3[k];
        sums.r2[k] += wq_scale * adj_q[1] * g3[k];
    }
    sums.qwq += c.d4_inverse * (q[0] * adj_q[0] + q[1] * adj_q[1]);
    sums.weight += c.taper;
    sums.used += 1;
}

/// The one-pass fit of one view: (χ², dof, θ = (a₁₁, a₁₂, b₁, a₂₁, a₂₂, b₂)); `None` with fewer
/// than 4 weighted corners or a normal matrix that is not positive definite.
fn solve(sums: &ViewSums) -> Option<(f64, f64, [f64; 6])> {
    if sums.used < MIN_CORNERS {
        return None;
    }
    // g̃g̃ᵀ from its 6 unique entries (g_x², g_x g_y, g_x, g_y², g_y, 1).
    let block = |s: &[f64; 6]| [[s[0], s[1], s[2]], [s[1], s[3], s[4]], [s[2], s[4], s[5]]];
    let (b11, b12, b22) = (block(&sums.s11), block(&sums.s12), block(&sums.s22));
    let mut a = [[0.0; 6]; 6];
    for r in 0..3 {
        for c in 0..3 {
            a[r][c] = b11[r][c];
            a[r][c + 3] = b12[r][c];
            a[r + 3][c] = b12[r][c];
            a[r + 3][c + 3] = b22[r][c];
        }
    }
    let rhs = [
        sums.r1[0], sums.r1[1], sums.r1[2], sums.r2[0], sums.r2[1], sums.r2[2],
    ];
    // Cholesky a = L Lᵀ in place (lower triangle), then y = L⁻¹ rhs; multiplications by 1/Lₖₖ
    // as in the kernel, so the two round alike.
    let mut inverse = [0.0; 6];
    for k in 0..6 {
        let mut diagonal = a[k][k];
        for m in 0..k {
            diagonal -= a[k][m] * a[k][m];
        }
        if !(diagonal > 0.0) {
            return None;
        }
        a[k][k] = diagonal.sqrt();
        inverse[k] = 1.0 / a[k][k];
        for r in k + 1..6 {
            let mut value = a[r][k];
            for m in 0..k {
                value -= a[r][m] * a[k][m];
            }
            a[r][k] = value * inverse[k];
        }
    }
    let mut y = [0.0; 6];
    let mut explained = 0.0;
    for r in 0..6 {
        let mut value = rhs[r];
        for m in 0..r {
            value -= a[r][m] * y[m];
        }
        y[r] = value * inverse[r];
        explained += y[r] * y[r];
    }
    // θ = L⁻ᵀ y.
    let mut theta = [0.0; 6];
    for r in (0..6).rev() {
        let mut value = y[r];
        for m in r + 1..6 {
            value -= a[m][r] * theta[m];
        }
        theta[r] = value * inverse[r];
    }
    Some((
        (sums.qwq - explained).max(0.0),
        2.0 * sums.weight - 6.0,
        theta,
    ))
}

/// Σ rᵀWr of one corner under the fitted map θ (the exact second pass).
#[inline(always)]
fn residual_term(c: &CornerTerms, theta: &[f64; 6]) -> f64 {
    let [gx, gy] = c.g;
    let inv_d = 1.0 / c.d;
    let r = [
        c.q_prime[0] * inv_d - (theta[0] * gx + theta[1] * gy + theta[2]),
        c.q_prime[1] * inv_d - (theta[3] * gx + theta[4] * gy + theta[5]),
    ];
    let scale = c.d * c.d * c.d4_inverse;
    scale * (c.adj[0] * r[0] * r[0] + 2.0 * c.adj[1] * r[0] * r[1] + c.adj[2] * r[1] * r[1])
}

/// (χ², dof) of the corners `rows` (one view) under the unit axis `normal` (n_z > 0).
pub fn view_chi2(rows: &[[f64; ROW]], normal: &[f64; 3]) -> Option<(f64, f64)> {
    view_chi2_tapered(rows, normal, TAPER)
}

fn view_chi2_tapered(rows: &[[f64; ROW]], normal: &[f64; 3], kappa: f64) -> Option<(f64, f64)> {
    let t = [normal[0] / normal[2], normal[1] / normal[2], 1.0];
    let mut sums = ViewSums::default();
    for row in rows {
        if let Some(c) = corner_terms(row, &t, kappa) {
            accumulate(&mut sums, &c);
        }
    }
    let (mut chi2, dof, theta) = solve(&sums)?;
    if chi2 < CANCELLATION * sums.qwq {
        chi2 = rows
            .iter()
            .filter_map(|row| corner_terms(row, &t, kappa))
            .map(|c| residual_term(&c, &theta))
            .sum();
    }
    Some((chi2, dof))
}

/// The affine-grid cost Σχ² / Σdof of all views of `data` under `normal`, from the corners' rows
/// ([`affine_rows`]`(data)`, which the backends compute once); `None` when a view cannot be
/// fitted or no degree of freedom is left.
pub fn affine_grid_cost(data: &StereoData, rows: &[[f64; ROW]], normal: &[f64; 3]) -> Option<f64> {
    if !(normal[2] > 0.0) {
        return None;
    }
    let (mut chi2, mut dof) = (0.0, 0.0);
    for range in &data.views {
        let (c, d) = view_chi2(&rows[range.clone()], normal)?;
        chi2 += c;
        dof += d;
    }
    (dof > 0.0).then(|| chi2 / dof)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::costs::invariants::{affine_grid, projected_vops};
    use crate::calib::{Board, SceneSpec, Target, simulate};
    use crate::model::normal_from_tilt_azimuth;

    /// Without the taper the fused χ² equals the explicit weighted fit of
    /// [`invariants::affine_grid`](crate::calib::costs::invariants::affine_grid) (binocular VOPs solved by
    /// a 3×3 system, projected orthogonally, fitted by a 6×6 generalised least squares): another
    /// derivation of the same number.
    #[test]
    fn fused_sums_equal_the_explicit_weighted_fit() {
        let rig = crate::io::rig_from_json_str(
            include_str!("../../../data/example_rig.json"),
            "example".as_ref(),
        )
        .unwrap();
        let board = Target::Board(Board {
            rows: 6,
            cols: 9,
            square: 0.04,
        });
        let scene = simulate(&rig, &SceneSpec::pair(board, 6, 0.2, 3, 0, 1)).unwrap();
        let data = StereoData::from_observations(&rig, [0, 1], &scene.observations).unwrap();
        let mut worst: f64 = 0.0;
        for (tilt, azimuth) in [
            (8.05, 45.0),
            (0.0, 0.0),
            (3.0, -100.0),
            (15.0, 170.0),
            (25.0, 80.0),
        ] {
            let n = normal_from_tilt_azimuth(f64::to_radians(tilt), f64::to_radians(azimuth));
            for range in &data.views {
                let fused =
                    view_chi2_tapered(&affine_rows(&data)[range.clone()], &[n.x, n.y, n.z], 0.0)
                        .unwrap();
                let vops = projected_vops(&data, &data.corners[range.clone()], &n);
                let (chi2, dof) = affine_grid(&data, &vops).unwrap();
                assert_eq!(fused.1, dof as f64);
                let relative = (fused.0 - chi2).abs() / chi2;
                worst = worst.max(relative);
                // χ² = Σ qᵀWq − |y|² cancels up to ~1e7-fold near the minimum (Σ qᵀWq/χ² measured
                // ≥ 4.5e3 at the truth, larger for single views), so f64 rounding leaves ~1e-9.
                assert!(
                    relative < 1e-8,
                    "tilt {tilt} azimuth {azimuth}: {} vs {chi2}",
                    fused.0
                );
            }
        }
        println!("fused vs explicit affine-grid χ²: {worst:.1e} relative");
    }

    #[test]
    fn the_kernel_uses_the_same_taper() {
        let kernel = include_str!("../../../shaders/calib/affine_grid.wgsl");
        assert!(
            kernel.contains(&format!("const TAPER: real = {TAPER:?};")),
            "TAPER differs from {TAPER}"
        );
        assert!(kernel.contains(&format!("const ROW: u32 = {ROW}u;")));
        assert!(
            kernel.contains(&format!("const CANCELLATION: real = {CANCELLATION:e};")),
            "CANCELLATION differs"
        );
    }
}
