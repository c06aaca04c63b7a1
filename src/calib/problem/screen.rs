//! Gross corner errors found from the board's own shape in each image, before any model of the
//! refraction: a corner detected 50 px off ruins the invariants of the consecutive method (one
//! such corner outweighs a whole view), and no axis search can be trusted to expose it, since the
//! search may settle on an axis that gives that corner no weight.
//!
//! In one image the corners of a planar board are a smooth function of their grid position:
//! undistorted (the lens model of the rig) and bent into the water at the rig's port (Snell's
//! law about the port's axis, the ray's offset in the port left out), they are a homography of
//! the grid (perspective) moved by the small field of that offset. Per image, a homography H is
//! fitted to all corners (the direct linear transform on Hartley-normalised coordinates), which
//! leaves the smooth field e = p − H(g) (and the noise). Each corner's e is
//! predicted from the others of the 5 × 5 block of grid positions around it (shifted inside the
//! board at its edges) by a least-squares polynomial in the grid coordinates,
//! e ≈ Σ θₖ φₖ(x, y), φ = (1, x, y, x², xy, y²). The residual is standardised by the prediction's
//! own variance, r / √(1 + h) with h = φ₀ᵀ(ΦᵀΦ)⁻¹φ₀, so interior and edge corners compare alike,
//! and taken back to image pixels through the local Jacobian of the bending.
//! Where four rows and four columns of the block are present the polynomial is a cubic (the ten
//! monomials up to degree 3), else a quadratic. An outlier bends the fitted H only smoothly, which
//! the local polynomial absorbs. Measured on simulated scenes with boards tilted up to 60°: the
//! model error is at most 0.03 px (the pixels themselves, not bent into the water: 0.6 px at a
//! board's corner, and 3.4 px there behind a wide lens, k1 = −0.26, zoo seed 75; a quadratic of
//! the pixels alone, without H, misses by up to 3.4 px on the simulated scenes). The noise σ̂
//! comes from the median residual
//! (the median of |r| for isotropic Gaussian noise of σ per coordinate is σ√(2 ln 2)); a corner
//! is a suspect above max([`MIN_THRESHOLD_PX`], [`THRESHOLD_SIGMAS`] σ̂). Per image the worst
//! suspect is removed and the rest predicted again, so that one gross error does not also
//! condemn its neighbours, up to a quarter of the image's corners.
//!
//! Boards with fewer than 3 rows or columns cannot be screened (no quadratic); nothing is
//! flagged there. The screen finds gross errors only (above 2 px, or 8 σ̂): smaller ones are
//! left to the reprojection residuals of the fit.

use nalgebra::{Matrix2, Matrix3, Point2, SMatrix, SVector, Vector2, Vector3};
use rayon::prelude::*;

use crate::base::Board;
use crate::calib::problem::observations::{MIN_VIEW_CORNERS, SeenView};
use crate::model::snell::bent_into_water;
use crate::model::{Ports, Rig};

/// Width of the block of grid positions a corner is predicted from.
pub const WINDOW: usize = 5;

/// Smallest deviation, pixels, that makes a corner a suspect whatever the noise: far above the
/// local polynomial's model error (at most 0.03 px, measured on simulated scenes with boards
/// tilted up to 60°), and low enough that a 6 px error at a board's corner, whose prediction
/// from its neighbours is an extrapolation (standardised deviation 2.9 px), is found.
pub const MIN_THRESHOLD_PX: f64 = 2.0;

/// Deviation, in units of the estimated noise σ̂, that makes a corner a suspect.
pub const THRESHOLD_SIGMAS: f64 = 8.0;

/// Median of |r| / σ for a 2-D isotropic Gaussian: √(2 ln 2).
const MEDIAN_NORM: f64 = 1.177_410_022_515_474_6;

/// A corner whose position in one image does not follow the board's shape around it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Suspect {
    /// 0-based view.
    pub view: usize,
    /// The rig camera whose image it is off in.
    pub camera: usize,
    /// Corner index on the board (row-major).
    pub corner: usize,
    /// Its standardised deviation from the prediction of its neighbours, pixels.
    pub deviation_px: f64,
}

/// The result of screening every image of every view.
#[derive(Debug, Clone, PartialEq)]
pub struct Screening {
    /// The suspects, largest deviation first.
    pub suspects: Vec<Suspect>,
    /// Estimated corner noise σ̂ per coordinate, pixels, from the corners that are not suspects;
    /// `None` when no corner could be predicted (boards under 3 × 3).
    pub noise_px: Option<f64>,
    /// The deviation above which a corner is a suspect, pixels.
    pub threshold_px: f64,
}

