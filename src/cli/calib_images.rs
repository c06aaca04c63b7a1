//! `flatport calibrate --images DIR --board BOARD.json --port surface|shared|housings`: a whole
//! rig from images or videos of a board: every camera's lens in air, then the extrinsics and the
//! ports under water (DESIGN.md §3c).

use std::path::Path;

use anyhow::{Context, bail};

use flatport::calib::pipeline::boards::{BoardsCalibration, PortKind, RefineIntrinsics, RigSetup};
use flatport::calib::pipeline::intrinsics::IntrinsicsFit;
use flatport::io::{read_board, read_rig, write_boards_report, write_rig};
use flatport::runs::board_footage::{
    DEFAULT_MAX_AIR_VIEWS, DEFAULT_MAX_WATER_FRAMES, FootageOptions, read_board_footage,
};
use flatport::runs::images::{
    FitSettings, LensSource, air_lens, boards_options, calibrate, cameras_from_rig, check_glass,
    glass_per_camera, refusal, water_lens_starts,
};

use super::calib::{
    CalibrateArgs, CalibrationStatus, PortArg, backend, calibration_engine, summary,
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
    check_glass(&args.glass, port)?;
    let source = LensSource::choose(dir, args.rig.is_some());
    let footage_options = FootageOptions {
        master: args.master.clone(),
        frame_step: args.frame_step.map(|s| s as usize),
        max_air_views: args
            .max_frames
            .map_or(DEFAULT_MAX_AIR_VIEWS, |m| m as usize),
        max_water_frames: args
            .max_frames
            .map_or(DEFAULT_MAX_WATER_FRAMES, |m| m as usize),
        air: source == LensSource::Air,
    };
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
    let mut fits = Vec::new();
    let cameras = match source {
        LensSource::Rig => {
            let path = args.rig.as_ref().expect("a rig file with LensSource::Rig");
            cameras_from_rig(&read_rig(path)?, &path.display().to_string(), &footage)?
        }
        LensSource::Water => {
            eprintln!(
                "no air/ folder and no --rig: every lens from the underwater frames, with the ports and the extrinsics (docs/calibration.md, \"Lenses from underwater frames alone\")"
            );
            let starts = water_lens_starts(&footage, &board, index_air, index_water)?;
            for (camera, start) in names.iter().zip(&starts) {
                eprintln!(
                    "water/{camera}: lens start fx {:.1}, fy {:.1}, cx {:.1}, cy {:.1} px (the underwater views' pinhole, its focal length over n_water/n_air)",
                    start.fx, start.fy, start.cx, start.cy
                );
            }
            starts
        }
        LensSource::Air => {
            let mut cameras = Vec::new();
            for (k, camera) in footage.cameras.iter().enumerate() {
                let name = &camera.name;
                eprintln!(
                    "air/{name}: the board in {} of {} images, {} used",
                    camera.air_read.1,
                    camera.air_read.0,
                    camera.air.len()
                );
                let fit = air_lens(&footage, k, &board)?;
                print_intrinsics(name, &fit);
                cameras.push(fit.camera);
                fits.push((name.clone(), fit));
            }
            cameras
        }
    };
    let (read, with_board, by_two) = footage.water_read;
    eprintln!(
        "underwater: the board in {with_board} of {read} frames ({by_two} seen by two or more cameras); {} frames used",
        footage.water.len()
    );
    let frames = &footage.water;
    // Each camera's in-air corners, for the report's coverage pictures.
    let setup = RigSetup {
        cameras,
        port,
        glass,
        index_air,
        index_water,
    };
    let engine = calibration_engine(&args.engine)?;
    eprintln!("device: {}", engine.describe());
    let settings = FitSettings {
        huber: args.huber,
        max_iterations: args.max_iterations,
        max_rms_px: args.max_rms_px,
        max_tilt_deg: args.max_tilt_deg,
        holdout: args.holdout,
        refine_intrinsics: RefineIntrinsics::from_name(&args.refine_intrinsics).unwrap_or_default(),
    };
    let options = boards_options(&settings, backend(engine), &fits);
    eprintln!(
        "calibrating the extrinsics and {} from {} frames ({} % held out)...",
        match port {
            PortKind::Surface => "the water surface".to_string(),
            PortKind::Shared => "the shared port".to_string(),
            PortKind::Housings => format!("{} housings' ports", names.len()),
        },
        footage.water.len(),
        (100.0 * args.holdout).round()
    );
    let mut status = CalibrationStatus::new();
    let result = calibrate(
        source,
        &names,
        &setup,
        &board,
        &footage,
        &options,
        &mut |p| status.update(p),
    );
    status.finish();
    let (result, lens_choice) = result?;
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
            frames,
            options.calibration.huber,
        );
        input.air = footage.air_corners();
        super::calib::written_report(report_dir, &input)?;
    }
    let report = &result.calibration.report;
    if !report.fits {
        bail!(
            "{} {} not written{}",
            refusal(&result),
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
    for line in &result.turned {
        eprintln!("{line}");
    }
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
        let squares = if v.distances > 0 {
            format!(
                "{} neighbouring corners triangulated: median error {:.3} mm ({:.3} % of the square), RMS {:.3} mm",
                v.distances,
                v.median_error_m * 1e3,
                v.median_error_percent,
                v.rms_error_m * 1e3
            )
        } else {
            "no corner seen by two cameras to triangulate".to_string()
        };
        outln!(
            "held out {} frames: reprojection RMS {:.3} px; {squares}",
            v.frames.len(),
            v.rms_px,
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
