//! The inner corners a chessboard grid missed, filled in (issue 45: a backscatter speck on one
//! corner hides it from the ChESS front end, and a grid of 53 of 54 corners is not a board).
//!
//! A grid qualifies when its labels span the board's shape and it misses at most
//! [`MAX_FILLED_FRACTION`] of the corners, every border line of the grid keeping at least half of
//! its corners (so the extent is held by many corners, not by one stray label). Each missing
//! corner is then
//!
//! 1. **predicted** by the homography of the grid's found corners within
//!    [`LOCAL_HOMOGRAPHY_RADIUS`] squares of it (at least [`MIN_FILL_NEIGHBOURS`] of them),
//!    which also gives the board's two axes there (pixels per square);
//! 2. **checked** to be a chessboard corner on the image: the four squares around the prediction
//!    must alternate, the two on one diagonal at least [`MIN_CONTRAST`] grey levels lighter than
//!    the two on the other ([`corner_pattern`], medians over the middle of each square, away
//!    from the corner where a speck sits). A prediction that lands on something else (an
//!    occluder, the background) rejects the board: it is not the whole board;
//! 3. **refined** on the image ([`refine_corner`]): the corner is the point every edge line of
//!    the window passes through, as in OpenCV's `cornerSubPix` (each pixel's gradient g is
//!    normal to the vector from the corner q to the pixel p on an edge: gᵀ(p − q) = 0, solved
//!    in least squares), made robust to a speck: only pixels whose gradient is normal to one of
//!    the board's two axes there and points from the dark square to the light one count, and
//!    each is weighted by Tukey's biweight of its distance from its edge line (iteratively
//!    reweighted), so the speck's radial gradients drop out. When the refinement cannot place
//!    the corner reliably (saturated window, too few edge pixels, no convergence, a move of more
//!    than [`MAX_REFINE_SHIFT_PX`] from the prediction) the prediction stands, and the
//!    detection says so ([`FilledCorner::unrefined`]): a chessboard's detection holds every
//!    corner.
//!
//! Written here, not taken from calib-targets: its recall boosters (interior gap fill, line
//! extension, geometry-only recovery) attach existing ChESS corners to empty cells, and a corner
//! under a speck has no ChESS corner to attach; its saddle-point refiner (a quadratic fitted to
//! the 5 × 5 pixels at the corner) is what the speck spoils, and is not public API of
//! calib-targets (it lives in `chess-corners-core`, not a dependency of flatport).

use image::GrayImage;
use nalgebra::{DMatrix, Matrix2, Point2, Vector2};

use super::{LOCAL_HOMOGRAPHY_RADIUS, MIN_CONTRAST, apply, bilinear, fit_homography};

/// Most corners a grid may miss and still be filled in, as a fraction of the board's corners:
/// 10 % (5 of a 9 × 6 board's 54).
pub const MAX_FILLED_FRACTION: f64 = 0.1;

/// Fewest found corners within [`LOCAL_HOMOGRAPHY_RADIUS`] squares of a missing corner for its
/// prediction: 6 (a board's corner has 8 at most).
pub const MIN_FILL_NEIGHBOURS: usize = 6;

/// Farthest the refinement may move a filled corner from its prediction, pixels, before the
/// prediction is kept instead.
pub const MAX_REFINE_SHIFT_PX: f64 = 1.0;

/// Half-size of the refinement's window as a fraction of the local square side (the nearest
/// other corner's edges lie a whole side away), between [`MIN_REFINE_WINDOW_PX`] and
/// [`MAX_REFINE_WINDOW_PX`].
const REFINE_WINDOW_REL: f64 = 0.45;
const MIN_REFINE_WINDOW_PX: f64 = 4.0;
const MAX_REFINE_WINDOW_PX: f64 = 20.0;

/// Largest angle between a pixel's gradient and the normal of the board axis it is taken to lie
/// along (degrees).
const EDGE_ANGLE_TOL_DEG: f64 = 20.0;

/// Tukey's biweight scales (pixels of distance from the edge line): a wide pass from the
/// prediction, then a narrow one.
const TUKEY_WIDE_PX: f64 = 3.0;
const TUKEY_NARROW_PX: f64 = 1.5;