impl Screening {
    /// Whether the corner image (view, camera, corner) is a suspect.
    pub fn is_suspect(&self, view: usize, camera: usize, corner: usize) -> bool {
        self.suspects
            .iter()
            .any(|s| (s.view, s.camera, s.corner) == (view, camera, corner))
    }

    /// `seen` without the suspects' corner images; `None` when an image would be left with fewer
    /// than [`MIN_VIEW_CORNERS`] corners (then every estimate uses them all).
    pub fn without_suspects(&self, seen: &[SeenView]) -> Option<Vec<SeenView>> {
        if self.suspects.is_empty() {
            return None;
        }
        let mut clean = seen.to_vec();
        for (v, view) in clean.iter_mut().enumerate() {
            for (k, corners) in &mut view.cameras {
                corners.retain(|&(i, _)| !self.is_suspect(v, *k, i));
                if corners.len() < MIN_VIEW_CORNERS {
                    return None;
                }
            }
        }
        Some(clean)
    }
}

/// The corners of one image of one view on the board grid: per index, `Some` of its field value
/// and the matrix taking a change of it back to image pixels.
type Image = Vec<Option<(Point2<f64>, Matrix2<f64>)>>;

/// Every image of every view, as (view, rig camera, corners): each corner's undistorted
/// direction bent into the water at the rig's port ([`bent_into_water`]), as a pixel offset from
/// the principal point (fx·x, fy·y of those normalised coordinates, times n_water / n_air so that
/// a pixel near the axis stays a pixel), minus the image's fitted homography of the grid.
///
/// Bent into the water, the corners are a homography of the grid up to the port's small offsets;
/// the pixels themselves carry the refraction's field, which near the edge of a wide lens bends
/// faster than the local polynomial follows (zoo seed 75, k1 = −0.26: a board's corner 3.4 px off
/// the prediction of its neighbours, and a noise σ̂ of 0.06 px where the corners' is 0.01).
fn images(rig: &Rig, board: &Board, seen: &[SeenView]) -> Vec<(usize, usize, Image)> {
    let mut out = Vec::new();
    for (v, view) in seen.iter().enumerate() {
        for (k, corners) in &view.cameras {
            let camera = &rig.cameras()[*k];
            let intrinsics = &camera.intrinsics;
            let (port, axis) = match rig.ports() {
                Ports::Shared(port) => (
                    port,
                    camera.cam_from_master.rotation * port.normal().into_inner(),
                ),
                Ports::PerCamera(ports) => (&ports[*k], ports[*k].normal().into_inner()),
            };
            let ratio = port.index_air() / port.index_water();
            let bent = |p: &Point2<f64>| -> Option<Vector2<f64>> {
                let x = intrinsics.normalized_from_img(p)?;
                let x = bent_into_water(&x, &axis, ratio).map_or(x, |w| w / ratio);
                Some(Vector2::new(intrinsics.fx * x.x, intrinsics.fy * x.y))
            };
            // Each corner's field value, and the inverse of the map's Jacobian there (central
            // differences over half a pixel), so that deviations are measured in pixels.
            let h = 0.5;
            let undistorted: Vec<(usize, Vector2<f64>, Matrix2<f64>)> = corners
                .iter()
                .filter_map(|(i, p)| {
                    let q = bent(p)?;
                    let along =
                        |d: Vector2<f64>| Some((bent(&(p + d))? - bent(&(p - d))?) / (2.0 * h));
                    let jacobian = Matrix2::from_columns(&[
                        along(Vector2::new(h, 0.0))?,
                        along(Vector2::new(0.0, h))?,
                    ]);
                    Some((*i, q, jacobian.try_inverse()?))
                })
                .collect();
            out.push((v, *k, smooth_field(board, &undistorted)));
        }
    }
    out
}

/// One image's field e = p − H(g) on the board grid, from its corners (index, undistorted pixel
/// offset, the matrix back to image pixels).
fn smooth_field(board: &Board, corners: &[(usize, Vector2<f64>, Matrix2<f64>)]) -> Image {
    let points: Vec<(Vector2<f64>, Vector2<f64>)> = corners
        .iter()
        .map(|&(i, p, _)| {
            let (r, col) = board.grid_position(i);
            (Vector2::new(col as f64, r as f64), p)
        })
        .collect();
    let homography = fit_homography(&points);
    let mut image = vec![None; board.corners()];
    for (&(index, _, to_pixels), (g, p)) in corners.iter().zip(&points) {
        let e = homography.as_ref().map_or(*p, |h| p - apply(h, g));
        image[index] = Some((Point2::from(e), to_pixels));
    }
    image
}

