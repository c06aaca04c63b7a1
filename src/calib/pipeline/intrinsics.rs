//! In-air intrinsics of one camera from independent views of a planar board
//! ([`calibrate_intrinsics`]): Zhang's closed form, then maximum likelihood over the pinhole,
//! the OpenCV lens model and every view's pose, with the lens terms chosen by held-out views and
//! outlier views named and dropped.
//!
//! The steps:
//!
//! 1. **Screen** each view: a view with fewer than [`MIN_VIEW_CORNERS`] corners, with corners on
//!    one board line, or whose homography is degenerate is left out with the reason
//!    ([`IntrinsicsFit::excluded`]); malformed input (a corner id off the board, a repeated id, a
//!    non-finite pixel) is an error. At least [`MIN_VIEWS`] views must remain.
//! 2. **Closed form** (Zhang, PAMI 2000): each view's homography board → pixel (normalised DLT);
//!    B = K⁻ᵀK⁻¹ from hᵢᵀBhⱼ constraints with zero skew; K from B. Where that fails (too few or
//!    too similar views, a principal point outside the image) the principal point is fixed at the
//!    image centre and only fx, fy are solved. Poses from the homographies by
//!    [`pinhole_pose`]; distortion 0.
//! 3. **Maximum likelihood**: Levenberg–Marquardt ([`levenberg_marquardt`]) over fx, fy, cx, cy,
//!    the free lens coefficients and every view's pose, with the block normal equations
//!    ([`BlockNormalEquations`], Schur complement on the poses) and analytic Jacobians.
//! 4. **Outlier views** ([`IntrinsicsOptions::outlier_factor`]): a view whose RMS exceeds
//!    `outlier_factor` × the median view RMS *and* [`IntrinsicsOptions::outlier_floor_px`] is
//!    named with both numbers and dropped, and the rest refitted, until none is left (at most
//!    [`OUTLIER_ROUNDS`] rounds).
//! 5. **Lens model** ([`ModelChoice::Auto`]): the nested candidates k1·p1·p2 ⊂ k1·k2·p1·p2 ⊂
//!    k1·k2·p1·p2·k3 are compared by k-fold cross-validation over views (each fold's intrinsics
//!    fitted on the other views; each held-out view's pose fitted with those intrinsics held; the
//!    RMS of all held-out corners). A richer candidate replaces the current choice only when its
//!    held-out RMS is lower by more than [`IntrinsicsOptions::model_margin`] (default 1 %). Why a
//!    margin: a term the lens does not have lowers the training RMS but not the held-out one (it
//!    fits noise), so without a margin the choice between two near-equal numbers would be a coin
//!    flip; 1 % of an RMS of √2·σ is a systematic lens error of about 0.2·σ per corner, below what
//!    a calibration at noise σ can use. Each candidate's held-out RMS is kept
//!    ([`ModelSelection::candidates`]).
//! 6. **Final fit** with the chosen model, one more outlier check, and the standard deviations
//!    σ = √diag((JᵀJ)⁻¹)·σ̂, σ̂² = SSR / (2N − p), p = free intrinsics + 6 per view, as OpenCV's
//!    `calibrateCameraExtended` (≥ 4.8) reports them.
//!
//! Parameter order everywhere: fx, fy, cx, cy, k1, k2, p1, p2, k3 (pixels; the OpenCV order of
//! the coefficients). Residual: projected − observed pixel; the RMS is over each corner's 2-D
//! residual length, as OpenCV's `calibrateCamera` returns it. Pure library code: no I/O.

use nalgebra::{DVector, Isometry3, Matrix2x3, Matrix3, Point2, Point3, Vector2, Vector3};

use crate::base::Board;
use crate::calib::error::{CalibError, number};
use crate::calib::pipeline::poses::pinhole_pose;
use crate::calib::pipeline::report::{Covariances, covariances};
use crate::calib::solvers::block::{
    BlockNormalEquations, POSE_PARAMETERS, move_pose, robust, view_share,
};
use crate::calib::solvers::lm::{
    LeastSquares, LmOptions, NormalEquations, Termination, levenberg_marquardt,
};
use crate::model::camera::{PinholeCamera, distort_with_jacobian};

/// Fewest views the calibration needs after screening and outlier removal.
pub const MIN_VIEWS: usize = 3;

/// Fewest corners a view needs (a homography has 8 degrees of freedom: 4 points).
pub const MIN_VIEW_CORNERS: usize = 4;

/// Most rounds of outlier removal after one fit.
pub const OUTLIER_ROUNDS: usize = 3;

/// Number of intrinsic parameters: fx, fy, cx, cy, k1, k2, p1, p2, k3.
pub const INTRINSICS: usize = 9;

/// One in-air view of the board by one camera.
#[derive(Debug, Clone, PartialEq)]
pub struct AirView {
    /// What names the view in messages (the image's file name, a video's frame).
    pub label: String,
    /// The corners found: (corner index in [`Board`]'s row-major numbering, raw distorted pixel).
    pub corners: Vec<(usize, Point2<f64>)>,
}

/// Which of the lens coefficients [k1, k2, p1, p2, k3] are estimated; the others are held at 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LensTerms {
    /// Free flags in the order k1, k2, p1, p2, k3.
    pub free: [bool; 5],
}

impl LensTerms {
    /// No distortion: the pinhole alone.
    pub const NONE: Self = Self { free: [false; 5] };
    /// k1, p1, p2.
    pub const K1_TANGENTIAL: Self = Self {
        free: [true, false, true, true, false],
    };
    /// k1, k2, p1, p2 (OpenCV's `CALIB_FIX_K3`).
    pub const K1_K2_TANGENTIAL: Self = Self {
        free: [true, true, true, true, false],
    };
    /// k1, k2, p1, p2, k3 (OpenCV's default).
    pub const ALL: Self = Self { free: [true; 5] };

    /// The candidates [`ModelChoice::Auto`] compares, simplest first.
    pub const AUTO_CANDIDATES: [Self; 3] = [Self::K1_TANGENTIAL, Self::K1_K2_TANGENTIAL, Self::ALL];

    /// The free coefficients' names, `k1, k2, p1, p2` (`none` when none).
    pub fn describe(&self) -> String {
        let names = ["k1", "k2", "p1", "p2", "k3"];
        let free: Vec<&str> = names
            .iter()
            .zip(self.free)
            .filter_map(|(n, f)| f.then_some(*n))
            .collect();
        if free.is_empty() {
            "none".into()
        } else {
            free.join(", ")
        }
    }

