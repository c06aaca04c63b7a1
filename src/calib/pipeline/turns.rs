//! A chessboard's corner order made to agree across the cameras of each frame.
//!
//! A chessboard looks the same turned by 180° in its plane when its squares per side add up to
//! an even number (8 × 6 corners, 9 × 7 squares), and by 90° when it is square; the colours of
//! its corner squares cannot tell its ends apart then, and without a rig each image's corner 0
//! is chosen on its own ([`crate::detect`]: where the board's rows run most nearly to the right
//! in the image). Cameras rolled against each other (90°, 180°), or a board whose rows run near
//! the vertical, then number the same frame's corners from different ends, and no rigid rig
//! explains both: the fit is refused at hundreds of pixels.
//!
//! [`agree_turns`] numbers every camera's corners as the others of its frames do. Each image's
//! board rotation by the pinhole model is computed under each turn of its numbering; cameras are
//! taken in turn, the one sharing most frames with those already placed first, and the rotation
//! cam_from_master that most of its shared frames allow (within [`AGREE_DEG`]) is kept, each
//! frame taking the turn nearest it. The turns are 90° or 180° apart, the pinhole rotations of a
//! board seen through a port a few degrees off the truth: the vote is not close.

use nalgebra::{Point2, UnitQuaternion};

use super::extrinsics::image_pose;
use crate::base::Board;
use crate::calib::problem::observations::{CameraKey, Observations, WaterFrame};
use crate::calib::problem::target::Target;
use crate::model::Rig;

/// Largest angle (degrees) between a frame's rotation cam_from_master and a candidate's for
/// the frame to count for it: a quarter of the smallest turn (90°), well above the pinhole
/// rotation's error through a port (a few degrees).
pub const AGREE_DEG: f64 = 22.5;

/// The turns of `board` in its plane that map its corner grid onto itself, as permutations of
/// the corner indices (turn `t` numbers corner `i` as `turns[t][i]`): the identity and 180°;
/// 90° and 270° too when the board is square.
pub fn board_turns(board: &Board) -> Vec<Vec<usize>> {
    let (rows, cols) = (board.rows, board.cols);
    let index = |r: usize, c: usize| r * cols + c;
    let by = |f: &dyn Fn(usize, usize) -> (usize, usize)| -> Vec<usize> {
        (0..board.corners())
            .map(|i| {
                let (r, c) = board.grid_position(i);
                let (r2, c2) = f(r, c);
                index(r2, c2)
            })
            .collect()
    };
    let mut turns = vec![by(&|r, c| (r, c)), by(&|r, c| (rows - 1 - r, cols - 1 - c))];
    if rows == cols {
        // (c, r) → (n − 1 − r, c) and (r, n − 1 − c): the board point (x, y) about its centre
        // to (−y, x) and (y, −x), rotations (not mirror images) either way.
        turns.push(by(&|r, c| (c, cols - 1 - r)));
        turns.push(by(&|r, c| (cols - 1 - c, r)));
    }
    turns
}

/// What [`agree_turns`] changed in one camera's images.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Turned {
    /// The rig camera.
    pub camera: usize,
    /// Its images whose corners were renumbered.
    pub turned: usize,
    /// Its images with a board pose (the ones that took part).
    pub images: usize,
}

