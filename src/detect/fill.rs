//! The inner corners a chessboard grid missed, filled in (issue 45: a backscatter speck on one
//! corner hides it from the ChESS front end, and a grid of 53 of 54 corners is not a board).
//!
//! A grid qualifies when its labels span the board's shape and it misses at most
//! [`MAX_FILLED_FRACTION`] of the corners, every border line of the grid keeping at least half of
//! its corners (so the extent is held by many corners, not by one stray label). Each missing
//! corner is then
//!
//! 1. **predicted** from the grid's found corners within [`LOCAL_HOMOGRAPHY_RADIUS`] squares of
//!    it (at least [`MIN_FILL_NEIGHBOURS`] of them): their homography, corrected by a quadratic
//!    fitted to their residuals ([`predict`]), which also gives the board's two axes there;
//! 2. **checked** to be a chessboard corner on the image: the four squares around the prediction
//!    must alternate, the two on one diagonal at least [`MIN_CONTRAST`] grey levels lighter than
//!    the two on the other ([`corner_pattern`], medians over the middle of each square, away
//!    from the corner where a speck sits). A prediction that lands on something else (an
//!    occluder, the background) rejects the board: it is not the whole board;
//! 3. **refined** on the image ([`refine_corner`]): a blurred corner (two edge lines through
//!    it, a contrast, a blur, the light's slope) fitted to the pixels within 0.45 of a side,
//!    each pixel weighted by Tukey's biweight of its residual so that a speck's pixels drop
//!    out: the squares' edges place the corner when a speck covers its centre. When the
//!    refinement cannot place the corner reliably (saturated window, a window that does not fix
//!    it to [`MAX_REFINE_SIGMA_PX`], no convergence, a move of more than
//!    [`MAX_REFINE_SHIFT_PX`] from the prediction) the prediction stands, and the detection
//!    says so ([`FilledCorner::unrefined`]): a chessboard's detection holds every corner.
//!
//! Measured by leaving out every corner of the whole boards in the 48 chessboard images of
//! python/tests/test_detector_vs_opencv.py (seed 7) in turn and filling it in
//! (tests/detect_specks.rs, `leave_one_out`): at imaging 1, 1239 corners, filled in 0.019 px
//! RMS from the exact corners (0.064 px at most; the prediction alone 0.092, the ChESS corner
//! 0.055); at imaging 2, 1131 corners, 0.072 px RMS (0.70 at most; prediction 0.143, ChESS
//! 0.185); every one refined, 3 of each set not filled (no alternating squares seen).
//!
//! Written here, not taken from calib-targets: its recall boosters (interior gap fill, line
//! extension, geometry-only recovery) attach existing ChESS corners to empty cells, and a corner
//! under a speck has no ChESS corner to attach; its saddle-point refiner (a quadratic fitted to
//! the 5 × 5 pixels at the corner) is what the speck spoils, and is not public API of
//! calib-targets (it lives in `chess-corners-core`, not a dependency of flatport). The
//! prediction reuses `fit_homography`, the ChArUco check's.

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
/// other corner's edges lie a whole side away), between 4 and 20 px.
const REFINE_WINDOW_REL: f64 = 0.45;
const MIN_REFINE_WINDOW_PX: f64 = 4.0;
const MAX_REFINE_WINDOW_PX: f64 = 20.0;

/// Tukey's biweight constant (in robust standard deviations of the residuals, at least
/// `MIN_RESIDUAL_SCALE` grey levels): 4.685, 95 % efficient on Gaussian noise.
const TUKEY_C: f64 = 4.685;
const MIN_RESIDUAL_SCALE: f64 = 2.0;

/// Plain least-squares iterations of the fit before the robust weights start (the model must
/// be near the image before its residuals say which pixels are outliers), and most iterations
/// in all.
const WARM_ITERATIONS: usize = 8;
const MAX_ITERATIONS: usize = 40;

/// Largest standard deviation of the fitted corner (pixels, from the fit's information about q
/// and its residuals) for the window to count as fixing it.
pub const MAX_REFINE_SIGMA_PX: f64 = 0.1;

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
    /// prediction ([`predict`]).
    pub unrefined: Option<Unrefined>,
}

