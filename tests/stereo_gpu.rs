//! Dense stereo's GPU stages (src/stereo/gpu, shaders/stereo) against the CPU path on rendered
//! scenes, on lavapipe in CI: the same depths and the same valid pixels within bounds that f32
//! against f64 allows, the GPU's depths against the renderer's exact depth (an independent
//! oracle, the CPU path's acceptance levels), frames reusing one device, and a volume over the
//! adapter's limits refused by name. Release mode: `cargo test --release --test stereo_gpu`.
#![cfg(feature = "gpu")]

mod stereo_common;

use flatport::model::Rig;
use flatport::stereo::gpu::GpuStereo;
use flatport::stereo::{Backend, DepthMap, StereoOptions, stereo_on};
use stereo_common::*;

/// The GPU stereo on the first adapter, or `None` (with a note) when there is none outside CI.
fn device() -> Option<GpuStereo> {
    match GpuStereo::new(None) {
        Ok(device) => {
            eprintln!("GPU adapter: {}", device.context().adapter().name);
            Some(device)
        }
        Err(e) if std::env::var_os("CI").is_none() => {
            eprintln!("SKIPPED (no Vulkan adapter; CI fails here instead): {e}");
            None
        }
        Err(e) => panic!("CI needs a Vulkan adapter (scripts/test.sh installs lavapipe): {e}"),
    }
}

fn options(range: (f64, f64)) -> StereoOptions {
    StereoOptions {
        depth_range: Some(range),
        ..StereoOptions::default()
    }
}

/// How the two maps compare: valid masks, and depths in hypothesis steps where both are valid.
#[derive(Debug)]
struct Agreement {
    /// Pixels where both or neither have a depth, of all.
    mask: f64,
    /// Of the pixels valid in both, those within `STEP_BOUND` steps.
    close: f64,
    /// Median |Δ(1/z)| / Δq over the pixels valid in both.
    median_steps: f64,
    both: usize,
}

/// Depth agreement within a quarter of a hypothesis step (in 1/z, the sweep's own unit).
const STEP_BOUND: f64 = 0.25;

fn agreement(cpu: &DepthMap, gpu: &DepthMap) -> Agreement {
    let (min, max) = cpu.depth_range;
    let step = (1.0 / min - 1.0 / max) / (cpu.hypotheses - 1) as f64;
    let n = cpu.depth.len();
    let mut same_mask = 0;
    let mut steps = Vec::new();
    for i in 0..n {
        let (a, b) = (cpu.depth[i], gpu.depth[i]);
        if a.is_finite() == b.is_finite() {
            same_mask += 1;
        }
        if a.is_finite() && b.is_finite() {
            steps.push((1.0 / f64::from(a) - 1.0 / f64::from(b)).abs() / step);
        }
    }
    let close = steps.iter().filter(|s| **s <= STEP_BOUND).count();
    let both = steps.len();
    steps.sort_by(f64::total_cmp);
    Agreement {
        mask: same_mask as f64 / n as f64,
        close: close as f64 / both.max(1) as f64,
        median_steps: steps.get(both / 2).copied().unwrap_or(f64::NAN),
        both,
    }
}

/// Why these bounds. The GPU computes the costs in f32 (rays, projections to ~1e-3 px, bilinear
/// samples, window sums down strips of rows) and rounds them to the same u16 units as the CPU's f64
/// path: most costs are equal, a few differ by one unit (1/2047 of the range) where the f64 value
/// lies within f32's error of a rounding boundary. SGM and the selection are the same integer
/// arithmetic, so a pixel's winner changes only where two hypotheses' aggregated costs are within a
/// few units: then the winner (and the parabola) may move by a step, and the masks may differ where
/// the confidence, the consistency check or a depth edge sits at its threshold. Such pixels are
/// rare on a textured scene: at most 1 % with a depth more than a quarter step apart (the
/// refinement itself differs by < 0.01 step for equal costs) and at most 2 % of the pixels with one
/// map valid and the other not.
fn assert_agreement(name: &str, a: &Agreement) {
    eprintln!("{name}: {a:?}");
    assert!(
        a.both > 20_000,
        "{name}: only {} pixels valid in both",
        a.both
    );
    assert!(a.mask >= 0.98, "{name}: valid masks differ: {a:?}");
    assert!(a.close >= 0.99, "{name}: depths differ: {a:?}");
    assert!(a.median_steps <= 0.02, "{name}: depths differ: {a:?}");
}

fn both_ways(
    rig: &Rig,
    scene: &flatport::render::TexturedScene,
    range: (f64, f64),
    device: &GpuStereo,
) -> (DepthMap, DepthMap, Rendered) {
    let rendered = render_all(rig, scene, 2.0);
    let options = options(range);
    let started = std::time::Instant::now();
    let cpu = stereo_on(rig, &rendered.images, &options, Backend::Cpu, &|_| {}).unwrap();
    let cpu_s = started.elapsed().as_secs_f64();
    let started = std::time::Instant::now();
    let gpu = stereo_on(
        rig,
        &rendered.images,
        &options,
        Backend::Gpu(device),
        &|_| {},
    )
    .unwrap();
    eprintln!(
        "cpu {cpu_s:.2} s {:?}; gpu {:.2} s {:?}",
        cpu.stage_seconds,
        started.elapsed().as_secs_f64(),
        gpu.stage_seconds
    );
    (cpu, gpu, rendered)
}

