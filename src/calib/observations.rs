//! Stereo observations of a planar board: for each view, the corners found in both images.

use nalgebra::{Matrix2, Point2, Vector2};

use super::board::Board;
use super::error::{CalibError, Side};
use crate::model::PinholeCamera;

/// One stereo view: corner `i` (row-major) in the left and the right image, raw (distorted)
/// pixels; `None` where the corner was not detected (in both images).
#[derive(Debug, Clone, PartialEq)]
pub struct StereoView {
    /// Corners in the left (first) camera's image.
    pub left: Vec<Option<Point2<f64>>>,
    /// Corners in the right (second) camera's image.
    pub right: Vec<Option<Point2<f64>>>,
}

impl StereoView {
    /// Indices of the corners seen in both images.
    pub fn matched(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.left.len()).filter(|&i| self.left[i].is_some() && self.right.get(i).is_some_and(|c| c.is_some()))
    }

    /// The corners of one image.
    pub fn side(&self, side: Side) -> &[Option<Point2<f64>>] {
        match side {
            Side::Left => &self.left,
            Side::Right => &self.right,
        }
    }
}

/// Stereo views of one board, as in the observations file.
#[derive(Debug, Clone, PartialEq)]
pub struct Observations {
    /// The board.
    pub board: Board,
    /// The views, in file order.
    pub views: Vec<StereoView>,
    /// Names of the rig cameras that took the left and right images (default: the first two).
    pub cameras: Option<[String; 2]>,
}

/// Fewest corners seen in both images for a view to take part.
pub const MIN_VIEW_CORNERS: usize = 6;

/// Smallest ratio of the singular values of the board-to-image affine map (normalised by the
/// board's own aspect) below which a view is refused as edge-on: the corners lie on a line.
pub const EDGE_ON_RATIO: f64 = 0.02;

/// Ratio below which an oblique view is reported (about 80° between the board and the image).
pub const OBLIQUE_RATIO: f64 = 0.17;

impl Observations {
    /// Checks the observations against the board and the two cameras' images: the corner counts,
    /// nulls in both images or neither, finite corners inside the images, at least
    /// [`MIN_VIEW_CORNERS`] matched corners per view that span the board (not edge-on).
    ///
    /// Returns the warnings for views that can be used but are weak (oblique views).
    pub fn validate(&self, left: &PinholeCamera, right: &PinholeCamera) -> Result<Vec<String>, CalibError> {
        let board = &self.board;
        if board.rows < 2 || board.cols < 2 {
            return Err(CalibError::BadBoard {
                reason: format!("needs at least 2 × 2 inner corners, got rows {} × cols {}", board.rows, board.cols),
            });
        }
        if !(board.square > 0.0 && board.square.is_finite()) {
            return Err(CalibError::BadBoard { reason: format!("square must be a positive length in metres, got {}", board.square) });
        }
        if self.views.is_empty() {
            return Err(CalibError::NoViews);
        }
        let expected = board.corners();
        let mut warnings = Vec::new();
        for (v, view) in self.views.iter().enumerate() {
            for (side, corners, camera) in [(Side::Left, &view.left, left), (Side::Right, &view.right, right)] {
                if corners.len() != expected {
                    return Err(CalibError::CornerCount { view: v, side, got: corners.len(), expected });
                }
                for (i, corner) in corners.iter().enumerate() {
                    let Some(p) = corner else { continue };
                    if !(p.x.is_finite() && p.y.is_finite()) {
                        return Err(CalibError::CornerNotFinite { view: v, side, corner: i, u: p.x, v: p.y });
                    }
                    // Pixel centres run from 0 to size − 1; a corner may lie up to half a pixel beyond.
                    let inside = (-0.5..=camera.width as f64 - 0.5).contains(&p.x)
                        && (-0.5..=camera.height as f64 - 0.5).contains(&p.y);
                    if !inside {
                        return Err(CalibError::CornerOutsideImage {
                            view: v,
                            side,
                            corner: i,
                            u: p.x,
                            v: p.y,
                            width: camera.width,
                            height: camera.height,
                        });
                    }
                }
            }
            for i in 0..expected {
                match (view.left[i], view.right[i]) {
                    (Some(_), None) => return Err(CalibError::CornerInOneImage { view: v, corner: i, missing: Side::Right }),
                    (None, Some(_)) => return Err(CalibError::CornerInOneImage { view: v, corner: i, missing: Side::Left }),
                    _ => {}
                }
            }
            let matched = view.matched().count();
            if matched < MIN_VIEW_CORNERS {
                return Err(CalibError::UnusableView {
                    view: v,
                    reason: format!("{matched} corners seen in both images; a view needs at least {MIN_VIEW_CORNERS}"),
                });
            }
            let mut worst = f64::INFINITY;
            for side in [Side::Left, Side::Right] {
                let ratio = spread_ratio(board, view.side(side)).ok_or_else(|| CalibError::UnusableView {
                    view: v,
                    reason: format!("the {} corners do not span the board (all on one row or column)", side.name()),
                })?;
                worst = worst.min(ratio);
            }
            if worst < EDGE_ON_RATIO {
                return Err(CalibError::UnusableView {
                    view: v,
                    reason: format!(
                        "the board is seen edge-on: its corners lie on a line in the image (spread ratio {worst:.3} < {EDGE_ON_RATIO})"
                    ),
                });
            }
            if worst < OBLIQUE_RATIO {
                warnings.push(format!(
                    "view {v}: the board is seen very obliquely (spread ratio {worst:.3}): its corners constrain the axis poorly"
                ));
            }
        }
        Ok(warnings)
    }

