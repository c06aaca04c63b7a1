//! Board corners in images, in the order the calibration needs: row-major as OpenCV's
//! `findChessboardCorners` gives them (corner `r·cols + c` at board point (c·s, r·s)), with the
//! same physical corner 0 in every camera of a view. A ChArUco board ([`board`]) names its
//! corners itself ([`detect_charuco`]: OpenCV's corner ids, partial views included); a plain
//! chessboard needs the rules below. [`find_corners`] takes either kind.
//!
//! The corners come from the `calib-targets` crate (ChESS corners, its chessboard grid, the
//! saddle-point sub-pixel refiner); the few inner corners a grid of the board's shape misses
//! (a backscatter speck on a corner) are filled in by [`fill`]. A ChArUco board the grid does
//! not find is found from its markers ([`markers`]). The grid's labels say which
//! corner is next to which, not which end of the board is corner 0: a chessboard looks the same
//! turned by 180° (and by 90° when it is square), up to the colours of its squares. [`Detection::orderings`] holds every ordering the
//! image allows; [`colour_rule`], [`image_rule`] and [`pair_by_rays`] choose among them.
//!
//! **Corner 0 (the documented rule).** Corner 0 is the inner corner at the board's black corner
//! square: the square between corners 0, 1, cols and cols + 1 is black. On a board whose squares
//! per side (cols + 1, rows + 1) add up to an odd number (9×6: 10 × 7 squares) the two ends of the
//! board have corner squares of opposite colours, so the colour decides in every image. On a
//! colour-symmetric board (both ends alike, e.g. 8×6 or 9×7) the colour cannot decide: with a rig,
//! the other cameras of a view take the ordering whose rays meet those of the first camera; without
//! one, each image takes the ordering whose rows run most nearly left to right in the image, and a
//! view where some image's rows run too close to vertical for that is reported, not guessed
//! (`calibrate --images`, which orders each image alone, makes the orders agree across the
//! cameras once their lenses are known: [`crate::calib::pipeline::turns`]).
//! Chirality is fixed: with the rows running right in the image, the next row lies below, so the
//! board frame's z axis (row direction × column direction) points away from the camera, as in
//! the calibration's board model.

pub mod fill;
pub mod markers;

pub use crate::base::{BoardError, BoardSpec, CharucoSpec};
pub use fill::{FilledCorner, Unrefined};

use image::GrayImage;
use nalgebra::Point2;

use crate::base::Board;
use crate::model::{Rig, triangulate_rays};

use calib_targets::chessboard::ChessboardParams;
use calib_targets::core::{DetectorConfig, ImageRefiner};

/// Why an image gave no board.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Miss {
    /// No chessboard grid at all.
    NoBoard,
    /// A grid, but not the whole board.
    Partial {
        /// Corners found (the largest grid).
        found: usize,
        /// Its extent, corners across × down the image.
        extent: (usize, usize),
    },
    /// A ChArUco board, but too few of its corners to use ([`MIN_CHARUCO_CORNERS`], spanning
    /// two rows and two columns of the board).
    Sparse {
        /// Corners found, with their ids.
        found: usize,
    },
}

impl std::fmt::Display for Miss {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Miss::NoBoard => write!(f, "no board found"),
            Miss::Partial {
                found,
                extent: (w, h),
            } => {
                write!(
                    f,
                    "found a grid of {found} corners ({w} × {h}), not the whole board"
                )
            }
            Miss::Sparse { found } => write!(
                f,
                "found {found} ChArUco corners, fewer than {MIN_CHARUCO_CORNERS} spanning two rows and two columns of the board"
            ),
        }
    }
}

/// The board found in one image.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    /// Every row-major ordering of the corners the image allows (2, or 4 for a square board),
    /// each `rows · cols` pixels; they differ by turns of the board in its plane.
    pub orderings: Vec<Vec<Point2<f64>>>,
    /// The inner corners the grid missed (a speck on a corner hides it), filled in by
    /// [`fill`]; empty when the grid was whole. Those with [`FilledCorner::unrefined`] set sit
    /// where their neighbours put them, not where the image does, and are no observation
    /// ([`Detection::observed`]).
    pub filled: Vec<FilledCorner>,
}

impl Detection {
    /// Ordering `o`'s corners as observations: `None` for a corner the image did not place (a
    /// filled corner whose refinement failed: [`FilledCorner::unrefined`]). Its prediction from
    /// the neighbours can be pixels off on a slanted, distorted board (zoo seed 43's cam0: one
    /// such corner 2.5 px off in one in-air view moved the lens's fx by 2.5 px), and a guess is
    /// not a measurement: the view keeps its other corners.
    pub fn observed(&self, o: usize) -> Vec<Option<Point2<f64>>> {
        self.orderings[o]
            .iter()
            .map(|&p| {
                let guessed = self
                    .filled
                    .iter()
                    .any(|f| f.unrefined.is_some() && f.pixel == p);
                (!guessed).then_some(p)
            })
            .collect()
    }
}

/// The ChESS front end: the workspace defaults of calib-targets with the saddle-point refiner,
/// which replaces the centre of mass of the response (measured on rendered images: see
/// docs/images.md, "The detector").
fn chess_config() -> DetectorConfig {
    calib_targets::detect::default_chess_config().with_refiner(ImageRefiner::saddle_point())
}

/// Standard deviation (pixels) of the Gaussian blur before the corners are found. On sharp
/// rendered images (anti-aliased, no blur) the saddle-point refiner's worst corner was 0.37 px
/// off without it and 0.07 px with 0.8–1.2 px (RMS 0.02 px either way); see docs/images.md,
/// "The detector".
pub const PRE_BLUR_PX: f32 = 1.0;

/// Board corner (column, row) → grid label (i, j), given the grid's width and height.
type Turn = fn(usize, usize, usize, usize) -> (usize, usize);

