//! The calibration costs on the GPU against the f64 CPU reference: every [`CostKind`] and the
//! linear air layer over one batch of candidate interfaces on simulated scenes, f64 and f32
//! kernels, one dispatch and many chunks. With `CI` set, a missing Vulkan adapter fails the run.
//! `cargo test --release --test calib_gpu -- --nocapture` prints the deviations.

mod gpu_harness;

use flatport::calib::{
    Board, Candidate, CostBackend, CostKind, CpuBackend, GpuBackend, SceneSpec, StereoData, Target,
    simulate,
};
use flatport::engine::GpuEngine;
use flatport::gpu::{Precision, Rows};
use flatport::model::Rig;
use gpu_harness::{Random, engine};
use nalgebra::{Unit, Vector3};

/// f64 kernels: |gpu − cpu| ≤ 1e-9 · |cpu| for every cost and air layer (measured ≤ 1.1e-12, and
/// for the affine grid ≤ 1.1e-11 on the small scenes and 3.5e-10 on the 1230-candidate batch: the
/// covariance of a corner near the degenerate plane, cond ~ 1e12, carries ε·cond of its own
/// rounding on either side, and the kernel's Newton-corrected reciprocals may differ from IEEE
/// ones by an ulp). Rounding analysis of the affine grid (docs/accuracy.md): its one-pass χ² has
/// condition number κ̃ = Σ q̃ᵀWq̃ / χ² < 1e4 (positions shifted by the affine map through three
/// reference corners; views beyond are summed again from their residuals), so two adapters
/// differ by at most κ̃·m·u ≈ 1e4 · 50 · 1.1e-16 ≈ 6e-11 from the sums, with every f64
/// reciprocal and square root corrected by a Newton step. Unshifted, κ reached 1e6 and an H200,
/// whose f64 reciprocals are not IEEE, differed by 4.4e-8.
const F64_RELATIVE: f64 = 1e-9;

// f32 kernels. The f32 upload rounds each corner's air rays by ≈ 6e-8 rad per component, which
// is ≈ u·f = 6e-8 · 865 px ≈ 5e-5 px of extra pixel noise: ε/σ = 5e-4 of the 0.1 px simulated
// noise. (The kernels' own rounding is of the same order: pixels ≈ 1e3 px carry 6e-5 px, and the
// f32 Newton stopping rule leaves less.) At its minimum every cost measures the noise, to first
// order in it (RMS costs ∝ σ, the χ² ∝ σ²), so it moves by at most ε/σ relative (2ε/σ for the χ²)
// even with every perturbation aligned with the residuals; away from the minimum model error
// dominates and the relative change is smaller. Measured over three scenes × 50 candidates and
// one of 15 views × 1230 candidates: ≤ 1.8e-4 (reprojection 6.9e-5, scene 2.9e-5, ray gap
// 2.2e-5, affine grid 4.2e-5, plane fitting 1.6e-4, plane angles 1.8e-4, the unweighted plane
// errors including the corners near the degenerate plane): independent rounding partly averages
// over the corners. The affine grid's covariance is formed in f64 on the host from the kernel's
// Jacobian: formed in f32 it lost positive definiteness for corners with cond Σ ~ 1e12 and
// made 2 of the 1230 candidates +∞.
/// f32: relative bound of the RMS costs (reprojection, scene, ray gap, plane fitting, plane
/// angles): ε/σ.
const F32_RELATIVE: f64 = 5e-4;
/// f32: relative bound of the affine-grid χ² (quadratic in the noise): 2ε/σ.
const F32_RELATIVE_CHI2: f64 = 1e-3;

/// f32: absolute bound of the least-squares air layer, metres. Each corner's signed gap moves by
/// ≈ 1e-7 m (its rounded air rays, ≈ 1e-7 rad, at ≈ 1 m), and d = −Σab/Σa² moves by that over
/// √Σa² = rms|a|·√N ≈ 3.5e-3 · √216 ≈ 0.05 (4 views): ≈ 2e-6 m (measured ≤ 2.5e-6 m over three
/// scenes). 1e-5 m leaves room for axes where the gaps depend less on d; it is far below the
/// 1–2 mm by which 0.1 px of noise moves d in these scenes.
const F32_AIR_DISTANCE: f64 = 1e-5;