/// Fewest edge pixels (inside half the biweight's scale of their edge line) along each of the
/// two axes for a refined corner to stand.
const MIN_EDGE_PIXELS: usize = 6;

/// Fraction of the window's dark-square pixels at the top of the grey scale (≥ 250) that makes
/// the window saturated: a board's dark square never is.
const MAX_SATURATED_DARK: f64 = 0.1;

/// A corner the chessboard grid missed, which [`super::detect_board`] filled in.
#[derive(Debug, Clone, PartialEq)]
pub struct FilledCorner {
    /// Where the detection puts it (the same pixel in every ordering).
    pub pixel: Point2<f64>,
    /// Where the homography of its grid neighbours put it.
    pub predicted: Point2<f64>,
    /// `None` when the image placed it ([`refine_corner`]); otherwise why `pixel` is the
    /// prediction.
    pub unrefined: Option<Unrefined>,
}

/// Why a filled corner's refinement was not kept.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Unrefined {
    /// Over a tenth of the window's dark-square pixels at the top of the grey scale.
    Saturated,
    /// Fewer than 6 edge pixels along one of the board's axes.
    FewEdges,
    /// The reweighted solution did not settle.
    NoConvergence,
    /// It moved farther than [`MAX_REFINE_SHIFT_PX`] from the prediction.
    Moved {
        /// The move, pixels.
        px: f64,
    },
}

impl std::fmt::Display for Unrefined {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Unrefined::Saturated => write!(f, "its window is saturated"),
            Unrefined::FewEdges => write!(f, "too few edge pixels around it"),
            Unrefined::NoConvergence => write!(f, "the refinement did not converge"),
            Unrefined::Moved { px } => write!(
                f,
                "the refinement moved it {px:.2} px (over {MAX_REFINE_SHIFT_PX} px) from the prediction"
            ),
        }
    }
}

/// Fills the missing corners of `grid` (`grid[j·w + i]`, labels i across, j down, `None` where
/// missing) in place, on `image` (as read): what [`super::detect_board`] does with a grid that
/// misses corners. `None` (the grid left as it was) when the grid does not qualify or some
/// prediction is not a chessboard corner on the image (the rules in the module's documentation).
pub fn fill_grid(
    grid: &mut [Option<Point2<f64>>],
    w: usize,
    h: usize,
    image: &GrayImage,
) -> Option<Vec<FilledCorner>> {
    let smoothed = calib_targets::detect::preprocess(image, super::PRE_BLUR_PX);
    fill_missing(grid, w, h, image, &smoothed)
}

/// [`fill_grid`] with the image the grid was found in (`smoothed`, [`super::PRE_BLUR_PX`]) at
/// hand; `raw` is the image as read.
pub(super) fn fill_missing(
    grid: &mut [Option<Point2<f64>>],
    w: usize,
    h: usize,
    raw: &GrayImage,
    smoothed: &GrayImage,
) -> Option<Vec<FilledCorner>> {
    let missing: Vec<usize> = (0..grid.len()).filter(|&k| grid[k].is_none()).collect();
    if missing.is_empty() {
        return Some(Vec::new());
    }
    if missing.len() as f64 > MAX_FILLED_FRACTION * grid.len() as f64 || w < 2 || h < 2 {
        return None;
    }
    let found_on = |cells: &mut dyn Iterator<Item = usize>| -> (usize, usize) {
        cells.fold((0, 0), |(found, all), k| {
            (found + usize::from(grid[k].is_some()), all + 1)
        })
    };
    let borders = [
        found_on(&mut (0..w)),
        found_on(&mut ((h - 1) * w..h * w)),
        found_on(&mut (0..h).map(|j| j * w)),
        found_on(&mut (0..h).map(|j| j * w + w - 1)),
    ];
    if borders.iter().any(|&(found, all)| 2 * found < all) {
        return None;
    }
    let r = LOCAL_HOMOGRAPHY_RADIUS as i64;
    let mut filled = Vec::with_capacity(missing.len());
    for &k in &missing {
        let (i, j) = ((k % w) as i64, (k / w) as i64);
        let pairs: Vec<(Point2<f64>, Point2<f64>)> = (0..grid.len())
            .filter_map(|n| {
                let (ni, nj) = ((n % w) as i64, (n / w) as i64);
                let near = (ni - i).abs() <= r && (nj - j).abs() <= r;
                grid[n]
                    .filter(|_| near)
                    .map(|p| (Point2::new(ni as f64, nj as f64), p))
            })
            .collect();
        if pairs.len() < MIN_FILL_NEIGHBOURS {
            return None;
        }
        let (predicted, along_i, along_j) = predict(&pairs, Point2::new(i as f64, j as f64))?;
        let pattern = corner_pattern(smoothed, predicted, along_i, along_j)?;
        let refined = refine_corner(raw, smoothed, predicted, along_i, along_j, pattern);
        filled.push((k, predicted, refined));
    }
    Some(
        filled
            .into_iter()
            .map(|(k, predicted, refined)| {
                let corner = match refined {
                    Ok(pixel) => FilledCorner {
                        pixel,
                        predicted,
                        unrefined: None,
                    },
                    Err(why) => FilledCorner {
                        pixel: predicted,
                        predicted,
                        unrefined: Some(why),
                    },
                };
                grid[k] = Some(corner.pixel);
                corner
            })
            .collect(),
    )
}