/// Finds `board` in a grey image: all its `rows · cols` inner corners, or why not. A grid with
/// the board's shape that misses a few inner corners (at most a tenth, every border line holding
/// at least half of its corners) has them filled in ([`fill`]: predicted from their
/// neighbours, checked to be a chessboard corner on the image, refined robustly to a speck, and
/// listed in [`Detection::filled`]); any other grid, or one whose gap is not a chessboard
/// corner, is [`Miss::Partial`].
pub fn detect_board(image: &GrayImage, board: &Board) -> Result<Detection, Miss> {
    let params = ChessboardParams::sweep_default();
    let smoothed = calib_targets::detect::preprocess(image, PRE_BLUR_PX);
    let detection =
        calib_targets::detect::detect_chessboard_best(&smoothed, &chess_config(), &params)
            .map_err(|_| Miss::NoBoard)?;
    let corners = &detection.corners;
    if corners.is_empty() {
        return Err(Miss::NoBoard);
    }
    let min_u = corners.iter().map(|c| c.grid.u).min().unwrap_or(0);
    let min_v = corners.iter().map(|c| c.grid.v).min().unwrap_or(0);
    let w = (corners.iter().map(|c| c.grid.u).max().unwrap_or(0) - min_u + 1) as usize;
    let h = (corners.iter().map(|c| c.grid.v).max().unwrap_or(0) - min_v + 1) as usize;
    let partial = Miss::Partial {
        found: corners.len(),
        extent: (w, h),
    };
    let shape = w * h == board.corners() && (w == board.cols || w == board.rows);
    if !shape || corners.len() > board.corners() {
        return Err(partial);
    }
    // grid[j][i], i across the image (right), j down.
    let mut grid = vec![None; w * h];
    for c in corners {
        let (i, j) = ((c.grid.u - min_u) as usize, (c.grid.v - min_v) as usize);
        grid[j * w + i] = Some(Point2::new(
            f64::from(c.position.x),
            f64::from(c.position.y),
        ));
    }
    let filled =
        fill::fill_missing(&mut grid, w, h, image, &smoothed).ok_or_else(|| partial.clone())?;
    // The labels should run right and down in the image (i × j = +z, image y down); mirror them
    // if they do not, so that the orderings below keep the board's chirality.
    let (Some(origin), Some(along_i), Some(along_j)) = (grid[0], grid[w - 1], grid[(h - 1) * w])
    else {
        return Err(partial);
    };
    let (di, dj) = (along_i - origin, along_j - origin);
    if di.x * dj.y - di.y * dj.x < 0.0 {
        for row in grid.chunks_mut(w) {
            row.reverse();
        }
    }
    let at = |i: usize, j: usize| grid[j * w + i];
    // An ordering maps board corner (c, r) to grid (i, j); the four turns of the board in its
    // plane keep the chirality (rows to the right ⇒ next row below).
    let turns: [Turn; 4] = [
        |c, r, _, _| (c, r),                 // rows run right
        |c, r, w, h| (w - 1 - c, h - 1 - r), // rows run left
        |c, r, w, _| (w - 1 - r, c),         // rows run down
        |c, r, _, h| (r, h - 1 - c),         // rows run up
    ];
    let mut orderings = Vec::new();
    for (k, turn) in turns.iter().enumerate() {
        let fits = if k < 2 {
            w == board.cols && h == board.rows
        } else {
            w == board.rows && h == board.cols
        };
        if !fits {
            continue;
        }
        let ordering: Option<Vec<_>> = (0..board.corners())
            .map(|n| {
                let (r, c) = board.grid_position(n);
                let (i, j) = turn(c, r, w, h);
                at(i, j)
            })
            .collect();
        orderings.extend(ordering);
    }
    if orderings.is_empty() {
        return Err(partial);
    }
    Ok(Detection { orderings, filled })
}

/// True when the two ends of the board have corner squares of opposite colours, so that the
/// colour tells corner 0 from the last corner: cols + rows odd.
pub fn colour_decides(board: &Board) -> bool {
    (board.cols + board.rows) % 2 == 1
}

/// Mean grey level (0 … 255) inside the quadrilateral of corners a, b, c, d (a–b one side, c–d
/// the opposite side), sampled on a 4 × 4 grid over its middle half, bilinear.
fn quad_mean(
    image: &GrayImage,
    a: Point2<f64>,
    b: Point2<f64>,
    c: Point2<f64>,
    d: Point2<f64>,
) -> f64 {
    let mut sum = 0.0;
    let mut count = 0.0;
    for i in 0..4 {
        for j in 0..4 {
            let (s, t) = (
                0.25 + 0.5 * (i as f64 + 0.5) / 4.0,
                0.25 + 0.5 * (j as f64 + 0.5) / 4.0,
            );
            let p = a.coords * ((1.0 - s) * (1.0 - t))
                + b.coords * (s * (1.0 - t))
                + c.coords * ((1.0 - s) * t)
                + d.coords * (s * t);
            if let Some(v) = bilinear(image, p.x, p.y) {
                sum += v;
                count += 1.0;
            }
        }
    }
    if count > 0.0 { sum / count } else { f64::NAN }
}

fn bilinear(image: &GrayImage, x: f64, y: f64) -> Option<f64> {
    let (w, h) = (image.width() as f64, image.height() as f64);
    if !(x >= 0.0 && y >= 0.0 && x <= w - 1.0 && y <= h - 1.0) {
        return None;
    }
    let (x0, y0) = (x.floor() as u32, y.floor() as u32);
    let (x1, y1) = (
        (x0 + 1).min(image.width() - 1),
        (y0 + 1).min(image.height() - 1),
    );
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let g = |x, y| f64::from(image.get_pixel(x, y).0[0]);
    Some(
        (g(x0, y0) * (1.0 - fx) + g(x1, y0) * fx) * (1.0 - fy)
            + (g(x0, y1) * (1.0 - fx) + g(x1, y1) * fx) * fy,
    )
}

/// Smallest difference in grey levels (of 255) between the first square and its neighbour that
/// the colour rule trusts.
pub const MIN_CONTRAST: f64 = 12.0;

/// The orderings whose first square (corners 0, 1, cols, cols + 1) is black, judged against the
/// next square along the row; `None` when the contrast is below [`MIN_CONTRAST`] for some
/// ordering (the image does not show the colours clearly).
pub fn colour_rule(
    image: &GrayImage,
    board: &Board,
    orderings: &[Vec<Point2<f64>>],
) -> Option<Vec<usize>> {
    let cols = board.cols;
    let mut dark = Vec::new();
    for (k, p) in orderings.iter().enumerate() {
        let first = quad_mean(image, p[0], p[1], p[cols], p[cols + 1]);
        let next = quad_mean(image, p[1], p[2], p[cols + 1], p[cols + 2]);
        if !((first - next).abs() >= MIN_CONTRAST) {
            return None;
        }
        if first < next {
            dark.push(k);
        }
    }
    Some(dark)
}

/// Unit direction of the first row (corner 0 → corner cols − 1) in the image.
fn row_direction(board: &Board, p: &[Point2<f64>]) -> nalgebra::Vector2<f64> {
    (p[board.cols - 1] - p[0]).normalize()
}

/// Smallest lead, in cosine of the row direction against the image's u axis, of the best ordering
/// over the next for [`image_rule`] to decide: two orderings 180° apart are told apart unless the
/// rows lie within 14.5° of vertical (|cos| < 0.25).
pub const MIN_IMAGE_RULE_LEAD: f64 = 0.5;