    /// Free flags over all nine intrinsics (fx, fy, cx, cy always free).
    fn intrinsics_free(&self) -> [bool; INTRINSICS] {
        let mut free = [true; INTRINSICS];
        free[4..].copy_from_slice(&self.free);
        free
    }
}

/// How the lens terms are chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ModelChoice {
    /// By held-out views among [`LensTerms::AUTO_CANDIDATES`] (see the [module](self) docs).
    #[default]
    Auto,
    /// Exactly these terms.
    Fixed(LensTerms),
}

/// Settings of [`calibrate_intrinsics`].
#[derive(Debug, Clone, PartialEq)]
pub struct IntrinsicsOptions {
    /// How the lens terms are chosen (default [`ModelChoice::Auto`]).
    pub model: ModelChoice,
    /// Relative drop of the held-out RMS a richer lens model must bring to be chosen (0.01: 1 %).
    pub model_margin: f64,
    /// Folds of the cross-validation over views (at most one per view).
    pub folds: usize,
    /// Huber threshold on each corner's residual length, pixels (`None`: plain least squares, as
    /// OpenCV).
    pub huber_px: Option<f64>,
    /// A view is an outlier when its RMS exceeds this many times the median view RMS...
    pub outlier_factor: f64,
    /// ...and this many pixels (so a set of near-perfect views does not call 0.05 px an outlier).
    pub outlier_floor_px: f64,
    /// Iteration bound of each Levenberg–Marquardt run.
    pub max_iterations: usize,
}

impl Default for IntrinsicsOptions {
    fn default() -> Self {
        Self {
            model: ModelChoice::Auto,
            model_margin: 0.01,
            folds: 5,
            huber_px: None,
            outlier_factor: 3.0,
            outlier_floor_px: 0.5,
            max_iterations: 200,
        }
    }
}

/// One candidate lens model and how well it predicted views it was not fitted to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModelCandidate {
    /// The free coefficients.
    pub terms: LensTerms,
    /// RMS over every held-out corner of the cross-validation, pixels (∞ where a fold's fit
    /// failed).
    pub held_out_rms_px: f64,
}

/// Which lens terms were estimated, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelSelection {
    /// The free coefficients of the fit.
    pub terms: LensTerms,
    /// The candidates compared (empty for [`ModelChoice::Fixed`] or too few views).
    pub candidates: Vec<ModelCandidate>,
    /// The reason, one line.
    pub reason: String,
}

/// The intrinsics of one camera and how well they fit.
#[derive(Debug, Clone, PartialEq)]
pub struct IntrinsicsFit {
    /// The estimate (fixed lens coefficients are 0).
    pub camera: PinholeCamera,
    /// Standard deviations of fx, fy, cx, cy, k1, k2, p1, p2, k3 (0 for fixed coefficients):
    /// [`std_classical`](Self::std_classical), each raised where the views scatter more than
    /// σ̂ says (blurred or noisier views, corners of a view that err together:
    /// [`widened`](crate::calib::pipeline::report::widened)).
    pub std: [f64; INTRINSICS],
    /// The same by OpenCV's formula (≥ 4.8): √diag((JᵀJ)⁻¹)·σ̂, which assumes every corner errs
    /// independently with one variance.
    pub std_classical: [f64; INTRINSICS],
    /// RMS of the corners' 2-D residual lengths over the views used, pixels.
    pub rms_px: f64,
    /// σ̂ = √(SSR / (2N − p)), the estimated corner noise per coordinate, pixels.
    pub sigma_px: f64,
    /// Per input view: its RMS, pixels. For an outlier view, the RMS of its pose fitted with the
    /// final intrinsics held; `None` for an excluded view.
    pub view_rms_px: Vec<Option<f64>>,
    /// Outlier views (input index, why), dropped from the estimate.
    pub outliers: Vec<(usize, String)>,
    /// Views left out before the fit (input index, why): too few corners, corners on one line, a
    /// degenerate homography.
    pub excluded: Vec<(usize, String)>,
    /// Which lens terms are free, and why.
    pub model: ModelSelection,
    /// Per input view: the board pose in the camera frame (for an outlier view, fitted with the
    /// final intrinsics held); `None` for an excluded view.
    pub cam_from_board: Vec<Option<Isometry3<f64>>>,
    /// Corners in the estimate (outliers and excluded views left out).
    pub corners: usize,
    /// Levenberg–Marquardt steps of the final fit.
    pub iterations: usize,
    /// Why the final fit stopped.
    pub termination: Termination,
}