/// Fewest neighbours for the quadratic correction of [`predict`] (6 coefficients per coordinate).
const MIN_QUADRATIC_NEIGHBOURS: usize = 12;

/// The pixel of grid label `at` from `pairs` (label, pixel) of its neighbours, and the board's
/// two axes there (pixels per square, along i and along j): the homography H of the pairs
/// ([`fit_homography`]), plus, with at least 12 pairs, the constant term of a quadratic in the
/// label offset (1, di, dj, di², di·dj, dj²) fitted in least squares to the pixels' residuals
/// from H. Through a flat port the board is no homography of the image: on the exact corners
/// of the 48 chessboard images of python/tests/test_detector_vs_opencv.py (imaging 1 and 2),
/// predicting each inner corner from those within 2 squares missed by 0.26 px RMS (0.73 px at
/// most) with H alone and by 0.041 px RMS (0.17 px at most) with the correction; with noise
/// of 0.15 px on the neighbours (a degraded image's corners), 0.11 px RMS. `None` when the
/// pairs fix no homography.
pub fn predict(
    pairs: &[(Point2<f64>, Point2<f64>)],
    at: Point2<f64>,
) -> Option<(Point2<f64>, Vector2<f64>, Vector2<f64>)> {
    let homography = fit_homography(pairs)?;
    let mut correction = Vector2::zeros();
    if pairs.len() >= MIN_QUADRATIC_NEIGHBOURS {
        let mut a = DMatrix::<f64>::zeros(pairs.len(), 6);
        let mut b = DMatrix::<f64>::zeros(pairs.len(), 2);
        for (k, (label, pixel)) in pairs.iter().enumerate() {
            let (x, y) = (label.x - at.x, label.y - at.y);
            let row = [1.0, x, y, x * x, x * y, y * y];
            for (c, value) in row.iter().enumerate() {
                a[(k, c)] = *value;
            }
            let residual = pixel - apply(&homography, *label)?;
            b[(k, 0)] = residual.x;
            b[(k, 1)] = residual.y;
        }
        let solution = a.svd(true, true).solve(&b, 1e-12).ok()?;
        correction = Vector2::new(solution[(0, 0)], solution[(0, 1)]);
    }
    let predicted = apply(&homography, at)? + correction;
    let step = |d: Vector2<f64>| -> Option<Vector2<f64>> {
        Some(apply(&homography, at + d * 0.5)? - apply(&homography, at - d * 0.5)?)
    };
    Some((predicted, step(Vector2::x())?, step(Vector2::y())?))
}

