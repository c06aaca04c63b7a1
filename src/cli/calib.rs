//! `flatport calibrate` (and the pieces `flatport simulate` shares: the board option, the naive start).

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};

use flatport::calib::RigObservations;
use flatport::calib::methods::calibrate::calibrate_rig;
use flatport::calib::methods::rig_bundle::Estimate;
use flatport::calib::methods::rig_calibrate::{
    Estimated, RigCalibrationOptions, RigReport, is_thesis_stereo_case,
};
use flatport::calib::simulate::MAX_BOARD_CORNERS;
use flatport::calib::solvers::search::{
    MAX_CAP_GRID_AXES, cap_grid_size, min_cap_grid_spacing_deg_text,
};
use flatport::calib::{
    Board, CalibError, CalibrationOptions, CalibrationProgress, CalibrationReport, CostBackend,
    CpuBackend, GpuBackend, Method, Observations, StereoData, calibrate_with_progress,
};
use flatport::engine::Engine;
use flatport::io::{
    IoError, Truth, read_observations, read_rig, read_truth, write_report, write_rig,
};
use flatport::io::{read_rig_observations, rig_report_to_json_string, write_atomic};
use flatport::model::{Interface, Ports, Rig};

/// How to estimate (`--method`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum MethodArg {
    /// The thesis: axis from the weighted affine-grid invariant, air layer by linear least squares
    Consecutive,
    /// Maximum likelihood (Levenberg–Marquardt on the reprojection error) from the consecutive result
    Simultaneous,
    /// Consecutive, then maximum likelihood from several starts; the lowest cost wins
    Auto,
}

/// `flatport calibrate`
#[derive(Debug, Args)]
pub struct CalibrateArgs {
    /// Rig file: calibrated cameras; its ports are the start guess, what --estimate does not name is known
    #[arg(long, value_name = "RIG.json")]
    rig: PathBuf,
    /// Observations: the target's corners in every camera that saw each view (JSON, see below)
    #[arg(long, value_name = "OBS.json")]
    observations: PathBuf,
    /// The calibrated rig: the input rig with everything estimated replaced by its estimate
    #[arg(long, short, value_name = "RIG.json")]
    output: PathBuf,
    /// Also write the full report as JSON
    #[arg(long, value_name = "REPORT.json")]
    report: Option<PathBuf>,
    /// Estimator
    #[arg(long, value_enum, default_value_t = MethodArg::Auto)]
    method: MethodArg,
    /// What to estimate, comma-separated: axis, distance, layers (every layer thickness; indices
    /// stay known), layer:K (layer K's thickness only, 0-based as in the rig file: `layer:1` for
    /// the water of a glass–water–glass tank), extrinsics (R, t of every camera but the master).
    /// With a port per camera every port is estimated. A port with the same medium on both sides
    /// (a tank with air behind) keeps its distance: it changes no ray
    #[arg(long, value_name = "LIST", default_value = "axis,distance", value_parser = parse_estimate)]
    estimate: Estimate,
    /// Largest axis tilt from the master camera's z axis that the global search covers (degrees)
    #[arg(long, value_name = "DEG", default_value_t = 30.0, value_parser = super::values::tilt_bound, allow_negative_numbers = true)]
    max_tilt_deg: f64,
    /// Spacing of the global search grid over the axis (degrees; the grid holds at most 100 000 axes)
    #[arg(long, value_name = "DEG", default_value_t = 1.5, value_parser = super::values::positive, allow_negative_numbers = true)]
    grid_step_deg: f64,
    /// Huber loss with this threshold on each corner's residual (pixels); default plain least squares
    #[arg(long, value_name = "PX", value_parser = super::values::positive, allow_negative_numbers = true)]
    huber: Option<f64>,
    /// Iteration bound of the maximum-likelihood refinement
    #[arg(long, default_value_t = 200, allow_negative_numbers = true)]
    max_iterations: usize,
    /// Largest RMS reprojection error (pixels, either camera, outlier corners left out) accepted
    /// as a fit: above it the report (if asked for) is written with what the data look like, the
    /// rig is not written, and the exit status is 1
    #[arg(long, value_name = "PX", default_value_t = flatport::calib::methods::calibrate::DEFAULT_MAX_RMS_PX)]
    max_rms_px: f64,
    /// Truth of a simulated scene (from `flatport simulate`): print the errors of the result
    #[arg(long, value_name = "TRUTH.json")]
    truth: Option<PathBuf>,
    #[command(flatten)]
    engine: super::EngineArgs,
}

