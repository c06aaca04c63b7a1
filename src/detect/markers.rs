//! A ChArUco board found from its markers first, the way OpenCV's CharucoDetector finds it: the
//! second route of [`super::detect_charuco`], for the images where calib-targets' chessboard grid
//! finds no board. That grid is built from ChESS corners and their axes; a board seen at a steep
//! slant (its square's corners at 40° in the image), or large squares behind a wide lens cut by
//! the image's edge, give it corners it cannot join (zoo seeds 70 and 4: OpenCV found 3 and 3
//! boards more, docs/images.md). A marker is a dark quadrilateral whatever the slant:
//!
//! 1. **Outlines** ([`marker_quads`]): the image thresholded against its local mean
//!    ([`THRESHOLD_RADII_PX`]), the outer borders of the dark regions (imageproc: Suzuki–Abe
//!    contours, Douglas–Peucker to four vertices), convex, each side at least
//!    [`MIN_MARKER_SIDE_CELLS`] pixels per cell, clear of the image's edge; each side a line
//!    fitted to its border pixels, the corners where the lines meet.
//! 2. **Codes** ([`decode`]): each cell of the marker (border and bits) read as the mean of 9
//!    samples over its middle, dark or light by the midpoint of the cells' two groups (Otsu);
//!    a border all dark, the bits matched against the board's dictionary in the four turns of
//!    the outline (at most the dictionary's correctable bits wrong); a marker id the board does
//!    not hold, or one id read at two places, is dropped.
//! 3. **Corners** ([`corners_from_markers`]): each inner corner beside a decoded marker
//!    predicted by the homography of the one or two markers whose squares touch it, then
//!    refined on the image by [`fill::refine_corner_in`] with the markers' pixels left out (the
//!    fit models four plain squares) and a move of up to [`MAX_SHIFT_REL`] of a side; a corner
//!    the image does not place (no saddle, a weak window) is left out.
//!
//! [`super::detect_charuco`] then checks these corners as it checks the grid's
//! ([`super::inconsistent_charuco_corners`]). Written here rather than taken from a crate:
//! calib-targets decodes markers only in the cells of its chessboard grid (the grid is what
//! fails), and the Rust ArUco crates read their own dictionaries, not OpenCV's.

use std::collections::HashMap;

use calib_targets::aruco::Matcher;
use image::GrayImage;
use imageproc::contours::{BorderType, find_contours};
use imageproc::contrast::adaptive_threshold;
use imageproc::geometry::approximate_polygon_dp;
use nalgebra::{Point2, Vector2};

use super::fill::{self, Pattern, Window};
use super::{MIN_CONTRAST, apply, bilinear, fit_homography};
use crate::base::CharucoSpec;

/// Half-sizes (pixels) of the neighbourhoods whose mean each pixel is thresholded against, one
/// pass each: a marker's border must come out dark and joined, which takes a neighbourhood about
/// as large as a cell (OpenCV's detector tries windows of 3, 13 and 23 px).
pub const THRESHOLD_RADII_PX: [u32; 3] = [3, 8, 16];

/// How much darker than its neighbourhood's mean (grey levels) a pixel must be to count as dark:
/// OpenCV's `adaptiveThreshConstant`.
pub const THRESHOLD_DELTA: i32 = 7;

/// Fewest pixels per cell (border included) along a marker's shortest side: under it the cells'
/// middles are a pixel wide and the code is not read.
pub const MIN_MARKER_SIDE_CELLS: f64 = 1.6;

/// Farthest a corner may move from the markers' prediction in its refinement, as a fraction of
/// the shorter side of its square in the image (and at least 1 px): the outlines are fitted to
/// border pixels, half a pixel inside the edge, so the prediction misses by a pixel or so.
pub const MAX_SHIFT_REL: f64 = 0.15;

/// A decoded marker: its id and the image pixels of its four corners in the order the board
/// prints them (top-left, top-right, bottom-right, bottom-left of the marker as drawn, x right
/// and y down on the board).
#[derive(Debug, Clone, PartialEq)]
pub struct Marker {
    /// The marker's id in the board's dictionary.
    pub id: usize,
    /// Its corners, top-left first, clockwise as the board is drawn.
    pub corners: [Point2<f64>; 4],
}

