//! `flatport simulate` and `flatport calibrate`.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};

use flatport::calib::{
    Board, CalibError, CalibrationOptions, CalibrationReport, CostBackend, CpuBackend, GpuBackend, Method, Observations, SceneSpec,
    StereoData, calibrate, simulate,
};
use flatport::engine::Engine;
use flatport::io::{IoError, Truth, read_observations, read_rig, read_truth, write_observations, write_report, write_rig, write_truth};
use flatport::model::Rig;

/// `flatport simulate`
#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// Rig file: cameras and the true interface
    #[arg(long, value_name = "RIG.json")]
    rig: PathBuf,
    /// Board as COLSxROWS@SQUARE: inner corners per row × per column (OpenCV's patternSize) and
    /// the square in metres
    #[arg(long, value_name = "COLSxROWS@M", default_value = "9x6@0.04", value_parser = parse_board)]
    board: Board,
    /// Number of stereo views
    #[arg(long, default_value_t = 20, allow_negative_numbers = true)]
    views: usize,
    /// Standard deviation of the Gaussian noise added to every corner coordinate (pixels)
    #[arg(long, value_name = "PX", default_value_t = 0.1, value_parser = super::values::non_negative, allow_negative_numbers = true)]
    noise: f64,
    /// Seed of the random poses and noise (equal seeds give equal scenes)
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    seed: u64,
    /// Rig cameras that take the left and right images (default: the first two)
    #[arg(long, value_name = "A,B", value_parser = super::parse_pair, allow_hyphen_values = true)]
    cameras: Option<(String, String)>,
    /// Largest angle between the board's normal and the master camera's axis (degrees, in [0, 90))
    #[arg(long, value_name = "DEG", default_value_t = 45.0, value_parser = super::values::tilt_below_90, allow_negative_numbers = true)]
    max_board_tilt_deg: f64,
    /// Output folder (created if missing): observations.json, truth.json, rig.json
    #[arg(long, short, value_name = "DIR")]
    output: PathBuf,
}

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
    /// Rig file: calibrated cameras; its interface is the start guess, its layers and indices are known values
    #[arg(long, value_name = "RIG.json")]
    rig: PathBuf,
    /// Observations: board corners in both images per view (JSON, see the README)
    #[arg(long, value_name = "OBS.json")]
    observations: PathBuf,
    /// The calibrated rig: the input rig with the calibrated interface
    #[arg(long, short, value_name = "RIG.json")]
    output: PathBuf,
    /// Also write the full report as JSON
    #[arg(long, value_name = "REPORT.json")]
    report: Option<PathBuf>,
    /// Estimator
    #[arg(long, value_enum, default_value_t = MethodArg::Auto)]
    method: MethodArg,
    /// Largest axis tilt from the master camera's z axis that the global search covers (degrees)
    #[arg(long, value_name = "DEG", default_value_t = 30.0, value_parser = super::values::tilt_bound, allow_negative_numbers = true)]
    max_tilt_deg: f64,
    /// Spacing of the global search grid over the axis (degrees)
    #[arg(long, value_name = "DEG", default_value_t = 1.5, value_parser = super::values::positive, allow_negative_numbers = true)]
    grid_step_deg: f64,
    /// Huber loss with this threshold on each corner's residual (pixels); default plain least squares
    #[arg(long, value_name = "PX", value_parser = super::values::positive, allow_negative_numbers = true)]
    huber: Option<f64>,
    /// Iteration bound of the maximum-likelihood refinement
    #[arg(long, default_value_t = 200, allow_negative_numbers = true)]
    max_iterations: usize,
    /// Truth of a simulated scene (from `flatport simulate`): print the errors of the result
    #[arg(long, value_name = "TRUTH.json")]
    truth: Option<PathBuf>,
    #[command(flatten)]
    engine: super::EngineArgs,
}

