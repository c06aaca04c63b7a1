//! Observations (DESIGN.md §3b): views of a board or a 3-D target, each view holding the corners
//! that each rig camera saw. One camera, two or N are the same data; the stereo form of the file
//! (`left`/`right`, optional `"cameras": [A, B]`) is read as the two-camera case.
//!
//! [`Observations::resolve`] checks the values against a rig and gives each view as the
//! corners each camera saw ([`SeenView`]); [`Observations::check`] looks at the views as a whole:
//! boards seen edge-on or very obliquely, views that repeat another, views of one board pose.

use nalgebra::{Matrix2, Point2, Vector2};

use crate::base::Board;
use crate::calib::error::CalibError;
use crate::calib::problem::target::Target;
use crate::model::Rig;

/// One synchronized frame under water: per rig camera, the board corners it saw ((corner
/// index, raw pixel); empty when it did not see the board).
#[derive(Debug, Clone, PartialEq)]
pub struct WaterFrame {
    /// A name for messages (the frame's index or file).
    pub label: String,
    /// Per rig camera, in rig order.
    pub corners: Vec<Vec<(usize, Point2<f64>)>>,
}

/// Which rig camera took an image.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CameraKey {
    /// A rig camera's name (the general form's key, or the stereo form's `"cameras"`).
    Name(String),
    /// The stereo form without `"cameras"`: `left` is rig camera 0, `right` rig camera 1.
    Position(usize),
}

/// The corners one camera saw in one view, in target order (`None`: not detected).
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// The camera.
    pub camera: CameraKey,
    /// The key as the file spells it (`left`, or a camera name), for messages and file paths.
    pub key: String,
    /// One entry per target corner.
    pub corners: Vec<Option<Point2<f64>>>,
}

impl Image {
    /// The target indices of the corners this image holds, in order.
    pub fn seen_corners(&self) -> Vec<usize> {
        self.corners
            .iter()
            .enumerate()
            .filter_map(|(i, c)| c.map(|_| i))
            .collect()
    }
}

/// One view: the images of the cameras that saw it.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct View {
    /// The images, in file order.
    pub images: Vec<Image>,
}

/// Views of one target by the cameras of a rig.
#[derive(Debug, Clone, PartialEq)]
pub struct Observations {
    /// The target.
    pub target: Target,
    /// The views, in file order.
    pub views: Vec<View>,
    /// Read from the stereo form, whose contract is that a corner not detected is null in both
    /// images ([`CalibError::CornerInOneImage`] otherwise).
    pub stereo_form: bool,
}

/// The corners one camera saw in one view: (target index, raw pixel), in target order.
pub type ImageCorners = Vec<(usize, Point2<f64>)>;

/// The corners two cameras both saw in one view: (target index, [pixel in the first, in the
/// second]), in target order.
pub type PairCorners = Vec<(usize, [Point2<f64>; 2])>;

/// One view resolved against a rig: per camera that saw it, its rig index and the corners it saw
/// as (target index, raw pixel).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SeenView {
    /// (rig camera, corners), cameras in rig order.
    pub cameras: Vec<(usize, ImageCorners)>,
    /// The file key of each image (`left`, or a camera name), as `cameras`.
    pub keys: Vec<String>,
}

impl SeenView {
    /// Corners seen in this view, all cameras together.
    pub fn observations(&self) -> usize {
        self.cameras.iter().map(|(_, c)| c.len()).sum()
    }

    /// The corners camera `k` saw in this view, if it saw it.
    pub fn corners_of(&self, k: usize) -> Option<&[(usize, Point2<f64>)]> {
        self.cameras
            .iter()
            .find(|(c, _)| *c == k)
            .map(|(_, corners)| corners.as_slice())
    }
}

/// Fewest corners an image must hold to take part (and, for a pair's costs, fewest corners seen
/// in both images of a view).
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

impl Observations {
    /// Observations of `target` without views yet (the general form).
    pub fn new(target: Target) -> Self {
        Self {
            target,
            views: Vec::new(),
            stereo_form: false,
        }
    }

