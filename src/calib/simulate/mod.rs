//! Simulated calibration scenes for any rig: 1..N cameras behind one shared port or a port each,
//! looking at a board or a 3-D target. Random target poses in the water in front of a camera,
//! corners projected exactly through each camera's port, kept a margin from the image border,
//! and truncated Gaussian pixel noise, everything from one seed. A camera that does not see the
//! whole target in a view is left out of that view ([`Cameras::Any`]), or every view is seen
//! whole by one pair of cameras ([`Cameras::Pair`], the stereo scenes of the thesis).

pub use crate::base::rng;
pub mod spread;
pub mod zoo;

use nalgebra::{Isometry3, Point2, Point3, Translation3, UnitQuaternion, Vector3};

use crate::base::Rng;
use crate::calib::error::{CalibError, number};
use crate::calib::problem::observations::{CameraKey, Image, Observations, View};
use crate::calib::problem::target::Target;
use crate::model::{RefractiveCamera, Rig};

/// Which cameras image a view.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Cameras {
    /// Every camera that sees the whole target, the cameras of `required` always among them and
    /// at least `min` cameras in all; poses are drawn in front of the master camera.
    Any {
        /// Rig cameras that must see the whole target in every view.
        required: Vec<usize>,
        /// Every view is seen whole by at least this many cameras (at least 1).
        min: usize,
    },
    /// Exactly these two rig cameras, both seeing every corner of every view, the depths sized by
    /// the first: the stereo scenes of the thesis, placed as `flatport simulate` has always
    /// placed them for a stereo pair (so that a seed gives the same scene as before).
    Pair(usize, usize),
}

/// How to simulate a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneSpec {
    /// What the cameras look at.
    pub target: Target,
    /// Number of views.
    pub views: usize,
    /// Standard deviation of the Gaussian pixel noise added to each coordinate, pixels.
    pub noise_px: f64,
    /// Seed of the random generator (equal seeds give equal scenes).
    pub seed: u64,
    /// Largest angle between the target's z axis and the viewing axis of the camera the poses
    /// are drawn in front of, radians.
    pub max_target_tilt: f64,
    /// Corners keep this many pixels from the image border (before noise; at least 5 σ).
    pub margin_px: f64,
    /// Which cameras image each view.
    pub cameras: Cameras,
}

impl SceneSpec {
    /// Defaults: targets turned up to 45° toward the master camera, corners 10 px inside the
    /// images, every view seen by the master ([`Cameras::Any`] requiring camera 0).
    pub fn new(target: Target, views: usize, noise_px: f64, seed: u64) -> Self {
        Self {
            target,
            views,
            noise_px,
            seed,
            max_target_tilt: 45f64.to_radians(),
            margin_px: 10.0,
            cameras: Cameras::Any {
                required: vec![0],
                min: 1,
            },
        }
    }

    /// [`SceneSpec::new`] imaged by the pair `first`, `second` alone ([`Cameras::Pair`]).
    pub fn pair(
        target: Target,
        views: usize,
        noise_px: f64,
        seed: u64,
        first: usize,
        second: usize,
    ) -> Self {
        Self {
            cameras: Cameras::Pair(first, second),
            ..Self::new(target, views, noise_px, seed)
        }
    }
}

/// A simulated scene: what the cameras saw and the truth behind it.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// The corners as detected (with noise), each image keyed by its rig camera's name; a camera
    /// that did not see the whole target in a view is absent from it.
    pub observations: Observations,
    /// X_master = R·X_target + t for each view.
    pub master_from_target: Vec<Isometry3<f64>>,
    /// The rig cameras that saw each view, in the order of its images.
    pub seen_by: Vec<Vec<usize>>,
}

/// Most corners a target may have: far beyond any printed chessboard a detector finds (OpenCV's
/// are tens by tens), and every pose tried projects all of them.
pub const MAX_BOARD_CORNERS: usize = 10_000;

