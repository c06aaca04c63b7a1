//! `flatport calibrate --images DIR --board BOARD.json --port surface|shared|housings`: a whole
//! rig from images or videos of a board: every camera's lens in air, then the extrinsics and the
//! ports under water (DESIGN.md §3c).

use std::path::Path;

use anyhow::{Context, bail};

use flatport::calib::Board;
use flatport::calib::Options;
use flatport::calib::pipeline::boards::{
    BoardsCalibration, BoardsOptions, PortKind, RefineIntrinsics, RigSetup, calibrate_from_boards,
};
use flatport::calib::pipeline::intrinsics::{
    IntrinsicsFit, IntrinsicsOptions, calibrate_intrinsics,
};
use flatport::calib::pipeline::water_lenses::{calibrate_lenses_under_water, water_lens_start};
use flatport::io::board_footage::{
    DEFAULT_MAX_AIR_VIEWS, DEFAULT_MAX_WATER_FRAMES, Footage, FootageOptions, read_board_footage,
};
use flatport::io::{read_board, read_rig, write_boards_report, write_rig};
use flatport::model::{Layer, PinholeCamera};

use super::calib::{
    CalibrateArgs, CalibrationStatus, GlassArg, PortArg, backend, calibration_engine, summary,
};
use super::progress::Progress;

