//! The CPU figures of `flatport bench`: each relation on the scalar and the vector path, one
//! thread and all; the affine-grid sweep; the memory triad as the CPU's roof; and where the vector
//! path's time goes against the floor of its square roots and divisions.

use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use flatport::calib::{CostBackend, CostKind, CpuBackend};
use flatport::engine::workload::Workload;
use flatport::engine::{CpuEngine, CpuPath};
use flatport::model::RefractiveCamera;

use super::record::{Figure, Measure, Recorder};
use super::{Setup, fastest};

/// The relations on both CPU paths, one thread and all threads, the paths taking turns run by
/// run; then the affine-grid sweep on all threads.
pub(super) fn figures(
    setup: &Setup,
    repeats: usize,
    recorder: &mut Recorder,
) -> anyhow::Result<()> {
    let n = setup.work.pixels.len();
    let (a, b, a_pinhole, work) = (&setup.a, &setup.b, &setup.a_pinhole, &setup.work);
    let mut out6 = vec![[0.0; 6]; n];
    let mut out4 = vec![[0.0; 4]; n];
    let mut out2 = vec![[0.0; 2]; n];
    let mut status = vec![0u32; n];
    let all = CpuEngine::new(None).threads();
    for threads in [1, all] {
        let [scalar, vector] = [CpuPath::Scalar, CpuPath::Vector]
            .map(|path| CpuEngine::with_path(Some(threads), path));
        let mut pair = |kernel: &'static str, run: &mut dyn FnMut(&CpuEngine)| {
            let [t_scalar, t_vector] = alternating(repeats, [&scalar, &vector], run);
            recorder.record(
                Measure::cpu(kernel, Some("scalar"), threads, "end_to_end"),
                t_scalar,
            );
            recorder.record(
                Measure::cpu(kernel, Some("vector"), threads, "end_to_end"),
                t_vector,
            );
        };
        pair("backproject", &mut |cpu| {
            cpu.backproject(a, &work.pixels, &mut out6, &mut status)
        });
        pair("backproject_pinhole", &mut |cpu| {
            cpu.backproject(a_pinhole, &work.pixels, &mut out6, &mut status)
        });
        pair("project", &mut |cpu| {
            cpu.project(a, &work.points, &mut out2, &mut status)
        });
        pair("triangulate", &mut |cpu| {
            cpu.triangulate(a, b, &work.matches, &mut out4, &mut status)
        });
        pair("vop", &mut |cpu| {
            cpu.vop(a, &work.points, &mut out6, &mut status)
        });
    }
    let backend = CpuBackend::new(&setup.sweep_data);
    let t = fastest(repeats.min(2), || {
        Ok(backend
            .costs(CostKind::AffineGrid, &setup.sweep_candidates)
            .map(drop)?)
    })?;
    recorder.record(Measure::cpu("sweep", None, all, "end_to_end"), t);
    Ok(())
}

/// Fastest of `repeats` runs of `run` on each engine after one warm-up each, the engines taking
/// turns run by run, in seconds.
pub(super) fn alternating(
    repeats: usize,
    engines: [&CpuEngine; 2],
    run: &mut dyn FnMut(&CpuEngine),
) -> [f64; 2] {
    let mut best = [f64::INFINITY; 2];
    for round in 0..=repeats.max(1) {
        for (k, engine) in engines.iter().enumerate() {
            let start = Instant::now();
            run(engine);
            if round > 0 {
                best[k] = best[k].min(start.elapsed().as_secs_f64());
            }
        }
    }
    best
}

/// The CPU clock the OS reports, in Hz (`cpu MHz` of /proc/cpuinfo; the nominal clock in a
/// virtual machine, not the boost clock), where there is one.
pub(super) fn cpu_clock_hz() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("cpu MHz"))?;
    let mhz: f64 = line.split(':').nth(1)?.trim().parse().ok()?;
    (mhz > 0.0).then_some(mhz * 1e6)
}

/// The CPU's model name (`model name` of /proc/cpuinfo), else what the standard library knows.
pub(super) fn cpu_model() -> String {
    let model = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|text| {
            let line = text.lines().find(|l| l.starts_with("model name"))?;
            Some(line.split(':').nth(1)?.trim().to_string())
        });
    model.unwrap_or_else(|| std::env::consts::ARCH.to_string())
}

/// STREAM triad a = b + s·c over 3 × 64 MiB arrays on all cores: bytes read and written per
/// second (24 per element, write-allocate traffic not counted), best of 5.
pub(super) fn memory_stream_bandwidth() -> f64 {
    let n = 8 << 20;
    let b = vec![1.0f64; n];
    let c = vec![2.0f64; n];
    let mut a = vec![0.0f64; n];
    let mut best = f64::INFINITY;
    for k in 0..6 {
        let s = 0.5 + k as f64;
        let start = Instant::now();
        a.par_chunks_mut(1 << 16)
            .zip(b.par_chunks(1 << 16))
            .zip(c.par_chunks(1 << 16))
            .for_each(|((a, b), c)| {
                for ((a, b), c) in a.iter_mut().zip(b).zip(c) {
                    *a = b + s * c;
                }
            });
        if k > 0 {
            best = best.min(start.elapsed().as_secs_f64());
        }
    }
    std::hint::black_box(&a);
    24.0 * n as f64 / best
}