/// Most corner images a simulated scene may hold (views × corners × cameras imaging them; a
/// stereo pair's two images of a corner count once): each takes about 100 bytes in memory and
/// about 80 in observations.json, so the largest scene is about 1 GB in memory and 0.8 GB on disk
/// (185 000 stereo views of a 9×6 board).
pub const MAX_SIMULATED_CORNERS: usize = 10_000_000;

/// Most random poses tried per view before giving up.
const MAX_TRIES_PER_VIEW: usize = 20_000;

/// Largest simulated corner noise, pixels.
pub const MAX_NOISE_PX: f64 = 100.0;

/// Checks the sizes of a scene before anything is allocated: a target of 4 to
/// [`MAX_BOARD_CORNERS`] corners, 1 to [`MAX_SIMULATED_CORNERS`] / (corners × `images`) views,
/// where `images` is the number of cameras that may image a view (1 for a stereo pair).
pub fn check_scene_size(target: &Target, images: usize, views: usize) -> Result<(), CalibError> {
    let corners = target.len();
    if !(4..=MAX_BOARD_CORNERS).contains(&corners) {
        return Err(CalibError::BadBoard {
            reason: format!(
                "a target of {corners} corners: 4 to {MAX_BOARD_CORNERS} are simulated (every pose tried projects all of them)"
            ),
        });
    }
    let most = MAX_SIMULATED_CORNERS / (corners * images.max(1));
    if views == 0 || views > most {
        return Err(CalibError::Options(format!(
            "{views} views of a target of {corners} corners: 1 to {most} views ({MAX_SIMULATED_CORNERS} corner images in all; each takes about 100 bytes in memory and 80 in observations.json)"
        )));
    }
    Ok(())
}

/// Where the target poses are drawn: the target's point `centre` (its own frame) along the master
/// camera's view at depths in [near, 3 near], within the central part of a field of view in water
/// whose half-angle has tangent `tan_half_fov`, sized by one camera's lens and port (the master's;
/// a pair's first camera's).
struct Placement {
    centre: Vector3<f64>,
    near: f64,
    tan_half_fov: f64,
}

impl Placement {
    /// The placement of `spec` for `rig` (target points `points`, `radius` about their centroid
    /// `centroid`).
    fn of(rig: &Rig, spec: &SceneSpec, centroid: Vector3<f64>, radius: f64) -> Self {
        let reference = match spec.cameras {
            Cameras::Any { .. } => 0,
            Cameras::Pair(first, _) => first,
        };
        let port = rig.port_in_master(reference);
        let intrinsics = rig.cameras()[reference].intrinsics;
        let half_fov_air = (0.5
            * (intrinsics.width as f64 / intrinsics.fx)
                .min(intrinsics.height as f64 / intrinsics.fy))
        .atan();
        let sin_water = half_fov_air.sin() * port.index_air() / port.index_water();
        match (&spec.cameras, &spec.target) {
            // The stereo scenes as they have always been drawn: the board's own centre, and its
            // centre 5 cm beyond the first camera's port.
            (Cameras::Pair(..), Target::Board(board)) => {
                let tan_half_fov = sin_water.asin().tan();
                let diagonal =
                    ((board.rows - 1) as f64).hypot((board.cols - 1) as f64) * board.square;
                Self {
                    centre: board.centre_in_board().coords,
                    near: (0.5 * diagonal / tan_half_fov).max(port.outer_distance() + 0.05),
                    tan_half_fov,
                }
            }
            _ => {
                let tan_half_fov = sin_water.min(0.999).asin().tan();
                // Where each camera's last interface (master frame: n·X = outer) crosses the
                // master's axis X = (0, 0, z): the whole target beyond the farthest.
                let far_port = (0..rig.cameras().len())
                    .map(|k| {
                        let p = rig.port_in_master(k);
                        (p.outer_distance() / p.normal().z).max(0.0)
                    })
                    .fold(0.0, f64::max);
                Self {
                    centre: centroid,
                    near: (radius / tan_half_fov).max(far_port + radius + 0.05),
                    tan_half_fov,
                }
            }
        }
    }
}