/// The run of `flatport calibrate --images`.
pub fn run(args: &CalibrateArgs, dir: &Path) -> anyhow::Result<()> {
    let board_path = args.board.as_ref().context(
        "--images needs --board BOARD.json (the board's description, see docs/images.md)",
    )?;
    let spec = read_board(board_path)?;
    let board = spec.corner_grid();
    let port = match args.port {
        Some(PortArg::Surface) => PortKind::Surface,
        Some(PortArg::Shared) => PortKind::Shared,
        Some(PortArg::Housings) => PortKind::Housings,
        None => bail!(
            "--images needs --port: surface (one bare water surface in front of every camera), shared (one port with its glass in front of every camera) or housings (a port per camera)"
        ),
    };
    let footage_options = FootageOptions {
        master: args.master.clone(),
        frame_step: args.frame_step.map(|s| s as usize),
        max_air_views: args
            .max_frames
            .map_or(DEFAULT_MAX_AIR_VIEWS, |m| m as usize),
        max_water_frames: args
            .max_frames
            .map_or(DEFAULT_MAX_WATER_FRAMES, |m| m as usize),
        // Without --rig the lenses come from air/, or, where there is no air/ folder, from the
        // underwater frames themselves.
        air: args.rig.is_none() && dir.join("air").is_dir(),
    };
    let water_lenses = args.rig.is_none() && !footage_options.air;
    let mut bar: Option<(String, Progress)> = None;
    let footage = read_board_footage(dir, &spec, &footage_options, &mut |what, done, total| {
        if bar.as_ref().is_none_or(|(w, _)| w != what) {
            bar = Some((what.to_string(), Progress::new(what, "images", args.quiet)));
        }
        if let Some((_, progress)) = bar.as_mut() {
            progress.update(done, total);
        }
    })?;
    drop(bar);
    let names = footage.names();
    let glass = glass_per_camera(&args.glass, &names, port)?;
    let index_water = args.index_water.unwrap_or(1.333);
    let index_air = args.index_air.unwrap_or(1.0);
    eprintln!(
        "cameras: {} (master {}); port: {}; board: {} {}x{} corners of {} mm",
        names.join(", "),
        names[0],
        port.name(),
        spec.kind(),
        board.cols,
        board.rows,
        board.square * 1e3
    );
    for note in &footage.notes {
        eprintln!("{note}");
    }
    // In-air intrinsics, the rig's cameras, or the starts from the underwater frames.
    let (cameras, fits) = match &args.rig {
        Some(path) => (cameras_from_rig(path, &footage)?, Vec::new()),
        None if water_lenses => {
            eprintln!(
                "no air/ folder and no --rig: every lens from the underwater frames, with the ports and the extrinsics (docs/calibration.md, \"Lenses from underwater frames alone\")"
            );
            (
                water_lens_starts(&footage, &board, index_air, index_water)?,
                Vec::new(),
            )
        }
        None => air_intrinsics(&footage, &board)?,
    };
    let (read, with_board, by_two) = footage.water_read;
    eprintln!(
        "underwater: the board in {with_board} of {read} frames ({by_two} seen by two or more cameras); {} frames used",
        footage.water.len()
    );
    let frames = footage.water;
    // Each camera's in-air corners, for the report's coverage pictures.
    let air_corners: Vec<Vec<nalgebra::Point2<f64>>> = footage
        .cameras
        .iter()
        .map(|c| {
            c.air
                .iter()
                .flat_map(|v| v.corners.iter().map(|(_, p)| *p))
                .collect()
        })
        .collect();
    let setup = RigSetup {
        cameras,
        port,
        glass,
        index_air,
        index_water,
    };
    let engine = calibration_engine(&args.engine)?;
    eprintln!("device: {}", engine.describe());
    let options = BoardsOptions {
        calibration: Options {
            huber: args.huber.or(BoardsOptions::default().calibration.huber),
            max_iterations: args.max_iterations,
            max_rms_px: args.max_rms_px,
            max_tilt: args.max_tilt_deg.to_radians(),
            backend: backend(engine),
            ..Options::default()
        },
        holdout: args.holdout,
        lens_std: fits.iter().map(|(_, fit)| fit.std).collect(),
        refine_intrinsics: match args.refine_intrinsics.as_str() {
            "never" => RefineIntrinsics::Never,
            "always" => RefineIntrinsics::Always,
            _ => RefineIntrinsics::Auto,
        },
        ..BoardsOptions::default()
    };
    eprintln!(
        "calibrating the extrinsics and {} from {} frames ({} % held out)...",
        match port {
            PortKind::Surface => "the water surface".to_string(),
            PortKind::Shared => "the shared port".to_string(),
            PortKind::Housings => format!("{} housings' ports", names.len()),
        },
        frames.len(),
        (100.0 * args.holdout).round()
    );
    let mut status = CalibrationStatus::new();
    let mut lens_choice = None;
    let result = if water_lenses {
        calibrate_lenses_under_water(&names, &setup, &board, &frames, &options, &mut |p| {
            status.update(p)
        })
        .map(|w| {
            lens_choice = Some(w.reason);
            w.calibration
        })
    } else {
        calibrate_from_boards(&names, &setup, &board, &frames, &options, &mut |p| {
            status.update(p)
        })
    };
    status.finish();
    let result = result?;
    print_result(&result, &names);
    if let Some(reason) = &lens_choice {
        outln!("lenses: {reason}");
        for camera in result.calibration.rig.cameras() {
            let std = result
                .calibration
                .report
                .cameras
                .iter()
                .find(|c| c.name == camera.name)
                .and_then(|c| c.intrinsics_std);
            let s = |j: usize| std.and_then(|s| s[j]).unwrap_or(f64::NAN);
            let c = &camera.intrinsics;
            outln!(
                "{}: fx {:.2} ± {:.2}, fy {:.2} ± {:.2}, cx {:.2} ± {:.2}, cy {:.2} ± {:.2} px; distortion [{}] (from the underwater frames)",
                camera.name,
                c.fx,
                s(0),
                c.fy,
                s(1),
                c.cx,
                s(2),
                c.cy,
                s(3),
                c.distortion
                    .iter()
                    .map(|d| format!("{d:.5}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
    }
    if let Some(path) = &args.report {
        write_boards_report(path, &result, &names, &fits)?;
    }
    if let Some(report_dir) = &args.report_dir {
        let mut input = flatport::report::Input::from_boards(
            &super::calib::command_line(),
            &result,
            &names,
            &board,
            &frames,
            options.calibration.huber,
        );
        input.air = air_corners;
        super::calib::written_report(report_dir, &input)?;
    }
    let report = &result.calibration.report;
    if !report.fits {
        bail!(
            "the calibration does not fit: {}. What the data look like: {}. {} not written{}",
            result.verdict.why.join("; "),
            report.diagnosis.join("; "),
            args.output.display(),
            args.report.as_ref().map_or(String::new(), |p| format!(
                "; the report is in {}",
                p.display()
            ))
        );
    }
    if let Some(path) = &args.truth {
        let truth = flatport::io::read_truth(path)?;
        // The truth's cameras may come in another order, with another master: compare camera by
        // camera, in the truth's master frame.
        let calibrated = &result.calibration.rig;
        let in_truth_order = truth.rig.as_ref().and_then(|t| {
            let order: Option<Vec<usize>> = t
                .cameras()
                .iter()
                .map(|c| calibrated.camera_index(&c.name))
                .collect();
            order.and_then(|o| calibrated.reordered(&o))
        });
        let calibrated = in_truth_order.as_ref().unwrap_or(calibrated);
        outln!("{}", super::calib::truth_errors(calibrated, &truth, path)?);
    }
    write_rig(&args.output, &result.calibration.rig)?;
    outln!(
        "wrote {}{}",
        args.output.display(),
        args.report
            .as_ref()
            .map_or(String::new(), |p| format!(", {}", p.display()))
    );
    Ok(())
}

/// The glass of each camera's port from `--glass` (`T:N` for all, `CAMERA=T:N` for one).
fn glass_per_camera(
    glass: &[GlassArg],
    names: &[String],
    port: PortKind,
) -> anyhow::Result<Vec<Vec<Layer>>> {
    let mut per_camera = vec![Vec::new(); names.len()];
    for g in glass {
        let layer = Layer {
            thickness: g.thickness,
            index: g.index,
        };
        match (&g.camera, port) {
            (_, PortKind::Surface) => bail!(
                "--glass: --port surface is a bare water surface, without glass (use --port shared for a window)"
            ),
            (Some(camera), PortKind::Shared) => bail!(
                "--glass {camera}=...: with --port shared one port is in front of every camera; give --glass THICKNESS:INDEX"
            ),
            (Some(camera), PortKind::Housings) => {
                let k = names.iter().position(|n| n == camera).with_context(|| {
                    format!(
                        "--glass {camera}=...: no camera '{camera}' (cameras: {})",
                        names.join(", ")
                    )
                })?;
                per_camera[k] = vec![layer];
            }
            (None, _) => {
                for layers in &mut per_camera {
                    if layers.is_empty() {
                        *layers = vec![layer];
                    }
                }
            }
        }
    }
    Ok(per_camera)
}

/// The intrinsics of the footage's cameras from the rig file at `path` (by name, of the same size).
fn cameras_from_rig(path: &Path, footage: &Footage) -> anyhow::Result<Vec<PinholeCamera>> {
    let rig = read_rig(path)?;
    footage
        .cameras
        .iter()
        .map(|camera| {
            let k = rig.camera_index(&camera.name).with_context(|| {
                format!(
                    "{}: no camera '{}' (the camera folders name the cameras; the rig has {})",
                    path.display(),
                    camera.name,
                    rig.cameras()
                        .iter()
                        .map(|c| c.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            })?;
            let intrinsics = rig.cameras()[k].intrinsics.clone();
            if (intrinsics.width, intrinsics.height) != (camera.width, camera.height) {
                bail!(
                    "{}: camera '{}' is {}x{} pixels, its frames {}x{}",
                    path.display(),
                    camera.name,
                    intrinsics.width,
                    intrinsics.height,
                    camera.width,
                    camera.height
                );
            }
            Ok(intrinsics)
        })
        .collect()
}

/// Every camera's start lens from its underwater frames (their magnification divided out).
fn water_lens_starts(
    footage: &Footage,
    board: &Board,
    index_air: f64,
    index_water: f64,
) -> anyhow::Result<Vec<PinholeCamera>> {
    footage
        .cameras
        .iter()
        .enumerate()
        .map(|(k, camera)| {
            let start = water_lens_start(
                &camera.name,
                (camera.width, camera.height),
                board,
                &footage.water,
                k,
                index_air,
                index_water,
            )?;
            eprintln!(
                "water/{}: lens start fx {:.1}, fy {:.1}, cx {:.1}, cy {:.1} px (the underwater views' pinhole, its focal length over n_water/n_air)",
                camera.name, start.fx, start.fy, start.cx, start.cy
            );
            Ok(start)
        })
        .collect()
}

/// Every camera's lens from its in-air views.
fn air_intrinsics(
    footage: &Footage,
    board: &Board,
) -> anyhow::Result<(Vec<PinholeCamera>, Vec<(String, IntrinsicsFit)>)> {
    let mut cameras = Vec::new();
    let mut fits = Vec::new();
    for camera in &footage.cameras {
        let name = &camera.name;
        eprintln!(
            "air/{name}: the board in {} of {} images, {} used",
            camera.air_read.1,
            camera.air_read.0,
            camera.air.len()
        );
        let fit = calibrate_intrinsics(
            name,
            camera.width,
            camera.height,
            board,
            &camera.air,
            &IntrinsicsOptions::default(),
        )
        .with_context(|| format!("the in-air calibration of camera '{name}'"))?;
        print_intrinsics(name, &fit);
        cameras.push(fit.camera.clone());
        fits.push((name.clone(), fit));
    }
    Ok((cameras, fits))
}

fn print_intrinsics(name: &str, fit: &IntrinsicsFit) {
    let c = &fit.camera;
    let s = &fit.std;
    outln!(
        "{name}: fx {:.2} ± {:.2}, fy {:.2} ± {:.2}, cx {:.2} ± {:.2}, cy {:.2} ± {:.2} px; distortion [{}]; RMS {:.3} px over {} views ({})",
        c.fx,
        s[0],
        c.fy,
        s[1],
        c.cx,
        s[2],
        c.cy,
        s[3],
        c.distortion
            .iter()
            .map(|d| format!("{d:.5}"))
            .collect::<Vec<_>>()
            .join(", "),
        fit.rms_px,
        fit.view_rms_px.iter().filter(|r| r.is_some()).count(),
        fit.model.reason
    );
    for (v, why) in fit.outliers.iter().chain(&fit.excluded) {
        outln!("  {name}: view {v} left out: {why}");
    }
}

fn print_result(result: &BoardsCalibration, names: &[String]) {
    for link in &result.links {
        if link.camera != 0 {
            eprintln!(
                "extrinsics start: {} from {} ({} shared frames)",
                names[link.camera], names[link.via], link.frames
            );
        }
    }
    for line in &result.left_out {
        eprintln!("{line}");
    }
    for corner in &result.dropped_corners {
        outln!("corner left out after the first fit: {corner}");
    }
    for (label, why) in &result.dropped {
        outln!("frame {label} dropped as an outlier: {why}");
    }
    out!("{}", summary(&result.calibration.report));
    if let Some(v) = &result.validation {
        outln!(
            "held out {} frames: reprojection RMS {:.3} px; {} neighbouring corners triangulated: median error {:.3} mm ({:.3} % of the square), RMS {:.3} mm",
            v.frames.len(),
            v.rms_px,
            v.distances,
            v.median_error_m * 1e3,
            v.median_error_percent,
            v.rms_error_m * 1e3
        );
        if v.views_left_out + v.corners_left_out > 0 {
            outln!(
                "  of the held-out frames, {} left out (no board pose that projects every corner) and {} corner images (misdetections, far off the board's shape)",
                v.views_left_out,
                v.corners_left_out
            );
        }
    }
    if let Some(choice) = &result.intrinsics {
        outln!("intrinsics: {}", choice.reason);
    }
    outln!("verdict: {}", result.verdict.line());
}
