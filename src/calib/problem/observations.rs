//! Stereo observations of a planar board: for each view, the corners found in both images.

use nalgebra::{Matrix2, Point2, Vector2};

use crate::calib::error::{CalibError, Side};
use crate::calib::problem::board::Board;
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
        (0..self.left.len())
            .filter(|&i| self.left[i].is_some() && self.right.get(i).is_some_and(|c| c.is_some()))
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

/// Largest coordinate difference, pixels, at which a view is a copy of another: far below the
/// noise of any corner detector (two detections of a board that did not move differ by ≥ 0.1 px
/// somewhere), above the rounding of a file written with 3 decimals.
pub const REPEAT_PX: f64 = 0.01;

/// RMS corner difference, pixels, below which two views show the same board pose: the board moved
/// by less than about a millimetre at half a metre, which adds no pose to the calibration.
pub const SAME_POSE_PX: f64 = 1.0;

/// The corners of one view for comparison: (board index, [left, right] pixel), in index order.
pub type ViewCorners = Vec<(usize, [Point2<f64>; 2])>;

/// How the views relate to each other ([`compare_views`]).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ViewGroups {
    /// Views that repeat an earlier one: (view, the first view of its copies, largest difference px).
    pub repeats: Vec<(usize, usize, f64)>,
    /// Groups of two or more views that show the same board pose (within [`SAME_POSE_PX`] RMS),
    /// each in file order, with the largest RMS difference to the group's first view.
    pub same_pose: Vec<(Vec<usize>, f64)>,
    /// Distinct board poses among the views.
    pub distinct: usize,
}

impl ViewGroups {
    /// [`CalibError::RepeatedView`] for the first view that repeats an earlier one, if any.
    pub fn check_repeats(&self) -> Result<(), CalibError> {
        match self.repeats.first() {
            Some(&(view, earlier, max_px)) => Err(CalibError::RepeatedView {
                view,
                earlier,
                max_px,
                more: self.repeats.len() - 1,
            }),
            None => Ok(()),
        }
    }
}

/// The RMS and largest corner difference of two views over the corners both hold, pixels;
/// `None` when they share fewer than [`MIN_VIEW_CORNERS`] corners (or less than half of either)
/// or differ by more than `tolerance` RMS (the sum stops early then).
fn view_difference(a: &ViewCorners, b: &ViewCorners, tolerance: f64) -> Option<(f64, f64)> {
    let bound = 2.0 * tolerance * tolerance * a.len().min(b.len()) as f64;
    let (mut i, mut j) = (0, 0);
    let (mut sum, mut largest, mut shared) = (0.0, 0.0f64, 0usize);
    while i < a.len() && j < b.len() {
        match a[i].0.cmp(&b[j].0) {
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
            std::cmp::Ordering::Equal => {
                for k in 0..2 {
                    let d = a[i].1[k] - b[j].1[k];
                    sum += d.norm_squared();
                    largest = largest.max(d.x.abs()).max(d.y.abs());
                }
                if sum > bound {
                    return None;
                }
                shared += 1;
                i += 1;
                j += 1;
            }
        }
    }
    if shared < MIN_VIEW_CORNERS || 2 * shared < a.len().max(b.len()) {
        return None;
    }
    let rms = (sum / (2 * shared) as f64).sqrt();
    (rms <= tolerance).then_some((rms, largest))
}

fn root(parent: &mut [usize], mut v: usize) -> usize {
    while parent[v] != v {
        parent[v] = parent[parent[v]];
        v = parent[v];
    }
    v
}

/// Views of one pose compared with a later view of that pose when looking for a copy among them.
const MAX_GROUP_COMPARISONS: usize = 64;