/// The bound of one cost's relative deviation from the CPU where many views are summed in one
/// dispatch; `None` for the f32 air-distance cost, whose bound F32_AIR_DISTANCE is the f32 gap
/// sums' error over 4 views (40 views of f32 items are beyond it, 2e-3 relative here).
fn view_sum_bound(precision: Precision, name: &str) -> Option<f64> {
    match (precision, name) {
        (Precision::F64, _) => Some(F64_RELATIVE),
        (_, "air-distance") => None,
        (_, "affine-grid") => Some(F32_RELATIVE_CHI2),
        _ => Some(F32_RELATIVE),
    }
}

fn example_rig() -> Rig {
    flatport::io::read_rig(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/data/example_rig.json"
    )))
    .expect("example rig")
}

/// The 9×6 board of 4 cm squares.
const BOARD_9X6: Board = Board {
    rows: 6,
    cols: 9,
    square: 0.04,
};

/// A board of 96 corners: more than the scene kernel keeps of a view between its passes
/// (`CACHED_CORNERS` in `shaders/calib/scene_fit.wgsl`), so it triangulates them again.
const BOARD_12X8: Board = Board {
    rows: 8,
    cols: 12,
    square: 0.03,
};

/// `views` simulated views of the 9×6 board of 4 cm squares behind the example rig, 0.1 px noise.
fn stereo_data(views: usize, seed: u64) -> StereoData {
    board_data(BOARD_9X6, views, seed)
}

/// `views` simulated views of `board` behind the example rig, 0.1 px noise.
fn board_data(board: Board, views: usize, seed: u64) -> StereoData {
    let rig = example_rig();
    let spec = SceneSpec::pair(Target::Board(board), views, 0.1, seed, 0, 1);
    let scene = simulate(&rig, &spec).expect("simulated scene");
    StereoData::from_observations(&rig, [0, 1], &scene.observations).expect("stereo data")
}

/// The true interface, then `n − 3` random axes tilted up to 20° with air layers of 5–40 mm, then
/// two that put the right camera outside the air (its centre is 6 cm along +x: an axis tilted
/// 20° toward +x needs d > 20.5 mm) and one close to that limit.
fn candidates(data: &StereoData, n: usize, seed: u64) -> Vec<Candidate> {
    let mut random = Random(seed);
    let mut out = vec![Candidate::of(data.rig.shared_interface().unwrap())];
    while out.len() < n - 3 {
        let (tilt, azimuth) = (
            random.range(0.0, 20f64.to_radians()),
            random.range(0.0, std::f64::consts::TAU),
        );
        let normal = flatport::model::normal_from_tilt_azimuth(tilt, azimuth);
        out.push(Candidate {
            normal,
            air_distance: random.range(0.005, 0.040),
        });
    }
    let toward_right = flatport::model::normal_from_tilt_azimuth(20f64.to_radians(), 0.0);
    let limit = data.min_air_distance(&toward_right);
    for air_distance in [0.005, limit - 1e-4, limit + 5e-3] {
        out.push(Candidate {
            normal: toward_right,
            air_distance,
        });
    }
    out
}

/// The largest deviation of `gpu` from `cpu` over candidates both answer: (max |Δ| / |cpu|,
/// max |Δ|, candidates without an answer). Panics where one answers and the other does not.
fn deviation(what: &str, cpu: &[f64], gpu: &[f64]) -> Deviation {
    assert_eq!(cpu.len(), gpu.len(), "{what}: one value per candidate");
    let mut d = Deviation {
        relative: 0.0,
        absolute: 0.0,
        infinite: 0,
    };
    for (k, (c, g)) in cpu.iter().zip(gpu).enumerate() {
        assert_eq!(
            c.is_finite(),
            g.is_finite(),
            "{what}: candidate {k}: cpu {c}, gpu {g}"
        );
        if c.is_finite() {
            d.absolute = d.absolute.max((g - c).abs());
            d.relative = d
                .relative
                .max((g - c).abs() / c.abs().max(f64::MIN_POSITIVE));
        } else {
            d.infinite += 1;
        }
    }
    d
}

struct Deviation {
    relative: f64,
    absolute: f64,
    infinite: usize,
}