/// Hartley normalisation of 2-D points: T with T·(x, 1) centred, mean distance √2.
fn normalisation(points: impl Iterator<Item = Vector2<f64>> + Clone) -> Matrix3<f64> {
    let n = points.clone().count().max(1) as f64;
    let mean = points.clone().fold(Vector2::zeros(), |a, p| a + p) / n;
    let spread = points.map(|p| (p - mean).norm()).sum::<f64>() / n;
    let s = if spread > 0.0 {
        std::f64::consts::SQRT_2 / spread
    } else {
        1.0
    };
    Matrix3::new(s, 0.0, -s * mean.x, 0.0, s, -s * mean.y, 0.0, 0.0, 1.0)
}

/// The homography p ≈ H(g) through (grid, pixel) pairs by the normalised direct linear
/// transform: the eigenvector of the smallest eigenvalue of AᵀA. `None` with fewer than 4 pairs
/// or a degenerate fit.
fn fit_homography(points: &[(Vector2<f64>, Vector2<f64>)]) -> Option<Matrix3<f64>> {
    if points.len() < 4 {
        return None;
    }
    let tg = normalisation(points.iter().map(|(g, _)| *g));
    let tp = normalisation(points.iter().map(|(_, p)| *p));
    let mut ata = SMatrix::<f64, 9, 9>::zeros();
    for (g, p) in points {
        let g = tg * Vector3::new(g.x, g.y, 1.0);
        let p = tp * Vector3::new(p.x, p.y, 1.0);
        let rows = [
            SVector::<f64, 9>::from_column_slice(&[
                -g.x,
                -g.y,
                -1.0,
                0.0,
                0.0,
                0.0,
                p.x * g.x,
                p.x * g.y,
                p.x,
            ]),
            SVector::<f64, 9>::from_column_slice(&[
                0.0,
                0.0,
                0.0,
                -g.x,
                -g.y,
                -1.0,
                p.y * g.x,
                p.y * g.y,
                p.y,
            ]),
        ];
        for row in rows {
            ata += row * row.transpose();
        }
    }
    let eigen = ata.symmetric_eigen();
    let smallest = (0..9).min_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]))?;
    let h = eigen.eigenvectors.column(smallest);
    let normalised = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let homography = tp.try_inverse()? * normalised * tg;
    homography
        .iter()
        .all(|v| v.is_finite())
        .then_some(homography)
}

fn apply(h: &Matrix3<f64>, g: &Vector2<f64>) -> Vector2<f64> {
    let q = h * Vector3::new(g.x, g.y, 1.0);
    Vector2::new(q.x / q.z, q.y / q.z)
}

/// The first of `WINDOW` consecutive grid lines around `at` inside `0..size`.
fn window_start(at: usize, size: usize) -> usize {
    at.saturating_sub(WINDOW / 2)
        .min(size.saturating_sub(WINDOW))
}

/// The standardised deviation of corner `index` from the polynomial through the other corners
/// of its block that are present and not `excluded`; `None` when they cannot fix a quadratic.
fn deviation(board: &Board, image: &Image, excluded: &[bool], index: usize) -> Option<f64> {
    let (rows, cols) = (board.rows, board.cols);
    if rows < 3 || cols < 3 {
        return None;
    }
    let (r0, c0) = board.grid_position(index);
    let (rs, cs) = (window_start(r0, rows), window_start(c0, cols));
    let mut points = Vec::with_capacity(WINDOW * WINDOW);
    let (mut used_rows, mut used_cols) = (0u32, 0u32);
    for r in rs..(rs + WINDOW).min(rows) {
        for c in cs..(cs + WINDOW).min(cols) {
            let i = r * cols + c;
            if i == index || excluded[i] {
                continue;
            }
            let Some((p, _)) = image[i] else { continue };
            points.push((c as f64 - c0 as f64, r as f64 - r0 as f64, p));
            used_rows |= 1 << (r - rs);
            used_cols |= 1 << (c - cs);
        }
    }
    // A cubic where four rows and columns fix it, else a quadratic.
    let cubic = used_rows.count_ones() >= 4 && used_cols.count_ones() >= 4 && points.len() >= 14;
    let terms = if cubic { 10 } else { 6 };
    if points.len() < terms + 3 || used_rows.count_ones() < 3 || used_cols.count_ones() < 3 {
        return None;
    }
    let (p, to_pixels) = image[index]?;
    let (predicted, leverage) = if cubic {
        predict::<10>(&points)?
    } else {
        predict::<6>(&points)?
    };
    Some((to_pixels * (p.coords - predicted)).norm() / (1.0 + leverage).sqrt())
}