/// Finds views that repeat another (every shared corner within [`REPEAT_PX`]) and groups of
/// views of one board pose (within [`SAME_POSE_PX`] RMS).
///
/// Each view is compared with every earlier one, latest first; the sum of squared differences
/// stops as soon as it exceeds the tolerance, which for views of different poses is after the
/// first corner or two. Once a view matches the pose of an earlier one only the other views of
/// that pose (at most `MAX_GROUP_COMPARISONS`, 64) are searched for a copy. Views with fewer than
/// [`MIN_VIEW_CORNERS`] corners in common, or less than half of either's, are not compared.
pub fn compare_views(views: &[ViewCorners]) -> ViewGroups {
    let n = views.len();
    let mut pose_parent: Vec<usize> = (0..n).collect();
    let mut copy_parent: Vec<usize> = (0..n).collect();
    let mut copy_gap = vec![0.0f64; n];
    for i in 0..n {
        let mut pose: Option<usize> = None;
        let mut compared = 0;
        for j in (0..i).rev() {
            if let Some(group) = pose {
                if root(&mut pose_parent, j) != group {
                    continue;
                }
                compared += 1;
                if compared > MAX_GROUP_COMPARISONS {
                    break;
                }
            }
            let Some((_, largest)) = view_difference(&views[i], &views[j], SAME_POSE_PX) else {
                continue;
            };
            let (ri, rj) = (root(&mut pose_parent, i), root(&mut pose_parent, j));
            pose_parent[ri.max(rj)] = ri.min(rj);
            pose = Some(root(&mut pose_parent, j));
            if largest <= REPEAT_PX {
                let (ci, cj) = (root(&mut copy_parent, i), root(&mut copy_parent, j));
                copy_parent[ci.max(cj)] = ci.min(cj);
                copy_gap[i] = copy_gap[i].max(largest);
                break;
            }
        }
    }
    let mut groups = ViewGroups::default();
    let mut members: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for (v, &gap) in copy_gap.iter().enumerate() {
        let copy = root(&mut copy_parent, v);
        if copy != v {
            groups.repeats.push((v, copy, gap));
        }
        members
            .entry(root(&mut pose_parent, v))
            .or_default()
            .push(v);
    }
    groups.distinct = members.len();
    for (first, views_of_pose) in members {
        if views_of_pose.len() > 1 {
            let spread = views_of_pose[1..]
                .iter()
                .filter_map(|&v| {
                    view_difference(&views[v], &views[first], f64::INFINITY).map(|d| d.0)
                })
                .fold(0.0, f64::max);
            groups.same_pose.push((views_of_pose, spread));
        }
    }
    groups
}

/// View indices as short text: `0–4, 7, 9–11`.
pub fn view_list(views: &[usize]) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut k = 0;
    while k < views.len() {
        let mut end = k;
        while end + 1 < views.len() && views[end + 1] == views[end] + 1 {
            end += 1;
        }
        parts.push(if end > k + 1 {
            format!("{}–{}", views[k], views[end])
        } else if end == k + 1 {
            format!("{}, {}", views[k], views[end])
        } else {
            views[k].to_string()
        });
        k = end + 1;
    }
    parts.join(", ")
}

/// The pose groups as text for a message: `views 0–14 within 0.258 px RMS`.
pub fn describe_pose_groups(groups: &ViewGroups) -> String {
    groups
        .same_pose
        .iter()
        .map(|(views, rms)| format!("views {} within {rms:.3} px RMS", view_list(views)))
        .collect::<Vec<_>>()
        .join("; ")
}