/// Every cost and the air layers of `batch` on the CPU and on `gpu`, (name, deviation), and the
/// GPU's values (costs of each kind, then the air layers, +∞ where none).
fn compare(
    data: &StereoData,
    gpu: &GpuBackend<&StereoData, &GpuEngine>,
    batch: &[Candidate],
) -> (Vec<(&'static str, Deviation)>, Vec<Vec<f64>>) {
    let cpu = CpuBackend::new(data);
    let (mut out, mut values) = (Vec::new(), Vec::new());
    for kind in CostKind::ALL {
        let (c, g) = (
            cpu.costs(kind, batch).unwrap(),
            gpu.costs(kind, batch).unwrap(),
        );
        let d = deviation(kind.name(), &c, &g);
        if !kind.axis_only() {
            // The last three candidates: two with the right camera outside the air (random ones
            // tilted toward it with a thin air layer may be too).
            assert!(
                g[batch.len() - 3].is_infinite() && g[batch.len() - 2].is_infinite(),
                "{}: camera outside the air",
                kind.name()
            );
            assert!(g[0].is_finite(), "{}: the true interface", kind.name());
        }
        out.push((kind.name(), d));
        values.push(g);
    }
    let normals: Vec<Unit<Vector3<f64>>> = batch.iter().map(|c| c.normal).collect();
    let as_costs = |d: Vec<Option<f64>>| -> Vec<f64> {
        d.into_iter().map(|d| d.unwrap_or(f64::INFINITY)).collect()
    };
    let (c, g) = (
        as_costs(cpu.air_distances(&normals).unwrap()),
        as_costs(gpu.air_distances(&normals).unwrap()),
    );
    let d = deviation("air-distance", &c, &g);
    assert_eq!(d.infinite, 0, "every axis has an air layer");
    out.push(("air-distance", d));
    values.push(g);
    (out, values)
}

/// The scenes of the parity tests: (board, views, seed).
const SCENES: [(Board, usize, u64); 4] = [
    (BOARD_9X6, 4, 11),
    (BOARD_9X6, 15, 3),
    (BOARD_9X6, 6, 99),
    (BOARD_12X8, 5, 7),
];

#[test]
fn f64_kernels_match_the_cpu_reference() {
    let Some(engine) = engine(Precision::F64) else {
        return;
    };
    for (board, views, seed) in SCENES {
        let data = board_data(board, views, seed);
        let batch = candidates(&data, 50, seed + 1);
        let gpu = GpuBackend::new(&data, &engine);
        for (name, d) in compare(&data, &gpu, &batch).0 {
            eprintln!(
                "f64 {views:>2} views {name:>14}: max relative deviation {:.2e} (absolute {:.2e})",
                d.relative, d.absolute
            );
            assert!(d.relative <= F64_RELATIVE, "f64 {name}: {:e}", d.relative);
        }
    }
}

#[test]
fn f32_kernels_match_the_cpu_reference() {
    let Some(engine) = engine(Precision::F32) else {
        return;
    };
    for (board, views, seed) in SCENES {
        let data = board_data(board, views, seed);
        let batch = candidates(&data, 50, seed + 1);
        let gpu = GpuBackend::new(&data, &engine);
        for (name, d) in compare(&data, &gpu, &batch).0 {
            eprintln!(
                "f32 {views:>2} views {name:>14}: max relative deviation {:.2e} (absolute {:.2e})",
                d.relative, d.absolute
            );
            match name {
                "air-distance" => assert!(
                    d.absolute <= F32_AIR_DISTANCE,
                    "f32 {name}: {:e} m",
                    d.absolute
                ),
                "affine-grid" => assert!(
                    d.relative <= F32_RELATIVE_CHI2,
                    "f32 {name}: {:e}",
                    d.relative
                ),
                _ => assert!(d.relative <= F32_RELATIVE, "f32 {name}: {:e}", d.relative),
            }
        }
    }
}

/// The batch size of a search grid: 1230 candidates over 15 views of 54 corners, both precisions
/// (this batch holds corners near the degenerate plane that a 50-candidate batch may miss).
#[test]
fn a_large_batch_matches_in_both_precisions() {
    let data = stereo_data(15, 3);
    let batch = candidates(&data, 1230, 21);
    for precision in [Precision::F64, Precision::F32] {
        let Some(engine) = engine(precision) else {
            return;
        };
        let gpu = GpuBackend::new(&data, &engine);
        for (name, d) in compare(&data, &gpu, &batch).0 {
            eprintln!(
                "{precision} 1230 candidates {name:>14}: max relative deviation {:.2e} (absolute {:.2e})",
                d.relative, d.absolute
            );
            match (precision, name) {
                (Precision::F64, _) => {
                    assert!(d.relative <= F64_RELATIVE, "f64 {name}: {:e}", d.relative)
                }
                (_, "air-distance") => assert!(
                    d.absolute <= F32_AIR_DISTANCE,
                    "f32 {name}: {:e} m",
                    d.absolute
                ),
                (_, "affine-grid") => assert!(
                    d.relative <= F32_RELATIVE_CHI2,
                    "f32 {name}: {:e}",
                    d.relative
                ),
                _ => assert!(d.relative <= F32_RELATIVE, "f32 {name}: {:e}", d.relative),
            }
        }
    }
}

/// Many chunks of a few candidates each give the same values as one dispatch, bit for bit (each
/// item's arithmetic does not depend on the chunking), and still match the CPU.
#[test]
fn chunked_batches_match_one_dispatch() {
    let Some(whole) = engine(Precision::F64) else {
        return;
    };
    let Some(mut chunked) = engine(Precision::F64) else {
        return;
    };
    let data = stereo_data(4, 11);
    let batch = candidates(&data, 50, 12);
    // 1000 items: 960 after rounding to whole workgroups, 4 candidates of 216 corners per chunk:
    // 13 chunks, the last one short.
    chunked.set_max_chunk_items(1000);
    let (deviations, chunked_values) = compare(&data, &GpuBackend::new(&data, &chunked), &batch);
    for (name, d) in deviations {
        assert!(
            d.relative <= F64_RELATIVE,
            "chunked f64 {name}: {:e}",
            d.relative
        );
    }
    let (_, whole_values) = compare(&data, &GpuBackend::new(&data, &whole), &batch);
    assert_eq!(chunked_values, whole_values, "chunking changed a value");
}

/// `data` with view `v` cut to its first three corners (one board row: collinear), so that no
/// rigid board fit and no affine grid (fewer than 4 corners) exists for that view under any
/// candidate.
fn with_a_degenerate_view(data: &StereoData, v: usize) -> StereoData {
    let mut cut = data.clone();
    let mut corners = Vec::new();
    let mut views = Vec::new();
    for (k, range) in data.views.iter().enumerate() {
        let keep = if k == v { 3 } else { range.len() };
        let start = corners.len();
        corners.extend_from_slice(&data.corners[range.start..range.start + keep]);
        views.push(start..corners.len());
    }
    cut.corners = corners;
    cut.views = views;
    cut
}

/// The per-view kernels' items are added over the views on the device (`calib_view_sum`): with
/// the items per dispatch lowered to 2 304 (36 workgroups), a call of 300 candidates over 40
/// views of 54 corners runs 2 batches of views (36 and 4, the second adding to the sums already
/// on the device), 5 chunks of 64 candidates and 2 submissions (3 and 2 chunks), in one storage
/// block and in uniform windows. The values are those of one dispatch bit for bit in both
/// precisions (the views are added in the same order, in f64) and match the CPU. A view cut to three collinear corners, in the last batch, makes every candidate's
/// affine-grid, scene and reprojection cost +∞ on both devices, however the items are chunked,
/// while the ray gap and the air layers, which do not fit boards, still match the CPU.
#[test]
fn views_are_summed_on_the_device_across_batches_chunks_and_submissions() {
    let data = stereo_data(40, 3);
    let batch = candidates(&data, 300, 4);
    let degenerate = with_a_degenerate_view(&data, 37);
    for precision in [Precision::F64, Precision::F32] {
        let (Some(whole), Some(mut chunked)) = (engine(precision), engine(precision)) else {
            return;
        };
        chunked.set_max_chunk_items(2304);
        let (_, whole_values) = compare(&data, &GpuBackend::new(&data, &whole), &batch);
        for rows in Rows::ALL {
            let mut gpu = GpuBackend::new(&data, &chunked);
            gpu.set_rows(Some(rows));
            let (deviations, values) = compare(&data, &gpu, &batch);
            for (name, d) in deviations {
                let Some(bound) = view_sum_bound(precision, name) else {
                    continue;
                };
                assert!(
                    d.relative <= bound,
                    "{precision} {rows:?} chunked {name}: {:e}",
                    d.relative
                );
            }
            // f64 sums on adapters with SHADER_F64, whatever the kernels' precision.
            if chunked.context().adapter().f64 {
                assert_eq!(
                    values, whole_values,
                    "{precision} {rows:?}: chunking changed a value"
                );
            }

            let mut gpu = GpuBackend::new(&degenerate, &chunked);
            gpu.set_rows(Some(rows));
            let cpu = CpuBackend::new(&degenerate);
            for kind in CostKind::ALL {
                let (c, g) = (
                    cpu.costs(kind, &batch).unwrap(),
                    gpu.costs(kind, &batch).unwrap(),
                );
                deviation(kind.name(), &c, &g);
                if matches!(
                    kind,
                    CostKind::AffineGrid | CostKind::Scene | CostKind::Reprojection
                ) {
                    assert!(
                        g.iter().chain(&c).all(|&v| v == f64::INFINITY),
                        "{precision} {rows:?} {}",
                        kind.name()
                    );
                }
            }
            let whole_gpu = GpuBackend::new(&degenerate, &whole);
            for kind in [
                CostKind::AffineGrid,
                CostKind::Scene,
                CostKind::Reprojection,
            ] {
                let g = whole_gpu.costs(kind, &batch).unwrap();
                assert!(
                    g.iter().all(|&v| v == f64::INFINITY),
                    "{precision} one dispatch {}",
                    kind.name()
                );
            }
            let normals: Vec<Unit<Vector3<f64>>> = batch.iter().map(|c| c.normal).collect();
            let as_costs = |d: Vec<Option<f64>>| -> Vec<f64> {
                d.into_iter().map(|d| d.unwrap_or(f64::INFINITY)).collect()
            };
            let d = deviation(
                "air-distance",
                &as_costs(cpu.air_distances(&normals).unwrap()),
                &as_costs(gpu.air_distances(&normals).unwrap()),
            );
            assert_eq!(
                d.infinite, 0,
                "{precision} {rows:?}: every axis has an air layer"
            );
        }
    }
}

/// The staging path (discrete GPUs: storage buffers copied to and from host-mapped staging
/// buffers) gives the values of the directly mapped path lavapipe uses by default, bit for bit,
/// for every cost and the air layers (candidate and per-view kernels), in both precisions.
#[test]
fn staged_and_mapped_buffers_agree() {
    let data = stereo_data(4, 11);
    let batch = candidates(&data, 50, 13);
    for precision in [Precision::F32, Precision::F64] {
        let (Some(mapped), Some(staged)) = (
            gpu_harness::engine_with(precision, true),
            gpu_harness::engine_with(precision, false),
        ) else {
            return;
        };
        assert!(!staged.context().maps_storage());
        let (_, in_mapped) = compare(&data, &GpuBackend::new(&data, &mapped), &batch);
        let (_, in_staged) = compare(&data, &GpuBackend::new(&data, &staged), &batch);
        assert_eq!(
            in_mapped, in_staged,
            "{precision}: the staging changed a value"
        );
    }
}

/// A board of 300 corners: a view's affine-grid rows (2 700 f64 vec4) exceed a uniform window,
/// so every view of that kernel is read from one storage block.
const BOARD_20X15: Board = Board {
    rows: 15,
    cols: 20,
    square: 0.02,
};

/// The per-view kernels read their corner rows from uniform windows where every view fits one
/// (`Rows` in src/gpu/compose.rs): 30 views of 54 corners fill two f32 windows of the
/// scene kernels, three f64 ones, and eight of the affine grid; the 300-corner views of a 20×15
/// board send the affine grid to storage in both precisions. Either way the values are those of
/// one storage block, bit for bit, and match the CPU.
#[test]
fn uniform_windows_match_one_storage_block() {
    for precision in [Precision::F64, Precision::F32] {
        let Some(engine) = engine(precision) else {
            return;
        };
        for (board, views, seed) in [(BOARD_9X6, 30, 5), (BOARD_20X15, 3, 8)] {
            let data = board_data(board, views, seed);
            let batch = candidates(&data, 40, seed + 1);
            let (mut windows, mut storage) = (
                GpuBackend::new(&data, &engine),
                GpuBackend::new(&data, &engine),
            );
            windows.set_rows(Some(Rows::Uniform));
            storage.set_rows(Some(Rows::Storage));
            let (deviations, in_windows) = compare(&data, &windows, &batch);
            for (name, d) in deviations {
                let Some(bound) = view_sum_bound(precision, name) else {
                    continue;
                };
                assert!(
                    d.relative <= bound,
                    "{precision} {views} views {name}: {:e}",
                    d.relative
                );
            }
            let (_, in_storage) = compare(&data, &storage, &batch);
            assert_eq!(
                in_windows, in_storage,
                "{precision} {views} views: the binding changed a value"
            );
        }
    }
}

/// The reprojection kernel projects each corner from its observed air ray without the
/// safeguards of the full forward projection where every medium is at least as dense as the air
/// around the cameras, and marks the views it does not settle for a second kernel with the full
/// projection. A port layer of index 1.0 behind air of 1.003 (ρ < 1) sends every view there: the
/// costs still match the CPU in both precisions.
#[test]
fn a_layer_less_dense_than_air_takes_the_safeguarded_projection() {
    let path = std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/data/example_rig.json"
    ));
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    assert_eq!(json["interface"]["index_air"], 1.003);
    json["interface"]["layers"][0]["index"] = 1.0.into();
    let rig = flatport::io::rig_from_json_str(&json.to_string(), path).expect("rig");
    let spec = SceneSpec::pair(Target::Board(BOARD_9X6), 5, 0.1, 17, 0, 1);
    let scene = simulate(&rig, &spec).expect("simulated scene");
    let data =
        StereoData::from_observations(&rig, [0, 1], &scene.observations).expect("stereo data");
    let batch = candidates(&data, 30, 4);
    let cpu = CpuBackend::new(&data)
        .costs(CostKind::Reprojection, &batch)
        .unwrap();
    for (precision, bound) in [
        (Precision::F64, F64_RELATIVE),
        (Precision::F32, F32_RELATIVE),
    ] {
        let Some(engine) = engine(precision) else {
            return;
        };
        let gpu = GpuBackend::new(&data, &engine)
            .costs(CostKind::Reprojection, &batch)
            .unwrap();
        let d = deviation("reprojection", &cpu, &gpu);
        assert!(gpu[0].is_finite(), "{precision}: the true interface");
        assert!(
            d.relative <= bound,
            "{precision} reprojection: {:e}",
            d.relative
        );
    }
}

