//! `flatport simulate`: views of a board or a 3-D target by any rig, with the truth.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Args;

use flatport::calib::simulate::{Cameras, MAX_SIMULATED_CORNERS, check_scene_size};
use flatport::calib::{Board, CalibError, SceneSpec, Target, simulate};
use flatport::io::{
    IoError, Truth, read_rig, read_target, write_observations, write_rig,
    write_stereo_observations, write_truth,
};
use flatport::model::{Ports, Rig};

use super::calib::{naive_start, parse_board, stereo_pair};

/// `flatport simulate`
#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// Rig file: cameras and the true port(s), shared or one per camera
    #[arg(long, value_name = "RIG.json")]
    rig: PathBuf,
    /// Board as COLSxROWS@SQUARE: inner corners per row × per column (OpenCV's patternSize) and
    /// the square in metres; at most 10 000 corners
    #[arg(long, value_name = "COLSxROWS@M", default_value = "9x6@0.04", value_parser = parse_board)]
    board: Board,
    /// A 3-D target instead of the board: JSON {"points": [[x, y, z], ...]} in metres, in the
    /// target's own frame, opening toward the cameras along its -z axis (as a board's front)
    #[arg(long, value_name = "TARGET.json", conflicts_with = "board")]
    target: Option<PathBuf>,
    /// Number of views (at most 10⁷ corners in all: 185 185 views of a 9×6 board by two cameras
    /// in the stereo form)
    #[arg(long, default_value_t = 20, allow_negative_numbers = true)]
    views: usize,
    /// Standard deviation of the Gaussian noise added to every corner coordinate (pixels)
    #[arg(long, value_name = "PX", default_value_t = 0.1, value_parser = super::values::non_negative, allow_negative_numbers = true)]
    noise: f64,
    /// Seed of the random poses and noise (equal seeds give equal scenes)
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    seed: u64,
    /// Stereo form: the rig cameras that take the left and right images (default: the first
    /// two); only for a board and a shared port
    #[arg(long, value_name = "A,B", value_parser = super::parse_pair, allow_hyphen_values = true)]
    cameras: Option<(String, String)>,
    /// General form: every view is seen whole by the master camera and by at least this many
    /// cameras in all (default 1)
    #[arg(long, value_name = "N", allow_negative_numbers = true)]
    min_cameras: Option<usize>,
    /// Largest angle between the target's normal (z axis) and the master camera's axis (degrees, in [0, 90))
    #[arg(long, value_name = "DEG", default_value_t = 45.0, value_parser = super::values::tilt_below_90, allow_negative_numbers = true)]
    max_board_tilt_deg: f64,
    /// Output folder (created if missing): observations.json, truth.json, rig.json, start_rig.json
    #[arg(long, short, value_name = "DIR")]
    output: PathBuf,
}

/// Whether `simulate` writes the stereo form (a board, a shared port, and two cameras or a pair
/// named by `--cameras`): the observations of today's stereo calibration, unchanged.
fn stereo_form(rig: &Rig, args: &SimulateArgs) -> bool {
    args.target.is_none()
        && matches!(rig.ports(), Ports::Shared(_))
        && (rig.cameras().len() == 2 || args.cameras.is_some())
}

pub fn run_simulate(args: SimulateArgs) -> anyhow::Result<()> {
    // Sizes first, before anything is read or allocated.
    if args.target.is_none() {
        let most = MAX_SIMULATED_CORNERS / args.board.corners();
        if args.views == 0 || args.views > most {
            bail!(
                "--views {}: must lie in 1..={most} for a {}x{} board ({MAX_SIMULATED_CORNERS} corners in all: each takes about 100 bytes in memory and 80 in observations.json)",
                args.views,
                args.board.cols,
                args.board.rows
            );
        }
    }
    let rig = read_rig(&args.rig)?;
    if stereo_form(&rig, &args) {
        if args.min_cameras.is_some() {
            bail!(
                "--min-cameras applies to the general form; {} has a stereo pair behind a shared port and a board, where both cameras see every view",
                args.rig.display()
            );
        }
        simulate_stereo(&rig, &args)
    } else {
        if let Some((a, b)) = &args.cameras {
            bail!(
                "--cameras {a},{b} picks the stereo pair of a rig behind one shared port looking at a board; {} {}: every camera of the rig takes part (leave --cameras out)",
                args.rig.display(),
                if args.target.is_some() {
                    "with a 3-D target is simulated in the general form".to_string()
                } else {
                    format!(
                        "has {} camera(s) with {}, simulated in the general form",
                        rig.cameras().len(),
                        match rig.ports() {
                            Ports::Shared(_) => "one shared port",
                            Ports::PerCamera(_) => "a port per camera",
                        }
                    )
                }
            );
        }
        simulate_general(&rig, &args)
    }
}