/// Calibrates one camera's intrinsics in air from independent views of `board` (see the
/// [module](self) docs for the steps, the lens-model rule and the outlier rule).
///
/// `name` labels errors (`air/<name>/<view label>`); `width`, `height` are the image size in
/// pixels. Errors: no or malformed views (a corner id off the board, a repeated id, a non-finite
/// pixel), fewer than [`MIN_VIEWS`] usable views, no camera matrix from the homographies, a fit
/// that does not converge to a valid camera, invalid options.
pub fn calibrate_intrinsics(
    name: &str,
    width: u32,
    height: u32,
    board: &Board,
    views: &[AirView],
    options: &IntrinsicsOptions,
) -> Result<IntrinsicsFit, CalibError> {
    check_options(name, width, height, board, options)?;
    let field = |label: &str| format!("air/{name}/{label}");
    let mut excluded = Vec::new();
    let mut prepared = Vec::new();
    for (index, view) in views.iter().enumerate() {
        match prepare_view(board, view, &field(&view.label))? {
            Ok(points) => prepared.push(Prepared {
                index,
                board_points: points.0,
                pixels: points.1,
            }),
            Err(reason) => excluded.push((index, reason)),
        }
    }
    // Homographies in pixels scaled about the image centre (conditioning).
    let centre = Vector2::new((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
    let scale = (width as f64 + height as f64) / 2.0;
    let mut homographies = Vec::new();
    let mut kept = Vec::new();
    for view in prepared {
        let scaled: Vec<Vector2<f64>> = view.pixels.iter().map(|p| (p - centre) / scale).collect();
        match homography(&view.board_points, &scaled) {
            Some(h) => {
                homographies.push(h);
                kept.push(view);
            }
            None => excluded.push((
                view.index,
                "degenerate homography: the corners do not span the board's plane in the image"
                    .into(),
            )),
        }
    }
    excluded.sort_by_key(|(i, _)| *i);
    if kept.len() < MIN_VIEWS {
        return Err(too_few(name, views, kept.len(), &excluded, &[]));
    }
    let k_scaled = zhang(&homographies).ok_or_else(|| CalibError::Observation {
        field: format!("air/{name}"),
        reason: "no camera matrix fits the views' homographies (Zhang's closed form): are the views all parallel to one another?".into(),
    })?;
    let mut start = [0.0; INTRINSICS];
    start[0] = k_scaled[0] * scale;
    start[1] = k_scaled[1] * scale;
    start[2] = k_scaled[2] * scale + centre.x;
    start[3] = k_scaled[3] * scale + centre.y;
    let mut views_used = Vec::new();
    let mut poses = Vec::new();
    for view in kept {
        match pose_from(&start, &view) {
            Some(pose) => {
                poses.push(pose);
                views_used.push(view);
            }
            None => excluded.push((
                view.index,
                "no board pose fits its corners with the closed-form camera".into(),
            )),
        }
    }
    excluded.sort_by_key(|(i, _)| *i);
    if views_used.len() < MIN_VIEWS {
        return Err(too_few(name, views, views_used.len(), &excluded, &[]));
    }
    let lm = LmOptions {
        max_iterations: options.max_iterations,
        cost_tolerance: 1e-12,
        ..LmOptions::default()
    };
    let first_terms = match options.model {
        ModelChoice::Auto => LensTerms::K1_K2_TANGENTIAL,
        ModelChoice::Fixed(terms) => terms,
    };
    let mut state = State {
        intrinsics: start,
        poses,
    };
    let mut outliers = Vec::new();
    let mut dropped: Vec<Prepared> = Vec::new();
    // Fit with the start model; drop outlier views until none is left.
    let mut fit = fit_with_outliers(
        name,
        views,
        &excluded,
        &mut views_used,
        &mut state,
        &mut dropped,
        &mut outliers,
        first_terms,
        options,
        &lm,
    )?;
    let selection = match options.model {
        ModelChoice::Fixed(terms) => ModelSelection {
            terms,
            candidates: Vec::new(),
            reason: format!("fixed by the caller: {}", terms.describe()),
        },
        ModelChoice::Auto => select_model(&views_used, &state, options, &lm),
    };
    if selection.terms != first_terms {
        fit = fit_with_outliers(
            name,
            views,
            &excluded,
            &mut views_used,
            &mut state,
            &mut dropped,
            &mut outliers,
            selection.terms,
            options,
            &lm,
        )?;
    }
    finish(
        name, width, height, views, excluded, views_used, dropped, outliers, state, fit, selection,
        &lm,
    )
}

/// One usable view: its input index, its corners' board points and pixels.
#[derive(Debug, Clone)]
struct Prepared {
    index: usize,
    board_points: Vec<Point3<f64>>,
    pixels: Vec<Vector2<f64>>,
}

/// The parameters: fx, fy, cx, cy, k1, k2, p1, p2, k3 and each view's cam_from_board.
#[derive(Debug, Clone)]
struct State {
    intrinsics: [f64; INTRINSICS],
    poses: Vec<Isometry3<f64>>,
}

/// The final normal equations and solver report of a fit.
struct Fitted {
    normal: BlockNormalEquations,
    iterations: usize,
    termination: Termination,
}

fn check_options(
    name: &str,
    width: u32,
    height: u32,
    board: &Board,
    options: &IntrinsicsOptions,
) -> Result<(), CalibError> {
    if width == 0 || height == 0 {
        return Err(CalibError::Options(format!(
            "camera '{name}': image size {width}×{height} px must be positive"
        )));
    }
    if board.corners() < MIN_VIEW_CORNERS || !(board.square > 0.0) || !board.square.is_finite() {
        return Err(CalibError::BadBoard {
            reason: format!(
                "{}×{} inner corners of {} m: intrinsics need at least {MIN_VIEW_CORNERS} corners and a positive square",
                board.cols, board.rows, board.square
            ),
        });
    }
    let checks = [
        (
            "model_margin",
            options.model_margin,
            (0.0..1.0).contains(&options.model_margin),
        ),
        (
            "outlier_factor",
            options.outlier_factor,
            options.outlier_factor > 1.0,
        ),
        (
            "outlier_floor_px",
            options.outlier_floor_px,
            options.outlier_floor_px >= 0.0,
        ),
        (
            "huber_px",
            options.huber_px.unwrap_or(1.0),
            options.huber_px.is_none_or(|k| k > 0.0),
        ),
    ];
    for (field, value, ok) in checks {
        if !ok || !value.is_finite() {
            return Err(CalibError::Options(format!(
                "intrinsics option {field} = {} is out of range",
                number(value)
            )));
        }
    }
    if options.folds < 2 || options.max_iterations == 0 {
        return Err(CalibError::Options(format!(
            "intrinsics options: folds ({}) must be >= 2 and max_iterations ({}) >= 1",
            options.folds, options.max_iterations
        )));
    }
    Ok(())
}

/// The view's board points and pixels, `Ok(Err(reason))` when it cannot be used (too few corners,
/// corners on one line), `Err` when it is malformed.
#[allow(clippy::type_complexity)]
fn prepare_view(
    board: &Board,
    view: &AirView,
    field: &str,
) -> Result<Result<(Vec<Point3<f64>>, Vec<Vector2<f64>>), String>, CalibError> {
    let mut seen = vec![false; board.corners()];
    let mut points = Vec::with_capacity(view.corners.len());
    let mut pixels = Vec::with_capacity(view.corners.len());
    for &(id, pixel) in &view.corners {
        if id >= board.corners() {
            return Err(CalibError::Observation {
                field: field.into(),
                reason: format!(
                    "corner id {id} is off the board ({} × {} inner corners: ids 0..{})",
                    board.cols,
                    board.rows,
                    board.corners()
                ),
            });
        }
        if seen[id] {
            return Err(CalibError::Observation {
                field: field.into(),
                reason: format!("corner id {id} appears twice"),
            });
        }
        seen[id] = true;
        if !pixel.x.is_finite() || !pixel.y.is_finite() {
            return Err(CalibError::Observation {
                field: field.into(),
                reason: format!("corner {id} is not finite: [{}, {}]", pixel.x, pixel.y),
            });
        }
        points.push(board.point_in_board(id));
        pixels.push(pixel.coords);
    }
    if points.len() < MIN_VIEW_CORNERS {
        return Ok(Err(format!(
            "{} corner(s): a view needs at least {MIN_VIEW_CORNERS}",
            points.len()
        )));
    }
    // Board corners on one line (one row, one column, one diagonal) fix no homography. Grid
    // points: the scatter's smaller eigenvalue is exactly 0 on a line and at least of order
    // square² / corners otherwise.
    let n = points.len() as f64;
    let mean = points
        .iter()
        .fold(Vector2::zeros(), |a, p| a + p.xy().coords)
        / n;
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in &points {
        let d = p.xy().coords - mean;
        sxx += d.x * d.x;
        sxy += d.x * d.y;
        syy += d.y * d.y;
    }
    let trace = sxx + syy;
    let det = sxx * syy - sxy * sxy;
    let smaller = trace / 2.0 - ((trace / 2.0).powi(2) - det).max(0.0).sqrt();
    if smaller <= 1e-9 * trace {
        return Ok(Err(format!(
            "its {} corners lie on one line of the board: no homography",
            points.len()
        )));
    }
    Ok(Ok((points, pixels)))
}

fn too_few(
    name: &str,
    views: &[AirView],
    usable: usize,
    excluded: &[(usize, String)],
    outliers: &[(usize, String)],
) -> CalibError {
    let mut reasons: Vec<String> = excluded
        .iter()
        .chain(outliers)
        .map(|(i, why)| format!("{}: {why}", views[*i].label))
        .collect();
    reasons.truncate(8);
    CalibError::Observation {
        field: format!("air/{name}"),
        reason: format!(
            "{usable} usable view(s) of the {} given: intrinsics need at least {MIN_VIEWS}{}{}",
            views.len(),
            if reasons.is_empty() { "" } else { "; " },
            reasons.join("; ")
        ),
    }
}

/// The homography H (3×3, up to scale) with pixel ~ H·(X, Y, 1) of board points (X, Y, 0):
/// Hartley-normalised DLT. `None` when degenerate (its null space is not one-dimensional, or H is
/// singular).
fn homography(board_points: &[Point3<f64>], pixels: &[Vector2<f64>]) -> Option<Matrix3<f64>> {
    let normaliser = |points: &[Vector2<f64>]| -> Option<Matrix3<f64>> {
        let n = points.len() as f64;
        let mean = points.iter().fold(Vector2::zeros(), |a, p| a + p) / n;
        let spread = points.iter().map(|p| (p - mean).norm()).sum::<f64>() / n;
        if !(spread > 0.0) {
            return None;
        }
        let s = std::f64::consts::SQRT_2 / spread;
        Some(Matrix3::new(
            s,
            0.0,
            -s * mean.x,
            0.0,
            s,
            -s * mean.y,
            0.0,
            0.0,
            1.0,
        ))
    };
    let object: Vec<Vector2<f64>> = board_points.iter().map(|p| p.xy().coords).collect();
    let t_object = normaliser(&object)?;
    let t_image = normaliser(pixels)?;
    let mut ata = nalgebra::SMatrix::<f64, 9, 9>::zeros();
    for (o, p) in object.iter().zip(pixels) {
        let o = t_object * Vector3::new(o.x, o.y, 1.0);
        let p = t_image * Vector3::new(p.x, p.y, 1.0);
        let rows = [
            [o.x, o.y, 1.0, 0.0, 0.0, 0.0, -p.x * o.x, -p.x * o.y, -p.x],
            [0.0, 0.0, 0.0, o.x, o.y, 1.0, -p.y * o.x, -p.y * o.y, -p.y],
        ];
        for row in rows {
            let r = nalgebra::SVector::<f64, 9>::from_row_slice(&row);
            ata += r * r.transpose();
        }
    }
    let eigen = ata.symmetric_eigen();
    let mut order: Vec<usize> = (0..9).collect();
    order.sort_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]));
    let (smallest, next) = (eigen.eigenvalues[order[0]], eigen.eigenvalues[order[1]]);
    // A unique homography: the second-smallest eigenvalue well clear of the smallest (the
    // normalised system's eigenvalues are of order 1 for a homography that the corners fix).
    if !(next > 1e-10 * eigen.eigenvalues.max()) || !(smallest <= 0.5 * next) {
        return None;
    }
    let h = eigen.eigenvectors.column(order[0]);
    let hn = Matrix3::from_row_slice(h.as_slice());
    let h = t_image.try_inverse()? * hn * t_object;
    let scale = h.norm();
    let h = h / scale;
    (h.determinant().abs() > 1e-12 && h.iter().all(|x| x.is_finite())).then_some(h)
}

