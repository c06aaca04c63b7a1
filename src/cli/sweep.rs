//! `flatport sweep`: a calibration cost over a grid of axes (and air layers), with .npy, CSV,
//! PNG and summary outputs.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::{Args, Subcommand, ValueEnum};
use serde_json::json;

use flatport::calib::sweep::{
    Linspace, MAX_SWEEP_CELLS, MinPool, Shard, SweepChunk, SweepMinimum, SweepSpec, SweepSummary,
    sweep, sweep_cells, too_many_cells,
};
use flatport::calib::{CalibError, CostKind};
use flatport::engine::Engine;
use flatport::io::npy::NpyReader;
use flatport::io::npy::NpyWriter;
use flatport::io::plot::{CostMap, write_heatmap, write_polar};
use flatport::io::sweep_shard::{
    CellRange, GridAxes, GridAxis, SHARD_FORMAT, SHARD_VERSION, ShardIndex, ShardInputs,
    ShardManifest, read_shard_manifest, sha256_file, write_shard_manifest,
};
use flatport::io::{IoError, TableWriter, Truth, read_truth, write_atomic};

use super::progress::Progress;

/// Which cost to sweep (`--cost`). The names are `CostKind::name`, as in the summary, the report
/// and docs/sweeps.md; `invariant` and `3d` are the older spellings, still accepted.
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
    #[arg(long, value_name = "RIG.json", required = true)]
    pub rig: Option<PathBuf>,
    /// Observations (JSON, as for calibrate)
    #[arg(long, value_name = "OBS.json", required_unless_present = "targetless")]
    pub observations: Option<PathBuf>,
    /// No board: sweep the targetless cost (the RMS reprojection error of matches of a textured
    /// scene, each match's point fitted alone under the cell's port; docs/targetless.md) over the
    /// master's port, from the frames in --images; needs --distance
    #[arg(long, requires_all = ["images", "distance"], conflicts_with_all = ["observations", "cost", "shard"], help_heading = "Targetless")]
    pub targetless: bool,
    /// With --targetless: one folder per rig camera, named as in the rig, of synchronized frames
    /// (images sorted by name, or one video), as `calibrate --targetless` reads them
    #[arg(
        long,
        value_name = "DIR",
        requires = "targetless",
        help_heading = "Targetless"
    )]
    pub images: Option<PathBuf>,
    /// With --targetless: frames used, START:STOP:STEP, each part optional [default: at most 8
    /// spread over the footage]
    #[arg(
        long,
        value_name = "START:STOP:STEP",
        requires = "targetless",
        help_heading = "Targetless"
    )]
    pub frames: Option<flatport::io::frames::FrameSelection>,
    /// The cost (the older names `invariant` and `3d` are accepted for affine-grid and scene)
    #[arg(long, value_enum, default_value_t = CostArg::Invariant)]
    pub cost: CostArg,
    /// Tilts of the axis from the master camera's z axis, degrees: START:STOP:COUNT, both ends included
    #[arg(long, value_name = "START:STOP:COUNT", value_parser = parse_linspace, allow_hyphen_values = true, required = true)]
    pub tilt_deg: Option<Linspace>,
    /// Azimuths atan2(n_y, n_x), degrees: START:STOP:COUNT, both ends included
    #[arg(long, value_name = "START:STOP:COUNT", value_parser = parse_linspace, allow_hyphen_values = true, required = true)]
    pub azimuth_deg: Option<Linspace>,
    /// Air layers in metres: START:STOP:COUNT; without it each axis takes its least-squares air layer
    #[arg(long, value_name = "START:STOP:COUNT", value_parser = parse_distances, allow_hyphen_values = true)]
    pub distance: Option<Linspace>,
    /// Output folder (created if missing)
    #[arg(long, short, value_name = "DIR", required = true)]
    pub output: Option<PathBuf>,
    /// Truth of a simulated scene: marked in the pictures and given in the summary
    #[arg(long, value_name = "TRUTH.json")]
    pub truth: Option<PathBuf>,
    /// Axis cells per batch handed to the backend (1 to 1048576; a batch holds at most 262144
    /// cells whatever the distance grid)
    #[arg(
        long,
        value_name = "CELLS",
        default_value_t = 4096,
        allow_negative_numbers = true
    )]
    pub chunk: usize,
    /// No progress bar
    #[arg(long, short)]
    pub quiet: bool,
    /// Evaluate only slice INDEX of COUNT contiguous slices of the grid's cells (row-major,
    /// 0-based: 0/4 … 3/4) into DIR's shard files (cost.npy over the slice, shard.json); `flatport
    /// sweep merge` joins the shards
    #[arg(long, value_name = "INDEX/COUNT", value_parser = Shard::parse)]
    pub shard: Option<Shard>,
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
        Ok(m) if m.is_file() || m.file_type().is_symlink() => std::fs::remove_file(path)
            .with_context(|| {
                format!(
                    "cannot remove the stale {} of an earlier sweep",
                    path.display()
                )
            }),
        Ok(_) => {
            eprintln!(
                "warning: {} is not a file of an earlier sweep's (not written by this one), left alone",
                path.display()
            );
            Ok(())
        }
    }
}