/// Among `candidates` (indices into `orderings`), the one whose rows run most nearly to the right
/// in the image; `None` when the runner-up is within [`MIN_IMAGE_RULE_LEAD`].
pub fn image_rule(
    board: &Board,
    orderings: &[Vec<Point2<f64>>],
    candidates: &[usize],
) -> Option<usize> {
    let mut scored: Vec<(f64, usize)> = candidates
        .iter()
        .map(|&k| (row_direction(board, &orderings[k]).x, k))
        .collect();
    scored.sort_by(|a, b| b.0.total_cmp(&a.0));
    match scored[..] {
        [(_, k)] => Some(k),
        [(best, k), (next, _), ..] if best - next >= MIN_IMAGE_RULE_LEAD => Some(k),
        _ => None,
    }
}

/// How much better the chosen pairing's rays must meet than the next one's (ratio of RMS gaps)
/// for [`pair_by_rays`] to decide.
pub const MIN_RAY_GAP_RATIO: f64 = 4.0;

/// The ordering among `candidates` of rig camera `camera` whose corners' water rays meet those of
/// `reference` (rig camera `reference_camera`'s corners in their chosen order) best, with the RMS
/// gap (metres) of the best and of the runner-up; `None` as the choice when the runner-up is within
/// [`MIN_RAY_GAP_RATIO`] or no pairing triangulates.
pub fn pair_by_rays(
    rig: &Rig,
    reference_camera: usize,
    reference: &[Point2<f64>],
    camera: usize,
    orderings: &[Vec<Point2<f64>>],
    candidates: &[usize],
) -> (Option<usize>, Vec<(usize, f64)>) {
    let (a, b) = (
        rig.refractive_camera(reference_camera),
        rig.refractive_camera(camera),
    );
    let mut gaps: Vec<(usize, f64)> = candidates
        .iter()
        .map(|&k| {
            let mut sum = 0.0;
            let mut count = 0usize;
            for (p, q) in reference.iter().zip(&orderings[k]) {
                let gap = a
                    .backproject(p)
                    .and_then(|ra| b.backproject(q).and_then(|rb| triangulate_rays(&ra, &rb)));
                if let Ok(t) = gap {
                    sum += t.residual * t.residual;
                    count += 1;
                }
            }
            // Pairs without an answer count as far apart: a flipped pairing often has none.
            let missing = reference.len() - count;
            (
                k,
                if count == 0 {
                    f64::INFINITY
                } else {
                    ((sum + missing as f64) / reference.len() as f64).sqrt()
                },
            )
        })
        .collect();
    gaps.sort_by(|x, y| x.1.total_cmp(&y.1));
    let choice = match gaps[..] {
        [(k, best)] if best.is_finite() => Some(k),
        [(k, best), (_, next), ..] if best.is_finite() && next >= MIN_RAY_GAP_RATIO * best => {
            Some(k)
        }
        _ => None,
    };
    (choice, gaps)
}

/// What one image gave: the board (or why not) and, where the board's colours decide, the
/// orderings whose first square is black ([`colour_rule`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Found {
    /// The orderings the image allows.
    pub detection: Detection,
    /// [`colour_rule`]'s answer: `None` when the colours do not decide (colour-symmetric board,
    /// low contrast).
    pub colour: Option<Vec<usize>>,
}

impl Found {
    /// Runs [`colour_rule`] where the board's colours can decide.
    pub fn new(image: &GrayImage, board: &Board, detection: Detection) -> Self {
        let colour = if colour_decides(board) {
            colour_rule(image, board, &detection.orderings).filter(|c| !c.is_empty())
        } else {
            None
        };
        Self { detection, colour }
    }

    /// The single ordering the colours leave, if they leave one.
    fn by_colour(&self) -> Option<usize> {
        match self.colour.as_deref() {
            Some([k]) => Some(*k),
            _ => None,
        }
    }

    fn candidates(&self) -> Vec<usize> {
        match &self.colour {
            Some(c) => c.clone(),
            None => (0..self.detection.orderings.len()).collect(),
        }
    }
}

/// Which rule chose an image's corner 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rule {
    /// The black corner square ([`colour_rule`]).
    Colour,
    /// The rows run most nearly to the right ([`image_rule`]).
    Image,
    /// The rays meet those of the view's first camera ([`pair_by_rays`]).
    Rays,
    /// The first camera of a view with a rig and no colour to go by: any ordering will do, the
    /// others follow it by their rays.
    Reference,
}

impl Rule {
    /// A short name for reports.
    pub fn name(self) -> &'static str {
        match self {
            Rule::Colour => "colour",
            Rule::Image => "image",
            Rule::Rays => "rays",
            Rule::Reference => "reference",
        }
    }
}

/// Chooses corner 0 in every image of one view, so that it is the same physical corner in all of
/// them (the rules in the module's documentation). `found[k]` is camera `names[k]`'s result (`None` when
/// it did not see the board); with a rig, `rig_cameras[k]` is camera k's index in it. Returns
/// each camera's ordering and the rule that chose it, or why the view cannot be resolved.
pub fn resolve_view(
    board: &Board,
    names: &[String],
    rig: Option<(&Rig, &[usize])>,
    found: &[Option<Found>],
) -> Result<Vec<Option<(usize, Rule)>>, String> {
    let mut chosen: Vec<Option<(usize, Rule)>> = vec![None; found.len()];
    // The cameras that saw the board, with what they found.
    let seen: Vec<(usize, &Found)> = found
        .iter()
        .enumerate()
        .filter_map(|(k, f)| f.as_ref().map(|f| (k, f)))
        .collect();
    let image_choice = |f: &Found| image_rule(board, &f.detection.orderings, &f.candidates());
    match rig {
        Some((rig, indices)) if seen.len() > 1 => {
            let (reference, first) = seen
                .iter()
                .copied()
                .find(|(_, f)| f.by_colour().is_some())
                .unwrap_or(seen[0]);
            let by_colour = first.by_colour();
            let (ordering, rule) = match by_colour {
                Some(o) => (o, Rule::Colour),
                None => (
                    image_choice(first).unwrap_or(first.candidates()[0]),
                    Rule::Reference,
                ),
            };
            chosen[reference] = Some((ordering, rule));
            let corners = &first.detection.orderings[ordering];
            for &(k, f) in seen.iter().filter(|(k, _)| *k != reference) {
                let all: Vec<usize> = (0..f.detection.orderings.len()).collect();
                let (rays, gaps) = pair_by_rays(
                    rig,
                    indices[reference],
                    corners,
                    indices[k],
                    &f.detection.orderings,
                    &all,
                );
                let colour = if by_colour.is_some() {
                    f.by_colour()
                } else {
                    None
                };
                chosen[k] = Some(match (colour, rays) {
                    (Some(c), Some(r)) if c == r => (r, Rule::Rays),
                    (Some(c), Some(r)) => {
                        return Err(format!(
                            "camera {}: the colours put corner 0 at one end of the board (ordering {c}) and the rays at the other (ordering {r})",
                            names[k]
                        ));
                    }
                    (None, Some(r)) => (r, Rule::Rays),
                    (Some(c), None) => (c, Rule::Colour),
                    (None, None) => {
                        let text: Vec<String> = gaps
                            .iter()
                            .map(|(o, g)| format!("ordering {o}: {:.1} mm", g * 1e3))
                            .collect();
                        return Err(format!(
                            "camera {}: no colour to go by and its rays meet those of camera {} about equally well either way round ({})",
                            names[k],
                            names[reference],
                            text.join(", ")
                        ));
                    }
                });
            }
        }
        _ => {
            let all_by_colour = seen.iter().all(|(_, f)| f.by_colour().is_some());
            for &(k, f) in &seen {
                chosen[k] = Some(if let (true, Some(o)) = (all_by_colour, f.by_colour()) {
                    (o, Rule::Colour)
                } else if let Some(o) = image_choice(f) {
                    (o, Rule::Image)
                } else if seen.len() == 1 {
                    // One camera alone: either end serves, the board's pose is free.
                    (f.candidates()[0], Rule::Reference)
                } else {
                    return Err(format!(
                        "camera {}: the colours do not decide and the board's rows run too close to vertical in the image to tell \
                         its ends apart (give --rig to pair the cameras by their rays)",
                        names[k]
                    ));
                });
            }
        }
    }
    Ok(chosen)
}

