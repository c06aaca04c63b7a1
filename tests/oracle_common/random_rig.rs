//! Random rigs for property tests (`proptest_model`, `cpu_vector`): a stereo pair behind a port
//! tilted up to 30°, 0–3 layers, indices 1.0–1.8 (one in four within 1% of the air's, so that
//! steep rays meet total internal reflection), optional distortion.

use super::*;
use nalgebra::Unit;
use proptest::prelude::*;

#[derive(Debug, Clone)]
pub struct RigSpec {
    pub tilt: f64,
    pub azimuth: f64,
    pub air_distance: f64,
    pub layers: Vec<(f64, f64)>,
    pub index_air: f64,
    pub index_water: f64,
    pub distortion: Option<[f64; 5]>,
    pub focal: f64,
    /// Axis (polar, azimuth) and angle of the right camera's rotation.
    pub turn: (f64, f64, f64),
    pub baseline: (f64, f64, f64),
}

pub fn rig_spec() -> impl Strategy<Value = RigSpec> {
    // One index in four within 1% of the air's, so that steep rays meet total internal reflection.
    let index = || prop_oneof![3 => 1.0..1.8f64, 1 => 1.0..1.01f64];
    let layer =
        (-4.0..0.05f64.log10(), index()).prop_map(|(log_t, index)| (10f64.powf(log_t), index));
    let distortion = prop::option::of((
        -0.15..0.1f64,
        -0.03..0.03f64,
        -5e-4..5e-4f64,
        -5e-4..5e-4f64,
        -0.005..0.005f64,
    ))
    .prop_map(|d| d.map(|(k1, k2, p1, p2, k3)| [k1, k2, p1, p2, k3]));
    (
        (
            0.0..30f64.to_radians(),
            -std::f64::consts::PI..std::f64::consts::PI,
            0.001..0.1f64,
        ),
        prop::collection::vec(layer, 0..=3),
        (1.0..1.01f64, index()),
        (distortion, 800.0..1200.0f64),
        (
            0.0..std::f64::consts::PI,
            -std::f64::consts::PI..std::f64::consts::PI,
            0.0..10f64.to_radians(),
        ),
        (0.03..0.15f64, -0.01..0.01f64, -0.01..0.01f64),
    )
        .prop_map(
            |(
                (tilt, azimuth, air_distance),
                layers,
                (index_air, index_water),
                (distortion, focal),
                turn,
                baseline,
            )| {
                RigSpec {
                    tilt,
                    azimuth,
                    air_distance,
                    layers,
                    index_air,
                    index_water,
                    distortion,
                    focal,
                    turn,
                    baseline,
                }
            },
        )
}

/// The rig of a spec. The master sits at the origin; the right camera's air layer is kept ≥ 1 mm by
/// raising d where its centre would otherwise lie beyond the first interface.
pub fn build(spec: &RigSpec) -> Fixture {
    let normal = normal_from_angles(spec.tilt, spec.azimuth);
    let right_centre = Point3::new(spec.baseline.0, spec.baseline.1, spec.baseline.2);
    let air_distance = spec
        .air_distance
        .max(normal.dot(&right_centre.coords) + 1e-3);
    let stack = Stack {
        normal,
        air_distance,
        thicknesses: spec.layers.iter().map(|l| l.0).collect(),
        indices: std::iter::once(spec.index_air)
            .chain(spec.layers.iter().map(|l| l.1))
            .chain(std::iter::once(spec.index_water))
            .collect(),
    };
    let (polar, azimuth, angle) = spec.turn;
    let axis = Unit::new_normalize(normal_from_angles(polar, azimuth));
    let camera = |rotation: Matrix3<f64>, centre: Point3<f64>, f: f64| CamParams {
        rotation,
        centre,
        width: 1280,
        height: 1024,
        fx: f,
        fy: f * 1.001,
        cx: 639.5,
        cy: 511.5,
        distortion: spec.distortion.unwrap_or([0.0; 5]),
    };
    let cams = vec![
        camera(Matrix3::identity(), Point3::origin(), spec.focal),
        camera(
            Rotation3::from_axis_angle(&axis, angle).into_inner(),
            right_centre,
            spec.focal * 0.98,
        ),
    ];
    Fixture::build("random", stack, cams)
}