/// Parses `START:STOP:COUNT`.
pub fn parse_linspace(text: &str) -> Result<Linspace, String> {
    let parts: Vec<&str> = text.split(':').collect();
    let error = || format!("expected START:STOP:COUNT such as 0:20:64, got '{text}'");
    let [start, stop, count] = parts[..] else {
        return Err(error());
    };
    let start: f64 = start.trim().parse().map_err(|_| error())?;
    let stop: f64 = stop.trim().parse().map_err(|_| error())?;
    let count: usize = count.trim().parse().map_err(|_| error())?;
    if count == 0 || !start.is_finite() || !stop.is_finite() {
        return Err(format!(
            "COUNT must be ≥ 1 and START, STOP finite, got '{text}'"
        ));
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
        bail!(
            "--chunk {}: must lie in 1..={MAX_CHUNK} axis cells per batch (larger batches gain nothing; the backend splits them anyway)",
            args.chunk
        );
    }
    if spec
        .checked_cells()
        .is_none_or(|cells| cells > MAX_SWEEP_CELLS)
    {
        let options = format!(
            "--tilt-deg …:{} × --azimuth-deg …:{}{}",
            spec.tilt_deg.count,
            spec.azimuth_deg.count,
            spec.distance
                .map_or(String::new(), |d| format!(" × --distance …:{}", d.count))
        );
        bail!("{options}: {}", too_many_cells(&spec.shape()));
    }
    Ok(())
}

/// Parses the `--distance` grid: START:STOP:COUNT of air layers, both ends > 0 m.
pub fn parse_distances(text: &str) -> Result<Linspace, String> {
    let grid = parse_linspace(text)?;
    if !(grid.start > 0.0 && grid.stop > 0.0) {
        return Err(format!(
            "air layers must be > 0 m, got START {} and STOP {}",
            grid.start, grid.stop
        ));
    }
    Ok(grid)
}

fn grid_json(l: &Linspace) -> serde_json::Value {
    json!({"start": l.start, "stop": l.stop, "count": l.count})
}

