//! Property tests over random rigs: normals tilted up to 30° in any azimuth, 0–3 layers of
//! 0.1–50 mm with indices 1.0–1.8, air layers of 1–100 mm, lens distortion on and off, a second
//! camera turned by up to 10°. Oracles: the independent tracer of tests/common, Snell's law,
//! round trips, and the binocular VOP construction against each camera's own VOP.

mod common;

use common::*;
use flatport::model::vop::{real_from_virtual, virtual_from_real};
use flatport::model::{
    Interface, Layer, NoSolution, PinholeCamera, Rig, RigCamera, binocular_vop,
    normal_from_tilt_azimuth, triangulate_rays,
};
use nalgebra::{Matrix3, Point2, Rotation3, Vector3};
use proptest::prelude::*;

#[derive(Debug, Clone)]
struct RigSpec {
    tilt: f64,
    azimuth: f64,
    air: f64,
    layers: Vec<(f64, f64)>,
    index_air: f64,
    index_water: f64,
    distortion: bool,
    baseline: f64,
    turn: (f64, f64, f64),
}

fn rig_spec() -> impl Strategy<Value = RigSpec> {
    (
        0.0..30f64.to_radians(),
        -std::f64::consts::PI..std::f64::consts::PI,
        0.001..0.1f64,
        prop::collection::vec((0.0001..0.05f64, 1.0..1.8f64), 0..=3),
        1.0..1.01f64,
        1.0..1.8f64,
        any::<bool>(),
        0.03..0.15f64,
        (-0.1..0.1f64, -0.17..0.17f64, -0.1..0.1f64),
    )
        .prop_map(
            |(tilt, azimuth, air, layers, index_air, index_water, distortion, baseline, turn)| {
                RigSpec {
                    tilt,
                    azimuth,
                    air,
                    layers,
                    index_air,
                    index_water,
                    distortion,
                    baseline,
                    turn,
                }
            },
        )
}