/// Parses `COLSxROWS@SQUARE`.
pub fn parse_board(text: &str) -> Result<Board, String> {
    let error = || format!("expected COLSxROWS@SQUARE such as 9x6@0.04, got '{text}'");
    let (size, square) = text.split_once('@').ok_or_else(error)?;
    let (cols, rows) = size.split_once(['x', 'X']).ok_or_else(error)?;
    let cols: usize = cols.trim().parse().map_err(|_| error())?;
    let rows: usize = rows.trim().parse().map_err(|_| error())?;
    let square: f64 = square.trim().parse().map_err(|_| error())?;
    if cols < 2 || rows < 2 || !(square > 0.0 && square.is_finite()) {
        return Err(format!("a board needs at least 2x2 inner corners and a square > 0 m, got '{text}'"));
    }
    Ok(Board { rows, cols, square })
}

/// Rig indices of the stereo pair: by name, else the first two cameras.
pub fn stereo_pair(rig: &Rig, names: Option<(&str, &str)>, source: &str) -> anyhow::Result<[usize; 2]> {
    if rig.cameras().len() < 2 {
        bail!("the rig has {} camera(s): calibration needs a stereo pair", rig.cameras().len());
    }
    let Some((a, b)) = names else { return Ok([0, 1]) };
    let index = |name: &str| {
        rig.camera_index(name).with_context(|| {
            let known: Vec<&str> = rig.cameras().iter().map(|c| c.name.as_str()).collect();
            format!("{source} names camera '{name}', which the rig does not have (it has {})", known.join(", "))
        })
    };
    let pair = [index(a)?, index(b)?];
    if pair[0] == pair[1] {
        bail!("{source}: the left and right camera are the same ('{a}')");
    }
    Ok(pair)
}

pub fn run_simulate(args: SimulateArgs) -> anyhow::Result<()> {
    let rig = read_rig(&args.rig)?;
    let pair = stereo_pair(&rig, args.cameras.as_ref().map(|(a, b)| (a.as_str(), b.as_str())), "--cameras")?;
    if args.views == 0 {
        bail!("--views must be at least 1");
    }
    let mut spec = SceneSpec::new(args.board, args.views, args.noise, args.seed);
    spec.max_board_tilt = args.max_board_tilt_deg.to_radians();
    let scene = simulate(&rig, pair[0], pair[1], &spec)?;
    std::fs::create_dir_all(&args.output).with_context(|| format!("cannot create {}", args.output.display()))?;
    write_observations(&args.output.join("observations.json"), &scene.observations)?;
    let truth = Truth { interface: rig.interface().clone(), master_from_board: scene.master_from_board, noise_px: args.noise, seed: args.seed };
    write_truth(&args.output.join("truth.json"), &truth)?;
    write_rig(&args.output.join("rig.json"), &rig)?;
    let i = rig.interface();
    println!(
        "simulated {} views of a {}x{} board ({} m squares), {} px noise, seed {}\ntruth: tilt {:.4}°, azimuth {:.4}°, air layer {:.3} mm\nwrote {}/observations.json, truth.json, rig.json",
        args.views,
        args.board.cols,
        args.board.rows,
        args.board.square,
        args.noise,
        args.seed,
        i.tilt().to_degrees(),
        i.azimuth().to_degrees(),
        i.air_distance() * 1e3,
        args.output.display()
    );
    Ok(())
}

/// A calibration error about the observations, located in the file.
fn in_file(path: &Path, error: CalibError) -> anyhow::Error {
    IoError::Invalid { path: path.to_path_buf(), field: error.field(), reason: error.to_string() }.into()
}

/// Reads a rig and observations, checks the observations against the pair of cameras they name
/// (errors located in the observations file), and prepares them: (rig, data, warnings).
pub fn load_stereo_data(rig_path: &Path, observations_path: &Path) -> anyhow::Result<(Rig, StereoData, Vec<String>)> {
    let rig = read_rig(rig_path)?;
    let observations: Observations = read_observations(observations_path)?;
    let names = observations.cameras.as_ref().map(|[a, b]| (a.as_str(), b.as_str()));
    let pair = stereo_pair(&rig, names, &observations_path.display().to_string())?;
    let intrinsics = pair.map(|k| rig.cameras()[k].intrinsics);
    let warnings = observations.validate(&intrinsics[0], &intrinsics[1]).map_err(|e| in_file(observations_path, e))?;
    let data = StereoData::new(&rig, pair, &observations).map_err(|e| in_file(observations_path, e))?;
    Ok((rig, data, warnings))
}