/// Runs a sweep into `args.output`; returns the summary JSON. Everything is written under
/// temporary names and renamed into place only when the sweep completed. With `--shard I/N`
/// only that slice of the grid is evaluated, into the shard's files (`ShardFiles`); the
/// summary is then the shard's manifest.
pub fn run_sweep(args: &SweepArgs) -> anyhow::Result<serde_json::Value> {
    if args.targetless {
        return run_targetless_sweep(args);
    }
    let missing =
        |option: &str| anyhow::anyhow!("flatport sweep needs {option} (see flatport sweep --help)");
    let (rig, observations) = (
        args.rig.as_deref().ok_or_else(|| missing("--rig"))?,
        args.observations
            .as_deref()
            .ok_or_else(|| missing("--observations"))?,
    );
    let tilt_deg = args.tilt_deg.ok_or_else(|| missing("--tilt-deg"))?;
    let azimuth_deg = args.azimuth_deg.ok_or_else(|| missing("--azimuth-deg"))?;
    let dir = args.output.as_deref().ok_or_else(|| missing("--output"))?;
    let spec = SweepSpec {
        kind: args.cost.kind(),
        tilt_deg,
        azimuth_deg,
        distance: args.distance,
    };
    check_sizes(args, &spec)?;
    spec.validate()?;
    let (rig_file, data, _) = super::calib::load_stereo_data(rig, observations)?;
    if rig_file.shared_interface().is_none() {
        // The invariants and the ray gap are relations of one interface that both cameras look
        // through; behind a port each, only the image and 3-D costs mean anything.
        if !matches!(spec.kind, CostKind::Reprojection | CostKind::Scene) {
            bail!(
                "the {} cost assumes both cameras behind one shared port, and this rig has a port per camera: sweep --cost reprojection or scene, which move camera '{}''s own port",
                spec.kind.name(),
                rig_file.cameras()[data.cameras[0]].name
            );
        }
        eprintln!(
            "a port per camera: the grid moves camera '{}''s own port (tilt from its z axis, in its frame); camera '{}''s port stays as in the rig",
            rig_file.cameras()[data.cameras[0]].name,
            rig_file.cameras()[data.cameras[1]].name
        );
    }
    let truth = args.truth.as_deref().map(read_truth).transpose()?;
    let engine: Engine = args.engine.engine_quiet()?;
    let backend = super::calib::cost_backend(&engine, &data);
    let device = backend.describe_cost(spec.kind);
    eprintln!("device: {device}");
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let cells = args
        .shard
        .map_or(0..spec.cells(), |shard| shard.cells(spec.cells()));
    let shape = spec.shape();
    eprintln!(
        "sweeping the {} cost over {} cells ({}{}) × {} corners...",
        spec.kind.name(),
        cells.len(),
        shape
            .iter()
            .map(|s| s.to_string())
            .collect::<Vec<_>>()
            .join(" × "),
        args.shard.map_or(String::new(), |s| format!(
            ", shard {s}: cells {}..{}",
            cells.start, cells.end
        )),
        data.corners.len()
    );
    let mut progress = Progress::new("sweep", "cells", args.quiet);
    if let Some(shard) = args.shard {
        let mut files = ShardFiles::create(dir, &spec, cells.len())?;
        let summary = sweep_cells(
            backend.as_ref(),
            &spec,
            args.chunk,
            cells.clone(),
            &mut |chunk| files.add(&chunk),
            &mut |done, total| progress.update(done, total),
        )?;
        let inputs = ShardInputs {
            rig_sha256: sha256_file(rig)?,
            observations_sha256: sha256_file(observations)?,
            correspondences: data.corners.len(),
            views: data.views.len(),
        };
        let manifest = ShardManifest {
            format: SHARD_FORMAT.into(),
            version: SHARD_VERSION,
            shard: ShardIndex {
                index: shard.index,
                count: shard.count,
            },
            cells: CellRange {
                start: cells.start,
                end: cells.end,
                total: spec.cells(),
            },
            cost: spec.kind.name().into(),
            grid: GridAxes {
                tilt_deg: grid_axis(&spec.tilt_deg),
                azimuth_deg: grid_axis(&spec.azimuth_deg),
                distance: spec.distance.as_ref().map(grid_axis),
            },
            inputs,
            device,
            seconds: summary.seconds,
            finite_cells: summary.finite,
        };
        files.finish(dir, &manifest)?;
        return Ok(serde_json::to_value(&manifest).expect("plain data"));
    }
    let mut outputs = SweepOutputs::create(dir, &spec)?;
    let summary = sweep(
        backend.as_ref(),
        &spec,
        args.chunk,
        &mut |chunk| outputs.add(&chunk),
        &mut |done, total| progress.update(done, total),
    )?;
    let info = SweepInfo {
        cost: spec.kind.name().into(),
        unit: spec.kind.unit().into(),
        correspondences: data.corners.len(),
        views: data.views.len(),
        seconds: summary.seconds,
        device,
    };
    outputs.finish(dir, &spec, &summary, &info, truth.as_ref())
}