/// A profile (air layer solved per axis, then the cost) agrees across the backends.
#[test]
fn profiles_match_the_cpu_reference() {
    let Some(engine) = engine(Precision::F64) else {
        return;
    };
    let data = stereo_data(4, 11);
    let normals: Vec<_> = candidates(&data, 20, 5).iter().map(|c| c.normal).collect();
    let (cpu, gpu) = (CpuBackend::new(&data), GpuBackend::new(&data, &engine));
    for kind in [CostKind::Reprojection, CostKind::AffineGrid] {
        let (c, g) = (
            cpu.profile(kind, &normals).unwrap().1,
            gpu.profile(kind, &normals).unwrap().1,
        );
        let d = deviation(kind.name(), &c, &g);
        assert!(
            d.relative <= F64_RELATIVE,
            "profile {}: {:e}",
            kind.name(),
            d.relative
        );
    }
}

/// Times one batch of 1230 candidates (15 views of 54 corners) for the affine-grid and
/// reprojection costs on the CPU and on the GPU in f32 and f64; the GPU after one warm-up call
/// (pipeline compilation). `cargo test --release --test calib_gpu -- --ignored --nocapture`.
#[test]
#[ignore = "timing"]
fn time_a_1230_candidate_batch() {
    let data = stereo_data(15, 3);
    let batch = candidates(&data, 1230, 21);
    let time = |backend: &dyn CostBackend, kind: CostKind| {
        let started = std::time::Instant::now();
        let costs = backend.costs(kind, &batch).unwrap();
        (
            started.elapsed().as_secs_f64(),
            costs.iter().filter(|c| c.is_finite()).count(),
        )
    };
    for kind in [CostKind::AffineGrid, CostKind::Reprojection] {
        let cpu = CpuBackend::new(&data);
        let (seconds, finite) = time(&cpu, kind);
        eprintln!(
            "{:>12} {}: {seconds:.3} s ({finite} finite)",
            kind.name(),
            cpu.describe()
        );
        for precision in [Precision::F32, Precision::F64] {
            let Some(engine) = engine(precision) else {
                return;
            };
            let gpu = GpuBackend::new(&data, &engine);
            time(&gpu, kind);
            let (seconds, finite) = time(&gpu, kind);
            eprintln!(
                "{:>12} {}: {seconds:.3} s ({finite} finite)",
                kind.name(),
                gpu.describe()
            );
        }
    }
}