/// Zhang's closed form with zero skew: [fx, fy, cx, cy] (in the homographies' pixel units) from
/// the homographies of ≥ 2 views. Free principal point from ≥ 3 views where that gives a valid
/// camera with its principal point within the image (±0.5 in the scaled units); else the
/// principal point fixed at 0 (the image centre). `None` when neither gives a camera.
fn zhang(homographies: &[Matrix3<f64>]) -> Option<[f64; 4]> {
    let v = |h: &Matrix3<f64>, i: usize, j: usize| -> [f64; 6] {
        let (hi, hj) = (h.column(i), h.column(j));
        [
            hi[0] * hj[0],
            hi[0] * hj[1] + hi[1] * hj[0],
            hi[1] * hj[1],
            hi[2] * hj[0] + hi[0] * hj[2],
            hi[2] * hj[1] + hi[1] * hj[2],
            hi[2] * hj[2],
        ]
    };
    let full = (homographies.len() >= 3)
        .then(|| {
            // b = [B11, B22, B13, B23, B33] (B12 = 0: zero skew).
            let mut ata = nalgebra::SMatrix::<f64, 5, 5>::zeros();
            for h in homographies {
                let (v12, v11, v22) = (v(h, 0, 1), v(h, 0, 0), v(h, 1, 1));
                for row in [v12, std::array::from_fn(|k| v11[k] - v22[k])] {
                    let r = nalgebra::SVector::<f64, 5>::from_row_slice(&[
                        row[0], row[2], row[3], row[4], row[5],
                    ]);
                    ata += r * r.transpose();
                }
            }
            let eigen = ata.symmetric_eigen();
            let b = eigen
                .eigenvectors
                .column(eigen.eigenvalues.imin())
                .into_owned();
            let b = if b[0] < 0.0 { -b } else { b };
            let (b11, b22, b13, b23, b33) = (b[0], b[1], b[2], b[3], b[4]);
            if !(b11 > 0.0 && b22 > 0.0) {
                return None;
            }
            let cx = -b13 / b11;
            let cy = -b23 / b22;
            let lambda = b33 - b13 * b13 / b11 - b23 * b23 / b22;
            let (fx2, fy2) = (lambda / b11, lambda / b22);
            (fx2 > 0.0 && fy2 > 0.0 && cx.abs() < 0.5 && cy.abs() < 0.5)
                .then(|| [fx2.sqrt(), fy2.sqrt(), cx, cy])
        })
        .flatten();
    let plausible =
        |k: &[f64; 4]| k.iter().all(|x| x.is_finite()) && (k[0] / k[1]).max(k[1] / k[0]) < 1.5;
    if let Some(k) = full.filter(plausible) {
        return Some(k);
    }
    // Principal point at the centre: b = [B11, B22, B33].
    let mut ata = Matrix3::zeros();
    for h in homographies {
        let (v12, v11, v22) = (v(h, 0, 1), v(h, 0, 0), v(h, 1, 1));
        for row in [v12, std::array::from_fn(|k| v11[k] - v22[k])] {
            let r = Vector3::new(row[0], row[2], row[5]);
            ata += r * r.transpose();
        }
    }
    let eigen = ata.symmetric_eigen();
    let b = eigen
        .eigenvectors
        .column(eigen.eigenvalues.imin())
        .into_owned();
    let b = if b[0] < 0.0 { -b } else { b };
    let (fx2, fy2) = (b[2] / b[0], b[2] / b[1]);
    let k = [fx2.sqrt(), fy2.sqrt(), 0.0, 0.0];
    (fx2 > 0.0 && fy2 > 0.0 && plausible(&k)).then_some(k)
}