/// The vector path's cost per item against the floor of its √ and ÷ alone.
#[derive(Debug, Serialize)]
pub(super) struct Floors {
    /// Cost of one √ and one ÷ per f64 lane on this machine, measured in this run (cycles).
    sqrt_cycles_per_lane: f64,
    div_cycles_per_lane: f64,
    kernels: Vec<Floor>,
}

#[derive(Debug, Serialize)]
struct Floor {
    kernel: &'static str,
    /// √ and ÷ per item that the relation cannot do without (the scalar model's count, with its
    /// iteration counts measured on this workload).
    sqrt_per_item: f64,
    div_per_item: f64,
    floor_cycles_per_item: f64,
    /// The vector path, one thread, this run.
    cycles_per_item: Option<f64>,
}

/// Prints and returns, for each CPU relation, its cycles per item on the vector path against the
/// floor set by its square roots and divisions alone, each costed at this machine's measured
/// throughput per lane. The counts are the scalar model's per row:
/// - back-projection: √(1 + x² + y²) and its reciprocal, the water's √ and 1/cos a, per layer one
///   √ and one ÷; with distortion one √ (the tolerance) and one ÷ per Newton step of the
///   undistortion (steps per block of lanes, measured);
/// - forward projection: √ of r, the start's two ÷, per Newton iteration (mean over the workload,
///   measured) one √ and one ÷ per medium but the reference and the step's ÷, then √q and 1/z;
/// - triangulation: two back-projections, the residual's √ and two ÷.
pub(super) fn where_the_time_goes(
    a: &RefractiveCamera,
    a_pinhole: &RefractiveCamera,
    work: &Workload,
    results: &[Figure],
    clock_hz: Option<f64>,
) -> Option<Floors> {
    let hz = clock_hz?;
    let (sqrt_s, div_s) = flatport::engine::cpu::lanes::sqrt_div_seconds(200_000);
    let (sqrt_c, div_c) = (sqrt_s * hz, div_s * hz);
    let layers = a.layers().len() as f64;
    let backproject = |camera: &RefractiveCamera| {
        let steps = flatport::engine::cpu::lanes::undistortion_steps(camera, &work.pixels);
        let distorts = if camera.intrinsics().has_distortion() {
            1.0
        } else {
            0.0
        };
        (2.0 + layers + distorts, 2.0 + layers + steps)
    };
    let iterations: Vec<u32> = work
        .points
        .iter()
        .filter_map(|p| {
            a.air_path_to(&nalgebra::Point3::new(p[0], p[1], p[2]))
                .ok()
                .map(|path| path.iterations)
        })
        .collect();
    let mean_iterations =
        iterations.iter().map(|&i| f64::from(i)).sum::<f64>() / iterations.len().max(1) as f64;
    let media = layers + 2.0;
    let project = (
        2.0 + mean_iterations * (media - 1.0),
        3.0 + mean_iterations * media,
    );
    let (bp, bp_pinhole) = (backproject(a), backproject(a_pinhole));
    let triangulate = (2.0 * bp.0 + 1.0, 2.0 * bp.1 + 2.0);
    let measured = |kernel: &str| {
        results
            .iter()
            .find(|f| f.kernel == kernel && f.cpu_path == Some("vector") && f.threads == 1)
            .and_then(|f| f.cycles_per_item)
    };
    outln!("
where the time goes (vector path, one thread; √ {sqrt_c:.1} and ÷ {div_c:.1} cycles per lane, measured; {mean_iterations:.2} Newton iterations per projected point):");
    let kernels: Vec<Floor> = [
        ("backproject", bp),
        ("backproject_pinhole", bp_pinhole),
        ("project", project),
        ("triangulate", triangulate),
    ]
    .into_iter()
    .map(|(kernel, (sqrt, div))| {
        let floor = sqrt * sqrt_c + div * div_c;
        let cycles = measured(kernel);
        let shown = cycles
            .map(|c| format!("{c:6.0} cycles/item = {:4.1}× the floor", c / floor))
            .unwrap_or_default();
        outln!(
            "  {kernel:19} {sqrt:5.1} √ + {div:5.1} ÷ per item: floor {floor:5.1} cycles; {shown}"
        );
        Floor {
            kernel,
            sqrt_per_item: sqrt,
            div_per_item: div,
            floor_cycles_per_item: floor,
            cycles_per_item: cycles,
        }
    })
    .collect();
    Some(Floors {
        sqrt_cycles_per_lane: sqrt_c,
        div_cycles_per_lane: div_c,
        kernels,
    })
}