/// The stereo form, as before the general form existed (equal seeds, equal files).
fn simulate_stereo(rig: &Rig, args: &SimulateArgs) -> anyhow::Result<()> {
    let pair = stereo_pair(
        rig,
        args.cameras.as_ref().map(|(a, b)| (a.as_str(), b.as_str())),
        "--cameras",
    )?;
    let mut spec = SceneSpec::pair(
        Target::Board(args.board),
        args.views,
        args.noise,
        args.seed,
        pair[0],
        pair[1],
    );
    spec.max_target_tilt = args.max_board_tilt_deg.to_radians();
    let scene = simulate(rig, &spec)?;
    create_output(args)?;
    write_stereo_observations(&args.output.join("observations.json"), &scene.observations)?;
    let truth = Truth {
        interface: rig.port_in_master(pair[0]),
        master_from_board: scene.master_from_target,
        noise_px: args.noise,
        seed: args.seed,
        rig: Some(rig.clone()),
    };
    write_outputs(rig, args, &truth)?;
    let i = rig.port_in_master(pair[0]);
    outln!(
        "simulated {} views of a {}x{} board ({} m squares), {} px noise, seed {}\ntruth: tilt {:.4}°, azimuth {:.4}°, air layer {:.3} mm\nwrote {}/observations.json, truth.json, rig.json (the truth), start_rig.json (a naive start: axis on the camera's z, 10 mm air)",
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

/// The general form: every camera of the rig, a board or a 3-D target.
fn simulate_general(rig: &Rig, args: &SimulateArgs) -> anyhow::Result<()> {
    let target = match &args.target {
        Some(path) => read_target(path)?,
        None => Target::Board(args.board),
    };
    if let Err(CalibError::Options(reason)) =
        check_scene_size(&target, rig.cameras().len(), args.views)
    {
        bail!("--views {}: {reason}", args.views);
    }
    let mut spec = SceneSpec::new(target.clone(), args.views, args.noise, args.seed);
    spec.max_target_tilt = args.max_board_tilt_deg.to_radians();
    if let Some(n) = args.min_cameras {
        let count = rig.cameras().len();
        if !(1..=count).contains(&n) {
            bail!(
                "--min-cameras {n}: {} has {count} camera(s), so 1 to {count}",
                args.rig.display()
            );
        }
        spec.cameras = Cameras::Any {
            required: vec![0],
            min: n,
        };
    }
    let scene = simulate(rig, &spec).map_err(|e| match (&args.target, &e) {
        // What is wrong with the target, located in its file.
        (Some(path), CalibError::BadBoard { reason }) => IoError::Invalid {
            path: path.clone(),
            field: "points".into(),
            reason: reason.clone(),
        }
        .into(),
        (Some(path), CalibError::Options(_)) => {
            anyhow::Error::new(e).context(format!("simulating views of {}", path.display()))
        }
        _ => anyhow::Error::new(e),
    })?;
    create_output(args)?;
    write_observations(&args.output.join("observations.json"), &scene.observations)?;
    let truth = Truth {
        interface: rig.port_in_master(0),
        master_from_board: scene.master_from_target.clone(),
        noise_px: args.noise,
        seed: args.seed,
        rig: Some(rig.clone()),
    };
    write_outputs(rig, args, &truth)?;
    let what = match &target {
        Target::Board(b) => format!("a {}x{} board ({} m squares)", b.cols, b.rows, b.square),
        Target::Points(p) => format!(
            "the {}-point target of {}",
            p.len(),
            args.target
                .as_ref()
                .map_or(String::new(), |t| t.display().to_string())
        ),
    };
    let ports = match rig.ports() {
        Ports::Shared(_) => "one shared port",
        Ports::PerCamera(_) => "a port per camera",
    };
    let seen: Vec<String> = rig
        .cameras()
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let views = scene.seen_by.iter().filter(|s| s.contains(&k)).count();
            format!("{} {views}", c.name)
        })
        .collect();
    let i = rig.port_in_master(0);
    outln!(
        "simulated {} views of {what} by {} camera(s) behind {ports}, {} px noise, seed {}\nviews seen whole, per camera: {}\ntruth: the master's port tilt {:.4}°, azimuth {:.4}°, air layer {:.3} mm (every camera's in truth.json and rig.json)\nwrote {}/observations.json (general form), truth.json, rig.json (the truth), start_rig.json (a naive start: each port's axis on its camera's z, 10 mm air)",
        args.views,
        rig.cameras().len(),
        args.noise,
        args.seed,
        seen.join(", "),
        i.tilt().to_degrees(),
        i.azimuth().to_degrees(),
        i.air_distance() * 1e3,
        args.output.display()
    );
    Ok(())
}

fn create_output(args: &SimulateArgs) -> anyhow::Result<()> {
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("cannot create {}", args.output.display()))
}

/// truth.json, rig.json (the truth) and start_rig.json (the naive start).
fn write_outputs(rig: &Rig, args: &SimulateArgs, truth: &Truth) -> anyhow::Result<()> {
    write_truth(&args.output.join("truth.json"), truth)?;
    write_rig(&args.output.join("rig.json"), rig)?;
    write_rig(&args.output.join("start_rig.json"), &naive_start(rig)?)?;
    Ok(())
}