/// The view's cam_from_board by the pinhole model of `intrinsics` (its corners undistorted).
fn pose_from(intrinsics: &[f64; INTRINSICS], view: &Prepared) -> Option<Isometry3<f64>> {
    let camera = camera_of(intrinsics);
    let mut object = Vec::with_capacity(view.pixels.len());
    let mut image = Vec::with_capacity(view.pixels.len());
    for (p, x) in view.board_points.iter().zip(&view.pixels) {
        let distorted = Vector2::new((x.x - camera.cx) / camera.fx, (x.y - camera.cy) / camera.fy);
        if let Some(n) = camera.undistort_normalized(&distorted) {
            object.push(*p);
            image.push(n);
        }
    }
    let pose = pinhole_pose(&object, &image)?;
    // In front of the camera.
    view.board_points
        .iter()
        .all(|p| (pose * p).z > 0.0)
        .then_some(pose)
}

/// A [`PinholeCamera`] of the parameter vector (no validation: the size is unused here).
fn camera_of(intrinsics: &[f64; INTRINSICS]) -> PinholeCamera {
    let [fx, fy, cx, cy, k1, k2, p1, p2, k3] = *intrinsics;
    PinholeCamera {
        width: 1,
        height: 1,
        fx,
        fy,
        cx,
        cy,
        distortion: [k1, k2, p1, p2, k3],
    }
}

/// Reprojection of one view under `intrinsics` and `pose`: the residuals (projected − observed)
/// and, when `jacobian` is asked for, ∂r/∂(free intrinsics, then ω, τ of the pose) in
/// [`view_share`]'s layout. `None` when a corner lies at or behind the camera plane.
fn view_residuals(
    intrinsics: &[f64; INTRINSICS],
    free: &[bool; INTRINSICS],
    pose: &Isometry3<f64>,
    view: &Prepared,
    mut jacobian: Option<&mut Vec<Vector2<f64>>>,
) -> Option<Vec<Vector2<f64>>> {
    let [fx, fy, cx, cy, k1, k2, p1, p2, k3] = *intrinsics;
    let coefficients = [k1, k2, p1, p2, k3];
    let n = view.pixels.len();
    let globals = free.iter().filter(|f| **f).count();
    let columns = globals + POSE_PARAMETERS;
    if let Some(j) = jacobian.as_deref_mut() {
        j.clear();
        j.resize(columns * n, Vector2::zeros());
    }
    let mut residuals = Vec::with_capacity(n);
    for (i, (point, observed)) in view.board_points.iter().zip(&view.pixels).enumerate() {
        let y = pose * point;
        if !(y.z > 1e-12) {
            return None;
        }
        let (x, yy) = (y.x / y.z, y.y / y.z);
        let d = distort_with_jacobian(coefficients, x, yy);
        let pixel = Vector2::new(fx * d.x + cx, fy * d.y + cy);
        residuals.push(pixel - observed);
        let Some(j) = jacobian.as_deref_mut() else {
            continue;
        };
        let r2 = x * x + yy * yy;
        let (r4, xy) = (r2 * r2, x * yy);
        // ∂pixel/∂(fx, fy, cx, cy, k1, k2, p1, p2, k3).
        let all = [
            Vector2::new(d.x, 0.0),
            Vector2::new(0.0, d.y),
            Vector2::new(1.0, 0.0),
            Vector2::new(0.0, 1.0),
            Vector2::new(fx * x * r2, fy * yy * r2),
            Vector2::new(fx * x * r4, fy * yy * r4),
            Vector2::new(fx * 2.0 * xy, fy * (r2 + 2.0 * yy * yy)),
            Vector2::new(fx * (r2 + 2.0 * x * x), fy * 2.0 * xy),
            Vector2::new(fx * x * r4 * r2, fy * yy * r4 * r2),
        ];
        let mut column = 0;
        for (p, derivative) in all.iter().enumerate() {
            if free[p] {
                j[column * n + i] = *derivative;
                column += 1;
            }
        }
        // ∂pixel/∂Y = diag(fx, fy) · D · ∂(x, y)/∂Y, Y the point in the camera frame.
        let inv_z = 1.0 / y.z;
        let projection = Matrix2x3::new(inv_z, 0.0, -x * inv_z, 0.0, inv_z, -yy * inv_z);
        let lens = nalgebra::Matrix2::new(fx * d.dxx, fx * d.dxy, fy * d.dxy, fy * d.dyy);
        let a = lens * projection;
        // Pose step (ω, τ): Y ← exp(ω)·Y + τ, ∂Y/∂ω = −[Y]×, ∂Y/∂τ = I.
        for axis in 0..3 {
            let e = Vector3::ith(axis, 1.0);
            j[(globals + axis) * n + i] = a * e.cross(&y.coords);
            j[(globals + 3 + axis) * n + i] = a * e;
        }
    }
    Some(residuals)
}