/// The least-squares polynomial of the first `N` monomials (1, x, y, x², xy, y², x³, x²y, xy², y³)
/// through `points` (x, y, value), evaluated at (0, 0): (θ₀, its variance factor e₀ᵀ(ΦᵀΦ)⁻¹e₀).
fn predict<const N: usize>(points: &[(f64, f64, Point2<f64>)]) -> Option<(Vector2<f64>, f64)> {
    let mut normal = SMatrix::<f64, N, N>::zeros();
    let (mut rhs_u, mut rhs_v) = (SVector::<f64, N>::zeros(), SVector::<f64, N>::zeros());
    for &(x, y, p) in points {
        let all = [
            1.0,
            x,
            y,
            x * x,
            x * y,
            y * y,
            x * x * x,
            x * x * y,
            x * y * y,
            y * y * y,
        ];
        let phi = SVector::<f64, N>::from_fn(|k, _| all[k]);
        normal += phi * phi.transpose();
        rhs_u += phi * p.x;
        rhs_v += phi * p.y;
    }
    // The prediction at (0, 0) is θ₀ = e₀ᵀ(ΦᵀΦ)⁻¹Φᵀp; its variance factor is the (0, 0) entry of
    // (ΦᵀΦ)⁻¹, and e₀ᵀ(ΦᵀΦ)⁻¹ is the solution of (ΦᵀΦ) w = e₀.
    let cholesky = normal.cholesky()?;
    let w = cholesky.solve(&SVector::<f64, N>::from_fn(
        |k, _| if k == 0 { 1.0 } else { 0.0 },
    ));
    Some((Vector2::new(w.dot(&rhs_u), w.dot(&rhs_v)), w[0]))
}

fn deviations(board: &Board, image: &Image, excluded: &[bool]) -> Vec<(usize, f64)> {
    (0..image.len())
        .filter(|&i| image[i].is_some() && !excluded[i])
        .filter_map(|i| deviation(board, image, excluded, i).map(|d| (i, d)))
        .collect()
}

fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    Some(values[values.len() / 2])
}