/// The squares around a chessboard corner at `corner`, the board's axes there being `along_i`
/// and `along_j` (pixels per square): which diagonal is light, `light` = +1 when the squares at
/// +i+j and −i−j are (−1 for the other diagonal), and the contrast (grey levels, the darker
/// light square less the lighter dark one); `None` when that contrast is below
/// [`MIN_CONTRAST`] (no alternating squares: not a chessboard corner). Each square's grey is the
/// median of 25 samples over its middle (0.3 … 0.7 of a side from the corner along each axis).
pub fn corner_pattern(
    image: &GrayImage,
    corner: Point2<f64>,
    along_i: Vector2<f64>,
    along_j: Vector2<f64>,
) -> Option<Pattern> {
    let square = |si: f64, sj: f64| -> Option<f64> {
        let mut values = Vec::with_capacity(25);
        for a in 0..5 {
            for b in 0..5 {
                let (u, v) = (0.3 + 0.1 * a as f64, 0.3 + 0.1 * b as f64);
                let p = corner + along_i * (si * u) + along_j * (sj * v);
                values.push(bilinear(image, p.x, p.y)?);
            }
        }
        values.sort_by(f64::total_cmp);
        Some(values[values.len() / 2])
    };
    let (pp, mm) = (square(1.0, 1.0)?, square(-1.0, -1.0)?);
    let (pm, mp) = (square(1.0, -1.0)?, square(-1.0, 1.0)?);
    let plus_light = pp.min(mm) - pm.max(mp);
    let minus_light = pm.min(mp) - pp.max(mm);
    let (light, contrast) = if plus_light >= minus_light {
        (1.0, plus_light)
    } else {
        (-1.0, minus_light)
    };
    (contrast >= MIN_CONTRAST).then_some(Pattern { light, contrast })
}

/// The squares around a corner, as [`corner_pattern`] finds them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pattern {
    /// +1 when the squares at +i+j and −i−j are the light ones, −1 otherwise.
    pub light: f64,
    /// The darker light square's grey less the lighter dark square's (grey levels).
    pub contrast: f64,
}

/// Grey levels over a rectangle of pixels: columns x0 … x0 + width − 1, rows y0 … y0 + height − 1.
struct Tile {
    x0: i64,
    y0: i64,
    width: i64,
    height: i64,
    values: Vec<f64>,
}

impl Tile {
    /// `image` over the rectangle, pixels outside the image taken from its nearest edge.
    fn from_image(image: &GrayImage, x0: i64, y0: i64, width: i64, height: i64) -> Self {
        let (w, h) = (i64::from(image.width()), i64::from(image.height()));
        let mut values = Vec::with_capacity((width * height) as usize);
        for y in y0..y0 + height {
            for x in x0..x0 + width {
                let (cx, cy) = (x.clamp(0, w - 1) as u32, y.clamp(0, h - 1) as u32);
                values.push(f64::from(image.get_pixel(cx, cy).0[0]));
            }
        }
        Self {
            x0,
            y0,
            width,
            height,
            values,
        }
    }

    fn at(&self, x: i64, y: i64) -> f64 {
        self.values[((y - self.y0) * self.width + (x - self.x0)) as usize]
    }

    /// The minimum (`erode`) or maximum over the disc `offsets` around every pixel, on the
    /// rectangle `margin` pixels inside this one (the offsets reach at most `margin`).
    fn morph(&self, offsets: &[(i64, i64)], margin: i64, erode: bool) -> Self {
        let (x0, y0) = (self.x0 + margin, self.y0 + margin);
        let (width, height) = (self.width - 2 * margin, self.height - 2 * margin);
        let mut values = Vec::with_capacity((width * height).max(0) as usize);
        for y in y0..y0 + height {
            for x in x0..x0 + width {
                let around = offsets.iter().map(|&(dx, dy)| self.at(x + dx, y + dy));
                values.push(if erode {
                    around.fold(f64::INFINITY, f64::min)
                } else {
                    around.fold(f64::NEG_INFINITY, f64::max)
                });
            }
        }
        Self {
            x0,
            y0,
            width,
            height,
            values,
        }
    }

    /// Sobel gradient (grey levels per pixel) at (x, y), at least one pixel inside the tile.
    fn sobel(&self, x: i64, y: i64) -> Vector2<f64> {
        let g = |dx: i64, dy: i64| self.at(x + dx, y + dy);
        let gx = (g(1, -1) + 2.0 * g(1, 0) + g(1, 1) - g(-1, -1) - 2.0 * g(-1, 0) - g(-1, 1)) / 8.0;
        let gy = (g(-1, 1) + 2.0 * g(0, 1) + g(1, 1) - g(-1, -1) - 2.0 * g(0, -1) - g(1, -1)) / 8.0;
        Vector2::new(gx, gy)
    }
}