/// Largest gap a ChArUco corner may have from the position the local homography of its grid
/// neighbours predicts for it ([`inconsistent_charuco_corners`]), as a fraction of the local square
/// side (pixels per square there, from the same homography): 0.12.
///
/// Why 0.12: a board seen through a flat port is not a homography of the image (refraction bends
/// it, more towards the image edge), and even 2 squares around a corner the homography misses
/// correct corners by up to 0.08 of a side (measured: 1377 corners of the rendered calibration set
/// of the example rig, through its 8° port, squares 80–160 px: 99 % below 0.033, largest 0.080 at
/// a board corner, where the fit extrapolates). The features a ChArUco corner can be mistaken
/// for lie farther: the white margin's junctions and the marker's corners next to a corner are
/// (1 − marker/square)/2 of a side along each axis away, 0.18 of a side diagonally on a board
/// with markers at 0.75 of the square (the misplaced corner that led here was 0.21 of a side
/// off), and a neighbouring corner is a whole side away. 0.12 is 1.5 × the largest model error
/// and leaves the nearest false feature 1.5 × beyond the threshold.
pub const MAX_LOCAL_HOMOGRAPHY_GAP_REL: f64 = 0.12;

/// Floor of the threshold in pixels, whatever the square side: the corners' own noise (a few
/// hundredths of a pixel on rendered images, ~0.1–0.3 px on real ones) must never flag a corner of
/// a small board.
pub const MIN_LOCAL_HOMOGRAPHY_GAP_PX: f64 = 1.0;

/// How far around a corner, in board squares along rows and columns (Chebyshev distance), the
/// neighbours lie that [`inconsistent_charuco_corners`] fits its local homography to: 2, up to 24
/// neighbours, enough that one misplaced neighbour barely moves the fit, near enough that the
/// refraction's departure from a homography stays small (see [`MAX_LOCAL_HOMOGRAPHY_GAP_REL`]).
pub const LOCAL_HOMOGRAPHY_RADIUS: usize = 2;

/// True when some 4 of the board points have no 3 on one line (else no homography is fixed:
/// the board points here are whole numbers, so the test is exact).
fn four_in_general_position(pairs: &[(Point2<f64>, Point2<f64>)]) -> bool {
    let n = pairs.len();
    let line = |a: usize, b: usize, c: usize| {
        let (p, q, r) = (pairs[a].0, pairs[b].0, pairs[c].0);
        ((q - p).perp(&(r - p))).abs() < 1e-9
    };
    for a in 0..n {
        for b in a + 1..n {
            for c in b + 1..n {
                if line(a, b, c) {
                    continue;
                }
                for d in c + 1..n {
                    if !line(a, b, d) && !line(a, c, d) && !line(b, c, d) {
                        return true;
                    }
                }
            }
        }
    }
    false
}

/// Board → image homography through `pairs` (board point, pixel), by the normalised DLT;
/// `None` when the points do not fix one (fewer than 4, or degenerate: three of four on a line).
fn fit_homography(pairs: &[(Point2<f64>, Point2<f64>)]) -> Option<nalgebra::Matrix3<f64>> {
    use nalgebra::{DMatrix, Matrix3};
    if !four_in_general_position(pairs) {
        return None;
    }
    // Hartley's normalisation: centroid at 0, mean distance √2.
    let normaliser = |points: &mut dyn Iterator<Item = Point2<f64>>| -> Option<Matrix3<f64>> {
        let points: Vec<Point2<f64>> = points.collect();
        let n = points.len() as f64;
        let centre = points
            .iter()
            .fold(nalgebra::Vector2::zeros(), |s, p| s + p.coords)
            / n;
        let spread = points
            .iter()
            .map(|p| (p.coords - centre).norm())
            .sum::<f64>()
            / n;
        if !(spread > 0.0) {
            return None;
        }
        let s = std::f64::consts::SQRT_2 / spread;
        Some(Matrix3::new(
            s,
            0.0,
            -s * centre.x,
            0.0,
            s,
            -s * centre.y,
            0.0,
            0.0,
            1.0,
        ))
    };
    let t_board = normaliser(&mut pairs.iter().map(|p| p.0))?;
    let t_image = normaliser(&mut pairs.iter().map(|p| p.1))?;
    // At least 10 rows (zeros past the data), so that the thin SVD keeps all 9 right singular
    // vectors, the null vector of 4 points' 8 equations included.
    let mut a = DMatrix::<f64>::zeros(2 * pairs.len().max(5), 9);
    for (k, (b, i)) in pairs.iter().enumerate() {
        let b = t_board * b.to_homogeneous();
        let i = t_image * i.to_homogeneous();
        let (x, y, u, v) = (b.x / b.z, b.y / b.z, i.x / i.z, i.y / i.z);
        let rows = [
            [x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y, -u],
            [0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y, -v],
        ];
        for (r, row) in rows.iter().enumerate() {
            for (c, value) in row.iter().enumerate() {
                a[(2 * k + r, c)] = *value;
            }
        }
    }
    let svd = a.svd(false, true);
    let v_t = svd.v_t?;
    // The solution is the right singular vector of the smallest singular value; a second one
    // near zero means the points leave the homography free (degenerate configuration).
    let mut order: Vec<usize> = (0..9).collect();
    order.sort_by(|&p, &q| svd.singular_values[p].total_cmp(&svd.singular_values[q]));
    let (smallest, second, largest) = (
        order[0],
        svd.singular_values[order[1]],
        svd.singular_values[order[8]],
    );
    if !(second > 1e-8 * largest) {
        return None;
    }
    let h = v_t.row(smallest);
    let h_norm = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let inverse = t_image.try_inverse()?;
    Some(inverse * h_norm * t_board)
}