/// `flatport sweep --images DIR --rig RIG.json --targetless`: the targetless cost of the scene's
/// matches over the master's port (axis × air distance), into the files a sweep writes.
fn run_targetless_sweep(args: &SweepArgs) -> anyhow::Result<serde_json::Value> {
    use flatport::calib::targetless::sweep::{SWEEP_TRACKS, sweep_targetless};
    use flatport::calib::targetless::{MatchOptions, check_frames, start::spread, tracks_of};
    let missing = |option: &str| {
        anyhow::anyhow!("flatport sweep --targetless needs {option} (see flatport sweep --help)")
    };
    let rig_path = args.rig.as_deref().ok_or_else(|| missing("--rig"))?;
    let images = args
        .images
        .as_deref()
        .ok_or_else(|| missing("--images DIR"))?;
    let spec = SweepSpec {
        // The targetless cost is a reprojection error (px); the summary names it `targetless`.
        kind: CostKind::Reprojection,
        tilt_deg: args.tilt_deg.ok_or_else(|| missing("--tilt-deg"))?,
        azimuth_deg: args.azimuth_deg.ok_or_else(|| missing("--azimuth-deg"))?,
        distance: Some(args.distance.ok_or_else(|| {
            missing(
                "--distance START:STOP:COUNT (the targetless cost has no linear air-layer profile)",
            )
        })?),
    };
    let dir = args.output.as_deref().ok_or_else(|| missing("--output"))?;
    check_sizes(args, &spec)?;
    spec.validate()?;
    let rig = flatport::io::read_rig(rig_path)?;
    if rig.cameras().len() < 2 {
        bail!("the rig has one camera: the targetless cost matches the scene between cameras");
    }
    if let flatport::model::Ports::PerCamera(_) = rig.ports() {
        eprintln!(
            "a port per camera: the grid moves camera '{}''s own port (tilt from its z axis, in its frame); the other cameras' ports stay as in the rig",
            rig.cameras()[0].name
        );
    }
    let truth = args.truth.as_deref().map(read_truth).transpose()?;
    let frames = super::calib_targetless::read_frames(&rig, images, args.frames)?;
    check_frames(&rig, &frames)?;
    let quiet = args.quiet;
    let (tracks, _) = tracks_of(&frames, &MatchOptions::default(), &mut |line| {
        if !quiet {
            eprintln!("  {line}");
        }
    });
    let sample = spread(&tracks, SWEEP_TRACKS);
    if sample.is_empty() {
        bail!(
            "{}: no matches between the master and the other cameras: film more texture, or check that the images belong to these cameras",
            images.display()
        );
    }
    let device = format!(
        "cpu (f64, {} threads): the targetless profile",
        rayon::current_num_threads()
    );
    eprintln!("device: {device}");
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    eprintln!(
        "sweeping the targetless cost over {} cells ({}) × {} tracks (of {} matched)...",
        spec.cells(),
        spec.shape()
            .iter()
            .map(|s| s.to_string())
            .collect::<Vec<_>>()
            .join(" × "),
        sample.len(),
        tracks.len()
    );
    let mut progress = Progress::new("sweep", "cells", args.quiet);
    let mut outputs = SweepOutputs::create(dir, &spec)?;
    let summary = sweep_targetless(
        &rig,
        &sample,
        &spec,
        &mut |chunk| outputs.add(&chunk),
        &mut |done, total| progress.update(done, total),
    )?;
    let info = SweepInfo {
        cost: "targetless".into(),
        unit: "px".into(),
        correspondences: sample.len(),
        views: frames.len(),
        seconds: summary.seconds,
        device,
    };
    outputs.finish(dir, &spec, &summary, &info, truth.as_ref())
}

fn grid_axis(l: &Linspace) -> GridAxis {
    GridAxis {
        start: l.start,
        stop: l.stop,
        count: l.count,
    }
}

fn linspace(g: &GridAxis) -> Linspace {
    Linspace {
        start: g.start,
        stop: g.stop,
        count: g.count,
    }
}

/// What the summary says besides the grid's costs.
struct SweepInfo {
    /// The cost's name (`CostKind::name`, or `targetless`).
    cost: String,
    /// Its unit.
    unit: String,
    correspondences: usize,
    views: usize,
    /// Wall-clock seconds (summed over the shards of a merge).
    seconds: f64,
    device: String,
}

/// The files of a whole sweep, written as the cells come in row-major order: cost.npy,
/// distance.npy (a profile's air layers), cost.csv, and the min-pooled picture.
struct SweepOutputs {
    arrays: CostArrays,
    csv: TableWriter<4>,
    pool: MinPool,
    tilts: Linspace,
    azimuths: Linspace,
    depth: usize,
}

impl SweepOutputs {
    fn create(dir: &Path, spec: &SweepSpec) -> anyhow::Result<Self> {
        let (tilts, azimuths) = (spec.tilt_deg, spec.azimuth_deg);
        Ok(Self {
            arrays: CostArrays::create(dir, &spec.shape(), spec.profiles_air_distance())?,
            csv: TableWriter::create(
                Some(&dir.join("cost.csv")),
                ["tilt_deg", "azimuth_deg", "distance", "cost"],
            )?,
            // The pictures show the lowest cost over the air layers of each axis, min-pooled to at
            // most PICTURE_SIDE² blocks: memory stays bounded by the picture and the batch.
            pool: MinPool::new(tilts, azimuths, PICTURE_SIDE),
            tilts,
            azimuths,
            depth: spec.distance.map_or(1, |d| d.count),
        })
    }

    /// Takes the next cells. An interruption (Ctrl-C, SIGTERM) ends the process in
    /// `cli::signals`, which removes the writers' temporary files: nothing is left behind.
    fn add(&mut self, chunk: &SweepChunk) -> Result<(), CalibError> {
        self.arrays.add(chunk)?;
        let (tilts, azimuths, depth) = (self.tilts, self.azimuths, self.depth);
        let rows =
            chunk
                .costs
                .iter()
                .zip(chunk.distances)
                .enumerate()
                .map(|(k, (&cost, &distance))| {
                    let axis = (chunk.first + k) / depth;
                    Some([
                        tilts.value(axis / azimuths.count),
                        azimuths.value(axis % azimuths.count),
                        distance,
                        cost,
                    ])
                });
        self.csv
            .write_rows(rows)
            .map_err(|e| CalibError::Options(e.to_string()))?;
        for (k, &cost) in chunk.costs.iter().enumerate() {
            self.pool.add((chunk.first + k) / depth, cost);
        }
        Ok(())
    }