/// The board's decoded markers in `smoothed` (the image after [`super::PRE_BLUR_PX`]).
pub fn find_markers(smoothed: &GrayImage, spec: &CharucoSpec) -> Vec<Marker> {
    let matcher = Matcher::new(spec.dictionary, spec.dictionary.max_correction_bits());
    let cells = spec.marker_bits() + 2;
    // Every reading of each id, with its bits read wrong.
    let mut readings: HashMap<usize, Vec<(u32, Marker)>> = HashMap::new();
    for quad in marker_quads(smoothed, cells) {
        if let Some((hamming, marker)) = decode(smoothed, &quad, spec, &matcher) {
            readings
                .entry(marker.id)
                .or_default()
                .push((hamming, marker));
        }
    }
    // The thresholds find one outline within a pixel or two; an id read at two places (half a
    // marker apart) is a misread and is dropped.
    let mut markers: Vec<Marker> = readings
        .into_values()
        .filter_map(|mut found| {
            let first = centre(&found[0].1.corners);
            let tolerance = 0.5 * side(&found[0].1.corners);
            if found
                .iter()
                .any(|(_, m)| (centre(&m.corners) - first).norm() > tolerance)
            {
                return None;
            }
            found.sort_by_key(|&(hamming, _)| hamming);
            Some(found.swap_remove(0).1)
        })
        .collect();
    markers.sort_by_key(|m| m.id);
    markers
}

fn centre(corners: &[Point2<f64>; 4]) -> Point2<f64> {
    Point2::from(corners.iter().map(|p| p.coords).sum::<Vector2<f64>>() / 4.0)
}

/// The shortest side of a quadrilateral, pixels.
fn side(corners: &[Point2<f64>; 4]) -> f64 {
    (0..4)
        .map(|k| (corners[(k + 1) % 4] - corners[k]).norm())
        .fold(f64::INFINITY, f64::min)
}

/// Dark convex quadrilaterals that may be markers of `cells` cells a side, their corners
/// sub-pixel, clockwise in the image (x right, y down); every threshold pass's.
pub fn marker_quads(smoothed: &GrayImage, cells: usize) -> Vec<[Point2<f64>; 4]> {
    let (width, height) = (f64::from(smoothed.width()), f64::from(smoothed.height()));
    let min_side = MIN_MARKER_SIDE_CELLS * cells as f64;
    let mut quads = Vec::new();
    for radius in THRESHOLD_RADII_PX {
        // adaptive_threshold makes a pixel white unless it is darker than its mean by delta; the
        // contours follow the non-zero pixels, so the dark ones are made non-zero.
        let mut dark = adaptive_threshold(smoothed, radius, THRESHOLD_DELTA);
        for p in dark.iter_mut() {
            *p = 255 - *p;
        }
        for contour in find_contours::<i32>(&dark) {
            if contour.border_type != BorderType::Outer || contour.points.len() < 4 * cells {
                continue;
            }
            let points: Vec<Point2<f64>> = contour
                .points
                .iter()
                .map(|p| Point2::new(f64::from(p.x), f64::from(p.y)))
                .collect();
            let perimeter = points.len() as f64;
            let polygon = approximate_polygon_dp(&contour.points, 0.04 * perimeter, true);
            if polygon.len() != 4 {
                continue;
            }
            let vertices: Vec<usize> = polygon
                .iter()
                .filter_map(|v| contour.points.iter().position(|p| p == v))
                .collect();
            if vertices.len() != 4 {
                continue;
            }
            let Some(mut quad) = refined_quad(&points, &vertices) else {
                continue;
            };
            let inside = quad
                .iter()
                .all(|p| p.x >= 2.0 && p.y >= 2.0 && p.x <= width - 3.0 && p.y <= height - 3.0);
            if !inside || side(&quad) < min_side || !convex(&quad) {
                continue;
            }
            // Clockwise in the image: (q1 − q0) × (q3 − q0) > 0 with y down.
            if (quad[1] - quad[0]).perp(&(quad[3] - quad[0])) < 0.0 {
                quad.swap(1, 3);
            }
            quads.push(quad);
        }
    }
    quads
}

/// True when the quadrilateral turns the same way at each corner.
fn convex(quad: &[Point2<f64>; 4]) -> bool {
    let turns: Vec<f64> = (0..4)
        .map(|k| {
            let (a, b) = (quad[k], quad[(k + 1) % 4]);
            (b - a).perp(&(quad[(k + 2) % 4] - b))
        })
        .collect();
    turns.iter().all(|&t| t > 0.0) || turns.iter().all(|&t| t < 0.0)
}

