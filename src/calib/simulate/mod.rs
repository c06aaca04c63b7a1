//! Simulated calibration scenes: random board poses in the water seen fully by both cameras,
//! corners projected exactly through the interface, Gaussian pixel noise. [`simulate_rig`] does
//! the same for any rig (1..N cameras, a shared port or a port per camera) and any [`Target`].
//!
//! [`Target`]: crate::calib::Target

pub mod rig;
pub mod rng;

pub use rig::{RigScene, RigSceneSpec, check_rig_scene_size, simulate_rig};

use nalgebra::{Isometry3, Point2, Translation3, UnitQuaternion, Vector3};

use crate::calib::error::CalibError;
use crate::calib::problem::board::Board;
use crate::calib::problem::observations::{Observations, StereoView};
use crate::calib::simulate::rng::Rng;
use crate::model::{RefractiveCamera, Rig};

/// How to simulate a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneSpec {
    /// The board.
    pub board: Board,
    /// Number of views.
    pub views: usize,
    /// Standard deviation of the Gaussian pixel noise added to each coordinate, pixels.
    pub noise_px: f64,
    /// Seed of the random generator (equal seeds give equal scenes).
    pub seed: u64,
    /// Largest angle between the board normal and the master camera's viewing axis, radians.
    pub max_board_tilt: f64,
    /// Corners keep this many pixels from the image border (before noise).
    pub margin_px: f64,
}

impl SceneSpec {
    /// Defaults: boards turned up to 45° toward the camera, corners 10 px inside the images.
    pub fn new(board: Board, views: usize, noise_px: f64, seed: u64) -> Self {
        Self {
            board,
            views,
            noise_px,
            seed,
            max_board_tilt: 45f64.to_radians(),
            margin_px: 10.0,
        }
    }
}

/// A simulated scene: what the cameras saw and the truth behind it.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// The corners as detected (with noise).
    pub observations: Observations,
    /// X_master = R·X_board + t for each view.
    pub master_from_board: Vec<Isometry3<f64>>,
}

/// Most corners a board may have (rows × cols): far beyond any printed chessboard a detector
/// finds (OpenCV's are tens by tens), and every pose tried projects all of them.
pub const MAX_BOARD_CORNERS: usize = 10_000;

/// Most corners a simulated scene may hold (views × board corners): each takes about 100 bytes in
/// memory (both images' pixels, the views' bookkeeping) and about 80 in observations.json, so the
/// largest scene is about 1 GB in memory and 0.8 GB on disk (185 000 views of a 9×6 board).
pub const MAX_SIMULATED_CORNERS: usize = 10_000_000;

/// Checks the sizes of a scene before anything is allocated: a board of at most
/// [`MAX_BOARD_CORNERS`] corners, 1 to [`MAX_SIMULATED_CORNERS`] / corners views.
pub fn check_scene_size(board: &Board, views: usize) -> Result<(), CalibError> {
    let corners = board.rows.checked_mul(board.cols).filter(|&c| c <= MAX_BOARD_CORNERS).ok_or_else(|| CalibError::BadBoard {
        reason: format!(
            "{} × {} corners: at most {MAX_BOARD_CORNERS} corners are simulated (every pose tried projects all of them)",
            board.rows, board.cols
        ),
    })?;
    let most = MAX_SIMULATED_CORNERS / corners.max(1);
    if views == 0 || views > most {
        return Err(CalibError::Options(format!(
            "{views} views of a {}×{} board: 1 to {most} views ({MAX_SIMULATED_CORNERS} corners in all; each takes about 100 bytes in memory and 80 in observations.json)",
            board.cols, board.rows
        )));
    }
    Ok(())
}

/// Most random poses tried per view before giving up.
const MAX_TRIES_PER_VIEW: usize = 20_000;

/// Largest simulated corner noise, pixels.
pub const MAX_NOISE_PX: f64 = 100.0;