    /// Puts the files in place, draws the pictures and writes summary.json; returns the summary.
    fn finish(
        self,
        dir: &Path,
        spec: &SweepSpec,
        summary: &SweepSummary,
        info: &SweepInfo,
        truth: Option<&Truth>,
    ) -> anyhow::Result<serde_json::Value> {
        let Self {
            arrays,
            csv,
            pool,
            tilts,
            azimuths,
            ..
        } = self;
        let Some(minimum) = summary.minimum else {
            bail!(
                "no cell of the grid has a finite {} cost: every candidate leaves corners without an answer",
                info.cost
            );
        };
        let profile_distance = spec.profiles_air_distance();
        arrays.finish(dir)?;
        csv.finish()?;
        let no_answer = summary.cells - summary.finite;
        if no_answer > 0 {
            eprintln!(
                "warning: {no_answer} of {} cells have no finite {} cost (inf in cost.npy and cost.csv, grey in the pictures): \
                 under those candidates some corner has no answer (a camera outside the air, a totally reflected ray, a corner \
                 triangulated behind the port){}",
                summary.cells,
                info.cost,
                if profile_distance {
                    "; without --distance this is often an axis whose least-squares air layer leaves a camera outside the air"
                } else {
                    ""
                }
            );
        }

        let truth_deg = truth.map(|t| {
            (
                t.interface.tilt().to_degrees(),
                t.interface.azimuth().to_degrees(),
            )
        });
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
                "{} cost{} over {} axes × {} {}{pooled}",
                info.cost,
                if spec.distance.is_some() {
                    " (lowest over the air layers)"
                } else {
                    ""
                },
                spec.axes(),
                info.correspondences,
                data_name(&info.cost)
            ),
            cost_label: format!("{} ({})", info.cost, info.unit),
            minimum: Some((minimum.tilt_deg, minimum.azimuth_deg)),
            truth: truth_deg,
        };
        write_heatmap(&dir.join("heatmap.png"), &map)?;
        write_polar(&dir.join("polar.png"), &map)?;
        let finite = |x: f64| {
            if x.is_finite() {
                json!(x)
            } else {
                serde_json::Value::Null
            }
        };
        let summary_json = json!({
            "cost": info.cost,
            "unit": info.unit,
            "argmin": {"tilt_deg": minimum.tilt_deg, "azimuth_deg": minimum.azimuth_deg, "distance": finite(minimum.distance), "cost": minimum.cost, "cell": minimum.cell},
            "grid": {"tilt_deg": grid_json(&tilts), "azimuth_deg": grid_json(&azimuths), "distance": spec.distance.as_ref().map(grid_json)},
            "shape": spec.shape(),
            "cells": summary.cells,
            "finite_cells": summary.finite,
            "correspondences": info.correspondences,
            "views": info.views,
            "seconds": info.seconds,
            "cells_per_s": summary.cells as f64 / info.seconds,
            "cell_correspondences_per_s": (summary.cells * info.correspondences) as f64 / info.seconds,
            "device": info.device,
            "truth": truth.map(|t| json!({"tilt_deg": t.interface.tilt().to_degrees(), "azimuth_deg": t.interface.azimuth().to_degrees(), "distance": t.interface.air_distance()})),
        });
        let mut text = serde_json::to_string_pretty(&summary_json).expect("plain data");
        text.push('\n');
        write_atomic(&dir.join("summary.json"), text.as_bytes())?;
        Ok(summary_json)
    }
}

/// The files of one shard: cost.npy (and a profile's distance.npy), one-dimensional over the
/// shard's cells, and shard.json, its manifest (written last, so a folder with a manifest holds a
/// whole shard).
struct ShardFiles {
    arrays: CostArrays,
}

impl ShardFiles {
    fn create(dir: &Path, spec: &SweepSpec, cells: usize) -> anyhow::Result<Self> {
        Ok(Self {
            arrays: CostArrays::create(dir, &[cells], spec.profiles_air_distance())?,
        })
    }

    fn add(&mut self, chunk: &SweepChunk) -> Result<(), CalibError> {
        self.arrays.add(chunk)
    }

    fn finish(self, dir: &Path, manifest: &ShardManifest) -> anyhow::Result<()> {
        self.arrays.finish(dir)?;
        // A shard folder holds a shard only: a whole sweep's other files would be stale there.
        for stale in ["cost.csv", "heatmap.png", "polar.png", "summary.json"] {
            remove_stale(&dir.join(stale))?;
        }
        write_shard_manifest(&dir.join("shard.json"), manifest)?;
        Ok(())
    }
}