/// Renumbers the corners of `frames` (each frame's corners per camera of `rig`, raw pixels) so
/// that every camera of a frame numbers them from the same physical corner (the module's
/// documentation); `rig` gives the lenses. Returns the cameras some of whose images were
/// renumbered. Images without a pinhole pose (fewer than six corners, on a line) are left as
/// they are.
pub fn agree_turns(rig: &Rig, board: &Board, frames: &mut [WaterFrame]) -> Vec<Turned> {
    let turns = board_turns(board);
    let target = Target::Board(*board);
    let n = rig.cameras().len();
    let renumbered = |corners: &[(usize, Point2<f64>)], turn: &[usize]| -> Vec<_> {
        corners
            .iter()
            .filter_map(|&(i, p)| Some((*turn.get(i)?, p)))
            .collect()
    };
    // rotations[f][k][t]: cam_k_from_board in frame f with its corners numbered by turn t.
    let rotations: Vec<Vec<Option<Vec<UnitQuaternion<f64>>>>> = frames
        .iter()
        .map(|frame| {
            (0..n)
                .map(|k| {
                    let corners = frame.corners.get(k)?;
                    turns
                        .iter()
                        .map(|turn| {
                            image_pose(rig, &target, k, &renumbered(corners, turn), None)
                                .map(|pose| pose.rotation)
                        })
                        .collect()
                })
                .collect()
        })
        .collect();
    let seen = |f: usize, k: usize| rotations[f][k].as_deref();
    // The board's rotation master_from_board in each frame placed so far, each camera's
    // cam_from_master, and the turn each image takes.
    let mut board_in_master: Vec<Option<UnitQuaternion<f64>>> = vec![None; frames.len()];
    let mut placed = vec![false; n];
    let mut choice = vec![vec![0usize; n]; frames.len()];
    let angle = |a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>| a.angle_to(b).to_degrees();
    while let Some(k) = (0..n).filter(|&k| !placed[k]).max_by_key(|&k| {
        let shared = (0..frames.len())
            .filter(|&f| seen(f, k).is_some() && board_in_master[f].is_some())
            .count();
        let own = (0..frames.len()).filter(|&f| seen(f, k).is_some()).count();
        // Shared frames first; among cameras sharing none, the one with the most images
        // starts a new group (its numbering is the group's).
        (shared, own, std::cmp::Reverse(k))
    }) {
        placed[k] = true;
        let shared: Vec<usize> = (0..frames.len())
            .filter(|&f| seen(f, k).is_some() && board_in_master[f].is_some())
            .collect();
        // cam_from_master of frame f under turn t.
        let candidate = |f: usize, t: usize| -> UnitQuaternion<f64> {
            seen(f, k).map_or_else(UnitQuaternion::identity, |r| r[t])
                * board_in_master[f].unwrap_or_default().inverse()
        };
        let nearest = |f: usize, to: &UnitQuaternion<f64>| -> (usize, f64) {
            (0..turns.len())
                .map(|t| (t, angle(&candidate(f, t), to)))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap_or((0, f64::INFINITY))
        };
        let cam_from_master = shared
            .iter()
            .flat_map(|&f| (0..turns.len()).map(move |t| (f, t)))
            .map(|(f, t)| {
                let x = candidate(f, t);
                let (support, spread) = shared.iter().fold((0usize, 0.0), |(n, s), &g| {
                    let (_, a) = nearest(g, &x);
                    if a < AGREE_DEG {
                        (n + 1, s + a)
                    } else {
                        (n, s)
                    }
                });
                (x, support, spread)
            })
            .max_by(|a, b| a.1.cmp(&b.1).then(b.2.total_cmp(&a.2)))
            .map_or_else(UnitQuaternion::identity, |(x, _, _)| x);
        // The shared frames take the turn nearest the camera's rotation; in the others its
        // numbering places the board.
        let placements: Vec<(usize, Result<usize, UnitQuaternion<f64>>)> = (0..frames.len())
            .filter_map(|f| {
                let r = seen(f, k)?;
                Some(if board_in_master[f].is_some() {
                    (f, Ok(nearest(f, &cam_from_master).0))
                } else {
                    (f, Err(cam_from_master.inverse() * r[0]))
                })
            })
            .collect();
        for (f, placement) in placements {
            match placement {
                Ok(t) => choice[f][k] = t,
                Err(board) => board_in_master[f] = Some(board),
            }
        }
    }
    let mut changed = Vec::new();
    for k in 0..n {
        let images = (0..frames.len()).filter(|&f| seen(f, k).is_some()).count();
        let mut turned = 0;
        for (frame, row) in frames.iter_mut().zip(&choice) {
            let t = row[k];
            if t != 0
                && let Some(corners) = frame.corners.get_mut(k)
            {
                *corners = renumbered(corners, &turns[t]);
                corners.sort_by_key(|&(i, _)| i);
                turned += 1;
            }
        }
        if turned > 0 {
            changed.push(Turned {
                camera: k,
                turned,
                images,
            });
        }
    }
    changed
}