/// Simulates `spec.views` views of `spec.target` by the cameras of `rig`, each looking through
/// its own port ([`Rig::refractive_camera`]: the shared port or the camera's own). A pose is
/// drawn in the water in front of the master camera until the cameras `spec.cameras` asks for
/// see every corner at least the margin inside their images; each camera that does gets an image
/// of the view (exact pixels plus noise, redrawn where the noise would carry a corner over the
/// margin), the others are left out of it. No occlusion of the target by itself is modelled: a
/// 3-D target should open toward the cameras (its z axis away from them, as a board's).
///
/// Errors: [`CalibError::BadBoard`] for a board smaller than 2 × 2 or a target whose points are
/// not finite or all coincide; [`CalibError::Options`] for a noise outside [0,
/// [`MAX_NOISE_PX`]], cameras not in the rig, a minimum outside 1..=cameras, a scene larger than
/// [`check_scene_size`] allows, or no pose found for a view.
pub fn simulate(rig: &Rig, spec: &SceneSpec) -> Result<Scene, CalibError> {
    let target = &spec.target;
    let count = rig.cameras().len();
    if let Target::Board(board) = target
        && (board.rows < 2 || board.cols < 2 || !(board.square > 0.0 && board.square.is_finite()))
    {
        return Err(CalibError::BadBoard {
            reason: format!(
                "{} × {} corners of {} m",
                board.rows, board.cols, board.square
            ),
        });
    }
    let images_per_view = match spec.cameras {
        Cameras::Any { .. } => count,
        Cameras::Pair(..) => 1,
    };
    check_scene_size(target, images_per_view, spec.views)?;
    let points: Vec<Point3<f64>> = (0..target.len()).map(|i| target.point(i)).collect();
    if let Some(i) = points
        .iter()
        .position(|p| !p.coords.iter().all(|x| x.is_finite()))
    {
        return Err(CalibError::BadBoard {
            reason: format!(
                "target point {i} {:?} is not finite",
                points[i].coords.as_slice()
            ),
        });
    }
    let centroid = points.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / points.len() as f64;
    let radius = points
        .iter()
        .map(|p| (p.coords - centroid).norm())
        .fold(0.0, f64::max);
    if !(radius > 0.0) {
        return Err(CalibError::BadBoard {
            reason: "every target point is the same point".into(),
        });
    }
    if !(spec.noise_px >= 0.0 && spec.noise_px <= MAX_NOISE_PX) {
        return Err(CalibError::Options(format!(
            "noise must lie in [0, {MAX_NOISE_PX}] px (a corner detector's error is a fraction of a pixel), got {}",
            number(spec.noise_px)
        )));
    }
    // The cameras that may image a view, in the order their images are drawn.
    let (imaging, required, least): (Vec<usize>, Vec<usize>, usize) = match &spec.cameras {
        Cameras::Any { required, min } => {
            if let Some(&k) = required.iter().find(|&&k| k >= count) {
                return Err(CalibError::Options(format!(
                    "camera {k} must see every view, and the rig has {count} camera(s)"
                )));
            }
            if !(1..=count).contains(min) {
                return Err(CalibError::Options(format!(
                    "every view seen by at least {min} cameras: the rig has {count} (1 to {count})"
                )));
            }
            ((0..count).collect(), required.clone(), *min)
        }
        &Cameras::Pair(a, b) => {
            if a >= count || b >= count || a == b {
                return Err(CalibError::Options(format!(
                    "the pair ({a}, {b}) is not two cameras of the rig ({count} camera(s))"
                )));
            }
            (vec![a, b], vec![a, b], 2)
        }
    };
    // Exact corners keep at least 5 σ from the border, and a noise sample that would carry a
    // corner over that margin is drawn again (a Gaussian truncated at ≥ 5 σ: the default 10 px
    // margin is 100 σ at 0.1 px, where no sample is ever redrawn).
    let margin = spec.margin_px.max(5.0 * spec.noise_px);
    let cameras: Vec<RefractiveCamera> = (0..count).map(|k| rig.refractive_camera(k)).collect();
    let placement = Placement::of(rig, spec, centroid, radius);
    let mut rng = Rng::new(spec.seed);

    let mut views = Vec::with_capacity(spec.views);
    let mut poses = Vec::with_capacity(spec.views);
    let mut seen_by = Vec::with_capacity(spec.views);
    for v in 0..spec.views {
        let (pose, pixels) = (0..MAX_TRIES_PER_VIEW)
            .find_map(|_| {
                let pose = random_pose(
                    &mut rng,
                    &placement.centre,
                    placement.near,
                    3.0 * placement.near,
                    placement.tan_half_fov,
                    spec.max_target_tilt,
                );
                let pixels: Vec<(usize, Option<Vec<Point2<f64>>>)> = imaging
                    .iter()
                    .map(|&k| (k, visible(&cameras[k], rig, k, &points, &pose, margin)))
                    .collect();
                let seen = pixels.iter().filter(|(_, p)| p.is_some()).count();
                let ok = seen >= least
                    && required
                        .iter()
                        .all(|&k| pixels.iter().any(|(c, p)| *c == k && p.is_some()));
                ok.then_some((pose, pixels))
            })
            .ok_or_else(|| no_pose(rig, v, &required, least, &points, radius))?;
        let mut draw = || loop {
            let offset = spec.noise_px * rng.normal();
            if offset.abs() <= margin {
                break offset;
            }
        };
        let mut images = Vec::new();
        let mut saw = Vec::new();
        for (k, exact) in pixels {
            let Some(exact) = exact else { continue };
            let name = rig.cameras()[k].name.clone();
            let corners = exact
                .iter()
                .map(|p| Some(Point2::new(p.x + draw(), p.y + draw())))
                .collect();
            images.push(Image {
                camera: CameraKey::Name(name.clone()),
                key: name,
                corners,
            });
            saw.push(k);
        }
        views.push(View { images });
        poses.push(pose);
        seen_by.push(saw);
    }
    Ok(Scene {
        observations: Observations {
            target: target.clone(),
            views,
            stereo_form: false,
        },
        master_from_target: poses,
        seen_by,
    })
}