/// cost.npy and, for a profile, distance.npy of a sweep or of a shard (shaped as the grid, or
/// flat over the shard's cells), written as the cells come.
struct CostArrays {
    cost: NpyWriter,
    distance: Option<NpyWriter>,
}

impl CostArrays {
    fn create(dir: &Path, shape: &[usize], profile_distance: bool) -> anyhow::Result<Self> {
        Ok(Self {
            cost: NpyWriter::create(&dir.join("cost.npy"), shape)?,
            distance: if profile_distance {
                Some(NpyWriter::create(&dir.join("distance.npy"), shape)?)
            } else {
                None
            },
        })
    }

    fn add(&mut self, chunk: &SweepChunk) -> Result<(), CalibError> {
        let io = |e: IoError| CalibError::Options(e.to_string());
        self.cost.write(chunk.costs).map_err(io)?;
        if let Some(npy) = self.distance.as_mut() {
            npy.write(chunk.distances).map_err(io)?;
        }
        Ok(())
    }

    /// Puts the arrays in place; without a distance.npy of its own, removes the one an earlier
    /// sweep left in `dir`, so the folder never mixes two sweeps.
    fn finish(self, dir: &Path) -> anyhow::Result<()> {
        self.cost.finish()?;
        match self.distance {
            Some(npy) => npy.finish()?,
            None => remove_stale(&dir.join("distance.npy"))?,
        }
        Ok(())
    }
}

/// `flatport sweep merge`
#[derive(Debug, Args)]
pub struct MergeArgs {
    /// The shards' folders (each with shard.json and cost.npy), in any order
    #[arg(value_name = "SHARD_DIR", required = true, num_args = 1..)]
    pub shards: Vec<PathBuf>,
    /// Output folder (created if missing): the files an unsharded sweep writes
    #[arg(long, short, value_name = "DIR")]
    pub output: PathBuf,
    /// Truth of a simulated scene: marked in the pictures and given in the summary
    #[arg(long, value_name = "TRUTH.json")]
    pub truth: Option<PathBuf>,
}

/// Values read from a shard at a time.
const MERGE_BATCH: usize = 1 << 16;

/// Merges the shards of one sweep into the files an unsharded sweep writes: cost.npy (the same
/// bytes), distance.npy, cost.csv, the pictures and summary.json of the whole grid. Refuses shards
/// of different sweeps (cost, grid, rig or observations differ), a shard given twice, and a set
/// that leaves cells out.
pub fn run_merge(args: &MergeArgs) -> anyhow::Result<serde_json::Value> {
    let shards = read_shards(&args.shards)?;
    check_same_sweep(&shards)?;
    let order = shard_order(&shards)?;
    let (first_dir, first) = &shards[0];
    let spec = merged_spec(first_dir, first)?;
    let truth = args.truth.as_deref().map(read_truth).transpose()?;
    let dir = &args.output;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut outputs = SweepOutputs::create(dir, &spec)?;
    let mut merged = Merged::default();
    let mut devices: Vec<&str> = Vec::new();
    for k in order {
        let (shard_dir, m) = &shards[k];
        merged.seconds += m.seconds;
        if !devices.contains(&m.device.as_str()) {
            devices.push(&m.device);
        }
        merge_shard(shard_dir, m, &spec, &mut merged, &mut outputs)?;
    }
    let summary = SweepSummary {
        minimum: merged.minimum,
        cells: spec.cells(),
        finite: merged.finite,
        seconds: merged.seconds,
    };
    let info = SweepInfo {
        cost: spec.kind.name().into(),
        unit: spec.kind.unit().into(),
        correspondences: first.inputs.correspondences,
        views: first.inputs.views,
        seconds: merged.seconds,
        device: devices.join("; "),
    };
    eprintln!("merged {} shards of {} cells", shards.len(), spec.cells());
    outputs.finish(dir, &spec, &summary, &info, truth.as_ref())
}

/// The manifest of each shard folder.
fn read_shards(dirs: &[PathBuf]) -> anyhow::Result<Vec<(PathBuf, ShardManifest)>> {
    dirs.iter()
        .map(|dir| {
            let manifest = read_shard_manifest(&dir.join("shard.json")).with_context(|| {
                format!(
                    "{} is not a sweep shard (flatport sweep --shard I/N writes one)",
                    dir.display()
                )
            })?;
            Ok((dir.clone(), manifest))
        })
        .collect()
}