/// [`agree_turns`] over observations of a chessboard by the cameras of `rig` (the observations
/// route: a file written by a detector that numbers each image on its own, as
/// `cv::findChessboardCorners` does on a colour-symmetric board). Where some camera's turn
/// says so, returns a copy of `observations` with those images' corners renumbered, and per
/// camera turned its name and what changed; `None` where nothing turns (nothing is copied).
/// Images whose camera the rig does not have are left to [`Observations::resolve`]'s error.
/// Nothing turns for a 3-D target or one camera.
pub fn agree_observation_turns(
    rig: &Rig,
    observations: &Observations,
) -> Option<(Observations, Vec<(String, Turned)>)> {
    let board = observations.target.board().copied()?;
    let n = rig.cameras().len();
    if n < 2 {
        return None;
    }
    let camera_of = |key: &CameraKey| match key {
        CameraKey::Name(name) => rig.cameras().iter().position(|c| &c.name == name),
        CameraKey::Position(k) => (*k < n).then_some(*k),
    };
    let mut frames: Vec<WaterFrame> = observations
        .views
        .iter()
        .enumerate()
        .map(|(v, view)| {
            let mut corners = vec![Vec::new(); n];
            for image in &view.images {
                if let Some(k) = camera_of(&image.camera) {
                    corners[k] = image
                        .corners
                        .iter()
                        .enumerate()
                        .filter_map(|(i, p)| Some((i, (*p)?)))
                        .collect();
                }
            }
            WaterFrame {
                label: format!("view {v}"),
                corners,
            }
        })
        .collect();
    let turned = agree_turns(rig, &board, &mut frames);
    if turned.is_empty() {
        return None;
    }
    let mut agreed = observations.clone();
    for (view, frame) in agreed.views.iter_mut().zip(&frames) {
        for image in &mut view.images {
            let Some(k) = camera_of(&image.camera) else {
                continue;
            };
            let mut corners = vec![None; image.corners.len()];
            for &(i, p) in &frame.corners[k] {
                if let Some(slot) = corners.get_mut(i) {
                    *slot = Some(p);
                }
            }
            image.corners = corners;
        }
    }
    let named = turned
        .into_iter()
        .map(|t| (rig.cameras()[t.camera].name.clone(), t))
        .collect();
    Some((agreed, named))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::simulate::{Cameras, SceneSpec, simulate};

    /// A colour-symmetric board (8 + 6 corners: 9 × 7 squares) and a square one.
    const BOARDS: [Board; 2] = [
        Board {
            rows: 6,
            cols: 8,
            square: 0.03,
        },
        Board {
            rows: 5,
            cols: 5,
            square: 0.04,
        },
    ];

    /// Each turn is a rotation of the board's points about its centre (a permutation, distances
    /// kept, not a mirror image).
    #[test]
    fn the_turns_are_rotations_of_the_grid() {
        for board in BOARDS {
            let turns = board_turns(&board);
            assert_eq!(turns.len(), if board.rows == board.cols { 4 } else { 2 });
            let target = Target::Board(board);
            let centre = board.centre_in_board();
            for turn in &turns {
                let mut sorted = turn.clone();
                sorted.sort_unstable();
                assert_eq!(sorted, (0..board.corners()).collect::<Vec<_>>());
                // The rotation taking corner 0's and corner 1's offsets from the centre to their
                // images' takes every corner's.
                let offset = |i: usize| target.point(i) - centre;
                let (a, b) = (offset(0), offset(1));
                let (ta, tb) = (offset(turn[0]), offset(turn[1]));
                let cross = a.x * b.y - a.y * b.x;
                assert!(
                    ((ta.x * tb.y - ta.y * tb.x) - cross).abs() < 1e-12,
                    "a mirror image"
                );
                let angle = ta.y.atan2(ta.x) - a.y.atan2(a.x);
                let (s, c) = angle.sin_cos();
                for (i, &to) in turn.iter().enumerate().take(board.corners()) {
                    let (p, q) = (offset(i), offset(to));
                    let rotated = (c * p.x - s * p.y, s * p.x + c * p.y);
                    assert!((rotated.0 - q.x).abs() < 1e-12 && (rotated.1 - q.y).abs() < 1e-12);
                }
            }
        }
    }

    /// A 2 × 2 array's cameras (one of them rolled by 180° here) see each of [`BOARDS`] in 12
    /// frames; a third of the images are renumbered by
    /// each of the board's turns, as a detector choosing each image's corner 0 on its own would.
    /// After [`agree_turns`] every image of a frame numbers its corners as the first camera
    /// does (checked against the simulation's own numbering, up to one turn per frame).
    #[test]
    fn every_camera_of_a_frame_numbers_the_corners_alike() {
        let rig = crate::io::read_rig("data/rigs/array_2x2.json".as_ref()).unwrap();
        let mut cameras = rig.cameras().to_vec();
        let roll = nalgebra::Isometry3::rotation(nalgebra::Vector3::z() * std::f64::consts::PI);
        cameras[2].cam_from_master = roll * cameras[2].cam_from_master;
        let rig = Rig::with_ports(cameras, rig.ports().clone()).unwrap();
        for board in BOARDS {
            let mut spec = SceneSpec::new(Target::Board(board), 12, 0.0, 11);
            spec.cameras = Cameras::Any {
                required: vec![0, 1, 2, 3],
                min: 4,
            };
            let scene = simulate(&rig, &spec).unwrap();
            let seen = scene.observations.resolve(&rig).unwrap();
            let turns = board_turns(&board);
            let truth: Vec<WaterFrame> = seen
                .iter()
                .enumerate()
                .map(|(v, view)| {
                    let mut corners = vec![Vec::new(); 4];
                    for (k, c) in &view.cameras {
                        corners[*k] = c.clone();
                        corners[*k].sort_by_key(|&(i, _)| i);
                    }
                    WaterFrame {
                        label: v.to_string(),
                        corners,
                    }
                })
                .collect();
            let mut frames = truth.clone();
            let mut scrambled = 0;
            for (v, frame) in frames.iter_mut().enumerate() {
                for (k, corners) in frame.corners.iter_mut().enumerate() {
                    let t = (v + 2 * k) % 3 % turns.len();
                    if t != 0 {
                        scrambled += 1;
                        *corners = corners.iter().map(|&(i, p)| (turns[t][i], p)).collect();
                        corners.sort_by_key(|&(i, _)| i);
                    }
                }
            }
            assert!(scrambled > 10);
            let changed = agree_turns(&rig, &board, &mut frames);
            assert!(!changed.is_empty());
            for (found, truth) in frames.iter().zip(&truth) {
                // The frame's one turn: the one taking camera 0's numbering to the truth's.
                let agrees = |t: &Vec<usize>| {
                    found.corners.iter().zip(&truth.corners).all(|(a, b)| {
                        let mut back: Vec<_> = a.iter().map(|&(i, p)| (t[i], p)).collect();
                        back.sort_by_key(|&(i, _)| i);
                        back == *b
                    })
                };
                assert!(
                    turns.iter().any(agrees),
                    "frame {}: the cameras still number the corners differently ({}x{} board)",
                    found.label,
                    board.cols,
                    board.rows
                );
            }
        }
    }

    /// Observations whose second camera numbers every other view from the far end (as
    /// `cv::findChessboardCorners` may on a colour-symmetric board) come back numbered as the
    /// simulation numbered them, camera 1 named as turned.
    #[test]
    fn observations_numbered_from_either_end_are_agreed() {
        let rig = crate::io::read_rig("data/example_rig.json".as_ref()).unwrap();
        let board = BOARDS[0];
        let spec = SceneSpec::pair(Target::Board(board), 12, 0.1, 3, 0, 1);
        let truth = simulate(&rig, &spec).unwrap().observations;
        let half = &board_turns(&board)[1];
        let mut observations = truth.clone();
        for view in observations.views.iter_mut().step_by(2) {
            let image = &mut view.images[1];
            let mut corners = vec![None; image.corners.len()];
            for (i, p) in image.corners.iter().enumerate() {
                corners[half[i]] = *p;
            }
            image.corners = corners;
        }
        assert_ne!(observations, truth);
        let (agreed, changed) = agree_observation_turns(&rig, &observations).expect("turned");
        assert_eq!(changed.len(), 1, "{changed:?}");
        assert_eq!(changed[0].0, rig.cameras()[1].name);
        assert_eq!(changed[0].1.turned, 6);
        assert_eq!(agreed, truth);
        // Agreed observations stay as they are.
        assert_eq!(agree_observation_turns(&rig, &agreed), None);
    }
}