/// Issue 13: the per-corner data go to the device once per backend and stay there across the
/// many small calls of a stencil refinement (7 candidates a call), every call still matching the
/// CPU; a backend over other data (the same engine) uploads its own and matches the CPU on them.
#[test]
fn corner_data_stay_on_the_device_across_small_calls() {
    let Some(engine) = engine(Precision::F64) else {
        return;
    };
    let data = stereo_data(4, 11);
    let batch = candidates(&data, 70, 31);
    let (cpu, gpu) = (CpuBackend::new(&data), GpuBackend::new(&data, &engine));
    assert_eq!(gpu.uploads(), 0, "nothing uploaded before a call");
    for stencil in batch.chunks(7) {
        for kind in CostKind::ALL {
            let (c, g) = (
                cpu.costs(kind, stencil).unwrap(),
                gpu.costs(kind, stencil).unwrap(),
            );
            let d = deviation(kind.name(), &c, &g);
            assert!(
                d.relative <= F64_RELATIVE,
                "{}: {:e}",
                kind.name(),
                d.relative
            );
        }
        let normals: Vec<_> = stencil.iter().map(|c| c.normal).collect();
        let (c, g) = (
            cpu.air_distances(&normals).unwrap(),
            gpu.air_distances(&normals).unwrap(),
        );
        let as_values = |d: Vec<Option<f64>>| -> Vec<f64> {
            d.into_iter().map(|d| d.unwrap_or(f64::INFINITY)).collect()
        };
        let d = deviation("air-distance", &as_values(c), &as_values(g));
        assert!(d.relative <= F64_RELATIVE, "air-distance: {:e}", d.relative);
    }
    // Air rays (ray gap), VOP rows (plane errors), affine-grid input, scene-fit input: once each.
    assert_eq!(
        gpu.uploads(),
        4,
        "each input uploaded once over 10 × 8 calls"
    );
    let other = stereo_data(6, 99);
    let on_other = gpu.over(&other);
    let cpu_other = CpuBackend::new(&other);
    for kind in CostKind::ALL {
        let (c, g) = (
            cpu_other.costs(kind, &batch[..7]).unwrap(),
            on_other.costs(kind, &batch[..7]).unwrap(),
        );
        let d = deviation(kind.name(), &c, &g);
        assert!(
            d.relative <= F64_RELATIVE,
            "other data {}: {:e}",
            kind.name(),
            d.relative
        );
    }
    // And the first backend still answers for its own data.
    let (c, g) = (
        cpu.costs(CostKind::Reprojection, &batch[..7]).unwrap(),
        gpu.costs(CostKind::Reprojection, &batch[..7]).unwrap(),
    );
    assert!(deviation("reprojection again", &c, &g).relative <= F64_RELATIVE);
    assert_eq!(gpu.uploads(), 4, "still resident after another backend ran");
}

