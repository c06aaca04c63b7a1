//! Observations in the general form (DESIGN.md §3b): views of a board or a 3-D target, each view
//! holding the corners that each rig camera saw, keyed by camera. One camera, two or N are the
//! same data; the stereo form (`left`/`right`) is one case of it.

use nalgebra::Point2;

use crate::calib::error::CalibError;
use crate::calib::problem::observations::{MIN_VIEW_CORNERS, Observations, StereoView};
use crate::calib::problem::target::Target;
use crate::model::Rig;

/// Which rig camera took an image.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CameraKey {
    /// A rig camera's name (the general form's key).
    Name(String),
    /// The stereo form without `"cameras"`: `left` is rig camera 0, `right` rig camera 1.
    Position(usize),
}

/// The corners one camera saw in one view, in target order (`None`: not detected).
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// The camera.
    pub camera: CameraKey,
    /// The key as the file spells it (for messages).
    pub key: String,
    /// One entry per target corner.
    pub corners: Vec<Option<Point2<f64>>>,
}

/// One view: the images of the cameras that saw it.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RigView {
    /// The images, in file order.
    pub images: Vec<Image>,
}

/// Views of one target by the cameras of a rig.
#[derive(Debug, Clone, PartialEq)]
pub struct RigObservations {
    /// The target.
    pub target: Target,
    /// The views, in file order.
    pub views: Vec<RigView>,
}

/// One view resolved against a rig: per camera that saw it, its rig index and the corners it saw
/// as (target index, raw pixel).
#[derive(Debug, Clone, PartialEq)]
pub struct SeenView {
    /// (rig camera, corners), cameras in rig order.
    pub cameras: Vec<(usize, Vec<(usize, Point2<f64>)>)>,
}

impl SeenView {
    /// Corners seen in this view, all cameras together.
    pub fn observations(&self) -> usize {
        self.cameras.iter().map(|(_, c)| c.len()).sum()
    }
}

impl RigObservations {
    /// Resolves every image's camera in `rig` and checks the values: a known camera, at most one
    /// image per camera in a view, one entry per target corner, finite corners inside the image.
    /// Views keep their numbers; a camera with fewer than [`MIN_VIEW_CORNERS`] corners in a view
    /// is an error (a detector that found fewer should leave the camera out of the view).
    pub fn resolve(&self, rig: &Rig) -> Result<Vec<SeenView>, CalibError> {
        if self.views.is_empty() {
            return Err(CalibError::NoViews);
        }
        let expected = self.target.len();
        let mut seen = Vec::with_capacity(self.views.len());
        for (v, view) in self.views.iter().enumerate() {
            let mut cameras: Vec<(usize, Vec<(usize, Point2<f64>)>)> =
                Vec::with_capacity(view.images.len());
            for image in &view.images {
                let field = format!("views[{v}].{}", image.key);
                let error =
                    |field: String, reason: String| CalibError::Observation { field, reason };
                let k = match &image.camera {
                    CameraKey::Name(name) => rig
                        .cameras()
                        .iter()
                        .position(|c| &c.name == name)
                        .ok_or_else(|| {
                            let names: Vec<&str> =
                                rig.cameras().iter().map(|c| c.name.as_str()).collect();
                            error(
                                field.clone(),
                                format!(
                                    "'{name}' is not a camera of the rig (its cameras: {})",
                                    names.join(", ")
                                ),
                            )
                        })?,
                    CameraKey::Position(k) if *k < rig.cameras().len() => *k,
                    CameraKey::Position(k) => {
                        return Err(error(
                            field,
                            format!(
                                "the stereo form's '{}' image is rig camera {k}, and the rig has {} camera(s)",
                                image.key,
                                rig.cameras().len()
                            ),
                        ));
                    }
                };
                if cameras.iter().any(|(c, _)| *c == k) {
                    return Err(error(
                        field,
                        format!(
                            "camera '{}' has two images in this view",
                            rig.cameras()[k].name
                        ),
                    ));
                }
                if image.corners.len() != expected {
                    return Err(error(
                        field,
                        format!("{} corners, the target has {expected}", image.corners.len()),
                    ));
                }
                let intrinsics = &rig.cameras()[k].intrinsics;
                let mut corners = Vec::with_capacity(expected);
                for (i, corner) in image.corners.iter().enumerate() {
                    let Some(p) = corner else { continue };
                    let field = format!("{field}[{i}]");
                    if !(p.x.is_finite() && p.y.is_finite()) {
                        return Err(error(field, format!("[{}, {}] is not finite", p.x, p.y)));
                    }
                    // Pixel centres run from 0 to size − 1; a corner may lie up to half a pixel beyond.
                    let inside = (-0.5..=intrinsics.width as f64 - 0.5).contains(&p.x)
                        && (-0.5..=intrinsics.height as f64 - 0.5).contains(&p.y);
                    if !inside {
                        return Err(error(
                            field,
                            format!(
                                "({}, {}) px lies outside camera '{}''s {}×{} image",
                                p.x,
                                p.y,
                                rig.cameras()[k].name,
                                intrinsics.width,
                                intrinsics.height
                            ),
                        ));
                    }
                    corners.push((i, *p));
                }
                if corners.len() < MIN_VIEW_CORNERS {
                    return Err(error(
                        field,
                        format!(
                            "{} corners seen; an image needs at least {MIN_VIEW_CORNERS} (leave a camera that did not see the target out of the view)",
                            corners.len()
                        ),
                    ));
                }
                cameras.push((k, corners));
            }
            cameras.sort_by_key(|(k, _)| *k);
            seen.push(SeenView { cameras });
        }
        Ok(seen)
    }

    /// The stereo observations of cameras `a` and `b` (rig indices) among `seen` (these
    /// observations resolved against `rig`, [`Self::resolve`]): the views both saw, with the
    /// corners both saw (a corner one of them missed is null in both). `None` for a 3-D target
    /// (the binocular costs need a board).
    pub fn pair(&self, seen: &[SeenView], rig: &Rig, a: usize, b: usize) -> Option<Observations> {
        stereo_pair(&self.target, seen, rig, a, b)
    }
}

/// [`RigObservations::pair`] of views `seen` of `target`.
pub fn stereo_pair(
    target: &Target,
    seen: &[SeenView],
    rig: &Rig,
    a: usize,
    b: usize,
) -> Option<Observations> {
    let Target::Board(board) = *target else {
        return None;
    };
    let mut views = Vec::new();
    for view in seen {
        let find = |k: usize| {
            view.cameras
                .iter()
                .find(|(c, _)| *c == k)
                .map(|(_, corners)| corners)
        };
        let (Some(left), Some(right)) = (find(a), find(b)) else {
            continue;
        };
        let mut stereo = StereoView {
            left: vec![None; board.corners()],
            right: vec![None; board.corners()],
        };
        for &(i, p) in left {
            stereo.left[i] = Some(p);
        }
        for &(i, p) in right {
            stereo.right[i] = Some(p);
        }
        for i in 0..board.corners() {
            if stereo.left[i].is_none() || stereo.right[i].is_none() {
                stereo.left[i] = None;
                stereo.right[i] = None;
            }
        }
        if stereo.matched().count() >= MIN_VIEW_CORNERS {
            views.push(stereo);
        }
    }
    let names = [a, b].map(|k| rig.cameras()[k].name.clone());
    Some(Observations {
        board,
        views,
        cameras: Some(names),
    })
}