    /// Resolves every image's camera in `rig` and checks the values: a target of at least 2 × 2
    /// corners (a board) and at least one view; a known camera, at most one image per camera in
    /// a view, one entry per target corner, finite corners inside the image, at least
    /// [`MIN_VIEW_CORNERS`] corners per image (a detector that found fewer should leave the
    /// camera out of the view), and in the stereo form a corner null in both images or neither.
    /// Views keep their numbers.
    pub fn resolve(&self, rig: &Rig) -> Result<Vec<SeenView>, CalibError> {
        if let Target::Board(board) = &self.target {
            check_board(board)?;
        }
        if self.views.is_empty() {
            return Err(CalibError::NoViews);
        }
        let expected = self.target.len();
        let mut seen = Vec::with_capacity(self.views.len());
        for (v, view) in self.views.iter().enumerate() {
            let mut cameras: Vec<(usize, ImageCorners, String)> =
                Vec::with_capacity(view.images.len());
            for image in &view.images {
                let k = resolve_camera(rig, v, image)?;
                let camera = &rig.cameras()[k];
                if cameras.iter().any(|(c, _, _)| *c == k) {
                    return Err(CalibError::Observation {
                        field: format!("views[{v}].{}", image.key),
                        reason: format!("camera '{}' has two images in this view", camera.name),
                    });
                }
                if image.corners.len() != expected {
                    return Err(CalibError::CornerCount {
                        view: v,
                        image: image.key.clone(),
                        got: image.corners.len(),
                        expected,
                    });
                }
                let intrinsics = &camera.intrinsics;
                let mut corners = Vec::with_capacity(expected);
                for (i, corner) in image.corners.iter().enumerate() {
                    let Some(p) = corner else { continue };
                    if !(p.x.is_finite() && p.y.is_finite()) {
                        return Err(CalibError::CornerNotFinite {
                            view: v,
                            image: image.key.clone(),
                            corner: i,
                            u: p.x,
                            v: p.y,
                        });
                    }
                    // Pixel centres run from 0 to size − 1; a corner may lie up to half a pixel beyond.
                    let inside = (-0.5..=intrinsics.width as f64 - 0.5).contains(&p.x)
                        && (-0.5..=intrinsics.height as f64 - 0.5).contains(&p.y);
                    if !inside {
                        return Err(CalibError::CornerOutsideImage {
                            view: v,
                            image: image.key.clone(),
                            corner: i,
                            u: p.x,
                            v: p.y,
                            width: intrinsics.width,
                            height: intrinsics.height,
                        });
                    }
                    corners.push((i, *p));
                }
                if corners.len() < MIN_VIEW_CORNERS {
                    return Err(CalibError::UnusableView {
                        view: v,
                        reason: format!(
                            "the {} image holds {} corners; an image needs at least {MIN_VIEW_CORNERS} (leave a camera that did not see the target out of the view)",
                            image.key,
                            corners.len()
                        ),
                    });
                }
                cameras.push((k, corners, image.key.clone()));
            }
            if self.stereo_form {
                check_null_in_both(v, view)?;
            }
            cameras.sort_by_key(|(k, _, _)| *k);
            let (cameras, keys) = cameras.into_iter().map(|(k, c, key)| ((k, c), key)).unzip();
            seen.push(SeenView { cameras, keys });
        }
        Ok(seen)
    }

