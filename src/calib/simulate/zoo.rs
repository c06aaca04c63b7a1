//! A zoo of random rigs over the space users have (issue 45): 1–8 cameras at any roll, with
//! baselines of 5 cm to 1 m, behind a port per camera (housings tilted up to 10°, 2–40 mm of air,
//! 3–25 mm of glass), one shared window, a tank wall, or above a water surface 0.1–2 m below
//! cameras at different heights; lenses of 50–95° field of view and real distortion; a ChArUco
//! board of a common dictionary or a chessboard, sized to be seen 0.2–3 m away. Each rig is a
//! pure function of its seed, so a table over seeds 1…N can be made again anywhere.
//!
//! What a rig is *for* is in [`ZooRig`]: the truth, the board, and the facts a user knows and
//! gives on the command line (`--port`, `--glass`); `tests/zoo.rs` renders each rig, runs
//! `flatport calibrate --images` with no other option and scores the result against the truth.

use nalgebra::{Matrix3, Rotation3, Unit, Vector3};

use super::rng::Rng;
use crate::model::{
    Interface, Layer, ModelError, PinholeCamera, Ports, Rig, RigCamera, normal_from_tilt_azimuth,
};

/// The kind of port of a zoo rig (the `--port` a user gives).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ZooPort {
    /// A housing per camera.
    Housings,
    /// One window with glass in front of every camera.
    Shared,
    /// A tank's glass wall, the cameras outside it (a shared port, further away and thinner).
    TankWall,
    /// A bare water surface below cameras at different heights.
    Surface,
}

impl ZooPort {
    /// The `--port` value: `housings`, `shared` or `surface` (a tank wall is a shared port).
    pub fn flag(self) -> &'static str {
        match self {
            Self::Housings => "housings",
            Self::Shared | Self::TankWall => "shared",
            Self::Surface => "surface",
        }
    }

    /// A name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Self::Housings => "housings",
            Self::Shared => "shared window",
            Self::TankWall => "tank wall",
            Self::Surface => "surface",
        }
    }
}

/// The board of a zoo rig, as BOARD.json describes it (DESIGN.md §3c).
#[derive(Debug, Clone, PartialEq)]
pub struct ZooBoard {
    /// `Some(dictionary)` for ChArUco (OpenCV's name), `None` for a chessboard.
    pub dictionary: Option<&'static str>,
    /// Squares across.
    pub squares_x: usize,
    /// Squares down.
    pub squares_y: usize,
    /// Side of a square, metres.
    pub square: f64,
}

impl ZooBoard {
    /// The BOARD.json text of this board.
    pub fn json(&self) -> String {
        match self.dictionary {
            Some(dictionary) => format!(
                "{{\"type\": \"charuco\", \"squares_x\": {}, \"squares_y\": {}, \"square_size\": {}, \"marker_size\": {}, \"dictionary\": \"{dictionary}\", \"legacy_pattern\": false}}\n",
                self.squares_x,
                self.squares_y,
                self.square,
                0.75 * self.square
            ),
            None => format!(
                "{{\"type\": \"chessboard\", \"squares_x\": {}, \"squares_y\": {}, \"square_size\": {}}}\n",
                self.squares_x, self.squares_y, self.square
            ),
        }
    }
}

/// One rig of the zoo: the truth and what a user would tell `calibrate --images` about it.
#[derive(Debug, Clone)]
pub struct ZooRig {
    /// The seed it was made from.
    pub seed: u64,
    /// The kind of port.
    pub port: ZooPort,
    /// The true rig (the master first; camera names sort in rig order).
    pub rig: Rig,
    /// The board.
    pub board: ZooBoard,
    /// The `--glass` arguments a user gives (`T:N`, or `CAMERA=T:N` per housing).
    pub glass: Vec<String>,
    /// The distance of the nearest board, metres from the master, that the board is sized for.
    pub board_distance: f64,
}

impl ZooRig {
    /// The range of board distances under water to render, metres along the master's axis
    /// (`render --distance NEAR:FAR`): the board's distance to twice it.
    pub fn water_distance(&self) -> (f64, f64) {
        (self.board_distance, 2.0 * self.board_distance)
    }
}

impl ZooRig {
    /// One line saying what this rig is.
    pub fn describe(&self) -> String {
        let cameras = self.rig.cameras();
        let baseline = cameras
            .iter()
            .map(|c| c.centre_in_master().coords.norm())
            .fold(0.0, f64::max);
        format!(
            "seed {}: {} camera(s), {}, baseline {:.2} m, {} {}x{} squares of {:.0} mm for {:.2} m",
            self.seed,
            cameras.len(),
            self.port.name(),
            baseline,
            self.board.dictionary.unwrap_or("chessboard"),
            self.board.squares_x,
            self.board.squares_y,
            self.board.square * 1e3,
            self.board_distance
        )
    }
}