/// Parses `COLSxROWS@SQUARE`.
/// Smallest and largest square of a simulated board, metres: a tenth of a millimetre to ten metres.
const MIN_SQUARE_M: f64 = 1e-4;
const MAX_SQUARE_M: f64 = 10.0;

pub fn parse_board(text: &str) -> Result<Board, String> {
    let error = || format!("expected COLSxROWS@SQUARE such as 9x6@0.04, got '{text}'");
    let (size, square) = text.split_once('@').ok_or_else(error)?;
    let (cols, rows) = size.split_once(['x', 'X']).ok_or_else(error)?;
    let cols: usize = cols.trim().parse().map_err(|_| error())?;
    let rows: usize = rows.trim().parse().map_err(|_| error())?;
    let square: f64 = square.trim().parse().map_err(|_| error())?;
    if cols < 2 || rows < 2 || !(square > 0.0 && square.is_finite()) {
        return Err(format!(
            "a board needs at least 2x2 inner corners and a square > 0 m, got '{text}'"
        ));
    }
    if !(MIN_SQUARE_M..=MAX_SQUARE_M).contains(&square) {
        return Err(format!(
            "a square of {square:e} m: boards have squares from {MIN_SQUARE_M} m to {MAX_SQUARE_M} m (the square is in metres: 40 mm is 0.04), got '{text}'"
        ));
    }
    if cols.checked_mul(rows).is_none_or(|c| c > MAX_BOARD_CORNERS) {
        return Err(format!(
            "'{text}' has {cols} × {rows} inner corners; at most {MAX_BOARD_CORNERS} are simulated (every pose tried projects all of them)"
        ));
    }
    Ok(Board { rows, cols, square })
}

/// Rig indices of the stereo pair: by name, else the first two cameras.
pub fn stereo_pair(
    rig: &Rig,
    names: Option<(&str, &str)>,
    source: &str,
) -> anyhow::Result<[usize; 2]> {
    if rig.cameras().len() < 2 {
        bail!(
            "the rig has {} camera(s): calibration needs a stereo pair",
            rig.cameras().len()
        );
    }
    let Some((a, b)) = names else {
        return Ok([0, 1]);
    };
    let index = |name: &str| {
        rig.camera_index(name).with_context(|| {
            let known: Vec<&str> = rig.cameras().iter().map(|c| c.name.as_str()).collect();
            format!(
                "{source} names camera '{name}', which the rig does not have (it has {})",
                known.join(", ")
            )
        })
    };
    let pair = [index(a)?, index(b)?];
    if pair[0] == pair[1] {
        bail!("{source}: the left and right camera are the same ('{a}')");
    }
    Ok(pair)
}

/// The naive start guess for calibrating `rig`: its cameras, layers and indices with the axis on
/// the master camera's z axis and 10 mm of air. `simulate` writes it as start_rig.json, and the
/// demo calibrates from it.
pub fn naive_start(rig: &Rig) -> anyhow::Result<Rig> {
    let naive = |port: &Interface| port.with_pose(nalgebra::Vector3::z(), NAIVE_AIR_DISTANCE);
    let ports = match rig.ports() {
        Ports::Shared(interface) => Ports::Shared(naive(interface)?),
        Ports::PerCamera(ports) => {
            Ports::PerCamera(ports.iter().map(naive).collect::<Result<_, _>>()?)
        }
    };
    Ok(rig.with_new_ports(ports)?)
}

/// The air layer of [`naive_start`], metres.
pub const NAIVE_AIR_DISTANCE: f64 = 0.01;

