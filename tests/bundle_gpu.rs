//! The bundle's residual stencils on the GPU (`GpuResiduals`, f64) against the CPU reference
//! (`CpuResiduals`, the CPU engine's vector path, bit for bit the bundle's own CPU code): every
//! evaluation of a whole central-difference stencil, on simulated scenes of a one-camera rig, a
//! camera pair behind a shared port, a pair with a port each, a four-camera array and a tank of
//! three layers. With `CI` set, a missing Vulkan adapter fails the run.
//! `cargo test --release --test bundle_gpu -- --nocapture` prints the deviations.

mod gpu_harness;

use flatport::calib::backends::gpu::GpuResiduals;
use flatport::calib::backends::residuals::{CpuResiduals, ResidualBackend, StencilBatch};
use flatport::calib::pipeline::bundle::{Bundle, Estimate, State};
use flatport::calib::{Board, SceneSpec, SeenView, Target, simulate};
use flatport::gpu::Precision;
use flatport::model::Rig;
use gpu_harness::engine;
use nalgebra::Vector2;

/// DESIGN.md §5: f64 GPU results within 1e-12 relative of the CPU. A residual is a projected
/// pixel minus an observed one (≈ 0.1 px of a pixel ≈ 10³ px), so the bound is relative to the
/// projected pixel: |Δr| ≤ 1e-12 · |pixel|, ≈ 1e-9 px.
const F64_RELATIVE: f64 = 1e-12;

fn rig(name: &str) -> Rig {
    let path = format!("{}/data/{name}", env!("CARGO_MANIFEST_DIR"));
    flatport::io::read_rig(path.as_ref()).expect("rig")
}

const BOARD: Board = Board {
    rows: 6,
    cols: 9,
    square: 0.04,
};

/// A simulated scene of `rig` (`views` views, 0.1 px noise): its views and a state off the truth
/// (the first port turned by ~1.3° and 2 mm more air, every camera's extrinsics as in the rig).
fn scene(rig: &Rig, views: usize, seed: u64) -> (Target, Vec<SeenView>, State) {
    let target = Target::Board(BOARD);
    let scene = simulate(rig, &SceneSpec::new(target.clone(), views, 0.1, seed)).expect("scene");
    let seen = scene.observations.resolve(rig).expect("views");
    let mut state = State::of(rig, scene.master_from_target);
    let port = &mut state.ports[0];
    port.distance += 2e-3;
    port.normal = nalgebra::Unit::new_normalize(
        port.normal.into_inner() + nalgebra::Vector3::new(0.02, -0.01, 0.0),
    );
    (target, seen, state)
}

/// The largest |gpu − cpu| / |projected pixel| over every residual of every evaluation, and the
/// number of evaluations without an answer (on both).
fn compare(
    what: &str,
    corners: &[flatport::calib::backends::residuals::ObservedCorner],
    cpu: &[Option<Vec<Vector2<f64>>>],
    gpu: &[Option<Vec<Vector2<f64>>>],
) -> (f64, usize) {
    assert_eq!(cpu.len(), gpu.len(), "{what}: one answer per evaluation");
    let (mut worst, mut unanswered) = (0.0f64, 0);
    for (e, (c, g)) in cpu.iter().zip(gpu).enumerate() {
        let (Some(c), Some(g)) = (c, g) else {
            assert_eq!(
                c.is_some(),
                g.is_some(),
                "{what}: evaluation {e} answered on one side only"
            );
            unanswered += 1;
            continue;
        };
        assert_eq!(c.len(), corners.len(), "{what}: a residual per corner");
        for ((rc, rg), corner) in c.iter().zip(g).zip(corners) {
            if *rc == Vector2::zeros() {
                // A corner of a camera the evaluation does not move: exactly 0 on both.
                assert_eq!(rg, rc, "{what}: evaluation {e}, corner {corner:?}");
                continue;
            }
            let pixel = (rc + Vector2::from(corner.observed)).norm();
            worst = worst.max((rg - rc).norm() / pixel);
        }
    }
    (worst, unanswered)
}