/// The four corners of a contour whose vertices are at `vertices` (indices into `points`, in
/// the contour's order): a line fitted to the middle 70 % of each side's border pixels, the
/// corners where neighbouring lines meet; `None` for a side too short to fit or parallel lines.
fn refined_quad(points: &[Point2<f64>], vertices: &[usize]) -> Option<[Point2<f64>; 4]> {
    let mut order = vertices.to_vec();
    order.sort_unstable();
    let n = points.len();
    // Each side: a point on it and its direction.
    let mut lines = Vec::with_capacity(4);
    for k in 0..4 {
        let (start, end) = (order[k], order[(k + 1) % 4]);
        let length = (end + n - start) % n;
        let skip = (length as f64 * 0.15).ceil() as usize;
        if length < 2 * skip + 3 {
            return None;
        }
        let side: Vec<Point2<f64>> = (skip..=length - skip)
            .map(|t| points[(start + t) % n])
            .collect();
        let mean = side.iter().map(|p| p.coords).sum::<Vector2<f64>>() / side.len() as f64;
        let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
        for p in &side {
            let d = p.coords - mean;
            sxx += d.x * d.x;
            sxy += d.x * d.y;
            syy += d.y * d.y;
        }
        // The principal direction of the scatter.
        let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
        lines.push((Point2::from(mean), Vector2::new(angle.cos(), angle.sin())));
    }
    let meet = |(p, u): (Point2<f64>, Vector2<f64>), (q, v): (Point2<f64>, Vector2<f64>)| {
        let det = u.perp(&v);
        if det.abs() < 1e-3 {
            return None;
        }
        let t = (q - p).perp(&v) / det;
        Some(p + u * t)
    };
    let mut quad = [Point2::origin(); 4];
    for k in 0..4 {
        // Corner k+1 (of the sorted vertices) is where side k meets side k+1.
        quad[(k + 1) % 4] = meet(lines[k], lines[(k + 1) % 4])?;
    }
    // A corner far from its contour vertex: the lines do not describe the outline.
    for k in 0..4 {
        if (quad[k] - points[order[k]]).norm() > 3.0 + 0.1 * side(&quad) {
            return None;
        }
    }
    Some(quad)
}

/// The marker in `quad` (clockwise in the image): its id and its corners in the board's order,
/// with the number of its bits read wrong; `None` when the border is not dark all round, the
/// cells show too little contrast, or no turn of the code is one of the board's markers.
fn decode(
    smoothed: &GrayImage,
    quad: &[Point2<f64>; 4],
    spec: &CharucoSpec,
    matcher: &Matcher,
) -> Option<(u32, Marker)> {
    let bits = spec.marker_bits();
    let cells = bits + 2;
    let n = cells as f64;
    let square = [
        Point2::new(0.0, 0.0),
        Point2::new(n, 0.0),
        Point2::new(n, n),
        Point2::new(0.0, n),
    ];
    let pairs: Vec<_> = square.iter().copied().zip(quad.iter().copied()).collect();
    let h = fit_homography(&pairs)?;
    // Mean grey of each cell, row-major (cy across rows from the quad's first corner).
    let mut means = Vec::with_capacity(cells * cells);
    for cy in 0..cells {
        for cx in 0..cells {
            let mut sum = 0.0;
            for a in 0..3 {
                for b in 0..3 {
                    let at = Point2::new(
                        cx as f64 + 0.3 + 0.2 * f64::from(a),
                        cy as f64 + 0.3 + 0.2 * f64::from(b),
                    );
                    let p = apply(&h, at)?;
                    sum += bilinear(smoothed, p.x, p.y)?;
                }
            }
            means.push(sum / 9.0);
        }
    }
    let threshold = otsu(&means)?;
    let dark = |cx: usize, cy: usize| means[cy * cells + cx] < threshold;
    let border =
        (0..cells).all(|k| dark(k, 0) && dark(k, cells - 1) && dark(0, k) && dark(cells - 1, k));
    if !border {
        return None;
    }
    // The code with the quad's corner `turn` as the marker's top-left: cell (cx, cy) of the
    // marker as drawn is cell turn⁻¹(cx, cy) of the quad's grid.
    let code = |turn: usize| -> u64 {
        let mut code = 0u64;
        for y in 0..bits {
            for x in 0..bits {
                let (cx, cy) = (x + 1, y + 1);
                let (qx, qy) = match turn {
                    0 => (cx, cy),
                    1 => (cells - 1 - cy, cx),
                    2 => (cells - 1 - cx, cells - 1 - cy),
                    _ => (cy, cells - 1 - cx),
                };
                if dark(qx, qy) {
                    code |= 1 << (y * bits + x);
                }
            }
        }
        code
    };
    let found = matcher.match_code(code(0))?;
    let id = found.id as usize;
    if id >= spec.marker_count() {
        return None;
    }
    let expected = *spec.dictionary.codes().get(id)?;
    // The turn whose code is the dictionary's (fewest bits wrong).
    let (turn, hamming) = (0..4)
        .map(|turn| (turn, (code(turn) ^ expected).count_ones()))
        .min_by_key(|&(_, wrong)| wrong)?;
    if hamming > u32::from(spec.dictionary.max_correction_bits()) {
        return None;
    }
    let corners = std::array::from_fn(|k| quad[(k + turn) % 4]);
    Some((hamming, Marker { id, corners }))
}