/// A calibration error about the observations, located in the file.
fn in_file(path: &Path, error: CalibError) -> anyhow::Error {
    IoError::Invalid {
        path: path.to_path_buf(),
        field: error.field(),
        reason: error.to_string(),
    }
    .into()
}

/// Reads a rig and observations, checks the observations against the pair of cameras they name
/// (errors located in the observations file), and prepares them: (rig, data, warnings).
pub fn load_stereo_data(
    rig_path: &Path,
    observations_path: &Path,
) -> anyhow::Result<(Rig, StereoData, Vec<String>)> {
    let rig = read_rig(rig_path)?;
    let observations: Observations = match read_observations(observations_path) {
        Ok(stereo) => stereo,
        // The general form (views keyed by camera name): the views and corners the rig's first
        // two cameras both saw.
        Err(stereo_error) => {
            let Ok(general) = read_rig_observations(observations_path) else {
                return Err(stereo_error.into());
            };
            if rig.cameras().len() < 2 {
                bail!(
                    "{}: this needs two cameras (its costs are over a camera pair); the rig has one",
                    observations_path.display()
                );
            }
            let seen = general
                .resolve(&rig)
                .map_err(|e| in_file(observations_path, e))?;
            general.pair(&seen, &rig, 0, 1).ok_or_else(|| {
                anyhow::anyhow!(
                    "{}: this needs a board (its costs are over the board's grid), not a 3-D target",
                    observations_path.display()
                )
            })?
        }
    };
    let names = observations
        .cameras
        .as_ref()
        .map(|[a, b]| (a.as_str(), b.as_str()));
    let pair = stereo_pair(&rig, names, &observations_path.display().to_string())?;
    let intrinsics = pair.map(|k| rig.cameras()[k].intrinsics);
    let warnings = observations
        .validate(&intrinsics[0], &intrinsics[1])
        .map_err(|e| in_file(observations_path, e))?;
    let data =
        StereoData::new(&rig, pair, &observations).map_err(|e| in_file(observations_path, e))?;
    Ok((rig, data, warnings))
}

/// The cost backend on `engine`'s device.
pub fn cost_backend<'a>(engine: &'a Engine, data: &'a StereoData) -> Box<dyn CostBackend + 'a> {
    match engine {
        Engine::Cpu(_) => Box::new(CpuBackend::new(data)),
        Engine::Gpu(gpu) => Box::new(GpuBackend::new(data, gpu)),
    }
}

/// Checks the size of the global search grid before anything is read.
fn check_grid_step(args: &CalibrateArgs) -> anyhow::Result<()> {
    let (bound, spacing) = (
        args.max_tilt_deg.to_radians(),
        args.grid_step_deg.to_radians(),
    );
    // Other values of the two options are refused by the calibration with their own message.
    if bound > 0.0 && bound < 80f64.to_radians() && spacing > 0.0 && spacing <= bound {
        let axes = cap_grid_size(bound, spacing);
        if axes > MAX_CAP_GRID_AXES as f64 {
            bail!(
                "--grid-step-deg {}: the global search over --max-tilt-deg {} would take {axes:.3e} axes; it takes at most {MAX_CAP_GRID_AXES} (each axis costs an evaluation over every corner): use --grid-step-deg {} or more",
                args.grid_step_deg,
                args.max_tilt_deg,
                min_cap_grid_spacing_deg_text(bound)
            );
        }
    }
    Ok(())
}

fn parse_estimate(text: &str) -> Result<Estimate, String> {
    Estimate::parse(text)
}