    /// Number of corners seen in both images, over all views.
    pub fn matched_corners(&self) -> usize {
        self.views.iter().map(|v| v.matched().count()).sum()
    }
}

/// Ratio of the smaller to the larger singular value of the affine map from the board grid
/// (in squares) to the image, fitted by least squares to the corners present: 1 for a board seen
/// face-on with square pixels, → 0 as the board turns edge-on. `None` when the corners present
/// do not span two grid directions.
fn spread_ratio(board: &Board, corners: &[Option<Point2<f64>>]) -> Option<f64> {
    let present: Vec<(Vector2<f64>, Vector2<f64>)> = corners
        .iter()
        .enumerate()
        .filter_map(|(i, c)| {
            let (r, col) = board.grid_position(i);
            c.map(|p| (Vector2::new(col as f64, r as f64), p.coords))
        })
        .collect();
    let n = present.len() as f64;
    let mean_g = present.iter().fold(Vector2::zeros(), |a, (g, _)| a + g) / n;
    let mean_p = present.iter().fold(Vector2::zeros(), |a, (_, p)| a + p) / n;
    let (mut gg, mut pg) = (Matrix2::zeros(), Matrix2::zeros());
    for (g, p) in &present {
        let (dg, dp) = (g - mean_g, p - mean_p);
        gg += dg * dg.transpose();
        pg += dp * dg.transpose();
    }
    // A = PG · GG⁻¹ maps grid steps to pixels.
    if !(gg.determinant() > 1e-9 * gg.norm_squared()) {
        return None;
    }
    let a = pg * gg.try_inverse()?;
    let s = a.singular_values();
    let (large, small) = (s.max(), s.min());
    if !(large > 0.0) {
        return None;
    }
    Some(small / large)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> PinholeCamera {
        PinholeCamera::new("c", 640, 480, 500.0, 500.0, 320.0, 240.0, [0.0; 5]).unwrap()
    }

    fn grid(board: &Board, shear: f64) -> Vec<Option<Point2<f64>>> {
        (0..board.corners())
            .map(|i| {
                let (r, c) = board.grid_position(i);
                Some(Point2::new(100.0 + 20.0 * c as f64, 100.0 + shear * 20.0 * r as f64 + 2.0 * c as f64))
            })
            .collect()
    }

    fn observations(views: Vec<StereoView>) -> Observations {
        Observations { board: Board { rows: 4, cols: 5, square: 0.04 }, views, cameras: None }
    }

    #[test]
    fn good_views_pass_and_bad_ones_are_named() {
        let board = Board { rows: 4, cols: 5, square: 0.04 };
        let good = StereoView { left: grid(&board, 1.0), right: grid(&board, 1.0) };
        assert_eq!(observations(vec![good.clone()]).validate(&camera(), &camera()), Ok(vec![]));

        let mut short = good.clone();
        short.right.pop();
        assert!(matches!(
            observations(vec![good.clone(), short]).validate(&camera(), &camera()),
            Err(CalibError::CornerCount { view: 1, side: Side::Right, got: 19, expected: 20 })
        ));

        let mut outside = good.clone();
        outside.left[3] = Some(Point2::new(700.0, 10.0));
        let error = observations(vec![outside]).validate(&camera(), &camera()).unwrap_err();
        assert!(matches!(error, CalibError::CornerOutsideImage { view: 0, side: Side::Left, corner: 3, .. }));
        assert_eq!(error.field(), "views[0].left[3]");

        let mut one_sided = good.clone();
        one_sided.right[7] = None;
        assert!(matches!(
            observations(vec![one_sided]).validate(&camera(), &camera()),
            Err(CalibError::CornerInOneImage { view: 0, corner: 7, missing: Side::Right })
        ));

        let edge_on = StereoView { left: grid(&board, 0.0), right: grid(&board, 0.0) };
        assert!(matches!(
            observations(vec![edge_on]).validate(&camera(), &camera()),
            Err(CalibError::UnusableView { view: 0, .. })
        ));
        let oblique = StereoView { left: grid(&board, 0.12), right: grid(&board, 1.0) };
        let warnings = observations(vec![oblique]).validate(&camera(), &camera()).unwrap();
        assert_eq!(warnings.len(), 1, "{warnings:?}");

        let mut sparse = good;
        for i in 0..15 {
            sparse.left[i] = None;
            sparse.right[i] = None;
        }
        assert!(matches!(
            observations(vec![sparse]).validate(&camera(), &camera()),
            Err(CalibError::UnusableView { view: 0, .. })
        ));
        assert_eq!(observations(vec![]).validate(&camera(), &camera()), Err(CalibError::NoViews));
    }
}
