//! `flatport sweep`: a calibration cost over a grid of axes (and air layers), with .npy, CSV,
//! PNG and summary outputs.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use serde_json::json;

use flatport::calib::sweep::{Linspace, MAX_SWEEP_CELLS, MinPool, SweepChunk, SweepSpec, sweep, too_many_cells};
use flatport::calib::{CalibError, CostKind};
use flatport::engine::Engine;
use flatport::io::npy::NpyWriter;
use flatport::io::plot::{CostMap, write_heatmap, write_polar};
use flatport::io::{IoError, TableWriter, read_truth, write_atomic};

use super::progress::Progress;

/// Which cost to sweep (`--cost`). The names are `CostKind::name`, as in the summary, the report
/// and the README; `invariant` and `3d` are the older spellings, still accepted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum CostArg {
    /// The weighted affine-grid invariant (axis only): χ² per degree of freedom, px²
    #[value(name = "affine-grid", alias = "invariant")]
    Invariant,
    /// RMS reprojection error of the rigidly fitted boards, px
    Reprojection,
    /// RMS residual of the rigid board fit to the triangulated corners (3-D scene error), m
    #[value(name = "scene", alias = "3d")]
    Scene,
}

impl CostArg {
    fn kind(self) -> CostKind {
        match self {
            Self::Invariant => CostKind::AffineGrid,
            Self::Reprojection => CostKind::Reprojection,
            Self::Scene => CostKind::Scene,
        }
    }
}

/// `flatport sweep`
#[derive(Debug, Args)]
pub struct SweepArgs {
    /// Rig file: cameras; its layers and indices are used, its normal and distance are not
    #[arg(long, value_name = "RIG.json")]
    pub rig: PathBuf,
    /// Observations (JSON, as for calibrate)
    #[arg(long, value_name = "OBS.json")]
    pub observations: PathBuf,
    /// The cost (the older names `invariant` and `3d` are accepted for affine-grid and scene)
    #[arg(long, value_enum, default_value_t = CostArg::Invariant)]
    pub cost: CostArg,
    /// Tilts of the axis from the master camera's z axis, degrees: START:STOP:COUNT, both ends included
    #[arg(long, value_name = "START:STOP:COUNT", value_parser = parse_linspace, allow_hyphen_values = true)]
    pub tilt_deg: Linspace,
    /// Azimuths atan2(n_y, n_x), degrees: START:STOP:COUNT, both ends included
    #[arg(long, value_name = "START:STOP:COUNT", value_parser = parse_linspace, allow_hyphen_values = true)]
    pub azimuth_deg: Linspace,
    /// Air layers in metres: START:STOP:COUNT; without it each axis takes its least-squares air layer
    #[arg(long, value_name = "START:STOP:COUNT", value_parser = parse_linspace)]
    pub distance: Option<Linspace>,
    /// Output folder (created if missing)
    #[arg(long, short, value_name = "DIR")]
    pub output: PathBuf,
    /// Truth of a simulated scene: marked in the pictures and given in the summary
    #[arg(long, value_name = "TRUTH.json")]
    pub truth: Option<PathBuf>,
    /// Axis cells per batch handed to the backend (1 to 1048576; a batch holds at most 262144
    /// cells whatever the distance grid)
    #[arg(long, value_name = "CELLS", default_value_t = 4096)]
    pub chunk: usize,
    /// No progress bar
    #[arg(long, short)]
    pub quiet: bool,
    #[command(flatten)]
    pub engine: super::EngineArgs,
}

/// Removes `path`, an output of an earlier sweep into the same folder that this sweep does not
/// write (distance.npy after a sweep with --distance or of an axis-only cost), so that the folder
/// holds one sweep's files only. Only a regular file or a symbolic link is removed (the link, not
/// its target); anything else under that name is left alone, with a warning.
fn remove_stale(path: &Path) -> anyhow::Result<()> {
    match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(e).with_context(|| format!("cannot inspect {}", path.display())),
        Ok(m) if m.is_file() || m.file_type().is_symlink() => {
            std::fs::remove_file(path).with_context(|| format!("cannot remove the stale {} of an earlier sweep", path.display()))
        }
        Ok(_) => {
            eprintln!("warning: {} is not a file of an earlier sweep's (not written by this one), left alone", path.display());
            Ok(())
        }
    }
}

/// Parses `START:STOP:COUNT`.
pub fn parse_linspace(text: &str) -> Result<Linspace, String> {
    let parts: Vec<&str> = text.split(':').collect();
    let error = || format!("expected START:STOP:COUNT such as 0:20:64, got '{text}'");
    let [start, stop, count] = parts[..] else { return Err(error()) };
    let start: f64 = start.trim().parse().map_err(|_| error())?;
    let stop: f64 = stop.trim().parse().map_err(|_| error())?;
    let count: usize = count.trim().parse().map_err(|_| error())?;
    if count == 0 || !start.is_finite() || !stop.is_finite() {
        return Err(format!("COUNT must be ≥ 1 and START, STOP finite, got '{text}'"));
    }
    if count == 1 && start != stop {
        return Err(format!("one value needs START = STOP, got '{text}'"));
    }
    Ok(Linspace { start, stop, count })
}