/// Common image sizes (width, height).
const SIZES: [(u32, u32); 5] = [
    (640, 480),
    (1024, 768),
    (1280, 1024),
    (1440, 1080),
    (1920, 1080),
];
/// ChArUco dictionaries users print (OpenCV's names) and their marker counts.
const DICTIONARIES: [(&str, usize); 4] = [
    ("DICT_4X4_50", 50),
    ("DICT_5X5_100", 100),
    ("DICT_6X6_250", 250),
    ("DICT_4X4_100", 100),
];

/// The rig of `seed`: the kind of port, the cameras, the ports and the board drawn from the
/// ranges of the module documentation.
pub fn zoo_rig(seed: u64) -> Result<ZooRig, ModelError> {
    let mut rng = Rng::new(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0x5EED);
    let port = match (rng.uniform() * 4.0) as usize {
        0 => ZooPort::Housings,
        1 => ZooPort::Shared,
        2 => ZooPort::TankWall,
        _ => ZooPort::Surface,
    };
    let count = 1 + (rng.uniform() * 8.0).min(7.999) as usize;
    let count = if port == ZooPort::Surface {
        count.max(2)
    } else {
        count
    };
    let (width, height) = SIZES[(rng.uniform() * SIZES.len() as f64) as usize % SIZES.len()];
    // Horizontal field of view 50–95°.
    let fov = rng.range(50.0, 95.0).to_radians();
    let focal = f64::from(width) / 2.0 / (fov / 2.0).tan();
    // Distortion grows with the field of view: barrel k1 down to −0.3 for the widest lenses.
    let wide = (fov.to_degrees() - 50.0) / 45.0;
    // The baseline: 5 cm – 1 m across the rig; the cameras on a rough circle of that diameter,
    // converging on a point at the boards' distance.
    let baseline = if count == 1 {
        0.0
    } else {
        (rng.range(0.05f64.ln(), 1.0f64.ln())).exp()
    };
    // Boards 0.2–3 m away, and at least 1.5 baselines (the cameras converge by at most ~35°,
    // as rigs that share a board are built); above a surface, past it.
    let surface_below = (rng.range(0.1f64.ln(), 2.0f64.ln())).exp();
    let board_distance = match port {
        ZooPort::Surface => (surface_below * rng.range(1.4, 2.2)).max(surface_below + 0.15),
        _ => (rng.range(0.2f64.ln(), 3.0f64.ln())).exp(),
    };
    let board_distance = board_distance.max(1.5 * baseline);
    let mut cameras = Vec::with_capacity(count);
    let phase = rng.range(0.0, std::f64::consts::TAU);
    for k in 0..count {
        let name = format!("cam{k}");
        let lens = PinholeCamera::new(
            &name,
            width,
            height,
            focal * rng.range(0.99, 1.01),
            focal * rng.range(0.99, 1.01),
            (f64::from(width) - 1.0) / 2.0 + rng.range(-0.02, 0.02) * f64::from(width),
            (f64::from(height) - 1.0) / 2.0 + rng.range(-0.02, 0.02) * f64::from(height),
            [
                -0.3 * wide * rng.range(0.3, 1.0) + rng.range(-0.03, 0.03),
                0.1 * wide * rng.range(0.0, 1.0),
                rng.range(-5e-4, 5e-4),
                rng.range(-5e-4, 5e-4),
                0.0,
            ],
        )?;
        let centre = if k == 0 {
            Vector3::zeros()
        } else {
            let angle = phase + std::f64::consts::TAU * k as f64 / count as f64;
            let radius = baseline / 2.0 * rng.range(0.7, 1.0);
            let height = if port == ZooPort::Surface {
                rng.range(-0.03, 0.03)
            } else {
                rng.range(-0.01, 0.01)
            };
            // Relative to the master at the origin: the master is one of the circle's points.
            Vector3::new(
                radius * (angle.cos() - phase.cos()),
                radius * (angle.sin() - phase.sin()),
                height,
            )
        };
        // Look at a point on the master's axis at the boards' distance (toe-in), jittered by a
        // few degrees, rolled by any angle.
        let aim = Vector3::new(0.0, 0.0, board_distance) - centre;
        let forward = Unit::new_normalize(aim);
        let toe = Rotation3::rotation_between(&Vector3::z(), &forward)
            .unwrap_or_else(Rotation3::identity);
        let jitter = Rotation3::from_euler_angles(
            rng.range(-3.0, 3.0).to_radians(),
            rng.range(-3.0, 3.0).to_radians(),
            0.0,
        );
        let roll = if k == 0 {
            0.0
        } else {
            rng.range(0.0, std::f64::consts::TAU)
        };
        let master_from_cam = toe * jitter * Rotation3::from_axis_angle(&Vector3::z_axis(), roll);
        let master_from_cam = if k == 0 {
            Rotation3::identity()
        } else {
            master_from_cam
        };
        let cam_from_master: Matrix3<f64> = master_from_cam.inverse().into_inner();
        cameras.push(RigCamera::new(
            &name,
            lens,
            cam_from_master,
            -cam_from_master * centre,
        )?);
    }
    let glass_of = |rng: &mut Rng, low: f64, high: f64| Layer {
        thickness: rng.range(low, high),
        index: rng.range(1.47, 1.53),
    };
    let mut glass = Vec::new();
    let ports = match port {
        ZooPort::Housings => {
            let mut ports = Vec::with_capacity(count);
            for camera in &cameras {
                let layer = glass_of(&mut rng, 0.003, 0.025);
                glass.push(format!(
                    "{}={}:{}",
                    camera.name, layer.thickness, layer.index
                ));
                let n = normal_from_tilt_azimuth(
                    rng.range(0.0, 10.0).to_radians(),
                    rng.range(0.0, std::f64::consts::TAU),
                );
                ports.push(Interface::new(
                    n.into_inner(),
                    rng.range(0.002, 0.04),
                    vec![layer],
                    1.0,
                    1.333,
                )?);
            }
            Ports::PerCamera(ports)
        }
        ZooPort::Shared | ZooPort::TankWall | ZooPort::Surface => {
            let (tilt, layers, air) = match port {
                ZooPort::Shared => (10.0, vec![glass_of(&mut rng, 0.003, 0.025)], (0.002, 0.04)),
                ZooPort::TankWall => (10.0, vec![glass_of(&mut rng, 0.003, 0.012)], (0.01, 0.15)),
                _ => (3.0, Vec::new(), (surface_below, surface_below)),
            };
            for layer in &layers {
                glass.push(format!("{}:{}", layer.thickness, layer.index));
            }
            let n = normal_from_tilt_azimuth(
                rng.range(0.0, tilt).to_radians(),
                rng.range(0.0, std::f64::consts::TAU),
            );
            // The air distance from the camera farthest along the axis (each camera its share).
            let farthest = cameras
                .iter()
                .map(|c| n.dot(&c.centre_in_master().coords))
                .fold(0.0, f64::max);
            let distance = farthest + rng.range(air.0, air.1);
            Ports::Shared(Interface::new(
                n.into_inner(),
                distance,
                layers,
                1.0,
                1.333,
            )?)
        }
    };
    let rig = Rig::with_ports(cameras, ports)?;
    // A board that fills about 60 % of the image's width at `board_distance` and 30 % at
    // twice it (the range the set is rendered over: [`ZooRig::water_distance`]).
    let (squares_x, squares_y) = (
        5 + (rng.uniform() * 6.0) as usize,
        4 + (rng.uniform() * 4.0) as usize,
    );
    let (squares_x, squares_y) = (squares_x.max(squares_y + 1), squares_y);
    let outer = 0.6 * board_distance * f64::from(width) / (focal * 1.333);
    let square = (outer / squares_x as f64 * 1e3).round() / 1e3;
    let dictionary = if rng.uniform() < 0.75 {
        let fitting: Vec<_> = DICTIONARIES
            .iter()
            .filter(|(_, markers)| *markers > squares_x * squares_y / 2)
            .collect();
        Some(fitting[(rng.uniform() * fitting.len() as f64) as usize % fitting.len()].0)
    } else {
        None
    };
    Ok(ZooRig {
        seed,
        port,
        rig,
        board: ZooBoard {
            dictionary,
            squares_x,
            squares_y,
            square: square.max(0.005),
        },
        glass,
        board_distance,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_rig_is_valid_and_a_function_of_its_seed() {
        let mut kinds = std::collections::HashSet::new();
        for seed in 1..=200 {
            let a = zoo_rig(seed).unwrap();
            let b = zoo_rig(seed).unwrap();
            assert_eq!(a.rig, b.rig, "seed {seed}");
            kinds.insert(a.port.name());
            let n = a.rig.cameras().len();
            assert!((1..=8).contains(&n), "seed {seed}: {n} cameras");
            // Every camera is in the air by at least 2 mm (DESIGN.md §1: d_k > 0).
            for k in 0..n {
                let air = a.rig.refractive_camera(k).air_distance();
                assert!(air >= 0.002 - 1e-12, "seed {seed}: camera {k} air {air}");
            }
            assert!(
                a.board.square > 0.0 && a.board_distance > 0.1,
                "{}",
                a.describe()
            );
        }
        assert_eq!(kinds.len(), 4, "{kinds:?}");
    }
}