#[test]
fn gpu_and_cpu_agree_on_a_shared_port_pair() {
    let Some(device) = device() else { return };
    let rig = rig(SHARED_PORT_PAIR);
    let scene = scene(vec![seabed(1.6, 3), sphere([0.12, 0.05, 1.3], 0.15, 12)]);
    let (cpu, gpu, rendered) = both_ways(&rig, &scene, (0.8, 2.5), &device);
    assert_agreement("shared port", &agreement(&cpu, &gpu));
    // The GPU's depths against the renderer's (not the CPU's): the CPU path's acceptance levels.
    let seen = seen_by_another(&rig, 0, &rendered);
    let a = accuracy(&gpu, &rendered.depths[0], &seen);
    eprintln!("gpu accuracy: {a:?}");
    assert!(
        a.valid_fraction >= 0.85 && a.median <= 0.003 && a.within_2 >= 0.93,
        "{a:?}"
    );
    assert!(
        a.periphery_median <= 0.005 && a.unseen_gross <= 0.05,
        "{a:?}"
    );
    // A second frame on the same device (pipelines and buffers reused): the same map.
    let again = stereo_on(
        &rig,
        &rendered.images,
        &options((0.8, 2.5)),
        Backend::Gpu(&device),
        &|_| {},
    )
    .unwrap();
    assert!(
        again
            .depth
            .iter()
            .zip(&gpu.depth)
            .all(|(a, b)| a.to_bits() == b.to_bits()),
        "a second frame differs"
    );
}

#[test]
fn gpu_and_cpu_agree_with_three_cameras_above_water() {
    // Two SGM lines a workgroup (the default is 8).
    let Some(device) = device().map(|d| d.with_sgm_lines(2)) else {
        return;
    };
    let rig = rig(ABOVE_WATER_TRIO);
    let scene = scene(vec![seabed(1.5, 5), sphere([0.1, 0.08, 1.3], 0.12, 32)]);
    let (cpu, gpu, _) = both_ways(&rig, &scene, (0.9, 2.2), &device);
    assert_agreement("three cameras", &agreement(&cpu, &gpu));
}

/// Four paths, a hypothesis count that no lane count divides, one SGM line a workgroup.
#[test]
fn gpu_and_cpu_agree_with_four_paths_and_an_odd_hypothesis_count() {
    let Some(device) = device().map(|d| d.with_sgm_lines(1)) else {
        return;
    };
    let rig = rig(SHARED_PORT_PAIR);
    let scene = scene(vec![seabed(1.6, 3), sphere([0.12, 0.05, 1.3], 0.15, 12)]);
    let rendered = render_all(&rig, &scene, 2.0);
    let options = StereoOptions {
        hypotheses: Some(97),
        paths: 4,
        ..options((0.8, 2.5))
    };
    let cpu = stereo_on(&rig, &rendered.images, &options, Backend::Cpu, &|_| {}).unwrap();
    let gpu = stereo_on(
        &rig,
        &rendered.images,
        &options,
        Backend::Gpu(&device),
        &|_| {},
    )
    .unwrap();
    assert_agreement("four paths, 97 hypotheses", &agreement(&cpu, &gpu));
}

#[test]
fn a_volume_over_the_adapter_limits_is_refused_by_name() {
    let Some(device) = device() else { return };
    let cap = device.context().max_storage_binding() as usize;
    // The volumes are u16 per (pixel, hypothesis), packed two a word: W·H·D·2 bytes for an even
    // D. One exactly at the cap fits; one word a pixel (two hypotheses) more does not.
    let (w, h) = (1024, 1024);
    let d = cap / (w * h * 2);
    if (3..=1024).contains(&d) && d.is_multiple_of(2) {
        assert!(device.refuses(w, h, d, 1).is_none(), "{d} hypotheses fit");
    }
    let d = d + 2;
    let reason = device.refuses(w, h, d.max(3), 1);
    if d <= 1024 {
        let reason = reason.expect("over the cap");
        assert!(
            reason.contains("storage binding") && reason.contains("--device cpu"),
            "{reason}"
        );
    }
    assert!(device.refuses(320, 256, 128, 1).is_none());
    assert!(
        device
            .refuses(320, 256, 128, 9)
            .unwrap()
            .contains("at most 8")
    );
    assert!(
        device
            .refuses(320, 256, 2000, 1)
            .unwrap()
            .contains("at most 1024")
    );
}

/// `Sweep` in src/stereo/gpu/mod.rs mirrors `struct Sweep` in shaders/stereo/sweep.wgsl: the same
/// size as naga's layouter gives it (no GPU needed).
#[test]
fn the_sweep_uniform_matches_its_wgsl_struct() {
    use flatport::gpu::{Precision, Rows, source};
    let text = source(
        &flatport::stereo::gpu::kernels::COST,
        Precision::F32,
        Rows::Storage,
    );
    let module = naga::front::wgsl::parse_str(&text).unwrap_or_else(|e| panic!("{e}"));
    let mut layouter = naga::proc::Layouter::default();
    layouter.update(module.to_ctx()).unwrap();
    let (handle, _) = module
        .types
        .iter()
        .find(|(_, t)| t.name.as_deref() == Some("Sweep"))
        .expect("struct Sweep");
    assert_eq!(
        layouter[handle].size as usize,
        std::mem::size_of::<flatport::stereo::gpu::Sweep>()
    );
}
