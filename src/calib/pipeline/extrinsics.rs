//! The start of the extrinsics from board co-observations: every camera's pose relative to the
//! master from the frames in which both saw the board, chained through other cameras where two
//! never saw a frame together (a pose graph, its spanning tree grown from the master along the
//! links with the most shared frames).
//!
//! Each (camera, frame) gives the board's pose in that camera by the pinhole model
//! ([`pinhole_pose`]). Of the undistorted corners themselves that is the pose of the *apparent*
//! board, nearer by about n_water / n_air and bent the more the farther a camera looks off the
//! port's axis, so that cameras converging from a wide baseline see different apparent boards:
//! through one window, three cameras 0.3 m apart came out at half their distances. So the links
//! are made twice: first from the apparent boards, for the rotations, then from the corners'
//! directions bent into the water at the port's axis in each camera's frame
//! ([`corner_direction`]; a shared port's axis carried into each camera by the first link's
//! rotation), which place the boards where the port's rays go, up to their offset of a few
//! millimetres. Either way it is only the start of the maximum-likelihood fit, which estimates
//! the extrinsics with the ports.
//!
//! A link between two cameras takes, of its frames' relative poses, the one nearest all others
//! (the medoid, in rotation angle plus translation over the median distance to the board): one
//! bad frame cannot move it.

use nalgebra::{Isometry3, Point3, Vector2, Vector3};

use super::poses::{corner_direction, pinhole_pose, port_axis};
use crate::calib::error::CalibError;
use crate::calib::problem::observations::SeenView;
use crate::calib::problem::target::Target;
use crate::model::Rig;

/// Fewest corners of an image for its board pose to take part in a link.
pub const MIN_LINK_CORNERS: usize = 6;

/// How one camera was linked to the master.
#[derive(Debug, Clone, PartialEq)]
pub struct Link {
    /// The camera.
    pub camera: usize,
    /// The camera it was linked through (the master links to itself).
    pub via: usize,
    /// Frames both saw.
    pub frames: usize,
}