/// The least-squares problem over the free intrinsics and every view's pose.
struct Problem<'a> {
    views: &'a [Prepared],
    free: [bool; INTRINSICS],
    huber: Option<f64>,
}

impl Problem<'_> {
    fn globals(&self) -> usize {
        self.free.iter().filter(|f| **f).count()
    }
}

impl LeastSquares for Problem<'_> {
    type State = State;
    type Normal = BlockNormalEquations;

    fn dimension(&self, state: &State) -> usize {
        self.globals() + POSE_PARAMETERS * state.poses.len()
    }

    fn cost(&self, state: &State) -> Option<f64> {
        let mut cost = 0.0;
        for (view, pose) in self.views.iter().zip(&state.poses) {
            let r = view_residuals(&state.intrinsics, &self.free, pose, view, None)?;
            cost += r
                .iter()
                .map(|r| robust(self.huber, r.norm_squared()).0)
                .sum::<f64>();
        }
        Some(cost)
    }

    fn normal_equations(&self, state: &State) -> Option<BlockNormalEquations> {
        let globals = self.globals();
        let mut jacobian = Vec::new();
        let mut shares = Vec::with_capacity(self.views.len());
        for (view, pose) in self.views.iter().zip(&state.poses) {
            let r = view_residuals(
                &state.intrinsics,
                &self.free,
                pose,
                view,
                Some(&mut jacobian),
            )?;
            shares.push(view_share(
                &r,
                &jacobian,
                globals + POSE_PARAMETERS,
                self.huber,
            ));
        }
        Some(BlockNormalEquations::from_shares(globals, shares))
    }

    fn retract(&self, state: &State, delta: &DVector<f64>) -> State {
        let mut intrinsics = state.intrinsics;
        let mut column = 0;
        for (p, free) in self.free.iter().enumerate() {
            if *free {
                intrinsics[p] += delta[column];
                column += 1;
            }
        }
        let poses = state
            .poses
            .iter()
            .enumerate()
            .map(|(v, pose)| {
                let start = column + POSE_PARAMETERS * v;
                move_pose(pose, &delta.as_slice()[start..start + POSE_PARAMETERS])
            })
            .collect();
        State { intrinsics, poses }
    }
}

/// Fits `terms` (the others set to 0) and every pose from `state`; `None` when the start is
/// invalid or the fit ends at an invalid camera.
fn fit(
    views: &[Prepared],
    state: &mut State,
    free: [bool; INTRINSICS],
    options: &IntrinsicsOptions,
    lm: &LmOptions,
) -> Option<Fitted> {
    for (p, f) in free.iter().enumerate().skip(4) {
        if !f {
            state.intrinsics[p] = 0.0;
        }
    }
    let problem = Problem {
        views,
        free,
        huber: options.huber_px,
    };
    let (end, report, normal) = levenberg_marquardt(&problem, state.clone(), lm);
    let normal = normal?;
    if report.termination == Termination::InvalidStart
        || !(end.intrinsics[0] > 0.0 && end.intrinsics[1] > 0.0)
        || !end.intrinsics.iter().all(|x| x.is_finite())
    {
        return None;
    }
    *state = end;
    Some(Fitted {
        normal,
        iterations: report.iterations,
        termination: report.termination,
    })
}

/// Per-view RMS under `state`.
fn view_rms(views: &[Prepared], state: &State) -> Vec<f64> {
    let free = [false; INTRINSICS];
    views
        .iter()
        .zip(&state.poses)
        .map(|(view, pose)| {
            view_residuals(&state.intrinsics, &free, pose, view, None)
                .map(|r| rms(&r))
                .unwrap_or(f64::INFINITY)
        })
        .collect()
}

fn rms(residuals: &[Vector2<f64>]) -> f64 {
    (residuals.iter().map(|r| r.norm_squared()).sum::<f64>() / residuals.len() as f64).sqrt()
}

fn median(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    if n % 2 == 1 {
        sorted[n / 2]
    } else {
        0.5 * (sorted[n / 2 - 1] + sorted[n / 2])
    }
}

/// Fits `terms`, then drops outlier views (the [module](self) docs' rule) and refits, up to
/// [`OUTLIER_ROUNDS`] times. Dropped views move from `views_used` (and their poses from `state`)
/// to `dropped`, with the reason in `outliers`.
#[allow(clippy::too_many_arguments)]
fn fit_with_outliers(
    name: &str,
    all_views: &[AirView],
    excluded: &[(usize, String)],
    views_used: &mut Vec<Prepared>,
    state: &mut State,
    dropped: &mut Vec<Prepared>,
    outliers: &mut Vec<(usize, String)>,
    terms: LensTerms,
    options: &IntrinsicsOptions,
    lm: &LmOptions,
) -> Result<Fitted, CalibError> {
    let free = terms.intrinsics_free();
    let not_converged = || CalibError::Observation {
        field: format!("air/{name}"),
        reason: format!(
            "the maximum-likelihood fit ({} free) ended at no valid camera",
            terms.describe()
        ),
    };
    let mut fitted = fit(views_used, state, free, options, lm).ok_or_else(not_converged)?;
    for _ in 0..OUTLIER_ROUNDS {
        let per_view = view_rms(views_used, state);
        let med = median(&per_view);
        let bound = (options.outlier_factor * med).max(options.outlier_floor_px);
        let flagged: Vec<usize> = (0..per_view.len())
            .filter(|&v| per_view[v] > bound)
            .collect();
        if flagged.is_empty() {
            break;
        }
        if views_used.len() - flagged.len() < MIN_VIEWS {
            let mut named = outliers.clone();
            named.extend(
                flagged
                    .iter()
                    .map(|&v| (views_used[v].index, "outlier view".to_string())),
            );
            return Err(too_few(
                name,
                all_views,
                views_used.len() - flagged.len(),
                excluded,
                &named,
            ));
        }
        for &v in flagged.iter().rev() {
            let view = views_used.remove(v);
            state.poses.remove(v);
            outliers.push((
                view.index,
                format!(
                    "view RMS {} px > {} × the median view RMS {} px (and > {} px)",
                    number(per_view[v]),
                    number(options.outlier_factor),
                    number(med),
                    number(options.outlier_floor_px)
                ),
            ));
            dropped.push(view);
        }
        fitted = fit(views_used, state, free, options, lm).ok_or_else(not_converged)?;
    }
    outliers.sort_by_key(|(i, _)| *i);
    Ok(fitted)
}

