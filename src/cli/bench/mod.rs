//! `flatport bench`: items per second of back-projection, forward projection and triangulation on
//! every path (CPU f64 scalar and vector, one thread and all threads; GPU f32 and f64, kernel-only
//! and end to end), the affine-grid sweep and the calibration backend's stencil calls, each read
//! against its physical roof measured in the same run: the memory triad for the CPU, the host
//! link for an end-to-end GPU call, the device memory (a copy kernel) for a GPU kernel.
//!
//! - [`record`]: one figure, its printed line and JSON row, its roof;
//! - [`cpu`]: the CPU figures, the triad, where the vector path's time goes;
//! - [`gpu`]: the GPU roofs and figures;
//! - [`device`]: the device-resident chain (matched pixels → 3-D points, rows never on the host);
//! - [`stereo`]: dense stereo's frames per second per device;
//! - [`ratios`]: the ratios printed at the end.

mod cpu;
mod device;
mod gpu;
mod ratios;
mod record;
mod stereo;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use clap::Args;
use serde::Serialize;

use flatport::calib::{Board, Candidate, SceneSpec, StereoData, Target, simulate};
use flatport::engine::workload::{Workload, without_distortion};
use flatport::io::{rig_from_json_str, write_atomic};
use flatport::model::{RefractiveCamera, Rig, normal_from_tilt_azimuth};

use super::demo::EXAMPLE_RIG;
use record::{Figure, Recorder};

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

/// Bytes each bench item takes on the host: the inputs (pixels 16, points 24, matches 32), the
/// outputs (48 + 32 + 16), a status word (4), and the f32 copies for the f32-host figures
/// (pixels 8, points 12, outputs 24 + 8); the GPU paths hold as much again in buffers.
const BYTES_PER_ITEM: usize = 224;
/// Most `--items`: 2²⁴ items take about 3.8 GB on the host (and as much in GPU buffers).
pub const MAX_ITEMS: usize = 1 << 24;
/// Most `--sweep-cells`: each costs one evaluation over the ~10 000 correspondences per repetition.
pub const MAX_SWEEP_CELLS: usize = 1 << 20;
/// Most `--repeats`.
pub const MAX_REPEATS: usize = 1000;

/// What every figure runs on: the batch, the cameras, the sweep's correspondences and axes.
pub(super) struct Setup {
    work: Workload,
    /// The rig's first camera, its second (the first again on a one-camera rig), and the first
    /// without its distortion (the refraction alone).
    a: RefractiveCamera,
    b: RefractiveCamera,
    a_pinhole: RefractiveCamera,
    sweep_data: StereoData,
    sweep_candidates: Vec<Candidate>,
    /// The air layer of the stencil figures' candidates (the rig's shared port's).
    air_distance: f64,
}

impl Setup {
    fn new(rig: &Rig, items: usize, sweep_cells: usize) -> anyhow::Result<Self> {
        let (sweep_data, sweep_candidates) = sweep_workload(rig, sweep_cells)?;
        Ok(Self {
            work: Workload::new(rig, items),
            a: rig.refractive_camera(0),
            b: rig.refractive_camera(1.min(rig.cameras().len() - 1)),
            a_pinhole: without_distortion(rig)?.refractive_camera(0),
            sweep_data,
            sweep_candidates,
            air_distance: rig.shared_interface().map_or(0.02, |i| i.air_distance()),
        })
    }

    /// Items of the sweep figure: axis cells × correspondences.
    fn sweep_items(&self) -> usize {
        self.sweep_candidates.len() * self.sweep_data.corners.len()
    }
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

/// The JSON report.
#[derive(Debug, Serialize)]
struct Report {
    memory_stream_bytes_per_s: f64,
    /// What ran: the CPU's model, threads and the vector path's instruction set, the GPU adapter.
    cpu_model: String,
    cpu_threads: usize,
    cpu_instruction_set: &'static str,
    /// The clock the OS reports (/proc/cpuinfo), which `cycles_per_item` counts in.
    cpu_clock_hz: Option<f64>,
    /// Where the time goes on the vector path, one thread.
    floors: Option<cpu::Floors>,
    /// The GPU adapter and driver, and its roofs: the host link both ways and the device memory.
    gpu_adapter: Option<String>,
    host_link_upload_bytes_per_s: Option<f64>,
    host_link_download_bytes_per_s: Option<f64>,
    device_memory_bytes_per_s: Option<f64>,
    results: Vec<Figure>,
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
    eprintln!(
        "flatport bench: {} items per batch, fastest of {} runs",
        args.items, args.repeats
    );
    let setup = Setup::new(&rig, args.items, args.sweep_cells)?;
    eprintln!(
        "sweep figures: {} axis cells × {} correspondences = {} items (weighted affine-grid invariant)",
        setup.sweep_candidates.len(),
        setup.sweep_data.corners.len(),
        setup.sweep_items()
    );
    let clock_hz = cpu::cpu_clock_hz();
    let cpu_model = cpu::cpu_model();
    let mut recorder = Recorder::new(args.items, setup.sweep_items(), clock_hz, cpu_model.clone());

    let stream = cpu::memory_stream_bandwidth();
    outln!(
        "memory streaming bandwidth (triad, all cores): {:.2} GB/s",
        stream / 1e9
    );
    let isa = flatport::engine::cpu::lanes::instruction_set();
    eprintln!(
        "CPU ({cpu_model}) paths: scalar (the model row by row) and vector ({isa}), run by run in turn"
    );
    cpu::figures(&setup, args.repeats, &mut recorder)?;
    let gpu = if args.no_gpu {
        None
    } else {
        Some(gpu::figures(
            &setup,
            args.adapter.as_deref(),
            args.repeats,
            &mut recorder,
        )?)
    };

    stereo::figures(args.adapter.as_deref(), args.no_gpu, args.repeats)?;

    let threads = flatport::engine::CpuEngine::new(None).threads();
    let results = recorder.results;
    let floors =
        cpu::where_the_time_goes(&setup.a, &setup.a_pinhole, &setup.work, &results, clock_hz);
    ratios::print_ratios(&results, stream, threads);
    if let Some(path) = &args.json {
        let roofs = gpu.as_ref().map(|(_, roofs)| roofs);
        let report = Report {
            memory_stream_bytes_per_s: stream,
            cpu_model,
            cpu_threads: threads,
            cpu_instruction_set: isa,
            cpu_clock_hz: clock_hz,
            floors,
            gpu_adapter: gpu.as_ref().map(|(name, _)| name.clone()),
            host_link_upload_bytes_per_s: roofs.map(|r| r.link.upload),
            host_link_download_bytes_per_s: roofs.map(|r| r.link.download),
            device_memory_bytes_per_s: roofs.map(|r| r.device.bytes_per_s),
            results,
        };
        let text = serde_json::to_string_pretty(&report).context("serialising the report")?;
        write_atomic(path, text.as_bytes())?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