/// `h` applied to `p`; `None` at the line the homography sends to infinity.
fn apply(h: &nalgebra::Matrix3<f64>, p: Point2<f64>) -> Option<Point2<f64>> {
    let q = h * p.to_homogeneous();
    (q.z.abs() > f64::EPSILON).then(|| Point2::new(q.x / q.z, q.y / q.z))
}

/// For corner `corners[index]` (`(id, pixel)`, ids as [`detect_charuco`] gives them on a corner
/// grid `cols` wide): its distance (pixels) from where the homography fitted to the other corners
/// within [`LOCAL_HOMOGRAPHY_RADIUS`] squares puts it, and the local square side (pixels, the
/// shorter of the two board axes there); `None` when those corners do not fix a homography
/// (fewer than 4, or degenerate) or `index` is out of range.
pub fn local_homography_gap(
    corners: &[(usize, Point2<f64>)],
    cols: usize,
    index: usize,
) -> Option<(f64, f64)> {
    let (id, pixel) = *corners.get(index)?;
    let (row, col) = ((id / cols) as i64, (id % cols) as i64);
    let r = LOCAL_HOMOGRAPHY_RADIUS as i64;
    let pairs: Vec<(Point2<f64>, Point2<f64>)> = corners
        .iter()
        .enumerate()
        .filter(|&(k, &(other, _))| {
            let (orow, ocol) = ((other / cols) as i64, (other % cols) as i64);
            k != index && (orow - row).abs() <= r && (ocol - col).abs() <= r
        })
        .map(|(_, &(other, p))| (Point2::new((other % cols) as f64, (other / cols) as f64), p))
        .collect();
    let h = fit_homography(&pairs)?;
    let at = Point2::new(col as f64, row as f64);
    let predicted = apply(&h, at)?;
    let side_u = (apply(&h, at + nalgebra::Vector2::new(1.0, 0.0))? - predicted).norm();
    let side_v = (apply(&h, at + nalgebra::Vector2::new(0.0, 1.0))? - predicted).norm();
    Some(((pixel - predicted).norm(), side_u.min(side_v)))
}

/// The ids of the ChArUco corners that disagree with their grid neighbours, which
/// [`detect_charuco`] drops (a corner dropped is harmless; a misplaced corner with a valid id
/// misleads every calibration downstream).
///
/// **The rule.** A corner is kept when its distance from the position the local homography
/// ([`local_homography_gap`]) of the corners within [`LOCAL_HOMOGRAPHY_RADIUS`] squares predicts
/// is at most max([`MIN_LOCAL_HOMOGRAPHY_GAP_PX`], [`MAX_LOCAL_HOMOGRAPHY_GAP_REL`] × the local
/// square side). The corner farthest beyond its threshold is dropped first and the rest are judged
/// again without it (a misplaced corner also pulls its neighbours' fits), until every corner left
/// passes. A corner whose neighbours do not fix a homography (fewer than 4 of them, or on one
/// line) cannot be checked and is dropped too.
pub fn inconsistent_charuco_corners(corners: &[(usize, Point2<f64>)], cols: usize) -> Vec<usize> {
    let mut kept: Vec<(usize, Point2<f64>)> = corners.to_vec();
    let mut dropped = Vec::new();
    if cols == 0 {
        return dropped;
    }
    loop {
        // (how far beyond its threshold, as a ratio; index) of the worst corner.
        let worst = (0..kept.len())
            .map(|k| {
                let excess = match local_homography_gap(&kept, cols, k) {
                    Some((gap, side)) => {
                        gap / (MAX_LOCAL_HOMOGRAPHY_GAP_REL * side).max(MIN_LOCAL_HOMOGRAPHY_GAP_PX)
                    }
                    None => f64::INFINITY,
                };
                (
                    if excess.is_nan() {
                        f64::INFINITY
                    } else {
                        excess
                    },
                    k,
                )
            })
            .max_by(|a, b| a.0.total_cmp(&b.0));
        match worst {
            Some((excess, k)) if excess > 1.0 => dropped.push(kept.remove(k).0),
            _ => break,
        }
    }
    dropped.sort_unstable();
    dropped
}

/// calib-targets' ChArUco tuning with its grid-smoothness pre-filter and its marker-homography
/// corner validation switched off (thresholds infinite). Both assume the board is a homography of
/// the image (no lens distortion, no refraction): the first predicts each grid corner as the
/// midpoint of its neighbours and moves it when it is more than 3 px off (0.05 × its nominal
/// 60 px square), the second fits one homography to the decoded markers' corners and moves or
/// drops each corner more than 4.8 px from it, re-detecting the strongest ChESS response near the
/// prediction. Through a flat port, with squares of 100–160 px, both fire on correct corners: in
/// view 18 (left) of the example rig's rendered calibration set the grid was exact (22 corners
/// within 0.03 px), the first moved corner 3 by 9 px in the marker sampling (4 markers decoded
/// instead of 6), the second's homography of those 4 markers (all on one side) missed the far
/// column by 29 px, dropped 6 correct corners and moved corner 6 by 31 px onto the white margin
/// beside a marker. [`inconsistent_charuco_corners`] checks corners by a local model instead
/// and drops, never moves.
fn charuco_tuning(
    mut tuning: calib_targets::charuco::CharucoAdvancedTuning,
) -> calib_targets::charuco::CharucoAdvancedTuning {
    tuning.grid_smoothness_threshold_rel = f32::INFINITY;
    tuning.corner_validation_threshold_rel = f32::INFINITY;
    tuning
}

/// Median distance (pixels) between ChArUco corners next to each other on the board (ids
/// `k`, `k + 1` in one row, `k`, `k + cols` in one column), or `None` without such a pair.
fn median_side_px(corners: &[(usize, Point2<f64>)], cols: usize) -> Option<f64> {
    let at = |id: usize| {
        corners
            .binary_search_by_key(&id, |&(k, _)| k)
            .ok()
            .map(|i| corners[i].1)
    };
    let mut sides: Vec<f64> = corners
        .iter()
        .flat_map(|&(id, p)| {
            let right = (id % cols + 1 < cols).then(|| at(id + 1)).flatten();
            let below = at(id + cols);
            [right, below]
                .into_iter()
                .flatten()
                .map(move |q| (q - p).norm())
        })
        .collect();
    if sides.is_empty() {
        return None;
    }
    sides.sort_by(f64::total_cmp);
    Some(sides[sides.len() / 2])
}

/// A rectangle of an image: x, y of its top-left pixel, width, height.
type Region = (u32, u32, u32, u32);

/// What one search of [`detect_charuco`] read: the decoded markers' count and the labelled
/// corners (id, pixel), by id.
type Reading = (usize, Vec<(usize, Point2<f64>)>);