pub fn run_calibrate(args: CalibrateArgs) -> anyhow::Result<()> {
    check_grid_step(&args)?;
    {
        let rig = read_rig(&args.rig)?;
        let observations = read_rig_observations(&args.observations)?;
        if !is_thesis_stereo_case(&rig, &observations, &args.estimate) {
            return run_rig_calibrate(&args, &rig, &observations);
        }
    }
    let (rig, data, warnings) = load_stereo_data(&args.rig, &args.observations)?;
    let options = CalibrationOptions {
        method: match args.method {
            MethodArg::Consecutive => Method::Consecutive,
            MethodArg::Simultaneous => Method::Simultaneous,
            MethodArg::Auto => Method::Auto,
        },
        max_tilt: args.max_tilt_deg.to_radians(),
        grid_spacing: args.grid_step_deg.to_radians(),
        huber: args.huber,
        max_iterations: args.max_iterations,
        max_rms_px: args.max_rms_px,
    };
    if args.huber.is_some_and(|k| k.is_nan() || k <= 0.0) {
        bail!("--huber must be a positive number of pixels");
    }
    if args.max_rms_px.is_nan() || args.max_rms_px <= 0.0 {
        bail!(
            "--max-rms-px must be a positive number of pixels, got {}",
            args.max_rms_px
        );
    }
    let engine = calibration_engine(&args.engine)?;
    let backend = cost_backend(&engine, &data);
    eprintln!("device: {}", engine.describe());
    eprintln!(
        "calibrating from {} views ({} corners seen by both cameras), method {}...",
        data.views.len(),
        data.corners.len(),
        options.method.name()
    );
    // Errors about the data name the observations file.
    let mut status = CalibrationStatus::new();
    let calibration = calibrate_with_progress(backend.as_ref(), &options, warnings, &mut |p| {
        status.update(p)
    });
    status.finish();
    let calibration = calibration.map_err(|e| in_file(&args.observations, e))?;
    let report = &calibration.report;
    if let Some(path) = &args.report {
        write_report(path, report)?;
    }
    out!("{}", summary(report));
    if let Some(path) = &args.truth {
        let truth = read_truth(path)?;
        outln!("{}", truth_errors(report, &truth));
    }
    if !report.fits {
        let worst = report.inlier_rms_px[0].max(report.inlier_rms_px[1]);
        bail!(
            "{}: the calibration does not fit: the reprojection RMS is {worst:.2} px (outlier corners left out), above --max-rms-px {}. What the data look like: {}. {} not written{}",
            args.observations.display(),
            args.max_rms_px,
            report.diagnosis.join("; "),
            args.output.display(),
            args.report.as_ref().map_or(String::new(), |p| format!(
                "; the report is in {}",
                p.display()
            ))
        );
    }
    let calibrated = rig.with_interface(calibration.interface.clone())?;
    write_rig(&args.output, &calibrated)?;
    outln!(
        "wrote {}{}",
        args.output.display(),
        args.report
            .as_ref()
            .map_or(String::new(), |p| format!(", {}", p.display()))
    );
    Ok(())
}

/// Progress of a long calibration on stderr (stage, steps, cost): nothing during the first
/// [`CalibrationStatus::SILENT`] (short runs stay quiet); then on a terminal one line redrawn at
/// most five times a second; elsewhere (a log) a line when a stage starts and at most one every
/// [`CalibrationStatus::LOG_EVERY`] within it.
struct CalibrationStatus {
    started: Instant,
    terminal: bool,
    last: Option<Instant>,
    stage: String,
    drawn: bool,
}

impl CalibrationStatus {
    const SILENT: Duration = Duration::from_secs(3);
    const LOG_EVERY: Duration = Duration::from_secs(30);
    const REDRAW_EVERY: Duration = Duration::from_millis(200);

    fn new() -> Self {
        Self {
            started: Instant::now(),
            terminal: std::io::stderr().is_terminal(),
            last: None,
            stage: String::new(),
            drawn: false,
        }
    }