/// Fits each held-out view's pose with the intrinsics held; the sum of squared residual lengths
/// and the number of corners. `None` when a pose does not fit.
fn held_out_residuals(
    intrinsics: &[f64; INTRINSICS],
    views: &[Prepared],
    lm: &LmOptions,
) -> Option<(f64, usize)> {
    let mut sum = 0.0;
    let mut corners = 0;
    for view in views {
        let pose = pose_from(intrinsics, view)?;
        let mut state = State {
            intrinsics: *intrinsics,
            poses: vec![pose],
        };
        let problem = Problem {
            views: std::slice::from_ref(view),
            free: [false; INTRINSICS],
            huber: None,
        };
        let (end, _, _) = levenberg_marquardt(&problem, state.clone(), lm);
        state = end;
        let r = view_residuals(
            &state.intrinsics,
            &problem.free,
            &state.poses[0],
            view,
            None,
        )?;
        sum += r.iter().map(|r| r.norm_squared()).sum::<f64>();
        corners += r.len();
    }
    Some((sum, corners))
}

/// The lens terms by k-fold cross-validation over views (the [module](self) docs' rule).
fn select_model(
    views: &[Prepared],
    state: &State,
    options: &IntrinsicsOptions,
    lm: &LmOptions,
) -> ModelSelection {
    let count = views.len();
    let folds = options.folds.min(count);
    // Each fold trains on the views not in it: at least MIN_VIEWS of them.
    if count < MIN_VIEWS + 1 || count - count.div_ceil(folds) < MIN_VIEWS {
        return ModelSelection {
            terms: LensTerms::K1_K2_TANGENTIAL,
            candidates: Vec::new(),
            reason: format!(
                "{count} views are too few to compare lens models on held-out views: OpenCV's usual k1, k2, p1, p2"
            ),
        };
    }
    let candidates: Vec<ModelCandidate> = LensTerms::AUTO_CANDIDATES
        .iter()
        .map(|&terms| {
            let free = terms.intrinsics_free();
            let mut sum = 0.0;
            let mut corners = 0;
            for fold in 0..folds {
                let (train, test): (Vec<usize>, Vec<usize>) =
                    (0..count).partition(|v| v % folds != fold);
                let train_views: Vec<Prepared> = train.iter().map(|&v| views[v].clone()).collect();
                let test_views: Vec<Prepared> = test.iter().map(|&v| views[v].clone()).collect();
                let mut fold_state = State {
                    intrinsics: state.intrinsics,
                    poses: train.iter().map(|&v| state.poses[v]).collect(),
                };
                let held_out = fit(&train_views, &mut fold_state, free, options, lm)
                    .and_then(|_| held_out_residuals(&fold_state.intrinsics, &test_views, lm));
                match held_out {
                    Some((s, n)) => {
                        sum += s;
                        corners += n;
                    }
                    None => {
                        sum = f64::INFINITY;
                        corners = 1;
                        break;
                    }
                }
            }
            ModelCandidate {
                terms,
                held_out_rms_px: (sum / corners.max(1) as f64).sqrt(),
            }
        })
        .collect();
    let mut chosen = candidates[0];
    let mut reasons = Vec::new();
    for candidate in &candidates[1..] {
        let needed = (1.0 - options.model_margin) * chosen.held_out_rms_px;
        if candidate.held_out_rms_px < needed {
            reasons.push(format!(
                "{} predicts held-out views better ({} < {} px)",
                candidate.terms.describe(),
                number(candidate.held_out_rms_px),
                number(chosen.held_out_rms_px)
            ));
            chosen = *candidate;
        } else {
            reasons.push(format!(
                "{} does not predict held-out views {}% better ({} against {} px)",
                candidate.terms.describe(),
                number(100.0 * options.model_margin),
                number(candidate.held_out_rms_px),
                number(chosen.held_out_rms_px)
            ));
        }
    }
    ModelSelection {
        terms: chosen.terms,
        reason: format!(
            "{}-fold cross-validation over {count} views: {}",
            folds,
            reasons.join("; ")
        ),
        candidates,
    }
}

