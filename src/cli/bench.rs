//! `flatport bench`: items per second of back-projection, forward projection and triangulation on
//! every path (CPU f64 scalar and vector, one thread and all threads; GPU f32 and f64, kernel-only
//! and end to end), where the CPU vector path's time goes, and the machine's memory streaming
//! bandwidth as the physical limit, from one run.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use clap::Args;
use rayon::prelude::*;
use serde::Serialize;

use flatport::calib::{
    Board, Candidate, CostBackend, CostKind, CpuBackend, GpuBackend, SceneSpec, StereoData, Target,
    simulate,
};
use flatport::engine::GpuEngine;
use flatport::engine::gpu::kernels;
use flatport::engine::workload::{Workload, without_distortion};
use flatport::engine::{CpuEngine, CpuPath};
use flatport::gpu::{GpuContext, KernelSource, Precision, STREAM_CHUNK_ROWS};
use flatport::io::{rig_from_json_str, write_atomic};
use flatport::model::{RefractiveCamera, Rig, normal_from_tilt_azimuth};

use super::demo::EXAMPLE_RIG;

/// `flatport bench`
#[derive(Debug, Args)]
pub struct BenchArgs {
    /// Items per batch (at most 16777216)
    #[arg(long, default_value_t = 1 << 20, allow_negative_numbers = true)]
    items: usize,
    /// Timed repetitions per figure (the fastest counts; 1 to 1000)
    #[arg(long, default_value_t = 3, allow_negative_numbers = true)]
    repeats: usize,
    /// Also write the results as JSON
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Rig to measure on (default: the built-in example)
    #[arg(long, value_name = "RIG.json")]
    rig: Option<PathBuf>,
    /// GPU adapter: its index or part of its name as `flatport info` lists them (else $FLATPORT_ADAPTER, else the best)
    #[arg(long, value_name = "NAME")]
    adapter: Option<String>,
    /// Skip the GPU paths
    #[arg(long)]
    no_gpu: bool,
    /// Axis cells of the invariant sweep figure (over about 10 000 correspondences; at most 1048576)
    #[arg(
        long,
        value_name = "CELLS",
        default_value_t = 4096,
        allow_negative_numbers = true
    )]
    sweep_cells: usize,
}

/// The sweep workload: 185 simulated views of a 9×6 board (9 990 correspondences) by the first
/// two cameras, and a square tilt × azimuth grid of about `cells` axes (tilts 0–20°).
fn sweep_workload(rig: &Rig, cells: usize) -> anyhow::Result<(StereoData, Vec<Candidate>)> {
    let board = Target::Board(Board {
        rows: 6,
        cols: 9,
        square: 0.04,
    });
    let scene = simulate(rig, &SceneSpec::pair(board, 185, 0.1, 1, 0, 1))?;
    let data = StereoData::from_observations(rig, [0, 1], &scene.observations)?;
    let side = (cells.max(1) as f64).sqrt().ceil() as usize;
    let candidates = (0..side * side)
        .map(|k| {
            let tilt = 20f64.to_radians() * (k / side) as f64 / side as f64;
            let azimuth =
                std::f64::consts::TAU * (k % side) as f64 / side as f64 - std::f64::consts::PI;
            Candidate {
                normal: normal_from_tilt_azimuth(tilt, azimuth),
                air_distance: f64::NAN,
            }
        })
        .collect();
    Ok((data, candidates))
}

/// One figure of the JSON report.
#[derive(Debug, Serialize)]
struct Figure {
    kernel: &'static str,
    path: &'static str,
    /// On the CPU: `scalar` (the model row by row) or `vector` (the lanes of `engine::cpu::lanes`).
    #[serde(skip_serializing_if = "Option::is_none")]
    cpu_path: Option<&'static str>,
    precision: &'static str,
    threads: usize,
    stage: &'static str,
    /// The clock: `host` (wall clock around the work) or `gpu_timestamp` (GPU timestamps around
    /// the compute pass, for the GPU `kernel` stage where the adapter has TIMESTAMP_QUERY).
    timer: &'static str,
    items: usize,
    items_per_s: f64,
    /// For one CPU thread: cycles per item at the clock the OS reports (`cpu_clock_hz`).
    #[serde(skip_serializing_if = "Option::is_none")]
    cycles_per_item: Option<f64>,
}