/// The start of every camera's `cam_from_master` (the master's the identity) and how each was
/// linked, from the views' pinhole board poses.
///
/// Errors: a camera that shares no frame, directly or through a chain of other cameras, with the
/// master ([`CalibError::Options`] naming it and the cameras it did share frames with).
pub fn extrinsics_start(
    rig: &Rig,
    target: &Target,
    views: &[SeenView],
) -> Result<(Vec<Isometry3<f64>>, Vec<Link>), CalibError> {
    let n = rig.cameras().len();
    let poses = image_poses(rig, target, views, &vec![None; n]);
    let (apparent, linked) = link_poses(&poses, n);
    let missing: Vec<usize> = (0..n).filter(|&k| linked[k].is_none()).collect();
    if let Some(&k) = missing.first() {
        let names = |list: &[usize]| {
            list.iter()
                .map(|&c| format!("'{}'", rig.cameras()[c].name))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let seen_alone = (0..views.len()).filter(|&v| poses[v][k].is_some()).count();
        let reached: Vec<usize> = (0..n).filter(|&c| linked[c].is_some()).collect();
        return Err(CalibError::Options(format!(
            "camera {} never sees the board in a frame together with {} (directly or through a chain of other cameras): its pose relative to the master cannot be found ({} saw the board in {seen_alone} frame(s) on its own{}); film frames in which it and one of the other cameras both see the board",
            names(&[k]),
            names(&reached),
            names(&[k]),
            if missing.len() > 1 {
                format!("; also unlinked: {}", names(&missing[1..]))
            } else {
                String::new()
            }
        )));
    }
    // Again with the corners' directions in the water: the port's axis in each camera's frame
    // (a shared port's from the apparent link's rotation, which the refraction moves little).
    let axes: Vec<Option<Vector3<f64>>> = (0..n)
        .map(|k| Some(port_axis(rig, k, &apparent[k].rotation)))
        .collect();
    let (in_water, linked_in_water) = link_poses(&image_poses(rig, target, views, &axes), n);
    if linked_in_water.iter().all(Option::is_some) {
        return Ok((in_water, linked_in_water.into_iter().flatten().collect()));
    }
    Ok((apparent, linked.into_iter().flatten().collect()))
}

/// Every camera's `cam_from_master` from board poses `cam_from_target[view][camera]` (`None`
/// where that camera has no pose in that view) over `n` cameras: Prim's maximum spanning tree over
/// the shared-frame counts grown from the master (camera 0), each link the medoid of its frames'
/// relative poses cam_b_from_cam_a = cam_b_from_target · (cam_a_from_target)⁻¹.
///
/// Returns the poses (the identity for the master and for any camera left unlinked) and each
/// camera's link (`None`: it shares no frame, directly or through a chain, with the master).
pub fn link_poses(
    cam_from_target: &[Vec<Option<Isometry3<f64>>>],
    n: usize,
) -> (Vec<Isometry3<f64>>, Vec<Option<Link>>) {
    let poses = cam_from_target;
    let pose = |v: usize, k: usize| poses[v].get(k).copied().flatten();
    let shared = |a: usize, b: usize| -> Vec<usize> {
        (0..poses.len())
            .filter(|&v| pose(v, a).is_some() && pose(v, b).is_some())
            .collect()
    };
    let mut linked: Vec<Option<Link>> = vec![None; n];
    let mut cam_from_master = vec![Isometry3::identity(); n];
    if n == 0 {
        return (cam_from_master, linked);
    }
    linked[0] = Some(Link {
        camera: 0,
        via: 0,
        frames: (0..poses.len()).filter(|&v| pose(v, 0).is_some()).count(),
    });
    while linked.iter().any(Option::is_none) {
        let mut best: Option<(usize, usize, Vec<usize>)> = None;
        for a in (0..n).filter(|&a| linked[a].is_some()) {
            for b in (0..n).filter(|&b| linked[b].is_none()) {
                let frames = shared(a, b);
                if !frames.is_empty()
                    && best.as_ref().is_none_or(|(_, _, f)| frames.len() > f.len())
                {
                    best = Some((a, b, frames));
                }
            }
        }
        let Some((a, b, frames)) = best else { break };
        // cam_b_from_cam_a of each shared frame; the medoid.
        let candidates: Vec<Isometry3<f64>> = frames
            .iter()
            .map(|&v| {
                let (pa, pb) = (
                    pose(v, a).unwrap_or_default(),
                    pose(v, b).unwrap_or_default(),
                );
                pb * pa.inverse()
            })
            .collect();
        let depth = median(
            frames
                .iter()
                .map(|&v| pose(v, a).map_or(1.0, |p| p.translation.vector.norm()))
                .collect(),
        )
        .max(1e-6);
        let b_from_a = medoid(&candidates, depth);
        cam_from_master[b] = b_from_a * cam_from_master[a];
        linked[b] = Some(Link {
            camera: b,
            via: a,
            frames: frames.len(),
        });
    }
    (cam_from_master, linked)
}

/// cam_from_target of every (view, camera) with a pose ([`image_pose`]), each corner's direction
/// bent into the water at `axes[camera]` (the port's axis in that camera's frame; `None`: the
/// pixels' own directions).
fn image_poses(
    rig: &Rig,
    target: &Target,
    views: &[SeenView],
    axes: &[Option<Vector3<f64>>],
) -> Vec<Vec<Option<Isometry3<f64>>>> {
    views
        .iter()
        .map(|view| {
            let mut row = vec![None; rig.cameras().len()];
            for (k, corners) in &view.cameras {
                row[*k] = image_pose(rig, target, *k, corners, axes[*k].as_ref());
            }
            row
        })
        .collect()
}

/// The pinhole pose cam_from_target of one image, when it has enough corners off one line.
pub(super) fn image_pose(
    rig: &Rig,
    target: &Target,
    k: usize,
    corners: &[(usize, nalgebra::Point2<f64>)],
    axis: Option<&Vector3<f64>>,
) -> Option<Isometry3<f64>> {
    if corners.len() < MIN_LINK_CORNERS {
        return None;
    }
    let (object, image): (Vec<Point3<f64>>, Vec<Vector2<f64>>) = corners
        .iter()
        .filter_map(|(i, pixel)| Some((target.point(*i), corner_direction(rig, k, pixel, axis)?)))
        .unzip();
    let pose = pinhole_pose(&object, &image)?;
    // In front of the camera, and finite.
    let finite = pose.translation.vector.iter().all(|x| x.is_finite());
    let in_front = object.iter().all(|p| (pose * p).z > 0.0);
    (finite && in_front).then_some(pose)
}

/// The candidate nearest all others: rotation angle (radians) plus translation over `scale`.
fn medoid(candidates: &[Isometry3<f64>], scale: f64) -> Isometry3<f64> {
    let distance = |a: &Isometry3<f64>, b: &Isometry3<f64>| {
        a.rotation.angle_to(&b.rotation)
            + (a.translation.vector - b.translation.vector).norm() / scale
    };
    candidates
        .iter()
        .min_by(|a, b| {
            let da: f64 = candidates.iter().map(|c| distance(a, c)).sum();
            let db: f64 = candidates.iter().map(|c| distance(b, c)).sum();
            da.total_cmp(&db)
        })
        .copied()
        .unwrap_or_else(Isometry3::identity)
}

fn median(mut values: Vec<f64>) -> f64 {
    if values.is_empty() {
        return 1.0;
    }
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::Board;
    use crate::calib::simulate::{Cameras, SceneSpec, simulate};
    use crate::model::Ports;

    /// Cameras linked only through a chain of frames (tl–tr in some views, tr–bl–br in others;
    /// tl never with bl or br) get their extrinsics exactly from noise-free views of a rig in
    /// air (no refraction: the pinhole poses are exact).
    #[test]
    fn a_chain_of_frames_links_cameras_that_never_met() {
        let rig = crate::io::read_rig("data/rigs/array_2x2.json".as_ref()).unwrap();
        let dry = rig
            .with_new_ports(match rig.ports() {
                crate::model::Ports::Shared(port) => crate::model::Ports::Shared(
                    crate::model::Interface::new(
                        port.normal().into_inner(),
                        port.air_distance(),
                        vec![],
                        1.0,
                        1.0,
                    )
                    .unwrap(),
                ),
                other => other.clone(),
            })
            .unwrap();
        let board = Target::Board(Board {
            rows: 6,
            cols: 8,
            square: 0.03,
        });
        let mut spec = SceneSpec::new(board.clone(), 12, 0.0, 7);
        spec.cameras = Cameras::Any {
            required: vec![0, 1, 2, 3],
            min: 4,
        };
        let scene = simulate(&dry, &spec).unwrap();
        let mut seen = scene.observations.resolve(&dry).unwrap();
        // Views 0-5: tl and tr; views 6-11: tr, bl and br. tl never meets bl or br.
        for (v, view) in seen.iter_mut().enumerate() {
            let keep = |k: usize| if v < 6 { k <= 1 } else { k >= 1 };
            let (cameras, keys) = view
                .cameras
                .drain(..)
                .zip(view.keys.drain(..))
                .filter(|((k, _), _)| keep(*k))
                .unzip();
            (view.cameras, view.keys) = (cameras, keys);
        }
        let (found, links) = extrinsics_start(&dry, &board, &seen).unwrap();
        assert_eq!(links[2].via, 1, "{links:?}");
        assert_eq!(links[3].via, 1, "{links:?}");
        for (k, camera) in dry.cameras().iter().enumerate() {
            let error = found[k].inverse() * camera.cam_from_master;
            assert!(
                error.rotation.angle() < 1e-7 && error.translation.vector.norm() < 1e-7,
                "camera {k}: {error:?} ({links:?})"
            );
        }
    }

    /// Three cameras up to 0.3 m apart, converging through one window on boards 1.3–2.6 m away
    /// (the zoo's seed 12), the start knowing the port's glass but not its axis or air (the
    /// naive port: the optical axis, 10 mm). The pinhole poses of the pixels place the cameras
    /// at about half their distances from the master (the apparent boards differ from camera to
    /// camera), which left every start of its fit undefined; the poses of the directions bent
    /// into the water must place them within 15 % of those distances and 2° of their rotations
    /// (measured: 10 % and 1.1°, what the naive port's untilted axis and air leave), and at
    /// most a third as far off as the pinhole poses.
    #[test]
    fn a_wide_baseline_through_one_window_keeps_its_length() {
        let zoo = crate::calib::simulate::zoo::zoo_rig(12).unwrap();
        let rig = &zoo.rig;
        assert!(matches!(rig.ports(), Ports::Shared(_)) && rig.cameras().len() == 3);
        let board = Target::Board(Board {
            rows: zoo.board.squares_y - 1,
            cols: zoo.board.squares_x - 1,
            square: zoo.board.square,
        });
        let mut spec = SceneSpec::new(board.clone(), 16, 0.0, 3);
        spec.cameras = Cameras::Any {
            required: vec![0, 1, 2],
            min: 3,
        };
        let scene = simulate(rig, &spec).unwrap();
        let naive = rig
            .with_new_ports(match rig.ports() {
                Ports::Shared(port) => Ports::Shared(
                    crate::model::Interface::new(
                        Vector3::z(),
                        0.01,
                        port.layers().to_vec(),
                        port.index_air(),
                        port.index_water(),
                    )
                    .unwrap(),
                ),
                other => other.clone(),
            })
            .unwrap();
        let seen = scene.observations.resolve(&naive).unwrap();
        let (found, _) = extrinsics_start(&naive, &board, &seen).unwrap();
        let pinhole_poses = image_poses(&naive, &board, &seen, &[None; 3]);
        let (pinhole, _) = link_poses(&pinhole_poses, 3);
        for (k, camera) in rig.cameras().iter().enumerate().skip(1) {
            let truth = camera.cam_from_master.inverse().translation.vector;
            let off = |pose: &Isometry3<f64>| (pose.inverse().translation.vector - truth).norm();
            let rotation = (found[k].rotation.inverse() * camera.cam_from_master.rotation).angle();
            let (start, before) = (off(&found[k]), off(&pinhole[k]));
            assert!(
                start < 0.15 * truth.norm() && rotation < 2f64.to_radians() && start < before / 3.0,
                "camera {k}: centre {:.3} m off of {:.3} m (pinhole poses {before:.3} m off), rotation {:.2}° off",
                start,
                truth.norm(),
                rotation.to_degrees()
            );
        }
    }
}
