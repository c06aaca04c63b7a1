//! `flatport calibrate` (and the pieces `flatport simulate` shares: the board option, the naive start).

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};

use flatport::calib::simulate::MAX_BOARD_CORNERS;
use flatport::calib::solvers::search::{
    MAX_CAP_GRID_AXES, cap_grid_size, min_cap_grid_spacing_deg_text,
};
use flatport::calib::{
    Backend, Board, CalibError, CameraPair, CostBackend, CpuBackend, Estimate, Estimated,
    GpuBackend, Method, Options, Progress, Report, StereoData, calibrate_with_progress,
};
use flatport::engine::Engine;
use flatport::io::{
    IoError, Truth, read_observations, read_rig, read_truth, write_report, write_rig,
};
use flatport::model::{Interface, Ports, Rig};
use flatport::runs::images::Glass;

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

/// The port in front of the cameras (`--port`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PortArg {
    /// One bare water surface in front of every camera (no glass)
    Surface,
    /// One port, with its glass (--glass), in front of every camera
    Shared,
    /// A port per camera, each in its own housing
    Housings,
}

/// `flatport calibrate`
#[derive(Debug, Args)]
pub struct CalibrateArgs {
    /// Rig file: calibrated cameras; its ports are the start guess, what --estimate does not name
    /// is known. With --images: the cameras' in-air calibration instead of DIR/air/
    #[arg(long, value_name = "RIG.json", required_unless_present = "images")]
    pub rig: Option<PathBuf>,
    /// Observations: the target's corners in every camera that saw each view (JSON, see below)
    #[arg(
        long,
        value_name = "OBS.json",
        required_unless_present = "images",
        conflicts_with = "images"
    )]
    pub observations: Option<PathBuf>,
    /// The calibrated rig: the input rig with everything estimated replaced by its estimate
    #[arg(long, short, value_name = "RIG.json")]
    pub output: PathBuf,
    /// Also write the full report as JSON
    #[arg(long, value_name = "REPORT.json")]
    pub report: Option<PathBuf>,
    /// Also write a report to read: DIR/index.html (one page, opens offline in any browser), its
    /// pictures as PNG (the rig, per camera residual quivers, error maps and coverage, RMS per
    /// frame, histogram, held-out frames by depth), the numbers as JSON and CSV, the verdict and
    /// which views to add (every route), e.g. --report-dir report
    #[arg(long, value_name = "DIR")]
    pub report_dir: Option<PathBuf>,
    /// From images or videos alone: DIR holds water/<camera>/ (synchronized frames under water)
    /// and, where there are any, air/<camera>/ (each camera's in-air views of the board; without
    /// air/ and --rig the lenses come from the underwater frames); each folder images
    /// (PNG/JPEG/TIFF, sorted by name) or one video (MP4/MOV/AVI/MKV). Needs --board and --port
    #[arg(long, value_name = "DIR", help_heading = "From images")]
    pub images: Option<PathBuf>,
    /// The board (BOARD.json: ChArUco or chessboard, see docs/images.md)
    #[arg(long, value_name = "BOARD.json", help_heading = "From images")]
    pub board: Option<PathBuf>,
    /// The port in front of the cameras
    #[arg(long, value_enum, help_heading = "From images")]
    pub port: Option<PortArg>,
    /// Glass of the port(s): THICKNESS:INDEX (metres) for every port, or CAMERA=THICKNESS:INDEX
    /// for one camera's housing; repeatable
    #[arg(long, value_name = "[CAMERA=]T:N", value_parser = parse_glass, help_heading = "From images")]
    pub glass: Vec<Glass>,
    /// Refractive index of the water [default: 1.333]
    #[arg(long, value_name = "N", help_heading = "From images")]
    pub index_water: Option<f64>,
    /// Refractive index of the medium around the cameras [default: 1.0]
    #[arg(long, value_name = "N", help_heading = "From images")]
    pub index_air: Option<f64>,
    /// The master camera (its frame is the rig's) [default: the first camera folder by name]
    #[arg(long, value_name = "NAME", help_heading = "From images")]
    pub master: Option<String>,
    /// Read every N-th frame [default: 1, or as many as keep about 4 × --max-frames]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..), help_heading = "From images")]
    pub frame_step: Option<u64>,
    /// Most frames used per camera in air and under water, chosen for spread over the image and
    /// the board's poses [default: 40 in air, 60 under water]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(3..), help_heading = "From images")]
    pub max_frames: Option<u64>,
    /// Share of the underwater frames (seen by two or more cameras; with one camera, any) held
    /// out of the fit: the verdict (good / usable / poor) rests on how well the rig explains them
    #[arg(
        long,
        value_name = "SHARE",
        default_value_t = 0.2,
        help_heading = "From images"
    )]
    pub holdout: f64,
    /// Refine every camera's lens with the underwater frames: auto (kept where the held-out
    /// frames' RMS falls by more than 2 %), never, or always
    #[arg(long, value_name = "WHEN", default_value = "auto", value_parser = ["auto", "never", "always"], help_heading = "From images")]
    pub refine_intrinsics: String,
    /// No progress bars
    #[arg(long, short, help_heading = "From images")]
    pub quiet: bool,
    /// No board: calibrate the port(s) of --rig (cameras and extrinsics known, its ports the
    /// start) from matches of any textured scene. DIR holds one folder per rig camera, named as
    /// in the rig, of synchronized frames (images sorted by name, or one video), as `stereo`
    /// reads them (see docs/targetless.md)
    #[arg(long, requires_all = ["images", "rig"], conflicts_with_all = ["board", "port", "glass"], help_heading = "Targetless")]
    pub targetless: bool,
    /// Frames used by --targetless: START:STOP:STEP, each part optional (0:300:10, ::5)
    /// [default: at most 8 spread over the footage]
    #[arg(
        long,
        value_name = "START:STOP:STEP",
        requires = "targetless",
        help_heading = "Targetless"
    )]
    pub frames: Option<flatport::io::frames::FrameSelection>,
    /// With --targetless: refuse (write no rig) when an axis' σ exceeds this (degrees)
    #[arg(long, value_name = "DEG", default_value_t = 0.1, value_parser = super::values::positive, requires = "targetless", help_heading = "Targetless")]
    pub max_sigma_axis_deg: f64,
    /// With --targetless: refuse (write no rig) when an air distance's (or water height's) σ
    /// exceeds this (millimetres)
    #[arg(long, value_name = "MM", default_value_t = 2.0, value_parser = super::values::positive, requires = "targetless", help_heading = "Targetless")]
    pub max_sigma_distance_mm: f64,
    /// Estimator
    #[arg(long, value_enum, default_value_t = MethodArg::Auto)]
    pub method: MethodArg,
    /// What to estimate, comma-separated: axis, distance, layers (every layer thickness; indices
    /// stay known), layer:K (layer K's thickness only, 0-based as in the rig file: `layer:1` for
    /// the water of a glass–water–glass tank), extrinsics (R, t of every camera but the master),
    /// intrinsics (every camera's fx, fy, cx, cy and its lens terms that are not 0 in the rig
    /// file, refined with the underwater views; `--method simultaneous` or `auto`).
    /// With a port per camera every port is estimated. A port with the same medium on both sides
    /// (a tank with air behind) keeps its distance: it changes no ray
    #[arg(long, value_name = "LIST", default_value = "axis,distance", value_parser = parse_estimate)]
    pub estimate: Estimate,
    /// Largest axis tilt from the master camera's z axis that the global search covers (degrees)
    #[arg(long, value_name = "DEG", default_value_t = 30.0, value_parser = super::values::tilt_bound, allow_negative_numbers = true)]
    pub max_tilt_deg: f64,
    /// Spacing of the consecutive method's global search grid over the axis (degrees; the grid
    /// holds at most 100 000 axes) [default: 1.5, or --max-tilt-deg where that is smaller]
    #[arg(long, value_name = "DEG", value_parser = super::values::positive, allow_negative_numbers = true)]
    pub grid_step_deg: Option<f64>,
    /// Huber loss with this threshold on each corner's residual (pixels); default plain least squares
    #[arg(long, value_name = "PX", value_parser = super::values::positive, allow_negative_numbers = true)]
    pub huber: Option<f64>,
    /// Iteration bound of the maximum-likelihood refinement
    #[arg(long, default_value_t = 200, allow_negative_numbers = true)]
    pub max_iterations: usize,
    /// Largest RMS reprojection error (pixels, any camera, outlier corners left out) accepted as a
    /// fit: above it the report (if asked for) is written with what the data look like, the rig
    /// is not written, and the exit status is 1. Default: 3 px, and a maximum-likelihood fit
    /// within 3 × the corner noise seen in the images + 0.2 px (a fit far above the noise is
    /// plainly wrong); a value given here is the bound, whatever the noise. With --images:
    /// 2 px, and the held-out frames judge the rest (docs/calibration.md, "From images alone")
    #[arg(long, value_name = "PX")]
    pub max_rms_px: Option<f64>,
    /// Truth of a simulated scene (from `flatport simulate`; with --targetless the true RIG.json):
    /// print the errors of the result
    #[arg(long, value_name = "TRUTH.json")]
    pub truth: Option<PathBuf>,
    #[command(flatten)]
    pub engine: super::EngineArgs,
}