/// Otsu's threshold between two groups of values, `None` when the groups' means differ by less
/// than [`MIN_CONTRAST`].
fn otsu(values: &[f64]) -> Option<f64> {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let total: f64 = sorted.iter().sum();
    let n = sorted.len() as f64;
    let (mut best, mut split) = (f64::NEG_INFINITY, None);
    let mut low_sum = 0.0;
    for k in 1..sorted.len() {
        low_sum += sorted[k - 1];
        let (a, b) = (k as f64, n - k as f64);
        let (low, high) = (low_sum / a, (total - low_sum) / b);
        let between = a * b * (high - low).powi(2);
        if between > best {
            best = between;
            split = Some((low, high, 0.5 * (sorted[k - 1] + sorted[k])));
        }
    }
    let (low, high, threshold) = split?;
    (high - low >= MIN_CONTRAST).then_some(threshold)
}

/// The board's inner corners (`(id, pixel)`, by id) beside the `markers`, refined on the image:
/// `raw` as read, `smoothed` after the pre-blur.
pub fn corners_from_markers(
    raw: &GrayImage,
    smoothed: &GrayImage,
    spec: &CharucoSpec,
    markers: &[Marker],
) -> Vec<(usize, Point2<f64>)> {
    let grid = spec.corner_grid();
    let margin = 0.5 * (1.0 - spec.marker_size_m / spec.square_size_m);
    // The marker in square (a, b): its index in `markers`.
    let mut at_square = HashMap::new();
    for a in 0..spec.squares_x {
        for b in 0..spec.squares_y {
            if let Some(id) = spec.marker_at_square(a, b)
                && let Some(k) = markers.iter().position(|m| m.id == id)
            {
                at_square.insert((a, b), k);
            }
        }
    }
    // Board points (in squares, x right, y down) of a marker's corners, by square.
    let marker_points = |(a, b): (usize, usize)| -> [Point2<f64>; 4] {
        let (x0, y0) = (a as f64 + margin, b as f64 + margin);
        let (x1, y1) = (a as f64 + 1.0 - margin, b as f64 + 1.0 - margin);
        [
            Point2::new(x0, y0),
            Point2::new(x1, y0),
            Point2::new(x1, y1),
            Point2::new(x0, y1),
        ]
    };
    let mut corners = Vec::new();
    for id in 0..grid.corners() {
        let (row, col) = (id / grid.cols, id % grid.cols);
        // The squares touching corner (col + 1, row + 1) that hold a decoded marker.
        let touching: Vec<(usize, usize)> = [
            (col, row),
            (col + 1, row),
            (col, row + 1),
            (col + 1, row + 1),
        ]
        .into_iter()
        .filter(|square| at_square.contains_key(square))
        .collect();
        if touching.is_empty() {
            continue;
        }
        let pairs: Vec<(Point2<f64>, Point2<f64>)> = touching
            .iter()
            .flat_map(|&square| {
                let marker = &markers[at_square[&square]];
                marker_points(square).into_iter().zip(marker.corners)
            })
            .collect();
        let Some(h) = fit_homography(&pairs) else {
            continue;
        };
        let board = Point2::new(col as f64 + 1.0, row as f64 + 1.0);
        let step =
            |d: Vector2<f64>| Some(apply(&h, board + d * 0.5)? - apply(&h, board - d * 0.5)?);
        let (Some(predicted), Some(along_i), Some(along_j)) =
            (apply(&h, board), step(Vector2::x()), step(Vector2::y()))
        else {
            continue;
        };
        // The light squares (with markers) at +i+j and −i−j, or at the other diagonal.
        let light = if spec.marker_at_square(col + 1, row + 1).is_some() {
            1.0
        } else {
            -1.0
        };
        let Some(pattern) = charuco_pattern(smoothed, predicted, along_i, along_j, light, margin)
        else {
            continue;
        };
        let side = along_i.norm().min(along_j.norm());
        let rules = Window {
            max_shift_px: (MAX_SHIFT_REL * side).max(1.0),
            marker_margin: Some(margin),
        };
        if let Ok(p) =
            fill::refine_corner_in(raw, smoothed, predicted, along_i, along_j, pattern, &rules)
        {
            corners.push((id, p));
        }
    }
    corners
}

