//! Simulated scenes for any rig: 1..N cameras behind one shared port or a port each, looking at a
//! board or a 3-D target. The ideas of [`simulate`](super::simulate) (random poses in the water in
//! front of the master camera, corners kept a margin from the image border, truncated Gaussian
//! pixel noise, everything from one seed), with the general observations (DESIGN.md §3b) as
//! output: a camera that does not see the whole target in a view is left out of that view.

use nalgebra::{Isometry3, Point2, Vector3};

use crate::calib::error::{CalibError, number};
use crate::calib::problem::rig_observations::{CameraKey, Image, RigObservations, RigView};
use crate::calib::problem::target::Target;
use crate::calib::simulate::rng::Rng;
use crate::calib::simulate::{MAX_BOARD_CORNERS, MAX_NOISE_PX, MAX_SIMULATED_CORNERS, random_pose};
use crate::model::Rig;

/// How to simulate a scene for a rig.
#[derive(Debug, Clone, PartialEq)]
pub struct RigSceneSpec {
    /// What the cameras look at.
    pub target: Target,
    /// Number of views.
    pub views: usize,
    /// Standard deviation of the Gaussian pixel noise added to each coordinate, pixels.
    pub noise_px: f64,
    /// Seed of the random generator (equal seeds give equal scenes).
    pub seed: u64,
    /// Largest angle between the target's z axis and the master camera's viewing axis, radians.
    pub max_target_tilt: f64,
    /// Corners keep this many pixels from the image border (before noise; at least 5 σ).
    pub margin_px: f64,
    /// Rig cameras that must see the whole target in every view (default: the master, whose
    /// frame the poses are given in). An empty list lets any camera see a view alone.
    pub required: Vec<usize>,
    /// Every view is seen whole by at least this many cameras (default 1, at least 1).
    pub min_cameras: usize,
}

impl RigSceneSpec {
    /// Defaults: targets turned up to 45° toward the master camera, corners 10 px inside the
    /// images, every view seen by the master.
    pub fn new(target: Target, views: usize, noise_px: f64, seed: u64) -> Self {
        Self {
            target,
            views,
            noise_px,
            seed,
            max_target_tilt: 45f64.to_radians(),
            margin_px: 10.0,
            required: vec![0],
            min_cameras: 1,
        }
    }
}

/// A simulated scene for a rig: what the cameras saw and the truth behind it.
#[derive(Debug, Clone, PartialEq)]
pub struct RigScene {
    /// The corners as detected (with noise), each image keyed by its rig camera's name, cameras
    /// in rig order; a camera that did not see the whole target in a view is absent from it.
    pub observations: RigObservations,
    /// X_master = R·X_target + t for each view.
    pub master_from_target: Vec<Isometry3<f64>>,
    /// The rig cameras that saw each view, in rig order.
    pub seen_by: Vec<Vec<usize>>,
}

/// Checks the sizes of a scene before anything is allocated: a target of 4 to
/// [`MAX_BOARD_CORNERS`] corners, 1 to [`MAX_SIMULATED_CORNERS`] / (corners × cameras) views.
pub fn check_rig_scene_size(
    target: &Target,
    cameras: usize,
    views: usize,
) -> Result<(), CalibError> {
    let corners = target.len();
    if !(4..=MAX_BOARD_CORNERS).contains(&corners) {
        return Err(CalibError::BadBoard {
            reason: format!(
                "a target of {corners} corners: 4 to {MAX_BOARD_CORNERS} are simulated (every pose tried projects all of them)"
            ),
        });
    }
    let most = MAX_SIMULATED_CORNERS / (corners * cameras.max(1));
    if views == 0 || views > most {
        return Err(CalibError::Options(format!(
            "{views} views of a target of {corners} corners by {cameras} camera(s): 1 to {most} views ({MAX_SIMULATED_CORNERS} corners in all)"
        )));
    }
    Ok(())
}

/// Most random poses tried per view before giving up.
const MAX_TRIES_PER_VIEW: usize = 20_000;