/// Largest `--chunk`: bigger batches gain nothing (the backend splits them for the device anyway).
pub const MAX_CHUNK: usize = 1 << 20;

/// Blocks per side of the heat map and polar plot: grids with more values per axis are drawn
/// min-pooled ([`MinPool`]) so the pictures hold at most this many blocks squared.
pub const PICTURE_SIDE: usize = 512;

/// Checks the sizes the options ask for before anything is read or allocated.
fn check_sizes(args: &SweepArgs, spec: &SweepSpec) -> anyhow::Result<()> {
    if !(1..=MAX_CHUNK).contains(&args.chunk) {
        bail!("--chunk {}: must lie in 1..={MAX_CHUNK} axis cells per batch (larger batches gain nothing; the backend splits them anyway)", args.chunk);
    }
    if spec.checked_cells().is_none_or(|cells| cells > MAX_SWEEP_CELLS) {
        let options = format!(
            "--tilt-deg …:{} × --azimuth-deg …:{}{}",
            spec.tilt_deg.count,
            spec.azimuth_deg.count,
            spec.distance.map_or(String::new(), |d| format!(" × --distance …:{}", d.count))
        );
        bail!("{options}: {}", too_many_cells(&spec.shape()));
    }
    Ok(())
}

fn grid_json(l: &Linspace) -> serde_json::Value {
    json!({"start": l.start, "stop": l.stop, "count": l.count})
}