    fn update(&mut self, p: &CalibrationProgress) {
        let now = Instant::now();
        let elapsed = now - self.started;
        if elapsed < Self::SILENT {
            return;
        }
        let new_stage = p.stage != self.stage;
        let every = if self.terminal {
            Self::REDRAW_EVERY
        } else {
            Self::LOG_EVERY
        };
        if !new_stage && self.last.is_some_and(|l| now - l < every) {
            return;
        }
        if new_stage {
            self.stage = p.stage.to_string();
        }
        self.last = Some(now);
        let steps = match p.total {
            Some(total) => format!("{}/{total}", p.done),
            None => format!("iteration {}", p.done),
        };
        let cost = if p.cost.is_finite() {
            format!(", cost {:.6e} {}", p.cost, p.unit)
        } else {
            String::new()
        };
        let line = format!(
            "[{:.1} s] {}: {steps}{cost}",
            elapsed.as_secs_f64(),
            p.stage
        );
        let mut err = std::io::stderr().lock();
        let _ = if self.terminal {
            write!(err, "\r{line}\x1b[K")
        } else {
            writeln!(err, "{line}")
        };
        self.drawn = true;
    }

    /// Ends the redrawn line on a terminal.
    fn finish(&mut self) {
        if self.terminal && self.drawn {
            let _ = writeln!(std::io::stderr());
        }
    }
}

/// The engine for cost batches. Without `--precision` a GPU runs f64 where the adapter has it:
/// the local refinement takes finite differences far below f32's resolution.
pub fn calibration_engine(args: &super::EngineArgs) -> anyhow::Result<Engine> {
    if args.precision.is_none() && args.device != super::Device::Cpu {
        let f64_args = super::EngineArgs {
            device: args.device,
            precision: Some(super::PrecisionArg::F64),
            adapter: args.adapter.clone(),
        };
        if let Ok(engine) = f64_args.engine_quiet() {
            return Ok(engine);
        }
    }
    args.engine_quiet()
}

/// Errors of a result against the truth of a simulated scene, one line.
pub fn truth_errors(report: &CalibrationReport, truth: &Truth) -> String {
    let axis = report
        .candidate
        .normal
        .angle(truth.interface.normal())
        .to_degrees();
    let air = (report.candidate.air_distance - truth.interface.air_distance()) * 1e3;
    format!("against the truth: axis off by {axis:.5}°, air layer off by {air:+.4} mm")
}

/// Errors of a calibrated rig against the whole true rig of a simulated scene, one line per port
/// and per camera whose extrinsics differ: each port's axis (in its own frame) and air distance,
/// its layer thicknesses where they differ, each camera's rotation and translation. Ports are
/// compared in their own frames (a camera's port in that camera's frame).
pub fn rig_truth_errors(result: &Rig, truth: &Rig) -> String {
    use flatport::calib::methods::rig_calibrate::port_names;
    let mut text = String::from("against the truth:");
    for ((name, got), (_, want)) in port_names(result).iter().zip(port_names(truth)) {
        text += &format!(
            "\n  port {name}: axis off by {:.5}°, air layer off by {:+.4} mm",
            got.normal().angle(want.normal()).to_degrees(),
            (got.air_distance() - want.air_distance()) * 1e3
        );
        for (k, (a, b)) in got.layers().iter().zip(want.layers()).enumerate() {
            if a.thickness != b.thickness {
                text += &format!(
                    ", layer {k} thickness off by {:+.4} mm",
                    (a.thickness - b.thickness) * 1e3
                );
            }
        }
    }
    for (got, want) in result.cameras().iter().zip(truth.cameras()).skip(1) {
        let (g, w) = (got.cam_from_master, want.cam_from_master);
        if g != w {
            text += &format!(
                "\n  camera {}: rotation off by {:.5}°, translation off by {:.4} mm",
                got.name,
                g.rotation.angle_to(&w.rotation).to_degrees(),
                (g.translation.vector - w.translation.vector).norm() * 1e3
            );
        }
    }
    text
}

/// Outlier images listed in the summary (the report lists all).
const MAX_LISTED_OUTLIERS: usize = 12;