/// Parses `T:N` or `CAMERA=T:N`.
pub fn parse_glass(text: &str) -> Result<Glass, String> {
    let (camera, rest) = match text.split_once('=') {
        Some((c, r)) => (Some(c.trim().to_string()), r),
        None => (None, text),
    };
    let error = || {
        format!(
            "expected THICKNESS:INDEX (metres, e.g. 0.01:1.49) or CAMERA=THICKNESS:INDEX, got '{text}'"
        )
    };
    let (t, n) = rest.split_once(':').ok_or_else(error)?;
    let thickness: f64 = t.trim().parse().map_err(|_| error())?;
    let index: f64 = n.trim().parse().map_err(|_| error())?;
    if !(thickness > 0.0 && thickness < 1.0) {
        return Err(format!(
            "'{text}': a glass thickness between 0 and 1 m (in metres: 10 mm is 0.01)"
        ));
    }
    if !(1.0..=4.0).contains(&index) {
        return Err(format!("'{text}': a refractive index from 1 to 4"));
    }
    if camera.as_deref() == Some("") {
        return Err(error());
    }
    Ok(Glass {
        camera,
        thickness,
        index,
    })
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
) -> anyhow::Result<CameraPair> {
    if rig.cameras().len() < 2 {
        bail!(
            "the rig has {} camera(s): calibration needs a stereo pair",
            rig.cameras().len()
        );
    }
    let Some((a, b)) = names else {
        return Ok(CameraPair::new(0, 1));
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
    let pair = CameraPair::new(index(a)?, index(b)?);
    if pair.first == pair.second {
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

/// Reads a rig and observations of a board and prepares one camera pair's corners for the pair
/// costs (errors located in the observations file): the two cameras of every view when each view
/// holds the same two (the stereo form), else the rig's first two cameras. Returns (rig, data,
/// warnings about the views).
pub fn load_stereo_data(
    rig_path: &Path,
    observations_path: &Path,
) -> anyhow::Result<(Rig, StereoData, Vec<String>)> {
    let rig = read_rig(rig_path)?;
    let observations = read_observations(observations_path)?;
    let Some(board) = observations.target.board().copied() else {
        bail!(
            "{}: this needs a board (its costs are over the board's grid), not a 3-D target",
            observations_path.display()
        );
    };
    if rig.cameras().len() < 2 {
        bail!(
            "{}: this needs two cameras (its costs are over a camera pair); the rig has one",
            observations_path.display()
        );
    }
    let seen = observations
        .resolve(&rig)
        .map_err(|e| in_file(observations_path, e))?;
    let warnings = observations
        .check(&seen)
        .map_err(|e| in_file(observations_path, e))?;
    let pair = match seen.first().map(|v| v.cameras.as_slice()) {
        Some([(a, _), (b, _)])
            if seen
                .iter()
                .all(|v| v.cameras.iter().map(|c| c.0).eq([*a, *b])) =>
        {
            // The order of the file (left, right), whatever the rig's order.
            let first = &observations.views[0].images[0];
            let first_is_a = matches!(&first.camera, flatport::calib::CameraKey::Position(0))
                || rig.camera_index(&first.key) == Some(*a)
                || matches!(&first.camera, flatport::calib::CameraKey::Name(n) if rig.camera_index(n) == Some(*a));
            if first_is_a { [*a, *b] } else { [*b, *a] }
        }
        _ => [0, 1],
    };
    let data =
        StereoData::new(&rig, pair, &board, &seen).map_err(|e| in_file(observations_path, e))?;
    if data.views.len() < 3 {
        bail!(
            "{}: cameras {} and {} see the board together in {} view(s); the pair costs need at least 3",
            observations_path.display(),
            rig.cameras()[pair[0]].name,
            rig.cameras()[pair[1]].name,
            data.views.len()
        );
    }
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
    let Some(step) = args.grid_step_deg else {
        return Ok(());
    };
    let (bound, spacing) = (args.max_tilt_deg.to_radians(), step.to_radians());
    // Other values of the two options are refused by the calibration with their own message.
    if bound > 0.0 && bound < 80f64.to_radians() && spacing > 0.0 && spacing <= bound {
        let axes = cap_grid_size(bound, spacing);
        if axes > MAX_CAP_GRID_AXES as f64 {
            bail!(
                "--grid-step-deg {}: the global search over --max-tilt-deg {} would take {axes:.3e} axes; it takes at most {MAX_CAP_GRID_AXES} (each axis costs an evaluation over every corner): use --grid-step-deg {} or more",
                step,
                args.max_tilt_deg,
                min_cap_grid_spacing_deg_text(bound)
            );
        }
    }
    Ok(())
}

/// The command as it was typed, for the report's page.
pub fn command_line() -> String {
    std::env::args().collect::<Vec<_>>().join(" ")
}

/// Writes the report page of `input` into `dir` and says where it is.
pub fn written_report(
    dir: &std::path::Path,
    input: &flatport::report::Input,
) -> anyhow::Result<()> {
    let written = flatport::report::write_report(dir, input)?;
    eprintln!(
        "report: {} ({} files)",
        written.index.display(),
        written.files.len()
    );
    if let Some(advice) = &written.advice {
        for line in &advice.text {
            eprintln!("  {line}");
        }
    }
    Ok(())
}

fn parse_estimate(text: &str) -> Result<Estimate, String> {
    Estimate::parse(text)
}

pub fn run_calibrate(args: CalibrateArgs) -> anyhow::Result<()> {
    check_grid_step(&args)?;
    if let Some(bound) = args.max_rms_px
        && !(bound > 0.0)
    {
        bail!("--max-rms-px must be a positive number of pixels, got {bound}");
    }
    let (Some(rig_path), Some(observations_path)) = (&args.rig, &args.observations) else {
        bail!("calibrate needs --rig and --observations, or --images DIR (see --help)");
    };
    let rig = read_rig(rig_path)?;
    let observations = read_observations(observations_path)?;
    let engine = calibration_engine(&args.engine)?;
    eprintln!("device: {}", engine.describe());
    let options = Options {
        method: match args.method {
            MethodArg::Consecutive => Method::Consecutive,
            MethodArg::Simultaneous => Method::Simultaneous,
            MethodArg::Auto => Method::Auto,
        },
        estimate: args.estimate,
        max_tilt: args.max_tilt_deg.to_radians(),
        grid_spacing: args.grid_step_deg.map(f64::to_radians),
        huber: args.huber,
        max_iterations: args.max_iterations,
        max_rms_px: args.max_rms_px,
        backend: backend(engine),
        lens_prior: None,
    };
    eprintln!(
        "calibrating {} camera(s) ({}) from {} views, estimating {}, method {}...",
        rig.cameras().len(),
        match rig.ports() {
            Ports::Shared(_) => "one shared port",
            Ports::PerCamera(_) => "a port per camera",
        },
        observations.views.len(),
        options.estimate.name(),
        options.method.name()
    );
    let mut status = CalibrationStatus::new();
    let calibration =
        calibrate_with_progress(&rig, &observations, &options, &mut |p| status.update(p));
    status.finish();
    // Errors about the data name the observations file.
    let calibration = calibration.map_err(|e| in_file(observations_path, e))?;
    let report = &calibration.report;
    if let Some(path) = &args.report {
        write_report(path, report)?;
    }
    if let Some(dir) = &args.report_dir {
        let input = flatport::report::Input::from_observations(
            &command_line(),
            &calibration.rig,
            report,
            &observations,
            options.huber,
        );
        written_report(dir, &input)?;
    }
    out!("{}", summary(report));
    if let Some(path) = &args.truth {
        let truth = read_truth(path)?;
        outln!("{}", truth_errors(&calibration.rig, &truth, path)?);
    }
    if !report.fits {
        let worst = report.worst_inlier_rms_px();
        let bound = options.rms_bound();
        let why = match report.noise_px {
            Some(s) if worst <= bound => format!(
                "far above the corner noise seen in the images (σ ≈ {s:.3} px; a fit comes within {} σ + {} px, and --max-rms-px accepts a bound of your own)",
                flatport::calib::pipeline::NOISE_FACTOR,
                flatport::calib::pipeline::NOISE_MARGIN_PX
            ),
            _ => format!("above --max-rms-px {bound}"),
        };
        bail!(
            "{}: the calibration does not fit: the reprojection RMS is {worst:.2} px in the worst camera (outlier corners left out), {why}. What the data look like: {}. {} not written{}",
            observations_path.display(),
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

/// Where the calibration's cost batches run: the GPU engine, or the CPU.
pub fn backend(engine: Engine) -> Backend {
    match engine {
        Engine::Gpu(gpu) => Backend::Gpu(std::sync::Arc::new(gpu)),
        Engine::Cpu(_) => Backend::Cpu,
    }
}

/// Progress of a long calibration on stderr (stage, steps, cost): nothing during the first
/// [`CalibrationStatus::SILENT`] (short runs stay quiet); then on a terminal one line redrawn at
/// most five times a second; elsewhere (a log) a line when a stage starts and at most one every
/// [`CalibrationStatus::LOG_EVERY`] within it.
pub struct CalibrationStatus {
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

    pub fn new() -> Self {
        Self {
            started: Instant::now(),
            terminal: std::io::stderr().is_terminal(),
            last: None,
            stage: String::new(),
            drawn: false,
        }
    }

    pub fn update(&mut self, p: &Progress) {
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
    pub fn finish(&mut self) {
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

/// The errors of a calibrated rig against the truth of a simulated scene (`flatport simulate`'s
/// truth.json at `path`): every port and camera against the whole true rig, or, in truth files
/// written before the rig was kept, the first port against the true port.
pub fn truth_errors(result: &Rig, truth: &Truth, path: &Path) -> anyhow::Result<String> {
    match &truth.rig {
        Some(true_rig) if true_rig.cameras().len() == result.cameras().len() => {
            Ok(rig_truth_errors(result, true_rig))
        }
        Some(true_rig) => bail!(
            "{}: the truth's rig has {} camera(s), the calibrated one {}",
            path.display(),
            true_rig.cameras().len(),
            result.cameras().len()
        ),
        None => {
            let port = result.port_in_master(0);
            Ok(format!(
                "against the truth: axis off by {:.5}°, air layer off by {:+.4} mm",
                port.normal().angle(truth.interface.normal()).to_degrees(),
                (port.air_distance() - truth.interface.air_distance()) * 1e3
            ))
        }
    }
}

/// Errors of a calibrated rig against the whole true rig of a simulated scene, one line per port
/// and per camera whose extrinsics differ: each port's axis (in its own frame) and air distance,
/// its layer thicknesses where they differ, each camera's rotation and translation. Cameras are
/// paired by name (the truth re-expressed with the calibrated rig's master first, so a
/// calibration that chose another master or order is compared camera to camera), by position
/// only when the names differ (and then it says so). Ports are compared in their own frames (a
/// camera's port in that camera's frame).
pub fn rig_truth_errors(result: &Rig, truth: &Rig) -> String {
    use flatport::calib::pipeline::report::port_names;
    let mut lines = Vec::new();
    let by_name: Option<Vec<usize>> = result
        .cameras()
        .iter()
        .map(|c| truth.cameras().iter().position(|t| t.name == c.name))
        .collect();
    let truth = match by_name.and_then(|order| truth.reordered(&order)) {
        Some(reordered) => reordered,
        None => {
            lines.push(format!(
                "(the truth's cameras are named {}: paired with the calibrated ones by position)",
                truth
                    .cameras()
                    .iter()
                    .map(|c| format!("'{}'", c.name))
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
            truth.clone()
        }
    };
    let truth = &truth;
    for ((name, got), (_, want)) in port_names(result).iter().zip(port_names(truth)) {
        let mut line = format!(
            "port {name}: axis off by {:.5}°, air layer off by {:+.4} mm",
            got.normal().angle(want.normal()).to_degrees(),
            (got.air_distance() - want.air_distance()) * 1e3
        );
        for (k, (a, b)) in got.layers().iter().zip(want.layers()).enumerate() {
            if a.thickness != b.thickness {
                line += &format!(
                    ", layer {k} thickness off by {:+.4} mm",
                    (a.thickness - b.thickness) * 1e3
                );
            }
        }
        lines.push(line);
    }
    for (got, want) in result.cameras().iter().zip(truth.cameras()).skip(1) {
        let (g, w) = (got.cam_from_master, want.cam_from_master);
        if g != w {
            lines.push(format!(
                "camera {}: rotation off by {:.5}°, translation off by {:.4} mm",
                got.name,
                g.rotation.angle_to(&w.rotation).to_degrees(),
                (g.translation.vector - w.translation.vector).norm() * 1e3
            ));
        }
    }
    // One shared port and nothing else estimated: one line.
    match lines.as_slice() {
        [only] if only.starts_with("port shared: ") => {
            format!("against the truth: {}", &only["port shared: ".len()..])
        }
        _ => format!("against the truth:\n  {}", lines.join("\n  ")),
    }
}

/// Outlier images listed in the summary (the report lists all).
const MAX_LISTED_OUTLIERS: usize = 12;

/// A value with its standard deviation, in `unit` after multiplying by `scale`.
fn with_std(value: &Estimated, scale: f64, unit: &str) -> String {
    match value.std {
        Some(s) => format!("{:.4} ± {:.4} {unit}", value.value * scale, s * scale),
        None => format!("{:.4} {unit}", value.value * scale),
    }
}

/// The human summary printed on stdout: what ran, every port and camera with standard
/// deviations, the RMS values, the 3-D errors of a pair, the worst view, the outlier images, the
/// warnings and the diagnosis.
pub fn summary(report: &Report) -> String {
    let degrees = 180.0 / std::f64::consts::PI;
    let mut text = format!(
        "calibrated ({}) in {:.3} s on {}\n",
        report.strategy, report.seconds, report.backend
    );
    for port in &report.ports {
        let n = port.normal;
        text += &format!(
            "  port {}: tilt {}, azimuth {}, air layer {}",
            port.name,
            with_std(&port.tilt, degrees, "°"),
            with_std(&port.azimuth, degrees, "°"),
            with_std(&port.distance, 1e3, "mm")
        );
        for (i, t) in port.thicknesses.iter().enumerate() {
            text += &format!(", layer {i} {}", with_std(t, 1e3, "mm"));
        }
        text += &format!("\n    normal [{:.6}, {:.6}, {:.6}]\n", n[0], n[1], n[2]);
    }
    for camera in &report.cameras {
        text += &format!(
            "  camera {}: {} views, {} corners, reprojection RMS {:.4} px",
            camera.name, camera.views, camera.observations, camera.rms_px
        );
        if let Some((r, t)) = camera.extrinsics_std {
            text += &format!(
                ", extrinsics σ R [{:.4}, {:.4}, {:.4}]°, t [{:.3}, {:.3}, {:.3}] mm",
                r[0] * degrees,
                r[1] * degrees,
                r[2] * degrees,
                t[0] * 1e3,
                t[1] * 1e3,
                t[2] * 1e3
            );
        }
        text += "\n";
    }
    text += &format!(
        "  RMS {:.4} px over {} corner observations in {} views{}{}\n",
        report.rms_px,
        report.observations,
        report.views,
        report
            .sigma_px
            .map_or(String::new(), |s| format!(", noise estimate σ̂ {s:.4} px")),
        report.noise_px.map_or(String::new(), |s| format!(
            " (corner noise seen in the images σ ≈ {s:.4} px)"
        ))
    );
    if let Some((parameter, factor)) = &report.sigma_from_scatter {
        text += &format!(
            "  σ from the views' scatter where it exceeds σ̂'s: raised up to ×{factor:.2} ({parameter})\n"
        );
    }
    if let Some(scene) = &report.scene {
        text += &format!(
            "  3-D ({}–{}): board fit RMS {:.4} mm, square deviation RMS {:.4} mm\n",
            scene.cameras[0],
            scene.cameras[1],
            scene.rms_m * 1e3,
            scene.square_deviation_rms_m * 1e3
        );
    }
    let worst = (0..report.views)
        .map(|v| {
            let rms = report
                .cameras
                .iter()
                .map(|c| c.rms_px_per_view[v])
                .filter(|r| !r.is_nan())
                .fold(0.0, f64::max);
            (v, rms)
        })
        .max_by(|a, b| a.1.total_cmp(&b.1));
    if let Some((v, rms)) = worst {
        text += &format!(
            "  {} views, {} corners; worst view {v}: {rms:.4} px in its worst camera\n",
            report.views, report.corners
        );
    }
    text += &format!(
        "  {} iterations ({})\n",
        report.iterations, report.termination
    );
    if !report.outliers.is_empty() {
        let corners: std::collections::BTreeSet<(usize, usize)> =
            report.outliers.iter().map(|o| (o.view, o.corner)).collect();
        text += &format!(
            "  {} outlier corner(s) (view, image, corner: residual under the result):\n",
            corners.len()
        );
        for o in report.outliers.iter().take(MAX_LISTED_OUTLIERS) {
            text += &format!(
                "    view {}, {} image ({}), corner {}: {:.2} px{}\n",
                o.view,
                o.image,
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
        if report.outliers.len() > MAX_LISTED_OUTLIERS {
            text += &format!(
                "    … and {} more (all in the report)\n",
                report.outliers.len() - MAX_LISTED_OUTLIERS
            );
        }
    }
    for warning in &report.warnings {
        text += &format!("warning: {warning}\n");
    }
    for finding in &report.diagnosis {
        text += &format!("diagnosis: {finding}\n");
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A calibration that chose the other camera as its master is compared camera to camera:
    /// the true rig itself, reordered, is off by nothing (paired by position it was off by the
    /// whole baseline).
    #[test]
    fn truth_is_paired_by_name() {
        let truth = flatport::io::rig_from_json_str(
            super::super::demo::EXAMPLE_RIG,
            Path::new("data/example_rig.json"),
        )
        .unwrap();
        let swapped = truth.reordered(&[1, 0]).unwrap();
        let text = rig_truth_errors(&swapped, &truth);
        assert!(!text.contains("by position"), "{text}");
        for number in text
            .split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-' || c == '+'))
            .filter_map(|w| w.parse::<f64>().ok())
        {
            assert!(number.abs() < 1e-9, "{text}");
        }
        let mut renamed = swapped.cameras().to_vec();
        renamed[0].name = "other".into();
        let renamed = Rig::with_ports(renamed, swapped.ports().clone()).unwrap();
        assert!(rig_truth_errors(&renamed, &truth).contains("by position"));
    }
}