/// Two housings (data/rigs/housings.json, a port per camera), 12 noise-free views: at the true
/// port of the first camera every triangulating cost is zero and its profile's air layer is the
/// true one, on the CPU and in both GPU precisions. The candidates move the first camera's port
/// only; the second camera's stays where the rig has it. (Moving both, the GPU put the minimum of
/// a 17 × 16 sweep 8° from the truth, and the CPU's profile moved the second camera's origins
/// with the air layer: 0.19 px at the truth, the profile's air layer 10.2 mm for 12 mm.)
#[test]
fn a_port_per_camera_moves_only_the_first_cameras_port() {
    let rig = flatport::io::read_rig(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/data/rigs/housings.json"
    )))
    .expect("housings rig");
    let flatport::model::Ports::PerCamera(ports) = rig.ports() else {
        panic!("housings.json has a port per camera");
    };
    // The first camera's port, in its frame (the candidates' convention behind a port each).
    let (normal, distance) = (*ports[0].normal(), ports[0].air_distance());
    let scene = simulate(
        &rig,
        &SceneSpec::pair(Target::Board(BOARD_9X6), 12, 0.0, 3, 0, 1),
    )
    .expect("scene");
    let data =
        StereoData::from_observations(&rig, [0, 1], &scene.observations).expect("stereo data");
    let truth = Candidate {
        normal,
        air_distance: distance,
    };
    // Bounds: f64 rounding; f32 as the constants above say for its air layer, and ≈ 5e-5 px of
    // rounded air rays per corner (measured 8.4e-5 px, 2.2e-7 m at the truth).
    let check = |name: &str, backend: &dyn CostBackend, pixels: f64, metres: f64, air: f64| {
        let (profiled, profile) = backend
            .profile(CostKind::Reprojection, &[normal])
            .expect("profile");
        let at_truth = |kind| backend.costs(kind, &[truth]).expect("costs")[0];
        let (reprojection, scene) = (at_truth(CostKind::Reprojection), at_truth(CostKind::Scene));
        eprintln!(
            "{name}: profile air layer {:.9} m ({:.2e} px), at the truth {reprojection:.2e} px, {scene:.2e} m",
            profiled[0].air_distance, profile[0]
        );
        assert!(
            (profiled[0].air_distance - distance).abs() <= air,
            "{name}: profile air layer {} m, truth {distance} m",
            profiled[0].air_distance
        );
        assert!(profile[0] <= pixels, "{name}: profile {} px", profile[0]);
        assert!(reprojection <= pixels, "{name}: {reprojection} px");
        assert!(scene <= metres, "{name}: {scene} m");
    };
    check("cpu", &CpuBackend::new(&data), 1e-9, 1e-12, 1e-9);
    for precision in [Precision::F64, Precision::F32] {
        let Some(engine) = engine(precision) else {
            return;
        };
        let gpu = GpuBackend::new(&data, &engine);
        match precision {
            Precision::F64 => check("gpu f64", &gpu, 1e-9, 1e-12, 1e-9),
            Precision::F32 => check("gpu f32", &gpu, 5e-4, 1e-6, F32_AIR_DISTANCE),
        }
    }
}