/// The human summary printed on stdout.
pub fn summary(report: &CalibrationReport) -> String {
    let c = &report.candidate;
    let n = c.normal;
    let mut text = format!(
        "calibrated ({}) in {:.3} s on {}\n",
        report.method.name(),
        report.seconds,
        report.backend
    );
    let std = report.std;
    let pm = |i: usize, scale: f64, unit: &str| {
        std.map_or(String::new(), |s| format!(" ± {:.4}{unit}", s[i] * scale))
    };
    text += &format!("  normal      [{:.6}, {:.6}, {:.6}]\n", n.x, n.y, n.z);
    text += &format!(
        "  tilt        {:.4}°{}\n",
        c.tilt().to_degrees(),
        pm(0, 180.0 / std::f64::consts::PI, "°")
    );
    text += &format!(
        "  azimuth     {:.4}°{}\n",
        c.azimuth().to_degrees(),
        pm(1, 180.0 / std::f64::consts::PI, "°")
    );
    text += &format!(
        "  air layer   {:.4} mm{}\n",
        c.air_distance * 1e3,
        pm(2, 1e3, " mm")
    );
    text += &format!(
        "  reprojection RMS: left {:.4} px, right {:.4} px{}\n",
        report.rms_px[0],
        report.rms_px[1],
        report
            .sigma_px
            .map_or(String::new(), |s| format!(" (noise estimate σ {s:.4} px)"))
    );
    text += &format!(
        "  3-D: board fit RMS {:.4} mm, square deviation RMS {:.4} mm\n",
        report.scene_rms_m * 1e3,
        report.square_deviation_rms_m * 1e3
    );
    let worst = report
        .rms_px_per_view
        .iter()
        .enumerate()
        .max_by(|a, b| a.1[0].max(a.1[1]).total_cmp(&b.1[0].max(b.1[1])));
    if let Some((v, rms)) = worst {
        text += &format!(
            "  {} views, {} corners; worst view {v}: {:.4} / {:.4} px\n",
            report.views, report.corners, rms[0], rms[1]
        );
    }
    text += &format!(
        "  {} iterations ({})\n",
        report.iterations, report.termination
    );
    if !report.outlier_images.is_empty() {
        text += &format!(
            "  {} outlier corner(s) (view, image, corner: residual under the result):\n",
            report.outliers.len()
        );
        for o in report.outlier_images.iter().take(MAX_LISTED_OUTLIERS) {
            text += &format!(
                "    view {}, {} image ({}), corner {}: {:.2} px{}\n",
                o.view,
                o.side.name(),
                o.camera,
                o.corner,
                o.residual_px,
                if o.screened {
                    " (off the board's shape in its image: not used by the estimate)"
                } else {
                    ""
                }
            );
        }
        if report.outlier_images.len() > MAX_LISTED_OUTLIERS {
            text += &format!(
                "    … and {} more (all in the report)\n",
                report.outlier_images.len() - MAX_LISTED_OUTLIERS
            );
        }
    }
    for warning in &report.warnings {
        text += &format!("warning: {warning}\n");
    }
    text
}

