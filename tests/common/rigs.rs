//! The rigs of issue 10's accuracy bounds (the same as `tests/rig_calibration.rs`'s): the example
//! rig's 1280×1024 cameras (f = 864.91 px, mild distortion) behind 14 mm of glass (1.473), air
//! 1.003, water 1.333, each axis tilted a few degrees; a 9×6 board of 40 mm squares. Shared by
//! `tests/calibration_uncertainty.rs` and `examples/accuracy_study.rs` (which includes this file
//! by path), so the study's rows and the σ test describe the same rigs.
#![allow(dead_code)]

use flatport::calib::{Board, Target};
use flatport::model::{
    Interface, Layer, PinholeCamera, Ports, Rig, RigCamera, normal_from_tilt_azimuth,
};
use nalgebra::{Isometry3, Rotation3, Translation3, UnitQuaternion, Vector3};

pub fn intrinsics() -> PinholeCamera {
    PinholeCamera::new(
        "c",
        1280,
        1024,
        864.91,
        864.91,
        640.0,
        512.0,
        [-0.08, 0.012, 0.0, 0.0, 0.0],
    )
    .unwrap()
}

/// A 14 mm glass port with its axis `tilt_deg` from z at `azimuth_deg`, `distance` m of air.
pub fn port(tilt_deg: f64, azimuth_deg: f64, distance: f64) -> Interface {
    let n = normal_from_tilt_azimuth(tilt_deg.to_radians(), azimuth_deg.to_radians());
    Interface::new(
        n.into_inner(),
        distance,
        vec![Layer {
            thickness: 0.014,
            index: 1.473,
        }],
        1.003,
        1.333,
    )
    .unwrap()
}

/// A camera at `centre` (master frame, m) turned by `yaw_deg` about y and `pitch_deg` about x.
pub fn camera(name: &str, yaw_deg: f64, pitch_deg: f64, centre: [f64; 3]) -> RigCamera {
    let r = Rotation3::from_euler_angles(pitch_deg.to_radians(), yaw_deg.to_radians(), 0.0)
        .into_inner();
    let t = -r * Vector3::from(centre);
    RigCamera::new(name, intrinsics(), r, t).unwrap()
}

/// The 9×6 board of 40 mm squares.
pub fn board() -> Target {
    Target::Board(Board {
        rows: 6,
        cols: 9,
        square: 0.04,
    })
}

/// One camera in a housing: axis 8° at 45°, 20 mm of air.
pub fn one_camera() -> Rig {
    Rig::new(
        vec![camera("cam", 0.0, 0.0, [0.0; 3])],
        port(8.0, 45.0, 0.02),
    )
    .unwrap()
}

/// Four cameras (a 12 × 10 cm grid, turned 3° inward) behind one window: axis 8° at 30°, 30 mm.
pub fn four_cameras() -> Rig {
    let cameras = vec![
        camera("c0", 0.0, 0.0, [0.0, 0.0, 0.0]),
        camera("c1", -3.0, 0.0, [0.12, 0.0, 0.0]),
        camera("c2", 0.0, 3.0, [0.0, 0.1, 0.0]),
        camera("c3", -3.0, 3.0, [0.12, 0.1, 0.0]),
    ];
    Rig::new(cameras, port(8.0, 30.0, 0.03)).unwrap()
}

/// Two housings 15 cm apart (the right one turned 2° inward), each its own port (in its camera's
/// frame): 8° at 45° with 20 mm, 5° at 200° with 25 mm.
pub fn two_housings() -> Rig {
    let cameras = vec![
        camera("left", 0.0, 0.0, [0.0; 3]),
        camera("right", -2.0, 0.0, [0.15, 0.0, 0.0]),
    ];
    let ports = Ports::PerCamera(vec![port(8.0, 45.0, 0.02), port(5.0, 200.0, 0.025)]);
    Rig::with_ports(cameras, ports).unwrap()
}

/// A stereo pair behind one port (6 cm baseline, right camera turned 1°): axis 8° at 45°, 20 mm.
pub fn stereo() -> Rig {
    Rig::new(
        vec![
            camera("left", 0.0, 0.0, [0.0; 3]),
            camera("right", -1.0, 0.0, [0.06, 0.0, 0.0]),
        ],
        port(8.0, 45.0, 0.02),
    )
    .unwrap()
}

/// An in-air stereo calibration's error of the size OpenCV's `stereoCalibrate` gave a new user
/// (DESIGN.md §3b): 0.154° in R, 3.0 mm in T, applied on the left of cam_from_master.
pub fn opencv_error() -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(0.002, -0.002, 0.001),
        UnitQuaternion::from_euler_angles(0.0015, -0.002, 0.001),
    )
}

/// The naive start of every port: axis on its frame's z axis, 10 mm of air.
pub fn naive(rig: &Rig) -> Rig {
    let naive = |p: &Interface| p.with_pose(Vector3::z(), 0.01).unwrap();
    let ports = match rig.ports() {
        Ports::Shared(i) => Ports::Shared(naive(i)),
        Ports::PerCamera(ports) => Ports::PerCamera(ports.iter().map(naive).collect()),
    };
    rig.with_new_ports(ports).unwrap()
}

/// Every port of `rig` in its own frame (the master's when shared, its camera's otherwise).
pub fn ports(rig: &Rig) -> Vec<Interface> {
    match rig.ports() {
        Ports::Shared(i) => vec![i.clone()],
        Ports::PerCamera(ports) => ports.clone(),
    }
}