/// Why a filled corner's refinement was not kept.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Unrefined {
    /// Over a tenth of the window's dark-square pixels at the top of the grey scale.
    Saturated,
    /// The window does not fix the corner: its standard deviation from the fit is over
    /// [`MAX_REFINE_SIGMA_PX`], or the fitted saddle lost its contrast or its blur (no edges).
    Weak {
        /// The corner's standard deviation from the fit, pixels (infinite without a saddle).
        sigma_px: f64,
    },
    /// The fit did not settle in 40 iterations.
    NoConvergence,
    /// It moved farther than [`Window::max_shift_px`] ([`MAX_REFINE_SHIFT_PX`] for a filled
    /// corner) from the prediction.
    Moved {
        /// The move, pixels.
        px: f64,
        /// The farthest it was allowed to move, pixels.
        limit_px: f64,
    },
    /// The fit put it outside the image.
    Outside,
}

impl std::fmt::Display for Unrefined {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Unrefined::Saturated => write!(f, "its window is saturated"),
            Unrefined::Weak { sigma_px } => write!(
                f,
                "the image around it fixes it to {sigma_px:.2} px only (over {MAX_REFINE_SIGMA_PX} px)"
            ),
            Unrefined::NoConvergence => write!(f, "the refinement did not converge"),
            Unrefined::Moved { px, limit_px } => write!(
                f,
                "the refinement moved it {px:.2} px (over {limit_px} px) from the prediction"
            ),
            Unrefined::Outside => write!(f, "the refinement put it outside the image"),
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
        // A corner outside the image is not in view: the board is not whole.
        if !inside(raw, predicted) {
            return None;
        }
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

/// Whether pixel `p` lies within `image` (pixel centres at whole coordinates, 0 … size − 1).
fn inside(image: &GrayImage, p: Point2<f64>) -> bool {
    p.x >= 0.0
        && p.y >= 0.0
        && p.x <= f64::from(image.width()) - 1.0
        && p.y <= f64::from(image.height()) - 1.0
}

/// Fewest neighbours for the quadratic correction of [`predict`] (6 coefficients per coordinate).
const MIN_QUADRATIC_NEIGHBOURS: usize = 12;

/// The pixel of grid label `at` from `pairs` (label, pixel) of its neighbours, and the board's
/// two axes there (pixels per square, along i and along j): the homography H of the pairs
/// (`fit_homography`), plus, with at least 12 pairs, the constant term of a quadratic in the
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
/// median of 25 samples over its middle (0.3 … 0.7 of a side from the corner along each axis),
/// of those inside the image: by the image's edge a square with fewer than 5 there is left out,
/// and one square of each diagonal decides.
pub fn corner_pattern(
    image: &GrayImage,
    corner: Point2<f64>,
    along_i: Vector2<f64>,
    along_j: Vector2<f64>,
) -> Option<Pattern> {
    // A square's grey from its samples inside the image (a corner by the image's edge has
    // squares partly outside it); `None` with fewer than 5 of its 25.
    let square = |si: f64, sj: f64| -> Option<f64> {
        let mut values = Vec::with_capacity(25);
        for a in 0..5 {
            for b in 0..5 {
                let (u, v) = (0.3 + 0.1 * a as f64, 0.3 + 0.1 * b as f64);
                let p = corner + along_i * (si * u) + along_j * (sj * v);
                values.extend(bilinear(image, p.x, p.y));
            }
        }
        if values.len() < 5 {
            return None;
        }
        values.sort_by(f64::total_cmp);
        Some(values[values.len() / 2])
    };
    // The squares of each diagonal that the image shows (at least one of each).
    let plus: Vec<f64> = [square(1.0, 1.0), square(-1.0, -1.0)]
        .into_iter()
        .flatten()
        .collect();
    let minus: Vec<f64> = [square(1.0, -1.0), square(-1.0, 1.0)]
        .into_iter()
        .flatten()
        .collect();
    if plus.is_empty() || minus.is_empty() {
        return None;
    }
    let lowest = |v: &[f64]| v.iter().copied().fold(f64::INFINITY, f64::min);
    let highest = |v: &[f64]| v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let plus_light = lowest(&plus) - highest(&minus);
    let minus_light = lowest(&minus) - highest(&plus);
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

/// Tukey's biweight of residual `r` at scale `c`: (1 − (r/c)²)² inside ±c, 0 outside.
fn tukey(r: f64, c: f64) -> f64 {
    let t = r / c;
    if t.abs() < 1.0 {
        (1.0 - t * t).powi(2)
    } else {
        0.0
    }
}

/// Parameters of the blurred-corner model of [`refine_corner`], in this order: the corner
/// (qx, qy), the directions φ1, φ2 of the two edge lines (radians), the mean grey m, the
/// half-contrast c, the blur b (pixels), the light's slope (gx, gy) across the window.
type Params = nalgebra::SVector<f64, 9>;

/// The model's grey level at `p` and its derivatives by the parameters; `origin` is the
/// prediction, where the light's slope is referred.
///
/// I(p) = m + gx (px − ox) + gy (py − oy) + c · tanh(u / b) · tanh(v / b),
/// u = n(φ1)ᵀ(p − q), v = n(φ2)ᵀ(p − q), n(φ) = (−sin φ, cos φ).
fn corner_model(params: &Params, origin: Point2<f64>, p: Point2<f64>) -> (f64, Params) {
    let (qx, qy, phi1, phi2) = (params[0], params[1], params[2], params[3]);
    let (m, c, b, gx, gy) = (params[4], params[5], params[6], params[7], params[8]);
    let (dx, dy) = (p.x - qx, p.y - qy);
    let (s1, c1) = phi1.sin_cos();
    let (s2, c2) = phi2.sin_cos();
    let u = -s1 * dx + c1 * dy;
    let v = -s2 * dx + c2 * dy;
    let (t1, t2) = ((u / b).tanh(), (v / b).tanh());
    let (d1, d2) = (1.0 - t1 * t1, 1.0 - t2 * t2);
    let value = m + gx * (p.x - origin.x) + gy * (p.y - origin.y) + c * t1 * t2;
    // ∂I/∂u and ∂I/∂v.
    let (di_du, di_dv) = (c * d1 * t2 / b, c * t1 * d2 / b);
    let gradient = Params::from_column_slice(&[
        di_du * s1 + di_dv * s2,      // ∂u/∂qx = sin φ1
        -di_du * c1 - di_dv * c2,     // ∂u/∂qy = −cos φ1
        -di_du * (c1 * dx + s1 * dy), // ∂u/∂φ1
        -di_dv * (c2 * dx + s2 * dy), // ∂v/∂φ2
        1.0,
        t1 * t2,
        -(di_du * u + di_dv * v) / b,
        p.x - origin.x,
        p.y - origin.y,
    ]);
    (value, gradient)
}

/// A chessboard corner near `predicted`, the board's axes there being `along_i` and `along_j`
/// (pixels per square) and its squares `pattern`: a robust fit of a blurred corner to the
/// pixels of `smoothed` within 0.45 of a side (4 … 20 px) of the prediction.
///
/// **The model** (`corner_model`): I(p) = m + g·(p − o) + c · tanh(u/b) · tanh(v/b), u and v
/// the signed distances of p from the two edge lines through the corner q (directions φ1, φ2),
/// b the blur, m and c the squares' mean grey and half-contrast, g the light's slope across
/// the window (vignetting, a light gradient), o the prediction. Nine parameters, started from
/// the prediction, the board's axes, the window's median grey, the squares' contrast and a
/// blur of 1.5 px, fitted by Levenberg–Marquardt: 8 plain least-squares iterations, then each
/// pixel weighted by Tukey's biweight of its residual (scale 4.685 × the residuals' robust
/// standard deviation, 1.4826 × MAD, at least 2 grey levels), so that a speck's pixels (far
/// brighter than the model) drop out, until the corner moves less than 10⁻⁴ px (40 iterations
/// at most). A corner is the saddle of its four squares, not a feature of a few pixels at its
/// centre, so the squares' edges place it when a speck covers the centre.
///
/// Measured with the prediction as the start: see the module's documentation (0.019 and
/// 0.072 px RMS at imaging 1 and 2, where calib-targets' saddle-point refiner's corners are
/// 0.055 and 0.185 px); on the 5 corners under specks there, 0.01–0.06 px from the exact ones.
///
/// Errs as [`Unrefined`] says: the window saturated (checked on `raw`, the image as read), no
/// convergence, a corner whose standard deviation (from the fit's information about q, with
/// the robust residual scale) exceeds [`MAX_REFINE_SIGMA_PX`] or whose fitted saddle lost its
/// contrast (|c| below a quarter of the pattern's half-contrast, or the other diagonal light)
/// or its blur (b outside 0.2 px … the window), a move of more than [`MAX_REFINE_SHIFT_PX`]
/// from the prediction, a corner outside the image. Pixel centres are at whole coordinates.
pub fn refine_corner(
    raw: &GrayImage,
    smoothed: &GrayImage,
    predicted: Point2<f64>,
    along_i: Vector2<f64>,
    along_j: Vector2<f64>,
    pattern: Pattern,
) -> Result<Point2<f64>, Unrefined> {
    let plain = Window {
        max_shift_px: MAX_REFINE_SHIFT_PX,
        marker_margin: None,
    };
    refine_corner_in(raw, smoothed, predicted, along_i, along_j, pattern, &plain)
}

/// What [`refine_corner_in`] reads of the window around a corner and how far it lets it move.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    /// Farthest the corner may move from its prediction (pixels), else [`Unrefined::Moved`].
    pub max_shift_px: f64,
    /// A ChArUco board's white margin around each marker, as a fraction of a side: the light
    /// squares' pixels farther than that from both of the square's edges through the corner
    /// (the marker, less 1.5 px) are left out of the fit, which models four plain squares.
    pub marker_margin: Option<f64>,
}

/// [`refine_corner`] with the window's rules given: how far the corner may move, and a ChArUco
/// board's markers left out ([`Window`]).
pub fn refine_corner_in(
    raw: &GrayImage,
    smoothed: &GrayImage,
    predicted: Point2<f64>,
    along_i: Vector2<f64>,
    along_j: Vector2<f64>,
    pattern: Pattern,
    rules: &Window,
) -> Result<Point2<f64>, Unrefined> {
    let side = along_i.norm().min(along_j.norm());
    let radius = (REFINE_WINDOW_REL * side).clamp(MIN_REFINE_WINDOW_PX, MAX_REFINE_WINDOW_PX);
    let no_saddle = Unrefined::Weak {
        sigma_px: f64::INFINITY,
    };
    // Board coordinates (u along i, v along j, in squares) of an image offset.
    let to_board = Matrix2::from_columns(&[along_i, along_j])
        .try_inverse()
        .ok_or(no_saddle)?;
    let (width, height) = (i64::from(smoothed.width()), i64::from(smoothed.height()));
    let x0 = ((predicted.x - radius).floor() as i64).max(0);
    let y0 = ((predicted.y - radius).floor() as i64).max(0);
    let x1 = ((predicted.x + radius).ceil() as i64).min(width - 1);
    let y1 = ((predicted.y + radius).ceil() as i64).min(height - 1);
    // (pixel, grey) over the window.
    let mut window = Vec::new();
    let (mut dark, mut saturated) = (0usize, 0usize);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let p = Point2::new(x as f64, y as f64);
            if (p - predicted).norm() > radius {
                continue;
            }
            let (xu, yu) = (x as u32, y as u32);
            let uv = to_board * (p - predicted);
            let on_light = uv.x.signum() * uv.y.signum() == pattern.light;
            if let Some(margin) = rules.marker_margin {
                let beyond = |t: f64, along: &Vector2<f64>| t.abs() > margin - 1.5 / along.norm();
                if on_light && beyond(uv.x, &along_i) && beyond(uv.y, &along_j) {
                    continue;
                }
            }
            window.push((p, f64::from(smoothed.get_pixel(xu, yu).0[0])));
            // Away from the edge lines (1.5 px), a dark square's pixel.
            let off_edges =
                (uv.x * along_i.norm()).abs() > 1.5 && (uv.y * along_j.norm()).abs() > 1.5;
            if off_edges && uv.x.signum() * uv.y.signum() != pattern.light {
                dark += 1;
                saturated += usize::from(raw.get_pixel(xu, yu).0[0] >= 250);
            }
        }
    }
    if dark > 0 && saturated as f64 > MAX_SATURATED_DARK * dark as f64 {
        return Err(Unrefined::Saturated);
    }
    if window.len() < 2 * Params::zeros().len() {
        return Err(no_saddle);
    }
    let (phi1, phi2) = (along_i.y.atan2(along_i.x), along_j.y.atan2(along_j.x));
    // tanh(u) is positive on the +j side of the i edge line when n(φ1)·along_j > 0, and
    // tanh(v) on the +i side when n(φ2)·along_i > 0: c's sign puts the light squares where
    // the pattern saw them.
    let n = |phi: f64| Vector2::new(-phi.sin(), phi.cos());
    let orientation = n(phi1).dot(&along_j).signum() * n(phi2).dot(&along_i).signum();
    let expected_c = pattern.light * orientation * pattern.contrast / 2.0;
    let mut greys: Vec<f64> = window.iter().map(|w| w.1).collect();
    let median = |values: &mut [f64]| {
        values.sort_by(f64::total_cmp);
        values[values.len() / 2]
    };
    let mut params = Params::from_column_slice(&[
        predicted.x,
        predicted.y,
        phi1,
        phi2,
        median(&mut greys),
        expected_c,
        1.5,
        0.0,
        0.0,
    ]);
    let residuals = |params: &Params| -> Vec<f64> {
        window
            .iter()
            .map(|&(p, grey)| grey - corner_model(params, predicted, p).0)
            .collect()
    };
    let valid = |params: &Params| params[6] > 0.2 && params[6] < radius;
    let mut r = residuals(&params);
    let mut weights = vec![1.0; window.len()];
    let mut scale = f64::INFINITY;
    let mut lambda = 1e-3;
    let mut converged = false;
    let mut information = Matrix2::zeros();
    for iteration in 0..MAX_ITERATIONS {
        if iteration >= WARM_ITERATIONS {
            let centre = median(&mut r.clone());
            let mut deviations: Vec<f64> = r.iter().map(|x| (x - centre).abs()).collect();
            scale = (1.4826 * median(&mut deviations)).max(MIN_RESIDUAL_SCALE);
            for (w, x) in weights.iter_mut().zip(&r) {
                *w = tukey(*x, TUKEY_C * scale);
            }
        }
        let mut a = nalgebra::SMatrix::<f64, 9, 9>::zeros();
        let mut g = Params::zeros();
        for (&(p, _), (&w, &x)) in window.iter().zip(weights.iter().zip(&r)) {
            if w == 0.0 {
                continue;
            }
            let (_, jacobian) = corner_model(&params, predicted, p);
            a += jacobian * jacobian.transpose() * w;
            g += jacobian * (w * x);
        }
        information = a.fixed_view::<2, 2>(0, 0).into_owned();
        let cost = |r: &[f64]| -> f64 { r.iter().zip(&weights).map(|(x, w)| w * x * x).sum() };
        let before = cost(&r);
        let mut step = None;
        while lambda <= 1e6 {
            let damped = a
                + nalgebra::SMatrix::<f64, 9, 9>::from_diagonal(&a.diagonal()) * lambda
                + nalgebra::SMatrix::<f64, 9, 9>::identity() * 1e-9;
            let Some(delta) = damped.lu().solve(&g) else {
                lambda *= 4.0;
                continue;
            };
            let next = params + delta;
            let next_r = residuals(&next);
            if valid(&next) && cost(&next_r) <= before {
                step = Some((delta, next, next_r));
                lambda = (lambda / 3.0).max(1e-6);
                break;
            }
            lambda *= 4.0;
        }
        let Some((delta, next, next_r)) = step else {
            // No step lowers the cost: a minimum for these weights (once they are robust).
            if iteration >= WARM_ITERATIONS + 3 {
                converged = true;
                break;
            }
            lambda = 1e-3;
            continue;
        };
        params = next;
        r = next_r;
        if (params[0] - predicted.x).hypot(params[1] - predicted.y) > radius {
            break;
        }
        if delta[0].hypot(delta[1]) < 1e-4 && iteration >= WARM_ITERATIONS + 3 {
            converged = true;
            break;
        }
    }
    if !converged {
        return Err(Unrefined::NoConvergence);
    }
    // The corner's covariance ≈ scale² · (the information's q block)⁻¹ (the other parameters
    // held: a lower bound, enough to tell a window of edges from one without).
    let sigma_px = information
        .symmetric_eigenvalues()
        .min()
        .max(0.0)
        .recip()
        .sqrt()
        * scale;
    let c = params[5];
    if !(c * expected_c > 0.0 && c.abs() >= expected_c.abs() / 4.0 && valid(&params)) {
        return Err(no_saddle);
    }
    if !(sigma_px <= MAX_REFINE_SIGMA_PX) {
        return Err(Unrefined::Weak { sigma_px });
    }
    let q = Point2::new(params[0], params[1]);
    let moved = (q - predicted).norm();
    if moved > rules.max_shift_px {
        return Err(Unrefined::Moved {
            px: moved,
            limit_px: rules.max_shift_px,
        });
    }
    if !inside(raw, q) {
        return Err(Unrefined::Outside);
    }
    Ok(q)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grid whose missing corner lies outside the image (5 px left of it) is not a whole
    /// board: nothing is filled in (zoo seed 1, degraded: a filled corner at y = 783 of 768
    /// refused the calibration).
    #[test]
    fn a_missing_corner_outside_the_image_is_not_filled() {
        // Squares of 20 px, corner (i, j) at (−5 + 20 i, 30 + 20 j).
        let image = GrayImage::from_fn(100, 100, |x, y| {
            let (u, v) = ((f64::from(x) + 5.0) / 20.0, (f64::from(y) - 30.0) / 20.0);
            let dark = (u.floor() as i64 + v.floor() as i64).rem_euclid(2) == 0;
            image::Luma([if dark { 40 } else { 200 }])
        });
        let (w, h) = (4, 3);
        let mut grid: Vec<Option<Point2<f64>>> = (0..w * h)
            .map(|k| {
                let (i, j) = ((k % w) as f64, (k / w) as f64);
                Some(Point2::new(-5.0 + 20.0 * i, 30.0 + 20.0 * j))
            })
            .collect();
        grid[0] = None;
        let before = grid.clone();
        assert_eq!(fill_missing(&mut grid, w, h, &image, &image), None);
        assert_eq!(grid, before);
        // The same grid one square to the right is inside: filled, at the corner.
        let mut shifted: Vec<Option<Point2<f64>>> = before
            .iter()
            .map(|p| p.map(|p| p + Vector2::new(20.0, 0.0)))
            .collect();
        let filled = fill_missing(&mut shifted, w, h, &image, &image).expect("filled");
        assert_eq!(filled.len(), 1);
        assert!(
            (filled[0].pixel - Point2::new(15.0, 30.0)).norm() < 0.2,
            "{filled:?}"
        );
    }

    /// A corner 3 px from the image's top edge (the zoo's chessboards reach it): the squares
    /// above it are all but outside the image, those below decide, the light diagonal read the
    /// right way round; a corner with no square of one diagonal inside is none.
    #[test]
    fn a_corner_by_the_images_edge_is_judged_by_the_squares_inside() {
        let corner = Point2::new(60.0, 3.0);
        // Squares of 20 px: light where (x − 60)·(y − 3) > 0.
        let image = GrayImage::from_fn(120, 60, |x, y| {
            let (u, v) = (f64::from(x) - corner.x, f64::from(y) - corner.y);
            image::Luma([if u * v > 0.0 { 200 } else { 40 }])
        });
        let (along_i, along_j) = (Vector2::new(20.0, 0.0), Vector2::new(0.0, 20.0));
        let pattern = corner_pattern(&image, corner, along_i, along_j).expect("a corner");
        assert_eq!(pattern.light, 1.0);
        assert!(pattern.contrast > 150.0, "{pattern:?}");
        // By a corner of the image only the square at +i+j is inside: no square of the other
        // diagonal to compare with, so no corner.
        let flat = corner_pattern(&image, Point2::new(2.0, 2.0), along_i, along_j);
        assert_eq!(flat, None);
    }

    #[test]
    fn the_corner_models_derivatives_match_central_differences() {
        let params =
            Params::from_column_slice(&[10.3, -4.2, 0.3, 1.9, 120.0, -45.0, 1.7, 0.8, -0.5]);
        let origin = Point2::new(10.0, -4.0);
        for p in [
            Point2::new(12.0, -1.0),
            Point2::new(7.5, -6.0),
            Point2::new(10.0, -4.0),
            Point2::new(14.0, -9.0),
        ] {
            let (_, analytic) = corner_model(&params, origin, p);
            for k in 0..9 {
                let h = 1e-6 * params[k].abs().max(1.0);
                let mut up = params;
                let mut down = params;
                up[k] += h;
                down[k] -= h;
                let numeric =
                    (corner_model(&up, origin, p).0 - corner_model(&down, origin, p).0) / (2.0 * h);
                assert!(
                    (numeric - analytic[k]).abs() <= 1e-5 * numeric.abs().max(1.0),
                    "parameter {k} at {p}: analytic {} numeric {numeric}",
                    analytic[k]
                );
            }
        }
    }

    /// The pixel of grid label (i, j) under an exact homography (squares of 30–40 px).
    fn homography_pixel(i: f64, j: f64) -> Point2<f64> {
        let w = 1.0 + 0.02 * i + 0.01 * j;
        Point2::new(
            (200.0 + 38.0 * i + 4.0 * j) / w,
            (150.0 + 3.0 * i + 35.0 * j) / w,
        )
    }

    #[test]
    fn a_corner_on_an_exact_homography_is_predicted_exactly() {
        for (ci, cj) in [(3.0, 2.0), (0.0, 0.0), (8.0, 5.0)] {
            let pairs: Vec<_> = (0..6)
                .flat_map(|j| (0..9).map(move |i| (f64::from(i), f64::from(j))))
                .filter(|&(i, j)| {
                    (i, j) != (ci, cj) && (i - ci).abs() <= 2.0 && (j - cj).abs() <= 2.0
                })
                .map(|(i, j)| (Point2::new(i, j), homography_pixel(i, j)))
                .collect();
            let (predicted, along_i, along_j) = predict(&pairs, Point2::new(ci, cj)).unwrap();
            assert!(
                (predicted - homography_pixel(ci, cj)).norm() < 1e-6,
                "{ci}, {cj}"
            );
            let expected_i = homography_pixel(ci + 0.5, cj) - homography_pixel(ci - 0.5, cj);
            let expected_j = homography_pixel(ci, cj + 0.5) - homography_pixel(ci, cj - 0.5);
            assert!((along_i - expected_i).norm() < 1e-6 && (along_j - expected_j).norm() < 1e-6);
        }
    }

    /// A corner drawn by the model itself (edges along (1, 0.1) and (−0.15, 1), blur 1.2 px,
    /// greys 60 and 180) at `corner`, 61 × 61 pixels, with a bright speck (σ 2 px, +150 grey)
    /// `speck` px from the corner.
    fn drawn_corner(
        corner: Point2<f64>,
        speck: Vector2<f64>,
    ) -> (GrayImage, Vector2<f64>, Vector2<f64>) {
        let (along_i, along_j): (Vector2<f64>, Vector2<f64>) =
            (Vector2::new(30.0, 3.0), Vector2::new(-4.5, 30.0));
        let params = Params::from_column_slice(&[
            corner.x,
            corner.y,
            along_i.y.atan2(along_i.x),
            along_j.y.atan2(along_j.x),
            120.0,
            60.0,
            1.2,
            0.0,
            0.0,
        ]);
        let image = GrayImage::from_fn(61, 61, |x, y| {
            let p = Point2::new(f64::from(x), f64::from(y));
            let grey = corner_model(&params, corner, p).0
                + 150.0 * (-(p - (corner + speck)).norm_squared() / 8.0).exp();
            image::Luma([grey.round().clamp(0.0, 255.0) as u8])
        });
        (image, along_i, along_j)
    }

    #[test]
    fn a_speck_on_the_corner_does_not_move_the_refined_corner() {
        // The image is the model itself on 8-bit pixels plus the speck: the bound 0.02 px is
        // the rounding's share.
        let corner = Point2::new(30.37, 29.81);
        for speck in [
            Vector2::zeros(),
            Vector2::new(1.5, -1.0),
            Vector2::new(-3.0, 2.0),
        ] {
            let (image, along_i, along_j) = drawn_corner(corner, speck);
            let predicted = corner + Vector2::new(0.4, -0.3);
            let pattern = corner_pattern(&image, predicted, along_i, along_j).unwrap();
            let refined = refine_corner(&image, &image, predicted, along_i, along_j, pattern)
                .unwrap_or_else(|why| panic!("speck at {speck}: {why}"));
            assert!(
                (refined - corner).norm() < 0.02,
                "speck at {speck}: refined {refined}, {} px off",
                (refined - corner).norm()
            );
        }
    }

    #[test]
    fn a_flat_window_is_not_refined() {
        let image = GrayImage::from_pixel(61, 61, image::Luma([128]));
        let pattern = Pattern {
            light: 1.0,
            contrast: 100.0,
        };
        let result = refine_corner(
            &image,
            &image,
            Point2::new(30.0, 30.0),
            Vector2::new(30.0, 0.0),
            Vector2::new(0.0, 30.0),
            pattern,
        );
        assert!(
            matches!(
                result,
                Err(Unrefined::Weak { .. }) | Err(Unrefined::NoConvergence)
            ),
            "{result:?}"
        );
        assert_eq!(
            corner_pattern(
                &image,
                Point2::new(30.0, 30.0),
                Vector2::new(30.0, 0.0),
                Vector2::new(0.0, 30.0)
            ),
            None
        );
    }
}