/// The part of an image the upscaled passes of [`detect_charuco`] search, from the image after
/// the pre-blur (`smoothed`, [`PRE_BLUR_PX`]): the bounding box of its ChESS corners that have
/// two others within 1.8 times the corners' median nearest-neighbour distance (a board's
/// corners and its markers', not isolated specks), grown by 3 such distances and 16 px, within
/// the image; the whole image when fewer than 4 corners are so placed, or more than
/// [`REGION_MAX_CORNERS`] were found (a cluttered image, searched whole). On the zoo's rig of
/// seed 7 a board with a square's margin fills a fifth of its image, on the example rig's small
/// squares a fiftieth: the upscaled passes cost that much less.
fn board_region(smoothed: &GrayImage) -> Region {
    let whole = (0, 0, smoothed.width(), smoothed.height());
    let corners: Vec<(f64, f64)> = calib_targets::detect::detect_corners(smoothed, &chess_config())
        .iter()
        .map(|c| (f64::from(c.position.x), f64::from(c.position.y)))
        .collect();
    if corners.len() < 4 || corners.len() > REGION_MAX_CORNERS {
        return whole;
    }
    let distance = |a: (f64, f64), b: (f64, f64)| (a.0 - b.0).hypot(a.1 - b.1);
    let mut nearest: Vec<f64> = corners
        .iter()
        .enumerate()
        .map(|(i, &a)| {
            corners
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, &b)| distance(a, b))
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    nearest.sort_by(f64::total_cmp);
    let spacing = nearest[nearest.len() / 2];
    let clustered: Vec<(f64, f64)> = corners
        .iter()
        .filter(|&&a| {
            corners
                .iter()
                .filter(|&&b| b != a && distance(a, b) <= 1.8 * spacing)
                .count()
                >= 2
        })
        .copied()
        .collect();
    if clustered.len() < 4 {
        return whole;
    }
    let margin = 3.0 * spacing + 16.0;
    // The clustered corners' extent along one axis, grown by the margin, within 0..size.
    let span = |along: fn(&(f64, f64)) -> f64, size: u32| {
        let (low, high) = clustered
            .iter()
            .map(along)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(v), hi.max(v))
            });
        let start = (low - margin).max(0.0).floor() as u32;
        let end = (high + margin).min(f64::from(size)).ceil() as u32;
        (start, end)
    };
    let (x0, x1) = span(|c| c.0, smoothed.width());
    let (y0, y1) = span(|c| c.1, smoothed.height());
    if x1 <= x0 || y1 <= y0 {
        return whole;
    }
    (x0, y0, x1 - x0, y1 - y0)
}

/// Most ChESS corners [`board_region`] clusters (its pairwise distances grow as their square).
pub const REGION_MAX_CORNERS: usize = 4000;

/// `image` upscaled `k` times (Catmull-Rom) and blurred by `blur` of the upscaled image's pixels,
/// or `None` if it cannot be resized. The blur comes first, at `blur / k` of the image's own
/// pixels (blurring and interpolating commute, up to the interpolation's own slight smoothing),
/// on `k²` times fewer pixels. fast_image_resize does the upscaling: SIMD convolution, where
/// `image::imageops::resize` took 38 ms for a 640 × 480 image doubled (most of a pass).
fn upscaled(image: &GrayImage, k: u32, blur: f32) -> Option<GrayImage> {
    use fast_image_resize::{
        FilterType, PixelType, ResizeAlg, ResizeOptions, Resizer, images::Image,
    };
    let smoothed = calib_targets::detect::preprocess(image, blur / k as f32);
    let (width, height) = smoothed.dimensions();
    let source = Image::from_vec_u8(width, height, smoothed.into_raw(), PixelType::U8).ok()?;
    let mut target = Image::new(width * k, height * k, PixelType::U8);
    let options = ResizeOptions::new().resize_alg(ResizeAlg::Convolution(FilterType::CatmullRom));
    Resizer::new().resize(&source, &mut target, &options).ok()?;
    GrayImage::from_raw(width * k, height * k, target.into_vec())
}

/// The upscaled passes of [`detect_charuco`], in order, after its search of the image as it is:
/// (upscaling factor, blur in the upscaled image's pixels). They read small squares, where
/// ChESS's ring (radius 5 px) spans a whole square and a marker's cells are a pixel or two wide,
/// so that calib-targets finds the corners but decodes no marker, or misses the grid. No one
/// pass reads every small board (a light blur keeps the cells of clean images, a heavier one the
/// grid of noisy ones), so each factor is tried with both. The search stops at the first pass
/// that reads enough of the board ([`UPSCALE_BELOW_SIDE_PX`]), or no more of it than the best
/// pass before: on the zoo's 8-camera rig of seed 7 (192 images, 9 × 4 corners, squares 12–30
/// px) that keeps every board and 95 % of the corners of running every pass, in a quarter of the
/// time. Measured against OpenCV's CharucoDetector in docs/images.md, "Small squares".
pub const UPSCALED_PASSES: [(u32, f32); 5] = [
    (2, PRE_BLUR_PX),
    (2, 2.0 * PRE_BLUR_PX),
    (3, PRE_BLUR_PX),
    (3, 3.0 * PRE_BLUR_PX),
    (4, 1.5 * PRE_BLUR_PX),
];

/// Squares (median side, pixels) from which [`detect_charuco`] takes a pass's answer as it is;
/// under it, the next pass is tried too, unless three quarters of the markers were decoded.
pub const UPSCALE_BELOW_SIDE_PX: f64 = 30.0;

/// Fewest decoded markers a pass of [`detect_charuco`] is taken with: on a noisy image upscaled
/// four times, one misread marker labelled eight corners two to five squares off.
pub const MIN_CHARUCO_MARKERS: usize = 2;

/// Largest upscaled region (pixels) [`detect_charuco`] searches ([`board_region`] upscaled):
/// 640 × 480 upscaled four times, 1920 × 1080 twice. A board spread wider is searched at the
/// image's own scale only.
pub const UPSCALED_MAX_PIXELS: u64 = 9_000_000;

/// Fewest ChArUco corners [`detect_charuco`] returns, and they must span at least two rows and
/// two columns of the board: a view's board pose (6 unknowns) needs at least 4 points off one
/// line (a line of points leaves the rotation about it free), as OpenCV's
/// `estimatePoseCharucoBoard` needs 4.
pub const MIN_CHARUCO_CORNERS: usize = 4;