/// Every shard is of the first's sweep: the same cost, grid, rig, observations and shard count.
fn check_same_sweep(shards: &[(PathBuf, ShardManifest)]) -> anyhow::Result<()> {
    let (first_dir, first) = &shards[0];
    for (dir, m) in &shards[1..] {
        let differs = |what: &str| {
            anyhow::anyhow!(
                "{} and {} are shards of different sweeps: their {what} differ (merge only the shards of one `flatport sweep … --shard I/N` run)",
                first_dir.display(),
                dir.display()
            )
        };
        if m.cost != first.cost {
            return Err(differs(&format!("costs ('{}', '{}')", first.cost, m.cost)));
        }
        if m.grid != first.grid {
            return Err(differs("grids"));
        }
        if m.inputs.rig_sha256 != first.inputs.rig_sha256 {
            return Err(differs("rig files (SHA-256)"));
        }
        if m.inputs != first.inputs {
            return Err(differs("observations files (SHA-256)"));
        }
        if m.shard.count != first.shard.count || m.cells.total != first.cells.total {
            return Err(differs(&format!(
                "shard counts ({}, {})",
                first.shard.count, m.shard.count
            )));
        }
    }
    Ok(())
}

/// The shards in cell order (indices into `shards`): each shard once, with the cells its index
/// owns, none missing.
fn shard_order(shards: &[(PathBuf, ShardManifest)]) -> anyhow::Result<Vec<usize>> {
    let first = &shards[0].1;
    let count = first.shard.count;
    let mut by_index: Vec<Option<usize>> = vec![None; count];
    for (k, (dir, m)) in shards.iter().enumerate() {
        if let Some(other) = by_index[m.shard.index] {
            bail!(
                "{} and {} are both shard {}/{count}",
                shards[other].0.display(),
                dir.display(),
                m.shard.index
            );
        }
        let expected = Shard {
            index: m.shard.index,
            count,
        }
        .cells(m.cells.total);
        if (m.cells.start, m.cells.end) != (expected.start, expected.end) {
            bail!(
                "{}: shard {}/{count} claims cells {}..{}, but that shard is cells {}..{}",
                dir.display(),
                m.shard.index,
                m.cells.start,
                m.cells.end,
                expected.start,
                expected.end
            );
        }
        by_index[m.shard.index] = Some(k);
    }
    let missing: Vec<String> = (0..count)
        .filter(|&i| by_index[i].is_none())
        .map(|i| {
            let cells = Shard { index: i, count }.cells(first.cells.total);
            format!("{i}/{count} (cells {}..{})", cells.start, cells.end)
        })
        .collect();
    if !missing.is_empty() {
        bail!(
            "the shards leave cells out: shard{} {} missing",
            if missing.len() == 1 { "" } else { "s" },
            missing.join(", ")
        );
    }
    Ok(by_index.into_iter().flatten().collect())
}

/// The whole sweep's grid and cost, from the first shard's manifest.
fn merged_spec(dir: &Path, first: &ShardManifest) -> anyhow::Result<SweepSpec> {
    let kind = CostKind::from_name(&first.cost)
        .ok_or_else(|| anyhow::anyhow!("{}: unknown cost '{}'", dir.display(), first.cost))?;
    let spec = SweepSpec {
        kind,
        tilt_deg: linspace(&first.grid.tilt_deg),
        azimuth_deg: linspace(&first.grid.azimuth_deg),
        distance: first.grid.distance.as_ref().map(linspace),
    };
    spec.validate()?;
    if spec.cells() != first.cells.total {
        bail!(
            "{}: the grid has {} cells, the manifest says {}",
            dir.display(),
            spec.cells(),
            first.cells.total
        );
    }
    Ok(spec)
}

/// The running minimum, finite count and seconds of a merge.
#[derive(Default)]
struct Merged {
    minimum: Option<SweepMinimum>,
    finite: usize,
    seconds: f64,
    /// Buffers reused from batch to batch.
    costs: Vec<f64>,
    distances: Vec<f64>,
}