/// Tukey's biweight of residual `r` at scale `c`: (1 − (r/c)²)² inside ±c, 0 outside.
fn tukey(r: f64, c: f64) -> f64 {
    let t = r / c;
    if t.abs() < 1.0 {
        (1.0 - t * t).powi(2)
    } else {
        0.0
    }
}

/// Radius of the disc of the grey opening before the refinement, as a fraction of the square
/// side, between 2 and 5 px: wide enough to erase a speck of σ up to ~2 px (backscatter's are
/// 0.5–3 px), narrow enough to leave the edges a window to refine on.
const OPENING_REL: f64 = 0.15;
const MIN_OPENING_PX: f64 = 2.0;
const MAX_OPENING_PX: f64 = 5.0;

/// A chessboard corner near `predicted`, the board's axes there being `along_i` and `along_j`
/// (pixels per square) and its squares `pattern`.
///
/// The window: pixels p between ρ + 2 px and 0.45 of a side (4 … 20 px) of the prediction,
/// ρ = 0.15 of a side (2 … 5 px). Its grey levels (of `smoothed`) go through a grey opening
/// with a disc of radius ρ (the minimum over the disc, then the maximum): a bright speck
/// narrower than the disc is erased, and a straight edge is kept as it is (only the light
/// squares' tips within ρ of the corner are rounded off, hence the hole in the window).
///
/// The corner: the point q that the window's edge lines pass through, q = argmin Σ w_p
/// (ĝ_pᵀ(p − q))², ĝ_p the unit (Sobel) gradient of the opened window, as `cornerSubPix` solves
/// it. A pixel counts for an axis when ĝ_p is within 20° of that axis's normal, pointing towards
/// the light square on the pixel's side of the corner, and |g_p| is at least a twentieth of the
/// squares' contrast; w_p = |g_p| · Tukey(ĝ_pᵀ(p − q)), with Tukey's scale 3 px and then 1.5
/// px, reweighted until q moves less than 0.001 px. Pixel centres are at whole coordinates.
/// Errs as [`Unrefined`] says; `raw` (the image as read) is only looked at for saturation.
pub fn refine_corner(
    raw: &GrayImage,
    smoothed: &GrayImage,
    predicted: Point2<f64>,
    along_i: Vector2<f64>,
    along_j: Vector2<f64>,
    pattern: Pattern,
) -> Result<Point2<f64>, Unrefined> {
    let side = along_i.norm().min(along_j.norm());
    let radius = (REFINE_WINDOW_REL * side).clamp(MIN_REFINE_WINDOW_PX, MAX_REFINE_WINDOW_PX);
    let rho = (OPENING_REL * side).clamp(MIN_OPENING_PX, MAX_OPENING_PX);
    let hole = rho + 2.0;
    // Board coordinates (u along i, v along j, in squares) of an image offset.
    let to_board = Matrix2::from_columns(&[along_i, along_j])
        .try_inverse()
        .ok_or(Unrefined::FewEdges)?;
    // Unit normals of the two axes, each pointing towards the other axis's + side.
    let normal = |along: Vector2<f64>, other: Vector2<f64>| {
        let n = Vector2::new(-along.y, along.x).normalize();
        if n.dot(&other) < 0.0 { -n } else { n }
    };
    let normals = [normal(along_i, along_j), normal(along_j, along_i)];
    let (width, height) = (i64::from(smoothed.width()), i64::from(smoothed.height()));
    let x0 = ((predicted.x - radius).floor() as i64).max(1);
    let y0 = ((predicted.y - radius).floor() as i64).max(1);
    let x1 = ((predicted.x + radius).ceil() as i64).min(width - 2);
    let y1 = ((predicted.y + radius).ceil() as i64).min(height - 2);
    if x1 < x0 || y1 < y0 {
        return Err(Unrefined::FewEdges);
    }
    let reach = rho.floor() as i64;
    let disc: Vec<(i64, i64)> = (-reach..=reach)
        .flat_map(|dy| (-reach..=reach).map(move |dx| (dx, dy)))
        .filter(|&(dx, dy)| ((dx * dx + dy * dy) as f64) <= rho * rho)
        .collect();
    // The window plus 1 px for the gradient, plus the disc twice for the opening.
    let margin = 1 + 2 * reach;
    let tile = Tile::from_image(
        smoothed,
        x0 - margin,
        y0 - margin,
        x1 - x0 + 1 + 2 * margin,
        y1 - y0 + 1 + 2 * margin,
    );
    let opened = tile.morph(&disc, reach, true).morph(&disc, reach, false);
    let min_gradient = pattern.contrast / 20.0;
    let cos_tol = EDGE_ANGLE_TOL_DEG.to_radians().cos();
    // (pixel, unit gradient, |gradient|, axis 0 or 1, sign of the gradient along that axis's
    // normal)
    let mut pixels = Vec::new();
    let (mut dark, mut saturated) = (0usize, 0usize);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let p = Point2::new(x as f64, y as f64);
            let distance = (p - predicted).norm();
            if distance > radius {
                continue;
            }
            let uv = to_board * (p - predicted);
            // Away from the edge lines (1.5 px), a dark square's pixel.
            let off_edges =
                (uv.x * along_i.norm()).abs() > 1.5 && (uv.y * along_j.norm()).abs() > 1.5;
            if off_edges && uv.x.signum() * uv.y.signum() != pattern.light {
                dark += 1;
                saturated += usize::from(raw.get_pixel(x as u32, y as u32).0[0] >= 250);
            }
            if distance < hole {
                continue;
            }
            let g = opened.sobel(x, y);
            let magnitude = g.norm();
            if !(magnitude >= min_gradient) {
                continue;
            }
            let unit = g / magnitude;
            for (axis, n) in normals.iter().enumerate() {
                if unit.dot(n).abs() >= cos_tol {
                    pixels.push((p, unit, magnitude, axis, unit.dot(n).signum()));
                }
            }
        }
    }
    if dark > 0 && saturated as f64 > MAX_SATURATED_DARK * dark as f64 {
        return Err(Unrefined::Saturated);
    }
    // Along axis i (u), the light square on the +u side lies at +v when `light` = +1: the
    // gradient points along +normal there and along −normal on the −u side; likewise for j.
    let expected_sign = |q: Point2<f64>, p: Point2<f64>, axis: usize| {
        let uv = to_board * (p - q);
        let along = if axis == 0 { uv.x } else { uv.y };
        along.signum() * pattern.light
    };
    let mut q = predicted;
    let mut converged = false;
    let mut inliers = [0usize; 2];
    'scales: for scale in [TUKEY_WIDE_PX, TUKEY_NARROW_PX] {
        converged = false;
        for _ in 0..50 {
            let mut a = Matrix2::zeros();
            let mut b = Vector2::zeros();
            inliers = [0, 0];
            for &(p, unit, magnitude, axis, sign) in &pixels {
                if sign != expected_sign(q, p, axis) {
                    continue;
                }
                let residual = unit.dot(&(p - q));
                let weight = magnitude * tukey(residual, scale);
                if weight == 0.0 {
                    continue;
                }
                if residual.abs() < 0.5 * scale {
                    inliers[axis] += 1;
                }
                let outer = unit * unit.transpose() * weight;
                a += outer;
                b += outer * p.coords;
            }
            let Some(next) = a.try_inverse().map(|inverse| Point2::from(inverse * b)) else {
                break 'scales;
            };
            let step = (next - q).norm();
            q = next;
            if !(step.is_finite() && (q - predicted).norm() <= radius) {
                break 'scales;
            }
            if step < 1e-3 {
                converged = true;
                break;
            }
        }
        if !converged {
            break;
        }
    }
    if inliers.iter().any(|&n| n < MIN_EDGE_PIXELS) {
        return Err(Unrefined::FewEdges);
    }
    if !converged {
        return Err(Unrefined::NoConvergence);
    }
    let moved = (q - predicted).norm();
    if moved > MAX_REFINE_SHIFT_PX {
        return Err(Unrefined::Moved { px: moved });
    }
    Ok(q)
}