    /// These observations without the images no pose can come from: fewer than
    /// [`MIN_VIEW_CORNERS`] corners, or (of a board) every corner on one row or one column of the
    /// board, as partial boards often give. Such an image is left out of its view, and a view
    /// left with no image is left out (the views after it move up one number); one warning each,
    /// naming the view as numbered here.
    pub fn without_unusable_images(&self) -> (Self, Vec<String>) {
        let mut warnings = Vec::new();
        let mut views = Vec::with_capacity(self.views.len());
        for (v, view) in self.views.iter().enumerate() {
            let mut images = Vec::with_capacity(view.images.len());
            for image in &view.images {
                let why = unusable_image(&self.target, &image.seen_corners());
                match why {
                    Some(why) => warnings.push(format!(
                        "view {v}: the {} image is left out ({why}: no pose of the target from it)",
                        image.key
                    )),
                    None => images.push(image.clone()),
                }
            }
            if images.is_empty() {
                warnings.push(format!(
                    "view {v} is left out: none of its images is usable (the views after it move up one number)"
                ));
            } else {
                views.push(View { images });
            }
        }
        (
            Self {
                views,
                ..self.clone()
            },
            warnings,
        )
    }

    /// The views as a whole, resolved as [`Self::resolve`] gives them: an error for a board seen
    /// edge-on in an image (its corners on a line) and for a view that repeats an earlier one;
    /// warnings for boards seen very obliquely and for views that show one board pose.
    pub fn check(&self, seen: &[SeenView]) -> Result<Vec<String>, CalibError> {
        let mut warnings = Vec::new();
        if let Target::Board(board) = &self.target {
            for (v, view) in seen.iter().enumerate() {
                let mut worst: Option<(f64, &String)> = None;
                for (image, (_, corners)) in view.keys.iter().zip(&view.cameras) {
                    let ratio = spread_ratio(board, corners).ok_or_else(|| {
                        CalibError::UnusableView {
                            view: v,
                            reason: format!(
                                "the {image} corners do not span the board (all on one row or column)"
                            ),
                        }
                    })?;
                    if worst.is_none_or(|(w, _)| ratio < w) {
                        worst = Some((ratio, image));
                    }
                }
                let Some((worst, image)) = worst else {
                    continue;
                };
                if worst < EDGE_ON_RATIO {
                    return Err(CalibError::UnusableView {
                        view: v,
                        reason: format!(
                            "the board is seen edge-on in the {image} image: its corners lie on a line (spread ratio {worst:.3} < {EDGE_ON_RATIO})"
                        ),
                    });
                }
                if worst < OBLIQUE_RATIO {
                    warnings.push(format!(
                        "view {v}: the board is seen very obliquely in the {image} image (spread ratio {worst:.3}): its corners constrain the port poorly"
                    ));
                }
            }
        }
        let groups = compare_views(&view_corners(seen));
        groups.check_repeats()?;
        for (views, rms) in &groups.same_pose {
            warnings.push(format!(
                "views {} show the same target pose (their corners lie within {rms:.2} px RMS of each other): they count as one pose; move or turn the target between views",
                view_list(views)
            ));
        }
        Ok(warnings)
    }
}

/// Why an image holding `corners` (target indices, in order) of `target` gives no pose of it, if
/// it gives none: fewer than [`MIN_VIEW_CORNERS`] corners, or (of a board) every corner on one
/// row or one column of the board.
pub fn unusable_image(target: &Target, corners: &[usize]) -> Option<String> {
    if corners.len() < MIN_VIEW_CORNERS {
        return Some(format!(
            "{} corner(s), fewer than {MIN_VIEW_CORNERS}",
            corners.len()
        ));
    }
    let board = target.board()?;
    (on_one_line(corners, |i| i / board.cols) || on_one_line(corners, |i| i % board.cols))
        .then(|| "its corners lie on one row or column of the board".to_string())
}

/// Whether every one of `corners` has the same `line` (row or column of the board).
fn on_one_line(corners: &[usize], line: impl Fn(usize) -> usize) -> bool {
    corners.windows(2).all(|w| line(w[0]) == line(w[1]))
}

/// A board of at least 2 × 2 corners and a positive square.
fn check_board(board: &Board) -> Result<(), CalibError> {
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
    Ok(())
}