/// Runs a sweep into `args.output`; returns the summary JSON. Everything is written under
/// temporary names and renamed into place only when the sweep completed.
pub fn run_sweep(args: &SweepArgs) -> anyhow::Result<serde_json::Value> {
    let spec = SweepSpec { kind: args.cost.kind(), tilt_deg: args.tilt_deg, azimuth_deg: args.azimuth_deg, distance: args.distance };
    check_sizes(args, &spec)?;
    spec.validate()?;
    let (_, data, _) = super::calib::load_stereo_data(&args.rig, &args.observations)?;
    let truth = args.truth.as_deref().map(read_truth).transpose()?;
    let engine: Engine = args.engine.engine_quiet()?;
    let backend = super::calib::cost_backend(&engine, &data);
    eprintln!("device: {}", engine.describe());
    let dir = &args.output;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;

    let shape = spec.shape();
    let depth = spec.distance.map_or(1, |d| d.count);
    let profile_distance = spec.distance.is_none() && !spec.kind.axis_only();
    let mut cost_npy = NpyWriter::create(&dir.join("cost.npy"), &shape)?;
    let mut distance_npy = if profile_distance { Some(NpyWriter::create(&dir.join("distance.npy"), &shape)?) } else { None };
    let mut csv = TableWriter::create(Some(&dir.join("cost.csv")), ["tilt_deg", "azimuth_deg", "distance", "cost"])?;
    // The pictures show the lowest cost over the air layers of each axis, min-pooled to at most
    // PICTURE_SIDE² blocks: memory stays bounded by the picture and the batch, not the grid.
    let (tilts, azimuths) = (spec.tilt_deg, spec.azimuth_deg);
    let mut pool = MinPool::new(tilts, azimuths, PICTURE_SIDE);
    // An interruption (Ctrl-C, SIGTERM) ends the process in `cli::signals`, which removes the
    // writers' temporary files: nothing of the sweep is left behind.
    let mut sink = |chunk: SweepChunk| -> Result<(), CalibError> {
        let io = |e: IoError| CalibError::Options(e.to_string());
        cost_npy.write(chunk.costs).map_err(io)?;
        if let Some(npy) = distance_npy.as_mut() {
            npy.write(chunk.distances).map_err(io)?;
        }
        let rows = chunk.costs.iter().zip(chunk.distances).enumerate().map(|(k, (&cost, &distance))| {
            let axis = (chunk.first + k) / depth;
            Some([tilts.value(axis / azimuths.count), azimuths.value(axis % azimuths.count), distance, cost])
        });
        csv.write_rows(rows).map_err(io)?;
        for (k, &cost) in chunk.costs.iter().enumerate() {
            pool.add((chunk.first + k) / depth, cost);
        }
        Ok(())
    };
    let cells = spec.cells();
    eprintln!(
        "sweeping the {} cost over {} cells ({}) × {} corners...",
        spec.kind.name(),
        cells,
        shape.iter().map(|s| s.to_string()).collect::<Vec<_>>().join(" × "),
        data.corners.len()
    );
    let mut progress = Progress::new("sweep", "cells", args.quiet);
    let summary = sweep(backend.as_ref(), &spec, args.chunk, &mut sink, &mut |done, total| progress.update(done, total))?;
    let Some(minimum) = summary.minimum else {
        drop(cost_npy);
        drop(distance_npy);
        bail!("no cell of the grid has a finite {} cost: every candidate leaves corners without an answer", spec.kind.name());
    };
    cost_npy.finish()?;
    if let Some(n) = distance_npy {
        n.finish()?;
    } else {
        remove_stale(&dir.join("distance.npy"))?;
    }
    csv.finish()?;
    let no_answer = summary.cells - summary.finite;
    if no_answer > 0 {
        eprintln!(
            "warning: {no_answer} of {} cells have no finite {} cost (inf in cost.npy and cost.csv, grey in the pictures): \
             under those candidates some corner has no answer (a camera outside the air, a totally reflected ray, a corner \
             triangulated behind the port){}",
            summary.cells,
            spec.kind.name(),
            if profile_distance { "; without --distance this is often an axis whose least-squares air layer leaves a camera outside the air" } else { "" }
        );
    }

    let truth_deg = truth.as_ref().map(|t| (t.interface.tilt().to_degrees(), t.interface.azimuth().to_degrees()));
    let (tilt_values, azimuth_values) = (pool.tilts_deg(), pool.azimuths_deg());
    let pooled = match pool.factors() {
        (1, 1) => String::new(),
        (t, a) => format!(", each block the lowest of {t} × {a} axes"),
    };
    let map = CostMap {
        tilts_deg: &tilt_values,
        azimuths_deg: &azimuth_values,
        values: pool.values(),
        title: format!(
            "{} cost{} over {} axes × {} corners{pooled}",
            spec.kind.name(),
            if spec.distance.is_some() { " (lowest over the air layers)" } else { "" },
            spec.axes(),
            data.corners.len()
        ),
        cost_label: format!("{} ({})", spec.kind.name(), spec.kind.unit()),
        minimum: Some((minimum.tilt_deg, minimum.azimuth_deg)),
        truth: truth_deg,
    };
    write_heatmap(&dir.join("heatmap.png"), &map)?;
    write_polar(&dir.join("polar.png"), &map)?;
    let finite = |x: f64| if x.is_finite() { json!(x) } else { serde_json::Value::Null };
    let summary_json = json!({
        "cost": spec.kind.name(),
        "unit": spec.kind.unit(),
        "argmin": {"tilt_deg": minimum.tilt_deg, "azimuth_deg": minimum.azimuth_deg, "distance": finite(minimum.distance), "cost": minimum.cost, "cell": minimum.cell},
        "grid": {"tilt_deg": grid_json(&tilts), "azimuth_deg": grid_json(&azimuths), "distance": spec.distance.as_ref().map(grid_json)},
        "shape": shape,
        "cells": summary.cells,
        "finite_cells": summary.finite,
        "correspondences": data.corners.len(),
        "views": data.views.len(),
        "seconds": summary.seconds,
        "cells_per_s": summary.cells as f64 / summary.seconds,
        "cell_correspondences_per_s": (summary.cells * data.corners.len()) as f64 / summary.seconds,
        "device": engine.describe(),
        "truth": truth.as_ref().map(|t| json!({"tilt_deg": t.interface.tilt().to_degrees(), "azimuth_deg": t.interface.azimuth().to_degrees(), "distance": t.interface.air_distance()})),
    });
    let mut text = serde_json::to_string_pretty(&summary_json).expect("plain data");
    text.push('\n');
    write_atomic(&dir.join("summary.json"), text.as_bytes())?;
    Ok(summary_json)
}

/// `flatport sweep` from the command line: runs and prints where everything went.
pub fn run(args: SweepArgs) -> anyhow::Result<()> {
    let summary = run_sweep(&args)?;
    print_summary(&summary, &args.output);
    Ok(())
}

/// The lines printed after a sweep.
pub fn print_summary(summary: &serde_json::Value, dir: &Path) {
    let m = &summary["argmin"];
    outln!(
        "minimum {} = {:.6e} {} at tilt {:.4}°, azimuth {:.4}°{}",
        summary["cost"].as_str().unwrap_or(""),
        m["cost"].as_f64().unwrap_or(f64::NAN),
        summary["unit"].as_str().unwrap_or(""),
        m["tilt_deg"].as_f64().unwrap_or(f64::NAN),
        m["azimuth_deg"].as_f64().unwrap_or(f64::NAN),
        m["distance"].as_f64().map_or(String::new(), |d| format!(", air layer {:.3} mm", d * 1e3))
    );
    outln!(
        "{} cells × {} corners in {:.2} s ({:.3e} cell·corners/s)",
        summary["cells"],
        summary["correspondences"],
        summary["seconds"].as_f64().unwrap_or(f64::NAN),
        summary["cell_correspondences_per_s"].as_f64().unwrap_or(f64::NAN)
    );
    outln!("wrote {}/cost.npy, cost.csv, heatmap.png, polar.png, summary.json", dir.display());
}