/// The report of the final fit: σ, per-view RMS, outlier views' poses with the final intrinsics.
#[allow(clippy::too_many_arguments)]
fn finish(
    name: &str,
    width: u32,
    height: u32,
    views: &[AirView],
    excluded: Vec<(usize, String)>,
    views_used: Vec<Prepared>,
    dropped: Vec<Prepared>,
    outliers: Vec<(usize, String)>,
    state: State,
    fitted: Fitted,
    model: ModelSelection,
    lm: &LmOptions,
) -> Result<IntrinsicsFit, CalibError> {
    let free = model.terms.intrinsics_free();
    let corners: usize = views_used.iter().map(|v| v.pixels.len()).sum();
    let parameters = free.iter().filter(|f| **f).count() + POSE_PARAMETERS * views_used.len();
    let cost = fitted.normal.cost();
    let sigma2 = cost / (2 * corners).saturating_sub(parameters).max(1) as f64;
    let mut std = [0.0; INTRINSICS];
    let mut std_classical = [0.0; INTRINSICS];
    if let Some(Covariances {
        classical, raised, ..
    }) = covariances(&fitted.normal, sigma2)
    {
        let mut column = 0;
        for (p, f) in free.iter().enumerate() {
            if *f {
                std_classical[p] = classical[(column, column)].max(0.0).sqrt();
                std[p] = raised[(column, column)].max(0.0).sqrt();
                column += 1;
            }
        }
    } else {
        std = [f64::INFINITY; INTRINSICS];
        for (p, f) in free.iter().enumerate() {
            if !f {
                std[p] = 0.0;
            }
        }
        std_classical = std;
    }
    let mut view_rms_px = vec![None; views.len()];
    let mut cam_from_board = vec![None; views.len()];
    let per_view = view_rms(&views_used, &state);
    let mut sum = 0.0;
    for ((view, pose), r) in views_used.iter().zip(&state.poses).zip(&per_view) {
        view_rms_px[view.index] = Some(*r);
        cam_from_board[view.index] = Some(*pose);
        sum += r * r * view.pixels.len() as f64;
    }
    for view in &dropped {
        let pose = pose_from(&state.intrinsics, view).map(|start| {
            let problem = Problem {
                views: std::slice::from_ref(view),
                free: [false; INTRINSICS],
                huber: None,
            };
            let start = State {
                intrinsics: state.intrinsics,
                poses: vec![start],
            };
            levenberg_marquardt(&problem, start, lm).0.poses[0]
        });
        if let Some(pose) = pose {
            let r = view_rms(
                std::slice::from_ref(view),
                &State {
                    intrinsics: state.intrinsics,
                    poses: vec![pose],
                },
            );
            view_rms_px[view.index] = Some(r[0]);
            cam_from_board[view.index] = Some(pose);
        }
    }
    let [fx, fy, cx, cy, k1, k2, p1, p2, k3] = state.intrinsics;
    let camera = PinholeCamera::new(name, width, height, fx, fy, cx, cy, [k1, k2, p1, p2, k3])
        .map_err(|e| CalibError::Observation {
            field: format!("air/{name}"),
            reason: format!("the fit ended at no valid camera: {e}"),
        })?;
    Ok(IntrinsicsFit {
        camera,
        std,
        std_classical,
        rms_px: (sum / corners as f64).sqrt(),
        sigma_px: sigma2.sqrt(),
        view_rms_px,
        outliers,
        excluded,
        model,
        cam_from_board,
        corners,
        iterations: fitted.iterations,
        termination: fitted.termination,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::Rng;
    use nalgebra::{Translation3, UnitQuaternion};

    fn board() -> Board {
        Board {
            rows: 6,
            cols: 9,
            square: 0.04,
        }
    }

    /// A view of the whole board at a fixed pose, as a `Prepared`.
    fn prepared(pose: &Isometry3<f64>, camera: &PinholeCamera) -> Prepared {
        let b = board();
        let board_points: Vec<Point3<f64>> =
            (0..b.corners()).map(|i| b.point_in_board(i)).collect();
        let pixels = board_points
            .iter()
            .map(|p| camera.img_from_cam(&(pose * p)).unwrap().coords + Vector2::new(0.3, -0.2))
            .collect();
        Prepared {
            index: 0,
            board_points,
            pixels,
        }
    }

    #[test]
    fn analytic_jacobian_equals_central_differences() {
        let camera = PinholeCamera::new(
            "t",
            1280,
            1024,
            1000.0,
            1010.0,
            640.0,
            500.0,
            [-0.2, 0.1, 1e-3, -5e-4, 0.02],
        )
        .unwrap();
        let pose = Isometry3::from_parts(
            Translation3::new(-0.15, -0.1, 0.6),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -0.4, 0.1)),
        );
        let view = prepared(&pose, &camera);
        let intrinsics = [1000.0, 1010.0, 640.0, 500.0, -0.2, 0.1, 1e-3, -5e-4, 0.02];
        let free = [true; INTRINSICS];
        let mut jacobian = Vec::new();
        let base = view_residuals(&intrinsics, &free, &pose, &view, Some(&mut jacobian)).unwrap();
        let n = base.len();
        let problem = Problem {
            views: std::slice::from_ref(&view),
            free,
            huber: None,
        };
        let state = State {
            intrinsics,
            poses: vec![pose],
        };
        // Steps sized to each parameter's scale; central differences err by O(h²).
        let steps = [
            1e-3, 1e-3, 1e-3, 1e-3, 1e-6, 1e-6, 1e-7, 1e-7, 1e-6, 1e-6, 1e-6, 1e-6, 1e-7, 1e-7,
            1e-7,
        ];
        for (p, h) in steps.iter().enumerate() {
            let mut delta = DVector::zeros(15);
            delta[p] = *h;
            let plus = problem.retract(&state, &delta);
            delta[p] = -*h;
            let minus = problem.retract(&state, &delta);
            let rp = view_residuals(&plus.intrinsics, &free, &plus.poses[0], &view, None).unwrap();
            let rm =
                view_residuals(&minus.intrinsics, &free, &minus.poses[0], &view, None).unwrap();
            for i in 0..n {
                let numeric = (rp[i] - rm[i]) / (2.0 * h);
                let analytic = jacobian[p * n + i];
                let error = (numeric - analytic).norm();
                assert!(
                    error <= 1e-6 * analytic.norm().max(1.0),
                    "parameter {p}, corner {i}: analytic {analytic:?}, numeric {numeric:?}"
                );
            }
        }
    }

    #[test]
    fn homography_of_a_pinhole_view_is_exact_and_a_line_is_refused() {
        let mut rng = Rng::new(3);
        let h_true = Matrix3::new(900.0, 30.0, 400.0, -20.0, 950.0, 300.0, 0.1, 0.05, 1.0);
        let b = board();
        let points: Vec<Point3<f64>> = (0..b.corners()).map(|i| b.point_in_board(i)).collect();
        let pixels: Vec<Vector2<f64>> = points
            .iter()
            .map(|p| {
                let q = h_true * Vector3::new(p.x, p.y, 1.0);
                Vector2::new(q.x / q.z, q.y / q.z)
            })
            .collect();
        let h = homography(&points, &pixels).unwrap();
        let h = h / h[(2, 2)];
        assert!((h - h_true).norm() < 1e-8 * h_true.norm(), "{h}");
        // One board row: no homography; as a view it is excluded with a reason, not an error.
        let row: Vec<(usize, Point2<f64>)> = (0..9)
            .map(|c| (c, Point2::from(pixels[c] + Vector2::new(rng.normal(), 0.0))))
            .collect();
        let view = AirView {
            label: "row.png".into(),
            corners: row,
        };
        let reason = prepare_view(&b, &view, "air/t/row.png")
            .unwrap()
            .unwrap_err();
        assert!(reason.contains("one line"), "{reason}");
    }

    #[test]
    fn malformed_views_are_errors_that_name_the_view() {
        let view = AirView {
            label: "bad.png".into(),
            corners: vec![(54, Point2::new(1.0, 2.0))],
        };
        let error = prepare_view(&board(), &view, "air/cam/bad.png").unwrap_err();
        assert_eq!(error.field(), "air/cam/bad.png");
        assert!(error.to_string().contains("corner id 54"), "{error}");
        let view = AirView {
            label: "twice.png".into(),
            corners: vec![(3, Point2::new(1.0, 2.0)), (3, Point2::new(4.0, 2.0))],
        };
        assert!(
            prepare_view(&board(), &view, "x")
                .unwrap_err()
                .to_string()
                .contains("twice")
        );
        let view = AirView {
            label: "nan.png".into(),
            corners: vec![(3, Point2::new(f64::NAN, 2.0))],
        };
        assert!(
            prepare_view(&board(), &view, "x")
                .unwrap_err()
                .to_string()
                .contains("not finite")
        );
    }
}