/// The rig camera of `image` of view `v`.
fn resolve_camera(rig: &Rig, v: usize, image: &Image) -> Result<usize, CalibError> {
    let field = || format!("views[{v}].{}", image.key);
    match &image.camera {
        CameraKey::Name(name) => rig.camera_index(name).ok_or_else(|| {
            let names: Vec<&str> = rig.cameras().iter().map(|c| c.name.as_str()).collect();
            CalibError::Observation {
                field: field(),
                reason: format!(
                    "'{name}' is not a camera of the rig (its cameras: {})",
                    names.join(", ")
                ),
            }
        }),
        CameraKey::Position(k) if *k < rig.cameras().len() => Ok(*k),
        CameraKey::Position(k) => Err(CalibError::Observation {
            field: field(),
            reason: format!(
                "the stereo form's '{}' image is rig camera {k}, and the rig has {} camera(s)",
                image.key,
                rig.cameras().len()
            ),
        }),
    }
}

/// The stereo form's contract: a corner not detected is null in both images of a view.
fn check_null_in_both(v: usize, view: &View) -> Result<(), CalibError> {
    let [a, b] = match view.images.as_slice() {
        [a, b] => [a, b],
        _ => return Ok(()),
    };
    for (i, (p, q)) in a.corners.iter().zip(&b.corners).enumerate() {
        let missing = match (p, q) {
            (Some(_), None) => &b.key,
            (None, Some(_)) => &a.key,
            _ => continue,
        };
        return Err(CalibError::CornerInOneImage {
            view: v,
            corner: i,
            missing: missing.clone(),
        });
    }
    Ok(())
}

/// The images of one view for comparison: ((camera, target index), pixel), sorted.
pub type ViewCorners = Vec<((usize, usize), Point2<f64>)>;

/// The corners of every resolved view, for [`compare_views`].
pub fn view_corners(seen: &[SeenView]) -> Vec<ViewCorners> {
    seen.iter()
        .map(|view| {
            let mut corners: ViewCorners = view
                .cameras
                .iter()
                .flat_map(|(k, corners)| corners.iter().map(move |&(i, p)| ((*k, i), p)))
                .collect();
            corners.sort_by_key(|&(key, _)| key);
            corners
        })
        .collect()
}

/// How the views relate to each other ([`compare_views`]).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ViewGroups {
    /// Views that repeat an earlier one: (view, the first view of its copies, largest difference px).
    pub repeats: Vec<(usize, usize, f64)>,
    /// Groups of two or more views that show the same target pose (within [`SAME_POSE_PX`] RMS),
    /// each in file order, with the largest RMS difference to the group's first view.
    pub same_pose: Vec<(Vec<usize>, f64)>,
    /// Distinct target poses among the views.
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