/// Simulates `spec.views` views of `spec.target` by every camera of `rig`, each looking through
/// its own port ([`Rig::refractive_camera`]: the shared port or the camera's own). A pose is
/// drawn in the water in front of the master camera until every camera of `spec.required` and at
/// least `spec.min_cameras` cameras see every corner at least the margin inside their images;
/// each camera that does gets an image of the view (exact pixels plus noise), the others are
/// left out of it. No occlusion of the target by itself is modelled: a 3-D target should open
/// toward the cameras (its z axis away from them, as a board's).
///
/// Errors: [`CalibError::BadBoard`] for a board smaller than 2 × 2 or a target whose points are
/// not finite or all coincide; [`CalibError::Options`] for a noise outside [0,
/// [`MAX_NOISE_PX`]], a required camera not in the rig, `min_cameras` outside 1..=cameras, a
/// scene larger than [`check_rig_scene_size`] allows, or no pose found for a view.
pub fn simulate_rig(rig: &Rig, spec: &RigSceneSpec) -> Result<RigScene, CalibError> {
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
    check_rig_scene_size(target, count, spec.views)?;
    let points: Vec<_> = (0..target.len()).map(|i| target.point(i)).collect();
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
    let centre = points.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / points.len() as f64;
    let radius = points
        .iter()
        .map(|p| (p.coords - centre).norm())
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
    if let Some(&k) = spec.required.iter().find(|&&k| k >= count) {
        return Err(CalibError::Options(format!(
            "camera {k} must see every view, and the rig has {count} camera(s)"
        )));
    }
    if !(1..=count).contains(&spec.min_cameras) {
        return Err(CalibError::Options(format!(
            "every view seen by at least {} cameras: the rig has {count} (1 to {count})",
            spec.min_cameras
        )));
    }
    // As in `simulate`: exact corners keep at least 5 σ from the border, and a noise sample that
    // would carry a corner over that margin is drawn again (a Gaussian truncated at ≥ 5 σ).
    let margin = spec.margin_px.max(5.0 * spec.noise_px);
    let cameras: Vec<_> = (0..count).map(|k| rig.refractive_camera(k)).collect();
    let mut rng = Rng::new(spec.seed);
    // Depth range from the master camera's field of view through its port: the target must fit.
    let port = rig.port_in_master(0);
    let intrinsics = rig.cameras()[0].intrinsics;
    let half_fov_air = (0.5
        * (intrinsics.width as f64 / intrinsics.fx).min(intrinsics.height as f64 / intrinsics.fy))
    .atan();
    let tan_half_fov_water = (half_fov_air.sin() * port.index_air() / port.index_water())
        .min(0.999)
        .asin()
        .tan();
    let far_port = (0..count)
        .map(|k| {
            // Where camera k's last interface (master frame: n·X = outer) crosses the master's
            // axis X = (0, 0, z).
            let p = rig.port_in_master(k);
            (p.outer_distance() / p.normal().z).max(0.0)
        })
        .fold(0.0, f64::max);
    let near = (radius / tan_half_fov_water).max(far_port + radius + 0.05);
    let far = 3.0 * near;

    let mut views = Vec::with_capacity(spec.views);
    let mut poses = Vec::with_capacity(spec.views);
    let mut seen_by = Vec::with_capacity(spec.views);
    for v in 0..spec.views {
        let (pose, pixels) = (0..MAX_TRIES_PER_VIEW)
            .find_map(|_| {
                let pose = random_pose(
                    &mut rng,
                    &centre,
                    near,
                    far,
                    tan_half_fov_water,
                    spec.max_target_tilt,
                );
                let pixels: Vec<Option<Vec<Point2<f64>>>> = cameras
                    .iter()
                    .enumerate()
                    .map(|(k, camera)| {
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
                    })
                    .collect();
                let seen = pixels.iter().filter(|p| p.is_some()).count();
                let ok = seen >= spec.min_cameras
                    && spec.required.iter().all(|&k| pixels[k].is_some());
                ok.then_some((pose, pixels))
            })
            .ok_or_else(|| {
                let who = if spec.required.is_empty() {
                    String::new()
                } else {
                    let names: Vec<&str> = spec
                        .required
                        .iter()
                        .map(|&k| rig.cameras()[k].name.as_str())
                        .collect();
                    format!(" with {} among them", names.join(", "))
                };
                CalibError::Options(format!(
                    "view {v}: found no pose in {MAX_TRIES_PER_VIEW} tries in which at least {} camera(s){who} see the whole target ({} corners, {} m across)",
                    spec.min_cameras,
                    points.len(),
                    number(2.0 * radius)
                ))
            })?;
        let mut draw = || loop {
            let offset = spec.noise_px * rng.normal();
            if offset.abs() <= margin {
                break offset;
            }
        };
        let mut images = Vec::new();
        let mut saw = Vec::new();
        for (k, exact) in pixels.into_iter().enumerate() {
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
        views.push(RigView { images });
        poses.push(pose);
        seen_by.push(saw);
    }
    Ok(RigScene {
        observations: RigObservations {
            target: target.clone(),
            views,
        },
        master_from_target: poses,
        seen_by,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::Board;
    use crate::model::{Interface, Layer, PinholeCamera, Ports, RigCamera};
    use nalgebra::{Matrix3, Point3, Rotation3};

    fn intrinsics() -> PinholeCamera {
        PinholeCamera::new("c", 800, 600, 700.0, 700.0, 400.0, 300.0, [0.0; 5]).unwrap()
    }

    fn port(normal: Vector3<f64>, distance: f64) -> Interface {
        let glass = vec![Layer {
            thickness: 0.01,
            index: 1.49,
        }];
        Interface::new(normal, distance, glass, 1.0, 1.333).unwrap()
    }

    /// Two housings: camera 1 moved 0.2 m right and turned 3° inward, each with its own tilted port.
    fn housings() -> Rig {
        let master =
            RigCamera::new("a", intrinsics(), Matrix3::identity(), Vector3::zeros()).unwrap();
        let r = Rotation3::from_euler_angles(0.0, -3f64.to_radians(), 0.0).into_inner();
        let c = Vector3::new(0.2, 0.0, 0.0);
        let second = RigCamera::new("b", intrinsics(), r, -(r * c)).unwrap();
        let ports = vec![
            port(Vector3::new(8f64.to_radians().tan(), 0.0, 1.0), 0.02),
            port(Vector3::new(0.0, 5f64.to_radians().tan(), 1.0), 0.015),
        ];
        Rig::with_ports(vec![master, second], Ports::PerCamera(ports)).unwrap()
    }

    #[test]
    fn corners_are_the_projections_of_the_posed_target_and_seeds_reproduce() {
        let rig = housings();
        let target = Target::Board(Board {
            rows: 5,
            cols: 7,
            square: 0.03,
        });
        let mut spec = RigSceneSpec::new(target.clone(), 12, 0.0, 3);
        let scene = simulate_rig(&rig, &spec).unwrap();
        assert_eq!(scene.observations.views.len(), 12);
        assert_eq!(scene, simulate_rig(&rig, &spec).unwrap());
        let mut both = 0;
        for (v, view) in scene.observations.views.iter().enumerate() {
            assert_eq!(view.images[0].key, "a", "the master sees every view");
            both += usize::from(view.images.len() == 2);
            for image in &view.images {
                let k = rig.camera_index(&image.key).unwrap();
                // The oracle: each camera's port written in the master frame by hand from the
                // camera's own frame (n = Rᵀ n_k, d = d_k + n·C), projected through a rig with
                // that port shared (by the cameras up to k: the master sits behind the
                // other housing's glass).
                let Ports::PerCamera(ports) = rig.ports() else {
                    unreachable!()
                };
                let cam = &rig.cameras()[k];
                let n = cam.cam_from_master.rotation.inverse() * ports[k].normal().into_inner();
                let d = ports[k].air_distance() + n.dot(&cam.centre_in_master().coords);
                let shared = ports[k].with_pose(n, d).unwrap();
                let oracle = Rig::new(rig.cameras()[..=k].to_vec(), shared)
                    .unwrap()
                    .refractive_camera(k);
                for (i, corner) in image.corners.iter().enumerate() {
                    let point = scene.master_from_target[v] * target.point(i);
                    let expected = oracle.project(&point).unwrap();
                    assert!(
                        (corner.unwrap() - expected).norm() < 1e-9,
                        "view {v} camera {k} corner {i}"
                    );
                }
            }
        }
        assert!(both > 0, "the two housings overlap");
        // Noise: the offsets from the noise-free scene have the asked standard deviation.
        spec.noise_px = 0.5;
        let noisy = simulate_rig(&rig, &spec).unwrap();
        assert_eq!(noisy.master_from_target, scene.master_from_target);
        let offsets: Vec<f64> = noisy
            .observations
            .views
            .iter()
            .zip(&scene.observations.views)
            .flat_map(|(a, b)| a.images.iter().zip(&b.images))
            .flat_map(|(a, b)| a.corners.iter().zip(&b.corners))
            .flat_map(|(a, b)| {
                let d = a.unwrap() - b.unwrap();
                [d.x, d.y]
            })
            .collect();
        let rms = (offsets.iter().map(|x| x * x).sum::<f64>() / offsets.len() as f64).sqrt();
        // ≥ 840 samples: the RMS of a unit Gaussian sample has a standard error ≈ 1/√(2n) < 2.5 %.
        assert!((rms / 0.5 - 1.0).abs() < 0.1, "{rms}");
        assert_ne!(
            simulate_rig(
                &rig,
                &RigSceneSpec {
                    seed: 4,
                    ..spec.clone()
                }
            )
            .unwrap(),
            noisy
        );
    }

    #[test]
    fn a_3d_target_one_camera_and_requirements() {
        let master =
            RigCamera::new("solo", intrinsics(), Matrix3::identity(), Vector3::zeros()).unwrap();
        let rig = Rig::new(vec![master], port(Vector3::z(), 0.03)).unwrap();
        // A cube corner opening toward the camera.
        let mut points = Vec::new();
        for i in 0..3 {
            for j in 0..3 {
                let (a, b) = (0.03 * (i + 1) as f64, 0.03 * (j + 1) as f64);
                points.push(Point3::new(a, b, 0.0));
                points.push(Point3::new(0.0, a, -b));
                points.push(Point3::new(a, 0.0, -b));
            }
        }
        let target = Target::Points(points);
        let scene = simulate_rig(&rig, &RigSceneSpec::new(target.clone(), 5, 0.0, 9)).unwrap();
        let camera = rig.refractive_camera(0);
        for (v, view) in scene.observations.views.iter().enumerate() {
            assert_eq!(view.images.len(), 1);
            for (i, c) in view.images[0].corners.iter().enumerate() {
                let p = camera
                    .project(&(scene.master_from_target[v] * target.point(i)))
                    .unwrap();
                assert_eq!(c.unwrap(), p);
            }
        }
        let mut spec = RigSceneSpec::new(target.clone(), 5, 0.0, 9);
        spec.min_cameras = 2;
        assert!(matches!(
            simulate_rig(&rig, &spec),
            Err(CalibError::Options(_))
        ));
        spec.min_cameras = 1;
        spec.required = vec![1];
        assert!(matches!(
            simulate_rig(&rig, &spec),
            Err(CalibError::Options(_))
        ));
        let same = Target::Points(vec![Point3::new(0.1, 0.0, 0.0); 5]);
        assert!(matches!(
            simulate_rig(&rig, &RigSceneSpec::new(same, 5, 0.0, 9)),
            Err(CalibError::BadBoard { .. })
        ));
    }
}