/// Screens every image of every view of `seen` (observations of `board` by the cameras of
/// `rig`; see the module documentation).
pub fn screen(rig: &Rig, board: &Board, seen: &[SeenView]) -> Screening {
    let images = images(rig, board, seen);
    let none = vec![false; board.corners()];
    // Every image alone, in parallel: first without exclusions (for σ̂), then removing suspects.
    let first: Vec<Vec<(usize, f64)>> = images
        .par_iter()
        .map(|(_, _, image)| deviations(board, image, &none))
        .collect();
    let mut all: Vec<f64> = first.iter().flatten().map(|&(_, d)| d).collect();
    let Some(median_first) = median(&mut all) else {
        return Screening {
            suspects: Vec::new(),
            noise_px: None,
            threshold_px: f64::INFINITY,
        };
    };
    let threshold = (THRESHOLD_SIGMAS * median_first / MEDIAN_NORM).max(MIN_THRESHOLD_PX);
    let screened: Vec<(Vec<Suspect>, Vec<f64>)> = images
        .par_iter()
        .zip(first)
        .map(|((view, camera, image), mut found)| {
            let mut excluded = none.clone();
            let mut suspects = Vec::new();
            let present = image.iter().filter(|c| c.is_some()).count();
            loop {
                let worst = found.iter().copied().max_by(|a, b| a.1.total_cmp(&b.1));
                match worst {
                    Some((i, d)) if d > threshold && 4 * (suspects.len() + 1) <= present => {
                        excluded[i] = true;
                        suspects.push(Suspect {
                            view: *view,
                            camera: *camera,
                            corner: i,
                            deviation_px: d,
                        });
                        found = deviations(board, image, &excluded);
                    }
                    _ => return (suspects, found.into_iter().map(|(_, d)| d).collect()),
                }
            }
        })
        .collect();
    let mut suspects: Vec<Suspect> = screened
        .iter()
        .flat_map(|(s, _)| s.iter().copied())
        .collect();
    let mut kept: Vec<f64> = screened.into_iter().flat_map(|(_, k)| k).collect();
    suspects.sort_by(|a, b| b.deviation_px.total_cmp(&a.deviation_px));
    let noise_px = median(&mut kept).map(|m| m / MEDIAN_NORM);
    Screening {
        suspects,
        noise_px,
        threshold_px: threshold,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::{SceneSpec, Target, simulate};

    const BOARD: Board = Board {
        rows: 6,
        cols: 9,
        square: 0.04,
    };

    /// A simulated scene with gross errors (view, corner, camera, pixels) added: the rig and the
    /// views.
    fn data_with(
        noise: f64,
        seed: u64,
        tilt_deg: f64,
        errors: &[(usize, usize, usize, f64)],
    ) -> (Rig, Vec<SeenView>) {
        let rig = crate::io::rig_from_json_str(
            include_str!("../../../data/example_rig.json"),
            "example".as_ref(),
        )
        .unwrap();
        let mut spec = SceneSpec::pair(Target::Board(BOARD), 12, noise, seed, 0, 1);
        spec.max_target_tilt = tilt_deg.to_radians();
        let mut scene = simulate(&rig, &spec).unwrap();
        for &(v, i, k, size) in errors {
            let p = scene.observations.views[v].images[k].corners[i]
                .as_mut()
                .unwrap();
            p.x += size * 0.6;
            p.y -= size * 0.8;
        }
        let seen = scene.observations.resolve(&rig).unwrap();
        (rig, seen)
    }

    fn data(noise: f64, seed: u64, tilt_deg: f64) -> (Rig, Vec<SeenView>) {
        data_with(noise, seed, tilt_deg, &[])
    }

    #[test]
    fn clean_boards_have_no_suspects_and_the_noise_is_estimated() {
        for (noise, seed, tilt) in [
            (0.0, 1, 60.0),
            (0.0, 6, 45.0),
            (0.125, 2, 45.0),
            (0.125, 7, 60.0),
            (0.5, 3, 60.0),
            (1.0, 4, 30.0),
        ] {
            let (rig, seen) = data(noise, seed, tilt);
            let screening = screen(&rig, &BOARD, &seen);
            let largest = screening.suspects.first().map_or(0.0, |s| s.deviation_px);
            let images = images(&rig, &BOARD, &seen);
            let none = vec![false; 54];
            let d = images
                .iter()
                .flat_map(|(_, _, image)| deviations(&BOARD, image, &none))
                .map(|(_, d)| d)
                .fold(0.0, f64::max);
            println!(
                "noise {noise} px: σ̂ {:?} px, threshold {:.2} px, {} suspects, largest deviation {d:.3} px",
                screening.noise_px,
                screening.threshold_px,
                screening.suspects.len()
            );
            assert!(
                screening.suspects.is_empty(),
                "noise {noise}: {:?} (largest {largest})",
                screening.suspects
            );
            let sigma = screening.noise_px.unwrap();
            // Standardised residuals are unbiased; the model error of the local cubic is small
            // (largest deviation without noise: 0.03 px).
            assert!(
                (sigma - noise).abs() < 0.1 * noise + 0.02,
                "noise {noise}: σ̂ {sigma}"
            );
        }
    }

    #[test]
    fn gross_errors_are_found_where_they_are() {
        // Corner positions (view, corner) with a gross error in one image: interior, edge, the
        // board's corner, and two neighbours in one view.
        let errors = [
            (0, 3, 0, 40.0),
            (2, 17, 1, 12.0),
            (5, 0, 0, 25.0),
            (7, 30, 1, 50.0),
            (7, 31, 1, 30.0),
            (9, 53, 0, 6.0),
        ];
        let (rig, seen) = data_with(0.2, 5, 45.0, &errors);
        let screening = screen(&rig, &BOARD, &seen);
        let mut found: Vec<(usize, usize, usize)> = screening
            .suspects
            .iter()
            .map(|s| (s.view, s.corner, s.camera))
            .collect();
        found.sort();
        let mut expected: Vec<(usize, usize, usize)> =
            errors.iter().map(|&(v, i, k, _)| (v, i, k)).collect();
        expected.sort();
        assert_eq!(found, expected, "{:?}", screening.suspects);
        let reduced = screening.without_suspects(&seen).unwrap();
        let count = |views: &[SeenView]| views.iter().map(SeenView::observations).sum::<usize>();
        assert_eq!(count(&reduced), count(&seen) - errors.len());
        assert_eq!(reduced.len(), seen.len());
        for s in &screening.suspects {
            assert!(
                reduced[s.view]
                    .corners_of(s.camera)
                    .unwrap()
                    .iter()
                    .all(|&(i, _)| i != s.corner)
            );
        }
    }
}