/// The RMS and largest coordinate difference of two views over the corner images both hold,
/// pixels; `None` when they share fewer than [`MIN_VIEW_CORNERS`] (or less than half of either)
/// or differ by more than `tolerance` RMS (the sum stops early then).
fn view_difference(a: &ViewCorners, b: &ViewCorners, tolerance: f64) -> Option<(f64, f64)> {
    let bound = tolerance * tolerance * a.len().min(b.len()) as f64;
    let (mut i, mut j) = (0, 0);
    let (mut sum, mut largest, mut shared) = (0.0, 0.0f64, 0usize);
    while i < a.len() && j < b.len() {
        match a[i].0.cmp(&b[j].0) {
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
            std::cmp::Ordering::Equal => {
                let d = a[i].1 - b[j].1;
                sum += d.norm_squared();
                largest = largest.max(d.x.abs()).max(d.y.abs());
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
    let rms = (sum / shared as f64).sqrt();
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

/// Finds views that repeat another (every shared corner image within [`REPEAT_PX`]) and groups
/// of views of one target pose (within [`SAME_POSE_PX`] RMS).
///
/// Each view is compared with every earlier one, latest first; the sum of squared differences
/// stops as soon as it exceeds the tolerance, which for views of different poses is after the
/// first corner or two. Once a view matches the pose of an earlier one only the other views of
/// that pose (at most `MAX_GROUP_COMPARISONS`, 64) are searched for a copy. Views with fewer than
/// [`MIN_VIEW_CORNERS`] corner images in common, or less than half of either's, are not compared.
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

/// Ratio of the smaller to the larger singular value of the affine map from the board grid
/// (in squares) to the image, fitted by least squares to the corners present: 1 for a board seen
/// face-on with square pixels, → 0 as the board turns edge-on. `None` when the corners present
/// do not span two grid directions.
fn spread_ratio(board: &Board, corners: &[(usize, Point2<f64>)]) -> Option<f64> {
    let present: Vec<(Vector2<f64>, Vector2<f64>)> = corners
        .iter()
        .map(|&(i, p)| {
            let (r, col) = board.grid_position(i);
            (Vector2::new(col as f64, r as f64), p.coords)
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

/// The views that cameras `a` and `b` both saw, for the costs of that pair: per view its number
/// and the corners both saw, as (target index, [pixel in a, pixel in b]); views with fewer than
/// [`MIN_VIEW_CORNERS`] such corners are left out.
pub fn pair_views(seen: &[SeenView], a: usize, b: usize) -> Vec<(usize, PairCorners)> {
    let mut out = Vec::new();
    for (v, view) in seen.iter().enumerate() {
        let (Some(first), Some(second)) = (view.corners_of(a), view.corners_of(b)) else {
            continue;
        };
        // Both lists are in target order.
        let mut matched = Vec::with_capacity(first.len().min(second.len()));
        let mut j = 0;
        for &(i, p) in first {
            while j < second.len() && second[j].0 < i {
                j += 1;
            }
            if j < second.len() && second[j].0 == i {
                matched.push((i, [p, second[j].1]));
            }
        }
        if matched.len() >= MIN_VIEW_CORNERS {
            out.push((v, matched));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Interface, PinholeCamera, RigCamera};
    use nalgebra::{Matrix3, Vector3};

    const BOARD: Board = Board {
        rows: 4,
        cols: 5,
        square: 0.04,
    };

    /// Two 640×480 cameras named left and right behind one port.
    fn rig() -> Rig {
        let camera = |name: &str, x: f64| {
            let intrinsics =
                PinholeCamera::new(name, 640, 480, 500.0, 500.0, 320.0, 240.0, [0.0; 5]).unwrap();
            RigCamera::new(
                name,
                intrinsics,
                Matrix3::identity(),
                Vector3::new(x, 0.0, 0.0),
            )
            .unwrap()
        };
        let port = Interface::new(Vector3::z(), 0.02, vec![], 1.0, 1.333).unwrap();
        Rig::new(vec![camera("left", 0.0), camera("right", -0.1)], port).unwrap()
    }

    /// A board's corners on a sheared grid (`shear` 0: every corner on one line).
    fn grid(shear: f64, shift: f64) -> Vec<Option<Point2<f64>>> {
        (0..BOARD.corners())
            .map(|i| {
                let (r, c) = BOARD.grid_position(i);
                Some(Point2::new(
                    100.0 + shift + 20.0 * c as f64,
                    100.0 - 0.5 * shift + shear * 20.0 * r as f64 + 2.0 * c as f64,
                ))
            })
            .collect()
    }

    fn image(key: &str, corners: Vec<Option<Point2<f64>>>) -> Image {
        Image {
            camera: CameraKey::Name(key.into()),
            key: key.into(),
            corners,
        }
    }

    fn stereo(views: Vec<[Vec<Option<Point2<f64>>>; 2]>) -> Observations {
        Observations {
            target: Target::Board(BOARD),
            views: views
                .into_iter()
                .map(|[l, r]| View {
                    images: vec![image("left", l), image("right", r)],
                })
                .collect(),
            stereo_form: true,
        }
    }

    #[test]
    fn images_no_pose_comes_from_are_left_out_and_said() {
        // View 0: the right image holds five corners of one row (a partial board at the image's
        // edge); view 1: both images hold five corners; view 2: whole.
        let mut one_row = grid(1.0, 0.0);
        for (i, c) in one_row.iter_mut().enumerate() {
            if i >= BOARD.cols {
                *c = None;
            }
        }
        let mut few = grid(1.0, 0.0);
        for c in few.iter_mut().skip(5) {
            *c = None;
        }
        let mut observations = stereo(vec![
            [grid(1.0, 0.0), one_row],
            [few.clone(), few],
            [grid(1.0, 0.0), grid(1.0, 0.0)],
        ]);
        observations.stereo_form = false;
        let (kept, warnings) = observations.without_unusable_images();
        assert_eq!(kept.views.len(), 2, "{warnings:?}");
        assert_eq!(kept.views[0].images.len(), 1);
        assert_eq!(kept.views[0].images[0].key, "left");
        assert_eq!(kept.views[1], observations.views[2]);
        assert!(
            warnings[0].starts_with("view 0: the right image is left out (5 corner(s)"),
            "{warnings:?}"
        );
        // A partial board's corners along one row, or one column, give no pose.
        let long = Target::Board(Board {
            rows: 7,
            cols: 8,
            square: 0.04,
        });
        let row: Vec<usize> = (8..16).collect();
        let column: Vec<usize> = (0..7).map(|r| r * 8 + 3).collect();
        for line in [&row, &column] {
            let why = unusable_image(&long, line).unwrap();
            assert!(why.contains("one row or column"), "{why}");
        }
        assert!(unusable_image(&long, &[8, 9, 10, 11, 12, 13, 21]).is_none());
        assert!(
            warnings.iter().any(|w| w.starts_with("view 1 is left out")),
            "{warnings:?}"
        );
        assert!(kept.resolve(&rig()).is_ok());
        // A column on a 3-D target is no line of the board: only the count matters.
        let points = Target::Points(
            (0..8)
                .map(|i| nalgebra::Point3::new(i as f64, 0.0, 0.0))
                .collect(),
        );
        assert!(unusable_image(&points, &[0, 1, 2, 3, 4, 5]).is_none());
        assert!(unusable_image(&points, &[0, 1, 2]).is_some());
    }

    #[test]
    fn good_views_resolve_and_bad_ones_are_named() {
        let rig = rig();
        let good = [grid(1.0, 0.0), grid(1.0, 0.0)];
        let seen = stereo(vec![good.clone()]).resolve(&rig).unwrap();
        assert_eq!(seen[0].cameras.len(), 2);
        assert_eq!(seen[0].keys, ["left", "right"]);
        assert_eq!(seen[0].observations(), 40);

        let mut short = good.clone();
        short[1].pop();
        let error = stereo(vec![good.clone(), short]).resolve(&rig).unwrap_err();
        assert!(
            matches!(&error, CalibError::CornerCount { view: 1, image, got: 19, expected: 20 } if image == "right"),
            "{error:?}"
        );
        assert_eq!(error.field(), "views[1].right");

        let mut outside = good.clone();
        outside[0][3] = Some(Point2::new(700.0, 10.0));
        let error = stereo(vec![outside]).resolve(&rig).unwrap_err();
        assert_eq!(error.field(), "views[0].left[3]");
        assert!(
            error.to_string().contains("outside the 640×480 image"),
            "{error}"
        );

        let mut not_finite = good.clone();
        not_finite[1][0] = Some(Point2::new(f64::NAN, 10.0));
        let error = stereo(vec![not_finite]).resolve(&rig).unwrap_err();
        assert_eq!(error.field(), "views[0].right[0]");

        // The stereo form's contract; in the general form one camera may miss a corner.
        let mut one_sided = good.clone();
        one_sided[1][7] = None;
        let error = stereo(vec![one_sided.clone()]).resolve(&rig).unwrap_err();
        assert!(
            matches!(&error, CalibError::CornerInOneImage { view: 0, corner: 7, missing } if missing == "right"),
            "{error:?}"
        );
        let mut general = stereo(vec![one_sided]);
        general.stereo_form = false;
        let seen = general.resolve(&rig).unwrap();
        assert_eq!(seen[0].corners_of(1).unwrap().len(), 19);
        assert_eq!(pair_views(&seen, 0, 1)[0].1.len(), 19);

        let mut sparse = good.clone();
        for corners in &mut sparse {
            for c in corners.iter_mut().take(15) {
                *c = None;
            }
        }
        assert!(matches!(
            stereo(vec![sparse]).resolve(&rig),
            Err(CalibError::UnusableView { view: 0, .. })
        ));
        let mut unknown = stereo(vec![good.clone()]);
        unknown.views[0].images[1] = image("middle", grid(1.0, 0.0));
        let error = unknown.resolve(&rig).unwrap_err();
        assert!(
            error
                .to_string()
                .contains("'middle' is not a camera of the rig (its cameras: left, right)"),
            "{error}"
        );
        let mut twice = stereo(vec![good]);
        twice.views[0].images[1] = image("left", grid(1.0, 0.0));
        assert!(
            twice
                .resolve(&rig)
                .unwrap_err()
                .to_string()
                .contains("two images")
        );
        assert_eq!(stereo(vec![]).resolve(&rig), Err(CalibError::NoViews));
    }

    #[test]
    fn edge_on_views_are_refused_and_oblique_ones_reported() {
        let rig = rig();
        let edge_on = stereo(vec![[grid(0.0, 0.0), grid(0.0, 0.0)]]);
        let seen = edge_on.resolve(&rig).unwrap();
        assert!(matches!(
            edge_on.check(&seen),
            Err(CalibError::UnusableView { view: 0, .. })
        ));
        let oblique = stereo(vec![[grid(0.12, 0.0), grid(1.0, 0.0)]]);
        let seen = oblique.resolve(&rig).unwrap();
        let warnings = oblique.check(&seen).unwrap();
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(warnings[0].contains("left image"), "{warnings:?}");
    }

    #[test]
    fn repeated_views_are_named_and_same_poses_grouped() {
        let rig = rig();
        let view = |shift: f64| [grid(1.0, shift), grid(1.1, shift)];
        let observations = stereo(vec![
            view(0.0),
            view(30.0),
            view(60.0),
            view(0.0),
            view(30.004),
        ]);
        let seen = observations.resolve(&rig).unwrap();
        let error = observations.check(&seen).unwrap_err();
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

        // A copy with a few corners missing is still a copy.
        let mut partial = view(0.0);
        partial[0][4] = None;
        partial[1][4] = None;
        let seen = stereo(vec![view(10.0), view(0.0), partial])
            .resolve(&rig)
            .unwrap();
        assert_eq!(
            compare_views(&view_corners(&seen)).repeats,
            vec![(2, 1, 0.0)]
        );

        // Fifteen copies: one pose.
        let seen = stereo(vec![view(0.0); 15]).resolve(&rig).unwrap();
        let groups = compare_views(&view_corners(&seen));
        assert_eq!((groups.distinct, groups.repeats.len()), (1, 14));

        // Re-detections of one pose (0.3 px apart) are one pose, not copies; 5 px apart is another.
        let observations = stereo(vec![view(0.0), view(0.3), view(5.0), view(-0.2)]);
        let seen = observations.resolve(&rig).unwrap();
        let groups = compare_views(&view_corners(&seen));
        assert!(groups.repeats.is_empty(), "{groups:?}");
        assert_eq!(groups.distinct, 2);
        assert_eq!(groups.same_pose[0].0, vec![0, 1, 3]);
        let warnings = observations.check(&seen).unwrap();
        assert!(
            warnings
                .iter()
                .any(|w| w.starts_with("views 0, 1, 3 show the same target pose")),
            "{warnings:?}"
        );
        assert_eq!(view_list(&[0, 1, 2, 3, 7, 9, 10]), "0–3, 7, 9, 10");
    }
}