/// Simulates `spec.views` views of the board by cameras `left` and `right` of `rig`, behind the
/// rig's interface (the truth). Every corner of every view lies inside both images.
///
/// Errors: [`CalibError::Options`] when no pose that both cameras see fully is found (board too
/// large for the common field of view, or cameras that do not overlap), or when the scene is
/// larger than [`check_scene_size`] allows.
pub fn simulate(
    rig: &Rig,
    left: usize,
    right: usize,
    spec: &SceneSpec,
) -> Result<Scene, CalibError> {
    let board = &spec.board;
    if board.rows < 2 || board.cols < 2 || !(board.square > 0.0) {
        return Err(CalibError::BadBoard {
            reason: format!(
                "{} × {} corners of {} m",
                board.rows, board.cols, board.square
            ),
        });
    }
    check_scene_size(board, spec.views)?;
    if !(spec.noise_px >= 0.0 && spec.noise_px <= MAX_NOISE_PX) {
        return Err(CalibError::Options(format!(
            "noise must lie in [0, {MAX_NOISE_PX}] px (a corner detector's error is a fraction of a pixel), got {}",
            crate::calib::error::number(spec.noise_px)
        )));
    }
    // Noisy corners must stay inside the images, as a detector reports them: the poses keep
    // every exact corner at least 5 σ from the border, and a noise sample that would carry a
    // corner over that margin is drawn again (a Gaussian truncated at the margin, ≥ 5 σ: the
    // default 10 px margin is 100 σ at 0.1 px, where no sample is ever redrawn).
    let margin = spec.margin_px.max(5.0 * spec.noise_px);
    let cameras = [rig.refractive_camera(left), rig.refractive_camera(right)];
    let mut rng = Rng::new(spec.seed);
    let interface = rig.port_in_master(left);
    // Depth range from the field of view in water of the master camera: the board must fit.
    let intrinsics = rig.cameras()[left].intrinsics;
    let half_fov_air = (0.5
        * (intrinsics.width as f64 / intrinsics.fx).min(intrinsics.height as f64 / intrinsics.fy))
    .atan();
    let tan_half_fov_water = (half_fov_air.sin() * interface.index_air() / interface.index_water())
        .asin()
        .tan();
    let diagonal = ((board.rows - 1) as f64).hypot((board.cols - 1) as f64) * board.square;
    let near = (0.5 * diagonal / tan_half_fov_water).max(interface.outer_distance() + 0.05);
    let far = 3.0 * near;

    let mut views = Vec::with_capacity(spec.views);
    let mut poses = Vec::with_capacity(spec.views);
    for v in 0..spec.views {
        let (pose, pixels) = (0..MAX_TRIES_PER_VIEW)
            .find_map(|_| {
                let pose = random_pose(
                    &mut rng,
                    &board.centre_in_board().coords,
                    near,
                    far,
                    tan_half_fov_water,
                    spec.max_board_tilt,
                );
                visible_corners(&cameras, rig, [left, right], board, &pose, margin).map(|p| (pose, p))
            })
            .ok_or_else(|| {
                CalibError::Options(format!(
                    "view {v}: found no pose in which both cameras see the whole {}×{} board of {} m squares",
                    board.rows, board.cols, crate::calib::error::number(board.square)
                ))
            })?;
        let mut draw = || loop {
            let offset = spec.noise_px * rng.normal();
            if offset.abs() <= margin {
                break offset;
            }
        };
        let mut noisy = |p: &Point2<f64>| Some(Point2::new(p.x + draw(), p.y + draw()));
        let left_corners = pixels[0].iter().map(&mut noisy).collect();
        let right_corners = pixels[1].iter().map(&mut noisy).collect();
        views.push(StereoView {
            left: left_corners,
            right: right_corners,
        });
        poses.push(pose);
    }
    let names = [
        rig.cameras()[left].name.clone(),
        rig.cameras()[right].name.clone(),
    ];
    Ok(Scene {
        observations: Observations {
            board: *board,
            views,
            cameras: Some(names),
        },
        master_from_board: poses,
    })
}

/// A target pose: the point `centre` of the target (its frame) at a random depth in [near, far]
/// inside the central part of the master camera's view, the target's z axis within `max_tilt`
/// of the camera's, turned about it by up to ±30°.
pub(crate) fn random_pose(
    rng: &mut Rng,
    centre_in_target: &Vector3<f64>,
    near: f64,
    far: f64,
    tan_half_fov: f64,
    max_tilt: f64,
) -> Isometry3<f64> {
    let z = rng.range(near, far);
    let reach = 0.7 * z * tan_half_fov;
    let centre = Vector3::new(rng.range(-reach, reach), rng.range(-reach, reach), z);
    // Tilt about a random in-plane axis, uniform in solid angle within the cone.
    let cos_tilt = rng.range(max_tilt.cos(), 1.0);
    let axis_angle = rng.range(0.0, std::f64::consts::TAU);
    let axis = Vector3::new(axis_angle.cos(), axis_angle.sin(), 0.0);
    let tilt = UnitQuaternion::from_scaled_axis(axis * cos_tilt.acos());
    let spin = UnitQuaternion::from_scaled_axis(Vector3::z() * rng.range(-0.5, 0.5));
    let rotation = tilt * spin;
    let to_centre = Translation3::from(-centre_in_target);
    Isometry3::from_parts(Translation3::from(centre), rotation) * to_centre
}

/// The exact pixels of every corner in both cameras, or `None` when a corner does not project or
/// falls within `margin` pixels of an image border.
fn visible_corners(
    cameras: &[RefractiveCamera; 2],
    rig: &Rig,
    indices: [usize; 2],
    board: &Board,
    pose: &Isometry3<f64>,
    margin: f64,
) -> Option<[Vec<Point2<f64>>; 2]> {
    let mut out = [
        Vec::with_capacity(board.corners()),
        Vec::with_capacity(board.corners()),
    ];
    for (k, camera) in cameras.iter().enumerate() {
        let i = &rig.cameras()[indices[k]].intrinsics;
        for c in 0..board.corners() {
            let pixel = camera.project(&(pose * board.point_in_board(c))).ok()?;
            let inside = pixel.x >= margin
                && pixel.y >= margin
                && pixel.x <= i.width as f64 - 1.0 - margin
                && pixel.y <= i.height as f64 - 1.0 - margin;
            if !inside {
                return None;
            }
            out[k].push(pixel);
        }
    }
    Some(out)
}