/// The exact pixels of every target point under `pose` in camera `k`, or `None` when one does
/// not project or falls within `margin` pixels of an image border.
fn visible(
    camera: &RefractiveCamera,
    rig: &Rig,
    k: usize,
    points: &[Point3<f64>],
    pose: &Isometry3<f64>,
    margin: f64,
) -> Option<Vec<Point2<f64>>> {
    let i = &rig.cameras()[k].intrinsics;
    points
        .iter()
        .map(|p| {
            let pixel = camera.project(&(pose * p)).ok()?;
            let inside = pixel.x >= margin
                && pixel.y >= margin
                && pixel.x <= i.width as f64 - 1.0 - margin
                && pixel.y <= i.height as f64 - 1.0 - margin;
            inside.then_some(pixel)
        })
        .collect()
}

/// The error for a view no pose was found for.
fn no_pose(
    rig: &Rig,
    v: usize,
    required: &[usize],
    least: usize,
    points: &[Point3<f64>],
    radius: f64,
) -> CalibError {
    let who = if required.is_empty() {
        String::new()
    } else {
        let names: Vec<&str> = required
            .iter()
            .map(|&k| rig.cameras()[k].name.as_str())
            .collect();
        format!(" with {} among them", names.join(", "))
    };
    CalibError::Options(format!(
        "view {v}: found no pose in {MAX_TRIES_PER_VIEW} tries in which at least {least} camera(s){who} see the whole target ({} corners, {} m across)",
        points.len(),
        number(2.0 * radius)
    ))
}

/// A target pose X_master = R·X_target + t: the point `centre` of the target (its frame) at a
/// random depth in [near, far] inside the central part of the master camera's view, the target's
/// z axis within `max_tilt` of the camera's, turned about it by up to ±30°.
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