impl Observations {
    /// Checks the observations against the board and the two cameras' images: the corner counts,
    /// nulls in both images or neither, finite corners inside the images, at least
    /// [`MIN_VIEW_CORNERS`] matched corners per view that span the board (not edge-on).
    ///
    /// Returns the warnings for views that can be used but are weak (oblique views).
    pub fn validate(
        &self,
        left: &PinholeCamera,
        right: &PinholeCamera,
    ) -> Result<Vec<String>, CalibError> {
        let board = &self.board;
        if board.rows < 2 || board.cols < 2 {
            return Err(CalibError::BadBoard {
                reason: format!(
                    "needs at least 2 × 2 inner corners, got rows {} × cols {}",
                    board.rows, board.cols
                ),
            });
        }
        if !(board.square > 0.0 && board.square.is_finite()) {
            return Err(CalibError::BadBoard {
                reason: format!(
                    "square must be a positive length in metres, got {}",
                    board.square
                ),
            });
        }
        if self.views.is_empty() {
            return Err(CalibError::NoViews);
        }
        let expected = board.corners();
        let mut warnings = Vec::new();
        for (v, view) in self.views.iter().enumerate() {
            for (side, corners, camera) in [
                (Side::Left, &view.left, left),
                (Side::Right, &view.right, right),
            ] {
                if corners.len() != expected {
                    return Err(CalibError::CornerCount {
                        view: v,
                        side,
                        got: corners.len(),
                        expected,
                    });
                }
                for (i, corner) in corners.iter().enumerate() {
                    let Some(p) = corner else { continue };
                    if !(p.x.is_finite() && p.y.is_finite()) {
                        return Err(CalibError::CornerNotFinite {
                            view: v,
                            side,
                            corner: i,
                            u: p.x,
                            v: p.y,
                        });
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
                    (Some(_), None) => {
                        return Err(CalibError::CornerInOneImage {
                            view: v,
                            corner: i,
                            missing: Side::Right,
                        });
                    }
                    (None, Some(_)) => {
                        return Err(CalibError::CornerInOneImage {
                            view: v,
                            corner: i,
                            missing: Side::Left,
                        });
                    }
                    _ => {}
                }
            }
            let matched = view.matched().count();
            if matched < MIN_VIEW_CORNERS {
                return Err(CalibError::UnusableView {
                    view: v,
                    reason: format!(
                        "{matched} corners seen in both images; a view needs at least {MIN_VIEW_CORNERS}"
                    ),
                });
            }
            let mut worst = f64::INFINITY;
            for side in [Side::Left, Side::Right] {
                let ratio = spread_ratio(board, view.side(side)).ok_or_else(|| {
                    CalibError::UnusableView {
                        view: v,
                        reason: format!(
                            "the {} corners do not span the board (all on one row or column)",
                            side.name()
                        ),
                    }
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
        let groups = compare_views(&self.view_corners());
        groups.check_repeats()?;
        for (views, rms) in &groups.same_pose {
            warnings.push(format!(
                "views {} show the same board pose (their corners lie within {rms:.2} px RMS of each other): they count as one pose; move or turn the board between views",
                view_list(views)
            ));
        }
        Ok(warnings)
    }

    /// The corners seen in both images of every view, for [`compare_views`].
    pub fn view_corners(&self) -> Vec<ViewCorners> {
        self.views
            .iter()
            .map(|v| {
                v.matched()
                    .map(|i| {
                        (
                            i,
                            [v.left[i].expect("matched"), v.right[i].expect("matched")],
                        )
                    })
                    .collect()
            })
            .collect()
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
                Some(Point2::new(
                    100.0 + 20.0 * c as f64,
                    100.0 + shear * 20.0 * r as f64 + 2.0 * c as f64,
                ))
            })
            .collect()
    }

    fn observations(views: Vec<StereoView>) -> Observations {
        Observations {
            board: Board {
                rows: 4,
                cols: 5,
                square: 0.04,
            },
            views,
            cameras: None,
        }
    }

    #[test]
    fn good_views_pass_and_bad_ones_are_named() {
        let board = Board {
            rows: 4,
            cols: 5,
            square: 0.04,
        };
        let good = StereoView {
            left: grid(&board, 1.0),
            right: grid(&board, 1.0),
        };
        assert_eq!(
            observations(vec![good.clone()]).validate(&camera(), &camera()),
            Ok(vec![])
        );

        let mut short = good.clone();
        short.right.pop();
        assert!(matches!(
            observations(vec![good.clone(), short]).validate(&camera(), &camera()),
            Err(CalibError::CornerCount {
                view: 1,
                side: Side::Right,
                got: 19,
                expected: 20
            })
        ));

        let mut outside = good.clone();
        outside.left[3] = Some(Point2::new(700.0, 10.0));
        let error = observations(vec![outside])
            .validate(&camera(), &camera())
            .unwrap_err();
        assert!(matches!(
            error,
            CalibError::CornerOutsideImage {
                view: 0,
                side: Side::Left,
                corner: 3,
                ..
            }
        ));
        assert_eq!(error.field(), "views[0].left[3]");

        let mut one_sided = good.clone();
        one_sided.right[7] = None;
        assert!(matches!(
            observations(vec![one_sided]).validate(&camera(), &camera()),
            Err(CalibError::CornerInOneImage {
                view: 0,
                corner: 7,
                missing: Side::Right
            })
        ));

        let edge_on = StereoView {
            left: grid(&board, 0.0),
            right: grid(&board, 0.0),
        };
        assert!(matches!(
            observations(vec![edge_on]).validate(&camera(), &camera()),
            Err(CalibError::UnusableView { view: 0, .. })
        ));
        let oblique = StereoView {
            left: grid(&board, 0.12),
            right: grid(&board, 1.0),
        };
        let warnings = observations(vec![oblique])
            .validate(&camera(), &camera())
            .unwrap();
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
        assert_eq!(
            observations(vec![]).validate(&camera(), &camera()),
            Err(CalibError::NoViews)
        );
    }

    /// A view moved by `shift` pixels in both images (a different pose when large).
    fn shifted(view: &StereoView, shift: f64) -> StereoView {
        let move_all = |c: &Vec<Option<Point2<f64>>>| {
            c.iter()
                .map(|p| p.map(|p| Point2::new(p.x + shift, p.y - 0.5 * shift)))
                .collect()
        };
        StereoView {
            left: move_all(&view.left),
            right: move_all(&view.right),
        }
    }

    #[test]
    fn repeated_views_are_named_and_same_poses_grouped() {
        let board = Board {
            rows: 4,
            cols: 5,
            square: 0.04,
        };
        let a = StereoView {
            left: grid(&board, 1.0),
            right: grid(&board, 1.1),
        };
        let views = vec![
            a.clone(),
            shifted(&a, 30.0),
            shifted(&a, 60.0),
            a.clone(),
            shifted(&a, 30.004),
        ];
        let error = observations(views)
            .validate(&camera(), &camera())
            .unwrap_err();
        assert!(
            matches!(
                error,
                CalibError::RepeatedView {
                    view: 3,
                    earlier: 0,
                    more: 1,
                    ..
                }
            ),
            "{error:?}"
        );
        assert_eq!(error.field(), "views[3]");
        assert!(
            error.to_string().starts_with("views[3] repeats views[0]")
                && error.to_string().contains("1 more"),
            "{error}"
        );

        // A copy with a few corners missing is still a copy.
        let mut partial = a.clone();
        partial.left[4] = None;
        partial.right[4] = None;
        let groups = compare_views(
            &observations(vec![shifted(&a, 10.0), a.clone(), partial]).view_corners(),
        );
        assert_eq!(groups.repeats, vec![(2, 1, 0.0)]);

        // Fifteen copies: one pose.
        let groups = compare_views(&observations(vec![a.clone(); 15]).view_corners());
        assert_eq!(groups.distinct, 1);
        assert_eq!(groups.repeats.len(), 14);
        assert!(groups.repeats.iter().all(|&(_, first, _)| first == 0));

        // Re-detections of one pose (0.3 px apart) are not copies but one pose; 5 px apart is
        // another pose.
        let views = vec![
            a.clone(),
            shifted(&a, 0.3),
            shifted(&a, 5.0),
            shifted(&a, -0.2),
        ];
        let groups = compare_views(&observations(views.clone()).view_corners());
        assert!(groups.repeats.is_empty(), "{groups:?}");
        assert_eq!(groups.distinct, 2);
        assert_eq!(groups.same_pose.len(), 1);
        assert_eq!(groups.same_pose[0].0, vec![0, 1, 3]);
        let warnings = observations(views).validate(&camera(), &camera()).unwrap();
        assert!(
            warnings
                .iter()
                .any(|w| w.starts_with("views 0, 1, 3 show the same board pose")),
            "{warnings:?}"
        );
        assert_eq!(view_list(&[0, 1, 2, 3, 7, 9, 10]), "0–3, 7, 9, 10");
    }
}