/// A ChArUco board's corners in a grey image: `(id, pixel)` sorted by id, id =
/// `row·(squares_x − 1) + col` as OpenCV numbers them (= the index of [`CharucoSpec::corner_grid`]),
/// sub-pixel. A board crossing the image edge or with markers hidden gives the corners found, with
/// their ids; fewer than [`MIN_CHARUCO_CORNERS`] (or all on one line of the board) is
/// [`Miss::Sparse`].
///
/// calib-targets finds the chessboard grid (ChESS corners, the saddle-point refiner after a blur
/// of [`PRE_BLUR_PX`], as for plain chessboards), decodes the markers in its cells and aligns the
/// grid to the board by them (its three chessboard parameter sets, the richest answer wins).
/// Its two stages that move corners by a global model are off (`charuco_tuning`); instead every
/// corner must agree with the local homography of its grid neighbours, else it is dropped
/// ([`inconsistent_charuco_corners`]). Where no pass gives a board (a steep slant, large squares
/// cut by the image's edge: corners the grid cannot join), the markers are found first and the
/// corners beside them refined on the image ([`markers`], OpenCV's route), then checked alike.
pub fn detect_charuco(
    image: &GrayImage,
    spec: &CharucoSpec,
) -> Result<Vec<(usize, Point2<f64>)>, Miss> {
    let grid = spec.corner_grid();
    let cols = grid.cols;
    let configs: Vec<_> =
        calib_targets::charuco::CharucoParams::sweep_for_board(&spec.to_calib_targets())
            .into_iter()
            .map(|mut params| {
                params.chess = chess_config();
                let tuning = charuco_tuning(params.effective_tuning().into_owned());
                params.with_advanced(tuning)
            })
            .collect();
    // One search of a prepared image: `image` at its own scale (k = 1) or a part of it, upscaled
    // k times, with its top-left pixel at `origin`; the corners in the image's own pixels
    // (x + (u + ½)/k − ½: pixel centres at integers, at either scale), with the decoded markers'
    // count.
    let search = |prepared: &GrayImage, k: u32, (x0, y0): (u32, u32)| -> Option<Reading> {
        let detection = calib_targets::detect::detect_charuco_best(prepared, &configs).ok()?;
        // One decoded marker is too little evidence for the board's labels: a misread one
        // places every corner squares off.
        if detection.markers.len() < MIN_CHARUCO_MARKERS {
            return None;
        }
        let k = f64::from(k);
        let mut corners: Vec<(usize, Point2<f64>)> = detection
            .corners
            .iter()
            .filter(|c| (c.id as usize) < grid.corners())
            .map(|c| {
                let at = |origin: u32, v: f32| f64::from(origin) + (f64::from(v) + 0.5) / k - 0.5;
                (
                    c.id as usize,
                    Point2::new(at(x0, c.position.x), at(y0, c.position.y)),
                )
            })
            .collect();
        corners.sort_by_key(|&(id, _)| id);
        // One pixel per id (calib-targets labels without duplicates; keep that true here).
        corners.dedup_by_key(|&mut (id, _)| id);
        Some((detection.markers.len(), corners))
    };
    // Enough of the board read: squares of UPSCALE_BELOW_SIDE_PX or more, or three quarters of
    // its markers decoded.
    let markers = spec.marker_count();
    let enough = |found: &Option<Reading>| {
        found.as_ref().is_some_and(|(decoded, corners)| {
            4 * decoded >= 3 * markers
                || median_side_px(corners, cols).is_some_and(|side| side >= UPSCALE_BELOW_SIDE_PX)
        })
    };
    let score = |found: &Option<(usize, Vec<_>)>| found.as_ref().map(|(m, c)| (*m, c.len()));
    // The image as it is, after the pre-blur: the first search, and where the upscaled passes'
    // region comes from.
    let own_scale = calib_targets::detect::preprocess(image, PRE_BLUR_PX);
    let mut best = search(&own_scale, 1, (0, 0));
    if !enough(&best) {
        let (x0, y0, width, height) = board_region(&own_scale);
        let part = if (width, height) == image.dimensions() {
            std::borrow::Cow::Borrowed(image)
        } else {
            std::borrow::Cow::Owned(
                image::imageops::crop_imm(image, x0, y0, width, height).to_image(),
            )
        };
        let pixels = u64::from(width) * u64::from(height);
        for &(k, blur) in &UPSCALED_PASSES {
            if pixels * u64::from(k * k) > UPSCALED_MAX_PIXELS {
                continue;
            }
            let found =
                upscaled(&part, k, blur).and_then(|prepared| search(&prepared, k, (x0, y0)));
            // A pass that reads no more of the board than the best so far: finer passes rarely do.
            if best.is_some() && score(&found) <= score(&best) {
                break;
            }
            if score(&found) > score(&best) {
                best = found;
            }
            if enough(&best) {
                break;
            }
        }
    }
    let from_grid = checked_charuco_corners(best.map(|(_, c)| c).unwrap_or_default(), cols);
    if from_grid.is_ok() {
        return from_grid;
    }
    // No board from the grid: the markers first (a steep slant, large squares cut by the edge).
    let found = markers::find_markers(&own_scale, spec);
    if found.len() < MIN_CHARUCO_MARKERS {
        return from_grid;
    }
    let corners = markers::corners_from_markers(image, &own_scale, spec, &found);
    match (checked_charuco_corners(corners, cols), from_grid) {
        (Ok(corners), _) => Ok(corners),
        // The grid's miss unless the markers read more of the board.
        (Err(Miss::Sparse { found }), Err(Miss::Sparse { found: before })) if found > before => {
            Err(Miss::Sparse { found })
        }
        (Err(Miss::Sparse { found }), Err(Miss::NoBoard)) => Err(Miss::Sparse { found }),
        (Err(_), from_grid) => from_grid,
    }
}

/// `corners` (by id) without those [`inconsistent_charuco_corners`] finds misplaced, or why
/// they are not a board: none ([`Miss::NoBoard`]), fewer than [`MIN_CHARUCO_CORNERS`] or all on
/// one row or column ([`Miss::Sparse`]).
fn checked_charuco_corners(
    mut corners: Vec<(usize, Point2<f64>)>,
    cols: usize,
) -> Result<Vec<(usize, Point2<f64>)>, Miss> {
    if corners.is_empty() {
        return Err(Miss::NoBoard);
    }
    let misplaced = inconsistent_charuco_corners(&corners, cols);
    corners.retain(|(id, _)| misplaced.binary_search(id).is_err());
    if corners.is_empty() {
        return Err(Miss::Sparse { found: 0 });
    }
    let (row0, col0) = (corners[0].0 / cols, corners[0].0 % cols);
    let two_rows = corners.iter().any(|&(id, _)| id / cols != row0);
    let two_cols = corners.iter().any(|&(id, _)| id % cols != col0);
    if corners.len() < MIN_CHARUCO_CORNERS || !two_rows || !two_cols {
        return Err(Miss::Sparse {
            found: corners.len(),
        });
    }
    Ok(corners)
}

/// The corners of a board of either kind in one image, as [`find_corners`] gives them.
#[derive(Debug, Clone, PartialEq)]
pub enum BoardCorners {
    /// A whole chessboard, its corner 0 still to be chosen ([`Found`], [`resolve_view`]).
    Chessboard(Detection),
    /// ChArUco corners with their ids ([`detect_charuco`]).
    Charuco(Vec<(usize, Point2<f64>)>),
}

