//! Board poses for a calibration set as a person films one: the board held at random places,
//! distances and angles in front of a rig, often partly outside some images (a ChArUco board's
//! corners carry their ids, so partial views count).

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use super::rng::Rng;
use crate::base::Board;
use crate::model::Rig;

/// Largest tilt of the board from facing the master camera, radians (40°).
pub const MAX_TILT: f64 = 0.698_131_700_797_731_8;

/// Fewest corners some camera must see for a pose to be kept.
const MIN_SEEN: usize = 6;

/// The range of distances (metres, along the master's z axis) at which `board` (`outer` metres
/// across, its outer squares) fills between about 90 % and 35 % of the master camera's image
/// width, seen through a medium of `index_water` (a flat port magnifies by about it).
pub fn depth_range(rig: &Rig, outer: f64, index_water: f64) -> (f64, f64) {
    let camera = &rig.cameras()[0].intrinsics;
    let span = camera.fx * outer / f64::from(camera.width) * index_water;
    (span / 0.9, span / 0.35)
}

/// `count` poses master_from_board of `board` in front of `rig`, at distances `depth` (metres along
/// the master's z axis), across ±30 % of the distance sideways, turned up to [`MAX_TILT`] and
/// ±35° in plane; each seen by some camera in at least six corners (by `project`, which says
/// where a board-frame point lands in camera k: `None` outside its image). Deterministic in
/// `seed`.
pub fn board_poses(
    rig: &Rig,
    board: &Board,
    count: usize,
    depth: (f64, f64),
    seed: u64,
    project: &dyn Fn(usize, &nalgebra::Point3<f64>) -> bool,
) -> Vec<Isometry3<f64>> {
    let mut rng = Rng::new(seed);
    let centre = board.centre_in_board();
    let mut poses = Vec::with_capacity(count);
    let mut tries = 0;
    while poses.len() < count && tries < 1000 * count.max(1) {
        tries += 1;
        let z = rng.range(depth.0, depth.1);
        let position = Vector3::new(rng.range(-0.3, 0.3) * z, rng.range(-0.25, 0.25) * z, z);
        let towards = rng.range(0.0, std::f64::consts::TAU);
        let axis = Vector3::new(towards.cos(), towards.sin(), 0.0);
        let rotation = UnitQuaternion::from_scaled_axis(axis * rng.range(0.0, MAX_TILT))
            * UnitQuaternion::from_scaled_axis(Vector3::z() * rng.range(-0.6, 0.6));
        let pose = Isometry3::from_parts(Translation3::from(position), rotation)
            * Translation3::from(-centre.coords);
        let seen = (0..rig.cameras().len()).any(|k| {
            (0..board.corners())
                .filter(|&i| project(k, &(pose * board.point_in_board(i))))
                .count()
                >= MIN_SEEN
        });
        if seen {
            poses.push(pose);
        }
    }
    poses
}