/// Two housings whose ports have different layer stacks: one camera behind a bare interface, the
/// other behind three layers, in both orders (the candidates move the first camera's port). The
/// kernels run their layer loops to the rig's most layers (`RIG_LAYERS`), each camera to its own
/// count: a camera given the other's layers, or a later layer that is not masked off where a
/// camera has fewer, moves its rays and fails the comparison.
#[test]
fn cameras_with_different_layer_stacks_match_the_cpu_reference() {
    for bare_first in [true, false] {
        let rig = gpu_harness::rig_with_layer_stacks(bare_first);
        let flatport::model::Ports::PerCamera(ports) = rig.ports() else {
            panic!("a port per camera");
        };
        let layers: Vec<usize> = [0, 1]
            .map(|k| rig.refractive_camera(k).layers().len())
            .into();
        let scene = simulate(
            &rig,
            &SceneSpec::pair(Target::Board(BOARD_9X6), 6, 0.1, 21, 0, 1),
        )
        .expect("scene");
        let data =
            StereoData::from_observations(&rig, [0, 1], &scene.observations).expect("stereo data");
        // The truth and axes tilted up to 4° from it with air layers of 8–25 mm, in the first
        // camera's frame.
        let (normal, distance) = (*ports[0].normal(), ports[0].air_distance());
        let mut random = Random(17);
        let mut batch = vec![Candidate {
            normal,
            air_distance: distance,
        }];
        while batch.len() < 24 {
            let tilt = flatport::model::normal_from_tilt_azimuth(
                random.range(0.0, 4f64.to_radians()),
                random.range(0.0, std::f64::consts::TAU),
            );
            let rotation = nalgebra::Rotation3::rotation_between(&Vector3::z(), &normal)
                .expect("axis not opposite z");
            batch.push(Candidate {
                normal: Unit::new_normalize(rotation * tilt.into_inner()),
                air_distance: random.range(0.008, 0.025),
            });
        }
        let normals: Vec<_> = batch.iter().map(|c| c.normal).collect();
        let cpu = CpuBackend::new(&data);
        for precision in [Precision::F64, Precision::F32] {
            let Some(engine) = engine(precision) else {
                return;
            };
            let gpu = GpuBackend::new(&data, &engine);
            let (relative, air) = match precision {
                Precision::F64 => (F64_RELATIVE, 1e-9),
                Precision::F32 => (F32_RELATIVE, F32_AIR_DISTANCE),
            };
            for kind in [CostKind::Reprojection, CostKind::Scene] {
                let (c, g) = (
                    cpu.costs(kind, &batch).unwrap(),
                    gpu.costs(kind, &batch).unwrap(),
                );
                let d = deviation(kind.name(), &c, &g);
                eprintln!(
                    "layers {layers:?}, {precision} {}: relative {:.1e}, {} without an answer",
                    kind.name(),
                    d.relative,
                    d.infinite
                );
                assert!(c[0].is_finite(), "{}: the truth has a cost", kind.name());
                assert!(
                    d.relative <= relative,
                    "layers {layers:?}, {precision} {}: relative {:e}",
                    kind.name(),
                    d.relative
                );
            }
            let (c, g) = (
                cpu.air_distances(&normals).unwrap(),
                gpu.air_distances(&normals).unwrap(),
            );
            for (k, (c, g)) in c.iter().zip(&g).enumerate() {
                let (c, g) = (c.expect("cpu air layer"), g.expect("gpu air layer"));
                assert!(
                    (c - g).abs() <= air,
                    "layers {layers:?}, {precision} air layer {k}: cpu {c}, gpu {g}"
                );
            }
        }
    }
}