/// Finds the board `spec` describes: [`detect_board`] for a chessboard (whole boards only),
/// [`detect_charuco`] for a ChArUco board.
pub fn find_corners(image: &GrayImage, spec: &BoardSpec) -> Result<BoardCorners, Miss> {
    match spec {
        BoardSpec::Chessboard(board) => detect_board(image, board).map(BoardCorners::Chessboard),
        BoardSpec::Charuco(charuco) => detect_charuco(image, charuco).map(BoardCorners::Charuco),
    }
}

/// Corners with ids → one entry per corner of a grid of `count`, `None` where the id is absent
/// (the observations file's per-corner `null`, docs/DESIGN.md §3b). Ids at or past `count` are
/// ignored.
pub fn corners_by_id(corners: &[(usize, Point2<f64>)], count: usize) -> Vec<Option<Point2<f64>>> {
    let mut all = vec![None; count];
    for &(id, p) in corners {
        if let Some(slot) = all.get_mut(id) {
            *slot = Some(p);
        }
    }
    all
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A patch of 12 px squares in one corner of a grey image with scattered specks: the
    /// region holds every inner corner of the patch with a margin and is a small part of the
    /// image; a blank image gives the whole image.
    #[test]
    fn the_region_is_where_the_corners_cluster() {
        let (x0, y0, side, n) = (420u32, 300u32, 12u32, 8u32);
        let mut image = GrayImage::from_pixel(640, 480, image::Luma([128]));
        for y in y0..y0 + n * side {
            for x in x0..x0 + n * side {
                let dark = ((x - x0) / side + (y - y0) / side) % 2 == 0;
                image.put_pixel(x, y, image::Luma([if dark { 30 } else { 225 }]));
            }
        }
        // Specks: isolated dark dots far from the patch.
        for (sx, sy) in [(40u32, 40u32), (200, 90), (90, 300), (300, 420), (600, 60)] {
            for dy in 0..3 {
                for dx in 0..3 {
                    image.put_pixel(sx + dx, sy + dy, image::Luma([20]));
                }
            }
        }
        let (rx, ry, rw, rh) =
            board_region(&calib_targets::detect::preprocess(&image, PRE_BLUR_PX));
        let inner = (
            x0 + side,
            y0 + side,
            x0 + (n - 1) * side,
            y0 + (n - 1) * side,
        );
        assert!(
            rx + side <= inner.0
                && ry + side <= inner.1
                && rx + rw >= inner.2 + side
                && ry + rh >= inner.3 + side,
            "region {:?} does not hold the patch's inner corners {inner:?} with a square's margin",
            (rx, ry, rw, rh)
        );
        assert!(
            u64::from(rw) * u64::from(rh) * 4 < 640 * 480,
            "region {:?} is over a quarter of the image",
            (rx, ry, rw, rh)
        );
        let blank = GrayImage::from_pixel(320, 240, image::Luma([128]));
        assert_eq!(
            board_region(&calib_targets::detect::preprocess(&blank, PRE_BLUR_PX)),
            (0, 0, 320, 240)
        );
    }

    #[test]
    fn the_colour_decides_on_boards_with_an_odd_number_of_squares() {
        assert!(colour_decides(&Board {
            rows: 6,
            cols: 9,
            square: 0.04
        }));
        assert!(!colour_decides(&Board {
            rows: 6,
            cols: 8,
            square: 0.04
        }));
        assert!(!colour_decides(&Board {
            rows: 7,
            cols: 9,
            square: 0.04
        }));
    }

    #[test]
    fn the_image_rule_picks_rows_running_right_and_refuses_near_vertical_rows() {
        let board = Board {
            rows: 2,
            cols: 2,
            square: 1.0,
        };
        let p = |x: f64, y: f64| Point2::new(x, y);
        let right = vec![p(0.0, 0.0), p(10.0, 1.0), p(0.0, 10.0), p(10.0, 11.0)];
        let left: Vec<_> = right.iter().rev().copied().collect();
        assert_eq!(
            image_rule(&board, &[right.clone(), left.clone()], &[0, 1]),
            Some(0)
        );
        assert_eq!(image_rule(&board, &[left, right], &[0, 1]), Some(1));
        let down = vec![p(0.0, 0.0), p(1.0, 10.0), p(-10.0, 0.0), p(-9.0, 10.0)];
        let up: Vec<_> = down.iter().rev().copied().collect();
        assert_eq!(image_rule(&board, &[down, up], &[0, 1]), None);
    }
    /// Corners of a 6 × 4 corner grid seen in perspective (an exact homography, squares of
    /// 20–40 px), ids row-major.
    fn perspective_grid() -> Vec<(usize, Point2<f64>)> {
        (0..24)
            .map(|id| {
                let (c, r) = ((id % 6) as f64, (id / 6) as f64);
                let w = 1.0 + 0.05 * c + 0.03 * r;
                (
                    id,
                    Point2::new(
                        (100.0 + 38.0 * c + 4.0 * r) / w,
                        (80.0 + 3.0 * c + 35.0 * r) / w,
                    ),
                )
            })
            .collect()
    }

    #[test]
    fn the_local_homography_guard_drops_a_corner_moved_by_5_px_and_only_it() {
        let grid = perspective_grid();
        assert_eq!(inconsistent_charuco_corners(&grid, 6), Vec::<usize>::new());
        // Every corner sits on the homography: gaps at rounding level.
        for k in 0..grid.len() {
            let (gap, side) = local_homography_gap(&grid, 6, k).unwrap();
            assert!(
                gap < 1e-6 && side > 15.0 && side < 45.0,
                "{k}: {gap} {side}"
            );
        }
        for moved in [0, 8, 23] {
            let mut corners = grid.clone();
            corners[moved].1 += nalgebra::Vector2::new(3.0, 4.0); // 5 px
            assert_eq!(inconsistent_charuco_corners(&corners, 6), vec![moved]);
        }
        // 1 px on squares of ~35 px is within the threshold (noise, refraction), and stays.
        let mut corners = grid.clone();
        corners[8].1.x += 1.0;
        assert_eq!(
            inconsistent_charuco_corners(&corners, 6),
            Vec::<usize>::new()
        );
    }

    #[test]
    fn corners_whose_neighbours_fix_no_homography_are_dropped() {
        let grid = perspective_grid();
        // A 2 × 2 block: each corner has 3 neighbours.
        let block: Vec<_> = [0, 1, 6, 7].iter().map(|&k| grid[k]).collect();
        assert_eq!(inconsistent_charuco_corners(&block, 6), vec![0, 1, 6, 7]);
        // One row and one more corner: no 4 of any corner's neighbours are free of 3 on a line.
        let row: Vec<_> = [0, 1, 2, 3, 4, 9].iter().map(|&k| grid[k]).collect();
        assert_eq!(inconsistent_charuco_corners(&row, 6).len(), 6);
    }
}