fn build(spec: &RigSpec) -> Rig {
    let n = normal_from_tilt_azimuth(spec.tilt, spec.azimuth).into_inner();
    let d = if spec.distortion {
        [-0.1, 0.02, 0.0005, -0.0004, -0.001]
    } else {
        [0.0; 5]
    };
    let intrinsics = PinholeCamera::new("c", 1280, 1024, 864.91, 866.0, 640.5, 511.0, d).unwrap();
    let rotation = Rotation3::from_euler_angles(spec.turn.0, spec.turn.1, spec.turn.2).into_inner();
    let centre = Vector3::new(spec.baseline, 0.003, -0.002);
    // Keep the second camera in the air: the air layer is measured from the master.
    let air = spec.air + n.dot(&centre).max(0.0);
    let layers = spec
        .layers
        .iter()
        .map(|&(thickness, index)| Layer { thickness, index })
        .collect();
    Rig::new(
        vec![
            RigCamera::new("left", intrinsics, Matrix3::identity(), Vector3::zeros()).unwrap(),
            RigCamera::new("right", intrinsics, rotation, -(rotation * centre)).unwrap(),
        ],
        Interface::new(n, air, layers, spec.index_air, spec.index_water).unwrap(),
    )
    .unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// Closed form, tracing and the independent tracer agree, including on which pixels have no
    /// answer (total internal reflection when a layer or the water is less dense than the air).
    #[test]
    fn back_projection_agrees_with_tracing(spec in rig_spec(), u in 0.0..1279.0f64, v in 0.0..1023.0f64, k in 0..2usize) {
        let rig = build(&spec);
        let camera = rig.refractive_camera(k);
        let stack = Stack::of(&rig, k);
        let pixel = Point2::new(u, v);
        let oracle = trace(&stack, dir_of_pixel(&stack, pixel));
        match (camera.backproject(&pixel), camera.backproject_traced(&pixel), oracle) {
            (Ok(closed), Ok(traced), Some((origin, dir, dirs))) => {
                prop_assert!((closed.dir.norm() - 1.0).abs() < 1e-15);
                prop_assert!((closed.dir.into_inner() - dir).norm() < 1e-9);
                prop_assert!((traced.dir.into_inner() - dir).norm() < 1e-9);
                let scale = 1.0 + origin.norm();
                prop_assert!((closed.origin.coords - origin).norm() < 1e-9 * scale);
                prop_assert!((traced.origin.coords - origin).norm() < 1e-9 * scale);
                // Snell across the stack: μ_air |v × n| = μ_w |w × n|, v, n, w coplanar.
                let n = rig.shared_interface().unwrap().normal().into_inner();
                let air = dirs[0];
                let i = rig.shared_interface().unwrap();
                prop_assert!((i.index_air() * air.cross(&n).norm() - i.index_water() * closed.dir.cross(&n).norm()).abs() < 1e-12);
                prop_assert!(air.cross(&n).dot(&closed.dir).abs() < 1e-12);
                // On the outer interface.
                prop_assert!((n.dot(&closed.origin.coords) - i.outer_distance()).abs() < 1e-12 * scale);
            }
            (Err(NoSolution::TotalInternalReflection), Err(NoSolution::TotalInternalReflection), None) => {}
            (a, b, c) => prop_assert!(false, "closed {a:?}, traced {b:?}, oracle {:?}", c.map(|c| c.1)),
        }
    }

    /// pixel → ray → point along it → pixel, and point → pixel → ray through the point.
    #[test]
    fn projection_round_trips(spec in rig_spec(), u in 0.0..1279.0f64, v in 0.0..1023.0f64, s in 0.001..10.0f64, k in 0..2usize) {
        let rig = build(&spec);
        let camera = rig.refractive_camera(k);
        let pixel = Point2::new(u, v);
        let Ok(ray) = camera.backproject(&pixel) else { return Ok(()) };
        let point = ray.point_at(s);
        let back = camera.project(&point).unwrap();
        prop_assert!((back - pixel).norm() < 1e-6, "pixel {pixel:?} came back as {back:?}");
        let again = camera.backproject(&back).unwrap();
        let miss = (point - again.origin).cross(&again.dir).norm();
        prop_assert!(miss < 1e-9 * (1.0 + s), "{miss}");
    }

    /// Stereo: triangulation returns the point; binocular VOPs from the axis alone equal each
    /// camera's VOP; the VOP relations invert each other.
    #[test]
    fn stereo_triangulation_and_binocular_vops(spec in rig_spec(), x in -0.5..0.5f64, y in -0.4..0.4f64, depth in 0.05..6.0f64) {
        let rig = build(&spec);
        let interface = rig.shared_interface().unwrap();
        let n = interface.normal().into_inner();
        let base = Vector3::new(x, y, 0.0) * (0.2 + depth);
        let point = nalgebra::Point3::from(base + n * ((interface.outer_distance() + depth - n.dot(&base)) / 1.0));
        let (left, right) = (rig.refractive_camera(0), rig.refractive_camera(1));
        let (Ok(pl), Ok(pr)) = (left.project(&point), right.project(&point)) else { return Ok(()) };
        let (Ok(a), Ok(b)) = (left.backproject(&pl), right.backproject(&pr)) else { return Ok(()) };
        if let Ok(t) = triangulate_rays(&a, &b) {
            prop_assert!((t.point - point).norm() < 1e-7, "{:?} vs {point:?}", t.point);
            prop_assert!(t.residual < 1e-9);
        }
        let (vl, vr) = (left.vop(&point).unwrap(), right.vop(&point).unwrap());
        let (dl, dr) = (left.dir_in_air_from_img(&pl).unwrap(), right.dir_in_air_from_img(&pr).unwrap());
        match binocular_vop(left.centre(), &dl, right.centre(), &dr, interface.normal()) {
            Ok(b) if b.conditioning > 1e-3 => {
                prop_assert!((b.vop_left - vl.vop).norm() < 1e-9, "left VOP off by {}", (b.vop_left - vl.vop).norm());
                prop_assert!((b.vop_right - vr.vop).norm() < 1e-9, "right VOP off by {}", (b.vop_right - vr.vop).norm());
            }
            _ => {}
        }
        for vop in [vl, vr] {
            let there = virtual_from_real(vop.depth, vop.incidence, interface.layers(), interface.index_air(), interface.index_water()).unwrap();
            prop_assert!((there - vop.vop_distance).abs() < 1e-9);
            let back = real_from_virtual(there, vop.incidence, interface.layers(), interface.index_air(), interface.index_water()).unwrap();
            prop_assert!((back - vop.depth).abs() < 1e-9 * (1.0 + vop.depth));
        }
    }
}