/// The squares around a ChArUco corner: `light` as the board says, the contrast between the
/// white margins next to the corner (half the margin out along the light diagonal) and the
/// middles of the two black squares; `None` below [`MIN_CONTRAST`] or off the image.
fn charuco_pattern(
    smoothed: &GrayImage,
    corner: Point2<f64>,
    along_i: Vector2<f64>,
    along_j: Vector2<f64>,
    light: f64,
    margin: f64,
) -> Option<Pattern> {
    let grey = |u: f64, v: f64| {
        let p = corner + along_i * u + along_j * v;
        bilinear(smoothed, p.x, p.y)
    };
    let m = 0.5 * margin;
    let whites = [grey(m, light * m)?, grey(-m, -light * m)?];
    let blacks = [grey(0.5, -light * 0.5)?, grey(-0.5, light * 0.5)?];
    let contrast = whites[0].min(whites[1]) - blacks[0].max(blacks[1]);
    (contrast >= MIN_CONTRAST).then_some(Pattern { light, contrast })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A marker of `spec` drawn turned by `angle` about the image's centre (4 × 4 samples a
    /// pixel), `cell` pixels a cell, on a light square twice its size; with its top-left corner's
    /// pixel.
    fn drawn(spec: &CharucoSpec, id: usize, angle: f64, cell: f64) -> (GrayImage, Point2<f64>) {
        let cells = (spec.marker_bits() + 2) as f64;
        let half = 0.5 * cells * cell;
        let (size, centre) = (240u32, Point2::new(119.5, 119.5));
        let (c, s) = (angle.cos(), angle.sin());
        let grey = |p: Point2<f64>| -> f64 {
            let d = p - centre;
            // Marker coordinates (pixels from its top-left, x along its top edge).
            let (x, y) = (c * d.x + s * d.y + half, -s * d.x + c * d.y + half);
            if x.abs().max(y.abs()) > 2.0 * half + half {
                return 100.0; // the background beyond the light square
            }
            if x < 0.0 || y < 0.0 || x >= 2.0 * half || y >= 2.0 * half {
                return 220.0;
            }
            let (cx, cy) = ((x / cell) as usize, (y / cell) as usize);
            if spec.marker_cell_is_black(id, cx, cy) {
                30.0
            } else {
                220.0
            }
        };
        let image = GrayImage::from_fn(size, size, |px, py| {
            let mut sum = 0.0;
            for a in 0..4 {
                for b in 0..4 {
                    let p = Point2::new(
                        f64::from(px) - 0.375 + 0.25 * f64::from(a),
                        f64::from(py) - 0.375 + 0.25 * f64::from(b),
                    );
                    sum += grey(p);
                }
            }
            image::Luma([(sum / 16.0).round() as u8])
        });
        let top_left = centre + Vector2::new(c * -half - s * -half, s * -half + c * -half);
        (image, top_left)
    }

    #[test]
    fn a_marker_turned_any_way_is_read_with_its_corners_in_the_boards_order() {
        let spec = CharucoSpec::new(5, 5, 0.04, 0.03, "DICT_4X4_50", false).unwrap();
        for turn in 0..4 {
            let angle = 0.3 + f64::from(turn) * std::f64::consts::FRAC_PI_2;
            let (image, top_left) = drawn(&spec, 7, angle, 10.0);
            let smoothed = calib_targets::detect::preprocess(&image, super::super::PRE_BLUR_PX);
            let markers = find_markers(&smoothed, &spec);
            assert_eq!(markers.len(), 1, "turn {turn}: {markers:?}");
            assert_eq!(markers[0].id, 7, "turn {turn}");
            let miss = (markers[0].corners[0] - top_left).norm();
            assert!(
                miss < 1.0,
                "turn {turn}: top-left {} px from {top_left}",
                miss
            );
        }
    }

    #[test]
    fn otsu_splits_two_groups_and_refuses_one() {
        let two = [30.0, 32.0, 35.0, 200.0, 210.0, 190.0];
        let t = otsu(&two).unwrap();
        assert!(t > 35.0 && t < 190.0, "{t}");
        assert_eq!(otsu(&[100.0, 104.0, 101.0, 108.0]), None);
    }
}