/// The cost backend on `engine`'s device.
pub fn cost_backend<'a>(engine: &'a Engine, data: &'a StereoData) -> Box<dyn CostBackend + 'a> {
    match engine {
        Engine::Cpu(_) => Box::new(CpuBackend::new(data)),
        Engine::Gpu(gpu) => Box::new(GpuBackend::new(data, gpu)),
    }
}

pub fn run_calibrate(args: CalibrateArgs) -> anyhow::Result<()> {
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
    };
    if args.huber.is_some_and(|k| k.is_nan() || k <= 0.0) {
        bail!("--huber must be a positive number of pixels");
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
    let calibration = calibrate(backend.as_ref(), &options, warnings)?;
    let calibrated = rig.with_interface(calibration.interface.clone())?;
    write_rig(&args.output, &calibrated)?;
    if let Some(path) = &args.report {
        write_report(path, &calibration.report)?;
    }
    print!("{}", summary(&calibration.report));
    if let Some(path) = &args.truth {
        let truth = read_truth(path)?;
        println!("{}", truth_errors(&calibration.report, &truth));
    }
    println!("wrote {}{}", args.output.display(), args.report.as_ref().map_or(String::new(), |p| format!(", {}", p.display())));
    Ok(())
}

/// The engine for cost batches. Without `--precision` a GPU runs f64 where the adapter has it:
/// the local refinement takes finite differences far below f32's resolution.
pub fn calibration_engine(args: &super::EngineArgs) -> anyhow::Result<Engine> {
    if args.precision.is_none() && args.device != super::Device::Cpu {
        let f64_args = super::EngineArgs { device: args.device, precision: Some(super::PrecisionArg::F64), adapter: args.adapter.clone() };
        if let Ok(engine) = f64_args.engine_quiet() {
            return Ok(engine);
        }
    }
    args.engine_quiet()
}

/// Errors of a result against the truth of a simulated scene, one line.
pub fn truth_errors(report: &CalibrationReport, truth: &Truth) -> String {
    let axis = report.candidate.normal.angle(truth.interface.normal()).to_degrees();
    let air = (report.candidate.air_distance - truth.interface.air_distance()) * 1e3;
    format!("against the truth: axis off by {axis:.5}°, air layer off by {air:+.4} mm")
}

/// The human summary printed on stdout.
pub fn summary(report: &CalibrationReport) -> String {
    let c = &report.candidate;
    let n = c.normal;
    let mut text = format!("calibrated ({}) in {:.3} s on {}\n", report.method.name(), report.seconds, report.backend);
    let std = report.std;
    let pm = |i: usize, scale: f64, unit: &str| std.map_or(String::new(), |s| format!(" ± {:.4}{unit}", s[i] * scale));
    text += &format!("  normal      [{:.6}, {:.6}, {:.6}]\n", n.x, n.y, n.z);
    text += &format!("  tilt        {:.4}°{}\n", c.tilt().to_degrees(), pm(0, 180.0 / std::f64::consts::PI, "°"));
    text += &format!("  azimuth     {:.4}°{}\n", c.azimuth().to_degrees(), pm(1, 180.0 / std::f64::consts::PI, "°"));
    text += &format!("  air layer   {:.4} mm{}\n", c.air_distance * 1e3, pm(2, 1e3, " mm"));
    text += &format!(
        "  reprojection RMS: left {:.4} px, right {:.4} px{}\n",
        report.rms_px[0],
        report.rms_px[1],
        report.sigma_px.map_or(String::new(), |s| format!(" (noise estimate σ {s:.4} px)"))
    );
    text += &format!(
        "  3-D: board fit RMS {:.4} mm, square deviation RMS {:.4} mm\n",
        report.scene_rms_m * 1e3,
        report.square_deviation_rms_m * 1e3
    );
    let worst = report.rms_px_per_view.iter().enumerate().max_by(|a, b| a.1[0].max(a.1[1]).total_cmp(&b.1[0].max(b.1[1])));
    if let Some((v, rms)) = worst {
        text += &format!("  {} views, {} corners; worst view {v}: {:.4} / {:.4} px\n", report.views, report.corners, rms[0], rms[1]);
    }
    text += &format!("  {} iterations ({})\n", report.iterations, report.termination);
    for warning in &report.warnings {
        text += &format!("warning: {warning}\n");
    }
    text
}