#[derive(Debug, Serialize)]
struct Report {
    memory_stream_bytes_per_s: f64,
    /// What ran: the CPU's threads, the vector path's instruction set, the GPU adapter.
    cpu_threads: usize,
    cpu_instruction_set: &'static str,
    /// The clock the OS reports (/proc/cpuinfo), which `cycles_per_item` counts in.
    cpu_clock_hz: Option<f64>,
    /// Where the time goes on the vector path, one thread.
    floors: Option<Floors>,
    gpu_adapter: Option<String>,
    results: Vec<Figure>,
}

/// The vector path's cost per item against the floor of its √ and ÷ alone.
#[derive(Debug, Serialize)]
struct Floors {
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

/// Fastest of `repeats` runs of `run` on each engine after one warm-up each, the engines taking
/// turns run by run, in seconds.
fn alternating(
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
fn cpu_clock_hz() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("cpu MHz"))?;
    let mhz: f64 = line.split(':').nth(1)?.trim().parse().ok()?;
    (mhz > 0.0).then_some(mhz * 1e6)
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
fn where_the_time_goes(
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

/// Fastest of `repeats` runs of `f` after one warm-up, in seconds.
fn fastest(repeats: usize, mut f: impl FnMut() -> anyhow::Result<()>) -> anyhow::Result<f64> {
    f()?;
    let mut best = f64::INFINITY;
    for _ in 0..repeats.max(1) {
        let start = Instant::now();
        f()?;
        best = best.min(start.elapsed().as_secs_f64());
    }
    Ok(best)
}

/// STREAM triad a = b + s·c over 3 × 64 MiB arrays on all cores: bytes read and written per
/// second (24 per element, write-allocate traffic not counted), best of 5.
fn memory_stream_bandwidth() -> f64 {
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

fn human(rate: f64) -> String {
    if rate >= 1e9 {
        format!("{:7.2} G/s", rate / 1e9)
    } else if rate >= 1e5 {
        format!("{:7.2} M/s", rate / 1e6)
    } else {
        format!("{:7.2} k/s", rate / 1e3)
    }
}

/// Bytes each bench item takes on the host: the inputs (pixels 16, points 24, matches 32), the
/// outputs (48 + 32 + 16), a status word (4), and the f32 copies for the f32-host figures
/// (pixels 8, points 12, outputs 24 + 8); the GPU paths hold as much again in buffers.
const BYTES_PER_ITEM: usize = 224;
/// Most `--items`: 2²⁴ items take about 3.8 GB on the host (and as much in GPU buffers).
pub const MAX_ITEMS: usize = 1 << 24;
/// Candidates per call of the stencil figures (a finite-difference stencil's size) and calls timed.
const STENCIL: usize = 7;
const STENCIL_CALLS: usize = 20;
/// Most `--sweep-cells`: each costs one evaluation over the ~10 000 correspondences per repetition.
pub const MAX_SWEEP_CELLS: usize = 1 << 20;
/// Most `--repeats`.
pub const MAX_REPEATS: usize = 1000;

/// Checks the sizes the options ask for before anything is allocated.
fn check_sizes(args: &BenchArgs) -> anyhow::Result<()> {
    if !(1..=MAX_ITEMS).contains(&args.items) {
        bail!(
            "--items {}: must lie in 1..={MAX_ITEMS} ({BYTES_PER_ITEM} bytes an item on the host, {:.1} GB at the limit, as much again on the GPU; {} items would take {:.3e} bytes)",
            args.items,
            (BYTES_PER_ITEM * MAX_ITEMS) as f64 / 1e9,
            args.items,
            args.items as f64 * BYTES_PER_ITEM as f64
        );
    }
    if !(1..=MAX_SWEEP_CELLS).contains(&args.sweep_cells) {
        bail!(
            "--sweep-cells {}: must lie in 1..={MAX_SWEEP_CELLS} (each cell is evaluated over about 10 000 correspondences per repetition)",
            args.sweep_cells
        );
    }
    if !(1..=MAX_REPEATS).contains(&args.repeats) {
        bail!("--repeats {}: must lie in 1..={MAX_REPEATS}", args.repeats);
    }
    Ok(())
}

pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    check_sizes(&args)?;
    let rig: Rig = match &args.rig {
        Some(path) => flatport::io::read_rig(path)?,
        None => rig_from_json_str(EXAMPLE_RIG, Path::new("<built-in example rig>"))?,
    };
    let n = args.items.max(1);
    eprintln!(
        "flatport bench: {n} items per batch, fastest of {} runs",
        args.repeats
    );
    let work = Workload::new(&rig, n);
    let (a, b) = (
        rig.refractive_camera(0),
        rig.refractive_camera(1.min(rig.cameras().len() - 1)),
    );
    let mut results = Vec::new();
    let (sweep_data, sweep_candidates) = sweep_workload(&rig, args.sweep_cells)?;
    let sweep_items = sweep_candidates.len() * sweep_data.corners.len();
    eprintln!(
        "sweep figures: {} axis cells × {} correspondences = {sweep_items} items (weighted affine-grid invariant)",
        sweep_candidates.len(),
        sweep_data.corners.len()
    );
    // The clock of the next figure: `host` unless a GPU kernel time sets `gpu_timestamp`.
    let next_timer = std::cell::Cell::new("host");
    // Items of the next figure where fewer than the batch were timed (a GPU kernel time: one chunk).
    let next_items = std::cell::Cell::new(None);
    // The CPU path of the next figure (`scalar`, `vector`; none for the GPU and the sweep).
    let cpu_path = std::cell::Cell::new(None);
    let clock_hz = cpu_clock_hz();
    let mut record = |kernel: &'static str,
                      path: &'static str,
                      precision: &'static str,
                      threads: usize,
                      stage: &'static str,
                      seconds: f64| {
        let timer = next_timer.replace("host");
        let items = match next_items.take() {
            Some(items) => items,
            None if kernel == "sweep" => sweep_items,
            None => n,
        };
        let items_per_s = items as f64 / seconds;
        // Cycles per item at the OS's clock, for one thread on the CPU.
        let cycles_per_item = clock_hz
            .filter(|_| path == "cpu" && threads == 1)
            .map(|hz| hz / items_per_s);
        let figure = Figure {
            kernel,
            path,
            cpu_path: cpu_path.get(),
            precision,
            threads,
            stage,
            timer,
            items,
            items_per_s,
            cycles_per_item,
        };
        let clock = if timer == "host" {
            String::new()
        } else {
            format!("  ({timer})")
        };
        let cycles = cycles_per_item
            .map(|c| format!("  {c:6.0} cycles/item"))
            .unwrap_or_default();
        let variant = cpu_path.get().unwrap_or("");
        outln!(
            "{kernel:19} {path:3} {variant:6} {precision} {threads:>3} thr {stage:10} {}{clock}{cycles}",
            human(items_per_s)
        );
        results.push(figure);
    };

    let stream = memory_stream_bandwidth();
    outln!(
        "memory streaming bandwidth (triad, all cores): {:.2} GB/s",
        stream / 1e9
    );

    let all = CpuEngine::new(None);
    let mut out6 = vec![[0.0; 6]; n];
    let mut out4 = vec![[0.0; 4]; n];
    let mut out2 = vec![[0.0; 2]; n];
    let mut status = vec![0u32; n];
    // The first camera without its distortion: the refraction alone.
    let a_pinhole = without_distortion(&rig)?.refractive_camera(0);
    let isa = flatport::engine::cpu::lanes::instruction_set();
    eprintln!("CPU paths: scalar (the model row by row) and vector ({isa}), run by run in turn");
    for threads in [1, all.threads()] {
        let [scalar, vector] = [CpuPath::Scalar, CpuPath::Vector]
            .map(|path| CpuEngine::with_path(Some(threads), path));
        let mut pair = |kernel: &'static str, run: &mut dyn FnMut(&CpuEngine)| {
            let [t_scalar, t_vector] = alternating(args.repeats, [&scalar, &vector], run);
            cpu_path.set(Some("scalar"));
            record(kernel, "cpu", "f64", threads, "end_to_end", t_scalar);
            cpu_path.set(Some("vector"));
            record(kernel, "cpu", "f64", threads, "end_to_end", t_vector);
        };
        pair("backproject", &mut |cpu| {
            cpu.backproject(&a, &work.pixels, &mut out6, &mut status)
        });
        pair("backproject_pinhole", &mut |cpu| {
            cpu.backproject(&a_pinhole, &work.pixels, &mut out6, &mut status)
        });
        pair("project", &mut |cpu| {
            cpu.project(&a, &work.points, &mut out2, &mut status)
        });
        pair("triangulate", &mut |cpu| {
            cpu.triangulate(&a, &b, &work.matches, &mut out4, &mut status)
        });
        pair("vop", &mut |cpu| {
            cpu.vop(&a, &work.points, &mut out6, &mut status)
        });
    }
    let cpu_backend = CpuBackend::new(&sweep_data);
    let t = fastest(args.repeats.min(2), || {
        Ok(cpu_backend
            .costs(CostKind::AffineGrid, &sweep_candidates)
            .map(drop)?)
    })?;
    cpu_path.set(None);
    record("sweep", "cpu", "f64", all.threads(), "end_to_end", t);

    let mut adapter = None;
    if !args.no_gpu {
        let context = GpuContext::new(args.adapter.as_deref())
            .context("the GPU paths need a Vulkan adapter (or pass --no-gpu)")?;
        adapter = Some(format!(
            "{} ({})",
            context.adapter().name,
            context.adapter().driver
        ));
        eprintln!("GPU adapter: {}", adapter.as_deref().unwrap_or_default());
        let has_f64 = context.adapter().f64;
        // The workload as a pipeline with f32 data holds it (converted before timing).
        let to_f32 = |rows: &[[f64; 3]]| -> Vec<[f32; 3]> {
            rows.iter().map(|r| r.map(|v| v as f32)).collect()
        };
        let points_f32 = to_f32(&work.points);
        let pixels_f32: Vec<[f32; 2]> = work.pixels.iter().map(|r| r.map(|v| v as f32)).collect();
        let mut out2_f32 = vec![[0.0f32; 2]; n];
        let mut out6_f32 = vec![[0.0f32; 6]; n];
        let mut gpu = GpuEngine::new(context, Precision::F32)?;
        for precision in [Precision::F32, Precision::F64] {
            if precision == Precision::F64 {
                if !has_f64 {
                    eprintln!("the adapter has no SHADER_F64: no f64 figures");
                    break;
                }
                let context = GpuContext::new(args.adapter.as_deref())?;
                gpu = GpuEngine::new(context, Precision::F64)?;
            }
            let p = precision.name();
            let kernel_only = |kernel: &KernelSource,
                               gpu: &GpuEngine,
                               a: &RefractiveCamera,
                               b: &RefractiveCamera|
             -> anyhow::Result<f64> {
                // One chunk at most: the kernel over the batch's first rows.
                let (seconds, timer, items) = match kernel.name {
                    name if name == kernels::BACKPROJECT.name => {
                        let rows = &work.pixels[..n.min(gpu.chunk_rows::<2, 6>())];
                        let (s, t) =
                            gpu.kernel_seconds::<2, 6>(kernel, a, b, rows, args.repeats)?;
                        (s, t, rows.len())
                    }
                    name if name == kernels::PROJECT.name => {
                        let rows = &work.points[..n.min(gpu.chunk_rows::<3, 2>())];
                        let (s, t) =
                            gpu.kernel_seconds::<3, 2>(kernel, a, b, rows, args.repeats)?;
                        (s, t, rows.len())
                    }
                    _ => {
                        let rows = &work.matches[..n.min(gpu.chunk_rows::<4, 4>())];
                        let (s, t) =
                            gpu.kernel_seconds::<4, 4>(kernel, a, b, rows, args.repeats)?;
                        (s, t, rows.len())
                    }
                };
                next_timer.set(timer.name());
                next_items.set(Some(items));
                Ok(seconds)
            };
            record(
                "backproject",
                "gpu",
                p,
                0,
                "kernel",
                kernel_only(&kernels::BACKPROJECT, &gpu, &a, &a)?,
            );
            let t = fastest(args.repeats, || {
                Ok(gpu.backproject(&a, &work.pixels, &mut out6, &mut status)?)
            })?;
            record("backproject", "gpu", p, 0, "end_to_end", t);
            let t = fastest(args.repeats, || {
                Ok(gpu.backproject(&a, &pixels_f32, &mut out6_f32, &mut status)?)
            })?;
            record("backproject", "gpu", p, 0, "end_to_end_f32_host", t);
            record(
                "project",
                "gpu",
                p,
                0,
                "kernel",
                kernel_only(&kernels::PROJECT, &gpu, &a, &a)?,
            );
            // Streamed through the ring in chunks of STREAM_CHUNK_ROWS, and in as few chunks as
            // the bindings allow (one here, so nothing overlaps), round by round in turn;
            // `end_to_end` is the one the engine chooses for this adapter
            // (`default_stream_chunk_rows`: one chunk on lavapipe, the ring on a hardware GPU).
            let chosen = gpu.stream_chunk_rows();
            let mut best = [f64::INFINITY; 2];
            for round in 0..=args.repeats {
                for (k, rows) in [STREAM_CHUNK_ROWS, usize::MAX].into_iter().enumerate() {
                    gpu.set_stream_chunk_rows(rows);
                    let start = Instant::now();
                    gpu.project(&a, &work.points, &mut out2, &mut status)?;
                    if round > 0 {
                        best[k] = best[k].min(start.elapsed().as_secs_f64());
                    }
                }
            }
            gpu.set_stream_chunk_rows(chosen);
            let engine_choice = if chosen == STREAM_CHUNK_ROWS {
                best[0]
            } else {
                best[1]
            };
            record("project", "gpu", p, 0, "end_to_end", engine_choice);
            record("project", "gpu", p, 0, "end_to_end_streamed", best[0]);
            record("project", "gpu", p, 0, "end_to_end_one_chunk", best[1]);
            // The same with the host's data in f32 (no conversion where the kernel is f32).
            let t = fastest(args.repeats, || {
                Ok(gpu.project(&a, &points_f32, &mut out2_f32, &mut status)?)
            })?;
            record("project", "gpu", p, 0, "end_to_end_f32_host", t);
            record(
                "triangulate",
                "gpu",
                p,
                0,
                "kernel",
                kernel_only(&kernels::TRIANGULATE, &gpu, &a, &b)?,
            );
            let t = fastest(args.repeats, || {
                Ok(gpu.triangulate(&a, &b, &work.matches, &mut out4, &mut status)?)
            })?;
            record("triangulate", "gpu", p, 0, "end_to_end", t);
            // The fused affine-grid kernel runs in f64 whatever the engine's precision: one figure.
            if precision == Precision::F64 {
                let gpu_backend = GpuBackend::new(&sweep_data, &gpu);
                let t = fastest(args.repeats.min(2), || {
                    Ok(gpu_backend
                        .costs(CostKind::AffineGrid, &sweep_candidates)
                        .map(drop)?)
                })?;
                record("sweep", "gpu", p, 0, "end_to_end", t);
                // A stencil refinement's small calls (7 candidates each) with the corner rows
                // kept on the device, and uploaded again before every call (as before they
                // stayed there).
                let true_distance = rig.shared_interface().map_or(0.02, |i| i.air_distance());
                let stencil: Vec<Candidate> = sweep_candidates
                    .iter()
                    .take(STENCIL)
                    .map(|c| Candidate {
                        normal: c.normal,
                        air_distance: true_distance,
                    })
                    .collect();
                for (kernel, kind) in [
                    ("stencil_reprojection", CostKind::Reprojection),
                    ("stencil_affine_grid", CostKind::AffineGrid),
                ] {
                    // The two ways in turn, round by round (a shared machine's load drifts);
                    // the first round warms up.
                    let mut best = [f64::INFINITY; 2];
                    for round in 0..=args.repeats {
                        for (k, evict) in [false, true].into_iter().enumerate() {
                            let start = Instant::now();
                            for _ in 0..STENCIL_CALLS {
                                if evict {
                                    gpu_backend.evict();
                                }
                                gpu_backend.costs(kind, &stencil)?;
                            }
                            if round > 0 {
                                best[k] = best[k].min(start.elapsed().as_secs_f64());
                            }
                        }
                    }
                    for (stage, t) in ["resident", "uploaded_each_call"].into_iter().zip(best) {
                        next_items.set(Some(stencil.len() * STENCIL_CALLS));
                        record(kernel, "gpu", p, 0, stage, t);
                    }
                }
            }
        }
    }

    super::bench_stereo::stereo_figures(args.adapter.as_deref(), args.no_gpu, args.repeats)?;
    let floors = where_the_time_goes(&a, &a_pinhole, &work, &results, clock_hz);
    print_ratios(&results, stream, all.threads());
    if let Some(path) = &args.json {
        let report = Report {
            memory_stream_bytes_per_s: stream,
            cpu_threads: all.threads(),
            cpu_instruction_set: isa,
            cpu_clock_hz: clock_hz,
            floors,
            gpu_adapter: adapter,
            results,
        };
        let text = serde_json::to_string_pretty(&report).context("serialising the report")?;
        write_atomic(path, text.as_bytes())?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

/// Ratios between the paths of this run, without verdicts: the speed goals, and the outside
/// reference they were set against, are in docs/performance.md, "Speed goals" (this command
/// cannot run that reference, so it does not compare against it).
fn print_ratios(results: &[Figure], stream: f64, threads: usize) {
    // A CPU figure is the vector path's unless `scalar` is asked for.
    let rate_on = |kernel: &str,
                   path: &str,
                   cpu_path: Option<&str>,
                   precision: &str,
                   threads: Option<usize>,
                   stage: &str| {
        results
            .iter()
            .find(|f| {
                f.kernel == kernel
                    && f.path == path
                    && (path != "cpu" || f.cpu_path.is_none() || f.cpu_path == cpu_path)
                    && f.precision == precision
                    && threads.is_none_or(|t| f.threads == t)
                    && f.stage == stage
            })
            .map(|f| f.items_per_s)
    };
    let rate = |kernel: &str, path: &str, precision: &str, threads: Option<usize>, stage: &str| {
        rate_on(kernel, path, Some("vector"), precision, threads, stage)
    };
    outln!("\nratios from this run (the goals are in the README, \"Speed goals\"):");
    let cpu_all = |k: &str| rate(k, "cpu", "f64", Some(threads), "end_to_end");
    let show = |name: &str, value: Option<f64>| match value {
        Some(v) => outln!("  {name:72} {v:8.2}"),
        None => outln!("  {name:72}      n/a"),
    };
    let ratio = |x: Option<f64>, y: Option<f64>| x.zip(y).map(|(x, y)| x / y);
    for kernel in [
        "backproject",
        "backproject_pinhole",
        "project",
        "triangulate",
        "vop",
    ] {
        for t in [1, threads] {
            let vector = rate_on(kernel, "cpu", Some("vector"), "f64", Some(t), "end_to_end");
            let scalar = rate_on(kernel, "cpu", Some("scalar"), "f64", Some(t), "end_to_end");
            show(
                &format!("{kernel} CPU vector / scalar, {t} thread(s)"),
                ratio(vector, scalar),
            );
        }
    }
    show(
        "backproject GPU f32 kernel / CPU f64 all threads",
        ratio(
            rate("backproject", "gpu", "f32", None, "kernel"),
            cpu_all("backproject"),
        ),
    );
    show(
        "backproject GPU f32 end to end / CPU f64 all threads",
        ratio(
            rate("backproject", "gpu", "f32", None, "end_to_end"),
            cpu_all("backproject"),
        ),
    );
    let best = results
        .iter()
        .filter(|f| f.kernel == "backproject")
        .map(|f| f.items_per_s)
        .fold(0.0, f64::max);
    show(
        "best backproject × 24 B / memory streaming bandwidth",
        Some(best * 24.0 / stream),
    );
    show(
        "project GPU f32 end to end / CPU f64 all threads",
        ratio(
            rate("project", "gpu", "f32", None, "end_to_end"),
            cpu_all("project"),
        ),
    );
    show(
        "project GPU f32 end to end, f32 host data / CPU f64 all threads",
        ratio(
            rate("project", "gpu", "f32", None, "end_to_end_f32_host"),
            cpu_all("project"),
        ),
    );
    show(
        "project GPU f32 kernel alone / CPU f64 all threads (the end-to-end ceiling)",
        ratio(
            rate("project", "gpu", "f32", None, "kernel"),
            cpu_all("project"),
        ),
    );
    show(
        "project GPU f32 end to end: streamed / one chunk without overlap",
        ratio(
            rate("project", "gpu", "f32", None, "end_to_end_streamed"),
            rate("project", "gpu", "f32", None, "end_to_end_one_chunk"),
        ),
    );
    show(
        "project GPU f32 end to end / GPU f32 kernel alone",
        ratio(
            rate("project", "gpu", "f32", None, "end_to_end"),
            rate("project", "gpu", "f32", None, "kernel"),
        ),
    );
    for kernel in ["stencil_reprojection", "stencil_affine_grid"] {
        let resident = rate(kernel, "gpu", "f64", None, "resident");
        let uploaded = rate(kernel, "gpu", "f64", None, "uploaded_each_call");
        let per_call = |r: Option<f64>| r.map(|r| 1e3 * STENCIL as f64 / r);
        show(
            &format!("{kernel} (GPU f64, {STENCIL} candidates): ms per call, rows resident"),
            per_call(resident),
        );
        show(
            &format!("{kernel} (GPU f64, {STENCIL} candidates): ms per call, uploaded each call"),
            per_call(uploaded),
        );
        show(
            &format!("{kernel}: speed-up from keeping the rows on the device"),
            ratio(resident, uploaded),
        );
    }
    // The README's sweep figure: 256 × 256 axes over 10 000 correspondences.
    let seconds = |r: Option<f64>| r.map(|r| 256.0 * 256.0 * 1e4 / r);
    show(
        "sweep GPU (f64 kernel): seconds for 256² axes × 10⁴ correspondences",
        seconds(rate("sweep", "gpu", "f64", None, "end_to_end")),
    );
    show(
        "sweep CPU f64 all threads: seconds for 256² axes × 10⁴ correspondences",
        seconds(rate("sweep", "cpu", "f64", Some(threads), "end_to_end")),
    );
}