/// `calibrate` for any rig (one camera, N cameras, a port per camera, a 3-D target, more
/// estimated than the axis and air distance): [`calibrate_rig`], its summary, the report, and the
/// rig only when the fit is within `--max-rms-px`.
fn run_rig_calibrate(
    args: &CalibrateArgs,
    rig: &Rig,
    observations: &RigObservations,
) -> anyhow::Result<()> {
    if args.max_rms_px.is_nan() || args.max_rms_px <= 0.0 {
        bail!(
            "--max-rms-px must be a positive number of pixels, got {}",
            args.max_rms_px
        );
    }
    let options = RigCalibrationOptions {
        estimate: args.estimate,
        method: match args.method {
            MethodArg::Consecutive => Method::Consecutive,
            MethodArg::Simultaneous => Method::Simultaneous,
            MethodArg::Auto => Method::Auto,
        },
        max_tilt: args.max_tilt_deg.to_radians(),
        huber: args.huber,
        max_iterations: args.max_iterations,
        max_rms_px: args.max_rms_px,
    };
    eprintln!(
        "calibrating {} camera(s) ({}) from {} views, estimating {}...",
        rig.cameras().len(),
        if rig.shared_interface().is_some() {
            "one shared port"
        } else {
            "a port per camera"
        },
        observations.views.len(),
        options.estimate.name()
    );
    let calibration =
        calibrate_rig(rig, observations, &options).map_err(|e| in_file(&args.observations, e))?;
    let report = &calibration.report;
    if let Some(path) = &args.report {
        write_atomic(path, rig_report_to_json_string(report).as_bytes())?;
    }
    out!("{}", rig_summary(report));
    if let Some(path) = &args.truth {
        let truth = read_truth(path)?;
        match &truth.rig {
            Some(true_rig) if true_rig.cameras().len() == calibration.rig.cameras().len() => {
                outln!("{}", rig_truth_errors(&calibration.rig, true_rig))
            }
            Some(_) => bail!(
                "{}: the truth's rig has {} camera(s), the calibrated one {}",
                path.display(),
                truth.rig.as_ref().map_or(0, |r| r.cameras().len()),
                calibration.rig.cameras().len()
            ),
            None => bail!(
                "{}: this truth file holds no rig (written before rigs were kept); simulate again",
                path.display()
            ),
        }
    }
    if !report.fits {
        let worst = report.worst_rms_px();
        bail!(
            "{}: the calibration does not fit: the reprojection RMS is {worst:.2} px in the worst camera, above --max-rms-px {}. What the data look like: {}. {} not written{}",
            args.observations.display(),
            args.max_rms_px,
            report.diagnosis.join("; "),
            args.output.display(),
            args.report.as_ref().map_or(String::new(), |p| format!(
                "; the report is in {}",
                p.display()
            ))
        );
    }
    write_rig(&args.output, &calibration.rig)?;
    outln!(
        "wrote {}{}",
        args.output.display(),
        args.report
            .as_ref()
            .map_or(String::new(), |p| format!(", {}", p.display()))
    );
    Ok(())
}

/// A value with its standard deviation, in `unit` after multiplying by `scale`.
fn with_std(value: &Estimated, scale: f64, unit: &str) -> String {
    match value.std {
        Some(s) => format!("{:.4} ± {:.4} {unit}", value.value * scale, s * scale),
        None => format!("{:.4} {unit}", value.value * scale),
    }
}

/// The human summary of a rig calibration.
pub fn rig_summary(report: &RigReport) -> String {
    let mut text = format!("method: {}\n", report.method);
    for port in &report.ports {
        text += &format!(
            "port {}: tilt {}, azimuth {}, air distance {}",
            port.name,
            with_std(&port.tilt, 180.0 / std::f64::consts::PI, "°"),
            with_std(&port.azimuth, 180.0 / std::f64::consts::PI, "°"),
            with_std(&port.distance, 1e3, "mm")
        );
        for (i, t) in port.thicknesses.iter().enumerate() {
            text += &format!(", layer {i} {}", with_std(t, 1e3, "mm"));
        }
        text += "\n";
    }
    for camera in &report.cameras {
        text += &format!(
            "camera {}: {} views, {} corners, RMS {:.4} px",
            camera.name, camera.views, camera.observations, camera.rms_px
        );
        if let Some((r, t)) = camera.extrinsics_std {
            let d = 180.0 / std::f64::consts::PI;
            text += &format!(
                ", extrinsics σ R [{:.4}, {:.4}, {:.4}]°, t [{:.3}, {:.3}, {:.3}] mm",
                r[0] * d,
                r[1] * d,
                r[2] * d,
                t[0] * 1e3,
                t[1] * 1e3,
                t[2] * 1e3
            );
        }
        text += "\n";
    }
    text += &format!(
        "RMS {:.4} px over {} corner observations in {} views, σ̂ {:.4} px{}; {} iterations ({}), {:.2} s\n",
        report.rms_px,
        report.observations,
        report.views,
        report.sigma_px,
        report.corner_noise_px.map_or(String::new(), |s| format!(
            " (corner noise seen in the images σ ≈ {s:.4} px)"
        )),
        report.iterations,
        report.termination,
        report.seconds
    );
    for warning in &report.warnings {
        text += &format!("warning: {warning}\n");
    }
    for finding in &report.diagnosis {
        text += &format!("diagnosis: {finding}\n");
    }
    text
}