/// Streams one shard's cost.npy (and distance.npy where the sweep profiles the air layer) into
/// `outputs` in batches of [`MERGE_BATCH`] cells, keeping the minimum.
fn merge_shard(
    shard_dir: &Path,
    m: &ShardManifest,
    spec: &SweepSpec,
    merged: &mut Merged,
    outputs: &mut SweepOutputs,
) -> anyhow::Result<()> {
    let depth = spec.distance.map_or(1, |d| d.count);
    let open = |name: &str| -> anyhow::Result<NpyReader> {
        let path = shard_dir.join(name);
        let reader = NpyReader::open(&path)?;
        if reader.shape() != [m.cells.end - m.cells.start] {
            bail!(
                "{}: shape {:?}, but the shard has {} cells",
                path.display(),
                reader.shape(),
                m.cells.end - m.cells.start
            );
        }
        Ok(reader)
    };
    let mut cost_reader = open("cost.npy")?;
    let mut distance_reader = if spec.profiles_air_distance() {
        Some(open("distance.npy")?)
    } else {
        None
    };
    let (mut costs, mut distances) = (
        std::mem::take(&mut merged.costs),
        std::mem::take(&mut merged.distances),
    );
    let mut cell = m.cells.start;
    while cost_reader.read(MERGE_BATCH, &mut costs)? > 0 {
        match distance_reader.as_mut() {
            Some(reader) => {
                reader.read(costs.len(), &mut distances)?;
            }
            None => {
                distances.clear();
                distances.extend(
                    (cell..cell + costs.len())
                        .map(|c| spec.distance.map_or(f64::NAN, |d| d.value(c % depth))),
                );
            }
        }
        for (i, &cost) in costs.iter().enumerate() {
            if cost.is_finite() {
                merged.finite += 1;
                if merged.minimum.is_none_or(|best| cost < best.cost) {
                    let (tilt_deg, azimuth_deg) = spec.cell_angles_deg(cell + i);
                    merged.minimum = Some(SweepMinimum {
                        cell: cell + i,
                        tilt_deg,
                        azimuth_deg,
                        distance: distances[i],
                        cost,
                    });
                }
            }
        }
        outputs.add(&SweepChunk {
            first: cell,
            costs: &costs,
            distances: &distances,
        })?;
        cell += costs.len();
    }
    (merged.costs, merged.distances) = (costs, distances);
    Ok(())
}

/// `flatport sweep …` (a sweep, or one shard of it) or `flatport sweep merge …`.
#[derive(Debug, Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct SweepCommand {
    #[command(subcommand)]
    pub action: Option<SweepAction>,
    #[command(flatten)]
    pub run: SweepArgs,
}

/// What `flatport sweep` does besides sweeping.
#[derive(Debug, Subcommand)]
pub enum SweepAction {
    /// Join the shards of a sweep (`--shard I/N`) into the files an unsharded sweep writes
    #[command(after_help = "\
cost.npy comes out byte for byte as an unsharded sweep on the same device writes it; cost.csv,
distance.npy, the pictures and summary.json are made from the whole grid (summary.json's seconds
add up the shards'). Shards of different sweeps (another cost, grid, rig or observations file), a
shard given twice, and a set that leaves cells out are refused, naming them.

Examples:
  flatport sweep merge shard-0 shard-1 shard-2 shard-3 --output sweep
  flatport sweep merge shards/* -o sweep --truth scene/truth.json")]
    Merge(MergeArgs),
}

/// `flatport sweep` from the command line: runs and prints where everything went.
pub fn run(command: SweepCommand) -> anyhow::Result<()> {
    match command.action {
        Some(SweepAction::Merge(args)) => {
            let summary = run_merge(&args)?;
            print_summary(&summary, &args.output);
        }
        None => {
            let args = command.run;
            let summary = run_sweep(&args)?;
            let output = args.output.as_deref().unwrap_or(Path::new("."));
            match args.shard {
                Some(shard) => outln!(
                    "shard {shard}: cells {}..{} in {:.2} s; wrote {}/cost.npy, shard.json (join the shards with `flatport sweep merge`)",
                    summary["cells"]["start"],
                    summary["cells"]["end"],
                    summary["seconds"].as_f64().unwrap_or(f64::NAN),
                    output.display()
                ),
                None => print_summary(&summary, output),
            }
        }
    }
    Ok(())
}

/// What a sweep's correspondences are: the targetless cost's are tracks (a master corner and its
/// matches), the boards' corners.
fn data_name(cost: &str) -> &'static str {
    if cost == "targetless" {
        "tracks"
    } else {
        "corners"
    }
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
        m["distance"]
            .as_f64()
            .map_or(String::new(), |d| format!(", air layer {:.3} mm", d * 1e3))
    );
    let data = data_name(summary["cost"].as_str().unwrap_or(""));
    outln!(
        "{} cells × {} {data} in {:.2} s ({:.3e} cell·{data}/s)",
        summary["cells"],
        summary["correspondences"],
        summary["seconds"].as_f64().unwrap_or(f64::NAN),
        summary["cell_correspondences_per_s"]
            .as_f64()
            .unwrap_or(f64::NAN)
    );
    outln!(
        "wrote {}/cost.npy, cost.csv, heatmap.png, polar.png, summary.json",
        dir.display()
    );
}