/// Every evaluation of the stencil of `estimate` at a state off the truth of a scene of `rig`
/// on the GPU and the CPU: equal to [`F64_RELATIVE`]; plus one evaluation that puts the target
/// inside the air (an air layer 1 m thicker), which neither answers.
fn stencil_matches(name: &str, estimate: &str, views: usize) {
    let Some(engine) = engine(Precision::F64) else {
        return;
    };
    let rig = rig(name);
    let (target, seen, state) = scene(&rig, views, 3);
    let estimate = Estimate::parse(estimate).unwrap();
    let bundle = Bundle::new(&rig, &target, &seen, estimate, None);
    let corners = bundle.observed_corners();
    let mut batch: StencilBatch = bundle.stencil(&state).expect("a valid stencil");
    let mut far = state.clone();
    far.ports[0].distance += 1.0;
    batch
        .cameras
        .push(bundle.cameras(&far).expect("still a rig"));
    batch
        .evaluations
        .push(flatport::calib::backends::residuals::Evaluation {
            cameras: batch.cameras.len() - 1,
            poses: 0,
            only: None,
        });
    let cpu = CpuResiduals::new(&corners).residuals(&batch);
    let gpu_backend = GpuResiduals::new(&engine, &corners).expect("f64 engine");
    let gpu = gpu_backend.residuals(&batch);
    assert!(
        gpu_backend.failure().is_none(),
        "{:?}",
        gpu_backend.failure()
    );
    let (worst, unanswered) = compare(name, &corners, &cpu, &gpu);
    eprintln!(
        "{name} ({} cameras, {} corners, {} evaluations, estimate {}): max |Δr|/|pixel| = {worst:.2e}",
        rig.cameras().len(),
        corners.len(),
        batch.evaluations.len(),
        estimate.name()
    );
    assert_eq!(
        unanswered, 1,
        "{name}: the target inside the air has no answer, the rest do"
    );
    assert!(worst <= F64_RELATIVE, "{name}: {worst:e}");
}

#[test]
fn one_camera_stencils_match_the_cpu() {
    stencil_matches("rigs/single_housing.json", "axis,distance,layers", 6);
}

#[test]
fn a_shared_port_pair_matches_the_cpu() {
    stencil_matches("example_rig.json", "axis,distance,extrinsics", 6);
}

#[test]
fn a_port_per_camera_matches_the_cpu() {
    // Each port's columns evaluate only its camera: the other's rows are 0 on both.
    stencil_matches("rigs/housings.json", "axis,distance,layers,extrinsics", 6);
}

#[test]
fn a_four_camera_array_matches_the_cpu() {
    stencil_matches("rigs/array_2x2.json", "axis,distance,extrinsics", 8);
}

#[test]
fn a_tank_of_three_layers_matches_the_cpu() {
    // The second and third layers are read from each invocation's own camera copy.
    stencil_matches("rigs/tank.json", "axis,layers", 6);
}

/// The corners go to the device once for any number of calls; an f32 engine is refused (the
/// bundle stays on the CPU there).
#[test]
fn corners_stay_on_the_device_and_f32_is_refused() {
    let Some(gpu) = engine(Precision::F64) else {
        return;
    };
    let rig = rig("rigs/array_2x2.json");
    let (target, seen, state) = scene(&rig, 4, 9);
    let bundle = Bundle::new(&rig, &target, &seen, Estimate::default(), None);
    let corners = bundle.observed_corners();
    let backend = GpuResiduals::new(&gpu, &corners).unwrap();
    let batch = bundle.stencil(&state).unwrap();
    let first = backend.residuals(&batch);
    for _ in 0..3 {
        assert_eq!(
            backend.residuals(&batch),
            first,
            "the same answer every call"
        );
    }
    assert_eq!(backend.uploads(), 1);
    let Some(f32_engine) = engine(Precision::F32) else {
        return;
    };
    assert!(GpuResiduals::new(&f32_engine, &corners).is_err());
}

/// A batch cut into many chunks (the engine's item limit lowered to one workgroup) answers as
/// one dispatch does.
#[test]
fn chunked_batches_match_one_dispatch() {
    let (Some(whole), Some(mut small)) = (engine(Precision::F64), engine(Precision::F64)) else {
        return;
    };
    small.set_max_chunk_items(64);
    let rig = rig("rigs/housings.json");
    let (target, seen, state) = scene(&rig, 3, 4);
    let all = Estimate::parse("axis,distance,extrinsics").unwrap();
    let bundle = Bundle::new(&rig, &target, &seen, all, None);
    let corners = bundle.observed_corners();
    let batch = bundle.stencil(&state).unwrap();
    let one = GpuResiduals::new(&whole, &corners)
        .unwrap()
        .residuals(&batch);
    let chunked = GpuResiduals::new(&small, &corners).unwrap();
    assert!(corners.len() > 64, "more corners than a chunk holds");
    // A chunk of fewer items than one evaluation's corners cannot hold an evaluation.
    assert!(chunked.evaluate(&batch).is_err());
    let mut medium = engine(Precision::F64).unwrap();
    medium.set_max_chunk_items(3 * corners.len());
    let chunked = GpuResiduals::new(&medium, &corners).unwrap();
    assert_eq!(chunked.evaluate(&batch).unwrap(), one);
}
